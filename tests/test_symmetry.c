/* Symmetries and bonds of a model (src/model/symmetry.c, src/model/bonds.c):
 * which momentum components mrvi_model_conserved claims, checked against the
 * group action of every element kind and against runs (a claimed component
 * stays at its initial value to the Newton tolerance, a broken one moves by
 * the impulse of the force that breaks it), and which springs and rods
 * mrvi_model_edges lists. */
#include "models.h"
#include "testlib.h"
#include "util/util.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Law parameters by name. */
static void params(const char *law, double *par, const char *n1, double v1,
                   const char *n2, double v2, const char *n3, double v3) {
  const mrvi_law *l = mrvi_law_find(law);
  CHECK(l != NULL, "law %s registered", law);
  memset(par, 0, MRVI_LAW_MAX_PARAMS * sizeof *par);
  for (int i = 0; l && i < l->n_params; i++) {
    const char *p = l->param_names[i];
    par[i] = n1 && !strcmp(p, n1)   ? v1
             : n2 && !strcmp(p, n2) ? v2
             : n3 && !strcmp(p, n3) ? v3
                                    : par[i];
  }
}

/* Three particles in dimension d (slow a, fast b and c) on pair springs, an
 * angle at b and a rod a-c: invariant under every translation and
 * rotation. */
static mrvi_model *free_body(int d) {
  mrvi_model *m = mrvi_model_create();
  int ok = mrvi_model_set_dimension(m, d) == 0;
  const double xa[3] = {0.1, -0.2, 0.3}, va[3] = {0.4, 0.1, -0.2};
  const double xb[3] = {1.1, 0.2, -0.1}, vb[3] = {-0.3, 0.5, 0.2};
  const double xc[3] = {0.6, 1.0, 0.4}, vc[3] = {0.2, -0.6, 0.3};
  ok &= mrvi_model_add_particle(m, "a", 2.0, MRVI_SLOW, xa, va) == 0;
  ok &= mrvi_model_add_particle(m, "b", 0.5, MRVI_FAST, xb, vb) == 1;
  ok &= mrvi_model_add_particle(m, "c", 0.7, MRVI_FAST, xc, vc) == 2;
  double k[MRVI_LAW_MAX_PARAMS];
  params("linear", k, "stiffness", 3.0, NULL, 0, NULL, 0);
  ok &= mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "linear", k, 1.0) >= 0;
  params("linear", k, "stiffness", 40.0, NULL, 0, NULL, 0);
  ok &= mrvi_model_add_spring(m, MRVI_FAST, 1, 2, "linear", k, 0.9) >= 0;
  if (d >= 2)
    ok &= mrvi_model_add_angle(m, MRVI_SLOW, 0, 1, 2, 0.5, NAN) >= 0;
  ok &= mrvi_model_add_distance(m, 0, 2, NAN) >= 0;
  ok &= mrvi_model_project_velocities(m, NULL) == 0;
  CHECK(ok, "free body in %d-D builds: %s", d, mrvi_model_errmsg(m));
  return m;
}

/* Expected flags: lin (d entries), ang (3 in 3-D, 1 in 2-D). */
static void expect(const mrvi_model *m, const char *what, const int *lin,
                   const int *ang) {
  const int d = mrvi_model_dimension(m), na = d == 3 ? 3 : d == 2 ? 1 : 0;
  int l[3] = {-1, -1, -1}, a[3] = {-1, -1, -1};
  CHECK(mrvi_model_conserved(m, l, a) == 0, "%s: conserved returns 0", what);
  for (int i = 0; i < d; i++)
    CHECK(l[i] == lin[i], "%s: linear momentum %c conserved = %d, expected %d",
          what, "xyz"[i], l[i], lin[i]);
  for (int i = 0; i < na; i++)
    CHECK(a[i] == ang[i], "%s: angular momentum %s conserved = %d, expected %d",
          what,
          na == 1  ? "J"
          : i == 0 ? "J_x"
          : i == 1 ? "J_y"
                   : "J_z",
          a[i], ang[i]);
  CHECK(l[d < 3 ? d : 2] == (d < 3 ? -1 : l[2]) &&
            a[na < 3 ? na : 2] == (na < 3 ? -1 : a[2]),
        "%s: nothing written past dimension %d", what, d);
}

/* Element kinds one at a time on the free body (3-D), each against the
 * flags its group action gives. */
static void element_kinds(void) {
  const int all[3] = {1, 1, 1}, none[3] = {0, 0, 0};
  mrvi_model *m = free_body(3);
  expect(m, "springs, angle, rod between particles", all, all);
  mrvi_model_free(m);

  m = free_body(3);
  const double g[3] = {0, 0, -9.81};
  mrvi_model_set_gravity(m, g);
  expect(m, "gravity along -e3", (const int[]){1, 1, 0},
         (const int[]){0, 0, 1});
  mrvi_model_free(m);

  m = free_body(3);
  const double on_z[3] = {0, 0, 2}, on_x[3] = {1.5, 0, 0}, off[3] = {1, 1, 0};
  double k[MRVI_LAW_MAX_PARAMS];
  params("linear", k, "stiffness", 2.0, NULL, 0, NULL, 0);
  mrvi_model_add_anchor_spring(m, MRVI_SLOW, 0, on_z, "linear", k, 0.0);
  expect(m, "anchor on the z axis", none, (const int[]){0, 0, 1});
  mrvi_model_add_distance_anchor(m, 1, on_x, NAN);
  expect(m, "anchors on the z and x axes", none, none);
  mrvi_model_free(m);
  m = free_body(3);
  mrvi_model_add_distance_anchor(m, 1, off, NAN);
  expect(m, "rod to an anchor off every axis", none, none);
  mrvi_model_free(m);

  m = free_body(3);
  const double nz[3] = {0, 0, 1};
  mrvi_model_add_plane(m, 0, nz, NAN);
  expect(m, "plane z = const", (const int[]){1, 1, 0}, (const int[]){0, 0, 1});
  mrvi_model_free(m);
  m = free_body(3);
  const double nxy[3] = {1, 1, 0};
  mrvi_model_add_plane(m, 0, nxy, NAN);
  expect(m, "plane x + y = const", (const int[]){0, 0, 1}, none);
  mrvi_model_free(m);

  m = free_body(3);
  const int ax[3] = {1, 0, 0};
  mrvi_model_add_fixed(m, 2, ax, NULL);
  expect(m, "fixed x of one particle", (const int[]){0, 1, 1},
         (const int[]){1, 0, 0});
  mrvi_model_free(m);

  /* Forces: one along x breaks x translations; opposite forces on two
   * particles cancel for translations but not for rotations about y, z. */
  m = free_body(3);
  const int cx[1] = {0}; /* a.x */
  const double fx[1] = {1.5};
  mrvi_model_add_force(m, MRVI_SLOW, 1, cx, fx);
  expect(m, "force along x", (const int[]){0, 1, 1}, (const int[]){1, 0, 0});
  const int cx2[1] = {6}; /* c.x */
  const double fx2[1] = {-1.5};
  mrvi_model_add_force(m, MRVI_FAST, 1, cx2, fx2);
  expect(m, "opposite forces along x", all, (const int[]){1, 0, 0});
  mrvi_model_free(m);

  /* A term on particle coordinates: s = a.x - b.x is translation invariant
   * along x, not rotation invariant about y or z. */
  m = free_body(3);
  const int cc[2] = {0, 3};
  const double coef[2] = {1.0, -1.0};
  params("linear", k, "stiffness", 5.0, NULL, 0, NULL, 0);
  mrvi_model_add_term(m, MRVI_SLOW, 2, cc, coef, 0.0, "linear", k);
  expect(m, "term a.x - b.x", all, (const int[]){1, 0, 0});
  mrvi_model_free(m);
}

/* 2-D (rotations of the plane), 1-D (no rotations) and generalised
 * coordinates, which do not move under the group. */
static void dimensions(void) {
  mrvi_model *m = free_body(2);
  expect(m, "2-D springs", (const int[]){1, 1}, (const int[]){1});
  const double g[2] = {0, -9.81};
  mrvi_model_set_gravity(m, g);
  expect(m, "2-D gravity", (const int[]){1, 0}, (const int[]){0});
  mrvi_model_free(m);
  m = free_body(2);
  const double origin[2] = {0, 0};
  mrvi_model_add_distance_anchor(m, 0, origin, NAN);
  expect(m, "2-D rod to the origin", (const int[]){0, 0}, (const int[]){1});
  mrvi_model_free(m);

  m = free_body(1);
  expect(m, "1-D springs", (const int[]){1}, NULL);
  mrvi_model_free(m);

  /* A generalised coordinate with its own term: the particles' maps keep
   * their symmetry. */
  m = mrvi_model_create();
  mrvi_model_add_coordinate(m, "q", 1.0, MRVI_SLOW, 0.5, 0.0);
  mrvi_model_set_dimension(m, 2);
  const double x0[2] = {0, 0}, x1[2] = {1, 0}, v[2] = {0, 0.3};
  mrvi_model_add_particle(m, "a", 1.0, MRVI_SLOW, x0, v);
  mrvi_model_add_particle(m, "b", 1.0, MRVI_SLOW, x1, x0);
  double k[MRVI_LAW_MAX_PARAMS];
  params("linear", k, "stiffness", 1.0, NULL, 0, NULL, 0);
  const int qc[1] = {0};
  const double one[1] = {1.0};
  mrvi_model_add_term(m, MRVI_SLOW, 1, qc, one, 0.0, "linear", k);
  mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "linear", k, 1.0);
  expect(m, "term on a generalised coordinate", (const int[]){1, 1},
         (const int[]){1});
  mrvi_model_free(m);

  /* The paper's systems (arXiv 2406.12991 §6) and the cart pendulum, as
   * their description files say. */
  m = test_spring_ring();
  expect(m, "spring ring", (const int[]){0, 0, 0}, (const int[]){0, 0, 1});
  mrvi_model_free(m);
  m = test_cart_pendulum();
  expect(m, "cart pendulum", (const int[]){1, 1, 0}, (const int[]){0, 0, 1});
  mrvi_model_free(m);
  m = test_fpu();
  int l[3] = {-1, -1, -1}, a[3] = {-1, -1, -1};
  CHECK(mrvi_model_conserved(m, l, a) == 0 && l[0] == -1 && a[0] == -1,
        "no particles: nothing written");
  mrvi_model_free(m);
}

/* Momentum maps along a run: the claimed components stay at their initial
 * values to the Newton tolerance; gravity changes linear momentum by
 * exactly its impulse -M g t (a linear potential: the quadrature is exact). */
typedef struct track {
  double L0[3], J0[3], dL[3], dJ[3];
  double t;
} track;

static int observe(void *user, const mrvi_record *r) {
  track *tr = user;
  if (r->k == 0) {
    memcpy(tr->L0, r->linear_momentum, sizeof tr->L0);
    memcpy(tr->J0, r->angular_momentum, sizeof tr->J0);
  }
  for (int i = 0; i < 3; i++) {
    tr->dL[i] = r->linear_momentum[i] - tr->L0[i];
    tr->dJ[i] = fmax(fabs(tr->dJ[i]), fabs(r->angular_momentum[i] - tr->J0[i]));
  }
  tr->t = r->t;
  return 0;
}

static void runs(void) {
  mrvi_model *m = free_body(3);
  const double g[3] = {0, 0, -9.81};
  mrvi_model_set_gravity(m, g);
  mrvi_settings s = test_settings("midpoint-midpoint", 0.02, 4, 2.0, 1e-12);
  track tr = {{0}, {0}, {0}, {0}, 0};
  mrvi_summary sum;
  CHECK(mrvi_run(m, &s, observe, &tr, NULL, &sum) == 0, "run: %s", sum.message);
  int lin[3], ang[3];
  mrvi_model_conserved(m, lin, ang);
  const double mass = 2.0 + 0.5 + 0.7;
  for (int i = 0; i < 3; i++) {
    const double impulse = lin[i] ? 0.0 : -mass * 9.81 * tr.t;
    CHECK_NEAR(tr.dL[i], impulse, 1e-9,
               lin[i] ? "conserved L component" : "L_z changes by -M g t");
  }
  CHECK(ang[2] && tr.dJ[2] < 1e-9, "J_z conserved: drift %.2e", tr.dJ[2]);
  CHECK(!ang[0] && !ang[1] && tr.dJ[0] > 1e-2 && tr.dJ[1] > 1e-2,
        "J_x, J_y not claimed and they do change (%.2e, %.2e)", tr.dJ[0],
        tr.dJ[1]);
  mrvi_model_free(m);
}

/* Bonds: springs and rods between two particles, in order, with their
 * rate; anchors and pair laws are left out. */
static void edges(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 3);
  const double x[4][3] = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  const double v[3] = {0, 0, 0}, anchor[3] = {0, 0, 5};
  const char *names[4] = {"a", "b", "c", "d"};
  for (int i = 0; i < 4; i++)
    mrvi_model_add_particle(m, names[i], 1.0, i < 2 ? MRVI_SLOW : MRVI_FAST,
                            x[i], v);
  double k[MRVI_LAW_MAX_PARAMS], lj[MRVI_LAW_MAX_PARAMS],
      inv[MRVI_LAW_MAX_PARAMS];
  params("linear", k, "stiffness", 1.0, NULL, 0, NULL, 0);
  params("lennard-jones", lj, "epsilon", 1.0, "sigma", 0.5, "cutoff", 2.0);
  params("inverse", inv, "constant", -1.0, NULL, 0, NULL, 0);
  int ok = mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "linear", k, 1.0) >= 0;
  ok &= mrvi_model_add_anchor_spring(m, MRVI_SLOW, 0, anchor, "linear", k,
                                     0.0) >= 0;
  ok &= mrvi_model_add_spring(m, MRVI_FAST, 2, 3, "linear", k, 1.0) >= 0;
  ok &=
      mrvi_model_add_spring(m, MRVI_SLOW, 0, 2, "lennard-jones", lj, 0.0) >= 0;
  ok &= mrvi_model_add_spring(m, MRVI_SLOW, 1, 3, "inverse", inv, 0.0) >= 0;
  ok &= mrvi_model_add_distance(m, 1, 2, NAN) >= 0;
  ok &= mrvi_model_add_distance_anchor(m, 3, anchor, NAN) >= 0;
  CHECK(ok, "bond model builds: %s", mrvi_model_errmsg(m));
  CHECK(mrvi_model_edges(m, NULL, NULL, 0) == 3, "3 edges counted");
  int pairs[6] = {-1, -1, -1, -1, -1, -1}, kind[3] = {-1, -1, -1};
  CHECK(mrvi_model_edges(m, pairs, kind, 3) == 3, "3 edges written");
  const int want_pairs[6] = {0, 1, 2, 3, 1, 2}, want_kind[3] = {0, 1, 2};
  CHECK(!memcmp(pairs, want_pairs, sizeof pairs) &&
            !memcmp(kind, want_kind, sizeof kind),
        "edges a-b slow, c-d fast, b-c rod: got %d-%d:%d %d-%d:%d %d-%d:%d",
        pairs[0], pairs[1], kind[0], pairs[2], pairs[3], kind[1], pairs[4],
        pairs[5], kind[2]);
  int one[2] = {-1, -1}, k1 = -1;
  CHECK(mrvi_model_edges(m, one, &k1, 1) == 3 && one[0] == 0 && one[1] == 1 &&
            k1 == 0,
        "cap 1: the first edge written, all counted");
  mrvi_model_free(m);
}

int main(void) {
  element_kinds();
  dimensions();
  runs();
  edges();
  return test_finish();
}
