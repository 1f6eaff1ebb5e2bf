/* libFuzzer target: the description-file loader with overrides.
 *
 * The input is the description text; every line that starts with
 * "# set: " (the convention of tests/bad_input/) also becomes one --set
 * override, so the seeds in systems/ and tests/bad_input/ carry theirs.
 * The description is read up to its first NUL byte (as a string).  Any
 * crash, sanitizer report, leak or timeout is a finding; a rejected input
 * is not.
 *
 * A model the loader admits that is small (at most STEP_MAX_N coordinates,
 * STEP_MAX_P micro steps a macro step) then takes STEP_COUNT macro steps,
 * on two threads where the build has them (the description's
 * tuning.thread_chunk decides the partitions): a crafted file reaches the
 * integrator's creation from the model (the compact springs' records, the
 * partitions of the records over threads, the solver path's blocks) and
 * its solvers, not only the loader.  A step may fail (Newton, a singular
 * matrix): only a crash, a report or a leak is a finding.
 *
 * Built twice (tests/fuzz/meson.build): fuzz_loader steps as above;
 * fuzz_load (-DFUZZ_STEP=0) only loads, several times the inputs a second,
 * so that CI's bounded time covers more of the loader (tests/fuzz/run.sh
 * runs both on one corpus). */
#include "mrvi.h"

#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define MAX_OVERRIDES 16
#define STEP_MAX_N 64
#define STEP_MAX_P 16
#define STEP_COUNT 2
#ifndef FUZZ_STEP
#define FUZZ_STEP 1
#endif

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  char *text = malloc(size + 1);
  if (!text)
    return 0;
  memcpy(text, data, size);
  text[size] = '\0';
  /* Overrides: copies of the "# set: " lines, up to their newline. */
  char *ov[MAX_OVERRIDES];
  int n_ov = 0;
  for (char *line = text; line && n_ov < MAX_OVERRIDES;) {
    char *nl = strchr(line, '\n');
    size_t len = nl ? (size_t)(nl - line) : strlen(line);
    if (len >= 7 && !strncmp(line, "# set: ", 7)) {
      ov[n_ov] = malloc(len - 6);
      if (!ov[n_ov])
        break;
      memcpy(ov[n_ov], line + 7, len - 7);
      ov[n_ov][len - 7] = '\0';
      n_ov++;
    }
    line = nl ? nl + 1 : NULL;
  }
  char msg[1024];
  mrvi_system *sys = NULL;
  int st = mrvi_system_load_string(text, "fuzz.yaml", (const char *const *)ov,
                                   n_ov, &sys, msg, sizeof msg);
  /* The contract: a system on success, none and a message on failure. */
  if ((st == MRVI_OK) != (sys != NULL) || (st != MRVI_OK && !msg[0]))
    abort();
  if (FUZZ_STEP && sys && mrvi_model_n(sys->model) <= STEP_MAX_N &&
      sys->settings.micro_steps <= STEP_MAX_P) {
    mrvi_settings s = sys->settings;
    s.threads = mrvi_threads_supported() ? 2 : 1;
    /* (iteration and sample counts the file may raise a thousandfold
     * bounded, so that a step stays within the fuzzer's timeout) */
#define AT_MOST(x, n) ((x) = (x) < (n) ? (x) : (n))
    AT_MOST(s.newton_max_iter, 50);
    AT_MOST(s.tuning.slow_newton_max, 50);
    AT_MOST(s.tuning.outer_max, 50);
    AT_MOST(s.tuning.shoot_max, 8);
    AT_MOST(s.tuning.krylov_max_it, 1000);
    AT_MOST(s.tuning.slow_samples, 64);
    AT_MOST(s.tuning.slow_hess_samples, 64);
#undef AT_MOST
    mrvi_integrator *it = NULL;
    if (mrvi_integrator_create(sys->model, &s, &it, msg, sizeof msg) == MRVI_OK)
      for (int k = 0; k < STEP_COUNT && mrvi_integrator_step(it) == MRVI_OK;
           k++)
        ;
    mrvi_integrator_free(it);
  }
  mrvi_system_free(sys);
  for (int i = 0; i < n_ov; i++)
    free(ov[i]);
  free(text);
  return 0;
}
