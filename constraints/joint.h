/* What the joint types (spherical.c, revolute.c) share: the layout of their
 * inputs and parameters and the rows that make two body points coincide
 * (doc/multibody.md, "Joints").
 *
 * A rigid body of dimension d is its centre of mass phi and its directors
 * d_1..d_d (Betsch & Leyendecker 2006, Part II): d (d + 1) inputs, phi
 * first, then d_1, d_2, [d_3], d entries each.  A body point with
 * body-frame components rho is x = phi + sum_i rho^i d_i, affine in the
 * inputs.  A joint acts on body A and body B (2 d (d + 1) inputs) or on
 * body A and the ground (d (d + 1) inputs).
 *
 * Parameters: par[0] = d (2 or 3), par[1] = number of bodies (2, or 1 for
 * the ground), then rho_A (d entries, A's frame), then rho_B (B's frame) or
 * the ground point (space), then what the type adds. */
#ifndef MRVI_CONSTRAINTS_JOINT_H
#define MRVI_CONSTRAINTS_JOINT_H

#include "internal.h"

#include <math.h>
#include <string.h>

#define MRVI_JOINT_HEAD 2 /* par[0] = d, par[1] = bodies */

/* Inputs of one body of dimension d. */
static inline int mrvi_joint_body_inputs(int d) { return d * (d + 1); }

/* Check the common part: finite parameters, d in dims (a bit mask of
 * 1 << d), 1 or 2 bodies, n_in = bodies d (d + 1), n_params =
 * MRVI_JOINT_HEAD + 2 d + extra.  Returns d, or a status < 0 with a
 * message. */
static inline int mrvi_joint_check(const char *type, int dims, int extra,
                                   int n_in, int n_params, const double *par,
                                   char *msg, size_t len) {
  if (n_params < MRVI_JOINT_HEAD)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: parameters start with the dimension and the number "
                     "of bodies (got %d parameters)",
                     type, n_params);
  for (int i = 0; i < n_params; i++)
    if (!isfinite(par[i]))
      return mrvi_fail(msg, len, MRVI_EINVAL, "%s: parameters must be finite",
                       type);
  const int d = (int)par[0], nb = (int)par[1];
  if ((double)d != par[0] || d < 2 || d > 3 || !(dims & (1 << d)))
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: a joint of dimension %g does not exist (it needs %s)",
                     type, par[0],
                     dims == (1 << 3)   ? "3-D bodies"
                     : dims == (1 << 2) ? "2-D bodies"
                                        : "2-D or 3-D bodies");
  if ((double)nb != par[1] || nb < 1 || nb > 2)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: joins one body to the ground or two bodies (got %g)",
                     type, par[1]);
  if (n_in != nb * mrvi_joint_body_inputs(d) ||
      n_params != MRVI_JOINT_HEAD + 2 * d + extra)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: %d bod%s of dimension %d need %d inputs and %d "
                     "parameters (got %d and %d)",
                     type, nb, nb == 1 ? "y" : "ies", d,
                     nb * mrvi_joint_body_inputs(d),
                     MRVI_JOINT_HEAD + 2 * d + extra, n_in, n_params);
  return d;
}

/* Rows 0..d-1: x_A - x_B = 0 with x = phi + sum_i rho^i d_i (x_B the
 * ground point for one body).  Linear in the inputs: G has the constant
 * entries 1 (phi) and rho^i (d_i), negative for B; g and the first d rows
 * of G (row stride n_in, zeroed here) are written. */
static inline void mrvi_joint_point_rows(int n_in, const double *par,
                                         const double *y, double *g,
                                         double *G) {
  const int d = (int)par[0], nb = (int)par[1];
  const int nq = mrvi_joint_body_inputs(d);
  const double *rho[2] = {par + MRVI_JOINT_HEAD, par + MRVI_JOINT_HEAD + d};
  memset(G, 0, (size_t)d * (size_t)n_in * sizeof *G);
  for (int a = 0; a < d; a++) {
    g[a] = 0.0;
    for (int b = 0; b < nb; b++) {
      const double s = b == 0 ? 1.0 : -1.0;
      const double *yb = y + b * nq;
      double *Gb = G + (size_t)a * (size_t)n_in + b * nq;
      double x = yb[a];
      Gb[a] = s;
      for (int i = 0; i < d; i++) {
        x += rho[b][i] * yb[d * (1 + i) + a];
        Gb[d * (1 + i) + a] = s * rho[b][i];
      }
      g[a] += s * x;
    }
    if (nb == 1)
      g[a] -= rho[1][a]; /* the ground point */
  }
}

/* The vector sum_i c^i d_i of the body whose inputs start at yb (d = 3). */
static inline void mrvi_joint_vector(const double *yb, const double *c,
                                     double *v) {
  for (int a = 0; a < 3; a++)
    v[a] = c[0] * yb[3 + a] + c[1] * yb[6 + a] + c[2] * yb[9 + a];
}

#endif
