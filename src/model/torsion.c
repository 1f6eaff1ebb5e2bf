/* Torsional springs on revolute joints (doc/multibody.md, "Torsional
 * springs"): the energy phi(theta - theta0) of the rotation angle theta of
 * a moving body relative to a reference (a body, or the ground) about an
 * axis, with any registered law phi.
 *
 * The joint's frame t_1..t_D (bodies.c, mrvi_joint_frame) is stored in each
 * body's frame at the initial configuration.  With u, v the frame vectors
 * normal to the axis (3-D: t_2, t_3, the axis t_1; 2-D: t_1, t_2, the axis
 * the plane's normal), the vectors r_u = sum_i t_u^i d_ref^i,
 * r_v = sum_i t_v^i d_ref^i (constants in space for the ground) and
 * m_u = sum_i t_u^i d_mov^i are affine in the directors, and
 *
 *   c = r_u . m_u = cos(theta),   s = r_v . m_u = sin(theta)
 *
 * on the constraint manifold (m_u = cos(theta) r_u + sin(theta) r_v when the
 * relative rotation is about the axis).  theta = atan2(s, c) is smooth
 * wherever c^2 + s^2 > 0 (also between the nodes, where the directors are
 * not unit vectors), but only up to multiples of 2 pi.  The unwrapped angle
 * is a function of the path, not of the configuration: a spring that has
 * turned once stores 2 pi k^2 more energy than at the same configuration
 * unturned.  So each element keeps the branch `unwrap`, its angle at the
 * last accepted node, and evaluates
 *
 *   theta = unwrap + atan2(s cos(unwrap) - c sin(unwrap),
 *                          c cos(unwrap) + s sin(unwrap)),
 *
 * the angle nearest unwrap: continuous through +-pi over any number of
 * turns, a smooth function of q within pi of the branch (so within one
 * step), with the derivatives of atan2(s, c).  The integrator keeps the
 * branches (mrvi_model_torsion_follow after each accepted step). */
#include "model/model.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* v = sum_i t[i] Y_i over the D director blocks Y_i (D entries each). */
static void director_vector(int D, const double *t, const double *y,
                            double *v) {
  for (int k = 0; k < D; k++) {
    v[k] = 0.0;
    for (int i = 0; i < D; i++)
      v[k] += t[i] * y[i * D + k];
  }
}

static double dot(int D, const double *a, const double *b) {
  double s = 0.0;
  for (int k = 0; k < D; k++)
    s += a[k] * b[k];
  return s;
}

/* c, s of element e at inputs y (e's reference vectors r_u, r_v and the
 * moving m_u into ru, rv, mu). */
static void cos_sin(const mrvi_element *e, int D, const double *y, double *ru,
                    double *rv, double *mu, double *c, double *s) {
  const int two = e->n_in == 2 * D * D;
  const double *t = e->axes;
  if (two) {
    director_vector(D, t, y, ru);
    director_vector(D, t + D, y, rv);
    director_vector(D, t + 2 * D, y + D * D, mu);
  } else {
    memcpy(ru, t, (size_t)D * sizeof *ru);
    memcpy(rv, t + D, (size_t)D * sizeof *rv);
    director_vector(D, t + 2 * D, y, mu);
  }
  *c = dot(D, ru, mu);
  *s = dot(D, rv, mu);
}

/* The angle of (c, s) nearest the branch b. */
static double nearest(double b, double c, double s) {
  const double cb = cos(b), sb = sin(b);
  return b + atan2(s * cb - c * sb, c * cb + s * sb);
}

double mrvi_torsion_eval(const mrvi_element *e, int D, const double *y,
                         double *grad, double *hess) {
  double ru[3], rv[3], mu[3], c, s;
  cos_sin(e, D, y, ru, rv, mu, &c, &s);
  const double theta = nearest(e->axes[MRVI_TORSION_BRANCH], c, s);
  double phi, d1, d2;
  e->law->eval(e->params, theta - e->shift, &phi, &d1, &d2);
  if (!grad && !hess)
    return phi;
  /* Gradients of c and s: the reference's director i gets t_u^i m_u
   * (t_v^i m_u), the moving body's director j gets t_u^j r_u (t_u^j r_v). */
  const int n = e->n_in, two = n == 2 * D * D, off = two ? D * D : 0;
  const double *tu = e->axes, *tv = e->axes + D, *tm = e->axes + 2 * D;
  double gc[2 * 9], gs[2 * 9];
  for (int i = 0; two && i < D; i++)
    for (int k = 0; k < D; k++) {
      gc[i * D + k] = tu[i] * mu[k];
      gs[i * D + k] = tv[i] * mu[k];
    }
  for (int j = 0; j < D; j++)
    for (int k = 0; k < D; k++) {
      gc[off + j * D + k] = tm[j] * ru[k];
      gs[off + j * D + k] = tm[j] * rv[k];
    }
  /* theta = atan2(s, c) up to the branch: theta_c = -s/rho^2,
   * theta_s = c/rho^2. */
  const double r2 = c * c + s * s, tc = -s / r2, ts = c / r2;
  double gt[2 * 9];
  for (int a = 0; a < n; a++)
    gt[a] = tc * gc[a] + ts * gs[a];
  if (grad)
    for (int a = 0; a < n; a++)
      grad[a] = d1 * gt[a];
  if (!hess)
    return phi;
  /* theta_yy = theta_c c_yy + theta_s s_yy + h_cc c_y c_y^T
   *          + h_ss s_y s_y^T + h_cs (c_y s_y^T + s_y c_y^T), with
   * h_cc = -h_ss = 2 c s/rho^4, h_cs = (s^2 - c^2)/rho^4; c_yy and s_yy
   * couple the reference's director i with the moving one's j by
   * t_u^i t_m^j I (t_v^i t_m^j I). */
  const double r4 = r2 * r2, hcc = 2.0 * c * s / r4, hcs = (s * s - c * c) / r4;
  for (int a = 0; a < n; a++)
    for (int b = 0; b < n; b++)
      hess[a * n + b] =
          d2 * gt[a] * gt[b] + d1 * (hcc * (gc[a] * gc[b] - gs[a] * gs[b]) +
                                     hcs * (gc[a] * gs[b] + gs[a] * gc[b]));
  for (int i = 0; two && i < D; i++)
    for (int j = 0; j < D; j++) {
      const double w = d1 * (tc * tu[i] + ts * tv[i]) * tm[j];
      for (int k = 0; k < D; k++) {
        hess[(i * D + k) * n + off + j * D + k] += w;
        hess[(off + j * D + k) * n + i * D + k] += w;
      }
    }
  return phi;
}

/* The angle of torsion element e at q on the branch nearest b. */
static double angle_at(const mrvi_model *m, const mrvi_element *e,
                       const double *q, double b) {
  double y[18], ru[3], rv[3], mu[3], c, s;
  for (int j = 0; j < e->n_in; j++)
    y[j] = q[e->in[j]];
  cos_sin(e, m->dimension, y, ru, rv, mu, &c, &s);
  return nearest(b, c, s);
}

int mrvi_model_n_torsions(const mrvi_model *m) { return m->n_torsions; }

void mrvi_model_torsion_init(const mrvi_model *m, const double *q,
                             double *ref) {
  if (m->n_torsions == 0) /* (no pass over a network's elements) */
    return;
  for (int i = 0, t = 0; i < m->n_elements; i++)
    if (m->erecs[i].kind == MRVI_ELEMENT_TORSION) {
      const mrvi_element *e = &m->full[m->erecs[i].ci]; /* (kept in full) */
      ref[t++] = angle_at(m, e, q, e->shift);
    }
}

void mrvi_model_torsion_set(const mrvi_model *m, const double *ref) {
  /* (the elements array is the model's; its branches are run state) */
  if (m->n_torsions == 0)
    return;
  for (int i = 0, t = 0; i < m->n_elements; i++)
    if (m->erecs[i].kind == MRVI_ELEMENT_TORSION)
      m->full[m->erecs[i].ci].axes[MRVI_TORSION_BRANCH] = ref[t++];
}

double mrvi_model_torsion_follow(const mrvi_model *m, const double *q,
                                 double *ref, int *worst) {
  double jump = 0.0;
  if (worst)
    *worst = -1;
  for (int i = 0, t = 0; i < m->n_elements; i++)
    if (m->erecs[i].kind == MRVI_ELEMENT_TORSION) {
      mrvi_element *e = &m->full[m->erecs[i].ci];
      const double a = angle_at(m, e, q, ref[t]);
      if (fabs(a - ref[t]) > jump) {
        jump = fabs(a - ref[t]);
        if (worst)
          *worst = i;
      }
      e->axes[MRVI_TORSION_BRANCH] = ref[t++] = a;
    }
  return jump;
}

int mrvi_model_add_torsion(mrvi_model *m, mrvi_rate potential, int body_a,
                           int body_b, const double *axis, const char *law,
                           const double *params, double rest_angle) {
  if (body_a < 0 || body_a >= m->n_bodies || body_b >= m->n_bodies)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "torsional spring: unknown body "
                           "(index %d)",
                           body_a < 0 || body_a >= m->n_bodies ? body_a
                                                               : body_b);
  const char *na = m->bodies[body_a].name,
             *nb = body_b >= 0 ? m->bodies[body_b].name : "ground";
  char what[300];
  mrvi_fmt(what, sizeof what, "torsional spring %s-%s", na, nb);
  if (body_a == body_b)
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: a body and itself", what);
  const int D = m->bodies[body_a].dim;
  if ((D == 3) != (axis != NULL))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           D == 3 ? "%s: a 3-D torsional spring needs an axis"
                                  : "%s: a 2-D torsional spring takes no axis "
                                    "(it turns about the plane's normal)",
                           what);
  double nn = 0.0;
  for (int k = 0; axis && k < 3; k++)
    nn += axis[k] * axis[k];
  if (axis && !(isfinite(nn) && nn > 0.0))
    return mrvi_model_fail(
        m, MRVI_EINVAL, "%s: the axis must be a nonzero finite vector", what);
  if (!isfinite(rest_angle))
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: rest angle must be finite",
                           what);
  mrvi_element e = {.kind = MRVI_ELEMENT_TORSION,
                    .potential = potential,
                    .shift = rest_angle};
  int st = mrvi_model_set_law(m, &e, law, params, what);
  if (st < 0)
    return st;
  /* The reference is body A (the ground with one body), the moving body B
   * (A with the ground): theta turns the mover relative to the reference
   * about the axis, counter-clockwise seen from its tip. */
  const int ref = body_b >= 0 ? body_a : -1,
            mov = body_b >= 0 ? body_b : body_a;
  double t[9];
  mrvi_joint_frame(D, axis, t);
  const int u = D == 3 ? 1 : 0, v = D == 3 ? 2 : 1;
  e.n_in = (ref >= 0 ? 2 : 1) * D * D;
  e.in = mrvi_model_inputs(m, e.n_in);
  e.axes = malloc((MRVI_TORSION_BRANCH + 1) * sizeof *e.axes);
  if (!e.in || !e.axes) {
    free(e.axes);
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  }
  if (ref >= 0) {
    mrvi_body_frame_of(m, ref, t + D * u, e.axes);
    mrvi_body_frame_of(m, ref, t + D * v, e.axes + D);
  } else {
    memcpy(e.axes, t + D * u, (size_t)D * sizeof *t);
    memcpy(e.axes + D, t + D * v, (size_t)D * sizeof *t);
  }
  mrvi_body_frame_of(m, mov, t + D * u, e.axes + 2 * D);
  int n_in = 0;
  for (int s = 0; s < 2; s++) {
    const int b = s ? mov : ref;
    for (int j = 0; b >= 0 && j < D * D; j++)
      e.in[n_in++] = m->bodies[b].first + D + j; /* d_1 .. d_D */
  }
  e.axes[MRVI_TORSION_BRANCH] = angle_at(m, &e, m->q0, rest_angle);
  return mrvi_model_push_element(m, &e, what);
}
