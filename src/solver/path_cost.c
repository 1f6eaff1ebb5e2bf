/* Cost estimates of the two paths of a constrained step in the multiplier
 * form (doc/solver.md, "Choosing between general and schur-bordered";
 * measured with bench_paths: doc/performance/paths.md, "Constrained paths: the
 * choice by cost estimates" and "Constrained paths: per-step costs"): the
 * work of one macro step's linear algebra, which is all the two paths do
 * differently (both assemble the same CSC Jacobian, step.c, from the same
 * predictor).  Counted from the structure alone, so that the choice is
 * deterministic.  The step's pattern J is built from the model
 * (step_pattern), and on it:
 *
 *  - general (solver/newton.c) factors the n x n step by an LU in dense
 *    storage that skips zeros: it clears, scans and lists n^2 entries, and
 *    eliminates with the fill of its ordering (J ordered as newton.c
 *    orders it and eliminated symbolically, lu_flops: without pivoting,
 *    2 |L_k| |U_k| per pivot, L flops), for every Newton update:
 *
 *        E_g = u (c_i (w n^2 + L) + K_g)
 *
 *    (the Jacobian it assembles anew for each update after the first is
 *    left to c_i and K_g: a term per nonzero did not improve the choice);
 *  - schur-bordered (solver/bordered.c) eliminates the node blocks
 *    (bordered_flops: the LU of each fast node block D_c that skips zeros,
 *    the solves for the slow columns A_fs has entries in and their
 *    products into S, S's LU, and with macro-node constraints only the
 *    bordering by their r_s multipliers) once per step, F_b flops, and
 *    solves the later updates with the kept factors (simplified Newton,
 *    integrator.c: S_b flops each):
 *
 *        E_b = F_b + K_b + (u - 1) S_b.
 *
 * u = path_updates (Newton updates per macro step), c_i = path_index_cost
 * (an indexed flop of the LU that skips zeros against one of the dense
 * blocks), w = path_entry_cost (per stored entry), K_g and K_b =
 * path_factor_general and path_factor_bordered (the fixed cost of a
 * factorisation: calls, clearing, pivot searches), all in flops of the dense
 * block kernels and measured across the shipped systems (MRVI_TUNING_LIST).
 * Beyond newton_dense_max, and above MRVI_NEWTON_DENSE_SURE rows where
 * newton.c's own decision (mrvi_newton_dense_chosen, taken here on the
 * pattern J) prefers it by flops, the general path takes UMFPACK, whose
 * fixed costs and fill this does not model: there general is HUGE_VAL and
 * the structured path is kept, as measured (the spacecraft and the
 * flexible pendulum at p >= 5 and 20).
 */
#include "solver/solver.h"

#include <math.h>
#include <stdlib.h>

/* Mark the pairs of inputs in[0..k) in the n x n pattern P. */
static void couple(unsigned char *P, int n, const int *in, int k) {
  for (int i = 0; i < k; i++)
    for (int j = 0; j < k; j++)
      P[(size_t)in[i] * (size_t)n + (size_t)in[j]] = 1;
}

/* Mark in P the pairs of a constraint's inputs that its second
 * derivatives couple: the nonzeros of lambda^T hess g at the initial
 * configuration and at a fixed displacement of it (so that entries zero
 * by the symmetry of the initial state count; a body's director
 * orthonormality d_i . d_j couples component k of d_i with component k of
 * d_j alone, not all its inputs pairwise). */
static int constraint_hessian(const mrvi_model *m, const mrvi_constraint *ct,
                              unsigned char *P) {
  const int k = ct->n_in, r = ct->rows, n = m->n;
  double *y = malloc((size_t)k * sizeof *y), *g = malloc((size_t)r * sizeof *g),
         *G = malloc((size_t)r * (size_t)k * sizeof *G),
         *H = malloc((size_t)r * (size_t)k * (size_t)k * sizeof *H);
  if (!y || !g || !G || !H) {
    free(y), free(g), free(G), free(H);
    return MRVI_ENOMEM;
  }
  for (int t = 0; t < 2; t++) {
    for (int i = 0; i < k; i++)
      y[i] = m->q0[ct->in[i]] + (t ? 0.01 * (i + 1) : 0.0);
    ct->type->eval(k, ct->n_params, ct->params, y, g, G, H);
    for (int i = 0; i < k; i++)
      for (int j = 0; j < k; j++) {
        int nz = i == j;
        for (int l = 0; l < r && !nz; l++) {
          const double h =
              H[((size_t)l * (size_t)k + (size_t)i) * (size_t)k + (size_t)j];
          nz = h != 0.0; /* (a NaN counts too) */
        }
        if (nz)
          P[(size_t)ct->in[i] * (size_t)n + (size_t)ct->in[j]] = 1;
      }
  }
  free(y), free(g), free(G), free(H);
  return MRVI_OK;
}

/* The step's pattern as rows of bits (nw words each). */
typedef struct {
  int n, nw;
  unsigned long long *bits;
} pattern;

static void set(pattern *J, int r, int c) {
  J->bits[(size_t)r * (size_t)J->nw + (size_t)(c / 64)] |= 1ULL << (c % 64);
}

static int get(const pattern *J, int r, int c) {
  return (int)(J->bits[(size_t)r * (size_t)J->nw + (size_t)(c / 64)] >>
               (c % 64)) &
         1;
}

/* The multiplier form's step pattern (step.h's layout, as
 * solver/bordered.c reads it) from the coupling pattern P of the model's
 * coordinates: unknowns q_{k+1}^s (row: the slow row), the fast nodes
 * 1..p (row c: fast row c, coupled to the nodes c-1 .. c+1), the r_s
 * multipliers of the macro-node constraints (rows: their equations at node
 * k+1) and those of the micro nodes (column lambda^m, m = 0..p-1, and row
 * g(z^{m+1}) share block m). */
static void step_pattern(const mrvi_model *m, const unsigned char *P, int p,
                         int rs, int rf, pattern *J) {
  const int n = m->n, ns = m->n_slow, nf = m->n_fast, nu = ns + p * nf;
  for (int u = 0; u < n; u++)
    for (int v = 0; v < n; v++) {
      if (!P[(size_t)u * (size_t)n + (size_t)v])
        continue;
      const int su = m->rate[u] == MRVI_SLOW, sv = m->rate[v] == MRVI_SLOW;
      const int a = m->slot[u], b = m->slot[v];
      if (su && sv)
        set(J, a, b);
      for (int c = 0; c < p; c++) {
        if (su && !sv)
          set(J, a, ns + c * nf + b);
        else if (!su && sv)
          set(J, ns + c * nf + a, b);
        else if (!su)
          for (int d = c - 2; d <= c; d++)
            if (d >= 0)
              set(J, ns + c * nf + a, ns + d * nf + b);
      }
    }
  int js = 0, jm = 0;
  for (int k = 0; k < m->n_constraints; k++) {
    const mrvi_constraint *ct = &m->constraints[k];
    for (int r = 0; r < ct->rows; r++) {
      for (int i = 0; i < ct->n_in; i++) {
        const int u = ct->in[i], slow = m->rate[u] == MRVI_SLOW;
        const int a = m->slot[u];
        if (ct->where == MRVI_SLOW) { /* at node k+1 = fast node p */
          const int x = slow ? a : ns + (p - 1) * nf + a, l = nu + js + r;
          set(J, l, x);
          set(J, x, l);
          continue;
        }
        for (int c = 0; c < p; c++) {
          const int l = nu + rs + c * rf + jm + r;
          /* g(z^{c+1}): node c+1's fast and the slow unknowns */
          set(J, l, slow ? a : ns + c * nf + a);
          /* lambda^c: fast row c (node c) and the slow row */
          set(J, slow ? a : ns + c * nf + a, l);
        }
      }
    }
    *(ct->where == MRVI_SLOW ? &js : &jm) += ct->rows;
  }
}

/* Flops of the general path's dense LU that skips zeros on pattern J:
 * rows and columns ordered by increasing nonzero count of row plus column
 * (stably, as solver/newton.c), then Gaussian elimination without
 * pivoting on the bits, 2 |L_k| |U_k| per pivot with the fill. */
static double lu_flops(pattern *J, int *deg, int *order) {
  const int n = J->n;
  for (int i = 0; i < n; i++)
    deg[i] = 0;
  for (int r = 0; r < n; r++)
    for (int c = 0; c < n; c++)
      if (get(J, r, c))
        deg[r]++, deg[c]++;
  for (int i = 0; i < n; i++) {
    int k = i;
    for (; k > 0 && deg[order[k - 1]] > deg[i]; k--)
      order[k] = order[k - 1];
    order[k] = i;
  }
  /* B = J renumbered, in the upper half of the bits (rows n..2n-1) */
  pattern B = {n, J->nw, J->bits + (size_t)n * (size_t)J->nw};
  for (int r = 0; r < n; r++)
    for (int c = 0; c < n; c++)
      if (get(J, order[r], order[c]))
        set(&B, r, c);
  double flops = 0.0;
  for (int k = 0; k < n; k++) {
    long u = 0;
    for (int c = k + 1; c < n; c++)
      u += get(&B, k, c);
    const unsigned long long *bk = B.bits + (size_t)k * (size_t)B.nw;
    for (int i = k + 1; i < n; i++) {
      if (!get(&B, i, k))
        continue;
      flops += 2.0 * (double)u + 1.0;
      unsigned long long *bi = B.bits + (size_t)i * (size_t)B.nw;
      for (int w = k / 64; w < B.nw; w++)
        bi[w] |= bk[w];
    }
  }
  return flops;
}

/* Gaussian elimination without pivoting of the k x k pattern D (bytes,
 * row-major, modified: the fill), 2 |L_k| |U_k| + |L_k| flops per pivot,
 * as mrvi_dense_lu_factor_nz skips zeros; its factors' nonzeros in *nz. */
static double block_lu_flops(unsigned char *D, int k, long *nz) {
  double flops = 0.0;
  long z = 0;
  for (int r = 0; r < k; r++) {
    long u = 0;
    for (int c = r + 1; c < k; c++)
      u += D[(size_t)r * (size_t)k + (size_t)c];
    z += u + 1;
    for (int i = r + 1; i < k; i++) {
      unsigned char *di = D + (size_t)i * (size_t)k;
      if (!di[r])
        continue;
      z++;
      flops += 2.0 * (double)u + 1.0;
      for (int c = r + 1; c < k; c++)
        di[c] |= D[(size_t)r * (size_t)k + (size_t)c];
    }
  }
  *nz = z;
  return flops;
}

/* Entries of J in rows R[0..nr) and columns C[0..nc). */
static long block_nnz(const pattern *J, const int *R, int nr, const int *C,
                      int nc) {
  long z = 0;
  for (int i = 0; i < nr; i++)
    for (int j = 0; j < nc; j++)
      z += get(J, R[i], C[j]);
  return z;
}

/* Row (and column) of J of unknown i of fast node block c: its fast
 * unknowns (i < nf), then its micro-node multipliers (step_pattern's
 * layout). */
static int node_row(int ns, int nf, int nu, int rs, int rf, int c, int i) {
  return i < nf ? ns + c * nf + i : nu + rs + c * rf + (i - nf);
}

/* schur-bordered's factorisation and kept-factor solve on pattern J, in
 * flops (solver/bordered.c): for each fast node block c (rows and columns
 * F_c: its fast unknowns, with micro-node constraints its multipliers) the
 * LU of D_c that skips zeros, Y_c = D_c^-1 (A_fs,c - L1_c Y_{c-1} -
 * L2_c Y_{c-2}) on the kv slow columns that A_fs has an entry in (a dense
 * solve, 2 b^2 kv, and the products with L1, L2) and its product A_sf,c Y_c
 * into S; then S's LU, and with macro-node constraints only, the bordering
 * by their r multipliers.  A solve with kept factors: one sweep of the
 * same blocks with one column. */
static int bordered_flops(const mrvi_model *m, const pattern *J, int p, int rs,
                          int rf, double *factor, double *solve) {
  const int ns = m->n_slow, nf = m->n_fast, nu = ns + p * nf;
  const int b = nf + rf, a = ns + (rf > 0 ? rs : 0);
  int *S = malloc(((size_t)a + 1) * sizeof *S),
      *F = malloc(3 * ((size_t)b + 1) * sizeof *F);
  unsigned char *D = malloc((size_t)b * (size_t)b + 1);
  if (!S || !F || !D) {
    free(S), free(F), free(D);
    return MRVI_ENOMEM;
  }
  for (int i = 0; i < a; i++)
    S[i] = i < ns ? i : nu + (i - ns);
  /* F + (c % 3) b: the rows and columns of node block c */
  const int *Fc[3] = {F, F + b, F + 2 * b};
  /* the slow columns with an entry in A_fs at any node */
  int kv = 0;
  for (int j = 0; j < a; j++) {
    int hit = 0;
    for (int c = 0; c < p && !hit; c++)
      for (int i = 0; i < b && !hit; i++)
        hit = get(J, node_row(ns, nf, nu, rs, rf, c, i), S[j]);
    kv += hit;
  }
  double f = 0.0, sv = 0.0;
  for (int c = 0; c < p; c++) {
    int *Rc = F + (c % 3) * b;
    for (int i = 0; i < b; i++)
      Rc[i] = node_row(ns, nf, nu, rs, rf, c, i);
    for (int i = 0; i < b; i++)
      for (int j = 0; j < b; j++)
        D[(size_t)i * (size_t)b + (size_t)j] =
            (unsigned char)get(J, Rc[i], Rc[j]);
    long lu_nz;
    const double lu = block_lu_flops(D, b, &lu_nz);
    const long l1 = c >= 1 ? block_nnz(J, Rc, b, Fc[(c - 1) % 3], b) : 0,
               l2 = c >= 2 ? block_nnz(J, Rc, b, Fc[(c - 2) % 3], b) : 0,
               sf = block_nnz(J, S, a, Rc, b), fs = block_nnz(J, Rc, b, S, a);
    f += lu + 2.0 * (double)b * b * kv + 2.0 * (double)(l1 + l2 + sf) * kv;
    sv += 2.0 * (double)lu_nz + 2.0 * (double)(l1 + l2 + sf + fs);
  }
  const double A = a;
  f += 2.0 / 3.0 * A * A * A;
  sv += 2.0 * A * A;
  if (rf == 0 && rs > 0) { /* W = S^-1 B_s, K = -C_s W and its LU */
    const double r = rs;
    f += 2 * r * A * A + 2 * r * r * A + 2.0 / 3.0 * r * r * r;
    sv += 4 * r * A + 2 * r * r;
  }
  *factor = f;
  *solve = sv;
  free(S), free(F), free(D);
  return MRVI_OK;
}

/* Whether the general path's Newton solver (solver/newton.c) takes its
 * dense LU on the step's pattern J: its own decision
 * (mrvi_newton_dense_chosen) on J in compressed columns, from the pattern
 * alone (1 dense, 0 UMFPACK, < 0 out of memory). */
static int general_dense(const pattern *J, int dense_max) {
  const int n = J->n;
  if (n > dense_max || n <= MRVI_NEWTON_DENSE_SURE)
    return n <= dense_max;
  long nnz = 0;
  for (int r = 0; r < n; r++)
    for (int c = 0; c < n; c++)
      nnz += get(J, r, c);
  int *Ap = malloc(((size_t)n + 1) * sizeof *Ap),
      *Ai = malloc(((size_t)nnz + 1) * sizeof *Ai);
  int dense = MRVI_ENOMEM;
  if (Ap && Ai) {
    int e = 0;
    for (int c = 0; c < n; c++) {
      Ap[c] = e;
      for (int r = 0; r < n; r++)
        if (get(J, r, c))
          Ai[e++] = r;
    }
    Ap[n] = e;
    dense = mrvi_newton_dense_chosen(n, Ap, Ai, NULL, dense_max);
  }
  free(Ap), free(Ai);
  return dense;
}

int mrvi_path_costs(const mrvi_model *m, const mrvi_settings *s,
                    mrvi_path_cost *c) {
  const int n = m->n, p = s->micro_steps;
  unsigned char *P = calloc((size_t)n * (size_t)n + 1, 1);
  if (!P)
    return MRVI_ENOMEM;
  for (int i = 0; i < n; i++)
    P[(size_t)i * (size_t)n + (size_t)i] = 1;
  for (int e = 0; e < m->n_elements; e++) {
    const mrvi_element *el = MRVI_ELEMENT(m, e);
    /* (gravity and constant forces are linear: no Hessian) */
    if (el->kind != MRVI_ELEMENT_GRAVITY && el->kind != MRVI_ELEMENT_FORCE)
      couple(P, n, el->in, el->n_in);
  }
  int rs = 0, rf = 0;
  int st = MRVI_OK;
  for (int k = 0; k < m->n_constraints && st == MRVI_OK; k++) {
    const mrvi_constraint *ct = &m->constraints[k];
    st = constraint_hessian(m, ct, P);
    *(ct->where == MRVI_SLOW ? &rs : &rf) += ct->rows;
  }
  if (st < 0) {
    free(P);
    return st;
  }
  const mrvi_tuning *t = &s->tuning;
  c->r_slow = rs;
  c->r_micro = rf;
  c->n = m->n_slow + rs + (long)p * (m->n_fast + rf);
  c->nnz = -1;
  c->a = m->n_slow + (rf > 0 ? rs : 0);
  c->b = m->n_fast + rf;
  c->general = HUGE_VAL; /* UMFPACK's: not modelled */
  c->general_dense = 0;
  c->bordered = 0.0;
  if (c->n <= t->newton_dense_max) {
    const int nj = (int)c->n, nw = (nj + 63) / 64;
    pattern J = {nj, nw, calloc(2 * (size_t)nj * (size_t)nw + 1, 8)};
    int *deg = malloc(((size_t)nj + 1) * sizeof *deg),
        *order = malloc(((size_t)nj + 1) * sizeof *order);
    if (!J.bits || !deg || !order) {
      free(J.bits), free(deg), free(order), free(P);
      return MRVI_ENOMEM;
    }
    step_pattern(m, P, p, rs, rf, &J);
    c->nnz = 0;
    for (size_t i = 0; i < (size_t)nj * (size_t)nw; i++)
      for (unsigned long long x = J.bits[i]; x; x &= x - 1)
        c->nnz++;
    double fb = 0.0, sb = 0.0;
    st = bordered_flops(m, &J, p, rs, rf, &fb, &sb);
    if (st == MRVI_OK)
      c->general_dense = general_dense(&J, t->newton_dense_max);
    if (c->general_dense < 0)
      st = c->general_dense;
    /* Per macro step of u Newton updates: general factorises for each (its
     * LU that skips zeros, weighted, and a fixed cost); schur-bordered for
     * the first, and solves the others with the kept factors. */
    const double nn = (double)nj, u = t->path_updates;
    if (c->general_dense > 0) {
      const double fg = t->path_index_cost * (t->path_entry_cost * nn * nn +
                                              lu_flops(&J, deg, order));
      c->general = u * (fg + t->path_factor_general);
    }
    c->bordered = fb + t->path_factor_bordered + (u - 1.0) * sb;
    free(J.bits), free(deg), free(order);
  }
  free(P);
  return st;
}
