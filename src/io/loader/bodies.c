/* `bodies:` of a description file (doc/multibody.md): rigid bodies
 * {name, mass, inertia, position, orientation, velocity, angular_velocity,
 * frame, rate} in `dimension` 2 or 3, each added by mrvi_model_add_body (its
 * coordinates NAME.x .. NAME.d3z follow the particles in model order). */
#include "io/loader/loader_internal.h"

#include <math.h>
#include <string.h>

static const char *const body_keys[] = {
    "name",        "mass",     "inertia",          "position",
    "orientation", "velocity", "angular_velocity", "rate",
    "frame"};

/* `orientation:` as the rows of a D x D rotation matrix, as {axis, angle}
 * (3-D; a unit axis, the angle in radians, Rodrigues' formula), as
 * {quaternion: [w, x, y, z]} (3-D, unit) or as an angle (2-D); row-major
 * into R. */
static int load_orientation(loader *L, struct fy_node *n, int D, double *R) {
  int st;
  if (D == 2 && fy_node_is_scalar(n)) {
    double a;
    if ((st = mrvi_ld_as_number(L, n, "orientation angle", &a)))
      return st;
    R[0] = cos(a), R[1] = -sin(a), R[2] = sin(a), R[3] = cos(a);
    return MRVI_OK;
  }
  if (D == 3 && fy_node_is_mapping(n)) {
    static const char *const keys[] = {"axis", "angle", "quaternion"};
    struct fy_node *an, *gn, *qn = mrvi_ld_get(n, "quaternion");
    double k[4], a;
    if ((st = mrvi_ld_check_keys(L, n, "orientation", keys, 3, NULL, 0)))
      return st;
    if (qn) { /* [w, x, y, z], R = the rotation of the unit quaternion */
      if (mrvi_ld_get(n, "axis") || mrvi_ld_get(n, "angle"))
        return mrvi_ld_fail(L, n,
                            "orientation: give either {axis, angle} or "
                            "{quaternion}, not both");
      if ((st = mrvi_ld_as_unit(L, qn, "quaternion", 4, k)))
        return st;
      mrvi_quaternion_rotation(k[0], k[1], k[2], k[3], R);
      return MRVI_OK;
    }
    if ((st = mrvi_ld_need(L, n, "axis", "orientation", &an)) ||
        (st = mrvi_ld_as_unit(L, an, "rotation axis", 3, k)) ||
        (st = mrvi_ld_need(L, n, "angle", "orientation", &gn)) ||
        (st = mrvi_ld_as_number(L, gn, "angle", &a)))
      return st;
    const double c = cos(a), s = sin(a);
    for (int i = 0; i < 3; i++)
      for (int j = 0; j < 3; j++) {
        const double K = i == j                 ? 0.0
                         : (j - i + 3) % 3 == 1 ? -k[3 - i - j]
                                                : k[3 - i - j];
        R[i * 3 + j] = (i == j ? c : 0.0) + s * K + (1 - c) * k[i] * k[j];
      }
    return MRVI_OK;
  }
  if ((st = mrvi_ld_want_list(L, n, "orientation")))
    return st;
  if (fy_node_sequence_item_count(n) != D)
    return mrvi_ld_fail(L, n,
                        "orientation: a %d x %d rotation matrix is %d rows "
                        "(or %s)",
                        D, D, D,
                        D == 3 ? "{axis: [x, y, z], angle: radians} or "
                                 "{quaternion: [w, x, y, z]}"
                               : "an angle in radians");
  for (int i = 0; i < D; i++)
    if ((st = mrvi_ld_as_vector(L, fy_node_sequence_get_by_index(n, i),
                                "orientation row", D, R + i * D)))
      return st;
  return MRVI_OK;
}

/* The node a builder message is about: inertia, orientation, mass or the
 * entry. */
static struct fy_node *culprit(loader *L, struct fy_node *item) {
  const char *msg = mrvi_model_errmsg(L->sys->model);
  static const char *const keys[] = {"inertia", "orientation", "mass", "rate"};
  for (int i = 0; i < COUNT(keys); i++)
    if (strstr(msg, keys[i]) && mrvi_ld_get(item, keys[i]))
      return mrvi_ld_get(item, keys[i]);
  return mrvi_ld_get(item, "name") ? mrvi_ld_get(item, "name") : item;
}

static int load_body(loader *L, struct fy_node *item, int i, int D) {
  char where[64];
  mrvi_fmt(where, sizeof where, "bodies.%d", i);
  const int nw = D == 3 ? 3 : 1;
  struct fy_node *v;
  const char *name;
  double mass, J[3], x0[3], R[9], v0[3] = {0, 0, 0}, w[3] = {0, 0, 0};
  mrvi_rate rate;
  int st;
  if ((st = mrvi_ld_want_mapping(L, item, where)) ||
      (st = mrvi_ld_check_keys(L, item, where, body_keys, COUNT(body_keys),
                               NULL, 0)) ||
      (st = mrvi_ld_need(L, item, "name", where, &v)) ||
      (st = mrvi_ld_as_string(L, v, "name", &name)) ||
      (st = mrvi_ld_need(L, item, "mass", where, &v)) ||
      (st = mrvi_ld_as_number(L, v, "mass", &mass)) ||
      (st = mrvi_ld_need(L, item, "inertia", where, &v)) ||
      (st = mrvi_ld_as_vector(L, v, "inertia", nw, J)) ||
      (st = mrvi_ld_need(L, item, "position", where, &v)) ||
      (st = mrvi_ld_as_vector(L, v, "position", D, x0)) ||
      (st = mrvi_ld_as_rate(L, item, "rate", &rate)))
    return st;
  if ((v = mrvi_ld_get(item, "orientation")) &&
      (st = load_orientation(L, v, D, R)))
    return st;
  if ((v = mrvi_ld_get(item, "velocity")) &&
      (st = mrvi_ld_as_vector(L, v, "velocity", D, v0)))
    return st;
  if ((v = mrvi_ld_get(item, "angular_velocity")) &&
      (st = mrvi_ld_as_vector(L, v, "angular_velocity", nw, w)))
    return st;
  static const char *const frames[] = {"space", "body"};
  int body_frame = 0;
  if ((v = mrvi_ld_get(item, "frame")) &&
      (st = mrvi_ld_as_choice(L, v, "frame", frames, 2, &body_frame)))
    return st;
  if (body_frame) { /* v = R V, omega = R Omega (2-D: omega a scalar) */
    double Rb[9], vb[3], wb[3];
    if (!mrvi_ld_get(item, "orientation"))
      for (int r = 0; r < D * D; r++)
        Rb[r] = r % (D + 1) == 0;
    else
      memcpy(Rb, R, sizeof(double) * (size_t)(D * D));
    memcpy(vb, v0, sizeof vb);
    memcpy(wb, w, sizeof wb);
    for (int r = 0; r < D; r++) {
      v0[r] = 0;
      for (int c = 0; c < D; c++)
        v0[r] += Rb[r * D + c] * vb[c];
    }
    for (int r = 0; D == 3 && r < 3; r++) {
      w[r] = 0;
      for (int c = 0; c < 3; c++)
        w[r] += Rb[r * 3 + c] * wb[c];
    }
  }
  mrvi_model *m = L->sys->model;
  const int b =
      mrvi_model_add_body(m, name, D, rate, mass, J, x0,
                          mrvi_ld_get(item, "orientation") ? R : NULL, v0, w);
  if (b < 0)
    return mrvi_ld_fail_model(L, culprit(L, item), b);
  /* Messages about the body's internal constraint point at its entry. */
  return mrvi_ld_constraint_item(L, mrvi_model_n_constraints(m) - 1, item);
}

int mrvi_ld_bodies(loader *L, struct fy_node *list, int dim) {
  int st = mrvi_ld_want_list(L, list, "bodies");
  if (st)
    return st;
  if (dim != 2 && dim != 3)
    return mrvi_ld_fail(L, list, "rigid bodies need dimension 2 or 3 (got %d)",
                        dim);
  void *it = NULL;
  struct fy_node *item;
  for (int i = 0; !st && (item = fy_node_sequence_iterate(list, &it)); i++)
    st = load_body(L, item, i, dim);
  return st;
}
