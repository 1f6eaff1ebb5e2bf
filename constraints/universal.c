/* universal: a Hooke joint (cross) between two rigid bodies or a body and
 * the ground (doc/multibody.md, "Joints"), rows of constraints/joint.h
 * with the joint's frame t_1 = the axis fixed in A and t_2 = the second
 * axis fixed in B:
 *   3-D (4 rows): r = 0, the body points coincide, and a_1 . b_2 = cos(alpha),
 *   the two axes keep the angle alpha they make at the initial
 *   configuration; the bodies keep two relative rotations (about a_1 and
 *   about b_2).
 * Perpendicular axes (alpha = pi/2) take the common parameters; oblique
 * ones (a cross with oblique arms) one more, cos(alpha), with B's t_2 the
 * second axis itself (not made normal to t_1).  The row's gradient with
 * respect to a relative rotation w is w . (b_2 x a_1), of size sin(alpha):
 * parallel axes (no second rotation to keep) are refused by the builder
 * (src/model/bodies.c). */
#include "joint.h"

static const mrvi_joint_row rows3[] = {{'p', 0, 0}, {'d', 0, 1}};

/* Parameters of the perpendicular joint (constraints/joint.h: 3-D, a
 * frame); an oblique one appends cos(alpha). */
#define COMMON_PARAMS (MRVI_JOINT_HEAD + 2 * 3 + 2 * 9)

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  const int oblique = n_params == COMMON_PARAMS + 1;
  const int rows =
      mrvi_joint_check_rows("universal", 1, rows3, 2, NULL, 0, n_in,
                            n_params - oblique, par, msg, len);
  if (rows < 0 || !oblique)
    return rows;
  const double c = par[n_params - 1];
  if (!(isfinite(c) && fabs(c) < 1.0))
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "universal: the cosine of the angle between the axes "
                     "must lie in (-1, 1) (got %g)",
                     c);
  return rows;
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  mrvi_joint_eval_rows(rows3, 2, NULL, 0, n_in, par, y, g, G, H);
  if (n_params == COMMON_PARAMS + 1)
    g[3] -= par[n_params - 1]; /* a_1 . b_2 - cos(alpha) */
}

static int affine(int n_in, int n_params, const double *par) {
  (void)n_in, (void)n_params;
  return mrvi_joint_affine_rows(rows3, 2, NULL, 0, par);
}

const mrvi_constraint_type mrvi_constraint_universal = {
    .name = "universal",
    .summary = "Hooke joint: the body points coincide and an axis fixed in A "
               "keeps its angle to one fixed in B (3-D, 4 rows)",
    .check = check,
    .eval = eval,
    .affine = affine,
    .joint_motion = MRVI_JOINT_UNIVERSAL,
};
