/* body: the internal constraints of a rigid body in the director
 * formulation (doc/multibody.md; Betsch & Leyendecker 2006, Part II): its
 * directors d_1..d_D (inputs: D = 2 or 3 vectors of D entries, n_in = D^2,
 * no parameters) stay orthonormal,
 *
 *   g_ii = (d_i . d_i - 1) / 2,   g_ij = d_i . d_j  (i < j),
 *
 * rows in the order 11, 22, [33,] 12, [13, 23] (3-D: 6 rows, 2-D: 3).
 * Gradients dg_ii/dd_i = d_i, dg_ij/dd_i = d_j, dg_ij/dd_j = d_i; second
 * derivatives constant: d2g_ii/dd_i^2 = I, d2g_ij/(dd_i dd_j) = I. */
#include "util/util.h"

#include <math.h>
#include <string.h>

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  (void)par;
  if ((n_in != 4 && n_in != 9) || n_params != 0)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "body: needs the directors of one rigid body (4 inputs "
                     "in 2-D, 9 in 3-D) and no parameters (got %d inputs and "
                     "%d parameters)",
                     n_in, n_params);
  return n_in == 4 ? 3 : 6;
}

/* Director pairs (i, j) of the rows: the diagonal first. */
static int pairs(int D, int (*ij)[2]) {
  int r = 0;
  for (int i = 0; i < D; i++, r++)
    ij[r][0] = ij[r][1] = i;
  for (int i = 0; i < D; i++)
    for (int j = i + 1; j < D; j++, r++) {
      ij[r][0] = i;
      ij[r][1] = j;
    }
  return r;
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params, (void)par;
  const int D = n_in == 4 ? 2 : 3;
  int ij[6][2];
  const int rows = pairs(D, ij);
  memset(G, 0, (size_t)rows * (size_t)n_in * sizeof *G);
  if (H)
    memset(H, 0, (size_t)rows * (size_t)n_in * (size_t)n_in * sizeof *H);
  for (int r = 0; r < rows; r++) {
    const int i = ij[r][0], j = ij[r][1];
    const double *di = y + D * i, *dj = y + D * j;
    double s = 0.0;
    for (int a = 0; a < D; a++)
      s += di[a] * dj[a];
    g[r] = i == j ? 0.5 * (s - 1.0) : s;
    for (int a = 0; a < D; a++) {
      G[r * n_in + D * i + a] += dj[a];
      if (i != j)
        G[r * n_in + D * j + a] += di[a];
      if (H) {
        double *Hr = H + (size_t)r * (size_t)n_in * (size_t)n_in;
        Hr[(D * i + a) * n_in + D * j + a] = 1.0;
        Hr[(D * j + a) * n_in + D * i + a] = 1.0;
      }
    }
  }
}

const mrvi_constraint_type mrvi_constraint_body = {
    .name = "body",
    .summary = "orthonormal directors of a rigid body: (d_i.d_i - 1)/2 = 0, "
               "d_i.d_j = 0 (3 rows in 2-D, 6 in 3-D)",
    .check = check,
    .eval = eval,
};
