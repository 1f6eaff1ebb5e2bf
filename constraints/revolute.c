/* revolute: a hinge between two rigid bodies or a body and the ground
 * (doc/multibody.md, "Joints"; Betsch & Leyendecker 2006, Part II).
 *
 * 2-D (2 rows): the body points coincide, as the spherical joint's rows
 * (constraints/joint.h):  x_A - x_B = 0.
 *
 * 3-D (5 rows): the points coincide (rows 0-2) and the hinge axis
 * n = sum_i a^i d_A^i fixed in A stays normal to two vectors
 * U = sum_j u^j d_B^j, W = sum_j w^j d_B^j fixed in B that are normal to
 * the axis in B (for the ground U = u, W = w in space):
 *
 *   g_3 = n . U,   g_4 = n . W.
 *
 * Gradients: dg_3/dd_A^i = a^i U, dg_3/dd_B^j = u^j n (g_4 alike); second
 * derivatives d2g_3/(dd_A^i dd_B^j) = a^i u^j I, zero elsewhere.
 * Parameters after the two points (3-D only): a (A's frame), u and w (B's
 * frame, or space for the ground), 9 entries. */
#include "joint.h"

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  if (n_params >= 1 && par[0] == 2.0)
    return mrvi_joint_check("revolute", 1 << 2, 0, n_in, n_params, par, msg,
                            len) < 0
               ? MRVI_EINVAL
               : 2;
  const int d = mrvi_joint_check("revolute", (1 << 2) | (1 << 3), 9, n_in,
                                 n_params, par, msg, len);
  if (d < 0)
    return d;
  const double *a = par + MRVI_JOINT_HEAD + 6;
  for (int v = 0; v < 3; v++) {
    const double *c = a + 3 * v;
    if (!(c[0] * c[0] + c[1] * c[1] + c[2] * c[2] > 0.0))
      return mrvi_fail(msg, len, MRVI_EINVAL,
                       "revolute: the %s must not be zero",
                       v == 0 ? "axis" : "vectors normal to the axis");
  }
  return 5;
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  const int d = (int)par[0], nb = (int)par[1];
  if (H)
    memset(H, 0,
           (size_t)(d == 2 ? 2 : 5) * (size_t)n_in * (size_t)n_in * sizeof *H);
  mrvi_joint_point_rows(n_in, par, y, g, G);
  if (d == 2)
    return;
  const double *ca = par + MRVI_JOINT_HEAD + 6, *cb[2] = {ca + 3, ca + 6};
  const double *yb = y + 12;
  double n[3], U[2][3];
  mrvi_joint_vector(y, ca, n);
  for (int r = 0; r < 2; r++) {
    if (nb == 2)
      mrvi_joint_vector(yb, cb[r], U[r]);
    else
      memcpy(U[r], cb[r], sizeof U[r]);
  }
  for (int r = 0; r < 2; r++) {
    double *Gr = G + (size_t)(3 + r) * (size_t)n_in;
    memset(Gr, 0, (size_t)n_in * sizeof *Gr);
    g[3 + r] = n[0] * U[r][0] + n[1] * U[r][1] + n[2] * U[r][2];
    for (int i = 0; i < 3; i++)
      for (int c = 0; c < 3; c++) {
        Gr[3 * (1 + i) + c] = ca[i] * U[r][c];
        if (nb == 2)
          Gr[12 + 3 * (1 + i) + c] = cb[r][i] * n[c];
      }
    if (!H || nb == 1)
      continue;
    double *Hr = H + (size_t)(3 + r) * (size_t)n_in * (size_t)n_in;
    for (int i = 0; i < 3; i++)
      for (int j = 0; j < 3; j++)
        for (int c = 0; c < 3; c++) {
          const int ia = 3 * (1 + i) + c, jb = 12 + 3 * (1 + j) + c;
          Hr[ia * n_in + jb] = Hr[jb * n_in + ia] = ca[i] * cb[r][j];
        }
  }
}

const mrvi_constraint_type mrvi_constraint_revolute = {
    .name = "revolute",
    .summary = "hinge: body points coincide (2-D: 2 rows) and, in 3-D, an "
               "axis fixed in both bodies (5 rows)",
    .check = check,
    .eval = eval,
};
