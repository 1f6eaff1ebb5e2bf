/* Evaluation points of the generalised rule eq:Zapprox on the micro grid and
 * of the macro-node rule eq:slow_potential_affine (arXiv 2406.12991 §3.3). */
#include "step/step.h"

static int push(mrvi_point *pts, int n, double w, double tau, int m,
                double theta) {
  if (w == 0.0)
    return n; /* a rule with a zero weight (rectangle) has one point */
  pts[n] = (mrvi_point){.w = w,
                        .a0 = 1.0 - tau,
                        .a1 = tau,
                        .m = m,
                        .cA = 1.0 - theta,
                        .cB = theta};
  return n + 1;
}

int mrvi_quadrature_points(mrvi_rule rule, mrvi_grid grid, double macro_step,
                           int p, mrvi_point *pts) {
  const double a = rule.alpha, g = rule.gamma;
  int n = 0;
  if (grid == MRVI_GRID_MACRO) {
    /* dT [a Z(q_k^s, q_k^{f,0}) + (1 - a) Z(q_{k+1}^s, q_k^{f,p})] */
    n = push(pts, n, a * macro_step, 0.0, 0, 0.0);
    n = push(pts, n, (1.0 - a) * macro_step, 1.0, p - 1, 1.0);
    return n;
  }
  const double dt = macro_step / p;
  for (int m = 0; m < p; m++) {
    /* a Z(g z^m + (1-g) z^{m+1}) + (1-a) Z((1-g) z^m + g z^{m+1}):
     * the first point lies at theta = 1 - g of the interval, the second at
     * theta = g; they coincide for the midpoint rule g = 1/2. */
    const double t1 = 1.0 - g, t2 = g;
    if (t1 == t2) {
      n = push(pts, n, dt, (m + t1) / p, m, t1);
    } else {
      n = push(pts, n, a * dt, (m + t1) / p, m, t1);
      n = push(pts, n, (1.0 - a) * dt, (m + t2) / p, m, t2);
    }
  }
  return n;
}
