/* Multirate discrete mechanics and optimal control (src/ocp/):
 * - adjoint gradients of the cost and of every terminal constraint against
 *   central differences (relative 1e-6) for every named scheme, p in
 *   {1, 5}, slow and fast actuators on slow and fast coordinates;
 * - double integrator rest-to-rest: J_N = J* N^2/(N^2 - 1),
 *   J* = 6 m^2 d^2 / T^3, beside an uncoupled fast oscillator (p = 5) and
 *   alone (p = 1), to 1e-8 relative;
 * - harmonic oscillator rest-to-rest over one period: J* = m^2 w^2 d^2 / T,
 *   order 2 (midpoint) fitted from a halving sequence;
 * - p = 1 equals a few-line single-rate DMOC written here (midpoint L_d,
 *   f^+- = (h/2) u), to 1e-8 on the optimal controls;
 * - the adjoint's step Jacobian dense and in sparse rows, its transposed
 *   solves factorised every step and refined from kept factors: the same
 *   gradients to 1e-10 (unconstrained, both constraint forms). */
#include "model/model.h"
#include "models.h"
#include "ocp/ocp.h"
#include "ocp/ocp_internal.h"
#include "testlib.h"

#include <hdf5.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/wait.h>
#include <time.h>

/* The gradients against central differences (testlib.h). */
static void check_gradients(mrvi_ocp *o, const char *what) {
  test_ocp_gradients(o, what, 0.5);
}

/* mrvi_ocp_create, checked. */
static mrvi_ocp *create_problem(mrvi_model *m, const mrvi_settings *s) {
  mrvi_ocp *o = NULL;
  char msg[300];
  const int st = mrvi_ocp_create(m, s, &o, msg, sizeof msg);
  CHECK(st == 0, "create: %s", msg);
  return st == 0 ? o : NULL;
}

/* FPU problem (four actuators: slow and fast grids on slow and fast
 * coordinates, tracking, four terminal constraints and a terminal
 * penalty). */
static mrvi_ocp *fpu_problem(mrvi_model *m, const mrvi_settings *s) {
  mrvi_ocp *o = create_problem(m, s);
  if (!o)
    return NULL;
  mrvi_ocp_add_actuator(o, 0, MRVI_GRID_MACRO, 1.0, -HUGE_VAL, HUGE_VAL);
  mrvi_ocp_add_actuator(o, 3, MRVI_GRID_MICRO, 2.0, -HUGE_VAL, HUGE_VAL);
  mrvi_ocp_add_actuator(o, 4, MRVI_GRID_MACRO, 0.5, -HUGE_VAL, HUGE_VAL);
  mrvi_ocp_add_actuator(o, 1, MRVI_GRID_MICRO, 1.5, -HUGE_VAL, HUGE_VAL);
  mrvi_ocp_add_tracking(o, 2, 3.0, 0.1);
  mrvi_ocp_add_tracking(o, 5, 2.0, -0.1);
  mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, 0, 1.0, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 1, 0.5, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, 3, 0.0, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 5, 0.2, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 4, 0.1, 7.0);
  return o;
}

/* The FPU problem for every named scheme and p in {1, 5}. */
static void test_gradients(void) {
  const char *const *schemes = mrvi_scheme_names();
  const int ps[2] = {1, 5};
  for (int is = 0; schemes[is]; is++)
    for (int ip = 0; ip < 2; ip++) {
      mrvi_model *m = test_fpu();
      mrvi_settings s = test_settings(schemes[is], 0.03, ps[ip], 0.12, 1e-13);
      /* Every other case with the step Jacobian in sparse rows. */
      if ((is + ip) % 2)
        s.tuning.adjoint_dense_max = 0;
      mrvi_ocp *o = fpu_problem(m, &s);
      if (o) {
        char what[100];
        mrvi_fmt(what, sizeof what, "FPU %s p=%d", schemes[is], ps[ip]);
        check_gradients(o, what);
      }
      mrvi_ocp_free(o);
      mrvi_model_free(m);
    }
}

/* Cart pendulum problem: actuators on slow and fast coordinates and grids,
 * a pair force between cart and bob, tracking, terminal conditions. */
static mrvi_ocp *cart_problem_pair(mrvi_model *m, const mrvi_settings *s,
                                   int pair) {
  mrvi_ocp *o = create_problem(m, s);
  if (!o)
    return NULL;
  /* cart.x, cart.y slow (0, 1); bob.x, bob.y fast (3, 4) */
  mrvi_ocp_add_actuator(o, 0, MRVI_GRID_MACRO, 1.0, -HUGE_VAL, HUGE_VAL);
  mrvi_ocp_add_actuator(o, 1, MRVI_GRID_MICRO, 2.0, -HUGE_VAL, HUGE_VAL);
  mrvi_ocp_add_actuator(o, 3, MRVI_GRID_MICRO, 0.5, -HUGE_VAL, HUGE_VAL);
  mrvi_ocp_add_actuator(o, 4, MRVI_GRID_MACRO, 1.5, -HUGE_VAL, HUGE_VAL);
  /* A pair force between cart and bob (along the rod). */
  if (pair)
    mrvi_ocp_add_pair_actuator(o, 0, 1, MRVI_GRID_MICRO, 1.0, -HUGE_VAL,
                               HUGE_VAL);
  mrvi_ocp_add_tracking(o, 5, 3.0, -0.2);
  mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, 0, 0.1, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 0, 0.0, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, 3, 0.0, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 4, 0.0, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 5, 0.0, 4.0);
  return o;
}
static mrvi_ocp *cart_problem(mrvi_model *m, const mrvi_settings *s) {
  return cart_problem_pair(m, s, 1);
}

/* Cart pendulum (slow cart on a plane, fast bob on a rod: constraints at
 * macro and micro nodes) in both constraint forms. */
static void test_gradients_constrained(void) {
  const char *const *schemes = mrvi_scheme_names();
  const int ps[2] = {1, 5};
  const char *forms[2] = {"multipliers", "null-space"};
  for (int is = 0; schemes[is]; is++)
    for (int ip = 0; ip < 2; ip++)
      for (int form = 0; form < 2; form++) {
        mrvi_model *m = test_cart_pendulum();
        mrvi_settings s = test_settings(schemes[is], 0.01, ps[ip], 0.04, 1e-13);
        s.constraint_form = form ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
        s.constraint_tol = 1e-13;
        if ((is + ip + form) % 2)
          s.tuning.adjoint_dense_max = 0;
        mrvi_ocp *o = cart_problem(m, &s);
        if (o) {
          char what[120];
          mrvi_fmt(what, sizeof what, "cart pendulum %s p=%d %s", schemes[is],
                   ps[ip], forms[form]);
          check_gradients(o, what);
        }
        mrvi_ocp_free(o);
        mrvi_model_free(m);
      }
}

/* Cost and constraint gradients of o at u into g (n (1 + m)). */
static int gradients_at(mrvi_ocp *o, const double *u, double *g) {
  const int n = mrvi_ocp_n_controls(o), m = mrvi_ocp_n_constraints(o);
  double J, c[16];
  return m <= 16 ? mrvi_ocp_evaluate(o, u, &J, g, c, g + n) : -1;
}

/* The adjoint's six ways (step Jacobian dense or in sparse rows; every
 * step factorised, kept factors refined to adjoint_refine_max, or refined
 * while that costs less than a factorisation, adjoint_refine_by_cost)
 * give the same gradients to 1e-10 relative, at two controls in turn (the
 * second starts from the first's kept factors); on the FPU the ways
 * refined to adjoint_refine_max factorise fewer steps than there are. */
static void test_adjoint_ways(void) {
  const char *forms[3] = {"unconstrained", "multipliers", "null-space"};
  for (int f = 0; f < 3; f++)
    for (int ip = 0; ip < 2; ip++) {
      const int p = ip ? 5 : 1;
      double *ref = NULL;
      int n_ref = 0;
      for (int way = 0; way < 6; way++) {
        mrvi_model *m = f ? test_cart_pendulum() : test_fpu();
        mrvi_settings s = test_settings("midpoint-midpoint", f ? 0.01 : 0.03, p,
                                        f ? 0.08 : 0.24, 1e-13);
        s.constraint_form =
            f == 2 ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
        s.constraint_tol = 1e-13;
        s.tuning.adjoint_dense_max = way & 1 ? 0 : 1000000;
        s.tuning.adjoint_refine_max = way & 6 ? 8 : 0;
        s.tuning.adjoint_refine_by_cost = way >= 4;
        mrvi_ocp *o = f ? cart_problem(m, &s) : fpu_problem(m, &s);
        if (!o) {
          mrvi_model_free(m);
          continue;
        }
        const int n = mrvi_ocp_n_controls(o), nm = mrvi_ocp_n_constraints(o);
        const int len = 2 * n * (1 + nm);
        double *u = malloc((size_t)n * sizeof *u);
        double *g = calloc((size_t)len, sizeof *g);
        int st = 0;
        for (int t = 0; t < 2 && st == 0; t++) {
          for (int i = 0; i < n; i++)
            u[i] = 0.5 * sin(1.7 * i + 0.3 + t);
          st = gradients_at(o, u, g + t * n * (1 + nm));
        }
        CHECK(st == 0, "%s p=%d way %d: %s", forms[f], p, way,
              mrvi_ocp_errmsg(o));
        if (st == 0 && way == 0) {
          ref = g;
          n_ref = len;
          g = NULL;
        } else if (st == 0 && ref && n_ref == len) {
          double err = 0.0, sc = 0.0;
          for (int i = 0; i < len; i++) {
            err = fmax(err, fabs(g[i] - ref[i]));
            sc = fmax(sc, fabs(ref[i]));
          }
          CHECK(err <= 1e-10 * sc,
                "%s p=%d way %d: gradients differ by %.3e "
                "(scale %.3e)",
                forms[f], p, way, err, sc);
          /* 2 evaluations of N steps (N = 8); the pendulum's steps change
           * too fast for the refinement (it factorises them). */
          if (way & 2 && f == 0)
            CHECK(o->adjoint_factorisations < 16,
                  "%s p=%d way %d: %ld step factorisations in 16 steps",
                  forms[f], p, way, o->adjoint_factorisations);
        }
        free(u);
        free(g);
        mrvi_ocp_free(o);
        mrvi_model_free(m);
      }
      free(ref);
    }
}

/* A 2-D chain of three slow links on rods from the pivot (constraints at
 * macro nodes only: schur-bordered's slow-only form), a fast light mass on
 * a stiff spring from the last link, gravity. */
static mrvi_model *link_chain(int nl) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double gr[2] = {0, -9.81}, pivot[2] = {0, 0};
  mrvi_model_set_gravity(m, gr);
  for (int i = 0; i < nl; i++) {
    const double x[2] = {0.3 * (i + 1), -0.4 * (i + 1)}, v[2] = {0.2 * i, -0.1};
    char name[16];
    snprintf(name, sizeof name, "h%d", i + 1);
    mrvi_model_add_particle(m, name, 1.0 + i, MRVI_SLOW, x, v);
  }
  const double xf[2] = {0.3 * nl, -0.4 * nl - 0.15}, vf[2] = {0.1, 0.3},
               k[1] = {900};
  mrvi_model_add_particle(m, "tip", 0.1, MRVI_FAST, xf, vf);
  mrvi_model_add_spring(m, MRVI_FAST, nl - 1, nl, "linear", k, NAN);
  mrvi_model_add_distance_anchor(m, 0, pivot, NAN);
  for (int i = 0; i + 1 < nl; i++)
    mrvi_model_add_distance(m, i, i + 1, NAN);
  mrvi_model_project_velocities(m, NULL);
  return m;
}

/* Its problem: slow actuators on two links, a fast one on the tip, a
 * terminal velocity and a penalised position. */
static mrvi_ocp *chain_problem(mrvi_model *m, const mrvi_settings *s) {
  mrvi_ocp *o = create_problem(m, s);
  if (!o)
    return NULL;
  const int tip = m->n - 2; /* (the tip's x) */
  mrvi_ocp_add_actuator(o, 0, MRVI_GRID_MACRO, 1.0, -HUGE_VAL, HUGE_VAL);
  mrvi_ocp_add_actuator(o, tip - 1, MRVI_GRID_MICRO, 2.0, -HUGE_VAL, HUGE_VAL);
  mrvi_ocp_add_actuator(o, tip, MRVI_GRID_MICRO, 0.5, -HUGE_VAL, HUGE_VAL);
  mrvi_ocp_add_tracking(o, tip + 1, 3.0, -1.2);
  mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 2, 0.3, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, tip, 0.3 * (m->n / 2 - 1), 2.0);
  return o;
}

/* Constrained models on schur-bordered (the forward pass through its block
 * elimination keeping the multipliers, the adjoint solving the transposed
 * steps with it): the path taken, the gradients against central
 * differences, the forward run against the general path's to 1e-10, the
 * kept factors refined against every step factorised (1e-10); the
 * null-space form (general path) on the same problems.  The cart pendulum
 * (micro-node constraints: the node blocks) for every scheme, a chain of
 * 3 links (rods at macro nodes only: the slow block bordered) and one of
 * 12 links on the chain elimination (bordered_max 0: the forward pass and
 * the adjoint's transposed solves), p in {1, 5}. */
static void test_bordered(void) {
  const char *const *schemes = mrvi_scheme_names();
  const char *forms[2] = {"multipliers", "null-space"};
  /* (case 1: the cart pendulum with its pair actuator, a state actuator:
   * its Jacobian in the node blocks, ocp_path) */
  for (int mc = 0; mc < 5; mc++)
    for (int is = 0; schemes[is] && (mc <= 1 || is == 0); is++)
      for (int ip = 0; ip < 2; ip++)
        for (int form = 0; form < 2; form++) {
          /* (case 4: the cart pendulum on the sparse node blocks,
           * solver/bordered_sparse.c: bordered_node_max 0) */
          const int model = mc > 1 && mc < 4 ? mc - 1 : 0, pair = mc == 1,
                    sparse = mc == 4;
          const int p = ip ? 5 : 1;
          mrvi_model *m =
              model ? link_chain(model == 2 ? 12 : 3) : test_cart_pendulum();
          mrvi_settings s = test_settings(
              model ? "midpoint-midpoint" : schemes[is], model ? 0.02 : 0.01, p,
              model ? 0.1 : 0.04, model ? 1e-14 : 1e-13);
          s.constraint_form =
              form ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
          s.constraint_tol = 1e-13;
          if ((is + ip) % 2)
            s.tuning.adjoint_dense_max = 0;
          if (model) /* (the cost model prefers general on so short a
                        chain) */
            s.solver = MRVI_SOLVER_STRUCTURED * !form;
          if (model == 2) /* (the chain elimination, solver/chain.c, in
                             the forward pass and the adjoint) */
            s.tuning.bordered_max = 0;
          if (sparse)
            s.tuning.bordered_node_max = 0, s.tuning.bordered_slow_max = 6000;
          mrvi_settings sg = s;
          sg.solver = MRVI_SOLVER_GENERAL;
          mrvi_ocp *o =
              model ? chain_problem(m, &s) : cart_problem_pair(m, &s, pair);
          mrvi_ocp *og =
              model ? chain_problem(m, &sg) : cart_problem_pair(m, &sg, pair);
          s.tuning.adjoint_refine_max = 0;
          mrvi_ocp *o0 =
              model ? chain_problem(m, &s) : cart_problem_pair(m, &s, pair);
          char what[160], why[300];
          mrvi_fmt(what, sizeof what, "bordered: %s %s p=%d %s",
                   model == 2 ? "chain (chain elimination)"
                   : model    ? "chain"
                   : pair     ? "cart pendulum with a pair actuator"
                   : sparse   ? "cart pendulum (sparse node blocks)"
                              : "cart pendulum",
                   model ? "midpoint-midpoint" : schemes[is], p, forms[form]);
          const char *path = o ? mrvi_ocp_solver_path(o, why, sizeof why) : 0;
          const char *want = form ? "general" : "schur-bordered";
          CHECK(path && strcmp(path, want) == 0 &&
                    (form || (strstr(why, "chain elimination") != NULL) ==
                                 (model == 2)),
                "%s: path %s (%s)", what, path ? path : "none", why);
          if (o && og && o0) {
            check_gradients(o, what);
            /* the adjoint on bordered.c's transposed solves, the chain
             * elimination's on the 12-link chain (with a state actuator
             * on the dense LU where H is dense) */
            const int dense_lu =
                pair && o->nv <= o->settings.tuning.adjoint_dense_max;
            const int on_chain =
                o->bordered ? mrvi_bordered_on_chain(o->bordered) : -1;
            CHECK(form || (dense_lu ? on_chain < 0 : on_chain == (model == 2)),
                  "%s: schur-bordered adjoint %s", what,
                  on_chain < 0 ? "missing"
                  : on_chain   ? "on the chain elimination"
                               : "on the dense blocks");
            test_ocp_same_forward(o, og, m->n, what, 0.5, 1e-10);
            /* kept factors refined (o) against every step factorised
             * (o0), at two controls in turn */
            const int n = mrvi_ocp_n_controls(o),
                      nm = mrvi_ocp_n_constraints(o);
            double *u = malloc((size_t)n * sizeof *u),
                   *g = calloc((size_t)(2 * n * (1 + nm)), sizeof *g);
            double err = 0.0, sc = 0.0;
            int st = 0;
            for (int t = 0; t < 2 && st == 0; t++) {
              for (int i = 0; i < n; i++)
                u[i] = 0.5 * sin(1.7 * i + 0.3 + t);
              st =
                  gradients_at(o, u, g) | gradients_at(o0, u, g + n * (1 + nm));
              for (int i = 0; i < n * (1 + nm); i++) {
                err = fmax(err, fabs(g[i] - g[n * (1 + nm) + i]));
                sc = fmax(sc, fabs(g[n * (1 + nm) + i]));
              }
            }
            CHECK(st == 0 && err <= 1e-10 * sc,
                  "%s: kept factors against every step factorised: status "
                  "%d, gradients differ by %.3e (scale %.3e)",
                  what, st, err, sc);
            free(u);
            free(g);
          }
          mrvi_ocp_free(o);
          mrvi_ocp_free(og);
          mrvi_ocp_free(o0);
          mrvi_model_free(m);
        }
}

/* Slow free mass (and, if p > 1, an uncoupled fast oscillator). */
static mrvi_model *double_integrator(double mass, int with_fast) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_add_coordinate(m, "x", mass, MRVI_SLOW, 0.0, 0.0);
  if (with_fast) {
    mrvi_model_add_coordinate(m, "y", 0.3, MRVI_FAST, 0.01, 0.2);
    const int c = 1;
    const double one = 1.0, k[1] = {0.3 * 2500.0};
    mrvi_model_add_term(m, MRVI_FAST, 1, &c, &one, 0.0, "linear", k);
  }
  return m;
}

/* Rest-to-rest 0 -> d of coordinate 0 in t_end with effort cost; returns
 * the optimal cost (NaN on failure); u (n) gets the controls. */
static double rest_to_rest(mrvi_model *m, const mrvi_settings *s, double d,
                           mrvi_ocp_algorithm alg, double *u_out) {
  mrvi_ocp *o = NULL;
  char msg[300];
  double J = NAN;
  if (mrvi_ocp_create(m, s, &o, msg, sizeof msg) != 0) {
    CHECK(0, "create: %s", msg);
    return J;
  }
  mrvi_ocp_add_actuator(o, 0, MRVI_GRID_MACRO, 1.0, -HUGE_VAL, HUGE_VAL);
  mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, 0, d, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 0, 0.0, 0.0);
  mrvi_ocp_set_algorithm(o, alg);
  /* The augmented-Lagrangian algorithms do not reach ftol_rel 1e-15 within
   * the 2000 evaluations (status max_evaluations, not converged). */
  mrvi_ocp_set_tolerances(o, alg == MRVI_OCP_SLSQP ? 1e-15 : 1e-10, 1e-11);
  const int n = mrvi_ocp_n_controls(o);
  double *u = calloc((size_t)n, sizeof *u);
  mrvi_ocp_result r;
  const int st = mrvi_ocp_solve(o, u, &r);
  CHECK(st == 0, "solve: %s (%s, %d evaluations)", mrvi_ocp_errmsg(o),
        r.nlopt_name, r.evaluations);
  if (st == 0)
    J = r.cost;
  if (u_out)
    memcpy(u_out, u, (size_t)n * sizeof *u);
  free(u);
  mrvi_ocp_free(o);
  return J;
}

static void test_double_integrator(void) {
  const double mass = 2.0, d = 1.0, T = 2.0;
  const int N = 10;
  const double Js = 6.0 * mass * mass * d * d / (T * T * T);
  const double JN = Js * N * N / (N * N - 1.0);
  for (int p = 1; p <= 5; p += 4) {
    mrvi_model *m = double_integrator(mass, p > 1);
    mrvi_settings s = test_settings("midpoint-midpoint", T / N, p, T, 1e-12);
    const double J = rest_to_rest(m, &s, d, MRVI_OCP_SLSQP, NULL);
    CHECK(fabs(J - JN) <= 1e-8 * JN,
          "double integrator p=%d: J = %.15g, J_N = %.15g (rel %.2e)", p, J, JN,
          fabs(J - JN) / JN);
    mrvi_model_free(m);
  }
  /* The augmented-Lagrangian algorithms reach the same optimum (their
   * penalty iteration stops at a looser tolerance).  On the general path:
   * at the terminal tolerance 1e-11 whether L-BFGS's line search stalls
   * (NLopt FAILURE) hangs on the last bits of the cost, and the schur
   * path's differ (N = 8..20 fail on either path for most N). */
  const mrvi_ocp_algorithm algs[2] = {MRVI_OCP_AUGLAG_LBFGS,
                                      MRVI_OCP_AUGLAG_CCSAQ};
  for (int a = 0; a < 2; a++) {
    mrvi_model *m = double_integrator(mass, 0);
    mrvi_settings s = test_settings("midpoint-midpoint", T / N, 1, T, 1e-12);
    s.solver = MRVI_SOLVER_GENERAL;
    const double J = rest_to_rest(m, &s, d, algs[a], NULL);
    CHECK(fabs(J - JN) <= 1e-6 * JN,
          "double integrator algorithm %d: J = %.15g, J_N = %.15g", a, J, JN);
    mrvi_model_free(m);
  }
}

static void test_oscillator_period(void) {
  const double w = 2.0 * acos(-1.0), T = 1.0, d = 0.5;
  const double Js = w * w * d * d / T;
  double err[4];
  for (int i = 0; i < 4; i++) {
    const int N = 10 << i;
    mrvi_model *m = test_oscillator(w);
    /* Start at rest at 0. */
    m->q0[0] = 0.0;
    mrvi_settings s = test_settings("midpoint-midpoint", T / N, 1, T, 1e-12);
    const double J = rest_to_rest(m, &s, d, MRVI_OCP_SLSQP, NULL);
    err[i] = fabs(J - Js);
    mrvi_model_free(m);
  }
  for (int i = 0; i + 1 < 4; i++) {
    const double order = log2(err[i] / err[i + 1]);
    CHECK(fabs(order - 2.0) < 0.1,
          "oscillator period: order %.3f (errors %.3e, %.3e)", order, err[i],
          err[i + 1]);
  }
}

/* Independent single-rate DMOC of m q'' + k q = u (midpoint L_d, f^+- =
 * (h/2) u): the map u -> (q_N, p_N) is affine, so the effort-optimal
 * rest-to-rest controls solve min 1/2 h |u|^2, A u = b directly. */
static void dmoc_reference(double mass, double k, double h, int N, double d,
                           double *u) {
  double A[2][200], c0[2] = {0.0, 0.0};
  for (int col = -1; col < N; col++) {
    double q = 0.0, p = 0.0;
    for (int j = 0; j < N; j++) {
      const double uj = col == j ? 1.0 : 0.0;
      /* p + D1 Ld + h u/2 = 0, D1 Ld = -m (q1-q)/h - h k (q+q1)/4 */
      const double q1 = (p + mass * q / h - h * k * q / 4 + h * uj / 2) /
                        (mass / h + h * k / 4);
      p = mass * (q1 - q) / h - h * k * (q + q1) / 4 + h * uj / 2;
      q = q1;
    }
    if (col < 0) {
      c0[0] = q;
      c0[1] = p;
    } else {
      A[0][col] = q - c0[0];
      A[1][col] = p - c0[1];
    }
  }
  /* u = A^T (A A^T)^-1 (b - c0). */
  double G[4] = {0, 0, 0, 0}, r[2] = {d - c0[0], 0.0 - c0[1]};
  for (int j = 0; j < N; j++)
    for (int a = 0; a < 2; a++)
      for (int b = 0; b < 2; b++)
        G[a * 2 + b] += A[a][j] * A[b][j];
  mrvi_dense_solve(2, G, r);
  for (int j = 0; j < N; j++)
    u[j] = A[0][j] * r[0] + A[1][j] * r[1];
}

static void test_dmoc_reference(void) {
  const double w = 3.0, mass = 1.0, T = 1.3, d = 0.7;
  const int N = 20;
  mrvi_model *m = test_oscillator(w);
  m->q0[0] = 0.0;
  mrvi_settings s = test_settings("midpoint-midpoint", T / N, 1, T, 1e-13);
  double u[20], ur[20];
  rest_to_rest(m, &s, d, MRVI_OCP_SLSQP, u);
  dmoc_reference(mass, w * w, T / N, N, d, ur);
  double err = 0, sc = 0;
  for (int j = 0; j < N; j++) {
    err = fmax(err, fabs(u[j] - ur[j]));
    sc = fmax(sc, fabs(ur[j]));
  }
  CHECK(err <= 1e-8 * sc,
        "p = 1 vs single-rate DMOC: max |du| = %.3e (scale %.3e)", err, sc);
  mrvi_model_free(m);
}

/* Gantry crane in the plane: slow cart on the line y = 0, fast bob on a
 * rod of length 0.2 below it; the cart moves 0 -> 1 in T = 2 and cart and
 * bob end at rest above each other.  Both constraint forms give the same
 * optimum; the rod length holds to the constraint tolerance. */
static void test_gantry(void) {
  double J[2];
  for (int form = 0; form < 2; form++) {
    mrvi_model *m = mrvi_model_create();
    mrvi_model_set_dimension(m, 2);
    const double xc[2] = {0, 0}, xb[2] = {0, -0.2}, v0[2] = {0, 0};
    const double g[2] = {0, -9.81}, ny[2] = {0, 1};
    mrvi_model_add_particle(m, "cart", 1.0, MRVI_SLOW, xc, v0);
    mrvi_model_add_particle(m, "bob", 0.1, MRVI_FAST, xb, v0);
    mrvi_model_set_gravity(m, g);
    mrvi_model_add_plane(m, 0, ny, 0.0);
    mrvi_model_add_distance(m, 0, 1, NAN);
    mrvi_settings s = test_settings("midpoint-midpoint", 0.1, 5, 2.0, 1e-12);
    s.constraint_form = form ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
    s.constraint_tol = 1e-12;
    mrvi_ocp *o = NULL;
    char msg[300];
    J[form] = NAN;
    if (mrvi_ocp_create(m, &s, &o, msg, sizeof msg) == 0) {
      mrvi_ocp_add_actuator(o, 0, MRVI_GRID_MACRO, 1.0, -HUGE_VAL, HUGE_VAL);
      mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, 0, 1.0, 0.0);
      mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 0, 0.0, 0.0);
      mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, 2, 1.0, 0.0);
      mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 2, 0.0, 0.0);
      mrvi_ocp_set_tolerances(o, 1e-14, 1e-9);
      const int n = mrvi_ocp_n_controls(o);
      double *u = calloc((size_t)n, sizeof *u);
      mrvi_ocp_result r;
      const int st = mrvi_ocp_solve(o, u, &r);
      CHECK(st == 0, "gantry %d: %s (%d evaluations, violation %.2e)", form,
            mrvi_ocp_errmsg(o), r.evaluations, r.violation);
      J[form] = r.cost;
      /* Rod length at every macro node. */
      const double *q = mrvi_ocp_q(o);
      double worst = 0.0;
      for (long k = 0; k <= mrvi_ocp_n_steps(o); k++) {
        const double dx = q[4 * k + 2] - q[4 * k],
                     dy = q[4 * k + 3] - q[4 * k + 1];
        worst = fmax(worst, fabs(sqrt(dx * dx + dy * dy) - 0.2));
      }
      CHECK(worst <= 1e-11, "gantry %d: rod length error %.2e", form, worst);
      free(u);
    } else {
      CHECK(0, "gantry create: %s", msg);
    }
    mrvi_ocp_free(o);
    mrvi_model_free(m);
  }
  CHECK(fabs(J[0] - J[1]) <= 1e-6 * fabs(J[0]),
        "gantry: cost multipliers %.12g vs null-space %.12g", J[0], J[1]);
}

/* Four particles in 2-D: A, B slow, C, D fast, springs A-B, B-C (slow)
 * and C-D (fast); no anchors, no gravity: only internal forces. */
static mrvi_model *four_particles(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double x[4][2] = {{0, 0}, {1, 0.2}, {1.0, 0.7}, {1.4, 0.9}};
  const double v[4][2] = {{0.1, 0.2}, {0, -0.1}, {0.3, 0}, {0, 0.2}};
  const double mass[4] = {1, 1.5, 0.2, 0.3};
  const char *names[4] = {"A", "B", "C", "D"};
  for (int i = 0; i < 4; i++)
    mrvi_model_add_particle(m, names[i], mass[i], i < 2 ? MRVI_SLOW : MRVI_FAST,
                            x[i], v[i]);
  const double k1[1] = {2.0}, k2[1] = {3.0}, k3[1] = {300.0};
  mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "linear", k1, 1.0);
  mrvi_model_add_spring(m, MRVI_SLOW, 1, 2, "linear", k2, 0.5);
  mrvi_model_add_spring(m, MRVI_FAST, 2, 3, "linear", k3, 0.4);
  return m;
}

/* Pair-force actuators (src/ocp/state_forces.c):
 * - adjoint gradients of the cost and the terminal constraints against
 *   central differences (relative 1e-6), every scheme, p in {1, 5}, pairs
 *   slow-slow (macro grid), fast-fast (micro), slow-fast (macro, micro);
 * - internal forces: total linear and angular momentum constant at every
 *   macro node (the discrete pair force depends on the relative position
 *   only and is rotation invariant), while the motion does change;
 * - two free particles moving along their line: the direction is constant,
 *   so the momenta are exactly p_0 -+ u t_k e. */
/* The four particles with four pair actuators (slow-slow, fast-fast,
 * slow-fast on both grids), tracking and terminal conditions. */
static mrvi_ocp *pair_problem(mrvi_model *m, const mrvi_settings *s) {
  mrvi_ocp *o = create_problem(m, s);
  if (!o)
    return NULL;
  int a = mrvi_ocp_add_pair_actuator(o, 0, 1, MRVI_GRID_MACRO, 1.0, -HUGE_VAL,
                                     HUGE_VAL);
  a |= mrvi_ocp_add_pair_actuator(o, 2, 3, MRVI_GRID_MICRO, 2.0, -HUGE_VAL,
                                  HUGE_VAL);
  a |= mrvi_ocp_add_pair_actuator(o, 1, 2, MRVI_GRID_MACRO, 0.5, -HUGE_VAL,
                                  HUGE_VAL);
  a |= mrvi_ocp_add_pair_actuator(o, 3, 0, MRVI_GRID_MICRO, 1.5, -HUGE_VAL,
                                  HUGE_VAL);
  CHECK(a >= 0, "pair actuators: %s", mrvi_ocp_errmsg(o));
  mrvi_ocp_add_tracking(o, 4, 3.0, 1.1);
  mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, 0, 0.1, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 7, 0.2, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, 5, 0.3, 0.0);
  mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 3, 0.1, 5.0);
  return o;
}

static void test_pair_actuators(void) {
  const char *const *schemes = mrvi_scheme_names();
  const int ps[2] = {1, 5};
  for (int is = 0; schemes[is]; is++)
    for (int ip = 0; ip < 2; ip++) {
      mrvi_model *m = four_particles();
      mrvi_settings s = test_settings(schemes[is], 0.05, ps[ip], 0.2, 1e-13);
      mrvi_settings sg = s;
      sg.solver = MRVI_SOLVER_GENERAL;
      mrvi_ocp *o = pair_problem(m, &s), *og = pair_problem(m, &sg);
      int st = o ? 0 : MRVI_EINVAL;
      if (o && og) {
        char what[100], why[300];
        mrvi_fmt(what, sizeof what, "pair %s p=%d", schemes[is], ps[ip]);
        /* the integrator's path where it is a Newton path on the CSC
         * assembly (the model's own choice: schur on midpoint-midpoint),
         * else general */
        const char *ip_path = mrvi_solver_path(m, &s, NULL, 0);
        const char *path = mrvi_ocp_solver_path(o, why, sizeof why);
        const int newton = ip_path && (!strcmp(ip_path, "schur") ||
                                       !strcmp(ip_path, "schur-bordered"));
        CHECK(path && ip_path && !strcmp(path, newton ? ip_path : "general") &&
                  (strcmp(schemes[is], "midpoint-midpoint") ||
                   !strcmp(path, "schur")),
              "%s: path %s (%s), the integrator's %s", what,
              path ? path : "none", why, ip_path ? ip_path : "none");
        check_gradients(o, what);
        test_ocp_same_forward(o, og, m->n, what, 0.5, 1e-10);
        /* Momentum maps at every macro node. */
        const int n = mrvi_ocp_n_controls(o);
        double *u = malloc((size_t)n * sizeof *u), J;
        for (int i = 0; i < n; i++)
          u[i] = 2.0 * sin(0.9 * i + 0.4);
        st = mrvi_ocp_evaluate(o, u, &J, NULL, NULL, NULL);
        double P0[3], L0[3], P[3], L[3], dP = 0.0, dL = 0.0, moved = 0.0;
        const double *q = mrvi_ocp_q(o), *pm = mrvi_ocp_p(o);
        const long N = mrvi_ocp_n_steps(o);
        mrvi_model_momentum(m, q, pm, P0, L0);
        for (long k = 1; st == 0 && k <= N; k++) {
          mrvi_model_momentum(m, q + 8 * k, pm + 8 * k, P, L);
          dP = fmax(dP, fmax(fabs(P[0] - P0[0]), fabs(P[1] - P0[1])));
          dL = fmax(dL, fabs(L[0] - L0[0]));
        }
        /* The same run without the forces differs: they act. */
        double *qf = malloc((size_t)(8 * (N + 1)) * sizeof *qf);
        memcpy(qf, q, (size_t)(8 * (N + 1)) * sizeof *qf);
        for (int i = 0; i < n; i++)
          u[i] = 0.0;
        st |= mrvi_ocp_evaluate(o, u, &J, NULL, NULL, NULL);
        for (long j = 0; j < 8 * (N + 1); j++)
          moved = fmax(moved, fabs(qf[j] - mrvi_ocp_q(o)[j]));
        CHECK(st == 0 && dP <= 1e-12 && dL <= 1e-12 && moved > 1e-3,
              "%s: internal pair forces: |P - P0| %.2e, |L - L0| %.2e, "
              "effect %.2e",
              what, dP, dL, moved);
        free(qf);
        free(u);
      }
      CHECK(st == 0, "pair problem %s p=%d: %s", schemes[is], ps[ip],
            o ? mrvi_ocp_errmsg(o) : "not created");
      mrvi_ocp_free(o);
      mrvi_ocp_free(og);
      mrvi_model_free(m);
    }
  /* Two free slow particles on the x axis, pushed apart by u. */
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double xa[2] = {0, 0}, xb[2] = {1, 0}, va[2] = {0.1, 0},
               vb[2] = {-0.2, 0};
  mrvi_model_add_particle(m, "a", 1.0, MRVI_SLOW, xa, va);
  mrvi_model_add_particle(m, "b", 2.0, MRVI_SLOW, xb, vb);
  mrvi_settings s = test_settings("midpoint-midpoint", 0.1, 3, 1.0, 1e-13);
  mrvi_ocp *o = NULL;
  char msg[300];
  if (mrvi_ocp_create(m, &s, &o, msg, sizeof msg) == 0 &&
      mrvi_ocp_add_pair_actuator(o, 0, 1, MRVI_GRID_MACRO, 1.0, -HUGE_VAL,
                                 HUGE_VAL) >= 0) {
    const double uc = 0.3;
    double u[10], J, err = 0.0;
    for (int i = 0; i < 10; i++)
      u[i] = uc;
    const int st = mrvi_ocp_evaluate(o, u, &J, NULL, NULL, NULL);
    for (long k = 0; st == 0 && k <= 10; k++) {
      const double *p = mrvi_ocp_p(o) + 4 * k, t = 0.1 * k;
      err = fmax(err, fabs(p[0] - (0.1 - uc * t)));
      err = fmax(err, fabs(p[2] - (-0.4 + uc * t)));
      err = fmax(err, fmax(fabs(p[1]), fabs(p[3])));
    }
    CHECK(st == 0 && err <= 1e-13,
          "pair force along the line: max |p - (p0 -+ u t e)| = %.2e", err);
  } else {
    CHECK(0, "pair line: %s", o ? mrvi_ocp_errmsg(o) : msg);
  }
  /* Errors: the same particle twice, an index out of range. */
  if (o) {
    CHECK(mrvi_ocp_add_pair_actuator(o, 1, 1, MRVI_GRID_MACRO, 1.0, -1, 1) ==
                  MRVI_EINVAL &&
              strstr(mrvi_ocp_errmsg(o), "twice"),
          "pair actuator on one particle: %s", mrvi_ocp_errmsg(o));
    CHECK(mrvi_ocp_add_pair_actuator(o, 0, 5, MRVI_GRID_MACRO, 1.0, -1, 1) ==
                  MRVI_EINVAL &&
              strstr(mrvi_ocp_errmsg(o), "out of range"),
          "pair actuator on particle 5: %s", mrvi_ocp_errmsg(o));
  }
  mrvi_ocp_free(o);
  mrvi_model_free(m);
}

/* Fast micro nodes of the shooting trajectory (mrvi_ocp_micro_q/p, written
 * to /micro): with zero controls they equal the integrator's micro nodes
 * (every scheme, FPU, p = 5) to the Newton tolerance; under a constant
 * force u on a free fast coordinate (grid micro or macro) the discrete
 * momentum at micro node j is exactly p_0 + u j dt, which needs the
 * f^+ of the micro interval ending at the node. */
static void test_micro_nodes(void) {
  const char *const *schemes = mrvi_scheme_names();
  const int p = 5;
  for (int is = 0; schemes[is]; is++) {
    mrvi_model *m = test_fpu();
    mrvi_settings s = test_settings(schemes[is], 0.03, p, 0.3, 1e-13);
    mrvi_ocp *o = NULL;
    mrvi_integrator *it = NULL;
    char msg[300];
    int st = mrvi_ocp_create(m, &s, &o, msg, sizeof msg);
    if (st == 0)
      st = mrvi_integrator_create(m, &s, &it, msg, sizeof msg);
    CHECK(st == 0, "micro %s: create: %s", schemes[is], msg);
    if (st == 0) {
      mrvi_ocp_add_actuator(o, 3, MRVI_GRID_MICRO, 1.0, -HUGE_VAL, HUGE_VAL);
      double *u = calloc((size_t)mrvi_ocp_n_controls(o), sizeof *u), J;
      st = mrvi_ocp_evaluate(o, u, &J, NULL, NULL, NULL);
      CHECK(st == 0, "micro %s: evaluate: %s", schemes[is], mrvi_ocp_errmsg(o));
      const int nf = m->n_fast;
      double eq = 0.0, ep = 0.0;
      for (long k = 0; st == 0 && k < mrvi_ocp_n_steps(o); k++) {
        if ((st = mrvi_integrator_step(it)) < 0)
          break;
        const double *iq = mrvi_integrator_micro_q(it),
                     *ip = mrvi_integrator_micro_p(it);
        const double *oq = mrvi_ocp_micro_q(o) + (k * p + 1) * nf,
                     *op = mrvi_ocp_micro_p(o) + (k * p + 1) * nf;
        for (int i = 0; i < p * nf; i++) {
          eq = fmax(eq, fabs(iq[i] - oq[i]));
          ep = fmax(ep, fabs(ip[i] - op[i]));
        }
      }
      CHECK(st == 0 && eq <= 1e-11 && ep <= 1e-9,
            "micro %s: OCP vs integrator at u = 0: q %.2e, p %.2e", schemes[is],
            eq, ep);
      free(u);
    }
    mrvi_integrator_free(it);
    mrvi_ocp_free(o);
    mrvi_model_free(m);
  }
  /* Constant force on a free fast coordinate. */
  for (int grid = 0; grid < 2; grid++) {
    mrvi_model *m = mrvi_model_create();
    mrvi_model_add_coordinate(m, "x", 1.0, MRVI_SLOW, 0.0, 0.0);
    mrvi_model_add_coordinate(m, "y", 0.3, MRVI_FAST, 0.1, -0.4);
    mrvi_settings s = test_settings("midpoint-midpoint", 0.1, p, 1.0, 1e-13);
    mrvi_ocp *o = NULL;
    char msg[300];
    int st = mrvi_ocp_create(m, &s, &o, msg, sizeof msg);
    CHECK(st == 0, "constant force: create: %s", msg);
    if (st == 0) {
      mrvi_ocp_add_actuator(o, 1, grid ? MRVI_GRID_MACRO : MRVI_GRID_MICRO, 1.0,
                            -HUGE_VAL, HUGE_VAL);
      const int n = mrvi_ocp_n_controls(o);
      const double uc = 0.7, p0 = 0.3 * -0.4, dt = 0.1 / p;
      double *u = malloc((size_t)n * sizeof *u), J, err = 0.0;
      for (int i = 0; i < n; i++)
        u[i] = uc;
      st = mrvi_ocp_evaluate(o, u, &J, NULL, NULL, NULL);
      const long nm = mrvi_ocp_n_steps(o) * p + 1;
      for (long j = 0; st == 0 && j < nm; j++)
        err = fmax(err, fabs(mrvi_ocp_micro_p(o)[j] - (p0 + uc * j * dt)));
      CHECK(st == 0 && err <= 1e-13,
            "constant force, %s grid: max |p_j - (p_0 + u j dt)| = %.2e",
            grid ? "macro" : "micro", err);
      free(u);
    }
    mrvi_ocp_free(o);
    mrvi_model_free(m);
  }
}

/* Dataset `name` (e.g. /macro/q) of an output file (malloc'ed, *n
 * entries) or NULL. */
static double *read_dataset(const char *path, const char *name, size_t *n) {
  hid_t f = H5Fopen(path, H5F_ACC_RDONLY, H5P_DEFAULT);
  if (f < 0)
    return NULL;
  hid_t d = H5Dopen2(f, name, H5P_DEFAULT);
  double *q = NULL;
  if (d >= 0) {
    hid_t sp = H5Dget_space(d);
    *n = (size_t)H5Sget_simple_extent_npoints(sp);
    q = malloc(*n * sizeof *q);
    if (q &&
        H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, q) < 0) {
      free(q);
      q = NULL;
    }
    H5Sclose(sp);
    H5Dclose(d);
  }
  H5Fclose(f);
  return q;
}

/* Root string attribute name of the HDF5 file path into out ("" if
 * missing). */
static void read_root_string(const char *path, const char *name, char *out,
                             size_t len) {
  out[0] = 0;
  hid_t f = H5Fopen(path, H5F_ACC_RDONLY, H5P_DEFAULT);
  if (f < 0)
    return;
  hid_t a = H5Aexists(f, name) > 0 ? H5Aopen(f, name, H5P_DEFAULT) : -1;
  if (a >= 0) {
    hid_t t = H5Aget_type(a);
    const size_t n = H5Tget_size(t);
    if (n < len && H5Aread(a, t, out) >= 0)
      out[n] = 0;
    H5Tclose(t);
    H5Aclose(a);
  }
  H5Fclose(f);
}

/* The step solver path of the forward pass in `mrvi optimize`'s summary
 * and in the root attribute "solver" of its output: schur for the double
 * integrator (midpoint-midpoint), sweep with explicit-slow, general for the
 * constrained gantry crane. */
static void test_cli_path(void) {
  const char *bin = getenv("MRVI_BIN");
  if (!bin)
    return;
  const struct {
    const char *file, *extra, *path;
  } cases[] = {
      {"systems/ocp_double_integrator.yaml", "", "schur"},
      {"systems/ocp_double_integrator.yaml",
       "--set integrator.scheme=explicit-slow", "sweep"},
      {"systems/ocp_gantry_crane.yaml", "", "schur-bordered"},
      {"systems/ocp_gantry_crane.yaml",
       "--set integrator.constraints.form=null-space", "general"},
  };
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    char cmd[2048], attr[64];
    snprintf(cmd, sizeof cmd,
             "%s optimize %s -q -o test_ocp_path.h5 %s 2>&1 | grep -q "
             "'^  solver path  *%s ('",
             bin, test_source_path(cases[i].file), cases[i].extra,
             cases[i].path);
    const int st = system(cmd);
    read_root_string("test_ocp_path.h5", "solver", attr, sizeof attr);
    CHECK(WIFEXITED(st) && WEXITSTATUS(st) == 0 &&
              strcmp(attr, cases[i].path) == 0,
          "mrvi optimize %s %s: summary without 'solver path %s' (exit %d) "
          "or attribute solver '%s'",
          cases[i].file, cases[i].extra, cases[i].path,
          WIFEXITED(st) ? WEXITSTATUS(st) : -1, attr);
  }
  remove("test_ocp_path.h5");
}

/* `mrvi optimize` on the shipped problems: exit 0 at the optimum, 2 when
 * the optimiser stops before the terminal conditions hold, 1 for bad
 * input. */
static void test_cli(void) {
  const char *bin = getenv("MRVI_BIN");
  if (!bin) {
    CHECK(0, "MRVI_BIN not set");
    return;
  }
  struct {
    const char *file, *extra;
    int rc;
  } cases[] = {
      {"systems/ocp_double_integrator.yaml", "", 0},
      {"systems/ocp_gantry_crane.yaml", "", 0},
      {"systems/ocp_gantry_crane.yaml",
       "--set integrator.constraints.form=null-space", 0},
      {"systems/ocp_gantry_crane.yaml",
       "--set control.solver.max_evaluations=2", 2},
      {"tests/bad_input/control_bounds.yaml", "", 1},
  };
  for (size_t i = 0; i < sizeof cases / sizeof cases[0]; i++) {
    char cmd[2048];
    snprintf(cmd, sizeof cmd,
             "%s optimize %s -q -o test_ocp_cli.h5 %s "
             ">/dev/null 2>&1",
             bin, test_source_path(cases[i].file), cases[i].extra);
    const int st = system(cmd);
    const int rc = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
    CHECK(rc == cases[i].rc, "mrvi optimize %s %s: exit %d, expected %d",
          cases[i].file, cases[i].extra, rc, cases[i].rc);
  }
  remove("test_ocp_cli.h5");
  /* Replay: the stored optimal controls through `mrvi run --controls`
   * (multiplier form, and the null-space form for the same controls)
   * reproduce the optimised trajectory and meet the terminal conditions. */
  const char *crane = test_source_path("systems/ocp_gantry_crane.yaml");
  char cmd[2048];
  snprintf(cmd, sizeof cmd,
           "%s optimize %s -q -o test_ocp_opt.h5 >/dev/null 2>&1", bin, crane);
  int st = system(cmd);
  CHECK(WIFEXITED(st) && WEXITSTATUS(st) == 0, "optimize for replay");
  const char *extra[2] = {"", "--set integrator.constraints.form=null-space"};
  for (int i = 0; i < 2; i++) {
    snprintf(cmd, sizeof cmd,
             "%s run %s --controls test_ocp_opt.h5 -o test_ocp_replay.h5 %s "
             ">/dev/null 2>&1",
             bin, crane, extra[i]);
    st = system(cmd);
    CHECK(WIFEXITED(st) && WEXITSTATUS(st) == 0, "replay %s: exit %d", extra[i],
          WIFEXITED(st) ? WEXITSTATUS(st) : -1);
    /* Macro nodes and the fast coordinates at every micro node (/micro,
     * written by the same writer as `mrvi run`), to the Newton tolerance
     * 1e-12 of the file (momenta: M/dt = 10 times that). */
    const char *names[3] = {"/macro/q", "/micro/q_fast", "/micro/p_fast"};
    const double tols[3] = {1e-10, 1e-10, 1e-9};
    for (int d = 0; d < 3; d++) {
      size_t na = 0, nb = 0;
      double *a = read_dataset("test_ocp_opt.h5", names[d], &na);
      double *b = read_dataset("test_ocp_replay.h5", names[d], &nb);
      double diff = a && b && na == nb && na > 0 ? 0.0 : HUGE_VAL;
      for (size_t j = 0; a && b && j < na && j < nb; j++)
        diff = fmax(diff, fabs(a[j] - b[j]));
      CHECK(diff <= tols[d], "replay %s: %s: max |replay - optimum| = %.2e",
            extra[i], names[d], diff);
      free(a);
      free(b);
    }
    /* 40 steps, p = 5: 201 micro nodes of the one fast particle (x, y). */
    size_t nq = 0;
    double *mq = read_dataset("test_ocp_opt.h5", "/micro/q_fast", &nq);
    CHECK(nq == 201 * 2,
          "optimize: /micro/q_fast has %zu entries, 402 "
          "expected",
          nq);
    free(mq);
  }
  remove("test_ocp_opt.h5");
  remove("test_ocp_replay.h5");
}

/* CPU time of this thread (a loaded machine preempts the longer
 * evaluation more often than the short forward run: wall-clock ratios
 * grew 4-fold at load 7 on 2 cores). */
static double thread_time(void) {
  struct timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Cost of the adjoint: one cost+gradient evaluation (forward sweep plus
 * the backward sweep for the cost and two constraints) against the forward
 * sweep alone, FPU with p = 1 and 10, N = 60, midpoint-midpoint (forward on
 * the schur path).  Target <= 3: 1.3-2.5 with the general path's forward,
 * 6-8 with the schur path's while the adjoint factorised every step with
 * UMFPACK, 2.6-3.3 with the dense LU backend (doc/optimal-control.md);
 * asserted <= 20 so that sanitizer builds pass while a sweep that is not
 * linear in N fails. */
static void test_adjoint_cost(void) {
  const int ps[2] = {1, 10};
  for (int ip = 0; ip < 2; ip++) {
    mrvi_model *m = test_fpu();
    mrvi_settings s =
        test_settings("midpoint-midpoint", 0.1, ps[ip], 6.0, 1e-11);
    mrvi_ocp *o = NULL;
    char msg[300];
    if (mrvi_ocp_create(m, &s, &o, msg, sizeof msg) != 0) {
      CHECK(0, "create: %s", msg);
      mrvi_model_free(m);
      return;
    }
    mrvi_ocp_add_actuator(o, 0, MRVI_GRID_MACRO, 1.0, -HUGE_VAL, HUGE_VAL);
    mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, 0, 0.0, 0.0);
    mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, 0, 0.0, 0.0);
    const int n = mrvi_ocp_n_controls(o);
    double *u = calloc((size_t)n, sizeof *u), *g = calloc((size_t)n, sizeof *g);
    double *cg = calloc((size_t)(2 * n), sizeof *cg), c[2], J;
    double tf = 1e30, ta = 1e30;
    for (int r = 0; r < 5; r++) {
      double t0 = thread_time();
      mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL);
      tf = fmin(tf, thread_time() - t0);
      t0 = thread_time();
      mrvi_ocp_evaluate(o, u, &J, g, c, cg);
      ta = fmin(ta, thread_time() - t0);
    }
    CHECK(ta <= 20.0 * tf,
          "FPU p=%d N=60: cost+gradient %.3g ms = %.2f x forward %.3g ms",
          ps[ip], 1e3 * ta, ta / tf, 1e3 * tf);
    free(u);
    free(g);
    free(cg);
    mrvi_ocp_free(o);
    mrvi_model_free(m);
  }
}

/* The forward pass of o equals that of og (the same problem on the
 * general path) at the same controls: cost and terminal constraints to
 * 1e-10 relative to their scale (the Newton tolerance 1e-13 times the
 * condition of the step maps). */
static void check_against_general(mrvi_ocp *o, mrvi_ocp *og, const char *what) {
  const int n = mrvi_ocp_n_controls(o), nc = mrvi_ocp_n_constraints(o);
  double *u = malloc((size_t)n * sizeof *u);
  double *c = calloc((size_t)nc + 1, sizeof *c);
  double *cg = calloc((size_t)nc + 1, sizeof *cg), J = NAN, Jg = NAN;
  for (int i = 0; i < n; i++)
    u[i] = 0.4 * cos(0.9 * i + 0.2);
  const int st = mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL) |
                 mrvi_ocp_evaluate(og, u, &Jg, NULL, cg, NULL);
  double err = fabs(J - Jg) / fabs(Jg);
  for (int i = 0; i < nc; i++)
    err = fmax(err, fabs(c[i] - cg[i]) / fmax(1.0, fabs(cg[i])));
  CHECK(st == 0 && err <= 1e-10,
        "%s: against the general path: status %d, difference %.3e", what, st,
        err);
  free(u);
  free(c);
  free(cg);
}

/* The FPU with, if quartic, a quartic term added to the fast potential W
 * (non-linear micro steps on the sweep path). */
static mrvi_model *fpu_model(int quartic) {
  mrvi_model *m = test_fpu();
  if (quartic) {
    const int c = 4;
    const double one = 1.0, pw[2] = {40.0, 4.0};
    mrvi_model_add_term(m, MRVI_FAST, 1, &c, &one, 0.0, "power", pw);
  }
  return m;
}

/* The forward pass takes the integrator's step solver path (explicit,
 * sweep with linear and with Newton micro steps, schur, general on
 * request), control forces included: on each, p in {1, 5}, the adjoint
 * gradients of the cost and of every terminal constraint match central
 * differences (relative 1e-6), and cost and constraints equal the general
 * path's at the same controls to 1e-10 (relative to their scale: the
 * Newton tolerance 1e-13 times the condition of the step maps). */
static void test_paths(void) {
  static const struct {
    const char *scheme, *path;
    int quartic, general;
  } cases[] = {{"fully-explicit", "explicit", 0, 0},
               {"explicit-slow", "sweep", 0, 0},
               {"explicit-slow", "sweep", 1, 0},
               {"midpoint-midpoint", "schur", 1, 0},
               {"trapezoidal-midpoint", "general", 1, 1}};
  const int ps[2] = {1, 5};
  for (size_t ic = 0; ic < sizeof cases / sizeof cases[0]; ic++)
    for (int ip = 0; ip < 2; ip++) {
      mrvi_model *m = fpu_model(cases[ic].quartic);
      mrvi_settings s =
          test_settings(cases[ic].scheme, 0.03, ps[ip], 0.12, 1e-13);
      if (cases[ic].general)
        s.solver = MRVI_SOLVER_GENERAL;
      mrvi_settings sg = s;
      sg.solver = MRVI_SOLVER_GENERAL;
      mrvi_ocp *o = fpu_problem(m, &s), *og = fpu_problem(m, &sg);
      char what[120];
      mrvi_fmt(what, sizeof what, "paths: FPU%s %s p=%d",
               cases[ic].quartic ? " (quartic W)" : "", cases[ic].scheme,
               ps[ip]);
      if (o && og) {
        char why[300];
        const char *path = mrvi_ocp_solver_path(o, why, sizeof why);
        CHECK(path && strcmp(path, cases[ic].path) == 0,
              "%s: path %s (%s), expected %s", what, path ? path : "none", why,
              cases[ic].path);
        check_gradients(o, what);
        check_against_general(o, og, what);
      }
      mrvi_ocp_free(o);
      mrvi_ocp_free(og);
      mrvi_model_free(m);
    }
}

/* The iterative paths (blocks beyond the dense limit 64): a slow mass
 * coupled by a quartic spring to the first of 65 fast oscillators joined
 * by quartic springs.  explicit-slow takes sweep-cg (micro steps by CG),
 * midpoint-midpoint schur-krylov (GMRES on the slow unknowns); p in
 * {1, 5}, actuators on the slow mass (macro grid), a fast node (micro
 * grid) and a fast node on the macro grid; the adjoint gradients match
 * central differences (1e-6) and the forward pass the general path's
 * (1e-10). */
static void test_paths_iterative(void) {
  const char *schemes[2] = {"explicit-slow", "midpoint-midpoint"};
  const char *paths[2] = {"sweep-cg", "schur-krylov"};
  const int ps[2] = {1, 5}, nf = 65;
  for (int is = 0; is < 2; is++)
    for (int ip = 0; ip < 2; ip++) {
      mrvi_model *m = mrvi_model_create();
      mrvi_model_add_coordinate(m, "x", 1.0, MRVI_SLOW, 0.1, 0.5);
      for (int i = 0; i < nf; i++) {
        char name[16];
        mrvi_fmt(name, sizeof name, "y%d", i);
        mrvi_model_add_coordinate(m, name, 0.5, MRVI_FAST, 0.01 * sin(i),
                                  0.2 * cos(i));
      }
      const double pw[2] = {0.25, 4.0}, k[1] = {0.5 * 400.0}, one = 1.0;
      const double a2[2] = {1.0, -1.0};
      const int xs[2] = {0, 1};
      mrvi_model_add_term(m, MRVI_SLOW, 2, xs, a2, 0.0, "power", pw);
      for (int i = 1; i <= nf; i++) {
        mrvi_model_add_term(m, MRVI_FAST, 1, &i, &one, 0.0, "linear", k);
        const int c[2] = {i + 1, i};
        if (i < nf)
          mrvi_model_add_term(m, MRVI_FAST, 2, c, a2, 0.0, "power", pw);
      }
      mrvi_settings s = test_settings(schemes[is], 0.05, ps[ip], 0.15, 1e-13);
      mrvi_settings sg = s;
      sg.solver = MRVI_SOLVER_GENERAL;
      mrvi_ocp *o = NULL, *og = NULL;
      char msg[300], what[100];
      mrvi_fmt(what, sizeof what, "paths: 65 fast oscillators %s p=%d",
               schemes[is], ps[ip]);
      const int st = mrvi_ocp_create(m, &s, &o, msg, sizeof msg) |
                     mrvi_ocp_create(m, &sg, &og, msg, sizeof msg);
      CHECK(st == 0, "%s: create: %s", what, msg);
      for (int j = 0; st == 0 && j < 2; j++) {
        mrvi_ocp *q = j ? og : o;
        mrvi_ocp_add_actuator(q, 0, MRVI_GRID_MACRO, 1.0, -HUGE_VAL, HUGE_VAL);
        mrvi_ocp_add_actuator(q, 4, MRVI_GRID_MICRO, 2.0, -HUGE_VAL, HUGE_VAL);
        mrvi_ocp_add_actuator(q, 40, MRVI_GRID_MACRO, 0.5, -HUGE_VAL, HUGE_VAL);
        mrvi_ocp_add_tracking(q, 2, 3.0, 0.05);
        mrvi_ocp_add_terminal(q, MRVI_OCP_POSITION, 0, 0.3, 0.0);
        mrvi_ocp_add_terminal(q, MRVI_OCP_VELOCITY, 1, 0.0, 0.0);
        mrvi_ocp_add_terminal(q, MRVI_OCP_POSITION, 40, 0.0, 0.0);
      }
      if (st == 0) {
        char why[300];
        const char *path = mrvi_ocp_solver_path(o, why, sizeof why);
        CHECK(path && strcmp(path, paths[is]) == 0,
              "%s: path %s (%s), expected %s", what, path ? path : "none", why,
              paths[is]);
        check_gradients(o, what);
        check_against_general(o, og, what);
      }
      mrvi_ocp_free(o);
      mrvi_ocp_free(og);
      mrvi_model_free(m);
    }
}

/* The lattice problem of bench_ocp --lattice at 200 coordinates (10 x 10
 * particles, every second column fast: 100 slow, 100 fast), N = 10, with
 * midpoint-midpoint (schur-krylov), explicit-slow (sweep-cg) and
 * fully-explicit (explicit): the adjoint's transposed step solves on the
 * schur-krylov elimination run backwards give the gradients of the sparse
 * LU's (tuning.adjoint_krylov = 0) to 1e-8 relative, at two controls in
 * turn, with no fallback to the LU; and central differences (1e-6). */
static const char *lattice_format =
    "name: lattice_ocp\ndimension: 2\n"
    "generate:\n"
    "  - {kind: lattice2d, name: p, count: [%d, %d], spacing: 1.0, mass: 1.0,\n"
    "     rates: {every: %d}, slow_spring: {law: linear, stiffness: 10},\n"
    "     fast_spring: {law: linear, stiffness: %g},\n"
    "     initial: [{index: [%d, 2], displacement: [%g, %g],\n"
    "                velocity: [0.0, 0.5]}]}\n"
    "integrator: {scheme: midpoint-midpoint, macro_step: 0.05, micro_steps: "
    "10, t_end: 0.5,\n  newton: {tolerance: 1e-12}}\n"
    "control:\n"
    "  actuators:\n"
    "    - {name: push, coordinate: p0_0.x, grid: macro, weight: 1}\n"
    "  tracking:\n"
    "    - {coordinate: p1_1.y, weight: 1, reference: 0}\n"
    "  terminal:\n"
    "    - {coordinate: p0_0.x, position: 0.2, velocity: 0}\n";

/* The lattice's text: 10 x 10 particles, every second one slow, fast
 * springs of stiffness 1000, particle (i = 2, 2) displaced by
 * (dx, dy) = (0.1, 0.05); lattice_set changes these (lattice_set(0, ...):
 * back to them). */
static char lattice_text[1024];
static void lattice_set(int count, int every, double fast_k, int j, double dx,
                        double dy) {
  if (count == 0)
    lattice_set(10, 2, 1000.0, 2, 0.1, 0.05);
  else
    snprintf(lattice_text, sizeof lattice_text, lattice_format, count, count,
             every, fast_k, j, dx, dy);
}

/* A lattice OCP loaded two ways (way 0 with the first n_common overrides,
 * way 1 with n_extra more), way 0's path checked, and the gradients of
 * both at two controls in turn (g[w]: len entries); the largest
 * difference of the two ways' gradients and way 1's largest entry. */
typedef struct two_way {
  mrvi_system *sys[2];
  mrvi_ocp *o[2];
  double *u[2], *g[2];
  int n, nm, len;
} two_way;

static int two_way_gradients(two_way *tw, const char *label, const char **ov,
                             int n_common, int n_extra, const char *path_want) {
  char msg[2048];
  int st = 0;
  memset(tw, 0, sizeof *tw);
  for (int w = 0; w < 2 && st == 0; w++) {
    st = mrvi_system_load_string(lattice_text, "lattice.yaml", ov,
                                 n_common + w * n_extra, &tw->sys[w], msg,
                                 sizeof msg);
    if (st == 0)
      st = mrvi_ocp_load(tw->sys[w], &tw->o[w], &tw->u[w], msg, sizeof msg);
    CHECK(st == 0, "%s: load: %s", label, msg);
  }
  if (st != 0)
    return st;
  const char *path = mrvi_ocp_solver_path(tw->o[0], NULL, 0);
  CHECK(path && strcmp(path, path_want) == 0, "%s: path %s, expected %s", label,
        path ? path : "none", path_want);
  const int n = tw->n = mrvi_ocp_n_controls(tw->o[0]);
  const int nm = tw->nm = mrvi_ocp_n_constraints(tw->o[0]);
  tw->len = 2 * n * (1 + nm);
  for (int w = 0; w < 2 && st == 0; w++) {
    tw->g[w] = calloc((size_t)tw->len, sizeof *tw->g[w]);
    for (int t = 0; t < 2 && st == 0; t++) {
      for (int i = 0; i < n; i++)
        tw->u[w][i] = 0.5 * sin(0.7 * i + t);
      st = gradients_at(tw->o[w], tw->u[w], tw->g[w] + t * n * (1 + nm));
    }
    CHECK(st == 0, "%s: way %d: %s", label, w, mrvi_ocp_errmsg(tw->o[w]));
  }
  return st;
}

static void two_way_diff(const two_way *tw, double *err, double *sc) {
  *err = *sc = 0.0;
  for (int i = 0; i < tw->len; i++) {
    *err = fmax(*err, fabs(tw->g[0][i] - tw->g[1][i]));
    *sc = fmax(*sc, fabs(tw->g[1][i]));
  }
}

static void two_way_free(two_way *tw) {
  for (int w = 0; w < 2; w++) {
    free(tw->g[w]);
    free(tw->u[w]);
    mrvi_ocp_free(tw->o[w]);
    mrvi_system_free(tw->sys[w]);
  }
}

static void adjoint_krylov_scheme(const char *scheme, const char *path_want) {
  char sch[64];
  snprintf(sch, sizeof sch, "integrator.scheme=%s", scheme);
  /* (fully-explicit: the assembled adjoint, not adjoint_explicit.c's) */
  const char *ov[3] = {sch, "integrator.tuning.adjoint_explicit=0",
                       "integrator.tuning.adjoint_krylov=0"};
  char label[96];
  snprintf(label, sizeof label, "adjoint krylov, %s", scheme);
  two_way tw;
  if (two_way_gradients(&tw, label, ov, 2, 1, path_want) != 0)
    goto out;
  mrvi_ocp **o = tw.o;
  const int nm = tw.nm;
  double err, sc;
  two_way_diff(&tw, &err, &sc);
  CHECK(sc > 0.0 && err <= 1e-8 * sc,
        "adjoint krylov, %s: gradients differ from the LU's by %.3e (scale "
        "%.3e)",
        scheme, err, sc);
  /* 2 evaluations of N = 10 steps, 2 functionals each */
  CHECK(o[0]->adjoint_krylov_solves == 2 * 10 * (1 + nm) &&
            o[0]->adjoint_krylov_fallbacks == 0 &&
            o[1]->adjoint_krylov_solves == 0,
        "adjoint krylov, %s: %ld solves, %ld fallbacks (LU way: %ld solves)",
        scheme, o[0]->adjoint_krylov_solves, o[0]->adjoint_krylov_fallbacks,
        o[1]->adjoint_krylov_solves);
  char what[96];
  snprintf(what, sizeof what, "adjoint krylov: lattice 200, %s", scheme);
  check_gradients(o[0], what);
out:
  two_way_free(&tw);
}

static void test_adjoint_krylov(void) {
  adjoint_krylov_scheme("midpoint-midpoint", "schur-krylov");
  adjoint_krylov_scheme("explicit-slow", "sweep-cg");
  adjoint_krylov_scheme("fully-explicit", "explicit");
}

/* How explicit-slow's micro steps are expected to be solved (sweep-cg):
 * by the forest alone, unless the overrides turn it off (then the CG
 * alone); MICRO_CG: by the CG alone (no forest). */
enum { MICRO_FOREST, MICRO_CG };
static int micro_want = MICRO_FOREST;

/* The explicit paths' adjoint (ocp/adjoint_explicit.c: the recursion run
 * backwards with Hessian-vector products) against the transposed step
 * solves of the assembled step Jacobian (tuning.adjoint_explicit = 0, with
 * the sparse LU: adjoint_krylov = 0) on the lattice of 200 coordinates,
 * at two controls in turn: the same gradients to 1e-12 relative on the
 * explicit path (no iteration) and on sweep-cg where its micro steps are
 * solved by elimination along the lattice's fast chains (adjoint_forest),
 * 1e-11 where by the CG (adjoint_forest = 0, or no kept blocks: at
 * adjoint_krylov_rtol = 1e-10); and central differences (1e-6).
 * fully-explicit at p = 10 and p = 1 (velocity Verlet; dT = 0.025, away
 * from its stability limit, where the differences lose digits), the
 * macro-grid V with alpha = 0.3 beside the fast rule alpha = 0.7,
 * gamma = 0 (weights differing at every node); explicit-slow at p = 10
 * and p = 1, and with two points per micro interval (alpha = 0.4,
 * gamma = 0.3). */

static void adjoint_explicit_variant(const char *what, const char *scheme,
                                     const char *path_want, double tol,
                                     const char *ov1, const char *ov2) {
  char sch[64];
  snprintf(sch, sizeof sch, "integrator.scheme=%s", scheme);
  const char *ov[5] = {sch};
  int n_ov = 1;
  if (ov1)
    ov[n_ov++] = ov1;
  if (ov2)
    ov[n_ov++] = ov2;
  ov[n_ov] = "integrator.tuning.adjoint_explicit=0";
  ov[n_ov + 1] = "integrator.tuning.adjoint_krylov=0";
  char label[160];
  snprintf(label, sizeof label, "adjoint explicit, %s", what);
  two_way tw;
  if (two_way_gradients(&tw, label, ov, n_ov, 2, path_want) != 0)
    goto out;
  mrvi_ocp **o = tw.o;
  CHECK(o[0]->adj_explicit == 1 && o[1]->adj_explicit == 0,
        "adjoint explicit, %s: taken %d, reference %d", what,
        o[0]->adj_explicit, o[1]->adj_explicit);
  double err, sc;
  two_way_diff(&tw, &err, &sc);
  CHECK(sc > 0.0 && err <= tol * sc,
        "adjoint explicit, %s: gradients differ from the assembled "
        "adjoint's by %.3e (scale %.3e)",
        what, err, sc);
  /* explicit-slow's micro steps: by elimination along the lattice's
   * fast chains (tuning adjoint_forest), no CG; by the CG alone where
   * that is off (or the Hessian blocks are not kept) */
  if (strcmp(path_want, "sweep-cg") == 0) {
    const int cg = micro_want == MICRO_CG ||
                   (ov1 && strstr(ov1, "adjoint_forest=0")) ||
                   (ov2 && strstr(ov2, "adjoint_hessblocks=0"));
    const long nfo = o[0]->adjoint_forest_solves, ncg = o[0]->adjoint_cg_solves;
    CHECK(cg ? nfo == 0 && ncg > 0 : nfo > 0 && ncg == 0,
          "adjoint explicit, %s: %ld micro steps by the forest, %ld by the "
          "CG",
          what, nfo, ncg);
    printf("adjoint explicit, %s: %ld micro steps by the forest, %ld by the "
           "CG\n",
           what, nfo, ncg);
  }
  /* Nothing of an evaluation carries over into the next: the first
   * controls' gradients again after a value alone at the second, bitwise
   * the first's. */
  const int n = tw.n, len = n * (1 + tw.nm);
  double J, c[16], *g = calloc((size_t)len, sizeof *g);
  for (int i = 0; i < n; i++)
    tw.u[0][i] = 0.5 * sin(0.7 * i + 1);
  int st = mrvi_ocp_evaluate(o[0], tw.u[0], &J, NULL, c, NULL);
  for (int i = 0; i < n; i++)
    tw.u[0][i] = 0.5 * sin(0.7 * i);
  st = st ? st : gradients_at(o[0], tw.u[0], g);
  CHECK(st == 0 && g && memcmp(g, tw.g[0], (size_t)len * sizeof *g) == 0,
        "adjoint explicit, %s: the gradients again after a value alone: "
        "status %d, not the first's",
        what, st);
  free(g);
  char name[96];
  snprintf(name, sizeof name, "adjoint explicit: lattice 200, %s", what);
  check_gradients(o[0], name);
out:
  two_way_free(&tw);
}

static void test_adjoint_explicit(void) {
  const char *fe = "fully-explicit", *es = "explicit-slow";
  adjoint_explicit_variant("fully-explicit", fe, "explicit", 1e-12, NULL, NULL);
  adjoint_explicit_variant("fully-explicit, products", fe, "explicit", 1e-12,
                           "integrator.tuning.adjoint_hessblocks=0", NULL);
  adjoint_explicit_variant("fully-explicit, p = 1", fe, "explicit", 1e-12,
                           "integrator.micro_steps=1",
                           "integrator.macro_step=0.025");
  adjoint_explicit_variant("slow alpha 0.3, fast alpha 0.7 gamma 0", fe,
                           "explicit", 1e-12,
                           "integrator.slow={grid: macro, alpha: 0.3}",
                           "integrator.fast={alpha: 0.7, gamma: 0}");
  adjoint_explicit_variant("explicit-slow", es, "sweep-cg", 1e-12, NULL, NULL);
  adjoint_explicit_variant("explicit-slow, CG", es, "sweep-cg", 1e-11,
                           "integrator.tuning.adjoint_forest=0", NULL);
  adjoint_explicit_variant("explicit-slow, products", es, "sweep-cg", 1e-11,
                           "integrator.tuning.adjoint_one_point=0",
                           "integrator.tuning.adjoint_hessblocks=0");
  adjoint_explicit_variant("explicit-slow, p = 1", es, "sweep-cg", 1e-12,
                           "integrator.micro_steps=1",
                           "integrator.macro_step=0.025");
  adjoint_explicit_variant("explicit-slow, fast alpha 0.4 gamma 0.3", es,
                           "sweep-cg", 1e-12,
                           "integrator.fast={alpha: 0.4, gamma: 0.3}", NULL);
}

/* The fallbacks of explicit-slow's elimination along W's forest
 * (adjoint_explicit.c), each forced.  W's springs in cycles (9 x 9
 * particles, every third one slow: the fast ones in ladders of two
 * columns): no forest, every micro step by the CG, the gradients those of
 * the assembled adjoint and of central differences, as above.  A pivot of
 * the elimination not positive (stiff fast springs, 2.3e5, one compressed
 * by 0.3 along its fast column: K + c hess W indefinite on some micro
 * steps): that step goes to the CG, which needs a positive definite matrix
 * and (here, after some such steps) stops at non-positive curvature, so
 * the evaluation fails (MRVI_ESINGULAR, the micro step named) after the
 * forest took the steps before it, while the value alone is found; the
 * assembled adjoint (tuning adjoint_explicit = 0, the sparse LU) gives
 * finite gradients (not checked against central differences: at this
 * stiffness and h = 1e-5 they agree to 1e-6 relative only, 1.0e-6 on the
 * constraints; at 2.2e5, every pivot positive, to 2e-9). */
static void test_adjoint_forest_fallbacks(void) {
  const char *es = "explicit-slow";
  lattice_set(9, 3, 1000.0, 2, 0.1, 0.05);
  micro_want = MICRO_CG;
  adjoint_explicit_variant("explicit-slow, W in cycles", es, "sweep-cg", 1e-11,
                           NULL, NULL);
  micro_want = MICRO_FOREST;
  lattice_set(10, 2, 2.3e5, 3, 0.0, 0.3);
  const char *ov[3] = {"integrator.scheme=explicit-slow",
                       "integrator.tuning.adjoint_explicit=0",
                       "integrator.tuning.adjoint_krylov=0"};
  for (int w = 0; w < 2; w++) {
    char msg[2048];
    mrvi_system *sys = NULL;
    mrvi_ocp *o = NULL;
    double *u = NULL;
    int st = mrvi_system_load_string(lattice_text, "lattice.yaml", ov,
                                     w ? 3 : 1, &sys, msg, sizeof msg);
    if (st == 0)
      st = mrvi_ocp_load(sys, &o, &u, msg, sizeof msg);
    CHECK(st == 0, "forest pivot: load: %s", msg);
    if (st != 0)
      goto next;
    const int n = mrvi_ocp_n_controls(o), m = mrvi_ocp_n_constraints(o);
    double J, c[16], *g = calloc((size_t)n * (size_t)(1 + m), sizeof *g);
    for (int i = 0; i < n; i++)
      u[i] = 0.5 * sin(0.7 * i);
    st = mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL);
    CHECK(st == 0 && isfinite(J), "forest pivot, way %d: value: %s", w,
          mrvi_ocp_errmsg(o));
    st = mrvi_ocp_evaluate(o, u, &J, g, c, g + n);
    int finite = 1;
    for (int i = 0; i < n * (1 + m); i++)
      finite = finite && isfinite(g[i]);
    if (w == 1) {
      CHECK(st == 0 && finite, "forest pivot: the assembled adjoint: %s",
            mrvi_ocp_errmsg(o));
    } else {
      const char *em = mrvi_ocp_errmsg(o);
      printf("forest pivot: %ld micro steps by the forest, %ld by the CG, "
             "status %d: %s\n",
             o->adjoint_forest_solves, o->adjoint_cg_solves, st, em);
      CHECK(o->adj_explicit && st == MRVI_ESINGULAR &&
                strstr(em, "non-positive curvature") &&
                o->adjoint_forest_solves > 0 && o->adjoint_cg_solves >= 1,
            "forest pivot: status %d (%s), %ld forest, %ld CG solves", st, em,
            o->adjoint_forest_solves, o->adjoint_cg_solves);
    }
    free(g);
  next:
    free(u);
    mrvi_ocp_free(o);
    mrvi_system_free(sys);
  }
  lattice_set(0, 0, 0.0, 0, 0.0, 0.0);
}

/* The optimum found on the path chosen automatically equals the general
 * path's: the rest-to-rest double integrator beside a fast oscillator
 * (p = 5) reaches J_N = J* N^2/(N^2 - 1) to 1e-8 on the explicit, sweep and
 * schur paths, and the FPU problem's optimal controls agree with the
 * general path's to 1e-6 of their scale (SLSQP stops at ftol 1e-12). */
static void test_paths_optimum(void) {
  const double mass = 2.0, d = 1.0, T = 2.0;
  const int N = 10;
  const double JN =
      6.0 * mass * mass * d * d / (T * T * T) * N * N / (N * N - 1.0);
  const char *schemes[3] = {"fully-explicit", "explicit-slow",
                            "midpoint-midpoint"};
  const char *paths[3] = {"explicit", "sweep", "schur"};
  for (int is = 0; is < 3; is++) {
    mrvi_model *m = double_integrator(mass, 1);
    mrvi_settings s = test_settings(schemes[is], T / N, 5, T, 1e-12);
    const char *path = mrvi_solver_path(m, &s, NULL, 0);
    CHECK(path && strcmp(path, paths[is]) == 0, "double integrator %s: %s",
          schemes[is], path ? path : "none");
    const double J = rest_to_rest(m, &s, d, MRVI_OCP_SLSQP, NULL);
    CHECK(fabs(J - JN) <= 1e-8 * JN,
          "double integrator %s (%s path): J = %.15g, J_N = %.15g", schemes[is],
          paths[is], J, JN);
    mrvi_model_free(m);
  }
  for (int is = 0; is < 3; is++) {
    mrvi_model *m = fpu_model(1);
    mrvi_settings s = test_settings(schemes[is], 0.03, 5, 0.12, 1e-13);
    mrvi_settings sg = s;
    sg.solver = MRVI_SOLVER_GENERAL;
    mrvi_ocp *o = fpu_problem(m, &s), *og = fpu_problem(m, &sg);
    if (o && og) {
      const int n = mrvi_ocp_n_controls(o);
      double *u = calloc((size_t)n, sizeof *u), *ug = calloc((size_t)n, 8);
      mrvi_ocp_result r, rg;
      const int st = mrvi_ocp_solve(o, u, &r),
                stg = mrvi_ocp_solve(og, ug, &rg);
      double err = 0.0, sc = 0.0;
      for (int i = 0; i < n; i++) {
        err = fmax(err, fabs(u[i] - ug[i]));
        sc = fmax(sc, fabs(ug[i]));
      }
      CHECK(st == 0 && stg == 0 && err <= 1e-6 * sc &&
                fabs(r.cost - rg.cost) <= 1e-9 * fabs(rg.cost),
            "FPU %s optimum (%s path) against general: status %d/%d, "
            "max |du| %.3e (scale %.3e), cost %.15g / %.15g",
            schemes[is], paths[is], st, stg, err, sc, r.cost, rg.cost);
      free(u);
      free(ug);
    }
    mrvi_ocp_free(o);
    mrvi_ocp_free(og);
    mrvi_model_free(m);
  }
}

/* Paths of the general kind: a constrained model in the null-space form
 * (the multiplier form takes schur-bordered, test_bordered), pair
 * actuators, and integrator.solver = structured where no structured path
 * applies. */
static void test_paths_general(void) {
  mrvi_model *m = test_cart_pendulum();
  mrvi_settings s = test_settings("explicit-slow", 0.01, 5, 0.04, 1e-13);
  s.constraint_form = MRVI_FORM_NULL_SPACE;
  mrvi_ocp *o = NULL;
  char msg[300], why[300];
  if (mrvi_ocp_create(m, &s, &o, msg, sizeof msg) == 0) {
    mrvi_ocp_add_actuator(o, 0, MRVI_GRID_MACRO, 1.0, -HUGE_VAL, HUGE_VAL);
    const char *path = mrvi_ocp_solver_path(o, why, sizeof why);
    CHECK(path && strcmp(path, "general") == 0 && strstr(why, "null-space"),
          "cart pendulum, null-space form: path %s (%s)", path ? path : "none",
          why);
  }
  mrvi_ocp_free(o);
  /* integrator.solver = structured: the evaluation fails with the reason. */
  s.solver = MRVI_SOLVER_STRUCTURED;
  o = NULL;
  if (mrvi_ocp_create(m, &s, &o, msg, sizeof msg) == 0) {
    mrvi_ocp_add_actuator(o, 0, MRVI_GRID_MACRO, 1.0, -HUGE_VAL, HUGE_VAL);
    double u[4] = {0, 0, 0, 0}, J;
    CHECK(mrvi_ocp_solver_path(o, NULL, 0) == NULL, "structured: a path");
    const int st = mrvi_ocp_evaluate(o, u, &J, NULL, NULL, NULL);
    CHECK(st == MRVI_EINVAL &&
              strstr(mrvi_ocp_errmsg(o), "integrator.solver = structured") &&
              strstr(mrvi_ocp_errmsg(o), "null-space"),
          "structured on a constrained model: status %d, '%s'", st,
          mrvi_ocp_errmsg(o));
  }
  mrvi_ocp_free(o);
  mrvi_model_free(m);
  /* Pair actuators on a model the integrator steps by the sweep. */
  m = four_particles();
  s = test_settings("explicit-slow", 0.05, 5, 0.2, 1e-13);
  o = NULL;
  if (mrvi_ocp_create(m, &s, &o, msg, sizeof msg) == 0) {
    const char *ip = mrvi_solver_path(m, &s, NULL, 0);
    mrvi_ocp_add_pair_actuator(o, 0, 1, MRVI_GRID_MACRO, 1.0, -HUGE_VAL,
                               HUGE_VAL);
    const char *path = mrvi_ocp_solver_path(o, why, sizeof why);
    CHECK(ip && strcmp(ip, "general") != 0 && path &&
              strcmp(path, "general") == 0 && strstr(why, "pair actuators"),
          "pair actuators: integrator path %s, problem path %s (%s)",
          ip ? ip : "none", path ? path : "none", why);
  }
  mrvi_ocp_free(o);
  mrvi_model_free(m);
}

/* The redundancy check of terminal equalities (ocp_terminal_redundant) on
 * a long rigid truss: a 2-D ladder of K cells (bottom b_i = (i, 0), top
 * t_i = (i, 1); rods b_i t_i, b_i b_i+1, t_i t_i+1 and the diagonal
 * b_i t_i+1), 3 degrees of freedom.  With b_K-1's x and y and t_K-1's x
 * given at one end, b_0's y at the other end, K cells away, is implied (the
 * rank test must see the whole truss, not the coordinates the condition
 * touches), for positions and for velocities; without the diagonal of the
 * middle cell (4 degrees of freedom) it is not.  K = 120: 480 coordinates,
 * 477 rows. */
static void test_redundant_truss(void) {
  enum { K = 120 };
  for (int broken = 0; broken < 2; broken++) {
    mrvi_model *m = mrvi_model_create();
    mrvi_model_set_dimension(m, 2);
    for (int i = 0; i < K; i++)
      for (int top = 0; top < 2; top++) {
        const double x[2] = {1.0 * i, 1.0 * top}, v[2] = {0.0, 0.0};
        char name[16];
        snprintf(name, sizeof name, "%c%d", top ? 't' : 'b', i);
        mrvi_model_add_particle(m, name, 1.0 + 0.5 * top, MRVI_SLOW, x, v);
      }
    for (int i = 0; i < K; i++) {
      mrvi_model_add_distance(m, 2 * i, 2 * i + 1, NAN);
      if (i + 1 < K) {
        mrvi_model_add_distance(m, 2 * i, 2 * i + 2, NAN);
        mrvi_model_add_distance(m, 2 * i + 1, 2 * i + 3, NAN);
        if (!broken || i != K / 2)
          mrvi_model_add_distance(m, 2 * i, 2 * i + 3, NAN);
      }
    }
    CHECK(mrvi_model_constraint_rows(m) == 4 * K - 3 - broken, "truss rows %d",
          mrvi_model_constraint_rows(m));
    mrvi_settings s;
    mrvi_settings_default(&s);
    mrvi_ocp *o = create_problem(m, &s);
    if (!o) {
      mrvi_model_free(m);
      continue;
    }
    const int bx = 4 * (K - 1), by = bx + 1, tx = bx + 2, b0y = 1;
    const mrvi_ocp_terminal_kind kinds[2] = {MRVI_OCP_POSITION,
                                             MRVI_OCP_VELOCITY};
    for (int k = 0; k < 2; k++) {
      const int c[3] = {bx, by, tx};
      for (int j = 0; j < 3; j++) {
        const int st = mrvi_ocp_add_terminal(o, kinds[k], c[j], 0.0, 0.0);
        CHECK(st == (3 + broken) * k + j,
              "truss (broken %d), %s %d: accepted (%d: %s)", broken,
              k ? "velocity" : "position", j, st, mrvi_ocp_errmsg(o));
      }
      const int st = mrvi_ocp_add_terminal(o, kinds[k], b0y, 0.0, 0.0);
      if (broken)
        CHECK(st == 4 * k + 3,
              "truss without a diagonal: the far %s condition is free (%d: "
              "%s)",
              k ? "velocity" : "position", st, mrvi_ocp_errmsg(o));
      else
        CHECK(st < 0 && strstr(mrvi_ocp_errmsg(o), "implied"),
              "rigid truss: the far %s condition is implied (%d: %s)",
              k ? "velocity" : "position", st, mrvi_ocp_errmsg(o));
    }
    CHECK(mrvi_ocp_n_constraints(o) == 6 + 2 * broken, "truss: %d conditions",
          mrvi_ocp_n_constraints(o));
    mrvi_ocp_free(o);
    mrvi_model_free(m);
  }
}

int main(void) {
  lattice_set(0, 0, 0.0, 0, 0.0, 0.0);
  test_gradients();
  test_gradients_constrained();
  test_adjoint_ways();
  test_bordered();
  test_double_integrator();
  test_oscillator_period();
  test_dmoc_reference();
  test_gantry();
  test_micro_nodes();
  test_pair_actuators();
  test_cli();
  test_cli_path();
  test_adjoint_cost();
  test_paths();
  test_paths_iterative();
  test_adjoint_krylov();
  test_adjoint_explicit();
  test_adjoint_forest_fallbacks();
  test_paths_optimum();
  test_paths_general();
  test_redundant_truss();
  return test_finish();
}
