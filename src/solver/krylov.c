/* Krylov solvers for the large-block step paths (doc/solver.md,
 * "sweep-cg" and "schur-krylov"): preconditioned conjugate gradients for
 * the symmetric micro-step blocks M/dt + O(dt K), restarted GMRES for the
 * Schur complement on the slow unknowns.  Both are matrix-free (the
 * operator is a callback) and work in caller-owned workspaces, so that a
 * solve allocates nothing. */
#include "solver/solver.h"

#include <math.h>
#include <string.h>

static double dot(int n, const double *a, const double *b) {
  double s = 0.0;
  for (int i = 0; i < n; i++)
    s += a[i] * b[i];
  return s;
}

/* One pass of mrvi_pcg over rows [i0, i1): x += alpha p, r -= alpha q,
 * and ||r||_inf and r^T D^-1 r of the rows (the same sums in the same
 * order as separate passes). */
void mrvi_pcg_update(double *x, double *r, const double *p, const double *q,
                     const double *dinv, double alpha, int i0, int i1,
                     double *r_inf, double *rz) {
  double rn = 0.0, rz1 = 0.0;
  for (int i = i0; i < i1; i++) {
    x[i] += alpha * p[i];
    const double ri = r[i] - alpha * q[i];
    r[i] = ri;
    const double a = fabs(ri);
    rn = isnan(a) || a > rn ? a : rn;
    rz1 += ri * (dinv[i] * ri);
  }
  *r_inf = rn;
  *rz = rz1;
}

/* Jacobi-preconditioned CG on A x = b from x = 0.  Stops when
 * ||r||_inf <= max(atol, rtol ||b||_inf) (r the recursively updated
 * residual b - A x).  A direction with p^T A p <= 0 (A not positive
 * definite) stops it with MRVI_CG_CURVATURE and *curvature =
 * p^T A p / p^T p; no convergence within max_it gives MRVI_CG_MAXIT. */
int mrvi_pcg(int n, mrvi_matvec A, void *ctx, const double *dinv,
             const double *b, double *x, double rtol, double atol, int max_it,
             double *work, int *iterations, double *curvature) {
  double *r = work, *p = work + n, *q = work + 2 * (size_t)n;
  *iterations = 0;
  *curvature = 0.0;
  memset(x, 0, (size_t)n * sizeof(double));
  /* r = b, p = z = D^-1 r (z is formed where it is used, not stored),
   * ||b||_inf and r^T z in one pass. */
  double bn = 0.0, rz = 0.0;
  for (int i = 0; i < n; i++) {
    const double bi = b[i], a = fabs(bi);
    r[i] = bi;
    p[i] = dinv[i] * bi;
    rz += bi * p[i];
    bn = isnan(a) || a > bn ? a : bn;
  }
  const double stop = fmax(atol, rtol * bn);
  if (bn <= stop)
    return MRVI_CG_OK;
  for (int k = 1; k <= max_it; k++) {
    const double pq = A(ctx, p, q);
    if (!(pq > 0.0)) {
      *iterations = k;
      *curvature = pq / dot(n, p, p);
      return MRVI_CG_CURVATURE;
    }
    const double alpha = rz / pq;
    double rn = 0.0, rz1 = 0.0;
    mrvi_pcg_update(x, r, p, q, dinv, alpha, 0, n, &rn, &rz1);
    *iterations = k;
    if (rn <= stop)
      return MRVI_CG_OK;
    if (!isfinite(rn))
      return MRVI_CG_MAXIT;
    const double beta = rz1 / rz;
    rz = rz1;
    for (int i = 0; i < n; i++)
      p[i] = dinv[i] * r[i] + beta * p[i];
  }
  return MRVI_CG_MAXIT;
}

size_t mrvi_gmres_work(int n, int restart) {
  const size_t m = (size_t)restart;
  return (m + 1) * (size_t)n + (m + 1) * m + 3 * (m + 1) + (size_t)n;
}

/* Restarted GMRES (Saad & Schultz) with right preconditioning by the
 * diagonal dinv, from x = 0: A M^-1 u = b, x = M^-1 u.  Stops when the
 * residual 2-norm is at most max(atol, rtol ||b||_2).  The operator may
 * fail (status < 0, returned as is). */
int mrvi_gmres(int n, mrvi_matvec_status A, void *ctx, const double *dinv,
               const double *b, double *x, double rtol, double atol,
               int restart, int max_it, double *work, int *iterations,
               double *y, int *ny) {
  const int m = restart;
  double *V = work;                             /* (m + 1) x n */
  double *H = V + (size_t)(m + 1) * (size_t)n;  /* (m + 1) x m */
  double *cs = H + (size_t)(m + 1) * (size_t)m; /* m + 1 */
  double *sn = cs + m + 1, *g = sn + m + 1;     /* m + 1 each */
  double *t = g + m + 1;                        /* n */
  *iterations = 0;
  if (ny)
    *ny = 0;
  memset(x, 0, (size_t)n * sizeof(double));
  const double bn = sqrt(dot(n, b, b));
  const double stop = fmax(atol, rtol * bn);
  if (bn <= stop)
    return MRVI_CG_OK;
  int total = 0;
  for (;;) {
    /* r = b - A x (x = 0 on the first cycle) */
    double beta;
    if (total == 0) {
      memcpy(V, b, (size_t)n * sizeof(double));
      beta = bn;
    } else {
      if (ny)
        *ny = -1;
      int s = A(ctx, x, V);
      if (s < 0)
        return s;
      for (int i = 0; i < n; i++)
        V[i] = b[i] - V[i];
      beta = sqrt(dot(n, V, V));
      if (beta <= stop)
        return MRVI_CG_OK;
    }
    for (int i = 0; i < n; i++)
      V[i] /= beta;
    memset(g, 0, (size_t)(m + 1) * sizeof(double));
    g[0] = beta;
    int k = 0;
    double res = beta;
    while (k < m && total < max_it) {
      double *v = V + (size_t)k * (size_t)n, *w = v + n;
      for (int i = 0; i < n; i++)
        t[i] = dinv[i] * v[i];
      int s = A(ctx, t, w);
      if (s < 0)
        return s;
      /* Modified Gram-Schmidt */
      for (int j = 0; j <= k; j++) {
        const double *vj = V + (size_t)j * (size_t)n;
        const double h = dot(n, vj, w);
        H[j * m + k] = h;
        for (int i = 0; i < n; i++)
          w[i] -= h * vj[i];
      }
      const double hn = sqrt(dot(n, w, w));
      H[(k + 1) * m + k] = hn;
      if (hn > 0.0)
        for (int i = 0; i < n; i++)
          w[i] /= hn;
      /* Givens rotations on column k */
      for (int j = 0; j < k; j++) {
        const double a = H[j * m + k], c = H[(j + 1) * m + k];
        H[j * m + k] = cs[j] * a + sn[j] * c;
        H[(j + 1) * m + k] = -sn[j] * a + cs[j] * c;
      }
      const double a = H[k * m + k], c = H[(k + 1) * m + k];
      const double r = hypot(a, c);
      cs[k] = r > 0.0 ? a / r : 1.0;
      sn[k] = r > 0.0 ? c / r : 0.0;
      H[k * m + k] = r;
      H[(k + 1) * m + k] = 0.0;
      g[k + 1] = -sn[k] * g[k];
      g[k] = cs[k] * g[k];
      res = fabs(g[k + 1]);
      k++;
      total++;
      if (res <= stop || !(hn > 0.0) || !isfinite(res))
        break;
    }
    /* y = H^-1 g (upper triangular k x k), u = V y, x += M^-1 u */
    for (int j = k - 1; j >= 0; j--) {
      double s = g[j];
      for (int l = j + 1; l < k; l++)
        s -= H[j * m + l] * g[l];
      g[j] = H[j * m + j] != 0.0 ? s / H[j * m + j] : 0.0;
    }
    if (y && total == k) {
      memcpy(y, g, (size_t)k * sizeof(double));
      *ny = k;
    }
    memset(t, 0, (size_t)n * sizeof(double));
    for (int j = 0; j < k; j++) {
      const double *vj = V + (size_t)j * (size_t)n;
      for (int i = 0; i < n; i++)
        t[i] += g[j] * vj[i];
    }
    for (int i = 0; i < n; i++)
      x[i] += dinv[i] * t[i];
    *iterations = total;
    if (!isfinite(res))
      return MRVI_CG_MAXIT;
    if (res <= stop)
      return MRVI_CG_OK;
    if (total >= max_it)
      return MRVI_CG_MAXIT;
  }
}
