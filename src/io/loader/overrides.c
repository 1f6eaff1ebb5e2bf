/* --set overrides: "dotted.path=value" applied to the document tree, and the
 * description text kept with the run (the input with the new values
 * spliced in when it can be). */
#include "io/loader/loader_internal.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

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
  if (!a || !b || fy_node_get_style(old) != FYNS_PLAIN ||
      mrvi_ld_override_of(L, old) || b->input_pos < a->input_pos) {
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

/* Parse `value` as a YAML node of the document. */
static int build_value(loader *L, const char *text, const char *value,
                       struct fy_node **out) {
  if (!*value)
    return set_error(L, text, "empty value");
  int line, col;
  long code,
      at = mrvi_ld_first_invalid(value, strlen(value), &line, &col, &code);
  if (at >= 0) {
    char what[128];
    mrvi_ld_describe_invalid(what, sizeof what, value, at, code);
    return set_error(L, text, "%s", what);
  }
  *out = fy_node_build_from_string(L->doc, value, FY_NT);
  if (*out && mrvi_ld_find_alias(*out)) {
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
    return mrvi_ld_fail_nomem(L);
  }
  if (p) {
    if (fy_node_pair_set_value(p, v)) {
      fy_node_free(v);
      return mrvi_ld_fail_nomem(L);
    }
  } else {
    if (fy_node_sequence_insert_before(seq, old, v) ||
        !fy_node_sequence_remove(seq, old)) {
      fy_node_free(v);
      return mrvi_ld_fail_nomem(L);
    }
    fy_node_free(old);
  }
  return remember(L, v, text) ? mrvi_ld_fail_nomem(L) : MRVI_OK;
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
    return st ? st : mrvi_ld_fail_nomem(L);
  }
  L->splice_ok = 0; /* the text has no place for a new key */
  if (remember(L, k, text) || remember(L, v, text))
    return mrvi_ld_fail_nomem(L);
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
      if (mrvi_ld_is_null(node)) {
        /* `integrator:` with nothing below: make it a mapping. */
        struct fy_node *m = fy_node_create_mapping(L->doc);
        if (!m || fy_node_pair_set_value(p, m)) {
          fy_node_free(m);
          return mrvi_ld_fail_nomem(L);
        }
        L->splice_ok = 0;
        if (remember(L, m, text))
          return mrvi_ld_fail_nomem(L);
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
int mrvi_ld_apply_override(loader *L, const char *text) {
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
    return mrvi_ld_fail_nomem(L);
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
  struct fy_diag *diag = mrvi_ld_diag_create();
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
char *mrvi_ld_description_text(loader *L, const char *text,
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
