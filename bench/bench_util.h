/* Helpers shared by the benchmarks: CPU time, medians, least-squares
 * exponents, list parsing, and the FPU forces written out by hand (the
 * force-evaluation floor and the first-order peer systems use them). */
#ifndef MRVI_BENCH_UTIL_H
#define MRVI_BENCH_UTIL_H

#include "mrvi.h"

/* CPU time of the process in seconds (CLOCK_PROCESS_CPUTIME_ID). */
double bench_cpu(void);
/* CPU time of the calling thread in seconds (CLOCK_THREAD_CPUTIME_ID).
 * Under RLIMIT_CPU (bench_run_child's children) the kernel reads the
 * process clock from the process-wide timer, which advances in scheduler
 * ticks (1-4 ms); the thread clock keeps its nanoseconds, so a short
 * single-threaded phase (an integrator's creation) is timed with it. */
double bench_thread_cpu(void);
/* The compiler, build type and flags of this build (bench/meson.build),
 * printed with each table. */
const char *bench_build(void);
/* Median of x[0..n) (sorts x in place). */
double bench_median(double *x, int n);
/* Least-squares slope of log y against log x over the n pairs with
 * x, y > 0; NAN with fewer than two. */
double bench_exponent(const double *x, const double *y, int n);
/* Parse "1,10,100" into at most `max` integers >= 1; count or -1. */
int bench_parse_ints(const char *s, int *out, int max);
/* Parse "0.1,0.05" into at most `max` positive doubles; count or -1. */
int bench_parse_doubles(const char *s, double *out, int max);
/* Parse a positive double; 0 or -1. */
int bench_parse_positive(const char *s, double *out);
/* The options --repeats R (1 <= R <= max_repeats) and --steps K (K >= 1)
 * that bench_chain, bench_floor and bench_loops share: 1 if argv[*i] is
 * one of them with its value (into *repeats or *steps; *i advanced past
 * it), 0 if it is neither, -1 if its value is missing or bad. */
int bench_repeats_steps(int argc, char **argv, int *i, int max_repeats,
                        int *repeats, int *steps);

/* Deterministic uniform numbers in [-1, 1) from *state (an LCG). */
double bench_uniform(unsigned long long *state);
/* The value in kB of the /proc/self/status line starting with key (e.g.
 * "VmHWM:", the peak resident set), -1 if unknown. */
long bench_status_kb(const char *key);
/* The same from another /proc file of that format (e.g.
 * /proc/self/smaps_rollup, "AnonHugePages:"); -1 when absent. */
long bench_proc_kb(const char *file, const char *key);
/* The 1-minute load average (/proc/loadavg), NAN if unknown. */
double bench_load(void);

/* Run fn(fd, arg) in a forked child limited to `budget` seconds of CPU
 * (RLIMIT_CPU; four times that plus a minute of wall time) and mem_gb of
 * address space (RLIMIT_AS; not under AddressSanitizer); fn writes records
 * of `size` bytes to fd.  The last complete record goes to rec; returns the
 * number of complete records read (0: none, e.g. the child was killed
 * first), with the child's wait status in *wstatus. */
int bench_run_child(void (*fn)(int fd, void *arg), void *arg, void *rec,
                    size_t size, double budget, double mem_gb, int *wstatus);

/* A model the caller built up to status st (< 0: a step failed, or m is
 * NULL): gravity g set, or NULL with the model's message in msg and m
 * freed. */
mrvi_model *bench_model_finish(mrvi_model *m, int st, const double *g,
                               char *msg, size_t len);

/* bench_chain's pendulum chain of n links (2-D, gravity (0, -gravity)):
 * heavy links h_i (mass 2, slow) one apart along a line 45 degrees from
 * the downward vertical, each with a light mass l_i (0.05, fast) 0.1
 * below it on a slow spring (k = 2000), consecutive light masses joined by
 * fast springs (k = 2000, rest length 1); kind c: 0, 1 the links on rods
 * (distance constraints, h_1 to the origin), 2 on stiff slow springs
 * (k = 10^5, rest length 1) instead, 3 rigid bars (2-D bodies, length 1,
 * mass 2, slow) on revolute joints, the first to the ground at the
 * origin, the light masses on their lower ends.  NULL with the message in
 * msg. */
mrvi_model *bench_chain_model(int c, int n, double gravity, char *msg,
                              size_t len);

/* Step `it` (created on m) from m's initial state, q0 and p0 = M v0, at
 * least `steps` macro steps and until `min_cpu` seconds of CPU time have
 * passed (at most 10^5 steps), restarting from that state every `horizon`
 * steps so that long timings stay on the same motion.  CPU seconds per
 * step into *step_s and Newton updates per step into *newton; 0, or -1
 * with the message in msg. */
int bench_time_steps(mrvi_integrator *it, const mrvi_model *m, long steps,
                     double min_cpu, long horizon, double *step_s,
                     double *newton, char *msg, size_t len);

/* Path of systems/NAME: $MRVI_SOURCE_ROOT/systems/NAME, else the first of
 * systems/NAME and ../systems/NAME that exists (static buffer). */
const char *bench_system_path(const char *name);

/* The FPU of systems/fpu.yaml written out by hand (l = 3, unit masses,
 * omega^2 = 2500), coordinates ordered (qs1, qs2, qs3, qf1, qf2, qf3) as in
 * the file.  V = 1/4 sum of quartic springs, W = omega^2/2 |qf|^2. */
enum { BENCH_FPU_N = 6 };
#define BENCH_FPU_OMEGA2 2500.0
/* Initial positions and velocities of the file. */
void bench_fpu_initial(double *q, double *v);
/* Forces -grad V (slow) and -grad W (fast), written (not accumulated). */
void bench_fpu_force_slow(const double *q, double *f);
void bench_fpu_force_fast(const double *q, double *f);
/* Total energy 1/2 |v|^2 + V + W (unit masses). */
double bench_fpu_energy(const double *q, const double *v);

#endif
