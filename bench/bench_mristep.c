/* mrvi against its peer, SUNDIALS ARKODE MRIStep, on the FPU at p = 10.
 *
 * MRIStep integrates the FPU as a first-order system y = (q, v) (unit
 * masses) split into a slow part f_s = (0, -grad V) (the quartic coupling)
 * and a fast part f_f = (v, -grad W) (the stiff springs, W = omega^2/2
 * |q^f|^2, and the kinematics): MRI-GARK-ERK33a outside with the fixed
 * macro step dT, an explicit inner ARKStep (Knoth-Wolke ERK 3(3)) with the
 * fixed step dT/p.  mrvi runs midpoint-midpoint and explicit-slow with the
 * same dT and p on systems/fpu.yaml.
 *
 *  1. Error in q at t = 20 (Euclidean norm over the six coordinates)
 *     against RK4 with step 1e-5, and CPU time (median of --repeats, whole
 *     run including set-up) for several dT.
 *  2. The CPU-time ratio mrvi / MRIStep at matched errors 1e-2 .. 1e-5:
 *     log time interpolated linearly in log error between the two
 *     neighbouring dT of each method.
 *  3. A long run (t = 10^4, dT = 0.05, p = 10): the maximal relative
 *     energy error over the first and the second half of the run.
 * A measurement: no thresholds. */
#include "bench_util.h"

enum { MAX_OVERRIDES = 16 };

#include <arkode/arkode_arkstep.h>
#include <arkode/arkode_mristep.h>
#include <math.h>
#include <nvector/nvector_serial.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { MAX_DT = 24, MAX_REPEATS = 99, N = BENCH_FPU_N };

static const char usage[] =
    "Usage: bench_mristep [--quick] [--dT DT1,DT2,...] [--p P] [--t-end T]\n"
    "                     [--repeats R] [--long-t T] [--long-dT DT]\n"
    "                     [--file FPU.yaml] [--set KEY=VALUE]...\n"
    "\n"
    "Error in q at T (default 20) against RK4 (step 1e-5) vs CPU time for\n"
    "SUNDIALS MRIStep (MRI-GARK-ERK33a + fixed-step inner ERK, inner step\n"
    "dT/P) and mrvi midpoint-midpoint and explicit-slow with P micro steps\n"
    "(default 10); the time ratio at matched errors 1e-2..1e-5; and the\n"
    "relative energy error of a long run (default t = 1e4, dT = 0.05) over\n"
    "its first and second half.  Default dT = 0.4/2^k, k = 0..10; R = 3.\n"
    "--quick: dT = 0.2,0.1,0.05,0.025, R = 1, long run t = 100.\n"
    "--set applies a description override to the mrvi runs (repeatable).\n";

static int bad_usage(void) {
  fputs(usage, stderr);
  return 1;
}

/* ---- first-order FPU for SUNDIALS and RK4 ---- */
static int rhs_slow(sunrealtype t, N_Vector y, N_Vector ydot, void *user) {
  (void)t;
  (void)user;
  const double *x = N_VGetArrayPointer(y);
  double *d = N_VGetArrayPointer(ydot);
  for (int i = 0; i < N; i++)
    d[i] = 0.0;
  bench_fpu_force_slow(x, d + N);
  return 0;
}

static int rhs_fast(sunrealtype t, N_Vector y, N_Vector ydot, void *user) {
  (void)t;
  (void)user;
  const double *x = N_VGetArrayPointer(y);
  double *d = N_VGetArrayPointer(ydot);
  for (int i = 0; i < N; i++)
    d[i] = x[N + i];
  bench_fpu_force_fast(x, d + N);
  return 0;
}

/* Full right-hand side of y = (q, v). */
static void rhs_full(const double *y, double *d) {
  double f[N];
  for (int i = 0; i < N; i++)
    d[i] = y[N + i];
  bench_fpu_force_slow(y, d + N);
  bench_fpu_force_fast(y, f);
  for (int i = 0; i < N; i++)
    d[N + i] += f[i];
}

/* Classical RK4 from the initial state to t_end with n steps: q(t_end). */
static void rk4(double t_end, long n, double *q) {
  double y[2 * N], k1[2 * N], k2[2 * N], k3[2 * N], k4[2 * N], z[2 * N];
  double h = t_end / (double)n;
  bench_fpu_initial(y, y + N);
  for (long s = 0; s < n; s++) {
    rhs_full(y, k1);
    for (int i = 0; i < 2 * N; i++)
      z[i] = y[i] + 0.5 * h * k1[i];
    rhs_full(z, k2);
    for (int i = 0; i < 2 * N; i++)
      z[i] = y[i] + 0.5 * h * k2[i];
    rhs_full(z, k3);
    for (int i = 0; i < 2 * N; i++)
      z[i] = y[i] + h * k3[i];
    rhs_full(z, k4);
    for (int i = 0; i < 2 * N; i++)
      y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]);
  }
  memcpy(q, y, sizeof(double) * N);
}

/* ---- MRIStep ---- */
typedef struct mri {
  SUNContext ctx;
  N_Vector y;
  void *inner, *outer;
  MRIStepInnerStepper stepper;
  MRIStepCoupling coupling;
} mri;

static void mri_free(mri *r) {
  MRIStepFree(&r->outer);
  MRIStepInnerStepper_Free(&r->stepper);
  ARKStepFree(&r->inner);
  MRIStepCoupling_Free(r->coupling);
  if (r->y)
    N_VDestroy(r->y);
  SUNContext_Free(&r->ctx);
}

/* Set up MRIStep at the initial state with macro step dT, inner step
 * dT/p and stop time t_end.  0 or -1. */
static int mri_create(mri *r, double dT, int p, double t_end) {
  memset(r, 0, sizeof *r);
  if (SUNContext_Create(NULL, &r->ctx) != 0)
    return -1;
  r->y = N_VNew_Serial(2 * N, r->ctx);
  if (!r->y)
    return -1;
  double *y = N_VGetArrayPointer(r->y);
  bench_fpu_initial(y, y + N);
  r->inner = ARKStepCreate(rhs_fast, NULL, 0.0, r->y, r->ctx);
  if (!r->inner ||
      ARKStepSetTableNum(r->inner, ARKODE_DIRK_NONE, ARKODE_KNOTH_WOLKE_3_3) ||
      ARKStepSetFixedStep(r->inner, dT / p) ||
      ARKStepSetMaxNumSteps(r->inner, 100000) ||
      ARKStepCreateMRIStepInnerStepper(r->inner, &r->stepper))
    return -1;
  r->outer = MRIStepCreate(rhs_slow, NULL, 0.0, r->y, r->stepper, r->ctx);
  r->coupling = MRIStepCoupling_LoadTable(ARKODE_MRI_GARK_ERK33a);
  if (!r->outer || !r->coupling || MRIStepSetCoupling(r->outer, r->coupling) ||
      MRIStepSetFixedStep(r->outer, dT) ||
      MRIStepSetMaxNumSteps(r->outer, 2000000000L) ||
      MRIStepSetStopTime(r->outer, t_end))
    return -1;
  return 0;
}

/* MRIStep to t_end: q(t_end) and the CPU time.  0 or -1. */
static int mri_run(double dT, int p, double t_end, double *q, double *time,
                   long *fast_evals) {
  mri r;
  double t0 = bench_cpu();
  int st = mri_create(&r, dT, p, t_end);
  double t = 0.0;
  if (st == 0)
    st = MRIStepEvolve(r.outer, t_end, r.y, &t, ARK_NORMAL) < 0 ? -1 : 0;
  *time = bench_cpu() - t0;
  if (st == 0) {
    memcpy(q, N_VGetArrayPointer(r.y), sizeof(double) * N);
    long nfe = 0, nfi = 0;
    ARKStepGetNumRhsEvals(r.inner, &nfe, &nfi);
    *fast_evals = nfe;
  }
  mri_free(&r);
  return st;
}

/* ---- mrvi ---- */
static int mrvi_case(const mrvi_settings *base, const char *scheme, double dT,
                     int p, double t_end, mrvi_settings *s) {
  *s = *base;
  if (mrvi_settings_set_scheme(s, scheme) < 0)
    return -1;
  s->macro_step = dT;
  s->micro_steps = p;
  s->t_end = t_end;
  return 0;
}

/* mrvi to t_end: q(t_end) and the CPU time.  0 or -1. */
static int mrvi_go(const mrvi_model *m, const mrvi_settings *s, double *q,
                   double *time, long *iterations) {
  char msg[1024];
  double t0 = bench_cpu();
  mrvi_integrator *it = NULL;
  int st = mrvi_integrator_create(m, s, &it, msg, sizeof msg);
  long n = mrvi_settings_n_steps(s), iters = 0;
  for (long k = 0; st == 0 && k < n; k++) {
    st = mrvi_integrator_step(it);
    iters += mrvi_integrator_last_iterations(it);
  }
  *time = bench_cpu() - t0;
  if (st == 0)
    memcpy(q, mrvi_integrator_q(it), sizeof(double) * N);
  else
    fprintf(stderr, "bench_mristep: %s dT=%g: %s\n", s->scheme, s->macro_step,
            it ? mrvi_integrator_errmsg(it) : msg);
  *iterations = iters;
  mrvi_integrator_free(it);
  return st < 0 ? -1 : 0;
}

static double dist(const double *a, const double *b) {
  double s = 0.0;
  for (int i = 0; i < N; i++)
    s += (a[i] - b[i]) * (a[i] - b[i]);
  return sqrt(s);
}

/* CPU time at error e, interpolating log time linearly in log error between
 * the first pair of neighbouring dT (coarse to fine) that brackets e; NAN
 * when no pair does. */
static double time_at(const double *err, const double *time, int n, double e) {
  for (int i = 0; i + 1 < n; i++) {
    double a = err[i], b = err[i + 1];
    if (!(a > 0 && b > 0) || !isfinite(a))
      continue;
    if ((a >= e && b <= e) || (a <= e && b >= e)) {
      if (a == b)
        return time[i];
      double w = (log(e) - log(a)) / (log(b) - log(a));
      return exp(log(time[i]) + w * (log(time[i + 1]) - log(time[i])));
    }
  }
  return NAN;
}

enum { METHODS = 3 };
static const char *const method_names[METHODS] = {
    "MRIStep ERK33a", "mrvi midpoint-midpoint", "mrvi explicit-slow"};
static const char *const mrvi_schemes[METHODS] = {NULL, "midpoint-midpoint",
                                                  "explicit-slow"};

/* One run of method `j`; 0 or -1. */
static int run_method(int j, const mrvi_model *m, const mrvi_settings *base,
                      double dT, int p, double t_end, double *q, double *time,
                      long *work) {
  if (j == 0)
    return mri_run(dT, p, t_end, q, time, work);
  mrvi_settings s;
  if (mrvi_case(base, mrvi_schemes[j], dT, p, t_end, &s) < 0)
    return -1;
  return mrvi_go(m, &s, q, time, work);
}

/* Long run: max relative energy error over the first / second half. */
static int long_run(int j, const mrvi_model *m, const mrvi_settings *base,
                    double dT, int p, double t_end, double *e1, double *e2,
                    double *time) {
  long n = (long)ceil(t_end / dT - 1e-9);
  double q[N], v[N];
  bench_fpu_initial(q, v);
  double h0 = bench_fpu_energy(q, v);
  *e1 = *e2 = 0.0;
  double t0 = bench_cpu();
  int st = 0;
  if (j == 0) {
    mri r;
    st = mri_create(&r, dT, p, n * dT);
    double t;
    for (long k = 1; st == 0 && k <= n; k++) {
      if (MRIStepEvolve(r.outer, n * dT, r.y, &t, ARK_ONE_STEP) < 0) {
        st = -1;
        break;
      }
      const double *y = N_VGetArrayPointer(r.y);
      double e = fabs(bench_fpu_energy(y, y + N) - h0) / fabs(h0);
      double *half = 2 * k <= n ? e1 : e2;
      if (!(e <= *half)) /* NaN too */
        *half = e;
    }
    mri_free(&r);
  } else {
    mrvi_settings s;
    char msg[1024];
    mrvi_integrator *it = NULL;
    st = mrvi_case(base, mrvi_schemes[j], dT, p, n * dT, &s);
    if (st == 0)
      st = mrvi_integrator_create(m, &s, &it, msg, sizeof msg);
    for (long k = 1; st == 0 && k <= n; k++) {
      if ((st = mrvi_integrator_step(it)) < 0)
        break;
      /* unit masses: v = p */
      double e =
          fabs(bench_fpu_energy(mrvi_integrator_q(it), mrvi_integrator_p(it)) -
               h0) /
          fabs(h0);
      double *half = 2 * k <= n ? e1 : e2;
      if (!(e <= *half))
        *half = e;
    }
    if (st < 0)
      fprintf(stderr, "bench_mristep: long run %s: %s\n", s.scheme,
              it ? mrvi_integrator_errmsg(it) : msg);
    mrvi_integrator_free(it);
  }
  *time = bench_cpu() - t0;
  return st < 0 ? -1 : 0;
}

int main(int argc, char **argv) {
  const char *overrides[MAX_OVERRIDES];
  int n_over = 0;
  double dts[MAX_DT], t_end = 20.0, long_t = 1e4, long_dT = 0.05;
  int n_dt = 11, p = 10, repeats = 3, quick = 0, dt_set = 0, r_set = 0,
      lt_set = 0;
  const char *file = NULL;
  for (int i = 0; i < n_dt; i++)
    dts[i] = 0.4 / (double)(1 << i);
  for (int i = 1; i < argc; i++) {
    const char *a = argv[i];
    int has_value = i + 1 < argc;
    if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
      fputs(usage, stdout);
      return 0;
    } else if (!strcmp(a, "--quick")) {
      quick = 1;
    } else if (!strcmp(a, "--dT") && has_value) {
      if ((n_dt = bench_parse_doubles(argv[++i], dts, MAX_DT)) <= 0)
        return bad_usage();
      dt_set = 1;
    } else if (!strcmp(a, "--p") && has_value) {
      p = atoi(argv[++i]);
      if (p < 1)
        return bad_usage();
    } else if (!strcmp(a, "--t-end") && has_value) {
      if (bench_parse_positive(argv[++i], &t_end) < 0)
        return bad_usage();
    } else if (!strcmp(a, "--repeats") && has_value) {
      repeats = atoi(argv[++i]);
      if (repeats < 1 || repeats > MAX_REPEATS)
        return bad_usage();
      r_set = 1;
    } else if (!strcmp(a, "--long-t") && has_value) {
      if (bench_parse_positive(argv[++i], &long_t) < 0)
        return bad_usage();
      lt_set = 1;
    } else if (!strcmp(a, "--long-dT") && has_value) {
      if (bench_parse_positive(argv[++i], &long_dT) < 0)
        return bad_usage();
    } else if (!strcmp(a, "--set") && has_value) {
      if (n_over == MAX_OVERRIDES)
        return bad_usage();
      overrides[n_over++] = argv[++i];
    } else if (!strcmp(a, "--file") && has_value) {
      file = argv[++i];
    } else {
      return bad_usage();
    }
  }
  if (quick) {
    if (!dt_set) {
      const double q[] = {0.2, 0.1, 0.05, 0.025};
      n_dt = 4;
      memcpy(dts, q, sizeof q);
    }
    if (!r_set)
      repeats = 1;
    if (!lt_set)
      long_t = 100.0;
  }

  char msg[4096];
  mrvi_system *sys = NULL;
  if (!file)
    file = bench_system_path("fpu.yaml");
  if (mrvi_system_load(file, overrides, n_over, &sys, msg, sizeof msg) < 0) {
    fprintf(stderr, "bench_mristep: %s\n", msg);
    return 1;
  }
  const mrvi_model *m = sys->model;
  mrvi_settings base = sys->settings;
  if (mrvi_model_n(m) != N) {
    fprintf(stderr, "bench_mristep: %s is not the six-coordinate FPU\n", file);
    return 1;
  }

  /* Reference: RK4, step 1e-5; its own error estimated against step 2e-5
   * (RK4: error(2h) ~ 16 error(h)). */
  long n_ref = (long)ceil(t_end / 1e-5);
  double q_ref[N], q_half[N];
  rk4(t_end, n_ref, q_ref);
  rk4(t_end, n_ref / 2, q_half);
  printf("# mrvi %s vs SUNDIALS ARKODE MRIStep (%s)  FPU %s  p = %d  "
         "q(t = %g)\n",
         mrvi_version(), SUNDIALS_VERSION, file, p, t_end);
  printf("# build: %s\n", bench_build());
  printf("# reference RK4 h = %.0e (estimated error %.1e); CPU time median "
         "of %d, set-up included\n\n",
         t_end / (double)n_ref, dist(q_ref, q_half) / 15.0, repeats);
  printf("| %-22s | %9s | %7s | %10s | %10s | %12s |\n", "method", "dT",
         "steps", "error q", "CPU s", "work");
  printf("|------------------------|----------:|--------:|-----------:|"
         "-----------:|-------------:|\n");

  static double err[METHODS][MAX_DT], tim[METHODS][MAX_DT];
  int failures = 0;
  for (int j = 0; j < METHODS; j++) {
    for (int i = 0; i < n_dt; i++) {
      double t[MAX_REPEATS], q[N];
      long work = 0;
      int st = 0;
      for (int r = 0; r < repeats && st == 0; r++)
        st = run_method(j, m, &base, dts[i], p, t_end, q, &t[r], &work);
      if (st < 0) {
        err[j][i] = tim[j][i] = NAN;
        printf("| %-22s | %9g | %7s | %10s | %10s | %12s |\n", method_names[j],
               dts[i], "", "failed", "", "");
        continue;
      }
      err[j][i] = dist(q, q_ref);
      tim[j][i] = bench_median(t, repeats);
      printf("| %-22s | %9g | %7ld | %10.3e | %10.4f | %5ld %6s |\n",
             method_names[j], dts[i], (long)ceil(t_end / dts[i] - 1e-9),
             err[j][i], tim[j][i], work, j ? "newton" : "f_fast");
      fflush(stdout);
    }
  }

  /* Matched errors. */
  static const double levels[] = {1e-2, 1e-3, 1e-4, 1e-5};
  printf("\nCPU time at matched error (interpolated), ratio to MRIStep "
         "(> 1: mrvi slower)\n\n");
  printf("| %8s | %12s | %12s | %8s | %12s | %8s |\n", "error", "MRIStep s",
         "mid-mid s", "ratio", "expl-slow s", "ratio");
  printf("|---------:|-------------:|-------------:|---------:|-------------:|"
         "---------:|\n");
  for (int l = 0; l < 4; l++) {
    double t0 = time_at(err[0], tim[0], n_dt, levels[l]);
    double t1 = time_at(err[1], tim[1], n_dt, levels[l]);
    double t2 = time_at(err[2], tim[2], n_dt, levels[l]);
    printf("| %8.0e | %12.4g | %12.4g | %8.2f | %12.4g | %8.2f |\n", levels[l],
           t0, t1, t1 / t0, t2, t2 / t0);
  }
  printf("(nan: the error is outside the measured range of that method)\n");

  /* Long run. */
  printf("\nLong run: t = %g, dT = %g, p = %d; max relative energy error\n\n",
         long_t, long_dT, p);
  printf("| %-22s | %12s | %12s | %10s |\n", "method", "first half",
         "second half", "CPU s");
  printf("|------------------------|-------------:|-------------:|"
         "-----------:|\n");
  for (int j = 0; j < METHODS; j++) {
    double e1, e2, t;
    if (long_run(j, m, &base, long_dT, p, long_t, &e1, &e2, &t) < 0) {
      printf("| %-22s | %12s | %12s | %10.2f |\n", method_names[j], "failed",
             "", t);
      failures++;
      continue;
    }
    printf("| %-22s | %12.3e | %12.3e | %10.2f |\n", method_names[j], e1, e2,
           t);
    fflush(stdout);
  }
  printf("\nGoals (issue 8): explicit-slow faster than MRIStep (ratio < 1) "
         "at every error 1e-2..1e-5;\nmidpoint-midpoint faster at 1e-2..1e-4 "
         "and within 2x at 1e-5; mrvi energy error bounded over t = 1e4.\n");
  mrvi_system_free(sys);
  return failures ? 1 : 0;
}
