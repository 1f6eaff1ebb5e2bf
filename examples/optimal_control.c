/* An optimal control problem built in code and solved (multirate DMOC,
 * doc/optimal-control.md).
 *
 *   optimal_control
 *
 * A slow free mass x (m = 2) is pushed by a force u, piecewise constant on
 * the macro grid, from rest at 0 to rest at d = 1 in T = 2 with the least
 * effort J = 1/2 int u^2 dt, beside an uncoupled fast oscillator y that
 * rides along (p = 5 micro steps per macro step).  The continuous optimum
 * is J* = 6 m^2 d^2 / T^3 = 3; on N macro steps of the midpoint discrete
 * Lagrangian the discrete optimum is J_N = J* N^2 / (N^2 - 1), 300/99 for
 * N = 10 (systems/ocp_double_integrator.yaml is the same problem as a
 * description file).  The program prints the optimal cost, J_N and the
 * optimal force on each macro step.
 *
 * The optimal control API is the header mrvi_ocp.h, installed beside
 * mrvi.h: build as load_and_run.c says.
 */
#include <math.h>
#include <mrvi.h>
#include <mrvi_ocp.h>
#include <stdio.h>
#include <stdlib.h>

int main(void) {
  const double mass = 2, d = 1, T = 2;
  const int N = 10;

  /* The model: x slow and free, y fast with W = k y^2 / 2 (a term of the
   * law "linear" on the combination 1 * y). */
  mrvi_model *m = mrvi_model_create();
  if (!m)
    return 1;
  const int x = mrvi_model_add_coordinate(m, "x", mass, MRVI_SLOW, 0, 0);
  const int y = mrvi_model_add_coordinate(m, "y", 0.3, MRVI_FAST, 0.01, 0.2);
  const double one = 1, k = 750;
  if (x < 0 || y < 0 ||
      mrvi_model_add_term(m, MRVI_FAST, 1, &y, &one, 0, "linear", &k) < 0) {
    fprintf(stderr, "model: %s\n", mrvi_model_errmsg(m));
    mrvi_model_free(m);
    return 1;
  }
  mrvi_settings s;
  mrvi_settings_default(&s);
  mrvi_settings_set_scheme(&s, "midpoint-midpoint");
  s.macro_step = T / N;
  s.micro_steps = 5;
  s.t_end = T;
  s.newton_tol = 1e-12;

  /* The problem: one actuator on x (macro grid, weight 1, no bounds), the
   * terminal conditions x(T) = d and x'(T) = 0 as equality constraints
   * (penalty 0), NLopt's SLSQP to a tight tolerance. */
  char msg[1024];
  mrvi_ocp *o = NULL;
  if (mrvi_ocp_create(m, &s, &o, msg, sizeof msg) < 0) {
    fprintf(stderr, "ocp: %s\n", msg);
    mrvi_model_free(m);
    return 1;
  }
  if (mrvi_ocp_add_actuator(o, x, MRVI_GRID_MACRO, 1.0, -HUGE_VAL, HUGE_VAL) <
          0 ||
      mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, x, d, 0) < 0 ||
      mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, x, 0, 0) < 0) {
    fprintf(stderr, "ocp: %s\n", mrvi_ocp_errmsg(o));
    mrvi_ocp_free(o);
    mrvi_model_free(m);
    return 1;
  }
  mrvi_ocp_set_tolerances(o, 1e-14, 1e-10);

  /* Solve from u = 0: u receives the optimal controls. */
  const int n_u = mrvi_ocp_n_controls(o);
  double *u = calloc((size_t)n_u, sizeof *u);
  mrvi_ocp_result res;
  const int st = u ? mrvi_ocp_solve(o, u, &res) : MRVI_ENOMEM;
  if (st < 0) {
    fprintf(stderr, "solve: %s\n", mrvi_ocp_errmsg(o));
  } else {
    const double J_star = 6 * mass * mass * d * d / (T * T * T);
    printf("%d controls, %d evaluations (%s)\n", n_u, res.evaluations,
           res.nlopt_name);
    printf("optimal cost %.15f\n", res.cost);
    printf("discrete optimum J_N %.15f\n", J_star * N * N / (N * N - 1.0));
    printf("terminal violation %.3e\n", res.violation);
    for (int j = 0; j < n_u; j++)
      printf("  u[%d] = %+.9f\n", j, u[j]);
  }
  free(u);
  mrvi_ocp_free(o);
  mrvi_model_free(m);
  return st < 0 ? 2 : 0;
}
