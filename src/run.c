/* Run driver: integrate a model to t_end and hand every macro node to an
 * observer (the HDF5 writer, a progress bar, a test). */
#include "internal.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Fill the observables of a record at (q, p). */
static void observe_state(const mrvi_model *m, mrvi_record *r) {
  mrvi_model_energy(m, r->q, r->p, &r->kinetic, &r->potential_slow,
                    &r->potential_fast);
  r->energy = r->kinetic + r->potential_slow + r->potential_fast;
  memset(r->linear_momentum, 0, sizeof r->linear_momentum);
  memset(r->angular_momentum, 0, sizeof r->angular_momentum);
  mrvi_model_momentum(m, r->q, r->p, r->linear_momentum, r->angular_momentum);
}

/* max |g(q)| over all constraints (0 without constraints). */
static double max_constraint_residual(const mrvi_model *m, const double *q) {
  if (m->constraint_rows == 0)
    return 0.0;
  double *g = malloc((size_t)m->constraint_rows * sizeof *g);
  if (!g)
    return NAN;
  mrvi_model_constraint_eval(m, q, g, NULL);
  double r = 0.0;
  for (int i = 0; i < m->constraint_rows; i++)
    r = fmax(r, fabs(g[i]));
  free(g);
  return r;
}

/* The first non-finite value of node k (q, p, then the energies), described
 * in msg; 0 when all are finite.  A run never stores or reports such a node
 * as a result: the integrator's state has left the range of doubles. */
static int nonfinite_state(const mrvi_model *m, const mrvi_record *r, char *msg,
                           size_t len) {
  const int n = mrvi_model_n(m);
  const char *what = NULL;
  int idx = -1;
  double v = 0.0;
  for (int i = 0; i < n && !what; i++) {
    if (!isfinite(r->q[i]))
      what = "q", idx = i, v = r->q[i];
    else if (!isfinite(r->p[i]))
      what = "p", idx = i, v = r->p[i];
  }
  if (!what) {
    const struct {
      const char *name;
      double v;
    } e[] = {{"kinetic energy", r->kinetic},
             {"slow potential", r->potential_slow},
             {"fast potential", r->potential_fast},
             {"energy", r->energy}};
    for (size_t i = 0; i < sizeof e / sizeof e[0] && !what; i++)
      if (!isfinite(e[i].v))
        what = e[i].name, v = e[i].v;
  }
  if (!what)
    return 0;
  char at[32] = "";
  if (idx >= 0)
    mrvi_fmt(at, sizeof at, "[%d]", idx);
  mrvi_fmt(msg, len,
           "non-finite state at macro node %ld (t = %g): %s%s = %g; the run "
           "stopped before storing it",
           r->k, r->t, what, at, v);
  return 1;
}

int mrvi_run(const mrvi_model *m, const mrvi_settings *s,
             mrvi_observer observer, void *user, volatile const int *stop_flag,
             mrvi_summary *sum) {
  return mrvi_run_from(m, s, NULL, observer, user, stop_flag, sum);
}

int mrvi_run_from(const mrvi_model *m, const mrvi_settings *s,
                  const mrvi_start *start, mrvi_observer observer, void *user,
                  volatile const int *stop_flag, mrvi_summary *sum) {
  mrvi_summary local;
  if (!sum)
    sum = &local;
  memset(sum, 0, sizeof *sum);
  const double t_start = mrvi_clock();
  mrvi_integrator *it = NULL;
  int st = mrvi_integrator_create(m, s, &it, sum->message, sizeof sum->message);
  if (st < 0) {
    sum->status = st;
    return st;
  }
  const long N = mrvi_settings_n_steps(s);
  const int nf = m->n_fast, p = s->micro_steps;
  const double dt = s->macro_step / p;
  const long k0 = start ? start->k : 0;
  if (start &&
      (st = mrvi_integrator_resume_state(it, k0, start->q, start->p)) < 0) {
    mrvi_fmt(sum->message, sizeof sum->message, "%s",
             mrvi_integrator_errmsg(it));
    mrvi_integrator_free(it);
    return sum->status = st;
  }
  if (k0 > N) {
    mrvi_fmt(sum->message, sizeof sum->message,
             "start node %ld is beyond the last node %ld", k0, N);
    mrvi_integrator_free(it);
    return sum->status = MRVI_EINVAL;
  }

  /* k = k0 (0 unless started from a node): the initial state and the single
   * micro node t_k0. */
  mrvi_record r = {0};
  r.k = k0;
  r.t = (double)k0 * s->macro_step;
  r.q = mrvi_integrator_q(it);
  r.p = mrvi_integrator_p(it);
  observe_state(m, &r);
  /* Initial fast part, in model order of the fast coordinates. */
  double *fq = malloc((2 * (size_t)nf + 1 + (size_t)p) * sizeof(double));
  if (!fq) {
    mrvi_integrator_free(it);
    mrvi_fmt(sum->message, sizeof sum->message, "out of memory");
    return sum->status = MRVI_ENOMEM;
  }
  double *fp = fq + nf;
  double *zeros = fp + nf; /* p micro residuals without constraints */
  for (int j = 0; j < p; j++)
    zeros[j] = 0.0;
  for (int j = 0; j < nf; j++) {
    fq[j] = r.q[m->fast_index[j]];
    fp[j] = r.p[m->fast_index[j]];
  }
  r.micro_count = 1;
  /* Node k0 > 0 as the last micro node of step k0-1 -> k0 (bitwise the
   * time an uninterrupted run stores for it). */
  r.micro_t0 =
      k0 > 0 ? ((double)(k0 - 1) * s->macro_step + dt) + (double)(p - 1) * dt
             : 0.0;
  r.micro_dt = dt;
  r.micro_q_fast = fq;
  r.micro_p_fast = fp;
  /* Constraints at the initial node. */
  r.n_lambda = m->constraint_rows;
  double cres0 = max_constraint_residual(m, r.q);
  r.constraint_residual = cres0;
  r.micro_constraint_residual = &cres0;
  r.hidden_constraint_residual = mrvi_model_hidden_residual(m, r.q, r.p);
  const double H0 = r.energy;
  const double scale = fabs(H0) > DBL_MIN ? fabs(H0) : 1.0;
  if (nonfinite_state(m, &r, sum->message, sizeof sum->message))
    st = MRVI_ENONFINITE;
  else if (observer && (st = observer(user, &r)) < 0)
    mrvi_fmt(sum->message, sizeof sum->message,
             "stopped by the observer at t = %g (%s)", r.t, mrvi_strerror(st));

  for (long k = k0; st >= 0 && k < N; k++) {
    if (stop_flag && *stop_flag) {
      st = MRVI_EINTERRUPTED;
      mrvi_fmt(sum->message, sizeof sum->message,
               "interrupted after %ld of %ld macro steps (t = %g)", k, N,
               mrvi_integrator_time(it));
      break;
    }
    st = mrvi_integrator_step(it);
    if (st < 0) {
      mrvi_fmt(sum->message, sizeof sum->message, "%s",
               mrvi_integrator_errmsg(it));
      break;
    }
    const int iters = mrvi_integrator_last_iterations(it);
    sum->steps++;
    sum->iterations_total += iters;
    if (iters > sum->iterations_max)
      sum->iterations_max = iters;
    r.k = k + 1;
    r.t = (double)(k + 1) * s->macro_step;
    r.q = mrvi_integrator_q(it);
    r.p = mrvi_integrator_p(it);
    observe_state(m, &r);
    r.iterations = iters;
    r.residual = mrvi_integrator_last_residual(it);
    r.micro_count = p;
    r.micro_t0 = (double)k * s->macro_step + dt;
    r.micro_q_fast = mrvi_integrator_micro_q(it);
    r.micro_p_fast = mrvi_integrator_micro_p(it);
    if (m->n_constraints > 0) {
      r.lambda_prev = mrvi_integrator_lambda(it);
      r.micro_constraint_residual =
          mrvi_integrator_micro_constraint_residual(it);
      r.constraint_residual = 0.0;
      for (int j = 0; j < p; j++)
        r.constraint_residual =
            fmax(r.constraint_residual, r.micro_constraint_residual[j]);
      r.hidden_constraint_residual = mrvi_model_hidden_residual(m, r.q, r.p);
    } else {
      r.micro_constraint_residual = zeros;
    }
    if (nonfinite_state(m, &r, sum->message, sizeof sum->message)) {
      st = MRVI_ENONFINITE;
      break;
    }
    const double err = fabs(r.energy - H0) / scale;
    if (err > sum->max_rel_energy_error || isnan(err))
      sum->max_rel_energy_error = err;
    if (observer && (st = observer(user, &r)) < 0)
      mrvi_fmt(sum->message, sizeof sum->message,
               "stopped by the observer at t = %g (%s)", r.t,
               mrvi_strerror(st));
  }
  mrvi_integrator_timing(it, &sum->assemble_time, &sum->solve_time);
  sum->roundoff_steps = mrvi_integrator_roundoff_steps(it);
  mrvi_integrator_krylov_stats(it, &sum->krylov);
  mrvi_integrator_free(it);
  free(fq);
  sum->wall_time = mrvi_clock() - t_start;
  sum->status = st < 0 ? st : MRVI_OK;
  return sum->status;
}
