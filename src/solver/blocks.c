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
#include "internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

struct mrvi_blocks {
  int ns, nf, p;
  double *Ass, *Asf, *Afs; /* ns x ns, ns x p nf, p nf x ns */
  double *D, *L1, *L2;     /* p blocks nf x nf each: column m, m-1, m-2 */
  int *piv;                /* p x nf (pivots of the factored D) */
  double *Y, *z, *S, *r;   /* p nf x ns, p nf, ns x ns, ns */
  int *spiv;
  double **dst; /* block entry of every CSC entry (built on the first
                   factorisation: the pattern is fixed for the run) */
  long n_dst;
};

void mrvi_blocks_free(mrvi_blocks *b) {
  if (!b)
    return;
  free(b->Ass);
  free(b->Asf);
  free(b->Afs);
  free(b->D);
  free(b->L1);
  free(b->L2);
  free(b->piv);
  free(b->Y);
  free(b->z);
  free(b->S);
  free(b->r);
  free(b->spiv);
  free(b->dst);
  free(b);
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
  ALLOC(b->Ass, ns * ns, double);
  ALLOC(b->Asf, ns * nF, double);
  ALLOC(b->Afs, nF * ns, double);
  ALLOC(b->D, p * nf * nf, double);
  ALLOC(b->L1, p * nf * nf, double);
  ALLOC(b->L2, p * nf * nf, double);
  ALLOC(b->piv, nF, int);
  ALLOC(b->Y, nF * ns, double);
  ALLOC(b->z, nF, double);
  ALLOC(b->S, ns * ns, double);
  ALLOC(b->r, ns, double);
  ALLOC(b->spiv, ns, int);
#undef ALLOC
  if (!b->Ass || !b->Asf || !b->Afs || !b->D || !b->L1 || !b->L2 || !b->piv ||
      !b->Y || !b->z || !b->S || !b->r || !b->spiv) {
    mrvi_blocks_free(b);
    return MRVI_ENOMEM;
  }
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
 * structure, MRVI_ENOMEM. */
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
        if (!(b->dst[q] = block_entry(b, st->Ai[q], j))) {
          free(b->dst);
          b->dst = NULL;
          return MRVI_EINVAL;
        }
    b->n_dst = nnz;
  }
  memset(b->Ass, 0, (size_t)ns * (size_t)ns * sizeof(double));
  memset(b->Asf, 0, (size_t)ns * (size_t)nF * sizeof(double));
  memset(b->Afs, 0, (size_t)nF * (size_t)ns * sizeof(double));
  const size_t bb = (size_t)p * (size_t)nf * (size_t)nf;
  memset(b->D, 0, bb * sizeof(double));
  memset(b->L1, 0, bb * sizeof(double));
  memset(b->L2, 0, bb * sizeof(double));
  for (long q = 0; q < nnz; q++)
    *b->dst[q] += st->Ax[q];
  return MRVI_OK;
}

/* X (p nf x nrhs) <- A_ff^-1 X by a block forward sweep (D factored). */
static void sweep_solve(const mrvi_blocks *b, double *X, int nrhs) {
  const int nf = b->nf;
  const size_t blk = (size_t)nf * (size_t)nf, row = (size_t)nf * (size_t)nrhs;
  for (int m = 0; m < b->p; m++) {
    double *xm = X + (size_t)m * row;
    for (int d = 1; d <= 2 && d <= m; d++) {
      const double *L = (d == 1 ? b->L1 : b->L2) + (size_t)m * blk;
      const double *xc = X + (size_t)(m - d) * row;
      for (int i = 0; i < nf; i++)
        for (int k = 0; k < nf; k++) {
          const double l = L[i * nf + k];
          if (l != 0.0)
            for (int c = 0; c < nrhs; c++)
              xm[i * nrhs + c] -= l * xc[k * nrhs + c];
        }
    }
    mrvi_dense_lu_solve(nf, b->D + (size_t)m * blk,
                        b->piv + (size_t)m * (size_t)nf, xm, nrhs);
  }
}

int mrvi_blocks_factor(mrvi_blocks *b, const mrvi_step *st) {
  const int ns = b->ns, nf = b->nf, p = b->p, nF = p * nf;
  const int sc = scatter(b, st);
  if (sc < 0)
    return sc;
  const size_t blk = (size_t)nf * (size_t)nf;
  for (int m = 0; m < p; m++)
    if (mrvi_dense_lu_factor(nf, b->D + (size_t)m * blk,
                             b->piv + (size_t)m * (size_t)nf) < 0)
      return MRVI_ESINGULAR;
  /* Y = A_ff^-1 A_fs, S = A_ss - A_sf Y (factored) */
  memcpy(b->Y, b->Afs, (size_t)nF * (size_t)ns * sizeof(double));
  if (ns > 0)
    sweep_solve(b, b->Y, ns);
  for (int i = 0; i < ns; i++) {
    const double *a = b->Asf + (size_t)i * (size_t)nF;
    for (int j = 0; j < ns; j++) {
      double s = b->Ass[i * ns + j];
      for (int k = 0; k < nF; k++)
        s -= a[k] * b->Y[(size_t)k * (size_t)ns + (size_t)j];
      b->S[i * ns + j] = s;
    }
  }
  if (ns > 0 && mrvi_dense_lu_factor(ns, b->S, b->spiv) < 0)
    return MRVI_ESINGULAR;
  return MRVI_OK;
}

void mrvi_blocks_solve(const mrvi_blocks *b, const double *R, double *dx) {
  const int ns = b->ns, nF = b->p * b->nf;
  /* z = A_ff^-1 R_f, r = R_s - A_sf z, ds = S^-1 r, df = z - Y ds */
  memcpy(b->z, R + ns, (size_t)nF * sizeof(double));
  sweep_solve(b, b->z, 1);
  for (int i = 0; i < ns; i++) {
    const double *a = b->Asf + (size_t)i * (size_t)nF;
    double s = R[i];
    for (int k = 0; k < nF; k++)
      s -= a[k] * b->z[k];
    b->r[i] = s;
  }
  if (ns > 0)
    mrvi_dense_lu_solve(ns, b->S, b->spiv, b->r, 1);
  memcpy(dx, b->r, (size_t)ns * sizeof(double));
  for (int k = 0; k < nF; k++) {
    double s = b->z[k];
    for (int j = 0; j < ns; j++)
      s -= b->Y[(size_t)k * (size_t)ns + (size_t)j] * b->r[j];
    dx[ns + k] = s;
  }
}
