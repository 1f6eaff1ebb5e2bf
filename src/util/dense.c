/* Small dense linear algebra for constraint blocks (a few rows each):
 * Gaussian elimination and a Householder QR with explicit Q. */
#include "util/util.h"

#include <math.h>
#include <string.h>

int mrvi_dense_solve(int n, double *A, double *b) {
  for (int k = 0; k < n; k++) {
    int piv = k;
    for (int i = k + 1; i < n; i++)
      if (fabs(A[i * n + k]) > fabs(A[piv * n + k]))
        piv = i;
    if (!(fabs(A[piv * n + k]) > 0.0))
      return -1;
    if (piv != k) {
      for (int j = 0; j < n; j++) {
        const double t = A[k * n + j];
        A[k * n + j] = A[piv * n + j];
        A[piv * n + j] = t;
      }
      const double t = b[k];
      b[k] = b[piv];
      b[piv] = t;
    }
    for (int i = k + 1; i < n; i++) {
      const double f = A[i * n + k] / A[k * n + k];
      if (f == 0.0)
        continue;
      for (int j = k; j < n; j++)
        A[i * n + j] -= f * A[k * n + j];
      b[i] -= f * b[k];
    }
  }
  for (int i = n - 1; i >= 0; i--) {
    double s = b[i];
    for (int j = i + 1; j < n; j++)
      s -= A[i * n + j] * b[j];
    b[i] = s / A[i * n + i];
  }
  return 0;
}

int mrvi_dense_qr(int m, int n, double *A, double *Q) {
  /* Q starts as the identity and accumulates the reflectors H_0 ... H_{n-1}
   * so that A = Q R with R in the upper triangle of A. */
  for (int i = 0; i < m; i++)
    for (int j = 0; j < m; j++)
      Q[i * m + j] = i == j ? 1.0 : 0.0;
  double scale = 0.0;
  for (int i = 0; i < m * n; i++)
    scale = fmax(scale, fabs(A[i]));
  int rank_ok = 1;
  for (int k = 0; k < n && k < m; k++) {
    double norm = 0.0;
    for (int i = k; i < m; i++)
      norm += A[i * n + k] * A[i * n + k];
    norm = sqrt(norm);
    if (norm <= 1e-12 * scale || norm == 0.0) {
      rank_ok = 0;
      continue;
    }
    const double alpha = A[k * n + k] > 0.0 ? -norm : norm;
    /* v = a - alpha e_k, H = I - 2 v v^T / (v^T v) */
    double v[MRVI_DENSE_MAX];
    double vv = 0.0;
    for (int i = k; i < m; i++) {
      v[i - k] = A[i * n + k] - (i == k ? alpha : 0.0);
      vv += v[i - k] * v[i - k];
    }
    if (vv == 0.0)
      continue;
    for (int j = k; j < n; j++) {
      double s = 0.0;
      for (int i = k; i < m; i++)
        s += v[i - k] * A[i * n + j];
      s *= 2.0 / vv;
      for (int i = k; i < m; i++)
        A[i * n + j] -= s * v[i - k];
    }
    /* Q <- Q H */
    for (int r = 0; r < m; r++) {
      double s = 0.0;
      for (int i = k; i < m; i++)
        s += Q[r * m + i] * v[i - k];
      s *= 2.0 / vv;
      for (int i = k; i < m; i++)
        Q[r * m + i] -= s * v[i - k];
    }
  }
  return rank_ok ? 0 : -1;
}

int mrvi_dense_lu_pivot(int n, double *A, int *piv, int k) {
  int r = k;
  for (int i = k + 1; i < n; i++)
    if (fabs(A[i * n + k]) > fabs(A[r * n + k]))
      r = i;
  piv[k] = r;
  if (!(fabs(A[r * n + k]) > 0.0))
    return -1;
  if (r != k)
    for (int j = 0; j < n; j++) {
      const double t = A[k * n + j];
      A[k * n + j] = A[r * n + j];
      A[r * n + j] = t;
    }
  return 0;
}

/* LU with partial pivoting in place (n x n row-major); -1 if singular. */
int mrvi_dense_lu_factor(int n, double *A, int *piv) {
  for (int k = 0; k < n; k++) {
    if (mrvi_dense_lu_pivot(n, A, piv, k) < 0)
      return -1;
    const double d = 1.0 / A[k * n + k];
    for (int i = k + 1; i < n; i++) {
      const double f = (A[i * n + k] *= d);
      if (f != 0.0)
        for (int j = k + 1; j < n; j++)
          A[i * n + j] -= f * A[k * n + j];
    }
  }
  return 0;
}

int mrvi_uf_root(int *up, int a) {
  while (up[a] != a)
    a = up[a] = up[up[a]];
  return a;
}

void mrvi_quaternion_rotation(double w, double x, double y, double z,
                              double *R) {
  R[0] = 1 - 2 * (y * y + z * z), R[1] = 2 * (x * y - w * z),
  R[2] = 2 * (x * z + w * y);
  R[3] = 2 * (x * y + w * z), R[4] = 1 - 2 * (x * x + z * z),
  R[5] = 2 * (y * z - w * x);
  R[6] = 2 * (x * z - w * y), R[7] = 2 * (y * z + w * x),
  R[8] = 1 - 2 * (x * x + y * y);
}

void mrvi_degree_order(int n, const int *deg, int *order, int *pos) {
  for (int i = 0; i < n; i++) { /* insertion sort */
    int k = i;
    for (; k > 0 && deg[order[k - 1]] > deg[i]; k--)
      order[k] = order[k - 1];
    order[k] = i;
  }
  for (int k = 0; k < n; k++)
    pos[order[k]] = k;
}

int mrvi_dense_lu_factor_nz(int n, double *A, int *piv, int *nzc) {
  for (int k = 0; k < n; k++) {
    if (mrvi_dense_lu_pivot(n, A, piv, k) < 0)
      return -1;
    const double *ak = A + k * n, d = 1.0 / ak[k];
    int nn = 0;
    for (int j = k + 1; j < n; j++)
      if (ak[j] != 0.0)
        nzc[nn++] = j;
    for (int i = k + 1; i < n; i++) {
      double *ai = A + i * n;
      if (ai[k] == 0.0)
        continue;
      const double f = (ai[k] *= d);
      for (int t = 0; t < nn; t++)
        ai[nzc[t]] -= f * ak[nzc[t]];
    }
  }
  return 0;
}

/* Solve with mrvi_dense_lu_factor's factors; b (n x nrhs row-major) becomes x.
 * The factorisation swaps whole rows (P A = L U with L in its final row
 * order), so all row swaps apply to b before the forward substitution. */
/* mrvi_dense_lu_solve with one right-hand side: the same arithmetic
 * without the loops over the columns of b. */
static void lu_solve1(int n, const double *A, const int *piv, double *b) {
  for (int k = 0; k < n; k++)
    if (piv[k] != k) {
      const double t = b[piv[k]];
      b[piv[k]] = b[k];
      b[k] = t;
    }
  for (int k = 0; k < n; k++) {
    const double bk = b[k];
    for (int i = k + 1; i < n; i++) {
      const double f = A[i * n + k];
      if (f != 0.0)
        b[i] -= f * bk;
    }
  }
  for (int i = n - 1; i >= 0; i--) {
    double bi = b[i];
    for (int j = i + 1; j < n; j++) {
      const double u = A[i * n + j];
      if (u != 0.0)
        bi -= u * b[j];
    }
    b[i] = bi / A[i * n + i];
  }
}

void mrvi_dense_lu_solve(int n, const double *A, const int *piv, double *b,
                         int nrhs) {
  if (nrhs == 1) {
    lu_solve1(n, A, piv, b);
    return;
  }
  for (int k = 0; k < n; k++)
    if (piv[k] != k)
      for (int c = 0; c < nrhs; c++) {
        const double t = b[piv[k] * nrhs + c];
        b[piv[k] * nrhs + c] = b[k * nrhs + c];
        b[k * nrhs + c] = t;
      }
  for (int k = 0; k < n; k++) {
    for (int i = k + 1; i < n; i++) {
      const double f = A[i * n + k];
      if (f != 0.0)
        for (int c = 0; c < nrhs; c++)
          b[i * nrhs + c] -= f * b[k * nrhs + c];
    }
  }
  /* Back substitution by rows of b, the nonzeros of U only (each entry
   * of b takes its terms in the order of j as a dot product would). */
  for (int i = n - 1; i >= 0; i--) {
    double *bi = b + i * nrhs;
    for (int j = i + 1; j < n; j++) {
      const double u = A[i * n + j];
      if (u != 0.0)
        for (int c = 0; c < nrhs; c++)
          bi[c] -= u * b[j * nrhs + c];
    }
    for (int c = 0; c < nrhs; c++)
      bi[c] /= A[i * n + i];
  }
}

/* Solve A^T x = b with mrvi_dense_lu_factor's factors of A (P A = L U, so
 * A^T = U^T L^T P); b (n x nrhs row-major) becomes x. */
void mrvi_dense_lu_solve_transpose(int n, const double *A, const int *piv,
                                   double *b, int nrhs) {
  /* U^T w = b: forward substitution by rows of U (contiguous), its
   * nonzeros only; each entry of w takes its terms in the order of j as
   * the dot product of a column would. */
  for (int j = 0; j < n; j++) {
    const double *uj = A + (size_t)j * (size_t)n;
    double *bj = b + (size_t)j * (size_t)nrhs;
    for (int c = 0; c < nrhs; c++)
      bj[c] /= uj[j];
    for (int i = j + 1; i < n; i++) {
      const double u = uj[i];
      if (u != 0.0)
        for (int c = 0; c < nrhs; c++)
          b[(size_t)i * nrhs + c] -= u * bj[c];
    }
  }
  /* L^T y = w: backward substitution, unit diagonal. */
  for (int k = n - 1; k >= 0; k--)
    for (int i = k + 1; i < n; i++) {
      const double f = A[i * n + k];
      if (f != 0.0)
        for (int c = 0; c < nrhs; c++)
          b[k * nrhs + c] -= f * b[i * nrhs + c];
    }
  /* x = P^T y: the row swaps in reverse order. */
  for (int k = n - 1; k >= 0; k--)
    if (piv[k] != k)
      for (int c = 0; c < nrhs; c++) {
        const double t = b[piv[k] * nrhs + c];
        b[piv[k] * nrhs + c] = b[k * nrhs + c];
        b[k * nrhs + c] = t;
      }
}

int mrvi_dense_extend_basis(int n, double *B, int k, double *v, double rtol) {
  double n0 = 0.0;
  for (int j = 0; j < n; j++)
    n0 += v[j] * v[j];
  n0 = sqrt(n0);
  if (!(n0 > 0.0))
    return 0;
  for (int pass = 0; pass < 2; pass++)
    for (int i = 0; i < k; i++) {
      const double *b = B + (size_t)i * (size_t)n;
      double d = 0.0;
      for (int j = 0; j < n; j++)
        d += b[j] * v[j];
      for (int j = 0; j < n; j++)
        v[j] -= d * b[j];
    }
  double nr = 0.0;
  for (int j = 0; j < n; j++)
    nr += v[j] * v[j];
  nr = sqrt(nr);
  if (nr <= rtol * n0)
    return 0;
  double *b = B + (size_t)k * (size_t)n;
  for (int j = 0; j < n; j++)
    b[j] = v[j] / nr;
  return 1;
}
