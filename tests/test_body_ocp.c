/* Optimal control on rigid bodies (src/ocp/state_forces.c,
 * src/ocp/body_terminal.c; doc/optimal-control.md, "Bodies"):
 * - adjoint gradients of the cost and of every terminal constraint against
 *   central differences (relative 1e-6) in both constraint forms: a free
 *   3-D body under torques in space and in the body frame and a force at a
 *   body point, with terminal attitude, angular velocity in space and (a
 *   penalty) in the body frame; a slow body on a revolute joint to the
 *   ground carrying a fast body on a second revolute joint (p = 3), with a
 *   joint torque on the micro grid and penalties on attitude and angular
 *   velocity (as equalities they repeat joint rows and are refused); a 2-D
 *   pendulum driven by a joint torque and a body torque;
 * - the terminal values: the attitude rows are the rotation vector of
 *   R_target^T R_N, the angular velocity rows J^-1 R^T L from the final
 *   momenta (computed here independently);
 * - a constant torque tau on a body at rest gives it the angular momentum
 *   tau T up to the truncation error;
 * - a 2-D pendulum brought to rest by a joint torque ends with a projected
 *   angular speed below the terminal tolerance (the condition is imposed on
 *   the projected momenta; on p_N itself it left -1.5 rad/s). */
#include "model/model.h"
#include "models.h"
#include "ocp/ocp.h"
#include "testlib.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static mrvi_settings settings(double dT, int p, double t_end,
                              mrvi_constraint_form form) {
  mrvi_settings s = test_settings("midpoint-midpoint", dT, p, t_end, 1e-13);
  s.constraint_form = form;
  s.constraint_tol = 1e-13;
  return s;
}

static const char *form_name(mrvi_constraint_form f) {
  return f == MRVI_FORM_NULL_SPACE ? "null-space" : "multipliers";
}

/* The gradients against central differences (testlib.h). */
static void check_gradients(mrvi_ocp *o, const char *what) {
  test_ocp_gradients(o, what, 0.4);
}

static mrvi_ocp *create(const mrvi_model *m, const mrvi_settings *s) {
  mrvi_ocp *o = NULL;
  char msg[300];
  const int st = mrvi_ocp_create(m, s, &o, msg, sizeof msg);
  CHECK(st == 0, "create: %s", msg);
  return st == 0 ? o : NULL;
}

/* ---------------------------------------------------------------------------
 * A free 3-D body.
 * ------------------------------------------------------------------------- */
static const double free_J[3] = {1.0, 2.0, 2.5};

static mrvi_model *free_body(const double *omega) {
  mrvi_model *m = mrvi_model_create();
  const double x0[3] = {0.1, -0.2, 0.3}, w[3] = {0.3, 0.4, -0.2};
  double R[9];
  test_rotation(w, 1.0, R);
  CHECK(mrvi_model_add_body(m, "B", 3, MRVI_SLOW, 2.0, free_J, x0, R, NULL,
                            omega) == 0,
        "free body: %s", mrvi_model_errmsg(m));
  return m;
}

static void test_free_body(mrvi_constraint_form form) {
  const double w0[3] = {0.4, -0.3, 0.8};
  mrvi_model *m = free_body(w0);
  const mrvi_settings s = settings(0.1, 1, 0.8, form);
  mrvi_ocp *o = create(m, &s);
  if (!o) {
    mrvi_model_free(m);
    return;
  }
  const double ax[3] = {0.3, -0.2, 1.0}, bx[3] = {1.0, 0.5, 0.0};
  const double at[3] = {0.2, 0.1, -0.3}, dir[3] = {0.0, 1.0, 0.5};
  const double wt[3] = {-0.5, 0.2, 0.9}, om[3] = {0.1, 0.0, -0.2};
  double Rt[9];
  test_rotation(wt, 1.0, Rt);
  CHECK(mrvi_ocp_add_torque_actuator(o, 0, ax, 0, MRVI_GRID_MACRO, 1.0,
                                     -HUGE_VAL, HUGE_VAL) == 0 &&
            mrvi_ocp_add_torque_actuator(o, 0, bx, 1, MRVI_GRID_MACRO, 2.0,
                                         -HUGE_VAL, HUGE_VAL) == 1 &&
            mrvi_ocp_add_body_force_actuator(o, 0, at, dir, MRVI_GRID_MACRO,
                                             1.0, -HUGE_VAL, HUGE_VAL) == 2 &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ATTITUDE, 0, Rt, 0.0) == 0 &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ANGULAR_VELOCITY, 0, om,
                                       0.0) == 3 &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ANGULAR_VELOCITY_BODY, 0, om,
                                       3.0) == 0,
        "free body actuators and terminals: %s", mrvi_ocp_errmsg(o));
  CHECK(!strcmp(mrvi_ocp_actuator_kind(o, 0), "torque") &&
            !strcmp(mrvi_ocp_actuator_kind(o, 2), "force") &&
            mrvi_ocp_actuator_body(o, 1) == 0 &&
            !strcmp(mrvi_ocp_actuator_name(o, 0), "B.torque"),
        "actuator kinds and names");
  char what[80];
  snprintf(what, sizeof what, "free body, torques and a force, %s",
           form_name(form));
  check_gradients(o, what);

  /* The terminal values against their definitions, computed here from the
   * trajectory of the last evaluation. */
  const int n = m->n, nc = mrvi_ocp_n_constraints(o);
  const double *q = mrvi_ocp_q(o) + mrvi_ocp_n_steps(o) * n;
  const double *p = mrvi_ocp_p(o) + mrvi_ocp_n_steps(o) * n;
  double c[6], u[24], J;
  for (int i = 0; i < mrvi_ocp_n_controls(o); i++)
    u[i] = 0.4 * sin(1.7 * i + 0.3);
  mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL);
  CHECK(nc == 6, "six constraint rows (got %d)", nc);
  /* A = Rt^T R, angle from the trace, axis from the skew part. */
  double A[9], L[3] = {0, 0, 0};
  for (int a = 0; a < 3; a++)
    for (int b = 0; b < 3; b++) {
      A[a * 3 + b] = 0.0;
      for (int j = 0; j < 3; j++)
        A[a * 3 + b] += Rt[j * 3 + a] * q[3 + 3 * b + j];
    }
  const double th = acos(0.5 * (A[0] + A[4] + A[8] - 1.0));
  const double v[3] = {th / (2 * sin(th)) * (A[7] - A[5]),
                       th / (2 * sin(th)) * (A[2] - A[6]),
                       th / (2 * sin(th)) * (A[3] - A[1])};
  for (int i = 0; i < 3; i++) {
    const double *d = q + 3 + 3 * i, *pd = p + 3 + 3 * i;
    L[0] += d[1] * pd[2] - d[2] * pd[1];
    L[1] += d[2] * pd[0] - d[0] * pd[2];
    L[2] += d[0] * pd[1] - d[1] * pd[0];
  }
  double ev = 0.0, ew = 0.0;
  for (int a = 0; a < 3; a++) {
    double w = 0.0; /* omega = R J^-1 R^T L */
    for (int r = 0; r < 3; r++) {
      const double *dr = q + 3 + 3 * r;
      w += dr[a] * (dr[0] * L[0] + dr[1] * L[1] + dr[2] * L[2]) / free_J[r];
    }
    ev = fmax(ev, fabs(c[a] - v[a]));
    ew = fmax(ew, fabs(c[3 + a] - (w - om[a])));
  }
  printf("  terminal values against their definitions: attitude %.2e, "
         "angular velocity %.2e (angle %.3f)\n",
         ev, ew, th);
  CHECK(ev < 1e-12 && ew < 1e-12, "terminal values: attitude %.3e, omega %.3e",
        ev, ew);
  mrvi_ocp_free(o);
  mrvi_model_free(m);
}

/* A constant torque tau (space) on a body at rest for T: L_N = tau T up to
 * the truncation error (the discrete forcing is the midpoint rule of the
 * torque's virtual work). */
static void test_torque_impulse(void) {
  const double zero[3] = {0, 0, 0}, tau[3] = {0.2, -0.1, 0.3};
  double err[2];
  for (int r = 0; r < 2; r++) {
    mrvi_model *m = free_body(zero);
    const mrvi_settings s =
        settings(r ? 0.05 : 0.1, 1, 2.0, MRVI_FORM_MULTIPLIERS);
    mrvi_ocp *o = create(m, &s);
    mrvi_ocp_add_torque_actuator(o, 0, tau, 0, MRVI_GRID_MACRO, 1.0, -HUGE_VAL,
                                 HUGE_VAL);
    const int nu = mrvi_ocp_n_controls(o);
    double *u = malloc((size_t)nu * sizeof *u), J, P[3], L[3];
    for (int i = 0; i < nu; i++)
      u[i] = 1.0;
    CHECK(mrvi_ocp_evaluate(o, u, &J, NULL, NULL, NULL) == 0, "impulse: %s",
          mrvi_ocp_errmsg(o));
    const long N = mrvi_ocp_n_steps(o);
    mrvi_model_momentum(m, mrvi_ocp_q(o) + N * m->n, mrvi_ocp_p(o) + N * m->n,
                        P, L);
    err[r] = 0.0;
    for (int a = 0; a < 3; a++)
      err[r] = fmax(err[r], fabs(L[a] - 2.0 * tau[a]));
    free(u);
    mrvi_ocp_free(o);
    mrvi_model_free(m);
  }
  printf("constant torque on a body at rest: max |L_N - tau T| %.3e, %.3e "
         "(dT = 0.1, 0.05): order %.2f\n",
         err[0], err[1], log2(err[0] / err[1]));
  CHECK(err[0] < 1e-2 && err[1] < err[0] * 0.3,
        "torque impulse: %.3e, %.3e (order 2 expected)", err[0], err[1]);
}

/* ---------------------------------------------------------------------------
 * A slow body on a revolute joint to the ground carrying a fast body on a
 * second revolute joint (the joint between them on the micro grid).
 * ------------------------------------------------------------------------- */
static mrvi_model *chain_model(void) {
  mrvi_model *m = mrvi_model_create();
  const double J1[3] = {0.5, 0.6, 0.3}, J2[3] = {0.1, 0.12, 0.05};
  const double x1[3] = {0.5, 0.0, 0.0}, x2[3] = {1.3, 0.0, 0.0};
  const double w1[3] = {0.0, 0.0, 0.3}, w2[3] = {0.0, 0.2, 0.5};
  const double o0[3] = {0, 0, 0}, o1[3] = {1.0, 0.0, 0.0};
  const double z[3] = {0, 0, 1}, y[3] = {0, 1, 0};
  CHECK(mrvi_model_add_body(m, "arm", 3, MRVI_SLOW, 1.0, J1, x1, NULL, NULL,
                            w1) == 0 &&
            mrvi_model_add_body(m, "tip", 3, MRVI_FAST, 0.2, J2, x2, NULL, NULL,
                                w2) == 1,
        "chain bodies: %s", mrvi_model_errmsg(m));
  const int j0 = mrvi_model_add_joint(m, "revolute", 0, -1, o0, z);
  const int j1 = mrvi_model_add_joint(m, "revolute", 0, 1, o1, y);
  CHECK(j0 >= 0 && j1 >= 0, "chain joints: %s", mrvi_model_errmsg(m));
  double one = 0.0;
  CHECK(mrvi_model_project_velocities(m, &one) == 0, "projection");
  return m;
}

static void test_chain(mrvi_constraint_form form) {
  mrvi_model *m = chain_model();
  int j[2] = {-1, -1}, nj = 0; /* the joints, in the order added */
  for (int c = 0; c < m->n_constraints && nj < 2; c++)
    if (!strcmp(m->constraints[c].type->name, "revolute"))
      j[nj++] = c;
  const int j0 = j[0], j1 = j[1];
  const mrvi_settings s = settings(0.1, 3, 0.6, form);
  mrvi_ocp *o = create(m, &s);
  if (!o) {
    mrvi_model_free(m);
    return;
  }
  const double tx[3] = {1.0, 0.0, 0.2}, wt[3] = {0.0, 0.0, 0.4};
  double Rt[9];
  test_rotation(wt, 1.0, Rt);
  const double om[3] = {0.0, 0.0, 0.1};
  CHECK(mrvi_ocp_add_joint_torque_actuator(o, j0, MRVI_GRID_MACRO, 1.0,
                                           -HUGE_VAL, HUGE_VAL) == 0 &&
            mrvi_ocp_add_joint_torque_actuator(o, j1, MRVI_GRID_MICRO, 0.5,
                                               -HUGE_VAL, HUGE_VAL) == 1 &&
            mrvi_ocp_add_torque_actuator(o, 1, tx, 1, MRVI_GRID_MICRO, 1.0,
                                         -HUGE_VAL, HUGE_VAL) == 2 &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ATTITUDE, 0, Rt, 2.0) == 0 &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ANGULAR_VELOCITY_BODY, 1, om,
                                       3.0) == 0,
        "chain actuators and terminals: %s", mrvi_ocp_errmsg(o));
  /* As equalities both repeat joint rows (the chain has two degrees of
   * freedom): refused, naming the joints, and nothing added. */
  CHECK(mrvi_ocp_add_body_terminal(o, MRVI_OCP_ATTITUDE, 0, Rt, 0.0) < 0 &&
            strstr(mrvi_ocp_errmsg(o), "implied by its joints") &&
            strstr(mrvi_ocp_errmsg(o), "revolute arm-ground") &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ANGULAR_VELOCITY, 1, om,
                                       0.0) < 0 &&
            strstr(mrvi_ocp_errmsg(o), "angular velocit") &&
            mrvi_ocp_n_constraints(o) == 0 && mrvi_ocp_n_terminals(o) == 6,
        "redundant body terminal equalities refused: %s", mrvi_ocp_errmsg(o));
  CHECK(!strcmp(mrvi_ocp_actuator_kind(o, 0), "joint_torque"),
        "joint torque kind");
  char what[80];
  snprintf(what, sizeof what, "slow-fast chain, joint torques (p = 3), %s",
           form_name(form));
  check_gradients(o, what);
  mrvi_ocp_free(o);
  mrvi_model_free(m);
}

/* The same chain driven by forces on the bodies' centres (coordinate
 * actuators: their forces do not depend on the positions) or, if torques,
 * by the joint torques, a body torque and a force at a body point (state
 * actuators: their Jacobian in the node blocks, ocp_path), with the step
 * solver forced to schur-bordered in the multiplier form (the null-space
 * form takes general): the gradients against central differences, the
 * forward run against the general path's to 1e-10. */
static void test_chain_bordered(mrvi_constraint_form form, int p, int torques) {
  mrvi_model *m = chain_model();
  mrvi_settings s = settings(0.1, p, 0.6, form);
  s.solver =
      form == MRVI_FORM_MULTIPLIERS ? MRVI_SOLVER_STRUCTURED : MRVI_SOLVER_AUTO;
  mrvi_settings sg = s;
  sg.solver = MRVI_SOLVER_GENERAL;
  const mrvi_settings *ss[2] = {&s, &sg};
  mrvi_ocp *o[2] = {NULL, NULL};
  const int arm = mrvi_model_body_first(m, 0),
            tip = mrvi_model_body_first(m, 1);
  int j[2] = {-1, -1}, nj = 0; /* the joints, in the order added */
  for (int c = 0; c < m->n_constraints && nj < 2; c++)
    if (!strcmp(m->constraints[c].type->name, "revolute"))
      j[nj++] = c;
  const double tx[3] = {1.0, 0.0, 0.2}, at[3] = {0.1, 0.05, 0.0},
               dir[3] = {0.0, 0.6, 0.8};
  for (int k = 0; k < 2; k++) {
    if (!(o[k] = create(m, ss[k])))
      continue;
    if (torques) {
      CHECK(mrvi_ocp_add_joint_torque_actuator(o[k], j[0], MRVI_GRID_MACRO, 1.0,
                                               -HUGE_VAL, HUGE_VAL) == 0 &&
                mrvi_ocp_add_joint_torque_actuator(o[k], j[1], MRVI_GRID_MICRO,
                                                   0.5, -HUGE_VAL,
                                                   HUGE_VAL) == 1 &&
                mrvi_ocp_add_torque_actuator(o[k], 1, tx, 1, MRVI_GRID_MICRO,
                                             1.0, -HUGE_VAL, HUGE_VAL) == 2 &&
                mrvi_ocp_add_body_force_actuator(o[k], 0, at, dir,
                                                 MRVI_GRID_MACRO, 1.0,
                                                 -HUGE_VAL, HUGE_VAL) == 3 &&
                mrvi_ocp_add_terminal(o[k], MRVI_OCP_VELOCITY, tip + 1, 0.2,
                                      0.0) == 0 &&
                mrvi_ocp_add_terminal(o[k], MRVI_OCP_POSITION, tip + 2, 0.1,
                                      4.0) == 0,
            "chain state actuators: %s", mrvi_ocp_errmsg(o[k]));
      continue;
    }
    CHECK(mrvi_ocp_add_actuator(o[k], arm + 1, MRVI_GRID_MACRO, 1.0, -HUGE_VAL,
                                HUGE_VAL) == 0 &&
              mrvi_ocp_add_actuator(o[k], tip + 2, MRVI_GRID_MICRO, 0.5,
                                    -HUGE_VAL, HUGE_VAL) == 1 &&
              mrvi_ocp_add_actuator(o[k], tip, MRVI_GRID_MACRO, 2.0, -HUGE_VAL,
                                    HUGE_VAL) == 2 &&
              mrvi_ocp_add_terminal(o[k], MRVI_OCP_VELOCITY, tip + 1, 0.2,
                                    0.0) == 0 &&
              mrvi_ocp_add_terminal(o[k], MRVI_OCP_POSITION, tip + 2, 0.1,
                                    4.0) == 0,
          "chain force actuators: %s", mrvi_ocp_errmsg(o[k]));
  }
  char what[120], why[300];
  snprintf(what, sizeof what, "slow-fast chain, %s (p = %d), %s",
           torques ? "torques" : "forces", p, form_name(form));
  const char *path = o[0] ? mrvi_ocp_solver_path(o[0], why, sizeof why) : 0;
  const char *want =
      form == MRVI_FORM_MULTIPLIERS ? "schur-bordered" : "general";
  CHECK(path && !strcmp(path, want), "%s: path %s (%s)", what,
        path ? path : "none", why);
  if (o[0] && o[1]) {
    check_gradients(o[0], what);
    test_ocp_same_forward(o[0], o[1], m->n, what, 0.4, 1e-10);
  }
  mrvi_ocp_free(o[0]);
  mrvi_ocp_free(o[1]);
  mrvi_model_free(m);
}

/* ---------------------------------------------------------------------------
 * 2-D pendulum: a joint torque and a body torque.
 * ------------------------------------------------------------------------- */
/* A 2-D link of length 1 (mass 1, inertia PENDULUM_J, slow) on a revolute
 * joint j0 to the ground at its end, horizontal, turning at 0.5 rad/s,
 * under gravity. */
#define PENDULUM_J (1.0 / 12)
static mrvi_model *planar_pendulum(int *j0) {
  mrvi_model *m = mrvi_model_create();
  const double J = PENDULUM_J, x0[2] = {0.5, 0.0}, g[2] = {0, -9.81};
  const double R0[4] = {1, 0, 0, 1}, w0 = 0.5, o0[2] = {0, 0};
  CHECK(mrvi_model_add_body(m, "link", 2, MRVI_SLOW, 1.0, &J, x0, R0, NULL,
                            &w0) == 0 &&
            mrvi_model_set_gravity(m, g) >= 0,
        "pendulum: %s", mrvi_model_errmsg(m));
  *j0 = mrvi_model_add_joint(m, "revolute", 0, -1, o0, NULL);
  double corr;
  CHECK(*j0 >= 0 && mrvi_model_project_velocities(m, &corr) == 0,
        "pendulum joint: %s", mrvi_model_errmsg(m));
  return m;
}

static void test_planar(mrvi_constraint_form form) {
  int j0;
  mrvi_model *m = planar_pendulum(&j0);
  const mrvi_settings s = settings(0.05, 2, 0.5, form);
  mrvi_ocp *o = create(m, &s);
  if (!o) {
    mrvi_model_free(m);
    return;
  }
  const double ax[3] = {0, 0, 1}, th = -0.7, om = 0.2;
  const double Rt[4] = {cos(th), -sin(th), sin(th), cos(th)};
  CHECK(mrvi_ocp_add_joint_torque_actuator(o, j0, MRVI_GRID_MACRO, 1.0,
                                           -HUGE_VAL, HUGE_VAL) == 0 &&
            mrvi_ocp_add_torque_actuator(o, 0, ax, 0, MRVI_GRID_MICRO, 1.0,
                                         -HUGE_VAL, HUGE_VAL) == 1 &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ATTITUDE, 0, Rt, 0.0) == 0 &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ANGULAR_VELOCITY, 0, &om,
                                       0.0) == 1,
        "pendulum actuators and terminals: %s", mrvi_ocp_errmsg(o));
  char what[80];
  snprintf(what, sizeof what, "2-D pendulum, joint and body torque, %s",
           form_name(form));
  check_gradients(o, what);
  mrvi_ocp_free(o);
  mrvi_model_free(m);
}

/* ---------------------------------------------------------------------------
 * The 2-D pendulum brought to rest at -0.7 rad by its joint torque.  The
 * angular velocity condition is imposed on the final momenta projected onto
 * the hidden constraints (the joint's impulse moves the discrete momentum
 * off them): the projected angular speed, computed here from the final
 * state, ends below the terminal tolerance.
 * ------------------------------------------------------------------------- */
static void test_planar_rest(mrvi_constraint_form form) {
  int j0;
  mrvi_model *m = planar_pendulum(&j0);
  const mrvi_settings s = settings(0.05, 2, 1.0, form);
  mrvi_ocp *o = create(m, &s);
  if (!o) {
    mrvi_model_free(m);
    return;
  }
  const double th = -0.7, rest = 0.0;
  const double Rt[4] = {cos(th), -sin(th), sin(th), cos(th)};
  CHECK(mrvi_ocp_add_joint_torque_actuator(o, j0, MRVI_GRID_MACRO, 1.0,
                                           -HUGE_VAL, HUGE_VAL) == 0 &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ATTITUDE, 0, Rt, 0.0) == 0 &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ANGULAR_VELOCITY, 0, &rest,
                                       0.0) == 1,
        "pendulum at rest: %s", mrvi_ocp_errmsg(o));
  char what[80];
  snprintf(what, sizeof what, "2-D pendulum to rest, %s", form_name(form));
  check_gradients(o, what);
  const int nu = mrvi_ocp_n_controls(o), n = m->n;
  double *u = calloc((size_t)nu, sizeof *u);
  mrvi_ocp_result r;
  const int st = mrvi_ocp_solve(o, u, &r);
  CHECK(st == 0, "%s: %s (%s)", what, r.status, mrvi_ocp_errmsg(o));
  /* The final state, its momenta projected here (L = sum d_i x p_i). */
  const int R = mrvi_model_constraint_rows(m);
  double q[6], p[6], pp[6], gc[8], G[48], A[64], mu[8];
  memcpy(q, mrvi_ocp_q(o) + mrvi_ocp_n_steps(o) * n, sizeof q);
  memcpy(p, mrvi_ocp_p(o) + mrvi_ocp_n_steps(o) * n, sizeof p);
  memcpy(pp, p, sizeof pp);
  CHECK(n == 6 && R <= 8 &&
            mrvi_constraints_project(m, q, pp, NULL, gc, G, A, mu) == 0,
        "%s: projection of the final momenta", what);
  const double w_raw =
      (q[2] * p[3] - q[3] * p[2] + q[4] * p[5] - q[5] * p[4]) / PENDULUM_J;
  const double w_proj =
      (q[2] * pp[3] - q[3] * pp[2] + q[4] * pp[5] - q[5] * pp[4]) / PENDULUM_J;
  const double ang = atan2(q[3], q[2]), tol = mrvi_ocp_terminal_tolerance(o);
  printf("  %s: %s in %d evaluations, cost %.6f, angle %.12f; angular "
         "velocity projected %.2e (tolerance %.0e), unprojected %.2e\n",
         what, r.status, r.evaluations, r.cost, ang, w_proj, tol, w_raw);
  CHECK(fabs(w_proj) <= tol && fabs(ang - th) <= tol,
        "%s: projected angular velocity %.3e, angle %.15g", what, w_proj, ang);
  free(u);
  mrvi_ocp_free(o);
  mrvi_model_free(m);
}

/* ---------------------------------------------------------------------------
 * Single rotation components: the direction of one director (two rows) and
 * single angular velocity components.  A free body: the direction of d3
 * and Omega_2 (body frame) as equalities, omega_1 (space) as a penalty;
 * gradients against central differences and the values against their
 * definitions.  A body on a revolute joint about e3: the angular velocity
 * about the hinge is an equality it can meet, the other components and the
 * direction of any director repeat joint rows and are refused.
 * ------------------------------------------------------------------------- */
static void test_components(mrvi_constraint_form form) {
  const double w0[3] = {0.4, -0.3, 0.8};
  mrvi_model *m = free_body(w0);
  const mrvi_settings s = settings(0.1, 1, 0.8, form);
  mrvi_ocp *o = create(m, &s);
  if (!o) {
    mrvi_model_free(m);
    return;
  }
  const double ax[3] = {0.3, -0.2, 1.0}, bx[3] = {1.0, 0.5, 0.0};
  const double e3[3] = {0.2, -0.3, 1.0};
  CHECK(mrvi_ocp_add_torque_actuator(o, 0, ax, 0, MRVI_GRID_MACRO, 1.0,
                                     -HUGE_VAL, HUGE_VAL) == 0 &&
            mrvi_ocp_add_torque_actuator(o, 0, bx, 1, MRVI_GRID_MACRO, 2.0,
                                         -HUGE_VAL, HUGE_VAL) == 1 &&
            mrvi_ocp_add_body_direction(o, 0, 2, e3, 0.0) == 0 &&
            mrvi_ocp_add_body_angular_velocity_component(o, 1, 0, 1, 0.1,
                                                         0.0) == 2 &&
            mrvi_ocp_add_body_angular_velocity_component(o, 0, 0, 0, -0.2,
                                                         2.0) == 0,
        "free body components: %s", mrvi_ocp_errmsg(o));
  CHECK(mrvi_ocp_n_constraints(o) == 3 && mrvi_ocp_n_terminals(o) == 4,
        "component rows: %d constraints, %d terminals",
        mrvi_ocp_n_constraints(o), mrvi_ocp_n_terminals(o));
  mrvi_ocp_terminal_kind kind;
  mrvi_ocp_terminal(o, 0, &kind, NULL, NULL, NULL);
  CHECK(kind == MRVI_OCP_DIRECTION &&
            !strcmp(mrvi_ocp_terminal_kind_name(kind), "direction"),
        "direction kind");
  char what[96];
  snprintf(what, sizeof what,
           "free body, direction of d3 and angular "
           "velocity components, %s",
           form_name(form));
  check_gradients(o, what);
  /* Values: |rows| is the angle between d3 and e, the rows' vector in the
   * plane normal to e is along e x d3; Omega_2 = d2 . L / J2. */
  const int n = m->n;
  double c[3], u[16], J;
  for (int i = 0; i < mrvi_ocp_n_controls(o); i++)
    u[i] = 0.4 * sin(1.7 * i + 0.3);
  mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL);
  const double *q = mrvi_ocp_q(o) + mrvi_ocp_n_steps(o) * n;
  const double *p = mrvi_ocp_p(o) + mrvi_ocp_n_steps(o) * n;
  const double *d3 = q + 9, *d2 = q + 6;
  const double ne = sqrt(e3[0] * e3[0] + e3[1] * e3[1] + e3[2] * e3[2]);
  const double e[3] = {e3[0] / ne, e3[1] / ne, e3[2] / ne};
  double ed = 0.0, L[3] = {0, 0, 0};
  for (int a = 0; a < 3; a++)
    ed += e[a] * d3[a] / sqrt(d3[0] * d3[0] + d3[1] * d3[1] + d3[2] * d3[2]);
  for (int i = 0; i < 3; i++) {
    const double *d = q + 3 + 3 * i, *pd = p + 3 + 3 * i;
    L[0] += d[1] * pd[2] - d[2] * pd[1];
    L[1] += d[2] * pd[0] - d[0] * pd[2];
    L[2] += d[0] * pd[1] - d[1] * pd[0];
  }
  const double Om2 = (d2[0] * L[0] + d2[1] * L[1] + d2[2] * L[2]) / free_J[1];
  const double ang = acos(ed), rows = hypot(c[0], c[1]);
  printf("  direction rows: |rows| %.12f, angle(d3, e) %.12f; Omega_2 - "
         "target %.3e (definition %.3e)\n",
         rows, ang, c[2], Om2 - 0.1);
  CHECK(fabs(rows - ang) < 1e-9 * fmax(1.0, ang) && ang > 0.05,
        "direction rows %.15g, angle %.15g", rows, ang);
  CHECK(fabs(c[2] - (Om2 - 0.1)) < 1e-12, "Omega_2 component %.15g vs %.15g",
        c[2], Om2 - 0.1);
  mrvi_ocp_free(o);
  mrvi_model_free(m);

  /* A body on a revolute joint about e3. */
  m = mrvi_model_create();
  const double J1[3] = {0.5, 0.6, 0.3}, x1[3] = {0.5, 0.0, 0.0};
  const double w1[3] = {0.0, 0.0, 0.3}, o0[3] = {0, 0, 0}, z[3] = {0, 0, 1};
  CHECK(mrvi_model_add_body(m, "arm", 3, MRVI_SLOW, 1.0, J1, x1, NULL, NULL,
                            w1) == 0,
        "arm: %s", mrvi_model_errmsg(m));
  const int j0 = mrvi_model_add_joint(m, "revolute", 0, -1, o0, z);
  double one = 0.0;
  CHECK(j0 >= 0 && mrvi_model_project_velocities(m, &one) == 0, "arm joint");
  const mrvi_settings s2 = settings(0.1, 1, 0.6, form);
  o = create(m, &s2);
  if (!o) {
    mrvi_model_free(m);
    return;
  }
  const double d1t[3] = {cos(0.4), sin(0.4), 0.0};
  CHECK(mrvi_ocp_add_joint_torque_actuator(o, j0, MRVI_GRID_MACRO, 1.0,
                                           -HUGE_VAL, HUGE_VAL) == 0 &&
            mrvi_ocp_add_body_angular_velocity_component(o, 0, 0, 2, 0.1,
                                                         0.0) == 0,
        "arm: angular velocity about the hinge: %s", mrvi_ocp_errmsg(o));
  CHECK(mrvi_ocp_add_body_angular_velocity_component(o, 0, 0, 0, 0.0, 0.0) <
                0 &&
            strstr(mrvi_ocp_errmsg(o), "implied by its joints") &&
            mrvi_ocp_add_body_direction(o, 0, 2, z, 0.0) < 0 &&
            strstr(mrvi_ocp_errmsg(o), "terminal direction") &&
            mrvi_ocp_add_body_direction(o, 0, 0, d1t, 0.0) < 0 &&
            strstr(mrvi_ocp_errmsg(o), "revolute arm-ground") &&
            mrvi_ocp_n_constraints(o) == 1 && mrvi_ocp_n_terminals(o) == 1,
        "arm: components the joint imposes refused: %s", mrvi_ocp_errmsg(o));
  CHECK(mrvi_ocp_add_body_direction(o, 0, 0, d1t, 1.5) == 0 &&
            mrvi_ocp_add_body_direction(o, 0, 5, d1t, 1.5) < 0 &&
            mrvi_ocp_add_body_direction(o, 0, 0, (double[3]){0, 0, 0}, 1.5) < 0,
        "arm: direction penalty, bad director and zero direction: %s",
        mrvi_ocp_errmsg(o));
  snprintf(what, sizeof what,
           "revolute arm, hinge rate and d1 direction (penalty), %s",
           form_name(form));
  check_gradients(o, what);
  mrvi_ocp_free(o);
  mrvi_model_free(m);
}

/* ---------------------------------------------------------------------------
 * A 2-D wheel on a revolute joint to the ground with a torsional spring
 * (linear, k = 1, J = 1 about the hinge: theta = 4 sin t unforced), which
 * turns through pi at t = 0.9 and reaches 3.99 rad at T = 1.5.  The OCP's
 * forward pass follows the spring's branch from node to node as the
 * integrator does (the same trajectory with u = 0), and the adjoint
 * evaluates every step on that step's branch (the gradients against
 * central differences).
 * ------------------------------------------------------------------------- */
static void test_torsion_through_pi(mrvi_constraint_form form) {
  mrvi_model *m = mrvi_model_create();
  const double J = 1.0, k = 1.0, w0 = 4.0, x0[2] = {0, 0};
  CHECK(mrvi_model_add_body(m, "wheel", 2, MRVI_SLOW, 1.0, &J, x0, NULL, NULL,
                            &w0) == 0,
        "wheel: %s", mrvi_model_errmsg(m));
  const int j0 = mrvi_model_add_joint(m, "revolute", 0, -1, x0, NULL);
  CHECK(j0 >= 0 && mrvi_model_add_torsion(m, MRVI_SLOW, 0, -1, NULL, "linear",
                                          &k, 0.0) >= 0,
        "wheel joint and spring: %s", mrvi_model_errmsg(m));
  const mrvi_settings s = settings(0.05, 1, 1.5, form);
  mrvi_ocp *o = create(m, &s);
  if (!o) {
    mrvi_model_free(m);
    return;
  }
  const double th = 3.9, om = 0.5;
  const double Rt[4] = {cos(th), -sin(th), sin(th), cos(th)};
  CHECK(mrvi_ocp_add_joint_torque_actuator(o, j0, MRVI_GRID_MACRO, 1.0,
                                           -HUGE_VAL, HUGE_VAL) == 0 &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ATTITUDE, 0, Rt, 0.0) == 0 &&
            mrvi_ocp_add_body_terminal(o, MRVI_OCP_ANGULAR_VELOCITY, 0, &om,
                                       0.0) == 1,
        "wheel actuator and terminals: %s", mrvi_ocp_errmsg(o));
  /* Unforced: the integrator's trajectory, wound past pi. */
  const int nu = mrvi_ocp_n_controls(o), n = m->n;
  double *u = calloc((size_t)nu, sizeof *u), J0, c[2];
  int st = mrvi_ocp_evaluate(o, u, &J0, NULL, c, NULL);
  CHECK(st == 0, "wheel forward: %s", mrvi_ocp_errmsg(o));
  mrvi_integrator *it = NULL;
  char msg[300];
  CHECK(mrvi_integrator_create(m, &s, &it, msg, sizeof msg) == 0, "%s", msg);
  const long N = mrvi_settings_n_steps(&s);
  for (long i = 0; i < N && it; i++)
    CHECK(mrvi_integrator_step(it) == 0, "wheel step: %s",
          mrvi_integrator_errmsg(it));
  double diff = 0.0;
  for (int i = 0; i < n && it && st == 0; i++)
    diff =
        fmax(diff, fabs(mrvi_ocp_q(o)[N * n + i] - mrvi_integrator_q(it)[i]));
  const double wound = it ? mrvi_integrator_torsion_angle(it)[0] : 0.0;
  printf("wheel through pi (%s): unforced angle %.6f (4 sin 1.5 = %.6f), "
         "OCP forward vs integrator %.2e\n",
         form_name(form), wound, 4 * sin(1.5), diff);
  CHECK(wound > M_PI + 0.5 && fabs(wound - 4 * sin(1.5)) < 1e-2,
        "wheel: unforced angle %.6f, expected past pi near %.6f", wound,
        4 * sin(1.5));
  CHECK(st == 0 && diff <= 1e-11,
        "wheel: OCP forward differs from the integrator by %.3e", diff);
  mrvi_integrator_free(it);
  free(u);
  char what[80];
  snprintf(what, sizeof what, "wheel with a torsional spring through pi, %s",
           form_name(form));
  check_gradients(o, what);
  mrvi_ocp_free(o);
  mrvi_model_free(m);
}

/* Refusals with their reasons. */
static void test_refusals(void) {
  const double zero[3] = {0, 0, 0};
  mrvi_model *m = free_body(zero);
  const mrvi_settings s = settings(0.1, 1, 0.5, MRVI_FORM_MULTIPLIERS);
  mrvi_ocp *o = create(m, &s);
  const double bad[9] = {1, 0, 0, 0, 1, 0, 0, 0, -1};
  CHECK(mrvi_ocp_add_torque_actuator(o, 0, zero, 0, MRVI_GRID_MACRO, 1.0,
                                     -HUGE_VAL, HUGE_VAL) < 0 &&
            strstr(mrvi_ocp_errmsg(o), "nonzero"),
        "zero torque axis refused: %s", mrvi_ocp_errmsg(o));
  CHECK(mrvi_ocp_add_torque_actuator(o, 3, zero, 0, MRVI_GRID_MACRO, 1.0,
                                     -HUGE_VAL, HUGE_VAL) < 0 &&
            strstr(mrvi_ocp_errmsg(o), "out of range"),
        "unknown body refused: %s", mrvi_ocp_errmsg(o));
  CHECK(mrvi_ocp_add_body_terminal(o, MRVI_OCP_ATTITUDE, 0, bad, 0.0) < 0 &&
            strstr(mrvi_ocp_errmsg(o), "not a rotation"),
        "reflection as a target refused: %s", mrvi_ocp_errmsg(o));
  CHECK(mrvi_ocp_add_joint_torque_actuator(o, 0, MRVI_GRID_MACRO, 1.0,
                                           -HUGE_VAL, HUGE_VAL) < 0 &&
            strstr(mrvi_ocp_errmsg(o), "not a revolute joint"),
        "joint torque on the body constraint refused: %s", mrvi_ocp_errmsg(o));
  mrvi_ocp_free(o);
  mrvi_model_free(m);
}

int main(void) {
  test_free_body(MRVI_FORM_MULTIPLIERS);
  test_free_body(MRVI_FORM_NULL_SPACE);
  test_torque_impulse();
  test_chain(MRVI_FORM_MULTIPLIERS);
  test_chain(MRVI_FORM_NULL_SPACE);
  for (int p = 1; p <= 5; p += 4) {
    for (int t = 0; t < 2; t++) {
      test_chain_bordered(MRVI_FORM_MULTIPLIERS, p, t);
      test_chain_bordered(MRVI_FORM_NULL_SPACE, p, t);
    }
  }
  test_planar(MRVI_FORM_MULTIPLIERS);
  test_planar(MRVI_FORM_NULL_SPACE);
  test_planar_rest(MRVI_FORM_MULTIPLIERS);
  test_planar_rest(MRVI_FORM_NULL_SPACE);
  test_components(MRVI_FORM_MULTIPLIERS);
  test_components(MRVI_FORM_NULL_SPACE);
  test_torsion_through_pi(MRVI_FORM_MULTIPLIERS);
  test_torsion_through_pi(MRVI_FORM_NULL_SPACE);
  test_refusals();
  return test_finish();
}
