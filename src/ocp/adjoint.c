/* Cost, terminal conditions and their exact discrete adjoint gradients.
 *
 * Write the shooting trajectory as all nodes Y of the grid (slow macro
 * nodes, fast micro nodes) and the discrete Euler-Lagrange equations as
 * E(Y, u) = 0: at every node but the last, the sum over the steps touching
 * it of D_node L_d^k plus the control forces (and p_0 at the initial
 * nodes).  With H_k the Hessian of L_d^k in the nodes z_k of step k, the
 * adjoint of a functional Phi(Y, p_N, u) solves
 *   sum_k H_k mu[z_k] = grad_Y Phi   (on the unknown nodes),
 * with mu = -dPhi/dp_N on the final nodes (p_N = D_2 L_d^{N-1} + f^+).
 * The system is block triangular in the steps; its diagonal block is the
 * transposed step Jacobian A_k^T of eq:DEL_ini (a block of H_k, gathered
 * into the step's CSC pattern and solved through the Newton solver's
 * transposed solve), the off-diagonal blocks are other parts of H_k.  Then
 *   dPhi/du = dPhi/du|_direct - sum_k mu[z_k]^T d(forces_k)/du.
 * All functionals (cost and every terminal constraint) share one sweep. */
#include "ocp/ocp_internal.h"
#include "util/simd.h"

#include <limits.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Constraint c at node point pt of step k: force -w G^T lambda (lambda at
 * variable lv, if lv >= 0) into the node rows with its derivatives, and the
 * equation g = 0 at row er (if er >= 0). */
static void jac_constraint(mrvi_ocp *o, int c, const mrvi_point *pt, int lv,
                           int er, ocp_jac *J) {
  mrvi_step *st = &o->step;
  const mrvi_constraint *kc = &o->model->constraints[c];
  const int n = kc->n_in, rows = kc->rows;
  mrvi_step_constraint_eval(st, c, pt, o->x, lv >= 0);
  /* Node coefficients: for a constraint node, cA = 1 at fast node m. */
  int zi[MRVI_MAX_INPUTS][2];
  double zc[MRVI_MAX_INPUTS][2];
  for (int j = 0; j < n; j++) {
    ocp_znodes(o, kc->in[j], pt, zi[j], zc[j]);
    if (o->model->rate[kc->in[j]] == MRVI_FAST)
      zc[j][1] = 0.0; /* node point: fast node m only */
  }
  /* hs = sum_r lambda_r d^2 g_r (rows in order for every entry: the sums
   * of the entries one by one). */
  double hs[MRVI_MAX_INPUTS * MRVI_MAX_INPUTS];
  if (lv >= 0) {
    const double *lam = o->x + st->n_unknowns + (lv - o->nz);
    for (int e = 0; e < n * n; e++)
      hs[e] = 0.0;
    for (int r = 0; r < rows; r++) {
      const double *Hr = st->cH + (size_t)r * (size_t)(n * n);
      const mrvi_v2 lr = v2_set(lam[r], lam[r]);
      int e = 0;
      for (; e + 1 < n * n; e += 2)
        v2_store(hs + e, v2_add(v2_load(hs + e), v2_mul(lr, v2_load(Hr + e))));
      for (; e < n * n; e++)
        hs[e] += lam[r] * Hr[e];
    }
  }
  for (int j = 0; j < n; j++)
    for (int a = 0; a < 2; a++) {
      if (zc[j][a] == 0.0)
        continue;
      const int zr = zi[j][a];
      if (er >= 0)
        for (int r = 0; r < rows; r++)
          ocp_jac_add(J, er + r, zr,
                      zc[j][a] * st->cG[(size_t)r * (size_t)n + (size_t)j]);
      if (lv < 0)
        continue;
      for (int r = 0; r < rows; r++)
        ocp_jac_add(J, zr, lv + r,
                    -pt->w * zc[j][a] *
                        st->cG[(size_t)r * (size_t)n + (size_t)j]);
      for (int l = 0; l < n; l++) {
        const double h = hs[j * n + l];
        for (int b = 0; b < 2; b++)
          if (zc[l][b] != 0.0)
            ocp_jac_add(J, zr, zi[l][b], -pt->w * zc[j][a] * zc[l][b] * h);
      }
    }
}

void ocp_jacobian(mrvi_ocp *o, long k, ocp_jac *J) {
  const mrvi_model *m = o->model;
  mrvi_step *st = &o->step;
  const int ns = o->ns, nf = o->nf, p = o->p;
  const long *gz = o->gz;
  for (int z = 0; z < o->nz; z++)
    o->gz[z] = ocp_global(o, k, z);
  /* Kinetic: M/h [[1, -1], [-1, 1]] on every interval. */
  for (int s = 0; s < ns; s++) {
    const double a = MRVI_MASS(m, m->slow_index[s]) / st->dT;
    ocp_jac_add(J, s, s, a);
    ocp_jac_add(J, ns + s, ns + s, a);
    ocp_jac_add(J, s, ns + s, -a);
    ocp_jac_add(J, ns + s, s, -a);
  }
  for (int mm = 0; mm < p; mm++)
    for (int s = 0; s < nf; s++) {
      const double a = MRVI_MASS(m, m->fast_index[s]) / st->dt;
      const int i = 2 * ns + mm * nf + s, j = i + nf;
      ocp_jac_add(J, i, i, a);
      ocp_jac_add(J, j, j, a);
      ocp_jac_add(J, i, j, -a);
      ocp_jac_add(J, j, i, -a);
    }
  /* Potentials: -w c_a c_b hess Z at every evaluation point. */
  for (int c = 0; c < 2; c++)
    for (int ip = 0; ip < st->n_pts[c]; ip++) {
      const mrvi_point *pt = &st->pts[c][ip];
      for (int ie = 0; ie < st->n_elem_of_class[c]; ie++) {
        const mrvi_element *e = MRVI_ELEMENT(m, MRVI_STEP_ELEM(st, c, ie));
        if (e->kind == MRVI_ELEMENT_GRAVITY)
          continue;
        const int n = e->n_in;
        int zi[MRVI_MAX_INPUTS][2];
        double zc[MRVI_MAX_INPUTS][2];
        for (int j = 0; j < n; j++) {
          ocp_znodes(o, e->in[j], pt, zi[j], zc[j]);
          st->y[j] =
              zc[j][0] * o->Q[gz[zi[j][0]]] + zc[j][1] * o->Q[gz[zi[j][1]]];
        }
        mrvi_element_eval(m, e, st->y, st->g, st->H);
        /* Node pairs of zero coefficient skipped (a point on a node: the
         * explicit schemes' points), in every mode alike, so that the
         * pattern and the recorded slots agree. */
        for (int j = 0; j < n; j++)
          for (int l = 0; l < n; l++) {
            const double h = pt->w * st->H[j * n + l];
            for (int a = 0; a < 2; a++)
              for (int b = 0; b < 2; b++)
                if (zc[j][a] != 0.0 && zc[l][b] != 0.0)
                  ocp_jac_add(J, zi[j][a], zi[l][b], -zc[j][a] * zc[l][b] * h);
          }
      }
    }
  if (o->n_state > 0)
    ocp_state_jacobian(o, k, J);
  if (o->nl == 0)
    return;
  /* Constraints in the step's layout (step/step.h, struct mrvi_step):
   * slow-only: lambda at node 0 (weight dT), equation at q_{k+1}^s;
   * micro-node: lambda^m at nodes 0..p-1 (weight dt), equations at nodes
   * 1..p.  Variables and rows nz + (step index - n_unknowns). */
  const int nz = o->nz;
  for (int i = 0; i < st->n_slow_c; i++) {
    const int c = st->slow_c[i], off = st->c_off[c];
    const mrvi_point p0 = mrvi_step_node_point(st, 0, st->dT);
    const mrvi_point p1 = mrvi_step_node_point(st, p, st->dT);
    jac_constraint(o, c, &p0, nz + off, -1, J);
    jac_constraint(o, c, &p1, -1, nz + off, J);
  }
  const int base = nz + st->r_slow, rm = st->r_micro;
  for (int mm = 0; mm <= p; mm++) {
    const mrvi_point pt = mrvi_step_node_point(st, mm, st->dt);
    for (int i = 0; i < st->n_micro_c; i++) {
      const int c = st->micro_c[i], off = st->c_off[c];
      if (mm < p)
        jac_constraint(o, c, &pt, base + mm * rm + off, -1, J);
      if (mm > 0)
        jac_constraint(o, c, &pt, -1, base + (mm - 1) * rm + off, J);
    }
  }
}

/* Global index of the final node of coordinate c and its slot in p_N. */
static long final_node(const mrvi_ocp *o, int c, int *pslot) {
  const mrvi_model *m = o->model;
  const int s = m->slot[c];
  if (m->rate[c] == MRVI_SLOW) {
    *pslot = s;
    return o->N * o->ns + s;
  }
  *pslot = o->ns + s;
  return (o->N + 1) * o->ns + o->N * o->p * o->nf + s;
}

/* A terminal condition of the final positions q and momenta pp (model
 * order, n each): its value (target subtracted) and, with b not NULL, b_j =
 * M_j df/dpp_j and gq_j = df/dq_j at fixed pp (b and gq cleared by the
 * caller; gq may be NULL). */
typedef double (*momentum_fn)(const mrvi_ocp *o, const ocp_terminal *T,
                              const double *q, const double *pp, double *b,
                              double *gq);

/* f(q, P(q) p): f evaluated on the momenta p (model order, n) at q
 * projected onto the hidden constraint G M^-1 p = 0 (the physical,
 * constraint-consistent velocities; mrvi_constraints_project), with its
 * derivatives in p into gp and, with gq not NULL, in q into gq.  pp = p -
 * G^T mu, (G M^-1 G^T) mu = G M^-1 p, is linear in p and M^-1 P symmetric,
 * so gp = P^T a = M^-1 P (M a) for a = df/dpp (one projection of b = M a,
 * whose multiplier is w = (G M^-1 G^T)^-1 G a).  Differentiating pp in q
 * (G = G(q), H_r the Hessian of constraint row r):
 *   df/dq = df/dq|_pp - sum_r (mu_r H_r gp + w_r H_r M^-1 pp),
 * one Hessian per constraint (the central differences in every coordinate
 * this replaces cost n projections of O(R^2 n) each: minutes on the
 * constrained lattice at n = 3 040, doc/performance/17-ocp17.md).  NAN
 * where the constraint gradients are dependent. */
static double projected(const mrvi_ocp *o, const ocp_terminal *T, momentum_fn f,
                        const double *q, const double *p, double *gq,
                        double *gp) {
  const mrvi_model *m = o->model;
  const int n = m->n, R = mrvi_model_constraint_rows(m);
  const int ci = m->max_constraint_in > 0 ? m->max_constraint_in : 1;
  double *pp = o->pv + 2 * n, *b = o->pv + 3 * n, *g = o->pv + 6 * n;
  double *G = g + R, *A = G + (size_t)R * (size_t)n, *mu = A + (size_t)R * R;
  double *lam = mu + R, *y = lam + R, *gl = y + ci, *Gl = gl + ci;
  double *H = Gl + (size_t)ci * ci;
  memset(b, 0, (size_t)n * sizeof *b);
  if (gq)
    memset(gq, 0, (size_t)n * sizeof *gq);
  memcpy(pp, p, (size_t)n * sizeof *pp);
  const int ok = mrvi_constraints_project(m, q, pp, NULL, g, G, A, mu);
  memcpy(lam, mu, (size_t)R * sizeof *lam);
  double v = f(o, T, q, pp, b, gq);
  if (ok != MRVI_OK ||
      mrvi_constraints_project(m, q, b, NULL, g, G, A, mu) != MRVI_OK)
    v = NAN;
  for (int j = 0; j < n; j++)
    gp[j] = isfinite(v) ? b[j] / MRVI_MASS(m, j) : NAN;
  for (int c = 0; gq && isfinite(v) && c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    if (k->affine)
      continue;
    const int ni = k->n_in;
    for (int j = 0; j < ni; j++)
      y[j] = q[k->in[j]];
    mrvi_constraint_eval_at(k, y, gl, Gl, H);
    for (int r = 0; r < k->rows; r++) {
      const double a = lam[k->first_row + r], w = mu[k->first_row + r];
      for (int i = 0; i < ni; i++) {
        double s = 0.0;
        for (int j = 0; j < ni; j++) {
          const int cj = k->in[j];
          s += H[((size_t)r * ni + i) * ni + j] *
               (a * gp[cj] + w * pp[cj] / MRVI_MASS(m, cj));
        }
        gq[k->in[i]] -= s;
      }
    }
  }
  for (int j = 0; gq && !isfinite(v) && j < n; j++)
    gq[j] = NAN;
  return v;
}

/* Velocity of coordinate T->coord minus its target (momentum_fn). */
static double coordinate_velocity(const mrvi_ocp *o, const ocp_terminal *T,
                                  const double *q, const double *pp, double *b,
                                  double *gq) {
  (void)q, (void)gq;
  if (b)
    b[T->coord] = 1.0;
  return pp[T->coord] / MRVI_MASS(o->model, T->coord) - T->target;
}

/* Body condition T (momentum_fn): its value on the body's D (D + 1)
 * coordinates. */
static double body_condition(const mrvi_ocp *o, const ocp_terminal *T,
                             const double *q, const double *pp, double *b,
                             double *gq) {
  const int D = o->model->dimension, nb = D * (D + 1);
  double gqb[12], gp[12];
  const double v =
      ocp_body_terminal(o, T, q + T->coord, pp + T->coord, gqb, gp);
  for (int k = 0; b && k < nb; k++)
    b[T->coord + k] = MRVI_MASS(o->model, T->coord + k) * gp[k];
  for (int k = 0; gq && k < nb; k++)
    gq[T->coord + k] = gqb[k];
  return v;
}

/* Whether a constraint other than body's own internal one acts on its
 * coordinates (a joint, a rod to a point of it): the internal constraints'
 * forces have no moment (L = sum d_i x p_{d_i} is blind to them), the
 * others' do, and its angular velocity must then be read from projected
 * momenta. */
static int body_constrained(const mrvi_model *m, int body) {
  const mrvi_body *B = &m->bodies[body];
  const int lo = B->first, hi = lo + B->dim * (B->dim + 1);
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *C = &m->constraints[c];
    if (c == B->constraint)
      continue;
    for (int i = 0; i < C->n_in; i++)
      if (C->in[i] >= lo && C->in[i] < hi)
        return 1;
  }
  return 0;
}

/* Terminal row T of value v and derivatives dq, dp in every coordinate's
 * final node and momentum (model order): into val, gQ, gp (row 0, the
 * cost, for a penalty; else constraint row 1 + (*ic)++). */
static void add_full_row(const mrvi_ocp *o, const ocp_terminal *T, double v,
                         const double *dq, const double *dp, long nn, int npn,
                         int *ic, double *val, double *gQ, double *gp) {
  const int f = T->penalty > 0.0 ? 0 : 1 + (*ic)++;
  const double scale = f == 0 ? T->penalty * v : 1.0;
  int pj;
  val[f] += f == 0 ? 0.5 * T->penalty * v * v : v;
  for (int j = 0; j < o->model->n; j++) {
    const long g = final_node(o, j, &pj);
    if (gQ)
      gQ[(size_t)f * (size_t)nn + (size_t)g] += scale * dq[j];
    gp[(size_t)f * (size_t)npn + (size_t)pj] += scale * dp[j];
  }
}

/* A velocity condition T of a constrained model on the projected momenta
 * (a function of every coordinate's final node and momentum). */
static void projected_row(const mrvi_ocp *o, const ocp_terminal *T,
                          momentum_fn fn, long nn, int npn, int *ic,
                          double *val, double *gQ, double *gp) {
  const int n = o->model->n;
  double *q = o->pv, *p = q + n, *dq = q + 4 * n, *dp = q + 5 * n;
  int pj;
  for (int j = 0; j < n; j++) {
    q[j] = o->Q[final_node(o, j, &pj)];
    p[j] = o->pN[pj];
  }
  const double v = projected(o, T, fn, q, p, gQ ? dq : NULL, dp);
  add_full_row(o, T, v, dq, dp, nn, npn, ic, val, gQ, gp);
}

/* Body terminal condition T (one row): its value into val and its
 * derivatives in the body's final nodes and momenta into gQ, gp (row 0, the
 * cost, for a penalty; else constraint row 1 + (*ic)++).  An angular
 * velocity of a body held by other constraints is read from the projected
 * momenta. */
static void body_terminal(const mrvi_ocp *o, const ocp_terminal *T, long nn,
                          int npn, int *ic, double *val, double *gQ,
                          double *gp) {
  const int D = o->model->dimension, n = D * (D + 1);
  const int velocity =
      T->kind != MRVI_OCP_ATTITUDE && T->kind != MRVI_OCP_DIRECTION;
  if (velocity && o->pv && body_constrained(o->model, T->body)) {
    projected_row(o, T, body_condition, nn, npn, ic, val, gQ, gp);
    return;
  }
  double q[12], p[12], gq[12], gpv[12];
  long g[12];
  int ps[12];
  for (int k = 0; k < n; k++) {
    g[k] = final_node(o, T->coord + k, &ps[k]);
    q[k] = o->Q[g[k]];
    p[k] = o->pN[ps[k]];
  }
  const double v = ocp_body_terminal(o, T, q, p, gq, gpv);
  const int f = T->penalty > 0.0 ? 0 : 1 + (*ic)++;
  const double scale = f == 0 ? T->penalty * v : 1.0;
  val[f] += f == 0 ? 0.5 * T->penalty * v * v : v;
  for (int k = 0; k < n; k++) {
    if (gQ)
      gQ[(size_t)f * (size_t)nn + (size_t)g[k]] += scale * gq[k];
    gp[(size_t)f * (size_t)npn + (size_t)ps[k]] += scale * gpv[k];
  }
}

/* Cost and constraints with their direct partial derivatives: rows
 * f = 0 (cost), 1..n_con of gQ (n_nodes; NULL: not wanted, nor cleared),
 * gp (ns + nf), gu (n_u). */
static void functionals(const mrvi_ocp *o, const double *u, double *val,
                        double *gQ, double *gp, double *gu) {
  const mrvi_model *m = o->model;
  const int nfun = 1 + o->n_con, npn = o->ns + o->nf;
  const long nn = o->n_nodes;
  memset(val, 0, (size_t)nfun * sizeof *val);
  if (gQ)
    memset(gQ, 0, (size_t)nfun * (size_t)nn * sizeof *gQ);
  memset(gp, 0, (size_t)nfun * (size_t)npn * sizeof *gp);
  memset(gu, 0, (size_t)nfun * (size_t)o->n_u * sizeof *gu);
  const double dT = o->settings.macro_step, dt = dT / o->p;
  /* Effort 1/2 int w u^2 dt (exact for piecewise constant u). */
  for (int a = 0; a < o->n_act; a++) {
    const ocp_actuator *A = &o->act[a];
    const double h = A->grid == MRVI_GRID_MACRO ? dT : dt;
    for (int j = 0; j < A->size; j++) {
      const double v = u[A->offset + j];
      val[0] += 0.5 * A->weight * h * v * v;
      gu[A->offset + j] += A->weight * h * v;
    }
  }
  /* Tracking: exact integral of the squared linear interpolant. */
  for (int t = 0; t < o->n_trk; t++) {
    const ocp_tracking *T = &o->trk[t];
    const int c = T->coord, s = m->slot[c];
    const int slow = m->rate[c] == MRVI_SLOW;
    const long nint = slow ? o->N : o->N * o->p;
    const double h = slow ? dT : dt, w = T->weight * h / 6.0;
    for (long i = 0; i < nint; i++) {
      const long ga = slow ? i * o->ns + s : (o->N + 1) * o->ns + i * o->nf + s;
      const long gb = ga + (slow ? o->ns : o->nf);
      const double ea = o->Q[ga] - T->ref, eb = o->Q[gb] - T->ref;
      val[0] += w * (ea * ea + ea * eb + eb * eb);
      if (!gQ)
        continue;
      gQ[ga] += w * (2.0 * ea + eb);
      gQ[gb] += w * (2.0 * eb + ea);
    }
  }
  /* Terminal conditions. */
  int ic = 0;
  for (int t = 0; t < o->n_term; t++) {
    const ocp_terminal *T = &o->term[t];
    if (T->body >= 0) {
      body_terminal(o, T, nn, npn, &ic, val, gQ, gp);
      continue;
    }
    int ps;
    const long g = final_node(o, T->coord, &ps);
    const double M = MRVI_MASS(m, T->coord);
    if (T->kind == MRVI_OCP_VELOCITY && o->pv) {
      projected_row(o, T, coordinate_velocity, nn, npn, &ic, val, gQ, gp);
      continue;
    }
    const double v =
        (T->kind == MRVI_OCP_POSITION ? o->Q[g] : o->pN[ps] / M) - T->target;
    const double dv = T->kind == MRVI_OCP_POSITION ? 1.0 : 1.0 / M;
    const int f = T->penalty > 0.0 ? 0 : 1 + ic++;
    const double scale = f == 0 ? T->penalty * v : 1.0;
    val[f] += f == 0 ? 0.5 * T->penalty * v * v : v;
    if (T->kind == MRVI_OCP_POSITION && gQ)
      gQ[(size_t)f * (size_t)nn + (size_t)g] += scale * dv;
    else
      gp[(size_t)f * (size_t)npn + (size_t)ps] += scale * dv;
  }
}

/* Whether the adjoint assembles the step Jacobian dense (small steps, where
 * that is cheaper: doc/performance/ocp.md, bench_ocp --lattice). */
static int dense_jacobian(const mrvi_ocp *o) {
  return o->nv <= o->settings.tuning.adjoint_dense_max;
}

/* Row (i < 0: column j) of H of index i (j) of the step's CSC pattern:
 * rows q_k^s, fast nodes 0..p-1, constraint equations; columns q_{k+1}^s,
 * fast nodes 1..p, multipliers. */
static int h_row(const mrvi_ocp *o, int i) {
  const int ns = o->ns, nx = o->step.n_unknowns;
  return i < ns ? i : (i < nx ? 2 * ns + (i - ns) : o->nz + i - nx);
}
static int h_column(const mrvi_ocp *o, int j) {
  const int ns = o->ns, nx = o->step.n_unknowns;
  return j < ns ? ns + j
                : (j < nx ? 2 * ns + o->nf + (j - ns) : o->nz + j - nx);
}

static int cmp_int(const void *a, const void *b) {
  const int x = *(const int *)a, y = *(const int *)b;
  return (x > y) - (x < y);
}

/* The sparse rows of H (the same pattern for every step; found at step k,
 * whose data are loaded): count the assembly's entries per row, list their
 * columns, sort and merge duplicates; then the slot of every entry of A_k
 * in them. */
static int sparse_pattern(mrvi_ocp *o, long k) {
  const int nv = o->nv;
  const mrvi_step *st = &o->step;
  free(o->h_ptr);
  free(o->h_col);
  free(o->h_val);
  o->h_col = NULL;
  o->h_val = NULL;
  o->h_sparse = 0;
  long *ptr = o->h_ptr = calloc((size_t)nv + 1, sizeof *ptr);
  long *fill = malloc(((size_t)nv + 1) * sizeof *fill);
  if (!ptr || !fill) {
    free(fill);
    return MRVI_ENOMEM;
  }
  ocp_jac a = {.mode = OCP_JAC_COUNT, .nv = nv, .ptr = ptr};
  ocp_jacobian(o, k, &a);
  for (int i = 0; i < nv; i++) {
    ptr[i + 1] += ptr[i];
    fill[i] = ptr[i];
  }
  /* The slots of the entries, recorded at the next assembly (none if
   * there is no room for them: then every step bisects). */
  free(o->h_slot);
  o->n_h_slot = 0;
  o->h_slot_cap = ptr[nv] < INT_MAX ? ptr[nv] : 0;
  o->h_slot = malloc(((size_t)o->h_slot_cap + 1) * sizeof *o->h_slot);
  if (!o->h_slot)
    o->h_slot_cap = 0;
  int *col = malloc(((size_t)ptr[nv] + 1) * sizeof *col);
  if (!col) {
    free(fill);
    return MRVI_ENOMEM;
  }
  a = (ocp_jac){.mode = OCP_JAC_LIST, .nv = nv, .col = col, .fill = fill};
  ocp_jacobian(o, k, &a);
  free(fill);
  long w = 0;
  for (int i = 0; i < nv; i++) {
    const long b = ptr[i], e = ptr[i + 1];
    qsort(col + b, (size_t)(e - b), sizeof *col, cmp_int);
    ptr[i] = w;
    for (long t = b; t < e; t++)
      if (w == ptr[i] || col[t] != col[w - 1])
        col[w++] = col[t];
  }
  ptr[nv] = w;
  int *shrunk = realloc(col, ((size_t)w + 1) * sizeof *col);
  o->h_col = shrunk ? shrunk : col;
  o->h_val = calloc((size_t)w + 1, sizeof *o->h_val);
  if (!o->h_val)
    return MRVI_ENOMEM;
  for (int j = 0; j < st->n_total; j++)
    for (int e = st->Ap[j]; e < st->Ap[j + 1]; e++) {
      const int row = h_row(o, st->Ai[e]), c = h_column(o, j);
      const int *lo = o->h_col + ptr[row], *hi = o->h_col + ptr[row + 1];
      const int *f = bsearch(&c, lo, (size_t)(hi - lo), sizeof c, cmp_int);
      o->h_of_a[e] = f ? (long)(f - o->h_col) : -1;
    }
  o->h_sparse = 1;
  return MRVI_OK;
}

/* Whether the adjoint's transposed step solves take the schur-krylov
 * elimination: where the forward pass does (large unconstrained steps),
 * and on the explicit paths (explicit, sweep, sweep-cg) for steps too
 * large for the dense H, whose forward pass factorises nothing either
 * (against the sparse LU of the step: doc/performance/ocp.md, "Optimal
 * control on a lattice"), where they do not take their own adjoint
 * (adjoint_explicit.c, ocp_explicit_ok). */
static int adjoint_krylov_path(const mrvi_ocp *o) {
  switch (o->path) {
  case MRVI_PATH_SCHUR_KRYLOV:
    return 1;
  case MRVI_PATH_EXPLICIT:
  case MRVI_PATH_SWEEP:
  case MRVI_PATH_SWEEP_CG:
    return !dense_jacobian(o);
  default:
    return 0;
  }
}

/* The place of every entry of A_k in the dense H. */
static void dense_slots(mrvi_ocp *o) {
  const mrvi_step *st = &o->step;
  for (int j = 0; j < st->n_total; j++)
    for (int e = st->Ap[j]; e < st->Ap[j + 1]; e++)
      o->h_of_a[e] = (long)h_row(o, st->Ai[e]) * o->nv + h_column(o, j);
}

/* Lazily sized adjoint workspace for nfun functionals: the dense H and its
 * rows where dense_jacobian, else the sparse rows at the first step. */
static int adjoint_alloc(mrvi_ocp *o, int nfun) {
  const size_t nn = (size_t)o->n_nodes, nu = (size_t)o->step.n_total;
  const size_t npn = (size_t)(o->ns + o->nf), f = (size_t)nfun;
  const size_t nv = (size_t)o->nv;
  ocp_adjoint_free(o);
  const size_t n = (size_t)o->model->n,
               R = (size_t)mrvi_model_constraint_rows(o->model);
  const size_t ci = (size_t)(o->model->max_constraint_in > 0
                                 ? o->model->max_constraint_in
                                 : 1); /* (projected's workspace) */
  o->pv = R > 0 ? malloc((6 * n + R * (n + R + 3) + ci * (2 + ci + ci * ci)) *
                         sizeof *o->pv)
                : NULL;
  o->r = calloc(f * (2 * nn + npn + (size_t)o->n_u + 1), sizeof(double));
  o->mu = calloc(f * nn + 1, sizeof(double));
  if (!o->r || !o->mu || (R > 0 && !o->pv))
    return MRVI_ENOMEM;
  /* The explicit path's adjoint needs no step Jacobian. */
  if (ocp_explicit_ok(o)) {
    if (ocp_explicit_alloc(o, nfun) < 0)
      return MRVI_ENOMEM;
    o->nfun_alloc = nfun;
    return MRVI_OK;
  }
  o->gz = malloc((size_t)o->nz * sizeof *o->gz);
  const mrvi_step *st = &o->step;
  o->h_of_a = malloc(((size_t)st->nnz + 1) * sizeof *o->h_of_a);
  o->Ak = malloc(((size_t)st->nnz + 1) * sizeof *o->Ak);
  int ok = o->gz && o->h_of_a && o->Ak && ocp_state_alloc(o) == MRVI_OK;
  if (ok && dense_jacobian(o)) {
    o->H = malloc((nv * nv + 1) * sizeof *o->H);
    ok = o->H != NULL;
    if (ok)
      dense_slots(o);
  }
  o->rhs = calloc(f * nu + 1, sizeof(double));
  o->sol = calloc(f * nu + nu + 1, sizeof(double));
  o->nfun_alloc = ok && o->rhs && o->sol ? nfun : 0;
  if (!o->nfun_alloc)
    return MRVI_ENOMEM;
  /* The schur-krylov elimination on the step's pattern (a pattern outside
   * its block structure keeps the LU: EINVAL). */
  char msg[300];
  const mrvi_tuning *tn = &o->settings.tuning;
  if (adjoint_krylov_path(o) && tn->adjoint_krylov &&
      mrvi_skrylov_create(st, &o->skrylov, msg, sizeof msg) == MRVI_ENOMEM)
    return MRVI_ENOMEM;
  if (o->skrylov)
    mrvi_skrylov_set_rtol(o->skrylov, tn->adjoint_krylov_rtol,
                          tn->adjoint_krylov_rtol);
  /* schur-bordered: its block elimination on the step's pattern, the
   * forward pass's (node blocks, the slow block bordered, or the chain
   * elimination: each has its transposed solve); one outside its
   * structure: the general path's LU, as the forward pass's integrator
   * would have refused it.  With state actuators and a step within the
   * dense H (adjoint_dense_max), the dense LU's refinement of all
   * functionals at once costs less (bench/ocp_winch.yaml, p = 5: cost +
   * gradient 1.7x cheaper; doc/performance/ocp.md, "State actuators on schur
   * and schur-bordered"). */
  if (o->path == MRVI_PATH_SCHUR_BORDERED) {
    const int s = mrvi_bordered_create(st, &o->bordered);
    if (s == MRVI_ENOMEM)
      return s;
    if (o->bordered && o->n_state > 0 && dense_jacobian(o)) {
      mrvi_bordered_free(o->bordered);
      o->bordered = NULL;
    }
    /* (the refinement's 2 blocks and the blocked solve's nfun columns) */
    o->bd_work =
        malloc(((2 * MRVI_REFINE_BLOCK + f) * nu + 1) * sizeof *o->bd_work);
    if (!o->bd_work)
      return MRVI_ENOMEM;
    if (!o->bordered && !o->newton &&
        !(o->newton =
              mrvi_newton_create(st->n_total, st->Ap, st->Ai, st->Ax,
                                 tn->newton_dense_max, msg, sizeof msg)))
      return MRVI_ENOMEM;
  }
  return MRVI_OK;
}

/* H of step k (its data loaded) into its sparse rows (h_ptr, h_col,
 * h_val) and A_k (Ak): assembled dense (o->H) and gathered into the rows
 * of the assembly's pattern (made at the first step, sparse_pattern), or
 * into the rows directly. */
static int step_jacobian(mrvi_ocp *o, long k) {
  const int nv = o->nv;
  const long nnz = o->step.nnz;
  if (dense_jacobian(o)) {
    if (!o->h_sparse) {
      const int s = sparse_pattern(o, k);
      if (s < 0)
        return s;
      dense_slots(o);
    }
    double *H = o->H;
    memset(H, 0, (size_t)nv * (size_t)nv * sizeof *H);
    ocp_jac a = {.mode = OCP_JAC_DENSE, .nv = nv, .J = H};
    ocp_jacobian(o, k, &a);
    for (int row = 0; row < nv; row++)
      for (long e = o->h_ptr[row]; e < o->h_ptr[row + 1]; e++)
        o->h_val[e] = H[(size_t)row * (size_t)nv + (size_t)o->h_col[e]];
    for (long e = 0; e < nnz; e++)
      o->Ak[e] = H[o->h_of_a[e]];
    return MRVI_OK;
  }
  /* The slots recorded at the first step replayed; an entry outside the
   * pattern (not expected: the pattern depends on the step templates only)
   * makes it again from this step. */
  int done = 0;
  if (o->h_sparse && o->n_h_slot > 0) {
    memset(o->h_val, 0, (size_t)o->h_ptr[nv] * sizeof *o->h_val);
    ocp_jac a = {.mode = OCP_JAC_SLOTS,
                 .nv = nv,
                 .val = o->h_val,
                 .slot = o->h_slot,
                 .max_slot = o->n_h_slot};
    ocp_jacobian(o, k, &a);
    done = a.n_slot == o->n_h_slot;
  }
  for (int pass = 0; pass < 2 && !done; pass++) {
    if (!o->h_sparse || pass == 1) {
      const int s = sparse_pattern(o, k);
      if (s < 0)
        return s;
    }
    memset(o->h_val, 0, (size_t)o->h_ptr[nv] * sizeof *o->h_val);
    ocp_jac a = {.mode = OCP_JAC_SPARSE,
                 .nv = nv,
                 .ptr = o->h_ptr,
                 .col = o->h_col,
                 .val = o->h_val,
                 .slot = o->h_slot,
                 .max_slot = o->h_slot_cap};
    ocp_jacobian(o, k, &a);
    done = !a.miss;
    o->n_h_slot = done && a.n_slot == o->h_slot_cap ? a.n_slot : 0;
  }
  for (long e = 0; e < nnz; e++)
    o->Ak[e] = o->h_of_a[e] >= 0 ? o->h_val[o->h_of_a[e]] : 0.0;
  return MRVI_OK;
}

/* A_k^T x_f = b_f (rhs, sol: nfun x n_total) by the schur-krylov
 * elimination run backwards with A_k's values (adjoint_krylov_path: the
 * solver that never factorises the step); its fallback, the sparse LU of
 * the step, counted. */
static int krylov_transpose(mrvi_ocp *o, int nfun, char *msg, size_t len) {
  const size_t nt = (size_t)o->step.n_total;
  const mrvi_krylov_stats *ks = mrvi_skrylov_stats(o->skrylov);
  const long fallbacks = ks->fallbacks;
  mrvi_skrylov_factor_values(o->skrylov, o->Ak);
  for (int f = 0; f < nfun; f++) {
    const int s = mrvi_skrylov_solve(o->skrylov, 1, o->rhs + (size_t)f * nt,
                                     o->sol + (size_t)f * nt, msg, len);
    if (s < 0)
      return s;
  }
  o->adjoint_krylov_solves += nfun;
  o->adjoint_krylov_fallbacks += ks->fallbacks - fallbacks;
  return MRVI_OK;
}

/* A_k^T x (rhs, sol: nfun x n_total) with schur-bordered's block
 * elimination (bordered.c, mrvi_bordered_solve_transpose_n: the
 * functionals together, in one pass over the chain elimination's
 * factors): from the factors kept (of a later step, or of the previous
 * evaluation) refined against A_k as on the general path
 * (mrvi_refine_transpose), A_k factorised where none are kept or the
 * refinement does not get there. */
static int bd_solve(void *ctx, int nrhs, const double *b, double *x, char *msg,
                    size_t len) {
  mrvi_ocp *o = ctx;
  return mrvi_bordered_solve_transpose_n(
      o->bordered, &o->step, nrhs, b, x,
      o->bd_work + 2 * MRVI_REFINE_BLOCK * (size_t)o->step.n_total, msg, len);
}
static int bordered_transpose(mrvi_ocp *o, int nfun, char *msg, size_t len) {
  mrvi_step *st = &o->step;
  const int max_refine = o->settings.tuning.adjoint_refine_max;
  /* (a factorisation's cost in refinement steps, phi, and a solve's part
   * of one, sigma: mrvi_bordered_transpose_cost, the chain elimination's
   * and the node blocks' estimates; the bordered slow block has none, 0) */
  double sigma = 0.5;
  const double phi = o->settings.tuning.adjoint_refine_by_cost
                         ? mrvi_bordered_transpose_cost(o->bordered, st, &sigma)
                         : 0.0;
  /* Without an estimate (the bordered slow block, the whole step's LU)
   * the refinement gives up after two sweeps: where the kept factors (of
   * step k + 1, or of step 0 of the evaluation before) need more, a fresh
   * factorisation and one solve cost less (the constrained lattice at
   * n = 60 on node blocks: 5-9 sweeps per functional and step with 8
   * allowed, cost + gradient 20-25 % dearer; doc/performance/ocp.md, "The
   * constrained lattice's first evaluation").  With one, the cost rule
   * stops it (refine_give_up), and A_k is factorised at once where that
   * and the nfun solves cost less than the refinement is expected to: its
   * mean cost per functional over the steps so far, at least one
   * correction's (the first solve and the residual that accepts it). */
  const int refine =
      phi > 0.0 || max_refine <= 2 || mrvi_bordered_on_chain(o->bordered)
          ? max_refine
          : 2;
  const double expect = o->bd_ref_units > 1.0 ? o->bd_ref_units : 1.0;
  const int direct = phi > 0.0 && phi + nfun * sigma <= nfun * expect;
  int ok = 0;
  if (o->bd_factored && refine > 0 && !direct) {
    double units;
    ok = mrvi_refine_transpose(st->n_total, st->Ap, st->Ai, o->Ak, nfun, o->rhs,
                               o->sol, refine, phi, sigma, &units, o->bd_work,
                               bd_solve, o, msg, len);
    if (phi > 0.0 && ok >= 0) {
      /* The mean of the steps seen, then a running mean of weight 1/8:
       * with no history (the first evaluation) the first step's cost
       * alone, one step that converged quickly, held the mean below the
       * factorisation's cost for most of the sweep (the constrained
       * lattice at n = 60: 14 of 20 steps refined at 5-13 corrections per
       * functional, the first cost + gradient 3.1 forward runs against
       * 2.1 later; doc/performance/17-ocp17.md). */
      units = (units + (ok ? 0.0 : phi + nfun * sigma)) / nfun;
      const int c = o->bd_ref_count < 8 ? ++o->bd_ref_count : 8;
      o->bd_ref_units += (units - o->bd_ref_units) / c;
    }
  }
  if (ok < 0)
    return ok;
  if (ok == 1)
    return MRVI_OK;
  /* (step.Ax: the values the factors are of, as bordered.c reads them) */
  memcpy(st->Ax, o->Ak, (size_t)st->nnz * sizeof *st->Ax);
  o->bd_factored = 0;
  int s = mrvi_bordered_factor(o->bordered, st, msg, len);
  if (s < 0)
    return s;
  o->bd_factored = 1;
  o->adjoint_factorisations++;
  return bd_solve(o, nfun, o->rhs, o->sol, msg, len);
}

/* The backward sweep over the steps with H_k assembled and A_k^T solved:
 * o->mu (final nodes set) on every equation node from gQ (overwritten);
 * the state actuators' part of the control gradients into gu (nfun rows of
 * n_u) from the forces of H_k's assembly. */
static int adjoint_steps(mrvi_ocp *o, int nfun, double *gQ, double *gu) {
  /* (sizes: products over the functionals, nodes or steps in size_t or
   * long; within one step's unknowns, such as 2 ns + p nf <= nz <= nv, in
   * int: ocp_check_sizes refuses nv beyond INT_MAX) */
  mrvi_step *st = &o->step;
  const int ns = o->ns, nf = o->nf, p = o->p, nu = st->n_unknowns, nz = o->nz;
  const long N = o->N, nn = o->n_nodes;
  int s;
  const int nl = o->nl, nt = st->n_total;
  char msg[300];
  for (long k = N - 1; k >= 0; k--) {
    /* Step k's data and converged unknowns (x, lambda). */
    st->qs0 = o->Q + k * ns;
    st->qf0 = o->Q + (N + 1) * ns + k * p * nf;
    memcpy(o->x, o->Q + (k + 1) * ns, (size_t)ns * sizeof(double));
    memcpy(o->x + ns, o->Q + (N + 1) * ns + (k * p + 1) * nf,
           (size_t)p * (size_t)nf * sizeof(double));
    memcpy(o->x + nu, o->Lam + k * nl, (size_t)nl * sizeof(double));
    o->k_cur = k;         /* for the pair-force step hook */
    if (o->n_torsion > 0) /* step k's branches, as in the forward pass */
      mrvi_model_torsion_set(o->model, o->branch + k * o->n_torsion);
    if ((s = step_jacobian(o, k)) < 0)
      return mrvi_ocp_fail(o, s, "out of memory");
    const long *gz = o->gz; /* global node of every z of step k */
    /* r -= J_k[final rows, :]^T mu[final] (final: q_{k+1}^s and fast node
     * p, whose adjoints are known), every functional f at each entry of
     * H (its order of operations for each f as alone); the multiplier
     * columns into the right-hand sides' lambda rows. */
    for (int f = 0; f < nfun; f++)
      for (int i = 0; i < nl; i++)
        o->rhs[(size_t)f * (size_t)nt + (size_t)(nu + i)] = 0.0;
    for (int zz = ns; zz < nz; zz++) {
      if (zz >= 2 * ns && zz < 2 * ns + p * nf)
        continue;
      for (long e = o->h_ptr[zz]; e < o->h_ptr[zz + 1]; e++) {
        const int y = o->h_col[e];
        const double h = o->h_val[e];
        if (h == 0.0)
          continue;
        for (int f = 0; f < nfun; f++) {
          const double mz = o->mu[f * nn + gz[zz]];
          if (mz == 0.0)
            continue;
          if (y < nz)
            gQ[f * nn + gz[y]] -= h * mz;
          else
            o->rhs[(size_t)f * (size_t)nt + (size_t)(nu + y - nz)] -= h * mz;
        }
      }
    }
    /* Right-hand side on the step's unknowns (x_k, lambda_k). */
    for (int f = 0; f < nfun; f++) {
      const double *r = gQ + f * nn;
      double *b = o->rhs + (size_t)f * (size_t)nt;
      for (int i = 0; i < ns; i++)
        b[i] = r[gz[ns + i]];
      for (int i = 0; i < p * nf; i++)
        b[ns + i] = r[gz[2 * ns + nf + i]];
    }
    /* A_k^T mu_k = b with the step Jacobian at the converged step: where
     * the forward pass takes schur-krylov or an explicit path
     * (adjoint_krylov_path), schur-krylov's elimination run backwards;
     * else the solver's transposed solve (UMFPACK_At, or the dense LU of
     * small steps) with the factors it keeps (of step k + 1, or of the
     * forward pass's last Newton update) refined against A_k, factorised
     * anew where that does not converge in tuning.adjoint_refine_max
     * steps. */
    if (o->skrylov) {
      s = krylov_transpose(o, nfun, msg, sizeof msg);
    } else if (o->bordered) {
      s = bordered_transpose(o, nfun, msg, sizeof msg);
    } else {
      int refactored;
      s = mrvi_newton_solve_transpose_kept(
          o->newton_full ? o->newton_full : o->newton, o->Ak, nfun, o->rhs,
          o->sol, o->settings.tuning.adjoint_refine_max,
          o->settings.tuning.adjoint_refine_by_cost, &refactored, msg,
          sizeof msg);
      o->adjoint_factorisations += refactored;
    }
    if (s < 0)
      return mrvi_ocp_fail(o, s, "adjoint step %ld: %s", k + 1, msg);
    /* mu on the equation nodes of step k; r -= J_k[rows_k, :]^T mu_k
     * (every f at each entry, as above). */
    const double *x = o->sol;
    for (int i = 0; i < nt; i++) {
      /* dynamic rows: q_k^s, fast nodes 0..p-1; then constraint rows */
      const int row = i < ns ? i : (i < nu ? 2 * ns + (i - ns) : nz + i - nu);
      for (int f = 0; f < nfun && row < nz; f++)
        o->mu[f * nn + gz[row]] = x[(size_t)f * (size_t)nt + (size_t)i];
      for (long e = o->h_ptr[row]; e < o->h_ptr[row + 1]; e++) {
        const int y = o->h_col[e];
        const double h = o->h_val[e];
        if (y >= nz)
          break;
        if (h == 0.0)
          continue;
        for (int f = 0; f < nfun; f++) {
          const double xf = x[(size_t)f * (size_t)nt + (size_t)i];
          if (xf != 0.0)
            gQ[f * nn + gz[y]] -= h * xf;
        }
      }
    }
    if (o->n_state > 0)
      ocp_state_gradient(o, k, nfun, o->mu, gu);
  }
  return MRVI_OK;
}

int mrvi_ocp_evaluate(mrvi_ocp *o, const double *u, double *J, double *grad,
                      double *c, double *cgrad) {
  for (int i = 0; i < o->n_u; i++)
    if (!isfinite(u[i]))
      return mrvi_ocp_fail(o, MRVI_ENONFINITE, "control %d is not finite", i);
  int s = ocp_forward(o, u);
  if (s < 0)
    return s;
  const int nfun = 1 + o->n_con, npn = o->ns + o->nf;
  const long nn = o->n_nodes;
  if (nfun != o->nfun_alloc && adjoint_alloc(o, nfun) < 0)
    return mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
  double *gQ = o->r, *val = o->r + (size_t)nfun * (size_t)nn;
  double *gp = val + nfun, *gu = gp + (size_t)nfun * (size_t)npn;
  /* (val, gp and gu fit in the second n_nodes block of r; see alloc.) */
  functionals(o, u, val, grad || cgrad ? gQ : NULL, gp, gu);
  *J = val[0];
  if (c)
    for (int i = 0; i < o->n_con; i++)
      c[i] = val[1 + i];
  if (!grad && !cgrad)
    return MRVI_OK;

  /* Backward sweep.  mu: global node adjoints; final nodes -dPhi/dp_N. */
  const int ns = o->ns, nf = o->nf, p = o->p;
  const long N = o->N;
  /* (mu not cleared: either sweep writes every node's adjoint, step k's
   * equation nodes before any read of them) */
  for (int f = 0; f < nfun; f++) {
    for (int i = 0; i < ns; i++)
      o->mu[f * nn + N * ns + i] = -gp[(size_t)f * (size_t)npn + (size_t)i];
    for (int i = 0; i < nf; i++)
      o->mu[f * nn + (N + 1) * ns + N * p * nf + i] =
          -gp[(size_t)f * (size_t)npn + (size_t)(ns + i)];
  }
  s = o->adj_explicit ? ocp_explicit_adjoint(o, nfun, gQ)
                      : adjoint_steps(o, nfun, gQ, gu);
  if (s < 0)
    return s;
  /* dPhi/du = direct - sum_k mu[z_k]^T dforces_k/du. */
  for (int f = 0; f < nfun; f++) {
    double *out =
        f == 0 ? grad : (cgrad ? cgrad + (size_t)(f - 1) * o->n_u : NULL);
    if (!out)
      continue;
    memcpy(out, gu + (size_t)f * o->n_u, (size_t)o->n_u * sizeof(double));
    const double *mu = o->mu + f * nn;
    for (long k = 0; k < N; k++)
      for (int i = 0; i < o->n_force; i++) {
        const ocp_force *fe = &o->force[i];
        out[ocp_control_index(o, k, fe)] -=
            fe->coef * mu[ocp_global(o, k, fe->z)];
      }
  }
  return MRVI_OK;
}
