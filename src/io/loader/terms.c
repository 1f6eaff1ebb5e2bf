/* `terms:` of a description file: a law on a linear combination of
 * coordinates plus an offset. */
#include "io/loader/loader_internal.h"

#include <stdlib.h>

static const char *const term_keys[] = {"combination", "offset", "law",
                                        "potential"};

int mrvi_ld_terms(loader *L, struct fy_node *list) {
  int st = mrvi_ld_want_list(L, list, "terms");
  if (st)
    return st;
  int n = mrvi_model_n(L->sys->model);
  int *coords = malloc((size_t)(n + 1) * sizeof *coords);
  double *coef = malloc((size_t)(n + 1) * sizeof *coef);
  if (!coords || !coef) {
    st = mrvi_ld_fail_nomem(L);
    goto done;
  }
  void *it = NULL;
  struct fy_node *item, *comb;
  for (int i = 0; !st && (item = fy_node_sequence_iterate(list, &it)); i++) {
    char where[64];
    mrvi_fmt(where, sizeof where, "terms.%d", i);
    const mrvi_law *law = NULL;
    double params[MRVI_LAW_MAX_PARAMS] = {0}, offset;
    mrvi_rate potential;
    int k;
    if ((st = mrvi_ld_want_mapping(L, item, where)) ||
        (st = mrvi_ld_law(L, item, where, term_keys, COUNT(term_keys), &law,
                          params)) ||
        (st = mrvi_ld_need(L, item, "combination", where, &comb)) ||
        (st = mrvi_ld_combination(L, comb, coords, coef, &k)) ||
        (st = mrvi_ld_opt_number(L, item, "offset", 0.0, &offset)) ||
        (st = mrvi_ld_as_rate(L, item, "potential", &potential)))
      break;
    int e = mrvi_model_add_term(L->sys->model, potential, k, coords, coef,
                                offset, law->name, params);
    if (e < 0)
      st = mrvi_ld_fail_model(L, item, e);
  }
done:
  free(coords);
  free(coef);
  return st;
}
