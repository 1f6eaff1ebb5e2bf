/* Block elimination for the Newton matrix of an unconstrained step
 * (doc/solver.md, "schur" path).
 *
 * Columns: q_{k+1}^s (ns), then the fast nodes 1..p (block c = node - 1).
 * Rows: the slow row (ns), then the fast row of node m = 0..p-1.  Row m
 * involves nodes m-1, m, m+1 only (kinetic part and the micro intervals
 * m-1, m of eq:Zapprox), i.e. column blocks m-2, m-1, m: the fast-fast part
 * A_ff is block lower-triangular with three block diagonals.  The slow
 * unknowns couple every row (V and W on the micro grid interpolate
 * q_{k+1}^s), so
 *   [A_ss A_sf] [ds]   [R_s]
 *   [A_fs A_ff] [df] = [R_f]
 * is solved with the Schur complement on the slow block:
 *   Y = A_ff^-1 A_fs, z = A_ff^-1 R_f        (block forward sweeps)
 *   (A_ss - A_sf Y) ds = R_s - A_sf z,  df = z - Y ds,
 * at O(p (nf^3 + nf^2 ns) + ns^3) per factorisation instead of a sparse LU
 * of the whole step, and O(p (nf^2 + nf ns) + ns^2) per solve with kept
 * factors (the integrator reuses them while Newton converges). */
#include "solver/solver.h"
#include "util/simd.h"
#include "util/small.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The factors of row block m of a class with one point per interval
 * (interval_row_k), from its points m - 1 (Q) and m (P), made once at
 * creation: each product as interval_row_k would form it, and in fl the
 * bit of each add that interval_row_k makes (the same tests). */
enum {
  RC_SS = 1 << 0,  /* Ass: P, a0 a1 */
  RC_SFQ = 1 << 1, /* Asf column block m - 1: Q, a0 cB */
  RC_SFP = 1 << 2, /* Asf column block m - 1: P, a0 cA */
  RC_SFL = 1 << 3, /* Asf column block m = p - 1: P, a0 cB */
  RC_FSQ = 1 << 4, /* Afs row block m: Q, cB a1 */
  RC_FSP = 1 << 5, /* Afs row block m: P, cA a1 */
  RC_D = 1 << 6,   /* D_m: P, cA cB */
  RC_L1Q = 1 << 7, /* L1_m: Q, cB cB */
  RC_L1P = 1 << 8, /* L1_m: P, cA cA */
  RC_L2 = 1 << 9   /* L2_m: Q, cB cA */
};
typedef struct row_coef {
  double ss, sfq, sfp, sfl, fsq, fsp, d, l1q, l1p, l2;
  unsigned fl;
} row_coef;

struct mrvi_blocks {
  int ns, nf, p;
  double *Ass, *Asf, *Afs; /* ns x ns, ns x p nf, p nf x ns */
  double *D, *L1, *L2;     /* p blocks nf x nf each: column m, m-1, m-2 */
  double *blk;             /* the six above, contiguous in this order */
  size_t n_blk;
  int *piv;              /* p x nf (pivots of the factored D) */
  double *dinv, *sdinv;  /* p x nf, ns: reciprocal pivots of D and S */
  double *Y, *z, *S, *r; /* p nf x ns (in place of Afs), p nf, ns x ns, ns */
  int r_done;            /* r = R_s - A_sf z made by the last factorisation
                            (schur_r_k) */
  int *spiv;
  double **dst; /* block entry of every CSC entry (built on the first
                   factorisation: the pattern is fixed for the run) */
  long n_dst;
  double sink; /* where the constraint rows of x's columns go (bordered.c) */
  /* Direct assembly (mrvi_blocks_assemble): V and W compiled on the packed
   * point configuration zp = (z_s, z_f), its gradient G and Hessian H
   * (nz x nz, nz = ns + nf), the masses, and whether a class has slow and
   * fast inputs. */
  mrvi_terms *kc[2];
  double *zp, *G, *H, *ms, *mf;
  double *vel; /* p nf: the micro intervals' velocities (assemble_k) */
  int has_s[2], has_f[2];
  int assembled; /* the blocks hold the Newton matrix of the last
                    mrvi_blocks_assemble (not yet factored) */
  /* The constant part of the Newton matrix (kinetic rows and the classes
   * whose Hessian is constant, quad[c]: every element quadratic), saved on
   * the first assembly: Ass, Asf, Afs, D, L1, L2 in order. */
  int quad[2], const_ok;
  double *cblk;
  /* The blocks still wait for their constant part (an assembly with jac
   * after the first): restored by the first class that adds Hessians
   * (before it; in its own pass if it keeps them per interval), or at the
   * end of the assembly if none does. */
  int restore;
  /* A class with a constant Hessian on small blocks (ns, nf <= 4) takes
   * its gradient as the affine map g0 + Hq z (nz and nz x nz): a few
   * products instead of a pass over its terms. */
  double *g0[2], *Hq[2];
  /* V and W have the same points (midpoint-midpoint): each point is
   * visited once with the two classes' gradients summed. */
  int same_pts;
  /* Class c has one point per micro interval, point m in interval m (the
   * midpoint and trapezoidal rules on the micro grid, p >= 2; set at
   * creation): its points' Hessians are kept, one
   * per interval (Hp, p x nz x nz), and added to the blocks row block by
   * row block after the points (interval_hessians_k). */
  int per_iv[2];
  double *Hp;
  row_coef *rc[2]; /* with per_iv[c]: class c's factors per row block */
  /* Chord matrix (mrvi_blocks_chord): the structure admits it (chord_st;
   * const_uni: the constant part's fast row blocks from 2 on are equal,
   * known after the first assembly), it is requested (chord), and the
   * blocks as last assembled hold it (uniform: the fast row blocks from 2
   * on are those of row block 2, which alone is filled and factored). */
  int chord_st, const_uni, chord, uniform;
  /* Class c's weights of the frozen Hessian in the slow blocks (set with
   * chord_st): Ass, then per node j = 1..p the column block j - 1 of Asf
   * and the row block j - 1 of Afs (2p + 1). */
  double *fw[2];
  /* Class c's frozen Hessian: the mean of those at its first and last
   * points (mrvi_blocks_chord_spread; nz x nz each). */
  double *Hz[2];
  double m_min; /* the smallest mass (the chord rule's measure) */
  /* Constant chord (mrvi_blocks_const_factor): blocks of the same step
   * holding the factors of the constant part alone, made once per run
   * (cf_status its factorisation's status). */
  mrvi_blocks *cf;
  int cf_status;
  /* ... and on a step of at most const_chord_dense unknowns (mrvi.h,
   * MRVI_TUNING_LIST) its inverse (n x n, by rows): a solve is then n
   * independent dot products instead of the sweeps' chain. */
  double *cinv;
  int n_cinv;
};

void mrvi_blocks_free(mrvi_blocks *b) {
  if (!b)
    return;
  free(b->blk);
  free(b->piv);
  free(b->z);
  free(b->S);
  free(b->r);
  free(b->spiv);
  free(b->dinv);
  free(b->sdinv);
  free(b->dst);
  mrvi_terms_free(b->kc[0]);
  mrvi_terms_free(b->kc[1]);
  free(b->zp);
  free(b->G);
  free(b->H);
  free(b->ms);
  free(b->mf);
  free(b->vel);
  free(b->cblk);
  free(b->Hp);
  mrvi_blocks_free(b->cf);
  free(b->cinv);
  for (int c = 0; c < 2; c++) {
    free(b->rc[c]);
    free(b->fw[c]);
    free(b->Hz[c]);
    free(b->g0[c]);
    free(b->Hq[c]);
  }
  free(b);
}

/* The factors of interval_row_k for the p points pts of a class with one
 * point per interval (NULL if out of memory). */
static row_coef *row_coefs(const mrvi_point *pts, int p) {
  row_coef *rc = calloc((size_t)p, sizeof(row_coef));
  for (int m = 0; rc && m < p; m++) {
    const mrvi_point *P = &pts[m];
    const double w = P->w, a0 = P->a0, a1 = P->a1, cA = P->cA, cB = P->cB;
    /* Point m - 1: zero factors before the first interval. */
    double qw = 0.0, qa0 = 0.0, qa1 = 0.0, qA = 0.0, qB = 0.0;
    if (m >= 1) {
      const mrvi_point *Q = &pts[m - 1];
      qw = Q->w;
      qa0 = Q->a0;
      qa1 = Q->a1;
      qA = Q->cA;
      qB = Q->cB;
    }
    row_coef *r = &rc[m];
    unsigned fl = 0;
    r->ss = -w * a0 * a1;
    fl |= a0 != 0.0 && a1 != 0.0 ? RC_SS : 0;
    r->sfq = -qw * qa0 * qB;
    fl |= m >= 1 && qa0 != 0.0 && qB != 0.0 ? RC_SFQ : 0;
    r->sfp = -w * a0 * cA;
    fl |= m >= 1 && a0 != 0.0 && cA != 0.0 ? RC_SFP : 0;
    r->sfl = -w * a0 * cB;
    fl |= m == p - 1 && a0 != 0.0 && cB != 0.0 ? RC_SFL : 0;
    r->fsq = -qw * qB * qa1;
    fl |= m >= 1 && qa1 != 0.0 && qB != 0.0 ? RC_FSQ : 0;
    r->fsp = -w * cA * a1;
    fl |= a1 != 0.0 && cA != 0.0 ? RC_FSP : 0;
    r->d = -w * cA * cB;
    fl |= cA != 0.0 && cB != 0.0 ? RC_D : 0;
    r->l1q = -qw * qB * qB;
    fl |= m >= 1 && qB != 0.0 ? RC_L1Q : 0;
    r->l1p = -w * cA * cA;
    fl |= m >= 1 && cA != 0.0 ? RC_L1P : 0;
    r->l2 = -qw * qB * qA;
    fl |= m >= 2 && qA != 0.0 && qB != 0.0 ? RC_L2 : 0;
    r->fl = fl;
  }
  return rc;
}

int mrvi_blocks_create(const mrvi_step *st, mrvi_blocks **out) {
  mrvi_blocks *b = calloc(1, sizeof *b);
  *out = NULL;
  if (!b)
    return MRVI_ENOMEM;
  b->ns = st->ns;
  b->nf = st->nf;
  b->p = st->p;
  const size_t ns = (size_t)b->ns, nf = (size_t)b->nf, p = (size_t)b->p;
  const size_t nF = p * nf;
#define ALLOC(ptr, count, type)                                                \
  ptr = calloc((count) > 0 ? (count) : 1, sizeof(type))
  b->n_blk = ns * ns + 2 * ns * nF + 3 * p * nf * nf;
  ALLOC(b->blk, b->n_blk, double);
  ALLOC(b->piv, nF, int);
  ALLOC(b->z, nF, double);
  ALLOC(b->S, ns * ns, double);
  ALLOC(b->r, ns, double);
  ALLOC(b->spiv, ns, int);
  ALLOC(b->dinv, nF, double);
  ALLOC(b->sdinv, ns, double);
  const size_t nz = ns + nf;
  ALLOC(b->zp, nz, double);
  ALLOC(b->G, nz, double);
  ALLOC(b->H, nz * nz, double);
  ALLOC(b->ms, ns, double);
  ALLOC(b->mf, nf, double);
  ALLOC(b->vel, nF, double);
#undef ALLOC
  if (!b->blk || !b->piv || !b->z || !b->S || !b->r || !b->spiv || !b->dinv ||
      !b->sdinv || !b->zp || !b->G || !b->H || !b->ms || !b->mf || !b->vel) {
    mrvi_blocks_free(b);
    return MRVI_ENOMEM;
  }
  b->Ass = b->blk;
  b->Asf = b->Ass + ns * ns;
  b->Afs = b->Asf + ns * nF;
  b->D = b->Afs + nF * ns;
  b->L1 = b->D + p * nf * nf;
  b->L2 = b->L1 + p * nf * nf;
  b->Y = b->Afs; /* the sweep for Y runs in place */
  const mrvi_model *m = st->model;
  int *col = malloc((size_t)(m->n > 0 ? m->n : 1) * sizeof *col);
  if (!col) {
    mrvi_blocks_free(b);
    return MRVI_ENOMEM;
  }
  for (int c = 0; c < m->n; c++)
    col[c] = (m->rate[c] == MRVI_SLOW ? 0 : b->ns) + m->slot[c];
  for (int c = 0; c < 2; c++) {
    const int st_ok = mrvi_terms_create_range(
                          m, st->elem_of_class[c], st->elem_first[c],
                          st->n_elem_of_class[c], col, 0, &b->kc[c]) == MRVI_OK;
    for (int ie = 0; st_ok && ie < st->n_elem_of_class[c]; ie++) {
      const int r = mrvi_model_element_rates(m, MRVI_STEP_ELEM(st, c, ie));
      b->has_s[c] |= (r >> MRVI_SLOW) & 1;
      b->has_f[c] |= (r >> MRVI_FAST) & 1;
    }
    if (!st_ok) {
      free(col);
      mrvi_blocks_free(b);
      return MRVI_ENOMEM;
    }
  }
  free(col);
  for (int c = 0; c < 2; c++)
    b->quad[c] = mrvi_terms_quadratic(b->kc[c]);
  if (!(b->cblk = calloc(b->n_blk + 1, sizeof(double)))) {
    mrvi_blocks_free(b);
    return MRVI_ENOMEM;
  }
  const size_t nz0 = (size_t)b->ns + (size_t)b->nf;
  for (int c = 0; c < 2; c++) {
    if (!b->quad[c] || b->ns > 4 || b->nf > 4 || nz0 == 0)
      continue;
    if (mrvi_terms_affine(b->kc[c], (int)nz0, &b->g0[c], &b->Hq[c]) !=
        MRVI_OK) {
      mrvi_blocks_free(b);
      return MRVI_ENOMEM;
    }
  }
  b->same_pts = mrvi_step_same_points(st);
  for (int c = 0; c < 2; c++) {
    b->per_iv[c] = st->n_pts[c] == b->p && b->p >= 2 && nz0 > 0;
    for (int ip = 0; ip < st->n_pts[c]; ip++)
      if (st->pts[c][ip].m != ip)
        b->per_iv[c] = 0;
  }
  if ((b->per_iv[0] || b->per_iv[1]) &&
      !(b->Hp = calloc((size_t)b->p * nz0 * nz0, sizeof(double)))) {
    mrvi_blocks_free(b);
    return MRVI_ENOMEM;
  }
  for (int c = 0; c < 2; c++)
    if (b->per_iv[c] && !(b->rc[c] = row_coefs(st->pts[c], b->p))) {
      mrvi_blocks_free(b);
      return MRVI_ENOMEM;
    }
  /* Chord: every class whose Hessian is not constant has one point per
   * interval, and the points of intervals 1..p-1 the same weights (row
   * block m >= 2 takes points m - 1 and m). */
  b->chord_st = b->p >= 2 && nz0 > 0;
  for (int c = 0; c < 2; c++) {
    if (b->quad[c])
      continue;
    if (!b->per_iv[c])
      b->chord_st = 0;
    for (int ip = 2; b->chord_st && ip < st->n_pts[c]; ip++) {
      const mrvi_point *a = &st->pts[c][1], *q = &st->pts[c][ip];
      if (a->w != q->w || a->cA != q->cA || a->cB != q->cB)
        b->chord_st = 0;
    }
  }
  for (int c = 0; c < 2 && b->chord_st; c++) {
    if (b->quad[c])
      continue;
    const mrvi_point *pts = st->pts[c];
    const int p = b->p;
    double *fw = b->fw[c] = calloc(2 * (size_t)p + 1, sizeof(double));
    b->Hz[c] = calloc(nz0 * nz0, sizeof(double));
    if (!fw || !b->Hz[c]) {
      mrvi_blocks_free(b);
      return MRVI_ENOMEM;
    }
    for (int j = 0; j < p; j++) {
      const mrvi_point *P = &pts[j], *N = j + 1 < p ? &pts[j + 1] : NULL;
      const mrvi_point *Q = j >= 1 ? &pts[j - 1] : NULL;
      fw[0] -= P->w * P->a0 * P->a1;
      /* column block j: point j by cB, point j + 1 by cA; row block j:
       * point j by cA, point j - 1 by cB */
      fw[1 + 2 * j] = -P->w * P->a0 * P->cB - (N ? N->w * N->a0 * N->cA : 0.0);
      fw[2 + 2 * j] = -P->w * P->cA * P->a1 - (Q ? Q->w * Q->cB * Q->a1 : 0.0);
    }
  }
  for (int i = 0; i < b->ns; i++)
    b->ms[i] = MRVI_MASS(m, m->slow_index[i]);
  for (int i = 0; i < b->nf; i++)
    b->mf[i] = MRVI_MASS(m, m->fast_index[i]);
  b->m_min = INFINITY;
  for (int i = 0; i < b->ns; i++)
    b->m_min = fmin(b->m_min, b->ms[i]);
  for (int i = 0; i < b->nf; i++)
    b->m_min = fmin(b->m_min, b->mf[i]);
  *out = b;
  return MRVI_OK;
}

/* The block entry that CSC entry (i, j) adds to; NULL if it lies outside
 * the block structure (it cannot for an unconstrained step). */
static double *block_entry(mrvi_blocks *b, int i, int j) {
  const int ns = b->ns, nf = b->nf, nF = b->p * nf;
  if (i < ns && j < ns)
    return &b->Ass[i * ns + j];
  if (i < ns)
    return &b->Asf[(size_t)i * (size_t)nF + (size_t)(j - ns)];
  if (j < ns)
    return &b->Afs[(size_t)(i - ns) * (size_t)ns + (size_t)j];
  const int rb = (i - ns) / nf, rf = (i - ns) % nf;
  const int cb = (j - ns) / nf, cf = (j - ns) % nf;
  double *blk = rb == cb       ? b->D
                : rb == cb + 1 ? b->L1
                : rb == cb + 2 ? b->L2
                               : NULL;
  return blk ? &blk[((size_t)rb * (size_t)nf + (size_t)rf) * (size_t)nf +
                    (size_t)cf]
             : NULL;
}

/* Scatter the CSC values of st into the blocks through the entry map (built
 * on the first call); MRVI_EINVAL if an entry lies outside the block
 * structure, MRVI_ENOMEM.  The constraint rows of a constrained step
 * (bordered.c) go to a sink. */
static int scatter(mrvi_blocks *b, const mrvi_step *st) {
  const int ns = b->ns, nf = b->nf, p = b->p, nF = p * nf;
  const long nnz = st->Ap[ns + nF];
  if (!b->dst || b->n_dst != nnz) {
    free(b->dst);
    b->n_dst = 0;
    b->dst = malloc((size_t)(nnz > 0 ? nnz : 1) * sizeof *b->dst);
    if (!b->dst)
      return MRVI_ENOMEM;
    for (int j = 0; j < ns + nF; j++)
      for (int q = st->Ap[j]; q < st->Ap[j + 1]; q++)
        if (!(b->dst[q] = st->Ai[q] >= ns + nF
                              ? &b->sink
                              : block_entry(b, st->Ai[q], j))) {
          free(b->dst);
          b->dst = NULL;
          return MRVI_EINVAL;
        }
    b->n_dst = nnz;
  }
  memset(b->blk, 0, b->n_blk * sizeof(double));
  for (long q = 0; q < nnz; q++)
    *b->dst[q] += st->Ax[q];
  return MRVI_OK;
}

/* LU with partial pivoting in place, as mrvi_dense_lu_factor; -1 if
 * singular. */
ALWAYS_INLINE int lu_factor_k(const int n, double *restrict A,
                              int *restrict piv, double *restrict dinv) {
  UNROLL for (int k = 0; k < n; k++) {
    int r = k;
    UNROLL for (int i = k + 1; i < n;
                i++) if (fabs(A[i * n + k]) > fabs(A[r * n + k])) r = i;
    piv[k] = r;
    if (!(fabs(A[r * n + k]) > 0.0))
      return -1;
    if (r != k)
      UNROLL for (int j = 0; j < n; j++) {
        const double t = A[k * n + j];
        A[k * n + j] = A[r * n + j];
        A[r * n + j] = t;
      }
    const double d = dinv[k] = 1.0 / A[k * n + k];
    UNROLL for (int i = k + 1; i < n; i++) {
      const double f = (A[i * n + k] *= d);
      UNROLL for (int j = k + 1; j < n; j++) A[i * n + j] -= f * A[k * n + j];
    }
  }
  return 0;
}

/* B (n x nrhs) <- A^-1 B with lu_factor_k's factors (as
 * mrvi_dense_lu_solve, without its tests for zero factors). */
ALWAYS_INLINE void lu_solve_k(const int n, const double *restrict A,
                              const int *restrict piv,
                              const double *restrict dinv, double *restrict B,
                              const int nrhs) {
  /* The factorisation swaps whole rows (P A = L U, L in its final row
   * order): every swap applies to B before the forward substitution.
   * Small n: each swap row r tested by its constant index, so that a B
   * in locals stays in registers (a row picked by a run-time index makes
   * the compiler keep B in memory). */
  if (n <= 4) {
    UNROLL for (int k = 0; k + 1 < n; k++)
        UNROLL for (int r = k + 1; r < n; r++) {
      if (piv[k] == r) {
        UNROLL for (int c = 0; c < nrhs; c++) {
          const double t = B[r * nrhs + c];
          B[r * nrhs + c] = B[k * nrhs + c];
          B[k * nrhs + c] = t;
        }
      }
    }
  } else
    UNROLL for (int k = 0; k + 1 < n; k++) { /* piv[n - 1] = n - 1 */
      if (piv[k] != k) {
        double *bk = B + k * nrhs, *br = B + piv[k] * nrhs;
        UNROLL for (int c = 0; c < nrhs; c++) {
          const double t = br[c];
          br[c] = bk[c];
          bk[c] = t;
        }
      }
    }
  UNROLL for (int k = 0; k < n; k++) {
    const double *bk = B + k * nrhs;
    UNROLL for (int i = k + 1; i < n; i++) {
      const double f = A[i * n + k];
      UNROLL for (int c = 0; c < nrhs; c++) B[i * nrhs + c] -= f * bk[c];
    }
  }
  UNROLL for (int i = n - 1; i >= 0; i--) {
    double *bi = B + i * nrhs;
    UNROLL for (int j = i + 1; j < n; j++) {
      const double a = A[i * n + j];
      UNROLL for (int c = 0; c < nrhs; c++) bi[c] -= a * B[j * nrhs + c];
    }
    const double d = dinv[i]; /* multiplications: off the division
                                 latency in the sequential sweeps */
    UNROLL for (int c = 0; c < nrhs; c++) bi[c] *= d;
  }
}

/* x_m -= L1 x_{m-1} + L2 x_{m-2} (row block m >= 1; x_{m-2} unread at
 * m = 1): the products summed apart from x_m (the L2 part does not wait
 * for x_{m-1}). */
ALWAYS_INLINE void
couple_k(const int m, double *restrict xm, const double *restrict x1,
         const double *restrict x2, const double *restrict L1,
         const double *restrict L2, const int nf, const int nrhs) {
  UNROLL for (int i = 0; i < nf; i++) UNROLL for (int c = 0; c < nrhs; c++) {
    double s1 = 0.0, s2 = 0.0;
    UNROLL for (int k = 0; k < nf; k++) s1 += L1[i * nf + k] * x1[k * nrhs + c];
    if (m >= 2)
      UNROLL for (int k = 0; k < nf; k++) s2 +=
          L2[i * nf + k] * x2[k * nrhs + c];
    xm[i * nrhs + c] -= s1 + s2;
  }
}

/* Row block m of the block forward sweep (D factored, with its pivots and
 * reciprocal pivots): x_m <- D^-1 (x_m - L1 x_{m-1} - L2 x_{m-2}). */
ALWAYS_INLINE void
sweep_row_k(const int m, double *restrict X, const double *restrict L1,
            const double *restrict L2, const double *restrict D, const int *piv,
            const double *dinv, const int nf, const int nrhs) {
  const int row = nf * nrhs, dense = nf <= 4;
  double *restrict xm = X + (size_t)m * (size_t)row;
  const double *restrict x1 = xm - row, *restrict x2 = x1 - row;
  if (dense && m >= 1) {
    couple_k(m, xm, x1, x2, L1, L2, nf, nrhs);
  } else if (m >= 1) {
    UNROLL for (int d = 1; d <= 2 && d <= m; d++) {
      const double *restrict L = d == 1 ? L1 : L2;
      const double *restrict xc = xm - d * row;
      for (int i = 0; i < nf; i++)
        for (int k = 0; k < nf; k++) {
          const double l = L[i * nf + k];
          if (l != 0.0)
            for (int c = 0; c < nrhs; c++)
              xm[i * nrhs + c] -= l * xc[k * nrhs + c];
        }
    }
  }
  if (dense)
    lu_solve_k(nf, D, piv, dinv, xm, nrhs);
  else
    mrvi_dense_lu_solve(nf, D, piv, xm, nrhs);
}

/* X (p nf x nrhs) <- A_ff^-1 X by a block forward sweep (D factored):
 * X_m <- D_m^-1 (X_m - L1_m X_{m-1} - L2_m X_{m-2}).  Blocks beyond the
 * small sizes skip zero entries of L1, L2 (sparse couplings of networks).
 * Uniform blocks (chord matrix): the row blocks from 2 on use row block
 * 2's. */
ALWAYS_INLINE void sweep_k(const mrvi_blocks *b, double *restrict X,
                           const int nf, const int nrhs) {
  const size_t blk = (size_t)nf * (size_t)nf;
  const int p = b->p, last = b->uniform && p > 3 ? 3 : p;
  for (int m = 0; m < last; m++)
    sweep_row_k(m, X, b->L1 + m * blk, b->L2 + m * blk, b->D + m * blk,
                b->piv + (size_t)m * nf, b->dinv + (size_t)m * nf, nf, nrhs);
  if (last == p)
    return;
  const double *restrict L1 = b->L1 + 2 * blk, *restrict L2 = b->L2 + 2 * blk,
                         *restrict D = b->D + 2 * blk;
  const int *piv = b->piv + 2 * nf;
  const double *dinv = b->dinv + 2 * nf;
  for (int m = 3; m < p; m++)
    sweep_row_k(m, X, L1, L2, D, piv, dinv, nf, nrhs);
}

static void sweep_solve(const mrvi_blocks *b, double *X, int nrhs) {
  if (nrhs == 1) {
    SMALL(b->nf, NF, sweep_k(b, X, NF, 1));
  } else {
    SMALL2(nrhs, NR, b->nf, NF, sweep_k(b, X, NF, NR));
  }
}

/* Row block m of a dense sweep (sweep_row_k with nf <= 4) on locals: v
 * is read from src (x_m's right-hand side; src may be xm), x1 and x2 hold
 * the solved x_{m-1}, x_{m-2}; x_m is solved into v and stored to xm, and
 * x1, x2 move on.  Every value passes from row block to row block in
 * registers: loaded back from X, the vector loads of a row block spanned
 * two stores of the last one and missed the store-to-load forwarding. */
ALWAYS_INLINE void
row_regs_k(const int m, const double *src, double *xm, double *restrict x1,
           double *restrict x2, const double *restrict L1,
           const double *restrict L2, const double *restrict D, const int *piv,
           const double *dinv, const int nf, const int nrhs) {
  double v[16]; /* (nf, nrhs <= 4: constant indices once unrolled) */
  UNROLL for (int i = 0; i < nf; i++) UNROLL for (int c = 0; c < nrhs; c++)
      v[i * nrhs + c] = src[i * nrhs + c];
  if (m >= 1)
    couple_k(m, v, x1, x2, L1, L2, nf, nrhs);
  lu_solve_k(nf, D, piv, dinv, v, nrhs);
  UNROLL for (int i = 0; i < nf; i++) UNROLL for (int c = 0; c < nrhs; c++) {
    const int e = i * nrhs + c;
    xm[e] = v[e];
    x2[e] = x1[e];
    x1[e] = v[e];
  }
}

/* Row block m of Y (nf x ns, in place) and of z (from zs to zm) as the
 * columns of one nf x (ns + 1) block [Y_m | z_m], ns + 1 = 2 np, in np
 * vectors per row on locals (x1, x2: the last two row blocks): couple_k
 * and lu_solve_k (n <= 4) on pairs of columns, each lane's operations
 * those of row_regs_k on Y and on z alone in the same order (the same
 * results, bit for bit), half the arithmetic instructions (ns = 3: the
 * z column pairs with Y's third). */
ALWAYS_INLINE void row_yz_k(const int m, double *restrict ym,
                            const double *restrict zsm, double *restrict zm,
                            mrvi_v2 *restrict x1, mrvi_v2 *restrict x2,
                            const double *restrict L1,
                            const double *restrict L2, const double *restrict D,
                            const int *piv, const double *dinv, const int nf,
                            const int np) {
  const int ns = 2 * np - 1;
  mrvi_v2 v[8]; /* (nf <= 4, np <= 2) */
  UNROLL for (int i = 0; i < nf; i++) {
    UNROLL for (int c = 0; c + 1 < np; c++) v[i * np + c] =
        v2_load(ym + i * ns + 2 * c);
    v[i * np + np - 1] = v2_set(ym[i * ns + ns - 1], zsm[i]);
  }
  if (m >= 1) /* couple_k */
    UNROLL for (int i = 0; i < nf; i++) UNROLL for (int c = 0; c < np; c++) {
      mrvi_v2 s1 = v2_zero(), s2 = s1;
      UNROLL for (int k = 0; k < nf; k++) s1 =
          v2_add(s1, v2_scale(L1[i * nf + k], x1[k * np + c]));
      if (m >= 2)
        UNROLL for (int k = 0; k < nf; k++) s2 =
            v2_add(s2, v2_scale(L2[i * nf + k], x2[k * np + c]));
      v[i * np + c] = v2_sub(v[i * np + c], v2_add(s1, s2));
    }
  /* lu_solve_k: the swaps by constant row indices, the substitutions */
  UNROLL for (int k = 0; k + 1 < nf; k++)
      UNROLL for (int r = k + 1; r < nf; r++) {
    if (piv[k] == r)
      UNROLL for (int c = 0; c < np; c++) {
        const mrvi_v2 t = v[r * np + c];
        v[r * np + c] = v[k * np + c];
        v[k * np + c] = t;
      }
  }
  UNROLL for (int k = 0; k < nf; k++) UNROLL for (int i = k + 1; i < nf; i++) {
    const double f = D[i * nf + k];
    UNROLL for (int c = 0; c < np; c++) v[i * np + c] =
        v2_sub(v[i * np + c], v2_scale(f, v[k * np + c]));
  }
  UNROLL for (int i = nf - 1; i >= 0; i--) {
    UNROLL for (int j = i + 1; j < nf; j++) {
      const double a = D[i * nf + j];
      UNROLL for (int c = 0; c < np; c++) v[i * np + c] =
          v2_sub(v[i * np + c], v2_scale(a, v[j * np + c]));
    }
    const double d = dinv[i];
    UNROLL for (int c = 0; c < np; c++) v[i * np + c] =
        v2_scale(d, v[i * np + c]);
  }
  UNROLL for (int i = 0; i < nf; i++) {
    UNROLL for (int c = 0; c + 1 < np; c++)
        v2_store(ym + i * ns + 2 * c, v[i * np + c]);
    const mrvi_v2 t = v[i * np + np - 1];
    ym[i * ns + ns - 1] = v2_lo(t);
    zm[i] = v2_hi(t);
  }
  UNROLL for (int e = 0; e < nf * np; e++) {
    x2[e] = x1[e];
    x1[e] = v[e];
  }
}

/* With Y: Y (p nf x ns) <- A_ff^-1 Y and z (p nf) <- A_ff^-1 zs in one
 * sweep, row block m of Y, then of z (each as sweep_k alone: the same
 * operations); without, z alone.  Both chains run from row block to row
 * block, each waiting on its last row block: in one loop the z chain
 * overlaps the Y chains.  nf, ns as constants (SMALL2_ONLY, z alone SMALL4):
 * the row blocks in registers (row_regs_k), z's right-hand side read from zs (a
 * copy of p nf doubles first was a `rep movsb`). */
ALWAYS_INLINE void sweep2_k(const mrvi_blocks *b, double *restrict Y,
                            double *restrict z, const double *restrict zs,
                            const int nf, const int ns, const int regs) {
  const size_t blk = (size_t)nf * (size_t)nf;
  const int p = b->p, last = b->uniform && p > 3 ? 3 : p;
  double y1[16], y2[16], z1[4], z2[4]; /* (regs: the last two row blocks) */
  /* (regs, ns odd: Y and z as the column pairs of one block, row_yz_k) */
  const int yz = regs && Y && ns % 2 == 1 && ns <= 3;
  mrvi_v2 w1[8], w2[8];
  if (regs) {
    zero_k(y1, 16); /* (unread at m <= 1, but copied on) */
    zero_k(y2, 16);
    zero_k(z1, 4);
    zero_k(z2, 4);
    UNROLL_ALL for (int e = 0; e < 8; e++) w1[e] = w2[e] = v2_zero();
  } else {
    memcpy(z, zs, (size_t)p * (size_t)nf * sizeof(double));
  }
  for (int m = 0; m < p; m++) {
    const int r = m < last ? m : 2; /* (uniform: row block 2's from 2 on) */
    const double *L1 = b->L1 + r * blk, *L2 = b->L2 + r * blk,
                 *D = b->D + r * blk, *dinv = b->dinv + (size_t)r * nf;
    const int *piv = b->piv + (size_t)r * nf;
    if (yz) {
      row_yz_k(m, Y + (size_t)m * nf * ns, zs + (size_t)m * nf,
               z + (size_t)m * nf, w1, w2, L1, L2, D, piv, dinv, nf,
               (ns + 1) / 2);
    } else if (regs) {
      if (Y) {
        double *ym = Y + (size_t)m * nf * ns;
        row_regs_k(m, ym, ym, y1, y2, L1, L2, D, piv, dinv, nf, ns);
      }
      row_regs_k(m, zs + (size_t)m * nf, z + (size_t)m * nf, z1, z2, L1, L2, D,
                 piv, dinv, nf, 1);
    } else {
      if (Y)
        sweep_row_k(m, Y, L1, L2, D, piv, dinv, nf, ns);
      sweep_row_k(m, z, L1, L2, D, piv, dinv, nf, 1);
    }
  }
}

/* Zero the blocks (dir 0), save them to cblk (dir 1) or restore them from
 * cblk (dir 2). */
static void copy_blocks(mrvi_blocks *b, int dir) {
  const size_t len = b->n_blk * sizeof(double);
  if (dir == 0)
    memset(b->blk, 0, len);
  else if (dir == 1)
    memcpy(b->cblk, b->blk, len);
  else
    memcpy(b->blk, b->cblk, len);
}

/* The fast-fast block of row block rb and column block cb (rb - cb in
 * 0..2: D, L1, L2 of row block rb). */
static double *ff_block(mrvi_blocks *b, int rb, int cb) {
  double *base = rb == cb ? b->D : rb == cb + 1 ? b->L1 : b->L2;
  return base + (size_t)rb * (size_t)b->nf * (size_t)b->nf;
}

/* dst (rows x cols, leading dimension ldd) += f src (leading dimension
 * lds). */
ALWAYS_INLINE void add_scaled_k(double *restrict dst, int ldd,
                                const double *restrict src, int lds,
                                const int rows, const int cols, double f) {
  UNROLL for (int i = 0; i < rows; i++) UNROLL for (int j = 0; j < cols; j++)
      dst[i * ldd + j] += f * src[i * lds + j];
}

/* Hessian H of point pt (packed nz x nz) into the blocks: the entry of
 * input j in row (a0 | cA node m, cB node m + 1) and input l in column
 * (a1 | cA node m, cB node m + 1) gets -w c_row c_col H_jl, as the scatter
 * of step.c (mrvi_step_rows_of, mrvi_step_cols_of). */
ALWAYS_INLINE void point_hessian_k(mrvi_blocks *b, const mrvi_point *pt,
                                   int has_s, int has_f, const int ns,
                                   const int nf) {
  const int p = b->p, nz = ns + nf, nF = p * nf;
  const int mm = pt->m;
  const double *H = b->H;
  /* Fast rows: (coefficient, row block); fast columns: (coefficient,
   * column block = node - 1). */
  double rc[2], cc[2];
  int rb[2], cb[2], nr = 0, nc = 0;
  const double cA = pt->cA, cB = pt->cB;
  if (cA != 0.0) {
    rc[nr] = cA;
    rb[nr++] = mm;
    if (mm >= 1) {
      cc[nc] = cA;
      cb[nc++] = mm - 1;
    }
  }
  if (cB != 0.0) {
    if (mm + 1 <= p - 1) {
      rc[nr] = cB;
      rb[nr++] = mm + 1;
    }
    cc[nc] = cB;
    cb[nc++] = mm;
  }
  /* In locals: the stores into the blocks could alias pt. */
  const double w = pt->w, a0 = pt->a0, a1 = pt->a1;
  if (has_s) {
    if (a0 != 0.0 && a1 != 0.0)
      add_scaled_k(b->Ass, ns, H, nz, ns, ns, -w * a0 * a1);
    if (has_f) {
      for (int k = 0; a0 != 0.0 && k < nc; k++)
        add_scaled_k(b->Asf + (size_t)cb[k] * nf, nF, H + ns, nz, ns, nf,
                     -w * a0 * cc[k]);
      for (int k = 0; a1 != 0.0 && k < nr; k++)
        add_scaled_k(b->Afs + (size_t)rb[k] * nf * (size_t)ns, ns,
                     H + (size_t)ns * nz, nz, nf, ns, -w * rc[k] * a1);
    }
  }
  if (!has_f)
    return;
  const double *Hff = H + (size_t)ns * nz + ns;
  for (int r = 0; r < nr; r++)
    for (int c = 0; c < nc; c++)
      add_scaled_k(ff_block(b, rb[r], cb[c]), nf, Hff, nz, nf, nf,
                   -w * rc[r] * cc[c]);
}

/* dst (rows x cols, leading dimension ldd) += f1 s1 + f2 s2 (leading
 * dimension lds), s1 only if n1, s2 only if n2: add_scaled_k for s1 and
 * then for s2 in one pass (the same sums). */
ALWAYS_INLINE void add_scaled2_k(double *restrict dst, int ldd,
                                 const double *restrict s1, double f1, int n1,
                                 const double *restrict s2, double f2, int n2,
                                 int lds, const int rows, const int cols) {
  if (n1 && n2) {
    UNROLL for (int i = 0; i < rows; i++) UNROLL for (int j = 0; j < cols; j++)
        dst[i * ldd + j] =
            (dst[i * ldd + j] + f1 * s1[i * lds + j]) + f2 * s2[i * lds + j];
  } else if (n1) {
    add_scaled_k(dst, ldd, s1, lds, rows, cols, f1);
  } else if (n2) {
    add_scaled_k(dst, ldd, s2, lds, rows, cols, f2);
  }
}

/* add_scaled2_k on the block dst of the blocks (c NULL), or, restoring
 * the constant part in the same pass, dst = c + f1 s1 + f2 s2 from c, the
 * block's saved constant part (c: dst's place in cblk; the same sums as
 * the copy and then the adds; a plain copy if neither n1 nor n2). */
ALWAYS_INLINE void acc2_k(double *restrict dst, int ldd,
                          const double *restrict c, const double *restrict s1,
                          double f1, int n1, const double *restrict s2,
                          double f2, int n2, int lds, const int rows,
                          const int cols) {
  if (!c) {
    add_scaled2_k(dst, ldd, s1, f1, n1, s2, f2, n2, lds, rows, cols);
  } else if (n1 && n2) {
    UNROLL for (int i = 0; i < rows; i++) UNROLL for (int j = 0; j < cols; j++)
        dst[i * ldd + j] =
            (c[i * ldd + j] + f1 * s1[i * lds + j]) + f2 * s2[i * lds + j];
  } else if (n1 || n2) {
    const double *restrict sx = n1 ? s1 : s2;
    const double f = n1 ? f1 : f2;
    UNROLL for (int i = 0; i < rows; i++) UNROLL for (int j = 0; j < cols; j++)
        dst[i * ldd + j] = c[i * ldd + j] + f * sx[i * lds + j];
  } else {
    UNROLL for (int i = 0; i < rows; i++) UNROLL for (int j = 0; j < cols; j++)
        dst[i * ldd + j] = c[i * ldd + j];
  }
}

/* The place of block entry dst in the saved constant part if fresh, else
 * NULL (acc2_k). */
static inline const double *saved(const mrvi_blocks *b, const double *dst,
                                  int fresh) {
  return fresh ? b->cblk + (dst - b->blk) : NULL;
}

/* Row block m of the Hessians H of point m and HQ of point m - 1 (unread
 * at m = 0) of a class with one point per micro interval (point m in
 * interval m), with the factors r of row block m (row_coefs): row block m
 * (and slow column block m - 1, node m) takes what points m - 1 (Q) and
 * m (P) give it, in that order -- the entries and the order of
 * point_hessian_k point by point (the same sums), with each destination
 * read and written once. */
ALWAYS_INLINE void interval_row_k(mrvi_blocks *b, const row_coef *r,
                                  const int m, const double *H,
                                  const double *HQ, int has_s, int has_f,
                                  const int fresh, const int ns, const int nf) {
  const int nz = ns + nf, nF = b->p * nf;
  const size_t blk = (size_t)nf * (size_t)nf;
  const unsigned fl = r->fl;
  if (has_s) {
    if (fl & RC_SS)
      add_scaled_k(b->Ass, ns, H, nz, ns, ns, r->ss);
    if (has_f) {
      /* slow rows, column block m - 1: Q by cB, P by cA */
      if (m >= 1) {
        double *d = b->Asf + (size_t)(m - 1) * nf;
        acc2_k(d, nF, saved(b, d, fresh), HQ + ns, r->sfq, fl & RC_SFQ, H + ns,
               r->sfp, fl & RC_SFP, nz, ns, nf);
      }
      if (m == b->p - 1) { /* (RC_SFL only here) */
        double *d = b->Asf + (size_t)m * nf;
        acc2_k(d, nF, saved(b, d, fresh), H + ns, r->sfl, fl & RC_SFL, H, 0.0,
               0, nz, ns, nf);
      }
      /* row block m, slow columns: Q by cB, P by cA */
      double *d = b->Afs + (size_t)m * nf * (size_t)ns;
      acc2_k(d, ns, saved(b, d, fresh), HQ + (size_t)ns * nz, r->fsq,
             fl & RC_FSQ, H + (size_t)ns * nz, r->fsp, fl & RC_FSP, nz, nf, ns);
    }
  }
  if (has_f) {
    const double *Hff = H + (size_t)ns * nz + ns,
                 *HQff = HQ + (size_t)ns * nz + ns;
    /* D_m: P, row cA, column cB; L1_m: Q by cB cB, then P by cA cA;
     * L2_m: Q, row cB, column cA (flags only where m >= 1, 2) */
    double *D = b->D + (size_t)m * blk, *L1 = b->L1 + (size_t)m * blk,
           *L2 = b->L2 + (size_t)m * blk;
    acc2_k(D, nf, saved(b, D, fresh), Hff, r->d, fl & RC_D, Hff, 0.0, 0, nz, nf,
           nf);
    acc2_k(L1, nf, saved(b, L1, fresh), HQff, r->l1q, fl & RC_L1Q, Hff, r->l1p,
           fl & RC_L1P, nz, nf, nf);
    acc2_k(L2, nf, saved(b, L2, fresh), HQff, r->l2, fl & RC_L2, Hff, 0.0, 0,
           nz, nf, nf);
  }
}

/* The Hessians of a class with one point per interval into the blocks,
 * row block by row block (interval_row_k): point m's at H0 + m hstep
 * (the kept Hp, hstep one Hessian; or one Hessian for every point,
 * hstep 0).  fresh: the blocks' constant part is restored in the same pass
 * (each block read from cblk, the Hessians added, written once), as
 * copy_blocks(b, 2) and then the adds would (the same sums); the blocks
 * the rows do not reach (Ass, and the slow or fast blocks of a class
 * without slow or fast inputs) are copied. */
ALWAYS_INLINE void interval_hessians_k(mrvi_blocks *b, const row_coef *rc,
                                       const double *H0, size_t hstep,
                                       int has_s, int has_f, const int fresh,
                                       const int ns, const int nf) {
  if (fresh) {
    const size_t nF = (size_t)b->p * (size_t)nf;
    const double *c = b->cblk;
    memcpy(b->Ass, c, (size_t)ns * (size_t)ns * sizeof(double));
    if (!has_s || !has_f) /* A_sf, A_fs */
      memcpy(b->Asf, saved(b, b->Asf, 1), 2 * ns * nF * sizeof(double));
    if (!has_f) /* D, L1, L2 */
      memcpy(b->D, saved(b, b->D, 1), 3 * nF * (size_t)nf * sizeof(double));
  }
  for (int m = 0; m < b->p; m++)
    interval_row_k(b, rc + m, m, H0 + m * hstep,
                   H0 + (m >= 1 ? m - 1 : 0) * hstep, has_s, has_f, fresh, ns,
                   nf);
}

/* (a call: inlined, it crowded the registers of the assembly loop) */
static __attribute__((noinline)) void
interval_hessians(mrvi_blocks *b, int c, int has_s, int has_f, int fresh) {
  const row_coef *rc = b->rc[c];
  const double *H0 = b->Hp;
  if (fresh) {
    SMALL2(b->ns, NS, b->nf, NF,
           interval_hessians_k(b, rc, H0, (size_t)(NS + NF) * (NS + NF), has_s,
                               has_f, 1, NS, NF));
  } else {
    SMALL2(b->ns, NS, b->nf, NF,
           interval_hessians_k(b, rc, H0, (size_t)(NS + NF) * (NS + NF), has_s,
                               has_f, 0, NS, NF));
  }
}

/* The chord matrix of a class with one point per interval: its Hessian H,
 * frozen at one point of the step, for every point (the entries of
 * interval_hessians_k with H in place of each point's): the slow blocks
 * in full (their weights a0, a1 vary along the step), the fast blocks of
 * row blocks 0 .. min(p, 3) - 1 only (the rows from 2 on are equal). */
ALWAYS_INLINE void frozen_hessian_k(mrvi_blocks *b, const double *restrict H,
                                    const mrvi_point *pts,
                                    const double *restrict fw, int has_s,
                                    int has_f, const int ns, const int nf) {
  const int p = b->p, nz = ns + nf, nF = p * nf;
  const size_t blk = (size_t)nf * (size_t)nf;
  const double *Hff = H + (size_t)ns * nz + ns;
  if (has_s) {
    add_scaled_k(b->Ass, ns, H, nz, ns, ns, fw[0]);
    for (int j = 0; has_f && j < p; j++) {
      add_scaled_k(b->Asf + (size_t)j * nf, nF, H + ns, nz, ns, nf,
                   fw[1 + 2 * j]);
      add_scaled_k(b->Afs + (size_t)j * nf * (size_t)ns, ns,
                   H + (size_t)ns * nz, nz, nf, ns, fw[2 + 2 * j]);
    }
  }
  if (!has_f)
    return;
  for (int m = 0; m < p && m < 3; m++) {
    const mrvi_point *P = &pts[m], *Q = m >= 1 ? &pts[m - 1] : NULL;
    add_scaled_k(b->D + (size_t)m * blk, nf, Hff, nz, nf, nf,
                 -P->w * P->cA * P->cB);
    if (Q)
      add_scaled_k(b->L1 + (size_t)m * blk, nf, Hff, nz, nf, nf,
                   -Q->w * Q->cB * Q->cB - P->w * P->cA * P->cA);
    if (m >= 2)
      add_scaled_k(b->L2 + (size_t)m * blk, nf, Hff, nz, nf, nf,
                   -Q->w * Q->cB * Q->cA);
  }
}

static void frozen_hessian(mrvi_blocks *b, const double *H,
                           const mrvi_point *pts, const double *fw, int has_s,
                           int has_f) {
  SMALL2(b->ns, NS, b->nf, NF,
         frozen_hessian_k(b, H, pts, fw, has_s, has_f, NS, NF));
}

static void point_hessian(mrvi_blocks *b, const mrvi_point *pt, int cls) {
  SMALL2(b->ns, NS, b->nf, NF,
         point_hessian_k(b, pt, b->has_s[cls], b->has_f[cls], NS, NF));
}

/* Configuration zp of point pt at the displacements x (step.c, gather):
 * its slow part if slow, its fast part if fast (a class without inputs of
 * one rate leaves that part unread). */
ALWAYS_INLINE void point_config_k(mrvi_blocks *b, const mrvi_step *st,
                                  const double *x, const mrvi_point *pt,
                                  int slow, int fast, const int ns,
                                  const int nf) {
  const int mm = pt->m;
  const double a1 = pt->a1, cA = pt->cA, cB = pt->cB;
  const double *restrict dA = mm == 0 ? NULL : x + ns + (size_t)(mm - 1) * nf;
  const double *restrict dB = x + ns + (size_t)mm * nf;
  const double *restrict qs0 = st->qs0, *restrict qf0 = st->qf0;
  double *restrict zp = b->zp;
  if (slow)
    UNROLL for (int s = 0; s < ns; s++) zp[s] = qs0[s] + a1 * x[s];
  if (!fast)
    return;
  if (dA) {
    UNROLL for (int f = 0; f < nf; f++) zp[ns + f] =
        cA * (qf0[f] + dA[f]) + cB * (qf0[f] + dB[f]);
  } else {
    UNROLL for (int f = 0; f < nf; f++) zp[ns + f] =
        cA * qf0[f] + cB * (qf0[f] + dB[f]);
  }
}

static void point_config(mrvi_blocks *b, const mrvi_step *st, const double *x,
                         const mrvi_point *pt) {
  SMALL2(b->ns, NS, b->nf, NF, point_config_k(b, st, x, pt, 1, 1, NS, NF));
}

/* H (nz x nz) of class c at point pt's configuration (G is scratch
 * here). */
static void class_hessian(mrvi_blocks *b, int c, double *H) {
  const size_t nz = (size_t)(b->ns + b->nf);
  memset(b->G, 0, nz * sizeof(double));
  memset(H, 0, nz * nz * sizeof(double));
  mrvi_terms_eval(b->kc[c], b->zp, 1.0, b->G, H, (int)nz, 1.0);
}

/* The Hessian H of every point of a class with one point per interval
 * into the blocks (interval_row_k). */
static void const_rows(mrvi_blocks *b, int c, const double *H, int has_s,
                       int has_f) {
  SMALL2(b->ns, NS, b->nf, NF,
         interval_hessians_k(b, b->rc[c], H, 0, has_s, has_f, 0, NS, NF));
}

/* The constant part of the Newton matrix into the blocks: the kinetic rows
 * and the classes with a constant Hessian (quad), at any x. */
static void constant_part(mrvi_blocks *b, const mrvi_step *st,
                          const double *x) {
  const int ns = b->ns, nf = b->nf, p = b->p;
  copy_blocks(b, 0);
  for (int s = 0; s < ns; s++)
    b->Ass[s * ns + s] += -b->ms[s] / st->dT;
  for (int mm = 0; mm < p; mm++)
    for (int f = 0; f < nf; f++) {
      const double M = b->mf[f], dt = st->dt;
      if (mm >= 2)
        ff_block(b, mm, mm - 2)[f * nf + f] += -M / dt;
      if (mm >= 1)
        ff_block(b, mm, mm - 1)[f * nf + f] += 2.0 * M / dt;
      ff_block(b, mm, mm)[f * nf + f] += -M / dt;
    }
  /* A class whose terms are all quadratic has the same Hessian at every
   * configuration, bit for bit (its second derivatives do not depend on
   * s = a^T z - b): evaluated at its first point, then added for every
   * point, row block by row block for a class with one point per interval
   * (the same sums). */
  for (int c = 0; c < 2; c++) {
    if (!b->quad[c] || st->n_pts[c] == 0)
      continue;
    point_config(b, st, x, &st->pts[c][0]);
    class_hessian(b, c, b->H);
    if (b->per_iv[c])
      const_rows(b, c, b->H, b->has_s[c], b->has_f[c]);
    else
      for (int ip = 0; ip < st->n_pts[c]; ip++)
        point_hessian(b, &st->pts[c][ip], c);
  }
}

/* affine_grad_k with each G[i] read alone: G as the terms' kernel (a
 * call) stored it, one entry at a time; a vector load of two entries
 * would miss the store-to-load forwarding and wait for the stores. */
ALWAYS_INLINE void affine_add_k(const double *restrict g0,
                                const double *restrict Hq,
                                const double *restrict z, double *restrict G,
                                const int lo, const int nz) {
  const volatile double *Gv = G;
  UNROLL for (int i = lo; i < nz; i++) {
    double t = g0[i];
    UNROLL for (int j = lo; j < nz; j++) t += Hq[i * nz + j] * z[j];
    G[i] = Gv[i] + t;
  }
}

/* G += gradient of class c at zp: the terms, or g0 + Hq zp (from the
 * first fast column if the class has no slow inputs); H += its Hessian, or
 * with set H = its Hessian (mrvi_terms_eval_set: H need not be cleared). */
ALWAYS_INLINE void class_grad_k(mrvi_blocks *b, int c, double *restrict G,
                                double *H, int set, const int ns,
                                const int nf) {
  const double *restrict Hq = b->Hq[c], *restrict g0 = b->g0[c];
  if (H) {
    if (set)
      mrvi_terms_eval_set(b->kc[c], b->zp, G, H, ns + nf);
    else
      mrvi_terms_eval(b->kc[c], b->zp, 1.0, G, H, ns + nf, 1.0);
    return;
  }
  if (!Hq) { /* (the same gradient, by the kernels without a Hessian) */
    mrvi_terms_grad(b->kc[c], b->zp, G);
    return;
  }
  if (b->has_s[c]) /* (each with constant bounds) */
    affine_add_k(g0, Hq, b->zp, G, 0, ns + nf);
  else
    affine_add_k(g0, Hq, b->zp, G, ns, ns + nf);
}

/* The chord matrix's Hessian of loop class c (with W if the points are
 * the same: h0, h1 as in assemble_k), the one mrvi_blocks_chord_spread
 * kept, into the blocks (a call: inlined, it crowded the registers of the
 * assembly loop). */
static __attribute__((noinline)) void
frozen_point(mrvi_blocks *b, const mrvi_step *st, const double *x, int c,
             int h0, int h1, int Hs, int Hf) {
  const size_t n2 = (size_t)(b->ns + b->nf) * (size_t)(b->ns + b->nf);
  const double *H0 = h0 ? b->Hz[c] : NULL,
               *H1 = h1 && b->same_pts ? b->Hz[1] : NULL;
  const double *H = H0 ? H0 : H1; /* (one of them: read in place) */
  if (H0 && H1) {
    for (size_t i = 0; i < n2; i++)
      b->H[i] = H0[i] + H1[i];
    H = b->H;
  }
  (void)x;
  frozen_hessian(b, H, st->pts[c], b->fw[b->quad[c] ? 1 : c], Hs, Hf);
}

/* vel[i] = (d[i] - d[i - nf]) / dt for i < n (d[i - nf] = 0 for i < nf):
 * two at a time, which the compiler divides as a pair. */
ALWAYS_INLINE void velocities_k(const double *restrict d, double *restrict vel,
                                const int n, const int nf, const double dt) {
  UNROLL for (int f = 0; f < nf; f++) vel[f] = d[f] / dt; /* (d - 0) / dt */
  int i = nf;
  for (; i + 1 < n; i += 2) {
    vel[i] = (d[i] - d[i - nf]) / dt;
    vel[i + 1] = (d[i + 1] - d[i + 1 - nf]) / dt;
  }
  if (i < n)
    vel[i] = (d[i] - d[i - nf]) / dt;
}

/* The residual (with the momenta's potential parts) and, if jac, the
 * potential part of the Newton matrix (mrvi_blocks_assemble). */
ALWAYS_INLINE void assemble_k(mrvi_blocks *b, const mrvi_step *st,
                              const double *x, double *R, int jac, const int ns,
                              const int nf) {
  const int p = b->p, nz = ns + nf;
  double *mps = st->mom_ps, *mpf = st->mom_pf;
  if (mps) /* (mpf cleared with the kinetic rows below) */
    UNROLL for (int s = 0; s < ns; s++) mps[s] = 0.0;
  /* Kinetic rows (step.c, assemble_kinetic) on the displacements x. */
  const double dT = st->dT, dt = st->dt;
  UNROLL for (int s = 0; s < ns; s++) R[s] = st->ps0[s] - b->ms[s] * x[s] / dT;
  /* The velocities of the micro intervals first, in one pass over the
   * p nf entries (the divisions set the pace of these rows). */
  const double *restrict d0 = x + ns, *restrict mf = b->mf;
  double *restrict vel = b->vel;
  velocities_k(d0, vel, p * nf, nf, dt);
  UNROLL for (int f = 0; f < nf; f++) R[ns + f] = st->pf0[f] - mf[f] * vel[f];
  /* The momenta's potential parts cleared in the same loop, through a
   * volatile pointer: GCC turns a loop of zero stores into a memset, and
   * that of p nf doubles was a `rep stos` (p = 100: 2.4 kB, above the C
   * library's threshold), whose start-up costs more than the stores. */
  volatile double *mpv = mpf;
  if (mpf)
    UNROLL for (int f = 0; f < nf; f++) mpv[f] = 0.0;
  for (int mm = 1; mm < p; mm++) {
    const double *restrict vl = vel + (size_t)(mm - 1) * nf;
    double *restrict Rm = R + ns + (size_t)mm * nf;
    UNROLL for (int f = 0; f < nf; f++) Rm[f] = mf[f] * (vl[f] - vl[f + nf]);
    if (mpf)
      UNROLL for (int f = 0; f < nf; f++) mpv[(size_t)mm * nf + f] = 0.0;
  }
  /* Potential points: gradient (and, for a Hessian that is not constant,
   * the Hessian) of the class at the point's configuration, into the rows
   * and blocks of its nodes; with the same points for V and W, both
   * classes at once (c1 = 1). */
  const int same = b->same_pts;
  for (int c = 0; c < (same ? 1 : 2); c++) {
    /* What the points of class c (and W with them) need. */
    const int c1 = same ? 1 : c;
    const int h0 = jac && !b->quad[c], h1 = same && jac && !b->quad[1];
    const int hess = h0 || h1;
    /* chord: the Hessian at one point of the step, added after the
     * points; one point per interval: Hessians kept, added after them */
    const int frozen = hess && b->uniform;
    const int defer = hess && !frozen && b->per_iv[c];
    /* The rows of a rate the classes have no inputs of get no gradient. */
    const int hs = b->has_s[c] || b->has_s[c1],
              hf = b->has_f[c] || b->has_f[c1];
    const int Hs = (h0 && b->has_s[c]) || (h1 && b->has_s[1]),
              Hf = (h0 && b->has_f[c]) || (h1 && b->has_f[1]);
    /* Restored here unless in interval_hessians' pass. */
    const int fresh = hess && defer && b->restore;
    if (hess && !defer && b->restore) {
      copy_blocks(b, 2);
      b->restore = 0;
    }
    for (int ip = 0; ip < st->n_pts[c]; ip++) {
      const mrvi_point *pt = &st->pts[c][ip];
      const int mm = pt->m;
      point_config_k(b, st, x, pt, hs, hf, ns, nf);
      double *restrict G = b->G;
      UNROLL for (int i = 0; i < nz; i++) G[i] = 0.0;
      double *Ht = defer ? b->Hp + (size_t)ip * (size_t)nz * (size_t)nz : b->H;
      const int ph = hess && !frozen; /* this point's Hessian */
      /* (Ht written by the first class with a Hessian, added to by the
       * second: not cleared) */
      class_grad_k(b, c, G, ph && h0 ? Ht : NULL, 1, ns, nf);
      if (same)
        class_grad_k(b, 1, G, ph && h1 ? Ht : NULL, !h0, ns, nf);
      /* The point's factors in locals: R may alias nothing of pt, but the
       * compiler cannot know. */
      const double w = pt->w, a0 = pt->a0, a1 = pt->a1, cA = pt->cA,
                   cB = pt->cB;
      const double *restrict Gf = G + ns;
      if (hs && a0 != 0.0)
        UNROLL for (int s = 0; s < ns; s++) R[s] -= w * a0 * G[s];
      if (hf && cA != 0.0) {
        double *restrict Rm = R + ns + (size_t)mm * nf;
        UNROLL for (int f = 0; f < nf; f++) Rm[f] -= w * cA * Gf[f];
      }
      if (hf && cB != 0.0 && mm + 1 <= p - 1) {
        double *restrict Rm = R + ns + (size_t)(mm + 1) * nf;
        UNROLL for (int f = 0; f < nf; f++) Rm[f] -= w * cB * Gf[f];
      }
      if (mps) {
        if (hs)
          UNROLL for (int s = 0; s < ns; s++) mps[s] -= w * a1 * G[s];
        if (hf) {
          double *restrict pm = mpf + (size_t)mm * nf;
          UNROLL for (int f = 0; f < nf; f++) pm[f] -= w * cB * Gf[f];
        }
      }
      if (ph && !defer)
        point_hessian_k(b, pt, Hs, Hf, ns, nf);
    }
    if (defer) {
      interval_hessians(b, c, Hs, Hf, fresh);
      b->restore = 0;
    }
    if (frozen)
      frozen_point(b, st, x, c, h0, h1, Hs, Hf);
  }
  if (b->restore) { /* (no class adds Hessians) */
    copy_blocks(b, 2);
    b->restore = 0;
  }
}

/* 1 if the constant part's fast row blocks m >= 2 equal row block 2's. */
static int const_uniform(const mrvi_blocks *b) {
  const size_t blk = (size_t)b->nf * (size_t)b->nf;
  const double *D = b->cblk + (b->D - b->blk), *L1 = b->cblk + (b->L1 - b->blk),
               *L2 = b->cblk + (b->L2 - b->blk);
  for (int m = 3; m < b->p; m++)
    if (memcmp(D + m * blk, D + 2 * blk, blk * sizeof(double)) ||
        memcmp(L1 + m * blk, L1 + 2 * blk, blk * sizeof(double)) ||
        memcmp(L2 + m * blk, L2 + 2 * blk, blk * sizeof(double)))
      return 0;
  return 1;
}

/* The constant part of the Newton matrix into the blocks and saved to
 * cblk, once per run (the first assembly with jac, or the constant
 * chord's factorisation). */
static void make_constant(mrvi_blocks *b, const mrvi_step *st,
                          const double *x) {
  constant_part(b, st, x);
  copy_blocks(b, 1);
  b->const_ok = 1;
  b->const_uni = const_uniform(b);
}

int mrvi_blocks_assemble(mrvi_blocks *b, const mrvi_step *st, const double *x,
                         double *R, int jac) {
  const int ns = b->ns, nf = b->nf;
  if (!st->increments || st->n_lambda > 0 || st->extra)
    return MRVI_EINVAL;
  b->assembled = jac;
  /* The constant part: computed and saved once, then restored. */
  if (jac && !b->const_ok) {
    make_constant(b, st, x);
  } else if (jac) {
    b->restore = 1; /* (by assemble_k) */
  }
  if (jac)
    b->uniform = b->chord && b->chord_st && b->const_uni;
  SMALL2(ns, NS, nf, NF, assemble_k(b, st, x, R, jac, NS, NF));
  if (st->f_rows) /* control forces: constants of the step */
    for (int i = 0; i < st->n_unknowns; i++)
      R[i] += st->f_rows[i];
  return MRVI_OK;
}

int mrvi_blocks_chord_ok(const mrvi_blocks *b) {
  return b->chord_st && (!b->const_ok || b->const_uni);
}

void mrvi_blocks_chord(mrvi_blocks *b, int on) { b->chord = on; }

double mrvi_blocks_chord_spread(mrvi_blocks *b, const mrvi_step *st,
                                const double *x) {
  const size_t nz = (size_t)(b->ns + b->nf), n2 = nz * nz;
  double spread = 0.0;
  for (int c = 0; c < 2; c++) {
    if (b->quad[c] || st->n_pts[c] < 2)
      continue;
    /* H at the last point into Hz, then the first point's: their
     * difference, and their mean kept in Hz */
    double *Hz = b->Hz[c];
    if (!Hz)
      return INFINITY;
    point_config(b, st, x, &st->pts[c][st->n_pts[c] - 1]);
    class_hessian(b, c, Hz);
    point_config(b, st, x, &st->pts[c][0]);
    class_hessian(b, c, b->H);
    for (size_t i = 0; i < n2; i++) {
      const double d = fabs(b->H[i] - Hz[i]);
      spread = d > spread ? d : spread;
      Hz[i] = 0.5 * (Hz[i] + b->H[i]);
    }
  }
  return spread / b->m_min;
}

/* S = A_ss - A_sf Y. */
ALWAYS_INLINE void schur_k(mrvi_blocks *b, const int ns) {
  const int nF = b->p * b->nf;
  const double *restrict Y = b->Y;
  UNROLL for (int i = 0; i < ns; i++) {
    const double *restrict a = b->Asf + (size_t)i * (size_t)nF;
    double s[ns > 0 ? ns : 1];
    UNROLL for (int j = 0; j < ns; j++) s[j] = b->Ass[i * ns + j];
    UNROLL2 for (int k = 0; k < nF; k++) UNROLL for (int j = 0; j < ns; j++)
        s[j] -= a[k] * Y[(size_t)k * ns + j];
    UNROLL for (int j = 0; j < ns; j++) b->S[i * ns + j] = s[j];
  }
}

/* schur_k and, in the same pass, r = R_s - A_sf z (slow_solve_k's first
 * part, into b->r) for ns = 1 or 3: the columns of S and r as pairs of
 * lanes, [S_i0 S_i1 | S_i2 r_i] (ns = 3) or [S_00 r_0], each lane's sums
 * those of schur_k and slow_solve_k in the same order (the same results,
 * bit for bit), half the arithmetic instructions. */
ALWAYS_INLINE void schur_r_k(mrvi_blocks *b, const double *R, const int ns) {
  const int nF = b->p * b->nf, np = (ns + 1) / 2;
  const double *restrict Y = b->Y, *restrict z = b->z, *restrict Asf = b->Asf;
  mrvi_v2 acc[3 * 2]; /* (ns <= 3: np <= 2) */
  UNROLL for (int i = 0; i < ns; i++) {
    UNROLL for (int c = 0; c + 1 < np; c++) acc[i * np + c] =
        v2_load(b->Ass + i * ns + 2 * c);
    acc[i * np + np - 1] = v2_set(b->Ass[i * ns + ns - 1], R[i]);
  }
  UNROLL2 for (int k = 0; k < nF; k++) {
    mrvi_v2 y[2];
    UNROLL for (int c = 0; c + 1 < np; c++) y[c] =
        v2_load(Y + (size_t)k * ns + 2 * c);
    y[np - 1] = v2_set(Y[(size_t)k * ns + ns - 1], z[k]);
    UNROLL for (int i = 0; i < ns; i++) {
      const double a = Asf[(size_t)i * nF + k];
      UNROLL for (int c = 0; c < np; c++) acc[i * np + c] =
          v2_sub(acc[i * np + c], v2_scale(a, y[c]));
    }
  }
  UNROLL for (int i = 0; i < ns; i++) {
    UNROLL for (int c = 0; c + 1 < np; c++)
        v2_store(b->S + i * ns + 2 * c, acc[i * np + c]);
    const mrvi_v2 t = acc[i * np + np - 1];
    b->S[i * ns + ns - 1] = v2_lo(t);
    b->r[i] = v2_hi(t);
  }
}

/* Factorise the blocks as they are (scattered or assembled directly);
 * with R (n_unknowns), also z = A_ff^-1 R_f, in the sweep of Y. */
static int factor_blocks(mrvi_blocks *b, const double *R) {
  const int ns = b->ns, nf = b->nf, p = b->p;
  const size_t blk = (size_t)nf * (size_t)nf;
  int bad = 0;
  const int nfac = b->uniform && p > 3 ? 3 : p; /* (uniform: rows 0..2) */
  for (int m = 0; m < nfac && !bad; m++) {
    double *Dm = b->D + (size_t)m * blk;
    int *pm = b->piv + (size_t)m * (size_t)nf;
    SMALL(nf, NF, bad = lu_factor_k(NF, Dm, pm, b->dinv + (size_t)m * nf) < 0);
  }
  if (bad)
    return MRVI_ESINGULAR;
  /* Y = A_ff^-1 A_fs (in place of A_fs), S = A_ss - A_sf Y (factored) */
  if (R && MRVI_SMALL_KERNELS && SMALL2_SIZE(ns, nf)) {
    SMALL2_ONLY(ns, NS, nf, NF, sweep2_k(b, b->Y, b->z, R + ns, NF, NS, 1));
  } else if (R) {
    sweep2_k(b, ns > 0 ? b->Y : NULL, b->z, R + ns, nf, ns, 0);
  } else if (ns > 0) {
    sweep_solve(b, b->Y, ns);
  }
  /* (with R and ns = 1 or 3: r = R_s - A_sf z too, b->r_done) */
  b->r_done = R && MRVI_SMALL_KERNELS && (ns == 1 || ns == 3);
  if (b->r_done && ns == 3) {
    schur_r_k(b, R, 3);
  } else if (b->r_done) {
    schur_r_k(b, R, 1);
  } else {
    SMALL(ns, NS, schur_k(b, NS));
  }
  if (ns > 0) {
    SMALL(ns, NS, bad = lu_factor_k(NS, b->S, b->spiv, b->sdinv) < 0);
  }
  return bad ? MRVI_ESINGULAR : MRVI_OK;
}

/* mrvi_blocks_factor, with z = A_ff^-1 R_f if R. */
static int factor(mrvi_blocks *b, const mrvi_step *st, const double *R) {
  if (b->assembled) {
    b->assembled = 0;
    return factor_blocks(b, R);
  }
  b->uniform = 0;
  const int sc = scatter(b, st);
  return sc < 0 ? sc : factor_blocks(b, R);
}

int mrvi_blocks_factor(mrvi_blocks *b, const mrvi_step *st) {
  return factor(b, st, NULL);
}

/* ds = S^-1 (R_s - A_sf z), df = z - Y ds (after z = A_ff^-1 R_f). */
ALWAYS_INLINE void slow_solve_k(const mrvi_blocks *b, const double *R,
                                double *restrict dx, const int rdone,
                                const int ns) {
  const int nF = b->p * b->nf;
  const double *restrict z = b->z, *restrict Y = b->Y;
  double r[ns > 0 ? ns : 1];
  const double *restrict Asf = b->Asf;
  if (rdone) { /* (made with S: schur_r_k) */
    UNROLL for (int i = 0; i < ns; i++) r[i] = b->r[i];
  } else if (ns <= 4) { /* the rows' sums side by side, each in its order */
    UNROLL for (int i = 0; i < ns; i++) r[i] = R[i];
    UNROLL2 for (int k = 0; k < nF; k++) {
      const double zk = z[k];
      UNROLL for (int i = 0; i < ns; i++) r[i] -= Asf[(size_t)i * nF + k] * zk;
    }
  } else { /* (row by row: each row of A_sf read in order) */
    for (int i = 0; i < ns; i++) {
      const double *restrict a = Asf + (size_t)i * (size_t)nF;
      double s = R[i];
      UNROLL2 for (int k = 0; k < nF; k++) s -= a[k] * z[k];
      r[i] = s;
    }
  }
  if (ns > 0)
    lu_solve_k(ns, b->S, b->spiv, b->sdinv, r, 1);
  UNROLL for (int j = 0; j < ns; j++) dx[j] = r[j];
  UNROLL2 for (int k = 0; k < nF; k++) {
    double s = z[k];
    UNROLL for (int j = 0; j < ns; j++) s -= Y[(size_t)k * ns + j] * r[j];
    dx[ns + k] = s;
  }
}

void mrvi_blocks_solve(const mrvi_blocks *b, const double *R, double *dx) {
  const int ns = b->ns, nF = b->p * b->nf;
  /* z = A_ff^-1 R_f, r = R_s - A_sf z, ds = S^-1 r, df = z - Y ds; for
   * small fast blocks through the register sweep */
  if (MRVI_SMALL_KERNELS && b->nf >= 1 && b->nf <= 4) {
    SMALL4(b->nf, NF, sweep2_k(b, NULL, b->z, R + ns, NF, 1, 1));
  } else {
    memcpy(b->z, R + ns, (size_t)nF * sizeof(double));
    sweep_solve(b, b->z, 1);
  }
  SMALL(ns, NS, slow_solve_k(b, R, dx, 0, NS));
}

void mrvi_blocks_slow_solve(const mrvi_blocks *b, double *r, int nrhs) {
  if (b->ns > 0)
    lu_solve_k(b->ns, b->S, b->spiv, b->sdinv, r, nrhs);
}

void mrvi_blocks_solve_transpose(const mrvi_blocks *b, const double *R,
                                 double *dx) {
  const int ns = b->ns, nf = b->nf, p = b->p, nF = p * nf;
  const size_t blk = (size_t)nf * (size_t)nf;
  double *z = b->z, *r = b->r;
  /* J = [A_ss A_sf; A_fs A_ff] = [S A_sf; 0 A_ff] [I 0; Y I] (slow
   * first): J^T x = R by w_s = R_s - Y^T R_f, S^T x_s = w_s, then
   * A_ff^T x_f = R_f - A_sf^T x_s by a backward block sweep. */
  for (int j = 0; j < ns; j++)
    r[j] = R[j];
  for (int k = 0; k < nF; k++) {
    const double rk = R[ns + k];
    if (rk != 0.0)
      for (int j = 0; j < ns; j++)
        r[j] -= b->Y[(size_t)k * ns + j] * rk;
  }
  if (ns > 0)
    mrvi_dense_lu_solve_transpose(ns, b->S, b->spiv, r, 1);
  for (int k = 0; k < nF; k++)
    z[k] = R[ns + k];
  for (int i = 0; i < ns; i++)
    if (r[i] != 0.0)
      for (int k = 0; k < nF; k++)
        z[k] -= b->Asf[(size_t)i * nF + k] * r[i];
  /* Row block m of A_ff has D_m, L1_m, L2_m in column blocks m, m-1, m-2
   * (uniform: row blocks 3.. those of row block 2). */
  for (int m = p - 1; m >= 0; m--) {
    const size_t bm = b->uniform && m >= 3 ? 2 : (size_t)m;
    double *zm = z + (size_t)m * nf;
    mrvi_dense_lu_solve_transpose(nf, b->D + bm * blk, b->piv + bm * nf, zm, 1);
    for (int d = 1; d <= 2 && d <= m; d++) {
      const double *L = (d == 1 ? b->L1 : b->L2) + bm * blk;
      double *zc = zm - (size_t)d * nf;
      for (int i = 0; i < nf; i++)
        if (zm[i] != 0.0)
          for (int k = 0; k < nf; k++)
            zc[k] -= L[i * nf + k] * zm[i];
    }
  }
  memcpy(dx, r, (size_t)ns * sizeof *dx);
  memcpy(dx + ns, z, (size_t)nF * sizeof *dx);
}

int mrvi_blocks_factor_solve(mrvi_blocks *b, const mrvi_step *st,
                             const double *R, double *dx) {
  const int s = factor(b, st, R);
  if (s == MRVI_OK)
    SMALL(b->ns, NS, slow_solve_k(b, R, dx, b->r_done, NS));
  return s;
}

/* Constant chord (doc/solver.md, "Newton details"): the Newton matrix
 * without the Hessians of the classes whose Hessian is not constant --
 * the kinetic rows and the quadratic classes alone, a run constant --
 * factored once, into blocks of its own (b->cf, made on the first call:
 * the exact factorisations of the step keep b's).  The constant part is
 * made here if no assembly has made it yet (bitwise the same at every
 * x). */
int mrvi_blocks_const_factor(mrvi_blocks *b, const mrvi_step *st,
                             const double *x) {
  if (b->cf)
    return b->cf_status;
  if (!st->increments || st->n_lambda > 0 || st->extra)
    return MRVI_EINVAL;
  int s = mrvi_blocks_create(st, &b->cf);
  if (s < 0)
    return s;
  if (!b->const_ok) { /* (as mrvi_blocks_assemble's first) */
    make_constant(b, st, x);
    b->assembled = 0;
  }
  memcpy(b->cf->blk, b->cblk, b->n_blk * sizeof(double));
  b->cf->assembled = 1; /* (factored as they are) */
  if ((b->cf_status = mrvi_blocks_factor(b->cf, st)) < 0)
    return b->cf_status;
  /* Small steps: the inverse, column j the solve of the unit vector e_j. */
  const int n = b->ns + b->p * b->nf;
  if (n > st->tuning.const_chord_dense)
    return MRVI_OK;
  double *e = malloc(2 * (size_t)n * sizeof(double)), *col = e + n;
  if (!e || !(b->cinv = malloc((size_t)n * (size_t)n * sizeof(double)))) {
    free(e);
    return b->cf_status = MRVI_ENOMEM;
  }
  for (int j = 0; j < n; j++) {
    for (int i = 0; i < n; i++)
      e[i] = i == j;
    mrvi_blocks_solve(b->cf, e, col);
    for (int i = 0; i < n; i++)
      b->cinv[i * n + j] = col[i];
  }
  free(e);
  b->n_cinv = n;
  return MRVI_OK;
}

/* dx = J_const^-1 R with the constant chord's factors
 * (mrvi_blocks_const_factor), and x -= dx: by its inverse on small steps
 * (the same dx to round-off), each entry of x updated as its dx is formed
 * (a separate pass would load dx in pairs just stored one by one, which
 * misses the store-to-load forwarding). */
void mrvi_blocks_const_solve(const mrvi_blocks *b, const double *R, double *dx,
                             double *x) {
  const int n = b->n_cinv;
  if (!n) {
    mrvi_blocks_solve(b->cf, R, dx);
    for (int i = 0; i < b->ns + b->p * b->nf; i++)
      x[i] -= dx[i];
    return;
  }
  const double *restrict A = b->cinv;
  for (int i = 0; i < n; i++) {
    double s = 0.0;
    for (int j = 0; j < n; j++)
      s += A[i * n + j] * R[j];
    dx[i] = s;
    x[i] -= s;
  }
}

/* 1 if a point of class c puts its Hessian into the Newton matrix: a row
 * it feeds (slow by a0, fast node m by cA, node m + 1 <= p - 1 by cB) and
 * a column it depends on (q_{k+1}^s by a1, node m >= 1 by cA, node m + 1
 * by cB) both in the class's inputs.  Not at p = 1 on the trapezoidal
 * rule: the point at node k has a1 = cB = 0, the one at node k + 1
 * a0 = cA = 0 and no row m + 1. */
static int class_feeds(const mrvi_blocks *b, const mrvi_step *st, int c) {
  const int hs = b->has_s[c], hf = b->has_f[c];
  for (int ip = 0; ip < st->n_pts[c]; ip++) {
    const mrvi_point *pt = &st->pts[c][ip];
    const int row =
        (hs && pt->a0 != 0.0) ||
        (hf && (pt->cA != 0.0 || (pt->cB != 0.0 && pt->m + 1 <= b->p - 1)));
    const int col = (hs && pt->a1 != 0.0) ||
                    (hf && ((pt->cA != 0.0 && pt->m >= 1) || pt->cB != 0.0));
    if (row && col)
      return 1;
  }
  return 0;
}

/* The a-priori measure of the constant chord's error: the largest row sum
 * of |hess Z(q0)| over the classes whose Hessian is not constant and
 * enters the Newton matrix (class_feeds), at the model's initial
 * configuration q0 (a run constant), over the smallest mass; 0 where the
 * constant part is the whole Newton matrix. */
double mrvi_blocks_const_measure(mrvi_blocks *b, const mrvi_step *st) {
  const mrvi_model *m = st->model;
  const int nz = b->ns + b->nf;
  for (int c = 0; c < m->n; c++)
    b->zp[(m->rate[c] == MRVI_SLOW ? 0 : b->ns) + m->slot[c]] = m->q0[c];
  double e = 0.0;
  for (int c = 0; c < 2; c++) {
    if (b->quad[c] || !class_feeds(b, st, c))
      continue;
    class_hessian(b, c, b->H);
    for (int i = 0; i < nz; i++) {
      double r = 0.0;
      for (int j = 0; j < nz; j++)
        r += fabs(b->H[i * nz + j]);
      e = r > e ? r : e;
    }
  }
  return e / b->m_min;
}
