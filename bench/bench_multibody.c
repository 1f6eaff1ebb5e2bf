/* Multirate pays on a multibody system (doc/performance/multibody.md,
 * "Multibody"; doc/multibody.md): a description file (default
 * systems/flexible_pendulum.yaml; systems/robot_arm_payload.yaml is the
 * one where it pays) with its scheme (midpoint-midpoint in both) at p
 * micro steps against p = 1 (the same scheme single-rate).  Each run's
 * error is max |q(T) - q_ref(T)| at a fixed time T against a fine
 * single-rate reference, split into the slow and the fast coordinates; its
 * cost the process CPU time of creating the integrator and taking the
 * steps (the best of `repeat` runs), the micro nodes kept as `mrvi run`
 * keeps them with the file's output settings.  The table lists every run (a run
 * whose Newton fails is listed as failed and left out); the summary
 * matches errors: for each multirate run, the CPU time p = 1 needs for the
 * same error, interpolated log-log between the two single-rate runs that
 * bracket it, and the ratio; a run of either kind more accurate than a
 * finer one of its kind (the lucky phase of a fast oscillation at T, before
 * the step resolves it) is not matched.  A measurement, not a test: no
 * thresholds.
 *
 *   bench_multibody [--quick] [--p P] [--t T] [--repeat R] [--dt LIST]
 *                   [--halvings K] [--p1-general] [--set KEY=VALUE]...
 *                   [FILE.yaml]
 *   bench_multibody --cost [--t T] [--set KEY=VALUE]... [FILE.yaml]
 *
 * --dt: the multirate macro steps (default 0.02,0.01,0.005,0.0025);
 * --halvings: the single-rate steps 0.02 / 2^i, i < K (default 8), the
 * reference at 1/16 of the finest; --p1-general: the single-rate runs (and
 * the reference) on the general path, where it is faster than the
 * automatic choice (doc/performance/multibody.md, "Multibody").
 * --cost: CPU time per macro step (creation left out, the best of R runs)
 * at the file's macro step for p = 1, 2, 5, 10, 20, 40, with the solver
 * path each takes: how the cost of a macro step grows with p; and the
 * Newton updates per macro step and the CPU time per micro node and update
 * (per step and update at p = 1).
 *
 * Defaults: p = 10, T = 1, R = 3, systems/flexible_pendulum.yaml (through
 * $MRVI_SOURCE_ROOT or ".."); --quick: T = 0.2, R = 1, K = 6, the first
 * three macro steps. */
#include "bench_util.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char usage[] =
    "Usage: bench_multibody [--quick] [--p P] [--t T] [--repeat R] "
    "[--dt LIST] [--halvings K] [--p1-general] [--set KEY=VALUE]... "
    "[FILE.yaml]\n"
    "       bench_multibody --cost [--t T] [--repeat R] [--set KEY=VALUE]... "
    "[FILE.yaml]\n"
    "\n"
    "Error at time T against a fine reference and CPU time of the file's\n"
    "scheme with p micro steps and with p = 1, and the CPU ratio at\n"
    "matched error; default p = 10, T = 1, R = 3 repeats,\n"
    "systems/flexible_pendulum.yaml; --dt: the multirate macro steps\n"
    "(default 0.02,0.01,0.005,0.0025); --halvings K: single-rate steps\n"
    "0.02/2^i, i < K (default 8); --p1-general: p = 1 on the general\n"
    "path; --set applies a description-file\n"
    "override (e.g. integrator.constraints.form=null-space).\n"
    "--cost: CPU time per macro step against p at the file's macro step,\n"
    "with the solver path of each p, Newton updates per macro step and\n"
    "CPU time per micro node and update.\n";

/* The micro nodes a run keeps: as `mrvi run` with the file's output
 * settings (the last alone where output.micro and output.micro_slow are
 * off: settings.micro_last_only). */
static int keep_micro(const mrvi_system *sys, mrvi_integrator *it) {
  return mrvi_integrator_keep_micro(it, sys->output_micro ||
                                            sys->output_micro_slow);
}

/* N steps of dT with p micro steps from the file's initial state; q (n)
 * gets the last node; returns the CPU time or a negative value. */
static int p1_general; /* --p1-general: the single-rate runs on general */

static double run(const mrvi_system *sys, int p, double dT, long N, double *q) {
  mrvi_settings s = sys->settings;
  s.micro_steps = p;
  if (p == 1 && p1_general)
    s.solver = MRVI_SOLVER_GENERAL;
  s.macro_step = dT;
  s.t_end = (double)N * dT;
  const double t0 = bench_cpu();
  mrvi_integrator *it = NULL;
  char msg[512];
  if (mrvi_integrator_create(sys->model, &s, &it, msg, sizeof msg) != 0) {
    fprintf(stderr, "p = %d, dT = %g: %s\n", p, dT, msg);
    return -1.0;
  }
  if (keep_micro(sys, it) < 0) {
    fprintf(stderr, "p = %d, dT = %g: out of memory\n", p, dT);
    mrvi_integrator_free(it);
    return -1.0;
  }
  for (long k = 0; k < N; k++)
    if (mrvi_integrator_step(it) != 0) {
      fprintf(stderr, "p = %d, dT = %g: %s\n", p, dT,
              mrvi_integrator_errmsg(it));
      mrvi_integrator_free(it);
      return -1.0;
    }
  const double t = bench_cpu() - t0;
  memcpy(q, mrvi_integrator_q(it),
         (size_t)mrvi_model_n(sys->model) * sizeof *q);
  mrvi_integrator_free(it);
  return t;
}

/* --cost: CPU time per macro step (stepping only) against p, the best of
 * `repeat` runs of T / dT steps. */
static int cost_table(const mrvi_system *sys, double T, int repeat) {
  const int ps[] = {1, 2, 5, 10, 20, 40};
  const double dT = sys->settings.macro_step;
  const long N = lround(T / dT) > 0 ? lround(T / dT) : 1;
  printf("# %s, %s form, dT = %g, %ld macro steps; %s\n", sys->name,
         sys->settings.constraint_form == MRVI_FORM_NULL_SPACE ? "null-space"
                                                               : "multiplier",
         dT, N, bench_build());
  printf("%5s %16s %14s %14s %10s %16s\n", "p", "path", "ms/macro", "ms/micro",
         "updates", "us/node/update");
  for (size_t i = 0; i < sizeof ps / sizeof *ps; i++) {
    mrvi_settings s = sys->settings;
    s.micro_steps = ps[i];
    s.t_end = (double)N * dT;
    double best = INFINITY;
    long updates = 0; /* Newton iterations of the N steps */
    const char *path = "?";
    for (int r = 0; r < repeat; r++) {
      mrvi_integrator *it = NULL;
      char msg[512];
      if (mrvi_integrator_create(sys->model, &s, &it, msg, sizeof msg) != 0) {
        fprintf(stderr, "p = %d: %s\n", ps[i], msg);
        return -1;
      }
      path = mrvi_integrator_solver_path(it);
      if (keep_micro(sys, it) < 0) {
        fprintf(stderr, "p = %d: out of memory\n", ps[i]);
        mrvi_integrator_free(it);
        return -1;
      }
      const double t0 = bench_cpu();
      updates = 0;
      for (long k = 0; k < N; k++) {
        if (mrvi_integrator_step(it) != 0) {
          fprintf(stderr, "p = %d: %s\n", ps[i], mrvi_integrator_errmsg(it));
          mrvi_integrator_free(it);
          return -1;
        }
        updates += mrvi_integrator_last_iterations(it);
      }
      best = fmin(best, bench_cpu() - t0);
      mrvi_integrator_free(it);
    }
    const double u = updates > 0 ? (double)updates : NAN;
    printf("%5d %16s %14.4f %14.4f %10.2f %16.2f\n", ps[i], path,
           1e3 * best / (double)N, 1e3 * best / (double)N / ps[i],
           u / (double)N, 1e6 * best / u / ps[i]);
    fflush(stdout);
  }
  return 0;
}

enum { MAX_RUNS = 12 };

/* A comma-separated list of positive numbers into v (at most MAX_RUNS);
 * returns their count or -1. */
static int parse_list(const char *arg, double *v) {
  char buf[256];
  if (strlen(arg) >= sizeof buf)
    return -1;
  strcpy(buf, arg);
  int k = 0;
  for (char *tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
    if (k == MAX_RUNS || bench_parse_positive(tok, &v[k]) < 0)
      return -1;
    k++;
  }
  return k > 0 ? k : -1;
}

typedef struct row {
  int p;
  double dT, err, cpu;
  double err_s, err_f; /* the error on the slow and on the fast coordinates */
} row;

/* Best CPU time of `repeat` runs and the error against q_ref; a run that
 * fails (Newton diverges at a large step) is printed and kept out of the
 * matching (err NAN).  Returns -1 only for the reference's failure. */
static void measure(const mrvi_system *sys, int p, double dT, double T,
                    int repeat, const double *q_ref, double *q, row *r) {
  const long N = lround(T / dT);
  const int n = mrvi_model_n(sys->model);
  r->p = p, r->dT = dT, r->cpu = INFINITY, r->err = 0.0;
  r->err_s = r->err_f = 0.0;
  for (int i = 0; i < repeat; i++) {
    const double t = run(sys, p, dT, N, q);
    if (t < 0) {
      r->err = r->err_s = r->err_f = r->cpu = NAN;
      printf("%5d %12.6g %6ld %12s\n", p, dT, N, "failed");
      fflush(stdout);
      return;
    }
    r->cpu = fmin(r->cpu, t);
  }
  for (int i = 0; i < n; i++) {
    const double e = fabs(q[i] - q_ref[i]);
    double *part =
        mrvi_model_rate(sys->model, i) == MRVI_FAST ? &r->err_f : &r->err_s;
    *part = fmax(*part, e);
    r->err = fmax(r->err, e);
  }
  printf("%5d %12.6g %6ld %12.3e %12.3e %12.3e %12.4f\n", p, dT, N, r->err,
         r->err_s, r->err_f, r->cpu);
  fflush(stdout);
}

/* CPU time of the single-rate runs s (ns, dT decreasing) at error e:
 * log-log interpolation between the two that bracket e at the last
 * crossing, i.e. the step from which on every finer run (those measured)
 * is at least as accurate (a fast oscillation's error at T is not
 * monotone in dT until the step resolves it; a lucky coarse run does not
 * count); NAN outside. */
static double cpu_at(const row *s, int ns, double e) {
  for (int i = ns - 2; i >= 0; i--) {
    const double a = s[i].err, b = s[i + 1].err;
    if (isnan(a) || isnan(b))
      continue;
    if (a >= e && b <= e) {
      const double w = a == b ? 0.0 : log(e / a) / log(b / a);
      return exp(log(s[i].cpu) + w * log(s[i + 1].cpu / s[i].cpu));
    }
    if (b > e)
      return NAN; /* the finest runs are still above e */
  }
  return NAN;
}

int main(int argc, char **argv) {
  int p = 10, repeat = 3, cost = 0, n_sr = 8, n_mr = 4;
  double mr_dT[MAX_RUNS] = {0.02, 0.01, 0.005, 0.0025};
  double T = 1.0;
  const char *file = NULL, *sets[16];
  int n_sets = 0;
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
      fputs(usage, stdout);
      return 0;
    } else if (!strcmp(argv[i], "--quick")) {
      T = 0.2, repeat = 1, n_sr = 6, n_mr = n_mr < 3 ? n_mr : 3;
    } else if (!strcmp(argv[i], "--cost")) {
      cost = 1;
    } else if (!strcmp(argv[i], "--p") && i + 1 < argc) {
      p = atoi(argv[++i]);
    } else if (!strcmp(argv[i], "--t") && i + 1 < argc) {
      if (bench_parse_positive(argv[++i], &T) < 0)
        return fputs(usage, stderr), 2;
    } else if (!strcmp(argv[i], "--set") && i + 1 < argc && n_sets < 16) {
      sets[n_sets++] = argv[++i];
    } else if (!strcmp(argv[i], "--dt") && i + 1 < argc) {
      if ((n_mr = parse_list(argv[++i], mr_dT)) < 0)
        return fputs(usage, stderr), 2;
    } else if (!strcmp(argv[i], "--p1-general")) {
      p1_general = 1;
    } else if (!strcmp(argv[i], "--halvings") && i + 1 < argc) {
      n_sr = atoi(argv[++i]);
      if (n_sr < 2 || n_sr > MAX_RUNS)
        return fputs(usage, stderr), 2;
    } else if (!strcmp(argv[i], "--repeat") && i + 1 < argc) {
      repeat = atoi(argv[++i]);
    } else if (argv[i][0] != '-' && !file) {
      file = argv[i];
    } else {
      fputs(usage, stderr);
      return 2;
    }
  }
  if (p < 2 || repeat < 1)
    return fputs(usage, stderr), 2;
  if (!file)
    file = bench_system_path("flexible_pendulum.yaml");
  mrvi_system *sys = NULL;
  char msg[1024];
  if (mrvi_system_load(file, sets, n_sets, &sys, msg, sizeof msg) != 0) {
    fprintf(stderr, "%s\n", msg);
    return 1;
  }
  if (cost) {
    const int st = cost_table(sys, T, repeat);
    mrvi_system_free(sys);
    return st ? 1 : 0;
  }
  const int n = mrvi_model_n(sys->model);
  double *q_ref = malloc((size_t)n * sizeof *q_ref),
         *q = malloc((size_t)n * sizeof *q);
  /* Single-rate from dT = 0.02 down by halvings to where it resolves the
   * fast part (on flexible_pendulum its error falls as dT^2 from
   * dT = 6.25e-4 on, not monotonically above); the reference: p = 1 at a
   * step 2^-4 of the finest single-rate run. */
  double sr_dT[MAX_RUNS];
  for (int i = 0; i < n_sr; i++)
    sr_dT[i] = 0.02 / (double)(1L << i);
  const double ref_dT = sr_dT[n_sr - 1] / 16.0;
  printf("# %s, %s, T = %g, %s form; %s\n", sys->name, sys->settings.scheme, T,
         sys->settings.constraint_form == MRVI_FORM_NULL_SPACE ? "null-space"
                                                               : "multiplier",
         bench_build());
  printf("# reference: p = 1, dT = %g (%ld steps)%s\n", ref_dT,
         lround(T / ref_dT),
         p1_general ? "; every p = 1 run on the general path" : "");
  if (run(sys, 1, ref_dT, lround(T / ref_dT), q_ref) < 0)
    return 1;
  printf("%5s %12s %6s %12s %12s %12s %12s\n", "p", "dT", "steps", "error",
         "slow", "fast", "cpu [s]");
  row mr[MAX_RUNS], sr[MAX_RUNS];
  for (int i = 0; i < n_mr; i++)
    measure(sys, p, mr_dT[i], T, repeat, q_ref, q, &mr[i]);
  for (int i = 0; i < n_sr; i++)
    measure(sys, 1, sr_dT[i], T, repeat, q_ref, q, &sr[i]);
  printf("\n# matched error: p = 1's CPU time for each p = %d run's error "
         "(log-log between the bracketing p = 1 runs)\n",
         p);
  printf("%12s %12s %12s %14s %8s\n", "dT", "error", "cpu p", "cpu p=1 same",
         "ratio");
  for (int i = 0; i < n_mr; i++) {
    if (isnan(mr[i].err))
      continue;
    /* A multirate run more accurate than one at a smaller dT has a lucky
     * phase of a fast oscillation at T, as a coarse p = 1 run can (cpu_at):
     * outside the range where the error falls with dT, not matched. */
    int lucky = 0;
    for (int j = 0; j < n_mr; j++)
      lucky |= mr[j].dT < mr[i].dT && mr[j].err > mr[i].err;
    const double c1 = lucky ? NAN : cpu_at(sr, n_sr, mr[i].err);
    printf("%12.6g %12.3e %12.4f %14.4f %8.2f%s\n", mr[i].dT, mr[i].err,
           mr[i].cpu, c1, c1 / mr[i].cpu,
           lucky ? "  (a finer run is less accurate)" : "");
  }
  free(q_ref);
  free(q);
  mrvi_system_free(sys);
  return 0;
}
