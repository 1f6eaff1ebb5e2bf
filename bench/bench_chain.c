/* Chains: cost per macro step against the number of links, constrained and
 * unconstrained.
 *
 * The chain of systems/pendulum_chain.yaml grown to n links (2-D, gravity
 * (0, -9.81)): heavy links h_i (mass 2, slow) one apart along a line 45
 * degrees from the downward vertical, h_1 on a rod to the pivot at the
 * origin and h_{i+1} on a rod to h_i; each link carries a light mass l_i
 * (0.05, fast) 0.1 below it on a stiff slow spring (k = 2000; it touches a
 * slow particle), and consecutive light masses are joined by fast springs
 * (k = 2000, rest length the initial distance).  Three models:
 *   rods     the rods as distance constraints (particles + rods),
 *   springs  the same chain with stiff slow springs (k = 10^5, rest length
 *            1) in place of the rods: the unconstrained twin,
 *   rigid    n rigid bars (2-D bodies, length 1, mass 2, slow) on revolute
 *            joints, the first to the ground at the origin, each carrying
 *            a light mass on a spring to its lower end (a body point) and
 *            the light masses joined by fast springs.
 * Every model is run with midpoint-midpoint and trapezoidal-midpoint on the
 * path mrvi_solver_path picks (listed), rods and rigid bars also in the
 * null-space form (the rigid bars with the joint-reduced basis, and with
 * the numerical QR one as before it), springs also on the general path (the one
 * the constrained chains take). (explicit-slow is unstable here: the
 * attachments' slow springs have omega dT = 2.)  dT = 0.01, p = 10 by default.
 * The cases of one n alternate, --repeats rounds, best of them; each times
 * blocks of 20 macro steps (--horizon) from the initial state (the
 * integrator set back to it, so that the falling chain stays in its first
 * 0.2 s) until --steps steps and 0.3 s.  Then the exponent of the time per
 * macro step in n and the ratio rods / springs.  A measurement: no thresholds
 * (doc/performance/chains.md, "Chains").
 *
 * --trajectory K: instead, each n of the list runs one case (--case C, the
 * index in case_names, default the rigid bars) and one scheme for K
 * consecutive macro steps from the initial state (no reset: the chain
 * falls for K dT) and prints the Newton updates of every step, their mean
 * and largest, and the first step that failed.  --gravity G scales the
 * load (the tension at the chain's top, which limits dT), --tune NAME=VALUE
 * sets a tuning constant (doc/performance/chains.md, "The rigid chain at 1 000
 * links, continued"). */
#include "bench_util.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { MAX_N = 16, MAX_REPEATS = 9, N_CASES = 7, N_SCHEMES = 2 };
static long horizon = 20;     /* macro steps from the initial state, repeated */
static double gravity = 9.81; /* --gravity */
static const char *tune[8];   /* --tune NAME=VALUE */
static int n_tune;
#define MIN_CPU 0.3

/* Case c builds chain kind chain_of[c]. */
static const char *const case_names[N_CASES] = {
    "rods (multipliers)", "rods (null space)", "springs",
    "springs (general)",  "rigid bars",        "rigid bars (null space)",
    "rigid bars (QR)"};
static const int chain_of[N_CASES] = {0, 1, 2, 2, 3, 3, 3};
static const char *const scheme_names[N_SCHEMES] = {"midpoint-midpoint",
                                                    "trapezoidal-midpoint"};

static const char usage[] =
    "Usage: bench_chain [--quick] [--n N1,N2,...] [--repeats R]\n"
    "                   [--steps K] [--dT DT] [--p P] [--budget SECONDS]\n"
    "\n"
    "Pendulum chains of N links (default 10,30,100,300,1000): rods,\n"
    "the same with stiff springs in place of the rods, and rigid bars on\n"
    "revolute joints; midpoint-midpoint and trapezoidal-midpoint on the\n"
    "path chosen automatically (springs also on the general path, rods\n"
    "and rigid bars also in the null-space form); CPU\n"
    "time per macro step (at least K steps, default 3, and 0.3 s), best\n"
    "of R alternating rounds (default 3).\n"
    "A case slower than SECONDS per macro step (default 5) ends the larger\n"
    "N of that case.  --quick: N = 10,30, R = 1, K = 2.\n"
    "--trajectory K [--case C] [--scheme S]: case C (0 rods, 1 rods null\n"
    "space, 2 springs, 3 springs general, 4 rigid bars (default), 5 rigid\n"
    "bars null space (joint-reduced), 6 rigid bars null space with the\n"
    "numerical QR basis), scheme S (default midpoint-midpoint) for K\n"
    "consecutive macro steps from the initial state at each N: Newton\n"
    "updates per step.\n"
    "--gravity G: gravity G instead of 9.81 (the chain's tension at its\n"
    "top, about N G (2.05), is what limits dT: doc/performance.md).\n"
    "--tune NAME=VALUE: a tuning constant (up to 8).\n"
    "--horizon H: the timed blocks restart from the initial state every H\n"
    "macro steps (default 20; the 1 000-bar chain fails at its fifth step\n"
    "at dT = 0.01, so 4 once a step takes less than 0.1 s).\n"
    "--cases C1,C2,...: only these cases (numbered as for --case).\n";

static int bad_usage(void) {
  fputs(usage, stderr);
  return 1;
}

/* The settings of case cs, with the --tune constants. */
static int case_settings(int cs, const char *scheme, double dT, int p,
                         mrvi_settings *s, char *msg, size_t len) {
  mrvi_settings_default(s);
  mrvi_settings_set_scheme(s, scheme);
  s->macro_step = dT;
  s->micro_steps = p;
  s->t_end = 1e6 * dT;
  s->newton_tol = 1e-10;
  s->energy_warning = 0;
  s->constraint_form = chain_of[cs] == 1 || cs >= 5 ? MRVI_FORM_NULL_SPACE
                                                    : MRVI_FORM_MULTIPLIERS;
  s->tuning.nullspace_tree = cs != 6; /* 6: the numerical (QR) basis */
  s->solver = cs == 3 ? MRVI_SOLVER_GENERAL : MRVI_SOLVER_AUTO;
  for (int t = 0; t < n_tune; t++) {
    char name[64];
    const char *eq = strchr(tune[t], '=');
    if (!eq) {
      snprintf(msg, len, "--tune %s: not NAME=VALUE", tune[t]);
      return -1;
    }
    snprintf(name, sizeof name, "%.*s", (int)(eq - tune[t]), tune[t]);
    if (mrvi_settings_set_tuning(s, name, atof(eq + 1), msg, len) < 0)
      return -1;
  }
  return 0;
}

typedef struct result {
  int status; /* 0 ok, 1 failed, 3 not run */
  int n;      /* coordinates */
  double step, newton;
  char path[16];
  char message[200];
} result;

static result run_one(int cs, int links, const char *scheme, double dT, int p,
                      int steps) {
  result r;
  memset(&r, 0, sizeof r);
  r.status = 1;
  char msg[512];
  const int c = chain_of[cs];
  mrvi_model *m = bench_chain_model(c, links, gravity, msg, sizeof msg);
  if (!m) {
    snprintf(r.message, sizeof r.message, "%.190s", msg);
    return r;
  }
  mrvi_settings s;
  r.n = mrvi_model_n(m);
  mrvi_integrator *it = NULL;
  if (case_settings(cs, scheme, dT, p, &s, msg, sizeof msg) < 0 ||
      mrvi_integrator_create(m, &s, &it, msg, sizeof msg) < 0) {
    snprintf(r.message, sizeof r.message, "%.190s", msg);
    mrvi_model_free(m);
    return r;
  }
  if (bench_time_steps(it, m, steps, MIN_CPU, horizon, &r.step, &r.newton,
                       r.message, sizeof r.message) == 0)
    r.status = 0;
  snprintf(r.path, sizeof r.path, "%s", mrvi_integrator_solver_path(it));
  mrvi_integrator_free(it);
  mrvi_model_free(m);
  return r;
}

/* Case cs with scheme for K consecutive macro steps at each n of the list:
 * the Newton updates of every step. */
static int trajectory(const int *n_list, int n_n, int cs, const char *scheme,
                      double dT, int p, int K) {
  printf("# trajectory: %s, %s, %d consecutive macro steps from the initial "
         "state, Newton updates per step\n\n",
         case_names[cs], scheme, K);
  int *iters = malloc((size_t)K * sizeof *iters);
  if (!iters)
    return 1;
  for (int ni = 0; ni < n_n; ni++) {
    char msg[512];
    const int links = n_list[ni];
    mrvi_model *m =
        bench_chain_model(chain_of[cs], links, gravity, msg, sizeof msg);
    mrvi_integrator *it = NULL;
    if (!m) {
      printf("links %d: %s\n", links, msg);
      continue;
    }
    mrvi_settings s;
    if (case_settings(cs, scheme, dT, p, &s, msg, sizeof msg) < 0 ||
        mrvi_integrator_create(m, &s, &it, msg, sizeof msg) < 0) {
      printf("links %d: %s\n", links, msg);
      mrvi_model_free(m);
      continue;
    }
    int k = 0, worst = 0;
    long sum = 0;
    const double t0 = bench_cpu();
    for (; k < K; k++) {
      if (mrvi_integrator_step(it) < 0)
        break;
      iters[k] = mrvi_integrator_last_iterations(it);
      sum += iters[k];
      worst = iters[k] > worst ? iters[k] : worst;
    }
    const double cpu = bench_cpu() - t0;
    printf("links %d (%s): %d steps, %.3f updates per step, at most %d, "
           "%.3g s per step%s%s\n  ",
           links, mrvi_integrator_solver_path(it), k, k ? (double)sum / k : 0.0,
           worst, k ? cpu / k : 0.0, k < K ? "; failed: " : "",
           k < K ? mrvi_integrator_errmsg(it) : "");
    for (int j = 0; j < k; j++)
      printf("%d%s", iters[j], (j + 1) % 50 == 0 ? "\n  " : "");
    printf("\n");
    fflush(stdout);
    mrvi_integrator_free(it);
    mrvi_model_free(m);
  }
  free(iters);
  return 0;
}

int main(int argc, char **argv) {
  int n_list[MAX_N] = {10, 30, 100, 300, 1000}, n_n = 5, repeats = 3, steps = 3,
      p = 10, quick = 0, n_set = 0, traj = 0, traj_case = 4,
      only[N_CASES] = {0}, n_only = 0;
  double dT = 0.01, budget = 5.0;
  const char *traj_scheme = scheme_names[0];
  for (int i = 1; i < argc; i++) {
    const char *a = argv[i];
    int has = i + 1 < argc;
    if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
      fputs(usage, stdout);
      return 0;
    } else if (!strcmp(a, "--quick")) {
      quick = 1;
    } else if (!strcmp(a, "--n") && has) {
      if ((n_n = bench_parse_ints(argv[++i], n_list, MAX_N)) <= 0)
        return bad_usage();
      n_set = 1;
    } else if (!strcmp(a, "--p") && has) {
      if ((p = atoi(argv[++i])) < 1)
        return bad_usage();
    } else if (!strcmp(a, "--dT") && has) {
      if (bench_parse_positive(argv[++i], &dT) < 0)
        return bad_usage();
    } else if (!strcmp(a, "--trajectory") && has) {
      if ((traj = atoi(argv[++i])) < 1)
        return bad_usage();
    } else if (!strcmp(a, "--horizon") && has) {
      if ((horizon = atol(argv[++i])) < 1)
        return bad_usage();
    } else if (!strcmp(a, "--gravity") && has) {
      if (bench_parse_positive(argv[++i], &gravity) < 0)
        return bad_usage();
    } else if (!strcmp(a, "--tune") && has && n_tune < 8) {
      tune[n_tune++] = argv[++i];
    } else if (!strcmp(a, "--case") && has) {
      traj_case = atoi(argv[++i]);
      if (traj_case < 0 || traj_case >= N_CASES)
        return bad_usage();
    } else if (!strcmp(a, "--scheme") && has) {
      traj_scheme = argv[++i];
    } else if (!strcmp(a, "--cases") && has) {
      /* (case numbers from 0: bench_parse_ints takes positive ones) */
      const char *c = argv[++i];
      for (n_only = 0; *c; n_only++) {
        char *end;
        const long v = strtol(c, &end, 10);
        if (end == c || v < 0 || v >= N_CASES || (*end && *end != ','))
          return bad_usage();
        only[v] = 1;
        c = *end ? end + 1 : end;
      }
      if (n_only == 0)
        return bad_usage();
    } else if (!strcmp(a, "--budget") && has) {
      if (bench_parse_positive(argv[++i], &budget) < 0)
        return bad_usage();
    } else if (bench_repeats_steps(argc, argv, &i, MAX_REPEATS, &repeats,
                                   &steps) <= 0) {
      return bad_usage();
    }
  }
  if (quick) {
    if (!n_set) {
      n_n = 2;
      n_list[0] = 10;
      n_list[1] = 30;
    }
    repeats = 1;
    steps = 2;
  }
  if (traj) {
    printf("# mrvi %s  pendulum chains  dT = %g  p = %d  gravity %g  load "
           "average %.2f\n",
           mrvi_version(), dT, p, gravity, bench_load());
    return trajectory(n_list, n_n, traj_case, traj_scheme, dT, p, traj);
  }
  printf("# mrvi %s  pendulum chains  dT = %g  p = %d  at least %d macro "
         "steps and %g s  best of %d alternating rounds  load average %.2f "
         "at the start\n",
         mrvi_version(), dT, p, steps, MIN_CPU, repeats, bench_load());
  printf("# build: %s\n\n", bench_build());

  static result res[N_SCHEMES][N_CASES][MAX_N];
  int dead[N_SCHEMES][N_CASES] = {{0}};
  for (int ni = 0; ni < n_n; ni++) {
    for (int si = 0; si < N_SCHEMES; si++)
      for (int c = 0; c < N_CASES; c++)
        res[si][c][ni].status = 3;
    for (int r = 0; r < repeats; r++)
      for (int si = 0; si < N_SCHEMES; si++)
        for (int c = 0; c < N_CASES; c++) {
          if (dead[si][c] || (n_only && !only[c]))
            continue;
          result x = run_one(c, n_list[ni], scheme_names[si], dT, p, steps);
          result *b = &res[si][c][ni];
          if (b->status != 0 || (x.status == 0 && x.step < b->step))
            *b = x;
          if (x.status != 0) {
            fprintf(stderr, "%s %s n = %d: %s\n", scheme_names[si],
                    case_names[c], n_list[ni], x.message);
            dead[si][c] = 1;
          } else if (x.step > budget) {
            dead[si][c] = 1; /* larger n would take too long */
          }
        }
  }

  printf("| %-20s | %-18s | %6s | %6s | %-12s | %11s | %9s | %11s |\n",
         "scheme", "chain", "links", "n", "path", "step_s", "newton/st",
         "vs springs");
  printf("|----------------------|--------------------|-------:|-------:|"
         "--------------|------------:|----------:|------------:|\n");
  for (int si = 0; si < N_SCHEMES; si++)
    for (int c = 0; c < N_CASES; c++)
      for (int ni = 0; ni < n_n; ni++) {
        const result *x = &res[si][c][ni], *u = &res[si][2][ni];
        if (x->status == 3)
          continue;
        if (x->status != 0) {
          printf("| %-20s | %-18s | %6d | failed: %s |\n", scheme_names[si],
                 case_names[c], n_list[ni], x->message);
          continue;
        }
        double ratio = u->status == 0 ? x->step / u->step : NAN;
        printf("| %-20s | %-18s | %6d | %6d | %-12s | %11.4g | %9.2f | %11.2f "
               "|\n",
               scheme_names[si], case_names[c], n_list[ni], x->n, x->path,
               x->step, x->newton, ratio);
      }
  printf("\nExponents of the time per macro step in the number of links "
         "(least squares on log-log over the completed n; goal <= 1.1 and "
         "rods within 3x of springs)\n\n");
  printf("| %-20s | %-18s | %8s | %8s |\n|----------------------|----------"
         "----------|---------:|---------:|\n",
         "scheme", "chain", "exponent", "n fitted");
  for (int si = 0; si < N_SCHEMES; si++)
    for (int c = 0; c < N_CASES; c++) {
      double x[MAX_N], y[MAX_N];
      int k = 0;
      for (int ni = 0; ni < n_n; ni++)
        if (res[si][c][ni].status == 0) {
          x[k] = n_list[ni];
          y[k++] = res[si][c][ni].step;
        }
      if (k >= 2)
        printf("| %-20s | %-18s | %8.3f | %8d |\n", scheme_names[si],
               case_names[c], bench_exponent(x, y, k), k);
    }
  printf("\n# load average %.2f at the end\n", bench_load());
  return 0;
}
