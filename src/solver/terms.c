/* Potential classes compiled for evaluation (doc/solver.md, "Evaluation"):
 * the elements of one class with their inputs mapped once to columns of a
 * packed configuration z, so that the step loops evaluate the gradient (and
 * Hessian) without looking up rates and slots per input.  Terms phi(s),
 * s = a^T q - b, are evaluated here (the linear law inline, others through
 * their law table), and so are springs and anchors phi(|d| - L0), d =
 * x_i - x_j or x_i - a (the Hooke and small power forms inline, others
 * through their law table: the gradient phi' n on x_i, -phi' n on x_j with
 * n = d / |d|, the Hessian phi'' n n^T + phi'/|d| (I - n n^T) in blocks
 * of +-1); every other element through mrvi_element_eval.  The
 * arithmetic is that of mrvi_element_eval and the laws, in the same order,
 * so the results are bitwise the same. */
#include "solver/solver.h"
#include "util/simd.h"
#include "util/small.h"

#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

enum { KT_LINEAR, KT_POWER, KT_LAW, KT_ELEMENT };
enum { K_ANY = -2 }; /* law of a compact record: its own (kterm4.k) */
typedef struct kterm {
  /* inputs col[first..first+n) and, for an element with coefficients (terms,
   * gravity), coef[cfirst..cfirst+n); a spring or anchor compiled to a
   * kspring record has neither (its columns are in the record) */
  int kind, n, first, cfirst;
  int k;   /* integer exponent (KT_POWER) */
  int run; /* KT_LINEAR with one input: the number of such terms from here */
  double c, e, shift; /* stiffness or coefficient, exponent, offset b */
  const mrvi_element *el;
  int run4, q4; /* KT_LINEAR or KT_POWER with 2..4 inputs: the number of
                   such terms from here, their first record in q4 */
  int runs, qs; /* a spring or anchor: the number of such elements of one
                   law code (kspring.k) from here, their first record in qs */
} kterm;

/* Springs and anchors compact and contiguous (kspring runs): the columns of
 * x_i and x_j (x_j's unused for an anchor, whose point is el->anchor: read
 * there, not copied, anchors being few beside springs) and the law:
 * k = KS_HOOKE (phi' = c s), 0..8 (c s^k, mrvi_power_derivs_ce from ce and
 * ce1), KS_MORSE (c = a, ce = 2 D a, ce1 = 2 D a a: laws/morse.c inline)
 * or KS_LAW (the law table of el). */
enum { KS_HOOKE = -1, KS_LAW = -3, KS_MORSE = -4 };
typedef struct kspring {
  int two, k;
  int ci[3], cj[3];
  double c, shift, ce, ce1;
  const mrvi_element *el;
} kspring;

/* A Hooke spring whose particles' coordinates are consecutive columns
 * (ci..ci+dim-1, cj..cj+dim-1): the data its gradient reads, a quarter of
 * a kspring (the explicit paths' loop streams them). */
typedef struct khooke {
  int ci, cj;
  double c, shift;
} khooke;

/* The columns of a khooke spring, where a class's springs share one
 * stiffness and rest length (hooke_class: a third of a khooke). */
typedef struct khpair {
  int ci, cj;
} khpair;

/* A spring of a class whose springs share one law and its parameters, on
 * consecutive columns (spring_class: the random networks' Morse springs):
 * its first columns and rest length, the rest of its kspring once per
 * class (16 bytes a spring instead of 72). */
typedef struct kspair {
  int ci, cj;
  double shift;
} kspair;

/* khooke records as the kernels read them: q[r], or the columns pr[r] with
 * the class's c and shift. */
typedef struct hsrc {
  const khooke *q;
  const khpair *pr;
  double c, shift;
} hsrc;

ALWAYS_INLINE khooke hooke_rec(hsrc s, int r) {
  return s.pr ? (khooke){s.pr[r].ci, s.pr[r].cj, s.c, s.shift} : s.q[r];
}

/* The few-input terms compact and contiguous (kterm4 runs). */
typedef struct kterm4 {
  int n, k; /* inputs; integer exponent, -1 for the linear law */
  int col[4];
  double a[4];
  double c, e, shift;
  double ce, ce1; /* c e and c e (e - 1) (mrvi_power_derivs' products) */
} kterm4;

struct mrvi_terms {
  const mrvi_model *m;
  int n;
  kterm *t;
  int *col;
  double *coef;
  double *y, *g, *H; /* element workspace */
  kterm4 *q4;
  kspring *qs;
  khooke *qh; /* per record of qs (used where hooke_run) */
  /* A gradient-only class of khooke springs alone (hooke_class): qh
   * without t, col, coef, hooke_run or the elements (a Hooke spring's
   * record is all its gradient and value read); its gradient is hooke_grad
   * over qh, one run.  Where every spring has the stiffness and rest
   * length of the first, qp (its columns) with qp_c and qp_shift instead
   * of qh (the lattices: 8 bytes a spring instead of 24). */
  int hooke_only;
  int exact; /* mrvi_terms_create_grad_exact: hooke_only with hooke_grad's
                two divisions per spring */
  khpair *qp;
  double qp_c, qp_shift;
  /* A gradient-only class of springs or anchors of one kind and one law
   * code alone, not all khooke springs (spring_class): qs without t, col,
   * coef, qh or hooke_run; its gradient is springs_eval over qs, one run
   * (terms_springs would make the class one such run).  Where they are
   * springs of one law and one parameter set on consecutive columns, qm
   * (their columns and rest lengths) with qm_law (the rest of each one's
   * kspring: the first's) instead of qs, its gradient pairs_eval over qm;
   * qs is made from them where threads partition the class
   * (class_records). */
  int spring_only;
  kspair *qm;
  kspring qm_law;
  unsigned char *hooke_run; /* per record of qs: the run from it is of
                               khooke springs */
  /* A class of springs and anchors alone (every element a kspring record;
   * springs_runs): qs, qh and hooke_run as terms_springs makes them, and
   * instead of a kterm per element (t NULL) the first record of each run,
   * rs[0 .. n_rs] (rs[n_rs] = n): the loops over the kterms step from run
   * to run, term_at making each run's kterm (72 bytes an element less:
   * the random networks' fast springs on explicit-slow). */
  int *rs, n_rs;
  int dim; /* the model's dimension (a spring's inputs: 2 dim, an anchor's
              dim) */
  /* Every term a compact record (q4[0..n)): gradients by one loop over
   * them (flat_grad), with the law flat_k (K_ANY: each record's). */
  int flat, flat_k;
  /* flat_sym applies: flat, and every record's columns distinct */
  int sym;
  /* Threads (mrvi_terms_set_threads; part_grad): a class of springs and
   * anchors alone, its gradient's columns [0, ncol) in n_part parts of
   * `chunk` columns (a partition that depends on the class and chunk, not
   * on the number of threads).  Part c's records are part_rec[part_first[c]
   * .. part_first[c+1]), in the serial order, each with the mask of the
   * columns it writes in c (bit k: x_i's k-th, bit dim + k: x_j's): each
   * part writes its own columns alone, and every column sums its
   * contributions in the serial order, so the gradient is the serial one
   * bitwise for every number of threads (a record spanning parts is
   * evaluated once per part).  part_run[i] (khooke classes): the number
   * of consecutive records from entry i on that write all their columns
   * in the part (0 where entry i's mask lacks one), taken by the serial
   * kernel in one loop. */
  /* mrvi_terms_set_value_chunks: the value summed per chunk of vchunk
   * elements (0: in one sum), the chunks' sums vpart added in order;
   * the chunks on vthreads threads. */
  int vchunk, vthreads;
  double *vpart;
  int threads, chunk, n_part, ncol;
  int part_hooke; /* every record a khooke spring: part_hooke_k on qh */
  /* mrvi_terms_set_recip: mrvi_terms_grad's and mrvi_terms_grad_part's
   * khooke runs with one division per spring (hooke_grad1's arithmetic),
   * as a gradient-only class has them */
  int recip;
  int *part_first, *part_rec, *part_run;
  unsigned char *part_mask;
  /* mrvi_terms_set_fused (a class of khooke springs alone, one division
   * per spring, its records qh[0 .. n) in the serial order): the records
   * in blocks of fuse_b, and after block b every column below fuse_done[b]
   * complete (no later record reads or writes it); fuse_zero[b]: one past
   * the largest column blocks 0..b touch (the columns zeroed before block
   * b, none touched before).  fuse_ncol: the columns. */
  int fuse_nb, fuse_b, fuse_ncol;
  int *fuse_zero, *fuse_done;
};

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
  free(kc->qs);
  free(kc->qh);
  free(kc->qp);
  free(kc->qm);
  free(kc->hooke_run);
  free(kc->rs);
  free(kc->part_first);
  free(kc->vpart);
  free(kc->part_rec);
  free(kc->part_mask);
  free(kc->part_run);
  free(kc->fuse_zero);
  free(kc->fuse_done);
  free(kc);
}

/* Element it's kterm: kc->t[it], or in a class kept without them
 * (springs_runs) the kterm terms_springs would have made, the run of
 * records from it (the last of its run's in rs: a binary search) into
 * tmp. */
ALWAYS_INLINE const kterm *term_at(const mrvi_terms *kc, int it, kterm *tmp) {
  if (kc->t)
    return &kc->t[it];
  int lo = 0, hi = kc->n_rs; /* rs[lo] <= it < rs[hi] */
  while (hi - lo > 1) {
    const int mid = (lo + hi) / 2;
    if (kc->rs[mid] <= it)
      lo = mid;
    else
      hi = mid;
  }
  const kspring *q = kc->qs ? &kc->qs[it] : NULL; /* (NULL: khooke) */
  *tmp = (kterm){.kind = KT_ELEMENT,
                 .n = (!q || q->two ? 2 : 1) * kc->dim,
                 .el = q ? q->el : NULL,
                 .runs = kc->rs[hi] - it,
                 .qs = it};
  return tmp;
}

/* Record r of a class of khooke springs kept without kspring records
 * (springs_runs) as its kspring: a Hooke spring's fields that the kernels
 * read (two, k, c, shift, the columns), the values spring_law_of and
 * spring_cols give them. */
ALWAYS_INLINE kspring hooke_spring(const khooke *h, int dim) {
  kspring q = {.two = 1, .k = KS_HOOKE, .c = h->c, .shift = h->shift};
  for (int k = 0; k < dim; k++) {
    q.ci[k] = h->ci + k;
    q.cj[k] = h->cj + k;
  }
  return q;
}

/* Records r0 .. r0 + nr - 1 (nr <= KS_PIECE unless kc->qs) as kspring
 * records: kc->qs + r0, or made into buf from qh where the class keeps
 * none. */
enum { KS_PIECE = 64 };
ALWAYS_INLINE const kspring *springs_at(const mrvi_terms *kc, int r0, int nr,
                                        kspring *buf) {
  if (kc->qs)
    return kc->qs + r0;
  for (int r = 0; r < nr; r++)
    buf[r] = hooke_spring(&kc->qh[r0 + r], kc->dim);
  return buf;
}

/* A run of nr records from r0 through a kernel CALL(q, n, r) (the n
 * records q, the r-th of the run first): at once from qs, or in pieces of
 * KS_PIECE made from qh, in their order (each record's sums as at once:
 * the same bits). */
#define SPRING_PIECES(kc, r0, nr, CALL)                                        \
  do {                                                                         \
    kspring piece_[KS_PIECE];                                                  \
    const int step_ = (kc)->qs ? (nr) : KS_PIECE;                              \
    for (int r_ = 0; r_ < (nr); r_ += step_) {                                 \
      const int n_ = (nr)-r_ < step_ ? (nr)-r_ : step_;                        \
      const kspring *q_ = springs_at(kc, (r0) + r_, n_, piece_);               \
      CALL(q_, n_, r_);                                                        \
    }                                                                          \
  } while (0)

static int spring_law(const mrvi_element *e) {
  if (e->form == MRVI_LAW_FORM_HOOKE)
    return KS_HOOKE;
  if (e->form == MRVI_LAW_FORM_MORSE)
    return KS_MORSE;
  const double x = e->params[1];
  if (e->form == MRVI_LAW_FORM_POWER && x >= 0.0 && x <= 8.0 &&
      (double)(int)x == x)
    return (int)x;
  return KS_LAW;
}

/* Whether e is compiled to a kspring record (a spring or an anchor of
 * points, not of body points, which carry coefficients). */
static int spring_record(const mrvi_element *e, int dim) {
  const int two = e->kind == MRVI_ELEMENT_SPRING;
  return (two || e->kind == MRVI_ELEMENT_ANCHOR) && dim >= 1 && dim <= 3 &&
         e->n_in == (two ? 2 : 1) * dim && !e->coef;
}

/* The law of spring or anchor e into its record q. */
static void spring_law_of(const mrvi_element *e, kspring *q) {
  q->two = e->kind == MRVI_ELEMENT_SPRING;
  q->k = spring_law(e);
  q->el = mrvi_element_stable(e);
  q->c = e->params[0];
  q->shift = e->shift;
  q->ce = e->params[0] * e->params[1];
  q->ce1 = e->params[0] * e->params[1] * (e->params[1] - 1);
  if (q->k == KS_MORSE) { /* (laws/morse.c's products: 2 D a, 2 D a a) */
    q->c = e->params[1];
    q->ce = 2 * e->params[0] * e->params[1];
    q->ce1 = q->ce * e->params[1];
  }
}

/* The columns of spring or anchor e into its record q: col_of[e->in[.]],
 * or e->in itself without col_of (q->two set). */
static void spring_cols(const mrvi_element *e, const int *col_of, int dim,
                        kspring *q) {
  const int *in = e->in;
  for (int k = 0; k < dim; k++) {
    q->ci[k] = col_of ? col_of[in[k]] : in[k];
    q->cj[k] = q->two ? (col_of ? col_of[in[dim + k]] : in[dim + k]) : 0;
  }
}

/* The elements of a class being compiled: list[0 .. n - 1], or without a
 * list the consecutive elements first, first + 1, ... (a class of the step
 * that keeps no list, mrvi_step.elem_first: no temporary list, whose freed
 * pages glibc would keep, doc/performance/17-mem17.md). */
typedef struct elem_src {
  const int *list;
  int first;
} elem_src;

ALWAYS_INLINE int elem_at(elem_src s, int ie) {
  return s.list ? s.list[ie] : s.first + ie;
}

/* Element i as the loops below read it: its prototype where it is a
 * compact spring (every field but its rest length and inputs, which
 * compact_cols and spring_rec read from its record: no view made), else
 * the element. */
ALWAYS_INLINE const mrvi_element *law_el(const mrvi_model *m, int i) {
  const mrvi_element *p = mrvi_model_compact(m, i);
  return p ? p : mrvi_model_element(m, i, NULL);
}

/* Compact spring i's rest length and the first columns of its ends:
 * col_of[.] of their first coordinates, or those without col_of (its
 * view's shift and spring_cols' ci[0], cj[0]). */
ALWAYS_INLINE kspair compact_ends(const mrvi_model *m, int i,
                                  const int *col_of) {
  const mrvi_erec *r = &m->erecs[i];
  return col_of ? (kspair){col_of[r->ci], col_of[r->cj], r->shift}
                : (kspair){r->ci, r->cj, r->shift};
}

/* Whether each end of compact spring i has consecutive columns (its
 * coordinates do: so without col_of). */
ALWAYS_INLINE int compact_consecutive(const mrvi_model *m, int i,
                                      const int *col_of, int dim) {
  const mrvi_erec *r = &m->erecs[i];
  int ok = 1;
  for (int k = 1; col_of && k < dim; k++)
    ok &= (col_of[r->ci + k] == col_of[r->ci] + k) &
          (col_of[r->cj + k] == col_of[r->cj] + k);
  return ok;
}

/* The record of spring or anchor element i, e = law_el(m, i): spring_law_of
 * and spring_cols of the element (a compact spring's rest length and
 * columns from its record). */
static void spring_rec(const mrvi_model *m, int i, const mrvi_element *e,
                       const int *col_of, int dim, kspring *q) {
  spring_law_of(e, q);
  if (!mrvi_model_compact(m, i)) {
    spring_cols(e, col_of, dim, q);
    return;
  }
  const mrvi_erec *r = &m->erecs[i];
  q->shift = r->shift;
  for (int k = 0; k < dim; k++) {
    q->ci[k] = col_of ? col_of[r->ci + k] : r->ci + k;
    q->cj[k] = col_of ? col_of[r->cj + k] : r->cj + k;
  }
}

/* The khooke records of kc as the kernels read them. */
static hsrc hooke_src(const mrvi_terms *kc) {
  return (hsrc){kc->qh, kc->qp, kc->qp_c, kc->qp_shift};
}

/* The kspring records of a class whose every run is of khooke springs,
 * from those (their columns consecutive from khooke's): the records
 * terms_springs and hooke_class leave out of a gradient-only class. */
static int hooke_records(mrvi_terms *kc) {
  int ns = 0;
  const int all = kc->hooke_only || kc->rs; /* (rs: khooke springs) */
  for (int ie = 0; ie < kc->n; ie++)
    ns += all || kc->t[ie].runs > 0;
  kc->qs = calloc((size_t)(ns > 0 ? ns : 1), sizeof *kc->qs);
  if (!kc->qs)
    return MRVI_ENOMEM;
  for (int ie = 0; ie < kc->n; ie++) {
    if (!all && kc->t[ie].runs == 0)
      continue;
    const int r = all ? ie : kc->t[ie].qs;
    kspring *q = &kc->qs[r];
    const khooke h = hooke_rec(hooke_src(kc), r);
    if (all) { /* (a Hooke spring: its law is its khooke's) */
      *q = hooke_spring(&h, kc->dim);
      continue;
    }
    spring_law_of(kc->t[ie].el, q);
    q->shift = h.shift; /* (the element's: t->el may be its law alone) */
    for (int k = 0; k < kc->dim; k++) {
      q->ci[k] = h.ci + k;
      q->cj[k] = h.cj + k;
    }
  }
  return MRVI_OK;
}

/* Record r of a class of kspair records as a kspring (the same values as
 * spring_law_of and spring_cols give it). */
ALWAYS_INLINE kspring pair_spring(const mrvi_terms *kc, int r) {
  kspring q = kc->qm_law;
  const kspair *pr = &kc->qm[r];
  for (int k = 0; k < 3; k++) {
    q.ci[k] = pr->ci + k;
    q.cj[k] = pr->cj + k;
  }
  q.shift = pr->shift;
  return q;
}

/* The kspring records of a gradient-only class that keeps fewer (the
 * threads' partition reads them): from its kspair records, else
 * hooke_records. */
static int class_records(mrvi_terms *kc) {
  if (!kc->qm)
    return hooke_records(kc);
  kc->qs = malloc((size_t)(kc->n > 0 ? kc->n : 1) * sizeof *kc->qs);
  if (!kc->qs)
    return MRVI_ENOMEM;
  for (int r = 0; r < kc->n; r++)
    kc->qs[r] = pair_spring(kc, r);
  return MRVI_OK;
}

/* The first ne columns qp of a class that shared one stiffness and rest
 * length as khooke records qh (for the class's ne + 1 and later springs,
 * which do not share them). */
static int hooke_unshare(mrvi_terms *kc, int ne) {
  kc->qh = malloc((size_t)kc->n * sizeof *kc->qh);
  if (!kc->qh)
    return MRVI_ENOMEM;
  for (int r = 0; r < ne; r++)
    kc->qh[r] = hooke_rec(hooke_src(kc), r);
  free(kc->qp);
  kc->qp = NULL;
  return MRVI_OK;
}

/* The number of compact springs from elem_at(elems, 0) on of prototype lp, each
 * end on consecutive columns col_of[.] (or coordinates without col_of)
 * and, where qp, of the rest length `shift` (its bits): their columns into
 * qp (hooke_class's records of the springs of one law and rest length,
 * the lattices', and shared_law's check of one law and parameter set, the
 * random networks', read from the records alone). */
ALWAYS_INLINE int compact_run_k(const mrvi_model *m, elem_src elems, int n,
                                const int *col_of, const int dim, int lp,
                                double shift, khpair *restrict qp) {
  const mrvi_erec *rec = m->erecs;
  int ie = 0;
  for (; ie < n; ie++) {
    const mrvi_erec *r = &rec[elem_at(elems, ie)];
    if (!r->compact || r->lp != lp ||
        (qp && memcmp(&r->shift, &shift, sizeof shift) != 0))
      break;
    int ok = 1;
    if (col_of)
      for (int k = 1; k < dim; k++)
        ok &= (col_of[r->ci + k] == col_of[r->ci] + k) &
              (col_of[r->cj + k] == col_of[r->cj] + k);
    if (!ok)
      break;
    if (qp)
      qp[ie] = col_of ? (khpair){col_of[r->ci], col_of[r->cj]}
                      : (khpair){r->ci, r->cj};
  }
  return ie;
}

static int compact_run(const mrvi_model *m, elem_src elems, int n,
                       const int *col_of, int dim, int lp, double shift,
                       khpair *qp) {
  return dim == 2   ? compact_run_k(m, elems, n, col_of, 2, lp, shift, qp)
         : dim == 3 ? compact_run_k(m, elems, n, col_of, 3, lp, shift, qp)
                    : compact_run_k(m, elems, n, col_of, dim, lp, shift, qp);
}

/* A gradient-only class whose elements are all Hooke springs on
 * consecutive columns (terms_springs would make them one run of khooke
 * springs): their khooke records and elements alone, no kterm (the
 * lattices' classes on the explicit paths).  0 if the class is not such,
 * else 1, or MRVI_ENOMEM. */
static int hooke_class(mrvi_terms *kc, const mrvi_model *m, elem_src elems,
                       int n_elems, const int *col_of) {
  const int dim = kc->dim;
  if (n_elems < 1)
    return 0;
  /* (one pass, the records made as the elements are checked: columns
   * alone while the springs share the first's stiffness and rest length,
   * khooke records from the first that does not) */
  khpair *qp = kc->qp = malloc((size_t)n_elems * sizeof *kc->qp);
  if (!qp)
    return MRVI_ENOMEM;
  const mrvi_element *hooke = NULL; /* (a law found to be Hooke's) */
  /* (the springs from the first on that share its prototype, a Hooke
   * spring's, and rest length in one loop: the values the loop below
   * would give them) */
  int ie0 = 0;
  const mrvi_element *p0 = mrvi_model_compact(m, elem_at(elems, 0));
  if (p0 && spring_record(p0, dim) && p0->form == MRVI_LAW_FORM_HOOKE) {
    const mrvi_erec *r0 = &m->erecs[elem_at(elems, 0)];
    ie0 = compact_run(m, elems, n_elems, col_of, dim, r0->lp, r0->shift, qp);
    kc->qp_c = p0->params[0];
    kc->qp_shift = r0->shift;
    hooke = p0;
  }
  for (int ie = ie0; ie < n_elems; ie++) {
    const int i = elem_at(elems, ie);
    const mrvi_element *e = law_el(m, i);
    /* (a Hooke spring's record: spring_law_of's c and shift, spring_cols'
     * first columns; the law's other products are not read) */
    khooke h;
    int ok = e == hooke ||
             (spring_record(e, dim) && e->kind == MRVI_ELEMENT_SPRING &&
              e->form == MRVI_LAW_FORM_HOOKE);
    if (ok && mrvi_model_compact(m, i)) {
      const kspair pr = compact_ends(m, i, col_of);
      h = (khooke){pr.ci, pr.cj, e->params[0], pr.shift};
      ok = compact_consecutive(m, i, col_of, dim);
      hooke = e;
    } else if (ok) {
      const int *in = e->in;
      h.c = e->params[0];
      h.shift = e->shift;
      h.ci = col_of ? col_of[in[0]] : in[0];
      h.cj = col_of ? col_of[in[dim]] : in[dim];
      for (int k = 1; ok && k < dim; k++)
        ok = (col_of ? col_of[in[k]] : in[k]) == h.ci + k &&
             (col_of ? col_of[in[dim + k]] : in[dim + k]) == h.cj + k;
    }
    if (!ok) {
      free(kc->qh);
      free(kc->qp);
      kc->qh = NULL;
      kc->qp = NULL;
      return 0;
    }
    if (ie == 0) {
      kc->qp_c = h.c;
      kc->qp_shift = h.shift;
    }
    /* (the same bits: -0 and 0 are not one stiffness here) */
    if (qp && (memcmp(&h.c, &kc->qp_c, sizeof h.c) ||
               memcmp(&h.shift, &kc->qp_shift, sizeof h.shift))) {
      if (hooke_unshare(kc, ie) < 0) {
        free(kc->qp);
        kc->qp = NULL;
        return MRVI_ENOMEM;
      }
      qp = NULL;
    }
    if (qp)
      qp[ie] = (khpair){h.ci, h.cj};
    else
      kc->qh[ie] = h;
  }
  kc->hooke_only = 1;
  return 1;
}

/* Whether the n_elems elems are springs of one compiled law (not Hooke's:
 * hooke_class) with one parameter set, each on consecutive columns: a
 * class of kspair records. */
static int shared_law(const mrvi_model *m, elem_src elems, int n_elems,
                      const int *col_of, int dim) {
  const mrvi_element *e0 = law_el(m, elem_at(elems, 0));
  const int law = spring_law(e0);
  if (e0->kind != MRVI_ELEMENT_SPRING || law == KS_LAW || law == KS_HOOKE)
    return 0;
  /* (the springs of the first's prototype from the first on in one loop) */
  const int ie0 =
      mrvi_model_compact(m, elem_at(elems, 0)) && spring_record(e0, dim)
          ? compact_run(m, elems, n_elems, col_of, dim,
                        m->erecs[elem_at(elems, 0)].lp, 0.0, NULL)
          : 0;
  for (int ie = ie0; ie < n_elems; ie++) {
    const int i = elem_at(elems, ie);
    const mrvi_element *e = law_el(m, i);
    if (!spring_record(e, dim) || e->kind != MRVI_ELEMENT_SPRING ||
        e->law != e0->law ||
        (e->params != e0->params &&
         memcmp(e->params, e0->params,
                (size_t)e0->law->n_params * sizeof *e->params)))
      return 0;
    if (mrvi_model_compact(m, i)) {
      if (!compact_consecutive(m, i, col_of, dim))
        return 0;
      continue;
    }
    kspring q = {.two = 1};
    spring_cols(e, col_of, dim, &q);
    for (int k = 1; k < dim; k++)
      if (q.ci[k] != q.ci[0] + k || q.cj[k] != q.cj[0] + k)
        return 0;
  }
  return 1;
}

/* A gradient-only class of springs or anchors of one kind and one law
 * code, not all khooke springs (hooke_class takes those): their kspring
 * records alone, in the class's order, no kterm (the Morse springs of
 * random networks on the explicit paths).  0 if the class is not such,
 * else 1, or MRVI_ENOMEM. */
static int spring_class(mrvi_terms *kc, const mrvi_model *m, elem_src elems,
                        int n_elems, const int *col_of) {
  const int dim = kc->dim;
  if (n_elems < 1 || !spring_record(law_el(m, elem_at(elems, 0)), dim))
    return 0;
  const mrvi_element *e0 = law_el(m, elem_at(elems, 0));
  const int kind = e0->kind;
  const int law = spring_law(e0);
  if (shared_law(m, elems, n_elems, col_of, dim)) {
    kc->qm = malloc((size_t)n_elems * sizeof *kc->qm);
    if (!kc->qm)
      return MRVI_ENOMEM;
    spring_law_of(e0, &kc->qm_law);
    for (int ie = 0; ie < n_elems; ie++) {
      const int i = elem_at(elems, ie);
      const mrvi_element *e = mrvi_model_compact(m, i) ? NULL : law_el(m, i);
      kc->qm[ie] =
          e ? (kspair){col_of ? col_of[e->in[0]] : e->in[0],
                       col_of ? col_of[e->in[dim]] : e->in[dim], e->shift}
            : compact_ends(m, i, col_of);
    }
    kc->qm_law.shift = kc->qm[0].shift; /* (the first's, as its view's) */
    kc->spring_only = 1;
    return 1;
  }
  kc->qs = malloc((size_t)n_elems * sizeof *kc->qs);
  if (!kc->qs)
    return MRVI_ENOMEM;
  /* (all khooke springs: terms_springs' khooke run instead) */
  int hooke = kind == MRVI_ELEMENT_SPRING && law == KS_HOOKE;
  for (int ie = 0; ie < n_elems; ie++) {
    const mrvi_element *e = law_el(m, elem_at(elems, ie));
    if (!spring_record(e, dim) || e->kind != kind || spring_law(e) != law) {
      free(kc->qs);
      kc->qs = NULL;
      return 0;
    }
    kspring *q = &kc->qs[ie];
    *q = (kspring){0};
    spring_rec(m, elem_at(elems, ie), e, col_of, dim, q);
    for (int k = 1; hooke && k < dim; k++)
      hooke = q->ci[k] == q->ci[0] + k && q->cj[k] == q->cj[0] + k;
  }
  if (hooke) {
    free(kc->qs);
    kc->qs = NULL;
    return 0;
  }
  kc->spring_only = 1;
  return 1;
}

/* The springs and anchors of kc as compact records, in runs of one kind
 * (spring or anchor) and one law code; their columns col_of[e->in[.]] (or
 * e->in itself without col_of).  grad_only: the kspring records are left
 * out when every run is of khooke springs (mrvi_terms_create_grad). */
static int terms_springs(mrvi_terms *kc, elem_src elems, const int *col_of,
                         int grad_only) {
  const int dim = kc->dim;
  int ns = 0;
  for (int ie = kc->n - 1; ie >= 0; ie--) {
    kterm *t = &kc->t[ie];
    const mrvi_element *e = t->el;
    if (!spring_record(e, dim))
      continue;
    const kterm *u = ie + 1 < kc->n ? &kc->t[ie + 1] : NULL;
    const int same = u && u->runs > 0 && u->el->kind == e->kind &&
                     spring_law(u->el) == spring_law(e);
    t->runs = 1 + (same ? u->runs : 0);
    ns++;
  }
  const size_t nq = (size_t)(ns > 0 ? ns : 1);
  kc->qs = grad_only ? NULL : calloc(nq, sizeof *kc->qs);
  kc->qh = calloc(nq, sizeof *kc->qh);
  kc->hooke_run = calloc(nq, 1);
  if ((!grad_only && !kc->qs) || !kc->qh || !kc->hooke_run)
    return MRVI_ENOMEM;
  for (int ie = 0, is = 0; ie < kc->n; ie++) {
    kterm *t = &kc->t[ie];
    if (t->runs == 0)
      continue;
    kspring one, *q = kc->qs ? &kc->qs[is] : &one;
    t->qs = is++;
    spring_rec(kc->m, elem_at(elems, ie), t->el, col_of, dim, q);
    int consecutive = q->two && q->k == KS_HOOKE;
    for (int k = 1; k < dim; k++)
      consecutive &= q->ci[k] == q->ci[0] + k && q->cj[k] == q->cj[0] + k;
    kc->qh[t->qs] = (khooke){q->ci[0], q->cj[0], q->c, q->shift};
    kc->hooke_run[t->qs] = (unsigned char)consecutive;
  }
  /* A run is of khooke springs when every record in it is (from its end
   * backwards: hooke_run[r] = the record's and the rest of its run's). */
  for (int ie = kc->n - 1; ie >= 0; ie--) {
    const kterm *t = &kc->t[ie];
    if (t->runs > 1 && !kc->hooke_run[t->qs + 1])
      kc->hooke_run[t->qs] = 0;
  }
  int all_hooke = 1;
  for (int r = 0; r < ns; r++)
    all_hooke &= kc->hooke_run[r];
  if (kc->qs || all_hooke)
    return MRVI_OK;
  /* (gradient only, some run not of khooke springs: the records after all) */
  kc->qs = calloc(nq, sizeof *kc->qs);
  if (!kc->qs)
    return MRVI_ENOMEM;
  for (int ie = 0; ie < kc->n; ie++) {
    const kterm *t = &kc->t[ie];
    if (t->runs == 0)
      continue;
    spring_rec(kc->m, elem_at(elems, ie), t->el, col_of, dim, &kc->qs[t->qs]);
  }
  return MRVI_OK;
}

/* A full class (not gradient-only) whose every element is a kspring
 * record: the records terms_springs would make (qs, qh, hooke_run: the
 * same runs of one kind and one law code, the same values) without the
 * kterms, col or coef; the first record of each run in rs.  0 if the
 * class is not such, else 1, or MRVI_ENOMEM. */
static int springs_runs(mrvi_terms *kc, const mrvi_model *m, elem_src elems,
                        int n_elems, const int *col_of) {
  const int dim = kc->dim;
  if (n_elems < 1)
    return 0;
  /* (first the runs and whether every record is a khooke spring, so that
   * the kspring records are not made where they would be freed: freeing
   * them would raise glibc's mmap threshold, and the sweep's arrays after
   * them would be zeroed in the heap instead of mapped untouched) */
  int n_rs = 1, all_hooke = 1;
  const mrvi_element *u = NULL; /* (the previous element's law) */
  for (int ie = 0; ie < n_elems; ie++) {
    const int i = elem_at(elems, ie);
    const mrvi_element *e = law_el(m, i);
    if (!spring_record(e, dim))
      return 0;
    n_rs +=
        u && u != e && (u->kind != e->kind || spring_law(u) != spring_law(e));
    u = e;
    all_hooke &= e->kind == MRVI_ELEMENT_SPRING && spring_law(e) == KS_HOOKE;
    if (mrvi_model_compact(m, i)) {
      all_hooke &= compact_consecutive(m, i, col_of, dim);
      continue;
    }
    kspring q = {.two = e->kind == MRVI_ELEMENT_SPRING};
    spring_cols(e, col_of, dim, &q);
    for (int k = 1; k < dim; k++)
      all_hooke &= q.ci[k] == q.ci[0] + k && q.cj[k] == q.cj[0] + k;
  }
  const size_t nq = (size_t)n_elems;
  /* (every record a khooke spring: no kspring records, the kernels make
   * them from qh, springs_at; the lattices' fast springs) */
  kc->qs = all_hooke ? NULL : malloc(nq * sizeof *kc->qs);
  kc->qh = malloc(nq * sizeof *kc->qh);
  kc->hooke_run = malloc(nq);
  kc->rs = malloc(((size_t)n_rs + 1) * sizeof *kc->rs);
  kc->y = calloc(1, sizeof *kc->y); /* (no generic element: a stub each) */
  kc->g = calloc(1, sizeof *kc->g);
  kc->H = calloc(1, sizeof *kc->H);
  if ((!all_hooke && !kc->qs) || !kc->qh || !kc->hooke_run || !kc->rs ||
      !kc->y || !kc->g || !kc->H)
    return MRVI_ENOMEM;
  kc->n_rs = 0;
  kspring prev = {0};
  for (int ie = 0; ie < n_elems; ie++) {
    kspring q = {0};
    spring_rec(m, elem_at(elems, ie), law_el(m, elem_at(elems, ie)), col_of,
               dim, &q);
    if (ie == 0 || q.two != prev.two || q.k != prev.k)
      kc->rs[kc->n_rs++] = ie;
    prev = q;
    int consecutive = q.two && q.k == KS_HOOKE;
    for (int k = 1; k < dim; k++)
      consecutive &= q.ci[k] == q.ci[0] + k && q.cj[k] == q.cj[0] + k;
    if (kc->qs)
      kc->qs[ie] = q;
    kc->qh[ie] = (khooke){q.ci[0], q.cj[0], q.c, q.shift};
    kc->hooke_run[ie] = (unsigned char)consecutive;
  }
  kc->rs[kc->n_rs] = n_elems;
  /* (terms_springs' rule: hooke_run[r] = the record's and the rest of its
   * run's) */
  for (int i = 0; i < kc->n_rs; i++)
    for (int r = kc->rs[i + 1] - 2; r >= kc->rs[i]; r--)
      if (!kc->hooke_run[r + 1])
        kc->hooke_run[r] = 0;
  return 1;
}

static int terms_create(const mrvi_model *m, elem_src elems, int n_elems,
                        const int *col_of, int grad_only, mrvi_terms **out) {
  mrvi_terms *kc = calloc(1, sizeof *kc);
  *out = NULL;
  if (!kc)
    return MRVI_ENOMEM;
  const int dim = kc->dim = m->dimension;
  kc->m = m;
  kc->n = n_elems;
  kc->exact = grad_only == 2;
  int hc = grad_only ? hooke_class(kc, m, elems, n_elems, col_of) : 0;
  if (hc == 0 && grad_only)
    hc = spring_class(kc, m, elems, n_elems, col_of);
  if (hc == 0 && !grad_only)
    hc = springs_runs(kc, m, elems, n_elems, col_of);
  if (hc < 0) {
    mrvi_terms_free(kc);
    return hc;
  }
  if (hc > 0) {
    *out = kc;
    return MRVI_OK;
  }
  /* Columns for the elements without a kspring record, coefficients for
   * those that have them. */
  int n_col = 0, n_coef = 0, max_in = 1;
  for (int ie = 0; ie < n_elems; ie++) {
    const mrvi_element *e = law_el(m, elem_at(elems, ie));
    n_col += spring_record(e, dim) ? 0 : e->n_in;
    n_coef += e->coef ? e->n_in : 0;
    max_in = e->n_in > max_in ? e->n_in : max_in;
  }
  const size_t mi = (size_t)max_in;
  kc->t = calloc((size_t)(n_elems > 0 ? n_elems : 1), sizeof *kc->t);
  kc->col = calloc((size_t)(n_col > 0 ? n_col : 1), sizeof *kc->col);
  kc->coef = calloc((size_t)(n_coef > 0 ? n_coef : 1), sizeof *kc->coef);
  kc->y = calloc(mi, sizeof *kc->y);
  kc->g = calloc(mi, sizeof *kc->g);
  kc->H = calloc(mi * mi, sizeof *kc->H);
  if (!kc->t || !kc->col || !kc->coef || !kc->y || !kc->g || !kc->H) {
    mrvi_terms_free(kc);
    return MRVI_ENOMEM;
  }
  int first = 0, cfirst = 0;
  for (int ie = 0; ie < n_elems; ie++) {
    const mrvi_element *e = law_el(m, elem_at(elems, ie));
    kterm *t = &kc->t[ie];
    t->el = mrvi_element_stable(e); /* (its law: it lasts) */
    t->n = e->n_in;
    t->first = first;
    t->cfirst = cfirst;
    t->kind = KT_ELEMENT;
    if (e->kind == MRVI_ELEMENT_TERM) {
      t->kind = e->form == MRVI_LAW_FORM_HOOKE ? KT_LINEAR : KT_LAW;
      t->shift = e->shift;
      t->c = e->params[0];
      t->e = e->params[1];
      if (mrvi_element_small_power(e)) {
        t->kind = KT_POWER;
        t->k = (int)t->e;
      }
    }
    if (e->coef) {
      for (int j = 0; j < e->n_in; j++)
        kc->coef[cfirst + j] = e->coef[j];
      cfirst += e->n_in;
    }
    if (spring_record(e, dim))
      continue;
    for (int j = 0; j < e->n_in; j++)
      kc->col[first + j] = col_of ? col_of[e->in[j]] : e->in[j];
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
      q->a[j] = kc->coef[t->cfirst + j];
    }
  }
  if (terms_springs(kc, elems, col_of, grad_only) < 0) {
    mrvi_terms_free(kc);
    return MRVI_ENOMEM;
  }
  kc->flat = n_elems > 0 && n4 == n_elems;
  kc->flat_k = n_elems > 0 ? kc->q4[0].k : 0;
  for (int i = 1; i < n4; i++)
    if (kc->q4[i].k != kc->flat_k)
      kc->flat_k = K_ANY;
  kc->sym = kc->flat;
  for (int r = 0; r < n4; r++)
    for (int j = 0; j < kc->q4[r].n; j++)
      for (int l = 0; l < j; l++)
        if (kc->q4[r].col[l] == kc->q4[r].col[j])
          kc->sym = 0;
  *out = kc;
  return MRVI_OK;
}

int mrvi_terms_create(const mrvi_model *m, const int *elems, int n_elems,
                      const int *col_of, mrvi_terms **out) {
  return terms_create(m, (elem_src){elems, 0}, n_elems, col_of, 0, out);
}

int mrvi_terms_create_grad(const mrvi_model *m, const int *elems, int n_elems,
                           const int *col_of, mrvi_terms **out) {
  return terms_create(m, (elem_src){elems, 0}, n_elems, col_of, 1, out);
}

int mrvi_terms_create_grad_exact(const mrvi_model *m, const int *elems,
                                 int n_elems, const int *col_of,
                                 mrvi_terms **out) {
  return terms_create(m, (elem_src){elems, 0}, n_elems, col_of, 2, out);
}

int mrvi_terms_create_range(const mrvi_model *m, const int *elems, int first,
                            int n_elems, const int *col_of, int mode,
                            mrvi_terms **out) {
  return terms_create(m, (elem_src){elems, first}, n_elems, col_of, mode, out);
}

int mrvi_terms_create_value(const mrvi_model *m, const int *list, int n_elems,
                            mrvi_terms **out) {
  const elem_src elems = {list, 0};
  mrvi_terms *kc = calloc(1, sizeof *kc);
  *out = NULL;
  if (!kc)
    return MRVI_ENOMEM;
  kc->dim = m->dimension;
  kc->m = m;
  kc->n = n_elems;
  const int hc = hooke_class(kc, m, elems, n_elems, NULL);
  if (hc > 0) {
    *out = kc;
    return MRVI_OK;
  }
  mrvi_terms_free(kc);
  return hc < 0 ? hc : terms_create(m, elems, n_elems, NULL, 0, out);
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
    mrvi_power_derivs(t->c, t->e, t->k, s, &d1, &d2);
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
 * Its data is read into locals first (term4_derivs: the inputs into col
 * and a, phi' and phi'' into d1 and d2): the stores into g and J could
 * alias it. */
ALWAYS_INLINE void term4_derivs(const kterm4 *q, const double *z, int *col,
                                double *a, double *d1, double *d2, const int n,
                                const int kk) {
  UNROLL for (int j = 0; j < n; j++) {
    col[j] = q->col[j];
    a[j] = q->a[j];
  }
  const double c = q->c;
  const int k = kk == K_ANY ? q->k : kk;
  double s = -q->shift;
  UNROLL for (int j = 0; j < n; j++) s += a[j] * z[col[j]];
  if (k < 0) {
    *d1 = c * s;
    *d2 = c;
  } else {
    mrvi_power_derivs_ce(q->ce, q->ce1, k, s, d1, d2);
  }
}

ALWAYS_INLINE void term4_eval(const kterm4 *q, const double *z, double scale,
                              double *g, double *J, int ld, double hscale,
                              const int n, const int unit, const int kk) {
  int col[4];
  double a[4], d1, d2;
  term4_derivs(q, z, col, a, &d1, &d2, n, kk);
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

/* One spring (two) or anchor of dimension dim and law code k (K_ANY: the
 * record's): mrvi_element_eval's distance arithmetic in its order, the
 * gradient added to g and the Hessian to J as eval_k adds an element's
 * (bitwise the same). */
ALWAYS_INLINE void spring_derivs(const kspring *q, const double *z, double u[3],
                                 double *d1, double *a, double *b,
                                 const int dim, const int two, const int kk) {
  double d[3], r2 = 0.0;
  UNROLL for (int k = 0; k < dim; k++) {
    d[k] = z[q->ci[k]] - (two ? z[q->cj[k]] : q->el->anchor[k]);
    r2 += d[k] * d[k];
  }
  const double r = sqrt(r2), s = r - q->shift;
  const int k = kk == K_ANY ? q->k : kk;
  double phi, d2;
  if (k == KS_HOOKE) {
    *d1 = q->c * s;
    d2 = q->c;
  } else if (k >= 0) {
    mrvi_power_derivs_ce(q->ce, q->ce1, k, s, d1, &d2);
  } else if (k == KS_MORSE) { /* laws/morse.c in its order */
    const double x = exp(-q->c * s);
    *d1 = q->ce * x * (1 - x);
    d2 = q->ce1 * x * (2 * x - 1);
  } else {
    q->el->law->eval(q->el->params, s, &phi, d1, &d2);
  }
  UNROLL for (int k = 0; k < dim; k++) u[k] = 0.0;
  *a = 0.0; /* Hessian blocks a u u^T + b I */
  if (r > 0.0) {
    UNROLL for (int k = 0; k < dim; k++) u[k] = d[k] / r;
    *a = d2 - *d1 / r;
    *b = *d1 / r;
  } else {
    *b = d2; /* (the limit at r = 0, as model.c) */
  }
}

ALWAYS_INLINE void spring_eval(const kspring *q, const double *z, double scale,
                               double *g, double *J, int ld, double hscale,
                               const int dim, const int two, const int kk,
                               const int unit) {
  double u[3], d1, a, b;
  spring_derivs(q, z, u, &d1, &a, &b, dim, two, kk);
  UNROLL for (int k = 0; k < dim; k++) g[q->ci[k]] +=
      unit ? d1 * u[k] : scale * (d1 * u[k]);
  if (two)
    UNROLL for (int k = 0; k < dim; k++) g[q->cj[k]] +=
        unit ? -d1 * u[k] : scale * (-d1 * u[k]);
  if (!J)
    return;
  UNROLL for (int i = 0; i < dim; i++) {
    double *Ji = J + (size_t)q->ci[i] * (size_t)ld;
    double *Jj = two ? J + (size_t)q->cj[i] * (size_t)ld : NULL;
    UNROLL for (int j = 0; j < dim; j++) {
      const double A = a * u[i] * u[j] + (i == j ? b : 0.0);
      Ji[q->ci[j]] += unit ? A : hscale * A;
      if (two) {
        Ji[q->cj[j]] += unit ? -A : hscale * -A;
        Jj[q->ci[j]] += unit ? -A : hscale * -A;
        Jj[q->cj[j]] += unit ? A : hscale * A;
      }
    }
  }
}

ALWAYS_INLINE void springs_k(const kspring *q, int nr, const double *z,
                             double scale, double *g, double *J, int ld,
                             double hscale, const int dim, const int two,
                             const int unit) {
  switch (q->k) {
  case KS_HOOKE:
    for (int r = 0; r < nr; r++)
      spring_eval(q + r, z, scale, g, J, ld, hscale, dim, two, KS_HOOKE, unit);
    break;
  case KS_LAW:
    for (int r = 0; r < nr; r++)
      spring_eval(q + r, z, scale, g, J, ld, hscale, dim, two, KS_LAW, unit);
    break;
  case KS_MORSE:
    for (int r = 0; r < nr; r++)
      spring_eval(q + r, z, scale, g, J, ld, hscale, dim, two, KS_MORSE, unit);
    break;
  default:
    for (int r = 0; r < nr; r++)
      spring_eval(q + r, z, scale, g, J, ld, hscale, dim, two, K_ANY, unit);
  }
}

/* M(D, T) for the dimension D and kind T (1: spring, 0: anchor) of a run
 * of records q in a class of dimension dim: one instance per shape. */
#define SPRING_SHAPES(M)                                                       \
  do {                                                                         \
    if (dim == 2 && q->two)                                                    \
      M(2, 1);                                                                 \
    else if (dim == 2)                                                         \
      M(2, 0);                                                                 \
    else if (dim == 3 && q->two)                                               \
      M(3, 1);                                                                 \
    else if (dim == 3)                                                         \
      M(3, 0);                                                                 \
    else if (q->two)                                                           \
      M(1, 1);                                                                 \
    else                                                                       \
      M(1, 0);                                                                 \
  } while (0)

/* A run of nr springs or anchors of one law code (a loop per dimension,
 * kind and law code). */
static __attribute__((noinline)) void
springs_eval(const kspring *q, int nr, const double *z, double scale, double *g,
             double *J, int ld, double hscale, int dim) {
  const int unit = scale == 1.0 && (!J || hscale == 1.0);
#define SPRINGS(D, T)                                                          \
  do {                                                                         \
    if (unit)                                                                  \
      springs_k(q, nr, z, scale, g, J, ld, hscale, D, T, 1);                   \
    else                                                                       \
      springs_k(q, nr, z, scale, g, J, ld, hscale, D, T, 0);                   \
  } while (0)
  SPRING_SHAPES(SPRINGS);
#undef SPRINGS
}

/* The length's reciprocal, 0 at length 0: one division, no branch (the
 * gradient-only classes' springs, hooke_grad_k and part_hooke_k with one =
 * 1: u = d / r by it instead of a division per axis; the last bits differ
 * from spring_eval's). */
ALWAYS_INLINE double recip_len(double rr) {
  const double ir = 1.0 / rr;
  return rr > 0.0 ? ir : 0.0;
}

/* A khooke spring's unit direction u (0 at zero length) and force
 * magnitude c (r - shift): u = d / r per axis (spring_eval's arithmetic) or,
 * with one = 1, by the reciprocal of r. */
ALWAYS_INLINE double hooke_dir(const khooke *h, const double *z, int ci, int cj,
                               double u[3], const int dim, const int one) {
  double d[3], r2 = 0.0;
  UNROLL for (int k = 0; k < dim; k++) {
    d[k] = z[ci + k] - z[cj + k];
    r2 += d[k] * d[k];
  }
  const double rr = sqrt(r2), d1 = h->c * (rr - h->shift);
  u[0] = u[1] = u[2] = 0.0;
  if (one) {
    const double i0 = recip_len(rr);
    UNROLL for (int k = 0; k < dim; k++) u[k] = d[k] * i0;
  } else if (rr > 0.0) {
    UNROLL for (int k = 0; k < dim; k++) u[k] = d[k] / rr;
  }
  return d1;
}

/* The gradient of a run of nr khooke springs in dimension dim:
 * spring_eval's arithmetic at unit scale (bitwise the same), or with one =
 * 1 (a gradient-only class, mrvi_terms_create_grad) one division per
 * spring. */
ALWAYS_INLINE void hooke_grad_k(hsrc q, int r0, int nr, const double *z,
                                double *g, const int dim, const int one) {
  for (int r = r0; r < r0 + nr; r++) {
    const khooke h = hooke_rec(q, r);
    const int ci = h.ci, cj = h.cj;
    double u[3];
    const double d1 = hooke_dir(&h, z, ci, cj, u, dim, one);
    UNROLL for (int k = 0; k < dim; k++) g[ci + k] += d1 * u[k];
    UNROLL for (int k = 0; k < dim; k++) g[cj + k] += -d1 * u[k];
  }
}

static __attribute__((noinline)) void
hooke_grad(const khooke *q, int nr, const double *z, double *g, int dim) {
  const hsrc s = {q, NULL, 0.0, 0.0};
  if (dim == 2)
    hooke_grad_k(s, 0, nr, z, g, 2, 0);
  else if (dim == 3)
    hooke_grad_k(s, 0, nr, z, g, 3, 0);
  else
    hooke_grad_k(s, 0, nr, z, g, 1, 0);
}

ALWAYS_INLINE void hooke_grad_pairs(hsrc q, int r0, int nr, const double *z,
                                    double *g, const int dim);

/* hooke_grad with one division per spring (a gradient-only class), two
 * springs at a time (hooke_grad_pairs: hooke_grad_k's values bit for
 * bit). */
static __attribute__((noinline)) void
hooke_grad1(hsrc q, int nr, const double *z, double *g, int dim) {
  if (dim == 2 && q.pr) /* (one stiffness and rest length: the columns) */
    hooke_grad_pairs((hsrc){NULL, q.pr, q.c, q.shift}, 0, nr, z, g, 2);
  else if (dim == 3 && q.pr)
    hooke_grad_pairs((hsrc){NULL, q.pr, q.c, q.shift}, 0, nr, z, g, 3);
  else if (dim == 2)
    hooke_grad_pairs((hsrc){q.q, NULL, 0.0, 0.0}, 0, nr, z, g, 2);
  else if (dim == 3)
    hooke_grad_pairs((hsrc){q.q, NULL, 0.0, 0.0}, 0, nr, z, g, 3);
  else
    hooke_grad_pairs(q, 0, nr, z, g, 1);
}

/* hooke_grad on a hooke_class's records, shared or not (an exact class,
 * mrvi_terms_create_grad_exact: the two divisions per spring). */
static __attribute__((noinline)) void
hooke_grad_src(hsrc q, int nr, const double *z, double *g, int dim) {
  if (!q.pr)
    hooke_grad(q.q, nr, z, g, dim);
  else if (dim == 2)
    hooke_grad_k(q, 0, nr, z, g, 2, 0);
  else if (dim == 3)
    hooke_grad_k(q, 0, nr, z, g, 3, 0);
  else
    hooke_grad_k(q, 0, nr, z, g, 1, 0);
}

/* Element t's value (returned), gradient g and Hessian H (either NULL) at
 * its inputs gathered from z, by the generic evaluation. */
static double element_at(const mrvi_terms *kc, const kterm *t, const double *z,
                         double *g, double *H) {
  const int *col = kc->col + t->first;
  for (int j = 0; j < t->n; j++)
    kc->y[j] = z[col[j]];
  return mrvi_element_eval(kc->m, t->el, kc->y, g, H);
}

ALWAYS_INLINE void eval_k(mrvi_terms *kc, const double *z, double scale,
                          double *g, double *J, int ld, double hscale,
                          const int unit) {
  for (int it = 0; it < kc->n; it++) {
    kterm tt;
    const kterm *t = term_at(kc, it, &tt);
    if (t->run4 > 0) {
      run4_eval(kc->q4 + t->q4, t->run4, z, scale, g, J, ld, hscale, unit);
      it += t->run4 - 1;
      continue;
    }
    if (t->runs > 0 && !J && unit && kc->hooke_run[t->qs]) {
      if (kc->recip)
        hooke_grad1((hsrc){kc->qh + t->qs, NULL, 0.0, 0.0}, t->runs, z, g,
                    kc->dim);
      else
        hooke_grad(kc->qh + t->qs, t->runs, z, g, kc->dim);
      it += t->runs - 1;
      continue;
    }
    if (t->runs > 0) {
#define EVAL_(q, n, r) springs_eval(q, n, z, scale, g, J, ld, hscale, kc->dim)
      SPRING_PIECES(kc, t->qs, t->runs, EVAL_);
#undef EVAL_
      it += t->runs - 1;
      continue;
    }
    const int n = t->n, *col = kc->col + t->first;
    const double *a = kc->coef + t->cfirst;
    if (t->run > 1) { /* as below, one input each */
      run1_eval(t, t->run, col, a, z, scale, g, J, ld, hscale);
      it += t->run - 1;
      continue;
    }
    if (t->kind == KT_ELEMENT) {
      const int lin = t->el->kind == MRVI_ELEMENT_GRAVITY;
      element_at(kc, t, z, kc->g, J && !lin ? kc->H : NULL);
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

/* springs_k over a class of kspair records, in dimension dim with law
 * code kk (K_ANY: the class's): each record's kspring (pair_spring),
 * spring_eval's arithmetic, so bitwise springs_eval's over its kspring
 * records. */
ALWAYS_INLINE void pairs_k(const mrvi_terms *kc, const double *z, double scale,
                           double *g, double *J, int ld, double hscale,
                           const int dim, const int kk, const int unit) {
  kspring q = kc->qm_law; /* (pair_spring's fields, set per record) */
  for (int r = 0; r < kc->n; r++) {
    const kspair *pr = &kc->qm[r];
    for (int k = 0; k < dim; k++) {
      q.ci[k] = pr->ci + k;
      q.cj[k] = pr->cj + k;
    }
    q.shift = pr->shift;
    spring_eval(&q, z, scale, g, J, ld, hscale, dim, 1, kk, unit);
  }
}

static __attribute__((noinline)) void pairs_eval(const mrvi_terms *kc,
                                                 const double *z, double scale,
                                                 double *g, double *J, int ld,
                                                 double hscale) {
  const int unit = scale == 1.0 && (!J || hscale == 1.0);
  const int morse = kc->qm_law.k == KS_MORSE;
#define PAIRS(D, K)                                                            \
  do {                                                                         \
    if (unit)                                                                  \
      pairs_k(kc, z, scale, g, J, ld, hscale, D, K, 1);                        \
    else                                                                       \
      pairs_k(kc, z, scale, g, J, ld, hscale, D, K, 0);                        \
  } while (0)
  if (kc->dim == 3 && morse)
    PAIRS(3, KS_MORSE);
  else if (kc->dim == 3)
    PAIRS(3, K_ANY);
  else if (kc->dim == 2 && morse)
    PAIRS(2, KS_MORSE);
  else if (kc->dim == 2)
    PAIRS(2, K_ANY);
  else
    PAIRS(1, K_ANY);
#undef PAIRS
}

static __attribute__((noinline)) void
terms_eval_any(mrvi_terms *kc, const double *z, double scale, double *g,
               double *J, int ld, double hscale) {
  if (scale == 1.0 && (!J || hscale == 1.0))
    eval_k(kc, z, scale, g, J, ld, hscale, 1);
  else
    eval_k(kc, z, scale, g, J, ld, hscale, 0);
}

static void flat_eval(const mrvi_terms *kc, const double *z, double *g,
                      double *J, int ld);

void mrvi_terms_eval(mrvi_terms *kc, const double *z, double scale, double *g,
                     double *J, int ld, double hscale) {
  if (kc->hooke_only) /* (gradient only: scale 1, no J) */
    mrvi_terms_grad(kc, z, g);
  else if (kc->qm)
    pairs_eval(kc, z, scale, g, J, ld, hscale);
  else if (kc->spring_only) /* (eval_k's one run) */
    springs_eval(kc->qs, kc->n, z, scale, g, J, ld, hscale, kc->dim);
  else if (kc->flat && J && scale == 1.0 && hscale == 1.0)
    flat_eval(kc, z, g, J, ld); /* (a call: see flat_grad) */
  else
    terms_eval_any(kc, z, scale, g, J, ld, hscale);
}

/* The gradient of a class of compact records alone, with law k: one loop
 * over the records (their input count a branch per term), without the
 * dispatch per run of eval_k; the same products in the same order. */
ALWAYS_INLINE void flat_grad_k(const kterm4 *q, int n, const double *z,
                               double *g, double *J, int ld, const int k) {
  for (int r = 0; r < n; r++) {
    switch (q[r].n) {
    case 2:
      term4_eval(q + r, z, 1.0, g, J, ld, 1.0, 2, 1, k);
      break;
    case 3:
      term4_eval(q + r, z, 1.0, g, J, ld, 1.0, 3, 1, k);
      break;
    default:
      term4_eval(q + r, z, 1.0, g, J, ld, 1.0, 4, 1, k);
    }
  }
}

/* (calls, not inlined: each saves only the registers it uses, and the
 * dispatch in mrvi_terms_grad jumps to them) */
static __attribute__((noinline)) void flat_grad(const mrvi_terms *kc,
                                                const double *z, double *g) {
  switch (kc->flat_k) {
  case -1:
    flat_grad_k(kc->q4, kc->n, z, g, NULL, 0, -1);
    break;
  case 4:
    flat_grad_k(kc->q4, kc->n, z, g, NULL, 0, 4);
    break;
  default:
    flat_grad_k(kc->q4, kc->n, z, g, NULL, 0, K_ANY);
  }
}

/* flat_grad with the Hessian into J (scale and hscale 1): the
 * evaluation of eval_k for such a class, the same products in the same
 * order. */
static __attribute__((noinline)) void
flat_eval(const mrvi_terms *kc, const double *z, double *g, double *J, int ld) {
  switch (kc->flat_k) {
  case -1:
    flat_grad_k(kc->q4, kc->n, z, g, J, ld, -1);
    break;
  case 4:
    flat_grad_k(kc->q4, kc->n, z, g, J, ld, 4);
    break;
  default:
    flat_grad_k(kc->q4, kc->n, z, g, J, ld, K_ANY);
  }
}

/* A compact record's gradient into g and Hessian added into J
 * (mrvi_terms_eval_set): term4_eval's products at unit scale, the
 * Hessian's product (d2 a_j) a_l formed for j <= l only, its sum with the
 * entry (col_j, col_l) written to both (col_j, col_l) and (col_l, col_j),
 * which are equal (every term writes both). */
ALWAYS_INLINE void term4_sym(const kterm4 *q, const double *z, double *g,
                             double *J, int ld, const int n, const int kk) {
  int col[4];
  double a[4], d1, d2;
  term4_derivs(q, z, col, a, &d1, &d2, n, kk);
  UNROLL for (int j = 0; j < n; j++) g[col[j]] += d1 * a[j];
  double *Jr[4]; /* the rows of the inputs */
  UNROLL for (int j = 0; j < n; j++) Jr[j] = J + (size_t)col[j] * (size_t)ld;
  UNROLL for (int j = 0; j < n; j++) {
    const double u = d2 * a[j];
    Jr[j][col[j]] += u * a[j];
    UNROLL for (int l = j + 1; l < n; l++) {
      const double v = Jr[j][col[l]] + u * a[l];
      Jr[j][col[l]] = v;
      Jr[l][col[j]] = v;
    }
  }
}

ALWAYS_INLINE void flat_sym_k(const mrvi_terms *kc, const double *z, double *g,
                              double *J, int ld, const int k) {
  const kterm4 *q = kc->q4;
  for (int r = 0; r < kc->n; r++) {
    switch (q[r].n) {
    case 2:
      term4_sym(q + r, z, g, J, ld, 2, k);
      break;
    case 3:
      term4_sym(q + r, z, g, J, ld, 3, k);
      break;
    default:
      term4_sym(q + r, z, g, J, ld, 4, k);
    }
  }
}

/* J cleared here, not by the caller (a fixed-size memset, which GCC
 * inlines as `rep stos`: its start-up costs more than the stores at this
 * size): for ld <= 8 by vector stores in line (zero_k at constant sizes),
 * else by the library's memset. */
#if MRVI_SMALL_KERNELS
#define ZERO_CASE(L)                                                           \
  case L:                                                                      \
    zero_k(J, (L) * (L));                                                      \
    break;
#else
#define ZERO_CASE(L)
#endif
static __attribute__((noinline)) void
flat_sym(const mrvi_terms *kc, const double *z, double *g, double *J, int ld) {
  switch (ld) {
    ZERO_CASE(1)
    ZERO_CASE(2)
    ZERO_CASE(3)
    ZERO_CASE(4)
    ZERO_CASE(5)
    ZERO_CASE(6)
    ZERO_CASE(7)
    ZERO_CASE(8)
  default:
    memset(J, 0, (size_t)ld * (size_t)ld * sizeof(double));
  }
  switch (kc->flat_k) {
  case -1:
    flat_sym_k(kc, z, g, J, ld, -1);
    break;
  case 4:
    flat_sym_k(kc, z, g, J, ld, 4);
    break;
  default:
    flat_sym_k(kc, z, g, J, ld, K_ANY);
  }
}

static __attribute__((noinline)) void
eval_set_any(mrvi_terms *kc, const double *z, double *g, double *J, int ld) {
  memset(J, 0, (size_t)ld * (size_t)ld * sizeof(double));
  mrvi_terms_eval(kc, z, 1.0, g, J, ld, 1.0);
}

/* (a dispatch that jumps to either: the registers the second saves were
 * saved on the way to flat_sym as well) */
void mrvi_terms_eval_set(mrvi_terms *kc, const double *z, double *g, double *J,
                         int ld) {
  if (kc->sym)
    flat_sym(kc, z, g, J, ld);
  else
    eval_set_any(kc, z, g, J, ld);
}

int mrvi_terms_quadratic(const mrvi_terms *kc) {
  if (kc->hooke_only || kc->spring_only || kc->rs) /* (springs: not
                                                       polynomial) */
    return 0;
  for (int i = 0; i < kc->n; i++)
    if (!mrvi_element_is_quadratic(kc->t[i].el))
      return 0;
  return 1;
}

int mrvi_terms_affine(mrvi_terms *kc, int n, double **g0, double **H) {
  const size_t nz = (size_t)(n > 0 ? n : 1);
  double *z = calloc(nz, sizeof(double));
  *g0 = calloc(nz, sizeof(double));
  *H = calloc(nz * nz, sizeof(double));
  if (!z || !*g0 || !*H) {
    free(z);
    free(*g0);
    free(*H);
    *g0 = *H = NULL;
    return MRVI_ENOMEM;
  }
  mrvi_terms_eval(kc, z, 1.0, *g0, *H, n, 1.0);
  free(z);
  return MRVI_OK;
}

int mrvi_terms_flat(const mrvi_terms *kc) {
  return kc->flat ? (kc->flat_k == K_ANY ? 2 : 1) : 0;
}

/* Gradient only: the evaluation above with scale 1 and no Hessian (the
 * same products in the same order, so bitwise the same gradient). */
static __attribute__((noinline)) void
terms_grad_any(mrvi_terms *kc, const double *z, double *g) {
  eval_k(kc, z, 1.0, g, NULL, 0, 0.0, 1);
}

/* Springs a and b of hooke_grad_k with one = 1, one in each lane of a pair
 * (util/simd.h): each lane the scalar kernel's operations in its order, the
 * two square roots and divisions in one instruction each; t[k] = c (r -
 * shift) d_k (1 / r), 0 where r <= 0 or NaN (hooke_dir's u times d1). */
ALWAYS_INLINE void hooke_pair(const khooke *a, const khooke *b, const double *z,
                              mrvi_v2 t[3], const int dim) {
  mrvi_v2 d[3], r2 = v2_zero();
  UNROLL for (int k = 0; k < dim; k++) {
    d[k] = v2_sub(v2_set(z[a->ci + k], z[b->ci + k]),
                  v2_set(z[a->cj + k], z[b->cj + k]));
    r2 = v2_add(r2, v2_mul(d[k], d[k]));
  }
  const mrvi_v2 rr = v2_sqrt(r2);
  const mrvi_v2 d1 =
      v2_mul(v2_set(a->c, b->c), v2_sub(rr, v2_set(a->shift, b->shift)));
  const mrvi_v2 ir = v2_pos_or_zero(rr, v2_div(v2_set(1.0, 1.0), rr));
  UNROLL for (int k = 0; k < dim; k++) t[k] = v2_mul(d1, v2_mul(d[k], ir));
}

/* One spring's sums of hooke_grad_pairs in dimension 2 or 3: its first
 * two axes v01 as a pair at ci and cj (g + v, g - v = g + (-v) lane by
 * lane), the third v2 alone. */
ALWAYS_INLINE void pair_add(double *g, int ci, int cj, mrvi_v2 v01, double v2,
                            const int dim) {
  v2_store(g + ci, v2_add(v2_load(g + ci), v01));
  if (dim == 3)
    g[ci + 2] += v2;
  v2_store(g + cj, v2_sub(v2_load(g + cj), v01));
  if (dim == 3)
    g[cj + 2] += -v2;
}

/* Part c's records (mrvi_terms_set_threads): spring_eval's gradient at
 * unit scale, each column written only where the record's mask has it. */
ALWAYS_INLINE void part_k(const kspring *q, const int *rec,
                          const unsigned char *mask, int nr, const double *z,
                          double *g, const int dim) {
  for (int i = 0; i < nr; i++) {
    const kspring *s = q + rec[i];
    const unsigned mk = mask[i];
    double u[3], d1, a, b;
    const int two = s->two;
    if (two)
      spring_derivs(s, z, u, &d1, &a, &b, dim, 1, K_ANY);
    else
      spring_derivs(s, z, u, &d1, &a, &b, dim, 0, K_ANY);
    UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << k) g[s->ci[k]] +=
        d1 * u[k];
    if (two)
      UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << (dim + k))
          g[s->cj[k]] += -d1 * u[k];
  }
}

/* Spring h's sums in part_hooke_pairs: its axes' values v01 (the first
 * two) and v2, each column of the mask mk (pair_add where it has all). */
ALWAYS_INLINE void part_pair_add(double *g, const khooke *h, unsigned mk,
                                 mrvi_v2 v01, double v2, const int dim) {
  if (dim >= 2 && mk == (1u << 2 * dim) - 1) {
    pair_add(g, h->ci, h->cj, v01, v2, dim);
    return;
  }
  const double v[3] = {v2_lo(v01), v2_hi(v01), v2};
  UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << k) g[h->ci + k] += v[k];
  UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << (dim + k)) g[h->cj + k] +=
      -v[k];
}

/* part_hooke_k with one = 1 on a part's entries two at a time (the lanes
 * of hooke_pair), the sums entry by entry in the part's order, whole
 * records or masked: the scalar loop's values bit for bit (es-zero's
 * argument, hooke_grad_pairs); a run of at least two consecutive whole
 * records (run) by the serial kernel's loop itself, hooke_grad_pairs,
 * without the list and the masks (the same lanes and sums: the parts'
 * gradient had cost 1.45 times the serial one on lattice2d,
 * doc/performance/17-thr17.md); the entries done returned (an odd last
 * one left to the scalar loop). */
ALWAYS_INLINE int part_hooke_pairs(hsrc q, const int *rec,
                                   const unsigned char *mask, const int *run,
                                   int nr, const double *z, double *g,
                                   const int dim) {
  int i = 0;
  while (i + 2 <= nr) {
    if (run[i] >= 2) {
      hooke_grad_pairs(q, rec[i], run[i], z, g, dim);
      i += run[i];
      continue;
    }
    const khooke a = hooke_rec(q, rec[i]), b = hooke_rec(q, rec[i + 1]);
    mrvi_v2 t[3];
    hooke_pair(&a, &b, z, t, dim);
    const mrvi_v2 t1 = dim >= 2 ? t[1] : v2_zero();
    const mrvi_v2 t2 = dim == 3 ? t[2] : v2_zero();
    part_pair_add(g, &a, mask[i], v2_set(v2_lo(t[0]), v2_lo(t1)), v2_lo(t2),
                  dim);
    part_pair_add(g, &b, mask[i + 1], v2_set(v2_hi(t[0]), v2_hi(t1)), v2_hi(t2),
                  dim);
    i += 2;
  }
  return i;
}

/* part_k for a class of khooke springs alone (hooke_grad_k's arithmetic,
 * bitwise spring_eval's, or with one = 1 hooke_grad1's, two springs at a
 * time: part_hooke_pairs): the quarter-size records. */
ALWAYS_INLINE void part_hooke_k(hsrc q, const int *rec,
                                const unsigned char *mask, const int *run,
                                int nr, const double *z, double *g,
                                const int dim, const int one) {
  for (int i = one ? part_hooke_pairs(q, rec, mask, run, nr, z, g, dim) : 0;
       i < nr; i++) {
    if (run[i] > 0) { /* whole records: the serial loop, the same sums */
      hooke_grad_k(q, rec[i], run[i], z, g, dim, one);
      i += run[i] - 1;
      continue;
    }
    const khooke h = hooke_rec(q, rec[i]);
    const unsigned mk = mask[i];
    const int ci = h.ci, cj = h.cj;
    double u[3];
    const double d1 = hooke_dir(&h, z, ci, cj, u, dim, one);
    UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << k) g[ci + k] +=
        d1 * u[k];
    UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << (dim + k)) g[cj + k] +=
        -d1 * u[k];
  }
}

void mrvi_terms_grad_part(const mrvi_terms *kc, int c, const double *z,
                          double *g) {
  const int r0 = kc->part_first[c], nr = kc->part_first[c + 1] - r0;
  const int *rec = kc->part_rec + r0;
  const unsigned char *mask = kc->part_mask + r0;
  /* (part_run: a class of khooke springs' alone, else NULL, which takes
   * no offset) */
  const int *run = kc->part_run ? kc->part_run + r0 : NULL;
  /* (q: the shared columns where the class has them, hooke_class; else
   * the kernels read qh, whose constant NULL columns the compiler folds) */
  const int one = (kc->hooke_only && !kc->exact) || kc->recip;
  const hsrc qh = {kc->qh, NULL, 0.0, 0.0}, q = hooke_src(kc);
  if (kc->part_hooke && !one && kc->qp && kc->dim == 2) /* (an exact class's
                                                           shared ones) */
    part_hooke_k(q, rec, mask, run, nr, z, g, 2, 0);
  else if (kc->part_hooke && !one && kc->qp && kc->dim == 3)
    part_hooke_k(q, rec, mask, run, nr, z, g, 3, 0);
  else if (kc->part_hooke && !one && kc->qp)
    part_hooke_k(q, rec, mask, run, nr, z, g, 1, 0);
  else if (kc->part_hooke && one && kc->qp && kc->dim == 2)
    part_hooke_k(q, rec, mask, run, nr, z, g, 2, 1);
  else if (kc->part_hooke && one && kc->qp && kc->dim == 3)
    part_hooke_k(q, rec, mask, run, nr, z, g, 3, 1);
  else if (kc->part_hooke && one && kc->qp)
    part_hooke_k(q, rec, mask, run, nr, z, g, 1, 1);
  else if (kc->part_hooke && one && kc->dim == 2) /* (qh: pr NULL folded) */
    part_hooke_k(qh, rec, mask, run, nr, z, g, 2, 1);
  else if (kc->part_hooke && one && kc->dim == 3)
    part_hooke_k(qh, rec, mask, run, nr, z, g, 3, 1);
  else if (kc->part_hooke && one)
    part_hooke_k(qh, rec, mask, run, nr, z, g, 1, 1);
  else if (kc->part_hooke && kc->dim == 2)
    part_hooke_k(qh, rec, mask, run, nr, z, g, 2, 0);
  else if (kc->part_hooke && kc->dim == 3)
    part_hooke_k(qh, rec, mask, run, nr, z, g, 3, 0);
  else if (kc->part_hooke)
    part_hooke_k(qh, rec, mask, run, nr, z, g, 1, 0);
  else if (kc->dim == 2)
    part_k(kc->qs, rec, mask, nr, z, g, 2);
  else if (kc->dim == 3)
    part_k(kc->qs, rec, mask, nr, z, g, 3);
  else
    part_k(kc->qs, rec, mask, nr, z, g, 1);
}

/* The parts on kc->threads threads (each writes its own columns). */
static __attribute__((noinline)) void part_grad(mrvi_terms *kc, const double *z,
                                                double *g) {
  const int n_part = kc->n_part;
  MRVI_PARALLEL_FOR(kc->threads)
  for (int c = 0; c < n_part; c++)
    mrvi_terms_grad_part(kc, c, z, g);
}

/* Write column k of record q (x_i's for k < dim, then x_j's). */
static int record_col(const kspring *q, int dim, int k) {
  return k < dim ? q->ci[k] : q->cj[k - dim];
}

int mrvi_even_parts(int n, int chunk) {
  const int np = (n - 1) / chunk + 1;
  return np + (np & 1);
}
int mrvi_part_start(int c, int n, int n_part) {
  return (int)((long)c * n / n_part);
}
/* The part of mrvi_even_parts holding item i. */
static int part_of(int i, int n, int n_part) {
  return (int)(((long)(i + 1) * n_part + n - 1) / n - 1);
}

/* The part owning each column: mrvi_even_parts of the ncol columns (ncol
 * > 0), else the part of the records (mrvi_even_parts of them, in the serial
 * order) holding the first record that writes the column.  NULL on a column
 * outside [0, ncol) or no memory (*n_col: the columns mapped, *n_part:
 * the parts). */
static int *column_owners(const mrvi_terms *kc, int chunk, int ncol, int *n_col,
                          int *n_part) {
  const int dim = kc->dim, by_rec = ncol <= 0;
  if (by_rec)
    for (int r = 0; r < kc->n; r++)
      for (int k = 0; k < (kc->qs[r].two ? 2 * dim : dim); k++)
        ncol = record_col(&kc->qs[r], dim, k) >= ncol
                   ? record_col(&kc->qs[r], dim, k) + 1
                   : ncol;
  int *owner = malloc((size_t)(ncol > 0 ? ncol : 1) * sizeof *owner);
  if (!owner)
    return NULL;
  const int np = mrvi_even_parts(by_rec ? kc->n : ncol, chunk);
  for (int c = 0; c < ncol; c++)
    owner[c] = by_rec ? -1 : part_of(c, ncol, np);
  for (int r = 0; r < kc->n; r++)
    for (int k = 0; k < (kc->qs[r].two ? 2 * dim : dim); k++) {
      const int col = record_col(&kc->qs[r], dim, k);
      if (col < 0 || col >= ncol) {
        free(owner);
        return NULL;
      }
      if (owner[col] < 0)
        owner[col] = part_of(r, kc->n, np);
    }
  *n_col = ncol;
  *n_part = np;
  return owner;
}

/* Record q's masks of write columns per owning part: up to 2 dim distinct
 * parts into part[], masks into mask[]; returns their count. */
static int record_parts(const kspring *q, int dim, const int *owner,
                        int part[6], unsigned mask[6]) {
  int np = 0;
  for (int k = 0; k < (q->two ? 2 * dim : dim); k++) {
    const int o = owner[record_col(q, dim, k)];
    int i = 0;
    while (i < np && part[i] != o)
      i++;
    if (i == np) {
      part[np] = o;
      mask[np++] = 0;
    }
    mask[i] |= 1u << k;
  }
  return np;
}

/* kc->part_run of a class of khooke springs (two-sided: a whole record's
 * mask has 2 dim bits) partitioned into n_part parts of total entries. */
static int part_runs(mrvi_terms *kc, const int *first, int n_part, long total) {
  kc->part_run = malloc((size_t)(total > 0 ? total : 1) * sizeof(int));
  if (!kc->part_run)
    return MRVI_ENOMEM;
  const unsigned whole = (1u << 2 * kc->dim) - 1;
  for (int c = 0; c < n_part; c++)
    for (int i = first[c + 1] - 1; i >= first[c]; i--) {
      const int next = i + 1 < first[c + 1] && kc->part_run[i + 1] > 0 &&
                       kc->part_rec[i + 1] == kc->part_rec[i] + 1;
      kc->part_run[i] = kc->part_mask[i] != whole ? 0
                        : next                    ? kc->part_run[i + 1] + 1
                                                  : 1;
    }
  return MRVI_OK;
}

/* The entries of the parts of chunk (column_owners): each record once
 * per part it writes a column of; -1 without memory. */
static long part_entries(const mrvi_terms *kc, int chunk, int ncol) {
  int n_col = 0, n_part = 0, part[6];
  unsigned mask[6];
  int *owner = column_owners(kc, chunk, ncol, &n_col, &n_part);
  if (!owner)
    return -1;
  long total = 0;
  for (int r = 0; r < kc->n; r++)
    total += record_parts(&kc->qs[r], kc->dim, owner, part, mask);
  free(owner);
  return total;
}

/* A class of springs and anchors alone (mrvi_terms_set_threads). */
static int springs_alone(const mrvi_terms *kc) {
  int ns = 0;
  for (int i = 0; i < kc->n; i++)
    ns += kc->hooke_only || kc->spring_only || kc->rs || kc->t[i].runs > 0;
  return ns == kc->n;
}

static int set_parts(mrvi_terms *kc, int threads, const int *owner, int n_part);

int mrvi_terms_spread_chunk(mrvi_terms *kc, int chunk, int ncol,
                            double spread) {
  const int made = !kc->qs;
  if (!kc->part_first && chunk >= 1 && springs_alone(kc) &&
      (kc->qs || class_records(kc) == MRVI_OK)) {
    const int n = ncol > 0 ? ncol : kc->n;
    for (; n / 2 >= 2 * chunk; chunk *= 2) { /* (two parts at least) */
      const long total = part_entries(kc, chunk, ncol);
      if (total < 0 || (double)total <= (1.0 + spread) * kc->n)
        break;
    }
  }
  if (made) { /* (records made for the count alone, 35 B a coordinate on
               * random3d: mrvi_terms_set_threads makes them again where it
               * partitions the class) */
    free(kc->qs);
    kc->qs = NULL;
  }
  return chunk;
}

int mrvi_terms_set_threads_spread(mrvi_terms *kc, int threads, int chunk,
                                  int ncol, double spread) {
  if (threads > 1 && mrvi_threads_supported())
    chunk = mrvi_terms_spread_chunk(kc, chunk, ncol, spread);
  return mrvi_terms_set_threads(kc, threads, chunk, ncol);
}

int mrvi_terms_set_threads(mrvi_terms *kc, int threads, int chunk, int ncol) {
  if (!mrvi_threads_supported())
    threads = 1;
  if (kc->part_first) { /* (partitioned already) */
    kc->threads = threads > 1 ? threads : 1;
    return MRVI_OK;
  }
  kc->threads = 1;
  if (threads <= 1 || chunk < 1 || !springs_alone(kc) ||
      (ncol > 0 ? ncol : kc->n) < 2 * chunk)
    return MRVI_OK;
  if (!kc->qs && class_records(kc) < 0) /* (a gradient-only class) */
    return MRVI_ENOMEM;
  int n_col = 0, n_part = 0;
  int *owner = column_owners(kc, chunk, ncol, &n_col, &n_part);
  if (!owner) /* (no memory, or a column outside [0, ncol): stays serial) */
    return ncol > 0 ? MRVI_OK : MRVI_ENOMEM;
  const int rc = set_parts(kc, threads, owner, n_part);
  free(owner);
  if (rc == MRVI_OK && kc->part_first) {
    kc->ncol = ncol;
    kc->chunk = chunk;
  }
  return rc;
}

int mrvi_terms_set_threads_owner(mrvi_terms *kc, int threads, const int *owner,
                                 int n_col, int n_part) {
  if (!mrvi_threads_supported())
    threads = 1;
  if (kc->part_first)
    return MRVI_OK;
  kc->threads = 1;
  if (threads <= 1 || n_part < 2 || !springs_alone(kc))
    return MRVI_OK;
  if (!kc->qs && class_records(kc) < 0)
    return MRVI_ENOMEM;
  /* (every column the records write mapped to a part) */
  for (int r = 0; r < kc->n; r++)
    for (int k = 0; k < (kc->qs[r].two ? 2 * kc->dim : kc->dim); k++) {
      const int col = record_col(&kc->qs[r], kc->dim, k);
      if (col < 0 || col >= n_col || owner[col] < 0 || owner[col] >= n_part)
        return MRVI_OK;
    }
  return set_parts(kc, threads, owner, n_part);
}

/* kc in the n_part parts of the columns' owners (mrvi_terms_set_threads):
 * each part's records in the serial order with their masks of its
 * columns. */
static int set_parts(mrvi_terms *kc, int threads, const int *owner,
                     int n_part) {
  const int dim = kc->dim;
  int part[6];
  unsigned mask[6];
  /* Count each part's records, then list them in the serial order. */
  int *first = calloc((size_t)n_part + 1, sizeof *first);
  int *fill = malloc((size_t)n_part * sizeof *fill);
  long total = 0;
  for (int r = 0; first && r < kc->n; r++) {
    const int np = record_parts(&kc->qs[r], dim, owner, part, mask);
    for (int i = 0; i < np; i++)
      first[part[i] + 1]++;
    total += np;
  }
  if (total <= INT_MAX) {
    kc->part_rec = malloc((size_t)(total > 0 ? total : 1) * sizeof(int));
    kc->part_mask = malloc((size_t)(total > 0 ? total : 1));
  }
  if (!first || !fill || !kc->part_rec || !kc->part_mask) {
    free(first);
    free(fill);
    return total > INT_MAX ? MRVI_OK : MRVI_ENOMEM; /* (freed with kc) */
  }
  for (int c = 0; c < n_part; c++) {
    first[c + 1] += first[c];
    fill[c] = first[c];
  }
  for (int r = 0; r < kc->n; r++) {
    const int np = record_parts(&kc->qs[r], dim, owner, part, mask);
    for (int i = 0; i < np; i++) {
      kc->part_rec[fill[part[i]]] = r;
      kc->part_mask[fill[part[i]]++] = (unsigned char)mask[i];
    }
  }
  free(fill);
  kc->part_hooke = 1;
  for (int r = 0; r < kc->n; r++)
    kc->part_hooke &= kc->hooke_only || (!kc->spring_only && kc->hooke_run[r]);
  if (kc->part_hooke && part_runs(kc, first, n_part, total) < 0) {
    free(first);
    return MRVI_ENOMEM; /* (part_rec, part_mask freed with kc) */
  }
  kc->part_first = first;
  kc->n_part = n_part;
  kc->threads = threads;
  return MRVI_OK;
}

int mrvi_terms_parts(const mrvi_terms *kc) {
  return kc->part_first ? kc->n_part : 0;
}

void mrvi_terms_part_columns(const mrvi_terms *kc, int c, int *c0, int *c1) {
  *c0 = mrvi_part_start(c, kc->ncol, kc->n_part);
  *c1 = mrvi_part_start(c + 1, kc->ncol, kc->n_part);
}

int mrvi_terms_set_recip(mrvi_terms *kc) {
  /* (a class of khooke springs alone: its parts take part_hooke_k on
   * threads, with the serial loop's arithmetic) */
  int all = kc->hooke_only;
  if (!all && !kc->spring_only && kc->hooke_run && kc->n > 0) {
    all = 1;
    for (int i = 0; i < kc->n; i++)
      all &= kc->rs ? kc->hooke_run[i]
                    : kc->t[i].runs > 0 && kc->hooke_run[kc->t[i].qs];
  }
  kc->recip = all;
  return all;
}

/* The linearised chord updates of sweep-cg (doc/solver.md, "sweep-cg"):
 * a class of khooke springs with one division per spring
 * (mrvi_terms_set_recip), each record's Hessian at z0 kept as two numbers
 * next to the gradient there.  A spring's Hessian with respect to
 * d = x_i - x_j is t I + a d d^T, t = phi'/r = c (r - shift)/r and
 * a = (c - t)/r^2 (0 and 0 at r = 0). */
long mrvi_terms_lin_size(const mrvi_terms *kc) {
  if (!kc->recip || kc->hooke_only || !kc->qh || kc->n < 1 ||
      (kc->part_first && !kc->part_hooke))
    return 0;
  return 2 * (long)kc->n;
}

/* Records r0 .. r0 + nr - 1: hooke_grad_k's arithmetic with one = 1 (the
 * same gradient bits) and each record's (a, t) into lin. */
ALWAYS_INLINE void hooke_grad_lin_k(const khooke *q, int r0, int nr,
                                    const double *z, double *g, double *lin,
                                    const int dim) {
  for (int r = r0; r < r0 + nr; r++) {
    const khooke h = q[r];
    double d[3], r2 = 0.0;
    UNROLL for (int k = 0; k < dim; k++) {
      d[k] = z[h.ci + k] - z[h.cj + k];
      r2 += d[k] * d[k];
    }
    const double rr = sqrt(r2), d1 = h.c * (rr - h.shift), ir = recip_len(rr);
    const double t = d1 * ir;
    lin[2 * r] = (h.c - t) * ir * ir;
    lin[2 * r + 1] = t;
    UNROLL for (int k = 0; k < dim; k++) g[h.ci + k] += d1 * (d[k] * ir);
    UNROLL for (int k = 0; k < dim; k++) g[h.cj + k] += -d1 * (d[k] * ir);
  }
}

/* One record's product: h = (t I + a d d^T) (x_i - x_j), d from z0. */
ALWAYS_INLINE void hooke_hv_one(const khooke *h, const double *lr,
                                const double *z0, const double *x,
                                double h_out[3], const int dim) {
  double d[3], e[3], dd = 0.0;
  UNROLL for (int k = 0; k < dim; k++) {
    d[k] = z0[h->ci + k] - z0[h->cj + k];
    e[k] = x[h->ci + k] - x[h->cj + k];
    dd += d[k] * e[k];
  }
  const double ad = lr[0] * dd;
  UNROLL for (int k = 0; k < dim; k++) h_out[k] = ad * d[k] + lr[1] * e[k];
}

ALWAYS_INLINE void hooke_hv_k(const khooke *q, int r0, int nr, const double *z0,
                              const double *lin, const double *x, double s,
                              double *g, const int dim) {
  for (int r = r0; r < r0 + nr; r++) {
    double h[3];
    hooke_hv_one(q + r, lin + 2 * r, z0, x, h, dim);
    UNROLL for (int k = 0; k < dim; k++) g[q[r].ci + k] += s * h[k];
    UNROLL for (int k = 0; k < dim; k++) g[q[r].cj + k] += -(s * h[k]);
  }
}

/* Part c's records (mrvi_terms_set_threads) of either kernel, in the
 * serial order on the columns of their masks; lin written by the part
 * holding a record's first column alone. */
ALWAYS_INLINE void part_lin_k(const mrvi_terms *kc, int c, const double *z,
                              double *g, double *lin, const double *x, double s,
                              const int dim, const int hv) {
  const int r0 = kc->part_first[c], nr = kc->part_first[c + 1] - r0;
  const int *rec = kc->part_rec + r0, *run = kc->part_run + r0;
  const unsigned char *mask = kc->part_mask + r0;
  for (int i = 0; i < nr; i++) {
    if (run[i] > 0) { /* whole records: the serial loop, the same sums */
      if (hv)
        hooke_hv_k(kc->qh, rec[i], run[i], z, lin, x, s, g, dim);
      else
        hooke_grad_lin_k(kc->qh, rec[i], run[i], z, g, lin, dim);
      i += run[i] - 1;
      continue;
    }
    const khooke *h = kc->qh + rec[i];
    const unsigned mk = mask[i];
    double v[3];
    if (hv) {
      hooke_hv_one(h, lin + 2 * rec[i], z, x, v, dim);
      UNROLL for (int k = 0; k < dim; k++) v[k] = s * v[k];
    } else {
      double d[3], r2 = 0.0;
      UNROLL for (int k = 0; k < dim; k++) {
        d[k] = z[h->ci + k] - z[h->cj + k];
        r2 += d[k] * d[k];
      }
      const double rr = sqrt(r2), d1 = h->c * (rr - h->shift),
                   ir = recip_len(rr), t = d1 * ir;
      if (mk & 1u) {
        lin[2 * rec[i]] = (h->c - t) * ir * ir;
        lin[2 * rec[i] + 1] = t;
      }
      UNROLL for (int k = 0; k < dim; k++) v[k] = d1 * (d[k] * ir);
    }
    UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << k) g[h->ci + k] += v[k];
    UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << (dim + k))
        g[h->cj + k] += -v[k];
  }
}

void mrvi_terms_grad_lin(const mrvi_terms *kc, const double *z, double *g,
                         double *lin) {
  if (kc->dim == 2)
    hooke_grad_lin_k(kc->qh, 0, kc->n, z, g, lin, 2);
  else if (kc->dim == 3)
    hooke_grad_lin_k(kc->qh, 0, kc->n, z, g, lin, 3);
  else
    hooke_grad_lin_k(kc->qh, 0, kc->n, z, g, lin, 1);
}

void mrvi_terms_grad_lin_part(const mrvi_terms *kc, int c, const double *z,
                              double *g, double *lin) {
  if (kc->dim == 2)
    part_lin_k(kc, c, z, g, lin, NULL, 0.0, 2, 0);
  else if (kc->dim == 3)
    part_lin_k(kc, c, z, g, lin, NULL, 0.0, 3, 0);
  else
    part_lin_k(kc, c, z, g, lin, NULL, 0.0, 1, 0);
}

void mrvi_terms_hv_lin(const mrvi_terms *kc, const double *z0,
                       const double *lin, const double *x, double s,
                       double *g) {
  if (kc->dim == 2)
    hooke_hv_k(kc->qh, 0, kc->n, z0, lin, x, s, g, 2);
  else if (kc->dim == 3)
    hooke_hv_k(kc->qh, 0, kc->n, z0, lin, x, s, g, 3);
  else
    hooke_hv_k(kc->qh, 0, kc->n, z0, lin, x, s, g, 1);
}

void mrvi_terms_hv_lin_part(const mrvi_terms *kc, int c, const double *z0,
                            const double *lin, const double *x, double s,
                            double *g) {
  double *l = (double *)lin; /* (read alone where hv) */
  if (kc->dim == 2)
    part_lin_k(kc, c, z0, g, l, x, s, 2, 1);
  else if (kc->dim == 3)
    part_lin_k(kc, c, z0, g, l, x, s, 3, 1);
  else
    part_lin_k(kc, c, z0, g, l, x, s, 1, 1);
}

int mrvi_terms_threads(const mrvi_terms *kc) {
  return kc->threads > 1 ? kc->threads : 1;
}

void mrvi_terms_grad(mrvi_terms *kc, const double *z, double *g) {
  if (kc->threads > 1)
    part_grad(kc, z, g);
  else if (kc->hooke_only && kc->exact)
    hooke_grad_src(hooke_src(kc), kc->n, z, g, kc->dim);
  else if (kc->hooke_only)
    hooke_grad1(hooke_src(kc), kc->n, z, g, kc->dim);
  else if (kc->qm)
    pairs_eval(kc, z, 1.0, g, NULL, 0, 0.0);
  else if (kc->spring_only) /* (eval_k's one run at unit scale) */
    springs_eval(kc->qs, kc->n, z, 1.0, g, NULL, 0, 0.0, kc->dim);
  else if (kc->flat)
    flat_grad(kc, z, g);
  else
    terms_grad_any(kc, z, g);
}

/* Whether every term of kc is a khooke record of qh in the serial order
 * (hooke_grad1 over qh[0 .. n) is then mrvi_terms_grad's loop, bitwise). */
static int hooke_in_order(const mrvi_terms *kc) {
  if (kc->hooke_only || !kc->recip || !kc->qh || !kc->hooke_run || kc->n < 1)
    return 0;
  for (int it = 0; it < kc->n;) {
    kterm tt;
    const kterm *t = term_at(kc, it, &tt);
    if (!(t->runs > 0 && t->qs == it && kc->hooke_run[t->qs]))
      return 0;
    it += t->runs;
  }
  return 1;
}

int mrvi_terms_set_fused(mrvi_terms *kc, int ncol, int block) {
  free(kc->fuse_zero);
  free(kc->fuse_done);
  kc->fuse_zero = kc->fuse_done = NULL;
  kc->fuse_nb = 0;
  if (block < 1 || ncol < 1 || !hooke_in_order(kc))
    return 0;
  const int n = kc->n, dim = kc->dim, nb = (n + block - 1) / block;
  /* (the kept arrays before the temporary one, so that the temporary is
   * not held below them: freed, its pages go to what is allocated next
   * instead of staying a hole, doc/performance/17-mem17.md) */
  kc->fuse_zero = malloc((size_t)nb * sizeof(int));
  kc->fuse_done = malloc((size_t)nb * sizeof(int));
  int *last = malloc((size_t)ncol * sizeof(int));
  if (!last || !kc->fuse_zero || !kc->fuse_done) {
    free(last);
    free(kc->fuse_zero);
    free(kc->fuse_done);
    kc->fuse_zero = kc->fuse_done = NULL;
    return MRVI_ENOMEM;
  }
  for (int f = 0; f < ncol; f++)
    last[f] = -1;
  int top = 0; /* one past the largest column touched so far */
  for (int r = 0; r < n; r++) {
    const khooke *h = kc->qh + r;
    for (int k = 0; k < dim; k++) {
      if (h->ci + k >= ncol || h->cj + k >= ncol || h->ci < 0 || h->cj < 0) {
        free(last); /* (columns beyond ncol: not this class's layout) */
        return mrvi_terms_set_fused(kc, 0, 0);
      }
      last[h->ci + k] = last[h->cj + k] = r;
      top = h->ci + k + 1 > top ? h->ci + k + 1 : top;
      top = h->cj + k + 1 > top ? h->cj + k + 1 : top;
    }
    if (r % block == block - 1 || r == n - 1)
      kc->fuse_zero[r / block] = top;
  }
  /* fuse_done[b]: the columns below it all last touched in blocks <= b */
  int f = 0;
  for (int b = 0; b < nb; b++) {
    const int end = b + 1 < nb ? (b + 1) * block : n;
    while (f < ncol && last[f] < end)
      f++;
    kc->fuse_done[b] = f;
  }
  free(last);
  kc->fuse_nb = nb;
  kc->fuse_b = block;
  kc->fuse_ncol = ncol;
  return 1;
}

int mrvi_terms_fused(const mrvi_terms *kc) {
  return kc->fuse_nb > 0 && kc->threads <= 1;
}

/* The columns [zp, to) of mrvi_terms_grad_fused zeroed, by first where
 * given (in its pass over them); the new zp returned. */
static int fused_zero(double *g, int zp, int to, mrvi_cols_fn first,
                      void *ctx) {
  if (to <= zp)
    return zp;
  if (first) {
    first(ctx, to);
    return to;
  }
  for (; zp < to; zp++)
    g[zp] = 0.0;
  return zp;
}

/* hooke_grad_k with one = 1 on q[r0 .. r0 + nr), two springs at a time:
 * each lane the scalar kernel's operations (the square root and the
 * division of two springs in one instruction each, util/simd.h), the
 * sums into g spring by spring in the serial order, a spring's first two
 * axes as one pair (the same additions lane by lane), so g is
 * hooke_grad_k's bit for bit (z is not g: every difference is read before
 * any sum).  q: the records, or the columns of a class whose springs share
 * one stiffness and rest length (hooke_rec). */
ALWAYS_INLINE void hooke_grad_pairs(hsrc q, int r0, int nr, const double *z,
                                    double *g, const int dim) {
  int r = r0;
  for (; r + 2 <= r0 + nr; r += 2) {
    const khooke ra = hooke_rec(q, r), rb = hooke_rec(q, r + 1);
    const khooke *a = &ra, *b = &rb;
    mrvi_v2 t[3];
    hooke_pair(a, b, z, t, dim);
    if (dim == 1) {
      g[a->ci] += v2_lo(t[0]);
      g[a->cj] += -v2_lo(t[0]);
      g[b->ci] += v2_hi(t[0]);
      g[b->cj] += -v2_hi(t[0]);
      continue;
    }
    /* (a spring's first two axes as a pair: g + v and g - v = g + (-v)
     * lane by lane; a particle's columns are all or none of another's) */
    const mrvi_v2 t2 = dim == 3 ? t[2] : v2_zero();
    pair_add(g, a->ci, a->cj, v2_set(v2_lo(t[0]), v2_lo(t[1])), v2_lo(t2), dim);
    pair_add(g, b->ci, b->cj, v2_set(v2_hi(t[0]), v2_hi(t[1])), v2_hi(t2), dim);
  }
  hooke_grad_k(q, r, r0 + nr - r, z, g, dim, 1);
}

/* mrvi_terms_grad_fused in dimension dim: the blocks of hooke_grad1's
 * loop, each column zeroed just before the first block that adds to it. */
ALWAYS_INLINE void fused_k(const mrvi_terms *kc, const double *z, double *g,
                           mrvi_cols_fn first, mrvi_cols_fn done, void *ctx,
                           const int dim) {
  const int n = kc->n, nb = kc->fuse_nb, B = kc->fuse_b;
  int zp = 0, dp = 0;
  for (int b = 0; b < nb; b++) {
    const int r0 = b * B, nr = b + 1 < nb ? B : n - r0;
    zp = fused_zero(g, zp, kc->fuse_zero[b], first, ctx);
    hooke_grad_pairs((hsrc){kc->qh, NULL, 0.0, 0.0}, r0, nr, z, g, dim);
    const int d = kc->fuse_done[b];
    if (d > dp) { /* (and the columns no record touches) */
      zp = fused_zero(g, zp, d, first, ctx);
      done(ctx, d);
      dp = d;
    }
  }
  zp = fused_zero(g, zp, kc->fuse_ncol, first, ctx);
  if (dp < kc->fuse_ncol)
    done(ctx, kc->fuse_ncol);
}

void mrvi_terms_grad_fused(const mrvi_terms *kc, const double *z, double *g,
                           mrvi_cols_fn first, mrvi_cols_fn done, void *ctx) {
  if (kc->dim == 2)
    fused_k(kc, z, g, first, done, ctx, 2);
  else if (kc->dim == 3)
    fused_k(kc, z, g, first, done, ctx, 3);
  else
    fused_k(kc, z, g, first, done, ctx, 1);
}

int mrvi_terms_count(const mrvi_terms *kc) { return kc->n; }

int mrvi_terms_shared_law(const mrvi_terms *kc) { return kc->qm != NULL; }

long mrvi_terms_bytes(const mrvi_terms *kc) {
  long b = 0, n_col = 0, n_coef = 0, n4 = 0, ns = 0;
  for (int it = 0; kc->t && it < kc->n; it++) {
    const kterm *t = &kc->t[it];
    n_col += t->runs > 0 ? 0 : t->n;
    n_coef += t->el->coef ? t->n : 0;
    n4 += t->run4 > 0;
    ns += t->runs > 0;
  }
  if (!kc->t)
    ns = kc->qs || kc->qh ? kc->n : 0;
  b += kc->t ? kc->n * (long)sizeof *kc->t : 0;
  b += n_col * (long)sizeof *kc->col + n_coef * (long)sizeof *kc->coef;
  b += n4 * (long)sizeof *kc->q4;
  b += kc->qs ? ns * (long)sizeof *kc->qs : 0;
  b += kc->qh ? ns * (long)sizeof *kc->qh : 0;
  b += kc->hooke_run ? ns : 0;
  b += kc->qp ? kc->n * (long)sizeof *kc->qp : 0;
  b += kc->qm ? kc->n * (long)sizeof *kc->qm : 0;
  b += kc->rs ? (kc->n_rs + 1) * (long)sizeof *kc->rs : 0;
  return b;
}

/* flat_grad with each record's phi'' weighted into dsum: the gradient's
 * products and their order those of flat_grad (bitwise the same). */
ALWAYS_INLINE void term4_grad_d2(const kterm4 *q, const double *z, double *g,
                                 double w, double *dsum, const int n,
                                 const int k) {
  int col[4];
  double a[4], d1, d2;
  term4_derivs(q, z, col, a, &d1, &d2, n, k);
  UNROLL for (int j = 0; j < n; j++) g[col[j]] += d1 * a[j];
  *dsum += w * d2;
}

ALWAYS_INLINE void grad_d2_k(const kterm4 *q, int nr, const double *z,
                             double *g, double w, double *dsum, const int k) {
  for (int r = 0; r < nr; r++) {
    switch (q[r].n) {
    case 2:
      term4_grad_d2(q + r, z, g, w, dsum + r, 2, k);
      break;
    case 3:
      term4_grad_d2(q + r, z, g, w, dsum + r, 3, k);
      break;
    default:
      term4_grad_d2(q + r, z, g, w, dsum + r, 4, k);
    }
  }
}

void mrvi_terms_grad_d2(const mrvi_terms *kc, const double *z, double *g,
                        double w, double *dsum) {
  switch (kc->flat_k) {
  case -1:
    grad_d2_k(kc->q4, kc->n, z, g, w, dsum, -1);
    break;
  case 4:
    grad_d2_k(kc->q4, kc->n, z, g, w, dsum, 4);
    break;
  default:
    grad_d2_k(kc->q4, kc->n, z, g, w, dsum, K_ANY);
  }
}

void mrvi_terms_hess_d2(const mrvi_terms *kc, const double *dsum, double *J,
                        int ld, int lim) {
  for (int r = 0; r < kc->n; r++) {
    const kterm4 *q = &kc->q4[r];
    for (int j = 0; j < q->n; j++) {
      if (q->col[j] >= lim)
        continue;
      const double u = dsum[r] * q->a[j];
      for (int l = 0; l < q->n; l++)
        if (q->col[l] < lim)
          J[q->col[j] * ld + q->col[l]] += u * q->a[l];
    }
  }
}

/* A spring or anchor (spring_eval's arithmetic, law code kk): its
 * gradient added to g, and hscale times its Hessian, the blocks
 * [A -A; -A A] (or A), added entry by entry into Ax[map[k]] in the
 * row-major order of the element's n_in x n_in Hessian (mrvi_element_eval
 * and a scatter of it: bitwise the same); map[k] < 0: entry left out. */
ALWAYS_INLINE void spring_map(const kspring *q, const double *z, double *g,
                              double *Ax, const int *map, double hscale,
                              const int dim, const int two, const int kk,
                              const int compact, const unsigned mk) {
  double u[3], d1, a, b;
  spring_derivs(q, z, u, &d1, &a, &b, dim, two, kk);
  UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << k) g[q->ci[k]] +=
      d1 * u[k];
  if (two)
    UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << (dim + k))
        g[q->cj[k]] += -d1 * u[k];
  if (!map)
    return;
  const int n = two ? 2 * dim : dim;
  UNROLL for (int i = 0; i < n; i++) {
    UNROLL for (int j = 0; j < n; j++) {
      if (!(mk & 1u << j)) /* (column j: x_i's k-th, then x_j's) */
        continue;
      const int ii = i < dim ? i : i - dim, jj = j < dim ? j : j - dim;
      const double A = a * u[ii] * u[jj] + (ii == jj ? b : 0.0);
      /* (compact: the block pair's base, + the column's length a column
       * and 1 a row, mrvi_sblock_map_expand) */
      const int nb = two ? 2 : 1, bi = i < dim ? 0 : 1, bj = j < dim ? 0 : 1;
      const int t0 = compact ? map[bj * nb + bi] : map[i * n + j];
      const int t = compact && t0 >= 0 ? t0 + jj * map[nb * nb + bj] + ii : t0;
      if (t >= 0)
        Ax[t] += hscale * ((i < dim) == (j < dim) ? A : -A);
    }
  }
}

/* A run of nr springs or anchors from record q (element index ie0) into
 * the sparse values (a loop per dimension, kind and law code). */
ALWAYS_INLINE void springs_map_k(const kspring *q, int nr, int ie0,
                                 const double *z, double *g, double *Ax,
                                 const long *off, const int *emap,
                                 double hscale, const int dim, const int two) {
#define SPRINGS_MAP(KK)                                                        \
  for (int r = 0; r < nr; r++) {                                               \
    const long o = off[ie0 + r];                                               \
    if (o >= 0)                                                                \
      spring_map(q + r, z, g, Ax, emap + o, hscale, dim, two, KK, 0, ~0u);     \
    else if (o < -1) /* (a compact map) */                                     \
      spring_map(q + r, z, g, Ax, emap - 2 - o, hscale, dim, two, KK, 1, ~0u); \
    else /* (no Hessian entries) */                                            \
      spring_eval(q + r, z, 1.0, g, NULL, 0, 0.0, dim, two, KK, 1);            \
  }
  switch (q->k) {
  case KS_HOOKE:
    SPRINGS_MAP(KS_HOOKE)
    break;
  case KS_LAW:
    SPRINGS_MAP(KS_LAW)
    break;
  case KS_MORSE:
    SPRINGS_MAP(KS_MORSE)
    break;
  default:
    SPRINGS_MAP(K_ANY)
  }
#undef SPRINGS_MAP
}

static __attribute__((noinline)) void
springs_map(const kspring *q, int nr, int ie0, const double *z, double *g,
            double *Ax, const long *off, const int *emap, double hscale,
            int dim) {
#define SPRINGS_MP(D, T)                                                       \
  springs_map_k(q, nr, ie0, z, g, Ax, off, emap, hscale, D, T)
  SPRING_SHAPES(SPRINGS_MP);
#undef SPRINGS_MP
}

void mrvi_terms_eval_sparse(mrvi_terms *kc, const double *z, double *g,
                            double *Ax, const long *off, const int *emap,
                            double hscale) {
  for (int it = 0; it < kc->n; it++) {
    kterm tt;
    const kterm *t = term_at(kc, it, &tt);
    if (t->runs > 0) {
#define MAP_(q, n, r)                                                          \
  springs_map(q, n, it + r, z, g, Ax, off, emap, hscale, kc->dim)
      SPRING_PIECES(kc, t->qs, t->runs, MAP_);
#undef MAP_
      it += t->runs - 1;
      continue;
    }
    /* Every other element through the generic evaluation. */
    const int n = t->n, *col = kc->col + t->first;
    const int lin = t->el->kind == MRVI_ELEMENT_GRAVITY;
    element_at(kc, t, z, kc->g, lin ? NULL : kc->H);
    for (int j = 0; j < n; j++)
      g[col[j]] += kc->g[j];
    if (lin || off[it] == -1)
      continue;
    int buf[MRVI_SBLOCK_COMPACT_MAX * MRVI_SBLOCK_COMPACT_MAX];
    const int *map = emap + off[it];
    if (off[it] < -1) {
      mrvi_sblock_map_expand(emap - 2 - off[it], n, kc->dim, buf);
      map = buf;
    }
    for (int k = 0; k < n * n; k++)
      if (map[k] >= 0)
        Ax[map[k]] += hscale * kc->H[k];
  }
}

int mrvi_terms_sparse_parts(const mrvi_terms *kc) {
  if (!kc->part_first || !kc->qs)
    return 0;
  if (kc->rs) /* (springs_runs: record it is element it) */
    return kc->n_part;
  if (!kc->t)
    return 0;
  for (int it = 0; it < kc->n; it++) /* (record it: element it) */
    if (kc->t[it].runs < 1 || kc->t[it].qs != it)
      return 0;
  return kc->n_part;
}

/* Part c's records into the sparse values: spring_map on the columns of
 * the part's mask alone (the gradient's and the Hessian's), each record's
 * map by its element index (its record index, mrvi_terms_sparse_parts). */
static __attribute__((noinline)) void
part_map(const kspring *q, const int *rec, const unsigned char *mask, int nr,
         const double *z, double *g, double *Ax, const long *off,
         const int *emap, double hscale, int dim) {
#define PART_MAP(D)                                                            \
  for (int i = 0; i < nr; i++) {                                               \
    const kspring *s = q + rec[i];                                             \
    const long o = off[rec[i]];                                                \
    const int *map = o >= 0 ? emap + o : o < -1 ? emap - 2 - o : NULL;         \
    if (s->two && o < -1)                                                      \
      spring_map(s, z, g, Ax, map, hscale, D, 1, K_ANY, 1, mask[i]);           \
    else if (s->two)                                                           \
      spring_map(s, z, g, Ax, map, hscale, D, 1, K_ANY, 0, mask[i]);           \
    else if (o < -1)                                                           \
      spring_map(s, z, g, Ax, map, hscale, D, 0, K_ANY, 1, mask[i]);           \
    else                                                                       \
      spring_map(s, z, g, Ax, map, hscale, D, 0, K_ANY, 0, mask[i]);           \
  }
  if (dim == 2)
    PART_MAP(2)
  else if (dim == 3)
    PART_MAP(3)
  else
    PART_MAP(1)
#undef PART_MAP
}

void mrvi_terms_eval_sparse_part(const mrvi_terms *kc, int c, const double *z,
                                 double *g, double *Ax, const long *off,
                                 const int *emap, double hscale) {
  const int r0 = kc->part_first[c], nr = kc->part_first[c + 1] - r0;
  part_map(kc->qs, kc->part_rec + r0, kc->part_mask + r0, nr, z, g, Ax, off,
           emap, hscale, kc->dim);
}

/* A spring or anchor's gradient added to g (spring_eval's products),
 * hscale times the diagonal entries of its Hessian blocks [A -A; -A A]
 * (A_kk = a u_k u_k + b, spring_map's products) added to hd, and, unless
 * off is NULL, the absolute values of hscale times its off-diagonal
 * entries added to off by row; each only on the columns of the mask mk
 * (bit k: x_i's column k, bit dim + k: x_j's; ~0u: all, the serial loop;
 * a part's mask, mrvi_terms_set_threads, on threads). */
ALWAYS_INLINE void spring_hdiag(const kspring *q, const double *z, double *g,
                                double *hd, double *off, double hscale,
                                const unsigned mk, const int dim,
                                const int two) {
  double u[3], d1, a, b;
  spring_derivs(q, z, u, &d1, &a, &b, dim, two, K_ANY);
  UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << k) g[q->ci[k]] +=
      d1 * u[k];
  if (two)
    UNROLL for (int k = 0; k < dim; k++) if (mk & 1u << (dim + k))
        g[q->cj[k]] += -d1 * u[k];
  UNROLL for (int k = 0; k < dim; k++) {
    const double A = a * u[k] * u[k] + b;
    if (mk & 1u << k)
      hd[q->ci[k]] += hscale * A;
    if (two && mk & 1u << (dim + k))
      hd[q->cj[k]] += hscale * A;
  }
  if (!off)
    return;
  UNROLL for (int k = 0; k < dim; k++) {
    double o = 0.0;
    UNROLL for (int l = 0; l < dim; l++) {
      const double A = a * u[k] * u[l];
      o += (l != k ? fabs(hscale * A) : 0.0) +
           (two ? fabs(hscale * (A + (l == k ? b : 0.0))) : 0.0);
    }
    if (mk & 1u << k)
      off[q->ci[k]] += o;
    if (two && mk & 1u << (dim + k))
      off[q->cj[k]] += o;
  }
}

static __attribute__((noinline)) void springs_hdiag(const kspring *q, int nr,
                                                    const double *z, double *g,
                                                    double *hd, double *off,
                                                    double hscale, int dim) {
#define SPRINGS_HD(D, T)                                                       \
  do {                                                                         \
    for (int r = 0; r < nr; r++)                                               \
      spring_hdiag(q + r, z, g, hd, off, hscale, ~0u, D, T);                   \
  } while (0)
  SPRING_SHAPES(SPRINGS_HD);
#undef SPRINGS_HD
}

int mrvi_terms_springs_only(const mrvi_terms *kc) {
  if (kc->n < 1)
    return 0;
  if (kc->hooke_only || kc->spring_only || kc->rs)
    return 1;
  for (int it = 0; it < kc->n; it++)
    if (kc->t[it].runs < 1)
      return 0;
  return 1;
}

void mrvi_terms_grad_hdiag(const mrvi_terms *kc, const double *z, double *g,
                           double *hd, double *off, double hscale) {
  for (int it = 0; it < kc->n; it++) {
    kterm tt;
    const kterm *t = term_at(kc, it, &tt);
#define HD_(q, n, r) springs_hdiag(q, n, z, g, hd, off, hscale, kc->dim)
    SPRING_PIECES(kc, t->qs, t->runs, HD_);
#undef HD_
    it += t->runs - 1;
  }
}

/* One record of mrvi_terms_gershgorin: pass 0 adds its blocks' signed
 * own-particle off-diagonal entries hscale a u_k u_l (k < l) to s at the
 * particle's column k + l - 1 and, for a spring, each row's sum of the
 * absolute entries between its ends, hscale |a u_k u_l + b delta_kl|, to
 * o; pass 1 returns the largest row bound (o + sum_l |s|) dinv over its
 * columns (NaN where one is).  Only on the columns of the mask mk
 * (record_col's bits; ~0u: all). */
ALWAYS_INLINE double spring_gersh(const kspring *q, const double *z, double *s,
                                  double *o, const double *dinv, double hscale,
                                  const unsigned mk, const int pass,
                                  const int dim, const int two) {
  if (pass == 1) {
    double m = 0.0;
    for (int e = 0; e < (two ? 2 : 1); e++) {
      const int *c = e ? q->cj : q->ci;
      UNROLL for (int k = 0; k < dim; k++) {
        if (!(mk & 1u << (e * dim + k)))
          continue;
        double t = o[c[k]];
        UNROLL for (int l = 0; l < dim; l++) if (l != k) t +=
            fabs(s[c[k + l - 1]]);
        const double v = t * dinv[c[k]];
        m = v > m || isnan(v) ? v : m;
      }
    }
    return m;
  }
  double u[3], d1, a, b;
  spring_derivs(q, z, u, &d1, &a, &b, dim, two, K_ANY);
  UNROLL for (int k = 0; k < dim; k++)
      UNROLL for (int l = k + 1; l < dim; l++) {
    const double x = hscale * a * u[k] * u[l];
    if (mk & 1u << (k + l - 1))
      s[q->ci[k + l - 1]] += x;
    if (two && mk & 1u << (dim + k + l - 1))
      s[q->cj[k + l - 1]] += x;
  }
  if (two)
    UNROLL for (int k = 0; k < dim; k++) {
      double t = 0.0;
      UNROLL for (int l = 0; l < dim; l++) t +=
          fabs(hscale * (a * u[k] * u[l] + (l == k ? b : 0.0)));
      if (mk & 1u << k)
        o[q->ci[k]] += t;
      if (mk & 1u << (dim + k))
        o[q->cj[k]] += t;
    }
  return 0.0;
}

static __attribute__((noinline)) double
springs_gersh(const kspring *q, int nr, const double *z, double *s, double *o,
              const double *dinv, double hscale, int pass, int dim) {
  double m = 0.0;
#define SPRINGS_GS(D, T)                                                       \
  do {                                                                         \
    for (int r = 0; r < nr; r++) {                                             \
      const double v =                                                         \
          spring_gersh(q + r, z, s, o, dinv, hscale, ~0u, pass, D, T);         \
      m = v > m || isnan(v) ? v : m;                                           \
    }                                                                          \
  } while (0)
  SPRING_SHAPES(SPRINGS_GS);
#undef SPRINGS_GS
  return m;
}

double mrvi_terms_gershgorin(const mrvi_terms *kc, const double *z,
                             double hscale, const double *dinv, double *s,
                             double *o, int ncol) {
  memset(s, 0, (size_t)ncol * sizeof *s);
  memset(o, 0, (size_t)ncol * sizeof *o);
  double m = 0.0;
  for (int pass = 0; pass < 2; pass++)
    for (int it = 0; it < kc->n; it++) {
      kterm tt;
      const kterm *t = term_at(kc, it, &tt);
#define GS_(q, n, r)                                                           \
  do {                                                                         \
    const double v =                                                           \
        springs_gersh(q, n, z, s, o, dinv, hscale, pass, kc->dim);             \
    m = v > m || isnan(v) ? v : m;                                             \
  } while (0)
      SPRING_PIECES(kc, t->qs, t->runs, GS_);
#undef GS_
      it += t->runs - 1;
    }
  return isfinite(m) ? m : HUGE_VAL;
}

double mrvi_terms_gershgorin_part(const mrvi_terms *kc, int c, const double *z,
                                  double hscale, const double *dinv, double *s,
                                  double *o, int pass) {
  const int r0 = kc->part_first[c], nr = kc->part_first[c + 1] - r0;
  const int *rec = kc->part_rec + r0, dim = kc->dim;
  const unsigned char *mask = kc->part_mask + r0;
  const kspring *qs = kc->qs;
  if (pass == 0) { /* (the part's columns: no other part writes them) */
    int f0, f1;
    mrvi_terms_part_columns(kc, c, &f0, &f1);
    memset(s + f0, 0, (size_t)(f1 - f0) * sizeof *s);
    memset(o + f0, 0, (size_t)(f1 - f0) * sizeof *o);
  }
  double m = 0.0;
#define PART_GS(D, T)                                                          \
  do {                                                                         \
    const double v =                                                           \
        spring_gersh(q, z, s, o, dinv, hscale, mask[i], pass, D, T);           \
    m = v > m || isnan(v) ? v : m;                                             \
  } while (0)
  for (int i = 0; i < nr; i++) {
    const kspring *q = qs + rec[i];
    SPRING_SHAPES(PART_GS);
  }
#undef PART_GS
  return m;
}

/* Part c's records (mrvi_terms_set_threads) in the serial order, each
 * on the columns of its mask (spring_hdiag's products). */
static __attribute__((noinline)) void
part_hdiag(const kspring *q, const int *rec, const unsigned char *mask, int nr,
           const double *z, double *g, double *hd, double *off, double hscale,
           int dim) {
#define PART_HD(D)                                                             \
  for (int i = 0; i < nr; i++) {                                               \
    const kspring *s = q + rec[i];                                             \
    if (s->two)                                                                \
      spring_hdiag(s, z, g, hd, off, hscale, mask[i], D, 1);                   \
    else                                                                       \
      spring_hdiag(s, z, g, hd, off, hscale, mask[i], D, 0);                   \
  }
  if (dim == 2)
    PART_HD(2)
  else if (dim == 3)
    PART_HD(3)
  else
    PART_HD(1)
#undef PART_HD
}

void mrvi_terms_grad_hdiag_part(const mrvi_terms *kc, int c, const double *z,
                                double *g, double *hd, double *off,
                                double hscale) {
  const int r0 = kc->part_first[c], nr = kc->part_first[c + 1] - r0;
  part_hdiag(kc->qs, kc->part_rec + r0, kc->part_mask + r0, nr, z, g, hd, off,
             hscale, kc->dim);
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

/* phi(|x_i - x_j| - L0) of spring or anchor record q: mrvi_element_eval's
 * distance arithmetic in its order (model.c), so bitwise its value. */
static double spring_value(const kspring *q, const double *z, int dim) {
  double r2 = 0.0;
  for (int k = 0; k < dim; k++) {
    const double d = z[q->ci[k]] - (q->two ? z[q->cj[k]] : q->el->anchor[k]);
    r2 += d * d;
  }
  const double s = sqrt(r2) - q->shift;
  if (q->k == KS_HOOKE)
    return 0.5 * q->c * s * s; /* laws/linear.c */
  double phi, d1, d2;
  q->el->law->eval(q->el->params, s, &phi, &d1, &d2);
  return phi;
}

/* The values of records i0..i1-1 of a class of khooke springs alone
 * (hooke_class), from 0: spring_value's arithmetic for a Hooke spring, in
 * the class's order, so bitwise value_range of the full class. */
static double hooke_range(const mrvi_terms *kc, int i0, int i1,
                          const double *z) {
  double total = 0.0;
  for (int r = i0; r < i1; r++) {
    const khooke q = hooke_rec(hooke_src(kc), r);
    double r2 = 0.0;
    for (int k = 0; k < kc->dim; k++) {
      const double d = z[q.ci + k] - z[q.cj + k];
      r2 += d * d;
    }
    const double s = sqrt(r2) - q.shift;
    total += 0.5 * q.c * s * s; /* laws/linear.c */
  }
  return total;
}

/* The sum of elements i0..i1-1's values in their order, from 0.  kc->y:
 * scratch of a generic element (vsafe: the class has none). */
static double value_range(mrvi_terms *kc, int i0, int i1, const double *z) {
  if (kc->hooke_only)
    return hooke_range(kc, i0, i1, z);
  double total = 0.0;
  if (kc->qm) { /* (as below, each record's kspring) */
    for (int r = i0; r < i1; r++) {
      const kspring q = pair_spring(kc, r);
      total += spring_value(&q, z, kc->dim);
    }
    return total;
  }
  if (kc->spring_only || kc->rs) { /* (the loop below on runs) */
    for (int r = i0; r < i1; r++) {
      kspring one;
      total += spring_value(springs_at(kc, r, 1, &one), z, kc->dim);
    }
    return total;
  }
  for (int it = i0; it < i1; it++) {
    const kterm *t = &kc->t[it];
    const int n = t->n, *col = kc->col + t->first;
    const double *a = kc->coef + t->cfirst;
    if (t->runs > 0) {
      total += spring_value(&kc->qs[t->qs], z, kc->dim);
      continue;
    }
    if (t->kind == KT_ELEMENT) {
      if (t->el->kind == MRVI_ELEMENT_GRAVITY) { /* input by input */
        for (int j = 0; j < n; j++)
          total += a[j] * z[col[j]];
        continue;
      }
      total += element_at(kc, t, z, NULL, NULL);
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

double mrvi_terms_value(mrvi_terms *kc, const double *z) {
  if (kc->vchunk <= 0)
    return value_range(kc, 0, kc->n, z);
  const int nc = (kc->n - 1) / kc->vchunk + 1, ch = kc->vchunk;
  double *part = kc->vpart;
  MRVI_PARALLEL_FOR(kc->vthreads)
  for (int c = 0; c < nc; c++)
    part[c] =
        value_range(kc, c * ch, kc->n - c * ch < ch ? kc->n : (c + 1) * ch, z);
  double total = 0.0;
  for (int c = 0; c < nc; c++)
    total += part[c];
  return total;
}

int mrvi_terms_set_value_chunks(mrvi_terms *kc, int threads, int chunk) {
  kc->vchunk = 0;
  kc->vthreads = 1;
  if (chunk < 1 || kc->n < 2 * chunk ||
      (!kc->t && !kc->hooke_only && !kc->spring_only && !kc->rs))
    return MRVI_OK;
  free(kc->vpart);
  if (!(kc->vpart = malloc((size_t)((kc->n - 1) / chunk + 1) * sizeof(double))))
    return MRVI_ENOMEM;
  kc->vchunk = chunk;
  /* (threads only where no element needs the shared scratch kc->y) */
  int safe = mrvi_threads_supported();
  for (int i = 0;
       safe && !kc->hooke_only && !kc->spring_only && !kc->rs && i < kc->n; i++)
    safe = kc->t[i].runs > 0 || kc->t[i].kind != KT_ELEMENT ||
           kc->t[i].el->kind == MRVI_ELEMENT_GRAVITY;
  kc->vthreads = safe && threads > 1 ? threads : 1;
  return MRVI_OK;
}

/* A spring or anchor's Hessian block A = scale (a u u^T + b I) (its
 * Hessian is [A -A; -A A]; spring_derivs, law code K_ANY; a Hooke
 * spring's a = c L0 / r, b = c - a with one division). */
ALWAYS_INLINE void spring_block(const kspring *q, const double *restrict z,
                                double scale, double A[3][3], const int dim,
                                const int two, const int hooke) {
  double u[3], d1, a, b;
  if (hooke) {
    double d[3], r2 = 0.0;
    UNROLL for (int k = 0; k < dim; k++) {
      d[k] = z[q->ci[k]] - (two ? z[q->cj[k]] : q->el->anchor[k]);
      r2 += d[k] * d[k];
    }
    const double r = sqrt(r2), ir = recip_len(r);
    UNROLL for (int k = 0; k < dim; k++) u[k] = d[k] * ir;
    a = r > 0.0 ? q->c * q->shift * ir : 0.0;
    b = q->c - a;
  } else {
    spring_derivs(q, z, u, &d1, &a, &b, dim, two, K_ANY);
  }
  UNROLL for (int i = 0; i < dim; i++) UNROLL for (int j = 0; j < dim; j++)
      A[i][j] = scale * (a * u[i] * u[j] + (i == j ? b : 0.0));
}

/* A spring or anchor's Hessian blocks (spring_block) applied to every
 * vector: y_v[i] += A (x_v[i] - x_v[j]), y_v[j] -= the same. */
ALWAYS_INLINE void spring_hessvec(const kspring *q, const double *restrict z,
                                  int nvec, const double *restrict x, long xs,
                                  double *restrict y, long ys, double scale,
                                  const int dim, const int two,
                                  const int hooke) {
  int ci[3], cj[3];
  UNROLL for (int k = 0; k < dim; k++) {
    ci[k] = q->ci[k];
    cj[k] = two ? q->cj[k] : 0;
  }
  double A[3][3];
  spring_block(q, z, scale, A, dim, two, hooke);
  for (int v = 0; v < nvec; v++) {
    const double *xv = x + (size_t)v * (size_t)xs;
    double *yv = y + (size_t)v * (size_t)ys;
    double dx[3];
    UNROLL for (int k = 0; k < dim; k++) dx[k] =
        xv[ci[k]] - (two ? xv[cj[k]] : 0.0);
    UNROLL for (int i = 0; i < dim; i++) {
      double h = 0.0;
      UNROLL for (int j = 0; j < dim; j++) h += A[i][j] * dx[j];
      yv[ci[i]] += h;
      if (two)
        yv[cj[i]] -= h;
    }
  }
}

static __attribute__((noinline)) void
springs_hessvec(const kspring *q, int nr, const double *restrict z, int nvec,
                const double *restrict x, long xs, double *restrict y, long ys,
                double scale, int dim) {
#define SPRINGS_HV(D, T)                                                       \
  do {                                                                         \
    if (q->k == KS_HOOKE)                                                      \
      for (int r = 0; r < nr; r++)                                             \
        spring_hessvec(q + r, z, nvec, x, xs, y, ys, scale, D, T, 1);          \
    else                                                                       \
      for (int r = 0; r < nr; r++)                                             \
        spring_hessvec(q + r, z, nvec, x, xs, y, ys, scale, D, T, 0);          \
  } while (0)
  SPRING_SHAPES(SPRINGS_HV);
#undef SPRINGS_HV
}

void mrvi_terms_hessvec(mrvi_terms *kc, const double *z, int nvec,
                        const double *x, long xs, double *y, long ys,
                        double scale) {
  for (int it = 0; it < kc->n; it++) {
    kterm tt;
    const kterm *t = term_at(kc, it, &tt);
    if (t->runs > 0) {
#define HV_(q, n, r)                                                           \
  springs_hessvec(q, n, z, nvec, x, xs, y, ys, scale, kc->dim)
      SPRING_PIECES(kc, t->qs, t->runs, HV_);
#undef HV_
      it += t->runs - 1;
      continue;
    }
    /* Every other element's Hessian by the generic evaluation (an affine
     * one, gravity, has none). */
    if (t->el->kind == MRVI_ELEMENT_GRAVITY)
      continue;
    const int n = t->n, *col = kc->col + t->first;
    element_at(kc, t, z, kc->g, kc->H);
    for (int v = 0; v < nvec; v++) {
      const double *xv = x + (size_t)v * (size_t)xs;
      double *yv = y + (size_t)v * (size_t)ys;
      for (int j = 0; j < n; j++) {
        double h = 0.0;
        for (int l = 0; l < n; l++)
          h += kc->H[j * n + l] * xv[col[l]];
        yv[col[j]] += scale * h;
      }
    }
  }
}

/* A record's Hessian blocks (spring_block: scale (a u u^T + b I), [A -A;
 * -A A]) applied to x on the columns of the mask mk alone (bit k: x_i's
 * k-th, bit dim + k: x_j's): y[i] += A (x[i] - x[j]), y[j] -= the same,
 * spring_hessvec's products. */
ALWAYS_INLINE void spring_hessvec_mask(const kspring *q,
                                       const double *restrict z,
                                       const double *restrict x,
                                       double *restrict y, double scale,
                                       const unsigned mk, const int dim,
                                       const int two, const int hooke) {
  double A[3][3], dx[3];
  spring_block(q, z, scale, A, dim, two, hooke);
  UNROLL for (int k = 0; k < dim; k++) dx[k] =
      x[q->ci[k]] - (two ? x[q->cj[k]] : 0.0);
  UNROLL for (int i = 0; i < dim; i++) {
    double h = 0.0;
    UNROLL for (int j = 0; j < dim; j++) h += A[i][j] * dx[j];
    if (mk & 1u << i)
      y[q->ci[i]] += h;
    if (two && mk & 1u << (dim + i))
      y[q->cj[i]] -= h;
  }
}

static __attribute__((noinline)) void
recs_hessvec(const kspring *q, const int *rec, const unsigned char *mask,
             int nr, const double *z, const double *x, double *y, double scale,
             int dim) {
#define RECS_HV(D)                                                             \
  for (int i = 0; i < nr; i++) {                                               \
    const kspring *s = q + (rec ? rec[i] : i);                                 \
    const unsigned mk = mask ? mask[i] : ~0u;                                  \
    const int hk = s->k == KS_HOOKE;                                           \
    if (s->two && hk)                                                          \
      spring_hessvec_mask(s, z, x, y, scale, mk, D, 1, 1);                     \
    else if (s->two)                                                           \
      spring_hessvec_mask(s, z, x, y, scale, mk, D, 1, 0);                     \
    else if (hk)                                                               \
      spring_hessvec_mask(s, z, x, y, scale, mk, D, 0, 1);                     \
    else                                                                       \
      spring_hessvec_mask(s, z, x, y, scale, mk, D, 0, 0);                     \
  }
  if (dim == 2)
    RECS_HV(2)
  else if (dim == 3)
    RECS_HV(3)
  else
    RECS_HV(1)
#undef RECS_HV
}

void mrvi_terms_hessvec_part(const mrvi_terms *kc, int c, const double *z,
                             const double *x, double *y, double scale) {
  if (c < 0) { /* (every run, its records at once or in pieces) */
    for (int it = 0; it < kc->n; it++) {
      kterm tt;
      const kterm *t = term_at(kc, it, &tt);
#define HVP_(q, n, r) recs_hessvec(q, NULL, NULL, n, z, x, y, scale, kc->dim)
      SPRING_PIECES(kc, t->qs, t->runs, HVP_);
#undef HVP_
      it += t->runs - 1;
    }
    return;
  }
  const int r0 = kc->part_first[c], nr = kc->part_first[c + 1] - r0;
  recs_hessvec(kc->qs, kc->part_rec + r0, kc->part_mask + r0, nr, z, x, y,
               scale, kc->dim);
}

/* A record's off-diagonal Hessian entries on the columns of the mask mk
 * (spring_map's products, hscale A with A = a u_k u_l (+ b on l = k)):
 * those of its particles' own blocks (l != k) summed into own[0] and
 * own[1] by row (the other two components of the row's particle in their
 * order), the absolute values of those between its two particles into
 * nbr by row. */
ALWAYS_INLINE void spring_offdiag(const kspring *q, const double *z,
                                  double hscale, double *const own[2],
                                  double *nbr, const unsigned mk, const int dim,
                                  const int two) {
  double u[3], d1, a, b;
  spring_derivs(q, z, u, &d1, &a, &b, dim, two, K_ANY);
  UNROLL for (int k = 0; k < dim; k++) {
    double o = 0.0;
    UNROLL for (int l = 0; l < dim; l++) {
      const double A = a * u[k] * u[l] + (l == k ? b : 0.0);
      if (two)
        o += fabs(hscale * -A);
      if (l == k)
        continue;
      double *ol = own[l < k ? l : l - 1];
      if (mk & 1u << k)
        ol[q->ci[k]] += hscale * A;
      if (two && mk & 1u << (dim + k))
        ol[q->cj[k]] += hscale * A;
    }
    if (two && mk & 1u << k)
      nbr[q->ci[k]] += o;
    if (two && mk & 1u << (dim + k))
      nbr[q->cj[k]] += o;
  }
}

static __attribute__((noinline)) void
recs_offdiag(const kspring *q, const int *rec, const unsigned char *mask,
             int nr, const double *z, double hscale, double *const own[2],
             double *nbr, int dim) {
#define RECS_OD(D)                                                             \
  for (int i = 0; i < nr; i++) {                                               \
    const kspring *s = q + (rec ? rec[i] : i);                                 \
    const unsigned mk = mask ? mask[i] : ~0u;                                  \
    if (s->two)                                                                \
      spring_offdiag(s, z, hscale, own, nbr, mk, D, 1);                        \
    else                                                                       \
      spring_offdiag(s, z, hscale, own, nbr, mk, D, 0);                        \
  }
  if (dim == 2)
    RECS_OD(2)
  else if (dim == 3)
    RECS_OD(3)
  else
    RECS_OD(1)
#undef RECS_OD
}

void mrvi_terms_offdiag_part(const mrvi_terms *kc, int c, const double *z,
                             double hscale, double *const own[2], double *nbr) {
  if (c < 0) {
    for (int it = 0; it < kc->n; it++) {
      kterm tt;
      const kterm *t = term_at(kc, it, &tt);
#define ODP_(q, n, r)                                                          \
  recs_offdiag(q, NULL, NULL, n, z, hscale, own, nbr, kc->dim)
      SPRING_PIECES(kc, t->qs, t->runs, ODP_);
#undef ODP_
      it += t->runs - 1;
    }
    return;
  }
  const int r0 = kc->part_first[c], nr = kc->part_first[c + 1] - r0;
  recs_offdiag(kc->qs, kc->part_rec + r0, kc->part_mask + r0, nr, z, hscale,
               own, nbr, kc->dim);
}

/* The kept Hessian blocks of mrvi_terms_hessblocks: per spring or anchor
 * record the upper triangle of its block A by rows (dim (dim + 1) / 2
 * numbers), per other element its n x n Hessian (row-major), none for
 * gravity (affine), in the class's order. */
static long block_len(const mrvi_terms *kc, const kterm *t) {
  if (t->runs > 0)
    return (long)kc->dim * (kc->dim + 1) / 2;
  return t->el->kind == MRVI_ELEMENT_GRAVITY ? 0 : (long)t->n * t->n;
}

long mrvi_terms_hessblocks_size(const mrvi_terms *kc) {
  long n = 0;
  if (!kc->t && !kc->rs) /* (a gradient-only class: no records of the
                            elements) */
    return -1;
  for (int it = 0; it < kc->n; it++) {
    kterm tt;
    n += block_len(kc, term_at(kc, it, &tt));
  }
  return n;
}

/* Runs of springs or anchors: their blocks (spring_block at scale 1),
 * packed. */
static __attribute__((noinline)) void springs_blocks(const kspring *q, int nr,
                                                     const double *restrict z,
                                                     double *restrict B,
                                                     int dim) {
#define SPRINGS_HB(D, T, H)                                                    \
  for (int r = 0; r < nr; r++, B += D * (D + 1) / 2) {                         \
    double A[3][3];                                                            \
    spring_block(q + r, z, 1.0, A, D, T, H);                                   \
    int e = 0;                                                                 \
    UNROLL for (int i = 0; i < D; i++) UNROLL for (int j = i; j < D; j++)      \
        B[e++] = A[i][j];                                                      \
  }
#define SPRINGS_HB_DIM(D, T)                                                   \
  do {                                                                         \
    if (q->k == KS_HOOKE)                                                      \
      SPRINGS_HB(D, T, 1)                                                      \
    else                                                                       \
      SPRINGS_HB(D, T, 0)                                                      \
  } while (0)
  SPRING_SHAPES(SPRINGS_HB_DIM);
#undef SPRINGS_HB_DIM
#undef SPRINGS_HB
}

void mrvi_terms_hessblocks(mrvi_terms *kc, const double *z, double *B) {
  for (int it = 0; it < kc->n; it++) {
    kterm tt;
    const kterm *t = term_at(kc, it, &tt);
    if (t->runs > 0) {
#define HB_(q, n, r)                                                           \
  springs_blocks(q, n, z, B + (long)r * block_len(kc, t), kc->dim)
      SPRING_PIECES(kc, t->qs, t->runs, HB_);
#undef HB_
      B += (long)t->runs * block_len(kc, t);
      it += t->runs - 1;
      continue;
    }
    if (t->el->kind == MRVI_ELEMENT_GRAVITY)
      continue;
    const int n = t->n;
    element_at(kc, t, z, kc->g, B);
    B += (long)n * n;
  }
}

/* y_v += scale A (x_v[i] - x_v[j]), y_v[j] -= the same, for one packed
 * block A (springs_blocks) and every vector. */
ALWAYS_INLINE void block_apply(const kspring *q, const double *restrict B,
                               int nvec, const double *restrict x, long xs,
                               double *restrict y, long ys, double scale,
                               double *restrict xhx, const int dim,
                               const int two) {
  double A[3][3];
  int e = 0;
  UNROLL for (int i = 0; i < dim; i++) UNROLL for (int j = i; j < dim; j++) {
    A[i][j] = scale * B[e++];
    A[j][i] = A[i][j];
  }
  int ci[3], cj[3];
  UNROLL for (int k = 0; k < dim; k++) {
    ci[k] = q->ci[k];
    cj[k] = two ? q->cj[k] : 0;
  }
  for (int v = 0; v < nvec; v++) {
    const double *xv = x + (size_t)v * (size_t)xs;
    double *yv = y + (size_t)v * (size_t)ys;
    double dx[3];
    UNROLL for (int k = 0; k < dim; k++) dx[k] =
        xv[ci[k]] - (two ? xv[cj[k]] : 0.0);
    double xh = 0.0;
    UNROLL for (int i = 0; i < dim; i++) {
      double h = 0.0;
      UNROLL for (int j = 0; j < dim; j++) h += A[i][j] * dx[j];
      yv[ci[i]] += h;
      if (two)
        yv[cj[i]] -= h;
      xh += dx[i] * h;
    }
    if (xhx)
      xhx[v] += xh;
  }
}

static __attribute__((noinline)) void
springs_blocks_apply(const kspring *q, int nr, const double *restrict B,
                     int nvec, const double *restrict x, long xs,
                     double *restrict y, long ys, double scale,
                     double *restrict xhx, int dim) {
#define SPRINGS_BA(D, T)                                                       \
  do {                                                                         \
    for (int r = 0; r < nr; r++)                                               \
      block_apply(q + r, B + (long)r * (D * (D + 1) / 2), nvec, x, xs, y, ys,  \
                  scale, xhx, D, T);                                           \
  } while (0)
  SPRING_SHAPES(SPRINGS_BA);
#undef SPRINGS_BA
}

void mrvi_terms_hessblocks_apply(const mrvi_terms *kc, const double *B,
                                 int nvec, const double *x, long xs, double *y,
                                 long ys, double scale, double *xhx) {
  for (int it = 0; it < kc->n; it++) {
    kterm tt;
    const kterm *t = term_at(kc, it, &tt);
    if (t->runs > 0) {
#define BA_(q, n, r)                                                           \
  springs_blocks_apply(q, n, B + (long)r * block_len(kc, t), nvec, x, xs, y,   \
                       ys, scale, xhx, kc->dim)
      SPRING_PIECES(kc, t->qs, t->runs, BA_);
#undef BA_
      B += (long)t->runs * block_len(kc, t);
      it += t->runs - 1;
      continue;
    }
    if (t->el->kind == MRVI_ELEMENT_GRAVITY)
      continue;
    const int n = t->n, *col = kc->col + t->first;
    for (int v = 0; v < nvec; v++) {
      const double *xv = x + (size_t)v * (size_t)xs;
      double *yv = y + (size_t)v * (size_t)ys;
      double xh = 0.0;
      for (int j = 0; j < n; j++) {
        double h = 0.0;
        for (int l = 0; l < n; l++)
          h += B[j * n + l] * xv[col[l]];
        yv[col[j]] += scale * h;
        xh += xv[col[j]] * (scale * h);
      }
      if (xhx)
        xhx[v] += xh;
    }
    B += (long)n * n;
  }
}

int mrvi_terms_hessblocks_springs(const mrvi_terms *kc, int *ci, int *cj) {
  int nb = 0;
  if (!kc->t && !kc->rs)
    return -1;
  for (int it = 0; it < kc->n; it++) {
    kterm tt;
    const kterm *t = term_at(kc, it, &tt);
    if (t->runs > 0) {
      for (int r = 0; r < t->runs; r++, nb++) {
        kspring one;
        const kspring *q = springs_at(kc, t->qs + r, 1, &one);
        for (int k = 0; k < kc->dim; k++) {
          ci[nb * kc->dim + k] = q->ci[k];
          cj[nb * kc->dim + k] = q->two ? q->cj[k] : -1;
        }
      }
      it += t->runs - 1;
      continue;
    }
    if (t->el->kind != MRVI_ELEMENT_GRAVITY)
      return -1;
  }
  return nb;
}
