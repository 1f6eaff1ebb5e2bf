/* Convergence orders (paper §6.2, Table tab:convergence rates, Lemma
 * th:approx): for p = 5 and 10 on the FPU and the spring ring, the macro-node
 * errors eq:err_mac in q and p against a single-rate midpoint reference with
 * a tiny step, fitted by least squares over halving macro steps: slope
 * 2 +- 0.25 for midpoint-midpoint, 1 +- 0.25 for trapezoidal-midpoint and
 * trapezoidal-trapezoidal.
 *
 * Each scheme is fitted where its asymptotic order shows.  Trapezoidal-
 * midpoint has a second-order fast error that dominates for larger steps
 * (paper §6.2: "starts with a convergence order of two, but reduces for tiny
 * time steps to one"); its first-order slow error takes over below
 * dT ~ 1e-3 on both systems, so its range starts at 5e-4. */
#include "model/model.h"
#include "models.h"
#include "testlib.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef struct traj {
  int n;
  long rows, cap;
  double *q, *p; /* rows x n */
} traj;

static int keep(void *user, const mrvi_record *r) {
  traj *T = user;
  if (T->rows == T->cap) {
    T->cap = T->cap ? 2 * T->cap : 4096;
    T->q = realloc(T->q, (size_t)T->cap * T->n * sizeof(double));
    T->p = realloc(T->p, (size_t)T->cap * T->n * sizeof(double));
  }
  memcpy(T->q + (size_t)T->rows * T->n, r->q, (size_t)T->n * sizeof(double));
  memcpy(T->p + (size_t)T->rows * T->n, r->p, (size_t)T->n * sizeof(double));
  T->rows++;
  return 0;
}

static traj run(const mrvi_model *m, mrvi_settings s) {
  traj T = {.n = m->n};
  mrvi_summary sum;
  int st = mrvi_run(m, &s, keep, &T, NULL, &sum);
  CHECK(st == 0, "run %s dT=%g p=%d: %s", s.scheme, s.macro_step, s.micro_steps,
        sum.message);
  return T;
}

/* Least-squares slope of log e against log dT. */
static double slope(int n, const double *dT, const double *e) {
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (int i = 0; i < n; i++) {
    double x = log(dT[i]), y = log(e[i]);
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
  }
  return (n * sxy - sx * sy) / (n * sxx - sx * sx);
}

typedef struct range {
  const char *scheme;
  double order; /* expected */
  double dT0;   /* largest macro step; LEVELS halvings */
  double t_end; /* horizon */
} range;

static void study(const mrvi_model *m, const char *name, const range *rg) {
  enum { LEVELS = 4, REF = 4 };
  const int ps[2] = {5, 10};
  for (int ip = 0; ip < 2; ip++) {
    const int p = ps[ip];
    /* Reference: single-rate midpoint, a step dividing every micro step. */
    const double dTmin = rg->dT0 / (1 << (LEVELS - 1));
    const double h = dTmin / (p * REF);
    traj ref =
        run(m, test_settings("midpoint-midpoint", h, 1, rg->t_end, 1e-12));
    double dT[LEVELS], eq[LEVELS], ep[LEVELS];
    for (int l = 0; l < LEVELS; l++) {
      dT[l] = rg->dT0 / (1 << l);
      traj T = run(m, test_settings(rg->scheme, dT[l], p, rg->t_end, 1e-12));
      const long stride = lround(dT[l] / h);
      eq[l] = ep[l] = 0.0;
      for (long k = 0; k < T.rows && k * stride < ref.rows; k++) {
        double dq = 0, dp = 0;
        for (int i = 0; i < m->n; i++) {
          double a = T.q[k * m->n + i] - ref.q[k * stride * m->n + i];
          double b = T.p[k * m->n + i] - ref.p[k * stride * m->n + i];
          dq += a * a;
          dp += b * b;
        }
        eq[l] = fmax(eq[l], sqrt(dq));
        ep[l] = fmax(ep[l], sqrt(dp));
      }
      free(T.q);
      free(T.p);
    }
    const double oq = slope(LEVELS, dT, eq), op = slope(LEVELS, dT, ep);
    printf("%-12s %-24s p=%-2d dT %.4g..%.4g  e_q %.2e..%.2e order %.2f  "
           "e_p %.2e..%.2e order %.2f\n",
           name, rg->scheme, p, dT[0], dT[LEVELS - 1], eq[0], eq[LEVELS - 1],
           oq, ep[0], ep[LEVELS - 1], op);
    CHECK(fabs(oq - rg->order) <= 0.25, "%s %s p=%d: order in q %.3f", name,
          rg->scheme, p, oq);
    CHECK(fabs(op - rg->order) <= 0.25, "%s %s p=%d: order in p %.3f", name,
          rg->scheme, p, op);
    free(ref.q);
    free(ref.p);
  }
}

int main(void) {
  mrvi_model *fpu = test_fpu(), *ring = test_spring_ring();
  const range fpu_ranges[3] = {{"midpoint-midpoint", 2, 0.02, 0.5},
                               {"trapezoidal-midpoint", 1, 5e-4, 0.1},
                               {"trapezoidal-trapezoidal", 1, 0.02, 0.5}};
  const range ring_ranges[3] = {{"midpoint-midpoint", 2, 0.01, 0.5},
                                {"trapezoidal-midpoint", 1, 5e-4, 0.1},
                                {"trapezoidal-trapezoidal", 1, 0.01, 0.5}};
  for (int i = 0; i < 3; i++) {
    study(fpu, "fpu", &fpu_ranges[i]);
    study(ring, "spring ring", &ring_ranges[i]);
  }
  mrvi_model_free(fpu);
  mrvi_model_free(ring);
  return test_finish();
}
