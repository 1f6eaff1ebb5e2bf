/* `particles:` of a description file: point masses {name, mass, position,
 * velocity, rate} in `dimension` dimensions. */
#include "io/loader/loader_internal.h"

#include <stdlib.h>

static const char *const particle_keys[] = {"name", "mass", "position",
                                            "velocity", "rate"};

int mrvi_ld_particles(loader *L, struct fy_node *list, int dim) {
  int st = mrvi_ld_want_list(L, list, "particles");
  if (st)
    return st;
  int count = fy_node_sequence_item_count(list);
  L->parts = calloc((size_t)count + 1, sizeof *L->parts);
  if (!L->parts)
    return mrvi_ld_fail_nomem(L);
  void *it = NULL;
  struct fy_node *item, *nn, *v;
  for (int i = 0; (item = fy_node_sequence_iterate(list, &it)); i++) {
    char where[64];
    mrvi_fmt(where, sizeof where, "particles.%d", i);
    const char *name;
    double mass, x0[3] = {0, 0, 0}, v0[3] = {0, 0, 0};
    mrvi_rate rate;
    if ((st = mrvi_ld_want_mapping(L, item, where)) ||
        (st = mrvi_ld_check_keys(L, item, where, particle_keys,
                                 COUNT(particle_keys), NULL, 0)) ||
        (st = mrvi_ld_new_name(L, item, where, "particle", L->parts,
                               &L->part_hash, &nn, &name)) ||
        (st = mrvi_ld_need(L, item, "mass", where, &v)) ||
        (st = mrvi_ld_as_number(L, v, "mass", &mass)))
      return st;
    if (mass <= 0)
      return mrvi_ld_fail(L, v, "mass must be > 0, got %s", mrvi_ld_scalar0(v));
    if ((st = mrvi_ld_need(L, item, "position", where, &v)) ||
        (st = mrvi_ld_as_vector(L, v, "position", dim, x0)))
      return st;
    if ((v = mrvi_ld_get(item, "velocity")) &&
        (st = mrvi_ld_as_vector(L, v, "velocity", dim, v0)))
      return st;
    if ((st = mrvi_ld_as_rate(L, item, "rate", &rate)))
      return st;
    int idx = mrvi_model_add_particle(L->sys->model, name, mass, rate, x0, v0);
    if (idx < 0)
      return mrvi_ld_fail_model(L, item, idx);
    if (mrvi_ld_hash_put(&L->part_hash, name, L->n_parts))
      return mrvi_ld_fail_nomem(L);
    L->parts[L->n_parts++] = (named){name, nn, idx};
  }
  return MRVI_OK;
}
