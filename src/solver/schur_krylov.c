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
 * run), kept for the further solves with the same Jacobian. */
#include "internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Relative tolerances of the block CG solves and of GMRES (2-norm), and
 * GMRES's restart length and iteration cap. */
#define SK_CG_RTOL 1e-13
#define SK_GMRES_RTOL 1e-11
#define SK_RESTART 20
#define SK_GMRES_MAX_IT 100

struct mrvi_skrylov {
  const mrvi_step *st;
  int ns, nf, p;
  /* Pattern: per fast column (p nf) the end of its slow rows (s1) and of
   * its own row block (s2), and its diagonal entry (dg); per slow column
   * the first entry in a fast row (sdiv). */
  int *s1, *s2, *dg, *sdiv;
  /* The diagonal blocks -D_c by rows, compact (CSR, rows of block c at
   * dptr[c nf ..], local column indices, columns ascending), copied from
   * the Jacobian at each factor: dval[k] = -Ax[dsrc[k]].  A CG product
   * then streams 16 bytes per entry of D_c instead of the whole columns
   * of the step Jacobian. */
  int *dptr, *dcol, *dsrc;
  double *dval;
  double *dinv;               /* p nf: 1 / diag(-D_c) */
  double *dinv_s;             /* ns: 1 / diag(A_ss) */
  double *t;                  /* p nf: sweep vector of the S operator */
  double *rs, *ds;            /* ns */
  double *cgb, *cgx, *cgwork; /* nf, nf, 4 nf */
  double *gwork;              /* GMRES */
  int block;                  /* diagonal block of the CG operator */
  int failed;                 /* MRVI_CG_* of the last failed solve */
  double curvature;           /* of a non-positive direction */
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
  free(k->dptr);
  free(k->dcol);
  free(k->dsrc);
  free(k->dval);
  free(k->dinv);
  free(k->dinv_s);
  free(k->t);
  free(k->rs);
  free(k->ds);
  free(k->cgb);
  free(k->cgx);
  free(k->cgwork);
  free(k->gwork);
  mrvi_newton_free(k->lu);
  free(k);
}

/* The row structure of the diagonal blocks from the split columns: row f
 * of block c holds the entries (f, g) of columns g = 0..nf-1 in order, so
 * that a row sum adds the same products in the same order as the column
 * scatter. */
static int build_rows(mrvi_skrylov *k) {
  const int nf = k->nf, ns = k->ns;
  const size_t nF = (size_t)k->p * (size_t)nf;
  const int *Ai = k->st->Ai;
  size_t nd = 0;
  for (size_t j = 0; j < nF; j++)
    nd += (size_t)(k->s2[j] - k->s1[j]);
  k->dptr = calloc(nF + 1, sizeof *k->dptr);
  k->dcol = malloc((nd > 0 ? nd : 1) * sizeof *k->dcol);
  k->dsrc = malloc((nd > 0 ? nd : 1) * sizeof *k->dsrc);
  k->dval = malloc((nd > 0 ? nd : 1) * sizeof *k->dval);
  if (!k->dptr || !k->dcol || !k->dsrc || !k->dval)
    return -1;
  for (size_t j = 0; j < nF; j++)
    for (int q = k->s1[j]; q < k->s2[j]; q++)
      k->dptr[Ai[q] - ns + 1]++;
  for (size_t i = 0; i < nF; i++)
    k->dptr[i + 1] += k->dptr[i];
  /* Fill by columns ascending, with dptr[i] as the next free slot of row i
   * (shifted back afterwards). */
  for (size_t j = 0; j < nF; j++) {
    const int g = (int)(j % (size_t)nf);
    for (int q = k->s1[j]; q < k->s2[j]; q++) {
      const int at = k->dptr[Ai[q] - ns]++;
      k->dcol[at] = g;
      k->dsrc[at] = q;
    }
  }
  for (size_t i = nF; i > 0; i--)
    k->dptr[i] = k->dptr[i - 1];
  k->dptr[0] = 0;
  return 0;
}

int mrvi_skrylov_create(const mrvi_step *st, mrvi_skrylov **out, char *msg,
                        size_t len) {
  *out = NULL;
  mrvi_skrylov *k = calloc(1, sizeof *k);
  if (!k)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  k->st = st;
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
  ALLOC(k->rs, ns);
  ALLOC(k->ds, ns);
  ALLOC(k->cgb, nf);
  ALLOC(k->cgx, nf);
  ALLOC(k->cgwork, 4 * nf);
  ALLOC(k->gwork, mrvi_gmres_work(k->ns, SK_RESTART));
#undef ALLOC
  if (!k->s1 || !k->s2 || !k->dg || !k->sdiv || !k->dinv || !k->dinv_s ||
      !k->t || !k->rs || !k->ds || !k->cgb || !k->cgx || !k->cgwork ||
      !k->gwork) {
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
  if (build_rows(k) < 0) {
    mrvi_skrylov_free(k);
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  }
  *out = k;
  return MRVI_OK;
}

const mrvi_krylov_stats *mrvi_skrylov_stats(const mrvi_skrylov *k) {
  return &k->stats;
}

void mrvi_skrylov_factor(mrvi_skrylov *k) {
  const double *Ax = k->st->Ax;
  for (int j = 0; j < k->p * k->nf; j++) {
    const double d = -Ax[k->dg[j]];
    k->dinv[j] = d > 0.0 ? 1.0 / d : 1.0;
  }
  const int nd = k->dptr[k->p * k->nf];
  for (int i = 0; i < nd; i++)
    k->dval[i] = -Ax[k->dsrc[i]];
  for (int j = 0; j < k->ns; j++) {
    double d = 0.0;
    for (int q = k->st->Ap[j]; q < k->sdiv[j]; q++)
      if (k->st->Ai[q] == j)
        d = k->st->Ax[q];
    k->dinv_s[j] = d != 0.0 ? 1.0 / d : 1.0;
  }
  k->lu_active = 0;
}

/* y = -D_c v (positive definite where CG applies), c = k->block, by the
 * compact rows. */
static void neg_diag_block(void *ctx, const double *v, double *y) {
  const mrvi_skrylov *k = ctx;
  const int nf = k->nf;
  const int *ptr = k->dptr + (size_t)k->block * (size_t)nf;
  const int *col = k->dcol;
  const double *val = k->dval;
  for (int f = 0; f < nf; f++) {
    double s = 0.0;
    for (int q = ptr[f]; q < ptr[f + 1]; q++)
      s += val[q] * v[col[q]];
    y[f] = s;
  }
}

/* X (p nf) <- A_ff^-1 X by a block forward sweep; MRVI_CG_* on failure. */
static int forward_sweep(mrvi_skrylov *k, double *X) {
  const mrvi_step *st = k->st;
  const int nf = k->nf, ns = k->ns;
  for (int c = 0; c < k->p; c++) {
    double *xc = X + (size_t)c * (size_t)nf;
    /* D_c x = b  <=>  (-D_c) x = -b */
    for (int f = 0; f < nf; f++)
      k->cgb[f] = -xc[f];
    k->block = c;
    int it = 0;
    const int s = mrvi_pcg(
        nf, neg_diag_block, k, k->dinv + (size_t)c * (size_t)nf, k->cgb, k->cgx,
        SK_CG_RTOL, 0.0, MRVI_CG_MAX_IT, k->cgwork, &it, &k->curvature);
    k->stats.cg_solves++;
    k->stats.cg_iterations += it;
    if (it > k->stats.cg_max)
      k->stats.cg_max = it;
    if (s != MRVI_CG_OK) {
      k->failed = s;
      k->fail_block = c;
      k->fail_iters = it;
      return s;
    }
    memcpy(xc, k->cgx, (size_t)nf * sizeof(double));
    /* Later rows: X_{c+1}, X_{c+2} -= (their entries of column block c) */
    for (int f = 0; f < nf; f++) {
      const int jf = c * nf + f;
      const double v = xc[f];
      for (int q = k->s2[jf]; q < st->Ap[ns + jf + 1]; q++)
        X[st->Ai[q] - ns] -= st->Ax[q] * v;
    }
  }
  return MRVI_CG_OK;
}

/* y (p nf) = A_fs v (ns). */
static void apply_fs(const mrvi_skrylov *k, const double *v, double *y) {
  const mrvi_step *st = k->st;
  memset(y, 0, (size_t)k->p * (size_t)k->nf * sizeof(double));
  for (int j = 0; j < k->ns; j++)
    for (int q = k->sdiv[j]; q < st->Ap[j + 1]; q++)
      y[st->Ai[q] - k->ns] += st->Ax[q] * v[j];
}

/* y (ns) -= A_sf x (p nf). */
static void sub_sf(const mrvi_skrylov *k, const double *x, double *y) {
  const mrvi_step *st = k->st;
  for (int jf = 0; jf < k->p * k->nf; jf++)
    for (int q = st->Ap[k->ns + jf]; q < k->s1[jf]; q++)
      y[st->Ai[q]] -= st->Ax[q] * x[jf];
}

/* y = S v = A_ss v - A_sf A_ff^-1 A_fs v. */
static int schur_op(void *ctx, const double *v, double *y) {
  mrvi_skrylov *k = ctx;
  const mrvi_step *st = k->st;
  apply_fs(k, v, k->t);
  if (forward_sweep(k, k->t) != MRVI_CG_OK)
    return -1;
  memset(y, 0, (size_t)k->ns * sizeof(double));
  for (int j = 0; j < k->ns; j++)
    for (int q = st->Ap[j]; q < k->sdiv[j]; q++)
      y[st->Ai[q]] += st->Ax[q] * v[j];
  sub_sf(k, k->t, y);
  return 0;
}

/* The iterative solve; MRVI_CG_* on failure. */
static int solve_krylov(mrvi_skrylov *k, const double *R, double *dx) {
  const int ns = k->ns;
  const size_t nF = (size_t)k->p * (size_t)k->nf;
  double *df = dx + ns;
  /* z = A_ff^-1 R_f (in df), rs = R_s - A_sf z */
  memcpy(df, R + ns, nF * sizeof(double));
  int s = forward_sweep(k, df);
  if (s != MRVI_CG_OK)
    return s;
  if (ns == 0)
    return MRVI_CG_OK;
  memcpy(k->rs, R, (size_t)ns * sizeof(double));
  sub_sf(k, df, k->rs);
  int it = 0;
  s = mrvi_gmres(ns, schur_op, k, k->dinv_s, k->rs, k->ds, SK_GMRES_RTOL, 0.0,
                 SK_RESTART, SK_GMRES_MAX_IT, k->gwork, &it);
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
  /* df = A_ff^-1 (R_f - A_fs ds) */
  memcpy(dx, k->ds, (size_t)ns * sizeof(double));
  apply_fs(k, k->ds, df);
  for (size_t i = 0; i < nF; i++)
    df[i] = R[ns + i] - df[i];
  return forward_sweep(k, df);
}

int mrvi_skrylov_solve(mrvi_skrylov *k, const double *R, double *dx, char *msg,
                       size_t len) {
  const mrvi_step *st = k->st;
  if (k->lu_active)
    return mrvi_linsolve_solve(k->lu, st->Ax, 0, R, dx, msg, len);
  const int s = solve_krylov(k, R, dx);
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
  if (!k->lu && !(k->lu = mrvi_newton_create(st->n_unknowns, st->Ap, st->Ai,
                                             st->Ax, msg, len)))
    return MRVI_ESINGULAR;
  const int r = mrvi_newton_solve(k->lu, st->Ax, R, dx, msg, len);
  k->lu_active = r == MRVI_OK;
  return r;
}
