/* Constrained models on structured paths (doc/solver.md, "schur-bordered";
 * doc/constraints.md, "Momentum projection"): the schur-bordered path
 * against the general path (both constraint forms), and the two forms
 * against each other, on every shipped constrained system, scheme and p in
 * {1, 5} over 100 macro steps, on
 * generated pendulum chains where the automatic choice takes it and where
 * it is forced by bordered_max; the path chosen and its reason; the
 * sparse Gram matrix of the projection against the dense one; the choice
 * between general and schur-bordered by the cost estimates. */
#include "integrator/integrator.h"
#include "models.h"
#include "testlib.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Macro steps of each comparison: 100 (10 under AddressSanitizer). */
#define N_STEPS ((int)test_steps(100))

static const char *const systems[] = {
    "systems/cart_pendulum.yaml",   "systems/pendulum_chain.yaml",
    "systems/spring_ring_rod.yaml", "systems/triatomic.yaml",
    "systems/tutorial_rod.yaml",    "systems/rigid_pendulum.yaml",
    "systems/heavy_top.yaml",       "systems/flexible_pendulum.yaml",
    "systems/spacecraft.yaml",      "systems/robot_arm_payload.yaml",
    "systems/slider_crank.yaml",    "systems/ocp_reorient.yaml",
    "systems/ocp_gantry_crane.yaml"};
#define N_SYSTEMS ((int)(sizeof systems / sizeof systems[0]))

static mrvi_system *load(const char *rel, const char *scheme, int p,
                         const char *form, const char *solver) {
  char ov[11][96];
  const char *ovp[11];
  snprintf(ov[0], sizeof ov[0], "integrator.scheme=%s", scheme);
  snprintf(ov[1], sizeof ov[1], "integrator.micro_steps=%d", p);
  snprintf(ov[2], sizeof ov[2], "integrator.newton.tolerance=1e-12");
  snprintf(ov[3], sizeof ov[3], "integrator.solver=%s", solver);
  snprintf(ov[4], sizeof ov[4], "integrator.constraints.form=%s", form);
  snprintf(ov[5], sizeof ov[5], "integrator.constraints.tolerance=1e-12");
  /* schur-bordered forced on every system (the default limits keep it
   * from larger blocks) */
  snprintf(ov[6], sizeof ov[6], "integrator.tuning.bordered_max=100000");
  snprintf(ov[7], sizeof ov[7], "integrator.tuning.bordered_node_max=100000");
  /* Both paths from the same predictor: the joint sweep starts
   * schur-bordered elsewhere, its steps then agree with general's to the
   * tolerance (8.8e-13 after spring_ring_rod's first step), which that
   * system amplifies past this comparison's 1e-10 within 20 steps;
   * test_torsion tests the sweep. */
  snprintf(ov[8], sizeof ov[8], "integrator.tuning.predict_joints=0");
  /* The pendulum chain's stiff attachments at p = 1 need dT below
   * 2/omega for the explicit fast rules (as in test_solver). */
  int n_ov = 9;
  if (strstr(rel, "pendulum_chain"))
    snprintf(ov[n_ov++], sizeof ov[0], "integrator.macro_step=0.002");
  /* The optimal control problems start at rest (and the crane in its
   * equilibrium): without controls nothing would move and the comparison
   * would be empty.  An initial velocity consistent with the constraints
   * (the load across its rod; the satellite's spin) sets them in motion. */
  if (strstr(rel, "ocp_gantry_crane"))
    snprintf(ov[n_ov++], sizeof ov[0], "particles.1.velocity=[0.5, 0]");
  if (strstr(rel, "ocp_reorient"))
    snprintf(ov[n_ov++], sizeof ov[0],
             "bodies.0.angular_velocity=[0.3, -0.5, 0.8]");
  for (int i = 0; i < 11; i++)
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
  int n, ok;
  double *q, *p; /* (N_STEPS + 1) x n */
  char path[32];
  long factorisations, updates; /* of the run (Newton updates) */
} run_out;

/* Run m with s for `steps` macro steps; the macro q and p. */
static void run(const mrvi_model *m, const mrvi_settings *s, int steps,
                run_out *o) {
  mrvi_integrator *it = NULL;
  char msg[512];
  o->ok = 0;
  o->n = mrvi_model_n(m);
  o->q = calloc((size_t)(steps + 1) * (size_t)o->n, sizeof *o->q);
  o->p = calloc((size_t)(steps + 1) * (size_t)o->n, sizeof *o->p);
  if (!o->q || !o->p || mrvi_integrator_create(m, s, &it, msg, sizeof msg) < 0)
    return;
  snprintf(o->path, sizeof o->path, "%s", mrvi_integrator_solver_path(it));
  const size_t n = (size_t)o->n;
  memcpy(o->q, mrvi_integrator_q(it), n * sizeof(double));
  memcpy(o->p, mrvi_integrator_p(it), n * sizeof(double));
  for (int k = 0; k < steps; k++) {
    if (mrvi_integrator_step(it) < 0) {
      mrvi_integrator_free(it);
      return;
    }
    memcpy(o->q + (size_t)(k + 1) * n, mrvi_integrator_q(it),
           n * sizeof(double));
    memcpy(o->p + (size_t)(k + 1) * n, mrvi_integrator_p(it),
           n * sizeof(double));
    o->updates += mrvi_integrator_last_iterations(it);
  }
  o->factorisations = mrvi_integrator_factorisations(it);
  mrvi_integrator_free(it);
  o->ok = 1;
}

static void run_free(run_out *o) {
  free(o->q);
  free(o->p);
  o->q = o->p = NULL;
}

/* max |p| over the run: the comparison below is relative to it. */
static double max_momentum(const run_out *a, int steps) {
  double s = 0.0;
  for (size_t i = 0; i < (size_t)(steps + 1) * (size_t)a->n; i++)
    s = fmax(s, fabs(a->p[i]));
  return s;
}

/* max |a - b| / max |a| over the run, q and p separately. */
static double rel_diff(const run_out *a, const run_out *b, int steps) {
  double worst = 0.0;
  for (int w = 0; w < 2; w++) {
    const double *x = w ? a->p : a->q, *y = w ? b->p : b->q;
    double d = 0.0, s = 0.0;
    for (size_t i = 0; i < (size_t)(steps + 1) * (size_t)a->n; i++) {
      d = fmax(d, fabs(x[i] - y[i]));
      s = fmax(s, fabs(x[i]));
    }
    if (s > 0)
      worst = fmax(worst, d / s);
  }
  return worst;
}

/* m run with sa and with sg (general) for `steps` macro steps: both
 * complete and agree to 1e-10 relative. */
static void agree(const mrvi_model *m, const mrvi_settings *sa,
                  const mrvi_settings *sg, int steps, const char *what) {
  run_out a = {0}, g = {0};
  run(m, sa, steps, &a);
  run(m, sg, steps, &g);
  CHECK(a.ok && g.ok, "%s: runs completed", what);
  if (a.ok && g.ok) {
    const double d = rel_diff(&g, &a, steps);
    CHECK(d <= 1e-10, "%s: %s vs general: %.2e", what, a.path, d);
  }
  run_free(&a);
  run_free(&g);
}

/* schur-bordered (auto, multiplier form) against general in both forms,
 * every shipped constrained system, scheme and p in {1, 5}. */
/* Under AddressSanitizer (about 20× slower here) each system is compared
 * with one scheme, a different one per system in turn, both p and both
 * forms: every system and every scheme still run through the path, in a
 * twentieth of the time; the full product runs in the plain build. */
#if defined(__SANITIZE_ADDRESS__)
#define ONE_SCHEME_PER_SYSTEM 1
#else
#define ONE_SCHEME_PER_SYSTEM 0
#endif

static void test_shipped(void) {
  const char *const *schemes = mrvi_scheme_names();
  int compared = 0, failed_runs = 0, n_schemes = 0, forms = 0;
  double worst = 0.0, worst_forms = 0.0;
  while (schemes[n_schemes])
    n_schemes++;
  for (int sy = 0; sy < N_SYSTEMS; sy++)
    for (int sc = 0; schemes[sc]; sc++)
      for (int pi = 0; pi < 2; pi++) {
        if (ONE_SCHEME_PER_SYSTEM && sc != sy % n_schemes)
          continue;
        const int p = pi ? 5 : 1;
        mrvi_system *sa =
            load(systems[sy], schemes[sc], p, "multipliers", "structured");
        if (!sa)
          continue;
        CHECK(mrvi_model_constraint_rows(sa->model) > 0, "%s is constrained",
              systems[sy]);
        run_out a = {0}, g[2] = {{0}, {0}};
        run(sa->model, &sa->settings, N_STEPS, &a);
        for (int f = 0; f < 2; f++) {
          mrvi_system *sg = load(systems[sy], schemes[sc], p,
                                 f ? "null-space" : "multipliers", "general");
          if (sg)
            run(sg->model, &sg->settings, N_STEPS, &g[f]);
          mrvi_system_free(sg);
        }
        /* Both paths fail together (a scheme beyond its stability on a
         * system), or neither. */
        for (int f = 0; f < 2; f++) {
          if (f == 0)
            CHECK(a.ok == g[0].ok,
                  "%s %s p=%d: schur-bordered ok %d, general "
                  "ok %d",
                  systems[sy], schemes[sc], p, a.ok, g[0].ok);
          if (a.ok && g[f].ok) {
            CHECK(strcmp(a.path, "schur-bordered") == 0, "%s %s: path %s",
                  systems[sy], schemes[sc], a.path);
            CHECK(strcmp(g[f].path, "general") == 0, "general requested");
            /* the system moves (a trajectory at rest compares nothing) */
            CHECK(max_momentum(&g[f], N_STEPS) > 1e-3,
                  "%s %s p=%d: max |p| %.2e", systems[sy], schemes[sc], p,
                  max_momentum(&g[f], N_STEPS));
            const double d = rel_diff(&g[f], &a, N_STEPS);
            worst = fmax(worst, d);
            CHECK(d <= 1e-10,
                  "%s %s p=%d: schur-bordered vs general (%s): "
                  "%.2e",
                  systems[sy], schemes[sc], p, f ? "null-space" : "multipliers",
                  d);
            compared++;
          }
        }
        /* The two constraint forms on the general path directly: the same
         * trajectory to 1e-10 on every shipped system (doc/testing.md). */
        if (g[0].ok && g[1].ok) {
          const double d = rel_diff(&g[0], &g[1], N_STEPS);
          worst_forms = fmax(worst_forms, d);
          CHECK(d <= 1e-10, "%s %s p=%d: null-space vs multipliers: %.2e",
                systems[sy], schemes[sc], p, d);
          forms++;
        }
        failed_runs += !a.ok;
        run_free(&a);
        run_free(&g[0]);
        run_free(&g[1]);
        mrvi_system_free(sa);
      }
  /* 13 systems x 5 schemes x 2 p x 2 forms, less the few runs beyond a
   * scheme's stability (256 of 260 in the plain build). */
  CHECK(compared >= (ONE_SCHEME_PER_SYSTEM ? 36 : 240),
        "compared %d runs (%d not completed)", compared, failed_runs);
  printf("shipped systems: %d comparisons, largest difference %.2e; the "
         "forms compared %d times, largest difference %.2e\n",
         compared, worst, forms, worst_forms);
  CHECK(forms >= (ONE_SCHEME_PER_SYSTEM ? 18 : 120),
        "forms compared on %d runs", forms);
}

/* The pendulum chain of systems/pendulum_chain.yaml grown to n links in
 * 2-D: slow links (mass 2) on rods from the pivot, each carrying a fast
 * light mass (0.05) on a stiff slow spring, the light masses joined by
 * stiff fast springs, gravity; straight at 45 degrees, at rest.  The rods
 * are added in the given order (reverse: the last first). */
static mrvi_model *chain(int n, int reverse) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double gr[2] = {0, -9.81}, c = sqrt(0.5), v0[2] = {0, 0};
  mrvi_model_set_gravity(m, gr);
  char name[16];
  for (int i = 0; i < n; i++) {
    const double x[2] = {(i + 1) * c, -(i + 1) * c};
    snprintf(name, sizeof name, "h%d", i + 1);
    mrvi_model_add_particle(m, name, 2.0, MRVI_SLOW, x, v0);
  }
  for (int i = 0; i < n; i++) {
    /* a small initial velocity, so that the projection has work */
    const double x[2] = {(i + 1) * c, -(i + 1) * c - 0.1},
                 v[2] = {0.3 * sin(i), 0.2 * cos(i)};
    snprintf(name, sizeof name, "l%d", i + 1);
    mrvi_model_add_particle(m, name, 0.05, MRVI_FAST, x, v);
  }
  const double k[1] = {2000};
  for (int i = 0; i < n; i++)
    mrvi_model_add_spring(m, MRVI_SLOW, i, n + i, "linear", k, 0.1);
  for (int i = 0; i + 1 < n; i++)
    mrvi_model_add_spring(m, MRVI_FAST, n + i, n + i + 1, "linear", k, NAN);
  const double pivot[2] = {0, 0};
  for (int r = 0; r < n; r++) {
    const int i = reverse ? n - 1 - r : r;
    if (i == 0)
      mrvi_model_add_distance_anchor(m, 0, pivot, NAN);
    else
      mrvi_model_add_distance(m, i - 1, i, NAN);
  }
  mrvi_model_project_velocities(m, NULL);
  return m;
}

/* The rod chain of bench/bench_chain.c ("rods"): chain()'s links, each
 * link's particles, springs and rod added in turn (another numbering of
 * the same step: the dense LU's degree ordering, solver/newton.c, breaks
 * ties by it). */
static mrvi_model *chain_interleaved(int n) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double gr[2] = {0, -9.81}, c = sqrt(0.5), v0[2] = {0, 0};
  const double k[1] = {2000}, pivot[2] = {0, 0};
  mrvi_model_set_gravity(m, gr);
  char name[16];
  for (int i = 0; i < n; i++) {
    const double x[2] = {(i + 1) * c, -(i + 1) * c}, l[2] = {x[0], x[1] - 0.1};
    snprintf(name, sizeof name, "h%d", i + 1);
    mrvi_model_add_particle(m, name, 2.0, MRVI_SLOW, x, v0);
    snprintf(name, sizeof name, "l%d", i + 1);
    mrvi_model_add_particle(m, name, 0.05, MRVI_FAST, l, v0);
    mrvi_model_add_spring(m, MRVI_SLOW, 2 * i, 2 * i + 1, "linear", k, 0.1);
    if (i > 0)
      mrvi_model_add_spring(m, MRVI_FAST, 2 * i - 1, 2 * i + 1, "linear", k,
                            1.0);
    if (i == 0)
      mrvi_model_add_distance_anchor(m, 0, pivot, 1.0);
    else
      mrvi_model_add_distance(m, 2 * i - 2, 2 * i, 1.0);
  }
  return m;
}

static mrvi_settings chain_settings(int p, const char *solver) {
  mrvi_settings s = test_settings("midpoint-midpoint", 0.01, p, 1.0, 1e-12);
  s.constraint_tol = 1e-12;
  s.solver =
      strcmp(solver, "general") == 0 ? MRVI_SOLVER_GENERAL : MRVI_SOLVER_AUTO;
  return s;
}

/* n rigid bars (2-D bodies, length 1, mass 2, slow) on revolute joints
 * along a line 45 degrees from the downward vertical, the first to the
 * ground at the origin, each with a light fast mass on a slow spring to its
 * lower end, the light masses joined by fast springs (bench_chain's rigid
 * chain); ring: a joint from the last bar's lower end to the first bar
 * closes a loop. */
static mrvi_model *bars(int n, int ring) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double g[2] = {0.0, -9.81}, e[2] = {sqrt(0.5), -sqrt(0.5)};
  mrvi_model_set_gravity(m, g);
  int prev_b = -1, prev_l = -1, first = -1;
  for (int i = 0; i < n; i++) {
    const double h[2] = {(i + 1) * e[0], (i + 1) * e[1]};
    const double x[2] = {h[0] - 0.5 * e[0], h[1] - 0.5 * e[1]};
    const double R[4] = {e[0], -e[1], e[1], e[0]}, J[1] = {2.0 / 12.0};
    const double v[2] = {0.3 * sin(i), 0.2 * cos(i)}, w[1] = {0.4 * cos(i)};
    const double l[2] = {h[0], h[1] - 0.1}, k[1] = {2000.0};
    const double pivot[2] = {i * e[0], i * e[1]};
    char name[16];
    snprintf(name, sizeof name, "b%d", i);
    const int b =
        mrvi_model_add_body(m, name, 2, MRVI_SLOW, 2.0, J, x, R, v, w);
    CHECK(b >= 0 &&
              mrvi_model_add_joint(m, "revolute", b, prev_b, pivot, NULL) >= 0,
          "bar %d", i);
    snprintf(name, sizeof name, "l%d", i);
    const int li = mrvi_model_add_particle(m, name, 0.05, MRVI_FAST, l, v);
    mrvi_end eb = {-1, b, {0.5, 0, 0}}, el = {li, -1, {0, 0, 0}};
    CHECK(li >= 0 &&
              mrvi_model_add_end_spring(m, MRVI_SLOW, &eb, &el, NULL, "linear",
                                        k, 0.1) >= 0 &&
              (prev_l < 0 || mrvi_model_add_spring(m, MRVI_FAST, prev_l, li,
                                                   "linear", k, 1.0) >= 0),
          "light mass %d", i);
    first = first < 0 ? b : first;
    prev_b = b, prev_l = li;
  }
  if (ring) {
    const double end[2] = {n * e[0], n * e[1]};
    CHECK(mrvi_model_add_joint(m, "revolute", first, prev_b, end, NULL) >= 0,
          "closing joint");
  }
  mrvi_model_project_velocities(m, NULL);
  return m;
}

/* A binary tree of 7 slow particles (mass 2) on rods, the root on a rod to
 * the origin, each carrying a light fast mass on a slow spring, the light
 * masses joined by fast springs along the tree's edges. */
static mrvi_model *rod_tree(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double gr[2] = {0, -9.81}, k[1] = {2000}, pivot[2] = {0, 0};
  mrvi_model_set_gravity(m, gr);
  enum { N = 7 };
  double x[N][2] = {{0, -1}};
  char name[16];
  for (int i = 0; i < N; i++) {
    if (i > 0) { /* children below their parent, left and right */
      const int u = (i - 1) / 2, depth = i < 3 ? 1 : 2;
      x[i][0] = x[u][0] + (i % 2 ? -1.0 : 1.0) / depth;
      x[i][1] = x[u][1] - 0.5;
    }
    const double v[2] = {0.3 * sin(i), 0.2 * cos(i)};
    snprintf(name, sizeof name, "h%d", i);
    mrvi_model_add_particle(m, name, 2.0, MRVI_SLOW, x[i], v);
  }
  for (int i = 0; i < N; i++) {
    const double l[2] = {x[i][0], x[i][1] - 0.1}, v[2] = {0.1 * i, 0};
    snprintf(name, sizeof name, "l%d", i);
    mrvi_model_add_particle(m, name, 0.05, MRVI_FAST, l, v);
    mrvi_model_add_spring(m, MRVI_SLOW, i, N + i, "linear", k, 0.1);
    if (i > 0) {
      mrvi_model_add_spring(m, MRVI_FAST, N + (i - 1) / 2, N + i, "linear", k,
                            NAN);
      mrvi_model_add_distance(m, (i - 1) / 2, i, NAN);
    } else {
      mrvi_model_add_distance_anchor(m, 0, pivot, NAN);
    }
  }
  mrvi_model_project_velocities(m, NULL);
  return m;
}

/* The chain elimination of schur-bordered (solver/chain.c) against the
 * general path over N_STEPS macro steps (tolerances 1e-12), at p = 1 and
 * 5: a rod chain, a bar chain and a tree of rods (c = 0, 1, 4) forced onto
 * it (integrator.solver structured, bordered_max 0) and the bar chain by the
 * automatic choice (c = 2: beyond bordered_max, its check names it); a
 * closed loop of bars (c = 3) keeps general, and chain_block_max 0 turns it
 * off. */
static void test_chain_elimination(void) {
  for (int c = 0; c < 5; c++) {
    mrvi_model *m = c == 0   ? chain(8, 1)
                    : c == 4 ? rod_tree()
                             : bars(c == 3 ? 6 : 8, c == 3);
    for (int pi = 0; pi < 2; pi++) {
      const int p = pi ? 5 : 1;
      mrvi_settings sa = chain_settings(p, "auto"),
                    sg = chain_settings(p, "general");
      char msg[200], why[512] = "";
      if (c == 0 || c == 1 || c == 4) {
        sa.solver = MRVI_SOLVER_STRUCTURED;
        CHECK(mrvi_settings_set_tuning(&sa, "bordered_max", 0, msg,
                                       sizeof msg) == 0,
              "%s", msg);
      }
      const char *path = mrvi_solver_path(m, &sa, why, sizeof why);
      const int want = c != 3;
      CHECK(path && strcmp(path, want ? "schur-bordered" : "general") == 0 &&
                (strstr(why, "chain elimination") != NULL) == want,
            "case %d p = %d: path %s (%s)", c, p, path ? path : "none", why);
      if (c == 2) { /* off: general */
        mrvi_settings so = sa;
        CHECK(mrvi_settings_set_tuning(&so, "chain_block_max", 0, msg,
                                       sizeof msg) == 0,
              "%s", msg);
        path = mrvi_solver_path(m, &so, why, sizeof why);
        CHECK(path && strcmp(path, "general") == 0, "chain_block_max 0: %s",
              path ? path : "none");
      }
      if (c == 3)
        continue;
      char what[32];
      snprintf(what, sizeof what, "case %d p=%d", c, p);
      agree(m, &sa, &sg, N_STEPS, what);
    }
    mrvi_model_free(m);
  }
}

/* The chain elimination's transposed solve (mrvi_chain_solve_transpose,
 * the optimal-control adjoint's; test_bordered_transpose_solve): on the
 * rod chain, the bar chain and the tree of rods of test_chain_elimination
 * forced onto it (bordered_max 0), p in {1, 5}, J^T y = c to 1e-12
 * relative and c.J^-1 b = (J^-T c).b, on the chain elimination; three
 * right-hand sides in one pass (mrvi_chain_solve_transpose_n) each equal
 * to its single solve. */
static void test_chain_transpose(void) {
  for (int c = 0; c < 3; c++) {
    mrvi_model *m = c == 0 ? chain(8, 1) : c == 1 ? bars(8, 0) : rod_tree();
    for (int p = 1; p <= 5; p += 4) {
      mrvi_settings s = chain_settings(p, "auto");
      char msg[300];
      CHECK(mrvi_settings_set_tuning(&s, "bordered_max", 0, msg, sizeof msg) ==
                0,
            "%s", msg);
      double res, dual, multi;
      int on_chain;
      const int rc = test_bordered_transpose_solve(
          m, &s, &res, &dual, &on_chain, &multi, msg, sizeof msg);
      const char *name = c == 0 ? "rods" : c == 1 ? "bars" : "tree";
      printf("chain transpose: %s p=%d: |c - J^T y| %.2e, c.J^-1 b - J^-T c.b "
             "%.2e (relative), three together %.2e\n",
             name, p, res, dual, multi);
      CHECK(rc == 0 && res <= 1e-12 && dual <= 1e-12 && on_chain == 1 &&
                multi == 0.0,
            "%s p=%d: status %d (%s), |c - J^T y| %.3e, c.J^-1 b - J^-T c.b "
            "%.3e (relative), on the chain elimination %d, three together "
            "%.3e",
            name, p, rc, msg, res, dual, on_chain, multi);
    }
    mrvi_model_free(m);
  }
}

/* The chain elimination's refactorisation by cost (tuning keep_by_cost):
 * the rod chain and the bar chain of 8 links at p = 1 and 5 with the
 * policy on, off (the reuse_rate rule alone) and the refactorisation
 * forced at every update (reuse_rate 0: full Newton) agree with general to
 * 1e-10 over the steps; forced, every update factorises; kept, fewer; by
 * cost, no more factorisations than by the rate rule, and on the bars
 * fewer (measured: one per step against two, the kept factors' slower
 * contraction near the target taken on instead). */
static void test_chain_refactor(void) {
  for (int c = 0; c < 2; c++) {
    mrvi_model *m = c ? bars(8, 0) : chain(8, 1);
    for (int pi = 0; pi < 2; pi++) {
      const int p = pi ? 5 : 1;
      mrvi_settings sg = chain_settings(p, "general");
      run_out o[3] = {{0}}, g = {0};
      run(m, &sg, N_STEPS, &g);
      CHECK(g.ok, "case %d p = %d: general completed", c, p);
      for (int v = 0; v < 3; v++) {
        mrvi_settings s = chain_settings(p, "auto");
        char msg[200];
        s.solver = MRVI_SOLVER_STRUCTURED;
        CHECK(mrvi_settings_set_tuning(&s, "bordered_max", 0, msg,
                                       sizeof msg) == 0 &&
                  mrvi_settings_set_tuning(&s, "keep_by_cost", v != 1, msg,
                                           sizeof msg) == 0 &&
                  mrvi_settings_set_tuning(&s, "reuse_rate", v == 2 ? 0 : 0.1,
                                           msg, sizeof msg) == 0,
              "%s", msg);
        run(m, &s, N_STEPS, &o[v]);
        CHECK(o[v].ok && strcmp(o[v].path, "schur-bordered") == 0,
              "case %d p = %d variant %d: completed on %s", c, p, v, o[v].path);
        if (o[v].ok && g.ok) {
          const double d = rel_diff(&g, &o[v], N_STEPS);
          CHECK(d <= 1e-10, "case %d p = %d variant %d vs general: %.2e", c, p,
                v, d);
        }
      }
      CHECK(o[2].factorisations == o[2].updates &&
                o[0].factorisations < o[0].updates &&
                o[0].factorisations <= o[1].factorisations &&
                (c == 0 || o[0].factorisations < o[1].factorisations),
            "case %d p = %d: factorisations / updates by cost %ld / %ld, by "
            "rate %ld / %ld, forced %ld / %ld",
            c, p, o[0].factorisations, o[0].updates, o[1].factorisations,
            o[1].updates, o[2].factorisations, o[2].updates);
      printf("chain refactor case %d p = %d: factorisations / updates by cost "
             "%ld / %ld, by rate %ld / %ld, forced %ld / %ld\n",
             c, p, o[0].factorisations, o[0].updates, o[1].factorisations,
             o[1].updates, o[2].factorisations, o[2].updates);
      for (int v = 0; v < 3; v++)
        run_free(&o[v]);
      run_free(&g);
    }
    mrvi_model_free(m);
  }
}

/* The node blocks (micro-node multipliers joined to their nodes) at the
 * default limits: flexible_pendulum (blocks 11 and 22) and spacecraft
 * (18 and 138) take schur-bordered at p = 10 and 20 and agree with
 * general over 30 macro steps; with bordered_node_max below the fast block
 * they take general and say why. */
static void test_node_blocks(void) {
  const char *const files[] = {"systems/flexible_pendulum.yaml",
                               "systems/spacecraft.yaml"};
  for (int f = 0; f < 2; f++)
    for (int pi = 0; pi < 2; pi++) {
      const int p = pi ? 20 : 10;
      char ov[5][96];
      const char *ovp[5];
      snprintf(ov[0], sizeof ov[0], "integrator.micro_steps=%d", p);
      snprintf(ov[1], sizeof ov[1], "integrator.newton.tolerance=1e-12");
      snprintf(ov[2], sizeof ov[2], "integrator.constraints.tolerance=1e-12");
      snprintf(ov[3], sizeof ov[3], "integrator.solver=structured");
      snprintf(ov[4], sizeof ov[4], "integrator.solver=general");
      for (int i = 0; i < 5; i++)
        ovp[i] = ov[i];
      mrvi_system *sa = NULL, *sg = NULL;
      char msg[512], why[400] = "";
      if (mrvi_system_load(test_source_path(files[f]), ovp, 4, &sa, msg,
                           sizeof msg) < 0 ||
          mrvi_system_load(test_source_path(files[f]), ovp, 5, &sg, msg,
                           sizeof msg) < 0) {
        CHECK(0, "load %s: %s", files[f], msg);
        mrvi_system_free(sa);
        continue;
      }
      const char *path =
          mrvi_solver_path(sa->model, &sa->settings, why, sizeof why);
      CHECK(path && strcmp(path, "schur-bordered") == 0,
            "%s p=%d: path %s (%s)", files[f], p, path ? path : "none", why);
      run_out a = {0}, g = {0};
      run(sa->model, &sa->settings, 30, &a);
      run(sg->model, &sg->settings, 30, &g);
      CHECK(a.ok && g.ok, "%s p=%d: runs completed", files[f], p);
      if (a.ok && g.ok) {
        const double d = rel_diff(&g, &a, 30);
        CHECK(d <= 1e-10, "%s p=%d: %s vs general: %.2e", files[f], p, a.path,
              d);
        printf("%s p=%d: schur-bordered vs general %.2e\n", files[f], p, d);
      }
      run_free(&a);
      run_free(&g);
      mrvi_settings s = sa->settings;
      s.solver = MRVI_SOLVER_AUTO;
      CHECK(mrvi_settings_set_tuning(&s, "bordered_node_max", 16, msg,
                                     sizeof msg) == 0 &&
                mrvi_settings_set_tuning(&s, "bordered_slow_max", 0, msg,
                                         sizeof msg) == 0,
            "%s", msg);
      path = mrvi_solver_path(sa->model, &s, why, sizeof why);
      CHECK(path && strcmp(path, "general") == 0 &&
                strstr(why, "bordered_node_max") != NULL,
            "%s, bordered_node_max 16: path %s (%s)", files[f],
            path ? path : "none", why);
      mrvi_system_free(sa);
      mrvi_system_free(sg);
    }
}

/* The sparse node blocks (solver/bordered_sparse.c): a planar lattice of
 * 15 x 14 particles (alternately slow and fast: 210 fast coordinates), its
 * last column clamped and rods between slow-fast pairs of its top row
 * (bench_ocp --lattice --constrained's model), p = 10: the fast node block
 * of 210 coordinates and 21 multipliers is beyond bordered_node_max, so
 * the automatic choice takes schur-bordered with sparse node blocks where
 * bordered_slow_max allows (here 6000; off by default); its
 * trajectory against the general path's over 100 macro steps at tight
 * tolerances. */
static void test_sparse_node_blocks(void) {
  const int nx = 15, ny = 14;
  char text[8192];
  size_t k = (size_t)snprintf(
      text, sizeof text,
      "name: lattice\ndimension: 2\ngenerate:\n  - kind: lattice2d\n"
      "    name: p\n    count: [%d, %d]\n    spacing: 1.0\n    mass: 1.0\n"
      "    rates: {every: 2}\n"
      "    slow_spring: {law: linear, stiffness: 10}\n"
      "    fast_spring: {law: linear, stiffness: 1000}\n    initial:\n"
      "      - {index: [2, 2], displacement: [0.1, 0.05], velocity: [0.0, "
      "0.5]}\n"
      "integrator: {scheme: midpoint-midpoint, macro_step: 0.05, "
      "micro_steps: 10, t_end: 5, newton: {tolerance: 1e-12}, "
      "constraints: {tolerance: 1e-12}, tuning: {bordered_slow_max: 6000}}\n"
      "constraints:\n",
      nx, ny);
  for (int j = 0; j < ny; j++)
    k += (size_t)snprintf(text + k, sizeof text - k,
                          "  - {type: fixed, particle: p%d_%d}\n", nx - 1, j);
  for (int i = 0; i + 2 < nx; i += 2)
    k += (size_t)snprintf(text + k, sizeof text - k,
                          "  - {type: distance, between: [p%d_%d, p%d_%d]}\n",
                          i, ny - 1, i + 1, ny - 1);
  const char *gen[] = {"integrator.solver=general"};
  mrvi_system *sa = NULL, *sg = NULL;
  char msg[512], why[400] = "";
  if (mrvi_system_load_string(text, "lattice", NULL, 0, &sa, msg, sizeof msg) <
          0 ||
      mrvi_system_load_string(text, "lattice", gen, 1, &sg, msg, sizeof msg) <
          0) {
    CHECK(0, "load lattice: %s", msg);
    mrvi_system_free(sa);
    return;
  }
  const char *path =
      mrvi_solver_path(sa->model, &sa->settings, why, sizeof why);
  CHECK(path && strcmp(path, "schur-bordered") == 0 &&
            strstr(why, "sparse LU") != NULL,
        "lattice: path %s (%s)", path ? path : "none", why);
  const int steps = 100;
  run_out a = {0}, g = {0};
  run(sa->model, &sa->settings, steps, &a);
  run(sg->model, &sg->settings, steps, &g);
  CHECK(a.ok && g.ok && strcmp(a.path, "schur-bordered") == 0 &&
            strcmp(g.path, "general") == 0,
        "lattice: runs completed (%s, %s)", a.path, g.path);
  if (a.ok && g.ok) {
    const double d = rel_diff(&g, &a, steps);
    CHECK(d <= 1e-10, "lattice: sparse node blocks vs general: %.2e", d);
    printf("lattice %d x %d: sparse node blocks vs general %.2e\n", nx, ny, d);
  }
  run_free(&a);
  run_free(&g);
  mrvi_system_free(sa);
  mrvi_system_free(sg);
}

/* The choice between general and schur-bordered by the structural cost
 * estimates (solver/path_cost.c, doc/solver.md): on structurally different
 * models, the path (the faster one measured by bench_paths:
 * doc/performance/paths.md, "Constrained paths: per-step costs"), its reason
 * with both estimates, the estimate of the chosen path the smaller, the same
 * answer twice (no timing), and integrator.solver = structured keeping
 * schur-bordered. */
static void test_path_choice(void) {
  static const struct {
    const char *file;
    int p;
    const char *path, *reason;
  } cases[] = {
      /* all slow bodies: the dense LU of the sparse saddle point */
      {"systems/slider_crank.yaml", 1, "general", "against"},
      {"systems/slider_crank.yaml", 20, "general", "against"},
      {"systems/heavy_top.yaml", 1, "general", "against"},
      /* particles, micro-node rods: node blocks from p = 5 on, and at
       * p = 1 the factors kept for a step's later updates */
      {"systems/triatomic.yaml", 10, "schur-bordered", "on general"},
      {"systems/spring_ring_rod.yaml", 1, "schur-bordered", "on general"},
      /* slow arm, fast payload, macro-node joints: general up to p = 10 */
      {"systems/robot_arm_payload.yaml", 1, "general", "on schur-bordered"},
      {"systems/robot_arm_payload.yaml", 20, "schur-bordered", "on general"},
      /* bodies with micro-node joints: kept factors at p = 1 ... */
      {"systems/flexible_pendulum.yaml", 1, "schur-bordered", "on general"},
      {"systems/spacecraft.yaml", 1, "schur-bordered", "on general"},
      /* ... and beyond the dense LU's size */
      {"systems/spacecraft.yaml", 5, "schur-bordered", "newton_dense_max"}};
  for (size_t i = 0; i < sizeof cases / sizeof *cases; i++) {
    char ov[1][64];
    const char *ovp[1] = {ov[0]};
    snprintf(ov[0], sizeof ov[0], "integrator.micro_steps=%d", cases[i].p);
    mrvi_system *sys = NULL;
    char msg[512], why[512] = "", why2[512] = "";
    if (mrvi_system_load(test_source_path(cases[i].file), ovp, 1, &sys, msg,
                         sizeof msg) < 0) {
      CHECK(0, "load %s: %s", cases[i].file, msg);
      continue;
    }
    mrvi_settings s = sys->settings;
    const char *path = mrvi_solver_path(sys->model, &s, why, sizeof why);
    CHECK(path && strcmp(path, cases[i].path) == 0 &&
              strstr(why, cases[i].reason) != NULL,
          "%s p=%d: %s (%s)", cases[i].file, cases[i].p, path ? path : "none",
          why);
    /* the chosen path's estimate is the smaller */
    mrvi_path_cost c;
    CHECK(mrvi_path_costs(sys->model, &s, &c) == 0, "%s: costs", cases[i].file);
    if (c.n <= s.tuning.newton_dense_max)
      CHECK(
          (strcmp(path ? path : "", "general") == 0 ? c.general : c.bordered) <=
              fmin(c.general, c.bordered),
          "%s p=%d: %s estimated %.4g, general %.4g, schur-bordered %.4g",
          cases[i].file, cases[i].p, path ? path : "none",
          path && !strcmp(path, "general") ? c.general : c.bordered, c.general,
          c.bordered);
    else
      CHECK(path && strcmp(path, "schur-bordered") == 0,
            "%s p=%d: beyond newton_dense_max on %s", cases[i].file, cases[i].p,
            path ? path : "none");
    const char *again = mrvi_solver_path(sys->model, &s, why2, sizeof why2);
    CHECK(again == path && strcmp(why, why2) == 0, "%s: deterministic",
          cases[i].file);
    s.solver = MRVI_SOLVER_STRUCTURED;
    path = mrvi_solver_path(sys->model, &s, why, sizeof why);
    CHECK(path && strcmp(path, "schur-bordered") == 0 &&
              strstr(why, "estimated") == NULL,
          "%s p=%d structured: %s (%s)", cases[i].file, cases[i].p,
          path ? path : "none", why);
    mrvi_system_free(sys);
  }
}

/* Chains: 8 links on schur-bordered (requested, whatever the estimates say:
 * test_path_choice); 40 links take general (beyond
 * bordered_max) and schur-bordered where it is raised; both agree with
 * general. */
static void test_chains(void) {
  for (int c = 0; c < 3; c++) {
    const int n = c == 0 ? 8 : 40, steps = c == 0 ? N_STEPS : 20;
    mrvi_model *m = chain(n, 0);
    for (int pi = 0; pi < 2; pi++) {
      const int p = pi ? 5 : 1;
      mrvi_settings sa = chain_settings(p, "auto"),
                    sg = chain_settings(p, "general");
      char msg[200];
      if (c != 1)
        sa.solver = MRVI_SOLVER_STRUCTURED; /* whatever the estimates say */
      if (c == 2)
        CHECK(mrvi_settings_set_tuning(&sa, "bordered_max", 128, msg,
                                       sizeof msg) == 0,
              "%s", msg);
      char why[512] = "";
      const char *path = mrvi_solver_path(m, &sa, why, sizeof why);
      const char *want = "schur-bordered";
      CHECK(path && strcmp(path, want) == 0, "chain of %d (%s): path %s (%s)",
            n,
            c == 2 ? "bordered_max 128"
            : c    ? "auto"
                   : "structured",
            path ? path : "none", why);
      if (c == 1)
        CHECK(strstr(why, "chain elimination") != NULL, "reason: %s", why);
      char what[32];
      snprintf(what, sizeof what, "chain of %d p=%d", n, p);
      agree(m, &sa, &sg, steps, what);
    }
    mrvi_model_free(m);
  }
}

/* The general path's estimate takes newton.c's dense/sparse decision
 * (mrvi_newton_dense_chosen) on its estimated pattern: bench_chain's rod
 * chain at p = 10 (23 unknowns per link) keeps the dense LU at 10 links
 * (230 unknowns) and takes UMFPACK at 16 (368), as newton.c does on the
 * general path's assembled step (dense flops 1.60e5 and 6.15e5 against
 * UMFPACK's 4.51e5 and 7.48e5 there, 8.05e5 on the estimated pattern at
 * 16; doc/performance/kernels.md, "The dense/sparse switch by flops"); there
 * general is not costed and schur-bordered is chosen, saying why. */
static void test_general_backend(void) {
  for (int big = 0; big < 2; big++) {
    const int n = big ? 16 : 10;
    mrvi_model *m = chain_interleaved(n);
    mrvi_settings s = chain_settings(10, "auto");
    mrvi_path_cost c;
    CHECK(mrvi_path_costs(m, &s, &c) == 0, "chain of %d: costs", n);
    CHECK(c.n == 23L * n && c.general_dense == !big &&
              isfinite(c.general) == !big,
          "chain of %d: %ld unknowns, general_dense %d, general %.4g", n, c.n,
          c.general_dense, c.general);
    char why[512] = "";
    const char *path = mrvi_solver_path(m, &s, why, sizeof why);
    CHECK(path && strcmp(path, "schur-bordered") == 0 &&
              strstr(why, big ? "sparse LU by its flop estimate"
                              : "on general") != NULL,
          "chain of %d: %s (%s)", n, path ? path : "none", why);
    mrvi_model_free(m);
  }
}

/* The sparse Gram matrix (more than MRVI_GRAM_DENSE_MAX rows) against the
 * dense projection, rods in order and reversed (a wide envelope); a
 * redundant rod still refused with its name by the dense check. */
static void test_gram(void) {
  for (int reverse = 0; reverse < 2; reverse++) {
    const int n = 40;
    mrvi_model *m = chain(n, reverse);
    const int R = m->constraint_rows, nn = m->n;
    CHECK(R > MRVI_GRAM_DENSE_MAX, "%d rows take the sparse Gram", R);
    double *p = malloc((size_t)nn * sizeof *p), *pd = malloc((size_t)nn * 8),
           *g = malloc((size_t)R * 8), *G = malloc((size_t)R * nn * 8),
           *A = malloc((size_t)R * R * 8), *mu = malloc((size_t)R * 8),
           *mus = malloc((size_t)R * 8);
    for (int j = 0; j < nn; j++)
      p[j] = pd[j] = sin(1.7 * j + 0.3) * MRVI_MASS(m, j);
    mrvi_gram *gr = NULL;
    CHECK(mrvi_gram_create(m, &gr) == 0, "gram created");
    CHECK(mrvi_gram_factor(gr, m, m->q0) == 0, "gram factored");
    mrvi_gram_project(gr, m, p, mus);
    CHECK(mrvi_constraints_project(m, m->q0, pd, NULL, g, G, A, mu) == 0,
          "dense projection");
    double dp = 0.0, pm = 0.0, dm = 0.0, mm = 0.0;
    for (int j = 0; j < nn; j++) {
      dp = fmax(dp, fabs(p[j] - pd[j]));
      pm = fmax(pm, fabs(pd[j]));
    }
    for (int r = 0; r < R; r++) {
      dm = fmax(dm, fabs(mus[r] - mu[r]));
      mm = fmax(mm, fabs(mu[r]));
    }
    CHECK(dp <= 1e-12 * pm && dm <= 1e-11 * mm,
          "sparse vs dense projection (reverse %d): p %.2e, mu %.2e", reverse,
          dp / pm, dm / mm);
    CHECK(mrvi_model_hidden_residual(m, m->q0, p) <= 1e-13 * pm,
          "hidden constraint after the sparse projection: %.2e",
          mrvi_model_hidden_residual(m, m->q0, p));
    mrvi_gram_free(gr);
    free(p), free(pd), free(g), free(G), free(A), free(mu), free(mus);
    char msg[300] = "";
    CHECK(mrvi_constraints_independent(m, m->q0, msg, sizeof msg) == 0,
          "independent: %s", msg);
    /* A second rod between h3 and h4: the Gram matrix is singular, the
     * dense check names both. */
    mrvi_model_add_distance(m, 2, 3, NAN);
    mrvi_model_set_constraint_label(m, m->n_constraints - 1, "twin rod");
    gr = NULL;
    CHECK(mrvi_gram_create(m, &gr) == 0 &&
              mrvi_gram_factor(gr, m, m->q0) == MRVI_ESINGULAR,
          "redundant rows: a pivot at round-off");
    mrvi_gram_free(gr);
    msg[0] = '\0';
    CHECK(mrvi_constraints_independent(m, m->q0, msg, sizeof msg) ==
                  MRVI_ESINGULAR &&
              strstr(msg, "twin rod") && strstr(msg, "redundant"),
          "redundant rod refused: %s", msg);
    mrvi_model_free(m);
  }
}

int main(void) {
  test_gram();
  test_path_choice();
  test_general_backend();
  test_chains();
  test_chain_elimination();
  test_chain_transpose();
  test_chain_refactor();
  test_node_blocks();
  test_sparse_node_blocks();
  test_shipped();
  return test_finish();
}
