/* Derivatives of every law and every element kind against central finite
 * differences; model potential gradient and Hessian likewise. */
#include "internal.h"
#include "models.h"
#include "testlib.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* phi' and phi'' of every registered law at several strains. */
static void check_laws(void) {
  const double params[][MRVI_LAW_MAX_PARAMS] = {
      {1.25, 4}, {0.7, 2}, {-0.3, 3}, {2.0, 1}, {1.0, 2.5}};
  const double strains[] = {0.3, 1.7, -0.8, 0.05};
  for (int i = 0; i < mrvi_law_count(); i++) {
    const mrvi_law *law = mrvi_law_get(i);
    for (size_t a = 0; a < sizeof params / sizeof params[0]; a++)
      for (size_t b = 0; b < sizeof strains / sizeof strains[0]; b++) {
        double s = strains[b];
        if (params[a][1] != floor(params[a][1]) && s <= 0)
          continue; /* real exponents are defined for s > 0 only */
        const double h = 1e-5;
        double f, df, ddf, fp, dfp, ddfp, fm, dfm, ddfm;
        law->eval(params[a], s, &f, &df, &ddf);
        law->eval(params[a], s + h, &fp, &dfp, &ddfp);
        law->eval(params[a], s - h, &fm, &dfm, &ddfm);
        const double tol = 1e-7 * (1 + fabs(df) + fabs(ddf) + fabs(f));
        CHECK_NEAR(df, (fp - fm) / (2 * h), tol, law->name);
        CHECK_NEAR(ddf, (dfp - dfm) / (2 * h), tol, law->name);
      }
  }
}

/* Gradient and Hessian of every element of a model against central FD of
 * the element energy, at a perturbed configuration. */
static void check_elements(mrvi_model *m, const char *what) {
  double y[MRVI_MAX_INPUTS], g[MRVI_MAX_INPUTS], yp[MRVI_MAX_INPUTS];
  double H[MRVI_MAX_INPUTS * MRVI_MAX_INPUTS], gp[MRVI_MAX_INPUTS],
      gm[MRVI_MAX_INPUTS];
  srand(7);
  for (int ei = 0; ei < m->n_elements; ei++) {
    const mrvi_element *e = &m->elements[ei];
    const int n = e->n_in;
    if (n > MRVI_MAX_INPUTS)
      continue;
    for (int j = 0; j < n; j++)
      y[j] = m->q0[e->in[j]] + 0.1 * (rand() / (double)RAND_MAX - 0.5);
    mrvi_element_eval(m, e, y, g, e->kind == MRVI_ELEMENT_GRAVITY ? NULL : H);
    const double h = 1e-5;
    for (int j = 0; j < n; j++) {
      memcpy(yp, y, (size_t)n * sizeof *y);
      yp[j] = y[j] + h;
      const double fp = mrvi_element_eval(m, e, yp, gp, NULL);
      yp[j] = y[j] - h;
      const double fm = mrvi_element_eval(m, e, yp, gm, NULL);
      const double tol = 1e-6 * (1 + fabs(g[j]));
      CHECK_NEAR(g[j], (fp - fm) / (2 * h), tol, what);
      if (e->kind == MRVI_ELEMENT_GRAVITY)
        continue;
      for (int l = 0; l < n; l++)
        CHECK_NEAR(H[l * n + j], (gp[l] - gm[l]) / (2 * h),
                   1e-6 * (1 + fabs(H[l * n + j])), what);
    }
  }
}

/* Model potential gradient/Hessian (summed over elements) against FD. */
static void check_potential(mrvi_model *m, const char *what) {
  const int n = m->n;
  double *q = calloc((size_t)n, sizeof *q), *g = calloc((size_t)n, sizeof *g);
  double *H = calloc((size_t)n * n, sizeof *H);
  double *gp = calloc((size_t)n, sizeof *gp), *gm = calloc((size_t)n, sizeof *gm);
  for (int c = 0; c < 2; c++) {
    for (int i = 0; i < n; i++)
      q[i] = m->q0[i] + 0.05 * sin(3.0 * i + c);
    memset(g, 0, (size_t)n * sizeof *g);
    memset(H, 0, (size_t)n * n * sizeof *H);
    mrvi_model_potential(m, (mrvi_rate)c, q, g, H);
    const double h = 1e-5;
    for (int j = 0; j < n; j++) {
      const double qj = q[j];
      memset(gp, 0, (size_t)n * sizeof *gp);
      memset(gm, 0, (size_t)n * sizeof *gm);
      q[j] = qj + h;
      const double fp = mrvi_model_potential(m, (mrvi_rate)c, q, gp, NULL);
      q[j] = qj - h;
      const double fm = mrvi_model_potential(m, (mrvi_rate)c, q, gm, NULL);
      q[j] = qj;
      CHECK_NEAR(g[j], (fp - fm) / (2 * h), 1e-6 * (1 + fabs(g[j])), what);
      for (int i = 0; i < n; i++)
        CHECK_NEAR(H[i * n + j], (gp[i] - gm[i]) / (2 * h),
                   1e-6 * (1 + fabs(H[i * n + j])), what);
    }
  }
  free(q);
  free(g);
  free(H);
  free(gp);
  free(gm);
}

/* A spring at zero length with zero rest length (the spring ring's anchors
 * start away from it, but a run may pass through): the limit phi'' I. */
static void check_zero_length(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  const double x[2] = {0, 0}, v[2] = {0, 0}, k[1] = {3.0};
  mrvi_model_add_particle(m, "a", 1.0, MRVI_FAST, x, v);
  mrvi_model_add_anchor_spring(m, MRVI_FAST, 0, x, "linear", k, 0.0);
  double g[2] = {0, 0}, H[4] = {0, 0, 0, 0};
  mrvi_model_potential(m, MRVI_FAST, x, g, H);
  CHECK(g[0] == 0 && g[1] == 0, "zero-length gradient is zero");
  CHECK(H[0] == 3 && H[3] == 3 && H[1] == 0 && H[2] == 0,
        "zero-length Hessian is k I");
  mrvi_model_free(m);
}

/* Distance springs in 1-D and 2-D and a particle-particle spring with a
 * rest length, so every element kind meets every dimension. */
static mrvi_model *mixed_model(int dim) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, dim);
  const double x1[3] = {0.3, -0.2, 0.5}, x2[3] = {1.1, 0.4, -0.3},
               v[3] = {0, 0, 0}, anchor[3] = {-0.5, 0.2, 0.1};
  mrvi_model_add_particle(m, "a", 1.0, MRVI_SLOW, x1, v);
  mrvi_model_add_particle(m, "b", 2.0, MRVI_FAST, x2, v);
  const double pw[2] = {0.8, 3}, k[1] = {5.0}, pr[2] = {1.0, 2.5};
  mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "power", pw, 0.4);
  mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "power", pr, 0.2);
  mrvi_model_add_anchor_spring(m, MRVI_FAST, 1, anchor, "linear", k, 0.7);
  const double g[3] = {0.1, -9.81, 0.3};
  mrvi_model_set_gravity(m, g);
  return m;
}

int main(void) {
  check_laws();
  mrvi_model *fpu = test_fpu(), *ring = test_spring_ring();
  check_elements(fpu, "fpu element");
  check_elements(ring, "spring ring element");
  check_potential(fpu, "fpu potential");
  check_potential(ring, "spring ring potential");
  for (int d = 1; d <= 3; d++) {
    mrvi_model *m = mixed_model(d);
    check_elements(m, "mixed element");
    check_potential(m, "mixed potential");
    mrvi_model_free(m);
  }
  check_zero_length();
  mrvi_model_free(fpu);
  mrvi_model_free(ring);
  return test_finish();
}
