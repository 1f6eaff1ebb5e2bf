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

/* Unknown name among the model's particles or coordinates (particles = 0)
 * with a suggestion, in index order (the generated names made for it). */
static int fail_unknown_model_name(loader *L, struct fy_node *at, int particles,
                                   const char *name) {
  const mrvi_model *m = L->sys->model;
  const int n = particles ? mrvi_model_n_particles(m) : mrvi_model_n(m);
  const char **cand = malloc((size_t)(n > 0 ? n : 1) * sizeof *cand);
  char *made = cand ? mrvi_model_names(m, particles, cand) : NULL;
  if (!made) {
    free(cand);
    return mrvi_ld_fail_nomem(L);
  }
  const char *kind = particles ? "particle" : "coordinate";
  const char *c = mrvi_closest(name, cand, n);
  const int st = c ? mrvi_ld_fail(L, at, "unknown %s '%s'; did you mean '%s'?",
                                  kind, name, c)
                   : mrvi_ld_fail(L, at, "unknown %s '%s'", kind, name);
  free(made);
  free(cand);
  return st;
}

/* Particle named by the string node n: one of `particles:`, or a generated
 * one (its name by its generator's rule: the model finds it). */
int mrvi_ld_find_particle(loader *L, struct fy_node *n, const char *what,
                          int *index) {
  const char *pname;
  int st = mrvi_ld_as_string(L, n, what, &pname);
  if (st)
    return st;
  const named *p = mrvi_ld_find_named(L->parts, &L->part_hash, pname);
  const int generated = p ? -1 : mrvi_model_find_particle(L->sys->model, pname);
  if (!p && generated < 0)
    return fail_unknown_model_name(L, n, 1, pname);
  *index = p ? p->index : generated;
  return MRVI_OK;
}

/* Model coordinate named by the string node n (coordinates and particle
 * coordinates such as m1.x). */
int mrvi_ld_find_coordinate(loader *L, struct fy_node *n, const char *what,
                            int *index) {
  const char *cname;
  int st = mrvi_ld_as_string(L, n, what, &cname);
  if (st)
    return st;
  if ((*index = mrvi_model_find_coordinate(L->sys->model, cname)) >= 0)
    return MRVI_OK;
  return fail_unknown_model_name(L, n, 0, cname);
}
