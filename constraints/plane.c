/* plane: a particle on the plane n.x = c (inputs: the particle's d
 * coordinates; parameters n (d entries, not necessarily unit) and c).
 * g = (n.x - c) / |n|, the signed distance to the plane. */
#include "util/util.h"

#include <math.h>
#include <string.h>

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  if (n_in < 1 || n_in > 3 || n_params != n_in + 1) {
    mrvi_fmt(msg, len,
             "plane: needs a particle (d inputs) and parameters normal (d "
             "entries) and offset (got %d inputs and %d parameters)",
             n_in, n_params);
    return MRVI_EINVAL;
  }
  double nn = 0.0;
  for (int i = 0; i < n_params; i++) {
    if (!isfinite(par[i])) {
      mrvi_fmt(msg, len, "plane: normal and offset must be finite");
      return MRVI_EINVAL;
    }
    if (i < n_in)
      nn += par[i] * par[i];
  }
  if (!(nn > 0.0)) {
    mrvi_fmt(msg, len, "plane: the normal must not be zero");
    return MRVI_EINVAL;
  }
  return 1;
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  double nn = 0.0, s = 0.0;
  for (int a = 0; a < n_in; a++) {
    nn += par[a] * par[a];
    s += par[a] * y[a];
  }
  const double len = sqrt(nn);
  g[0] = (s - par[n_in]) / len;
  for (int a = 0; a < n_in; a++)
    G[a] = par[a] / len;
  if (H)
    memset(H, 0, (size_t)n_in * (size_t)n_in * sizeof *H);
}

/* An offset not given (NAN): the plane through the initial position,
 * n.x0 (linear.c). */
int mrvi_constraint_initial_rhs(int n_in, int n_params, double *par,
                                const double *y0, char *msg, size_t len);

/* {type: plane, particle: a, normal: [...], offset: c} */
static const mrvi_constraint_key keys[] = {
    {"particle", MRVI_KEY_PARTICLE, MRVI_KEY_REQUIRED, 0},
    {"normal", MRVI_KEY_VECTOR, MRVI_KEY_REQUIRED | MRVI_KEY_REPORT, 1},
    {"offset", MRVI_KEY_SCALAR, 0, 2},
    {0},
};

/* Affine whatever the parameters (linear.c). */
int mrvi_constraint_always_affine(int n_in, int n_params, const double *par);

const mrvi_constraint_type mrvi_constraint_plane = {
    .name = "plane",
    .summary = "particle on the plane n.x = c (residual: signed distance)",
    .check = check,
    .eval = eval,
    .affine = mrvi_constraint_always_affine,
    .initial = mrvi_constraint_initial_rhs,
    .keys = keys,
};
