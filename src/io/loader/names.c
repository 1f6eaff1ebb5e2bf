/* Names defined in a description file (coordinates and particles): a hash
 * from name to index, duplicate checks, and look-ups with suggestions. */
#include "io/loader/loader_internal.h"

#include <stdlib.h>
#include <string.h>

static size_t hash_name(const char *s) {
  size_t h = 1469598103934665603u;
  for (; *s; s++)
    h = (h ^ (unsigned char)*s) * 1099511628211u;
  return h;
}

/* Value stored for name, or -1. */
static int hash_find(const name_hash *h, const char *name) {
  if (!h->cap)
    return -1;
  for (size_t i = hash_name(name) & (h->cap - 1);; i = (i + 1) & (h->cap - 1))
    if (!h->val[i])
      return -1;
    else if (!strcmp(h->key[i], name))
      return h->val[i] - 1;
}

/* Add name -> value (name not present); MRVI_ENOMEM on failure. */
int mrvi_ld_hash_put(name_hash *h, const char *name, int value) {
  if (2 * (h->n + 1) > h->cap) {
    name_hash g = {.cap = h->cap ? 2 * h->cap : 64};
    g.key = malloc(g.cap * sizeof *g.key);
    g.val = calloc(g.cap, sizeof *g.val);
    if (!g.key || !g.val) {
      free(g.key);
      free(g.val);
      return MRVI_ENOMEM;
    }
    for (size_t i = 0; i < h->cap; i++)
      if (h->val[i])
        mrvi_ld_hash_put(&g, h->key[i], h->val[i] - 1);
    free(h->key);
    free(h->val);
    *h = g;
  }
  size_t i = hash_name(name) & (h->cap - 1);
  while (h->val[i])
    i = (i + 1) & (h->cap - 1);
  h->key[i] = name;
  h->val[i] = value + 1;
  h->n++;
  return MRVI_OK;
}

void mrvi_ld_hash_free(name_hash *h) {
  free(h->key);
  free(h->val);
}

const named *mrvi_ld_find_named(const named *tab, const name_hash *h,
                                const char *name) {
  int i = hash_find(h, name);
  return i >= 0 ? &tab[i] : NULL;
}

/* Unknown name with a suggestion among the defined ones. */
static int fail_unknown_name(loader *L, struct fy_node *at, const char *kind,
                             const char *name, const named *tab, int n) {
  const char **cand = malloc((size_t)(n > 0 ? n : 1) * sizeof *cand);
  if (!cand)
    return mrvi_ld_fail_nomem(L);
  for (int i = 0; i < n; i++)
    cand[i] = tab[i].name;
  const char *c = mrvi_closest(name, cand, n);
  free(cand);
  if (c)
    return mrvi_ld_fail(L, at, "unknown %s '%s'; did you mean '%s'?", kind,
                        name, c);
  return mrvi_ld_fail(L, at, "unknown %s '%s'", kind, name);
}

/* Name of a new coordinate or particle, rejecting duplicates. */
int mrvi_ld_new_name(loader *L, struct fy_node *item, const char *where,
                     const char *kind, const named *tab, const name_hash *h,
                     struct fy_node **name_node, const char **name) {
  int st = mrvi_ld_need(L, item, "name", where, name_node);
  if (st || (st = mrvi_ld_as_string(L, *name_node, "name", name)))
    return st;
  const named *prev = mrvi_ld_find_named(tab, h, *name);
  int line, col;
  if (prev && mrvi_ld_node_position(prev->node, &line, &col))
    return mrvi_ld_fail(L, *name_node,
                        "duplicate %s name '%s' (first defined at "
                        "line %d)",
                        kind, *name, line);
  if (prev)
    return mrvi_ld_fail(L, *name_node, "duplicate %s name '%s'", kind, *name);
  return MRVI_OK;
}

/* Particle named by the string node n. */
int mrvi_ld_find_particle(loader *L, struct fy_node *n, const char *what,
                          int *index) {
  const char *pname;
  int st = mrvi_ld_as_string(L, n, what, &pname);
  if (st)
    return st;
  const named *p = mrvi_ld_find_named(L->parts, &L->part_hash, pname);
  if (!p)
    return fail_unknown_name(L, n, "particle", pname, L->parts, L->n_parts);
  *index = p->index;
  return MRVI_OK;
}

/* Model coordinate named by the string node n (coordinates and particle
 * coordinates such as m1.x). */
int mrvi_ld_find_coordinate(loader *L, struct fy_node *n, const char *what,
                            int *index) {
  const mrvi_model *m = L->sys->model;
  const int count = mrvi_model_n(m);
  const char *cname;
  int st = mrvi_ld_as_string(L, n, what, &cname);
  if (st)
    return st;
  for (int j = (int)L->model_hash.n; j < count; j++) /* new since last */
    if (mrvi_ld_hash_put(&L->model_hash, mrvi_model_coordinate_name(m, j), j))
      return mrvi_ld_fail_nomem(L);
  if ((*index = hash_find(&L->model_hash, cname)) >= 0)
    return MRVI_OK;
  const char **names = malloc((size_t)(count + 1) * sizeof *names);
  if (!names)
    return mrvi_ld_fail_nomem(L);
  for (int j = 0; j < count; j++)
    names[j] = mrvi_model_coordinate_name(m, j);
  const char *c = mrvi_closest(cname, names, count);
  st = c ? mrvi_ld_fail(L, n, "unknown coordinate '%s'; did you mean '%s'?",
                        cname, c)
         : mrvi_ld_fail(L, n, "unknown coordinate '%s'", cname);
  free(names);
  return st;
}
