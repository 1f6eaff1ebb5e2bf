/* Pair-force actuators: equal and opposite forces of magnitude u along the
 * line between particles i and j (u > 0 pushes them apart), derivation in
 * doc/optimal-control.md.
 *
 * With u frozen the force is conservative, F = u grad r, r = |x_i - x_j|,
 * so its virtual work along the interpolated path is u delta int r dt.  On
 * every micro interval m of a step (length dt, control u_m: u_k for a
 * macro-grid actuator) the integral is taken by the midpoint rule at
 * t_k + (m + 1/2) dt, where every coordinate is interpolated on its own
 * grid (slow: weights 1 - theta, theta with theta = (m + 1/2)/p; fast: 1/2,
 * 1/2 between nodes m and m + 1):
 *   f_z = dt u_m d r(y_m(z)) / dz,   y_m(z) the interpolated positions.
 * For a force of constant direction this is exactly the rule of the
 * coordinate actuators (ocp.c); here f depends on the nodes, so the step
 * residual gets its derivatives (through the step hook), and so do the
 * adjoint's step Jacobians and the control gradient.  The discrete forcing
 * is a function of the relative position only and invariant under
 * rotations, so the pair's internal forces keep the total linear and
 * angular momentum of the discrete flow. */
#include "ocp/ocp_internal.h"

#include <math.h>

/* Inputs of a pair actuator at one point: 2 d coordinates (particle i,
 * then j), their two step nodes with coefficients, sign (+1 i, -1 j) and
 * component; unit vector e = (y_i - y_j)/r and P = (I - e e^T)/r. */
typedef struct pair_point {
  int n, d;
  int z[6][2];
  double c[6][2], sgn[6];
  int comp[6];
  double e[3], r, P[9];
} pair_point;

/* Midpoint of micro interval m (weight dt). */
static mrvi_point mid_point(const mrvi_ocp *o, int m) {
  const double th = (m + 0.5) / o->p;
  return (mrvi_point){.w = o->settings.macro_step / o->p,
                      .a0 = 1.0 - th,
                      .a1 = th,
                      .cA = 0.5,
                      .cB = 0.5,
                      .m = m};
}

static void pair_nodes(const mrvi_ocp *o, const ocp_actuator *A,
                       const mrvi_point *pt, pair_point *pp) {
  const mrvi_model *m = o->model;
  pp->d = m->dimension;
  pp->n = 2 * pp->d;
  for (int k = 0; k < pp->n; k++) {
    const int part = k < pp->d ? A->pi : A->pj, comp = k % pp->d;
    ocp_znodes(o, m->particles[part].first + comp, pt, pp->z[k], pp->c[k]);
    pp->sgn[k] = k < pp->d ? 1.0 : -1.0;
    pp->comp[k] = comp;
  }
}

/* e, r, P from the interpolated positions y (n entries). */
static void pair_geometry(pair_point *pp, const double *y) {
  const int d = pp->d;
  double r2 = 0.0;
  for (int a = 0; a < d; a++) {
    pp->e[a] = y[a] - y[d + a];
    r2 += pp->e[a] * pp->e[a];
  }
  pp->r = sqrt(r2);
  /* Coincident particles: no direction, no force (documented). */
  const double inv = pp->r > 0.0 ? 1.0 / pp->r : 0.0;
  for (int a = 0; a < d; a++)
    pp->e[a] *= inv;
  for (int a = 0; a < d; a++)
    for (int b = 0; b < d; b++)
      pp->P[a * d + b] = ((a == b) - pp->e[a] * pp->e[b]) * inv;
}

/* Control index of actuator A in step k, micro interval m. */
static int control(const mrvi_ocp *o, const ocp_actuator *A, long k, int m) {
  return A->grid == MRVI_GRID_MACRO ? A->offset + (int)k
                                    : A->offset + (int)(k * o->p) + m;
}

/* Residual row of step node z (-1: an end node, no row) and unknown column
 * (-1: a known start node); value of z at the step unknowns x. */
static int zrow(const mrvi_ocp *o, int z) {
  if (z < o->ns)
    return z;
  if (z < 2 * o->ns)
    return -1;
  return z - 2 * o->ns < o->p * o->nf ? z - o->ns : -1;
}
static int zcol(const mrvi_ocp *o, int z) {
  if (z < o->ns)
    return -1;
  if (z < 2 * o->ns)
    return z - o->ns;
  return z - 2 * o->ns < o->nf ? -1 : z - o->ns - o->nf;
}
static double zval(const mrvi_ocp *o, const mrvi_step *st, const double *x,
                   int z) {
  if (z < o->ns)
    return st->qs0[z];
  const int c = zcol(o, z);
  return c >= 0 ? x[c] : st->qf0[z - 2 * o->ns];
}

/* Visitor of one (pair actuator A, micro interval m) of step k with its
 * geometry pp, weight w = dt and control value. */
typedef void pair_visit(const mrvi_ocp *o, void *ctx, long k,
                        const pair_point *pp, double w, int control);

/* Visit every pair actuator and micro interval of step k, the geometry at
 * the step unknowns x (with st's known nodes) or, x = NULL, at the stored
 * trajectory. */
static void each_pair(const mrvi_ocp *o, const mrvi_step *st, const double *x,
                      long k, pair_visit *fn, void *ctx) {
  for (int ia = 0; ia < o->n_act; ia++) {
    const ocp_actuator *A = &o->act[ia];
    if (A->pi < 0)
      continue;
    for (int m = 0; m < o->p; m++) {
      const mrvi_point pt = mid_point(o, m);
      pair_point pp;
      double y[6];
      pair_nodes(o, A, &pt, &pp);
      for (int i = 0; i < pp.n; i++)
        for (int a = 0; a < 2; a++) {
          const int z = pp.z[i][a];
          const double v = x ? zval(o, st, x, z) : o->Q[ocp_global(o, k, z)];
          y[i] = a ? y[i] + pp.c[i][a] * v : pp.c[i][a] * v;
        }
      pair_geometry(&pp, y);
      fn(o, ctx, k, &pp, pt.w, control(o, A, k, m));
    }
  }
}

typedef struct hook_ctx {
  mrvi_step *st;
  double *R;
  int jac;
} hook_ctx;

/* f^- on the residual rows (both nodes of an input that are rows) and its
 * derivatives in the unknown columns. */
static void hook_visit(const mrvi_ocp *o, void *ctx, long k,
                       const pair_point *pp, double w, int ic) {
  hook_ctx *h = ctx;
  (void)k;
  const double wu = w * o->u_cur[ic];
  for (int i = 0; i < pp->n; i++)
    for (int a = 0; a < 2; a++) {
      const int row = zrow(o, pp->z[i][a]);
      if (row < 0)
        continue;
      const double ci = wu * pp->c[i][a] * pp->sgn[i];
      h->R[row] += ci * pp->e[pp->comp[i]];
      if (!h->jac)
        continue;
      /* Same calls on every pass (the pattern): no value tests. */
      for (int j = 0; j < pp->n; j++)
        for (int b = 0; b < 2; b++) {
          const int col = zcol(o, pp->z[j][b]);
          if (col >= 0)
            mrvi_step_jac_add(h->st, row, col,
                              ci * pp->c[j][b] * pp->sgn[j] *
                                  pp->P[pp->comp[i] * pp->d + pp->comp[j]]);
        }
    }
}

void ocp_pair_hook(void *ctx, mrvi_step *st, const double *x, double *R,
                   int jac) {
  const mrvi_ocp *o = ctx;
  hook_ctx h = {st, R, jac};
  each_pair(o, st, x, o->k_cur, hook_visit, &h);
}

/* f^+: the later node of each input (q_{k+1}^s, fast node m + 1). */
static void end_visit(const mrvi_ocp *o, void *ctx, long k,
                      const pair_point *pp, double w, int ic) {
  mrvi_ocp *ow = ctx;
  const int ns = o->ns, nf = o->nf;
  const double wu = w * o->u_cur[ic];
  (void)k;
  for (int i = 0; i < pp->n; i++) {
    const int z = pp->z[i][1];
    const double f = wu * pp->c[i][1] * pp->sgn[i] * pp->e[pp->comp[i]];
    if (z < 2 * ns) {
      ow->f_end[z - ns] += f;
    } else {
      const int zf = z - 2 * ns, mm = zf / nf, s = zf % nf;
      ow->f_plus[(mm - 1) * nf + s] += f;
      if (mm == o->p)
        ow->f_end[ns + s] += f;
    }
  }
}

void ocp_pair_end_forces(mrvi_ocp *o, long k, const double *u) {
  o->u_cur = u;
  each_pair(o, &o->step, o->x, k, end_visit, o);
}

static void jacobian_visit(const mrvi_ocp *o, void *ctx, long k,
                           const pair_point *pp, double w, int ic) {
  double *J = ctx;
  const int nv = o->nv;
  const double wu = w * o->u_cur[ic];
  (void)k;
  for (int i = 0; i < pp->n; i++)
    for (int a = 0; a < 2; a++)
      for (int j = 0; j < pp->n; j++)
        for (int b = 0; b < 2; b++)
          J[pp->z[i][a] * nv + pp->z[j][b]] +=
              wu * pp->c[i][a] * pp->sgn[i] * pp->c[j][b] * pp->sgn[j] *
              pp->P[pp->comp[i] * pp->d + pp->comp[j]];
}

void ocp_pair_jacobian(const mrvi_ocp *o, long k, double *J) {
  each_pair(o, NULL, NULL, k, jacobian_visit, J);
}

typedef struct gradient_ctx {
  const double *mu;
  double *out;
} gradient_ctx;

static void gradient_visit(const mrvi_ocp *o, void *ctx, long k,
                           const pair_point *pp, double w, int ic) {
  gradient_ctx *g = ctx;
  double sum = 0.0;
  for (int i = 0; i < pp->n; i++)
    for (int a = 0; a < 2; a++)
      sum += g->mu[ocp_global(o, k, pp->z[i][a])] * w * pp->c[i][a] *
             pp->sgn[i] * pp->e[pp->comp[i]];
  g->out[ic] -= sum;
}

void ocp_pair_gradient(const mrvi_ocp *o, long k, const double *mu,
                       double *out) {
  gradient_ctx g = {mu, out};
  each_pair(o, NULL, NULL, k, gradient_visit, &g);
}
