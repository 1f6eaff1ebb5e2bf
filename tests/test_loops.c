/* Closed loops of joints (doc/multibody.md, "Closed loops"): a planar
 * four-bar modelled in 3-D with revolute joints has 3 redundant constraint
 * rows, which the null-space form handles and the multiplier form refuses
 * with the joints' names; the loop holds to the constraint tolerance over
 * 10^4 steps with a bounded energy error.  The 2-D four-bar (no redundancy)
 * gives the same trajectory in both forms.  Initial positions off the
 * constraints are projected with the minimal (mass-weighted) displacement. */
#include "io/io.h"
#include "model/model.h"
#include "solver/solver.h"
#include "models.h"
#include "testlib.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static const char *form_name(mrvi_constraint_form f) {
  return f == MRVI_FORM_NULL_SPACE ? "null-space" : "multipliers";
}

/* ---------------------------------------------------------------------------
 * The four-bar: ground pivots A = 0 and D = (fb_d, 0), crank AB (fb_a),
 * coupler BC (fb_b), rocker DC (fb_c), a Grashof crank-rocker (s + l <=
 * p + q), crank angle fb_th0, crank angular velocity fb_w0 about e3,
 * gravity -fb_g e2 in the plane.  Each link is a uniform bar (d1 along it).
 * ------------------------------------------------------------------------- */
static const double fb_a = 1.0, fb_b = 3.0, fb_c = 2.5, fb_d = 3.0,
                    fb_th0 = 1.0, fb_w0 = 2.0, fb_g = 9.81;

/* The joint points A, B, C, D (3 entries each, z = 0) at crank angle th,
 * C on the upper branch (exact to round-off). */
static void fourbar_points(double th, double P[4][3]) {
  memset(P, 0, 4 * 3 * sizeof(double));
  P[1][0] = fb_a * cos(th);
  P[1][1] = fb_a * sin(th);
  P[3][0] = fb_d;
  /* C: |C - B| = b, |C - D| = c (intersection of two circles). */
  const double ex = P[3][0] - P[1][0], ey = P[3][1] - P[1][1];
  const double e = hypot(ex, ey);
  const double s = (fb_b * fb_b - fb_c * fb_c + e * e) / (2.0 * e);
  const double h = sqrt(fb_b * fb_b - s * s);
  P[2][0] = P[1][0] + (s * ex + h * ey) / e;
  P[2][1] = P[1][1] + (s * ey - h * ex) / e;
  if (P[2][1] < 0) { /* the other branch */
    P[2][0] = P[1][0] + (s * ex - h * ey) / e;
    P[2][1] = P[1][1] + (s * ey + h * ex) / e;
  }
}

/* A uniform bar from P to Q as a body (D = 2 or 3) of the given rate, at
 * rest or with angular velocity w about e3 around P (v = w e3 x (x - P)). */
static int add_bar_rate(mrvi_model *m, const char *name, int D, const double *P,
                        const double *Q, double mass, double w,
                        mrvi_rate rate) {
  const double dx = Q[0] - P[0], dy = Q[1] - P[1], l = hypot(dx, dy);
  const double c = dx / l, s = dy / l;
  const double x0[3] = {0.5 * (P[0] + Q[0]), 0.5 * (P[1] + Q[1]), 0.0};
  const double v0[3] = {-w * (x0[1] - P[1]), w * (x0[0] - P[0]), 0.0};
  const double Jt = mass * l * l / 12.0;
  if (D == 3) {
    const double R[9] = {c, -s, 0, s, c, 0, 0, 0, 1};
    const double J[3] = {0.1 * Jt, Jt, Jt}, om[3] = {0, 0, w};
    return mrvi_model_add_body(m, name, 3, rate, mass, J, x0, R, v0, om);
  }
  const double R[4] = {c, -s, s, c};
  return mrvi_model_add_body(m, name, 2, rate, mass, &Jt, x0, R, v0, &w);
}

static int add_bar(mrvi_model *m, const char *name, int D, const double *P,
                   const double *Q, double mass, double w) {
  return add_bar_rate(m, name, D, P, Q, mass, w, MRVI_SLOW);
}

/* The four-bar in D dimensions; off moves the rocker's centre by off along
 * e2 after the joints are made (which meet the typed positions exactly), so
 * that its two joints are off by off.  With fast: a fast particle on a stiff
 * spring to an anchor and a soft slow spring to the coupler's midpoint (so that
 * p > 1 has fast coordinates). */
static mrvi_model *fourbar(int D, double off, int fast) {
  mrvi_model *m = mrvi_model_create();
  double P[4][3];
  fourbar_points(fb_th0, P);
  const double axis[3] = {0, 0, 1}, g[3] = {0, -fb_g, 0};
  mrvi_model_set_dimension(m, D);
  int st = add_bar(m, "crank", D, P[0], P[1], 1.0, fb_w0);
  st |= add_bar(m, "coupler", D, P[1], P[2], 2.0, 0.0);
  st |= add_bar(m, "rocker", D, P[3], P[2], 1.5, 0.0);
  CHECK(st >= 0, "four-bar %d-D bodies: %s", D, mrvi_model_errmsg(m));
  const char *rev = "revolute";
  const double *ax = D == 3 ? axis : NULL;
  st = mrvi_model_add_joint(m, rev, 0, -1, P[0], ax);
  st |= mrvi_model_add_joint(m, rev, 0, 1, P[1], ax);
  st |= mrvi_model_add_joint(m, rev, 1, 2, P[2], ax);
  st |= mrvi_model_add_joint(m, rev, 2, -1, P[3], ax);
  CHECK(st >= 0, "four-bar %d-D joints: %s", D, mrvi_model_errmsg(m));
  m->q0[mrvi_model_body_first(m, 2) + 1] += off;
  CHECK(mrvi_model_set_gravity(m, g) >= 0, "gravity: %s", mrvi_model_errmsg(m));
  if (fast) {
    const double x[3] = {1.5, 2.5, 0.0}, v[3] = {0.3, -0.2, 0.0};
    const int f = mrvi_model_add_particle(m, "f", 0.2, MRVI_FAST, x, v);
    const mrvi_end pf = {.particle = f, .body = -1},
                   cm = {.particle = -1, .body = 1, .at = {0, 0, 0}};
    const double kf = 400.0, ks = 5.0, anchor[3] = {1.5, 2.7, 0.0};
    CHECK(f >= 0 &&
              mrvi_model_add_end_spring(m, MRVI_FAST, &pf, NULL, anchor,
                                        "linear", &kf, 0.15) >= 0 &&
              mrvi_model_add_end_spring(m, MRVI_SLOW, &pf, &cm, NULL, "linear",
                                        &ks, NAN) >= 0,
          "fast particle: %s", mrvi_model_errmsg(m));
  }
  return m;
}

/* The description file rel (from the source root), or NULL (reported). */
static mrvi_system *load_system(const char *rel) {
  mrvi_system *sys = NULL;
  char msg[1024];
  if (mrvi_system_load(test_source_path(rel), NULL, 0, &sys, msg, sizeof msg) !=
      0) {
    CHECK(0, "%s loads: %s", rel, msg);
    return NULL;
  }
  return sys;
}

static mrvi_settings loop_settings(double dT, int p, double t_end,
                                   mrvi_constraint_form form) {
  mrvi_settings s = test_settings("midpoint-midpoint", dT, p, t_end, 1e-11);
  s.constraint_form = form;
  s.constraint_tol = 1e-11;
  return s;
}

/* max |g| (all rows, the redundant ones too) and max |H - H0| / |H0| over a
 * trajectory; *eH10 (may be NULL) the latter over its first tenth. */
static void loop_invariants(const mrvi_model *m, const mrvi_trajectory *tr,
                            double *eg, double *eH, double *eH10) {
  const int n = tr->n, R = mrvi_model_constraint_rows(m);
  double *g = malloc((size_t)R * sizeof *g), H0 = 0.0;
  *eg = *eH = 0.0;
  for (long k = 0; k < tr->n_macro; k++) {
    double T, V, W;
    mrvi_model_energy(m, tr->q + k * n, tr->p + k * n, &T, &V, &W);
    if (k == 0)
      H0 = T + V + W;
    *eH = fmax(*eH, fabs(T + V + W - H0) / fabs(H0));
    if (eH10 && 10 * k <= tr->n_macro)
      *eH10 = *eH;
    mrvi_model_constraint_eval(m, tr->q + k * n, g, NULL);
    for (int r = 0; r < R; r++)
      *eg = fmax(*eg, fabs(g[r]));
  }
  free(g);
}

/* The 3-D four-bar: 38 rows on 36 coordinates, rank 35. */
static void test_fourbar_3d(void) {
  mrvi_model *m = fourbar(3, 0.0, 0);
  char why[600];
  const int R = mrvi_model_constraint_rows(m);
  CHECK(R == 38, "four-bar 3-D: %d rows", R);
  /* The multiplier form refuses, naming the joints and what to do. */
  const int st = mrvi_model_check_independent(m, mrvi_model_q0(m));
  snprintf(why, sizeof why, "%s", mrvi_model_errmsg(m));
  CHECK(st == MRVI_ESINGULAR && strstr(why, "revolute") &&
            strstr(why, "null-space") && strstr(why, "2-D") &&
            strstr(why, "non-redundant joint set"),
        "four-bar 3-D refused in the multiplier form with its joints named: "
        "%s",
        why);
  mrvi_settings s = loop_settings(0.01, 1, 1.0, MRVI_FORM_MULTIPLIERS);
  mrvi_trajectory *tr = NULL;
  mrvi_summary sum;
  CHECK(mrvi_trajectory_run(m, &s, &tr, &sum) != 0 &&
            strstr(sum.message, "redundant constraints"),
        "multiplier-form run refused: %s", sum.message);
  mrvi_trajectory_free(tr);
  tr = NULL;
  /* The null-space form integrates it: 10^4 steps (also under the
   * sanitizers: the energy error's first tenth must span its swings). */
  const long n_steps = 10000;
  s = loop_settings(0.01, 1, n_steps * 0.01, MRVI_FORM_NULL_SPACE);
  if (mrvi_trajectory_run(m, &s, &tr, &sum) != 0) {
    CHECK(0, "four-bar 3-D null-space run: %s", sum.message);
  } else {
    double eg, eH, eH10 = 0.0;
    loop_invariants(m, tr, &eg, &eH, &eH10);
    /* The crank's angle at the end: it turns (a crank-rocker). */
    const double *q = tr->q + (tr->n_macro - 1) * tr->n;
    printf("four-bar 3-D (null-space): %ld steps, max |g| %.3g (all 38 rows), "
           "max relative energy error %.3g (%.3g over the first tenth), crank "
           "centre (%.3f, %.3f)\n",
           tr->n_macro - 1, eg, eH, eH10, q[0], q[1]);
    CHECK(tr->n_macro == n_steps + 1, "four-bar 3-D: %ld nodes", tr->n_macro);
    CHECK(eg <= 1e-11, "four-bar 3-D: loop closure %.3g", eg);
    /* Bounded: O(dT^2), reached early and not growing. */
    CHECK(eH < 3e-3 && eH < 1.5 * eH10,
          "four-bar 3-D: energy error %.3g (%.3g over the first tenth)", eH,
          eH10);
    /* Planar: every z coordinate of the centres stays 0. */
    double zmax = 0.0;
    for (long k = 0; k < tr->n_macro; k++)
      for (int b = 0; b < 3; b++)
        zmax = fmax(zmax, fabs(tr->q[k * tr->n + 12 * b + 2]));
    CHECK(zmax < 1e-12, "four-bar 3-D stays planar: %.3g", zmax);
  }
  mrvi_trajectory_free(tr);
  mrvi_model_free(m);
}

/* The 2-D four-bar (17 rows on 18 coordinates, independent) in 3-D and
 * 2-D agree, and both forms agree in 2-D, p in {1, 5}. */
static void test_fourbar_forms(void) {
  for (int p = 1; p <= 5; p += 4) {
    mrvi_model *m = fourbar(2, 0.0, p > 1);
    mrvi_trajectory *tr[2] = {NULL, NULL};
    mrvi_summary sum;
    for (int f = 0; f < 2; f++) {
      const mrvi_constraint_form form =
          f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
      const mrvi_settings s = loop_settings(0.01, p, 1.0, form);
      if (mrvi_trajectory_run(m, &s, &tr[f], &sum) != 0)
        CHECK(0, "four-bar 2-D (%s, p = %d): %s", form_name(form), p,
              sum.message);
    }
    if (tr[0] && tr[1]) {
      double d = 0.0;
      for (long i = 0; i < tr[0]->n_macro * tr[0]->n; i++)
        d = fmax(d, fabs(tr[0]->q[i] - tr[1]->q[i]));
      double eg, eH;
      loop_invariants(m, tr[1], &eg, &eH, NULL);
      printf("four-bar 2-D, p = %d: 100 steps, forms differ by %.3g, max |g| "
             "%.3g\n",
             p, d, eg);
      CHECK(tr[0]->n_macro == 101 && d < 1e-10,
            "four-bar 2-D p = %d: forms differ by %.3g", p, d);
      CHECK(eg <= 1e-11, "four-bar 2-D p = %d: max |g| %.3g", p, eg);
    }
    mrvi_trajectory_free(tr[0]);
    mrvi_trajectory_free(tr[1]);
    mrvi_model_free(m);
  }
  /* 3-D (redundant, null-space form) against 2-D (multipliers): the same
   * planar motion. */
  mrvi_model *m3 = fourbar(3, 0.0, 0), *m2 = fourbar(2, 0.0, 0);
  const mrvi_settings s3 = loop_settings(0.01, 1, 1.0, MRVI_FORM_NULL_SPACE),
                      s2 = loop_settings(0.01, 1, 1.0, MRVI_FORM_MULTIPLIERS);
  mrvi_trajectory *t3 = NULL, *t2 = NULL;
  mrvi_summary sum;
  if (mrvi_trajectory_run(m3, &s3, &t3, &sum) == 0 &&
      mrvi_trajectory_run(m2, &s2, &t2, &sum) == 0) {
    double d = 0.0;
    for (long k = 0; k < t2->n_macro; k++)
      for (int b = 0; b < 3; b++)
        for (int a = 0; a < 2; a++)
          d = fmax(d, fabs(t3->q[k * t3->n + 12 * b + a] -
                           t2->q[k * t2->n + 6 * b + a]));
    printf("four-bar 3-D (null-space) against 2-D (multipliers): centres "
           "differ by %.3g over 100 steps\n",
           d);
    CHECK(d < 1e-9, "four-bar 3-D against 2-D: %.3g", d);
  } else {
    CHECK(0, "four-bar 3-D / 2-D runs: %s", sum.message);
  }
  mrvi_trajectory_free(t3);
  mrvi_trajectory_free(t2);
  mrvi_model_free(m3);
  mrvi_model_free(m2);
}

/* ---------------------------------------------------------------------------
 * Projection of initial positions (doc/constraints.md, initial data).
 * ------------------------------------------------------------------------- */
static void test_projection(void) {
  /* A rod between masses 1 and 3 that start 1.001 apart: the minimal
   * M-weighted correction moves them along the rod by 0.001 * 3/4 and
   * 0.001 * 1/4. */
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 3);
  const double x1[3] = {0.2, -0.1, 0.3}, u[3] = {0.6, 0.0, 0.8},
               v0[3] = {0, 0, 0};
  double x2[3];
  for (int a = 0; a < 3; a++)
    x2[a] = x1[a] + 1.001 * u[a];
  const int i = mrvi_model_add_particle(m, "a", 1.0, MRVI_SLOW, x1, v0),
            j = mrvi_model_add_particle(m, "b", 3.0, MRVI_SLOW, x2, v0);
  CHECK(mrvi_model_add_distance(m, i, j, 1.0) >= 0, "rod: %s",
        mrvi_model_errmsg(m));
  double corr = 0.0, err = 0.0;
  CHECK(mrvi_model_project_positions(m, 1e-12, &corr, NULL) == MRVI_OK,
        "rod projected: %s", mrvi_model_errmsg(m));
  const double *q = mrvi_model_q0(m);
  for (int a = 0; a < 3; a++) {
    err = fmax(err, fabs(q[a] - (x1[a] + 0.00075 * u[a])));
    err = fmax(err, fabs(q[3 + a] - (x2[a] - 0.00025 * u[a])));
  }
  printf("projection of a rod 1.001 long onto length 1 (masses 1, 3): "
         "error against the minimal displacement %.3g, largest change %.3g\n",
         err, corr);
  CHECK(err < 1e-14, "rod projection: %.3g from the analytic one", err);
  CHECK(fabs(corr - 0.00075 * 0.8) < 1e-14, "rod projection: change %.3g",
        corr);
  mrvi_model_free(m);

  /* The 3-D four-bar with the rocker moved 1e-4 off the loop: projected onto
   * all 38 rows (3 redundant) by a change of the order of the offset. */
  m = fourbar(3, 1e-4, 0);
  const int R = mrvi_model_constraint_rows(m);
  double *g = malloc((size_t)R * sizeof *g), gmax = 0.0, g0 = 0.0;
  mrvi_model_constraint_eval(m, mrvi_model_q0(m), g, NULL);
  for (int r = 0; r < R; r++)
    g0 = fmax(g0, fabs(g[r]));
  CHECK(mrvi_model_project_positions(m, 1e-12, &corr, NULL) == MRVI_OK,
        "four-bar projected: %s", mrvi_model_errmsg(m));
  mrvi_model_constraint_eval(m, mrvi_model_q0(m), g, NULL);
  for (int r = 0; r < R; r++)
    gmax = fmax(gmax, fabs(g[r]));
  printf(
      "four-bar 3-D with the rocker 1e-4 off the loop: max |g| %.3g -> %.3g, "
      "largest change %.3g\n",
      g0, gmax, corr);
  CHECK(g0 > 1e-5 && gmax <= 1e-12, "four-bar projection: |g| %.3g", gmax);
  CHECK(corr > 1e-5 && corr < 1e-3, "four-bar projection: change %.3g", corr);
  /* And it runs from there in the null-space form. */
  const mrvi_settings s = loop_settings(0.01, 1, 0.5, MRVI_FORM_NULL_SPACE);
  mrvi_trajectory *tr = NULL;
  mrvi_summary sum;
  CHECK(mrvi_trajectory_run(m, &s, &tr, &sum) == 0, "projected run: %s",
        sum.message);
  mrvi_trajectory_free(tr);
  mrvi_model_free(m);
  free(g);

  /* Too far off (0.1): refused, naming the joints, positions unchanged. */
  m = fourbar(3, 0.1, 0);
  double before[64];
  memcpy(before, mrvi_model_q0(m), 36 * sizeof(double));
  int worst = -1;
  const int st = mrvi_model_project_positions(m, 1e-12, &corr, &worst);
  const char *msg = mrvi_model_errmsg(m);
  printf("four-bar 3-D with the rocker 0.1 off: %s\n", msg);
  CHECK(st == MRVI_EMODEL && strstr(msg, "revolute") && worst >= 0,
        "far-off four-bar refused: %s", msg);
  CHECK(memcmp(before, mrvi_model_q0(m), 36 * sizeof(double)) == 0,
        "refused projection leaves q0");
  mrvi_model_free(m);
}

/* ---------------------------------------------------------------------------
 * Universal joint (constraints/universal.c): a bar hanging from the ground
 * by a Hooke joint, its axis e1 fixed in the bar, the second axis e2 fixed
 * in the ground.  The bar may swing about e2 and about its own d1 but not
 * spin about the vertical.
 * ------------------------------------------------------------------------- */
static const double uj_M = 2.0, uj_l = 0.6, uj_th0 = 0.7;

/* The bar at angle uj_th0 about e2 from hanging down; w1 the initial
 * rate about its own d1 (a second swing); the universal joint's second
 * axis `second` (NULL: e2). */
static mrvi_model *hooke_axes(const char *type, double w1,
                              const double *second) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 3);
  const double c = cos(uj_th0), s = sin(uj_th0);
  const double R[9] = {c, 0, s, 0, 1, 0, -s, 0, c};
  const double x0[3] = {uj_l * s, 0, -uj_l * c}, J[3] = {0.05, 0.06, 0.02};
  const double w[3] = {w1 * c, 0.0, -w1 * s}; /* w1 d1 */
  double v0[3] = {w[1] * x0[2] - w[2] * x0[1], w[2] * x0[0] - w[0] * x0[2],
                  w[0] * x0[1] - w[1] * x0[0]};
  const double e1[3] = {c, 0, -s}, e2[3] = {0, 1, 0}, o[3] = {0, 0, 0},
               g[3] = {0, 0, -9.81};
  int st = mrvi_model_add_body(m, "bar", 3, MRVI_SLOW, uj_M, J, x0, R, v0, w);
  if (!strcmp(type, "universal"))
    st |=
        mrvi_model_add_joint_axes(m, type, 0, -1, o, e1, second ? second : e2);
  else
    st |= mrvi_model_add_joint(m, type, 0, -1, o, e2);
  st |= mrvi_model_set_gravity(m, g);
  CHECK(st >= 0, "%s pendulum: %s", type, mrvi_model_errmsg(m));
  return m;
}

static mrvi_model *hooke(const char *type, double w1) {
  return hooke_axes(type, w1, NULL);
}

/* Oblique axes: the second axis s = (0, cos 0.5, sin 0.5) fixed in the
 * ground makes the angle alpha with the bar's d1, cos(alpha) = d1(0) . s
 * = -sin(0.7) sin(0.5) = -0.309; the row a_1 . b_2 = cos(alpha) keeps it.
 * Checked: the gradient against central differences, the joint (all 4
 * rows) and d1 . s - cos(alpha) computed from the directors alone over
 * 10^4 steps (test_steps) in both forms, the motion leaves the perpendicular
 * joint's invariant d1 . e2 = 0 (the joint is not the perpendicular one), both
 * forms agree. */
static void test_universal_oblique(void) {
  const double s[3] = {0.0, cos(0.5), sin(0.5)};
  const double ca = -sin(uj_th0) * sin(0.5);
  mrvi_model *m = hooke_axes("universal", 3.0, s);
  const int n = mrvi_model_n(m), R = mrvi_model_constraint_rows(m);
  CHECK(R == 6 + 4, "oblique universal: %d rows (6 internal + 4)", R);
  double q[12], gp[10], gm[10], G[120], g[10], err = 0.0, gmax = 0.0;
  for (int i = 0; i < n; i++)
    q[i] = mrvi_model_q0(m)[i] + 0.1 * sin(3.1 * i + 0.4);
  mrvi_model_constraint_eval(m, q, g, G);
  for (int j = 0; j < n; j++) {
    const double h = 1e-6, q0 = q[j];
    q[j] = q0 + h;
    mrvi_model_constraint_eval(m, q, gp, NULL);
    q[j] = q0 - h;
    mrvi_model_constraint_eval(m, q, gm, NULL);
    q[j] = q0;
    for (int r = 0; r < R; r++)
      err = fmax(err, fabs((gp[r] - gm[r]) / (2 * h) - G[r * n + j]));
  }
  mrvi_model_constraint_eval(m, mrvi_model_q0(m), g, NULL);
  for (int r = 0; r < R; r++)
    gmax = fmax(gmax, fabs(g[r]));
  CHECK(err < 1e-8 && gmax < 1e-15,
        "oblique universal: gradient FD error %.3g, |g(q0)| %.3g", err, gmax);
  mrvi_trajectory *tr[2] = {NULL, NULL};
  const long n_steps = test_steps(10000);
  for (int f = 0; f < 2; f++) {
    const mrvi_settings st =
        loop_settings(0.01, 1, n_steps * 0.01,
                      f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS);
    mrvi_summary sum;
    if (mrvi_trajectory_run(m, &st, &tr[f], &sum) != 0)
      CHECK(0, "oblique universal swing: %s", sum.message);
  }
  for (int f = 0; f < 2 && tr[0] && tr[1]; f++) {
    double eg, eH, ea = 0.0, d1y = 0.0, ej = 0.0;
    loop_invariants(m, tr[f], &eg, &eH, NULL);
    for (long k = 0; k < tr[f]->n_macro; k++) {
      const double *d1 = tr[f]->q + k * n + 3;
      mrvi_model_constraint_eval(m, tr[f]->q + k * n, g, NULL);
      for (int r = 6; r < R; r++) /* the joint's rows */
        ej = fmax(ej, fabs(g[r]));
      ea = fmax(ea, fabs(d1[0] * s[0] + d1[1] * s[1] + d1[2] * s[2] - ca));
      d1y = fmax(d1y, fabs(d1[1]));
    }
    printf("oblique universal joint (cos alpha = %.4f, %s), %ld steps: max "
           "|d1 . s - cos alpha| %.3g, joint rows %.3g, all rows %.3g, "
           "energy %.3g, max |d1 . e2| %.3g\n",
           ca, form_name(f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS),
           tr[f]->n_macro - 1, ea, ej, eg, eH, d1y);
    CHECK(tr[f]->n_macro - 1 == n_steps, "oblique universal: %ld steps",
          tr[f]->n_macro - 1);
    CHECK(ea <= 1e-11 && ej <= 1e-11,
          "oblique universal: |d1 . s - cos alpha| %.3g, joint rows %.3g", ea,
          ej);
    CHECK(d1y > 0.05, "oblique universal: d1 . e2 stays %.3g", d1y);
    CHECK(eH < 1e-2, "oblique universal: energy error %.3g", eH);
  }
  if (tr[0] && tr[1]) {
    double d = 0.0;
    for (long i = 0; i < 100 * n; i++) /* the first 100 steps */
      d = fmax(d, fabs(tr[0]->q[i] - tr[1]->q[i]));
    printf("oblique universal: forms differ by %.3g over 100 steps\n", d);
    CHECK(d < 1e-10, "oblique universal: forms differ by %.3g", d);
  }
  mrvi_trajectory_free(tr[0]);
  mrvi_trajectory_free(tr[1]);
  mrvi_model_free(m);
}

/* The same joint from a description file: an oblique `second_axis` loads
 * into the row a_1 . b_2 = cos(alpha), met at the initial positions. */
static void test_universal_oblique_file(void) {
  char path[] = "/tmp/mrvi_test_loops_XXXXXX";
  const int fd = mkstemp(path);
  FILE *f = fd >= 0 ? fdopen(fd, "w") : NULL;
  CHECK(f != NULL, "temporary file");
  if (!f)
    return;
  fputs("name: oblique-hooke\n"
        "dimension: 3\n"
        "bodies:\n"
        "  - {name: bar, mass: 2, inertia: [0.05, 0.06, 0.02],\n"
        "     position: [0, 0, -0.6]}\n"
        "joints:\n"
        "  - {type: universal, bodies: [bar], point: [0, 0, 0],\n"
        "     axis: [1, 0, 0], second_axis: [0.7071067811865476, "
        "0.7071067811865476, 0]}\n"
        "integrator: {scheme: midpoint-midpoint, macro_step: 0.01,\n"
        "             t_end: 0.1}\n",
        f);
  fclose(f);
  mrvi_system *sys = NULL;
  char msg[600];
  const int st = mrvi_system_load(path, NULL, 0, &sys, msg, sizeof msg);
  remove(path);
  CHECK(st == 0, "oblique universal file loads: %s", msg);
  if (st != 0)
    return;
  const mrvi_model *m = sys->model;
  const int R = mrvi_model_constraint_rows(m), c = R == 10 ? 1 : -1;
  double g[10], gmax = 0.0;
  mrvi_model_constraint_eval(m, mrvi_model_q0(m), g, NULL);
  for (int r = 0; r < R && R == 10; r++)
    gmax = fmax(gmax, fabs(g[r]));
  const mrvi_constraint *k = c >= 0 ? &m->constraints[c] : NULL;
  const double cosine = k ? k->params[k->n_params - 1] : 0.0;
  printf("oblique universal from a file: cos alpha %.15g, |g(q0)| %.3g\n",
         cosine, gmax);
  CHECK(R == 10 && fabs(cosine - sqrt(0.5)) < 1e-15 && gmax < 1e-15,
        "oblique universal file: %d rows, cos alpha %.17g, |g(q0)| %.3g", R,
        cosine, gmax);
  mrvi_system_free(sys);
}

static void test_universal(void) {
  /* Rows and the gradient of the joint as built, against central
   * differences of g at a configuration off the initial one. */
  mrvi_model *m = hooke("universal", 0.0);
  const int n = mrvi_model_n(m), R = mrvi_model_constraint_rows(m);
  CHECK(R == 6 + 4, "universal: %d rows (6 internal + 4)", R);
  double q[12], gp[10], gm[10], G[120], g[10], err = 0.0, gmax = 0.0;
  for (int i = 0; i < n; i++)
    q[i] = mrvi_model_q0(m)[i] + 0.1 * sin(3.1 * i + 0.4);
  mrvi_model_constraint_eval(m, q, g, G);
  for (int j = 0; j < n; j++) {
    const double h = 1e-6, q0 = q[j];
    q[j] = q0 + h;
    mrvi_model_constraint_eval(m, q, gp, NULL);
    q[j] = q0 - h;
    mrvi_model_constraint_eval(m, q, gm, NULL);
    q[j] = q0;
    for (int r = 0; r < R; r++)
      err = fmax(err, fabs((gp[r] - gm[r]) / (2 * h) - G[r * n + j]));
  }
  mrvi_model_constraint_eval(m, mrvi_model_q0(m), g, NULL);
  for (int r = 0; r < R; r++)
    gmax = fmax(gmax, fabs(g[r]));
  printf("universal joint: gradient against central differences %.3g, "
         "|g(q0)| %.3g\n",
         err, gmax);
  CHECK(err < 1e-8, "universal gradient: FD error %.3g", err);
  CHECK(gmax < 1e-15, "universal joint holds at q0: %.3g", gmax);
  /* A swing about e2 stays planar: the revolute pendulum (hinge e2). */
  mrvi_model *r = hooke("revolute", 0.0);
  for (int f = 0; f < 2; f++) {
    const mrvi_constraint_form form =
        f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
    const mrvi_settings s = loop_settings(0.01, 1, 1.0, form);
    mrvi_trajectory *a = NULL, *b = NULL;
    mrvi_summary sum;
    if (mrvi_trajectory_run(m, &s, &a, &sum) == 0 &&
        mrvi_trajectory_run(r, &s, &b, &sum) == 0) {
      double d = 0.0;
      for (long i = 0; i < a->n_macro * n; i++)
        d = fmax(d, fabs(a->q[i] - b->q[i]));
      printf("universal against revolute, planar swing (%s): %.3g over 100 "
             "steps\n",
             form_name(form), d);
      CHECK(d < 1e-10, "universal planar swing (%s): %.3g", form_name(form), d);
    } else {
      CHECK(0, "universal / revolute runs (%s): %s", form_name(form),
            sum.message);
    }
    mrvi_trajectory_free(a);
    mrvi_trajectory_free(b);
  }
  mrvi_model_free(r);
  mrvi_model_free(m);
  /* Both swings at once: d1 stays normal to e2 (no spin about the
   * vertical), the joint holds, the energy is bounded; both forms agree. */
  m = hooke("universal", 3.0);
  mrvi_trajectory *tr[2] = {NULL, NULL};
  for (int f = 0; f < 2; f++) {
    const mrvi_settings s = loop_settings(
        0.01, 1, 10.0, f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS);
    mrvi_summary sum;
    if (mrvi_trajectory_run(m, &s, &tr[f], &sum) != 0)
      CHECK(0, "universal swing: %s", sum.message);
  }
  if (tr[0] && tr[1]) {
    double eg, eH, d1y = 0.0, d = 0.0, spread = 0.0;
    loop_invariants(m, tr[0], &eg, &eH, NULL);
    for (long k = 0; k < tr[0]->n_macro; k++) {
      d1y = fmax(d1y, fabs(tr[0]->q[k * n + 4]));
      spread = fmax(spread, fabs(tr[0]->q[k * n + 1]));
    }
    for (long i = 0; i < tr[0]->n_macro * n; i++)
      d = fmax(d, fabs(tr[0]->q[i] - tr[1]->q[i]));
    printf("universal joint, two swings, 1000 steps: max |d1 . e2| %.3g, "
           "max |g| %.3g, energy %.3g, max |y| of the centre %.3g, forms "
           "differ by %.3g\n",
           d1y, eg, eH, spread, d);
    CHECK(d1y <= 1e-11 && eg <= 1e-11, "universal: d1.e2 %.3g, |g| %.3g", d1y,
          eg);
    CHECK(spread > 0.05, "universal: the bar swings out of the plane (%.3g)",
          spread);
    CHECK(eH < 1e-2, "universal: energy error %.3g", eH);
    CHECK(d < 1e-8, "universal: forms differ by %.3g", d);
  }
  mrvi_trajectory_free(tr[0]);
  mrvi_trajectory_free(tr[1]);
  mrvi_model_free(m);
  /* Parallel axes are refused (also within 1e-9 of the cosine);
   * oblique ones are taken. */
  m = mrvi_model_create();
  mrvi_model_set_dimension(m, 3);
  const double x0[3] = {0, 0, -1}, J[3] = {1, 1, 1}, o[3] = {0, 0, 0},
               ex[3] = {1, 0, 0}, ex2[3] = {-2, 0, 0}, ob[3] = {1, 1, 0};
  mrvi_model_add_body(m, "b", 3, MRVI_SLOW, 1.0, J, x0, NULL, NULL, NULL);
  int st = mrvi_model_add_joint_axes(m, "universal", 0, -1, o, ex, ex2);
  CHECK(st < 0 && strstr(mrvi_model_errmsg(m), "parallel"),
        "parallel axes refused: %s", mrvi_model_errmsg(m));
  const double nearly[3] = {1, 4e-5, 0};
  st = mrvi_model_add_joint_axes(m, "universal", 0, -1, o, ex, nearly);
  CHECK(st < 0 && strstr(mrvi_model_errmsg(m), "parallel"),
        "nearly parallel axes refused: %s", mrvi_model_errmsg(m));
  st = mrvi_model_add_joint_axes(m, "universal", 0, -1, o, ex, ob);
  CHECK(st >= 0, "oblique axes (45 degrees) taken: %s", mrvi_model_errmsg(m));
  st = mrvi_model_add_joint(m, "universal", 0, -1, o, ex);
  CHECK(st < 0 && strstr(mrvi_model_errmsg(m), "needs a second axis"),
        "missing second axis refused: %s", mrvi_model_errmsg(m));
  st = mrvi_model_add_joint_axes(m, "revolute", 0, -1, o, ex, ob);
  CHECK(st < 0 && strstr(mrvi_model_errmsg(m), "takes no second axis"),
        "second axis of a revolute refused: %s", mrvi_model_errmsg(m));
  mrvi_model_free(m);
}

/* A description file whose loop (particles B, C on rods to anchors and to
 * each other) is typed to 4 digits: the loader projects it with a note. */
static void test_loader_projection(void) {
  char path[] = "/tmp/mrvi_test_loops_XXXXXX";
  const int fd = mkstemp(path);
  FILE *f = fd >= 0 ? fdopen(fd, "w") : NULL;
  CHECK(f != NULL, "temporary file");
  if (!f)
    return;
  fputs("name: typed-loop\n"
        "dimension: 2\n"
        "particles:\n"
        "  - {name: B, mass: 1, position: [0.5403, 0.8415]}\n"
        "  - {name: C, mass: 2, position: [3.0404, 2.4997], velocity: [1, 0]}\n"
        "constraints:\n"
        "  - {type: distance, name: crank, between: [B], anchor: [0, 0], "
        "length: 1}\n"
        "  - {type: distance, name: coupler, between: [B, C], length: 3}\n"
        "  - {type: distance, name: rocker, between: [C], anchor: [3, 0], "
        "length: 2.5}\n"
        "integrator: {macro_step: 0.01, t_end: 0.1}\n",
        f);
  fclose(f);
  mrvi_system *sys = NULL;
  char msg[1024] = "";
  const int st = mrvi_system_load(path, NULL, 0, &sys, msg, sizeof msg);
  unlink(path);
  CHECK(st == 0, "typed loop loads: %s", msg);
  if (st)
    return;
  double g[3];
  mrvi_model_constraint_eval(sys->model, mrvi_model_q0(sys->model), g, NULL);
  const double gmax = fmax(fabs(g[0]), fmax(fabs(g[1]), fabs(g[2])));
  printf("typed loop: note '%s', max |g| %.3g\n", sys->notes ? sys->notes : "",
         gmax);
  CHECK(sys->notes && strstr(sys->notes, "initial positions projected onto "
                                         "the constraints (largest change"),
        "typed loop: projection note: %s", sys->notes ? sys->notes : "none");
  CHECK(gmax <= 1e-12, "typed loop projected: max |g| %.3g", gmax);
  mrvi_system_free(sys);
}

/* systems/slider_crank.yaml: 10^4 steps, the loop closed to the
 * tolerance, the energy error bounded; both forms agree. */
static void test_slider_crank(void) {
  mrvi_system *sys = NULL;
  char msg[1024];
  int st = mrvi_system_load(test_source_path("systems/slider_crank.yaml"), NULL,
                            0, &sys, msg, sizeof msg);
  CHECK(st == 0, "systems/slider_crank.yaml loads: %s", msg);
  if (st)
    return;
  const mrvi_model *m = sys->model;
  mrvi_settings s = sys->settings;
  mrvi_trajectory *tr = NULL, *tn = NULL;
  mrvi_summary sum;
  if (mrvi_trajectory_run(m, &s, &tr, &sum) != 0) {
    CHECK(0, "slider-crank run: %s", sum.message);
  } else {
    double eg, eH, eH10 = 0.0, xmin = 1e300, xmax = -1e300;
    loop_invariants(m, tr, &eg, &eH, &eH10);
    const int xs = mrvi_model_body_first(m, 2);
    for (long k = 0; k < tr->n_macro; k++) {
      xmin = fmin(xmin, tr->q[k * tr->n + xs]);
      xmax = fmax(xmax, tr->q[k * tr->n + xs]);
    }
    printf("slider-crank: %ld steps, max |g| %.3g, max relative energy "
           "error %.3g (%.3g over the first tenth), slider in [%.4f, %.4f]\n",
           tr->n_macro - 1, eg, eH, eH10, xmin, xmax);
    CHECK(tr->n_macro == 10001, "slider-crank: %ld nodes", tr->n_macro);
    CHECK(eg <= s.constraint_tol, "slider-crank: loop closure %.3g", eg);
    CHECK(eH < 1e-2 && eH < 1.5 * eH10,
          "slider-crank: energy error %.3g (%.3g over the first tenth)", eH,
          eH10);
    /* The crank turns over: the slider reaches L - r and L + r. */
    CHECK(fabs(xmin - 1.0) < 1e-3 && fabs(xmax - 2.0) < 1e-3,
          "slider-crank: slider range [%.4f, %.4f]", xmin, xmax);
  }
  s.t_end = 100 * s.macro_step;
  s.constraint_form = MRVI_FORM_NULL_SPACE;
  if (tr && mrvi_trajectory_run(m, &s, &tn, &sum) == 0) {
    double d = 0.0;
    for (long i = 0; i < tn->n_macro * tn->n; i++)
      d = fmax(d, fabs(tn->q[i] - tr->q[i]));
    printf("slider-crank: forms differ by %.3g over 100 steps\n", d);
    CHECK(d < 1e-10, "slider-crank forms: %.3g", d);
  } else if (tr) {
    CHECK(0, "slider-crank null-space run: %s", sum.message);
  }
  mrvi_trajectory_free(tr);
  mrvi_trajectory_free(tn);
  mrvi_system_free(sys);
}

/* ---------------------------------------------------------------------------
 * Analytic null space of a free body (doc/multibody.md): P = [[I, 0], [0,
 * -d1^], [0, -d2^], [0, -d3^]] (2-D: [[I, 0], [0, J d1], [0, J d2]]).  G P
 * = 0 to round-off at any directors (orthonormal or not: the quadrature
 * points' are not), and P^T P = diag(I, 2 I) at orthonormal ones (full
 * column rank).
 * ------------------------------------------------------------------------- */
static void test_body_null_space(void) {
  for (int D = 2; D <= 3; D++) {
    mrvi_model *m = mrvi_model_create();
    mrvi_model_set_dimension(m, D);
    const double J[3] = {1.0, 2.0, 2.5}, x0[3] = {0.1, -0.2, 0.3},
                 w[3] = {0.5, 1.2, -0.7}, v0[3] = {0, 0, 0};
    CHECK(mrvi_model_add_body(m, "a", D, MRVI_SLOW, 2.0, D == 3 ? J : J + 2, x0,
                              NULL, v0, D == 3 ? w : w + 2) >= 0,
          "null-space body (%d-D): %s", D, mrvi_model_errmsg(m));
    const int n = D * (D + 1), R = mrvi_model_constraint_rows(m),
              nr = D == 3 ? 3 : 1;
    double q[12], g[6], G[6 * 12], P[12 * 6], gp = 0.0, gram = 0.0;
    unsigned seed = 12345u;
    for (int trial = 0; trial < 2; trial++) {
      /* Trial 0: a rotated orthonormal frame; 1: arbitrary directors. */
      const double th = 0.7, c = cos(th), sn = sin(th);
      for (int j = 0; j < n; j++) {
        seed = seed * 1103515245u + 12345u;
        q[j] = (double)(seed >> 8) / (double)(1u << 24) - 0.5;
      }
      if (trial == 0) {
        const double R3[9] = {c, -sn, 0, sn, c, 0, 0, 0, 1};
        for (int i = 0; i < D; i++)
          for (int a = 0; a < D; a++)
            q[D + D * i + a] = R3[a * 3 + i]; /* d^i = column i */
      }
      memset(P, 0, sizeof P);
      for (int a = 0; a < D; a++)
        P[a * (D + nr) + a] = 1.0;
      for (int k = 0; k < nr; k++) {
        double v[9];
        mrvi_nullspace_body_rotation(D, q + D, k, v);
        for (int j = 0; j < D * D; j++)
          P[(D + j) * (D + nr) + D + k] = v[j];
      }
      mrvi_model_constraint_eval(m, q, g, G);
      for (int r = 0; r < R; r++)
        for (int col = 0; col < D + nr; col++) {
          double s = 0.0;
          for (int j = 0; j < n; j++)
            s += G[r * n + j] * P[j * (D + nr) + col];
          gp = fmax(gp, fabs(s));
        }
      for (int a = 0; trial == 0 && a < D + nr; a++)
        for (int b = 0; b < D + nr; b++) {
          double s = 0.0;
          for (int j = 0; j < n; j++)
            s += P[j * (D + nr) + a] * P[j * (D + nr) + b];
          gram = fmax(gram, fabs(s - (a == b ? (a < D ? 1.0 : 2.0) : 0.0)));
        }
    }
    printf("free body null space (%d-D): max |G P| %.3g, max |P^T P - "
           "diag(I, 2I)| %.3g\n",
           D, gp, gram);
    CHECK(R == (D == 3 ? 6 : 3), "%d-D body: %d internal rows", D, R);
    CHECK(gp <= 1e-15, "%d-D body: |G P| %.3g", D, gp);
    CHECK(gram <= 1e-15, "%d-D body: P^T P off diag(I, 2I) by %.3g", D, gram);
    mrvi_model_free(m);
  }
}

/* ---------------------------------------------------------------------------
 * Nodal reparametrisation (doc/multibody.md): free slow bodies (3-D and
 * 2-D) in the null-space form take phi_{k+1} = phi_k + u, d_{k+1}^i =
 * exp(th^) d_k^i (2-D: R(th) d_k^i), so that their internal constraints
 * hold to round-off over 10^4 steps, with the default (loose) tolerances;
 * the multiplier form holds them to the constraint tolerance.  Both give
 * the same motion to the tolerance; tight tolerances, 100 steps: 1e-10.
 * ------------------------------------------------------------------------- */
/* Two bodies a (slow) and b of rate rb on a slow spring between body
 * points; b also on a spring of its own rate to an anchor (stiff when
 * fast) unless rb is -1 (b slow, no anchor). */
static mrvi_model *sprung_bodies(int D, int rb) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, D);
  const double J[3] = {1.0, 2.0, 2.5}, K[3] = {0.5, 0.7, 0.9},
               w[3] = {0.5, 1.2, -0.7}, w2[3] = {-2.0, 0.3, 1.1},
               x0[3] = {0.1, -0.2, 0.3}, x1[3] = {2.0, 0.5, 0.0},
               v0[3] = {0.5, 0.0, -0.25}, v1[3] = {0, 0, 0},
               R[9] = {0, -1, 0, 1, 0, 0, 0, 0, 1}, R2[4] = {0, -1, 1, 0};
  /* 2-D: the planar inertia J[2] and the angular velocity w[2]. */
  int st = mrvi_model_add_body(m, "a", D, MRVI_SLOW, 2.0, D == 3 ? J : J + 2,
                               x0, D == 3 ? R : R2, v0, D == 3 ? w : w + 2);
  const mrvi_rate rate_b = rb == MRVI_FAST ? MRVI_FAST : MRVI_SLOW;
  st |= mrvi_model_add_body(m, "b", D, rate_b, 1.0, D == 3 ? K : K + 2, x1,
                            NULL, v1, D == 3 ? w2 : w2 + 2);
  const mrvi_end a = {.particle = -1, .body = 0, .at = {0.5, 0.2, -0.1}},
                 b = {.particle = -1, .body = 1, .at = {-0.3, 0.1, 0.4}};
  const double k = 20.0;
  CHECK(st >= 0 && mrvi_model_add_end_spring(m, MRVI_SLOW, &a, &b, NULL,
                                             "linear", &k, 1.0) >= 0,
        "two sprung bodies (%d-D): %s", D, mrvi_model_errmsg(m));
  if (rb >= 0) {
    const mrvi_end c = {.particle = -1, .body = 1, .at = {0.2, -0.4, 0.3}};
    const double anchor[3] = {2.5, 1.0, 0.5}, kf = 400.0;
    CHECK(mrvi_model_add_end_spring(m, rate_b, &c, NULL, anchor, "linear", &kf,
                                    0.8) >= 0,
          "anchored body (%d-D): %s", D, mrvi_model_errmsg(m));
  }
  return m;
}

static void test_reparametrisation(void) {
  for (int D = 3; D >= 2; D--) {
    mrvi_model *m = sprung_bodies(D, -1);
    mrvi_trajectory *tr[2] = {NULL, NULL}, *tt[2] = {NULL, NULL};
    double eg[2] = {0, 0}, eH[2] = {0, 0};
    const long n_steps = test_steps(10000);
    for (int f = 0; f < 2; f++) {
      mrvi_settings s =
          test_settings("midpoint-midpoint", 0.01, 1, n_steps * 0.01, 1e-9);
      s.constraint_form = f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
      mrvi_summary sum;
      if (mrvi_trajectory_run(m, &s, &tr[f], &sum) != 0)
        CHECK(0, "reparametrisation run (%d-D, %s): %s", D,
              form_name(s.constraint_form), sum.message);
      else
        loop_invariants(m, tr[f], &eg[f], &eH[f], NULL);
      s = test_settings("midpoint-midpoint", 0.01, 1, 1.0, 1e-13);
      s.constraint_tol = 1e-13;
      s.constraint_form = f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
      if (mrvi_trajectory_run(m, &s, &tt[f], &sum) != 0)
        CHECK(0, "tight run (%d-D, %s): %s", D, form_name(s.constraint_form),
              sum.message);
    }
    if (tr[0] && tr[1]) {
      double d = 0.0;
      for (long i = 0; i < 101 * tr[0]->n; i++)
        d = fmax(d, fabs(tr[0]->q[i] - tr[1]->q[i]));
      printf("two free bodies on a spring (%d-D), %ld steps, Newton "
             "tolerance 1e-9, constraint tolerance 1e-10: max |g| %.3g "
             "(multipliers), %.3g (null space, reparametrised); energy %.3g, "
             "%.3g; forms differ by %.3g over 100 steps\n",
             D, n_steps, eg[0], eg[1], eH[0], eH[1], d);
      CHECK(eg[1] <= 1e-13, "reparametrised bodies (%d-D): max |g| %.3g", D,
            eg[1]);
      CHECK(d < 1e-8, "reparametrised against multipliers (%d-D): %.3g", D, d);
    }
    if (tt[0] && tt[1]) {
      double d = 0.0;
      for (long i = 0; i < tt[0]->n_macro * tt[0]->n; i++)
        d = fmax(d, fabs(tt[0]->q[i] - tt[1]->q[i]));
      printf("  tight tolerances (1e-13), 100 steps: forms differ by %.3g\n",
             d);
      CHECK(tt[0]->n_macro == 101 && d < 1e-10,
            "forms at tight tolerances (%d-D): %.3g", D, d);
    }
    for (int f = 0; f < 2; f++) {
      mrvi_trajectory_free(tr[f]);
      mrvi_trajectory_free(tt[f]);
    }
    mrvi_model_free(m);
  }
}

/* Largest |d_i . d_j - delta_ij| of the D directors stored from v[D]. */
static double frame_error(int D, const double *v) {
  double e = 0.0;
  for (int i = 0; i < D; i++)
    for (int j = 0; j < D; j++) {
      double s = 0.0;
      for (int a = 0; a < D; a++)
        s += v[D + D * i + a] * v[D + D * j + a];
      e = fmax(e, fabs(s - (i == j)));
    }
  return e;
}

/* Fast free bodies (doc/multibody.md): the null-space form reparametrises
 * every micro node z^1..z^p of a fast body, so its internal constraints hold
 * to round-off at every micro node over 10^4 macro steps (test_steps; loose
 * tolerances); both forms agree to 1e-10 at tight tolerances for p = 1 and
 * 5; with p = 1 the fast body gives the slow body's trajectory (the
 * single-rate scheme) to the Newton tolerance. */
static void test_fast_reparametrisation(void) {
  for (int D = 3; D >= 2; D--) {
    mrvi_model *mf = sprung_bodies(D, MRVI_FAST),
               *ms = sprung_bodies(D, MRVI_SLOW);
    const int nb = D * (D + 1);
    const long n_steps = test_steps(10000);
    mrvi_settings s =
        test_settings("midpoint-midpoint", 0.01, 5, n_steps * 0.01, 1e-9);
    s.constraint_form = MRVI_FORM_NULL_SPACE;
    mrvi_trajectory *tr = NULL;
    mrvi_summary sum;
    if (mrvi_trajectory_run(mf, &s, &tr, &sum) != 0) {
      CHECK(0, "fast body run (%d-D): %s", D, sum.message);
    } else {
      double e = 0.0;
      for (long i = 0; i < tr->n_micro; i++)
        e = fmax(e, frame_error(D, tr->micro_q + i * tr->n_fast));
      printf("fast free body (%d-D), p = 5, %ld macro steps, null space "
             "(reparametrised at micro nodes): max |d_i.d_j - delta_ij| over "
             "%ld micro nodes %.3g\n",
             D, n_steps, tr->n_micro, e);
      CHECK(tr->n_fast == nb && tr->n_micro == 5 * n_steps + 1,
            "fast body (%d-D): %d fast coordinates, %ld micro nodes", D,
            tr->n_fast, tr->n_micro);
      CHECK(e <= 1e-13, "fast body reparametrised (%d-D): %.3g", D, e);
    }
    mrvi_trajectory_free(tr);
    mrvi_trajectory *tt[3] = {NULL, NULL, NULL};
    for (int p = 1; p <= 5; p += 4) {
      for (int f = 0; f < 3; f++) { /* multipliers, null space; slow b */
        s = test_settings("midpoint-midpoint", 0.01, p, 1.0, 1e-13);
        s.constraint_tol = 1e-13;
        s.constraint_form = f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
        if ((f < 2 || p == 1) &&
            mrvi_trajectory_run(f < 2 ? mf : ms, &s, &tt[f], &sum) != 0)
          CHECK(0, "fast body, tight (%d-D, p = %d, case %d): %s", D, p, f,
                sum.message);
      }
      double d = 1e300, r = 0.0;
      if (tt[0] && tt[1]) {
        d = 0.0;
        for (long i = 0; i < tt[0]->n_macro * tt[0]->n; i++)
          d = fmax(d, fabs(tt[0]->q[i] - tt[1]->q[i]));
      }
      if (p == 1 && tt[1] && tt[2]) {
        /* Coordinates in model order: the same in both models. */
        for (long i = 0; i < tt[1]->n_macro * tt[1]->n; i++)
          r = fmax(r, fabs(tt[1]->q[i] - tt[2]->q[i]));
        printf("  p = 1: fast body against the same body slow %.3g\n", r);
        CHECK(r < 1e-11, "p = 1 reduction (%d-D): %.3g", D, r);
      }
      printf("  fast body (%d-D), p = %d, tight tolerances, 100 steps: forms "
             "differ by %.3g\n",
             D, p, d);
      CHECK(d < 1e-10, "fast body forms (%d-D, p = %d): %.3g", D, p, d);
      for (int f = 0; f < 3; f++) {
        mrvi_trajectory_free(tt[f]);
        tt[f] = NULL;
      }
    }
    mrvi_model_free(mf);
    mrvi_model_free(ms);
  }
}

/* The trees' fast particle: at l, on a fast linear spring (200) to anchor
 * and a slow one (50) to body b's point (0.5, 0, 0); st the status so far.
 * Returns the status. */
static int add_fast_particle(mrvi_model *m, int st, int b, const double *l,
                             const double *anchor) {
  const double v[3] = {0.0, 0.0, 0.0}, kf = 200.0, ks = 50.0;
  const int f =
      st >= 0 ? mrvi_model_add_particle(m, "l", 0.05, MRVI_FAST, l, v) : st;
  const mrvi_end pf = {.particle = f, .body = -1},
                 pb = {.particle = -1, .body = b, .at = {0.5, 0, 0}};
  if (f < 0)
    return f;
  st = mrvi_model_add_end_spring(m, MRVI_FAST, &pf, NULL, anchor, "linear", &kf,
                                 NAN);
  return st < 0 ? st
                : mrvi_model_add_end_spring(m, MRVI_SLOW, &pb, &pf, NULL,
                                            "linear", &ks, NAN);
}

/* Open chains and trees of bodies in joints (doc/multibody.md, "Joint-
 * reduced null space for chains and trees").  2-D: n bars of length 1 on
 * revolute joints, a chain from the ground along e = (1, -1)/sqrt 2, with a
 * last bar hung on the second's lower end (a tree) and a fast particle on a
 * slow spring to the last bar's end and a fast one to an anchor.  3-D: a
 * ball joint to the ground, then revolute (axis e_3), ball, weld and
 * revolute (axis (1, 1, 0)) joints along e = (1, 0.5, -1)/1.5, and a
 * branch on a ball joint at the second body's centre. */
static mrvi_model *jointed_tree_rate(int D, int n, mrvi_rate rate) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, D);
  const double e2[2] = {sqrt(0.5), -sqrt(0.5)},
               e3[3] = {1.0 / 1.5, 0.5 / 1.5, -1.0 / 1.5};
  const double *e = D == 2 ? e2 : e3, J2[1] = {2.0 / 12.0},
               J3[3] = {0.1, 0.5, 0.55}, w2[1] = {0.7},
               w3[3] = {0.2, -0.3, 0.5};
  const double ax1[3] = {0, 0, 1}, ax2[3] = {sqrt(0.5), sqrt(0.5), 0};
  static const char *const kinds3[] = {"spherical", "revolute", "spherical",
                                       "weld", "revolute"};
  int st = 0, prev = -1;
  for (int i = 0; i <= n && st >= 0; i++) {
    /* body i < n on the chain; body n the branch on body 1 */
    const int br = i == n;
    double x[3], pt[3];
    for (int a = 0; a < D; a++) {
      pt[a] = br ? (D == 2 ? 2.0 : 1.5) * e[a] : i * e[a];
      x[a] = pt[a] + 0.5 * e[a] + (br ? 0.3 * (a == 0) : 0.0);
    }
    char name[16];
    snprintf(name, sizeof name, "b%d", i);
    const int b = st =
        mrvi_model_add_body(m, name, D, rate, 2.0 + 0.1 * i, D == 2 ? J2 : J3,
                            x, NULL, NULL, i == 0 ? (D == 2 ? w2 : w3) : NULL);
    if (st < 0)
      break;
    const int parent = br ? 1 : prev;
    const char *kind = D == 2 ? "revolute" : br ? "spherical" : kinds3[i % 5];
    const double *axis = D == 2 || strcmp(kind, "revolute") ? NULL
                         : i % 5 == 1                       ? ax1
                                                            : ax2;
    /* the joint point: the chain's i e; the branch at the end of body 1 */
    st = mrvi_model_add_joint(m, kind, b, parent, pt, axis);
    prev = b;
  }
  const double g[3] = {0.0, D == 2 ? -9.81 : 0.0, D == 3 ? -9.81 : 0.0};
  if (st >= 0)
    st = mrvi_model_set_gravity(m, g);
  double l[3] = {0, 0, 0}, anchor[3] = {0, 0, 0};
  for (int a = 0; a < D; a++)
    l[a] = n * e[a] + (a == 1 ? -0.2 : 0.0), anchor[a] = l[a] + 0.5;
  CHECK(add_fast_particle(m, st, n - 1, l, anchor) >= 0,
        "jointed tree (%d-D): %s", D, mrvi_model_errmsg(m));
  return m;
}

static mrvi_model *jointed_tree(int D, int n) {
  return jointed_tree_rate(D, n, MRVI_SLOW);
}

/* Size of the step's system on the general path in the null-space form
 * (tree: the joint-reduced basis allowed). */
static int ns_size(const mrvi_model *m, int tree) {
  mrvi_settings s = test_settings("midpoint-midpoint", 0.01, 2, 1.0, 1e-9);
  s.constraint_form = MRVI_FORM_NULL_SPACE;
  s.tuning.nullspace_tree = tree;
  mrvi_integrator *it = NULL;
  char msg[512];
  if (mrvi_integrator_create(m, &s, &it, msg, sizeof msg) < 0) {
    CHECK(0, "jointed tree integrator: %s", msg);
    return -1;
  }
  const int n = mrvi_integrator_system_size(it);
  mrvi_integrator_free(it);
  return n;
}

/* The joint-reduced basis on a tree (doc/multibody.md, "Joint-reduced null
 * space for chains and trees"): it is taken (the step's system carries one
 * twist per body beside the QR basis's unknowns); over 100 steps of 0.01
 * (p = 2) at Newton and constraint tolerances tol it gives the trajectory
 * of the multiplier form and of the QR basis to within agree; over t_long
 * (test_steps of its steps) at Newton tolerance 1e-9 the constraints hold to
 * 1e-13 (the nodal reparametrisation keeps them at round-off, the forms that do
 * not only at the tolerance: printed for contrast with qr_long) with a bounded
 * energy error, no worse than the multiplier form's if vs_multipliers. */
typedef struct tree_case {
  const char *name;
  int nb;
  double tol, agree, t_long;
  int vs_multipliers, qr_long;
} tree_case;

static void check_joint_reduced(mrvi_model *m, int D, const tree_case *c) {
  const int T = D * (D + 1) / 2;
  const int nt = ns_size(m, 1), nq = ns_size(m, 0);
  CHECK(nq > 0 && nt == nq + c->nb * T,
        "%s (%d-D): system %d (joint-reduced) against %d (QR)", c->name, D, nt,
        nq);
  mrvi_trajectory *tt[3] = {NULL, NULL, NULL};
  for (int f = 0; f < 3; f++) {
    mrvi_settings s = test_settings("midpoint-midpoint", 0.01, 2, 1.0, c->tol);
    s.constraint_tol = c->tol;
    s.constraint_form = f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
    s.tuning.nullspace_tree = f == 1;
    mrvi_summary sum;
    if (mrvi_trajectory_run(m, &s, &tt[f], &sum) != 0)
      CHECK(0, "%s, tight (%d-D, case %d): %s", c->name, D, f, sum.message);
  }
  double d[2] = {0.0, 0.0};
  if (tt[0] && tt[1] && tt[2])
    for (long i = 0; i < tt[0]->n_macro * tt[0]->n; i++) {
      d[0] = fmax(d[0], fabs(tt[1]->q[i] - tt[0]->q[i]));
      d[1] = fmax(d[1], fabs(tt[1]->q[i] - tt[2]->q[i]));
    }
  printf("%s (%d-D, %d bodies), 100 steps at tolerances %.0e: joint-reduced "
         "null space against multipliers %.3g, against the QR null space "
         "%.3g\n",
         c->name, D, c->nb, c->tol, d[0], d[1]);
  CHECK(tt[0] && tt[0]->n_macro == 101 && d[0] < c->agree && d[1] < c->agree,
        "%s (%d-D), joint-reduced against the other forms: %.3g, %.3g", c->name,
        D, d[0], d[1]);
  for (int f = 0; f < 3; f++)
    mrvi_trajectory_free(tt[f]);
  /* default tolerances: joint-reduced (0), multipliers (1), QR basis (2) */
  mrvi_trajectory *tr[3] = {NULL, NULL, NULL};
  double eg[3] = {1, 1, 1}, eH[3] = {1, 1, 1}, eH10[3] = {1, 1, 1};
  const long n_long = test_steps(lround(c->t_long / 0.01));
  for (int f = 0; f < 3; f++) {
    if ((f == 1 && !c->vs_multipliers) || (f == 2 && !c->qr_long))
      continue;
    mrvi_settings s =
        test_settings("midpoint-midpoint", 0.01, 2, n_long * 0.01, 1e-9);
    s.constraint_form = f == 1 ? MRVI_FORM_MULTIPLIERS : MRVI_FORM_NULL_SPACE;
    s.tuning.nullspace_tree = f == 0;
    mrvi_summary sum;
    if (mrvi_trajectory_run(m, &s, &tr[f], &sum) != 0)
      CHECK(0, "%s run (%d-D, case %d): %s", c->name, D, f, sum.message);
    else
      loop_invariants(m, tr[f], &eg[f], &eH[f], &eH10[f]);
    mrvi_trajectory_free(tr[f]);
  }
  printf("  %ld steps, Newton tolerance 1e-9: max |g| %.3g, energy %.3g",
         n_long, eg[0], eH[0]);
  if (c->qr_long)
    printf(" (QR null space: max |g| %.3g)", eg[2]);
  if (c->vs_multipliers)
    printf(" (multipliers: max |g| %.3g, energy %.3g; first tenth %.3g, "
           "%.3g)",
           eg[1], eH[1], eH10[0], eH10[1]);
  printf("\n");
  CHECK(eg[0] <= 1e-13, "%s (%d-D), joint-reduced: max |g| %.3g", c->name, D,
        eg[0]);
  CHECK(eH[0] < 0.05 && (!c->vs_multipliers || eH[0] < 1.5 * eH[1] + 1e-6),
        "%s (%d-D), joint-reduced: energy %.3g (multipliers %.3g)", c->name, D,
        eH[0], eH[1]);
}

static void test_joint_reduced(void) {
  for (int D = 2; D <= 3; D++) {
    const int n = D == 2 ? 7 : 6;
    mrvi_model *m = jointed_tree(D, n);
    const tree_case c = {"jointed tree", n + 1, 1e-12, 1e-9, 30.0, 1, 0};
    check_joint_reduced(m, D, &c);
    mrvi_model_free(m);
  }
}

/* Newton updates per step along a long chain (doc/performance/chains.md,
 * "Chains: the ordering and the settled start"): the 2-D jointed tree of 100
 * bars, 10 steps (p = 2) at the tolerances of bench_chain, each form with and
 * without tuning predict_settle.  The predictor leaves the constraint forces
 * out: it violates the joints by about its error.  From it, the multiplier
 * form's first update has to absorb that violation; the joint-reduced form
 * turns each bar to the predictor's frame and places it on its parent's
 * joint point, which sets the chain's far end off by the sum of the turns'
 * errors above it.  Moved onto the constraints nearest in the mass metric
 * (a move in the range of M^-1 G^T, which the multipliers absorb), the
 * start keeps the predictor's accuracy along the constraints, and each
 * form needs at least half an update per step less; the joint-reduced form
 * then two, as on a chain of 10 bars. */
static void test_joint_reduced_long_chain(void) {
  mrvi_model *m = jointed_tree(2, 100);
  double per[2][2] = {{0.0, 0.0}, {0.0, 0.0}}; /* [form][settle] */
  for (int f = 0; f < 2; f++)
    for (int on = 0; on < 2; on++) {
      mrvi_settings s = test_settings("midpoint-midpoint", 0.01, 2, 0.1, 1e-10);
      s.constraint_tol = 1e-10;
      s.constraint_form = f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
      s.tuning.predict_settle = on;
      mrvi_summary sum;
      if (mrvi_run(m, &s, NULL, NULL, NULL, &sum) != 0)
        CHECK(0, "long chain (%s): %s", form_name(s.constraint_form),
              sum.message);
      else
        per[f][on] = (double)sum.iterations_total / (double)sum.steps;
    }
  printf("jointed chain of 100 bars, 10 steps: Newton updates per step "
         "%.2f (joint-reduced null space; %.2f from the predictor), %.2f "
         "(multipliers; %.2f from the predictor)\n",
         per[1][1], per[1][0], per[0][1], per[0][0]);
  for (int f = 0; f < 2; f++)
    CHECK(per[f][1] > 0.0 && per[f][1] <= per[f][0] - 0.5,
          "long chain (%s): %.2f updates per step from the settled "
          "predictor, %.2f from the predictor",
          f ? "joint-reduced" : "multipliers", per[f][1], per[f][0]);
  CHECK(per[1][1] <= 2.0, "long chain, joint-reduced: %.2f updates per step",
        per[1][1]);
  mrvi_model_free(m);
}

/* Trees with weld joints (doc/multibody.md, "Joint-reduced null space for
 * chains and trees"), in the plane z = 0: bar b0 on a joint to the ground
 * along e = (1, -1)/sqrt 2; b1 welded to b0's end, bent along e1; b2 on a
 * joint at b1's end; a branch b3 on a joint at b0's centre, hanging along
 * -e2, and b4 welded to b3's end, bent along e; a second root b5 welded to
 * the ground with b6 on a joint at its end; a fast particle on a slow spring
 * to a point of b2 and a fast one to an anchor.  b0 and b6 turn initially.
 * 2-D: the joints other than welds revolute.  3-D: b0 and b3 on ball
 * joints, b2 on a hinge about (1, 1, 1)/sqrt 3, b6 about e3. */
static mrvi_model *welded_tree(int D) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, D);
  const double J2[1] = {2.0 / 12.0}, J3[3] = {0.1, 0.5, 0.55},
               w2[2][1] = {{0.7}, {-0.4}},
               w3[2][3] = {{0.2, -0.3, 0.5}, {0.0, 0.0, -0.4}};
  const double s3 = 0.57735026918962576, axes[2][3] = {{s3, s3, s3}, {0, 0, 1}};
  /* joint point, bar direction, parent (-1: the ground), kind in 3-D (2-D:
   * revolute unless a weld), hinge axis in 3-D */
  static const struct {
    double pt[3], dir[3];
    int parent;
    const char *kind3;
    int axis;
  } bar[] = {{{0, 0, 0},
              {0.70710678118654752, -0.70710678118654752, 0},
              -1,
              "spherical",
              -1},
             {{0.70710678118654752, -0.70710678118654752, 0},
              {1, 0, 0},
              0,
              "weld",
              -1},
             {{1.70710678118654752, -0.70710678118654752, 0},
              {0.70710678118654752, -0.70710678118654752, 0},
              1,
              "revolute",
              0},
             {{0.35355339059327376, -0.35355339059327376, 0},
              {0, -1, 0},
              0,
              "spherical",
              -1},
             {{0.35355339059327376, -1.35355339059327376, 0},
              {0.70710678118654752, -0.70710678118654752, 0},
              3,
              "weld",
              -1},
             {{3.0, 0.0, 0}, {0, -1, 0}, -1, "weld", -1},
             {{3.0, -1.0, 0}, {1, 0, 0}, 5, "revolute", 1}};
  int st = 0;
  for (int i = 0; i < (int)(sizeof bar / sizeof bar[0]) && st >= 0; i++) {
    const double x[3] = {bar[i].pt[0] + 0.5 * bar[i].dir[0],
                         bar[i].pt[1] + 0.5 * bar[i].dir[1], 0.0};
    const int turns = i == 0 ? 0 : i == 6 ? 1 : -1;
    const double *w = turns < 0 ? NULL : D == 2 ? w2[turns] : w3[turns];
    char name[16];
    snprintf(name, sizeof name, "b%d", i);
    st = mrvi_model_add_body(m, name, D, MRVI_SLOW, 2.0 + 0.1 * i,
                             D == 2 ? J2 : J3, x, NULL, NULL, w);
    const int weld = !strcmp(bar[i].kind3, "weld");
    const char *kind = D == 3 ? bar[i].kind3 : weld ? "weld" : "revolute";
    const double *axis = D == 3 && bar[i].axis >= 0 ? axes[bar[i].axis] : NULL;
    if (st >= 0)
      st = mrvi_model_add_joint(m, kind, st, bar[i].parent, bar[i].pt, axis);
  }
  const double g[3] = {0.0, -9.81, 0.0};
  if (st >= 0)
    st = mrvi_model_set_gravity(m, g);
  const double l[3] = {2.4, -1.6, 0.1}, anchor[3] = {2.9, -1.1, 0.2};
  CHECK(add_fast_particle(m, st, 2, l, anchor) >= 0, "welded tree (%d-D): %s",
        D, mrvi_model_errmsg(m));
  return m;
}

static void test_joint_reduced_weld(void) {
  for (int D = 2; D <= 3; D++) {
    mrvi_model *m = welded_tree(D);
    const tree_case c = {"welded tree", 7, 1e-13, 1e-11, 10.0, 0, 0};
    check_joint_reduced(m, D, &c);
    mrvi_model_free(m);
  }
}

/* Trees of the joints with translations and of the cross, in the plane
 * z = 0 (doc/multibody.md, "Joint-reduced null space for chains and
 * trees"): bar b0 on the joint `kind` to the ground at 0; b1 on a ball
 * (2-D: revolute) joint at b0's end, turning; b2 on `kind` at b1's end with
 * b2 the joint's body B (the child carries the frame b_m); b3 on `kind` at
 * b1's centre with b3 its body A (the parent carries b_m), turning; a fast
 * particle on a slow spring to a point of b2 and a fast one to an anchor;
 * gravity -e2.  The axes (and a universal's second axes, oblique at the
 * ground) are out of the plane in 3-D. */
static mrvi_model *kind_tree(int D, const char *kind) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, D);
  const double J2[1] = {2.0 / 12.0}, J3[3] = {0.1, 0.5, 0.55},
               w2[2][1] = {{0.7}, {-0.4}},
               w3[2][3] = {{0.2, -0.3, 0.5}, {0.0, 0.3, -0.4}};
  static const struct {
    double pt[3], dir[3], axis2[2], axis3[3], second[3];
    int parent, child_is_b;
  } bar[] = {
      {{0, 0, 0},
       {0.6, -0.8, 0},
       {0.6, -0.8},
       {0.48, -0.64, 0.6},
       {0, 0, 1},
       -1,
       0},
      {{0.6, -0.8, 0}, {1, 0, 0}, {0, 0}, {0, 0, 0}, {0, 0, 0}, 0, 0},
      {{1.6, -0.8, 0}, {0, -1, 0}, {0.8, -0.6}, {0, 0.6, 0.8}, {1, 0, 0}, 1, 1},
      {{1.1, -0.8, 0},
       {0.6, -0.8, 0},
       {1, 0},
       {0.8, 0, -0.6},
       {0, 1, 0},
       1,
       0}};
  int st = 0, b[4];
  for (int i = 0; i < 4 && st >= 0; i++) {
    const double x[3] = {bar[i].pt[0] + 0.5 * bar[i].dir[0],
                         bar[i].pt[1] + 0.5 * bar[i].dir[1], 0.0};
    const double *w =
        i == 1 || i == 3 ? (D == 2 ? w2[i / 2] : w3[i / 2]) : NULL;
    char name[16];
    snprintf(name, sizeof name, "b%d", i);
    st = b[i] = mrvi_model_add_body(m, name, D, MRVI_SLOW, 2.0 + 0.1 * i,
                                    D == 2 ? J2 : J3, x, NULL, NULL, w);
    if (st < 0)
      break;
    const int pa = bar[i].parent < 0 ? -1 : b[bar[i].parent];
    if (i == 1) {
      st = mrvi_model_add_joint(m, D == 2 ? "revolute" : "spherical", b[i], pa,
                                bar[i].pt, NULL);
      continue;
    }
    const double *axis = D == 2 ? bar[i].axis2 : bar[i].axis3;
    const int A = bar[i].child_is_b ? pa : b[i],
              B = bar[i].child_is_b ? b[i] : pa;
    st = mrvi_model_add_joint_axes(m, kind, A, B, bar[i].pt, axis,
                                   strcmp(kind, "universal") ? NULL
                                                             : bar[i].second);
  }
  /* slow springs from b0, b2, b3 to points above them keep the slides
   * bounded (a row r . b_n is as large as r times its round-off) */
  for (int i = 0; i < 4 && st >= 0; i++) {
    const mrvi_end e = {.particle = -1, .body = b[i], .at = {0, 0, 0}};
    const double k = 20.0,
                 up[3] = {bar[i].pt[0] + 0.5 * bar[i].dir[0],
                          bar[i].pt[1] + 0.5 * bar[i].dir[1] + 1.0, 0.0};
    if (i != 1)
      st = mrvi_model_add_end_spring(m, MRVI_SLOW, &e, NULL, up, "linear", &k,
                                     NAN);
  }
  const double g[3] = {0.0, -9.81, 0.0};
  if (st >= 0)
    st = mrvi_model_set_gravity(m, g);
  const double l[3] = {2.2, -1.5, 0.1}, anchor[3] = {2.7, -1.0, 0.2};
  CHECK(add_fast_particle(m, st, 2, l, anchor) >= 0, "%s tree (%d-D): %s", kind,
        D, mrvi_model_errmsg(m));
  return m;
}

static void test_joint_reduced_kinds(void) {
  static const struct {
    const char *kind;
    int D;
  } cases[] = {{"prismatic", 2},
               {"prismatic", 3},
               {"cylindrical", 3},
               {"universal", 3},
               {"planar", 3}};
  for (int i = 0; i < (int)(sizeof cases / sizeof cases[0]); i++) {
    mrvi_model *m = kind_tree(cases[i].D, cases[i].kind);
    char name[32];
    snprintf(name, sizeof name, "%s tree", cases[i].kind);
    const tree_case c = {name, 4, 1e-13, 1e-11, 10.0, 0, 1};
    check_joint_reduced(m, cases[i].D, &c);
    mrvi_model_free(m);
  }
}

/* ---------------------------------------------------------------------------
 * Fast bodies in joints (doc/multibody.md, "Fast bodies in joints"): the
 * joint-reduced basis and nodal reparametrisation at the micro nodes, on
 * systems/flexible_pendulum.yaml and systems/spacecraft.yaml (fast trees
 * on a slow body's joint, their moving ground) and on the trees of
 * jointed_tree made fast (on the ground).
 * ------------------------------------------------------------------------- */

/* max |g| of the rows enforced at the micro nodes (micro-node constraints,
 * the slow coordinates interpolated as the step does) over every micro node
 * of tr (p micro steps), and of the other rows at the macro nodes (*eslow,
 * may be NULL); *eint (may be NULL): the first over the bodies' internal
 * rows alone. */
static double micro_residual_int(const mrvi_model *m, const mrvi_trajectory *tr,
                                 int p, double *eslow, double *eint) {
  const int n = tr->n, R = mrvi_model_constraint_rows(m);
  double *q = malloc((size_t)n * sizeof *q), *g = malloc((size_t)R * sizeof *g);
  double e = 0.0, es = 0.0, ei = 0.0;
  for (long i = 0; q && g && i < tr->n_micro; i++) {
    const long k = i / p;
    const double a1 = (double)(i % p) / p;
    for (int c = 0; c < n; c++) {
      const double *qk = tr->q + k * n + c;
      q[c] = a1 > 0.0 ? (1.0 - a1) * qk[0] + a1 * qk[n] : qk[0];
      if (m->rate[c] == MRVI_FAST)
        q[c] = tr->micro_q[i * tr->n_fast + m->slot[c]];
    }
    mrvi_model_constraint_eval(m, q, g, NULL);
    for (int c = 0; c < m->n_constraints; c++) {
      const mrvi_constraint *k = &m->constraints[c];
      int internal = 0;
      for (int b = 0; b < m->n_bodies; b++)
        internal |= m->bodies[b].constraint == c;
      for (int r = 0; r < k->rows; r++) {
        const double v = fabs(g[k->first_row + r]);
        if (k->where == MRVI_FAST)
          e = fmax(e, v);
        else if (i % p == 0)
          es = fmax(es, v);
        if (internal && k->where == MRVI_FAST)
          ei = fmax(ei, v);
      }
    }
  }
  free(q), free(g);
  if (eslow)
    *eslow = es;
  if (eint)
    *eint = ei;
  return e;
}

/* max |g| of the micro-node rows over every micro node (*eslow: the slow
 * rows at the macro nodes). */
static double micro_residual(const mrvi_model *m, const mrvi_trajectory *tr,
                             int p, double *eslow) {
  return micro_residual_int(m, tr, p, eslow, NULL);
}

/* On model m (dT its macro step): both forms agree at tolerances 1e-13 over
 * 100 macro steps (run lengths: test_steps) with the joint-reduced basis at the
 * micro nodes and with the QR basis (nullspace_tree 0), p = 1 and 5; over
 * n_long macro steps (p = 10) at Newton tolerance 1e-9 and constraint tolerance
 * 1e-10 the micro-node constraints hold to 1e-13 with the reparametrisation
 * (the QR basis only to the tolerance, printed over 100 steps); so do the slow
 * bodies' constraints at the macro nodes (free slow bodies reparametrised,
 * or slow bodies in joints placed on their joints). */
static void check_fast_forest(const char *name, const mrvi_model *m, double dT,
                              int n_long) {
  const long n_short = test_steps(100);
  n_long = (int)test_steps(n_long);
  for (int p = 1; p <= 5; p += 4) {
    mrvi_trajectory *tt[3] = {NULL, NULL, NULL};
    for (int f = 0; f < 3; f++) { /* multipliers, joint-reduced, QR */
      mrvi_settings s =
          test_settings("midpoint-midpoint", dT, p, n_short * dT, 1e-13);
      s.constraint_tol = 1e-13;
      s.constraint_form = f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
      s.tuning.nullspace_tree = f == 1;
      mrvi_summary sum;
      if (mrvi_trajectory_run(m, &s, &tt[f], &sum) != 0)
        CHECK(0, "%s, tight (p = %d, case %d): %s", name, p, f, sum.message);
    }
    double d[2] = {1e300, 1e300};
    if (tt[0] && tt[1] && tt[2]) {
      d[0] = d[1] = 0.0;
      for (long i = 0; i < tt[0]->n_macro * tt[0]->n; i++) {
        d[0] = fmax(d[0], fabs(tt[1]->q[i] - tt[0]->q[i]));
        d[1] = fmax(d[1], fabs(tt[1]->q[i] - tt[2]->q[i]));
      }
    }
    printf("%s, p = %d, %ld steps at tolerances 1e-13: fast joint-reduced "
           "null space against multipliers %.3g, against the QR null space "
           "%.3g\n",
           name, p, n_short, d[0], d[1]);
    CHECK(tt[0] && tt[0]->n_macro == n_short + 1 && d[0] < 1e-10 &&
              d[1] < 1e-10,
          "%s (p = %d): forms differ by %.3g, %.3g", name, p, d[0], d[1]);
    for (int f = 0; f < 3; f++)
      mrvi_trajectory_free(tt[f]);
  }
  double e[2] = {1.0, 1.0}, es[2] = {1.0, 1.0};
  const long n_steps[2] = {n_long, n_short}; /* the QR basis: for contrast */
  for (int f = 0; f < 2; f++) {              /* joint-reduced, QR */
    mrvi_settings s =
        test_settings("midpoint-midpoint", dT, 10, n_steps[f] * dT, 1e-9);
    s.constraint_tol = 1e-10;
    s.constraint_form = MRVI_FORM_NULL_SPACE;
    s.tuning.nullspace_tree = f == 0;
    mrvi_trajectory *tr = NULL;
    mrvi_summary sum;
    if (mrvi_trajectory_run(m, &s, &tr, &sum) != 0)
      CHECK(0, "%s run (case %d): %s", name, f, sum.message);
    else
      e[f] = micro_residual(m, tr, 10, &es[f]);
    CHECK(!tr || tr->n_micro == 10L * n_steps[f] + 1, "%s: %ld micro nodes",
          name, tr ? tr->n_micro : 0L);
    mrvi_trajectory_free(tr);
  }
  printf("  %d micro nodes (p = 10), Newton tolerance 1e-9: micro-node "
         "constraints max |g| %.3g (QR basis, %ld micro nodes: %.3g); "
         "slow-only rows at the macro nodes %.3g (QR basis %.3g)\n",
         10 * n_long, e[0], 10 * n_short, e[1], es[0], es[1]);
  CHECK(e[0] <= 1e-13, "%s: micro-node constraints %.3g", name, e[0]);
  CHECK(es[0] <= 1e-13, "%s: the slow bodies' constraints %.3g", name, es[0]);
}

/* The fast forest's multipliers and slow coupling by the Gram matrix
 * G_f G_f^T (tuning nullspace_gram_min 0, the default) against the QR of
 * G_f (257): the same least-squares quantities, so over `steps` macro
 * steps at tolerances 1e-12 (p = 5) the trajectories agree to 1e-10. */
static void check_gram_vs_qr(const char *name, const mrvi_model *m, double dT,
                             int steps) {
  mrvi_trajectory *tt[2] = {NULL, NULL};
  for (int f = 0; f < 2; f++) {
    mrvi_settings s =
        test_settings("midpoint-midpoint", dT, 5, steps * dT, 1e-12);
    s.constraint_tol = 1e-12;
    s.constraint_form = MRVI_FORM_NULL_SPACE;
    s.tuning.nullspace_gram_min = f ? 0 : 257;
    mrvi_summary sum;
    if (mrvi_trajectory_run(m, &s, &tt[f], &sum) != 0)
      CHECK(0, "%s (%s): %s", name, f ? "Gram" : "QR", sum.message);
  }
  double d = INFINITY, qm = 0.0;
  if (tt[0] && tt[1] && tt[0]->n_macro == tt[1]->n_macro) {
    d = 0.0;
    for (long i = 0; i < tt[0]->n_macro * tt[0]->n; i++) {
      d = fmax(d, fabs(tt[1]->q[i] - tt[0]->q[i]));
      qm = fmax(qm, fabs(tt[0]->q[i]));
    }
  }
  printf("  %s: Gram against QR multipliers, %d steps (p = 5, tolerances "
         "1e-12): max |q| difference %.3g (max |q| %.3g)\n",
         name, steps, d, qm);
  CHECK(d <= 1e-10, "%s: Gram against QR: %.3g", name, d);
  mrvi_trajectory_free(tt[0]);
  mrvi_trajectory_free(tt[1]);
}

static void test_fast_joint_reduced(void) {
  static const char *const files[] = {"systems/flexible_pendulum.yaml",
                                      "systems/spacecraft.yaml"};
  for (int i = 0; i < 2; i++) {
    mrvi_system *sys = NULL;
    char msg[1024], why[200] = "";
    int st = mrvi_system_load(test_source_path(files[i]), NULL, 0, &sys, msg,
                              sizeof msg);
    CHECK(st == 0, "%s loads: %s", files[i], msg);
    if (st)
      continue;
    CHECK(mrvi_nullspace_fast_plan(sys->model, why, sizeof why),
          "%s: fast forest planned (%s)", files[i], why);
    /* the spacecraft's null-space step (general path, 72 fast coordinates
     * per node) is far dearer than the pendulum's (doc/performance/kernels.md,
     * "Fast bodies in joints"): 1 000 micro nodes */
    check_fast_forest(files[i], sys->model, sys->settings.macro_step,
                      i == 1 ? 100 : 1000);
    check_gram_vs_qr(files[i], sys->model, sys->settings.macro_step,
                     i == 1 ? 20 : 100);
    mrvi_system_free(sys);
  }
  for (int D = 2; D <= 3; D++) {
    mrvi_model *m = jointed_tree_rate(D, 4, MRVI_FAST);
    char why[200] = "", name[64];
    snprintf(name, sizeof name, "fast tree on the ground (%d-D)", D);
    CHECK(mrvi_nullspace_fast_plan(m, why, sizeof why), "%s planned (%s)", name,
          why);
    check_fast_forest(name, m, 0.01, 1000);
    check_gram_vs_qr(name, m, 0.01, 100);
    mrvi_model_free(m);
  }
}

/* ---------------------------------------------------------------------------
 * The joint-reduced null space of closed loops (doc/multibody.md,
 * "Joint-reduced null space of closed loops"): the joint closing the loop is
 * cut, the spanning tree's basis P_tree restricted by the cut rows, P =
 * P_tree N.  Its system carries one twist per body and one unknown per kept
 * cut row beside the QR basis's unknowns (the 3-D four-bar's cut hinge keeps
 * 2 of its 5 rows: 3 are redundant); both bases solve the same discrete
 * null-space equations, so over 100 steps at tolerances 1e-12 they agree
 * to about the tolerance; over 10^4 steps the loop holds to the Newton
 * tolerance (the cut rows) and below.
 * ------------------------------------------------------------------------- */
static void check_loop_reduced(const char *name, const mrvi_model *m, int D,
                               int p, int rc, double dT) {
  const int T = D * (D + 1) / 2, nb = mrvi_model_n_bodies(m);
  const int nt = ns_size(m, 1), nq = ns_size(m, 0);
  CHECK(nq > 0 && nt == nq + nb * T + rc,
        "%s: system %d (loop-reduced) against %d (QR), %d bodies, %d cut rows",
        name, nt, nq, nb, rc);
  mrvi_trajectory *tt[2] = {NULL, NULL};
  for (int f = 0; f < 2; f++) {
    mrvi_settings s = loop_settings(dT, p, 100 * dT, MRVI_FORM_NULL_SPACE);
    s.newton_tol = s.constraint_tol = 1e-12;
    s.tuning.nullspace_tree = f;
    mrvi_summary sum;
    if (mrvi_trajectory_run(m, &s, &tt[f], &sum) != 0)
      CHECK(0, "%s (basis %d): %s", name, f, sum.message);
  }
  double d = INFINITY;
  if (tt[0] && tt[1] && tt[0]->n_macro == tt[1]->n_macro) {
    d = 0.0;
    for (long i = 0; i < tt[0]->n_macro * tt[0]->n; i++)
      d = fmax(d, fabs(tt[1]->q[i] - tt[0]->q[i]));
  }
  printf("%s: system %d (loop-reduced, %d cut rows) against %d (QR); 100 "
         "steps at tolerances 1e-12, p = %d: the bases differ by %.3g\n",
         name, nt, rc, nq, p, d);
  CHECK(d < 1e-10, "%s: loop-reduced against the QR basis: %.3g", name, d);
  mrvi_trajectory_free(tt[0]);
  mrvi_trajectory_free(tt[1]);
}

/* A ring of n bars (2-D, length 1) along a regular n-gon hung from its top
 * vertex at the origin: bar i from vertex i to i + 1, revolute joints
 * between neighbours and from bar 0 to the ground, the joint between the
 * last bar and the first closing the loop; with brace, a bar from vertex 1
 * to vertex n/2 + 1 on joints to the bars starting there (a second loop).
 * Gravity; bar 0 turning at 1 rad/s about the origin. */
static mrvi_model *ring(int n, int brace) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double pi = acos(-1.0), rad = 0.5 / sin(pi / n), g[2] = {0, -9.81};
  double v[64][3];
  for (int j = 0; j <= n && j < 64; j++) {
    const double a = pi / 2 + 2.0 * pi * j / n;
    v[j][0] = rad * cos(a), v[j][1] = rad * (sin(a) - 1.0), v[j][2] = 0.0;
  }
  int st = 0;
  char name[16];
  for (int i = 0; i < n; i++) {
    snprintf(name, sizeof name, "b%d", i);
    st |= add_bar(m, name, 2, v[i], v[i + 1], 1.0, i == 0 ? 1.0 : 0.0);
    st |= mrvi_model_add_joint(m, "revolute", i, i ? i - 1 : -1, v[i], NULL);
  }
  st |= mrvi_model_add_joint(m, "revolute", n - 1, 0, v[0], NULL);
  if (brace) {
    const int k = n / 2 + 1;
    st |= add_bar(m, "brace", 2, v[1], v[k], 1.0, 0.0);
    st |= mrvi_model_add_joint(m, "revolute", n, 1, v[1], NULL);
    st |= mrvi_model_add_joint(m, "revolute", n, k, v[k], NULL);
  }
  st |= mrvi_model_set_gravity(m, g);
  CHECK(st >= 0, "ring of %d bars: %s", n, mrvi_model_errmsg(m));
  return m;
}

static void test_loop_reduced(void) {
  /* A ring (the cut joint between two bars) and a braced ring (two loops,
   * two cut joints): which joints the plan cuts, then the bases. */
  for (int brace = 0; brace < 2; brace++) {
    mrvi_model *m = ring(8, brace);
    char why[200];
    const int ok = mrvi_nullspace_tree_plan(m, why, sizeof why);
    printf("ring of 8 bars%s: joint-reduced %d, cut at %s\n",
           brace ? " with a brace" : "", ok, why);
    CHECK(ok && strcmp(why, brace ? "'revolute b7-b0', 'revolute brace-b5'"
                                  : "'revolute b7-b0'") == 0,
          "ring%s: cut joints %s", brace ? " (braced)" : "", why);
    check_loop_reduced(brace ? "braced ring of 8 bars" : "ring of 8 bars", m, 2,
                       1, 2 + 2 * brace, 0.01);
    mrvi_model_free(m);
  }
  for (int D = 2; D <= 3; D++) {
    mrvi_model *m = fourbar(D, 0.0, D == 2);
    check_loop_reduced(D == 2 ? "four-bar 2-D" : "four-bar 3-D", m, D,
                       D == 2 ? 5 : 1, 2, 0.01);
    mrvi_model_free(m);
  }
  mrvi_system *sys = load_system("systems/slider_crank.yaml");
  if (!sys)
    return;
  check_loop_reduced("slider-crank", sys->model, 2, 1, 2, 0.01);
  /* 10^4 steps in the null-space form, the loop reduced */
  mrvi_settings s = sys->settings;
  s.constraint_form = MRVI_FORM_NULL_SPACE;
  mrvi_trajectory *tr = NULL;
  mrvi_summary sum;
  if (mrvi_trajectory_run(sys->model, &s, &tr, &sum) != 0) {
    CHECK(0, "slider-crank, loop-reduced: %s", sum.message);
  } else {
    double eg, eH, eH10 = 0.0;
    loop_invariants(sys->model, tr, &eg, &eH, &eH10);
    printf("slider-crank (loop-reduced null space): %ld steps, max |g| %.3g, "
           "max relative energy error %.3g (%.3g over the first tenth)\n",
           tr->n_macro - 1, eg, eH, eH10);
    CHECK(tr->n_macro == 10001 && eg <= s.constraint_tol,
          "slider-crank, loop-reduced: %ld nodes, loop closure %.3g",
          tr->n_macro, eg);
    CHECK(eH < 1e-2 && eH < 1.5 * eH10,
          "slider-crank, loop-reduced: energy error %.3g (%.3g over the first "
          "tenth)",
          eH, eH10);
  }
  mrvi_trajectory_free(tr);
  mrvi_system_free(sys);
}

/* ---------------------------------------------------------------------------
 * A closed loop of fast bodies (doc/multibody.md, "Fast closed loops"): the
 * four-bar's links made fast, with a stiff torsional spring (kt) on the
 * crank's ground joint (fast, in W) and a slow particle on soft slow springs
 * to an anchor and to the coupler's midpoint (in V).  In 3-D its micro-node
 * rows carry the 3 redundant rows of the planar loop: the null-space form
 * leaves them out of the QR basis at every micro node, the multiplier form
 * refuses the loop.  rate MRVI_SLOW makes the links and the torsional spring
 * slow (the single-rate loop).
 * ------------------------------------------------------------------------- */
static mrvi_model *fast_fourbar(int D, mrvi_rate rate) {
  mrvi_model *m = mrvi_model_create();
  double P[4][3];
  fourbar_points(fb_th0, P);
  const double axis[3] = {0, 0, 1}, g[3] = {0, -fb_g, 0}, kt = 60.0;
  mrvi_model_set_dimension(m, D);
  int st = add_bar_rate(m, "crank", D, P[0], P[1], 1.0, fb_w0, rate);
  st |= add_bar_rate(m, "coupler", D, P[1], P[2], 2.0, 0.0, rate);
  st |= add_bar_rate(m, "rocker", D, P[3], P[2], 1.5, 0.0, rate);
  const double *ax = D == 3 ? axis : NULL;
  st |= mrvi_model_add_joint(m, "revolute", 0, -1, P[0], ax);
  st |= mrvi_model_add_joint(m, "revolute", 0, 1, P[1], ax);
  st |= mrvi_model_add_joint(m, "revolute", 1, 2, P[2], ax);
  st |= mrvi_model_add_joint(m, "revolute", 2, -1, P[3], ax);
  st |= mrvi_model_add_torsion(m, rate, 0, -1, ax, "linear", &kt, 0.0);
  st |= mrvi_model_set_gravity(m, g);
  const double x[3] = {1.8, 2.6, 0.0}, v[3] = {0.3, -0.2, 0.0};
  const double anchor[3] = {1.8, 3.0, 0.0}, ka = 20.0, kc = 5.0;
  const int s = mrvi_model_add_particle(m, "s", 0.5, MRVI_SLOW, x, v);
  const mrvi_end ps = {.particle = s, .body = -1},
                 cm = {.particle = -1, .body = 1, .at = {0, 0, 0}};
  CHECK(st >= 0 && s >= 0 &&
            mrvi_model_add_end_spring(m, MRVI_SLOW, &ps, NULL, anchor, "linear",
                                      &ka, NAN) >= 0 &&
            mrvi_model_add_end_spring(m, MRVI_SLOW, &ps, &cm, NULL, "linear",
                                      &kc, NAN) >= 0,
        "fast four-bar (%d-D): %s", D, mrvi_model_errmsg(m));
  return m;
}

/* Run m (midpoint-midpoint, dT = 0.01, p micro steps, n macro steps) at
 * Newton and constraint tolerance tol in the given form; NULL (reported)
 * if it fails. */
static mrvi_trajectory *fast_loop_run(const mrvi_model *m, int p, long n,
                                      double tol, mrvi_constraint_form form,
                                      int tree) {
  mrvi_settings s = loop_settings(0.01, p, n * 0.01, form);
  s.newton_tol = s.constraint_tol = tol;
  s.tuning.nullspace_tree = tree;
  mrvi_trajectory *tr = NULL;
  mrvi_summary sum;
  if (mrvi_trajectory_run(m, &s, &tr, &sum) != 0) {
    CHECK(0, "fast four-bar (p = %d, %s): %s", p, form_name(form), sum.message);
    mrvi_trajectory_free(tr);
    return NULL;
  }
  return tr;
}

/* Max difference of the bodies' centres (first D entries of each body's
 * block) and the particle between a (D = 3) and b (D_b = 2 or 3). */
static double centres_differ(const mrvi_model *ma, const mrvi_trajectory *a,
                             const mrvi_model *mb, const mrvi_trajectory *b) {
  if (!a || !b || a->n_macro != b->n_macro)
    return INFINITY;
  const int Db = mrvi_model_dimension(mb);
  double d = 0.0;
  for (long k = 0; k < a->n_macro; k++)
    for (int i = 0; i <= 3; i++) { /* 3 bodies, then the particle */
      const int oa = i < 3 ? mrvi_model_body_first(ma, i) : 36;
      const int ob = i < 3 ? mrvi_model_body_first(mb, i) : 3 * Db * (Db + 1);
      for (int c = 0; c < 2; c++)
        d = fmax(d, fabs(a->q[k * a->n + oa + c] - b->q[k * b->n + ob + c]));
    }
  return d;
}

static void test_fast_loop(void) {
  mrvi_model *m3 = fast_fourbar(3, MRVI_FAST), *m2 = fast_fourbar(2, MRVI_FAST);
  mrvi_model *s3 = fast_fourbar(3, MRVI_SLOW);
  char why[200] = "";
  CHECK(mrvi_nullspace_fast_plan(m3, why, sizeof why) &&
            strstr(why, "'revolute rocker-ground'"),
        "fast four-bar: a fast forest cut at the rocker's pivot: %s", why);
  /* The multiplier form refuses it, naming the joints. */
  mrvi_settings s = loop_settings(0.01, 5, 0.1, MRVI_FORM_MULTIPLIERS);
  mrvi_trajectory *tr = NULL;
  mrvi_summary sum;
  CHECK(mrvi_trajectory_run(m3, &s, &tr, &sum) != 0 &&
            strstr(sum.message, "redundant constraints") &&
            strstr(sum.message, "revolute"),
        "fast four-bar refused in the multiplier form: %s", sum.message);
  mrvi_trajectory_free(tr);
  /* p = 5: the 3-D loop (null-space form, 3 redundant rows left out at every
   * micro node) against the planar loop (multipliers, no redundancy). */
  const long n_short = test_steps(100);
  mrvi_trajectory *a =
      fast_loop_run(m3, 5, n_short, 1e-12, MRVI_FORM_NULL_SPACE, 1);
  mrvi_trajectory *b =
      fast_loop_run(m2, 5, n_short, 1e-12, MRVI_FORM_MULTIPLIERS, 1);
  const double d5 = centres_differ(m3, a, m2, b);
  mrvi_trajectory_free(a), mrvi_trajectory_free(b);
  /* p = 1: the fast loop is the single-rate loop (links slow). */
  a = fast_loop_run(m3, 1, n_short, 1e-12, MRVI_FORM_NULL_SPACE, 1);
  b = fast_loop_run(s3, 1, n_short, 1e-12, MRVI_FORM_NULL_SPACE, 0);
  double d1 = a && b && a->n_macro == b->n_macro ? 0.0 : INFINITY;
  for (long i = 0; d1 < INFINITY && i < a->n_macro * a->n; i++)
    d1 = fmax(d1, fabs(a->q[i] - b->q[i]));
  mrvi_trajectory_free(a), mrvi_trajectory_free(b);
  printf("fast four-bar 3-D (null-space, 3 redundant micro-node rows left "
         "out), %ld steps at tolerances 1e-12: against the 2-D loop in the "
         "multiplier form (p = 5) %.3g; p = 1 against the loop made slow "
         "%.3g\n",
         n_short, d5, d1);
  CHECK(d5 < 1e-9, "fast four-bar 3-D against 2-D (p = 5): %.3g", d5);
  CHECK(d1 < 1e-10, "fast four-bar p = 1 against the slow loop: %.3g", d1);
  /* The cut basis (the tree's joints analytic, the cut hinge's 2 kept rows
   * reduced numerically) against the numerical QR basis at every micro
   * node, p = 1 and 5, tolerances 1e-12. */
  for (int p = 1; p <= 5; p += 4) {
    a = fast_loop_run(m3, p, n_short, 1e-12, MRVI_FORM_NULL_SPACE, 1);
    b = fast_loop_run(m3, p, n_short, 1e-12, MRVI_FORM_NULL_SPACE, 0);
    double dq = a && b && a->n_macro == b->n_macro ? 0.0 : INFINITY;
    for (long i = 0; dq < INFINITY && i < a->n_macro * a->n; i++)
      dq = fmax(dq, fabs(a->q[i] - b->q[i]));
    for (long i = 0; dq < INFINITY && i < a->n_micro * a->n_fast; i++)
      dq = fmax(dq, fabs(a->micro_q[i] - b->micro_q[i]));
    printf("fast four-bar 3-D, p = %d, %ld steps at tolerances 1e-12: the "
           "cut basis against the QR basis %.3g (macro and micro nodes)\n",
           p, n_short, dq);
    CHECK(dq < 1e-10, "fast four-bar p = %d: cut basis against QR: %.3g", p,
          dq);
    mrvi_trajectory_free(a), mrvi_trajectory_free(b);
  }
  /* Long run, p = 5, default-like tolerances: every row (the redundant ones
   * too) at every micro node, the energy error bounded. */
  const long n_long = test_steps(2000);
  mrvi_settings sl =
      loop_settings(0.01, 5, n_long * 0.01, MRVI_FORM_NULL_SPACE);
  sl.newton_tol = 1e-10;
  sl.constraint_tol = 1e-10;
  tr = NULL;
  if (mrvi_trajectory_run(m3, &sl, &tr, &sum) != 0) {
    CHECK(0, "fast four-bar, long run: %s", sum.message);
  } else {
    double eg, eH, eH10 = 0.0, es, eH2 = 0.0, H0 = 0.0;
    loop_invariants(m3, tr, &eg, &eH, &eH10);
    double ei;
    const double em = micro_residual_int(m3, tr, 5, &es, &ei);
    /* the energy error over the first half (its swings beat over several
     * seconds: the tenth is too short a window) */
    for (long k = 0; 2 * k <= tr->n_macro; k++) {
      double T, V, W;
      mrvi_model_energy(m3, tr->q + k * tr->n, tr->p + k * tr->n, &T, &V, &W);
      if (k == 0)
        H0 = T + V + W;
      eH2 = fmax(eH2, fabs(T + V + W - H0) / fabs(H0));
    }
    printf("fast four-bar 3-D, p = 5, %ld steps (%ld micro nodes), Newton "
           "and constraint tolerance 1e-10: max |g| %.3g over all 38 rows at "
           "every micro node (%.3g at the macro nodes; the links' internal "
           "rows %.3g), max relative energy error %.3g (%.3g over the first "
           "tenth, %.3g over the first half)\n",
           n_long, tr->n_micro, em, eg, ei, eH, eH10, eH2);
    CHECK(ei <= 1e-13, "fast four-bar: internal rows %.3g (reparametrised)",
          ei);
    CHECK(tr->n_micro == 5 * n_long + 1, "fast four-bar: %ld micro nodes",
          tr->n_micro);
    CHECK(em <= 1e-10 && eg <= 1e-10, "fast four-bar: loop closure %.3g, %.3g",
          em, eg);
    /* Bounded: the whole run's error within 1.5 times the first half's,
     * judged on the full horizon only (the sanitizers' runs are a tenth as
     * long, shorter than the swings' beat: there only the size is checked). */
    const int full_horizon = n_long == 2000;
    CHECK(eH < 1e-4 && (!full_horizon || eH < 1.5 * eH2),
          "fast four-bar: energy error %.3g (%.3g over the first half)", eH,
          eH2);
  }
  mrvi_trajectory_free(tr);
  mrvi_model_free(m3), mrvi_model_free(m2), mrvi_model_free(s3);
}

/* A ladder of n fast four-bars (n loops) in D dimensions: two rails of n
 * bars (length 1, slanted by 0.3) hung from the ground at (0, 0) and (1,
 * 0), the rungs joining the rails' lower ends, every bar fast on revolute
 * joints (axis e3 in 3-D), a stiff fast torsional spring on the left
 * rail's pivot (60 N m/rad) swinging it, gravity, and a slow particle on a
 * soft slow spring (5 N/m) to the lowest rung's centre.  In 3-D each rung's
 * second joint is cut, its 3 redundant rows left out: 36 n fast
 * coordinates, n degrees of freedom. */
static mrvi_model *fast_ladder(int D, int n) {
  mrvi_model *m = mrvi_model_create();
  const double axis[3] = {0, 0, 1}, g[3] = {0, -fb_g, 0}, kt = 60.0, sl = 0.3;
  const double *ax = D == 3 ? axis : NULL;
  mrvi_model_set_dimension(m, D);
  int st = 0, prev[2] = {-1, -1}, rung = -1;
  for (int j = 0; j < n && st >= 0; j++) {
    int rail[2];
    for (int side = 0; side < 2; side++) {
      const double P[3] = {side + sl * j, -j, 0},
                   Q[3] = {side + sl * (j + 1), -(j + 1), 0};
      char name[32];
      snprintf(name, sizeof name, "%c%d", side ? 'r' : 'l', j);
      rail[side] = add_bar_rate(m, name, D, P, Q, 1.0, 0.0, MRVI_FAST);
      st |= rail[side];
      st |= mrvi_model_add_joint(m, "revolute", rail[side], prev[side], P, ax);
    }
    const double P[3] = {sl * (j + 1), -(j + 1), 0},
                 Q[3] = {1 + sl * (j + 1), -(j + 1), 0};
    char name[32];
    snprintf(name, sizeof name, "rung%d", j);
    rung = add_bar_rate(m, name, D, P, Q, 1.0, 0.0, MRVI_FAST);
    st |= rung;
    st |= mrvi_model_add_joint(m, "revolute", rung, rail[0], P, ax);
    st |= mrvi_model_add_joint(m, "revolute", rung, rail[1], Q, ax);
    prev[0] = rail[0], prev[1] = rail[1];
  }
  st |= mrvi_model_add_torsion(m, MRVI_FAST, 0, -1, ax, "linear", &kt, 0.3);
  st |= mrvi_model_set_gravity(m, g);
  const double x[3] = {0.5 + sl * n, -n - 0.8, 0.0}, v[3] = {0.2, 0.1, 0.0};
  const double kc = 5.0;
  const int s = mrvi_model_add_particle(m, "s", 0.5, MRVI_SLOW, x, v);
  const mrvi_end ps = {.particle = s, .body = -1},
                 cm = {.particle = -1, .body = rung, .at = {0, 0, 0}};
  CHECK(st >= 0 && s >= 0 &&
            mrvi_model_add_end_spring(m, MRVI_SLOW, &ps, &cm, NULL, "linear",
                                      &kc, NAN) >= 0,
        "fast ladder (%d-D): %s", D, mrvi_model_errmsg(m));
  return m;
}

/* A ladder of 8 fast four-bars in 3-D: 288 fast coordinates, above the
 * numerical basis's cap of 256 (refused with tuning nullspace_tree 0); the
 * cut basis runs it (p = 2, tolerances 1e-11): every row (the 24 dropped
 * ones too) at every micro node to the tolerance, the links' internal rows
 * to 1e-13, and the bodies' centres and the particle as the planar ladder's
 * in the multiplier form to the tolerance's order. */
static void test_fast_ladder(void) {
  const int n = 8, p = 2;
  mrvi_model *m3 = fast_ladder(3, n), *m2 = fast_ladder(2, n);
  const long steps = test_steps(40);
  mrvi_settings s = loop_settings(0.01, p, steps * 0.01, MRVI_FORM_NULL_SPACE);
  s.tuning.nullspace_tree = 0;
  mrvi_trajectory *a = NULL, *b = NULL;
  mrvi_summary sum;
  const int refused = mrvi_trajectory_run(m3, &s, &a, &sum) != 0;
  CHECK(refused && strstr(sum.message, "more than 256"),
        "fast ladder: the QR basis refuses %d fast coordinates: %s",
        mrvi_model_n_fast(m3), refused ? sum.message : "ran");
  mrvi_trajectory_free(a);
  a = NULL;
  s.tuning.nullspace_tree = 1;
  const int ra = mrvi_trajectory_run(m3, &s, &a, &sum);
  CHECK(ra == 0, "fast ladder 3-D, cut basis: %s", sum.message);
  mrvi_settings s2 = s;
  s2.constraint_form = MRVI_FORM_MULTIPLIERS;
  const int rb = mrvi_trajectory_run(m2, &s2, &b, &sum);
  CHECK(rb == 0, "fast ladder 2-D, multipliers: %s", sum.message);
  if (ra == 0 && rb == 0 && a->n_macro == b->n_macro) {
    double es, ei, d = 0.0;
    const double em = micro_residual_int(m3, a, p, &es, &ei);
    const int nb = 3 * n;
    for (long k = 0; k < a->n_macro; k++)
      for (int i = 0; i <= nb; i++) { /* the bodies, then the particle */
        const int oa = i < nb ? mrvi_model_body_first(m3, i) : 12 * nb;
        const int ob = i < nb ? mrvi_model_body_first(m2, i) : 6 * nb;
        for (int c = 0; c < 2; c++)
          d = fmax(d, fabs(a->q[k * a->n + oa + c] - b->q[k * b->n + ob + c]));
      }
    printf("fast ladder of %d four-bars in 3-D (%d fast coordinates), p = %d, "
           "%ld steps, tolerances 1e-11: max |g| %.3g over every row at every "
           "micro node (internal rows %.3g); against the planar ladder in "
           "the multiplier form %.3g\n",
           n, mrvi_model_n_fast(m3), p, steps, em, ei, d);
    CHECK(em <= 1e-11 && ei <= 1e-13 && d < 1e-9,
          "fast ladder: |g| %.3g, internal %.3g, against 2-D %.3g", em, ei, d);
  }
  mrvi_trajectory_free(a), mrvi_trajectory_free(b);
  mrvi_model_free(m3), mrvi_model_free(m2);
}

/* A loop of fast and slow bodies whose redundant rows are micro-node rows
 * that follow only together with the slow rocker's ground joint (listed
 * first): refused in the null-space form with the constraint named. */
static void test_mixed_loop(void) {
  mrvi_model *m = mrvi_model_create();
  double P[4][3];
  fourbar_points(fb_th0, P);
  const double axis[3] = {0, 0, 1};
  mrvi_model_set_dimension(m, 3);
  int st = add_bar_rate(m, "crank", 3, P[0], P[1], 1.0, 0.0, MRVI_FAST);
  st |= add_bar_rate(m, "coupler", 3, P[1], P[2], 2.0, 0.0, MRVI_FAST);
  st |= add_bar_rate(m, "rocker", 3, P[3], P[2], 1.5, 0.0, MRVI_SLOW);
  st |= mrvi_model_add_joint(m, "revolute", 2, -1, P[3], axis);
  st |= mrvi_model_add_joint(m, "revolute", 0, -1, P[0], axis);
  st |= mrvi_model_add_joint(m, "revolute", 0, 1, P[1], axis);
  st |= mrvi_model_add_joint(m, "revolute", 1, 2, P[2], axis);
  CHECK(st >= 0, "mixed loop: %s", mrvi_model_errmsg(m));
  for (int p = 1; p <= 5; p += 4) { /* refused whatever p */
    const mrvi_settings s = loop_settings(0.01, p, 0.05, MRVI_FORM_NULL_SPACE);
    mrvi_trajectory *tr = NULL;
    mrvi_summary sum;
    const int rc = mrvi_trajectory_run(m, &s, &tr, &sum);
    printf("fast and slow bodies in one loop (null-space form, p = %d): %s\n",
           p, rc ? sum.message : "ran");
    CHECK(rc != 0 && strstr(sum.message, "redundant only together") &&
              strstr(sum.message, "'revolute"),
          "mixed loop refused (p = %d): %s", p, rc ? sum.message : "ran");
    mrvi_trajectory_free(tr);
  }
  mrvi_model_free(m);
}

/* tests/fast_fourbar.yaml, the same loop as a description file: 3 of its
 * redundant rows are micro-node rows (what `mrvi check` reports); as
 * shipped (p = 10, tolerances 1e-10) every row holds at every micro node. */
static void test_fast_loop_file(void) {
  mrvi_system *sys = load_system("tests/fast_fourbar.yaml");
  if (!sys)
    return;
  const mrvi_model *m = sys->model;
  const int red = mrvi_nullspace_micro_redundant(m, mrvi_model_q0(m));
  CHECK(mrvi_model_constraint_rows(m) == 38 && red == 3,
        "fast_fourbar.yaml: %d rows, %d redundant at the micro nodes",
        mrvi_model_constraint_rows(m), red);
  mrvi_settings s = sys->settings;
  const long n = test_steps(100);
  s.t_end = n * s.macro_step;
  mrvi_trajectory *tr = NULL;
  mrvi_summary sum;
  if (mrvi_trajectory_run(m, &s, &tr, &sum) != 0) {
    CHECK(0, "fast_fourbar.yaml: %s", sum.message);
  } else {
    double es;
    const double em = micro_residual(m, tr, s.micro_steps, &es);
    printf("tests/fast_fourbar.yaml: %d redundant micro-node rows; %ld micro "
           "nodes (p = %d): max |g| %.3g over all 38 rows\n",
           red, tr->n_micro, s.micro_steps, em);
    CHECK(tr->n_micro == s.micro_steps * n + 1 && em <= s.constraint_tol,
          "fast_fourbar.yaml: %ld micro nodes, max |g| %.3g", tr->n_micro, em);
  }
  mrvi_trajectory_free(tr);
  mrvi_system_free(sys);
}

/* `test_loops fast`: the fast bodies in joints alone (a meson test of its
 * own, test_loops_fast); `test_loops fast-loop`: the closed loop of fast
 * bodies (test_loops_fast_loop); else every other study. */
int main(int argc, char **argv) {
  if (argc > 1 && strcmp(argv[1], "fast") == 0) {
    test_fast_joint_reduced();
    return test_finish();
  }
  if (argc > 1 && strcmp(argv[1], "fast-loop") == 0) {
    test_fast_loop();
    test_fast_loop_file();
    test_mixed_loop();
    test_fast_ladder();
    return test_finish();
  }
  test_fourbar_3d();
  test_fourbar_forms();
  test_projection();
  test_loader_projection();
  test_universal();
  test_universal_oblique();
  test_universal_oblique_file();
  test_slider_crank();
  test_body_null_space();
  test_reparametrisation();
  test_fast_reparametrisation();
  test_joint_reduced();
  test_joint_reduced_long_chain();
  test_joint_reduced_weld();
  test_joint_reduced_kinds();
  test_loop_reduced();
  return test_finish();
}
