/* Analysis on top of the integrator: trajectories kept in memory, errors
 * against a reference (paper §6.2), propagation matrices and linear
 * stability (paper §5, Lemma lemma:stability_slow). */
#include "integrator/integrator.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* ---------------------------------------------------------------------------
 * Trajectories
 * ------------------------------------------------------------------------- */
void mrvi_trajectory_free(mrvi_trajectory *tr) {
  if (!tr)
    return;
  free(tr->t);
  free(tr->q);
  free(tr->p);
  free(tr->micro_t);
  free(tr->micro_q);
  free(tr->micro_p);
  free(tr);
}

static int keep_record(void *user, const mrvi_record *r) {
  mrvi_trajectory *tr = user;
  const size_t n = (size_t)tr->n, nf = (size_t)tr->n_fast;
  tr->t[tr->n_macro] = r->t;
  memcpy(tr->q + (size_t)tr->n_macro * n, r->q, n * sizeof(double));
  memcpy(tr->p + (size_t)tr->n_macro * n, r->p, n * sizeof(double));
  tr->n_macro++;
  for (int i = 0; i < r->micro_count; i++) {
    const size_t row = (size_t)tr->n_micro;
    tr->micro_t[row] = r->micro_t0 + i * r->micro_dt;
    if (nf > 0) {
      memcpy(tr->micro_q + row * nf, r->micro_q_fast + (size_t)i * nf,
             nf * sizeof(double));
      memcpy(tr->micro_p + row * nf, r->micro_p_fast + (size_t)i * nf,
             nf * sizeof(double));
    }
    tr->n_micro++;
  }
  return 0;
}

/* Elements rows x cols (+ extra) as a byte count of doubles in *bytes; 0,
 * or -1 when it overflows size_t. */
static int doubles_bytes(size_t rows, size_t cols, size_t extra,
                         size_t *bytes) {
  size_t count;
  return __builtin_mul_overflow(rows, cols, &count) ||
                 __builtin_add_overflow(count, extra, &count) ||
                 __builtin_mul_overflow(count, sizeof(double), bytes)
             ? -1
             : 0;
}

int mrvi_trajectory_run(const mrvi_model *m, const mrvi_settings *s,
                        mrvi_trajectory **out, mrvi_summary *summary) {
  mrvi_summary local;
  if (!summary)
    summary = &local;
  memset(summary, 0, sizeof *summary);
  *out = NULL;
  int st = mrvi_settings_check(s, summary->message, sizeof summary->message);
  if (st < 0)
    return summary->status = st;
  const long N = mrvi_settings_n_steps(s);
  /* Every buffer size checked: N (< 2^53) x p x n overflows size_t for
   * absurd settings long before any allocation could succeed. */
  size_t rows = 0, b_t, b_q, b_mt, b_mq;
  if (doubles_bytes((size_t)N, (size_t)s->micro_steps, 1, &b_mt) < 0 ||
      doubles_bytes((size_t)N, 1, 1, &b_t) < 0 ||
      doubles_bytes(b_t / sizeof(double), (size_t)m->n, 0, &b_q) < 0 ||
      doubles_bytes(b_mt / sizeof(double), (size_t)m->n_fast, 1, &b_mq) < 0) {
    mrvi_fmt(summary->message, sizeof summary->message,
             "a trajectory of %ld macro steps (integrator.t_end / "
             "integrator.macro_step) x %d micro steps "
             "(integrator.micro_steps) of %d coordinates does not fit in "
             "memory",
             N, s->micro_steps, m->n);
    return summary->status = MRVI_ENOMEM;
  }
  rows = b_t / sizeof(double);
  mrvi_trajectory *tr = calloc(1, sizeof *tr);
  if (!tr)
    return summary->status = MRVI_ENOMEM;
  tr->n = m->n;
  tr->n_fast = m->n_fast;
  tr->macro_step = s->macro_step;
  tr->micro_steps = s->micro_steps;
  tr->t = malloc(b_t);
  tr->q = malloc(b_q ? b_q : sizeof(double));
  tr->p = malloc(b_q ? b_q : sizeof(double));
  tr->micro_t = malloc(b_mt);
  tr->micro_q = malloc(b_mq);
  tr->micro_p = malloc(b_mq);
  if (!tr->t || !tr->q || !tr->p || !tr->micro_t || !tr->micro_q ||
      !tr->micro_p) {
    mrvi_trajectory_free(tr);
    mrvi_fmt(summary->message, sizeof summary->message,
             "out of memory for %zu nodes", rows);
    return summary->status = MRVI_ENOMEM;
  }
  st = mrvi_run(m, s, keep_record, tr, NULL, summary);
  if (st < 0) {
    mrvi_trajectory_free(tr);
    return st;
  }
  *out = tr;
  return MRVI_OK;
}

/* Row of the reference at time t (its nodes are j h), or -1. */
static long ref_row(const mrvi_trajectory *ref, double t) {
  const double j = t / ref->macro_step;
  const long r = lround(j);
  if (fabs(j - (double)r) > 1e-6 || r < 0 || r >= ref->n_macro)
    return -1;
  return r;
}

int mrvi_trajectory_errors(const mrvi_model *m, const mrvi_trajectory *run,
                           const mrvi_trajectory *ref, mrvi_errors *e,
                           char *msg, size_t len) {
  memset(e, 0, sizeof *e);
  e->macro_step = run->macro_step;
  e->micro_steps = run->micro_steps;
  if (ref->micro_steps != 1 || ref->n != run->n) {
    mrvi_fmt(msg, len,
             "the reference must be a single-rate run (p = 1) of "
             "the same model");
    return MRVI_EINVAL;
  }
  const double dt = run->macro_step / run->micro_steps;
  const double ratio = dt / ref->macro_step;
  if (fabs(ratio - round(ratio)) > 1e-6 || round(ratio) < 1) {
    mrvi_fmt(msg, len,
             "the reference step %g does not divide the micro step %g",
             ref->macro_step, dt);
    return MRVI_EINVAL;
  }
  const int n = m->n;
  for (long k = 0; k < run->n_macro; k++) {
    const long r = ref_row(ref, run->t[k]);
    if (r < 0) {
      mrvi_fmt(msg, len, "the reference ends at t = %g before the run (t = %g)",
               ref->t[ref->n_macro - 1], run->t[k]);
      return MRVI_EINVAL;
    }
    double dq = 0, dp = 0, dqs = 0, dqf = 0, dps = 0, dpf = 0;
    for (int i = 0; i < n; i++) {
      const double a = run->q[k * n + i] - ref->q[r * n + i];
      const double b = run->p[k * n + i] - ref->p[r * n + i];
      dq += a * a;
      dp += b * b;
      if (m->rate[i] == MRVI_SLOW) {
        dqs += a * a;
        dps += b * b;
      } else {
        dqf += a * a;
        dpf += b * b;
      }
    }
    e->q_mac = fmax(e->q_mac, sqrt(dq));
    e->p_mac = fmax(e->p_mac, sqrt(dp));
    e->qs_mac = fmax(e->qs_mac, sqrt(dqs));
    e->qf_mac = fmax(e->qf_mac, sqrt(dqf));
    e->ps_mac = fmax(e->ps_mac, sqrt(dps));
    e->pf_mac = fmax(e->pf_mac, sqrt(dpf));
  }
  /* Micro nodes m = 1..p-1 of every macro step (eq:err_mic). */
  const int p = run->micro_steps, nf = m->n_fast;
  if (p == 1 || nf == 0) {
    e->q_mic = e->p_mic = NAN;
    return MRVI_OK;
  }
  for (long j = 1; j < run->n_micro; j++) {
    if (j % p == 0)
      continue; /* macro node */
    const long r = ref_row(ref, run->micro_t[j]);
    if (r < 0) {
      mrvi_fmt(msg, len, "no reference node at micro time t = %g",
               run->micro_t[j]);
      return MRVI_EINVAL;
    }
    double dq = 0, dp = 0;
    for (int i = 0; i < nf; i++) {
      const int c = m->fast_index[i];
      const double a = run->micro_q[j * nf + i] - ref->q[r * n + c];
      const double b = run->micro_p[j * nf + i] - ref->p[r * n + c];
      dq += a * a;
      dp += b * b;
    }
    e->q_mic = fmax(e->q_mic, sqrt(dq));
    e->p_mic = fmax(e->p_mic, sqrt(dp));
  }
  return MRVI_OK;
}

/* ---------------------------------------------------------------------------
 * Propagation matrix and linear stability
 * ------------------------------------------------------------------------- */
int mrvi_propagation_matrix(const mrvi_model *m, const mrvi_settings *s,
                            double *P, char *msg, size_t len) {
  mrvi_settings one = *s;
  one.t_end = one.macro_step;
  mrvi_integrator *it = NULL;
  int st = mrvi_integrator_create(m, &one, &it, msg, len);
  if (st < 0)
    return st;
  const int n = m->n, d = 2 * n;
  double *z = calloc((size_t)d, sizeof *z);
  if (!z) {
    mrvi_integrator_free(it);
    return MRVI_ENOMEM;
  }
  for (int j = 0; j < d && st == 0; j++) {
    memset(z, 0, (size_t)d * sizeof *z);
    z[j] = 1.0;
    st = mrvi_integrator_set_state(it, 0.0, z, z + n);
    if (st == 0)
      st = mrvi_integrator_step(it);
    if (st < 0) {
      mrvi_fmt(msg, len, "%s", mrvi_integrator_errmsg(it));
      break;
    }
    const double *q = mrvi_integrator_q(it), *pm = mrvi_integrator_p(it);
    for (int i = 0; i < n; i++) {
      P[i * d + j] = q[i];
      P[(n + i) * d + j] = pm[i];
    }
  }
  free(z);
  mrvi_integrator_free(it);
  return st;
}

int mrvi_oscillator_omega(const mrvi_model *m, double *omega, char *msg,
                          size_t len) {
  if (m->n != 1 || m->n_slow != 1) {
    mrvi_fmt(msg, len,
             "the stability study needs one slow coordinate (got %d "
             "coordinates, %d slow)",
             m->n, m->n_slow);
    return MRVI_EMODEL;
  }
  double g = 0.0, H = 0.0;
  mrvi_model_potential(m, MRVI_SLOW, m->q0, &g, &H);
  if (!(H > 0)) {
    mrvi_fmt(msg, len,
             "V''(q0) = %g: the oscillator needs a positive "
             "stiffness",
             H);
    return MRVI_EMODEL;
  }
  *omega = sqrt(H / MRVI_MASS(m, 0));
  return MRVI_OK;
}

int mrvi_stability_at(const mrvi_model *m, const mrvi_settings *s, double x,
                      double *det, double *trace, char *msg, size_t len) {
  double omega;
  int st = mrvi_oscillator_omega(m, &omega, msg, len);
  if (st < 0)
    return st;
  mrvi_settings one = *s;
  one.macro_step = x / omega;
  one.t_end = one.macro_step;
  double P[4];
  st = mrvi_propagation_matrix(m, &one, P, msg, len);
  if (st < 0)
    return st;
  *det = P[0] * P[3] - P[1] * P[2];
  *trace = P[0] + P[3];
  return MRVI_OK;
}

int mrvi_stability_limit(const mrvi_model *m, const mrvi_settings *s,
                         double x_max, double step, double *limit, char *msg,
                         size_t len) {
  double det, tr, prev = 0.0;
  for (double x = step; x <= x_max + 0.5 * step; x += step) {
    int st = mrvi_stability_at(m, s, x, &det, &tr, msg, len);
    if (st < 0)
      return st;
    if (fabs(tr) >= 2.0) {
      /* Bisection on |tr| = 2 between prev (stable) and x (unstable). */
      double lo = prev, hi = x;
      for (int k = 0; k < 60 && hi - lo > 1e-12 * hi; k++) {
        const double mid = 0.5 * (lo + hi);
        if ((st = mrvi_stability_at(m, s, mid, &det, &tr, msg, len)) < 0)
          return st;
        if (fabs(tr) >= 2.0)
          hi = mid;
        else
          lo = mid;
      }
      *limit = 0.5 * (lo + hi);
      return MRVI_OK;
    }
    prev = x;
  }
  *limit = INFINITY;
  return MRVI_OK;
}

double mrvi_stability_bound(mrvi_rule slow, int p) {
  const double pp = (double)p * p;
  if (slow.gamma == 0.5)
    return p == 1 ? INFINITY : sqrt(12.0 * pp / (pp - 1.0));
  if (slow.gamma == 0.0 || slow.gamma == 1.0)
    return sqrt(12.0 * pp / (pp + 2.0));
  return NAN;
}
