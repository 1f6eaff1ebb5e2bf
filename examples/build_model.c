/* Build a model in code and integrate it step by step.
 *
 *   build_model
 *
 * A planar molecule of three particles: a heavy slow particle S joined by a
 * soft slow spring to a light fast particle F1, which a stiff fast spring
 * joins to a second light fast particle F2.  No external force acts, so
 * the discrete Noether theorem of the variational integrator (arXiv
 * 2406.12991) conserves the total linear and angular momentum to the
 * Newton tolerance, while the energy error stays bounded.  The program
 * integrates with mrvi_integrator_step and prints the largest drift of
 * both momenta and the largest relative energy error over the run.
 */
#include <math.h>
#include <mrvi.h>
#include <stdio.h>
#include <stdlib.h>

int main(void) {
  /* The model: particles (name, mass, rate, position, velocity), then
   * springs phi(|x_i - x_j| - L) with the law "linear", phi(s) = k s^2/2. */
  mrvi_model *m = mrvi_model_create();
  if (!m)
    return 1;
  mrvi_model_set_name(m, "molecule");
  mrvi_model_set_dimension(m, 2);
  const double xs[2] = {0, 0}, vs[2] = {0, -0.01};
  const double x1[2] = {1, 0}, v1[2] = {0, 0.5};
  const double x2[2] = {1.12, 0}, v2[2] = {0.3, 0.5};
  const int S = mrvi_model_add_particle(m, "S", 1.0, MRVI_SLOW, xs, vs);
  const int F1 = mrvi_model_add_particle(m, "F1", 0.01, MRVI_FAST, x1, v1);
  const int F2 = mrvi_model_add_particle(m, "F2", 0.01, MRVI_FAST, x2, v2);
  const double soft = 1.0, stiff = 100.0;
  /* A fast spring may only join fast particles: its potential is part of
   * W, integrated on the micro grid. */
  if (S < 0 || F1 < 0 || F2 < 0 ||
      mrvi_model_add_spring(m, MRVI_SLOW, S, F1, "linear", &soft, 1.0) < 0 ||
      mrvi_model_add_spring(m, MRVI_FAST, F1, F2, "linear", &stiff, 0.1) < 0) {
    fprintf(stderr, "model: %s\n", mrvi_model_errmsg(m));
    mrvi_model_free(m);
    return 1;
  }

  /* The scheme and step sizes: p = 10 micro steps of 0.004 per macro step
   * resolve the fast vibration (omega = sqrt(k / mu) = 141). */
  mrvi_settings s;
  mrvi_settings_default(&s);
  mrvi_settings_set_scheme(&s, "midpoint-midpoint");
  s.macro_step = 0.04;
  s.micro_steps = 10;
  s.t_end = 10.0;
  s.newton_tol = 1e-12;

  char msg[1024];
  mrvi_integrator *it = NULL;
  if (mrvi_integrator_create(m, &s, &it, msg, sizeof msg) < 0) {
    fprintf(stderr, "integrator: %s\n", msg);
    mrvi_model_free(m);
    return 1;
  }

  /* The momenta and energy at a node: q, p in model order (x, y of S, F1,
   * F2); angular momentum in 2-D is one number. */
  const int n = mrvi_model_n(m);
  double P0[2], L0, P[2], L, T, V, W;
  mrvi_model_momentum(m, mrvi_integrator_q(it), mrvi_integrator_p(it), P0, &L0);
  mrvi_model_energy(m, mrvi_integrator_q(it), mrvi_integrator_p(it), &T, &V,
                    &W);
  const double H0 = T + V + W, E = T + fabs(V) + fabs(W);
  double dP = 0, dL = 0, dH = 0;

  const long N = mrvi_settings_n_steps(&s);
  for (long k = 0; k < N; k++) {
    if (mrvi_integrator_step(it) < 0) {
      fprintf(stderr, "step %ld: %s\n", k + 1, mrvi_integrator_errmsg(it));
      mrvi_integrator_free(it);
      mrvi_model_free(m);
      return 2;
    }
    const double *q = mrvi_integrator_q(it), *p = mrvi_integrator_p(it);
    mrvi_model_momentum(m, q, p, P, &L);
    mrvi_model_energy(m, q, p, &T, &V, &W);
    dP = fmax(dP, fmax(fabs(P[0] - P0[0]), fabs(P[1] - P0[1])));
    dL = fmax(dL, fabs(L - L0));
    dH = fmax(dH, fabs(T + V + W - H0));
  }
  printf("%s: %d coordinates, %ld macro steps of %g, p = %d\n",
         mrvi_model_name(m), n, N, s.macro_step, s.micro_steps);
  printf("linear momentum (%.6f, %.6f), max drift %.3e\n", P0[0], P0[1], dP);
  printf("angular momentum %.6f, max drift %.3e\n", L0, dL);
  printf("max relative energy error %.3e\n", dH / E);
  mrvi_integrator_free(it);
  mrvi_model_free(m);
  return 0;
}
