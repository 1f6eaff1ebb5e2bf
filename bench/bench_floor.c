/* Floors and peers on spring networks of 10^3 to 10^6 coordinates.
 *
 * Three networks, each with soft slow springs (V) and stiff fast springs
 * (W) between fast particles, unit masses:
 *   lattice2d  the planar lattice of systems/lattice.yaml grown to n
 *              coordinates (mrvi_model_generate, lattice2d, rates every 2
 *              with an even row length: every second column fast; slow
 *              linear k = 10, fast linear k = 1000, rest length 1),
 *   lattice3d  the same on a cubic lattice (lattice3d),
 *   random3d   particles on a jittered cubic grid, each fast with
 *              probability 1/2, a bond between every two within 1.45 of
 *              each other with its initial length as rest length: fast
 *              harmonic (k = 1000) between two fast particles, slow Morse
 *              (depth 5, width 1: stiffness 10 at rest) otherwise.
 * Every particle starts displaced by up to 0.05 per axis and moving with up
 * to 0.1 (deterministic).  dT = 0.05, p = 10 by default.
 *
 * Methods, on one thread (but --threads, below) on the same forces (the spring
 * force phi'(s) (x_i - x_j)/|x_i - x_j|, s = |x_i - x_j| - L0, written out
 * here): respa    the r-RESPA floor: impulse method, dT/2 kicks of the slow
 * force at the macro nodes around p velocity-Verlet steps of dt = dT/p with the
 * fast force (fast particles stored first; the slow ones drift once per macro
 * step, which they may since no fast spring touches them).  Algebraically
 * mrvi's fully-explicit. verlet   the Stoermer-Verlet floor: velocity Verlet at
 * dt with all forces, p steps per macro step: the step size at which mrvi's
 * implicit schemes resolve the fast motion (bench_fpu's pairing). mrvi
 * fully-explicit, explicit-slow, midpoint-midpoint, trapezoidal-midpoint
 * through mrvi_integrator_step (no output, no energy monitor, the last micro
 * node alone kept where the path allows it, mrvi_integrator_keep_micro: the
 * floors keep and compute none of these either). lammps   Debian's `lmp` (found
 * on PATH, else skipped with a note) on the lattices: run_style respa 2 p (fast
 * springs as bonds on the inner level, slow springs as `pair_style list` on the
 *            outer) and run_style verlet at dt; CPU time = the log's loop
 *            time times its CPU share.
 *
 * --threads T: the floors also on threads (OpenMP over a static partition
 * of the coordinates, the same for every thread count: bitwise the serial
 * floor's state, checked), beside mrvi's schemes on 1 and T threads, and
 * STREAM's triad over the same array sizes: what two cores of this machine
 * give a hand-written step (doc/performance/threads.md, "Threads").
 *
 * Each case (network, n, method) runs in a forked child: build the network,
 * create the integrator (CPU time, also in macro steps), step at least
 * --steps macro steps and 0.3 s, report the time per macro step, the
 * solver's counters, and the peak resident memory (VmHWM) with the resident
 * memory before creation.  The methods of one (network, n) alternate,
 * --repeats rounds, best time of the rounds; with two rounds or more also
 * every round's time, the process' transparent huge pages (AnonHugePages)
 * and page faults, the best, median and worst round and the ratios to the
 * floor both ways round (a ratio moved by the floor's own spread shows as
 * such: doc/performance/16-fe16.md).  Before the timings, checks on
 * the smallest n: mrvi fully-explicit against the r-RESPA floor (and
 * LAMMPS respa against it), and every method's error against a fine
 * Verlet reference at t = 20 dT, which says what the pairings compare.  A
 * measurement: no thresholds (doc/performance.md). */
#define _DEFAULT_SOURCE /* wait4 */
#include "bench_util.h"
#ifdef _OPENMP
#include <omp.h>
#endif
#ifdef BENCH_OMP_PROFILE
#include "omp_profile.h"
#endif

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

enum { MAX_N = 8, MAX_REPEATS = 15, N_NETS = 3, CHECK_STEPS = 20 };
enum { CHECK_MAX_N = 20000 }; /* the checks run a fine Verlet reference */
#define MIN_CPU 0.3           /* (the default of --min-cpu) */

typedef enum method {
  M_RESPA,
  M_VERLET,
  M_FE,
  M_ES,
  M_MM,
  M_TM,
  M_LMP_RESPA,
  M_LMP_VERLET,
  N_METHODS
} method;

static const char *const method_names[N_METHODS] = {
    "floor r-RESPA", "floor Verlet",      "fully-explicit",
    "explicit-slow", "midpoint-midpoint", "trapezoidal-midpoint",
    "LAMMPS rRESPA", "LAMMPS Verlet"};
static const char *const net_names[N_NETS] = {"lattice2d", "lattice3d",
                                              "random3d"};

static const char usage[] =
    "Usage: bench_floor [--quick] [--n N1,N2,...] [--net NAME,...]\n"
    "                   [--repeats R] [--steps K] [--dT DT] [--p P]\n"
    "                   [--budget SECONDS] [--mem GB] [--big N]\n"
    "                   [--no-lammps] [--method NAME] [--threads T]\n"
    "                   [--min-cpu S]\n"
    "                   [--tuning NAME=VALUE]\n"
    "\n"
    "The r-RESPA and Stoermer-Verlet floors, mrvi's fully-explicit,\n"
    "explicit-slow, midpoint-midpoint and trapezoidal-midpoint, and LAMMPS\n"
    "(rRESPA, Verlet; when `lmp` is on PATH) on networks of about N\n"
    "coordinates (default 1000,10000,100000): lattice2d, lattice3d,\n"
    "random3d (default all).  Each case in a child process limited to\n"
    "SECONDS of CPU (default 300) and GB of address space (default 12);\n"
    "R rounds alternating the methods (default 3, at most 15), best of\n"
    "them (R >= 2: also every round, its huge pages and page faults, and\n"
    "best / median / worst with the ratios to the floor both ways); at least\n"
    "K macro steps (default 3) and S s of CPU (--min-cpu, default 0.3; 0:\n"
    "exactly K macro steps, so that two runs average the iteration counts\n"
    "over the same steps; the times of so short a run mean little, the cost\n"
    "model's ratio may be nan); dT = 0.05, P = 10.  Implicit\n"
    "schemes run only up to --big N coordinates (default 1000000).\n"
    "--method runs one method alone (as the tables name it, e.g.\n"
    "midpoint-midpoint) with the floor of its ratio (r-RESPA for the\n"
    "explicit paths, Verlet for the implicit schemes).  --threads T: instead "
    "of the tables above, the floors\n"
    "on a static partition of the coordinates (bitwise the serial floor's)\n"
    "and mrvi's schemes on 1 and on T threads (settings.threads),\n"
    "alternating, wall time per macro step, the ratio, the CPU ratio and\n"
    "the floor's ratio beside each scheme's (with the scheme's over it, the\n"
    "floor's CPU ratio and the T threads' CPU over their wall time), and\n"
    "STREAM's triad over arrays\n"
    "of n doubles on 1 and T threads; the other tables are on 1 thread.\n"
    "--tuning sets a tuning constant of mrvi's methods (mrvi.h,\n"
    "MRVI_TUNING_LIST), e.g. outer_max=0.\n"
    "  --quick: N = 300,1000, R = 1, K = 2, lattice2d\n"
    "only.\n"
#ifdef BENCH_OMP_PROFILE
    "bench_serial --serial T: each scheme on T threads, the serial\n"
    "fraction of its step from each thread's CPU time in and out of the\n"
    "parallel regions (run with OMP_WAIT_POLICY=passive), median of R\n"
    "runs, and the Amdahl bound it implies.\n"
#endif
    ;

static int bad_usage(void) {
  fputs(usage, stderr);
  return 1;
}

/* ------------------------------------------------------------------------
 * Networks.
 * ---------------------------------------------------------------------- */
typedef struct bond {
  int i, j;  /* particles */
  double L0; /* rest length */
  double k;  /* stiffness (linear), or Morse depth */
  double a;  /* Morse width; 0 for linear */
} bond;

typedef struct network {
  int kind, d, np;
  int nx[3];
  double *x0, *v0; /* d * np, particle order */
  char *fast;      /* np */
  bond *slow, *fst;
  long n_slow, n_fast;
} network;

static void network_free(network *w) {
  free(w->x0);
  free(w->v0);
  free(w->fast);
  free(w->slow);
  free(w->fst);
  memset(w, 0, sizeof *w);
}

static int add_bond(network *w, int i, int j, double L0, long *cap_s,
                    long *cap_f) {
  const int fast = w->fast[i] && w->fast[j];
  bond **list = fast ? &w->fst : &w->slow;
  long *count = fast ? &w->n_fast : &w->n_slow, *cap = fast ? cap_f : cap_s;
  if (*count == *cap) {
    long c = 2 * *cap + 1024;
    bond *t = realloc(*list, (size_t)c * sizeof *t);
    if (!t)
      return -1;
    *list = t;
    *cap = c;
  }
  bond b = {i, j, L0, 1000.0, 0.0};
  if (!fast) {
    if (w->kind == 2)
      b.k = 5.0, b.a = 1.0; /* Morse: 2 D a^2 = 10 */
    else
      b.k = 10.0;
  }
  (*list)[(*count)++] = b;
  return 0;
}

/* The network of kind `kind` with about n coordinates. */
static int network_make(network *w, int kind, int n) {
  memset(w, 0, sizeof *w);
  w->kind = kind;
  w->d = kind == 0 ? 2 : 3;
  const int d = w->d;
  int particles = n / d < 4 ? 4 : n / d;
  if (d == 2) {
    int nx = (int)lround(sqrt((double)particles));
    nx += nx % 2;
    w->nx[0] = nx;
    w->nx[1] = (particles + nx - 1) / nx;
    w->nx[2] = 1;
  } else {
    int s = (int)lround(cbrt((double)particles));
    if (s < 2)
      s = 2;
    w->nx[0] = s + s % 2;
    w->nx[1] = s;
    w->nx[2] = (particles + w->nx[0] * s - 1) / (w->nx[0] * s);
  }
  w->np = w->nx[0] * w->nx[1] * w->nx[2];
  w->x0 = malloc((size_t)w->np * d * sizeof *w->x0);
  w->v0 = malloc((size_t)w->np * d * sizeof *w->v0);
  w->fast = malloc((size_t)w->np);
  if (!w->x0 || !w->v0 || !w->fast)
    return -1;
  unsigned long long seed = 12345, rseed = 777;
  for (int i = 0; i < w->np; i++) {
    int idx[3] = {i % w->nx[0], i / w->nx[0] % w->nx[1],
                  i / (w->nx[0] * w->nx[1])};
    for (int a = 0; a < d; a++) {
      double jit = kind == 2 ? 0.2 * bench_uniform(&rseed) : 0.0;
      w->x0[i * d + a] = idx[a] + jit + 0.05 * bench_uniform(&seed);
      w->v0[i * d + a] = 0.1 * bench_uniform(&seed);
    }
    /* lattices: the generator's `every: 2`; random: probability 1/2 */
    w->fast[i] = kind == 2 ? bench_uniform(&rseed) > 0.0 : i % 2 == 1;
  }
  long cap_s = 0, cap_f = 0;
  const int *nx = w->nx;
  if (kind < 2) {
    /* The generator's order: each particle to its +x, +y, +z neighbour. */
    for (int i = 0; i < w->np; i++) {
      int idx[3] = {i % nx[0], i / nx[0] % nx[1], i / (nx[0] * nx[1])};
      int stride = 1;
      for (int a = 0; a < 3; a++) {
        if (idx[a] + 1 < nx[a] &&
            add_bond(w, i, i + stride, 1.0, &cap_s, &cap_f) < 0)
          return -1;
        stride *= nx[a];
      }
    }
    return 0;
  }
  /* random3d: pairs of grid sites at most one apart per axis (13 forward
   * neighbours) within 1.45 of each other. */
  for (int i = 0; i < w->np; i++) {
    int idx[3] = {i % nx[0], i / nx[0] % nx[1], i / (nx[0] * nx[1])};
    for (int dz = 0; dz <= 1; dz++)
      for (int dy = dz ? -1 : 0; dy <= 1; dy++)
        for (int dx = (dz || dy) ? -1 : 1; dx <= 1; dx++) {
          int o[3] = {idx[0] + dx, idx[1] + dy, idx[2] + dz};
          if (o[0] < 0 || o[0] >= nx[0] || o[1] < 0 || o[1] >= nx[1] ||
              o[2] >= nx[2])
            continue;
          int j = o[0] + nx[0] * (o[1] + nx[1] * o[2]);
          double r2 = 0;
          for (int a = 0; a < 3; a++) {
            double t = w->x0[i * 3 + a] - w->x0[j * 3 + a];
            r2 += t * t;
          }
          if (r2 < 1.45 * 1.45 &&
              add_bond(w, i, j, sqrt(r2), &cap_s, &cap_f) < 0)
            return -1;
        }
  }
  return 0;
}

/* The mrvi model of the network: the generator for the lattices, the
 * particles and springs one by one for the random network. */
static mrvi_model *network_model(const network *w, char *msg, size_t len) {
  mrvi_model *m = mrvi_model_create();
  if (!m || mrvi_model_set_dimension(m, w->d) < 0) {
    snprintf(msg, len, "model: out of memory");
    mrvi_model_free(m);
    return NULL;
  }
  int st = 0;
  if (w->kind < 2) {
    double *disp = malloc((size_t)w->np * w->d * sizeof *disp);
    if (!disp) {
      mrvi_model_free(m);
      return NULL;
    }
    for (int i = 0; i < w->np; i++) {
      int idx[3] = {i % w->nx[0], i / w->nx[0] % w->nx[1],
                    i / (w->nx[0] * w->nx[1])};
      for (int a = 0; a < w->d; a++)
        disp[i * w->d + a] = w->x0[i * w->d + a] - idx[a];
    }
    mrvi_generator g;
    memset(&g, 0, sizeof g);
    g.kind = w->kind == 0 ? MRVI_GEN_LATTICE2D : MRVI_GEN_LATTICE3D;
    g.prefix = "p";
    for (int a = 0; a < 3; a++)
      g.count[a] = w->nx[a];
    g.spacing = 1.0;
    g.mass = 1.0;
    g.rates = MRVI_RATES_EVERY;
    g.every = 2;
    g.slow.law = "linear";
    g.slow.params[0] = 10.0;
    g.slow.rest_length = NAN;
    g.fast.law = "linear";
    g.fast.params[0] = 1000.0;
    g.fast.rest_length = NAN;
    g.displacement = disp;
    g.velocity = w->v0;
    st = mrvi_model_generate(m, &g, NULL);
    free(disp);
  } else {
    for (int i = 0; i < w->np && st >= 0; i++) {
      char name[32];
      snprintf(name, sizeof name, "p%d", i);
      st = mrvi_model_add_particle(m, name, 1.0,
                                   w->fast[i] ? MRVI_FAST : MRVI_SLOW,
                                   w->x0 + i * 3, w->v0 + i * 3);
    }
    for (int pass = 0; pass < 2 && st >= 0; pass++) {
      /* the network's order within each class; classes do not interleave
       * in the sums, so the order between them does not matter */
      const bond *b = pass ? w->fst : w->slow;
      long nb = pass ? w->n_fast : w->n_slow;
      for (long e = 0; e < nb && st >= 0; e++) {
        double par[2] = {b[e].k, b[e].a};
        st = mrvi_model_add_spring(m, pass ? MRVI_FAST : MRVI_SLOW, b[e].i,
                                   b[e].j, pass ? "linear" : "morse", par,
                                   b[e].L0);
      }
    }
  }
  if (st < 0) {
    snprintf(msg, len, "model: %s", mrvi_model_errmsg(m));
    mrvi_model_free(m);
    return NULL;
  }
  return m;
}

/* ------------------------------------------------------------------------
 * The floors: flat arrays, fast particles first.
 * ---------------------------------------------------------------------- */
typedef struct fbond {
  int i, j; /* first coordinate of each end in the floor's arrays */
  double L0, k, a;
} fbond;

typedef struct floor_sys {
  int d, n, nf; /* coordinates, fast coordinates (first) */
  int *perm;    /* particle -> floor particle */
  double *x, *v, *fs, *ff;
  fbond *slow, *fst;
  long n_slow, n_fast;
  int morse;
} floor_sys;

static void floor_free(floor_sys *f) {
  free(f->perm);
  free(f->x);
  free(f->v);
  free(f->fs);
  free(f->ff);
  free(f->slow);
  free(f->fst);
}

static int floor_make(floor_sys *f, const network *w) {
  memset(f, 0, sizeof *f);
  const int d = w->d;
  f->d = d;
  f->n = d * w->np;
  f->morse = w->kind == 2;
  f->perm = malloc((size_t)w->np * sizeof *f->perm);
  f->x = malloc((size_t)f->n * sizeof *f->x);
  f->v = malloc((size_t)f->n * sizeof *f->v);
  f->fs = malloc((size_t)f->n * sizeof *f->fs);
  f->ff = malloc((size_t)f->n * sizeof *f->ff);
  f->slow = malloc((size_t)(w->n_slow + 1) * sizeof *f->slow);
  f->fst = malloc((size_t)(w->n_fast + 1) * sizeof *f->fst);
  if (!f->perm || !f->x || !f->v || !f->fs || !f->ff || !f->slow || !f->fst)
    return -1;
  int k = 0;
  for (int pass = 1; pass >= 0; pass--)
    for (int i = 0; i < w->np; i++)
      if (w->fast[i] == pass)
        f->perm[i] = k++;
  for (int i = 0; i < w->np; i++)
    if (w->fast[i])
      f->nf += d;
  for (int i = 0; i < w->np; i++)
    for (int a = 0; a < d; a++) {
      f->x[f->perm[i] * d + a] = w->x0[i * d + a];
      f->v[f->perm[i] * d + a] = w->v0[i * d + a];
    }
  for (int pass = 0; pass < 2; pass++) {
    const bond *b = pass ? w->fst : w->slow;
    long nb = pass ? w->n_fast : w->n_slow;
    fbond *out = pass ? f->fst : f->slow;
    for (long e = 0; e < nb; e++)
      out[e] = (fbond){f->perm[b[e].i] * d, f->perm[b[e].j] * d, b[e].L0,
                       b[e].k, b[e].a};
  }
  f->n_slow = w->n_slow;
  f->n_fast = w->n_fast;
  return 0;
}

/* Add the spring forces of bonds b[0..nb) (of type T, reading x at b.i,
 * b.j and writing F at b.WI, b.WJ) to F (D = 2, 3; Morse or linear): the
 * gradient of phi(|x_i - x_j| - L0). */
#define SPRINGS(NAME, T, WI, WJ, D, MORSE)                                     \
  static void NAME(const T *b, long nb, const double *x, double *F) {          \
    for (long e = 0; e < nb; e++) {                                            \
      const double *xi = x + b[e].i, *xj = x + b[e].j;                         \
      double dx[D], r2 = 0.0;                                                  \
      for (int c = 0; c < D; c++) {                                            \
        dx[c] = xi[c] - xj[c];                                                 \
        r2 += dx[c] * dx[c];                                                   \
      }                                                                        \
      const double r = sqrt(r2), s = r - b[e].L0;                              \
      double dphi;                                                             \
      if (MORSE) {                                                             \
        const double ex = exp(-b[e].a * s);                                    \
        dphi = 2 * b[e].k * b[e].a * ex * (1 - ex);                            \
      } else {                                                                 \
        dphi = b[e].k * s;                                                     \
      }                                                                        \
      const double c0 = dphi / r;                                              \
      for (int c = 0; c < D; c++) {                                            \
        F[b[e].WI + c] -= c0 * dx[c];                                          \
        F[b[e].WJ + c] += c0 * dx[c];                                          \
      }                                                                        \
    }                                                                          \
  }
SPRINGS(springs20, fbond, i, j, 2, 0)
SPRINGS(springs30, fbond, i, j, 3, 0)
SPRINGS(springs21, fbond, i, j, 2, 1)
SPRINGS(springs31, fbond, i, j, 3, 1)

static void floor_slow(const floor_sys *f, double *F) {
  if (f->d == 2)
    f->morse ? springs21(f->slow, f->n_slow, f->x, F)
             : springs20(f->slow, f->n_slow, f->x, F);
  else
    f->morse ? springs31(f->slow, f->n_slow, f->x, F)
             : springs30(f->slow, f->n_slow, f->x, F);
}

static void floor_fast(const floor_sys *f, double *F) {
  (f->d == 2 ? springs20 : springs30)(f->fst, f->n_fast, f->x, F);
}

/* r-RESPA (impulse) macro steps; fs and ff hold the forces at x on entry
 * (floor_forces). */
static void floor_forces(floor_sys *f) {
  memset(f->fs, 0, (size_t)f->n * sizeof *f->fs);
  memset(f->ff, 0, (size_t)f->nf * sizeof *f->ff);
  floor_slow(f, f->fs);
  floor_fast(f, f->ff);
}

static void respa_steps(floor_sys *f, double dT, int p, long steps) {
  const double dt = dT / p;
  const int n = f->n, nf = f->nf;
  double *restrict x = f->x, *restrict v = f->v, *restrict fs = f->fs,
                   *restrict ff = f->ff;
  for (long k = 0; k < steps; k++) {
    for (int i = 0; i < n; i++)
      v[i] += 0.5 * dT * fs[i];
    for (int m = 0; m < p; m++) {
      for (int i = 0; i < nf; i++) {
        v[i] += 0.5 * dt * ff[i];
        x[i] += dt * v[i];
      }
      memset(ff, 0, (size_t)nf * sizeof *ff);
      floor_fast(f, ff);
      for (int i = 0; i < nf; i++)
        v[i] += 0.5 * dt * ff[i];
    }
    for (int i = nf; i < n; i++)
      x[i] += dT * v[i];
    memset(fs, 0, (size_t)n * sizeof *fs);
    floor_slow(f, fs);
    for (int i = 0; i < n; i++)
      v[i] += 0.5 * dT * fs[i];
  }
}

/* Velocity Verlet at dt with all forces; fs holds the total force. */
static void verlet_steps(floor_sys *f, double dt, long steps) {
  const int n = f->n;
  double *restrict x = f->x, *restrict v = f->v, *restrict F = f->fs;
  for (long k = 0; k < steps; k++) {
    for (int i = 0; i < n; i++) {
      v[i] += 0.5 * dt * F[i];
      x[i] += dt * v[i];
    }
    memset(F, 0, (size_t)n * sizeof *F);
    floor_slow(f, F);
    floor_fast(f, F);
    for (int i = 0; i < n; i++)
      v[i] += 0.5 * dt * F[i];
  }
}

static void verlet_forces(floor_sys *f) {
  memset(f->fs, 0, (size_t)f->n * sizeof *f->fs);
  floor_slow(f, f->fs);
  floor_fast(f, f->fs);
}

/* ------------------------------------------------------------------------
 * The floors on threads (--threads): the same r-RESPA and Verlet steps with
 * OpenMP over a static partition of the coordinates that depends on n
 * alone (parts of PF_CHUNK coordinates, an even count, whole particles:
 * the fast coordinates' parts, then the slow ones').  Each part owns its
 * coordinates and lists, in the serial order, every bond with an end
 * among them; an end it does not own writes into the part's sink (a cache
 * line of its own after the n coordinates).  Each coordinate therefore
 * sums its bonds in the serial order: the state is bitwise the serial
 * floor's for every thread count (checked before the table).  One parallel
 * region per macro step, two position buffers (a part drifts into the
 * other buffer while other parts still read this one): one barrier per
 * micro step, two more per macro step (r-RESPA); one per Verlet step.
 * ---------------------------------------------------------------------- */
enum { PF_CHUNK = 4096, PF_SINK = 8 };

typedef struct pbond {
  int i, j;   /* read: first coordinate of each end */
  int wi, wj; /* write: the same, or the part's sink */
  double L0, k, a;
} pbond;

SPRINGS(psprings20, pbond, wi, wj, 2, 0)
SPRINGS(psprings30, pbond, wi, wj, 3, 0)
SPRINGS(psprings21, pbond, wi, wj, 2, 1)
SPRINGS(psprings31, pbond, wi, wj, 3, 1)

typedef struct pfloor {
  int d, n, nf, morse;
  int pf, pa;       /* fast parts [0, pf), all parts [0, pa) */
  int *lo;          /* pa + 1 coordinate bounds */
  long *so, *fo;    /* pa + 1 offsets of each part's slow, fast bonds */
  pbond *sb, *fb;   /* the parts' bond lists */
  double *x[2], *v; /* positions (two buffers), velocities */
  double *fs, *ff;  /* n + PF_SINK pa each */
  int cur;          /* the buffer holding the positions */
} pfloor;

static void pfloor_free(pfloor *f) {
  free(f->lo);
  free(f->so);
  free(f->fo);
  free(f->sb);
  free(f->fb);
  free(f->x[0]);
  free(f->x[1]);
  free(f->v);
  free(f->fs);
  free(f->ff);
  memset(f, 0, sizeof *f);
}

/* Part bounds of m coordinates (whole particles of d) from coordinate c0:
 * `parts` parts of equal particle counts written to lo[0..parts]. */
static void pfloor_bounds(int *lo, int c0, int m, int d, int parts) {
  const long np = m / d;
  for (int q = 0; q <= parts; q++)
    lo[q] = c0 + d * (int)(np * q / parts);
}

static int pfloor_parts(int m) {
  const int np = m > 0 ? (m - 1) / PF_CHUNK + 1 : 0;
  return np + (np & 1);
}

/* The part owning coordinate c (lo ascending). */
static int pfloor_owner(const int *lo, int pa, int c) {
  int a = 0, b = pa - 1;
  while (a < b) {
    const int mid = (a + b + 1) / 2;
    if (lo[mid] <= c)
      a = mid;
    else
      b = mid - 1;
  }
  return a;
}

/* The parts' lists of nb bonds b (of the floor f0) into *out, offsets off. */
static int pfloor_lists(pfloor *f, const fbond *b, long nb, long **off,
                        pbond **out) {
  const int pa = f->pa;
  *off = calloc((size_t)pa + 1, sizeof **off);
  if (!*off)
    return -1;
  for (long e = 0; e < nb; e++) {
    const int qi = pfloor_owner(f->lo, pa, b[e].i),
              qj = pfloor_owner(f->lo, pa, b[e].j);
    (*off)[qi + 1]++;
    if (qj != qi)
      (*off)[qj + 1]++;
  }
  for (int q = 0; q < pa; q++)
    (*off)[q + 1] += (*off)[q];
  *out = malloc((size_t)((*off)[pa] + 1) * sizeof **out);
  long *fill = malloc((size_t)pa * sizeof *fill);
  if (!*out || !fill) {
    free(fill);
    return -1;
  }
  memcpy(fill, *off, (size_t)pa * sizeof *fill);
  for (long e = 0; e < nb; e++) {
    const int qi = pfloor_owner(f->lo, pa, b[e].i),
              qj = pfloor_owner(f->lo, pa, b[e].j);
    for (int t = 0; t < (qj != qi ? 2 : 1); t++) {
      const int q = t ? qj : qi, sink = f->n + PF_SINK * q;
      (*out)[fill[q]++] = (pbond){b[e].i,
                                  b[e].j,
                                  qi == q ? b[e].i : sink,
                                  qj == q ? b[e].j : sink,
                                  b[e].L0,
                                  b[e].k,
                                  b[e].a};
    }
  }
  free(fill);
  return 0;
}

/* The partitioned floor of the serial floor s (its state and bonds). */
static int pfloor_make(pfloor *f, const floor_sys *s) {
  memset(f, 0, sizeof *f);
  f->d = s->d;
  f->n = s->n;
  f->nf = s->nf;
  f->morse = s->morse;
  f->pf = pfloor_parts(s->nf);
  f->pa = f->pf + pfloor_parts(s->n - s->nf);
  f->lo = malloc(((size_t)f->pa + 1) * sizeof *f->lo);
  if (!f->lo)
    return -1;
  pfloor_bounds(f->lo, 0, s->nf, s->d, f->pf);
  pfloor_bounds(f->lo + f->pf, s->nf, s->n - s->nf, s->d, f->pa - f->pf);
  const size_t len = (size_t)s->n + (size_t)PF_SINK * f->pa;
  for (int b = 0; b < 2; b++)
    f->x[b] = malloc(len * sizeof *f->x[b]);
  f->v = malloc(len * sizeof *f->v);
  f->fs = malloc(len * sizeof *f->fs);
  f->ff = malloc(len * sizeof *f->ff);
  if (!f->x[0] || !f->x[1] || !f->v || !f->fs || !f->ff ||
      pfloor_lists(f, s->slow, s->n_slow, &f->so, &f->sb) < 0 ||
      pfloor_lists(f, s->fst, s->n_fast, &f->fo, &f->fb) < 0)
    return -1;
    /* first touch by the part's thread (the same static schedule as the
     * steps) */
#pragma omp parallel for schedule(static)
  for (int q = 0; q < f->pa; q++)
    for (int i = f->lo[q]; i < f->lo[q + 1]; i++) {
      f->x[0][i] = f->x[1][i] = s->x[i];
      f->v[i] = s->v[i];
      f->fs[i] = f->ff[i] = 0.0;
    }
  return 0;
}

/* Part q's slow (fast) bonds' forces on x into F, added. */
static void pfloor_springs(const pfloor *f, int q, int fast, const double *x,
                           double *F) {
  const long *o = fast ? f->fo : f->so;
  const pbond *b = (fast ? f->fb : f->sb) + o[q];
  const long nb = o[q + 1] - o[q];
  if (f->d == 2)
    (fast || !f->morse ? psprings20 : psprings21)(b, nb, x, F);
  else
    (fast || !f->morse ? psprings30 : psprings31)(b, nb, x, F);
}

/* Zero part q's coordinates of F and add its slow and/or fast forces. */
static void pfloor_part_force(const pfloor *f, int q, int slow, int fast,
                              const double *x, double *F) {
  memset(F + f->lo[q], 0, (size_t)(f->lo[q + 1] - f->lo[q]) * sizeof *F);
  if (slow)
    pfloor_springs(f, q, 0, x, F);
  if (fast)
    pfloor_springs(f, q, 1, x, F);
}

/* The forces at the positions (r-RESPA: fs slow, ff fast; Verlet: fs
 * all). */
static void pfloor_forces(pfloor *f, int verlet) {
  const double *x = f->x[f->cur];
#pragma omp parallel for schedule(static)
  for (int q = 0; q < f->pa; q++) {
    pfloor_part_force(f, q, 1, verlet, x, f->fs);
    if (!verlet && q < f->pf)
      pfloor_part_force(f, q, 0, 1, x, f->ff);
  }
}

/* Part q's v += h F and, unless x1 is NULL, its drift x1 = x0 + dt v. */
static void pfloor_kick(const pfloor *f, int q, const double *F, double h,
                        double dt, const double *x0, double *x1) {
  double *v = f->v;
  for (int i = f->lo[q]; i < f->lo[q + 1]; i++) {
    v[i] += h * F[i];
    if (x1)
      x1[i] = x0[i] + dt * v[i];
  }
}

/* Part q's half kick with F at dt, and unless last the next step's half
 * kick and its drift from xc into xn (the serial loops' operations on each
 * coordinate in their order). */
static void pfloor_kick_drift(const pfloor *f, int q, const double *F,
                              double dt, int last, const double *xc,
                              double *xn) {
  double *v = f->v;
  for (int i = f->lo[q]; i < f->lo[q + 1]; i++) {
    v[i] += 0.5 * dt * F[i];
    if (!last) {
      v[i] += 0.5 * dt * F[i];
      xn[i] = xc[i] + dt * v[i];
    }
  }
}

/* respa_steps on the parts, bitwise: one macro step per parallel region. */
static void prespa_steps(pfloor *f, double dT, int p, long steps) {
  const double dt = dT / p;
  double *v = f->v, *fs = f->fs, *ff = f->ff;
  const int *lo = f->lo, pf = f->pf, pa = f->pa;
  for (long k = 0; k < steps; k++) {
    const int c0 = f->cur;
#pragma omp parallel
    {
      int c = c0;
      /* the slow kick; the slow particles' drift (into both buffers: the
       * fast force reads no slow coordinate); the first fast half kick
       * and drift */
      double *x0 = f->x[c], *x1 = f->x[1 - c];
#pragma omp for schedule(static)
      for (int q = 0; q < pa; q++) {
        pfloor_kick(f, q, fs, 0.5 * dT, 0.0, NULL, NULL);
        if (q < pf)
          pfloor_kick(f, q, ff, 0.5 * dt, dt, x0, x1);
        else
          for (int i = lo[q]; i < lo[q + 1]; i++)
            x0[i] = x1[i] = x0[i] + dT * v[i];
      }
      c = 1 - c;
      for (int m = 0; m < p; m++) {
        const double *xc = f->x[c];
        double *xn = f->x[1 - c];
        const int last = m == p - 1;
#pragma omp for schedule(static)
        for (int q = 0; q < pf; q++) {
          pfloor_part_force(f, q, 0, 1, xc, ff);
          pfloor_kick_drift(f, q, ff, dt, last, xc, xn);
        }
        if (!last)
          c = 1 - c;
      }
      const double *xe = f->x[c];
#pragma omp for schedule(static)
      for (int q = 0; q < pa; q++) {
        pfloor_part_force(f, q, 1, 0, xe, fs);
        pfloor_kick(f, q, fs, 0.5 * dT, 0.0, NULL, NULL);
      }
    }
    f->cur = (c0 + p) & 1;
  }
}

/* verlet_steps on the parts, bitwise: one parallel region per call. */
static void pverlet_steps(pfloor *f, double dt, long steps) {
  double *F = f->fs;
  const int pa = f->pa, pf = f->pf;
  const int c0 = f->cur;
#pragma omp parallel
  {
    int c = c0;
#pragma omp for schedule(static)
    for (int q = 0; q < pa; q++)
      pfloor_kick(f, q, F, 0.5 * dt, dt, f->x[c], f->x[1 - c]);
    c = 1 - c;
    for (long k = 0; k < steps; k++) {
      const double *xc = f->x[c];
      double *xn = f->x[1 - c];
      const int last = k == steps - 1;
#pragma omp for schedule(static)
      for (int q = 0; q < pa; q++) {
        pfloor_part_force(f, q, 1, q < pf, xc, F);
        pfloor_kick_drift(f, q, F, dt, last, xc, xn);
      }
      if (!last)
        c = 1 - c;
    }
  }
  f->cur = (int)((c0 + steps) & 1);
}

/* ------------------------------------------------------------------------
 * LAMMPS: a data file, a pair list and an input script in a directory;
 * `lmp` run on them.
 * ---------------------------------------------------------------------- */
static int have_lammps(void) {
  const char *path = getenv("PATH");
  char buf[4096];
  while (path && *path) {
    const char *e = strchr(path, ':');
    size_t len = e ? (size_t)(e - path) : strlen(path);
    snprintf(buf, sizeof buf, "%.*s/lmp", (int)len, path);
    if (access(buf, X_OK) == 0)
      return 1;
    path = e ? e + 1 : NULL;
  }
  return 0;
}

/* Write DIR/data, DIR/pairs and DIR/in for `steps` steps of `style`
 * (respa: outer dT, p inner; verlet: dt = dT/p, steps * p steps); the final
 * state goes to DIR/final (id x y z vx vy vz). */
static int lammps_write(const network *w, const char *dir, int respa, double dT,
                        int p, long steps) {
  char path[512];
  snprintf(path, sizeof path, "%s/data", dir);
  FILE *f = fopen(path, "w");
  if (!f)
    return -1;
  double lo[3] = {1e300, 1e300, -0.5}, hi[3] = {-1e300, -1e300, 0.5};
  for (int i = 0; i < w->np; i++)
    for (int a = 0; a < w->d; a++) {
      double x = w->x0[i * w->d + a];
      lo[a] = x < lo[a] ? x : lo[a];
      hi[a] = x > hi[a] ? x : hi[a];
    }
  fprintf(f,
          "bench_floor network\n\n%d atoms\n%ld bonds\n1 atom types\n"
          "1 bond types\n\n",
          w->np, w->n_fast);
  for (int a = 0; a < 3; a++)
    fprintf(f, "%.6f %.6f %clo %chi\n", a < w->d ? lo[a] - 2 : lo[a],
            a < w->d ? hi[a] + 2 : hi[a], 'x' + a, 'x' + a);
  fprintf(f, "\nMasses\n\n1 1.0\n\nAtoms # bond\n\n");
  for (int i = 0; i < w->np; i++)
    fprintf(f, "%d 1 1 %.17g %.17g %.17g\n", i + 1, w->x0[i * w->d],
            w->x0[i * w->d + 1], w->d == 3 ? w->x0[i * w->d + 2] : 0.0);
  fprintf(f, "\nVelocities\n\n");
  for (int i = 0; i < w->np; i++)
    fprintf(f, "%d %.17g %.17g %.17g\n", i + 1, w->v0[i * w->d],
            w->v0[i * w->d + 1], w->d == 3 ? w->v0[i * w->d + 2] : 0.0);
  fprintf(f, "\nBonds\n\n");
  for (long e = 0; e < w->n_fast; e++)
    fprintf(f, "%ld 1 %d %d\n", e + 1, w->fst[e].i + 1, w->fst[e].j + 1);
  if (fclose(f) != 0)
    return -1;
  snprintf(path, sizeof path, "%s/pairs", dir);
  if (!(f = fopen(path, "w")))
    return -1;
  /* pair list harmonic: K (r - r0)^2, K = k/2 */
  for (long e = 0; e < w->n_slow; e++)
    fprintf(f, "%d %d harmonic %.17g %.17g\n", w->slow[e].i + 1,
            w->slow[e].j + 1, 0.5 * w->slow[e].k, w->slow[e].L0);
  if (fclose(f) != 0)
    return -1;
  snprintf(path, sizeof path, "%s/in", dir);
  if (!(f = fopen(path, "w")))
    return -1;
  fprintf(f,
          "units lj\ndimension %d\nboundary s s %s\natom_style bond\n"
          "atom_modify map array sort 0 0\n"
          "read_data %s/data\n"
          "bond_style harmonic\nbond_coeff 1 %.17g 1.0\n"
          "pair_style list %s/pairs 2.0\npair_coeff * *\n"
          "special_bonds lj/coul 1.0 1.0 1.0\n"
          "neighbor 0.5 bin\nneigh_modify every 1000 delay 0 check yes\n"
          "fix 1 all nve\nthermo 0\n",
          w->d, w->d == 2 ? "p" : "s", dir, 0.5 * 1000.0, dir);
  if (respa)
    fprintf(f, "timestep %.17g\nrun_style respa 2 %d bond 1 pair 2\n", dT, p);
  else
    fprintf(f, "timestep %.17g\nrun_style verlet\n", dT / p);
  fprintf(f,
          "run %ld\nwrite_dump all custom %s/final id x y z vx vy vz "
          "modify sort id format float %%.17g\n",
          respa ? steps : steps * p, dir);
  return fclose(f) == 0 ? 0 : -1;
}

/* Run lmp on DIR/in; the loop's CPU seconds (loop time x CPU share) and
 * the steps it reports; -1 on failure with a message. */
static double lammps_run(const char *dir, long *steps_out, long *maxrss_kb,
                         char *msg, size_t len) {
  char in[512], log[512];
  snprintf(in, sizeof in, "%s/in", dir);
  snprintf(log, sizeof log, "%s/log", dir);
  fflush(stdout);
  pid_t pid = fork();
  if (pid < 0) {
    snprintf(msg, len, "fork failed");
    return -1;
  }
  if (pid == 0) {
    setenv("OMP_NUM_THREADS", "1", 1);
    setenv("OMPI_ALLOW_RUN_AS_ROOT", "1", 1);
    setenv("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1", 1);
    if (!freopen("/dev/null", "w", stdout) ||
        !freopen("/dev/null", "w", stderr))
      _exit(126);
    execlp("lmp", "lmp", "-in", in, "-log", log, "-screen", "none",
           (char *)NULL);
    _exit(127);
  }
  int status = 0;
  struct rusage ru;
  if (wait4(pid, &status, 0, &ru) < 0 || !WIFEXITED(status) ||
      WEXITSTATUS(status) != 0) {
    snprintf(msg, len, "lmp failed (status %d; see %.150s)", status, log);
    return -1;
  }
  *maxrss_kb = ru.ru_maxrss;
  FILE *f = fopen(log, "r");
  char line[1024];
  double loop = -1, cpu = 100.0;
  while (f && fgets(line, sizeof line, f)) {
    double t;
    int procs;
    long st;
    if (sscanf(line, "Loop time of %lf on %d procs for %ld steps", &t, &procs,
               &st) == 3)
      loop = t, *steps_out = st;
    const char *c = strstr(line, "% CPU use");
    if (c) {
      const char *b = c;
      while (b > line && (b[-1] == '.' || (b[-1] >= '0' && b[-1] <= '9')))
        b--;
      cpu = atof(b);
    }
  }
  if (f)
    fclose(f);
  if (loop < 0) {
    snprintf(msg, len, "no loop time in %.150s", log);
    return -1;
  }
  return loop * cpu / 100.0;
}

/* Final positions of a LAMMPS run (DIR/final) in particle order. */
static int lammps_final(const char *dir, const network *w, double *x) {
  char path[512], line[1024];
  snprintf(path, sizeof path, "%s/final", dir);
  FILE *f = fopen(path, "r");
  if (!f)
    return -1;
  int got = 0;
  while (fgets(line, sizeof line, f)) {
    int id;
    double p[3];
    if (sscanf(line, "%d %lf %lf %lf", &id, p, p + 1, p + 2) == 4 && id >= 1 &&
        id <= w->np) {
      for (int a = 0; a < w->d; a++)
        x[(id - 1) * w->d + a] = p[a];
      got++;
    }
  }
  fclose(f);
  return got == w->np ? 0 : -1;
}

/* ------------------------------------------------------------------------
 * One case in a child process.
 * ---------------------------------------------------------------------- */
typedef struct result {
  int status; /* 0 ok, 1 failed, 2 over budget / memory, 3 skipped */
  int n;
  long steps;
  double create, step;      /* CPU s: creation, per macro step */
  double wall;              /* wall s per macro step */
  double newton, cg, gmres; /* per macro step; CG iterations per micro step */
  double evals; /* gradient evaluations of schur-krylov's outer iteration per
                   micro step */
  /* the cost model of the explicit and sweep paths: evaluations of grad W
   * and grad V per macro step, and the network's fast and slow springs */
  double ev_w, ev_v;
  long springs_w, springs_v;
  double geq; /* ... in gradients of V + W (their share of the terms) */
  long nnz;
  char path[16];
  long rss_before_kb, peak_kb;
  /* where the time of the large networks moves (doc/performance/16-fe16.md):
   * the process' transparent huge pages at the end of the stepping
   * (AnonHugePages of /proc/self/smaps_rollup, kB, -1 unknown) and its page
   * faults (minor + major) during the stepping and in all */
  long ahp_kb, faults_step, faults_all;
  char message[200];
  /* bench_serial (--serial): per macro step after the first, the CPU time
   * of the stepping thread outside the parallel regions (the serial
   * work), of every thread inside them, of the busiest thread summed over
   * the regions, and the regions entered and barriers passed in them */
  double ser, par, par_max, regions, barriers;
} result;

typedef struct options {
  double dT, budget, mem_gb;
  double min_cpu; /* --min-cpu: at least this CPU time of steps (0: K alone) */
  int p, steps, big;
  int threads;        /* settings.threads of the mrvi methods (default 1) */
  int par_floor;      /* the floors on the parts, o->threads threads */
  const char *tuning; /* NAME=VALUE for the mrvi methods, or NULL */
  char tmpdir[256];
} options;

/* Reset the peak resident set (VmHWM) to the current one, so that the peak
 * read at the end belongs to what follows (Linux >= 4.0; else the peak
 * includes the network's construction). */
static void reset_peak(void) {
  FILE *f = fopen("/proc/self/clear_refs", "w");
  if (f) {
    fputs("5", f);
    fclose(f);
  }
}

static long page_faults(void) {
  struct rusage u;
  return getrusage(RUSAGE_SELF, &u) == 0 ? u.ru_minflt + u.ru_majflt : -1;
}

/* After the stepping: the huge pages and the faults since f0. */
static void memory_probe(result *r, long f0) {
  r->ahp_kb = bench_proc_kb("/proc/self/smaps_rollup", "AnonHugePages:");
  r->faults_all = page_faults();
  r->faults_step = f0 >= 0 && r->faults_all >= 0 ? r->faults_all - f0 : -1;
}

static double wall_clock(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

static void mrvi_case(mrvi_model *m, method me, const options *o, result *r) {
  char msg[512];
  mrvi_settings s;
  mrvi_settings_default(&s);
  mrvi_settings_set_scheme(&s, method_names[me]);
  s.macro_step = o->dT;
  s.micro_steps = o->p;
  s.t_end = 1e6 * o->dT;
  s.energy_warning = 0;
  s.threads = o->threads;
  if (o->tuning) {
    const char *eq = strchr(o->tuning, '=');
    char name[64];
    snprintf(name, sizeof name, "%.*s", eq ? (int)(eq - o->tuning) : 0,
             o->tuning);
    if (!eq ||
        mrvi_settings_set_tuning(&s, name, atof(eq + 1), msg, sizeof msg) < 0) {
      snprintf(r->message, sizeof r->message, "--tuning %.60s: %.120s",
               o->tuning, eq ? msg : "NAME=VALUE expected");
      return;
    }
  }
  r->n = mrvi_model_n(m);
  reset_peak();
  r->rss_before_kb = bench_status_kb("VmRSS:");
  mrvi_integrator *it = NULL;
  /* creation runs on this thread (bench_thread_cpu: ticks of the process
   * clock would round it to 0 at 10^4 coordinates) */
  double t0 = bench_thread_cpu();
  if (mrvi_integrator_create(m, &s, &it, msg, sizeof msg) < 0) {
    snprintf(r->message, sizeof r->message, "%.190s", msg);
    return;
  }
  /* the floors keep no micro nodes: the last alone (sweep paths) */
  if (mrvi_integrator_keep_micro(it, 0) < 0) {
    snprintf(r->message, sizeof r->message, "keep_micro: out of memory");
    mrvi_integrator_free(it);
    return;
  }
  r->create = bench_thread_cpu() - t0;
  const long f0 = page_faults();
  double t1 = bench_cpu(), w1 = wall_clock();
  long newton = 0, k = 0;
#ifdef BENCH_OMP_PROFILE
  bench_omp_profile p0, p1;
  memset(&p0, 0, sizeof p0);
#endif
  for (; k < o->steps || (bench_cpu() - t1 < o->min_cpu && k < 100000); k++) {
    if (mrvi_integrator_step(it) < 0) {
      snprintf(r->message, sizeof r->message, "%.190s",
               mrvi_integrator_errmsg(it));
      break;
    }
    newton += mrvi_integrator_last_iterations(it);
#ifdef BENCH_OMP_PROFILE
    if (k == 0) /* (the first step apart: its one-off work) */
      bench_omp_profile_read(&p0);
#endif
  }
#ifdef BENCH_OMP_PROFILE
  if (!r->message[0] && k > 1) {
    bench_omp_profile_read(&p1);
    const double ks = (double)(k - 1);
    r->ser = ((p1.main_cpu - p1.in_main) - (p0.main_cpu - p0.in_main)) / ks;
    r->par = (p1.in_all - p0.in_all) / ks;
    r->par_max = (p1.in_max - p0.in_max) / ks;
    r->regions = (double)(p1.regions - p0.regions) / ks;
    r->barriers = (double)(p1.barriers - p0.barriers) / ks;
  }
#endif
  if (!r->message[0]) {
    r->step = (bench_cpu() - t1) / k;
    r->wall = (wall_clock() - w1) / k;
    r->steps = k;
    memory_probe(r, f0);
    mrvi_krylov_stats ks;
    mrvi_integrator_krylov_stats(it, &ks);
    r->newton = (double)newton / k;
    r->cg = (double)ks.cg_iterations / ((double)k * o->p);
    r->gmres = (double)ks.gmres_iterations / k;
    r->evals = (double)ks.outer_evals / ((double)k * o->p);
    r->ev_w = (double)ks.sweep_evals_w / k;
    r->ev_v = (double)ks.sweep_evals_v / k;
    r->geq = ks.outer_grad_equivalents / ((double)k * o->p);
    r->nnz = mrvi_integrator_system_nnz(it);
    snprintf(r->path, sizeof r->path, "%s", mrvi_integrator_solver_path(it));
    r->status = 0;
  }
  mrvi_integrator_free(it);
}

static void floor_case(floor_sys *f, method me, const options *o, result *r) {
  r->n = f->n;
  reset_peak();
  r->rss_before_kb = bench_status_kb("VmRSS:");
  double t0 = bench_thread_cpu();
  me == M_RESPA ? floor_forces(f) : verlet_forces(f);
  r->create = bench_thread_cpu() - t0;
  const long f0 = page_faults();
  double t1 = bench_cpu();
  long k = 0;
  while (k < o->steps || bench_cpu() - t1 < o->min_cpu) {
    if (me == M_RESPA)
      respa_steps(f, o->dT, o->p, 1);
    else
      verlet_steps(f, o->dT / o->p, o->p);
    k++;
  }
  r->step = (bench_cpu() - t1) / k;
  r->steps = k;
  memory_probe(r, f0);
  snprintf(r->path, sizeof r->path, "-");
  r->status = isfinite(f->x[0]) ? 0 : 1;
  if (r->status)
    snprintf(r->message, sizeof r->message, "floor diverged");
}

/* floor_case on the parts (--threads), on o->threads threads: CPU of all
 * threads and wall time per macro step. */
static void pfloor_case(floor_sys *s, method me, const options *o, result *r) {
#ifdef _OPENMP
  omp_set_num_threads(o->threads);
#endif
  pfloor f;
  r->n = s->n;
  if (pfloor_make(&f, s) < 0) {
    pfloor_free(&f);
    snprintf(r->message, sizeof r->message, "floor: out of memory");
    return;
  }
  pfloor_forces(&f, me == M_VERLET);
  const double t1 = bench_cpu(), w1 = wall_clock();
  long k = 0;
  while (k < o->steps || bench_cpu() - t1 < o->min_cpu) {
    if (me == M_RESPA)
      prespa_steps(&f, o->dT, o->p, 1);
    else
      pverlet_steps(&f, o->dT / o->p, o->p);
    k++;
  }
  r->step = (bench_cpu() - t1) / k;
  r->wall = (wall_clock() - w1) / k;
  r->steps = k;
  snprintf(r->path, sizeof r->path, "%d parts", f.pa);
  r->status = isfinite(f.x[f.cur][0]) ? 0 : 1;
  if (r->status)
    snprintf(r->message, sizeof r->message, "floor diverged");
  pfloor_free(&f);
}

/* The network is built and freed before the measured part, so that the
 * peak memory is that of the model (or the floor's arrays) and the
 * integrator. */
static void child_case(int fd, int kind, int n, method me, const options *o) {
  result r;
  memset(&r, 0, sizeof r);
  r.status = 1;
  network w;
  floor_sys f;
  mrvi_model *m = NULL;
  const int fl = me == M_RESPA || me == M_VERLET;
  int ok = network_make(&w, kind, n) == 0;
  r.springs_w = w.n_fast;
  r.springs_v = w.n_slow;
  if (ok && fl)
    ok = floor_make(&f, &w) == 0;
  else if (ok)
    ok = (m = network_model(&w, r.message, sizeof r.message)) != NULL;
  network_free(&w);
  if (!ok && !r.message[0])
    snprintf(r.message, sizeof r.message, "network: out of memory");
  else if (ok && fl && o->par_floor)
    pfloor_case(&f, me, o, &r);
  else if (ok && fl)
    floor_case(&f, me, o, &r);
  else if (ok)
    mrvi_case(m, me, o, &r);
  r.peak_kb = bench_status_kb("VmHWM:");
  ssize_t wr = write(fd, &r, sizeof r);
  (void)wr;
  if (ok && fl)
    floor_free(&f);
  mrvi_model_free(m);
}

typedef struct case_args {
  int kind, n;
  method me;
  const options *o;
} case_args;

static void child_fn(int fd, void *arg) {
  const case_args *a = arg;
  child_case(fd, a->kind, a->n, a->me, a->o);
}

static result run_case(int kind, int n, method me, const options *o) {
  case_args a = {kind, n, me, o};
  result r;
  memset(&r, 0, sizeof r);
  int ws = 0;
  if (bench_run_child(child_fn, &a, &r, sizeof r, o->budget, o->mem_gb, &ws) ==
      0) {
    memset(&r, 0, sizeof r);
    r.status = 2;
    snprintf(r.message, sizeof r.message, "child %s %d",
             WIFSIGNALED(ws) ? "killed by signal" : "exited with",
             WIFSIGNALED(ws) ? WTERMSIG(ws) : WEXITSTATUS(ws));
  }
  return r;
}

static result lammps_case(const network *w, method me, const options *o) {
  result r;
  memset(&r, 0, sizeof r);
  r.status = 1;
  r.n = w->d * w->np;
  snprintf(r.path, sizeof r.path, "-");
  /* at least o->min_cpu: steps from the r-RESPA floor's speed are not known
   * here, so run o->steps and scale up while the loop is short */
  long steps = o->steps;
  for (int tries = 0; tries < 6; tries++) {
    long done = 0, rss = 0;
    if (lammps_write(w, o->tmpdir, me == M_LMP_RESPA, o->dT, o->p, steps) < 0) {
      snprintf(r.message, sizeof r.message, "cannot write %.150s", o->tmpdir);
      return r;
    }
    double t = lammps_run(o->tmpdir, &done, &rss, r.message, sizeof r.message);
    if (t < 0)
      return r;
    r.peak_kb = rss;
    r.steps = steps;
    r.step = t / steps;
    r.status = 0;
    if (t >= o->min_cpu)
      break;
    steps = (long)ceil(steps * fmin(10.0, 1.5 * o->min_cpu / fmax(t, 1e-3)));
  }
  return r;
}

/* ------------------------------------------------------------------------
 * Checks on the smallest n.
 * ---------------------------------------------------------------------- */

/* mrvi's state after `steps` macro steps of `scheme` (model order, q then
 * p); 0 or -1 with the message on stderr. */
static int mrvi_trajectory_end(const network *w, const char *scheme,
                               const options *o, long steps, double *q,
                               double *pm) {
  char msg[512];
  mrvi_model *m = network_model(w, msg, sizeof msg);
  if (!m) {
    fprintf(stderr, "%s\n", msg);
    return -1;
  }
  mrvi_settings s;
  mrvi_settings_default(&s);
  mrvi_settings_set_scheme(&s, scheme);
  s.macro_step = o->dT;
  s.micro_steps = o->p;
  s.t_end = steps * o->dT;
  s.newton_tol = 1e-12;
  mrvi_integrator *it = NULL;
  int st = mrvi_integrator_create(m, &s, &it, msg, sizeof msg);
  for (long k = 0; st >= 0 && k < steps; k++)
    st = mrvi_integrator_step(it);
  if (st < 0)
    fprintf(stderr, "%s: %s\n", scheme, it ? mrvi_integrator_errmsg(it) : msg);
  else {
    memcpy(q, mrvi_integrator_q(it), (size_t)mrvi_model_n(m) * sizeof *q);
    memcpy(pm, mrvi_integrator_p(it), (size_t)mrvi_model_n(m) * sizeof *pm);
  }
  mrvi_integrator_free(it);
  mrvi_model_free(m);
  return st < 0 ? -1 : 0;
}

/* Floor state in particle (model) order. */
static void floor_state(const floor_sys *f, const network *w, double *q,
                        double *v) {
  for (int i = 0; i < w->np; i++)
    for (int a = 0; a < w->d; a++) {
      q[i * w->d + a] = f->x[f->perm[i] * w->d + a];
      if (v)
        v[i * w->d + a] = f->v[f->perm[i] * w->d + a];
    }
}

static double max_diff(const double *a, const double *b, int n) {
  double e = 0;
  for (int i = 0; i < n; i++)
    e = fmax(e, fabs(a[i] - b[i]));
  return e;
}

static void checks(int kind, int n, const options *o, int lammps) {
  network w;
  floor_sys f;
  if (network_make(&w, kind, n) < 0 || floor_make(&f, &w) < 0) {
    fprintf(stderr, "checks: out of memory\n");
    exit(1);
  }
  const int nc = w.d * w.np;
  const long K = CHECK_STEPS;
  double *q = malloc((size_t)nc * sizeof *q), *p = malloc(nc * sizeof *p),
         *qf = malloc((size_t)nc * sizeof *qf),
         *vf = malloc((size_t)nc * sizeof *vf),
         *qref = malloc((size_t)nc * sizeof *qref);
  if (!q || !p || !qf || !vf || !qref) {
    fprintf(stderr, "checks: out of memory\n");
    exit(1);
  }
  floor_forces(&f);
  respa_steps(&f, o->dT, o->p, K);
  floor_state(&f, &w, qf, vf);
  double scale = 0;
  for (int i = 0; i < nc; i++)
    scale = fmax(scale, fabs(qf[i]));
  printf("%s, n = %d (%ld slow, %ld fast springs), %ld macro steps "
         "(t = %g):\n",
         net_names[kind], nc, w.n_slow, w.n_fast, K, K * o->dT);
  if (mrvi_trajectory_end(&w, "fully-explicit", o, K, q, p) == 0)
    printf("- mrvi fully-explicit vs the r-RESPA floor: max |dq| = %.2e, "
           "max |dp| = %.2e (max |q| = %.3g)\n",
           max_diff(q, qf, nc), max_diff(p, vf, nc), scale);
  if (lammps && kind < 2) {
    double *ql = malloc((size_t)nc * sizeof *ql);
    long done = 0, rss = 0;
    char msg[256];
    if (ql && lammps_write(&w, o->tmpdir, 1, o->dT, o->p, K) == 0 &&
        lammps_run(o->tmpdir, &done, &rss, msg, sizeof msg) >= 0 &&
        lammps_final(o->tmpdir, &w, ql) == 0)
      printf("- LAMMPS rRESPA vs the r-RESPA floor: max |dq| = %.2e\n",
             max_diff(ql, qf, nc));
    else
      printf("- LAMMPS rRESPA: check failed (%s)\n", ql ? msg : "memory");
    free(ql);
  }
  /* Errors against Verlet at dt/20 at t = K dT. */
  floor_sys g;
  floor_make(&g, &w);
  verlet_forces(&g);
  verlet_steps(&g, o->dT / o->p / 20, K * o->p * 20);
  floor_state(&g, &w, qref, NULL);
  floor_free(&g);
  floor_make(&g, &w);
  verlet_forces(&g);
  verlet_steps(&g, o->dT / o->p, K * o->p);
  floor_state(&g, &w, q, NULL);
  floor_free(&g);
  printf("- max |q - q_ref| at t = %g (q_ref: Verlet at dt/20): Verlet(dt) "
         "%.2e, r-RESPA floor %.2e",
         K * o->dT, max_diff(q, qref, nc), max_diff(qf, qref, nc));
  for (int s = M_FE; s <= M_TM; s++)
    if (mrvi_trajectory_end(&w, method_names[s], o, K, q, p) == 0)
      printf(", %s %.2e", method_names[s], max_diff(q, qref, nc));
  printf("\n\n");
  free(q);
  free(p);
  free(qf);
  free(vf);
  free(qref);
  floor_free(&f);
  network_free(&w);
}

/* ------------------------------------------------------------------------
 * Tables.
 * ---------------------------------------------------------------------- */
/* Whether --method (only, or NULL: every method) runs method me: the
 * method named, and the floor its ratio is taken against. */
static int selected(const char *only, method me) {
  if (!only || !strcmp(only, method_names[me]))
    return 1;
  const int explicit_path =
      !strcmp(only, method_names[M_FE]) || !strcmp(only, method_names[M_ES]);
  const int implicit =
      !strcmp(only, method_names[M_MM]) || !strcmp(only, method_names[M_TM]);
  return (me == M_RESPA && explicit_path) || (me == M_VERLET && implicit);
}

static double ratio(const result *a, const result *b) {
  return a->status == 0 && b->status == 0 && b->step > 0 ? a->step / b->step
                                                         : NAN;
}

static void print_ratio(const result *a, const result *b) {
  double x = ratio(a, b);
  if (isnan(x))
    printf(" %10s |", "-");
  else
    printf(" %10.2f |", x);
}

/* The median of the rounds of one case that completed (NAN if none). */
static double median_step(const result *x, int repeats) {
  double t[MAX_REPEATS];
  int c = 0;
  for (int r = 0; r < repeats; r++)
    if (x[r].status == 0)
      t[c++] = x[r].step;
  return c ? bench_median(t, c) : NAN;
}

/* Every round of the cases (the best-of table hides a bimodal time): its
 * time, the process' transparent huge pages at the end of its stepping and
 * its page faults; then per method the best, the median and the worst
 * round, and the ratios to the floor of the ratio table (r-RESPA for the
 * explicit paths, Verlet for the implicit schemes) both ways round: best
 * over best, median over median, best over the floor's median and median
 * over the floor's best, so that a ratio moved by the floor's own spread
 * shows as such (doc/performance/16-fe16.md). */
static void rounds_table(result (*res)[N_METHODS][MAX_REPEATS], int n_n,
                         int repeats) {
  printf("\nEvery round (CPU s per macro step; AnonHugePages of the process "
         "at the end of the stepping, MB; page faults during the stepping "
         "and in the whole child)\n\n| %8s | %5s | %-20s | %11s | %8s | "
         "%10s | %10s |\n|---------:|------:|----------------------|---------"
         "---:|---------:|-----------:|-----------:|\n",
         "n", "round", "method", "step_s", "AHP_MB", "faults/st", "faults");
  for (int ni = 0; ni < n_n; ni++)
    for (int r = 0; r < repeats; r++)
      for (int me = 0; me < N_METHODS; me++) {
        const result *x = &res[ni][me][r];
        if (x->status != 0 || me >= M_LMP_RESPA)
          continue;
        printf("| %8d | %5d | %-20s | %11.4g | %8.1f | %10ld | %10ld |\n", x->n,
               r + 1, method_names[me], x->step, x->ahp_kb / 1024.0,
               x->faults_step, x->faults_all);
      }
  printf("\nSpread of the rounds, and the ratios to the floor both ways "
         "round (best/best, median/median, best/floor's median, "
         "median/floor's best)\n\n| %8s | %-20s | %10s | %10s | %10s | "
         "%9s | %9s | %9s | %9s |\n|---------:|----------------------|-----"
         "------:|-----------:|-----------:|----------:|----------:|--------"
         "--:|----------:|\n",
         "n", "method", "best_s", "median_s", "worst_s", "best/best", "med/med",
         "best/med", "med/best");
  for (int ni = 0; ni < n_n; ni++)
    for (int me = 0; me < M_LMP_RESPA; me++) {
      const result *x = res[ni][me];
      double best = INFINITY, worst = -INFINITY;
      int n = 0;
      for (int r = 0; r < repeats; r++)
        if (x[r].status == 0) {
          best = fmin(best, x[r].step);
          worst = fmax(worst, x[r].step);
          n = x[r].n;
        }
      if (!n)
        continue;
      const double med = median_step(x, repeats);
      printf("| %8d | %-20s | %10.4g | %10.4g | %10.4g |", n, method_names[me],
             best, med, worst);
      const method fm = me == M_MM || me == M_TM ? M_VERLET : M_RESPA;
      const result *f = res[ni][fm];
      double fb = INFINITY;
      for (int r = 0; r < repeats; r++)
        if (f[r].status == 0)
          fb = fmin(fb, f[r].step);
      const double fmed = median_step(f, repeats);
      if (me == M_RESPA || me == M_VERLET || !isfinite(fb))
        printf(" %9s | %9s | %9s | %9s |\n", "-", "-", "-", "-");
      else
        printf(" %9.2f | %9.2f | %9.2f | %9.2f |\n", best / fb, med / fmed,
               best / fmed, med / fb);
    }
}

/* The implicit schemes' cost model in the floor's micro steps (one
 * hand-written gradient of V + W and the update): the ratio to Verlet, the
 * outer iteration's gradient evaluations per micro step (each of the terms
 * of an interval's points) and what they are worth in gradients of V + W
 * (their share of the terms), the Newton path's Krylov iterations (CG per
 * micro step: a Hessian-vector product of a micro block each; GMRES per
 * macro step), and the rest: ratio - gradient equivalents, the time not
 * explained by gradients at the floor's cost (the iteration's own vector
 * passes, the kernels' distance to the hand-written loop, the predictor's
 * sweep), and its share. */
static void cost_model(result (*r)[N_METHODS], const int *n_list, int n_n) {
  printf("\nCost model of the implicit schemes (units: the Verlet floor's "
         "micro step)\n\n| %-20s | %8s | %9s | %9s | %8s | %8s | %8s | %8s "
         "| %7s |\n|----------------------|---------:|----------:|---------:|"
         "---------:|---------:|---------:|---------:|--------:|\n",
         "method", "n", "x Verlet", "evals/mic", "grad-eq", "cg/micro",
         "gmres/st", "rest", "rest %");
  const method ms[] = {M_MM, M_TM};
  for (int i = 0; i < 2; i++)
    for (int ni = 0; ni < n_n; ni++) {
      const result *a = &r[ni][ms[i]];
      const double x = ratio(a, &r[ni][M_VERLET]);
      if (isnan(x))
        continue;
      printf("| %-20s | %8d | %9.2f | %9.2f | %8.2f | %8.2f | %8.2f | %8.2f "
             "| %6.0f%% |\n",
             method_names[ms[i]], a->n ? a->n : n_list[ni], x, a->evals, a->geq,
             a->cg, a->gmres, x - a->geq, 100.0 * (x - a->geq) / x);
    }
}

/* STREAM's triad a = b + s c over arrays of n doubles on t threads, a
 * static partition, `passes` passes in one parallel region without a
 * barrier between them (what the memory allows, no synchronisation):
 * bytes moved per second of wall time (24 n a pass) in *wall and per
 * second of the threads' CPU time in *cpu. */
static void triad_rate(double *a, const double *b, const double *c, int n,
                       int t, long passes, double *wall, double *cpu) {
  const double w0 = wall_clock(), c0 = bench_cpu();
#pragma omp parallel num_threads(t)
  for (long k = 0; k < passes; k++) {
#pragma omp for schedule(static) nowait
    for (int i = 0; i < n; i++)
      a[i] = b[i] + 3.0 * c[i];
  }
  const double bytes = 24.0 * n * (double)passes;
  *wall = bytes / (wall_clock() - w0);
  *cpu = bytes / (bench_cpu() - c0);
}

/* What threads_table measures beside the cases, in a child (libgomp's pool
 * does not survive a fork): whether the floors on the parts give the serial
 * floor's state bitwise on t threads (2 macro steps), and the triad's
 * bytes per second over arrays of the case's n doubles on 1 and t threads
 * (best of 3 each, alternating). */
typedef struct machine_args {
  int kind, n, t;
  const options *o;
} machine_args;

typedef struct machine_result {
  int bitwise;             /* 1 both floors bitwise, 0 not, -1 not run */
  double triad_1, triad_t; /* bytes per second of wall time */
  double cpu_1, cpu_t;     /* ... per second of CPU time */
} machine_result;

static int pfloor_same(const pfloor *p, const floor_sys *s) {
  return !memcmp(p->x[p->cur], s->x, (size_t)s->n * sizeof *s->x) &&
         !memcmp(p->v, s->v, (size_t)s->n * sizeof *s->v);
}

static void machine_fn(int fd, void *arg) {
  const machine_args *a = arg;
  machine_result mr = {-1, 0.0, 0.0, 0.0, 0.0};
  network w;
  if (network_make(&w, a->kind, a->n) == 0) {
    mr.bitwise = 1;
    for (int me = M_RESPA; me <= M_VERLET; me++) {
      floor_sys f;
      pfloor pf;
      memset(&pf, 0, sizeof pf);
#ifdef _OPENMP
      omp_set_num_threads(a->t);
#endif
      if (floor_make(&f, &w) < 0 || pfloor_make(&pf, &f) < 0) {
        mr.bitwise = -1;
      } else if (me == M_RESPA) {
        floor_forces(&f);
        pfloor_forces(&pf, 0);
        respa_steps(&f, a->o->dT, a->o->p, 2);
        prespa_steps(&pf, a->o->dT, a->o->p, 2);
      } else {
        verlet_forces(&f);
        pfloor_forces(&pf, 1);
        verlet_steps(&f, a->o->dT / a->o->p, 2 * a->o->p);
        pverlet_steps(&pf, a->o->dT / a->o->p, a->o->p);
        pverlet_steps(&pf, a->o->dT / a->o->p, a->o->p);
      }
      if (mr.bitwise == 1 && !pfloor_same(&pf, &f))
        mr.bitwise = 0;
      pfloor_free(&pf);
      floor_free(&f);
    }
  }
  network_free(&w);
  const int n = a->n;
  double *x = malloc(3 * (size_t)n * sizeof *x);
  if (x) {
#pragma omp parallel for schedule(static) num_threads(a->t)
    for (int i = 0; i < n; i++)
      x[i] = 0.0, x[n + i] = 1.0, x[2 * n + i] = 2.0;
    /* passes for about 0.2 s of one thread (best of 3 rounds each) */
    double w, c;
    triad_rate(x, x + n, x + 2 * n, n, 1, 10, &w, &c);
    const long passes = (long)(0.2 * w / (24.0 * n)) + 1;
    for (int r = 0; r < 3; r++)
      for (int j = 0; j < 2; j++) {
        triad_rate(x, x + n, x + 2 * n, n, j ? a->t : 1, passes, &w, &c);
        double *bw = j ? &mr.triad_t : &mr.triad_1;
        double *bc = j ? &mr.cpu_t : &mr.cpu_1;
        *bw = w > *bw ? w : *bw;
        *bc = c > *bc ? c : *bc;
      }
    free(x);
  }
  ssize_t wr = write(fd, &mr, sizeof mr);
  (void)wr;
}

/* The floors (on the parts) and mrvi's schemes on 1 and on t threads,
 * alternating: wall time per macro step, best of `repeats` rounds, the
 * ratio (one run), the CPU ratio, and beside each scheme its floor's ratio
 * (r-RESPA for the explicit paths, Verlet for the implicit schemes), the
 * scheme's over the floor's, the floor's CPU ratio and the T threads' CPU
 * over their wall time: on a loaded machine the speed-ups scatter, but the
 * ratio to the floor of the same round and the CPU ratios judge the goal
 * (doc/performance/threads.md, "Threads: explicit-slow's serial bound"). */
static int threads_table(options *o, int t, const int *nets, const int *n_list,
                         int n_n, int repeats, const char *only) {
  const method ms[] = {M_RESPA, M_VERLET, M_FE, M_ES, M_MM, M_TM};
  const int n_ms = (int)(sizeof ms / sizeof *ms);
  printf("# mrvi %s  threads: 1 against %d  dT = %g  p = %d  best of %d "
         "alternating rounds (wall time)  %d cores available  load average "
         "%.2f at the start\n",
         mrvi_version(), t, o->dT, o->p, repeats,
         (int)sysconf(_SC_NPROCESSORS_ONLN), bench_load());
  printf("# build: %s; threads %s; OMP_WAIT_POLICY %s; GOMP_SPINCOUNT %s\n\n",
         bench_build(),
         mrvi_threads_supported() ? "on (OpenMP)" : "off (no OpenMP)",
         getenv("OMP_WAIT_POLICY") ? getenv("OMP_WAIT_POLICY") : "unset",
         getenv("GOMP_SPINCOUNT") ? getenv("GOMP_SPINCOUNT") : "unset");
  for (int k = 0; k < N_NETS; k++) {
    if (!nets[k])
      continue;
    printf("## %s\n\nwall: wall time per macro step; cpu_T/cpu_1: the CPU "
           "time of all threads per macro step over one thread's (near 1: "
           "the threads add little work, whatever the load does to the wall "
           "times); floor: the speed-up of the floor of the scheme's pairing "
           "(r-RESPA for fully-explicit and explicit-slow, Verlet for the "
           "implicit schemes) in the same round; ours/floor: the speed-up "
           "over the floor's (the goal's 1.6 over a floor's 2 is 0.8); "
           "floor_cpu: the floor's cpu_T/cpu_1; busy_T: the CPU time of the "
           "T threads over their wall time (the cores the run had: T where "
           "the machine gave it every core, so that a speed-up below T "
           "with cpu_T/cpu_1 near 1 is the machine's, not serial work); "
           "floors on %d-coordinate parts (path: their count)\n\n| %-20s "
           "| %8s | %-12s | %11s | %11s | %7s | %11s | %7s | %10s | %9s | "
           "%6s |\n",
           net_names[k], (int)PF_CHUNK, "method", "n", "path", "wall_1_s",
           "wall_T_s", "speedup", "cpu_T/cpu_1", "floor", "ours/floor",
           "floor_cpu", "busy_T");
    printf("|----------------------|---------:|--------------|------------:|"
           "------------:|--------:|------------:|--------:|-----------:|"
           "----------:|-------:|\n");
    for (int ni = 0; ni < n_n; ni++) {
      result best[N_METHODS][2];
      int run[N_METHODS] = {0};
      for (int i = 0; i < n_ms; i++) {
        const method me = ms[i];
        const int fl = me == M_RESPA || me == M_VERLET;
        run[me] = !((me == M_MM || me == M_TM) && n_list[ni] > o->big) &&
                  (!only || !strcmp(only, method_names[me]) ||
                   (fl && (me == M_RESPA) == (!strcmp(only, "fully-explicit") ||
                                              !strcmp(only, "explicit-slow"))));
        best[me][0].status = best[me][1].status = 1;
        snprintf(best[me][0].message, sizeof best[me][0].message, "not run");
      }
      for (int r = 0; r < repeats; r++)
        for (int i = 0; i < n_ms; i++)
          for (int j = 0; j < 2 && run[ms[i]]; j++) {
            const method me = ms[i];
            o->threads = j ? t : 1;
            o->par_floor = me == M_RESPA || me == M_VERLET;
            result x = run_case(k, n_list[ni], me, o);
            result *b = &best[me][j];
            if (x.status == 0 && (b->status != 0 || x.wall < b->wall))
              *b = x;
            else if (x.status != 0 && b->status != 0)
              *b = x;
          }
      o->threads = 1;
      o->par_floor = 0;
      for (int i = 0; i < n_ms; i++) {
        const method me = ms[i];
        const result *b = best[me];
        if (!run[me])
          continue;
        if (b[0].status != 0 || b[1].status != 0) {
          printf("| %-20s | %8d | failed: %s |\n", method_names[me], n_list[ni],
                 b[0].status ? b[0].message : b[1].message);
          continue;
        }
        const method fm = me == M_MM || me == M_TM ? M_VERLET : M_RESPA;
        const result *fb = best[fm];
        const int fl_ok = me != M_RESPA && me != M_VERLET &&
                          fb[0].status == 0 && fb[1].status == 0;
        const double floor_x = fl_ok ? fb[0].wall / fb[1].wall : NAN;
        const double floor_c = fl_ok ? fb[1].step / fb[0].step : NAN;
        const double sp = b[0].wall / b[1].wall;
        printf("| %-20s | %8d | %-12s | %11.4g | %11.4g | %7.2f | %11.2f | "
               "%7.2f | %10.2f | %9.2f | %6.2f |\n",
               method_names[me], b[0].n, b[0].path, b[0].wall, b[1].wall, sp,
               b[1].step / b[0].step, floor_x, sp / floor_x, floor_c,
               b[1].step / b[1].wall);
        fflush(stdout);
      }
      machine_args ma = {k, n_list[ni], t, o};
      machine_result mr = {-1, 0.0, 0.0, 0.0, 0.0};
      int ws = 0;
      if (bench_run_child(machine_fn, &ma, &mr, sizeof mr, o->budget, o->mem_gb,
                          &ws) == 0)
        mr.bitwise = -1;
      printf("| (n = %d: triad a = b + 3 c over arrays of %d doubles, best "
             "of 3: 1 thread %.2f GB/s, %d threads %.2f GB/s, ratio %.2f; "
             "per CPU second %.2f and %.2f GB/s, cpu_T/cpu_1 %.2f; floors on "
             "%d threads bitwise the serial floor's: %s) |\n",
             n_list[ni], n_list[ni], 1e-9 * mr.triad_1, t, 1e-9 * mr.triad_t,
             mr.triad_t / mr.triad_1, 1e-9 * mr.cpu_1, 1e-9 * mr.cpu_t,
             mr.cpu_1 / mr.cpu_t, t,
             mr.bitwise == 1   ? "yes"
             : mr.bitwise == 0 ? "NO"
                               : "not checked");
      fflush(stdout);
    }
    printf("\n");
  }
  printf("# load average %.2f at the end\n", bench_load());
  return 0;
}

#ifdef BENCH_OMP_PROFILE
/* bench_serial --serial T: each scheme on T threads, the serial fraction
 * of its step (doc/performance/threads.md, "The serial fraction of a step on
 * threads"): s = the stepping thread's CPU time outside the parallel
 * regions over the step's work (that plus every thread's CPU time in the
 * regions), the Amdahl bound 1 / (s + (1 - s) / T) it implies, the
 * bound with the imbalance in the regions as well: work / (serial + the
 * busiest thread's time summed over the regions), and the same with the
 * one-thread step's CPU time as the work (a run on 1 thread before each
 * run on T: what the threads add to the work counts against them).
 * Median of `repeats` runs.  Run with OMP_WAIT_POLICY=passive (a waiting thread
 * sleeps and is not counted); CPU times, so the machine's load disturbs them
 * less than wall times. */
static int serial_table(options *o, int t, const int *nets, const int *n_list,
                        int n_n, int repeats, const char *only) {
  const method ms[] = {M_FE, M_ES, M_MM, M_TM};
  printf("# mrvi %s  serial fraction on %d threads  dT = %g  p = %d  median "
         "of %d runs  %d cores available  load average %.2f at the start\n",
         mrvi_version(), t, o->dT, o->p, repeats,
         (int)sysconf(_SC_NPROCESSORS_ONLN), bench_load());
  printf("# build: %s; OMP_WAIT_POLICY %s\n\n", bench_build(),
         getenv("OMP_WAIT_POLICY") ? getenv("OMP_WAIT_POLICY") : "unset");
  printf("| %-9s | %-20s | %8s | %-12s | %8s | %8s | %9s | %9s | %9s | "
         "%9s | %7s | %7s | %7s | %7s |\n|-----------|----------------------|"
         "---------:|--------------|---------:|---------:|----------:|--------"
         "--:|----------:|----------:|--------:|--------:|--------:|--------:|"
         "\n",
         "network", "method", "n", "path", "regions", "barriers", "serial_ms",
         "par_ms", "imbal_ms", "cpu_1_ms", "s %", "amdahl", "bound", "bound_1");
  for (int k = 0; k < N_NETS; k++)
    for (int ni = 0; ni < n_n; ni++)
      for (int i = 0; i < 4; i++) {
        const method me = ms[i];
        if (!nets[k] || (only && strcmp(only, method_names[me])) ||
            ((me == M_MM || me == M_TM) && n_list[ni] > o->big))
          continue;
        double sv[MAX_REPEATS], pv[MAX_REPEATS], mv[MAX_REPEATS];
        double rv[MAX_REPEATS], nb[MAX_REPEATS], fv[MAX_REPEATS],
            av[MAX_REPEATS], bv[MAX_REPEATS], cv[MAX_REPEATS], b1[MAX_REPEATS];
        result x;
        int ok = 0;
        for (int r = 0; r < repeats; r++) {
          o->threads = 1;
          const result x1 = run_case(k, n_list[ni], me, o);
          o->threads = t;
          x = run_case(k, n_list[ni], me, o);
          if (x.status != 0 || x.par <= 0.0 || x1.status != 0)
            continue;
          const double work = x.ser + x.par;
          const double fr = x.ser / work;
          sv[ok] = x.ser, pv[ok] = x.par, rv[ok] = x.regions;
          nb[ok] = x.barriers;
          mv[ok] = x.par_max - x.par / t;
          fv[ok] = fr;
          av[ok] = 1.0 / (fr + (1.0 - fr) / t);
          bv[ok] = work / (x.ser + x.par_max);
          cv[ok] = x1.step;
          b1[ok] = x1.step / (x.ser + x.par_max);
          ok++;
        }
        if (!ok) {
          printf("| %-9s | %-20s | %8d | failed or not threaded: %s |\n",
                 net_names[k], method_names[me], n_list[ni], x.message);
          continue;
        }
        printf("| %-9s | %-20s | %8d | %-12s | %8.0f | %8.0f | %9.3f | %9.2f "
               "| %9.3f | %9.2f | %7.2f | %7.2f | %7.2f | %7.2f |\n",
               net_names[k], method_names[me], x.n, x.path,
               bench_median(rv, ok), bench_median(nb, ok),
               1e3 * bench_median(sv, ok), 1e3 * bench_median(pv, ok),
               1e3 * bench_median(mv, ok), 1e3 * bench_median(cv, ok),
               100.0 * bench_median(fv, ok), bench_median(av, ok),
               bench_median(bv, ok), bench_median(b1, ok));
        fflush(stdout);
      }
  printf("\n# load average %.2f at the end\n", bench_load());
  return 0;
}
#endif

int main(int argc, char **argv) {
  options o;
  memset(&o, 0, sizeof o);
  o.dT = 0.05;
  o.p = 10;
  o.steps = 3;
  o.budget = 300;
  o.mem_gb = 12;
  o.min_cpu = MIN_CPU;
  o.big = 1000000;
  int n_list[MAX_N] = {1000, 10000, 100000}, n_n = 3, repeats = 3;
  int nets[N_NETS] = {1, 1, 1}, quick = 0, no_lammps = 0, n_set = 0;
  const char *only = NULL;
  int threads = 0, serial = 0;
  o.threads = 1;
  for (int i = 1; i < argc; i++) {
    const char *a = argv[i];
    int has = i + 1 < argc;
    if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
      fputs(usage, stdout);
      return 0;
    } else if (!strcmp(a, "--quick")) {
      quick = 1;
    } else if (!strcmp(a, "--n") && has) {
      if ((n_n = bench_parse_ints(argv[++i], n_list, MAX_N)) <= 0)
        return bad_usage();
      n_set = 1;
    } else if (!strcmp(a, "--net") && has) {
      const char *s = argv[++i];
      for (int k = 0; k < N_NETS; k++)
        nets[k] = strstr(s, net_names[k]) != NULL;
      if (!nets[0] && !nets[1] && !nets[2])
        return bad_usage();
    } else if (!strcmp(a, "--p") && has) {
      if ((o.p = atoi(argv[++i])) < 1)
        return bad_usage();
    } else if (!strcmp(a, "--big") && has) {
      if ((o.big = atoi(argv[++i])) < 1)
        return bad_usage();
    } else if (!strcmp(a, "--dT") && has) {
      if (bench_parse_positive(argv[++i], &o.dT) < 0)
        return bad_usage();
    } else if (!strcmp(a, "--min-cpu") && has) {
      char *end = NULL;
      o.min_cpu = strtod(argv[++i], &end);
      if (!end || *end || end == argv[i] || !(o.min_cpu >= 0.0) ||
          !(o.min_cpu <= 3600.0))
        return bad_usage();
    } else if (!strcmp(a, "--budget") && has) {
      if (bench_parse_positive(argv[++i], &o.budget) < 0)
        return bad_usage();
    } else if (!strcmp(a, "--mem") && has) {
      if (bench_parse_positive(argv[++i], &o.mem_gb) < 0)
        return bad_usage();
    } else if (!strcmp(a, "--method") && has) {
      only = argv[++i];
      int known = 0;
      for (int me = 0; me < N_METHODS; me++)
        known |= !strcmp(only, method_names[me]);
      if (!known)
        return bad_usage();
    } else if (!strcmp(a, "--threads") && has) {
      if ((threads = atoi(argv[++i])) < 2)
        return bad_usage();
#ifdef BENCH_OMP_PROFILE
    } else if (!strcmp(a, "--serial") && has) {
      if ((serial = atoi(argv[++i])) < 2)
        return bad_usage();
#endif
    } else if (!strcmp(a, "--tuning") && has) {
      o.tuning = argv[++i];
    } else if (!strcmp(a, "--no-lammps")) {
      no_lammps = 1;
    } else if (bench_repeats_steps(argc, argv, &i, MAX_REPEATS, &repeats,
                                   &o.steps) <= 0) {
      return bad_usage();
    }
  }
  if (quick) {
    if (!n_set) {
      n_n = 2;
      n_list[0] = 300;
      n_list[1] = 1000;
    }
    repeats = 1;
    o.steps = 2;
    nets[1] = nets[2] = 0;
  }
#ifdef BENCH_OMP_PROFILE
  if (serial > 1)
    return serial_table(&o, serial, nets, n_list, n_n, repeats, only);
#endif
  (void)serial;
  if (threads > 1)
    return threads_table(&o, threads, nets, n_list, n_n, repeats, only);
  const int lammps = !no_lammps && have_lammps();
  snprintf(o.tmpdir, sizeof o.tmpdir, "/tmp/bench_floor.%d", (int)getpid());
  if (lammps && mkdir(o.tmpdir, 0700) < 0) {
    fprintf(stderr, "cannot create %s\n", o.tmpdir);
    return 1;
  }

  printf("# mrvi %s  networks  dT = %g  p = %d  at least %d macro steps and "
         "%g s  best of %d alternating rounds  load average %.2f at the "
         "start\n",
         mrvi_version(), o.dT, o.p, o.steps, o.min_cpu, repeats, bench_load());
  printf("# build: %s\n", bench_build());
  printf("# LAMMPS: %s\n\n",
         no_lammps ? "off (--no-lammps)"
         : lammps  ? "lmp found on PATH (rRESPA: bonds inner, pair list "
                     "outer; Verlet at dt)"
                   : "not found (install Debian's lammps); its columns are "
                     "skipped");

  printf("## Checks (smallest n)\n\n");
  if (n_list[0] > CHECK_MAX_N)
    printf("skipped: the smallest n is above %d\n\n", CHECK_MAX_N);
  for (int k = 0; k < N_NETS && n_list[0] <= CHECK_MAX_N; k++)
    if (nets[k])
      checks(k, n_list[0], &o, lammps);

  static result res[N_NETS][MAX_N][N_METHODS];
  static result rounds[N_NETS][MAX_N][N_METHODS][MAX_REPEATS];
  for (int k = 0; k < N_NETS; k++) {
    if (!nets[k])
      continue;
    int dead[N_METHODS] = {0};
    for (int ni = 0; ni < n_n; ni++) {
      for (int me = 0; me < N_METHODS; me++) {
        res[k][ni][me].status = 3;
        res[k][ni][me].step = INFINITY;
        for (int r = 0; r < repeats; r++)
          rounds[k][ni][me][r].status = 3;
      }
      network w;
      int have_w = 0;
      for (int r = 0; r < repeats; r++)
        for (int me = 0; me < N_METHODS; me++) {
          int is_lmp = me >= M_LMP_RESPA;
          int implicit = me == M_MM || me == M_TM;
          if (dead[me] || (is_lmp && (!lammps || k == 2)) ||
              !selected(only, (method)me) || (implicit && n_list[ni] > o.big))
            continue;
          result x;
          if (is_lmp) {
            if (!have_w && network_make(&w, k, n_list[ni]) == 0)
              have_w = 1;
            if (!have_w)
              continue;
            x = lammps_case(&w, (method)me, &o);
          } else {
            x = run_case(k, n_list[ni], (method)me, &o);
          }
          rounds[k][ni][me][r] = x;
          result *best = &res[k][ni][me];
          if (x.status == 0 && (best->status != 0 || x.step < best->step))
            *best = x;
          else if (best->status != 0)
            *best = x;
          if (x.status != 0) {
            fprintf(stderr, "%s n = %d %s: %s\n", net_names[k], n_list[ni],
                    method_names[me], x.message);
            if (x.status == 2)
              dead[me] = 1;
          }
        }
      if (have_w)
        network_free(&w);
    }
    /* The network's tables as soon as it is measured. */
    printf("## %s\n\nTimes: CPU seconds per macro step (dT = %g; Verlet: p "
           "steps of dt), best of %d; creation: integrator set-up (floors: "
           "first force evaluation); memory: the child's peak resident set "
           "per coordinate and its growth from before the integrator's "
           "creation (LAMMPS: the process' peak)\n\n",
           net_names[k], o.dT, repeats);
    printf("| %-20s | %8s | %-12s | %11s | %9s | %10s | %9s | %9s | %8s | "
           "%8s | %8s | %9s | %10s |\n",
           "method", "n", "path", "step_s", "create_s", "create/st", "B/coord",
           "dB/coord", "newton/st", "cg/micro", "gmres/st", "nnz/coord",
           "grad/micro");
    printf("|----------------------|---------:|--------------|------------:|"
           "----------:|-----------:|----------:|----------:|---------:|"
           "---------:|---------:|----------:|-----------:|\n");
    for (int me = 0; me < N_METHODS; me++)
      for (int ni = 0; ni < n_n; ni++) {
        const result *r = &res[k][ni][me];
        if (r->status == 3)
          continue;
        if (r->status != 0) {
          printf("| %-20s | %8d | failed: %s |\n", method_names[me], n_list[ni],
                 r->message);
          continue;
        }
        printf("| %-20s | %8d | %-12s | %11.4g | %9.3g | %10.2f | %9.0f | "
               "%9.0f | %8.2f | %8.2f | %8.2f | %9.1f | %10.2f |\n",
               method_names[me], r->n, r->path, r->step, r->create,
               r->create / r->step, 1024.0 * r->peak_kb / r->n,
               r->rss_before_kb > 0
                   ? 1024.0 * (r->peak_kb - r->rss_before_kb) / r->n
                   : NAN,
               r->newton, r->cg, r->gmres, (double)r->nnz / r->n, r->evals);
      }
    printf("\nRatios (one run), issue-24 goals: fully-explicit <= 1.3 x "
           "r-RESPA, explicit-slow <= 4 x r-RESPA and faster than LAMMPS "
           "rRESPA, midpoint-midpoint and trapezoidal-midpoint <= 15 x "
           "Verlet\n\n");
    printf("| %8s | %10s | %10s | %10s | %10s | %10s | %10s | %10s |\n", "n",
           "FE/RESPA", "ES/RESPA", "MM/Verlet", "TM/Verlet", "ES/LMP-R",
           "FE/LMP-R", "LMP-V/Ver");
    printf("|---------:|-----------:|-----------:|-----------:|-----------:|"
           "-----------:|-----------:|-----------:|\n");
    for (int ni = 0; ni < n_n; ni++) {
      const result *r = res[k][ni];
      printf("| %8d |", r[M_RESPA].n ? r[M_RESPA].n : n_list[ni]);
      print_ratio(&r[M_FE], &r[M_RESPA]);
      print_ratio(&r[M_ES], &r[M_RESPA]);
      print_ratio(&r[M_MM], &r[M_VERLET]);
      print_ratio(&r[M_TM], &r[M_VERLET]);
      print_ratio(&r[M_ES], &r[M_LMP_RESPA]);
      print_ratio(&r[M_FE], &r[M_LMP_RESPA]);
      print_ratio(&r[M_LMP_VERLET], &r[M_VERLET]);
      printf("\n");
    }
    printf("\nCost model of the explicit paths against the r-RESPA floor "
           "(one grad W per micro step, one grad V per macro step): "
           "force work per macro step in spring evaluations, as a multiple "
           "of the floor's (p s_W + s_V); per micro step, the evaluations "
           "of grad W and of grad V (V: per macro step / p); 'other': the "
           "share of the time that force work at the floor's cost per "
           "spring does not explain, 1 - work / ratio\n\n");
    printf("| %8s | %-14s | %10s | %9s | %9s | %10s | %8s |\n", "n", "method",
           "ratio", "gradW/mic", "gradV/mic", "work/floor", "other");
    printf("|---------:|----------------|-----------:|----------:|----------:|"
           "-----------:|---------:|\n");
    for (int ni = 0; ni < n_n; ni++)
      for (int me = M_FE; me <= M_ES; me++) {
        const result *r = &res[k][ni][me], *fl = &res[k][ni][M_RESPA];
        if (r->status != 0 || fl->status != 0)
          continue;
        const double sw = (double)r->springs_w, sv = (double)r->springs_v;
        const double work =
            (r->ev_w * sw + r->ev_v * sv) / ((double)o.p * sw + sv);
        const double x = ratio(r, fl);
        printf("| %8d | %-14s | %10.2f | %9.2f | %9.3f | %10.2f | %7.0f%% |\n",
               r->n, method_names[me], x, r->ev_w / o.p, r->ev_v / o.p, work,
               100.0 * (1.0 - work / x));
      }
    cost_model(res[k], n_list, n_n);
    if (repeats >= 2)
      rounds_table(rounds[k], n_n, repeats);
    printf("\nExponents of the time per macro step in n (least squares on "
           "log-log over the completed n)\n\n| %-20s | %8s |\n|----------"
           "------------|---------:|\n",
           "method", "exponent");
    for (int me = 0; me < N_METHODS; me++) {
      double x[MAX_N], y[MAX_N];
      int c = 0;
      for (int ni = 0; ni < n_n; ni++)
        if (res[k][ni][me].status == 0) {
          x[c] = res[k][ni][me].n;
          y[c++] = res[k][ni][me].step;
        }
      if (c >= 2)
        printf("| %-20s | %8.3f |\n", method_names[me],
               bench_exponent(x, y, c));
    }
    printf("\n");
    fflush(stdout);
  }
  printf("# load average %.2f at the end\n", bench_load());
  if (lammps) {
    char cmd[300];
    snprintf(cmd, sizeof cmd, "%s/in", o.tmpdir);
    const char *files[] = {"in", "data", "pairs", "log", "final"};
    for (int i = 0; i < 5; i++) {
      snprintf(cmd, sizeof cmd, "%s/%s", o.tmpdir, files[i]);
      unlink(cmd);
    }
    rmdir(o.tmpdir);
  }
  return 0;
}
