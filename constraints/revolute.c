/* revolute: a hinge between two rigid bodies or a body and the ground
 * (doc/multibody.md, "Joints"; Betsch & Leyendecker 2006, Part II), rows
 * of constraints/joint.h with the joint's frame t_1 = the hinge axis:
 *   2-D (2 rows): r = 0, the body points coincide;
 *   3-D (5 rows): r = 0 and a_1 . b_2 = a_1 . b_3 = 0, the axis fixed in A
 *   stays normal to the two vectors fixed in B that are normal to it. */
#include "joint.h"

static const mrvi_joint_row rows3[] = {{'p', 0, 0}, {'d', 0, 1}, {'d', 0, 2}};
static const mrvi_joint_row rows2[] = {{'p', 0, 0}};

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  return mrvi_joint_check_rows("revolute", 1, rows3, 3, rows2, 1, n_in,
                               n_params, par, msg, len);
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  mrvi_joint_eval_rows(rows3, 3, rows2, 1, n_in, par, y, g, G, H);
}

static int affine(int n_in, int n_params, const double *par) {
  (void)n_in, (void)n_params;
  return mrvi_joint_affine_rows(rows3, 3, rows2, 1, par);
}

const mrvi_constraint_type mrvi_constraint_revolute = {
    .name = "revolute",
    .summary =
        "hinge: the body points coincide and, in 3-D, an axis fixed in both "
        "bodies (2-D: 2 rows, 3-D: 5)",
    .check = check,
    .eval = eval,
    .affine = affine,
    .joint_motion = MRVI_JOINT_HINGE,
};
