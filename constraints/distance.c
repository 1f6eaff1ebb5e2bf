/* distance: rigid rod of length L between two particles (inputs x_i, x_j:
 * 2d coordinates; parameter L) or between a particle and a fixed point a
 * (inputs x_i: d coordinates; parameters L, a).
 *
 *   g = (|r|^2 - L^2) / (2 L),  r = x_i - x_j  (or x_i - a)
 *
 * g vanishes exactly where |r| = L and equals |r| - L to first order, so the
 * residual reads as a length; unlike |r| - L it is smooth at r = 0. */
#include "util/util.h"

#include <math.h>
#include <string.h>

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  const int pair = n_params == 1 && n_in % 2 == 0 && n_in >= 2 && n_in <= 6;
  const int anchor = n_params == n_in + 1 && n_in >= 1 && n_in <= 3;
  if (!pair && !anchor) {
    mrvi_fmt(msg, len,
             "distance: needs two particles (2d inputs, parameter length) or "
             "a particle and an anchor (d inputs, parameters length and d "
             "anchor coordinates); got %d inputs and %d parameters",
             n_in, n_params);
    return MRVI_EINVAL;
  }
  for (int i = 0; i < n_params; i++)
    if (!isfinite(par[i])) {
      mrvi_fmt(msg, len, "distance: parameters must be finite");
      return MRVI_EINVAL;
    }
  if (!(par[0] > 0.0)) {
    mrvi_fmt(msg, len, "distance: length must be > 0 (got %g)", par[0]);
    return MRVI_EINVAL;
  }
  return 1;
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  const double L = par[0];
  const int anchor = n_params == n_in + 1;
  const int d = anchor ? n_in : n_in / 2;
  double r[3], rr = 0.0;
  for (int a = 0; a < d; a++) {
    r[a] = y[a] - (anchor ? par[1 + a] : y[d + a]);
    rr += r[a] * r[a];
  }
  g[0] = (rr - L * L) / (2.0 * L);
  for (int a = 0; a < d; a++) {
    G[a] = r[a] / L;
    if (!anchor)
      G[d + a] = -r[a] / L;
  }
  if (!H)
    return;
  /* d2g/dy2 = [I -I; -I I] / L (pair) or I / L (anchor). */
  memset(H, 0, (size_t)n_in * (size_t)n_in * sizeof *H);
  for (int a = 0; a < d; a++) {
    H[a * n_in + a] = 1.0 / L;
    if (!anchor) {
      H[(d + a) * n_in + d + a] = 1.0 / L;
      H[a * n_in + d + a] = -1.0 / L;
      H[(d + a) * n_in + a] = -1.0 / L;
    }
  }
}

/* A length not given (NAN): the initial distance. */
static int initial(int n_in, int n_params, double *par, const double *y0,
                   char *msg, size_t len) {
  const int pair = n_params == 1 && n_in % 2 == 0 && n_in >= 2 && n_in <= 6;
  const int anchor = n_params == n_in + 1 && n_in >= 1 && n_in <= 3;
  if ((!pair && !anchor) || !isnan(par[0]))
    return 0; /* check() judges the rest */
  const int d = anchor ? n_in : n_in / 2;
  double rr = 0.0;
  for (int a = 0; a < d; a++)
    rr += (y0[a] - (anchor ? par[1 + a] : y0[d + a])) *
          (y0[a] - (anchor ? par[1 + a] : y0[d + a]));
  par[0] = sqrt(rr);
  if (par[0] > 0.0)
    return 0;
  mrvi_fmt(msg, len,
           anchor ? "the particle starts at the anchor, so the length must "
                    "be given"
                  : "the particles start at the same point, so the length "
                    "must be given");
  return MRVI_EINVAL;
}

/* {type: distance, between: [a, b] | [a] + anchor, length} */
static const mrvi_constraint_key keys[] = {
    {"between", MRVI_KEY_ENDS, MRVI_KEY_REQUIRED | MRVI_KEY_REPORT, 0},
    {"anchor", MRVI_KEY_VECTOR, MRVI_KEY_ANCHOR, 2},
    {"length", MRVI_KEY_SCALAR, MRVI_KEY_POSITIVE, 1},
    {0},
};

const mrvi_constraint_type mrvi_constraint_distance = {
    .name = "distance",
    .summary = "rigid rod |x_i - x_j| = L (or |x_i - a| = L to an anchor)",
    .check = check,
    .eval = eval,
    .initial = initial,
    .keys = keys,
};
