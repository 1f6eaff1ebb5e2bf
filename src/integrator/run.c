/* Run driver: integrate a model to t_end and hand every macro node to an
 * observer (the HDF5 writer, a progress bar, a test). */
#include "integrator/integrator.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The potentials V and W compiled once per run (solver/terms.c): their
 * values at every node, bitwise mrvi_model_energy's, without its per-element
 * dispatch; a class of at least two chunks of tuning.thread_chunk elements
 * sums per chunk (on settings.threads threads), then the chunks in order
 * (mrvi_terms_set_value_chunks: the same bits for every thread count).
 * NULL entries (out of memory): mrvi_model_energy. */
typedef struct potentials {
  mrvi_terms *kc[2];
} potentials;

static void potentials_create(const mrvi_model *m, const mrvi_settings *s,
                              potentials *pot) {
  pot->kc[0] = pot->kc[1] = NULL;
  int *elems = malloc((size_t)(m->n_elements + 1) * sizeof *elems);
  for (int c = 0; elems && c < 2; c++) {
    int n = 0;
    for (int e = 0; e < m->n_elements; e++)
      if (m->erecs[e].potential == (mrvi_rate)c)
        elems[n++] = e;
    if (mrvi_terms_create_value(m, elems, n, &pot->kc[c]) < 0 ||
        mrvi_terms_set_value_chunks(pot->kc[c],
                                    mrvi_threads_resolve(s->threads),
                                    s->tuning.thread_chunk) < 0) {
      mrvi_terms_free(pot->kc[c]);
      pot->kc[c] = NULL;
    }
  }
  free(elems);
}

static void potentials_free(potentials *pot) {
  mrvi_terms_free(pot->kc[0]);
  mrvi_terms_free(pot->kc[1]);
}

/* Fill the observables of a record at (q, p). */
static void observe_state(const mrvi_model *m, const potentials *pot,
                          mrvi_record *r) {
  if (pot->kc[0] && pot->kc[1]) {
    mrvi_model_energy(m, r->q, r->p, &r->kinetic, NULL, NULL);
    r->potential_slow = mrvi_terms_value(pot->kc[0], r->q);
    r->potential_fast = mrvi_terms_value(pot->kc[1], r->q);
  } else {
    mrvi_model_energy(m, r->q, r->p, &r->kinetic, &r->potential_slow,
                      &r->potential_fast);
  }
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

/* Energy magnitude T + |V| + |W| of a record. */
static double energy_magnitude(const mrvi_record *r) {
  return fabs(r->kinetic) + fabs(r->potential_slow) + fabs(r->potential_fast);
}

/* The energy error of the run so far (mrvi_summary): max |H_k - H_0| over
 * the scale E_0 = T_0 + |V_0| + |W_0|, or when that is 0 over the largest
 * magnitude seen, or absolute when every energy was 0. */
static void energy_error(mrvi_summary *sum, double max_abs, double E0,
                         double max_mag) {
  sum->energy_scale_kind = E0 > 0 ? 0 : max_mag > 0 ? 1 : 2;
  sum->energy_scale = E0 > 0 ? E0 : max_mag > 0 ? max_mag : 1.0;
  sum->max_rel_energy_error = max_abs / sum->energy_scale;
}

/* "relative energy error 5.67" and its kind, for messages. */
static void describe_energy_error(const mrvi_summary *sum, char *buf,
                                  size_t len) {
  static const char *const kind[] = {
      "", " relative to the largest energy magnitude of the run (H_0 = 0)",
      " (absolute: every energy is 0)"};
  mrvi_fmt(buf, len, "%senergy error %.3g%s",
           sum->energy_scale_kind == 0 ? "relative " : "",
           sum->max_rel_energy_error, kind[sum->energy_scale_kind]);
}

/* After a failed step: when the energy had grown beyond the warning level,
 * say that the failure is probably an instability. */
static int instability_hint(mrvi_summary *sum, const mrvi_settings *s,
                            double t) {
  if (sum->steps == 0 || !(s->energy_warning > 0) ||
      !(sum->max_rel_energy_error > s->energy_warning))
    return 0;
  char err[160];
  describe_energy_error(sum, err, sizeof err);
  const size_t used = strlen(sum->message);
  mrvi_fmt(sum->message + used, sizeof sum->message - used,
           "; energy %s from %.6g to %.6g by t = %g (%s); the macro step %g "
           "is probably beyond the stability limit of this scheme; reduce "
           "macro_step",
           sum->energy_last > sum->energy_initial ? "grew" : "changed",
           sum->energy_initial, sum->energy_last, t, err, s->macro_step);
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
  /* The micro nodes each step hands to the observer: p, or the last. */
  const int rows =
      s->micro_last_only ? mrvi_integrator_keep_micro(it, 0) : s->micro_steps;
  if (rows < 0) {
    mrvi_fmt(sum->message, sizeof sum->message,
             "out of memory keeping the last micro node");
    mrvi_integrator_free(it);
    return sum->status = rows;
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
  if (start && start->torsion_angle &&
      start->n_torsion != mrvi_integrator_n_torsions(it)) {
    mrvi_fmt(sum->message, sizeof sum->message,
             "the start node has %d torsional spring branches, the model %d "
             "torsional springs",
             start->n_torsion, mrvi_integrator_n_torsions(it));
    mrvi_integrator_free(it);
    return sum->status = MRVI_EINVAL;
  }
  if (start && start->torsion_angle &&
      (st = mrvi_integrator_resume_torsion(it, start->torsion_angle)) < 0) {
    mrvi_fmt(sum->message, sizeof sum->message, "%s",
             mrvi_integrator_errmsg(it));
    mrvi_integrator_free(it);
    return sum->status = st;
  }
  if (start && start->chord_history &&
      (st = mrvi_integrator_resume_chord_history(it, start->n_chord,
                                                 start->chord_history)) < 0) {
    mrvi_fmt(sum->message, sizeof sum->message, "start node %ld: %s", k0,
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
  /* the integrator's array: each record sees the branches of its node */
  r.n_torsion = mrvi_integrator_n_torsions(it);
  r.torsion_angle = r.n_torsion > 0 ? mrvi_integrator_torsion_angle(it) : NULL;
  r.n_chord = mrvi_integrator_chord_history(it, r.chord_history);
  potentials pot;
  potentials_create(m, s, &pot);
  observe_state(m, &pot, &r);
  /* Initial fast part, in model order of the fast coordinates. */
  double *fq = malloc((2 * (size_t)nf + 1 + (size_t)p) * sizeof(double));
  if (!fq) {
    mrvi_integrator_free(it);
    potentials_free(&pot);
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
  const int resumed = start && start->energy;
  const double H0 = resumed ? start->energy[0] : r.energy;
  const double E0 = resumed ? start->energy[1] : energy_magnitude(&r);
  double max_abs = resumed ? start->energy[2] : 0.0;
  double max_mag = resumed ? start->energy[3] : E0;
  r.energy_running[0] = max_abs;
  r.energy_running[1] = max_mag;
  int hinted = 0; /* the failure message says the energy grew */
  sum->energy_initial = sum->energy_last = H0;
  energy_error(sum, max_abs, E0, max_mag);
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
      hinted = instability_hint(sum, s, mrvi_integrator_time(it));
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
    observe_state(m, &pot, &r);
    r.iterations = iters;
    r.residual = mrvi_integrator_last_residual(it);
    r.micro_count = rows;
    r.micro_t0 = rows == p ? (double)k * s->macro_step + dt : r.t;
    r.micro_q_fast = mrvi_integrator_micro_q(it);
    r.micro_p_fast = mrvi_integrator_micro_p(it);
    r.n_chord = mrvi_integrator_chord_history(it, r.chord_history);
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
      hinted = instability_hint(sum, s, r.t - s->macro_step);
      break;
    }
    const double err = fabs(r.energy - H0);
    if (err > max_abs || isnan(err))
      max_abs = err;
    max_mag = fmax(max_mag, energy_magnitude(&r));
    r.energy_running[0] = max_abs;
    r.energy_running[1] = max_mag;
    sum->energy_last = r.energy;
    energy_error(sum, max_abs, E0, max_mag);
    if (observer && (st = observer(user, &r)) < 0)
      mrvi_fmt(sum->message, sizeof sum->message,
               "stopped by the observer at t = %g (%s)", r.t,
               mrvi_strerror(st));
  }
  sum->timing_estimated =
      mrvi_integrator_timing(it, &sum->assemble_time, &sum->solve_time);
  sum->roundoff_steps = mrvi_integrator_roundoff_steps(it);
  mrvi_integrator_krylov_stats(it, &sum->krylov);
  mrvi_integrator_free(it);
  potentials_free(&pot);
  free(fq);
  sum->wall_time = mrvi_clock() - t_start;
  sum->status = st < 0 ? st : MRVI_OK;
  /* Warn about a large energy error, unless the failure message already
   * says it (instability_hint). */
  if (s->energy_warning > 0 && sum->max_rel_energy_error > s->energy_warning &&
      !hinted) {
    char err[160];
    describe_energy_error(sum, err, sizeof err);
    mrvi_fmt(sum->warning, sizeof sum->warning,
             "%s exceeds integrator.energy_warning = %g: the trajectory is "
             "probably inaccurate; the macro step %g is probably beyond the "
             "accuracy or stability range of the scheme %s; reduce macro_step",
             err, s->energy_warning, s->macro_step,
             s->scheme[0] ? s->scheme : "(custom)");
  }
  return sum->status;
}
