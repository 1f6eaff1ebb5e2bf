/* Status codes and small utilities shared by the library. */
#define _GNU_SOURCE /* sched_getaffinity, CPU_COUNT */
#include "util/util.h"

#include <sched.h>
#include <stdio.h>
#include <time.h>
#include <unistd.h>

const char *mrvi_strerror(int status) {
  switch (status) {
#define MRVI_STATUS_CASE(name, code, msg)                                      \
  case code:                                                                   \
    return msg;
    MRVI_STATUS_LIST(MRVI_STATUS_CASE)
#undef MRVI_STATUS_CASE
  default:
    return "unknown status";
  }
}

const char *mrvi_version(void) { return MRVI_VERSION; }

void mrvi_vfmt(char *buf, size_t len, const char *fmt, va_list ap) {
  if (!buf || len == 0)
    return;
  vsnprintf(buf, len, fmt, ap);
}

void mrvi_fmt(char *buf, size_t len, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(buf, len, fmt, ap);
  va_end(ap);
}

int mrvi_fail(char *msg, size_t len, int status, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(msg, len, fmt, ap);
  va_end(ap);
  return status;
}

double mrvi_clock(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

int mrvi_cores(void) {
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof set, &set) == 0 && CPU_COUNT(&set) > 0)
    return CPU_COUNT(&set);
  const long n = sysconf(_SC_NPROCESSORS_ONLN);
  return n > 0 ? (int)n : 1;
}

int mrvi_tasks_others(void) {
  FILE *f = fopen("/proc/loadavg", "r");
  int running = -1;
  if (f) {
    double l1, l5, l15;
    if (fscanf(f, "%lf %lf %lf %d/", &l1, &l5, &l15, &running) != 4)
      running = -1;
    fclose(f);
  }
  return running > 0 ? running - 1 : -1;
}

int mrvi_cores_idle(void) {
  const int cores = mrvi_cores(), others = mrvi_tasks_others();
  const int idle = others > 0 ? cores - others : cores;
  return idle > 1 ? idle : 1;
}

int mrvi_threads_supported(void) {
#ifdef _OPENMP
  return 1;
#else
  return 0;
#endif
}

int mrvi_threads_resolve(int requested) {
  if (!mrvi_threads_supported())
    return 1;
  return requested > 0 ? requested : mrvi_cores();
}

double mrvi_machine_memory(void) {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
  const double have = pages > 0 && page > 0 ? (double)pages * (double)page : 0;
#ifdef MRVI_MEMORY_CAP
  return have > 0 && have < (double)MRVI_MEMORY_CAP ? have
                                                    : (double)MRVI_MEMORY_CAP;
#else
  return have;
#endif
}
