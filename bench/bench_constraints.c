/* Cost of the two constraint forms (doc/constraints.md) on the shipped
 * constrained systems: for every system, form and p the table gives the size
 * and nonzeros of the Newton matrix, the Newton iterations and the time per
 * macro step (assembly + solve).  The macro step of the description file is
 * kept and p varies, so larger p resolves the fast motion more finely at the
 * same macro step.  A measurement, not a test: no thresholds.
 *
 *   bench_constraints [--quick] [--steps N] [--p 1,10,100] [FILE.yaml...]
 *
 * Defaults: N = 100 macro steps, p in {1, 10, 100}, the four constrained
 * systems under systems/ (found through $MRVI_SOURCE_ROOT or "..").
 * Runs whose Newton iteration fails print the reason in the last column. */
#include "bench_util.h"
#include "mrvi.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { MAX_P = 16 };

static const char usage[] =
    "Usage: bench_constraints [--quick] [--steps N] [--p P1,P2,...] "
    "[FILE.yaml...]\n"
    "\n"
    "Time per macro step and Newton matrix size of the multiplier and\n"
    "null-space forms; default N = 100 steps, p = 1,10,100 and the\n"
    "constrained systems of systems/.  --quick: N = 10, p = 1,10.\n";

static const char *const default_systems[] = {
    "systems/cart_pendulum.yaml", "systems/spring_ring_rod.yaml",
    "systems/triatomic.yaml", "systems/pendulum_chain.yaml"};

/* One run: N macro steps of a system with form and p; prints a row. */
static void bench_one(const char *path, const char *form, int p, int steps) {
  char ov[3][64];
  snprintf(ov[0], sizeof ov[0], "integrator.micro_steps=%d", p);
  snprintf(ov[1], sizeof ov[1], "integrator.constraints.form=%s", form);
  const char *overrides[2] = {ov[0], ov[1]};
  mrvi_system *sys = NULL;
  char msg[1024];
  if (mrvi_system_load(path, overrides, 2, &sys, msg, sizeof msg) != 0) {
    printf("%-18s %-12s %5d  load failed: %s\n", "?", form, p, msg);
    return;
  }
  mrvi_integrator *it = NULL;
  if (mrvi_integrator_create(sys->model, &sys->settings, &it, msg,
                             sizeof msg) != 0) {
    printf("%-18s %-12s %5d  %s\n", sys->name, form, p, msg);
    mrvi_system_free(sys);
    return;
  }
  long iters = 0;
  int done = 0;
  const char *why = "";
  for (; done < steps; done++) {
    if (mrvi_integrator_step(it) != 0) {
      why = mrvi_integrator_errmsg(it);
      break;
    }
    iters += mrvi_integrator_last_iterations(it);
  }
  double ta = 0.0, ts = 0.0;
  mrvi_integrator_timing(it, &ta, &ts);
  const double per = done > 0 ? (ta + ts) / done : 0.0;
  printf("%-18s %-12s %5d %7d %9ld %6.2f %12.1f %12.1f %12.1f  %s\n", sys->name,
         form, p, mrvi_integrator_system_size(it),
         mrvi_integrator_system_nnz(it), done ? (double)iters / done : 0.0,
         1e6 * per, done ? 1e6 * ta / done : 0.0, done ? 1e6 * ts / done : 0.0,
         why);
  fflush(stdout);
  mrvi_integrator_free(it);
  mrvi_system_free(sys);
}

int main(int argc, char **argv) {
  int steps = 100, ps[MAX_P] = {1, 10, 100}, np = 3;
  const char *files[64];
  int nfiles = 0;
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--help") || !strcmp(argv[i], "-h")) {
      fputs(usage, stdout);
      return 0;
    } else if (!strcmp(argv[i], "--quick")) { /* seconds: meson --benchmark */
      steps = 10;
      ps[0] = 1, ps[1] = 10, np = 2;
    } else if (!strcmp(argv[i], "--steps") && i + 1 < argc) {
      steps = atoi(argv[++i]);
    } else if (!strcmp(argv[i], "--p") && i + 1 < argc) {
      np = 0;
      for (char *s = strtok(argv[++i], ","); s && np < MAX_P;
           s = strtok(NULL, ","))
        ps[np++] = atoi(s);
    } else if (argv[i][0] == '-') {
      fprintf(stderr, "bench_constraints: unknown option '%s'\n%s", argv[i],
              usage);
      return 1;
    } else if (nfiles < 64) {
      files[nfiles++] = argv[i];
    }
  }
  if (steps < 1 || np == 0) {
    fputs(usage, stderr);
    return 1;
  }
  static char paths[4][4096];
  if (nfiles == 0) {
    const char *root = getenv("MRVI_SOURCE_ROOT");
    for (int i = 0; i < 4; i++) {
      snprintf(paths[i], sizeof paths[i], "%s/%s", root ? root : "..",
               default_systems[i]);
      files[nfiles++] = paths[i];
    }
  }
  printf("# build: %s\n", bench_build());
  printf("# %d macro steps per run; times in microseconds per macro step\n",
         steps);
  printf("%-18s %-12s %5s %7s %9s %6s %12s %12s %12s\n", "system", "form", "p",
         "size", "nnz", "it/st", "step [us]", "assemble", "solve");
  const char *forms[2] = {"multipliers", "null-space"};
  for (int f = 0; f < nfiles; f++)
    for (int a = 0; a < np; a++)
      for (int k = 0; k < 2; k++)
        bench_one(files[f], forms[k], ps[a], steps);
  return 0;
}
