/* HDF5 output (src/io/hdf5_writer.c, doc/output.md).
 *
 * Every test keeps an in-memory copy of the records it hands to the writer,
 * reopens the file with the plain HDF5 API and asserts that it holds exactly
 * (bitwise) those values, in the layout of doc/output.md:
 *   - synthetic records (no numerics): layout, shapes, attributes, several
 *     buffer flushes, `every`, micro output off, 1-D/2-D/no particles;
 *   - a process killed hard half-way keeps every flushed row;
 *   - real runs of the FPU and of a 3-D particle model through mrvi_run;
 *   - an observer error at k = 10 (error injection) leaves 11 macro rows;
 *   - constrained models: residuals, the multipliers one record late
 *     (/macro/lambda row j from record j+1, NaN at the last node) with
 *     `every`, across flushes and in stopped runs; /model/constraint_*;
 *     none of it for unconstrained models;
 *   - an unwritable path fails with a message and prints nothing;
 *   - `mrvi run` on systems/fpu.yaml writes exactly the in-memory run. */
#include "io/h5util.h"
#include "mrvi.h"
#include "testlib.h"

#include <hdf5.h>

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <signal.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

/* ---------------------------------------------------------------------------
 * In-memory copy of the records of a run
 * ------------------------------------------------------------------------- */
typedef struct rec {
  long k;
  double t, kinetic, vs, vf, energy, lin[3], ang[3], residual;
  int iterations, micro_count;
  double micro_t0, micro_dt;
  double *q, *p;       /* n */
  double *mq, *mp;     /* micro_count x nf */
  double cres, hres;   /* constraint and hidden constraint residual */
  double *lambda_prev; /* n_lambda, NULL when the record had none */
  double *mcres;       /* micro_count: micro_constraint_residual (or NULL) */
} rec;

typedef struct traj {
  int n, nf, n_lambda;
  long count, cap;
  rec *r;
} traj;

static void traj_init(traj *tr, const mrvi_model *m) {
  memset(tr, 0, sizeof *tr);
  tr->n = mrvi_model_n(m);
  tr->nf = mrvi_model_n_fast(m);
  tr->n_lambda = mrvi_model_constraint_rows(m);
}

static double *dup_doubles(const double *x, size_t count) {
  double *y = malloc((count ? count : 1) * sizeof *y);
  if (y && count)
    memcpy(y, x, count * sizeof *y);
  return y;
}

static void traj_add(traj *tr, const mrvi_record *r) {
  if (tr->count == tr->cap) {
    tr->cap = tr->cap ? 2 * tr->cap : 64;
    tr->r = realloc(tr->r, (size_t)tr->cap * sizeof *tr->r);
  }
  rec *c = &tr->r[tr->count++];
  c->k = r->k;
  c->t = r->t;
  c->kinetic = r->kinetic;
  c->vs = r->potential_slow;
  c->vf = r->potential_fast;
  c->energy = r->energy;
  memcpy(c->lin, r->linear_momentum, sizeof c->lin);
  memcpy(c->ang, r->angular_momentum, sizeof c->ang);
  c->iterations = r->iterations;
  c->residual = r->residual;
  c->micro_count = r->micro_count;
  c->micro_t0 = r->micro_t0;
  c->micro_dt = r->micro_dt;
  c->q = dup_doubles(r->q, (size_t)tr->n);
  c->p = dup_doubles(r->p, (size_t)tr->n);
  size_t mc = (size_t)r->micro_count * (size_t)tr->nf;
  c->mq = dup_doubles(mc ? r->micro_q_fast : NULL, mc);
  c->mp = dup_doubles(mc ? r->micro_p_fast : NULL, mc);
  c->cres = r->constraint_residual;
  c->hres = r->hidden_constraint_residual;
  c->lambda_prev =
      r->lambda_prev ? dup_doubles(r->lambda_prev, (size_t)tr->n_lambda) : NULL;
  c->mcres =
      r->micro_constraint_residual
          ? dup_doubles(r->micro_constraint_residual, (size_t)r->micro_count)
          : NULL;
}

static void traj_free(traj *tr) {
  for (long i = 0; i < tr->count; i++) {
    free(tr->r[i].q);
    free(tr->r[i].p);
    free(tr->r[i].mq);
    free(tr->r[i].mp);
    free(tr->r[i].lambda_prev);
    free(tr->r[i].mcres);
  }
  free(tr->r);
  memset(tr, 0, sizeof *tr);
}

/* Observer that copies every record and forwards it to the writer; it stops
 * the run with MRVI_EINTERRUPTED after forwarding record k = stop_at. */
typedef struct tee {
  mrvi_writer *w;
  traj *tr;
  long stop_at;
} tee;

static int tee_observe(void *user, const mrvi_record *r) {
  tee *t = user;
  traj_add(t->tr, r);
  if (t->w) {
    int rc = mrvi_writer_observe(t->w, r);
    if (rc)
      return rc;
  }
  return r->k == t->stop_at ? MRVI_EINTERRUPTED : 0;
}

/* ---------------------------------------------------------------------------
 * Reading the file
 * ------------------------------------------------------------------------- */

/* Does the object at an absolute path exist (no HDF5 error printed)? */
static int exists(hid_t f, const char *path) {
  char buf[256];
  snprintf(buf, sizeof buf, "%s", path);
  for (char *s = strchr(buf + 1, '/');; s = strchr(s + 1, '/')) {
    if (s)
      *s = '\0';
    if (H5Lexists(f, buf, H5P_DEFAULT) <= 0)
      return 0;
    if (!s)
      return 1;
    *s = '/';
  }
}

/* Read a whole numeric dataset as mtype; shape into dims (rank <= 2). */
static void *read_all(hid_t f, const char *path, hid_t mtype, size_t esize,
                      int *rank, hsize_t dims[2]) {
  dims[0] = dims[1] = 0;
  *rank = -1;
  hid_t d = H5Dopen2(f, path, H5P_DEFAULT);
  if (d < 0)
    return NULL;
  hid_t sp = H5Dget_space(d);
  *rank = H5Sget_simple_extent_ndims(sp);
  if (*rank < 0 || *rank > 2) {
    H5Sclose(sp);
    H5Dclose(d);
    return NULL;
  }
  H5Sget_simple_extent_dims(sp, dims, NULL);
  hsize_t count = 1;
  for (int i = 0; i < *rank; i++)
    count *= dims[i];
  void *buf = calloc(count ? count : 1, esize);
  if (count && H5Dread(d, mtype, H5S_ALL, H5S_ALL, H5P_DEFAULT, buf) < 0) {
    free(buf);
    buf = NULL;
  }
  H5Sclose(sp);
  H5Dclose(d);
  return buf;
}

/* Assert that dataset `path` has shape (rows) (rank 1) or (rows, cols) and
 * holds exactly the bytes of `expect`. */
static void check_data(hid_t f, const char *path, int want_rank, size_t rows,
                       size_t cols, hid_t mtype, size_t esize,
                       const void *expect) {
  int rank;
  hsize_t dims[2];
  void *got = read_all(f, path, mtype, esize, &rank, dims);
  CHECK(got != NULL, "%s: readable", path);
  if (!got)
    return;
  CHECK(rank == want_rank, "%s: rank %d, expected %d", path, rank, want_rank);
  CHECK(dims[0] == rows, "%s: %llu rows, expected %zu", path,
        (unsigned long long)dims[0], rows);
  if (want_rank == 2)
    CHECK(dims[1] == cols, "%s: %llu columns, expected %zu", path,
          (unsigned long long)dims[1], cols);
  if (rank == want_rank && dims[0] == rows && (rank == 1 || dims[1] == cols)) {
    int same = memcmp(got, expect, rows * cols * esize) == 0;
    CHECK(same, "%s: contents differ from the in-memory trajectory", path);
    if (!same)
      for (size_t i = 0; i < rows * cols; i++)
        if (memcmp((char *)got + i * esize, (const char *)expect + i * esize,
                   esize)) {
          fprintf(stderr, "  first difference at element %zu (row %zu)\n", i,
                  i / cols);
          break;
        }
  }
  free(got);
  if (strncmp(path, "/model/", 7) == 0)
    return;
  /* Appended datasets are chunked with an unlimited first dimension. */
  hid_t d = H5Dopen2(f, path, H5P_DEFAULT);
  hid_t sp = H5Dget_space(d);
  hsize_t maxdims[2] = {0, 0};
  H5Sget_simple_extent_dims(sp, NULL, maxdims);
  hid_t dcpl = H5Dget_create_plist(d);
  CHECK(H5Pget_layout(dcpl) == H5D_CHUNKED && maxdims[0] == H5S_UNLIMITED,
        "%s: chunked and extendible", path);
  H5Pclose(dcpl);
  H5Sclose(sp);
  H5Dclose(d);
}

static void check_f64(hid_t f, const char *path, int rank, size_t rows,
                      size_t cols, const double *expect) {
  check_data(f, path, rank, rows, cols, H5T_NATIVE_DOUBLE, sizeof(double),
             expect);
}

/* The n fixed-length strings of dataset or attribute obj (type ft) as
 * NUL-terminated rows of (*size) bytes (malloc'd), checking that they are
 * fixed-length: mrvi writes no variable-length strings (doc/output.md). */
static char *read_fixed(hid_t obj, int is_attr, hid_t ft, size_t n,
                        size_t *size, const char *what) {
  CHECK(H5Tget_class(ft) == H5T_STRING && H5Tis_variable_str(ft) == 0,
        "%s is a fixed-length string", what);
  if (H5Tget_class(ft) != H5T_STRING || H5Tis_variable_str(ft) != 0)
    return NULL;
  *size = H5Tget_size(ft) + 1;
  hid_t mt = H5Tcopy(H5T_C_S1);
  H5Tset_size(mt, *size);
  H5Tset_cset(mt, H5Tget_cset(ft));
  H5Tset_strpad(mt, H5T_STR_NULLTERM);
  char *out = calloc(n ? n * *size : 1, 1);
  herr_t rc = is_attr ? H5Aread(obj, mt, out)
                      : H5Dread(obj, mt, H5S_ALL, H5S_ALL, H5P_DEFAULT, out);
  if (out && rc < 0) {
    free(out);
    out = NULL;
  }
  H5Tclose(mt);
  return out;
}

/* String attribute (NULL if missing or not a fixed-length string). */
static char *attr_string(hid_t obj, const char *name) {
  if (H5Aexists(obj, name) <= 0)
    return NULL;
  hid_t a = H5Aopen(obj, name, H5P_DEFAULT);
  hid_t ft = H5Aget_type(a);
  char *out = NULL;
  size_t size = 0;
  if (H5Tget_class(ft) == H5T_STRING)
    out = read_fixed(a, 1, ft, 1, &size, name);
  H5Tclose(ft);
  H5Aclose(a);
  return out;
}

/* Numeric scalar attribute read as double / long; class must match. */
static int attr_number(hid_t obj, const char *name, H5T_class_t cls,
                       hid_t mtype, void *value) {
  if (H5Aexists(obj, name) <= 0)
    return -1;
  hid_t a = H5Aopen(obj, name, H5P_DEFAULT);
  hid_t ft = H5Aget_type(a);
  hid_t sp = H5Aget_space(a);
  int ok = H5Tget_class(ft) == cls &&
           H5Sget_simple_extent_type(sp) == H5S_SCALAR &&
           H5Aread(a, mtype, value) >= 0;
  H5Sclose(sp);
  H5Tclose(ft);
  H5Aclose(a);
  return ok ? 0 : -1;
}

static void check_attr_string(hid_t obj, const char *name, const char *want,
                              int substring) {
  char *got = attr_string(obj, name);
  CHECK(got && (substring ? strstr(got, want) != NULL : strcmp(got, want) == 0),
        "attribute %s = \"%s\", expected %s\"%s\"", name, got ? got : "(none)",
        substring ? "to contain " : "", want);
  free(got);
}

static void check_attr_double(hid_t obj, const char *name, double want) {
  double got = NAN;
  int rc = attr_number(obj, name, H5T_FLOAT, H5T_NATIVE_DOUBLE, &got);
  CHECK(rc == 0 && memcmp(&got, &want, sizeof got) == 0,
        "attribute %s = %.17g, expected %.17g", name, got, want);
}

static void check_attr_long(hid_t obj, const char *name, long want) {
  long got = -12345;
  int rc = attr_number(obj, name, H5T_INTEGER, H5T_NATIVE_LONG, &got);
  CHECK(rc == 0 && got == want, "attribute %s = %ld, expected %ld", name, got,
        want);
}

/* Assert that string dataset `path` holds exactly the count strings want
 * (fixed-length). */
static void check_strings(hid_t f, const char *path, int count,
                          const char *const *want) {
  hid_t d = H5Dopen2(f, path, H5P_DEFAULT);
  hid_t sp = d >= 0 ? H5Dget_space(d) : H5I_INVALID_HID;
  hid_t ft = d >= 0 ? H5Dget_type(d) : H5I_INVALID_HID;
  size_t size = 0;
  char *got = NULL;
  CHECK(d >= 0 && H5Sget_simple_extent_npoints(sp) == count &&
            (got = read_fixed(d, 0, ft, (size_t)count, &size, path)) != NULL,
        "%s: %d strings", path, count);
  for (int i = 0; got && i < count; i++)
    CHECK(strcmp(got + (size_t)i * size, want[i]) == 0,
          "%s[%d] = %s, expected %s", path, i, got + (size_t)i * size, want[i]);
  free(got);
  if (ft >= 0)
    H5Tclose(ft);
  if (sp >= 0)
    H5Sclose(sp);
  if (d >= 0)
    H5Dclose(d);
}

/* /model/constraint_* of a model with constraints, and the root attributes
 * of the constraint settings; neither without constraints. */
static void check_constraint_model(hid_t f, const mrvi_model *m,
                                   const mrvi_settings *s) {
  const int nc = mrvi_model_n_constraints(m);
  static const char *const items[] = {
      "/model/constraint_label", "/model/constraint_type",
      "/model/constraint_rows", "/model/constraint_where"};
  for (int i = 0; i < 4; i++)
    CHECK(exists(f, items[i]) == (nc > 0), "%s present iff constraints (%d)",
          items[i], nc);
  static const char *const attrs[] = {"constraint_form", "constraint_tolerance",
                                      "project_momenta"};
  for (int i = 0; i < 3; i++)
    CHECK((H5Aexists(f, attrs[i]) > 0) == (nc > 0),
          "attribute %s present iff constraints (%d)", attrs[i], nc);
  if (nc == 0)
    return;
  const char **label = calloc((size_t)nc, sizeof *label);
  const char **type = calloc((size_t)nc, sizeof *type);
  const char **where = calloc((size_t)nc, sizeof *where);
  int *rows = calloc((size_t)nc, sizeof *rows);
  for (int c = 0; c < nc; c++) {
    label[c] = mrvi_model_constraint_label(m, c);
    type[c] = mrvi_model_constraint_type_name(m, c);
    where[c] = mrvi_model_constraint_where(m, c) == MRVI_FAST ? "micro nodes"
                                                              : "macro nodes";
    rows[c] = mrvi_model_constraint_n_rows(m, c);
  }
  check_strings(f, "/model/constraint_label", nc, label);
  check_strings(f, "/model/constraint_type", nc, type);
  check_strings(f, "/model/constraint_where", nc, where);
  check_data(f, "/model/constraint_rows", 1, (size_t)nc, 1, H5T_NATIVE_INT,
             sizeof(int), rows);
  free(label);
  free(type);
  free(where);
  free(rows);
  check_attr_string(f, "constraint_form",
                    s->constraint_form == MRVI_FORM_NULL_SPACE ? "null-space"
                                                               : "multipliers",
                    0);
  check_attr_double(f, "constraint_tolerance", s->constraint_tol);
  check_attr_long(f, "project_momenta", s->project_momenta);
}

/* ---------------------------------------------------------------------------
 * The whole file against the in-memory trajectory
 * ------------------------------------------------------------------------- */
typedef struct expect {
  const mrvi_model *m;
  const mrvi_settings *s;
  const char *system;      /* root attribute `system` */
  const char *description; /* /model/description, NULL: absent */
  int every, micro;
  const char *stop_reason; /* expected substring of stop_reason */
  int complete;            /* written by close: the last record is kept */
} expect;

/* Macro records kept in the file: k % every == 0, plus the last one seen. */
static int kept(const traj *tr, const expect *e, long i) {
  return tr->r[i].k % e->every == 0 || (e->complete && i == tr->count - 1);
}

/* Assert that the file at path holds exactly the records of tr (all of them,
 * or with complete = 0 the ones a killed process had flushed) in the layout
 * of doc/output.md, with the attributes of e. */
static void verify(const char *path, const traj *tr, const expect *e) {
  const mrvi_model *m = e->m;
  const mrvi_settings *s = e->s;
  const int n = mrvi_model_n(m), nf = mrvi_model_n_fast(m);
  const int dim = mrvi_model_dimension(m);
  const int n_ang = dim == 3 ? 3 : dim == 2 ? 1 : 0;
  const int micro = e->micro && nf > 0;
  hid_t f = mrvi_h5_open_read(path, H5P_DEFAULT);
  CHECK(f >= 0, "%s: opens", path);
  if (f < 0)
    return;

  /* Root attributes. */
  check_attr_string(f, "mrvi_version", MRVI_VERSION, 0);
  check_attr_string(f, "system", e->system, 0);
  check_attr_string(f, "scheme", s->scheme, 0);
  check_attr_double(f, "alpha_slow", s->slow.alpha);
  check_attr_double(f, "gamma_slow", s->slow.gamma);
  check_attr_string(f, "slow_grid",
                    s->slow_grid == MRVI_GRID_MACRO ? "macro" : "micro", 0);
  check_attr_double(f, "alpha_fast", s->fast.alpha);
  check_attr_double(f, "gamma_fast", s->fast.gamma);
  check_attr_double(f, "macro_step", s->macro_step);
  check_attr_long(f, "micro_steps", s->micro_steps);
  check_attr_double(f, "t_end", s->t_end);
  check_attr_double(f, "newton_tolerance", s->newton_tol);
  check_attr_long(f, "newton_max_iterations", s->newton_max_iter);
  check_attr_long(f, "output_every", e->every);
  check_attr_string(f, "stop_reason", e->stop_reason, 1);
  if (e->complete)
    check_attr_long(f, "steps_completed",
                    tr->count ? tr->r[tr->count - 1].k : 0);

  /* /model */
  double *mass = calloc((size_t)n + 1, sizeof *mass);
  int *rate = calloc((size_t)n + 1, sizeof *rate);
  for (int i = 0; i < n; i++) {
    mass[i] = mrvi_model_mass(m, i);
    rate[i] = mrvi_model_rate(m, i) == MRVI_FAST;
  }
  check_data(f, "/model/mass", 1, (size_t)n, 1, H5T_NATIVE_DOUBLE,
             sizeof(double), mass);
  check_data(f, "/model/rate", 1, (size_t)n, 1, H5T_NATIVE_INT, sizeof(int),
             rate);
  free(mass);
  free(rate);
  {
    const char **names = calloc((size_t)n + 1, sizeof *names);
    char(*buf)[MRVI_NAME_MAX] = calloc((size_t)n + 1, sizeof *buf);
    for (int i = 0; names && buf && i < n; i++)
      names[i] = mrvi_model_coordinate_name(m, i, buf[i]);
    check_strings(f, "/model/name", n, names);
    free(buf);
    free(names);
  }
  check_constraint_model(f, m, s);
  CHECK(exists(f, "/model/description") == (e->description != NULL),
        "/model/description present iff given");
  if (e->description && exists(f, "/model/description")) {
    hid_t d = H5Dopen2(f, "/model/description", H5P_DEFAULT);
    hid_t ft = H5Dget_type(d);
    size_t size = 0;
    char *text = read_fixed(d, 0, ft, 1, &size, "/model/description");
    CHECK(text && strcmp(text, e->description) == 0,
          "/model/description is the input text verbatim");
    free(text);
    H5Tclose(ft);
    H5Dclose(d);
  }

  /* Expected arrays. */
  size_t nmac = 0, nmic = 0, nsol = 0;
  for (long i = 0; i < tr->count; i++) {
    nmac += kept(tr, e, i);
    nmic += micro ? (size_t)tr->r[i].micro_count : 0;
    nsol += tr->r[i].k >= 1;
  }
  double *t = calloc(nmac + 1, sizeof *t);
  double *q = calloc(nmac * (size_t)n + 1, sizeof *q);
  double *p = calloc(nmac * (size_t)n + 1, sizeof *p);
  double *en[4], *lin = calloc(nmac * 3 + 1, sizeof *lin),
                 *ang = calloc(nmac * 3 + 1, sizeof *ang);
  for (int j = 0; j < 4; j++)
    en[j] = calloc(nmac + 1, sizeof *en[j]);
  double *mt = calloc(nmic + 1, sizeof *mt);
  double *mq = calloc(nmic * (size_t)nf + 1, sizeof *mq);
  double *mp = calloc(nmic * (size_t)nf + 1, sizeof *mp);
  int *it = calloc(nsol + 1, sizeof *it);
  double *res = calloc(nsol + 1, sizeof *res);
  /* Constraints: residuals of the kept nodes and of every micro node; the
   * multipliers of kept node i come with record i+1, NaN without it. */
  const size_t R = (size_t)tr->n_lambda;
  double *cres = calloc(nmac + 1, sizeof *cres);
  double *hres = calloc(nmac + 1, sizeof *hres);
  double *lam = calloc(nmac * R + 1, sizeof *lam);
  double *mcres = calloc(nmic + 1, sizeof *mcres);
  size_t a = 0, b = 0, c = 0;
  for (long i = 0; i < tr->count; i++) {
    const rec *r = &tr->r[i];
    if (kept(tr, e, i)) {
      t[a] = r->t;
      memcpy(q + a * (size_t)n, r->q, (size_t)n * sizeof *q);
      memcpy(p + a * (size_t)n, r->p, (size_t)n * sizeof *p);
      en[0][a] = r->kinetic;
      en[1][a] = r->vs;
      en[2][a] = r->vf;
      en[3][a] = r->energy;
      memcpy(lin + a * (size_t)dim, r->lin, (size_t)dim * sizeof *lin);
      memcpy(ang + a * (size_t)n_ang, r->ang, (size_t)n_ang * sizeof *ang);
      cres[a] = r->cres;
      hres[a] = r->hres;
      const double *next = i + 1 < tr->count ? tr->r[i + 1].lambda_prev : NULL;
      for (size_t j = 0; j < R; j++)
        lam[a * R + j] = next ? next[j] : NAN;
      a++;
    }
    for (int j = 0; micro && j < r->micro_count; j++, b++) {
      mt[b] = r->micro_t0 + (double)j * r->micro_dt;
      memcpy(mq + b * (size_t)nf, r->mq + (size_t)j * (size_t)nf,
             (size_t)nf * sizeof *mq);
      memcpy(mp + b * (size_t)nf, r->mp + (size_t)j * (size_t)nf,
             (size_t)nf * sizeof *mp);
      mcres[b] = r->mcres ? r->mcres[j] : NAN;
    }
    if (r->k >= 1) {
      it[c] = r->iterations;
      res[c] = r->residual;
      c++;
    }
  }

  check_f64(f, "/macro/t", 1, nmac, 1, t);
  check_f64(f, "/macro/q", 2, nmac, (size_t)n, q);
  check_f64(f, "/macro/p", 2, nmac, (size_t)n, p);
  check_f64(f, "/macro/kinetic", 1, nmac, 1, en[0]);
  check_f64(f, "/macro/potential_slow", 1, nmac, 1, en[1]);
  check_f64(f, "/macro/potential_fast", 1, nmac, 1, en[2]);
  check_f64(f, "/macro/energy", 1, nmac, 1, en[3]);
  CHECK(exists(f, "/macro/linear_momentum") == (dim > 0),
        "/macro/linear_momentum present iff particles (dimension %d)", dim);
  CHECK(exists(f, "/macro/angular_momentum") == (n_ang > 0),
        "/macro/angular_momentum present iff dimension 2 or 3 (%d)", dim);
  if (dim > 0)
    check_f64(f, "/macro/linear_momentum", 2, nmac, (size_t)dim, lin);
  if (n_ang > 0)
    check_f64(f, "/macro/angular_momentum", 2, nmac, (size_t)n_ang, ang);
  CHECK(exists(f, "/micro") == micro, "/micro present iff micro output (%d)",
        micro);
  if (micro) {
    check_f64(f, "/micro/t", 1, nmic, 1, mt);
    check_f64(f, "/micro/q_fast", 2, nmic, (size_t)nf, mq);
    check_f64(f, "/micro/p_fast", 2, nmic, (size_t)nf, mp);
  }
  static const char *const constraint_outputs[] = {
      "/macro/constraint_residual", "/macro/hidden_constraint_residual",
      "/macro/lambda", "/micro/constraint_residual"};
  for (int j = 0; j < 4; j++)
    CHECK(exists(f, constraint_outputs[j]) == (R > 0 && (j < 3 || micro)),
          "%s present iff constraints (%zu rows)%s", constraint_outputs[j], R,
          j < 3 ? "" : " and /micro");
  if (R > 0) {
    check_f64(f, "/macro/constraint_residual", 1, nmac, 1, cres);
    check_f64(f, "/macro/hidden_constraint_residual", 1, nmac, 1, hres);
    check_f64(f, "/macro/lambda", 2, nmac, R, lam);
    if (micro)
      check_f64(f, "/micro/constraint_residual", 1, nmic, 1, mcres);
  }
  check_data(f, "/solver/iterations", 1, nsol, 1, H5T_NATIVE_INT, sizeof(int),
             it);
  check_f64(f, "/solver/residual", 1, nsol, 1, res);

  free(t);
  free(q);
  free(p);
  for (int j = 0; j < 4; j++)
    free(en[j]);
  free(lin);
  free(ang);
  free(mt);
  free(mq);
  free(mp);
  free(it);
  free(res);
  free(cres);
  free(hres);
  free(lam);
  free(mcres);
  CHECK(H5Fclose(f) >= 0, "%s: closes", path);
}

/* No HDF5 object of any file left open (the writer closes all it opens). */
static void check_no_open_objects(const char *when) {
  ssize_t open = H5Fget_obj_count((hid_t)H5F_OBJ_ALL, H5F_OBJ_ALL);
  CHECK(open == 0, "%s: %zd HDF5 objects still open", when, open);
}

/* ---------------------------------------------------------------------------
 * Every dataset and root attribute is documented in doc/output.md
 * ------------------------------------------------------------------------- */
static char *read_text(const char *path) {
  FILE *fp = fopen(path, "rb");
  if (!fp)
    return NULL;
  fseek(fp, 0, SEEK_END);
  long len = ftell(fp);
  fseek(fp, 0, SEEK_SET);
  char *s = malloc((size_t)len + 1);
  size_t got = fread(s, 1, (size_t)len, fp);
  s[got] = '\0';
  fclose(fp);
  return s;
}

static herr_t doc_link(hid_t g, const char *name, const H5L_info_t *info,
                       void *data) {
  (void)info;
  const char *doc = data;
  hid_t o = H5Oopen(g, name, H5P_DEFAULT);
  if (o >= 0 && H5Iget_type(o) == H5I_DATASET) {
    char key[300];
    snprintf(key, sizeof key, "`/%s`", name);
    CHECK(strstr(doc, key) != NULL, "doc/output.md documents %s", key);
  }
  if (o >= 0)
    H5Oclose(o);
  return 0;
}

static herr_t doc_attr(hid_t loc, const char *name, const H5A_info_t *info,
                       void *data) {
  (void)loc;
  (void)info;
  char key[300];
  snprintf(key, sizeof key, "`%s`", name);
  CHECK(strstr((const char *)data, key) != NULL,
        "doc/output.md documents attribute %s", key);
  return 0;
}

static void check_documented(const char *path) {
  char *doc = read_text(test_source_path("doc/output.md"));
  CHECK(doc != NULL, "doc/output.md exists");
  if (!doc)
    return;
  hid_t f = H5Fopen(path, H5F_ACC_RDONLY, H5P_DEFAULT);
  H5Lvisit(f, H5_INDEX_NAME, H5_ITER_INC, doc_link, doc);
  H5Aiterate2(f, H5_INDEX_NAME, H5_ITER_INC, NULL, doc_attr, doc);
  hid_t d = H5Dopen2(f, "/macro/q", H5P_DEFAULT);
  H5Aiterate2(d, H5_INDEX_NAME, H5_ITER_INC, NULL, doc_attr, doc);
  H5Dclose(d);
  H5Fclose(f);
  free(doc);
}

/* ---------------------------------------------------------------------------
 * Models
 * ------------------------------------------------------------------------- */

/* Law parameters by name (so the test does not depend on their order). */
static void law_params(const char *law, double *par, const char *n1, double v1,
                       const char *n2, double v2) {
  const mrvi_law *l = mrvi_law_find(law);
  CHECK(l != NULL, "law %s registered", law);
  for (int i = 0; l && i < l->n_params; i++) {
    if (n1 && strcmp(l->param_names[i], n1) == 0)
      par[i] = v1;
    if (n2 && strcmp(l->param_names[i], n2) == 0)
      par[i] = v2;
  }
}

/* FPU (arXiv 2406.12991 §6, doc/reproduction.md) with omega^2 = 2500. */
static mrvi_model *fpu_model(void) {
  mrvi_model *m = mrvi_model_create();
  const char *names[6] = {"qs1", "qs2", "qs3", "qf1", "qf2", "qf3"};
  const double q0[6] = {1, 0, 0, 0.02, 0, 0}, v0[6] = {1, 0, 0, 1, 0, 0};
  int ok = 1;
  for (int i = 0; i < 6; i++)
    ok &= mrvi_model_add_coordinate(m, names[i], 1.0,
                                    i < 3 ? MRVI_SLOW : MRVI_FAST, q0[i],
                                    v0[i]) == i;
  double pw[MRVI_LAW_MAX_PARAMS] = {0}, lin[MRVI_LAW_MAX_PARAMS] = {0};
  law_params("power", pw, "coefficient", 0.25, "exponent", 4.0);
  law_params("linear", lin, "stiffness", 2500.0, NULL, 0);
  const int c1[2] = {0, 3}, c2[4] = {1, 4, 0, 3}, c3[4] = {2, 5, 1, 4},
            c4[2] = {2, 5};
  const double a1[2] = {1, -1}, a23[4] = {1, -1, -1, -1}, a4[2] = {1, 1};
  ok &= mrvi_model_add_term(m, MRVI_SLOW, 2, c1, a1, 0, "power", pw) >= 0;
  ok &= mrvi_model_add_term(m, MRVI_SLOW, 4, c2, a23, 0, "power", pw) >= 0;
  ok &= mrvi_model_add_term(m, MRVI_SLOW, 4, c3, a23, 0, "power", pw) >= 0;
  ok &= mrvi_model_add_term(m, MRVI_SLOW, 2, c4, a4, 0, "power", pw) >= 0;
  for (int i = 3; i < 6; i++) {
    const double one = 1.0;
    ok &= mrvi_model_add_term(m, MRVI_FAST, 1, &i, &one, 0, "linear", lin) >= 0;
  }
  ok &= mrvi_model_set_name(m, "fpu") == 0;
  CHECK(ok, "FPU model builds: %s", mrvi_model_errmsg(m));
  return m;
}

/* Particles in `dim` dimensions: slow m1 (mass 2), fast m2 (mass 1), a slow
 * spring between them, a fast anchor spring on m2 and gravity; plus one
 * slow generalised coordinate c (declared first) on a slow linear term. */
static mrvi_model *particle_model(int dim) {
  mrvi_model *m = mrvi_model_create();
  int ok = mrvi_model_set_dimension(m, dim) == 0;
  ok &= mrvi_model_add_coordinate(m, "c", 1.5, MRVI_SLOW, 0.1, -0.2) == 0;
  const double x1[3] = {0, 0, 0}, v1[3] = {0.1, 0, 0.05};
  const double x2[3] = {1, 0.1, 0.1}, v2[3] = {0, 1, 0};
  ok &= mrvi_model_add_particle(m, "m1", 2.0, MRVI_SLOW, x1, v1) == 0;
  ok &= mrvi_model_add_particle(m, "m2", 1.0, MRVI_FAST, x2, v2) == 1;
  double k1[MRVI_LAW_MAX_PARAMS] = {0}, k2[MRVI_LAW_MAX_PARAMS] = {0};
  law_params("linear", k1, "stiffness", 10.0, NULL, 0);
  law_params("linear", k2, "stiffness", 400.0, NULL, 0);
  ok &= mrvi_model_add_spring(m, MRVI_SLOW, 0, 1, "linear", k1, 1.0) >= 0;
  const double anchor[3] = {1, 0, 0};
  ok &= mrvi_model_add_anchor_spring(m, MRVI_FAST, 1, anchor, "linear", k2,
                                     0.0) >= 0;
  const int c = 0;
  const double one = 1.0;
  ok &= mrvi_model_add_term(m, MRVI_SLOW, 1, &c, &one, 0, "linear", k1) >= 0;
  double g[3] = {0, 0, 0};
  g[dim - 1] = -9.81; /* along the last axis */
  ok &= mrvi_model_set_gravity(m, g) >= 0;
  ok &= mrvi_model_set_name(m, "particles") == 0;
  CHECK(ok, "particle model (%d-D) builds: %s", dim, mrvi_model_errmsg(m));
  return m;
}

/* Slow-only model: no fast coordinates, no particles. */
static mrvi_model *slow_model(void) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_add_coordinate(m, "x", 1.0, MRVI_SLOW, 1.0, 0.0);
  mrvi_model_add_coordinate(m, "y", 3.0, MRVI_SLOW, 0.0, 1.0);
  mrvi_model_set_name(m, "slow");
  return m;
}

/* 2-D constrained particles under gravity: a slow cart on the plane y = 0
 * (macro nodes, 1 row), a fast bob on a rod of length 1 from the cart
 * (micro nodes, 1 row) and a slow pin fixed where it starts (macro nodes,
 * 2 rows): 4 multipliers.  Initial data meet g = 0 and G M^-1 p = 0. */
static mrvi_model *constrained_model(void) {
  mrvi_model *m = mrvi_model_create();
  int ok = mrvi_model_set_dimension(m, 2) == 0;
  const double xc[2] = {0, 0}, vc[2] = {1, 0};
  const double xb[2] = {0, -1}, vb[2] = {0.5, 0};
  const double xp[2] = {2, 1}, vp[2] = {0, 0};
  ok &= mrvi_model_add_particle(m, "cart", 2.0, MRVI_SLOW, xc, vc) == 0;
  ok &= mrvi_model_add_particle(m, "bob", 1.0, MRVI_FAST, xb, vb) == 1;
  ok &= mrvi_model_add_particle(m, "pin", 1.0, MRVI_SLOW, xp, vp) == 2;
  const double g[2] = {0, -9.81}, up[2] = {0, 1};
  ok &= mrvi_model_set_gravity(m, g) >= 0;
  ok &= mrvi_model_add_plane(m, 0, up, NAN) == 0;
  ok &= mrvi_model_add_distance(m, 0, 1, NAN) == 1;
  ok &= mrvi_model_add_fixed(m, 2, NULL, NULL) == 2;
  ok &= mrvi_model_set_name(m, "cart-pendulum") == 0;
  CHECK(ok && mrvi_model_constraint_rows(m) == 4,
        "constrained model builds with 4 constraint rows: %s",
        mrvi_model_errmsg(m));
  return m;
}

/* Slow-only model with one linear constraint x + 2 y = 1 (no /micro). */
static mrvi_model *slow_constrained_model(void) {
  mrvi_model *m = slow_model();
  const int c[2] = {0, 1};
  const double a[2] = {1, 2};
  CHECK(mrvi_model_add_linear_constraint(m, 2, c, a, NAN) == 0,
        "linear constraint on the slow model: %s", mrvi_model_errmsg(m));
  return m;
}

static mrvi_settings settings(const char *scheme, double dT, int p,
                              double t_end) {
  mrvi_settings s;
  mrvi_settings_default(&s);
  CHECK(mrvi_settings_set_scheme(&s, scheme) == 0, "scheme %s", scheme);
  s.macro_step = dT;
  s.micro_steps = p;
  s.t_end = t_end;
  s.newton_tol = 1e-10;
  s.newton_max_iter = 30;
  return s;
}

/* ---------------------------------------------------------------------------
 * Synthetic records: the writer alone, no numerics
 * ------------------------------------------------------------------------- */
typedef struct synth {
  int n, nf, p, n_lambda;
  double dT;
  double *q, *pp, *mq, *mp;
  double *lambda, *mcres; /* n_lambda; p + 1 */
} synth;

static void synth_init(synth *g, const mrvi_model *m, const mrvi_settings *s) {
  g->n = mrvi_model_n(m);
  g->nf = mrvi_model_n_fast(m);
  g->p = s->micro_steps;
  g->dT = s->macro_step;
  g->q = malloc((size_t)g->n * sizeof *g->q);
  g->pp = malloc((size_t)g->n * sizeof *g->pp);
  g->mq = malloc(((size_t)g->p * (size_t)g->nf + 1) * sizeof *g->mq);
  g->mp = malloc(((size_t)g->p * (size_t)g->nf + 1) * sizeof *g->mp);
  g->n_lambda = mrvi_model_constraint_rows(m);
  g->lambda = malloc(((size_t)g->n_lambda + 1) * sizeof *g->lambda);
  g->mcres = malloc(((size_t)g->p + 1) * sizeof *g->mcres);
}

static void synth_free(synth *g) {
  free(g->q);
  free(g->pp);
  free(g->mq);
  free(g->mp);
  free(g->lambda);
  free(g->mcres);
}

/* Record k with distinct, non-round values in every field. */
static mrvi_record synth_record(synth *g, long k) {
  mrvi_record r;
  memset(&r, 0, sizeof r);
  r.k = k;
  r.t = (double)k * g->dT;
  for (int j = 0; j < g->n; j++) {
    g->q[j] = sin(0.37 * (double)k + 1.1 * j);
    g->pp[j] = cos(0.91 * (double)k - 0.3 * j) / 3.0;
  }
  r.q = g->q;
  r.p = g->pp;
  r.kinetic = 1.0 / (double)(k + 3);
  r.potential_slow = exp(-0.01 * (double)k);
  r.potential_fast = sqrt((double)k + 0.5);
  r.energy = r.kinetic + r.potential_slow + r.potential_fast;
  for (int j = 0; j < 3; j++) {
    r.linear_momentum[j] = 0.1 * (double)k + j / 7.0;
    r.angular_momentum[j] = -0.2 * (double)k + j / 11.0;
  }
  r.iterations = k ? (int)(k % 5) + 1 : 0;
  r.residual = k ? 1e-12 * (double)(k % 13) / 3.0 : 0.0;
  r.micro_count = k ? g->p : 1;
  r.micro_dt = g->dT / g->p;
  r.micro_t0 = k ? (double)(k - 1) * g->dT + r.micro_dt : 0.0;
  for (int i = 0; i < r.micro_count * g->nf; i++) {
    g->mq[i] = tan(0.001 * (double)(k * 31 + i));
    g->mp[i] = -(double)(k * 17 + i) / 9.0;
  }
  r.micro_q_fast = g->mq;
  r.micro_p_fast = g->mp;
  if (g->n_lambda > 0) {
    /* Multipliers of node k-1, distinct for every node and row. */
    r.n_lambda = g->n_lambda;
    for (int j = 0; j < g->n_lambda; j++)
      g->lambda[j] = 100.0 * (double)(k - 1) + 1.0 / (double)(j + 3);
    r.lambda_prev = k ? g->lambda : NULL;
    r.constraint_residual = 1e-11 * (double)(k % 7 + 1) / 3.0;
    r.hidden_constraint_residual = 1e-9 * (double)(k % 5 + 1) / 7.0;
    for (int i = 0; i < r.micro_count; i++)
      g->mcres[i] = 1e-12 * (double)(k * 13 + i) / 11.0;
    r.micro_constraint_residual = g->mcres;
  }
  return r;
}

/* Write records 0..last with the writer (settings s, micro, every) and
 * verify. */
static void synthetic_case_s(const char *name, mrvi_model *m,
                             const mrvi_settings *sp, long last, int every,
                             int micro, const char *description) {
  const mrvi_settings s = *sp;
  char path[64];
  snprintf(path, sizeof path, "synthetic_%s.h5", name);
  mrvi_writer_options opt = {"synthetic", description, every, micro, 0.0,
                             0,           0,           0,     0,     0};
  mrvi_writer *w = NULL;
  char msg[512];
  int rc = mrvi_writer_open(path, m, &s, &opt, &w, msg, sizeof msg);
  CHECK(rc == 0 && w, "%s: open: %s", name, msg);
  if (!w)
    return;
  traj tr;
  traj_init(&tr, m);
  synth g;
  synth_init(&g, m, &s);
  tee t = {w, &tr, -1};
  for (long k = 0; k <= last; k++) {
    mrvi_record r = synth_record(&g, k);
    CHECK(tee_observe(&t, &r) == 0, "%s: observe k = %ld", name, k);
  }
  rc = mrvi_writer_close(w, NULL, msg, sizeof msg);
  CHECK(rc == 0 && msg[0] == '\0', "%s: close: %s", name, msg);
  check_no_open_objects(name);
  expect e = {m, &s, "synthetic", description, every, micro, "completed", 1};
  verify(path, &tr, &e);
  if (strstr(name, "full"))
    check_documented(path);
  traj_free(&tr);
  synth_free(&g);
  remove(path);
}

static void synthetic_case(const char *name, mrvi_model *m, int p, long last,
                           int every, int micro, const char *description) {
  mrvi_settings s =
      settings("trapezoidal-midpoint", 0.25, p, 0.25 * (double)last);
  synthetic_case_s(name, m, &s, last, every, micro, description);
}

/* Constrained models: distinct multipliers per node show that row j of
 * /macro/lambda comes from record j+1, including when row j was flushed
 * before record j+1 arrived (records 256, 512 after the flushes at 255 and
 * 511, and at close). */
static void test_synthetic_constrained(void) {
  mrvi_model *mc = constrained_model(), *msc = slow_constrained_model();
  synthetic_case("cons_full", mc, 4, 599, 1, 1, "constrained\n");
  synthetic_case("cons_patch_at_close", mc, 2, 256, 1, 1, NULL);
  synthetic_case("cons_every3", mc, 4, 10, 3, 1, NULL); /* 0,3,6,9,10 */
  synthetic_case("cons_every5", mc, 2, 10, 5, 1, NULL); /* 0,5,10 */
  synthetic_case("cons_every7_long", mc, 3, 700, 7, 1, NULL);
  synthetic_case("cons_nomicro", mc, 4, 20, 1, 0, NULL);
  synthetic_case("cons_p1", mc, 1, 300, 1, 1, NULL);
  synthetic_case("cons_slow", msc, 3, 20, 2, 1, NULL);
  mrvi_settings s = settings("midpoint-midpoint", 0.5, 2, 5.0);
  s.constraint_form = MRVI_FORM_NULL_SPACE;
  s.constraint_tol = 3e-9;
  s.project_momenta = 0;
  synthetic_case_s("cons_null_space", mc, &s, 10, 1, 1, NULL);
  mrvi_model_free(msc);
  mrvi_model_free(mc);
}

static void test_synthetic(void) {
  mrvi_model *m3 = particle_model(3), *m2 = particle_model(2),
             *m1 = particle_model(1), *ms = slow_model();
  /* 600 records: two record-count flushes (256) and the rest at close. */
  synthetic_case("full", m3, 4, 599, 1, 1, "name: synthetic\n# ünïcödé\n");
  synthetic_case("every3", m3, 4, 10, 3, 1, NULL); /* keeps 0,3,6,9,10 */
  synthetic_case("every5", m3, 2, 10, 5, 1, NULL); /* 0,5,10: no duplicate */
  synthetic_case("every7_long", m3, 3, 700, 7, 1, NULL); /* pending at flush */
  synthetic_case("nomicro", m3, 4, 20, 1, 0, NULL);
  synthetic_case("dim2", m2, 2, 20, 1, 1, NULL);
  synthetic_case("dim1", m1, 2, 20, 1, 1, NULL);
  synthetic_case("slow", ms, 3, 20, 2, 1, "");
  synthetic_case("p1", m3, 1, 300, 1, 1, NULL);

  /* Explicit check of the `every` rule on /macro/t (k = 0,3,6,9,10). */
  {
    mrvi_settings s = settings("midpoint-midpoint", 0.5, 2, 5.0);
    mrvi_writer_options opt = {"x", NULL, 3, 1, 0.0, 0, 0, 0, 0, 0};
    mrvi_writer *w = NULL;
    char msg[256];
    mrvi_writer_open("every_rule.h5", m3, &s, &opt, &w, msg, sizeof msg);
    synth g;
    synth_init(&g, m3, &s);
    for (long k = 0; k <= 10 && w; k++) {
      mrvi_record r = synth_record(&g, k);
      mrvi_writer_observe(w, &r);
    }
    mrvi_writer_close(w, "completed", msg, sizeof msg);
    hid_t f = H5Fopen("every_rule.h5", H5F_ACC_RDONLY, H5P_DEFAULT);
    int rank;
    hsize_t dims[2];
    double *t =
        read_all(f, "/macro/t", H5T_NATIVE_DOUBLE, sizeof(double), &rank, dims);
    const double want[5] = {0, 1.5, 3.0, 4.5, 5.0};
    CHECK(t && dims[0] == 5 && memcmp(t, want, sizeof want) == 0,
          "every = 3 over k = 0..10 keeps t = 0, 1.5, 3, 4.5, 5");
    free(t);
    int *it = read_all(f, "/solver/iterations", H5T_NATIVE_INT, sizeof(int),
                       &rank, dims);
    CHECK(it && dims[0] == 10, "every = 3: /solver keeps all 10 steps");
    free(it);
    double *mt =
        read_all(f, "/micro/t", H5T_NATIVE_DOUBLE, sizeof(double), &rank, dims);
    CHECK(mt && dims[0] == 21 && mt[20] == 5.0,
          "every = 3: /micro keeps all 10 p + 1 nodes, last at t = 5");
    free(mt);
    H5Fclose(f);
    synth_free(&g);
    remove("every_rule.h5");
  }
  mrvi_model_free(m3);
  mrvi_model_free(m2);
  mrvi_model_free(m1);
  mrvi_model_free(ms);
}

/* Records out of order and bad micro counts are refused with a message; the
 * file stays valid and close reports the first error. */
static void test_bad_records(void) {
  mrvi_model *m = particle_model(3);
  mrvi_settings s = settings("midpoint-midpoint", 0.1, 2, 1.0);
  mrvi_writer *w = NULL;
  char msg[512];
  CHECK(mrvi_writer_open("bad_records.h5", m, &s, NULL, &w, msg, sizeof msg) ==
            0,
        "open with default options: %s", msg);
  synth g;
  synth_init(&g, m, &s);
  mrvi_record r0 = synth_record(&g, 0);
  CHECK(mrvi_writer_observe(w, &r0) == 0, "k = 0 accepted");
  mrvi_record r2 = synth_record(&g, 2);
  CHECK(mrvi_writer_observe(w, &r2) == MRVI_EINVAL, "k = 2 after 0 refused");
  mrvi_record r1 = synth_record(&g, 1);
  CHECK(mrvi_writer_observe(w, &r1) == MRVI_EINVAL,
        "writer stays failed after an error");
  int rc = mrvi_writer_close(w, "stopped", msg, sizeof msg);
  CHECK(rc == MRVI_EINVAL && strstr(msg, "order"),
        "close reports the first error: %d %s", rc, msg);
  check_no_open_objects("bad records");
  hid_t f = H5Fopen("bad_records.h5", H5F_ACC_RDONLY, H5P_DEFAULT);
  CHECK(f >= 0, "file valid after a refused record");
  int rank;
  hsize_t dims[2];
  double *t =
      read_all(f, "/macro/t", H5T_NATIVE_DOUBLE, sizeof(double), &rank, dims);
  CHECK(t && dims[0] == 1, "the accepted record is kept");
  free(t);
  check_attr_string(f, "system", "particles", 0); /* model name by default */
  check_attr_string(f, "stop_reason", "stopped", 0);
  H5Fclose(f);

  /* Too many micro nodes. */
  CHECK(mrvi_writer_open("bad_records.h5", m, &s, NULL, &w, msg, sizeof msg) ==
            0,
        "reopen: %s", msg);
  r0 = synth_record(&g, 0);
  r0.micro_count = 3; /* p = 2 */
  CHECK(mrvi_writer_observe(w, &r0) == MRVI_EINVAL, "micro_count > p refused");
  rc = mrvi_writer_close(w, NULL, msg, sizeof msg);
  CHECK(rc == MRVI_EINVAL && strstr(msg, "micro"), "message: %s", msg);
  CHECK(mrvi_writer_close(NULL, NULL, msg, sizeof msg) == 0,
        "close(NULL) is a no-op");

  /* A constrained model needs the multipliers of the previous node. */
  mrvi_model *mc = constrained_model();
  synth gc;
  synth_init(&gc, mc, &s);
  CHECK(mrvi_writer_open("bad_records.h5", mc, &s, NULL, &w, msg, sizeof msg) ==
            0,
        "open constrained: %s", msg);
  r0 = synth_record(&gc, 0);
  CHECK(mrvi_writer_observe(w, &r0) == 0, "constrained k = 0 accepted");
  r1 = synth_record(&gc, 1);
  r1.lambda_prev = NULL;
  CHECK(mrvi_writer_observe(w, &r1) == MRVI_EINVAL,
        "k = 1 without lambda_prev refused");
  rc = mrvi_writer_close(w, NULL, msg, sizeof msg);
  CHECK(rc == MRVI_EINVAL && strstr(msg, "lambda_prev"), "message: %s", msg);
  CHECK(mrvi_writer_open("bad_records.h5", mc, &s, NULL, &w, msg, sizeof msg) ==
            0,
        "reopen constrained: %s", msg);
  r0 = synth_record(&gc, 0);
  r0.n_lambda = 3;
  CHECK(mrvi_writer_observe(w, &r0) == MRVI_EINVAL,
        "record with 3 constraint rows for a model with 4 refused");
  rc = mrvi_writer_close(w, NULL, msg, sizeof msg);
  CHECK(rc == MRVI_EINVAL && strstr(msg, "constraint rows"), "message: %s",
        msg);
  synth_free(&gc);
  mrvi_model_free(mc);

  /* Bad options. */
  static char sentinel;
  mrvi_writer_options opt = {NULL, NULL, 0, 1, 0.0, 0, 0, 0, 0, 0};
  w = (mrvi_writer *)(void *)&sentinel;
  CHECK(mrvi_writer_open("bad_records.h5", m, &s, &opt, &w, msg, sizeof msg) ==
                MRVI_EINVAL &&
            w == NULL && strstr(msg, "every"),
        "every = 0 refused: %s", msg);
  CHECK(mrvi_writer_open("bad_records.h5", NULL, &s, NULL, &w, msg,
                         sizeof msg) == MRVI_EINVAL,
        "NULL model refused");
  check_no_open_objects("bad options");
  synth_free(&g);
  mrvi_model_free(m);
  remove("bad_records.h5");
}

/* A process killed hard (SIGKILL, no close) leaves a readable file with
 * every flushed row: flushes happen at least every 256 records.  With
 * constraints, /macro/lambda has the rows of /macro/t, the last one NaN (its
 * multipliers came with a record after the last flush). */
static void hard_kill_case(mrvi_model *m) {
  mrvi_settings s = settings("midpoint-midpoint", 0.1, 3, 100.0);
  const long last = 599;
  const char *path = "hard_kill.h5";
  fflush(NULL);
  pid_t pid = fork();
  if (pid == 0) {
    mrvi_writer *w = NULL;
    char msg[256];
    mrvi_writer_options opt = {"killed", NULL, 1, 1, 0.0, 0, 0, 0, 0, 0};
    if (mrvi_writer_open(path, m, &s, &opt, &w, msg, sizeof msg))
      _exit(3);
    synth g;
    synth_init(&g, m, &s);
    for (long k = 0; k <= last; k++) {
      mrvi_record r = synth_record(&g, k);
      if (mrvi_writer_observe(w, &r))
        _exit(4);
    }
    kill(getpid(), SIGKILL);
    _exit(5);
  }
  int status = 0;
  waitpid(pid, &status, 0);
  CHECK(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL,
        "child killed by SIGKILL (status %d)", status);
  /* Written in SWMR mode and killed: HDF5's "open for writing" flag is set,
   * a plain open refuses the file, SWMR reading opens it. */
  hid_t f = H5Fopen(path, H5F_ACC_RDONLY, H5P_DEFAULT);
  CHECK(f < 0, "a plain open refuses the file of a killed process");
  if (f >= 0)
    H5Fclose(f);
  H5Eclear2(H5E_DEFAULT);
  f = mrvi_h5_open_read(path, H5P_DEFAULT);
  CHECK(f >= 0, "file of a killed process opens for SWMR reading");
  if (f >= 0) {
    int rank;
    hsize_t dims[2];
    double *t =
        read_all(f, "/macro/t", H5T_NATIVE_DOUBLE, sizeof(double), &rank, dims);
    hsize_t rows = dims[0];
    CHECK(t && rows >= 512 && rows <= (hsize_t)last + 1,
          "killed after %ld records: %llu macro rows (>= 512 flushed)",
          last + 1, (unsigned long long)rows);
    free(t);
    /* The flushed prefix is exactly the records 0..rows-1. */
    traj tr;
    traj_init(&tr, m);
    synth g;
    synth_init(&g, m, &s);
    for (long k = 0; k < (long)rows; k++) {
      mrvi_record r = synth_record(&g, k);
      traj_add(&tr, &r);
    }
    check_attr_long(f, "steps_completed", (long)rows - 1);
    H5Fclose(f);
    expect e = {m, &s, "killed", NULL, 1, 1, "running", 0};
    verify(path, &tr, &e);
    traj_free(&tr);
    synth_free(&g);
  }
  remove(path);
}

/* A second writer on a file a live writer holds is refused before it
 * touches the file; an existing file that is no mrvi output is refused
 * unless force, an earlier mrvi output is replaced. */
static void test_lock(void) {
  mrvi_model *m = particle_model(2);
  mrvi_settings s = settings("midpoint-midpoint", 0.1, 2, 1.0);
  const char *path = "lock.h5";
  char msg[512] = "";
  mrvi_writer *w = NULL, *w2 = NULL;
  remove(path);
  CHECK(mrvi_writer_open(path, m, &s, NULL, &w, msg, sizeof msg) == MRVI_OK,
        "first writer opens: %s", msg);
  CHECK(mrvi_writer_open(path, m, &s, NULL, &w2, msg, sizeof msg) == MRVI_EIO &&
            !w2 && strstr(msg, "in use by another run"),
        "second writer refused: %s", msg);
  CHECK(mrvi_writer_close(w, NULL, msg, sizeof msg) == MRVI_OK,
        "first writer closes after the refusal: %s", msg);
  hid_t f = H5Fopen(path, H5F_ACC_RDONLY, H5P_DEFAULT);
  CHECK(f >= 0, "first writer's file intact");
  if (f >= 0)
    H5Fclose(f);
  CHECK(mrvi_writer_open(path, m, &s, NULL, &w, msg, sizeof msg) == MRVI_OK,
        "an earlier mrvi output is replaced: %s", msg);
  mrvi_writer_close(w, NULL, msg, sizeof msg);
  FILE *fp = fopen(path, "w");
  if (fp) {
    fputs("not an HDF5 file\n", fp);
    fclose(fp);
  }
  CHECK(mrvi_writer_open(path, m, &s, NULL, &w, msg, sizeof msg) == MRVI_EIO &&
            strstr(msg, "not an mrvi output"),
        "foreign file refused: %s", msg);
  char buf[32] = "";
  fp = fopen(path, "r");
  if (fp) {
    if (!fgets(buf, sizeof buf, fp))
      buf[0] = '\0';
    fclose(fp);
  }
  CHECK(!strcmp(buf, "not an HDF5 file\n"), "foreign file untouched");
  mrvi_writer_options opt = {NULL, NULL, 1, 1, 0.0, 1, 0, 0, 0, 0};
  CHECK(mrvi_writer_open(path, m, &s, &opt, &w, msg, sizeof msg) == MRVI_OK,
        "force replaces it: %s", msg);
  mrvi_writer_close(w, NULL, msg, sizeof msg);
  check_no_open_objects("lock");
  mrvi_model_free(m);
  remove(path);
}

static void test_hard_kill(void) {
  mrvi_model *m = particle_model(3), *mc = constrained_model();
  hard_kill_case(m);
  hard_kill_case(mc);
  mrvi_model_free(mc);
  mrvi_model_free(m);
}

/* An unwritable path fails with a message naming it, prints nothing (even
 * with HDF5's printer switched on by the caller) and leaves the caller's
 * error-printing setting as it was. */
static void test_unwritable(void) {
  mrvi_model *m = fpu_model();
  mrvi_settings s = settings("midpoint-midpoint", 0.1, 2, 1.0);
  H5Eset_auto2(H5E_DEFAULT, (H5E_auto2_t)H5Eprint2, stderr);
  const char *paths[2] = {"no-such-directory/out.h5", "."};
  for (int i = 0; i < 2; i++) {
    fflush(stderr);
    int saved = dup(2);
    FILE *tmp = tmpfile();
    dup2(fileno(tmp), 2);
    static char sentinel;
    mrvi_writer *w = (mrvi_writer *)(void *)&sentinel;
    char msg[512] = "untouched";
    int rc = mrvi_writer_open(paths[i], m, &s, NULL, &w, msg, sizeof msg);
    fflush(stderr);
    dup2(saved, 2);
    close(saved);
    long printed = (long)lseek(fileno(tmp), 0, SEEK_END);
    fclose(tmp);
    CHECK(rc == MRVI_EIO, "open %s fails with MRVI_EIO (%d)", paths[i], rc);
    CHECK(w == NULL, "open %s: *out = NULL", paths[i]);
    CHECK(strstr(msg, paths[i]) && strlen(msg) > strlen(paths[i]) + 10,
          "message names the path and the reason: %s", msg);
    CHECK(printed == 0, "open %s printed %ld bytes on stderr", paths[i],
          printed);
  }
  H5E_auto2_t func = NULL;
  void *data = NULL;
  H5Eget_auto2(H5E_DEFAULT, &func, &data);
  CHECK(func == (H5E_auto2_t)H5Eprint2 && data == stderr,
        "caller's HDF5 error printer restored");
  H5Eset_auto2(H5E_DEFAULT, NULL, NULL);
  check_no_open_objects("unwritable");
  mrvi_model_free(m);
}

/* An I/O failure during the run (file size limit: write() fails with
 * EFBIG) makes observe return MRVI_EIO with the system's reason; close
 * reports it too, releases every HDF5 object and nothing is printed.  Runs
 * in a child process, which exits with its number of failed checks. */
static void test_io_error(void) {
  fflush(NULL);
  pid_t pid = fork();
  if (pid == 0) {
    test_failed = 0;
    signal(SIGXFSZ, SIG_IGN);
    struct rlimit rl;
    getrlimit(RLIMIT_FSIZE, &rl);
    rl.rlim_cur = 48 << 10;
    setrlimit(RLIMIT_FSIZE, &rl);
    mrvi_model *m = particle_model(3);
    mrvi_settings s = settings("midpoint-midpoint", 0.01, 4, 1000.0);
    mrvi_writer *w = NULL;
    char msg[512] = "", cmsg[512] = "";
    int saved = dup(2);
    FILE *tmp = tmpfile();
    dup2(fileno(tmp), 2);
    int rc = mrvi_writer_open("io_error.h5", m, &s, NULL, &w, msg, sizeof msg);
    int orc = rc;
    long k = 0;
    synth g;
    synth_init(&g, m, &s);
    for (; orc == 0 && k < 100000; k++) {
      mrvi_record r = synth_record(&g, k);
      orc = mrvi_writer_observe(w, &r);
    }
    int crc = mrvi_writer_close(w, "stopped", cmsg, sizeof cmsg);
    fflush(stderr);
    dup2(saved, 2);
    close(saved);
    long printed = (long)lseek(fileno(tmp), 0, SEEK_END);
    fclose(tmp);
    CHECK(rc == 0, "open under a 48 KiB file size limit: %s", msg);
    CHECK(orc == MRVI_EIO, "observe fails with MRVI_EIO (%d after %ld records)",
          orc, k);
    CHECK(crc == MRVI_EIO && strstr(cmsg, "io_error.h5: ") == cmsg &&
              strstr(cmsg, strerror(EFBIG)),
          "close reports the write failure: %s", cmsg);
    CHECK(printed == 0, "nothing printed on stderr (%ld bytes)", printed);
    check_no_open_objects("after an I/O failure");
    synth_free(&g);
    mrvi_model_free(m);
    remove("io_error.h5");
    _exit(test_failed < 100 ? test_failed : 100);
  }
  int status = 0;
  waitpid(pid, &status, 0);
  CHECK(WIFEXITED(status) && WEXITSTATUS(status) == 0,
        "I/O failure checks (child status %d)", status);
}

/* ---------------------------------------------------------------------------
 * Real runs through mrvi_run
 * ------------------------------------------------------------------------- */

/* The constraint outputs of a run file checked through /macro/t alone
 * (independently of verify's bookkeeping): row j of the residuals is that of
 * the record of the node at /macro/t[j]; row j of /macro/lambda is the
 * lambda_prev of the record after that node, all NaN for the last node;
 * /micro/constraint_residual has the N p + 1 micro residuals in order. */
static void check_constraint_rows(const char *name, const char *path,
                                  const traj *tr, const mrvi_settings *s) {
  const int R = tr->n_lambda;
  hid_t f = H5Fopen(path, H5F_ACC_RDONLY, H5P_DEFAULT);
  int rank, lrank;
  hsize_t dt[2], dc[2], dh[2], dl[2], dm[2];
  const hid_t F = H5T_NATIVE_DOUBLE;
  const size_t E = sizeof(double);
  double *t = read_all(f, "/macro/t", F, E, &rank, dt);
  double *cres = read_all(f, "/macro/constraint_residual", F, E, &rank, dc);
  double *hres =
      read_all(f, "/macro/hidden_constraint_residual", F, E, &rank, dh);
  double *lam = read_all(f, "/macro/lambda", F, E, &lrank, dl);
  double *mcres = read_all(f, "/micro/constraint_residual", F, E, &rank, dm);
  H5Fclose(f);
  const hsize_t rows = dt[0];
  CHECK(t && cres && hres && lam && mcres, "%s: constraint outputs readable",
        name);
  CHECK(dc[0] == rows && dh[0] == rows,
        "%s: residuals have the %llu rows of /macro/t", name,
        (unsigned long long)rows);
  CHECK(lrank == 2 && dl[0] == rows && dl[1] == (hsize_t)R,
        "%s: /macro/lambda is %llu x %llu, expected %llu x %d", name,
        (unsigned long long)dl[0], (unsigned long long)dl[1],
        (unsigned long long)rows, R);
  if (t && cres && hres && lam && dc[0] == rows && dh[0] == rows &&
      dl[0] == rows && dl[1] == (hsize_t)R) {
    int same_res = 1, lag = 1, last_nan = 1;
    for (hsize_t j = 0; j < rows; j++) {
      const long k = lround(t[j] / s->macro_step);
      CHECK(k >= 0 && k < tr->count && tr->r[k].k == k,
            "%s: /macro/t[%llu] is the node of record %ld", name,
            (unsigned long long)j, k);
      if (k < 0 || k >= tr->count)
        break;
      const rec *r = &tr->r[k];
      same_res &= memcmp(&cres[j], &r->cres, E) == 0 &&
                  memcmp(&hres[j], &r->hres, E) == 0;
      const double *row = lam + j * (size_t)R;
      if (k + 1 < tr->count) {
        lag &= tr->r[k + 1].lambda_prev &&
               memcmp(row, tr->r[k + 1].lambda_prev, (size_t)R * E) == 0;
      } else {
        last_nan &= j == rows - 1;
        for (int i = 0; i < R; i++)
          last_nan &= isnan(row[i]);
      }
    }
    CHECK(same_res, "%s: residual rows are the records' values", name);
    CHECK(lag,
          "%s: /macro/lambda row j is lambda_prev of the record after "
          "node j",
          name);
    CHECK(last_nan, "%s: the last /macro/lambda row (and only it) is NaN",
          name);
  }
  const long steps = tr->count - 1;
  CHECK(dm[0] == (hsize_t)(steps * s->micro_steps + 1),
        "%s: %llu micro residual rows, expected %ld", name,
        (unsigned long long)dm[0], steps * s->micro_steps + 1);
  if (mcres && dm[0] == (hsize_t)(steps * s->micro_steps + 1)) {
    int same = 1;
    size_t b = 0;
    for (long i = 0; i < tr->count; i++)
      for (int j = 0; j < tr->r[i].micro_count; j++, b++)
        same &= memcmp(&mcres[b], &tr->r[i].mcres[j], E) == 0;
    CHECK(same, "%s: /micro/constraint_residual rows are the records'", name);
  }
  free(t);
  free(cres);
  free(hres);
  free(lam);
  free(mcres);
}
static void run_case(const char *name, mrvi_model *m, const mrvi_settings *s,
                     int every, long stop_at) {
  char path[64];
  snprintf(path, sizeof path, "run_%s.h5", name);
  mrvi_writer_options opt = {
      name, "description text\n", every, 1, 0.0, 0, 0, 0, 0, 0};
  mrvi_writer *w = NULL;
  char msg[512];
  int rc = mrvi_writer_open(path, m, s, &opt, &w, msg, sizeof msg);
  CHECK(rc == 0, "%s: open: %s", name, msg);
  if (rc)
    return;
  traj tr;
  traj_init(&tr, m);
  tee t = {w, &tr, stop_at};
  mrvi_summary sum;
  rc = mrvi_run(m, s, tee_observe, &t, NULL, &sum);
  const long N = mrvi_settings_n_steps(s);
  if (stop_at < 0) {
    CHECK(rc == 0, "%s: run completes: %s", name, sum.message);
    CHECK(tr.count == N + 1, "%s: %ld records for N = %ld", name, tr.count, N);
  } else {
    CHECK(rc == MRVI_EINTERRUPTED && sum.message[0],
          "%s: run stopped by the observer: %d %s", name, rc, sum.message);
    CHECK(tr.count == stop_at + 1, "%s: %ld records", name, tr.count);
  }
  int crc = mrvi_writer_close(w, sum.message, msg, sizeof msg);
  CHECK(crc == 0, "%s: close: %s", name, msg);
  check_no_open_objects(name);
  expect e = {m,
              s,
              name,
              "description text\n",
              every,
              1,
              stop_at < 0 ? "completed" : sum.message,
              1};
  verify(path, &tr, &e);

  /* Shapes as documented: N+1 macro, N p + 1 micro, N solver rows. */
  long steps = tr.count - 1, p = s->micro_steps;
  hid_t f = H5Fopen(path, H5F_ACC_RDONLY, H5P_DEFAULT);
  int rank;
  hsize_t dims[2];
  double *x;
  x = read_all(f, "/macro/t", H5T_NATIVE_DOUBLE, sizeof(double), &rank, dims);
  long want = every == 1 ? steps + 1 : steps / every + 1 + (steps % every != 0);
  CHECK(dims[0] == (hsize_t)want, "%s: %llu macro rows, expected %ld", name,
        (unsigned long long)dims[0], want);
  free(x);
  x = read_all(f, "/micro/t", H5T_NATIVE_DOUBLE, sizeof(double), &rank, dims);
  CHECK(dims[0] == (hsize_t)(steps * p + 1),
        "%s: %llu micro rows, expected %ld", name, (unsigned long long)dims[0],
        steps * p + 1);
  free(x);
  x = read_all(f, "/solver/residual", H5T_NATIVE_DOUBLE, sizeof(double), &rank,
               dims);
  CHECK(dims[0] == (hsize_t)steps, "%s: %llu solver rows, expected %ld", name,
        (unsigned long long)dims[0], steps);
  free(x);
  check_attr_long(f, "steps_completed", steps);
  H5Fclose(f);
  if (mrvi_model_constraint_rows(m) > 0)
    check_constraint_rows(name, path, &tr, s);

  /* As documented: micro row k p (the last micro node of a step, or the
   * initial node) is the macro node k, positions and momenta. */
  const int nf = mrvi_model_n_fast(m);
  const int *fast = mrvi_model_fast_index(m);
  double worst = 0;
  for (long i = 0; i < tr.count; i++) {
    const rec *r = &tr.r[i];
    const double *mq = r->mq + (size_t)(r->micro_count - 1) * (size_t)nf;
    const double *mp = r->mp + (size_t)(r->micro_count - 1) * (size_t)nf;
    for (int j = 0; j < nf; j++) {
      worst = fmax(worst, fabs(mq[j] - r->q[fast[j]]));
      worst = fmax(worst, fabs(mp[j] - r->p[fast[j]]) / fmax(1, fabs(mp[j])));
    }
  }
  CHECK(worst <= 1e-13,
        "%s: micro row k p equals the fast part of macro node k (%.3g)", name,
        worst);
  traj_free(&tr);
  remove(path);
}

static void test_runs(void) {
  mrvi_model *fpu = fpu_model();
  mrvi_model *pm = particle_model(3);
  mrvi_settings s1 = settings("midpoint-midpoint", 0.3, 5, 6.0); /* N = 20 */
  run_case("fpu", fpu, &s1, 1, -1);
  /* (b) error injection: the observer fails at k = 10. */
  run_case("fpu_stopped", fpu, &s1, 1, 10);
  /* (c) every = 3 over N = 20: k = 0, 3, ..., 18 and 20. */
  run_case("fpu_every3", fpu, &s1, 3, -1);
  mrvi_settings s2 = settings("explicit-slow", 0.01, 3, 0.5); /* N = 50 */
  run_case("particles", pm, &s2, 1, -1);
  mrvi_settings s3 = settings("trapezoidal-midpoint", 0.01, 4, 3.0);
  run_case("particles_long", pm, &s3, 1, 123); /* spans a flush */
  mrvi_model_free(fpu);
  mrvi_model_free(pm);

  /* Constrained: N = 20 steps, R = 4 multipliers; every = 3 keeps
   * k = 0, 3, ..., 18, 20; stopped by the observer at k = 7. */
  mrvi_model *cm = constrained_model();
  mrvi_settings s4 = settings("midpoint-midpoint", 0.05, 4, 1.0);
  run_case("constrained", cm, &s4, 1, -1);
  run_case("constrained_every3", cm, &s4, 3, -1);
  run_case("constrained_stopped", cm, &s4, 1, 7);
  run_case("constrained_every3_stopped", cm, &s4, 3, 7);
  mrvi_model_free(cm);
}

/* /model/particle_*, edges, conserved components and /micro/q_slow
 * (output.micro_slow): the slow coordinates at micro node m of step
 * k-1 -> k are (1 - m/p) q_{k-1}^s + (m/p) q_k^s of the records, to
 * 1e-15; row 0 is q_0^s and row k p is q_k^s exactly.  Without the option
 * the dataset is absent. */
static void test_particles_micro_slow(void) {
  mrvi_model *m = particle_model(3);
  mrvi_settings s = settings("midpoint-midpoint", 0.01, 4, 0.3); /* N = 30 */
  const int p = s.micro_steps, ns = mrvi_model_n_slow(m);
  const int *slow = mrvi_model_slow_index(m);
  for (int with = 0; with <= 1; with++) {
    const char *path = with ? "micro_slow.h5" : "micro_fast_only.h5";
    mrvi_writer_options opt = {"particles", NULL, 1, 1, 0.0, 0, with, 0, 0, 0};
    mrvi_writer *w = NULL;
    char msg[512];
    CHECK(mrvi_writer_open(path, m, &s, &opt, &w, msg, sizeof msg) == 0,
          "open %s: %s", path, msg);
    if (!w)
      continue;
    traj tr;
    traj_init(&tr, m);
    tee t = {w, &tr, -1};
    mrvi_summary sum;
    CHECK(mrvi_run(m, &s, tee_observe, &t, NULL, &sum) == 0, "run: %s",
          sum.message);
    CHECK(mrvi_writer_close(w, NULL, msg, sizeof msg) == 0, "close: %s", msg);
    hid_t f = H5Fopen(path, H5F_ACC_RDONLY, H5P_DEFAULT);
    CHECK(exists(f, "/micro/q_slow") == with, "%s: /micro/q_slow %s", path,
          with ? "present" : "absent");
    if (with) {
      int rank;
      hsize_t dims[2];
      double *qs = read_all(f, "/micro/q_slow", H5T_NATIVE_DOUBLE,
                            sizeof(double), &rank, dims);
      const long N = tr.count - 1;
      CHECK(qs && rank == 2 && dims[0] == (hsize_t)(N * p + 1) &&
                dims[1] == (hsize_t)ns,
            "/micro/q_slow shape (%llu, %llu), expected (%ld, %d)",
            (unsigned long long)dims[0], (unsigned long long)dims[1], N * p + 1,
            ns);
      double worst = 0.0;
      int nodes_exact = 1;
      for (long k = 0; qs && k <= N; k++)
        for (int mm = k == 0 ? 0 : 1; mm <= (k == 0 ? 0 : p); mm++) {
          const double *row = qs + (size_t)(k == 0 ? 0 : (k - 1) * p + mm) * ns;
          for (int j = 0; j < ns; j++) {
            const double b = (double)mm / p;
            const double want = k == 0 ? tr.r[0].q[slow[j]]
                                       : (1 - b) * tr.r[k - 1].q[slow[j]] +
                                             b * tr.r[k].q[slow[j]];
            worst = fmax(worst, fabs(row[j] - want) / fmax(1.0, fabs(want)));
            if (mm == p || k == 0)
              nodes_exact &= row[j] == tr.r[k].q[slow[j]];
          }
        }
      CHECK(worst <= 1e-15, "/micro/q_slow = linear interpolation (%.2e)",
            worst);
      CHECK(nodes_exact, "/micro/q_slow rows k p are the macro nodes q_k^s");
      free(qs);

      /* The particle datasets of the model (c, m1 slow, m2 fast). */
      const char *names[2] = {"m1", "m2"};
      check_strings(f, "/model/particle_name", 2, names);
      const int column[2] = {1, 4}, edges[2] = {0, 1}, edge_rate[1] = {0};
      const int none[3] = {0, 0, 0};
      check_data(f, "/model/particle_column", 1, 2, 1, H5T_NATIVE_INT,
                 sizeof(int), column);
      check_data(f, "/model/edges", 2, 1, 2, H5T_NATIVE_INT, sizeof(int),
                 edges);
      check_data(f, "/model/edge_rate", 1, 1, 1, H5T_NATIVE_INT, sizeof(int),
                 edge_rate);
      /* Anchor at (1, 0, 0) and gravity along -e3: nothing conserved. */
      check_data(f, "/model/linear_momentum_conserved", 1, 3, 1, H5T_NATIVE_INT,
                 sizeof(int), none);
      check_data(f, "/model/angular_momentum_conserved", 1, 3, 1,
                 H5T_NATIVE_INT, sizeof(int), none);
      int drank;
      hsize_t ddims[2];
      int *dim = read_all(f, "/model/dimension", H5T_NATIVE_INT, sizeof(int),
                          &drank, ddims);
      CHECK(dim && drank == 0 && *dim == 3, "/model/dimension: scalar 3");
      free(dim);
      check_documented(path);
    }
    H5Fclose(f);
    traj_free(&tr);
    remove(path);
  }
  /* A model without particles has none of the particle datasets. */
  mrvi_model *fpu = fpu_model();
  mrvi_writer_options opt = {"fpu", NULL, 1, 1, 0.0, 0, 1, 0, 0, 0};
  mrvi_writer *w = NULL;
  char msg[512];
  CHECK(mrvi_writer_open("no_particles.h5", fpu, &s, &opt, &w, msg,
                         sizeof msg) == 0,
        "open: %s", msg);
  mrvi_writer_close(w, NULL, msg, sizeof msg);
  hid_t f = H5Fopen("no_particles.h5", H5F_ACC_RDONLY, H5P_DEFAULT);
  CHECK(!exists(f, "/model/particle_column") && !exists(f, "/model/edges") &&
            !exists(f, "/model/dimension"),
        "no particles: no /model/particle_column, /model/edges, dimension");
  H5Fclose(f);
  remove("no_particles.h5");
  mrvi_model_free(fpu);
  mrvi_model_free(m);
}

/* `mrvi run` writes exactly what an in-memory run of the same file gives. */
static void test_cli(void) {
  const char *bin = getenv("MRVI_BIN");
  CHECK(bin != NULL, "MRVI_BIN set");
  if (!bin)
    return;
  char yaml[4096];
  snprintf(yaml, sizeof yaml, "%s", test_source_path("systems/fpu.yaml"));
  const char *ov[1] = {"integrator.t_end=3"};
  const char *out = "cli_fpu.h5";
  char cmd[8192];
  snprintf(cmd, sizeof cmd,
           "'%s' run '%s' -o '%s' --set %s --quiet >/dev/null 2>cli_fpu.err",
           bin, yaml, out, ov[0]);
  remove(out);
  int rc = system(cmd);
  CHECK(rc == 0, "mrvi run exits 0 (%d): %s", rc, cmd);
  mrvi_system *sys = NULL;
  char msg[1024];
  rc = mrvi_system_load(yaml, ov, 1, &sys, msg, sizeof msg);
  CHECK(rc == 0 && sys, "load %s: %s", yaml, msg);
  if (rc == 0 && sys) {
    traj tr;
    traj_init(&tr, sys->model);
    tee t = {NULL, &tr, -1};
    mrvi_summary sum;
    rc = mrvi_run(sys->model, &sys->settings, tee_observe, &t, NULL, &sum);
    CHECK(rc == 0, "in-memory run: %s", sum.message);
    expect e = {
        sys->model,        &sys->settings,    sys->name,   sys->description,
        sys->output_every, sys->output_micro, "completed", 1};
    verify(out, &tr, &e);
    check_documented(out);
    traj_free(&tr);
    mrvi_system_free(sys);
  }
  remove(out);
  remove("cli_fpu.err");
}

int main(void) {
  /* The test's own HDF5 calls may probe missing objects quietly. */
  H5Eset_auto2(H5E_DEFAULT, NULL, NULL);
  test_synthetic();
  test_synthetic_constrained();
  test_bad_records();
  test_hard_kill();
  test_lock();
  test_unwritable();
  test_io_error();
  test_runs();
  test_particles_micro_slow();
  test_cli();
  check_no_open_objects("end");
  return test_finish();
}
