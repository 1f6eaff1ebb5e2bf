/* linear: a^T q = b on generalised coordinates (inputs: the coordinates;
 * parameters a (n_in entries) and b).  g = a^T y - b. */
#include "util/util.h"

#include <math.h>
#include <string.h>

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  if (n_in < 1 || n_params != n_in + 1) {
    mrvi_fmt(msg, len,
             "linear: needs one coefficient per coordinate and a right-hand "
             "side (got %d coordinates and %d parameters)",
             n_in, n_params);
    return MRVI_EINVAL;
  }
  int nonzero = 0;
  for (int i = 0; i < n_params; i++) {
    if (!isfinite(par[i])) {
      mrvi_fmt(msg, len, "linear: coefficients must be finite");
      return MRVI_EINVAL;
    }
    if (i < n_in && par[i] != 0.0)
      nonzero = 1;
  }
  if (!nonzero) {
    mrvi_fmt(msg, len, "linear: all coefficients are zero");
    return MRVI_EINVAL;
  }
  return 1;
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  double s = 0.0;
  for (int j = 0; j < n_in; j++) {
    s += par[j] * y[j];
    G[j] = par[j];
  }
  g[0] = s - par[n_in];
  if (H)
    memset(H, 0, (size_t)n_in * (size_t)n_in * sizeof *H);
}

/* A right-hand side not given (NAN): the initial value of a^T y (also the
 * plane's offset, parameters (n, c)). */
int mrvi_constraint_initial_rhs(int n_in, int n_params, double *par,
                                const double *y0, char *msg, size_t len) {
  (void)msg, (void)len;
  if (n_in < 1 || n_params != n_in + 1 || !isnan(par[n_in]))
    return 0;
  double s = 0.0;
  for (int j = 0; j < n_in; j++)
    s += par[j] * y0[j];
  par[n_in] = s;
  return 0;
}

/* {type: linear, combination: {q1: 1, m1.x: -1}, value: b} */
static const mrvi_constraint_key keys[] = {
    {"combination", MRVI_KEY_COMBINATION, MRVI_KEY_REQUIRED | MRVI_KEY_REPORT,
     1},
    {"value", MRVI_KEY_SCALAR, 0, 2},
    {0},
};

/* affine of the types whose rows are affine in the inputs whatever the
 * parameters (linear; fixed and plane too). */
int mrvi_constraint_always_affine(int n_in, int n_params, const double *par) {
  (void)n_in, (void)n_params, (void)par;
  return 1;
}

const mrvi_constraint_type mrvi_constraint_linear = {
    .name = "linear",
    .summary = "a^T q = b on generalised coordinates",
    .check = check,
    .eval = eval,
    .initial = mrvi_constraint_initial_rhs,
    .affine = mrvi_constraint_always_affine,
    .keys = keys,
};
