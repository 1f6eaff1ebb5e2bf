/* The chain elimination of schur-bordered: a constrained step whose model
 * is a chain or a tree of couplings, eliminated block by block along it.
 *
 * The model's coordinates are the vertices of its coupling graph (an
 * element or a constraint joins each pair of its inputs).  A breadth-first
 * search from a pseudo-peripheral vertex (George and Liu, "Computer
 * Solution of Large Sparse Positive Definite Systems", 1981, sec. 4.3)
 * numbers them by levels, and a coupling joins the same or adjacent
 * levels.  Consecutive levels are merged into blocks of at least
 * CHAIN_BLOCK_MIN unknowns of the step, every step unknown goes to the block
 * of its coordinate (a slow one: one unknown, a fast one: p, one per micro
 * node), and a constraint's multipliers and equations to the last block of
 * its inputs.  The step's Newton matrix J (doc/constraints.md: the
 * multiplier form, step.h's layout) is then block tridiagonal,
 *
 *     J = [ J_00 J_01           ]     U_0 = J_00,
 *         [ J_10 J_11 J_12      ]     X_k = U_k^-1 J_k,k+1,
 *         [      J_21 J_22 ...  ]     U_k+1 = J_k+1,k+1 - J_k+1,k X_k,
 *
 * factorised as above with dense LU and partial pivoting in the blocks U_k
 * (X_k kept on the columns of block k+1 that J_k,k+1 has an entry in), in
 * O(sum_k b_k^3) flops: linear in the length of a chain or a tree of
 * bounded width, where schur-bordered's node blocks (the slow block of all
 * links: bordered.c) grow as its cube and the general path's sparse LU
 * pays UMFPACK's overheads (doc/performance/chains.md, "Chains: the chain
 * elimination").  The transposed step (the optimal-control adjoint's,
 * src/ocp/adjoint.c) is solved with the same factors, the two block sweeps
 * transposed and run in the other order (mrvi_chain_solve_transpose).
 * The multipliers of a block come after the coordinates
 * of their inputs (in it or in the block before), so a leading block of
 * the saddle-point matrix holds every coordinate its multipliers act on.
 *
 * A model whose constraints close a loop (a constraint joins two particles
 * or bodies that other constraints join already: the cut joints of
 * doc/multibody.md) keeps its path, as is one whose blocks exceed
 * chain_block_max (mrvi.h, MRVI_TUNING_LIST; 0: off). */
#include "solver/solver.h"

#include <stdlib.h>
#include <string.h>

/* Merged levels reach at least this many step unknowns: a block's LU costs
 * its cube, so small levels are merged and the others kept (a level of the
 * rod chain at p = 10 holds 23: merged in pairs at 24, 1.15-1.2x slower
 * at 300 links than alone). */
enum { CHAIN_BLOCK_MIN = 12 };

struct mrvi_chain {
  int n, nb;           /* step unknowns, blocks */
  int *blk, *pos;      /* block of unknown i and its index in it */
  int *bo, *bs;        /* block k: first unknown (permuted), size */
  int *cn, *co, *cpos; /* J_k,k+1's column count, offset into ccol, and
                        * for each unknown of block k+1, its column of
                        * X_k or -1 */
  int *ccol, *cur;
  size_t *uo, *xo; /* offsets of U_k and X_k in buf */
  int *piv, *nzc;
  /* CSC entries: into U_k (dq, dd), into X_k (xq, xd), and of J_k+1,k
   * (lq by block k from lp: row, column in their blocks lr, lc) */
  int *dq, *xq, *lq, *lp, *lr, *lc;
  size_t *dd, *xd;
  int *dp, *xp; /* the entries into U_k and X_k: dq, xq from dp[k], xp[k] */
  int nd, nx;
  double *lv; /* J_k+1,k's values at the last factorisation (by lq) */
  double *buf, *y;
  size_t n_buf;
};

void mrvi_chain_free(mrvi_chain *ch) {
  if (!ch)
    return;
  free(ch->blk), free(ch->dq), free(ch->bo), free(ch->bs);
  free(ch->cn), free(ch->co), free(ch->uo), free(ch->xo), free(ch->lp);
  free(ch->dd), free(ch->xd), free(ch->buf), free(ch->y);
  free(ch->ccol), free(ch->cur), free(ch->lv), free(ch->dp);
  free(ch);
}

/* The coupling graph of m's coordinates in CSR (adjacency with repeats). */
static int graph(const mrvi_model *m, int **gp, int **gi) {
  const int n = m->n;
  int *p = calloc((size_t)n + 2, sizeof *p), *deg = p + 1;
  if (!p)
    return MRVI_ENOMEM;
  mrvi_element_buf eb = {.e.proto = NULL}; /* (one view reused; in points
                                              into it) */
  for (int pass = 0; pass < 2; pass++) {
    int *g = pass ? *gi : NULL;
    for (int e = 0; e < m->n_elements + m->n_constraints; e++) {
      const int *in;
      int k;
      if (e < m->n_elements) {
        const mrvi_element *el = mrvi_model_element(m, e, &eb);
        if (el->kind == MRVI_ELEMENT_GRAVITY || el->kind == MRVI_ELEMENT_FORCE)
          continue;
        in = el->in, k = el->n_in;
      } else {
        in = m->constraints[e - m->n_elements].in;
        k = m->constraints[e - m->n_elements].n_in;
      }
      for (int a = 0; a < k; a++)
        for (int b = 0; b < k; b++)
          if (in[a] != in[b]) {
            if (pass)
              g[p[in[a]]++] = in[b];
            else
              deg[in[a]]++;
          }
    }
    if (!pass) {
      for (int i = 0; i < n; i++)
        p[i + 1] += p[i];
      *gi = malloc(((size_t)p[n] + 1) * sizeof **gi);
      if (!*gi) {
        free(p);
        return MRVI_ENOMEM;
      }
    } else {
      for (int i = n; i > 0; i--)
        p[i] = p[i - 1];
      p[0] = 0;
    }
  }
  *gp = p;
  return MRVI_OK;
}

/* Breadth-first levels of the component of s (lev: -1 where unvisited,
 * set from base; the vertices in q); returns the count and the last
 * vertex of least degree in *far. */
static int bfs(const int *gp, const int *gi, int s, int base, int *lev, int *q,
               int *far) {
  int h = 0, t = 0;
  q[t++] = s, lev[s] = base;
  while (h < t) {
    const int v = q[h++];
    for (int e = gp[v]; e < gp[v + 1]; e++)
      if (lev[gi[e]] < 0)
        lev[gi[e]] = lev[v] + 1, q[t++] = gi[e];
  }
  *far = q[t - 1];
  for (int k = t - 1; k >= 0 && lev[q[k]] == lev[q[t - 1]]; k--)
    if (gp[q[k] + 1] - gp[q[k]] < gp[*far + 1] - gp[*far])
      *far = q[k];
  return t;
}

int mrvi_chain_levels(const mrvi_model *m, int *level) {
  const int n = m->n;
  int *gp = NULL, *gi = NULL;
  if (graph(m, &gp, &gi) < 0)
    return MRVI_ENOMEM;
  int *q = malloc(((size_t)n + 1) * sizeof *q),
      *up = malloc(((size_t)n + 1) * sizeof *up),
      *par = malloc(((size_t)n + 1) * sizeof *par);
  if (!q || !up || !par) {
    free(gp), free(gi), free(q), free(up), free(par);
    return MRVI_ENOMEM;
  }
  for (int i = 0; i < n; i++)
    level[i] = -1;
  int base = 0, tree = 1;
  for (int s0 = 0; s0 < n; s0++) {
    if (level[s0] >= 0)
      continue;
    /* a pseudo-peripheral start: the far end of the search, while the
     * depth grows (at most a few times) */
    int s = s0, far, depth = -1;
    for (int it = 0; it < 4; it++) {
      const int t = bfs(gp, gi, s, 0, level, q, &far);
      const int d = level[q[t - 1]];
      for (int k = 0; k < t; k++)
        level[q[k]] = -1;
      if (d <= depth)
        break;
      depth = d, s = far;
    }
    const int t = bfs(gp, gi, s, base, level, q, &far);
    base = level[q[t - 1]] + 1;
  }
  /* A closed loop: a constraint joins two objects (particles and bodies,
   * each its coordinates; the union-find up) already joined by others. */
  for (int i = 0; i < n; i++)
    up[i] = i, par[i] = i;
  for (int k = 0; k < m->n_particles; k++)
    for (int d = 1; d < m->dimension; d++)
      par[mrvi_particle_first(m, k) + d] = mrvi_particle_first(m, k);
  for (int k = 0; k < m->n_bodies; k++) {
    const mrvi_body *bo = &m->bodies[k];
    for (int d = 1; d < bo->dim * (bo->dim + 1); d++)
      par[bo->first + d] = bo->first;
  }
  for (int c = 0; c < m->n_constraints && tree; c++) {
    if (m->constraints[c].n_in < 1)
      continue;
    const mrvi_constraint *ct = &m->constraints[c];
    const int o = par[ct->in[0]];
    for (int i = 1; i < ct->n_in && tree; i++) {
      const int oi = par[ct->in[i]];
      int seen = oi == o; /* an object this constraint touched before */
      for (int j = 1; j < i && !seen; j++)
        seen = par[ct->in[j]] == oi;
      if (seen)
        continue;
      const int ra = mrvi_uf_root(up, o), rb = mrvi_uf_root(up, oi);
      if (ra == rb)
        tree = 0;
      else
        up[ra] = rb;
    }
  }
  free(gp), free(gi), free(q), free(up), free(par);
  return tree ? base : 0;
}

/* The level of each constraint: the last of its inputs'. */
static int constraint_level(const mrvi_model *m, const int *level, int c) {
  int l = 0;
  for (int i = 0; i < m->constraints[c].n_in; i++)
    if (level[m->constraints[c].in[i]] > l)
      l = level[m->constraints[c].in[i]];
  return l;
}

int mrvi_chain_blocks(const mrvi_model *m, int p, int *blk, int *width) {
  const int n = m->n;
  int *lw = NULL;
  const int nl = mrvi_chain_levels(m, blk);
  if (nl <= 0)
    return nl;
  lw = calloc((size_t)nl + 1, sizeof *lw);
  if (!lw)
    return MRVI_ENOMEM;
  for (int i = 0; i < n; i++)
    lw[blk[i]] += m->rate[i] == MRVI_SLOW ? 1 : p;
  for (int c = 0; c < m->n_constraints; c++)
    lw[constraint_level(m, blk, c)] +=
        m->constraints[c].rows * (m->constraints[c].where == MRVI_SLOW ? 1 : p);
  /* level l -> block lw[l] (merged while below CHAIN_BLOCK_MIN) */
  int nb = 0, w = 0, wmax = 0;
  for (int l = 0; l < nl; l++) {
    w += lw[l];
    lw[l] = nb;
    if (w >= CHAIN_BLOCK_MIN || l == nl - 1) {
      wmax = w > wmax ? w : wmax;
      nb++, w = 0;
    }
  }
  for (int i = 0; i < n; i++)
    blk[i] = lw[blk[i]];
  free(lw);
  *width = wmax;
  return nb;
}

/* Whether schur-bordered's dense blocks are beyond their limits
 * (bordered_max, bordered_node_max) on m's constrained step with the chain
 * elimination on (chain_block_max > 0): the cheap part of the choice. */
static int beyond_dense(const mrvi_model *m, const mrvi_tuning *t) {
  int rs = 0, rf = 0;
  for (int c = 0; c < m->n_constraints; c++)
    *(m->constraints[c].where == MRVI_SLOW ? &rs : &rf) +=
        m->constraints[c].rows;
  const int bmax = t->bordered_max, nmax = t->bordered_node_max;
  const int beyond = rf == 0 ? m->n_slow > bmax || m->n_fast > bmax || rs > bmax
                             : m->n_slow + rs > nmax || m->n_fast + rf > nmax;
  return beyond && t->chain_block_max > 0 && m->n_constraints > 0;
}

/* mrvi_chain_wanted with m's blocks in blk (m->n; set where it returns
 * 1). */
static int chain_fits(const mrvi_model *m, int p, const mrvi_tuning *t,
                      int *blk, int *n_blocks, int *width) {
  const int nb = mrvi_chain_blocks(m, p, blk, width);
  if (nb < 0)
    return nb;
  *n_blocks = nb;
  return nb >= 2 && *width <= t->chain_block_max;
}

int mrvi_chain_wanted(const mrvi_model *m, int p, const mrvi_tuning *t,
                      int *n_blocks, int *width) {
  *n_blocks = *width = 0;
  if (!beyond_dense(m, t))
    return 0;
  int *blk = malloc(((size_t)m->n + 1) * sizeof *blk);
  if (!blk)
    return MRVI_ENOMEM;
  const int s = chain_fits(m, p, t, blk, n_blocks, width);
  free(blk);
  return s;
}

/* The block of every step unknown (step.h's layout). */
static int step_blocks(mrvi_chain *ch, const mrvi_step *st, const int *mb) {
  const mrvi_model *m = st->model;
  const int ns = st->ns, nf = st->nf, nu = st->n_unknowns, p = st->p;
  const int rs = st->r_slow, rf = st->r_micro;
  for (int i = 0; i < ns; i++)
    ch->blk[i] = mb[m->slow_index[i]];
  for (int i = ns; i < nu; i++)
    ch->blk[i] = mb[m->fast_index[(i - ns) % nf]];
  for (int k = 0; k < st->n_slow_c + st->n_micro_c; k++) {
    const int slow = k < st->n_slow_c;
    const int c = slow ? st->slow_c[k] : st->micro_c[k - st->n_slow_c];
    const int b = constraint_level(m, mb, c);
    for (int r = 0; r < m->constraints[c].rows; r++) {
      const int o = st->c_off[c] + r;
      if (slow)
        ch->blk[nu + o] = b;
      else
        for (int j = 0; j < p; j++)
          ch->blk[nu + rs + j * rf + o] = b;
    }
  }
  return MRVI_OK;
}

int mrvi_chain_create(const mrvi_step *st, mrvi_chain **out) {
  *out = NULL;
  const mrvi_model *m = st->model;
  if (!beyond_dense(m, &st->tuning))
    return MRVI_OK;
  const int n = st->n_total, *Ap = st->Ap, *Ai = st->Ai, nnz = Ap[n];
  mrvi_chain *ch = calloc(1, sizeof *ch);
  int *mb = malloc(((size_t)m->n + 1) * sizeof *mb);
  if (!ch || !mb) {
    free(mb), free(ch);
    return MRVI_ENOMEM;
  }
  int width = 0, s = MRVI_OK;
  ch->n = n;
  const int fits = chain_fits(m, st->p, &st->tuning, mb, &ch->nb, &width);
  if (fits <= 0) { /* (not a chain within the limits: none, MRVI_OK) */
    free(mb), mrvi_chain_free(ch);
    return fits;
  }
  const int nb = ch->nb;
  const size_t N = (size_t)n + 1, B = (size_t)nb + 1;
  /* the int arrays of n (blk, pos, cpos, piv, nzc) and of the entries
   * (dq, xq, lq, lr, lc) in two allocations, blk and dq */
  const size_t Z = (size_t)nnz + 1;
  ch->blk = malloc(5 * N * sizeof *ch->blk);
  ch->dq = malloc(5 * Z * sizeof *ch->dq);
  if (ch->blk && ch->dq) {
    ch->pos = ch->blk + N, ch->cpos = ch->pos + N, ch->piv = ch->cpos + N;
    ch->nzc = ch->piv + N;
    ch->xq = ch->dq + Z, ch->lq = ch->xq + Z, ch->lr = ch->lq + Z;
    ch->lc = ch->lr + Z;
  }
  ch->y = malloc(N * sizeof *ch->y);
  ch->bo = calloc(B + 1, sizeof *ch->bo);
  ch->bs = calloc(B, sizeof *ch->bs);
  ch->cn = calloc(B, sizeof *ch->cn);
  ch->co = calloc(B, sizeof *ch->co);
  ch->uo = calloc(B, sizeof *ch->uo);
  ch->xo = calloc(B, sizeof *ch->xo);
  ch->lp = calloc(B + 1, sizeof *ch->lp);
  ch->dp = calloc(2 * (B + 1), sizeof *ch->dp);
  ch->dd = malloc(Z * sizeof *ch->dd);
  ch->xd = malloc(Z * sizeof *ch->xd);
  if (!ch->blk || !ch->dq || !ch->y || !ch->bo || !ch->bs || !ch->cn ||
      !ch->co || !ch->uo || !ch->xo || !ch->lp || !ch->dp || !ch->dd ||
      !ch->xd) {
    s = MRVI_ENOMEM;
    goto done;
  }
  step_blocks(ch, st, mb);
  /* positions in the blocks, in index order */
  for (int i = 0; i < n; i++)
    ch->pos[i] = ch->bs[ch->blk[i]]++;
  for (int k = 0; k < nb; k++)
    ch->bo[k + 1] = ch->bo[k] + ch->bs[k];
  /* the columns of block k+1 with an entry in a row of block k: X_k's */
  for (int i = 0; i < n; i++)
    ch->cpos[i] = -1;
  for (int j = 0; j < n; j++)
    for (int q = Ap[j]; q < Ap[j + 1]; q++) {
      const int bi = ch->blk[Ai[q]], bj = ch->blk[j];
      if (bj > bi + 1 || bi > bj + 1) {
        s = MRVI_EINVAL; /* outside the block tridiagonal structure */
        goto done;
      }
      if (bj == bi + 1 && ch->cpos[j] < 0)
        ch->cpos[j] = ch->cn[bi]++;
    }
  /* X_k's column t is unknown ccol[co[k] + t] of block k+1 (its index) */
  for (int k = 0; k + 1 < nb; k++)
    ch->co[k + 1] = ch->co[k] + ch->cn[k];
  ch->ccol = malloc(N * sizeof *ch->ccol);
  if (!ch->ccol) {
    s = MRVI_ENOMEM;
    goto done;
  }
  for (int j = 0; j < n; j++)
    if (ch->cpos[j] >= 0)
      ch->ccol[ch->co[ch->blk[j] - 1] + ch->cpos[j]] = ch->pos[j];
  size_t off = 0;
  for (int k = 0; k < nb; k++) {
    const size_t b = (size_t)ch->bs[k];
    ch->uo[k] = off, off += b * b;
    ch->xo[k] = off, off += b * (size_t)ch->cn[k];
  }
  ch->n_buf = off;
  ch->buf = malloc((off + 1) * sizeof *ch->buf);
  ch->cur = malloc(B * sizeof *ch->cur);
  ch->lv = malloc(Z * sizeof *ch->lv);
  if (!ch->buf || !ch->cur || !ch->lv) {
    s = MRVI_ENOMEM;
    goto done;
  }
  /* the entries' destinations, listed by block (U_k's and X_k's by the
   * block of their row, so that mrvi_chain_factor fills a block just before
   * it eliminates it; J_k+1,k's by block k): counted, then placed with
   * cursors */
  ch->xp = ch->dp + B + 1;
  for (int j = 0; j < n; j++)
    for (int q = Ap[j]; q < Ap[j + 1]; q++) {
      const int bi = ch->blk[Ai[q]], bj = ch->blk[j];
      ch->dp[bi + 1] += bi == bj;
      ch->xp[bi + 1] += bj == bi + 1;
      ch->lp[bj + 1] += bi == bj + 1;
    }
  for (int pass = 0; pass < 2; pass++) {
    int *list = pass ? ch->dp : ch->xp;
    for (int k = 0; k < nb; k++)
      list[k + 1] += list[k];
    for (int k = nb; k > 0; k--) /* (cursors: list[k + 1] from list[k]) */
      list[k] = list[k - 1];
  }
  for (int k = 0; k < nb; k++)
    ch->lp[k + 1] += ch->lp[k], ch->cur[k] = ch->lp[k];
  for (int j = 0; j < n; j++)
    for (int q = Ap[j]; q < Ap[j + 1]; q++) {
      const int i = Ai[q], bi = ch->blk[i], bj = ch->blk[j];
      if (bi == bj) {
        const int e = ch->dp[bi + 1]++;
        ch->dq[e] = q;
        ch->dd[e] =
            ch->uo[bi] + (size_t)ch->pos[i] * (size_t)ch->bs[bi] + ch->pos[j];
      } else if (bj == bi + 1) {
        const int e = ch->xp[bi + 1]++;
        ch->xq[e] = q;
        ch->xd[e] = ch->xo[bi] + (size_t)ch->pos[i] * (size_t)ch->cn[bi] +
                    (size_t)ch->cpos[j];
      } else {
        const int e = ch->cur[bj]++;
        ch->lq[e] = q, ch->lr[e] = ch->pos[i], ch->lc[e] = ch->pos[j];
      }
    }
  ch->nd = ch->dp[nb], ch->nx = ch->xp[nb];
done:
  free(mb);
  if (s < 0) {
    mrvi_chain_free(ch);
    return s;
  }
  *out = ch;
  return MRVI_OK;
}

/* A factorisation's flops over a solve's: the blocks' LU (2 b^3 / 3), X_k
 * (2 b^2 c) and the Schur updates (2 c per entry of J_k+1,k) against the
 * forward sweep (2 b^2 and 2 per entry of J_k+1,k) and the backward one
 * (2 b c).  Fixed by the pattern (not by a clock): the policy built on it
 * gives the same iterates on every run. */
double mrvi_chain_factor_ratio(const mrvi_chain *ch) {
  double f = 0.0, s = 0.0;
  for (int k = 0; k < ch->nb; k++) {
    const double b = ch->bs[k], c = k + 1 < ch->nb ? ch->cn[k] : 0.0,
                 l = k + 1 < ch->nb ? ch->lp[k + 1] - ch->lp[k] : 0.0;
    f += 2.0 * b * b * b / 3.0 + 2.0 * b * b * c + 2.0 * l * c;
    s += 2.0 * b * b + 2.0 * l + 2.0 * b * c;
  }
  return s > 0.0 ? f / s : 0.0;
}

/* U_k and X_k (adjacent in buf) from the entries of block k. */
static void fill(mrvi_chain *ch, const double *Ax, int k) {
  const size_t end = k + 1 < ch->nb ? ch->uo[k + 1] : ch->n_buf;
  memset(ch->buf + ch->uo[k], 0, (end - ch->uo[k]) * sizeof *ch->buf);
  for (int e = ch->dp[k]; e < ch->dp[k + 1]; e++)
    ch->buf[ch->dd[e]] = Ax[ch->dq[e]];
  for (int e = ch->xp[k]; e < ch->xp[k + 1]; e++)
    ch->buf[ch->xd[e]] = Ax[ch->xq[e]];
}

int mrvi_chain_factor(mrvi_chain *ch, const double *Ax) {
  for (int e = 0; e < ch->lp[ch->nb]; e++)
    ch->lv[e] = Ax[ch->lq[e]];
  fill(ch, Ax, 0);
  for (int k = 0; k < ch->nb; k++) {
    const int b = ch->bs[k];
    double *U = ch->buf + ch->uo[k], *X = ch->buf + ch->xo[k];
    const int *piv = ch->piv + ch->bo[k];
    if (mrvi_dense_lu_factor_nz(b, U, ch->piv + ch->bo[k], ch->nzc) < 0)
      return MRVI_ESINGULAR;
    if (k + 1 == ch->nb)
      break;
    const int c = ch->cn[k], b1 = ch->bs[k + 1];
    const int *col = ch->ccol + ch->co[k];
    mrvi_dense_lu_solve(b, U, piv, X, c);
    fill(ch, Ax, k + 1);
    /* U_k+1 -= J_k+1,k X_k on X_k's columns */
    double *U1 = ch->buf + ch->uo[k + 1];
    for (int e = ch->lp[k]; e < ch->lp[k + 1]; e++) {
      const double a = ch->lv[e];
      if (a == 0.0)
        continue;
      double *u = U1 + (size_t)ch->lr[e] * (size_t)b1;
      const double *x = X + (size_t)ch->lc[e] * (size_t)c;
      for (int t = 0; t < c; t++)
        u[col[t]] -= a * x[t];
    }
  }
  return MRVI_OK;
}

void mrvi_chain_solve(const mrvi_chain *ch, const double *R, double *dx) {
  const int n = ch->n, nb = ch->nb;
  double *y = ch->y;
  for (int i = 0; i < n; i++)
    y[ch->bo[ch->blk[i]] + ch->pos[i]] = R[i];
  /* v_k = U_k^-1 (R_k - J_k,k-1 v_k-1) */
  for (int k = 0; k < nb; k++) {
    double *yk = y + ch->bo[k];
    if (k > 0) {
      const double *yp = y + ch->bo[k - 1];
      for (int e = ch->lp[k - 1]; e < ch->lp[k]; e++)
        yk[ch->lr[e]] -= ch->lv[e] * yp[ch->lc[e]];
    }
    mrvi_dense_lu_solve(ch->bs[k], ch->buf + ch->uo[k], ch->piv + ch->bo[k], yk,
                        1);
  }
  /* x_k = v_k - X_k x_k+1 (X_k's columns) */
  for (int k = nb - 2; k >= 0; k--) {
    double *yk = y + ch->bo[k];
    const double *y1 = y + ch->bo[k + 1], *X = ch->buf + ch->xo[k];
    const int c = ch->cn[k], *col = ch->ccol + ch->co[k];
    for (int i = 0; i < ch->bs[k]; i++) {
      double acc = 0.0;
      for (int t = 0; t < c; t++)
        acc += X[(size_t)i * (size_t)c + (size_t)t] * y1[col[t]];
      yk[i] -= acc;
    }
  }
  for (int i = 0; i < n; i++)
    dx[i] = y[ch->bo[ch->blk[i]] + ch->pos[i]];
}

/* J = L U with L block lower bidiagonal (U_k on the diagonal, J_k+1,k
 * below it) and U block upper bidiagonal (identities, X_k beside them), so
 * J^T = U^T L^T: w_k+1 = R_k+1 - X_k^T w_k forwards, then
 * x_k = U_k^-T (w_k - J_k+1,k^T x_k+1) backwards, with the same factors;
 * the nrhs right-hand sides interleaved in y (entry i of right-hand side
 * c at y[i nrhs + c]), each one's operations in the same order as alone
 * (a row of X_k^T skipped where w is zero in every one). */
void mrvi_chain_solve_transpose_n(const mrvi_chain *ch, int nrhs,
                                  const double *R, double *dx, double *y) {
  const int n = ch->n, nb = ch->nb;
  const size_t m = (size_t)nrhs;
  for (int i = 0; i < n; i++)
    for (size_t c = 0; c < m; c++)
      y[(size_t)(ch->bo[ch->blk[i]] + ch->pos[i]) * m + c] =
          R[c * (size_t)n + (size_t)i];
  for (int k = 0; k + 1 < nb; k++) {
    const double *yk = y + (size_t)ch->bo[k] * m, *X = ch->buf + ch->xo[k];
    double *y1 = y + (size_t)ch->bo[k + 1] * m;
    const int cn = ch->cn[k], *col = ch->ccol + ch->co[k];
    for (int i = 0; i < ch->bs[k]; i++) {
      const double *w = yk + (size_t)i * m;
      size_t nz = 0;
      for (size_t c = 0; c < m; c++)
        nz += w[c] != 0.0;
      if (!nz)
        continue;
      const double *xi = X + (size_t)i * (size_t)cn;
      for (int t = 0; t < cn; t++) {
        double *yt = y1 + (size_t)col[t] * m;
        for (size_t c = 0; c < m; c++)
          yt[c] -= xi[t] * w[c];
      }
    }
  }
  for (int k = nb - 1; k >= 0; k--) {
    double *yk = y + (size_t)ch->bo[k] * m;
    if (k + 1 < nb) {
      const double *y1 = y + (size_t)ch->bo[k + 1] * m;
      for (int e = ch->lp[k]; e < ch->lp[k + 1]; e++) {
        double *a = yk + (size_t)ch->lc[e] * m;
        const double *b = y1 + (size_t)ch->lr[e] * m;
        for (size_t c = 0; c < m; c++)
          a[c] -= ch->lv[e] * b[c];
      }
    }
    mrvi_dense_lu_solve_transpose(ch->bs[k], ch->buf + ch->uo[k],
                                  ch->piv + ch->bo[k], yk, nrhs);
  }
  for (int i = 0; i < n; i++)
    for (size_t c = 0; c < m; c++)
      dx[c * (size_t)n + (size_t)i] =
          y[(size_t)(ch->bo[ch->blk[i]] + ch->pos[i]) * m + c];
}

void mrvi_chain_solve_transpose(const mrvi_chain *ch, const double *R,
                                double *dx) {
  mrvi_chain_solve_transpose_n(ch, 1, R, dx, ch->y);
}
