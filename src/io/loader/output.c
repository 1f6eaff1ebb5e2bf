/* `output:` of a description file: the HDF5 file and what it records. */
#include "io/loader/loader_internal.h"

#include <stdlib.h>
#include <string.h>

static const char *const output_keys[] = {
    "file", "every", "micro", "micro_slow", "xdmf", "flush_interval"};

int mrvi_ld_output(loader *L, struct fy_node *out) {
  mrvi_system *sys = L->sys;
  struct fy_node *n;
  const char *file;
  int st;
  if ((st = mrvi_ld_want_mapping(L, out, "output")) ||
      (st = mrvi_ld_check_keys(L, out, "output", output_keys,
                               COUNT(output_keys), NULL, 0)))
    return st;
  if ((n = mrvi_ld_get(out, "file"))) {
    if ((st = mrvi_ld_as_string(L, n, "file", &file)))
      return st;
    char *copy = strdup(file);
    if (!copy)
      return mrvi_ld_fail_nomem(L);
    free(sys->output_file);
    sys->output_file = copy;
  }
  if ((n = mrvi_ld_get(out, "every"))) {
    if ((st = mrvi_ld_as_int(L, n, "every", &sys->output_every)))
      return st;
    if (sys->output_every < 1)
      return mrvi_ld_fail(L, n, "every must be >= 1, got %d",
                          sys->output_every);
  }
  if ((n = mrvi_ld_get(out, "micro")) &&
      (st = mrvi_ld_as_bool(L, n, "micro", &sys->output_micro)))
    return st;
  if ((n = mrvi_ld_get(out, "micro_slow")) &&
      (st = mrvi_ld_as_bool(L, n, "micro_slow", &sys->output_micro_slow)))
    return st;
  if ((n = mrvi_ld_get(out, "xdmf")) &&
      (st = mrvi_ld_as_bool(L, n, "xdmf", &sys->output_xdmf)))
    return st;
  if ((n = mrvi_ld_get(out, "flush_interval"))) {
    if ((st = mrvi_ld_as_number(L, n, "flush_interval",
                                &sys->output_flush_interval)))
      return st;
    if (!(sys->output_flush_interval > 0))
      return mrvi_ld_fail(L, n, "flush_interval must be > 0 seconds, got %g",
                          sys->output_flush_interval);
  }
  return MRVI_OK;
}
