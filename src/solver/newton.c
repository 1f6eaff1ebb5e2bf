/* Linear solves of the Newton iteration.  Two backends behind one
 * interface, chosen by size at creation:
 *  - UMFPACK: the symbolic analysis is done once for the fixed pattern of a
 *    run, the numeric factorisation once per iteration (STYLE: symbolic
 *    once, numeric many);
 *  - for n <= MRVI_NEWTON_DENSE_MAX, a dense LU with partial pivoting
 *    (dense.c) of the matrix scattered from its CSC values: on the small
 *    step Jacobians (general path, optimal-control adjoint) UMFPACK's fixed
 *    cost per factorisation dominates (doc/performance.md, bench_ocp).
 * The factors are kept after a solve, so that the same matrix can be solved
 * again, transposed too (mrvi_linsolve_solve: adjoint solves). */
#include "internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/umfpack.h>

struct mrvi_newton {
  int n;
  const int *Ap, *Ai;
  void *symbolic, *numeric;
  double control[UMFPACK_CONTROL];
  double info[UMFPACK_INFO];
  /* Dense backend (lu != NULL): row-major factors, pivots, and whether
   * they hold a factorisation. */
  double *lu, *rs; /* rs: reciprocal row scales */
  int *piv;
  int factored;
};

mrvi_newton *mrvi_newton_create(int n, const int *Ap, const int *Ai,
                                const double *Ax, char *msg, size_t len) {
  mrvi_newton *nw = calloc(1, sizeof *nw);
  if (!nw) {
    mrvi_fmt(msg, len, "out of memory");
    return NULL;
  }
  nw->n = n;
  nw->Ap = Ap;
  nw->Ai = Ai;
  if (n <= MRVI_NEWTON_DENSE_MAX) {
    nw->lu = malloc(((size_t)n * (size_t)n + 1) * sizeof *nw->lu);
    nw->piv = malloc(((size_t)n + 1) * sizeof *nw->piv);
    nw->rs = malloc(((size_t)n + 1) * sizeof *nw->rs);
    if (!nw->lu || !nw->piv || !nw->rs) {
      mrvi_newton_free(nw);
      mrvi_fmt(msg, len, "out of memory");
      return NULL;
    }
    return nw;
  }
  umfpack_di_defaults(nw->control);
  nw->control[UMFPACK_PRL] = 0; /* the library never prints */
  int st = umfpack_di_symbolic(n, n, Ap, Ai, Ax, &nw->symbolic, nw->control,
                               nw->info);
  if (st != UMFPACK_OK) {
    mrvi_fmt(msg, len, "UMFPACK symbolic analysis failed (status %d)", st);
    free(nw);
    return NULL;
  }
  return nw;
}

void mrvi_newton_free(mrvi_newton *nw) {
  if (!nw)
    return;
  if (nw->numeric)
    umfpack_di_free_numeric(&nw->numeric);
  if (nw->symbolic)
    umfpack_di_free_symbolic(&nw->symbolic);
  free(nw->lu);
  free(nw->piv);
  free(nw->rs);
  free(nw);
}

/* Dense backend: scatter the CSC values, scale every row by the reciprocal
 * of its sum of magnitudes (as UMFPACK's default UMFPACK_SCALE_SUM: the
 * dynamic rows M/h and the constraint rows G of a saddle-point matrix differ
 * by orders of magnitude) and factorise in place. */
static int dense_factor(mrvi_newton *nw, const double *Ax, char *msg,
                        size_t len) {
  const int n = nw->n;
  double *A = nw->lu;
  memset(A, 0, (size_t)n * (size_t)n * sizeof *A);
  for (int i = 0; i < n; i++)
    nw->rs[i] = 0.0;
  for (int j = 0; j < n; j++)
    for (int e = nw->Ap[j]; e < nw->Ap[j + 1]; e++) {
      A[(size_t)nw->Ai[e] * (size_t)n + (size_t)j] += Ax[e];
      nw->rs[nw->Ai[e]] += fabs(Ax[e]);
    }
  nw->factored = 1;
  for (int i = 0; i < n && nw->factored; i++) {
    nw->factored = nw->rs[i] > 0.0 && isfinite(nw->rs[i]);
    const double r = nw->rs[i] = 1.0 / nw->rs[i];
    for (int j = 0; j < n; j++)
      A[(size_t)i * (size_t)n + (size_t)j] *= r;
  }
  nw->factored = nw->factored && mrvi_dense_lu_factor(n, A, nw->piv) == 0;
  if (nw->factored)
    return MRVI_OK;
  mrvi_fmt(msg, len, "singular Newton matrix");
  return MRVI_ESINGULAR;
}

int mrvi_newton_factor(mrvi_newton *nw, const double *Ax, char *msg,
                       size_t len) {
  if (nw->lu)
    return dense_factor(nw, Ax, msg, len);
  if (nw->numeric)
    umfpack_di_free_numeric(&nw->numeric);
  int st = umfpack_di_numeric(nw->Ap, nw->Ai, Ax, nw->symbolic, &nw->numeric,
                              nw->control, nw->info);
  if (st == UMFPACK_OK)
    return MRVI_OK;
  if (nw->numeric)
    umfpack_di_free_numeric(&nw->numeric);
  if (st == UMFPACK_WARNING_singular_matrix) {
    mrvi_fmt(msg, len, "singular Newton matrix");
    return MRVI_ESINGULAR;
  }
  mrvi_fmt(msg, len, "UMFPACK numeric factorisation failed (status %d)", st);
  return st == UMFPACK_ERROR_out_of_memory ? MRVI_ENOMEM : MRVI_ESINGULAR;
}

int mrvi_linsolve_solve(mrvi_newton *nw, const double *Ax, int transpose,
                        const double *b, double *x, char *msg, size_t len) {
  if (nw->lu && nw->factored) {
    /* R^-1 A x = R^-1 b; (R^-1 A)^T (R x) = b for the transpose. */
    const int n = nw->n;
    if (transpose) {
      if (x != b)
        memcpy(x, b, (size_t)n * sizeof *x);
      mrvi_dense_lu_solve_transpose(n, nw->lu, nw->piv, x, 1);
      for (int i = 0; i < n; i++)
        x[i] *= nw->rs[i];
    } else {
      for (int i = 0; i < n; i++)
        x[i] = nw->rs[i] * b[i];
      mrvi_dense_lu_solve(n, nw->lu, nw->piv, x, 1);
    }
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
