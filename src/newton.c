/* Linear solves of the Newton iteration with UMFPACK: the symbolic analysis
 * is done once for the fixed pattern of a run, the numeric factorisation
 * once per iteration (STYLE: symbolic once, numeric many). */
#include "internal.h"

#include <stdlib.h>
#include <suitesparse/umfpack.h>

struct mrvi_newton {
  int n;
  const int *Ap, *Ai;
  void *symbolic;
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
  if (nw->symbolic)
    umfpack_di_free_symbolic(&nw->symbolic);
  free(nw);
}

int mrvi_newton_solve(mrvi_newton *nw, const double *Ax, const double *b,
                      double *dx, char *msg, size_t len) {
  void *numeric = NULL;
  int st = umfpack_di_numeric(nw->Ap, nw->Ai, Ax, nw->symbolic, &numeric,
                              nw->control, nw->info);
  if (st == UMFPACK_WARNING_singular_matrix) {
    umfpack_di_free_numeric(&numeric);
    mrvi_fmt(msg, len, "singular Newton matrix");
    return MRVI_ESINGULAR;
  }
  if (st != UMFPACK_OK) {
    if (numeric)
      umfpack_di_free_numeric(&numeric);
    mrvi_fmt(msg, len, "UMFPACK numeric factorisation failed (status %d)",
             st);
    return st == UMFPACK_ERROR_out_of_memory ? MRVI_ENOMEM : MRVI_ESINGULAR;
  }
  st = umfpack_di_solve(UMFPACK_A, nw->Ap, nw->Ai, Ax, dx, b, numeric,
                        nw->control, nw->info);
  umfpack_di_free_numeric(&numeric);
  if (st != UMFPACK_OK) {
    mrvi_fmt(msg, len, "UMFPACK solve failed (status %d)", st);
    return MRVI_ESINGULAR;
  }
  return MRVI_OK;
}

int mrvi_newton_solve_transpose(mrvi_newton *nw, const double *Ax, int nrhs,
                                const double *b, double *x, char *msg,
                                size_t len) {
  void *numeric = NULL;
  int st = umfpack_di_numeric(nw->Ap, nw->Ai, Ax, nw->symbolic, &numeric,
                              nw->control, nw->info);
  if (st != UMFPACK_OK) {
    if (numeric)
      umfpack_di_free_numeric(&numeric);
    mrvi_fmt(msg, len, "UMFPACK numeric factorisation failed (status %d)",
             st);
    return MRVI_ESINGULAR;
  }
  const size_t n = (size_t)nw->n;
  for (int i = 0; i < nrhs && st == UMFPACK_OK; i++)
    st = umfpack_di_solve(UMFPACK_At, nw->Ap, nw->Ai, Ax, x + (size_t)i * n,
                          b + (size_t)i * n, numeric, nw->control, nw->info);
  umfpack_di_free_numeric(&numeric);
  if (st != UMFPACK_OK) {
    mrvi_fmt(msg, len, "UMFPACK transposed solve failed (status %d)", st);
    return MRVI_ESINGULAR;
  }
  return MRVI_OK;
}
