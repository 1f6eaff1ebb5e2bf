/* State-dependent actuators (doc/optimal-control.md, "Pair forces" and
 * "Bodies"): forces whose direction depends on the configuration.  Each
 * actuator has model input coordinates y and a generalised force per unit
 * control F(y) with its derivative dF/dy:
 *   pair      equal and opposite forces along the line between particles
 *             i and j: F = +-e, e = (y_i - y_j)/r, dF/dy = +-(I - e e^T)/r
 *             (u > 0 pushes them apart; with u frozen F = grad r);
 *   torque    on a body's directors, F_{d_i} = 1/2 tau x d_i with tau fixed
 *             in space or in a body (2-D: 1/2 tau J d_i), whose virtual work
 *             on d_i' = w x d_i is tau . w;
 *   force     at a body point x = phi + sum rho^i d_i: F_phi = e,
 *             F_{d_i} = rho^i e (constant);
 *   joint     a revolute joint's motor torque: +u about the hinge on the
 *             second body, -u on the first (two torque terms).
 * On every micro interval m of a step (length dt, control u_m: u_k for a
 * macro-grid actuator) the virtual work along the interpolated path is
 * taken by the midpoint rule at t_k + (m + 1/2) dt, every coordinate
 * interpolated on its own grid (slow: weights 1 - theta, theta with
 * theta = (m + 1/2)/p; fast: 1/2, 1/2 between nodes m and m + 1):
 *   f_z = dt u_m c_z F(y_m),   df_z/dz' = dt u_m c_z c_z' dF/dy(y_m).
 * For a force of constant direction this is exactly the rule of the
 * coordinate actuators (ocp.c); here f depends on the nodes, so the step
 * residual gets it and its derivatives (through the step hook), and so do
 * the adjoint's step Jacobians and the control gradient. */
#include "ocp/ocp_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Inputs of a state-dependent actuator at one point: n model coordinates,
 * the two step nodes of each with coefficients; the force per unit
 * control F (n) and its derivative Dm[a n + b] = dF_a/dy_b at the
 * interpolated inputs y. */
typedef struct act_point {
  int n;
  int z[OCP_MAX_IN][2];
  double c[OCP_MAX_IN][2];
  double F[OCP_MAX_IN], Dm[OCP_MAX_IN * OCP_MAX_IN];
} act_point;

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

static void act_nodes(const mrvi_ocp *o, const ocp_actuator *A,
                      const mrvi_point *pt, act_point *ap) {
  ap->n = A->n_in;
  for (int k = 0; k < ap->n; k++)
    ocp_znodes(o, A->in[k], pt, ap->z[k], ap->c[k]);
}

/* Pair: inputs x_i then x_j (d each); F = +-e, Dm = +-P with
 * e = (y_i - y_j)/r and P = (I - e e^T)/r. */
static void pair_force(int d, const double *y, act_point *ap) {
  double e[3], r2 = 0.0;
  for (int a = 0; a < d; a++) {
    e[a] = y[a] - y[d + a];
    r2 += e[a] * e[a];
  }
  const double r = sqrt(r2);
  /* Coincident particles: no direction, no force (documented). */
  const double inv = r > 0.0 ? 1.0 / r : 0.0;
  for (int a = 0; a < d; a++)
    e[a] *= inv;
  const int n = 2 * d;
  for (int k = 0; k < n; k++) {
    const double sk = k < d ? 1.0 : -1.0;
    ap->F[k] = sk * e[k % d];
    for (int l = 0; l < n; l++) {
      const double sl = l < d ? 1.0 : -1.0;
      const int a = k % d, b = l % d;
      ap->Dm[k * n + l] = sk * sl * ((a == b) - e[a] * e[b]) * inv;
    }
  }
}

/* Torque term of an actuator on the directors of body block X (inputs
 * xo.., D^2 of them): f_{d_i} = 1/2 a x d_i (3-D), 1/2 a J d_i (2-D, J the
 * rotation by +90 degrees, a = the scalar torque), with a = s axis (space)
 * or a = s sum_j t^j d_Y^j (axis fixed in body block Y at inputs yo).
 * Its virtual work on d_i' = w x d_i is a . w (doc/optimal-control.md).
 * Added: the forces to F (if not NULL) and sc times their derivative
 * (n x n, linear in s axis) to Dm (if not NULL). */
static inline __attribute__((always_inline)) void
torque_force(int D, int n, const ocp_torque *T, const double *y, double *F,
             double sc, double *Dm) {
  const int xo = T->x_off;
  double a[3] = {T->s * T->axis[0], T->s * T->axis[1], T->s * T->axis[2]};
  if (D == 3 && T->y_off >= 0)
    for (int c = 0; c < 3; c++) {
      a[c] = 0.0;
      for (int j = 0; j < 3; j++)
        a[c] += T->s * T->axis[j] * y[T->y_off + 3 * j + c];
    }
  for (int i = 0; i < D; i++) {
    const double *d = y + xo + D * i;
    const int r = xo + D * i;
    if (D == 2) {
      const double h = 0.5 * T->s * T->axis[2];
      if (F) {
        F[r] += -h * d[1];
        F[r + 1] += h * d[0];
      }
      if (Dm) {
        Dm[r * n + r + 1] += sc * -h;
        Dm[(r + 1) * n + r] += sc * h;
      }
      continue;
    }
    if (F) {
      F[r] += 0.5 * (a[1] * d[2] - a[2] * d[1]);
      F[r + 1] += 0.5 * (a[2] * d[0] - a[0] * d[2]);
      F[r + 2] += 0.5 * (a[0] * d[1] - a[1] * d[0]);
    }
    if (!Dm)
      continue;
    /* d(a x d)/dd = [a]x */
    const double ax[9] = {0, -a[2], a[1], a[2], 0, -a[0], -a[1], a[0], 0};
    for (int p = 0; p < 3; p++)
      for (int q = 0; q < 3; q++)
        Dm[(r + p) * n + r + q] += sc * (0.5 * ax[p * 3 + q]);
    if (T->y_off < 0)
      continue;
    /* d(a x d)/da = -[d]x, da/dd_Y^j = s t^j I */
    const double dx[9] = {0, -d[2], d[1], d[2], 0, -d[0], -d[1], d[0], 0};
    for (int j = 0; j < 3; j++)
      for (int p = 0; p < 3; p++)
        for (int q = 0; q < 3; q++)
          Dm[(r + p) * n + T->y_off + 3 * j + q] +=
              sc * (-0.5 * T->s * T->axis[j] * dx[p * 3 + q]);
  }
}

/* F of actuator A at the interpolated inputs y into F (n), and sc dF/dy
 * added to Dm (n x n; NULL: F only). */
static inline __attribute__((always_inline)) void
act_force_scaled(const mrvi_ocp *o, const ocp_actuator *A, const double *y,
                 double *F, double sc, double *Dm) {
  const int D = o->model->dimension, n = A->n_in;
  if (A->pi >= 0) {
    act_point ap;
    ap.n = n;
    pair_force(D, y, &ap);
    memcpy(F, ap.F, (size_t)n * sizeof *F);
    for (int e = 0; Dm && e < n * n; e++)
      Dm[e] += sc * ap.Dm[e];
    return;
  }
  memset(F, 0, (size_t)n * sizeof *F);
  if (A->n_torque == 0) {
    /* Body force at a body point: x = phi + sum rho^i d_i, direction e
     * fixed in space: F_phi = e, F_{d_i} = rho^i e (constant). */
    for (int k = 0; k < n; k++)
      F[k] = (k < D ? 1.0 : A->at[k / D - 1]) * A->dir[k % D];
    return;
  }
  for (int t = 0; t < A->n_torque; t++)
    torque_force(D, n, &A->torque[t], y, F, sc, Dm);
}

/* F and Dm of actuator A at the interpolated inputs y. */
static void act_force(const mrvi_ocp *o, const ocp_actuator *A, const double *y,
                      act_point *ap) {
  const int n = ap->n;
  if (A->pi >= 0) {
    pair_force(o->model->dimension, y, ap);
    return;
  }
  memset(ap->Dm, 0, (size_t)n * (size_t)n * sizeof *ap->Dm);
  act_force_scaled(o, A, y, ap->F, 1.0, ap->Dm);
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
  return z - 2 * o->ns < (long)o->p * o->nf ? z - o->ns : -1;
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
  if (c < 0)
    return st->qf0[z - 2 * o->ns];
  if (!st->increments)
    return x[c];
  /* (the integrator's Newton paths: displacements from q_k^s, q_k^{f,0}) */
  return (z < 2 * o->ns ? st->qs0[z - o->ns]
                        : st->qf0[(z - 2 * o->ns) % o->nf]) +
         x[c];
}

/* Visitor of one (state-dependent actuator, micro interval m) of step k
 * with its forces ap, weight w = dt and control index. */
typedef void act_visit(const mrvi_ocp *o, void *ctx, long k,
                       const act_point *ap, double w, int control);

/* Visit every state-dependent actuator and micro interval of step k, the
 * forces at the step unknowns x (with st's known nodes); at the stored
 * trajectory: ocp_state_jacobian. */
static void each_act(const mrvi_ocp *o, const mrvi_step *st, const double *x,
                     long k, act_visit *fn, void *ctx) {
  for (int ia = 0; ia < o->n_act; ia++) {
    const ocp_actuator *A = &o->act[ia];
    if (A->n_in == 0)
      continue;
    for (int m = 0; m < o->p; m++) {
      const mrvi_point pt = mid_point(o, m);
      act_point ap;
      double y[OCP_MAX_IN];
      act_nodes(o, A, &pt, &ap);
      for (int i = 0; i < ap.n; i++)
        for (int a = 0; a < 2; a++) {
          const int z = ap.z[i][a];
          const double v = zval(o, st, x, z);
          y[i] = a ? y[i] + ap.c[i][a] * v : ap.c[i][a] * v;
        }
      act_force(o, A, y, &ap);
      fn(o, ctx, k, &ap, pt.w, control(o, A, k, m));
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
                       const act_point *ap, double w, int ic) {
  hook_ctx *h = ctx;
  (void)k;
  const double wu = w * o->u_cur[ic];
  for (int i = 0; i < ap->n; i++)
    for (int a = 0; a < 2; a++) {
      const int row = zrow(o, ap->z[i][a]);
      if (row < 0)
        continue;
      const double ci = wu * ap->c[i][a];
      h->R[row] += ci * ap->F[i];
      if (!h->jac)
        continue;
      /* Same calls on every pass (the pattern): no value tests. */
      for (int j = 0; j < ap->n; j++)
        for (int b = 0; b < 2; b++) {
          const int col = zcol(o, ap->z[j][b]);
          if (col >= 0)
            mrvi_step_jac_add(h->st, row, col,
                              ci * ap->c[j][b] * ap->Dm[i * ap->n + j]);
        }
    }
}

void ocp_state_hook(void *ctx, mrvi_step *st, const double *x, double *R,
                    int jac) {
  const mrvi_ocp *o = ctx;
  hook_ctx h = {st, R, jac};
  each_act(o, st, x, o->k_cur, hook_visit, &h);
}

/* f^+: the later node of each input (q_{k+1}^s, fast node m + 1). */
static void end_visit(const mrvi_ocp *o, void *ctx, long k, const act_point *ap,
                      double w, int ic) {
  mrvi_ocp *ow = ctx;
  const int ns = o->ns, nf = o->nf;
  const double wu = w * o->u_cur[ic];
  (void)k;
  for (int i = 0; i < ap->n; i++) {
    const int z = ap->z[i][1];
    const double f = wu * ap->c[i][1] * ap->F[i];
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

void ocp_state_end_forces(mrvi_ocp *o, long k, const double *u) {
  o->u_cur = u;
  each_act(o, &o->step, o->x, k, end_visit, o);
}

void ocp_state_end_hook(void *ctx, mrvi_step *st, const double *x) {
  mrvi_ocp *o = ctx;
  memcpy(o->f_end, o->f_end_c, (size_t)(o->ns + o->nf) * sizeof *o->f_end);
  memcpy(o->f_plus, o->f_plus_c,
         (size_t)o->p * (size_t)o->nf * sizeof *o->f_plus);
  each_act(o, st, x, o->k_cur, end_visit, o);
}

/* One point's forces per unit control as the adjoint's Jacobian pass
 * evaluated them, kept for its control gradient (ocp_state_gradient): the
 * nodes and coefficients of the inputs, F, the weight and the control. */
struct ocp_act_kept {
  int n, ic;
  double w;
  int z[OCP_MAX_IN][2];
  double c[OCP_MAX_IN][2];
  double F[OCP_MAX_IN];
};

int ocp_state_alloc(mrvi_ocp *o) {
  free(o->act_kept);
  o->n_act_kept = 0;
  o->act_kept = NULL;
  if (o->n_state == 0)
    return MRVI_OK;
  o->act_kept = malloc((size_t)o->n_state * (size_t)o->p * sizeof *o->act_kept);
  return o->act_kept ? MRVI_OK : MRVI_ENOMEM;
}

/* Whether A's inputs are all slow (then the same two step nodes and
 * coefficients for every input at a micro point, the same nodes at every
 * one); whether A and B have the same inputs. */
static int slow_inputs(const mrvi_ocp *o, const ocp_actuator *A) {
  for (int i = 0; i < A->n_in; i++)
    if (o->model->rate[A->in[i]] != MRVI_SLOW)
      return 0;
  return 1;
}
static int same_inputs(const ocp_actuator *A, const ocp_actuator *B) {
  return A->n_in == B->n_in &&
         memcmp(A->in, B->in, (size_t)A->n_in * sizeof *A->in) == 0;
}
/* Whether actuators ia..ib-1 are torques of one term each on the same
 * director blocks: then sum_B dt u_B dF_B/dy is the derivative of one
 * torque of axis sum_B dt u_B s_B t_B (its derivative is linear in s t). */
static int one_torque_run(const mrvi_ocp *o, int ia, int ib) {
  const ocp_torque *T = &o->act[ia].torque[0];
  for (int ja = ia; ja < ib; ja++) {
    const ocp_actuator *B = &o->act[ja];
    if (B->pi >= 0 || B->n_torque != 1 || B->torque[0].x_off != T->x_off ||
        B->torque[0].y_off != T->y_off)
      return 0;
  }
  return 1;
}

/* The forces of step k at the stored trajectory, kept (o->act_kept), and
 * their derivatives added to J: sum_m sum_A dt u c_a c_b dF/dy over the
 * micro intervals m and each run of actuators A with the same slow inputs
 * (one pair of nodes q_k, q_{k+1} for all of them, coefficients 1 - theta,
 * theta), added once per run; else per point.  The same calls in the same
 * order at every step (the pattern). */
void ocp_state_jacobian(mrvi_ocp *o, long k, ocp_jac *J) {
  enum { NS = OCP_MAX_IN * OCP_MAX_IN };
  double S[4 * NS], Dsum[NS];
  o->n_act_kept = 0;
  for (int ia = 0; ia < o->n_act;) {
    const ocp_actuator *A = &o->act[ia];
    if (A->n_in == 0) {
      ia++;
      continue;
    }
    const int n = A->n_in, slow = slow_inputs(o, A);
    int ib = ia + 1;
    while (slow && ib < o->n_act && same_inputs(A, &o->act[ib]))
      ib++;
    const int one = slow && one_torque_run(o, ia, ib);
    if (slow && o->p > 1)
      memset(S, 0, 4 * (size_t)n * (size_t)n * sizeof *S);
    act_point ap;
    for (int m = 0; m < o->p; m++) {
      const mrvi_point pt = mid_point(o, m);
      act_nodes(o, A, &pt, &ap);
      double y[OCP_MAX_IN];
      for (int i = 0; i < n; i++)
        y[i] = ap.c[i][0] * o->Q[ocp_global(o, k, ap.z[i][0])] +
               ap.c[i][1] * o->Q[ocp_global(o, k, ap.z[i][1])];
      /* A slow run: Dsum = sum_B dt u_B dF_B/dy at this point, each
       * actuator's derivative added scaled (no matrix of its own). */
      ocp_torque Tsum = {.x_off = A->torque[0].x_off,
                         .y_off = A->torque[0].y_off,
                         .s = 1.0,
                         .axis = {0.0, 0.0, 0.0}};
      if (slow)
        memset(Dsum, 0, (size_t)n * (size_t)n * sizeof *Dsum);
      for (int ja = ia; ja < ib; ja++) {
        const ocp_actuator *B = &o->act[ja];
        struct ocp_act_kept *K = &o->act_kept[o->n_act_kept++];
        K->n = n;
        K->ic = control(o, B, k, m);
        K->w = pt.w;
        memcpy(K->z, ap.z, (size_t)n * sizeof *K->z);
        memcpy(K->c, ap.c, (size_t)n * sizeof *K->c);
        const double wu = pt.w * o->u_cur[K->ic];
        if (one) {
          const ocp_torque *T = &B->torque[0];
          memset(K->F, 0, (size_t)n * sizeof *K->F);
          torque_force(o->model->dimension, n, T, y, K->F, 0.0, NULL);
          for (int c = 0; c < 3; c++)
            Tsum.axis[c] += wu * T->s * T->axis[c];
          continue;
        }
        if (slow) {
          act_force_scaled(o, B, y, K->F, wu, Dsum);
          continue;
        }
        act_force(o, B, y, &ap);
        memcpy(K->F, ap.F, (size_t)n * sizeof *K->F);
        for (int i = 0; i < n; i++)
          for (int a = 0; a < 2; a++)
            for (int j = 0; j < n; j++)
              for (int b = 0; b < 2; b++)
                ocp_jac_add(J, ap.z[i][a], ap.z[j][b],
                            wu * ap.c[i][a] * ap.c[j][b] * ap.Dm[i * n + j]);
      }
      if (one)
        torque_force(o->model->dimension, n, &Tsum, y, NULL, 1.0, Dsum);
      for (int a = 0; slow && o->p > 1 && a < 2; a++)
        for (int b = 0; b < 2; b++) {
          const double cab = ap.c[0][a] * ap.c[0][b];
          double *Sab = S + (size_t)(2 * a + b) * (size_t)(n * n);
          for (int e = 0; e < n * n; e++)
            Sab[e] += cab * Dsum[e];
        }
    }
    /* (one micro interval: S_ab = c_a c_b Dsum, not summed; a dense J's
     * rows addressed directly, the same adds in the same order) */
    for (int i = 0; slow && i < n; i++)
      for (int a = 0; a < 2; a++) {
        double *Jrow = J->mode == OCP_JAC_DENSE
                           ? J->J + (size_t)ap.z[i][a] * (size_t)J->nv
                           : NULL;
        for (int j = 0; j < n; j++)
          for (int b = 0; b < 2; b++) {
            const double v =
                o->p == 1
                    ? ap.c[0][a] * ap.c[0][b] * Dsum[i * n + j]
                    : S[(size_t)(2 * a + b) * (size_t)(n * n) + i * n + j];
            if (Jrow)
              Jrow[ap.z[j][b]] += v;
            else
              ocp_jac_add(J, ap.z[i][a], ap.z[j][b], v);
          }
      }
    ia = ib;
  }
}

/* Up to FB functionals' sums at once (independent chains, each in the
 * order of its terms). */
enum { FB = 8 };
void ocp_state_gradient(const mrvi_ocp *o, long k, int nfun, const double *mu,
                        double *gu) {
  const long nn = o->n_nodes;
  for (int t = 0; t < o->n_act_kept; t++) {
    const struct ocp_act_kept *K = &o->act_kept[t];
    long g[2 * OCP_MAX_IN];
    double wf[2 * OCP_MAX_IN];
    for (int i = 0; i < K->n; i++)
      for (int a = 0; a < 2; a++) {
        g[2 * i + a] = ocp_global(o, k, K->z[i][a]);
        wf[2 * i + a] = K->w * K->c[i][a] * K->F[i];
      }
    for (int f0 = 0; f0 < nfun; f0 += FB) {
      const int nb = nfun - f0 < FB ? nfun - f0 : FB;
      double sum[FB];
      for (int f = 0; f < nb; f++)
        sum[f] = 0.0;
      for (int e = 0; e < 2 * K->n; e++)
        for (int f = 0; f < nb; f++)
          sum[f] += mu[(size_t)(f0 + f) * (size_t)nn + (size_t)g[e]] * wf[e];
      for (int f = 0; f < nb; f++)
        gu[(size_t)(f0 + f) * (size_t)o->n_u + (size_t)K->ic] -= sum[f];
    }
  }
}
