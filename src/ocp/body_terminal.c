/* Terminal conditions on rigid bodies (doc/optimal-control.md, "Bodies"):
 * the attitude as the rotation vector of R_target^T R_N (three rows; 2-D:
 * the angle) and the angular velocity from the final discrete momenta
 * (three rows in space or in the body frame; 2-D: one; or single
 * components of it), and the direction of one director (two rows: the
 * rotation vector taking the target direction to it, normal to the
 * target), with their exact derivatives in the final positions and
 * momenta for the adjoint.
 *
 * Attitude: A = R_target^T R with A_ab = t_a . d_b (t_a the columns of
 * R_target).  With c = (tr A - 1)/2 = cos(theta) and s = vee(A - A^T)/2 =
 * sin(theta) n, the rotation vector is v = k s, k = atan2(|s|, c)/|s|,
 * defined as a function of A alone (smooth for angles below pi), so
 *   dv = k ds + s ((dk/dsigma)/sigma (s . ds) + dk/dc dc),  sigma = |s|.
 *
 * Angular velocity: the body's angular momentum about its centre of mass
 * L = sum_i d_i x p_{d_i} is the momentum map of the rotations (blind to
 * the internal constraints' forces), and L = R J Omega for a rigid motion
 * (d_i' = omega x d_i, p_{d_i} = E_i d_i', J_i = E_j + E_k), hence
 *   Omega_r = d_r . L / J_r (body frame),  omega = sum_r Omega_r d_r.
 * A joint's impulse does have a moment: for a body held by a constraint
 * other than its internal one, adjoint.c hands these functions the final
 * momenta projected onto the hidden constraints. */
#include "ocp/ocp_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* k = atan2(sigma, c) / sigma and its derivatives ks = (dk/dsigma)/sigma,
 * kc = dk/dc: the rotation vector (or angle vector) is k s for s of length
 * sigma = sin(theta) and c = cos(theta). */
static void angle_factor(double sig, double c, double *k, double *ks,
                         double *kc) {
  const double rho2 = sig * sig + c * c, th = atan2(sig, c);
  *kc = -1.0 / rho2;
  if (sig < 1e-3 && c > 0.0) {
    /* Series in sigma (the closed form cancels): k = 1/c - sigma^2/(3c^3). */
    *k = 1.0 / c - sig * sig / (3.0 * c * c * c);
    *ks = -2.0 / (3.0 * c * c * c);
  } else {
    *k = th / sig;
    *ks = (c * sig / rho2 - th) / (sig * sig * sig);
  }
}

/* Rotation vector row r of A (3 x 3) and its derivative GA[a b] = dv_r/dA_ab.
 */
static double rotvec_row(const double *A, int r, double *GA) {
  const double c = 0.5 * (A[0] + A[4] + A[8] - 1.0);
  const double s[3] = {0.5 * (A[7] - A[5]), 0.5 * (A[2] - A[6]),
                       0.5 * (A[3] - A[1])};
  const double sig = sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]);
  double k, ks, kc;
  angle_factor(sig, c, &k, &ks, &kc);
  double w[3];
  for (int q = 0; q < 3; q++)
    w[q] = (q == r ? k : 0.0) + s[r] * ks * s[q];
  memset(GA, 0, 9 * sizeof *GA);
  GA[7] += 0.5 * w[0];
  GA[5] -= 0.5 * w[0];
  GA[2] += 0.5 * w[1];
  GA[6] -= 0.5 * w[1];
  GA[3] += 0.5 * w[2];
  GA[1] -= 0.5 * w[2];
  for (int a = 0; a < 3; a++)
    GA[4 * a] += 0.5 * s[r] * kc;
  return k * s[r];
}

/* 2-D: the angle of A (2 x 2) and dtheta/dA. */
static double angle_2d(const double *A, double *GA) {
  const double S = 0.5 * (A[2] - A[1]), C = 0.5 * (A[0] + A[3]);
  const double rho2 = S * S + C * C;
  GA[2] = 0.5 * C / rho2;
  GA[1] = -0.5 * C / rho2;
  GA[0] = GA[3] = -0.5 * S / rho2;
  return atan2(S, C);
}

static double attitude(int D, const ocp_terminal *T, const double *q,
                       double *gq) {
  const double *Rt = T->R_target, *d = q + D;
  double A[9], GA[9];
  for (int a = 0; a < D; a++)
    for (int b = 0; b < D; b++) {
      A[a * D + b] = 0.0;
      for (int j = 0; j < D; j++)
        A[a * D + b] += Rt[j * D + a] * d[D * b + j];
    }
  const double v = D == 3 ? rotvec_row(A, T->row, GA) : angle_2d(A, GA);
  for (int b = 0; b < D; b++)
    for (int j = 0; j < D; j++) {
      double g = 0.0;
      for (int a = 0; a < D; a++)
        g += GA[a * D + b] * Rt[j * D + a];
      gq[D + D * b + j] = g;
    }
  return v;
}

/* Direction of director i along e (frame rows u, v, e in R_target): the
 * rotation vector taking e to d = d_i is w = k(sigma, c) e x d with
 * c = e . d, sigma = |e x d|; e x d has the components s_u = (e x d) . u
 * = -d . v and s_v = d . u (u x e = -v, v x e = u), and row r is
 * w_r = k s_r, with dw_r = k ds_r + s_r (ks (s . ds) + kc dc) linear in
 * dd (ds_u = -v . dd, ds_v = u . dd, dc = e . dd). */
static double direction(const ocp_terminal *T, const double *q, double *gq) {
  const double *u = T->R_target, *v = u + 3, *e = u + 6;
  const double *d = q + 3 + 3 * T->director;
  double su = 0.0, sv = 0.0, c = 0.0;
  for (int a = 0; a < 3; a++) {
    su -= d[a] * v[a];
    sv += d[a] * u[a];
    c += d[a] * e[a];
  }
  const double sig = sqrt(su * su + sv * sv);
  double k, ks, kc;
  angle_factor(sig, c, &k, &ks, &kc);
  const double sr = T->row == 0 ? su : sv;
  for (int a = 0; a < 3; a++) {
    const double dsu = -v[a], dsv = u[a];
    const double dsr = T->row == 0 ? dsu : dsv;
    gq[3 + 3 * T->director + a] =
        k * dsr + sr * (ks * (su * dsu + sv * dsv) + kc * e[a]);
  }
  return k * sr;
}

static void cross(const double *a, const double *b, double *out) {
  out[0] = a[1] * b[2] - a[2] * b[1];
  out[1] = a[2] * b[0] - a[0] * b[2];
  out[2] = a[0] * b[1] - a[1] * b[0];
}

static double angular_velocity(const mrvi_body *B, const ocp_terminal *T,
                               const double *q, const double *p, double *gq,
                               double *gp) {
  const double *d = q + 3, *pd = p + 3;
  double L[3] = {0, 0, 0}, Om[3], dOm[3][2][3][3]; /* [r][q|p][i][j] */
  for (int i = 0; i < 3; i++) {
    double x[3];
    cross(d + 3 * i, pd + 3 * i, x);
    for (int a = 0; a < 3; a++)
      L[a] += x[a];
  }
  for (int r = 0; r < 3; r++) {
    const double *dr = d + 3 * r, iJ = 1.0 / B->inertia[r];
    Om[r] = iJ * (dr[0] * L[0] + dr[1] * L[1] + dr[2] * L[2]);
    for (int i = 0; i < 3; i++) {
      double x[3], y[3];
      cross(pd + 3 * i, dr, x); /* d/dd_i */
      cross(dr, d + 3 * i, y);  /* d/dp_i */
      for (int j = 0; j < 3; j++) {
        dOm[r][0][i][j] = iJ * (x[j] + (i == r ? L[j] : 0.0));
        dOm[r][1][i][j] = iJ * y[j];
      }
    }
  }
  const int r = T->row;
  if (T->kind == MRVI_OCP_ANGULAR_VELOCITY_BODY) {
    for (int i = 0; i < 3; i++)
      for (int j = 0; j < 3; j++) {
        gq[3 + 3 * i + j] = dOm[r][0][i][j];
        gp[3 + 3 * i + j] = dOm[r][1][i][j];
      }
    return Om[r];
  }
  /* Space: omega_r = sum_s d_s[r] Omega_s. */
  double w = 0.0;
  for (int s = 0; s < 3; s++)
    w += d[3 * s + r] * Om[s];
  for (int i = 0; i < 3; i++)
    for (int j = 0; j < 3; j++) {
      double gqv = j == r ? Om[i] : 0.0, gpv = 0.0;
      for (int s = 0; s < 3; s++) {
        gqv += d[3 * s + r] * dOm[s][0][i][j];
        gpv += d[3 * s + r] * dOm[s][1][i][j];
      }
      gq[3 + 3 * i + j] = gqv;
      gp[3 + 3 * i + j] = gpv;
    }
  return w;
}

double ocp_body_terminal(const mrvi_ocp *o, const ocp_terminal *T,
                         const double *q, const double *p, double *gq,
                         double *gp) {
  const mrvi_model *m = o->model;
  const mrvi_body *B = &m->bodies[T->body];
  const int D = m->dimension, n = D * (D + 1);
  memset(gq, 0, (size_t)n * sizeof *gq);
  memset(gp, 0, (size_t)n * sizeof *gp);
  if (T->kind == MRVI_OCP_ATTITUDE)
    return attitude(D, T, q, gq);
  if (T->kind == MRVI_OCP_DIRECTION)
    return direction(T, q, gq);
  if (D == 3)
    return angular_velocity(B, T, q, p, gq, gp) - T->target;
  /* 2-D: L = sum_i d_i x p_i (scalar), omega = L / J. */
  const double iJ = 1.0 / B->inertia[0];
  double L = 0.0;
  for (int i = 0; i < 2; i++) {
    const double *di = q + 2 + 2 * i, *pi = p + 2 + 2 * i;
    L += di[0] * pi[1] - di[1] * pi[0];
    gq[2 + 2 * i] = iJ * pi[1];
    gq[3 + 2 * i] = -iJ * pi[0];
    gp[2 + 2 * i] = -iJ * di[1];
    gp[3 + 2 * i] = iJ * di[0];
  }
  return iJ * L - T->target;
}

/* Add row v to the orthonormal basis B (k rows) if its part outside
 * span(B) is larger than 1e-8 |v|; 0 when v is (numerically) in the span. */
static int extend_basis(int n, double *B, int *k, double *v) {
  const int added = mrvi_dense_extend_basis(n, B, *k, v, 1e-8);
  *k += added;
  return added;
}

/* The test point of the rank test: q0 moved by 1e-4 max(1, |q0|) in a
 * fixed pattern (projected back onto the constraints by the caller), so
 * that a condition is judged by the structure of the constraints rather
 * than by where they happen to point at q0 (a pendulum hanging straight
 * down has its rod gradient along y, which made a condition on the bob's y
 * look redundant; at 45 degrees it did not).  Returns max(1, |q0|). */
static double test_point(const mrvi_model *m, double *qg) {
  double qmax = 1.0;
  for (int i = 0; i < m->n; i++)
    qmax = fmax(qmax, fabs(m->q0[i]));
  for (int i = 0; i < m->n; i++)
    qg[i] = m->q0[i] + 1e-4 * qmax * sin(1.7 * i + 0.3);
  return qmax;
}

/* Equality condition T's gradient at (qg, p0) into v (n, zero outside the
 * condition's coordinates): in the positions (1) or the momenta (0); -1
 * where it is not finite (such a row is not judged). */
static int condition_row(const mrvi_ocp *o, const ocp_terminal *T,
                         const double *qg, const double *p0, double *v) {
  const int n = o->model->n, D = o->model->dimension, nb = D * (D + 1);
  double gq[12], gp[12];
  int pos;
  memset(v, 0, (size_t)n * sizeof *v);
  if (T->body >= 0) {
    ocp_body_terminal(o, T, qg + T->coord, p0 + T->coord, gq, gp);
    pos = T->kind == MRVI_OCP_ATTITUDE || T->kind == MRVI_OCP_DIRECTION;
    for (int j = 0; j < nb; j++)
      v[T->coord + j] = pos ? gq[j] : gp[j];
  } else {
    pos = T->kind == MRVI_OCP_POSITION;
    v[T->coord] = 1.0;
  }
  for (int j = 0; j < n; j++)
    if (!isfinite(v[j]))
      return -1;
  return pos;
}

/* The rank test in dense storage: Gram-Schmidt on the rows of G (positions)
 * and G M^-1 (momenta, the hidden constraints), then on the conditions;
 * O(R^2 n).  The fallback of the sparse test where the constraint rows are
 * dependent (closed loops) or the Gram factor fails. */
static int redundant_dense(const mrvi_ocp *o, int first, double *qg,
                           const double *p0, double qmax) {
  const mrvi_model *m = o->model;
  const int n = m->n, R = mrvi_model_constraint_rows(m);
  const int rows = R + o->n_term;
  double *G = malloc(((size_t)R * (size_t)n + 1) * sizeof *G);
  double *Bq = malloc(((size_t)rows * (size_t)n + 1) * sizeof *Bq);
  double *Bp = malloc(((size_t)rows * (size_t)n + 1) * sizeof *Bp);
  double *v = malloc(((size_t)n + 1) * sizeof *v);
  double *g = malloc(((size_t)R + 1) * sizeof *g);
  int kq = 0, kp = 0, bad = -2;
  if (!G || !Bq || !Bp || !v || !g)
    goto out;
  bad = -1;
  if (R > 0) {
    double change;
    char msg[200];
    if (mrvi_constraints_project_positions(m, qg, 1e-13 * qmax, &change, NULL,
                                           msg, sizeof msg) < 0)
      memcpy(qg, m->q0, (size_t)n * sizeof *qg);
  }
  /* Positions: the rows of G; momenta: the hidden constraints G M^-1 p. */
  mrvi_model_constraint_eval(m, qg, g, G);
  for (int r = 0; r < R; r++) {
    memcpy(v, G + (size_t)r * (size_t)n, (size_t)n * sizeof *v);
    extend_basis(n, Bq, &kq, v);
    for (int j = 0; j < n; j++)
      v[j] = G[(size_t)r * (size_t)n + j] / MRVI_MASS(m, j);
    extend_basis(n, Bp, &kp, v);
  }
  /* The equality conditions in order: the first from `first` on that is
   * implied by the constraints and the earlier conditions. */
  for (int t = 0; t < o->n_term && bad < 0; t++) {
    const ocp_terminal *T = &o->term[t];
    if (T->penalty > 0.0)
      continue;
    const int pos = condition_row(o, T, qg, p0, v);
    if (pos >= 0 && !extend_basis(n, pos ? Bq : Bp, pos ? &kq : &kp, v) &&
        t >= first)
      bad = t;
  }
out:
  free(G);
  free(Bq);
  free(Bp);
  free(v);
  free(g);
  return bad;
}

/* The rank test through the sparse Gram matrix A = G M^-1 G^T
 * (constraint_gram.c; O(R) for chains and trees): a condition's row x
 * (positions: its gradient v; momenta: M v, since v lies in the span of
 * the rows of G M^-1 exactly where M v lies in that of G) is split off the
 * span of G's rows in the metric M^-1, w = x - G^T A^-1 G M^-1 x (twice,
 * the second pass taking the first's round-off), and w, scaled to
 * y = M^-1/2 w, is Gram-Schmidt'ed against the earlier conditions' in the
 * same space; the condition is implied where what is left is at most
 * 1e-8 of |M^-1/2 x|.  Linear in n for a fixed number of conditions (the
 * dense test: O(R^2 n)).  -3 where the Gram factor fails (dependent rows):
 * the caller takes the dense test. */
static int redundant_sparse(const mrvi_ocp *o, int first, double *qg,
                            const double *p0, double qmax) {
  const mrvi_model *m = o->model;
  const int n = m->n, R = mrvi_model_constraint_rows(m);
  int ne = 0;
  for (int t = 0; t < o->n_term; t++)
    ne += o->term[t].penalty == 0.0;
  mrvi_gram *gr = NULL;
  double *Bq = malloc(((size_t)ne * (size_t)n + 1) * sizeof *Bq);
  double *Bp = malloc(((size_t)ne * (size_t)n + 1) * sizeof *Bp);
  double *v = malloc(((size_t)n + 1) * sizeof *v);
  double *mu = malloc(((size_t)R + 1) * sizeof *mu);
  int kq = 0, kp = 0, bad = -2;
  if (!Bq || !Bp || !v || !mu || mrvi_gram_create(m, &gr) < 0)
    goto out;
  bad = -3;
  /* The test point onto the constraints by chord corrections from the
   * factor at the moved point (as mrvi_constraints_project_positions does
   * by Newton), q0 itself where they do not get there. */
  if (mrvi_gram_factor(gr, m, qg) != MRVI_OK)
    goto out;
  if (!(mrvi_gram_settle(gr, m, qg, mu, MRVI_GRAM_SETTLE_PASSES) <=
        1e-13 * qmax))
    memcpy(qg, m->q0, (size_t)n * sizeof *qg);
  if (mrvi_gram_factor(gr, m, qg) != MRVI_OK)
    goto out;
  bad = -1;
  for (int t = 0; t < o->n_term && bad < 0; t++) {
    const ocp_terminal *T = &o->term[t];
    if (T->penalty > 0.0)
      continue;
    const int pos = condition_row(o, T, qg, p0, v);
    if (pos < 0)
      continue;
    double nx = 0.0;
    for (int j = 0; j < n; j++) {
      if (!pos)
        v[j] *= MRVI_MASS(m, j);
      nx += v[j] * v[j] / MRVI_MASS(m, j);
    }
    mrvi_gram_project(gr, m, v, mu);
    mrvi_gram_project(gr, m, v, mu);
    double nw = 0.0;
    for (int j = 0; j < n; j++) {
      v[j] /= sqrt(MRVI_MASS(m, j));
      nw += v[j] * v[j];
    }
    const int added =
        nw > 0.0 && mrvi_dense_extend_basis(n, pos ? Bq : Bp, pos ? kq : kp, v,
                                            1e-8 * sqrt(nx / nw));
    if (pos)
      kq += added;
    else
      kp += added;
    if (!added && t >= first)
      bad = t;
  }
out:
  mrvi_gram_free(gr);
  free(Bq);
  free(Bp);
  free(v);
  free(mu);
  return bad;
}

int ocp_terminal_redundant(const mrvi_ocp *o, int first) {
  const mrvi_model *m = o->model;
  const int n = m->n, R = mrvi_model_constraint_rows(m);
  double *p0 = malloc(((size_t)n + 1) * sizeof *p0);
  double *qg = malloc(((size_t)n + 1) * sizeof *qg);
  int bad = -2;
  if (p0 && qg) {
    for (int i = 0; i < n; i++)
      p0[i] = MRVI_MASS(m, i) * m->v0[i];
    const double qmax = test_point(m, qg);
    bad = R > 0 ? redundant_sparse(o, first, qg, p0, qmax) : -3;
    if (bad == -3) {
      test_point(m, qg);
      bad = redundant_dense(o, first, qg, p0, qmax);
    }
  }
  free(p0);
  free(qg);
  return bad;
}
