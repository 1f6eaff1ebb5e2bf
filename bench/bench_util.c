#include "bench_util.h"

#include <errno.h>
#include <limits.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

double bench_cpu(void) {
  struct timespec ts;
  clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

double bench_thread_cpu(void) {
  struct timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static int cmp_double(const void *a, const void *b) {
  double x = *(const double *)a, y = *(const double *)b;
  return (x > y) - (x < y);
}

double bench_median(double *x, int n) {
  if (n <= 0)
    return NAN;
  qsort(x, (size_t)n, sizeof *x, cmp_double);
  return n % 2 ? x[n / 2] : 0.5 * (x[n / 2 - 1] + x[n / 2]);
}

double bench_exponent(const double *x, const double *y, int n) {
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  int k = 0;
  for (int i = 0; i < n; i++) {
    if (!(x[i] > 0 && y[i] > 0))
      continue;
    double lx = log(x[i]), ly = log(y[i]);
    sx += lx;
    sy += ly;
    sxx += lx * lx;
    sxy += lx * ly;
    k++;
  }
  if (k < 2)
    return NAN;
  double d = k * sxx - sx * sx;
  return d > 0 ? (k * sxy - sx * sy) / d : NAN;
}

int bench_parse_ints(const char *s, int *out, int max) {
  int n = 0;
  while (*s) {
    char *end;
    long v = strtol(s, &end, 10);
    if (end == s || v < 1 || v > 100000000 || n == max)
      return -1;
    out[n++] = (int)v;
    s = end;
    if (*s == ',')
      s++;
    else if (*s)
      return -1;
  }
  return n > 0 ? n : -1;
}

int bench_parse_doubles(const char *s, double *out, int max) {
  int n = 0;
  while (*s) {
    char *end;
    double v = strtod(s, &end);
    if (end == s || !(v > 0) || n == max)
      return -1;
    out[n++] = v;
    s = end;
    if (*s == ',')
      s++;
    else if (*s)
      return -1;
  }
  return n > 0 ? n : -1;
}

int bench_parse_positive(const char *s, double *out) {
  char *end;
  double v = strtod(s, &end);
  if (end == s || *end || !(v > 0))
    return -1;
  *out = v;
  return 0;
}

int bench_repeats_steps(int argc, char **argv, int *i, int max_repeats,
                        int *repeats, int *steps) {
  const char *a = argv[*i];
  const int is_r = !strcmp(a, "--repeats"), is_s = !strcmp(a, "--steps");
  if (!is_r && !is_s)
    return 0;
  if (*i + 1 >= argc)
    return -1;
  char *end;
  const char *s = argv[++*i];
  errno = 0;
  const long v = strtol(s, &end, 10);
  if (end == s || *end || errno || v < 1 || v > (is_r ? max_repeats : INT_MAX))
    return -1;
  *(is_r ? repeats : steps) = (int)v;
  return 1;
}

double bench_uniform(unsigned long long *state) {
  *state = *state * 6364136223846793005ULL + 1442695040888963407ULL;
  return (double)(*state >> 11) / 4503599627370496.0 - 1.0;
}

long bench_status_kb(const char *key) {
  return bench_proc_kb("/proc/self/status", key);
}

long bench_proc_kb(const char *file, const char *key) {
  FILE *f = fopen(file, "r");
  char line[256];
  long kb = -1;
  const size_t len = strlen(key);
  while (f && fgets(line, sizeof line, f))
    if (!strncmp(line, key, len))
      kb = strtol(line + len, NULL, 10);
  if (f)
    fclose(f);
  return kb;
}

double bench_load(void) {
  double load = NAN;
  FILE *f = fopen("/proc/loadavg", "r");
  if (f) {
    if (fscanf(f, "%lf", &load) != 1)
      load = NAN;
    fclose(f);
  }
  return load;
}

int bench_run_child(void (*fn)(int fd, void *arg), void *arg, void *rec,
                    size_t size, double budget, double mem_gb, int *wstatus) {
  int fds[2];
  *wstatus = 0;
  fflush(stdout);
  if (pipe(fds) < 0)
    return 0;
  pid_t pid = fork();
  if (pid < 0) {
    close(fds[0]);
    close(fds[1]);
    return 0;
  }
  if (pid == 0) {
    close(fds[0]);
    struct rlimit lim = {(rlim_t)ceil(budget), (rlim_t)ceil(budget) + 5};
    setrlimit(RLIMIT_CPU, &lim);
#ifndef __SANITIZE_ADDRESS__ /* AddressSanitizer reserves terabytes */
    rlim_t bytes = (rlim_t)(mem_gb * 1073741824.0);
    struct rlimit as = {bytes, bytes};
    setrlimit(RLIMIT_AS, &as);
#else
    (void)mem_gb;
#endif
    alarm((unsigned)(4 * ceil(budget) + 60)); /* wall-clock safety */
    fn(fds[1], arg);
    close(fds[1]);
    _exit(0);
  }
  close(fds[1]);
  char *buf = malloc(size);
  int records = 0;
  for (;;) {
    size_t got = 0;
    while (buf && got < size) {
      ssize_t k = read(fds[0], buf + got, size - got);
      if (k <= 0)
        break;
      got += (size_t)k;
    }
    if (!buf || got < size)
      break;
    memcpy(rec, buf, size);
    records++;
  }
  free(buf);
  close(fds[0]);
  waitpid(pid, wstatus, 0);
  return records;
}

const char *bench_system_path(const char *name) {
  static char buf[4096];
  const char *root = getenv("MRVI_SOURCE_ROOT");
  if (root && *root) {
    snprintf(buf, sizeof buf, "%s/systems/%s", root, name);
    return buf;
  }
  snprintf(buf, sizeof buf, "systems/%s", name);
  if (access(buf, R_OK) == 0)
    return buf;
  snprintf(buf, sizeof buf, "../systems/%s", name);
  return buf;
}

void bench_fpu_initial(double *q, double *v) {
  for (int i = 0; i < BENCH_FPU_N; i++)
    q[i] = v[i] = 0.0;
  q[0] = 1.0;
  q[3] = 1.0 / sqrt(BENCH_FPU_OMEGA2);
  v[0] = v[3] = 1.0;
}

/* Strains of the four quartic springs s_j and their gradients: s0 = qs1 -
 * qf1, s_i = qs_{i+1} - qf_{i+1} - qs_i - qf_i, s3 = qs3 + qf3. */
void bench_fpu_force_slow(const double *q, double *f) {
  const double *s = q, *x = q + 3;
  double d0 = s[0] - x[0], d1 = s[1] - x[1] - s[0] - x[0],
         d2 = s[2] - x[2] - s[1] - x[1], d3 = s[2] + x[2];
  d0 = d0 * d0 * d0;
  d1 = d1 * d1 * d1;
  d2 = d2 * d2 * d2;
  d3 = d3 * d3 * d3;
  f[0] = -d0 + d1;
  f[1] = -d1 + d2;
  f[2] = -d2 - d3;
  f[3] = d0 + d1;
  f[4] = d1 + d2;
  f[5] = d2 - d3;
}

void bench_fpu_force_fast(const double *q, double *f) {
  f[0] = f[1] = f[2] = 0.0;
  for (int i = 3; i < 6; i++)
    f[i] = -BENCH_FPU_OMEGA2 * q[i];
}

double bench_fpu_energy(const double *q, const double *v) {
  const double *s = q, *x = q + 3;
  double d[4] = {s[0] - x[0], s[1] - x[1] - s[0] - x[0],
                 s[2] - x[2] - s[1] - x[1], s[2] + x[2]};
  double e = 0.0;
  for (int i = 0; i < 4; i++)
    e += 0.25 * d[i] * d[i] * d[i] * d[i];
  for (int i = 0; i < 3; i++)
    e += 0.5 * BENCH_FPU_OMEGA2 * x[i] * x[i];
  for (int i = 0; i < BENCH_FPU_N; i++)
    e += 0.5 * v[i] * v[i];
  return e;
}

#ifndef MRVI_BENCH_BUILD
#define MRVI_BENCH_BUILD "unknown"
#endif
const char *bench_build(void) { return MRVI_BENCH_BUILD; }

int bench_time_steps(mrvi_integrator *it, const mrvi_model *m, long steps,
                     double min_cpu, long horizon, double *step_s,
                     double *newton, char *msg, size_t len) {
  const int nc = mrvi_model_n(m);
  const double *q0 = mrvi_model_q0(m), *v0 = mrvi_model_v0(m);
  double *p0 = malloc((size_t)nc * sizeof *p0);
  if (!p0) {
    snprintf(msg, len, "out of memory");
    return -1;
  }
  for (int i = 0; i < nc; i++)
    p0[i] = mrvi_model_mass(m, i) * v0[i];
  long updates = 0, k = 0;
  int st = 0;
  const double t0 = bench_cpu();
  while (k < steps || (bench_cpu() - t0 < min_cpu && k < 100000)) {
    if ((k % horizon == 0 && k > 0 &&
         mrvi_integrator_set_state(it, 0.0, q0, p0) < 0) ||
        mrvi_integrator_step(it) < 0) {
      snprintf(msg, len, "%.190s", mrvi_integrator_errmsg(it));
      st = -1;
      break;
    }
    updates += mrvi_integrator_last_iterations(it);
    k++;
  }
  free(p0);
  if (st == 0) {
    *step_s = (bench_cpu() - t0) / (double)k;
    *newton = (double)updates / (double)k;
  }
  return st;
}

mrvi_model *bench_model_finish(mrvi_model *m, int st, const double *g,
                               char *msg, size_t len) {
  if (st >= 0)
    st = mrvi_model_set_gravity(m, g);
  if (st < 0) {
    snprintf(msg, len, "%s", m ? mrvi_model_errmsg(m) : "out of memory");
    mrvi_model_free(m);
    return NULL;
  }
  return m;
}

mrvi_model *bench_chain_model(int c, int n, double gravity, char *msg,
                              size_t len) {
  mrvi_model *m = mrvi_model_create();
  const double g[2] = {0.0, -gravity}, e[2] = {sqrt(0.5), -sqrt(0.5)};
  const double zero[2] = {0.0, 0.0};
  int st = m ? mrvi_model_set_dimension(m, 2) : MRVI_ENOMEM;
  int prev_h = -1, prev_l = -1;
  for (int i = 0; i < n && st >= 0; i++) {
    const double h[2] = {(i + 1) * e[0], (i + 1) * e[1]};
    const double l[2] = {h[0], h[1] - 0.1};
    char name[32];
    double k_soft[1] = {2000.0}, k_rod[1] = {1e5};
    int hi = -1, li = -1;
    mrvi_end end_h = {-1, -1, {0, 0, 0}};
    if (c < 3) {
      snprintf(name, sizeof name, "h%d", i);
      hi = st = mrvi_model_add_particle(m, name, 2.0, MRVI_SLOW, h, zero);
      end_h.particle = hi;
    } else {
      /* a bar from the previous joint to h along e: centre halfway */
      const double x[2] = {h[0] - 0.5 * e[0], h[1] - 0.5 * e[1]};
      const double R[4] = {e[0], -e[1], e[1], e[0]}; /* d1 along e */
      const double J[1] = {2.0 / 12.0};
      snprintf(name, sizeof name, "b%d", i);
      int b = st =
          mrvi_model_add_body(m, name, 2, MRVI_SLOW, 2.0, J, x, R, NULL, NULL);
      if (st >= 0) {
        const double pivot[2] = {i * e[0], i * e[1]};
        st = mrvi_model_add_joint(m, "revolute", b, prev_h, pivot, NULL);
      }
      end_h.body = b;
      end_h.at[0] = 0.5; /* the lower end along d1 */
      hi = b;
    }
    if (st < 0)
      break;
    snprintf(name, sizeof name, "l%d", i);
    li = st = mrvi_model_add_particle(m, name, 0.05, MRVI_FAST, l, zero);
    if (st < 0)
      break;
    mrvi_end end_l = {li, -1, {0, 0, 0}};
    st = mrvi_model_add_end_spring(m, MRVI_SLOW, &end_h, &end_l, NULL, "linear",
                                   k_soft, 0.1);
    if (st >= 0 && prev_l >= 0)
      st = mrvi_model_add_spring(m, MRVI_FAST, prev_l, li, "linear", k_soft,
                                 1.0);
    if (st >= 0 && c < 2)
      st = prev_h < 0 ? mrvi_model_add_distance_anchor(m, hi, zero, 1.0)
                      : mrvi_model_add_distance(m, prev_h, hi, 1.0);
    if (st >= 0 && c == 2)
      st = prev_h < 0 ? mrvi_model_add_anchor_spring(m, MRVI_SLOW, hi, zero,
                                                     "linear", k_rod, 1.0)
                      : mrvi_model_add_spring(m, MRVI_SLOW, prev_h, hi,
                                              "linear", k_rod, 1.0);
    prev_h = hi;
    prev_l = li;
  }
  return bench_model_finish(m, st, g, msg, len);
}
