/* Structure the multirate variational integrators preserve (paper §3.2):
 * - symplecticity: the finite-difference Jacobian Phi of the one-step map
 *   of the FPU satisfies ||Phi^T J Phi - J|| <= 1e-6 (every scheme, p = 5);
 * - discrete Noether (th_dNoether): the spring ring's angular momentum about
 *   e3 is constant to 10 x the Newton tolerance (every scheme, p = 1, 5, 10);
 * - bounded energy error without drift on the FPU (midpoint-midpoint,
 *   dT = 0.3, p = 1, 5, 10, t = 200). */
#include "model/model.h"
#include "models.h"
#include "testlib.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

static void symplecticity(const char *scheme) {
  mrvi_model *m = test_fpu();
  const int n = m->n, d = 2 * n;
  mrvi_settings s = test_settings(scheme, 0.1, 5, 1.0, 1e-13);
  mrvi_integrator *it = NULL;
  char msg[256];
  if (mrvi_integrator_create(m, &s, &it, msg, sizeof msg) < 0) {
    CHECK(0, "%s", msg);
    mrvi_model_free(m);
    return;
  }
  double z0[24], z[24], Phi[24 * 24];
  for (int i = 0; i < n; i++) {
    z0[i] = m->q0[i];
    z0[n + i] = MRVI_MASS(m, i) * m->v0[i];
  }
  const double h = 1e-5;
  int ok = 1;
  for (int j = 0; j < d; j++) {
    double col[2][24];
    for (int sg = 0; sg < 2; sg++) {
      memcpy(z, z0, sizeof z);
      z[j] += sg ? -h : h;
      mrvi_integrator_set_state(it, 0.0, z, z + n);
      ok &= mrvi_integrator_step(it) == 0;
      memcpy(col[sg], mrvi_integrator_q(it), (size_t)n * sizeof(double));
      memcpy(col[sg] + n, mrvi_integrator_p(it), (size_t)n * sizeof(double));
    }
    for (int i = 0; i < d; i++)
      Phi[i * d + j] = (col[0][i] - col[1][i]) / (2 * h);
  }
  CHECK(ok, "%s: steps converge", scheme);
  /* (Phi^T J Phi)_{ab} = sum_i Phi_{i a} Phi_{n+i b} - Phi_{n+i a} Phi_{i b} */
  double worst = 0.0;
  for (int a = 0; a < d; a++)
    for (int b = 0; b < d; b++) {
      double v = 0.0;
      for (int i = 0; i < n; i++)
        v += Phi[i * d + a] * Phi[(n + i) * d + b] -
             Phi[(n + i) * d + a] * Phi[i * d + b];
      const double Jab = (a < n && b == a + n)    ? 1.0
                         : (a >= n && b == a - n) ? -1.0
                                                  : 0.0;
      worst = fmax(worst, fabs(v - Jab));
    }
  CHECK(worst <= 1e-6, "%s p=5: ||Phi^T J Phi - J|| = %.3e", scheme, worst);
  printf("symplecticity %-24s ||Phi^T J Phi - J||_max = %.2e\n", scheme, worst);
  mrvi_integrator_free(it);
  mrvi_model_free(m);
}

typedef struct trace {
  long n, cap;
  double *t, *energy, *Jz;
} trace;

static int record(void *user, const mrvi_record *r) {
  trace *T = user;
  if (T->n == T->cap) {
    T->cap = T->cap ? 2 * T->cap : 1024;
    T->t = realloc(T->t, (size_t)T->cap * sizeof(double));
    T->energy = realloc(T->energy, (size_t)T->cap * sizeof(double));
    T->Jz = realloc(T->Jz, (size_t)T->cap * sizeof(double));
  }
  T->t[T->n] = r->t;
  T->energy[T->n] = r->energy;
  T->Jz[T->n] = r->angular_momentum[2];
  T->n++;
  return 0;
}

static void trace_free(trace *T) {
  free(T->t);
  free(T->energy);
  free(T->Jz);
}

static void noether(const char *scheme, int p) {
  mrvi_model *m = test_spring_ring();
  const double tol = 1e-8;
  mrvi_settings s = test_settings(scheme, 0.01, p, 2.0, tol);
  trace T = {0};
  mrvi_summary sum;
  int st = mrvi_run(m, &s, record, &T, NULL, &sum);
  CHECK(st == 0, "%s p=%d: run: %s", scheme, p, sum.message);
  double drift = 0.0, jump = 0.0;
  for (long k = 0; k < T.n; k++) {
    drift = fmax(drift, fabs(T.Jz[k] - T.Jz[0]));
    if (k > 0)
      jump = fmax(jump, fabs(T.Jz[k] - T.Jz[k - 1]));
  }
  CHECK(jump <= tol, "%s p=%d: angular momentum changes by %.3e in one step",
        scheme, p, jump);
  CHECK(T.n == 201, "%s p=%d: 201 macro nodes (got %ld)", scheme, p, T.n);
  CHECK(drift <= 10 * tol, "%s p=%d: angular momentum about e3 drifts %.3e",
        scheme, p, drift);
  printf("noether %-24s p=%-2d max|J3 - J3(0)| = %.2e (J3 = %.6g)\n", scheme, p,
         drift, T.Jz[0]);
  trace_free(&T);
  mrvi_model_free(m);
}

static void energy_no_drift(int p) {
  mrvi_model *m = test_fpu();
  mrvi_settings s = test_settings("midpoint-midpoint", 0.3, p, 200.0, 1e-9);
  trace T = {0};
  mrvi_summary sum;
  int st = mrvi_run(m, &s, record, &T, NULL, &sum);
  CHECK(st == 0, "fpu p=%d: run: %s", p, sum.message);
  double first = 0.0, second = 0.0;
  for (long k = 0; k < T.n; k++) {
    double e = fabs(T.energy[k] - T.energy[0]) / fabs(T.energy[0]);
    if (T.t[k] <= 100.0)
      first = fmax(first, e);
    else
      second = fmax(second, e);
  }
  CHECK(T.n == 668, "fpu p=%d: N+1 = 668 nodes (got %ld)", p, T.n);
  CHECK(first > 0 && second <= 1.5 * first,
        "fpu p=%d: energy error first half %.3e, second half %.3e", p, first,
        second);
  CHECK(fmax(first, second) < 0.05, "fpu p=%d: energy error %.3e bounded", p,
        fmax(first, second));
  printf("fpu energy p=%-2d max rel. error first half %.3e, second half %.3e\n",
         p, first, second);
  trace_free(&T);
  mrvi_model_free(m);
}

int main(void) {
  const char *const *schemes = mrvi_scheme_names();
  for (int i = 0; schemes[i]; i++)
    symplecticity(schemes[i]);
  const int ps[3] = {1, 5, 10};
  for (int i = 0; schemes[i]; i++)
    for (int j = 0; j < 3; j++)
      noether(schemes[i], ps[j]);
  for (int j = 0; j < 3; j++)
    energy_no_drift(ps[j]);
  return test_finish();
}
