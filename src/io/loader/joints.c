/* `joints:` of a description file (doc/multibody.md): {type, bodies,
 * point, axis, second_axis, name, spring}; one body joins it to the
 * ground, two join them.  point and the axes are in space at the initial
 * configuration (mrvi_model_add_joint_axes stores them in the bodies'
 * frames).  `spring:` on
 * a revolute joint is a torsional spring about its axis
 * (mrvi_model_add_torsion): {law, the law's parameters, rest_angle,
 * potential}. */
#include "io/loader/loader_internal.h"

#include <stdlib.h>
#include <string.h>

static const char *const joint_keys[] = {
    "type", "bodies", "point", "axis", "second_axis", "name", "spring"};
static const char *const torsion_keys[] = {"law", "rest_angle", "potential"};

/* `spring:` of joint `where` between bodies b (b[1] < 0: the ground). */
static int load_torsion(loader *L, struct fy_node *sn, const char *type,
                        const char *where, const int *b, const double *axis) {
  char at[96];
  mrvi_fmt(at, sizeof at, "%s.spring", where);
  if (strcmp(type, "revolute"))
    return mrvi_ld_fail(L, sn,
                        "%s: a torsional spring needs a revolute joint (this "
                        "one is %s)",
                        at, type);
  const mrvi_law *law = NULL;
  double params[MRVI_LAW_MAX_PARAMS] = {0}, rest = 0.0;
  mrvi_rate potential;
  int st;
  if ((st = mrvi_ld_want_mapping(L, sn, at)) ||
      (st = mrvi_ld_law(L, sn, at, torsion_keys, COUNT(torsion_keys), &law,
                        params)) ||
      (st = mrvi_ld_opt_number(L, sn, "rest_angle", 0.0, &rest)) ||
      (st = mrvi_ld_as_rate(L, sn, "potential", &potential)))
    return st;
  mrvi_model *m = L->sys->model;
  const int e = mrvi_model_add_torsion(m, potential, b[0], b[1], axis,
                                       law->name, params, rest);
  return e < 0 ? mrvi_ld_fail_model(L, sn, e) : MRVI_OK;
}

/* Body named by the string node n. */
static int find_body(loader *L, struct fy_node *n, int *b) {
  const mrvi_model *m = L->sys->model;
  const char *name;
  int st = mrvi_ld_as_string(L, n, "body", &name);
  if (st)
    return st;
  if ((*b = mrvi_model_find_body(m, name)) >= 0)
    return MRVI_OK;
  const int nb = mrvi_model_n_bodies(m);
  const char **names = malloc((size_t)(nb + 1) * sizeof *names);
  if (!names)
    return mrvi_ld_fail_nomem(L);
  for (int i = 0; i < nb; i++)
    names[i] = mrvi_model_body_name(m, i);
  char hint[400];
  mrvi_ld_suggest(hint, sizeof hint, name, names, nb);
  free(names);
  return mrvi_ld_fail(L, n, "unknown body '%s'%s", name, nb ? hint : "");
}

static int load_joint(loader *L, struct fy_node *item, int i, int dim) {
  char where[64];
  mrvi_fmt(where, sizeof where, "joints.%d", i);
  struct fy_node *tn, *bn, *pn, *an, *xn, *nn;
  double point[3], axis[3], second[3];
  const char *const *types = mrvi_joint_type_names();
  int n_types = 0, type, b[2] = {-1, -1}, st;
  while (types[n_types])
    n_types++;
  if ((st = mrvi_ld_want_mapping(L, item, where)) ||
      (st = mrvi_ld_check_keys(L, item, where, joint_keys, COUNT(joint_keys),
                               NULL, 0)) ||
      (st = mrvi_ld_need(L, item, "type", where, &tn)) ||
      (st = mrvi_ld_as_choice(L, tn, "joint type", types, n_types, &type)) ||
      (st = mrvi_ld_need(L, item, "bodies", where, &bn)) ||
      (st = mrvi_ld_want_list(L, bn, "bodies")))
    return st;
  const int count = fy_node_sequence_item_count(bn);
  if (count < 1 || count > 2)
    return mrvi_ld_fail(L, bn,
                        "bodies: one body (joined to the ground) or two, got "
                        "%d",
                        count);
  for (int k = 0; k < count; k++)
    if ((st = find_body(L, fy_node_sequence_get_by_index(bn, k), &b[k])))
      return st;
  if (count == 2 && b[0] == b[1])
    return mrvi_ld_fail(L, bn, "a joint between body '%s' and itself",
                        mrvi_model_body_name(L->sys->model, b[0]));
  if ((st = mrvi_ld_need(L, item, "point", where, &pn)) ||
      (st = mrvi_ld_as_vector(L, pn, "point", dim, point)))
    return st;
  if ((an = mrvi_ld_get(item, "axis")) &&
      (st = mrvi_ld_as_unit(L, an, "axis", dim, axis)))
    return st;
  if ((xn = mrvi_ld_get(item, "second_axis")) &&
      (st = mrvi_ld_as_unit(L, xn, "second_axis", dim, second)))
    return st;
  mrvi_model *m = L->sys->model;
  const int c = mrvi_model_add_joint_axes(m, types[type], b[0], b[1], point,
                                          an ? axis : NULL, xn ? second : NULL);
  if (c < 0) {
    const char *e = mrvi_model_errmsg(m);
    return mrvi_ld_fail_model(L,
                              xn && strstr(e, "second axis") ? xn
                              : an && strstr(e, "axis")      ? an
                                                             : item,
                              c);
  }
  if ((nn = mrvi_ld_get(item, "name"))) {
    const char *label;
    if ((st = mrvi_ld_as_string(L, nn, "name", &label)))
      return st;
    for (int prev = 0; prev < c; prev++)
      if (!strcmp(label, mrvi_model_constraint_label(m, prev)))
        return mrvi_ld_fail(L, nn, "duplicate constraint name '%s'", label);
    if (mrvi_model_set_constraint_label(m, c, label) < 0)
      return mrvi_ld_fail_nomem(L);
  }
  struct fy_node *sn = mrvi_ld_get(item, "spring");
  if (sn && (st = load_torsion(L, sn, types[type], where, b, an ? axis : NULL)))
    return st;
  return mrvi_ld_constraint_item(L, c, item);
}

int mrvi_ld_joints(loader *L, struct fy_node *list, int dim) {
  int st = mrvi_ld_want_list(L, list, "joints");
  if (st)
    return st;
  void *it = NULL;
  struct fy_node *item;
  for (int i = 0; !st && (item = fy_node_sequence_iterate(list, &it)); i++)
    st = load_joint(L, item, i, dim);
  return st;
}
