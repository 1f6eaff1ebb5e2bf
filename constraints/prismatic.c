/* prismatic: a slider between two rigid bodies or a body and the ground
 * (doc/multibody.md, "Joints"), rows of constraints/joint.h with the
 * joint's frame t_1 = the sliding axis: no relative rotation (the weld's
 * rotation rows) and the relative displacement r stays along the axis
 * fixed in B (or in space for the ground),
 *   3-D (5 rows): a_1 . b_2 = a_2 . b_3 = a_3 . b_1 = 0, r . b_2 = r . b_3 = 0
 *   2-D (2 rows): a_1 . b_2 = 0, r . b_2 = 0. */
#include "joint.h"

static const mrvi_joint_row rows3[] = {
    {'d', 0, 1}, {'d', 1, 2}, {'d', 2, 0}, {'s', 0, 1}, {'s', 0, 2}};
static const mrvi_joint_row rows2[] = {{'d', 0, 1}, {'s', 0, 1}};

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  return mrvi_joint_check_rows("prismatic", 1, rows3, 5, rows2, 2, n_in,
                               n_params, par, msg, len);
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  mrvi_joint_eval_rows(rows3, 5, rows2, 2, n_in, par, y, g, G, H);
}

static int affine(int n_in, int n_params, const double *par) {
  (void)n_in, (void)n_params;
  return mrvi_joint_affine_rows(rows3, 5, rows2, 2, par);
}

const mrvi_constraint_type mrvi_constraint_prismatic = {
    .name = "prismatic",
    .summary =
        "slider: no relative rotation, displacement along an axis fixed in B "
        "(2-D: 2 rows, 3-D: 5)",
    .check = check,
    .eval = eval,
    .affine = affine,
    .joint_motion = MRVI_JOINT_PRISMATIC,
};
