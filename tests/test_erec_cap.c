/* The element table beyond its prototypes (src/model/model.h, mrvi_erec):
 * a compact spring names its law's prototype in 24 bits, so the springs of
 * a model's 2^24 + 1-th distinct law (parameter set and rate) are kept in
 * full.  This program compiles src/model/model.c with MRVI_EREC_LP_MAX = 4
 * (tests/meson.build), so that a model of a few parameter sets takes that
 * path: the springs of the fifth set on are kept in full, with their own
 * inputs (before audit16 these pointed into mrvi_model_add_spring's stack
 * frame, gone when it returned: the integrator's first sweep read them,
 * SEGV under the fuzz build), and their energy, gradient and the
 * integrator's steps are those of the springs, against the formula. */
#include "model/model.h"
#include "mrvi.h"
#include "testlib.h"
#include <math.h>
#include <stdio.h>
#include <string.h>

_Static_assert(MRVI_EREC_LP_MAX == 4, "built with -DMRVI_EREC_LP_MAX=4");

#define NP 5
#define NS 7

static const int ends[NS][2] = {{0, 1}, {1, 2}, {2, 3}, {3, 4},
                                {4, 0}, {0, 2}, {1, 3}};

/* Spring s of stiffness 10 + s, rest length 1, added by a call whose frame
 * the next one reuses. */
static int add(mrvi_model *m, int s) {
  const double k[1] = {10.0 + s};
  return mrvi_model_add_spring(m, MRVI_SLOW, ends[s][0], ends[s][1], "linear",
                               k, 1.0);
}

/* Something else on the stack between the adds. */
static double scribble(int s) {
  volatile double junk[64];
  for (int i = 0; i < 64; i++)
    junk[i] = -1e6 * (i + s);
  return junk[s];
}

int main(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  double q0[2 * NP];
  for (int i = 0; i < NP; i++) {
    const double x[2] = {cos(1.3 * i) * (1.0 + 0.1 * i), sin(1.3 * i)},
                 v[2] = {0.1 * i, -0.05 * i};
    char name[16];
    snprintf(name, sizeof name, "p%d", i);
    CHECK(mrvi_model_add_particle(m, name, 1.0 + i, MRVI_SLOW, x, v) == i,
          "particle %d: %s", i, mrvi_model_errmsg(m));
    q0[2 * i] = x[0];
    q0[2 * i + 1] = x[1];
  }
  double sink = 0.0;
  for (int s = 0; s < NS; s++) {
    CHECK(add(m, s) == s, "spring %d: %s", s, mrvi_model_errmsg(m));
    sink += scribble(s);
  }
  CHECK(sink != 0.0, "the stack written");
  /* the first 4 sets compact, the others in full with their own inputs */
  for (int s = 0; s < NS; s++) {
    const int compact = mrvi_model_compact(m, s) != NULL;
    CHECK(compact == (s < MRVI_EREC_LP_MAX), "spring %d: compact %d", s,
          compact);
    const mrvi_element *e = MRVI_ELEMENT(m, s);
    int ok = e->n_in == 4 && e->kind == MRVI_ELEMENT_SPRING;
    for (int k = 0; ok && k < 2; k++)
      ok = e->in[k] == 2 * ends[s][0] + k && e->in[2 + k] == 2 * ends[s][1] + k;
    CHECK(ok, "spring %d: inputs %d %d %d %d", s, e->in[0], e->in[1], e->in[2],
          e->in[3]);
  }
  /* V and its gradient against sum_s k_s / 2 (|x_i - x_j| - 1)^2 */
  double g[2 * NP] = {0}, want = 0.0, gw[2 * NP] = {0};
  for (int s = 0; s < NS; s++) {
    const int i = ends[s][0], j = ends[s][1];
    const double dx = q0[2 * i] - q0[2 * j], dy = q0[2 * i + 1] - q0[2 * j + 1];
    const double r = sqrt(dx * dx + dy * dy), k = 10.0 + s;
    want += 0.5 * k * (r - 1.0) * (r - 1.0);
    const double f = k * (r - 1.0) / r;
    gw[2 * i] += f * dx;
    gw[2 * i + 1] += f * dy;
    gw[2 * j] -= f * dx;
    gw[2 * j + 1] -= f * dy;
  }
  const double V = mrvi_model_potential(m, MRVI_SLOW, q0, g, NULL);
  CHECK(fabs(V - want) <= 1e-14 * want, "V %.17g, formula %.17g", V, want);
  double gerr = 0.0, gmax = 0.0;
  for (int i = 0; i < 2 * NP; i++) {
    gerr = fmax(gerr, fabs(g[i] - gw[i]));
    gmax = fmax(gmax, fabs(gw[i]));
  }
  CHECK(gerr <= 1e-14 * gmax, "gradient error %.3g of %.3g", gerr, gmax);
  /* steps on the explicit and the implicit paths, 1 and 2 threads: the
   * energy of the conservative system bounded, the results equal */
  const char *schemes[2] = {"explicit-slow", "midpoint-midpoint"};
  for (int c = 0; c < 2; c++) {
    double q[2][2 * NP];
    for (int t = 1; t <= 2; t++) {
      mrvi_settings st;
      mrvi_settings_default(&st);
      CHECK(mrvi_settings_set_scheme(&st, schemes[c]) == MRVI_OK, "scheme %s",
            schemes[c]);
      st.macro_step = 0.01;
      st.micro_steps = 2;
      st.threads = mrvi_threads_supported() ? t : 1;
      st.tuning.thread_chunk = 1;
      char msg[512] = "";
      mrvi_integrator *it = NULL;
      int rc = mrvi_integrator_create(m, &st, &it, msg, sizeof msg);
      CHECK(rc == MRVI_OK, "%s: create: %s", schemes[c], msg);
      double H0 = 0, H = 0, dH = 0;
      for (int k = 0; rc == MRVI_OK && k < 200; k++) {
        rc = mrvi_integrator_step(it);
        double kin, slow, fast;
        mrvi_model_energy(m, mrvi_integrator_q(it), mrvi_integrator_p(it), &kin,
                          &slow, &fast);
        H = kin + slow + fast;
        if (k == 0)
          H0 = H;
        dH = fmax(dH, fabs(H - H0));
      }
      CHECK(rc == MRVI_OK, "%s: step %d", schemes[c], rc);
      CHECK(dH < 1e-2 * fabs(H0), "%s: energy drift %.3g of %.3g", schemes[c],
            dH, H0);
      if (it)
        memcpy(q[t - 1], mrvi_integrator_q(it), sizeof q[0]);
      mrvi_integrator_free(it);
    }
    CHECK(!memcmp(q[0], q[1], sizeof q[0]), "%s: 1 and 2 threads differ",
          schemes[c]);
  }
  mrvi_model_free(m);
  return test_finish();
}
