/* Rigid bodies as directors and the joints between them (doc/multibody.md).
 *
 * Director formulation (Betsch & Leyendecker 2006, Part II; Leyendecker,
 * Marsden & Ortiz 2008): a body point with body-frame components X is
 * x = phi + sum_i X^i d_i, phi the centre of mass and d_i the orthonormal
 * directors along the principal axes.  Its kinetic energy
 *
 *   T = 1/2 int |x'|^2 dm = 1/2 M |phi'|^2 + 1/2 sum_ij E_ij d_i'.d_j'
 *
 * (the cross terms vanish since int X dm = 0 about the centre of mass),
 * E_ij = int X^i X^j dm the second moments, diagonal along the principal
 * axes: E_i = int (X^i)^2 dm.  The principal moments of inertia are
 * J_i = int (|X|^2 - (X^i)^2) dm = E_j + E_k, so E_i = (J_j + J_k - J_i)/2,
 * positive for a body of positive volume exactly when J_i < J_j + J_k.  In
 * 2-D only J = E_1 + E_2 enters the rigid motion (|d_1'| = |d_2'| = theta');
 * E_1 = E_2 = J/2.  The mass matrix diag(M I, E_1 I, .., E_D I) is constant,
 * as the paper's Lagrangians require; the rigidity is the internal
 * constraint type "body" (constraints/body.c). */
#include "model/model.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

void mrvi_model_free_bodies(mrvi_model *m) {
  for (int b = 0; b < m->n_bodies; b++)
    free(m->bodies[b].name);
  free(m->bodies);
  m->bodies = NULL;
  m->n_bodies = m->cap_bodies = 0;
}

int mrvi_model_n_bodies(const mrvi_model *m) { return m->n_bodies; }

int mrvi_model_find_body(const mrvi_model *m, const char *name) {
  for (int b = 0; name && b < m->n_bodies; b++)
    if (strcmp(m->bodies[b].name, name) == 0)
      return b;
  return -1;
}

const char *mrvi_model_body_name(const mrvi_model *m, int b) {
  return b >= 0 && b < m->n_bodies ? m->bodies[b].name : NULL;
}

int mrvi_model_body_first(const mrvi_model *m, int b) {
  return b >= 0 && b < m->n_bodies ? m->bodies[b].first : -1;
}

int mrvi_model_body_of(const mrvi_model *m, int c) {
  for (int b = 0; b < m->n_bodies; b++) {
    const int D = m->bodies[b].dim;
    if (c >= m->bodies[b].first && c < m->bodies[b].first + D * (D + 1))
      return b;
  }
  return -1;
}

void mrvi_model_body_pose(const mrvi_model *m, int b, const double *q,
                          double *position, double *R) {
  const mrvi_body *bd = &m->bodies[b];
  const int D = bd->dim;
  const double *y = q + bd->first;
  for (int a = 0; a < D; a++) {
    if (position)
      position[a] = y[a];
    if (R)
      for (int i = 0; i < D; i++)
        R[a * D + i] = y[D * (1 + i) + a]; /* column i = d_i */
  }
}

/* ---------------------------------------------------------------------------
 * Adding a body
 * ------------------------------------------------------------------------- */

/* Second moments E_i from the principal moments J (D entries), or a status
 * with the reason in m's message. */
static int second_moments(mrvi_model *m, const char *name, int D,
                          const double *J, double *E) {
  for (int i = 0; i < (D == 3 ? 3 : 1); i++)
    if (!(isfinite(J[i]) && J[i] > 0.0))
      return mrvi_model_fail(m, MRVI_EINVAL,
                             "body '%s': the principal inertia must be "
                             "positive and finite (J%d = %g)",
                             name, i + 1, J[i]);
  if (D == 2) {
    E[0] = E[1] = 0.5 * J[0];
    return MRVI_OK;
  }
  for (int i = 0; i < 3; i++) {
    const int j = (i + 1) % 3, k = (i + 2) % 3;
    E[i] = 0.5 * (J[j] + J[k] - J[i]);
    if (!(J[i] < J[j] + J[k]))
      return mrvi_model_fail(
          m, MRVI_EINVAL,
          "body '%s': the principal inertia violates the strict triangle "
          "inequality J%d < J%d + J%d (J%d = %g, J%d + J%d = %g): the second "
          "moment E%d = (J%d + J%d - J%d)/2 = %g must be positive (a slender "
          "rod with E = 0 has no director form; give it a small thickness)",
          name, i + 1, j + 1, k + 1, i + 1, J[i], j + 1, k + 1, J[j] + J[k],
          i + 1, j + 1, k + 1, i + 1, E[i]);
  }
  return MRVI_OK;
}

/* Check R (D x D row-major) for a rotation within 1e-6 and write its
 * columns, orthonormalised by Gram-Schmidt (d_3 = d_1 x d_2), into d
 * (D vectors of D entries). */
static int rotation(mrvi_model *m, const char *name, int D, const double *R,
                    double *d) {
  double worst = 0.0;
  for (int i = 0; i < D; i++)
    for (int j = 0; j < D; j++) {
      double s = 0.0;
      for (int a = 0; a < D; a++) {
        if (!isfinite(R[a * D + i]))
          return mrvi_model_fail(m, MRVI_EINVAL,
                                 "body '%s': orientation must be finite", name);
        s += R[a * D + i] * R[a * D + j];
      }
      worst = fmax(worst, fabs(s - (i == j)));
    }
  const double det = D == 2 ? R[0] * R[3] - R[1] * R[2]
                            : R[0] * (R[4] * R[8] - R[5] * R[7]) -
                                  R[1] * (R[3] * R[8] - R[5] * R[6]) +
                                  R[2] * (R[3] * R[7] - R[4] * R[6]);
  if (!(worst <= 1e-6))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "body '%s': the orientation is not a rotation "
                           "matrix: max |R^T R - I| = %.3g exceeds 1e-6",
                           name, worst);
  if (!(det > 0.0))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "body '%s': the orientation has det %.6g, a "
                           "reflection, not a rotation (det must be +1: "
                           "swap two columns or negate one)",
                           name, det);
  for (int i = 0; i < D; i++)
    for (int a = 0; a < D; a++)
      d[i * D + a] = R[a * D + i];
  double n = sqrt(d[0] * d[0] + d[1] * d[1] + (D == 3 ? d[2] * d[2] : 0.0));
  for (int a = 0; a < D; a++)
    d[a] /= n;
  double *d2 = d + D, s = 0.0;
  for (int a = 0; a < D; a++)
    s += d[a] * d2[a];
  n = 0.0;
  for (int a = 0; a < D; a++) {
    d2[a] -= s * d[a];
    n += d2[a] * d2[a];
  }
  n = sqrt(n);
  for (int a = 0; a < D; a++)
    d2[a] /= n;
  if (D == 3) {
    d[6] = d[1] * d2[2] - d[2] * d2[1];
    d[7] = d[2] * d2[0] - d[0] * d2[2];
    d[8] = d[0] * d2[1] - d[1] * d2[0];
  }
  return MRVI_OK;
}

int mrvi_model_add_body(mrvi_model *m, const char *name, int dimension,
                        mrvi_rate rate, double mass, const double *inertia,
                        const double *x0, const double *R0, const double *v0,
                        const double *omega0) {
  static const char axis[3] = {'x', 'y', 'z'};
  const int D = dimension;
  if (!name || !*name || strchr(name, '.'))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "body name '%s' is empty or contains '.'",
                           name ? name : "");
  if (D != 2 && D != 3)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "body '%s': dimension must be 2 or 3 (got %d)", name,
                           D);
  if ((m->n_particles > 0 || m->n_bodies > 0) && m->dimension != D)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "body '%s' of dimension %d in a model of dimension "
                           "%d",
                           name, D, m->dimension);
  if (mrvi_model_find_body(m, name) >= 0)
    return mrvi_model_fail(m, MRVI_EINVAL, "duplicate body name '%s'", name);
  if (mrvi_model_find_particle(m, name) >= 0)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "body '%s': a particle has that name", name);
  if (rate != MRVI_SLOW && rate != MRVI_FAST)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "body '%s': rate must be slow or fast", name);
  if (!(isfinite(mass) && mass > 0.0))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "body '%s': mass must be positive (got %g)", name,
                           mass);
  if (!inertia || !x0)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "body '%s' needs its inertia and position", name);
  double E[3], d[9];
  static const double identity[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  const double eye2[4] = {1, 0, 0, 1};
  int st;
  if ((st = second_moments(m, name, D, inertia, E)) < 0 ||
      (st = rotation(m, name, D,
                     R0       ? R0
                     : D == 3 ? identity
                              : eye2,
                     d)) < 0)
    return st;
  /* Coordinates and their initial data: phi, phi' = v0; d_i, d_i' = w x d_i. */
  double q[12], v[12], mass_of[12];
  const double w[3] = {omega0 && D == 3 ? omega0[0] : 0.0,
                       omega0 && D == 3 ? omega0[1] : 0.0,
                       omega0 ? omega0[D == 3 ? 2 : 0] : 0.0};
  for (int a = 0; a < D; a++) {
    q[a] = x0[a];
    v[a] = v0 ? v0[a] : 0.0;
    mass_of[a] = mass;
  }
  for (int i = 0; i < D; i++) {
    const double *di = d + D * i;
    double *vi = v + D * (1 + i);
    if (D == 3) {
      vi[0] = w[1] * di[2] - w[2] * di[1];
      vi[1] = w[2] * di[0] - w[0] * di[2];
      vi[2] = w[0] * di[1] - w[1] * di[0];
    } else {
      vi[0] = -w[2] * di[1];
      vi[1] = w[2] * di[0];
    }
    for (int a = 0; a < D; a++) {
      q[D * (1 + i) + a] = di[a];
      mass_of[D * (1 + i) + a] = E[i];
    }
  }
  if (m->n_bodies == m->cap_bodies) {
    const int cap = m->cap_bodies ? 2 * m->cap_bodies : 4;
    mrvi_body *p = realloc(m->bodies, (size_t)cap * sizeof *p);
    if (!p)
      return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
    m->bodies = p;
    m->cap_bodies = cap;
  }
  mrvi_body body = {.name = strdup(name),
                    .first = m->n,
                    .dim = D,
                    .mass = mass,
                    .inertia = {inertia[0], D == 3 ? inertia[1] : 0.0,
                                D == 3 ? inertia[2] : 0.0}};
  if (!body.name)
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  m->dimension = D;
  for (int c = 0; c < D * (D + 1); c++) {
    char cname[300];
    if (c < D)
      mrvi_fmt(cname, sizeof cname, "%s.%c", name, axis[c]);
    else
      mrvi_fmt(cname, sizeof cname, "%s.d%d%c", name, c / D, axis[c % D]);
    if ((st = mrvi_model_add_coordinate(m, cname, mass_of[c], rate, q[c],
                                        v[c])) < 0) {
      free(body.name);
      return st;
    }
  }
  int in[9];
  for (int j = 0; j < D * D; j++)
    in[j] = body.first + D + j;
  char label[300];
  mrvi_fmt(label, sizeof label, "body %s", name);
  body.constraint =
      mrvi_model_add_constraint(m, "body", D * D, in, 0, NULL, label);
  if (body.constraint < 0) {
    free(body.name);
    return body.constraint;
  }
  m->bodies[m->n_bodies] = body;
  return m->n_bodies++;
}

/* ---------------------------------------------------------------------------
 * Joints: the builder turns a point and an axis given in space at the
 * initial configuration into the body-frame parameters of the constraint
 * types (constraints/joint.h), so that the initial positions meet them.
 * ------------------------------------------------------------------------- */
typedef struct joint_kind {
  const char *type;
  int dims;   /* bit mask 1 << D */
  int frame;  /* its parameters carry the joint's frame (constraints/joint.h) */
  int axis;   /* bit mask 1 << D: dimensions in which it needs an axis */
  int second; /* ... and a second axis (t_2 of its frame) */
} joint_kind;

static const joint_kind joint_kinds[] = {
    {"spherical", 1 << 3, 0, 0, 0},
    {"revolute", (1 << 2) | (1 << 3), 1, 1 << 3, 0},
    {"weld", (1 << 2) | (1 << 3), 1, 0, 0},
    {"prismatic", (1 << 2) | (1 << 3), 1, (1 << 2) | (1 << 3), 0},
    {"cylindrical", 1 << 3, 1, 1 << 3, 0},
    {"planar", 1 << 3, 1, 1 << 3, 0},
    {"universal", 1 << 3, 1, 1 << 3, 1 << 3},
};
#define N_JOINT_KINDS ((int)(sizeof joint_kinds / sizeof joint_kinds[0]))

const char *const *mrvi_joint_type_names(void) {
  static const char *names[N_JOINT_KINDS + 1];
  for (int i = 0; i < N_JOINT_KINDS; i++)
    names[i] = joint_kinds[i].type;
  return names;
}

/* Body-frame components R^T v of the space vector v (D entries) for body
 * b at the initial configuration. */
void mrvi_body_frame_of(const mrvi_model *m, int b, const double *v,
                        double *out) {
  const int D = m->bodies[b].dim;
  const double *y = m->q0 + m->bodies[b].first;
  for (int i = 0; i < D; i++) {
    out[i] = 0.0;
    for (int a = 0; a < D; a++)
      out[i] += y[D * (1 + i) + a] * v[a];
  }
}

/* The joint's frame t_1..t_D in space (D x D, row m = t_m): t_1 along the
 * axis (e_1 without one), then unit normals with (t_1, t_2, t_3)
 * right-handed (2-D: t_2 = t_1 turned by +90 degrees).  t_2 is along the
 * second axis if given (3-D, checked normal to t_1), else along the
 * coordinate axis least aligned with t_1, made normal to it. */
static void joint_frame(int D, const double *axis, const double *second,
                        double *t);
void mrvi_joint_frame(int D, const double *axis, double *t) {
  joint_frame(D, axis, NULL, t);
}

static void joint_frame(int D, const double *axis, const double *second,
                        double *t) {
  double n = 0.0;
  for (int a = 0; a < D; a++) {
    t[a] = axis ? axis[a] : a == 0;
    n += t[a] * t[a];
  }
  for (int a = 0; a < D; a++)
    t[a] /= sqrt(n);
  if (D == 2) {
    t[2] = -t[1], t[3] = t[0];
    return;
  }
  int k = 0;
  for (int a = 1; a < 3; a++)
    if (fabs(t[a]) < fabs(t[k]))
      k = a;
  n = 0.0;
  double c = 0.0;
  for (int a = 0; second && a < 3; a++)
    c += second[a] * t[a];
  for (int a = 0; a < 3; a++) {
    t[3 + a] = second ? second[a] - c * t[a] : (a == k) - t[k] * t[a];
    n += t[3 + a] * t[3 + a];
  }
  for (int a = 0; a < 3; a++)
    t[3 + a] /= sqrt(n);
  t[6] = t[1] * t[5] - t[2] * t[4];
  t[7] = t[2] * t[3] - t[0] * t[5];
  t[8] = t[0] * t[4] - t[1] * t[3];
}

int mrvi_model_add_joint(mrvi_model *m, const char *type, int body_a,
                         int body_b, const double *point, const double *axis) {
  return mrvi_model_add_joint_axes(m, type, body_a, body_b, point, axis, NULL);
}

/* The second axis of a joint that takes one: finite, not zero, not
 * parallel to the first axis (cosine within 1e-9 of +-1).  *cosine <- the
 * cosine of their angle, 0 when they are normal to 1e-9 (then the frame
 * makes them exactly normal). */
static int check_second_axis(mrvi_model *m, const char *type, const char *na,
                             const char *nb, const double *axis,
                             const double *second, double *cosine) {
  double aa = 0.0, bb = 0.0, ab = 0.0;
  for (int a = 0; a < 3; a++) {
    aa += axis[a] * axis[a];
    bb += second[a] * second[a];
    ab += axis[a] * second[a];
  }
  if (!(isfinite(bb) && bb > 0.0))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "%s joint %s-%s: the second axis must be a nonzero "
                           "finite vector",
                           type, na, nb);
  const double c = ab / sqrt(aa * bb);
  if (fabs(c) > 1.0 - 1e-9)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "%s joint %s-%s: the second axis is parallel to "
                           "the axis; a universal joint's axes (one in each "
                           "body) must make a nonzero angle (at least "
                           "%.2g degrees)",
                           type, na, nb, acos(1.0 - 1e-9) * 180.0 / M_PI);
  *cosine = fabs(c) > 1e-9 ? c : 0.0;
  return MRVI_OK;
}

int mrvi_model_add_joint_axes(mrvi_model *m, const char *type, int body_a,
                              int body_b, const double *point,
                              const double *axis, const double *second) {
  const joint_kind *kind = NULL;
  for (int i = 0; i < N_JOINT_KINDS; i++)
    if (type && strcmp(type, joint_kinds[i].type) == 0)
      kind = &joint_kinds[i];
  if (!kind)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "unknown joint type '%s' (joints: spherical, "
                           "revolute, weld, prismatic, cylindrical, planar, "
                           "universal)",
                           type ? type : "(null)");
  if (body_a < 0 || body_a >= m->n_bodies || body_b >= m->n_bodies)
    return mrvi_model_fail(
        m, MRVI_EINVAL, "%s joint: unknown body (index %d)", type,
        body_a < 0 || body_a >= m->n_bodies ? body_a : body_b);
  const char *na = m->bodies[body_a].name,
             *nb = body_b >= 0 ? m->bodies[body_b].name : "ground";
  if (body_a == body_b)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "%s joint between body '%s' and itself", type, na);
  const int D = m->bodies[body_a].dim;
  if (!(kind->dims & (1 << D)))
    return mrvi_model_fail(
        m, MRVI_EINVAL, "%s joint %s-%s: no %s joint in %d-D (%s)", type, na,
        nb, type, D,
        D == 2 ? "a 2-D hinge is the revolute joint" : "use a 2-D model");
  if (!point)
    return mrvi_model_fail(m, MRVI_EINVAL, "%s joint %s-%s: no point", type, na,
                           nb);
  const int needs_axis = (kind->axis >> D) & 1;
  if (needs_axis != (axis != NULL))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           needs_axis ? "%s joint %s-%s: a %d-D %s joint needs "
                                        "an axis"
                                      : "%s joint %s-%s: a %d-D %s joint takes "
                                        "no axis",
                           type, na, nb, D, type);
  const int needs_second = (kind->second >> D) & 1;
  if (needs_second != (second != NULL))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           needs_second ? "%s joint %s-%s: a %d-D %s joint "
                                          "needs a second axis (fixed in %s)"
                                        : "%s joint %s-%s: a %d-D %s joint "
                                          "takes no second axis%s",
                           type, na, nb, D, type, needs_second ? nb : "");
  double par[MRVI_MAX_INPUTS];
  int n_par = 0, in[24], n_in = 0;
  par[n_par++] = D;
  par[n_par++] = body_b >= 0 ? 2 : 1;
  const int bodies[2] = {body_a, body_b};
  for (int s = 0; s < 2; s++) {
    if (bodies[s] < 0) { /* the ground point, in space */
      for (int a = 0; a < D; a++)
        par[n_par++] = point[a];
      continue;
    }
    const mrvi_body *bd = &m->bodies[bodies[s]];
    double r[3];
    for (int a = 0; a < D; a++) {
      if (!isfinite(point[a]))
        return mrvi_model_fail(m, MRVI_EINVAL,
                               "%s joint %s-%s: point must be finite", type, na,
                               nb);
      r[a] = point[a] - m->q0[bd->first + a];
    }
    mrvi_body_frame_of(m, bodies[s], r, par + n_par);
    n_par += D;
    for (int j = 0; j < D * (D + 1); j++)
      in[n_in++] = bd->first + j;
  }
  if (kind->frame) {
    double nn = 0.0, t[9];
    for (int a = 0; axis && a < (D == 3 ? 3 : 2); a++)
      nn += axis[a] * axis[a];
    if (axis && !(isfinite(nn) && nn > 0.0))
      return mrvi_model_fail(m, MRVI_EINVAL,
                             "%s joint %s-%s: the axis must be a nonzero "
                             "finite vector",
                             type, na, nb);
    double cosine = 0.0;
    const int st =
        second ? check_second_axis(m, type, na, nb, axis, second, &cosine)
               : MRVI_OK;
    if (st < 0)
      return st;
    joint_frame(D, axis, second, t);
    /* t_m in A's frame, then in B's frame (in space for the ground); an
     * oblique second axis is B's t_2 itself, unit (constraints/universal.c). */
    double tb[9];
    memcpy(tb, t, sizeof t);
    if (cosine != 0.0) {
      double bb = 0.0;
      for (int a = 0; a < 3; a++)
        bb += second[a] * second[a];
      for (int a = 0; a < 3; a++)
        tb[3 + a] = second[a] / sqrt(bb);
    }
    for (int s = 0; s < 2; s++)
      for (int k = 0; k < D; k++, n_par += D) {
        const double *v = (s ? tb : t) + D * k;
        if (bodies[s] >= 0)
          mrvi_body_frame_of(m, bodies[s], v, par + n_par);
        else
          memcpy(par + n_par, v, (size_t)D * sizeof *v);
      }
    if (cosine != 0.0)
      par[n_par++] = cosine; /* a_1 . b_2 = cos(alpha) */
  }
  char label[300];
  mrvi_fmt(label, sizeof label, "%s %s-%s", type, na, nb);
  return mrvi_model_add_constraint(m, type, n_in, in, n_par, par, label);
}

/* ---------------------------------------------------------------------------
 * Derived outputs: angular velocity and joint reactions (doc/multibody.md,
 * "Angular velocity" and "Joint reactions")
 * ------------------------------------------------------------------------- */

void mrvi_model_body_angular_velocity(const mrvi_model *m, int b,
                                      const double *q, const double *p,
                                      double *omega) {
  const mrvi_body *bd = &m->bodies[b];
  const int D = bd->dim;
  const double *d = q + bd->first + D, *pd = p + bd->first + D;
  if (D == 2) {
    /* L = sum_i d_i x p_{d_i} (scalar), J = E_1 + E_2. */
    double L = 0.0;
    for (int i = 0; i < 2; i++)
      L += d[2 * i] * pd[2 * i + 1] - d[2 * i + 1] * pd[2 * i];
    omega[0] = L / bd->inertia[0];
    return;
  }
  /* L = sum_i d_i x p_{d_i} in space; omega = R J^-1 R^T L. */
  double L[3] = {0.0, 0.0, 0.0};
  for (int i = 0; i < 3; i++) {
    const double *u = d + 3 * i, *v = pd + 3 * i;
    L[0] += u[1] * v[2] - u[2] * v[1];
    L[1] += u[2] * v[0] - u[0] * v[2];
    L[2] += u[0] * v[1] - u[1] * v[0];
  }
  for (int a = 0; a < 3; a++)
    omega[a] = 0.0;
  for (int i = 0; i < 3; i++) {
    const double *u = d + 3 * i;
    const double w = (u[0] * L[0] + u[1] * L[1] + u[2] * L[2]) / bd->inertia[i];
    for (int a = 0; a < 3; a++)
      omega[a] += w * u[a];
  }
}

/* Joint kind of constraint c, or NULL when c is not a joint. */
static const joint_kind *joint_kind_of(const mrvi_constraint *c) {
  for (int i = 0; i < N_JOINT_KINDS; i++)
    if (strcmp(c->type->name, joint_kinds[i].type) == 0)
      return &joint_kinds[i];
  return NULL;
}

int mrvi_model_n_joints(const mrvi_model *m) {
  int n = 0;
  for (int c = 0; c < m->n_constraints; c++)
    n += joint_kind_of(&m->constraints[c]) != NULL;
  return n;
}

int mrvi_model_joint_constraint(const mrvi_model *m, int j) {
  for (int c = 0; c < m->n_constraints && j >= 0; c++)
    if (joint_kind_of(&m->constraints[c]) && j-- == 0)
      return c;
  return -1;
}

int mrvi_model_joint_bodies(const mrvi_model *m, int j, int *body_a,
                            int *body_b) {
  const int c = mrvi_model_joint_constraint(m, j);
  if (c < 0)
    return MRVI_EINVAL;
  const mrvi_constraint *k = &m->constraints[c];
  const int a = mrvi_model_body_of(m, k->in[0]);
  const int D = m->bodies[a].dim, nb = D * (D + 1);
  if (body_a)
    *body_a = a;
  if (body_b)
    *body_b = k->n_in > nb ? mrvi_model_body_of(m, k->in[nb]) : -1;
  return MRVI_OK;
}

int mrvi_model_joint_reaction(const mrvi_model *m, int j, const double *q,
                              const double *lambda, double *force,
                              double *torque) {
  const int c = mrvi_model_joint_constraint(m, j);
  if (c < 0)
    return MRVI_EINVAL;
  const mrvi_constraint *k = &m->constraints[c];
  const mrvi_body *bd = &m->bodies[mrvi_model_body_of(m, k->in[0])];
  const int D = bd->dim, n_in = k->n_in;
  double y[24], g[6], G[6 * 24];
  for (int i = 0; i < n_in; i++)
    y[i] = q[k->in[i]];
  mrvi_constraint_eval_at(k, y, g, G, NULL);
  /* Generalised force on body A's inputs (the first D (D + 1)):
   * f = -G_A^T lambda. */
  double f[12];
  for (int i = 0; i < D * (D + 1); i++) {
    f[i] = 0.0;
    for (int r = 0; r < k->rows; r++)
      f[i] -= G[r * n_in + i] * lambda[k->first_row + r];
  }
  /* Force: the phi block.  Torque about the joint point x_A = phi_A +
   * sum_i rho_A^i d_i (rho_A: params 2 .. 2 + D, constraints/joint.h):
   * sum_i d_i x f_{d_i} about phi_A, minus (x_A - phi_A) x force. */
  const double *rho = k->params + 2, *d = y + D;
  double arm[3] = {0.0, 0.0, 0.0};
  for (int i = 0; i < D; i++)
    for (int a = 0; a < D; a++)
      arm[a] += rho[i] * d[D * i + a];
  for (int a = 0; a < D; a++)
    force[a] = f[a];
  if (D == 2) {
    double t = -(arm[0] * f[1] - arm[1] * f[0]);
    for (int i = 0; i < 2; i++) {
      const double *u = d + 2 * i, *v = f + 2 + 2 * i;
      t += u[0] * v[1] - u[1] * v[0];
    }
    torque[0] = t;
    return MRVI_OK;
  }
  double t[3] = {-(arm[1] * f[2] - arm[2] * f[1]),
                 -(arm[2] * f[0] - arm[0] * f[2]),
                 -(arm[0] * f[1] - arm[1] * f[0])};
  for (int i = 0; i < 3; i++) {
    const double *u = d + 3 * i, *v = f + 3 + 3 * i;
    t[0] += u[1] * v[2] - u[2] * v[1];
    t[1] += u[2] * v[0] - u[0] * v[2];
    t[2] += u[0] * v[1] - u[1] * v[0];
  }
  memcpy(torque, t, sizeof t);
  return MRVI_OK;
}

int mrvi_model_joint_point(const mrvi_model *m, int j, const double *q,
                           double *x) {
  const int c = mrvi_model_joint_constraint(m, j);
  if (c < 0)
    return MRVI_EINVAL;
  const mrvi_constraint *k = &m->constraints[c];
  const int first = k->in[0], D = m->bodies[mrvi_model_body_of(m, first)].dim;
  const double *rho = k->params + 2; /* constraints/joint.h */
  for (int a = 0; a < D; a++) {
    x[a] = q[first + a];
    for (int i = 0; i < D; i++)
      x[a] += rho[i] * q[first + D * (1 + i) + a];
  }
  return MRVI_OK;
}

int mrvi_model_free_bodies_only(const mrvi_model *m) {
  if (m->n_bodies == 0)
    return 0;
  for (int c = 0; c < m->n_constraints; c++) {
    int own = 0;
    for (int b = 0; b < m->n_bodies; b++)
      own |= m->bodies[b].constraint == c;
    if (!own)
      return 0;
  }
  return 1;
}
