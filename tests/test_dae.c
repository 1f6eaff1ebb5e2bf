/* Constrained integration (doc/constraints.md): the multiplier and null-space
 * forms against an independent constrained midpoint integrator, against each
 * other, conservation laws, residuals and convergence order. */
#include "models.h"
#include "step/step.h"
#include "testlib.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---------------------------------------------------------------------------
 * Independent constrained midpoint variational integrator for the cart
 * pendulum (p = 1): L_d = h [T((q1-q0)/h) - V((q0+q1)/2)], action term
 * -h lambda^T c(q0), constraints c = (z_cart, |x_cart - x_bob|^2 - L^2)
 * (the same manifold as mrvi's g, different scaling):
 *   p0 - M (q1-q0)/h - (h/2) dV - h C(q0)^T lambda = 0,  c(q1) = 0,
 *   p1 = M (q1-q0)/h - (h/2) dV.
 * Solved by Newton with a finite-difference Jacobian on (q1, lambda).
 * ------------------------------------------------------------------------- */
static const double cp_mass[6] = {5, 5, 5, 0.5, 0.5, 0.5};

static void cp_constraints(const double *q, double L, double *c,
                           double C[2][6]) {
  double d[3];
  for (int a = 0; a < 3; a++)
    d[a] = q[a] - q[3 + a];
  c[0] = q[2];
  c[1] = d[0] * d[0] + d[1] * d[1] + d[2] * d[2] - L * L;
  memset(C, 0, 2 * 6 * sizeof(double));
  C[0][2] = 1.0;
  for (int a = 0; a < 3; a++) {
    C[1][a] = 2 * d[a];
    C[1][3 + a] = -2 * d[a];
  }
}

static void cp_residual(const double *q0, const double *p0, double h, double L,
                        const double *u, double *F) {
  const double *q1 = u, *lam = u + 6;
  double c[2], C0[2][6], C1[2][6];
  cp_constraints(q0, L, c, C0);
  for (int i = 0; i < 6; i++) {
    const double dV = (i == 2 || i == 5) ? cp_mass[i] * 9.81 : 0.0;
    F[i] = p0[i] - cp_mass[i] * (q1[i] - q0[i]) / h - 0.5 * h * dV -
           h * (C0[0][i] * lam[0] + C0[1][i] * lam[1]);
  }
  cp_constraints(q1, L, c, C1);
  F[6] = c[0];
  F[7] = c[1];
}

static void cp_step(double *q, double *p, double h, double L, double *lam) {
  double u[8], F[8], Fp[8], J[64];
  for (int i = 0; i < 6; i++)
    u[i] = q[i] + h * p[i] / cp_mass[i];
  u[6] = lam[0];
  u[7] = lam[1];
  for (int it = 0; it < 50; it++) {
    cp_residual(q, p, h, L, u, F);
    double r = 0.0;
    for (int i = 0; i < 8; i++)
      r = fmax(r, fabs(F[i]));
    if (r < 1e-13)
      break;
    for (int j = 0; j < 8; j++) {
      const double e = 1e-7 * fmax(1.0, fabs(u[j]));
      const double s = u[j];
      u[j] = s + e;
      cp_residual(q, p, h, L, u, Fp);
      u[j] = s;
      for (int i = 0; i < 8; i++)
        J[i * 8 + j] = (Fp[i] - F[i]) / e;
    }
    mrvi_dense_solve(8, J, F);
    for (int i = 0; i < 8; i++)
      u[i] -= F[i];
  }
  for (int i = 0; i < 6; i++) {
    const double dV = (i == 2 || i == 5) ? cp_mass[i] * 9.81 : 0.0;
    p[i] = cp_mass[i] * (u[i] - q[i]) / h - 0.5 * h * dV;
    q[i] = u[i];
  }
  lam[0] = u[6];
  lam[1] = u[7];
}

static void test_cart_pendulum_midpoint(void) {
  mrvi_model *m = test_cart_pendulum();
  const double h = 0.01, L = 0.2;
  for (int proj = 0; proj <= 1; proj++) {
    mrvi_settings s = test_settings("midpoint-midpoint", h, 1, 1.0, 1e-12);
    s.constraint_tol = 1e-13;
    s.project_momenta = proj;
    mrvi_integrator *it = NULL;
    char msg[512];
    CHECK(mrvi_integrator_create(m, &s, &it, msg, sizeof msg) == 0, "%s", msg);
    if (!it)
      break;
    double q[6], p[6], lam[2] = {0, 0};
    memcpy(q, mrvi_integrator_q(it), sizeof q);
    memcpy(p, mrvi_integrator_p(it), sizeof p);
    double dq = 0.0, dp = 0.0, qmax = 0.0, pmax = 0.0;
    for (int k = 0; k < 200; k++) {
      if (mrvi_integrator_step(it) != 0) {
        CHECK(0, "step %d: %s", k, mrvi_integrator_errmsg(it));
        break;
      }
      cp_step(q, p, h, L, lam);
      const double *qi = mrvi_integrator_q(it), *pi = mrvi_integrator_p(it);
      for (int i = 0; i < 6; i++) {
        dq = fmax(dq, fabs(qi[i] - q[i]));
        dp = fmax(dp, fabs(pi[i] - p[i]));
        qmax = fmax(qmax, fabs(q[i]));
        pmax = fmax(pmax, fabs(p[i]));
      }
      if (proj) /* the reference's p is not projected: follow mrvi's */
        memcpy(p, pi, sizeof p);
    }
    CHECK(dq <= 1e-10 * fmax(qmax, 1.0),
          "cart pendulum p = 1 (projection %d): max |q - q_ref| = %.3e", proj,
          dq);
    if (!proj)
      CHECK(dp <= 1e-10 * fmax(pmax, 1.0),
            "cart pendulum p = 1: max |p - p_ref| = %.3e", dp);
    mrvi_integrator_free(it);
  }
  mrvi_model_free(m);
}

/* Run a model and keep every macro q and the worst constraint residual at
 * the enforced nodes. */
typedef struct run_data {
  long n;
  int dim;
  double *q;
  double cres;   /* max over records of the micro-node residuals */
  double hidden; /* max hidden residual */
  double H0, dH;
  double P0[3], L0[3], dP[3], dL[3];
} run_data;

static int collect(void *user, const mrvi_record *r) {
  run_data *d = user;
  const int n = d->dim;
  memcpy(d->q + r->k * n, r->q, (size_t)n * sizeof(double));
  d->n = r->k + 1;
  for (int j = 0; j < r->micro_count; j++)
    d->cres = fmax(d->cres, r->micro_constraint_residual[j]);
  d->hidden = fmax(d->hidden, r->hidden_constraint_residual);
  if (r->k == 0) {
    d->H0 = r->energy;
    memcpy(d->P0, r->linear_momentum, sizeof d->P0);
    memcpy(d->L0, r->angular_momentum, sizeof d->L0);
  }
  d->dH = fmax(d->dH, fabs(r->energy - d->H0));
  for (int a = 0; a < 3; a++) {
    d->dP[a] = fmax(d->dP[a], fabs(r->linear_momentum[a] - d->P0[a]));
    d->dL[a] = fmax(d->dL[a], fabs(r->angular_momentum[a] - d->L0[a]));
  }
  return 0;
}

static int run(const mrvi_model *m, const mrvi_settings *s, run_data *d) {
  memset(d, 0, sizeof *d);
  d->dim = mrvi_model_n(m);
  d->q = malloc((size_t)(mrvi_settings_n_steps(s) + 1) * (size_t)d->dim *
                sizeof(double));
  mrvi_summary sum;
  int st = mrvi_run(m, s, collect, d, NULL, &sum);
  CHECK(st == 0, "%s: run %s", mrvi_model_name(m),
        st ? sum.message : "completed");
  return st;
}

/* Energy error over the first and second halves of a run. */
static void energy_halves(const mrvi_model *m, const mrvi_settings *s) {
  mrvi_trajectory *tr = NULL;
  mrvi_summary sum;
  if (mrvi_trajectory_run(m, s, &tr, &sum) != 0) {
    CHECK(0, "energy run: %s", sum.message);
    return;
  }
  const int n = tr->n;
  double H0 = 0.0, e1 = 0.0, e2 = 0.0;
  for (long k = 0; k < tr->n_macro; k++) {
    double kin, vs, vf;
    mrvi_model_energy(m, tr->q + k * n, tr->p + k * n, &kin, &vs, &vf);
    const double H = kin + vs + vf;
    if (k == 0)
      H0 = H;
    if (k < tr->n_macro / 2)
      e1 = fmax(e1, fabs(H - H0));
    else
      e2 = fmax(e2, fabs(H - H0));
  }
  CHECK(e2 <= 1.5 * e1 && e1 <= 1e-3 * fabs(H0) + 1e-3,
        "energy error first half %.3e, second half %.3e (H0 = %.4f, %ld "
        "steps)",
        e1, e2, H0, tr->n_macro - 1);
  mrvi_trajectory_free(tr);
}

/* Both forms, both schemes, p in {1, 5}: the same trajectories, and the
 * constraint residual within the tolerance at every enforced node.  Both
 * by full Newton (reuse_rate = 0), so that the forms differ by the
 * round-off of the linear solves: schur-bordered's kept factors (the
 * multiplier form's default) stop a step below 0.01 tol where full Newton
 * lands at round-off, and the pendulum chain amplifies that 1e-12 in q
 * twenty-thousandfold in 50 steps (2.6e-8; test_torsion compares the kept
 * factors with full Newton). */
static void test_forms_agree(const char *label, mrvi_model *m, double dT,
                             double t_end) {
  const char *schemes[2] = {"midpoint-midpoint", "trapezoidal-midpoint"};
  const int ps[2] = {1, 5};
  for (int a = 0; a < 2; a++)
    for (int b = 0; b < 2; b++) {
      run_data d[2];
      for (int f = 0; f < 2; f++) {
        mrvi_settings s = test_settings(schemes[a], dT, ps[b], t_end, 1e-11);
        s.constraint_tol = 1e-11;
        s.tuning.reuse_rate = 0.0;
        s.constraint_form = f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
        run(m, &s, &d[f]);
        CHECK(d[f].cres <= s.constraint_tol,
              "%s %s p=%d %s: constraint residual %.2e at the enforced nodes",
              label, schemes[a], ps[b], f ? "null-space" : "multipliers",
              d[f].cres);
      }
      double diff = 0.0;
      for (long i = 0; i < d[0].n * d[0].dim && d[0].n == d[1].n; i++)
        diff = fmax(diff, fabs(d[0].q[i] - d[1].q[i]));
      CHECK(d[0].n == d[1].n && d[0].n > 1 && diff <= 1e-8,
            "%s %s p=%d: forms differ by %.2e over %ld nodes", label,
            schemes[a], ps[b], diff, d[0].n);
      free(d[0].q);
      free(d[1].q);
    }
}

/* Cart pendulum, p = 5: horizontal momentum and angular momentum about e3
 * conserved to the Newton tolerance (discrete Noether: L_d and the
 * constraints are invariant), energy error bounded without drift, hidden
 * constraint met when momenta are projected. */
static void test_conservation(void) {
  mrvi_model *m = test_cart_pendulum();
  const double tol = 1e-10;
  for (int f = 0; f < 2; f++) {
    mrvi_settings s = test_settings("midpoint-midpoint", 0.02, 5, 100.0, tol);
    s.constraint_form = f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
    run_data d;
    if (run(m, &s, &d) != 0)
      continue;
    const char *form = f ? "null-space" : "multipliers";
    CHECK(d.dP[0] <= 10 * tol && d.dP[1] <= 10 * tol,
          "%s: horizontal momentum drift (%.2e, %.2e) over %ld steps", form,
          d.dP[0], d.dP[1], d.n - 1);
    CHECK(d.dL[2] <= 10 * tol, "%s: angular momentum about e3 drift %.2e", form,
          d.dL[2]);
    CHECK(d.hidden <= s.constraint_tol,
          "%s: hidden constraint |G M^-1 p| = %.2e with projection", form,
          d.hidden);
    free(d.q);
  }
  /* Energy: the error of the second half of a long run is no larger than
   * that of the first (no drift), and small. */
  mrvi_settings s = test_settings("midpoint-midpoint", 0.02, 5, 200.0, tol);
  energy_halves(m, &s);
  mrvi_model_free(m);
}

/* Without projection the hidden constraint is O(dt) off; the trajectory is
 * the same (the shift is absorbed by the next multipliers). */
static void test_projection_is_output_only(void) {
  mrvi_model *m = test_cart_pendulum();
  run_data d[2];
  for (int proj = 0; proj < 2; proj++) {
    mrvi_settings s = test_settings("midpoint-midpoint", 0.02, 5, 2.0, 1e-12);
    s.project_momenta = proj;
    run(m, &s, &d[proj]);
  }
  double diff = 0.0;
  for (long i = 0; i < d[0].n * d[0].dim; i++)
    diff = fmax(diff, fabs(d[0].q[i] - d[1].q[i]));
  CHECK(diff <= 1e-10, "projection changes positions by %.2e", diff);
  CHECK(d[0].hidden > 1e-4 && d[1].hidden < 1e-12,
        "hidden constraint %.2e without projection, %.2e with", d[0].hidden,
        d[1].hidden);
  free(d[0].q);
  free(d[1].q);
  mrvi_model_free(m);
}

/* With projection, the fast momenta at interior micro nodes meet the
 * hidden constraint together with the step's slow velocity v_s:
 * G_s v_s + G_f M_f^-1 p_f = 0 (cart pendulum: cart slow, bob fast). */
static void test_micro_projection(void) {
  mrvi_model *m = test_cart_pendulum();
  mrvi_settings s = test_settings("midpoint-midpoint", 0.02, 5, 1.0, 1e-12);
  mrvi_integrator *it = NULL;
  char msg[512];
  if (mrvi_integrator_create(m, &s, &it, msg, sizeof msg) != 0) {
    CHECK(0, "%s", msg);
    mrvi_model_free(m);
    return;
  }
  double worst = 0.0;
  for (int k = 0; k < 20; k++) {
    double q0[6], q[6], p[6];
    memcpy(q0, mrvi_integrator_q(it), sizeof q0);
    mrvi_integrator_step(it);
    const double *q1 = mrvi_integrator_q(it);
    const double *mq = mrvi_integrator_micro_q(it);
    const double *mp = mrvi_integrator_micro_p(it);
    for (int mm = 1; mm < 5; mm++) {
      for (int a = 0; a < 3; a++) {
        q[a] = q0[a] + (q1[a] - q0[a]) * mm / 5.0; /* cart interpolated */
        p[a] = 5.0 * (q1[a] - q0[a]) / 0.02;       /* M_s v_s */
        q[3 + a] = mq[(mm - 1) * 3 + a];
        p[3 + a] = mp[(mm - 1) * 3 + a];
      }
      worst = fmax(worst, mrvi_model_hidden_residual(m, q, p));
    }
  }
  CHECK(worst <= 1e-12, "hidden constraint at interior micro nodes %.2e",
        worst);
  mrvi_integrator_free(it);
  mrvi_model_free(m);
}

/* Multipliers reported per step are consistent: for the rod coupling the
 * slow cart and the fast bob, the step averages at p = 1, 5, 10 agree to
 * O(dT), while the node-0 values of p > 1 carry the cart's kick. */
static void test_multiplier_consistency(void) {
  mrvi_model *m = test_cart_pendulum();
  const int ps[3] = {1, 5, 10};
  double lam[3][2];
  for (int a = 0; a < 3; a++) {
    mrvi_settings s =
        test_settings("midpoint-midpoint", 0.0025, ps[a], 0.5, 1e-11);
    mrvi_integrator *it = NULL;
    char msg[512];
    if (mrvi_integrator_create(m, &s, &it, msg, sizeof msg) != 0) {
      CHECK(0, "%s", msg);
      return;
    }
    for (int k = 0; k < 200; k++)
      mrvi_integrator_step(it);
    memcpy(lam[a], mrvi_integrator_lambda(it), sizeof lam[a]);
    mrvi_integrator_free(it);
  }
  for (int a = 1; a < 3; a++) {
    CHECK(fabs(lam[a][1] - lam[0][1]) <= 0.02 * fabs(lam[0][1]),
          "rod multiplier p = %d: %.6f vs p = 1: %.6f", ps[a], lam[a][1],
          lam[0][1]);
    CHECK(fabs(lam[a][0] - lam[0][0]) <= 0.01 * fabs(lam[0][0]),
          "plane multiplier p = %d: %.6f vs p = 1: %.6f", ps[a], lam[a][0],
          lam[0][0]);
  }
  /* The plane carries the weight of cart and bob, (5 + 0.5) 9.81, up to
   * the bob's vertical acceleration. */
  CHECK(fabs(lam[0][0] + 5.5 * 9.81) < 3.0, "plane multiplier %.4f", lam[0][0]);
  mrvi_model_free(m);
}

/* Order 2 of midpoint-midpoint in q on macro nodes, p = 5 (fitted). */
static void test_convergence_order(void) {
  mrvi_model *m = test_cart_pendulum();
  mrvi_settings rs = test_settings("midpoint-midpoint", 1e-4, 1, 0.4, 1e-12);
  rs.constraint_tol = 1e-13;
  mrvi_trajectory *ref = NULL;
  mrvi_summary sum;
  if (mrvi_trajectory_run(m, &rs, &ref, &sum) != 0) {
    CHECK(0, "reference: %s", sum.message);
    mrvi_model_free(m);
    return;
  }
  const double steps[4] = {0.04, 0.02, 0.01, 0.005};
  double lx[4], ly[4];
  for (int i = 0; i < 4; i++) {
    mrvi_settings s =
        test_settings("midpoint-midpoint", steps[i], 5, 0.4, 1e-12);
    s.constraint_tol = 1e-13;
    mrvi_trajectory *tr = NULL;
    mrvi_errors e;
    char msg[256];
    CHECK(mrvi_trajectory_run(m, &s, &tr, &sum) == 0, "%s", sum.message);
    CHECK(tr && mrvi_trajectory_errors(m, tr, ref, &e, msg, sizeof msg) == 0,
          "%s", msg);
    lx[i] = log(steps[i]);
    ly[i] = log(e.q_mac);
    mrvi_trajectory_free(tr);
  }
  /* Least-squares slope of log error against log dT. */
  double mx = 0, my = 0, sxy = 0, sxx = 0;
  for (int i = 0; i < 4; i++)
    mx += lx[i] / 4, my += ly[i] / 4;
  for (int i = 0; i < 4; i++)
    sxy += (lx[i] - mx) * (ly[i] - my), sxx += (lx[i] - mx) * (lx[i] - mx);
  const double order = sxy / sxx;
  CHECK(fabs(order - 2.0) <= 0.25,
        "cart pendulum, midpoint-midpoint p = 5: order in q %.3f (errors "
        "%.2e .. %.2e)",
        order, exp(ly[0]), exp(ly[3]));
  mrvi_trajectory_free(ref);
  mrvi_model_free(m);
}

/* Redundant constraints: the multiplier form refuses them and names them;
 * the null-space form leaves the redundant row out (doc/constraints.md) and
 * gives the trajectory of the model without it. */
static void test_redundant(void) {
  mrvi_model *m = test_cart_pendulum(), *ref = test_cart_pendulum();
  const int z[1] = {2};
  const double one[1] = {1.0};
  mrvi_model_add_linear_constraint(m, 1, z, one, 0.0); /* z_cart = 0 again */
  mrvi_settings s = test_settings("midpoint-midpoint", 0.02, 5, 1.0, 1e-10);
  mrvi_integrator *it = NULL;
  char msg[512] = "";
  int st = mrvi_integrator_create(m, &s, &it, msg, sizeof msg);
  CHECK(st == MRVI_ESINGULAR && strstr(msg, "plane cart") &&
            strstr(msg, "linear on cart.z") && strstr(msg, "null-space"),
        "redundant constraints named (%d): %s", st, msg);
  mrvi_integrator_free(it);
  s.constraint_form = MRVI_FORM_NULL_SPACE;
  mrvi_trajectory *a = NULL, *b = NULL;
  mrvi_summary sum;
  st = mrvi_trajectory_run(m, &s, &a, &sum);
  CHECK(st == 0, "redundant constraints, null-space form: %s", sum.message);
  if (st == 0 && mrvi_trajectory_run(ref, &s, &b, &sum) == 0) {
    double d = 0.0;
    for (long i = 0; i < a->n_macro * a->n; i++)
      d = fmax(d, fabs(a->q[i] - b->q[i]));
    CHECK(d < 1e-12, "redundant row left out: trajectories differ by %.3g", d);
  }
  mrvi_trajectory_free(a);
  mrvi_trajectory_free(b);
  mrvi_model_free(m);
  mrvi_model_free(ref);
}

/* Two micro-node constraints whose fast parts are dependent (qf = qs1 and
 * qf = qs2): the full gradients are independent, so the multiplier form
 * integrates it, while the null-space form, which eliminates the
 * multipliers through the fast rows, refuses it with a message. */
static void test_null_space_limit(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_add_coordinate(m, "qs1", 1.0, MRVI_SLOW, 0.5, 0.1);
  mrvi_model_add_coordinate(m, "qs2", 2.0, MRVI_SLOW, 0.5, -0.2);
  mrvi_model_add_coordinate(m, "qf", 0.1, MRVI_FAST, 0.5, 0.0);
  const double k[1] = {4.0};
  const double one = 1.0;
  for (int i = 0; i < 2; i++)
    mrvi_model_add_term(m, MRVI_SLOW, 1, &i, &one, 0.0, "linear", k);
  const int c1[2] = {2, 0}, c2[2] = {2, 1};
  const double a[2] = {1.0, -1.0};
  mrvi_model_add_linear_constraint(m, 2, c1, a, 0.0);
  mrvi_model_add_linear_constraint(m, 2, c2, a, 0.0);
  mrvi_model_project_velocities(m, NULL);
  mrvi_settings s = test_settings("midpoint-midpoint", 0.05, 1, 2.0, 1e-11);
  run_data d;
  if (run(m, &s, &d) == 0) {
    CHECK(d.cres <= s.constraint_tol, "multiplier form: residual %.2e", d.cres);
    /* All three move together: qs1 = qs2 = qf, one oscillator of mass 3.1
     * and stiffness 8; energy conserved up to the midpoint error. */
    CHECK(fabs(d.q[d.n * 3 - 3] - d.q[d.n * 3 - 1]) <= 1e-10,
          "qs1 = qf at the end (%g, %g)", d.q[d.n * 3 - 3], d.q[d.n * 3 - 1]);
    free(d.q);
  }
  s.constraint_form = MRVI_FORM_NULL_SPACE;
  mrvi_integrator *it = NULL;
  char msg[512] = "";
  int st = mrvi_integrator_create(m, &s, &it, msg, sizeof msg);
  CHECK(st < 0 && strstr(msg, "null-space form") &&
            strstr(msg, "use form: multipliers"),
        "null-space form refuses dependent fast parts (%d): %s", st, msg);
  mrvi_integrator_free(it);
  /* p > 1: qs1 = qs2 would be enforced at every micro node on their
   * interpolation, p conditions on one node: refused by both forms. */
  s.micro_steps = 4;
  for (int f = 0; f < 2; f++) {
    s.constraint_form = f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
    it = NULL;
    st = mrvi_integrator_create(m, &s, &it, msg, sizeof msg);
    CHECK(st == MRVI_ESINGULAR && strstr(msg, "linear on qf, ...") &&
              strstr(msg, "dependent through their fast coordinates"),
          "p = 4: micro-node constraints over-constrain the slow motion "
          "(%d): %s",
          st, msg);
    mrvi_integrator_free(it);
  }
  mrvi_model_free(m);
}

/* The saddle-point Jacobian of the constrained step (doc/constraints.md), with
 * nonzero multipliers so that the -h sum lambda_i d2g_i terms count, against
 * central differences of the residual. */
static void test_step_jacobian(const char *label, mrvi_model *m,
                               const char *scheme, int p) {
  mrvi_settings s = test_settings(scheme, 0.02, p, 1.0, 1e-10);
  mrvi_step st;
  CHECK(mrvi_step_init(&st, m, &s) == 0, "step init");
  const int ns = mrvi_model_n_slow(m), nf = mrvi_model_n_fast(m),
            nt = st.n_total;
  double qs0[64], ps0[64], qf0[64], pf0[64];
  const double *q0 = mrvi_model_q0(m), *v0 = mrvi_model_v0(m);
  for (int i = 0; i < ns; i++) {
    const int j = mrvi_model_slow_index(m)[i];
    qs0[i] = q0[j];
    ps0[i] = mrvi_model_mass(m, j) * v0[j];
  }
  for (int i = 0; i < nf; i++) {
    const int j = mrvi_model_fast_index(m)[i];
    qf0[i] = q0[j];
    pf0[i] = mrvi_model_mass(m, j) * v0[j];
  }
  st.qs0 = qs0, st.qf0 = qf0, st.ps0 = ps0, st.pf0 = pf0;
  double *x = calloc((size_t)nt, sizeof *x), *R = calloc((size_t)nt, sizeof *R);
  /* Free flight plus a perturbation; multipliers of order one. */
  for (int i = 0; i < ns; i++)
    x[i] = qs0[i] + 0.02 * v0[mrvi_model_slow_index(m)[i]] + 1e-3 * (i % 3);
  for (int k = 1; k <= p; k++)
    for (int i = 0; i < nf; i++)
      x[ns + (k - 1) * nf + i] =
          qf0[i] + 0.02 * k / p * v0[mrvi_model_fast_index(m)[i]] -
          1e-3 * ((i + k) % 2);
  for (int i = st.n_unknowns; i < nt; i++)
    x[i] = 1.0 + 0.5 * (i % 3);
  CHECK(mrvi_step_build_pattern(&st, x) == 0, "pattern");
  mrvi_step_assemble(&st, x, R, 1);
  double scale;
  const double worst = test_step_fd_error(&st, x, &scale);
  CHECK(worst <= 1e-6 * scale,
        "%s %s p=%d: constrained Jacobian vs FD, max error %.2e (scale "
        "%.2e, %d unknowns incl. %d multipliers)",
        label, scheme, p, worst, scale, nt, st.n_lambda);
  free(x), free(R);
  mrvi_step_free(&st);
}

int main(void) {
  {
    mrvi_model *cp = test_cart_pendulum(), *sr = test_spring_ring_rod();
    for (int p = 1; p <= 3; p += 2) {
      test_step_jacobian("cart pendulum", cp, "midpoint-midpoint", p);
      test_step_jacobian("cart pendulum", cp, "trapezoidal-midpoint", p);
      test_step_jacobian("spring ring rod", sr, "midpoint-midpoint", p);
    }
    mrvi_model_free(cp);
    mrvi_model_free(sr);
  }
  test_null_space_limit();
  test_conservation();
  test_projection_is_output_only();
  test_micro_projection();
  test_multiplier_consistency();
  test_convergence_order();
  test_redundant();
  test_cart_pendulum_midpoint();
  mrvi_model *cp = test_cart_pendulum();
  test_forms_agree("cart pendulum", cp, 0.02, 2.0);
  mrvi_model_free(cp);
  mrvi_model *sr = test_spring_ring_rod();
  test_forms_agree("spring ring rod", sr, 0.01, 0.5);
  mrvi_model_free(sr);
  /* Every shipped constrained system, with its own macro step. */
  const char *systems[4] = {"cart_pendulum", "spring_ring_rod", "triatomic",
                            "pendulum_chain"};
  for (int i = 0; i < 4; i++) {
    char rel[128], msg[1024];
    snprintf(rel, sizeof rel, "systems/%s.yaml", systems[i]);
    mrvi_system *sys = NULL;
    if (mrvi_system_load(test_source_path(rel), NULL, 0, &sys, msg,
                         sizeof msg) != 0) {
      CHECK(0, "load %s: %s", rel, msg);
      continue;
    }
    const double dT = sys->settings.macro_step;
    test_forms_agree(systems[i], sys->model, dT, 50 * dT);
    mrvi_system_free(sys);
  }
  return test_finish();
}
