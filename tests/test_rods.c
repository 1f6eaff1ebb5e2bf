/* The link-local null space of particles on rods (solver/nullspace_rods.c,
 * doc/constraints.md "Particles on rods: the link-local basis"): which
 * models take it, the size of its system, and its trajectories against the
 * numerical (QR) basis and the multiplier form; beyond the QR basis's 256
 * coordinates of one rate, against the multiplier form alone. */
#include "models.h"
#include "solver/solver.h"
#include "testlib.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

/* A tree of n slow particles (mass 1 + 0.1 i) on rods in D dimensions:
 * h0 on a rod to an anchor, h_i to h_{i-1}, except that h_{n/2} hangs from
 * h1 (a branch); two more slow particles joined by a rod alone (a free
 * root); a fast light particle (0.05) on a slow spring to each of h0 ..
 * h3 and to the free pair's first, the light ones in a row of fast
 * springs; gravity.  loop: one more rod, h_{n-1} to h_{n/2} (a closed
 * loop); fast_rod: one more rod between two light particles. */
static mrvi_model *rod_tree(int D, int n, int loop, int fast_rod) {
  mrvi_model *m = mrvi_model_create();
  int st = mrvi_model_set_dimension(m, D);
  int h[1024], l[8], nl = 0;
  const double zero[3] = {0, 0, 0};
  for (int i = 0; i < n && st >= 0; i++) {
    const int par = i == n / 2 ? 1 : i - 1;
    double x[3] = {0, 0, 0}, v[3] = {0, 0, 0}, xp[3] = {0, 0, 0};
    for (int c = 0; c < D && i > 0; c++) /* (q0 moves as particles come) */
      xp[c] = mrvi_model_q0(m)[D * par + c];
    /* one apart from the parent, turning with i */
    const double a = 0.3 + 0.7 * sin(1.3 * i) + (i == n / 2 ? 1.2 : 0.0);
    x[0] = xp[0] + cos(a) * (D == 3 ? cos(0.4 * i) : 1.0);
    x[1] = xp[1] - sin(a);
    if (D == 3)
      x[2] = xp[2] + cos(a) * sin(0.4 * i);
    v[0] = 0.2 * cos(0.7 * i), v[D - 1] = 0.1 * sin(0.5 * i);
    char name[16];
    snprintf(name, sizeof name, "h%d", i);
    h[i] = st =
        mrvi_model_add_particle(m, name, 1.0 + 0.1 * i, MRVI_SLOW, x, v);
    if (st < 0)
      break;
    /* the rod's length: the initial distance, whatever v does */
    double L = 0.0;
    for (int c = 0; c < D; c++)
      L += (x[c] - xp[c]) * (x[c] - xp[c]);
    st = i == 0 ? mrvi_model_add_distance_anchor(m, h[i], zero, sqrt(L))
                : mrvi_model_add_distance(m, h[par], h[i], sqrt(L));
  }
  const int nh = n;
  for (int i = 0; i < 2 && st >= 0; i++) { /* the free pair */
    const double x[3] = {3.0 + 0.6 * i, 0.5, 0.2 * i},
                 v[3] = {0.1, -0.3 * i, 0};
    h[nh + i] = st =
        mrvi_model_add_particle(m, i ? "f1" : "f0", 0.7, MRVI_SLOW, x, v);
  }
  if (st >= 0)
    st = mrvi_model_add_distance(m, h[nh], h[nh + 1], NAN);
  const int att[5] = {h[0], h[1], h[2], h[3], h[nh]};
  for (int j = 0; j < 5 && st >= 0; j++) {
    const double *xa = mrvi_model_q0(m) + D * att[j];
    double x[3] = {xa[0], xa[1] - 0.1, D == 3 ? xa[2] : 0.0};
    const double v[3] = {0.05 * j, 0, 0}, k[1] = {400.0};
    char name[16];
    snprintf(name, sizeof name, "l%d", j);
    l[nl] = st = mrvi_model_add_particle(m, name, 0.05, MRVI_FAST, x, v);
    if (st < 0)
      break;
    st = mrvi_model_add_spring(m, MRVI_SLOW, att[j], l[nl], "linear", k, 0.1);
    if (st >= 0 && nl > 0) {
      double r = 0.0;
      const double *xb = mrvi_model_q0(m) + D * l[nl - 1];
      for (int c = 0; c < D; c++)
        r += (x[c] - xb[c]) * (x[c] - xb[c]);
      st = mrvi_model_add_spring(m, MRVI_FAST, l[nl - 1], l[nl], "linear", k,
                                 sqrt(r));
    }
    nl++;
  }
  if (st >= 0 && loop)
    st = mrvi_model_add_distance(m, h[n - 1], h[n / 2], NAN);
  if (st >= 0 && fast_rod)
    st = mrvi_model_add_distance(m, l[0], l[1], NAN);
  const double g[3] = {0.0, -9.81, 0.0};
  if (st >= 0)
    st = mrvi_model_set_gravity(m, g);
  CHECK(st >= 0, "rod tree (%d-D, %d): %s", D, n, mrvi_model_errmsg(m));
  return m;
}

/* Forms: 0 the link-local basis, 1 the QR basis, 2 multipliers. */
static mrvi_settings form(int f, const char *scheme, int p, double t_end,
                          double tol) {
  mrvi_settings s = test_settings(scheme, 0.01, p, t_end, tol);
  s.constraint_tol = tol;
  s.constraint_form = f == 2 ? MRVI_FORM_MULTIPLIERS : MRVI_FORM_NULL_SPACE;
  s.tuning.nullspace_tree = f == 0;
  s.solver = MRVI_SOLVER_GENERAL;
  return s;
}

/* The step's system size, or -1 and msg. */
static int system_size(const mrvi_model *m, int f, char *msg, size_t len) {
  mrvi_settings s = form(f, "midpoint-midpoint", 2, 1.0, 1e-10);
  mrvi_integrator *it = NULL;
  if (mrvi_integrator_create(m, &s, &it, msg, len) < 0)
    return -1;
  const int n = mrvi_integrator_system_size(it);
  mrvi_integrator_free(it);
  return n;
}

static void test_plan(void) {
  char why[200];
  for (int D = 2; D <= 3; D++) {
    mrvi_model *m = rod_tree(D, 6, 0, 0);
    CHECK(mrvi_nullspace_rods_plan(m, why, sizeof why) == 1 && !why[0],
          "rod tree (%d-D) takes the link-local basis: %s", D, why);
    mrvi_model_free(m);
  }
  mrvi_model *m = rod_tree(2, 6, 1, 0);
  CHECK(!mrvi_nullspace_rods_plan(m, why, sizeof why) &&
            strstr(why, "closes a loop") && strstr(why, "h5"),
        "a loop of rods keeps the numerical basis: %s", why);
  mrvi_model_free(m);
  m = rod_tree(2, 6, 0, 1);
  CHECK(!mrvi_nullspace_rods_plan(m, why, sizeof why) &&
            strstr(why, "not between slow particles"),
        "a fast rod keeps the numerical basis: %s", why);
  mrvi_model_free(m);
}

/* 100 steps at Newton and constraint tolerances 1e-12: the link-local
 * basis against the QR basis and the multiplier form. */
static void test_trajectories(void) {
  static const char *const schemes[2] = {"midpoint-midpoint",
                                         "trapezoidal-midpoint"};
  const int ps[2] = {1, 5};
  for (int D = 2; D <= 3; D++) {
    mrvi_model *m = rod_tree(D, D == 2 ? 9 : 7, 0, 0);
    char msg[512];
    const int n0 = system_size(m, 0, msg, sizeof msg);
    const int n1 = system_size(m, 1, msg, sizeof msg);
    const int rods = mrvi_model_n_constraints(m);
    CHECK(n1 > 0 && n0 == n1 + rods,
          "%d-D: system %d (link-local) against %d (QR) + %d rods", D, n0, n1,
          rods);
    for (int a = 0; a < 2; a++)
      for (int b = 0; b < 2; b++) {
        mrvi_trajectory *tr[3] = {NULL, NULL, NULL};
        for (int f = 0; f < 3; f++) {
          mrvi_settings s = form(f, schemes[a], ps[b], 1.0, 1e-12);
          mrvi_summary sum;
          if (mrvi_trajectory_run(m, &s, &tr[f], &sum) != 0)
            CHECK(0, "%d-D %s p=%d form %d: %s", D, schemes[a], ps[b], f,
                  sum.message);
        }
        double d[2] = {0.0, 0.0}, moved = 0.0;
        if (tr[0] && tr[1] && tr[2])
          for (long i = 0; i < tr[0]->n_macro * tr[0]->n; i++) {
            d[0] = fmax(d[0], fabs(tr[0]->q[i] - tr[1]->q[i]));
            d[1] = fmax(d[1], fabs(tr[0]->q[i] - tr[2]->q[i]));
            moved = fmax(moved, fabs(tr[0]->q[i] - tr[0]->q[i % tr[0]->n]));
          }
        printf("%d-D %s p=%d, 100 steps at 1e-12: link-local against QR "
               "%.3g, against multipliers %.3g (the chain moved %.3g)\n",
               D, schemes[a], ps[b], d[0], d[1], moved);
        CHECK(tr[0] && tr[0]->n_macro == 101 && d[0] < 1e-10 && d[1] < 1e-10 &&
                  moved > 0.1,
              "%d-D %s p=%d: link-local against QR %.3g, multipliers %.3g, "
              "moved %.3g",
              D, schemes[a], ps[b], d[0], d[1], moved);
        for (int f = 0; f < 3; f++)
          mrvi_trajectory_free(tr[f]);
      }
    mrvi_model_free(m);
  }
}

/* A chain of 200 rods (400 slow coordinates): the QR basis refuses it
 * (more than 256 constrained coordinates of one rate), the link-local
 * basis runs it, with the multiplier form's trajectory. */
static void test_long_chain(void) {
  mrvi_model *m = rod_tree(2, 198, 0, 0);
  char msg[512];
  const int nq = system_size(m, 1, msg, sizeof msg);
  CHECK(nq < 0 && strstr(msg, "more than 256"),
        "200 rods: the QR basis refuses (%d): %s", nq, msg);
  mrvi_trajectory *tr[2] = {NULL, NULL};
  for (int f = 0; f < 2; f++) {
    mrvi_settings s = form(2 * f, "midpoint-midpoint", 5, 0.1, 1e-12);
    mrvi_summary sum;
    if (mrvi_trajectory_run(m, &s, &tr[f], &sum) != 0)
      CHECK(0, "200 rods, form %d: %s", 2 * f, sum.message);
  }
  double d = 0.0;
  if (tr[0] && tr[1])
    for (long i = 0; i < tr[0]->n_macro * tr[0]->n; i++)
      d = fmax(d, fabs(tr[0]->q[i] - tr[1]->q[i]));
  printf("200 rods, 10 steps at 1e-12: link-local against multipliers %.3g\n",
         d);
  CHECK(tr[0] && tr[0]->n_macro == 11 && d < 1e-10,
        "200 rods: link-local against multipliers %.3g", d);
  for (int f = 0; f < 2; f++)
    mrvi_trajectory_free(tr[f]);
  mrvi_model_free(m);
}

int main(void) {
  test_plan();
  test_trajectories();
  test_long_chain();
  return test_finish();
}
