/* The `control:` section of a description file (doc/optimal-control.md,
 * keys in doc/description-files.md):
 *
 *   control:
 *     actuators:    [{name, coordinate | pair: [particle, particle] |
 *                     body + torque [+ frame] | body + force [+ at] |
 *                     joint, grid: macro|micro, weight, lower, upper,
 *                     initial}]
 *     tracking:     [{coordinate, weight, reference}]
 *     terminal:     [{coordinate, position, velocity, penalty} |
 *                    {body, attitude, angular_velocity (entries may be ~:
 *                     free), frame, director + direction, penalty}]
 *     solver:       {algorithm, tolerance, terminal_tolerance,
 *                    max_evaluations}
 *
 * Errors carry file:line:col of the offending node. */
#include "ocp/ocp_internal.h"

#include <libfyaml.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

typedef struct parser {
  const char *path;
  const mrvi_model *m;
  char *msg;
  size_t len;
  mrvi_override_of override_of;
  const void *ctx;
} parser;

static int position(struct fy_node *n, int *line, int *col);

/* Position of the key (or, in a list, the item before) holding n: an empty
 * list or mapping has no token of its own. */
static int holder_position(struct fy_node *n, int *line, int *col) {
  struct fy_node *parent = fy_node_get_parent(n);
  if (!parent || !fy_node_is_mapping(parent))
    return 0;
  void *it = NULL;
  struct fy_node_pair *p;
  while ((p = fy_node_mapping_iterate(parent, &it)))
    if (fy_node_pair_value(p) == n)
      return position(fy_node_pair_key(p), line, col);
  return 0;
}

/* 1-based position of n: its token, or its first key / item, or (empty)
 * the key holding it. */
static int position(struct fy_node *n, int *line, int *col) {
  if (!n)
    return 0;
  if (fy_node_is_scalar(n)) {
    struct fy_token *t = fy_node_get_scalar_token(n);
    const struct fy_mark *mk = t ? fy_token_start_mark(t) : NULL;
    if (!mk)
      return 0;
    *line = mk->line + 1;
    *col = mk->column + 1;
    return 1;
  }
  void *it = NULL;
  if (fy_node_is_mapping(n)) {
    struct fy_node_pair *p = fy_node_mapping_iterate(n, &it);
    if (p)
      return position(fy_node_pair_key(p), line, col);
  } else {
    struct fy_node *first = fy_node_sequence_iterate(n, &it);
    if (first)
      return position(first, line, col);
  }
  return holder_position(n, line, col);
}

/* a, or b when a is NULL (an optional key left out: the item instead). */
static struct fy_node *or_item(struct fy_node *a, struct fy_node *b) {
  return a ? a : b;
}

__attribute__((format(printf, 3, 4))) static int
fail(parser *P, struct fy_node *at, const char *fmt, ...) {
  char text[600];
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(text, sizeof text, fmt, ap);
  va_end(ap);
  const char *ov = P->override_of ? P->override_of(P->ctx, at) : NULL;
  int line = 1, col = 1;
  position(at, &line, &col);
  if (ov)
    mrvi_fmt(P->msg, P->len, "--set %s: %s", ov, text);
  else
    mrvi_fmt(P->msg, P->len, "%s:%d:%d: %s", P->path, line, col, text);
  return MRVI_EPARSE;
}

static struct fy_node *get(struct fy_node *map, const char *key) {
  return map ? fy_node_mapping_lookup_by_string(map, key, -1) : NULL;
}

/* Unknown keys of map (with a suggestion). */
static int check_keys(parser *P, struct fy_node *map, const char *where,
                      const char *const *keys, int n) {
  if (!fy_node_is_mapping(map))
    return fail(P, map, "%s must be a mapping", where);
  void *it = NULL;
  struct fy_node_pair *p;
  while ((p = fy_node_mapping_iterate(map, &it))) {
    struct fy_node *k = fy_node_pair_key(p);
    const char *s = k ? fy_node_get_scalar0(k) : NULL;
    int known = 0;
    for (int i = 0; s && i < n && !known; i++)
      known = !strcmp(s, keys[i]);
    if (!known) {
      const char *close = s ? mrvi_closest(s, keys, n) : NULL;
      char hint[120] = "";
      if (close)
        mrvi_fmt(hint, sizeof hint, "; did you mean '%s'?", close);
      return fail(P, k ? k : map, "unknown key '%s' in %s%s", s ? s : "?",
                  where, hint);
    }
  }
  return MRVI_OK;
}

/* Optional number at map[key] (default kept): finite, or with infinite =
 * 1 also YAML's .inf, -.inf (any case of .inf / .Inf / .INF, as YAML 1.2
 * spells them) and C's inf, -inf. */
static int number_of(parser *P, struct fy_node *map, const char *key,
                     const char *where, int infinite, double *out) {
  struct fy_node *n = get(map, key);
  if (!n)
    return MRVI_OK;
  const char *s = fy_node_is_scalar(n) ? fy_node_get_scalar0(n) : NULL;
  double v = NAN;
  if (s) {
    const char *t = s + (*s == '+' || *s == '-');
    char *end = NULL;
    if (!strcmp(t, ".inf") || !strcmp(t, ".Inf") || !strcmp(t, ".INF"))
      v = *s == '-' ? -HUGE_VAL : HUGE_VAL;
    else if (!(v = strtod(s, &end), end != s && !*end))
      v = NAN;
  }
  if (isnan(v))
    return fail(P, n, "%s.%s must be a number, got '%s'", where, key,
                s ? s : "a list or mapping");
  if (isinf(v) && !infinite)
    return fail(P, n, "%s.%s must be a finite number, got '%s'", where, key, s);
  *out = v;
  return MRVI_OK;
}

static int number(parser *P, struct fy_node *map, const char *key,
                  const char *where, double *out) {
  return number_of(P, map, key, where, 0, out);
}

/* Coordinate named at map["coordinate"] (required). */
static int coordinate(parser *P, struct fy_node *map, const char *where,
                      int *out) {
  struct fy_node *n = get(map, "coordinate");
  if (!n)
    return fail(P, map, "%s needs a 'coordinate'", where);
  const char *s = fy_node_is_scalar(n) ? fy_node_get_scalar0(n) : NULL;
  if (s && (*out = mrvi_model_find_coordinate(P->m, s)) >= 0)
    return MRVI_OK;
  /* (the names made on demand, mrvi_model_coordinate_name, in one block) */
  const char **names = malloc((size_t)(P->m->n + 1) * sizeof *names);
  char *made = names ? mrvi_model_names(P->m, 0, names) : NULL;
  if (!made) {
    free(names);
    return fail(P, n, "out of memory");
  }
  const char *close = s ? mrvi_closest(s, names, P->m->n) : NULL;
  char hint[160] = "";
  if (close)
    mrvi_fmt(hint, sizeof hint, "; did you mean '%s'?", close);
  free(made);
  free(names);
  return fail(P, n, "unknown coordinate '%s' in %s%s", s ? s : "?", where,
              hint);
}

/* Particles named at map["pair"]: a list of two different particles. */
static int pair(parser *P, struct fy_node *map, const char *where, int *pi,
                int *pj) {
  struct fy_node *n = get(map, "pair");
  if (get(map, "coordinate"))
    return fail(P, n, "%s: give either 'coordinate' or 'pair', not both",
                where);
  if (!fy_node_is_sequence(n) || fy_node_sequence_item_count(n) != 2)
    return fail(P, n, "%s.pair must be a list of two particle names", where);
  const mrvi_model *m = P->m;
  const char **names = malloc((size_t)(m->n_particles + 1) * sizeof *names);
  char *made = names ? mrvi_model_names(m, 1, names) : NULL;
  if (!made) {
    free(names);
    return fail(P, n, "out of memory");
  }
  int *out[2] = {pi, pj}, st = MRVI_OK;
  for (int e = 0; e < 2 && !st; e++) {
    struct fy_node *item = fy_node_sequence_get_by_index(n, e);
    const char *s = fy_node_is_scalar(item) ? fy_node_get_scalar0(item) : NULL;
    *out[e] = -1;
    for (int i = 0; s && i < m->n_particles && *out[e] < 0; i++)
      if (!strcmp(s, names[i]))
        *out[e] = i;
    if (*out[e] < 0) {
      const char *close =
          s && m->n_particles
              ? mrvi_closest(s, (const char *const *)names, m->n_particles)
              : NULL;
      char hint[160] = "";
      if (close)
        mrvi_fmt(hint, sizeof hint, "; did you mean '%s'?", close);
      st = fail(P, item, "unknown particle '%s' in %s.pair%s", s ? s : "?",
                where, hint);
    } else if (e == 1 && *pi == *pj) {
      st = fail(P, item, "%s.pair names particle '%s' twice", where, s);
    }
  }
  free(made);
  free(names);
  return st;
}

/* A list of n finite numbers at node v. */
static int vector(parser *P, struct fy_node *v, const char *where,
                  const char *key, int n, double *out) {
  if (!v || !fy_node_is_sequence(v) || fy_node_sequence_item_count(v) != n)
    return fail(P, v, "%s.%s must be a list of %d numbers", where, key, n);
  for (int i = 0; i < n; i++) {
    struct fy_node *e = fy_node_sequence_get_by_index(v, i);
    const char *s = fy_node_is_scalar(e) ? fy_node_get_scalar0(e) : NULL;
    char *end = NULL;
    out[i] = s ? strtod(s, &end) : NAN;
    if (!s || end == s || *end || !isfinite(out[i]))
      return fail(P, e, "%s.%s: entry %d must be a finite number", where, key,
                  i);
  }
  return MRVI_OK;
}

/* A number, or a list of n numbers, at node v (a 2-D torque or angular
 * velocity may be written as a number). */
static int number_or_vector(parser *P, struct fy_node *v, const char *where,
                            const char *key, int n, double *out) {
  if (v && fy_node_is_scalar(v) && n == 1) {
    char *end = NULL;
    const char *s = fy_node_get_scalar0(v);
    out[0] = strtod(s, &end);
    if (end == s || *end || !isfinite(out[0]))
      return fail(P, v, "%s.%s must be a finite number", where, key);
    return MRVI_OK;
  }
  return vector(P, v, where, key, n, out);
}

/* The body named at map["body"] (required). */
static int body_named(parser *P, struct fy_node *map, const char *where,
                      int *b) {
  struct fy_node *n = get(map, "body");
  const char *s = n && fy_node_is_scalar(n) ? fy_node_get_scalar0(n) : NULL;
  if (!n)
    return fail(P, map, "%s needs a 'body'", where);
  const mrvi_model *m = P->m;
  *b = s ? mrvi_model_find_body(m, s) : -1;
  if (*b >= 0)
    return MRVI_OK;
  const int nb = mrvi_model_n_bodies(m);
  const char **names = malloc((size_t)(nb + 1) * sizeof *names);
  const char *close = NULL;
  if (names) {
    for (int i = 0; i < nb; i++)
      names[i] = mrvi_model_body_name(m, i);
    close = s && nb ? mrvi_closest(s, names, nb) : NULL;
  }
  char hint[160] = "";
  if (close)
    mrvi_fmt(hint, sizeof hint, "; did you mean '%s'?", close);
  else if (nb == 0)
    mrvi_fmt(hint, sizeof hint, " (the model has no bodies)");
  const int st =
      fail(P, n, "unknown body '%s' in %s%s", s ? s : "?", where, hint);
  free(names);
  return st;
}

/* The revolute joint named at map["joint"]: its constraint index. */
static int joint_named(parser *P, struct fy_node *map, const char *where,
                       int *j) {
  struct fy_node *n = get(map, "joint");
  const char *s = fy_node_is_scalar(n) ? fy_node_get_scalar0(n) : NULL;
  const mrvi_model *m = P->m;
  *j = -1;
  for (int c = 0; s && c < m->n_constraints && *j < 0; c++)
    if (!strcmp(s, m->constraints[c].label))
      *j = c;
  if (*j < 0)
    return fail(P, n,
                "unknown joint '%s' in %s.joint (a joint's name, or "
                "its label 'revolute A-B' as `mrvi check` lists it)",
                s ? s : "?", where);
  if (strcmp(m->constraints[*j].type->name, "revolute"))
    return fail(P, n,
                "%s.joint: '%s' is a %s joint; a joint torque needs a "
                "revolute joint",
                where, s, m->constraints[*j].type->name);
  return MRVI_OK;
}

/* A frame key: "space" (default) or "body"; *body gets 1 for "body". */
static int frame_of(parser *P, struct fy_node *map, const char *where,
                    int *body) {
  struct fy_node *n = get(map, "frame");
  const char *s = n && fy_node_is_scalar(n) ? fy_node_get_scalar0(n) : "";
  *body = 0;
  if (!n || !strcmp(s, "space"))
    return MRVI_OK;
  if (!strcmp(s, "body")) {
    *body = 1;
    return MRVI_OK;
  }
  return fail(P, n, "%s.frame must be 'space' or 'body', not '%s'", where, s);
}

/* A state-dependent actuator on bodies (torque, force or joint torque);
 * -1 (no failure) when the item is a coordinate or pair actuator. */
static int body_actuator(parser *P, struct fy_node *item, const char *where,
                         mrvi_ocp *o, mrvi_grid grid, double w, double lo,
                         double hi, int *a) {
  static const char *const kinds[] = {"coordinate", "pair", "torque", "force",
                                      "joint"};
  int n_given = 0;
  for (int k = 0; k < 5; k++)
    if (get(item, kinds[k])) {
      if (n_given++)
        return fail(P, get(item, kinds[k]),
                    "%s: give one of 'coordinate', 'pair', 'torque' (with "
                    "'body'), 'force' (with 'body') or 'joint'",
                    where);
    }
  const int torque = get(item, "torque") != NULL;
  const int force = get(item, "force") != NULL;
  const int joint = get(item, "joint") != NULL;
  if (!torque && !force && !joint) {
    static const char *const only[] = {"body", "frame", "at"};
    for (int k = 0; k < 3; k++)
      if (get(item, only[k]))
        return fail(P, get(item, only[k]),
                    "%s.%s belongs to a 'torque' or 'force' actuator", where,
                    only[k]);
    *a = -1;
    return MRVI_OK;
  }
  const int D = P->m->dimension;
  int st, b = -1, frame = 0;
  if (joint) {
    if (get(item, "body") || get(item, "frame") || get(item, "at"))
      return fail(P,
                  or_item(get(item, "body"),
                          or_item(get(item, "frame"), get(item, "at"))),
                  "%s: a joint torque takes the joint's bodies and hinge; "
                  "no 'body', 'frame' or 'at'",
                  where);
    int j;
    if ((st = joint_named(P, item, where, &j)))
      return st;
    *a = mrvi_ocp_add_joint_torque_actuator(o, j, grid, w, lo, hi);
  } else if (torque) {
    double ax[3] = {0, 0, 0};
    if (get(item, "at"))
      return fail(P, get(item, "at"),
                  "%s.at belongs to a 'force' actuator (a torque acts on the "
                  "body as a whole)",
                  where);
    if ((st = body_named(P, item, where, &b)) ||
        (st = frame_of(P, item, where, &frame)) ||
        (st = D == 3 ? vector(P, get(item, "torque"), where, "torque", 3, ax)
                     : number_or_vector(P, get(item, "torque"), where, "torque",
                                        1, ax + 2)))
      return st;
    *a = mrvi_ocp_add_torque_actuator(o, b, ax, frame, grid, w, lo, hi);
    if (*a < 0)
      return fail(P, get(item, "torque"), "%s: %s", where, mrvi_ocp_errmsg(o));
  } else {
    double dir[3], at[3] = {0, 0, 0};
    if (get(item, "frame"))
      return fail(P, get(item, "frame"),
                  "%s.frame: a force actuator's direction is in space", where);
    if ((st = body_named(P, item, where, &b)) ||
        (st = vector(P, get(item, "force"), where, "force", D, dir)) ||
        (get(item, "at") &&
         (st = vector(P, get(item, "at"), where, "at", D, at))))
      return st;
    *a = mrvi_ocp_add_body_force_actuator(o, b, at, dir, grid, w, lo, hi);
    if (*a < 0)
      return fail(P, get(item, "force"), "%s: %s", where, mrvi_ocp_errmsg(o));
  }
  if (*a < 0)
    return fail(P, item, "%s: %s", where, mrvi_ocp_errmsg(o));
  return MRVI_OK;
}

static const char *const control_keys[] = {"actuators", "tracking", "terminal",
                                           "solver"};
static const char *const actuator_keys[] = {
    "name",    "coordinate", "pair",   "grid",  "weight", "lower", "upper",
    "initial", "body",       "torque", "frame", "force",  "at",    "joint"};
static const char *const tracking_keys[] = {"coordinate", "weight",
                                            "reference"};
static const char *const terminal_keys[] = {
    "coordinate", "position",         "velocity", "penalty",  "body",
    "attitude",   "angular_velocity", "frame",    "director", "direction"};
static const char *const solver_keys[] = {
    "algorithm", "tolerance", "terminal_tolerance", "max_evaluations"};

#define NKEYS(a) ((int)(sizeof a / sizeof a[0]))

/* initial[a]: actuator a's `initial` when a number; lists[a]: its node
 * when a list (one value per grid value, checked once the sizes are
 * known: initial_values). */
static int load_actuators(parser *P, struct fy_node *list, mrvi_ocp *o,
                          double *initial, struct fy_node **lists) {
  if (!list || !fy_node_is_sequence(list) ||
      fy_node_sequence_item_count(list) == 0)
    return fail(P, list, "control.actuators must be a non-empty list");
  void *it = NULL;
  struct fy_node *item;
  int i = 0, st;
  while ((item = fy_node_sequence_iterate(list, &it))) {
    char where[48];
    mrvi_fmt(where, sizeof where, "control.actuators[%d]", i);
    if ((st = check_keys(P, item, where, actuator_keys, NKEYS(actuator_keys))))
      return st;
    int c = -1, pi = -1, pj = -1;
    double w = 1.0, lo = -HUGE_VAL, hi = HUGE_VAL, u0 = 0.0;
    const int on_body = get(item, "torque") || get(item, "force") ||
                        get(item, "joint") || get(item, "body");
    if ((st = on_body             ? MRVI_OK
              : get(item, "pair") ? pair(P, item, where, &pi, &pj)
                                  : coordinate(P, item, where, &c)) ||
        (st = number(P, item, "weight", where, &w)) ||
        (st = number_of(P, item, "lower", where, 1, &lo)) ||
        (st = number_of(P, item, "upper", where, 1, &hi)))
      return st;
    struct fy_node *init = get(item, "initial");
    if (init && fy_node_is_sequence(init))
      lists[i] = init;
    else if ((st = number(P, item, "initial", where, &u0)))
      return st;
    mrvi_grid grid = MRVI_GRID_MACRO;
    struct fy_node *gn = get(item, "grid");
    if (gn) {
      const char *s = fy_node_is_scalar(gn) ? fy_node_get_scalar0(gn) : "";
      if (!strcmp(s, "micro"))
        grid = MRVI_GRID_MICRO;
      else if (strcmp(s, "macro"))
        return fail(P, gn, "%s.grid must be 'macro' or 'micro', not '%s'",
                    where, s);
    }
    if (!(w > 0.0) || !isfinite(w))
      return fail(P, get(item, "weight"), "%s.weight must be > 0", where);
    if (lo > hi || lo == HUGE_VAL || hi == -HUGE_VAL)
      return fail(P, or_item(get(item, "lower"), item),
                  "%s: lower bound %g > upper bound %g, or no finite value "
                  "between them",
                  where, lo, hi);
    if (u0 < lo || u0 > hi)
      return fail(P, or_item(get(item, "initial"), item),
                  "%s: initial value %g outside [%g, %g]", where, u0, lo, hi);
    int a = -1;
    if ((st = body_actuator(P, item, where, o, grid, w, lo, hi, &a)))
      return st;
    if (a < 0)
      a = pi >= 0 ? mrvi_ocp_add_pair_actuator(o, pi, pj, grid, w, lo, hi)
                  : mrvi_ocp_add_actuator(o, c, grid, w, lo, hi);
    if (a < 0)
      return fail(P, item, "%s: %s", where, mrvi_ocp_errmsg(o));
    struct fy_node *nn = get(item, "name");
    if (nn && fy_node_is_scalar(nn))
      mrvi_fmt(o->act[a].name, sizeof o->act[a].name, "%s",
               fy_node_get_scalar0(nn));
    /* /control/names and the replay's messages tell actuators apart by
     * name (the default name is the coordinate's). */
    for (int b = 0; b < a; b++)
      if (!strcmp(o->act[b].name, o->act[a].name))
        return fail(P, or_item(nn, item),
                    "%s: actuator name '%s' is already used by "
                    "control.actuators[%d]%s",
                    where, o->act[a].name, b,
                    nn ? ""
                       : " (a default name: the coordinate's, 'BODY.torque', "
                         "'BODY.force' or the joint's; give a 'name')");
    initial[a] = u0;
    i++;
  }
  return MRVI_OK;
}

/* The initial guess u0 (n_controls): each actuator's number on its whole
 * grid, or its list of one value per grid value, in its bounds (a start
 * of a multi-start, doc/batch.md, is such a list). */
static int initial_values(parser *P, const mrvi_ocp *o, const double *initial,
                          struct fy_node *const *lists, double *u0) {
  for (int a = 0; a < o->n_act; a++) {
    const ocp_actuator *A = &o->act[a];
    double *u = u0 + A->offset;
    char where[48];
    mrvi_fmt(where, sizeof where, "control.actuators[%d]", a);
    if (!lists[a]) {
      for (int j = 0; j < A->size; j++)
        u[j] = initial[a];
      continue;
    }
    if (fy_node_sequence_item_count(lists[a]) != A->size)
      return fail(P, lists[a],
                  "%s.initial: a number, or a list of one number per value "
                  "of the actuator (%d on its %s grid), got %d",
                  where, A->size,
                  A->grid == MRVI_GRID_MACRO ? "macro" : "micro",
                  fy_node_sequence_item_count(lists[a]));
    int st = vector(P, lists[a], where, "initial", A->size, u);
    if (st)
      return st;
    for (int j = 0; j < A->size; j++)
      if (u[j] < A->lower || u[j] > A->upper)
        return fail(P, fy_node_sequence_get_by_index(lists[a], j),
                    "%s.initial: entry %d, %g, outside [%g, %g]", where, j,
                    u[j], A->lower, A->upper);
  }
  return MRVI_OK;
}

static int load_tracking(parser *P, struct fy_node *list, mrvi_ocp *o) {
  if (!list)
    return MRVI_OK;
  if (!fy_node_is_sequence(list))
    return fail(P, list, "control.tracking must be a list");
  void *it = NULL;
  struct fy_node *item;
  int i = 0, st;
  while ((item = fy_node_sequence_iterate(list, &it))) {
    char where[48];
    mrvi_fmt(where, sizeof where, "control.tracking[%d]", i++);
    int c;
    double w = 1.0, ref = 0.0;
    if ((st =
             check_keys(P, item, where, tracking_keys, NKEYS(tracking_keys))) ||
        (st = coordinate(P, item, where, &c)) ||
        (st = number(P, item, "weight", where, &w)) ||
        (st = number(P, item, "reference", where, &ref)))
      return st;
    if (mrvi_ocp_add_tracking(o, c, w, ref) < 0)
      return fail(P, item, "%s: %s", where, mrvi_ocp_errmsg(o));
  }
  return MRVI_OK;
}

/* A second terminal condition of the same kind on coordinate c (target
 * NaN: none): with another target the problem has no solution, with the
 * same one the constraint Jacobian loses rank; both are refused. */
static int conflict(parser *P, const mrvi_ocp *o, struct fy_node *item,
                    const char *where, mrvi_ocp_terminal_kind kind, int c,
                    double target) {
  if (isnan(target))
    return MRVI_OK;
  const char *what = kind == MRVI_OCP_POSITION ? "position" : "velocity";
  for (int i = 0; i < o->n_term; i++)
    if (o->term[i].kind == kind && o->term[i].coord == c)
      return fail(P, or_item(get(item, what), item),
                  "%s: a second terminal %s of '%s' (%g; an earlier "
                  "condition asks %g)%s",
                  where, what, MRVI_CNAME(P->m, c), target, o->term[i].target,
                  o->term[i].target == target
                      ? ": a duplicate makes the conditions redundant"
                      : ": the conditions conflict");
  return MRVI_OK;
}

/* A target attitude: 3-D the rows of a rotation matrix or {axis, angle};
 * 2-D an angle or the rows of a 2 x 2 rotation matrix. */
static int attitude_target(parser *P, struct fy_node *n, const char *where,
                           int D, double *R) {
  if (D == 2 && fy_node_is_scalar(n)) {
    double a;
    int st = number_or_vector(P, n, where, "attitude", 1, &a);
    if (st)
      return st;
    R[0] = cos(a), R[1] = -sin(a), R[2] = sin(a), R[3] = cos(a);
    return MRVI_OK;
  }
  if (D == 3 && fy_node_is_mapping(n)) {
    static const char *const keys[] = {"axis", "angle"};
    double k[3], a = NAN;
    char w2[80];
    mrvi_fmt(w2, sizeof w2, "%s.attitude", where);
    int st = check_keys(P, n, w2, keys, 2);
    if (st || (st = vector(P, get(n, "axis"), w2, "axis", 3, k)) ||
        (st = number(P, n, "angle", w2, &a)))
      return st;
    const double nk = sqrt(k[0] * k[0] + k[1] * k[1] + k[2] * k[2]);
    if (!(nk > 0.0))
      return fail(P, get(n, "axis"), "%s.axis must not be zero", w2);
    if (isnan(a))
      return fail(P, n, "%s needs an 'angle' (radians)", w2);
    for (int i = 0; i < 3; i++)
      k[i] /= nk;
    const double K[9] = {0, -k[2], k[1], k[2], 0, -k[0], -k[1], k[0], 0};
    for (int i = 0; i < 3; i++)
      for (int j = 0; j < 3; j++) {
        double K2 = 0.0;
        for (int l = 0; l < 3; l++)
          K2 += K[i * 3 + l] * K[l * 3 + j];
        R[i * 3 + j] = (i == j) + sin(a) * K[i * 3 + j] + (1 - cos(a)) * K2;
      }
    return MRVI_OK;
  }
  if (!fy_node_is_sequence(n) || fy_node_sequence_item_count(n) != D)
    return fail(P, n,
                "%s.attitude: a %d x %d rotation matrix is %d rows of %d "
                "numbers, or %s",
                where, D, D, D, D,
                D == 3 ? "{axis: [x, y, z], angle: radians}"
                       : "an angle in radians");
  for (int i = 0; i < D; i++) {
    int st = vector(P, fy_node_sequence_get_by_index(n, i), where,
                    "attitude row", D, R + i * D);
    if (st)
      return st;
  }
  return MRVI_OK;
}

/* A terminal angular velocity: a number (2-D) or 3 entries, each a number
 * or null (~: that component free); free[i] <- 1 for a free one. */
static int angular_velocity_target(parser *P, struct fy_node *n,
                                   const char *where, int D, double *w,
                                   int *free_) {
  if (D == 2 || !n || !fy_node_is_sequence(n) ||
      fy_node_sequence_item_count(n) != 3) {
    for (int i = 0; i < 3; i++)
      free_[i] = 0;
    return number_or_vector(P, n, where, "angular_velocity", D == 3 ? 3 : 1, w);
  }
  int given = 0;
  for (int i = 0; i < 3; i++) {
    struct fy_node *e = fy_node_sequence_get_by_index(n, i);
    const char *s = fy_node_is_scalar(e) ? fy_node_get_scalar0(e) : NULL;
    free_[i] = s && (!strcmp(s, "~") || !strcmp(s, "null") ||
                     !strcmp(s, "Null") || !strcmp(s, "NULL"));
    if (free_[i])
      continue;
    char *end = NULL;
    w[i] = s ? strtod(s, &end) : NAN;
    if (!s || end == s || *end || !isfinite(w[i]))
      return fail(P, e,
                  "%s.angular_velocity: entry %d must be a finite number or "
                  "~ (that component free)",
                  where, i);
    given++;
  }
  if (!given)
    return fail(P, n,
                "%s.angular_velocity: every component is free (~); give at "
                "least one",
                where);
  return MRVI_OK;
}

/* director: 1 .. 3 and direction: [x, y, z] (3-D), both or neither;
 * *d <- the director's index (0 .. 2), -1 without. */
static int direction_target(parser *P, struct fy_node *item, const char *where,
                            int D, int *d, double *e) {
  struct fy_node *dn = get(item, "director"), *en = get(item, "direction");
  *d = -1;
  if (!dn && !en)
    return MRVI_OK;
  if (!dn || !en)
    return fail(P, dn ? dn : en,
                dn ? "%s: 'director' needs a 'direction' (in space) to end "
                     "along"
                   : "%s: 'direction' needs a 'director' (1, 2 or 3: the "
                     "one that ends along it)",
                where);
  if (D != 3)
    return fail(P, dn,
                "%s.director: a direction condition is 3-D only (in 2-D a "
                "director's direction is the attitude)",
                where);
  const char *s = fy_node_is_scalar(dn) ? fy_node_get_scalar0(dn) : NULL;
  if (!s || (strcmp(s, "1") && strcmp(s, "2") && strcmp(s, "3")))
    return fail(P, dn, "%s.director must be 1, 2 or 3 (d1, d2, d3), not '%s'",
                where, s ? s : "?");
  *d = s[0] - '1';
  int st = vector(P, en, where, "direction", 3, e);
  if (st)
    return st;
  if (!(e[0] * e[0] + e[1] * e[1] + e[2] * e[2] > 0.0))
    return fail(P, en, "%s.direction must not be zero", where);
  return MRVI_OK;
}

/* {body, attitude, angular_velocity, frame, director, direction,
 * penalty}. */
static int body_terminal(parser *P, struct fy_node *item, const char *where,
                         mrvi_ocp *o) {
  static const char *const coord_only[] = {"coordinate", "position",
                                           "velocity"};
  for (int k = 0; k < 3; k++)
    if (get(item, coord_only[k]))
      return fail(P, get(item, coord_only[k]),
                  "%s: '%s' is a condition on a coordinate; a body takes "
                  "'attitude' and 'angular_velocity'",
                  where, coord_only[k]);
  const int D = P->m->dimension;
  int b, frame = 0, st, dir;
  double pen = 0.0, R[9], w[3], e[3];
  struct fy_node *an = get(item, "attitude"),
                 *wn = get(item, "angular_velocity"),
                 *en = get(item, "direction");
  if ((st = body_named(P, item, where, &b)) ||
      (st = frame_of(P, item, where, &frame)) ||
      (st = number(P, item, "penalty", where, &pen)) ||
      (st = direction_target(P, item, where, D, &dir, e)))
    return st;
  if (!an && !wn && dir < 0)
    return fail(P, item,
                "%s needs 'attitude', 'angular_velocity' and/or 'director' "
                "with 'direction'",
                where);
  if (an && dir >= 0)
    return fail(P, en,
                "%s: a direction and the attitude of the same body: the "
                "attitude already fixes every director",
                where);
  if (get(item, "frame") && !wn)
    return fail(P, get(item, "frame"),
                "%s.frame is the frame of 'angular_velocity'", where);
  if (!(pen >= 0.0))
    return fail(P, get(item, "penalty"), "%s.penalty must be >= 0", where);
  /* A second condition of a kind on the same body (either frame for the
   * angular velocity) repeats or contradicts the first. */
  for (int i = 0; i < o->n_term; i++) {
    const ocp_terminal *T = &o->term[i];
    const int att = T->kind == MRVI_OCP_ATTITUDE,
              dn = T->kind == MRVI_OCP_DIRECTION;
    struct fy_node *clash = T->body != b               ? NULL
                            : att && (an || dir >= 0)  ? (an ? an : en)
                            : dn && an                 ? an
                            : dn && dir == T->director ? en
                            : !att && !dn && wn        ? wn
                                                       : NULL;
    if (clash)
      return fail(P, clash,
                  "%s: a second terminal %s of body '%s': the conditions "
                  "are redundant or conflict",
                  where,
                  clash == an   ? "attitude"
                  : clash == en ? "direction"
                                : "angular velocity",
                  mrvi_model_body_name(P->m, b));
  }
  if (an) {
    if ((st = attitude_target(P, an, where, D, R)))
      return st;
    if (mrvi_ocp_add_body_terminal(o, MRVI_OCP_ATTITUDE, b, R, pen) < 0)
      return fail(P, an, "%s: %s", where, mrvi_ocp_errmsg(o));
  }
  if (dir >= 0 && mrvi_ocp_add_body_direction(o, b, dir, e, pen) < 0)
    return fail(P, en, "%s: %s", where, mrvi_ocp_errmsg(o));
  if (wn) {
    int free_[3];
    if ((st = angular_velocity_target(P, wn, where, D, w, free_)))
      return st;
    if (!free_[0] && !free_[1] && !free_[2]) {
      if (mrvi_ocp_add_body_terminal(o,
                                     frame ? MRVI_OCP_ANGULAR_VELOCITY_BODY
                                           : MRVI_OCP_ANGULAR_VELOCITY,
                                     b, w, pen) < 0)
        return fail(P, wn, "%s: %s", where, mrvi_ocp_errmsg(o));
    }
    for (int r = 0; r < 3 && (free_[0] || free_[1] || free_[2]); r++)
      if (!free_[r] && mrvi_ocp_add_body_angular_velocity_component(
                           o, frame, b, r, w[r], pen) < 0)
        return fail(P, fy_node_sequence_get_by_index(wn, r), "%s: %s", where,
                    mrvi_ocp_errmsg(o));
  }
  return MRVI_OK;
}

static int load_terminal(parser *P, struct fy_node *list, mrvi_ocp *o) {
  if (!list)
    return MRVI_OK;
  if (!fy_node_is_sequence(list))
    return fail(P, list, "control.terminal must be a list");
  void *it = NULL;
  struct fy_node *item;
  int i = 0, st;
  while ((item = fy_node_sequence_iterate(list, &it))) {
    char where[48];
    mrvi_fmt(where, sizeof where, "control.terminal[%d]", i++);
    int c;
    double pos = NAN, vel = NAN, pen = 0.0;
    if ((st = check_keys(P, item, where, terminal_keys, NKEYS(terminal_keys))))
      return st;
    if (get(item, "body")) {
      if ((st = body_terminal(P, item, where, o)))
        return st;
      continue;
    }
    static const char *const body_only[] = {"attitude", "angular_velocity",
                                            "frame", "director", "direction"};
    for (int k = 0; k < 5; k++)
      if (get(item, body_only[k]))
        return fail(P, get(item, body_only[k]),
                    "%s.%s is a terminal condition on a body: give 'body'",
                    where, body_only[k]);
    if ((st = coordinate(P, item, where, &c)) ||
        (st = number(P, item, "position", where, &pos)) ||
        (st = number(P, item, "velocity", where, &vel)) ||
        (st = number(P, item, "penalty", where, &pen)))
      return st;
    if (isnan(pos) && isnan(vel))
      return fail(P, item, "%s needs 'position' and/or 'velocity'", where);
    if (!(pen >= 0.0))
      return fail(P, get(item, "penalty"), "%s.penalty must be >= 0", where);
    if ((st = conflict(P, o, item, where, MRVI_OCP_POSITION, c, pos)) ||
        (st = conflict(P, o, item, where, MRVI_OCP_VELOCITY, c, vel)))
      return st;
    if (!isnan(pos) &&
        mrvi_ocp_add_terminal(o, MRVI_OCP_POSITION, c, pos, pen) < 0)
      return fail(P, item, "%s: %s", where, mrvi_ocp_errmsg(o));
    if (!isnan(vel) &&
        mrvi_ocp_add_terminal(o, MRVI_OCP_VELOCITY, c, vel, pen) < 0)
      return fail(P, item, "%s: %s", where, mrvi_ocp_errmsg(o));
  }
  return MRVI_OK;
}

static int load_solver(parser *P, struct fy_node *map, mrvi_ocp *o) {
  if (!map)
    return MRVI_OK;
  int st =
      check_keys(P, map, "control.solver", solver_keys, NKEYS(solver_keys));
  if (st)
    return st;
  struct fy_node *an = get(map, "algorithm");
  if (an) {
    const char *s = fy_node_is_scalar(an) ? fy_node_get_scalar0(an) : "";
    const char *names[4];
    int found = -1;
    for (int a = 0; a < 4; a++) {
      names[a] = mrvi_ocp_algorithm_name((mrvi_ocp_algorithm)a);
      if (!strcmp(s, names[a]))
        found = a;
    }
    if (found < 0) {
      const char *close = mrvi_closest(s, names, 4);
      char hint[80] = "";
      if (close)
        mrvi_fmt(hint, sizeof hint, "; did you mean '%s'?", close);
      return fail(P, an,
                  "unknown algorithm '%s' (slsqp, auglag-lbfgs, auglag-mma, "
                  "auglag-ccsaq)%s",
                  s, hint);
    }
    o->algorithm = (mrvi_ocp_algorithm)found;
  }
  double ftol = o->ftol_rel, ttol = o->terminal_tol, me = o->max_eval;
  if ((st = number(P, map, "tolerance", "control.solver", &ftol)) ||
      (st = number(P, map, "terminal_tolerance", "control.solver", &ttol)) ||
      (st = number(P, map, "max_evaluations", "control.solver", &me)))
    return st;
  if (!(ftol > 0.0) || !(ttol > 0.0))
    return fail(P, map, "control.solver tolerances must be > 0");
  if (!(me >= 1.0) || me != floor(me) || me > 1e9)
    return fail(P, get(map, "max_evaluations"),
                "control.solver.max_evaluations must be a positive integer");
  o->ftol_rel = ftol;
  o->terminal_tol = ttol;
  o->max_eval = (int)me;
  return MRVI_OK;
}

int mrvi_ocp_parse(const mrvi_model *m, const mrvi_settings *s,
                   struct fy_node *control, const char *path,
                   mrvi_override_of override_of, const void *ctx,
                   mrvi_ocp **out, double **u0, char *msg, size_t len) {
  parser P = {path, m, msg, len, override_of, ctx};
  *out = NULL;
  if (u0)
    *u0 = NULL;
  int st =
      check_keys(&P, control, "control", control_keys, NKEYS(control_keys));
  if (st)
    return st;
  mrvi_ocp *o = NULL;
  char why[400];
  if ((st = mrvi_ocp_create(m, s, &o, why, sizeof why)) < 0)
    return fail(&P, control, "%s", why);
  struct fy_node *acts = get(control, "actuators");
  const int na =
      acts && fy_node_is_sequence(acts) ? fy_node_sequence_item_count(acts) : 0;
  double *initial = calloc((size_t)(na > 0 ? na : 1), sizeof *initial);
  struct fy_node **lists = calloc((size_t)(na > 0 ? na : 1), sizeof *lists);
  if (!initial || !lists) {
    free(initial);
    free(lists);
    mrvi_ocp_free(o);
    return fail(&P, control, "out of memory");
  }
  if (!acts)
    st = fail(&P, control, "control needs 'actuators'");
  if (!st && !(st = load_actuators(&P, acts, o, initial, lists)) &&
      !(st = load_tracking(&P, get(control, "tracking"), o)) &&
      !(st = load_terminal(&P, get(control, "terminal"), o)))
    st = load_solver(&P, get(control, "solver"), o);
  /* The guess is checked also when not asked for (mrvi check, mrvi run). */
  double *guess =
      st ? NULL : malloc((size_t)(o->n_u > 0 ? o->n_u : 1) * sizeof *guess);
  if (!st && !guess)
    st = fail(&P, control, "out of memory");
  if (!st)
    st = initial_values(&P, o, initial, lists, guess);
  if (!st && u0)
    *u0 = guess;
  else
    free(guess);
  free(initial);
  free(lists);
  if (st) {
    mrvi_ocp_free(o);
    return st;
  }
  *out = o;
  return MRVI_OK;
}

int mrvi_ocp_has_control(const mrvi_system *sys) {
  struct fy_document *doc =
      fy_document_build_from_string(NULL, sys->description, FY_NT);
  const int has = doc && get(fy_document_root(doc), "control") != NULL;
  fy_document_destroy(doc);
  return has;
}

int mrvi_ocp_load(const mrvi_system *sys, mrvi_ocp **out, double **u0,
                  char *msg, size_t len) {
  *out = NULL;
  struct fy_document *doc =
      fy_document_build_from_string(NULL, sys->description, FY_NT);
  if (!doc) {
    mrvi_fmt(msg, len, "%s: the description cannot be parsed", sys->path);
    return MRVI_EPARSE;
  }
  struct fy_node *control = get(fy_document_root(doc), "control");
  int st;
  if (!control) {
    mrvi_fmt(msg, len, "%s:1:1: the description has no 'control:' section",
             sys->path);
    st = MRVI_EPARSE;
  } else {
    st = mrvi_ocp_parse(sys->model, &sys->settings, control, sys->path, NULL,
                        NULL, out, u0, msg, len);
  }
  fy_document_destroy(doc);
  return st;
}
