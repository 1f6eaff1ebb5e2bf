/* One macro step in position-momentum form (arXiv 2406.12991 §3.1,
 * doc/solver.md, eq:DEL_ini).
 *
 * Unknowns x = (q_{k+1}^s, q_k^{f,1}, ..., q_k^{f,p}), size ns + p nf.
 * Residual rows:
 *   slow          p_k^s     + D_{q_k^s}     L_d = 0        (ns rows)
 *   fast node 0   p_k^{f,0} + D_{q_k^{f,0}} L_d = 0        (nf rows)
 *   fast node m               D_{q_k^{f,m}} L_d = 0        (nf rows, m
 * = 1..p-1) Row of fast node m (0..p-1): ns + m nf + slot; column of fast node
 * m (1..p): ns + (m-1) nf + slot; slow row and column: slot.
 *
 * L_d = T_d - V_d - W_d.  Every potential term is a sum of evaluation points
 * (quadrature.c); a point with weight w and node coefficients c contributes
 * -w c_a grad Z to D_{X_a} L_d and -w c_a c_b hess Z to its derivative.  The
 * same loop serves every rule: there is no scheme-specific derivative. */
#include "step/step.h"
#include "util/simd.h"
#include "util/small.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/umfpack.h>

/* Value of fast node m (0..p) in slot.  With st->increments the unknowns
 * are displacements from the known node values (q_k^s, q_k^{f,0}). */
static inline double fast_node(const mrvi_step *st, const double *x, int m,
                               int slot) {
  if (m == 0)
    return st->qf0[slot];
  const double v = x[st->ns + (m - 1) * st->nf + slot];
  return st->increments ? st->qf0[slot] + v : v;
}

/* q^{f,m+1} - q^{f,m} in slot: from the displacements directly with
 * st->increments, so that tiny steps lose no digits to |q|. */
static inline double fast_diff(const mrvi_step *st, const double *x, int m,
                               int slot) {
  if (!st->increments)
    return fast_node(st, x, m + 1, slot) - fast_node(st, x, m, slot);
  const double *d = x + st->ns + slot;
  return d[m * st->nf] - (m == 0 ? 0.0 : d[(m - 1) * st->nf]);
}

/* Slow part a0 q_k^s + a1 q_{k+1}^s of a point, and q_{k+1}^s - q_k^s. */
static inline double slow_at(const mrvi_step *st, const double *x, double a0,
                             double a1, int s) {
  return st->increments ? st->qs0[s] + a1 * x[s] : a0 * st->qs0[s] + a1 * x[s];
}
static inline double slow_diff(const mrvi_step *st, const double *x, int s) {
  return st->increments ? x[s] : x[s] - st->qs0[s];
}

/* Inputs of element e at point pt. */
static void gather(const mrvi_step *st, const mrvi_element *e,
                   const mrvi_point *pt, const double *x, double *y) {
  const mrvi_model *m = st->model;
  for (int j = 0; j < e->n_in; j++) {
    const int c = e->in[j], s = m->slot[c];
    if (m->rate[c] == MRVI_SLOW)
      y[j] = slow_at(st, x, pt->a0, pt->a1, s);
    else
      y[j] = pt->cA * fast_node(st, x, pt->m, s) +
             pt->cB * fast_node(st, x, pt->m + 1, s);
  }
}

static void potential_momenta(const mrvi_step *st, const mrvi_element *e,
                              const mrvi_point *pt, double *ps1, double *pf);

/* Residual rows (at most 2) that input c feeds at point pt, with their node
 * coefficients.  Returns the count.  (Inline for the assembly loop; the
 * exported mrvi_step_rows_of is the same.) */
static inline int rows_of(const mrvi_step *st, int c, const mrvi_point *pt,
                          int *row, double *coef) {
  const mrvi_model *m = st->model;
  const int s = m->slot[c];
  int n = 0;
  if (m->rate[c] == MRVI_SLOW) {
    if (pt->a0 != 0.0) {
      row[n] = s;
      coef[n++] = pt->a0;
    }
    return n;
  }
  if (pt->cA != 0.0) {
    row[n] = st->ns + pt->m * st->nf + s;
    coef[n++] = pt->cA;
  }
  if (pt->cB != 0.0 && pt->m + 1 <= st->p - 1) {
    row[n] = st->ns + (pt->m + 1) * st->nf + s;
    coef[n++] = pt->cB;
  }
  return n;
}

/* Unknown columns (at most 2) that input c depends on at point pt. */
static inline int cols_of(const mrvi_step *st, int c, const mrvi_point *pt,
                          int *col, double *coef) {
  const mrvi_model *m = st->model;
  const int s = m->slot[c];
  int n = 0;
  if (m->rate[c] == MRVI_SLOW) {
    if (pt->a1 != 0.0) {
      col[n] = s;
      coef[n++] = pt->a1;
    }
    return n;
  }
  if (pt->cA != 0.0 && pt->m >= 1) {
    col[n] = st->ns + (pt->m - 1) * st->nf + s;
    coef[n++] = pt->cA;
  }
  if (pt->cB != 0.0) {
    col[n] = st->ns + pt->m * st->nf + s;
    coef[n++] = pt->cB;
  }
  return n;
}

int mrvi_step_rows_of(const mrvi_step *st, int c, const mrvi_point *pt,
                      int *row, double *coef) {
  return rows_of(st, c, pt, row, coef);
}

int mrvi_step_cols_of(const mrvi_step *st, int c, const mrvi_point *pt,
                      int *col, double *coef) {
  return cols_of(st, c, pt, col, coef);
}

/* The recording pass of jac_add: the entry's row and column. */
static void jac_record(mrvi_step *st, int row, int col) {
  if (st->n_trip == st->cap_trip) {
    long c = st->cap_trip ? 2 * st->cap_trip : 1024;
    int *ti = realloc(st->Ti, (size_t)c * sizeof *ti);
    if (ti)
      st->Ti = ti;
    int *tj = realloc(st->Tj, (size_t)c * sizeof *tj);
    if (tj)
      st->Tj = tj;
    if (!ti || !tj) {
      st->recording = -1; /* out of memory: reported by build_pattern */
      return;
    }
    st->cap_trip = c;
  }
  st->Ti[st->n_trip] = row;
  st->Tj[st->n_trip] = col;
  st->n_trip++;
}

/* Add v at (row, col): records the pattern on the first pass, then sums into
 * the CSC values through the triplet map.  Both passes make the same calls
 * because every skip depends on structure (weights, coefficients) only. */
static inline void jac_add(mrvi_step *st, int row, int col, double v) {
  if (st->recording == 0)
    st->Ax[st->map[st->n_trip++]] += v;
  else if (st->recording > 0)
    jac_record(st, row, col);
}

/* Split the model's constraints into slow-only (macro nodes) and micro-node
 * ones and size the multiplier block (doc/constraints.md). */
static int init_constraints(mrvi_step *st) {
  const mrvi_model *m = st->model;
  const int nc = m->n_constraints;
  const size_t ci =
      (size_t)(m->max_constraint_in > 0 ? m->max_constraint_in : 1);
  st->slow_c = malloc((size_t)(nc + 1) * sizeof(int));
  st->micro_c = malloc((size_t)(nc + 1) * sizeof(int));
  st->c_off = malloc((size_t)(nc + 1) * sizeof(int));
  st->cy = malloc(ci * sizeof(double));
  st->cg = malloc(ci * sizeof(double));
  st->cG = malloc(ci * ci * sizeof(double));
  st->cH = malloc(ci * ci * ci * sizeof(double));
  if (!st->slow_c || !st->micro_c || !st->c_off || !st->cy || !st->cg ||
      !st->cG || !st->cH)
    return MRVI_ENOMEM;
  for (int c = 0; c < nc; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    if (k->where == MRVI_SLOW) {
      st->slow_c[st->n_slow_c++] = c;
      st->c_off[c] = st->r_slow;
      st->r_slow += k->rows;
    } else {
      st->micro_c[st->n_micro_c++] = c;
      st->c_off[c] = st->r_micro;
      st->r_micro += k->rows;
    }
  }
  st->n_lambda = st->r_slow + st->p * st->r_micro;
  st->n_total = st->n_unknowns + st->n_lambda;
  return MRVI_OK;
}

int mrvi_step_init(mrvi_step *st, const mrvi_model *m, const mrvi_settings *s) {
  memset(st, 0, sizeof *st);
  st->model = m;
  st->p = s->micro_steps;
  st->ns = m->n_slow;
  st->nf = m->n_fast;
  st->dT = s->macro_step;
  st->dt = s->macro_step / s->micro_steps;
  st->n_unknowns = st->ns + st->p * st->nf;
  st->tuning = s->tuning;
  st->threads = mrvi_threads_resolve(s->threads);
  const mrvi_rule rules[2] = {s->slow, s->fast};
  const mrvi_grid grids[2] = {s->slow_grid, MRVI_GRID_MICRO};
  int max_n_in = 1;
  for (int c = 0; c < 2; c++) {
    st->pts[c] = malloc((size_t)(2 * st->p + 2) * sizeof(mrvi_point));
    if (!st->pts[c])
      return MRVI_ENOMEM;
    st->n_pts[c] =
        mrvi_quadrature_points(rules[c], grids[c], st->dT, st->p, st->pts[c]);
  }
  /* (the records read directly: a compact spring has 2 d inputs, its
   * ends' d consecutive coordinates each, mrvi_model_compact; the lists
   * and counts in locals, which the stores do not alias) */
  const int d = m->dimension;
  /* Each class's count and span: a class whose elements are consecutive
   * (a network's springs added class by class) keeps no list. */
  int count[2] = {0}, last[2] = {-1, -1};
  for (int e = 0; e < m->n_elements; e++) {
    const int pot = m->erecs[e].potential;
    if (count[pot]++ == 0)
      st->elem_first[pot] = e;
    last[pot] = e;
  }
  int *list[2] = {NULL, NULL};
  for (int c = 0; c < 2; c++)
    if (count[c] > 0 && last[c] - st->elem_first[c] + 1 != count[c]) {
      list[c] = st->elem_of_class[c] = malloc((size_t)count[c] * sizeof(int));
      if (!list[c])
        return MRVI_ENOMEM;
    }
  count[0] = count[1] = 0;
  int compact = 0;
  for (int e = 0; e < m->n_elements; e++) {
    const int pot = m->erecs[e].potential;
    if (list[pot])
      list[pot][count[pot]] = e;
    count[pot]++;
    if (m->erecs[e].compact) {
      compact = 1;
      continue;
    }
    const int n_in = mrvi_model_element(m, e, NULL)->n_in;
    max_n_in = n_in > max_n_in ? n_in : max_n_in;
  }
  st->n_elem_of_class[0] = count[0];
  st->n_elem_of_class[1] = count[1];
  max_n_in = compact && 2 * d > max_n_in ? 2 * d : max_n_in;
  /* The first element of W (in element order) with a slow input. */
  st->fast_on_slow = -1;
  for (int i = 0; st->fast_on_slow < 0 && i < count[MRVI_FAST]; i++) {
    const int e = MRVI_STEP_ELEM(st, MRVI_FAST, i);
    if (mrvi_model_element_rates(m, e) & (1 << MRVI_SLOW))
      st->fast_on_slow = e;
  }
  const size_t mi = (size_t)(m->max_in > 0 ? m->max_in : 1);
  st->y = malloc((size_t)max_n_in * sizeof(double));
  st->g = malloc((size_t)max_n_in * sizeof(double));
  st->H = malloc(mi * mi * sizeof(double));
  st->kin = malloc((size_t)(4 * (st->nf > 0 ? st->nf : 1)) * sizeof(double));
  if (!st->y || !st->g || !st->H || !st->kin)
    return MRVI_ENOMEM;
  return init_constraints(st);
}

const int *mrvi_step_class_list(const mrvi_step *st, int c, int **own) {
  *own = NULL;
  if (st->elem_of_class[c])
    return st->elem_of_class[c];
  const int n = st->n_elem_of_class[c];
  if (!(*own = malloc((size_t)(n > 0 ? n : 1) * sizeof(int))))
    return NULL;
  for (int i = 0; i < n; i++)
    (*own)[i] = st->elem_first[c] + i;
  return *own;
}

void mrvi_step_free(mrvi_step *st) {
  if (!st)
    return;
  for (int c = 0; c < 2; c++) {
    free(st->pts[c]);
    free(st->elem_of_class[c]);
  }
  free(st->Ti);
  free(st->Tj);
  free(st->map);
  free(st->Ax);
  free(st->Ap);
  free(st->Ai);
  free(st->y);
  free(st->g);
  free(st->H);
  free(st->kin);
  free(st->slow_c);
  free(st->micro_c);
  free(st->c_off);
  free(st->cy);
  free(st->cg);
  free(st->cG);
  free(st->cH);
  memset(st, 0, sizeof *st);
}

/* Kinetic part of the residual and Jacobian (T_d of §3.3). */
static void assemble_kinetic(mrvi_step *st, const double *x, double *R,
                             int jac) {
  const mrvi_model *m = st->model;
  const int ns = st->ns, nf = st->nf, p = st->p;
  /* slow: p_k^s - M^s (q_{k+1}^s - q_k^s)/dT */
  for (int s = 0; s < ns; s++) {
    const double M = MRVI_MASS(m, m->slow_index[s]);
    R[s] = st->ps0[s] - M * slow_diff(st, x, s) / st->dT;
    if (jac)
      jac_add(st, s, s, -M / st->dT);
  }
  /* fast node 0: p_k^{f,0} - M^f (q^{f,1} - q^{f,0})/dt;
   * node m >= 1: M^f (q^m - q^{m-1})/dt - M^f (q^{m+1} - q^m)/dt (the
   * velocity of interval m - 1 kept from node m - 1, the masses' entries
   * formed once per call: the same values) */
  double *km = st->kin, *kd = km + nf, *k2 = kd + nf, *vl = k2 + nf;
  for (int s = 0; s < nf; s++) {
    const double M = MRVI_MASS(m, m->fast_index[s]);
    km[s] = M;
    kd[s] = -M / st->dt;
    k2[s] = 2.0 * M / st->dt;
  }
  for (int mm = 0; mm < p; mm++)
    for (int s = 0; s < nf; s++) {
      const double M = km[s];
      const int row = ns + mm * nf + s;
      const double vr = fast_diff(st, x, mm, s) / st->dt;
      if (mm == 0)
        R[row] = st->pf0[s] - M * vr;
      else
        R[row] = M * (vl[s] - vr);
      vl[s] = vr;
      if (jac) {
        if (mm >= 2)
          jac_add(st, row, ns + (mm - 2) * nf + s, kd[s]);
        if (mm >= 1)
          jac_add(st, row, ns + (mm - 1) * nf + s, k2[s]);
        jac_add(st, row, ns + mm * nf + s, kd[s]);
      }
    }
}

mrvi_point mrvi_step_node_point(const mrvi_step *st, int m, double w) {
  return (mrvi_point){.w = w,
                      .a0 = 1.0 - (double)m / st->p,
                      .a1 = (double)m / st->p,
                      .cA = 1.0,
                      .cB = 0.0,
                      .m = m};
}

int mrvi_step_same_points(const mrvi_step *st) {
  if (st->n_pts[0] != st->n_pts[1])
    return 0;
  for (int ip = 0; ip < st->n_pts[0]; ip++) {
    const mrvi_point *u = &st->pts[0][ip], *v = &st->pts[1][ip];
    if (!(u->m == v->m && u->w == v->w && u->a0 == v->a0 && u->a1 == v->a1 &&
          u->cA == v->cA && u->cB == v->cB))
      return 0;
  }
  return 1;
}

/* mrvi_step_constraint_at, inline in both exported forms (a call from one
 * to the other would go through the library's symbol table). */
static inline void constraint_at(const mrvi_step *st, int c,
                                 const mrvi_point *pt, const double *x,
                                 double *y, double *g, double *G, double *H) {
  const mrvi_model *m = st->model;
  const mrvi_constraint *k = &m->constraints[c];
  for (int j = 0; j < k->n_in; j++) {
    const int idx = k->in[j], s = m->slot[idx];
    y[j] = m->rate[idx] == MRVI_SLOW ? slow_at(st, x, pt->a0, pt->a1, s)
                                     : fast_node(st, x, pt->m, s);
  }
  mrvi_constraint_eval_at(k, y, g, G, H);
}

void mrvi_step_constraint_at(const mrvi_step *st, int c, const mrvi_point *pt,
                             const double *x, double *y, double *g, double *G,
                             double *H) {
  constraint_at(st, c, pt, x, y, g, G, H);
}

void mrvi_step_constraint_eval(mrvi_step *st, int c, const mrvi_point *pt,
                               const double *x, int hess) {
  constraint_at(st, c, pt, x, st->cy, st->cg, st->cG, hess ? st->cH : NULL);
}

/* Constraint force -w G(z)^T lambda of constraint c at node point pt into
 * the rows the node feeds, with its derivatives: lambda columns starting at
 * lcol, and -w c_row c_col sum_r lambda_r d2g_r on the unknown columns.
 * The caller has evaluated g, G (and, if the node has unknown columns and
 * jac and c is not affine, the second derivatives) at pt.  An affine
 * constraint's second derivatives are zero: its entries keep their place
 * in the pattern (recorded as for any constraint) and get nothing. */
static void constraint_force(mrvi_step *st, int c, const mrvi_point *pt,
                             const double *lam, int lcol, double *R, int jac) {
  const mrvi_constraint *k = &st->model->constraints[c];
  const int n = k->n_in, rows = k->rows;
  /* The unknown columns of every input, once (not once per row fed). */
  int kc[MRVI_MAX_INPUTS], cl[MRVI_MAX_INPUTS][2], nh = 0;
  double cc[MRVI_MAX_INPUTS][2];
  if (jac)
    for (int l = 0; l < n; l++)
      nh += kc[l] = cols_of(st, k->in[l], pt, cl[l], cc[l]);
  const int skip_hess = k->affine && st->recording == 0;
  for (int j = 0; j < n; j++) {
    int rj[2];
    double cj[2];
    const int kr = rows_of(st, k->in[j], pt, rj, cj);
    double f = 0.0;
    for (int r = 0; r < rows; r++)
      f += st->cG[r * n + j] * lam[r];
    for (int a = 0; a < kr; a++) {
      R[rj[a]] -= pt->w * cj[a] * f;
      if (!jac)
        continue;
      for (int r = 0; r < rows; r++)
        jac_add(st, rj[a], lcol + r, -pt->w * cj[a] * st->cG[r * n + j]);
      if (skip_hess) {
        st->n_trip += nh;
        continue;
      }
      for (int l = 0; l < n; l++) {
        if (kc[l] == 0)
          continue;
        double h = 0.0;
        for (int r = 0; r < rows && !k->affine; r++)
          h += lam[r] * st->cH[(r * n + j) * n + l];
        for (int b = 0; b < kc[l]; b++)
          jac_add(st, rj[a], cl[l][b], -pt->w * cj[a] * cc[l][b] * h);
      }
    }
  }
}

/* Constraint equations g(z) = 0 of constraint c at node point pt into rows
 * starting at row, with their derivatives G on the unknown columns (g and G
 * evaluated at pt by the caller). */
static void constraint_equation(mrvi_step *st, int c, const mrvi_point *pt,
                                int row, double *R, int jac) {
  const mrvi_constraint *k = &st->model->constraints[c];
  const int n = k->n_in;
  for (int r = 0; r < k->rows; r++)
    R[row + r] = st->cg[r];
  if (!jac)
    return;
  for (int j = 0; j < n; j++) {
    int cl[2];
    double cc[2];
    const int kc = cols_of(st, k->in[j], pt, cl, cc);
    for (int b = 0; b < kc; b++)
      for (int r = 0; r < k->rows; r++)
        jac_add(st, row + r, cl[b], cc[b] * st->cG[r * n + j]);
  }
}

/* The constrained action adds -h lambda^T g at every enforcing node
 * (doc/constraints.md): slow-only constraints with h = dT at node 0 (equations
 * at q_{k+1}^s), micro-node constraints with h = dt at nodes 0..p-1 (equations
 * at nodes 1..p, slow part interpolated). */
static void assemble_constraints(mrvi_step *st, const double *x, double *R,
                                 int jac) {
  const int nu = st->n_unknowns, p = st->p;
  const double *lam = x + nu;
  for (int i = 0; i < st->n_slow_c; i++) {
    const int c = st->slow_c[i], off = st->c_off[c];
    const mrvi_point p0 = mrvi_step_node_point(st, 0, st->dT);
    const mrvi_point p1 = mrvi_step_node_point(st, p, st->dT);
    mrvi_step_constraint_eval(st, c, &p0, x, 0); /* no unknown at node 0 */
    constraint_force(st, c, &p0, lam + off, nu + off, R, jac);
    mrvi_step_constraint_eval(st, c, &p1, x, 0);
    constraint_equation(st, c, &p1, nu + off, R, jac);
  }
  const int base = nu + st->r_slow, rm = st->r_micro;
  for (int mm = 0; mm <= p; mm++) {
    const mrvi_point pt = mrvi_step_node_point(st, mm, st->dt);
    for (int i = 0; i < st->n_micro_c; i++) {
      const int c = st->micro_c[i], off = st->c_off[c];
      /* One evaluation serves the force at nodes 0..p-1 and the equation
       * at nodes 1..p. */
      mrvi_step_constraint_eval(st, c, &pt, x,
                                jac && mm > 0 && mm < p &&
                                    !st->model->constraints[c].affine);
      if (mm < p)
        constraint_force(st, c, &pt, lam + st->r_slow + mm * rm + off,
                         base + mm * rm + off, R, jac);
      if (mm > 0)
        constraint_equation(st, c, &pt, base + (mm - 1) * rm + off, R, jac);
    }
  }
}

void mrvi_step_assemble(mrvi_step *st, const double *x, double *R, int jac) {
  const mrvi_model *m = st->model;
  const int nf = st->nf;
  double *mps = st->mom_ps, *mpf = st->mom_pf;
  if (jac && !st->recording) {
    memset(st->Ax, 0, (size_t)st->nnz * sizeof(double));
    st->n_trip = 0;
  }
  if (mps) {
    memset(mps, 0, (size_t)st->ns * sizeof(double));
    memset(mpf, 0, (size_t)st->p * (size_t)nf * sizeof(double));
  }
  assemble_kinetic(st, x, R, jac);
  if (st->f_rows)
    for (int i = 0; i < st->n_unknowns; i++)
      R[i] += st->f_rows[i];
  if (st->extra)
    st->extra(st->extra_ctx, st, x, R, jac);
  /* Elements outer, points inner: one element's entries of all its points
   * are summed while they are in cache (one pass over the Jacobian, not
   * one per point, for networks beyond the caches). */
  mrvi_element_buf eb = {.e.proto = NULL}; /* (one view reused) */
  for (int c = 0; c < 2; c++)
    for (int ie = 0; ie < st->n_elem_of_class[c]; ie++) {
      const mrvi_element *e =
          mrvi_model_element(m, MRVI_STEP_ELEM(st, c, ie), &eb);
      for (int ip = 0; ip < st->n_pts[c]; ip++) {
        const mrvi_point *pt = &st->pts[c][ip];
        const int n = e->n_in;
        if (e->kind == MRVI_ELEMENT_GRAVITY) {
          /* Linear (any number of inputs): gradient only. */
          gather(st, e, pt, x, st->y);
          mrvi_element_eval(m, e, st->y, st->g, NULL);
          if (mps)
            potential_momenta(st, e, pt, mps, mpf);
          for (int j = 0; j < n; j++) {
            int rj[2];
            double cj[2];
            const int k = rows_of(st, e->in[j], pt, rj, cj);
            for (int a = 0; a < k; a++)
              R[rj[a]] -= pt->w * cj[a] * st->g[j];
          }
          continue;
        }
        /* Every input once: its value at the point, the rows it feeds and
         * the unknown columns it depends on (at most two each: the nodes
         * the point interpolates; as rows_of, cols_of and gather). */
        int r[MRVI_MAX_INPUTS][2], cl[MRVI_MAX_INPUTS][2];
        double rc[MRVI_MAX_INPUTS][2], cc[MRVI_MAX_INPUTS][2];
        int kr[MRVI_MAX_INPUTS], kc[MRVI_MAX_INPUTS];
        for (int j = 0; j < n; j++) {
          const int ci = e->in[j], s = m->slot[ci];
          int k = 0, kk = 0;
          if (m->rate[ci] == MRVI_SLOW) {
            st->y[j] = slow_at(st, x, pt->a0, pt->a1, s);
            if (pt->a0 != 0.0) {
              r[j][k] = s;
              rc[j][k++] = pt->a0;
            }
            if (pt->a1 != 0.0) {
              cl[j][kk] = s;
              cc[j][kk++] = pt->a1;
            }
          } else {
            st->y[j] = pt->cA * fast_node(st, x, pt->m, s) +
                       pt->cB * fast_node(st, x, pt->m + 1, s);
            const int row = st->ns + pt->m * nf + s;
            if (pt->cA != 0.0) {
              r[j][k] = row;
              rc[j][k++] = pt->cA;
              if (pt->m >= 1) {
                cl[j][kk] = row - nf;
                cc[j][kk++] = pt->cA;
              }
            }
            if (pt->cB != 0.0) {
              if (pt->m + 1 <= st->p - 1) {
                r[j][k] = row + nf;
                rc[j][k++] = pt->cB;
              }
              cl[j][kk] = row;
              cc[j][kk++] = pt->cB;
            }
          }
          kr[j] = k;
          kc[j] = kk;
        }
        /* Terms phi(a^T q - b) here: their Hessian ddphi a a^T is formed
         * entry by entry in the scatter below; other elements by the model. */
        const int term = e->kind == MRVI_ELEMENT_TERM;
        double d2 = 0.0;
        if (term) {
          double arg = -e->shift, d1;
          for (int j = 0; j < n; j++)
            arg += e->coef[j] * st->y[j];
          mrvi_term_derivs(e, arg, &d1, &d2);
          for (int j = 0; j < n; j++)
            st->g[j] = d1 * e->coef[j];
        } else {
          mrvi_element_eval(m, e, st->y, st->g, jac ? st->H : NULL);
        }
        if (mps)
          potential_momenta(st, e, pt, mps, mpf);
        /* Gradient: -w c_row grad_j into every row input j feeds. */
        for (int j = 0; j < n; j++)
          for (int a = 0; a < kr[j]; a++)
            R[r[j][a]] -= pt->w * rc[j][a] * st->g[j];
        if (!jac)
          continue;
        /* Hessian scatter: -w c_row c_col H_jl (through the triplet map
         * directly once the pattern is recorded). */
        for (int j = 0; j < n; j++)
          for (int l = 0; l < n; l++) {
            const double h =
                term ? d2 * e->coef[j] * e->coef[l] : st->H[j * n + l];
            if (st->recording == 0) {
              const int *map = st->map;
              double *Ax = st->Ax;
              long t = st->n_trip;
              for (int a = 0; a < kr[j]; a++)
                for (int b = 0; b < kc[l]; b++)
                  Ax[map[t++]] += -pt->w * rc[j][a] * cc[l][b] * h;
              st->n_trip = t;
              continue;
            }
            for (int a = 0; a < kr[j]; a++)
              for (int b = 0; b < kc[l]; b++)
                jac_add(st, r[j][a], cl[l][b],
                        -pt->w * rc[j][a] * cc[l][b] * h);
          }
      }
    }
  if (st->n_lambda > 0)
    assemble_constraints(st, x, R, jac);
}

/* What build_pattern made, freed (out of memory: a later call starts
 * afresh). */
static int drop_pattern(mrvi_step *st) {
  free(st->Ti);
  free(st->Tj);
  free(st->Ap);
  free(st->Ai);
  free(st->map);
  free(st->Ax);
  st->Ti = st->Tj = st->Ai = st->Ap = st->map = NULL;
  st->Ax = NULL;
  st->cap_trip = st->n_trip = 0;
  st->nnz = 0;
  st->recording = 0;
  return MRVI_ENOMEM;
}

int mrvi_step_build_pattern(mrvi_step *st, const double *x) {
  const int n = st->n_total;
  double *R = malloc((size_t)n * sizeof *R);
  if (!R)
    return MRVI_ENOMEM;
  st->recording = 1;
  st->n_trip = 0;
  mrvi_step_assemble(st, x, R, 1);
  free(R);
  if (st->recording < 0)
    return drop_pattern(st);
  st->recording = 0;
  const long nt = st->n_trip;
  st->Ap = malloc((size_t)(n + 1) * sizeof *st->Ap);
  st->Ai = malloc((size_t)(nt > 0 ? nt : 1) * sizeof *st->Ai);
  st->map = malloc((size_t)(nt > 0 ? nt : 1) * sizeof *st->map);
  if (!st->Ap || !st->Ai || !st->map)
    return drop_pattern(st);
  int status = umfpack_di_triplet_to_col(n, n, (int)nt, st->Ti, st->Tj, NULL,
                                         st->Ap, st->Ai, NULL, st->map);
  free(st->Ti);
  free(st->Tj);
  st->Ti = st->Tj = NULL;
  st->cap_trip = 0;
  if (status != UMFPACK_OK)
    return drop_pattern(st);
  st->nnz = st->Ap[n];
  st->Ax = calloc((size_t)(st->nnz > 0 ? st->nnz : 1), sizeof *st->Ax);
  if (!st->Ax)
    return drop_pattern(st);
  return MRVI_OK;
}

/* Potential part of the momenta at the end nodes of point pt's interval:
 * -w a1 grad_s Z into ps1 and -w cB grad_f Z into pf (node m + 1 of
 * interval m, eq:pkfm+), from the gradient st->g of element e. */
static void potential_momenta(const mrvi_step *st, const mrvi_element *e,
                              const mrvi_point *pt, double *ps1, double *pf) {
  const mrvi_model *m = st->model;
  for (int j = 0; j < e->n_in; j++) {
    const int cidx = e->in[j], s = m->slot[cidx];
    if (m->rate[cidx] == MRVI_SLOW)
      ps1[s] -= pt->w * pt->a1 * st->g[j];
    else
      pf[pt->m * st->nf + s] -= pt->w * pt->cB * st->g[j];
  }
}

/* The fast kinetic parts M^f (d^{m+1} - d^m)/dt of columns [s0, s1) of
 * the fast increments d (p x nf) added to pf, node by node. */
static void kinetic_fast_columns(const mrvi_step *st, const double *d,
                                 double *pf, int s0, int s1) {
  const mrvi_model *m = st->model;
  const int nf = st->nf, p = st->p;
  const double dt = st->dt;
  for (int s = s0; s < s1; s++) {
    const double M = MRVI_MASS(m, m->fast_index[s]);
    const double *ds = d + s;
    pf[s] += M * (ds[0] - 0.0) / dt;
    for (int mm = 1; mm < p; mm++)
      pf[mm * nf + s] += M * (ds[mm * nf] - ds[(mm - 1) * nf]) / dt;
  }
}

/* The kinetic parts of the momenta from increments (mrvi_step.increments),
 * for ns, nf constants on small blocks. */
ALWAYS_INLINE void kinetic_increments_k(const mrvi_step *st, const double *x,
                                        double *ps1, double *pf, const int ns,
                                        const int nf) {
  const mrvi_model *m = st->model;
  const int p = st->p;
  const double dT = st->dT, dt = st->dt;
  UNROLL for (int s = 0; s < ns; s++) ps1[s] +=
      MRVI_MASS(m, m->slow_index[s]) * x[s] / dT;
  if (nf > 4) { /* (node by node; in parts of columns on threads) */
    const int chunk = st->tuning.thread_chunk;
    const int n_part = st->threads > 1 && chunk > 0 && nf >= 2 * chunk
                           ? (nf - 1) / chunk + 1
                           : 1;
    if (n_part == 1)
      kinetic_fast_columns(st, x + ns, pf, 0, nf);
    else {
      MRVI_PARALLEL_FOR(st->threads)
      for (int c = 0; c < n_part; c++)
        kinetic_fast_columns(st, x + ns, pf, (int)((long)c * nf / n_part),
                             (int)((long)(c + 1) * nf / n_part));
    }
    return;
  }
  /* The same sums over the fast entries i = mm nf + s in order, two at a
   * time as a pair of doubles (util/simd.h: one division for
   * two, the divisions set the pace; GCC -O2 left the loop scalar), two
   * nodes, nf pairs, per pass, with the masses of two nodes in M2. */
  double M2[8] = {0};
  UNROLL for (int s = 0; s < nf; s++) M2[s] = M2[nf + s] =
      MRVI_MASS(m, m->fast_index[s]);
  const double *restrict d = x + ns;
  double *restrict pv = pf;
  UNROLL for (int s = 0; s < nf; s++) pv[s] += M2[s] * (d[s] - 0.0) / dt;
  const int n = p * nf;
  const mrvi_v2 dt2 = v2_set(dt, dt);
  int i = nf;
  for (; nf > 0 && i + 2 * nf <= n; i += 2 * nf)
    UNROLL for (int k = 0; k < 2 * nf; k += 2) {
      const mrvi_v2 a = v2_load(d + i + k), b = v2_load(d + i + k - nf);
      const mrvi_v2 dp = v2_div(v2_mul(v2_load(M2 + k), v2_sub(a, b)), dt2);
      v2_store(pv + i + k, v2_add(v2_load(pv + i + k), dp));
    }
  for (int k = 0; i < n; i++, k++)
    pv[i] += M2[k] * (d[i] - d[i - nf]) / dt;
}

void mrvi_step_momenta_finish(mrvi_step *st, const double *x, double *ps1,
                              double *pf) {
  const mrvi_model *m = st->model;
  const int ns = st->ns, nf = st->nf, p = st->p;
  /* Kinetic parts: D_{q_{k+1}^s} T_d = M^s v_s; D_{q^{f,m+1}} T_d^m = M^f v_m
   */
  const double dT = st->dT, dt = st->dt;
  if (st->increments) { /* the same sums without a test per entry (a
                           step's fixed cost at p = 1) */
    SMALL2(ns, NS, nf, NF, kinetic_increments_k(st, x, ps1, pf, NS, NF));
  } else {
    for (int s = 0; s < ns; s++)
      ps1[s] += MRVI_MASS(m, m->slow_index[s]) * slow_diff(st, x, s) / dT;
    for (int s = 0; s < nf; s++) {
      const double M = MRVI_MASS(m, m->fast_index[s]);
      for (int mm = 0; mm < p; mm++)
        pf[mm * nf + s] += M * fast_diff(st, x, mm, s) / dt;
    }
  }
  if (st->extra_end)
    st->extra_end(st->extra_ctx, st, x);
  if (st->f_end) {
    for (int s = 0; s < ns; s++)
      ps1[s] += st->f_end[s];
    for (int s = 0; s < nf; s++)
      pf[(p - 1) * nf + s] += st->f_end[ns + s];
  }
  /* Constraint forces of the interior micro nodes on q_{k+1}^s:
   * -dt (m/p) G_s(z^m)^T lambda^m. */
  const double *lam = x + st->n_unknowns + st->r_slow;
  for (int mm = 1; mm < p && st->n_micro_c > 0; mm++) {
    const mrvi_point pt = mrvi_step_node_point(st, mm, st->dt);
    for (int i = 0; i < st->n_micro_c; i++) {
      const int c = st->micro_c[i];
      const mrvi_constraint *k = &m->constraints[c];
      const double *l = lam + mm * st->r_micro + st->c_off[c];
      mrvi_step_constraint_eval(st, c, &pt, x, 0);
      for (int j = 0; j < k->n_in; j++) {
        const int idx = k->in[j];
        if (m->rate[idx] != MRVI_SLOW)
          continue;
        double f = 0.0;
        for (int r = 0; r < k->rows; r++)
          f += st->cG[r * k->n_in + j] * l[r];
        ps1[m->slot[idx]] -= pt.w * pt.a1 * f;
      }
    }
  }
}

void mrvi_step_jac_add(mrvi_step *st, int row, int col, double v) {
  jac_add(st, row, col, v);
}

void mrvi_step_micro_residuals(const mrvi_step *st, const double *R,
                               double *out) {
  const int nu = st->n_unknowns, p = st->p;
  for (int mm = 1; mm <= p; mm++) {
    double worst = 0.0;
    for (int i = 0; i < st->n_micro_c; i++)
      for (int r = 0; r < st->model->constraints[st->micro_c[i]].rows; r++)
        worst = fmax(worst, fabs(R[nu + st->r_slow + (mm - 1) * st->r_micro +
                                   st->c_off[st->micro_c[i]] + r]));
    if (mm == p)
      for (int r = 0; r < st->r_slow; r++)
        worst = fmax(worst, fabs(R[nu + r]));
    out[mm - 1] = worst;
  }
}

void mrvi_step_momenta(mrvi_step *st, const double *x, double *ps1,
                       double *pf) {
  const mrvi_model *m = st->model;
  memset(ps1, 0, (size_t)st->ns * sizeof(double));
  memset(pf, 0, (size_t)st->p * (size_t)st->nf * sizeof(double));
  /* Elements outer, points inner, as in mrvi_step_assemble (the same
   * order of the sums). */
  mrvi_element_buf eb = {.e.proto = NULL}; /* (one view reused) */
  for (int c = 0; c < 2; c++)
    for (int ie = 0; ie < st->n_elem_of_class[c]; ie++) {
      const mrvi_element *e =
          mrvi_model_element(m, MRVI_STEP_ELEM(st, c, ie), &eb);
      for (int ip = 0; ip < st->n_pts[c]; ip++) {
        const mrvi_point *pt = &st->pts[c][ip];
        gather(st, e, pt, x, st->y);
        mrvi_element_eval(m, e, st->y, st->g, NULL);
        potential_momenta(st, e, pt, ps1, pf);
      }
    }
  mrvi_step_momenta_finish(st, x, ps1, pf);
}
