/* p = 1 reductions to classical one-step schemes (arXiv 2406.12991 §3.3,
 * remarks after th:midfmids, th:midftraps, th:trapftraps and Examples
 * ex:slow_ex__fast_im, ex:fully_ex).  Each classical scheme is written here in
 * a few lines on top of the model's gradient and Hessian only; mrvi's multirate
 * step with p = 1 must agree with it to 1e-12 over 100 steps, relative to
 * max|q| and max|p| (the spring ring's residual floor is about 1e-13 of its
 * momenta). */
#include "model/model.h"
#include "models.h"
#include "testlib.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#define NMAX 32

typedef struct sys {
  const mrvi_model *m;
  int n;
} sys;

/* grad of V (which = SLOW), W (FAST) or both (which = 2) at q. */
static void grad(const sys *S, int which, const double *q, double *g) {
  memset(g, 0, (size_t)S->n * sizeof *g);
  if (which != MRVI_FAST)
    mrvi_model_potential(S->m, MRVI_SLOW, q, g, NULL);
  if (which != MRVI_SLOW)
    mrvi_model_potential(S->m, MRVI_FAST, q, g, NULL);
}

static void hess(const sys *S, int which, const double *q, double *H) {
  double g[NMAX];
  memset(g, 0, sizeof g);
  memset(H, 0, (size_t)S->n * S->n * sizeof *H);
  if (which != MRVI_FAST)
    mrvi_model_potential(S->m, MRVI_SLOW, q, g, H);
  if (which != MRVI_SLOW)
    mrvi_model_potential(S->m, MRVI_FAST, q, g, H);
}

/* Solve A x = b (n x n, row-major, destroyed) by Gaussian elimination. */
static void solve(int n, double *A, double *b) {
  for (int k = 0; k < n; k++) {
    int piv = k;
    for (int i = k + 1; i < n; i++)
      if (fabs(A[i * n + k]) > fabs(A[piv * n + k]))
        piv = i;
    for (int j = 0; j < n; j++) {
      double t = A[k * n + j];
      A[k * n + j] = A[piv * n + j];
      A[piv * n + j] = t;
    }
    double t = b[k];
    b[k] = b[piv];
    b[piv] = t;
    for (int i = k + 1; i < n; i++) {
      double f = A[i * n + k] / A[k * n + k];
      for (int j = k; j < n; j++)
        A[i * n + j] -= f * A[k * n + j];
      b[i] -= f * b[k];
    }
  }
  for (int i = n - 1; i >= 0; i--) {
    for (int j = i + 1; j < n; j++)
      b[i] -= A[i * n + j] * b[j];
    b[i] /= A[i * n + i];
  }
}

/* Implicit midpoint for the potential class `which` on coordinates mask:
 *   q1 = q0 + h M^-1 (p0 + p1)/2,  p1 = p0 - h grad U((q0 + q1)/2)
 * (only coordinates with mask[i] move; others are frozen).  Newton on q1. */
static void midpoint(const sys *S, int which, const int *mask, double h,
                     double *q, double *p) {
  const int n = S->n;
  double q1[NMAX], g[NMAX], H[NMAX * NMAX], F[NMAX], A[NMAX * NMAX], mid[NMAX];
  for (int i = 0; i < n; i++)
    q1[i] = q[i] + (mask[i] ? h * p[i] / MRVI_MASS(S->m, i) : 0.0);
  for (int it = 0; it < 30; it++) {
    for (int i = 0; i < n; i++)
      mid[i] = 0.5 * (q[i] + q1[i]);
    grad(S, which, mid, g);
    hess(S, which, mid, H);
    /* F(q1) = M (q1 - q0)/h - p0 + h/2 grad U(mid) = 0 on the mask */
    for (int i = 0; i < n; i++) {
      F[i] = mask[i] ? MRVI_MASS(S->m, i) * (q1[i] - q[i]) / h - p[i] +
                           0.5 * h * g[i]
                     : 0.0;
      for (int j = 0; j < n; j++)
        A[i * n + j] = mask[i] && mask[j]
                           ? (i == j ? MRVI_MASS(S->m, i) / h : 0.0) +
                                 0.25 * h * H[i * n + j]
                           : (i == j ? 1.0 : 0.0);
    }
    solve(n, A, F);
    for (int i = 0; i < n; i++)
      q1[i] -= F[i];
  }
  for (int i = 0; i < n; i++)
    mid[i] = 0.5 * (q[i] + q1[i]);
  grad(S, which, mid, g);
  for (int i = 0; i < n; i++)
    if (mask[i]) {
      p[i] -= h * g[i];
      q[i] = q1[i];
    }
}

static void kick(const sys *S, int which, double h, const double *q, double *p,
                 const int *mask) {
  double g[NMAX];
  grad(S, which, q, g);
  for (int i = 0; i < S->n; i++)
    if (!mask || mask[i])
      p[i] -= h * g[i];
}

static void drift(const sys *S, double h, double *q, const double *p,
                  const int *mask) {
  for (int i = 0; i < S->n; i++)
    if (!mask || mask[i])
      q[i] += h * p[i] / MRVI_MASS(S->m, i);
}

typedef enum {
  IMPLICIT_MIDPOINT,  /* midpoint-midpoint */
  STORMER_VERLET,     /* trapezoidal alpha = 1/2 for V and W */
  VELOCITY_VERLET,    /* fully-explicit */
  SYMPLECTIC_EULER_A, /* left rectangle: p1 = p0 - h grad U(q0), q1 = q0 + h p1
                       */
  SYMPLECTIC_EULER_B, /* right rectangle: q1 = q0 + h p0, p1 = p0 - h grad U(q1)
                       */
  KICK_MIDPOINT, /* trapezoidal-midpoint: slow left rectangle, fast midpoint */
  IMEX           /* explicit-slow: half kicks of V around a midpoint W step */
} classical;

static void classical_step(const sys *S, classical c, double h, double *q,
                           double *p) {
  int all[NMAX], fast[NMAX], slow[NMAX];
  for (int i = 0; i < S->n; i++) {
    all[i] = 1;
    fast[i] = S->m->rate[i] == MRVI_FAST;
    slow[i] = !fast[i];
  }
  switch (c) {
  case IMPLICIT_MIDPOINT:
    midpoint(S, 2, all, h, q, p);
    break;
  case STORMER_VERLET:
  case VELOCITY_VERLET:
    kick(S, 2, h / 2, q, p, NULL);
    drift(S, h, q, p, NULL);
    kick(S, 2, h / 2, q, p, NULL);
    break;
  case SYMPLECTIC_EULER_A:
    kick(S, 2, h, q, p, NULL);
    drift(S, h, q, p, NULL);
    break;
  case SYMPLECTIC_EULER_B:
    drift(S, h, q, p, NULL);
    kick(S, 2, h, q, p, NULL);
    break;
  case KICK_MIDPOINT:
    /* p~ = p - h grad V(q0); slow drift with p~; fast midpoint in W from p~ */
    kick(S, MRVI_SLOW, h, q, p, NULL);
    drift(S, h, q, p, slow);
    midpoint(S, MRVI_FAST, fast, h, q, p);
    break;
  case IMEX:
    kick(S, MRVI_SLOW, h / 2, q, p, NULL);
    drift(S, h, q, p, slow);
    midpoint(S, MRVI_FAST, fast, h, q, p);
    kick(S, MRVI_SLOW, h / 2, q, p, NULL);
    break;
  }
}

/* Largest deviation between mrvi and the classical scheme over 100 steps
 * (infinity if a step fails). */
static double deviation(const mrvi_model *m, mrvi_settings s, classical c,
                        const char *what) {
  sys S = {m, m->n};
  mrvi_integrator *it = NULL;
  char msg[256];
  if (mrvi_integrator_create(m, &s, &it, msg, sizeof msg) < 0) {
    CHECK(0, "%s: %s", what, msg);
    return INFINITY;
  }
  double q[NMAX], p[NMAX];
  for (int i = 0; i < m->n; i++) {
    q[i] = m->q0[i];
    p[i] = MRVI_MASS(m, i) * m->v0[i];
  }
  double err = 0.0;
  int ok = 1;
  for (int k = 0; k < 100 && ok; k++) {
    classical_step(&S, c, s.macro_step, q, p);
    ok = mrvi_integrator_step(it) == 0;
    /* Deviation relative to the size of the state (max norms). */
    const double *qi = mrvi_integrator_q(it), *pi = mrvi_integrator_p(it);
    double dq = 0, dp = 0, nq = 1, np = 1;
    for (int i = 0; i < m->n; i++) {
      dq = fmax(dq, fabs(qi[i] - q[i]));
      dp = fmax(dp, fabs(pi[i] - p[i]));
      nq = fmax(nq, fabs(q[i]));
      np = fmax(np, fabs(p[i]));
    }
    err = fmax(err, fmax(dq / nq, dp / np));
  }
  CHECK(ok, "%s: step failed: %s", what, mrvi_integrator_errmsg(it));
  mrvi_integrator_free(it);
  return ok ? err : INFINITY;
}

static void compare(const mrvi_model *m, mrvi_settings s, classical c,
                    const char *what) {
  const double err = deviation(m, s, c, what);
  CHECK(err <= 1e-12, "%s: max relative deviation %.3e over 100 steps", what,
        err);
}

int main(void) {
  mrvi_model *models[2] = {test_fpu(), test_spring_ring()};
  const double h[2] = {0.01, 0.005};
  for (int k = 0; k < 2; k++) {
    const mrvi_model *m = models[k];
    const char *name = k ? "spring ring" : "fpu";
    char what[128];
    mrvi_settings s;
#define CASE(scheme, cls, label, ...)                                          \
  do {                                                                         \
    s = test_settings(scheme, h[k], 1, 1.0, 1e-12);                            \
    __VA_ARGS__;                                                               \
    snprintf(what, sizeof what, "%s: %s", name, label);                        \
    compare(m, s, cls, what);                                                  \
  } while (0)
    CASE("midpoint-midpoint", IMPLICIT_MIDPOINT,
         "midpoint-midpoint = implicit midpoint", (void)0);
    CASE("midpoint-midpoint", STORMER_VERLET,
         "trapezoidal alpha=1/2 = Stormer-Verlet",
         s.slow = (mrvi_rule){0.5, 1.0}, s.fast = (mrvi_rule){0.5, 0.0});
    CASE("fully-explicit", VELOCITY_VERLET, "fully-explicit = velocity Verlet",
         (void)0);
    CASE("trapezoidal-trapezoidal", SYMPLECTIC_EULER_A,
         "left rectangle (alpha=gamma=1) = symplectic Euler", (void)0);
    CASE("trapezoidal-trapezoidal", SYMPLECTIC_EULER_A,
         "left rectangle (alpha=gamma=0) = symplectic Euler",
         s.slow = (mrvi_rule){0.0, 0.0}, s.fast = (mrvi_rule){0.0, 0.0});
    CASE("trapezoidal-trapezoidal", SYMPLECTIC_EULER_B,
         "right rectangle (alpha=0, gamma=1) = adjoint symplectic Euler",
         s.slow = (mrvi_rule){0.0, 1.0}, s.fast = (mrvi_rule){0.0, 1.0});
    CASE("trapezoidal-midpoint", KICK_MIDPOINT,
         "trapezoidal-midpoint = kick + midpoint", (void)0);
    CASE("explicit-slow", IMEX, "explicit-slow = IMEX", (void)0);
#undef CASE
  }
  /* The check can fail: midpoint-midpoint is not Stormer-Verlet. */
  mrvi_settings s = test_settings("midpoint-midpoint", 0.01, 1, 1.0, 1e-12);
  const double control =
      deviation(models[0], s, STORMER_VERLET, "negative control");
  CHECK(control > 1e-4, "negative control: deviation %.3e must be large",
        control);
  mrvi_model_free(models[0]);
  mrvi_model_free(models[1]);
  return test_finish();
}
