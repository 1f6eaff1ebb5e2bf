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
 * transposed step Jacobian A_k^T of eq:DEL_ini (from the step assembly and
 * UMFPACK), the off-diagonal blocks are parts of H_k.  Then
 *   dPhi/du = dPhi/du|_direct - sum_k mu[z_k]^T d(forces_k)/du.
 * All functionals (cost and every terminal constraint) share one sweep. */
#include "ocp/ocp_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

void ocp_hessian(mrvi_ocp *o, long k, double *H) {
  const mrvi_model *m = o->model;
  mrvi_step *st = &o->step;
  const int ns = o->ns, nf = o->nf, p = o->p, nz = o->nz;
  memset(H, 0, (size_t)nz * (size_t)nz * sizeof *H);
  /* Kinetic: M/h [[1, -1], [-1, 1]] on every interval. */
  for (int s = 0; s < ns; s++) {
    const double a = m->mass[m->slow_index[s]] / st->dT;
    H[s * nz + s] += a;
    H[(ns + s) * nz + ns + s] += a;
    H[s * nz + ns + s] -= a;
    H[(ns + s) * nz + s] -= a;
  }
  for (int mm = 0; mm < p; mm++)
    for (int s = 0; s < nf; s++) {
      const double a = m->mass[m->fast_index[s]] / st->dt;
      const int i = 2 * ns + mm * nf + s, j = i + nf;
      H[i * nz + i] += a;
      H[j * nz + j] += a;
      H[i * nz + j] -= a;
      H[j * nz + i] -= a;
    }
  /* Potentials: -w c_a c_b hess Z at every evaluation point. */
  for (int c = 0; c < 2; c++)
    for (int ip = 0; ip < st->n_pts[c]; ip++) {
      const mrvi_point *pt = &st->pts[c][ip];
      for (int ie = 0; ie < st->n_elem_of_class[c]; ie++) {
        const mrvi_element *e = &m->elements[st->elem_of_class[c][ie]];
        if (e->kind == MRVI_ELEMENT_GRAVITY)
          continue;
        const int n = e->n_in;
        int zi[MRVI_MAX_INPUTS][2];
        double zc[MRVI_MAX_INPUTS][2];
        for (int j = 0; j < n; j++) {
          const int idx = e->in[j], s = m->slot[idx];
          if (m->rate[idx] == MRVI_SLOW) {
            zi[j][0] = s;
            zi[j][1] = ns + s;
            zc[j][0] = pt->a0;
            zc[j][1] = pt->a1;
          } else {
            zi[j][0] = 2 * ns + pt->m * nf + s;
            zi[j][1] = zi[j][0] + nf;
            zc[j][0] = pt->cA;
            zc[j][1] = pt->cB;
          }
          st->y[j] = zc[j][0] * o->Q[ocp_global(o, k, zi[j][0])] +
                     zc[j][1] * o->Q[ocp_global(o, k, zi[j][1])];
        }
        mrvi_element_eval(m, e, st->y, st->g, st->H);
        for (int j = 0; j < n; j++)
          for (int l = 0; l < n; l++) {
            const double h = pt->w * st->H[j * n + l];
            for (int a = 0; a < 2; a++)
              for (int b = 0; b < 2; b++)
                H[zi[j][a] * nz + zi[l][b]] -= zc[j][a] * zc[l][b] * h;
          }
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

/* Cost and constraints with their direct partial derivatives: rows
 * f = 0 (cost), 1..n_con of gQ (n_nodes), gp (ns + nf), gu (n_u). */
static void functionals(const mrvi_ocp *o, const double *u, double *val,
                        double *gQ, double *gp, double *gu) {
  const mrvi_model *m = o->model;
  const int nfun = 1 + o->n_con, npn = o->ns + o->nf;
  const long nn = o->n_nodes;
  memset(val, 0, (size_t)nfun * sizeof *val);
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
      gQ[ga] += w * (2.0 * ea + eb);
      gQ[gb] += w * (2.0 * eb + ea);
    }
  }
  /* Terminal conditions. */
  int ic = 0;
  for (int t = 0; t < o->n_term; t++) {
    const ocp_terminal *T = &o->term[t];
    int ps;
    const long g = final_node(o, T->coord, &ps);
    const double M = m->mass[T->coord];
    const double v =
        (T->kind == MRVI_OCP_POSITION ? o->Q[g] : o->pN[ps] / M) - T->target;
    const double dv = T->kind == MRVI_OCP_POSITION ? 1.0 : 1.0 / M;
    const int f = T->penalty > 0.0 ? 0 : 1 + ic++;
    const double scale = f == 0 ? T->penalty * v : 1.0;
    val[f] += f == 0 ? 0.5 * T->penalty * v * v : v;
    if (T->kind == MRVI_OCP_POSITION)
      gQ[(size_t)f * (size_t)nn + (size_t)g] += scale * dv;
    else
      gp[f * npn + ps] += scale * dv;
  }
}

/* Lazily sized adjoint workspace for nfun functionals. */
static int adjoint_alloc(mrvi_ocp *o, int nfun) {
  const size_t nn = (size_t)o->n_nodes, nu = (size_t)o->step.n_total;
  const size_t npn = (size_t)(o->ns + o->nf), f = (size_t)nfun;
  free(o->r);
  free(o->mu);
  free(o->rhs);
  free(o->sol);
  o->r = calloc(f * (2 * nn + npn + (size_t)o->n_u + 1), sizeof(double));
  o->mu = calloc(f * nn + 1, sizeof(double));
  o->rhs = calloc(f * nu + 1, sizeof(double));
  o->sol = calloc(f * nu + 1, sizeof(double));
  return o->r && o->mu && o->rhs && o->sol ? MRVI_OK : MRVI_ENOMEM;
}

int mrvi_ocp_evaluate(mrvi_ocp *o, const double *u, double *J, double *grad,
                      double *c, double *cgrad) {
  for (int i = 0; i < o->n_u; i++)
    if (!isfinite(u[i]))
      return mrvi_ocp_fail(o, MRVI_ENONFINITE, "control %d is not finite", i);
  int s = ocp_forward(o, u);
  if (s < 0)
    return s;
  const int nfun = 1 + o->n_con, npn = o->ns + o->nf, nz = o->nz;
  const long nn = o->n_nodes;
  if (!o->r && adjoint_alloc(o, nfun) < 0)
    return mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
  double *gQ = o->r, *val = o->r + (size_t)nfun * (size_t)nn;
  double *gp = val + nfun, *gu = gp + (size_t)nfun * (size_t)npn;
  /* (val, gp and gu fit in the second n_nodes block of r; see alloc.) */
  functionals(o, u, val, gQ, gp, gu);
  *J = val[0];
  if (c)
    for (int i = 0; i < o->n_con; i++)
      c[i] = val[1 + i];
  if (!grad && !cgrad)
    return MRVI_OK;

  /* Backward sweep.  mu: global node adjoints; final nodes -dPhi/dp_N. */
  mrvi_step *st = &o->step;
  const int ns = o->ns, nf = o->nf, p = o->p, nu = st->n_unknowns;
  const long N = o->N;
  memset(o->mu, 0, (size_t)nfun * (size_t)nn * sizeof(double));
  for (int f = 0; f < nfun; f++) {
    for (int i = 0; i < ns; i++)
      o->mu[f * nn + N * ns + i] = -gp[f * npn + i];
    for (int i = 0; i < nf; i++)
      o->mu[f * nn + (N + 1) * ns + N * p * nf + i] = -gp[f * npn + ns + i];
  }
  double *H = o->H;
  char msg[300];
  for (long k = N - 1; k >= 0; k--) {
    ocp_hessian(o, k, H);
    /* r -= H_k[:, final_k] mu[final_k] (final_k: q_{k+1}^s and fast node
     * p, whose adjoints are known). */
    for (int f = 0; f < nfun; f++) {
      double *r = gQ + f * nn;
      const double *mu = o->mu + f * nn;
      for (int zz = ns; zz < nz; zz++) {
        if (zz >= 2 * ns && zz < 2 * ns + p * nf)
          continue;
        const double mz = mu[ocp_global(o, k, zz)];
        if (mz != 0.0)
          for (int z = 0; z < nz; z++)
            r[ocp_global(o, k, z)] -= H[z * nz + zz] * mz;
      }
    }
    /* A_k^T mu_k = r[x_k] with the step Jacobian at the converged x_k. */
    st->qs0 = o->Q + k * ns;
    st->qf0 = o->Q + (N + 1) * ns + k * p * nf;
    memcpy(o->x, o->Q + (k + 1) * ns, (size_t)ns * sizeof(double));
    memcpy(o->x + ns, o->Q + (N + 1) * ns + (k * p + 1) * nf,
           (size_t)(p * nf) * sizeof(double));
    mrvi_step_assemble(st, o->x, o->R, 1);
    for (int f = 0; f < nfun; f++) {
      const double *r = gQ + f * nn;
      double *b = o->rhs + (size_t)f * (size_t)nu;
      for (int i = 0; i < ns; i++)
        b[i] = r[ocp_global(o, k, ns + i)];
      for (int i = 0; i < p * nf; i++)
        b[ns + i] = r[ocp_global(o, k, 2 * ns + nf + i)];
    }
    s = mrvi_newton_solve_transpose(o->newton, st->Ax, nfun, o->rhs, o->sol,
                                    msg, sizeof msg);
    if (s < 0)
      return mrvi_ocp_fail(o, s, "adjoint step %ld: %s", k + 1, msg);
    /* mu on the equation nodes of step k; r -= H_k[:, eq_k] mu_k. */
    for (int f = 0; f < nfun; f++) {
      double *r = gQ + f * nn, *mu = o->mu + f * nn;
      const double *x = o->sol + (size_t)f * (size_t)nu;
      for (int i = 0; i < nu; i++) {
        const int zz = i < ns ? i : 2 * ns + (i - ns); /* q_k^s, fast 0..p-1 */
        mu[ocp_global(o, k, zz)] = x[i];
        if (x[i] != 0.0)
          for (int z = 0; z < nz; z++)
            r[ocp_global(o, k, z)] -= H[z * nz + zz] * x[i];
      }
    }
  }
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
