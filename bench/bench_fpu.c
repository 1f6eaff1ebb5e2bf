/* Computing-time study on the Fermi-Pasta-Ulam problem (paper §6.3).
 *
 * The micro step dt is fixed (default 0.001) and the number of micro steps
 * p varies over {1, 10, 100, 1000}, so the macro step is dT = p dt and every
 * run does the same number of micro steps.  For each scheme and p the table
 * gives the macro steps, the size of the Newton system, the Newton
 * iterations, the total wall time and the time per macro step, split into
 * assembly (residual + Jacobian) and linear solves.  No thresholds: this is
 * a measurement, not a test.
 *
 *   bench_fpu [--t-end T] [--dt DT] [--p 1,10,100,1000] [--file FPU.yaml]
 *             [SCHEME...|all]
 *
 * By default the FPU of DESIGN §5 (l = 3, omega^2 = 2500) is built with the
 * C API; --file loads a description file instead (its integrator settings
 * other than the scheme, dT, p and t_end are kept). */
#include "mrvi.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { MAX_P = 32, MAX_SCHEMES = 16 };

static const char usage[] =
    "Usage: bench_fpu [--t-end T] [--dt DT] [--p P1,P2,...] [--file FILE]\n"
    "                 [SCHEME...|all]\n"
    "\n"
    "FPU computing-time study: fixed micro step DT (default 0.001), p micro\n"
    "steps per macro step (default 1,10,100,1000), horizon T (default 10),\n"
    "schemes (default midpoint-midpoint; 'all' runs every named scheme).\n";

static int bad_usage(void) {
  fputs(usage, stderr);
  return 1;
}

/* Fill a law's parameter vector by parameter name. */
static int law_params(const char *law_name, const char *const *names,
                      const double *values, int count, double *params) {
  const mrvi_law *law = mrvi_law_find(law_name);
  if (!law)
    return -1;
  for (int i = 0; i < law->n_params; i++) {
    params[i] = 0.0;
    for (int j = 0; j < count; j++)
      if (!strcmp(law->param_names[i], names[j]))
        params[i] = values[j];
  }
  return 0;
}

/* The FPU of DESIGN §5: l = 3, unit masses, omega^2 = 2500,
 * V = 1/4 [(qs1 - qf1)^4 + sum_i (qs_{i+1} - qf_{i+1} - qs_i - qf_i)^4
 *          + (qs3 + qf3)^4],  W = omega^2/2 |qf|^2,
 * qs0 = (1,0,0), qf0 = (1/omega,0,0), vs0 = vf0 = (1,0,0). */
static mrvi_model *build_fpu(void) {
  enum { L = 3 };
  const double omega2 = 2500.0, omega = 50.0;
  mrvi_model *m = mrvi_model_create();
  if (!m)
    return NULL;
  int qs[L], qf[L];
  char name[16];
  int ok = mrvi_model_set_name(m, "fpu") == 0;
  for (int i = 0; i < L && ok; i++) {
    snprintf(name, sizeof name, "qs%d", i + 1);
    qs[i] = mrvi_model_add_coordinate(m, name, 1.0, MRVI_SLOW, i ? 0.0 : 1.0,
                                      i ? 0.0 : 1.0);
    ok = qs[i] >= 0;
  }
  for (int i = 0; i < L && ok; i++) {
    snprintf(name, sizeof name, "qf%d", i + 1);
    qf[i] = mrvi_model_add_coordinate(m, name, 1.0, MRVI_FAST,
                                      i ? 0.0 : 1.0 / omega, i ? 0.0 : 1.0);
    ok = qf[i] >= 0;
  }

  /* Slow quartic terms 1/4 (a^T q)^4. */
  double power[MRVI_LAW_MAX_PARAMS], linear[MRVI_LAW_MAX_PARAMS];
  const char *const power_names[] = {"coefficient", "exponent"};
  const char *const linear_names[] = {"stiffness"};
  ok = ok &&
       law_params("power", power_names, (double[]){0.25, 4.0}, 2, power) == 0;
  ok = ok &&
       law_params("linear", linear_names, (double[]){omega2}, 1, linear) == 0;
  if (ok) {
    int c[4] = {qs[0], qf[0]};
    double a[4] = {1.0, -1.0};
    ok = mrvi_model_add_term(m, MRVI_SLOW, 2, c, a, 0.0, "power", power) >= 0;
  }
  for (int i = 0; i + 1 < L && ok; i++) {
    int c[4] = {qs[i + 1], qf[i + 1], qs[i], qf[i]};
    double a[4] = {1.0, -1.0, -1.0, -1.0};
    ok = mrvi_model_add_term(m, MRVI_SLOW, 4, c, a, 0.0, "power", power) >= 0;
  }
  if (ok) {
    int c[2] = {qs[L - 1], qf[L - 1]};
    double a[2] = {1.0, 1.0};
    ok = mrvi_model_add_term(m, MRVI_SLOW, 2, c, a, 0.0, "power", power) >= 0;
  }
  /* Fast harmonic terms omega^2/2 qf_j^2. */
  for (int i = 0; i < L && ok; i++) {
    double a = 1.0;
    ok = mrvi_model_add_term(m, MRVI_FAST, 1, &qf[i], &a, 0.0, "linear",
                             linear) >= 0;
  }
  if (!ok) {
    fprintf(stderr, "bench_fpu: building the FPU failed: %s\n",
            mrvi_model_errmsg(m));
    mrvi_model_free(m);
    return NULL;
  }
  return m;
}

/* Parse "1,10,100" into p[]; returns the count or -1. */
static int parse_p_list(const char *s, int *p) {
  int n = 0;
  while (*s) {
    char *end;
    long v = strtol(s, &end, 10);
    if (end == s || v < 1 || v > 1000000 || n == MAX_P)
      return -1;
    p[n++] = (int)v;
    s = end;
    if (*s == ',')
      s++;
    else if (*s)
      return -1;
  }
  return n;
}

static int parse_positive(const char *s, double *out) {
  char *end;
  double v = strtod(s, &end);
  if (end == s || *end || !(v > 0))
    return -1;
  *out = v;
  return 0;
}

int main(int argc, char **argv) {
  double dt = 0.001, t_end = 10.0;
  int p_list[MAX_P] = {1, 10, 100, 1000}, n_p = 4;
  const char *schemes[MAX_SCHEMES];
  int n_schemes = 0;
  const char *file = NULL;

  for (int i = 1; i < argc; i++) {
    const char *a = argv[i];
    int has_value = i + 1 < argc;
    if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
      fputs(usage, stdout);
      return 0;
    } else if (!strcmp(a, "--t-end") && has_value) {
      if (parse_positive(argv[++i], &t_end) < 0)
        return bad_usage();
    } else if (!strcmp(a, "--dt") && has_value) {
      if (parse_positive(argv[++i], &dt) < 0)
        return bad_usage();
    } else if (!strcmp(a, "--p") && has_value) {
      if ((n_p = parse_p_list(argv[++i], p_list)) <= 0)
        return bad_usage();
    } else if (!strcmp(a, "--file") && has_value) {
      file = argv[++i];
    } else if (a[0] == '-') {
      return bad_usage();
    } else if (!strcmp(a, "all")) {
      n_schemes = 0;
      for (const char *const *s = mrvi_scheme_names(); *s; s++)
        if (n_schemes < MAX_SCHEMES)
          schemes[n_schemes++] = *s;
    } else if (n_schemes < MAX_SCHEMES) {
      schemes[n_schemes++] = a;
    }
  }
  if (n_schemes == 0)
    schemes[n_schemes++] = "midpoint-midpoint";

  /* The model: built here, or loaded from a description file. */
  char msg[4096];
  mrvi_system *sys = NULL;
  mrvi_model *own = NULL;
  const mrvi_model *m;
  mrvi_settings base;
  mrvi_settings_default(&base);
  base.newton_tol = 1e-9; /* paper, FPU */
  if (file) {
    if (mrvi_system_load(file, NULL, 0, &sys, msg, sizeof msg) < 0) {
      fprintf(stderr, "%s\n", msg);
      return 1;
    }
    m = sys->model;
    base = sys->settings;
  } else {
    if (!(own = build_fpu()))
      return 1;
    m = own;
  }

  printf("# mrvi %s  FPU  dt = %g  t_end = %g  n = %d (%d slow, %d fast)\n",
         mrvi_version(), dt, t_end, mrvi_model_n(m), mrvi_model_n_slow(m),
         mrvi_model_n_fast(m));
  printf("%-24s %5s %8s %8s %6s %8s %8s %9s %10s %10s %10s %9s\n", "scheme",
         "p", "dT", "steps", "size", "nnz", "newton", "total_s", "step_ms",
         "assem_ms", "solve_ms", "max_dH");

  int failures = 0;
  for (int si = 0; si < n_schemes; si++) {
    for (int pi = 0; pi < n_p; pi++) {
      mrvi_settings s = base;
      if (mrvi_settings_set_scheme(&s, schemes[si]) < 0) {
        fprintf(stderr, "bench_fpu: unknown scheme '%s'\n", schemes[si]);
        failures++;
        break;
      }
      s.micro_steps = p_list[pi];
      s.macro_step = dt * p_list[pi];
      s.t_end = t_end < s.macro_step ? s.macro_step : t_end;
      if (mrvi_settings_check(&s, msg, sizeof msg) < 0) {
        fprintf(stderr, "bench_fpu: %s\n", msg);
        failures++;
        continue;
      }

      /* Size of the Newton system, from a throw-away integrator. */
      mrvi_integrator *it = NULL;
      int size = -1;
      long nnz = -1;
      if (mrvi_integrator_create(m, &s, &it, msg, sizeof msg) == 0) {
        size = mrvi_integrator_system_size(it);
        nnz = mrvi_integrator_system_nnz(it);
      }
      mrvi_integrator_free(it);

      mrvi_summary sum;
      memset(&sum, 0, sizeof sum);
      int st = mrvi_run(m, &s, NULL, NULL, NULL, &sum);
      double per = sum.steps > 0 ? 1e3 / (double)sum.steps : 0.0;
      printf("%-24s %5d %8g %8ld %6d %8ld %8ld %9.3f %10.4f %10.4f %10.4f "
             "%9.2e\n",
             s.scheme, s.micro_steps, s.macro_step, sum.steps, size, nnz,
             sum.iterations_total, sum.wall_time, sum.wall_time * per,
             sum.assemble_time * per, sum.solve_time * per,
             sum.max_rel_energy_error);
      fflush(stdout);
      if (st < 0) {
        fprintf(stderr, "bench_fpu: %s p=%d: %s\n", s.scheme, s.micro_steps,
                sum.message[0] ? sum.message : mrvi_strerror(st));
        failures++;
      }
    }
  }
  mrvi_system_free(sys);
  mrvi_model_free(own);
  return failures ? 1 : 0;
}
