/* What the joint types (spherical.c, revolute.c, weld.c, prismatic.c,
 * cylindrical.c, planar.c) share: the layout of their inputs and
 * parameters, and one evaluator of their rows (doc/multibody.md,
 * "Joints").
 *
 * A rigid body of dimension d is its centre of mass phi and its directors
 * d_1..d_d (Betsch & Leyendecker 2006, Part II): d (d + 1) inputs, phi
 * first, then d_1, d_2, [d_3], d entries each.  A joint acts on body A and
 * body B (2 d (d + 1) inputs) or on body A and the ground (d (d + 1)
 * inputs).  The inputs are blocks Y_k of d entries: phi_A, d_A^1 .. d_A^d,
 * then phi_B, d_B^1 .. d_B^d.
 *
 * Parameters: par[0] = d (2 or 3), par[1] = bodies (2, or 1 for the
 * ground), rho_A (d, A's frame), rho_B (d, B's frame) or the ground point
 * p (space), and for types with an orientation a frame t_1..t_d (the
 * joint's axis first) twice: in A's frame, then in B's frame (or in space
 * for the ground), d^2 entries each.
 *
 * Every row is a component of, or a dot product of, vectors affine in the
 * blocks, C = sum_k c_k Y_k + c0:
 *   r   = x_A - x_B = phi_A + sum_i rho_A^i d_A^i - (phi_B + sum_i rho_B^i
 *         d_B^i)  (x_B = p for the ground)
 *   a_m = sum_i t_m^i(A) d_A^i,   b_m = sum_i t_m^i(B) d_B^i  (t_m for the
 *         ground),
 * which equal the joint's frame t_m in space at the initial configuration.
 * Row kinds: 'p' the d components of r (linear); 'd' a_m . b_n; 's'
 * r . b_n.  For a product C . E: dg/dY_k = c_k E + e_k C and
 * d2g/(dY_k dY_l) = (c_k e_l + e_k c_l) I. */
#ifndef MRVI_CONSTRAINTS_JOINT_H
#define MRVI_CONSTRAINTS_JOINT_H

#include "util/util.h"

#include <math.h>
#include <string.h>

#define MRVI_JOINT_HEAD 2 /* par[0] = d, par[1] = bodies */

/* One row of a joint: kind 'p' (the d rows of r), 'd' (a_m . b_n) or 's'
 * (r . b_n); m, n index the frame (0 = the axis). */
typedef struct mrvi_joint_row {
  char kind;
  signed char m, n;
} mrvi_joint_row;

/* Inputs of one body of dimension d. */
static inline int mrvi_joint_body_inputs(int d) { return d * (d + 1); }

/* Rows of a row list in dimension d. */
static inline int mrvi_joint_rows(const mrvi_joint_row *rows, int n_rows,
                                  int d) {
  int r = 0;
  for (int i = 0; i < n_rows; i++)
    r += rows[i].kind == 'p' ? d : 1;
  return r;
}

/* Check the common part: finite parameters, d in dims (a bit mask of
 * 1 << d), 1 or 2 bodies, n_in = bodies d (d + 1), n_params =
 * MRVI_JOINT_HEAD + 2 d (+ 2 d^2 with a frame), nonzero frame vectors.
 * Returns d, or a status < 0 with a message. */
static inline int mrvi_joint_check(const char *type, int dims, int frame,
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
  const int want = MRVI_JOINT_HEAD + 2 * d + (frame ? 2 * d * d : 0);
  if (n_in != nb * mrvi_joint_body_inputs(d) || n_params != want)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: %d bod%s of dimension %d need %d inputs and %d "
                     "parameters (got %d and %d)",
                     type, nb, nb == 1 ? "y" : "ies", d,
                     nb * mrvi_joint_body_inputs(d), want, n_in, n_params);
  for (int v = 0; frame && v < 2 * d; v++) {
    const double *t = par + MRVI_JOINT_HEAD + 2 * d + d * v;
    double tt = 0.0;
    for (int a = 0; a < d; a++)
      tt += t[a] * t[a];
    if (!(tt > 0.0))
      return mrvi_fail(msg, len, MRVI_EINVAL,
                       "%s: the joint's frame vectors must not be zero", type);
  }
  return d;
}

/* An affine vector C = sum_k c[k] Y_k + c0 of the blocks. */
typedef struct mrvi_joint_vec {
  double c[8], c0[3];
} mrvi_joint_vec;

/* r = x_A - x_B. */
static inline void mrvi_joint_r(const double *par, mrvi_joint_vec *v) {
  const int d = (int)par[0], nb = (int)par[1];
  const double *rho = par + MRVI_JOINT_HEAD;
  memset(v, 0, sizeof *v);
  v->c[0] = 1.0;
  for (int i = 0; i < d; i++)
    v->c[1 + i] = rho[i];
  if (nb == 2) {
    v->c[d + 1] = -1.0;
    for (int i = 0; i < d; i++)
      v->c[d + 2 + i] = -rho[d + i];
  } else {
    for (int a = 0; a < d; a++)
      v->c0[a] = -rho[d + a];
  }
}

/* a_m (body 0) or b_m (body 1; constant t_m for the ground). */
static inline void mrvi_joint_axis(const double *par, int body, int m,
                                   mrvi_joint_vec *v) {
  const int d = (int)par[0], nb = (int)par[1];
  const double *t = par + MRVI_JOINT_HEAD + 2 * d + d * d * body + d * m;
  memset(v, 0, sizeof *v);
  if (body == 1 && nb == 1) {
    memcpy(v->c0, t, (size_t)d * sizeof *t);
    return;
  }
  for (int i = 0; i < d; i++)
    v->c[body * (d + 1) + 1 + i] = t[i];
}

/* Value of C at the inputs y (d entries). */
static inline void mrvi_joint_value(const mrvi_joint_vec *v, int d, int nk,
                                    const double *y, double *C) {
  for (int a = 0; a < d; a++) {
    C[a] = v->c0[a];
    for (int k = 0; k < nk; k++)
      C[a] += v->c[k] * y[k * d + a];
  }
}

/* Rows of a joint at the inputs y: g, G (rows x n_in) and, if H is not
 * NULL, the second derivatives (rows x n_in x n_in). */
static inline void mrvi_joint_eval(const mrvi_joint_row *rows, int n_rows,
                                   int n_in, const double *par, const double *y,
                                   double *g, double *G, double *H) {
  const int d = (int)par[0], nk = n_in / d;
  const int R = mrvi_joint_rows(rows, n_rows, d);
  memset(G, 0, (size_t)R * (size_t)n_in * sizeof *G);
  if (H)
    memset(H, 0, (size_t)R * (size_t)n_in * (size_t)n_in * sizeof *H);
  mrvi_joint_vec r, C, E;
  double Cv[3], Ev[3];
  mrvi_joint_r(par, &r);
  int row = 0;
  for (int i = 0; i < n_rows; i++) {
    if (rows[i].kind == 'p') { /* g = r, linear */
      mrvi_joint_value(&r, d, nk, y, Cv);
      for (int a = 0; a < d; a++, row++) {
        g[row] = Cv[a];
        for (int k = 0; k < nk; k++)
          G[(size_t)row * n_in + k * d + a] = r.c[k];
      }
      continue;
    }
    if (rows[i].kind == 'd')
      mrvi_joint_axis(par, 0, rows[i].m, &C);
    else
      C = r;
    mrvi_joint_axis(par, 1, rows[i].n, &E);
    mrvi_joint_value(&C, d, nk, y, Cv);
    mrvi_joint_value(&E, d, nk, y, Ev);
    g[row] = 0.0;
    for (int a = 0; a < d; a++)
      g[row] += Cv[a] * Ev[a];
    for (int k = 0; k < nk; k++)
      for (int a = 0; a < d; a++)
        G[(size_t)row * n_in + k * d + a] = C.c[k] * Ev[a] + E.c[k] * Cv[a];
    if (H) {
      double *Hr = H + (size_t)row * n_in * n_in;
      for (int k = 0; k < nk; k++)
        for (int l = 0; l < nk; l++) {
          const double h = C.c[k] * E.c[l] + E.c[k] * C.c[l];
          for (int a = 0; h != 0.0 && a < d; a++)
            Hr[(size_t)(k * d + a) * n_in + l * d + a] = h;
        }
    }
    row++;
  }
}

/* check and eval of a joint type whose rows are r3 (3-D; n3 = 0: none)
 * and r2 (2-D; n2 = 0: none), with or without a frame. */
static inline int
mrvi_joint_check_rows(const char *type, int frame, const mrvi_joint_row *r3,
                      int n3, const mrvi_joint_row *r2, int n2, int n_in,
                      int n_params, const double *par, char *msg, size_t len) {
  const int dims = (n3 ? 1 << 3 : 0) | (n2 ? 1 << 2 : 0);
  const int d =
      mrvi_joint_check(type, dims, frame, n_in, n_params, par, msg, len);
  return d < 0    ? d
         : d == 3 ? mrvi_joint_rows(r3, n3, 3)
                  : mrvi_joint_rows(r2, n2, 2);
}

/* affine of a joint type whose rows are r3 and r2 (constraints/joint.h's
 * rows, an instance already checked): the rows r are affine; a_m . b_n and
 * r . b_n are products of two affine vectors, affine where one is
 * constant, which b_n is for the ground (one body).  So a 2-D revolute
 * joint (r alone) and every joint to the ground are affine, a 3-D
 * revolute joint between two bodies is not. */
static inline int mrvi_joint_affine_rows(const mrvi_joint_row *r3, int n3,
                                         const mrvi_joint_row *r2, int n2,
                                         const double *par) {
  const mrvi_joint_row *rows = par[0] == 3.0 ? r3 : r2;
  const int n = par[0] == 3.0 ? n3 : n2;
  if (par[1] == 1.0)
    return 1;
  for (int i = 0; i < n; i++)
    if (rows[i].kind != 'p')
      return 0;
  return 1;
}

static inline void mrvi_joint_eval_rows(const mrvi_joint_row *r3, int n3,
                                        const mrvi_joint_row *r2, int n2,
                                        int n_in, const double *par,
                                        const double *y, double *g, double *G,
                                        double *H) {
  if (par[0] == 3.0)
    mrvi_joint_eval(r3, n3, n_in, par, y, g, G, H);
  else
    mrvi_joint_eval(r2, n2, n_in, par, y, g, G, H);
}

#endif
