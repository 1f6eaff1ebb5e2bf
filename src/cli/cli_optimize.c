/* mrvi optimize FILE [-o OUT.h5] [--set KEY=VALUE]... [--quiet]
 *
 * Optimal control (doc/optimal-control.md): read the system and its
 * `control:` section, optimise the controls with NLopt (single shooting,
 * exact discrete adjoint), print a line per iteration and a summary, and
 * write the optimal trajectory (layout of `mrvi run`, /micro included)
 * plus /control and /optimizer to HDF5 (doc/output.md).  The output path
 * is checked (created, lockable, its directory writable) before the
 * optimisation starts.  SIGINT and SIGTERM stop the optimiser after the
 * evaluation in progress; the best iterate is written with status
 * interrupted.  Meanwhile the output holds the best controls and the
 * history so far (mrvi_ocp_output_progress; before the first evaluation,
 * the initial controls and no history): what a SIGKILL leaves.  When
 * the file cannot be written (a full disk) the controls are printed
 * instead.
 * Exit status (doc/optimal-control.md, "Status"): 0 converged, 1 bad
 * input or an unusable output path, 2 not converged (every other status;
 * the file is written), 130/143 interrupted by SIGINT/SIGTERM (written). */
#include "cli.h"
#include "io/io.h"
#include "ocp/ocp.h"

#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

const char mrvi_usage_optimize[] =
    "Usage: mrvi optimize FILE [-o OUT.h5] [--set KEY=VALUE]... [--quiet]\n"
    "\n"
    "Solve the optimal control problem of the `control:` section of FILE\n"
    "(multirate DMOC: discrete Lagrange-d'Alembert on the integrator's\n"
    "discrete Lagrangian, single shooting, exact discrete adjoint, NLopt).\n"
    "Prints one line per evaluation (cost, largest terminal violation,\n"
    "gradient norm) and a summary; writes the optimal trajectory (/macro\n"
    "and /micro, as `mrvi run` writes them), /control and /optimizer to\n"
    "OUT.h5 (default: output.file with '.h5' replaced by '_opt.h5').\n"
    "Figures: src/cli/mrvi-plot optimize OUT.h5 -o DIR (controls, trajectory,\n"
    "optimiser history).\n"
    "\n"
    "Options:\n"
    "  -o, --output OUT.h5    output file\n"
    "  -s, --set KEY=VALUE    override a key of the description\n"
    "  -q, --quiet            no per-iteration lines\n"
    "  -h, --help             show this help\n"
    "\n"
    "Replay: `mrvi run FILE --controls OPT.h5 [-o OUT.h5]` runs the stored\n"
    "controls /control/u of OPT.h5 through the discrete equations of FILE,\n"
    "writes the trajectory and checks the terminal conditions.\n"
    "\n"
    "The output path is checked before the optimisation starts.  Ctrl-C\n"
    "(SIGINT) or SIGTERM stops the optimiser after the evaluation in\n"
    "progress and writes the best iterate so far (status interrupted).\n"
    "Meanwhile the file holds the best controls and the history so far\n"
    "(status running, no trajectory; rewritten at most every\n"
    "output.flush_interval s): what a SIGKILL leaves.\n"
    "\n"
    "Exit status: 0 converged (NLopt reached its tolerance and the terminal\n"
    "conditions hold to control.solver.terminal_tolerance), 1 invalid input\n"
    "or an unusable output path, 2 not converged (evaluation limit,\n"
    "terminal conditions not met, roundoff, failure; the file is written\n"
    "with that status), 130/143 interrupted by SIGINT/SIGTERM.\n";

/* Per evaluation: a row of /optimizer/history and, unless quiet, a line;
 * stop (non-zero) on a signal or when the history cannot grow. */
typedef struct progress {
  mrvi_ocp_output *out;
  const mrvi_ocp *o;
  int quiet, no_memory, progress_failed;
} progress;

static int on_iteration(void *data, int it, double cost, double viol,
                        double gnorm, double kkt) {
  progress *pr = data;
  if (mrvi_ocp_output_iteration(pr->out, cost, viol, gnorm, kkt) < 0) {
    pr->no_memory = 1;
    return 1;
  }
  /* The progress file (what a SIGKILL leaves); a failure is said once and
   * the optimisation goes on (close writes the whole file again). */
  char msg[1024];
  if (mrvi_ocp_output_progress(pr->out, mrvi_ocp_best_iterate(pr->o), msg,
                               sizeof msg) < 0 &&
      !pr->progress_failed) {
    pr->progress_failed = 1;
    fprintf(stderr, "mrvi optimize: warning: progress file not written: %s\n",
            msg);
  }
  if (!pr->quiet) {
    printf("%5d  cost %.12e  violation %.3e  |grad| %.3e\n", it, cost, viol,
           gnorm);
    fflush(stdout);
  }
  return mrvi_cli_stop_signal != 0;
}

/* `mrvi check`: the problem of the `control:` section, if any (actuators,
 * terminal conditions, algorithm).  Returns 0, or 1 when the section is
 * invalid (its message printed). */
int mrvi_cli_check_control(const mrvi_system *sys) {
  if (!mrvi_ocp_has_control(sys))
    return 0;
  char msg[2048];
  mrvi_ocp *o = NULL;
  double *u = NULL;
  if (mrvi_ocp_load(sys, &o, &u, msg, sizeof msg) < 0) {
    fprintf(stderr, "%s\n", msg);
    return 1;
  }
  const mrvi_model *m = sys->model;
  const int na = mrvi_ocp_n_actuators(o), nt = mrvi_ocp_n_terminals(o);
  printf("\n%-14s%d controls, %d terminal constraints, %s\n", "control",
         mrvi_ocp_n_controls(o), mrvi_ocp_n_constraints(o),
         mrvi_ocp_algorithm_name(mrvi_ocp_get_algorithm(o)));
  {
    char why[300] = "";
    const char *path = mrvi_ocp_solver_path(o, why, sizeof why);
    printf("%-14s%s: %s\n", "control path", path ? path : "none", why);
  }
  printf("%-14s%d\n", "actuators", na);
  for (int a = 0; a < na; a++) {
    const int c = mrvi_ocp_actuator_coordinate(o, a);
    char on[300];
    const char *kind = mrvi_ocp_actuator_kind(o, a);
    if (c >= 0) {
      snprintf(on, sizeof on, "on %s", MRVI_CNAME(m, c));
    } else if (strcmp(kind, "pair")) {
      snprintf(on, sizeof on, "%s on %s", kind,
               mrvi_model_body_name(m, mrvi_ocp_actuator_body(o, a)));
    } else {
      int pi, pj;
      mrvi_ocp_actuator_pair(o, a, &pi, &pj);
      snprintf(on, sizeof on, "pair %s - %s", MRVI_PNAME(m, pi),
               MRVI_PNAME(m, pj));
    }
    printf("  %3d  %s (%s; %s grid, %d values)\n", a,
           mrvi_ocp_actuator_name(o, a), on,
           mrvi_ocp_actuator_grid(o, a) == MRVI_GRID_MACRO ? "macro" : "micro",
           mrvi_ocp_actuator_size(o, a));
  }
  printf("%-14s%d (tolerance %g)\n", "terminal", nt,
         mrvi_ocp_terminal_tolerance(o));
  for (int i = 0; i < nt; i++) {
    mrvi_ocp_terminal_kind kind;
    int c;
    double target, penalty;
    mrvi_ocp_terminal(o, i, &kind, &c, &target, &penalty);
    int row;
    const int b = mrvi_ocp_terminal_body(o, i, &row);
    if (b >= 0)
      printf("  %3d  %s of body %s, row %d", i,
             mrvi_ocp_terminal_kind_name(kind), mrvi_model_body_name(m, b),
             row);
    else
      printf("  %3d  %s of %s = %g", i, mrvi_ocp_terminal_kind_name(kind),
             MRVI_CNAME(m, c), target);
    if (penalty > 0)
      printf(" (penalty %g)", penalty);
    putchar('\n');
  }
  /* What one evaluation costs, measured: an optimisation takes as many of
   * them as NLopt needs, at most the cap. */
  const int nc = mrvi_ocp_n_controls(o), ncon = mrvi_ocp_n_constraints(o);
  double J, *grad = malloc(((size_t)nc + (size_t)ncon * ((size_t)nc + 1) + 1) *
                           sizeof *grad);
  if (grad) {
    const double t0 = mrvi_clock();
    const int st = mrvi_ocp_evaluate(o, u, &J, grad, ncon ? grad + nc : NULL,
                                     ncon ? grad + nc + ncon : NULL);
    const double t = mrvi_clock() - t0;
    if (st == MRVI_OK)
      printf("%-14sone cost + gradient: wall time %.3g s (measured at the "
             "initial guess)\n%-14san optimisation takes as many as NLopt "
             "needs (3 to 24 on the shipped problems), at most %d "
             "(control.solver.max_evaluations): wall time up to %.3g s\n",
             "estimate", t, "", mrvi_ocp_max_evaluations(o),
             t * mrvi_ocp_max_evaluations(o));
    else
      printf("%-14sthe evaluation at the initial guess failed: %s\n",
             "estimate", mrvi_ocp_errmsg(o));
  }
  free(grad);
  free(u);
  mrvi_ocp_free(o);
  return 0;
}

/* Default output: output.file with ".h5" -> "_opt.h5". */
static char *default_output(const mrvi_system *sys) {
  const char *base = sys->output_file ? sys->output_file : "optimal.h5";
  size_t n = strlen(base);
  char *s = malloc(n + 8);
  if (!s)
    return NULL;
  strcpy(s, base);
  if (n > 3 && !strcmp(s + n - 3, ".h5"))
    s[n - 3] = '\0';
  strcat(s, "_opt.h5");
  return s;
}

/* mrvi run FILE --controls STORED.h5 [-o OUT.h5] [--set ...]: replay. */
static int replay(const char *file, const char *controls, const char *out,
                  const char **ov, int n_ov) {
  static char msg[8192];
  mrvi_system *sys = NULL;
  if (mrvi_system_load(file, ov, n_ov, &sys, msg, sizeof msg) < 0) {
    fprintf(stderr, "%s\n", msg);
    return 1;
  }
  mrvi_ocp *o = NULL;
  double *u = NULL;
  int rc = 1;
  if (mrvi_ocp_load(sys, &o, &u, msg, sizeof msg) < 0 ||
      mrvi_ocp_controls_read(controls, o, sys->settings.micro_steps, u, msg,
                             sizeof msg) < 0) {
    fprintf(stderr, "mrvi run: %s\n", msg);
    goto done;
  }
  const int nc = mrvi_ocp_n_constraints(o);
  double J, *c = calloc((size_t)nc + 1, sizeof *c);
  rc = 2;
  if (c && mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL) == 0) {
    double viol = 0.0;
    for (int i = 0; i < nc; i++)
      viol = fmax(viol, fabs(c[i]));
    const char *dst = out ? out : sys->output_file;
    if (mrvi_ocp_trajectory_write(dst, sys, o, msg, sizeof msg) < 0) {
      fprintf(stderr, "mrvi run: writing '%s' failed: %s\n", dst, msg);
    } else {
      const int met = viol <= mrvi_ocp_terminal_tolerance(o);
      printf("%s: replayed the controls of %s\n", file, controls);
      printf("  %-22s%.12e\n", "cost", J);
      printf("  %-22s%.3e (tolerance %.1e)%s\n", "terminal violation", viol,
             mrvi_ocp_terminal_tolerance(o), met ? "" : " NOT MET");
      printf("  %-22s%s\n", "output", dst);
      rc = met ? 0 : 2;
    }
  } else {
    fprintf(stderr, "mrvi run: %s\n", mrvi_ocp_errmsg(o));
  }
  free(c);
done:
  free(u);
  mrvi_ocp_free(o);
  mrvi_system_free(sys);
  return rc;
}

int mrvi_cmd_optimize(int argc, char **argv) {
  const char *file = NULL, *out = NULL, *controls = NULL;
  const int is_run = !strcmp(argv[0], "run"); /* mrvi run --controls */
  const char **ov = calloc((size_t)argc + 1, sizeof *ov);
  int n_ov = 0, quiet = 0;
  if (!ov)
    return 1;
  for (int i = 1; i < argc; i++) {
    const char *a = argv[i];
    if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
      fputs(mrvi_usage_optimize, stdout);
      free(ov);
      return 0;
    } else if (!strcmp(a, "-q") || !strcmp(a, "--quiet")) {
      quiet = 1;
    } else if ((!strcmp(a, "-o") || !strcmp(a, "--output")) && i + 1 < argc) {
      out = argv[++i];
    } else if (!strncmp(a, "--output=", 9)) {
      out = a + 9;
    } else if ((!strcmp(a, "-s") || !strcmp(a, "--set")) && i + 1 < argc) {
      ov[n_ov++] = argv[++i];
    } else if (is_run && !strcmp(a, "--controls") && i + 1 < argc) {
      controls = argv[++i];
    } else if (is_run && !strncmp(a, "--controls=", 11)) {
      controls = a + 11;
    } else if (!strncmp(a, "--set=", 6)) {
      ov[n_ov++] = a + 6;
    } else if (i + 1 == argc && (!strcmp(a, "-o") || !strcmp(a, "--output") ||
                                 !strcmp(a, "-s") || !strcmp(a, "--set") ||
                                 (is_run && !strcmp(a, "--controls")))) {
      fprintf(stderr, "mrvi %s: option '%s' needs a value\n", argv[0], a);
      free(ov);
      return 1;
    } else if (a[0] == '-' && a[1]) {
      fprintf(stderr, "mrvi %s: unknown option '%s'%s\n", argv[0], a,
              is_run ? " (with --controls: -o, --set, --quiet)" : "");
      mrvi_cli_usage_short(argv[0], is_run ? "" : mrvi_usage_optimize);
      free(ov);
      return 1;
    } else if (!file) {
      file = a;
    } else {
      fprintf(stderr, "mrvi optimize: unexpected argument '%s'\n", a);
      free(ov);
      return 1;
    }
  }
  if (!file) {
    fprintf(stderr, "mrvi optimize: missing FILE\n");
    mrvi_cli_usage_short("optimize", mrvi_usage_optimize);
    free(ov);
    return 1;
  }
  if (is_run) {
    const int rc = replay(file, controls, out, ov, n_ov);
    free(ov);
    return rc;
  }
  static char msg[8192];
  mrvi_system *sys = NULL;
  int st = mrvi_system_load(file, ov, n_ov, &sys, msg, sizeof msg);
  free(ov);
  if (st < 0) {
    fprintf(stderr, "%s\n", msg);
    return 1;
  }
  mrvi_ocp *o = NULL;
  double *u = NULL;
  if (mrvi_ocp_load(sys, &o, &u, msg, sizeof msg) < 0) {
    fprintf(stderr, "%s\n", msg);
    mrvi_system_free(sys);
    return 1;
  }
  char *def = out ? NULL : default_output(sys);
  if (!out)
    out = def;
  progress pr = {.quiet = quiet, .o = o};
  if (mrvi_ocp_output_open(out, sys, o, &pr.out, msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi optimize: %s\n", msg);
    free(u);
    free(def);
    mrvi_ocp_free(o);
    mrvi_system_free(sys);
    return 1;
  }
  mrvi_ocp_set_callback(o, on_iteration, &pr);
  mrvi_cli_install_handlers();
  /* The first progress file, before any evaluation: from here on a kill
   * leaves a readable file with the initial controls. */
  if (mrvi_ocp_output_start(pr.out, u, msg, sizeof msg) < 0) {
    pr.progress_failed = 1;
    fprintf(stderr, "mrvi optimize: warning: progress file not written: %s\n",
            msg);
  }
  printf("%s: %d controls, %d terminal constraints, %ld macro steps, p = %d, "
         "%s\n",
         file, mrvi_ocp_n_controls(o), mrvi_ocp_n_constraints(o),
         mrvi_ocp_n_steps(o), sys->settings.micro_steps,
         mrvi_ocp_algorithm_name(mrvi_ocp_get_algorithm(o)));
  const double t0 = mrvi_clock();
  mrvi_ocp_result res;
  st = mrvi_ocp_solve(o, u, &res);
  const double wall = mrvi_clock() - t0;
  if (!res.status[0]) /* failed before NLopt started: nothing to write */
    mrvi_fmt(res.status, sizeof res.status, "%s", "failed");
  const int sig = (int)mrvi_cli_stop_signal;
  int rc = st == 0 ? 0 : sig ? 128 + sig : 2;
  printf("%s (status %s)\n",
         st == 0 ? "optimum found"
         : sig   ? "optimisation INTERRUPTED"
                 : "NOT CONVERGED",
         res.status);
  printf("  %-22s%.12e\n", "cost", res.cost);
  printf("  %-22s%.3e (tolerance %.1e)\n", "terminal violation", res.violation,
         mrvi_ocp_terminal_tolerance(o));
  printf("  %-22s%d (NLopt: %s)\n", "evaluations", res.evaluations,
         res.nlopt_name);
  {
    char why[300] = "";
    const char *path = mrvi_ocp_solver_path(o, why, sizeof why);
    printf("  %-22s%s (%s)\n", "solver path", path ? path : "none", why);
  }
  printf("  %-22s%.3f s\n", "wall time", wall);
  if (st != 0)
    fprintf(stderr, "mrvi optimize: %s%s%s\n",
            sig == SIGTERM ? "SIGTERM: "
            : sig          ? "SIGINT: "
                           : "",
            pr.no_memory ? "out of memory for the history; " : "",
            mrvi_ocp_errmsg(o));
  /* The trajectory of the returned controls (re-evaluated by solve). */
  if (mrvi_ocp_output_close(pr.out, u, &res, res.status, msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi optimize: writing '%s' failed: %s\n", out,
            msg[0] ? msg : "unknown error");
    /* The controls are not lost with the file (a full disk): printed
     * exactly, actuator by actuator. */
    const int n = mrvi_ocp_n_controls(o);
    printf("controls NOT SAVED (%d values, actuator by actuator in the "
           "order of control.actuators, each over its grid):\n",
           n);
    for (int i = 0; i < n; i++)
      printf("%.17g\n", u[i]);
    fflush(stdout);
    if (rc == 0)
      rc = 2;
  } else {
    printf("  %-22s%s\n", "output", out);
    /* Last line: what the file's root stop_reason says when the
     * optimisation stopped short (the trajectory in it is complete either
     * way: that of the controls returned). */
    if (st != 0)
      printf("optimisation %s: %s holds the %s controls, stop_reason %s\n",
             sig ? "INTERRUPTED" : "NOT CONVERGED", out,
             sig ? "best" : "returned", res.status);
  }
  free(u);
  free(def);
  mrvi_ocp_free(o);
  mrvi_system_free(sys);
  return rc;
}
