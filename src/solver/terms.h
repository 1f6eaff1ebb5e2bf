/* The compiled potential classes' records and evaluation kernels
 * (solver/terms.c, doc/solver.md "Evaluation"), in a header so that the
 * step loops of the structured paths inline the gradient of the classes
 * whose terms all sit in compact runs (mrvi_terms_grad_k).  The arithmetic
 * is that of mrvi_element_eval and the laws, in the same order, so the
 * results are bitwise the same wherever the kernel is compiled. */
#ifndef MRVI_SOLVER_TERMS_H
#define MRVI_SOLVER_TERMS_H

#include "internal.h"
#include "small.h"

enum { KT_LINEAR, KT_POWER, KT_LAW, KT_ELEMENT };
typedef struct kterm {
  int kind, n, first; /* inputs col[first..first+n), coef[first..] */
  int k;              /* integer exponent (KT_POWER) */
  int run; /* KT_LINEAR with one input: the number of such terms from here */
  double c, e, shift; /* stiffness or coefficient, exponent, offset b */
  const mrvi_element *el;
  int run4, q4; /* KT_LINEAR or KT_POWER with 2..4 inputs: the number of
                   such terms from here, their first record in q4 */
} kterm;

/* The few-input terms compact and contiguous (kterm4 runs). */
typedef struct kterm4 {
  int n, k; /* inputs; integer exponent, -1 for the linear law */
  int col[4];
  double a[4];
  double c, e, shift;
  double ce, ce1; /* c e and c e (e - 1) (power_derivs' products) */
} kterm4;

struct mrvi_terms {
  const mrvi_model *m;
  int n;
  kterm *t;
  int *col;
  double *coef;
  double *y, *g, *H; /* element workspace */
  kterm4 *q4;
  int compact; /* every term in a run: mrvi_terms_grad_k inline */
};

/* phi' and phi'' of c s^e for a small integer e = k (laws/power.c without
 * phi, by repeated multiplication), from ce = c e and ce1 = c e (e - 1). */
static inline void power_derivs_ce(double ce, double ce1, int k, double s,
                                   double *d1, double *d2) {
  double sk = 1.0; /* s^(k-2), the product order of laws/power.c */
  switch (k) {
  case 3:
    sk = 1.0 * s;
    break;
  case 4:
    sk = (1.0 * s) * s;
    break;
  default:
    for (int i = 2; i < k; i++)
      sk *= s;
  }
  *d1 = k >= 1 ? ce * (k >= 2 ? sk * s : 1.0) : 0.0;
  *d2 = k >= 2 ? ce1 * sk : 0.0;
}

static inline void power_derivs(double c, double e, int k, double s, double *d1,
                                double *d2) {
  power_derivs_ce(c * e, c * e * (e - 1), k, s, d1, d2);
}

/* One term phi(a^T z - b) with n inputs: gradient into g, Hessian into J
 * (inlined with a constant n for the common sizes). */
ALWAYS_INLINE void term_eval(const kterm *t, const int *col, const double *a,
                             const double *z, double scale, double *g,
                             double *J, int ld, double hscale, const int n) {
  double s = -t->shift;
#pragma GCC unroll 4
  for (int j = 0; j < n; j++)
    s += a[j] * z[col[j]];
  double phi, d1, d2;
  if (t->kind == KT_LINEAR) {
    d1 = t->c * s;
    d2 = t->c;
  } else if (t->kind == KT_POWER) {
    power_derivs(t->c, t->e, t->k, s, &d1, &d2);
  } else {
    t->el->law->eval(t->el->params, s, &phi, &d1, &d2);
  }
#pragma GCC unroll 4
  for (int j = 0; j < n; j++)
    g[col[j]] += scale * (d1 * a[j]);
  if (J)
#pragma GCC unroll 4
    for (int j = 0; j < n; j++) {
      const double u = d2 * a[j];
      double *Jj = J + (size_t)col[j] * (size_t)ld;
#pragma GCC unroll 4
      for (int l = 0; l < n; l++)
        Jj[col[l]] += hscale * (u * a[l]);
    }
}

/* A compact term with n inputs (term_eval's arithmetic; unit: scale and
 * hscale are 1, whose products are left out, bitwise the same) and law k
 * (-1 linear, else the power's integer exponent; K_ANY: the record's).
 * Its data is read into locals first: the stores into g and J could alias
 * it. */
enum { K_ANY = -2 };
ALWAYS_INLINE void term4_eval(const kterm4 *q, const double *z, double scale,
                              double *g, double *J, int ld, double hscale,
                              const int n, const int unit, const int kk) {
  int col[4];
  double a[4];
  UNROLL for (int j = 0; j < n; j++) {
    col[j] = q->col[j];
    a[j] = q->a[j];
  }
  const double c = q->c;
  const int k = kk == K_ANY ? q->k : kk;
  double s = -q->shift;
  UNROLL for (int j = 0; j < n; j++) s += a[j] * z[col[j]];
  double d1, d2;
  if (k < 0) {
    d1 = c * s;
    d2 = c;
  } else {
    power_derivs_ce(q->ce, q->ce1, k, s, &d1, &d2);
  }
  UNROLL for (int j = 0; j < n; j++) g[col[j]] +=
      unit ? d1 * a[j] : scale * (d1 * a[j]);
  if (J)
    UNROLL for (int j = 0; j < n; j++) {
      const double u = d2 * a[j];
      double *Jj = J + (size_t)col[j] * (size_t)ld;
      UNROLL for (int l = 0; l < n; l++) Jj[col[l]] +=
          unit ? u * a[l] : hscale * (u * a[l]);
    }
}

/* A run of nr compact terms with n inputs each and one law (linear and
 * the quartic with the law a constant). */
ALWAYS_INLINE void run4_n(const kterm4 *q, int nr, const double *z,
                          double scale, double *g, double *J, int ld,
                          double hscale, const int n, const int unit) {
  switch (q->k) {
  case -1:
    for (int r = 0; r < nr; r++)
      term4_eval(q + r, z, scale, g, J, ld, hscale, n, unit, -1);
    break;
  case 4:
    for (int r = 0; r < nr; r++)
      term4_eval(q + r, z, scale, g, J, ld, hscale, n, unit, 4);
    break;
  default:
    for (int r = 0; r < nr; r++)
      term4_eval(q + r, z, scale, g, J, ld, hscale, n, unit, K_ANY);
  }
}

ALWAYS_INLINE void run4_eval(const kterm4 *q, int nr, const double *z,
                             double scale, double *g, double *J, int ld,
                             double hscale, const int unit) {
  switch (q->n) {
  case 2:
    run4_n(q, nr, z, scale, g, J, ld, hscale, 2, unit);
    break;
  case 3:
    run4_n(q, nr, z, scale, g, J, ld, hscale, 3, unit);
    break;
  default:
    run4_n(q, nr, z, scale, g, J, ld, hscale, 4, unit);
  }
}

/* A run of nr one-input linear terms from t (col, a: their inputs). */
ALWAYS_INLINE void run1_eval(const kterm *t, int nr, const int *col,
                             const double *a, const double *z, double scale,
                             double *g, double *J, int ld, double hscale) {
  for (int r = 0; r < nr; r++) {
    const double ar = a[r], d1 = t[r].c * (-t[r].shift + ar * z[col[r]]);
    g[col[r]] += scale * (d1 * ar);
    if (J)
      J[col[r] * ld + col[r]] += hscale * (t[r].c * ar * ar);
  }
}

ALWAYS_INLINE void eval_k(mrvi_terms *kc, const double *z, double scale,
                          double *g, double *J, int ld, double hscale,
                          const int unit) {
  for (int it = 0; it < kc->n; it++) {
    const kterm *t = &kc->t[it];
    if (t->run4 > 0) {
      run4_eval(kc->q4 + t->q4, t->run4, z, scale, g, J, ld, hscale, unit);
      it += t->run4 - 1;
      continue;
    }
    const int n = t->n, *col = kc->col + t->first;
    const double *a = kc->coef + t->first;
    if (t->run > 1) { /* as below, one input each */
      run1_eval(t, t->run, col, a, z, scale, g, J, ld, hscale);
      it += t->run - 1;
      continue;
    }
    if (t->kind == KT_ELEMENT) {
      const int lin = t->el->kind == MRVI_ELEMENT_GRAVITY;
      for (int j = 0; j < n; j++)
        kc->y[j] = z[col[j]];
      mrvi_element_eval(kc->m, t->el, kc->y, kc->g, J && !lin ? kc->H : NULL);
      for (int j = 0; j < n; j++)
        g[col[j]] += scale * kc->g[j];
      if (J && !lin)
        for (int j = 0; j < n; j++)
          for (int l = 0; l < n; l++)
            J[col[j] * ld + col[l]] += hscale * kc->H[j * n + l];
      continue;
    }
    /* Unrolled for the common few-input terms. */
    SMALL(n, N, term_eval(t, col, a, z, scale, g, J, ld, hscale, N));
  }
}

/* g += grad Z(z), inline for compact classes (every term in a run: the
 * kernels of mrvi_terms_grad, bitwise the same), through mrvi_terms_grad
 * otherwise. */
ALWAYS_INLINE void mrvi_terms_grad_k(mrvi_terms *kc, const double *z,
                                     double *g) {
  if (!kc->compact) {
    mrvi_terms_grad(kc, z, g);
    return;
  }
  for (int it = 0; it < kc->n;) {
    const kterm *t = &kc->t[it];
    if (t->run4 > 0) {
      run4_eval(kc->q4 + t->q4, t->run4, z, 1.0, g, NULL, 0, 0.0, 1);
      it += t->run4;
    } else {
      run1_eval(t, t->run, kc->col + t->first, kc->coef + t->first, z, 1.0, g,
                NULL, 0, 0.0);
      it += t->run;
    }
  }
}

#endif
