/* fixed: pin coordinates at given values (inputs: the pinned coordinates;
 * parameters: one target per input).  g_r = y_r - target_r, one row each. */
#include "util/util.h"

#include <math.h>
#include <string.h>

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  if (n_in < 1 || n_params != n_in) {
    mrvi_fmt(msg, len,
             "fixed: needs one target value per pinned coordinate (got %d "
             "coordinates and %d values)",
             n_in, n_params);
    return MRVI_EINVAL;
  }
  for (int i = 0; i < n_params; i++)
    if (!isfinite(par[i])) {
      mrvi_fmt(msg, len, "fixed: target values must be finite");
      return MRVI_EINVAL;
    }
  return n_in;
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  memset(G, 0, (size_t)n_in * (size_t)n_in * sizeof *G);
  for (int r = 0; r < n_in; r++) {
    g[r] = y[r] - par[r];
    G[r * n_in + r] = 1.0;
  }
  if (H)
    memset(H, 0, (size_t)n_in * (size_t)n_in * (size_t)n_in * sizeof *H);
}

/* Targets not given (NAN): the initial values. */
static int initial(int n_in, int n_params, double *par, const double *y0,
                   char *msg, size_t len) {
  (void)msg, (void)len;
  for (int r = 0; r < n_in && r < n_params; r++)
    if (isnan(par[r]))
      par[r] = y0[r];
  return 0;
}

/* {type: fixed, particle: a, axes: [x, z], position: [...]} */
static const mrvi_constraint_key keys[] = {
    {"particle", MRVI_KEY_PARTICLE, MRVI_KEY_REQUIRED, 0},
    {"axes", MRVI_KEY_AXES, 0, 0},
    {"position", MRVI_KEY_VECTOR, 0, 1},
    {0},
};

/* Affine whatever the parameters (linear.c). */
int mrvi_constraint_always_affine(int n_in, int n_params, const double *par);

const mrvi_constraint_type mrvi_constraint_fixed = {
    .name = "fixed",
    .summary = "pinned coordinates q_i = c_i (a particle, all or some axes)",
    .check = check,
    .eval = eval,
    .affine = mrvi_constraint_always_affine,
    .initial = initial,
    .keys = keys,
};
