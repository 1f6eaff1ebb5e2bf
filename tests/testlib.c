#include "testlib.h"

#include <math.h>
#include <stdarg.h>
#include <stdlib.h>

int test_passed = 0, test_failed = 0;

void test_check(int ok, const char *file, int line, const char *fmt, ...) {
  /* MRVI_TEST_VERBOSE=1 prints passing checks too (with their figures). */
  static int verbose = -1;
  if (verbose < 0)
    verbose = getenv("MRVI_TEST_VERBOSE") != NULL;
  if (ok)
    test_passed++;
  else
    test_failed++;
  if (ok && !verbose)
    return;
  va_list ap;
  va_start(ap, fmt);
  fprintf(stderr, "%s:%d: %s: ", file, line, ok ? "ok" : "FAIL");
  vfprintf(stderr, fmt, ap);
  fputc('\n', stderr);
  va_end(ap);
}

int test_finish(void) {
  printf("%d passed, %d failed\n", test_passed, test_failed);
  return test_failed == 0 && test_passed > 0 ? 0 : 1;
}

/* Built with AddressSanitizer: GCC's macro, Clang's feature test. */
#if defined(__SANITIZE_ADDRESS__)
#define SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
#define SANITIZED 1
#endif
#endif
#ifndef SANITIZED
#define SANITIZED 0
#endif

long test_steps(long n) {
  if (!SANITIZED || getenv("MRVI_TEST_FULL"))
    return n;
  return n / 10 > 10 ? n / 10 : 10;
}

const char *test_source_path(const char *relative) {
  static char buf[4096];
  const char *root = getenv("MRVI_SOURCE_ROOT");
  snprintf(buf, sizeof buf, "%s/%s", root ? root : "..", relative);
  return buf;
}

void test_rotation(const double *w, double t, double *R) {
  const double a = t * sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
  double k[3] = {0, 0, 0};
  if (a > 0)
    for (int i = 0; i < 3; i++)
      k[i] = w[i] * t / a;
  const double K[9] = {0, -k[2], k[1], k[2], 0, -k[0], -k[1], k[0], 0};
  for (int i = 0; i < 3; i++)
    for (int j = 0; j < 3; j++) {
      double K2 = 0.0;
      for (int l = 0; l < 3; l++)
        K2 += K[i * 3 + l] * K[l * 3 + j];
      R[i * 3 + j] = (i == j) + sin(a) * K[i * 3 + j] + (1 - cos(a)) * K2;
    }
}

void test_ocp_gradients(mrvi_ocp *o, const char *what, double amplitude) {
  const int n = mrvi_ocp_n_controls(o), m = mrvi_ocp_n_constraints(o);
  double *u = malloc((size_t)n * sizeof *u), *g = malloc((size_t)n * sizeof *g);
  double *cg = malloc((size_t)(m * n + 1) * sizeof *cg);
  double *cp = malloc((size_t)(m + 1) * sizeof *cp);
  double *cm = malloc((size_t)(m + 1) * sizeof *cm);
  for (int i = 0; i < n; i++)
    u[i] = amplitude * sin(1.7 * i + 0.3);
  double J;
  int st = mrvi_ocp_evaluate(o, u, &J, g, cp, cg);
  CHECK(st == 0, "%s: evaluate: %s", what, mrvi_ocp_errmsg(o));
  double errJ = 0, scJ = 0, errC = 0, scC = 0;
  for (int i = 0; i < n && st == 0; i++) {
    const double h = 1e-5, ui = u[i];
    double Jp, Jm;
    u[i] = ui + h;
    st |= mrvi_ocp_evaluate(o, u, &Jp, NULL, cp, NULL);
    u[i] = ui - h;
    st |= mrvi_ocp_evaluate(o, u, &Jm, NULL, cm, NULL);
    u[i] = ui;
    const double fd = (Jp - Jm) / (2 * h);
    errJ = fmax(errJ, fabs(fd - g[i]));
    scJ = fmax(scJ, fabs(fd));
    for (int j = 0; j < m; j++) {
      const double fc = (cp[j] - cm[j]) / (2 * h);
      errC = fmax(errC, fabs(fc - cg[j * n + i]));
      scC = fmax(scC, fabs(fc));
    }
  }
  printf("%s: %d controls, %d constraints: gradient error cost %.2e, "
         "constraints %.2e (relative)\n",
         what, n, m, scJ > 0 ? errJ / scJ : 0.0, scC > 0 ? errC / scC : 0.0);
  CHECK(st == 0 && scJ > 0 && errJ <= 1e-6 * scJ,
        "%s: cost gradient error %.3e (scale %.3e)", what, errJ, scJ);
  CHECK(m == 0 || (scC > 0 && errC <= 1e-6 * scC),
        "%s: constraint gradient error %.3e (scale %.3e)", what, errC, scC);
  free(u);
  free(g);
  free(cg);
  free(cp);
  free(cm);
}

void test_ocp_same_forward(mrvi_ocp *o, mrvi_ocp *og, int n_coords,
                           const char *what, double amplitude, double tol) {
  const int n = mrvi_ocp_n_controls(o), m = mrvi_ocp_n_constraints(o);
  const long nq = (mrvi_ocp_n_steps(o) + 1) * n_coords;
  double *u = malloc((size_t)n * sizeof *u);
  double *c = malloc((size_t)(2 * m + 2) * sizeof *c), *cg = c + m + 1;
  for (int i = 0; i < n; i++)
    u[i] = amplitude * sin(1.7 * i + 0.3);
  double J = 0.0, Jg = 0.0;
  const int st = mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL);
  const int sg = mrvi_ocp_evaluate(og, u, &Jg, NULL, cg, NULL);
  CHECK(st == 0 && sg == 0 && n == mrvi_ocp_n_controls(og) &&
            m == mrvi_ocp_n_constraints(og),
        "%s: evaluate: %s / %s", what, mrvi_ocp_errmsg(o), mrvi_ocp_errmsg(og));
  double dc = 0.0, sc = 0.0, dq = 0.0, sq = 0.0;
  for (int j = 0; j < m && st == 0 && sg == 0; j++) {
    dc = fmax(dc, fabs(c[j] - cg[j]));
    sc = fmax(sc, fabs(cg[j]));
  }
  const double *q = mrvi_ocp_q(o), *qg = mrvi_ocp_q(og);
  for (long i = 0; i < nq && st == 0 && sg == 0; i++) {
    dq = fmax(dq, fabs(q[i] - qg[i]));
    sq = fmax(sq, fabs(qg[i]));
  }
  printf("%s: cost %.15g against %.15g, constraints differ by %.2e, "
         "positions by %.2e\n",
         what, J, Jg, dc, dq);
  CHECK(fabs(J - Jg) <= tol * fabs(Jg) && dc <= tol * fmax(sc, 1.0) &&
            dq <= tol * sq,
        "%s: forward runs differ: cost %.17g / %.17g, constraints %.3e, "
        "positions %.3e",
        what, J, Jg, dc, dq);
  free(u);
  free(c);
}
