/* planar: body A moves in a plane fixed in body B (or in space), between
 * 3-D rigid bodies (doc/multibody.md, "Joints"), rows of
 * constraints/joint.h with the joint's frame t_1 = the plane's normal: the
 * normals fixed in A and B stay parallel and the displacement r stays in
 * the plane:  a_1 . b_2 = a_1 . b_3 = 0,  r . b_1 = 0  (3 rows). */
#include "joint.h"

static const mrvi_joint_row rows[] = {{'d', 0, 1}, {'d', 0, 2}, {'s', 0, 0}};

static int check(int n_in, int n_params, const double *par, char *msg,
                 size_t len) {
  return mrvi_joint_check_rows("planar", 1, rows, 3, NULL, 0, n_in, n_params,
                               par, msg, len);
}

static void eval(int n_in, int n_params, const double *par, const double *y,
                 double *g, double *G, double *H) {
  (void)n_params;
  mrvi_joint_eval_rows(rows, 3, NULL, 0, n_in, par, y, g, G, H);
}

static int affine(int n_in, int n_params, const double *par) {
  (void)n_in, (void)n_params;
  return mrvi_joint_affine_rows(rows, 3, NULL, 0, par);
}

const mrvi_constraint_type mrvi_constraint_planar = {
    .name = "planar",
    .summary =
        "plane on plane: parallel normals, no motion along them (3-D, 3 rows)",
    .check = check,
    .eval = eval,
    .affine = affine,
    .joint_motion = MRVI_JOINT_PLANAR,
};
