/* Analysis functions: linear stability (Lemma lemma:stability_slow), the
 * propagation matrix against the paper's closed form, errors against a
 * reference (eq:err_mac, eq:err_mic). */
#include "models.h"
#include "testlib.h"
#include "util/util.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static void stability(void) {
  mrvi_model *osc = test_oscillator(3.0);
  const char *schemes[2] = {"trapezoidal-midpoint", "midpoint-midpoint"};
  const int ps[5] = {1, 2, 3, 5, 10};
  char msg[256];
  for (int i = 0; i < 2; i++)
    for (int j = 0; j < 5; j++) {
      mrvi_settings s = test_settings(schemes[i], 0.1, ps[j], 0.1, 1e-12);
      double limit = 0;
      int st =
          mrvi_stability_limit(osc, &s, 20.0, 0.01, &limit, msg, sizeof msg);
      CHECK(st == 0, "%s", msg);
      const double bound = mrvi_stability_bound(s.slow, ps[j]);
      if (isinf(bound)) {
        CHECK(isinf(limit), "%s p=%d: unconditionally stable (limit %g)",
              schemes[i], ps[j], limit);
      } else {
        CHECK(fabs(limit - bound) <= 0.01 * bound,
              "%s p=%d: measured %.6f, analytic %.6f", schemes[i], ps[j], limit,
              bound);
      }
      printf("stability %-22s p=%-2d measured %-10.6g analytic %.6g\n",
             schemes[i], ps[j], limit, bound);
    }
  /* Midpoint with p = 1 is the midpoint rule: stable at omega dT = 100. */
  mrvi_settings s = test_settings("midpoint-midpoint", 0.1, 1, 0.1, 1e-12);
  double det, tr;
  CHECK(mrvi_stability_at(osc, &s, 100.0, &det, &tr, msg, sizeof msg) == 0,
        "%s", msg);
  CHECK(fabs(tr) < 2 && fabs(det - 1) < 1e-12,
        "midpoint p=1 at omega dT = 100: det %.15g trace %.15g", det, tr);
  /* The paper's P^{mid,s} entry by entry (M = 1, omega = 3). */
  for (int p = 1; p <= 4; p++) {
    s = test_settings("midpoint-midpoint", 0.37, p, 0.37, 1e-13);
    double P[4];
    CHECK(mrvi_propagation_matrix(osc, &s, P, msg, sizeof msg) == 0, "%s", msg);
    const double w = 3.0, dt = 0.37 / p, a = dt * dt * w * w;
    const double den = 12 + 2 * a * p * p + a;
    const double P11 = (12 - 4 * a * p * p + a) / den, P12 = 12 * p * dt / den;
    const double P21 = (-12 * dt * w * w * p + dt * a * w * w * p * p * p -
                        dt * a * w * w * p) /
                       den;
    CHECK_NEAR(P[0], P11, 1e-12, "P^mid_11");
    CHECK_NEAR(P[1], P12, 1e-12, "P^mid_12");
    CHECK_NEAR(P[2], P21, 1e-12, "P^mid_21");
    CHECK_NEAR(P[3], P11, 1e-12, "P^mid_22");
    /* The trace formula of the trapezoidal rule, any alpha. */
    s = test_settings("trapezoidal-midpoint", 0.37, p, 0.37, 1e-13);
    s.slow.alpha = 0.3;
    CHECK(mrvi_propagation_matrix(osc, &s, P, msg, sizeof msg) == 0, "%s", msg);
    const double trap = -2 * (2 * a * p * p + a - 6) / (a * p * p - a + 6);
    CHECK_NEAR(P[0] + P[3], trap, 1e-12, "tr P^trap");
    CHECK_NEAR(P[0] * P[3] - P[1] * P[2], 1.0, 1e-12, "det P^trap");
  }
  mrvi_model_free(osc);
}

/* Errors of a run against a reference: zero against itself on the macro
 * nodes when the reference is the same single-rate run, and the split into
 * slow and fast parts is consistent. */
static void errors(void) {
  mrvi_model *fpu = test_fpu();
  char msg[256];
  mrvi_summary sum;
  mrvi_trajectory *ref = NULL, *run = NULL, *same = NULL;
  CHECK(mrvi_trajectory_run(fpu, &(mrvi_settings){0}, &ref, &sum) < 0,
        "invalid settings are rejected");
  mrvi_settings s = test_settings("midpoint-midpoint", 0.001, 1, 0.2, 1e-12);
  CHECK(mrvi_trajectory_run(fpu, &s, &ref, &sum) == 0, "%s", sum.message);
  CHECK(mrvi_trajectory_run(fpu, &s, &same, &sum) == 0, "%s", sum.message);
  mrvi_errors e;
  CHECK(mrvi_trajectory_errors(fpu, same, ref, &e, msg, sizeof msg) == 0, "%s",
        msg);
  CHECK(e.q_mac == 0 && e.p_mac == 0 && isnan(e.q_mic), "self errors");
  s = test_settings("trapezoidal-midpoint", 0.02, 4, 0.2, 1e-12);
  CHECK(mrvi_trajectory_run(fpu, &s, &run, &sum) == 0, "%s", sum.message);
  CHECK(run->n_macro == 11 && run->n_micro == 41, "trajectory sizes");
  CHECK(mrvi_trajectory_errors(fpu, run, ref, &e, msg, sizeof msg) == 0, "%s",
        msg);
  CHECK(e.q_mac > 0 && e.q_mic > 0 && e.p_mic > 0, "errors are positive");
  CHECK(e.q_mac <= sqrt(e.qs_mac * e.qs_mac + e.qf_mac * e.qf_mac) + 1e-15 &&
            e.q_mac >= fmax(e.qs_mac, e.qf_mac) - 1e-15,
        "split consistent with the total");
  /* A reference that does not divide the micro step is refused. */
  mrvi_trajectory *coarse = NULL;
  s = test_settings("midpoint-midpoint", 0.003, 1, 0.2, 1e-12);
  CHECK(mrvi_trajectory_run(fpu, &s, &coarse, &sum) == 0, "%s", sum.message);
  CHECK(mrvi_trajectory_errors(fpu, run, coarse, &e, msg, sizeof msg) < 0 &&
            strstr(msg, "divide"),
        "non-dividing reference: %s", msg);
  mrvi_trajectory_free(coarse);
  mrvi_trajectory_free(ref);
  mrvi_trajectory_free(same);
  mrvi_trajectory_free(run);
  mrvi_model_free(fpu);
}

/* Buffer sizes of a kept trajectory are checked for overflow before any
 * allocation: 800 fast coordinates over 4e15 steps need 2.6e19 bytes, more
 * than size_t holds; the message names the keys. */
static void huge(void) {
  const char *text = "name: big\ndimension: 2\ngenerate:\n"
                     "  - kind: lattice2d\n    name: p\n    count: [20, 20]\n"
                     "    spacing: 1.0\n    mass: 1.0\n    rates: all_fast\n"
                     "    fast_spring: {law: linear, stiffness: 10}\n"
                     "integrator: {scheme: midpoint-midpoint, macro_step: 1, "
                     "micro_steps: 1, t_end: 4e15}\n";
  mrvi_system *sys = NULL;
  char msg[512];
  int st =
      mrvi_system_load_string(text, "big.yaml", NULL, 0, &sys, msg, sizeof msg);
  CHECK(st == 0 && sys, "huge: loads: %s", msg);
  if (!sys)
    return;
  CHECK(mrvi_model_n_fast(sys->model) == 800, "huge: 800 fast coordinates");
  mrvi_trajectory *tr = NULL;
  mrvi_summary sum;
  st = mrvi_trajectory_run(sys->model, &sys->settings, &tr, &sum);
  CHECK(st == MRVI_ENOMEM && !tr && strstr(sum.message, "integrator.t_end") &&
            strstr(sum.message, "does not fit in memory"),
        "huge: refused before allocating (%d: %s)", st, sum.message);
  mrvi_trajectory_free(tr);
  mrvi_system_free(sys);
}

int main(void) {
  stability();
  errors();
  huge();
  return test_finish();
}
