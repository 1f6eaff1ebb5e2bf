/* The adjoint of the explicit paths (fully-explicit, explicit-slow, and
 * every macro-grid V; doc/optimal-control.md, "The adjoint of the explicit
 * paths").
 *
 * On the explicit path every evaluation point sits on a node (arXiv 2406.12991
 * eq:slow_potential_affine (3.60) for V, eq:fast_potential_trapezoidal
 * (3.62) for W): V at the macro nodes with weights wV0 (node k) and wV1
 * (node k + 1), W at the micro nodes with weights ww[m] (both intervals'
 * at the interior nodes).  The Hessian of the step action L_d^k applied to
 * mu on the nodes z_k of step k is then, with hV = hess V(q) [mu^s; mu^f]
 * at a macro node and hW_m = hess W(q^m) mu^m at a micro node,
 *   s0:  M^s/dT (mu_s0 - mu_s1) - wV0 hV(k)^s
 *   s1:  M^s/dT (mu_s1 - mu_s0) - wV1 hV(k+1)^s
 *   f0:  M^f/dt (mu_0 - mu_1) - wV0 hV(k)^f - ww[0] hW_0
 *   fm:  M^f/dt (2 mu_m - mu_{m-1} - mu_{m+1}) - ww[m] hW_m, 0 < m < p
 *   fp:  M^f/dt (mu_p - mu_{p-1}) - wV1 hV(k+1)^f - ww[p] hW_p.
 * The adjoint equations (adjoint.c: sum_k H_k mu[z_k] = dPhi/dY at every
 * node but the initial ones, mu = -dPhi/dp_N on the final ones) at the
 * unknown nodes s1, f1..fp of step k give the adjoints of its equation
 * nodes s0, f0..f_{p-1} one after the other, each from adjoints already
 * known (the transposed step Jacobian A_k^T is triangular by node, its
 * diagonal -M^s/dT, -M^f/dt):
 *   mu_s0    = mu_s1 - dT/M^s R_s1,   mu_{p-1} = mu_p - dt/M^f R_p,
 *   mu_{m-1} = 2 mu_m - mu_{m+1} - dt/M^f R_m,   m = p-1..1,
 * where R at a node is dPhi/dY plus the weighted products there (both
 * steps' weights at a macro node, wV0 + wV1 and ww[0] + ww[p]), less the
 * kinetic part of the step after it (at a step's initial nodes).  R is
 * built in place in dPhi/dY's array just before it is read: one
 * Hessian-vector product of W per micro node and of V per macro node, the
 * backward twin of the forward recursion's one gradient of each (velocity
 * Verlet at p = 1), each element's Hessian formed once for every
 * functional's vector.
 *
 * The sweep paths (explicit-slow: W's points inside the micro intervals,
 * e.g. the midpoint, weight w and coefficients cA, cB on the interval's
 * nodes) couple node g's row to mu_{g-1} through the points of interval
 * g - 1 as well: their part w cA cB hess W(z_P) mu_{g-1} stays on the
 * left, and mu_{g-1} solves the transposed micro step
 *   (M^f/dt + sum_{P of g-1} w cA cB hess W(z_P)) mu_{g-1}
 *     = M^f/dt (2 mu_g - mu_{g+1}) - R_g
 * by CG with Hessian-vector products at the points (sweep_adjoint). */
#include "ocp/ocp_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The node (0 or 1) that interpolation coefficients c0, c1 put a point
 * on, -1 between the two. */
static int node_point(double c0, double c1) {
  if (c0 == 1.0 && c1 == 0.0)
    return 0;
  if (c0 == 0.0 && c1 == 1.0)
    return 1;
  return -1;
}

int ocp_explicit_ok(const mrvi_ocp *o) {
  const mrvi_step *st = &o->step;
  const int path = o->path;
  if ((path != MRVI_PATH_EXPLICIT && path != MRVI_PATH_SWEEP &&
       path != MRVI_PATH_SWEEP_CG) ||
      !o->settings.tuning.adjoint_explicit || o->nl > 0 || o->n_state > 0 ||
      o->n_torsion > 0)
    return 0;
  /* Every point on a node: V's at macro node k (fast node 0) or k + 1
   * (fast node p), W's (if it has elements) on a micro node. */
  for (int i = 0; i < st->n_pts[MRVI_SLOW]; i++) {
    const mrvi_point *pt = &st->pts[MRVI_SLOW][i];
    const int a = node_point(pt->a0, pt->a1), c = node_point(pt->cA, pt->cB);
    if (a < 0 || c != a || pt->m != (a ? o->p - 1 : 0))
      return 0;
  }
  return 1;
}

/* Whether a point of W lies inside its micro interval (the sweep paths'
 * implicit micro steps), not on a node. */
static int w_inside(const mrvi_ocp *o) {
  const mrvi_step *st = &o->step;
  for (int i = 0;
       st->n_elem_of_class[MRVI_FAST] > 0 && i < st->n_pts[MRVI_FAST]; i++)
    if (node_point(st->pts[MRVI_FAST][i].cA, st->pts[MRVI_FAST][i].cB) < 0)
      return 1;
  return 0;
}

/* Workspace (doubles): per functional hV and its vector (ns + nf each);
 * then zV (ns + nf), dT/M^s and M^s/dT (ns each), dt/M^f and M^f/dt (nf
 * each), ww (p + 1). */
int ocp_explicit_alloc(mrvi_ocp *o, int nfun) {
  const mrvi_model *m = o->model;
  const mrvi_step *st = &o->step;
  const size_t nsf = (size_t)(o->ns + o->nf), f = (size_t)nfun;
  int *col = malloc(((size_t)m->n + 1) * sizeof *col);
  if (!col)
    return MRVI_ENOMEM;
  for (int i = 0; i < m->n; i++)
    col[i] = m->rate[i] == MRVI_SLOW ? m->slot[i] : o->ns + m->slot[i];
  int s = mrvi_terms_create(m, st->elem_of_class[MRVI_SLOW],
                            st->n_elem_of_class[MRVI_SLOW], col,
                            &o->adj_terms[MRVI_SLOW]);
  for (int i = 0; i < m->n; i++)
    col[i] = m->slot[i];
  if (s == MRVI_OK)
    s = mrvi_terms_create(m, st->elem_of_class[MRVI_FAST],
                          st->n_elem_of_class[MRVI_FAST], col,
                          &o->adj_terms[MRVI_FAST]);
  free(col);
  /* (the sweep: the points' configurations 2 nf, then per functional the
   * combined adjoints and CG's r, p, q: 4 nf; its scalars: 3) */
  const size_t nfw = (size_t)o->nf;
  o->adj_work = malloc(
      (f * 2 * nsf + 3 * nsf + (size_t)o->p + 1 + (4 * f + 2) * nfw + 3 * f) *
      sizeof *o->adj_work);
  if (s < 0 || !o->adj_work)
    return MRVI_ENOMEM;
  o->adj_explicit = 1;
  return MRVI_OK;
}

/* r += w hess V(q_j) [mu^s; mu^f] at macro node j (r: nfun rows of
 * n_nodes) for every functional, through the packed hV (nfun x (ns + nf)). */
static void v_add(mrvi_ocp *o, int nfun, long j, double w, double *r) {
  const int ns = o->ns, nf = o->nf, nsf = ns + nf;
  const long nn = o->n_nodes, fj = (o->N + 1) * ns + j * o->p * nf;
  double *hV = o->adj_work, *xV = hV + (size_t)nfun * nsf;
  double *zV = xV + (size_t)nfun * nsf;
  if (w == 0.0 || !o->adj_terms[MRVI_SLOW])
    return;
  memcpy(zV, o->Q + j * ns, (size_t)ns * sizeof *zV);
  memcpy(zV + ns, o->Q + fj, (size_t)nf * sizeof *zV);
  for (int f = 0; f < nfun; f++) {
    const double *mu = o->mu + (size_t)f * (size_t)nn;
    memcpy(xV + f * nsf, mu + j * ns, (size_t)ns * sizeof *xV);
    memcpy(xV + f * nsf + ns, mu + fj, (size_t)nf * sizeof *xV);
  }
  memset(hV, 0, (size_t)nfun * (size_t)nsf * sizeof *hV);
  mrvi_terms_hessvec(o->adj_terms[MRVI_SLOW], zV, nfun, xV, nsf, hV, nsf, w);
  for (int f = 0; f < nfun; f++) {
    double *rf = r + (size_t)f * (size_t)nn;
    const double *h = hV + (size_t)f * nsf;
    for (int i = 0; i < ns; i++)
      rf[j * ns + i] += h[i];
    for (int i = 0; i < nf; i++)
      rf[fj + i] += h[ns + i];
  }
}

/* r += w hess W(q^g) mu^g at global fast node g for every functional
 * (straight into r's rows: W's columns are the fast slots). */
static void w_add(mrvi_ocp *o, int nfun, long g, double w, double *r) {
  const long at = (o->N + 1) * o->ns + g * o->nf;
  if (w != 0.0)
    mrvi_terms_hessvec(o->adj_terms[MRVI_FAST], o->Q + at, nfun, o->mu + at,
                       o->n_nodes, r + at, o->n_nodes, w);
}

/* The sweeps' coefficients from cs on (the workspace's layout): dT/M^s,
 * M^s/dT, dt/M^f, M^f/dt, W's weight on each micro node of a step where
 * its points are on nodes (ww, p + 1), and V's on macro nodes k and k + 1
 * (wV). */
static void coefficients(const mrvi_ocp *o, double *cs, double *wV) {
  const mrvi_model *m = o->model;
  const mrvi_step *st = &o->step;
  const int ns = o->ns, nf = o->nf, p = o->p;
  double *ks = cs + ns, *cf = ks + ns, *kf = cf + nf, *ww = kf + nf;
  for (int i = 0; i < ns; i++) {
    ks[i] = m->mass[m->slow_index[i]] / st->dT;
    cs[i] = st->dT / m->mass[m->slow_index[i]];
  }
  for (int i = 0; i < nf; i++) {
    kf[i] = m->mass[m->fast_index[i]] / st->dt;
    cf[i] = st->dt / m->mass[m->fast_index[i]];
  }
  /* The points' weights on their nodes (ocp_explicit_ok). */
  wV[0] = wV[1] = 0.0;
  for (int i = 0; i < st->n_pts[MRVI_SLOW]; i++)
    wV[st->pts[MRVI_SLOW][i].a1 == 1.0] += st->pts[MRVI_SLOW][i].w;
  for (int mm = 0; mm <= p; mm++)
    ww[mm] = 0.0;
  for (int i = 0; o->adj_terms[MRVI_FAST] && st->n_elem_of_class[MRVI_FAST] &&
                  i < st->n_pts[MRVI_FAST];
       i++) {
    const mrvi_point *pt = &st->pts[MRVI_FAST][i];
    if (node_point(pt->cA, pt->cB) >= 0)
      ww[pt->m + (pt->cB == 1.0)] += pt->w;
  }
}

/* The sweep of the file's header with r's rows completed in place: before
 * a node's adjoint is found from the row of its successor, that row holds
 * r plus the weighted products at the successor (and, at a step's
 * initial nodes, less the kinetic part of the step after). */
/* The rows of macro node k for step k - 1: step k's kinetic part taken
 * off (ks, kf: its slow and fast coefficients) with the adjoints of step
 * k's first nodes. */
static void kinetic_off(const mrvi_ocp *o, int nfun, long k, const double *ks,
                        const double *kf, double *gQ) {
  const int ns = o->ns, nf = o->nf;
  const long nn = o->n_nodes, F0 = (o->N + 1) * ns;
  const long s0 = k * ns, s1 = s0 + ns, fk = F0 + k * o->p * nf;
  for (int f = 0; f < nfun; f++) {
    const double *mu = o->mu + (size_t)f * (size_t)nn;
    double *r = gQ + (size_t)f * (size_t)nn;
    for (int i = 0; i < ns; i++)
      r[s0 + i] -= ks[i] * (mu[s0 + i] - mu[s1 + i]);
    for (int i = 0; i < nf; i++)
      r[fk + i] -= kf[i] * (mu[fk + i] - mu[fk + nf + i]);
  }
}

static void node_adjoint(mrvi_ocp *o, int nfun, double *gQ) {
  const int ns = o->ns, nf = o->nf, p = o->p, nsf = ns + nf;
  const long N = o->N, nn = o->n_nodes, F0 = (N + 1) * ns;
  double *cs = o->adj_work + (size_t)nfun * 2 * nsf + nsf, *ks = cs + ns;
  double *cf = ks + ns, *kf = cf + nf, *ww = kf + nf;
  double wV[2];
  coefficients(o, cs, wV);
  const double wV0 = wV[0], wV1 = wV[1];
  /* The final macro node: step N - 1's products alone. */
  v_add(o, nfun, N, wV1, gQ);
  w_add(o, nfun, N * p, ww[p], gQ);
  for (long k = N - 1; k >= 0; k--) {
    const long s0 = k * ns, s1 = s0 + ns, fk = F0 + k * p * nf;
    const long fp = fk + (long)p * nf;
    /* mu_s0 and mu_{p-1} from the rows of q_{k+1}^s and fast node p. */
    for (int f = 0; f < nfun; f++) {
      double *mu = o->mu + (size_t)f * (size_t)nn;
      const double *r = gQ + (size_t)f * (size_t)nn;
      for (int i = 0; i < ns; i++)
        mu[s0 + i] = mu[s1 + i] - cs[i] * r[s1 + i];
      for (int i = 0; i < nf; i++)
        mu[fp - nf + i] = mu[fp + i] - cf[i] * r[fp + i];
    }
    /* mu_{m-1} from the row of interior micro node m = p-1..1. */
    for (int mm = p - 1; mm >= 1; mm--) {
      const long fm = fk + (long)mm * nf;
      w_add(o, nfun, k * p + mm, ww[mm], gQ);
      for (int f = 0; f < nfun; f++) {
        double *mu = o->mu + (size_t)f * (size_t)nn;
        const double *r = gQ + (size_t)f * (size_t)nn;
        for (int i = 0; i < nf; i++)
          mu[fm - nf + i] =
              2.0 * mu[fm + i] - mu[fm + nf + i] - cf[i] * r[fm + i];
      }
    }
    if (k == 0)
      break; /* the initial nodes are data */
    /* The rows of macro node k for step k - 1: step k's kinetic part off,
     * both steps' products on. */
    kinetic_off(o, nfun, k, ks, kf, gQ);
    v_add(o, nfun, k, wV0 + wV1, gQ);
    w_add(o, nfun, k * p, ww[0] + ww[p], gQ);
  }
}

/* The matrix M^f/dt + sum_P w cA cB hess W(z_P) of a micro interval's
 * transposed step (the sweep paths' midpoint-type W), by its points. */
typedef struct {
  const double *kf, *z[2];
  double w[2];
  int np;
} interval_op;

/* q_f = B p_f for the nfun vectors p, q (nf each, consecutive): each
 * spring's Hessian formed once per point for all of them. */
static void interval_products(const mrvi_ocp *o, const interval_op *B, int nfun,
                              const double *p, double *q) {
  const int nf = o->nf;
  for (int f = 0; f < nfun; f++)
    for (int i = 0; i < nf; i++)
      q[(size_t)f * nf + i] = B->kf[i] * p[(size_t)f * nf + i];
  for (int i = 0; i < B->np; i++)
    mrvi_terms_hessvec(o->adj_terms[MRVI_FAST], B->z[i], nfun, p, nf, q, nf,
                       B->w[i]);
}

/* B x_f = r_f for every functional (x_f = x + f xs; r: nfun x nf, the
 * right-hand sides, overwritten) by Jacobi-preconditioned CG (dinv =
 * dt/M^f) run for all of them in step, one product of B with all their
 * directions per iteration; each stops at ||r_f||_inf <= rtol ||b_f||_inf.
 * p and q: nfun x nf each, then 3 nfun scalars after q.  MRVI_CG_OK,
 * _CURVATURE or _MAXIT (*its: iterations). */
static int interval_solve(const mrvi_ocp *o, const interval_op *B, int nfun,
                          const double *dinv, double *r, double *x, long xs,
                          double *p, double *q, double rtol, int *its) {
  const int nf = o->nf;
  double *rz = q + (size_t)nfun * nf, *stop = rz + nfun, *done = stop + nfun;
  int left = nfun;
  for (int f = 0; f < nfun; f++) {
    double *rf = r + (size_t)f * nf, *pf = p + (size_t)f * nf, bn = 0.0;
    double *xf = x + (size_t)f * (size_t)xs;
    rz[f] = 0.0;
    for (int i = 0; i < nf; i++) {
      xf[i] = 0.0;
      pf[i] = dinv[i] * rf[i];
      rz[f] += rf[i] * pf[i];
      const double a = fabs(rf[i]);
      bn = isnan(a) || a > bn ? a : bn;
    }
    stop[f] = rtol * bn;
    done[f] = !(bn > stop[f]);
    left -= done[f] != 0.0;
  }
  for (*its = 1; left > 0 && *its <= MRVI_CG_MAX_IT; ++*its) {
    interval_products(o, B, nfun, p, q);
    for (int f = 0; f < nfun; f++) {
      if (done[f] != 0.0)
        continue;
      double *rf = r + (size_t)f * nf, *pf = p + (size_t)f * nf;
      const double *qf = q + (size_t)f * nf;
      double *xf = x + (size_t)f * (size_t)xs, pq = 0.0;
      for (int i = 0; i < nf; i++)
        pq += pf[i] * qf[i];
      if (!(pq > 0.0))
        return MRVI_CG_CURVATURE;
      const double alpha = rz[f] / pq;
      double rn = 0.0, rz1 = 0.0;
      for (int i = 0; i < nf; i++) {
        xf[i] += alpha * pf[i];
        rf[i] -= alpha * qf[i];
        const double a = fabs(rf[i]);
        rn = isnan(a) || a > rn ? a : rn;
        rz1 += rf[i] * (dinv[i] * rf[i]);
      }
      if (!isfinite(rn))
        return MRVI_CG_MAXIT;
      if (rn <= stop[f]) {
        done[f] = 1.0;
        left--;
        continue;
      }
      const double beta = rz1 / rz[f];
      rz[f] = rz1;
      for (int i = 0; i < nf; i++)
        pf[i] = dinv[i] * rf[i] + beta * pf[i];
    }
  }
  return left == 0 ? MRVI_CG_OK : MRVI_CG_MAXIT;
}

/* R at fast node g (global) += sum over the points P of interval g (global)
 * of w cA hess W(z_P) (cA mu_g + cB mu_{g+1}): that interval's part of
 * row g (z, v: the workspace's zW and vW). */
static void interval_row_a(mrvi_ocp *o, int nfun, long g, double *gQ, double *z,
                           double *v) {
  const mrvi_step *st = &o->step;
  const int nf = o->nf, mm = (int)(g % o->p);
  const long nn = o->n_nodes, at = (o->N + 1) * o->ns + g * nf;
  for (int ip = 0; ip < st->n_pts[MRVI_FAST]; ip++) {
    const mrvi_point *pt = &st->pts[MRVI_FAST][ip];
    if (pt->m != mm || pt->cA == 0.0)
      continue;
    for (int i = 0; i < nf; i++)
      z[i] = pt->cA * o->Q[at + i] + pt->cB * o->Q[at + nf + i];
    for (int f = 0; f < nfun; f++) {
      const double *mu = o->mu + (size_t)f * (size_t)nn + at;
      for (int i = 0; i < nf; i++)
        v[(size_t)f * nf + i] = pt->cA * mu[i] + pt->cB * mu[nf + i];
    }
    mrvi_terms_hessvec(o->adj_terms[MRVI_FAST], z, nfun, v, nf, gQ + at, nn,
                       pt->w * pt->cA);
  }
}

/* The sweep paths (W's points inside the micro intervals): the header's
 * recursion with the fast rows coupled through the interval's points.
 * Row g of a fast node (g > 0, global) holds, besides the kinetic part
 * and r, the points of interval g (w cA hess W (cA mu_g + cB mu_{g+1}))
 * and of interval g - 1 (w cB hess W (cA mu_{g-1} + cB mu_g)); mu_{g-1}
 * solves
 *   (M^f/dt + sum_{P of g-1} w cA cB hess W(z_P)) mu_{g-1}
 *     = M^f/dt (2 mu_g - mu_{g+1}) - R_g
 * (mu_p alone for 2 mu_g - mu_{g+1} at a step's last node), R_g being r
 * plus every product of known adjoints: the transposed micro step, solved
 * by Jacobi-preconditioned CG (solver/krylov.c) with Hessian-vector
 * products at the interval's points, to tuning.krylov_cg_rtol. */
static int sweep_adjoint(mrvi_ocp *o, int nfun, double *gQ) {
  const mrvi_step *st = &o->step;
  const int ns = o->ns, nf = o->nf, p = o->p, nsf = ns + nf;
  const long N = o->N, nn = o->n_nodes, F0 = (N + 1) * ns;
  double *cs = o->adj_work + (size_t)nfun * 2 * nsf + nsf, *ks = cs + ns;
  double *cf = ks + ns, *kf = cf + nf, *ww = kf + nf;
  double *zW = ww + p + 1, *vW = zW + 2 * (size_t)nf;
  double *c = vW + (size_t)nfun * nf, *cp = c + (size_t)nfun * nf;
  double *cq = cp + (size_t)nfun * nf;
  double wV[2];
  coefficients(o, cs, wV);
  const double rtol = o->settings.tuning.adjoint_krylov_rtol;
  interval_op B = {.kf = kf};
  v_add(o, nfun, N, wV[1], gQ);
  for (long k = N - 1; k >= 0; k--) {
    const long s0 = k * ns, s1 = s0 + ns, fk = F0 + k * p * nf;
    for (int f = 0; f < nfun; f++) {
      double *mu = o->mu + (size_t)f * (size_t)nn;
      const double *r = gQ + (size_t)f * (size_t)nn;
      for (int i = 0; i < ns; i++)
        mu[s0 + i] = mu[s1 + i] - cs[i] * r[s1 + i];
    }
    for (int j = p; j >= 1; j--) {
      const long fj = fk + (long)j * nf, g = k * p + j;
      if (j < p)
        interval_row_a(o, nfun, g, gQ, zW, vW);
      /* Interval j - 1's points: their mu_g part of row g, and B. */
      B.np = 0;
      for (int ip = 0; ip < st->n_pts[MRVI_FAST] && B.np < 2; ip++) {
        const mrvi_point *pt = &st->pts[MRVI_FAST][ip];
        if (pt->m != j - 1)
          continue;
        double *z = zW + (size_t)B.np * nf;
        for (int i = 0; i < nf; i++)
          z[i] = pt->cA * o->Q[fj - nf + i] + pt->cB * o->Q[fj + i];
        if (pt->cB != 0.0)
          mrvi_terms_hessvec(o->adj_terms[MRVI_FAST], z, nfun, o->mu + fj, nn,
                             gQ + fj, nn, pt->w * pt->cB * pt->cB);
        B.z[B.np] = z;
        B.w[B.np++] = pt->w * pt->cA * pt->cB;
      }
      for (int f = 0; f < nfun; f++) {
        const double *mu = o->mu + (size_t)f * (size_t)nn;
        const double *r = gQ + (size_t)f * (size_t)nn;
        double *cf_ = c + (size_t)f * nf;
        for (int i = 0; i < nf; i++)
          cf_[i] = kf[i] * (j < p ? 2.0 * mu[fj + i] - mu[fj + nf + i]
                                  : mu[fj + i]) -
                   r[fj + i];
      }
      int its;
      const int s = interval_solve(o, &B, nfun, cf, c, o->mu + fj - nf, nn, cp,
                                   cq, rtol, &its);
      if (s != MRVI_CG_OK)
        return mrvi_ocp_fail(o, MRVI_ESINGULAR,
                             "adjoint of micro step %ld: CG %s after %d "
                             "iterations",
                             g,
                             s == MRVI_CG_CURVATURE
                                 ? "met non-positive curvature"
                                 : "did not converge",
                             its);
    }
    if (k == 0)
      break;
    kinetic_off(o, nfun, k, ks, kf, gQ);
    v_add(o, nfun, k, wV[0] + wV[1], gQ);
    interval_row_a(o, nfun, k * p, gQ, zW, vW);
  }
  return MRVI_OK;
}

int ocp_explicit_adjoint(mrvi_ocp *o, int nfun, double *gQ) {
  if (w_inside(o))
    return sweep_adjoint(o, nfun, gQ);
  node_adjoint(o, nfun, gQ);
  return MRVI_OK;
}
