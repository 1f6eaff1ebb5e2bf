/* Limits on hostile input (doc/description-files.md, "Limits"): printable
 * UTF-8 text of bounded size, and aliases whose expansion and nesting are
 * bounded before libfyaml resolves them. */
#include "io/loader/loader_internal.h"

#include <limits.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

/* Nodes aliases may add: this many plus 4 per node of the file. */
#define MAX_ALIAS_NODES 100000L

/* Offset of the first byte that does not start a printable YAML character
 * (YAML 1.2 §5.1: tab, LF, CR, U+0020..7E, U+0085, U+00A0..D7FF,
 * U+E000..FFFD, U+10000..10FFFF, UTF-8 encoded), or -1; *line and *col are
 * its 1-based position (columns in characters), *code the decoded
 * character or -1 for an invalid byte. */
long mrvi_ld_first_invalid(const char *text, size_t n, int *line, int *col,
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

/* What mrvi_ld_first_invalid found, for messages. */
void mrvi_ld_describe_invalid(char *buf, size_t len, const char *text, long at,
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
struct fy_node *mrvi_ld_find_alias(struct fy_node *n) {
  void *it = NULL;
  struct fy_node *a = NULL;
  if (fy_node_is_alias(n))
    return n;
  if (fy_node_is_sequence(n)) {
    struct fy_node *x;
    while (!a && (x = fy_node_sequence_iterate(n, &it)))
      a = mrvi_ld_find_alias(x);
  } else if (fy_node_is_mapping(n)) {
    struct fy_node_pair *p;
    while (!a && (p = fy_node_mapping_iterate(n, &it)))
      if (!(a = mrvi_ld_find_alias(fy_node_pair_key(p))))
        a = mrvi_ld_find_alias(fy_node_pair_value(p));
  }
  return a;
}

/* The text is printable UTF-8 (YAML 1.2 §5.1) of bounded size. */
int mrvi_ld_check_text(loader *L, const char *text) {
  size_t n = strlen(text);
  if (n > MAX_TEXT) {
    mrvi_fmt(L->msg, L->len, "%s: the description is larger than %zu MiB",
             L->path, MAX_TEXT >> 20);
    return MRVI_EPARSE;
  }
  int line, col;
  long code, at = mrvi_ld_first_invalid(text, n, &line, &col, &code);
  if (at >= 0) {
    char what[128];
    mrvi_ld_describe_invalid(what, sizeof what, text, at, code);
    mrvi_fmt(L->msg, L->len, "%s:%d:%d: %s", L->path, line, col, what);
    return MRVI_EPARSE;
  }
  return MRVI_OK;
}

/* Bound the nodes aliases add and the nesting depth through them, then
 * resolve aliases and merge keys. */
int mrvi_ld_resolve_aliases(loader *L) {
  struct fy_node *root = fy_document_root(L->doc);
  long own = count_nodes(root);
  expansion E = {.limit = MAX_ALIAS_NODES + 4 * own};
  if (expand_walk(&E, root, 0, NULL)) {
    if (E.exceed)
      return mrvi_ld_fail(
          L, E.at,
          "aliases expand the document beyond %ld nodes (an alias "
          "bomb?)",
          E.limit);
    return mrvi_ld_fail(L, E.at, "nesting deeper than %d levels", MAX_DEPTH);
  }
  if (fy_document_resolve(L->doc)) {
    void *it = NULL;
    if (fy_diag_errors_iterate(L->diag, &it))
      return mrvi_ld_syntax_error(L);
    return mrvi_ld_fail(L, NULL, "cannot resolve aliases");
  }
  return MRVI_OK;
}

/* The largest limits.max_memory, GiB: 2^20 (a PiB). */
#define MAX_MEMORY_GIB 1048576.0

int mrvi_ld_limits(loader *L, struct fy_node *lim) {
  static const char *const keys[] = {"max_coordinates", "max_memory"};
  struct fy_node *n;
  double v;
  int st;
  if ((st = mrvi_ld_want_mapping(L, lim, "limits")) ||
      (st = mrvi_ld_check_keys(L, lim, "limits", keys, COUNT(keys), NULL, 0)))
    return st;
  if ((n = mrvi_ld_get(lim, "max_coordinates"))) {
    if ((st = mrvi_ld_as_number(L, n, "limits.max_coordinates", &v)))
      return st;
    if (v != floor(v) || v < 1 || v > INT_MAX)
      return mrvi_ld_fail(L, n,
                          "limits.max_coordinates must be a whole number from "
                          "1 to %d, got %s",
                          INT_MAX, mrvi_ld_scalar0(n));
    L->max_coordinates = v;
  }
  if ((n = mrvi_ld_get(lim, "max_memory"))) {
    if ((st = mrvi_ld_as_number(L, n, "limits.max_memory", &v)))
      return st;
    if (!(v > 0) || v > MAX_MEMORY_GIB)
      return mrvi_ld_fail(L, n,
                          "limits.max_memory must be a number of GiB above 0 "
                          "and at most %.0f, got %s",
                          MAX_MEMORY_GIB, mrvi_ld_scalar0(n));
    L->max_memory = v;
  }
  return MRVI_OK;
}

double mrvi_ld_memory_limit(const loader *L) {
  const double gib = L->max_memory > 0 ? L->max_memory : MRVI_MAX_MEMORY_GIB;
  double b = gib * 1073741824.0;
#ifdef MRVI_MEMORY_CAP
  if (b > (double)MRVI_MEMORY_CAP)
    b = (double)MRVI_MEMORY_CAP;
#endif
  return b;
}

int mrvi_ld_check_memory(loader *L, struct fy_node *at, double need,
                         const char *fmt, ...) {
  const double lim = mrvi_ld_memory_limit(L);
  if (need <= lim)
    return MRVI_OK;
  char what[512];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(what, sizeof what, fmt, ap);
  va_end(ap);
  /* the value to set: need in GiB rounded up to 0.001 (and within it) */
  double set = ceil(need / 1073741824.0 * 1000.0) / 1000.0;
  if (set * 1073741824.0 < need)
    set += 0.001;
  const int dflt = L->max_memory <= 0;
  if (set > MAX_MEMORY_GIB)
    return mrvi_ld_fail(L, at,
                        "%s about %.4g GiB, more than limits.max_memory can "
                        "allow (%.0f GiB)",
                        what, need / 1073741824.0, MAX_MEMORY_GIB);
  return mrvi_ld_fail(
      L, at,
      "%s about %.4g GiB, more than limits.max_memory = %.10g GiB%s: to load "
      "it, set `limits: {max_memory: %.10g}` at the top level (or --set "
      "limits.max_memory=%.10g)",
      what, need / 1073741824.0, lim / 1073741824.0,
      dflt ? " (the default)" : "", set, set);
}
