/* `springs:` of a description file: a law on the distance between two
 * ends (particles or body points), or between an end and an anchor. */
#include "io/loader/loader_internal.h"

#include <math.h>
#include <string.h>

static const char *const spring_keys[] = {"between", "anchor", "law",
                                          "rest_length", "potential"};

/* `rest_length:` of a spring: a number, `initial` (the initial distance:
 * NAN for mrvi_model_add_end_spring) or absent (0). */
static int spring_rest(loader *L, struct fy_node *item, double *rest) {
  struct fy_node *n = mrvi_ld_get(item, "rest_length");
  *rest = 0.0;
  if (n && fy_node_is_scalar(n) && !strcmp(mrvi_ld_scalar0(n), "initial")) {
    *rest = NAN;
    return MRVI_OK;
  }
  return n ? mrvi_ld_as_number(L, n, "rest_length (a number or 'initial')",
                               rest)
           : MRVI_OK;
}

int mrvi_ld_springs(loader *L, struct fy_node *list, int dim) {
  int st = mrvi_ld_want_list(L, list, "springs");
  if (st)
    return st;
  void *it = NULL;
  struct fy_node *item;
  for (int i = 0; (item = fy_node_sequence_iterate(list, &it)); i++) {
    char where[64];
    mrvi_fmt(where, sizeof where, "springs.%d", i);
    const mrvi_law *law = NULL;
    double params[MRVI_LAW_MAX_PARAMS] = {0}, rest, anchor[3] = {0, 0, 0};
    int pi[2], ends;
    mrvi_end pt[2];
    mrvi_rate potential;
    if ((st = mrvi_ld_want_mapping(L, item, where)) ||
        (st = mrvi_ld_law(L, item, where, spring_keys, COUNT(spring_keys), &law,
                          params)) ||
        (st = mrvi_ld_ends(L, item, where, "spring", "between", "anchor", dim,
                           pi, pt, &ends, anchor)) ||
        (st = spring_rest(L, item, &rest)) ||
        (st = mrvi_ld_as_rate(L, item, "potential", &potential)))
      return st;
    int e = mrvi_model_add_end_spring(L->sys->model, potential, &pt[0],
                                      ends == 2 ? &pt[1] : NULL, anchor,
                                      law->name, params, rest);
    if (e < 0)
      return mrvi_ld_fail_model(L, item, e);
  }
  return MRVI_OK;
}
