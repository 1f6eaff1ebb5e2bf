/* Linear solves of the Newton iteration with UMFPACK: the symbolic analysis
 * is done once for the fixed pattern of a run, the numeric factorisation
 * once per iteration (STYLE: symbolic once, numeric many).  The numeric
 * factors are kept after a solve, so that the same matrix can be solved
 * again, transposed too (mrvi_linsolve_solve: adjoint solves). */
#include "internal.h"

#include <stdlib.h>
#include <suitesparse/umfpack.h>

struct mrvi_newton {
  int n;
  const int *Ap, *Ai;
  void *symbolic, *numeric;
  double control[UMFPACK_CONTROL];
  double info[UMFPACK_INFO];
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
  free(nw);
}

int mrvi_newton_factor(mrvi_newton *nw, const double *Ax, char *msg,
                       size_t len) {
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
