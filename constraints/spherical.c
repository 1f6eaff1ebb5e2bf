/* spherical: a ball joint between two 3-D rigid bodies or a body and the
 * ground (doc/multibody.md, "Joints"; Betsch & Leyendecker 2006, Part II):
 * the body points coincide, r = x_A - x_B = 0 (3 rows, linear in the
 * inputs: constant gradient, zero second derivatives).  Inputs and
 * parameters as constraints/joint.h lays them out, without a frame. */
#include "joint.h"

static const mrvi_joint_row rows[] = {{'p', 0, 0}};

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  return mrvi_joint_check_rows("spherical", 0, rows, 1, NULL, 0, n_in, n_params,
                               par, msg, len);
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  mrvi_joint_eval_rows(rows, 1, NULL, 0, n_in, par, y, g, G, H);
}

static int affine(int n_in, int n_params, const double *par) {
  (void)n_in, (void)n_params;
  return mrvi_joint_affine_rows(rows, 1, NULL, 0, par);
}

const mrvi_constraint_type mrvi_constraint_spherical = {
    .name = "spherical",
    .summary =
        "ball joint: a point of 3-D body A on a point of body B or the ground "
        "(3 rows)",
    .check = check,
    .eval = eval,
    .affine = affine,
    .joint_motion = MRVI_JOINT_BALL,
};
