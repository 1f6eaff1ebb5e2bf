/* Description files (doc/description-files.md): YAML 1.2 read with libfyaml,
 * --set overrides applied to the document tree, then interpreted into a
 * model and integrator settings.  This file is the driver: it reads the
 * text, applies the overrides, reads the top level (name, dimension,
 * gravity) and hands each section to the file of the same name in this
 * folder (loader_internal.h lists them).
 *
 * Every error becomes "file:line:col: message" at the node that caused it
 * (1-based), or "--set KEY=VALUE: message" when the node came from an
 * override. */
#include "io/loader/loader_internal.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const char *loader_override_of(const void *L, struct fy_node *n) {
  return mrvi_ld_override_of(L, n);
}

/* "control" is read by src/ocp/ocp_loader.c (optimal control), "batch" by
 * batch.c (mrvi batch). */
static const char *const top_keys[] = {
    "name",        "dimension", "gravity",     "particles",  "springs",
    "coordinates", "terms",     "constraints", "integrator", "output",
    "angles",      "forces",    "generate",    "bodies",     "joints",
    "control",     "batch",     "limits"};

static int load_model(loader *L, struct fy_node *root) {
  mrvi_model *m = L->sys->model;
  struct fy_node *n, *particles = mrvi_ld_get(root, "particles");
  struct fy_node *gravity = mrvi_ld_get(root, "gravity");
  int st, dim = 0;
  if ((st = mrvi_model_set_name(m, L->sys->name)))
    return mrvi_ld_fail_model(L, mrvi_ld_get(root, "name"), st);
  if ((n = mrvi_ld_get(root, "dimension"))) {
    if ((st = mrvi_ld_as_int(L, n, "dimension", &dim)))
      return st;
    if (dim < 1 || dim > 3)
      return mrvi_ld_fail(L, n, "dimension must be 1, 2 or 3, got %d", dim);
    if ((st = mrvi_model_set_dimension(m, dim)))
      return mrvi_ld_fail_model(L, n, st);
  } else if (particles || gravity || mrvi_ld_get(root, "generate") ||
             mrvi_ld_get(root, "bodies")) {
    return mrvi_ld_fail(L, root, "missing key 'dimension' (needed by %s)",
                        particles                       ? "particles"
                        : gravity                       ? "gravity"
                        : mrvi_ld_get(root, "generate") ? "generate"
                                                        : "bodies");
  }
  if ((n = mrvi_ld_get(root, "limits")) && (st = mrvi_ld_limits(L, n)))
    return st;
  /* Model order: coordinates first, then particles as declared (names by
   * hash, the partition extended by each add: linear in the file). */
  if ((n = mrvi_ld_get(root, "coordinates")) &&
      (st = mrvi_ld_coordinates(L, n)))
    return st;
  if (particles && (st = mrvi_ld_particles(L, particles, dim)))
    return st;
  if ((n = mrvi_ld_get(root, "generate")) &&
      (st = mrvi_ld_generators(L, n, dim)))
    return st;
  if ((n = mrvi_ld_get(root, "bodies")) && (st = mrvi_ld_bodies(L, n, dim)))
    return st;
  if (mrvi_model_n(m) == 0)
    return mrvi_ld_fail(L, root,
                        "the system has no coordinates: add 'coordinates', "
                        "'particles' or 'bodies'");
  if (gravity) {
    double g[3] = {0, 0, 0};
    if ((st = mrvi_ld_as_vector(L, gravity, "gravity", dim, g)))
      return st;
    if ((st = mrvi_model_set_gravity(m, g)) < 0)
      return mrvi_ld_fail_model(L, gravity, st);
  }
  if ((n = mrvi_ld_get(root, "springs")) && (st = mrvi_ld_springs(L, n, dim)))
    return st;
  if ((n = mrvi_ld_get(root, "terms")) && (st = mrvi_ld_terms(L, n)))
    return st;
  if ((n = mrvi_ld_get(root, "angles")) && (st = mrvi_ld_angles(L, n)))
    return st;
  if ((n = mrvi_ld_get(root, "forces")) && (st = mrvi_ld_forces(L, n, dim)))
    return st;
  if ((n = mrvi_ld_get(root, "constraints")) &&
      (st = mrvi_ld_constraints(L, n, dim)))
    return st;
  if ((n = mrvi_ld_get(root, "joints")) && (st = mrvi_ld_joints(L, n, dim)))
    return st;
  return MRVI_OK;
}

static int interpret(loader *L) {
  mrvi_system *sys = L->sys;
  struct fy_node *root = fy_document_root(L->doc), *n;
  int st;
  if (!root || mrvi_ld_is_null(root))
    return mrvi_ld_fail(L, NULL, "the description is empty");
  /* A root scalar is not quoted back: reading the text of a root quoted
   * scalar with escapes leaks in libfyaml 0.7 (found by tests/fuzz). */
  if (!fy_node_is_mapping(root))
    return mrvi_ld_fail(L, root, "the description must be a mapping, got %s",
                        fy_node_is_sequence(root) ? "a list"
                                                  : "a single value");
  if ((st = mrvi_ld_want_mapping(L, root, "the description")) ||
      (st = mrvi_ld_check_keys(L, root, "the top level", top_keys,
                               COUNT(top_keys), NULL, 0)))
    return st;
  const char *name;
  if ((st = mrvi_ld_need(L, root, "name", "the top level", &n)) ||
      (st = mrvi_ld_as_string(L, n, "name", &name)))
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
    return mrvi_ld_fail_nomem(L);
  mrvi_fmt(sys->output_file, flen, "%s.h5", name);

  if ((st = load_model(L, root)))
    return st;
  if ((n = mrvi_ld_get(root, "integrator")) && (st = mrvi_ld_integrator(L, n)))
    return st;
  char why[256];
  if (mrvi_settings_check(&sys->settings, why, sizeof why))
    return mrvi_ld_fail(L, n ? n : root, "%s", why);
  if ((st = mrvi_ld_check_sizes(L, n ? n : root)))
    return st;
  if ((st = mrvi_ld_check_constraints(L)))
    return st;
  if ((n = mrvi_ld_get(root, "output")) && (st = mrvi_ld_output(L, n)))
    return st;
  if ((n = mrvi_ld_get(root, "batch")) && (st = mrvi_ld_batch(L, n)))
    return st;
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
  L.diag = mrvi_ld_diag_create();
  if (!L.sys || !L.diag || !(L.sys->path = strdup(L.path))) {
    st = mrvi_ld_fail_nomem(&L);
    goto done;
  }

  st = mrvi_ld_check_text(&L, text);
  if (st)
    goto done;
  /* Parsed without resolving aliases: their expansion is bounded first. */
  struct fy_parse_cfg cfg = {.flags = FYPCF_QUIET | FYPCF_DEFAULT_VERSION_1_2,
                             .diag = L.diag};
  L.doc = fy_document_build_from_string(&cfg, text, FY_NT);
  if (!L.doc || fy_diag_got_error(L.diag) || !fy_document_root(L.doc)) {
    void *it = NULL;
    if (fy_diag_errors_iterate(L.diag, &it))
      st = mrvi_ld_syntax_error(&L);
    else /* no document at all: only comments or blank */
      st = mrvi_ld_fail(&L, NULL, "the description is empty");
    goto done;
  }
  st = mrvi_ld_resolve_aliases(&L);
  if (st)
    goto done;
  for (int i = 0; i < n_overrides && !st; i++)
    st = mrvi_ld_apply_override(&L, overrides[i]);
  if (st)
    goto done;
  if (!(L.sys->description =
            mrvi_ld_description_text(&L, text, overrides, n_overrides))) {
    st = mrvi_ld_fail_nomem(&L);
    goto done;
  }
  st = interpret(&L);
  /* The `control:` section (optimal control) is checked here too. */
  struct fy_node *control =
      st ? NULL : mrvi_ld_get(fy_document_root(L.doc), "control");
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
  mrvi_ld_hash_free(&L.coord_hash);
  mrvi_ld_hash_free(&L.part_hash);
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
  long code,
      at = nul ? mrvi_ld_first_invalid(text, used, &line, &col, &code) : -1;
  if (at >= 0 || big) {
    char what[128];
    if (big)
      mrvi_fmt(what, sizeof what, "the description is larger than %zu MiB",
               MAX_TEXT >> 20);
    else
      mrvi_ld_describe_invalid(what, sizeof what, text, at, code);
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
