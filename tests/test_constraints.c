/* Constraint types (constraints/): G and the second derivatives against
 * central finite differences, sizes, parameter checks, registry. */
#include "testlib.h"
#include "util/util.h"

#include <math.h>
#include <string.h>

/* FD check of one type at inputs y. */
static void check_type(const char *name, int n_in, int n_params,
                       const double *par, const double *y0) {
  const mrvi_constraint_type *t = mrvi_constraint_type_find(name);
  CHECK(t != NULL, "type %s registered", name);
  if (!t)
    return;
  char msg[256];
  const int rows = t->check(n_in, n_params, par, msg, sizeof msg);
  CHECK(rows >= 1 && rows <= n_in, "%s: rows %d (%s)", name, rows, msg);
  if (rows < 1)
    return;
  double y[24], g[16], G[256], H[4096], gp[16], gm[16], Gp[256], Gm[256];
  memcpy(y, y0, (size_t)n_in * sizeof *y);
  t->eval(n_in, n_params, par, y, g, G, H);
  double errG = 0.0, errH = 0.0, scale = 1.0;
  for (int j = 0; j < n_in; j++) {
    const double e = 1e-6;
    y[j] = y0[j] + e;
    t->eval(n_in, n_params, par, y, gp, Gp, NULL);
    y[j] = y0[j] - e;
    t->eval(n_in, n_params, par, y, gm, Gm, NULL);
    y[j] = y0[j];
    for (int r = 0; r < rows; r++) {
      errG = fmax(errG, fabs((gp[r] - gm[r]) / (2 * e) - G[r * n_in + j]));
      for (int l = 0; l < n_in; l++) {
        const double fd = (Gp[r * n_in + l] - Gm[r * n_in + l]) / (2 * e);
        errH = fmax(errH, fabs(fd - H[(r * n_in + l) * n_in + j]));
        scale = fmax(scale, fabs(H[(r * n_in + l) * n_in + j]));
      }
    }
  }
  /* Central differences: truncation e^2 |g'''| plus roundoff eps/e. */
  CHECK(errG <= 1e-8, "%s: G vs finite differences, error %.2e", name, errG);
  CHECK(errH <= 1e-8 * scale, "%s: second derivatives vs FD, error %.2e", name,
        errH);
  /* Symmetry of each second-derivative block. */
  double asym = 0.0;
  for (int r = 0; r < rows; r++)
    for (int j = 0; j < n_in; j++)
      for (int l = 0; l < n_in; l++)
        asym = fmax(asym, fabs(H[(r * n_in + j) * n_in + l] -
                               H[(r * n_in + l) * n_in + j]));
  CHECK(asym == 0.0, "%s: second derivatives symmetric (%.2e)", name, asym);
}

static void test_derivatives(void) {
  const double y6[6] = {0.3, -0.7, 1.1, -0.2, 0.5, 0.4};
  const double L[1] = {1.3};
  check_type("distance", 6, 1, L, y6); /* two particles, 3-D */
  check_type("distance", 4, 1, L, y6); /* two particles, 2-D */
  const double La[4] = {0.8, 0.1, -0.2, 0.3};
  check_type("distance", 3, 4, La, y6); /* anchor, 3-D */
  const double fx[2] = {0.5, -1.0};
  check_type("fixed", 2, 2, fx, y6);
  const double pl[4] = {1.0, 2.0, -2.0, 0.5};
  check_type("plane", 3, 4, pl, y6);
  const double li[4] = {1.0, -3.0, 0.5, 2.0};
  check_type("linear", 3, 4, li, y6);
  /* Rigid bodies and joints (doc/multibody.md): inputs phi, d_1.., d_D of
   * one or two bodies; joint parameters D, bodies, two points, [axes]. */
  double y24[24], jp[26];
  for (int i = 0; i < 24; i++)
    y24[i] = sin(1.7 * i + 0.3);
  for (int i = 0; i < 26; i++)
    jp[i] = cos(2.3 * i);
  check_type("body", 9, 0, jp, y24);
  check_type("body", 4, 0, jp, y24);
  /* Parameters: D, bodies, two points and (but spherical) two frames. */
  const char *const framed[] = {"revolute",    "weld",   "prismatic",
                                "cylindrical", "planar", "universal"};
  for (int nb = 1; nb <= 2; nb++) {
    jp[0] = 3, jp[1] = nb;
    check_type("spherical", 12 * nb, 8, jp, y24);
    for (int t = 0; t < 6; t++)
      check_type(framed[t], 12 * nb, 26, jp, y24);
    jp[0] = 2;
    for (int t = 0; t < 3; t++)
      check_type(framed[t], 6 * nb, 14, jp, y24);
  }
}

/* Values that are known exactly. */
static void test_values(void) {
  const mrvi_constraint_type *d = mrvi_constraint_type_find("distance");
  const double par[1] = {2.0}, y[6] = {3, 0, 0, 0, 0, 0};
  double g, G[6];
  d->eval(6, 1, par, y, &g, G, NULL);
  /* |r| = 3, L = 2: (9 - 4) / 4 */
  CHECK_NEAR(g, 1.25, 1e-15, "distance g");
  CHECK_NEAR(G[0], 1.5, 1e-15, "distance G");
  CHECK_NEAR(G[3], -1.5, 1e-15, "distance G (other end)");
  const mrvi_constraint_type *p = mrvi_constraint_type_find("plane");
  const double pl[4] = {0, 0, 2, 1}, yp[3] = {5, 6, 1.5};
  p->eval(3, 4, pl, yp, &g, G, NULL);
  /* signed distance of z = 1.5 from 2 z = 1, i.e. z = 0.5 */
  CHECK_NEAR(g, 1.0, 1e-15, "plane signed distance");
}

static void test_bad_parameters(void) {
  char msg[256];
  const mrvi_constraint_type *d = mrvi_constraint_type_find("distance");
  const double neg[1] = {-1.0};
  CHECK(d->check(6, 1, neg, msg, sizeof msg) < 0 && strstr(msg, "length"),
        "negative length rejected: %s", msg);
  CHECK(d->check(5, 1, neg, msg, sizeof msg) < 0, "odd input count rejected");
  const mrvi_constraint_type *p = mrvi_constraint_type_find("plane");
  const double zero[4] = {0, 0, 0, 1};
  CHECK(p->check(3, 4, zero, msg, sizeof msg) < 0 && strstr(msg, "normal"),
        "zero normal rejected: %s", msg);
  const mrvi_constraint_type *l = mrvi_constraint_type_find("linear");
  const double z2[3] = {0, 0, 1};
  CHECK(l->check(2, 3, z2, msg, sizeof msg) < 0, "zero coefficients rejected");
}

/* Model builders: where each constraint is enforced, defaults, labels,
 * unknown types, redundancy and inconsistent initial data. */
static void test_model(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double x0[2] = {0, 0}, x1[2] = {3, 4}, v[2] = {1, 1};
  mrvi_model_add_particle(m, "a", 1.0, MRVI_SLOW, x0, v);
  mrvi_model_add_particle(m, "b", 2.0, MRVI_FAST, x1, v);
  const double anchor[2] = {0, 1};
  CHECK(mrvi_model_add_distance(m, 0, 1, NAN) == 0, "rod a-b");
  CHECK(mrvi_model_add_distance_anchor(m, 0, anchor, NAN) == 1, "rod a-anchor");
  CHECK(mrvi_model_constraint_where(m, 0) == MRVI_FAST, "a-b at micro nodes");
  CHECK(mrvi_model_constraint_where(m, 1) == MRVI_SLOW, "a-anchor at macro");
  double g[2];
  mrvi_model_constraint_eval(m, mrvi_model_q0(m), g, NULL);
  CHECK(fabs(g[0]) < 1e-15 && fabs(g[1]) < 1e-15,
        "default lengths are the initial distances (%g, %g)", g[0], g[1]);
  CHECK(mrvi_model_check_initial_positions(m, 1e-12, NULL) == 0,
        "consistent initial positions");
  double corr = 0.0;
  CHECK(mrvi_model_project_velocities(m, &corr) == 0 && corr > 0.1,
        "velocities projected (correction %g)", corr);
  double p[4];
  for (int i = 0; i < 4; i++)
    p[i] = mrvi_model_mass(m, i) * mrvi_model_v0(m)[i];
  CHECK(mrvi_model_hidden_residual(m, mrvi_model_q0(m), p) < 1e-14,
        "hidden constraint after projection: %.2e",
        mrvi_model_hidden_residual(m, mrvi_model_q0(m), p));
  CHECK(mrvi_model_add_constraint(m, "distanse", 2, (int[]){0, 1}, 1,
                                  (double[]){1.0}, NULL) < 0 &&
            strstr(mrvi_model_errmsg(m), "did you mean 'distance'"),
        "misspelt type: %s", mrvi_model_errmsg(m));
  /* A second rod a-b is redundant with the first. */
  mrvi_model_add_distance(m, 0, 1, 5.0);
  CHECK(mrvi_model_check_independent(m, mrvi_model_q0(m)) < 0 &&
            strstr(mrvi_model_errmsg(m), "distance a-b") &&
            strstr(mrvi_model_errmsg(m), "redundant"),
        "redundant constraints named: %s", mrvi_model_errmsg(m));
  mrvi_model_free(m);

  m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  mrvi_model_add_particle(m, "a", 1.0, MRVI_SLOW, x0, v);
  mrvi_model_add_particle(m, "b", 1.0, MRVI_SLOW, x1, v);
  mrvi_model_add_distance(m, 0, 1, 4.0); /* initial distance is 5 */
  CHECK(mrvi_model_check_initial_positions(m, 1e-10, NULL) < 0 &&
            strstr(mrvi_model_errmsg(m), "distance a-b") &&
            strstr(mrvi_model_errmsg(m), "|g| = 1.125e+00"),
        "inconsistent initial positions: %s", mrvi_model_errmsg(m));
  mrvi_model_free(m);
}

static int my_check(int n_in, int n_params, const double *par, char *msg,
                    size_t len) {
  (void)par, (void)msg, (void)len;
  return n_in == 1 && n_params == 0 ? 1 : -2;
}
static void my_eval(int n_in, int n_params, const double *par, const double *y,
                    double *g, double *G, double *H) {
  (void)n_in, (void)n_params, (void)par;
  g[0] = y[0] * y[0] - 1.0;
  G[0] = 2.0 * y[0];
  if (H)
    H[0] = 2.0;
}

static void test_registry(void) {
  static const mrvi_constraint_type mine = {.name = "unit_square",
                                            .summary = "q^2 = 1",
                                            .check = my_check,
                                            .eval = my_eval};
  CHECK(mrvi_constraint_type_register(&mine) == 0, "user type registered");
  CHECK(mrvi_constraint_type_register(&mine) < 0, "duplicate name rejected");
  CHECK(mrvi_constraint_type_find("unit_square") == &mine, "found by name");
  check_type("unit_square", 1, 0, NULL, (double[]){0.7});
}

int main(void) {
  test_derivatives();
  test_values();
  test_bad_parameters();
  test_model();
  test_registry();
  return test_finish();
}
