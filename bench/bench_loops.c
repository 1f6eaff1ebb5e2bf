/* Closed loops: cost per macro step of a ring of n rigid bars against n,
 * by constraint form and null-space basis (doc/performance/chains.md, "Closed
 * loops: the joint-reduced null space with cut joints").
 *
 * The ring: n uniform bars (2-D bodies, length 1, mass 1, slow) along a
 * regular n-gon of side 1 whose top vertex is at the origin, bar i from
 * vertex i to vertex i + 1 (counter-clockwise), revolute joints between
 * consecutive bars at their common vertices, bar 0 on a revolute joint to
 * the ground at the origin, and the joint between bar n - 1 and bar 0 at
 * the origin closing the loop (n - 2 degrees of freedom); gravity (0,
 * -9.81).  Released at rest, the polygon sags.  Cases:
 *   multipliers      the multiplier form on the path mrvi_solver_path picks,
 *   loop-reduced     the null-space form with the joint-reduced basis of the
 *                    spanning tree, the closing joint cut (nullspace_tree.c),
 *   QR               the null-space form with the numerical basis (tuning
 *                    nullspace_tree 0; refused above 256 constrained
 *                    coordinates of one rate, n > 42),
 *   open, QR         the ring without its closing joint (an open chain) in
 *   open, Gram       the null-space form with the joint-reduced basis: what
 *                    the cut joint adds; with --fast, the fast multipliers
 *                    and slow coupling by the QR of G_f (nullspace_gram_min
 *                    257; refused above 256) or the Gram matrix G_f G_f^T
 *                    (nullspace_gram_min 0).
 * --ladder: instead a ladder of n four-bars (n loops): two rails of n bars
 * each (length 1, slanted by 0.3 to the side) hung from the ground at (0,
 * 0) and (1, 0), the rungs (length 1, horizontal) joining the rails' lower
 * ends, every bar on revolute joints at the nodes (3n bars, 4n joints, n
 * degrees of freedom); its open twin, "open, QR/Gram", has no rungs.  The
 * cut joints' paths to the ground grow with the depth of the ladder, so
 * C = G_c P_tree has O(n^2) entries there.
 * --fast: every bar fast and p = 5, the joints enforced at the 5 micro
 * nodes of a step; loop-reduced is then the cut basis of the fast forest
 * at every micro node (doc/multibody.md, "Fast closed loops"), QR the
 * numerical basis at every micro node.
 * midpoint-midpoint, dT = 0.01, p = 1, Newton tolerance 1e-10.  The cases
 * of one n alternate, --repeats rounds, best of them; each times blocks of
 * 20 macro steps from the initial state (the integrator set back to it)
 * until --steps steps and 0.3 s.  Then the exponent of the time per macro
 * step in n.  A measurement: no thresholds. */
#include "bench_util.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

enum { MAX_N = 16, MAX_REPEATS = 9, N_CASES = 5, HORIZON = 20 };
#define MIN_CPU 0.3

static const char *const case_names[N_CASES] = {"multipliers", "loop-reduced",
                                                "QR", "open, QR", "open, Gram"};

static const char usage[] =
    "usage: bench_loops [--quick] [--ladder] [--fast] [--n 10,30,100]\n"
    "                   [--repeats R] [--steps K]\n"
    "Cost per macro step of a ring of n rigid bars on revolute joints (a\n"
    "closed loop; --ladder: a ladder of n four-bars, n loops) against n:\n"
    "multiplier form, null-space form with the joint-reduced basis (the\n"
    "closing joints cut) and with the numerical (QR) basis, and the open\n"
    "twin (no closing joints) with the joint-reduced basis; CPU seconds per\n"
    "macro step, best of R rounds.  --fast: every bar fast, p = 5 (the\n"
    "joints enforced at the micro nodes).\n";

static int bad_usage(void) {
  fputs(usage, stderr);
  return 2;
}

static int fast; /* --fast */

/* Bar from P to Q (2-D, length |Q - P|, mass 1) as body `name` (fast with
 * --fast). */
static int add_bar(mrvi_model *m, const char *name, const double *P,
                   const double *Q) {
  const double dx = Q[0] - P[0], dy = Q[1] - P[1], l = hypot(dx, dy);
  const double x[2] = {0.5 * (P[0] + Q[0]), 0.5 * (P[1] + Q[1])};
  const double R[4] = {dx / l, -dy / l, dy / l, dx / l}, J[1] = {l * l / 12.0};
  return mrvi_model_add_body(m, name, 2, fast ? MRVI_FAST : MRVI_SLOW, 1.0, J,
                             x, R, NULL, NULL);
}

/* The ladder of n four-bars (closed: with its rungs). */
static mrvi_model *ladder_model(int n, int closed, char *msg, size_t len) {
  mrvi_model *m = mrvi_model_create();
  const double g[2] = {0.0, -9.81}, s = 0.3;
  int st = m ? mrvi_model_set_dimension(m, 2) : MRVI_ENOMEM;
  int prev[2] = {-1, -1};
  for (int j = 0; j < n && st >= 0; j++) {
    int rail[2] = {-1, -1};
    for (int side = 0; side < 2 && st >= 0; side++) {
      const double P[2] = {side + s * j, -j},
                   Q[2] = {side + s * (j + 1), -(j + 1)};
      char name[32];
      snprintf(name, sizeof name, "%c%d", side ? 'r' : 'l', j);
      rail[side] = st = add_bar(m, name, P, Q);
      if (st >= 0)
        st = mrvi_model_add_joint(m, "revolute", rail[side], prev[side], P,
                                  NULL);
    }
    if (st >= 0 && closed) { /* the rung at the rails' lower ends */
      const double P[2] = {s * (j + 1), -(j + 1)},
                   Q[2] = {1 + s * (j + 1), -(j + 1)};
      char name[32];
      snprintf(name, sizeof name, "rung%d", j);
      const int r = st = add_bar(m, name, P, Q);
      if (st >= 0)
        st = mrvi_model_add_joint(m, "revolute", r, rail[0], P, NULL);
      if (st >= 0)
        st = mrvi_model_add_joint(m, "revolute", r, rail[1], Q, NULL);
    }
    prev[0] = rail[0], prev[1] = rail[1];
  }
  return bench_model_finish(m, st, g, msg, len);
}

static int ladder; /* --ladder */

/* The ring of n bars (closed: with its closing joint). */
static mrvi_model *ring_model(int n, int closed, char *msg, size_t len) {
  mrvi_model *m = mrvi_model_create();
  const double g[2] = {0.0, -9.81}, pi = acos(-1.0);
  const double rad = 0.5 / sin(pi / n); /* circumradius of side 1 */
  double v[2][2];
  int st = m ? mrvi_model_set_dimension(m, 2) : MRVI_ENOMEM;
  int prev = -1, first = -1;
  for (int i = 0; i < n && st >= 0; i++) {
    for (int k = 0; k < 2; k++) { /* vertices i, i + 1; vertex 0 at 0 */
      const double a = pi / 2 + 2.0 * pi * (i + k) / n;
      v[k][0] = rad * cos(a);
      v[k][1] = rad * (sin(a) - 1.0);
    }
    const double dx = v[1][0] - v[0][0], dy = v[1][1] - v[0][1];
    const double x[2] = {0.5 * (v[0][0] + v[1][0]), 0.5 * (v[0][1] + v[1][1])};
    const double R[4] = {dx, -dy, dy, dx}, J[1] = {1.0 / 12.0};
    char name[32];
    snprintf(name, sizeof name, "b%d", i);
    const int b = st =
        mrvi_model_add_body(m, name, 2, MRVI_SLOW, 1.0, J, x, R, NULL, NULL);
    if (st >= 0)
      st = mrvi_model_add_joint(m, "revolute", b, prev, v[0], NULL);
    if (i == 0)
      first = b;
    prev = b;
  }
  if (st >= 0 && closed) /* the closing joint at the origin */
    st = mrvi_model_add_joint(m, "revolute", prev, first, v[1], NULL);
  return bench_model_finish(m, st, g, msg, len);
}

typedef struct result {
  int status; /* 0 ok, 1 failed */
  int size;   /* the step's system */
  int n;      /* coordinates */
  double step, newton;
  char path[16];
  char message[200];
} result;

static result run_one(int cs, int links, int steps) {
  result r;
  memset(&r, 0, sizeof r);
  r.status = 1;
  char msg[512];
  const int open = cs >= 3;
  mrvi_model *m = ladder ? ladder_model(links, !open, msg, sizeof msg)
                         : ring_model(links, !open, msg, sizeof msg);
  if (!m) {
    snprintf(r.message, sizeof r.message, "%.190s", msg);
    return r;
  }
  mrvi_settings s;
  mrvi_settings_default(&s);
  mrvi_settings_set_scheme(&s, "midpoint-midpoint");
  s.macro_step = 0.01;
  s.micro_steps = fast ? 5 : 1;
  s.t_end = 1e4;
  s.newton_tol = 1e-10;
  s.energy_warning = 0;
  s.constraint_form = cs ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
  s.tuning.nullspace_tree = cs != 2;
  /* the open model's fast multipliers: by the QR of G_f (up to its 256
   * coordinates) or the Gram matrix */
  if (open)
    s.tuning.nullspace_gram_min = cs == 3 ? 257 : 0;
  mrvi_integrator *it = NULL;
  if (mrvi_integrator_create(m, &s, &it, msg, sizeof msg) < 0) {
    snprintf(r.message, sizeof r.message, "%.190s", msg);
    mrvi_model_free(m);
    return r;
  }
  r.size = mrvi_integrator_system_size(it);
  r.n = mrvi_model_n(m);
  if (bench_time_steps(it, m, steps, MIN_CPU, HORIZON, &r.step, &r.newton,
                       r.message, sizeof r.message) == 0)
    r.status = 0; /* (from rest: the bodies' v0 are 0) */
  snprintf(r.path, sizeof r.path, "%s", mrvi_integrator_solver_path(it));
  mrvi_integrator_free(it);
  mrvi_model_free(m);
  return r;
}

int main(int argc, char **argv) {
  int n_list[MAX_N] = {10, 30, 100, 300}, n_n = 4, repeats = 3, steps = 20;
  for (int i = 1; i < argc; i++) {
    const char *a = argv[i];
    const int has = i + 1 < argc;
    if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
      fputs(usage, stdout);
      return 0;
    } else if (!strcmp(a, "--ladder")) {
      ladder = 1;
    } else if (!strcmp(a, "--fast")) {
      fast = 1;
    } else if (!strcmp(a, "--quick")) {
      n_n = 2, repeats = 1;
    } else if (!strcmp(a, "--n") && has) {
      if ((n_n = bench_parse_ints(argv[++i], n_list, MAX_N)) <= 0)
        return bad_usage();
    } else if (bench_repeats_steps(argc, argv, &i, MAX_REPEATS, &repeats,
                                   &steps) <= 0) {
      return bad_usage();
    }
  }
  printf("# bench_loops: %s%s, midpoint-midpoint, dT = 0.01, p = %d; CPU s "
         "per macro step, best of %d; load %.2f; %s\n",
         ladder ? "a ladder of n four-bars (2-D, n loops)"
                : "a ring of n rigid bars on revolute joints (2-D, one closed "
                  "loop)",
         fast ? ", every bar fast (its joints at the micro nodes)" : "",
         fast ? 5 : 1, repeats, bench_load(), bench_build());
  printf("%6s %6s  %-14s %8s %-16s %12s %8s\n", "links", "coords", "case",
         "system", "path", "s/step", "updates");
  double xs[N_CASES][MAX_N], ys[N_CASES][MAX_N];
  int got[N_CASES] = {0};
  for (int ni = 0; ni < n_n; ni++) {
    result best[N_CASES];
    for (int c = 0; c < N_CASES; c++)
      best[c].status = -1;
    for (int rep = 0; rep < repeats; rep++)
      for (int c = 0; c < N_CASES; c++) {
        if (rep > 0 && best[c].status != 0)
          continue;
        const result r = run_one(c, n_list[ni], steps);
        if (best[c].status != 0 || (r.status == 0 && r.step < best[c].step))
          best[c] = r;
      }
    for (int c = 0; c < N_CASES; c++) {
      const result *r = &best[c];
      if (r->status == 0) {
        printf("%6d %6d  %-14s %8d %-16s %12.3e %8.2f\n", n_list[ni], r->n,
               case_names[c], r->size, r->path, r->step, r->newton);
        xs[c][got[c]] = n_list[ni];
        ys[c][got[c]++] = r->step;
      } else {
        printf("%6d %6s  %-14s refused: %s\n", n_list[ni], "", case_names[c],
               r->message);
      }
    }
    fflush(stdout);
  }
  for (int c = 0; c < N_CASES; c++)
    if (got[c] >= 2)
      printf("# %s: time per step ~ n^%.2f\n", case_names[c],
             bench_exponent(xs[c], ys[c], got[c]));
  return 0;
}
