/* Potential classes compiled for evaluation (doc/solver.md, "Evaluation"):
 * the elements of one class with their inputs mapped once to columns of a
 * packed configuration z, so that the step loops evaluate the gradient (and
 * Hessian) without looking up rates and slots per input.  Terms phi(s),
 * s = a^T q - b, are evaluated here (the linear law inline, others through
 * their law table); every other element through mrvi_element_eval.  The
 * arithmetic is that of mrvi_element_eval and the laws, in the same order,
 * so the results are bitwise the same. */
#include "terms.h"

#include <stdlib.h>
#include <string.h>

/* A power law with a small integer exponent (evaluated inline). */
static int small_power(const mrvi_element *e) {
  extern const mrvi_law mrvi_law_power;
  const double x = e->params[1];
  return e->law == &mrvi_law_power && x >= 0.0 && x <= 8.0 &&
         (double)(int)x == x;
}

void mrvi_term_derivs(const mrvi_element *e, double s, double *d1, double *d2) {
  extern const mrvi_law mrvi_law_linear;
  if (e->law == &mrvi_law_linear) {
    *d1 = e->params[0] * s;
    *d2 = e->params[0];
  } else if (small_power(e)) {
    power_derivs(e->params[0], e->params[1], (int)e->params[1], s, d1, d2);
  } else {
    double phi;
    e->law->eval(e->params, s, &phi, d1, d2);
  }
}

void mrvi_terms_free(mrvi_terms *kc) {
  if (!kc)
    return;
  free(kc->t);
  free(kc->col);
  free(kc->coef);
  free(kc->y);
  free(kc->g);
  free(kc->H);
  free(kc->q4);
  free(kc);
}

int mrvi_terms_create(const mrvi_model *m, const int *elems, int n_elems,
                      const int *col_of, mrvi_terms **out) {
  extern const mrvi_law mrvi_law_linear;
  mrvi_terms *kc = calloc(1, sizeof *kc);
  *out = NULL;
  if (!kc)
    return MRVI_ENOMEM;
  int n_in = 0, max_in = 1;
  for (int ie = 0; ie < n_elems; ie++) {
    const int k = m->elements[elems[ie]].n_in;
    n_in += k;
    max_in = k > max_in ? k : max_in;
  }
  const size_t mi = (size_t)max_in;
  kc->m = m;
  kc->n = n_elems;
  kc->t = calloc((size_t)(n_elems > 0 ? n_elems : 1), sizeof *kc->t);
  kc->col = calloc((size_t)(n_in > 0 ? n_in : 1), sizeof *kc->col);
  kc->coef = calloc((size_t)(n_in > 0 ? n_in : 1), sizeof *kc->coef);
  kc->y = calloc(mi, sizeof *kc->y);
  kc->g = calloc(mi, sizeof *kc->g);
  kc->H = calloc(mi * mi, sizeof *kc->H);
  if (!kc->t || !kc->col || !kc->coef || !kc->y || !kc->g || !kc->H) {
    mrvi_terms_free(kc);
    return MRVI_ENOMEM;
  }
  int first = 0;
  for (int ie = 0; ie < n_elems; ie++) {
    const mrvi_element *e = &m->elements[elems[ie]];
    kterm *t = &kc->t[ie];
    t->el = e;
    t->n = e->n_in;
    t->first = first;
    t->kind = KT_ELEMENT;
    if (e->kind == MRVI_ELEMENT_TERM) {
      t->kind = e->law == &mrvi_law_linear ? KT_LINEAR : KT_LAW;
      t->shift = e->shift;
      t->c = e->params[0];
      t->e = e->params[1];
      if (small_power(e)) {
        t->kind = KT_POWER;
        t->k = (int)t->e;
      }
    }
    for (int j = 0; j < e->n_in; j++) {
      kc->col[first + j] = col_of ? col_of[e->in[j]] : e->in[j];
      kc->coef[first + j] = e->coef ? e->coef[j] : 0.0;
    }
    first += e->n_in;
  }
  /* Runs of one-input linear terms (k q^2/2 on a coordinate: the stiff
   * springs of W in the FPU) are evaluated in one loop, and so are runs of
   * terms with 2..4 inputs of the linear or a small power law (the quartic
   * springs of V in the FPU), from compact records, one loop per run of
   * terms with the same input count and law. */
  int n4 = 0;
  for (int ie = n_elems - 1; ie >= 0; ie--) {
    kterm *t = &kc->t[ie];
    const int next = ie + 1 < n_elems;
    if (t->kind == KT_LINEAR && t->n == 1)
      t->run = 1 + (next ? kc->t[ie + 1].run : 0);
    if ((t->kind == KT_LINEAR || t->kind == KT_POWER) && t->n >= 2 &&
        t->n <= 4) {
      /* (runs of one input count and one law) */
      const kterm *u = next ? &kc->t[ie + 1] : NULL;
      const int same = u && u->run4 > 0 && u->n == t->n && u->kind == t->kind &&
                       (t->kind == KT_LINEAR || u->k == t->k);
      t->run4 = 1 + (same ? u->run4 : 0);
      n4++;
    }
  }
  if (!(kc->q4 = calloc((size_t)(n4 > 0 ? n4 : 1), sizeof *kc->q4))) {
    mrvi_terms_free(kc);
    return MRVI_ENOMEM;
  }
  for (int ie = 0, i4 = 0; ie < n_elems; ie++) {
    kterm *t = &kc->t[ie];
    if (t->run4 == 0)
      continue;
    kterm4 *q = &kc->q4[t->q4 = i4++];
    q->n = t->n;
    q->k = t->kind == KT_LINEAR ? -1 : t->k;
    q->c = t->c;
    q->e = t->e;
    q->shift = t->shift;
    q->ce = t->c * t->e;
    q->ce1 = t->c * t->e * (t->e - 1);
    for (int j = 0; j < t->n; j++) {
      q->col[j] = kc->col[t->first + j];
      q->a[j] = kc->coef[t->first + j];
    }
  }
  /* Compact: eval_k takes a run at every term it starts from. */
  kc->compact = 1;
  for (int ie = 0; ie < n_elems;) {
    const kterm *t = &kc->t[ie];
    const int r = t->run4 > 0 ? t->run4 : t->run > 1 ? t->run : 0;
    if (r == 0) {
      kc->compact = 0;
      break;
    }
    ie += r;
  }
  *out = kc;
  return MRVI_OK;
}

void mrvi_terms_eval(mrvi_terms *kc, const double *z, double scale, double *g,
                     double *J, int ld, double hscale) {
  if (scale == 1.0 && (!J || hscale == 1.0))
    eval_k(kc, z, scale, g, J, ld, hscale, 1);
  else
    eval_k(kc, z, scale, g, J, ld, hscale, 0);
}

/* Gradient only: the evaluation above with scale 1 and no Hessian (the
 * same products in the same order, so bitwise the same gradient). */
void mrvi_terms_grad(mrvi_terms *kc, const double *z, double *g) {
  eval_k(kc, z, 1.0, g, NULL, 0, 0.0, 1);
}

/* c s^k for a small integer k: laws/power.c's phi (s^k by repeated
 * squaring, the same products). */
static double power_phi(double c, int k, double s) {
  double r = 1.0;
  for (long kk = k; kk > 0; kk >>= 1) {
    if (kk & 1)
      r *= s;
    s *= s;
  }
  return c * r;
}

double mrvi_terms_value(mrvi_terms *kc, const double *z) {
  double total = 0.0;
  for (int it = 0; it < kc->n; it++) {
    const kterm *t = &kc->t[it];
    const int n = t->n, *col = kc->col + t->first;
    const double *a = kc->coef + t->first;
    if (t->kind == KT_ELEMENT) {
      if (t->el->kind == MRVI_ELEMENT_GRAVITY) { /* input by input */
        for (int j = 0; j < n; j++)
          total += a[j] * z[col[j]];
        continue;
      }
      for (int j = 0; j < n; j++)
        kc->y[j] = z[col[j]];
      total += mrvi_element_eval(kc->m, t->el, kc->y, NULL, NULL);
      continue;
    }
    double s = -t->shift, phi, d1, d2;
    for (int j = 0; j < n; j++)
      s += a[j] * z[col[j]];
    if (t->kind == KT_LINEAR)
      phi = 0.5 * t->c * s * s; /* laws/linear.c */
    else if (t->kind == KT_POWER)
      phi = power_phi(t->c, t->k, s);
    else
      t->el->law->eval(t->el->params, s, &phi, &d1, &d2);
    total += phi;
  }
  return total;
}
