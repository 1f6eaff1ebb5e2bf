/* Reading nodes of a description file: errors at marks (file:line:col, or
 * the --set override that made the node), closest-name suggestions, typed
 * access to scalars, lists and mappings, and key checks.  libfyaml's own
 * diagnostics are collected on a silent diag object: the library never
 * prints. */
#include "io/loader/loader_internal.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static void diag_silent(struct fy_diag *diag, void *user, const char *buf,
                        size_t len) {
  (void)diag, (void)user, (void)buf, (void)len;
}

struct fy_diag *mrvi_ld_diag_create(void) {
  struct fy_diag_cfg cfg;
  fy_diag_cfg_default(&cfg);
  cfg.fp = NULL;
  cfg.output_fn = diag_silent;
  cfg.user = NULL;
  cfg.colorize = false;
  struct fy_diag *diag = fy_diag_create(&cfg);
  if (diag)
    fy_diag_set_collect_errors(diag, true);
  return diag;
}

/* The override that created n or one of its ancestors, or NULL. */
const char *mrvi_ld_override_of(const loader *L, struct fy_node *n) {
  for (; n; n = fy_node_get_parent(n))
    for (int i = 0; i < L->n_ov; i++)
      if (L->ov[i].node == n)
        return L->ov[i].text;
  return NULL;
}

static int token_position(struct fy_token *t, int *line, int *col) {
  const struct fy_mark *m = t ? fy_token_start_mark(t) : NULL;
  if (!m)
    return 0;
  *line = m->line + 1;
  *col = m->column + 1;
  return 1;
}

/* Position of the key that holds n (through enclosing lists). */
static int holder_position(struct fy_node *n, int *line, int *col) {
  struct fy_node *parent = fy_node_get_parent(n);
  if (!parent)
    return 0;
  if (fy_node_is_mapping(parent)) {
    void *it = NULL;
    struct fy_node_pair *p;
    while ((p = fy_node_mapping_iterate(parent, &it)))
      if (fy_node_pair_value(p) == n)
        return token_position(fy_node_get_scalar_token(fy_node_pair_key(p)),
                              line, col);
    return 0;
  }
  return holder_position(parent, line, col);
}

/* 1-based position of a parsed node: a scalar's token; for a collection its
 * first key or item; for an empty value the key that holds it.  (The
 * public API of libfyaml 0.7 has no marks on collections.) */
int mrvi_ld_node_position(struct fy_node *n, int *line, int *col) {
  if (!n)
    return 0;
  if (fy_node_is_scalar(n)) /* an empty value has no token */
    return token_position(fy_node_get_scalar_token(n), line, col) ||
           holder_position(n, line, col);
  void *it = NULL;
  struct fy_node *first = NULL;
  if (fy_node_is_mapping(n)) {
    struct fy_node_pair *p = fy_node_mapping_iterate(n, &it);
    first = p ? fy_node_pair_key(p) : NULL;
  } else {
    first = fy_node_sequence_iterate(n, &it);
  }
  return (first && mrvi_ld_node_position(first, line, col)) ||
         holder_position(n, line, col);
}

/* Write "where: message" and return MRVI_EPARSE.  `at` may be NULL (the
 * document as a whole, reported at 1:1). */
int mrvi_ld_fail(loader *L, struct fy_node *at, const char *fmt, ...) {
  char text[768];
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(text, sizeof text, fmt, ap);
  va_end(ap);
  const char *ov = mrvi_ld_override_of(L, at);
  int line, col;
  if (ov)
    mrvi_fmt(L->msg, L->len, "--set %s: %s", ov, text);
  else if (mrvi_ld_node_position(at, &line, &col))
    mrvi_fmt(L->msg, L->len, "%s:%d:%d: %s", L->path, line, col, text);
  else /* the document as a whole */
    mrvi_fmt(L->msg, L->len, "%s:1:1: %s", L->path, text);
  return MRVI_EPARSE;
}

int mrvi_ld_fail_nomem(loader *L) {
  mrvi_fmt(L->msg, L->len, "%s: out of memory", L->path);
  return MRVI_ENOMEM;
}

/* Builder failure: the model's message at the element's node. */
int mrvi_ld_fail_model_in(loader *L, struct fy_node *at, int status,
                          const char *fn) {
  if (status == MRVI_ENOMEM)
    return mrvi_ld_fail_nomem(L);
  const char *msg = mrvi_model_errmsg(L->sys->model);
  if (status >= 0 || !msg || !msg[0])
    return mrvi_ld_fail(L, at,
                        "internal error: a model builder called by %s "
                        "returned %d (%s) without a message",
                        fn, status, mrvi_strerror(status));
  return mrvi_ld_fail(L, at, "%s", msg);
}

/* "; did you mean 'x'?" or "; known: a, b, c" into buf. */
void mrvi_ld_suggest(char *buf, size_t len, const char *word,
                     const char *const *cand, int n) {
  const char *c = mrvi_closest(word, cand, n);
  if (c) {
    mrvi_fmt(buf, len, "; did you mean '%s'?", c);
    return;
  }
  size_t used = 0;
  buf[0] = '\0';
  for (int i = 0; i < n && used + 1 < len; i++) {
    int w = snprintf(buf + used, len - used, "%s%s",
                     i ? ", " : "; known: ", cand[i]);
    if (w < 0)
      break;
    used += (size_t)w;
  }
  if (n == 0)
    mrvi_fmt(buf, len, "; none defined");
}

const char *mrvi_ld_scalar0(struct fy_node *n) {
  const char *s = fy_node_get_scalar0(n);
  return s ? s : "";
}

/* YAML 1.2 core schema null: empty plain scalar, ~, null. */
int mrvi_ld_is_null(struct fy_node *n) {
  if (!n)
    return 1;
  if (!fy_node_is_scalar(n) || fy_node_get_style(n) != FYNS_PLAIN)
    return 0;
  const char *s = mrvi_ld_scalar0(n);
  return !*s || !strcmp(s, "~") || !strcmp(s, "null") || !strcmp(s, "Null") ||
         !strcmp(s, "NULL");
}

/* What a node is, for type errors. */
static void describe(struct fy_node *n, char *buf, size_t len) {
  if (mrvi_ld_is_null(n))
    mrvi_fmt(buf, len, "nothing");
  else if (fy_node_is_mapping(n))
    mrvi_fmt(buf, len, "a mapping");
  else if (fy_node_is_sequence(n))
    mrvi_fmt(buf, len, "a list");
  else if (fy_node_get_style(n) == FYNS_PLAIN)
    mrvi_fmt(buf, len, "'%.60s'", mrvi_ld_scalar0(n));
  else
    mrvi_fmt(buf, len, "the string \"%.60s\"", mrvi_ld_scalar0(n));
}

/* Pair of a mapping whose key is the scalar `key`, or NULL.  (libfyaml's
 * lookup by string parses the key as YAML and may print diagnostics.) */
struct fy_node_pair *mrvi_ld_find_pair(struct fy_node *map, const char *key) {
  size_t klen = strlen(key), len;
  void *it = NULL;
  struct fy_node_pair *p;
  while ((p = fy_node_mapping_iterate(map, &it))) {
    struct fy_node *k = fy_node_pair_key(p);
    const char *s = fy_node_is_scalar(k) ? fy_node_get_scalar(k, &len) : NULL;
    if (s && len == klen && !memcmp(s, key, len))
      return p;
  }
  return NULL;
}

/* Value of `key` in a mapping, NULL if absent or null. */
struct fy_node *mrvi_ld_get(struct fy_node *map, const char *key) {
  struct fy_node_pair *p = mrvi_ld_find_pair(map, key);
  struct fy_node *v = p ? fy_node_pair_value(p) : NULL;
  return mrvi_ld_is_null(v) ? NULL : v;
}

/* Required value of `key`; `where` names the mapping for the message. */
int mrvi_ld_need(loader *L, struct fy_node *map, const char *key,
                 const char *where, struct fy_node **out) {
  struct fy_node_pair *p = mrvi_ld_find_pair(map, key);
  if (!p)
    return mrvi_ld_fail(L, map, "missing key '%s' in %s", key, where);
  if (mrvi_ld_is_null(fy_node_pair_value(p)))
    return mrvi_ld_fail(L, fy_node_pair_key(p), "key '%s' in %s has no value",
                        key, where);
  *out = fy_node_pair_value(p);
  return MRVI_OK;
}

int mrvi_ld_want_mapping(loader *L, struct fy_node *n, const char *what) {
  char got[96];
  if (fy_node_is_mapping(n))
    return MRVI_OK;
  describe(n, got, sizeof got);
  return mrvi_ld_fail(L, n, "%s must be a mapping, got %s", what, got);
}

int mrvi_ld_want_list(loader *L, struct fy_node *n, const char *what) {
  char got[96];
  if (fy_node_is_sequence(n))
    return MRVI_OK;
  describe(n, got, sizeof got);
  return mrvi_ld_fail(L, n, "%s must be a list, got %s", what, got);
}

/* A finite number (plain scalar). */
int mrvi_ld_as_number(loader *L, struct fy_node *n, const char *what,
                      double *out) {
  char got[96];
  describe(n, got, sizeof got);
  if (!fy_node_is_scalar(n) || fy_node_get_style(n) != FYNS_PLAIN ||
      mrvi_ld_is_null(n))
    return mrvi_ld_fail(L, n, "%s must be a number, got %s", what, got);
  const char *s = mrvi_ld_scalar0(n);
  const char *t = s + (*s == '+' || *s == '-');
  if (!strcmp(t, ".inf") || !strcmp(t, ".Inf") || !strcmp(t, ".INF") ||
      !strcmp(t, ".nan") || !strcmp(t, ".NaN") || !strcmp(t, ".NAN"))
    return mrvi_ld_fail(L, n, "%s must be a finite number, got %s", what, s);
  char *end;
  errno = 0;
  double v = strtod(s, &end);
  if (end == s || *end)
    return mrvi_ld_fail(L, n, "%s must be a number, got %s", what, got);
  if (!isfinite(v) || (errno == ERANGE && fabs(v) > 1.0))
    return mrvi_ld_fail(L, n, "%s must be a finite number, got %s", what, s);
  *out = v;
  return MRVI_OK;
}

int mrvi_ld_as_int(loader *L, struct fy_node *n, const char *what, int *out) {
  double v;
  int st = mrvi_ld_as_number(L, n, what, &v);
  if (st)
    return st;
  if (v != floor(v))
    return mrvi_ld_fail(L, n, "%s must be an integer, got %s", what,
                        mrvi_ld_scalar0(n));
  if (fabs(v) > 1e9)
    return mrvi_ld_fail(L, n, "%s must be at most 10^9 in magnitude, got %s",
                        what, mrvi_ld_scalar0(n));
  *out = (int)v;
  return MRVI_OK;
}

int mrvi_ld_as_bool(loader *L, struct fy_node *n, const char *what, int *out) {
  static const char *const yes[] = {"true", "True", "TRUE"};
  static const char *const no[] = {"false", "False", "FALSE"};
  if (fy_node_is_scalar(n) && fy_node_get_style(n) == FYNS_PLAIN) {
    const char *s = mrvi_ld_scalar0(n);
    for (int i = 0; i < 3; i++) {
      if (!strcmp(s, yes[i]) || !strcmp(s, no[i])) {
        *out = !strcmp(s, yes[i]);
        return MRVI_OK;
      }
    }
  }
  char got[96];
  describe(n, got, sizeof got);
  return mrvi_ld_fail(L, n, "%s must be true or false, got %s", what, got);
}

/* A non-empty string (any scalar style). */
int mrvi_ld_as_string(loader *L, struct fy_node *n, const char *what,
                      const char **out) {
  char got[96];
  if (!fy_node_is_scalar(n) || mrvi_ld_is_null(n) || !*mrvi_ld_scalar0(n)) {
    describe(n, got, sizeof got);
    return mrvi_ld_fail(L, n, "%s must be a string, got %s", what, got);
  }
  *out = mrvi_ld_scalar0(n);
  return MRVI_OK;
}

/* One of a list of names; the message lists them (or suggests one). */
int mrvi_ld_as_choice(loader *L, struct fy_node *n, const char *what,
                      const char *const *names, int count, int *out) {
  const char *s;
  int st = mrvi_ld_as_string(L, n, what, &s);
  if (st)
    return st;
  for (int i = 0; i < count; i++) {
    if (!strcmp(s, names[i])) {
      *out = i;
      return MRVI_OK;
    }
  }
  char hint[512];
  mrvi_ld_suggest(hint, sizeof hint, s, names, count);
  return mrvi_ld_fail(L, n, "unknown %s '%s'%s", what, s, hint);
}

/* A list of exactly `dim` finite numbers (a bare number when dim is 1). */
int mrvi_ld_as_vector(loader *L, struct fy_node *n, const char *what, int dim,
                      double *out) {
  char item[80];
  if (dim == 1 && fy_node_is_scalar(n))
    return mrvi_ld_as_number(L, n, what, out);
  int st = mrvi_ld_want_list(L, n, what);
  if (st)
    return st;
  int count = fy_node_sequence_item_count(n);
  if (count != dim)
    return mrvi_ld_fail(L, n, "%s has %d entries, expected %d (dimension)",
                        what, count, dim);
  for (int i = 0; i < dim; i++) {
    mrvi_fmt(item, sizeof item, "%s[%d]", what, i);
    st = mrvi_ld_as_number(L, fy_node_sequence_get_by_index(n, i), item,
                           out + i);
    if (st)
      return st;
  }
  return MRVI_OK;
}

int mrvi_ld_as_unit(loader *L, struct fy_node *n, const char *what, int dim,
                    double *out) {
  int st = mrvi_ld_want_list(L, n, what);
  if (st)
    return st;
  if (fy_node_sequence_item_count(n) != dim)
    return mrvi_ld_fail(L, n, "%s has %d entries, expected %d", what,
                        fy_node_sequence_item_count(n), dim);
  if ((st = mrvi_ld_as_vector(L, n, what, dim, out)))
    return st;
  double len = 0;
  for (int i = 0; i < dim; i++)
    len += out[i] * out[i];
  len = sqrt(len);
  if (!(len > 0))
    return mrvi_ld_fail(L, n, "the %s must not be zero", what);
  if (!(fabs(len - 1) <= 1e-6))
    return mrvi_ld_fail(L, n,
                        "the %s must be a unit vector (length %.9g); divide "
                        "it by its length",
                        what, len);
  for (int i = 0; i < dim; i++)
    out[i] /= len;
  return MRVI_OK;
}

/* Every key of `map` must be in keys[0..n) or extra[0..n_extra). */
int mrvi_ld_check_keys(loader *L, struct fy_node *map, const char *where,
                       const char *const *keys, int n, const char *const *extra,
                       int n_extra) {
  const char *all[MAX_KEYS];
  int n_all = 0;
  for (int i = 0; i < n && n_all < MAX_KEYS; i++)
    all[n_all++] = keys[i];
  for (int i = 0; i < n_extra && n_all < MAX_KEYS; i++)
    all[n_all++] = extra[i];
  void *it = NULL;
  struct fy_node_pair *p;
  while ((p = fy_node_mapping_iterate(map, &it))) {
    struct fy_node *k = fy_node_pair_key(p);
    if (!fy_node_is_scalar(k) || mrvi_ld_is_null(k))
      return mrvi_ld_fail(L, k ? k : map, "keys in %s must be names", where);
    const char *s = mrvi_ld_scalar0(k);
    int known = 0;
    for (int i = 0; i < n_all && !known; i++)
      known = !strcmp(s, all[i]);
    if (!known) {
      char hint[512];
      mrvi_ld_suggest(hint, sizeof hint, s, all, n_all);
      return mrvi_ld_fail(L, k, "unknown key '%s' in %s%s", s, where, hint);
    }
  }
  return MRVI_OK;
}

int mrvi_ld_as_rate(loader *L, struct fy_node *map, const char *key,
                    mrvi_rate *out) {
  static const char *const rates[] = {"slow", "fast"};
  struct fy_node *n = mrvi_ld_get(map, key);
  int r = 0;
  if (n) {
    int st = mrvi_ld_as_choice(L, n, key, rates, 2, &r);
    if (st)
      return st;
  }
  *out = r ? MRVI_FAST : MRVI_SLOW;
  return MRVI_OK;
}

/* Optional number with a default. */
int mrvi_ld_opt_number(loader *L, struct fy_node *map, const char *key,
                       double def, double *out) {
  struct fy_node *n = mrvi_ld_get(map, key);
  *out = def;
  return n ? mrvi_ld_as_number(L, n, key, out) : MRVI_OK;
}

/* Optional number > 0 under `key` (`what` in messages); *out is left alone
 * when the key is absent.  *node (may be NULL) gets the value's node. */
int mrvi_ld_opt_positive(loader *L, struct fy_node *map, const char *key,
                         const char *what, double *out, struct fy_node **node) {
  struct fy_node *n = mrvi_ld_get(map, key);
  int st;
  if (node)
    *node = n;
  if (!n)
    return MRVI_OK;
  if ((st = mrvi_ld_as_number(L, n, what, out)))
    return st;
  if (!(*out > 0))
    return mrvi_ld_fail(L, n, "%s must be > 0, got %s", what,
                        mrvi_ld_scalar0(n));
  return MRVI_OK;
}

/* Append a line to sys->notes. */
int mrvi_ld_add_note(loader *L, const char *fmt, ...) {
  char text[512];
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(text, sizeof text, fmt, ap);
  va_end(ap);
  char *old = L->sys->notes;
  const size_t len = (old ? strlen(old) + 1 : 0) + strlen(text) + 1;
  char *notes = malloc(len);
  if (!notes)
    return mrvi_ld_fail_nomem(L);
  mrvi_fmt(notes, len, "%s%s%s", old ? old : "", old ? "\n" : "", text);
  free(old);
  L->sys->notes = notes;
  return MRVI_OK;
}

/* First collected libfyaml error, as file:line:col: message. */
int mrvi_ld_syntax_error(loader *L) {
  void *it = NULL;
  struct fy_diag_error *e, *first = NULL;
  while ((e = fy_diag_errors_iterate(L->diag, &it)))
    if (!first || (first->line <= 0 && e->line > 0))
      first = e;
  if (first && first->line > 0)
    mrvi_fmt(L->msg, L->len, "%s:%d:%d: YAML syntax error: %s", L->path,
             first->line, first->column > 0 ? first->column : 1,
             first->msg ? first->msg : "invalid YAML");
  else
    mrvi_fmt(L->msg, L->len, "%s: YAML syntax error: %s", L->path,
             first && first->msg ? first->msg : "invalid YAML");
  return MRVI_EPARSE;
}
