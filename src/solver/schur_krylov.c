/* Newton matrix of an unconstrained step with blocks beyond the dense limit
 * (doc/solver.md, "schur-krylov"): the block elimination of blocks.c with
 * iterative solves, working on the CSC Jacobian of step.c directly.
 *
 * Columns: q_{k+1}^s (ns), then the fast nodes 1..p (block c = node - 1).
 * Rows: the slow row (ns), then the fast row of node m = 0..p-1.  Fast
 * column block c has entries in the slow rows (A_sf), in row block c (the
 * diagonal block D_c = -(M^f/dt + sum_{points of interval c} w cA cB
 * hess_ff Z), symmetric) and in row blocks c+1, c+2 (the sub-diagonal
 * blocks of the block lower-triangular A_ff).  With
 *   S = A_ss - A_sf A_ff^-1 A_fs   (ns x ns, never formed)
 * a solve of J dx = R is
 *   z = A_ff^-1 R_f,  S ds = R_s - A_sf z  (GMRES),
 *   df = A_ff^-1 (R_f - A_fs ds),
 * where A_ff^-1 is a block forward sweep whose diagonal blocks are solved
 * by Jacobi-preconditioned CG on -D_c (solver/krylov.c), and S is applied
 * with one sweep per GMRES iteration.  S = -M^s/dT + O(dT K), so GMRES,
 * right-preconditioned by diag(A_ss), needs a few iterations.  Cost per
 * solve: (2 + GMRES iterations) sweeps of p CG solves, each a few sparse
 * products with D_c: O(p n) for a network.  A direction of non-positive
 * curvature in a block, or no convergence, falls back to a sparse LU of
 * the whole step (UMFPACK, symbolic analysis on the first fallback of the
 * run), kept for the further solves with the same Jacobian.
 *
 * The transposed solve J^T y = b (adjoints) runs the same elimination
 * backwards:
 *   z = A_ff^-T b_f,  S^T ys = b_s - A_fs^T z  (GMRES),
 *   yf = A_ff^-T (b_f - A_sf^T ys),
 *   S^T = A_ss^T - A_fs^T A_ff^-T A_sf^T,
 * where A_ff^T is block upper-triangular: a backward sweep c = p-1..0 whose
 * diagonal blocks D_c^T (= D_c) are solved by the same CG and whose
 * off-diagonal products are the columns of the sub-diagonal blocks, read
 * from the CSC Jacobian (columns are contiguous there); the preconditioners
 * are the same diagonals. */
#include "solver/solver.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The relative tolerances of the block CG solves and of GMRES (2-norm),
 * and GMRES's restart length and iteration cap, are the tuning constants
 * krylov_cg_rtol, krylov_gmres_rtol, krylov_restart and krylov_max_it
 * (mrvi.h, MRVI_TUNING_LIST); the tolerances can be set per object
 * (mrvi_skrylov_set_rtol). */
/* Sweeps of the S operator kept for the final one (T below). */
#define SK_KEEP 6

/* Entries of the step Jacobian gathered by rows or columns: pattern, the
 * Jacobian index of each entry (src, at creation only) and the values (a
 * slice of mrvi_skrylov.vals). */
typedef struct {
  int *ptr, *idx, *src;
  double *val;
} part;

static void part_free(part *P) {
  free(P->ptr);
  free(P->idx);
  free(P->src);
}

/* Allocate for `count` entries in `lines` rows or columns. */
static int part_alloc(part *P, size_t lines, size_t count) {
  P->ptr = calloc(lines + 1, sizeof *P->ptr);
  P->idx = malloc((count > 0 ? count : 1) * sizeof *P->idx);
  P->src = malloc((count > 0 ? count : 1) * sizeof *P->src);
  return P->ptr && P->idx && P->src ? 0 : -1;
}

/* The entries beg[j] .. end[j] - 1 of columns j = 0..ncol-1 (rows in the
 * fast block, Ai - ns, nF of them), by rows: row r holds (r, j) for j
 * ascending, with column index j % nf when `local`, else j. */
static int part_rows(part *P, size_t ncol, size_t nF, int nf, int ns,
                     const int *beg, const int *end, const int *Ai, int local) {
  size_t count = 0;
  for (size_t j = 0; j < ncol; j++)
    count += (size_t)(end[j] - beg[j]);
  if (part_alloc(P, nF, count) < 0)
    return -1;
  for (size_t j = 0; j < ncol; j++)
    for (int q = beg[j]; q < end[j]; q++)
      P->ptr[Ai[q] - ns + 1]++;
  for (size_t i = 0; i < nF; i++)
    P->ptr[i + 1] += P->ptr[i];
  /* ptr[i] is row i's next free slot while filling, shifted back after. */
  for (size_t j = 0; j < ncol; j++)
    for (int q = beg[j]; q < end[j]; q++) {
      const int at = P->ptr[Ai[q] - ns]++;
      P->idx[at] = local ? (int)(j % (size_t)nf) : (int)j;
      P->src[at] = q;
    }
  for (size_t i = nF; i > 0; i--)
    P->ptr[i] = P->ptr[i - 1];
  P->ptr[0] = 0;
  return 0;
}

/* The same entries by columns (row indices Ai). */
static int part_cols(part *P, size_t nF, const int *beg, const int *end,
                     const int *Ai) {
  size_t count = 0;
  for (size_t j = 0; j < nF; j++)
    count += (size_t)(end[j] - beg[j]);
  if (part_alloc(P, nF, count) < 0)
    return -1;
  int at = 0;
  for (size_t j = 0; j < nF; j++) {
    for (int q = beg[j]; q < end[j]; q++) {
      P->idx[at] = Ai[q];
      P->src[at++] = q;
    }
    P->ptr[j + 1] = at;
  }
  return 0;
}

struct mrvi_skrylov {
  const mrvi_step *st;
  const double *Ax; /* the Jacobian's values (st's pattern) taken at factor */
  int ns, nf, p;
  int transposed; /* the CG operator is -D_c^T (by D_c's columns) */
  double cg_rtol, gmres_rtol;
  /* Pattern: per fast column (p nf) the end of its slow rows (s1) and of
   * its own row block (s2), and its diagonal entry (dg); per slow column
   * the first entry in a fast row (sdiv). */
  int *s1, *s2, *dg, *sdiv;
  /* Compact copies of the parts a sweep reads, refreshed at each factor
   * in one pass over the Jacobian (vals[dst[q]] = Ax[q]; the entries of
   * A_ss go to a last, unused slot), so that the products stream only
   * their own entries instead of the whole columns of the step Jacobian:
   *   D  rows of D_c (row r = c nf + f; local columns, ascending),
   *   L  rows of the sub-diagonal blocks (global fast columns, ascending),
   *   sf columns of A_sf (per fast column, slow rows ascending),
   *   fs rows of A_fs (slow columns, ascending).
   * The row forms add the products in the column order of a scatter. */
  part D, L, sf, fs;
  double *vals;
  int *dst;       /* nnz of the step Jacobian */
  int *ddg;       /* p nf: index of D_c's diagonal entries in vals */
  double *dinv;   /* p nf: 1 / diag(-D_c) */
  double *dinv_s; /* ns: 1 / diag(A_ss) */
  double *t;      /* p nf: sweep vector of the S operator */
  /* The S operator's sweeps T_j = A_ff^-1 A_fs t_j of GMRES's first
   * SK_KEEP calls (p nf each), and GMRES's coefficients: when GMRES ends
   * in its first cycle, ds = sum y_j t_j, so A_ff^-1 A_fs ds = sum y_j T_j
   * and the final sweep is a combination of these. */
  double *T, *gy;
  int calls;
  double *rs, *ds;      /* ns */
  double *cgb, *cgwork; /* nf, 3 nf */
  double *gwork;        /* GMRES */
  int block;            /* diagonal block of the CG operator */
  /* The CG operator's rows on threads (nf of at least two chunks of
   * tuning.thread_chunk rows): its v^T y summed per chunk into vpart and
   * the chunks' sums added in order (for every thread count). */
  int threads, chunk, n_chunk;
  double *vpart;
  int failed;       /* MRVI_CG_* of the last failed solve */
  double curvature; /* of a non-positive direction */
  int fail_block, fail_iters;
  mrvi_newton *lu; /* whole-step fallback, on first use */
  int lu_active;   /* the current Jacobian is factored by LU */
  mrvi_krylov_stats stats;
};

void mrvi_skrylov_free(mrvi_skrylov *k) {
  if (!k)
    return;
  free(k->s1);
  free(k->s2);
  free(k->dg);
  free(k->sdiv);
  part_free(&k->D);
  part_free(&k->L);
  part_free(&k->sf);
  part_free(&k->fs);
  free(k->vals);
  free(k->dst);
  free(k->ddg);
  free(k->dinv);
  free(k->dinv_s);
  free(k->t);
  free(k->T);
  free(k->gy);
  free(k->rs);
  free(k->ds);
  free(k->cgb);
  free(k->cgwork);
  free(k->vpart);
  free(k->gwork);
  mrvi_newton_free(k->lu);
  free(k);
}

/* The values of the parts as slices of one array, and the destination of
 * every Jacobian entry in it (the src indices are then dropped). */
static int spread(mrvi_skrylov *k) {
  part *parts[4] = {&k->D, &k->L, &k->sf, &k->fs};
  const size_t nF = (size_t)k->p * (size_t)k->nf;
  const int nnz = k->st->Ap[k->ns + k->p * k->nf];
  size_t total = 0;
  for (int i = 0; i < 4; i++)
    total += (size_t)parts[i]->ptr[nF];
  k->vals = malloc((total + 1) * sizeof *k->vals);
  k->dst = malloc((size_t)(nnz > 0 ? nnz : 1) * sizeof *k->dst);
  k->ddg = malloc((nF > 0 ? nF : 1) * sizeof *k->ddg);
  if (!k->vals || !k->dst || !k->ddg)
    return -1;
  for (int q = 0; q < nnz; q++)
    k->dst[q] = (int)total;
  size_t off = 0;
  for (int i = 0; i < 4; i++) {
    part *P = parts[i];
    const int n = P->ptr[nF];
    P->val = k->vals + off;
    for (int e = 0; e < n; e++)
      k->dst[P->src[e]] = (int)off + e;
    off += (size_t)n;
    free(P->src);
    P->src = NULL;
  }
  for (size_t j = 0; j < nF; j++)
    k->ddg[j] = k->dst[k->dg[j]];
  return 0;
}

int mrvi_skrylov_create(const mrvi_step *st, mrvi_skrylov **out, char *msg,
                        size_t len) {
  *out = NULL;
  mrvi_skrylov *k = calloc(1, sizeof *k);
  if (!k)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  k->st = st;
  k->Ax = st->Ax;
  k->cg_rtol = st->tuning.krylov_cg_rtol;
  k->gmres_rtol = st->tuning.krylov_gmres_rtol;
  k->ns = st->ns;
  k->nf = st->nf;
  k->p = st->p;
  const size_t ns = (size_t)k->ns, nf = (size_t)k->nf, nF = nf * (size_t)k->p;
#define ALLOC(ptr, count)                                                      \
  ptr = malloc(((count) > 0 ? (count) : 1) * sizeof *ptr)
  ALLOC(k->s1, nF);
  ALLOC(k->s2, nF);
  ALLOC(k->dg, nF);
  ALLOC(k->sdiv, ns);
  ALLOC(k->dinv, nF);
  ALLOC(k->dinv_s, ns);
  ALLOC(k->t, nF);
  ALLOC(k->T, SK_KEEP * nF);
  ALLOC(k->gy, (size_t)st->tuning.krylov_restart);
  ALLOC(k->rs, ns);
  ALLOC(k->ds, ns);
  ALLOC(k->cgb, nf);
  ALLOC(k->cgwork, 3 * nf);
  k->chunk = st->tuning.thread_chunk;
  k->n_chunk =
      (int)nf >= 2 * k->chunk ? ((int)nf + k->chunk - 1) / k->chunk : 0;
  k->threads = k->n_chunk > 0 ? st->threads : 1;
  ALLOC(k->vpart, k->n_chunk > 0 ? k->n_chunk : 1);
  ALLOC(k->gwork, mrvi_gmres_work(k->ns, st->tuning.krylov_restart));
#undef ALLOC
  if (!k->s1 || !k->s2 || !k->dg || !k->sdiv || !k->dinv || !k->dinv_s ||
      !k->t || !k->T || !k->gy || !k->rs || !k->ds || !k->cgb || !k->cgwork ||
      !k->gwork || !k->vpart) {
    mrvi_skrylov_free(k);
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  }
  /* Split every column by row blocks (rows are sorted in each column). */
  const int *Ap = st->Ap, *Ai = st->Ai;
  const int n = k->ns + k->p * k->nf;
  for (int j = 0; j < n; j++) {
    const int c = j < k->ns ? -1 : (j - k->ns) / k->nf;
    const int lo = c < 0 ? 0 : k->ns + c * k->nf, hi = lo + k->nf;
    int q = Ap[j], ok = 1, diag = -1;
    for (int r = q + 1; r < Ap[j + 1]; r++)
      ok &= Ai[r] > Ai[r - 1];
    while (q < Ap[j + 1] && Ai[q] < k->ns)
      q++;
    if (c < 0) {
      k->sdiv[j] = q;
      continue;
    }
    const size_t jf = (size_t)(j - k->ns);
    k->s1[jf] = q;
    ok &= q == Ap[j + 1] || Ai[q] >= lo;
    while (q < Ap[j + 1] && Ai[q] < hi) {
      if (Ai[q] == j)
        diag = q;
      q++;
    }
    k->s2[jf] = q;
    k->dg[jf] = diag;
    if (!ok || diag < 0) {
      mrvi_skrylov_free(k);
      return mrvi_fail(msg, len, MRVI_EINVAL,
                       "step Jacobian column %d outside the block structure",
                       j);
    }
  }
  /* The column ends (for L) and starts (for sf) of the fast columns. */
  const int *fend = Ap + k->ns + 1, *fbeg = Ap + k->ns;
  const size_t nFc = (size_t)k->p * (size_t)k->nf;
  if (part_rows(&k->D, nFc, nFc, k->nf, k->ns, k->s1, k->s2, Ai, 1) < 0 ||
      part_rows(&k->L, nFc, nFc, k->nf, k->ns, k->s2, fend, Ai, 0) < 0 ||
      part_cols(&k->sf, nFc, fbeg, k->s1, Ai) < 0 ||
      part_rows(&k->fs, (size_t)k->ns, nFc, k->nf, k->ns, k->sdiv, Ap + 1, Ai,
                0) < 0) {
    mrvi_skrylov_free(k);
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  }
  if (spread(k) < 0) {
    mrvi_skrylov_free(k);
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  }
  *out = k;
  return MRVI_OK;
}

void mrvi_skrylov_set_rtol(mrvi_skrylov *k, double cg_rtol, double gmres_rtol) {
  k->cg_rtol = cg_rtol;
  k->gmres_rtol = gmres_rtol;
}

const mrvi_krylov_stats *mrvi_skrylov_stats(const mrvi_skrylov *k) {
  return &k->stats;
}

void mrvi_skrylov_factor(mrvi_skrylov *k) {
  mrvi_skrylov_factor_values(k, k->st->Ax);
}

void mrvi_skrylov_factor_values(mrvi_skrylov *k, const double *Ax) {
  k->Ax = Ax;
  const int nnz = k->st->Ap[k->ns + k->p * k->nf];
  for (int q = 0; q < nnz; q++)
    k->vals[k->dst[q]] = Ax[q];
  for (int j = 0; j < k->p * k->nf; j++) {
    const double d = -k->vals[k->ddg[j]];
    k->dinv[j] = d > 0.0 ? 1.0 / d : 1.0;
  }
  for (int j = 0; j < k->ns; j++) {
    double d = 0.0;
    for (int q = k->st->Ap[j]; q < k->sdiv[j]; q++)
      if (k->st->Ai[q] == j)
        d = Ax[q];
    k->dinv_s[j] = d != 0.0 ? 1.0 / d : 1.0;
  }
  k->lu_active = 0;
}

/* y = -D_c v (positive definite where CG applies), c = k->block, by the
 * compact rows of D_c (the same operations as adding the products of
 * -D_c); returns v^T y. */
static double neg_diag_rows(const mrvi_skrylov *k, const double *v, double *y,
                            int f0, int f1) {
  const int *ptr = k->D.ptr + (size_t)k->block * (size_t)k->nf;
  const int *col = k->D.idx;
  const double *val = k->D.val;
  double vy = 0.0;
  for (int f = f0; f < f1; f++) {
    double s = 0.0;
    for (int q = ptr[f]; q < ptr[f + 1]; q++)
      s -= val[q] * v[col[q]];
    y[f] = s;
    vy += v[f] * s;
  }
  return vy;
}

/* y = -D_c^T v by the columns of D_c in the CSC Jacobian (rows f0..f1-1
 * of D_c^T); returns v^T y. */
static double neg_diag_cols(const mrvi_skrylov *k, const double *v, double *y,
                            int f0, int f1) {
  const int j0 = k->ns + k->block * k->nf, r0 = j0;
  const int *Ai = k->st->Ai;
  const int *s1 = k->s1 + (size_t)k->block * (size_t)k->nf;
  const int *s2 = k->s2 + (size_t)k->block * (size_t)k->nf;
  const double *Ax = k->Ax;
  double vy = 0.0;
  for (int f = f0; f < f1; f++) {
    double s = 0.0;
    for (int q = s1[f]; q < s2[f]; q++)
      s -= Ax[q] * v[Ai[q] - r0];
    y[f] = s;
    vy += v[f] * s;
  }
  return vy;
}

static double neg_diag_range(const mrvi_skrylov *k, const double *v, double *y,
                             int f0, int f1) {
  return k->transposed ? neg_diag_cols(k, v, y, f0, f1)
                       : neg_diag_rows(k, v, y, f0, f1);
}

static double neg_diag_block(void *ctx, const double *v, double *y) {
  mrvi_skrylov *k = ctx;
  const int nf = k->nf, chunk = k->chunk, n_chunk = k->n_chunk;
  if (n_chunk == 0)
    return neg_diag_range(k, v, y, 0, nf);
  MRVI_PARALLEL_FOR(k->threads)
  for (int c = 0; c < n_chunk; c++)
    k->vpart[c] = neg_diag_range(k, v, y, c * chunk,
                                 nf - c * chunk < chunk ? nf : (c + 1) * chunk);
  double vy = 0.0;
  for (int c = 0; c < n_chunk; c++)
    vy += k->vpart[c];
  return vy;
}

/* Right-hand sides of forward_sweep from the slow unknowns vs: */
enum {
  FS_NONE,  /* X as given */
  FS_SET,   /* X = A_fs vs */
  FS_MINUS, /* X = X - A_fs vs */
};

/* x_c = (-D_c)^-1 k->cgb (or (-D_c^T)^-1 where k->transposed) by CG;
 * MRVI_CG_* on failure, recorded. */
static int block_cg(mrvi_skrylov *k, int c, double *xc) {
  const int nf = k->nf;
  k->block = c;
  int it = 0;
  const int s = mrvi_pcg(
      nf, neg_diag_block, k, k->dinv + (size_t)c * (size_t)nf, k->cgb, xc,
      k->cg_rtol, 0.0, MRVI_CG_MAX_IT, k->cgwork, &it, &k->curvature);
  k->stats.cg_solves++;
  k->stats.cg_iterations += it;
  if (it > k->stats.cg_max)
    k->stats.cg_max = it;
  if (s != MRVI_CG_OK) {
    k->failed = s;
    k->fail_block = c;
    k->fail_iters = it;
  }
  return s;
}

/* ysf -= M x_c for a block M (ns x nf) stored by its columns f: entries
 * val[q] in rows idx[q], q in ptr[f] .. ptr[f+1]-1 (A_sf's block c in the
 * forward sweep, A_fs's block c transposed in the backward sweep). */
static void sub_block_columns(int nf, const int *ptr, const int *idx,
                              const double *val, const double *xc,
                              double *ysf) {
  for (int f = 0; f < nf; f++) {
    const double v = xc[f];
    for (int q = ptr[f]; q < ptr[f + 1]; q++)
      ysf[idx[q]] -= val[q] * v;
  }
}

/* X (p nf) <- A_ff^-1 X by a block forward sweep (X first set from vs
 * by `fs`, block by block), and, if ysf is not NULL, ysf (ns) -= A_sf
 * (A_ff^-1 X) while each block is in cache; MRVI_CG_* on failure. */
static int forward_sweep(mrvi_skrylov *k, double *X, int fs, const double *vs,
                         double *ysf) {
  const int nf = k->nf;
  const int *lp = k->L.ptr, *lc = k->L.idx;
  const double *lv = k->L.val;
  const int *fc = k->fs.idx;
  const double *fv = k->fs.val;
  for (int c = 0; c < k->p; c++) {
    double *xc = X + (size_t)c * (size_t)nf;
    /* b_c = X_c - L_c X (earlier blocks);  D_c x = b  <=>  (-D_c) x = -b */
    const int *lpc = lp + (size_t)c * (size_t)nf;
    const int *fp = k->fs.ptr + (size_t)c * (size_t)nf;
    for (int f = 0; f < nf; f++) {
      double acc = xc[f];
      if (fs != FS_NONE) {
        double a = 0.0;
        for (int q = fp[f]; q < fp[f + 1]; q++)
          a += fv[q] * vs[fc[q]];
        acc = fs == FS_SET ? a : acc - a;
      }
      for (int q = lpc[f]; q < lpc[f + 1]; q++)
        acc -= lv[q] * X[lc[q]];
      k->cgb[f] = -acc;
    }
    /* X_c is read: the solution goes there */
    const int s = block_cg(k, c, xc);
    if (s != MRVI_CG_OK)
      return s;
    if (ysf)
      sub_block_columns(nf, k->sf.ptr + (size_t)c * (size_t)nf, k->sf.idx,
                        k->sf.val, xc, ysf);
  }
  return MRVI_CG_OK;
}

/* X (p nf) <- A_ff^-T X by a block backward sweep (X first set from vs by
 * `fs` with A_sf^T in place of A_fs), and, if ysf is not NULL, ysf (ns) -=
 * A_fs^T (A_ff^-T X) block by block; MRVI_CG_* on failure.  The products
 * with the sub-diagonal blocks' transposes are their columns in the CSC
 * Jacobian, rows of the later blocks (solved before). */
static int backward_sweep(mrvi_skrylov *k, double *X, int fs, const double *vs,
                          double *ysf) {
  const int nf = k->nf, ns = k->ns;
  const int *Ap = k->st->Ap + ns + 1, *Ai = k->st->Ai;
  const double *Ax = k->Ax;
  for (int c = k->p - 1; c >= 0; c--) {
    double *xc = X + (size_t)c * (size_t)nf;
    const size_t j0 = (size_t)c * (size_t)nf;
    /* b_c = X_c - sum_{r > c} A_ff[r][c]^T X_r;  (-D_c^T) x = -b */
    for (int f = 0; f < nf; f++) {
      const size_t j = j0 + (size_t)f;
      double acc = xc[f];
      if (fs != FS_NONE) {
        double a = 0.0;
        for (int q = k->sf.ptr[j]; q < k->sf.ptr[j + 1]; q++)
          a += k->sf.val[q] * vs[k->sf.idx[q]];
        acc = fs == FS_SET ? a : acc - a;
      }
      for (int q = k->s2[j]; q < Ap[j]; q++)
        acc -= Ax[q] * X[Ai[q] - ns];
      k->cgb[f] = -acc;
    }
    const int s = block_cg(k, c, xc);
    if (s != MRVI_CG_OK)
      return s;
    if (ysf)
      sub_block_columns(nf, k->fs.ptr + j0, k->fs.idx, k->fs.val, xc, ysf);
  }
  return MRVI_CG_OK;
}

/* The sweep of the solve under way: A_ff^-1 or, transposed, A_ff^-T. */
static int sweep(mrvi_skrylov *k, double *X, int fs, const double *vs,
                 double *ysf) {
  return k->transposed ? backward_sweep(k, X, fs, vs, ysf)
                       : forward_sweep(k, X, fs, vs, ysf);
}

/* y = S v = A_ss v - A_sf A_ff^-1 A_fs v (transposed: S^T v = A_ss^T v -
 * A_fs^T A_ff^-T A_sf^T v). */
static int schur_op(void *ctx, const double *v, double *y) {
  mrvi_skrylov *k = ctx;
  const mrvi_step *st = k->st;
  memset(y, 0, (size_t)k->ns * sizeof(double));
  if (k->transposed)
    for (int j = 0; j < k->ns; j++)
      for (int q = st->Ap[j]; q < k->sdiv[j]; q++)
        y[j] += k->Ax[q] * v[st->Ai[q]];
  else
    for (int j = 0; j < k->ns; j++)
      for (int q = st->Ap[j]; q < k->sdiv[j]; q++)
        y[st->Ai[q]] += k->Ax[q] * v[j];
  double *tv = k->calls < SK_KEEP
                   ? k->T + (size_t)k->calls * (size_t)k->p * (size_t)k->nf
                   : k->t;
  k->calls++;
  return sweep(k, tv, FS_SET, v, y) == MRVI_CG_OK ? 0 : -1;
}

/* The iterative solve (of J^T dx = R where k->transposed: every A below
 * transposed, the sweeps backward); MRVI_CG_* on failure. */
static int solve_krylov(mrvi_skrylov *k, const double *R, double *dx) {
  const int ns = k->ns;
  const size_t nF = (size_t)k->p * (size_t)k->nf;
  double *df = dx + ns;
  /* z = A_ff^-1 R_f (in df), rs = R_s - A_sf z */
  memcpy(df, R + ns, nF * sizeof(double));
  memcpy(k->rs, R, (size_t)ns * sizeof(double));
  int s = sweep(k, df, FS_NONE, NULL, k->rs);
  if (s != MRVI_CG_OK)
    return s;
  if (ns == 0)
    return MRVI_CG_OK;
  int it = 0, ny = -1;
  k->calls = 0;
  const mrvi_tuning *tn = &k->st->tuning;
  s = mrvi_gmres(ns, schur_op, k, k->dinv_s, k->rs, k->ds, k->gmres_rtol, 0.0,
                 tn->krylov_restart, tn->krylov_max_it, k->gwork, &it, k->gy,
                 &ny);
  k->stats.gmres_solves++;
  k->stats.gmres_iterations += it;
  if (it > k->stats.gmres_max)
    k->stats.gmres_max = it;
  if (s != MRVI_CG_OK) {
    if (s > 0) {
      k->failed = s;
      k->fail_block = -1;
      k->fail_iters = it;
    }
    return k->failed;
  }
  /* df = A_ff^-1 (R_f - A_fs ds) = z - sum y_j T_j, or by a sweep when
   * GMRES restarted or took more than SK_KEEP iterations */
  memcpy(dx, k->ds, (size_t)ns * sizeof(double));
  if (ny >= 0 && ny <= SK_KEEP) {
    for (int j = 0; j < ny; j++) {
      const double yj = k->gy[j], *Tj = k->T + (size_t)j * nF;
      for (size_t i = 0; i < nF; i++)
        df[i] -= yj * Tj[i];
    }
    return MRVI_CG_OK;
  }
  memcpy(df, R + ns, nF * sizeof(double));
  return sweep(k, df, FS_MINUS, k->ds, NULL);
}

int mrvi_skrylov_solve(mrvi_skrylov *k, int transpose, const double *R,
                       double *dx, char *msg, size_t len) {
  const mrvi_step *st = k->st;
  if (k->lu_active)
    return mrvi_linsolve_solve(k->lu, k->Ax, transpose, R, dx, msg, len);
  k->transposed = transpose;
  const int s = solve_krylov(k, R, dx);
  k->transposed = 0;
  if (s == MRVI_CG_OK)
    return MRVI_OK;
  /* Fallback: sparse LU of the whole step for this Jacobian. */
  mrvi_krylov_stats *ks = &k->stats;
  if (ks->fallbacks++ == 0) {
    if (s == MRVI_CG_CURVATURE)
      mrvi_fmt(ks->fallback_reason, sizeof ks->fallback_reason,
               "non-positive curvature p^T D p / p^T p = %.3e in diagonal "
               "block %d of the step Jacobian (-D = M/dt + w cA cB hess, "
               "where the potentials' negative curvature outweighs M/dt; a "
               "smaller micro step restores CG): sparse LU of the whole step",
               k->curvature, k->fail_block + 1);
    else
      mrvi_fmt(ks->fallback_reason, sizeof ks->fallback_reason,
               "%s did not converge in %d iterations: sparse LU of the whole "
               "step",
               k->fail_block < 0 ? "GMRES on the slow unknowns"
                                 : "CG on a diagonal block",
               k->fail_iters);
  }
  if (!k->lu &&
      !(k->lu = mrvi_newton_create(st->n_unknowns, st->Ap, st->Ai, k->Ax,
                                   st->tuning.newton_dense_max, msg, len)))
    return MRVI_ESINGULAR;
  int r = mrvi_newton_factor(k->lu, k->Ax, msg, len);
  if (r == MRVI_OK)
    r = mrvi_linsolve_solve(k->lu, k->Ax, transpose, R, dx, msg, len);
  k->lu_active = r == MRVI_OK;
  return r;
}
