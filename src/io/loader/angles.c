/* `angles:` of a description file: bending k [1 - cos(theta - theta0)] at
 * the vertex j of particles [i, j, k]. */
#include "io/loader/loader_internal.h"

#include <math.h>
#include <string.h>

static const char *const angle_keys[] = {"particles", "stiffness", "rest_angle",
                                         "potential"};

/* {particles: [i, j, k], stiffness, rest_angle (radians, default initial),
 *  potential} */
int mrvi_ld_angles(loader *L, struct fy_node *list) {
  int st = mrvi_ld_want_list(L, list, "angles");
  int count = st ? 0 : fy_node_sequence_item_count(list);
  for (int i = 0; i < count && !st; i++) {
    struct fy_node *item = fy_node_sequence_get_by_index(list, i), *ps, *n;
    char where[64];
    mrvi_fmt(where, sizeof where, "angles.%d", i);
    int pi[3];
    double k, rest = NAN;
    mrvi_rate potential;
    if ((st = mrvi_ld_want_mapping(L, item, where)) ||
        (st = mrvi_ld_check_keys(L, item, where, angle_keys, COUNT(angle_keys),
                                 NULL, 0)) ||
        (st = mrvi_ld_need(L, item, "particles", where, &ps)) ||
        (st = mrvi_ld_want_list(L, ps, "particles")))
      break;
    if (fy_node_sequence_item_count(ps) != 3) {
      st = mrvi_ld_fail(L, ps,
                        "particles of an angle must be [i, j, k] (vertex j), "
                        "got %d names",
                        fy_node_sequence_item_count(ps));
      break;
    }
    for (int a = 0; a < 3 && !st; a++)
      st = mrvi_ld_find_particle(L, fy_node_sequence_get_by_index(ps, a),
                                 "particles", &pi[a]);
    if (st || (st = mrvi_ld_need(L, item, "stiffness", where, &n)) ||
        (st = mrvi_ld_as_number(L, n, "stiffness", &k)) ||
        (st = mrvi_ld_as_rate(L, item, "potential", &potential)))
      break;
    if ((n = mrvi_ld_get(item, "rest_angle")) &&
        !(fy_node_is_scalar(n) && !strcmp(mrvi_ld_scalar0(n), "initial")) &&
        (st = mrvi_ld_as_number(L, n, "rest_angle (radians or 'initial')",
                                &rest)))
      break;
    int e = mrvi_model_add_angle(L->sys->model, potential, pi[0], pi[1], pi[2],
                                 k, rest);
    if (e < 0)
      st = mrvi_ld_fail_model(L, item, e);
  }
  return st;
}
