/* Pairs of doubles: the one place where mrvi uses machine-specific
 * instructions (doc/performance/kernels.md, "Specialised kernels").
 *
 * With MRVI_SIMD = 1 (the default wherever the compiler offers SSE2, i.e.
 * on x86-64) an mrvi_v2 is one SSE2 register and each operation one SSE2
 * instruction; with MRVI_SIMD = 0 (meson -Dsimd=false, or anywhere else)
 * it is a struct of two doubles and each operation plain C.  Every
 * operation works lane by lane with the scalar IEEE operation of that
 * lane, in the same order in both, so the two give the same results bit
 * for bit (tests/compare_builds.sh, run in CI, compares the trajectories
 * of shipped systems). */
#ifndef MRVI_UTIL_SIMD_H
#define MRVI_UTIL_SIMD_H

#ifndef MRVI_SIMD
#if defined(__SSE2__)
#define MRVI_SIMD 1
#else
#define MRVI_SIMD 0
#endif
#endif

#if defined(__GNUC__)
#define MRVI_V2_INLINE static inline __attribute__((always_inline))
#else
#define MRVI_V2_INLINE static inline
#endif

#if MRVI_SIMD
#include <emmintrin.h>

typedef __m128d mrvi_v2;

/* {p[0], p[1]} (no alignment assumed) */
MRVI_V2_INLINE mrvi_v2 v2_load(const double *p) { return _mm_loadu_pd(p); }
/* p[0], p[1] = v (no alignment assumed) */
MRVI_V2_INLINE void v2_store(double *p, mrvi_v2 v) { _mm_storeu_pd(p, v); }
/* {lo, hi} */
MRVI_V2_INLINE mrvi_v2 v2_set(double lo, double hi) {
  return _mm_set_pd(hi, lo);
}
MRVI_V2_INLINE mrvi_v2 v2_zero(void) { return _mm_setzero_pd(); }
MRVI_V2_INLINE double v2_lo(mrvi_v2 v) { return _mm_cvtsd_f64(v); }
MRVI_V2_INLINE double v2_hi(mrvi_v2 v) {
  return _mm_cvtsd_f64(_mm_unpackhi_pd(v, v));
}
/* a + b, a - b, a * b, a / b lane by lane */
MRVI_V2_INLINE mrvi_v2 v2_add(mrvi_v2 a, mrvi_v2 b) { return _mm_add_pd(a, b); }
MRVI_V2_INLINE mrvi_v2 v2_sub(mrvi_v2 a, mrvi_v2 b) { return _mm_sub_pd(a, b); }
MRVI_V2_INLINE mrvi_v2 v2_mul(mrvi_v2 a, mrvi_v2 b) { return _mm_mul_pd(a, b); }
MRVI_V2_INLINE mrvi_v2 v2_div(mrvi_v2 a, mrvi_v2 b) { return _mm_div_pd(a, b); }
/* s * v, each lane */
MRVI_V2_INLINE mrvi_v2 v2_scale(double s, mrvi_v2 v) {
  return _mm_mul_pd(_mm_set1_pd(s), v);
}
/* |v| (the sign bit cleared), each lane */
MRVI_V2_INLINE mrvi_v2 v2_abs(mrvi_v2 v) {
  return _mm_andnot_pd(_mm_set1_pd(-0.0), v);
}
/* a > b ? a : b, each lane (b if either is NaN) */
MRVI_V2_INLINE mrvi_v2 v2_max(mrvi_v2 a, mrvi_v2 b) { return _mm_max_pd(a, b); }
/* sqrt(v), each lane (the correctly rounded root, as sqrt) */
MRVI_V2_INLINE mrvi_v2 v2_sqrt(mrvi_v2 v) { return _mm_sqrt_pd(v); }
/* c > 0 ? v : 0, each lane (0 where c is NaN) */
MRVI_V2_INLINE mrvi_v2 v2_pos_or_zero(mrvi_v2 c, mrvi_v2 v) {
  return _mm_and_pd(_mm_cmpgt_pd(c, _mm_setzero_pd()), v);
}

#else
#include <math.h>

typedef struct {
  double lo, hi;
} mrvi_v2;

MRVI_V2_INLINE mrvi_v2 v2_load(const double *p) {
  const mrvi_v2 r = {p[0], p[1]};
  return r;
}
MRVI_V2_INLINE void v2_store(double *p, mrvi_v2 v) {
  p[0] = v.lo;
  p[1] = v.hi;
}
MRVI_V2_INLINE mrvi_v2 v2_set(double lo, double hi) {
  const mrvi_v2 r = {lo, hi};
  return r;
}
MRVI_V2_INLINE mrvi_v2 v2_zero(void) { return v2_set(0.0, 0.0); }
MRVI_V2_INLINE double v2_lo(mrvi_v2 v) { return v.lo; }
MRVI_V2_INLINE double v2_hi(mrvi_v2 v) { return v.hi; }
MRVI_V2_INLINE mrvi_v2 v2_add(mrvi_v2 a, mrvi_v2 b) {
  return v2_set(a.lo + b.lo, a.hi + b.hi);
}
MRVI_V2_INLINE mrvi_v2 v2_sub(mrvi_v2 a, mrvi_v2 b) {
  return v2_set(a.lo - b.lo, a.hi - b.hi);
}
MRVI_V2_INLINE mrvi_v2 v2_mul(mrvi_v2 a, mrvi_v2 b) {
  return v2_set(a.lo * b.lo, a.hi * b.hi);
}
MRVI_V2_INLINE mrvi_v2 v2_div(mrvi_v2 a, mrvi_v2 b) {
  return v2_set(a.lo / b.lo, a.hi / b.hi);
}
MRVI_V2_INLINE mrvi_v2 v2_scale(double s, mrvi_v2 v) {
  return v2_set(s * v.lo, s * v.hi);
}
MRVI_V2_INLINE mrvi_v2 v2_abs(mrvi_v2 v) {
  return v2_set(fabs(v.lo), fabs(v.hi));
}
MRVI_V2_INLINE mrvi_v2 v2_max(mrvi_v2 a, mrvi_v2 b) {
  return v2_set(a.lo > b.lo ? a.lo : b.lo, a.hi > b.hi ? a.hi : b.hi);
}
MRVI_V2_INLINE mrvi_v2 v2_sqrt(mrvi_v2 v) {
  return v2_set(sqrt(v.lo), sqrt(v.hi));
}
MRVI_V2_INLINE mrvi_v2 v2_pos_or_zero(mrvi_v2 c, mrvi_v2 v) {
  return v2_set(c.lo > 0.0 ? v.lo : 0.0, c.hi > 0.0 ? v.hi : 0.0);
}
#endif

#endif
