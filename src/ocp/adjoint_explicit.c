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
 * by CG with Hessian-vector products at the points (sweep_adjoint), or,
 * where W's springs join the fast particles in a forest (chains, trees),
 * exactly by block elimination along it (struct ocp_forest). */
#include "ocp/ocp_internal.h"
#include "util/simd.h"
#include "util/small.h"

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

struct ocp_forest;
static struct ocp_forest *forest_build(const mrvi_ocp *o);

/* Workspace (doubles): per functional hV and its vector (ns + nf each);
 * then zV (ns + nf), dT/M^s and M^s/dT (ns each), dt/M^f and M^f/dt (nf
 * each), ww (p + 1); the sweep's below. */
int ocp_explicit_alloc(mrvi_ocp *o, int nfun) {
  const mrvi_model *m = o->model;
  const mrvi_step *st = &o->step;
  const size_t nsf = (size_t)(o->ns + o->nf), f = (size_t)nfun;
  int *col = malloc(((size_t)m->n + 1) * sizeof *col);
  if (!col)
    return MRVI_ENOMEM;
  for (int i = 0; i < m->n; i++)
    col[i] = m->rate[i] == MRVI_SLOW ? m->slot[i] : o->ns + m->slot[i];
  int s = mrvi_terms_create_range(
      m, st->elem_of_class[MRVI_SLOW], st->elem_first[MRVI_SLOW],
      st->n_elem_of_class[MRVI_SLOW], col, 0, &o->adj_terms[MRVI_SLOW]);
  for (int i = 0; i < m->n; i++)
    col[i] = m->slot[i];
  if (s == MRVI_OK)
    s = mrvi_terms_create_range(
        m, st->elem_of_class[MRVI_FAST], st->elem_first[MRVI_FAST],
        st->n_elem_of_class[MRVI_FAST], col, 0, &o->adj_terms[MRVI_FAST]);
  free(col);
  /* (the sweep: the points' configurations 2 nf, then per functional the
   * combined adjoints and CG's r, p, q: 4 nf; its scalars: 5; hy: nf; a
   * norm: 1) */
  const size_t nfw = (size_t)o->nf;
  o->adj_work = malloc(
      (f * 2 * nsf + 3 * nsf + (size_t)o->p + 1 + (5 * f + 2) * nfw + 6 * f) *
      sizeof *o->adj_work);
  if (s < 0 || !o->adj_work)
    return MRVI_ENOMEM;
  /* W's Hessian blocks at one node or at an interval's two points (tuning
   * adjoint_hessblocks) */
  o->adj_hb = 0;
  o->adj_one = o->settings.tuning.adjoint_one_point;
  if (o->settings.tuning.adjoint_hessblocks &&
      o->step.n_elem_of_class[MRVI_FAST] > 0)
    o->adj_hb = mrvi_terms_hessblocks_size(o->adj_terms[MRVI_FAST]);
  if (o->adj_hb > 0 &&
      !(o->adj_blocks = malloc(2 * (size_t)o->adj_hb * sizeof(double))))
    return MRVI_ENOMEM;
  /* explicit-slow's micro steps by elimination along W's forest of
   * springs (tuning adjoint_forest; where it is none: by the CG) */
  o->adj_forest = NULL;
  if (o->adj_hb > 0 && o->settings.tuning.adjoint_forest && w_inside(o))
    o->adj_forest = forest_build(o);
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
 * (straight into r's rows: W's columns are the fast slots); the blocks
 * formed in one loop, then applied, where they are kept (the square
 * roots and divisions of the springs then overlap, unhindered by the
 * products' scattered additions). */
static void w_add(mrvi_ocp *o, int nfun, long g, double w, double *r) {
  const long at = (o->N + 1) * o->ns + g * o->nf;
  if (w == 0.0)
    return;
  mrvi_terms *W = o->adj_terms[MRVI_FAST];
  if (o->adj_hb > 0) {
    mrvi_terms_hessblocks(W, o->Q + at, o->adj_blocks);
    mrvi_terms_hessblocks_apply(W, o->adj_blocks, nfun, o->mu + at, o->n_nodes,
                                r + at, o->n_nodes, w, NULL);
  } else {
    mrvi_terms_hessvec(W, o->Q + at, nfun, o->mu + at, o->n_nodes, r + at,
                       o->n_nodes, w);
  }
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
    ks[i] = MRVI_MASS(m, m->slow_index[i]) / st->dT;
    cs[i] = st->dT / MRVI_MASS(m, m->slow_index[i]);
  }
  for (int i = 0; i < nf; i++) {
    kf[i] = MRVI_MASS(m, m->fast_index[i]) / st->dt;
    cf[i] = st->dt / MRVI_MASS(m, m->fast_index[i]);
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
      double *r = gQ + (size_t)f * (size_t)nn;
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
        double *r = gQ + (size_t)f * (size_t)nn;
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

/* A micro interval of the sweep paths (W's points inside it) by its
 * points P (at most two, mrvi_quadrature_points): their configurations
 * z_P = cA q_g + cB q_{g+1} on the interval's nodes g, g + 1, weights and
 * coefficients, and the Hessian blocks of W at the points inside the
 * interval (cA cB != 0), kept for the products there (hb, or NULL: formed
 * per product, mrvi_terms_hessvec).  The matrix of its transposed step is
 * M^f/dt + sum_P w cA cB hess W(z_P). */
typedef struct {
  const double *kf;
  int np;
  double *z[2], *hb[2];
  double w[2], cA[2], cB[2];
} interval_op;

/* y_v += scale hess W(z_P) x_v for point i of B and the nvec vectors
 * x_v = x + v xs, y_v = y + v ys (and xhx[v] += x_v^T that, where the
 * point's blocks are kept and xhx is not NULL). */
static void point_product(const mrvi_ocp *o, const interval_op *B, int i,
                          int nvec, const double *x, long xs, double *y,
                          long ys, double scale, double *xhx) {
  if (scale == 0.0)
    return;
  if (B->hb[i])
    mrvi_terms_hessblocks_apply(o->adj_terms[MRVI_FAST], B->hb[i], nvec, x, xs,
                                y, ys, scale, xhx);
  else
    mrvi_terms_hessvec(o->adj_terms[MRVI_FAST], B->z[i], nvec, x, xs, y, ys,
                       scale);
}

/* B for interval m of the step whose fast nodes start at Q + at (its
 * nodes m and m + 1): the points, their configurations in zW (2 nf) and
 * the blocks of those inside it in hbW (2 mrvi_terms_hessblocks_size, or
 * NULL: none kept). */
static void interval_setup(const mrvi_ocp *o, interval_op *B, long at, int m,
                           double *zW, double *hbW, long nhb) {
  const mrvi_step *st = &o->step;
  const int nf = o->nf;
  const double *q0 = o->Q + at + (long)m * nf, *q1 = q0 + nf;
  B->np = 0;
  for (int ip = 0; ip < st->n_pts[MRVI_FAST] && B->np < 2; ip++) {
    const mrvi_point *pt = &st->pts[MRVI_FAST][ip];
    if (pt->m != m)
      continue;
    const int i = B->np++;
    double *z = B->z[i] = zW + (size_t)i * nf;
    for (int f = 0; f < nf; f++)
      z[f] = pt->cA * q0[f] + pt->cB * q1[f];
    B->w[i] = pt->w;
    B->cA[i] = pt->cA;
    B->cB[i] = pt->cB;
    B->hb[i] = NULL;
    if (hbW && pt->cA != 0.0 && pt->cB != 0.0) {
      B->hb[i] = hbW + i * nhb;
      mrvi_terms_hessblocks(o->adj_terms[MRVI_FAST], z, B->hb[i]);
    }
  }
}

/* explicit-slow's transposed micro-step matrix K + sum_P c_P hess W(z_P)
 * (K = M^f/dt, c_P = w cA cB) where W's elements are springs and anchors
 * (mrvi_terms_hessblocks_springs) whose springs join the fast particles in
 * a forest: the lattices' fibres are chains.  Its nodes are those
 * particles (d columns each) in an elimination order, leaves first, each
 * joined to at most one later node, its parent, by block pe; the matrix's
 * block LDL^T (A_vv = D_v, A_pv = L_v D_v) has no fill: per node D_v^-1
 * and L_v = A_pv D_v^-1 (d x d each, row-major).  The other fast columns
 * are K's alone. */
struct ocp_forest {
  int nv, d, nb;
  int *col;          /* nv x d: the nodes' fast columns */
  int *par;          /* per node its parent (a later node) or -1 */
  int *pe;           /* per node the block joining it to its parent */
  int *bi, *bj;      /* per block its nodes (bj: -1 for an anchor) */
  int *child;        /* per block the node whose parent it joins, or -1 */
  int *inc, *inc_at; /* per node its blocks (springs, anchors): inc[inc_at[v]
                        .. inc_at[v + 1]) */
  int *ch, *ch_at;   /* per node its children, likewise */
  int *lone, nlone;  /* the fast columns outside the forest */
  int two;           /* the last factors forest_factor_2's (D_v^-1 packed) */
  double *D, *L;
};

void ocp_forest_free(struct ocp_forest *F) {
  if (!F)
    return;
  free(F->col);
  free(F->par);
  free(F->pe);
  free(F->bi);
  free(F->bj);
  free(F->child);
  free(F->inc);
  free(F->inc_at);
  free(F->ch);
  free(F->ch_at);
  free(F->lone);
  free(F->D);
  free(F->L);
  free(F);
}

/* The node of the d columns c (a particle's), made where none is yet
 * (node numbers in order of first use; cols, colnode): -1 where the
 * columns are not one particle's. */
static int forest_node(int nf, int d, const int *c, int *colnode, int *cols,
                       int *nv) {
  if (c[0] < 0 || c[0] >= nf)
    return -1;
  int v = colnode[c[0]];
  if (v < 0) {
    v = (*nv)++;
    for (int k = 0; k < d; k++) {
      if (c[k] < 0 || c[k] >= nf || colnode[c[k]] >= 0)
        return -1;
      colnode[c[k]] = v;
      cols[v * d + k] = c[k];
    }
  }
  for (int k = 0; k < d; k++)
    if (cols[v * d + k] != c[k])
      return -1;
  return v;
}

/* The forest of o's W, or NULL (not springs and anchors alone, a cycle of
 * springs, or out of memory: the CG takes every micro step). */
static struct ocp_forest *forest_build(const mrvi_ocp *o) {
  const int d = o->model->dimension, nf = o->nf;
  const int ne = o->step.n_elem_of_class[MRVI_FAST];
  struct ocp_forest *F = calloc(1, sizeof *F);
  int *ci = malloc(((size_t)d * ne + 1) * sizeof *ci);
  int *cj = malloc(((size_t)d * ne + 1) * sizeof *cj);
  int *colnode = malloc(((size_t)nf + 1) * sizeof *colnode);
  int *cols = malloc(((size_t)nf + 1) * sizeof *cols);
  int *up = malloc(((size_t)nf + 1) * sizeof *up);
  int *deg = calloc((size_t)nf + 2, sizeof *deg);
  int *adj = NULL, *pos = NULL, *queue = NULL, *tree = NULL, ok = 0;
  if (!F || !ci || !cj || !colnode || !cols || !up || !deg || d < 1 || d > 3)
    goto out;
  F->d = d;
  const int nb = mrvi_terms_hessblocks_springs(o->adj_terms[MRVI_FAST], ci, cj);
  if (nb < 1 || nb > ne)
    goto out;
  F->nb = nb;
  F->bi = malloc((size_t)nb * sizeof *F->bi);
  F->bj = malloc((size_t)nb * sizeof *F->bj);
  F->child = malloc((size_t)nb * sizeof *F->child);
  if (!F->bi || !F->bj || !F->child)
    goto out;
  for (int i = 0; i < nf; i++)
    colnode[i] = -1;
  int nv = 0;
  for (int b = 0; b < nb; b++) {
    F->child[b] = -1;
    F->bi[b] = forest_node(nf, d, ci + (size_t)b * d, colnode, cols, &nv);
    F->bj[b] = cj[(size_t)b * d] < 0
                   ? -1
                   : forest_node(nf, d, cj + (size_t)b * d, colnode, cols, &nv);
    if (F->bi[b] < 0 || (cj[(size_t)b * d] >= 0 && F->bj[b] < 0) ||
        F->bi[b] == F->bj[b])
      goto out;
  }
  /* A forest: no spring closes a cycle (nor doubles another). */
  for (int v = 0; v < nv; v++)
    up[v] = v;
  for (int b = 0; b < nb; b++) {
    if (F->bj[b] < 0)
      continue;
    const int a = mrvi_uf_root(up, F->bi[b]), c = mrvi_uf_root(up, F->bj[b]);
    if (a == c)
      goto out;
    up[a] = c;
    deg[F->bi[b] + 1]++;
    deg[F->bj[b] + 1]++;
  }
  /* Adjacency (blocks by node), then leaves first: a node is taken when
   * at most one neighbour is left, which becomes its parent. */
  adj = malloc(((size_t)2 * nb + 1) * sizeof *adj);
  pos = malloc(((size_t)nv + 1) * sizeof *pos);
  queue = malloc(((size_t)nv + 1) * sizeof *queue);
  F->col = malloc(((size_t)nv * d + 1) * sizeof *F->col);
  F->par = malloc(((size_t)nv + 1) * sizeof *F->par);
  F->pe = malloc(((size_t)nv + 1) * sizeof *F->pe);
  F->D = malloc(((size_t)nv * d * d + 1) * sizeof *F->D);
  F->L = malloc(((size_t)nv * d * d + 1) * sizeof *F->L);
  if (!adj || !pos || !queue || !F->col || !F->par || !F->pe || !F->D || !F->L)
    goto out;
  for (int v = 0; v < nv; v++)
    deg[v + 1] += deg[v];
  for (int v = 0; v < nv; v++)
    pos[v] = deg[v];
  for (int b = 0; b < nb; b++)
    if (F->bj[b] >= 0) {
      adj[pos[F->bi[b]]++] = b;
      adj[pos[F->bj[b]]++] = b;
    }
  /* Each tree from a leaf (or its one node), depth first, a node
   * numbered where it is reached, from nv - 1 down: a node's subtree gets
   * the numbers below its own, and a chain's nodes follow one another.
   * up: the new number (-1 not reached); pos: the block to the parent. */
  int taken = 0, nt = 0;
  tree = malloc(((size_t)2 * nv + 1) * sizeof *tree);
  if (!tree)
    goto out;
  for (int v = 0; v < nv; v++)
    up[v] = -1;
  for (int pass = 0; pass < 2; pass++)
    for (int r0 = 0; r0 < nv; r0++) {
      if (up[r0] >= 0 || (pass == 0 && deg[r0 + 1] - deg[r0] > 1))
        continue;
      tree[2 * nt] = taken;
      int nst = 0;
      queue[nst++] = r0;
      pos[r0] = -1;
      up[r0] = nv - 1 - taken++;
      while (nst > 0) {
        const int v = queue[--nst];
        for (int e = deg[v]; e < deg[v + 1]; e++) {
          const int b = adj[e], w = F->bi[b] == v ? F->bj[b] : F->bi[b];
          if (up[w] >= 0)
            continue;
          up[w] = nv - 1 - taken++;
          pos[w] = b;
          queue[nst++] = w;
        }
      }
      tree[2 * nt + 1] = taken - tree[2 * nt];
      nt++;
    }
  /* The trees interleaved four at a time, each in its order: the
   * consecutive nodes of an elimination then belong to four independent
   * chains, whose divisions and updates overlap (queue: the nodes by
   * number). */
  for (int v = 0; v < nv; v++)
    queue[up[v]] = v;
  for (int t0 = 0, e = 0; t0 < nt; t0 += 4) {
    const int t1 = t0 + 4 < nt ? t0 + 4 : nt;
    int most = 0;
    for (int t = t0; t < t1; t++)
      most = tree[2 * t + 1] > most ? tree[2 * t + 1] : most;
    for (int i = 0; i < most; i++)
      for (int t = t0; t < t1; t++)
        if (i < tree[2 * t + 1]) /* (tree t's nodes: numbers nv - taken) */
          up[queue[nv - tree[2 * t] - tree[2 * t + 1] + i]] = e++;
  }
  for (int v = 0; v < nv; v++) {
    F->pe[up[v]] = pos[v];
    if (pos[v] >= 0)
      F->child[pos[v]] = up[v];
  }
  for (int v = 0; v < nv; v++)
    for (int k = 0; k < d; k++)
      F->col[up[v] * d + k] = cols[v * d + k];
  for (int b = 0; b < nb; b++) {
    F->bi[b] = up[F->bi[b]];
    F->bj[b] = F->bj[b] < 0 ? -1 : up[F->bj[b]];
  }
  for (int v = 0; v < nv; v++) {
    const int b = F->pe[v];
    F->par[v] = b < 0 ? -1 : F->bi[b] == v ? F->bj[b] : F->bi[b];
  }
  F->nv = nv;
  /* the incidences and children by node, the lone columns */
  F->inc_at = calloc((size_t)nv + 2, sizeof *F->inc_at);
  F->ch_at = calloc((size_t)nv + 2, sizeof *F->ch_at);
  F->inc = malloc(((size_t)2 * nb + 1) * sizeof *F->inc);
  F->ch = malloc(((size_t)nv + 1) * sizeof *F->ch);
  F->lone = malloc(((size_t)nf + 1) * sizeof *F->lone);
  if (!F->inc_at || !F->ch_at || !F->inc || !F->ch || !F->lone)
    goto out;
  for (int b = 0; b < nb; b++) {
    F->inc_at[F->bi[b] + 2]++;
    if (F->bj[b] >= 0)
      F->inc_at[F->bj[b] + 2]++;
  }
  for (int v = 0; v < nv; v++)
    if (F->par[v] >= 0)
      F->ch_at[F->par[v] + 2]++;
  for (int v = 0; v < nv; v++) {
    F->inc_at[v + 2] += F->inc_at[v + 1];
    F->ch_at[v + 2] += F->ch_at[v + 1];
  }
  for (int b = 0; b < nb; b++) {
    F->inc[F->inc_at[F->bi[b] + 1]++] = b;
    if (F->bj[b] >= 0)
      F->inc[F->inc_at[F->bj[b] + 1]++] = b;
  }
  for (int v = 0; v < nv; v++)
    if (F->par[v] >= 0)
      F->ch[F->ch_at[F->par[v] + 1]++] = v;
  for (int i = 0; i < nf; i++)
    if (colnode[i] < 0)
      F->lone[F->nlone++] = i;
  ok = 1;
out:
  free(ci);
  free(cj);
  free(colnode);
  free(cols);
  free(up);
  free(deg);
  free(adj);
  free(pos);
  free(queue);
  free(tree);
  if (!ok) {
    ocp_forest_free(F);
    return NULL;
  }
  return F;
}

/* A d x d matrix (row-major) inverted in place by Gauss-Jordan without
 * pivoting: 0 if every pivot is positive (a symmetric one is then
 * positive definite), else -1. */
ALWAYS_INLINE int spd_invert(double *a, const int d) {
  for (int k = 0; k < d; k++) {
    const double piv = a[k * d + k];
    if (!(piv > 0.0) || !isfinite(piv))
      return -1;
    const double ip = 1.0 / piv;
    a[k * d + k] = 1.0;
    for (int j = 0; j < d; j++)
      a[k * d + j] *= ip;
    for (int i = 0; i < d; i++) {
      if (i == k)
        continue;
      const double f = a[i * d + k];
      a[i * d + k] = 0.0;
      for (int j = 0; j < d; j++)
        a[i * d + j] -= f * a[k * d + j];
    }
  }
  return 0;
}

/* Whether B's matrix is F's: every point with w cA cB != 0 has its
 * blocks kept. */
static int forest_fits(const struct ocp_forest *F, const interval_op *B) {
  if (!F)
    return 0;
  for (int i = 0; i < B->np; i++)
    if (B->w[i] * B->cA[i] * B->cB[i] != 0.0 && !B->hb[i])
      return 0;
  return 1;
}

/* c S of block b (its packed upper triangle in hb, scaled) summed over
 * the np points (c[P], hb[P]) into A (d x d, row-major, overwritten). */
ALWAYS_INLINE void forest_block(int np, const double *c,
                                const double *const *hb, int b, double *A,
                                const int d) {
  const int lb = d * (d + 1) / 2;
  for (int e = 0; e < d * d; e++)
    A[e] = 0.0;
  for (int P = 0; P < np; P++) {
    const double *h = hb[P] + (size_t)b * lb;
    for (int r = 0, e = 0; r < d; r++)
      for (int s = r; s < d; s++, e++) {
        A[r * d + s] += c[P] * h[e];
        if (s != r)
          A[s * d + r] += c[P] * h[e];
      }
  }
}

/* forest_factor for dimension d: the nodes in order, each pulling its
 * children's updates (D_v = K_v + sum of the blocks on v - sum over its
 * children u of L_u A_uv), then D_v^-1 and L_v = A_pv D_v^-1 (A_pv = -c S
 * of the block to the parent). */
ALWAYS_INLINE int forest_factor_d(struct ocp_forest *F, const double *kf,
                                  int np, const double *c,
                                  const double *const *hb, const int d) {
  const int dd = d * d;
  for (int v = 0; v < F->nv; v++) {
    double *Dv = F->D + (size_t)v * dd, A[9], S[9];
    for (int e = 0; e < dd; e++)
      Dv[e] = 0.0;
    for (int k = 0; k < d; k++)
      Dv[k * d + k] = kf[F->col[v * d + k]];
    for (int e = F->inc_at[v]; e < F->inc_at[v + 1]; e++) {
      forest_block(np, c, hb, F->inc[e], S, d);
      for (int l = 0; l < dd; l++)
        Dv[l] += S[l];
    }
    for (int e = F->ch_at[v]; e < F->ch_at[v + 1]; e++) {
      const int u = F->ch[e];
      const double *Lu = F->L + (size_t)u * dd;
      forest_block(np, c, hb, F->pe[u], S, d); /* (A_uv = -S) */
      for (int r = 0; r < d; r++)
        for (int s = 0; s < d; s++) {
          double t = 0.0;
          for (int k = 0; k < d; k++)
            t += Lu[r * d + k] * S[s * d + k];
          Dv[r * d + s] += t;
        }
    }
    if (spd_invert(Dv, d) != 0)
      return -1;
    if (F->par[v] < 0)
      continue;
    double *Lv = F->L + (size_t)v * dd;
    forest_block(np, c, hb, F->pe[v], A, d);
    for (int r = 0; r < d; r++)
      for (int s = 0; s < d; s++) {
        double t = 0.0;
        for (int k = 0; k < d; k++)
          t -= A[r * d + k] * Dv[k * d + s];
        Lv[r * d + s] = t;
      }
  }
  return 0;
}

/* forest_factor_d in the plane with one point (c, its blocks' packed
 * upper triangles hb: s0 s1 s2 per block), written out: D_v^-1 as s0 s1
 * s2 in D's first three entries. */
static int forest_factor_2(struct ocp_forest *F, const double *kf, double c,
                           const double *hb) {
  const int *col = F->col, *inc = F->inc, *ch = F->ch, *pe = F->pe;
  for (int v = 0; v < F->nv; v++) {
    double a = kf[col[2 * v]], b = 0.0, d = kf[col[2 * v + 1]];
    double ha = 0.0, hbb = 0.0, hd = 0.0;
    for (int e = F->inc_at[v]; e < F->inc_at[v + 1]; e++) {
      const double *h = hb + 3 * inc[e];
      ha += h[0];
      hbb += h[1];
      hd += h[2];
    }
    a += c * ha;
    b += c * hbb;
    d += c * hd;
    for (int e = F->ch_at[v]; e < F->ch_at[v + 1]; e++) {
      const int u = ch[e];
      const double *Lu = F->L + 4 * (size_t)u, *h = hb + 3 * pe[u];
      const double s0 = c * h[0], s1 = c * h[1], s2 = c * h[2];
      a += Lu[0] * s0 + Lu[1] * s1;
      b += Lu[0] * s1 + Lu[1] * s2;
      d += Lu[2] * s1 + Lu[3] * s2;
    }
    const double det = a * d - b * b;
    if (!(a > 0.0) || !(det > 0.0) || !isfinite(det))
      return -1;
    const double id = 1.0 / det, i0 = d * id, i1 = -b * id, i2 = a * id;
    double *Dv = F->D + 4 * (size_t)v;
    Dv[0] = i0;
    Dv[1] = i1;
    Dv[2] = i2;
    if (F->par[v] < 0)
      continue;
    const double *h = hb + 3 * pe[v];
    const double s0 = c * h[0], s1 = c * h[1], s2 = c * h[2];
    double *Lv = F->L + 4 * (size_t)v;
    Lv[0] = -(s0 * i0 + s1 * i1);
    Lv[1] = -(s0 * i1 + s1 * i2);
    Lv[2] = -(s1 * i0 + s2 * i1);
    Lv[3] = -(s1 * i1 + s2 * i2);
  }
  return 0;
}

/* F's factors of B's matrix: 0, or -1 where a pivot block is not
 * positive definite (the CG takes the micro step). */
static int forest_factor(struct ocp_forest *F, const interval_op *B) {
  double c[2];
  const double *hb[2];
  int np = 0;
  for (int i = 0; i < B->np; i++) {
    c[np] = B->w[i] * B->cA[i] * B->cB[i];
    hb[np] = B->hb[i];
    np += c[np] != 0.0;
  }
  F->two = F->d == 2 && np == 1;
  if (F->two)
    return forest_factor_2(F, B->kf, c[0], hb[0]);
  switch (F->d) {
  case 1:
    return forest_factor_d(F, B->kf, np, c, hb, 1);
  case 2:
    return forest_factor_d(F, B->kf, np, c, hb, 2);
  default:
    return forest_factor_d(F, B->kf, np, c, hb, 3);
  }
}

/* forest_solve for dimension d: L z = b (children first, into b), then
 * x_v = D_v^-1 z_v - L_v^T x_p (parents first). */
ALWAYS_INLINE void forest_solve_d(const struct ocp_forest *F, int nfun, int nf,
                                  const double *dinv, double *r, double *x,
                                  long xs, const int d) {
  const int dd = d * d, nv = F->nv, *col = F->col, *par = F->par;
  for (int v = 0; v < nv; v++) {
    if (par[v] < 0)
      continue;
    const double *Lv = F->L + (size_t)v * dd;
    const int *cv = col + v * d, *cp = col + par[v] * d;
    for (int f = 0; f < nfun; f++) {
      double *b = r + (size_t)f * nf;
      for (int i = 0; i < d; i++) {
        double t = 0.0;
        for (int j = 0; j < d; j++)
          t += Lv[i * d + j] * b[cv[j]];
        b[cp[i]] -= t;
      }
    }
  }
  for (int v = nv - 1; v >= 0; v--) {
    const double *Dv = F->D + (size_t)v * dd, *Lv = F->L + (size_t)v * dd;
    const int *cv = col + v * d, *cp = par[v] < 0 ? cv : col + par[v] * d;
    for (int f = 0; f < nfun; f++) {
      const double *b = r + (size_t)f * nf;
      double *xf = x + (size_t)f * (size_t)xs;
      double t[3];
      for (int i = 0; i < d; i++) {
        t[i] = 0.0;
        for (int j = 0; j < d; j++)
          t[i] += Dv[i * d + j] * b[cv[j]];
      }
      if (par[v] >= 0)
        for (int i = 0; i < d; i++)
          for (int j = 0; j < d; j++)
            t[i] -= Lv[j * d + i] * xf[cp[j]];
      for (int i = 0; i < d; i++)
        xf[cv[i]] = t[i];
    }
  }
  for (int f = 0; f < nfun; f++)
    for (int l = 0; l < F->nlone; l++) {
      const int i = F->lone[l];
      x[(size_t)f * (size_t)xs + i] = dinv[i] * r[(size_t)f * nf + i];
    }
}

/* forest_solve_d after forest_factor_2, written out */
static void forest_solve_2(const struct ocp_forest *F, int nfun, int nf,
                           const double *dinv, double *r, double *x, long xs) {
  const int nv = F->nv, *col = F->col, *par = F->par;
  for (int v = 0; v < nv; v++) {
    if (par[v] < 0)
      continue;
    const double *Lv = F->L + 4 * (size_t)v;
    const int c0 = col[2 * v], c1 = col[2 * v + 1];
    const int p0 = col[2 * par[v]], p1 = col[2 * par[v] + 1];
    for (int f = 0; f < nfun; f++) {
      double *b = r + (size_t)f * nf;
      const double b0 = b[c0], b1 = b[c1];
      b[p0] -= Lv[0] * b0 + Lv[1] * b1;
      b[p1] -= Lv[2] * b0 + Lv[3] * b1;
    }
  }
  for (int v = nv - 1; v >= 0; v--) {
    const double *Dv = F->D + 4 * (size_t)v, *Lv = F->L + 4 * (size_t)v;
    const int c0 = col[2 * v], c1 = col[2 * v + 1];
    const int pv = par[v] < 0 ? v : par[v];
    const int p0 = col[2 * pv], p1 = col[2 * pv + 1];
    for (int f = 0; f < nfun; f++) {
      const double *b = r + (size_t)f * nf;
      double *xf = x + (size_t)f * (size_t)xs;
      double t0 = Dv[0] * b[c0] + Dv[1] * b[c1];
      double t1 = Dv[1] * b[c0] + Dv[2] * b[c1];
      if (par[v] >= 0) {
        t0 -= Lv[0] * xf[p0] + Lv[2] * xf[p1];
        t1 -= Lv[1] * xf[p0] + Lv[3] * xf[p1];
      }
      xf[c0] = t0;
      xf[c1] = t1;
    }
  }
  for (int f = 0; f < nfun; f++)
    for (int l = 0; l < F->nlone; l++) {
      const int i = F->lone[l];
      x[(size_t)f * (size_t)xs + i] = dinv[i] * r[(size_t)f * nf + i];
    }
}

/* x_f = (matrix of F's last factors)^-1 r_f for every functional (x_f =
 * x + f xs; r: nfun x nf, overwritten; dinv = 1/K on the columns outside
 * the forest). */
static void forest_solve(const struct ocp_forest *F, int nfun, int nf,
                         const double *dinv, double *r, double *x, long xs) {
  if (F->two) {
    forest_solve_2(F, nfun, nf, dinv, r, x, xs);
    return;
  }
  switch (F->d) {
  case 1:
    forest_solve_d(F, nfun, nf, dinv, r, x, xs, 1);
    break;
  case 2:
    forest_solve_d(F, nfun, nf, dinv, r, x, xs, 2);
    break;
  default:
    forest_solve_d(F, nfun, nf, dinv, r, x, xs, 3);
  }
}

/* The passes of interval_solve over a functional's nf entries, four at a
 * time in two pairs (util/simd.h; the sums' chains are what bounds the
 * passes, not the arithmetic), then the tail.  CG's start: x = 0, p =
 * D^-1 r, q = kf p (B p's mass part); returns r.p, *bn = ||r||_inf,
 * *pq = p.q. */
static double cg_start(int nf, const double *restrict dinv,
                       const double *restrict kf, const double *restrict r,
                       double *restrict x, double *restrict p,
                       double *restrict q, double *bn, double *pq) {
  mrvi_v2 s0 = v2_zero(), s1 = v2_zero(), m0 = v2_zero(), m1 = v2_zero();
  mrvi_v2 t0 = v2_zero(), t1 = v2_zero();
  int i = 0;
  for (; i + 4 <= nf; i += 4) {
    const mrvi_v2 r0 = v2_load(r + i), r1 = v2_load(r + i + 2);
    const mrvi_v2 p0 = v2_mul(v2_load(dinv + i), r0);
    const mrvi_v2 p1 = v2_mul(v2_load(dinv + i + 2), r1);
    v2_store(x + i, v2_zero());
    v2_store(x + i + 2, v2_zero());
    v2_store(p + i, p0);
    v2_store(p + i + 2, p1);
    const mrvi_v2 q0 = v2_mul(v2_load(kf + i), p0);
    const mrvi_v2 q1 = v2_mul(v2_load(kf + i + 2), p1);
    v2_store(q + i, q0);
    v2_store(q + i + 2, q1);
    s0 = v2_add(s0, v2_mul(r0, p0));
    s1 = v2_add(s1, v2_mul(r1, p1));
    t0 = v2_add(t0, v2_mul(p0, q0));
    t1 = v2_add(t1, v2_mul(p1, q1));
    m0 = v2_max(v2_abs(r0), m0);
    m1 = v2_max(v2_abs(r1), m1);
  }
  const mrvi_v2 s = v2_add(s0, s1), m = v2_max(m0, m1), t = v2_add(t0, t1);
  double rp = v2_lo(s) + v2_hi(s), mx = fmax(v2_lo(m), v2_hi(m));
  double pt = v2_lo(t) + v2_hi(t);
  for (; i < nf; i++) {
    x[i] = 0.0;
    p[i] = dinv[i] * r[i];
    q[i] = kf[i] * p[i];
    rp += r[i] * p[i];
    pt += p[i] * q[i];
    mx = fabs(r[i]) > mx ? fabs(r[i]) : mx;
  }
  *bn = mx;
  *pq = pt;
  return rp;
}

/* p.q */
static double cg_dot(int nf, const double *restrict p,
                     const double *restrict q) {
  mrvi_v2 s0 = v2_zero(), s1 = v2_zero();
  int i = 0;
  for (; i + 4 <= nf; i += 4) {
    s0 = v2_add(s0, v2_mul(v2_load(p + i), v2_load(q + i)));
    s1 = v2_add(s1, v2_mul(v2_load(p + i + 2), v2_load(q + i + 2)));
  }
  const mrvi_v2 s = v2_add(s0, s1);
  double d = v2_lo(s) + v2_hi(s);
  for (; i < nf; i++)
    d += p[i] * q[i];
  return d;
}

/* x += alpha p, r -= alpha q; returns r.D^-1 r, *rn = ||r||_inf. */
static double cg_update(int nf, double alpha, const double *restrict dinv,
                        const double *restrict p, const double *restrict q,
                        double *restrict x, double *restrict r, double *rn) {
  mrvi_v2 s0 = v2_zero(), s1 = v2_zero(), m0 = v2_zero(), m1 = v2_zero();
  int i = 0;
  for (; i + 4 <= nf; i += 4) {
    v2_store(x + i, v2_add(v2_load(x + i), v2_scale(alpha, v2_load(p + i))));
    v2_store(x + i + 2,
             v2_add(v2_load(x + i + 2), v2_scale(alpha, v2_load(p + i + 2))));
    const mrvi_v2 r0 = v2_sub(v2_load(r + i), v2_scale(alpha, v2_load(q + i)));
    const mrvi_v2 r1 =
        v2_sub(v2_load(r + i + 2), v2_scale(alpha, v2_load(q + i + 2)));
    v2_store(r + i, r0);
    v2_store(r + i + 2, r1);
    s0 = v2_add(s0, v2_mul(r0, v2_mul(v2_load(dinv + i), r0)));
    s1 = v2_add(s1, v2_mul(r1, v2_mul(v2_load(dinv + i + 2), r1)));
    m0 = v2_max(v2_abs(r0), m0);
    m1 = v2_max(v2_abs(r1), m1);
  }
  const mrvi_v2 s = v2_add(s0, s1), m = v2_max(m0, m1);
  double rz = v2_lo(s) + v2_hi(s), mx = fmax(v2_lo(m), v2_hi(m));
  for (; i < nf; i++) {
    x[i] += alpha * p[i];
    r[i] -= alpha * q[i];
    rz += r[i] * (dinv[i] * r[i]);
    mx = fabs(r[i]) > mx ? fabs(r[i]) : mx;
  }
  *rn = mx;
  return rz;
}

/* p = D^-1 r + beta p, q = kf p; returns p.q. */
static double cg_direction(int nf, double beta, const double *restrict dinv,
                           const double *restrict kf, const double *restrict r,
                           double *restrict p, double *restrict q) {
  mrvi_v2 t0 = v2_zero(), t1 = v2_zero();
  int i = 0;
  for (; i + 4 <= nf; i += 4) {
    const mrvi_v2 p0 = v2_add(v2_mul(v2_load(dinv + i), v2_load(r + i)),
                              v2_scale(beta, v2_load(p + i)));
    const mrvi_v2 p1 = v2_add(v2_mul(v2_load(dinv + i + 2), v2_load(r + i + 2)),
                              v2_scale(beta, v2_load(p + i + 2)));
    const mrvi_v2 q0 = v2_mul(v2_load(kf + i), p0);
    const mrvi_v2 q1 = v2_mul(v2_load(kf + i + 2), p1);
    v2_store(p + i, p0);
    v2_store(p + i + 2, p1);
    v2_store(q + i, q0);
    v2_store(q + i + 2, q1);
    t0 = v2_add(t0, v2_mul(p0, q0));
    t1 = v2_add(t1, v2_mul(p1, q1));
  }
  const mrvi_v2 t = v2_add(t0, t1);
  double pt = v2_lo(t) + v2_hi(t);
  for (; i < nf; i++) {
    p[i] = dinv[i] * r[i] + beta * p[i];
    q[i] = kf[i] * p[i];
    pt += p[i] * q[i];
  }
  return pt;
}

/* B x_f = r_f for every functional (x_f = x + f xs; r: nfun x nf, the
 * right-hand sides, overwritten) by Jacobi-preconditioned CG (dinv =
 * dt/M^f, the inverse of B's mass part kf) run for all of them in step,
 * one product of B with all their directions per iteration; each stops at
 * ||r_f||_inf <= rtol ||b_f||_inf (bnorm[f] instead of ||b_f||_inf where
 * bnorm is given).  The curvature p.Bp is p.kf p, summed where the
 * direction is formed, plus the Hessians' p^T H p, summed by the product
 * where every point's blocks are kept (else by a pass over Bp).  p and q:
 * nfun x nf each, then 5 nfun scalars after q.  MRVI_CG_OK, _CURVATURE
 * or _MAXIT (*its: products).  (A NaN or infinity in r poisons the sums
 * r.D^-1 r, which are checked.) */
static int interval_solve(const mrvi_ocp *o, const interval_op *B, int nfun,
                          const double *dinv, double *r, double *x, long xs,
                          double *p, double *q, double rtol,
                          const double *bnorm, int *its) {
  const int nf = o->nf;
  double *rz = q + (size_t)nfun * nf, *stop = rz + nfun, *done = stop + nfun;
  double *pkp = done + nfun, *php = pkp + nfun;
  int left = nfun, kept = 1;
  for (int i = 0; i < B->np; i++)
    kept = kept && (B->hb[i] || B->w[i] * B->cA[i] * B->cB[i] == 0.0);
  *its = 0;
  for (int f = 0; f < nfun; f++) {
    const size_t of = (size_t)f * nf;
    double bn;
    rz[f] = cg_start(nf, dinv, B->kf, r + of, x + (size_t)f * (size_t)xs,
                     p + of, q + of, &bn, &pkp[f]);
    if (!isfinite(rz[f]))
      return MRVI_CG_MAXIT;
    stop[f] = rtol * (bnorm ? bnorm[f] : bn);
    done[f] = !(bn > stop[f]);
    left -= done[f] != 0.0;
  }
  for (*its = 0; left > 0 && *its < MRVI_CG_MAX_IT; ++*its) {
    for (int f = 0; f < nfun; f++)
      php[f] = 0.0;
    for (int i = 0; i < B->np; i++)
      point_product(o, B, i, nfun, p, nf, q, nf, B->w[i] * B->cA[i] * B->cB[i],
                    kept ? php : NULL);
    for (int f = 0; f < nfun; f++) {
      if (done[f] != 0.0)
        continue;
      const size_t of = (size_t)f * nf;
      const double pq = kept ? pkp[f] + php[f] : cg_dot(nf, p + of, q + of);
      if (!(pq > 0.0))
        return MRVI_CG_CURVATURE;
      const double alpha = rz[f] / pq;
      double rn;
      const double rz1 = cg_update(nf, alpha, dinv, p + of, q + of,
                                   x + (size_t)f * (size_t)xs, r + of, &rn);
      if (!isfinite(rz1))
        return MRVI_CG_MAXIT;
      if (rn <= stop[f]) {
        done[f] = 1.0;
        left--;
        continue;
      }
      const double beta = rz1 / rz[f];
      rz[f] = rz1;
      pkp[f] = cg_direction(nf, beta, dinv, B->kf, r + of, p + of, q + of);
    }
  }
  return left == 0 ? MRVI_CG_OK : MRVI_CG_MAXIT;
}

/* R at fast node g (global) += sum over the points P of interval g (B) of
 * w cA hess W(z_P) (cA mu_g + cB mu_{g+1}): that interval's part of row g
 * (v: the workspace's vW); nothing where one (sweep_adjoint keeps it in
 * hy). */
static void interval_row_a(mrvi_ocp *o, const interval_op *B, int one, int nfun,
                           long g, double *gQ, double *v) {
  const int nf = o->nf;
  const long nn = o->n_nodes, at = (o->N + 1) * o->ns + g * nf;
  if (one)
    return;
  for (int i = 0; i < B->np; i++) {
    if (B->cA[i] == 0.0)
      continue;
    for (int f = 0; f < nfun; f++) {
      const double *mu = o->mu + (size_t)f * (size_t)nn + at;
      for (int l = 0; l < nf; l++)
        v[(size_t)f * nf + l] = B->cA[i] * mu[l] + B->cB[i] * mu[nf + l];
    }
    point_product(o, B, i, nfun, v, nf, gQ + at, nn, B->w[i] * B->cA[i], NULL);
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
 * products at the interval's points, to tuning.adjoint_krylov_rtol.  W's
 * Hessian blocks at a point inside interval g - 1 are formed once
 * (mrvi_terms_hessblocks) for the interval's products.
 *
 * With one point P inside the interval (the midpoint: explicit-slow), H =
 * hess W(z_P), K = M^f/dt and c = w cA cB, the unknown y = mu_{g-1} +
 * (cB/cA) mu_g = (cA mu_{g-1} + cB mu_g)/cA takes every product but the
 * CG's: its system
 *   (K + c H) y = K (2 mu_g - mu_{g+1} + (cB/cA) mu_g) - R'_g
 * (R'_g: R_g without interval g - 1's w cB^2 H mu_g, which (K + c H)
 * (cB/cA) mu_g supplies) has no product on its right, and that interval's
 * part of row g - 1, w cA H (cA mu_{g-1} + cB mu_g) = w cA^2 H y, is
 * (cA/cB) (b - r - K y) from the CG's right-hand side b and last residual
 * r (B y = b - r), without a product either.  The CG stops at rtol times
 * ||K (2 mu_g - mu_{g+1}) - R'_g||_inf, the right-hand side of mu_{g-1}'s
 * system but for c H mu_g (relatively O(c ||H|| / K), below 1e-1 where
 * the forward's chord contracts). */
static int sweep_adjoint(mrvi_ocp *o, int nfun, double *gQ) {
  const int ns = o->ns, nf = o->nf, p = o->p, nsf = ns + nf;
  const long N = o->N, nn = o->n_nodes, F0 = (N + 1) * ns;
  double *cs = o->adj_work + (size_t)nfun * 2 * nsf + nsf, *ks = cs + ns;
  double *cf = ks + ns, *kf = cf + nf, *ww = kf + nf;
  double *zW = ww + p + 1, *vW = zW + 2 * (size_t)nf;
  double *c = vW + (size_t)nfun * nf, *cp = c + (size_t)nfun * nf;
  double *cq = cp + (size_t)nfun * nf, *hy = cq + (size_t)nfun * nf + 5 * nfun;
  double *bnorm = hy + (size_t)nfun * nf, *hbW = o->adj_blocks;
  const long nhb = o->adj_hb;
  double wV[2];
  coefficients(o, cs, wV);
  const double rtol = o->settings.tuning.adjoint_krylov_rtol;
  interval_op B = {.kf = kf};
  int one = 0;  /* (B: one point inside) */
  int pend = 0; /* (hy: a part of the next row read, not in gQ) */
  v_add(o, nfun, N, wV[1], gQ);
  for (long k = N - 1; k >= 0; k--) {
    const long s0 = k * ns, s1 = s0 + ns, fk = F0 + k * p * nf;
    for (int f = 0; f < nfun; f++) {
      double *mu = o->mu + (size_t)f * (size_t)nn;
      double *r = gQ + (size_t)f * (size_t)nn;
      for (int i = 0; i < ns; i++)
        mu[s0 + i] = mu[s1 + i] - cs[i] * r[s1 + i];
    }
    for (int j = p; j >= 1; j--) {
      const long fj = fk + (long)j * nf, g = k * p + j;
      if (j < p) /* (B: interval j, solved last) */
        interval_row_a(o, &B, one, nfun, g, gQ, vW);
      /* Interval j - 1: its points' mu_g part of row g, and B. */
      interval_setup(o, &B, fk, j - 1, zW, nhb > 0 ? hbW : NULL, nhb);
      one = o->adj_one && B.np == 1 && B.cA[0] != 0.0 && B.cB[0] != 0.0;
      const double ry = one ? B.cB[0] / B.cA[0] : 0.0;
      for (int i = 0; !one && i < B.np; i++)
        point_product(o, &B, i, nfun, o->mu + fj, nn, gQ + fj, nn,
                      B.w[i] * B.cB[i] * B.cB[i], NULL);
      for (int f = 0; f < nfun; f++) {
        const double *mu = o->mu + (size_t)f * (size_t)nn;
        double *r = gQ + (size_t)f * (size_t)nn;
        double *cf_ = c + (size_t)f * nf, bn = 0.0;
        double *h = hy + (size_t)f * nf;
        for (int i = 0; i < nf; i++) {
          const double m = mu[fj + i], R = r[fj + i] + (pend ? h[i] : 0.0);
          const double b = kf[i] * (j < p ? 2.0 * m - mu[fj + nf + i] : m) - R;
          cf_[i] = one ? b + kf[i] * (ry * m) : b;
          if (one)
            h[i] = cf_[i];
          bn = fabs(b) > bn ? fabs(b) : bn;
        }
        bnorm[f] = bn;
      }
      pend = 0;
      int its = 0, s = MRVI_CG_OK;
      double *x = o->mu + fj - nf;
      const int direct = forest_fits(o->adj_forest, &B) &&
                         forest_factor(o->adj_forest, &B) == 0;
      if (direct) {
        forest_solve(o->adj_forest, nfun, nf, cf, c, x, nn);
        o->adjoint_forest_solves++;
      } else {
        s = interval_solve(o, &B, nfun, cf, c, x, nn, cp, cq, rtol,
                           one ? bnorm : NULL, &its);
        o->adjoint_cg_solves++;
        o->adjoint_cg_products += its;
      }
      if (s != MRVI_CG_OK)
        return mrvi_ocp_fail(o, MRVI_ESINGULAR,
                             "adjoint of micro step %ld: CG %s after %d "
                             "iterations",
                             g,
                             s == MRVI_CG_CURVATURE
                                 ? "met non-positive curvature"
                                 : "did not converge",
                             its);
      /* y: the interval's part of row g - 1 into hy (b there), pending
       * till that row is read (it is not in the cache yet), and mu_{g-1}
       * from y */
      for (int f = 0; one && f < nfun; f++) {
        double *xf = x + (size_t)f * (size_t)nn, *h = hy + (size_t)f * nf;
        const double *rf = c + (size_t)f * nf, *mg = xf + nf;
        for (int i = 0; i < nf; i++) {
          h[i] = (1.0 / ry) * (h[i] - (direct ? 0.0 : rf[i]) - kf[i] * xf[i]);
          xf[i] -= ry * mg[i];
        }
      }
      pend = one;
    }
    if (k == 0)
      break;
    kinetic_off(o, nfun, k, ks, kf, gQ);
    v_add(o, nfun, k, wV[0] + wV[1], gQ);
    interval_row_a(o, &B, one, nfun, k * p, gQ, vW); /* (B: interval 0) */
  }
  return MRVI_OK;
}

int ocp_explicit_adjoint(mrvi_ocp *o, int nfun, double *gQ) {
  if (w_inside(o))
    return sweep_adjoint(o, nfun, gQ);
  node_adjoint(o, nfun, gQ);
  return MRVI_OK;
}
