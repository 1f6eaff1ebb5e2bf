/* Run driver and integrator API: number of steps, failure messages,
 * interruption, observer stop, restart from a saved state, settings checks. */
#include "model/model.h"
#include "models.h"
#include "testlib.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef struct counter {
  long calls, last_k, stop_at;
  double last_t;
  int micro_rows;
  volatile int *flag;
  long flag_at;
} counter;

static int count(void *user, const mrvi_record *r) {
  counter *c = user;
  c->calls++;
  c->last_k = r->k;
  c->last_t = r->t;
  c->micro_rows += r->micro_count;
  if (c->flag && r->k == c->flag_at)
    *c->flag = 1;
  return c->stop_at >= 0 && r->k == c->stop_at ? MRVI_EIO : 0;
}

static void steps_and_times(void) {
  mrvi_model *m = test_fpu();
  /* t_end = 200, dT = 0.3: N = ceil(666.67) = 667, the last node at 200.1 */
  mrvi_settings s = test_settings("midpoint-midpoint", 0.3, 2, 200.0, 1e-9);
  CHECK(mrvi_settings_n_steps(&s) == 667, "N for 200/0.3");
  s.t_end = 0.9; /* exactly 3 steps despite 0.9/0.3 = 3.0000000000000004 */
  CHECK(mrvi_settings_n_steps(&s) == 3, "N for 0.9/0.3");
  counter c = {.stop_at = -1};
  mrvi_summary sum;
  CHECK(mrvi_run(m, &s, count, &c, NULL, &sum) == 0, "run");
  CHECK(c.calls == 4 && c.last_k == 3, "observer sees k = 0..N");
  CHECK_NEAR(c.last_t, 0.9, 1e-15, "last time");
  CHECK(c.micro_rows == 3 * 2 + 1, "micro rows N p + 1");
  CHECK(sum.steps == 3 && sum.iterations_total >= 3, "summary counts");
  mrvi_model_free(m);
}

static void newton_failure(void) {
  mrvi_model *m = test_fpu();
  mrvi_settings s = test_settings("midpoint-midpoint", 0.3, 5, 3.0, 1e-14);
  s.newton_max_iter = 1;
  counter c = {.stop_at = -1};
  mrvi_summary sum;
  int st = mrvi_run(m, &s, count, &c, NULL, &sum);
  CHECK(st == MRVI_ENEWTON, "non-convergence is an error (%d)", st);
  CHECK(strstr(sum.message, "step 1 ") && strstr(sum.message, "t = 0") &&
            strstr(sum.message, "residual"),
        "message names step, time and residual: %s", sum.message);
  CHECK(c.calls == 1, "only the initial node was observed");
  mrvi_model_free(m);
}

static void interruption(void) {
  mrvi_model *m = test_fpu();
  mrvi_settings s = test_settings("trapezoidal-midpoint", 0.1, 3, 5.0, 1e-10);
  volatile int flag = 0;
  counter c = {.stop_at = -1, .flag = &flag, .flag_at = 7};
  mrvi_summary sum;
  int st = mrvi_run(m, &s, count, &c, &flag, &sum);
  CHECK(st == MRVI_EINTERRUPTED, "stop flag interrupts (%d)", st);
  CHECK(sum.steps == 7 && c.last_k == 7, "7 steps completed (%ld)", sum.steps);
  CHECK(strstr(sum.message, "interrupted") != NULL, "message: %s", sum.message);
  counter d = {.stop_at = 4};
  st = mrvi_run(m, &s, count, &d, NULL, &sum);
  CHECK(st == MRVI_EIO && d.last_k == 4, "observer stops the run");
  mrvi_model_free(m);
}

/* A run restarted from a saved (q, p) continues the same trajectory bit for
 * bit: the one-step map only needs (q_k, p_k) (arXiv 2406.12991 §3.1,
 * doc/solver.md); no solver state (predictor forces, factors, multipliers)
 * is carried from one step to the next.  On the schur (also where the
 * predictor solves the slow row), sweep (with a non-linear W: the
 * lattice's fast springs; with a quadratic W: the FPU) and explicit paths. */
static void restart_case(const mrvi_model *m, const mrvi_settings *s,
                         const char *label) {
  mrvi_integrator *a = NULL, *b = NULL;
  char msg[256];
  CHECK(mrvi_integrator_create(m, s, &a, msg, sizeof msg) == 0, "%s", msg);
  CHECK(mrvi_integrator_create(m, s, &b, msg, sizeof msg) == 0, "%s", msg);
  if (!a || !b) {
    mrvi_integrator_free(a);
    mrvi_integrator_free(b);
    return;
  }
  for (int k = 0; k < 10; k++)
    mrvi_integrator_step(a);
  mrvi_integrator_set_state(b, mrvi_integrator_time(a), mrvi_integrator_q(a),
                            mrvi_integrator_p(a));
  for (int k = 0; k < 10; k++) {
    mrvi_integrator_step(a);
    mrvi_integrator_step(b);
  }
  double d = 0;
  for (int i = 0; i < m->n; i++)
    d = fmax(d, fabs(mrvi_integrator_q(a)[i] - mrvi_integrator_q(b)[i]) +
                    fabs(mrvi_integrator_p(a)[i] - mrvi_integrator_p(b)[i]));
  CHECK(d == 0.0,
        "%s (%s path): restart reproduces the trajectory bitwise "
        "(%.3e)",
        label, mrvi_integrator_solver_path(a), d);
  CHECK_NEAR(mrvi_integrator_time(b), 20 * s->macro_step, 1e-14,
             "restart time");
  mrvi_integrator_free(a);
  mrvi_integrator_free(b);
}

static void restart(void) {
  mrvi_model *m = test_spring_ring();
  mrvi_settings s = test_settings("midpoint-midpoint", 0.01, 5, 1.0, 1e-12);
  restart_case(m, &s, "spring ring, midpoint-midpoint");
  mrvi_integrator *a = NULL;
  char msg[256];
  CHECK(mrvi_integrator_create(m, &s, &a, msg, sizeof msg) == 0, "%s", msg);
  CHECK(mrvi_integrator_system_size(a) == 9 + 5 * 9, "system size ns + p nf");
  mrvi_integrator_free(a);
  mrvi_model_free(m);
  m = test_fpu();
  s = test_settings("fully-explicit", 0.01, 5, 1.0, 1e-12);
  restart_case(m, &s, "fpu, fully-explicit");
  /* quadratic W on a small block: the affine sweep from the first step */
  s = test_settings("explicit-slow", 0.01, 5, 1.0, 1e-12);
  restart_case(m, &s, "fpu, explicit-slow");
  s = test_settings("explicit-slow", 0.001, 1, 1.0, 1e-12);
  restart_case(m, &s, "fpu, explicit-slow, p = 1");
  /* dT = 1 with dt = 0.001: the predictor solves the slow row by sampled
   * Newton steps and sweeps again (solver/predict.c, slow_newton). */
  s = test_settings("midpoint-midpoint", 1.0, 1000, 20.0, 1e-9);
  restart_case(m, &s, "fpu dT = 1, p = 1000, midpoint-midpoint");
  /* dT = 0.001, p = 1 and 2: the constant chord (one factorisation per
   * run, made on the restarted run's first step) */
  s = test_settings("midpoint-midpoint", 0.001, 1, 1.0, 1e-9);
  restart_case(m, &s, "fpu dT = 0.001, p = 1, midpoint-midpoint");
  s = test_settings("midpoint-midpoint", 0.002, 2, 1.0, 1e-9);
  restart_case(m, &s, "fpu dT = 0.002, p = 2, midpoint-midpoint");
  mrvi_model_free(m);
  mrvi_system *sys = NULL;
  const char *set[] = {"integrator.scheme=explicit-slow",
                       "integrator.micro_steps=5",
                       "integrator.newton.tolerance=1e-12"};
  CHECK(mrvi_system_load(test_source_path("systems/lattice.yaml"), set, 3, &sys,
                         msg, sizeof msg) == 0,
        "%s", msg);
  /* (without tuning.chord_carry: a step of (q_k, p_k) alone; with it,
   * restart_carry below) */
  if (sys) {
    sys->settings.tuning.chord_carry = 0;
    restart_case(sys->model, &sys->settings, "lattice, explicit-slow");
  }
  mrvi_system_free(sys);
}

/* tuning.chord_carry (solver/sweep.c): a step takes the rows' history of
 * the one before, so the restart of restart_case continues bit for bit
 * only with that history (mrvi_integrator_chord_history, then
 * mrvi_integrator_resume_chord_history after resume_state); restarted from
 * (q, p) alone it continues within the tolerance, not bit for bit (the
 * history matters).  The first step has none; a history of another size,
 * a non-finite one, or one given to a run without carry is refused. */
static void restart_carry(void) {
  mrvi_system *sys = NULL;
  char msg[256];
  const char *set[] = {
      "integrator.scheme=explicit-slow", "integrator.micro_steps=10",
      "integrator.newton.tolerance=1e-9", "generate.0.count=[40,20]",
      "integrator.tuning.chord_carry=1"};
  CHECK(mrvi_system_load(test_source_path("systems/lattice.yaml"), set, 5, &sys,
                         msg, sizeof msg) == 0,
        "%s", msg);
  if (!sys)
    return;
  const mrvi_model *m = sys->model;
  mrvi_integrator *a = NULL, *b = NULL, *c = NULL, *off = NULL;
  mrvi_settings s_off = sys->settings;
  s_off.tuning.chord_carry = 0;
  CHECK(
      mrvi_integrator_create(m, &sys->settings, &a, msg, sizeof msg) == 0 &&
          mrvi_integrator_create(m, &sys->settings, &b, msg, sizeof msg) == 0 &&
          mrvi_integrator_create(m, &sys->settings, &c, msg, sizeof msg) == 0 &&
          mrvi_integrator_create(m, &s_off, &off, msg, sizeof msg) == 0,
      "%s", msg);
  if (a && b && c && off) {
    const double *part[5];
    CHECK(mrvi_integrator_chord_history(a, part) == 0,
          "chord carry: no history before the first step");
    for (int k = 0; k < 10; k++)
      mrvi_integrator_step(a);
    const int nh = mrvi_integrator_chord_history(a, part);
    CHECK(nh == m->n_fast, "chord carry: history of %d per row (%d fast)", nh,
          m->n_fast);
    double *h = malloc(5 * (size_t)(nh > 0 ? nh : 1) * sizeof *h);
    for (int i = 0; i < 5 && nh > 0; i++)
      memcpy(h + (size_t)i * (size_t)nh, part[i], (size_t)nh * sizeof *h);
    const long k = mrvi_integrator_step_index(a);
    CHECK(mrvi_integrator_resume_state(b, k, mrvi_integrator_q(a),
                                       mrvi_integrator_p(a)) == 0,
          "resume b");
    CHECK(mrvi_integrator_resume_chord_history(b, nh, h) == 0, "%s",
          mrvi_integrator_errmsg(b));
    CHECK(mrvi_integrator_resume_state(c, k, mrvi_integrator_q(a),
                                       mrvi_integrator_p(a)) == 0,
          "resume c");
    /* refused: another size, a non-finite entry, a run without carry */
    CHECK(mrvi_integrator_resume_chord_history(c, nh - 1, h) == MRVI_EINVAL,
          "chord carry: a history of another size refused");
    const double keep = h[3 * (size_t)nh + 2];
    h[3 * (size_t)nh + 2] = NAN;
    CHECK(mrvi_integrator_resume_chord_history(c, nh, h) == MRVI_ENONFINITE,
          "chord carry: a non-finite history refused");
    h[3 * (size_t)nh + 2] = keep;
    CHECK(mrvi_integrator_resume_chord_history(off, nh, h) == MRVI_EINVAL,
          "chord carry: a history given to a run without carry refused (%s)",
          mrvi_integrator_errmsg(off));
    CHECK(mrvi_integrator_chord_history(c, part) == 0,
          "chord carry: refused histories leave none");
    for (int j = 0; j < 10; j++) {
      mrvi_integrator_step(a);
      mrvi_integrator_step(b);
      mrvi_integrator_step(c);
    }
    double db = 0, dc = 0;
    for (int i = 0; i < m->n; i++) {
      db =
          fmax(db, fabs(mrvi_integrator_q(a)[i] - mrvi_integrator_q(b)[i]) +
                       fabs(mrvi_integrator_p(a)[i] - mrvi_integrator_p(b)[i]));
      dc =
          fmax(dc, fabs(mrvi_integrator_q(a)[i] - mrvi_integrator_q(c)[i]) +
                       fabs(mrvi_integrator_p(a)[i] - mrvi_integrator_p(c)[i]));
    }
    CHECK(db == 0.0,
          "chord carry (%s path): restart with the history bitwise (%.3e)",
          mrvi_integrator_solver_path(a), db);
    CHECK(dc > 0.0 && dc < 1e-6,
          "chord carry: restart from (q, p) alone within the tolerance, not "
          "bitwise (%.3e)",
          dc);
    printf("chord carry: restart with the history %.3g, without %.3g\n", db,
           dc);
    free(h);
  }
  mrvi_integrator_free(a);
  mrvi_integrator_free(b);
  mrvi_integrator_free(c);
  mrvi_integrator_free(off);
  mrvi_system_free(sys);
}

/* Load a description from text; NULL (and a failed check) on error. */
static mrvi_system *load_text(const char *text, const char *const *set,
                              int n_set) {
  mrvi_system *sys = NULL;
  char msg[1024];
  CHECK(mrvi_system_load_string(text, "<test>", set, n_set, &sys, msg,
                                sizeof msg) == 0,
        "load: %s", msg);
  return sys;
}

/* The energy error of the summary, its scale, the warning above
 * settings.energy_warning and the instability hint of a failed step. */
static void energy_warning(void) {
  /* FPU, explicit-slow at the paper's dT = 0.3, p = 10: completes with an
   * energy error of several hundred percent (measured 5.67). */
  mrvi_model *m = test_fpu();
  mrvi_settings s = test_settings("explicit-slow", 0.3, 10, 200.0, 1e-9);
  CHECK_NEAR(s.energy_warning, 0.1, 0.0, "default energy_warning 10 %%");
  mrvi_summary sum;
  int st = mrvi_run(m, &s, NULL, NULL, NULL, &sum);
  CHECK(st == 0, "explicit-slow dT = 0.3 completes (%d: %s)", st, sum.message);
  CHECK(sum.energy_scale_kind == 0, "H_0 > 0: relative to the initial energy");
  /* T_0 = 1, V_0 = (0.98^4 + 1.02^4)/4, W_0 = 1250 * 0.02^2: all >= 0. */
  const double H0 = 1.0 + (pow(0.98, 4) + pow(1.02, 4)) / 4 + 0.5;
  CHECK_NEAR(sum.energy_initial, H0, 1e-14, "H_0 of the FPU");
  CHECK_NEAR(sum.energy_scale, H0, 1e-14, "scale T_0 + |V_0| + |W_0| = H_0");
  CHECK(sum.max_rel_energy_error > 1.0, "energy error %g > 100 %%",
        sum.max_rel_energy_error);
  CHECK(strstr(sum.warning, "relative energy error") &&
            strstr(sum.warning, "exceeds integrator.energy_warning = 0.1") &&
            strstr(sum.warning, "reduce macro_step"),
        "warning: %s", sum.warning);
  const double err = sum.max_rel_energy_error;
  s.energy_warning = 10.0;
  mrvi_run(m, &s, NULL, NULL, NULL, &sum);
  CHECK(sum.warning[0] == '\0' && sum.max_rel_energy_error == err,
        "energy_warning = 10: same error %g, no warning", err);
  s.energy_warning = 0.0;
  mrvi_run(m, &s, NULL, NULL, NULL, &sum);
  CHECK(sum.warning[0] == '\0', "energy_warning = 0: never warns");
  s = test_settings("midpoint-midpoint", 0.3, 10, 20.0, 1e-9);
  mrvi_run(m, &s, NULL, NULL, NULL, &sum);
  CHECK(sum.warning[0] == '\0' && sum.max_rel_energy_error < 0.1,
        "midpoint-midpoint: error %g, no warning", sum.max_rel_energy_error);
  /* A Newton failure without energy growth gets no instability hint. */
  s.newton_tol = 1e-300;
  s.newton_max_iter = 2;
  st = mrvi_run(m, &s, NULL, NULL, NULL, &sum);
  CHECK(st == MRVI_ENEWTON && !strstr(sum.message, "stability limit"),
        "first-step Newton failure: no hint: %s", sum.message);
  mrvi_model_free(m);

  /* H_0 = 0 with motion: a unit mass from rest under a unit force has
   * T = t^2/2, V = -t^2/2 (exact for the midpoint rule), so the scale is the
   * largest T + |V| = t_end^2 = 1. */
  const char *falling =
      "name: fall\n"
      "coordinates: [{name: x, mass: 1, position: 0, velocity: 0}]\n"
      "forces: [{coordinate: x, force: 1}]\n"
      "integrator: {macro_step: 0.1, t_end: 1}\n";
  mrvi_system *sys = load_text(falling, NULL, 0);
  if (sys) {
    mrvi_run(sys->model, &sys->settings, NULL, NULL, NULL, &sum);
    CHECK(sum.energy_scale_kind == 1,
          "H_0 = 0: relative to the run's "
          "largest magnitude (kind %d)",
          sum.energy_scale_kind);
    CHECK_NEAR(sum.energy_scale, 1.0, 1e-12, "scale = max T + |V| = 1");
    CHECK(sum.max_rel_energy_error < 1e-13, "energy conserved: %g",
          sum.max_rel_energy_error);
  }
  mrvi_system_free(sys);
  const char *rest = "name: rest\n"
                     "coordinates: [{name: x, mass: 1, position: 0}]\n"
                     "integrator: {macro_step: 0.1, t_end: 1}\n";
  sys = load_text(rest, NULL, 0);
  if (sys) {
    mrvi_run(sys->model, &sys->settings, NULL, NULL, NULL, &sum);
    CHECK(sum.energy_scale_kind == 2 && sum.energy_scale == 1.0 &&
              sum.max_rel_energy_error == 0.0,
          "every energy 0: absolute error 0 (kind %d)", sum.energy_scale_kind);
  }
  mrvi_system_free(sys);

  /* The pendulum chain, fully explicit at dT = 0.01: the energy grows by
   * orders of magnitude, then Newton fails; the message says why. */
  const char *set[] = {"integrator.scheme=fully-explicit"};
  char msg[1024];
  sys = NULL;
  CHECK(mrvi_system_load(test_source_path("systems/pendulum_chain.yaml"), set,
                         1, &sys, msg, sizeof msg) == 0,
        "%s", msg);
  if (sys) {
    st = mrvi_run(sys->model, &sys->settings, NULL, NULL, NULL, &sum);
    CHECK(st == MRVI_ENEWTON, "pendulum chain fully explicit fails (%d)", st);
    CHECK(strstr(sum.message, "Newton did not converge") &&
              strstr(sum.message, "; energy grew from -42.7589 to ") &&
              strstr(sum.message, "is probably beyond the stability limit "
                                  "of this scheme; reduce macro_step"),
          "instability hint: %s", sum.message);
    CHECK(sum.warning[0] == '\0', "the hint is not repeated as a warning");
  }
  mrvi_system_free(sys);
}

static void settings_checks(void) {
  mrvi_settings s;
  char msg[256];
  mrvi_settings_default(&s);
  CHECK(mrvi_settings_check(&s, msg, sizeof msg) == 0, "defaults are valid");
  CHECK(mrvi_settings_set_scheme(&s, "midpoint") == MRVI_EINVAL,
        "unknown scheme");
  s.slow.alpha = 1.5;
  CHECK(mrvi_settings_check(&s, msg, sizeof msg) < 0 && strstr(msg, "alpha"),
        "alpha out of range: %s", msg);
  mrvi_settings_default(&s);
  s.micro_steps = 0;
  CHECK(mrvi_settings_check(&s, msg, sizeof msg) < 0, "p < 1");
  mrvi_settings_default(&s);
  s.t_end = s.macro_step / 2;
  CHECK(mrvi_settings_check(&s, msg, sizeof msg) < 0, "t_end < dT");
  mrvi_settings_default(&s);
  s.macro_step = -1;
  CHECK(mrvi_settings_check(&s, msg, sizeof msg) < 0, "dT <= 0");
  mrvi_model *empty = mrvi_model_create();
  mrvi_integrator *it = NULL;
  mrvi_settings_default(&s);
  CHECK(mrvi_integrator_create(empty, &s, &it, msg, sizeof msg) ==
                MRVI_EMODEL &&
            it == NULL,
        "empty model rejected");
  mrvi_model_free(empty);
  CHECK(strcmp(mrvi_strerror(MRVI_ENEWTON),
               "Newton iteration did not converge") == 0,
        "strerror");
  CHECK(strcmp(mrvi_strerror(12345), "unknown status") == 0,
        "strerror unknown");
}

/* Builder errors name the offending element or coordinate. */
static void builder_checks(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double x[2] = {0, 1}, v[2] = {0, 0}, k[1] = {1};
  CHECK(mrvi_model_add_particle(m, "s", 1, MRVI_SLOW, x, v) == 0, "slow");
  CHECK(mrvi_model_add_particle(m, "f", 1, MRVI_FAST, x, v) == 1, "fast");
  int st = mrvi_model_add_spring(m, MRVI_FAST, 0, 1, "linear", k, 0);
  CHECK(st == MRVI_EMODEL && strstr(mrvi_model_errmsg(m), "s.x"),
        "fast spring on a slow particle: %s", mrvi_model_errmsg(m));
  CHECK(mrvi_model_add_particle(m, "f", 1, MRVI_FAST, x, v) < 0 &&
            strstr(mrvi_model_errmsg(m), "duplicate"),
        "duplicate particle");
  CHECK(mrvi_model_add_coordinate(m, "q", 0.0, MRVI_SLOW, 0, 0) < 0 &&
            strstr(mrvi_model_errmsg(m), "mass"),
        "mass <= 0");
  CHECK(mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "hooke", k, 0) < 0 &&
            strstr(mrvi_model_errmsg(m), "unknown law"),
        "unknown law");
  CHECK(mrvi_model_n_slow(m) == 2 && mrvi_model_n_fast(m) == 2, "partition");
  /* A particle's coordinate names are taken, found through the particle
   * (model.c keeps no coordinate-table entry for them), and a coordinate
   * of its own takes a particle coordinate's name from a later particle;
   * names with a particle's prefix but no such axis stay free. */
  CHECK(mrvi_model_add_coordinate(m, "f.y", 1, MRVI_SLOW, 0, 0) < 0 &&
            strstr(mrvi_model_errmsg(m), "duplicate coordinate name 'f.y'"),
        "a particle's coordinate name: %s", mrvi_model_errmsg(m));
  CHECK(mrvi_model_add_coordinate(m, "f.z", 1, MRVI_SLOW, 0, 0) == 4 &&
            mrvi_model_add_coordinate(m, "f.x.x", 1, MRVI_SLOW, 0, 0) == 5 &&
            mrvi_model_add_coordinate(m, "g.x", 1, MRVI_SLOW, 0, 0) == 6,
        "names free of particle coordinates: %s", mrvi_model_errmsg(m));
  CHECK(mrvi_model_add_particle(m, "g", 1, MRVI_FAST, x, v) < 0 &&
            strstr(mrvi_model_errmsg(m), "duplicate coordinate name 'g.x'"),
        "a particle over a coordinate's name: %s", mrvi_model_errmsg(m));
  CHECK(mrvi_model_add_coordinate(m, "f.z", 1, MRVI_SLOW, 0, 0) < 0,
        "a coordinate's own name twice");
  /* The same through the tables' growth (rehashing the coordinates of
   * their own among particles'). */
  int dup = 0;
  for (int i = 0; i < 200; i++) {
    char name[32];
    snprintf(name, sizeof name, "p%d", i);
    dup += mrvi_model_add_particle(m, name, 1, MRVI_SLOW, x, v) < 0;
    snprintf(name, sizeof name, "c%d", i);
    dup += mrvi_model_add_coordinate(m, name, 1, MRVI_SLOW, 0, 0) < 0;
  }
  for (int i = 0; i < 200; i += 7) {
    char name[32];
    snprintf(name, sizeof name, "p%d.y", i);
    dup += mrvi_model_add_coordinate(m, name, 1, MRVI_SLOW, 0, 0) >= 0;
    snprintf(name, sizeof name, "c%d", i);
    dup += mrvi_model_add_coordinate(m, name, 1, MRVI_SLOW, 0, 0) >= 0;
  }
  CHECK(dup == 0, "duplicates through the tables' growth: %d wrong", dup);
  mrvi_model_free(m);
}

/* A user law registered through the C API is usable by name. */
static void cubic_eval(const double *par, double s, double *phi, double *dphi,
                       double *ddphi) {
  *phi = par[0] * s * s * s;
  *dphi = 3 * par[0] * s * s;
  *ddphi = 6 * par[0] * s;
}
static const char *const cubic_names[] = {"c"};
static int cubic_degree(const double *par) {
  (void)par;
  return 3;
}
static const mrvi_law cubic = {.name = "cubic",
                               .summary = "c s^3",
                               .n_params = 1,
                               .param_names = cubic_names,
                               .eval = cubic_eval,
                               .degree = cubic_degree};

static void user_law(void) {
  CHECK(mrvi_law_register(&cubic) == 0, "register");
  CHECK(mrvi_law_register(&cubic) == MRVI_EINVAL, "no duplicate names");
  mrvi_model *m = mrvi_model_create();
  mrvi_model_add_coordinate(m, "q", 1, MRVI_SLOW, 0.5, 0);
  const int c = 0;
  const double one = 1, par[1] = {2.0};
  CHECK(mrvi_model_add_term(m, MRVI_SLOW, 1, &c, &one, 0, "cubic", par) == 0,
        "term with the user law");
  const double q = 0.5;
  CHECK_NEAR(mrvi_model_potential(m, MRVI_SLOW, &q, NULL, NULL), 0.25, 1e-15,
             "user law energy");
  mrvi_model_free(m);
}

/* The assembly and solve times of the summary are parts of the wall time:
 * measured on every step of a run of 64 steps, partly estimated from
 * sampled steps (and so flagged) on a long run of cheap steps, never above
 * the wall time.  cart_pendulum's first step (the run's factorisations)
 * costs many later ones: scaled to all steps, as the timer did, it made
 * the solve time 14 times the wall time. */
static void timing_bounds(void) {
  char msg[1024];
  mrvi_system *sys = NULL;
  if (mrvi_system_load(test_source_path("systems/cart_pendulum.yaml"), NULL, 0,
                       &sys, msg, sizeof msg) < 0) {
    CHECK(0, "load cart_pendulum: %s", msg);
    return;
  }
  mrvi_summary sum;
  for (int i = 0; i < 2; i++) {
    mrvi_settings s = sys->settings;
    if (i == 1)
      s.t_end = 64 * s.macro_step; /* the measured head only */
    CHECK(mrvi_run(sys->model, &s, NULL, NULL, NULL, &sum) == 0, "run %d", i);
    CHECK(sum.assemble_time >= 0 && sum.solve_time >= 0 &&
              sum.assemble_time + sum.solve_time <= sum.wall_time,
          "cart_pendulum, %ld steps: assemble %g + solve %g <= wall %g",
          sum.steps, sum.assemble_time, sum.solve_time, sum.wall_time);
    if (i == 1)
      CHECK(sum.steps == 64 && !sum.timing_estimated,
            "64 steps: every step measured (%ld, estimated %d)", sum.steps,
            sum.timing_estimated);
  }
  mrvi_system_free(sys);
  /* 1000 explicit FPU steps of a few microseconds (also under ASan):
   * sampled. */
  mrvi_model *m = test_fpu();
  mrvi_settings s = test_settings("fully-explicit", 0.01, 1, 10.0, 1e-9);
  CHECK(mrvi_run(m, &s, NULL, NULL, NULL, &sum) == 0, "FPU run");
  CHECK(sum.timing_estimated == 1, "FPU, 1000 cheap steps: estimated");
  CHECK(sum.assemble_time + sum.solve_time <= sum.wall_time,
        "FPU: assemble %g + solve %g <= wall %g", sum.assemble_time,
        sum.solve_time, sum.wall_time);
  mrvi_model_free(m);
}

int main(void) {
  steps_and_times();
  timing_bounds();
  newton_failure();
  interruption();
  restart();
  restart_carry();
  energy_warning();
  settings_checks();
  builder_checks();
  user_law();
  return test_finish();
}
