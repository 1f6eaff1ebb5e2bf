/* Minimal test harness shared by the mrvi tests.
 *
 * CHECK(cond, fmt, ...) records one assertion; CHECK_NEAR(a, b, tol, what)
 * checks |a - b| <= tol.  test_finish() prints "N passed, M failed" and
 * returns the exit code for main. */
#ifndef MRVI_TESTLIB_H
#define MRVI_TESTLIB_H

#include "ocp/ocp.h"

#include <stdio.h>

extern int test_passed, test_failed;

void test_check(int ok, const char *file, int line, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

#define CHECK(cond, ...) test_check(!!(cond), __FILE__, __LINE__, __VA_ARGS__)
#define CHECK_NEAR(a, b, tol, what)                                            \
  do {                                                                         \
    double a_ = (a), b_ = (b), t_ = (tol);                                     \
    test_check(a_ - b_ <= t_ && b_ - a_ <= t_, __FILE__, __LINE__,             \
               "%s: %.17g vs %.17g (tol %.3g)", (what), a_, b_, t_);           \
  } while (0)

int test_finish(void);

/* Steps of a long run: n, or n / 10 (at least 10) in a build with
 * AddressSanitizer (CI's build-san, .ci/run), where a step costs several
 * times as much and a long run repeats the code paths of its first steps;
 * the plain build checks the full length.  MRVI_TEST_FULL=1 keeps n. */
long test_steps(long n);

/* Path of a file under the source tree ($MRVI_SOURCE_ROOT, else ".."). */
const char *test_source_path(const char *relative);

/* R (3 x 3, row-major): the rotation by the angle |w| t about w
 * (Rodrigues: R = I + sin(a) K + (1 - cos a) K^2, K the cross-product
 * matrix of the unit axis); the identity for w = 0. */
void test_rotation(const double *w, double t, double *R);

/* Checks the gradients of the cost and of the constraints that
 * mrvi_ocp_evaluate returns against central differences (h = 1e-5) at
 * u_i = amplitude sin(1.7 i + 0.3): each within 1e-6 of its scale (the
 * largest difference quotient); prints the relative errors. */
void test_ocp_gradients(mrvi_ocp *o, const char *what, double amplitude);
/* Evaluates o and og (the same problem, og on another step solver path)
 * at the controls of test_ocp_gradients: cost, constraints and the macro
 * positions (n_coords a node) agree within tol relative to their largest
 * magnitude; prints the differences. */
void test_ocp_same_forward(mrvi_ocp *o, mrvi_ocp *og, int n_coords,
                           const char *what, double amplitude, double tol);

#endif
