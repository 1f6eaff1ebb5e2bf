/* `mrvi batch`: many runs of one description (doc/batch.md).  The case
 * table, the worker processes and the master file are src/batch and
 * src/io; this file reads the command line and prints. */
#include "batch/batch.h"
#include "cli.h"

#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

enum { EXIT_INPUT = 1, EXIT_RUN = 2, MSG_LEN = 8192 };

const char mrvi_usage_batch[] =
    "Usage: mrvi batch FILE -o OUT.h5 [--vary KEY=V1,V2,...]...\n"
    "                  [--vary KEY=linspace(a,b,n)|logspace(a,b,n)]... "
    "[--zip]\n"
    "                  [--seeds N [PERTURBATION]...] [--optimize] [--jobs N]\n"
    "                  [--threads T] [--quiet]\n"
    "       mrvi batch --resume OUT.h5 [--jobs N] [--threads T] [--quiet]\n"
    "\n"
    "Run FILE once per case: a case is 'mrvi run FILE --set KEY=VALUE' for\n"
    "one value of every --vary.  Several --vary form the Cartesian product\n"
    "(the last one varies fastest); --zip pairs their values instead (equal\n"
    "lengths).  Every case is loaded and checked before the first one runs.\n"
    "Case C is written to OUT.cases/case_CCCC.h5 in the layout of 'mrvi run';\n"
    "OUT.h5 holds the case table (/cases: overrides, values, seed, status,\n"
    "stop_reason, steps, wall_time, energy_error) and external links\n"
    "/runs/case_CCCC to the case files (doc/batch.md).\n"
    "\n"
    "The description's batch: section may hold vary, zip, seeds, command\n"
    "(run or optimize), the perturbations (velocity_std, position_std,\n"
    "position_distribution, temperature, rotation_std, rotations,\n"
    "control_std) and jobs in the same vocabulary; the command line\n"
    "overrides or extends it (a --vary of a key the file varies replaces\n"
    "the file's values).\n"
    "\n"
    "Options:\n"
    "  -o, --output OUT.h5   the master file\n"
    "      --vary KEY=VALUES a key of FILE (dotted path, as --set) and its\n"
    "                        values: a comma-separated list, linspace(a,b,n)\n"
    "                        or logspace(a,b,n) (10^a .. 10^b)\n"
    "      --zip             pair the --vary lists instead of their product\n"
    "      --seeds N         an ensemble: every parameter case N times, with\n"
    "                        seeds 0..N-1 (the seed column of the table)\n"
    "  PERTURBATION, of the seeded cases, one or more of:\n"
    "      --velocity-std S  perturb the initial velocities of a seeded case\n"
    "                        by S times standard normal numbers of its seed\n"
    "                        (projected onto the constraints); the numbers\n"
    "                        depend on the seed alone (doc/batch.md)\n"
    "      --position-std S, --position-distribution gaussian|uniform,\n"
    "      --temperature T, --rotation-std A, --rotations uniform\n"
    "                        perturb a seeded case's positions (projected),\n"
    "                        set thermal velocities (zero net momentum of\n"
    "                        particles and bodies) or\n"
    "                        turn its bodies (doc/batch.md, Ensembles)\n"
    "      --optimize        cases are 'mrvi optimize' (doc/batch.md)\n"
    "      --control-std S   multi-start: perturb a seeded case's initial\n"
    "                        guess by S times normal numbers of its seed\n"
    "  -j, --jobs N          worker processes (default: the idle cores, as\n"
    "                        --threads auto counts them, divided by\n"
    "                        --threads; per MPI rank its share)\n"
    "      --threads T|auto  threads of each case (default and auto: 1);\n"
    "                        jobs x threads stay within the idle cores\n"
    "                        unless both are given; results do not depend on "
    "T\n"
    "      --resume OUT.h5   run the cases of OUT.h5 that did not finish (a\n"
    "                        killed or interrupted batch)\n"
    "  -q, --quiet           no line per finished case\n"
    "  -h, --help            show this help\n"
    "\n"
    "A case that fails (Newton failure, non-finite state) is recorded with\n"
    "its reason and the others go on; an optimize case that does not\n"
    "converge is recorded as failed with the optimiser's status.\n"
    "Ctrl-C or SIGTERM: no case starts any more and the running ones stop\n"
    "at their next macro step, their files valid (--resume runs the rest).\n"
    "\n"
    "MPI (built with meson -Dmpi=enabled): 'mpiexec -n R mrvi batch ...'\n"
    "hands the cases out over R ranks, each with its own --jobs workers\n"
    "(default: its share of the machine's cores); the files are those of one\n"
    "process (doc/batch.md).  Every rank must run the same mrvi binary.\n"
    "\n"
    "Exit status:\n"
    "  0    every case completed\n"
    "  1    nothing was run: bad arguments, a case refused by the loader\n"
    "  2    the batch ran and at least one case failed or was not run (a\n"
    "       worker process killed: --resume runs it)\n"
    "  130  interrupted by SIGINT (143: SIGTERM)\n";

typedef struct batch_ctx {
  const char *out;
  int quiet, ranks, finished, failed, unfinished, total, optimize;
  int n_cases;
  char *seen; /* n_cases: a result came back for the case */
} batch_ctx;

/* Close the master file f after the status st of what was done with it
 * (its message in msg): a failure to close becomes the message.  0, or -1
 * after printing the message. */
static int table_close(mrvi_batch_file *f, int st, char *msg, size_t len) {
  char close_msg[MSG_LEN];
  if (mrvi_batch_file_close(f, close_msg, sizeof close_msg) < 0 && st == 0) {
    st = MRVI_EIO;
    snprintf(msg, len, "%s", close_msg);
  }
  if (st < 0) {
    fprintf(stderr, "mrvi batch: %s\n", msg);
    return -1;
  }
  return 0;
}

/* A finished case: its row of the table, and a line. */
static int on_done(void *user, const mrvi_batch_result *res) {
  batch_ctx *b = user;
  char msg[MSG_LEN];
  /* Open for this row only, without HDF5's file lock (batch_writer.c):
   * readers (h5py, h5dump) see the table while the batch runs, and a
   * reader holding it open does not block the row. */
  mrvi_batch_file *f = NULL;
  int st = mrvi_batch_file_open(b->out, NULL, NULL, &f, msg, sizeof msg);
  if (st == 0)
    st = mrvi_batch_file_row(f, res, msg, sizeof msg);
  if (table_close(f, st, msg, sizeof msg) < 0)
    return -1;
  b->finished++;
  if (res->c >= 0 && res->c < b->n_cases)
    b->seen[res->c] = 1;
  b->failed += res->status == MRVI_BATCH_FAILED;
  b->unfinished += res->status == MRVI_BATCH_PENDING;
  char where[32] = "";
  if (b->ranks > 1)
    snprintf(where, sizeof where, " (rank %d)", res->rank);
  if ((!b->quiet || res->status != MRVI_BATCH_COMPLETED) && b->optimize)
    fprintf(stderr,
            "mrvi batch: [%d/%d] case %d%s: %s (cost %.12e, violation "
            "%.3e, %d evaluations, NLopt %s, %.3f s)\n",
            b->finished, b->total, res->c, where, res->reason, res->cost,
            res->violation, res->evaluations, res->nlopt[0] ? res->nlopt : "-",
            res->wall_time);
  else if (!b->quiet || res->status != MRVI_BATCH_COMPLETED)
    fprintf(stderr,
            "mrvi batch: [%d/%d] case %d%s: %s (%ld steps, %.3f s, "
            "energy error %.3e)\n",
            b->finished, b->total, res->c, where, res->reason, res->steps,
            res->wall_time, res->energy_error);
  return 0;
}

/* An optimize batch: the best case over the whole table (this run's
 * cases and those of earlier runs of a resumed batch) into /best_case,
 * and a line. */
static int print_best(const char *out, int quiet) {
  char msg[MSG_LEN];
  mrvi_batch_file *f = NULL;
  int best = -1;
  double cost = NAN;
  int st = mrvi_batch_file_open(out, NULL, NULL, &f, msg, sizeof msg);
  if (st == 0)
    st = mrvi_batch_file_best(f, &best, &cost, msg, sizeof msg);
  if (table_close(f, st, msg, sizeof msg) < 0)
    return MRVI_EIO;
  char file[4096] = "";
  mrvi_batch_case_file(out, best, 0, file, sizeof file);
  if (!quiet && best >= 0)
    printf("%s: best case %d, cost %.12e (%s)\n", out, best, cost, file);
  else if (!quiet)
    printf("%s: no case converged\n", out);
  return 0;
}

/* After a signal: every case of todo that got no result (not started) is
 * recorded as pending with why, in one opening of the master file; the
 * number of such cases, or -1 (said on stderr). */
static int record_not_run(const batch_ctx *b, const int *todo, int n_todo,
                          const char *sig) {
  char msg[MSG_LEN];
  mrvi_batch_file *f = NULL;
  int st = mrvi_batch_file_open(b->out, NULL, NULL, &f, msg, sizeof msg);
  int n = 0;
  mrvi_batch_result res;
  memset(&res, 0, sizeof res);
  res.status = MRVI_BATCH_PENDING;
  res.energy_error = res.cost = res.violation = NAN;
  snprintf(res.reason, sizeof res.reason,
           "not run: the batch was stopped by %s before this case started "
           "(--resume runs it)",
           sig);
  for (int k = 0; st == 0 && k < n_todo; k++)
    if (!b->seen[todo[k]]) {
      res.c = todo[k];
      st = mrvi_batch_file_row(f, &res, msg, sizeof msg);
      n++;
    }
  return table_close(f, st, msg, sizeof msg) < 0 ? -1 : n;
}

/* A positive int argument, or -1. */
static int parse_count(const char *s, int zero_ok) {
  char *end;
  errno = 0;
  long v = strtol(s, &end, 10);
  if (errno || *end || end == s || v < (zero_ok ? 0 : 1) || v > 1000000)
    return -1;
  return (int)v;
}

static int usage_fail(const char *what) {
  fprintf(stderr, "mrvi batch: %s\n", what);
  mrvi_cli_usage_short("batch", mrvi_usage_batch);
  return EXIT_INPUT;
}

/* --velocity-std, --control-std, --position-std, --temperature,
 * --rotation-std S into pt: 1 when `a` is one of them (*rc set when its
 * value is not a number), else 0. */
static int std_option(const char *a, const char *v, mrvi_batch_perturb *pt,
                      int *rc) {
  static const char *const names[] = {"--velocity-std", "--control-std",
                                      "--position-std", "--temperature",
                                      "--rotation-std"};
  double *const to[] = {&pt->velocity_std, &pt->control_std, &pt->position_std,
                        &pt->temperature, &pt->rotation_std};
  for (int i = 0; i < 5; i++)
    if (!strcmp(a, names[i])) {
      char *end, what[64];
      *to[i] = strtod(v, &end);
      if (*end || end == v || isnan(*to[i])) {
        snprintf(what, sizeof what, "%s takes a number", a);
        *rc = usage_fail(what);
      }
      return 1;
    }
  return 0;
}

/* The description's `batch:` section under the command line: the file's
 * --vary entries in its order, a --vary of the same key on the command
 * line in place of the file's, the other --vary after them; --zip,
 * --seeds, the perturbations, --optimize and --jobs over the file's
 * (doc/batch.md).  On
 * return *axes holds every axis (the command line's moved into it). */
static int with_section(const mrvi_system *base, mrvi_batch_axis **axes,
                        int *n_axes, int *zip, int *seeds, int *command,
                        mrvi_batch_perturb *pt, int *jobs, char *msg,
                        size_t len) {
  mrvi_batch_section sec;
  if (mrvi_batch_section_read(base, &sec, msg, len) < 0)
    return -1;
  mrvi_batch_axis *all =
      calloc((size_t)(sec.n_vary + *n_axes) + 1, sizeof *all);
  int n = 0, rc = all ? 0 : -1;
  if (!all)
    snprintf(msg, len, "out of memory");
  char text[1024];
  for (int i = 0; rc == 0 && i < sec.n_vary; i++, n++)
    if (mrvi_batch_axis_parse(sec.vary[i], &all[n], text, sizeof text) < 0) {
      snprintf(msg, len, "%s: batch.vary: %s", sec.where[i], text);
      rc = -1;
    }
  const int n_file = n;
  for (int j = 0; rc == 0 && j < *n_axes; j++) {
    int k = 0;
    while (k < n_file && strcmp(all[k].key, (*axes)[j].key))
      k++;
    if (k < n_file)
      mrvi_batch_axis_clear(&all[k]);
    else
      k = n++;
    all[k] = (*axes)[j];
    memset(&(*axes)[j], 0, sizeof **axes);
  }
  if (rc == 0) {
    free(*axes);
    *axes = all;
    *n_axes = n;
    *zip = *zip || sec.zip == 1;
    if (*seeds < 0)
      *seeds = sec.seeds > 0 ? sec.seeds : 0;
    /* NAN, -1: not given on the command line; then the file's, or 0. */
    double *const mine[] = {&pt->velocity_std, &pt->control_std,
                            &pt->position_std, &pt->temperature,
                            &pt->rotation_std};
    const double file[] = {sec.velocity_std, sec.control_std, sec.position_std,
                           sec.temperature, sec.rotation_std};
    for (int i = 0; i < 5; i++)
      if (isnan(*mine[i]))
        *mine[i] = isnan(file[i]) ? 0.0 : file[i];
    if (pt->position_uniform < 0)
      pt->position_uniform = sec.position_uniform > 0;
    if (pt->rotation_uniform < 0)
      pt->rotation_uniform = sec.rotation_uniform > 0;
    if (*jobs == 0 && sec.jobs > 0)
      *jobs = sec.jobs;
    if (*command < 0)
      *command = sec.command >= 0 ? sec.command : MRVI_BATCH_RUN;

  } else {
    for (int i = 0; all && i < n; i++)
      mrvi_batch_axis_clear(&all[i]);
    free(all);
  }
  mrvi_batch_section_free(&sec);
  return rc;
}

/* The threads of each case: the given count, else (auto, the default) 1:
 * the jobs fill the idle cores, so jobs x threads stay within them
 * (doc/batch.md, "All cores"). */
static int case_threads(int given) { return given > 0 ? given : 1; }

/* A rank other than 0 of an MPI batch: the plan from rank 0, then its
 * cases (cli_batch_mpi.c). */
static int batch_follow(void) {
  mrvi_batch_plan plan;
  memset(&plan, 0, sizeof plan);
  const char *master = NULL;
  int jobs = 0;
  char msg[MSG_LEN];
  if (mrvi_batch_mpi_share(0, &plan, &master, &jobs)) {
    if (jobs == 0)
      jobs = mrvi_batch_mpi_jobs();
    /* A signal on this rank stops its cases; it takes no more. */
    mrvi_cli_install_handlers();
    if (mrvi_batch_mpi_run(&plan, master, NULL, 0, jobs, &mrvi_cli_stop_signal,
                           NULL, NULL, msg, sizeof msg) < 0 &&
        msg[0])
      fprintf(stderr, "mrvi batch: %s\n", msg);
  }
  free((char *)master);
  mrvi_batch_plan_free(&plan);
  return mrvi_batch_mpi_end(0);
}

int mrvi_cmd_batch(int argc, char **argv) {
  const char *file = NULL, *out = NULL, *resume = NULL;
  int zip = 0, seeds = -1, jobs = 0, quiet = 0, n_axes = 0, command = -1;
  int threads = 0;
  /* seeds -1, jobs 0, threads 0, command -1, NAN and -1 in pt: not given */
  mrvi_batch_perturb pt = {.velocity_std = NAN,
                           .control_std = NAN,
                           .position_std = NAN,
                           .temperature = NAN,
                           .rotation_std = NAN,
                           .position_uniform = -1,
                           .rotation_uniform = -1};
  int perturbs = 0; /* a perturbation option given */
  char msg[MSG_LEN];
  int rank = 0, ranks = 1;
  if (mrvi_batch_mpi_begin(&rank, &ranks, msg, sizeof msg) < 0) {
    if (msg[0])
      fprintf(stderr, "mrvi batch: %s\n", msg);
    return EXIT_INPUT;
  }
  if (rank > 0)
    return batch_follow();
  mrvi_batch_axis *axes = calloc((size_t)argc + 1, sizeof *axes);
  int rc = axes ? 0 : EXIT_INPUT;
  for (int i = 1; rc == 0 && i < argc; i++) {
    const char *a = argv[i];
    const char *v = i + 1 < argc ? argv[i + 1] : NULL;
    int takes =
        !strcmp(a, "-o") || !strcmp(a, "--output") || !strcmp(a, "--vary") ||
        !strcmp(a, "--seeds") || !strcmp(a, "--velocity-std") ||
        !strcmp(a, "--control-std") || !strcmp(a, "--position-std") ||
        !strcmp(a, "--position-distribution") || !strcmp(a, "--temperature") ||
        !strcmp(a, "--rotation-std") || !strcmp(a, "--rotations") ||
        !strcmp(a, "-j") || !strcmp(a, "--jobs") || !strcmp(a, "--resume") ||
        !strcmp(a, "--threads");
    if (takes && !v) {
      snprintf(msg, sizeof msg, "%s needs a value", a);
      rc = usage_fail(msg);
      break;
    }
    i += takes;
    if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
      fputs(mrvi_usage_batch, stdout);
      rc = -1;
    } else if (!strcmp(a, "-o") || !strcmp(a, "--output")) {
      out = v;
    } else if (!strcmp(a, "--resume")) {
      resume = v;
    } else if (!strcmp(a, "--vary")) {
      if (mrvi_batch_axis_parse(v, &axes[n_axes], msg, sizeof msg) < 0)
        rc = usage_fail(msg);
      else
        n_axes++;
    } else if (!strcmp(a, "--zip")) {
      zip = 1;
    } else if (!strcmp(a, "-q") || !strcmp(a, "--quiet")) {
      quiet = 1;
    } else if (!strcmp(a, "--seeds")) {
      if ((seeds = parse_count(v, 0)) < 0)
        rc = usage_fail("--seeds takes a count 0..1000000");
    } else if (!strcmp(a, "-j") || !strcmp(a, "--jobs")) {
      if ((jobs = parse_count(v, 0)) < 1)
        rc = usage_fail("--jobs takes a count 1..1000000");
    } else if (!strcmp(a, "--threads")) {
      if ((threads = mrvi_cli_threads("batch", "--threads", v)) < 0)
        rc = EXIT_INPUT;
    } else if (!strcmp(a, "--optimize")) {
      command = MRVI_BATCH_OPTIMIZE;
    } else if (std_option(a, v, &pt, &rc)) {
      perturbs = 1;
    } else if (!strcmp(a, "--position-distribution")) {
      perturbs = 1;
      pt.position_uniform = !strcmp(v, "uniform");
      if (strcmp(v, "uniform") && strcmp(v, "gaussian"))
        rc = usage_fail("--position-distribution takes gaussian or uniform");
    } else if (!strcmp(a, "--rotations")) {
      perturbs = 1;
      pt.rotation_uniform = 1;
      if (strcmp(v, "uniform"))
        rc = usage_fail("--rotations takes uniform (or give --rotation-std)");
    } else if (a[0] == '-') {
      snprintf(msg, sizeof msg, "unknown option '%s'", a);
      rc = usage_fail(msg);
    } else if (!file) {
      file = a;
    } else {
      snprintf(msg, sizeof msg, "unexpected argument '%s'", a);
      rc = usage_fail(msg);
    }
  }
  if (rc == 0 && resume &&
      (file || out || n_axes || zip || seeds >= 0 || perturbs || command >= 0))
    rc = usage_fail("--resume takes the cases from OUT.h5: give no FILE, -o, "
                    "--vary, --zip, --seeds, --optimize or a perturbation "
                    "with it");
  if (rc == 0 && !resume && (!file || !out))
    rc = usage_fail("give FILE and -o OUT.h5 (or --resume OUT.h5)");
  if (rc == 0 && file && out) {
    struct stat sa, sb;
    if (stat(file, &sa) == 0 && stat(out, &sb) == 0 && sa.st_dev == sb.st_dev &&
        sa.st_ino == sb.st_ino)
      rc = usage_fail("the output file is the description file");
  }

  mrvi_batch_plan plan;
  memset(&plan, 0, sizeof plan);
  int *status = NULL;
  /* The plan: from FILE and the options, or from OUT.h5. */
  if (rc == 0 && resume) {
    mrvi_batch_file *f = NULL;
    out = resume;
    if (mrvi_batch_file_open(resume, &plan, &status, &f, msg, sizeof msg) < 0) {
      fprintf(stderr, "mrvi batch: --resume %s\n", msg);
      rc = EXIT_INPUT;
    }
    mrvi_batch_file_close(f, msg, sizeof msg);
  } else if (rc == 0) {
    mrvi_system *base = NULL;
    if (mrvi_system_load(file, NULL, 0, &base, msg, sizeof msg) < 0 || !base) {
      fprintf(stderr, "%s\n", msg);
      rc = EXIT_INPUT;
    } else if (with_section(base, &axes, &n_axes, &zip, &seeds, &command, &pt,
                            &jobs, msg, sizeof msg) < 0) {
      fprintf(stderr, "mrvi batch: %s\n", msg);
      rc = EXIT_INPUT;
    } else if (mrvi_batch_plan_build(&plan, base->description, file, axes,
                                     n_axes, zip, seeds, command, &pt, msg,
                                     sizeof msg) < 0) {
      rc = usage_fail(msg);
    } else if (!quiet && pt.temperature > 0 && base->model->n_particles == 0 &&
               base->model->n_bodies == 0) {
      /* The sum of the momenta of plain coordinates (elongations, angles)
       * is no physical momentum: nothing is removed from it. */
      fprintf(stderr,
              "mrvi batch: %s has plain coordinates only: --temperature "
              "draws Maxwell-Boltzmann momenta per coordinate, no net "
              "momentum removed (doc/batch.md, Ensembles)\n",
              file);
    }
    mrvi_system_free(base);
  }
  for (int i = 0; axes && i < n_axes; i++)
    mrvi_batch_axis_clear(&axes[i]);
  free(axes);
  /* Every case is checked before any runs. */
  if (rc == 0 && mrvi_batch_plan_check(&plan, msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi batch: %s\n", msg);
    rc = EXIT_INPUT;
  }
  /* Until here a signal ends the process (nothing is written); from the
   * master file on it stops the batch (the worker processes inherit the
   * handlers and take the stop from this process). */
  if (rc == 0)
    mrvi_cli_install_handlers();
  if (rc == 0 && !resume) {
    mrvi_batch_file *f = NULL;
    if (mrvi_batch_file_create(out, &plan, &f, msg, sizeof msg) < 0 ||
        mrvi_batch_file_close(f, msg, sizeof msg) < 0) {
      fprintf(stderr, "mrvi batch: %s\n", msg);
      rc = EXIT_INPUT;
    }
  }
  /* The cases left to run: all, or the pending ones. */
  int *todo = rc == 0 ? malloc((size_t)plan.n_cases * sizeof *todo) : NULL;
  int n_todo = 0;
  if (rc == 0 && !todo) {
    fprintf(stderr, "mrvi batch: out of memory\n");
    rc = EXIT_INPUT;
  }
  for (int c = 0; rc == 0 && c < plan.n_cases; c++)
    if (!status || status[c] == MRVI_BATCH_PENDING)
      todo[n_todo++] = c;
  /* MPI: the other ranks get the plan (or leave), and each rank takes the
   * cores of its share of the machine unless --jobs says. */
  /* Each case on one thread unless --threads says, on every rank (the
   * plan carries it): the jobs and ranks fill the cores, one process the
   * idle ones (as --threads auto counts them: mrvi_cores_idle). */
  plan.threads = case_threads(threads);
  int jobs_given = jobs;
  mrvi_batch_mpi_share(rc == 0, &plan, &out, &jobs_given);
  if (rc == 0 && jobs == 0) {
    jobs = ranks > 1 ? mrvi_batch_mpi_jobs() : mrvi_cores_idle();
    /* jobs x threads within them unless --jobs says */
    jobs = jobs / plan.threads > 1 ? jobs / plan.threads : 1;
  }
  /* (mrvi_batch_mpi_jobs is collective: not called here again) */

  batch_ctx ctx = {.out = out,
                   .quiet = quiet,
                   .ranks = ranks,
                   .total = n_todo,
                   .optimize = plan.command == MRVI_BATCH_OPTIMIZE,
                   .n_cases = plan.n_cases,
                   .seen =
                       rc == 0 ? calloc((size_t)plan.n_cases + 1, 1) : NULL};
  if (rc == 0 && !ctx.seen) {
    fprintf(stderr, "mrvi batch: out of memory\n");
    rc = EXIT_RUN;
  }
  if (rc == 0) {
    if (!quiet && ranks > 1)
      fprintf(stderr, "mrvi batch: %d case%s%s on %d ranks x %d job%s -> %s\n",
              n_todo, n_todo == 1 ? "" : "s", resume ? " left" : "", ranks,
              jobs, jobs == 1 ? "" : "s", out);
    else if (!quiet)
      fprintf(stderr,
              "mrvi batch: %d case%s%s on %d job%s x %d thread%s -> %s\n",
              n_todo, n_todo == 1 ? "" : "s", resume ? " left" : "",
              jobs < n_todo ? jobs : n_todo, jobs == 1 ? "" : "s", plan.threads,
              plan.threads == 1 ? "" : "s", out);
    int st = mrvi_batch_mpi_run(&plan, out, todo, n_todo, jobs,
                                &mrvi_cli_stop_signal, on_done, &ctx, msg,
                                sizeof msg);
    if (st < 0 && msg[0])
      fprintf(stderr, "mrvi batch: %s\n", msg);
    const int sig = (int)mrvi_cli_stop_signal;
    const char *sig_name = sig == SIGTERM ? "SIGTERM" : "SIGINT";
    int not_started = 0;
    if (sig && (not_started = record_not_run(&ctx, todo, n_todo, sig_name)) < 0)
      st = MRVI_EIO;
    if (sig)
      fprintf(stderr,
              "mrvi batch: %s: %d running case%s stopped, %d not started "
              "(mrvi batch --resume %s runs them)\n",
              sig_name, ctx.unfinished, ctx.unfinished == 1 ? "" : "s",
              not_started, out);
    if (!quiet)
      printf("%s: %s%d of %d cases completed, %d failed, %d not run\n", out,
             sig ? "interrupted: " : "",
             ctx.finished - ctx.failed - ctx.unfinished, n_todo, ctx.failed,
             n_todo - (ctx.finished - ctx.unfinished));
    if (st == 0 && ctx.optimize && print_best(out, quiet) < 0)
      st = MRVI_EIO;
    rc = st < 0 || ctx.failed > 0 || ctx.unfinished > 0 || ctx.finished < n_todo
             ? EXIT_RUN
             : 0;
    if (sig)
      rc = 128 + sig;
  }
  free(ctx.seen);
  free(todo);
  free(status);
  mrvi_batch_plan_free(&plan);
  return mrvi_batch_mpi_end(rc < 0 ? 0 : rc);
}
