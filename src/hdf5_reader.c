/* Reading a run back from an mrvi HDF5 file (doc/output.md) into a
 * trajectory, e.g. a cached reference solution of a convergence study. */
#define _DEFAULT_SOURCE /* flock */
#include "h5util.h"
#include "internal.h"

#include <hdf5.h>
#include <errno.h>
#include <fcntl.h>
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
    const size_t count = (size_t)dims[0] * (size_t)(rank == 2 ? dims[1] : 1);
    buf = malloc((count > 0 ? count : 1) * sizeof(double));
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

void mrvi_h5_stop_reason(hid_t file, const char *path, char *buf, size_t len) {
  read_attr_string(file, "stop_reason", buf, len);
  if (strcmp(buf, "running") != 0)
    return;
  /* A live run holds flock(LOCK_EX) on its output (hdf5_writer.c). */
  int fd = open(path, O_RDONLY | O_CLOEXEC);
  int live =
      fd >= 0 && flock(fd, LOCK_SH | LOCK_NB) < 0 && errno == EWOULDBLOCK;
  if (fd >= 0)
    close(fd);
  if (!live)
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
