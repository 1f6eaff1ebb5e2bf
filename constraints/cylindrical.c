/* cylindrical: rotation about and sliding along one axis, between two 3-D
 * rigid bodies or a body and the ground (doc/multibody.md, "Joints"),
 * rows of constraints/joint.h with the joint's frame t_1 = the axis: the
 * axis fixed in A stays along the axis fixed in B, and the displacement r
 * stays along it:  a_1 . b_2 = a_1 . b_3 = 0,  r . b_2 = r . b_3 = 0
 * (4 rows). */
#include "joint.h"

static const mrvi_joint_row rows[] = {
    {'d', 0, 1}, {'d', 0, 2}, {'s', 0, 1}, {'s', 0, 2}};

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  return mrvi_joint_check_rows("cylindrical", 1, rows, 4, NULL, 0, n_in,
                               n_params, par, msg, len);
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  mrvi_joint_eval_rows(rows, 4, NULL, 0, n_in, par, y, g, G, H);
}

static int affine(int n_in, int n_params, const double *par) {
  (void)n_in, (void)n_params;
  return mrvi_joint_affine_rows(rows, 4, NULL, 0, par);
}

const mrvi_constraint_type mrvi_constraint_cylindrical = {
    .name = "cylindrical",
    .summary =
        "cylinder: rotation about and sliding along an axis (3-D, 4 rows)",
    .check = check,
    .eval = eval,
    .affine = affine,
    .joint_motion = MRVI_JOINT_CYLINDRICAL,
};
