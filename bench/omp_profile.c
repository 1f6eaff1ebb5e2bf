/* libgomp's GOMP_parallel interposed (omp_profile.h): the program's own
 * definition is the one libmrvi.so's calls bind to (the executable's
 * symbols come first in the dynamic lookup); it forwards to libgomp's
 * (dlsym RTLD_NEXT) with the region's function wrapped in a timer of each
 * thread's CPU clock.  Regions entered inside a region (nested, run by
 * one thread) are not timed apart: they are part of the outer region's
 * work. */
#define _GNU_SOURCE
#include "omp_profile.h"

#include <dlfcn.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

enum { MAX_TEAM = 256 };

typedef void (*gomp_parallel_fn)(void (*)(void *), void *, unsigned, unsigned);
typedef void (*gomp_barrier_fn)(void);

static gomp_parallel_fn real_parallel;
static gomp_barrier_fn real_barrier;
static long n_barriers; /* (team thread 0's: written by it alone) */
static _Thread_local int depth;
static double slot[MAX_TEAM];
static long n_regions;
static double sum_main, sum_all, sum_max;

static double thread_cpu(void) {
  struct timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

typedef struct wrapped {
  void (*fn)(void *);
  void *data;
} wrapped;

static void run_wrapped(void *arg) {
  const wrapped *w = arg;
  const int t = omp_get_thread_num();
  const double c0 = thread_cpu();
  depth++;
  w->fn(w->data);
  depth--;
  if (t < MAX_TEAM)
    slot[t] = thread_cpu() - c0;
}

void GOMP_parallel(void (*fn)(void *), void *data, unsigned num_threads,
                   unsigned flags);
void GOMP_parallel(void (*fn)(void *), void *data, unsigned num_threads,
                   unsigned flags) {
  if (!real_parallel) {
    /* (POSIX's way to convert dlsym's object pointer, without the cast
     * ISO C does not define) */
    void *sym = dlsym(RTLD_NEXT, "GOMP_parallel");
    memcpy(&real_parallel, &sym, sizeof real_parallel);
    sym = dlsym(RTLD_NEXT, "GOMP_barrier");
    memcpy(&real_barrier, &sym, sizeof real_barrier);
    if (!real_parallel || !real_barrier) {
      fputs("omp_profile: libgomp's GOMP_parallel or GOMP_barrier not "
            "found\n",
            stderr);
      abort();
    }
  }
  if (depth > 0) {
    real_parallel(fn, data, num_threads, flags);
    return;
  }
  for (int t = 0; t < MAX_TEAM; t++)
    slot[t] = 0.0;
  wrapped w = {fn, data};
  real_parallel(run_wrapped, &w, num_threads, flags);
  /* (after the join: every thread's slot written) */
  double all = 0.0, mx = 0.0;
  for (int t = 0; t < MAX_TEAM; t++) {
    all += slot[t];
    mx = slot[t] > mx ? slot[t] : mx;
  }
  n_regions++;
  sum_main += slot[0];
  sum_all += all;
  sum_max += mx;
}

/* The barriers GCC emits (`omp barrier`, the end of a static `omp for`)
 * counted on team thread 0; only inside a region, so after GOMP_parallel
 * has found libgomp's. */
void GOMP_barrier(void);
void GOMP_barrier(void) {
  if (omp_get_thread_num() == 0)
    n_barriers++;
  real_barrier();
}

int bench_omp_profile_read(bench_omp_profile *p) {
  p->regions = n_regions;
  p->barriers = n_barriers;
  p->main_cpu = thread_cpu();
  p->in_main = sum_main;
  p->in_all = sum_all;
  p->in_max = sum_max;
  return real_parallel ? 0 : -1;
}
