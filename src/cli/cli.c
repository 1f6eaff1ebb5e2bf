/* mrvi — command-line tool.
 *
 *   mrvi run FILE [-o OUT.h5] [--set KEY=VALUE]... [--quiet]
 *   mrvi check FILE [--set KEY=VALUE]...
 *   mrvi help [COMMAND] | --help | --version
 *
 * The library never prints and never exits; this file decides both.
 * Exit status: 0 success, 1 the run did not start (usage, invalid
 * description file, output cannot be created), 2 the run started and failed
 * (Newton, non-finite values, writing output), 128 + signal when interrupted
 * (130 for Ctrl-C, 143 for SIGTERM); an interrupted or failed run still
 * leaves a valid HDF5 file with every completed step. */
#include "cli.h"
#include "io/io.h"
#include "solver/solver.h"

#include <errno.h>
#include <signal.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

enum {
  EXIT_INPUT = 1, /* bad arguments or description file: nothing was run */
  EXIT_RUN = 2,   /* the run started and failed */
  MSG_LEN = 8192  /* loader messages may list several errors */
};

/* ---------------------------------------------------------------------------
 * Help texts
 * ------------------------------------------------------------------------- */
static const char usage_main[] =
    "Usage: mrvi COMMAND [ARGS]\n"
    "\n"
    "Variational multirate integrators for mechanical systems with slow and\n"
    "fast variables.\n"
    "\n"
    "Commands:\n"
    "  run FILE         integrate a description file and write an HDF5 file\n"
    "  check FILE       validate a description file and print the model\n"
    "  optimize FILE    optimal control of the `control:` section (NLopt)\n"
    "  export FILE.h5   particles and bodies of a run for OVITO/VMD/ASE (xyz)\n"
    "                   or ParaView (xdmf)\n"
    "  batch FILE       many runs: parameter studies and ensembles on all\n"
    "                   cores, resumable (doc/batch.md)\n"
    "  help [COMMAND]   show this help or the help of a command\n"
    "\n"
    "Studies (paper §5-§6; each prints a table and writes it to HDF5):\n"
    "  converge FILE    convergence orders against a single-rate reference\n"
    "  stability FILE   stability bounds of the slow harmonic oscillator\n"
    "  timing FILE      computing time versus p at a fixed micro step\n"
    "\n"
    "Options:\n"
    "  -h, --help       show this help\n"
    "  --version        print the version\n"
    "\n"
    "Run 'mrvi help COMMAND' (or 'mrvi COMMAND --help') for the options of a\n"
    "command.\n";

static const char usage_run[] =
    "Usage: mrvi run FILE [-o OUT.h5] [--set KEY=VALUE]... [--quiet] "
    "[--force]\n"
    "                [--from RUN.h5[:K]]\n"
    "       mrvi run --resume OUT.h5 [--set integrator.t_end=LATER] [--quiet]\n"
    "       mrvi run FILE --controls OPT.h5 [-o OUT.h5] [--set KEY=VALUE]...\n"
    "\n"
    "Integrate the system described in FILE (YAML) and write macro and micro\n"
    "trajectories, energies and solver statistics to an HDF5 file.  For a\n"
    "model with particles also write OUT.xdmf beside it (ParaView: particles\n"
    "and springs over time; output.xdmf: false turns it off; see also\n"
    "'mrvi export' and 'mrvi-plot animate').\n"
    "\n"
    "Options:\n"
    "  -o, --output OUT.h5   output file (default: output.file of FILE,\n"
    "                        else <name>.h5)\n"
    "  -s, --set KEY=VALUE   override a scalar of FILE by its dotted path,\n"
    "                        e.g. integrator.micro_steps=5 or\n"
    "                        particles.2.mass=3; may be repeated\n"
    "  -q, --quiet           no progress bar and no summary (errors are still\n"
    "                        printed)\n"
    "      --force           replace an existing OUT.h5 that is not an mrvi\n"
    "                        output (an earlier mrvi output is always\n"
    "                        replaced; a file a live run holds never is)\n"
    "      --resume OUT.h5   continue the run that wrote OUT.h5 and stopped\n"
    "                        (Ctrl-C, SIGTERM, killed, an error) from its\n"
    "                        last complete stored macro node, appending to\n"
    "                        OUT.h5; description and settings come from the\n"
    "                        file; the result equals an uninterrupted run bit\n"
    "                        for bit.  Refused for a file a live run holds.\n"
    "                        With --set integrator.t_end=LATER: extend a\n"
    "                        completed run in place to a later t_end (the\n"
    "                        same file as a run to LATER)\n"
    "      --from RUN.h5[:K] start a new run (a new output file) from the\n"
    "                        state of stored macro node K of RUN.h5 (default:\n"
    "                        its last node); FILE must have the same\n"
    "                        coordinates and macro_step, and steps K+1 .. N\n"
    "                        are taken (e.g. a later t_end extends a run)\n"
    "      --controls OPT.h5 replay an optimum: run the controls /control/u\n"
    "                        that 'mrvi optimize FILE' stored in OPT.h5\n"
    "                        through the discrete equations of FILE, write\n"
    "                        the trajectory and check the terminal\n"
    "                        conditions (with -o, --set, --quiet only)\n"
    "      --threads N|auto  threads of the element loops (default:\n"
    "                        MRVI_THREADS, else auto: the cores available\n"
    "                        if a loop is long enough for threads, else 1;\n"
    "                        mrvi check says which and why); the same\n"
    "                        results for every N.  N > 1 sets\n"
    "                        GOMP_SPINCOUNT=1000 unless the environment sets\n"
    "                        it or OMP_WAIT_POLICY\n"
    "  -h, --help            show this help\n"
    "\n"
    "Notes about the input, such as initial velocities projected onto the\n"
    "constraints' tangent space, are printed on stderr as 'FILE: note: ...'\n"
    "before the run starts (also with --quiet).\n"
    "\n"
    "A progress bar is drawn on stderr when it is a terminal.  Ctrl-C stops\n"
    "the run after the current step and leaves a valid file (a second\n"
    "Ctrl-C kills it at once).\n"
    "\n"
    "When the maximal energy error exceeds integrator.energy_warning\n"
    "(default 0.1, relative to the initial energy; --set changes it) the\n"
    "run completes with one warning on stderr and the root attribute\n"
    "'warning'; an error is printed once, on stderr.\n"
    "\n"
    "Exit status:\n"
    "  0    the run completed (also with an energy warning)\n"
    "  1    nothing was run: bad arguments, invalid description file, or the\n"
    "       output file cannot be created or is refused (no output is "
    "written)\n"
    "  2    the run failed (Newton did not converge, a non-finite state, an\n"
    "       output error such as a full disk); the output file\n"
    "       holds every completed step and the attribute stop_reason\n"
    "  130  interrupted by SIGINT (143: SIGTERM); the file is valid as for 2\n";

static const char usage_check[] =
    "Usage: mrvi check FILE [--set KEY=VALUE]...\n"
    "\n"
    "Validate the description file FILE and print the model: coordinate,\n"
    "particle and element counts, the slow/fast partition, every potential\n"
    "element, every constraint with the nodes it is enforced at (macro nodes\n"
    "for slow-only constraints, every micro node otherwise), the scheme with\n"
    "both quadrature rules, step sizes, the Newton and constraint settings,\n"
    "the step solver's path and the thread count (each with why), the\n"
    "output file and any notes (e.g. initial velocities projected onto the\n"
    "constraints).  Nothing is written.  With a control: section also the\n"
    "optimal control problem and an estimate of its time: one cost and\n"
    "gradient evaluated at the initial guess (the only integration check\n"
    "does).\n"
    "\n"
    "With constraints, FILE is valid only if the initial positions satisfy\n"
    "them to integrator.constraints.tolerance and their gradients are\n"
    "independent there.\n"
    "\n"
    "Options:\n"
    "  -s, --set KEY=VALUE   override a scalar of FILE by its dotted path\n"
    "      --threads N|auto  the thread count to check and show (default:\n"
    "                        MRVI_THREADS, else auto: what mrvi run would\n"
    "                        choose, and why)\n"
    "  -h, --help            show this help\n"
    "\n"
    "Exit status: 0 if FILE is valid, 1 otherwise.\n";

/* ---------------------------------------------------------------------------
 * Suggestions for misspelt commands and options
 * ------------------------------------------------------------------------- */

/* Closest of a NULL-terminated list of candidates, or NULL. */
static const char *closest(const char *word, const char *const *candidates) {
  int n = 0;
  while (candidates[n])
    n++;
  return mrvi_closest(word, candidates, n);
}

/* ---------------------------------------------------------------------------
 * Argument parsing (hand-written: options may come before or after FILE)
 * ------------------------------------------------------------------------- */
typedef struct cli_args {
  const char *file;
  const char *output;     /* -o, or NULL */
  const char **overrides; /* --set values, argc entries allocated */
  int n_overrides;
  int quiet;
  int force; /* --force: replace an existing file that is no mrvi output */
  int help;
  const char *resume; /* --resume OUT.h5 */
  const char *from;   /* --from OUT.h5[:k] */
  int threads;        /* --threads N, else MRVI_THREADS, else 0: auto */
} cli_args;

/* Options accepted by a command, for the parser and for suggestions
 * (--controls is handled by the replay of cli_optimize.c). */
static const char *const run_options[] = {
    "--output", "--set",  "--quiet",    "--force",   "--help",
    "--resume", "--from", "--controls", "--threads", NULL};
static const char *const check_options[] = {"--set", "--help", "--threads",
                                            NULL};

static void usage_error(const char *usage) { fputs(usage, stderr); }

void mrvi_cli_usage_short(const char *cmd, const char *usage) {
  const char *end = strstr(usage, "\n\n");
  if (*usage)
    fprintf(stderr, "%.*s\n",
            (int)(end ? end - usage : (ptrdiff_t)strlen(usage)), usage);
  fprintf(stderr, "Options and details: mrvi help %s\n", cmd);
}

int mrvi_cli_threads(const char *cmd, const char *what, const char *value) {
  if (!strcmp(value, "auto"))
    return 0;
  char *end = NULL;
  const long n = strtol(value, &end, 10);
  if (!*value || *end || n < 1 || n > 4096) {
    fprintf(stderr,
            "mrvi %s: %s takes a thread count 1..4096 or auto, got '%s'\n", cmd,
            what, value);
    return -1;
  }
  if (n > 1 && !mrvi_threads_supported()) {
    fprintf(stderr,
            "mrvi %s: %s %ld: this build has no threads (built without "
            "OpenMP: meson setup -Dopenmp=enabled); use 1\n",
            cmd, what, n);
    return -1;
  }
  return (int)n;
}

/* The value of an option that takes one: "--opt=V", "-oV" or the next
 * argument.  Returns NULL (with a message) if it is missing. */
static const char *option_value(const char *cmd, const char *arg,
                                const char *inline_value, int argc, char **argv,
                                int *i) {
  if (inline_value)
    return inline_value;
  if (*i + 1 >= argc) {
    fprintf(stderr, "mrvi %s: option '%s' needs a value\n", cmd, arg);
    return NULL;
  }
  return argv[++*i];
}

/* Parse the arguments after the command name.  allow_run enables
 * -o and --quiet.  Returns 0, or EXIT_INPUT after printing the reason. */
static int parse_args(const char *cmd, const char *usage, int allow_run,
                      int argc, char **argv, cli_args *a) {
  const char *const *known = allow_run ? run_options : check_options;
  int only_files = 0;
  memset(a, 0, sizeof *a);
  a->threads = -1; /* not given */
  a->overrides = calloc((size_t)argc + 1, sizeof *a->overrides);
  if (!a->overrides) {
    fprintf(stderr, "mrvi: out of memory\n");
    return EXIT_INPUT;
  }
  for (int i = 0; i < argc; i++) {
    const char *arg = argv[i];
    if (only_files || arg[0] != '-' || arg[1] == '\0') {
      if (a->file) {
        fprintf(stderr, "mrvi %s: unexpected argument '%s' (one FILE only)\n",
                cmd, arg);
        mrvi_cli_usage_short(cmd, usage);
        return EXIT_INPUT;
      }
      a->file = arg;
      continue;
    }
    if (strcmp(arg, "--") == 0) {
      only_files = 1;
      continue;
    }

    /* Split "--name=value"; short options may carry their value: "-oOUT". */
    char name[64];
    const char *inline_value = NULL;
    if (arg[1] == '-') {
      const char *eq = strchr(arg, '=');
      size_t len = eq ? (size_t)(eq - arg) : strlen(arg);
      if (len >= sizeof name)
        len = sizeof name - 1;
      memcpy(name, arg, len);
      name[len] = '\0';
      if (eq)
        inline_value = eq + 1;
    } else {
      name[0] = '-';
      name[1] = arg[1];
      name[2] = '\0';
      if (arg[2] != '\0')
        inline_value = arg + 2;
    }

    if (!strcmp(name, "-h") || !strcmp(name, "--help")) {
      a->help = 1;
    } else if (allow_run && (!strcmp(name, "-q") || !strcmp(name, "--quiet"))) {
      if (inline_value) {
        fprintf(stderr, "mrvi %s: option '%s' takes no value\n", cmd, name);
        return EXIT_INPUT;
      }
      a->quiet = 1;
    } else if (allow_run && !strcmp(name, "--force")) {
      if (inline_value) {
        fprintf(stderr, "mrvi %s: option '%s' takes no value\n", cmd, name);
        return EXIT_INPUT;
      }
      a->force = 1;
    } else if (allow_run &&
               (!strcmp(name, "-o") || !strcmp(name, "--output"))) {
      const char *v = option_value(cmd, name, inline_value, argc, argv, &i);
      if (!v)
        return EXIT_INPUT;
      if (!*v) {
        fprintf(stderr, "mrvi %s: empty output file name\n", cmd);
        return EXIT_INPUT;
      }
      a->output = v;
    } else if (allow_run &&
               (!strcmp(name, "--resume") || !strcmp(name, "--from"))) {
      const char *v = option_value(cmd, name, inline_value, argc, argv, &i);
      if (!v)
        return EXIT_INPUT;
      if (!*v) {
        fprintf(stderr, "mrvi %s: %s: empty file name\n", cmd, name);
        return EXIT_INPUT;
      }
      *(!strcmp(name, "--resume") ? &a->resume : &a->from) = v;
    } else if (!strcmp(name, "--threads")) {
      const char *v = option_value(cmd, name, inline_value, argc, argv, &i);
      if (!v || (a->threads = mrvi_cli_threads(cmd, "--threads", v)) < 0)
        return EXIT_INPUT;
    } else if (!strcmp(name, "-s") || !strcmp(name, "--set")) {
      const char *v = option_value(cmd, name, inline_value, argc, argv, &i);
      if (!v)
        return EXIT_INPUT;
      const char *eq = strchr(v, '=');
      if (!eq || eq == v) {
        fprintf(stderr,
                "mrvi %s: --set expects KEY=VALUE (e.g. "
                "integrator.micro_steps=5), got '%s'\n",
                cmd, v);
        return EXIT_INPUT;
      }
      a->overrides[a->n_overrides++] = v;
    } else {
      const char *hint = name[1] == '-' ? closest(name, known) : NULL;
      fprintf(stderr, "mrvi %s: unknown option '%s'", cmd, arg);
      if (hint)
        fprintf(stderr, "; did you mean '%s'?", hint);
      fputc('\n', stderr);
      mrvi_cli_usage_short(cmd, usage);
      return EXIT_INPUT;
    }
  }
  if (a->threads < 0 && getenv("MRVI_THREADS") &&
      (a->threads =
           mrvi_cli_threads(cmd, "MRVI_THREADS", getenv("MRVI_THREADS"))) < 0)
    return EXIT_INPUT;
  if (a->threads < 0)
    a->threads = 0; /* auto */
  if (!a->help && !a->file && !a->resume) {
    fprintf(stderr, "mrvi %s: missing FILE\n", cmd);
    mrvi_cli_usage_short(cmd, usage);
    return EXIT_INPUT;
  }
  return 0;
}

/* Load FILE with the overrides; print the loader's "file:line:col: message"
 * on failure.  Returns the system or NULL. */
static mrvi_system *load_system(const cli_args *a) {
  static char msg[MSG_LEN];
  mrvi_system *sys = NULL;
  msg[0] = '\0';
  int st = mrvi_system_load(a->file, a->overrides, a->n_overrides, &sys, msg,
                            sizeof msg);
  if (st < 0 || !sys) {
    if (msg[0]) {
      size_t len = strlen(msg);
      fputs(msg, stderr);
      if (msg[len - 1] != '\n')
        fputc('\n', stderr);
    } else {
      fprintf(stderr, "%s: %s\n", a->file, mrvi_strerror(st));
    }
    mrvi_system_free(sys);
    return NULL;
  }
  if (a->threads > 0)
    sys->settings.threads = a->threads;
  return sys;
}

static void restart_with_short_wait(void);

/* The thread count of a run of sys: --threads N or MRVI_THREADS N as
 * given, else (auto) mrvi_threads_auto's choice, its reason into why; more
 * than one thread chosen automatically restarts the command with libgomp's
 * short wait (bounded_wait), as an explicit count does before loading. */
static void choose_threads(const cli_args *a, mrvi_system *sys, char *why,
                           size_t len) {
  if (a->threads > 0) {
    sys->settings.threads = a->threads;
    mrvi_fmt(why, len, "--threads or MRVI_THREADS");
    return;
  }
  sys->settings.threads =
      mrvi_threads_auto(sys->model, &sys->settings, why, len);
  if (sys->settings.threads > 1)
    restart_with_short_wait();
}

/* ---------------------------------------------------------------------------
 * mrvi check
 * ------------------------------------------------------------------------- */

/* The loader's notes, one "[FILE: ]note: ..." line each. */
static void print_notes(FILE *f, const char *file, const char *notes) {
  for (const char *line = notes; line && *line;) {
    const char *end = strchr(line, '\n');
    const int len = end ? (int)(end - line) : (int)strlen(line);
    fprintf(f, "%s%snote: %.*s\n", file ? file : "", file ? ": " : "", len,
            line);
    line = end ? end + 1 : NULL;
  }
}

/* Print a list of coordinate names after a label, wrapped at 79 columns. */
static void print_names(const mrvi_model *m, const char *label,
                        const int *index, int count) {
  int col = printf("%-14s%d", label, count);
  const char *sep = count ? ": " : "";
  for (int i = 0; i < count; i++) {
    char buf[MRVI_NAME_MAX];
    const char *name = mrvi_model_coordinate_name(m, index[i], buf);
    int w = (int)(strlen(sep) + strlen(name));
    if (col + w > 79) {
      printf(",\n%14s", "");
      col = 14;
      sep = "";
    }
    col += printf("%s%s", sep, name);
    sep = ", ";
  }
  putchar('\n');
}

/* The tuning constants that differ from their defaults (doc/solver.md,
 * "Tuning"). */
static void print_tuning(const mrvi_settings *s) {
  int count;
  const mrvi_tuning_info *t = mrvi_tuning_table(&count);
  const char *label = "tuning";
  for (int i = 0; i < count; i++) {
    double v;
    if (mrvi_settings_get_tuning(s, t[i].name, &v) == 0 && v != t[i].value) {
      printf("%-14s%s = %g (default %g)\n", label, t[i].name, v, t[i].value);
      label = "";
    }
  }
}

static void print_rule(const char *label, mrvi_rule r, const char *grid) {
  printf("  %-12salpha = %g, gamma = %g, %s grid\n", label, r.alpha, r.gamma,
         grid);
}

static int cmd_check(int argc, char **argv) {
  cli_args a;
  int rc = parse_args("check", usage_check, 0, argc, argv, &a);
  if (rc || a.help) {
    if (!rc)
      fputs(usage_check, stdout);
    free(a.overrides);
    return rc;
  }
  mrvi_system *sys = load_system(&a);
  free(a.overrides);
  if (!sys)
    return EXIT_INPUT;

  const mrvi_model *m = sys->model;
  const mrvi_settings *s = &sys->settings;
  char msg[512], threads_why[256];
  choose_threads(&a, sys, threads_why, sizeof threads_why);
  if (mrvi_settings_check(s, msg, sizeof msg) < 0) {
    fprintf(stderr, "%s: %s\n", a.file, msg);
    mrvi_system_free(sys);
    return EXIT_INPUT;
  }

  int n = mrvi_model_n(m), ns = mrvi_model_n_slow(m), nf = mrvi_model_n_fast(m);
  int np = mrvi_model_n_particles(m), ne = mrvi_model_n_elements(m);
  long steps = mrvi_settings_n_steps(s);

  printf("%s: valid\n\n", a.file);
  printf("%-14s%s\n", "system", sys->name ? sys->name : mrvi_model_name(m));
  printf("%-14s%d (%d slow, %d fast)\n", "coordinates", n, ns, nf);
  if (np > 0)
    printf("%-14s%d in %d-D\n", "particles", np, mrvi_model_dimension(m));
  else
    printf("%-14s0\n", "particles");
  if (mrvi_model_n_bodies(m) > 0)
    printf("%-14s%d rigid in %d-D (doc/multibody.md)\n", "bodies",
           mrvi_model_n_bodies(m), mrvi_model_dimension(m));
  print_names(m, "slow", mrvi_model_slow_index(m), ns);
  print_names(m, "fast", mrvi_model_fast_index(m), nf);

  /* Masses and initial data, one coordinate a line (at most 200). */
  const double *q0 = mrvi_model_q0(m), *v0 = mrvi_model_v0(m);
  printf("%-14s%-16s %12s %12s %12s\n", "initial", "coordinate", "mass",
         "position", "velocity");
  for (int i = 0; i < n && i < 200; i++)
    printf("  %-28s %12.6g %12.6g %12.6g\n", MRVI_CNAME(m, i),
           mrvi_model_mass(m, i), q0[i], v0[i]);
  if (n > 200)
    printf("  ... and %d more coordinates\n", n - 200);
  printf("%-14s%d\n", "elements", ne);
  for (int e = 0; e < ne && e < 200; e++) {
    char buf[512];
    if (mrvi_model_describe_element(m, e, buf, sizeof buf) < 0)
      snprintf(buf, sizeof buf, "(no description)");
    printf("  %3d  %s\n", e, buf);
  }
  if (ne > 200)
    printf("  ... and %d more elements\n", ne - 200);
  const int nc = mrvi_model_n_constraints(m);
  printf("%-14s%d", "constraints", nc);
  if (nc > 0)
    printf(" (%d equation%s)", mrvi_model_constraint_rows(m),
           mrvi_model_constraint_rows(m) == 1 ? "" : "s");
  putchar('\n');
  for (int c = 0; c < nc; c++) {
    char buf[512];
    if (mrvi_model_describe_constraint(m, c, buf, sizeof buf) < 0)
      snprintf(buf, sizeof buf, "(no description)");
    printf("  %3d  %s\n", c, buf);
  }

  printf("\n%-14s%s\n", "scheme", s->scheme[0] ? s->scheme : "(custom)");
  print_rule("slow (V)", s->slow,
             s->slow_grid == MRVI_GRID_MACRO ? "macro" : "micro");
  print_rule("fast (W)", s->fast, "micro");
  printf("%-14s%g\n", "macro step", s->macro_step);
  printf("%-14s%d (micro step %g)\n", "micro steps", s->micro_steps,
         s->macro_step / s->micro_steps);
  printf("%-14s%g (%ld macro steps, last at t = %g)\n", "t_end", s->t_end,
         steps, (double)steps * s->macro_step);
  printf(
      "%-14stolerance %g%s, at most %d iterations\n", "newton", s->newton_tol,
      s->newton_criterion == MRVI_CRITERION_SCALED ? " (scaled by mass)" : "",
      s->newton_max_iter);
  {
    char why[512];
    const char *path = mrvi_solver_path(sys->model, s, why, sizeof why);
    printf("%-14s%s: %s\n", "solver", path ? path : "structured unavailable",
           why);
  }
  print_tuning(s);
  if (nc > 0)
    printf("%-14s%s form, tolerance %g, momentum projection %s\n",
           "constraints",
           s->constraint_form == MRVI_FORM_NULL_SPACE ? "null-space"
                                                      : "multipliers",
           s->constraint_tol, s->project_momenta ? "on" : "off");
  if (nc > 0 && s->constraint_form == MRVI_FORM_NULL_SPACE) {
    char why[8], tree_why[200] = "nullspace_tree 0";
    const int red = mrvi_constraints_rank(sys->model, mrvi_model_q0(sys->model),
                                          NULL, why, sizeof why);
    if (mrvi_model_free_bodies_only(sys->model) &&
        mrvi_model_dimension(sys->model) == 2)
      printf("%-14sanalytic (free planar rigid bodies: P = [[I, 0], [0, J "
             "d1], [0, J d2]]), nodal reparametrisation phi + u, R(th) d "
             "(fast bodies at every micro node)\n",
             "  null space");
    else if (mrvi_model_free_bodies_only(sys->model))
      printf("%-14sanalytic (free rigid bodies: P = [[I, 0], [0, -d1^], "
             "[0, -d2^], [0, -d3^]]), nodal reparametrisation phi + u, "
             "exp(th^) d (fast bodies at every micro node)\n",
             "  null space");
    else if (s->tuning.nullspace_tree &&
             mrvi_nullspace_tree_plan(sys->model, tree_why, sizeof tree_why) &&
             tree_why[0])
      printf("%-14sjoint-reduced with cut joints (closed loops, cut at %s: "
             "P = P_tree N, P_tree = blkdiag(P_i) (I - X)^-1 S of the "
             "spanning tree, N the null space of C = G_c P_tree of the cut "
             "joints' rows, solved sparse with one twist per body and one "
             "unknown per kept cut row); %d redundant row%s left out; nodal "
             "reparametrisation moving each body by its joint's free turns "
             "and slides, the cut joints held to the Newton tolerance\n",
             "  null space", tree_why, red > 0 ? red : 0, red == 1 ? "" : "s");
    else if (s->tuning.nullspace_tree && tree_why[0] == '\0')
      printf("%-14sjoint-reduced (open chains and trees of joints: P = "
             "blkdiag(P_i) (I - X)^-1 S, solved sparse with one twist per "
             "body), nodal reparametrisation moving each body by its "
             "joint's free turns and slides\n",
             "  null space");
    else if (s->tuning.nullspace_tree &&
             mrvi_nullspace_fast_plan(sys->model, tree_why, sizeof tree_why)) {
      char slow[340], slow_why[200];
      int n_slow_bodies = 0;
      for (int b = 0; b < mrvi_model_n_bodies(sys->model); b++)
        n_slow_bodies +=
            mrvi_model_rate(sys->model, mrvi_model_body_first(sys->model, b)) ==
            MRVI_SLOW;
      if (n_slow_bodies == 0)
        snprintf(slow, sizeof slow, "no slow bodies");
      else if (mrvi_nullspace_slow_side_free(sys->model))
        snprintf(slow, sizeof slow,
                 "slow bodies: analytic (free rigid bodies), reparametrised");
      else if (mrvi_nullspace_beside_plan(sys->model, slow_why,
                                          sizeof slow_why))
        snprintf(slow, sizeof slow,
                 "slow bodies: numerical (QR at q_k), reparametrised on their "
                 "joints");
      else
        snprintf(slow, sizeof slow,
                 "slow bodies: numerical (QR at q_k), their constraints to the "
                 "constraint tolerance (%s)",
                 slow_why);
      if (tree_why[0]) /* the fast forest's cut joints */
        printf("%-14sjoint-reduced at the micro nodes with cut joints "
               "(closed loops of fast bodies, cut at %s: P_f N at every "
               "micro node, P_f = blkdiag(P_i) (I - X)^-1 S of the fast "
               "spanning tree, N the null space of C = G_c P_f of the cut "
               "joints' kept rows); %d redundant row%s left out; nodal "
               "reparametrisation moving each fast body by its joint's free "
               "turns and slides, the cut joints held to the Newton "
               "tolerance; %s\n",
               "  null space", tree_why, red > 0 ? red : 0, red == 1 ? "" : "s",
               slow);
      else
        printf("%-14sjoint-reduced at the micro nodes (fast bodies in open "
               "chains and trees of joints, rooted at the ground or at a slow "
               "body's joint interpolated at the node: P_f = blkdiag(P_i) (I - "
               "X)^-1 S at every micro node), nodal reparametrisation moving "
               "each fast body by its joint's free turns and slides; %s\n",
               "  null space", slow);
    } else if (s->tuning.nullspace_tree &&
               mrvi_model_n_bodies(sys->model) == 0 &&
               mrvi_nullspace_rods_plan(sys->model, tree_why,
                                        sizeof tree_why)) {
      printf("%-14slink-local (open chains and trees of slow particles on "
             "rods: P = (I - X)^-1 S, S_t normal to particle t's rod, solved "
             "sparse with one unknown per rod), no reparametrisation (the "
             "rods held to the Newton tolerance)\n",
             "  null space");
    } else {
      const int red_f = red > 0 ? mrvi_nullspace_micro_redundant(
                                      sys->model, mrvi_model_q0(sys->model))
                                : 0;
      char at[160] = "";
      if (red_f > 0)
        snprintf(at, sizeof at,
                 " (%d of them enforced at the micro nodes: a closed loop of "
                 "fast bodies, left out of the QR at every micro node)",
                 red_f);
      printf("%-14snumerical (QR of the constraint gradients at every node); "
             "%d redundant row%s left out%s%s%s\n",
             "  null space", red > 0 ? red : 0, red == 1 ? "" : "s", at,
             mrvi_model_n_bodies(sys->model) > 0 ? "; not joint-reduced: "
                                                 : "; not link-local: ",
             tree_why);
    }
  }
  printf("%-14s%s (every %d, micro %s)\n", "output",
         sys->output_file ? sys->output_file : "-", sys->output_every,
         sys->output_micro ? "yes" : "no");
  if (mrvi_threads_supported())
    printf("%-14s%d (%s%s; element loops; the same results for every count; "
           "OMP_WAIT_POLICY %s, GOMP_SPINCOUNT %s)\n",
           "threads", s->threads, a.threads > 0 ? "" : "auto: ", threads_why,
           getenv("OMP_WAIT_POLICY") ? getenv("OMP_WAIT_POLICY") : "unset",
           getenv("GOMP_SPINCOUNT") ? getenv("GOMP_SPINCOUNT") : "unset");
  else
    printf("%-14s1 (this build has no threads: built without OpenMP)\n",
           "threads");
  const int bad_control = mrvi_cli_check_control(sys);
  if (sys->notes) {
    putchar('\n');
    print_notes(stdout, NULL, sys->notes);
  }
  mrvi_system_free(sys);
  return bad_control ? EXIT_INPUT : 0;
}

/* ---------------------------------------------------------------------------
 * mrvi run
 * ------------------------------------------------------------------------- */

/* Set by the signal handler: the signal number, 0 while running.  mrvi_run
 * polls it between steps, mrvi optimize after every evaluation
 * (cli_optimize.c).  The handler only stores to it (async-signal
 * safe); SA_RESETHAND makes a second Ctrl-C terminate at once. */
_Static_assert(_Generic((sig_atomic_t)0, int : 1, default : 0),
               "mrvi_run takes the stop flag as volatile int");
volatile sig_atomic_t mrvi_cli_stop_signal = 0;

/* Set while mrvi run loads its inputs (description, --resume, --from,
 * --controls), before anything is written: a signal then ends the process
 * at once, since a read inside HDF5 (a damaged file) never looks at the
 * flag. */
static volatile sig_atomic_t loading = 0;

static void on_signal(int sig) {
  if (loading)
    _exit(128 + sig);
  mrvi_cli_stop_signal = sig;
}

void mrvi_cli_install_handlers(void) {
  struct sigaction sa;
  memset(&sa, 0, sizeof sa);
  sa.sa_handler = on_signal;
  sigemptyset(&sa.sa_mask);
  sa.sa_flags = SA_RESETHAND;
  sigaction(SIGINT, &sa, NULL);
  sigaction(SIGTERM, &sa, NULL);
}

static double now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* "m:ss" or "h:mm:ss". */
static void format_duration(double sec, char *buf, size_t len) {
  if (!(sec >= 0) || sec > 1e8)
    sec = 0;
  long s = (long)(sec + 0.5);
  if (s >= 3600)
    snprintf(buf, len, "%ld:%02ld:%02ld", s / 3600, s / 60 % 60, s % 60);
  else
    snprintf(buf, len, "%ld:%02ld", s / 60, s % 60);
}

typedef struct run_ctx {
  mrvi_writer *writer;
  long n_steps;       /* N */
  int progress;       /* draw a progress bar on stderr */
  int drawn;          /* a bar is on screen */
  double t_start;     /* monotonic clock at start */
  double t_last_draw; /* last redraw */
} run_ctx;

static void progress_draw(run_ctx *c, long k) {
  enum { WIDTH = 24 };
  double elapsed = now() - c->t_start;
  double frac = c->n_steps > 0 ? (double)k / (double)c->n_steps : 1.0;
  char bar[WIDTH + 1], el[32], eta[32];
  int filled = (int)(frac * WIDTH);
  for (int i = 0; i < WIDTH; i++)
    bar[i] = i < filled ? '#' : '-';
  bar[WIDTH] = '\0';
  format_duration(elapsed, el, sizeof el);
  if (k > 0)
    format_duration(elapsed * (double)(c->n_steps - k) / (double)k, eta,
                    sizeof eta);
  else
    snprintf(eta, sizeof eta, "?");
  fprintf(stderr, "\r[%s] %3d%%  step %ld/%ld  %s elapsed  ETA %s\033[K", bar,
          (int)(100.0 * frac), k, c->n_steps, el, eta);
  fflush(stderr);
  c->drawn = 1;
}

static void progress_clear(run_ctx *c) {
  if (c->drawn) {
    fputs("\r\033[K", stderr);
    fflush(stderr);
    c->drawn = 0;
  }
}

/* Observer: write the record, then redraw the bar at most 10 times a second
 * (and not at all during the first half second, so short runs stay quiet). */
static int run_observe(void *user, const mrvi_record *r) {
  run_ctx *c = user;
  int st = mrvi_writer_observe(c->writer, r);
  if (st < 0)
    return st;
  if (c->progress) {
    double t = now();
    if (t - c->t_start >= 0.5 && t - c->t_last_draw >= 0.1) {
      progress_draw(c, r->k);
      c->t_last_draw = t;
    }
  }
  return 0;
}

/* Refuse to overwrite the description file itself with HDF5 output. */
static int same_file(const char *a, const char *b) {
  struct stat sa, sb;
  return stat(a, &sa) == 0 && stat(b, &sb) == 0 && sa.st_dev == sb.st_dev &&
         sa.st_ino == sb.st_ino;
}

/* k0: the node the run started from (0, or --resume / --from). */
static void print_summary(const mrvi_system *sys, const mrvi_summary *sum,
                          long n_steps, long k0, const char *out) {
  const mrvi_settings *s = &sys->settings;
  const char *name = sys->name ? sys->name : mrvi_model_name(sys->model);
  printf("%s: %s %ld of %ld macro steps, t = %g (%s, dT = %g, p = %d)\n", name,
         sum->status == MRVI_OK ? "completed" : "stopped after",
         k0 + sum->steps, n_steps, (double)(k0 + sum->steps) * s->macro_step,
         s->scheme[0] ? s->scheme : "custom", s->macro_step, s->micro_steps);
  if (k0 > 0)
    printf("  %-23s%ld (%ld steps in this run)\n", "started at node", k0,
           sum->steps);
  const char *path = mrvi_solver_path(sys->model, s, NULL, 0);
  printf("  %-23s%s\n", "solver path", path ? path : "none");
  printf("  %-23s%ld total, max %d per step\n", "Newton iterations",
         sum->iterations_total, sum->iterations_max);
  const mrvi_krylov_stats *ks = &sum->krylov;
  if (ks->cg_solves > 0)
    printf("  %-23s%ld block solves, %.2f iterations each, max %d\n",
           "CG (micro blocks)", ks->cg_solves,
           (double)ks->cg_iterations / (double)ks->cg_solves, ks->cg_max);
  if (ks->gmres_solves > 0)
    printf("  %-23s%ld solves, %.2f iterations each, max %d\n",
           "GMRES (slow unknowns)", ks->gmres_solves,
           (double)ks->gmres_iterations / (double)ks->gmres_solves,
           ks->gmres_max);
  if (ks->outer_steps + ks->outer_fallbacks > 0)
    printf(
        "  %-23s%ld steps, %.2f sweeps and %.2f gradient evaluations "
        "each per micro step; %ld left to Newton\n",
        "outer iteration", ks->outer_steps,
        (double)ks->outer_sweeps /
            (double)(ks->outer_steps + ks->outer_fallbacks),
        (double)ks->outer_evals /
            ((double)(ks->outer_steps + ks->outer_fallbacks) * s->micro_steps),
        ks->outer_fallbacks);
  if (ks->sweep_chord_sum != 0.0 && sum->steps > 0)
    /* (the sum to the last bit: its bits follow the order of the chord's
     * sums over the row, the same on every thread count) */
    printf("  %-23s%.2f gradient evaluations of W per micro step, "
           "relaxation ratios summed %.17g\n",
           "chord (sweep-cg)",
           (double)ks->sweep_evals_w / ((double)sum->steps * s->micro_steps),
           ks->sweep_chord_sum);
  if (ks->fallbacks > 0)
    fprintf(stderr,
            "warning: %ld linear solve%s fell back to a sparse LU (first: "
            "%s; see doc/solver.md)\n",
            ks->fallbacks, ks->fallbacks == 1 ? "" : "s", ks->fallback_reason);
  /* The energy error and what it is relative to (doc/output.md). */
  if (sum->energy_scale_kind == 0)
    printf("  %-23s%.3e\n", "max rel. energy error", sum->max_rel_energy_error);
  else if (sum->energy_scale_kind == 1)
    printf("  %-23s%.3e (H0 = 0: relative to the largest energy magnitude "
           "of the run, %.3e)\n",
           "max energy error", sum->max_rel_energy_error, sum->energy_scale);
  else
    printf("  %-23s%.3e (absolute: every energy is 0)\n",
           "max abs. energy error", sum->max_rel_energy_error);
  if (sum->roundoff_steps > 0)
    fprintf(stderr,
            "warning: %ld step%s stopped at the roundoff floor above the "
            "Newton tolerance %g (see doc/solver.md)\n",
            sum->roundoff_steps, sum->roundoff_steps == 1 ? "" : "s",
            s->newton_tol);
  /* Assembly and solve are measured on every step of short runs, else
   * estimated from sampled steps (mrvi_integrator_timing): say which. */
  if (sum->timing_estimated)
    printf("  %-23s%.3f s (assemble \u2248%.3f s, solve \u2248%.3f s: "
           "partly estimated from sampled steps)\n",
           "wall time", sum->wall_time, sum->assemble_time, sum->solve_time);
  else
    printf("  %-23s%.3f s (assemble %.3f s, solve %.3f s)\n", "wall time",
           sum->wall_time, sum->assemble_time, sum->solve_time);
  printf("  %-23s%s\n", "output", out);
  /* Why it stopped is printed once, on stderr, by cmd_run. */
  fflush(stdout);
}

/* --resume OUT.h5: the node to continue from and the system of its stored
 * description (which has the original overrides spliced in). */
static mrvi_system *load_resume(const cli_args *a, mrvi_stored_node **node,
                                int *extend) {
  char msg[MSG_LEN];
  /* One --set is allowed: a later integrator.t_end extends a completed run
   * in place. */
  *extend =
      a->n_overrides == 1 && !strncmp(a->overrides[0], "integrator.t_end=", 17);
  if (a->file || (a->n_overrides > 0 && !*extend) || a->output || a->from) {
    fprintf(stderr, "mrvi run: --resume takes the description, settings and "
                    "output file from OUT.h5; give no FILE, -o or --from "
                    "with it, and no --set but integrator.t_end=LATER (which "
                    "extends a completed run in place)\n");
    return NULL;
  }
  if (mrvi_stored_node_read(a->resume,
                            *extend ? MRVI_NODE_EXTEND : MRVI_NODE_RESUME, 0,
                            node, msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi run: --resume %s\n", msg);
    return NULL;
  }
  char name[4200];
  snprintf(name, sizeof name, "%s:/model/description", a->resume);
  mrvi_system *sys = NULL;
  if (mrvi_system_load_string((*node)->description, name, NULL, 0, &sys, msg,
                              sizeof msg) < 0 ||
      !sys) {
    fprintf(stderr, "mrvi run: --resume: %s\n", msg);
    mrvi_system_free(sys);
    mrvi_stored_node_free(*node);
    *node = NULL;
    return NULL;
  }
  int bad = mrvi_stored_run_check(a->resume, sys, msg, sizeof msg) < 0;
  if (bad)
    fprintf(stderr, "mrvi run: --resume %s; not resumed\n", msg);
  /* The stored run checked against its own description, an extension
   * loads that description again with the later t_end. */
  if (!bad && *extend) {
    mrvi_system_free(sys);
    sys = NULL;
    if (mrvi_system_load_string((*node)->description, name, a->overrides, 1,
                                &sys, msg, sizeof msg) < 0 ||
        !sys) {
      fprintf(stderr, "mrvi run: --resume --set %s: %s\n", a->overrides[0],
              msg);
      bad = 1;
    }
  }
  const long N = sys ? mrvi_settings_n_steps(&sys->settings) : 0;
  if (!bad && *extend && N <= (*node)->steps_completed) {
    fprintf(stderr,
            "mrvi run: --resume %s --set %s: the run already reached macro "
            "step %ld; integrator.t_end must give more steps (%ld)\n",
            a->resume, a->overrides[0], (*node)->steps_completed, N);
    bad = 1;
  }
  if (!bad && *extend && (*node)->steps_completed % (*node)->every != 0) {
    fprintf(stderr,
            "mrvi run: --resume %s: its last node (%ld) is not a multiple of "
            "output.every (%d), so the extended file would not be the file "
            "of a run to the later t_end; write a new file with --from\n",
            a->resume, (*node)->steps_completed, (*node)->every);
    bad = 1;
  }
  if (bad) {
    mrvi_system_free(sys);
    mrvi_stored_node_free(*node);
    *node = NULL;
    return NULL;
  }
  return sys;
}

/* The --from file against its own /model/description, loaded here. */
static int from_file_consistent(const char *path, const char *description) {
  char msg[MSG_LEN], name[4200];
  snprintf(name, sizeof name, "%s:/model/description", path);
  mrvi_system *own = NULL;
  int st = mrvi_system_load_string(description, name, NULL, 0, &own, msg,
                                   sizeof msg);
  if (st == MRVI_OK && own)
    st = mrvi_stored_run_check(path, own, msg, sizeof msg);
  else if (st == MRVI_OK)
    st = MRVI_EINVAL;
  if (st < 0)
    fprintf(stderr, "mrvi run: --from %s\n", msg);
  mrvi_system_free(own);
  return st;
}

/* --from OUT.h5[:k]: stored node k (default: the last) of an earlier run,
 * checked against the system of FILE. */
static mrvi_stored_node *load_from(const char *spec, const mrvi_system *sys,
                                   char *path, size_t path_len) {
  char msg[MSG_LEN];
  if (strlen(spec) >= path_len) {
    fprintf(stderr,
            "mrvi run: --from: a path of %zu bytes, longer than "
            "the system's limit (%zu); not read\n",
            strlen(spec), path_len - 1);
    return NULL;
  }
  snprintf(path, path_len, "%s", spec);
  long which = MRVI_NODE_LAST;
  char *colon = strrchr(path, ':');
  if (colon && colon[1]) {
    char *end;
    errno = 0;
    long k = strtol(colon + 1, &end, 10);
    if (*end == '\0') {
      if (errno || k < 0) {
        fprintf(stderr, "mrvi run: --from %s: node index must be >= 0\n", spec);
        return NULL;
      }
      which = k;
      *colon = '\0';
    }
  }
  mrvi_stored_node *node = NULL;
  if (mrvi_stored_node_read(path, which, mrvi_model_n(sys->model), &node, msg,
                            sizeof msg) < 0) {
    fprintf(stderr, "mrvi run: --from %s\n", msg);
    return NULL;
  }
  if (from_file_consistent(path, node->description) < 0) {
    mrvi_stored_node_free(node);
    return NULL;
  }
  const mrvi_settings *s = &sys->settings;
  const long N = mrvi_settings_n_steps(s);
  const char *bad = NULL;
  char why[512];
  if (node->n != mrvi_model_n(sys->model)) {
    snprintf(why, sizeof why, "it has %d coordinates, the model %d", node->n,
             mrvi_model_n(sys->model));
    bad = why;
  } else if (node->macro_step != s->macro_step) {
    snprintf(why, sizeof why,
             "its macro_step %.17g differs from integrator.macro_step %.17g",
             node->macro_step, s->macro_step);
    bad = why;
  } else if (node->k >= N) {
    snprintf(why, sizeof why,
             "node %ld (t = %g) is not before the last node %ld (t_end = %g)",
             node->k, node->t, N, s->t_end);
    bad = why;
  }
  if (bad) {
    fprintf(stderr, "mrvi run: --from %s: %s\n", path, bad);
    mrvi_stored_node_free(node);
    return NULL;
  }
  return node;
}

static int cmd_run(int argc, char **argv) {
  cli_args a;
  int rc = parse_args("run", usage_run, 1, argc, argv, &a);
  if (rc || a.help) {
    if (!rc)
      fputs(usage_run, stdout);
    free(a.overrides);
    return rc;
  }
  /* Loading: Ctrl-C and SIGTERM end the process (nothing is written yet);
   * from the output's creation on they only raise the stop flag. */
  loading = 1;
  mrvi_cli_install_handlers();
  mrvi_stored_node *node = NULL;
  int extend = 0;
  mrvi_system *sys =
      a.resume ? load_resume(&a, &node, &extend) : load_system(&a);
  free(a.overrides);
  char from_path[4096] = "";
  if (sys && a.from &&
      !(node = load_from(a.from, sys, from_path, sizeof from_path))) {
    mrvi_system_free(sys);
    sys = NULL;
  }
  loading = 0;
  if (!sys)
    return EXIT_INPUT;
  char threads_why[256];
  choose_threads(&a, sys, threads_why, sizeof threads_why);
  /* Without micro output nothing reads a step's inner micro nodes. */
  sys->settings.micro_last_only = !sys->output_micro && !sys->output_micro_slow;
  char tmsg[256];
  if (mrvi_settings_check(&sys->settings, tmsg, sizeof tmsg) < 0) {
    fprintf(stderr, "mrvi run: %s\n", tmsg);
    mrvi_system_free(sys);
    mrvi_stored_node_free(node);
    return EXIT_INPUT;
  }
  if (mrvi_cli_stop_signal) { /* interrupted while loading: write nothing */
    mrvi_system_free(sys);
    mrvi_stored_node_free(node);
    return 128 + (int)mrvi_cli_stop_signal;
  }
  if (!a.resume)
    print_notes(stderr, a.file, sys->notes);
  else if (!a.quiet)
    fprintf(stderr, "mrvi run: %s %s at macro node %ld (t = %g)\n",
            extend ? "extending" : "resuming", a.resume, node->k, node->t);
  if (a.resume && node->n != mrvi_model_n(sys->model)) {
    fprintf(stderr,
            "mrvi run: --resume %s: /macro/q has %d columns, the stored "
            "description's model %d\n",
            a.resume, node->n, mrvi_model_n(sys->model));
    mrvi_system_free(sys);
    mrvi_stored_node_free(node);
    return EXIT_INPUT;
  }

  /* Output file: --resume, -o, else output.file of the description. */
  const char *out = a.resume   ? a.resume
                    : a.output ? a.output
                               : sys->output_file;
  if (!out || !*out) {
    fprintf(stderr, "%s: no output file (give -o OUT.h5 or output.file)\n",
            a.file);
    mrvi_system_free(sys);
    return EXIT_INPUT;
  }
  /* An output name taken from the description (output.file, or name + .h5)
   * stays below the current directory: no control characters, not
   * absolute, no ".." component (a description from elsewhere must not
   * replace an earlier output in ../../x.h5 or /abs/x.h5), and a
   * name-derived one no directory part at all. */
  if (!a.output && !a.resume) {
    int bad = out[0] == '/';
    for (const char *c = out; *c; c++) {
      bad |= (unsigned char)*c < 0x20 || *c == 0x7f;
      bad |= (c == out || c[-1] == '/') && c[0] == '.' && c[1] == '.' &&
             (c[2] == '/' || c[2] == '\0');
    }
    const char *nm = sys->name ? sys->name : "";
    size_t ln = strlen(nm);
    if (!bad && ln > 0 && !strncmp(out, nm, ln) && !strcmp(out + ln, ".h5"))
      bad = strchr(nm, '/') != NULL || nm[0] == '.';
    if (bad) {
      fprintf(stderr,
              "%s: output file name '%s' (from the description) is absolute, "
              "leaves the current directory or contains control "
              "characters; give -o OUT.h5 or a plain output.file\n",
              a.file, out);
      mrvi_system_free(sys);
      return EXIT_INPUT;
    }
  }
  if (a.file && same_file(out, a.file)) {
    fprintf(stderr, "mrvi run: output file '%s' is the description file\n",
            out);
    mrvi_system_free(sys);
    mrvi_stored_node_free(node);
    return EXIT_INPUT;
  }
  if (a.from && node) {
    if (same_file(out, from_path)) {
      fprintf(stderr,
              "mrvi run: output file '%s' is the --from file (--from starts "
              "a new run; --resume %s continues that one)\n",
              out, out);
      mrvi_system_free(sys);
      mrvi_stored_node_free(node);
      return EXIT_INPUT;
    }
  }

  char msg[MSG_LEN];
  msg[0] = '\0';
  mrvi_writer_options opt = mrvi_system_writer_options(sys);
  opt.force = a.force;
  opt.resume = a.resume != NULL;
  opt.resume_k = node ? node->k : 0;
  opt.extend = extend;
  mrvi_writer *w = NULL;
  if (mrvi_writer_open(out, sys->model, &sys->settings, &opt, &w, msg,
                       sizeof msg) < 0 ||
      !w) {
    if (msg[0])
      fprintf(stderr, "mrvi run: %s\n", msg);
    else
      fprintf(stderr, "mrvi run: cannot create '%s'\n", out);
    mrvi_system_free(sys);
    mrvi_stored_node_free(node);
    return EXIT_INPUT;
  }

  run_ctx ctx = {
      .writer = w,
      .n_steps = mrvi_settings_n_steps(&sys->settings),
      .progress = !a.quiet && isatty(STDERR_FILENO),
      .t_start = now(),
  };
  mrvi_summary sum;
  memset(&sum, 0, sizeof sum);
  /* From a stored node; a resume at node 0 starts as the original run. */
  mrvi_start start = {0};
  if (node)
    start =
        (mrvi_start){.k = node->k,
                     .q = node->q,
                     .p = node->p,
                     .energy = a.resume ? node->energy : NULL,
                     .n_torsion = node->n_torsion,
                     .torsion_angle = node->torsion_angle,
                     .n_chord = a.resume ? node->n_chord : 0,
                     .chord_history = a.resume ? node->chord_history : NULL};
  int st = mrvi_run_from(sys->model, &sys->settings,
                         node && (a.from || node->k > 0) ? &start : NULL,
                         run_observe, &ctx, &mrvi_cli_stop_signal, &sum);
  mrvi_stored_node_free(node);
  node = NULL;
  if (st < 0 && sum.status == MRVI_OK)
    sum.status = st;
  progress_clear(&ctx);
  mrvi_writer_set_summary(w, &sum);

  /* Close in every case: the file records why the run stopped. */
  const char *reason = "completed";
  if (st < 0)
    reason = sum.message[0] ? sum.message : mrvi_strerror(st);
  char close_msg[1024];
  close_msg[0] = '\0';
  int cst = mrvi_writer_close(w, reason, close_msg, sizeof close_msg);

  if (!a.quiet)
    print_summary(sys, &sum, ctx.n_steps, start.k, out);
  /* The XDMF file for ParaView: the steps the file holds (particles and
   * rigid bodies). */
  if (sys->output_xdmf &&
      (mrvi_model_n_particles(sys->model) > 0 ||
       mrvi_model_n_bodies(sys->model) > 0) &&
      cst == MRVI_OK)
    mrvi_cli_write_xdmf(out, a.quiet, a.force);
  if (sum.warning[0])
    fprintf(stderr, "mrvi run: warning: %s\n", sum.warning);
  if (st == MRVI_EINTERRUPTED)
    fprintf(stderr, "mrvi run: %s: %s\n",
            mrvi_cli_stop_signal == SIGTERM ? "SIGTERM" : "SIGINT", reason);
  else if (st < 0 && !(st == MRVI_EIO && cst < 0)) /* else: the writer's */
    fprintf(stderr, "mrvi run: error: %s\n", reason);
  if (cst < 0)
    fprintf(stderr, "mrvi run: %s '%s': %s\n",
            st == MRVI_EIO ? "error: output stopped; writing" : "closing", out,
            close_msg[0] ? close_msg : mrvi_strerror(cst));
  mrvi_system_free(sys);

  if (st == MRVI_EINTERRUPTED)
    return 128 + (mrvi_cli_stop_signal ? (int)mrvi_cli_stop_signal : SIGINT);
  return st < 0 || cst < 0 ? EXIT_RUN : 0;
}

/* ---------------------------------------------------------------------------
 * main
 * ------------------------------------------------------------------------- */
static const char *const commands[] = {
    "run",    "check",    "help",   "converge", "stability",
    "timing", "optimize", "export", "batch",    NULL};
static const char *const global_options[] = {"--help", "--version", NULL};

static int unknown_command(const char *cmd) {
  const char *hint = closest(cmd, cmd[0] == '-' ? global_options : commands);
  fprintf(stderr, "mrvi: unknown %s '%s'", cmd[0] == '-' ? "option" : "command",
          cmd);
  if (hint)
    fprintf(stderr, "; did you mean '%s'?", hint);
  fputs("\n\n", stderr);
  usage_error(usage_main);
  return EXIT_INPUT;
}

/* Help text of a command, or NULL. */
static const char *command_usage(const char *cmd) {
  if (!strcmp(cmd, "run"))
    return usage_run;
  if (!strcmp(cmd, "check"))
    return usage_check;
  if (!strcmp(cmd, "help"))
    return usage_main;
  if (!strcmp(cmd, "converge"))
    return mrvi_usage_converge;
  if (!strcmp(cmd, "stability"))
    return mrvi_usage_stability;
  if (!strcmp(cmd, "timing"))
    return mrvi_usage_timing;
  if (!strcmp(cmd, "optimize"))
    return mrvi_usage_optimize;
  if (!strcmp(cmd, "export"))
    return mrvi_usage_export;
  if (!strcmp(cmd, "batch"))
    return mrvi_usage_batch;
  return NULL;
}

/* Whether the command line or MRVI_THREADS asks for more than one thread
 * (mrvi_cli_threads checks the values later). */
static int asks_threads(int argc, char **argv) {
  const char *e = getenv("MRVI_THREADS");
  int many = e && atoi(e) > 1;
  for (int i = 2; i < argc; i++)
    if (!strcmp(argv[i], "--threads") && i + 1 < argc)
      many |= atoi(argv[i + 1]) > 1;
    else if (!strncmp(argv[i], "--threads=", 10))
      many |= atoi(argv[i] + 10) > 1;
  return many;
}

/* libgomp's threads spin at each barrier up to GOMP_SPINCOUNT = 300 000
 * iterations before they sleep when OMP_WAIT_POLICY is unset; on a
 * machine with more runnable processes than cores a spinning thread holds
 * the core its partner needs, and the threaded loops ran up to 17x slower
 * than one thread.  Sleeping at once (OMP_WAIT_POLICY=passive) makes each
 * barrier a wake-up, which on a virtual machine costs an exit to the host,
 * about what two threads save between two barriers.  So a command on more
 * than one thread spins briefly, WAIT_SPINS iterations (libgomp's own
 * count for more threads than cores; about 25 us on the machine measured,
 * doc/performance/threads.md, "Threads"), then sleeps.  libgomp reads its
 * environment once, as the program loads, so the command restarts itself
 * once with GOMP_SPINCOUNT set, unless the environment sets
 * GOMP_SPINCOUNT or OMP_WAIT_POLICY (the user's choice stands).  If the
 * restart fails the command goes on with libgomp's default. */
#define WAIT_SPINS "1000"
static char **main_argv; /* for the restart */
static void restart_with_short_wait(void) {
  if (!mrvi_threads_supported() || getenv("OMP_WAIT_POLICY") ||
      getenv("GOMP_SPINCOUNT") || !main_argv)
    return;
  fflush(NULL);
  if (setenv("GOMP_SPINCOUNT", WAIT_SPINS, 1) == 0)
    execv("/proc/self/exe", main_argv);
  unsetenv("GOMP_SPINCOUNT");
}
static void bounded_wait(int argc, char **argv) {
  if (asks_threads(argc, argv))
    restart_with_short_wait();
}

int main(int argc, char **argv) {
  main_argv = argv;
  if (argc >= 2 && (!strcmp(argv[1], "run") || !strcmp(argv[1], "check") ||
                    !strcmp(argv[1], "batch")))
    bounded_wait(argc, argv);
  if (argc < 2) {
    usage_error(usage_main);
    return EXIT_INPUT;
  }
  const char *cmd = argv[1];
  if (!strcmp(cmd, "--help") || !strcmp(cmd, "-h")) {
    fputs(usage_main, stdout);
    return 0;
  }
  if (!strcmp(cmd, "--version")) {
    printf("mrvi %s\n", mrvi_version());
    return 0;
  }
  if (!strcmp(cmd, "help")) {
    if (argc == 2) {
      fputs(usage_main, stdout);
      return 0;
    }
    const char *u = command_usage(argv[2]);
    if (!u)
      return unknown_command(argv[2]);
    if (argc > 3) {
      fprintf(stderr, "mrvi help: unexpected argument '%s'\n", argv[3]);
      usage_error(usage_main);
      return EXIT_INPUT;
    }
    fputs(u, stdout);
    return 0;
  }
  for (int i = 2; !strcmp(cmd, "run") && i < argc; i++)
    if (!strncmp(argv[i], "--controls", 10)) /* replay (cli_optimize.c) */
      return mrvi_cmd_optimize(argc - 1, argv + 1);
  if (!strcmp(cmd, "run"))
    return cmd_run(argc - 2, argv + 2);
  if (!strcmp(cmd, "check"))
    return cmd_check(argc - 2, argv + 2);
  /* The studies (cli_study.c) take argv[0] = the command name. */
  if (!strcmp(cmd, "converge"))
    return mrvi_cmd_converge(argc - 1, argv + 1);
  if (!strcmp(cmd, "stability"))
    return mrvi_cmd_stability(argc - 1, argv + 1);
  if (!strcmp(cmd, "timing"))
    return mrvi_cmd_timing(argc - 1, argv + 1);
  if (!strcmp(cmd, "optimize"))
    return mrvi_cmd_optimize(argc - 1, argv + 1);
  if (!strcmp(cmd, "export"))
    return mrvi_cmd_export(argc - 1, argv + 1);
  if (!strcmp(cmd, "batch"))
    return mrvi_cmd_batch(argc - 1, argv + 1);
  return unknown_command(cmd);
}
