/* `forces:` of a description file: constant forces on a particle or a
 * coordinate. */
#include "io/loader/loader_internal.h"

static const char *const force_keys[] = {"particle", "coordinate", "force",
                                         "potential"};

/* {particle: a, force: [fx, fy, fz]} or {coordinate: q, force: f}, with
 * potential slow (default) or fast. */
int mrvi_ld_forces(loader *L, struct fy_node *list, int dim) {
  int st = mrvi_ld_want_list(L, list, "forces");
  int count = st ? 0 : fy_node_sequence_item_count(list);
  for (int i = 0; i < count && !st; i++) {
    struct fy_node *item = fy_node_sequence_get_by_index(list, i), *n, *f;
    char where[64];
    mrvi_fmt(where, sizeof where, "forces.%d", i);
    int coords[3], k = 1;
    double force[3] = {0, 0, 0};
    mrvi_rate potential;
    if ((st = mrvi_ld_want_mapping(L, item, where)) ||
        (st = mrvi_ld_check_keys(L, item, where, force_keys, COUNT(force_keys),
                                 NULL, 0)) ||
        (st = mrvi_ld_need(L, item, "force", where, &f)) ||
        (st = mrvi_ld_as_rate(L, item, "potential", &potential)))
      break;
    struct fy_node *pn = mrvi_ld_get(item, "particle"),
                   *cn = mrvi_ld_get(item, "coordinate");
    if (!pn == !cn) {
      st = mrvi_ld_fail(
          L, item, "%s needs exactly one of 'particle' or 'coordinate'", where);
      break;
    }
    if (pn) {
      int p;
      if ((st = mrvi_ld_find_particle(L, pn, "particle", &p)) ||
          (st = mrvi_ld_as_vector(L, f, "force", dim, force)))
        break;
      const int first = mrvi_particle_first(L->sys->model, p);
      for (int a = 0; a < dim; a++)
        coords[a] = first + a;
      k = dim;
    } else if ((st =
                    mrvi_ld_find_coordinate(L, cn, "coordinate", &coords[0])) ||
               (st = mrvi_ld_as_number(L, f, "force", &force[0]))) {
      break;
    }
    (void)n;
    int e = mrvi_model_add_force(L->sys->model, potential, k, coords, force);
    if (e < 0)
      st = mrvi_ld_fail_model(L, item, e);
  }
  return st;
}
