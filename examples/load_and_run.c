/* Load a description file and run it: the smallest complete mrvi program.
 *
 *   load_and_run FILE.yaml [KEY=VALUE]...
 *
 * Loads FILE with the overrides (each as `mrvi run --set KEY=VALUE`),
 * integrates it with mrvi_run, printing the energy at ten macro nodes
 * through an observer, and prints the steps taken and the maximal relative
 * energy error max_k |H_k - H_0| / E (doc/output.md, "Energy error").
 * Nothing is written to disk; for the HDF5 file of `mrvi run`, pass
 * mrvi_writer_observe and a writer from mrvi_writer_open as the observer.
 *
 * Build against an installed mrvi (README.md, "Use the library from C"):
 *   cc load_and_run.c $(pkg-config --cflags --libs mrvi) \
 *      -Wl,-rpath,$(pkg-config --variable=libdir mrvi) -o load_and_run
 *   ./load_and_run PREFIX/share/mrvi/systems/fpu.yaml integrator.t_end=30
 */
#include <mrvi.h>
#include <stdio.h>

/* The observer sees every macro node k = 0 .. N with the state (q, p in
 * model order), its energies and the Newton statistics of the step. */
static int show(void *user, const mrvi_record *r) {
  const long every = *(const long *)user;
  if (r->k % every == 0)
    printf("  t = %9.4f  H = %.12f\n", r->t, r->energy);
  return 0; /* a status < 0 would stop the run */
}

int main(int argc, char **argv) {
  if (argc < 2) {
    fprintf(stderr, "usage: %s FILE.yaml [KEY=VALUE]...\n", argv[0]);
    return 1;
  }
  /* Load: a description error comes back as "file:line:col: message". */
  char msg[4096];
  mrvi_system *sys = NULL;
  const char *const *overrides = (const char *const *)(argv + 2);
  if (mrvi_system_load(argv[1], overrides, argc - 2, &sys, msg, sizeof msg)) {
    fprintf(stderr, "%s\n", msg);
    return 1;
  }
  const mrvi_settings *s = &sys->settings;
  const long n_steps = mrvi_settings_n_steps(s);
  long every = n_steps >= 10 ? n_steps / 10 : 1;
  printf("%s: %d coordinates (%d slow, %d fast), %s, dT = %g, p = %d\n",
         sys->name, mrvi_model_n(sys->model), mrvi_model_n_slow(sys->model),
         mrvi_model_n_fast(sys->model), s->scheme, s->macro_step,
         s->micro_steps);

  /* Run: the summary is filled also when the run fails. */
  mrvi_summary sum;
  const int st = mrvi_run(sys->model, s, show, &every, NULL, &sum);
  printf("steps %ld of %ld, Newton iterations %ld\n", sum.steps, n_steps,
         sum.iterations_total);
  printf("max relative energy error %.9e\n", sum.max_rel_energy_error);
  if (st < 0)
    fprintf(stderr, "%s\n", sum.message);
  mrvi_system_free(sys);
  return st < 0 ? 2 : 0;
}
