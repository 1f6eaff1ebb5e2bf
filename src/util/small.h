/* Small-block kernels of the structured step solvers (doc/solver.md,
 * "Evaluation"). */
#ifndef MRVI_UTIL_SMALL_H
#define MRVI_UTIL_SMALL_H

#include <string.h>

/* Small-block kernels.  SMALL(n, N, code) runs code with N an integer
 * constant equal to n for n = 1..4, so that the compiler unrolls the loops
 * over the tiny blocks of few-body systems (the FPU: ns = nf = 3), and with
 * N = n otherwise.  The kernels are inlined into each case. */
/* -DMRVI_SMALL_KERNELS=0 (meson -Dsmall_kernels=false) keeps only the
 * run-time-size case: the same arithmetic in the same order, so the same
 * results bit for bit (tests/compare_builds.sh, in CI), compiled in a
 * fraction of the time.  clang with ASan + UBSan +
 * libFuzzer instrumentation needs over 10 minutes and 2.6 GB for the
 * unrolled cases of blocks.c (1 s without them); tests/fuzz/run.sh sets it. */
#ifndef MRVI_SMALL_KERNELS
#define MRVI_SMALL_KERNELS 1
#endif
#if !MRVI_SMALL_KERNELS
#define ALWAYS_INLINE static inline
#define UNROLL
#define UNROLL2
#define UNROLL_ALL
#define SMALL(n, N, ...)                                                       \
  do {                                                                         \
    const int N = (n);                                                         \
    __VA_ARGS__;                                                               \
  } while (0)
#define SMALL2(ns, NS, nf, NF, ...)                                            \
  do {                                                                         \
    const int NS = (ns), NF = (nf);                                            \
    __VA_ARGS__;                                                               \
  } while (0)
/* (the callers of SMALL4 and SMALL2_ONLY test MRVI_SMALL_KERNELS: nothing
 * to compile) */
#define SMALL2_ONLY(ns, NS, nf, NF, ...)                                       \
  do {                                                                         \
  } while (0)
#define SMALL2_SIZE(ns, nf) 0
#define SMALL4(n, N, ...)                                                      \
  do {                                                                         \
  } while (0)
#else
#define ALWAYS_INLINE static inline __attribute__((always_inline))
#define UNROLL _Pragma("GCC unroll 4")
/* two iterations per pass of a loop of run-time length (the same
 * operations in the same order, half the loop control) */
#define UNROLL2 _Pragma("GCC unroll 2")
/* a loop of constant length unrolled in full (up to 64 iterations) */
#define UNROLL_ALL _Pragma("GCC unroll 64")
/* The cases n = 1..4 of SMALL and SMALL4, N an integer constant. */
#define SMALL_CASES(N, ...)                                                    \
  case 1: {                                                                    \
    enum { N = 1 };                                                            \
    __VA_ARGS__;                                                               \
  } break;                                                                     \
  case 2: {                                                                    \
    enum { N = 2 };                                                            \
    __VA_ARGS__;                                                               \
  } break;                                                                     \
  case 3: {                                                                    \
    enum { N = 3 };                                                            \
    __VA_ARGS__;                                                               \
  } break;                                                                     \
  case 4: {                                                                    \
    enum { N = 4 };                                                            \
    __VA_ARGS__;                                                               \
  } break;
#define SMALL(n, N, ...)                                                       \
  switch (n) {                                                                 \
    SMALL_CASES(N, __VA_ARGS__)                                                \
  default: {                                                                   \
    const int N = (n);                                                         \
    __VA_ARGS__;                                                               \
  } break;                                                                     \
  }
/* SMALL2(ns, NS, nf, NF, code): a kernel of both block sizes, specialised
 * for one size: NS and NF integer constants where ns = nf = 1 or 3 (the
 * double integrator, the FPU), both at run time otherwise.  SMALL over each
 * size (the product, 25 cases) cost compile time and code for no speed a
 * benchmark measures (doc/performance/kernels.md, "Specialised kernels"). */
#define SMALL2_CASE(K, NS, NF, ...)                                            \
  case K: {                                                                    \
    enum { NS = K, NF = K };                                                   \
    __VA_ARGS__;                                                               \
  } break;
#define SMALL2(ns, NS, nf, NF, ...)                                            \
  switch ((ns) == (nf) ? (nf) : 0) {                                           \
    SMALL2_CASE(1, NS, NF, __VA_ARGS__)                                        \
    SMALL2_CASE(3, NS, NF, __VA_ARGS__)                                        \
  default: {                                                                   \
    const int NS = (ns), NF = (nf);                                            \
    __VA_ARGS__;                                                               \
  } break;                                                                     \
  }
/* SMALL2's specialised cases only (nothing otherwise): the kernels whose
 * local arrays need constant sizes (the caller checks SMALL2_SIZE). */
#define SMALL2_SIZE(ns, nf) ((ns) == (nf) && ((nf) == 1 || (nf) == 3))
#define SMALL2_ONLY(ns, NS, nf, NF, ...)                                       \
  switch ((ns) == (nf) ? (nf) : 0) {                                           \
    SMALL2_CASE(1, NS, NF, __VA_ARGS__)                                        \
    SMALL2_CASE(3, NS, NF, __VA_ARGS__)                                        \
  default:                                                                     \
    break;                                                                     \
  }
/* SMALL for n = 1..4 only (nothing otherwise): the kernels whose local
 * arrays have the small sizes' bound (the caller checks n). */
#define SMALL4(n, N, ...)                                                      \
  switch (n) {                                                                 \
    SMALL_CASES(N, __VA_ARGS__)                                                \
  default:                                                                     \
    break;                                                                     \
  }
#endif

/* a[0..n) = 0.  With n constant (nz x nz of a point's Hessian, up to 64
 * entries), GCC stores vectors in line: `memset`, inlined for a fixed size,
 * became `rep stos`, whose start-up cost exceeds the few stores. */
ALWAYS_INLINE void zero_k(double *restrict a, const int n) {
  UNROLL_ALL for (int i = 0; i < n; i++) a[i] = 0.0;
}

/* out[lo..nz) = g0 + Hq z on the rows and columns lo..nz-1 (g0: nz, Hq:
 * nz x nz), or with add out += that: the gradient of a class whose Hessian
 * is constant (quadratic terms) and zero outside those rows and columns,
 * as an affine map, a few products instead of a pass over its terms
 * (round-off apart, the same). */
ALWAYS_INLINE void affine_k(const double *restrict g0,
                            const double *restrict Hq, const double *restrict z,
                            double *restrict out, const int lo, const int nz,
                            const int add) {
  UNROLL for (int i = lo; i < nz; i++) {
    double t = g0[i];
    UNROLL for (int j = lo; j < nz; j++) t += Hq[i * nz + j] * z[j];
    out[i] = add ? out[i] + t : t;
  }
}

/* G[lo..nz) += g0 + Hq z (affine_k). */
ALWAYS_INLINE void affine_grad_k(const double *restrict g0,
                                 const double *restrict Hq,
                                 const double *restrict z, double *restrict G,
                                 const int lo, const int nz) {
  affine_k(g0, Hq, z, G, lo, nz, 1);
}

#endif
