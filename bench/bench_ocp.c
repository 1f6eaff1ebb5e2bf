/* Optimal control timings (doc/optimal-control.md):
 *   1. shipped problems at growing N and p: optimiser evaluations, time of
 *      one cost+gradient evaluation relative to one forward sweep (target
 *      <= 3), total time;
 *   2. the largest number of controls each algorithm solves within a time
 *      budget (default 60 s per solve), doubling N on the double
 *      integrator;
 *   3. (--lattice SIZES, alone) the planar lattice of systems/lattice.yaml
 *      grown to about n coordinates (midpoint-midpoint, p = 10, dT = 0.05,
 *      N = 20; one macro-grid actuator pushing the corner particle along x,
 *      tracking of one other coordinate, terminal position and velocity of
 *      the actuated coordinate): CPU time of one forward sweep and of one
 *      cost + gradient (constraint gradients included), their ratio, and
 *      the peak resident memory after each, every size in its own process
 *      (issue goal: ratio <= 3; memory <= 2x the forward run plus the
 *      stored trajectory).  --constrained adds holonomic constraints:
 *      the last column clamped (fixed) and rods (distance) between pairs
 *      of the top row, each coupling a slow and a fast particle;
 *      --solve then solves each size's problem with its algorithm (SLSQP)
 *      from the loaded initial controls: evaluations, CPU time, status;
 *   4. (--chain LINKS, alone) the same measurements on bench_chain's rod
 *      chain (bench_chain_model: particles on rods, each with a fast light
 *      mass; midpoint-midpoint, p = 10, dT = 0.01, N = 20): a macro-grid
 *      actuator pushing the first link along x, the last link's x at
 *      t_end a terminal constraint, effort cost (the chain elimination's
 *      adjoint: doc/performance/ocp.md, "Optimal control on the chain
 *      elimination").
 *      --no-solve: part 1 without the solves: cost + gradient per
 *      evaluation and over the forward run (best of three chunks of 20)
 *      at the loaded controls ("rest") and at u_i = 0.5 sin(0.7 i).
 * Usage: bench_ocp [--budget SECONDS] [--only PROBLEM] [--no-solve] [--lattice
 * SIZES
 * [--constrained] [--solve] [--set NAME=VALUE]...] [--chain LINKS [--solve]
 * [--set integrator.tuning.NAME=VALUE]...] (--set: overrides of the
 * problems of parts 1, 3 and 4)
 * (run from the source root, or set MRVI_SOURCE_ROOT; --only: part 1 for
 * one problem, e.g. ocp_reorient, and no part 2; ocp_winch and
 * ocp_winch_free, a crane with a winch (pair actuator), are in bench/). */
#include "bench_util.h"
#include "mrvi.h"
#include "ocp/ocp.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

static double now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* --set overrides of the problems (e.g.
 * integrator.tuning.adjoint_dense_max=0). */
enum { MAX_SET = 8 };
static const char *set[MAX_SET];
static int n_set;
static int constrained, solve; /* --constrained, --solve (part 3) */
static int no_solve;           /* --no-solve (part 1) */

typedef struct row {
  int n_u, evals, ok;
  double t_eval, ratio, total, cost;
  double ratio_opt; /* eval/fwd at the returned controls */
  char path[16];    /* step solver path of the forward pass */
} row;

/* Best of three: forward sweep alone (tf) and cost+gradient with the
 * constraint gradients (ta) at u, CPU time (the machine may be loaded). */
static void time_eval(mrvi_ocp *o, const double *u, double *g, double *c,
                      double *cg, double *tf, double *ta) {
  double J;
  *tf = *ta = 1e30;
  for (int i = 0; i < 3; i++) {
    double t0 = bench_cpu();
    mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL);
    *tf = fmin(*tf, bench_cpu() - t0);
    t0 = bench_cpu();
    mrvi_ocp_evaluate(o, u, &J, g, c, cg);
    *ta = fmin(*ta, bench_cpu() - t0);
  }
}

/* --no-solve: CPU time per evaluation, best of three chunks of 20, of the
 * forward run alone (tf) and of cost + gradient (ta) at u. */
static void time_chunks(mrvi_ocp *o, const double *u, double *g, double *c,
                        double *cg, double *tf, double *ta) {
  double J;
  *tf = *ta = 1e30;
  for (int i = 0; i < 3; i++) {
    double t0 = bench_cpu();
    for (int k = 0; k < 20; k++)
      mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL);
    *tf = fmin(*tf, (bench_cpu() - t0) / 20.0);
    t0 = bench_cpu();
    for (int k = 0; k < 20; k++)
      mrvi_ocp_evaluate(o, u, &J, g, c, cg);
    *ta = fmin(*ta, (bench_cpu() - t0) / 20.0);
  }
}

/* Load FILE with overrides, time evaluations and solve (--no-solve: time
 * at the loaded controls, r->ratio, and at u_i = 0.5 sin(0.7 i),
 * r->ratio_opt, with r->t_eval and r->total the two cost + gradient
 * times). */
static int bench(const char *file, const char **ov, int n_ov, int alg, row *r) {
  char msg[2048];
  mrvi_system *sys = NULL;
  memset(r, 0, sizeof *r);
  if (mrvi_system_load(file, ov, n_ov, &sys, msg, sizeof msg) < 0) {
    fprintf(stderr, "%s\n", msg);
    return -1;
  }
  mrvi_ocp *o = NULL;
  double *u = NULL;
  if (mrvi_ocp_load(sys, &o, &u, msg, sizeof msg) < 0) {
    fprintf(stderr, "%s\n", msg);
    mrvi_system_free(sys);
    return -1;
  }
  if (alg >= 0)
    mrvi_ocp_set_algorithm(o, (mrvi_ocp_algorithm)alg);
  const int n = mrvi_ocp_n_controls(o), m = mrvi_ocp_n_constraints(o);
  double *g = malloc((size_t)n * sizeof *g);
  double *cg = malloc((size_t)(m * n + 1) * sizeof *cg);
  double *c = malloc((size_t)(m + 1) * sizeof *c);
  double tf, ta;
  if (no_solve) {
    time_chunks(o, u, g, c, cg, &tf, &ta);
    r->t_eval = ta;
    r->ratio = ta / tf;
    for (int i = 0; i < n; i++)
      u[i] = 0.5 * sin(0.7 * i);
    time_chunks(o, u, g, c, cg, &tf, &ta);
    r->total = ta;
    r->ratio_opt = ta / tf;
    r->n_u = n;
    r->ok = 1;
  } else {
    time_eval(o, u, g, c, cg, &tf, &ta);
  }
  const char *path = mrvi_ocp_solver_path(o, NULL, 0);
  snprintf(r->path, sizeof r->path, "%s", path ? path : "none");
  if (no_solve)
    goto done;
  mrvi_ocp_result res;
  const double t0 = now();
  const int st = mrvi_ocp_solve(o, u, &res);
  r->total = now() - t0;
  r->n_u = n;
  r->evals = res.evaluations;
  r->ok = st == 0;
  r->t_eval = ta;
  r->ratio = ta / tf;
  r->cost = res.cost;
  /* At the returned controls (the forward Newton iterations of a problem
   * at rest under u = 0 are fewer than along a controlled motion). */
  double tf1, ta1;
  time_eval(o, u, g, c, cg, &tf1, &ta1);
  r->ratio_opt = ta1 / tf1;
done:
  free(g);
  free(cg);
  free(c);
  free(u);
  mrvi_ocp_free(o);
  mrvi_system_free(sys);
  return 0;
}

/* Part 3: the lattice problem at about n coordinates. */
#define ROUND_CPU 0.2 /* s, the least CPU time of one timing round */
typedef struct lattice_rec {
  int n, n_u, m, ok;
  double t_fwd, t_first, t_grad, fwd_kb, grad_kb, traj_kb;
  char path[16], message[200];
  /* --solve: evaluations, CPU time, outcome (0 evaluations: not run or
   * not finished within the budget). */
  int solve_evals;
  double solve_cpu, solve_cost, solve_violation, solve_kb;
  char solve_status[24], solve_nlopt[48];
} lattice_rec;

static const char *lattice_ocp_text =
    "name: lattice_ocp\ndimension: 2\n"
    "generate:\n"
    "  - kind: lattice2d\n"
    "    name: p\n"
    "    count: [6, 5]\n"
    "    spacing: 1.0\n"
    "    mass: 1.0\n"
    "    rates: {every: 2}\n"
    "    slow_spring: {law: linear, stiffness: 10}\n"
    "    fast_spring: {law: linear, stiffness: 1000}\n"
    "    initial:\n"
    "      - {index: [2, 2], displacement: [0.1, 0.05], velocity: [0.0, "
    "0.5]}\n"
    "integrator: {scheme: midpoint-midpoint, macro_step: 0.05, micro_steps: "
    "10, t_end: 1}\n"
    "control:\n"
    "  actuators:\n"
    "    - {name: push, coordinate: p0_0.x, grid: macro, weight: 1}\n"
    "  tracking:\n"
    "    - {coordinate: p1_1.y, weight: 1, reference: 0}\n"
    "  terminal:\n"
    "    - {coordinate: p0_0.x, position: 0.2, velocity: 0}\n"
    "  solver: {algorithm: slsqp}\n";

/* The lattice problem's text, with --constrained its constraints: the
 * last column (index nx - 1) clamped, rods between the particles 2i and
 * 2i + 1 of the top row (index ny - 1; slow and fast, each fast one in one
 * rod, none in the clamped column: two rods on one fast particle, both
 * along x, would constrain the slow ones alone, which the micro nodes
 * cannot enforce).  Caller frees. */
static char *lattice_text(int nx, int ny) {
  const size_t len = strlen(lattice_ocp_text) + 32 + 96 * (size_t)(nx + ny);
  char *t = malloc(len);
  if (!t)
    return NULL;
  size_t k = (size_t)snprintf(t, len, "%s", lattice_ocp_text);
  if (constrained) {
    k += (size_t)snprintf(t + k, len - k, "constraints:\n");
    for (int j = 0; j < ny; j++)
      k += (size_t)snprintf(t + k, len - k,
                            "  - {type: fixed, particle: p%d_%d}\n", nx - 1, j);
    for (int i = 0; i + 2 < nx; i += 2)
      k += (size_t)snprintf(t + k, len - k,
                            "  - {type: distance, between: [p%d_%d, p%d_%d]}\n",
                            i, ny - 1, i + 1, ny - 1);
  }
  return t;
}

/* Times one forward run and one cost + gradient of o at a controlled
 * motion (u: the loaded controls, kept for --solve), peak memory after
 * each, and with --solve the solve from u: records of r to fd (r's n, m
 * and traj_kb set by the caller).  Frees o and u. */
static void measure(int fd, mrvi_ocp *o, double *u, lattice_rec *r) {
  const int n = mrvi_ocp_n_controls(o), m = mrvi_ocp_n_constraints(o);
  double *u0 = NULL, *g = NULL, *c = NULL, *cg = NULL;
  r->n_u = n;
  u0 = malloc((size_t)n * sizeof *u0); /* the loaded guess, for --solve */
  if (u0)
    memcpy(u0, u, (size_t)n * sizeof *u0);
  for (int i = 0; i < n; i++)
    u[i] = 0.5 * sin(0.7 * i); /* a controlled motion */
  g = malloc((size_t)n * sizeof *g);
  c = malloc((size_t)(m + 1) * sizeof *c);
  cg = malloc((size_t)(m * n + 1) * sizeof *cg);
  const char *path = mrvi_ocp_solver_path(o, NULL, 0);
  snprintf(r->path, sizeof r->path, "%s", path ? path : "none");
  double J;
  int ok = u0 && g && c && cg;
  /* First forward (allocation and set-up) untimed, then the best of up
   * to three rounds within about a second each.  A round repeats the call
   * for at least ROUND_CPU seconds: the CPU clock of the child ticks in
   * steps of some milliseconds (4 ms here), as long as a small lattice's
   * forward run. */
  ok = ok && mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL) == 0;
  r->t_fwd = 1e30;
  for (int i = 0; i < 3 && ok; i++) {
    const double t0 = bench_cpu();
    int calls = 0;
    do {
      ok = mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL) == 0;
      calls++;
    } while (ok && bench_cpu() - t0 < ROUND_CPU);
    r->t_fwd = fmin(r->t_fwd, (bench_cpu() - t0) / calls);
    if (r->t_fwd > 1.0)
      break;
  }
  r->fwd_kb = (double)bench_status_kb("VmHWM:");
  /* The first cost + gradient (the adjoint's set-up: pattern, first
   * factorisation) apart, then the best of up to two rounds, each call at
   * controls moved as an optimiser would (kept factors from the
   * evaluation before). */
  r->t_grad = 1e30;
  for (int i = 0; i < 3 && ok; i++) {
    const double t0 = bench_cpu();
    int calls = 0;
    do {
      ok = mrvi_ocp_evaluate(o, u, &J, g, c, cg) == 0;
      calls++;
      for (int j = 0; j < n; j++)
        u[j] -= 0.01 * g[j];
    } while (ok && i > 0 && bench_cpu() - t0 < ROUND_CPU);
    const double t = (bench_cpu() - t0) / calls;
    if (i == 0)
      r->t_first = t;
    else
      r->t_grad = fmin(r->t_grad, t);
    (void)!write(fd, r, sizeof *r); /* a partial record */
    if (i > 0 && r->t_grad > 5.0)
      break;
  }
  r->grad_kb = (double)bench_status_kb("VmHWM:");
  r->ok = ok;
  if (!ok)
    snprintf(r->message, sizeof r->message, "%.199s", mrvi_ocp_errmsg(o));
  (void)!write(fd, r, sizeof *r);
  if (ok && solve) {
    mrvi_ocp_result res;
    memset(&res, 0, sizeof res);
    const double t0 = bench_cpu();
    (void)mrvi_ocp_solve(o, u0, &res);
    r->solve_cpu = bench_cpu() - t0;
    r->solve_evals = res.evaluations;
    r->solve_cost = res.cost;
    r->solve_violation = res.violation;
    r->solve_kb = (double)bench_status_kb("VmHWM:");
    snprintf(r->solve_status, sizeof r->solve_status, "%s", res.status);
    snprintf(r->solve_nlopt, sizeof r->solve_nlopt, "%s", res.nlopt_name);
    (void)!write(fd, r, sizeof *r);
  }
  free(u0);
  free(g);
  free(c);
  free(cg);
  free(u);
  mrvi_ocp_free(o);
}

static void lattice_child(int fd, void *arg) {
  const int target = *(const int *)arg;
  lattice_rec r;
  memset(&r, 0, sizeof r);
  /* nx x ny particles, nx = ny + 1 or so (6 x 5 at n = 60). */
  const int particles = target / 2 < 4 ? 4 : target / 2;
  int ny = (int)floor(sqrt((double)particles));
  while (ny > 2 && particles % ny != 0 && particles % ny < ny / 2)
    ny--;
  const int nx = (particles + ny - 1) / ny;
  char count[64], msg[2048];
  char *text = lattice_text(nx, ny);
  snprintf(count, sizeof count, "generate.0.count=[%d, %d]", nx, ny);
  const char *ov[1 + MAX_SET] = {count};
  for (int i = 0; i < n_set; i++)
    ov[1 + i] = set[i];
  mrvi_system *sys = NULL;
  mrvi_ocp *o = NULL;
  double *u = NULL;
  if (!text)
    snprintf(msg, sizeof msg, "out of memory");
  if (!text ||
      mrvi_system_load_string(text, "lattice_ocp", ov, 1 + n_set, &sys, msg,
                              sizeof msg) < 0 ||
      mrvi_ocp_load(sys, &o, &u, msg, sizeof msg) < 0) {
    snprintf(r.message, sizeof r.message, "%.199s", msg);
    (void)!write(fd, &r, sizeof r);
    mrvi_system_free(sys);
    free(text);
    return;
  }
  free(text);
  r.n = 2 * nx * ny;
  r.m = mrvi_model_constraint_rows(sys->model);
  /* Trajectory kept for the adjoint: nodes, momenta, multipliers. */
  r.traj_kb = 8.0 * (21.0 * 2 * nx * ny * 10 + 2 * 21.0 * 2 * nx * ny) / 1024.0;
  measure(fd, o, u, &r);
  mrvi_system_free(sys);
}

/* Part 4: the optimal control of a rod chain of n links (bench_chain's
 * "rods", bench_chain_model; midpoint-midpoint, p = 10, dT = 0.01, N = 20):
 * a macro-grid actuator pushing the first link along x, the last link's x
 * at t_end held at its initial value plus 0.05 (a terminal constraint),
 * effort cost. */
enum { CHAIN_P = 10, CHAIN_N = 20 };
static void chain_child(int fd, void *arg) {
  const int links = *(const int *)arg;
  lattice_rec r;
  memset(&r, 0, sizeof r);
  char msg[2048] = "";
  mrvi_settings s;
  mrvi_settings_default(&s);
  mrvi_model *m = bench_chain_model(0, links, 9.81, msg, sizeof msg);
  mrvi_ocp *o = NULL;
  int st = m ? mrvi_settings_set_scheme(&s, "midpoint-midpoint") : -1;
  s.macro_step = 0.01, s.micro_steps = CHAIN_P, s.t_end = CHAIN_N * 0.01;
  const char *pre = "integrator.tuning."; /* (--set: tuning constants) */
  const size_t lp = strlen(pre);
  for (int i = 0; i < n_set && st >= 0; i++) {
    const char *eq = strchr(set[i], '=');
    char key[64];
    if (!eq || strncmp(set[i], pre, lp) != 0) {
      snprintf(msg, sizeof msg, "--chain: --set takes %sNAME=VALUE", pre);
      st = -1;
      break;
    }
    snprintf(key, sizeof key, "%.*s", (int)(eq - set[i] - (long)lp),
             set[i] + lp);
    st = mrvi_settings_set_tuning(&s, key, atof(eq + 1), msg, sizeof msg);
  }
  if (st >= 0)
    st = mrvi_ocp_create(m, &s, &o, msg, sizeof msg);
  const int last = 4 * (links - 1); /* h_n's x (h_i, l_i in turn) */
  if (st >= 0 &&
      (mrvi_ocp_add_actuator(o, 0, MRVI_GRID_MACRO, 1.0, -HUGE_VAL, HUGE_VAL) <
           0 ||
       mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, last,
                             mrvi_model_q0(m)[last] + 0.05, 0.0) < 0)) {
    snprintf(msg, sizeof msg, "%s", mrvi_ocp_errmsg(o));
    st = -1;
  }
  double *u =
      st >= 0 ? calloc((size_t)mrvi_ocp_n_controls(o) + 1, sizeof *u) : NULL;
  if (!u) {
    snprintf(r.message, sizeof r.message, "%.199s",
             msg[0] ? msg : "out of memory");
    (void)!write(fd, &r, sizeof r);
    mrvi_ocp_free(o);
    mrvi_model_free(m);
    return;
  }
  r.n = mrvi_model_n(m);
  r.m = mrvi_model_constraint_rows(m);
  /* Trajectory kept for the adjoint: slow and fast nodes with their
   * momenta (and the fast micro momenta), the step multipliers. */
  r.traj_kb = 8.0 *
              ((CHAIN_N + 1.0) * 2 * mrvi_model_n_slow(m) +
               (CHAIN_N * CHAIN_P + 1.0) * 2 * mrvi_model_n_fast(m) +
               (double)CHAIN_N * r.m) /
              1024.0;
  measure(fd, o, u, &r);
  mrvi_model_free(m);
}

/* The table of parts 3 and 4: one child per size. */
static int size_table(const char *sizes, double budget, int chain) {
  int ns[16];
  const int k = bench_parse_ints(sizes, ns, 16);
  if (k < 1) {
    fputs("bench_ocp: --lattice and --chain take sizes such as 60,240,1012\n",
          stderr);
    return 1;
  }
  if (chain)
    printf("rod chain optimal control (midpoint-midpoint, p = %d, dT = 0.01, "
           "N = %d; n: coordinates), one process per size; %s\n",
           CHAIN_P, CHAIN_N, bench_build());
  else
    printf("lattice optimal control (midpoint-midpoint, p = 10, dT = 0.05, "
           "N = 20)%s, one process per size; %s\n",
           constrained ? ", constrained (last column fixed, rods between "
                         "slow-fast pairs of the top row)"
                       : "",
           bench_build());
  for (int i = 0; i < n_set; i++)
    printf("  --set %s\n", set[i]);
  printf("%6s %4s %4s %-13s %9s %9s %9s %7s %7s %9s %9s %9s %s\n", "n", "n_u",
         "rows", "path", "fwd [s]", "1st [s]", "c+g [s]", "1st/fwd", "c+g/fwd",
         "fwd [MB]", "c+g [MB]", "traj [MB]", "status");
  for (int i = 0; i < k; i++) {
    lattice_rec r;
    int wstatus = 0;
    const int got = bench_run_child(chain ? chain_child : lattice_child, &ns[i],
                                    &r, sizeof r, budget, 8.0, &wstatus);
    if (got == 0) {
      printf("%6d  did not finish within %.0f s CPU\n", ns[i], budget);
      continue;
    }
    printf("%6d %4d %4d %-13s %9.3g %9.3g %9.3g %7.2f %7.2f %9.1f %9.1f "
           "%9.1f %s\n",
           r.n, r.n_u, r.m, r.path, r.t_fwd, r.t_first, r.t_grad,
           r.t_first / r.t_fwd, r.t_grad / r.t_fwd, r.fwd_kb / 1024.0,
           r.grad_kb / 1024.0, r.traj_kb / 1024.0,
           r.ok ? "ok" : (r.message[0] ? r.message : "killed"));
    if (solve && r.ok && r.solve_status[0])
      printf("       solve: %d evaluations, %.1f s CPU, %s (%s), cost %.6g, "
             "violation %.2e, peak %.1f MB\n",
             r.solve_evals, r.solve_cpu, r.solve_status, r.solve_nlopt,
             r.solve_cost, r.solve_violation, r.solve_kb / 1024.0);
    else if (solve && r.ok)
      printf("       solve: did not finish within %.0f s CPU\n", budget);
    fflush(stdout);
  }
  return 0;
}

int main(int argc, char **argv) {
  double budget = 60.0;
  const char *only = NULL, *lattice = NULL, *chain = NULL;
  for (int i = 1; i < argc; i++) {
    if (!strcmp(argv[i], "--budget") && i + 1 < argc) {
      budget = atof(argv[++i]);
    } else if (!strcmp(argv[i], "--only") && i + 1 < argc) {
      only = argv[++i];
    } else if (!strcmp(argv[i], "--lattice") && i + 1 < argc) {
      lattice = argv[++i];
    } else if (!strcmp(argv[i], "--chain") && i + 1 < argc) {
      chain = argv[++i];
    } else if (!strcmp(argv[i], "--constrained")) {
      constrained = 1;
    } else if (!strcmp(argv[i], "--solve")) {
      solve = 1;
    } else if (!strcmp(argv[i], "--no-solve")) {
      no_solve = 1;
    } else if (!strcmp(argv[i], "--set") && i + 1 < argc && n_set < MAX_SET) {
      set[n_set++] = argv[++i];
    } else {
      fputs("usage: bench_ocp [--budget SECONDS] [--only PROBLEM] "
            "[--no-solve] "
            "[--lattice SIZES [--constrained] [--solve] "
            "[--set NAME=VALUE]...] [--chain LINKS [--solve] "
            "[--set integrator.tuning.NAME=VALUE]...]\n",
            stderr);
      return !!strcmp(argv[i], "--help");
    }
  }
  if (lattice || chain)
    return size_table(lattice ? lattice : chain, budget, !lattice);
  const char *root = getenv("MRVI_SOURCE_ROOT");
  /* The shipped problems (their scheme), and the FPU problem with the
   * schemes of the sweep and explicit paths. */
  enum { NP = 8 };
  const char *names[NP] = {"ocp_double_integrator",
                           "ocp_gantry_crane",
                           "ocp_fpu",
                           "ocp_fpu",
                           "ocp_fpu",
                           "ocp_reorient",
                           "ocp_winch",
                           "ocp_winch_free"};
  const char *scheme[NP] = {NULL, NULL, NULL, "explicit-slow", "fully-explicit",
                            NULL, NULL, NULL};
  char files[NP][1024];
  for (int i = 0; i < NP; i++) /* (ocp_winch*: bench/, a pair actuator) */
    snprintf(files[i], sizeof files[i], "%s/%s/%s.yaml", root ? root : ".",
             i >= 6 ? "bench" : "systems", names[i]);
  printf("# build: %s\n", bench_build());
  if (no_solve)
    printf("%-22s %-15s %4s %2s %5s %11s %8s %11s %8s %s\n", "problem",
           "scheme", "N", "p", "n_u", "c+g rest[ms]", "c+g/fwd", "c+g sin[ms]",
           "c+g/fwd", "path");
  else
    printf("%-22s %-15s %4s %2s %5s %5s %9s %8s %8s %9s %-8s %s\n", "problem",
           "scheme", "N", "p", "n_u", "evals", "eval [ms]", "eval/fwd",
           "at opt", "total [s]", "path", "status");
  const double T[NP] = {2.0, 2.0, 6.0, 6.0, 6.0, 5.0, 2.0, 2.0};
  const int Ns[3] = {20, 40, 80}, ps[2] = {1, 5};
  for (int f = 0; f < NP; f++)
    for (int in = 0; in < 3 && (!only || !strcmp(only, names[f])); in++)
      for (int ip = 0; ip < 2; ip++) {
        char a[64], b[64], c[64];
        snprintf(a, sizeof a, "integrator.macro_step=%.17g", T[f] / Ns[in]);
        snprintf(b, sizeof b, "integrator.micro_steps=%d", ps[ip]);
        snprintf(c, sizeof c, "integrator.scheme=%s",
                 scheme[f] ? scheme[f] : "midpoint-midpoint");
        const char *ov[3 + MAX_SET] = {a, b, c};
        for (int i = 0; i < n_set; i++)
          ov[3 + i] = set[i];
        row r;
        if (bench(files[f], ov, 3 + n_set, -1, &r) < 0)
          return 1;
        if (no_solve)
          printf("%-22s %-15s %4d %2d %5d %11.4f %8.2f %11.4f %8.2f %s\n",
                 names[f], scheme[f] ? scheme[f] : "midpoint-midpoint", Ns[in],
                 ps[ip], r.n_u, 1e3 * r.t_eval, r.ratio, 1e3 * r.total,
                 r.ratio_opt, r.path);
        else
          printf("%-22s %-15s %4d %2d %5d %5d %9.3f %8.2f %8.2f %9.3f %-8s "
                 "%s\n",
                 names[f], scheme[f] ? scheme[f] : "midpoint-midpoint", Ns[in],
                 ps[ip], r.n_u, r.evals, 1e3 * r.t_eval, r.ratio, r.ratio_opt,
                 r.total, r.path, r.ok ? "ok" : "FAILED");
        fflush(stdout);
      }
  if (only || no_solve)
    return 0;
  printf("\nlargest N (double integrator, p = 1, terminal tolerance 1e-8) "
         "solved within %.0f s:\n",
         budget);
  for (int alg = 0; alg < 4; alg++) {
    int best = 0;
    for (int N = 50; N <= 1 << 20; N *= 2) {
      char a[64];
      snprintf(a, sizeof a, "integrator.macro_step=%.17g", 2.0 / N);
      const char *ov[4] = {a, "integrator.micro_steps=1",
                           "control.solver.terminal_tolerance=1e-8",
                           "control.solver.tolerance=1e-10"};
      row r;
      if (bench(files[0], ov, 4, alg, &r) < 0)
        return 1;
      printf("  %-14s N = %7d: %5d evaluations, %8.3f s, %s path, %s\n",
             mrvi_ocp_algorithm_name((mrvi_ocp_algorithm)alg), N, r.evals,
             r.total, r.path, r.ok ? "ok" : "FAILED");
      fflush(stdout);
      if (!r.ok || r.total > budget)
        break;
      best = N;
      if (r.total > budget / 4) /* the next doubling would exceed it */
        break;
    }
    printf("  %-14s largest N = %d\n",
           mrvi_ocp_algorithm_name((mrvi_ocp_algorithm)alg), best);
  }
  return 0;
}
