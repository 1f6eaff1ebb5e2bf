/* `constraints:` of a description file (doc/constraints.md), and the check
 * of the initial data against them once the settings are known.
 *
 * An entry is read by the keys its type lists (mrvi_constraint_key in
 * src/mrvi.h): names give the inputs, numbers the parameters, so that a new
 * constraint type needs no code here. */
#include "io/loader/loader_internal.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Keys of a type without its own: {coordinates: [names], parameters:
 * [numbers]} (doc/constraints.md, "Adding a constraint type"). */
static const mrvi_constraint_key generic_keys[] = {
    {"coordinates", MRVI_KEY_COORDINATES, MRVI_KEY_REQUIRED, 0},
    {"parameters", MRVI_KEY_NUMBERS, 0, 1},
    {0},
};
#define MAX_ENTRY_KEYS 16 /* keys of one type read (the rest ignored) */

static const mrvi_constraint_key *keys_of(const mrvi_constraint_type *t) {
  return t->keys ? t->keys : generic_keys;
}

/* An entry being read: its inputs in the order of the keys, the numbers of
 * each key, and what its label names. */
typedef struct entry {
  const mrvi_constraint_type *type;
  const mrvi_constraint_key *keys;
  struct fy_node *item;
  const char *where;
  int dim;
  int *in, n_in;               /* model coordinates */
  double *num[MAX_ENTRY_KEYS]; /* numbers of keys[k], n_num[k] of them */
  int n_num[MAX_ENTRY_KEYS];
  int parts[2], n_parts; /* particles named (PARTICLE, ENDS) */
  int first;             /* in[first..first+dim): the last particle's */
  int on[3], n_on;       /* axes selected (AXES; default every axis) */
  const char *anchor;    /* the ANCHOR key, when given */
} entry;

static int add_inputs(loader *L, entry *e, const int *v, int k) {
  int *in = realloc(e->in, (size_t)(e->n_in + k + 1) * sizeof *in);
  if (!in)
    return mrvi_ld_fail_nomem(L);
  e->in = in;
  memcpy(in + e->n_in, v, (size_t)k * sizeof *v);
  e->n_in += k;
  return MRVI_OK;
}

static int set_numbers(loader *L, entry *e, int k, const double *v, int n) {
  free(e->num[k]);
  e->num[k] = malloc((size_t)(n + 1) * sizeof *v);
  if (!e->num[k])
    return mrvi_ld_fail_nomem(L);
  memcpy(e->num[k], v, (size_t)n * sizeof *v);
  e->n_num[k] = n;
  return MRVI_OK;
}

static int add_particle(loader *L, entry *e, int p) {
  int c[3];
  for (int a = 0; a < e->dim; a++)
    c[a] = mrvi_particle_first(L->sys->model, p) + a;
  if (e->n_parts < 2)
    e->parts[e->n_parts++] = p;
  e->first = e->n_in;
  return add_inputs(L, e, c, e->dim);
}

/* ENDS: `key: [a, b]`, or `key: [a]` with the ANCHOR key's point. */
static int read_ends(loader *L, entry *e, const mrvi_constraint_key *key) {
  const char *anchor_key = "anchor";
  int k_anchor = -1;
  for (int k = 0; k < MAX_ENTRY_KEYS && e->keys[k].name; k++)
    if (e->keys[k].flags & MRVI_KEY_ANCHOR) {
      anchor_key = e->keys[k].name;
      k_anchor = k;
    }
  char noun[96];
  double anchor[3] = {0, 0, 0};
  int pi[2], ends, st;
  mrvi_fmt(noun, sizeof noun, "%s constraint", e->type->name);
  if ((st = mrvi_ld_ends(L, e->item, e->where, noun, key->name, anchor_key,
                         e->dim, pi, NULL, &ends, anchor)))
    return st;
  if (ends == 2 && pi[0] == pi[1])
    return mrvi_ld_fail(L, mrvi_ld_get(e->item, key->name),
                        "%s: both ends are particle '%s'", e->type->name,
                        MRVI_PNAME(L->sys->model, pi[0]));
  for (int i = 0; i < ends; i++)
    if ((st = add_particle(L, e, pi[i])))
      return st;
  if (ends == 2 || k_anchor < 0)
    return MRVI_OK;
  e->anchor = anchor_key;
  return set_numbers(L, e, k_anchor, anchor, e->dim);
}

/* AXES: which coordinates of the entry's particle are inputs. */
static int read_axes(loader *L, entry *e, const char *key, struct fy_node *n) {
  static const char *const axis_names[] = {"x", "y", "z"};
  int on[3] = {0, 0, 0}, st;
  if ((st = mrvi_ld_want_list(L, n, key)))
    return st;
  const int count = fy_node_sequence_item_count(n);
  if (count == 0)
    return mrvi_ld_fail(L, n, "%s is empty (omit it to pin every axis)", key);
  for (int i = 0; i < count; i++) {
    struct fy_node *a = fy_node_sequence_get_by_index(n, i);
    int which;
    for (int k = e->dim; k < 3; k++)
      if (fy_node_is_scalar(a) && !strcmp(mrvi_ld_scalar0(a), axis_names[k]))
        return mrvi_ld_fail(L, a, "axis '%s' does not exist in %d-D",
                            axis_names[k], e->dim);
    if ((st = mrvi_ld_as_choice(L, a, "axis", axis_names, e->dim, &which)))
      return st;
    if (on[which])
      return mrvi_ld_fail(L, a, "axis '%s' listed twice", axis_names[which]);
    on[which] = 1;
  }
  /* Drop the particle's other coordinates from the inputs. */
  int kept = e->first;
  e->n_on = 0;
  for (int a = 0; a < e->dim; a++) {
    e->on[a] = on[a];
    if (on[a])
      e->in[kept++] = e->in[e->first + a], e->n_on++;
  }
  for (int j = e->first + e->dim; j < e->n_in; j++)
    e->in[kept++] = e->in[j];
  e->n_in = kept;
  return MRVI_OK;
}

/* SCALAR, VECTOR (entries of the selected axes) and NUMBERS; NAN for an
 * absent scalar or vector. */
static int read_numbers(loader *L, entry *e, int k, struct fy_node *n) {
  const mrvi_constraint_key *key = &e->keys[k];
  double v[3] = {NAN, NAN, NAN}, x[3];
  int st, count = 0;
  switch (key->kind) {
  case MRVI_KEY_SCALAR:
    count = 1;
    if (key->flags & MRVI_KEY_POSITIVE)
      st = mrvi_ld_opt_positive(L, e->item, key->name, key->name, v, NULL);
    else
      st = n ? mrvi_ld_as_number(L, n, key->name, v) : MRVI_OK;
    break;
  case MRVI_KEY_VECTOR:
    st = n ? mrvi_ld_as_vector(L, n, key->name, e->dim, x) : MRVI_OK;
    for (int a = 0; a < e->dim && !st; a++)
      if (e->on[a])
        v[count++] = n ? x[a] : NAN;
    break;
  default: { /* MRVI_KEY_NUMBERS */
    if (!n)
      return MRVI_OK;
    if ((st = mrvi_ld_want_list(L, n, key->name)))
      return st;
    count = fy_node_sequence_item_count(n);
    double *list = malloc((size_t)(count + 1) * sizeof *list);
    if (!list)
      return mrvi_ld_fail_nomem(L);
    for (int j = 0; j < count && !st; j++) {
      char what[96];
      mrvi_fmt(what, sizeof what, "%s[%d]", key->name, j);
      st = mrvi_ld_as_number(L, fy_node_sequence_get_by_index(n, j), what,
                             &list[j]);
    }
    st = st ? st : set_numbers(L, e, k, list, count);
    free(list);
    return st;
  }
  }
  return st ? st : set_numbers(L, e, k, v, count);
}

/* COORDINATES: a list of names; COMBINATION: {name: coefficient}. */
static int read_coordinates(loader *L, entry *e, int k, struct fy_node *n) {
  const char *key = e->keys[k].name;
  const int size = mrvi_model_n(L->sys->model) + 1;
  int *coords = malloc((size_t)size * sizeof *coords), count = 0, st;
  double *coef = malloc((size_t)size * sizeof *coef);
  if (!coords || !coef)
    st = mrvi_ld_fail_nomem(L);
  else if (e->keys[k].kind == MRVI_KEY_COMBINATION) {
    if (!(st = mrvi_ld_combination(L, n, coords, coef, &count)))
      st = set_numbers(L, e, k, coef, count);
  } else if (!(st = mrvi_ld_want_list(L, n, key))) {
    count = fy_node_sequence_item_count(n);
    if (count == 0)
      st = mrvi_ld_fail(L, n, "%s is empty", key);
    int *list =
        count > size ? realloc(coords, (size_t)count * sizeof *list) : coords;
    if (!list)
      st = mrvi_ld_fail_nomem(L);
    else
      coords = list;
    for (int j = 0; j < count && !st; j++)
      st = mrvi_ld_find_coordinate(L, fy_node_sequence_get_by_index(n, j), key,
                                   &coords[j]);
  }
  if (!st)
    st = add_inputs(L, e, coords, count);
  free(coords);
  free(coef);
  return st;
}

/* Every key of the entry in the order of the type's list. */
static int read_keys(loader *L, entry *e) {
  int st = MRVI_OK;
  for (int k = 0; k < MAX_ENTRY_KEYS && e->keys[k].name && !st; k++) {
    const mrvi_constraint_key *key = &e->keys[k];
    struct fy_node *n = mrvi_ld_get(e->item, key->name);
    if ((key->flags & MRVI_KEY_REQUIRED) &&
        (st = mrvi_ld_need(L, e->item, key->name, e->where, &n)))
      return st;
    switch (key->kind) {
    case MRVI_KEY_PARTICLE: {
      int p;
      if (n && !(st = mrvi_ld_find_particle(L, n, key->name, &p)))
        st = add_particle(L, e, p);
      break;
    }
    case MRVI_KEY_ENDS:
      st = read_ends(L, e, key);
      break;
    case MRVI_KEY_AXES:
      st = n ? read_axes(L, e, key->name, n) : MRVI_OK;
      break;
    case MRVI_KEY_COORDINATES:
    case MRVI_KEY_COMBINATION:
      st = n ? read_coordinates(L, e, k, n) : MRVI_OK;
      break;
    default: /* numbers; an ANCHOR vector is read with its ENDS */
      if (!(key->flags & MRVI_KEY_ANCHOR))
        st = read_numbers(L, e, k, n);
    }
  }
  return st;
}

/* "distance a-b", "distance a-anchor", "fixed a.xz", "plane a"; NULL (the
 * model's "<type> on <coordinate>, ...") when no particle is named. */
static const char *entry_label(const loader *L, const entry *e, char *buf,
                               size_t len) {
  static const char axis_name[] = "xyz";
  const mrvi_model *m = L->sys->model;
  char which[8] = "";
  if (e->n_parts == 0)
    return NULL;
  for (int a = 0, n = 0; a < e->dim && e->n_on < e->dim; a++)
    if (e->on[a])
      which[n++] = axis_name[a];
  mrvi_fmt(buf, len, "%s %s%s%s%s%s%s%s", e->type->name,
           MRVI_PNAME(m, e->parts[0]), e->n_parts > 1 ? "-" : "",
           e->n_parts > 1 ? MRVI_PNAME(m, e->parts[1]) : "",
           e->anchor ? "-" : "", e->anchor ? e->anchor : "", *which ? "." : "",
           which);
  return buf;
}

/* One entry of a registered type, read by the type's keys; returns the
 * constraint index (>= 0) or a status < 0. */
static int load_entry(loader *L, struct fy_node *item, const char *where,
                      const mrvi_constraint_type *t, int dim) {
  entry e = {.type = t,
             .keys = keys_of(t),
             .item = item,
             .where = where,
             .dim = dim,
             .on = {1, 1, 1},
             .n_on = dim};
  struct fy_node *report = item;
  char buf[300];
  int st = read_keys(L, &e), n_par = 0, max_rank = 0;
  for (int k = 0; k < MAX_ENTRY_KEYS && e.keys[k].name; k++) {
    n_par += e.n_num[k];
    max_rank = e.keys[k].param > max_rank ? e.keys[k].param : max_rank;
    if ((e.keys[k].flags & MRVI_KEY_REPORT) &&
        mrvi_ld_get(item, e.keys[k].name))
      report = mrvi_ld_get(item, e.keys[k].name);
  }
  /* The parameters: each key's numbers in the order of their ranks. */
  double *par = st ? NULL : malloc((size_t)(n_par + 1) * sizeof *par);
  if (!st && !par)
    st = mrvi_ld_fail_nomem(L);
  for (int r = 1, at = 0; r <= max_rank && !st; r++)
    for (int k = 0; k < MAX_ENTRY_KEYS && e.keys[k].name; k++)
      if (e.keys[k].param == r && e.n_num[k] > 0) {
        memcpy(par + at, e.num[k], (size_t)e.n_num[k] * sizeof *par);
        at += e.n_num[k];
      }
  if (!st) {
    st = mrvi_model_add_constraint(L->sys->model, t->name, e.n_in, e.in, n_par,
                                   par, entry_label(L, &e, buf, sizeof buf));
    if (st < 0)
      st = mrvi_ld_fail_model(L, report, st);
  }
  free(par);
  free(e.in);
  for (int k = 0; k < MAX_ENTRY_KEYS; k++)
    free(e.num[k]);
  return st;
}

/* Keys an entry of type t may have: type, name and the type's own. */
static int entry_keys(const mrvi_constraint_type *t, const char **keys) {
  const mrvi_constraint_key *own = keys_of(t);
  int n = 0;
  keys[n++] = "type";
  keys[n++] = "name";
  for (int k = 0; own[k].name && k < MAX_ENTRY_KEYS; k++)
    keys[n++] = own[k].name;
  return n;
}

/* Keys of every type (for an entry without `type:`), the generic last. */
static int all_constraint_keys(const char **keys) {
  const mrvi_constraint_type generic = {.name = "generic"};
  const int n_types = mrvi_constraint_type_count();
  int n = 0;
  for (int i = 0; i <= n_types; i++) {
    const mrvi_constraint_type *t =
        i < n_types ? mrvi_constraint_type_get(i) : &generic;
    const char *own[MAX_ENTRY_KEYS + 2];
    if (i < n_types && !t->keys)
      continue; /* the generic keys come last */
    const int k = entry_keys(t, own);
    for (int j = 0; j < k && n < MAX_KEYS; j++) {
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

/* Whether node n is a body point: a mapping, or a scalar naming a body. */
static int is_body_point(loader *L, struct fy_node *n) {
  return n && (fy_node_is_mapping(n) ||
               (fy_node_is_scalar(n) &&
                mrvi_model_find_body(L->sys->model, mrvi_ld_scalar0(n)) >= 0));
}

/* Whether entry `item` of type t is a distance, fixed or plane constraint
 * with a body point as an end (doc/multibody.md, "Constraints on body
 * points"). */
static int on_body_points(loader *L, struct fy_node *item,
                          const mrvi_constraint_type *t) {
  if (!strcmp(t->name, "fixed") || !strcmp(t->name, "plane"))
    return is_body_point(L, mrvi_ld_get(item, "particle"));
  struct fy_node *ends = mrvi_ld_get(item, "between");
  if (strcmp(t->name, "distance") || !ends || !fy_node_is_sequence(ends))
    return 0;
  for (int i = 0; i < fy_node_sequence_item_count(ends); i++)
    if (is_body_point(L, fy_node_sequence_get_by_index(ends, i)))
      return 1;
  return 0;
}

/* Such an entry, with the same keys as on particles, through
 * mrvi_model_add_end_distance, _fixed or _plane; returns the constraint
 * index (>= 0) or a status < 0. */
static int load_point_entry(loader *L, struct fy_node *item, const char *where,
                            const mrvi_constraint_type *t, int dim) {
  mrvi_model *m = L->sys->model;
  int st, c;
  if (!strcmp(t->name, "distance")) {
    mrvi_end pt[2];
    int pi[2], ends;
    double anchor[3] = {0, 0, 0}, length = NAN;
    if ((st = mrvi_ld_ends(L, item, where, "distance constraint", "between",
                           "anchor", dim, pi, pt, &ends, anchor)) ||
        (st = mrvi_ld_opt_positive(L, item, "length", "length", &length, NULL)))
      return st;
    c = mrvi_model_add_end_distance(m, &pt[0], ends == 2 ? &pt[1] : NULL,
                                    anchor, length);
    return c < 0 ? mrvi_ld_fail_model(L, mrvi_ld_get(item, "between"), c) : c;
  }
  mrvi_end pt;
  struct fy_node *n;
  if ((st = mrvi_ld_end_point(L, mrvi_ld_get(item, "particle"), "particle", dim,
                              &pt)))
    return st;
  if (!strcmp(t->name, "fixed")) {
    int in[3] = {0, 1, 2};
    entry e = {.type = t,
               .item = item,
               .where = where,
               .dim = dim,
               .on = {1, 1, 1},
               .n_on = dim};
    double pos[3];
    if ((n = mrvi_ld_get(item, "axes")) &&
        ((st = add_inputs(L, &e, in, dim)) ||
         (st = read_axes(L, &e, "axes", n)))) {
      free(e.in);
      return st;
    }
    free(e.in);
    if ((n = mrvi_ld_get(item, "position")) &&
        (st = mrvi_ld_as_vector(L, n, "position", dim, pos)))
      return st;
    c = mrvi_model_add_end_fixed(m, &pt, e.on, n ? pos : NULL);
  } else {
    double normal[3], offset = NAN;
    if ((st = mrvi_ld_need(L, item, "normal", where, &n)) ||
        (st = mrvi_ld_as_vector(L, n, "normal", dim, normal)) ||
        ((n = mrvi_ld_get(item, "offset")) &&
         (st = mrvi_ld_as_number(L, n, "offset", &offset))))
      return st;
    c = mrvi_model_add_end_plane(m, &pt, normal, offset);
  }
  return c < 0 ? mrvi_ld_fail_model(L, item, c) : c;
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
  const mrvi_constraint_type *t = mrvi_constraint_type_get(which);
  if ((st = mrvi_ld_check_keys(L, item, where, keys, entry_keys(t, keys), NULL,
                               0)))
    return st;
  const int c = on_body_points(L, item, t)
                    ? load_point_entry(L, item, where, t, dim)
                    : load_entry(L, item, where, t, dim);
  if (c < 0)
    return c;
  if ((st = mrvi_ld_constraint_item(L, c, item)))
    return st;
  return label_constraint(L, item, where, c);
}

int mrvi_ld_constraint_item(loader *L, int c, struct fy_node *item) {
  if (c >= L->cap_constraint_items) {
    const int cap = c + 1 > 2 * L->cap_constraint_items
                        ? c + 8
                        : 2 * L->cap_constraint_items;
    struct fy_node **p = realloc(L->constraint_items, (size_t)cap * sizeof *p);
    if (!p)
      return mrvi_ld_fail_nomem(L);
    memset(p + L->cap_constraint_items, 0,
           (size_t)(cap - L->cap_constraint_items) * sizeof *p);
    L->constraint_items = p;
    L->cap_constraint_items = cap;
  }
  L->constraint_items[c] = item;
  return MRVI_OK;
}

int mrvi_ld_constraints(loader *L, struct fy_node *list, int dim) {
  int st = mrvi_ld_want_list(L, list, "constraints");
  if (st)
    return st;
  L->constraint_list = list;
  void *it = NULL;
  struct fy_node *item;
  for (int i = 0; !st && (item = fy_node_sequence_iterate(list, &it)); i++)
    st = load_constraint(L, item, i, dim);
  return st;
}

/* Initial data against the constraints (doc/constraints.md), once the settings
 * are known: positions projected onto the constraints and velocities onto
 * their tangent space (with a note when they changed), independent
 * gradients in the multiplier form. */
int mrvi_ld_check_constraints(loader *L) {
  mrvi_model *m = L->sys->model;
  const int n_c = mrvi_model_n_constraints(m);
  int worst = -1, st;
  if (n_c == 0)
    return MRVI_OK;
  /* Positions off the constraints (a closed loop's cannot be typed
   * exactly) are projected onto them, within MRVI_PROJECT_POSITIONS_MAX. */
  double moved = 0.0;
  st = mrvi_model_project_positions(m, L->sys->settings.constraint_tol, &moved,
                                    &worst);
  if (st < 0)
    return st == MRVI_ENOMEM
               ? mrvi_ld_fail_nomem(L)
               : mrvi_ld_fail(L,
                              worst >= 0 ? L->constraint_items[worst]
                                         : L->constraint_list,
                              "%s", mrvi_model_errmsg(m));
  if (moved > 0 &&
      (st = mrvi_ld_add_note(L,
                             "initial positions projected onto the "
                             "constraints (largest change %.1e)",
                             moved)) < 0)
    return st;
  /* The null-space form handles redundant rows (doc/constraints.md). */
  if (L->sys->settings.constraint_form != MRVI_FORM_NULL_SPACE &&
      (st = mrvi_model_check_independent(m, mrvi_model_q0(m))) < 0) {
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
    if (!at) /* only bodies and joints: at the last of them */
      at = L->constraint_items[n_c - 1];
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
