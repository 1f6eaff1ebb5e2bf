/* What the potential elements of a description file share: a law and its
 * parameters (the law's parameter names are keys of the element), a linear
 * combination of coordinates, and the ends of a spring (also used by the
 * distance constraint). */
#include "io/loader/loader_internal.h"

#include <string.h>

/* The law named by `law:` of an element (NULL if the key is absent). */
static int find_law(loader *L, struct fy_node *item, const mrvi_law **law) {
  struct fy_node *n = mrvi_ld_get(item, "law");
  const char *name;
  int st;
  *law = NULL;
  if (!n)
    return MRVI_OK;
  if ((st = mrvi_ld_as_string(L, n, "law", &name)))
    return st;
  if ((*law = mrvi_law_find(name)))
    return MRVI_OK;
  const char *names[64];
  int count = mrvi_law_count() < 64 ? mrvi_law_count() : 64;
  for (int i = 0; i < count; i++)
    names[i] = mrvi_law_get(i)->name;
  char hint[512];
  mrvi_ld_suggest(hint, sizeof hint, name, names, count);
  return mrvi_ld_fail(L, n, "unknown law '%s'%s", name, hint);
}

/* Keys of an element: its own plus the law's parameters (of every law when
 * `law:` is missing, so that a misspelt `law` key is still found). */
static int check_element_keys(loader *L, struct fy_node *item,
                              const char *where, const char *const *keys,
                              int n_keys, const mrvi_law *law) {
  const char *params[MAX_KEYS];
  int n = 0;
  for (int i = 0; i < mrvi_law_count(); i++) {
    const mrvi_law *l = mrvi_law_get(i);
    if (law && l != law)
      continue;
    for (int j = 0; j < l->n_params && n + n_keys < MAX_KEYS; j++) {
      int dup = 0;
      for (int k = 0; k < n && !dup; k++)
        dup = !strcmp(params[k], l->param_names[j]);
      if (!dup)
        params[n++] = l->param_names[j];
    }
  }
  return mrvi_ld_check_keys(L, item, where, keys, n_keys, params, n);
}

/* Law and parameters of an element (the law's parameter names are keys). */
int mrvi_ld_law(loader *L, struct fy_node *item, const char *where,
                const char *const *keys, int n_keys, const mrvi_law **law,
                double *params) {
  struct fy_node *n;
  int st;
  if ((st = find_law(L, item, law)) ||
      (st = check_element_keys(L, item, where, keys, n_keys, *law)) ||
      (st = mrvi_ld_need(L, item, "law", where, &n)))
    return st;
  for (int i = 0; i < (*law)->n_params; i++) {
    const char *pname = (*law)->param_names[i];
    struct fy_node_pair *p = mrvi_ld_find_pair(item, pname);
    if (!p)
      return mrvi_ld_fail(L, item,
                          "missing key '%s' in %s (parameter of law '%s')",
                          pname, where, (*law)->name);
    if ((st = mrvi_ld_need(L, item, pname, where, &n)) ||
        (st = mrvi_ld_as_number(L, n, pname, &params[i])))
      return st;
  }
  return MRVI_OK;
}

/* `combination: {coordinate name: coefficient, ...}` (non-empty) into
 * coords, coef (mrvi_model_n entries each); *k gets the number of terms. */
int mrvi_ld_combination(loader *L, struct fy_node *comb, int *coords,
                        double *coef, int *k) {
  int st = mrvi_ld_want_mapping(L, comb, "combination");
  void *it = NULL;
  struct fy_node_pair *p;
  *k = 0;
  while (!st && (p = fy_node_mapping_iterate(comb, &it))) {
    struct fy_node *key = fy_node_pair_key(p);
    char what[128];
    if ((st = mrvi_ld_find_coordinate(L, key, "coordinate name", &coords[*k])))
      break;
    mrvi_fmt(what, sizeof what, "coefficient of %s", mrvi_ld_scalar0(key));
    if ((st = mrvi_ld_as_number(L, fy_node_pair_value(p), what, &coef[*k])))
      break;
    (*k)++;
  }
  if (!st && *k == 0)
    st = mrvi_ld_fail(L, comb, "combination is empty");
  return st;
}

/* Ends of a spring or constraint (`noun` in messages), under `key`:
 * `between: [a, b]`, or `between: [a]` with `anchor_key` (`anchor:`, dim
 * entries).
 * *ends is 1 or 2; pi gets the particle indices. */
/* A body point as an end (doc/description-files.md, "Body points"):
 * `{body: NAME, at: [X1, X2, X3]}` (body-frame components about the centre
 * of mass) or a body's name alone (its centre of mass).  A scalar naming no
 * body is left to mrvi_ld_find_particle (p->particle = 0 then). */
int mrvi_ld_end_point(loader *L, struct fy_node *n, const char *key, int dim,
                      mrvi_end *p) {
  static const char *const point_keys[] = {"body", "at"};
  const mrvi_model *m = L->sys->model;
  struct fy_node *bn, *at;
  *p = (mrvi_end){.particle = 0, .body = -1};
  if (fy_node_is_scalar(n)) {
    if ((p->body = mrvi_model_find_body(m, mrvi_ld_scalar0(n))) >= 0)
      p->particle = -1;
    return MRVI_OK;
  }
  int st;
  const char *name;
  if ((st = mrvi_ld_want_mapping(L, n, key)) ||
      (st = mrvi_ld_check_keys(L, n, key, point_keys, 2, NULL, 0)) ||
      (st = mrvi_ld_need(L, n, "body", key, &bn)) ||
      (st = mrvi_ld_as_string(L, bn, "body", &name)))
    return st;
  p->particle = -1;
  if ((p->body = mrvi_model_find_body(m, name)) < 0) {
    const char *names[64];
    const int count = mrvi_model_n_bodies(m) < 64 ? mrvi_model_n_bodies(m) : 64;
    for (int b = 0; b < count; b++)
      names[b] = mrvi_model_body_name(m, b);
    char hint[512];
    mrvi_ld_suggest(hint, sizeof hint, name, names, count);
    return mrvi_ld_fail(L, bn, "unknown body '%s'%s", name, hint);
  }
  at = mrvi_ld_get(n, "at");
  return at ? mrvi_ld_as_vector(L, at, "at (the point in the body's frame)",
                                dim, p->at)
            : MRVI_OK;
}

int mrvi_ld_ends(loader *L, struct fy_node *item, const char *where,
                 const char *noun, const char *key, const char *anchor_key,
                 int dim, int pi[2], mrvi_end *points, int *ends,
                 double *anchor) {
  struct fy_node *between, *anchor_node;
  int st;
  if ((st = mrvi_ld_need(L, item, key, where, &between)) ||
      (st = mrvi_ld_want_list(L, between, key)))
    return st;
  *ends = fy_node_sequence_item_count(between);
  if (*ends != 1 && *ends != 2)
    return mrvi_ld_fail(L, between,
                        "%s must name one particle (with %s) or two, got %d",
                        key, anchor_key, *ends);
  for (int e = 0; e < *ends; e++) {
    struct fy_node *n = fy_node_sequence_get_by_index(between, e);
    if (points && (st = mrvi_ld_end_point(L, n, key, dim, &points[e])))
      return st;
    if (points && (pi[e] = points[e].particle) < 0)
      continue;
    if ((st = mrvi_ld_find_particle(L, n, key, &pi[e])))
      return st;
    if (points)
      points[e].particle = pi[e];
  }
  anchor_node = mrvi_ld_get(item, anchor_key);
  if (*ends == 2 && anchor_node)
    return mrvi_ld_fail(L, anchor_node,
                        "%s given for a %s between two particles", anchor_key,
                        noun);
  if (*ends == 1 && !anchor_node)
    return mrvi_ld_fail(L, between, "a %s on one particle needs %s %s", noun,
                        strchr("aeiou", anchor_key[0]) ? "an" : "a",
                        anchor_key);
  if (anchor_node)
    return mrvi_ld_as_vector(L, anchor_node, anchor_key, dim, anchor);
  return MRVI_OK;
}
