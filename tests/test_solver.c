/* Step solver paths (doc/solver.md): every structured path against the
 * general Newton path on every shipped system, scheme, p and constraint
 * form; the explicit path without Newton iterations; path choice and its
 * refusal; solves with the step Jacobian and its transpose against the
 * assembled CSC matrix. */
#include "integrator/integrator.h"
#include "models.h"
#include "testlib.h"

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/umfpack.h>

static const char *const systems[] = {
    "systems/cart_pendulum.yaml", "systems/fpu.yaml",
    "systems/oscillator.yaml",    "systems/pendulum_chain.yaml",
    "systems/spring_ring.yaml",   "systems/spring_ring_rod.yaml",
    "systems/triatomic.yaml",     "systems/lattice.yaml"};
#define N_SYSTEMS ((int)(sizeof systems / sizeof systems[0]))
#define N_STEPS 20

static mrvi_system *load(const char *rel, const char *scheme, int p,
                         const char *form, const char *solver) {
  char ov[8][96];
  const char *ovp[8];
  snprintf(ov[0], sizeof ov[0], "integrator.scheme=%s", scheme);
  snprintf(ov[1], sizeof ov[1], "integrator.micro_steps=%d", p);
  snprintf(ov[2], sizeof ov[2], "integrator.newton.tolerance=1e-12");
  snprintf(ov[3], sizeof ov[3], "integrator.solver=%s", solver);
  snprintf(ov[4], sizeof ov[4], "integrator.constraints.form=%s", form);
  /* The FPU file's dT = 0.3 is for the midpoint rules; trapezoidal-
   * trapezoidal needs the paper's 0.03 (§6).  The pendulum chain's stiff
   * links at p = 1 need dT below 2/omega for the explicit fast rules. */
  const char *dT = strstr(rel, "fpu")              ? "0.03"
                   : strstr(rel, "pendulum_chain") ? "0.002"
                                                   : NULL;
  /* Every path from the same predictor (the joint sweep, schur-bordered's
   * with micro-node constraints, is tested in test_torsion; its steps agree
   * with general's to the tolerance, not to this comparison's 1e-10 over
   * 20 steps on cart_pendulum) */
  snprintf(ov[5], sizeof ov[5], "integrator.tuning.predict_joints=0");
  /* The constraint rows to the same tolerance (schur-bordered's updates
   * with kept factors stop at 0.01 times it, where full Newton's land
   * lower: at the file's 1e-10 the triatomic molecule's steps differ by
   * 5e-13 in g, 2e-10 after 20 trapezoidal steps) */
  snprintf(ov[6], sizeof ov[6], "integrator.constraints.tolerance=1e-12");
  snprintf(ov[7], sizeof ov[7], "integrator.macro_step=%s", dT ? dT : "");
  const int n_ov = dT ? 8 : 7;
  for (int i = 0; i < 8; i++)
    ovp[i] = ov[i];
  mrvi_system *sys = NULL;
  char msg[512];
  if (mrvi_system_load(test_source_path(rel), ovp, n_ov, &sys, msg,
                       sizeof msg) < 0) {
    CHECK(0, "load %s: %s", rel, msg);
    return NULL;
  }
  return sys;
}

typedef struct run_out {
  double q[N_STEPS + 1][64], p[N_STEPS + 1][64];
  double micro[N_STEPS][320];
  int iters[N_STEPS];
  const char *path;
  int n, nmicro, ok;
  long nfac;   /* factorisations of the schur path */
  long nshoot; /* steps solved by shooting */
  long nlast;  /* ... with the last update made without its sweep */
} run_out;

/* The integrator's chord and constant-chord modes for run()
 * (MRVI_CHORD_AUTO by default). */
static int run_chord = MRVI_CHORD_AUTO, run_cchord = MRVI_CHORD_AUTO,
           run_shoot = MRVI_CHORD_AUTO;
/* 1: run() keeps the last micro node alone (mrvi_integrator_keep_micro),
 * storing it as the step's micro nodes' last row. */
static int run_last_only = 0;

static void run(const mrvi_system *sys, run_out *o) {
  mrvi_integrator *it = NULL;
  char msg[512];
  o->ok = 0;
  const mrvi_model *m = sys->model;
  o->n = mrvi_model_n(m);
  o->nmicro = sys->settings.micro_steps * m->n_fast;
  if (o->n > 64 || o->nmicro > 320) {
    CHECK(0, "test buffers too small");
    return;
  }
  if (mrvi_integrator_create(m, &sys->settings, &it, msg, sizeof msg) < 0) {
    CHECK(0, "create: %s", msg);
    return;
  }
  mrvi_integrator_set_chord(it, run_chord);
  mrvi_integrator_set_const_chord(it, run_cchord);
  mrvi_integrator_set_shoot(it, run_shoot);
  const int p = sys->settings.micro_steps, nf = m->n_fast;
  const int rows = mrvi_integrator_keep_micro(it, !run_last_only);
  if (rows != (run_last_only ? 1 : p)) {
    CHECK(0, "keep_micro(%d): %d rows", !run_last_only, rows);
    mrvi_integrator_free(it);
    return;
  }
  o->path = mrvi_integrator_solver_path(it);
  memcpy(o->q[0], mrvi_integrator_q(it), (size_t)o->n * sizeof(double));
  memcpy(o->p[0], mrvi_integrator_p(it), (size_t)o->n * sizeof(double));
  for (int k = 0; k < N_STEPS; k++) {
    if (mrvi_integrator_step(it) < 0) {
      CHECK(0, "step %d: %s", k, mrvi_integrator_errmsg(it));
      mrvi_integrator_free(it);
      return;
    }
    memcpy(o->q[k + 1], mrvi_integrator_q(it), (size_t)o->n * sizeof(double));
    memcpy(o->p[k + 1], mrvi_integrator_p(it), (size_t)o->n * sizeof(double));
    if (rows == 1 && p > 1) /* the last row alone, the others zero */
      memcpy(o->micro[k] + (size_t)(p - 1) * nf, mrvi_integrator_micro_q(it),
             (size_t)nf * sizeof(double));
    else
      memcpy(o->micro[k], mrvi_integrator_micro_q(it),
             (size_t)o->nmicro * sizeof(double));
    o->iters[k] = mrvi_integrator_last_iterations(it);
  }
  o->nfac = mrvi_integrator_factorisations(it);
  o->nshoot = mrvi_integrator_shoot_steps(it);
  o->nlast = mrvi_integrator_shoot_last_steps(it);
  mrvi_integrator_free(it);
  o->ok = 1;
}

/* max |a - b| / max |a| over the run (q, p, micro q separately). */
static double rel_diff(const run_out *a, const run_out *b) {
  double worst = 0.0;
  for (int w = 0; w < 3; w++) {
    double d = 0.0, s = 0.0;
    for (int k = 0; k <= N_STEPS; k++) {
      const int n = w == 2 ? (k < N_STEPS ? a->nmicro : 0) : a->n;
      for (int i = 0; i < n; i++) {
        const double x = w == 0   ? a->q[k][i]
                         : w == 1 ? a->p[k][i]
                                  : a->micro[k][i];
        const double y = w == 0   ? b->q[k][i]
                         : w == 1 ? b->p[k][i]
                                  : b->micro[k][i];
        d = fmax(d, fabs(x - y));
        s = fmax(s, fabs(x));
      }
    }
    if (s > 0)
      worst = fmax(worst, d / s);
  }
  return worst;
}

/* Every path equals the general one (tolerance 1e-12, so both solutions
 * agree to ~1e-12 relative; 1e-10 leaves room for 20 steps of growth). */
static void test_paths_agree(void) {
  const char *const *schemes = mrvi_scheme_names();
  static run_out a, b;
  int n_explicit = 0, n_sweep = 0, n_schur = 0, n_bordered = 0;
  for (int sy = 0; sy < N_SYSTEMS; sy++)
    for (int sc = 0; schemes[sc]; sc++)
      for (int pi = 0; pi < 2; pi++)
        for (int f = 0; f < 2; f++) {
          const int p = pi ? 5 : 1;
          const char *form = f ? "null-space" : "multipliers";
          mrvi_system *sg = load(systems[sy], schemes[sc], p, form, "general");
          mrvi_system *sa = load(systems[sy], schemes[sc], p, form, "auto");
          if (!sg || !sa) {
            mrvi_system_free(sg);
            mrvi_system_free(sa);
            continue;
          }
          const int constrained = mrvi_model_constraint_rows(sg->model) > 0;
          if (f && !constrained) {
            mrvi_system_free(sg);
            mrvi_system_free(sa);
            continue;
          }
          run(sg, &a);
          run(sa, &b);
          if (a.ok && b.ok) {
            const double d = rel_diff(&a, &b);
            CHECK(d <= 1e-10, "%s %s p=%d %s: %s path vs general: %.2e",
                  systems[sy], schemes[sc], p, form, b.path, d);
            CHECK(strcmp(a.path, "general") == 0, "general path requested");
            const int slow_macro = sa->settings.slow_grid == MRVI_GRID_MACRO;
            /* Unconstrained models whose fast potential has fast inputs
             * only (all shipped ones) take a structured path for the
             * macro-grid schemes. */
            const int expl = strcmp(schemes[sc], "fully-explicit") == 0 ||
                             sa->model->n_fast == 0;
            /* Constrained: in the multiplier form the path of the cost
             * estimates (the shipped systems fit the dense limits;
             * test_constrained_paths checks the choice), general in the
             * null-space form. */
            const char *chosen =
                mrvi_solver_path(sa->model, &sa->settings, NULL, 0);
            const char *want = constrained   ? (f ? "general" : chosen)
                               : !slow_macro ? "schur"
                               : expl        ? "explicit"
                                             : "sweep";
            CHECK(strcmp(b.path, want) == 0, "%s %s: path %s", systems[sy],
                  schemes[sc], b.path);
            if (strcmp(b.path, "explicit") == 0) {
              n_explicit++;
              int mx = 0;
              for (int k = 0; k < N_STEPS; k++)
                mx = b.iters[k] > mx ? b.iters[k] : mx;
              CHECK(mx == 0, "explicit path: %d Newton iterations", mx);
            }
            if (strcmp(b.path, "sweep") == 0)
              n_sweep++;
            if (strcmp(b.path, "schur") == 0)
              n_schur++;
            if (strcmp(b.path, "schur-bordered") == 0)
              n_bordered++;
          }
          mrvi_system_free(sg);
          mrvi_system_free(sa);
        }
  CHECK(n_explicit >= 8 && n_sweep >= 4 && n_schur >= 18 && n_bordered >= 10,
        "structured paths exercised: %d explicit, %d sweep, %d schur, %d "
        "schur-bordered",
        n_explicit, n_sweep, n_schur, n_bordered);
}

/* integrator.solver = structured refuses schemes without a structured path
 * (a constrained model in the null-space form) and names the reason;
 * mrvi_solver_path agrees. */
static void test_choice(void) {
  mrvi_system *s = load("systems/triatomic.yaml", "midpoint-midpoint", 5,
                        "null-space", "structured");
  if (!s)
    return;
  char why[300] = "", msg[400] = "";
  CHECK(mrvi_solver_path(s->model, &s->settings, why, sizeof why) == NULL,
        "structured on a constrained model has no path");
  CHECK(strstr(why, "constrain") != NULL, "reason: %s", why);
  mrvi_integrator *it = NULL;
  CHECK(mrvi_integrator_create(s->model, &s->settings, &it, msg, sizeof msg) ==
                MRVI_EINVAL &&
            strstr(msg, "structured") != NULL,
        "create refuses: %s", msg);
  mrvi_integrator_free(it);
  mrvi_system_free(s);
  s = load("systems/triatomic.yaml", "fully-explicit", 5, "multipliers",
           "auto");
  if (!s)
    return;
  const char *path = mrvi_solver_path(s->model, &s->settings, why, sizeof why);
  CHECK(path && strcmp(path, "schur-bordered") == 0 &&
            strstr(why, "constrain") && strstr(why, "multipliers"),
        "constrained model in the multiplier form: %s", why);
  mrvi_system_free(s);
}

/* J x = b and J^T y = c with mrvi_integrator_jacobian_solve against the
 * CSC matrix assembled independently at the last step's data. */
static void test_jacobian_solve(void) {
  /* explicit, sweep, schur, general and (blocks beyond dense_max = 0)
   * schur-krylov paths */
  const char *const schemes[] = {"fully-explicit", "explicit-slow",
                                 "midpoint-midpoint", "midpoint-midpoint",
                                 "midpoint-midpoint"};
  const char *const solvers[] = {"auto", "auto", "auto", "general", "auto"};
  for (int sc = 0; sc < 5; sc++) {
    mrvi_system *s =
        load("systems/fpu.yaml", schemes[sc], 5, "multipliers", solvers[sc]);
    if (!s)
      continue;
    if (sc == 4)
      s->settings.tuning.dense_max = 0;
    const mrvi_model *m = s->model;
    mrvi_integrator *it = NULL;
    char msg[400];
    if (mrvi_integrator_create(m, &s->settings, &it, msg, sizeof msg) < 0) {
      CHECK(0, "create: %s", msg);
      mrvi_system_free(s);
      continue;
    }
    for (int k = 0; k < 3; k++)
      mrvi_integrator_step(it);
    /* Known data of the last step (k = 2 -> 3) and its solution. */
    const int n = m->n, ns = m->n_slow, nf = m->n_fast, p = 5;
    double qs0[64], qf0[64], ps0[64], pf0[64], qs1[64];
    mrvi_integrator *ref = NULL;
    mrvi_integrator_create(m, &s->settings, &ref, msg, sizeof msg);
    for (int k = 0; k < 2; k++)
      mrvi_integrator_step(ref);
    for (int i = 0; i < ns; i++) {
      qs0[i] = mrvi_integrator_q(ref)[m->slow_index[i]];
      ps0[i] = mrvi_integrator_p(ref)[m->slow_index[i]];
      qs1[i] = mrvi_integrator_q(it)[m->slow_index[i]];
    }
    for (int i = 0; i < nf; i++) {
      qf0[i] = mrvi_integrator_q(ref)[m->fast_index[i]];
      pf0[i] = mrvi_integrator_p(ref)[m->fast_index[i]];
    }
    mrvi_step st;
    mrvi_step_init(&st, m, &s->settings);
    st.qs0 = qs0;
    st.qf0 = qf0;
    st.ps0 = ps0;
    st.pf0 = pf0;
    const int N = st.n_total;
    CHECK(N == mrvi_integrator_jacobian_size(it), "size %d", N);
    double x[256], R[256], b[256], sol[256], xt[256];
    memcpy(x, qs1, (size_t)ns * sizeof(double));
    memcpy(x + ns, mrvi_integrator_micro_q(it),
           (size_t)(p * nf) * sizeof(double));
    mrvi_step_build_pattern(&st, x);
    mrvi_step_assemble(&st, x, R, 1);
    /* The last step's solution makes the residual vanish. */
    double rn = 0.0;
    for (int i = 0; i < N; i++)
      rn = fmax(rn, fabs(R[i]));
    CHECK(rn < 1e-9, "%s: residual at the solution %.2e", schemes[sc], rn);
    (void)n;
    for (int tr = 0; tr < 2; tr++) {
      for (int i = 0; i < N; i++)
        xt[i] = sin(1.0 + 0.7 * i) + 0.1 * tr;
      /* b = A xt or A^T xt from the CSC */
      memset(b, 0, (size_t)N * sizeof(double));
      double bn = 0.0;
      for (int j = 0; j < N; j++)
        for (int q = st.Ap[j]; q < st.Ap[j + 1]; q++) {
          if (tr)
            b[j] += st.Ax[q] * xt[st.Ai[q]];
          else
            b[st.Ai[q]] += st.Ax[q] * xt[j];
        }
      for (int i = 0; i < N; i++)
        bn = fmax(bn, fabs(b[i]));
      const int rc = mrvi_integrator_jacobian_solve(it, tr, b, sol);
      double err = 0.0;
      for (int i = 0; i < N; i++)
        err = fmax(err, fabs(sol[i] - xt[i]));
      CHECK(rc == MRVI_OK && err < 1e-10, "%s (%s): %s solve error %.2e",
            schemes[sc], mrvi_integrator_solver_path(it),
            tr ? "transposed" : "plain", err);
      if (sc == 4) {
        mrvi_krylov_stats ks;
        mrvi_integrator_krylov_stats(it, &ks);
        CHECK(!strcmp(mrvi_integrator_solver_path(it), "schur-krylov") &&
                  ks.fallbacks == 0,
              "fpu dense_max 0: path %s, %ld fallbacks to the LU",
              mrvi_integrator_solver_path(it), ks.fallbacks);
      }
    }
    mrvi_step_free(&st);
    mrvi_integrator_free(ref);
    mrvi_integrator_free(it);
    mrvi_system_free(s);
  }
}

/* Tiny steps (dT = 1e-6, p = 10, 1000 steps): Newton on increments meets
 * the tolerance in every step (no step stops at the roundoff floor, no
 * predictor is accepted), and the momentum change over the run agrees with
 * a run at dT/2 to 1e-6 of its size: the difference of two second-order
 * runs is (3/4) C dT^2 t, far below that; accepting predictors (free
 * flight) would lose the whole change. */
static void test_tiny_steps(void) {
  /* system, scheme, solver: every path */
  static const char *const cases[][3] = {
      {"systems/triatomic.yaml", "midpoint-midpoint", "general"},
      {"systems/triatomic.yaml", "midpoint-midpoint", "auto"},
      {"systems/fpu.yaml", "midpoint-midpoint", "general"},
      {"systems/fpu.yaml", "midpoint-midpoint", "auto"},
      {"systems/fpu.yaml", "explicit-slow", "auto"},
      {"systems/fpu.yaml", "fully-explicit", "auto"}};
  for (int c = 0; c < (int)(sizeof cases / sizeof cases[0]); c++) {
    const char *const *sys_names = cases[c];
    const int sy = 0;
    {
      double pend[2][64], p0[64];
      int n = 0;
      for (int half = 0; half < 2; half++) {
        char ov[5][80];
        const char *ovp[5] = {ov[0], ov[1], ov[2], ov[3], ov[4]};
        snprintf(ov[0], sizeof ov[0], "integrator.macro_step=%s",
                 half ? "5e-7" : "1e-6");
        snprintf(ov[1], sizeof ov[1], "integrator.t_end=1e-3");
        snprintf(ov[2], sizeof ov[2], "integrator.solver=%s", cases[c][2]);
        snprintf(ov[4], sizeof ov[4], "integrator.scheme=%s", cases[c][1]);
        snprintf(ov[3], sizeof ov[3], "integrator.micro_steps=10");
        mrvi_system *s = NULL;
        char msg[400];
        mrvi_integrator *it = NULL;
        if (mrvi_system_load(test_source_path(sys_names[sy]), ovp, 5, &s, msg,
                             sizeof msg) < 0 ||
            mrvi_integrator_create(s->model, &s->settings, &it, msg,
                                   sizeof msg) < 0) {
          CHECK(0, "%s: %s", sys_names[sy], msg);
          mrvi_system_free(s);
          return;
        }
        n = mrvi_model_n(s->model);
        memcpy(p0, mrvi_integrator_p(it), (size_t)n * sizeof(double));
        const long N = mrvi_settings_n_steps(&s->settings);
        int zero_iter = 0, ok = 1;
        double worst = 0.0;
        for (long k = 0; k < N && ok; k++) {
          ok = mrvi_integrator_step(it) == MRVI_OK;
          worst = fmax(worst, mrvi_integrator_last_residual(it));
          zero_iter += mrvi_integrator_last_iterations(it) == 0;
        }
        const int expl =
            strcmp(mrvi_integrator_solver_path(it), "explicit") == 0;
        CHECK(ok, "%s: %s", sys_names[sy], mrvi_integrator_errmsg(it));
        if (!half) {
          CHECK(mrvi_integrator_roundoff_steps(it) == 0 &&
                    worst <= s->settings.newton_tol,
                "%s (%s): every step at the tolerance: residual %.2e <= "
                "%.2e, %ld steps at the roundoff floor",
                sys_names[sy], mrvi_integrator_solver_path(it), worst,
                s->settings.newton_tol, mrvi_integrator_roundoff_steps(it));
          CHECK(expl || zero_iter == 0, "%s: %d predictors accepted",
                sys_names[sy], zero_iter);
        }
        memcpy(pend[half], mrvi_integrator_p(it), (size_t)n * sizeof(double));
        mrvi_integrator_free(it);
        mrvi_system_free(s);
      }
      double dmax = 0.0, change = 0.0;
      for (int i = 0; i < n; i++) {
        dmax = fmax(dmax, fabs(pend[0][i] - pend[1][i]));
        change = fmax(change, fabs(pend[1][i] - p0[i]));
      }
      CHECK(change > 0 && dmax <= 1e-6 * change,
            "%s (%s): momentum change %.3e, dT vs dT/2 differ by %.2e",
            sys_names[sy], cases[c][1], change, dmax);
    }
  }
}

/* A blow-up on the explicit path stops the run (no Newton residual would
 * notice): the FPU at dT = 1 is unstable in its slow quartic springs (p =
 * 1000), and in its stiff springs too at p = 1 (dt omega = 50 > 2; the
 * tight path of an uncontrolled step at p = 1). */
static void test_blowup(void) {
  const char *micro[] = {"integrator.micro_steps=1000",
                         "integrator.micro_steps=1"};
  for (int c = 0; c < 2; c++) {
    const char *ov[] = {"integrator.scheme=fully-explicit",
                        "integrator.macro_step=1", micro[c],
                        "integrator.t_end=20"};
    mrvi_system *s = NULL;
    mrvi_integrator *it = NULL;
    char msg[400];
    if (mrvi_system_load(test_source_path("systems/fpu.yaml"), ov, 4, &s, msg,
                         sizeof msg) < 0 ||
        mrvi_integrator_create(s->model, &s->settings, &it, msg, sizeof msg) <
            0) {
      CHECK(0, "blow-up set-up: %s", msg);
      mrvi_system_free(s);
      return;
    }
    int st = MRVI_OK, k = 0;
    while (k < 20 && (st = mrvi_integrator_step(it)) == MRVI_OK)
      k++;
    CHECK(st == MRVI_ENONFINITE &&
              strstr(mrvi_integrator_errmsg(it), "non-finite"),
          "explicit blow-up (%s) reported at step %d: %s", micro[c], k + 1,
          mrvi_integrator_errmsg(it));
    mrvi_integrator_free(it);
    mrvi_system_free(s);
  }
}

/* Constrained steps (general path, both forms): the transposed solve is
 * the adjoint of the plain one, c^T (J^-1 b) = (J^-T c)^T b, and the
 * solution has the size of the multiplier-form system. */
static void test_jacobian_solve_constrained(void) {
  for (int f = 0; f < 2; f++) {
    mrvi_system *s = load("systems/triatomic.yaml", "midpoint-midpoint", 5,
                          f ? "null-space" : "multipliers", "auto");
    if (!s)
      continue;
    mrvi_integrator *it = NULL;
    char msg[400];
    if (mrvi_integrator_create(s->model, &s->settings, &it, msg, sizeof msg) <
        0) {
      CHECK(0, "create: %s", msg);
      mrvi_system_free(s);
      continue;
    }
    CHECK(mrvi_integrator_jacobian_solve(it, 0, NULL, NULL) == MRVI_EINVAL,
          "no Jacobian before the first step");
    mrvi_integrator_step(it);
    const int N = mrvi_integrator_jacobian_size(it);
    double *b = calloc((size_t)N, sizeof *b), *c = calloc((size_t)N, sizeof *c);
    double *x = calloc((size_t)N, sizeof *x), *y = calloc((size_t)N, sizeof *y);
    for (int i = 0; i < N; i++) {
      b[i] = cos(0.3 + 1.1 * i);
      c[i] = sin(0.5 + 0.9 * i);
    }
    const int r0 = mrvi_integrator_jacobian_solve(it, 0, b, x);
    const int r1 = mrvi_integrator_jacobian_solve(it, 1, c, y);
    double cx = 0.0, yb = 0.0, scale = 0.0;
    for (int i = 0; i < N; i++) {
      cx += c[i] * x[i];
      yb += y[i] * b[i];
      scale += fabs(c[i] * x[i]) + fabs(y[i] * b[i]);
    }
    CHECK(r0 == MRVI_OK && r1 == MRVI_OK && fabs(cx - yb) <= 1e-12 * scale,
          "triatomic (%s, %s): c.J^-1 b = %.15g, J^-T c.b = %.15g",
          f ? "null-space" : "multipliers", mrvi_integrator_solver_path(it), cx,
          yb);
    free(b);
    free(c);
    free(x);
    free(y);
    mrvi_integrator_free(it);
    mrvi_system_free(s);
  }
}

/* schur-bordered's transposed solve (the adjoint of optimal control,
 * test_bordered_transpose_solve): J^T y = c to 1e-12 relative and
 * c.J^-1 b = (J^-T c).b for the node blocks (cart pendulum, micro-node
 * constraints) and the slow block bordered by the multipliers (pendulum
 * chain: mrvi_blocks_solve_transpose), p in {1, 5}; the chain elimination:
 * test_constrained_paths. */
static void test_bordered_transpose(void) {
  const char *files[2] = {"systems/cart_pendulum.yaml",
                          "systems/pendulum_chain.yaml"};
  for (int f = 0; f < 2; f++)
    for (int p = 1; p <= 5; p += 4) {
      mrvi_system *s =
          load(files[f], "midpoint-midpoint", p, "multipliers", "structured");
      if (!s)
        continue;
      double res, dual, multi;
      int on_chain;
      char msg[300];
      const int rc =
          test_bordered_transpose_solve(s->model, &s->settings, &res, &dual,
                                        &on_chain, &multi, msg, sizeof msg);
      printf("bordered transpose: %s p=%d: |c - J^T y| %.2e, c.J^-1 b - "
             "J^-T c.b %.2e (relative), three together %.2e\n",
             files[f], p, res, dual, multi);
      CHECK(rc == 0 && res <= 1e-12 && dual <= 1e-12 && on_chain == 0 &&
                multi == 0.0,
            "%s p=%d: status %d (%s), |c - J^T y| %.3e, c.J^-1 b - J^-T c.b "
            "%.3e (relative), on the chain elimination %d, three together "
            "%.3e",
            files[f], p, rc, msg, res, dual, on_chain, multi);
      mrvi_system_free(s);
    }
}

/* The predictor (solver/predict.c): the explicit multirate sweep leaves a
 * residual far below free flight's at the paper's step sizes, so that the
 * FPU at dT = 0.01, p = 10 converges with one Newton update per step (free
 * flight needs two); its frequency estimate finds the stiff springs'
 * omega = 50 (W = (omega^2/2)|q^f|^2 dominates the Hessian at q0); where
 * dt omega is large the sweep would be unstable and free flight is used. */
/* The FPU with the overrides set, a step of it and its predictor. */
static mrvi_system *fpu_predictor(const char **set, int n_set, mrvi_step *st,
                                  mrvi_predictor **pr) {
  char msg[512];
  mrvi_system *sys = NULL;
  *pr = NULL;
  CHECK(mrvi_system_load(test_source_path("systems/fpu.yaml"), set, n_set, &sys,
                         msg, sizeof msg) == 0,
        "%s", msg);
  if (!sys)
    return NULL;
  CHECK(mrvi_step_init(st, sys->model, &sys->settings) == 0, "step init");
  CHECK(mrvi_predictor_create(sys->model, st, pr) == 0, "predictor");
  return sys;
}

/* max |R| at the initial state of the prediction (or free flight). */
static double initial_residual(mrvi_step *st, mrvi_predictor *pr,
                               int free_flight) {
  const int nu = st->n_unknowns;
  double qs[8], qf[8], ps[8], pf[8];
  double *x = malloc((size_t)nu * sizeof *x);
  double *R = malloc((size_t)nu * sizeof *R);
  test_initial_data(st, qs, qf, ps, pf);
  st->increments = 1;
  if (free_flight)
    mrvi_predict_free_flight(st, x);
  else
    mrvi_predict_checked(pr, st, x);
  mrvi_step_assemble(st, x, R, 0);
  double r = 0.0;
  for (int i = 0; i < nu; i++)
    r = fmax(r, fabs(R[i]));
  free(x);
  free(R);
  return r;
}

/* fpu_predictor for one scheme, a macro step and micro steps (step), the
 * end time t_end and tolerance 1e-9. */
static mrvi_system *fpu_scheme_predictor(const char *scheme_name,
                                         const char *const step[2],
                                         const char *t_end, mrvi_step *st,
                                         mrvi_predictor **pr) {
  char scheme[64];
  snprintf(scheme, sizeof scheme, "integrator.scheme=%s", scheme_name);
  const char *set[] = {step[0], step[1], t_end,
                       "integrator.newton.tolerance=1e-9", scheme};
  mrvi_system *sys = fpu_predictor(set, 5, st, pr);
  if (sys)
    mrvi_predictor_set_tolerance(*pr, 1e-9);
  return sys;
}

static void test_predictor(void) {
  const char *set[] = {"integrator.macro_step=0.01",
                       "integrator.micro_steps=10", "integrator.t_end=1"};
  mrvi_step st;
  mrvi_predictor *pr;
  mrvi_system *sys = fpu_predictor(set, 3, &st, &pr);
  if (!sys)
    return;
  char msg[512];
  const double w = mrvi_predictor_omega_max(pr);
  CHECK(fabs(w - 50.0) < 0.5, "omega_max at q0 = %.4f (50 expected)", w);
  /* Residual of the prediction and of free flight at the initial state. */
  const double r = initial_residual(&st, pr, 0);
  const double rff = initial_residual(&st, pr, 1);
  CHECK(r < 1e-3 * rff, "predictor residual %.2e, free flight %.2e", r, rff);
  printf("predictor: omega_max %.4f, residual %.2e (free flight %.2e)\n", w, r,
         rff);
  mrvi_predictor_free(pr);
  mrvi_step_free(&st);
  /* One update per step on the schur path at the paper's step sizes. */
  mrvi_summary sum;
  CHECK(mrvi_run(sys->model, &sys->settings, NULL, NULL, NULL, &sum) == 0,
        "fpu run: %s", sum.message);
  CHECK(sum.iterations_total == sum.steps && sum.iterations_max == 1,
        "fpu dT = 0.01, p = 10: %ld updates in %ld steps (max %d)",
        sum.iterations_total, sum.steps, sum.iterations_max);
  mrvi_system_free(sys);
  /* dt omega = 3 at dT = 0.3, p = 5: free flight, and the run converges. */
  const char *big[] = {"integrator.macro_step=0.3", "integrator.micro_steps=5",
                       "integrator.t_end=3"};
  CHECK(mrvi_system_load(test_source_path("systems/fpu.yaml"), big, 3, &sys,
                         msg, sizeof msg) == 0,
        "%s", msg);
  if (!sys)
    return;
  CHECK(mrvi_run(sys->model, &sys->settings, NULL, NULL, NULL, &sum) == 0,
        "fpu dT = 0.3, p = 5 (free-flight predictor): %s", sum.message);
  mrvi_system_free(sys);
}

/* Large macro steps at the fixed micro step dt = 0.001 of bench_fpu
 * (dT = 0.1, 0.3, 1 with p = 100, 300, 1000): where the slow row is far
 * from solved after the sweep (the quartic coupling over dT = 1), the
 * predictor solves it by Newton steps with the fast nodes held and sweeps
 * them again (predict.c).  Its residual at the initial state must then be
 * within 10 sqrt(0.01 tol): sqrt(0.01 tol) is the residual from which one
 * Newton update is expected to land at the 0.01 tol where the updates
 * stop, and a sampled slow solve below the re-sweep threshold 10 (0.01
 * tol)^(1/4) leaves the fast rows about 1e-3 of its change, 1.8e-5 here
 * (measured: 4e-6 at dT = 0.1, 1e-8 .. 7e-7 at dT = 0.3 and 1; the
 * fixed-point update alone leaves 1.2e-4, 7.5e-3 and 2.7e-1, and the runs
 * took 1.22 / 2.62 / 4.30 updates per step).  Runs: at most 1.1 updates
 * per step on average and 2 in any step (measured: 1.00, 1.00 .. 1.03,
 * 1.00), every scheme whose slow row sees the micro nodes. */
static void test_predictor_large_steps(void) {
  static const char *const schemes[] = {
      "midpoint-midpoint", "trapezoidal-midpoint", "trapezoidal-trapezoidal"};
  static const char *const steps[][2] = {
      {"integrator.macro_step=0.1", "integrator.micro_steps=100"},
      {"integrator.macro_step=0.3", "integrator.micro_steps=300"},
      {"integrator.macro_step=1", "integrator.micro_steps=1000"}};
  const double tol = 1e-9;
  for (int sc = 0; sc < 3; sc++)
    for (int k = 0; k < 3; k++) {
      mrvi_step st;
      mrvi_predictor *pr;
      mrvi_system *sys = fpu_scheme_predictor(schemes[sc], steps[k],
                                              "integrator.t_end=5", &st, &pr);
      if (!sys)
        continue;
      const int pre = mrvi_predictor_presolve(pr, 1);
      const double r = initial_residual(&st, pr, 0);
      const int sweeps = mrvi_predictor_sweeps(pr);
      CHECK(r <= 10.0 * sqrt(0.01 * tol),
            "%s %s: predictor residual %.2e > %.2e", schemes[sc], steps[k][0],
            r, 10.0 * sqrt(0.01 * tol));
      /* The pre-solve where the fixed-point contraction at q0 is above
       * 0.1 (0.03 / 0.27 / 3.0 here): then, and at dT = 0.1, one sweep. */
      CHECK(pre == (k > 0) && sweeps == 1,
            "%s %s: pre-solve %d (expected %d), %d sweeps (expected 1)",
            schemes[sc], steps[k][0], pre, k > 0, sweeps);
      /* Without it (the path of models without a constant-Hessian W): the
       * same residual bound, with a second sweep at dT = 0.3 and 1. */
      mrvi_predictor_presolve(pr, 0);
      const double r0 = initial_residual(&st, pr, 0);
      const int sweeps0 = mrvi_predictor_sweeps(pr);
      CHECK(r0 <= 10.0 * sqrt(0.01 * tol) && sweeps0 == (k > 0 ? 2 : 1),
            "%s %s without the pre-solve: predictor residual %.2e (bound "
            "%.2e), %d sweeps (expected %d)",
            schemes[sc], steps[k][0], r0, 10.0 * sqrt(0.01 * tol), sweeps0,
            k > 0 ? 2 : 1);
      printf("fpu %s %s: predictor residual %.2e with %d sweep(s), %.2e "
             "with %d without the pre-solve\n",
             schemes[sc], steps[k][0], r, sweeps, r0, sweeps0);
      mrvi_predictor_free(pr);
      mrvi_step_free(&st);
      mrvi_summary sum;
      CHECK(mrvi_run(sys->model, &sys->settings, NULL, NULL, NULL, &sum) == 0,
            "%s %s: %s", schemes[sc], steps[k][0], sum.message);
      /* (trapezoidal-trapezoidal and trapezoidal-midpoint shoot: a slow
       * update after the first sweep and one more where the first does
       * not reach the tolerance, i.e. 2 at dT = 0.1, up to 3 at 0.3 and
       * 1; Newton takes one) */
      const int tt = strcmp(schemes[sc], "midpoint-midpoint") != 0;
      CHECK(sum.iterations_total <= (tt ? 3.0 : 1.1) * (double)sum.steps &&
                sum.iterations_max <= (tt ? 3 : 2),
            "%s %s: %ld Newton updates in %ld steps (max %d)", schemes[sc],
            steps[k][0], sum.iterations_total, sum.steps, sum.iterations_max);
      printf("fpu %s %s: predictor residual %.2e, %.2f updates per step "
             "(max %d)\n",
             schemes[sc], steps[k][0], r,
             (double)sum.iterations_total / (double)sum.steps,
             sum.iterations_max);
      mrvi_system_free(sys);
    }
}

/* Small macro steps (bench_fpu's dt = 0.001 at p = 1 and 2), where the
 * step's fixed cost is the predictor's: node k's gradients, evaluated once
 * (predict.c, node_gradients_k), give the slow row's first solve, interval
 * 0's implicit force and the points at node k.  The predictor's residual
 * at the initial state stays within 10 sqrt(0.01 tol), from where one
 * Newton update reaches the stop at 0.01 tol (every step of a run takes
 * one).  Trapezoidal-trapezoidal at p = 1 has every point on a node and
 * its rows explicit (the slow row holds node k's point only, fast row 0
 * its force): the prediction from node k's gradients is the solution, its
 * residual at round-off, below the floor 16 eps M |q| / dt = 5e-12. */
static void test_predictor_small_steps(void) {
  static const char *const schemes[] = {
      "midpoint-midpoint", "trapezoidal-midpoint", "trapezoidal-trapezoidal"};
  static const char *const steps[][2] = {
      {"integrator.macro_step=0.001", "integrator.micro_steps=1"},
      {"integrator.macro_step=0.002", "integrator.micro_steps=2"}};
  const double tol = 1e-9;
  for (int sc = 0; sc < 3; sc++)
    for (int k = 0; k < 2; k++) {
      mrvi_step st;
      mrvi_predictor *pr;
      mrvi_system *sys = fpu_scheme_predictor(schemes[sc], steps[k],
                                              "integrator.t_end=0.5", &st, &pr);
      if (!sys)
        continue;
      const double r = initial_residual(&st, pr, 0);
      const int exact = sc == 2 && k == 0;
      const double bound = exact ? 5e-12 : 10.0 * sqrt(0.01 * tol);
      CHECK(r <= bound, "%s %s: predictor residual %.2e > %.2e", schemes[sc],
            steps[k][1], r, bound);
      mrvi_predictor_free(pr);
      mrvi_step_free(&st);
      mrvi_summary sum;
      CHECK(mrvi_run(sys->model, &sys->settings, NULL, NULL, NULL, &sum) == 0,
            "%s %s: %s", schemes[sc], steps[k][1], sum.message);
      CHECK(sum.iterations_total == sum.steps && sum.iterations_max == 1,
            "%s %s: %ld Newton updates in %ld steps (max %d)", schemes[sc],
            steps[k][1], sum.iterations_total, sum.steps, sum.iterations_max);
      printf("fpu %s %s: predictor residual %.2e, %ld updates in %ld steps\n",
             schemes[sc], steps[k][1], r, sum.iterations_total, sum.steps);
      mrvi_system_free(sys);
    }
}

/* The one linear-solve interface (solver/newton.c) on both of its backends:
 * a dense LU up to dense_max rows (here 128), UMFPACK above.  Saddle-point
 * matrices [[0, G], [-G^T, K]] (K non-symmetric, rows scaled over six
 * orders of magnitude; the zero block first, so that partial pivoting swaps
 * rows from the first column on) solved with A and A^T; residuals against
 * the CSC matrix itself. */
static void test_linsolve_backends(void) {
  const int dense_max = 128, sizes[2] = {9, 3 * dense_max + 3};
  for (int t = 0; t < 2; t++) {
    const int n = sizes[t], nk = 2 * n / 3, ng = n - nk;
    double *A = calloc((size_t)n * (size_t)n, sizeof *A);
    int *Ap = malloc((size_t)(n + 1) * sizeof *Ap);
    int *Ai = malloc((size_t)n * (size_t)n * sizeof *Ai);
    double *Ax = malloc((size_t)n * (size_t)n * sizeof *Ax);
    double *b = malloc((size_t)n * sizeof *b),
           *x = malloc((size_t)n * sizeof *x);
    /* K: tridiagonal plus a coupling column, scaled by 10^(6 i / nk). */
    for (int i = 0; i < nk; i++) {
      const double sc = pow(10.0, 6.0 * i / nk);
      A[i * n + i] = sc * (4.0 + 0.1 * i);
      if (i > 0)
        A[i * n + i - 1] = -sc * 1.3;
      if (i + 1 < nk)
        A[i * n + i + 1] = -sc * 0.7;
      A[i * n + 0] += sc * 0.2;
    }
    /* G: each constraint row couples three of K's unknowns. */
    for (int r = 0; r < ng; r++)
      for (int c = 0; c < 3; c++) {
        const int j = (2 * r + c) % nk;
        const double g = cos(1.0 + r + 2.0 * c);
        A[(nk + r) * n + j] = g;
        A[j * n + nk + r] = -g * pow(10.0, 6.0 * j / nk);
      }
    /* Constraint rows and multipliers first: index i -> (i + ng) mod n. */
    double *P = calloc((size_t)n * (size_t)n, sizeof *P);
    for (int i = 0; i < n; i++)
      for (int j = 0; j < n; j++)
        P[((i + ng) % n) * n + (j + ng) % n] = A[i * n + j];
    free(A);
    A = P;
    int nnz = 0;
    for (int j = 0; j < n; j++) {
      Ap[j] = nnz;
      for (int i = 0; i < n; i++)
        if (A[i * n + j] != 0.0) {
          Ai[nnz] = i;
          Ax[nnz++] = A[i * n + j];
        }
    }
    Ap[n] = nnz;
    char msg[200];
    mrvi_newton *nw =
        mrvi_newton_create(n, Ap, Ai, Ax, dense_max, msg, sizeof msg);
    CHECK(nw != NULL, "n = %d: create: %s", n, msg);
    if (nw) {
      CHECK(mrvi_linsolve_solve(nw, Ax, 0, b, x, msg, sizeof msg) ==
                    MRVI_EINVAL &&
                strstr(msg, "no factorisation"),
            "n = %d: solve before factorising refused", n);
      const int f = mrvi_newton_factor(nw, Ax, msg, sizeof msg);
      CHECK(f == MRVI_OK, "n = %d: factor: %s", n, msg);
      for (int tr = 0; tr < 2 && f == MRVI_OK; tr++) {
        for (int i = 0; i < n; i++)
          b[i] = sin(0.4 + 1.7 * i);
        const int s = mrvi_linsolve_solve(nw, Ax, tr, b, x, msg, sizeof msg);
        /* ||op(A) x - b|| <= 1e3 eps (|op(A)| |x| + |b|), per row. */
        double worst = 0.0;
        for (int i = 0; i < n; i++) {
          double r = -b[i], sc = fabs(b[i]);
          for (int j = 0; j < n; j++) {
            const double a = tr ? A[j * n + i] : A[i * n + j];
            r += a * x[j];
            sc += fabs(a * x[j]);
          }
          worst = fmax(worst, fabs(r) / sc);
        }
        CHECK(s == MRVI_OK && worst <= 1e3 * DBL_EPSILON,
              "n = %d (%s): %s solve, worst relative row residual %.2e", n,
              n <= dense_max ? "dense" : "UMFPACK", tr ? "transposed" : "plain",
              worst);
      }
      /* A zero constraint row: singular, reported as such. */
      for (int e = 0; e < nnz; e++)
        if (Ai[e] == 0)
          Ax[e] = 0.0;
      CHECK(mrvi_newton_factor(nw, Ax, msg, sizeof msg) == MRVI_ESINGULAR &&
                strstr(msg, "singular"),
            "n = %d: singular matrix reported: %s", n, msg);
    }
    mrvi_newton_free(nw);
    free(A);
    free(Ap);
    free(Ai);
    free(Ax);
    free(b);
    free(x);
  }
}

/* The structured paths with a quadratic W whose Hessian is not diagonal,
 * against the general path: on a fast block of 3, the affine gradient
 * g0 + H z with the full products (the FPU's W is diagonal); on a block of 5
 * (beyond the small blocks), the sweep's predictor-corrector micro steps
 * (linear_sweep) and the explicit nodes' term-by-term gradients.  FPU-like
 * chains of nc + nc coordinates, W with one- and two-input linear springs. */
static void chain_yaml(int nc, char *text, size_t size);

static void chain_case(int nc) {
  char text[4096];
  chain_yaml(nc, text, sizeof text);
  const char *const schemes[] = {"explicit-slow", "fully-explicit"};
  const char *const want[] = {"sweep", "explicit"};
  static run_out a, b;
  for (int sc = 0; sc < 2; sc++)
    for (int p = 1; p <= 3; p += 2) {
      char ov[4][64];
      const char *ovp[4] = {ov[0], ov[1], ov[2], ov[3]};
      snprintf(ov[0], sizeof ov[0], "integrator.scheme=%s", schemes[sc]);
      snprintf(ov[1], sizeof ov[1], "integrator.micro_steps=%d", p);
      snprintf(ov[2], sizeof ov[2], "integrator.newton.tolerance=1e-12");
      mrvi_system *sys[2] = {NULL, NULL};
      char msg[512];
      for (int g = 0; g < 2; g++) {
        snprintf(ov[3], sizeof ov[3], "integrator.solver=%s",
                 g ? "auto" : "general");
        CHECK(mrvi_system_load_string(text, "chain.yaml", ovp, 4, &sys[g], msg,
                                      sizeof msg) == MRVI_OK,
              "chain%d: %s", nc, msg);
      }
      if (sys[0] && sys[1]) {
        run(sys[0], &a);
        run(sys[1], &b);
        CHECK(a.ok && b.ok && strcmp(b.path, want[sc]) == 0,
              "chain%d %s p=%d: path %s", nc, schemes[sc], p,
              b.ok ? b.path : "-");
        const double d = a.ok && b.ok ? rel_diff(&a, &b) : INFINITY;
        CHECK(d <= 1e-10, "chain%d %s p=%d: %s path vs general: %.2e", nc,
              schemes[sc], p, want[sc], d);
      }
      mrvi_system_free(sys[0]);
      mrvi_system_free(sys[1]);
    }
}

/* The chain of chain_case as a description file: nc slow and nc fast
 * coordinates, V quartic, W linear springs on each fast coordinate and
 * between neighbours (a Hessian that is not diagonal). */
static void chain_yaml(int nc, char *text, size_t size) {
  int n = 0;
  n +=
      snprintf(text + n, size - (size_t)n, "name: chain%d\ncoordinates:\n", nc);
  for (int i = 0; i < nc; i++)
    n += snprintf(text + n, size - (size_t)n,
                  "  - {name: s%d, mass: %d, position: %g, velocity: %g, "
                  "rate: slow}\n  - {name: f%d, mass: 1, position: %g, "
                  "velocity: %g, rate: fast}\n",
                  i, 1 + i % 2, 0.3 - 0.1 * i, 0.2 * (i == 0), i,
                  0.01 * (i + 1), i == 2 ? 1.0 : 0.0);
  n += snprintf(text + n, size - (size_t)n, "terms:\n");
  for (int i = 0; i < nc; i++) {
    /* V: (s_i - f_i [- s_{i-1} - f_{i-1}])^4 / 4; W: springs on f_i and
     * between f_i and f_{i-1} */
    char prev[40] = "";
    if (i)
      snprintf(prev, sizeof prev, ", s%d: -1, f%d: -1", i - 1, i - 1);
    n += snprintf(text + n, size - (size_t)n,
                  "  - {combination: {s%d: 1, f%d: -1%s}, law: power, "
                  "coefficient: 0.25, exponent: 4, potential: slow}\n"
                  "  - {combination: {f%d: 1}, law: linear, stiffness: %d, "
                  "potential: fast}\n",
                  i, i, prev, i, 900 + 100 * i);
    if (i)
      n += snprintf(text + n, size - (size_t)n,
                    "  - {combination: {f%d: 1, f%d: -1}, law: linear, "
                    "stiffness: 50, potential: fast}\n",
                    i, i - 1);
  }
  snprintf(text + n, size - (size_t)n,
           "integrator: {scheme: explicit-slow, macro_step: 0.01, "
           "micro_steps: 2, t_end: 1}\n");
}

/* The predictor's sweep for one point per micro interval in each class
 * (predict.c, sweep1_k: the three implicit schemes) against its generic
 * sweep over the points by kind: the same arithmetic in the same order, so
 * the same prediction (asserted to 1e-14 of max |x|; measured identical),
 * on the FPU (W's Hessian diagonal: its gradient by the diagonal) and on
 * chain_yaml's chain (W coupling neighbours: the full products), at p = 5
 * and 100 (dt = 0.001), with the sweep along the slow row's solve
 * (sum_slow) and, at p = 100 on the FPU (dT = 0.1), the sampled slow solve
 * after it.  The prediction's residual at the initial state must be within
 * 10 sqrt(0.01 tol), from where one Newton update reaches the stop. */
/* The adjoint's transposed solves from kept factors by cost
 * (mrvi_newton_solve_transpose_kept): on a dense 4 x 4 step, whose
 * factorisation costs about one refinement correction, five right-hand
 * sides are solved by factorising A at once (refactored, the same x as
 * mrvi_newton_solve_transpose bit for bit); without the cost rule the
 * kept factors of a matrix within 1e-10 are refined (not refactored) to the
 * same x within the refinement's round-off; on a full 60 x 60 matrix (a
 * factorisation about seven corrections) the rule refines too. */
static void test_transpose_kept_cost(void) {
  const int sizes[2] = {4, 60}, nrhs = 5;
  for (int t = 0; t < 2; t++) {
    const int n = sizes[t];
    int *Ap = malloc((size_t)(n + 1) * sizeof *Ap);
    int *Ai = malloc((size_t)(n * n) * sizeof *Ai);
    double *Ax = malloc((size_t)(n * n) * sizeof *Ax),
           *Bx = malloc((size_t)(n * n) * sizeof *Bx);
    double *b = malloc((size_t)(nrhs * n) * sizeof *b),
           *x = malloc((size_t)(nrhs * n) * sizeof *x),
           *y = malloc((size_t)(nrhs * n) * sizeof *y);
    int nnz = 0;
    for (int j = 0; j < n; j++) {
      Ap[j] = nnz;
      for (int i = t ? 0 : j - 1; i <= (t ? n - 1 : j + 1); i++)
        if (i >= 0 && i < n) {
          Ai[nnz] = i;
          Ax[nnz] = i == j
                        ? 4.0 + sin(j)
                        : (t ? 2.0 / n : 1.0) * (-1.0 + 0.3 * cos(i + 2.0 * j));
          Bx[nnz] = Ax[nnz] * (1.0 + 1e-10 * sin(3.0 * nnz));
          nnz++;
        }
    }
    Ap[n] = nnz;
    for (int i = 0; i < nrhs * n; i++)
      b[i] = cos(0.3 + 1.1 * i);
    char msg[200] = "";
    for (int by_cost = 0; by_cost < 2; by_cost++) {
      mrvi_newton *nw = mrvi_newton_create(n, Ap, Ai, Bx, 128, msg, sizeof msg);
      CHECK(nw && mrvi_newton_factor(nw, Bx, msg, sizeof msg) == MRVI_OK,
            "n = %d: %s", n, msg);
      if (!nw)
        continue;
      int refactored = -1;
      const int s = mrvi_newton_solve_transpose_kept(
          nw, Ax, nrhs, b, x, 8, by_cost, &refactored, msg, sizeof msg);
      const int want = by_cost && n == 4;
      CHECK(s == MRVI_OK && refactored == want,
            "n = %d, by cost %d: refactored %d, expected %d (%s)", n, by_cost,
            refactored, want, msg);
      CHECK(mrvi_newton_solve_transpose(nw, Ax, nrhs, b, y, msg, sizeof msg) ==
                MRVI_OK,
            "n = %d: %s", n, msg);
      double d = 0.0, sc = 0.0;
      for (int i = 0; i < nrhs * n; i++) {
        d = fmax(d, fabs(x[i] - y[i]));
        sc = fmax(sc, fabs(y[i]));
      }
      CHECK(want ? d == 0.0 : d <= 1e-13 * sc,
            "n = %d, by cost %d: x differs from A's own solve by %.3e", n,
            by_cost, d);
      mrvi_newton_free(nw);
    }
    free(Ap);
    free(Ai);
    free(Ax);
    free(Bx);
    free(b);
    free(x);
    free(y);
  }
}

static void test_predictor_one_point(void) {
  static const char *const schemes[] = {
      "midpoint-midpoint", "trapezoidal-midpoint", "trapezoidal-trapezoidal"};
  char chain[4096];
  chain_yaml(3, chain, sizeof chain);
  const double tol = 1e-9;
  for (int sy = 0; sy < 2; sy++)
    for (int sc = 0; sc < 3; sc++)
      for (int p = 5; p <= 100; p += 95) {
        char ov[4][64], msg[512];
        const char *ovp[4] = {ov[0], ov[1], ov[2], ov[3]};
        snprintf(ov[0], sizeof ov[0], "integrator.scheme=%s", schemes[sc]);
        snprintf(ov[1], sizeof ov[1], "integrator.micro_steps=%d", p);
        snprintf(ov[2], sizeof ov[2], "integrator.macro_step=%g", 0.001 * p);
        snprintf(ov[3], sizeof ov[3], "integrator.newton.tolerance=%g", tol);
        mrvi_system *sys = NULL;
        const int rc =
            sy == 0 ? mrvi_system_load(test_source_path("systems/fpu.yaml"),
                                       ovp, 4, &sys, msg, sizeof msg)
                    : mrvi_system_load_string(chain, "chain.yaml", ovp, 4, &sys,
                                              msg, sizeof msg);
        CHECK(rc == MRVI_OK, "%s", msg);
        if (!sys)
          continue;
        mrvi_step st;
        mrvi_predictor *pr = NULL;
        CHECK(mrvi_step_init(&st, sys->model, &sys->settings) == 0 &&
                  mrvi_predictor_create(sys->model, &st, &pr) == 0,
              "step and predictor");
        if (pr) {
          mrvi_predictor_set_tolerance(pr, tol);
          const int nu = st.n_unknowns;
          double *x = malloc(2 * (size_t)nu * sizeof *x), *x1 = x + nu;
          const double r = initial_residual(&st, pr, 0);
          double qs[8], qf[8], ps[8], pf[8]; /* (st points to them) */
          test_initial_data(&st, qs, qf, ps, pf);
          st.increments = 1;
          mrvi_predict_checked(pr, &st, x);
          const int one = mrvi_predictor_one_point(pr, 0);
          mrvi_predict_checked(pr, &st, x1);
          mrvi_predictor_one_point(pr, 1);
          double d = 0.0, xm = 0.0;
          for (int i = 0; i < nu; i++) {
            d = fmax(d, fabs(x[i] - x1[i]));
            xm = fmax(xm, fabs(x[i]));
          }
          const char *name = sy == 0 ? "fpu" : "chain3";
          CHECK(one == 1, "%s %s p=%d: the one-point sweep not taken", name,
                schemes[sc], p);
          /* (where the one-point sweep solves the rows with inside points
           * exactly, the generic one differs by its estimate of their
           * force; test_shoot checks the exact rows) */
          const int exact = mrvi_predictor_exact_inside(pr);
          CHECK(exact == (sy == 0 && sc == 1),
                "%s %s p=%d: exact inside rows %d", name, schemes[sc], p,
                exact);
          CHECK(d <= (exact ? 1e-5 : 1e-14) * xm,
                "%s %s p=%d: one-point sweep vs generic: %.2e (max |x| %.2e)",
                name, schemes[sc], p, d, xm);
          CHECK(r <= 10.0 * sqrt(0.01 * tol),
                "%s %s p=%d: predictor residual %.2e > %.2e", name, schemes[sc],
                p, r, 10.0 * sqrt(0.01 * tol));
          printf("%s %s p=%d: one-point sweep vs generic %.2e, predictor "
                 "residual %.2e\n",
                 name, schemes[sc], p, d, r);
          free(x);
        }
        mrvi_predictor_free(pr);
        mrvi_step_free(&st);
        mrvi_system_free(sys);
      }
}

/* FPU with the given scheme, dT, p and tolerance. */
static mrvi_system *fpu_at(const char *scheme, const char *dT, int p,
                           const char *tol) {
  char ov[4][64];
  snprintf(ov[0], sizeof ov[0], "integrator.scheme=%s", scheme);
  snprintf(ov[1], sizeof ov[1], "integrator.macro_step=%s", dT);
  snprintf(ov[2], sizeof ov[2], "integrator.micro_steps=%d", p);
  snprintf(ov[3], sizeof ov[3], "integrator.newton.tolerance=%s", tol);
  const char *ovp[4] = {ov[0], ov[1], ov[2], ov[3]};
  mrvi_system *sys = NULL;
  char msg[512];
  CHECK(mrvi_system_load(test_source_path("systems/fpu.yaml"), ovp, 4, &sys,
                         msg, sizeof msg) == 0,
        "fpu %s: %s", scheme, msg);
  return sys;
}

/* run() with *mode forced on, then off, then (au not NULL) by its rule;
 * *mode is left at the rule. */
static void run_modes(const mrvi_system *sys, int *mode, run_out *on,
                      run_out *off, run_out *au) {
  *mode = MRVI_CHORD_ON;
  run(sys, on);
  *mode = MRVI_CHORD_OFF;
  run(sys, off);
  *mode = MRVI_CHORD_AUTO;
  if (au)
    run(sys, au);
}

static int iters_total(const run_out *o) {
  int n = 0;
  for (int k = 0; k < N_STEPS; k++)
    n += o->iters[k];
  return n;
}

/* The chord matrix of the schur path (frozen Hessians, doc/solver.md
 * "Newton details"): forced on and off, the same trajectory as the general
 * path within 1e-10 (tolerance 1e-12; the residual is exact, only the
 * convergence differs) for the three implicit schemes at p = 5 and 10 --
 * and not bitwise the same as exact Newton, so the chord matrix was used.
 * At tolerance 1e-9: at dT = 0.01, p = 10 the chord update lands in one
 * update per step (as exact Newton) and the rule takes it (auto equals
 * forced on, bit for bit); at dT = 0.1, p = 100 the chord needs two
 * updates in some step (its contraction, about dT^2 |Delta hess V| / m,
 * measured 1e-4 .. 1e-3 against 5e-7 at dT = 0.01), so the rule falls
 * back to exact Newton there (auto equals forced off, bit for bit, one
 * update per step).  At p = 1 the chord does not apply (forced on equals
 * off). */
static void test_chord(void) {
  static const char *const schemes[] = {
      "midpoint-midpoint", "trapezoidal-midpoint", "trapezoidal-trapezoidal"};
  static run_out g, on, off, au;
  run_shoot = MRVI_CHORD_OFF; /* (the Newton updates alone) */
  for (int sc = 0; sc < 3; sc++)
    for (int pi = 0; pi < 2; pi++) {
      const int p = pi ? 10 : 5;
      mrvi_system *sg =
          load("systems/fpu.yaml", schemes[sc], p, "multipliers", "general");
      mrvi_system *sa =
          load("systems/fpu.yaml", schemes[sc], p, "multipliers", "auto");
      if (!sg || !sa) {
        mrvi_system_free(sg);
        mrvi_system_free(sa);
        continue;
      }
      run(sg, &g);
      run_modes(sa, &run_chord, &on, &off, NULL);
      if (g.ok && on.ok && off.ok) {
        CHECK(strcmp(on.path, "schur") == 0, "path %s", on.path);
        const double d_on = rel_diff(&g, &on), d_off = rel_diff(&g, &off);
        CHECK(d_on <= 1e-10 && d_off <= 1e-10,
              "fpu %s p=%d: chord vs general %.2e, exact vs general %.2e",
              schemes[sc], p, d_on, d_off);
        CHECK(rel_diff(&on, &off) > 0.0, "fpu %s p=%d: chord not used",
              schemes[sc], p);
      }
      mrvi_system_free(sg);
      mrvi_system_free(sa);
    }
  /* p = 1: one point per interval but no equal row blocks to share; the
   * structure is refused and forcing the chord changes nothing. */
  mrvi_system *s1 =
      load("systems/fpu.yaml", "midpoint-midpoint", 1, "multipliers", "auto");
  if (s1) {
    run_modes(s1, &run_chord, &on, &off, NULL);
    CHECK(on.ok && off.ok && rel_diff(&on, &off) == 0.0,
          "fpu p=1: the chord was used");
    mrvi_system_free(s1);
  }
  for (int sc = 0; sc < 3; sc++)
    for (int big = 0; big < 2; big++) {
      mrvi_system *sys =
          fpu_at(schemes[sc], big ? "0.1" : "0.01", big ? 100 : 10, "1e-9");
      if (!sys)
        continue;
      run_modes(sys, &run_chord, &on, &off, &au);
      mrvi_system_free(sys);
      if (!on.ok || !off.ok || !au.ok)
        continue;
      const int n_on = iters_total(&on), n_off = iters_total(&off),
                n_au = iters_total(&au);
      const run_out *same = big ? &off : &on;
      CHECK(rel_diff(&au, same) == 0.0,
            "fpu %s dT=%s: the rule did not take %s", schemes[sc],
            big ? "0.1" : "0.01", big ? "exact Newton" : "the chord");
      CHECK(n_off == N_STEPS && n_au == N_STEPS,
            "fpu %s: %d updates (exact), %d (auto) in %d steps", schemes[sc],
            n_off, n_au, N_STEPS);
      CHECK(big ? n_on > N_STEPS : n_on == N_STEPS,
            "fpu %s dT=%s: %d chord updates in %d steps", schemes[sc],
            big ? "0.1" : "0.01", n_on, N_STEPS);
      printf("fpu %s dT=%s: updates in %d steps: chord %d, exact %d, auto %d\n",
             schemes[sc], big ? "0.1" : "0.01", N_STEPS, n_on, n_off, n_au);
    }
  run_shoot = MRVI_CHORD_AUTO;
}

/* The constant chord (doc/solver.md, "Newton details"): the Newton
 * matrix without V's Hessian, factored once per run.  FPU, dt = 0.001,
 * tolerance 1e-9, the three implicit schemes: at p = 1 and 2 the rule
 * takes it (e = dT^2 |hess V(q0)| / m = 1.8e-5, 7.3e-5): one
 * factorisation for the run, one update per step, and the trajectory of
 * exact Newton (the constant chord off) within 1e-9 relative (both stop
 * at a residual below 0.01 tol; measured up to 3e-11 over 20 steps);
 * at p = 10 (e = 1.8e-3) the rule leaves it (auto equals off bit for
 * bit).  Forced on at the FPU's dT = 0.03 (p = 1, 5; e = 1.6e-2), where
 * one update contracts by about 1e-2, and at tolerance 1e-12: the exact
 * refactorisation after a poor update is taken (more than one
 * factorisation) and the trajectory is the general path's within 1e-10;
 * except for the trapezoidal schemes at p = 1, whose Newton matrix is the
 * constant part (e = 0): one factorisation, one update per step, and the
 * rule takes it at that dT too (auto equals forced on, bit for bit). */
static void test_const_chord(void) {
  static const char *const schemes[] = {
      "midpoint-midpoint", "trapezoidal-midpoint", "trapezoidal-trapezoidal"};
  static run_out g, on, off, au;
  run_shoot = MRVI_CHORD_OFF; /* (the Newton updates alone) */
  for (int sc = 0; sc < 3; sc++)
    for (int pi = 0; pi < 3; pi++) {
      const int p = pi == 0 ? 1 : pi == 1 ? 2 : 10;
      char dT[16];
      snprintf(dT, sizeof dT, "%g", 0.001 * p);
      mrvi_system *sys = fpu_at(schemes[sc], dT, p, "1e-9");
      if (!sys)
        continue;
      run_cchord = MRVI_CHORD_OFF;
      run(sys, &off);
      run_cchord = MRVI_CHORD_AUTO;
      run(sys, &au);
      mrvi_system_free(sys);
      if (!off.ok || !au.ok)
        continue;
      const int n_au = iters_total(&au);
      const double d = rel_diff(&au, &off);
      printf("fpu %s p=%d: constant chord %ld factorisations, %d updates in "
             "%d steps, %.2e off exact Newton\n",
             schemes[sc], p, au.nfac, n_au, N_STEPS, d);
      CHECK(off.nfac >= N_STEPS, "fpu %s p=%d: %ld exact factorisations",
            schemes[sc], p, off.nfac);
      if (p == 10) {
        CHECK(d == 0.0 && au.nfac == off.nfac,
              "fpu %s p=10: the constant chord was taken", schemes[sc]);
        continue;
      }
      CHECK(au.nfac == 1 && n_au == N_STEPS,
            "fpu %s p=%d: constant chord: %ld factorisations, %d updates in "
            "%d steps",
            schemes[sc], p, au.nfac, n_au, N_STEPS);
      CHECK(d <= 1e-9, "fpu %s p=%d: constant chord %.2e off exact Newton",
            schemes[sc], p, d);
    }
  for (int sc = 0; sc < 3; sc++)
    for (int pi = 0; pi < 2; pi++) {
      const int p = pi ? 5 : 1;
      mrvi_system *sg =
          load("systems/fpu.yaml", schemes[sc], p, "multipliers", "general");
      mrvi_system *sa =
          load("systems/fpu.yaml", schemes[sc], p, "multipliers", "auto");
      if (sg && sa) {
        run(sg, &g);
        run_cchord = MRVI_CHORD_ON;
        run(sa, &on);
        run_cchord = MRVI_CHORD_AUTO;
        if (g.ok && on.ok) {
          const double d = rel_diff(&g, &on);
          printf("fpu %s p=%d dT=0.03: constant chord forced: %ld "
                 "factorisations, %d updates in %d steps, %.2e off general\n",
                 schemes[sc], p, on.nfac, iters_total(&on), N_STEPS, d);
          CHECK(d <= 1e-10,
                "fpu %s p=%d: forced constant chord %.2e off general",
                schemes[sc], p, d);
          /* (at p = 1 the trapezoidal V's Hessian is not in the Newton
           * matrix: the constant chord is exact) */
          if (p == 1 && sc > 0) {
            CHECK(on.nfac == 1 && iters_total(&on) == N_STEPS,
                  "fpu %s p=1: %ld factorisations, %d updates", schemes[sc],
                  on.nfac, iters_total(&on));
            run(sa, &au); /* (so the rule takes it at any dT) */
            CHECK(au.ok && au.nfac == 1 && rel_diff(&au, &on) == 0.0,
                  "fpu %s p=1 dT=0.03: the rule left the exact constant chord",
                  schemes[sc]);
          } else
            CHECK(on.nfac > 1, "fpu %s p=%d: no exact refactorisation taken",
                  schemes[sc], p);
        }
      }
      mrvi_system_free(sg);
      mrvi_system_free(sa);
    }
  run_shoot = MRVI_CHORD_AUTO;
}

/* Shooting on the slow unknowns (doc/solver.md, "Newton details"): where
 * the predictor's sweep solves every fast row exactly (no point inside a
 * micro interval: trapezoidal-trapezoidal), a schur step is solved by
 * slow updates, each followed by a sweep, and accepted on the exact
 * residual.  FPU, dt = 0.001, tolerance 1e-12: forced on and off, the
 * general path's trajectory within 1e-10 at p = 5, 10, 30, 100 (dT up to
 * 0.1); every step solved by shooting (a sweep that left a fast row
 * unsolved would fail the residual check and fall back to Newton, and
 * the count would show it); by the rule (auto) at p = 10 and 100, where
 * it is the same run as forced on, bit for bit, and not at p = 2, where
 * the constant chord takes the step.  Not offered where a point lies
 * inside an interval (midpoint-midpoint). */
static void test_shoot(void) {
  static run_out g, on, off, au;
  static const int ps[] = {2, 5, 10, 30, 100};
  static const char *const schemes[] = {"trapezoidal-trapezoidal",
                                        "trapezoidal-midpoint"};
  for (int sc = 0; sc < 2; sc++) {
    long last = 0;
    for (int pi = 0; pi < 5; pi++) {
      const int p = ps[pi];
      char ov[5][64];
      const char *ovp[5] = {ov[0], ov[1], ov[2], ov[3], ov[4]};
      snprintf(ov[0], sizeof ov[0], "integrator.scheme=%s", schemes[sc]);
      snprintf(ov[1], sizeof ov[1], "integrator.macro_step=%g", 0.001 * p);
      snprintf(ov[2], sizeof ov[2], "integrator.micro_steps=%d", p);
      snprintf(ov[3], sizeof ov[3], "integrator.newton.tolerance=1e-12");
      snprintf(ov[4], sizeof ov[4], "integrator.solver=general");
      mrvi_system *sg = NULL, *sa = NULL;
      char msg[512];
      CHECK(mrvi_system_load(test_source_path("systems/fpu.yaml"), ovp, 5, &sg,
                             msg, sizeof msg) == 0 &&
                mrvi_system_load(test_source_path("systems/fpu.yaml"), ovp, 4,
                                 &sa, msg, sizeof msg) == 0,
            "fpu %s p=%d: %s", schemes[sc], p, msg);
      if (sg && sa) {
        run(sg, &g);
        run_modes(sa, &run_shoot, &on, &off, &au);
        if (g.ok && on.ok && off.ok && au.ok) {
          const double d_on = rel_diff(&g, &on), d_off = rel_diff(&g, &off);
          printf("fpu %s p=%d: shooting %ld steps (%ld with an unswept last "
                 "update), %d updates in %d steps, %.2e off general (Newton "
                 "%.2e)\n",
                 schemes[sc], p, on.nshoot, on.nlast, iters_total(&on), N_STEPS,
                 d_on, d_off);
          CHECK(d_on <= 1e-10 && d_off <= 1e-10,
                "fpu %s p=%d: shooting %.2e, Newton %.2e off general",
                schemes[sc], p, d_on, d_off);
          /* (an unswept last update that left the step above the
           * tolerance would have gone on to Newton) */
          CHECK(on.nshoot == N_STEPS && off.nshoot == 0,
                "fpu %s p=%d: %ld steps shot (forced on), %ld (off)",
                schemes[sc], p, on.nshoot, off.nshoot);
          last += on.nlast;
          if (p == 2)
            CHECK(au.nshoot == 0 && rel_diff(&au, &off) == 0.0,
                  "fpu %s p=2: the rule took shooting", schemes[sc]);
          else if (p == 10 || p == 100)
            CHECK(au.nshoot == N_STEPS && rel_diff(&au, &on) == 0.0,
                  "fpu %s p=%d: the rule left shooting", schemes[sc], p);
        }
      }
      mrvi_system_free(sg);
      mrvi_system_free(sa);
    }
    /* The unswept last update is taken (and accepted) somewhere. */
    CHECK(last > 0, "fpu %s: no step took the unswept last update",
          schemes[sc]);
  }
  mrvi_system *sm = fpu_at("midpoint-midpoint", "0.01", 10, "1e-9");
  if (sm) {
    run_shoot = MRVI_CHORD_ON;
    run(sm, &on);
    run_shoot = MRVI_CHORD_AUTO;
    CHECK(on.ok && on.nshoot == 0, "fpu midpoint-midpoint: %ld steps shot",
          on.nshoot);
    mrvi_system_free(sm);
  }
}

/* The schur path's direct assembly (doc/solver.md, "Evaluation") against
 * the CSC matrix of step.c scattered into the same blocks: the Newton
 * update of the block elimination agrees to 1e-12 of its size.  This
 * checks the matrix itself (a wrong matrix still converges, in more
 * updates): the constant part -- kinetic rows and quadratic classes,
 * whose Hessian is evaluated once and added row block by row block for a
 * class with one point per interval, point by point otherwise (p = 1) --
 * and the Hessians of the other classes.  Models: the FPU (W quadratic,
 * fast only), a chain of linear springs (every class quadratic, V with
 * slow and fast inputs: slow couplings in the constant part), the chain
 * with a quartic fast spring, the spring ring (distance springs). */
static void direct_case(mrvi_model *m, const char *label, const char *scheme,
                        int p, double dT, int vquad, int wquad) {
  mrvi_settings s = test_settings(scheme, dT, p, 1.0, 1e-10);
  mrvi_step st;
  CHECK(mrvi_step_init(&st, m, &s) == 0, "%s: step init", label);
  st.increments = 1;
  const int ns = st.ns, nf = st.nf, nu = st.n_unknowns;
  double *qs0 = calloc(ns + 1, sizeof(double)),
         *ps0 = calloc(ns + 1, sizeof(double)),
         *qf0 = calloc(nf + 1, sizeof(double)),
         *pf0 = calloc(nf + 1, sizeof(double));
  test_initial_data(&st, qs0, qf0, ps0, pf0);
  double *x = calloc(nu, sizeof(double)), *R[2], *dx[2];
  for (int k = 0; k < 2; k++) {
    R[k] = calloc(nu, sizeof(double));
    dx[k] = calloc(nu, sizeof(double));
  }
  /* displacements: free flight plus a wiggle */
  for (int i = 0; i < ns; i++)
    x[i] = dT * ps0[i] / MRVI_MASS(m, m->slow_index[i]) + 0.01 * sin(i + 1.0);
  for (int k = 1; k <= p; k++)
    for (int i = 0; i < nf; i++)
      x[ns + (k - 1) * nf + i] =
          k * (dT / p) * pf0[i] / MRVI_MASS(m, m->fast_index[i]) +
          0.01 * cos(k + 2.0 * i);
  mrvi_blocks *b[2] = {NULL, NULL};
  for (int k = 0; k < 2; k++)
    CHECK(mrvi_blocks_create(&st, &b[k]) == MRVI_OK, "%s: blocks", label);
  /* twice: the constant part made (first) and restored (second) */
  for (int pass = 0; pass < 2; pass++) {
    CHECK(mrvi_blocks_assemble(b[0], &st, x, R[0], 1) == MRVI_OK,
          "%s: assemble", label);
    CHECK(mrvi_blocks_factor(b[0], &st) == MRVI_OK, "%s: factor", label);
    mrvi_blocks_solve(b[0], R[0], dx[0]);
  }
  CHECK(mrvi_step_build_pattern(&st, x) == 0, "%s: pattern", label);
  mrvi_step_assemble(&st, x, R[1], 1);
  CHECK(mrvi_blocks_factor(b[1], &st) == MRVI_OK, "%s: CSC factor", label);
  mrvi_blocks_solve(b[1], R[1], dx[1]);
  double e = 0.0, sc = 0.0;
  for (int i = 0; i < nu; i++) {
    e = fmax(e, fabs(dx[0][i] - dx[1][i]));
    sc = fmax(sc, fabs(dx[1][i]));
  }
  CHECK(sc > 0.0 && e <= 1e-12 * sc,
        "%s %s p=%d: direct update %.2e (relative) off the CSC one's", label,
        scheme, p, sc > 0.0 ? e / sc : e);
  /* Factor and solve in one (z swept with Y): the same update bit for
   * bit, on the direct assembly and on the CSC values. */
  double *dx2 = calloc(nu, sizeof(double));
  CHECK(mrvi_blocks_assemble(b[0], &st, x, R[0], 1) == MRVI_OK, "%s: assemble",
        label);
  CHECK(mrvi_blocks_factor_solve(b[0], &st, R[0], dx2) == MRVI_OK,
        "%s: factor_solve", label);
  CHECK(memcmp(dx2, dx[0], nu * sizeof(double)) == 0,
        "%s %s p=%d: factor_solve differs from factor, solve", label, scheme,
        p);
  CHECK(mrvi_blocks_factor_solve(b[1], &st, R[1], dx2) == MRVI_OK,
        "%s: CSC factor_solve", label);
  CHECK(memcmp(dx2, dx[1], nu * sizeof(double)) == 0,
        "%s %s p=%d: CSC factor_solve differs from factor, solve", label,
        scheme, p);
  /* The constant chord's update (doc/solver.md, "Newton details"): where
   * every class is quadratic the constant part is the whole Newton
   * matrix, so its update is the exact one to round-off; also at p = 1 for
   * a class on the trapezoidal rule (its points at nodes k and k + 1 feed
   * no row with a Hessian in the unknowns: a0 a1 = cA cB = 0, and node
   * k + 1's cB row is beyond the step).  Else it differs by about
   * |A^-1 (A - A_const)|, the Hessians left out. */
  const int trap_v = strncmp(scheme, "trapezoidal", 11) == 0,
            trap_w = strcmp(scheme, "trapezoidal-trapezoidal") == 0;
  const int exact =
      p == 1 ? (vquad || trap_v) && (wquad || trap_w) : vquad && wquad;
  CHECK(mrvi_blocks_const_factor(b[1], &st, x) == MRVI_OK, "%s: const factor",
        label);
  double *xc = calloc(nu, sizeof(double)); /* (x -= dx: -dx from 0) */
  mrvi_blocks_const_solve(b[1], R[0], dx2, xc);
  for (int i = 0; i < nu; i++)
    CHECK(xc[i] == -dx2[i], "%s: const solve: x -= dx at %d", label, i);
  free(xc);
  double ec = 0.0;
  for (int i = 0; i < nu; i++)
    ec = fmax(ec, fabs(dx2[i] - dx[0][i]));
  if (exact)
    CHECK(ec <= 1e-12 * sc,
          "%s %s p=%d: constant chord update %.2e (relative) off the exact",
          label, scheme, p, ec / sc);
  else
    CHECK(ec > 1e-10 * sc,
          "%s %s p=%d: constant chord update %.2e (relative) equals the "
          "exact one",
          label, scheme, p, ec / sc);
  free(dx2);
  for (int k = 0; k < 2; k++) {
    mrvi_blocks_free(b[k]);
    free(R[k]);
    free(dx[k]);
  }
  free(x);
  free(qs0);
  free(ps0);
  free(qf0);
  free(pf0);
  mrvi_step_free(&st);
}

static void test_direct(void) {
  mrvi_model *fpu = test_fpu(), *ring = test_spring_ring();
  /* qs1 - qf1 - qf2 - qs2 with linear springs, soft on the slow ones (lin);
   * with a quartic fast spring on qf2 too (lin4); and qs1 - qs2, qf1 - qf2
   * decoupled, with a quartic spring on qs1 (V's Hessian, not constant,
   * has no fast inputs: the blocks' restore copies the fast blocks) */
  mrvi_model *lin[3];
  const double a[2] = {1, -1};
  for (int c = 0; c < 3; c++) {
    mrvi_model *m = lin[c] = mrvi_model_create();
    const char *names[4] = {"qs1", "qs2", "qf1", "qf2"};
    for (int i = 0; i < 4; i++)
      mrvi_model_add_coordinate(m, names[i], 1.0 + 0.5 * i,
                                i < 2 ? MRVI_SLOW : MRVI_FAST, 0.1 * i,
                                1.0 - 0.3 * i);
    const int l1[2] = {0, 2}, l2[2] = {1, 3}, l3[2] = {2, 3}, l4[1] = {2},
              l5[1] = {3};
    const double k1[1] = {3.0}, k2[1] = {400.0}, pw[2] = {100.0, 4.0};
    const int l6[2] = {0, 1}; /* (decoupled: qs1 - qs2) */
    int ok = mrvi_model_add_term(m, MRVI_SLOW, 2, c == 2 ? l6 : l1, a, 0.0,
                                 "linear", k1) >= 0;
    if (c < 2)
      ok &= mrvi_model_add_term(m, MRVI_SLOW, 2, l2, a, 0.0, "linear", k1) >= 0;
    ok &= mrvi_model_add_term(m, MRVI_FAST, 2, l3, a, 0.0, "linear", k2) >= 0;
    ok &= mrvi_model_add_term(m, MRVI_FAST, 1, l4, a, 0.0, "linear", k2) >= 0;
    if (c == 1)
      ok &= mrvi_model_add_term(m, MRVI_FAST, 1, l5, a, 0.0, "power", pw) >= 0;
    if (c == 2)
      ok &= mrvi_model_add_term(m, MRVI_SLOW, 1, l1, a, 0.0, "power", pw) >= 0;
    CHECK(ok, "linear chain %d: %s", c, mrvi_model_errmsg(m));
  }
  /* qs1 - qf1 - qf2, one slow coordinate (ns = 1: the sweep's Y and z
   * in one vector per row, row_yz_k with one column pair), a quartic V
   * spring on qf2 */
  mrvi_model *one = mrvi_model_create();
  {
    const char *names[3] = {"qs1", "qf1", "qf2"};
    for (int i = 0; i < 3; i++)
      mrvi_model_add_coordinate(one, names[i], 1.0 + 0.5 * i,
                                i < 1 ? MRVI_SLOW : MRVI_FAST, 0.1 * i,
                                1.0 - 0.3 * i);
    const int l1[2] = {0, 1}, l2[2] = {1, 2}, l3[1] = {1}, l4[1] = {2};
    const double k1[1] = {3.0}, k2[1] = {400.0}, pw[2] = {100.0, 4.0};
    int ok =
        mrvi_model_add_term(one, MRVI_SLOW, 2, l1, a, 0.0, "linear", k1) >= 0;
    ok &= mrvi_model_add_term(one, MRVI_FAST, 2, l2, a, 0.0, "linear", k2) >= 0;
    ok &= mrvi_model_add_term(one, MRVI_FAST, 1, l3, a, 0.0, "linear", k2) >= 0;
    ok &= mrvi_model_add_term(one, MRVI_SLOW, 1, l4, a, 0.0, "power", pw) >= 0;
    CHECK(ok, "one slow coordinate: %s", mrvi_model_errmsg(one));
  }
  const char *const schemes[3] = {"midpoint-midpoint", "trapezoidal-midpoint",
                                  "trapezoidal-trapezoidal"};
  for (int i = 0; i < 3; i++) {
    const int tt = i == 2;
    for (int p = 1; p <= 5; p += 4) {
      direct_case(fpu, "fpu", schemes[i], p, 0.03, 0, 1);
      direct_case(one, "one slow coordinate", schemes[i], p, 0.03, 0, 1);
      direct_case(lin[0], "linear chain", schemes[i], p, 0.03, 1, 1);
      direct_case(lin[1], "chain with a quartic W", schemes[i], p + 1, 0.03, 1,
                  0);
      direct_case(lin[2], "decoupled chains, quartic slow spring", schemes[i],
                  p, 0.03, 0, 1);
      direct_case(ring, "spring ring", schemes[i], p, tt ? 0.001 : 0.01, 0, 0);
    }
  }
  mrvi_model_free(lin[0]);
  mrvi_model_free(lin[1]);
  mrvi_model_free(lin[2]);
  mrvi_model_free(one);
  mrvi_model_free(fpu);
  mrvi_model_free(ring);
}

/* The path names (MRVI_PATH_LIST, the one list): distinct, each a row of
 * doc/solver.md's table of paths, and the name the integrator reports for
 * the path it chose. */
static void test_path_names(void) {
  FILE *f = fopen(test_source_path("doc/solver.md"), "r");
  static char doc[1 << 18];
  const size_t n = f ? fread(doc, 1, sizeof doc - 1, f) : 0;
  doc[n] = '\0';
  if (f)
    fclose(f);
  for (int i = 0; i < MRVI_N_PATHS; i++) {
    const char *name = mrvi_path_name(i);
    char row[80];
    snprintf(row, sizeof row, "\n| `%s` |", name);
    CHECK(strstr(doc, row) != NULL, "doc/solver.md: no row for path %s", name);
    for (int j = 0; j < i; j++)
      CHECK(strcmp(name, mrvi_path_name(j)) != 0, "path %d and %d: %s", i, j,
            name);
  }
  CHECK(strcmp(mrvi_path_name(MRVI_N_PATHS), "unknown") == 0, "path %d: %s",
        MRVI_N_PATHS, mrvi_path_name(MRVI_N_PATHS));
  /* (the fpu by each scheme: schur, sweep, explicit; general forced) */
  static const char *const schemes[] = {"midpoint-midpoint", "explicit-slow",
                                        "fully-explicit", "midpoint-midpoint"};
  static const char *const want[] = {"schur", "sweep", "explicit", "general"};
  mrvi_model *m = test_fpu();
  for (int k = 0; k < 4; k++) {
    mrvi_settings s = test_settings(schemes[k], 0.01, 2, 0.02, 1e-9);
    s.solver = k == 3 ? MRVI_SOLVER_GENERAL : MRVI_SOLVER_AUTO;
    mrvi_integrator *it = NULL;
    char msg[300];
    CHECK(mrvi_integrator_create(m, &s, &it, msg, sizeof msg) == 0 &&
              strcmp(mrvi_integrator_solver_path(it), want[k]) == 0 &&
              strcmp(mrvi_solver_path(m, &s, NULL, 0), want[k]) == 0 &&
              mrvi_integrator_step(it) == 0,
          "fpu %s: path %s, want %s (%s)", schemes[k],
          it ? mrvi_integrator_solver_path(it) : "-", want[k], msg);
    mrvi_integrator_free(it);
  }
  mrvi_model_free(m);
}

/* The tuning constants (mrvi.h, MRVI_TUNING_LIST; doc/solver.md,
 * "Tuning"): the defaults are the table's, every name can be set and read
 * back, unknown names and bad values are refused with a clear message, the
 * doc's table equals the code's, and changing a value changes the choice
 * it governs: dense_max the path, shoot_kappa whether steps shoot. */
static void test_tuning(void) {
  int count;
  const mrvi_tuning_info *t = mrvi_tuning_table(&count);
  mrvi_settings s;
  mrvi_settings_default(&s);
  char msg[300];
  CHECK(count >= 16, "%d tuning constants", count);
  for (int i = 0; i < count; i++) {
    double v = -1.0;
    CHECK(mrvi_settings_get_tuning(&s, t[i].name, &v) == 0 && v == t[i].value,
          "tuning %s: default %g, table %g", t[i].name, v, t[i].value);
    /* (each end of the range, then back) */
    const double ends[3] = {t[i].lowest, t[i].highest, t[i].value};
    for (int e = 0; e < 3; e++) {
      const int st =
          mrvi_settings_set_tuning(&s, t[i].name, ends[e], msg, sizeof msg);
      CHECK(st == 0 && mrvi_settings_get_tuning(&s, t[i].name, &v) == 0 &&
                v == ends[e] && mrvi_settings_check(&s, msg, sizeof msg) == 0,
            "tuning %s = %g: status %d, read %g (%s)", t[i].name, ends[e], st,
            v, msg);
    }
    CHECK(mrvi_settings_set_tuning(&s, t[i].name, t[i].lowest - 1.0, msg,
                                   sizeof msg) == MRVI_EINVAL &&
              strstr(msg, t[i].name) && strstr(msg, "must lie in"),
          "tuning %s below its range: '%s'", t[i].name, msg);
    CHECK(mrvi_settings_set_tuning(&s, t[i].name, NAN, msg, sizeof msg) ==
              MRVI_EINVAL,
          "tuning %s = NaN accepted", t[i].name);
    /* (a fraction inside the range: a switch 0..1 at 1 takes 0.5) */
    const double frac =
        t[i].value + 0.5 <= t[i].highest ? t[i].value + 0.5 : t[i].value - 0.5;
    if (t[i].integer)
      CHECK(mrvi_settings_set_tuning(&s, t[i].name, frac, msg, sizeof msg) ==
                    MRVI_EINVAL &&
                strstr(msg, "integer"),
            "tuning %s = %g: '%s'", t[i].name, frac, msg);
  }
  mrvi_settings d;
  mrvi_settings_default(&d);
  CHECK(memcmp(&s.tuning, &d.tuning, sizeof d.tuning) == 0,
        "tuning not back at its defaults");
  CHECK(mrvi_settings_set_tuning(&s, "shoot_kapa", 1.0, msg, sizeof msg) ==
                MRVI_EINVAL &&
            strstr(msg, "unknown tuning constant 'shoot_kapa'") &&
            strstr(msg, "did you mean 'shoot_kappa'"),
        "unknown name: '%s'", msg);
  double v;
  CHECK(mrvi_settings_get_tuning(&s, "no_such_constant", &v) == MRVI_EINVAL,
        "get of an unknown name");
  s.tuning.dense_max = -1; /* (set directly: the check sees it) */
  CHECK(mrvi_settings_check(&s, msg, sizeof msg) == MRVI_EINVAL &&
            strstr(msg, "dense_max"),
        "dense_max = -1 passed the check: '%s'", msg);

  /* The doc's table: one row per constant, `name` | default | meaning. */
  FILE *f = fopen(test_source_path("doc/solver.md"), "r");
  CHECK(f != NULL, "doc/solver.md not found");
  if (f) {
    static char doc[1 << 18];
    const size_t n = fread(doc, 1, sizeof doc - 1, f);
    doc[n] = '\0';
    fclose(f);
    const char *sec = strstr(doc, "\n## Tuning\n");
    CHECK(sec != NULL, "doc/solver.md: no Tuning section");
    const char *end = sec ? strstr(sec + 1, "\n## ") : NULL;
    int rows = 0;
    for (const char *l = sec;
         l && (l = strstr(l, "\n| `")) && (!end || l < end); l++)
      rows++;
    CHECK(rows == count, "doc/solver.md, Tuning: %d rows, the code %d", rows,
          count);
    for (int i = 0; sec && i < count; i++) {
      char row[600];
      snprintf(row, sizeof row, "\n| `%s` | %g | %s |\n", t[i].name, t[i].value,
               t[i].meaning);
      CHECK(strstr(sec, row) != NULL, "doc/solver.md, Tuning: no row%s", row);
    }
  }

  /* dense_max: the fpu's blocks (3 slow, 3 fast) beyond it take the
   * Krylov form of the schur path. */
  mrvi_model *m = test_fpu();
  mrvi_settings_default(&s);
  CHECK(strcmp(mrvi_solver_path(m, &s, NULL, 0), "schur") == 0,
        "fpu midpoint-midpoint: %s", mrvi_solver_path(m, &s, NULL, 0));
  mrvi_settings_set_tuning(&s, "dense_max", 2, msg, sizeof msg);
  CHECK(strcmp(mrvi_solver_path(m, &s, NULL, 0), "schur-krylov") == 0,
        "fpu midpoint-midpoint, dense_max 2: %s",
        mrvi_solver_path(m, &s, NULL, 0));
  mrvi_settings_set_scheme(&s, "explicit-slow");
  CHECK(strcmp(mrvi_solver_path(m, &s, NULL, 0), "sweep-cg") == 0,
        "fpu explicit-slow, dense_max 2: %s", mrvi_solver_path(m, &s, NULL, 0));
  mrvi_model_free(m);

  /* shoot_kappa: trapezoidal-trapezoidal at p = 10 shoots every step by
   * its rule (test_shoot); with shoot_kappa 0 below the run's kappa, none,
   * and the same solution to the tolerance. */
  mrvi_system *sys = fpu_at("trapezoidal-trapezoidal", "0.01", 10, "1e-12");
  if (sys) {
    static run_out au, no;
    run(sys, &au);
    CHECK(mrvi_settings_set_tuning(&sys->settings, "shoot_kappa", 0.0, msg,
                                   sizeof msg) == 0,
          "%s", msg);
    run(sys, &no);
    CHECK(au.ok && no.ok && au.nshoot == N_STEPS && no.nshoot == 0 &&
              rel_diff(&au, &no) <= 1e-10,
          "fpu trapezoidal-trapezoidal p=10: %ld steps shot by default, %ld "
          "with shoot_kappa 0, %.2e apart",
          au.nshoot, no.nshoot, rel_diff(&au, &no));
    mrvi_system_free(sys);
  }
}

/* Keeping the last micro node alone (mrvi_integrator_keep_micro) leaves
 * the trajectory bit for bit on every path (one row kept), and the last
 * micro node too: on the explicit, sweep and sweep-cg paths each node is
 * written over the last; the Newton paths solve every node but copy out
 * the last alone and leave the interior nodes' momentum projection out
 * (an output only: schur-bordered with micro-node constraints). */
static void test_keep_micro(void) {
  static const char *const schemes[] = {"fully-explicit", "explicit-slow",
                                        "trapezoidal-trapezoidal",
                                        "midpoint-midpoint"};
  static run_out all, last;
  int n_last = 0, seen_cg = 0, n_bordered = 0;
  for (int i = 0; i < N_SYSTEMS; i++)
    for (int sc = 0; sc < 4; sc++)
      for (int p = 1; p <= 5; p += 4)
        for (int cg = 0; cg < 2; cg++) {
          mrvi_system *sys =
              load(systems[i], schemes[sc], p, "multipliers", "auto");
          if (!sys)
            continue;
          char msg[200];
          if (cg && mrvi_settings_set_tuning(&sys->settings, "dense_max", 1,
                                             msg, sizeof msg) < 0)
            CHECK(0, "%s", msg);
          memset(&all, 0, sizeof all);
          memset(&last, 0, sizeof last);
          run_last_only = 0;
          run(sys, &all);
          run_last_only = 1;
          run(sys, &last);
          run_last_only = 0;
          mrvi_system_free(sys);
          if (!all.ok || !last.ok)
            continue;
          const int structured = !strcmp(all.path, "explicit") ||
                                 !strcmp(all.path, "sweep") ||
                                 !strcmp(all.path, "sweep-cg");
          n_last += structured;
          seen_cg |= !strcmp(all.path, "sweep-cg");
          n_bordered += p > 1 && !strcmp(all.path, "schur-bordered");
          int same = 1;
          const int nf = all.nmicro / p;
          for (int k = 0; k <= N_STEPS; k++) {
            same &=
                !memcmp(all.q[k], last.q[k], (size_t)all.n * sizeof(double));
            same &=
                !memcmp(all.p[k], last.p[k], (size_t)all.n * sizeof(double));
            if (k < N_STEPS)
              same &= !memcmp(all.micro[k] + (size_t)(p - 1) * nf,
                              last.micro[k] + (size_t)(p - 1) * nf,
                              (size_t)nf * sizeof(double));
          }
          CHECK(same,
                "%s %s p=%d dense_max %s (%s): the last micro node "
                "alone changes the run",
                systems[i], schemes[sc], p, cg ? "1" : "default", all.path);
        }
  CHECK(n_last >= 10 && seen_cg, "keep_micro: %d runs on the sweep paths, %s",
        n_last, seen_cg ? "sweep-cg seen" : "sweep-cg not seen");
  CHECK(n_bordered >= 4, "keep_micro: %d runs on schur-bordered at p > 1",
        n_bordered);
  /* Without the nodes there is no step Jacobian to solve with. */
  mrvi_system *sys =
      load("systems/lattice.yaml", "fully-explicit", 5, "multipliers", "auto");
  mrvi_integrator *it = NULL;
  char msg[300];
  if (sys && mrvi_integrator_create(sys->model, &sys->settings, &it, msg,
                                    sizeof msg) == 0) {
    const int nj = mrvi_integrator_jacobian_size(it);
    double *b = calloc((size_t)nj, sizeof *b),
           *x = calloc((size_t)nj, sizeof *x);
    const int rows = mrvi_integrator_keep_micro(it, 0);
    const int st = mrvi_integrator_step(it);
    const int js = b && x ? mrvi_integrator_jacobian_solve(it, 0, b, x) : 0;
    CHECK(rows == 1 && st == 0 && js == MRVI_EINVAL &&
              strstr(mrvi_integrator_errmsg(it), "keep_micro"),
          "lattice fully-explicit, last node alone: rows %d, step %d, "
          "jacobian_solve %d (%s)",
          rows, st, js, mrvi_integrator_errmsg(it));
    free(b);
    free(x);
  }
  mrvi_integrator_free(it);
  /* Switching between the two during a run (the state's buffers change
   * hands with the last node alone, mrvi_integrator_keep_micro resizes
   * them) leaves it bit for bit; the step Jacobian is back after a step
   * with every node kept. */
  mrvi_integrator *ref = NULL;
  it = NULL;
  if (sys &&
      mrvi_integrator_create(sys->model, &sys->settings, &ref, msg,
                             sizeof msg) == 0 &&
      mrvi_integrator_create(sys->model, &sys->settings, &it, msg,
                             sizeof msg) == 0) {
    const int n = mrvi_model_n(sys->model), nf = sys->model->n_fast;
    const int p = sys->settings.micro_steps,
              nj = mrvi_integrator_jacobian_size(it);
    double *b = calloc((size_t)nj, sizeof *b),
           *x = calloc((size_t)nj, sizeof *x);
    int same = 1, steps = 0, js = -1;
    for (int k = 0; k < 12 && b && x; k++) {
      if (k % 4 == 0)
        mrvi_integrator_keep_micro(it, k % 8 == 4);
      if (mrvi_integrator_step(ref) < 0 || mrvi_integrator_step(it) < 0)
        break;
      steps++;
      same &= !memcmp(mrvi_integrator_q(ref), mrvi_integrator_q(it),
                      (size_t)n * sizeof(double)) &&
              !memcmp(mrvi_integrator_p(ref), mrvi_integrator_p(it),
                      (size_t)n * sizeof(double));
      const size_t last = k % 8 >= 4 ? (size_t)(p - 1) * (size_t)nf : 0;
      same &= !memcmp(mrvi_integrator_micro_q(ref) + (size_t)(p - 1) * nf,
                      mrvi_integrator_micro_q(it) + last,
                      (size_t)nf * sizeof(double)) &&
              !memcmp(mrvi_integrator_micro_p(ref) + (size_t)(p - 1) * nf,
                      mrvi_integrator_micro_p(it) + last,
                      (size_t)nf * sizeof(double));
      if (k == 5)
        js = mrvi_integrator_jacobian_solve(it, 0, b, x);
    }
    CHECK(steps == 12 && same && js == 0,
          "lattice fully-explicit, last node alone and all nodes in turn: "
          "%d steps, %s, jacobian_solve %d",
          steps, same ? "bit for bit" : "the run changes", js);
    free(b);
    free(x);
  }
  mrvi_integrator_free(ref);
  mrvi_integrator_free(it);
  mrvi_system_free(sys);
}

/* Issue 26, class 10: a stiff quartic W (explicit-slow, dT = 0.3, p = 1,
 * omega dt about 10 at the start).  The sweep's row-0 estimate (the
 * implicit force at the free flight) then moves away from the solution:
 * its micro-step Newton took 17 updates in step 1 and failed in step 2 at
 * the default 20, where the general path takes 6 to 8.  With the fallback
 * to the free flight (sweep.c, solve_implicit) the sweep needs no more
 * updates than the general path plus one, at the default iteration limit,
 * and at p = 5 (rows 1..4 keep their estimate) too. */
static const char stiff_quartic_yaml[] =
    "name: stiff_quartic\n"
    "coordinates:\n"
    "  - {name: qs, mass: 1, position: 1, velocity: 0, rate: slow}\n"
    "  - {name: qf1, mass: 1, position: 0.5, velocity: 1, rate: fast}\n"
    "  - {name: qf2, mass: 1, position: 0, velocity: 0, rate: fast}\n"
    "terms:\n"
    "  - {combination: {qs: 1}, law: linear, stiffness: 1, potential: slow}\n"
    "  - {combination: {qs: 1, qf1: -1}, law: linear, stiffness: 1, "
    "potential: slow}\n"
    "  - {combination: {qf1: 1}, law: power, coefficient: 400, exponent: 4, "
    "potential: fast}\n"
    "  - {combination: {qf2: 1, qf1: -1}, law: power, coefficient: 400, "
    "exponent: 4, potential: fast}\n"
    "integrator: {scheme: explicit-slow, macro_step: 0.3}\n";

static void test_stiff_quartic_sweep(void) {
  static run_out a, b;
  for (int p = 1; p <= 5; p += 4) {
    mrvi_system *sys[2] = {NULL, NULL};
    char ov[2][64], msg[512];
    const char *ovp[2] = {ov[0], ov[1]};
    snprintf(ov[0], sizeof ov[0], "integrator.micro_steps=%d", p);
    for (int g = 0; g < 2; g++) {
      snprintf(ov[1], sizeof ov[1], "integrator.solver=%s",
               g ? "general" : "auto");
      CHECK(mrvi_system_load_string(stiff_quartic_yaml, "stiff.yaml", ovp, 2,
                                    &sys[g], msg, sizeof msg) == MRVI_OK,
            "stiff quartic: %s", msg);
    }
    if (sys[0] && sys[1]) {
      run(sys[0], &a);
      run(sys[1], &b);
      int ia = 0, ib = 0;
      for (int k = 0; k < N_STEPS; k++) {
        ia = a.iters[k] > ia ? a.iters[k] : ia;
        ib = b.iters[k] > ib ? b.iters[k] : ib;
      }
      CHECK(a.ok && b.ok && strcmp(a.path, "sweep") == 0,
            "stiff quartic p=%d: the sweep path completes (%s)", p,
            a.ok ? a.path : "failed");
      CHECK(a.ok && b.ok && ia <= ib + 1,
            "stiff quartic p=%d: sweep at most %d micro-step updates, "
            "general %d",
            p, ia, ib);
      const double d = a.ok && b.ok ? rel_diff(&a, &b) : INFINITY;
      CHECK(d <= 1e-7, "stiff quartic p=%d: sweep vs general %.2e", p, d);
    }
    mrvi_system_free(sys[0]);
    mrvi_system_free(sys[1]);
  }
}

/* newton.criterion: scaled (issue 26, class 10): masses 1e6 and 1e-6, the
 * fast momenta about 5e-6.  At the absolute tolerance 1e-12 the sweep and
 * general paths agree on the light coordinate only to about 1e-7 relative
 * (its rows' residual is near its momentum's size); with the scaled
 * criterion (each row divided by its mass) to 1e-10 in every coordinate
 * and at every node, micro nodes included. */
static const char tiny_mass_yaml[] =
    "name: tiny_mass\n"
    "coordinates:\n"
    "  - {name: qs, mass: 1.0e6, position: 1, velocity: 0, rate: slow}\n"
    "  - {name: qf, mass: 1.0e-6, position: 0.1, velocity: 5, rate: fast}\n"
    "terms:\n"
    "  - {combination: {qs: 1}, law: linear, stiffness: 1.0e6, "
    "potential: slow}\n"
    "  - {combination: {qs: 1, qf: -1}, law: linear, stiffness: 1.0e-6, "
    "potential: slow}\n"
    "  - {combination: {qf: 1}, law: power, coefficient: 1.0e-3, exponent: 4, "
    "potential: fast}\n"
    "  - {combination: {qf: 1}, law: linear, stiffness: 2.5e-3, "
    "potential: fast}\n"
    "integrator: {scheme: explicit-slow, macro_step: 0.1, micro_steps: 5, "
    "newton: {tolerance: 1.0e-12}}\n";

/* max over coordinates (and micro nodes) of max_k |a - b| / max_k |b|. */
static double rel_diff_each(const run_out *a, const run_out *b) {
  double worst = 0.0;
  for (int w = 0; w < 3; w++) {
    const int n = w == 2 ? a->nmicro : a->n;
    for (int i = 0; i < n; i++) {
      double d = 0.0, s = 0.0;
      for (int k = 0; k < (w == 2 ? N_STEPS : N_STEPS + 1); k++) {
        const double x = w == 0   ? a->q[k][i]
                         : w == 1 ? a->p[k][i]
                                  : a->micro[k][i];
        const double y = w == 0   ? b->q[k][i]
                         : w == 1 ? b->p[k][i]
                                  : b->micro[k][i];
        d = fmax(d, fabs(x - y));
        s = fmax(s, fabs(y));
      }
      if (s > 0)
        worst = fmax(worst, d / s);
    }
  }
  return worst;
}

static void test_scaled_criterion(void) {
  static run_out a, b;
  const char *const criteria[] = {"absolute", "scaled"};
  double d[2] = {INFINITY, INFINITY};
  for (int c = 0; c < 2; c++) {
    mrvi_system *sys[2] = {NULL, NULL};
    char ov[2][64], msg[512];
    const char *ovp[2] = {ov[0], ov[1]};
    snprintf(ov[0], sizeof ov[0], "integrator.newton.criterion=%s",
             criteria[c]);
    for (int g = 0; g < 2; g++) {
      snprintf(ov[1], sizeof ov[1], "integrator.solver=%s",
               g ? "general" : "auto");
      CHECK(mrvi_system_load_string(tiny_mass_yaml, "tiny.yaml", ovp, 2,
                                    &sys[g], msg, sizeof msg) == MRVI_OK,
            "tiny mass: %s", msg);
    }
    if (sys[0] && sys[1]) {
      CHECK(sys[0]->settings.newton_criterion ==
                (c ? MRVI_CRITERION_SCALED : MRVI_CRITERION_ABSOLUTE),
            "tiny mass: criterion %s loaded", criteria[c]);
      run(sys[0], &a);
      run(sys[1], &b);
      CHECK(a.ok && strcmp(a.path, "sweep") == 0, "tiny mass: path %s",
            a.ok ? a.path : "-");
      if (a.ok && b.ok)
        d[c] = rel_diff_each(&a, &b);
    }
    mrvi_system_free(sys[0]);
    mrvi_system_free(sys[1]);
  }
  CHECK(d[1] <= 1e-10,
        "tiny mass, scaled criterion: sweep vs general %.2e relative", d[1]);
  /* (the case the criterion is for: the absolute one is far looser here) */
  CHECK(d[0] > 1e3 * d[1], "tiny mass: absolute %.2e against scaled %.2e", d[0],
        d[1]);
}

/* The ordering rule of solver/newton.c on two patterns of the same size
 * above MRVI_NEWTON_METIS_TRY: a chain (each of nb blocks of 3 unknowns
 * coupled to itself and the next, as the rigid chain's step), whose AMD
 * order is nearly fill-free, must keep AMD; a 2-D five-point lattice of
 * side m, where nested dissection's O(m^2 log m) fill beats minimum
 * degree's, must take METIS.  Both then factorise and solve to round-off. */
static void test_ordering_choice(void) {
  const int m = 120, n = m * m, nb = n / 3;
  int *Ap = malloc((size_t)(n + 1) * sizeof *Ap);
  int *Ai = malloc(9 * (size_t)n * sizeof *Ai);
  double *Ax = malloc(9 * (size_t)n * sizeof *Ax);
  double *b = malloc((size_t)n * sizeof *b), *x = malloc((size_t)n * sizeof *x);
  for (int lattice = 0; lattice < 2; lattice++) {
    int nnz = 0;
    for (int j = 0; j < n; j++) {
      Ap[j] = nnz;
      /* Column j: rows in increasing order, diagonally dominant. */
      if (lattice) {
        const int r = j / m, c = j % m;
        const int nb4[5] = {r > 0 ? j - m : -1, c > 0 ? j - 1 : -1, j,
                            c + 1 < m ? j + 1 : -1, r + 1 < m ? j + m : -1};
        for (int k = 0; k < 5; k++)
          if (nb4[k] >= 0) {
            Ai[nnz] = nb4[k];
            Ax[nnz++] = nb4[k] == j ? 4.5 : -1.0 - 0.01 * k;
          }
      } else {
        const int blk = j / 3, lo = (blk > 0 ? blk - 1 : 0) * 3,
                  hi = (blk + 1 < nb ? blk + 2 : nb) * 3;
        for (int i = lo; i < hi; i++) {
          Ai[nnz] = i;
          Ax[nnz++] = i == j ? 10.0 : 0.3 + 0.01 * ((i + 2 * j) % 7);
        }
      }
    }
    Ap[n] = nnz;
    char msg[200];
    mrvi_newton *nw = mrvi_newton_create(n, Ap, Ai, Ax, 0, msg, sizeof msg);
    CHECK(nw != NULL, "ordering: create: %s", msg);
    if (!nw)
      continue;
    const int want = lattice ? UMFPACK_ORDERING_METIS : UMFPACK_ORDERING_AMD;
    CHECK(mrvi_newton_ordering(nw) == want,
          "ordering of the %s (n = %d): %d, expected %d",
          lattice ? "lattice" : "chain", n, mrvi_newton_ordering(nw), want);
    for (int i = 0; i < n; i++)
      b[i] = sin(0.3 + 1.1 * i);
    CHECK(mrvi_newton_solve(nw, Ax, b, x, msg, sizeof msg) == MRVI_OK,
          "ordering: solve: %s", msg);
    double worst = 0.0;
    for (int i = 0; i < n; i++)
      worst = fmax(worst, fabs(b[i]));
    for (int j = 0; j < n; j++)
      for (int e = Ap[j]; e < Ap[j + 1]; e++)
        b[Ai[e]] -= Ax[e] * x[j];
    double r = 0.0;
    for (int i = 0; i < n; i++)
      r = fmax(r, fabs(b[i]));
    CHECK(r <= 1e3 * DBL_EPSILON * 10.0 * worst, "ordering (%s): residual %.2e",
          lattice ? "lattice" : "chain", r);
    printf("ordering: %s of %d rows -> %s\n", lattice ? "lattice" : "chain", n,
           mrvi_newton_ordering(nw) == UMFPACK_ORDERING_METIS ? "METIS"
                                                              : "AMD");
    mrvi_newton_free(nw);
  }
  free(Ap);
  free(Ai);
  free(Ax);
  free(b);
  free(x);
}

/* The dense/sparse switch of solver/newton.c within newton_dense_max (512
 * here): a chain of 140 blocks of 3 unknowns (each coupled to itself and
 * the next) numbered i -> 97 i mod n, which the dense LU's degree ordering
 * leaves scattered (its fill near n^2 against AMD's nearly none), must take
 * UMFPACK; 20 dense node blocks of 22 joined by 3 x 3 couplings and a
 * dense border of 10 rows and columns (a body step's shape), whose
 * degree ordering is fill-free, must keep the dense LU.  Each solves to
 * round-off and agrees with UMFPACK's solution (dense_max 0);
 * mrvi_newton_dense_chosen takes the same decision. */
static void test_dense_switch(void) {
  for (int body = 0; body < 2; body++) {
    const int n = body ? 22 * 20 + 10 : 3 * 140, nb = n / 3;
    int *Ap = malloc((size_t)(n + 1) * sizeof *Ap);
    int *Ai = malloc((size_t)n * (size_t)n * sizeof *Ai);
    double *Ax = malloc((size_t)n * (size_t)n * sizeof *Ax);
    double *b = malloc(3 * (size_t)n * sizeof *b), *x = b + n, *y = x + n;
    int nnz = 0;
    for (int j = 0; j < n; j++) {
      Ap[j] = nnz;
      const int J = (int)(97L * j % n), lo = (J / 3 > 0 ? J / 3 - 1 : 0) * 3,
                hi = (J / 3 + 1 < nb ? J / 3 + 2 : nb) * 3;
      for (int i = 0; i < n; i++) {
        const int I = (int)(97L * i % n), bi = i < n - 10 ? i / 22 : -1,
                  bj = j < n - 10 ? j / 22 : -1;
        const int on = body
                           ? bi < 0 || bj < 0 || bi == bj ||
                                 (abs(bi - bj) == 1 && i % 22 < 3 && j % 22 < 3)
                           : I >= lo && I < hi;
        if (on) {
          Ai[nnz] = i;
          Ax[nnz++] = i == j ? 50.0 : 0.3 + 0.01 * ((i + 2 * j) % 7);
        }
      }
    }
    Ap[n] = nnz;
    char msg[200];
    mrvi_newton *nw = mrvi_newton_create(n, Ap, Ai, Ax, 512, msg, sizeof msg),
                *sp = mrvi_newton_create(n, Ap, Ai, Ax, 0, msg, sizeof msg);
    CHECK(nw && sp, "dense switch: create: %s", msg);
    if (nw && sp) {
      CHECK((mrvi_newton_ordering(nw) < 0) == body,
            "dense switch: %s of %d rows: ordering %d (-1: dense LU)",
            body ? "body blocks" : "scrambled chain", n,
            mrvi_newton_ordering(nw));
      /* the decision alone (the general path's cost estimate), with the
       * values and from the pattern alone */
      CHECK(mrvi_newton_dense_chosen(n, Ap, Ai, Ax, 512) == body &&
                mrvi_newton_dense_chosen(n, Ap, Ai, NULL, 512) == body &&
                mrvi_newton_dense_chosen(n, Ap, Ai, NULL, n - 1) == 0,
            "dense switch: %s: mrvi_newton_dense_chosen disagrees",
            body ? "body blocks" : "scrambled chain");
      for (int i = 0; i < n; i++)
        b[i] = sin(0.3 + 1.1 * i);
      CHECK(mrvi_newton_solve(nw, Ax, b, x, msg, sizeof msg) == MRVI_OK &&
                mrvi_newton_solve(sp, Ax, b, y, msg, sizeof msg) == MRVI_OK,
            "dense switch: solve: %s", msg);
      double d = 0.0, r = 0.0;
      for (int i = 0; i < n; i++)
        d = fmax(d, fabs(x[i] - y[i]));
      for (int j = 0; j < n; j++)
        for (int e = Ap[j]; e < Ap[j + 1]; e++)
          b[Ai[e]] -= Ax[e] * x[j];
      for (int i = 0; i < n; i++)
        r = fmax(r, fabs(b[i]));
      CHECK(r <= 1e3 * DBL_EPSILON && d <= 1e3 * DBL_EPSILON,
            "dense switch (%s): residual %.2e, against UMFPACK %.2e",
            body ? "body blocks" : "scrambled chain", r, d);
      printf("dense switch: %s of %d rows -> %s\n",
             body ? "body blocks" : "scrambled chain", n,
             mrvi_newton_ordering(nw) < 0 ? "dense LU" : "UMFPACK");
    }
    mrvi_newton_free(nw);
    mrvi_newton_free(sp);
    free(Ap);
    free(Ai);
    free(Ax);
    free(b);
  }
}

int main(void) {
  test_bordered_transpose();
  test_ordering_choice();
  test_dense_switch();
  test_keep_micro();
  test_stiff_quartic_sweep();
  test_scaled_criterion();
  test_tuning();
  test_path_names();
  test_direct();
  test_chord();
  test_const_chord();
  test_shoot();
  test_linsolve_backends();
  test_transpose_kept_cost();
  test_predictor();
  test_predictor_large_steps();
  test_predictor_small_steps();
  test_predictor_one_point();
  test_jacobian_solve_constrained();
  test_blowup();
  test_tiny_steps();
  test_paths_agree();
  chain_case(3);
  chain_case(5);
  test_choice();
  test_jacobian_solve();
  return test_finish();
}
