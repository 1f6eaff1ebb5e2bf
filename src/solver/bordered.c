/* The `schur-bordered` path: constrained steps in the multiplier form by
 * block elimination of the step bordered by the constraint rows.
 *
 * The Newton matrix of a constrained step (doc/constraints.md) is
 *
 *     J = [ A  B ]   A: the n_unknowns rows and columns of x (with the
 *         [ C  E ]      constraint Hessians -h lambda^T hess g at the
 *                       unknown nodes), B: the multipliers' columns,
 *                       C: the constraint equations' gradients, E = 0,
 *
 * and A has the structure of an unconstrained step: a slow block coupled
 * to every micro node and a fast block lower-triangular by micro nodes
 * (row m: nodes m-2 .. m), which the schur path's block elimination
 * factors in O(p (n_f^3 + n_f^2 n_s) + n_s^3) (solver/blocks.c).
 *
 * Where every constraint is enforced at macro nodes only (slow
 * coordinates: B and C touch the slow unknowns alone, E = 0), the slow
 * block of A^-1 is S^-1, S the kept Schur complement of blocks.c, so with
 * z = A^-1 R_x and W = S^-1 B_s,
 *
 *     (-C_s W) dlambda = R_c - C z,   dx = A^-1 (R_x - B dlambda),
 *
 * a dense system of the r_s multipliers, n_lambda solves with S (n_s^2
 * each) and two block solves.
 *
 * With constraints at the micro nodes (step.h's layout), the multipliers
 * lambda^m of micro node m enter the fast row m (and the slow row) only,
 * and the equations g(z^{m+1}) involve the fast node m+1 (and the slow
 * unknowns, the slow coordinates interpolated) only.  So the node blocks
 *
 *     slow:     columns (q_{k+1}^s, lambda_k), rows (slow row, g(q_{k+1}^s))
 *     fast c:   columns (q^{f,c+1}, lambda^c), rows (fast row c, g(z^{c+1}))
 *
 * (c = 0 .. p-1; sizes n_s + r_s and n_f + r_f) keep the structure of an
 * unconstrained step: the fast block is block lower-triangular with three
 * block diagonals (column blocks c-2 .. c), each diagonal block a saddle
 * point [A_cc, -h G(z^c)^T; G(z^{c+1}), 0].  It is eliminated as the
 * schur path does (blocks.c), with dense LU and partial pivoting on the
 * node blocks:
 *
 *     Y_c = D_c^-1 (A_fs,c - L1_c Y_{c-1} - L2_c Y_{c-2})    (forward sweep)
 *     S = A_ss - sum_c A_sf,c Y_c,
 *
 * at O(p ((n_f + r_f)^3 + (n_f + r_f)^2 k) + (n_s + r_s)^3) per
 * factorisation: linear in p, where bordering A by all p r_f multipliers
 * cost p r_f block solves and a dense system of p r_f, cubic in p.  Here k
 * <= n_s + r_s counts the slow columns that A_fs has an entry in (at any
 * node): the sweep keeps the others of Y, zero by structure, out (on
 * systems/flexible_pendulum.yaml 6 of the slow block's 11, the arm's
 * coordinates, which the elbow reads, and not its multipliers), with the
 * same arithmetic on the kept ones.  The path
 * is chosen where n_s + r_s, n_f + r_f are at most bordered_node_max
 * (and, with constraints at macro nodes only, n_s, n_f, r_s at most
 * bordered_max: solver/sweep.c, mrvi_sweep_path); larger blocks keep the sparse
 * LU of the general path, whose fill on chains and trees grows linearly with
 * the length (doc/solver.md).  Where a node block is singular though the
 * step is not (micro-node constraints dependent through their fast
 * coordinates, allowed at p = 1), the path solves with the general path's LU
 * of the whole step from then on.  The Jacobian is the general path's (the CSC
 * assembled by step.c); a factorisation's iterate is the general path's up
 * to the round-off of the linear solve, and the integrator keeps the
 * factors for a step's later updates while they contract well
 * (mrvi_bordered_solve: simplified Newton, doc/solver.md, "Newton
 * details"). */
#include "solver/solver.h"

#include <stdlib.h>
#include <string.h>

struct mrvi_bordered {
  mrvi_blocks *blocks;
  int nu, nl;
  double *K;     /* nl x nl: -C_s W, then its LU (slow_only) */
  int *piv;      /* nl */
  double *r;     /* nl */
  double *dz;    /* nu */
  int slow_only; /* B, C on the slow unknowns only, E = 0 */
  int ns;
  double *W; /* ns x nl: S^-1 B_s (slow_only) */
  /* Node blocks (micro-node constraints): sizes a (slow) and b (fast),
   * p fast blocks; the block and offset of every row and column of J
   * (rblk, roff: node_of); the ka slow columns with an entry of A_fs
   * (ycol: the columns of Y); where each CSC entry
   * goes (dst, built at creation); the dense blocks (one allocation nbuf):
   * Ass (a x a), Asf (a x p b), Afs = Y (p b x ka), D, L1, L2 (p b x b each:
   * column blocks c, c-1, c-2 of row block c), S (a x a), z (p b + a). */
  int a, b, p, ka;
  int *rblk, *roff, *dpiv, *spiv, *ycol;
  /* The structure, listed once at creation: the entries of L1_c, L2_c
   * (rows li, columns lj, by rows; list 2 c + k - 1 from lp; its row i
   * from lr[(2 c + k - 1) (b + 1) + i]), of Asf
   * (columns sfj of slow row i from sfp[i]) and the kept slow columns kt
   * (ka: the column t of Y's r-th).  Workspace dnz (b) for the LU.  Of
   * those, the kv with a nonzero in A_fs at this factorisation (their slow
   * columns kvt), Y's columns at stride kv. */
  int *lp, *lr, *li, *lj, *sfp, *sfj, *kt, *dnz, *kvt, kv;
  /* The nonzeros of each factored D_c, listed after its factorisation
   * (lu_lists): per block 2 b + 1 offsets in fo (L's column k from
   * fo[k], U's row i without the diagonal from fo[b + i]) into the indices
   * fi (at most b^2 - b per block, from c b^2). */
  int *fo, *fi;
  double **dst;
  double *nbuf, *Ass, *Asf, *Y, *D, *L1, *L2, *S, *z;
  size_t n_nbuf;
  /* The LU of the whole step (the general path's), from the first node
   * block that is singular on: micro-node constraints dependent through
   * their fast coordinates (allowed at p = 1, doc/constraints.md) make the
   * saddle-point blocks singular while the step is not. */
  mrvi_newton *whole;
  int dense_max;
  /* The chain elimination (solver/chain.c) of the whole step, for chains
   * and trees beyond the dense blocks' limits (mrvi_chain_wanted). */
  mrvi_chain *chain;
  /* The node blocks beyond bordered_node_max, sparse
   * (solver/bordered_sparse.c; rblk, roff J's order within each block). */
  mrvi_nsparse *nsp;
};

void mrvi_bordered_free(mrvi_bordered *bd) {
  if (!bd)
    return;
  mrvi_blocks_free(bd->blocks);
  mrvi_newton_free(bd->whole);
  mrvi_chain_free(bd->chain);
  mrvi_nsparse_free(bd->nsp);
  free(bd->rblk);
  free(bd->roff);
  free(bd->dpiv);
  free(bd->spiv);
  free(bd->ycol);
  free(bd->lp);
  free(bd->lr);
  free(bd->li);
  free(bd->lj);
  free(bd->sfp);
  free(bd->sfj);
  free(bd->kt);
  free(bd->kvt);
  free(bd->dnz);
  free(bd->fo);
  free(bd->fi);
  free(bd->dst);
  free(bd->nbuf);
  free(bd->K);
  free(bd->piv);
  free(bd->r);
  free(bd->dz);
  free(bd->W);
  free(bd);
}

/* Node block and offset of row or column i of J (the same numbers: row
 * n_unknowns + r_s + (m-1) r_f + o, g(z^m), and column
 * n_unknowns + r_s + m' r_f + o, lambda^{m'}, both go to offset n_f + o of
 * fast block m - 1 = m'; block -1 the slow one). */
static void node_of(const mrvi_step *st, int i, int *blk, int *off) {
  const int ns = st->ns, nf = st->nf, nu = st->n_unknowns;
  const int rs = st->r_slow, rf = st->r_micro;
  if (i < ns) {
    *blk = -1, *off = i;
  } else if (i < nu) {
    *blk = (i - ns) / nf, *off = (i - ns) % nf;
  } else if (i < nu + rs) {
    *blk = -1, *off = ns + i - nu;
  } else {
    /* g(z^m), m = 1..p: block m - 1; lambda^m, m = 0..p-1: block m */
    *blk = (i - nu - rs) / rf, *off = nf + (i - nu - rs) % rf;
  }
}

/* The structure lists of bd (above) from the destinations of the CSC
 * entries: marked in the (zeroed) blocks, read off by rows, cleared. */
static int node_lists(mrvi_bordered *bd, const mrvi_step *st) {
  const int a = bd->a, b = bd->b, p = bd->p, nnz = st->Ap[st->n_total];
  const size_t pb = (size_t)p * (size_t)b, bb = (size_t)b * (size_t)b;
  bd->lp = malloc((2 * (size_t)p + 1) * sizeof *bd->lp);
  bd->lr = malloc((2 * (size_t)p * ((size_t)b + 1) + 1) * sizeof *bd->lr);
  bd->li = malloc(((size_t)nnz + 1) * sizeof *bd->li);
  bd->lj = malloc(((size_t)nnz + 1) * sizeof *bd->lj);
  bd->sfp = malloc(((size_t)a + 1) * sizeof *bd->sfp);
  bd->sfj = malloc(((size_t)nnz + 1) * sizeof *bd->sfj);
  bd->kt = malloc(((size_t)a + 1) * sizeof *bd->kt);
  bd->kvt = malloc(((size_t)a + 1) * sizeof *bd->kvt);
  bd->dnz = malloc(((size_t)b + 1) * sizeof *bd->dnz);
  if (!bd->lp || !bd->lr || !bd->li || !bd->lj || !bd->sfp || !bd->sfj ||
      !bd->kt || !bd->kvt || !bd->dnz)
    return MRVI_ENOMEM;
  for (int q = 0; q < nnz; q++)
    *bd->dst[q] = 1.0;
  int e = 0;
  for (int c = 0; c < p; c++)
    for (int k = 1; k <= 2; k++) {
      const double *L = (k == 1 ? bd->L1 : bd->L2) + (size_t)c * bb;
      int *lr = bd->lr + (size_t)(2 * c + k - 1) * ((size_t)b + 1);
      bd->lp[2 * c + k - 1] = e;
      for (int i = 0; i < b; i++) {
        lr[i] = e;
        for (int j = 0; j < b; j++)
          if (L[(size_t)i * b + j] != 0.0)
            bd->li[e] = i, bd->lj[e++] = j;
      }
      lr[b] = e;
    }
  bd->lp[2 * p] = e;
  e = 0;
  for (int i = 0; i < a; i++) {
    bd->sfp[i] = e;
    for (size_t j = 0; j < pb; j++)
      if (bd->Asf[(size_t)i * pb + j] != 0.0)
        bd->sfj[e++] = (int)j;
  }
  bd->sfp[a] = e;
  for (int t = 0; t < a; t++)
    if (bd->ycol[t] >= 0)
      bd->kt[bd->ycol[t]] = t;
  memset(bd->nbuf, 0, bd->n_nbuf * sizeof *bd->nbuf);
  return MRVI_OK;
}

/* The node blocks' workspaces and the destination of every CSC entry;
 * MRVI_EINVAL if an entry lies outside the structure (a fast row block
 * coupled to a column block after it or more than two before it). */
static int node_create(mrvi_bordered *bd, const mrvi_step *st) {
  const int n = st->n_total, p = st->p;
  bd->a = st->ns + st->r_slow, bd->b = st->nf + st->r_micro, bd->p = p;
  const size_t a = (size_t)bd->a, b = (size_t)bd->b, pb = (size_t)p * b;
  bd->rblk = malloc((size_t)n * sizeof *bd->rblk);
  bd->roff = malloc((size_t)n * sizeof *bd->roff);
  bd->dpiv = malloc((pb + 1) * sizeof *bd->dpiv);
  bd->spiv = malloc((a + 1) * sizeof *bd->spiv);
  bd->ycol = calloc(a + 1, sizeof *bd->ycol);
  bd->dst = malloc(((size_t)st->Ap[n] + 1) * sizeof *bd->dst);
  bd->fo = malloc(((size_t)p * (2 * b + 1) + 1) * sizeof *bd->fo);
  bd->fi = malloc((pb * b + 1) * sizeof *bd->fi);
  bd->n_nbuf = 2 * a * a + 2 * a * pb + 3 * pb * b + pb + a;
  bd->nbuf = calloc(bd->n_nbuf + 1, sizeof *bd->nbuf);
  if (!bd->rblk || !bd->roff || !bd->dpiv || !bd->spiv || !bd->ycol ||
      !bd->dst || !bd->fo || !bd->fi || !bd->nbuf)
    return MRVI_ENOMEM;
  bd->Ass = bd->nbuf;
  bd->Asf = bd->Ass + a * a;
  bd->Y = bd->Asf + a * pb;
  bd->D = bd->Y + pb * a;
  bd->L1 = bd->D + pb * b;
  bd->L2 = bd->L1 + pb * b;
  bd->S = bd->L2 + pb * b;
  bd->z = bd->S + a * a;
  for (int i = 0; i < n; i++) {
    node_of(st, i, &bd->rblk[i], &bd->roff[i]);
  }
  /* The offsets in the fast blocks ordered by their degrees in D's
   * pattern (rows and columns alike), as the general path's dense LU
   * orders its unknowns: the saddle-point blocks fill less. */
  int *deg = calloc(b + 1, sizeof *deg), *ord = malloc((b + 1) * sizeof *ord),
      *pos = malloc((b + 1) * sizeof *pos);
  if (!deg || !ord || !pos) {
    free(deg), free(ord), free(pos);
    return MRVI_ENOMEM;
  }
  for (int j = 0; j < n; j++)
    for (int q = st->Ap[j]; q < st->Ap[j + 1]; q++)
      if (mrvi_node_class(bd->rblk[st->Ai[q]], bd->rblk[j]) == MRVI_NODE_D)
        deg[bd->roff[st->Ai[q]]]++, deg[bd->roff[j]]++;
  mrvi_degree_order(bd->b, deg, ord, pos);
  for (int i = 0; i < n; i++)
    if (bd->rblk[i] >= 0)
      bd->roff[i] = pos[bd->roff[i]];
  free(deg), free(ord), free(pos);
  /* The columns of Y: the slow columns with an entry in a fast row (ycol
   * first marks them, then maps a column to its rank among them). */
  for (int j = 0; j < n; j++)
    for (int q = st->Ap[j]; q < st->Ap[j + 1]; q++)
      if (mrvi_node_class(bd->rblk[st->Ai[q]], bd->rblk[j]) == MRVI_NODE_FS)
        bd->ycol[bd->roff[j]] = 1;
  bd->ka = 0;
  for (int t = 0; t < bd->a; t++)
    bd->ycol[t] = bd->ycol[t] ? bd->ka++ : -1;
  const size_t ka = (size_t)bd->ka;
  for (int j = 0; j < n; j++)
    for (int q = st->Ap[j]; q < st->Ap[j + 1]; q++) {
      const int i = st->Ai[q], rb = bd->rblk[i], cb = bd->rblk[j];
      const size_t ro = (size_t)bd->roff[i], co = (size_t)bd->roff[j];
      const int cls = mrvi_node_class(rb, cb);
      double *d;
      switch (cls) {
      case MRVI_NODE_SS:
        d = bd->Ass + ro * a + co;
        break;
      case MRVI_NODE_SF:
        d = bd->Asf + ro * pb + (size_t)cb * b + co;
        break;
      case MRVI_NODE_FS:
        d = bd->Y + ((size_t)rb * b + ro) * ka + (size_t)bd->ycol[co];
        break;
      case MRVI_NODE_D:
      case MRVI_NODE_L1:
      case MRVI_NODE_L2:
        d = (cls == MRVI_NODE_D    ? bd->D
             : cls == MRVI_NODE_L1 ? bd->L1
                                   : bd->L2) +
            ((size_t)rb * b + ro) * b + co;
        break;
      default:
        return MRVI_EINVAL;
      }
      bd->dst[q] = d;
    }
  return node_lists(bd, st);
}

/* The sparse node blocks (beyond bordered_node_max): J's rows and columns
 * in their blocks in J's order (no reordering: each block's pattern keeps
 * its rows ascending). */
static int nsparse_create(mrvi_bordered *bd, const mrvi_step *st) {
  const int n = st->n_total;
  bd->rblk = malloc(((size_t)n + 1) * sizeof *bd->rblk);
  bd->roff = malloc(((size_t)n + 1) * sizeof *bd->roff);
  if (!bd->rblk || !bd->roff)
    return MRVI_ENOMEM;
  for (int i = 0; i < n; i++)
    node_of(st, i, &bd->rblk[i], &bd->roff[i]);
  return mrvi_nsparse_create(st, bd->rblk, bd->roff, &bd->nsp);
}

int mrvi_bordered_create(const mrvi_step *st, mrvi_bordered **out) {
  *out = NULL;
  mrvi_bordered *bd = calloc(1, sizeof *bd);
  if (!bd)
    return MRVI_ENOMEM;
  bd->nu = st->n_unknowns;
  bd->nl = st->n_lambda;
  bd->ns = st->ns;
  bd->dense_max = st->tuning.newton_dense_max;
  /* The pattern (fixed for the run) says whether the constraints touch
   * the slow unknowns only. */
  bd->slow_only = 1;
  for (int j = 0; j < st->n_total; j++)
    for (int q = st->Ap[j]; q < st->Ap[j + 1]; q++) {
      const int row_c = st->Ai[q] >= bd->nu, col_c = j >= bd->nu;
      if ((row_c && (col_c || j >= st->ns)) ||
          (col_c && !row_c && st->Ai[q] >= st->ns))
        bd->slow_only = 0;
    }
  /* The chain elimination where mrvi_chain_wanted (the path's choice)
   * takes it (a pattern not block tridiagonal in the chain's blocks: the
   * LU of the whole step, as where a block is singular). */
  int s = mrvi_chain_create(st, &bd->chain);
  if (s == MRVI_EINVAL || bd->chain) {
    s = MRVI_OK;
    bd->slow_only = 0;
  } else if (s == MRVI_OK && !bd->slow_only &&
             st->nf + st->r_micro > st->tuning.bordered_node_max) {
    s = nsparse_create(bd, st);
  } else if (s == MRVI_OK && !bd->slow_only) {
    s = node_create(bd, st);
  } else if (s == MRVI_OK) {
    const size_t nu = (size_t)bd->nu, nl = (size_t)bd->nl;
    bd->K = malloc((nl * nl + 1) * sizeof *bd->K);
    bd->piv = malloc((nl + 1) * sizeof *bd->piv);
    bd->r = malloc((nl + 1) * sizeof *bd->r);
    bd->dz = malloc((nu + 1) * sizeof *bd->dz);
    bd->W = malloc(((size_t)st->ns * nl + 1) * sizeof *bd->W);
    if (!bd->K || !bd->piv || !bd->r || !bd->dz || !bd->W)
      s = MRVI_ENOMEM;
    else if (mrvi_blocks_create(st, &bd->blocks) < 0)
      s = MRVI_ENOMEM;
  }
  if (s < 0) {
    mrvi_bordered_free(bd);
    return s;
  }
  *out = bd;
  return MRVI_OK;
}

/* Y's columns (A_fs as scattered, stride ka) that are zero at every node
 * stay zero through the sweep (a joint's point on a body's axis reads the
 * other director with weight 0): left out, the others moved to the front
 * at stride kv, their slow columns in kvt.  Returns kv. */
static int drop_zero_columns(mrvi_bordered *bd) {
  const size_t pb = (size_t)bd->p * (size_t)bd->b, ka = (size_t)bd->ka;
  double *Y = bd->Y;
  int kv = 0;
  for (size_t r = 0; r < ka; r++) {
    int used = 0;
    for (size_t j = 0; j < pb && !used; j++)
      used = Y[j * ka + r] != 0.0;
    if (used)
      bd->kvt[kv++] = (int)r;
  }
  if ((size_t)kv < ka) /* in place: every move goes to a lower index */
    for (size_t j = 0; j < pb; j++)
      for (int u = 0; u < kv; u++)
        Y[j * (size_t)kv + (size_t)u] = Y[j * ka + (size_t)bd->kvt[u]];
  for (int u = 0; u < kv; u++)
    bd->kvt[u] = bd->kt[bd->kvt[u]];
  return bd->kv = kv;
}

/* The nonzeros of the LU factors of a node block (D, b x b, factored in
 * place) into the lists o (2 b + 1 offsets) and ix: L's column k (rows
 * below the diagonal, ascending) and U's row i (columns right of the
 * diagonal, ascending). */
static void lu_lists(int b, const double *D, int *o, int *ix) {
  int e = 0;
  for (int k = 0; k < b; k++) {
    o[k] = e;
    for (int i = k + 1; i < b; i++)
      if (D[(size_t)i * b + k] != 0.0)
        ix[e++] = i;
  }
  for (int i = 0; i < b; i++) {
    o[b + i] = e;
    for (int j = i + 1; j < b; j++)
      if (D[(size_t)i * b + j] != 0.0)
        ix[e++] = j;
  }
  o[2 * b] = e;
}

/* mrvi_dense_lu_solve with a node block's factors by their nonzero lists
 * (lu_lists): x (b x nrhs row-major) becomes D^-1 x, the same arithmetic
 * in the same order (the dense solve skips the zeros that the lists leave
 * out) at the cost of the factors' nonzeros, not b^2. */
static void lu_solve_lists(int b, const double *D, const int *piv, const int *o,
                           const int *ix, double *x, int nrhs) {
  for (int k = 0; k < b; k++)
    if (piv[k] != k)
      for (int c = 0; c < nrhs; c++) {
        const double t = x[(size_t)piv[k] * nrhs + c];
        x[(size_t)piv[k] * nrhs + c] = x[(size_t)k * nrhs + c];
        x[(size_t)k * nrhs + c] = t;
      }
  if (nrhs == 1) {
    for (int k = 0; k < b; k++) {
      const double xk = x[k];
      for (int e = o[k]; e < o[k + 1]; e++)
        x[ix[e]] -= D[(size_t)ix[e] * b + k] * xk;
    }
    for (int i = b - 1; i >= 0; i--) {
      const double *Di = D + (size_t)i * b;
      double xi = x[i];
      for (int e = o[b + i]; e < o[b + i + 1]; e++)
        xi -= Di[ix[e]] * x[ix[e]];
      x[i] = xi / Di[i];
    }
    return;
  }
  for (int k = 0; k < b; k++) {
    const double *xk = x + (size_t)k * nrhs;
    for (int e = o[k]; e < o[k + 1]; e++) {
      const double f = D[(size_t)ix[e] * b + k];
      double *xi = x + (size_t)ix[e] * nrhs;
      for (int c = 0; c < nrhs; c++)
        xi[c] -= f * xk[c];
    }
  }
  for (int i = b - 1; i >= 0; i--) {
    const double *Di = D + (size_t)i * b;
    double *xi = x + (size_t)i * nrhs;
    for (int e = o[b + i]; e < o[b + i + 1]; e++) {
      const double u = Di[ix[e]];
      const double *xj = x + (size_t)ix[e] * nrhs;
      for (int c = 0; c < nrhs; c++)
        xi[c] -= u * xj[c];
    }
    for (int c = 0; c < nrhs; c++)
      xi[c] /= Di[i];
  }
}

/* Node blocks: scatter J, factor the D_c, sweep Y = A_ff^-1 A_fs, form and
 * factor S = A_ss - A_sf Y. */
static int node_factor(mrvi_bordered *bd, const mrvi_step *st, char *msg,
                       size_t len) {
  const int a = bd->a, b = bd->b, p = bd->p;
  const size_t pb = (size_t)p * (size_t)b;
  /* Every entry of the structure is set (one CSC entry each); of the
   * others only D's and Y's, which the factorisation fills, need zeroing. */
  memset(bd->Y, 0, pb * (size_t)bd->ka * sizeof *bd->Y);
  memset(bd->D, 0, pb * (size_t)b * sizeof *bd->D);
  for (int q = 0; q < st->Ap[st->n_total]; q++)
    *bd->dst[q] = st->Ax[q];
  const int ka = drop_zero_columns(bd);
  for (int c = 0; c < p; c++) {
    double *D = bd->D + (size_t)c * b * b, *Yc = bd->Y + (size_t)c * b * ka;
    /* Y_c = D_c^-1 (A_fs,c - L1_c Y_{c-1} - L2_c Y_{c-2}) */
    for (int k = 1; k <= 2 && k <= c; k++) {
      const double *L = (k == 1 ? bd->L1 : bd->L2) + (size_t)c * b * b;
      const double *Yp = bd->Y + (size_t)(c - k) * b * ka;
      for (int e = bd->lp[2 * c + k - 1]; e < bd->lp[2 * c + k]; e++) {
        const int i = bd->li[e], j = bd->lj[e];
        const double l = L[(size_t)i * b + j];
        if (l != 0.0)
          for (int t = 0; t < ka; t++)
            Yc[(size_t)i * ka + t] -= l * Yp[(size_t)j * ka + t];
      }
    }
    if (mrvi_dense_lu_factor_nz(b, D, bd->dpiv + (size_t)c * b, bd->dnz) < 0)
      return mrvi_fail(msg, len, MRVI_ESINGULAR,
                       "singular Newton matrix (node block %d of the "
                       "schur-bordered path)",
                       c + 1);
    int *o = bd->fo + (size_t)c * (2 * (size_t)b + 1);
    int *ix = bd->fi + (size_t)c * b * b;
    lu_lists(b, D, o, ix);
    lu_solve_lists(b, D, bd->dpiv + (size_t)c * b, o, ix, Yc, ka);
  }
  /* S = A_ss - A_sf Y (Y's columns ycol) */
  memcpy(bd->S, bd->Ass, (size_t)a * (size_t)a * sizeof *bd->S);
  for (int i = 0; i < a; i++)
    for (int e = bd->sfp[i]; e < bd->sfp[i + 1]; e++) {
      const size_t j = (size_t)bd->sfj[e];
      const double f = bd->Asf[(size_t)i * pb + j];
      double *Si = bd->S + (size_t)i * a;
      const double *Yj = bd->Y + j * (size_t)ka;
      if (f != 0.0)
        for (int r = 0; r < ka; r++)
          Si[bd->kvt[r]] -= f * Yj[r];
    }
  if (mrvi_dense_lu_factor(a, bd->S, bd->spiv) < 0)
    return mrvi_fail(msg, len, MRVI_ESINGULAR,
                     "singular Newton matrix (slow Schur complement of the "
                     "schur-bordered path)");
  return MRVI_OK;
}

/* from (J's order) into bd->z (node-block order: the fast blocks, then
 * the slow one), or (from NULL) bd->z back into to. */
static void node_order(const mrvi_bordered *bd, const double *from,
                       double *to) {
  const size_t b = (size_t)bd->b, pb = (size_t)bd->p * b;
  for (int i = 0; i < bd->nu + bd->nl; i++) {
    double *zi = bd->rblk[i] >= 0
                     ? bd->z + (size_t)bd->rblk[i] * b + (size_t)bd->roff[i]
                     : bd->z + pb + bd->roff[i];
    if (from)
      *zi = from[i];
    else
      to[i] = *zi;
  }
}

/* J dx = R with the node blocks' factors. */
static void node_solve(const mrvi_bordered *bd, const double *R, double *dx) {
  const int a = bd->a, b = bd->b, p = bd->p, ka = bd->kv;
  const size_t pb = (size_t)p * (size_t)b;
  double *z = bd->z, *ds = bd->z + pb;
  /* z = A_ff^-1 R_f (forward sweep), in node-block order */
  node_order(bd, R, NULL);
  for (int c = 0; c < p; c++) {
    double *zc = z + (size_t)c * b;
    for (int k = 1; k <= 2 && k <= c; k++) {
      const double *L = (k == 1 ? bd->L1 : bd->L2) + (size_t)c * b * b;
      const double *zp = z + (size_t)(c - k) * b;
      const int *lr = bd->lr + (size_t)(2 * c + k - 1) * ((size_t)b + 1);
      for (int i = 0; i < b; i++) { /* row by row */
        if (lr[i] == lr[i + 1])
          continue;
        const double *Li = L + (size_t)i * b;
        double acc = 0.0;
        for (int e = lr[i]; e < lr[i + 1]; e++)
          acc += Li[bd->lj[e]] * zp[bd->lj[e]];
        zc[i] -= acc;
      }
    }
    lu_solve_lists(b, bd->D + (size_t)c * b * b, bd->dpiv + (size_t)c * b,
                   bd->fo + (size_t)c * (2 * (size_t)b + 1),
                   bd->fi + (size_t)c * b * b, zc, 1);
  }
  /* S ds = R_s - A_sf z, then df = z - Y ds */
  for (int i = 0; i < a; i++) {
    double acc = 0.0;
    for (int e = bd->sfp[i]; e < bd->sfp[i + 1]; e++)
      acc += bd->Asf[(size_t)i * pb + (size_t)bd->sfj[e]] * z[bd->sfj[e]];
    ds[i] -= acc;
  }
  mrvi_dense_lu_solve(a, bd->S, bd->spiv, ds, 1);
  for (size_t j = 0; j < pb; j++) {
    double acc = 0.0;
    for (int r = 0; r < ka; r++)
      acc += bd->Y[j * (size_t)ka + (size_t)r] * ds[bd->kvt[r]];
    z[j] -= acc;
  }
  node_order(bd, NULL, dx);
}

/* Constraints at macro nodes only: A by block elimination (the
 * constraint rows of x's columns skipped), W = S^-1 B_s, K = -C_s W and
 * its LU. */
static int factor(mrvi_bordered *bd, const mrvi_step *st, char *msg,
                  size_t len) {
  const int nu = bd->nu, nl = bd->nl, ns = bd->ns;
  const int *Ap = st->Ap, *Ai = st->Ai;
  const double *Ax = st->Ax;
  int s = mrvi_blocks_factor(bd->blocks, st);
  if (s == MRVI_EINVAL)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "the step's Jacobian does not have the block structure "
                     "of the schur-bordered path");
  if (s < 0)
    return mrvi_fail(msg, len, MRVI_ESINGULAR,
                     "singular Newton matrix (block elimination)");
  memset(bd->K, 0, (size_t)nl * (size_t)nl * sizeof *bd->K);
  memset(bd->W, 0, (size_t)ns * (size_t)nl * sizeof *bd->W);
  for (int l = 0; l < nl; l++)
    for (int q = Ap[nu + l]; q < Ap[nu + l + 1]; q++)
      bd->W[(size_t)Ai[q] * (size_t)nl + (size_t)l] += Ax[q];
  mrvi_blocks_slow_solve(bd->blocks, bd->W, nl);
  for (int j = 0; j < ns; j++)
    for (int q = Ap[j]; q < Ap[j + 1]; q++) {
      if (Ai[q] < nu)
        continue;
      double *ka = bd->K + (size_t)(Ai[q] - nu) * (size_t)nl;
      const double *wj = bd->W + (size_t)j * (size_t)nl;
      for (int l = 0; l < nl; l++)
        ka[l] -= Ax[q] * wj[l];
    }
  if (mrvi_dense_lu_factor(nl, bd->K, bd->piv) < 0)
    return mrvi_fail(msg, len, MRVI_ESINGULAR,
                     "singular Newton matrix (constraint rows)");
  return MRVI_OK;
}

/* J dx = R with the factors (constraints at macro nodes only). */
static void solve(mrvi_bordered *bd, const mrvi_step *st, const double *R,
                  double *dx) {
  const int nu = bd->nu, nl = bd->nl;
  const int *Ap = st->Ap, *Ai = st->Ai;
  const double *Ax = st->Ax;
  /* z = A^-1 R_x, K dlambda = R_c - C z */
  mrvi_blocks_solve(bd->blocks, R, bd->dz);
  for (int a = 0; a < nl; a++)
    bd->r[a] = R[nu + a];
  for (int j = 0; j < nu; j++)
    for (int q = Ap[j]; q < Ap[j + 1]; q++)
      if (Ai[q] >= nu)
        bd->r[Ai[q] - nu] -= Ax[q] * bd->dz[j];
  mrvi_dense_lu_solve(nl, bd->K, bd->piv, bd->r, 1);
  for (int l = 0; l < nl; l++)
    dx[nu + l] = bd->r[l];
  /* dx = A^-1 (R_x - B dlambda) */
  for (int i = 0; i < nu; i++)
    bd->dz[i] = R[i];
  for (int l = 0; l < nl; l++)
    for (int q = Ap[nu + l]; q < Ap[nu + l + 1]; q++)
      bd->dz[Ai[q]] -= Ax[q] * bd->r[l];
  mrvi_blocks_solve(bd->blocks, bd->dz, dx);
}

int mrvi_bordered_factor_solve(mrvi_bordered *bd, const mrvi_step *st,
                               const double *R, double *dx, char *msg,
                               size_t len) {
  const int s = mrvi_bordered_factor(bd, st, msg, len);
  return s < 0 ? s : mrvi_bordered_solve(bd, st, R, dx, msg, len);
}

int mrvi_bordered_solve(mrvi_bordered *bd, const mrvi_step *st, const double *R,
                        double *dx, char *msg, size_t len) {
  if (bd->whole)
    return mrvi_linsolve_solve(bd->whole, st->Ax, 0, R, dx, msg, len);
  if (bd->nsp)
    return mrvi_nsparse_solve(bd->nsp, 0, R, dx, msg, len);
  if (bd->chain)
    mrvi_chain_solve(bd->chain, R, dx);
  else if (!bd->slow_only)
    node_solve(bd, R, dx);
  else
    solve(bd, st, R, dx);
  return MRVI_OK;
}

/* J^T dx = R with the node blocks' factors: J = [A_ff 0; A_sf S] [I Y;
 * 0 I] in node-block order (rows and columns alike), so w_s = R_s - Y^T
 * R_f, S^T ds = w_s, and A_ff^T df = R_f - A_sf^T ds by a backward sweep
 * (A_ff^T block upper-triangular: D_c^T on the diagonal, L1_{c+1}^T and
 * L2_{c+2}^T beside it). */
static void node_solve_transpose(const mrvi_bordered *bd, const double *R,
                                 double *dx) {
  const int a = bd->a, b = bd->b, p = bd->p, ka = bd->kv;
  const size_t pb = (size_t)p * (size_t)b;
  double *z = bd->z, *ds = bd->z + pb;
  node_order(bd, R, NULL);
  for (size_t j = 0; j < pb; j++)
    if (z[j] != 0.0)
      for (int r = 0; r < ka; r++)
        ds[bd->kvt[r]] -= bd->Y[j * (size_t)ka + (size_t)r] * z[j];
  mrvi_dense_lu_solve_transpose(a, bd->S, bd->spiv, ds, 1);
  for (int i = 0; i < a; i++)
    if (ds[i] != 0.0)
      for (int e = bd->sfp[i]; e < bd->sfp[i + 1]; e++)
        z[bd->sfj[e]] -= bd->Asf[(size_t)i * pb + (size_t)bd->sfj[e]] * ds[i];
  for (int c = p - 1; c >= 0; c--) {
    double *zc = z + (size_t)c * b;
    mrvi_dense_lu_solve_transpose(b, bd->D + (size_t)c * b * b,
                                  bd->dpiv + (size_t)c * b, zc, 1);
    for (int k = 1; k <= 2 && k <= c; k++) {
      const double *L = (k == 1 ? bd->L1 : bd->L2) + (size_t)c * b * b;
      double *zp = z + (size_t)(c - k) * b;
      for (int e = bd->lp[2 * c + k - 1]; e < bd->lp[2 * c + k]; e++)
        zp[bd->lj[e]] -= L[(size_t)bd->li[e] * b + bd->lj[e]] * zc[bd->li[e]];
    }
  }
  node_order(bd, NULL, dx);
}

/* J^T dx = R with the factors (constraints at macro nodes only): J = [A B;
 * C 0], K = -C A^-1 B, so with z = A^-T R_x, K^T dlambda = R_c - B^T z and
 * dx = A^-T (R_x - C^T dlambda). */
static void solve_transpose(mrvi_bordered *bd, const mrvi_step *st,
                            const double *R, double *dx) {
  const int nu = bd->nu, nl = bd->nl;
  const int *Ap = st->Ap, *Ai = st->Ai;
  const double *Ax = st->Ax;
  mrvi_blocks_solve_transpose(bd->blocks, R, bd->dz);
  for (int l = 0; l < nl; l++) {
    double s = R[nu + l];
    for (int q = Ap[nu + l]; q < Ap[nu + l + 1]; q++)
      if (Ai[q] < nu)
        s -= Ax[q] * bd->dz[Ai[q]];
    bd->r[l] = s;
  }
  mrvi_dense_lu_solve_transpose(nl, bd->K, bd->piv, bd->r, 1);
  for (int j = 0; j < nu; j++) {
    double s = R[j];
    for (int q = Ap[j]; q < Ap[j + 1]; q++)
      if (Ai[q] >= nu)
        s -= Ax[q] * bd->r[Ai[q] - nu];
    bd->dz[j] = s;
  }
  for (int l = 0; l < nl; l++)
    dx[nu + l] = bd->r[l];
  mrvi_blocks_solve_transpose(bd->blocks, bd->dz, dx);
}

int mrvi_bordered_factor(mrvi_bordered *bd, const mrvi_step *st, char *msg,
                         size_t len) {
  if (bd->slow_only)
    return factor(bd, st, msg, len);
  if (!bd->whole) {
    /* (neither a chain nor node blocks: the chain's pattern was not block
     * tridiagonal, the whole step's LU from the start) */
    const int s = bd->chain  ? mrvi_chain_factor(bd->chain, st->Ax)
                  : bd->nsp  ? mrvi_nsparse_factor(bd->nsp, st, msg, len)
                  : bd->nbuf ? node_factor(bd, st, msg, len)
                             : MRVI_ESINGULAR;
    if (s != MRVI_ESINGULAR)
      return s;
    bd->whole = mrvi_newton_create(st->n_total, st->Ap, st->Ai, st->Ax,
                                   bd->dense_max, msg, len);
    if (!bd->whole)
      return MRVI_ESINGULAR;
  }
  return mrvi_newton_factor(bd->whole, st->Ax, msg, len);
}

int mrvi_bordered_on_chain(const mrvi_bordered *bd) {
  return bd->chain && !bd->whole;
}

double mrvi_bordered_refactor_cost(const mrvi_bordered *bd) {
  return bd->chain && !bd->whole ? mrvi_chain_factor_ratio(bd->chain) / 3.0
                                 : 0.0;
}

double mrvi_bordered_transpose_cost(const mrvi_bordered *bd,
                                    const mrvi_step *st, double *solve_share) {
  *solve_share = 0.5;
  if (bd->whole || bd->chain)
    return mrvi_bordered_refactor_cost(bd);
  if (bd->slow_only || !bd->nbuf)
    return 0.0;
  /* Node blocks, multiply-adds from their sizes and lists (as node_factor
   * and node_solve_transpose run them; Y's columns the ka kept): the
   * factorisation scatters J and clears D and Y, factors the p D_c (b^3 /
   * 3), sweeps Y (L1, L2 entries and D_c's solves, ka columns), forms S
   * (A_sf's entries, ka each) and factors it (a^3 / 3); the transposed
   * solve runs over Y, S's and the D_c's factors, A_sf, L1 and L2 once,
   * the residual over J twice. */
  const double a = bd->a, b = bd->b, p = bd->p, ka = bd->ka;
  const double nl = bd->lp[2 * bd->p], nsf = bd->sfp[bd->a];
  const double nnz = st->Ap[st->n_total];
  const double f = nnz + p * b * (b + ka) + p * b * b * b / 3.0 +
                   ka * (nl + p * b * b) + ka * nsf + a * a * a / 3.0;
  const double solve =
      p * b * ka + a * a + nsf + p * b * b + nl + 2.0 * (p * b + a);
  *solve_share = solve / (solve + 2.0 * nnz);
  return f / (solve + 2.0 * nnz);
}

int mrvi_bordered_solve_transpose_n(mrvi_bordered *bd, const mrvi_step *st,
                                    int nrhs, const double *R, double *dx,
                                    double *work, char *msg, size_t len) {
  const size_t n = (size_t)st->n_total;
  if (bd->chain && !bd->whole && nrhs > 1) {
    mrvi_chain_solve_transpose_n(bd->chain, nrhs, R, dx, work);
    return MRVI_OK;
  }
  for (int c = 0; c < nrhs; c++) {
    const int s = mrvi_bordered_solve_transpose(bd, st, R + (size_t)c * n,
                                                dx + (size_t)c * n, msg, len);
    if (s < 0)
      return s;
  }
  return MRVI_OK;
}

int mrvi_bordered_solve_transpose(mrvi_bordered *bd, const mrvi_step *st,
                                  const double *R, double *dx, char *msg,
                                  size_t len) {
  if (bd->whole)
    return mrvi_linsolve_solve(bd->whole, st->Ax, 1, R, dx, msg, len);
  if (bd->nsp)
    return mrvi_nsparse_solve(bd->nsp, 1, R, dx, msg, len);
  if (bd->chain)
    mrvi_chain_solve_transpose(bd->chain, R, dx);
  else if (!bd->slow_only)
    node_solve_transpose(bd, R, dx);
  else
    solve_transpose(bd, st, R, dx);
  return MRVI_OK;
}
