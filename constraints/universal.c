/* universal: a Hooke joint (cross) between two rigid bodies or a body and
 * the ground (doc/multibody.md, "Joints"), rows of constraints/joint.h
 * with the joint's frame t_1 = the axis fixed in A and t_2 = the second
 * axis fixed in B (perpendicular to t_1 at the initial configuration):
 *   3-D (4 rows): r = 0, the body points coincide, and a_1 . b_2 = 0, the
 *   two axes stay perpendicular; the bodies keep two relative rotations
 *   (about a_1 and about b_2). */
#include "joint.h"

static const mrvi_joint_row rows3[] = {{'p', 0, 0}, {'d', 0, 1}};

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  return mrvi_joint_check_rows("universal", 1, rows3, 2, NULL, 0, n_in,
                               n_params, par, msg, len);
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  mrvi_joint_eval_rows(rows3, 2, NULL, 0, n_in, par, y, g, G, H);
}

const mrvi_constraint_type mrvi_constraint_universal = {
    .name = "universal",
    .summary = "Hooke joint: the body points coincide and an axis fixed in A "
               "stays perpendicular to one fixed in B (3-D, 4 rows)",
    .check = check,
    .eval = eval,
};
