/* `batch:` of a description file (doc/batch.md, "The batch: section"): the
 * options of `mrvi batch` in the file, in the command line's vocabulary.
 *
 *   batch:
 *     vary:                       # in order; the last varies fastest
 *       integrator.micro_steps: [1, 2, 4]         # a list of values
 *       integrator.macro_step: logspace(-2,-1,4)  # or the --vary text
 *     zip: false
 *     seeds: 8
 *     velocity_std: 0.01
 *     command: run                # or optimize (a multi-start with
 *     control_std: 0.5            #   control_std and seeds)
 *     position_std: 1e-3          # translational positions, projected
 *     position_distribution: gaussian   # or uniform
 *     temperature: 0.5            # thermal velocities, no net momentum
 *     rotation_std: 0.1           # bodies turned by small rotations,
 *     rotations: uniform          #   or uniformly
 *     jobs: 2
 *
 * A run (`mrvi run`, `mrvi check`) checks the section and does nothing
 * with it; `mrvi batch` reads it through mrvi_batch_section_read.  Values
 * stay text, as --vary takes them: linspace(...) and logspace(...) are
 * expanded by src/batch, whose messages are prefixed with the entry's
 * file:line:col (where[]). */
#include "io/loader/loader_internal.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *const batch_keys[] = {
    "vary",        "seeds",        "velocity_std",          "zip",
    "jobs",        "command",      "control_std",           "position_std",
    "temperature", "rotation_std", "position_distribution", "rotations"};

/* Append "KEY=VALUES" and its position to out. */
static int add_vary(loader *L, mrvi_batch_section *out, struct fy_node *at,
                    const char *key, const char *values) {
  int line = 1, col = 1;
  mrvi_ld_node_position(at, &line, &col);
  size_t nk = strlen(key) + strlen(values) + 2;
  size_t nw = strlen(L->path) + 32;
  char **v = realloc(out->vary, (size_t)(out->n_vary + 1) * sizeof *v);
  if (v)
    out->vary = v;
  char **w =
      v ? realloc(out->where, (size_t)(out->n_vary + 1) * sizeof *w) : NULL;
  if (w)
    out->where = w;
  char *kv = w ? malloc(nk) : NULL, *pos = kv ? malloc(nw) : NULL;
  if (!pos) {
    free(kv);
    return mrvi_ld_fail_nomem(L);
  }
  snprintf(kv, nk, "%s=%s", key, values);
  snprintf(pos, nw, "%s:%d:%d", L->path, line, col);
  out->vary[out->n_vary] = kv;
  out->where[out->n_vary++] = pos;
  return MRVI_OK;
}

/* `vary:` entry KEY: VALUE (the --vary text) or KEY: [V1, V2, ...]. */
static int read_vary_entry(loader *L, struct fy_node_pair *pair,
                           mrvi_batch_section *out) {
  struct fy_node *k = fy_node_pair_key(pair), *v = fy_node_pair_value(pair);
  const char *key = mrvi_ld_scalar0(k);
  if (!*key || strchr(key, '\n'))
    return mrvi_ld_fail(L, k,
                        "batch.vary: a key must be a dotted path, as "
                        "--set takes it");
  if (!v || mrvi_ld_is_null(v))
    return mrvi_ld_fail(L, k, "batch.vary.%s: no values", key);
  if (fy_node_is_scalar(v))
    return out ? add_vary(L, out, v, key, mrvi_ld_scalar0(v)) : MRVI_OK;
  if (!fy_node_is_sequence(v) || fy_node_sequence_item_count(v) < 1)
    return mrvi_ld_fail(L, v,
                        "batch.vary.%s: expected a non-empty list of values "
                        "or a value as --vary takes it (V1,V2,..., "
                        "linspace(a,b,n), logspace(a,b,n))",
                        key);
  /* The list joined by commas, as --vary takes it. */
  size_t n = 1;
  void *it = NULL;
  struct fy_node *item;
  while ((item = fy_node_sequence_iterate(v, &it))) {
    const char *s = mrvi_ld_scalar0(item);
    if (!fy_node_is_scalar(item) || mrvi_ld_is_null(item) || !*s)
      return mrvi_ld_fail(L, item,
                          "batch.vary.%s: a value must be a number "
                          "or a word",
                          key);
    if (strchr(s, ',') || strchr(s, '\n'))
      return mrvi_ld_fail(L, item,
                          "batch.vary.%s: a value cannot contain ',' or a "
                          "newline, got '%s'",
                          key, s);
    n += strlen(s) + 1;
  }
  if (!out)
    return MRVI_OK;
  char *joined = calloc(n, 1);
  if (!joined)
    return mrvi_ld_fail_nomem(L);
  it = NULL;
  for (int i = 0; (item = fy_node_sequence_iterate(v, &it)); i++) {
    if (i)
      strcat(joined, ",");
    strcat(joined, mrvi_ld_scalar0(item));
  }
  int st = add_vary(L, out, v, key, joined);
  free(joined);
  return st;
}

/* A standard deviation: finite and >= 0. */
static int std_value(loader *L, struct fy_node *n, const char *what,
                     double *x) {
  int st = mrvi_ld_as_number(L, n, what, x);
  if (!st && (!(*x >= 0) || !isfinite(*x)))
    return mrvi_ld_fail(L, n, "%s must be finite and >= 0, got %g", what, *x);
  return st;
}

/* The section into out (NULL: check only). */
static int read_batch(loader *L, struct fy_node *sec, mrvi_batch_section *out) {
  struct fy_node *n;
  int st, v;
  double x;
  if ((st = mrvi_ld_want_mapping(L, sec, "batch")) ||
      (st = mrvi_ld_check_keys(L, sec, "batch", batch_keys, COUNT(batch_keys),
                               NULL, 0)))
    return st;
  if ((n = mrvi_ld_get(sec, "vary"))) {
    if ((st = mrvi_ld_want_mapping(L, n, "batch.vary")))
      return st;
    void *it = NULL;
    struct fy_node_pair *pair;
    while ((pair = fy_node_mapping_iterate(n, &it)))
      if ((st = read_vary_entry(L, pair, out)))
        return st;
  }
  if ((n = mrvi_ld_get(sec, "seeds"))) {
    if ((st = mrvi_ld_as_int(L, n, "batch.seeds", &v)))
      return st;
    if (v < 0 || v > 1000000)
      return mrvi_ld_fail(L, n, "batch.seeds must be 0..1000000, got %d", v);
    if (out)
      out->seeds = v;
  }
  if ((n = mrvi_ld_get(sec, "jobs"))) {
    if ((st = mrvi_ld_as_int(L, n, "batch.jobs", &v)))
      return st;
    if (v < 1 || v > 1000000)
      return mrvi_ld_fail(L, n, "batch.jobs must be 1..1000000, got %d", v);
    if (out)
      out->jobs = v;
  }
  if ((n = mrvi_ld_get(sec, "zip"))) {
    if ((st = mrvi_ld_as_bool(L, n, "batch.zip", &v)))
      return st;
    if (out)
      out->zip = v;
  }
  if ((n = mrvi_ld_get(sec, "velocity_std"))) {
    if ((st = std_value(L, n, "batch.velocity_std", &x)))
      return st;
    if (out)
      out->velocity_std = x;
  }
  if ((n = mrvi_ld_get(sec, "control_std"))) {
    if ((st = std_value(L, n, "batch.control_std", &x)))
      return st;
    if (out)
      out->control_std = x;
  }
  const char *const stds[] = {"position_std", "temperature", "rotation_std"};
  double *const to[] = {out ? &out->position_std : NULL,
                        out ? &out->temperature : NULL,
                        out ? &out->rotation_std : NULL};
  for (int i = 0; i < 3; i++)
    if ((n = mrvi_ld_get(sec, stds[i]))) {
      char what[40];
      snprintf(what, sizeof what, "batch.%s", stds[i]);
      if ((st = std_value(L, n, what, &x)))
        return st;
      if (out)
        *to[i] = x;
    }
  if ((n = mrvi_ld_get(sec, "position_distribution"))) {
    const char *s = fy_node_is_scalar(n) ? mrvi_ld_scalar0(n) : "";
    if (strcmp(s, "gaussian") && strcmp(s, "uniform"))
      return mrvi_ld_fail(L, n,
                          "batch.position_distribution must be 'gaussian' or "
                          "'uniform', got '%s'",
                          s);
    if (out)
      out->position_uniform = !strcmp(s, "uniform");
  }
  if ((n = mrvi_ld_get(sec, "rotations"))) {
    const char *s = fy_node_is_scalar(n) ? mrvi_ld_scalar0(n) : "";
    if (strcmp(s, "uniform"))
      return mrvi_ld_fail(L, n, "batch.rotations must be 'uniform', got '%s'",
                          s);
    if (out)
      out->rotation_uniform = 1;
  }
  if ((n = mrvi_ld_get(sec, "command"))) {
    const char *s = fy_node_is_scalar(n) ? mrvi_ld_scalar0(n) : "";
    if (strcmp(s, "run") && strcmp(s, "optimize"))
      return mrvi_ld_fail(L, n,
                          "batch.command must be 'run' or 'optimize', "
                          "got '%s'",
                          s);
    if (out)
      out->command = strcmp(s, "run") ? MRVI_BATCH_OPTIMIZE : MRVI_BATCH_RUN;
  }
  return MRVI_OK;
}

int mrvi_ld_batch(loader *L, struct fy_node *batch) {
  return read_batch(L, batch, NULL);
}

void mrvi_batch_section_free(mrvi_batch_section *sec) {
  if (!sec)
    return;
  for (int i = 0; i < sec->n_vary; i++) {
    free(sec->vary[i]);
    free(sec->where[i]);
  }
  free(sec->vary);
  free(sec->where);
  memset(sec, 0, sizeof *sec);
}

int mrvi_batch_section_read(const mrvi_system *sys, mrvi_batch_section *out,
                            char *msg, size_t len) {
  memset(out, 0, sizeof *out);
  out->zip = out->seeds = out->jobs = out->command = -1;
  out->position_uniform = out->rotation_uniform = -1;
  out->velocity_std = out->control_std = out->position_std = NAN;
  out->temperature = out->rotation_std = NAN;
  loader L = {
      .path = sys->path ? sys->path : "<string>", .msg = msg, .len = len};
  L.diag = mrvi_ld_diag_create();
  if (!L.diag)
    return mrvi_ld_fail_nomem(&L);
  /* The text was read and checked by the loader already; parsed again as
   * it did (aliases resolved within the same bounds). */
  struct fy_parse_cfg cfg = {.flags = FYPCF_QUIET | FYPCF_DEFAULT_VERSION_1_2,
                             .diag = L.diag};
  L.doc = fy_document_build_from_string(&cfg, sys->description, FY_NT);
  int st = MRVI_OK;
  if (!L.doc || fy_diag_got_error(L.diag) || !fy_document_root(L.doc))
    st = mrvi_ld_syntax_error(&L);
  if (!st)
    st = mrvi_ld_resolve_aliases(&L);
  struct fy_node *sec =
      st ? NULL : mrvi_ld_get(fy_document_root(L.doc), "batch");
  if (sec)
    st = read_batch(&L, sec, out);
  if (st) {
    mrvi_batch_section_free(out);
    out->zip = out->seeds = out->jobs = out->command = -1;
    out->position_uniform = out->rotation_uniform = -1;
    out->velocity_std = out->control_std = out->position_std = NAN;
    out->temperature = out->rotation_std = NAN;
  } else {
    msg[0] = '\0';
  }
  fy_document_destroy(L.doc);
  fy_diag_destroy(L.diag);
  return st;
}
