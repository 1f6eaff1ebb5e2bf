/* Reading a run back from an mrvi HDF5 file (doc/output.md) into a
 * trajectory, e.g. a cached reference solution of a convergence study. */
#define _DEFAULT_SOURCE /* flock */
#include "io/h5util.h"
#include "io/io.h"

#include <hdf5.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <unistd.h>

/* Read a whole float64 dataset of rank 1 or 2; *rows, *cols get its shape
 * (cols = 1 for rank 1).  Returns a malloc'ed array or NULL. */
static double *read_matrix(hid_t file, const char *name, long *rows,
                           int *cols) {
  hid_t d = H5Dopen2(file, name, H5P_DEFAULT);
  if (d < 0)
    return NULL;
  hid_t sp = H5Dget_space(d);
  hsize_t dims[2] = {0, 1};
  const int rank = H5Sget_simple_extent_ndims(sp);
  double *buf = NULL;
  if (rank >= 1 && rank <= 2 &&
      H5Sget_simple_extent_dims(sp, dims, NULL) >= 0) {
    /* Shapes come from the file: a product beyond size_t is refused. */
    size_t count = 0, bytes = 0;
    if (!__builtin_mul_overflow((size_t)dims[0],
                                (size_t)(rank == 2 ? dims[1] : 1), &count) &&
        !__builtin_mul_overflow(count > 0 ? count : 1, sizeof(double), &bytes))
      buf = malloc(bytes);
    if (buf &&
        H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, buf) < 0) {
      free(buf);
      buf = NULL;
    }
    *rows = (long)dims[0];
    *cols = rank == 2 ? (int)dims[1] : 1;
  }
  H5Sclose(sp);
  H5Dclose(d);
  return buf;
}

static int read_attr_double(hid_t file, const char *name, double *v) {
  hid_t a = H5Aopen(file, name, H5P_DEFAULT);
  if (a < 0)
    return -1;
  herr_t rc = H5Aread(a, H5T_NATIVE_DOUBLE, v);
  H5Aclose(a);
  return rc < 0 ? -1 : 0;
}

/* Root string attribute into buf ("" if absent): variable-length or
 * fixed-length. */
static void read_attr_string(hid_t file, const char *name, char *buf,
                             size_t len) {
  buf[0] = '\0';
  hid_t a = H5Aopen(file, name, H5P_DEFAULT);
  if (a < 0)
    return;
  hid_t t = H5Aget_type(a);
  hid_t mt = H5Tcopy(H5T_C_S1);
  if (H5Tget_class(t) == H5T_STRING && H5Tis_variable_str(t) > 0) {
    char *s = NULL;
    H5Tset_size(mt, H5T_VARIABLE);
    H5Tset_cset(mt, H5Tget_cset(t));
    if (H5Aread(a, mt, &s) >= 0 && s) {
      mrvi_fmt(buf, len, "%s", s);
      H5free_memory(s);
    }
  } else if (H5Tget_class(t) == H5T_STRING) {
    const size_t n = H5Tget_size(t);
    char *s = calloc(n + 1, 1);
    H5Tset_size(mt, n + 1);
    H5Tset_cset(mt, H5Tget_cset(t));
    H5Tset_strpad(mt, H5T_STR_NULLTERM);
    if (s && H5Aread(a, mt, s) >= 0)
      mrvi_fmt(buf, len, "%s", s);
    free(s);
  }
  H5Tclose(mt);
  H5Tclose(t);
  H5Aclose(a);
}

hid_t mrvi_h5_open_read(const char *path, hid_t fapl) {
  hid_t f = H5Fopen(path, H5F_ACC_RDONLY, fapl);
  if (f < 0)
    f = H5Fopen(path, H5F_ACC_RDONLY | H5F_ACC_SWMR_READ, fapl);
  if (f >= 0)
    H5Eclear2(H5E_DEFAULT);
  return f;
}

/* A live run holds flock(LOCK_EX) on its output (hdf5_writer.c). */
static int held_by_live_run(const char *path) {
  int fd = open(path, O_RDONLY | O_CLOEXEC);
  int live =
      fd >= 0 && flock(fd, LOCK_SH | LOCK_NB) < 0 && errno == EWOULDBLOCK;
  if (fd >= 0)
    close(fd);
  return live;
}

void mrvi_h5_stop_reason(hid_t file, const char *path, char *buf, size_t len) {
  read_attr_string(file, "stop_reason", buf, len);
  if (!strcmp(buf, "running") && !held_by_live_run(path))
    mrvi_fmt(buf, len, "%s", "incomplete (writer killed)");
}

int mrvi_run_file_status(const char *path, char *reason, size_t len) {
  H5E_auto2_t func;
  void *data;
  H5Eget_auto2(H5E_DEFAULT, &func, &data);
  H5Eset_auto2(H5E_DEFAULT, NULL, NULL);
  hid_t f = mrvi_h5_open_read(path, H5P_DEFAULT);
  int st = MRVI_OK;
  if (f < 0) {
    st = mrvi_fail(reason, len, MRVI_EIO, "%s: cannot open as an HDF5 file",
                   path);
  } else {
    mrvi_h5_stop_reason(f, path, reason, len);
    H5Fclose(f);
    if (!reason[0])
      st = mrvi_fail(reason, len, MRVI_EIO,
                     "%s: not an mrvi output (no stop_reason)", path);
  }
  H5Eclear2(H5E_DEFAULT);
  H5Eset_auto2(H5E_DEFAULT, func, data);
  return st;
}

int mrvi_trajectory_read(const char *path, mrvi_trajectory **out, char *msg,
                         size_t len) {
  *out = NULL;
  H5E_auto2_t func;
  void *data;
  H5Eget_auto2(H5E_DEFAULT, &func, &data);
  H5Eset_auto2(H5E_DEFAULT, NULL, NULL);
  int st = MRVI_OK;
  mrvi_trajectory *tr = calloc(1, sizeof *tr);
  hid_t file = mrvi_h5_open_read(path, H5P_DEFAULT);
  if (!tr) {
    st = MRVI_ENOMEM;
    mrvi_fmt(msg, len, "out of memory");
    goto done;
  }
  if (file < 0) {
    st = MRVI_EIO;
    mrvi_fmt(msg, len, "%s: cannot open as an HDF5 file", path);
    goto done;
  }
  char reason[256];
  mrvi_h5_stop_reason(file, path, reason, sizeof reason);
  if (strcmp(reason, "completed") != 0) {
    st = MRVI_EIO;
    mrvi_fmt(msg, len, "%s: the run did not complete (stop_reason: %s)", path,
             reason[0] ? reason : "missing");
    goto done;
  }
  double dT = 0, p = 0;
  if (read_attr_double(file, "macro_step", &dT) < 0 ||
      read_attr_double(file, "micro_steps", &p) < 0) {
    st = MRVI_EIO;
    mrvi_fmt(msg, len, "%s: missing attribute macro_step or micro_steps", path);
    goto done;
  }
  tr->macro_step = dT;
  tr->micro_steps = (int)p;
  long rows = 0, rq = 0, rp = 0, rm = 0;
  int cols = 0, cq = 0, cp = 0, cr = 0;
  tr->t = read_matrix(file, "/macro/t", &rows, &cols);
  tr->q = read_matrix(file, "/macro/q", &rq, &cq);
  tr->p = read_matrix(file, "/macro/p", &rp, &cp);
  double *rate = read_matrix(file, "/model/rate", &rm, &cr);
  if (!tr->t || !tr->q || !tr->p || !rate || rq != rows || rp != rows ||
      cq != cp || rm != cq) {
    free(rate);
    st = MRVI_EIO;
    mrvi_fmt(msg, len,
             "%s: /macro/t, /macro/q, /macro/p or /model/rate "
             "missing or inconsistent",
             path);
    goto done;
  }
  tr->n = cq;
  tr->n_macro = rows;
  for (long i = 0; i < rm; i++)
    tr->n_fast += rate[i] != 0.0;
  free(rate);
  /* The micro datasets are optional (output.micro: false). */
  long mr = 0;
  int mc = 0;
  tr->micro_t = read_matrix(file, "/micro/t", &mr, &mc);
  tr->n_micro = tr->micro_t ? mr : 0;
  if (tr->micro_t) {
    long r2 = 0;
    int c2 = 0;
    tr->micro_q = read_matrix(file, "/micro/q_fast", &r2, &c2);
    tr->micro_p = read_matrix(file, "/micro/p_fast", &r2, &c2);
  }
done:
  if (file >= 0)
    H5Fclose(file);
  H5Eset_auto2(H5E_DEFAULT, func, data);
  if (st < 0) {
    mrvi_trajectory_free(tr);
    return st;
  }
  *out = tr;
  return MRVI_OK;
}

/* Row `row` of the float64 dataset name (rank 1: cols = 1) into buf;
 * *rows gets its row count.  -1 when missing or not that wide. */
static int read_row(hid_t file, const char *name, hsize_t row, int cols,
                    double *buf, hsize_t *rows) {
  hid_t d = H5Dopen2(file, name, H5P_DEFAULT);
  if (d < 0)
    return -1;
  hid_t sp = H5Dget_space(d);
  hsize_t dims[2] = {0, 1};
  const int rank = H5Sget_simple_extent_ndims(sp);
  int rc = -1;
  if (rank >= 1 && rank <= 2 && H5Sget_simple_extent_dims(sp, dims, NULL) >= 0)
    *rows = dims[0];
  if (rank >= 1 && rank <= 2 && (rank == 1 ? 1 : (int)dims[1]) == cols &&
      row < dims[0]) {
    hsize_t off[2] = {row, 0}, cnt[2] = {1, (hsize_t)cols};
    hid_t ms = H5Screate_simple(rank, cnt, NULL);
    if (H5Sselect_hyperslab(sp, H5S_SELECT_SET, off, NULL, cnt, NULL) >= 0 &&
        H5Dread(d, H5T_NATIVE_DOUBLE, ms, sp, H5P_DEFAULT, buf) >= 0)
      rc = 0;
    H5Sclose(ms);
  }
  H5Sclose(sp);
  H5Dclose(d);
  return rc;
}

/* The scalar string dataset name (variable length), malloc'ed, or NULL. */
static char *read_string_dataset(hid_t file, const char *name) {
  hid_t d = H5Dopen2(file, name, H5P_DEFAULT);
  if (d < 0)
    return NULL;
  char *s = NULL, *out = NULL;
  hid_t t = H5Dget_type(d);
  hid_t mt = H5Tcopy(H5T_C_S1);
  H5Tset_size(mt, H5T_VARIABLE);
  H5Tset_cset(mt, H5Tget_cset(t));
  if (H5Tis_variable_str(t) > 0 &&
      H5Dread(d, mt, H5S_ALL, H5S_ALL, H5P_DEFAULT, &s) >= 0 && s) {
    out = strdup(s);
    H5free_memory(s);
  }
  H5Tclose(mt);
  H5Tclose(t);
  H5Dclose(d);
  return out;
}

/* Fill node (rows of /macro/t known) from row `row`; the node index is
 * t / macro_step and must reproduce t exactly. */
static int read_node_row(hid_t file, const char *path, hsize_t row,
                         mrvi_stored_node *node, char *msg, size_t len) {
  hsize_t rows = 0;
  double t = 0;
  if (read_row(file, "/macro/t", row, 1, &t, &rows) < 0 ||
      read_row(file, "/macro/q", row, node->n, node->q, &rows) < 0 ||
      read_row(file, "/macro/p", row, node->n, node->p, &rows) < 0)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: cannot read row %llu of /macro/t, /macro/q or "
                     "/macro/p",
                     path, (unsigned long long)row);
  const double kd = t / node->macro_step;
  const long k = (long)(kd + 0.5);
  if (!(kd >= -0.5 && kd < 9.0e15) || (double)k * node->macro_step != t)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: /macro/t[%llu] = %.17g is not a multiple of "
                     "macro_step %.17g",
                     path, (unsigned long long)row, t, node->macro_step);
  node->k = k;
  node->t = t;
  return MRVI_OK;
}

static int stored_node_read(hid_t file, const char *path, long which,
                            mrvi_stored_node *node, char *msg, size_t len) {
  if (H5Aexists(file, "mrvi_version") <= 0)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: not an mrvi output (no root attribute "
                     "mrvi_version)",
                     path);
  mrvi_h5_stop_reason(file, path, node->stop_reason, sizeof node->stop_reason);
  if (which == MRVI_NODE_RESUME && H5Lexists(file, "/control", H5P_DEFAULT) > 0)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: written by mrvi optimize or run --controls; "
                     "resuming a controlled run is not supported",
                     path);
  if (which == MRVI_NODE_RESUME && !strcmp(node->stop_reason, "completed"))
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: the run completed; nothing to resume (to go on "
                     "past t_end: mrvi run FILE --set integrator.t_end=... "
                     "--from %s -o NEW.h5)",
                     path, path);
  if (which == MRVI_NODE_RESUME && !strcmp(node->stop_reason, "running"))
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: the file is in use by another run (locked); not "
                     "touched",
                     path);
  double every = 1, steps = 0; /* counts below 2^53: exact as doubles */
  if (read_attr_double(file, "macro_step", &node->macro_step) < 0 ||
      read_attr_double(file, "steps_completed", &steps) < 0 ||
      read_attr_double(file, "output_every", &every) < 0 || every < 1 ||
      !(node->macro_step > 0))
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: attribute macro_step, steps_completed or "
                     "output_every missing or invalid",
                     path);
  const long K = (long)steps;
  node->every = (int)every;
  node->steps_completed = K;
  node->description = read_string_dataset(file, "/model/description");
  if (!node->description)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: no /model/description to take the settings from",
                     path);
  long nr = 0;
  int nc = 0;
  double *rate = read_matrix(file, "/model/rate", &nr, &nc);
  free(rate);
  hsize_t rows = 0;
  double t0;
  const int empty = read_row(file, "/macro/t", 0, 1, &t0, &rows) < 0;
  if (!rate || nr < 1 || (empty && (which != MRVI_NODE_RESUME || rows > 0)))
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: /model/rate or /macro/t missing or empty", path);
  node->n = (int)nr;
  node->q = calloc((size_t)nr, sizeof *node->q);
  node->p = calloc((size_t)nr, sizeof *node->p);
  if (!node->q || !node->p)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  if (empty)
    return MRVI_OK; /* killed before its first row: resume from node 0 */
  const long e = node->every;
  if (which == MRVI_NODE_LAST)
    return read_node_row(file, path, rows - 1, node, msg, len);
  if (which >= 0) {
    int st = read_node_row(file, path, rows - 1, node, msg, len);
    if (st < 0)
      return st;
    const long last = node->k;
    hsize_t row = (hsize_t)(which / e);
    if (which > last || (which % e != 0 && which != last))
      return mrvi_fail(msg, len, MRVI_EINVAL,
                       "%s: macro node %ld is not stored (stored: 0 to %ld "
                       "in steps of %ld%s)",
                       path, which, last, e,
                       last % e ? ", and the last node" : "");
    if (which == last)
      row = rows - 1;
    return read_node_row(file, path, row, node, msg, len);
  }
  /* Resume: the last kept node within steps_completed whose multipliers
   * arrived (the next step reports them; its projection impulse cannot be
   * recomputed, so a node without them is not resumed from). */
  long k = K / e * e;
  hsize_t lrows = 0;
  const int has_lambda = H5Lexists(file, "/macro/lambda", H5P_DEFAULT) > 0;
  int nl = 0;
  if (has_lambda) {
    hid_t d = H5Dopen2(file, "/macro/lambda", H5P_DEFAULT);
    hid_t sp = H5Dget_space(d);
    hsize_t dims[2] = {0, 0};
    H5Sget_simple_extent_dims(sp, dims, NULL);
    H5Sclose(sp);
    H5Dclose(d);
    nl = (int)dims[1];
  }
  double *lam = malloc(((size_t)nl + 1) * sizeof *lam);
  if (!lam)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  for (; k > 0 && has_lambda; k -= e) {
    int finite =
        read_row(file, "/macro/lambda", (hsize_t)(k / e), nl, lam, &lrows) == 0;
    for (int i = 0; i < nl && finite; i++)
      finite = lam[i] == lam[i];
    if (finite)
      break;
  }
  free(lam);
  if ((hsize_t)(k / e) >= rows)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: steps_completed = %ld but /macro/t has %llu rows",
                     path, K, (unsigned long long)rows);
  int st = read_node_row(file, path, (hsize_t)(k / e), node, msg, len);
  if (st == MRVI_OK && node->k != k)
    st = mrvi_fail(msg, len, MRVI_EIO,
                   "%s: /macro/t[%ld] is node %ld, expected %ld", path, k / e,
                   node->k, k);
  return st;
}

/* node->energy: H_0 and T_0 + |V_0| + |W_0| from row 0, the running energy
 * error of node k from its row (k / every). */
static int read_node_energy(hid_t file, const char *path,
                            mrvi_stored_node *node, char *msg, size_t len) {
  hsize_t rows = 0;
  double e[3] = {0};
  const hsize_t row = (hsize_t)(node->k / (node->every > 0 ? node->every : 1));
  if (read_row(file, "/macro/energy", 0, 1, &node->energy[0], &rows) < 0 ||
      read_row(file, "/macro/kinetic", 0, 1, &e[0], &rows) < 0 ||
      read_row(file, "/macro/potential_slow", 0, 1, &e[1], &rows) < 0 ||
      read_row(file, "/macro/potential_fast", 0, 1, &e[2], &rows) < 0 ||
      read_row(file, "/macro/energy_running", row, 2, &node->energy[2], &rows) <
          0)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: cannot read the energies of rows 0 and %llu "
                     "(/macro/energy_running; a file of an earlier mrvi "
                     "cannot be resumed)",
                     path, (unsigned long long)row);
  node->energy[1] = fabs(e[0]) + fabs(e[1]) + fabs(e[2]);
  return MRVI_OK;
}

int mrvi_stored_node_read(const char *path, long which, mrvi_stored_node **out,
                          char *msg, size_t len) {
  *out = NULL;
  mrvi_fmt(msg, len, "%s", "");
  H5E_auto2_t func;
  void *data;
  H5Eget_auto2(H5E_DEFAULT, &func, &data);
  H5Eset_auto2(H5E_DEFAULT, NULL, NULL);
  mrvi_stored_node *node = calloc(1, sizeof *node);
  const int live = held_by_live_run(path);
  hid_t f =
      node && !live ? mrvi_h5_open_read(path, H5P_DEFAULT) : H5I_INVALID_HID;
  int st;
  if (!node)
    st = mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  else if (live)
    st = mrvi_fail(msg, len, MRVI_EIO,
                   "%s: the file is in use by another run (locked); not "
                   "touched",
                   path);
  else if (f < 0)
    st = mrvi_fail(msg, len, MRVI_EIO,
                   "%s: cannot open as an HDF5 file (missing or not HDF5)",
                   path);
  else
    st = stored_node_read(f, path, which, node, msg, len);
  if (st == MRVI_OK && which == MRVI_NODE_RESUME && node->k > 0)
    st = read_node_energy(f, path, node, msg, len);
  if (f >= 0)
    H5Fclose(f);
  H5Eclear2(H5E_DEFAULT);
  H5Eset_auto2(H5E_DEFAULT, func, data);
  if (st < 0) {
    mrvi_stored_node_free(node);
    return st;
  }
  *out = node;
  return MRVI_OK;
}

void mrvi_stored_node_free(mrvi_stored_node *node) {
  if (!node)
    return;
  free(node->q);
  free(node->p);
  free(node->description);
  free(node);
}
