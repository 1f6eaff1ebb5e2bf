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
int mrvi_ld_ends(loader *L, struct fy_node *item, const char *where,
                 const char *noun, const char *key, const char *anchor_key,
                 int dim, int pi[2], int *ends, double *anchor) {
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
  for (int e = 0; e < *ends; e++)
    if ((st = mrvi_ld_find_particle(
             L, fy_node_sequence_get_by_index(between, e), key, &pi[e])))
      return st;
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
