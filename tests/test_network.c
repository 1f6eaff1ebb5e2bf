/* Large networks (doc/solver.md, "sweep-cg" and "schur-krylov"): generated
 * planar lattices beyond the dense block limit.  The iterative paths give
 * the general path's trajectory (same equations, same converged solution);
 * their CG and GMRES iteration counts stay at the few that the condition
 * numbers allow; a micro-step matrix with non-positive curvature falls back
 * to a sparse LU with the reason, and the trajectory is still the general
 * path's.  On the shipped unconstrained systems, forced by dense_max = 0,
 * the iterative paths give the general path's trajectory over 100 steps. */
#include "solver/solver.h"
#include "testlib.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Deterministic uniform numbers in [-1, 1). */
static double uniform(unsigned long long *state) {
  *state = *state * 6364136223846793005ULL + 1442695040888963407ULL;
  return (double)(*state >> 11) / 4503599627370496.0 - 1.0;
}

static void append(char **buf, size_t *len, size_t *cap, const char *fmt, ...) {
  for (;;) {
    va_list ap;
    va_start(ap, fmt);
    const int k = vsnprintf(*buf + *len, *cap - *len, fmt, ap);
    va_end(ap);
    if (k >= 0 && *len + (size_t)k < *cap) {
      *len += (size_t)k;
      return;
    }
    *cap = 2 * *cap + (size_t)(k > 0 ? k : 0) + 4096;
    *buf = realloc(*buf, *cap);
    if (!*buf)
      abort();
  }
}

/* The lattice of bench/bench_lattice.c: nx x ny unit masses at spacing 1,
 * even rows slow, odd rows fast; stiff fast springs (k = 2500) along the
 * fast rows, slow springs of stiffness k_slow (1 in the benchmark)
 * elsewhere; perturbed positions and velocities.  Caller frees. */
static char *lattice_k(int nx, int ny, const char *k_slow) {
  size_t len = 0, cap = 0;
  char *b = NULL;
  unsigned long long seed = 12345;
  append(&b, &len, &cap, "name: lattice\ndimension: 2\nparticles:\n");
  for (int j = 0; j < ny; j++)
    for (int i = 0; i < nx; i++) {
      const double dx = 0.05 * uniform(&seed), dy = 0.05 * uniform(&seed);
      const double vx = 0.1 * uniform(&seed), vy = 0.1 * uniform(&seed);
      append(&b, &len, &cap,
             "  - {name: p%d_%d, mass: 1, rate: %s, position: [%.6f, %.6f], "
             "velocity: [%.6f, %.6f]}\n",
             i, j, j % 2 ? "fast" : "slow", i + dx, j + dy, vx, vy);
    }
  append(&b, &len, &cap, "springs:\n");
  for (int j = 0; j < ny; j++)
    for (int i = 0; i < nx; i++) {
      if (i + 1 < nx)
        append(&b, &len, &cap,
               "  - {between: [p%d_%d, p%d_%d], law: linear, stiffness: %s, "
               "rest_length: 1, potential: %s}\n",
               i, j, i + 1, j, j % 2 ? "2500" : k_slow,
               j % 2 ? "fast" : "slow");
      if (j + 1 < ny)
        append(&b, &len, &cap,
               "  - {between: [p%d_%d, p%d_%d], law: linear, stiffness: %s, "
               "rest_length: 1, potential: slow}\n",
               i, j, i, j + 1, k_slow);
    }
  return b;
}

static char *lattice(int nx, int ny) { return lattice_k(nx, ny, "1"); }

/* n fast unit masses on a line (1-D), joined by weak springs (k = 100) and
 * each held by an anchor spring of stiffness +k or -k alternately (W has
 * curvature -k in half of the coordinates), plus one slow mass coupled to
 * the first by a soft spring.  At dt^2 k / 4 > 1 the micro-step matrix
 * M/dt + (dt/4) hess W is indefinite. */
static char *inverted_anchors(int n, double k) {
  size_t len = 0, cap = 0;
  char *b = NULL;
  append(
      &b, &len, &cap,
      "name: anchors\ndimension: 1\nparticles:\n"
      "  - {name: s, mass: 1, rate: slow, position: [9], velocity: [0.1]}\n");
  for (int i = 0; i < n; i++)
    append(&b, &len, &cap,
           "  - {name: c%d, mass: 1, rate: fast, position: [%g], "
           "velocity: [%g]}\n",
           i, 10.0 + 0.5 * i, i == n / 2 ? 1e-3 : 0.0);
  append(&b, &len, &cap,
         "springs:\n  - {between: [s, c0], law: linear, stiffness: 1, "
         "rest_length: 0.9}\n");
  for (int i = 0; i < n; i++) {
    append(&b, &len, &cap,
           "  - {between: [c%d], anchor: [0], law: linear, stiffness: %g, "
           "rest_length: initial, potential: fast}\n",
           i, i % 2 ? k : -k);
    if (i + 1 < n)
      append(&b, &len, &cap,
             "  - {between: [c%d, c%d], law: linear, stiffness: 100, "
             "rest_length: 0.5, potential: fast}\n",
             i, i + 1);
  }
  return b;
}

static mrvi_system *load_text(const char *text, const char *const *set,
                              int n_set) {
  mrvi_system *sys = NULL;
  char msg[512];
  if (mrvi_system_load_string(text, "network", set, n_set, &sys, msg,
                              sizeof msg) < 0) {
    CHECK(0, "load: %s", msg);
    return NULL;
  }
  return sys;
}

typedef struct trajectory {
  int n, nmicro, steps, ok;
  double *q, *p, *micro; /* (steps + 1) x n, ..., steps x nmicro */
  int max_iter;
  char path[32];
  mrvi_krylov_stats ks;
} trajectory;

static void run(const mrvi_system *sys, int steps, trajectory *t) {
  const mrvi_model *m = sys->model;
  memset(t, 0, sizeof *t);
  t->n = mrvi_model_n(m);
  t->nmicro = sys->settings.micro_steps * m->n_fast;
  t->steps = steps;
  t->q = calloc((size_t)(steps + 1) * (size_t)t->n, sizeof(double));
  t->p = calloc((size_t)(steps + 1) * (size_t)t->n, sizeof(double));
  t->micro = calloc((size_t)steps * (size_t)t->nmicro, sizeof(double));
  mrvi_integrator *it = NULL;
  char msg[512];
  if (mrvi_integrator_create(m, &sys->settings, &it, msg, sizeof msg) < 0) {
    CHECK(0, "create: %s", msg);
    return;
  }
  snprintf(t->path, sizeof t->path, "%s", mrvi_integrator_solver_path(it));
  const size_t n = (size_t)t->n, nm = (size_t)t->nmicro;
  memcpy(t->q, mrvi_integrator_q(it), n * sizeof(double));
  memcpy(t->p, mrvi_integrator_p(it), n * sizeof(double));
  for (int k = 0; k < steps; k++) {
    if (mrvi_integrator_step(it) < 0) {
      CHECK(0, "%s step %d: %s", t->path, k + 1, mrvi_integrator_errmsg(it));
      mrvi_integrator_free(it);
      return;
    }
    memcpy(t->q + (size_t)(k + 1) * n, mrvi_integrator_q(it),
           n * sizeof(double));
    memcpy(t->p + (size_t)(k + 1) * n, mrvi_integrator_p(it),
           n * sizeof(double));
    memcpy(t->micro + (size_t)k * nm, mrvi_integrator_micro_q(it),
           nm * sizeof(double));
    if (mrvi_integrator_last_iterations(it) > t->max_iter)
      t->max_iter = mrvi_integrator_last_iterations(it);
  }
  mrvi_integrator_krylov_stats(it, &t->ks);
  mrvi_integrator_free(it);
  t->ok = 1;
}

static void release(trajectory *t) {
  free(t->q);
  free(t->p);
  free(t->micro);
}

/* max |a - b| / max |a| over q, p and the micro nodes (each separately). */
static double rel_diff(const trajectory *a, const trajectory *b) {
  const double *x[3] = {a->q, a->p, a->micro}, *y[3] = {b->q, b->p, b->micro};
  const size_t len[3] = {(size_t)(a->steps + 1) * (size_t)a->n,
                         (size_t)(a->steps + 1) * (size_t)a->n,
                         (size_t)a->steps * (size_t)a->nmicro};
  double worst = 0.0;
  for (int w = 0; w < 3; w++) {
    double d = 0.0, s = 0.0;
    for (size_t i = 0; i < len[w]; i++) {
      d = fmax(d, fabs(x[w][i] - y[w][i]));
      s = fmax(s, fabs(x[w][i]));
    }
    if (s > 0.0)
      worst = fmax(worst, d / s);
  }
  return worst;
}

/* Whether sys's run resumed at node k of t (its q_k, p_k) reaches t's last
 * node bit for bit: a step depends on (q_k, p_k) alone.  *it: the resumed
 * integrator (the caller frees it; NULL if it could not be created). */
static int resumes_bitwise(const mrvi_system *sys, const trajectory *t, int k,
                           mrvi_integrator **it) {
  char msg[512];
  const size_t n = (size_t)t->n;
  *it = NULL;
  int same = mrvi_integrator_create(sys->model, &sys->settings, it, msg,
                                    sizeof msg) == 0 &&
             mrvi_integrator_resume_state(*it, k, t->q + (size_t)k * n,
                                          t->p + (size_t)k * n) == 0;
  for (int j = k; same && j < t->steps; j++)
    same = mrvi_integrator_step(*it) == 0;
  const size_t last = (size_t)t->steps * n;
  return same &&
         !memcmp(mrvi_integrator_q(*it), t->q + last, n * sizeof(double)) &&
         !memcmp(mrvi_integrator_p(*it), t->p + last, n * sizeof(double));
}

/* Settings overrides: scheme, p, dT, tolerance, solver. */
typedef struct overrides {
  char text[5][80];
  const char *ptr[5];
} overrides;

static const char *const *set(overrides *o, const char *scheme, int p,
                              double dT, double tol, const char *solver) {
  snprintf(o->text[0], sizeof o->text[0], "integrator.scheme=%s", scheme);
  snprintf(o->text[1], sizeof o->text[1], "integrator.micro_steps=%d", p);
  snprintf(o->text[2], sizeof o->text[2], "integrator.macro_step=%g", dT);
  snprintf(o->text[3], sizeof o->text[3], "integrator.newton.tolerance=%g",
           tol);
  snprintf(o->text[4], sizeof o->text[4], "integrator.solver=%s", solver);
  for (int i = 0; i < 5; i++)
    o->ptr[i] = o->text[i];
  return o->ptr;
}

/* The trajectory of `scheme` on `text` by the iterative path (auto)
 * against the general path, tolerance 1e-12: asserts the paths (general,
 * want) and the agreement to 1e-10; *b receives the iterative run (its
 * stats; released here).  outer_max >= 0 sets that tuning constant of the
 * iterative run (schur-krylov's outer iteration; 0: off).  Returns
 * whether both runs completed. */
static int agree_outer(const char *text, const char *scheme, int p, double dT,
                       int steps, const char *want, int outer_max,
                       trajectory *b) {
  overrides og, oa;
  mrvi_system *sg =
      load_text(text, set(&og, scheme, p, dT, 1e-12, "general"), 5);
  mrvi_system *sa = load_text(text, set(&oa, scheme, p, dT, 1e-12, "auto"), 5);
  if (sa && outer_max >= 0)
    sa->settings.tuning.outer_max = outer_max;
  int ok = 0;
  memset(b, 0, sizeof *b);
  if (sg && sa) {
    trajectory a;
    run(sg, steps, &a);
    run(sa, steps, b);
    if ((ok = a.ok && b->ok)) {
      const double d = rel_diff(&a, b);
      CHECK(d <= 1e-10, "%s p=%d: %s vs general: %.2e", scheme, p, b->path, d);
      CHECK(strcmp(a.path, "general") == 0 && strcmp(b->path, want) == 0,
            "%s: paths %s, %s", scheme, a.path, b->path);
      printf("%-24s p=%d %-13s vs general %.2e  outer %ld steps (%ld left "
             "to Newton), %.2f sweeps each  CG %.2f/solve (max %d)  "
             "GMRES %.2f/solve (max %d)\n",
             scheme, p, b->path, d, b->ks.outer_steps, b->ks.outer_fallbacks,
             (double)b->ks.outer_sweeps / fmax(1.0, (double)b->ks.outer_steps),
             b->ks.cg_solves
                 ? (double)b->ks.cg_iterations / (double)b->ks.cg_solves
                 : 0.0,
             b->ks.cg_max,
             b->ks.gmres_solves
                 ? (double)b->ks.gmres_iterations / (double)b->ks.gmres_solves
                 : 0.0,
             b->ks.gmres_max);
    }
    release(&a);
    release(b);
  }
  mrvi_system_free(sg);
  mrvi_system_free(sa);
  return ok;
}

static int agree(const char *text, const char *scheme, int p, double dT,
                 int steps, const char *want, trajectory *b) {
  return agree_outer(text, scheme, p, dT, steps, want, -1, b);
}

/* A 10 x 8 lattice (80 slow and 80 fast coordinates, beyond the dense
 * limit 64): every scheme with an implicit fast rule on its iterative path
 * against the general path, tolerance 1e-12, 100 steps (test_steps), p in
 * {1, 5}.  Both solutions meet ||R|| <= 1e-12 with a Jacobian M/dt +
 * O(dt K), so they differ by about 1e-12 dt / M relative to q and p; 1e-10
 * leaves room for 100 steps of growth (doc/solver.md).  The schur-krylov
 * schemes run twice: with the outer iteration (solver/outer.c), which at p = 5
 * solves every step (its row chord contracts by about (omega dt)^2/4 = 0.024
 * per update at dt = 0.002, omega = 98), and without it (outer_max 0: Newton
 * with GMRES and CG in every step).  At p = 1 (dt = 0.01, (omega dt)^2/4 = 0.24
 * > chord_jacobi_max 0.1) it is not used: Newton in every step. */
static void test_agree(void) {
  static const char *const schemes[] = {"explicit-slow", "midpoint-midpoint",
                                        "trapezoidal-midpoint",
                                        "trapezoidal-trapezoidal"};
  static const char *const want[] = {"sweep-cg", "schur-krylov", "schur-krylov",
                                     "schur-krylov"};
  char *text = lattice(10, 8);
  const int steps = (int)test_steps(100);
  mrvi_system *one = load_text(text, NULL, 0);
  if (one)
    CHECK(one->model->n_slow == 80 && one->model->n_fast == 80,
          "lattice: %d slow, %d fast", one->model->n_slow, one->model->n_fast);
  mrvi_system_free(one);
  for (int sc = 0; sc < 4; sc++)
    for (int pi = 0; pi < 2; pi++) {
      const int p = pi ? 5 : 1;
      trajectory b;
      /* (explicit-slow at p = 5: the Jacobi chord in every row, row 0's
       * too, no CG; at p = 1 its bound fails and Newton's CG runs) */
      if (agree_outer(text, schemes[sc], p, 0.01, steps, want[sc],
                      sc > 0 ? 0 : -1, &b))
        CHECK((b.ks.cg_solves > 0) == (sc > 0 || p == 1) &&
                  b.ks.fallbacks == 0 && b.ks.outer_steps == 0,
              "%s p=%d: %ld CG solves, %ld fallbacks (%s), %ld outer steps",
              schemes[sc], p, b.ks.cg_solves, b.ks.fallbacks,
              b.ks.fallback_reason, b.ks.outer_steps);
      if (sc > 0 && agree(text, schemes[sc], p, 0.01, steps, want[sc], &b))
        CHECK(p == 1 ? b.ks.outer_steps + b.ks.outer_fallbacks == 0
                     : b.ks.outer_steps == steps && b.ks.outer_fallbacks == 0 &&
                           b.ks.cg_solves == 0,
              "%s p=%d: %ld outer steps, %ld left to Newton, %ld CG solves",
              schemes[sc], p, b.ks.outer_steps, b.ks.outer_fallbacks,
              b.ks.cg_solves);
    }
  free(text);
}

/* Iteration counts at the benchmark's step sizes (dT = 0.01, p = 10) on a
 * 30 x 30 lattice (1800 coordinates).  With unit masses the micro-step
 * block is J = (I + (dt^2/4) H)/dt, H the fast-fast Hessian with spectrum
 * in [-w^2, w^2] (w = omega_max, power iteration at q0), so the Jacobi-
 * preconditioned J has condition number kappa <= ((1 + a)/(1 - a))^2,
 * a = (w dt)^2/4, and CG reduces the A-norm error by 2 rho^k, rho =
 * (sqrt(kappa) - 1)/(sqrt(kappa) + 1); in the inf-norm of the residual that
 * is 2 sqrt(kappa n) rho^k.  The tightest stopping rule (1e-13 relative,
 * schur-krylov) then needs at most k = log(1e-13 / (2 sqrt(kappa n))) /
 * log(rho) iterations per block solve.  GMRES works on S diag(A_ss)^-1 =
 * I + E with ||E|| = O((dT omega_slow)^2 + p dt^2 K_sf^2 ...) << 1 and
 * contracts by ||E|| per iteration: 1e-11 in at most 6 iterations as long
 * as ||E|| <= 0.015.  Newton: at most 2 updates per step on schur-krylov;
 * on sweep-cg (explicit-slow) exactly 1 in row 0 of a step (the later rows
 * take Jacobi chord updates: bound below).  Newton's residual
 * after one update is quadratic in the predictor's row residual r0.  Rows
 * m >= 1 started from the last interval's implicit force held fixed (now
 * extrapolated where the chord runs, which lowers r0), r0 the
 * change of that force over one micro step, and one update reaches the
 * tolerance (benchmark lattice n = 312: r0 <= 2e-2, after the update
 * <= 1.2e-10 against 1e-9).  Row 0 has no last force (a step depends on
 * (q_k, p_k) alone); its implicit points are evaluated once at the estimate
 * without implicit force, which leaves a = (omega dt)^2/4 = 0.0024 times
 * that whole force as r0: 1.9e-4 (median, n = 312), below the other rows',
 * so it too takes one update.  Started from no implicit force (r0 = 1e-1),
 * one update left 3e-9 and nearly every macro step took 2. */
static void test_iterations(void) {
  char *text = lattice(30, 30);
  static const char *const schemes[] = {"explicit-slow", "midpoint-midpoint"};
  for (int sc = 0; sc < 2; sc++) {
    overrides o;
    mrvi_system *s =
        load_text(text, set(&o, schemes[sc], 10, 0.01, 1e-9, "auto"), 5);
    if (!s)
      continue;
    /* (schur-krylov's Newton: its outer iteration off, test_outer) */
    s->settings.tuning.outer_max = 0;
    mrvi_step st;
    mrvi_predictor *pr = NULL;
    mrvi_step_init(&st, s->model, &s->settings);
    mrvi_predictor_create(s->model, &st, &pr);
    const double w = mrvi_predictor_omega_max(pr);
    mrvi_predictor_free(pr);
    mrvi_step_free(&st);
    const double dt = 0.001, a = 0.25 * (w * dt) * (w * dt);
    const double kappa = pow((1.0 + a) / (1.0 - a), 2.0);
    const double rho = (sqrt(kappa) - 1.0) / (sqrt(kappa) + 1.0);
    const int n = s->model->n_fast;
    const int bound =
        (int)ceil(log(1e-13 / (2.0 * sqrt(kappa * n))) / log(rho));
    trajectory t;
    run(s, 10, &t);
    if (t.ok) {
      const mrvi_krylov_stats *k = &t.ks;
      CHECK(sc == 0 ||
                (k->cg_solves > 0 && k->cg_max <= bound && k->cg_max <= 30),
            "%s (%s): CG at most %d iterations per block solve (bound %d "
            "from omega_max %.1f)",
            schemes[sc], t.path, k->cg_max, bound, w);
      CHECK(sc == 0 || (k->gmres_solves > 0 && k->gmres_max <= 6),
            "%s: GMRES at most %d iterations per solve", schemes[sc],
            k->gmres_max);
      /* sweep-cg: Jacobi chord updates in every row (row 0's too: its
       * bound holds at the first iterate), each contracting the residual
       * by at most the Jacobi iteration's spectral radius 2a/(1 - a) (the
       * off-diagonal part of (dt^2/4) H is at most 2a in norm, the
       * diagonal of J at least (1 - a)/dt), from a predictor residual at
       * most 2e-2 (the held force's, above; the extrapolation only lowers
       * it); no CG.  schur-krylov: 2 Newton updates. */
      const double rj = 2.0 * a / (1.0 - a);
      const int chord_bound = (int)ceil(log(1e-9 / 2e-2) / log(rj));
      const int nbound = sc == 0 ? chord_bound : 2;
      CHECK(t.max_iter <= nbound && k->fallbacks == 0,
            "%s: %d updates at most (bound %d), %ld fallbacks", schemes[sc],
            t.max_iter, nbound, k->fallbacks);
      CHECK(sc == 1 || k->cg_solves == 0,
            "%s: %ld CG solves in 10 steps (the chord from row 0 on)",
            schemes[sc], k->cg_solves);
      printf("%s 30x30 (%s): omega_max %.1f, CG max %d (bound %d), %.2f "
             "per solve; GMRES max %d; Newton max %d\n",
             schemes[sc], t.path, w, k->cg_max, bound,
             (double)k->cg_iterations / fmax(1.0, (double)k->cg_solves),
             k->gmres_max, t.max_iter);
    }
    release(&t);
    mrvi_system_free(s);
  }
  free(text);
}

/* Non-positive curvature: 80 fast masses, half of them on anchor springs
 * of stiffness -2500, at dt = 0.05 (dT = 0.1, p = 2): dt^2 k / 4 = 1.56,
 * so the micro-step matrix has diagonal entries (1 - 1.56)/dt < 0 and CG
 * meets p^T J p <= 0 at once.  The solve falls back to a sparse LU with
 * the reason, and the trajectory is still the general path's (to the 1e-10
 * of test_agree).  Two steps: the inverted springs amplify the motion
 * about tenfold per micro step, and the masses would soon cross. */
static void test_fallback(void) {
  char *text = inverted_anchors(80, 2500.0);
  static const char *const schemes[] = {"explicit-slow", "midpoint-midpoint"};
  static const char *const want[] = {"sweep-cg", "schur-krylov"};
  for (int sc = 0; sc < 2; sc++) {
    overrides og, oa;
    mrvi_system *sg =
        load_text(text, set(&og, schemes[sc], 2, 0.1, 1e-12, "general"), 5);
    mrvi_system *sa =
        load_text(text, set(&oa, schemes[sc], 2, 0.1, 1e-12, "auto"), 5);
    if (sg && sa) {
      trajectory a, b;
      run(sg, 2, &a);
      run(sa, 2, &b);
      if (a.ok && b.ok) {
        const double d = rel_diff(&a, &b);
        CHECK(strcmp(b.path, want[sc]) == 0, "%s: path %s", schemes[sc],
              b.path);
        CHECK(d <= 1e-10, "%s with fallback vs general: %.2e", schemes[sc], d);
        CHECK(b.ks.fallbacks > 0 &&
                  strstr(b.ks.fallback_reason, "non-positive curvature") &&
                  strstr(b.ks.fallback_reason, "sparse LU"),
              "%s: %ld fallbacks: %s", schemes[sc], b.ks.fallbacks,
              b.ks.fallback_reason);
        printf("%s inverted anchors: %ld fallbacks (%s), vs general %.2e\n",
               schemes[sc], b.ks.fallbacks, b.ks.fallback_reason, d);
      }
      release(&a);
      release(&b);
      /* The run summary carries the count and the reason. */
      mrvi_summary sum;
      mrvi_settings s = sa->settings;
      s.t_end = 2 * s.macro_step;
      mrvi_run(sa->model, &s, NULL, NULL, NULL, &sum);
      CHECK(sum.status == MRVI_OK && sum.krylov.fallbacks > 0 &&
                strstr(sum.krylov.fallback_reason, "curvature"),
            "%s summary: status %d, %ld fallbacks", schemes[sc], sum.status,
            sum.krylov.fallbacks);
    }
    mrvi_system_free(sg);
    mrvi_system_free(sa);
  }
  free(text);
}

/* Path choice: the large lattice takes the iterative paths under auto and
 * structured (with reasons naming CG / GMRES), general when asked. */
static void test_choice(void) {
  char *text = lattice(10, 8);
  static const char *const schemes[] = {"explicit-slow", "midpoint-midpoint",
                                        "fully-explicit"};
  static const char *const want[] = {"sweep-cg", "schur-krylov", "explicit"};
  static const char *const word[] = {"CG", "GMRES", "explicit"};
  for (int sc = 0; sc < 3; sc++)
    for (int so = 0; so < 3; so++) {
      static const char *const solvers[] = {"auto", "structured", "general"};
      overrides o;
      mrvi_system *s =
          load_text(text, set(&o, schemes[sc], 5, 0.01, 1e-9, solvers[so]), 5);
      if (!s)
        continue;
      char why[400] = "";
      const char *path =
          mrvi_solver_path(s->model, &s->settings, why, sizeof why);
      const char *expect = so == 2 ? "general" : want[sc];
      CHECK(path && strcmp(path, expect) == 0 &&
                strstr(why, so == 2 ? "requested" : word[sc]),
            "%s, solver %s: %s: %s", schemes[sc], solvers[so],
            path ? path : "(none)", why);
      mrvi_system_free(s);
    }
  free(text);
}

/* Stiff slow springs (k = 400) at dT = 0.05: dT^2 k / M = 1, so the Schur
 * complement S = -M/dT + O(dT K) is far from its diagonal and GMRES needs
 * more iterations than schur-krylov keeps sweeps of (6): the final sweep
 * of a Newton update is then computed afresh instead of combined from the
 * kept ones.  The trajectory is still the general path's to 1e-10 (as in
 * test_agree). */
static void test_many_gmres(void) {
  char *text = lattice_k(10, 8, "400");
  trajectory b;
  if (agree(text, "midpoint-midpoint", 5, 0.05, 4, "schur-krylov", &b))
    CHECK(b.ks.gmres_max > 6 && b.ks.fallbacks == 0,
          "GMRES max %d (want > 6), %ld fallbacks", b.ks.gmres_max,
          b.ks.fallbacks);
  free(text);
}

/* The Jacobi chord of sweep-cg (doc/solver.md, "sweep-cg") on the 10 x 8
 * lattice (fast springs k = 2500 in chains along x): with unit masses its
 * Gershgorin bound is rho = (dt k / 2) / (1/dt + dt k / 2) = 0.043 at dt =
 * 0.006 (dT = 0.03, p = 5) and 0.111 at dt = 0.01 (dT = 0.05).  Below the
 * default bound 0.1 every update is a chord update, row 0's first too (its
 * bound from the elements' entries at its first iterate: no CG solve);
 * above it Newton in every row (a CG solve each); with the
 * bound raised to 0.5 and 8 iterations allowed, the chord (contracting by
 * about 0.11 from a residual of about 1e-2) cannot reach 1e-12 in the 4
 * updates it may take, so Newton takes over in those rows.  Every case
 * gives the general path's trajectory to 1e-10 (as test_agree). */
static void test_chord(void) {
  char *text = lattice(10, 8);
  const struct {
    double dT, bound;
    int max_iter, chord; /* chord: expected in every row */
  } cases[] = {{0.03, 0.1, 20, 1}, {0.05, 0.1, 20, 0}, {0.05, 0.5, 8, 0}};
  const int steps = 10, p = 5;
  for (int c = 0; c < 3; c++) {
    overrides og, oa;
    mrvi_system *sg = load_text(
        text, set(&og, "explicit-slow", p, cases[c].dT, 1e-12, "general"), 5);
    mrvi_system *sa = load_text(
        text, set(&oa, "explicit-slow", p, cases[c].dT, 1e-12, "auto"), 5);
    if (sg && sa) {
      sa->settings.tuning.chord_jacobi_max = cases[c].bound;
      sa->settings.newton_max_iter = cases[c].max_iter;
      /* (the chord's history within the step alone; across steps, with
       * its resume: test_run's restart_carry, test_resume) */
      sa->settings.tuning.chord_carry = 0;
      trajectory a, b;
      run(sg, steps, &a);
      run(sa, steps, &b);
      if (a.ok && b.ok) {
        const double d = rel_diff(&a, &b);
        const long cg = b.ks.cg_solves;
        CHECK(d <= 1e-10, "chord case %d: vs general %.2e", c, d);
        CHECK(cases[c].chord ? cg == 0 : cg > 2 * steps,
              "chord case %d (dT %g, bound %g): %ld CG solves in %d steps "
              "of %d rows",
              c, cases[c].dT, cases[c].bound, cg, steps, p);
        /* Without tuning.chord_carry a step depends on (q_k, p_k) alone
         * (the chord's history holds rows of the current step): resumed at
         * node 5, the run continues bit for bit. */
        mrvi_integrator *it = NULL;
        CHECK(resumes_bitwise(sa, &b, 5, &it),
              "chord case %d: resumed at node 5, not bit for bit", c);
        mrvi_integrator_free(it);
        printf("chord case %d: dT %g bound %g: %ld CG solves, %d updates "
               "at most, vs general %.2e\n",
               c, cases[c].dT, cases[c].bound, cg, b.max_iter, d);
      }
      release(&a);
      release(&b);
    }
    mrvi_system_free(sg);
    mrvi_system_free(sa);
  }
  free(text);
}

/* The 10 x 8 lattice at dT = 0.03, p = 5 (the chord in every row),
 * tolerance 1e-12, by the general path (s[0]) and twice by sweep-cg (s[1],
 * s[2]): whether all three loaded. */
static int chord_systems(const char *text, overrides o[3], mrvi_system *s[3]) {
  for (int k = 0; k < 3; k++)
    s[k] = load_text(
        text,
        set(&o[k], "explicit-slow", 5, 0.03, 1e-12, k ? "auto" : "general"), 5);
  return s[0] && s[1] && s[2];
}

/* tuning.chord_carry (solver/sweep.c): each step's first rows extrapolate
 * the implicit force from the last rows of the step before.  On the 10 x 8
 * lattice at dT = 0.03, p = 5 (the chord in every row), tolerance 1e-12:
 * the general path's trajectory within 1e-10, as without it, and fewer
 * gradients of W than without it (the first rows' predictors are quartic,
 * not held fixed, linear, ...). */
static void test_chord_carry(void) {
  char *text = lattice(10, 8);
  overrides og, oa, oc;
  mrvi_system *sg =
      load_text(text, set(&og, "explicit-slow", 5, 0.03, 1e-12, "general"), 5);
  mrvi_system *sa =
      load_text(text, set(&oa, "explicit-slow", 5, 0.03, 1e-12, "auto"), 5);
  mrvi_system *sc =
      load_text(text, set(&oc, "explicit-slow", 5, 0.03, 1e-12, "auto"), 5);
  if (sg && sa && sc) {
    sa->settings.tuning.chord_carry = 0;
    sc->settings.tuning.chord_carry = 1;
    trajectory a, b, c;
    run(sg, 10, &a);
    run(sa, 10, &b);
    run(sc, 10, &c);
    if (a.ok && b.ok && c.ok) {
      const double d = rel_diff(&a, &c);
      CHECK(!strcmp(c.path, "sweep-cg"), "chord carry: path %s", c.path);
      CHECK(d <= 1e-10, "chord carry: vs general %.2e", d);
      CHECK(c.ks.sweep_evals_w < b.ks.sweep_evals_w,
            "chord carry: %ld gradients of W, %ld without", c.ks.sweep_evals_w,
            b.ks.sweep_evals_w);
      printf("chord carry: %ld gradients of W (%ld without), vs general "
             "%.2e\n",
             c.ks.sweep_evals_w, b.ks.sweep_evals_w, d);
    }
    release(&a);
    release(&b);
    release(&c);
  }
  mrvi_system_free(sg);
  mrvi_system_free(sa);
  mrvi_system_free(sc);
  free(text);
}

/* tuning.chord_linear (solver/sweep.c): each chord row's first plain
 * update keeps the springs' Hessians and its next two updates take the
 * residual linearised there (Hessian-vector products); the rows end on
 * exact residuals alone.  On the 10 x 8 lattice at dT = 0.03, p = 5 (the
 * chord in every row), tolerance 1e-12, without chord_carry: the general
 * path's trajectory within 1e-10 (as without it), products taken, fewer
 * gradients of W than without it, and resumed at node 5 the run continues
 * bit for bit (the pattern is fixed within each row). */
static void test_chord_linear(void) {
  char *text = lattice(10, 8);
  overrides o[3];
  mrvi_system *sy[3];
  trajectory tr[3];
  const int ok = chord_systems(text, o, sy);
  for (int k = 1; ok && k < 3; k++) {
    sy[k]->settings.tuning.chord_carry = 0;
    sy[k]->settings.tuning.chord_linear = k == 2 ? 2 : 0;
  }
  for (int k = 0; ok && k < 3; k++)
    run(sy[k], 10, &tr[k]);
  const trajectory *a = &tr[0], *b = &tr[1], *c = &tr[2];
  if (ok && a->ok && b->ok && c->ok) {
    const double d = rel_diff(a, c), d0 = rel_diff(a, b);
    CHECK(!strcmp(c->path, "sweep-cg"), "chord linear: path %s", c->path);
    CHECK(d <= 1e-10, "chord linear: vs general %.2e", d);
    CHECK(b->ks.sweep_products_w == 0 && c->ks.sweep_products_w > 0 &&
              c->ks.sweep_evals_w < b->ks.sweep_evals_w,
          "chord linear: %ld gradients of W and %ld products, %ld and %ld "
          "without",
          c->ks.sweep_evals_w, c->ks.sweep_products_w, b->ks.sweep_evals_w,
          b->ks.sweep_products_w);
    mrvi_integrator *it = NULL;
    CHECK(resumes_bitwise(sy[2], c, 5, &it),
          "chord linear: resumed at node 5, not bit for bit");
    mrvi_integrator_free(it);
    printf("chord linear: %ld gradients of W and %ld products (%ld "
           "gradients without), vs general %.2e (%.2e without)\n",
           c->ks.sweep_evals_w, c->ks.sweep_products_w, b->ks.sweep_evals_w, d,
           d0);
  }
  for (int k = 0; ok && k < 3; k++)
    release(&tr[k]);
  for (int k = 0; k < 3; k++)
    mrvi_system_free(sy[k]);
  free(text);
}

/* Three runs of explicit-slow on the lattice text (p = 5, dT = 0.02,
 * tolerance 1e-9, 6 steps, parts of 16 coordinates), run k with its
 * settings set by cfg(settings, k, a, b); 1 where all three completed. */
typedef void (*variant_fn)(mrvi_settings *s, int k, int a, int b);
static int run_three(const char *text, trajectory t[3], variant_fn cfg, int a,
                     int b) {
  memset(t, 0, 3 * sizeof *t);
  int ok = 1;
  for (int k = 0; k < 3; k++) {
    overrides o;
    mrvi_system *sys =
        load_text(text, set(&o, "explicit-slow", 5, 0.02, 1e-9, "auto"), 5);
    t[k].ok = 0;
    if (sys) {
      sys->settings.tuning.thread_chunk = 16;
      cfg(&sys->settings, k, a, b);
      run(sys, 6, &t[k]);
    }
    ok = ok && t[k].ok;
    mrvi_system_free(sys);
  }
  return ok;
}

/* test_chord_threads's runs: 1, 2, 3 threads. */
static void chord_variant(mrvi_settings *s, int k, int carry, int lin) {
  s->threads = k + 1;
  s->tuning.chord_carry = carry;
  s->tuning.chord_linear = lin;
}

/* test_storage's runs: the absolute criterion on 1 thread, the scaled one
 * on 1 and on 2. */
static void storage_variant(mrvi_settings *s, int k, int a, int b) {
  (void)a, (void)b;
  s->newton_criterion =
      k == 0 ? MRVI_CRITERION_ABSOLUTE : MRVI_CRITERION_SCALED;
  s->threads = k == 2 ? 2 : 1;
}

/* sweep-cg's chord on threads (doc/performance/threads.md, "Threads"): the 40 x
 * 20 perturbed lattice (800 fast coordinates, moving everywhere) by
 * explicit-slow with the chord's pass and the row ends in parts of 16
 * coordinates, on 1, 2 and 3 threads: the trajectory and the sum of the
 * chord's relaxation ratios (mrvi_krylov_stats.sweep_chord_sum, whose last
 * bits follow the order of the sums over the parts: the trajectory does
 * not show them) the same bit for bit.  Summing the parts in another
 * order on more than one thread (an OpenMP reduction) fails here.  With
 * carry, the same with tuning.chord_carry (the history kept per entry);
 * with lin, with tuning.chord_linear (the linearised updates' products in
 * the parts). */
static void test_chord_threads(int carry, int lin) {
  char *text = lattice(40, 20);
  trajectory t[3];
  const int ok = run_three(text, t, chord_variant, carry, lin);
  if (ok) {
    CHECK(!strcmp(t[0].path, "sweep-cg"), "chord threads: path %s", t[0].path);
    CHECK(t[0].ks.sweep_chord_sum != 0.0, "chord threads: no relaxation");
    printf("chord threads, chord_carry %d, chord_linear %d:\n", carry, lin);
    CHECK(!lin || t[0].ks.sweep_products_w > 0,
          "chord threads: no linearised update");
    const size_t n = (size_t)(t[0].steps + 1) * (size_t)t[0].n;
    for (int k = 1; k < 3; k++) {
      CHECK(!memcmp(t[0].q, t[k].q, n * sizeof(double)) &&
                !memcmp(t[0].p, t[k].p, n * sizeof(double)),
            "chord threads: %d threads, trajectory not 1's bit for bit", k + 1);
      CHECK(!memcmp(&t[0].ks.sweep_chord_sum, &t[k].ks.sweep_chord_sum,
                    sizeof(double)),
            "chord threads: %d threads, chord sums %.17g against 1's %.17g",
            k + 1, t[k].ks.sweep_chord_sum, t[0].ks.sweep_chord_sum);
    }
    printf("chord threads: sum of relaxation ratios %.17g on 1, 2, 3 "
           "threads\n",
           t[0].ks.sweep_chord_sum);
  }
  for (int k = 0; k < 3; k++)
    release(&t[k]);
  free(text);
}

/* sweep-cg's storage (solver/sweep.c): under the absolute criterion with
 * equal fast masses the sweep keeps two entries of 1/M^f and M^f (its
 * passes read entry 0) and no Newton weights; the scaled criterion keeps
 * every entry and the weights 1/M^f.  With unit masses both criteria are
 * the same arithmetic (every weight 1, the CG tolerance's smallest mass 1),
 * so the 40 x 20 lattice by explicit-slow (the fresh chord of row 0, whose
 * Hessian diagonal and off-diagonal sums share the chord's arrays, the
 * extrapolated predictors, end_predict) gives the same trajectory bit for
 * bit either way on 1 thread, and the scaled one on 2 threads (the
 * chord's parts of 16, fresh_part, start_parts, a row's end deferred to
 * the next row's first update, end_parts) the absolute criterion's on 1
 * again: a pass that read an entry the compact layout does not keep, or
 * an array shared while it is live, would not.  (The scaled criterion's
 * general chord pass once stored the first update's implicit force over
 * the last row's converged one, which the deferred row end had not yet
 * moved into the history: 4e-10 apart here on 2 threads.)  The absolute
 * criterion on 2 threads: test_chord_threads. */
static void test_storage(void) {
  char *text = lattice(40, 20);
  trajectory t[3];
  const int ok = run_three(text, t, storage_variant, 0, 0);
  if (ok) {
    CHECK(!strcmp(t[0].path, "sweep-cg"), "storage: path %s", t[0].path);
    const size_t n = (size_t)(t[0].steps + 1) * (size_t)t[0].n;
    const size_t nm = (size_t)t[0].steps * (size_t)t[0].nmicro;
    for (int k = 1; k < 3; k++)
      CHECK(!memcmp(t[0].q, t[k].q, n * sizeof(double)) &&
                !memcmp(t[0].p, t[k].p, n * sizeof(double)) &&
                !memcmp(t[0].micro, t[k].micro, nm * sizeof(double)),
            "storage: the scaled criterion on %d threads, trajectory not "
            "the absolute criterion's on 1 bit for bit (max rel. diff %.3g)",
            k, rel_diff(&t[0], &t[k]));
    printf("storage: explicit-slow, the scaled criterion on 1 and 2 "
           "threads: the absolute criterion's trajectory on 1 thread bit for "
           "bit\n");
  }
  for (int k = 0; k < 3; k++)
    release(&t[k]);
  free(text);
}

/* schur-krylov's outer iteration (solver/outer.c, doc/solver.md) on the
 * 10 x 8 lattice at dT = 0.01, p = 5 (dt = 0.002: its fast rows' chord
 * contracts by about (omega dt)^2/4 = 0.024 per update, omega = 98), 10
 * steps, for midpoint-midpoint and trapezoidal-midpoint:
 *  - at tolerance 1e-9 every step by the outer iteration in at most 4
 *    sweeps (measured 2 to 3: the slow update contracts the slow residual
 *    by 1e-2 or more per sweep, and the last sweep only confirms the
 *    rows), no Newton, no CG;
 *  - resumed at node 5, the run continues bit for bit (a step depends on
 *    (q_k, p_k) alone);
 *  - forced to fail (outer_rate 1e-3: no update contracts that much), every
 *    step is left to Newton from the predictor, so the trajectory is the
 *    one with the outer iteration off bit for bit, and counted. */
static void test_outer(void) {
  char *text = lattice(10, 8);
  static const char *const schemes[] = {"midpoint-midpoint",
                                        "trapezoidal-midpoint"};
  const int steps = 10;
  for (int sc = 0; sc < 2; sc++) {
    overrides o;
    mrvi_system *s =
        load_text(text, set(&o, schemes[sc], 5, 0.01, 1e-9, "auto"), 5);
    if (!s)
      continue;
    trajectory a, b, c;
    run(s, steps, &a);
    s->settings.tuning.outer_rate = 1e-3;
    run(s, steps, &b);
    s->settings.tuning.outer_rate = 0.5;
    s->settings.tuning.outer_max = 0;
    run(s, steps, &c);
    s->settings.tuning.outer_max = 12;
    if (a.ok && b.ok && c.ok) {
      CHECK(a.ks.outer_steps == steps && a.ks.outer_fallbacks == 0 &&
                a.ks.cg_solves == 0 && a.max_iter <= 4,
            "%s: %ld outer steps, %ld left to Newton, %ld CG solves, %d "
            "sweeps at most",
            schemes[sc], a.ks.outer_steps, a.ks.outer_fallbacks, a.ks.cg_solves,
            a.max_iter);
      const double d = rel_diff(&c, &a);
      CHECK(d <= 1e-8, "%s: outer vs Newton %.2e", schemes[sc], d);
      const size_t n = (size_t)b.n, nq = (size_t)(steps + 1) * n;
      CHECK(b.ks.outer_steps == 0 && b.ks.outer_fallbacks == steps &&
                !memcmp(b.q, c.q, nq * sizeof(double)) &&
                !memcmp(b.p, c.p, nq * sizeof(double)),
            "%s forced to fail: %ld outer steps, %ld left to Newton, "
            "trajectory %s Newton's",
            schemes[sc], b.ks.outer_steps, b.ks.outer_fallbacks,
            memcmp(b.q, c.q, nq * sizeof(double)) ? "not" : "bitwise");
      mrvi_integrator *it = NULL;
      const int same = resumes_bitwise(s, &a, 5, &it);
      CHECK(same, "%s: resumed at node 5, not bit for bit", schemes[sc]);
      /* Newton is built on the first step left to it (or Jacobian solve),
       * not at creation, where the outer iteration is the first choice. */
      CHECK(!a.ks.newton_built && b.ks.newton_built && c.ks.newton_built,
            "%s: Newton built %d with no step left to it, %d after "
            "fallbacks, %d without the outer iteration",
            schemes[sc], a.ks.newton_built, b.ks.newton_built,
            c.ks.newton_built);
      mrvi_krylov_stats ks;
      const int nj = mrvi_integrator_jacobian_size(it);
      double *rhs = calloc((size_t)nj, sizeof *rhs),
             *sol = calloc((size_t)nj, sizeof *sol);
      if (same && rhs && sol) {
        rhs[0] = 1.0;
        mrvi_integrator_krylov_stats(it, &ks);
        const int before = ks.newton_built;
        const int js = mrvi_integrator_jacobian_solve(it, 1, rhs, sol);
        mrvi_integrator_krylov_stats(it, &ks);
        CHECK(!before && js == 0 && ks.newton_built && isfinite(sol[0]) &&
                  sol[0] != 0.0,
              "%s: Jacobian solve after outer steps: status %d (%s), Newton "
              "built %d -> %d",
              schemes[sc], js, js ? mrvi_integrator_errmsg(it) : "", before,
              ks.newton_built);
      }
      free(rhs);
      free(sol);
      mrvi_integrator_free(it);
      printf("%s outer: %.2f sweeps per step (max %d), %.2f gradient "
             "evaluations per micro step, vs Newton %.2e\n",
             schemes[sc], (double)a.ks.outer_sweeps / (double)a.ks.outer_steps,
             a.max_iter, (double)a.ks.outer_evals / (double)(steps * 5), d);
    }
    release(&a);
    release(&b);
    release(&c);
    mrvi_system_free(s);
  }
  free(text);
}

/* The iterative paths forced (integrator.tuning.dense_max = 0: every block
 * beyond the dense limit) on every shipped unconstrained system, every
 * scheme, p in {1, 5}: sweep becomes sweep-cg and schur schur-krylov, and
 * the trajectory is the general path's to 1e-10 over 100 macro steps
 * (test_steps: 10 under the sanitizers), tolerance 1e-12.  The FPU (and
 * its optimal control problem's) at the paper's dT = 0.03 (0.3 is for the
 * midpoint rules; trapezoidal-trapezoidal needs 0.03, arXiv 2406.12991 §6,
 * and the explicit rules at p = 1 below 2/omega), as in test_solver. */
static void test_forced_shipped(void) {
  static const char *const files[] = {"systems/fpu.yaml",
                                      "systems/oscillator.yaml",
                                      "systems/spring_ring.yaml",
                                      "systems/tutorial_spring.yaml",
                                      "systems/lattice.yaml",
                                      "systems/ocp_fpu.yaml",
                                      "systems/ocp_double_integrator.yaml"};
  const char *const *schemes = mrvi_scheme_names();
  const int steps = (int)test_steps(100);
  int n_cg = 0, n_krylov = 0;
  double worst = 0.0;
  for (size_t f = 0; f < sizeof files / sizeof *files; f++)
    for (int sc = 0; schemes[sc]; sc++)
      for (int pi = 0; pi < 2; pi++) {
        const int p = pi ? 5 : 1;
        char ov[6][96];
        const char *ovp[6];
        snprintf(ov[0], sizeof ov[0], "integrator.scheme=%s", schemes[sc]);
        snprintf(ov[1], sizeof ov[1], "integrator.micro_steps=%d", p);
        snprintf(ov[2], sizeof ov[2], "integrator.newton.tolerance=1e-12");
        snprintf(ov[3], sizeof ov[3], "integrator.solver=general");
        snprintf(ov[4], sizeof ov[4], "integrator.tuning.dense_max=0");
        snprintf(ov[5], sizeof ov[5], "integrator.macro_step=0.03");
        const int fpu = strstr(files[f], "fpu.yaml") != NULL;
        for (int i = 0; i < 6; i++)
          ovp[i] = ov[i];
        /* the general run: overrides 0-3 (and the FPU's dT, moved) */
        const char *og[5] = {ovp[0], ovp[1], ovp[2], ovp[3], ovp[5]};
        mrvi_system *sg = NULL, *sa = NULL;
        char msg[512];
        const char *path = test_source_path(files[f]);
        if (mrvi_system_load(path, og, fpu ? 5 : 4, &sg, msg, sizeof msg) < 0) {
          CHECK(0, "load %s: %s", files[f], msg);
          continue;
        }
        snprintf(ov[3], sizeof ov[3], "integrator.solver=auto");
        if (mrvi_system_load(path, ovp, fpu ? 6 : 5, &sa, msg, sizeof msg) <
            0) {
          CHECK(0, "load %s: %s", files[f], msg);
          mrvi_system_free(sg);
          continue;
        }
        CHECK(mrvi_model_constraint_rows(sa->model) == 0, "%s unconstrained",
              files[f]);
        /* the path at the default limits, and its iterative counterpart */
        mrvi_settings sd = sa->settings;
        sd.tuning.dense_max = sg->settings.tuning.dense_max;
        const char *dense = mrvi_solver_path(sa->model, &sd, NULL, 0);
        const char *want = !dense                        ? "(none)"
                           : strcmp(dense, "sweep") == 0 ? "sweep-cg"
                           : strcmp(dense, "schur") == 0 ? "schur-krylov"
                                                         : dense;
        trajectory a, b;
        run(sg, steps, &a);
        run(sa, steps, &b);
        CHECK(a.ok && b.ok, "%s %s p=%d: runs completed", files[f], schemes[sc],
              p);
        if (a.ok && b.ok) {
          const double d = rel_diff(&a, &b);
          worst = fmax(worst, d);
          CHECK(strcmp(a.path, "general") == 0 && strcmp(b.path, want) == 0,
                "%s %s p=%d: paths %s, %s (want %s)", files[f], schemes[sc], p,
                a.path, b.path, want);
          CHECK(d <= 1e-10, "%s %s p=%d: %s forced vs general: %.2e", files[f],
                schemes[sc], p, b.path, d);
          n_cg += strcmp(b.path, "sweep-cg") == 0;
          n_krylov += strcmp(b.path, "schur-krylov") == 0;
        }
        release(&a);
        release(&b);
        mrvi_system_free(sg);
        mrvi_system_free(sa);
      }
  printf("shipped systems, dense_max 0: %d sweep-cg and %d schur-krylov runs "
         "over %d steps, largest difference from general %.2e\n",
         n_cg, n_krylov, steps, worst);
  CHECK(n_cg >= 12 && n_krylov >= 42,
        "iterative paths forced: %d sweep-cg, %d schur-krylov runs", n_cg,
        n_krylov);
}

/* omega_max at creation (mrvi_predictor_omega_max): where Gershgorin's
 * bound settles the paths' tests of it (dt omega <= 1/2, (omega dt)^2/4 <=
 * chord_jacobi_max) it is that bound, which must lie above the power
 * iteration's estimate (a Rayleigh quotient: at most the largest
 * eigenvalue) and, on the lattice, near it (1.06 measured); elsewhere it is
 * the power iteration's, bit for bit.  The lattice's springs are
 * stretched and sheared (tension terms off the diagonal), the anchors'
 * W indefinite. */
static void test_omega_bound(void) {
  char *lat = lattice(12, 10), *anc = inverted_anchors(20, 50.0);
  const struct {
    const char *text, *scheme;
    int p;
    double dT;
    int bound; /* 1: the bound settles the tests, 0: it does not */
  } cs[] = {{lat, "midpoint-midpoint", 10, 0.01, 1},
            {lat, "trapezoidal-midpoint", 2, 0.1, 0},
            {anc, "midpoint-midpoint", 10, 0.01, 1},
            {anc, "midpoint-midpoint", 1, 0.2, 0}};
  for (size_t i = 0; i < sizeof cs / sizeof *cs; i++) {
    overrides o;
    mrvi_system *s = load_text(
        cs[i].text, set(&o, cs[i].scheme, cs[i].p, cs[i].dT, 1e-9, "auto"), 5);
    if (!s)
      continue;
    mrvi_step st;
    mrvi_predictor *pr = NULL;
    mrvi_step_init(&st, s->model, &s->settings);
    mrvi_predictor_create(s->model, &st, &pr);
    const double w = mrvi_predictor_omega_max(pr),
                 wp = mrvi_predictor_omega_power(pr), dt = st.dt;
    if (cs[i].bound)
      CHECK(w >= wp * (1.0 - 1e-9) && w <= 1.5 * wp && dt * w <= 0.5 &&
                0.25 * (w * dt) * (w * dt) <= st.tuning.chord_jacobi_max,
            "case %zu: omega_max %.6g a bound that settles the tests, "
            "power iteration %.6g",
            i, w, wp);
    else
      CHECK(w == wp && dt * wp > 0.5,
            "case %zu: omega_max %.6g the power iteration's %.6g", i, w, wp);
    printf("omega_max case %zu: %.6g (power iteration %.6g, dt omega %.3g)\n",
           i, w, wp, dt * w);
    mrvi_predictor_free(pr);
    mrvi_step_free(&st);
    mrvi_system_free(s);
  }
  free(lat);
  free(anc);
}

int main(void) {
  test_omega_bound();
  test_chord();
  test_chord_carry();
  test_chord_threads(0, 0);
  test_chord_threads(1, 0);
  test_chord_threads(1, 2);
  test_chord_linear();
  test_storage();
  test_choice();
  test_agree();
  test_iterations();
  test_fallback();
  test_many_gmres();
  test_outer();
  test_forced_shipped();
  return test_finish();
}
