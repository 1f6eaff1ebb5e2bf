/* The adjoint of the explicit path (fully-explicit, and every macro-grid
 * V beside a trapezoidal-family W; doc/optimal-control.md, "The adjoint of
 * the explicit path").
 *
 * On that path every evaluation point sits on a node (arXiv 2406.12991
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
 * functional's vector. */
#include "ocp/ocp_internal.h"

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
  if (o->path != MRVI_PATH_EXPLICIT || !o->settings.tuning.adjoint_explicit ||
      o->nl > 0 || o->n_state > 0 || o->n_torsion > 0)
    return 0;
  /* Every point on a node: V's at macro node k (fast node 0) or k + 1
   * (fast node p), W's (if it has elements) on a micro node. */
  for (int i = 0; i < st->n_pts[MRVI_SLOW]; i++) {
    const mrvi_point *pt = &st->pts[MRVI_SLOW][i];
    const int a = node_point(pt->a0, pt->a1), c = node_point(pt->cA, pt->cB);
    if (a < 0 || c != a || pt->m != (a ? o->p - 1 : 0))
      return 0;
  }
  for (int i = 0;
       st->n_elem_of_class[MRVI_FAST] > 0 && i < st->n_pts[MRVI_FAST]; i++)
    if (node_point(st->pts[MRVI_FAST][i].cA, st->pts[MRVI_FAST][i].cB) < 0)
      return 0;
  return 1;
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
  o->adj_work =
      malloc((f * 2 * nsf + 3 * nsf + (size_t)o->p + 1) * sizeof *o->adj_work);
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

/* The sweep of the file's header with r's rows completed in place: before
 * a node's adjoint is found from the row of its successor, that row holds
 * r plus the weighted products at the successor (and, at a step's
 * initial nodes, less the kinetic part of the step after). */
void ocp_explicit_adjoint(mrvi_ocp *o, int nfun, double *gQ) {
  const mrvi_model *m = o->model;
  const mrvi_step *st = &o->step;
  const int ns = o->ns, nf = o->nf, p = o->p, nsf = ns + nf;
  const long N = o->N, nn = o->n_nodes, F0 = (N + 1) * ns;
  double *cs = o->adj_work + (size_t)nfun * 2 * nsf + nsf, *ks = cs + ns;
  double *cf = ks + ns, *kf = cf + nf, *ww = kf + nf;
  for (int i = 0; i < ns; i++) {
    ks[i] = m->mass[m->slow_index[i]] / st->dT;
    cs[i] = st->dT / m->mass[m->slow_index[i]];
  }
  for (int i = 0; i < nf; i++) {
    kf[i] = m->mass[m->fast_index[i]] / st->dt;
    cf[i] = st->dt / m->mass[m->fast_index[i]];
  }
  /* The points' weights on their nodes (ocp_explicit_ok). */
  double wV0 = 0.0, wV1 = 0.0;
  for (int i = 0; i < st->n_pts[MRVI_SLOW]; i++)
    *(st->pts[MRVI_SLOW][i].a1 == 1.0 ? &wV1 : &wV0) += st->pts[MRVI_SLOW][i].w;
  for (int mm = 0; mm <= p; mm++)
    ww[mm] = 0.0;
  for (int i = 0; o->adj_terms[MRVI_FAST] && st->n_elem_of_class[MRVI_FAST] &&
                  i < st->n_pts[MRVI_FAST];
       i++) {
    const mrvi_point *pt = &st->pts[MRVI_FAST][i];
    ww[pt->m + (pt->cB == 1.0)] += pt->w;
  }
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
    for (int f = 0; f < nfun; f++) {
      const double *mu = o->mu + (size_t)f * (size_t)nn;
      double *r = gQ + (size_t)f * (size_t)nn;
      for (int i = 0; i < ns; i++)
        r[s0 + i] -= ks[i] * (mu[s0 + i] - mu[s1 + i]);
      for (int i = 0; i < nf; i++)
        r[fk + i] -= kf[i] * (mu[fk + i] - mu[fk + nf + i]);
    }
    v_add(o, nfun, k, wV0 + wV1, gQ);
    w_add(o, nfun, k * p, ww[0] + ww[p], gQ);
  }
}
