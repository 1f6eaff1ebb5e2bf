/* The micro-step Newton matrix of the sweep path for fast blocks beyond
 * the dense limit (doc/solver.md, "sweep-cg"):
 *   J = M^f/dt + sum_points w cA cB hess_ff W(z)          (nf x nf)
 * symmetric, assembled on a fixed sparse pattern (the fast inputs of every
 * W element, plus the diagonal) recorded once per run, and solved by
 * Jacobi-preconditioned CG (solver/krylov.c).  M/dt dominates at the step
 * sizes in use, so J is positive definite with condition number about
 * 1 + (omega dt)^2/4 and CG converges in a few iterations.  A direction of
 * non-positive curvature, or no convergence, falls back to a sparse LU of
 * J (UMFPACK: symbolic analysis on the first fallback of the run, numeric
 * per fallback), counted with its reason.  Memory O(nnz); nothing is
 * allocated after creation except UMFPACK's factors on a fallback.
 *
 * Matrix-free (mrvi_sblock_create_free, a class of springs and anchors
 * kept as records): no pattern and no values; the assembly keeps the
 * configuration z, the scale and the Hessian's diagonal alone (with the
 * gradient, mrvi_terms_grad_hdiag: the assembled diagonal bitwise, summed
 * into D^-1's array, which the solve inverts in place), and each CG
 * product forms every record's dim x dim block at z again
 * (mrvi_terms_hessvec_part): 5 nf doubles in all (D^-1 and the CG's four
 * vectors) where the values and their row indices took 12
 * bytes an entry, about 20 entries a fast coordinate on the random
 * networks (doc/performance/explicit.md, "explicit-slow's matrix-free Newton
 * block").  The LU fallback assembles the block from the records then. */
#include "solver/solver.h"

#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/umfpack.h>

struct mrvi_sblock {
  int nf;
  int dense_max; /* the fallback LU's (mrvi_newton_create) */
  int *Ap, *Ai;  /* CSC pattern (symmetric), sorted rows */
  long nnz;
  double *Ax; /* values */
  int *diag;  /* nf: index of (f, f) in Ax */
  int dim;    /* the model's (the compact maps' blocks) */
  /* per element of the class: offset in emap of its map, n_in x n_in Ax
   * indices (-1: a slow pair), or -2 - the offset of its compact map
   * (mrvi_sblock_map_expand), or -1: no Hessian */
  long *elem_off;
  int *emap;
  long n_map;              /* ints in emap */
  double *dinv, *x, *work; /* Jacobi preconditioner, solution, CG (3 nf) */
  mrvi_newton *lu;         /* fallback, created on first use */
  mrvi_krylov_stats stats;
  /* mrvi_sblock_set_parts: the rows (columns) in n_part parts on threads;
   * psum: a part's sums, PSUM_STRIDE doubles (a cache line) each */
  int n_part, threads;
  double *psum;
  /* matrix-free (kc set): the records of kc at z (the last assembly's
   * configuration: the caller keeps it until the solve and
   * mrvi_sblock_jacobi) times hs, n_add assemblies since the values were
   * zeroed (one allowed: one z); the Hessian's diagonal in dinv until
   * the solve makes it D^-1 (nonpos: some J_ff <= 0 or NaN there, D^-1 1);
   * the product's M/dt: mscale mdiag[f minc] (mscale 0 before the solve,
   * as the values before their shift).  Ap, Ai, Ax: made by an LU
   * fallback alone. */
  mrvi_terms *kc;
  const double *z, *mdiag;
  double hs, mscale;
  int minc, n_add, nonpos;
  /* kc partitioned as the block's rows (mrvi_sblock_set_parts): each part
   * forms its rows of a product from its records; else (one thread: kc
   * not partitioned) one thread forms the product whole first, each
   * row's sum the same bits either way (the records' order) */
  int kc_parts;
};

/* Doubles per part in psum: a cache line of its own (the parts' sums are
 * written by different threads). */
enum { PSUM_STRIDE = 8 };

void mrvi_sblock_free(mrvi_sblock *sb) {
  if (!sb)
    return;
  free(sb->Ap);
  free(sb->Ai);
  free(sb->Ax);
  free(sb->diag);
  free(sb->elem_off);
  free(sb->emap);
  free(sb->dinv);
  free(sb->x);
  free(sb->work);
  free(sb->psum);
  mrvi_newton_free(sb->lu);
  free(sb);
}

/* The rows of one column of the pattern (r[0..nr) in bucket order) sorted
 * with duplicates once into u (returned: their count). */
static int column_rows(const int *r, int nr, int *u) {
  int nu = 0;
  for (int b = 0; b < nr; b++) { /* (a few dozen rows: insertion) */
    const int x = r[b];
    int i = nu;
    while (i > 0 && u[i - 1] > x)
      i--;
    if (i > 0 && u[i - 1] == x)
      continue;
    memmove(u + i + 1, u + i, (size_t)(nu - i) * sizeof *u);
    u[i] = x;
    nu++;
  }
  return nu;
}

/* The index in Ax of entry (row r, column c) of the pattern. */
static int entry_at(const mrvi_sblock *sb, int r, int c) {
  int lo = sb->Ap[c], hi = sb->Ap[c + 1] - 1;
  while (lo < hi) {
    const int mid = (lo + hi) / 2;
    if (sb->Ai[mid] < r)
      lo = mid + 1;
    else
      hi = mid;
  }
  return lo;
}

/* Whether element e's map takes the compact form (mrvi_sblock_map_expand):
 * its inputs in blocks of dim (2 or 3) coordinates, each block either all
 * slow or all fast on consecutive slots whose columns hold the same rows
 * (same[c]: column c's rows are column c - 1's), so that the entries of a
 * pair of blocks are a base index, +1 a row, + the column's length a
 * column (rows sorted, each once). */
static int compact_ok(const mrvi_model *m, const mrvi_element *e,
                      const unsigned char *same) {
  const int dim = m->dimension, n = e->n_in;
  if (dim < 2 || n % dim != 0 || n > MRVI_SBLOCK_COMPACT_MAX)
    return 0;
  for (int b = 0; b < n; b += dim) {
    const int fast = m->rate[e->in[b]] == MRVI_FAST, s0 = m->slot[e->in[b]];
    for (int k = 1; k < dim; k++) {
      if ((m->rate[e->in[b + k]] == MRVI_FAST) != fast)
        return 0;
      if (fast && (m->slot[e->in[b + k]] != s0 + k || !same[s0 + k]))
        return 0;
    }
  }
  return 1;
}

/* Pattern of the fast-fast Hessians of elements `elems` (model indices)
 * and the diagonal in CSC, rows sorted and each once in a column (as
 * umfpack_di_triplet_to_col makes it from the triplets: the diagonal, then
 * every element's fast-fast pairs), built by columns without the triplets;
 * then each element's map of its Hessian's entries to their indices in Ax:
 * compact (nb x nb block bases and nb column lengths, nb = n_in / dim) where
 * compact_ok, else n_in x n_in indices (-1: a slow pair). */
/* A block of nf rows with nothing allocated but itself. */
static mrvi_sblock *sblock_new(int nf, int dim, int dense_max) {
  mrvi_sblock *sb = calloc(1, sizeof *sb);
  if (sb) {
    sb->nf = nf;
    sb->dense_max = dense_max;
    sb->dim = dim;
  }
  return sb;
}

int mrvi_sblock_create(const mrvi_model *m, const int *elems, int n_elems,
                       int dense_max, mrvi_sblock **out) {
  const int nf = m->n_fast, dim = m->dimension;
  *out = NULL;
  mrvi_sblock *sb = sblock_new(nf, dim, dense_max);
  if (!sb)
    return MRVI_ENOMEM;
  sb->elem_off = malloc((size_t)(n_elems > 0 ? n_elems : 1) * sizeof(long));
  if (!sb->elem_off)
    goto oom;
  /* Column c's entries are bucket positions start[c] .. start[c + 1]. */
  long *start = calloc((size_t)nf + 2, sizeof *start);
  sb->diag = malloc((size_t)(nf > 0 ? nf : 1) * sizeof(int));
  sb->Ap = malloc((size_t)(nf + 1) * sizeof(int));
  if (!start || !sb->diag || !sb->Ap) {
    free(start);
    goto oom;
  }
  for (int f = 0; f < nf; f++)
    start[f + 2]++;
  for (int ie = 0; ie < n_elems; ie++) {
    const mrvi_element *e = MRVI_ELEMENT(m, elems[ie]);
    if (e->kind == MRVI_ELEMENT_GRAVITY)
      continue; /* linear: no Hessian */
    for (int j = 0; j < e->n_in; j++)
      for (int l = 0; l < e->n_in; l++)
        if (m->rate[e->in[j]] == MRVI_FAST && m->rate[e->in[l]] == MRVI_FAST)
          start[m->slot[e->in[l]] + 2]++;
  }
  for (int c = 0; c < nf; c++)
    start[c + 2] += start[c + 1];
  const long nb = start[nf + 1];
  int *rows =
      nb <= INT_MAX ? malloc((size_t)(nb > 0 ? nb : 1) * sizeof(int)) : NULL;
  sb->Ai = rows ? malloc((size_t)(nb > 0 ? nb : 1) * sizeof(int)) : NULL;
  if (!sb->Ai) {
    free(rows);
    free(start);
    goto oom;
  }
  /* (start[c + 1]: the next free position of column c) */
  for (int f = 0; f < nf; f++)
    rows[start[f + 1]++] = f;
  for (int ie = 0; ie < n_elems; ie++) {
    const mrvi_element *e = MRVI_ELEMENT(m, elems[ie]);
    if (e->kind == MRVI_ELEMENT_GRAVITY)
      continue;
    for (int j = 0; j < e->n_in; j++)
      for (int l = 0; l < e->n_in; l++)
        if (m->rate[e->in[j]] == MRVI_FAST && m->rate[e->in[l]] == MRVI_FAST)
          rows[start[m->slot[e->in[l]] + 1]++] = m->slot[e->in[j]];
  }
  /* (start[c]: column c's first position again) */
  int k = 0;
  sb->Ap[0] = 0;
  for (int c = 0; c < nf; c++) {
    k += column_rows(rows + start[c], (int)(start[c + 1] - start[c]),
                     sb->Ai + k);
    sb->Ap[c + 1] = k;
  }
  free(rows);
  free(start);
  int *Ai = realloc(sb->Ai, (size_t)(k > 0 ? k : 1) * sizeof(int));
  if (Ai)
    sb->Ai = Ai;
  sb->nnz = k;
  for (int f = 0; f < nf; f++)
    sb->diag[f] = entry_at(sb, f, f);
  /* The maps: their sizes, then their entries. */
  unsigned char *same = malloc((size_t)(nf > 0 ? nf : 1));
  if (!same)
    goto oom;
  for (int c = 0; c < nf; c++) {
    const int len = sb->Ap[c + 1] - sb->Ap[c];
    same[c] = c > 0 && len == sb->Ap[c] - sb->Ap[c - 1] &&
              memcmp(sb->Ai + sb->Ap[c], sb->Ai + sb->Ap[c - 1],
                     (size_t)len * sizeof(int)) == 0;
  }
  long nm = 0;
  for (int ie = 0; ie < n_elems; ie++) {
    const mrvi_element *e = MRVI_ELEMENT(m, elems[ie]);
    sb->elem_off[ie] = -1;
    if (e->kind == MRVI_ELEMENT_GRAVITY)
      continue;
    const int n = e->n_in, nbk = n / (dim > 0 ? dim : 1);
    if (compact_ok(m, e, same)) {
      sb->elem_off[ie] = -2 - nm; /* (compact) */
      nm += (long)nbk * nbk + nbk;
    } else {
      sb->elem_off[ie] = nm;
      nm += (long)n * n;
    }
  }
  sb->n_map = nm;
  sb->emap = malloc((size_t)(nm > 0 ? nm : 1) * sizeof(int));
  if (!sb->emap) {
    free(same);
    goto oom;
  }
  for (int ie = 0; ie < n_elems; ie++) {
    const mrvi_element *e = MRVI_ELEMENT(m, elems[ie]);
    const long o = sb->elem_off[ie];
    if (o == -1)
      continue;
    const int n = e->n_in;
    if (o >= 0) {
      int *em = sb->emap + o;
      for (int j = 0; j < n; j++)
        for (int l = 0; l < n; l++) {
          const int fast =
              m->rate[e->in[j]] == MRVI_FAST && m->rate[e->in[l]] == MRVI_FAST;
          em[j * n + l] =
              fast ? entry_at(sb, m->slot[e->in[j]], m->slot[e->in[l]]) : -1;
        }
      continue;
    }
    int *cm = sb->emap + (-2 - o);
    const int nbk = n / dim;
    for (int bj = 0; bj < nbk; bj++) {
      const int c = m->slot[e->in[bj * dim]];
      const int cf = m->rate[e->in[bj * dim]] == MRVI_FAST;
      cm[nbk * nbk + bj] = cf ? sb->Ap[c + 1] - sb->Ap[c] : 0;
      for (int bi = 0; bi < nbk; bi++) {
        const int fast = cf && m->rate[e->in[bi * dim]] == MRVI_FAST;
        cm[bj * nbk + bi] =
            fast ? entry_at(sb, m->slot[e->in[bi * dim]], c) : -1;
      }
    }
  }
  free(same);
  sb->Ax = calloc((size_t)(sb->nnz > 0 ? sb->nnz : 1), sizeof(double));
  sb->dinv = malloc((size_t)(nf > 0 ? nf : 1) * sizeof(double));
  sb->x = malloc((size_t)(nf > 0 ? nf : 1) * sizeof(double));
  sb->work = malloc((size_t)(nf > 0 ? 3 * nf : 1) * sizeof(double));
  if (!sb->Ax || !sb->dinv || !sb->x || !sb->work)
    goto oom;
  *out = sb;
  return MRVI_OK;
oom:
  mrvi_sblock_free(sb);
  return MRVI_ENOMEM;
}

int mrvi_sblock_create_free(mrvi_terms *kc, int nf, int dim, int dense_max,
                            mrvi_sblock **out) {
  *out = NULL;
  if (!mrvi_terms_springs_only(kc) || mrvi_terms_hessblocks_size(kc) < 0 ||
      nf < 0 || dim < 1 || dim > 3)
    return MRVI_EINVAL;
  mrvi_sblock *sb = sblock_new(nf, dim, dense_max);
  if (!sb)
    return MRVI_ENOMEM;
  sb->kc = kc;
  const size_t n = (size_t)(nf > 0 ? nf : 1);
  sb->dinv = calloc(n, sizeof(double));
  sb->x = malloc(n * sizeof(double));
  sb->work = malloc(3 * n * sizeof(double));
  if (!sb->dinv || !sb->x || !sb->work) {
    mrvi_sblock_free(sb);
    return MRVI_ENOMEM;
  }
  *out = sb;
  return MRVI_OK;
}

int mrvi_sblock_free_form(const mrvi_sblock *sb) { return sb->kc != NULL; }

void mrvi_sblock_map_expand(const int *cm, int n, int dim, int *map) {
  const int nb = n / dim;
  for (int i = 0; i < n; i++)
    for (int j = 0; j < n; j++) {
      const int base = cm[(j / dim) * nb + i / dim];
      map[i * n + j] =
          base < 0 ? -1 : base + (j % dim) * cm[nb * nb + j / dim] + i % dim;
    }
}

void mrvi_sblock_zero(mrvi_sblock *sb) {
  if (sb->kc) {
    memset(sb->dinv, 0, (size_t)sb->nf * sizeof(double));
    sb->n_add = 0;
    sb->mscale = 0.0;
    return;
  }
  memset(sb->Ax, 0, (size_t)sb->nnz * sizeof(double));
}

int mrvi_sblock_set_parts(mrvi_sblock *sb, int n_part, int threads) {
  if (n_part < 2 || n_part > sb->nf)
    return MRVI_OK; /* (serial) */
  double *p = realloc(sb->psum, (size_t)n_part * PSUM_STRIDE * sizeof *p);
  if (!p)
    return MRVI_ENOMEM;
  sb->psum = p;
  sb->n_part = n_part;
  sb->kc_parts = sb->kc && mrvi_terms_sparse_parts(sb->kc) == n_part;
  sb->threads = threads > 1 ? threads : 1;
  return MRVI_OK;
}

int mrvi_sblock_parts(const mrvi_sblock *sb) { return sb->n_part; }

void mrvi_sblock_add_terms_part(mrvi_sblock *sb, const mrvi_terms *kc, int c,
                                const double *z, double *g, double scale,
                                int zero) {
  const int f0 = mrvi_part_start(c, sb->nf, sb->n_part);
  const int f1 = mrvi_part_start(c + 1, sb->nf, sb->n_part);
  if (sb->kc) { /* (the configuration and scale kept by part 0 alone) */
    if (zero)
      memset(sb->dinv + f0, 0, (size_t)(f1 - f0) * sizeof(double));
    mrvi_terms_grad_hdiag_part(kc, c, z, g, sb->dinv, NULL, scale);
    if (c == 0) {
      sb->z = z;
      sb->hs = scale;
      sb->n_add = zero ? 1 : sb->n_add + 1;
      sb->mscale = 0.0;
    }
    return;
  }
  if (zero)
    memset(sb->Ax + sb->Ap[f0], 0,
           (size_t)(sb->Ap[f1] - sb->Ap[f0]) * sizeof(double));
  mrvi_terms_eval_sparse_part(kc, c, z, g, sb->Ax, sb->elem_off, sb->emap,
                              scale);
}

void mrvi_sblock_add_element(mrvi_sblock *sb, int ie, const double *H, int n_in,
                             double scale) {
  if (sb->kc) /* (matrix-free: the records' Hessians alone) */
    return;
  const long o = sb->elem_off[ie];
  if (o == -1)
    return;
  int buf[MRVI_SBLOCK_COMPACT_MAX * MRVI_SBLOCK_COMPACT_MAX];
  const int *map = sb->emap + o;
  if (o < -1) {
    mrvi_sblock_map_expand(sb->emap + (-2 - o), n_in, sb->dim, buf);
    map = buf;
  }
  for (int k = 0; k < n_in * n_in; k++)
    if (map[k] >= 0)
      sb->Ax[map[k]] += scale * H[k];
}

void mrvi_sblock_add_terms(mrvi_sblock *sb, mrvi_terms *kc, const double *z,
                           double *g, double scale) {
  if (sb->kc) {
    mrvi_terms_grad_hdiag(kc, z, g, sb->dinv, NULL, scale);
    sb->z = z;
    sb->hs = scale;
    sb->n_add++;
    sb->mscale = 0.0;
    return;
  }
  mrvi_terms_eval_sparse(kc, z, g, sb->Ax, sb->elem_off, sb->emap, scale);
}

static double matvec_parts(void *ctx, const double *x, double *y);
static double free_rows(const mrvi_sblock *sb, int c, const double *x,
                        double *y, int f0, int f1);

void mrvi_sblock_matvec(const mrvi_sblock *sb, const double *x, double *y) {
  if (sb->n_part > 0) { /* (the CG's product on threads) */
    matvec_parts((void *)sb, x, y);
    return;
  }
  if (sb->kc) {
    free_rows(sb, -1, x, y, 0, sb->nf);
    return;
  }
  memset(y, 0, (size_t)sb->nf * sizeof(double));
  for (int j = 0; j < sb->nf; j++)
    for (int q = sb->Ap[j]; q < sb->Ap[j + 1]; q++)
      y[sb->Ai[q]] += sb->Ax[q] * x[j];
}

const double *mrvi_sblock_values(const mrvi_sblock *sb, long *nnz) {
  *nnz = sb->kc ? 0 : sb->nnz;
  return sb->kc ? NULL : sb->Ax;
}

long mrvi_sblock_map_ints(const mrvi_sblock *sb) { return sb->n_map; }

/* Matrix-free: rows [f0, f1) of y = J x, those of part c (c < 0: every
 * record, all rows): the records' blocks at z on the part's columns, in
 * the records' order, then the rows' M/dt x. */
static void free_y(const mrvi_sblock *sb, int c, const double *x, double *y,
                   int f0, int f1) {
  memset(y + f0, 0, (size_t)(f1 - f0) * sizeof(double));
  mrvi_terms_hessvec_part(sb->kc, c, sb->z, x, y, sb->hs);
  const double ms = sb->mscale, *md = sb->mdiag;
  const size_t inc = (size_t)sb->minc;
  if (ms != 0.0)
    for (int f = f0; f < f1; f++)
      y[f] += ms * md[f * inc] * x[f];
}

/* Whether a product on the parts takes free_y whole first (kc not in the
 * block's parts). */
static int free_whole(const mrvi_sblock *sb) { return sb->kc && !sb->kc_parts; }

/* free_y and the rows' x.y. */
static double free_rows(const mrvi_sblock *sb, int c, const double *x,
                        double *y, int f0, int f1) {
  free_y(sb, c, x, y, f0, f1);
  double xy = 0.0;
  for (int f = f0; f < f1; f++)
    xy += x[f] * y[f];
  return xy;
}

/* Rows [f0, f1) of y = J x in row form (row f's entries are column f's,
 * the pattern symmetric: J^T x, which is J x to round-off, the values
 * symmetric to round-off), each row one sum in the order of its columns;
 * returns their x.y.  Matrix-free: part c's (free_rows). */
static double rows_product(const mrvi_sblock *sb, int c, const double *x,
                           double *y, int f0, int f1) {
  if (sb->kc && !sb->kc_parts) { /* (y formed whole: free_whole) */
    double xy = 0.0;
    for (int f = f0; f < f1; f++)
      xy += x[f] * y[f];
    return xy;
  }
  if (sb->kc)
    return free_rows(sb, c, x, y, f0, f1);
  const int *Ap = sb->Ap, *Ai = sb->Ai;
  const double *Ax = sb->Ax;
  double xy = 0.0;
  for (int f = f0; f < f1; f++) {
    double s = 0.0;
    for (int q = Ap[f]; q < Ap[f + 1]; q++)
      s += Ax[q] * x[Ai[q]];
    y[f] = s;
    xy += x[f] * s;
  }
  return xy;
}

/* The CG's product on threads (mrvi_sblock_set_parts): the parts' rows
 * and sums, the sums added in the parts' order, so every number of
 * threads gives the same bits (not the serial scatter's). */
static double matvec_parts(void *ctx, const double *x, double *y) {
  mrvi_sblock *sb = ctx;
  const int nf = sb->nf, n_part = sb->n_part;
  if (free_whole(sb))
    free_y(sb, -1, x, y, 0, nf);
  MRVI_PARALLEL_FOR(sb->threads)
  for (int c = 0; c < n_part; c++)
    sb->psum[PSUM_STRIDE * c] =
        rows_product(sb, c, x, y, mrvi_part_start(c, nf, n_part),
                     mrvi_part_start(c + 1, nf, n_part));
  double xy = 0.0;
  for (int c = 0; c < n_part; c++)
    xy += sb->psum[PSUM_STRIDE * c];
  return xy;
}

static double matvec(void *ctx, const double *x, double *y) {
  const mrvi_sblock *sb = ctx;
  if (sb->kc)
    return free_rows(sb, -1, x, y, 0, sb->nf);
  memset(y, 0, (size_t)sb->nf * sizeof(double));
  for (int j = 0; j < sb->nf; j++) {
    const double xj = x[j];
    for (int q = sb->Ap[j]; q < sb->Ap[j + 1]; q++)
      y[sb->Ai[q]] += sb->Ax[q] * xj;
  }
  double xy = 0.0;
  for (int i = 0; i < sb->nf; i++)
    xy += x[i] * y[i];
  return xy;
}

const mrvi_krylov_stats *mrvi_sblock_stats(const mrvi_sblock *sb) {
  return &sb->stats;
}

/* Matrix-free: rows [j0, j1) of mrvi_sblock_jacobi, part c's (c < 0:
 * all), the off-diagonal sums from the records at z into the CG's work
 * (idle after the solve): |own[0]| + |own[1]| + nbr, the assembled row's
 * absolute sum (mrvi_terms_offdiag_part; its own block's entries each the
 * assembled one bitwise, the sum's order the particle's then the
 * springs'), D^-1 the solve's (1 / J_ff, bitwise the assembled
 * block's). */
static void free_offdiag(const mrvi_sblock *sb, int c, int j0, int j1) {
  const int nf = sb->nf;
  double *const own[2] = {sb->work, sb->work + nf};
  for (int k = 0; k < 3; k++)
    memset(sb->work + (size_t)k * nf + j0, 0,
           (size_t)(j1 - j0) * sizeof(double));
  mrvi_terms_offdiag_part(sb->kc, c, sb->z, sb->hs, own,
                          sb->work + 2 * (size_t)nf);
}
static double free_jacobi(const mrvi_sblock *sb, int c, double *dinv, int j0,
                          int j1) {
  const int nf = sb->nf;
  const double *own[2] = {sb->work, sb->work + nf};
  const double *nbr = sb->work + 2 * (size_t)nf;
  if (!free_whole(sb) || sb->n_part == 0)
    free_offdiag(sb, c, j0, j1);
  double bound = 0.0;
  for (int j = j0; j < j1; j++) {
    if (sb->nonpos)
      return HUGE_VAL;
    const double off = fabs(own[0][j]) + fabs(own[1][j]) + nbr[j];
    dinv[j] = sb->dinv[j];
    bound = fmax(bound, off * dinv[j]);
  }
  return bound;
}

/* Columns [j0, j1) of mrvi_sblock_jacobi (part c; matrix-free:
 * free_jacobi). */
static double jacobi_columns(const mrvi_sblock *sb, int c, double *dinv, int j0,
                             int j1) {
  if (sb->kc)
    return free_jacobi(sb, c, dinv, j0, j1);
  double bound = 0.0;
  for (int j = j0; j < j1; j++) {
    const double d = sb->Ax[sb->diag[j]];
    if (!(d > 0.0))
      return HUGE_VAL;
    double off = 0.0; /* column j's off-diagonal sum: row j's (symmetric) */
    for (int q = sb->Ap[j]; q < sb->Ap[j + 1]; q++)
      if (q != sb->diag[j])
        off += fabs(sb->Ax[q]);
    dinv[j] = 1.0 / d;
    bound = fmax(bound, off * dinv[j]);
  }
  return bound;
}

/* (In parts: each column's arithmetic the serial loop's; the parts'
 * bounds, none NaN, combined by the same maximum: the serial bound.) */
double mrvi_sblock_jacobi(const mrvi_sblock *sb, double *dinv) {
  const int nf = sb->nf, n_part = sb->n_part;
  if (n_part == 0)
    return jacobi_columns(sb, -1, dinv, 0, nf);
  if (free_whole(sb)) /* (the sums whole first) */
    free_offdiag(sb, -1, 0, nf);
  MRVI_PARALLEL_FOR(sb->threads)
  for (int c = 0; c < n_part; c++)
    sb->psum[PSUM_STRIDE * c] =
        jacobi_columns(sb, c, dinv, mrvi_part_start(c, nf, n_part),
                       mrvi_part_start(c + 1, nf, n_part));
  double bound = 0.0;
  for (int c = 0; c < n_part; c++)
    bound = fmax(bound, sb->psum[PSUM_STRIDE * c]);
  return bound;
}

/* The parts' slots k of psum combined in the parts' order: their sum
 * (max = 0) or their maximum, a NaN kept (max = 1; mrvi_pcg's test). */
static double psum_combine(const double *psum, int n_part, int k, int max) {
  double v = 0.0;
  for (int c = 0; c < n_part; c++) {
    const double a = psum[PSUM_STRIDE * c + k];
    v = !max ? v + a : isnan(a) || a > v ? a : v;
  }
  return v;
}

/* mrvi_pcg on the parts (mrvi_sblock_set_parts) in one parallel region:
 * the same iteration, each vector loop (the start, the product, x and r
 * with ||r||_inf and r^T z, the next direction) in the parts' rows, their
 * sums per part and the parts' sums added in the parts' order by every
 * thread, so that every thread takes the same decisions and every number
 * of threads gives the same bits (those of per-part sums, not mrvi_pcg's
 * one sum).  Three barriers per iteration; before, the product was a
 * region of its own and the vector loops ran on one thread. */
static int pcg_parts(mrvi_sblock *sb, double *b, double rtol, double atol,
                     int max_it, int *iterations, double *curvature) {
  const int n = sb->nf, n_part = sb->n_part;
  const double *dinv = sb->dinv;
  double *x = sb->x, *r = sb->work, *p = sb->work + n;
  double *q = sb->work + 2 * (size_t)n, *ps = sb->psum;
  int status = MRVI_CG_MAXIT, its = 0;
#ifdef _OPENMP
#pragma omp parallel num_threads(sb->threads)
#endif
  {
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
    for (int c = 0; c < n_part; c++) {
      const int i1 = mrvi_part_start(c + 1, n, n_part);
      double bn = 0.0, rz = 0.0;
      for (int i = mrvi_part_start(c, n, n_part); i < i1; i++) {
        const double bi = b[i], a = fabs(bi);
        x[i] = 0.0;
        r[i] = bi;
        p[i] = dinv[i] * bi;
        rz += bi * p[i];
        bn = isnan(a) || a > bn ? a : bn;
      }
      ps[PSUM_STRIDE * c] = rz;
      ps[PSUM_STRIDE * c + 1] = bn;
    }
    double rz = psum_combine(ps, n_part, 0, 0);
    const double bn = psum_combine(ps, n_part, 1, 1);
    const double stop = fmax(atol, rtol * bn);
    int st = bn <= stop ? MRVI_CG_OK : MRVI_CG_MAXIT, k = 0;
    /* (slots: 0, 1 the start; 2 the product; 3, 4 the update: a slot is
     * written again only after a barrier that follows its reads) */
    for (k = 1; k <= max_it && st == MRVI_CG_MAXIT; k++) {
      if (free_whole(sb)) {
#ifdef _OPENMP
#pragma omp single
#endif
        free_y(sb, -1, p, q, 0, n);
      }
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
      for (int c = 0; c < n_part; c++)
        ps[PSUM_STRIDE * c + 2] =
            rows_product(sb, c, p, q, mrvi_part_start(c, n, n_part),
                         mrvi_part_start(c + 1, n, n_part));
      const double pq = psum_combine(ps, n_part, 2, 0);
      if (!(pq > 0.0)) {
        st = MRVI_CG_CURVATURE;
        break;
      }
      const double alpha = rz / pq;
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
      for (int c = 0; c < n_part; c++)
        mrvi_pcg_update(x, r, p, q, dinv, alpha, mrvi_part_start(c, n, n_part),
                        mrvi_part_start(c + 1, n, n_part),
                        &ps[PSUM_STRIDE * c + 3], &ps[PSUM_STRIDE * c + 4]);
      const double rn = psum_combine(ps, n_part, 3, 1);
      const double rz1 = psum_combine(ps, n_part, 4, 0);
      if (rn <= stop) {
        st = MRVI_CG_OK;
        break;
      }
      if (!isfinite(rn))
        break;
      const double beta = rz1 / rz;
      rz = rz1;
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
      for (int c = 0; c < n_part; c++) {
        const int i1 = mrvi_part_start(c + 1, n, n_part);
        for (int i = mrvi_part_start(c, n, n_part); i < i1; i++)
          p[i] = dinv[i] * r[i] + beta * p[i];
      }
    }
#ifdef _OPENMP
#pragma omp master
#endif
    {
      status = st;
      its = bn <= stop ? 0 : k > max_it ? max_it : k;
    }
  }
  *iterations = its;
  *curvature = 0.0;
  if (status == MRVI_CG_CURVATURE) {
    double pp = 0.0;
    for (int i = 0; i < n; i++)
      pp += p[i] * p[i];
    *curvature = psum_combine(ps, n_part, 2, 0) / pp;
  }
  return status;
}

/* Matrix-free: J assembled from the records at z (their blocks,
 * mrvi_terms_hessblocks, times hs) and M/dt into Ap, Ai, Ax (CSC, the
 * triplets summed by UMFPACK) for the LU fallback. */
static int free_assemble(mrvi_sblock *sb) {
  const int nf = sb->nf, dim = sb->dim;
  const long nbd = mrvi_terms_hessblocks_size(sb->kc);
  const int nr = nbd >= 0 ? (int)(nbd / (dim * (dim + 1) / 2)) : -1;
  const long nt = nf + 4L * dim * dim * (nr > 0 ? nr : 0);
  free(sb->Ap);
  free(sb->Ai);
  free(sb->Ax);
  sb->Ap = NULL;
  sb->Ai = NULL;
  sb->Ax = NULL;
  if (nr < 0 || nbd < 0 || nt > INT_MAX)
    return MRVI_ENOMEM;
  double *B = malloc((size_t)(nbd > 0 ? nbd : 1) * sizeof *B);
  int *ci = malloc((size_t)(2 * dim * nr + 1) * sizeof *ci);
  int *Ti = malloc((size_t)nt * 2 * sizeof *Ti);
  double *Tx = malloc((size_t)nt * sizeof *Tx);
  sb->Ap = malloc((size_t)(nf + 1) * sizeof(int));
  sb->Ai = malloc((size_t)nt * sizeof(int));
  sb->Ax = malloc((size_t)nt * sizeof(double));
  int st = MRVI_ENOMEM;
  if (!B || !ci || !Ti || !Tx || !sb->Ap || !sb->Ai || !sb->Ax)
    goto done;
  mrvi_terms_hessblocks(sb->kc, sb->z, B);
  int *cj = ci + (size_t)dim * nr, *Tj = Ti + nt, t = 0;
  if (mrvi_terms_hessblocks_springs(sb->kc, ci, cj) != nr)
    goto done;
  for (int f = 0; f < nf; f++, t++) {
    Ti[t] = Tj[t] = f;
    Tx[t] = sb->mscale * sb->mdiag[(size_t)f * (size_t)sb->minc];
  }
  const double *b = B;
  for (int r = 0; r < nr; r++, b += dim * (dim + 1) / 2) {
    double A[3][3];
    int e = 0;
    for (int i = 0; i < dim; i++)
      for (int j = i; j < dim; j++)
        A[i][j] = A[j][i] = sb->hs * b[e++];
    const int *pi = ci + r * dim, *pj = cj + r * dim;
    for (int i = 0; i < dim; i++)
      for (int j = 0; j < dim; j++) {
        const int two = pj[0] >= 0;
        const int rows[2] = {pi[i], two ? pj[i] : -1};
        const int cols[2] = {pi[j], two ? pj[j] : -1};
        for (int a = 0; a < 1 + two; a++)
          for (int c = 0; c < 1 + two; c++) {
            Ti[t] = rows[a];
            Tj[t] = cols[c];
            Tx[t++] = a == c ? A[i][j] : -A[i][j];
          }
      }
  }
  st = umfpack_di_triplet_to_col(nf, nf, t, Ti, Tj, Tx, sb->Ap, sb->Ai, sb->Ax,
                                 NULL) == UMFPACK_OK
           ? MRVI_OK
           : MRVI_ENOMEM;
done:
  free(B);
  free(ci);
  free(Ti);
  free(Tx);
  return st;
}

/* Relative CG tolerance besides the caller's absolute one (a share of the
 * Newton tolerance): reachable where that share is below round-off. */
#define SBLOCK_RTOL 1e-12

int mrvi_sblock_solve(mrvi_sblock *sb, const double *diag, int inc,
                      double dscale, double *b, double atol, char *msg,
                      size_t len) {
  const int nf = sb->nf;
  double *x = sb->x;
  if (sb->kc && sb->n_add != 1) {
    mrvi_fmt(msg, len,
             "matrix-free micro-step block: %d assemblies since the values "
             "were zeroed (one configuration is kept)",
             sb->n_add);
    return MRVI_EINVAL;
  }
  double *dg = sb->kc ? sb->dinv : sb->Ax;
  int nonpos = 0;
  for (int f = 0; f < nf; f++) {
    const double d = (dg[sb->kc ? f : sb->diag[f]] += dscale * diag[f * inc]);
    sb->dinv[f] = d > 0.0 ? 1.0 / d : 1.0;
    nonpos |= !(d > 0.0);
  }
  if (sb->kc) {
    sb->nonpos = nonpos;
    sb->mscale = dscale;
    sb->mdiag = diag;
    sb->minc = inc;
  }
  int it = 0;
  double curv = 0.0;
  const int max_it = nf < MRVI_CG_MAX_IT ? nf + 10 : MRVI_CG_MAX_IT;
  const int s = sb->n_part > 0
                    ? pcg_parts(sb, b, SBLOCK_RTOL, atol, max_it, &it, &curv)
                    : mrvi_pcg(nf, matvec, sb, sb->dinv, b, x, SBLOCK_RTOL,
                               atol, max_it, sb->work, &it, &curv);
  mrvi_krylov_stats *k = &sb->stats;
  k->cg_solves++;
  k->cg_iterations += it;
  if (it > k->cg_max)
    k->cg_max = it;
  if (s == MRVI_CG_OK) {
    memcpy(b, x, (size_t)nf * sizeof(double));
    return MRVI_OK;
  }
  /* Fallback: sparse LU of the block. */
  if (k->fallbacks++ == 0) {
    if (s == MRVI_CG_CURVATURE)
      mrvi_fmt(k->fallback_reason, sizeof k->fallback_reason,
               "non-positive curvature p^T J p / p^T p = %.3e of the "
               "micro-step Newton matrix J = M/dt + w cA cB hess W (the fast "
               "potential's negative curvature outweighs M/dt; a smaller "
               "micro step restores CG): sparse LU of the %d x %d block",
               curv, nf, nf);
    else
      mrvi_fmt(k->fallback_reason, sizeof k->fallback_reason,
               "CG on the micro-step Newton matrix did not converge in %d "
               "iterations: sparse LU of the %d x %d block",
               it, nf, nf);
  }
  if (sb->kc) { /* (assembled from the records, analysed afresh) */
    mrvi_newton_free(sb->lu);
    sb->lu = NULL;
    const int a = free_assemble(sb);
    if (a < 0) {
      mrvi_fmt(msg, len,
               "out of memory for the LU fallback of the %d x %d "
               "micro-step block",
               nf, nf);
      return a;
    }
  }
  if (!sb->lu && !(sb->lu = mrvi_newton_create(nf, sb->Ap, sb->Ai, sb->Ax,
                                               sb->dense_max, msg, len)))
    return MRVI_ESINGULAR;
  const int r = mrvi_newton_solve(sb->lu, sb->Ax, b, x, msg, len);
  if (r < 0) {
    const size_t used = strlen(msg);
    mrvi_fmt(msg + used, len - used, " (micro-step block, after %s)",
             s == MRVI_CG_CURVATURE ? "non-positive curvature in CG"
                                    : "CG did not converge");
    return r;
  }
  memcpy(b, x, (size_t)nf * sizeof(double));
  return MRVI_OK;
}
