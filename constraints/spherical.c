/* spherical: a ball joint between two 3-D rigid bodies or a body and the
 * ground (doc/multibody.md, "Joints"; Betsch & Leyendecker 2006, Part II):
 * the body points rho_A of A and rho_B of B (or the ground point a)
 * coincide,
 *
 *   g = phi_A + sum_i rho_A^i d_A^i - (phi_B + sum_i rho_B^i d_B^i)  (3 rows)
 *
 * (or - a).  Inputs and parameters as constraints/joint.h lays them out,
 * no parameters beyond the two points.  g is linear in the inputs: its
 * gradient is constant and its second derivatives vanish. */
#include "joint.h"

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  const int d =
      mrvi_joint_check("spherical", 1 << 3, 0, n_in, n_params, par, msg, len);
  return d < 0 ? d : 3;
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  mrvi_joint_point_rows(n_in, par, y, g, G);
  if (H)
    memset(H, 0, (size_t)3 * (size_t)n_in * (size_t)n_in * sizeof *H);
}

const mrvi_constraint_type mrvi_constraint_spherical = {
    .name = "spherical",
    .summary = "ball joint: a point of 3-D body A on a point of body B or "
               "the ground (3 rows)",
    .check = check,
    .eval = eval,
};
