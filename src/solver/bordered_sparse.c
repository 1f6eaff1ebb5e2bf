/* schur-bordered's node blocks beyond the dense limit (bordered_node_max):
 * the same block elimination as bordered.c's node blocks (the fast node
 * blocks D_c = [A_cc, -h G(z^c)^T; G(z^{c+1}), 0] on the diagonal, L1_c,
 * L2_c beside it, the slow block and its multipliers bordered), with
 *
 *   - each D_c factored on its own sparse pattern by mrvi_newton (the
 *     general path's solver: the dense LU that skips zeros or UMFPACK, by
 *     its flop estimate; solver/newton.c), its factors solving with D_c and
 *     D_c^T through the one interface mrvi_linsolve_solve;
 *   - L1, L2, A_sf and A_fs kept as lists of their nonzeros;
 *   - Y = A_ff^-1 A_fs never stored: S = A_ss - A_sf Y is formed from
 *     chunks of NS_CHUNK of Y's columns at a time (a forward sweep of
 *     sparse solves each), and a solve sweeps A_ff twice instead of reading
 *     Y:  J dx = R:    v = A_ff^-1 R_f, S ds = R_s - A_sf v,
 *                      df = A_ff^-1 (R_f - A_fs ds);
 *         J^T dx = R:  v = A_ff^-T R_f, S^T ds = R_s - A_fs^T v,
 *                      df = A_ff^-T (R_f - A_sf^T ds)
 *     (A_ff block lower-triangular: A_ff^-T by a backward sweep).
 *
 * Storage O(nnz(J) + the D_c's factors + a^2 + NS_CHUNK p b), where the
 * dense node blocks take p (3 b^2 + 2 a b); the dense slow Schur complement
 * S (a = n_s + r_s unknowns, a^3 / 3 per factorisation) remains, which
 * bounds the path (bordered_slow_max; doc/solver.md).  A factorisation is
 * O(p k nnz(LU(D_c)) + nnz(A_sf) k + a^3 / 3), k the slow columns with an
 * entry in a fast row. */
#include "solver/solver.h"

#include <stdlib.h>
#include <string.h>

/* Columns of Y formed per sweep while S is built. */
enum { NS_CHUNK = 16 };

struct mrvi_nsparse {
  int n, a, b, p, dense_max;
  const int *rblk, *roff; /* bordered.c's: block and offset of J's rows */
  /* D_c: CSC of b x b (dp: p (b + 1) offsets, di rows), values dx (block
   * c's from dp[c (b + 1)]), its solver nw[c] (created at the first
   * factorisation, when the values are known). */
  int *dp, *di;
  double *dx;
  mrvi_newton **nw;
  /* L1, L2 by row block c (lo[c] .. lo[c + 1]): row in block c (lr),
   * column in A_ff's fast order (lc: block c - 1 or c - 2 times b plus its
   * offset), value lx.  A_sf: slow row si, fast column sj, value sx.  A_fs
   * by slow column (fp: the ka kept columns' offsets, fcol their slow
   * offsets): fast row fi, value fx. */
  int *lo, *lr, *lc, *si, *sj, *fp, *fcol, *fi;
  double *lx, *sx, *fx;
  int nsf, ka;
  double *Ass, *S;
  int *spiv;
  double **dst;
  double *z, *w, *tmp, *ych; /* n, p b, b, NS_CHUNK p b */
};

void mrvi_nsparse_free(mrvi_nsparse *ns) {
  if (!ns)
    return;
  if (ns->nw)
    for (int c = 0; c < ns->p; c++)
      mrvi_newton_free(ns->nw[c]);
  free(ns->nw);
  free(ns->dp);
  free(ns->di);
  free(ns->dx);
  free(ns->lo);
  free(ns->lr);
  free(ns->lc);
  free(ns->lx);
  free(ns->si);
  free(ns->sj);
  free(ns->sx);
  free(ns->fp);
  free(ns->fcol);
  free(ns->fi);
  free(ns->fx);
  free(ns->Ass);
  free(ns->S);
  free(ns->spiv);
  free(ns->dst);
  free(ns->z);
  free(ns->w);
  free(ns->tmp);
  free(ns->ych);
  free(ns);
}

/* The lists and their destinations from J's pattern; MRVI_EINVAL where an
 * entry lies outside the structure (as bordered.c's node_create). */
static int lists(mrvi_nsparse *ns, const mrvi_step *st) {
  const int n = ns->n, b = ns->b, p = ns->p, a = ns->a;
  const int *Ap = st->Ap, *Ai = st->Ai;
  const size_t nnz = (size_t)Ap[n];
  int nd = 0, nl = 0, nsf = 0, nfs = 0;
  int *lcnt = calloc((size_t)p + 1, sizeof *lcnt);
  int *fcnt = calloc((size_t)a + 1, sizeof *fcnt);
  if (!lcnt || !fcnt) {
    free(lcnt), free(fcnt);
    return MRVI_ENOMEM;
  }
  int bad = 0;
  for (int j = 0; j < n; j++)
    for (int q = Ap[j]; q < Ap[j + 1]; q++) {
      const int rb = ns->rblk[Ai[q]], cb = ns->rblk[j];
      switch (mrvi_node_class(rb, cb)) {
      case MRVI_NODE_SS:
        break;
      case MRVI_NODE_SF:
        nsf++;
        break;
      case MRVI_NODE_FS:
        nfs++, fcnt[ns->roff[j]]++;
        break;
      case MRVI_NODE_D:
        nd++;
        break;
      case MRVI_NODE_L1:
      case MRVI_NODE_L2:
        nl++, lcnt[rb]++;
        break;
      default:
        bad = 1;
      }
    }
  if (bad) {
    free(lcnt), free(fcnt);
    return MRVI_EINVAL;
  }
  ns->dp = malloc(((size_t)p * ((size_t)b + 1) + 1) * sizeof *ns->dp);
  ns->di = malloc(((size_t)nd + 1) * sizeof *ns->di);
  ns->dx = calloc((size_t)nd + 1, sizeof *ns->dx);
  ns->lo = malloc(((size_t)p + 1) * sizeof *ns->lo);
  ns->lr = malloc(((size_t)nl + 1) * sizeof *ns->lr);
  ns->lc = malloc(((size_t)nl + 1) * sizeof *ns->lc);
  ns->lx = calloc((size_t)nl + 1, sizeof *ns->lx);
  ns->si = malloc(((size_t)nsf + 1) * sizeof *ns->si);
  ns->sj = malloc(((size_t)nsf + 1) * sizeof *ns->sj);
  ns->sx = calloc((size_t)nsf + 1, sizeof *ns->sx);
  ns->fp = malloc(((size_t)a + 1) * sizeof *ns->fp);
  ns->fcol = malloc(((size_t)a + 1) * sizeof *ns->fcol);
  ns->fi = malloc(((size_t)nfs + 1) * sizeof *ns->fi);
  ns->fx = calloc((size_t)nfs + 1, sizeof *ns->fx);
  ns->dst = malloc((nnz + 1) * sizeof *ns->dst);
  int *dcnt = calloc((size_t)p * ((size_t)b + 1) + 1, sizeof *dcnt);
  int *fpos = malloc(((size_t)a + 1) * sizeof *fpos);
  if (!ns->dp || !ns->di || !ns->dx || !ns->lo || !ns->lr || !ns->lc ||
      !ns->lx || !ns->si || !ns->sj || !ns->sx || !ns->fp || !ns->fcol ||
      !ns->fi || !ns->fx || !ns->dst || !dcnt || !fpos) {
    free(lcnt), free(fcnt), free(dcnt), free(fpos);
    return MRVI_ENOMEM;
  }
  /* offsets: D_c's columns (counted by column), L's row blocks, A_fs's
   * kept slow columns */
  for (int j = 0; j < n; j++)
    for (int q = Ap[j]; q < Ap[j + 1]; q++)
      if (mrvi_node_class(ns->rblk[Ai[q]], ns->rblk[j]) == MRVI_NODE_D)
        dcnt[(size_t)ns->rblk[j] * ((size_t)b + 1) + (size_t)ns->roff[j]]++;
  int e = 0;
  for (int c = 0; c < p; c++) {
    int *dp = ns->dp + (size_t)c * ((size_t)b + 1);
    const int *cnt = dcnt + (size_t)c * ((size_t)b + 1);
    const int base = e;
    for (int k = 0; k < b; k++)
      dp[k] = e - base, e += cnt[k];
    dp[b] = e - base;
  }
  ns->lo[0] = 0;
  for (int c = 0; c < p; c++)
    ns->lo[c + 1] = ns->lo[c] + lcnt[c];
  ns->ka = 0;
  int off = 0;
  for (int t = 0; t < a; t++) {
    fpos[t] = -1;
    if (fcnt[t] > 0) {
      ns->fp[ns->ka] = off, ns->fcol[ns->ka] = t, fpos[t] = ns->ka++;
      off += fcnt[t];
    }
  }
  ns->fp[ns->ka] = off;
  /* fill (each list in J's column order; D_c's rows ascending within a
   * column as J's are, the order being kept by roff) */
  memset(dcnt, 0, ((size_t)p * ((size_t)b + 1) + 1) * sizeof *dcnt);
  memset(lcnt, 0, ((size_t)p + 1) * sizeof *lcnt);
  memset(fcnt, 0, ((size_t)a + 1) * sizeof *fcnt);
  size_t dbase = 0;
  int *dstart = malloc(((size_t)p + 1) * sizeof *dstart);
  if (!dstart) {
    free(lcnt), free(fcnt), free(dcnt), free(fpos);
    return MRVI_ENOMEM;
  }
  for (int c = 0; c < p; c++) {
    dstart[c] = (int)dbase;
    dbase += (size_t)ns->dp[(size_t)c * ((size_t)b + 1) + (size_t)b];
  }
  nsf = 0;
  for (int j = 0; j < n; j++)
    for (int q = Ap[j]; q < Ap[j + 1]; q++) {
      const int i = Ai[q], rb = ns->rblk[i], cb = ns->rblk[j];
      const int ro = ns->roff[i], co = ns->roff[j];
      switch (mrvi_node_class(rb, cb)) { /* (none outside: checked above) */
      case MRVI_NODE_SS:
        ns->dst[q] = ns->Ass + (size_t)ro * (size_t)a + (size_t)co;
        break;
      case MRVI_NODE_SF:
        ns->si[nsf] = ro, ns->sj[nsf] = cb * b + co;
        ns->dst[q] = ns->sx + nsf++;
        break;
      case MRVI_NODE_FS: {
        const int u = fpos[co], k = ns->fp[u] + fcnt[u]++;
        ns->fi[k] = rb * b + ro;
        ns->dst[q] = ns->fx + k;
        break;
      }
      case MRVI_NODE_D: {
        const size_t col = (size_t)rb * ((size_t)b + 1) + (size_t)co;
        const int k = dstart[rb] + ns->dp[col] + dcnt[col]++;
        ns->di[k] = ro;
        ns->dst[q] = ns->dx + k;
        break;
      }
      default: {
        const int k = ns->lo[rb] + lcnt[rb]++;
        ns->lr[k] = ro, ns->lc[k] = cb * b + co;
        ns->dst[q] = ns->lx + k;
      }
      }
    }
  ns->nsf = nsf;
  free(lcnt), free(fcnt), free(dcnt), free(fpos), free(dstart);
  return MRVI_OK;
}

int mrvi_nsparse_create(const mrvi_step *st, const int *rblk, const int *roff,
                        mrvi_nsparse **out) {
  *out = NULL;
  mrvi_nsparse *ns = calloc(1, sizeof *ns);
  if (!ns)
    return MRVI_ENOMEM;
  ns->n = st->n_total, ns->p = st->p;
  ns->a = st->ns + st->r_slow, ns->b = st->nf + st->r_micro;
  ns->dense_max = st->tuning.newton_dense_max;
  ns->rblk = rblk, ns->roff = roff;
  const size_t a = (size_t)ns->a, pb = (size_t)ns->p * (size_t)ns->b;
  ns->nw = calloc((size_t)ns->p + 1, sizeof *ns->nw);
  ns->Ass = calloc(a * a + 1, sizeof *ns->Ass);
  ns->S = malloc((a * a + 1) * sizeof *ns->S);
  ns->spiv = malloc((a + 1) * sizeof *ns->spiv);
  ns->z = malloc(((size_t)ns->n + 1) * sizeof *ns->z);
  ns->w = malloc((pb + 1) * sizeof *ns->w);
  ns->tmp = malloc(((size_t)ns->b + 1) * sizeof *ns->tmp);
  ns->ych = malloc((NS_CHUNK * pb + 1) * sizeof *ns->ych);
  int s = !ns->nw || !ns->Ass || !ns->S || !ns->spiv || !ns->z || !ns->w ||
                  !ns->tmp || !ns->ych
              ? MRVI_ENOMEM
              : lists(ns, st);
  if (s < 0) {
    mrvi_nsparse_free(ns);
    return s;
  }
  *out = ns;
  return MRVI_OK;
}

/* x (p b, A_ff's fast order) becomes A_ff^-1 x (forward sweep) or A_ff^-T x
 * (backward sweep). */
static int sweep(mrvi_nsparse *ns, int transpose, double *x, char *msg,
                 size_t len) {
  const int b = ns->b, p = ns->p;
  const size_t b1 = (size_t)b + 1;
  size_t doff = 0; /* block c's values from dx + doff */
  for (int c = 0; c < p && transpose; c++)
    doff += (size_t)ns->dp[(size_t)c * b1 + (size_t)b];
  for (int i = 0; i < p; i++) {
    const int c = transpose ? p - 1 - i : i;
    double *xc = x + (size_t)c * (size_t)b;
    if (transpose)
      doff -= (size_t)ns->dp[(size_t)c * b1 + (size_t)b];
    else
      for (int e = ns->lo[c]; e < ns->lo[c + 1]; e++)
        xc[ns->lr[e]] -= ns->lx[e] * x[ns->lc[e]];
    const int s = mrvi_linsolve_solve(ns->nw[c], ns->dx + doff, transpose, xc,
                                      ns->tmp, msg, len);
    if (s < 0)
      return s;
    memcpy(xc, ns->tmp, (size_t)b * sizeof *xc);
    if (transpose)
      for (int e = ns->lo[c]; e < ns->lo[c + 1]; e++)
        x[ns->lc[e]] -= ns->lx[e] * xc[ns->lr[e]];
    else
      doff += (size_t)ns->dp[(size_t)c * b1 + (size_t)b];
  }
  return MRVI_OK;
}

int mrvi_nsparse_factor(mrvi_nsparse *ns, const mrvi_step *st, char *msg,
                        size_t len) {
  const int a = ns->a, b = ns->b, p = ns->p;
  const size_t pb = (size_t)p * (size_t)b, b1 = (size_t)b + 1;
  for (int q = 0; q < st->Ap[st->n_total]; q++)
    *ns->dst[q] = st->Ax[q];
  size_t doff = 0;
  for (int c = 0; c < p; c++) {
    const int *dp = ns->dp + (size_t)c * b1;
    double *dx = ns->dx + doff;
    if (!ns->nw[c] && !(ns->nw[c] = mrvi_newton_create(
                            b, dp, ns->di + doff, dx, ns->dense_max, msg, len)))
      return MRVI_ENOMEM;
    mrvi_newton_no_refine(ns->nw[c]);
    if (mrvi_newton_factor(ns->nw[c], dx, msg, len) < 0)
      return mrvi_fail(msg, len, MRVI_ESINGULAR,
                       "singular Newton matrix (sparse node block %d of the "
                       "schur-bordered path)",
                       c + 1);
    doff += (size_t)dp[b];
  }
  /* S = A_ss - A_sf A_ff^-1 A_fs, NS_CHUNK of A_fs's columns at a time */
  memcpy(ns->S, ns->Ass, (size_t)a * (size_t)a * sizeof *ns->S);
  for (int u0 = 0; u0 < ns->ka; u0 += NS_CHUNK) {
    const int nc = ns->ka - u0 < NS_CHUNK ? ns->ka - u0 : NS_CHUNK;
    memset(ns->ych, 0, (size_t)nc * pb * sizeof *ns->ych);
    for (int u = 0; u < nc; u++) {
      double *y = ns->ych + (size_t)u * pb;
      for (int k = ns->fp[u0 + u]; k < ns->fp[u0 + u + 1]; k++)
        y[ns->fi[k]] = ns->fx[k];
      const int s = sweep(ns, 0, y, msg, len);
      if (s < 0)
        return s;
    }
    for (int e = 0; e < ns->nsf; e++) {
      double *Si = ns->S + (size_t)ns->si[e] * (size_t)a;
      const double f = ns->sx[e];
      const double *y = ns->ych + (size_t)ns->sj[e];
      for (int u = 0; u < nc; u++)
        Si[ns->fcol[u0 + u]] -= f * y[(size_t)u * pb];
    }
  }
  if (mrvi_dense_lu_factor(a, ns->S, ns->spiv) < 0)
    return mrvi_fail(msg, len, MRVI_ESINGULAR,
                     "singular Newton matrix (slow Schur complement of the "
                     "schur-bordered path)");
  return MRVI_OK;
}

int mrvi_nsparse_solve(mrvi_nsparse *ns, int transpose, const double *R,
                       double *dx, char *msg, size_t len) {
  const int a = ns->a, b = ns->b, n = ns->n;
  const size_t pb = (size_t)ns->p * (size_t)b;
  double *z = ns->z, *ds = ns->z + pb, *w = ns->w;
  /* node-block order: the fast blocks, then the slow one */
  for (int i = 0; i < n; i++)
    *(ns->rblk[i] >= 0 ? z + (size_t)ns->rblk[i] * (size_t)b + ns->roff[i]
                       : ds + ns->roff[i]) = R[i];
  memcpy(w, z, pb * sizeof *w);
  int s = sweep(ns, transpose, w, msg, len);
  if (s < 0)
    return s;
  if (!transpose) {
    for (int e = 0; e < ns->nsf; e++)
      ds[ns->si[e]] -= ns->sx[e] * w[ns->sj[e]];
    mrvi_dense_lu_solve(a, ns->S, ns->spiv, ds, 1);
    for (int u = 0; u < ns->ka; u++) {
      const double d = ds[ns->fcol[u]];
      for (int k = ns->fp[u]; k < ns->fp[u + 1]; k++)
        z[ns->fi[k]] -= ns->fx[k] * d;
    }
  } else {
    for (int u = 0; u < ns->ka; u++) {
      double acc = 0.0;
      for (int k = ns->fp[u]; k < ns->fp[u + 1]; k++)
        acc += ns->fx[k] * w[ns->fi[k]];
      ds[ns->fcol[u]] -= acc;
    }
    mrvi_dense_lu_solve_transpose(a, ns->S, ns->spiv, ds, 1);
    for (int e = 0; e < ns->nsf; e++)
      z[ns->sj[e]] -= ns->sx[e] * ds[ns->si[e]];
  }
  if ((s = sweep(ns, transpose, z, msg, len)) < 0)
    return s;
  for (int i = 0; i < n; i++)
    dx[i] = ns->rblk[i] >= 0
                ? z[(size_t)ns->rblk[i] * (size_t)b + (size_t)ns->roff[i]]
                : ds[ns->roff[i]];
  return MRVI_OK;
}
