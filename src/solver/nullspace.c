/* Discrete null-space form of the constrained step (doc/constraints.md).
 *
 * The multiplier form solves   R(x, lambda) = F(x) - C(x) lambda = 0,
 *                              h(x) = 0,
 * C holding the constraint-force columns (dt a0 G_s^T on the slow rows and
 * dt G_f^T on the rows of fast node m for lambda^m; dT G^T on the slow rows
 * for slow-only constraints).  The null-space form premultiplies the
 * dynamic rows by P^T with P^T C = 0, which removes lambda:
 *
 *   P^T F(x) = 0,  h(x) = 0       (n_unknowns equations).
 *
 * P is built node by node.  With G_f(z^m)^T = [Q1 Q2] [R; 0] (QR over the
 * fast coordinates the micro-node constraints touch):
 *   - per fast node m, the columns of Q2 and unit vectors of the other fast
 *     coordinates (local rows of the reduced system); fast free bodies
 *     take their analytic columns instead, fast bodies in open chains and
 *     trees of joints their joint-reduced ones (nullspace_tree.c), each
 *     with their micro nodes reparametrised;
 *   - per slow basis vector b (null space of the slow-only constraints'
 *     G(q_k)), the slow part b and at every node m the fast part
 *     -a0_m Q1 R^-T G_s(z^m) b, which cancels the coupling of b with the
 *     micro-node constraints.
 * The reduced rows therefore keep the arrowhead pattern of the step.
 *
 * Redundant rows (a closed loop of joints modelled in 3-D): the rows the
 * integrator's rank-revealing pass at q0 marks (drop) are left out of the
 * QR, of the equations and of lambda (0 there), slow-only rows at q_k and
 * micro-node rows (a loop of fast bodies) at every micro node.  The null
 * space of the kept rows is that of all rows while the rank stays, and
 * their zero set is the loop's near q0, so the step is the same
 * (doc/constraints.md; doc/multibody.md, "Fast closed loops").
 *
 * Newton matrix: at R = F - C lambda = 0, d(P^T F) = P^T (dF - dC lambda)
 * because d(P^T) C lambda = -P^T dC lambda (from P^T C = 0).  dF - dC lambda
 * is the x-block of the multiplier Jacobian evaluated at lambda, so the
 * reduced matrix is [P^T A; H] with A, H taken from the assembled
 * multiplier system at lambda = lambda(x): no derivative of P is needed,
 * also at the unknown micro nodes.  lambda(x) solves the fast rows of each
 * node in the least-squares sense (exact at the solution). */
#include "solver/solver.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/umfpack.h>

#define MAXD MRVI_DENSE_MAX

struct mrvi_nullspace {
  int n; /* reduced size = n_unknowns */
  int ns, nf, p;
  int nfc, nsc; /* constrained fast / slow slots */
  int *fc, *sc; /* slot lists */
  int *fpos;    /* fast slot -> index in fc or -1 */
  int r, rs;    /* kept micro-node rows / rows of slow-only constraints */
  int rk;       /* slow-only rows kept (rs less the redundant ones) */
  int *srow;    /* slow-only row -> index among the kept ones, or -1 */
  int rm;       /* micro-node rows, the redundant ones too (st->r_micro) */
  int *fkeep;   /* micro-node row -> index among the kept ones, or -1 */
  int *fk_row;  /* kept micro-node row -> its row */
  /* Nodal reparametrisation (free bodies, no other constraint): the slot
   * of each slow body's phi (its directors follow) and of each fast
   * body's, or NULL; dim the bodies' dimension D (D^2 director entries,
   * D(D-1)/2 rotations). */
  int n_rep, *rep_slot, dim;
  int n_frep, *frep_slot;
  double *rep_d;  /* scratch: D^2 per slow body */
  double *frep_d; /* D^2 per fast body and micro node 0..p: scratch, then
                     the directors at which P was built (lambda) */
  int nbs;        /* slow basis size ns - rs */
  int *b_slot;    /* basis vector i: its slot (unit) or -1 (Q column) */
  int *b_coupled; /* does it couple to the micro-node constraints? */
  /* Per node m = 0..p-1: Q (nfc x nfc), R (r x r), G_s (r x ns). */
  double *Q, *Rm, *Gs;
  double *Qs, *Rs; /* slow-only block: nsc x nsc, rs x rs */
  double *A, *t;   /* scratch: MAXD x MAXD, max(MAXD, nfc) */
  /* Above MAXD constrained fast coordinates (the fast forest only): per
   * node the kept rows' G_f (r x nfc) in Q and the LU of G_f G_f^T (r x r)
   * in Rm with its pivots, instead of the QR. */
  int gram, *piv;
  double *Gf, *Gsl; /* G_f (r x nfc) at one node, slow-only G (rs x nsc) */
  double *B;        /* slow basis vectors, nbs x ns */
  /* Recipe of the reduced rows: source rows and their coefficients. */
  int *rec_start, *rec_row;
  double *rec_coef;
  long n_rec;
  /* Rows of the full matrix (x columns only) as CSR into st->Ax. */
  int *csr_start, *csr_col, *csr_idx;
  /* Reduced matrix on a fixed CSC pattern. */
  int *map, *Ap, *Ai;
  double *Ax;
  long nnz;
  mrvi_nstree *tree; /* the joint-reduced basis (nullspace_tree.c), or NULL */
  /* The fast forest's joint-reduced local columns (nullspace_tree.c), or
   * NULL: per node m = 0..p-1, nfc - r columns of nfc entries; the iterate
   * before an update (retract). */
  mrvi_nstree *fast;
  double *Fcol, *xold;
  mrvi_nstree *slow; /* beside it, the slow bodies' placement, or NULL */
  mrvi_nsrods *rods; /* the link-local basis (nullspace_rods.c), or NULL */
};

void mrvi_nullspace_free(mrvi_nullspace *z) {
  if (!z)
    return;
  free(z->fc), free(z->sc), free(z->fpos), free(z->b_slot), free(z->srow);
  free(z->fkeep), free(z->fk_row);
  free(z->rep_slot), free(z->rep_d), free(z->frep_slot), free(z->frep_d);
  free(z->b_coupled), free(z->Q), free(z->Rm), free(z->Gs), free(z->Qs);
  free(z->Rs), free(z->A), free(z->t), free(z->piv), free(z->B), free(z->Gf),
      free(z->Gsl);
  free(z->rec_start), free(z->rec_row), free(z->rec_coef);
  free(z->csr_start), free(z->csr_col), free(z->csr_idx);
  free(z->map), free(z->Ap), free(z->Ai), free(z->Ax);
  mrvi_nstree_free(z->tree);
  mrvi_nstree_free(z->fast), free(z->Fcol), free(z->xold);
  mrvi_nstree_free(z->slow);
  mrvi_nsrods_free(z->rods);
  free(z);
}

const int *mrvi_nullspace_Ap(const mrvi_nullspace *z) {
  return z->tree   ? mrvi_nstree_Ap(z->tree)
         : z->rods ? mrvi_nsrods_Ap(z->rods)
                   : z->Ap;
}
const int *mrvi_nullspace_Ai(const mrvi_nullspace *z) {
  return z->tree   ? mrvi_nstree_Ai(z->tree)
         : z->rods ? mrvi_nsrods_Ai(z->rods)
                   : z->Ai;
}
const double *mrvi_nullspace_Ax(const mrvi_nullspace *z) {
  return z->tree   ? mrvi_nstree_Ax(z->tree)
         : z->rods ? mrvi_nsrods_Ax(z->rods)
                   : z->Ax;
}
long mrvi_nullspace_nnz(const mrvi_nullspace *z) {
  return z->tree   ? mrvi_nstree_nnz(z->tree)
         : z->rods ? mrvi_nsrods_nnz(z->rods)
                   : z->nnz;
}
int mrvi_nullspace_size(const mrvi_nullspace *z) {
  return z->tree   ? mrvi_nstree_size(z->tree)
         : z->rods ? mrvi_nsrods_size(z->rods)
                   : z->n;
}
int mrvi_nullspace_joint_reduced(const mrvi_nullspace *z) {
  return z->tree != NULL;
}

/* Row of fast node m, slot f, in the full system. */
static inline int frow(const mrvi_nullspace *z, int m, int f) {
  return z->ns + m * z->nf + f;
}

/* Append source row `row` to the recipe (growing it). */
static int rec_push(mrvi_nullspace *z, long *cap, int row) {
  if (z->n_rec == *cap) {
    const long c = *cap ? 2 * *cap : 256;
    int *r = realloc(z->rec_row, (size_t)c * sizeof *r);
    if (!r)
      return -1;
    z->rec_row = r;
    *cap = c;
  }
  z->rec_row[z->n_rec++] = row;
  return 0;
}

/* Source rows of every reduced row, fixed by structure (doc/constraints.md,
 * null-space basis): slow basis rows, then the local rows of nodes 0..p-1, then
 * the constraint equations. */
static int build_recipe(mrvi_nullspace *z, const mrvi_step *st) {
  const int nu = st->n_unknowns;
  long cap = 0;
  z->rec_start = malloc((size_t)(st->n_unknowns + 1) * sizeof(int));
  if (!z->rec_start)
    return -1;
  int row = 0;
  for (int i = 0; i < z->nbs; i++) {
    z->rec_start[row++] = (int)z->n_rec;
    if (z->b_slot[i] >= 0) {
      if (rec_push(z, &cap, z->b_slot[i]) < 0)
        return -1;
    } else {
      for (int a = 0; a < z->nsc; a++)
        if (rec_push(z, &cap, z->sc[a]) < 0)
          return -1;
    }
    if (z->b_coupled[i])
      for (int m = 0; m < z->p; m++)
        for (int a = 0; a < z->nfc; a++)
          if (rec_push(z, &cap, frow(z, m, z->fc[a])) < 0)
            return -1;
  }
  for (int m = 0; m < z->p; m++) {
    for (int f = 0; f < z->nf; f++)
      if (z->fpos[f] < 0) {
        z->rec_start[row++] = (int)z->n_rec;
        if (rec_push(z, &cap, frow(z, m, f)) < 0)
          return -1;
      }
    for (int j = z->r; j < z->nfc; j++) {
      z->rec_start[row++] = (int)z->n_rec;
      for (int a = 0; a < z->nfc; a++)
        if (rec_push(z, &cap, frow(z, m, z->fc[a])) < 0)
          return -1;
    }
  }
  for (int e = 0; e < st->n_lambda; e++) {
    if (e < z->rs ? z->srow[e] < 0 : z->fkeep[(e - z->rs) % z->rm] < 0)
      continue;
    z->rec_start[row++] = (int)z->n_rec;
    if (rec_push(z, &cap, nu + e) < 0)
      return -1;
  }
  z->rec_start[row] = (int)z->n_rec;
  z->rec_coef =
      malloc((size_t)(z->n_rec > 0 ? z->n_rec : 1) * sizeof *z->rec_coef);
  return row == nu && z->rec_coef ? 0 : -1;
}

int mrvi_nullspace_csr(const mrvi_step *st, int **start, int **col, int **idx) {
  const int n = st->n_total, nu = st->n_unknowns;
  int *cs = *start = calloc((size_t)n + 1, sizeof(int));
  int *cc = *col = malloc((size_t)(st->nnz > 0 ? st->nnz : 1) * sizeof(int));
  int *ci = *idx = malloc((size_t)(st->nnz > 0 ? st->nnz : 1) * sizeof(int));
  if (!cs || !cc || !ci)
    return -1;
  for (int j = 0; j < nu; j++)
    for (int k = st->Ap[j]; k < st->Ap[j + 1]; k++)
      cs[st->Ai[k] + 1]++;
  for (int i = 0; i < n; i++)
    cs[i + 1] += cs[i];
  int *fill = malloc((size_t)n * sizeof *fill);
  if (!fill)
    return -1;
  memcpy(fill, cs, (size_t)n * sizeof *fill);
  for (int j = 0; j < nu; j++)
    for (int k = st->Ap[j]; k < st->Ap[j + 1]; k++) {
      const int i = st->Ai[k];
      cc[fill[i]] = j;
      ci[fill[i]++] = k;
    }
  free(fill);
  return 0;
}

/* Pattern of the reduced matrix: every (reduced row, column) a source row
 * reaches, mapped to CSC once. */
static int build_pattern(mrvi_nullspace *z) {
  const int n = z->n;
  long nt = 0;
  for (long e = 0; e < z->n_rec; e++) {
    const int r = z->rec_row[e];
    nt += z->csr_start[r + 1] - z->csr_start[r];
  }
  if (nt > 2147483647L)
    return -1;
  int *Ti = malloc((size_t)(nt > 0 ? nt : 1) * sizeof *Ti);
  int *Tj = malloc((size_t)(nt > 0 ? nt : 1) * sizeof *Tj);
  z->map = malloc((size_t)(nt > 0 ? nt : 1) * sizeof *z->map);
  z->Ap = malloc((size_t)(n + 1) * sizeof *z->Ap);
  z->Ai = malloc((size_t)(nt > 0 ? nt : 1) * sizeof *z->Ai);
  if (!Ti || !Tj || !z->map || !z->Ap || !z->Ai) {
    free(Ti), free(Tj);
    return -1;
  }
  long t = 0;
  for (int i = 0; i < n; i++)
    for (int e = z->rec_start[i]; e < z->rec_start[i + 1]; e++) {
      const int r = z->rec_row[e];
      for (int k = z->csr_start[r]; k < z->csr_start[r + 1]; k++) {
        Ti[t] = i;
        Tj[t++] = z->csr_col[k];
      }
    }
  const int status = umfpack_di_triplet_to_col(n, n, (int)nt, Ti, Tj, NULL,
                                               z->Ap, z->Ai, NULL, z->map);
  free(Ti), free(Tj);
  if (status != UMFPACK_OK)
    return -1;
  z->nnz = z->Ap[n];
  z->Ax = calloc((size_t)(z->nnz > 0 ? z->nnz : 1), sizeof *z->Ax);
  return z->Ax ? 0 : -1;
}

static int reparametrise(mrvi_nullspace *z, const mrvi_model *m);

/* The redundant micro-node rows drop marks (a closed loop of fast bodies)
 * must follow from the kept micro-node rows alone: those hold at every
 * micro node, where the slow-only rows do not (enforced at the macro nodes
 * only).  The rank-revealing pass of mrvi_constraints_rank (rows of G(q0)
 * in model order, metric M^-1, 1e-9 relative) over the micro-node rows
 * alone must leave out the same rows. */
static int micro_redundancy_local(const mrvi_step *st,
                                  const unsigned char *drop, char *msg,
                                  size_t len) {
  const mrvi_model *m = st->model;
  const int R = m->constraint_rows, n = m->n;
  double *g = malloc((size_t)R * sizeof *g);
  double *G = malloc((size_t)R * (size_t)n * sizeof *G);
  double *E = malloc(((size_t)st->r_micro + 1) * (size_t)n * sizeof *E);
  double *v = malloc((size_t)n * sizeof *v);
  if (!g || !G || !E || !v) {
    free(g), free(G), free(E), free(v);
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  }
  mrvi_model_constraint_eval(m, m->q0, g, G);
  int rank = 0, bad = -1;
  for (int c = 0; c < m->n_constraints && bad < 0; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    for (int rr = 0; k->where == MRVI_FAST && rr < k->rows; rr++) {
      const int row = k->first_row + rr;
      for (int j = 0; j < n; j++)
        v[j] = G[(size_t)row * n + j] / sqrt(MRVI_MASS(m, j));
      const int kept = mrvi_dense_extend_basis(n, E, rank, v, 1e-9);
      rank += kept;
      if (kept == !!drop[row]) {
        bad = c;
        break;
      }
    }
  }
  free(g), free(G), free(E), free(v);
  if (bad < 0)
    return MRVI_OK;
  return mrvi_fail(msg, len, MRVI_ESINGULAR,
                   "null-space form: constraint '%s', enforced at micro "
                   "nodes, is redundant only together with constraints "
                   "enforced at the macro nodes (a closed loop of fast and "
                   "slow bodies); make the loop's bodies all fast or all slow",
                   m->constraints[bad].label);
}

int mrvi_nullspace_create(const mrvi_step *st, const unsigned char *drop,
                          int tree, mrvi_nullspace **out, char *msg,
                          size_t len) {
  const mrvi_model *m = st->model;
  *out = NULL;
  mrvi_nullspace *z = calloc(1, sizeof *z);
  if (!z)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  if (tree && st->tuning.nullspace_tree) {
    /* Open chains and trees of joints: the joint-reduced basis. */
    char why[200];
    const int s = mrvi_nstree_create(st, drop, &z->tree, why, sizeof why);
    if (s < 0) {
      mrvi_nullspace_free(z);
      return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
    }
    if (s > 0) {
      z->n = mrvi_nstree_size(z->tree);
      *out = z;
      return MRVI_OK;
    }
    /* Open chains and trees of particles on rods: the link-local basis. */
    const int r = mrvi_nsrods_create(st, drop, &z->rods, why, sizeof why);
    if (r < 0) {
      mrvi_nullspace_free(z);
      return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
    }
    if (r > 0) {
      z->n = mrvi_nsrods_size(z->rods);
      *out = z;
      return MRVI_OK;
    }
  }
  z->n = st->n_unknowns;
  z->ns = st->ns;
  z->nf = st->nf;
  z->p = st->p;
  z->rm = st->r_micro;
  z->rs = st->r_slow;
  const int ns = st->ns, nf = st->nf;
  z->fc = malloc((size_t)(nf + 1) * sizeof(int));
  z->fpos = malloc((size_t)(nf + 1) * sizeof(int));
  z->sc = malloc((size_t)(ns + 1) * sizeof(int));
  int *spos = malloc((size_t)(ns + 1) * sizeof(int));
  int *ms = calloc((size_t)(ns + 1), sizeof(int));
  z->srow = malloc((size_t)(z->rs + 1) * sizeof(int));
  z->fkeep = malloc((size_t)(z->rm + 1) * sizeof(int));
  z->fk_row = malloc((size_t)(z->rm + 1) * sizeof(int));
  if (!z->fc || !z->fpos || !z->sc || !spos || !ms || !z->srow || !z->fkeep ||
      !z->fk_row)
    goto oom;
  /* Kept rows, numbered in order: slow-only ones and micro-node ones (a
   * closed loop of fast bodies), the redundant ones left out. */
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    for (int rr = 0; rr < k->rows; rr++) {
      const int red = drop && drop[k->first_row + rr];
      if (k->where == MRVI_FAST)
        z->fkeep[st->c_off[c] + rr] = red ? -1 : 0;
      else
        z->srow[st->c_off[c] + rr] = red ? -1 : 0;
    }
  }
  for (int e = 0; e < z->rs; e++)
    if (z->srow[e] == 0)
      z->srow[e] = z->rk++;
  for (int e = 0; e < z->rm; e++)
    if (z->fkeep[e] == 0) {
      z->fk_row[z->r] = e;
      z->fkeep[e] = z->r++;
    }
  if (z->r < z->rm) {
    const int s = micro_redundancy_local(st, drop, msg, len);
    if (s < 0) {
      free(spos), free(ms);
      mrvi_nullspace_free(z);
      return s;
    }
  }
  for (int f = 0; f < nf; f++)
    z->fpos[f] = -1;
  for (int s = 0; s < ns; s++)
    spos[s] = -1;
  /* Constrained slots: fast inputs of micro-node constraints, slow inputs
   * of slow-only ones; ms marks slow inputs of micro-node constraints. */
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    for (int j = 0; j < k->n_in; j++) {
      const int idx = k->in[j], s = m->slot[idx];
      if (k->where == MRVI_FAST && m->rate[idx] == MRVI_FAST) {
        if (z->fpos[s] < 0) {
          z->fpos[s] = z->nfc;
          z->fc[z->nfc++] = s;
        }
      } else if (k->where == MRVI_FAST) {
        ms[s] = 1;
      } else if (spos[s] < 0) {
        spos[s] = z->nsc;
        z->sc[z->nsc++] = s;
      }
    }
  }
  if (z->r > z->nfc || z->rk > z->nsc) {
    const int st =
        mrvi_fail(msg, len, MRVI_ESINGULAR,
                  "null-space form: %d micro-node constraint equations "
                  "on %d fast coordinates (or %d slow-only equations on "
                  "%d slow coordinates) cannot be independent; use "
                  "form: multipliers",
                  z->r, z->nfc, z->rk, z->nsc);
    free(spos), free(ms);
    mrvi_nullspace_free(z);
    return st;
  }
  /* Fast bodies in open chains and trees of joints: the joint-reduced
   * local columns at every micro node. */
  if (tree && st->tuning.nullspace_tree && z->r > 0) {
    char why[200];
    const int s = mrvi_nsfast_create(st, z->fpos, z->nfc, z->r, z->fkeep,
                                     &z->fast, why, sizeof why);
    const size_t nc = (size_t)(z->nfc - z->r) * (size_t)z->nfc;
    if (s < 0 ||
        (z->fast &&
         (!(z->Fcol = malloc(((size_t)st->p * nc + 1) * sizeof(double))) ||
          !(z->xold = malloc((size_t)(st->n_unknowns + 1) * sizeof(double))))))
      goto oom;
    /* Slow bodies in joints beside it: their joint-reduced placement. */
    if (z->fast && !mrvi_nullspace_slow_side_free(m) && z->rk == z->rs &&
        mrvi_nsslow_create(st, &z->slow, why, sizeof why) < 0)
      goto oom;
  }
  /* The QR of the micro-node rows is dense and capped; the fast forest
   * needs it only for the multipliers and the slow coupling, which the
   * Gram matrix G_f G_f^T gives as well (gram), at a third of the cost
   * and without the cap: above the cap, for closed loops (cut joints) and
   * for open fast trees from nullspace_gram_min constrained fast
   * coordinates (doc/performance/chains.md, "The Gram matrix for open fast
   * trees"). */
  z->gram = z->fast && (z->nfc > MAXD || mrvi_nsfast_cut_rows(z->fast) > 0 ||
                        z->nfc >= st->tuning.nullspace_gram_min);
  if ((z->nfc > MAXD && !z->gram) || z->nsc > MAXD) {
    free(spos), free(ms);
    mrvi_nullspace_free(z);
    return mrvi_fail(
        msg, len, MRVI_EMODEL,
        "null-space form: constraints touch more than %d coordinates "
        "of one rate; use form: multipliers",
        MAXD);
  }
  /* Slow basis: unit vectors of the slots outside sc, then the columns of
   * the slow-only block's null space. */
  z->nbs = ns - z->rk;
  z->b_slot = malloc((size_t)(z->nbs + 1) * sizeof(int));
  z->b_coupled = malloc((size_t)(z->nbs + 1) * sizeof(int));
  if (!z->b_slot || !z->b_coupled)
    goto oom;
  int any_ms_in_sc = 0;
  for (int a = 0; a < z->nsc; a++)
    any_ms_in_sc |= ms[z->sc[a]];
  int i = 0;
  for (int s = 0; s < ns; s++)
    if (spos[s] < 0) {
      z->b_slot[i] = s;
      z->b_coupled[i++] = ms[s] && z->r > 0;
    }
  for (; i < z->nbs; i++) {
    z->b_slot[i] = -1;
    z->b_coupled[i] = any_ms_in_sc && z->r > 0;
  }
  free(spos), free(ms);
  spos = ms = NULL;
  const size_t p = (size_t)st->p, nfc = (size_t)z->nfc, r = (size_t)z->r;
  z->Q = malloc((p * (z->gram ? r : nfc) * nfc + 1) * sizeof(double));
  z->piv = malloc((p * r + 1) * sizeof(int));
  z->Rm = malloc((p * r * r + 1) * sizeof(double));
  z->Gs = malloc((p * r * (size_t)ns + 1) * sizeof(double));
  z->Qs = malloc(((size_t)z->nsc * (size_t)z->nsc + 1) * sizeof(double));
  z->Rs = malloc(((size_t)z->rk * (size_t)z->rk + 1) * sizeof(double));
  z->A = malloc((size_t)MAXD * MAXD * sizeof(double));
  z->t = malloc((size_t)(MAXD > z->nfc ? MAXD : z->nfc) * sizeof(double));
  z->B = malloc(((size_t)z->nbs * (size_t)ns + 1) * sizeof(double));
  z->Gf = malloc((r * nfc + 1) * sizeof(double));
  z->Gsl = malloc(((size_t)z->rk * (size_t)z->nsc + 1) * sizeof(double));
  if (!z->Q || !z->piv || !z->Rm || !z->Gs || !z->Qs || !z->Rs || !z->A ||
      !z->t || !z->B || !z->Gf || !z->Gsl)
    goto oom;
  if (build_recipe(z, st) < 0 ||
      mrvi_nullspace_csr(st, &z->csr_start, &z->csr_col, &z->csr_idx) < 0 ||
      build_pattern(z) < 0 || reparametrise(z, m) < 0)
    goto oom;
  *out = z;
  return MRVI_OK;
oom:
  free(spos), free(ms);
  mrvi_nullspace_free(z);
  return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
}

int mrvi_nullspace_micro_redundant(const mrvi_model *m, const double *q) {
  char why[8];
  unsigned char *drop = malloc((size_t)m->constraint_rows + 1);
  if (!drop)
    return MRVI_ENOMEM;
  int n = mrvi_constraints_rank(m, q, drop, why, sizeof why);
  if (n > 0) {
    n = 0;
    for (int c = 0; c < m->n_constraints; c++)
      for (int r = 0;
           m->constraints[c].where == MRVI_FAST && r < m->constraints[c].rows;
           r++)
        n += drop[m->constraints[c].first_row + r];
  }
  free(drop);
  return n;
}

int mrvi_nullspace_slow_side_free(const mrvi_model *m) {
  for (int c = 0; c < m->n_constraints; c++) {
    int internal = m->constraints[c].where == MRVI_FAST;
    for (int b = 0; b < m->n_bodies && !internal; b++)
      internal = m->bodies[b].constraint == c;
    if (!internal)
      return 0;
  }
  return 1;
}

/* Which bodies the nodal reparametrisation of free bodies takes: all of
 * them when every constraint is the internal one of a body (2-D or 3-D,
 * slow or fast; no joint, no other constraint) and each body's D(D+1)
 * coordinates are consecutive slots of its rate's block, the slow ones
 * when the fast bodies are the fast forest's and the slow ones free; else
 * none.  Slow bodies: the new macro node; fast bodies: every unknown micro
 * node z^1..z^p. */
static int reparametrise(mrvi_nullspace *z, const mrvi_model *m) {
  if (!(mrvi_model_free_bodies_only(m) ||
        (z->fast && mrvi_nullspace_slow_side_free(m))) ||
      z->rk != z->rs || m->n_bodies == 0)
    return 0;
  const int D = m->bodies[0].dim, nb = m->n_bodies;
  z->rep_slot = malloc((size_t)nb * sizeof *z->rep_slot);
  z->frep_slot = malloc((size_t)nb * sizeof *z->frep_slot);
  z->rep_d = malloc((size_t)nb * 9 * sizeof *z->rep_d);
  z->frep_d = malloc((size_t)nb * 9 * (size_t)(z->p + 1) * sizeof *z->frep_d);
  if (!z->rep_slot || !z->frep_slot || !z->rep_d || !z->frep_d)
    return -1;
  int ns = 0, nf = 0;
  for (int b = 0; b < nb; b++) {
    /* A body's coordinates are consecutive slots of one rate's block. */
    const int f = m->bodies[b].first, s0 = m->slot[f];
    const mrvi_rate rate = m->rate[f];
    if (m->bodies[b].dim != D)
      return 0;
    for (int j = 1; j < D * (D + 1); j++)
      if (m->slot[f + j] != s0 + j || m->rate[f + j] != rate)
        return 0;
    if (rate == MRVI_SLOW)
      z->rep_slot[ns++] = s0;
    else if (!z->fast)
      z->frep_slot[nf++] = s0;
  }
  z->dim = D;
  z->n_rep = ns;
  z->n_frep = nf;
  return 0;
}

int mrvi_nullspace_reparametrised(const mrvi_nullspace *z) {
  return z->tree   ? mrvi_nstree_bodies(z->tree)
         : z->rods ? mrvi_nsrods_settles(z->rods)
         : z->fast ? z->n_rep + mrvi_nsfast_bodies(z->fast) +
                         (z->slow ? mrvi_nsfast_bodies(z->slow) : 0)
                   : z->n_rep + z->n_frep;
}

/* v <- exp(th^) v (Rodrigues; the series below |th| = 1e-4); in 2-D v <-
 * R(th) v with th[0] the angle. */
void mrvi_nullspace_rotate(int D, const double *th, double *v) {
  if (D == 2) {
    const double c = cos(th[0]), s = sin(th[0]), x = v[0];
    v[0] = c * x - s * v[1];
    v[1] = s * x + c * v[1];
    return;
  }
  const double t2 = th[0] * th[0] + th[1] * th[1] + th[2] * th[2];
  const double t = sqrt(t2);
  double a, b; /* exp(th^) = I + a th^ + b th^2 */
  if (t < 1e-4) {
    a = 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0);
    b = 0.5 * (1.0 - t2 / 12.0 * (1.0 - t2 / 30.0));
  } else {
    a = sin(t) / t;
    b = (1.0 - cos(t)) / t2;
  }
  const double c[3] = {th[1] * v[2] - th[2] * v[1], th[2] * v[0] - th[0] * v[2],
                       th[0] * v[1] - th[1] * v[0]};
  const double cc[3] = {th[1] * c[2] - th[2] * c[1],
                        th[2] * c[0] - th[0] * c[2],
                        th[0] * c[1] - th[1] * c[0]};
  for (int i = 0; i < 3; i++)
    v[i] += a * c[i] + b * cc[i];
}

/* The rotation th of director increments w^i at directors d^i (D x D
 * each, rows): th = 1/2 sum_i d^i x w^i (2-D: the scalar cross product,
 * th[0]), exact for w^i = th x d^i (2-D: th J d^i) with d orthonormal --
 * the left inverse of the body's null-space matrix
 * (mrvi_nullspace_body_rotation); for w^i = R d^i - d^i with R a rotation,
 * sin|th| th/|th|. */
void mrvi_nullspace_rotation_of(int D, const double *d, const double *w,
                                double *th) {
  th[0] = th[1] = th[2] = 0.0;
  for (int i = 0; i < D; i++) {
    const double *a = d + D * i, *b = w + D * i;
    if (D == 2) {
      th[0] += 0.5 * (a[0] * b[1] - a[1] * b[0]);
      continue;
    }
    th[0] += 0.5 * (a[1] * b[2] - a[2] * b[1]);
    th[1] += 0.5 * (a[2] * b[0] - a[0] * b[2]);
    th[2] += 0.5 * (a[0] * b[1] - a[1] * b[0]);
  }
}

void mrvi_nullspace_body_rotation(int D, const double *d, int k, double *v) {
  for (int i = 0; i < D; i++) {
    const double *a = d + D * i;
    double *u = v + D * i;
    if (D == 2) { /* J d = (-d_y, d_x) */
      u[0] = -a[1];
      u[1] = a[0];
      continue;
    }
    const int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
    u[k] = 0.0;
    u[k1] = -a[k2]; /* (e_k x d)_k1 = -d_k2 */
    u[k2] = a[k1];  /* (e_k x d)_k2 = d_k1 */
  }
}

/* Directors d (positions; rows d^1..d^D) from the D^2 entries x holds,
 * which are displacements from q0 when q0 is not NULL (st->increments). */
static void directors(int D, const double *x, const double *q0, double *d) {
  for (int j = 0; j < D * D; j++)
    d[j] = x[j] + (q0 ? q0[j] : 0.0);
}

/* Store the directors d (positions) into x (displacements from q0 if not
 * NULL). */
static void set_directors(int D, double *x, const double *q0, const double *d) {
  for (int j = 0; j < D * D; j++)
    x[j] = d[j] - (q0 ? q0[j] : 0.0);
}

/* Where x holds the directors of slow body b (the new macro node) and of
 * fast body b at micro node m = 1..p, and the known positions they are
 * displacements from (NULL unless st->increments). */
static double *slow_dirs(const mrvi_nullspace *z, const mrvi_step *st,
                         double *x, int b, const double **q0) {
  const int o = z->rep_slot[b] + z->dim;
  *q0 = st->increments ? st->qs0 + o : NULL;
  return x + o;
}
static double *fast_dirs(const mrvi_nullspace *z, const mrvi_step *st,
                         double *x, int b, int m, const double **q0) {
  const int o = z->frep_slot[b] + z->dim;
  *q0 = st->increments ? st->qf0 + o : NULL;
  return x + z->ns + (m - 1) * z->nf + o;
}

/* d <- exp(th^) d for the D directors, th = 1/2 sum_i d^i x w^i from the
 * director increments w (the left inverse of P). */
static void turn(int D, double *d, const double *w) {
  double th[3];
  mrvi_nullspace_rotation_of(D, d, w, th);
  for (int i = 0; i < D; i++)
    mrvi_nullspace_rotate(D, th, d + D * i);
}

/* d <- the frame ref turned by the rotation that takes it closest to the
 * frame w: 1/2 sum ref^i x w^i = sin|th| th/|th| for a rotation; its angle
 * from the sine (a predictor turns by much less than pi/2 in a step). */
void mrvi_nullspace_nearest_rotation(int D, const double *ref, const double *w,
                                     double *th) {
  mrvi_nullspace_rotation_of(D, ref, w, th);
  const double sn = sqrt(th[0] * th[0] + th[1] * th[1] + th[2] * th[2]);
  const double f = sn > 1e-300 && sn < 1.0 ? asin(sn) / sn : 1.0;
  for (int a = 0; a < 3; a++)
    th[a] *= f;
}

static void nearest_turn(int D, const double *ref, const double *w, double *d) {
  double th[3];
  mrvi_nullspace_nearest_rotation(D, ref, w, th);
  for (int j = 0; j < D * D; j++)
    d[j] = ref[j];
  for (int i = 0; i < D; i++)
    mrvi_nullspace_rotate(D, th, d + D * i);
}

void mrvi_nullspace_retract(mrvi_nullspace *z, const mrvi_step *st, double *x,
                            const double *dx) {
  if (z->tree) {
    mrvi_nstree_retract(z->tree, st, x, dx);
    return;
  }
  if (z->rods) {
    mrvi_nsrods_retract(z->rods, x, dx);
    return;
  }
  const int D = z->dim, p = z->p;
  const double *q0;
  if (z->fast)
    memcpy(z->xold, x, (size_t)st->n_unknowns * sizeof *x);
  /* The rotated directors from the iterate, before x changes. */
  for (int b = 0; b < z->n_rep; b++) {
    double *v = slow_dirs(z, st, x, b, &q0), *d = z->rep_d + 9 * b, w[9];
    directors(D, v, q0, d);
    for (int j = 0; j < D * D; j++)
      w[j] = -dx[v - x + j];
    turn(D, d, w);
  }
  for (int b = 0; b < z->n_frep; b++)
    for (int mm = 1; mm <= p; mm++) {
      double *v = fast_dirs(z, st, x, b, mm, &q0), w[9];
      double *d = z->frep_d + 9 * ((size_t)b * (p + 1) + mm);
      directors(D, v, q0, d);
      for (int j = 0; j < D * D; j++)
        w[j] = -dx[v - x + j];
      turn(D, d, w);
    }
  for (int s = 0; s < st->n_unknowns; s++)
    x[s] -= dx[s];
  for (int b = 0; b < z->n_rep; b++) {
    double *v = slow_dirs(z, st, x, b, &q0);
    set_directors(D, v, q0, z->rep_d + 9 * b);
  }
  for (int b = 0; b < z->n_frep; b++)
    for (int mm = 1; mm <= p; mm++) {
      double *v = fast_dirs(z, st, x, b, mm, &q0);
      set_directors(D, v, q0, z->frep_d + 9 * ((size_t)b * (p + 1) + mm));
    }
  /* The slow bodies on their joints, then the fast forest on the new slow
   * nodes, micro node by micro node. */
  if (z->slow)
    mrvi_nsslow_retract(z->slow, st, z->xold, x, dx);
  if (z->fast)
    mrvi_nsfast_retract(z->fast, st, z->xold, x, dx);
}

void mrvi_nullspace_start(mrvi_nullspace *z, const mrvi_step *st, double *x) {
  if (z->tree) {
    mrvi_nstree_start(z->tree, st, x);
    return;
  }
  if (z->rods) {
    mrvi_nsrods_start(z->rods, st, x);
    return;
  }
  const int D = z->dim;
  const double *q0;
  /* Each new node: the frame before it turned as close as can be to the
   * predictor's (fast bodies node by node from z^0). */
  for (int b = 0; b < z->n_rep; b++) {
    double *v = slow_dirs(z, st, x, b, &q0), w[9], d[9];
    directors(D, v, q0, w);
    nearest_turn(D, st->qs0 + z->rep_slot[b] + D, w, d);
    set_directors(D, v, q0, d);
  }
  for (int b = 0; b < z->n_frep; b++) {
    double ref[9], w[9], d[9];
    for (int j = 0; j < D * D; j++)
      ref[j] = st->qf0[z->frep_slot[b] + D + j];
    for (int mm = 1; mm <= z->p; mm++) {
      double *v = fast_dirs(z, st, x, b, mm, &q0);
      directors(D, v, q0, w);
      nearest_turn(D, ref, w, d);
      set_directors(D, v, q0, d);
      memcpy(ref, d, sizeof ref);
    }
  }
  if (z->slow)
    mrvi_nsslow_start(z->slow, st, x);
  if (z->fast)
    mrvi_nsfast_start(z->fast, st, x);
}

/* QR of the transpose of the k x nc block G (row-major, k rows): Q
 * (nc x nc), R (k x k upper).  -1 if the rows of G are dependent. */
static int block_qr(mrvi_nullspace *z, int k, int nc, const double *G,
                    double *Q, double *R) {
  for (int a = 0; a < nc; a++)
    for (int b = 0; b < k; b++)
      z->A[a * k + b] = G[b * nc + a];
  if (mrvi_dense_qr(nc, k, z->A, Q) < 0)
    return -1;
  for (int a = 0; a < k; a++)
    for (int b = 0; b < k; b++)
      R[a * k + b] = b >= a ? z->A[a * k + b] : 0.0;
  return 0;
}

/* The LU (piv) of G G^T (k x k, into K) of the k x nc block G (row-major):
 * the QR's R^T R, for blocks above its cap.  -1 if singular. */
static int gram_lu(int k, int nc, const double *G, double *K, int *piv) {
  /* column by column over its few nonzero rows (piv: their list) */
  memset(K, 0, (size_t)k * k * sizeof *K);
  for (int c = 0; c < nc; c++) {
    int n = 0;
    for (int a = 0; a < k; a++)
      if (G[a * nc + c] != 0.0)
        piv[n++] = a;
    for (int i = 0; i < n; i++)
      for (int j = 0; j < n; j++)
        K[piv[i] * k + piv[j]] += G[piv[i] * nc + c] * G[piv[j] * nc + c];
  }
  return mrvi_dense_lu_factor(k, K, piv);
}

/* Solve R^T y = u (R k x k upper) in place. */
static void solve_rt(int k, const double *R, double *u) {
  for (int a = 0; a < k; a++) {
    double s = u[a];
    for (int b = 0; b < a; b++)
      s -= R[b * k + a] * u[b];
    u[a] = s / R[a * k + a];
  }
}

/* Solve R y = u (R k x k upper) in place. */
static void solve_r(int k, const double *R, double *u) {
  for (int a = k - 1; a >= 0; a--) {
    double s = u[a];
    for (int b = a + 1; b < k; b++)
      s -= R[a * k + b] * u[b];
    u[a] = s / R[a * k + a];
  }
}

int mrvi_nullspace_lambda(mrvi_nullspace *z, mrvi_step *st, double *x,
                          const double *F, char *msg, size_t len) {
  if (z->tree)
    return mrvi_nstree_lambda(z->tree, st, x, F, msg, len);
  if (z->rods)
    return mrvi_nsrods_lambda(z->rods, st, x, F, msg, len);
  const mrvi_model *m = st->model;
  const int ns = z->ns, nfc = z->nfc, r = z->r, rs = z->rs, rk = z->rk;
  double *lam = x + st->n_unknowns;
  /* Directors of the fast free bodies at nodes 0..p-1, where their
   * analytic basis is built (mrvi_nullspace_reduce). */
  for (int b = 0; b < z->n_frep; b++)
    for (int mm = 0; mm < z->p; mm++) {
      double *d = z->frep_d + 9 * ((size_t)b * (z->p + 1) + mm);
      const double *q0 = NULL, *v = st->qf0 + z->frep_slot[b] + z->dim;
      if (mm > 0)
        v = fast_dirs(z, st, x, b, mm, &q0);
      directors(z->dim, v, q0, d);
    }
  /* Micro-node constraints, node by node. */
  for (int mm = 0; mm < z->p; mm++) {
    const mrvi_point pt = mrvi_step_node_point(st, mm, st->dt);
    double *Q = z->Q + (size_t)mm * (z->gram ? r : nfc) * nfc;
    double *R = z->Rm + (size_t)mm * r * r;
    double *Gs = z->Gs + (size_t)mm * r * ns;
    double *Gb = z->gram ? Q : z->Gf;
    if (r == 0)
      continue;
    memset(Gb, 0, (size_t)(r * nfc) * sizeof *Gb);
    memset(Gs, 0, (size_t)(r * ns) * sizeof *Gs);
    for (int i = 0; i < st->n_micro_c; i++) {
      const int c = st->micro_c[i], off = st->c_off[c];
      const mrvi_constraint *k = &m->constraints[c];
      mrvi_step_constraint_eval(st, c, &pt, x, 0);
      for (int j = 0; j < k->n_in; j++) {
        const int idx = k->in[j], s = m->slot[idx];
        for (int rr = 0; rr < k->rows; rr++) {
          const double v = st->cG[rr * k->n_in + j];
          const int q = z->fkeep[off + rr];
          if (q < 0)
            continue;
          if (m->rate[idx] == MRVI_FAST)
            Gb[q * nfc + z->fpos[s]] += v;
          else
            Gs[q * ns + s] += v;
        }
      }
    }
    if (z->gram ? gram_lu(r, nfc, Gb, R, z->piv + (size_t)mm * r) < 0
                : block_qr(z, r, nfc, Gb, Q, R) < 0)
      return mrvi_fail(msg, len, MRVI_ESINGULAR,
                       "null-space form: the fast parts of the micro-node "
                       "constraints are dependent at micro node %d; use form: "
                       "multipliers",
                       mm);
    /* dt R lambda^m = Q1^T F_m on the kept rows (dt G_f G_f^T lambda^m =
     * G_f F_m: the same least-squares solution), 0 on the redundant ones */
    double *u = z->t, *l = lam + rs + mm * z->rm;
    for (int a = 0; a < r; a++) {
      double s = 0.0;
      for (int b = 0; b < nfc; b++)
        s += (z->gram ? Gb[a * nfc + b] : Q[b * nfc + a]) *
             F[frow(z, mm, z->fc[b])];
      u[a] = s;
    }
    if (z->gram)
      mrvi_dense_lu_solve(r, R, z->piv + (size_t)mm * r, u, 1);
    else
      solve_r(r, R, u);
    for (int e = 0; e < z->rm; e++)
      l[e] = z->fkeep[e] >= 0 ? u[z->fkeep[e]] / st->dt : 0.0;
    if (z->fast &&
        mrvi_nsfast_columns(z->fast, st, x, mm, z->fpos, nfc, Gb,
                            z->Fcol + (size_t)mm * (nfc - r) * nfc) < 0)
      return mrvi_fail(msg, len, MRVI_ESINGULAR,
                       "null-space form: the kept rows of the cut joints are "
                       "dependent on the fast tree's motions at micro node %d; "
                       "use form: multipliers",
                       mm);
  }
  if (rs == 0)
    return MRVI_OK;
  /* Slow-only constraints at q_k: what the slow rows leave after the
   * micro-node forces, dT R_s lambda = Q1s^T (F_s - sum_m dt a0 G_s^T l). */
  double *G = z->Gsl;
  memset(G, 0, (size_t)(rk * z->nsc) * sizeof *G);
  const mrvi_point p0 = mrvi_step_node_point(st, 0, st->dT);
  for (int i = 0; i < st->n_slow_c; i++) {
    const int c = st->slow_c[i], off = st->c_off[c];
    const mrvi_constraint *k = &m->constraints[c];
    mrvi_step_constraint_eval(st, c, &p0, x, 0);
    for (int j = 0; j < k->n_in; j++) {
      const int s = m->slot[k->in[j]];
      int a = 0;
      while (z->sc[a] != s)
        a++;
      for (int rr = 0; rr < k->rows; rr++)
        if (z->srow[off + rr] >= 0)
          G[z->srow[off + rr] * z->nsc + a] += st->cG[rr * k->n_in + j];
    }
  }
  if (block_qr(z, rk, z->nsc, G, z->Qs, z->Rs) < 0)
    return mrvi_fail(
        msg, len, MRVI_ESINGULAR,
        "null-space form: the slow-only constraints are dependent");
  double *u = z->t; /* kept rows, then spread over lam[0..rs) */
  for (int a = 0; a < rk; a++) {
    double s = 0.0;
    for (int b = 0; b < z->nsc; b++) {
      const int sl = z->sc[b];
      double f = F[sl];
      for (int mm = 0; mm < z->p; mm++) {
        const double a0 = 1.0 - (double)mm / z->p;
        const double *Gs = z->Gs + (size_t)mm * r * ns;
        const double *l = lam + rs + mm * z->rm;
        for (int q = 0; q < r; q++)
          f -= st->dt * a0 * Gs[q * ns + sl] * l[z->fk_row[q]];
      }
      s += z->Qs[b * z->nsc + a] * f;
    }
    u[a] = s;
  }
  solve_r(rk, z->Rs, u);
  for (int e = 0; e < rs; e++)
    lam[e] = z->srow[e] >= 0 ? u[z->srow[e]] / st->dT : 0.0;
  return MRVI_OK;
}

/* Column j of the analytic null-space matrix of the free bodies at q_k
 * (Betsch & Leyendecker 2006): P = [[I, 0], [0, -d1^], [0, -d2^],
 * [0, -d3^]] acting on (u, w) (2-D: [[I, 0], [0, J d1], [0, J d2]]).  The
 * columns of u are the unit vectors of phi, which no constraint touches
 * (basis vectors of their own); column j here is body j / nr turning
 * about its rotation j % nr (nr = 3 in 3-D, 1 in 2-D). */
static void free_body_column(const mrvi_nullspace *z, const mrvi_step *st,
                             int j, double *b) {
  const int D = z->dim, nr = D == 3 ? 3 : 1, s0 = z->rep_slot[j / nr];
  mrvi_nullspace_body_rotation(D, st->qs0 + s0 + D, j % nr, b + s0 + D);
}

/* Local column j (0..nfc-r-1) of micro node m for the fast free bodies:
 * body j / nr turning about its rotation j % nr at its directors at node m
 * (recorded by mrvi_nullspace_lambda), over the constrained fast slots fc
 * (col: nfc entries). */
static void fast_body_column(const mrvi_nullspace *z, int m, int j,
                             double *col) {
  const int D = z->dim, nr = D == 3 ? 3 : 1, b = j / nr, s0 = z->frep_slot[b];
  double v[9];
  mrvi_nullspace_body_rotation(D, z->frep_d + 9 * ((size_t)b * (z->p + 1) + m),
                               j % nr, v);
  for (int a = 0; a < z->nfc; a++)
    col[a] = 0.0;
  for (int e = 0; e < D * D; e++)
    col[z->fpos[s0 + D + e]] = v[e];
}

void mrvi_nullspace_reduce(mrvi_nullspace *z, const mrvi_step *st,
                           const double *Rfull, double *rhs) {
  if (z->tree) {
    mrvi_nstree_reduce(z->tree, st, Rfull, rhs);
    return;
  }
  if (z->rods) {
    mrvi_nsrods_reduce(z->rods, st, Rfull, rhs);
    return;
  }
  const int ns = z->ns, nfc = z->nfc, r = z->r, nsc = z->nsc;
  /* Slow basis vectors b (ns each). */
  for (int i = 0; i < z->nbs; i++) {
    double *b = z->B + (size_t)i * ns;
    memset(b, 0, (size_t)ns * sizeof *b);
    const int j = i - (z->nbs - (nsc - z->rk)); /* j-th column of Q2 */
    if (z->b_slot[i] >= 0)
      b[z->b_slot[i]] = 1.0;
    else if (z->n_rep)
      free_body_column(z, st, j, b);
    else
      for (int a = 0; a < nsc; a++)
        b[z->sc[a]] = z->Qs[a * nsc + z->rk + j];
  }
  /* Coefficients in recipe order. */
  long e = 0;
  for (int i = 0; i < z->nbs; i++) {
    const double *b = z->B + (size_t)i * ns;
    if (z->b_slot[i] >= 0)
      z->rec_coef[e++] = 1.0;
    else
      for (int a = 0; a < nsc; a++)
        z->rec_coef[e++] = b[z->sc[a]];
    if (!z->b_coupled[i])
      continue;
    for (int mm = 0; mm < z->p; mm++) {
      /* v_m = -a0 Q1 R^-T (G_s b) */
      const double a0 = 1.0 - (double)mm / z->p;
      const double *Q = z->Q + (size_t)mm * (z->gram ? r : nfc) * nfc;
      const double *R = z->Rm + (size_t)mm * r * r;
      const double *Gs = z->Gs + (size_t)mm * r * ns;
      double *u = z->t;
      for (int q = 0; q < r; q++) {
        double s = 0.0;
        for (int c = 0; c < ns; c++)
          s += Gs[q * ns + c] * b[c];
        u[q] = s;
      }
      /* Q1 R^-T = G_f^T (G_f G_f^T)^-1 */
      if (z->gram)
        mrvi_dense_lu_solve(r, R, z->piv + (size_t)mm * r, u, 1);
      else
        solve_rt(r, R, u);
      for (int a = 0; a < nfc; a++) {
        double s = 0.0;
        for (int q = 0; q < r; q++)
          s += (z->gram ? Q[q * nfc + a] : Q[a * nfc + q]) * u[q];
        z->rec_coef[e++] = -a0 * s;
      }
    }
  }
  for (int mm = 0; mm < z->p; mm++) {
    const double *Q = z->Q + (size_t)mm * (z->gram ? r : nfc) * nfc;
    for (int f = 0; f < z->nf; f++)
      if (z->fpos[f] < 0)
        z->rec_coef[e++] = 1.0;
    for (int j = r; j < nfc; j++) {
      if (z->fast) {
        const double *c = z->Fcol + ((size_t)mm * (nfc - r) + (j - r)) * nfc;
        for (int a = 0; a < nfc; a++)
          z->rec_coef[e++] = c[a];
        continue;
      }
      if (z->n_frep) {
        fast_body_column(z, mm, j - r, z->t);
        for (int a = 0; a < nfc; a++)
          z->rec_coef[e++] = z->t[a];
        continue;
      }
      for (int a = 0; a < nfc; a++)
        z->rec_coef[e++] = Q[a * nfc + j];
    }
  }
  for (int k = 0; k < st->n_lambda - (z->rs - z->rk) - z->p * (z->rm - z->r);
       k++)
    z->rec_coef[e++] = 1.0;
  /* Rows of the reduced system: combinations of the full rows. */
  const mrvi_row_recipe rr = {z->n,   z->rec_start, z->rec_row,
                              NULL,   z->csr_start, z->csr_idx,
                              z->map, z->rec_coef,  NULL};
  mrvi_row_recipe_apply(&rr, st, Rfull, z->Ax, z->nnz, rhs);
}

void mrvi_row_recipe_apply(const mrvi_row_recipe *r, const mrvi_step *st,
                           const double *R, double *Ax, long nnz, double *rhs) {
  memset(Ax, 0, (size_t)nnz * sizeof *Ax);
  long t = 0;
  for (int i = 0; i < r->n; i++) {
    double s = 0.0;
    for (int k = r->rec_start[i]; k < r->rec_start[i + 1]; k++) {
      const int row = r->rec_row[k];
      const double c = r->rec_coef[k];
      s += c * R[row];
      for (int q = r->csr_start[row]; q < r->csr_start[row + 1]; q++)
        Ax[r->map[t++]] += c * st->Ax[r->csr_idx[q]];
    }
    if (r->ext_start)
      for (int k = r->ext_start[i]; k < r->ext_start[i + 1]; k++)
        Ax[r->map[t++]] += r->ext_coef[k];
    rhs[i] = s;
  }
}
