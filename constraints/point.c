/* point: the particle constraints distance, fixed and plane on points that
 * are affine in the coordinates, such as body points x = phi + sum_i X^i d_i
 * (doc/multibody.md, "Constraints on body points").
 *
 * The inputs are nb blocks Y_b of d coordinates with constant weights w_b,
 * and x = sum_b w_b Y_b (a particle is one block of weight 1, a body point
 * phi with 1 and d_i with X^i; the second end of a distance enters with the
 * weights negated, so x = x_a - x_b).  Parameters: d, nb, w_1 .. w_nb, the
 * kind, then the kind's own:
 *
 *   0 distance  L, a (d):       g = (|x - a|^2 - L^2) / (2 L)
 *                               dg/dY_b = w_b (x - a) / L,
 *                               d2g/dY_b dY_c = w_b w_c I / L
 *   1 fixed     mask (d), p (d): g_k = x_k - p_k for the axes k with
 *                               mask_k = 1; dg_k/dY_b = w_b e_k
 *   2 plane     n (d), o:       g = n . x - o; dg/dY_b = w_b n
 *
 * As the particles' distance, fixed and plane (distance.c, fixed.c,
 * plane.c), of which these are the same functions of x. */
#include "util/util.h"

#include <math.h>
#include <string.h>

enum { DISTANCE, FIXED, PLANE };

/* Layout: d, nb, kind and the first parameter of the kind's own. */
static int layout(int n_params, const double *par, int *d, int *nb, int *kind,
                  int *own) {
  if (n_params < 3)
    return -1;
  *d = (int)par[0], *nb = (int)par[1];
  if ((double)*d != par[0] || *d < 1 || *d > 3 || (double)*nb != par[1] ||
      *nb < 1 || *nb > 8 || n_params < 3 + *nb)
    return -1;
  const double k = par[2 + *nb];
  *kind = (int)k;
  *own = 3 + *nb;
  if ((double)*kind != k || *kind < DISTANCE || *kind > PLANE)
    return -1;
  const int want = *kind == DISTANCE ? 1 + *d
                   : *kind == FIXED  ? 2 * *d
                                     : *d + 1;
  return n_params == *own + want ? 0 : -1;
}

static int rows_of(int d, int kind, const double *own) {
  if (kind != FIXED)
    return 1;
  int r = 0;
  for (int k = 0; k < d; k++)
    r += own[k] != 0.0;
  return r;
}

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  int d, nb, kind, own;
  for (int i = 0; i < n_params; i++)
    if (!isfinite(par[i]))
      return mrvi_fail(msg, len, MRVI_EINVAL,
                       "point: parameters must be finite");
  if (layout(n_params, par, &d, &nb, &kind, &own) < 0 || n_in != nb * d)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "point: parameters d, nb, nb weights, kind (0 distance, "
                     "1 fixed, 2 plane) and the kind's own, on nb d inputs; "
                     "got %d inputs and %d parameters",
                     n_in, n_params);
  if (kind == DISTANCE && !(par[own] > 0.0))
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "point: length must be > 0 (got %g)", par[own]);
  const int rows = rows_of(d, kind, par + own);
  if (rows == 0)
    return mrvi_fail(msg, len, MRVI_EINVAL, "point: no axis fixed");
  if (kind == PLANE) {
    double nn = 0.0;
    for (int k = 0; k < d; k++)
      nn += par[own + k] * par[own + k];
    if (!(nn > 0.0))
      return mrvi_fail(msg, len, MRVI_EINVAL,
                       "point: the plane's normal must not be zero");
  }
  return rows;
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  int d, nb, kind, own;
  layout(n_params, par, &d, &nb, &kind, &own);
  const double *w = par + 2, *o = par + own;
  double x[3] = {0, 0, 0};
  for (int b = 0; b < nb; b++)
    for (int k = 0; k < d; k++)
      x[k] += w[b] * y[b * d + k];
  const int rows = rows_of(d, kind, o);
  memset(G, 0, (size_t)rows * (size_t)n_in * sizeof *G);
  if (H)
    memset(H, 0, (size_t)rows * (size_t)n_in * (size_t)n_in * sizeof *H);
  if (kind == DISTANCE) {
    const double L = o[0];
    double rr = 0.0;
    for (int k = 0; k < d; k++) {
      x[k] -= o[1 + k];
      rr += x[k] * x[k];
    }
    g[0] = (rr - L * L) / (2.0 * L);
    for (int b = 0; b < nb; b++)
      for (int k = 0; k < d; k++)
        G[b * d + k] = w[b] * x[k] / L;
    for (int b = 0; H && b < nb; b++)
      for (int c = 0; c < nb; c++)
        for (int k = 0; k < d; k++)
          H[(b * d + k) * n_in + c * d + k] = w[b] * w[c] / L;
    return;
  }
  if (kind == PLANE) {
    g[0] = -o[d];
    for (int k = 0; k < d; k++)
      g[0] += o[k] * x[k];
    for (int b = 0; b < nb; b++)
      for (int k = 0; k < d; k++)
        G[b * d + k] = w[b] * o[k];
    return;
  }
  for (int k = 0, r = 0; k < d; k++) /* FIXED */
    if (o[k] != 0.0) {
      g[r] = x[k] - o[d + k];
      for (int b = 0; b < nb; b++)
        G[r * n_in + b * d + k] = w[b];
      r++;
    }
}

/* Fixed and plane are affine in x, so in the inputs; distance is not. */
static int affine(int n_in, int n_params, const double *par) {
  (void)n_in;
  int d, nb, kind, own;
  return layout(n_params, par, &d, &nb, &kind, &own) == 0 && kind != DISTANCE;
}

const mrvi_constraint_type mrvi_constraint_point = {
    .name = "point",
    .summary = "distance, fixed or plane on affine points such as body "
               "points (x = sum_b w_b Y_b)",
    .check = check,
    .eval = eval,
    .affine = affine,
};
