/* mrvi's analysis commands (paper §5-§6):
 *
 *   mrvi converge FILE   convergence study: errors (6.1) / (6.2) of the paper
 *                        against a single-rate reference, observed orders
 *   mrvi stability FILE  propagation matrix of the slow oscillator, largest
 *                        stable omega dT next to Lemma lemma:stability_slow
 *   mrvi timing FILE     computing-time study at fixed micro step (§6.3)
 *
 * Each prints a table and writes it to HDF5 (and CSV on request); the
 * layouts are in doc/output.md. */
#include "cli.h"

#include "batch/batch.h"
#include "io/io.h"
#include "mrvi.h"

#include <errno.h>
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

enum { EXIT_INPUT = 1, EXIT_RUN = 2, MAX_LIST = 64, MSG = 8192 };
/* converge: consecutive observed orders further apart than this are not in
 * the asymptotic range; without --dt0 at most this many halvings. */
#define ORDER_SPREAD 0.3
enum { MAX_HALVINGS = 16 };

const char mrvi_usage_converge[] =
    "Usage: mrvi converge FILE [options]\n"
    "\n"
    "Convergence study of the scheme in FILE: runs with halving macro steps\n"
    "at fixed p, errors on macro nodes (arXiv 2406.12991, eq. (6.1), also\n"
    "split into slow and fast parts) and fast micro nodes (eq. (6.2)) against\n"
    "a single-rate reference run with a tiny step, and the observed order\n"
    "between rows.\n"
    "The reference is computed with a step of the smallest micro step / 8\n"
    "(deepened as the chosen range goes down).\n"
    "\n"
    "Options:\n"
    "  --dt LIST           macro steps, e.g. 0.02,0.01,0.005\n"
    "  --dt0 X             largest macro step, halved --levels - 1 times\n"
    "  --levels N          number of macro steps in the table (default 4)\n"
    "                      Without --dt and --dt0 the range is chosen: macro\n"
    "                      steps halve from min(integrator.macro_step,\n"
    "                      t_end/4) until the observed orders of the last N\n"
    "                      rows agree within 0.3 (at most 16 halvings); the\n"
    "                      larger steps, also those whose runs fail, are\n"
    "                      skipped (and named).  When the\n"
    "                      orders of a table disagree by more than 0.3, a\n"
    "                      warning says the steps are not all in the\n"
    "                      asymptotic range.\n"
    "  --p LIST            micro steps per macro step, e.g. 5,10 (default:\n"
    "                      integrator.micro_steps)\n"
    "  --t-end T           horizon (default 0.5, as in the paper)\n"
    "  --reference FILE    reference run: an HDF5 file of `mrvi run` with p = "
    "1\n"
    "                      whose step divides every micro step\n"
    "  --ref-step H        step of the computed reference (default: smallest\n"
    "                      micro step / 8)\n"
    "  --ref-scheme NAME   scheme of the computed reference (default\n"
    "                      midpoint-midpoint, second order)\n"
    "  --cache DIR         keep computed references in DIR and reuse them\n"
    "                      (default .mrvi-cache); --no-cache keeps none\n"
    "  -o, --output OUT.h5 table file (default <name>-convergence.h5)\n"
    "  --csv OUT.csv       also write the table as CSV\n"
    "  -j, --jobs N        worker processes for the runs (default: the idle\n"
    "                      cores, as for mrvi batch; 1 runs them in this\n"
    "                      process); with more than one, each run is on one\n"
    "                      thread.  The table does not depend on N.  Under\n"
    "                      mpiexec -n R (built with MPI) the runs are spread\n"
    "                      over the R ranks, N jobs each (doc/batch.md)\n"
    "  -s, --set KEY=VALUE override a key of FILE (repeatable)\n"
    "  -q, --quiet         print only errors\n";

const char mrvi_usage_stability[] =
    "Usage: mrvi stability FILE [options]\n"
    "\n"
    "Linear stability of the slow harmonic oscillator in FILE (one slow\n"
    "coordinate, e.g. systems/oscillator.yaml).  The propagation matrix of\n"
    "one macro step comes from two runs of one step from unit states; the\n"
    "largest stable omega dT (|trace| < 2, det = 1) is found by a scan and\n"
    "bisection for the trapezoidal (alpha = gamma = 1) and the midpoint rule\n"
    "of the slow potential on the micro grid, next to the analytic bounds of\n"
    "Lemma lemma:stability_slow: 12 p^2/(p^2 + 2) and 12 p^2/(p^2 - 1) for\n"
    "(omega dT)^2.\n"
    "\n"
    "Options:\n"
    "  --p LIST            micro steps (default 1,2,3,5,10)\n"
    "  --max X             end of the scan of omega dT (default 20)\n"
    "  --step X            scan step (default 0.01)\n"
    "  --at X              also print det and trace at omega dT = X\n"
    "  -j, --jobs N        worker processes for the 2 x (number of p) limits\n"
    "                      and scans (default: the idle cores, as for mrvi\n"
    "                      batch; 1 runs them in this process); the table\n"
    "                      does not depend on N.  Under mpiexec -n R (built\n"
    "                      with MPI) they are spread over the R ranks, N\n"
    "                      jobs each\n"
    "  -o, --output OUT.h5 table file (default <name>-stability.h5)\n"
    "  -s, --set KEY=VALUE override a key of FILE (repeatable)\n"
    "  -q, --quiet         print only errors\n";

const char mrvi_usage_timing[] =
    "Usage: mrvi timing FILE [options]\n"
    "\n"
    "Computing-time study (paper §6.3): the micro step is fixed and p grows,\n"
    "so dT = p dt grows and the number of macro steps falls.  Prints total\n"
    "time, Newton iterations and the time per macro step spent assembling\n"
    "and solving, for each scheme and p.  Total time is measured; assembly\n"
    "and solve are estimated from sampled steps where the steps are short\n"
    "(doc/output.md).  On a loaded machine take --repeat 5: medians.\n"
    "\n"
    "Options:\n"
    "  --dt X              micro step (default 0.001)\n"
    "  --p LIST            (default 1,5,10,20,50,100,200,500,1000)\n"
    "  --schemes LIST      (default midpoint-midpoint,trapezoidal-midpoint,\n"
    "                      trapezoidal-trapezoidal)\n"
    "  --t-end T           horizon (default integrator.t_end of FILE)\n"
    "  --repeat N          run each scheme and p N times and report the\n"
    "                      median of each time (default 1)\n"
    "                      A run that fails (e.g. unstable at a large dT)\n"
    "                      gives a row of NaN and exit status 2.\n"
    "  -o, --output OUT.h5 table file (default <name>-timing.h5)\n"
    "  --csv OUT.csv       also write the table as CSV\n"
    "  -s, --set KEY=VALUE override a key of FILE (repeatable)\n"
    "  -q, --quiet         print only errors\n";

/* ---------------------------------------------------------------------------
 * Arguments
 * ------------------------------------------------------------------------- */
typedef struct args {
  const char *file;
  const char *sets[MAX_LIST];
  int n_sets;
  const char *opt[32][2]; /* (name, value) of other options */
  int n_opt;
  int quiet, no_cache;
} args;

/* Options that take a value, per command (NULL-terminated). */
static int takes_value(const char *name, const char *const *names) {
  for (int i = 0; names[i]; i++)
    if (!strcmp(name, names[i]))
      return 1;
  return 0;
}

static int parse(int argc, char **argv, const char *usage,
                 const char *const *names, args *a) {
  memset(a, 0, sizeof *a);
  for (int i = 1; i < argc; i++) {
    const char *arg = argv[i];
    if (!strcmp(arg, "-h") || !strcmp(arg, "--help")) {
      fputs(usage, stdout);
      return 0;
    }
    if (!strcmp(arg, "-q") || !strcmp(arg, "--quiet")) {
      a->quiet = 1;
      continue;
    }
    if (!strcmp(arg, "--no-cache")) {
      a->no_cache = 1;
      continue;
    }
    if (arg[0] != '-' || !arg[1]) {
      if (a->file) {
        fprintf(stderr, "mrvi %s: more than one FILE ('%s')\n", argv[0], arg);
        return -1;
      }
      a->file = arg;
      continue;
    }
    /* --name=value or --name value; -o and -s are short forms. */
    char name[64];
    const char *value = NULL;
    const char *eq = strchr(arg, '=');
    if (!strcmp(arg, "-o"))
      snprintf(name, sizeof name, "--output");
    else if (!strcmp(arg, "-s"))
      snprintf(name, sizeof name, "--set");
    else if (!strcmp(arg, "-j"))
      snprintf(name, sizeof name, "--jobs");
    else if (eq && !strncmp(arg, "--", 2)) {
      snprintf(name, sizeof name, "%.*s", (int)(eq - arg), arg);
      value = eq + 1;
    } else
      snprintf(name, sizeof name, "%s", arg);
    if (strcmp(name, "--set") && !takes_value(name, names)) {
      fprintf(stderr, "mrvi %s: unknown option '%s'\n", argv[0], arg);
      mrvi_cli_usage_short(argv[0], usage);
      return -1;
    }
    if (!value) {
      if (i + 1 >= argc) {
        fprintf(stderr, "mrvi %s: option '%s' needs a value\n", argv[0], arg);
        return -1;
      }
      value = argv[++i];
    }
    if (!strcmp(name, "--set")) {
      if (a->n_sets == MAX_LIST) {
        fprintf(stderr, "mrvi %s: too many --set options\n", argv[0]);
        return -1;
      }
      a->sets[a->n_sets++] = value;
    } else if (a->n_opt < 32) {
      a->opt[a->n_opt][0] = strdup(name);
      a->opt[a->n_opt][1] = value;
      a->n_opt++;
    }
  }
  if (!a->file) {
    fprintf(stderr, "mrvi %s: missing FILE\n", argv[0]);
    mrvi_cli_usage_short(argv[0], usage);
    return -1;
  }
  return 1;
}

static void args_free(args *a) {
  for (int i = 0; i < a->n_opt; i++)
    free((void *)a->opt[i][0]);
}

static const char *get(const args *a, const char *name) {
  const char *v = NULL;
  for (int i = 0; i < a->n_opt; i++)
    if (!strcmp(a->opt[i][0], name))
      v = a->opt[i][1];
  return v;
}

static int parse_double(const char *cmd, const char *opt, const char *s,
                        double *v) {
  char *end;
  errno = 0;
  *v = strtod(s, &end);
  if (errno || end == s || *end || !isfinite(*v)) {
    fprintf(stderr, "mrvi %s: %s: '%s' is not a finite number\n", cmd, opt, s);
    return -1;
  }
  return 0;
}

/* Comma-separated list of numbers; integers when `integer`. */
static int parse_list(const char *cmd, const char *opt, const char *s,
                      double *v, int max, int integer) {
  int n = 0;
  char buf[1024];
  snprintf(buf, sizeof buf, "%s", s);
  for (char *tok = strtok(buf, ","); tok; tok = strtok(NULL, ",")) {
    if (n == max) {
      fprintf(stderr, "mrvi %s: %s: at most %d values\n", cmd, opt, max);
      return -1;
    }
    if (parse_double(cmd, opt, tok, &v[n]) < 0)
      return -1;
    if (integer && (v[n] != floor(v[n]) || v[n] < 1)) {
      fprintf(stderr, "mrvi %s: %s: '%s' is not a positive integer\n", cmd, opt,
              tok);
      return -1;
    }
    if (!integer && !(v[n] > 0)) {
      fprintf(stderr, "mrvi %s: %s: '%s' must be positive\n", cmd, opt, tok);
      return -1;
    }
    n++;
  }
  if (n == 0) {
    fprintf(stderr, "mrvi %s: %s: empty list\n", cmd, opt);
    return -1;
  }
  return n;
}

static mrvi_system *load(const char *cmd, const args *a) {
  char *msg = malloc(MSG);
  mrvi_system *sys = NULL;
  if (!msg)
    return NULL;
  (void)cmd;
  if (mrvi_system_load(a->file, a->sets, a->n_sets, &sys, msg, MSG) < 0)
    fprintf(stderr, "%s\n", msg); /* file:line:col: message, once */
  free(msg);
  return sys;
}

static void default_output(char *buf, size_t len, const char *given,
                           const mrvi_system *sys, const char *what) {
  if (given)
    snprintf(buf, len, "%s", given);
  else
    snprintf(buf, len, "%s-%s.h5", sys->name, what);
}

/* Observed order between consecutive rows. */
static double order(double e0, double e1, double h0, double h1) {
  if (!(e0 > 0) || !(e1 > 0))
    return NAN;
  return log(e0 / e1) / log(h0 / h1);
}

/* Least-squares slope of log e against log h over the finite rows. */
static double fitted_order(int n, const double *h, const double *e) {
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  int m = 0;
  for (int i = 0; i < n; i++)
    if (e[i] > 0 && isfinite(e[i])) {
      const double x = log(h[i]), y = log(e[i]);
      sx += x;
      sy += y;
      sxx += x * x;
      sxy += x * y;
      m++;
    }
  if (m < 2)
    return NAN;
  return (m * sxy - sx * sy) / (m * sxx - sx * sx);
}

static void print_num(FILE *f, double v) {
  if (isnan(v))
    fprintf(f, " %9s", "-");
  else
    fprintf(f, " %9.3e", v);
}

static void print_order(FILE *f, double v) {
  if (isnan(v))
    fprintf(f, " %5s", "");
  else
    fprintf(f, " %5.2f", v);
}

/* ---------------------------------------------------------------------------
 * converge
 * ------------------------------------------------------------------------- */

typedef struct conv_table {
  int p, rows;
  double dT[MAX_LIST];
  mrvi_errors e[MAX_LIST];
} conv_table;

/* Largest difference between observed orders of e_q^mac (and of e_p^mac)
 * over rows [a, b) of a table (orders between consecutive rows; NaN orders
 * skipped); *col names the column.  0 when there are fewer than 2. */
static double order_spread(const conv_table *T, int a, int b,
                           const char **col) {
  double worst = 0.0;
  for (int c = 0; c < 2; c++) {
    double lo = INFINITY, hi = -INFINITY;
    for (int r = a + 1; r < b; r++) {
      const double o =
          c == 0
              ? order(T->e[r - 1].q_mac, T->e[r].q_mac, T->dT[r - 1], T->dT[r])
              : order(T->e[r - 1].p_mac, T->e[r].p_mac, T->dT[r - 1], T->dT[r]);
      if (isfinite(o)) {
        lo = fmin(lo, o);
        hi = fmax(hi, o);
      }
    }
    if (hi - lo > worst) {
      worst = hi - lo;
      if (col)
        *col = c == 0 ? "e_q^mac" : "e_p^mac";
    }
  }
  if (col && worst == 0.0)
    *col = "e_q^mac";
  return worst;
}

/* Reference run: read from `given`, from the cache, or computed (and cached).
 */
static mrvi_trajectory *reference(const char *cmd, const args *a,
                                  const mrvi_system *sys, const char *scheme,
                                  double h, double t_ref, int quiet) {
  char msg[1024];
  mrvi_trajectory *ref = NULL;
  const char *given = get(a, "--reference");
  if (given) {
    if (mrvi_trajectory_read(given, &ref, msg, sizeof msg) < 0) {
      fprintf(stderr, "mrvi %s: %s\n", cmd, msg);
      return NULL;
    }
    return ref;
  }
  mrvi_settings s = sys->settings;
  if (mrvi_settings_set_scheme(&s, scheme) < 0) {
    fprintf(stderr, "mrvi %s: unknown reference scheme '%s'\n", cmd, scheme);
    return NULL;
  }
  s.macro_step = h;
  s.micro_steps = 1;
  s.t_end = t_ref;
  const long steps = mrvi_settings_n_steps(&s);
  char path[2048] = "";
  const char *dir = get(a, "--cache") ? get(a, "--cache") : ".mrvi-cache";
  if (!a->no_cache) {
    snprintf(path, sizeof path, "%s/%s-%016llx-%s-h%.6e-t%.6e.h5", dir,
             sys->name, mrvi_model_hash(sys->model), scheme, h, t_ref);
    if (mrvi_trajectory_read(path, &ref, msg, sizeof msg) == 0) {
      if (!quiet)
        printf("reference: %s (cached)\n", path);
      return ref;
    }
  }
  if (!quiet)
    printf("reference: %s, single rate, h = %.4g, %ld steps%s%s\n", scheme, h,
           steps, path[0] ? " -> " : "", path);
  fflush(stdout);
  mrvi_summary sum;
  if (!path[0] || (mkdir(dir, 0777) < 0 && errno != EEXIST)) {
    if (path[0])
      fprintf(stderr,
              "mrvi %s: cannot create cache directory '%s'; the "
              "reference is not cached\n",
              cmd, dir);
    if (mrvi_trajectory_run(sys->model, &s, &ref, &sum) < 0) {
      fprintf(stderr, "mrvi %s: reference run failed: %s\n", cmd, sum.message);
      return NULL;
    }
    return ref;
  }
  /* Run through the HDF5 writer into the cache, then read it back. */
  mrvi_writer *w = NULL;
  mrvi_writer_options opt = {.system_name = sys->name, .every = 1};
  if (mrvi_writer_open(path, sys->model, &s, &opt, &w, msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi %s: %s\n", cmd, msg);
    return NULL;
  }
  int st = mrvi_run(sys->model, &s, mrvi_writer_observe, w, NULL, &sum);
  mrvi_writer_close(w, st < 0 ? sum.message : "completed", msg, sizeof msg);
  if (st < 0) {
    fprintf(stderr, "mrvi %s: reference run failed: %s\n", cmd, sum.message);
    remove(path);
    return NULL;
  }
  if (mrvi_trajectory_read(path, &ref, msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi %s: %s\n", cmd, msg);
    return NULL;
  }
  return ref;
}

/* Field of an mrvi_errors at byte offset `off`. */
static double field(const mrvi_errors *e, size_t off) {
  return *(const double *)((const char *)e + off);
}

/* One block of the table: four error columns, each with the observed order
 * against the previous row. */
static void print_block(const conv_table *T, const char *const names[4],
                        const size_t off[4], const char *note) {
  printf("%10s", "dT");
  for (int c = 0; c < 4; c++)
    printf(" %9s %5s", names[c], "order");
  printf("%s\n", note);
  for (int r = 0; r < T->rows; r++) {
    printf("%10.4g", T->dT[r]);
    for (int c = 0; c < 4; c++) {
      const double v = field(&T->e[r], off[c]);
      print_num(stdout, v);
      print_order(stdout, r ? order(field(&T->e[r - 1], off[c]), v,
                                    T->dT[r - 1], T->dT[r])
                            : NAN);
    }
    printf("\n");
  }
}

static void print_conv(const conv_table *T, const mrvi_system *sys,
                       double t_end) {
  static const char *const all[4] = {"e_q^mac", "e_p^mac", "e_q^mic",
                                     "e_p^mic"};
  static const char *const split[4] = {"e_qs", "e_qf", "e_ps", "e_pf"};
  const size_t all_off[4] = {
      offsetof(mrvi_errors, q_mac), offsetof(mrvi_errors, p_mac),
      offsetof(mrvi_errors, q_mic), offsetof(mrvi_errors, p_mic)};
  const size_t split_off[4] = {
      offsetof(mrvi_errors, qs_mac), offsetof(mrvi_errors, qf_mac),
      offsetof(mrvi_errors, ps_mac), offsetof(mrvi_errors, pf_mac)};
  printf("\n%s, %s, p = %d, t_end = %g\n", sys->name, sys->settings.scheme,
         T->p, t_end);
  print_block(T, all, all_off, "");
  print_block(T, split, split_off, "   (macro nodes, slow/fast)");
  double eq[MAX_LIST], ep[MAX_LIST];
  for (int r = 0; r < T->rows; r++) {
    eq[r] = T->e[r].q_mac;
    ep[r] = T->e[r].p_mac;
  }
  printf("fitted order on macro nodes: q %.2f, p %.2f\n",
         fitted_order(T->rows, T->dT, eq), fitted_order(T->rows, T->dT, ep));
}

/* The table into path; 0, or -1 with the message printed. */
static int write_conv(const char *cmd, const char *path, const conv_table *T,
                      int nt, const mrvi_system *sys, double t_end, double h,
                      const char *ref_scheme) {
  mrvi_convergence_rows by_p[MAX_LIST];
  for (int t = 0; t < nt; t++)
    by_p[t] = (mrvi_convergence_rows){T[t].p, T[t].rows, T[t].dT, T[t].e};
  const mrvi_convergence_table table = {
      .system = sys->name,
      .scheme = sys->settings.scheme,
      .t_end = t_end,
      .reference_step = h,
      .reference_scheme = ref_scheme,
      .n_p = nt,
      .by_p = by_p,
  };
  char msg[1024];
  if (mrvi_study_write_convergence(path, &table, msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi %s: %s\n", cmd, msg);
    return -1;
  }
  return 0;
}

static int write_conv_csv(const char *cmd, const char *path,
                          const conv_table *T, int nt) {
  FILE *f = fopen(path, "w");
  if (!f) {
    fprintf(stderr, "mrvi %s: cannot create '%s': %s\n", cmd, path,
            strerror(errno));
    return -1;
  }
  fprintf(f, "p,macro_step");
#define CSV_HEAD(dset, field) fprintf(f, "," #dset);
  MRVI_ERROR_COLUMNS(CSV_HEAD)
#undef CSV_HEAD
  fprintf(f, ",order_q_mac,order_p_mac\n");
  for (int t = 0; t < nt; t++)
    for (int r = 0; r < T[t].rows; r++) {
      const mrvi_errors *e = &T[t].e[r], *g = r ? &T[t].e[r - 1] : NULL;
      fprintf(f, "%d,%.17g", T[t].p, T[t].dT[r]);
#define CSV_ROW(dset, field) fprintf(f, ",%.17g", e->field);
      MRVI_ERROR_COLUMNS(CSV_ROW)
#undef CSV_ROW
      const double oq =
          g ? order(g->q_mac, e->q_mac, T[t].dT[r - 1], T[t].dT[r]) : NAN;
      const double op =
          g ? order(g->p_mac, e->p_mac, T[t].dT[r - 1], T[t].dT[r]) : NAN;
      fprintf(f, ",%.6g,%.6g\n", oq, op);
    }
  if (fclose(f) != 0) {
    fprintf(stderr, "mrvi %s: writing '%s' failed\n", cmd, path);
    return -1;
  }
  return 0;
}

/* One run of the study (macro step, p) and its errors: the record a
 * worker process returns (mrvi_batch_map). */
typedef struct conv_run {
  int run_failed, errors_failed;
  mrvi_errors e;
  char msg[1024];
} conv_run;

/* What the runs of rows first ... share. */
typedef struct conv_job {
  const mrvi_system *sys;
  const mrvi_trajectory *ref;
  const double *dts, *ps;
  int n_p;
  double t_end;
  int first;
} conv_job;

/* Item k: row first + k / n_p, p number k % n_p. */
static void conv_item(void *user, int k, void *out) {
  const conv_job *job = user;
  conv_run *r = out;
  const int i = job->first + k / job->n_p, j = k % job->n_p;
  mrvi_settings s = job->sys->settings;
  s.macro_step = job->dts[i];
  s.micro_steps = (int)job->ps[j];
  s.t_end = job->t_end;
  mrvi_trajectory *run = NULL;
  mrvi_summary sum;
  if (mrvi_trajectory_run(job->sys->model, &s, &run, &sum) < 0) {
    r->run_failed = 1;
    snprintf(r->msg, sizeof r->msg, "%s", sum.message);
    return;
  }
  if (mrvi_trajectory_errors(job->sys->model, run, job->ref, &r->e, r->msg,
                             sizeof r->msg) < 0)
    r->errors_failed = 1;
  mrvi_trajectory_free(run);
}

/* --jobs: worker processes for the runs (default: the idle cores, as
 * `mrvi batch` and --threads auto count them, mrvi_cores_idle; over MPI
 * ranks, each rank's share of its machine's cores), or -1 with the message
 * printed.  The results do not depend on threads (util.h), and forked
 * workers must not inherit a thread pool: with more than one job, or over
 * ranks (whose runs are always on forked workers), every run of sys is on
 * one thread. */
static int parse_jobs(const char *cmd, const args *a, mrvi_system *sys,
                      int ranks) {
  int jobs = ranks > 1 ? mrvi_batch_mpi_jobs() : mrvi_cores_idle();
  if (get(a, "--jobs")) {
    double v;
    if (parse_double(cmd, "--jobs", get(a, "--jobs"), &v) < 0)
      return -1;
    if (!(v >= 1 && v <= 4096 && v == floor(v))) {
      fprintf(stderr, "mrvi %s: --jobs must be an integer in [1, 4096]\n", cmd);
      return -1;
    }
    jobs = (int)v;
  }
  if (jobs > 1 || ranks > 1)
    sys->settings.threads = 1;
  return jobs;
}

/* Under an MPI launcher (mpiexec -n R mrvi converge|stability ...) every
 * rank runs the study in step: the same arguments, so the same calls of
 * the collectives (mrvi_batch_mpi_map hands the runs out over the ranks
 * and gives every rank every record); rank 0 alone computes the
 * reference, prints and writes: the other ranks' output goes to
 * /dev/null. */
static int with_ranks(const char *cmd, int (*study)(int, char **, int, int),
                      int argc, char **argv) {
  int rank = 0, ranks = 1;
  char msg[1024];
  if (mrvi_batch_mpi_begin(&rank, &ranks, msg, sizeof msg) < 0) {
    if (msg[0])
      fprintf(stderr, "mrvi %s: %s\n", cmd, msg);
    return EXIT_INPUT;
  }
  if (rank > 0) {
    fflush(NULL);
    FILE *null = fopen("/dev/null", "w");
    if (null) {
      dup2(fileno(null), 1);
      dup2(fileno(null), 2);
      fclose(null);
    }
  }
  return mrvi_batch_mpi_end(study(argc, argv, rank, ranks));
}

/* The system of FILE on every rank, or NULL on every rank (a rank that
 * cannot load it is named by rank 0). */
static mrvi_system *load_everywhere(const char *cmd, const args *a) {
  mrvi_system *sys = load(cmd, a);
  const int bad = mrvi_batch_mpi_agree(sys != NULL);
  if (bad < 0)
    return sys;
  if (bad > 0)
    fprintf(stderr,
            "mrvi %s: MPI rank %d cannot load %s: every rank reads FILE "
            "(and the files it names)\n",
            cmd, bad, a->file);
  mrvi_system_free(sys);
  return NULL;
}

static long gcd(long a, long b) { return b ? gcd(b, a % b) : a; }

static int converge(int argc, char **argv, int rank, int ranks) {
  static const char *const names[] = {
      "--dt",    "--dt0",       "--levels",   "--p",
      "--t-end", "--reference", "--ref-step", "--ref-scheme",
      "--cache", "--output",    "--csv",      "--jobs",
      NULL};
  args a;
  int pr = parse(argc, argv, mrvi_usage_converge, names, &a);
  if (pr <= 0) {
    args_free(&a);
    return pr == 0 ? 0 : EXIT_INPUT;
  }
  const char *cmd = "converge";
  int code = EXIT_INPUT;
  mrvi_system *sys = load_everywhere(cmd, &a);
  conv_table *T = calloc(MAX_LIST, sizeof *T);
  mrvi_trajectory *ref = NULL;
  if (!sys || !T)
    goto out;
  /* Macro steps, p, horizon. */
  double dts[MAX_LIST], ps[MAX_LIST], t_end = 0.5, levels = 4,
                                      dt0 = sys->settings.macro_step;
  int n_dt, n_p = 1;
  const int adaptive = !get(&a, "--dt") && !get(&a, "--dt0");
  ps[0] = sys->settings.micro_steps;
  if (get(&a, "--t-end") &&
      parse_double(cmd, "--t-end", get(&a, "--t-end"), &t_end) < 0)
    goto out;
  if (get(&a, "--dt0") &&
      parse_double(cmd, "--dt0", get(&a, "--dt0"), &dt0) < 0)
    goto out;
  if (get(&a, "--levels") &&
      (parse_double(cmd, "--levels", get(&a, "--levels"), &levels) < 0 ||
       levels < 2 || levels > MAX_LIST || levels != floor(levels))) {
    fprintf(stderr, "mrvi %s: --levels must be an integer in [2, %d]\n", cmd,
            MAX_LIST);
    goto out;
  }
  if (get(&a, "--dt")) {
    if ((n_dt = parse_list(cmd, "--dt", get(&a, "--dt"), dts, MAX_LIST, 0)) < 0)
      goto out;
  } else {
    /* Without --dt0 the range is chosen: halving from min(macro_step,
     * t_end/4) until the orders of the last `levels` rows agree. */
    n_dt = adaptive ? MAX_HALVINGS : (int)levels;
    if (adaptive)
      dt0 = fmin(dt0, t_end / 4);
    for (int i = 0; i < n_dt; i++)
      dts[i] = dt0 / (double)(1L << i);
  }
  if (get(&a, "--p") &&
      (n_p = parse_list(cmd, "--p", get(&a, "--p"), ps, MAX_LIST, 1)) < 0)
    goto out;
  const int jobs = parse_jobs(cmd, &a, sys, ranks);
  if (jobs < 0)
    goto out;
  if (!(t_end > 0)) {
    fprintf(stderr, "mrvi %s: --t-end must be positive\n", cmd);
    goto out;
  }
  for (int i = 0; i < n_dt; i++)
    if (dts[i] > t_end) {
      fprintf(stderr, "mrvi %s: macro step %g exceeds the horizon %g\n", cmd,
              dts[i], t_end);
      goto out;
    }
  /* Reference step: divides every micro step dT_i/p_j; default the
   * smallest micro step over lcm-compatible p, divided by 8. */
  double t_ref = 0.0;
  long lcm = 1;
  for (int j = 0; j < n_p; j++)
    lcm = lcm / gcd(lcm, (long)ps[j]) * (long)ps[j];
  for (int i = 0; i < n_dt; i++)
    t_ref = fmax(t_ref, ceil(t_end / dts[i] - 1e-9) * dts[i]);
  double h_fixed = NAN; /* --ref-step */
  if (get(&a, "--ref-step") &&
      parse_double(cmd, "--ref-step", get(&a, "--ref-step"), &h_fixed) < 0)
    goto out;
  const char *ref_scheme =
      get(&a, "--ref-scheme") ? get(&a, "--ref-scheme") : "midpoint-midpoint";
  if (!a.quiet) {
    printf("convergence study of %s (%s)\n", sys->name, a.file);
    if (adaptive)
      printf("macro steps: halving from %g until the observed orders of the "
             "last %d agree within %.1f\n",
             dts[0], (int)levels, ORDER_SPREAD);
    fflush(stdout);
  }
  code = EXIT_RUN;
  int rows = 0, done_to = 0; /* rows [0, done_to) have their runs */
  conv_run *runs = calloc((size_t)MAX_LIST * MAX_LIST, sizeof *runs);
  if (!runs)
    goto out;
  for (int i = 0; i < n_dt; i++) {
    /* A reference fine enough for row i: computed once for the fixed
     * table, deepened 4 halvings at a time for the chosen range. */
    const double h_row = dts[i] / (double)lcm / 8.0;
    if (!ref || (!get(&a, "--reference") && isnan(h_fixed) &&
                 ref->macro_step > h_row * (1 + 1e-9))) {
      const int deep = adaptive ? (i + 3 < n_dt ? i + 3 : n_dt - 1) : n_dt - 1;
      const double h = isnan(h_fixed) ? dts[deep] / (double)lcm / 8.0 : h_fixed;
      mrvi_trajectory_free(ref);
      ref = rank == 0 ? reference(cmd, &a, sys, ref_scheme, h, t_ref, a.quiet)
                      : NULL;
      if (mrvi_batch_mpi_share_trajectory(&ref) < 0) {
        code = EXIT_INPUT;
        free(runs);
        goto out;
      }
    }
    if (i >= done_to) {
      /* The runs of rows i .. to-1 at once, on --jobs processes: rows this
       * reference is fine enough for, and with the chosen range none past
       * a row that may end the study (no run is wasted). */
      int to = i + 1;
      while (to < n_dt && (!adaptive || to < (int)levels) &&
             (get(&a, "--reference") || !isnan(h_fixed) ||
              ref->macro_step <= dts[to] / (double)lcm / 8.0 * (1 + 1e-9)))
        to++;
      conv_job job = {sys, ref, dts, ps, n_p, t_end, i};
      char msg[1024];
      if (mrvi_batch_mpi_map((to - i) * n_p, jobs, sizeof *runs, conv_item,
                             &job, runs + (size_t)i * n_p, msg,
                             sizeof msg) < 0) {
        fprintf(stderr, "mrvi %s: %s\n", cmd, msg);
        free(runs);
        goto out;
      }
      done_to = to;
    }
    for (int j = 0; j < n_p; j++) {
      const conv_run *r = &runs[(size_t)i * n_p + j];
      T[j].p = (int)ps[j];
      T[j].dT[i] = dts[i];
      if (r->run_failed) {
        if (adaptive && i + 1 < n_dt) { /* a coarse step may fail: halve on */
          if (!a.quiet)
            printf("dT = %g, p = %d failed, trying smaller steps: %s\n", dts[i],
                   (int)ps[j], r->msg);
          const mrvi_errors none = {dts[i], (int)ps[j], NAN, NAN, NAN,
                                    NAN,    NAN,        NAN, NAN, NAN};
          T[j].e[i] = none;
          continue;
        }
        fprintf(stderr, "mrvi %s: run dT = %g, p = %d failed: %s\n", cmd,
                dts[i], (int)ps[j], r->msg);
        free(runs);
        goto out;
      }
      if (r->errors_failed) {
        fprintf(stderr, "mrvi %s: %s\n", cmd, r->msg);
        code = EXIT_INPUT;
        free(runs);
        goto out;
      }
      T[j].e[i] = r->e;
    }
    rows = i + 1;
    if (adaptive && rows >= (int)levels) {
      int settled = 1;
      for (int j = 0; j < n_p; j++) {
        T[j].rows = rows;
        for (int r = rows - (int)levels; r < rows; r++)
          settled &= isfinite(T[j].e[r].q_mac) && isfinite(T[j].e[r].p_mac);
        settled &=
            order_spread(&T[j], rows - (int)levels, rows, NULL) <= ORDER_SPREAD;
      }
      if (settled)
        break;
    }
  }
  free(runs);
  /* The table: every row, or with the chosen range its last `levels`. */
  const int first = adaptive && rows > (int)levels ? rows - (int)levels : 0;
  for (int j = 0; j < n_p; j++) {
    T[j].rows = rows - first;
    memmove(T[j].dT, T[j].dT + first, (size_t)T[j].rows * sizeof T[j].dT[0]);
    memmove(T[j].e, T[j].e + first, (size_t)T[j].rows * sizeof T[j].e[0]);
  }
  if (first > 0 && !a.quiet)
    printf("skipped the macro steps %g ... %g: their orders had not settled "
           "(or their runs failed)\n",
           dts[0], dts[first - 1]);
  for (int j = 0; j < n_p; j++) {
    if (!a.quiet)
      print_conv(&T[j], sys, t_end);
    const char *col;
    const double spread = order_spread(&T[j], 0, T[j].rows, &col);
    if (spread > ORDER_SPREAD)
      fprintf(stderr,
              "mrvi %s: warning: p = %d: consecutive observed orders of %s "
              "differ by up to %.2f (more than %.1f): the macro steps %g ... "
              "%g are not all in the asymptotic range, the fitted orders do "
              "not measure the scheme's order; %s\n",
              cmd, T[j].p, col, spread, ORDER_SPREAD, T[j].dT[0],
              T[j].dT[T[j].rows - 1],
              adaptive ? "no settled range was found within the halvings "
                         "tried (--dt0, --levels)"
                       : "use smaller macro steps (--dt0), or give neither "
                         "--dt nor --dt0 to let mrvi choose the range");
  }
  char out[2048];
  default_output(out, sizeof out, get(&a, "--output"), sys, "convergence");
  code = 0;
  if (rank > 0) /* rank 0 writes */
    goto out;
  code = EXIT_RUN;
  if (write_conv(cmd, out, T, n_p, sys, t_end, ref->macro_step,
                 get(&a, "--reference") ? get(&a, "--reference") : ref_scheme) <
      0)
    goto out;
  if (get(&a, "--csv") && write_conv_csv(cmd, get(&a, "--csv"), T, n_p) < 0)
    goto out;
  if (!a.quiet)
    printf("\ntable: %s%s%s\n", out, get(&a, "--csv") ? ", " : "",
           get(&a, "--csv") ? get(&a, "--csv") : "");
  code = 0;
out:
  mrvi_trajectory_free(ref);
  free(T);
  mrvi_system_free(sys);
  args_free(&a);
  return code;
}

int mrvi_cmd_converge(int argc, char **argv) {
  return with_ranks("converge", converge, argc, argv);
}

/* ---------------------------------------------------------------------------
 * stability
 * ------------------------------------------------------------------------- */
/* stability: the scan of omega dT has this many points. */
enum { K = 400 };

/* The limit and the scan of one rule and p: the record a worker process
 * returns (mrvi_batch_map). */
typedef struct stab_run {
  int failed;
  double measured;
  double trace[K];
  char msg[1024];
} stab_run;

typedef struct stab_job {
  const mrvi_system *sys;
  const mrvi_rule *rules;
  const double *ps;
  int n_p;
  double x_max, step;
  const double *xs;
} stab_job;

/* The settings of rule r, p = ps[j]: the slow potential on the micro grid. */
static mrvi_settings stab_settings(const mrvi_system *sys, mrvi_rule rule,
                                   double p) {
  mrvi_settings s = sys->settings;
  s.slow = rule;
  s.slow_grid = MRVI_GRID_MICRO;
  s.micro_steps = (int)p;
  s.newton_tol = 1e-12;
  return s;
}

/* Item k: rule k / n_p, p number k % n_p. */
static void stab_item(void *user, int k, void *out) {
  const stab_job *job = user;
  stab_run *run = out;
  const int r = k / job->n_p, j = k % job->n_p;
  const mrvi_settings s = stab_settings(job->sys, job->rules[r], job->ps[j]);
  if (mrvi_stability_limit(job->sys->model, &s, job->x_max, job->step,
                           &run->measured, run->msg, sizeof run->msg) < 0) {
    run->failed = 1;
    return;
  }
  for (int i = 0; i < K; i++) {
    double det;
    if (mrvi_stability_at(job->sys->model, &s, job->xs[i], &det, &run->trace[i],
                          run->msg, sizeof run->msg) < 0) {
      run->failed = 1;
      return;
    }
  }
}

static int stability(int argc, char **argv, int rank, int ranks) {
  static const char *const names[] = {"--p",      "--max",  "--step", "--at",
                                      "--output", "--jobs", NULL};
  args a;
  int pr = parse(argc, argv, mrvi_usage_stability, names, &a);
  if (pr <= 0) {
    args_free(&a);
    return pr == 0 ? 0 : EXIT_INPUT;
  }
  const char *cmd = "stability";
  int code = EXIT_INPUT;
  double ps[MAX_LIST] = {1, 2, 3, 5, 10}, x_max = 20, step = 0.01, at = NAN;
  int n_p = 5;
  double *scan = NULL;
  char msg[1024];
  mrvi_system *sys = load_everywhere(cmd, &a);
  if (!sys)
    goto out;
  if ((get(&a, "--p") &&
       (n_p = parse_list(cmd, "--p", get(&a, "--p"), ps, MAX_LIST, 1)) < 0) ||
      (get(&a, "--max") &&
       parse_double(cmd, "--max", get(&a, "--max"), &x_max) < 0) ||
      (get(&a, "--step") &&
       parse_double(cmd, "--step", get(&a, "--step"), &step) < 0) ||
      (get(&a, "--at") && parse_double(cmd, "--at", get(&a, "--at"), &at) < 0))
    goto out;
  const int jobs = parse_jobs(cmd, &a, sys, ranks);
  if (jobs < 0)
    goto out;
  if (!(x_max > 0) || !(step > 0) || step > x_max) {
    fprintf(stderr, "mrvi %s: need 0 < --step <= --max\n", cmd);
    goto out;
  }
  double omega;
  if (mrvi_oscillator_omega(sys->model, &omega, msg, sizeof msg) < 0) {
    fprintf(stderr, "%s: %s\n", a.file, msg);
    goto out;
  }
  code = EXIT_RUN;
  /* The two rules of the lemma for V on the micro grid, in the order of
   * mrvi_stability_rule_name (trapezoidal, midpoint). */
  const mrvi_rule rules[MRVI_STABILITY_RULES] = {{1.0, 1.0}, {0.5, 0.5}};
  double measured[2][MAX_LIST], analytic[2][MAX_LIST];
  scan = malloc((size_t)2 * n_p * K * sizeof(double));
  double xs[K];
  if (!scan)
    goto out;
  for (int k = 0; k < K; k++)
    xs[k] = x_max * (k + 1) / K;
  /* The 2 x n_p limits and scans on --jobs worker processes, gathered in
   * their order: the first failure in that order is reported. */
  stab_job job = {sys, rules, ps, n_p, x_max, step, xs};
  stab_run *runs = calloc((size_t)2 * n_p, sizeof *runs);
  if (!runs)
    goto out;
  if (mrvi_batch_mpi_map(2 * n_p, jobs, sizeof *runs, stab_item, &job, runs,
                         msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi %s: %s\n", cmd, msg);
    free(runs);
    goto out;
  }
  for (int r = 0; r < 2; r++)
    for (int j = 0; j < n_p; j++) {
      const stab_run *run = &runs[r * n_p + j];
      if (run->failed) {
        fprintf(stderr, "mrvi %s: %s\n", cmd, run->msg);
        free(runs);
        goto out;
      }
      measured[r][j] = run->measured;
      analytic[r][j] = mrvi_stability_bound(rules[r], (int)ps[j]);
      memcpy(scan + ((size_t)r * n_p + j) * K, run->trace, sizeof run->trace);
    }
  free(runs);
  if (!a.quiet) {
    printf("linear stability of %s (omega = %g): largest stable omega dT\n",
           sys->name, omega);
    printf("%4s  %-28s  %-28s\n", "", "trapezoidal (alpha=gamma=1)",
           "midpoint (gamma=1/2)");
    printf("%4s  %9s %9s %8s  %9s %9s %8s\n", "p", "measured", "analytic",
           "rel.diff", "measured", "analytic", "rel.diff");
    for (int j = 0; j < n_p; j++) {
      printf("%4d ", (int)ps[j]);
      for (int r = 0; r < 2; r++) {
        const double m = measured[r][j], an = analytic[r][j];
        if (isinf(m) && isinf(an))
          printf(" %9s %9s %8s ", "stable", "uncond.", "-");
        else
          printf(" %9.5f %9.5f %8.1e ", m, an, fabs(m - an) / an);
      }
      printf("\n");
    }
    printf("limit p -> infinity: %.5f (sqrt 12) for both rules; scan up to "
           "omega dT = %g\n",
           sqrt(12.0), x_max);
  }
  if (!isnan(at)) {
    printf("\npropagation matrix at omega dT = %g:\n%4s  %-25s  %-25s\n", at,
           "p", "trapezoidal det, trace", "midpoint det, trace");
    for (int j = 0; j < n_p; j++) {
      printf("%4d ", (int)ps[j]);
      for (int r = 0; r < 2; r++) {
        const mrvi_settings s = stab_settings(sys, rules[r], ps[j]);
        double det, tr;
        if (mrvi_stability_at(sys->model, &s, at, &det, &tr, msg, sizeof msg) <
            0) {
          fprintf(stderr, "mrvi %s: %s\n", cmd, msg);
          goto out;
        }
        printf(" %11.8f %11.6f %-3s", det, tr, fabs(tr) < 2 ? "" : "!");
      }
      printf("\n");
    }
    printf("(! = unstable: |trace| >= 2)\n");
  }
  char out[2048];
  default_output(out, sizeof out, get(&a, "--output"), sys, "stability");
  code = 0;
  if (rank > 0) /* rank 0 writes */
    goto out;
  code = EXIT_RUN;
  int pint[MAX_LIST];
  for (int j = 0; j < n_p; j++)
    pint[j] = (int)ps[j];
  const mrvi_stability_table table = {
      .system = sys->name,
      .omega = omega,
      .n_p = n_p,
      .p = pint,
      .measured = {measured[0], measured[1]},
      .analytic = {analytic[0], analytic[1]},
      .n_scan = K,
      .omega_dT = xs,
      .trace = scan,
  };
  if (mrvi_study_write_stability(out, &table, msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi %s: %s\n", cmd, msg);
    goto out;
  }
  if (!a.quiet)
    printf("table: %s\n", out);
  code = 0;
out:
  free(scan);
  mrvi_system_free(sys);
  args_free(&a);
  return code;
}

int mrvi_cmd_stability(int argc, char **argv) {
  return with_ranks("stability", stability, argc, argv);
}

/* ---------------------------------------------------------------------------
 * timing
 * ------------------------------------------------------------------------- */
typedef mrvi_timing_row timing_row;

#define MAX_REPEAT 99

static int compare_double(const void *x, const void *y) {
  const double a = *(const double *)x, b = *(const double *)y;
  return (a > b) - (a < b);
}

/* Median of v[0..n-1] (reordered). */
static double median(double *v, int n) {
  qsort(v, (size_t)n, sizeof *v, compare_double);
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

int mrvi_cmd_timing(int argc, char **argv) {
  static const char *const names[] = {"--dt",     "--p",   "--schemes",
                                      "--t-end",  "--csv", "--repeat",
                                      "--output", NULL};
  args a;
  int pr = parse(argc, argv, mrvi_usage_timing, names, &a);
  if (pr <= 0) {
    args_free(&a);
    return pr == 0 ? 0 : EXIT_INPUT;
  }
  const char *cmd = "timing";
  int code = EXIT_INPUT;
  double ps[MAX_LIST] = {1, 5, 10, 20, 50, 100, 200, 500, 1000}, dt = 0.001;
  int n_p = 9, n_s = 0, failed = 0, repeat = 1;
  char schemes_buf[1024] =
      "midpoint-midpoint,trapezoidal-midpoint,trapezoidal-trapezoidal";
  const char *schemes[16];
  timing_row *rows = NULL;
  FILE *csv = NULL;
  mrvi_system *sys = load(cmd, &a);
  if (!sys)
    goto out;
  double t_end = sys->settings.t_end;
  if ((get(&a, "--p") &&
       (n_p = parse_list(cmd, "--p", get(&a, "--p"), ps, MAX_LIST, 1)) < 0) ||
      (get(&a, "--dt") &&
       parse_double(cmd, "--dt", get(&a, "--dt"), &dt) < 0) ||
      (get(&a, "--t-end") &&
       parse_double(cmd, "--t-end", get(&a, "--t-end"), &t_end) < 0))
    goto out;
  if (get(&a, "--repeat")) {
    double r;
    if (parse_list(cmd, "--repeat", get(&a, "--repeat"), &r, 1, 1) < 0)
      goto out;
    if (r > MAX_REPEAT) {
      fprintf(stderr, "mrvi %s: --repeat: at most %d\n", cmd, MAX_REPEAT);
      goto out;
    }
    repeat = (int)r;
  }
  if (get(&a, "--schemes"))
    snprintf(schemes_buf, sizeof schemes_buf, "%s", get(&a, "--schemes"));
  for (char *tok = strtok(schemes_buf, ","); tok && n_s < 16;
       tok = strtok(NULL, ",")) {
    mrvi_settings s;
    mrvi_settings_default(&s);
    if (mrvi_settings_set_scheme(&s, tok) < 0) {
      fprintf(stderr, "mrvi %s: unknown scheme '%s'\n", cmd, tok);
      goto out;
    }
    schemes[n_s++] = tok;
  }
  if (!(dt > 0) || !(t_end > 0)) {
    fprintf(stderr, "mrvi %s: --dt and --t-end must be positive\n", cmd);
    goto out;
  }
  rows = calloc((size_t)n_s * n_p, sizeof *rows);
  if (!rows)
    goto out;
  code = EXIT_RUN;
  if (!a.quiet) {
    printf("computing time of %s, dt = %g, t_end = %g", sys->name, dt, t_end);
    if (repeat > 1)
      printf(", times: medians of %d runs", repeat);
    printf("\n%-24s %5s %8s %8s %6s %9s %9s %11s %11s %11s\n", "scheme", "p",
           "dT", "steps", "size", "Newton it", "total [s]", "step [ms]",
           "assemble", "solve");
  }
  for (int i = 0; i < n_s; i++)
    for (int j = 0; j < n_p; j++) {
      mrvi_settings s = sys->settings;
      mrvi_settings_set_scheme(&s, schemes[i]);
      s.micro_steps = (int)ps[j];
      s.macro_step = ps[j] * dt;
      s.t_end = fmax(t_end, s.macro_step);
      mrvi_summary sum;
      timing_row *r = &rows[i * n_p + j];
      double times[3][MAX_REPEAT]; /* wall, assemble, solve per run */
      int st = MRVI_OK;
      for (int k = 0; k < repeat && st == MRVI_OK; k++) {
        st = mrvi_run(sys->model, &s, NULL, NULL, NULL, &sum);
        times[0][k] = sum.wall_time;
        times[1][k] = sum.assemble_time;
        times[2][k] = sum.solve_time;
      }
      if (st < 0) {
        /* A failed run (e.g. unstable at a large dT) is a row of NaN; the
         * study goes on and the exit status reports it. */
        fprintf(stderr, "mrvi %s: %s, p = %d failed: %s\n", cmd, schemes[i],
                (int)ps[j], sum.message);
#define TIMING_NAN(name) r->name = NAN;
        MRVI_TIMING_COLUMNS(TIMING_NAN)
#undef TIMING_NAN
        failed++;
        continue;
      }
      /* Iterations and steps are the same in every run (a run depends on
       * its input alone); the times are medians. */
      r->total_time = median(times[0], repeat);
      r->iterations = (double)sum.iterations_total;
      r->macro_steps = (double)sum.steps;
      r->time_per_step = r->total_time / sum.steps;
      r->assemble_per_step = median(times[1], repeat) / sum.steps;
      r->solve_per_step = median(times[2], repeat) / sum.steps;
      r->system_size =
          mrvi_model_n_slow(sys->model) + ps[j] * mrvi_model_n_fast(sys->model);
      if (!a.quiet) {
        printf("%-24s %5d %8.4g %8.0f %6.0f %9.0f %9.3f %11.4f %11.4f "
               "%11.4f\n",
               schemes[i], (int)ps[j], s.macro_step, r->macro_steps,
               r->system_size, r->iterations, r->total_time,
               1e3 * r->time_per_step, 1e3 * r->assemble_per_step,
               1e3 * r->solve_per_step);
        fflush(stdout);
      }
    }
  char out[2048];
  default_output(out, sizeof out, get(&a, "--output"), sys, "timing");
  int pint[MAX_LIST];
  for (int j = 0; j < n_p; j++)
    pint[j] = (int)ps[j];
  const mrvi_timing_table table = {
      .system = sys->name,
      .micro_step = dt,
      .t_end = t_end,
      .repeat = repeat,
      .n_p = n_p,
      .n_schemes = n_s,
      .p = pint,
      .schemes = schemes,
      .rows = rows,
  };
  char msg[1024];
  if (mrvi_study_write_timing(out, &table, msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi %s: %s\n", cmd, msg);
    goto out;
  }
  if (get(&a, "--csv")) {
    csv = fopen(get(&a, "--csv"), "w");
    if (!csv) {
      fprintf(stderr, "mrvi %s: cannot create '%s'\n", cmd, get(&a, "--csv"));
      goto out;
    }
    fprintf(csv, "scheme,p");
#define TIMING_HEAD(name) fprintf(csv, "," #name);
    MRVI_TIMING_COLUMNS(TIMING_HEAD)
#undef TIMING_HEAD
    fprintf(csv, "\n");
    for (int i = 0; i < n_s; i++)
      for (int j = 0; j < n_p; j++) {
        fprintf(csv, "%s,%d", schemes[i], (int)ps[j]);
#define TIMING_CELL(name) fprintf(csv, ",%.9g", rows[i * n_p + j].name);
        MRVI_TIMING_COLUMNS(TIMING_CELL)
#undef TIMING_CELL
        fprintf(csv, "\n");
      }
  }
  if (!a.quiet)
    printf("table: %s\n", out);
  code = failed ? EXIT_RUN : 0;
out:
  if (csv && fclose(csv) != 0)
    code = EXIT_RUN;
  free(rows);
  mrvi_system_free(sys);
  args_free(&a);
  return code;
}
