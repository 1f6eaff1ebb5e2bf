/* Torsional springs on revolute joints and the multibody systems built on
 * them (doc/multibody.md, "Torsional springs"): the element's gradient and
 * Hessian against central differences (2-D and 3-D, two bodies and a body
 * with the ground, several laws, on a far branch); a body spinning through
 * +-pi many times on a soft torsional spring keeps a continuous potential
 * and a bounded energy, and follows the harmonic oscillator; both
 * constraint forms agree on systems/flexible_pendulum.yaml and
 * systems/spacecraft.yaml (p = 1 and 5), whose orders are fitted from runs
 * and whose momenta are conserved where the symmetry holds. */
#include "integrator/integrator.h"
#include "io/io.h"
#include "model/model.h"
#include "models.h"
#include "testlib.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* Two bodies a, b (dimension D) with torsional springs between them (law
 * `law`) and from a to the ground (linear). */
static mrvi_model *sprung_pair(int D, const char *law, const double *par) {
  mrvi_model *m = mrvi_model_create();
  const double J3[3] = {1.0, 2.0, 2.5}, K3[3] = {1.5, 1.0, 2.0}, J2 = 0.7,
               K2 = 0.4, xa[3] = {0, 0, 0}, xb[3] = {1, 0.5, 0.3},
               wa[3] = {0.3, -0.2, 0.5}, wb[3] = {0.1, 0.4, -0.6},
               axis[3] = {0.3, -0.5, 0.8}, k = 2.0;
  double Ra[9], Rb[9];
  test_rotation(wa, 1.0, Ra), test_rotation(wb, 1.0, Rb);
  const double R2a[4] = {cos(0.3), -sin(0.3), sin(0.3), cos(0.3)},
               R2b[4] = {cos(-1.1), -sin(-1.1), sin(-1.1), cos(-1.1)};
  mrvi_model_set_dimension(m, D);
  int st = mrvi_model_add_body(m, "a", D, MRVI_SLOW, 1.0, D == 3 ? J3 : &J2, xa,
                               D == 3 ? Ra : R2a, NULL, NULL);
  st |= mrvi_model_add_body(m, "b", D, MRVI_SLOW, 2.0, D == 3 ? K3 : &K2, xb,
                            D == 3 ? Rb : R2b, NULL, NULL);
  CHECK(st == 1 &&
            mrvi_model_add_torsion(m, MRVI_SLOW, 0, 1, D == 3 ? axis : NULL,
                                   law, par, 0.4) >= 0 &&
            mrvi_model_add_torsion(m, MRVI_SLOW, 1, -1, D == 3 ? axis : NULL,
                                   "linear", &k, -0.2) >= 0,
        "torsional springs %d-D (%s): %s", D, law, mrvi_model_errmsg(m));
  return m;
}

/* Gradient and Hessian of V against central differences at q (off the
 * constraint manifold: the energy is defined on R^n). */
static void fd_check(const mrvi_model *m, const double *q0, const char *what) {
  const int n = mrvi_model_n(m);
  double *q = malloc((size_t)n * sizeof *q), *g = calloc((size_t)n, sizeof *g),
         *H = calloc((size_t)n * n, sizeof *H),
         *gp = malloc((size_t)n * sizeof *gp),
         *gm = malloc((size_t)n * sizeof *gm);
  memcpy(q, q0, (size_t)n * sizeof *q);
  mrvi_model_potential(m, MRVI_SLOW, q, g, H);
  const double h = 1e-5;
  double eg = 0.0, eh = 0.0, scale = 0.0, hscale = 0.0;
  for (int i = 0; i < n; i++) {
    const double qi = q[i];
    memset(gp, 0, (size_t)n * sizeof *gp);
    memset(gm, 0, (size_t)n * sizeof *gm);
    q[i] = qi + h;
    const double Vp = mrvi_model_potential(m, MRVI_SLOW, q, gp, NULL);
    q[i] = qi - h;
    const double Vm = mrvi_model_potential(m, MRVI_SLOW, q, gm, NULL);
    q[i] = qi;
    eg = fmax(eg, fabs((Vp - Vm) / (2 * h) - g[i]));
    scale = fmax(scale, fabs(g[i]));
    for (int j = 0; j < n; j++) {
      eh = fmax(eh, fabs((gp[j] - gm[j]) / (2 * h) - H[i * n + j]));
      hscale = fmax(hscale, fabs(H[i * n + j]));
    }
  }
  printf("%s: gradient vs central differences %.3g (max |grad| %.3g), "
         "Hessian %.3g (max |H| %.3g)\n",
         what, eg, scale, eh, hscale);
  CHECK(scale > 0.1 && eg < 1e-8 * fmax(1.0, scale) &&
            eh < 1e-6 * fmax(1.0, hscale),
        "%s: gradient %.3g, Hessian %.3g", what, eg, eh);
  free(q), free(g), free(H), free(gp), free(gm);
}

static void test_derivatives(void) {
  const double lin = 3.0, morse[3] = {2.0, 1.5, 0.1}, pw[2] = {0.7, 4.0};
  const struct {
    const char *law;
    const double *par;
  } laws[] = {{"linear", &lin}, {"morse", morse}, {"power", pw}};
  for (int D = 2; D <= 3; D++)
    for (size_t l = 0; l < sizeof laws / sizeof laws[0]; l++) {
      mrvi_model *m = sprung_pair(D, laws[l].law, laws[l].par);
      const int n = mrvi_model_n(m);
      double *q = malloc((size_t)n * sizeof *q);
      for (int i = 0; i < n; i++)
        q[i] = mrvi_model_q0(m)[i] + 0.05 * sin(1.7 * i + 0.3);
      char what[96];
      mrvi_fmt(what, sizeof what, "torsion %d-D, %s", D, laws[l].law);
      fd_check(m, q, what);
      /* On the branch three turns on (the spring wound up), the same
       * derivatives, and the energy of the angle 6 pi further. */
      const int nt = mrvi_model_n_torsions(m);
      double ref[2], V0 = mrvi_model_potential(m, MRVI_SLOW, q, NULL, NULL);
      mrvi_model_torsion_init(m, q, ref);
      const double th = ref[0];
      ref[0] += 6 * M_PI;
      mrvi_model_torsion_set(m, ref);
      mrvi_fmt(what, sizeof what, "torsion %d-D, %s, 3 turns", D, laws[l].law);
      fd_check(m, q, what);
      double V3 = mrvi_model_potential(m, MRVI_SLOW, q, NULL, NULL), phi, d1,
             d2;
      const mrvi_law *law = mrvi_law_find(laws[l].law);
      double lp[MRVI_LAW_MAX_PARAMS];
      memcpy(lp, laws[l].par, (size_t)law->n_params * sizeof *lp);
      double p0, p3;
      law->eval(lp, th - 0.4, &p0, &d1, &d2);
      law->eval(lp, th + 6 * M_PI - 0.4, &p3, &d1, &d2);
      (void)phi;
      CHECK(nt == 2 && fabs((V3 - V0) - (p3 - p0)) < 1e-9 * fmax(1, fabs(p3)),
            "%s: V moves by phi(theta + 6 pi) - phi(theta): %.17g vs %.17g",
            what, V3 - V0, p3 - p0);
      free(q);
      mrvi_model_free(m);
    }
}

/* ---------------------------------------------------------------------------
 * A body on a revolute joint through its centre of mass with a soft
 * torsional spring k/2 theta^2, set spinning at omega0: the harmonic
 * oscillator J theta'' = -k theta with amplitude omega0 sqrt(J/k), here
 * about 3.2 turns each way.  The angle followed by the integrator passes
 * +-pi many times; the energy (with the unwrapped angle) stays bounded and
 * theta(t) follows omega0/Omega sin(Omega t) to the truncation error.
 * ------------------------------------------------------------------------- */
typedef struct spin {
  long crossings;             /* passages of the followed angle through +-pi */
  double amax, eth, eH, jump; /* max |theta|, max |theta - exact|, energy */
} spin;

static int spin_run(int D, mrvi_constraint_form form, double dT, spin *r) {
  mrvi_model *m = mrvi_model_create();
  const double J3[3] = {1.0, 1.2, 1.5}, J2 = 1.0, x0[3] = {0, 0, 0},
               axis[3] = {0, 0, 1}, k = 0.01, w0 = 2.0;
  double w3[3] = {0, 0, w0}, R[9];
  const double tilt[3] = {0.0, 0.0, 0.4};
  test_rotation(tilt, 1.0, R);
  mrvi_model_set_dimension(m, D);
  /* 3-D: J about the axis e_3 is J3[2] (the body's d_3 along e_3). */
  const double J = D == 3 ? J3[2] : J2;
  int st = mrvi_model_add_body(m, "wheel", D, MRVI_SLOW, 1.0, D == 3 ? J3 : &J2,
                               x0, D == 3 ? R : NULL, NULL, D == 3 ? w3 : &w0);
  CHECK(st == 0 &&
            mrvi_model_add_joint(m, "revolute", 0, -1, x0,
                                 D == 3 ? axis : NULL) >= 0 &&
            mrvi_model_add_torsion(m, MRVI_SLOW, 0, -1, D == 3 ? axis : NULL,
                                   "linear", &k, 0.0) >= 0,
        "spinning wheel %d-D: %s", D, mrvi_model_errmsg(m));
  const double Om = sqrt(k / J), T = 2 * M_PI / Om;
  mrvi_settings s = test_settings("midpoint-midpoint", dT, 1, 1.25 * T, 1e-12);
  s.constraint_form = form;
  s.constraint_tol = 1e-12;
  mrvi_trajectory *tr = NULL;
  mrvi_summary sum;
  if (mrvi_trajectory_run(m, &s, &tr, &sum) != 0) {
    CHECK(0, "spinning wheel %d-D: %s", D, sum.message);
    mrvi_model_free(m);
    return -1;
  }
  /* Follow the angle along the stored nodes as the integrator did. */
  const int n = tr->n;
  double ref, H0 = 0.0;
  *r = (spin){0};
  mrvi_model_torsion_init(m, tr->q, &ref);
  for (long j = 0; j < tr->n_macro; j++) {
    const double prev = ref;
    mrvi_model_torsion_follow(m, tr->q + j * n, &ref, NULL);
    r->jump = fmax(r->jump, fabs(ref - prev));
    if (j > 0 &&
        floor((prev + M_PI) / (2 * M_PI)) != floor((ref + M_PI) / (2 * M_PI)))
      r->crossings++;
    double Tk, V, W;
    mrvi_model_energy(m, tr->q + j * n, tr->p + j * n, &Tk, &V, &W);
    if (j == 0)
      H0 = Tk + V + W;
    r->eH = fmax(r->eH, fabs(Tk + V + W - H0) / H0);
    r->amax = fmax(r->amax, fabs(ref) / (w0 / Om));
    r->eth = fmax(r->eth, fabs(ref - w0 / Om * sin(Om * tr->t[j])));
  }
  mrvi_trajectory_free(tr);
  mrvi_model_free(m);
  return 0;
}

static void test_spin(int D, mrvi_constraint_form form) {
  spin r[2];
  for (int i = 0; i < 2; i++)
    if (spin_run(D, form, i ? 0.025 : 0.05, &r[i]) < 0)
      return;
  printf("spinning wheel %d-D (%s): %ld crossings of +-pi, max |theta| / "
         "amplitude %.6f; dT = 0.05, 0.025: max |theta - theta_exact| %.3g, "
         "%.3g, max relative energy error %.3g, %.3g; largest turn per step "
         "%.3g\n",
         D, form == MRVI_FORM_NULL_SPACE ? "null-space" : "multipliers",
         r[0].crossings, r[0].amax, r[0].eth, r[1].eth, r[0].eH, r[1].eH,
         r[0].jump);
  /* The wrapped angle would jump by 2 pi at each crossing: here the
   * amplitude is reached, the energy bounded, both errors O(dT^2). */
  const double oth = log2(r[0].eth / r[1].eth), oH = log2(r[0].eH / r[1].eH);
  CHECK(r[0].crossings >= 10 && fabs(r[0].amax - 1) < 1e-2 && r[0].eH < 1e-3 &&
            fabs(oth - 2) < 0.1 && fabs(oH - 2) < 0.1,
        "spinning wheel %d-D: crossings %ld, amplitude ratio %.6g, energy "
        "error %.3g, orders %.3g (angle), %.3g (energy)",
        D, r[0].crossings, r[0].amax, r[0].eH, oth, oH);
}

/* ---------------------------------------------------------------------------
 * Constraints on body points (constraint type "point"): g, G and H of a
 * distance between two body points, a body point and a particle, a body
 * point and an anchor, a fixed body point and one on a plane, against
 * central differences at a point off the manifold; the initial data meet
 * them (g = 0 at q0).
 * ------------------------------------------------------------------------- */
static void test_point_constraints(int D) {
  mrvi_model *m = sprung_pair(D, "linear", (const double[]){1.0});
  const double xp[3] = {0.5, -1.0, 0.2};
  const double vp[3] = {0, 0, 0};
  const int p = mrvi_model_add_particle(m, "p", 0.5, MRVI_SLOW, xp, vp);
  CHECK(p >= 0, "particle: %s", mrvi_model_errmsg(m));
  const mrvi_end a = {.particle = -1, .body = 0, .at = {0.4, -0.2, 0.3}},
                 b = {.particle = -1, .body = 1, .at = {-0.3, 0.5, 0.1}},
                 pe = {.particle = p, .body = -1};
  const double anchor[3] = {0.2, 0.9, -0.4}, normal[3] = {0.3, -1.0, 0.5};
  const int axes[3] = {1, 0, 1};
  int c[6];
  c[0] = mrvi_model_add_end_distance(m, &a, &b, NULL, NAN);
  c[1] = mrvi_model_add_end_distance(m, &pe, &b, NULL, NAN);
  c[2] = mrvi_model_add_end_distance(m, &a, NULL, anchor, NAN);
  c[3] = mrvi_model_add_end_fixed(m, &b, axes, NULL);
  c[4] = mrvi_model_add_end_plane(m, &a, normal, NAN);
  CHECK(c[0] >= 0 && c[1] >= 0 && c[2] >= 0 && c[3] >= 0 && c[4] >= 0,
        "constraints on body points %d-D: %s", D, mrvi_model_errmsg(m));
  c[5] = mrvi_model_add_end_distance(m, &a, &a, NULL, 1.0);
  CHECK(c[5] < 0 && strstr(mrvi_model_errmsg(m), "both ends are on body 'a'"),
        "distance between two points of one body refused: %s",
        mrvi_model_errmsg(m));
  const int R = mrvi_model_constraint_rows(m), n = mrvi_model_n(m);
  double *g = malloc((size_t)R * sizeof *g);
  mrvi_model_constraint_eval(m, mrvi_model_q0(m), g, NULL);
  double g0 = 0.0;
  for (int r = 0; r < R; r++)
    g0 = fmax(g0, fabs(g[r]));
  CHECK(R == D * (D + 1) + 3 + (D == 3 ? 2 : 1) + 1 && g0 < 1e-14,
        "body-point constraints %d-D: %d rows, max |g(q0)| %.3g", D, R, g0);
  free(g);
  double eG = 0.0, eH = 0.0;
  const double h = 1e-5;
  for (int k = 0; k < 5; k++) {
    const mrvi_constraint *con = &m->constraints[c[k]];
    const int ni = con->n_in, rows = con->rows;
    double y[MRVI_MAX_INPUTS], gp[8], gm[8], G[8 * MRVI_MAX_INPUTS],
        Gp[8 * MRVI_MAX_INPUTS], Gm[8 * MRVI_MAX_INPUTS];
    double *H = malloc((size_t)rows * ni * ni * sizeof *H);
    for (int j = 0; j < ni; j++)
      y[j] = mrvi_model_q0(m)[con->in[j]] + 0.05 * sin(2.3 * j + k);
    mrvi_constraint_eval_at(con, y, gp, G, H);
    for (int j = 0; j < ni; j++) {
      const double yj = y[j];
      y[j] = yj + h;
      mrvi_constraint_eval_at(con, y, gp, Gp, NULL);
      y[j] = yj - h;
      mrvi_constraint_eval_at(con, y, gm, Gm, NULL);
      y[j] = yj;
      for (int r = 0; r < rows; r++) {
        eG = fmax(eG, fabs((gp[r] - gm[r]) / (2 * h) - G[r * ni + j]));
        for (int l = 0; l < ni; l++)
          eH = fmax(eH, fabs((Gp[r * ni + l] - Gm[r * ni + l]) / (2 * h) -
                             H[(size_t)r * ni * ni + (size_t)l * ni + j]));
      }
    }
    free(H);
  }
  printf("constraints on body points %d-D: %d rows, G vs central differences "
         "%.3g, H %.3g\n",
         D, R, eG, eH);
  CHECK(eG < 1e-9 && eH < 1e-8, "body-point constraints %d-D: G %.3g, H %.3g",
        D, eG, eH);
  (void)n;
  mrvi_model_free(m);
}

/* Run system `sys` with the constraint form and p given, t_end = N dT;
 * NULL with a failed check on failure. */
static mrvi_trajectory *run_system(const mrvi_system *sys,
                                   mrvi_constraint_form form, int p, long N,
                                   double dT, const char *what) {
  mrvi_settings s = sys->settings;
  s.constraint_form = form;
  s.micro_steps = p;
  s.macro_step = dT;
  s.t_end = (double)N * dT;
  s.newton_tol = 1e-12;
  s.constraint_tol = 1e-12;
  mrvi_trajectory *tr = NULL;
  mrvi_summary sum;
  if (mrvi_trajectory_run(sys->model, &s, &tr, &sum) != 0) {
    CHECK(0, "%s: %s", what, sum.message);
    return NULL;
  }
  return tr;
}

/* max |q_a - q_b| over the macro nodes. */
static double max_diff(const mrvi_trajectory *a, const mrvi_trajectory *b) {
  double e = 0.0;
  for (long i = 0; i < a->n_macro * a->n && a->n_macro == b->n_macro; i++)
    e = fmax(e, fabs(a->q[i] - b->q[i]));
  return a->n_macro == b->n_macro ? e : INFINITY;
}

static mrvi_system *load(const char *path, const char *text) {
  mrvi_system *sys = NULL;
  char msg[1024];
  const int st =
      text ? mrvi_system_load_string(text, path, NULL, 0, &sys, msg, sizeof msg)
           : mrvi_system_load(test_source_path(path), NULL, 0, &sys, msg,
                              sizeof msg);
  CHECK(st == 0, "%s loads: %s", path, msg);
  return st == 0 ? sys : NULL;
}

/* The rigid pendulum pinned by `fixed` on a body point is the one on a
 * revolute joint (the same rows r = x_A - p); a bar hung from an anchor by
 * a rod to a body point and kept on a plane through another. */
static const char *pinned_yaml =
    "name: pinned\n"
    "dimension: 2\n"
    "gravity: [0, -9.81]\n"
    "bodies:\n"
    "  - {name: link, mass: 1, inertia: 0.08333333333333333,\n"
    "     position: [0.4330127018922193, -0.25], orientation: "
    "1.0471975511965976}\n"
    "constraints:\n"
    "  - {type: fixed, particle: {body: link, at: [0, 0.5]}}\n"
    "integrator: {scheme: midpoint-midpoint, macro_step: 0.01, t_end: 1}\n";

static const char *rod_yaml =
    "name: rod\n"
    "dimension: 3\n"
    "gravity: [0, 0, -9.81]\n"
    "bodies:\n"
    "  - {name: bar, mass: 1, inertia: [0.1, 0.12, 0.05], position: [1, 0, "
    "0], angular_velocity: [0.3, -0.2, 0.5]}\n"
    "particles: [{name: bob, mass: 0.3, position: [1.5, 0.2, -0.4]}]\n"
    "constraints:\n"
    "  - {type: distance, between: [{body: bar, at: [-0.3, 0, 0]}], anchor: "
    "[0, 0, 0]}\n"
    "  - {type: distance, between: [bob, {body: bar, at: [0.3, 0.1, 0]}]}\n"
    "  - {type: plane, particle: {body: bar, at: [0, 0.2, 0]}, normal: [0, "
    "1, 0]}\n"
    "integrator: {scheme: midpoint-midpoint, macro_step: 0.01, t_end: 1}\n";

static void test_point_runs(void) {
  mrvi_system *a = load("systems/rigid_pendulum.yaml", NULL),
              *b = load("pinned.yaml", pinned_yaml),
              *c = load("rod.yaml", rod_yaml);
  if (a && b) {
    mrvi_trajectory *ta = run_system(a, MRVI_FORM_MULTIPLIERS, 1, 100, 0.01,
                                     "rigid pendulum"),
                    *tb = run_system(b, MRVI_FORM_MULTIPLIERS, 1, 100, 0.01,
                                     "pinned by a body point");
    if (ta && tb) {
      const double e = max_diff(ta, tb);
      printf("pendulum pinned by a fixed body point vs on a revolute joint, "
             "100 steps: max |q - q_joint| %.3g\n",
             e);
      CHECK(e < 1e-10, "pinned pendulum vs revolute joint: %.3g", e);
    }
    mrvi_trajectory_free(ta);
    mrvi_trajectory_free(tb);
  }
  if (c) {
    const int R = mrvi_model_constraint_rows(c->model);
    CHECK(R == 6 + 3, "rod system: %d rows (want 9)", R);
    mrvi_trajectory *t[2];
    for (int f = 0; f < 2; f++)
      t[f] = run_system(c, f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS, 1,
                        100, 0.01, "rod system");
    if (t[0] && t[1]) {
      double eg = 0.0, *g = malloc((size_t)R * sizeof *g);
      for (long k = 0; k < t[0]->n_macro; k++) {
        mrvi_model_constraint_eval(c->model, t[0]->q + k * t[0]->n, g, NULL);
        for (int r = 0; r < R; r++)
          eg = fmax(eg, fabs(g[r]));
      }
      free(g);
      const double e = max_diff(t[0], t[1]);
      printf("bar on a rod, a plane and a rod to a particle (3-D), 100 "
             "steps: max |g| %.3g, forms agree to %.3g\n",
             eg, e);
      CHECK(eg <= 1e-12 && e < 1e-10, "rod system: |g| %.3g, forms %.3g", eg,
            e);
    }
    mrvi_trajectory_free(t[0]);
    mrvi_trajectory_free(t[1]);
  }
  mrvi_system_free(a);
  mrvi_system_free(b);
  mrvi_system_free(c);
}

/* ---------------------------------------------------------------------------
 * The shipped multibody systems with torsional springs: both constraint
 * forms give the same trajectory to 1e-10 over 100 macro steps with p = 1
 * and p = 5; the spacecraft (free, no gravity) conserves its linear and
 * angular momentum; flexible_pendulum's error at t = 0.4 against a fine
 * single-rate reference (dT = 1.5625e-5) falls as dT^2 for p = 1 and p = 5,
 * and it is the fast links' (the wrist's ringing): p = 10 at dT = 0.0025
 * is more accurate than p = 1 at the same dT by more than p^2 / 4 (the
 * fast error falls as the micro step squared; the slow arm's and the
 * slow-fast joint's, order 2 in dT, would keep the two alike).
 * ------------------------------------------------------------------------- */
static void momenta_drift(const mrvi_model *m, const mrvi_trajectory *tr,
                          double *eP, double *eL) {
  double P0[3], L0[3];
  *eP = *eL = 0.0;
  for (long k = 0; k < tr->n_macro; k++) {
    double P[3] = {0, 0, 0}, L[3] = {0, 0, 0};
    mrvi_model_momentum(m, tr->q + k * tr->n, tr->p + k * tr->n, P, L);
    if (k == 0)
      memcpy(P0, P, sizeof P), memcpy(L0, L, sizeof L);
    for (int a = 0; a < 3; a++) {
      *eP = fmax(*eP, fabs(P[a] - P0[a]));
      *eL = fmax(*eL, fabs(L[a] - L0[a]));
    }
  }
}

static void test_forms(const char *path, double dT, int conserved) {
  mrvi_system *sys = load(path, NULL);
  if (!sys)
    return;
  for (int p = 1; p <= 5; p += 4) {
    mrvi_trajectory *t[2];
    for (int f = 0; f < 2; f++)
      t[f] = run_system(sys, f ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS,
                        p, 100, dT, path);
    if (t[0] && t[1]) {
      const double e = max_diff(t[0], t[1]);
      double eP[2], eL[2];
      for (int f = 0; f < 2; f++)
        momenta_drift(sys->model, t[f], &eP[f], &eL[f]);
      printf("%s, p = %d, 100 steps of %g: forms agree to %.3g; max |P - P0| "
             "%.3g, %.3g, max |L - L0| %.3g, %.3g (multipliers, null space)\n",
             path, p, dT, e, eP[0], eP[1], eL[0], eL[1]);
      CHECK(e < 1e-10, "%s, p = %d: forms differ by %.3g", path, p, e);
      /* Multipliers: to round-off (every Newton update keeps the momenta).
       * Null space: the fast bodies' micro nodes are reparametrised on their
       * joints, so the update is no longer linear and the momenta hold to
       * the Newton tolerance (1e-12) per step, times the appendages' reach
       * (3.5) for the angular momentum (doc/multibody.md, "Fast bodies in
       * joints"). */
      if (conserved)
        CHECK(eP[0] < 1e-10 && eL[0] < 1e-10 && eP[1] < 100 * 1e-12 &&
                  eL[1] < 100 * 3.5 * 1e-12,
              "%s, p = %d: momentum %.3g, %.3g, angular momentum %.3g, %.3g",
              path, p, eP[0], eP[1], eL[0], eL[1]);
    }
    mrvi_trajectory_free(t[0]);
    mrvi_trajectory_free(t[1]);
  }
  mrvi_system_free(sys);
}

/* max |q(T) - q_ref(T)| at the last node. */
static double final_error(const mrvi_trajectory *a, const mrvi_trajectory *r) {
  double e = 0.0;
  const double *qa = a->q + (a->n_macro - 1) * a->n,
               *qr = r->q + (r->n_macro - 1) * r->n;
  for (int i = 0; i < a->n; i++)
    e = fmax(e, fabs(qa[i] - qr[i]));
  return e;
}

static void test_orders(void) {
  const char *path = "systems/flexible_pendulum.yaml";
  mrvi_system *sys = load(path, NULL);
  if (!sys)
    return;
  const double T = 0.4;
  mrvi_trajectory *ref =
      run_system(sys, MRVI_FORM_MULTIPLIERS, 1, 25600, T / 25600, "reference");
  for (int p = 1; ref && p <= 5; p += 4) {
    /* The wrist's 166 rad/s: p = 1 is in the asymptotic range from
     * dT = 0.000625 (its phase error omega^3 dT^2 t / 24 then 0.03 rad at
     * t = 0.4), p = 5 from dT = 0.005 (micro step 0.001: 0.08 rad). */
    const double dT0 = p == 1 ? 0.000625 : 0.005;
    double e[3];
    int ok = 1;
    for (int r = 0; r < 3 && ok; r++) {
      const double dT = dT0 / (1 << r);
      mrvi_trajectory *tr = run_system(sys, MRVI_FORM_MULTIPLIERS, p,
                                       (long)(T / dT + 0.5), dT, path);
      ok = tr != NULL;
      e[r] = ok ? final_error(tr, ref) : 0.0;
      mrvi_trajectory_free(tr);
    }
    if (!ok)
      break;
    const double o1 = log2(e[0] / e[1]), o2 = log2(e[1] / e[2]);
    printf("flexible_pendulum, p = %d: max |q(0.4) - q_ref| at dT = %g, %g, "
           "%g: %.3g, %.3g, %.3g: orders %.3f, %.3f\n",
           p, dT0, dT0 / 2, dT0 / 4, e[0], e[1], e[2], o1, o2);
    CHECK(fabs(o1 - 2) < 0.25 && fabs(o2 - 2) < 0.15,
          "flexible_pendulum, p = %d: orders %.3f, %.3f (want 2)", p, o1, o2);
  }
  /* The fast part dominates: p = 10 against p = 1 at dT = 0.0025 (p = 1's
   * phase error 0.5 rad at t = 0.4, still in its asymptotic range). */
  double e[2] = {0.0, 0.0};
  for (int i = 0; ref && i < 2; i++) {
    const double dT = 0.0025;
    mrvi_trajectory *tr = run_system(sys, MRVI_FORM_MULTIPLIERS, i ? 10 : 1,
                                     (long)(T / dT + 0.5), dT, path);
    e[i] = tr ? final_error(tr, ref) : NAN;
    mrvi_trajectory_free(tr);
  }
  if (ref) {
    printf("flexible_pendulum at dT = 0.0025: max |q(0.4) - q_ref| %.3g at "
           "p = 1, %.3g at p = 10 (%.1f times smaller)\n",
           e[0], e[1], e[0] / e[1]);
    CHECK(e[0] > 25.0 * e[1],
          "flexible_pendulum at dT = 0.0025: p = 10 error %.3g, p = 1 %.3g "
          "(want 25 times smaller)",
          e[1], e[0]);
  }
  mrvi_trajectory_free(ref);
  mrvi_system_free(sys);
}

/* The joint sweep (solver/predict_joints.c, doc/solver.md "The joint
 * sweep"): flexible_pendulum at its own settings (p = 10, dT = 0.005, the
 * schur-bordered path), 100 macro steps with the predictor's sweep moving
 * the fast nodes onto the elbow and wrist and without it.  Without, a
 * macro step took 3.8 Newton updates (the predictor off the joints by
 * (omega m dt)^2 at node m, the multipliers from zero); with it 2.0, and
 * not fewer than 1 (the predictor is never accepted): at most 2.1 is the
 * test, and 1.5 updates fewer than without.  The converged steps are the
 * same to the tolerance. */
static void test_joint_sweep(void) {
  const char *path = "systems/flexible_pendulum.yaml";
  mrvi_system *sys = load(path, NULL);
  if (!sys)
    return;
  double its[2];
  mrvi_trajectory *tr[2] = {NULL, NULL};
  for (int j = 0; j < 2; j++) {
    mrvi_settings s = sys->settings;
    s.t_end = 100 * s.macro_step;
    s.tuning.predict_joints = j;
    /* (full Newton, every update factorised: the count the predictor
     * sets; test_kept_factors counts the updates with kept factors) */
    s.tuning.reuse_rate = 0.0;
    mrvi_summary sum;
    CHECK(mrvi_trajectory_run(sys->model, &s, &tr[j], &sum) == 0,
          "flexible_pendulum, predict_joints = %d: %s", j, sum.message);
    its[j] = sum.steps > 0 ? (double)sum.iterations_total / sum.steps : NAN;
  }
  const double e = tr[0] && tr[1] ? max_diff(tr[0], tr[1]) : NAN;
  printf("flexible_pendulum, p = 10, dT = 0.005: %.3f Newton updates per "
         "macro step with the joint sweep, %.3f without; trajectories "
         "differ by %.3g\n",
         its[1], its[0], e);
  CHECK(its[1] <= 2.1 && its[0] - its[1] >= 1.5,
        "joint sweep: %.3f updates per macro step (want <= 2.1), %.3f "
        "without",
        its[1], its[0]);
  CHECK(e < 1e-9, "joint sweep: trajectories differ by %.3g", e);
  mrvi_trajectory_free(tr[0]);
  mrvi_trajectory_free(tr[1]);
  mrvi_system_free(sys);
}

/* The joint sweep's bound dt omega_max <= 1/2 on the frequencies it meets
 * (tuning joints_omega; solver/predict.c, joints_omega): flexible_pendulum
 * at p = 10, dT = 0.02 (dt = 0.002), where omega_max of the unconstrained
 * hess(V + W) (320 rad/s: dt omega 0.64) left the predictor to free flight
 * and the fast part on its micro-node constraints (the wrist, 166 rad/s:
 * 0.33) takes the joint sweep.  25 macro steps at Newton and constraint
 * tolerance 1e-12 on schur-bordered with and without, and on the general
 * path (the reference; its own predictor, full Newton): the Newton updates
 * fall from 4.9 to 4.0 a step (the test: at least 0.5 fewer, at most
 * 4.3; 5.4 to 3.9 at the file's tolerance 1e-11)
 * and the trajectory is the general path's within 1e-10. */
static void test_joints_omega(void) {
  mrvi_system *sys = load("systems/flexible_pendulum.yaml", NULL);
  if (!sys)
    return;
  mrvi_trajectory *tr[3] = {NULL, NULL, NULL};
  double its[3] = {NAN, NAN, NAN};
  for (int j = 0; j < 3; j++) {
    mrvi_settings s = sys->settings;
    s.micro_steps = 10;
    s.macro_step = 0.02;
    s.t_end = 25 * s.macro_step;
    s.newton_tol = s.constraint_tol = 1e-12;
    s.tuning.joints_omega = j == 1;
    if (j == 2)
      s.solver = MRVI_SOLVER_GENERAL;
    mrvi_summary sum;
    if (mrvi_trajectory_run(sys->model, &s, &tr[j], &sum) != 0) {
      CHECK(0, "flexible_pendulum, dT = 0.02, run %d: %s", j, sum.message);
      continue;
    }
    its[j] = sum.steps > 0 ? (double)sum.iterations_total / sum.steps : NAN;
  }
  const double e = tr[1] && tr[2] ? max_diff(tr[1], tr[2]) : NAN,
               e0 = tr[0] && tr[2] ? max_diff(tr[0], tr[2]) : NAN;
  printf("flexible_pendulum, p = 10, dT = 0.02: %.3f Newton updates per "
         "macro step with the constrained omega_max, %.3f without (general "
         "path %.3f); against the general path %.3g and %.3g\n",
         its[1], its[0], its[2], e, e0);
  CHECK(its[1] <= 4.3 && its[0] - its[1] >= 0.5,
        "joints_omega: %.3f updates per macro step (want <= 4.3), %.3f "
        "without",
        its[1], its[0]);
  CHECK(e <= 1e-10 && e0 <= 1e-10,
        "joints_omega: %.3g (%.3g without) from the general path", e, e0);
  for (int j = 0; j < 3; j++)
    mrvi_trajectory_free(tr[j]);
  mrvi_system_free(sys);
}

/* n_steps steps of s on model m: the Newton updates and factorisations,
 * the largest constraint residual at a micro node, and the positions of
 * every macro node after the first into q (n_steps x n; NULL: not). */
typedef struct kept_run {
  long updates, factorisations;
  double g_max;
  const char *path;
} kept_run;

static int kept_factors_run(const mrvi_model *m, const mrvi_settings *s,
                            int n_steps, double *q, kept_run *out) {
  mrvi_integrator *it = NULL;
  char msg[512];
  memset(out, 0, sizeof *out);
  if (mrvi_integrator_create(m, s, &it, msg, sizeof msg) < 0) {
    CHECK(0, "kept factors: %s", msg);
    return -1;
  }
  out->path = mrvi_integrator_solver_path(it);
  const int n = mrvi_model_n(m);
  for (int k = 0; k < n_steps; k++) {
    if (mrvi_integrator_step(it) < 0) {
      CHECK(0, "kept factors, step %d: %s", k, mrvi_integrator_errmsg(it));
      mrvi_integrator_free(it);
      return -1;
    }
    out->updates += mrvi_integrator_last_iterations(it);
    const double *g = mrvi_integrator_micro_constraint_residual(it);
    for (int i = 0; i < s->micro_steps; i++)
      out->g_max = fmax(out->g_max, g[i]);
    if (q)
      memcpy(q + (size_t)k * n, mrvi_integrator_q(it), (size_t)n * sizeof *q);
  }
  out->factorisations = mrvi_integrator_factorisations(it);
  mrvi_integrator_free(it);
  return 0;
}

/* schur-bordered keeps the factors of a step's first update for the next
 * ones while they contract well (simplified Newton, the schur path's rule;
 * doc/solver.md, "Newton details"): counted on the flexible pendulum at
 * p = 10 (one factorisation a step where full Newton takes two, at most
 * 2.2 updates a step), with the trajectory full Newton's (reuse_rate = 0)
 * within 10 times the Newton tolerance over 100 steps (the steps differ by
 * round-off: the kept factors land below 0.01 tol, full Newton at the
 * round-off floor; the pendulum's ringing wrist amplifies that).  And the
 * constraint rows, which the dynamic rows' contraction does not measure:
 * the triatomic molecule with trapezoidal-trapezoidal at p = 1, whose
 * dynamic rows are linear (at round-off after the first update) while the
 * constraint rows converge linearly with kept factors, takes them and
 * still ends every step at 0.01 times the constraint tolerance (it stopped
 * at 0.65 times it when the rule read the dynamic rows alone). */
static void test_kept_factors(void) {
  mrvi_system *sys = load("systems/flexible_pendulum.yaml", NULL);
  if (!sys)
    return;
  enum { N = 100 };
  const int n = mrvi_model_n(sys->model);
  double *q[2] = {malloc((size_t)N * n * sizeof(double)),
                  malloc((size_t)N * n * sizeof(double))};
  kept_run r[2];
  for (int j = 0; j < 2 && q[0] && q[1]; j++) {
    mrvi_settings s = sys->settings;
    if (j == 0)
      s.tuning.reuse_rate = 0.0; /* full Newton */
    if (kept_factors_run(sys->model, &s, N, q[j], &r[j]) < 0)
      goto done;
  }
  double d = 0.0;
  for (size_t i = 0; i < (size_t)N * n; i++)
    d = fmax(d, fabs(q[0][i] - q[1][i]));
  const double tol = sys->settings.newton_tol;
  printf("flexible_pendulum, p = 10, %d steps on %s: full Newton %.2f "
         "updates and %.2f factorisations a step, kept factors %.2f and "
         "%.2f; residual evaluations %.2f -> %.2f a step; positions differ "
         "by %.3g\n",
         N, r[1].path, (double)r[0].updates / N,
         (double)r[0].factorisations / N, (double)r[1].updates / N,
         (double)r[1].factorisations / N,
         (double)(r[0].updates + r[0].factorisations) / N,
         (double)(r[1].updates + r[1].factorisations) / N, d);
  CHECK(strcmp(r[1].path, "schur-bordered") == 0, "path %s", r[1].path);
  CHECK(r[0].factorisations == r[0].updates,
        "full Newton: %ld factorisations for %ld updates", r[0].factorisations,
        r[0].updates);
  CHECK(r[1].factorisations <= N + N / 20 &&
            r[1].updates - r[1].factorisations >= N - N / 20 &&
            r[1].updates <= 2.2 * N,
        "kept factors: %ld factorisations, %ld updates in %d steps",
        r[1].factorisations, r[1].updates, N);
  CHECK(d <= 10.0 * tol, "kept factors: positions differ by %.3g", d);

  /* The constraint rows: triatomic, trapezoidal-trapezoidal, p = 1. */
  mrvi_system *tri = load("systems/triatomic.yaml", NULL);
  if (tri) {
    mrvi_settings s = tri->settings;
    s.micro_steps = 1;
    s.tuning.predict_joints = 0;
    kept_run t;
    if (mrvi_settings_set_scheme(&s, "trapezoidal-trapezoidal") == 0 &&
        kept_factors_run(tri->model, &s, 20, NULL, &t) == 0) {
      printf("triatomic, trapezoidal-trapezoidal, p = 1, 20 steps on %s: "
             "%ld updates, %ld factorisations, largest |g| %.3g (tolerance "
             "%.3g)\n",
             t.path, t.updates, t.factorisations, t.g_max, s.constraint_tol);
      CHECK(strcmp(t.path, "schur-bordered") == 0 &&
                t.updates > t.factorisations &&
                t.g_max <=
                    tri->settings.tuning.reuse_tighten * s.constraint_tol,
            "triatomic, kept factors on %s: %ld updates, %ld factorisations, "
            "|g| %.3g",
            t.path, t.updates, t.factorisations, t.g_max);
    }
    mrvi_system_free(tri);
  }
done:
  free(q[0]);
  free(q[1]);
  mrvi_system_free(sys);
}

/* A step that turns a torsional spring by pi/2 or more is refused with
 * its name: two wheels on one axle (2-D, a revolute joint at their common
 * centre) counter-rotating at +-2 rad/s with dT = 0.4, which the midpoint
 * rule (RATTLE on the directors: the sine of the turn a step is omega dT)
 * turns by asin(0.8) = 0.93 rad each, 1.85 rad relative to each other, a
 * step.  (One body turns by at most a quarter turn a step: no step
 * exists beyond omega dT = 1, so the relative turn of two bodies is the
 * way to reach the limit.) */
static void test_turn_refused(void) {
  mrvi_model *m = mrvi_model_create();
  const double J = 1.0, wa = 2.0, wb = -2.0, x0[2] = {0, 0}, k = 0.01;
  mrvi_model_set_dimension(m, 2);
  mrvi_model_add_body(m, "a", 2, MRVI_SLOW, 1.0, &J, x0, NULL, NULL, &wa);
  mrvi_model_add_body(m, "b", 2, MRVI_SLOW, 1.0, &J, x0, NULL, NULL, &wb);
  mrvi_model_add_joint(m, "revolute", 0, 1, x0, NULL);
  mrvi_model_add_torsion(m, MRVI_SLOW, 0, 1, NULL, "linear", &k, 0.0);
  mrvi_settings s = test_settings("midpoint-midpoint", 0.4, 1, 2.0, 1e-12);
  mrvi_trajectory *tr = NULL;
  mrvi_summary sum;
  const int st = mrvi_trajectory_run(m, &s, &tr, &sum);
  printf("wheels turning 1.85 rad apart a step: %s\n", sum.message);
  CHECK(st < 0 && strstr(sum.message, "torsional spring a-b") &&
            strstr(sum.message, "turned by 1.85 rad") &&
            strstr(sum.message, "reduce integrator.macro_step"),
        "a step turning a torsional spring by pi/2 or more refused: %s",
        sum.message);
  mrvi_trajectory_free(tr);
  mrvi_model_free(m);
}

int main(void) {
  test_derivatives();
  test_point_constraints(2);
  test_point_constraints(3);
  test_turn_refused();
  test_point_runs();
  test_forms("systems/flexible_pendulum.yaml", 0.01, 0);
  test_forms("systems/spacecraft.yaml", 0.05, 1);
  test_joint_sweep();
  test_joints_omega();
  test_kept_factors();
  test_orders();
  for (int D = 2; D <= 3; D++) {
    test_spin(D, MRVI_FORM_MULTIPLIERS);
    test_spin(D, MRVI_FORM_NULL_SPACE);
  }
  return test_finish();
}
