/* weld: two rigid bodies (or a body and the ground) fixed to each other
 * (doc/multibody.md, "Joints"), rows of constraints/joint.h: the body
 * points coincide, r = 0, and the frames keep their relative rotation,
 *   3-D (6 rows): a_1 . b_2 = a_2 . b_3 = a_3 . b_1 = 0
 *   2-D (3 rows): a_1 . b_2 = 0
 * (near the initial configuration these are the three / one components of
 * the relative rotation vector). */
#include "joint.h"

static const mrvi_joint_row rows3[] = {
    {'p', 0, 0}, {'d', 0, 1}, {'d', 1, 2}, {'d', 2, 0}};
static const mrvi_joint_row rows2[] = {{'p', 0, 0}, {'d', 0, 1}};

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  return mrvi_joint_check_rows("weld", 1, rows3, 4, rows2, 2, n_in, n_params,
                               par, msg, len);
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  mrvi_joint_eval_rows(rows3, 4, rows2, 2, n_in, par, y, g, G, H);
}

static int affine(int n_in, int n_params, const double *par) {
  (void)n_in, (void)n_params;
  return mrvi_joint_affine_rows(rows3, 4, rows2, 2, par);
}

const mrvi_constraint_type mrvi_constraint_weld = {
    .name = "weld",
    .summary = "weld: the bodies fixed to each other (2-D: 3 rows, 3-D: 6)",
    .check = check,
    .eval = eval,
    .affine = affine,
    .joint_motion = MRVI_JOINT_WELD,
};
