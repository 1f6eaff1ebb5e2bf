/* Description files (doc/description-files.md): YAML 1.2 read with libfyaml,
 * --set overrides applied to the document tree, then interpreted into a
 * model and integrator settings.
 *
 * Every error becomes "file:line:col: message" at the node that caused it
 * (1-based), or "--set KEY=VALUE: message" when the node came from an
 * override.  libfyaml's own diagnostics are collected on a silent diag
 * object: the library never prints. */
#include "internal.h"

#include <libfyaml.h>

#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define COUNT(a) ((int)(sizeof(a) / sizeof((a)[0])))
#define MAX_KEYS 64 /* keys of one mapping, law parameters included */
/* Limits on hostile input (doc/description-files.md, "Limits"). */
#define MAX_TEXT ((size_t)64 << 20) /* bytes of a description or override */
#define MAX_DEPTH 256               /* nesting, counted through aliases */
/* Nodes aliases may add: this many plus 4 per node of the file. */
#define MAX_ALIAS_NODES 100000L

/* Node created by an override, with the override's text. */
typedef struct override_node {
  struct fy_node *node;
  const char *text;
} override_node;

/* An override that replaced a scalar of the input text: the description
 * keeps the file's text (and comments) with value spliced into
 * text[start, end). */
typedef struct splice {
  size_t start, end;
  const char *value;
  struct fy_node *node; /* the new value node */
} splice;

/* A name defined in the file: coordinate or particle. */
typedef struct named {
  const char *name; /* owned by the document */
  struct fy_node *node;
  int index; /* model coordinate index / particle index */
} named;

/* Open-addressing hash of names (linear probing, FNV-1a): slot holds
 * 1 + value, 0 when empty; keys point into the document or the model. */
typedef struct name_hash {
  const char **key;
  int *val;
  size_t cap, n; /* cap a power of two (or 0), n <= cap / 2 */
} name_hash;

typedef struct loader {
  const char *path; /* display name */
  struct fy_diag *diag;
  struct fy_document *doc;
  char *msg;
  size_t len;
  override_node *ov;
  int n_ov, cap_ov;
  splice *sp;
  int n_sp, cap_sp;
  int splice_ok; /* every override replaced a scalar of the text */
  named *coords, *parts;
  int n_coords, n_parts;
  name_hash coord_hash, part_hash;   /* name -> index into coords / parts */
  name_hash model_hash;              /* model coordinate name -> index */
  struct fy_node *constraint_list;   /* `constraints:`, NULL if absent */
  struct fy_node **constraint_items; /* entry of each model constraint */
  mrvi_system *sys;
} loader;

/* ---------------------------------------------------------------------------
 * Error reporting
 * ------------------------------------------------------------------------- */

static void diag_silent(struct fy_diag *diag, void *user, const char *buf,
                        size_t len) {
  (void)diag, (void)user, (void)buf, (void)len;
}

static struct fy_diag *diag_create(void) {
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
static const char *override_of(const loader *L, struct fy_node *n) {
  for (; n; n = fy_node_get_parent(n))
    for (int i = 0; i < L->n_ov; i++)
      if (L->ov[i].node == n)
        return L->ov[i].text;
  return NULL;
}
static const char *loader_override_of(const void *L, struct fy_node *n) {
  return override_of(L, n);
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
static int node_position(struct fy_node *n, int *line, int *col) {
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
  return (first && node_position(first, line, col)) ||
         holder_position(n, line, col);
}

/* Write "where: message" and return MRVI_EPARSE.  `at` may be NULL (the
 * document as a whole, reported at 1:1). */
__attribute__((format(printf, 3, 4))) static int
fail(loader *L, struct fy_node *at, const char *fmt, ...) {
  char text[768];
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(text, sizeof text, fmt, ap);
  va_end(ap);
  const char *ov = override_of(L, at);
  int line, col;
  if (ov)
    mrvi_fmt(L->msg, L->len, "--set %s: %s", ov, text);
  else if (node_position(at, &line, &col))
    mrvi_fmt(L->msg, L->len, "%s:%d:%d: %s", L->path, line, col, text);
  else /* the document as a whole */
    mrvi_fmt(L->msg, L->len, "%s:1:1: %s", L->path, text);
  return MRVI_EPARSE;
}

static int fail_nomem(loader *L) {
  mrvi_fmt(L->msg, L->len, "%s: out of memory", L->path);
  return MRVI_ENOMEM;
}

/* Builder failure: the model's message at the element's node. */
static int fail_model(loader *L, struct fy_node *at, int status) {
  if (status == MRVI_ENOMEM)
    return fail_nomem(L);
  return fail(L, at, "%s", mrvi_model_errmsg(L->sys->model));
}

/* ---------------------------------------------------------------------------
 * Closest-name suggestions
 * ------------------------------------------------------------------------- */

/* "; did you mean 'x'?" or "; known: a, b, c" into buf. */
static void suggest(char *buf, size_t len, const char *word,
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

/* ---------------------------------------------------------------------------
 * Typed access to nodes
 * ------------------------------------------------------------------------- */

static const char *scalar0(struct fy_node *n) {
  const char *s = fy_node_get_scalar0(n);
  return s ? s : "";
}

/* YAML 1.2 core schema null: empty plain scalar, ~, null. */
static int is_null(struct fy_node *n) {
  if (!n)
    return 1;
  if (!fy_node_is_scalar(n) || fy_node_get_style(n) != FYNS_PLAIN)
    return 0;
  const char *s = scalar0(n);
  return !*s || !strcmp(s, "~") || !strcmp(s, "null") || !strcmp(s, "Null") ||
         !strcmp(s, "NULL");
}

/* What a node is, for type errors. */
static void describe(struct fy_node *n, char *buf, size_t len) {
  if (is_null(n))
    mrvi_fmt(buf, len, "nothing");
  else if (fy_node_is_mapping(n))
    mrvi_fmt(buf, len, "a mapping");
  else if (fy_node_is_sequence(n))
    mrvi_fmt(buf, len, "a list");
  else if (fy_node_get_style(n) == FYNS_PLAIN)
    mrvi_fmt(buf, len, "'%.60s'", scalar0(n));
  else
    mrvi_fmt(buf, len, "the string \"%.60s\"", scalar0(n));
}

/* Pair of a mapping whose key is the scalar `key`, or NULL.  (libfyaml's
 * lookup by string parses the key as YAML and may print diagnostics.) */
static struct fy_node_pair *find_pair(struct fy_node *map, const char *key) {
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
static struct fy_node *get(struct fy_node *map, const char *key) {
  struct fy_node_pair *p = find_pair(map, key);
  struct fy_node *v = p ? fy_node_pair_value(p) : NULL;
  return is_null(v) ? NULL : v;
}

/* Required value of `key`; `where` names the mapping for the message. */
static int need(loader *L, struct fy_node *map, const char *key,
                const char *where, struct fy_node **out) {
  struct fy_node_pair *p = find_pair(map, key);
  if (!p)
    return fail(L, map, "missing key '%s' in %s", key, where);
  if (is_null(fy_node_pair_value(p)))
    return fail(L, fy_node_pair_key(p), "key '%s' in %s has no value", key,
                where);
  *out = fy_node_pair_value(p);
  return MRVI_OK;
}

static int want_mapping(loader *L, struct fy_node *n, const char *what) {
  char got[96];
  if (fy_node_is_mapping(n))
    return MRVI_OK;
  describe(n, got, sizeof got);
  return fail(L, n, "%s must be a mapping, got %s", what, got);
}

static int want_list(loader *L, struct fy_node *n, const char *what) {
  char got[96];
  if (fy_node_is_sequence(n))
    return MRVI_OK;
  describe(n, got, sizeof got);
  return fail(L, n, "%s must be a list, got %s", what, got);
}

/* A finite number (plain scalar). */
static int as_number(loader *L, struct fy_node *n, const char *what,
                     double *out) {
  char got[96];
  describe(n, got, sizeof got);
  if (!fy_node_is_scalar(n) || fy_node_get_style(n) != FYNS_PLAIN || is_null(n))
    return fail(L, n, "%s must be a number, got %s", what, got);
  const char *s = scalar0(n);
  const char *t = s + (*s == '+' || *s == '-');
  if (!strcmp(t, ".inf") || !strcmp(t, ".Inf") || !strcmp(t, ".INF") ||
      !strcmp(t, ".nan") || !strcmp(t, ".NaN") || !strcmp(t, ".NAN"))
    return fail(L, n, "%s must be a finite number, got %s", what, s);
  char *end;
  errno = 0;
  double v = strtod(s, &end);
  if (end == s || *end)
    return fail(L, n, "%s must be a number, got %s", what, got);
  if (!isfinite(v) || (errno == ERANGE && fabs(v) > 1.0))
    return fail(L, n, "%s must be a finite number, got %s", what, s);
  *out = v;
  return MRVI_OK;
}

static int as_int(loader *L, struct fy_node *n, const char *what, int *out) {
  double v;
  int st = as_number(L, n, what, &v);
  if (st)
    return st;
  if (v != floor(v))
    return fail(L, n, "%s must be an integer, got %s", what, scalar0(n));
  if (fabs(v) > 1e9)
    return fail(L, n, "%s must be at most 10^9 in magnitude, got %s", what,
                scalar0(n));
  *out = (int)v;
  return MRVI_OK;
}

static int as_bool(loader *L, struct fy_node *n, const char *what, int *out) {
  static const char *const yes[] = {"true", "True", "TRUE"};
  static const char *const no[] = {"false", "False", "FALSE"};
  if (fy_node_is_scalar(n) && fy_node_get_style(n) == FYNS_PLAIN) {
    const char *s = scalar0(n);
    for (int i = 0; i < 3; i++) {
      if (!strcmp(s, yes[i]) || !strcmp(s, no[i])) {
        *out = !strcmp(s, yes[i]);
        return MRVI_OK;
      }
    }
  }
  char got[96];
  describe(n, got, sizeof got);
  return fail(L, n, "%s must be true or false, got %s", what, got);
}

/* A non-empty string (any scalar style). */
static int as_string(loader *L, struct fy_node *n, const char *what,
                     const char **out) {
  char got[96];
  if (!fy_node_is_scalar(n) || is_null(n) || !*scalar0(n)) {
    describe(n, got, sizeof got);
    return fail(L, n, "%s must be a string, got %s", what, got);
  }
  *out = scalar0(n);
  return MRVI_OK;
}

/* One of a list of names; the message lists them (or suggests one). */
static int as_choice(loader *L, struct fy_node *n, const char *what,
                     const char *const *names, int count, int *out) {
  const char *s;
  int st = as_string(L, n, what, &s);
  if (st)
    return st;
  for (int i = 0; i < count; i++) {
    if (!strcmp(s, names[i])) {
      *out = i;
      return MRVI_OK;
    }
  }
  char hint[512];
  suggest(hint, sizeof hint, s, names, count);
  return fail(L, n, "unknown %s '%s'%s", what, s, hint);
}

/* A list of exactly `dim` finite numbers (a bare number when dim is 1). */
static int as_vector(loader *L, struct fy_node *n, const char *what, int dim,
                     double *out) {
  char item[80];
  if (dim == 1 && fy_node_is_scalar(n))
    return as_number(L, n, what, out);
  int st = want_list(L, n, what);
  if (st)
    return st;
  int count = fy_node_sequence_item_count(n);
  if (count != dim)
    return fail(L, n, "%s has %d entries, expected %d (dimension)", what, count,
                dim);
  for (int i = 0; i < dim; i++) {
    mrvi_fmt(item, sizeof item, "%s[%d]", what, i);
    st = as_number(L, fy_node_sequence_get_by_index(n, i), item, out + i);
    if (st)
      return st;
  }
  return MRVI_OK;
}

/* Every key of `map` must be in keys[0..n) or extra[0..n_extra). */
static int check_keys(loader *L, struct fy_node *map, const char *where,
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
    if (!fy_node_is_scalar(k) || is_null(k))
      return fail(L, k ? k : map, "keys in %s must be names", where);
    const char *s = scalar0(k);
    int known = 0;
    for (int i = 0; i < n_all && !known; i++)
      known = !strcmp(s, all[i]);
    if (!known) {
      char hint[512];
      suggest(hint, sizeof hint, s, all, n_all);
      return fail(L, k, "unknown key '%s' in %s%s", s, where, hint);
    }
  }
  return MRVI_OK;
}

/* ---------------------------------------------------------------------------
 * Overrides: "dotted.path=value" applied to the document tree
 * ------------------------------------------------------------------------- */

static int remember(loader *L, struct fy_node *n, const char *text) {
  if (L->n_ov == L->cap_ov) {
    int cap = L->cap_ov ? 2 * L->cap_ov : 8;
    override_node *ov = realloc(L->ov, (size_t)cap * sizeof *ov);
    if (!ov)
      return MRVI_ENOMEM;
    L->ov = ov;
    L->cap_ov = cap;
  }
  L->ov[L->n_ov].node = n;
  L->ov[L->n_ov].text = text;
  L->n_ov++;
  return MRVI_OK;
}

static int set_error(loader *L, const char *text, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static int set_error(loader *L, const char *text, const char *fmt, ...) {
  char buf[512];
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(buf, sizeof buf, fmt, ap);
  va_end(ap);
  mrvi_fmt(L->msg, L->len, "--set %s: %s", text, buf);
  return MRVI_EPARSE;
}

/* Pair of `map` whose key is the longest run of segments seg[0..k) joined by
 * dots (coordinate names such as m1.x contain dots); *used = k.  The
 * segments lie one after another in one buffer, NULs in place of the dots,
 * so each key is compared once with the remaining path (linear in the
 * mapping's keys, whatever the path's length). */
static struct fy_node_pair *
lookup_segments(struct fy_node *map, char *const *seg, int n_seg, int *used) {
  const char *path = seg[0];
  const char *end = seg[n_seg - 1] + strlen(seg[n_seg - 1]);
  size_t best_len = 0, len;
  struct fy_node_pair *best = NULL, *p;
  void *it = NULL;
  while ((p = fy_node_mapping_iterate(map, &it))) {
    struct fy_node *k = fy_node_pair_key(p);
    const char *s = fy_node_is_scalar(k) ? fy_node_get_scalar(k, &len) : NULL;
    if (!s || len == 0 || len > (size_t)(end - path) || len <= best_len ||
        (path[len] != '\0' && path + len != end))
      continue;
    size_t c = 0;
    while (c < len && (path[c] ? path[c] : '.') == s[c] &&
           (path[c] || s[c] == '.'))
      c++;
    if (c == len) {
      best = p;
      best_len = len;
    }
  }
  if (best) {
    int k = 1;
    for (size_t c = 0; c < best_len; c++)
      k += path[c] == '\0';
    *used = k;
  }
  return best;
}

/* The segments seg[0..upto) joined for messages. */
static void path_prefix(char *buf, size_t len, char *const *seg, int upto) {
  size_t off = 0;
  buf[0] = '\0';
  for (int i = 0; i < upto; i++) {
    int w = snprintf(buf + off, len - off, "%s%s", i ? "." : "", seg[i]);
    if (w < 0 || (size_t)w >= len - off)
      return;
    off += (size_t)w;
  }
}

/* Note that `old` (about to be replaced by `v`) was a scalar of the input
 * text, or clear splice_ok when the change cannot be spliced. */
static int note_splice(loader *L, struct fy_node *old, struct fy_node *v,
                       const char *value) {
  for (int i = 0; i < L->n_sp; i++)
    if (L->sp[i].node == old) { /* the same key set twice */
      L->sp[i].node = v;
      L->sp[i].value = value;
      return MRVI_OK;
    }
  struct fy_token *t = fy_node_get_scalar_token(old);
  const struct fy_mark *a = t ? fy_token_start_mark(t) : NULL;
  const struct fy_mark *b = t ? fy_token_end_mark(t) : NULL;
  /* Plain scalars only: a quoted scalar's token excludes its quotes. */
  if (!a || !b || fy_node_get_style(old) != FYNS_PLAIN || override_of(L, old) ||
      b->input_pos < a->input_pos) {
    L->splice_ok = 0;
    return MRVI_OK;
  }
  if (L->n_sp == L->cap_sp) {
    int cap = L->cap_sp ? 2 * L->cap_sp : 8;
    splice *sp = realloc(L->sp, (size_t)cap * sizeof *sp);
    if (!sp)
      return MRVI_ENOMEM;
    L->sp = sp;
    L->cap_sp = cap;
  }
  L->sp[L->n_sp++] = (splice){a->input_pos, b->input_pos, value, v};
  return MRVI_OK;
}

static long first_invalid(const char *text, size_t n, int *line, int *col,
                          long *code);
static void describe_invalid(char *buf, size_t len, const char *text, long at,
                             long code);
static struct fy_node *find_alias(struct fy_node *n);

/* Parse `value` as a YAML node of the document. */
static int build_value(loader *L, const char *text, const char *value,
                       struct fy_node **out) {
  if (!*value)
    return set_error(L, text, "empty value");
  int line, col;
  long code, at = first_invalid(value, strlen(value), &line, &col, &code);
  if (at >= 0) {
    char what[128];
    describe_invalid(what, sizeof what, value, at, code);
    return set_error(L, text, "%s", what);
  }
  *out = fy_node_build_from_string(L->doc, value, FY_NT);
  if (*out && find_alias(*out)) {
    fy_node_free(*out);
    *out = NULL;
    return set_error(L, text, "aliases (*name) are not allowed in a value");
  }
  if (*out)
    return MRVI_OK;
  void *it = NULL;
  struct fy_diag_error *e, *last = NULL;
  while ((e = fy_diag_errors_iterate(L->diag, &it)))
    last = e;
  return set_error(L, text, "invalid value: %s",
                   last && last->msg ? last->msg : "not a YAML value");
}

/* Replace `old` (the value of pair p, or else an item of the list seq) by
 * the override's value. */
static int replace_value(loader *L, const char *text, const char *value,
                         struct fy_node_pair *p, struct fy_node *seq,
                         struct fy_node *old) {
  struct fy_node *v;
  int st = build_value(L, text, value, &v);
  if (st)
    return st;
  if (note_splice(L, old, v, value)) {
    fy_node_free(v);
    return fail_nomem(L);
  }
  if (p) {
    if (fy_node_pair_set_value(p, v)) {
      fy_node_free(v);
      return fail_nomem(L);
    }
  } else {
    if (fy_node_sequence_insert_before(seq, old, v) ||
        !fy_node_sequence_remove(seq, old)) {
      fy_node_free(v);
      return fail_nomem(L);
    }
    fy_node_free(old);
  }
  return remember(L, v, text) ? fail_nomem(L) : MRVI_OK;
}

/* Add `key` to a mapping: with the override's value when `value` is given,
 * else an empty mapping (*out) to continue the path in. */
static int add_key(loader *L, const char *text, struct fy_node *map,
                   const char *key, const char *value, struct fy_node **out) {
  struct fy_node *k = fy_node_create_scalar_copy(L->doc, key, FY_NT);
  struct fy_node *v = NULL;
  int st = value ? build_value(L, text, value, &v) : MRVI_OK;
  if (!st && !value)
    v = fy_node_create_mapping(L->doc);
  if (st || !k || !v || fy_node_mapping_append(map, k, v)) {
    fy_node_free(k);
    fy_node_free(v);
    return st ? st : fail_nomem(L);
  }
  L->splice_ok = 0; /* the text has no place for a new key */
  if (remember(L, k, text) || remember(L, v, text))
    return fail_nomem(L);
  *out = v;
  return MRVI_OK;
}

/* Walk the dotted path seg[0..n_seg) from the root: list items by index,
 * mapping keys by name (missing keys are created), then set the value. */
static int set_path(loader *L, const char *text, const char *value,
                    char *const *seg, int n_seg) {
  struct fy_node *node = fy_document_root(L->doc);
  char where[512], parent[512];
  if (!node || !fy_node_is_mapping(node))
    return set_error(L, text, "the document is not a mapping");
  for (int i = 0, depth = 1; i < n_seg; depth++) {
    if (depth > MAX_DEPTH) /* the document's own depth bound */
      return set_error(L, text, "the path is deeper than %d levels", MAX_DEPTH);
    if (fy_node_is_sequence(node)) {
      char *end;
      long idx = strtol(seg[i], &end, 10);
      int count = fy_node_sequence_item_count(node);
      path_prefix(where, sizeof where, seg, i + 1); /* for messages */
      path_prefix(parent, sizeof parent, seg, i);
      if (*end || end == seg[i] || idx < 0 || idx >= count)
        return set_error(L, text,
                         "no such key '%s' (%s has %d item%s, index from 0)",
                         where, parent, count, count == 1 ? "" : "s");
      struct fy_node *item = fy_node_sequence_get_by_index(node, (int)idx);
      if (i == n_seg - 1)
        return replace_value(L, text, value, NULL, node, item);
      node = item;
      i++;
    } else if (fy_node_is_mapping(node)) {
      int used = 0;
      struct fy_node_pair *p = lookup_segments(node, seg + i, n_seg - i, &used);
      if (!p) {
        int last = i == n_seg - 1;
        /* A list item below a missing key: the path does not exist. */
        if (!last && strspn(seg[i + 1], "0123456789") == strlen(seg[i + 1])) {
          path_prefix(where, sizeof where, seg, i + 2);
          path_prefix(parent, sizeof parent, seg, i);
          return set_error(L, text,
                           "the path '%s' does not exist (%s%shas no key '%s')",
                           where, parent, i ? " " : "the file ", seg[i]);
        }
        int st = add_key(L, text, node, seg[i], last ? value : NULL, &node);
        if (st || last)
          return st;
        i++;
        continue;
      }
      if (i + used == n_seg)
        return replace_value(L, text, value, p, NULL, fy_node_pair_value(p));
      node = fy_node_pair_value(p);
      i += used;
      if (is_null(node)) {
        /* `integrator:` with nothing below: make it a mapping. */
        struct fy_node *m = fy_node_create_mapping(L->doc);
        if (!m || fy_node_pair_set_value(p, m)) {
          fy_node_free(m);
          return fail_nomem(L);
        }
        L->splice_ok = 0;
        if (remember(L, m, text))
          return fail_nomem(L);
        node = m;
      }
    } else {
      path_prefix(where, sizeof where, seg, i + 1);
      path_prefix(parent, sizeof parent, seg, i);
      return set_error(L, text,
                       "no such key '%s' ('%s' is a value, not a mapping or "
                       "list)",
                       where, parent);
    }
  }
  return MRVI_OK;
}

/* Apply one override "dotted.key=value" to the document. */
static int apply_override(loader *L, const char *text) {
  const char *eq = strchr(text, '=');
  if (!eq || eq == text)
    return set_error(L, text, "expected KEY=VALUE");
  if (strlen(text) > MAX_TEXT)
    return set_error(L, "...", "longer than %zu MiB", MAX_TEXT >> 20);
  /* Split the key into segments: one copy, dots replaced by NULs. */
  size_t klen = (size_t)(eq - text);
  char *key = malloc(klen + 1);
  char **seg = malloc((klen + 1) * sizeof *seg);
  int st = MRVI_OK, n_seg = 0;
  if (!key || !seg) {
    free(key);
    free(seg);
    return fail_nomem(L);
  }
  memcpy(key, text, klen);
  key[klen] = '\0';
  seg[n_seg++] = key;
  for (char *c = key; *c; c++)
    if (*c == '.') {
      *c = '\0';
      seg[n_seg++] = c + 1;
    }
  for (int i = 0; i < n_seg && !st; i++)
    if (!*seg[i])
      st = set_error(L, text, "empty component in key path");
  if (!st)
    st = set_path(L, text, eq + 1, seg, n_seg);
  free(seg);
  free(key);
  return st;
}

/* ---------------------------------------------------------------------------
 * Interpretation: names
 * ------------------------------------------------------------------------- */

static size_t hash_name(const char *s) {
  size_t h = 1469598103934665603u;
  for (; *s; s++)
    h = (h ^ (unsigned char)*s) * 1099511628211u;
  return h;
}

/* Value stored for name, or -1. */
static int hash_find(const name_hash *h, const char *name) {
  if (!h->cap)
    return -1;
  for (size_t i = hash_name(name) & (h->cap - 1);; i = (i + 1) & (h->cap - 1))
    if (!h->val[i])
      return -1;
    else if (!strcmp(h->key[i], name))
      return h->val[i] - 1;
}

/* Add name -> value (name not present); MRVI_ENOMEM on failure. */
static int hash_put(name_hash *h, const char *name, int value) {
  if (2 * (h->n + 1) > h->cap) {
    name_hash g = {.cap = h->cap ? 2 * h->cap : 64};
    g.key = malloc(g.cap * sizeof *g.key);
    g.val = calloc(g.cap, sizeof *g.val);
    if (!g.key || !g.val) {
      free(g.key);
      free(g.val);
      return MRVI_ENOMEM;
    }
    for (size_t i = 0; i < h->cap; i++)
      if (h->val[i])
        hash_put(&g, h->key[i], h->val[i] - 1);
    free(h->key);
    free(h->val);
    *h = g;
  }
  size_t i = hash_name(name) & (h->cap - 1);
  while (h->val[i])
    i = (i + 1) & (h->cap - 1);
  h->key[i] = name;
  h->val[i] = value + 1;
  h->n++;
  return MRVI_OK;
}

static void hash_free(name_hash *h) {
  free(h->key);
  free(h->val);
}

static const named *find_named(const named *tab, const name_hash *h,
                               const char *name) {
  int i = hash_find(h, name);
  return i >= 0 ? &tab[i] : NULL;
}

/* Unknown name with a suggestion among the defined ones. */
static int fail_unknown_name(loader *L, struct fy_node *at, const char *kind,
                             const char *name, const named *tab, int n) {
  const char **cand = malloc((size_t)(n > 0 ? n : 1) * sizeof *cand);
  if (!cand)
    return fail_nomem(L);
  for (int i = 0; i < n; i++)
    cand[i] = tab[i].name;
  const char *c = mrvi_closest(name, cand, n);
  free(cand);
  if (c)
    return fail(L, at, "unknown %s '%s'; did you mean '%s'?", kind, name, c);
  return fail(L, at, "unknown %s '%s'", kind, name);
}

/* Name of a new coordinate or particle, rejecting duplicates. */
static int new_name(loader *L, struct fy_node *item, const char *where,
                    const char *kind, const named *tab, const name_hash *h,
                    struct fy_node **name_node, const char **name) {
  int st = need(L, item, "name", where, name_node);
  if (st || (st = as_string(L, *name_node, "name", name)))
    return st;
  const named *prev = find_named(tab, h, *name);
  int line, col;
  if (prev && node_position(prev->node, &line, &col))
    return fail(L, *name_node,
                "duplicate %s name '%s' (first defined at "
                "line %d)",
                kind, *name, line);
  if (prev)
    return fail(L, *name_node, "duplicate %s name '%s'", kind, *name);
  return MRVI_OK;
}

static int as_rate(loader *L, struct fy_node *map, const char *key,
                   mrvi_rate *out) {
  static const char *const rates[] = {"slow", "fast"};
  struct fy_node *n = get(map, key);
  int r = 0;
  if (n) {
    int st = as_choice(L, n, key, rates, 2, &r);
    if (st)
      return st;
  }
  *out = r ? MRVI_FAST : MRVI_SLOW;
  return MRVI_OK;
}

/* Optional number with a default. */
static int opt_number(loader *L, struct fy_node *map, const char *key,
                      double def, double *out) {
  struct fy_node *n = get(map, key);
  *out = def;
  return n ? as_number(L, n, key, out) : MRVI_OK;
}

/* Optional number > 0 under `key` (`what` in messages); *out is left alone
 * when the key is absent.  *node (may be NULL) gets the value's node. */
static int opt_positive(loader *L, struct fy_node *map, const char *key,
                        const char *what, double *out, struct fy_node **node) {
  struct fy_node *n = get(map, key);
  int st;
  if (node)
    *node = n;
  if (!n)
    return MRVI_OK;
  if ((st = as_number(L, n, what, out)))
    return st;
  if (!(*out > 0))
    return fail(L, n, "%s must be > 0, got %s", what, scalar0(n));
  return MRVI_OK;
}

/* ---------------------------------------------------------------------------
 * Interpretation: model
 * ------------------------------------------------------------------------- */

static const char *const top_keys[] = {
    "name",        "dimension", "gravity",     "particles",  "springs",
    "coordinates", "terms",     "constraints", "integrator", "output",
    "angles",      "forces",    "generate",
    "control" /* optimal control, read by src/ocp/ocp_loader.c */};
static const char *const coordinate_keys[] = {"name", "mass", "position",
                                              "velocity", "rate"};
static const char *const particle_keys[] = {"name", "mass", "position",
                                            "velocity", "rate"};
static const char *const spring_keys[] = {"between", "anchor", "law",
                                          "rest_length", "potential"};
static const char *const term_keys[] = {"combination", "offset", "law",
                                        "potential"};
static const char *const integrator_keys[] = {
    "scheme", "slow",   "fast",        "macro_step", "micro_steps",
    "t_end",  "newton", "constraints", "solver",     "energy_warning"};
static const char *const slow_rule_keys[] = {"alpha", "gamma", "grid"};
static const char *const fast_rule_keys[] = {"alpha", "gamma"};
static const char *const newton_keys[] = {"tolerance", "max_iterations"};
static const char *const constraint_setting_keys[] = {"form", "tolerance",
                                                      "projection"};
static const char *const output_keys[] = {
    "file", "every", "micro", "micro_slow", "xdmf", "flush_interval"};

static int load_coordinates(loader *L, struct fy_node *list) {
  int st = want_list(L, list, "coordinates");
  if (st)
    return st;
  int count = fy_node_sequence_item_count(list);
  L->coords = calloc((size_t)count + 1, sizeof *L->coords);
  if (!L->coords)
    return fail_nomem(L);
  void *it = NULL;
  struct fy_node *item, *nn, *v;
  for (int i = 0; (item = fy_node_sequence_iterate(list, &it)); i++) {
    char where[64];
    mrvi_fmt(where, sizeof where, "coordinates.%d", i);
    const char *name;
    double mass, q0, v0;
    mrvi_rate rate;
    if ((st = want_mapping(L, item, where)) ||
        (st = check_keys(L, item, where, coordinate_keys,
                         COUNT(coordinate_keys), NULL, 0)) ||
        (st = new_name(L, item, where, "coordinate", L->coords, &L->coord_hash,
                       &nn, &name)) ||
        (st = need(L, item, "mass", where, &v)) ||
        (st = as_number(L, v, "mass", &mass)))
      return st;
    if (mass <= 0)
      return fail(L, v, "mass must be > 0, got %s", scalar0(v));
    if ((st = need(L, item, "position", where, &v)) ||
        (st = as_number(L, v, "position", &q0)) ||
        (st = opt_number(L, item, "velocity", 0.0, &v0)) ||
        (st = as_rate(L, item, "rate", &rate)))
      return st;
    int idx =
        mrvi_model_add_coordinate(L->sys->model, name, mass, rate, q0, v0);
    if (idx < 0)
      return fail_model(L, item, idx);
    if (hash_put(&L->coord_hash, name, L->n_coords))
      return fail_nomem(L);
    L->coords[L->n_coords++] = (named){name, nn, idx};
  }
  return MRVI_OK;
}

static int load_particles(loader *L, struct fy_node *list, int dim) {
  int st = want_list(L, list, "particles");
  if (st)
    return st;
  int count = fy_node_sequence_item_count(list);
  L->parts = calloc((size_t)count + 1, sizeof *L->parts);
  if (!L->parts)
    return fail_nomem(L);
  void *it = NULL;
  struct fy_node *item, *nn, *v;
  for (int i = 0; (item = fy_node_sequence_iterate(list, &it)); i++) {
    char where[64];
    mrvi_fmt(where, sizeof where, "particles.%d", i);
    const char *name;
    double mass, x0[3] = {0, 0, 0}, v0[3] = {0, 0, 0};
    mrvi_rate rate;
    if ((st = want_mapping(L, item, where)) ||
        (st = check_keys(L, item, where, particle_keys, COUNT(particle_keys),
                         NULL, 0)) ||
        (st = new_name(L, item, where, "particle", L->parts, &L->part_hash, &nn,
                       &name)) ||
        (st = need(L, item, "mass", where, &v)) ||
        (st = as_number(L, v, "mass", &mass)))
      return st;
    if (mass <= 0)
      return fail(L, v, "mass must be > 0, got %s", scalar0(v));
    if ((st = need(L, item, "position", where, &v)) ||
        (st = as_vector(L, v, "position", dim, x0)))
      return st;
    if ((v = get(item, "velocity")) &&
        (st = as_vector(L, v, "velocity", dim, v0)))
      return st;
    if ((st = as_rate(L, item, "rate", &rate)))
      return st;
    int idx = mrvi_model_add_particle(L->sys->model, name, mass, rate, x0, v0);
    if (idx < 0)
      return fail_model(L, item, idx);
    if (hash_put(&L->part_hash, name, L->n_parts))
      return fail_nomem(L);
    L->parts[L->n_parts++] = (named){name, nn, idx};
  }
  return MRVI_OK;
}

/* The law named by `law:` of an element (NULL if the key is absent). */
static int find_law(loader *L, struct fy_node *item, const mrvi_law **law) {
  struct fy_node *n = get(item, "law");
  const char *name;
  int st;
  *law = NULL;
  if (!n)
    return MRVI_OK;
  if ((st = as_string(L, n, "law", &name)))
    return st;
  if ((*law = mrvi_law_find(name)))
    return MRVI_OK;
  const char *names[64];
  int count = mrvi_law_count() < 64 ? mrvi_law_count() : 64;
  for (int i = 0; i < count; i++)
    names[i] = mrvi_law_get(i)->name;
  char hint[512];
  suggest(hint, sizeof hint, name, names, count);
  return fail(L, n, "unknown law '%s'%s", name, hint);
}

/* Keys of an element: its own plus the law's parameters (of every law when
 * `law:` is missing, so that a misspelt `law` key is still found). */
static int check_element_keys(loader *L, struct fy_node *item,
                              const char *where, const char *const *keys,
                              int n_keys, const mrvi_law *law) {
  const char *params[MAX_KEYS];
  int n = 0;
  for (int i = 0; i < mrvi_law_count(); i++) {
    const mrvi_law *l = mrvi_law_get(i);
    if (law && l != law)
      continue;
    for (int j = 0; j < l->n_params && n + n_keys < MAX_KEYS; j++) {
      int dup = 0;
      for (int k = 0; k < n && !dup; k++)
        dup = !strcmp(params[k], l->param_names[j]);
      if (!dup)
        params[n++] = l->param_names[j];
    }
  }
  return check_keys(L, item, where, keys, n_keys, params, n);
}

/* Law and parameters of an element (the law's parameter names are keys). */
static int load_law(loader *L, struct fy_node *item, const char *where,
                    const char *const *keys, int n_keys, const mrvi_law **law,
                    double *params) {
  struct fy_node *n;
  int st;
  if ((st = find_law(L, item, law)) ||
      (st = check_element_keys(L, item, where, keys, n_keys, *law)) ||
      (st = need(L, item, "law", where, &n)))
    return st;
  for (int i = 0; i < (*law)->n_params; i++) {
    const char *pname = (*law)->param_names[i];
    struct fy_node_pair *p = find_pair(item, pname);
    if (!p)
      return fail(L, item, "missing key '%s' in %s (parameter of law '%s')",
                  pname, where, (*law)->name);
    if ((st = need(L, item, pname, where, &n)) ||
        (st = as_number(L, n, pname, &params[i])))
      return st;
  }
  return MRVI_OK;
}

/* Particle named by the string node n. */
static int find_particle(loader *L, struct fy_node *n, const char *what,
                         int *index) {
  const char *pname;
  int st = as_string(L, n, what, &pname);
  if (st)
    return st;
  const named *p = find_named(L->parts, &L->part_hash, pname);
  if (!p)
    return fail_unknown_name(L, n, "particle", pname, L->parts, L->n_parts);
  *index = p->index;
  return MRVI_OK;
}

/* Model coordinate named by the string node n (coordinates and particle
 * coordinates such as m1.x). */
static int find_coordinate(loader *L, struct fy_node *n, const char *what,
                           int *index) {
  const mrvi_model *m = L->sys->model;
  const int count = mrvi_model_n(m);
  const char *cname;
  int st = as_string(L, n, what, &cname);
  if (st)
    return st;
  for (int j = (int)L->model_hash.n; j < count; j++) /* new since last */
    if (hash_put(&L->model_hash, mrvi_model_coordinate_name(m, j), j))
      return fail_nomem(L);
  if ((*index = hash_find(&L->model_hash, cname)) >= 0)
    return MRVI_OK;
  const char **names = malloc((size_t)(count + 1) * sizeof *names);
  if (!names)
    return fail_nomem(L);
  for (int j = 0; j < count; j++)
    names[j] = mrvi_model_coordinate_name(m, j);
  const char *c = mrvi_closest(cname, names, count);
  st = c ? fail(L, n, "unknown coordinate '%s'; did you mean '%s'?", cname, c)
         : fail(L, n, "unknown coordinate '%s'", cname);
  free(names);
  return st;
}

/* `combination: {coordinate name: coefficient, ...}` (non-empty) into
 * coords, coef (mrvi_model_n entries each); *k gets the number of terms. */
static int load_combination(loader *L, struct fy_node *comb, int *coords,
                            double *coef, int *k) {
  int st = want_mapping(L, comb, "combination");
  void *it = NULL;
  struct fy_node_pair *p;
  *k = 0;
  while (!st && (p = fy_node_mapping_iterate(comb, &it))) {
    struct fy_node *key = fy_node_pair_key(p);
    char what[128];
    if ((st = find_coordinate(L, key, "coordinate name", &coords[*k])))
      break;
    mrvi_fmt(what, sizeof what, "coefficient of %s", scalar0(key));
    if ((st = as_number(L, fy_node_pair_value(p), what, &coef[*k])))
      break;
    (*k)++;
  }
  if (!st && *k == 0)
    st = fail(L, comb, "combination is empty");
  return st;
}

/* Ends of a spring or distance constraint (`noun` in messages):
 * `between: [a, b]`, or `between: [a]` with `anchor:` (dim entries).
 * *ends is 1 or 2; pi gets the particle indices. */
static int load_ends(loader *L, struct fy_node *item, const char *where,
                     const char *noun, int dim, int pi[2], int *ends,
                     double *anchor) {
  struct fy_node *between, *anchor_node;
  int st;
  if ((st = need(L, item, "between", where, &between)) ||
      (st = want_list(L, between, "between")))
    return st;
  *ends = fy_node_sequence_item_count(between);
  if (*ends != 1 && *ends != 2)
    return fail(L, between,
                "between must name one particle (with "
                "anchor) or two, got %d",
                *ends);
  for (int e = 0; e < *ends; e++)
    if ((st = find_particle(L, fy_node_sequence_get_by_index(between, e),
                            "between", &pi[e])))
      return st;
  anchor_node = get(item, "anchor");
  if (*ends == 2 && anchor_node)
    return fail(L, anchor_node, "anchor given for a %s between two particles",
                noun);
  if (*ends == 1 && !anchor_node)
    return fail(L, between, "a %s on one particle needs an anchor", noun);
  if (anchor_node)
    return as_vector(L, anchor_node, "anchor", dim, anchor);
  return MRVI_OK;
}

/* `rest_length:` of a spring: a number, `initial` (the initial distance)
 * or absent (0). */
static int spring_rest(loader *L, struct fy_node *item, const int pi[2],
                       int ends, const double *anchor, double *rest) {
  struct fy_node *n = get(item, "rest_length");
  *rest = 0.0;
  if (n && fy_node_is_scalar(n) && !strcmp(scalar0(n), "initial")) {
    *rest = mrvi_model_initial_distance(L->sys->model, pi[0],
                                        ends == 2 ? pi[1] : -1, anchor);
    return MRVI_OK;
  }
  return n ? as_number(L, n, "rest_length (a number or 'initial')", rest)
           : MRVI_OK;
}

static int load_springs(loader *L, struct fy_node *list, int dim) {
  int st = want_list(L, list, "springs");
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
    mrvi_rate potential;
    if ((st = want_mapping(L, item, where)) ||
        (st = load_law(L, item, where, spring_keys, COUNT(spring_keys), &law,
                       params)) ||
        (st = load_ends(L, item, where, "spring", dim, pi, &ends, anchor)) ||
        (st = spring_rest(L, item, pi, ends, anchor, &rest)) ||
        (st = as_rate(L, item, "potential", &potential)))
      return st;
    int e = ends == 2
                ? mrvi_model_add_spring(L->sys->model, potential, pi[0], pi[1],
                                        law->name, params, rest)
                : mrvi_model_add_anchor_spring(L->sys->model, potential, pi[0],
                                               anchor, law->name, params, rest);
    if (e < 0)
      return fail_model(L, item, e);
  }
  return MRVI_OK;
}

static int load_terms(loader *L, struct fy_node *list) {
  int st = want_list(L, list, "terms");
  if (st)
    return st;
  int n = mrvi_model_n(L->sys->model);
  int *coords = malloc((size_t)(n + 1) * sizeof *coords);
  double *coef = malloc((size_t)(n + 1) * sizeof *coef);
  if (!coords || !coef) {
    st = fail_nomem(L);
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
    if ((st = want_mapping(L, item, where)) ||
        (st = load_law(L, item, where, term_keys, COUNT(term_keys), &law,
                       params)) ||
        (st = need(L, item, "combination", where, &comb)) ||
        (st = load_combination(L, comb, coords, coef, &k)) ||
        (st = opt_number(L, item, "offset", 0.0, &offset)) ||
        (st = as_rate(L, item, "potential", &potential)))
      break;
    int e = mrvi_model_add_term(L->sys->model, potential, k, coords, coef,
                                offset, law->name, params);
    if (e < 0)
      st = fail_model(L, item, e);
  }
done:
  free(coords);
  free(coef);
  return st;
}

/* ---------------------------------------------------------------------------
 * Interpretation: constraints (doc/constraints.md)
 *
 * Each entry adds one model constraint; its loader returns the constraint
 * index (>= 0) or a status < 0.
 * ------------------------------------------------------------------------- */

/* {type: distance, between: [a, b] | [a] + anchor, length} */
static int load_distance(loader *L, struct fy_node *item, const char *where,
                         int dim) {
  double anchor[3] = {0, 0, 0}, length = NAN; /* NAN: initial distance */
  int pi[2], ends, st;
  if ((st = load_ends(L, item, where, "distance constraint", dim, pi, &ends,
                      anchor)) ||
      (st = opt_positive(L, item, "length", "length", &length, NULL)))
    return st;
  int c = ends == 2
              ? mrvi_model_add_distance(L->sys->model, pi[0], pi[1], length)
              : mrvi_model_add_distance_anchor(L->sys->model, pi[0], anchor,
                                               length);
  return c < 0 ? fail_model(L, get(item, "between"), c) : c;
}

/* {type: fixed, particle: a, axes: [x, z], position: [...]} */
static int load_fixed(loader *L, struct fy_node *item, const char *where,
                      int dim) {
  static const char *const axis_names[] = {"x", "y", "z"};
  struct fy_node *n, *axes_node = get(item, "axes");
  double position[3] = {0, 0, 0};
  int axes[3] = {0, 0, 0}, p, st;
  if ((st = need(L, item, "particle", where, &n)) ||
      (st = find_particle(L, n, "particle", &p)))
    return st;
  if (axes_node) {
    if ((st = want_list(L, axes_node, "axes")))
      return st;
    const int count = fy_node_sequence_item_count(axes_node);
    if (count == 0)
      return fail(L, axes_node, "axes is empty (omit it to pin every axis)");
    for (int i = 0; i < count; i++) {
      struct fy_node *a = fy_node_sequence_get_by_index(axes_node, i);
      int which;
      for (int k = dim; k < 3; k++)
        if (fy_node_is_scalar(a) && !strcmp(scalar0(a), axis_names[k]))
          return fail(L, a, "axis '%s' does not exist in %d-D", axis_names[k],
                      dim);
      if ((st = as_choice(L, a, "axis", axis_names, dim, &which)))
        return st;
      if (axes[which])
        return fail(L, a, "axis '%s' listed twice", axis_names[which]);
      axes[which] = 1;
    }
  }
  if ((n = get(item, "position")) &&
      (st = as_vector(L, n, "position", dim, position)))
    return st;
  int c = mrvi_model_add_fixed(L->sys->model, p, axes_node ? axes : NULL,
                               n ? position : NULL);
  return c < 0 ? fail_model(L, item, c) : c;
}

/* {type: plane, particle: a, normal: [...], offset: c} */
static int load_plane(loader *L, struct fy_node *item, const char *where,
                      int dim) {
  struct fy_node *n, *normal_node;
  double normal[3] = {0, 0, 0}, offset;
  int p, st;
  if ((st = need(L, item, "particle", where, &n)) ||
      (st = find_particle(L, n, "particle", &p)) ||
      (st = need(L, item, "normal", where, &normal_node)) ||
      (st = as_vector(L, normal_node, "normal", dim, normal)) ||
      (st = opt_number(L, item, "offset", NAN, &offset)))
    return st;
  int c = mrvi_model_add_plane(L->sys->model, p, normal, offset);
  return c < 0 ? fail_model(L, normal_node, c) : c;
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
    st = fail_nomem(L);
  else if (!(st = need(L, item, "combination", where, &comb)) &&
           !(st = load_combination(L, comb, coords, coef, &k)) &&
           !(st = opt_number(L, item, "value", NAN, &value))) {
    st =
        mrvi_model_add_linear_constraint(L->sys->model, k, coords, coef, value);
    if (st < 0)
      st = fail_model(L, comb, st);
  }
  free(coords);
  free(coef);
  return st;
}

/* A registered type without its own syntax:
 * {type: NAME, coordinates: [names...], parameters: [numbers...]} */
static int load_generic(loader *L, struct fy_node *item, const char *where,
                        const char *type, const char *label) {
  struct fy_node *list, *par = get(item, "parameters");
  int st;
  if ((st = need(L, item, "coordinates", where, &list)) ||
      (st = want_list(L, list, "coordinates")) ||
      (par && (st = want_list(L, par, "parameters"))))
    return st;
  const int n_in = fy_node_sequence_item_count(list);
  const int n_par = par ? fy_node_sequence_item_count(par) : 0;
  if (n_in == 0)
    return fail(L, list, "coordinates is empty");
  int *coords = malloc((size_t)n_in * sizeof *coords);
  double *params = malloc((size_t)(n_par + 1) * sizeof *params);
  if (!coords || !params)
    st = fail_nomem(L);
  for (int j = 0; j < n_in && !st; j++)
    st = find_coordinate(L, fy_node_sequence_get_by_index(list, j),
                         "coordinates", &coords[j]);
  for (int j = 0; j < n_par && !st; j++) {
    char what[64];
    mrvi_fmt(what, sizeof what, "parameters[%d]", j);
    st = as_number(L, fy_node_sequence_get_by_index(par, j), what, &params[j]);
  }
  if (!st) {
    st = mrvi_model_add_constraint(L->sys->model, type, n_in, coords, n_par,
                                   params, label);
    if (st < 0)
      st = fail_model(L, item, st);
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
  struct fy_node *n = get(item, "name");
  const char *label = mrvi_model_constraint_label(m, c);
  char buf[600];
  int st;
  if (n && (st = as_string(L, n, "name", &label)))
    return st;
  for (int prev = 0; prev < c; prev++) {
    if (strcmp(label, mrvi_model_constraint_label(m, prev)))
      continue;
    int line, col;
    if (n && node_position(L->constraint_items[prev], &line, &col))
      return fail(L, n,
                  "duplicate constraint name '%s' (constraint at line %d)",
                  label, line);
    if (n)
      return fail(L, n, "duplicate constraint name '%s'", label);
    mrvi_fmt(buf, sizeof buf, "%s (%s)", label, where);
    label = buf;
    break;
  }
  if (label == mrvi_model_constraint_label(m, c))
    return MRVI_OK;
  /* The builders take no label: replace the one they made. */
  if (mrvi_model_set_constraint_label(m, c, label) < 0)
    return fail_nomem(L);
  return MRVI_OK;
}

static int load_constraint(loader *L, struct fy_node *item, int i, int dim) {
  const char *keys[MAX_KEYS], *type_names[64];
  char where[64];
  struct fy_node *type_node;
  int st, which;
  mrvi_fmt(where, sizeof where, "constraints.%d", i);
  if ((st = want_mapping(L, item, where)))
    return st;
  if (!get(item, "type") &&
      (st = check_keys(L, item, where, keys, all_constraint_keys(keys), NULL,
                       0)))
    return st;
  const int n_types =
      mrvi_constraint_type_count() < 64 ? mrvi_constraint_type_count() : 64;
  for (int t = 0; t < n_types; t++)
    type_names[t] = mrvi_constraint_type_get(t)->name;
  if ((st = need(L, item, "type", where, &type_node)) ||
      (st = as_choice(L, type_node, "constraint type", type_names, n_types,
                      &which)))
    return st;
  const constraint_syntax *s = constraint_syntaxes;
  while (s->type && strcmp(s->type, type_names[which]))
    s++;
  if ((st = check_keys(L, item, where, keys, syntax_keys(s, keys), NULL, 0)))
    return st;
  const int c = s->load ? s->load(L, item, where, dim)
                        : load_generic(L, item, where, type_names[which], NULL);
  if (c < 0)
    return c;
  L->constraint_items[c] = item;
  return label_constraint(L, item, where, c);
}

static int load_constraints(loader *L, struct fy_node *list, int dim) {
  int st = want_list(L, list, "constraints");
  if (st)
    return st;
  const int count = fy_node_sequence_item_count(list);
  L->constraint_list = list;
  L->constraint_items = calloc((size_t)count + 1, sizeof *L->constraint_items);
  if (!L->constraint_items)
    return fail_nomem(L);
  void *it = NULL;
  struct fy_node *item;
  for (int i = 0; !st && (item = fy_node_sequence_iterate(list, &it)); i++)
    st = load_constraint(L, item, i, dim);
  return st;
}

/* Append a line to sys->notes. */
__attribute__((format(printf, 2, 3))) static int
add_note(loader *L, const char *fmt, ...) {
  char text[512];
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(text, sizeof text, fmt, ap);
  va_end(ap);
  char *old = L->sys->notes;
  const size_t len = (old ? strlen(old) + 1 : 0) + strlen(text) + 1;
  char *notes = malloc(len);
  if (!notes)
    return fail_nomem(L);
  mrvi_fmt(notes, len, "%s%s%s", old ? old : "", old ? "\n" : "", text);
  free(old);
  L->sys->notes = notes;
  return MRVI_OK;
}

/* Initial data against the constraints (doc/constraints.md), once the settings
 * are known: positions within the tolerance, independent gradients, velocities
 * projected onto the tangent space (with a note when they changed). */
static int check_constraints(loader *L) {
  mrvi_model *m = L->sys->model;
  const int n_c = mrvi_model_n_constraints(m);
  int worst = -1, st;
  if (n_c == 0)
    return MRVI_OK;
  st = mrvi_model_check_initial_positions(m, L->sys->settings.constraint_tol,
                                          &worst);
  if (st < 0)
    return st == MRVI_ENOMEM ? fail_nomem(L)
                             : fail(L,
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
    return st == MRVI_ENOMEM ? fail_nomem(L) : fail(L, at, "%s", msg);
  }
  double correction = 0.0;
  if ((st = mrvi_model_project_velocities(m, &correction)) < 0)
    return st == MRVI_ENOMEM
               ? fail_nomem(L)
               : fail(L, L->constraint_list, "%s", mrvi_model_errmsg(m));
  if (correction > 0)
    return add_note(L,
                    "initial velocities projected onto the constraints' "
                    "tangent space (largest change %.1e)",
                    correction);
  return MRVI_OK;
}

/* ---------------------------------------------------------------------------
 * Interpretation: angles, constant forces, generators
 * ------------------------------------------------------------------------- */
static const char *const angle_keys[] = {"particles", "stiffness", "rest_angle",
                                         "potential"};
static const char *const force_keys[] = {"particle", "coordinate", "force",
                                         "potential"};
static const char *const generate_keys[] = {
    "kind",  "name",   "count",       "spacing",     "origin", "mass",
    "rates", "spring", "slow_spring", "fast_spring", "initial"};
static const char *const generated_spring_keys[] = {"law", "rest_length"};
static const char *const initial_keys[] = {"index", "displacement", "velocity"};

/* {particles: [i, j, k], stiffness, rest_angle (radians, default initial),
 *  potential} */
static int load_angles(loader *L, struct fy_node *list) {
  int st = want_list(L, list, "angles");
  int count = st ? 0 : fy_node_sequence_item_count(list);
  for (int i = 0; i < count && !st; i++) {
    struct fy_node *item = fy_node_sequence_get_by_index(list, i), *ps, *n;
    char where[64];
    mrvi_fmt(where, sizeof where, "angles.%d", i);
    int pi[3];
    double k, rest = NAN;
    mrvi_rate potential;
    if ((st = want_mapping(L, item, where)) ||
        (st = check_keys(L, item, where, angle_keys, COUNT(angle_keys), NULL,
                         0)) ||
        (st = need(L, item, "particles", where, &ps)) ||
        (st = want_list(L, ps, "particles")))
      break;
    if (fy_node_sequence_item_count(ps) != 3) {
      st = fail(L, ps,
                "particles of an angle must be [i, j, k] (vertex j), "
                "got %d names",
                fy_node_sequence_item_count(ps));
      break;
    }
    for (int a = 0; a < 3 && !st; a++)
      st = find_particle(L, fy_node_sequence_get_by_index(ps, a), "particles",
                         &pi[a]);
    if (st || (st = need(L, item, "stiffness", where, &n)) ||
        (st = as_number(L, n, "stiffness", &k)) ||
        (st = as_rate(L, item, "potential", &potential)))
      break;
    if ((n = get(item, "rest_angle")) &&
        !(fy_node_is_scalar(n) && !strcmp(scalar0(n), "initial")) &&
        (st = as_number(L, n, "rest_angle (radians or 'initial')", &rest)))
      break;
    int e = mrvi_model_add_angle(L->sys->model, potential, pi[0], pi[1], pi[2],
                                 k, rest);
    if (e < 0)
      st = fail_model(L, item, e);
  }
  return st;
}

/* {particle: a, force: [fx, fy, fz]} or {coordinate: q, force: f}, with
 * potential slow (default) or fast. */
static int load_forces(loader *L, struct fy_node *list, int dim) {
  int st = want_list(L, list, "forces");
  int count = st ? 0 : fy_node_sequence_item_count(list);
  for (int i = 0; i < count && !st; i++) {
    struct fy_node *item = fy_node_sequence_get_by_index(list, i), *n, *f;
    char where[64];
    mrvi_fmt(where, sizeof where, "forces.%d", i);
    int coords[3], k = 1;
    double force[3] = {0, 0, 0};
    mrvi_rate potential;
    if ((st = want_mapping(L, item, where)) ||
        (st = check_keys(L, item, where, force_keys, COUNT(force_keys), NULL,
                         0)) ||
        (st = need(L, item, "force", where, &f)) ||
        (st = as_rate(L, item, "potential", &potential)))
      break;
    struct fy_node *pn = get(item, "particle"), *cn = get(item, "coordinate");
    if (!pn == !cn) {
      st = fail(L, item, "%s needs exactly one of 'particle' or 'coordinate'",
                where);
      break;
    }
    if (pn) {
      int p;
      if ((st = find_particle(L, pn, "particle", &p)) ||
          (st = as_vector(L, f, "force", dim, force)))
        break;
      const int first = L->sys->model->particles[p].first;
      for (int a = 0; a < dim; a++)
        coords[a] = first + a;
      k = dim;
    } else if ((st = find_coordinate(L, cn, "coordinate", &coords[0])) ||
               (st = as_number(L, f, "force", &force[0]))) {
      break;
    }
    (void)n;
    int e = mrvi_model_add_force(L->sys->model, potential, k, coords, force);
    if (e < 0)
      st = fail_model(L, item, e);
  }
  return st;
}

/* A generated particle becomes a name the rest of the file can use. */
static int add_generated_name(loader *L, struct fy_node *at, int p) {
  named *np = realloc(L->parts, (size_t)(L->n_parts + 2) * sizeof *np);
  if (!np)
    return fail_nomem(L);
  L->parts = np;
  const char *name = L->sys->model->particles[p].name;
  if (find_named(L->parts, &L->part_hash, name))
    return fail(L, at, "generated particle name '%s' is already used", name);
  if (hash_put(&L->part_hash, name, L->n_parts))
    return fail_nomem(L);
  L->parts[L->n_parts++] = (named){name, at, p};
  return MRVI_OK;
}

/* `spring:` / `slow_spring:` / `fast_spring:` of a generator. */
static int load_spring_spec(loader *L, struct fy_node *n, const char *where,
                            mrvi_spring_spec *sp) {
  const mrvi_law *law;
  struct fy_node *r;
  int st;
  sp->rest_length = NAN;
  if ((st = want_mapping(L, n, where)) ||
      (st = load_law(L, n, where, generated_spring_keys,
                     COUNT(generated_spring_keys), &law, sp->params)))
    return st;
  sp->law = law->name;
  if ((r = get(n, "rest_length")))
    return as_number(L, r, "rest_length", &sp->rest_length);
  return MRVI_OK;
}

/* `rates:` all_slow | all_fast | alternate | {every: k} */
static int load_rate_rule(loader *L, struct fy_node *n, mrvi_generator *g) {
  static const char *const rules[] = {"all_slow", "all_fast", "alternate"};
  int r = 0, st;
  if (fy_node_is_mapping(n)) {
    struct fy_node *e;
    static const char *const every_keys[] = {"every"};
    if ((st = check_keys(L, n, "rates", every_keys, 1, NULL, 0)) ||
        (st = need(L, n, "every", "rates", &e)) ||
        (st = as_int(L, e, "every", &g->every)))
      return st;
    if (g->every < 1)
      return fail(L, e, "every must be >= 1, got %d", g->every);
    g->rates = MRVI_RATES_EVERY;
    return MRVI_OK;
  }
  if ((st = as_choice(L, n, "rates (or {every: k})", rules, 3, &r)))
    return st;
  g->rates = (mrvi_rate_rule)r;
  return MRVI_OK;
}

/* `initial:` list of {index: i | [i, j(, k)], displacement, velocity}. */
static int load_generated_initial(loader *L, struct fy_node *list,
                                  const mrvi_generator *g, long total, int dim,
                                  double *disp, double *vel) {
  int st = want_list(L, list, "initial");
  int count = st ? 0 : fy_node_sequence_item_count(list);
  const int axes = g->kind == MRVI_GEN_LATTICE3D   ? 3
                   : g->kind == MRVI_GEN_LATTICE2D ? 2
                                                   : 1;
  for (int i = 0; i < count && !st; i++) {
    struct fy_node *item = fy_node_sequence_get_by_index(list, i), *in, *n;
    char where[64];
    mrvi_fmt(where, sizeof where, "initial.%d", i);
    double idx[3] = {0, 0, 0};
    if ((st = want_mapping(L, item, where)) ||
        (st = check_keys(L, item, where, initial_keys, COUNT(initial_keys),
                         NULL, 0)) ||
        (st = need(L, item, "index", where, &in)) ||
        (st = as_vector(L, in, "index", axes, idx)))
      break;
    long lin = 0, stride = 1;
    for (int a = 0; a < axes; a++) {
      const int na = g->count[a];
      if (idx[a] != floor(idx[a]) || idx[a] < 0 || idx[a] >= na) {
        st = fail(L, in, "index %g is outside 0..%d", idx[a], na - 1);
        break;
      }
      lin += (long)idx[a] * stride;
      stride *= na;
    }
    if (st || lin >= total)
      break;
    if ((n = get(item, "displacement")) &&
        (st = as_vector(L, n, "displacement", dim, disp + lin * dim)))
      break;
    if ((n = get(item, "velocity")) &&
        (st = as_vector(L, n, "velocity", dim, vel + lin * dim)))
      break;
  }
  return st;
}

/* One `generate:` entry; notes its counts for `mrvi check`. */
static int load_generator(loader *L, struct fy_node *item, const char *where,
                          int dim) {
  static const char *const kinds[] = {"chain", "ring", "lattice2d",
                                      "lattice3d"};
  mrvi_generator g = {.spacing = 1.0, .every = 1};
  struct fy_node *n;
  int st, kind = 0;
  if ((st = want_mapping(L, item, where)) ||
      (st = check_keys(L, item, where, generate_keys, COUNT(generate_keys),
                       NULL, 0)) ||
      (st = need(L, item, "kind", where, &n)) ||
      (st = as_choice(L, n, "generator kind", kinds, 4, &kind)) ||
      (st = need(L, item, "name", where, &n)) ||
      (st = as_string(L, n, "name", &g.prefix)) ||
      (st = need(L, item, "mass", where, &n)) ||
      (st = as_number(L, n, "mass", &g.mass)))
    return st;
  if (!(g.mass > 0))
    return fail(L, n, "mass must be > 0, got %s", scalar0(n));
  g.kind = (mrvi_generator_kind)kind;
  const int axes = kind == MRVI_GEN_LATTICE3D   ? 3
                   : kind == MRVI_GEN_LATTICE2D ? 2
                                                : 1;
  if ((st = need(L, item, "count", where, &n)))
    return st;
  if (axes <= 1) {
    if ((st = as_int(L, n, "count", &g.count[0])))
      return st;
  } else {
    double c[3];
    if ((st = as_vector(L, n, "count", axes, c)))
      return st;
    for (int a = 0; a < axes; a++)
      if (c[a] != floor(c[a]) || c[a] < 1 || c[a] > 1e6)
        return fail(L, n, "count entries must be integers >= 1");
    for (int a = 0; a < axes; a++)
      g.count[a] = (int)c[a];
  }
  char msg[256];
  const long total = mrvi_generator_particles(&g, msg, sizeof msg);
  if (total < 0)
    return fail(L, n, "%s", msg);
  if ((st = opt_positive(L, item, "spacing", "spacing", &g.spacing, NULL)))
    return st;
  if ((n = get(item, "origin")) &&
      (st = as_vector(L, n, "origin", dim, g.origin)))
    return st;
  if ((n = get(item, "rates")) && (st = load_rate_rule(L, n, &g)))
    return st;
  if ((n = get(item, "spring"))) {
    if ((st = load_spring_spec(L, n, "spring", &g.slow)))
      return st;
    g.fast = g.slow;
  }
  if ((n = get(item, "slow_spring")) &&
      (st = load_spring_spec(L, n, "slow_spring", &g.slow)))
    return st;
  if ((n = get(item, "fast_spring")) &&
      (st = load_spring_spec(L, n, "fast_spring", &g.fast)))
    return st;
  double *disp = NULL, *vel = NULL;
  if ((n = get(item, "initial"))) {
    disp = calloc((size_t)total * (size_t)dim, sizeof *disp);
    vel = calloc((size_t)total * (size_t)dim, sizeof *vel);
    if (!disp || !vel)
      st = fail_nomem(L);
    else
      st = load_generated_initial(L, n, &g, total, dim, disp, vel);
    g.displacement = disp;
    g.velocity = vel;
  }
  int counts[4] = {0, 0, 0, 0};
  int first = st ? 0 : mrvi_model_generate(L->sys->model, &g, counts);
  free(disp);
  free(vel);
  if (st)
    return st;
  if (first < 0)
    return fail_model(L, item, first);
  for (long p = 0; p < total && !st; p++)
    st = add_generated_name(L, item, first + (int)p);
  if (st)
    return st;
  return add_note(L,
                  "%s: %s '%s' generated %d particles (%d slow, %d fast), "
                  "%d springs (%d slow, %d fast)",
                  where, kinds[kind], g.prefix, counts[0], counts[1],
                  counts[0] - counts[1], counts[2] + counts[3], counts[2],
                  counts[3]);
}

static int load_generators(loader *L, struct fy_node *list, int dim) {
  int st = want_list(L, list, "generate");
  int count = st ? 0 : fy_node_sequence_item_count(list);
  for (int i = 0; i < count && !st; i++) {
    char where[64];
    mrvi_fmt(where, sizeof where, "generate.%d", i);
    st = load_generator(L, fy_node_sequence_get_by_index(list, i), where, dim);
  }
  return st;
}

static int load_model(loader *L, struct fy_node *root) {
  mrvi_model *m = L->sys->model;
  struct fy_node *n, *particles = get(root, "particles");
  struct fy_node *gravity = get(root, "gravity");
  int st, dim = 0;
  if ((st = mrvi_model_set_name(m, L->sys->name)))
    return fail_model(L, get(root, "name"), st);
  if ((n = get(root, "dimension"))) {
    if ((st = as_int(L, n, "dimension", &dim)))
      return st;
    if (dim < 1 || dim > 3)
      return fail(L, n, "dimension must be 1, 2 or 3, got %d", dim);
    if ((st = mrvi_model_set_dimension(m, dim)))
      return fail_model(L, n, st);
  } else if (particles || gravity || get(root, "generate")) {
    return fail(L, root, "missing key 'dimension' (needed by %s)",
                particles ? "particles"
                : gravity ? "gravity"
                          : "generate");
  }
  /* Model order: coordinates first, then particles as declared (names by
   * hash, the partition extended by each add: linear in the file). */
  if ((n = get(root, "coordinates")) && (st = load_coordinates(L, n)))
    return st;
  if (particles && (st = load_particles(L, particles, dim)))
    return st;
  if ((n = get(root, "generate")) && (st = load_generators(L, n, dim)))
    return st;
  if (mrvi_model_n(m) == 0)
    return fail(L, root,
                "the system has no coordinates: add 'coordinates' "
                "or 'particles'");
  if (gravity) {
    double g[3] = {0, 0, 0};
    if ((st = as_vector(L, gravity, "gravity", dim, g)))
      return st;
    if ((st = mrvi_model_set_gravity(m, g)))
      return fail_model(L, gravity, st);
  }
  if ((n = get(root, "springs")) && (st = load_springs(L, n, dim)))
    return st;
  if ((n = get(root, "terms")) && (st = load_terms(L, n)))
    return st;
  if ((n = get(root, "angles")) && (st = load_angles(L, n)))
    return st;
  if ((n = get(root, "forces")) && (st = load_forces(L, n, dim)))
    return st;
  if ((n = get(root, "constraints")) && (st = load_constraints(L, n, dim)))
    return st;
  return MRVI_OK;
}

/* ---------------------------------------------------------------------------
 * Interpretation: integrator settings and output
 * ------------------------------------------------------------------------- */

/* alpha and gamma of one rule, each in [0, 1]. */
static int load_rule(loader *L, struct fy_node *map, const char *where,
                     mrvi_rule *r) {
  static const char *const keys[] = {"alpha", "gamma"};
  double *val[] = {&r->alpha, &r->gamma};
  for (int i = 0; i < 2; i++) {
    struct fy_node *n = get(map, keys[i]);
    char what[64];
    mrvi_fmt(what, sizeof what, "%s.%s", where, keys[i]);
    if (!n)
      continue;
    int st = as_number(L, n, what, val[i]);
    if (st)
      return st;
    if (*val[i] < 0 || *val[i] > 1)
      return fail(L, n, "%s must be in [0, 1], got %s", what, scalar0(n));
  }
  return MRVI_OK;
}

/* integrator.constraints: {form, tolerance, projection} (doc/constraints.md).
 */
static int load_constraint_settings(loader *L, struct fy_node *map) {
  static const char *const forms[] = {"multipliers", "null-space"};
  mrvi_settings *s = &L->sys->settings;
  struct fy_node *v;
  int st, form;
  if ((st = want_mapping(L, map, "integrator.constraints")) ||
      (st =
           check_keys(L, map, "integrator.constraints", constraint_setting_keys,
                      COUNT(constraint_setting_keys), NULL, 0)))
    return st;
  if ((v = get(map, "form"))) {
    if ((st = as_choice(L, v, "constraint form", forms, 2, &form)))
      return st;
    s->constraint_form = form ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
  }
  if ((st = opt_positive(L, map, "tolerance", "constraint tolerance",
                         &s->constraint_tol, NULL)))
    return st;
  if ((v = get(map, "projection")))
    return as_bool(L, v, "projection", &s->project_momenta);
  return MRVI_OK;
}

static int load_integrator(loader *L, struct fy_node *in) {
  mrvi_settings *s = &L->sys->settings;
  struct fy_node *n, *dT_node, *t_node;
  int st;
  if ((st = want_mapping(L, in, "integrator")) ||
      (st = check_keys(L, in, "integrator", integrator_keys,
                       COUNT(integrator_keys), NULL, 0)))
    return st;
  /* The scheme sets both rules; slow/fast then override parts of them. */
  if ((n = get(in, "scheme"))) {
    const char *const *names = mrvi_scheme_names();
    int count = 0, which;
    while (names[count])
      count++;
    if ((st = as_choice(L, n, "scheme", names, count, &which)))
      return st;
    if ((st = mrvi_settings_set_scheme(s, names[which])))
      return fail(L, n, "cannot set scheme '%s'", names[which]);
  }
  if ((n = get(in, "slow"))) {
    static const char *const grids[] = {"micro", "macro"};
    struct fy_node *g;
    int grid;
    if ((st = want_mapping(L, n, "integrator.slow")) ||
        (st = check_keys(L, n, "integrator.slow", slow_rule_keys,
                         COUNT(slow_rule_keys), NULL, 0)) ||
        (st = load_rule(L, n, "integrator.slow", &s->slow)))
      return st;
    if ((g = get(n, "grid"))) {
      if ((st = as_choice(L, g, "grid", grids, 2, &grid)))
        return st;
      s->slow_grid = grid ? MRVI_GRID_MACRO : MRVI_GRID_MICRO;
    }
  }
  if ((n = get(in, "fast")) &&
      ((st = want_mapping(L, n, "integrator.fast")) ||
       (st = check_keys(L, n, "integrator.fast", fast_rule_keys,
                        COUNT(fast_rule_keys), NULL, 0)) ||
       (st = load_rule(L, n, "integrator.fast", &s->fast))))
    return st;
  if ((st = opt_positive(L, in, "macro_step", "macro_step", &s->macro_step,
                         &dT_node)))
    return st;
  if ((n = get(in, "micro_steps"))) {
    if ((st = as_int(L, n, "micro_steps", &s->micro_steps)))
      return st;
    if (s->micro_steps < 1)
      return fail(L, n, "micro_steps must be >= 1, got %d", s->micro_steps);
  }
  if ((t_node = get(in, "t_end")) &&
      (st = as_number(L, t_node, "t_end", &s->t_end)))
    return st;
  if (s->t_end < s->macro_step)
    return fail(L, t_node ? t_node : dT_node,
                "t_end (%g) must be >= macro_step (%g)", s->t_end,
                s->macro_step);
  if ((n = get(in, "newton"))) {
    struct fy_node *v;
    if ((st = want_mapping(L, n, "integrator.newton")) ||
        (st = check_keys(L, n, "integrator.newton", newton_keys,
                         COUNT(newton_keys), NULL, 0)))
      return st;
    if ((st = opt_positive(L, n, "tolerance", "tolerance", &s->newton_tol,
                           NULL)))
      return st;
    if ((v = get(n, "max_iterations"))) {
      if ((st = as_int(L, v, "max_iterations", &s->newton_max_iter)))
        return st;
      if (s->newton_max_iter < 1)
        return fail(L, v, "max_iterations must be >= 1, got %d",
                    s->newton_max_iter);
    }
  }
  if ((n = get(in, "energy_warning"))) {
    if ((st = as_number(L, n, "energy_warning", &s->energy_warning)))
      return st;
    if (!(s->energy_warning >= 0))
      return fail(L, n, "energy_warning must be >= 0 (0: never warn), got %g",
                  s->energy_warning);
  }
  if ((n = get(in, "solver"))) { /* doc/solver.md */
    static const char *const solvers[] = {"auto", "structured", "general"};
    int which;
    if ((st = as_choice(L, n, "solver", solvers, 3, &which)))
      return st;
    s->solver = (mrvi_solver)which;
  }
  if ((n = get(in, "constraints")))
    return load_constraint_settings(L, n);
  return MRVI_OK;
}

static int load_output(loader *L, struct fy_node *out) {
  mrvi_system *sys = L->sys;
  struct fy_node *n;
  const char *file;
  int st;
  if ((st = want_mapping(L, out, "output")) ||
      (st = check_keys(L, out, "output", output_keys, COUNT(output_keys), NULL,
                       0)))
    return st;
  if ((n = get(out, "file"))) {
    if ((st = as_string(L, n, "file", &file)))
      return st;
    char *copy = strdup(file);
    if (!copy)
      return fail_nomem(L);
    free(sys->output_file);
    sys->output_file = copy;
  }
  if ((n = get(out, "every"))) {
    if ((st = as_int(L, n, "every", &sys->output_every)))
      return st;
    if (sys->output_every < 1)
      return fail(L, n, "every must be >= 1, got %d", sys->output_every);
  }
  if ((n = get(out, "micro")) &&
      (st = as_bool(L, n, "micro", &sys->output_micro)))
    return st;
  if ((n = get(out, "micro_slow")) &&
      (st = as_bool(L, n, "micro_slow", &sys->output_micro_slow)))
    return st;
  if ((n = get(out, "xdmf")) && (st = as_bool(L, n, "xdmf", &sys->output_xdmf)))
    return st;
  if ((n = get(out, "flush_interval"))) {
    if ((st = as_number(L, n, "flush_interval", &sys->output_flush_interval)))
      return st;
    if (!(sys->output_flush_interval > 0))
      return fail(L, n, "flush_interval must be > 0 seconds, got %g",
                  sys->output_flush_interval);
  }
  return MRVI_OK;
}

/* Sizes the integrator allocates per macro step: p n_f micro unknowns in
 * an int, and their storage within the machine's memory. */
static int check_sizes(loader *L, struct fy_node *at) {
  const mrvi_settings *s = &L->sys->settings;
  long long pn = (long long)s->micro_steps * mrvi_model_n_fast(L->sys->model);
  if (pn > INT_MAX / 8)
    return fail(L, at,
                "integrator.micro_steps × fast coordinates = %d × %d is too "
                "large (at most %d)",
                s->micro_steps, mrvi_model_n_fast(L->sys->model), INT_MAX / 8);
  const double have = mrvi_machine_memory();
  /* eight vectors of the step's unknowns, and the quadrature points of
   * both potentials (2p + 2 each) */
  const double need = 8.0 * 8.0 * (double)(pn + mrvi_model_n(L->sys->model)) +
                      4.0 * ((double)s->micro_steps + 1.0) * sizeof(mrvi_point);
  if (have > 0 && need > have)
    return fail(L, at,
                "integrator.micro_steps × fast coordinates = %d × %d needs "
                "about %.3g GiB per macro step, more than this machine's "
                "%.3g GiB",
                s->micro_steps, mrvi_model_n_fast(L->sys->model),
                need / 1073741824.0, have / 1073741824.0);
  return MRVI_OK;
}

static int interpret(loader *L) {
  mrvi_system *sys = L->sys;
  struct fy_node *root = fy_document_root(L->doc), *n;
  int st;
  if (!root || is_null(root))
    return fail(L, NULL, "the description is empty");
  /* A root scalar is not quoted back: reading the text of a root quoted
   * scalar with escapes leaks in libfyaml 0.7 (found by tests/fuzz). */
  if (!fy_node_is_mapping(root))
    return fail(L, root, "the description must be a mapping, got %s",
                fy_node_is_sequence(root) ? "a list" : "a single value");
  if ((st = want_mapping(L, root, "the description")) ||
      (st = check_keys(L, root, "the top level", top_keys, COUNT(top_keys),
                       NULL, 0)))
    return st;
  const char *name;
  if ((st = need(L, root, "name", "the top level", &n)) ||
      (st = as_string(L, n, "name", &name)))
    return st;
  sys->name = strdup(name);
  sys->model = mrvi_model_create();
  mrvi_settings_default(&sys->settings);
  sys->output_every = 1;
  sys->output_micro = 1;
  sys->output_xdmf = 1;
  size_t flen = strlen(name) + 4;
  sys->output_file = malloc(flen);
  if (!sys->name || !sys->model || !sys->output_file)
    return fail_nomem(L);
  mrvi_fmt(sys->output_file, flen, "%s.h5", name);

  if ((st = load_model(L, root)))
    return st;
  if ((n = get(root, "integrator")) && (st = load_integrator(L, n)))
    return st;
  char why[256];
  if (mrvi_settings_check(&sys->settings, why, sizeof why))
    return fail(L, n ? n : root, "%s", why);
  if ((st = check_sizes(L, n ? n : root)))
    return st;
  if ((st = check_constraints(L)))
    return st;
  if ((n = get(root, "output")) && (st = load_output(L, n)))
    return st;
  return MRVI_OK;
}

/* ---------------------------------------------------------------------------
 * Entry points
 * ------------------------------------------------------------------------- */

static int cmp_splice(const void *a, const void *b) {
  const splice *x = a, *y = b;
  return x->start < y->start ? -1 : x->start > y->start;
}

/* The input text with the spliced values, if that text parses to the same
 * document as the modified tree (else NULL). */
static char *spliced_text(loader *L, const char *text) {
  qsort(L->sp, (size_t)L->n_sp, sizeof *L->sp, cmp_splice);
  size_t len = strlen(text) + 1;
  for (int i = 0; i < L->n_sp; i++) {
    if (L->sp[i].end > strlen(text) ||
        (i > 0 && L->sp[i].start < L->sp[i - 1].end))
      return NULL;
    len += strlen(L->sp[i].value);
  }
  char *out = malloc(len);
  if (!out)
    return NULL;
  size_t pos = 0, off = 0;
  for (int i = 0; i < L->n_sp; i++) {
    size_t keep = L->sp[i].start - pos, vlen = strlen(L->sp[i].value);
    memcpy(out + off, text + pos, keep);
    memcpy(out + off + keep, L->sp[i].value, vlen);
    off += keep + vlen;
    pos = L->sp[i].end;
  }
  strcpy(out + off, text + pos);
  /* Keep it only if it means the same as the modified tree. */
  struct fy_diag *diag = diag_create();
  struct fy_parse_cfg cfg = {.flags = FYPCF_QUIET | FYPCF_DEFAULT_VERSION_1_2 |
                                      FYPCF_RESOLVE_DOCUMENT,
                             .diag = diag};
  struct fy_document *doc =
      diag ? fy_document_build_from_string(&cfg, out, FY_NT) : NULL;
  int same =
      doc && fy_node_compare(fy_document_root(doc), fy_document_root(L->doc));
  fy_document_destroy(doc);
  fy_diag_destroy(diag);
  if (!same) {
    free(out);
    return NULL;
  }
  return out;
}

/* Text of the description after the overrides: the input verbatim when
 * there are none; with overrides, a header naming them, then the input with
 * the new values spliced in (comments kept) when every override replaced a
 * scalar, else the modified document emitted by libfyaml. */
static char *description_text(loader *L, const char *text,
                              const char *const *overrides, int n_ov) {
  if (n_ov == 0)
    return strdup(text);
  char *body = L->splice_ok ? spliced_text(L, text) : NULL;
  if (!body)
    body = fy_emit_document_to_string(L->doc, FYECF_MODE_PRETTY);
  if (!body)
    return NULL;
  size_t len = strlen(body) + strlen(L->path) + 64;
  for (int i = 0; i < n_ov; i++)
    len += strlen(overrides[i]) + 16;
  char *out = malloc(len);
  if (out) {
    size_t off = (size_t)snprintf(out, len, "# %s with overrides:\n", L->path);
    for (int i = 0; i < n_ov; i++)
      off += (size_t)snprintf(out + off, len - off, "#   --set %s\n",
                              overrides[i]);
    snprintf(out + off, len - off, "%s", body);
  }
  free(body);
  return out;
}

/* First collected libfyaml error, as file:line:col: message. */
static int syntax_error(loader *L) {
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

/* ---------------------------------------------------------------------------
 * Limits on hostile input (doc/description-files.md, "Limits")
 * ------------------------------------------------------------------------- */

/* Offset of the first byte that does not start a printable YAML character
 * (YAML 1.2 §5.1: tab, LF, CR, U+0020..7E, U+0085, U+00A0..D7FF,
 * U+E000..FFFD, U+10000..10FFFF, UTF-8 encoded), or -1; *line and *col are
 * its 1-based position (columns in characters), *code the decoded
 * character or -1 for an invalid byte. */
static long first_invalid(const char *text, size_t n, int *line, int *col,
                          long *code) {
  const unsigned char *s = (const unsigned char *)text;
  *line = 1;
  *col = 1;
  for (size_t i = 0; i < n;) {
    unsigned c = s[i];
    int len = c < 0x80             ? 1
              : (c & 0xe0) == 0xc0 ? 2
              : (c & 0xf0) == 0xe0 ? 3
              : (c & 0xf8) == 0xf0 ? 4
                                   : 0;
    unsigned long u = len == 1   ? c
                      : len == 2 ? c & 0x1f
                      : len == 3 ? c & 0x0f
                                 : c & 0x07;
    int ok = len > 0 && i + (size_t)len <= n;
    for (int k = 1; ok && k < len; k++) {
      ok = (s[i + k] & 0xc0) == 0x80;
      u = (u << 6) | (s[i + k] & 0x3f);
    }
    static const unsigned long least[5] = {0, 0, 0x80, 0x800, 0x10000};
    if (!ok || u < least[len] || u > 0x10ffff) { /* overlong or beyond */
      *code = -1;
      return (long)i;
    }
    int printable = u == 9 || u == 10 || u == 13 || (u >= 0x20 && u <= 0x7e) ||
                    u == 0x85 || (u >= 0xa0 && u <= 0xd7ff) ||
                    (u >= 0xe000 && u <= 0xfffd) || u >= 0x10000;
    if (!printable) {
      *code = (long)u;
      return (long)i;
    }
    if (c == '\n') {
      (*line)++;
      *col = 1;
    } else {
      (*col)++;
    }
    i += (size_t)len;
  }
  return -1;
}

/* What first_invalid found, for messages. */
static void describe_invalid(char *buf, size_t len, const char *text, long at,
                             long code) {
  if (code < 0)
    mrvi_fmt(buf, len, "invalid byte 0x%02x: not UTF-8 text",
             (unsigned char)text[at]);
  else if (code == 0)
    mrvi_fmt(buf, len, "NUL byte: not a text file");
  else
    mrvi_fmt(buf, len, "control character U+%04lX is not allowed in YAML",
             code);
}

/* Nodes of the tree at n, not following aliases. */
static long count_nodes(struct fy_node *n) {
  long c = 1;
  void *it = NULL;
  if (fy_node_is_sequence(n)) {
    struct fy_node *x;
    while ((x = fy_node_sequence_iterate(n, &it)))
      c += count_nodes(x);
  } else if (fy_node_is_mapping(n)) {
    struct fy_node_pair *p;
    while ((p = fy_node_mapping_iterate(n, &it)))
      c +=
          count_nodes(fy_node_pair_key(p)) + count_nodes(fy_node_pair_value(p));
  }
  return c;
}

typedef struct expansion {
  long extra, limit;    /* nodes added by aliases, their bound */
  struct fy_node *at;   /* outermost alias being expanded, or the node */
  int too_deep, exceed; /* which bound was hit */
} expansion;

/* Walk the tree as it will be after alias resolution, counting the nodes
 * aliases add and the depth, stopping at the first bound hit (so the walk
 * itself is bounded: billion laughs stops after `limit` nodes). */
static int expand_walk(expansion *E, struct fy_node *n, int depth,
                       struct fy_node *alias) {
  if (!n)
    return 0;
  if (depth > MAX_DEPTH) {
    E->too_deep = 1;
    E->at = alias ? alias : n;
    return 1;
  }
  if (alias && ++E->extra > E->limit) {
    E->exceed = 1;
    E->at = alias;
    return 1;
  }
  if (fy_node_is_alias(n))
    return expand_walk(E, fy_node_resolve_alias(n), depth, alias ? alias : n);
  void *it = NULL;
  if (fy_node_is_sequence(n)) {
    struct fy_node *x;
    while ((x = fy_node_sequence_iterate(n, &it)))
      if (expand_walk(E, x, depth + 1, alias))
        return 1;
  } else if (fy_node_is_mapping(n)) {
    struct fy_node_pair *p;
    while ((p = fy_node_mapping_iterate(n, &it)))
      if (expand_walk(E, fy_node_pair_key(p), depth + 1, alias) ||
          expand_walk(E, fy_node_pair_value(p), depth + 1, alias))
        return 1;
  }
  return 0;
}

/* Any alias in the tree at n (override values may not hold one). */
static struct fy_node *find_alias(struct fy_node *n) {
  void *it = NULL;
  struct fy_node *a = NULL;
  if (fy_node_is_alias(n))
    return n;
  if (fy_node_is_sequence(n)) {
    struct fy_node *x;
    while (!a && (x = fy_node_sequence_iterate(n, &it)))
      a = find_alias(x);
  } else if (fy_node_is_mapping(n)) {
    struct fy_node_pair *p;
    while (!a && (p = fy_node_mapping_iterate(n, &it)))
      if (!(a = find_alias(fy_node_pair_key(p))))
        a = find_alias(fy_node_pair_value(p));
  }
  return a;
}

/* The text is printable UTF-8 (YAML 1.2 §5.1) of bounded size. */
static int check_text(loader *L, const char *text) {
  size_t n = strlen(text);
  if (n > MAX_TEXT) {
    mrvi_fmt(L->msg, L->len, "%s: the description is larger than %zu MiB",
             L->path, MAX_TEXT >> 20);
    return MRVI_EPARSE;
  }
  int line, col;
  long code, at = first_invalid(text, n, &line, &col, &code);
  if (at >= 0) {
    char what[128];
    describe_invalid(what, sizeof what, text, at, code);
    mrvi_fmt(L->msg, L->len, "%s:%d:%d: %s", L->path, line, col, what);
    return MRVI_EPARSE;
  }
  return MRVI_OK;
}

/* Bound the nodes aliases add and the nesting depth through them, then
 * resolve aliases and merge keys. */
static int resolve_aliases(loader *L) {
  struct fy_node *root = fy_document_root(L->doc);
  long own = count_nodes(root);
  expansion E = {.limit = MAX_ALIAS_NODES + 4 * own};
  if (expand_walk(&E, root, 0, NULL)) {
    if (E.exceed)
      return fail(L, E.at,
                  "aliases expand the document beyond %ld nodes (an alias "
                  "bomb?)",
                  E.limit);
    return fail(L, E.at, "nesting deeper than %d levels", MAX_DEPTH);
  }
  if (fy_document_resolve(L->doc)) {
    void *it = NULL;
    if (fy_diag_errors_iterate(L->diag, &it))
      return syntax_error(L);
    return fail(L, NULL, "cannot resolve aliases");
  }
  return MRVI_OK;
}

void mrvi_system_free(mrvi_system *sys) {
  if (!sys)
    return;
  mrvi_model_free(sys->model);
  free(sys->name);
  free(sys->path);
  free(sys->output_file);
  free(sys->description);
  free(sys->notes);
  free(sys);
}

int mrvi_system_load_string(const char *text, const char *display_name,
                            const char *const *overrides, int n_overrides,
                            mrvi_system **out, char *msg, size_t len) {
  char scratch[8];
  if (!msg || len == 0) {
    msg = scratch;
    len = sizeof scratch;
  }
  msg[0] = '\0';
  if (out)
    *out = NULL;
  if (!text || !out || n_overrides < 0 || (n_overrides > 0 && !overrides)) {
    mrvi_fmt(msg, len, "mrvi_system_load_string: invalid argument");
    return MRVI_EINVAL;
  }
  loader L = {.path = display_name ? display_name : "<string>",
              .msg = msg,
              .len = len,
              .splice_ok = 1};
  int st = MRVI_OK;
  L.sys = calloc(1, sizeof *L.sys);
  L.diag = diag_create();
  if (!L.sys || !L.diag || !(L.sys->path = strdup(L.path))) {
    st = fail_nomem(&L);
    goto done;
  }

  st = check_text(&L, text);
  if (st)
    goto done;
  /* Parsed without resolving aliases: their expansion is bounded first. */
  struct fy_parse_cfg cfg = {.flags = FYPCF_QUIET | FYPCF_DEFAULT_VERSION_1_2,
                             .diag = L.diag};
  L.doc = fy_document_build_from_string(&cfg, text, FY_NT);
  if (!L.doc || fy_diag_got_error(L.diag) || !fy_document_root(L.doc)) {
    void *it = NULL;
    if (fy_diag_errors_iterate(L.diag, &it))
      st = syntax_error(&L);
    else /* no document at all: only comments or blank */
      st = fail(&L, NULL, "the description is empty");
    goto done;
  }
  st = resolve_aliases(&L);
  if (st)
    goto done;
  for (int i = 0; i < n_overrides && !st; i++)
    st = apply_override(&L, overrides[i]);
  if (st)
    goto done;
  if (!(L.sys->description =
            description_text(&L, text, overrides, n_overrides))) {
    st = fail_nomem(&L);
    goto done;
  }
  st = interpret(&L);
  /* The `control:` section (optimal control) is checked here too. */
  struct fy_node *control = st ? NULL : get(fy_document_root(L.doc), "control");
  if (control) {
    struct mrvi_ocp *o = NULL;
    st = mrvi_ocp_parse(L.sys->model, &L.sys->settings, control, L.path,
                        loader_override_of, &L, &o, NULL, msg, len);
    mrvi_ocp_free(o);
  }

done:
  if (st) {
    mrvi_system_free(L.sys);
  } else {
    *out = L.sys;
    msg[0] = '\0';
  }
  free(L.coords);
  free(L.parts);
  hash_free(&L.coord_hash);
  hash_free(&L.part_hash);
  hash_free(&L.model_hash);
  free(L.constraint_items);
  free(L.ov);
  free(L.sp);
  fy_document_destroy(L.doc);
  fy_diag_destroy(L.diag);
  return st;
}

int mrvi_system_load(const char *path, const char *const *overrides,
                     int n_overrides, mrvi_system **out, char *msg,
                     size_t len) {
  if (out)
    *out = NULL;
  if (!path) {
    mrvi_fmt(msg, len, "mrvi_system_load: no file name");
    return MRVI_EINVAL;
  }
  FILE *f = fopen(path, "rb");
  if (!f) {
    mrvi_fmt(msg, len, "%s: cannot open: %s", path, strerror(errno));
    return MRVI_EIO;
  }
  /* Read the whole file (the description is kept verbatim), at most
   * MAX_TEXT bytes, stopping at the first NUL byte (/dev/zero). */
  size_t cap = 4096, used = 0;
  char *text = malloc(cap);
  int st = text ? MRVI_OK : MRVI_ENOMEM, nul = 0, big = 0;
  while (!st) {
    if (used + 1 == cap) {
      if (used > MAX_TEXT) {
        big = 1;
        break;
      }
      char *t = realloc(text, 2 * cap);
      if (!t) {
        st = MRVI_ENOMEM;
        break;
      }
      text = t;
      cap *= 2;
    }
    size_t got = fread(text + used, 1, cap - used - 1, f);
    nul = got && memchr(text + used, 0, got);
    used += got;
    if (got == 0 || nul)
      break;
  }
  if (!st && ferror(f))
    st = MRVI_EIO;
  fclose(f);
  if (st) {
    mrvi_fmt(msg, len, "%s: %s", path,
             st == MRVI_EIO ? "read error" : "out of memory");
    free(text);
    return st;
  }
  text[used] = '\0';
  int line, col;
  long code, at = nul ? first_invalid(text, used, &line, &col, &code) : -1;
  if (at >= 0 || big) {
    char what[128];
    if (big)
      mrvi_fmt(what, sizeof what, "the description is larger than %zu MiB",
               MAX_TEXT >> 20);
    else
      describe_invalid(what, sizeof what, text, at, code);
    if (big)
      mrvi_fmt(msg, len, "%s: %s", path, what);
    else
      mrvi_fmt(msg, len, "%s:%d:%d: %s", path, line, col, what);
    free(text);
    return MRVI_EPARSE;
  }
  st = mrvi_system_load_string(text, path, overrides, n_overrides, out, msg,
                               len);
  free(text);
  return st;
}
