/* Per-region CPU times of OpenMP parallel regions (bench_serial only;
 * doc/performance/threads.md, "The serial fraction of a step on threads").
 * omp_profile.c interposes libgomp's GOMP_parallel (the one entry point
 * GCC emits for mrvi's `parallel` and `parallel for schedule(static)`
 * regions) and times, with each thread's CPU clock, every top-level
 * region on each thread of its team; and GOMP_barrier (the barriers inside
 * the regions: `omp barrier`, the end of a static `omp for`), counted.  Run
 * with OMP_WAIT_POLICY=passive: a thread waiting at a barrier then sleeps and
 * its wait is not counted, so a thread's CPU time in a region is its work
 * there. */
#ifndef BENCH_OMP_PROFILE_H
#define BENCH_OMP_PROFILE_H

typedef struct bench_omp_profile {
  long regions;    /* top-level parallel regions entered */
  long barriers;   /* barriers passed inside them (GOMP_barrier, thread 0) */
  double main_cpu; /* the calling thread's CPU time, s (all of it) */
  double in_main;  /* ... of it inside the regions (as team thread 0) */
  double in_all;   /* every thread's CPU time inside the regions */
  double in_max;   /* sum over the regions of the busiest thread's */
} bench_omp_profile;

/* The counters so far (call from the thread that enters the regions);
 * 0, or -1 where the interposition is not in effect (no region seen
 * through it: the program not linked with omp_profile.c). */
int bench_omp_profile_read(bench_omp_profile *p);

#endif
