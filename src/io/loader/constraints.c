/* `constraints:` of a description file (doc/constraints.md), and the check
 * of the initial data against them once the settings are known.
 *
 * Each entry adds one model constraint; its loader returns the constraint
 * index (>= 0) or a status < 0. */
#include "io/loader/loader_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* {type: distance, between: [a, b] | [a] + anchor, length} */
static int load_distance(loader *L, struct fy_node *item, const char *where,
                         int dim) {
  double anchor[3] = {0, 0, 0}, length = NAN; /* NAN: initial distance */
  int pi[2], ends, st;
  if ((st = mrvi_ld_ends(L, item, where, "distance constraint", dim, pi, &ends,
                         anchor)) ||
      (st = mrvi_ld_opt_positive(L, item, "length", "length", &length, NULL)))
    return st;
  int c = ends == 2
              ? mrvi_model_add_distance(L->sys->model, pi[0], pi[1], length)
              : mrvi_model_add_distance_anchor(L->sys->model, pi[0], anchor,
                                               length);
  return c < 0 ? mrvi_ld_fail_model(L, mrvi_ld_get(item, "between"), c) : c;
}

/* {type: fixed, particle: a, axes: [x, z], position: [...]} */
static int load_fixed(loader *L, struct fy_node *item, const char *where,
                      int dim) {
  static const char *const axis_names[] = {"x", "y", "z"};
  struct fy_node *n, *axes_node = mrvi_ld_get(item, "axes");
  double position[3] = {0, 0, 0};
  int axes[3] = {0, 0, 0}, p, st;
  if ((st = mrvi_ld_need(L, item, "particle", where, &n)) ||
      (st = mrvi_ld_find_particle(L, n, "particle", &p)))
    return st;
  if (axes_node) {
    if ((st = mrvi_ld_want_list(L, axes_node, "axes")))
      return st;
    const int count = fy_node_sequence_item_count(axes_node);
    if (count == 0)
      return mrvi_ld_fail(L, axes_node,
                          "axes is empty (omit it to pin every axis)");
    for (int i = 0; i < count; i++) {
      struct fy_node *a = fy_node_sequence_get_by_index(axes_node, i);
      int which;
      for (int k = dim; k < 3; k++)
        if (fy_node_is_scalar(a) && !strcmp(mrvi_ld_scalar0(a), axis_names[k]))
          return mrvi_ld_fail(L, a, "axis '%s' does not exist in %d-D",
                              axis_names[k], dim);
      if ((st = mrvi_ld_as_choice(L, a, "axis", axis_names, dim, &which)))
        return st;
      if (axes[which])
        return mrvi_ld_fail(L, a, "axis '%s' listed twice", axis_names[which]);
      axes[which] = 1;
    }
  }
  if ((n = mrvi_ld_get(item, "position")) &&
      (st = mrvi_ld_as_vector(L, n, "position", dim, position)))
    return st;
  int c = mrvi_model_add_fixed(L->sys->model, p, axes_node ? axes : NULL,
                               n ? position : NULL);
  return c < 0 ? mrvi_ld_fail_model(L, item, c) : c;
}

/* {type: plane, particle: a, normal: [...], offset: c} */
static int load_plane(loader *L, struct fy_node *item, const char *where,
                      int dim) {
  struct fy_node *n, *normal_node;
  double normal[3] = {0, 0, 0}, offset;
  int p, st;
  if ((st = mrvi_ld_need(L, item, "particle", where, &n)) ||
      (st = mrvi_ld_find_particle(L, n, "particle", &p)) ||
      (st = mrvi_ld_need(L, item, "normal", where, &normal_node)) ||
      (st = mrvi_ld_as_vector(L, normal_node, "normal", dim, normal)) ||
      (st = mrvi_ld_opt_number(L, item, "offset", NAN, &offset)))
    return st;
  int c = mrvi_model_add_plane(L->sys->model, p, normal, offset);
  return c < 0 ? mrvi_ld_fail_model(L, normal_node, c) : c;
}

/* {type: linear, combination: {q1: 1, m1.x: -1}, value: b} */
static int load_linear(loader *L, struct fy_node *item, const char *where,
                       int dim) {
  (void)dim;
  struct fy_node *comb;
  const int n = mrvi_model_n(L->sys->model);
  int *coords = malloc((size_t)(n + 1) * sizeof *coords);
  double *coef = malloc((size_t)(n + 1) * sizeof *coef), value;
  int k, st;
  if (!coords || !coef)
    st = mrvi_ld_fail_nomem(L);
  else if (!(st = mrvi_ld_need(L, item, "combination", where, &comb)) &&
           !(st = mrvi_ld_combination(L, comb, coords, coef, &k)) &&
           !(st = mrvi_ld_opt_number(L, item, "value", NAN, &value))) {
    st =
        mrvi_model_add_linear_constraint(L->sys->model, k, coords, coef, value);
    if (st < 0)
      st = mrvi_ld_fail_model(L, comb, st);
  }
  free(coords);
  free(coef);
  return st;
}

/* A registered type without its own syntax:
 * {type: NAME, coordinates: [names...], parameters: [numbers...]} */
static int load_generic(loader *L, struct fy_node *item, const char *where,
                        const char *type, const char *label) {
  struct fy_node *list, *par = mrvi_ld_get(item, "parameters");
  int st;
  if ((st = mrvi_ld_need(L, item, "coordinates", where, &list)) ||
      (st = mrvi_ld_want_list(L, list, "coordinates")) ||
      (par && (st = mrvi_ld_want_list(L, par, "parameters"))))
    return st;
  const int n_in = fy_node_sequence_item_count(list);
  const int n_par = par ? fy_node_sequence_item_count(par) : 0;
  if (n_in == 0)
    return mrvi_ld_fail(L, list, "coordinates is empty");
  int *coords = malloc((size_t)n_in * sizeof *coords);
  double *params = malloc((size_t)(n_par + 1) * sizeof *params);
  if (!coords || !params)
    st = mrvi_ld_fail_nomem(L);
  for (int j = 0; j < n_in && !st; j++)
    st = mrvi_ld_find_coordinate(L, fy_node_sequence_get_by_index(list, j),
                                 "coordinates", &coords[j]);
  for (int j = 0; j < n_par && !st; j++) {
    char what[64];
    mrvi_fmt(what, sizeof what, "parameters[%d]", j);
    st = mrvi_ld_as_number(L, fy_node_sequence_get_by_index(par, j), what,
                           &params[j]);
  }
  if (!st) {
    st = mrvi_model_add_constraint(L->sys->model, type, n_in, coords, n_par,
                                   params, label);
    if (st < 0)
      st = mrvi_ld_fail_model(L, item, st);
  }
  free(coords);
  free(params);
  return st;
}

/* The types with their own syntax; any other registered type takes
 * `coordinates` and `parameters`. */
typedef struct constraint_syntax {
  const char *type;
  const char *const keys[6];
  int (*load)(loader *L, struct fy_node *item, const char *where, int dim);
} constraint_syntax;

static const constraint_syntax constraint_syntaxes[] = {
    {"distance",
     {"type", "name", "between", "anchor", "length"},
     load_distance},
    {"fixed", {"type", "name", "particle", "axes", "position"}, load_fixed},
    {"plane", {"type", "name", "particle", "normal", "offset"}, load_plane},
    {"linear", {"type", "name", "combination", "value"}, load_linear},
    {NULL, {"type", "name", "coordinates", "parameters"}, NULL},
};

static int syntax_keys(const constraint_syntax *s, const char **keys) {
  int n = 0;
  while (n < COUNT(s->keys) && s->keys[n])
    keys[n] = s->keys[n], n++;
  return n;
}

/* Keys of every syntax (for an entry without `type:`). */
static int all_constraint_keys(const char **keys) {
  int n = 0;
  for (int i = 0; i < COUNT(constraint_syntaxes); i++) {
    const char *own[COUNT(constraint_syntaxes[0].keys)];
    const int k = syntax_keys(&constraint_syntaxes[i], own);
    for (int j = 0; j < k; j++) {
      int dup = 0;
      for (int l = 0; l < n && !dup; l++)
        dup = !strcmp(keys[l], own[j]);
      if (!dup)
        keys[n++] = own[j];
    }
  }
  return n;
}

/* Label of constraint c: the entry's `name:` (unique), else the builder's,
 * made unique by the entry's path so that messages name one constraint. */
static int label_constraint(loader *L, struct fy_node *item, const char *where,
                            int c) {
  mrvi_model *m = L->sys->model;
  struct fy_node *n = mrvi_ld_get(item, "name");
  const char *label = mrvi_model_constraint_label(m, c);
  char buf[600];
  int st;
  if (n && (st = mrvi_ld_as_string(L, n, "name", &label)))
    return st;
  for (int prev = 0; prev < c; prev++) {
    if (strcmp(label, mrvi_model_constraint_label(m, prev)))
      continue;
    int line, col;
    if (n && mrvi_ld_node_position(L->constraint_items[prev], &line, &col))
      return mrvi_ld_fail(
          L, n, "duplicate constraint name '%s' (constraint at line %d)", label,
          line);
    if (n)
      return mrvi_ld_fail(L, n, "duplicate constraint name '%s'", label);
    mrvi_fmt(buf, sizeof buf, "%s (%s)", label, where);
    label = buf;
    break;
  }
  if (label == mrvi_model_constraint_label(m, c))
    return MRVI_OK;
  /* The builders take no label: replace the one they made. */
  if (mrvi_model_set_constraint_label(m, c, label) < 0)
    return mrvi_ld_fail_nomem(L);
  return MRVI_OK;
}

static int load_constraint(loader *L, struct fy_node *item, int i, int dim) {
  const char *keys[MAX_KEYS], *type_names[64];
  char where[64];
  struct fy_node *type_node;
  int st, which;
  mrvi_fmt(where, sizeof where, "constraints.%d", i);
  if ((st = mrvi_ld_want_mapping(L, item, where)))
    return st;
  if (!mrvi_ld_get(item, "type") &&
      (st = mrvi_ld_check_keys(L, item, where, keys, all_constraint_keys(keys),
                               NULL, 0)))
    return st;
  const int n_types =
      mrvi_constraint_type_count() < 64 ? mrvi_constraint_type_count() : 64;
  for (int t = 0; t < n_types; t++)
    type_names[t] = mrvi_constraint_type_get(t)->name;
  if ((st = mrvi_ld_need(L, item, "type", where, &type_node)) ||
      (st = mrvi_ld_as_choice(L, type_node, "constraint type", type_names,
                              n_types, &which)))
    return st;
  const constraint_syntax *s = constraint_syntaxes;
  while (s->type && strcmp(s->type, type_names[which]))
    s++;
  if ((st = mrvi_ld_check_keys(L, item, where, keys, syntax_keys(s, keys), NULL,
                               0)))
    return st;
  const int c = s->load ? s->load(L, item, where, dim)
                        : load_generic(L, item, where, type_names[which], NULL);
  if (c < 0)
    return c;
  L->constraint_items[c] = item;
  return label_constraint(L, item, where, c);
}

int mrvi_ld_constraints(loader *L, struct fy_node *list, int dim) {
  int st = mrvi_ld_want_list(L, list, "constraints");
  if (st)
    return st;
  const int count = fy_node_sequence_item_count(list);
  L->constraint_list = list;
  L->constraint_items = calloc((size_t)count + 1, sizeof *L->constraint_items);
  if (!L->constraint_items)
    return mrvi_ld_fail_nomem(L);
  void *it = NULL;
  struct fy_node *item;
  for (int i = 0; !st && (item = fy_node_sequence_iterate(list, &it)); i++)
    st = load_constraint(L, item, i, dim);
  return st;
}

/* Initial data against the constraints (doc/constraints.md), once the settings
 * are known: positions within the tolerance, independent gradients, velocities
 * projected onto the tangent space (with a note when they changed). */
int mrvi_ld_check_constraints(loader *L) {
  mrvi_model *m = L->sys->model;
  const int n_c = mrvi_model_n_constraints(m);
  int worst = -1, st;
  if (n_c == 0)
    return MRVI_OK;
  st = mrvi_model_check_initial_positions(m, L->sys->settings.constraint_tol,
                                          &worst);
  if (st < 0)
    return st == MRVI_ENOMEM
               ? mrvi_ld_fail_nomem(L)
               : mrvi_ld_fail(L,
                              worst >= 0 ? L->constraint_items[worst]
                                         : L->constraint_list,
                              "%s", mrvi_model_errmsg(m));
  if ((st = mrvi_model_check_independent(m, mrvi_model_q0(m))) < 0) {
    /* At the last constraint the message names (labels are unique). */
    const char *msg = mrvi_model_errmsg(m);
    struct fy_node *at = L->constraint_list;
    char quoted[600];
    for (int c = n_c - 1; c >= 0 && at == L->constraint_list; c--) {
      mrvi_fmt(quoted, sizeof quoted, "'%s'",
               mrvi_model_constraint_label(m, c));
      if (strstr(msg, quoted))
        at = L->constraint_items[c];
    }
    return st == MRVI_ENOMEM ? mrvi_ld_fail_nomem(L)
                             : mrvi_ld_fail(L, at, "%s", msg);
  }
  double correction = 0.0;
  if ((st = mrvi_model_project_velocities(m, &correction)) < 0)
    return st == MRVI_ENOMEM ? mrvi_ld_fail_nomem(L)
                             : mrvi_ld_fail(L, L->constraint_list, "%s",
                                            mrvi_model_errmsg(m));
  if (correction > 0)
    return mrvi_ld_add_note(
        L,
        "initial velocities projected onto the constraints' "
        "tangent space (largest change %.1e)",
        correction);
  return MRVI_OK;
}
