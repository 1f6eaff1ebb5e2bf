/* The `control:` section of a description file (doc/optimal-control.md,
 * keys in doc/description-files.md):
 *
 *   control:
 *     actuators:    [{name, coordinate | pair: [particle, particle],
 *                     grid: macro|micro, weight, lower, upper, initial}]
 *     tracking:     [{coordinate, weight, reference}]
 *     terminal:     [{coordinate, position, velocity, penalty}]
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
  for (int i = 0; s && i < P->m->n; i++)
    if (!strcmp(s, P->m->names[i])) {
      *out = i;
      return MRVI_OK;
    }
  const char *close =
      s ? mrvi_closest(s, (const char *const *)P->m->names, P->m->n) : NULL;
  char hint[160] = "";
  if (close)
    mrvi_fmt(hint, sizeof hint, "; did you mean '%s'?", close);
  return fail(P, n, "unknown coordinate '%s' in %s%s", s ? s : "?", where,
              hint);
}

/* The constraint that pins coordinate c by itself (its gradient at q0 has
 * no other entry), or -1. */
static int fixing_constraint(const mrvi_model *m, int c) {
  for (int i = 0; i < m->n_constraints; i++) {
    const mrvi_constraint *k = &m->constraints[i];
    double y[MRVI_MAX_INPUTS], g[MRVI_MAX_INPUTS];
    double *G = malloc((size_t)(k->rows * k->n_in) * sizeof *G);
    if (!G || k->n_in > MRVI_MAX_INPUTS || k->rows > MRVI_MAX_INPUTS) {
      free(G);
      continue;
    }
    for (int j = 0; j < k->n_in; j++)
      y[j] = m->q0[k->in[j]];
    mrvi_constraint_eval_at(k, y, g, G, NULL);
    int only = 1, touches = 0;
    for (int r = 0; r < k->rows; r++)
      for (int j = 0; j < k->n_in; j++)
        if (G[r * k->n_in + j] != 0.0) {
          if (k->in[j] == c)
            touches = 1;
          else
            only = 0;
        }
    free(G);
    if (touches && only)
      return i;
  }
  return -1;
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
  if (!names)
    return fail(P, n, "out of memory");
  for (int i = 0; i < m->n_particles; i++)
    names[i] = m->particles[i].name;
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
  free(names);
  return st;
}

static const char *const control_keys[] = {"actuators", "tracking", "terminal",
                                           "solver"};
static const char *const actuator_keys[] = {"name",  "coordinate", "pair",
                                            "grid",  "weight",     "lower",
                                            "upper", "initial"};
static const char *const tracking_keys[] = {"coordinate", "weight",
                                            "reference"};
static const char *const terminal_keys[] = {"coordinate", "position",
                                            "velocity", "penalty"};
static const char *const solver_keys[] = {
    "algorithm", "tolerance", "terminal_tolerance", "max_evaluations"};

#define NKEYS(a) ((int)(sizeof a / sizeof a[0]))

static int load_actuators(parser *P, struct fy_node *list, mrvi_ocp *o,
                          double *initial) {
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
    if ((st = get(item, "pair") ? pair(P, item, where, &pi, &pj)
                                : coordinate(P, item, where, &c)) ||
        (st = number(P, item, "weight", where, &w)) ||
        (st = number_of(P, item, "lower", where, 1, &lo)) ||
        (st = number_of(P, item, "upper", where, 1, &hi)) ||
        (st = number(P, item, "initial", where, &u0)))
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
    const int a = pi >= 0
                      ? mrvi_ocp_add_pair_actuator(o, pi, pj, grid, w, lo, hi)
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
                       : " (the default name is the coordinate's; give "
                         "a 'name')");
    initial[a] = u0;
    i++;
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
                  where, what, P->m->names[c], target, o->term[i].target,
                  o->term[i].target == target
                      ? ": a duplicate makes the conditions redundant"
                      : ": the conditions conflict");
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
    if ((st =
             check_keys(P, item, where, terminal_keys, NKEYS(terminal_keys))) ||
        (st = coordinate(P, item, where, &c)) ||
        (st = number(P, item, "position", where, &pos)) ||
        (st = number(P, item, "velocity", where, &vel)) ||
        (st = number(P, item, "penalty", where, &pen)))
      return st;
    if (isnan(pos) && isnan(vel))
      return fail(P, item, "%s needs 'position' and/or 'velocity'", where);
    if (!(pen >= 0.0))
      return fail(P, get(item, "penalty"), "%s.penalty must be >= 0", where);
    const int k = fixing_constraint(P->m, c);
    if (k >= 0)
      return fail(P, get(item, "coordinate"),
                  "%s: coordinate '%s' is fixed by constraint '%s'; a "
                  "terminal condition on it is redundant",
                  where, P->m->names[c], P->m->constraints[k].label);
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
  if (!initial) {
    mrvi_ocp_free(o);
    return fail(&P, control, "out of memory");
  }
  if (!acts)
    st = fail(&P, control, "control needs 'actuators'");
  if (!st && !(st = load_actuators(&P, acts, o, initial)) &&
      !(st = load_tracking(&P, get(control, "tracking"), o)) &&
      !(st = load_terminal(&P, get(control, "terminal"), o)))
    st = load_solver(&P, get(control, "solver"), o);
  if (!st && u0) {
    *u0 = malloc((size_t)o->n_u * sizeof **u0);
    if (!*u0)
      st = fail(&P, control, "out of memory");
    for (int a = 0; !st && a < o->n_act; a++)
      for (int j = 0; j < o->act[a].size; j++)
        (*u0)[o->act[a].offset + j] = initial[a];
  }
  free(initial);
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
