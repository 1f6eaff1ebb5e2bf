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
