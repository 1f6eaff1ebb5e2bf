/* The one-step map (q_k, p_k) -> (q_{k+1}, p_{k+1}) solved by Newton. */
#include "internal.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

struct mrvi_integrator {
  const mrvi_model *model;
  mrvi_settings settings;
  mrvi_step step;
  mrvi_newton *newton;
  double t0;            /* time of node k = 0 */
  long k;
  double *q, *p;        /* model order, n */
  double *qs, *qf, *ps, *pf; /* rate blocks of the state */
  double *x, *R, *dx;   /* unknowns, residual, Newton update */
  double *ps1;          /* ns */
  double *micro_q, *micro_p; /* p x nf */
  double *lambda;       /* constraint rows: multipliers at node k of the last step */
  double *micro_cres;   /* p: max |g| at micro nodes 1..p of the last step */
  int last_iterations;
  double last_residual;
  double t_assemble, t_solve;
  char errmsg[512];
};

static int fail(mrvi_integrator *it, int status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

static int fail(mrvi_integrator *it, int status, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(it->errmsg, sizeof it->errmsg, fmt, ap);
  va_end(ap);
  return status;
}

const char *mrvi_integrator_errmsg(const mrvi_integrator *it) {
  return it ? it->errmsg : "no integrator";
}

void mrvi_integrator_free(mrvi_integrator *it) {
  if (!it)
    return;
  mrvi_newton_free(it->newton);
  mrvi_step_free(&it->step);
  free(it->q);
  free(it->p);
  free(it->qs);
  free(it->qf);
  free(it->ps);
  free(it->pf);
  free(it->x);
  free(it->R);
  free(it->dx);
  free(it->ps1);
  free(it->micro_q);
  free(it->micro_p);
  free(it->lambda);
  free(it->micro_cres);
  free(it);
}

static double *alloc(size_t n) { return calloc(n > 0 ? n : 1, sizeof(double)); }

/* Split model-order (q, p) into the rate blocks. */
static void split_state(mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  for (int s = 0; s < m->n_slow; s++) {
    it->qs[s] = it->q[m->slow_index[s]];
    it->ps[s] = it->p[m->slow_index[s]];
  }
  for (int s = 0; s < m->n_fast; s++) {
    it->qf[s] = it->q[m->fast_index[s]];
    it->pf[s] = it->p[m->fast_index[s]];
  }
}

/* Predictor: free flight with the current momenta on both grids. */
static void predict(mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  const mrvi_step *st = &it->step;
  for (int s = 0; s < st->ns; s++)
    it->x[s] = it->qs[s] + st->dT * it->ps[s] / m->mass[m->slow_index[s]];
  for (int mm = 1; mm <= st->p; mm++)
    for (int s = 0; s < st->nf; s++)
      it->x[st->ns + (mm - 1) * st->nf + s] =
          it->qf[s] + mm * st->dt * it->pf[s] / m->mass[m->fast_index[s]];
}

static double norm_inf(const double *v, int n) {
  double r = 0.0;
  for (int i = 0; i < n; i++) {
    const double a = fabs(v[i]);
    if (isnan(a))
      return a;
    if (a > r)
      r = a;
  }
  return r;
}

/* Roundoff floor of the residual: its rows subtract momenta of size
 * M |q| / dt, so no iterate can push ||R|| below a few eps times that.  The
 * Newton test is ||R|| <= max(tol, floor); for the paper's set-ups the floor
 * is far below the tolerance (FPU, dt = 1e-3: about 1e-12). */
static double residual_floor(const mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  const mrvi_step *st = &it->step;
  double scale = 0.0;
  for (int s = 0; s < st->ns; s++) {
    const double M = m->mass[m->slow_index[s]];
    scale = fmax(scale, fabs(it->ps[s]) +
                            M * (fabs(it->qs[s]) + fabs(it->x[s])) / st->dT);
  }
  for (int s = 0; s < st->nf; s++) {
    double qmax = fabs(it->qf[s]);
    for (int mm = 1; mm <= st->p; mm++)
      qmax = fmax(qmax, fabs(it->x[st->ns + (mm - 1) * st->nf + s]));
    const double M = m->mass[m->fast_index[s]];
    scale = fmax(scale, fabs(it->pf[s]) + 4.0 * M * qmax / st->dt);
  }
  return 16.0 * DBL_EPSILON * scale;
}

int mrvi_integrator_create(const mrvi_model *m, const mrvi_settings *s,
                           mrvi_integrator **out, char *msg, size_t len) {
  *out = NULL;
  if (!m || !s) {
    mrvi_fmt(msg, len, "model and settings are required");
    return MRVI_EINVAL;
  }
  int st = mrvi_settings_check(s, msg, len);
  if (st < 0)
    return st;
  if (m->n == 0) {
    mrvi_fmt(msg, len, "the model has no coordinates");
    return MRVI_EMODEL;
  }
  mrvi_integrator *it = calloc(1, sizeof *it);
  if (!it) {
    mrvi_fmt(msg, len, "out of memory");
    return MRVI_ENOMEM;
  }
  it->model = m;
  it->settings = *s;
  if ((st = mrvi_step_init(&it->step, m, s)) < 0)
    goto oom;
  const size_t n = (size_t)m->n, ns = (size_t)m->n_slow,
               nf = (size_t)m->n_fast, p = (size_t)s->micro_steps,
               nu = (size_t)it->step.n_unknowns;
  it->q = alloc(n);
  it->p = alloc(n);
  it->qs = alloc(ns);
  it->ps = alloc(ns);
  it->qf = alloc(nf);
  it->pf = alloc(nf);
  it->x = alloc(nu);
  it->R = alloc(nu);
  it->dx = alloc(nu);
  it->ps1 = alloc(ns);
  it->micro_q = alloc(p * nf);
  it->micro_p = alloc(p * nf);
  it->lambda = alloc((size_t)m->constraint_rows);
  it->micro_cres = alloc(p);
  if (!it->q || !it->p || !it->qs || !it->ps || !it->qf || !it->pf ||
      !it->x || !it->R || !it->dx || !it->ps1 || !it->micro_q || !it->micro_p || !it->lambda || !it->micro_cres)
    goto oom;
  /* Initial state (q0, M v0) at t = 0. */
  for (size_t i = 0; i < n; i++) {
    it->q[i] = m->q0[i];
    it->p[i] = m->mass[i] * m->v0[i];
  }
  split_state(it);
  it->step.qs0 = it->qs;
  it->step.qf0 = it->qf;
  it->step.ps0 = it->ps;
  it->step.pf0 = it->pf;
  /* Pattern and symbolic analysis once per run. */
  predict(it);
  if ((st = mrvi_step_build_pattern(&it->step, it->x)) < 0)
    goto oom;
  mrvi_step_assemble(&it->step, it->x, it->R, 1);
  it->newton = mrvi_newton_create(it->step.n_unknowns, it->step.Ap,
                                  it->step.Ai, it->step.Ax, msg, len);
  if (!it->newton) {
    mrvi_integrator_free(it);
    return MRVI_ESINGULAR;
  }
  *out = it;
  return MRVI_OK;
oom:
  mrvi_integrator_free(it);
  mrvi_fmt(msg, len, "out of memory");
  return MRVI_ENOMEM;
}

int mrvi_integrator_set_state(mrvi_integrator *it, double t, const double *q,
                              const double *p) {
  const int n = it->model->n;
  for (int i = 0; i < n; i++)
    if (!isfinite(q[i]) || !isfinite(p[i]))
      return fail(it, MRVI_ENONFINITE, "state is not finite");
  memcpy(it->q, q, (size_t)n * sizeof *q);
  memcpy(it->p, p, (size_t)n * sizeof *p);
  split_state(it);
  it->t0 = t;
  it->k = 0;
  return MRVI_OK;
}

int mrvi_integrator_step(mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  mrvi_step *st = &it->step;
  const int nu = st->n_unknowns;
  const double tol = it->settings.newton_tol;
  const int max_it = it->settings.newton_max_iter;
  char msg[256] = "";

  predict(it);
  double t = mrvi_clock();
  mrvi_step_assemble(st, it->x, it->R, 1);
  it->t_assemble += mrvi_clock() - t;
  int iter = 0;
  double res = norm_inf(it->R, nu);
  while (!(res <= fmax(tol, residual_floor(it)))) {
    if (!isfinite(res) || iter == max_it) {
      it->last_iterations = iter;
      it->last_residual = res;
      return fail(it, isfinite(res) ? MRVI_ENEWTON : MRVI_ENONFINITE,
                  "step %ld (t = %.10g -> %.10g): Newton %s after %d "
                  "iterations, residual %.3e (tolerance %.3e, roundoff floor "
                  "%.1e)",
                  it->k + 1, it->t0 + (double)it->k * st->dT,
                  it->t0 + (double)(it->k + 1) * st->dT,
                  isfinite(res) ? "did not converge" : "produced non-finite values",
                  iter, res, tol, residual_floor(it));
    }
    t = mrvi_clock();
    int s = mrvi_newton_solve(it->newton, st->Ax, it->R, it->dx, msg,
                              sizeof msg);
    it->t_solve += mrvi_clock() - t;
    if (s < 0) {
      it->last_iterations = iter;
      it->last_residual = res;
      return fail(it, s, "step %ld (t = %.10g): %s, residual %.3e", it->k + 1,
                  it->t0 + (double)it->k * st->dT, msg, res);
    }
    for (int i = 0; i < nu; i++)
      it->x[i] -= it->dx[i];
    iter++;
    t = mrvi_clock();
    mrvi_step_assemble(st, it->x, it->R, 1);
    it->t_assemble += mrvi_clock() - t;
    res = norm_inf(it->R, nu);
  }
  it->last_iterations = iter;
  it->last_residual = res;

  /* Momenta at the new macro node and the fast micro nodes (eq:pkfm+). */
  mrvi_step_momenta(st, it->x, it->ps1, it->micro_p);
  const int ns = st->ns, nf = st->nf, p = st->p;
  memcpy(it->micro_q, it->x + ns, (size_t)p * (size_t)nf * sizeof(double));
  memcpy(it->qs, it->x, (size_t)ns * sizeof(double));
  memcpy(it->ps, it->ps1, (size_t)ns * sizeof(double));
  memcpy(it->qf, it->micro_q + (size_t)(p - 1) * (size_t)nf,
         (size_t)nf * sizeof(double));
  memcpy(it->pf, it->micro_p + (size_t)(p - 1) * (size_t)nf,
         (size_t)nf * sizeof(double));
  for (int s = 0; s < ns; s++) {
    it->q[m->slow_index[s]] = it->qs[s];
    it->p[m->slow_index[s]] = it->ps[s];
  }
  for (int s = 0; s < nf; s++) {
    it->q[m->fast_index[s]] = it->qf[s];
    it->p[m->fast_index[s]] = it->pf[s];
  }
  it->k++;
  return MRVI_OK;
}

double mrvi_integrator_time(const mrvi_integrator *it) {
  return it->t0 + (double)it->k * it->settings.macro_step;
}
long mrvi_integrator_step_index(const mrvi_integrator *it) { return it->k; }
const double *mrvi_integrator_q(const mrvi_integrator *it) { return it->q; }
const double *mrvi_integrator_p(const mrvi_integrator *it) { return it->p; }
const double *mrvi_integrator_micro_q(const mrvi_integrator *it) {
  return it->micro_q;
}
const double *mrvi_integrator_micro_p(const mrvi_integrator *it) {
  return it->micro_p;
}
const double *mrvi_integrator_lambda(const mrvi_integrator *it) {
  return it->lambda;
}
const double *mrvi_integrator_micro_constraint_residual(
    const mrvi_integrator *it) {
  return it->micro_cres;
}
int mrvi_integrator_last_iterations(const mrvi_integrator *it) {
  return it->last_iterations;
}
double mrvi_integrator_last_residual(const mrvi_integrator *it) {
  return it->last_residual;
}
int mrvi_integrator_system_size(const mrvi_integrator *it) {
  return it->step.n_unknowns;
}
long mrvi_integrator_system_nnz(const mrvi_integrator *it) {
  return it->step.nnz;
}
void mrvi_integrator_timing(const mrvi_integrator *it, double *assemble,
                            double *solve) {
  if (assemble)
    *assemble = it->t_assemble;
  if (solve)
    *solve = it->t_solve;
}
