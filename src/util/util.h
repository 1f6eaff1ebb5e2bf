/* What src/util/ offers every layer above it: messages and statuses,
 * name suggestions, the clock and the machine's memory, limits, dense LU and
 * QR (status.c, suggest.c, dense.c). */
#ifndef MRVI_UTIL_H
#define MRVI_UTIL_H

#include "mrvi.h"

#include <stdarg.h>

#ifndef M_PI /* not in strict C11 */
#define M_PI 3.14159265358979323846
#endif

/* printf into a caller buffer (NULL-safe, always terminated). */
void mrvi_fmt(char *buf, size_t len, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
void mrvi_vfmt(char *buf, size_t len, const char *fmt, va_list ap);
/* Write a message into msg and return status (for `return mrvi_fail(...)`). */
int mrvi_fail(char *msg, size_t len, int status, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

/* The candidate (of n) closest to `word` by edit distance if it is close
 * enough to be a likely typo, else NULL; ties go to the longer common
 * prefix (suggest.c). */
const char *mrvi_closest(const char *word, const char *const *cand, int n);

/* Wall clock in seconds (monotonic). */
double mrvi_clock(void);
/* The machine's physical memory in bytes (0 when unknown): sizes needing
 * more are refused before allocation.  A build may lower it with
 * -DMRVI_MEMORY_CAP=BYTES (the fuzz build does, so that what the checks
 * admit fits the fuzzer's memory limit; tests/fuzz/run.sh). */
double mrvi_machine_memory(void);
/* Threads (OpenMP, meson option `openmp`; doc/performance/threads.md,
 * "Threads"): the processors this process may run on (its affinity mask), and
 * the count a setting asks for (0: that) capped to 1 in a build without OpenMP.
 * MRVI_PARALLEL_FOR(t): the next loop on t threads, its iterations split
 * statically; a plain loop without OpenMP.  The loops so marked write disjoint
 * data and combine nothing: no reductions, so results do not depend on the
 * number of threads. */
int mrvi_cores(void);
/* The tasks runnable now besides this one: the first number of the fourth
 * field of /proc/loadavg (running/total, the reader included) less one;
 * -1 where it cannot be read (not Linux). */
int mrvi_tasks_others(void);
/* The cores of mrvi_cores() that no other task is running on now (at
 * least 1; all of them where mrvi_tasks_others cannot tell): what `--threads
 * auto` and `mrvi batch` fill (doc/performance/threads.md, "The automatic
 * thread count"). */
int mrvi_cores_idle(void);
int mrvi_threads_resolve(int requested);
#ifdef _OPENMP
#define MRVI_PRAGMA(x) _Pragma(#x)
#define MRVI_PARALLEL_FOR(t)                                                   \
  MRVI_PRAGMA(omp parallel for num_threads(t) schedule(static))
#else
#define MRVI_PARALLEL_FOR(t)
#endif
/* Particles one `generate:` entry may make (the fuzz build lowers it). */
#ifndef MRVI_MAX_GENERATED
#define MRVI_MAX_GENERATED 10000000
#endif
/* Coordinates a description's model may reach through its `generate:`
 * entries when its `limits.max_coordinates` is absent: 10^7, ten times the
 * largest network the benchmarks run, on every machine alike
 * (doc/description-files.md, "Limits"). */
#ifndef MRVI_MAX_COORDINATES
#define MRVI_MAX_COORDINATES 10000000
#endif
/* The memory, in GiB, a description's model and its integrator's step may
 * take by the loader's estimates when its `limits.max_memory` is absent:
 * the same on every machine (doc/description-files.md, "Limits"); 16 GiB
 * is 64 bytes (the step's eight vectors) for each of the 2^28 micro
 * unknowns the loader admits.  A build with -DMRVI_MEMORY_CAP=BYTES (the
 * fuzz build) also caps a limit the file raises. */
#ifndef MRVI_MAX_MEMORY_GIB
#define MRVI_MAX_MEMORY_GIB 16
#endif

/* Dense helpers (dense.c).  Solve A x = b in place (A n x n row-major,
 * overwritten; b becomes x); -1 if singular. */
int mrvi_dense_solve(int n, double *A, double *b);
/* LU with partial pivoting of A (n x n row-major) in place, pivots in piv
 * (n); -1 if singular.  mrvi_dense_lu_solve: b (n x nrhs row-major)
 * becomes A^-1 b.  The small blocks of the structured step solvers. */
int mrvi_dense_lu_factor(int n, double *A, int *piv);
/* The same factorisation (the same arithmetic) updating only the nonzero
 * columns of each pivot row: for matrices with many zeros (nzc: workspace
 * of n). */
int mrvi_dense_lu_factor_nz(int n, double *A, int *piv, int *nzc);
/* Indices 0..n-1 sorted by their degrees deg, ascending and stable (ties
 * in index order): order[k] the k-th, pos[i] the rank of index i (the
 * elimination order of the dense LUs of Newton matrices: fewer fill). */
void mrvi_degree_order(int n, const int *deg, int *order, int *pos);
/* The root of a in the union-find forest up (up[a] == a at a root),
 * halving the path on the way (the cycle tests of the forests of joints,
 * rods and fast springs). */
int mrvi_uf_root(int *up, int a);
/* R (3 x 3, row-major) <- the rotation of the unit quaternion
 * w + x i + y j + z k: R = (w^2 - |v|^2) I + 2 v v^T + 2 w [v]x. */
void mrvi_quaternion_rotation(double w, double x, double y, double z,
                              double *R);
/* Step k of that factorisation's pivoting: the largest |A_ik|, i >= k, its
 * row in piv[k] and swapped with row k; -1 if that column is zero. */
int mrvi_dense_lu_pivot(int n, double *A, int *piv, int k);
void mrvi_dense_lu_solve(int n, const double *A, const int *piv, double *b,
                         int nrhs);
/* The same with A^T: b (n x nrhs row-major) becomes A^-T b. */
void mrvi_dense_lu_solve_transpose(int n, const double *A, const int *piv,
                                   double *b, int nrhs);
#define MRVI_DENSE_MAX 256
/* Householder QR of A (m x n row-major, m <= MRVI_DENSE_MAX): A is
 * overwritten with R in its upper triangle, Q (m x m row-major) is explicit
 * and orthogonal; A = Q R.  Returns -1 if a column is (numerically) in the
 * span of the previous ones. */
int mrvi_dense_qr(int m, int n, double *A, double *Q);
/* Rank-revealing step of modified Gram-Schmidt (two passes): v (n
 * entries, overwritten) against the k orthonormal rows of B.  If the part
 * of v outside their span is larger than rtol |v|, it is normalised into
 * B's row k (v may be that row) and 1 returned; else (v numerically in the
 * span, or zero) 0. */
int mrvi_dense_extend_basis(int n, double *B, int k, double *v, double rtol);

#endif
