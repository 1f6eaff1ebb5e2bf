/* Linear solves of the Newton iteration.  Two backends behind one
 * interface, chosen at creation by size and, above MRVI_NEWTON_DENSE_SURE
 * rows, by the estimated flops of both (sparse_cheaper):
 *  - UMFPACK: the symbolic analysis is done once for the fixed pattern of a
 *    run, the numeric factorisation once per iteration (STYLE: symbolic
 *    once, numeric many);
 *  - for n <= dense_max (newton_dense_max, mrvi.h), an LU with partial
 *    pivoting in dense
 *    storage that skips zeros, of the row-scaled matrix renumbered for
 *    little fill: on the small step Jacobians (general path, optimal-control
 *    adjoint) UMFPACK's fixed cost per factorisation dominates
 *    (doc/performance/ocp.md, bench_ocp).
 * The factors are kept after a solve, so that the same matrix can be solved
 * again, transposed too (mrvi_linsolve_solve: adjoint solves). */
#include "solver/solver.h"
#include "util/simd.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/umfpack.h>

struct mrvi_newton {
  int n;
  const int *Ap, *Ai;
  void *symbolic, *numeric;
  int ordering; /* Info[UMFPACK_ORDERING_USED] of the kept analysis */
  double control[UMFPACK_CONTROL];
  double info[UMFPACK_INFO];
  /* Dense backend (lu != NULL), for B = P R^-1 A P^T: the rows scaled by
   * the reciprocals rs of their sums of magnitudes (as UMFPACK's default
   * UMFPACK_SCALE_SUM: the dynamic rows M/h and the constraint rows G of a
   * saddle-point matrix differ by orders of magnitude), rows and columns
   * renumbered by pos (original -> position) in the order of increasing
   * nonzero count of row plus column, so that the dense slow and constraint
   * couplings come last and the micro-node band first (little fill).
   * Factors S B = L U in lu (row-major, in place) with row swaps piv, and
   * their nonzeros by rows (CSR: L strictly lower, U with its diagonal) for
   * the solves. */
  double *lu, *rs, *val, *y;
  int *piv, *pos, *nzc, *ptr, *idx;
  int factored;
  /* refinement workspace (mrvi_newton_solve_transpose_kept: 4 L n
   * doubles for L interleaved right-hand sides) */
  double *ref;
  int ref_lanes;
  /* mrvi_newton_refactor_cost: the dense elimination's multiply-adds from
   * the pattern (dense_lu_flops; 0: not yet counted), UMFPACK's flops and
   * nonzeros of L and U at its last factorisation */
  double lu_ma, umf_flops, umf_lu;
  /* mrvi_newton_solve_transpose_kept by cost: the refinement's cost per
   * right-hand side in corrections (a solve and a residual), a running
   * mean over its calls (a call that gave up counted with the
   * factorisation after it); 0: none yet */
  double ref_units;
};

/* The dense backend's ordering pos (original -> position, n entries) of
 * the pattern (Ap, Ai): increasing nonzero count of row plus column (deg,
 * order: workspaces of n entries). */
static void dense_order(int n, const int *Ap, const int *Ai, int *deg,
                        int *order, int *pos) {
  for (int i = 0; i < n; i++)
    deg[i] = Ap[i + 1] - Ap[i];
  for (int e = 0; e < Ap[n]; e++)
    deg[Ai[e]]++;
  mrvi_degree_order(n, deg, order, pos);
}

/* Dense backend set-up: its workspaces (nw->pos made by choose_dense). */
static int dense_create(mrvi_newton *nw) {
  const size_t n = (size_t)nw->n, nn = n * n + 1;
  nw->lu = malloc(nn * sizeof *nw->lu);
  nw->val = malloc(nn * sizeof *nw->val);
  nw->idx = malloc(nn * sizeof *nw->idx);
  nw->rs = malloc((n + 1) * sizeof *nw->rs);
  nw->y = malloc((n + 1) * sizeof *nw->y);
  nw->piv = malloc((n + 1) * sizeof *nw->piv);
  nw->nzc = malloc((n + 1) * sizeof *nw->nzc);
  nw->ptr = malloc((2 * n + 2) * sizeof *nw->ptr);
  if (!nw->lu || !nw->val || !nw->idx || !nw->rs || !nw->y || !nw->piv ||
      !nw->nzc || !nw->ptr)
    return MRVI_ENOMEM;
  return MRVI_OK;
}

/* Frees the dense backend's storage (nw->lu NULL: UMFPACK's). */
static void dense_release(mrvi_newton *nw) {
  free(nw->lu);
  free(nw->rs);
  free(nw->val);
  free(nw->y);
  free(nw->piv);
  free(nw->pos);
  free(nw->nzc);
  free(nw->ptr);
  free(nw->idx);
  nw->lu = nw->rs = nw->val = nw->y = NULL;
  nw->piv = nw->pos = nw->nzc = nw->ptr = nw->idx = NULL;
}

/* Flops of the dense backend's elimination (a multiply-add per entry
 * updated) in its ordering pos, without pivoting, from the pattern:
 * rows as bit sets, row i joined by row k where L(i,k) != 0. */
static double dense_lu_flops(int n, const int *Ap, const int *Ai,
                             const int *pos) {
  const size_t w = ((size_t)n + 63) / 64;
  unsigned long long *R = calloc((size_t)n * w + 1, sizeof *R);
  if (!R)
    return HUGE_VAL;
  for (int j = 0; j < n; j++)
    for (int e = Ap[j]; e < Ap[j + 1]; e++) {
      const int r = pos[Ai[e]], c = pos[j];
      R[(size_t)r * w + (size_t)c / 64] |= 1ULL << (c % 64);
    }
  double flops = 0.0;
  for (int k = 0; k < n; k++) {
    const unsigned long long *rk = R + (size_t)k * w;
    /* entries of row k right of the pivot */
    double u = 0.0;
    for (size_t q = (size_t)k / 64; q < w; q++) {
      unsigned long long x = rk[q];
      if (q == (size_t)k / 64)
        x &= k % 64 == 63 ? 0ULL : ~0ULL << (k % 64 + 1);
      u += (double)__builtin_popcountll(x);
    }
    for (int i = k + 1; i < n; i++) {
      unsigned long long *ri = R + (size_t)i * w;
      if (!(ri[k / 64] >> (k % 64) & 1ULL))
        continue;
      flops += u;
      for (size_t q = (size_t)k / 64; q < w; q++)
        ri[q] |= rk[q];
    }
  }
  free(R);
  return flops;
}

/* Estimated nonzeros of L and U from a symbolic analysis's Info. */
static double factor_fill(const double *info) {
  return info[UMFPACK_LNZ_ESTIMATE] + info[UMFPACK_UNZ_ESTIMATE];
}

/* Analyse the pattern again ordered by METIS (nested dissection) and keep
 * that analysis where its factors are estimated to have fewer nonzeros
 * than with AMD's (the analysis in nw).  Neither ordering wins everywhere:
 * nested dissection gives less fill on 2-D lattices, AMD on chains and
 * trees, whose minimum-degree order is nearly fill-free (doc/solver.md,
 * "Orderings"; doc/performance/chains.md).  A failed METIS analysis keeps
 * AMD's. */
static void try_metis(mrvi_newton *nw, const double *Ax) {
  double control[UMFPACK_CONTROL], info[UMFPACK_INFO];
  memcpy(control, nw->control, sizeof control);
  control[UMFPACK_ORDERING] = UMFPACK_ORDERING_METIS;
  void *symbolic = NULL;
  if (umfpack_di_symbolic(nw->n, nw->n, nw->Ap, nw->Ai, Ax, &symbolic, control,
                          info) != UMFPACK_OK) {
    if (symbolic)
      umfpack_di_free_symbolic(&symbolic);
    return;
  }
  if (!(factor_fill(info) < factor_fill(nw->info))) {
    umfpack_di_free_symbolic(&symbolic);
    return;
  }
  umfpack_di_free_symbolic(&nw->symbolic);
  nw->symbolic = symbolic;
  memcpy(nw->control, control, sizeof control);
  nw->ordering = (int)info[UMFPACK_ORDERING_USED];
}

/* The dense backend's choice beyond MRVI_NEWTON_DENSE_SURE rows: UMFPACK
 * (its analysis kept in nw) where the dense LU's flops in its ordering
 * exceed MRVI_NEWTON_DENSE_RATIO times UMFPACK's estimate from its symbolic
 * analysis: on banded steps (rod chains) the degree ordering fills in, on
 * the body systems' it does not (doc/performance/kernels.md, "The dense/sparse
 * switch by flops"). */
static int sparse_cheaper(mrvi_newton *nw, const double *Ax) {
  if (umfpack_di_symbolic(nw->n, nw->n, nw->Ap, nw->Ai, Ax, &nw->symbolic,
                          nw->control, nw->info) != UMFPACK_OK) {
    if (nw->symbolic)
      umfpack_di_free_symbolic(&nw->symbolic);
    return 0;
  }
  const double fd = dense_lu_flops(nw->n, nw->Ap, nw->Ai, nw->pos);
  if (fd > MRVI_NEWTON_DENSE_RATIO * nw->info[UMFPACK_FLOPS_ESTIMATE]) {
    nw->ordering = (int)nw->info[UMFPACK_ORDERING_USED];
    return 1;
  }
  umfpack_di_free_symbolic(&nw->symbolic);
  return 0;
}

/* The backend of an nw of at most dense_max rows (n, Ap, Ai and control
 * set): the dense backend's ordering in nw->pos, then 1 for the dense LU,
 * 0 for UMFPACK (its analysis kept in nw: sparse_cheaper), < 0 out of
 * memory.  Decided before the dense LU's n^2 storage is made. */
static int choose_dense(mrvi_newton *nw, const double *Ax) {
  const size_t n = (size_t)nw->n;
  int *ws = malloc((2 * n + 1) * sizeof *ws);
  nw->pos = malloc((n + 1) * sizeof *nw->pos);
  if (!ws || !nw->pos) {
    free(ws);
    return MRVI_ENOMEM;
  }
  dense_order(nw->n, nw->Ap, nw->Ai, ws, ws + n, nw->pos);
  free(ws);
  return nw->n <= MRVI_NEWTON_DENSE_SURE || !sparse_cheaper(nw, Ax);
}

/* An nw with no backend yet. */
static void newton_init(mrvi_newton *nw, int n, const int *Ap, const int *Ai) {
  nw->n = n;
  nw->Ap = Ap;
  nw->Ai = Ai;
  umfpack_di_defaults(nw->control);
  nw->control[UMFPACK_PRL] = 0; /* the library never prints */
}

int mrvi_newton_dense_chosen(int n, const int *Ap, const int *Ai,
                             const double *Ax, int dense_max) {
  if (n > dense_max)
    return 0;
  mrvi_newton nw = {0};
  newton_init(&nw, n, Ap, Ai);
  const int dense = choose_dense(&nw, Ax);
  if (nw.symbolic)
    umfpack_di_free_symbolic(&nw.symbolic);
  free(nw.pos);
  return dense;
}

int mrvi_newton_ordering(const mrvi_newton *nw) {
  return nw->lu ? -1 : nw->ordering;
}

mrvi_newton *mrvi_newton_create(int n, const int *Ap, const int *Ai,
                                const double *Ax, int dense_max, char *msg,
                                size_t len) {
  mrvi_newton *nw = calloc(1, sizeof *nw);
  if (!nw) {
    mrvi_fmt(msg, len, "out of memory");
    return NULL;
  }
  newton_init(nw, n, Ap, Ai);
  if (n <= dense_max) {
    const int dense = choose_dense(nw, Ax);
    if (dense > 0 && dense_create(nw) == MRVI_OK)
      return nw;
    if (dense == 0) { /* UMFPACK with the analysis made */
      free(nw->pos);
      nw->pos = NULL;
      return nw;
    }
    mrvi_newton_free(nw);
    mrvi_fmt(msg, len, "out of memory");
    return NULL;
  }
  int st = umfpack_di_symbolic(n, n, Ap, Ai, Ax, &nw->symbolic, nw->control,
                               nw->info);
  if (st != UMFPACK_OK) {
    mrvi_fmt(msg, len, "UMFPACK symbolic analysis failed (status %d)", st);
    free(nw);
    return NULL;
  }
  nw->ordering = (int)nw->info[UMFPACK_ORDERING_USED];
  if (n >= MRVI_NEWTON_METIS_TRY)
    try_metis(nw, Ax);
  return nw;
}

void mrvi_newton_free(mrvi_newton *nw) {
  if (!nw)
    return;
  if (nw->numeric)
    umfpack_di_free_numeric(&nw->numeric);
  if (nw->symbolic)
    umfpack_di_free_symbolic(&nw->symbolic);
  dense_release(nw);
  free(nw->ref);
  free(nw);
}

/* Dense backend: scatter the scaled, renumbered CSC values into B, factorise
 * and list the factors' nonzeros by rows: L in ptr[0..n], U in
 * ptr[n+1..2n+1] (diagonal first). */
static int dense_factor(mrvi_newton *nw, const double *Ax, char *msg,
                        size_t len) {
  const int n = nw->n;
  double *B = nw->lu;
  memset(B, 0, (size_t)n * (size_t)n * sizeof *B);
  for (int i = 0; i < n; i++)
    nw->rs[i] = 0.0;
  for (int e = 0; e < nw->Ap[n]; e++)
    nw->rs[nw->Ai[e]] += fabs(Ax[e]);
  nw->factored = 1;
  for (int i = 0; i < n; i++) {
    nw->factored = nw->factored && nw->rs[i] > 0.0 && isfinite(nw->rs[i]);
    nw->rs[i] = 1.0 / nw->rs[i];
  }
  for (int j = 0; j < n && nw->factored; j++)
    for (int e = nw->Ap[j]; e < nw->Ap[j + 1]; e++)
      B[(size_t)nw->pos[nw->Ai[e]] * (size_t)n + (size_t)nw->pos[j]] +=
          nw->rs[nw->Ai[e]] * Ax[e];
  nw->factored =
      nw->factored && mrvi_dense_lu_factor_nz(n, B, nw->piv, nw->nzc) == 0;
  if (!nw->factored) {
    mrvi_fmt(msg, len, "singular Newton matrix");
    return MRVI_ESINGULAR;
  }
  int *lp = nw->ptr, *up = nw->ptr + n + 1, e = 0;
  for (int i = 0; i < n; i++) {
    lp[i] = e;
    for (int j = 0; j < i; j++)
      if (B[i * n + j] != 0.0) {
        nw->idx[e] = j;
        nw->val[e++] = B[i * n + j];
      }
  }
  lp[n] = e;
  for (int i = 0; i < n; i++) {
    up[i] = e;
    nw->idx[e] = i;
    nw->val[e++] = B[i * n + i];
    for (int j = i + 1; j < n; j++)
      if (B[i * n + j] != 0.0) {
        nw->idx[e] = j;
        nw->val[e++] = B[i * n + j];
      }
  }
  up[n] = e;
  return MRVI_OK;
}

/* Dense backend solves (A = R P^T S^T L U P):
 *   A x = b:   L U (P x) = S P R^-1 b;
 *   A^T x = b: U^T L^T S (P R x) = P b. */
static void dense_solve(const mrvi_newton *nw, int transpose, const double *b,
                        double *x) {
  const int n = nw->n, *lp = nw->ptr, *up = nw->ptr + n + 1, *ix = nw->idx;
  const double *v = nw->val;
  double *y = nw->y;
  if (!transpose) {
    for (int i = 0; i < n; i++)
      y[nw->pos[i]] = nw->rs[i] * b[i];
    for (int k = 0; k < n; k++)
      if (nw->piv[k] != k) {
        const double t = y[k];
        y[k] = y[nw->piv[k]];
        y[nw->piv[k]] = t;
      }
    for (int i = 0; i < n; i++) {
      double s = y[i];
      for (int e = lp[i]; e < lp[i + 1]; e++)
        s -= v[e] * y[ix[e]];
      y[i] = s;
    }
    for (int i = n - 1; i >= 0; i--) {
      double s = y[i];
      for (int e = up[i] + 1; e < up[i + 1]; e++)
        s -= v[e] * y[ix[e]];
      y[i] = s / v[up[i]];
    }
    for (int i = 0; i < n; i++)
      x[i] = y[nw->pos[i]];
    return;
  }
  for (int i = 0; i < n; i++)
    y[nw->pos[i]] = b[i];
  /* U^T w = y, L^T z = w by columns of the transposes (rows of L, U). */
  for (int i = 0; i < n; i++) {
    const double w = y[i] /= v[up[i]];
    for (int e = up[i] + 1; e < up[i + 1]; e++)
      y[ix[e]] -= v[e] * w;
  }
  for (int i = n - 1; i >= 0; i--)
    for (int e = lp[i]; e < lp[i + 1]; e++)
      y[ix[e]] -= v[e] * y[i];
  for (int k = n - 1; k >= 0; k--)
    if (nw->piv[k] != k) {
      const double t = y[k];
      y[k] = y[nw->piv[k]];
      y[nw->piv[k]] = t;
    }
  for (int i = 0; i < n; i++)
    x[i] = nw->rs[i] * y[nw->pos[i]];
}

int mrvi_newton_factor(mrvi_newton *nw, const double *Ax, char *msg,
                       size_t len) {
  if (nw->lu)
    return dense_factor(nw, Ax, msg, len);
  if (nw->numeric)
    umfpack_di_free_numeric(&nw->numeric);
  int st = umfpack_di_numeric(nw->Ap, nw->Ai, Ax, nw->symbolic, &nw->numeric,
                              nw->control, nw->info);
  if (st == UMFPACK_OK) {
    nw->umf_flops = nw->info[UMFPACK_FLOPS];
    nw->umf_lu = nw->info[UMFPACK_LNZ] + nw->info[UMFPACK_UNZ];
    return MRVI_OK;
  }
  if (nw->numeric)
    umfpack_di_free_numeric(&nw->numeric);
  if (st == UMFPACK_WARNING_singular_matrix) {
    mrvi_fmt(msg, len, "singular Newton matrix");
    return MRVI_ESINGULAR;
  }
  mrvi_fmt(msg, len, "UMFPACK numeric factorisation failed (status %d)", st);
  return st == UMFPACK_ERROR_out_of_memory ? MRVI_ENOMEM : MRVI_ESINGULAR;
}

void mrvi_newton_no_refine(mrvi_newton *nw) {
  nw->control[UMFPACK_IRSTEP] = 0.0;
}

int mrvi_linsolve_solve(mrvi_newton *nw, const double *Ax, int transpose,
                        const double *b, double *x, char *msg, size_t len) {
  if (nw->lu && nw->factored) {
    dense_solve(nw, transpose, b, x);
    return MRVI_OK;
  }
  if (!nw->numeric) {
    mrvi_fmt(msg, len, "no factorisation to solve with");
    return MRVI_EINVAL;
  }
  int st = umfpack_di_solve(transpose ? UMFPACK_At : UMFPACK_A, nw->Ap, nw->Ai,
                            Ax, x, b, nw->numeric, nw->control, nw->info);
  if (st != UMFPACK_OK) {
    mrvi_fmt(msg, len, "UMFPACK solve failed (status %d)", st);
    return MRVI_ESINGULAR;
  }
  return MRVI_OK;
}

int mrvi_newton_solve(mrvi_newton *nw, const double *Ax, const double *b,
                      double *dx, char *msg, size_t len) {
  const int st = mrvi_newton_factor(nw, Ax, msg, len);
  return st < 0 ? st : mrvi_linsolve_solve(nw, Ax, 0, b, dx, msg, len);
}

/* A Newton update: as mrvi_newton_solve without UMFPACK's iterative
 * refinement (Control[UMFPACK_IRSTEP] = 0 for this solve only).  The update
 * is only needed to the Newton tolerance, and the caller re-evaluates the
 * residual exactly at the updated point: that residual, not the accuracy
 * of the solve, decides convergence (doc/solver.md, "Newton details"). */
int mrvi_newton_update(mrvi_newton *nw, const double *Ax, const double *b,
                       double *dx, char *msg, size_t len) {
  const int st = mrvi_newton_factor(nw, Ax, msg, len);
  if (st < 0)
    return st;
  const double irstep = nw->control[UMFPACK_IRSTEP];
  nw->control[UMFPACK_IRSTEP] = 0.0;
  const int s = mrvi_linsolve_solve(nw, Ax, 0, b, dx, msg, len);
  nw->control[UMFPACK_IRSTEP] = irstep;
  return s;
}

/* Solve A^T x_i = b_i for nrhs right-hand sides (columns of length n),
 * through the same factorisation and solve as the Newton updates. */
int mrvi_newton_solve_transpose(mrvi_newton *nw, const double *Ax, int nrhs,
                                const double *b, double *x, char *msg,
                                size_t len) {
  int st = mrvi_newton_factor(nw, Ax, msg, len);
  const size_t n = (size_t)nw->n;
  for (int i = 0; i < nrhs && st == MRVI_OK; i++)
    st = mrvi_linsolve_solve(nw, Ax, 1, b + (size_t)i * n, x + (size_t)i * n,
                             msg, len);
  return st;
}

/* A factorisation's cost over a refinement correction's (a solve and a
 * residual), and in *solve_share the solve's part of a correction. */
static double refactor_units(mrvi_newton *nw, double *solve_share) {
  const double n = nw->n, nnz = nw->Ap[nw->n];
  *solve_share = 0.5;
  if (nw->lu) {
    if (!nw->factored)
      return 0.0;
    if (nw->lu_ma == 0.0)
      nw->lu_ma = dense_lu_flops(nw->n, nw->Ap, nw->Ai, nw->pos);
    /* (the factorisation also clears, fills and lists the n^2 entries;
     * a solve runs over the factors' nonzeros, permutes and scales) */
    const double solve = (double)nw->ptr[2 * nw->n + 1] + 2.0 * n;
    *solve_share = solve / (solve + 2.0 * nnz);
    return (nw->lu_ma + 3.0 * n * n) / (solve + 2.0 * nnz);
  }
  if (!nw->numeric)
    return 0.0;
  const double solve = nw->umf_lu + 2.0 * n;
  *solve_share = solve / (solve + 2.0 * nnz);
  return 0.5 * nw->umf_flops / (solve + 2.0 * nnz);
}

double mrvi_newton_refactor_cost(mrvi_newton *nw) {
  double share;
  return refactor_units(nw, &share);
}

/* Whether a refinement stops at step it (residual rmax, the step before's
 * rprev, target: its round-off): after max_refine steps, a step that
 * reduced the residual by less than 4, or (phi > 0) where the steps still
 * needed at this contraction are more than phi (a factorisation's cost in
 * refinement steps: factorising A is cheaper). */
static int refine_give_up(int it, int max_refine, double phi, double rmax,
                          double rprev, double target) {
  if (it == max_refine)
    return 1;
  if (it == 0)
    return 0;
  const double rate = rmax / rprev;
  if (!(rate <= 0.25))
    return 1;
  return phi > 0.0 && rate > 0.0 && ceil(log(target / rmax) / log(rate)) > phi;
}

/* Iterative refinement against A of a solution from kept factors of an
 * earlier matrix B of the same pattern: x <- x + B^-T (b - A^T x), which
 * converges while ||B^-T (A - B)^T|| < 1 (consecutive steps of a smooth
 * trajectory).  Each right-hand side stops at ||b - A^T x||_inf <= 64 eps
 * max_j (|A^T| |x| + |b|)_j, the size of the round-off of the residual
 * itself (its iterates those of its refinement alone), and the block
 * gives up where refine_give_up says so for one (the caller then
 * factorises A). */
int mrvi_refine_transpose(int n, const int *Ap, const int *Ai, const double *Ax,
                          int nrhs, const double *b, double *x, int max_refine,
                          double phi, double sigma, double *units, double *work,
                          mrvi_tsolve_fn solve, void *ctx, char *msg,
                          size_t len) {
  const size_t nn = (size_t)n;
  *units = 0.0;
  double *r = work, *d = work + MRVI_REFINE_BLOCK * nn;
  for (int c0 = 0; c0 < nrhs; c0 += MRVI_REFINE_BLOCK) {
    const int nb =
        nrhs - c0 < MRVI_REFINE_BLOCK ? nrhs - c0 : MRVI_REFINE_BLOCK;
    /* act[a]: the right-hand side c0 + act[a] of the na still refined */
    int act[MRVI_REFINE_BLOCK], na = nb;
    double rprev[MRVI_REFINE_BLOCK];
    for (int a = 0; a < nb; a++) {
      act[a] = a;
      rprev[a] = INFINITY;
    }
    int st = solve(ctx, nb, b + (size_t)c0 * nn, x + (size_t)c0 * nn, msg, len);
    *units += nb * sigma;
    for (int it = 0; st == MRVI_OK && na > 0; it++) {
      int kept = 0;
      *units += na * (1.0 - sigma);
      for (int a = 0; a < na; a++) {
        const int c = c0 + act[a];
        const double *bc = b + (size_t)c * nn, *xc = x + (size_t)c * nn;
        double *rc = r + (size_t)kept * nn;
        /* r = b - A^T x (column j of A dotted with x) and its scale. */
        double rmax = 0.0, scale = 0.0;
        for (int j = 0; j < n; j++) {
          double sum = bc[j], sc = fabs(bc[j]);
          for (int e = Ap[j]; e < Ap[j + 1]; e++) {
            const double t = Ax[e] * xc[Ai[e]];
            sum -= t;
            sc += fabs(t);
          }
          rc[j] = sum;
          rmax = fmax(rmax, fabs(sum));
          scale = fmax(scale, sc);
          if (!isfinite(sum))
            rmax = INFINITY;
        }
        if (rmax <= 64.0 * DBL_EPSILON * scale)
          continue;
        if (refine_give_up(it, max_refine, phi, rmax, rprev[act[a]],
                           64.0 * DBL_EPSILON * scale))
          return 0;
        rprev[act[a]] = rmax;
        act[kept++] = act[a];
      }
      na = kept;
      if (na == 0)
        break;
      *units += na * sigma;
      st = solve(ctx, na, r, d, msg, len);
      for (int a = 0; a < na && st == MRVI_OK; a++) {
        double *xc = x + (size_t)(c0 + act[a]) * nn;
        const double *dc = d + (size_t)a * nn;
        for (int j = 0; j < n; j++)
          xc[j] += dc[j];
      }
    }
    if (st != MRVI_OK)
      return st;
  }
  return 1;
}

/* mrvi_newton_solve_transpose_kept: the same refinement with nw's own kept
 * factors (UMFPACK's or the dense LU's), A factorised where it stalls.  The
 * right-hand sides go in blocks of L = 2, 4
 * or 8 (the fewest lanes that hold them, at most 8), whose residuals are
 * taken in one pass over A with x and b interleaved (xt[row L + i]; each
 * one's sums in the same order as alone: the same iterates). */
enum { REF_LANES = 8 };

/* r_i = b_i - A^T x_i for the L lanes (r: L rows of n), with
 * rmax_i = ||r_i||_inf (infinite where r_i is not finite) and
 * scale_i = max_j (|A^T| |x_i| + |b_i|)_j; a constant L in each call (the
 * lane loops unrolled and vectorised). */
static inline __attribute__((always_inline)) void
lanes_residual(const mrvi_newton *nw, int L, const double *Ax, const double *xt,
               const double *bt, double *r, double *rmax, double *scale) {
  const int n = nw->n;
  for (int i = 0; i < L; i++)
    rmax[i] = scale[i] = 0.0;
  for (int j = 0; j < n; j++) {
    /* lanes 2 h, 2 h + 1 in s_h, c_h (held in registers: L / 2 of them
     * used; lane by lane the scalar operations) */
    const double *bj = bt + (size_t)j * (size_t)L;
    mrvi_v2 s0 = v2_load(bj), s1 = v2_zero(), s2 = v2_zero(), s3 = v2_zero();
    mrvi_v2 c0 = v2_abs(s0), c1 = v2_zero(), c2 = v2_zero(), c3 = v2_zero();
    if (L > 2) {
      s1 = v2_load(bj + 2);
      c1 = v2_abs(s1);
    }
    if (L > 4) {
      s2 = v2_load(bj + 4);
      c2 = v2_abs(s2);
      s3 = v2_load(bj + 6);
      c3 = v2_abs(s3);
    }
    for (int e = nw->Ap[j]; e < nw->Ap[j + 1]; e++) {
      const mrvi_v2 a = v2_set(Ax[e], Ax[e]);
      const double *xr = xt + (size_t)nw->Ai[e] * (size_t)L;
      const mrvi_v2 t0 = v2_mul(a, v2_load(xr));
      s0 = v2_sub(s0, t0);
      c0 = v2_add(c0, v2_abs(t0));
      if (L > 2) {
        const mrvi_v2 t1 = v2_mul(a, v2_load(xr + 2));
        s1 = v2_sub(s1, t1);
        c1 = v2_add(c1, v2_abs(t1));
      }
      if (L > 4) {
        const mrvi_v2 t2 = v2_mul(a, v2_load(xr + 4));
        s2 = v2_sub(s2, t2);
        c2 = v2_add(c2, v2_abs(t2));
        const mrvi_v2 t3 = v2_mul(a, v2_load(xr + 6));
        s3 = v2_sub(s3, t3);
        c3 = v2_add(c3, v2_abs(t3));
      }
    }
    const mrvi_v2 sum[4] = {s0, s1, s2, s3}, sc[4] = {c0, c1, c2, c3};
    double s[REF_LANES], c[REF_LANES];
    for (int h = 0; h < L / 2; h++) {
      v2_store(s + 2 * h, sum[h]);
      v2_store(c + 2 * h, sc[h]);
    }
    for (int i = 0; i < L; i++) {
      r[(size_t)j * (size_t)L + (size_t)i] = s[i];
      const double as = fabs(s[i]);
      rmax[i] = as > rmax[i] ? as : rmax[i];
      scale[i] = c[i] > scale[i] ? c[i] : scale[i];
      if (!isfinite(s[i]))
        rmax[i] = INFINITY;
    }
  }
}

/* The dense factors' transposed solve (dense_solve) of the L lanes of bt
 * into xt (interleaved; yt: L n), lane by lane its scalar operations. */
static inline __attribute__((always_inline)) void
dense_solve_lanes(const mrvi_newton *nw, int L, const double *bt, double *xt,
                  double *yt) {
  const int n = nw->n, *lp = nw->ptr, *up = nw->ptr + n + 1, *ix = nw->idx;
  const double *v = nw->val;
  const size_t l = (size_t)L;
  for (int i = 0; i < n; i++)
    memcpy(yt + (size_t)nw->pos[i] * l, bt + (size_t)i * l, l * sizeof *yt);
  for (int i = 0; i < n; i++) {
    double *yi = yt + (size_t)i * l;
    const mrvi_v2 p = v2_set(v[up[i]], v[up[i]]);
    for (int h = 0; h < L; h += 2)
      v2_store(yi + h, v2_div(v2_load(yi + h), p));
    for (int e = up[i] + 1; e < up[i + 1]; e++) {
      double *ye = yt + (size_t)ix[e] * l;
      const mrvi_v2 c = v2_set(v[e], v[e]);
      for (int h = 0; h < L; h += 2)
        v2_store(ye + h, v2_sub(v2_load(ye + h), v2_mul(c, v2_load(yi + h))));
    }
  }
  for (int i = n - 1; i >= 0; i--) {
    const double *yi = yt + (size_t)i * l;
    for (int e = lp[i]; e < lp[i + 1]; e++) {
      double *ye = yt + (size_t)ix[e] * l;
      const mrvi_v2 c = v2_set(v[e], v[e]);
      for (int h = 0; h < L; h += 2)
        v2_store(ye + h, v2_sub(v2_load(ye + h), v2_mul(c, v2_load(yi + h))));
    }
  }
  for (int k = n - 1; k >= 0; k--)
    if (nw->piv[k] != k) {
      double *a = yt + (size_t)k * l, *c = yt + (size_t)nw->piv[k] * l;
      for (int h = 0; h < L; h += 2) {
        const mrvi_v2 t = v2_load(a + h);
        v2_store(a + h, v2_load(c + h));
        v2_store(c + h, t);
      }
    }
  for (int i = 0; i < n; i++) {
    const double *yp = yt + (size_t)nw->pos[i] * l;
    const mrvi_v2 rs = v2_set(nw->rs[i], nw->rs[i]);
    for (int h = 0; h < L; h += 2)
      v2_store(xt + (size_t)i * l + h, v2_mul(rs, v2_load(yp + h)));
  }
}

/* The kept factors' transposed solve of the lanes of bt into dt (both
 * interleaved, L lanes; lanes not active: dt anything) with workspace w
 * (L n): the dense ones all at once where more than half the lanes are
 * active (na of them), else (and UMFPACK's) lane by lane. */
static int solve_lanes(mrvi_newton *nw, const double *Ax, int L,
                       const int *active, int nb, int na, const double *bt,
                       double *dt, double *w, char *msg, size_t len) {
  const int n = nw->n;
  if (nw->lu && 2 * na > L) {
    if (L == 2)
      dense_solve_lanes(nw, 2, bt, dt, w);
    else if (L == 4)
      dense_solve_lanes(nw, 4, bt, dt, w);
    else
      dense_solve_lanes(nw, REF_LANES, bt, dt, w);
    return MRVI_OK;
  }
  for (int i = 0; i < nb; i++) {
    if (!active[i])
      continue;
    for (int j = 0; j < n; j++)
      w[j] = bt[(size_t)j * (size_t)L + (size_t)i];
    const int st = mrvi_linsolve_solve(nw, Ax, 1, w, w + n, msg, len);
    if (st != MRVI_OK)
      return st;
    for (int j = 0; j < n; j++)
      dt[(size_t)j * (size_t)L + (size_t)i] = w[n + j];
  }
  return MRVI_OK;
}

int mrvi_newton_solve_transpose_kept(mrvi_newton *nw, const double *Ax,
                                     int nrhs, const double *b, double *x,
                                     int max_refine, int by_cost,
                                     int *refactored, char *msg, size_t len) {
  const int n = nw->n;
  const int kept = nw->lu ? nw->factored : nw->numeric != NULL;
  *refactored = 1;
  if (!kept || max_refine <= 0)
    return mrvi_newton_solve_transpose(nw, Ax, nrhs, b, x, msg, len);
  double sigma = 0.5;
  const double phi = by_cost ? refactor_units(nw, &sigma) : 0.0;
  /* By cost, A is factorised at once where that and the nrhs solves cost
   * less than the refinement is expected to: its mean cost per right-hand
   * side so far, at least one correction's (the first solve and the
   * residual that accepts it).  On the smallest steps (the dense LU of a
   * few unknowns) a factorisation costs about one correction, and the
   * residual is the work saved. */
  const double expect = nw->ref_units > 1.0 ? nw->ref_units : 1.0;
  if (phi > 0.0 && phi + nrhs * sigma <= nrhs * expect)
    return mrvi_newton_solve_transpose(nw, Ax, nrhs, b, x, msg, len);
  double units = 0.0; /* this call's, in corrections */
  const int L = nrhs <= 2 ? 2 : nrhs <= 4 ? 4 : REF_LANES;
  const size_t ln = (size_t)L * (size_t)n, l = (size_t)L;
  if (nw->ref_lanes < L) {
    free(nw->ref);
    nw->ref_lanes = 0;
    if (!(nw->ref = malloc((5 * ln + 1) * sizeof *nw->ref))) {
      mrvi_fmt(msg, len, "out of memory");
      return MRVI_ENOMEM;
    }
    nw->ref_lanes = L;
  }
  /* Interleaved (unused lanes zero): residuals r, corrections d, x, b;
   * the lanes' solve's workspace y. */
  double *r = nw->ref, *d = r + ln, *xt = d + ln, *bt = xt + ln, *yt = bt + ln;
  /* UMFPACK's own refinement steps are this loop's: off meanwhile. */
  const double irstep = nw->control[UMFPACK_IRSTEP];
  nw->control[UMFPACK_IRSTEP] = 0.0;
  int ok = 1;
  for (int i0 = 0; i0 < nrhs && ok; i0 += L) {
    const int nb = nrhs - i0 < L ? nrhs - i0 : L;
    const double *bi = b + (size_t)i0 * (size_t)n;
    double *xi = x + (size_t)i0 * (size_t)n;
    /* active[i]: right-hand side i0 + i still refined */
    int active[REF_LANES], na = nb;
    double rprev[REF_LANES], rmax[REF_LANES], scale[REF_LANES];
    memset(bt, 0, ln * sizeof *bt);
    memset(xt, 0, ln * sizeof *xt);
    for (int i = 0; i < nb; i++) {
      active[i] = 1;
      rprev[i] = INFINITY;
      for (int j = 0; j < n; j++)
        bt[(size_t)j * l + (size_t)i] = bi[(size_t)i * (size_t)n + (size_t)j];
    }
    ok =
        solve_lanes(nw, Ax, L, active, nb, na, bt, xt, yt, msg, len) == MRVI_OK;
    units += nb * sigma;
    for (int it = 0; na > 0 && ok; it++) {
      units += na * (1.0 - sigma);
      if (L == 2)
        lanes_residual(nw, 2, Ax, xt, bt, r, rmax, scale);
      else if (L == 4)
        lanes_residual(nw, 4, Ax, xt, bt, r, rmax, scale);
      else
        lanes_residual(nw, REF_LANES, Ax, xt, bt, r, rmax, scale);
      /* Converged ones leave the block; where one gives up
       * (refine_give_up), factorising is cheaper. */
      for (int i = 0; i < nb && ok; i++) {
        if (!active[i])
          continue;
        if (rmax[i] <= 64.0 * DBL_EPSILON * scale[i]) {
          active[i] = 0;
          na--;
          continue;
        }
        if (refine_give_up(it, max_refine, phi, rmax[i], rprev[i],
                           64.0 * DBL_EPSILON * scale[i]))
          ok = 0;
        rprev[i] = rmax[i];
      }
      if (!ok || na == 0)
        break;
      units += na * sigma;
      ok =
          solve_lanes(nw, Ax, L, active, nb, na, r, d, yt, msg, len) == MRVI_OK;
      for (int j = 0; j < n && ok; j++)
        for (int i = 0; i < nb; i++)
          if (active[i])
            xt[(size_t)j * l + (size_t)i] += d[(size_t)j * l + (size_t)i];
    }
    for (int i = 0; i < nb && ok; i++)
      for (int j = 0; j < n; j++)
        xi[(size_t)i * (size_t)n + (size_t)j] = xt[(size_t)j * l + (size_t)i];
  }
  nw->control[UMFPACK_IRSTEP] = irstep;
  if (phi > 0.0) {
    units = (units + (ok ? 0.0 : phi + nrhs * sigma)) / nrhs;
    nw->ref_units =
        nw->ref_units > 0.0 ? 0.875 * nw->ref_units + 0.125 * units : units;
  }
  /* Stalled (or the kept factors failed): factorise A. */
  if (!ok)
    return mrvi_newton_solve_transpose(nw, Ax, nrhs, b, x, msg, len);
  *refactored = 0;
  return MRVI_OK;
}
