/* The automatic thread count (`mrvi run --threads auto`, the command's
 * default; doc/performance/threads.md, "The automatic thread count").
 *
 * A loop of the step runs on threads only when it has at least two parts
 * of tuning.thread_chunk entries (mrvi.h, MRVI_TUNING_LIST): the fast or
 * slow coordinates (the explicit sweep, the kinetic parts of the momenta,
 * schur-krylov's CG rows) or the records of V or W (their gradients and
 * values, one record per element).  A model whose longest such loop is
 * shorter never enters a parallel region, and more threads only cost it
 * the command's restart (cli.c, bounded_wait); a model with one that long
 * gets the cores this process may use that no other task is running on:
 * on a machine busier than its cores two threads lost to one
 * (doc/performance/threads.md), a thread waiting at each barrier for its
 * partner to get a core back. */
#include "integrator/integrator.h"

int mrvi_threads_auto(const mrvi_model *m, const mrvi_settings *s, char *why,
                      size_t len) {
  char dummy[1];
  if (!why || len == 0) {
    why = dummy;
    len = sizeof dummy;
  }
  if (!mrvi_threads_supported()) {
    mrvi_fmt(why, len, "this build has no threads (built without OpenMP)");
    return 1;
  }
  const int cores = mrvi_cores();
  if (!m || !s) {
    mrvi_fmt(why, len, "no model");
    return 1;
  }
  /* The longest loop that can be cut into parts. */
  int elems[2] = {0, 0};
  for (int e = 0; e < m->n_elements; e++)
    elems[m->erecs[e].potential == MRVI_FAST]++;
  const int size[4] = {m->n_fast, m->n_slow, elems[MRVI_FAST],
                       elems[MRVI_SLOW]};
  static const char *const what[4] = {"fast coordinates", "slow coordinates",
                                      "elements of W", "elements of V"};
  int big = 0;
  for (int i = 1; i < 4; i++)
    big = size[i] > size[big] ? i : big;
  const long need = 2L * s->tuning.thread_chunk;
  if (size[big] < need) {
    mrvi_fmt(why, len,
             "no loop long enough for threads: the longest, %d %s, is under "
             "two parts of tuning.thread_chunk %d",
             size[big], what[big], s->tuning.thread_chunk);
    return 1;
  }
  if (cores < 2) {
    mrvi_fmt(why, len, "one core available to this process");
    return 1;
  }
  const int others = mrvi_tasks_others();
  if (others >= cores - 1) { /* (at most one core idle: one thread) */
    mrvi_fmt(why, len,
             "%d other task%s running on the %d cores available to this "
             "process (a loop of %d %s could take them)",
             others, others == 1 ? "" : "s", cores, size[big], what[big]);
    return 1;
  }
  const int free_cores = others > 0 ? cores - others : cores;
  mrvi_fmt(why, len,
           "the %s available to this process%s: %d %s, at least two parts "
           "of tuning.thread_chunk %d",
           free_cores == cores ? "cores" : "idle cores",
           free_cores == cores ? "" : " (others busy)", size[big], what[big],
           s->tuning.thread_chunk);
  return free_cores;
}
