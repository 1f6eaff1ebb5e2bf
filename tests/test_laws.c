/* Derivatives of every law and every element kind against central finite
 * differences; model potential gradient and Hessian likewise. */
#include "models.h"
#include "solver/solver.h"
#include "testlib.h"

#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* phi' and phi'' of every registered law at several strains. */
static void check_laws(void) {
  const double params[][MRVI_LAW_MAX_PARAMS] = {
      {1.25, 4}, {0.7, 2}, {-0.3, 3}, {2.0, 1}, {1.0, 2.5}};
  const double strains[] = {0.3, 1.7, -0.8, 0.05};
  for (int i = 0; i < mrvi_law_count(); i++) {
    const mrvi_law *law = mrvi_law_get(i);
    for (size_t a = 0; a < sizeof params / sizeof params[0]; a++)
      for (size_t b = 0; b < sizeof strains / sizeof strains[0]; b++) {
        double s = strains[b];
        char msg[128];
        if (law->check && law->check(params[a], msg, sizeof msg) < 0)
          continue; /* parameters outside this law's domain */
        if (params[a][1] != floor(params[a][1]) && s <= 0)
          continue; /* real exponents are defined for s > 0 only */
        const double h = 1e-5;
        double f, df, ddf, fp, dfp, ddfp, fm, dfm, ddfm;
        law->eval(params[a], s, &f, &df, &ddf);
        law->eval(params[a], s + h, &fp, &dfp, &ddfp);
        law->eval(params[a], s - h, &fm, &dfm, &ddfm);
        const double tol = 1e-7 * (1 + fabs(df) + fabs(ddf) + fabs(f));
        CHECK_NEAR(df, (fp - fm) / (2 * h), tol, law->name);
        CHECK_NEAR(ddf, (dfp - dfm) / (2 * h), tol, law->name);
      }
  }
}

/* Gradient and Hessian of every element of a model against central FD of
 * the element energy, at a perturbed configuration. */
static void check_elements(mrvi_model *m, const char *what) {
  double y[MRVI_MAX_INPUTS], g[MRVI_MAX_INPUTS], yp[MRVI_MAX_INPUTS];
  double H[MRVI_MAX_INPUTS * MRVI_MAX_INPUTS], gp[MRVI_MAX_INPUTS],
      gm[MRVI_MAX_INPUTS];
  srand(7);
  for (int ei = 0; ei < m->n_elements; ei++) {
    const mrvi_element *e = MRVI_ELEMENT(m, ei);
    const int n = e->n_in;
    if (n > MRVI_MAX_INPUTS)
      continue;
    for (int j = 0; j < n; j++)
      y[j] = m->q0[e->in[j]] + 0.1 * (rand() / (double)RAND_MAX - 0.5);
    mrvi_element_eval(m, e, y, g, e->kind == MRVI_ELEMENT_GRAVITY ? NULL : H);
    const double h = 1e-5;
    for (int j = 0; j < n; j++) {
      memcpy(yp, y, (size_t)n * sizeof *y);
      yp[j] = y[j] + h;
      const double fp = mrvi_element_eval(m, e, yp, gp, NULL);
      yp[j] = y[j] - h;
      const double fm = mrvi_element_eval(m, e, yp, gm, NULL);
      const double tol = 1e-6 * (1 + fabs(g[j]));
      CHECK_NEAR(g[j], (fp - fm) / (2 * h), tol, what);
      if (e->kind == MRVI_ELEMENT_GRAVITY)
        continue;
      for (int l = 0; l < n; l++)
        CHECK_NEAR(H[l * n + j], (gp[l] - gm[l]) / (2 * h),
                   1e-6 * (1 + fabs(H[l * n + j])), what);
    }
  }
}

/* Model potential gradient/Hessian (summed over elements) against FD. */
static void check_potential(mrvi_model *m, const char *what) {
  const int n = m->n;
  double *q = calloc((size_t)n, sizeof *q), *g = calloc((size_t)n, sizeof *g);
  double *H = calloc((size_t)n * n, sizeof *H);
  double *gp = calloc((size_t)n, sizeof *gp),
         *gm = calloc((size_t)n, sizeof *gm);
  for (int c = 0; c < 2; c++) {
    for (int i = 0; i < n; i++)
      q[i] = m->q0[i] + 0.05 * sin(3.0 * i + c);
    memset(g, 0, (size_t)n * sizeof *g);
    memset(H, 0, (size_t)n * n * sizeof *H);
    mrvi_model_potential(m, (mrvi_rate)c, q, g, H);
    const double h = 1e-5;
    for (int j = 0; j < n; j++) {
      const double qj = q[j];
      memset(gp, 0, (size_t)n * sizeof *gp);
      memset(gm, 0, (size_t)n * sizeof *gm);
      q[j] = qj + h;
      const double fp = mrvi_model_potential(m, (mrvi_rate)c, q, gp, NULL);
      q[j] = qj - h;
      const double fm = mrvi_model_potential(m, (mrvi_rate)c, q, gm, NULL);
      q[j] = qj;
      CHECK_NEAR(g[j], (fp - fm) / (2 * h), 1e-6 * (1 + fabs(g[j])), what);
      for (int i = 0; i < n; i++)
        CHECK_NEAR(H[i * n + j], (gp[i] - gm[i]) / (2 * h),
                   1e-6 * (1 + fabs(H[i * n + j])), what);
    }
  }
  free(q);
  free(g);
  free(H);
  free(gp);
  free(gm);
}

/* A spring at zero length with zero rest length (the spring ring's anchors
 * start away from it, but a run may pass through): the limit phi'' I. */
static void check_zero_length(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double x[2] = {0, 0}, v[2] = {0, 0}, k[1] = {3.0};
  mrvi_model_add_particle(m, "a", 1.0, MRVI_FAST, x, v);
  mrvi_model_add_anchor_spring(m, MRVI_FAST, 0, x, "linear", k, 0.0);
  double g[2] = {0, 0}, H[4] = {0, 0, 0, 0};
  mrvi_model_potential(m, MRVI_FAST, x, g, H);
  CHECK(g[0] == 0 && g[1] == 0, "zero-length gradient is zero");
  CHECK(H[0] == 3 && H[3] == 3 && H[1] == 0 && H[2] == 0,
        "zero-length Hessian is k I");
  mrvi_model_free(m);
}

/* Distance springs in 1-D and 2-D and a particle-particle spring with a
 * rest length, so every element kind meets every dimension. */
static mrvi_model *mixed_model(int dim) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, dim);
  const double x1[3] = {0.3, -0.2, 0.5}, x2[3] = {1.1, 0.4, -0.3},
               v[3] = {0, 0, 0}, anchor[3] = {-0.5, 0.2, 0.1};
  mrvi_model_add_particle(m, "a", 1.0, MRVI_SLOW, x1, v);
  mrvi_model_add_particle(m, "b", 2.0, MRVI_FAST, x2, v);
  const double pw[2] = {0.8, 3}, k[1] = {5.0}, pr[2] = {1.0, 2.5};
  mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "power", pw, 0.4);
  mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "power", pr, 0.2);
  mrvi_model_add_anchor_spring(m, MRVI_FAST, 1, anchor, "linear", k, 0.7);
  const double g[3] = {0.1, -9.81, 0.3};
  mrvi_model_set_gravity(m, g);
  return m;
}

/* The pair laws at physical parameters: derivatives against FD, the
 * Morse and Lennard-Jones minima, the cutoff shift. */
static void check_pair_laws(void) {
  const struct {
    const char *name;
    double par[3];
    double s[4];
  } cases[] = {
      {"morse", {2.0, 1.5}, {-0.3, 0.0, 0.4, 2.0}},
      {"lennard-jones", {1.0, 1.0, 2.5}, {0.9, 1.1224, 1.5, 2.4}},
      {"lennard-jones", {0.5, 2.0, 5.0}, {1.9, 2.3, 3.0, 4.5}},
      {"inverse", {3.0}, {0.5, 1.0, 2.0, 7.0}},
      {"inverse", {-2.0}, {0.5, 1.0, 2.0, 7.0}},
  };
  for (size_t c = 0; c < sizeof cases / sizeof cases[0]; c++) {
    const mrvi_law *law = mrvi_law_find(cases[c].name);
    CHECK(law != NULL, "law %s registered", cases[c].name);
    if (!law)
      continue;
    char msg[128];
    CHECK(law->check(cases[c].par, msg, sizeof msg) == 0, "%s parameters ok",
          cases[c].name);
    for (int b = 0; b < 4; b++) {
      const double s = cases[c].s[b], h = 1e-6;
      double f, df, ddf, fp, dfp, ddfp, fm, dfm, ddfm;
      law->eval(cases[c].par, s, &f, &df, &ddf);
      law->eval(cases[c].par, s + h, &fp, &dfp, &ddfp);
      law->eval(cases[c].par, s - h, &fm, &dfm, &ddfm);
      /* central differences: truncation h^2 phi^(3)/6 and rounding
       * 1e-16 phi / h, both far below 1e-6 relative here */
      CHECK_NEAR(df, (fp - fm) / (2 * h), 1e-6 * (1 + fabs(df)), law->name);
      CHECK_NEAR(ddf, (dfp - dfm) / (2 * h), 1e-6 * (1 + fabs(ddf)), law->name);
    }
  }
  const mrvi_law *lj = mrvi_law_find("lennard-jones"),
                 *mo = mrvi_law_find("morse");
  const double ljp[3] = {1.5, 1.2, 3.0}, mop[2] = {2.0, 1.5};
  double f, df, ddf;
  /* Minimum at 2^(1/6) sigma with depth eps (less the shift) and curvature
   * 72 eps / (2^(1/3) sigma^2). */
  const double rmin = pow(2.0, 1.0 / 6.0) * 1.2;
  const double x6 = pow(1.2 / 3.0, 6), shift = 4 * 1.5 * (x6 * x6 - x6);
  lj->eval(ljp, rmin, &f, &df, &ddf);
  CHECK_NEAR(df, 0.0, 1e-12, "lennard-jones minimum");
  CHECK_NEAR(f, -1.5 - shift, 1e-12, "lennard-jones depth");
  CHECK_NEAR(ddf, 72 * 1.5 / (pow(2.0, 1.0 / 3.0) * 1.44), 1e-10,
             "lennard-jones curvature");
  /* Continuous at the cutoff, zero beyond. */
  double fa, fb, d1, d2;
  lj->eval(ljp, 3.0 - 1e-9, &fa, &d1, &d2);
  lj->eval(ljp, 3.0, &fb, &d1, &d2);
  CHECK_NEAR(fa, 0.0, 1e-9, "lennard-jones energy at the cutoff");
  CHECK(fb == 0 && d1 == 0 && d2 == 0, "lennard-jones zero beyond cutoff");
  mo->eval(mop, 0.0, &f, &df, &ddf);
  CHECK(f == 0 && df == 0, "morse minimum at the rest length");
  CHECK_NEAR(ddf, 2 * 2.0 * 1.5 * 1.5, 1e-12, "morse curvature 2 D a^2");
  mo->eval(mop, 50.0, &f, &df, &ddf);
  CHECK_NEAR(f, 2.0, 1e-12, "morse dissociation energy");
}

/* Angles and constant forces in 2-D and 3-D: gradient and Hessian against
 * FD via check_elements/check_potential, and the energy against
 * k [1 - cos(theta - theta0)] computed directly. */
static void check_angles_forces(void) {
  for (int dim = 2; dim <= 3; dim++) {
    mrvi_model *m = mrvi_model_create();
    mrvi_model_set_dimension(m, dim);
    const double v[3] = {0, 0, 0};
    const double x[5][3] = {{1.0, 0.1, 0.2},
                            {0.0, 0.0, 0.0},
                            {-0.3, 0.9, -0.4},
                            {-1.0, 0.05, 0.1},
                            {0.7, -0.6, 0.3}};
    const char *names[5] = {"a", "b", "c", "d", "e"};
    for (int i = 0; i < 5; i++)
      mrvi_model_add_particle(m, names[i], 1.0 + i,
                              i < 2 ? MRVI_SLOW : MRVI_FAST, x[i], v);
    CHECK(mrvi_model_add_angle(m, MRVI_SLOW, 0, 1, 2, 2.0, 1.1) >= 0,
          "angle with rest angle");
    CHECK(mrvi_model_add_angle(m, MRVI_SLOW, 0, 1, 3, 1.5, M_PI) >= 0,
          "straight angle (near collinear start)");
    CHECK(mrvi_model_add_angle(m, MRVI_FAST, 2, 3, 4, 0.7, NAN) >= 0,
          "angle at its initial value");
    CHECK(mrvi_model_add_angle(m, MRVI_FAST, 1, 2, 3, 1.0, 1.0) == MRVI_EMODEL,
          "fast angle on a slow particle rejected");
    CHECK(strstr(mrvi_model_errmsg(m), "potential: slow") != NULL,
          "hint to make it slow: %s", mrvi_model_errmsg(m));
    CHECK(mrvi_model_add_angle(m, MRVI_SLOW, 0, 0, 2, 1.0, 1.0) == MRVI_EINVAL,
          "repeated particle rejected");
    CHECK(mrvi_model_add_angle(m, MRVI_SLOW, 0, 1, 2, 1.0, 4.0) == MRVI_EINVAL,
          "rest angle beyond pi rejected");
    const int cs[2] = {0, 1}, cf[1] = {2 * dim + 1};
    const double fs[2] = {0.3, -1.2}, ff[1] = {2.5};
    CHECK(mrvi_model_add_force(m, MRVI_SLOW, 2, cs, fs) >= 0, "slow force");
    CHECK(mrvi_model_add_force(m, MRVI_FAST, 1, cf, ff) >= 0, "fast force");
    check_elements(m, dim == 2 ? "2-D angle/force" : "3-D angle/force");
    check_potential(m,
                    dim == 2 ? "2-D angle/force pot" : "3-D angle/force pot");
    /* Initial rest angle: zero energy at q0 for the third angle; the energy
     * of the first against its formula; the force is -f^T q. */
    const mrvi_element *e = MRVI_ELEMENT(m, 2);
    double y[9], th;
    for (int j = 0; j < e->n_in; j++)
      y[j] = m->q0[e->in[j]];
    CHECK_NEAR(mrvi_element_eval(m, e, y, NULL, NULL), 0.0, 1e-14,
               "angle energy zero at its initial rest angle");
    e = MRVI_ELEMENT(m, 0);
    for (int j = 0; j < e->n_in; j++)
      y[j] = m->q0[e->in[j]];
    {
      double uv = 0, uu = 0, vv = 0;
      for (int p = 0; p < dim; p++) {
        uv += (x[0][p] - x[1][p]) * (x[2][p] - x[1][p]);
        uu += (x[0][p] - x[1][p]) * (x[0][p] - x[1][p]);
        vv += (x[2][p] - x[1][p]) * (x[2][p] - x[1][p]);
      }
      th = acos(uv / sqrt(uu * vv));
    }
    CHECK_NEAR(mrvi_element_eval(m, e, y, NULL, NULL),
               2.0 * (1 - cos(th - 1.1)), 1e-14, "angle energy formula");
    e = MRVI_ELEMENT(m, 3);
    for (int j = 0; j < e->n_in; j++)
      y[j] = m->q0[e->in[j]];
    CHECK_NEAR(mrvi_element_eval(m, e, y, NULL, NULL),
               -(0.3 * x[0][0] - 1.2 * x[0][1]), 1e-14, "force potential");
    mrvi_model_free(m);
  }
}

/* Lennard-Jones dimer from an integrator run: upward zero crossings of
 * r - r0 (linear interpolation) give the period. */
static void check_lj_dimer(void) {
  const double eps = 1.0, sig = 1.0, m1 = 1.0, m2 = 2.0, A = 0.005;
  const double r0 = pow(2.0, 1.0 / 6.0) * sig, mu = m1 * m2 / (m1 + m2);
  const double keff = 72 * eps / (pow(2.0, 1.0 / 3.0) * sig * sig);
  const double omega = sqrt(keff / mu);
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 1);
  const double xa[1] = {0.0}, xb[1] = {r0 + A}, v[1] = {0.0};
  mrvi_model_add_particle(m, "a", m1, MRVI_SLOW, xa, v);
  mrvi_model_add_particle(m, "b", m2, MRVI_SLOW, xb, v);
  const double par[3] = {eps, sig, 2.5 * sig};
  CHECK(mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "lennard-jones", par, 0.0) >=
            0,
        "lennard-jones pair");
  mrvi_settings s;
  mrvi_settings_default(&s);
  s.macro_step = 1e-3;
  s.t_end = 10 * 2 * M_PI / omega;
  mrvi_integrator *it = NULL;
  char msg[256];
  CHECK(mrvi_integrator_create(m, &s, &it, msg, sizeof msg) == 0, "%s", msg);
  if (!it) {
    mrvi_model_free(m);
    return;
  }
  const long N = mrvi_settings_n_steps(&s);
  double prev = A, first = -1, last = -1, rmax = -1e9, rmin = 1e9;
  int crossings = 0;
  for (long k = 0; k < N; k++) {
    if (mrvi_integrator_step(it) != 0) {
      CHECK(0, "step %ld: %s", k, mrvi_integrator_errmsg(it));
      break;
    }
    const double *q = mrvi_integrator_q(it);
    const double r = q[1] - q[0], d = r - r0;
    rmax = r > rmax ? r : rmax;
    rmin = r < rmin ? r : rmin;
    if (prev < 0 && d >= 0) {
      const double t = mrvi_integrator_time(it) - s.macro_step * d / (d - prev);
      if (first < 0)
        first = t;
      last = t;
      crossings++;
    }
    prev = d;
  }
  const double period = (last - first) / (crossings - 1);
  /* Anharmonic shift about -18 A^2 relative (cubic and quartic terms of
   * the well, Landau-Lifshitz, Mechanics, section 28) = 4.5e-4; midpoint
   * phase error (omega dT)^2/24 = 4e-6: a 1e-3 tolerance, which a wrong
   * k_eff or mass (factor 2 in either) misses by far. */
  CHECK(crossings >= 9, "dimer oscillates (%d crossings)", crossings);
  CHECK_NEAR(2 * M_PI / period / omega, 1.0, 1e-3,
             "lennard-jones dimer frequency / sqrt(k_eff/mu)");
  /* Centre of the oscillation: r0 + O(A^2) (about 1.2e-4 here). */
  CHECK_NEAR(0.5 * (rmax + rmin), r0, 3e-4, "dimer oscillates about 2^1/6 sig");
  CHECK_NEAR(0.5 * (rmax - rmin), A, 0.1 * A, "dimer amplitude");
  mrvi_integrator_free(it);
  mrvi_model_free(m);
}

/* A molecule-like system with every new element in a multirate run: a fast
 * bent triatomic (linear bonds, fast angle, fast constant force) tied to a
 * slow heavy particle by a Morse bond, an inverse-law repulsion and a slow
 * angle.  The elements' derivatives are checked against FD above; here
 * they must work slow and fast inside the step: Newton converges to 1e-10
 * in few iterations and the energy error stays small (measured 2.4e-6
 * midpoint, 5.6e-4 trapezoidal-midpoint at dT = 0.02, p = 5). */
static void check_molecule_run(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double v0[2] = {0, 0}, va[2] = {0.3, -0.2};
  const double xa[2] = {1.0, 0.0}, xb[2] = {0.0, 0.0}, xc[2] = {-0.3, 0.95},
               xd[2] = {0.2, -2.0};
  mrvi_model_add_particle(m, "a", 1.0, MRVI_FAST, xa, va);
  mrvi_model_add_particle(m, "b", 1.0, MRVI_FAST, xb, v0);
  mrvi_model_add_particle(m, "c", 1.0, MRVI_FAST, xc, v0);
  mrvi_model_add_particle(m, "d", 10.0, MRVI_SLOW, xd, v0);
  const double k[1] = {100.0}, morse[2] = {1.0, 1.2}, inv[1] = {0.5};
  int ok =
      mrvi_model_add_spring(m, MRVI_FAST, 0, 1, "linear", k, 1.0) >= 0 &&
      mrvi_model_add_spring(m, MRVI_FAST, 1, 2, "linear", k, 1.0) >= 0 &&
      mrvi_model_add_angle(m, MRVI_FAST, 0, 1, 2, 5.0, 1.9) >= 0 &&
      mrvi_model_add_spring(m, MRVI_SLOW, 1, 3, "morse", morse, 1.8) >= 0 &&
      mrvi_model_add_spring(m, MRVI_SLOW, 0, 3, "inverse", inv, 0.0) >= 0 &&
      mrvi_model_add_angle(m, MRVI_SLOW, 0, 1, 3, 0.5, NAN) >= 0;
  const int fc[1] = {4};
  const double f[1] = {0.2};
  ok = ok && mrvi_model_add_force(m, MRVI_FAST, 1, fc, f) >= 0;
  CHECK(ok, "molecule built: %s", mrvi_model_errmsg(m));
  const char *schemes[2] = {"midpoint-midpoint", "trapezoidal-midpoint"};
  for (int i = 0; i < 2 && ok; i++) {
    mrvi_settings s = test_settings(schemes[i], 0.02, 5, 4.0, 1e-10);
    mrvi_summary sum;
    const int st = mrvi_run(m, &s, NULL, NULL, NULL, &sum);
    CHECK(st == MRVI_OK, "%s molecule run: %s", schemes[i], sum.message);
    CHECK(sum.iterations_max <= 4, "%s: at most 4 Newton iterations (%d)",
          schemes[i], sum.iterations_max);
    CHECK(sum.max_rel_energy_error < 2e-3, "%s: energy error %.2e", schemes[i],
          sum.max_rel_energy_error);
  }
  mrvi_model_free(m);
}

/* Terms of every kernel of mrvi_terms_grad (solver/terms.c): runs of
 * one-input linear terms, linear and integer-power terms of 1..4 inputs,
 * powers of every small exponent, a real exponent and a Morse law (the law
 * table), five inputs (the general kernel). */
static mrvi_model *terms_model(void) {
  mrvi_model *m = mrvi_model_create();
  for (int i = 0; i < 6; i++)
    mrvi_model_add_coordinate(
        m, (const char *[]){"a", "b", "c", "d", "e", "f"}[i], 1.0 + i,
        i < 3 ? MRVI_SLOW : MRVI_FAST, 0.3 * i - 0.7, 0.0);
  const int c[6] = {0, 3, 1, 4, 2, 5}, cf[3] = {3, 4, 5};
  const double a[6] = {1.0, -1.0, 0.5, 2.0, -1.5, 0.25};
  const double lin[1] = {7.0}, mo[2] = {2.0, 1.5}, real[2] = {0.6, 2.5};
  /* W (fast coordinates only): a run of one-input linear terms, powers */
  for (int i = 0; i < 3; i++)
    mrvi_model_add_term(m, MRVI_FAST, 1, cf + i, a + i, 0.1 * i, "linear", lin);
  for (int k = 2; k <= 3; k++) {
    const double pw[2] = {0.4, k};
    mrvi_model_add_term(m, MRVI_FAST, k, cf, a, 0.1, "power", pw);
  }
  /* V: phi = 0.3 s^k on k % 4 + 1 inputs, linear terms of 1..5 inputs */
  for (int k = 0; k <= 6; k++) {
    const double pw[2] = {0.3, k};
    mrvi_model_add_term(m, MRVI_SLOW, k % 4 + 1, c, a, 0.2, "power", pw);
  }
  for (int n = 1; n <= 5; n++)
    mrvi_model_add_term(m, MRVI_SLOW, n, c + 6 - n, a, -0.1, "linear", lin);
  mrvi_model_add_term(m, MRVI_SLOW, 2, c, a, -2.0, "power", real);
  mrvi_model_add_term(m, MRVI_SLOW, 3, c + 1, a, 0.3, "morse", mo);
  return m;
}

/* Classes of compact terms alone (mrvi_terms_grad's flat loop): V with
 * 2..4 inputs and mixed laws (linear, s^3, s^4, s^4), W with quartics on
 * 2 and 3 inputs (one law). */
static mrvi_model *flat_model(void) {
  mrvi_model *m = mrvi_model_create();
  for (int i = 0; i < 6; i++)
    mrvi_model_add_coordinate(
        m, (const char *[]){"a", "b", "c", "d", "e", "f"}[i], 1.0 + i,
        i < 3 ? MRVI_SLOW : MRVI_FAST, 0.2 * i - 0.5, 0.0);
  const int c[6] = {0, 3, 1, 4, 2, 5}, cf[3] = {3, 4, 5};
  const double a[6] = {1.0, -1.0, 0.5, 2.0, -1.5, 0.25};
  const double lin[1] = {3.0}, p3[2] = {0.5, 3}, p4[2] = {0.25, 4};
  mrvi_model_add_term(m, MRVI_SLOW, 2, c, a, 0.1, "linear", lin);
  mrvi_model_add_term(m, MRVI_SLOW, 3, c + 1, a + 1, -0.2, "power", p3);
  mrvi_model_add_term(m, MRVI_SLOW, 4, c + 2, a, 0.0, "power", p4);
  mrvi_model_add_term(m, MRVI_SLOW, 2, c + 4, a + 2, 0.3, "power", p4);
  for (int n = 2; n <= 3; n++)
    mrvi_model_add_term(m, MRVI_FAST, n, cf + 3 - n, a + n, 0.1 * n, "power",
                        p4);
  mrvi_model_add_term(m, MRVI_FAST, 3, cf, a + 1, -0.1, "power", p4);
  mrvi_model_add_term(m, MRVI_FAST, 2, cf, a, 0.0, "power", p4);
  return m;
}

/* mrvi_terms_eval_set at z (n columns) into J of ld x ld filled with NaN
 * first: the gradient of mrvi_terms_eval bitwise; its Hessian, the entries
 * beyond n zero; for a flat class exactly symmetric and bitwise
 * mrvi_terms_eval's where the class's coefficients are all +-1 (exact
 * products), else to 1e-14; for any other class bitwise. */
static void check_eval_set(mrvi_terms *kc, const double *z, int n, int ld,
                           int unit, const char *what) {
  const int flat = mrvi_terms_flat(kc) > 0;
  unit = unit || !flat;
  const size_t nl = (size_t)ld;
  double *g1 = calloc((size_t)n, sizeof *g1),
         *g2 = calloc((size_t)n, sizeof *g2);
  double *J1 = calloc((size_t)n * (size_t)n, sizeof *J1),
         *J2 = calloc(nl * nl, sizeof *J2);
  for (size_t i = 0; i < nl * nl; i++)
    J2[i] = NAN;
  mrvi_terms_eval(kc, z, 1.0, g1, J1, n, 1.0);
  mrvi_terms_eval_set(kc, z, g2, J2, ld);
  CHECK(memcmp(g1, g2, (size_t)n * sizeof *g1) == 0,
        "%s: eval_set's gradient bitwise mrvi_terms_eval's", what);
  int sym = 1, zero = 1, same = 1;
  for (int i = 0; i < ld; i++)
    for (int l = 0; l < ld; l++) {
      const double v = J2[(size_t)i * nl + (size_t)l];
      sym = sym && (!flat ||
                    memcmp(&v, &J2[(size_t)l * nl + (size_t)i], sizeof v) == 0);
      if (i >= n || l >= n) {
        zero = zero && v == 0.0;
        continue;
      }
      const double w = J1[i * n + l];
      same = same && (unit ? v == w : fabs(v - w) <= 1e-14 * (1 + fabs(w)));
    }
  CHECK(sym, "%s: eval_set's Hessian exactly symmetric (ld %d)", what, ld);
  CHECK(zero, "%s: eval_set's Hessian zero beyond column %d (ld %d)", what, n,
        ld);
  CHECK(same, "%s: eval_set's Hessian %s mrvi_terms_eval's (ld %d)", what,
        unit ? "bitwise" : "within 1e-14 of", ld);
  free(g1);
  free(g2);
  free(J1);
  free(J2);
}

/* A weighted sum of Hessians from phi'' per term (mrvi_terms_grad_d2 at
 * three configurations, mrvi_terms_hess_d2): each gradient bitwise
 * mrvi_terms_grad's; the sum, over all columns, within 1e-13 of the sum of
 * mrvi_terms_eval's Hessians; over the columns below lim = n - 1 the same
 * entries and nothing at or beyond lim. */
static void check_hess_d2(mrvi_terms *kc, const mrvi_model *m, int n, int c,
                          const char *what) {
  const int nt = mrvi_terms_count(kc);
  double *dsum = calloc((size_t)nt + 1, sizeof *dsum);
  double *q = calloc((size_t)n, sizeof *q), *g1 = calloc((size_t)n, sizeof *g1),
         *g2 = calloc((size_t)n, sizeof *g2);
  double *H = calloc((size_t)n * (size_t)n, sizeof *H),
         *S = calloc((size_t)n * (size_t)n, sizeof *S),
         *L = calloc((size_t)n * (size_t)n, sizeof *L);
  const double w[3] = {0.25, -1.5, 3.0};
  for (int r = 0; r < 3; r++) {
    for (int i = 0; i < n; i++) {
      q[i] = m->q0[i] + 0.1 * cos(2.0 * i + c + 1.3 * r);
      g1[i] = g2[i] = 0.0;
    }
    memset(H, 0, (size_t)n * (size_t)n * sizeof *H);
    mrvi_terms_eval(kc, q, 1.0, g1, H, n, 1.0);
    for (int i = 0; i < n * n; i++)
      S[i] += w[r] * H[i];
    memset(g1, 0, (size_t)n * sizeof *g1);
    mrvi_terms_grad(kc, q, g1);
    mrvi_terms_grad_d2(kc, q, g2, w[r], dsum);
    CHECK(memcmp(g1, g2, (size_t)n * sizeof *g1) == 0,
          "%s class %d: grad_d2's gradient bitwise mrvi_terms_grad's", what, c);
  }
  memset(H, 0, (size_t)n * (size_t)n * sizeof *H);
  mrvi_terms_hess_d2(kc, dsum, H, n, n);
  mrvi_terms_hess_d2(kc, dsum, L, n, n - 1);
  double err = 0.0, scale = 0.0, rest = 0.0, lerr = 0.0;
  for (int i = 0; i < n; i++)
    for (int j = 0; j < n; j++) {
      err = fmax(err, fabs(H[i * n + j] - S[i * n + j]));
      scale = fmax(scale, fabs(S[i * n + j]));
      if (i < n - 1 && j < n - 1)
        lerr = fmax(lerr, fabs(L[i * n + j] - H[i * n + j]));
      else
        rest = fmax(rest, fabs(L[i * n + j]));
    }
  CHECK(scale > 0.0 && err <= 1e-13 * scale,
        "%s class %d: hess_d2 %.2e off the summed Hessians (max %.2e)", what, c,
        err, scale);
  CHECK(lerr == 0.0 && rest == 0.0,
        "%s class %d: hess_d2 below lim: %.2e off, %.2e beyond", what, c, lerr,
        rest);
  free(dsum);
  free(q);
  free(g1);
  free(g2);
  free(H);
  free(S);
  free(L);
}

/* mrvi_terms_grad is mrvi_terms_eval at scale 1 without a Hessian, bitwise,
 * and both are the model's potential gradient (to rounding);
 * mrvi_terms_value is the model's potential value, bitwise;
 * mrvi_terms_eval_set as check_eval_set. */
static void check_terms_grad(const mrvi_model *m, const char *what) {
  const int n = m->n;
  int *elems = calloc((size_t)m->n_elements + 1, sizeof *elems);
  double *q = calloc((size_t)n, sizeof *q), *g1 = calloc((size_t)n, sizeof *g1);
  double *g2 = calloc((size_t)n, sizeof *g2),
         *gm = calloc((size_t)n, sizeof *gm);
  for (int c = 0; c < 2; c++) {
    int ne = 0;
    for (int e = 0; e < m->n_elements; e++)
      if (m->erecs[e].potential == (mrvi_rate)c)
        elems[ne++] = e;
    mrvi_terms *kc = NULL;
    CHECK(mrvi_terms_create(m, elems, ne, NULL, &kc) == MRVI_OK, "%s: create",
          what);
    if (!kc)
      continue;
    /* Which gradient loop it takes: the flat one for a class of linear and
     * small integer-power terms on 2..4 inputs (one law: 1, mixed: 2). */
    int compact = ne > 0, one_law = 1;
    const mrvi_element *e0 = ne > 0 ? MRVI_ELEMENT(m, elems[0]) : NULL;
    for (int i = 0; i < ne && compact; i++) {
      const mrvi_element *e = MRVI_ELEMENT(m, elems[i]);
      const int term = e->kind == MRVI_ELEMENT_TERM && e->n_in >= 2 &&
                       e->n_in <= 4 && e0->kind == MRVI_ELEMENT_TERM;
      const int linear = term && strcmp(e->law->name, "linear") == 0;
      const int power = term && strcmp(e->law->name, "power") == 0 &&
                        e->params[1] >= 0 && e->params[1] <= 8 &&
                        e->params[1] == (int)e->params[1];
      compact = linear || power;
      one_law = one_law && compact && e->law == e0->law &&
                (linear || e->params[1] == e0->params[1]);
    }
    const int flat = compact ? (one_law ? 1 : 2) : 0;
    int unit = 1; /* coefficients +-1 */
    for (int i = 0; i < ne; i++) {
      const mrvi_element *e = MRVI_ELEMENT(m, elems[i]);
      for (int j = 0; j < e->n_in && e->coef; j++)
        unit = unit && fabs(e->coef[j]) == 1.0;
    }
    CHECK(mrvi_terms_flat(kc) == flat, "%s class %d: flat loop %d, expected %d",
          what, c, mrvi_terms_flat(kc), flat);
    for (int r = 0; r < 8; r++) { /* configurations around q0 */
      for (int i = 0; i < n; i++) {
        q[i] = m->q0[i] + 0.05 * sin(3.0 * i + c + 0.7 * r);
        g1[i] = g2[i] = gm[i] = 0.0;
      }
      mrvi_terms_eval(kc, q, 1.0, g1, NULL, 0, 0.0);
      mrvi_terms_grad(kc, q, g2);
      const double v = mrvi_model_potential(m, (mrvi_rate)c, q, gm, NULL);
      const double vt = mrvi_terms_value(kc, q);
      CHECK(memcmp(&v, &vt, sizeof v) == 0,
            "%s class %d: value %.17g bitwise the model's %.17g", what, c, vt,
            v);
      CHECK(memcmp(g1, g2, (size_t)n * sizeof *g1) == 0,
            "%s class %d: grad kernel bitwise the general evaluation", what, c);
      for (int i = 0; i < n; i++)
        CHECK_NEAR(g2[i], gm[i], 1e-13 * (1 + fabs(gm[i])), what);
      /* (ld = n, n + 2 and, at r = 2, n + 5: J cleared in line up to
       * ld = 8, by memset beyond) */
      check_eval_set(kc, q, n, n + (r & 1) * 2 + (r == 2) * 5, unit, what);
    }
    if (flat)
      check_hess_d2(kc, m, n, c, what);
    mrvi_terms_free(kc);
  }
  free(elems);
  free(q);
  free(g1);
  free(g2);
  free(gm);
}

/* A law's properties are fields of its table (degree, form), and they
 * agree with its eval: a degree <= 2 has a constant phi'', a form gives phi
 * in closed form. */
static void check_law_properties(void) {
  const double params[][MRVI_LAW_MAX_PARAMS] = {
      {1.25, 4}, {0.7, 2}, {-0.3, 3}, {2.0, 1}, {1.0, 2.5}, {0.5, 0}};
  const double strains[] = {0.3, 0.7, 1.3, 1.9};
  for (int i = 0; i < mrvi_law_count(); i++) {
    const mrvi_law *law = mrvi_law_get(i);
    for (size_t a = 0; a < sizeof params / sizeof params[0]; a++) {
      const double *par = params[a];
      char msg[128];
      if (law->check && law->check(par, msg, sizeof msg) < 0)
        continue;
      const int d = law->degree ? law->degree(par) : -1;
      double lo = INFINITY, hi = -INFINITY;
      for (size_t b = 0; b < sizeof strains / sizeof strains[0]; b++) {
        const double s = strains[b];
        double f, df, ddf;
        law->eval(par, s, &f, &df, &ddf);
        lo = fmin(lo, ddf);
        hi = fmax(hi, ddf);
        if (law->form == MRVI_LAW_FORM_HOOKE)
          CHECK(f == 0.5 * par[0] * s * s && df == par[0] * s && ddf == par[0],
                "%s (%g): not k s^2 / 2 at s = %g", law->name, par[0], s);
        if (law->form == MRVI_LAW_FORM_POWER)
          CHECK_NEAR(f, par[0] * pow(s, par[1]), 1e-14 * fabs(f), law->name);
      }
      /* phi'' constant exactly where the degree says <= 2 */
      const int flat = hi - lo <= 1e-14 * fabs(hi);
      CHECK(flat == (d >= 0 && d <= 2),
            "%s (%g, %g): degree %d, phi'' from %g to %g", law->name, par[0],
            par[1], d, lo, hi);
    }
  }
}

/* The solvers read a law's fields, never which table it is: copies of the
 * power and linear tables under other names give the FPU bitwise the same
 * run on every path (schur with the constant chord and with shooting,
 * sweep, explicit, general); a user law is quadratic by its degree; a form
 * without the parameters it reads is refused. */
static mrvi_law power_copy, linear_copy;
static void cubic_like(const double *par, double s, double *phi, double *dphi,
                       double *ddphi) {
  *phi = par[0] * s * s;
  *dphi = 2 * par[0] * s;
  *ddphi = 2 * par[0];
}
static int degree_two(const double *par) {
  (void)par;
  return 2;
}
static void check_law_copies(void) {
  power_copy = *mrvi_law_find("power");
  power_copy.name = "power-copy";
  linear_copy = *mrvi_law_find("linear");
  linear_copy.name = "linear-copy";
  CHECK(mrvi_law_register(&power_copy) == 0 &&
            mrvi_law_register(&linear_copy) == 0,
        "register the copies");
  mrvi_model *a = test_fpu(), *b = test_fpu_laws("power-copy", "linear-copy");
  static const struct {
    const char *scheme;
    double dT;
    int p;
    mrvi_solver solver;
  } runs[] = {{"midpoint-midpoint", 0.002, 2, MRVI_SOLVER_AUTO},
              {"trapezoidal-trapezoidal", 0.01, 10, MRVI_SOLVER_AUTO},
              {"explicit-slow", 0.01, 5, MRVI_SOLVER_AUTO},
              {"fully-explicit", 0.01, 5, MRVI_SOLVER_AUTO},
              {"midpoint-midpoint", 0.01, 5, MRVI_SOLVER_GENERAL}};
  for (size_t r = 0; a && b && r < sizeof runs / sizeof runs[0]; r++) {
    mrvi_settings s =
        test_settings(runs[r].scheme, runs[r].dT, runs[r].p, 1.0, 1e-10);
    s.solver = runs[r].solver;
    mrvi_integrator *ia = NULL, *ib = NULL;
    char msg[300];
    int ok = mrvi_integrator_create(a, &s, &ia, msg, sizeof msg) == 0 &&
             mrvi_integrator_create(b, &s, &ib, msg, sizeof msg) == 0;
    for (int k = 0; ok && k < 20; k++)
      ok = mrvi_integrator_step(ia) == 0 && mrvi_integrator_step(ib) == 0 &&
           memcmp(mrvi_integrator_q(ia), mrvi_integrator_q(ib),
                  6 * sizeof(double)) == 0 &&
           memcmp(mrvi_integrator_p(ia), mrvi_integrator_p(ib),
                  6 * sizeof(double)) == 0;
    CHECK(ok, "fpu %s (%s) with copied laws: not bitwise the same (%s)",
          runs[r].scheme, ia ? mrvi_integrator_solver_path(ia) : "-", msg);
    mrvi_integrator_free(ia);
    mrvi_integrator_free(ib);
  }
  mrvi_model_free(a);
  mrvi_model_free(b);

  static const char *const names[] = {"c"};
  static mrvi_law square = {.name = "square",
                            .summary = "c s^2",
                            .n_params = 1,
                            .param_names = names,
                            .eval = cubic_like};
  CHECK(mrvi_law_register(&square) == 0, "register square");
  mrvi_model *m = mrvi_model_create();
  mrvi_model_add_coordinate(m, "q", 1, MRVI_SLOW, 0.5, 0);
  const int c = 0;
  const double one = 1, par[1] = {2.0};
  CHECK(mrvi_model_add_term(m, MRVI_SLOW, 1, &c, &one, 0, "square", par) == 0,
        "term with square");
  CHECK(!mrvi_element_is_quadratic(MRVI_ELEMENT(m, 0)),
        "a law without a degree taken as quadratic");
  square.degree = degree_two; /* (read when asked) */
  CHECK(mrvi_element_is_quadratic(MRVI_ELEMENT(m, 0)),
        "a law of degree 2 not taken as quadratic");
  mrvi_model_free(m);
  static mrvi_law bad = {.name = "bad-power",
                         .n_params = 1,
                         .param_names = names,
                         .eval = cubic_like,
                         .form = MRVI_LAW_FORM_POWER};
  CHECK(mrvi_law_register(&bad) == MRVI_EINVAL,
        "a power form with one parameter registered");
}

/* The model's compact spring table (model.h, mrvi_erec): every spring of
 * every registered law added between two particles, in 1-D, 2-D and 3-D,
 * slow and fast, with parameter sets shared and not, between anchors,
 * terms and gravity (kept in full), reads back through the accessor as it
 * was added: kind, rate, law, parameters, rest length (bits), inputs,
 * particles; the prototypes the compiled terms keep stay valid while more
 * laws are added. */
static void check_compact_table(void) {
  for (int d = 1; d <= 3; d++) {
    mrvi_model *m = mrvi_model_create();
    mrvi_model_set_dimension(m, d);
    const double v[3] = {0, 0, 0};
    for (int i = 0; i < 6; i++) {
      char name[16];
      snprintf(name, sizeof name, "p%d", i);
      const double x[3] = {0.9 * i, 0.1 * i * i, -0.3 * i};
      CHECK(mrvi_model_add_particle(m, name, 1.0 + i,
                                    i < 2 ? MRVI_SLOW : MRVI_FAST, x, v) >= 0,
            "compact: particle (%s)", mrvi_model_errmsg(m));
    }
    enum { MAX_ADD = 512 };
    struct {
      int e, i, j, slow;
      const mrvi_law *law;
      double par[MRVI_LAW_MAX_PARAMS], rest;
      const mrvi_element *stable;
    } add[MAX_ADD];
    int na = 0, full = 0;
    const double sets[][MRVI_LAW_MAX_PARAMS] = {
        {1.25, 4, 3.0}, {0.7, 2, 2.5}, {2.0, 1.5, 4.0}, {-0.0, 3, 2.0}};
    for (int l = 0; l < mrvi_law_count(); l++) {
      const mrvi_law *law = mrvi_law_get(l);
      for (size_t a = 0; a < sizeof sets / sizeof sets[0]; a++) {
        char msg[128];
        if (law->check && law->check(sets[a], msg, sizeof msg) < 0)
          continue;
        for (int r = 0; r < 3 && na < MAX_ADD; r++) {
          const int slow = (r + (int)a) % 2, i = slow ? r % 2 : 2 + r,
                    j = slow ? 5 - r : 3 + (r + 1) % 3;
          const double rest = r == 1 ? -0.0 : 0.25 * (1 + r + (int)a);
          const int e = mrvi_model_add_spring(m, slow ? MRVI_SLOW : MRVI_FAST,
                                              i, j, law->name, sets[a], rest);
          CHECK(e == mrvi_model_n_elements(m) - 1, "compact: %s added (%s)",
                law->name, mrvi_model_errmsg(m));
          if (e < 0)
            continue;
          add[na].e = e;
          add[na].i = i;
          add[na].j = j;
          add[na].slow = slow;
          add[na].law = law;
          memcpy(add[na].par, sets[a], sizeof add[na].par);
          add[na].rest = rest;
          add[na].stable = mrvi_element_stable(MRVI_ELEMENT(m, e));
          na++;
        }
        /* (elements kept in full between them) */
        const double anchor[3] = {0.5, -1.0, 2.0}, k[1] = {3.0};
        if (mrvi_model_add_anchor_spring(m, MRVI_FAST, 4, anchor, "linear", k,
                                         0.5) >= 0)
          full++;
      }
    }
    const double g[3] = {0.1, -9.81, 0.3};
    CHECK(mrvi_model_set_gravity(m, g) >= 0, "compact: gravity");
    full++;
    CHECK(na >= 3 * mrvi_law_count() && m->n_full == full &&
              m->n_elements == na + full,
          "compact: %d springs in records, %d elements in full", na, m->n_full);
    for (int a = 0; a < na; a++) {
      const mrvi_element *e = MRVI_ELEMENT(m, add[a].e);
      const mrvi_law *law = add[a].law;
      int ok = m->erecs[add[a].e].compact && e->kind == MRVI_ELEMENT_SPRING &&
               e->potential == (add[a].slow ? MRVI_SLOW : MRVI_FAST) &&
               e->law == law && e->form == law->form && !e->coef &&
               e->n_in == 2 * d &&
               memcmp(&e->shift, &add[a].rest, sizeof e->shift) == 0 &&
               memcmp(e->params, add[a].par,
                      (size_t)law->n_params * sizeof *e->params) == 0 &&
               mrvi_element_particle(m, e, 0) == add[a].i &&
               mrvi_element_particle(m, e, d) == add[a].j;
      for (int k = 0; k < d; k++)
        ok &= e->in[k] == mrvi_particle_first(m, add[a].i) + k &&
              e->in[d + k] == mrvi_particle_first(m, add[a].j) + k;
      /* (the prototype the terms keep: the law, parameters and rate) */
      const mrvi_element *p = add[a].stable;
      ok &= p == mrvi_element_stable(e) && p->law == law &&
            p->params == e->params && p->potential == e->potential &&
            p->kind == MRVI_ELEMENT_SPRING && !p->coef;
      CHECK(ok, "compact: %dD spring %d (%s) reads back as added", d, a,
            law->name);
    }
    /* (equal law and parameters share a prototype; a rate does not) */
    CHECK(add[0].stable == MRVI_ELEMENT(m, add[0].e)->proto &&
              add[0].stable != add[1].stable,
          "compact: prototypes by law, parameters and rate");
    mrvi_model_free(m);
  }
}

/* Counts beyond an int (the compact table's 32-bit first coordinates and
 * prototype indices, every int count of the model): mrvi_model_reserve
 * refuses them with a message before it allocates, and the model is as
 * before; a generator too (mrvi_model_room). */
static void check_model_room(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 3);
  const double x[3] = {0, 0, 0};
  const double x1[3] = {1, 0, 0}, k[1] = {1.0};
  CHECK(mrvi_model_add_particle(m, "a", 1.0, MRVI_SLOW, x, x) == 0 &&
            mrvi_model_add_particle(m, "b", 1.0, MRVI_SLOW, x1, x) == 1 &&
            mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "linear", k, 1.0) == 0,
        "room: particles (%s)", mrvi_model_errmsg(m));
  const int cap = m->cap, cap_e = m->cap_elements;
  /* 6 + 3 floor((2^31 - 1) / 3) coordinates; 1 + (2^31 - 1) elements */
  const int st = mrvi_model_reserve(m, INT_MAX / 3, 0);
  CHECK(st == MRVI_EINVAL && m->cap == cap && m->n == 6 &&
            strstr(mrvi_model_errmsg(m), "the model would have 2147483652 "
                                         "coordinates") != NULL,
        "room: %d, '%s'", st, mrvi_model_errmsg(m));
  const int se = mrvi_model_reserve(m, 0, INT_MAX);
  CHECK(se == MRVI_EINVAL && m->cap_elements == cap_e && m->n_elements == 1 &&
            strstr(mrvi_model_errmsg(m), "2147483648 elements") != NULL,
        "room: elements %d, '%s'", se, mrvi_model_errmsg(m));
  /* a ring of 10^6 x 1 particles 2000 times: within an int per generator,
   * beyond one for the model (mrvi_model_room's sum, as the loader's) */
  char msg[256] = "";
  CHECK(mrvi_model_room(m, 2000.0 * 1e6, 2000.0 * 1e6, NULL, msg, sizeof msg) ==
                MRVI_EINVAL &&
            strstr(msg, "6000000006 coordinates") != NULL,
        "room: sum '%s'", msg);
  CHECK(mrvi_model_room(m, 10, 10, NULL, msg, sizeof msg) == MRVI_OK,
        "room: 10 particles refused: %s", msg);
  mrvi_model_free(m);
}

int main(void) {
  check_compact_table();
  check_model_room();
  check_law_properties();
  check_law_copies();
  check_laws();
  check_pair_laws();
  check_angles_forces();
  check_lj_dimer();
  check_molecule_run();

  mrvi_model *fpu = test_fpu(), *ring = test_spring_ring();
  check_elements(fpu, "fpu element");
  check_elements(ring, "spring ring element");
  check_potential(fpu, "fpu potential");
  check_potential(ring, "spring ring potential");
  for (int d = 1; d <= 3; d++) {
    mrvi_model *m = mixed_model(d);
    check_elements(m, "mixed element");
    check_potential(m, "mixed potential");
    mrvi_model_free(m);
  }
  check_zero_length();
  check_terms_grad(fpu, "fpu terms");
  check_terms_grad(ring, "spring ring terms");
  for (int d = 1; d <= 3; d++) {
    mrvi_model *m = mixed_model(d);
    check_terms_grad(m, "mixed terms");
    mrvi_model_free(m);
  }
  mrvi_model *tm = terms_model();
  CHECK(tm && tm->n_elements == 3 + 2 + 7 + 5 + 2, "terms model built");
  check_terms_grad(tm, "term kernels");
  mrvi_model_free(tm);
  mrvi_model *fm = flat_model();
  CHECK(fm && fm->n_elements == 8, "flat terms model built (%s)",
        fm ? mrvi_model_errmsg(fm) : "");
  check_terms_grad(fm, "flat term kernels");
  mrvi_model_free(fm);
  mrvi_model_free(fpu);
  mrvi_model_free(ring);
  return test_finish();
}
