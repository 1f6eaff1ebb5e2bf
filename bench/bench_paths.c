/* The automatic path choice of constrained models against measurement
 * (doc/performance/paths.md, "Constrained paths: the choice by cost estimates"
 * and "Constrained paths: per-step costs"; doc/solver.md, "Paths"): for
 * every shipped constrained system, at p = 1 and the file's p, at the
 * file's macro step and a quarter of it, the CPU time per macro step
 * (stepping only, creation left out, no output) of the general path
 * (integrator.solver = general) and of schur-bordered (forced by
 * integrator.solver = structured and bordered_max and bordered_node_max
 * lifted) in the multiplier form, and of the general path in the
 * null-space form, interleaved (one run of each in turn, `repeat` times,
 * the best kept), with the structure each cost depends on: n_s, n_f, the
 * size and nonzeros of the multiplier form's step, the Newton updates per
 * macro step, the path the automatic choice takes and its two cost
 * estimates (mrvi_solver_path's reason), and the chosen path's time over
 * the faster one's.  A measurement, not a test.
 *
 *   bench_paths [--quick] [--repeat R] [--budget S] [--p LIST]
 *               [--dt-scale LIST] [--tuning NAME=VALUE]... [FILE.yaml]...
 *
 * --p: micro steps (0: the file's); --dt-scale: factors of the file's
 * macro step; --tuning: a tuning constant (MRVI_TUNING_LIST) for every run
 * and for the choice.  Each run takes about S seconds (default 0.1; the
 * number of macro steps from a 3-step calibration on the general path,
 * 3 … 20000); --quick: R = 1, p = 1 and the file's, two systems.  Defaults:
 * R = 3, p = 1 and the file's, scales 1 and 0.25, the shipped constrained
 * systems (through $MRVI_SOURCE_ROOT or ".."). */
#include "bench_util.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char usage[] =
    "Usage: bench_paths [--quick] [--repeat R] [--budget S] [--p LIST]\n"
    "                   [--dt-scale LIST] [--tuning NAME=VALUE]... "
    "[FILE.yaml]...\n"
    "\n"
    "CPU time per macro step of the general and schur-bordered paths\n"
    "(multiplier form) and of general in the null-space form, on the\n"
    "shipped constrained systems at p = 1 and the file's p (--p, 0: the\n"
    "file's), at the file's macro step and a quarter of it (--dt-scale),\n"
    "with the automatic choice, its cost estimates and the chosen path's\n"
    "time over the faster one's.\n";

static const char *const shipped[] = {
    "cart_pendulum.yaml",     "pendulum_chain.yaml", "spring_ring_rod.yaml",
    "triatomic.yaml",         "tutorial_rod.yaml",   "rigid_pendulum.yaml",
    "heavy_top.yaml",         "slider_crank.yaml",   "flexible_pendulum.yaml",
    "robot_arm_payload.yaml", "spacecraft.yaml",     "ocp_gantry_crane.yaml",
    "ocp_reorient.yaml"};

/* Tuning constants set by --tuning, for every run and the choice. */
static const char *tuning_names[16];
static double tuning_values[16];
static int n_tuning;

static void apply_tuning(mrvi_settings *s) {
  for (int i = 0; i < n_tuning; i++)
    mrvi_settings_set_tuning(s, tuning_names[i], tuning_values[i], NULL, 0);
}

enum { GENERAL, BORDERED, NULLSPACE, N_RUNS };

/* One run's figures. */
typedef struct {
  double ms;             /* CPU ms per macro step (best) */
  double its;            /* Newton updates per macro step */
  double asm_ms, sol_ms; /* of ms: assembling, and the linear solves
                            (mrvi_integrator_timing) */
  int size;
  long nnz;
  int ok;
} figures;

/* Settings of run kind k at p micro steps. */
static mrvi_settings settings_of(const mrvi_system *sys, int kind, int p,
                                 double scale, long N) {
  mrvi_settings s = sys->settings;
  apply_tuning(&s);
  s.micro_steps = p;
  s.macro_step *= scale;
  s.t_end = (double)N * s.macro_step;
  s.constraint_form =
      kind == NULLSPACE ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
  if (kind == BORDERED) {
    s.solver = MRVI_SOLVER_STRUCTURED; /* the structured path, whatever
                                          the cost estimates say */
    s.tuning.bordered_max = 1000000;
    s.tuning.bordered_node_max = 1000000;
  } else {
    s.solver = MRVI_SOLVER_GENERAL;
  }
  return s;
}

/* N macro steps of run kind `kind`; CPU seconds, or a negative value. */
static double run(const mrvi_system *sys, int kind, int p, double scale, long N,
                  figures *f) {
  const mrvi_settings s = settings_of(sys, kind, p, scale, N);
  mrvi_integrator *it = NULL;
  char msg[512];
  if (mrvi_integrator_create(sys->model, &s, &it, msg, sizeof msg) != 0)
    return -1.0;
  const char *path = mrvi_integrator_solver_path(it);
  if (kind == BORDERED && strcmp(path, "schur-bordered")) {
    mrvi_integrator_free(it);
    return -1.0;
  }
  long its = 0;
  const double t0 = bench_cpu();
  for (long k = 0; k < N; k++) {
    if (mrvi_integrator_step(it) != 0) {
      mrvi_integrator_free(it);
      return -1.0;
    }
    its += mrvi_integrator_last_iterations(it);
  }
  const double t = bench_cpu() - t0;
  f->its = (double)its / (double)N;
  double ta, ts;
  mrvi_integrator_timing(it, &ta, &ts);
  f->asm_ms = 1e3 * ta / (double)N;
  f->sol_ms = 1e3 * ts / (double)N;
  f->size = mrvi_integrator_system_size(it);
  f->nnz = mrvi_integrator_system_nnz(it);
  mrvi_integrator_free(it);
  return t;
}

/* One row: the three runs interleaved, `repeat` times. */
static void row(const mrvi_system *sys, int p, double scale, int repeat,
                double budget) {
  figures f[N_RUNS] = {{0}};
  /* calibration: 3 steps on the general path */
  figures cal = {0};
  const double tc = run(sys, GENERAL, p, scale, 3, &cal);
  long N = tc > 0 ? lround(budget / (tc / 3.0)) : 20;
  N = N < 3 ? 3 : N > 20000 ? 20000 : N;
  for (int k = 0; k < N_RUNS; k++)
    f[k].ms = INFINITY;
  for (int r = 0; r < repeat; r++)
    for (int k = 0; k < N_RUNS; k++) {
      figures g = {0};
      const double t = run(sys, k, p, scale, N, &g);
      if (t < 0)
        continue;
      g.ms = 1e3 * t / (double)N;
      g.ok = 1;
      if (g.ms < f[k].ms)
        f[k] = g;
    }
  /* the automatic choice and its estimates */
  mrvi_settings s = sys->settings;
  apply_tuning(&s);
  s.micro_steps = p;
  s.macro_step *= scale;
  s.constraint_form = MRVI_FORM_MULTIPLIERS;
  s.solver = MRVI_SOLVER_AUTO;
  char why[1024];
  const char *path = mrvi_solver_path(sys->model, &s, why, sizeof why);
  /* a and b from the step's size at p (a + p b) and the model */
  const int ns = mrvi_model_n_slow(sys->model),
            nf = mrvi_model_n_fast(sys->model);
  const int size = f[GENERAL].ok ? f[GENERAL].size : f[BORDERED].size;
  const char *faster = !f[BORDERED].ok                   ? "general"
                       : f[GENERAL].ms <= f[BORDERED].ms ? "general"
                                                         : "schur-bordered";
  const double chosen = !strcmp(path ? path : "", "schur-bordered")
                            ? f[BORDERED].ms
                            : f[GENERAL].ms;
  const double best = fmin(f[GENERAL].ms, f[BORDERED].ms);
  printf("%-18s %3d %8.3g %3d %3d %5d %7ld %4ld | %9.4f %4.2f | %9.4f %4.2f | "
         "%9.4f | %-14s %-14s %5.2f\n",
         sys->name, p, s.macro_step, ns, nf, size,
         f[GENERAL].ok ? f[GENERAL].nnz : -1L, N, f[GENERAL].ms, f[GENERAL].its,
         f[BORDERED].ok ? f[BORDERED].ms : NAN, f[BORDERED].its,
         f[NULLSPACE].ok ? f[NULLSPACE].ms : NAN, path ? path : "?", faster,
         chosen / best);
  const char *est = strstr(why, "estimate");
  printf("%-18s     # %s\n", "", est ? est : why);
  printf("%-18s     # assembling, solving [ms per step]: general %.4f, %.4f; "
         "schur-bordered %.4f, %.4f\n",
         "", f[GENERAL].asm_ms, f[GENERAL].sol_ms, f[BORDERED].asm_ms,
         f[BORDERED].sol_ms);
  fflush(stdout);
}

/* A number (a tuning constant's value); 0 or -1. */
static int parse_value(const char *arg, double *v) {
  char *end;
  *v = strtod(arg, &end);
  return end == arg || *end ? -1 : 0;
}

/* "1,0,10": micro step counts, 0 the file's; count or -1. */
static int parse_ps(const char *arg, int *ps) {
  int n = 0;
  const char *c = arg;
  while (n < 16) {
    char *end;
    const long v = strtol(c, &end, 10);
    if (end == c || v < 0 || v > 100000)
      return -1;
    ps[n++] = (int)v;
    if (*end == 0)
      return n;
    if (*end != ',')
      return -1;
    c = end + 1;
  }
  return -1;
}

int main(int argc, char **argv) {
  int repeat = 3, quick = 0, ps[16] = {1, 0}, n_p = 2, n_dt = 2;
  double budget = 0.1, dts[16] = {1.0, 0.25};
  const char *files[64];
  int n_files = 0;
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
      fputs(usage, stdout);
      return 0;
    } else if (!strcmp(argv[i], "--quick")) {
      quick = 1, repeat = 1;
    } else if (!strcmp(argv[i], "--repeat") && i + 1 < argc) {
      repeat = atoi(argv[++i]);
    } else if (!strcmp(argv[i], "--budget") && i + 1 < argc) {
      if (bench_parse_positive(argv[++i], &budget) < 0)
        return fputs(usage, stderr), 2;
    } else if (!strcmp(argv[i], "--p") && i + 1 < argc) {
      if ((n_p = parse_ps(argv[++i], ps)) < 1)
        return fputs(usage, stderr), 2;
    } else if (!strcmp(argv[i], "--dt-scale") && i + 1 < argc) {
      if ((n_dt = bench_parse_doubles(argv[++i], dts, 16)) < 1)
        return fputs(usage, stderr), 2;
    } else if (!strcmp(argv[i], "--tuning") && i + 1 < argc && n_tuning < 16) {
      char *eq = strchr(argv[++i], '=');
      mrvi_settings probe;
      mrvi_settings_default(&probe);
      if (!eq || (*eq = 0, parse_value(eq + 1, &tuning_values[n_tuning])) < 0 ||
          mrvi_settings_set_tuning(&probe, argv[i], tuning_values[n_tuning],
                                   NULL, 0) < 0)
        return fputs(usage, stderr), 2;
      tuning_names[n_tuning++] = argv[i];
    } else if (argv[i][0] != '-' && n_files < 64) {
      files[n_files++] = argv[i];
    } else {
      fputs(usage, stderr);
      return 2;
    }
  }
  if (repeat < 1)
    return fputs(usage, stderr), 2;
  static char names[sizeof shipped / sizeof *shipped][1024];
  if (n_files == 0) {
    const int n = quick ? 2 : (int)(sizeof shipped / sizeof *shipped);
    for (int i = 0; i < n; i++) {
      snprintf(names[i], sizeof names[i], "%s",
               bench_system_path(shipped[quick ? 8 + i : i]));
      files[n_files++] = names[i];
    }
  }
  printf("# bench_paths: ms per macro step (best of %d, interleaved), "
         "Newton updates per step; load %.2f; %s\n",
         repeat, bench_load(), bench_build());
  for (int i = 0; i < n_tuning; i++)
    printf("# tuning %s = %g\n", tuning_names[i], tuning_values[i]);
  printf("%-18s %3s %8s %3s %3s %5s %7s %4s | %9s %4s | %9s %4s | %9s | %-14s "
         "%-14s %5s\n",
         "system", "p", "dT", "ns", "nf", "size", "nnz", "N", "general", "its",
         "bordered", "its", "null-sp", "automatic", "faster", "ratio");
  for (int i = 0; i < n_files; i++) {
    mrvi_system *sys = NULL;
    char msg[1024];
    if (mrvi_system_load(files[i], NULL, 0, &sys, msg, sizeof msg) != 0) {
      fprintf(stderr, "%s\n", msg);
      return 1;
    }
    /* p = 0: the file's; each p once */
    int done[16], n_done = 0;
    for (int j = 0; j < n_p; j++) {
      const int p = ps[j] > 0 ? ps[j] : sys->settings.micro_steps;
      int seen = 0;
      for (int d = 0; d < n_done; d++)
        seen |= done[d] == p;
      if (seen)
        continue;
      done[n_done++] = p;
      for (int d = 0; d < n_dt; d++)
        row(sys, p, dts[d], repeat, budget);
    }
    mrvi_system_free(sys);
  }
  return 0;
}
