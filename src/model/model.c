/* Model builder: coordinates, particles, potential elements, partition. */
#include "model/model.h"

#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int mrvi_model_fail(mrvi_model *m, int status, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(m->errmsg, sizeof m->errmsg, fmt, ap);
  va_end(ap);
  return status;
}

/* Grow *p (elements of size sz) so that it holds at least need entries. */
static int grow(void **p, int *cap, int need, size_t sz) {
  if (need <= *cap)
    return 0;
  int c = *cap ? *cap : 8;
  while (c < need) /* (doubled up to INT_MAX: an int count never wraps) */
    c = c > INT_MAX / 2 ? INT_MAX : 2 * c;
  void *q = realloc(*p, (size_t)c * sz);
  if (!q)
    return -1;
  *p = q;
  *cap = c;
  return 0;
}

mrvi_model *mrvi_model_create(void) {
  mrvi_model *m = calloc(1, sizeof *m);
  if (!m)
    return NULL;
  m->name = strdup("model");
  if (!m->name) {
    free(m);
    return NULL;
  }
  return m;
}

/* Release the constraint instances of m. */
static void free_constraints(mrvi_model *m) {
  for (int c = 0; c < m->n_constraints; c++) {
    free(m->constraints[c].label);
    free(m->constraints[c].in);
    free(m->constraints[c].params);
  }
  free(m->constraints);
  m->constraints = NULL;
  m->n_constraints = m->cap_constraints = 0;
}

void mrvi_model_free(mrvi_model *m) {
  if (!m)
    return;
  for (int i = 0; i < m->n_blocks; i++)
    free(m->blocks[i]);
  free(m->blocks);
  for (int e = 0; e < m->n_full; e++) {
    free(m->full[e].coef);
    if (m->full[e].kind == MRVI_ELEMENT_TORSION)
      free(m->full[e].axes);
  }
  free(m->own_names);
  free(m->own_coord);
  for (int r = 0; r < m->n_rules; r++)
    free(m->rules[r].prefix);
  free(m->rules);
  free(m->mass);
  free(m->q0);
  free(m->v0);
  free(m->rate);
  free(m->particles);
  free(m->erecs);
  free(m->full);
  for (int i = 0; i < m->n_protos; i++)
    free(m->protos[i]);
  free(m->protos);
  free(m->proto_table);
  free_constraints(m);
  mrvi_model_free_bodies(m);
  free(m->slow_index);
  free(m->fast_index);
  free(m->slot);
  for (int i = 0; i < m->n_param_sets; i++)
    free(m->param_sets[i]);
  free(m->param_sets);
  free(m->param_table);
  free(m->coord_table);
  free(m->particle_table);
  free(m->name);
  free(m);
}

const char *mrvi_model_errmsg(const mrvi_model *m) {
  return m ? m->errmsg : "no model";
}

int mrvi_model_set_name(mrvi_model *m, const char *name) {
  if (!name)
    return mrvi_model_fail(m, MRVI_EINVAL, "model name is NULL");
  char *d = strdup(name);
  if (!d)
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  free(m->name);
  m->name = d;
  return MRVI_OK;
}

int mrvi_model_set_dimension(mrvi_model *m, int dimension) {
  if (dimension < 1 || dimension > 3)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "dimension must be 1, 2 or 3 (got %d)", dimension);
  if ((m->n_particles > 0 || m->n_bodies > 0) && dimension != m->dimension)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "dimension cannot change after particles or bodies "
                           "were added");
  m->dimension = dimension;
  return MRVI_OK;
}

static void fnv(unsigned long long *h, const void *data, size_t n) {
  const unsigned char *b = data;
  for (size_t i = 0; i < n; i++) {
    *h ^= b[i];
    *h *= 1099511628211ULL;
  }
}

/* ---------------------------------------------------------------------------
 * Name tables: open addressing (linear probing) on an FNV-1a hash, load at
 * most 1/2, so that building a model with n names costs O(n).
 * ------------------------------------------------------------------------- */
/* Entries a table (names, parameter sets, spring prototypes) holds at most:
 * its power-of-two capacity, at least twice the count, stays an int. */
#define TABLE_MAX (INT_MAX / 4)

static unsigned long name_hash(const char *s, size_t len) {
  unsigned long h = 2166136261UL;
  for (size_t i = 0; i < len; i++)
    h = (h ^ (unsigned char)s[i]) * 16777619UL;
  return h;
}

/* Index of the entry named by the len characters of `name` (name_of), or
 * -1. */
static int table_find(const int *table, int cap, const char *name, size_t len,
                      const char *(*name_of)(const mrvi_model *, int),
                      const mrvi_model *m) {
  if (!table)
    return -1;
  for (unsigned long h = name_hash(name, len) & (unsigned long)(cap - 1);;
       h = (h + 1) & (unsigned long)(cap - 1)) {
    if (table[h] == 0)
      return -1;
    const char *t = name_of(m, table[h] - 1);
    if (strncmp(t, name, len) == 0 && t[len] == '\0')
      return table[h] - 1;
  }
}

static void table_put(int *table, int cap, const char *name, int index) {
  unsigned long h = name_hash(name, strlen(name)) & (unsigned long)(cap - 1);
  while (table[h] != 0)
    h = (h + 1) & (unsigned long)(cap - 1);
  table[h] = index + 1;
}

/* Make room for count + 1 entries (rehashing the count entries: the
 * indices i < n_index for which in_table is 1, or all of them without
 * in_table). */
static int table_reserve(int **table, int *cap, int count, int n_index,
                         int (*in_table)(const mrvi_model *, int),
                         const char *(*name_of)(const mrvi_model *, int),
                         const mrvi_model *m) {
  if (2 * (count + 1) <= *cap)
    return 0;
  if (count >= TABLE_MAX)
    return -1;
  int c = *cap ? 2 * *cap : 64;
  while (2 * (count + 1) > c)
    c *= 2;
  int *t = calloc((size_t)c, sizeof *t);
  if (!t)
    return -1;
  for (int i = 0; i < n_index; i++)
    if (!in_table || in_table(m, i))
      table_put(t, c, name_of(m, i), i);
  free(*table);
  *table = t;
  *cap = c;
  return 0;
}

/* Room for one more particle record, the records of the particles before
 * it made where none were kept (each {NULL, p * dimension}); nonzero when
 * out of memory. */
static int keep_particles(mrvi_model *m) {
  if (grow((void **)&m->particles, &m->cap_particles, m->n_particles + 1,
           sizeof *m->particles))
    return 1;
  if (!m->particles_kept)
    for (int p = 0; p < m->n_particles; p++)
      m->particles[p] = (mrvi_particle){NULL, p * m->dimension};
  m->particles_kept = 1;
  return 0;
}

static const char *own_name(const mrvi_model *m, int k) {
  return m->own_names[k];
}
static const char *particle_name(const mrvi_model *m, int i) {
  return mrvi_particle_stored(m, i);
}
static int has_stored_name(const mrvi_model *m, int i) {
  return mrvi_particle_stored(m, i) != NULL;
}

/* Particle owning coordinate c, or -1: particles are added with fresh
 * coordinates, so their first coordinates increase with the particle
 * index. */
static int particle_of(const mrvi_model *m, int c) {
  int lo = 0, hi = m->n_particles - 1, p = -1;
  while (lo <= hi) { /* the last particle whose first is <= c */
    const int mid = lo + (hi - lo) / 2;
    if (mrvi_particle_first(m, mid) <= c) {
      p = mid;
      lo = mid + 1;
    } else {
      hi = mid - 1;
    }
  }
  return p >= 0 && c < mrvi_particle_first(m, p) + m->dimension ? p : -1;
}

/* The unsigned decimal number at *s (no sign, at most 9 digits), or -1;
 * *s moves past it. */
static long parse_index(const char **s) {
  long v = 0;
  int k = 0;
  for (; **s >= '0' && **s <= '9' && k < 10; (*s)++, k++)
    v = 10 * v + (**s - '0');
  return k == 0 || k > 9 ? -1 : v;
}

/* The particle of rule r named by the len characters of `name`, or -1:
 * the indices after the prefix, checked by making the name again (no
 * leading zeros, no other separators). */
static int rule_find(const mrvi_name_rule *r, const char *name, size_t len) {
  const size_t pl = strlen(r->prefix);
  if (len <= pl || strncmp(name, r->prefix, pl) != 0)
    return -1;
  const int axes = r->kind == MRVI_GEN_LATTICE3D   ? 3
                   : r->kind == MRVI_GEN_LATTICE2D ? 2
                                                   : 1;
  const char *s = name + pl;
  long idx[3] = {0, 0, 0};
  for (int a = 0; a < axes; a++) {
    if (a > 0 && *s++ != '_')
      return -1;
    idx[a] = parse_index(&s);
    if (idx[a] < 0 || (axes > 1 && idx[a] >= r->n[a]))
      return -1;
  }
  if ((size_t)(s - name) != len)
    return -1;
  const long lin = idx[0] + (long)r->n[0] * (idx[1] + (long)r->n[1] * idx[2]);
  if (lin >= r->count)
    return -1;
  char buf[MRVI_NAME_MAX];
  mrvi_generated_name(r->kind, r->prefix, r->n, lin, buf, sizeof buf);
  if (strncmp(buf, name, len) != 0 || buf[len] != '\0')
    return -1;
  return r->first + (int)lin;
}

/* The particle named by the len characters of `name`, or -1: a stored
 * name in the table, else a generated one by its rule. */
static int find_particle_n(const mrvi_model *m, const char *name, size_t len) {
  const int p = table_find(m->particle_table, m->particle_table_cap, name, len,
                           particle_name, m);
  for (int r = 0; p < 0 && r < m->n_rules; r++) {
    const int q = rule_find(&m->rules[r], name, len);
    if (q >= 0)
      return q;
  }
  return p;
}

int mrvi_model_find_particle(const mrvi_model *m, const char *name) {
  return find_particle_n(m, name, strlen(name));
}

const char *mrvi_model_particle_name(const mrvi_model *m, int p, char *buf) {
  if (mrvi_particle_stored(m, p))
    return mrvi_particle_stored(m, p);
  for (int r = 0; r < m->n_rules; r++) {
    const mrvi_name_rule *u = &m->rules[r];
    if (p >= u->first && p < u->first + u->count) {
      mrvi_generated_name(u->kind, u->prefix, u->n, p - u->first, buf,
                          MRVI_NAME_MAX);
      return buf;
    }
  }
  buf[0] = '\0'; /* (not reached: every particle has a name) */
  return buf;
}

/* Own coordinate c's index in own_coord (increasing), or -1. */
static int own_of(const mrvi_model *m, int c) {
  int lo = 0, hi = m->n_own - 1;
  while (lo <= hi) {
    const int mid = lo + (hi - lo) / 2;
    if (m->own_coord[mid] == c)
      return mid;
    if (m->own_coord[mid] < c)
      lo = mid + 1;
    else
      hi = mid - 1;
  }
  return -1;
}

const char *mrvi_model_coordinate_name(const mrvi_model *m, int i, char *buf) {
  static const char axis[3] = {'x', 'y', 'z'};
  if (i < 0 || i >= m->n)
    return NULL;
  const int p = particle_of(m, i), k = p < 0 ? own_of(m, i) : -1;
  if (p < 0)
    return k >= 0 ? m->own_names[k] : NULL;
  char pname[MRVI_NAME_MAX];
  mrvi_fmt(buf, MRVI_NAME_MAX, "%s.%c", mrvi_model_particle_name(m, p, pname),
           axis[i - mrvi_particle_first(m, p)]);
  return buf;
}

int mrvi_model_find_coordinate(const mrvi_model *m, const char *name) {
  const int k = table_find(m->coord_table, m->coord_table_cap, name,
                           strlen(name), own_name, m);
  if (k >= 0)
    return m->own_coord[k];
  static const char axes[] = "xyz";
  const char *dot = strrchr(name, '.');
  if (!dot || dot == name || !dot[1] || dot[2])
    return -1;
  const char *a = strchr(axes, dot[1]);
  if (!a || a - axes >= m->dimension)
    return -1;
  const int p = find_particle_n(m, name, (size_t)(dot - name));
  if (p < 0)
    return -1;
  const int pc = mrvi_particle_first(m, p) + (int)(a - axes);
  char buf[MRVI_NAME_MAX]; /* (a name cut at MRVI_NAME_MAX is not found) */
  return strcmp(mrvi_model_coordinate_name(m, pc, buf), name) == 0 ? pc : -1;
}

/* Extend the slow/fast index maps by the coordinate just appended (the
 * arrays have m->cap entries, reserve_coordinates). */
static void update_partition(mrvi_model *m) {
  const int i = m->n - 1;
  if (m->rate[i] == MRVI_SLOW) {
    m->slot[i] = m->n_slow;
    m->slow_index[m->n_slow++] = i;
  } else {
    m->slot[i] = m->n_fast;
    m->fast_index[m->n_fast++] = i;
  }
}

/* Make room for `need` coordinates in every per-coordinate array. */
static int reserve_coordinates(mrvi_model *m, int need) {
  if (need <= m->cap)
    return 0;
  int c = m->cap ? (m->cap > INT_MAX / 2 ? INT_MAX : 2 * m->cap) : 16;
  if (c < need)
    c = need;
  void *b = realloc(m->mass, (m->mass_inc ? (size_t)c : 1) * sizeof *m->mass);
  if (b)
    m->mass = b;
  void *q = realloc(m->q0, (size_t)c * sizeof *m->q0);
  if (q)
    m->q0 = q;
  void *v = realloc(m->v0, (size_t)c * sizeof *m->v0);
  if (v)
    m->v0 = v;
  void *r = realloc(m->rate, (size_t)c * sizeof *m->rate);
  if (r)
    m->rate = r;
  void *si = realloc(m->slow_index, (size_t)c * sizeof *m->slow_index);
  if (si)
    m->slow_index = si;
  void *fi = realloc(m->fast_index, (size_t)c * sizeof *m->fast_index);
  if (fi)
    m->fast_index = fi;
  void *sl = realloc(m->slot, (size_t)c * sizeof *m->slot);
  if (sl)
    m->slot = sl;
  if (!b || !q || !v || !r || !si || !fi || !sl)
    return -1;
  m->cap = c;
  return 0;
}

/* `bytes` in the model's blocks (freed with the model), aligned for int,
 * or NULL when out of memory: a block holds the names and inputs of many
 * coordinates and elements, without the allocator's per-allocation
 * overhead. */
static void *block_alloc(mrvi_model *m, size_t bytes) {
  bytes = (bytes + sizeof(int) - 1) / sizeof(int) * sizeof(int);
  if (m->n_blocks == 0 || m->block_used + bytes > m->block_cap) {
    const size_t cap = bytes > 65536 ? bytes : 65536;
    char *b = malloc(cap);
    if (!b || grow((void **)&m->blocks, &m->cap_blocks, m->n_blocks + 1,
                   sizeof *m->blocks)) {
      free(b);
      return NULL;
    }
    m->blocks[m->n_blocks++] = b;
    m->block_used = 0;
    m->block_cap = cap;
  }
  char *d = m->blocks[m->n_blocks - 1] + m->block_used;
  m->block_used += bytes;
  return d;
}

static char *store_name(mrvi_model *m, const char *name) {
  const size_t len = strlen(name) + 1;
  char *d = block_alloc(m, len);
  if (d)
    memcpy(d, name, len);
  return d;
}

int *mrvi_model_inputs(mrvi_model *m, int n) {
  return block_alloc(m, (size_t)(n > 0 ? n : 1) * sizeof(int));
}

/* Append a coordinate; in_table: a coordinate of its own (not a
 * particle's), its name stored and in the coordinate table. */
static int add_coord(mrvi_model *m, const char *name, double mass,
                     mrvi_rate rate, double q0, double v0, int in_table) {
  if (!name || !*name)
    return mrvi_model_fail(m, MRVI_EINVAL, "coordinate name is empty");
  if (!isfinite(mass) || mass <= 0)
    return mrvi_model_fail(
        m, MRVI_EINVAL, "mass of '%s' must be positive (got %g)", name, mass);
  if (!isfinite(q0) || !isfinite(v0))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "initial data of '%s' must be finite", name);
  if (rate != MRVI_SLOW && rate != MRVI_FAST)
    return mrvi_model_fail(m, MRVI_EINVAL, "rate of '%s' must be slow or fast",
                           name);
  if (mrvi_model_find_coordinate(m, name) >= 0)
    return mrvi_model_fail(m, MRVI_EINVAL, "duplicate coordinate name '%s'",
                           name);
  if (reserve_coordinates(m, m->n + 1) ||
      (in_table && (table_reserve(&m->coord_table, &m->coord_table_cap,
                                  m->n_own, m->n_own, NULL, own_name, m) ||
                    grow((void **)&m->own_names, &m->cap_own, m->n_own + 1,
                         sizeof *m->own_names))))
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  if (in_table) { /* (own_coord: the capacity of own_names) */
    void *oc = realloc(m->own_coord, (size_t)m->cap_own * sizeof *m->own_coord);
    char *d = oc ? store_name(m, name) : NULL;
    if (oc)
      m->own_coord = oc;
    if (!d)
      return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
    m->own_names[m->n_own] = d;
    m->own_coord[m->n_own] = m->n;
    table_put(m->coord_table, m->coord_table_cap, d, m->n_own);
    m->n_own++;
  }
  if (m->mass_inc == 0 && m->n > 0 && mass != m->mass[0]) {
    /* (the first mass that differs: every entry kept from here on) */
    double *b = realloc(m->mass, (size_t)m->cap * sizeof *m->mass);
    if (!b)
      return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
    for (int i = 1; i < m->n; i++)
      b[i] = b[0];
    m->mass = b;
    m->mass_inc = 1;
  }
  m->mass[(size_t)m->n * (size_t)m->mass_inc] = mass;
  m->q0[m->n] = q0;
  m->v0[m->n] = v0;
  m->rate[m->n] = rate;
  m->n++;
  update_partition(m);
  return m->n - 1;
}

int mrvi_model_add_coordinate(mrvi_model *m, const char *name, double mass,
                              mrvi_rate rate, double q0, double v0) {
  return add_coord(m, name, mass, rate, q0, v0, 1);
}

/* Whether `name` is PREFIX + k (k decimal, no leading zero, below 10^9:
 * what rule_find reads back) that a sequence rule makes: 1 where the last
 * rule is the sequence of PREFIX that ends at the next particle and k its
 * next index, 2 where k is 0 and a new sequence may start (fewer than
 * MRVI_SEQUENCE_RULES), else 0 (the name is stored). */
static int sequence_name(const mrvi_model *m, const char *name) {
  const size_t len = strlen(name);
  size_t pl = len;
  while (pl > 0 && name[pl - 1] >= '0' && name[pl - 1] <= '9')
    pl--;
  const size_t digits = len - pl;
  if (pl == 0 || pl > MRVI_RULE_PREFIX_MAX || digits == 0 || digits > 9 ||
      (digits > 1 && name[pl] == '0'))
    return 0;
  const char *s = name + pl;
  const long k = parse_index(&s);
  int seq = 0;
  for (int r = 0; r < m->n_rules; r++)
    seq += m->rules[r].kind == MRVI_RULE_SEQUENCE;
  const mrvi_name_rule *u = m->n_rules ? &m->rules[m->n_rules - 1] : NULL;
  if (u && u->kind == MRVI_RULE_SEQUENCE && k == u->count &&
      u->first + u->count == m->n_particles && strlen(u->prefix) == pl &&
      strncmp(u->prefix, name, pl) == 0)
    return 1;
  return k == 0 && seq < MRVI_SEQUENCE_RULES ? 2 : 0;
}

/* mrvi_model_add_particle; ruled: named by the last rule (not stored). */
static int add_particle(mrvi_model *m, const char *name, double mass,
                        mrvi_rate rate, const double *x0, const double *v0,
                        int ruled) {
  static const char axis[3] = {'x', 'y', 'z'};
  if (m->dimension < 1)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "set the dimension before adding particles");
  if (!name || !*name || strchr(name, '.'))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "particle name '%s' is empty or contains '.'",
                           name ? name : "");
  if (!x0 || !v0)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "particle '%s' needs position and velocity", name);
  if (mrvi_model_find_particle(m, name) >= 0)
    return mrvi_model_fail(m, MRVI_EINVAL, "duplicate particle name '%s'",
                           name);
  if (mrvi_model_find_body(m, name) >= 0)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "particle '%s': a body has that name", name);
  if (!isfinite(mass) || mass <= 0)
    return mrvi_model_fail(
        m, MRVI_EINVAL, "mass of '%s' must be positive (got %g)", name, mass);
  /* (PREFIX0, PREFIX1, ...: named by a sequence rule, not stored) */
  const int seq = ruled ? 0 : sequence_name(m, name);
  ruled = ruled || seq;
  if (!ruled && table_reserve(&m->particle_table, &m->particle_table_cap,
                              m->n_particle_table, m->n_particles,
                              has_stored_name, particle_name, m))
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  /* (a particle whose name is not stored and whose first coordinate is
   * its index times the dimension needs no record while every one before
   * it is such: m->particles_kept) */
  if ((m->particles_kept || !ruled || m->n != m->n_particles * m->dimension) &&
      keep_particles(m))
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  char *pname = ruled ? NULL : store_name(m, name);
  if (!ruled && !pname)
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  if (seq == 2) { /* (a new sequence: PREFIX0) */
    char prefix[MRVI_RULE_PREFIX_MAX + 1];
    mrvi_fmt(prefix, sizeof prefix, "%.*s", (int)(strlen(name) - 1), name);
    const int n1[3] = {INT_MAX, 1, 1};
    if (mrvi_model_add_rule(m, MRVI_RULE_SEQUENCE, prefix, n1) < 0)
      return MRVI_ENOMEM;
  }
  int first = m->n;
  for (int d = 0; d < m->dimension; d++) {
    char buf[256];
    mrvi_fmt(buf, sizeof buf, "%s.%c", name, axis[d]);
    int st = add_coord(m, buf, mass, rate, x0[d], v0[d], 0);
    if (st < 0) { /* (its coordinates go: they have no name without it) */
      while (m->n > first)
        m->rate[--m->n] == MRVI_SLOW ? m->n_slow-- : m->n_fast--;
      if (seq == 2) /* (and the sequence it began) */
        free(m->rules[--m->n_rules].prefix);
      return st;
    }
  }
  if (m->particles_kept)
    m->particles[m->n_particles] = (mrvi_particle){pname, first};
  if (ruled) {
    m->rules[m->n_rules - 1].count++;
  } else {
    table_put(m->particle_table, m->particle_table_cap, pname, m->n_particles);
    m->n_particle_table++;
  }
  return m->n_particles++;
}

int mrvi_model_add_particle(mrvi_model *m, const char *name, double mass,
                            mrvi_rate rate, const double *x0,
                            const double *v0) {
  return add_particle(m, name, mass, rate, x0, v0, 0);
}

int mrvi_model_add_ruled_particle(mrvi_model *m, const char *name, double mass,
                                  mrvi_rate rate, const double *x0,
                                  const double *v0) {
  return add_particle(m, name, mass, rate, x0, v0, 1);
}

int mrvi_model_room(const mrvi_model *m, double particles, double springs,
                    double *bytes, char *msg, size_t len) {
  const double d = m->dimension > 0 ? m->dimension : 1;
  const double n = m->n + d * particles, np = m->n_particles + particles,
               ne = m->n_elements + springs;
  if (n > INT_MAX || np > INT_MAX || ne > INT_MAX)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "the model would have %.0f coordinates, %.0f "
                     "particles and %.0f elements: more than %d of one kind",
                     n, np, ne, INT_MAX);
  /* the per-coordinate arrays (mass, q0, v0, rate, slow_index, fast_index,
   * slot), the particles, the element records */
  const double per_coord =
      3.0 * sizeof(double) + sizeof *m->rate + 3.0 * sizeof(int);
  if (bytes)
    *bytes =
        per_coord * n + sizeof(mrvi_particle) * np + sizeof(mrvi_erec) * ne;
  return MRVI_OK;
}

int mrvi_model_reserve(mrvi_model *m, int particles, int elements) {
  const int d = m->dimension > 0 ? m->dimension : 1;
  if (particles < 0 || elements < 0)
    return mrvi_model_fail(m, MRVI_EINVAL, "reserve: negative count");
  const int st = mrvi_model_room(m, particles, elements, NULL, m->errmsg,
                                 sizeof m->errmsg);
  if (st < 0)
    return st;
  if (reserve_coordinates(m, m->n + d * particles) ||
      (m->particles_kept &&
       grow((void **)&m->particles, &m->cap_particles,
            m->n_particles + particles, sizeof *m->particles)) ||
      grow((void **)&m->erecs, &m->cap_elements, m->n_elements + elements,
           sizeof *m->erecs))
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  return MRVI_OK;
}

int mrvi_model_add_rule(mrvi_model *m, int kind, const char *prefix,
                        const int n[3]) {
  char *d = strdup(prefix);
  if (!d || grow((void **)&m->rules, &m->cap_rules, m->n_rules + 1,
                 sizeof *m->rules)) {
    free(d);
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  }
  m->rules[m->n_rules++] =
      (mrvi_name_rule){d, kind, {n[0], n[1], n[2]}, m->n_particles, 0};
  return MRVI_OK;
}

char *mrvi_model_names(const mrvi_model *m, int particles, const char **out) {
  const int count = particles ? m->n_particles : m->n;
  size_t bytes = 1;
  char buf[MRVI_NAME_MAX];
  for (int i = 0; i < count; i++) { /* (the names made here: their room) */
    const int made =
        particles ? !mrvi_particle_stored(m, i) : particle_of(m, i) >= 0;
    if (made)
      bytes += strlen(particles ? mrvi_model_particle_name(m, i, buf)
                                : mrvi_model_coordinate_name(m, i, buf)) +
               1;
  }
  char *block = malloc(bytes), *at = block;
  for (int i = 0; block && i < count; i++) {
    const char *s = particles ? mrvi_model_particle_name(m, i, buf)
                              : mrvi_model_coordinate_name(m, i, buf);
    if (s == buf) {
      const size_t len = strlen(s) + 1;
      memcpy(at, s, len);
      out[i] = at;
      at += len;
    } else {
      out[i] = s;
    }
  }
  return block;
}

/* Release what element e (not yet pushed) owns. */
static void drop_element(mrvi_element *e) {
  free(e->coef);
  if (e->kind == MRVI_ELEMENT_TORSION)
    free(e->axes);
}

/* Hash of a spring's law, parameter set (interned: its address) and rate. */
static size_t proto_hash(const mrvi_element *e) {
  unsigned long long h = 14695981039346656037ULL;
  fnv(&h, &e->law, sizeof e->law);
  fnv(&h, &e->params, sizeof e->params);
  fnv(&h, &e->potential, sizeof e->potential);
  return (size_t)h;
}

/* NOT_COMPACT: an element kept in full; BEYOND_PROTOS: a spring that would
 * be compact but its law is one beyond MRVI_EREC_LP_MAX prototypes (kept
 * in full too). */
enum { NOT_COMPACT = -1000, BEYOND_PROTOS = -1001 };
/* (the record's fields: lp's 24 bits, kind's 4, potential's 1) */
_Static_assert(MRVI_EREC_LP_MAX >= 1 && MRVI_EREC_LP_MAX <= (1 << 24),
               "a prototype index beyond the record's 24 bits");
_Static_assert(MRVI_ELEMENT_TORSION < 16, "an element kind beyond 4 bits");
_Static_assert(MRVI_SLOW < 2 && MRVI_FAST < 2, "a rate beyond 1 bit");
_Static_assert(sizeof(mrvi_erec) == 20, "the element record is 20 bytes");
/* The prototype of e's law, parameters and rate (kind spring, no inputs,
 * rest length NaN), made if new; its index, BEYOND_PROTOS beyond
 * MRVI_EREC_LP_MAX prototypes. */
static int spring_proto(mrvi_model *m, const mrvi_element *e) {
  if (2 * (m->n_protos + 1) > m->proto_table_cap) {
    const int c = m->proto_table_cap ? 2 * m->proto_table_cap : 16;
    int *t = calloc((size_t)c, sizeof *t);
    if (!t)
      return MRVI_ENOMEM;
    free(m->proto_table);
    m->proto_table = t;
    m->proto_table_cap = c;
    for (int i = 0; i < m->n_protos; i++) {
      size_t k = proto_hash(m->protos[i]) & (size_t)(c - 1);
      while (t[k] != 0)
        k = (k + 1) & (size_t)(c - 1);
      t[k] = i + 1;
    }
  }
  const size_t mask = (size_t)(m->proto_table_cap - 1);
  size_t k = proto_hash(e) & mask;
  for (; m->proto_table[k] != 0; k = (k + 1) & mask) {
    const mrvi_element *p = m->protos[m->proto_table[k] - 1];
    if (p->law == e->law && p->params == e->params &&
        p->potential == e->potential)
      return m->proto_table[k] - 1;
  }
  /* (the record's 24 bits: a further law's springs are kept in full) */
  if (m->n_protos >= MRVI_EREC_LP_MAX)
    return BEYOND_PROTOS;
  mrvi_element *p = malloc(sizeof *p);
  if (!p || grow((void **)&m->protos, &m->cap_protos, m->n_protos + 1,
                 sizeof *m->protos)) {
    free(p);
    return MRVI_ENOMEM;
  }
  m->protos[m->n_protos] = p;
  *p = (mrvi_element){.law = e->law,
                      .params = e->params,
                      .shift = NAN,
                      .n_in = e->n_in,
                      .kind = MRVI_ELEMENT_SPRING,
                      .potential = e->potential,
                      .form = e->form};
  m->proto_table[k] = m->n_protos + 1;
  return m->n_protos++;
}

/* The prototype index of e if it is kept in its record alone (a spring of
 * a law between two particles' consecutive coordinates, no coefficients),
 * else NOT_COMPACT or BEYOND_PROTOS; MRVI_ENOMEM. */
static int compact_spring(mrvi_model *m, const mrvi_element *e) {
  const int d = m->dimension;
  if (e->kind != MRVI_ELEMENT_SPRING || e->coef || !e->law || !e->params ||
      d < 1 || d > 3 || e->n_in != 2 * d || e->proto)
    return NOT_COMPACT;
  for (int k = 0; k < d; k++)
    if (e->in[k] != e->in[0] + k || e->in[d + k] != e->in[d] + k)
      return NOT_COMPACT;
  return spring_proto(m, e);
}

/* Append an element whose inputs are already set; checks the rate rule. */
static int push_element(mrvi_model *m, mrvi_element *e, const char *what) {
  if (e->potential != MRVI_SLOW && e->potential != MRVI_FAST) {
    drop_element(e);
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: potential must be slow or fast",
                           what);
  }
  if (e->potential == MRVI_FAST)
    for (int j = 0; j < e->n_in; j++)
      if (m->rate[e->in[j]] == MRVI_SLOW) {
        int c = e->in[j];
        drop_element(e);
        return mrvi_model_fail(
            m, MRVI_EMODEL,
            "fast %s touches slow coordinate '%s': the fast potential "
            "W may depend on fast coordinates only; to couple slow and "
            "fast particles make it slow ('potential: slow'), i.e. part "
            "of V, which the default micro slow grid evaluates at every "
            "micro step",
            what, MRVI_CNAME(m, c));
      }
  int lp = compact_spring(m, e);
  /* A spring beyond the prototypes is kept in full: its inputs, which a
   * compact spring's caller may pass on its stack (mrvi_model_add_spring),
   * copied into the model's blocks. */
  if (lp == BEYOND_PROTOS) {
    int *in = mrvi_model_inputs(m, e->n_in);
    if (in)
      memcpy(in, e->in, (size_t)e->n_in * sizeof *in);
    e->in = in;
    lp = in ? NOT_COMPACT : MRVI_ENOMEM;
  }
  if ((lp < 0 && lp != NOT_COMPACT) ||
      grow((void **)&m->erecs, &m->cap_elements, m->n_elements + 1,
           sizeof *m->erecs) ||
      (lp < 0 &&
       grow((void **)&m->full, &m->cap_full, m->n_full + 1, sizeof *m->full))) {
    drop_element(e);
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  }
  if (e->kind != MRVI_ELEMENT_GRAVITY && e->n_in > m->max_in)
    m->max_in = e->n_in;
  mrvi_erec *r = &m->erecs[m->n_elements];
  *r = (mrvi_erec){.kind = e->kind, .potential = e->potential};
  if (lp >= 0) {
    r->shift = e->shift;
    r->lp = (unsigned)lp;
    r->ci = e->in[0];
    r->cj = e->in[m->dimension];
    r->compact = 1;
  } else {
    r->ci = m->n_full;
    m->full[m->n_full] = *e;
    m->full[m->n_full++].proto = NULL;
  }
  m->n_torsions += e->kind == MRVI_ELEMENT_TORSION;
  return m->n_elements++;
}

int mrvi_model_push_element(mrvi_model *m, mrvi_element *e, const char *what) {
  return push_element(m, e, what);
}

/* Allocate e->in and e->coef (e->n_in entries each). */
static int alloc_inputs(mrvi_model *m, mrvi_element *e) {
  e->in = mrvi_model_inputs(m, e->n_in);
  e->coef = malloc((size_t)e->n_in * sizeof *e->coef);
  if (e->in && e->coef)
    return MRVI_OK;
  free(e->coef);
  return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
}

/* Parameter sets and anchor points: v (MRVI_LAW_MAX_PARAMS values) stored
 * once per model, so that the elements of a network share the few sets they
 * have; NULL when out of memory.  Sets are equal when their bits are (NaN,
 * -0). */
static unsigned long long set_hash(const double *v) {
  unsigned long long h = 14695981039346656037ULL;
  fnv(&h, v, MRVI_LAW_MAX_PARAMS * sizeof *v);
  return h;
}

static const double *intern_params(mrvi_model *m, const double *v) {
  const size_t bytes = MRVI_LAW_MAX_PARAMS * sizeof *v;
  if (m->n_param_sets >= TABLE_MAX)
    return NULL;
  if (2 * (m->n_param_sets + 1) > m->param_table_cap) {
    const int c = m->param_table_cap ? 2 * m->param_table_cap : 64;
    int *t = calloc((size_t)c, sizeof *t);
    if (!t)
      return NULL;
    for (int i = 0; i < m->n_param_sets; i++) {
      size_t h = set_hash(m->param_sets[i]) & (size_t)(c - 1);
      while (t[h] != 0)
        h = (h + 1) & (size_t)(c - 1);
      t[h] = i + 1;
    }
    free(m->param_table);
    m->param_table = t;
    m->param_table_cap = c;
  }
  const size_t mask = (size_t)(m->param_table_cap - 1);
  size_t h = set_hash(v) & mask;
  for (; m->param_table[h] != 0; h = (h + 1) & mask)
    if (memcmp(m->param_sets[m->param_table[h] - 1], v, bytes) == 0)
      return m->param_sets[m->param_table[h] - 1];
  double *set = malloc(bytes);
  if (!set || grow((void **)&m->param_sets, &m->cap_param_sets,
                   m->n_param_sets + 1, sizeof *m->param_sets)) {
    free(set);
    return NULL;
  }
  memcpy(set, v, bytes);
  m->param_sets[m->n_param_sets++] = set;
  m->param_table[h] = m->n_param_sets;
  return set;
}

/* Look up the law and copy and check its parameters. */
int mrvi_model_set_law(mrvi_model *m, mrvi_element *e, const char *law,
                       const double *params, const char *what) {
  e->law = mrvi_law_find(law);
  if (!e->law)
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: unknown law '%s'", what,
                           law ? law : "(null)");
  e->form = e->law->form;
  if (e->law->n_params > 0 && !params)
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: law '%s' needs parameters",
                           what, law);
  double v[MRVI_LAW_MAX_PARAMS] = {0};
  for (int i = 0; i < e->law->n_params; i++)
    v[i] = params[i];
  if (e->law->check) {
    char msg[256] = "";
    if (e->law->check(v, msg, sizeof msg) < 0)
      return mrvi_model_fail(m, MRVI_EINVAL, "%s: %s", what, msg);
  }
  if (!(e->params = intern_params(m, v)))
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  return MRVI_OK;
}

int mrvi_element_particle(const mrvi_model *m, const mrvi_element *e, int j) {
  /* (springs between body points carry their weights in coef) */
  return !e->coef && j >= 0 && j < e->n_in ? particle_of(m, e->in[j]) : -1;
}

static int particle_inputs(mrvi_model *m, mrvi_element *e, int np,
                           const int *parts) {
  const int d = m->dimension;
  e->n_in = np * d;
  e->in = mrvi_model_inputs(m, e->n_in);
  if (!e->in)
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  for (int a = 0; a < np; a++)
    for (int k = 0; k < d; k++)
      e->in[a * d + k] = mrvi_particle_first(m, parts[a]) + k;
  return MRVI_OK;
}

int mrvi_model_add_spring(mrvi_model *m, mrvi_rate potential, int particle_i,
                          int particle_j, const char *law, const double *params,
                          double rest_length) {
  if (particle_i < 0 || particle_i >= m->n_particles || particle_j < 0 ||
      particle_j >= m->n_particles)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "spring: particle index out of range");
  if (particle_i == particle_j)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "spring: both ends are particle '%s'",
                           MRVI_PNAME(m, particle_i));
  if (!isfinite(rest_length))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "spring: rest length must be finite");
  char what[300];
  mrvi_fmt(what, sizeof what, "spring %s-%s", MRVI_PNAME(m, particle_i),
           MRVI_PNAME(m, particle_j));
  mrvi_element e = {.kind = MRVI_ELEMENT_SPRING,
                    .potential = potential,
                    .shift = rest_length};
  int st = mrvi_model_set_law(m, &e, law, params, what);
  if (st < 0)
    return st;
  /* (its inputs on the stack: push_element keeps the spring in its record
   * alone, or copies them where it keeps it in full) */
  int in[6];
  e.n_in = 2 * m->dimension;
  e.in = in;
  for (int k = 0; k < m->dimension; k++) {
    in[k] = mrvi_particle_first(m, particle_i) + k;
    in[m->dimension + k] = mrvi_particle_first(m, particle_j) + k;
  }
  return push_element(m, &e, what);
}

int mrvi_model_add_anchor_spring(mrvi_model *m, mrvi_rate potential,
                                 int particle_i, const double *anchor,
                                 const char *law, const double *params,
                                 double rest_length) {
  if (particle_i < 0 || particle_i >= m->n_particles)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "spring: particle index out of range");
  if (!anchor)
    return mrvi_model_fail(m, MRVI_EINVAL, "spring: anchor is NULL");
  if (!isfinite(rest_length))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "spring: rest length must be finite");
  char what[300];
  mrvi_fmt(what, sizeof what, "spring %s-anchor", MRVI_PNAME(m, particle_i));
  mrvi_element e = {.kind = MRVI_ELEMENT_ANCHOR,
                    .potential = potential,
                    .shift = rest_length};
  double point[MRVI_LAW_MAX_PARAMS] = {0};
  for (int k = 0; k < m->dimension; k++) {
    if (!isfinite(anchor[k]))
      return mrvi_model_fail(m, MRVI_EINVAL, "%s: anchor must be finite", what);
    point[k] = anchor[k];
  }
  if (!(e.anchor = intern_params(m, point)))
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  int st = mrvi_model_set_law(m, &e, law, params, what);
  if (st < 0)
    return st;
  if ((st = particle_inputs(m, &e, 1, &particle_i)) < 0)
    return st;
  return push_element(m, &e, what);
}

/* ---------------------------------------------------------------------------
 * Springs between ends: particles and body points
 * ------------------------------------------------------------------------- */

static int check_end(mrvi_model *m, const mrvi_end *e, const char *what) {
  if (!e)
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: end is NULL", what);
  if (e->particle >= 0) {
    if (e->particle >= m->n_particles)
      return mrvi_model_fail(m, MRVI_EINVAL, "%s: particle index out of range",
                             what);
    return MRVI_OK;
  }
  if (e->body < 0 || e->body >= m->n_bodies)
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: body index out of range", what);
  for (int k = 0; k < m->dimension; k++)
    if (!isfinite(e->at[k]))
      return mrvi_model_fail(m, MRVI_EINVAL,
                             "%s: the point on body '%s' must be finite", what,
                             m->bodies[e->body].name);
  return MRVI_OK;
}

static void end_name(const mrvi_model *m, const mrvi_end *e, char *buf,
                     size_t len) {
  if (e->particle >= 0) {
    mrvi_fmt(buf, len, "%s", MRVI_PNAME(m, e->particle));
    return;
  }
  const double *a = e->at;
  if (m->dimension == 2)
    mrvi_fmt(buf, len, "%s@[%g, %g]", m->bodies[e->body].name, a[0], a[1]);
  else
    mrvi_fmt(buf, len, "%s@[%g, %g, %g]", m->bodies[e->body].name, a[0], a[1],
             a[2]);
}

/* "KIND A-B" (B "anchor" when b is NULL) into buf; MRVI_EINVAL with that
 * label when both ends are points of one body (their distance is
 * constant), else 0.  Springs and distance constraints between ends. */
static int end_pair(mrvi_model *m, const char *kind, const mrvi_end *a,
                    const mrvi_end *b, char *buf, size_t len) {
  char na[128], nb[128] = "anchor";
  end_name(m, a, na, sizeof na);
  if (b)
    end_name(m, b, nb, sizeof nb);
  mrvi_fmt(buf, len, "%s %s-%s", kind, na, nb);
  if (b && a->particle < 0 && b->particle < 0 && a->body == b->body)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "%s: both ends are on body '%s' (their distance is "
                           "constant)",
                           buf, m->bodies[a->body].name);
  return 0;
}

/* The end's position as blocks of D consecutive coordinates with constant
 * weights, x = sum_b w[b] q[first[b] .. first[b] + D): a particle is one
 * block of weight 1, a body point phi (1) and d_i (at[i]).  Returns the
 * number of blocks (at most 4). */
static int end_blocks(const mrvi_model *m, const mrvi_end *e, int *first,
                      double *w) {
  if (e->particle >= 0) {
    first[0] = mrvi_particle_first(m, e->particle);
    w[0] = 1.0;
    return 1;
  }
  const mrvi_body *bd = &m->bodies[e->body];
  first[0] = bd->first;
  w[0] = 1.0;
  for (int i = 0; i < bd->dim; i++) {
    first[1 + i] = bd->first + bd->dim * (1 + i);
    w[1 + i] = e->at[i];
  }
  return 1 + bd->dim;
}

int mrvi_model_end_position(const mrvi_model *m, const mrvi_end *e,
                            const double *q, double *x) {
  if (!e || !q || !x || (e->particle >= m->n_particles) ||
      (e->particle < 0 && (e->body < 0 || e->body >= m->n_bodies)))
    return MRVI_EINVAL;
  int first[4];
  double w[4];
  const int nb = end_blocks(m, e, first, w), D = m->dimension;
  for (int k = 0; k < D; k++) {
    x[k] = 0.0;
    for (int b = 0; b < nb; b++)
      x[k] += w[b] * q[first[b] + k];
  }
  return MRVI_OK;
}

int mrvi_model_add_end_spring(mrvi_model *m, mrvi_rate potential,
                              const mrvi_end *a, const mrvi_end *b,
                              const double *anchor, const char *law,
                              const double *params, double rest_length) {
  int st;
  if ((st = check_end(m, a, "spring")) < 0 ||
      (b && (st = check_end(m, b, "spring")) < 0))
    return st;
  if (!b && !anchor)
    return mrvi_model_fail(m, MRVI_EINVAL, "spring: anchor is NULL");
  const int D = m->dimension;
  double xa[3], xb[3] = {0, 0, 0};
  mrvi_model_end_position(m, a, m->q0, xa);
  if (b)
    mrvi_model_end_position(m, b, m->q0, xb);
  for (int k = 0; !b && k < D; k++)
    xb[k] = anchor[k];
  if (isnan(rest_length)) {
    rest_length = 0.0;
    for (int k = 0; k < D; k++)
      rest_length += (xa[k] - xb[k]) * (xa[k] - xb[k]);
    rest_length = sqrt(rest_length);
  }
  if (a->particle >= 0 && (!b || b->particle >= 0))
    return b ? mrvi_model_add_spring(m, potential, a->particle, b->particle,
                                     law, params, rest_length)
             : mrvi_model_add_anchor_spring(m, potential, a->particle, anchor,
                                            law, params, rest_length);
  char what[300];
  if (end_pair(m, "spring", a, b, what, sizeof what) < 0)
    return MRVI_EINVAL;
  if (!isfinite(rest_length))
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: rest length must be finite",
                           what);
  mrvi_element e = {.kind = b ? MRVI_ELEMENT_SPRING : MRVI_ELEMENT_ANCHOR,
                    .potential = potential,
                    .shift = rest_length};
  double point[MRVI_LAW_MAX_PARAMS] = {0};
  for (int k = 0; !b && k < D; k++) {
    if (!isfinite(anchor[k]))
      return mrvi_model_fail(m, MRVI_EINVAL, "%s: anchor must be finite", what);
    point[k] = anchor[k];
  }
  if (!b && !(e.anchor = intern_params(m, point)))
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  if ((st = mrvi_model_set_law(m, &e, law, params, what)) < 0)
    return st;
  /* Inputs: the blocks of a with their weights, then those of b negated
   * (x_a - x_b); blocks of weight 0 (a point on an axis) are left out. */
  int first[8], n_blocks = 0;
  double w[8];
  for (int s = 0; s < (b ? 2 : 1); s++) {
    int f[4];
    double wt[4];
    const int nb_end = end_blocks(m, s ? b : a, f, wt);
    for (int i = 0; i < nb_end; i++)
      if (wt[i] != 0.0) {
        first[n_blocks] = f[i];
        w[n_blocks++] = s ? -wt[i] : wt[i];
      }
  }
  e.n_in = n_blocks * D;
  if (alloc_inputs(m, &e) < 0)
    return MRVI_ENOMEM;
  for (int i = 0; i < n_blocks; i++)
    for (int k = 0; k < D; k++) {
      e.in[i * D + k] = first[i] + k;
      e.coef[i * D + k] = w[i];
    }
  return push_element(m, &e, what);
}

/* ---------------------------------------------------------------------------
 * Constraints on ends (constraint type "point", constraints/point.c): the
 * blocks of the ends with their weights, the second end's negated, then
 * the kind and its own parameters.  Particles alone keep their own types.
 * ------------------------------------------------------------------------- */
static int add_point_constraint(mrvi_model *m, const mrvi_end *a,
                                const mrvi_end *b, int kind, int n_own,
                                const double *own, const char *label) {
  const int D = m->dimension;
  int first[8], n_blocks = 0, in[MRVI_MAX_INPUTS];
  double w[8], par[MRVI_MAX_INPUTS];
  for (int s = 0; s < (b ? 2 : 1); s++) {
    int f[4];
    double wt[4];
    const int nb_end = end_blocks(m, s ? b : a, f, wt);
    for (int i = 0; i < nb_end; i++)
      if (wt[i] != 0.0) {
        first[n_blocks] = f[i];
        w[n_blocks++] = s ? -wt[i] : wt[i];
      }
  }
  int n_par = 0;
  par[n_par++] = D;
  par[n_par++] = n_blocks;
  for (int i = 0; i < n_blocks; i++) {
    par[n_par++] = w[i];
    for (int k = 0; k < D; k++)
      in[i * D + k] = first[i] + k;
  }
  par[n_par++] = kind;
  for (int i = 0; i < n_own; i++)
    par[n_par++] = own[i];
  return mrvi_model_add_constraint(m, "point", n_blocks * D, in, n_par, par,
                                   label);
}

int mrvi_model_add_end_distance(mrvi_model *m, const mrvi_end *a,
                                const mrvi_end *b, const double *anchor,
                                double length) {
  int st;
  if ((st = check_end(m, a, "distance")) < 0 ||
      (b && (st = check_end(m, b, "distance")) < 0))
    return st;
  if (!b && !anchor)
    return mrvi_model_fail(m, MRVI_EINVAL, "distance: anchor is NULL");
  if (a->particle >= 0 && (!b || b->particle >= 0))
    return b ? mrvi_model_add_distance(m, a->particle, b->particle, length)
             : mrvi_model_add_distance_anchor(m, a->particle, anchor, length);
  const int D = m->dimension;
  char label[300];
  if (end_pair(m, "distance", a, b, label, sizeof label) < 0)
    return MRVI_EINVAL;
  double own[4] = {length, 0, 0, 0}, xa[3], xb[3] = {0, 0, 0};
  for (int k = 0; !b && k < D; k++)
    xb[k] = own[1 + k] = anchor[k];
  if (isnan(length)) { /* the initial distance */
    mrvi_model_end_position(m, a, m->q0, xa);
    if (b)
      mrvi_model_end_position(m, b, m->q0, xb);
    double rr = 0.0;
    for (int k = 0; k < D; k++)
      rr += (xa[k] - xb[k]) * (xa[k] - xb[k]);
    own[0] = sqrt(rr);
  }
  return add_point_constraint(m, a, b, 0, 1 + D, own, label);
}

int mrvi_model_add_end_fixed(mrvi_model *m, const mrvi_end *a, const int *axes,
                             const double *position) {
  int st = check_end(m, a, "fixed");
  if (st < 0)
    return st;
  if (a->particle >= 0)
    return mrvi_model_add_fixed(m, a->particle, axes, position);
  const int D = m->dimension;
  double own[6], x0[3];
  mrvi_model_end_position(m, a, m->q0, x0);
  static const char axis_name[] = "xyz";
  char which[8] = "", na[128], label[300];
  int n = 0;
  for (int k = 0; k < D; k++) {
    own[k] = !axes || axes[k];
    own[D + k] = position ? position[k] : x0[k];
    if (own[k] != 0.0)
      which[n++] = axis_name[k];
  }
  end_name(m, a, na, sizeof na);
  mrvi_fmt(label, sizeof label, "fixed %s%s%s", na, n < D ? "." : "",
           n < D ? which : "");
  return add_point_constraint(m, a, NULL, 1, 2 * D, own, label);
}

int mrvi_model_add_end_plane(mrvi_model *m, const mrvi_end *a,
                             const double *normal, double offset) {
  int st = check_end(m, a, "plane");
  if (st < 0)
    return st;
  if (!normal)
    return mrvi_model_fail(m, MRVI_EINVAL, "plane: normal is NULL");
  if (a->particle >= 0)
    return mrvi_model_add_plane(m, a->particle, normal, offset);
  const int D = m->dimension;
  double own[4], x0[3], nn = 0.0;
  for (int k = 0; k < D; k++)
    nn += normal[k] * normal[k];
  nn = sqrt(nn);
  mrvi_model_end_position(m, a, m->q0, x0);
  own[D] = 0.0;
  for (int k = 0; k < D; k++) {
    own[k] = nn > 0.0 ? normal[k] / nn : normal[k];
    own[D] += own[k] * x0[k];
  }
  if (!isnan(offset))
    own[D] = nn > 0.0 ? offset / nn : offset;
  char na[128], label[300];
  end_name(m, a, na, sizeof na);
  mrvi_fmt(label, sizeof label, "plane %s", na);
  return add_point_constraint(m, a, NULL, 2, D + 1, own, label);
}

int mrvi_model_add_term(mrvi_model *m, mrvi_rate potential, int n_terms,
                        const int *coords, const double *coef, double offset,
                        const char *law, const double *params) {
  if (n_terms < 1 || !coords || !coef)
    return mrvi_model_fail(m, MRVI_EINVAL, "term: empty combination");
  if (n_terms > MRVI_MAX_INPUTS)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "term: at most %d coordinates per term",
                           MRVI_MAX_INPUTS);
  if (!isfinite(offset))
    return mrvi_model_fail(m, MRVI_EINVAL, "term: offset must be finite");
  for (int j = 0; j < n_terms; j++) {
    if (coords[j] < 0 || coords[j] >= m->n)
      return mrvi_model_fail(
          m, MRVI_EINVAL, "term: coordinate index %d out of range", coords[j]);
    if (!isfinite(coef[j]))
      return mrvi_model_fail(m, MRVI_EINVAL,
                             "term: coefficient of '%s' must be finite",
                             MRVI_CNAME(m, coords[j]));
    for (int i = 0; i < j; i++)
      if (coords[i] == coords[j])
        return mrvi_model_fail(m, MRVI_EINVAL,
                               "term: coordinate '%s' appears twice",
                               MRVI_CNAME(m, coords[j]));
  }
  char what[300];
  mrvi_fmt(what, sizeof what, "term on %s%s", MRVI_CNAME(m, coords[0]),
           n_terms > 1 ? ", ..." : "");
  mrvi_element e = {.kind = MRVI_ELEMENT_TERM,
                    .potential = potential,
                    .shift = offset,
                    .n_in = n_terms};
  int st = mrvi_model_set_law(m, &e, law, params, what);
  if (st < 0)
    return st;
  e.in = mrvi_model_inputs(m, n_terms);
  e.coef = malloc((size_t)n_terms * sizeof *e.coef);
  if (!e.in || !e.coef) {
    free(e.coef);
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  }
  memcpy(e.in, coords, (size_t)n_terms * sizeof *e.in);
  memcpy(e.coef, coef, (size_t)n_terms * sizeof *e.coef);
  return push_element(m, &e, what);
}

int mrvi_model_set_gravity(mrvi_model *m, const double *g) {
  if (!g)
    return mrvi_model_fail(m, MRVI_EINVAL, "gravity is NULL");
  if ((m->n_particles == 0 && m->n_bodies == 0) || m->dimension < 1)
    return mrvi_model_fail(m, MRVI_EINVAL, "gravity needs particles or bodies");
  for (int k = 0; k < m->dimension; k++)
    if (!isfinite(g[k]))
      return mrvi_model_fail(m, MRVI_EINVAL, "gravity must be finite");
  for (int e = 0; e < m->n_elements; e++)
    if (m->erecs[e].kind == MRVI_ELEMENT_GRAVITY)
      return mrvi_model_fail(m, MRVI_EINVAL, "gravity is already set");
  const int d = m->dimension;
  mrvi_element e = {.kind = MRVI_ELEMENT_GRAVITY,
                    .potential = MRVI_SLOW,
                    .n_in = (m->n_particles + m->n_bodies) * d};
  if (alloc_inputs(m, &e) < 0)
    return MRVI_ENOMEM;
  /* -sum_i m_i g^T x_i, bodies at their centres of mass: -M g^T phi
   * (doc/multibody.md) */
  for (int i = 0; i < m->n_particles + m->n_bodies; i++)
    for (int k = 0; k < d; k++) {
      int c = (i < m->n_particles ? mrvi_particle_first(m, i)
                                  : m->bodies[i - m->n_particles].first) +
              k;
      e.in[i * d + k] = c;
      e.coef[i * d + k] = -MRVI_MASS(m, c) * g[k];
    }
  return push_element(m, &e, "gravity");
}

/* Angle at particle j between i and k at the positions x (model order). */
static double angle_at(const mrvi_model *m, const double *x, int i, int j,
                       int k) {
  const int d = m->dimension;
  const double *xi = x + mrvi_particle_first(m, i),
               *xj = x + mrvi_particle_first(m, j),
               *xk = x + mrvi_particle_first(m, k);
  double uv = 0, uu = 0, vv = 0;
  for (int a = 0; a < d; a++) {
    const double u = xi[a] - xj[a], v = xk[a] - xj[a];
    uv += u * v;
    uu += u * u;
    vv += v * v;
  }
  if (uu == 0 || vv == 0)
    return NAN;
  double c = uv / sqrt(uu * vv);
  return acos(c > 1 ? 1 : c < -1 ? -1 : c);
}

int mrvi_model_add_angle(mrvi_model *m, mrvi_rate potential, int particle_i,
                         int particle_j, int particle_k, double stiffness,
                         double rest_angle) {
  const int np = m->n_particles;
  if (particle_i < 0 || particle_i >= np || particle_j < 0 ||
      particle_j >= np || particle_k < 0 || particle_k >= np)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "angle: particle index out of range");
  if (m->dimension < 2)
    return mrvi_model_fail(m, MRVI_EINVAL, "angle: needs dimension 2 or 3");
  const char *ni = MRVI_PNAME(m, particle_i), *nj = MRVI_PNAME(m, particle_j),
             *nk = MRVI_PNAME(m, particle_k);
  char what[400];
  mrvi_fmt(what, sizeof what, "angle %s-%s-%s", ni, nj, nk);
  if (particle_i == particle_j || particle_j == particle_k ||
      particle_i == particle_k)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "%s: the three particles must differ", what);
  if (!isfinite(stiffness))
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: stiffness must be finite",
                           what);
  if (isnan(rest_angle)) {
    rest_angle = angle_at(m, m->q0, particle_i, particle_j, particle_k);
    if (isnan(rest_angle))
      return mrvi_model_fail(m, MRVI_EINVAL,
                             "%s: the initial angle is undefined (two "
                             "particles coincide)",
                             what);
  }
  if (!(rest_angle >= 0 && rest_angle <= M_PI))
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "%s: rest angle must be in [0, pi] radians (got %g)",
                           what, rest_angle);
  mrvi_element e = {
      .kind = MRVI_ELEMENT_ANGLE, .potential = potential, .shift = rest_angle};
  double v[MRVI_LAW_MAX_PARAMS] = {0};
  v[0] = stiffness;
  v[1] = cos(rest_angle);
  /* sin(pi) is 1.2e-16, not 0: keep the smooth straight case exact. */
  v[2] = rest_angle == M_PI || rest_angle == 0 ? 0.0 : sin(rest_angle);
  if (!(e.params = intern_params(m, v)))
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  int parts[3] = {particle_i, particle_j, particle_k}, st;
  if ((st = particle_inputs(m, &e, 3, parts)) < 0)
    return st;
  return push_element(m, &e, what);
}

int mrvi_model_add_force(mrvi_model *m, mrvi_rate potential, int n_terms,
                         const int *coords, const double *f) {
  if (n_terms < 1 || n_terms > MRVI_MAX_INPUTS || !coords || !f)
    return mrvi_model_fail(m, MRVI_EINVAL, "force: 1 to %d coordinates needed",
                           MRVI_MAX_INPUTS);
  for (int j = 0; j < n_terms; j++) {
    if (coords[j] < 0 || coords[j] >= m->n)
      return mrvi_model_fail(
          m, MRVI_EINVAL, "force: coordinate index %d out of range", coords[j]);
    if (!isfinite(f[j]))
      return mrvi_model_fail(m, MRVI_EINVAL, "force on '%s' must be finite",
                             MRVI_CNAME(m, coords[j]));
  }
  char what[300];
  mrvi_fmt(what, sizeof what, "force on %s%s", MRVI_CNAME(m, coords[0]),
           n_terms > 1 ? ", ..." : "");
  mrvi_element e = {
      .kind = MRVI_ELEMENT_FORCE, .potential = potential, .n_in = n_terms};
  e.in = mrvi_model_inputs(m, n_terms);
  e.coef = malloc((size_t)n_terms * sizeof *e.coef);
  if (!e.in || !e.coef) {
    free(e.coef);
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  }
  for (int j = 0; j < n_terms; j++) {
    e.in[j] = coords[j];
    e.coef[j] = -f[j]; /* potential -f^T q */
  }
  return push_element(m, &e, what);
}

double mrvi_model_initial_distance(const mrvi_model *m, int particle_i,
                                   int particle_j, const double *anchor) {
  if (particle_i < 0 || particle_i >= m->n_particles ||
      particle_j >= m->n_particles || (particle_j < 0 && !anchor))
    return NAN;
  const double *a = m->q0 + mrvi_particle_first(m, particle_i),
               *b = particle_j >= 0 ? m->q0 + mrvi_particle_first(m, particle_j)
                                    : anchor;
  double r2 = 0;
  for (int k = 0; k < m->dimension; k++)
    r2 += (a[k] - b[k]) * (a[k] - b[k]);
  return sqrt(r2);
}

/* ---------------------------------------------------------------------------
 * Read access
 * ------------------------------------------------------------------------- */
int mrvi_model_n(const mrvi_model *m) { return m->n; }
int mrvi_model_n_slow(const mrvi_model *m) { return m->n_slow; }
int mrvi_model_n_fast(const mrvi_model *m) { return m->n_fast; }
int mrvi_model_dimension(const mrvi_model *m) {
  return m->n_particles > 0 || m->n_bodies > 0 ? m->dimension : 0;
}
int mrvi_model_n_particles(const mrvi_model *m) { return m->n_particles; }
int mrvi_model_n_elements(const mrvi_model *m) { return m->n_elements; }
const char *mrvi_model_name(const mrvi_model *m) { return m->name; }
double mrvi_model_mass(const mrvi_model *m, int i) { return MRVI_MASS(m, i); }
mrvi_rate mrvi_model_rate(const mrvi_model *m, int i) {
  return (mrvi_rate)m->rate[i];
}
const double *mrvi_model_q0(const mrvi_model *m) { return m->q0; }
const double *mrvi_model_v0(const mrvi_model *m) { return m->v0; }
const int *mrvi_model_slow_index(const mrvi_model *m) { return m->slow_index; }
const int *mrvi_model_fast_index(const mrvi_model *m) { return m->fast_index; }

int mrvi_model_describe_element(const mrvi_model *m, int idx, char *buf,
                                size_t len) {
  if (idx < 0 || idx >= m->n_elements)
    return MRVI_EINVAL;
  const mrvi_element *e = MRVI_ELEMENT(m, idx);
  const char *rate = e->potential == MRVI_SLOW ? "slow" : "fast";
  char law[256] = "";
  if (e->law) {
    size_t used = 0;
    used += (size_t)snprintf(law, sizeof law, "%s(", e->law->name);
    for (int i = 0; i < e->law->n_params && used < sizeof law; i++)
      used +=
          (size_t)snprintf(law + used, sizeof law - used, "%s%s=%g",
                           i ? ", " : "", e->law->param_names[i], e->params[i]);
    if (used < sizeof law)
      snprintf(law + used, sizeof law - used, ")");
  }
  switch (e->kind) {
  case MRVI_ELEMENT_SPRING:
  case MRVI_ELEMENT_ANCHOR:
    if (e->coef) { /* body points: name the coordinates' range */
      mrvi_fmt(buf, len,
               "%s spring between points (%d inputs, %s .. %s), rest length "
               "%g, %s",
               rate, e->n_in, MRVI_CNAME(m, e->in[0]),
               MRVI_CNAME(m, e->in[e->n_in - 1]), e->shift, law);
      break;
    }
    if (e->kind == MRVI_ELEMENT_ANCHOR)
      goto anchor;
    mrvi_fmt(buf, len, "%s spring %s-%s, rest length %g, %s", rate,
             MRVI_PNAME(m, mrvi_element_particle(m, e, 0)),
             MRVI_PNAME(m, mrvi_element_particle(m, e, m->dimension)), e->shift,
             law);
    break;
  anchor : {
    char a[96];
    if (m->dimension == 1)
      mrvi_fmt(a, sizeof a, "[%g]", e->anchor[0]);
    else if (m->dimension == 2)
      mrvi_fmt(a, sizeof a, "[%g, %g]", e->anchor[0], e->anchor[1]);
    else
      mrvi_fmt(a, sizeof a, "[%g, %g, %g]", e->anchor[0], e->anchor[1],
               e->anchor[2]);
    mrvi_fmt(buf, len, "%s spring %s-anchor %s, rest length %g, %s", rate,
             MRVI_PNAME(m, mrvi_element_particle(m, e, 0)), a, e->shift, law);
    break;
  }
  case MRVI_ELEMENT_TERM: {
    char comb[512];
    size_t used = 0;
    comb[0] = '\0';
    /* As one writes it: "qs1 - qf1", "2*q1 + 0.5*q2 - 1"; no "1*", no
     * "+ -", no "- 0". */
    for (int j = 0; j < e->n_in && used < sizeof comb; j++) {
      const double c = e->coef[j], a = fabs(c);
      const char *sign = c < 0 ? (j ? " - " : "-") : (j ? " + " : "");
      char k[32] = "";
      if (a != 1)
        mrvi_fmt(k, sizeof k, "%g*", a);
      used += (size_t)snprintf(comb + used, sizeof comb - used, "%s%s%s", sign,
                               k, MRVI_CNAME(m, e->in[j]));
    }
    char off[40] = "";
    if (e->shift != 0)
      mrvi_fmt(off, sizeof off, " %c %g", e->shift > 0 ? '-' : '+',
               fabs(e->shift));
    mrvi_fmt(buf, len, "%s term on %s%s, %s", rate, comb, off, law);
    break;
  }
  case MRVI_ELEMENT_GRAVITY:
    if (m->n_bodies > 0)
      mrvi_fmt(buf, len, "slow gravity on %d particles and %d bodies",
               m->n_particles, m->n_bodies);
    else
      mrvi_fmt(buf, len, "slow gravity on %d particles", m->n_particles);
    break;
  case MRVI_ELEMENT_ANGLE:
    mrvi_fmt(buf, len, "%s angle %s-%s-%s, stiffness %g, rest angle %g rad",
             rate, MRVI_PNAME(m, mrvi_element_particle(m, e, 0)),
             MRVI_PNAME(m, mrvi_element_particle(m, e, m->dimension)),
             MRVI_PNAME(m, mrvi_element_particle(m, e, 2 * m->dimension)),
             e->params[0], e->shift);
    break;
  case MRVI_ELEMENT_FORCE: {
    char f[512];
    size_t used = 0;
    f[0] = '\0';
    for (int j = 0; j < e->n_in && used < sizeof f; j++)
      used +=
          (size_t)snprintf(f + used, sizeof f - used, "%s%s %g", j ? ", " : "",
                           MRVI_CNAME(m, e->in[j]), -e->coef[j]);
    mrvi_fmt(buf, len, "%s constant force: %s", rate, f);
    break;
  }
  case MRVI_ELEMENT_TORSION: {
    const int D = m->dimension, body = mrvi_model_body_of(m, e->in[0]),
              other =
                  e->n_in > D * D ? mrvi_model_body_of(m, e->in[D * D]) : -1;
    mrvi_fmt(buf, len, "%s torsional spring %s-%s, rest angle %g rad, %s", rate,
             m->bodies[body].name,
             other >= 0 ? m->bodies[other].name : "ground", e->shift, law);
    break;
  }
  }
  return MRVI_OK;
}

/* ---------------------------------------------------------------------------
 * Element evaluation
 * ------------------------------------------------------------------------- */

/* Distance between body points (doc/multibody.md, "Body points"): the
 * inputs are blocks of dim coordinates with weights coef, so that
 * d = sum_j coef[j] y[j] (input j along axis j % dim) - anchor, and with
 * A = phi'' u u^T + phi'/r (I - u u^T) the chain rule with constant
 * coefficients gives grad_j = coef[j] phi' u[j % dim] and
 * H_jl = coef[j] coef[l] A[j % dim][l % dim]. */
static double eval_points(const mrvi_element *e, int dim, const double *y,
                          double *grad, double *hess) {
  const int n = e->n_in, anchored = e->kind == MRVI_ELEMENT_ANCHOR;
  double d[3], r2 = 0.0;
  for (int k = 0; k < dim; k++)
    d[k] = anchored ? -e->anchor[k] : 0.0;
  for (int j = 0; j < n; j++)
    d[j % dim] += e->coef[j] * y[j];
  for (int k = 0; k < dim; k++)
    r2 += d[k] * d[k];
  const double r = sqrt(r2);
  double phi, dphi, ddphi;
  e->law->eval(e->params, r - e->shift, &phi, &dphi, &ddphi);
  double u[3] = {0, 0, 0}, a = 0.0, b = ddphi; /* A = a u u^T + b I */
  if (r > 0.0) {
    for (int k = 0; k < dim; k++)
      u[k] = d[k] / r;
    a = ddphi - dphi / r;
    b = dphi / r;
  }
  if (grad)
    for (int j = 0; j < n; j++)
      grad[j] = e->coef[j] * dphi * u[j % dim];
  if (hess)
    for (int i = 0; i < n; i++)
      for (int j = 0; j < n; j++) {
        const int p = i % dim, q = j % dim;
        hess[i * n + j] =
            e->coef[i] * e->coef[j] * (a * u[p] * u[q] + (p == q ? b : 0.0));
      }
  return phi;
}

/* Distance-type element: inputs x (d) [and y (d)], d = x - (y or anchor).
 * Gradient wrt x is phi' u, Hessian block A = phi'' u u^T + phi'/r (I - u u^T);
 * for a two-particle spring the blocks are [A -A; -A A]. */
static double eval_distance(const mrvi_element *e, int dim, const double *y,
                            double *grad, double *hess) {
  double d[3], r2 = 0.0;
  const int two = e->kind == MRVI_ELEMENT_SPRING;
  if (e->coef)
    return eval_points(e, dim, y, grad, hess);
  for (int k = 0; k < dim; k++) {
    d[k] = y[k] - (two ? y[dim + k] : e->anchor[k]);
    r2 += d[k] * d[k];
  }
  const double r = sqrt(r2);
  double phi, dphi, ddphi;
  e->law->eval(e->params, r - e->shift, &phi, &dphi, &ddphi);
  double u[3] = {0, 0, 0}, a = 0.0, b = 0.0; /* A = a u u^T + b I */
  if (r > 0.0) {
    for (int k = 0; k < dim; k++)
      u[k] = d[k] / r;
    a = ddphi - dphi / r;
    b = dphi / r;
  } else {
    /* r = 0: smooth only when phi'(-L0) = 0; the limit of A is phi'' I. */
    b = ddphi;
  }
  const int n = two ? 2 * dim : dim;
  if (grad)
    for (int k = 0; k < dim; k++) {
      grad[k] = dphi * u[k];
      if (two)
        grad[dim + k] = -dphi * u[k];
    }
  if (hess)
    for (int i = 0; i < dim; i++)
      for (int j = 0; j < dim; j++) {
        double A = a * u[i] * u[j] + (i == j ? b : 0.0);
        hess[i * n + j] = A;
        if (two) {
          hess[i * n + dim + j] = -A;
          hess[(dim + i) * n + j] = -A;
          hess[(dim + i) * n + dim + j] = A;
        }
      }
  return phi;
}

/* Angle element k [1 - cos(theta - theta0)] = k [1 - c C0 - s S0] with
 * c = cos theta = u.v/(|u||v|), s = sin theta, u = x_i - x_j, v = x_k - x_j.
 * dE/dc = -k C0 + k S0 c/s, d2E/dc2 = k S0/s^3; the derivatives of c in
 * (u, v) are mapped to (x_i, x_j, x_k) by x_i -> u, x_k -> v, x_j -> -u-v. */
static double eval_angle(const mrvi_element *e, int d, const double *y,
                         double *grad, double *hess) {
  const double k = e->params[0], C0 = e->params[1], S0 = e->params[2];
  double u[3], v[3], a = 0, b = 0;
  for (int p = 0; p < d; p++) {
    u[p] = y[p] - y[d + p];
    v[p] = y[2 * d + p] - y[d + p];
    a += u[p] * u[p];
    b += v[p] * v[p];
  }
  const int n = 3 * d;
  if (grad)
    memset(grad, 0, (size_t)n * sizeof *grad);
  if (hess)
    memset(hess, 0, (size_t)n * n * sizeof *hess);
  if (a == 0 || b == 0)
    return 0.0; /* undefined angle: no force */
  a = sqrt(a);
  b = sqrt(b);
  double c = 0;
  for (int p = 0; p < d; p++) {
    u[p] /= a;
    v[p] /= b;
    c += u[p] * v[p];
  }
  c = c > 1 ? 1 : c < -1 ? -1 : c;
  double s = sqrt(1 - c * c);
  const double E = k * (1 - c * C0 - s * S0);
  double Ec = -k * C0, Ecc = 0;
  if (S0 != 0) {
    if (s < 1e-12)
      s = 1e-12; /* collinear with theta0 != 0, pi: singular (documented) */
    Ec += k * S0 * c / s;
    Ecc = k * S0 / (s * s * s);
  }
  double gu[3], gv[3];
  for (int p = 0; p < d; p++) {
    gu[p] = (v[p] - c * u[p]) / a;
    gv[p] = (u[p] - c * v[p]) / b;
  }
  if (grad)
    for (int p = 0; p < d; p++) {
      grad[p] = Ec * gu[p];
      grad[2 * d + p] = Ec * gv[p];
      grad[d + p] = -Ec * (gu[p] + gv[p]);
    }
  if (!hess)
    return E;
  /* Hessian in (u, v): blocks Huu, Huv, Hvv (Hvu = Huv^T). */
  double Huu[9], Huv[9], Hvv[9];
  for (int p = 0; p < d; p++)
    for (int q = 0; q < d; q++) {
      const double dl = p == q;
      Huu[p * 3 + q] = Ecc * gu[p] * gu[q] -
                       Ec / (a * a) *
                           ((v[p] - c * u[p]) * u[q] +
                            u[p] * (v[q] - c * u[q]) + c * (dl - u[p] * u[q]));
      Hvv[p * 3 + q] = Ecc * gv[p] * gv[q] -
                       Ec / (b * b) *
                           ((u[p] - c * v[p]) * v[q] +
                            v[p] * (u[q] - c * v[q]) + c * (dl - v[p] * v[q]));
      Huv[p * 3 + q] =
          Ecc * gu[p] * gv[q] +
          Ec / (a * b) * (dl - v[p] * v[q] - u[p] * u[q] + c * u[p] * v[q]);
    }
  /* Coefficients of u and v in blocks i, j, k. */
  static const double J[3][2] = {{1, 0}, {-1, -1}, {0, 1}};
  for (int A = 0; A < 3; A++)
    for (int B = 0; B < 3; B++)
      for (int p = 0; p < d; p++)
        for (int q = 0; q < d; q++)
          hess[(A * d + p) * n + B * d + q] =
              J[A][0] * J[B][0] * Huu[p * 3 + q] +
              J[A][0] * J[B][1] * Huv[p * 3 + q] +
              J[A][1] * J[B][0] * Huv[q * 3 + p] +
              J[A][1] * J[B][1] * Hvv[p * 3 + q];
  return E;
}

int mrvi_element_is_quadratic(const mrvi_element *e) {
  switch (e->kind) {
  case MRVI_ELEMENT_GRAVITY:
  case MRVI_ELEMENT_FORCE:
    return 1;
  case MRVI_ELEMENT_TERM: { /* phi(a^T q - b): quadratic with phi */
    const int degree = e->law->degree ? e->law->degree(e->params) : -1;
    return degree >= 0 && degree <= 2;
  }
  default:
    return 0; /* distances and angles are not polynomial in positions */
  }
}

void mrvi_term_derivs(const mrvi_element *e, double s, double *d1, double *d2) {
  if (e->form == MRVI_LAW_FORM_HOOKE) {
    *d1 = e->params[0] * s;
    *d2 = e->params[0];
  } else if (mrvi_element_small_power(e)) {
    mrvi_power_derivs(e->params[0], e->params[1], (int)e->params[1], s, d1, d2);
  } else {
    double phi;
    e->law->eval(e->params, s, &phi, d1, d2);
  }
}

double mrvi_element_eval(const mrvi_model *m, const mrvi_element *e,
                         const double *y, double *grad, double *hess) {
  switch (e->kind) {
  case MRVI_ELEMENT_ANGLE:
    return eval_angle(e, m->dimension, y, grad, hess);
  case MRVI_ELEMENT_TORSION:
    return mrvi_torsion_eval(e, m->dimension, y, grad, hess);
  case MRVI_ELEMENT_FORCE: {
    double v = 0.0;
    for (int j = 0; j < e->n_in; j++) {
      v += e->coef[j] * y[j];
      if (grad)
        grad[j] = e->coef[j];
    }
    if (hess)
      memset(hess, 0, (size_t)e->n_in * e->n_in * sizeof *hess);
    return v;
  }
  case MRVI_ELEMENT_SPRING:
  case MRVI_ELEMENT_ANCHOR:
    return eval_distance(e, m->dimension, y, grad, hess);
  case MRVI_ELEMENT_TERM: {
    double s = -e->shift;
    for (int j = 0; j < e->n_in; j++)
      s += e->coef[j] * y[j];
    double phi, dphi, ddphi;
    e->law->eval(e->params, s, &phi, &dphi, &ddphi);
    if (grad)
      for (int j = 0; j < e->n_in; j++)
        grad[j] = dphi * e->coef[j];
    if (hess)
      for (int i = 0; i < e->n_in; i++)
        for (int j = 0; j < e->n_in; j++)
          hess[i * e->n_in + j] = ddphi * e->coef[i] * e->coef[j];
    return phi;
  }
  case MRVI_ELEMENT_GRAVITY: {
    double v = 0.0;
    for (int j = 0; j < e->n_in; j++) {
      v += e->coef[j] * y[j];
      if (grad)
        grad[j] = e->coef[j];
    }
    /* Linear: the Hessian is zero and never requested. */
    return v;
  }
  }
  return 0.0;
}

/* ---------------------------------------------------------------------------
 * Energies and momentum maps
 * ------------------------------------------------------------------------- */
double mrvi_model_potential(const mrvi_model *m, mrvi_rate potential,
                            const double *q, double *grad, double *hess) {
  double y[MRVI_MAX_INPUTS], g[MRVI_MAX_INPUTS];
  double H[MRVI_MAX_INPUTS * MRVI_MAX_INPUTS];
  double total = 0.0;
  for (int ei = 0; ei < m->n_elements; ei++) {
    if (m->erecs[ei].potential != potential)
      continue;
    const mrvi_element *e = MRVI_ELEMENT(m, ei);
    const int lin = e->kind == MRVI_ELEMENT_GRAVITY;
    /* Gravity is evaluated in one pass; other elements are small. */
    if (lin) {
      for (int j = 0; j < e->n_in; j++) {
        total += e->coef[j] * q[e->in[j]];
        if (grad)
          grad[e->in[j]] += e->coef[j];
      }
      continue;
    }
    for (int j = 0; j < e->n_in; j++)
      y[j] = q[e->in[j]];
    total += mrvi_element_eval(m, e, y, grad ? g : NULL, hess ? H : NULL);
    for (int i = 0; i < e->n_in; i++) {
      if (grad)
        grad[e->in[i]] += g[i];
      if (hess)
        for (int j = 0; j < e->n_in; j++)
          hess[(size_t)e->in[i] * (size_t)m->n + (size_t)e->in[j]] +=
              H[i * e->n_in + j];
    }
  }
  return total;
}

void mrvi_model_energy(const mrvi_model *m, const double *q, const double *p,
                       double *kinetic, double *slow, double *fast) {
  double t = 0.0;
  for (int i = 0; i < m->n; i++)
    t += 0.5 * p[i] * p[i] / MRVI_MASS(m, i);
  if (kinetic)
    *kinetic = t;
  if (slow)
    *slow = mrvi_model_potential(m, MRVI_SLOW, q, NULL, NULL);
  if (fast)
    *fast = mrvi_model_potential(m, MRVI_FAST, q, NULL, NULL);
}

/* x (dimension entries) cross p added to J (3 entries; 2-D: J[0]). */
static void add_cross(int d, const double *x, const double *v, double *J) {
  if (d == 3) {
    J[0] += x[1] * v[2] - x[2] * v[1];
    J[1] += x[2] * v[0] - x[0] * v[2];
    J[2] += x[0] * v[1] - x[1] * v[0];
  } else if (d == 2) {
    J[0] += x[0] * v[1] - x[1] * v[0];
  }
}

void mrvi_model_momentum(const mrvi_model *m, const double *q, const double *p,
                         double *linear, double *angular) {
  const int d = m->dimension;
  double L[3] = {0, 0, 0}, J[3] = {0, 0, 0};
  for (int i = 0; i < m->n_particles; i++) {
    const double *x = q + mrvi_particle_first(m, i);
    const double *v = p + mrvi_particle_first(m, i);
    for (int k = 0; k < d; k++)
      L[k] += v[k];
    add_cross(d, x, v, J);
  }
  /* Bodies (doc/multibody.md): p_phi and phi x p_phi + sum_i d_i x p_{d_i},
   * the momentum maps of translations and rotations of (phi, d_i). */
  for (int b = 0; b < m->n_bodies; b++) {
    const int f = m->bodies[b].first;
    for (int k = 0; k < d; k++)
      L[k] += p[f + k];
    for (int i = 0; i <= d; i++)
      add_cross(d, q + f + d * i, p + f + d * i, J);
  }
  if (linear)
    for (int k = 0; k < d; k++)
      linear[k] = L[k];
  if (angular)
    for (int k = 0; k < (d == 3 ? 3 : d == 2 ? 1 : 0); k++)
      angular[k] = J[k];
}

/* ---------------------------------------------------------------------------
 * Fingerprint (FNV-1a over the defining data)
 * ------------------------------------------------------------------------- */
unsigned long long mrvi_model_hash(const mrvi_model *m) {
  unsigned long long h = 1469598103934665603ULL;
  fnv(&h, &m->n, sizeof m->n);
  fnv(&h, &m->dimension, sizeof m->dimension);
  for (int i = 0; i < m->n; i++) {
    char buf[MRVI_NAME_MAX];
    const char *name = mrvi_model_coordinate_name(m, i, buf);
    fnv(&h, name, strlen(name) + 1);
    const double mass = MRVI_MASS(m, i);
    const mrvi_rate rate = (mrvi_rate)m->rate[i];
    fnv(&h, &mass, sizeof(double));
    fnv(&h, &m->q0[i], sizeof(double));
    fnv(&h, &m->v0[i], sizeof(double));
    fnv(&h, &rate, sizeof rate);
  }
  for (int e = 0; e < m->n_elements; e++) {
    const mrvi_element *el = MRVI_ELEMENT(m, e);
    /* (the enumerations' bytes, as when the fields had their types) */
    const mrvi_element_kind kind = el->kind;
    const mrvi_rate potential = el->potential;
    fnv(&h, &kind, sizeof kind);
    fnv(&h, &potential, sizeof potential);
    if (el->law) {
      fnv(&h, el->law->name, strlen(el->law->name) + 1);
      fnv(&h, el->params, (size_t)el->law->n_params * sizeof(double));
    } else if (el->kind == MRVI_ELEMENT_ANGLE) {
      fnv(&h, el->params, sizeof(double)); /* stiffness; shift is theta0 */
    }
    fnv(&h, &el->shift, sizeof el->shift);
    static const double no_anchor[3];
    const int anchored = el->kind == MRVI_ELEMENT_ANCHOR && el->anchor;
    fnv(&h, anchored ? el->anchor : no_anchor, sizeof no_anchor);
    fnv(&h, el->in, (size_t)el->n_in * sizeof *el->in);
    if (el->coef)
      fnv(&h, el->coef, (size_t)el->n_in * sizeof *el->coef);
    if (el->kind == MRVI_ELEMENT_TORSION)
      fnv(&h, el->axes, (size_t)(3 * m->dimension) * sizeof *el->axes);
  }
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    fnv(&h, k->type->name, strlen(k->type->name) + 1);
    fnv(&h, k->in, (size_t)k->n_in * sizeof *k->in);
    fnv(&h, k->params, (size_t)k->n_params * sizeof *k->params);
  }
  return h;
}
