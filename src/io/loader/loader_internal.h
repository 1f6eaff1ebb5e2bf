/* What the files of src/io/loader/ share: the loader's state, and the
 * helpers that read nodes of the description (marks, numbers, vectors,
 * names) with "file:line:col: message" errors.  One file per section of
 * the description file (doc/description-files.md):
 *
 *   loader.c       the driver: opens the text, applies --set overrides,
 *                  reads the top level (name, dimension, gravity) and
 *                  dispatches the sections
 *   coordinates.c  particles.c  springs.c  terms.c  angles.c  forces.c
 *   generate.c     constraints.c  integrator.c  output.c  bodies.c
 *   joints.c       batch.c
 *                  the section of the same name (`control:` is read in
 *                  src/ocp/ocp_loader.c)
 *   read.c         errors at marks, typed access to nodes, key checks
 *   names.c        coordinate and particle names
 *   elements.c     what potential elements share: law and parameters,
 *                  linear combinations, the ends of a spring or rod
 *   overrides.c    --set KEY=VALUE applied to the document tree
 *   limits.c       limits on hostile input (text, aliases, depth)
 *
 * Section readers return MRVI_OK or a status with L->msg written. */
#ifndef MRVI_LOADER_INTERNAL_H
#define MRVI_LOADER_INTERNAL_H

#include "io/io.h"

#include <libfyaml.h>

#define COUNT(a) ((int)(sizeof(a) / sizeof((a)[0])))
#define MAX_KEYS 64 /* keys of one mapping, law parameters included */
/* Limits on hostile input (doc/description-files.md, "Limits"). */
#define MAX_TEXT ((size_t)64 << 20) /* bytes of a description or override */
#define MAX_DEPTH 256               /* nesting, counted through aliases */

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
  struct fy_node *constraint_list;   /* `constraints:`, NULL if absent */
  struct fy_node **constraint_items; /* entry of each model constraint */
  int cap_constraint_items;
  double max_coordinates; /* limits.max_coordinates; 0: MRVI_MAX_COORDINATES */
  double max_memory;      /* limits.max_memory (GiB); 0: MRVI_MAX_MEMORY_GIB */
  mrvi_system *sys;
} loader;

/* ---------------------------------------------------------------------------
 * Sections (one file each)
 * ------------------------------------------------------------------------- */
int mrvi_ld_coordinates(loader *L, struct fy_node *list);
int mrvi_ld_particles(loader *L, struct fy_node *list, int dim);
int mrvi_ld_generators(loader *L, struct fy_node *list, int dim);
/* `limits:` (limits.c): max_coordinates, what `generate:` may reach, and
 * max_memory, what the model and the integrator's step may take. */
int mrvi_ld_limits(loader *L, struct fy_node *lim);
/* limits.max_memory in bytes (the default where the file has none; a
 * build's MRVI_MEMORY_CAP caps it). */
double mrvi_ld_memory_limit(const loader *L);
/* MRVI_EPARSE at `at` when need (bytes) exceeds mrvi_ld_memory_limit:
 * "WHAT need(s) about X GiB, more than limits.max_memory = Y GiB: to load
 * it, set `limits: {max_memory: Z}`" (Z: need in GiB rounded up to
 * 0.001); MRVI_OK within it. */
int mrvi_ld_check_memory(loader *L, struct fy_node *at, double need,
                         const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));
int mrvi_ld_springs(loader *L, struct fy_node *list, int dim);
int mrvi_ld_terms(loader *L, struct fy_node *list);
int mrvi_ld_angles(loader *L, struct fy_node *list);
int mrvi_ld_forces(loader *L, struct fy_node *list, int dim);
int mrvi_ld_constraints(loader *L, struct fy_node *list, int dim);
int mrvi_ld_bodies(loader *L, struct fy_node *list, int dim);
int mrvi_ld_joints(loader *L, struct fy_node *list, int dim);
/* Remember the entry that made model constraint c (messages point at it). */
int mrvi_ld_constraint_item(loader *L, int c, struct fy_node *item);
/* Initial data against the constraints, once the settings are known. */
int mrvi_ld_check_constraints(loader *L);
int mrvi_ld_integrator(loader *L, struct fy_node *in);
/* Sizes the integrator allocates per macro step, against the file's
 * limits (mrvi_ld_check_memory). */
int mrvi_ld_check_sizes(loader *L, struct fy_node *at);
int mrvi_ld_output(loader *L, struct fy_node *out);
/* `batch:` checked (every load), read by mrvi_batch_section_read. */
int mrvi_ld_batch(loader *L, struct fy_node *batch);

/* ---------------------------------------------------------------------------
 * Errors at marks (read.c)
 * ------------------------------------------------------------------------- */
/* A libfyaml diag object that collects errors and prints nothing. */
struct fy_diag *mrvi_ld_diag_create(void);
/* The override that created n or one of its ancestors, or NULL. */
const char *mrvi_ld_override_of(const loader *L, struct fy_node *n);
/* 1-based line and column of a node; 0 when it has none. */
int mrvi_ld_node_position(struct fy_node *n, int *line, int *col);
/* Write "file:line:col: message" (or "--set KEY=VALUE: message") at the
 * node `at` (NULL: the document, 1:1) and return MRVI_EPARSE. */
int mrvi_ld_fail(loader *L, struct fy_node *at, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
int mrvi_ld_fail_nomem(loader *L);
/* Builder failure: the model's message at the element's node.  Never an
 * empty message: without one from the model (or for a status that is not
 * an error) it names the loader function `fn` and the status. */
int mrvi_ld_fail_model_in(loader *L, struct fy_node *at, int status,
                          const char *fn);
#define mrvi_ld_fail_model(L, at, status)                                      \
  mrvi_ld_fail_model_in(L, at, status, __func__)
/* First collected libfyaml error, as file:line:col: message. */
int mrvi_ld_syntax_error(loader *L);
/* "; did you mean 'x'?" or "; known: a, b, c" into buf. */
void mrvi_ld_suggest(char *buf, size_t len, const char *word,
                     const char *const *cand, int n);
/* Append a line to sys->notes (shown by `mrvi check`). */
int mrvi_ld_add_note(loader *L, const char *fmt, ...)
    __attribute__((format(printf, 2, 3)));

/* ---------------------------------------------------------------------------
 * Typed access to nodes (read.c); `what` names the value in messages
 * ------------------------------------------------------------------------- */
const char *mrvi_ld_scalar0(struct fy_node *n); /* "" when not a scalar */
int mrvi_ld_is_null(struct fy_node *n);         /* YAML 1.2 null */
/* Pair of a mapping whose key is the scalar `key`, or NULL. */
struct fy_node_pair *mrvi_ld_find_pair(struct fy_node *map, const char *key);
/* Value of `key` in a mapping, NULL if absent or null. */
struct fy_node *mrvi_ld_get(struct fy_node *map, const char *key);
/* Required value of `key`; `where` names the mapping for the message. */
int mrvi_ld_need(loader *L, struct fy_node *map, const char *key,
                 const char *where, struct fy_node **out);
int mrvi_ld_want_mapping(loader *L, struct fy_node *n, const char *what);
int mrvi_ld_want_list(loader *L, struct fy_node *n, const char *what);
int mrvi_ld_as_number(loader *L, struct fy_node *n, const char *what,
                      double *out);
int mrvi_ld_as_int(loader *L, struct fy_node *n, const char *what, int *out);
int mrvi_ld_as_bool(loader *L, struct fy_node *n, const char *what, int *out);
int mrvi_ld_as_string(loader *L, struct fy_node *n, const char *what,
                      const char **out);
/* One of names[0..count); *out gets its index. */
int mrvi_ld_as_choice(loader *L, struct fy_node *n, const char *what,
                      const char *const *names, int count, int *out);
/* Exactly `dim` finite numbers (a bare number when dim is 1). */
int mrvi_ld_as_vector(loader *L, struct fy_node *n, const char *what, int dim,
                      double *out);
/* A unit vector of `dim` entries (an axis, a quaternion): finite, its
 * length 1 within 1e-6 (as a rotation matrix's R^T R = I is checked), then
 * normalised to round-off; a zero or non-unit vector is refused. */
int mrvi_ld_as_unit(loader *L, struct fy_node *n, const char *what, int dim,
                    double *out);
/* `key: slow | fast` (default slow). */
int mrvi_ld_as_rate(loader *L, struct fy_node *map, const char *key,
                    mrvi_rate *out);
/* Optional number with a default. */
int mrvi_ld_opt_number(loader *L, struct fy_node *map, const char *key,
                       double def, double *out);
/* Optional number > 0 (*out left alone when absent; *node may be NULL). */
int mrvi_ld_opt_positive(loader *L, struct fy_node *map, const char *key,
                         const char *what, double *out, struct fy_node **node);
/* Every key of `map` must be in keys[0..n) or extra[0..n_extra). */
int mrvi_ld_check_keys(loader *L, struct fy_node *map, const char *where,
                       const char *const *keys, int n, const char *const *extra,
                       int n_extra);

/* ---------------------------------------------------------------------------
 * Names (names.c)
 * ------------------------------------------------------------------------- */
int mrvi_ld_hash_put(name_hash *h, const char *name, int value);
void mrvi_ld_hash_free(name_hash *h);
const named *mrvi_ld_find_named(const named *tab, const name_hash *h,
                                const char *name);
/* `name:` of a new coordinate or particle (`kind`), rejecting duplicates. */
int mrvi_ld_new_name(loader *L, struct fy_node *item, const char *where,
                     const char *kind, const named *tab, const name_hash *h,
                     struct fy_node **name_node, const char **name);
/* Particle index / model coordinate index named by the string node n. */
int mrvi_ld_find_particle(loader *L, struct fy_node *n, const char *what,
                          int *index);
int mrvi_ld_find_coordinate(loader *L, struct fy_node *n, const char *what,
                            int *index);

/* ---------------------------------------------------------------------------
 * What elements share (elements.c)
 * ------------------------------------------------------------------------- */
/* `law:` and its parameters (keys of the item besides keys[0..n_keys)). */
int mrvi_ld_law(loader *L, struct fy_node *item, const char *where,
                const char *const *keys, int n_keys, const mrvi_law **law,
                double *params);
/* `combination: {coordinate: coefficient, ...}` (non-empty). */
int mrvi_ld_combination(loader *L, struct fy_node *comb, int *coords,
                        double *coef, int *k);
/* `key: [a, b]`, or `key: [a]` with `anchor_key:` (dim numbers), as
 * `between:` and `anchor:` of a spring; *ends is 1 or 2.  With points
 * (2 entries, may be NULL: particles only) an end may also be a body point
 * (`{body: NAME, at: [..]}` or a body's name): points[e] gets every end and
 * pi[e] is -1 for a body point. */
/* One end at node n that may be a body point (`{body: NAME, at: [..]}` or
 * a body's name); a scalar naming no body leaves p->particle = 0 for
 * mrvi_ld_find_particle. */
int mrvi_ld_end_point(loader *L, struct fy_node *n, const char *key, int dim,
                      mrvi_end *p);
int mrvi_ld_ends(loader *L, struct fy_node *item, const char *where,
                 const char *noun, const char *key, const char *anchor_key,
                 int dim, int pi[2], mrvi_end *points, int *ends,
                 double *anchor);

/* ---------------------------------------------------------------------------
 * Overrides (overrides.c) and limits on hostile input (limits.c)
 * ------------------------------------------------------------------------- */
/* Apply one override "dotted.key=value" to the document. */
int mrvi_ld_apply_override(loader *L, const char *text);
/* Text of the description after the overrides (malloc'd; NULL: no memory). */
char *mrvi_ld_description_text(loader *L, const char *text,
                               const char *const *overrides, int n_ov);
/* Offset of the first byte that is not printable YAML text, or -1. */
long mrvi_ld_first_invalid(const char *text, size_t n, int *line, int *col,
                           long *code);
void mrvi_ld_describe_invalid(char *buf, size_t len, const char *text, long at,
                              long code);
/* Any alias in the tree at n, or NULL. */
struct fy_node *mrvi_ld_find_alias(struct fy_node *n);
/* The text is printable UTF-8 of bounded size. */
int mrvi_ld_check_text(loader *L, const char *text);
/* Bound what aliases add, then resolve them and merge keys. */
int mrvi_ld_resolve_aliases(loader *L);

#endif
