/* `coordinates:` of a description file: generalised coordinates
 * {name, mass, position, velocity, rate}. */
#include "io/loader/loader_internal.h"

#include <stdlib.h>

static const char *const coordinate_keys[] = {"name", "mass", "position",
                                              "velocity", "rate"};

int mrvi_ld_coordinates(loader *L, struct fy_node *list) {
  int st = mrvi_ld_want_list(L, list, "coordinates");
  if (st)
    return st;
  int count = fy_node_sequence_item_count(list);
  L->coords = calloc((size_t)count + 1, sizeof *L->coords);
  if (!L->coords)
    return mrvi_ld_fail_nomem(L);
  void *it = NULL;
  struct fy_node *item, *nn, *v;
  for (int i = 0; (item = fy_node_sequence_iterate(list, &it)); i++) {
    char where[64];
    mrvi_fmt(where, sizeof where, "coordinates.%d", i);
    const char *name;
    double mass, q0, v0;
    mrvi_rate rate;
    if ((st = mrvi_ld_want_mapping(L, item, where)) ||
        (st = mrvi_ld_check_keys(L, item, where, coordinate_keys,
                                 COUNT(coordinate_keys), NULL, 0)) ||
        (st = mrvi_ld_new_name(L, item, where, "coordinate", L->coords,
                               &L->coord_hash, &nn, &name)) ||
        (st = mrvi_ld_need(L, item, "mass", where, &v)) ||
        (st = mrvi_ld_as_number(L, v, "mass", &mass)))
      return st;
    if (mass <= 0)
      return mrvi_ld_fail(L, v, "mass must be > 0, got %s", mrvi_ld_scalar0(v));
    if ((st = mrvi_ld_need(L, item, "position", where, &v)) ||
        (st = mrvi_ld_as_number(L, v, "position", &q0)) ||
        (st = mrvi_ld_opt_number(L, item, "velocity", 0.0, &v0)) ||
        (st = mrvi_ld_as_rate(L, item, "rate", &rate)))
      return st;
    int idx =
        mrvi_model_add_coordinate(L->sys->model, name, mass, rate, q0, v0);
    if (idx < 0)
      return mrvi_ld_fail_model(L, item, idx);
    if (mrvi_ld_hash_put(&L->coord_hash, name, L->n_coords))
      return mrvi_ld_fail_nomem(L);
    L->coords[L->n_coords++] = (named){name, nn, idx};
  }
  return MRVI_OK;
}
