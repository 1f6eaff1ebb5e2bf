#include "models.h"

#include "solver/solver.h"
#include "step/step.h"

#include <math.h>
#include <stdlib.h>

mrvi_model *test_fpu(void) { return test_fpu_laws("power", "linear"); }

mrvi_model *test_fpu_laws(const char *power, const char *linear) {
  mrvi_model *m = mrvi_model_create();
  const char *names[6] = {"qs1", "qs2", "qs3", "qf1", "qf2", "qf3"};
  const double omega = 50.0;
  const double q0[6] = {1, 0, 0, 1.0 / omega, 0, 0};
  const double v0[6] = {1, 0, 0, 1, 0, 0};
  for (int i = 0; i < 6; i++)
    mrvi_model_add_coordinate(m, names[i], 1.0, i < 3 ? MRVI_SLOW : MRVI_FAST,
                              q0[i], v0[i]);
  /* V = 1/4 [(qs1 - qf1)^4 + sum (qs_{i+1} - qf_{i+1} - qs_i - qf_i)^4
   *          + (qs3 + qf3)^4] */
  const double pw[2] = {0.25, 4.0};
  const int c1[2] = {0, 3}, c4[2] = {2, 5};
  const double a1[2] = {1, -1}, a4[2] = {1, 1};
  const int c2[4] = {1, 4, 0, 3}, c3[4] = {2, 5, 1, 4};
  const double a23[4] = {1, -1, -1, -1};
  mrvi_model_add_term(m, MRVI_SLOW, 2, c1, a1, 0.0, power, pw);
  mrvi_model_add_term(m, MRVI_SLOW, 4, c2, a23, 0.0, power, pw);
  mrvi_model_add_term(m, MRVI_SLOW, 4, c3, a23, 0.0, power, pw);
  mrvi_model_add_term(m, MRVI_SLOW, 2, c4, a4, 0.0, power, pw);
  /* W = omega^2/2 |qf|^2 */
  const double k[1] = {omega * omega};
  for (int i = 3; i < 6; i++) {
    const double one = 1.0;
    mrvi_model_add_term(m, MRVI_FAST, 1, &i, &one, 0.0, linear, k);
  }
  mrvi_model_set_name(m, "fpu");
  return m;
}

mrvi_model *test_spring_ring(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 3);
  const double r = 2.0, h = 2.0, pi = acos(-1.0);
  double q[6][3], v[6][3] = {{0}};
  for (int i = 0; i < 6; i++) {
    q[i][0] = r * sin(i * pi / 3);
    q[i][1] = -r * cos(i * pi / 3);
    q[i][2] = -h;
  }
  const double off[4][3] = {
      {0.3, 0.3, 0}, {0.2, -0.3, -0.3}, {0.2, -0.2, 0}, {-0.3, 0.4, 0}};
  const int who[4] = {2, 4, 1, 3}; /* q3, q5, q2, q4 */
  for (int a = 0; a < 4; a++)
    for (int k = 0; k < 3; k++)
      q[who[a]][k] += off[a][k];
  double e12[3], e36[3], n12 = 0, n36 = 0;
  for (int k = 0; k < 3; k++) {
    e12[k] = q[0][k] - q[1][k];
    e36[k] = q[2][k] - q[5][k];
    n12 += e12[k] * e12[k];
    n36 += e36[k] * e36[k];
  }
  for (int k = 0; k < 3; k++) {
    v[0][k] = 5 * e12[k] / sqrt(n12);
    v[1][k] = -30 * e12[k] / sqrt(n12);
    v[2][k] = -5 * e36[k] / sqrt(n36);
  }
  const double v4[3] = {50, 40, -10}, v6[3] = {50, 40, 10};
  for (int k = 0; k < 3; k++) {
    v[3][k] = v4[k];
    v[5][k] = v6[k];
  }
  const char *names[6] = {"m1", "m2", "m3", "m4", "m5", "m6"};
  for (int i = 0; i < 6; i++)
    mrvi_model_add_particle(m, names[i], 2.0,
                            i % 2 == 0 ? MRVI_SLOW : MRVI_FAST, q[i], v[i]);
  const double origin[3] = {0, 0, 0};
  const double w1[1] = {2.0}, w2[1] = {4000.0}, ring[2] = {5.0 / 4.0, 4.0};
  for (int i = 0; i < 6; i++) {
    if (i % 2 == 0)
      mrvi_model_add_anchor_spring(m, MRVI_SLOW, i, origin, "linear", w1, 0.0);
    else
      mrvi_model_add_anchor_spring(m, MRVI_FAST, i, origin, "linear", w2, 0.0);
    mrvi_model_add_spring(m, MRVI_SLOW, i, (i + 1) % 6, "power", ring, 0.0);
  }
  const double g[3] = {0, 0, -9.81};
  mrvi_model_set_gravity(m, g);
  mrvi_model_set_name(m, "spring-ring");
  return m;
}

mrvi_model *test_oscillator(double omega) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_add_coordinate(m, "q", 1.0, MRVI_SLOW, 1.0, 0.0);
  const int c = 0;
  const double one = 1.0, k[1] = {omega * omega};
  mrvi_model_add_term(m, MRVI_SLOW, 1, &c, &one, 0.0, "linear", k);
  return m;
}

void test_initial_data(mrvi_step *st, double *qs, double *qf, double *ps,
                       double *pf) {
  const mrvi_model *m = st->model;
  for (int i = 0; i < m->n_slow; i++) {
    qs[i] = m->q0[m->slow_index[i]];
    ps[i] = MRVI_MASS(m, m->slow_index[i]) * m->v0[m->slow_index[i]];
  }
  for (int i = 0; i < m->n_fast; i++) {
    qf[i] = m->q0[m->fast_index[i]];
    pf[i] = MRVI_MASS(m, m->fast_index[i]) * m->v0[m->fast_index[i]];
  }
  st->qs0 = qs;
  st->qf0 = qf;
  st->ps0 = ps;
  st->pf0 = pf;
}

int test_bordered_transpose_solve(const mrvi_model *m, const mrvi_settings *s,
                                  double *res, double *dual, int *on_chain,
                                  double *multi, char *msg, size_t len) {
  mrvi_step st;
  *res = *dual = *multi = INFINITY, *on_chain = -1, msg[0] = 0;
  int rc = mrvi_step_init(&st, m, s);
  if (rc < 0)
    return rc;
  const int nt = st.n_total, nu = st.n_unknowns;
  double *d = calloc((size_t)(4 * m->n + 17 * nt), sizeof *d);
  double *qs = d, *qf = qs + m->n, *ps = qf + m->n, *pf = ps + m->n;
  double *x = pf + m->n, *R = x + nt, *b = R + nt, *c = b + nt, *y = c + nt;
  /* three right-hand sides, their solves one by one and together, and the
   * blocked solve's workspace */
  double *B3 = y + nt, *Y1 = B3 + 3 * nt, *Y3 = Y1 + 3 * nt, *w = Y3 + 3 * nt;
  mrvi_bordered *bd = NULL;
  rc = d ? MRVI_OK : MRVI_ENOMEM;
  if (rc == 0) {
    test_initial_data(&st, qs, qf, ps, pf);
    st.increments = 1;
    mrvi_predict_free_flight(&st, x);
    for (int i = nu; i < nt; i++)
      x[i] = 0.1 * cos(1.3 * i);
    rc = mrvi_step_build_pattern(&st, x);
  }
  if (rc == 0) {
    mrvi_step_assemble(&st, x, R, 1);
    rc = mrvi_bordered_create(&st, &bd);
  }
  if (rc == 0)
    rc = mrvi_bordered_factor(bd, &st, msg, len);
  for (int i = 0; i < nt && d; i++) {
    b[i] = cos(0.3 + 1.1 * i);
    c[i] = sin(0.5 + 0.9 * i);
  }
  if (rc == 0)
    rc = mrvi_bordered_solve_transpose(bd, &st, c, y, msg, len);
  if (rc == 0)
    rc = mrvi_bordered_solve(bd, &st, b, x, msg, len);
  for (int i = 0; i < nt && rc == 0; i++) {
    B3[i] = c[i];
    B3[nt + i] = b[i];
    B3[2 * nt + i] = i % 2 ? c[i] : 0.0;
  }
  for (int k = 0; k < 3 && rc == 0; k++)
    rc = mrvi_bordered_solve_transpose(bd, &st, B3 + k * nt, Y1 + k * nt, msg,
                                       len);
  if (rc == 0)
    rc = mrvi_bordered_solve_transpose_n(bd, &st, 3, B3, Y3, w, msg, len);
  if (rc == 0) {
    double dm = 0.0, ym = 0.0;
    for (int i = 0; i < 3 * nt; i++) {
      dm = fmax(dm, fabs(Y3[i] - Y1[i]));
      ym = fmax(ym, fabs(Y1[i]));
    }
    *multi = dm / ym;
  }
  if (rc == 0) {
    double r = 0.0, scale = 0.0, cx = 0.0, yb = 0.0, sd = 0.0;
    for (int j = 0; j < nt; j++) {
      double rj = c[j], sc = fabs(c[j]);
      for (int e = st.Ap[j]; e < st.Ap[j + 1]; e++) {
        rj -= st.Ax[e] * y[st.Ai[e]];
        sc += fabs(st.Ax[e] * y[st.Ai[e]]);
      }
      r = fmax(r, fabs(rj));
      scale = fmax(scale, sc);
      cx += c[j] * x[j];
      yb += y[j] * b[j];
      sd += fabs(c[j] * x[j]) + fabs(y[j] * b[j]);
    }
    *res = r / scale, *dual = fabs(cx - yb) / sd;
    *on_chain = mrvi_bordered_on_chain(bd);
  }
  mrvi_bordered_free(bd);
  free(d);
  mrvi_step_free(&st);
  return rc;
}

mrvi_settings test_settings(const char *scheme, double dT, int p, double t_end,
                            double tol) {
  mrvi_settings s;
  mrvi_settings_default(&s);
  mrvi_settings_set_scheme(&s, scheme);
  s.macro_step = dT;
  s.micro_steps = p;
  s.t_end = t_end;
  s.newton_tol = tol;
  s.newton_max_iter = 50;
  return s;
}

mrvi_model *test_cart_pendulum(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 3);
  const double L = 0.2, a = acos(-1.0) / 6.0;
  const double xc[3] = {0, 0, 0}, vc[3] = {0.3, 0.1, 0};
  const double xb[3] = {L * sin(a), 0, -L * cos(a)}, vb[3] = {0, 1.2, 0};
  mrvi_model_add_particle(m, "cart", 5.0, MRVI_SLOW, xc, vc);
  mrvi_model_add_particle(m, "bob", 0.5, MRVI_FAST, xb, vb);
  const double g[3] = {0, 0, -9.81}, n[3] = {0, 0, 1};
  mrvi_model_set_gravity(m, g);
  mrvi_model_add_plane(m, 0, n, 0.0);
  mrvi_model_add_distance(m, 0, 1, NAN);
  mrvi_model_project_velocities(m, NULL);
  mrvi_model_set_name(m, "cart_pendulum");
  return m;
}

mrvi_model *test_spring_ring_rod(void) {
  mrvi_model *m = test_spring_ring();
  mrvi_model_add_distance(m, 0, 1, NAN);
  mrvi_model_project_velocities(m, NULL);
  return m;
}

double test_step_fd_error(struct mrvi_step *st, double *x, double *scale) {
  const int nt = st->n_total;
  double *J = calloc((size_t)nt * nt, sizeof *J);
  double *Rp = calloc((size_t)nt, sizeof *Rp),
         *Rm = calloc((size_t)nt, sizeof *Rm);
  for (int c = 0; c < nt; c++)
    for (int k = st->Ap[c]; k < st->Ap[c + 1]; k++)
      J[(size_t)st->Ai[k] * nt + c] += st->Ax[k];
  *scale = 0.0;
  for (size_t k = 0; k < (size_t)nt * nt; k++)
    *scale = fmax(*scale, fabs(J[k]));
  double worst = 0.0;
  for (int c = 0; c < nt; c++) {
    const double h = 1e-6, xc = x[c];
    x[c] = xc + h;
    mrvi_step_assemble(st, x, Rp, 0);
    x[c] = xc - h;
    mrvi_step_assemble(st, x, Rm, 0);
    x[c] = xc;
    for (int r = 0; r < nt; r++)
      worst =
          fmax(worst, fabs((Rp[r] - Rm[r]) / (2 * h) - J[(size_t)r * nt + c]));
  }
  free(J), free(Rp), free(Rm);
  return worst;
}
