/* The one-step equations (arXiv 2406.12991 §3.1, doc/solver.md):
 * - the residual equals p_k + D L_d of a discrete Lagrangian written here
 *   straight from eq:discrete_Lagrangian / eq:Zapprox /
 * eq:slow_potential_affine (derivatives by central differences), and the output
 * momenta equal D_{q_{k+1}} L_d and the micro momenta D_{q^{f,m}} L_d^{m-1}
 * (eq:pkfm+);
 * - the assembled Newton matrix equals the finite-difference Jacobian of the
 *   residual, entry by entry, for every named scheme with p in {1, 3}. */
#include "models.h"
#include "step/step.h"
#include "testlib.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct nodes {
  const mrvi_model *m;
  const mrvi_settings *s;
  double *qs0, *qs1; /* ns */
  double *qf;        /* (p+1) x nf */
} nodes;

/* Full configuration z = (slow part, fast part) into q (model order). */
static void compose(const mrvi_model *m, const double *qs, const double *qf,
                    double *q) {
  for (int i = 0; i < m->n_slow; i++)
    q[m->slow_index[i]] = qs[i];
  for (int i = 0; i < m->n_fast; i++)
    q[m->fast_index[i]] = qf[i];
}

/* Potential of class c at the affine combination a z^m + b z^{m+1} where
 * z^m = (q^{s,m}, q^{f,m}) and q^{s,m} interpolates the slow macro nodes. */
static double pot_at(const nodes *X, int c, int mm, double a, double b) {
  const mrvi_model *m = X->m;
  const int p = X->s->micro_steps, ns = m->n_slow, nf = m->n_fast;
  double qs[64], qf[64], q[128];
  for (int i = 0; i < ns; i++) {
    double s0 =
        (1.0 - (double)mm / p) * X->qs0[i] + ((double)mm / p) * X->qs1[i];
    double s1 = (1.0 - (double)(mm + 1) / p) * X->qs0[i] +
                ((double)(mm + 1) / p) * X->qs1[i];
    qs[i] = a * s0 + b * s1;
  }
  for (int i = 0; i < nf; i++)
    qf[i] = a * X->qf[mm * nf + i] + b * X->qf[(mm + 1) * nf + i];
  compose(m, qs, qf, q);
  return mrvi_model_potential(m, (mrvi_rate)c, q, NULL, NULL);
}

/* L_d, or with only >= 0 the part L_d^only of micro interval `only` (fast
 * kinetic energy and potential evaluations of that interval; no slow
 * kinetic energy). */
static double Ld(const nodes *X, int only) {
  const mrvi_model *m = X->m;
  const mrvi_settings *s = X->s;
  const int p = s->micro_steps, ns = m->n_slow, nf = m->n_fast;
  const double dT = s->macro_step, dt = dT / p;
  double L = 0.0;
  if (only < 0)
    for (int i = 0; i < ns; i++) {
      double v = (X->qs1[i] - X->qs0[i]) / dT;
      L += 0.5 * dT * MRVI_MASS(m, m->slow_index[i]) * v * v;
    }
  for (int mm = 0; mm < p; mm++) {
    if (only >= 0 && mm != only)
      continue;
    for (int i = 0; i < nf; i++) {
      double v = (X->qf[(mm + 1) * nf + i] - X->qf[mm * nf + i]) / dt;
      L += 0.5 * dt * MRVI_MASS(m, m->fast_index[i]) * v * v;
    }
    /* eq:Zapprox for W, and for V on the micro grid */
    for (int c = 0; c < 2; c++) {
      const mrvi_rule r = c == MRVI_SLOW ? s->slow : s->fast;
      if (c == MRVI_SLOW && s->slow_grid == MRVI_GRID_MACRO)
        continue;
      L -= dt * (r.alpha * pot_at(X, c, mm, r.gamma, 1 - r.gamma) +
                 (1 - r.alpha) * pot_at(X, c, mm, 1 - r.gamma, r.gamma));
    }
  }
  /* eq:slow_potential_affine */
  if (s->slow_grid == MRVI_GRID_MACRO) {
    if (only < 0 || only == 0)
      L -= dT * s->slow.alpha * pot_at(X, MRVI_SLOW, 0, 1, 0);
    if (only < 0 || only == p - 1)
      L -= dT * (1 - s->slow.alpha) * pot_at(X, MRVI_SLOW, p - 1, 0, 1);
  }
  return L;
}

/* Central difference of L_d (or L_d^only) with respect to *v. */
static double dLd(nodes *X, double *v, int only) {
  const double h = 1e-6 * (1 + fabs(*v)), v0 = *v;
  *v = v0 + h;
  double lp = Ld(X, only);
  *v = v0 - h;
  double lm = Ld(X, only);
  *v = v0;
  return (lp - lm) / (2 * h);
}

static void check_settings(const mrvi_model *m, mrvi_settings s,
                           const char *label) {
  const int p = s.micro_steps;
  const double dT = s.macro_step;
  const char *scheme = s.scheme;
  mrvi_step st;
  CHECK(mrvi_step_init(&st, m, &s) == 0, "step init");
  const int ns = m->n_slow, nf = m->n_fast, nu = st.n_unknowns;
  double *qs0 = calloc(ns + 1, sizeof(double)),
         *ps0 = calloc(ns + 1, sizeof(double));
  double *qf0 = calloc(nf + 1, sizeof(double)),
         *pf0 = calloc(nf + 1, sizeof(double));
  test_initial_data(&st, qs0, qf0, ps0, pf0);
  /* A generic point: free flight plus a deterministic wiggle. */
  double *x = calloc(nu, sizeof(double)), *R = calloc(nu, sizeof(double));
  for (int i = 0; i < ns; i++)
    x[i] = qs0[i] + dT * ps0[i] / MRVI_MASS(m, m->slow_index[i]) +
           0.01 * sin(i + 1.0);
  for (int k = 1; k <= p; k++)
    for (int i = 0; i < nf; i++)
      x[ns + (k - 1) * nf + i] =
          qf0[i] + k * (dT / p) * pf0[i] / MRVI_MASS(m, m->fast_index[i]) +
          0.01 * cos(k + 2.0 * i);
  CHECK(mrvi_step_build_pattern(&st, x) == 0, "pattern");
  mrvi_step_assemble(&st, x, R, 1);

  /* Residual against derivatives of L_d. */
  nodes X = {m, &s, calloc(ns + 1, sizeof(double)),
             calloc(ns + 1, sizeof(double)),
             calloc((size_t)(p + 1) * nf + 1, sizeof(double))};
  memcpy(X.qs0, qs0, ns * sizeof(double));
  memcpy(X.qs1, x, ns * sizeof(double));
  memcpy(X.qf, qf0, nf * sizeof(double));
  memcpy(X.qf + nf, x + ns, (size_t)p * nf * sizeof(double));
  char what[200];
  snprintf(what, sizeof what, "%s %s p=%d residual = p_k + D L_d", label,
           scheme, p);
  for (int i = 0; i < ns; i++) {
    double d = dLd(&X, &X.qs0[i], -1);
    CHECK_NEAR(R[i], ps0[i] + d, 1e-6 * (1 + fabs(d)), what);
  }
  for (int k = 0; k < p; k++)
    for (int i = 0; i < nf; i++) {
      double d = dLd(&X, &X.qf[k * nf + i], -1);
      double expect = (k == 0 ? pf0[i] : 0.0) + d;
      CHECK_NEAR(R[ns + k * nf + i], expect, 1e-6 * (1 + fabs(d)), what);
    }
  /* Output momenta. */
  double *ps1 = calloc(ns + 1, sizeof(double)),
         *pf = calloc((size_t)p * nf + 1, sizeof(double));
  mrvi_step_momenta(&st, x, ps1, pf);
  snprintf(what, sizeof what, "%s %s p=%d momenta = D L_d", label, scheme, p);
  for (int i = 0; i < ns; i++) {
    double d = dLd(&X, &X.qs1[i], -1);
    CHECK_NEAR(ps1[i], d, 1e-6 * (1 + fabs(d)), what);
  }
  for (int k = 1; k <= p; k++)
    for (int i = 0; i < nf; i++) {
      double d = dLd(&X, &X.qf[k * nf + i], k - 1);
      CHECK_NEAR(pf[(k - 1) * nf + i], d, 1e-6 * (1 + fabs(d)), what);
    }

  /* Jacobian against central differences of the residual. */
  snprintf(what, sizeof what, "%s %s p=%d Jacobian", label, scheme, p);
  double scale;
  const double err = test_step_fd_error(&st, x, &scale);
  CHECK(err <= 1e-6 * scale, "%s: max entry error %.2e (scale %.2e)", what, err,
        scale);
  free(ps1);
  free(pf);
  free(X.qs0);
  free(X.qs1);
  free(X.qf);
  free(x);
  free(R);
  free(qs0);
  free(ps0);
  free(qf0);
  free(pf0);
  mrvi_step_free(&st);
}

/* The model's and the step's compact storage (doc/performance/16-es-mem16.md):
 * one mass entry while every mass is the first's, every entry from the
 * first that differs; no element list for a class of consecutive elements,
 * a list for an interleaved one, both read as the element order. */
/* Particles named by a sequence rule, each on the coordinates after the
 * last, keep no record (particles_kept 0); the first that is not such (after
 * a coordinate of its own, or with a stored name) makes every record, and
 * the names and first coordinates read the same before and after. */
static void test_particle_records(void) {
  for (int how = 0; how < 2; how++) {
    mrvi_model *m = mrvi_model_create();
    CHECK(m && mrvi_model_set_dimension(m, 3) == 0, "model");
    const double x[3] = {0.0, 1.0, 2.0}, v[3] = {0.0, 0.0, 0.0};
    for (int i = 0; i < 3; i++) {
      char name[16];
      snprintf(name, sizeof name, "q%d", i);
      CHECK(mrvi_model_add_particle(m, name, 1.0, MRVI_SLOW, x, v) == i,
            "particle %d", i);
    }
    CHECK(m->particles_kept == 0, "no particle records kept");
    for (int kept = 0; kept < 2; kept++) {
      for (int i = 0; i < 3; i++) {
        char want[16], buf[MRVI_NAME_MAX];
        snprintf(want, sizeof want, "q%d", i);
        CHECK(mrvi_particle_first(m, i) == 3 * i &&
                  strcmp(mrvi_model_particle_name(m, i, buf), want) == 0 &&
                  mrvi_model_find_particle(m, want) == i,
              "particle %d (kept %d): first %d, name %s", i, kept,
              mrvi_particle_first(m, i), mrvi_model_particle_name(m, i, buf));
        snprintf(want, sizeof want, "q%d.z", i);
        CHECK(strcmp(MRVI_CNAME(m, 3 * i + 2), want) == 0 &&
                  mrvi_model_find_coordinate(m, want) == 3 * i + 2,
              "coordinate %s (kept %d)", want, kept);
      }
      if (kept)
        break;
      /* how 0: a coordinate of its own, then q3 (first 10, not 9); how 1:
       * a particle whose name is stored */
      if (how == 0)
        CHECK(mrvi_model_add_coordinate(m, "c", 1.0, MRVI_SLOW, 0.0, 0.0) == 9,
              "own coordinate");
      CHECK(mrvi_model_add_particle(m, how ? "b" : "q3", 1.0, MRVI_FAST, x,
                                    v) == 3,
            "particle 3");
      CHECK(m->particles_kept == 1, "records kept (how %d)", how);
      CHECK(mrvi_particle_first(m, 3) == 9 + !how &&
                (mrvi_particle_stored(m, 3) != NULL) == how &&
                strcmp(MRVI_PNAME(m, 3), how ? "b" : "q3") == 0 &&
                strcmp(MRVI_CNAME(m, 9 + !how), how ? "b.x" : "q3.x") == 0,
            "particle 3 (how %d): first %d, name %s", how,
            mrvi_particle_first(m, 3), MRVI_PNAME(m, 3));
    }
    if (how == 0)
      CHECK(strcmp(MRVI_CNAME(m, 9), "c") == 0, "own coordinate's name");
    mrvi_model_free(m);
  }
}

static void test_compact_storage(void) {
  const double masses[4] = {2.0, 2.0, 2.0, 0.5};
  mrvi_model *m = mrvi_model_create();
  CHECK(m && mrvi_model_set_dimension(m, 2) == 0, "model");
  for (int i = 0; i < 4; i++) {
    const double x[2] = {(double)i, 0.1 * i}, v[2] = {0.0, 0.0};
    char name[16];
    snprintf(name, sizeof name, "a%d", i);
    CHECK(mrvi_model_add_particle(m, name, masses[i],
                                  i % 2 ? MRVI_FAST : MRVI_SLOW, x, v) >= 0,
          "particle %d", i);
    CHECK(m->mass_inc == (i == 3), "mass_inc %d after particle %d", m->mass_inc,
          i);
  }
  for (int c = 0; c < 8; c++)
    CHECK(mrvi_model_mass(m, c) == masses[c / 2] &&
              MRVI_MASS(m, c) == masses[c / 2],
          "mass of coordinate %d", c);
  /* springs by potential: slow, slow, fast, slow (V interleaved) */
  const double k[1] = {10.0};
  const mrvi_rate pot[4] = {MRVI_SLOW, MRVI_SLOW, MRVI_FAST, MRVI_SLOW};
  const int ends[4][2] = {{0, 2}, {0, 1}, {1, 3}, {2, 3}};
  for (int e = 0; e < 4; e++)
    CHECK(mrvi_model_add_spring(m, pot[e], ends[e][0], ends[e][1], "linear", k,
                                1.0) >= 0,
          "spring %d", e);
  for (int interleaved = 1; interleaved >= 0; interleaved--) {
    if (!interleaved) { /* (a model of V's springs then W's) */
      mrvi_model_free(m);
      m = mrvi_model_create();
      mrvi_model_set_dimension(m, 2);
      for (int i = 0; i < 4; i++) {
        const double x[2] = {(double)i, 0.1 * i}, v[2] = {0.0, 0.0};
        char name[16];
        snprintf(name, sizeof name, "a%d", i);
        mrvi_model_add_particle(m, name, 1.0, i % 2 ? MRVI_FAST : MRVI_SLOW, x,
                                v);
      }
      for (int e = 0; e < 4; e++)
        mrvi_model_add_spring(m, e == 3 ? MRVI_FAST : MRVI_SLOW, ends[e][0],
                              ends[e][1], "linear", k, 1.0);
      CHECK(m->mass_inc == 0, "equal masses: one entry");
    }
    mrvi_settings s = test_settings("explicit-slow", 0.1, 2, 1.0, 1e-10);
    mrvi_step st;
    CHECK(mrvi_step_init(&st, m, &s) == MRVI_OK, "step init");
    CHECK((st.elem_of_class[MRVI_SLOW] != NULL) == interleaved &&
              st.elem_of_class[MRVI_FAST] == NULL,
          "element lists kept: V %d, W %d (interleaved %d)",
          st.elem_of_class[MRVI_SLOW] != NULL,
          st.elem_of_class[MRVI_FAST] != NULL, interleaved);
    for (int c = 0; c < 2; c++) {
      int *own = NULL, i = 0;
      const int *list = mrvi_step_class_list(&st, c, &own);
      CHECK(list != NULL, "class list");
      for (int e = 0; list && e < m->n_elements; e++)
        if ((int)m->erecs[e].potential == c) {
          CHECK(i < st.n_elem_of_class[c] && MRVI_STEP_ELEM(&st, c, i) == e &&
                    list[i] == e,
                "class %d element %d: %d", c, i, e);
          i++;
        }
      CHECK(i == st.n_elem_of_class[c], "class %d: %d elements", c, i);
      free(own);
    }
    mrvi_step_free(&st);
  }
  mrvi_model_free(m);
}

int main(void) {
  test_compact_storage();
  test_particle_records();
  mrvi_model *fpu = test_fpu(), *ring = test_spring_ring(),
             *osc = test_oscillator(2.0);
  const char *const *schemes = mrvi_scheme_names();
  const int ps[2] = {1, 3};
  for (int i = 0; schemes[i]; i++)
    for (int j = 0; j < 2; j++) {
      check_settings(fpu, test_settings(schemes[i], 0.1, ps[j], 1, 1e-10),
                     "fpu");
      check_settings(ring, test_settings(schemes[i], 0.01, ps[j], 1, 1e-10),
                     "spring ring");
      check_settings(osc, test_settings(schemes[i], 0.3, ps[j], 1, 1e-10),
                     "oscillator");
    }
  /* Rules beyond the named schemes (eq:Zapprox with any alpha, gamma):
   * right rectangle, Lobatto, and general values, micro and macro grid. */
  const mrvi_rule rules[3][2] = {{{0.0, 1.0}, {1.0, 0.0}},
                                 {{0.5, 0.0}, {0.5, 1.0}},
                                 {{0.3, 0.2}, {0.7, 0.9}}};
  for (int r = 0; r < 3; r++)
    for (int g = 0; g < 2; g++) {
      mrvi_settings s = test_settings("midpoint-midpoint", 0.1, 3, 1.0, 1e-10);
      snprintf(s.scheme, sizeof s.scheme, "rule%d%s", r, g ? "-macro" : "");
      s.slow = rules[r][0];
      s.fast = rules[r][1];
      s.slow_grid = g ? MRVI_GRID_MACRO : MRVI_GRID_MICRO;
      check_settings(fpu, s, "fpu");
      s.macro_step = 0.01;
      check_settings(ring, s, "spring ring");
    }
  mrvi_model_free(fpu);
  mrvi_model_free(ring);
  mrvi_model_free(osc);
  return test_finish();
}
