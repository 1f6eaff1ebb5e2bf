/* Validated reading of HDF5 input files.
 *
 * Every HDF5 file mrvi reads -- run --resume and --from, run --controls,
 * export, the reference runs of a study, the writer reopening its output
 * to append -- is untrusted: it may come from a colleague, a shared drive
 * or an older mrvi, be damaged or be crafted.  Every dataset and attribute
 * is read through this file, which checks before a byte of data is read:
 *
 *   - the object is a dataset of the expected type class (numbers: integer
 *     or floating point, which HDF5 converts; or strings);
 *   - its dataspace has exactly the expected rank, asked with
 *     H5Sget_simple_extent_ndims before H5Sget_simple_extent_dims fills a
 *     fixed array (a file may declare any rank up to 32);
 *   - every dimension equals what the model or the other datasets imply,
 *     MRVI_H5_ANY where the file decides (the rows a run stored);
 *   - the bytes to allocate, computed in size_t with overflow checks, are
 *     at most mrvi_h5_read_cap() (a file of a few kB may declare 2^64
 *     entries on a chunked dataset with no chunk written);
 *
 * and reads into buffers sized from the checked shape.  An attribute must
 * hold exactly one value.  A failure is a message naming the file, the
 * dataset and what was expected and found; the caller's status.  HDF5's
 * automatic printing of its error stack is switched off around every read
 * by the callers (mrvi_h5_quiet_begin): the library never prints. */
#include "io/h5util.h"
#include "util/util.h"

#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

/* ---------------------------------------------------------------------------
 * Sizes
 * ------------------------------------------------------------------------- */

size_t mrvi_h5_read_cap(void) {
  const double have = mrvi_machine_memory();
  const double cap = have > 0 ? have / 4 : (double)((size_t)1 << 30);
  return cap < (double)SIZE_MAX ? (size_t)cap : SIZE_MAX;
}

/* *bytes = a * b * c, or -1 when it overflows size_t. */
static int product(hsize_t a, hsize_t b, size_t c, size_t *bytes) {
  size_t ab;
  if (a > SIZE_MAX || b > SIZE_MAX ||
      __builtin_mul_overflow((size_t)a, (size_t)b, &ab) ||
      __builtin_mul_overflow(ab, c, bytes))
    return -1;
  return 0;
}

/* *cols = the values of one row (the product of the dimensions after the
 * first; 1 for rank 0 and 1), or -1 when it overflows. */
static int row_values(int rank, const hsize_t *dims, hsize_t *cols) {
  size_t c = 1;
  for (int i = 1; i < rank; i++)
    if (dims[i] > SIZE_MAX || __builtin_mul_overflow(c, (size_t)dims[i], &c))
      return -1;
  *cols = (hsize_t)c;
  return 0;
}

/* "11 x 9", "any x 4", "a scalar". */
static void shape_text(char *buf, size_t len, int rank, const hsize_t *dims) {
  if (rank <= 0) {
    mrvi_fmt(buf, len, "%s", rank == 0 ? "a scalar" : "empty");
    return;
  }
  buf[0] = '\0';
  for (int i = 0; i < rank; i++) {
    const size_t used = strlen(buf);
    if (dims[i] == MRVI_H5_ANY)
      mrvi_fmt(buf + used, len - used, "%sany", i ? " x " : "");
    else
      mrvi_fmt(buf + used, len - used, "%s%llu", i ? " x " : "",
               (unsigned long long)dims[i]);
  }
}

/* ---------------------------------------------------------------------------
 * Datasets
 * ------------------------------------------------------------------------- */

int mrvi_h5in_exists(const mrvi_h5in *in, const char *name) {
  /* Each link of the path in turn: H5Lexists fails on a missing group. */
  char part[256];
  for (const char *s = strchr(name + 1, '/');; s = strchr(s + 1, '/')) {
    const size_t n = s ? (size_t)(s - name) : strlen(name);
    if (n >= sizeof part)
      return 0;
    memcpy(part, name, n);
    part[n] = '\0';
    /* Hard links only: a soft or external link may lead anywhere. */
    H5L_info_t info;
    if (H5Lexists(in->file, part, H5P_DEFAULT) <= 0 ||
        H5Lget_info(in->file, part, &info, H5P_DEFAULT) < 0 ||
        info.type != H5L_TYPE_HARD) {
      H5Eclear2(H5E_DEFAULT);
      return 0;
    }
    if (!s)
      return 1;
  }
}

static const char *kind_text(int kind) {
  return kind == MRVI_H5_STRING ? "strings" : "numbers";
}

static int class_fits(H5T_class_t c, int kind) {
  return kind == MRVI_H5_STRING ? c == H5T_STRING
                                : c == H5T_INTEGER || c == H5T_FLOAT;
}

/* Rank of a dataspace: 0 scalar, the rank of a simple one, -1 null. */
static int space_rank(hid_t sp) {
  const H5S_class_t c = H5Sget_simple_extent_type(sp);
  if (c == H5S_SCALAR)
    return 0;
  if (c != H5S_SIMPLE)
    return -1;
  return H5Sget_simple_extent_ndims(sp);
}

hid_t mrvi_h5in_open(const mrvi_h5in *in, const char *name, int kind, int rank,
                     const hsize_t *want, hsize_t *dims) {
  if (!mrvi_h5in_exists(in, name)) {
    mrvi_fail(in->msg, in->len, MRVI_EIO, "%s: no dataset %s", in->path, name);
    return H5I_INVALID_HID;
  }
  hid_t d = H5Dopen2(in->file, name, H5P_DEFAULT);
  if (d < 0) {
    H5Eclear2(H5E_DEFAULT);
    mrvi_fail(in->msg, in->len, MRVI_EIO, "%s: %s is not a dataset", in->path,
              name);
    return H5I_INVALID_HID;
  }
  hid_t t = H5Dget_type(d);
  const H5T_class_t c = t >= 0 ? H5Tget_class(t) : H5T_NO_CLASS;
  if (t >= 0)
    H5Tclose(t);
  hid_t sp = H5Dget_space(d);
  const int found = sp >= 0 ? space_rank(sp) : -1;
  hsize_t got[MRVI_H5_MAX_RANK] = {0, 0, 0, 0};
  /* The rank first: the dims array has room for the expected rank only. */
  int ok = class_fits(c, kind) && found == rank && rank <= MRVI_H5_MAX_RANK &&
           (rank == 0 || H5Sget_simple_extent_dims(sp, got, NULL) == rank);
  if (sp >= 0)
    H5Sclose(sp);
  char a[128], b[128];
  if (!class_fits(c, kind)) {
    mrvi_fail(in->msg, in->len, MRVI_EIO, "%s: %s does not hold %s", in->path,
              name, kind_text(kind));
  } else if (found != rank) {
    mrvi_fail(in->msg, in->len, MRVI_EIO, "%s: %s has rank %d, expected %d",
              in->path, name, found, rank);
  } else if (!ok) {
    mrvi_fail(in->msg, in->len, MRVI_EIO, "%s: %s: unreadable dataspace",
              in->path, name);
  } else {
    int wide = 0; /* a dimension after the first beyond an int count */
    for (int i = 0; i < rank; i++) {
      ok &= !want || want[i] == MRVI_H5_ANY || want[i] == got[i];
      wide |= i > 0 && got[i] > INT_MAX;
    }
    if (ok && wide) {
      shape_text(a, sizeof a, rank, got);
      mrvi_fail(in->msg, in->len, MRVI_EIO,
                "%s: %s is %s, wider than mrvi reads (%s%d columns)", in->path,
                name, a, "at most ", INT_MAX);
      ok = 0;
    } else if (!ok && rank == 1) {
      mrvi_fail(in->msg, in->len, MRVI_EIO,
                "%s: %s has %llu entries, expected %llu", in->path, name,
                (unsigned long long)got[0], (unsigned long long)want[0]);
    } else if (!ok) {
      shape_text(a, sizeof a, rank, got);
      shape_text(b, sizeof b, rank, want);
      mrvi_fail(in->msg, in->len, MRVI_EIO, "%s: %s is %s, expected %s",
                in->path, name, a, b);
    }
  }
  H5Eclear2(H5E_DEFAULT);
  if (!ok) {
    H5Dclose(d);
    return H5I_INVALID_HID;
  }
  for (int i = 0; i < rank; i++)
    dims[i] = got[i];
  return d;
}

int mrvi_h5in_shape(const mrvi_h5in *in, const char *name, int kind, int rank,
                    const hsize_t *want, hsize_t *dims) {
  hid_t d = mrvi_h5in_open(in, name, kind, rank, want, dims);
  if (d < 0)
    return MRVI_EIO;
  H5Dclose(d);
  return MRVI_OK;
}

/* Rows [row, row + rows) of the open dataset d (rank 0: its value) as
 * mtype into buf, which has room for cap elements. */
static int read_rows(const mrvi_h5in *in, hid_t d, const char *name,
                     hid_t mtype, int rank, const hsize_t *dims, hsize_t row,
                     hsize_t rows, void *buf, size_t cap) {
  const hsize_t total = rank > 0 ? dims[0] : 1;
  hsize_t cols = 1;
  size_t count = 0, bytes = 0;
  if (row > total || rows > total - row)
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: %s has %llu rows; rows %llu to %llu were asked for",
                     in->path, name, (unsigned long long)total,
                     (unsigned long long)row, (unsigned long long)(row + rows));
  if (row_values(rank, dims, &cols) < 0 || product(rows, cols, 1, &count) < 0 ||
      count > cap || product(rows, cols, H5Tget_size(mtype), &bytes) < 0)
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: %s: %llu x %llu values do not fit the %zu expected",
                     in->path, name, (unsigned long long)rows,
                     (unsigned long long)cols, cap);
  if (bytes > mrvi_h5_read_cap())
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: %s asks for %zu bytes, more than a quarter of this "
                     "machine's memory",
                     in->path, name, bytes);
  if (count == 0)
    return MRVI_OK;
  herr_t rc;
  if (rank == 0) {
    rc = H5Dread(d, mtype, H5S_ALL, H5S_ALL, H5P_DEFAULT, buf);
  } else {
    hid_t fs = H5Dget_space(d);
    hsize_t start[MRVI_H5_MAX_RANK] = {row, 0, 0, 0}, n[MRVI_H5_MAX_RANK];
    n[0] = rows;
    for (int i = 1; i < rank; i++)
      n[i] = dims[i];
    const hsize_t flat = (hsize_t)count;
    hid_t ms = H5Screate_simple(1, &flat, NULL);
    rc = fs >= 0 && ms >= 0
             ? H5Sselect_hyperslab(fs, H5S_SELECT_SET, start, NULL, n, NULL)
             : -1;
    if (rc >= 0)
      rc = H5Dread(d, mtype, ms, fs, H5P_DEFAULT, buf);
    if (ms >= 0)
      H5Sclose(ms);
    if (fs >= 0)
      H5Sclose(fs);
  }
  if (rc < 0) {
    char what[256];
    mrvi_fmt(what, sizeof what, "cannot read %s (rows %llu to %llu)", name,
             (unsigned long long)row, (unsigned long long)(row + rows));
    mrvi_h5_error_message(in->msg, in->len, in->path, what);
    return MRVI_EIO;
  }
  return MRVI_OK;
}

int mrvi_h5in_read(const mrvi_h5in *in, const char *name, hid_t mtype, int rank,
                   const hsize_t *want, hsize_t row, hsize_t rows, void *buf,
                   size_t cap) {
  hsize_t dims[MRVI_H5_MAX_RANK] = {1, 1, 1, 1};
  hid_t d = mrvi_h5in_open(in, name, MRVI_H5_NUMBER, rank, want, dims);
  if (d < 0)
    return MRVI_EIO;
  const int st = read_rows(in, d, name, mtype, rank, dims, row, rows, buf, cap);
  H5Dclose(d);
  return st;
}

int mrvi_h5in_read_new(const mrvi_h5in *in, const char *name, hid_t mtype,
                       int rank, const hsize_t *want, hsize_t rows, void **out,
                       hsize_t *dims) {
  *out = NULL;
  hsize_t got[MRVI_H5_MAX_RANK] = {1, 1, 1, 1};
  hid_t d = mrvi_h5in_open(in, name, MRVI_H5_NUMBER, rank, want, got);
  if (d < 0)
    return MRVI_EIO;
  const hsize_t total = rank > 0 ? got[0] : 1;
  const hsize_t n = rows < total ? rows : total;
  hsize_t cols = 1;
  size_t count = 0, bytes = 0;
  int st = MRVI_OK;
  if (row_values(rank, got, &cols) < 0 || product(n, cols, 1, &count) < 0 ||
      product(n, cols, H5Tget_size(mtype), &bytes) < 0 ||
      bytes > mrvi_h5_read_cap())
    st = mrvi_fail(in->msg, in->len, MRVI_EIO,
                   "%s: %s (%llu x %llu values) is larger than a quarter of "
                   "this machine's memory",
                   in->path, name, (unsigned long long)n,
                   (unsigned long long)cols);
  void *buf = st == MRVI_OK ? malloc(bytes ? bytes : 1) : NULL;
  if (st == MRVI_OK && !buf)
    st = mrvi_fail(in->msg, in->len, MRVI_ENOMEM, "%s: %s: out of memory",
                   in->path, name);
  if (st == MRVI_OK)
    st = read_rows(in, d, name, mtype, rank, got, 0, n, buf, count);
  H5Dclose(d);
  if (st < 0) {
    free(buf);
    return st;
  }
  if (dims)
    for (int i = 0; i < rank; i++)
      dims[i] = got[i];
  *out = buf;
  return MRVI_OK;
}

/* ---------------------------------------------------------------------------
 * Strings
 * ------------------------------------------------------------------------- */

void mrvi_h5_strings_free(char **s, size_t count) {
  if (!s)
    return;
  for (size_t i = 0; i < count; i++)
    free(s[i]);
  free(s);
}

/* Copy of s (at most max_len bytes) into *out; -1 when longer. */
static int copy_bounded(const char *s, size_t max_len, char **out) {
  const size_t n = s ? strnlen(s, max_len + 1) : 0;
  if (n > max_len)
    return -1;
  *out = malloc(n + 1);
  if (*out) {
    memcpy(*out, s ? s : "", n);
    (*out)[n] = '\0';
  }
  return 0;
}

/* The n strings of the open string dataset or attribute obj (type t,
 * space of n elements): fixed-length, up to max_len bytes each (and a
 * terminator).  Variable-length strings are refused before any read: their
 * data are in the file's global heap, which libhdf5 reads unchecked (an
 * overrun in H5HG_read, allocations of whatever length a corrupted one
 * declares; doc/output.md, "Strings").  is_attr: obj is an attribute. */
static int read_text(const mrvi_h5in *in, const char *name, hid_t obj,
                     int is_attr, hid_t t, size_t n, size_t max_len,
                     char **out) {
  if (mrvi_h5_type_variable(t))
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: %s: variable-length strings (a file of an older "
                     "mrvi, or edited): not read; mrvi reads fixed-length "
                     "strings only (doc/output.md)",
                     in->path, name);
  const size_t stored = H5Tget_size(t);
  if (stored == 0 || stored > max_len + 1)
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: %s: strings of %zu bytes, at most %zu expected",
                     in->path, name, stored, max_len + 1);
  const size_t size = stored + 1;
  size_t bytes;
  if (product(n, 1, size, &bytes) < 0 || bytes > mrvi_h5_read_cap())
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: %s: too many strings (%zu)", in->path, name, n);
  char *raw = calloc(bytes ? bytes : 1, 1);
  hid_t mt = H5Tcopy(H5T_C_S1);
  int st = raw && mt >= 0 ? MRVI_OK : MRVI_ENOMEM;
  if (st == MRVI_OK) {
    H5Tset_size(mt, size);
    H5Tset_cset(mt, H5Tget_cset(t));
    H5Tset_strpad(mt, H5T_STR_NULLTERM);
    const herr_t rc =
        is_attr ? H5Aread(obj, mt, raw)
                : H5Dread(obj, mt, H5S_ALL, H5S_ALL, H5P_DEFAULT, raw);
    if (rc < 0) {
      char what[256];
      mrvi_fmt(what, sizeof what, "cannot read %s", name);
      mrvi_h5_error_message(in->msg, in->len, in->path, what);
      st = MRVI_EIO;
    }
    for (size_t i = 0; i < n && st == MRVI_OK; i++) {
      if (copy_bounded(raw + i * size, max_len, &out[i]) < 0)
        st = mrvi_fail(in->msg, in->len, MRVI_EIO,
                       "%s: %s: entry %zu is longer than %zu bytes", in->path,
                       name, i, max_len);
      else if (!out[i])
        st = MRVI_ENOMEM;
    }
  }
  if (st == MRVI_ENOMEM)
    mrvi_fail(in->msg, in->len, st, "%s: %s: out of memory", in->path, name);
  if (mt >= 0)
    H5Tclose(mt);
  free(raw);
  return st;
}

int mrvi_h5in_strings(const mrvi_h5in *in, const char *name, int rank,
                      hsize_t count, size_t max_len, char ***out) {
  *out = NULL;
  hsize_t dims[1] = {1};
  const hsize_t want[1] = {count};
  hid_t d = mrvi_h5in_open(in, name, MRVI_H5_STRING, rank, want, dims);
  if (d < 0)
    return MRVI_EIO;
  const size_t n = rank == 1 ? (size_t)dims[0] : 1;
  int st = MRVI_OK;
  char **s =
      n <= mrvi_h5_read_cap() / sizeof *s ? calloc(n ? n : 1, sizeof *s) : NULL;
  if (!s)
    st = mrvi_fail(in->msg, in->len, MRVI_ENOMEM, "%s: %s: out of memory",
                   in->path, name);
  hid_t t = st == MRVI_OK ? H5Dget_type(d) : H5I_INVALID_HID;
  if (st == MRVI_OK)
    st = t >= 0 ? read_text(in, name, d, 0, t, n, max_len, s) : MRVI_EIO;
  if (t >= 0)
    H5Tclose(t);
  H5Dclose(d);
  H5Eclear2(H5E_DEFAULT);
  if (st < 0) {
    mrvi_h5_strings_free(s, n);
    return st;
  }
  *out = s;
  return MRVI_OK;
}

/* ---------------------------------------------------------------------------
 * Root attributes: one value each
 * ------------------------------------------------------------------------- */

int mrvi_h5in_has_attr(const mrvi_h5in *in, const char *name) {
  const htri_t e = H5Aexists(in->file, name);
  H5Eclear2(H5E_DEFAULT);
  return e > 0;
}

/* The root attribute name, checked to hold one value of kind; its type in
 * *t (caller closes both). */
static hid_t attr_open(const mrvi_h5in *in, const char *name, int kind,
                       hid_t *t) {
  *t = H5I_INVALID_HID;
  if (!mrvi_h5in_has_attr(in, name)) {
    mrvi_fail(in->msg, in->len, MRVI_EIO, "%s: no root attribute %s", in->path,
              name);
    return H5I_INVALID_HID;
  }
  hid_t a = H5Aopen(in->file, name, H5P_DEFAULT);
  hid_t sp = a >= 0 ? H5Aget_space(a) : H5I_INVALID_HID;
  const hssize_t points = sp >= 0 ? H5Sget_simple_extent_npoints(sp) : -1;
  if (sp >= 0)
    H5Sclose(sp);
  *t = a >= 0 ? H5Aget_type(a) : H5I_INVALID_HID;
  const H5T_class_t c = *t >= 0 ? H5Tget_class(*t) : H5T_NO_CLASS;
  H5Eclear2(H5E_DEFAULT);
  if (a >= 0 && points == 1 && class_fits(c, kind))
    return a;
  if (a < 0)
    mrvi_fail(in->msg, in->len, MRVI_EIO, "%s: cannot open attribute %s",
              in->path, name);
  else if (points != 1)
    mrvi_fail(in->msg, in->len, MRVI_EIO,
              "%s: attribute %s holds %lld values, expected one", in->path,
              name, (long long)points);
  else
    mrvi_fail(in->msg, in->len, MRVI_EIO, "%s: attribute %s does not hold %s",
              in->path, name, kind == MRVI_H5_STRING ? "a string" : "a number");
  if (*t >= 0)
    H5Tclose(*t);
  *t = H5I_INVALID_HID;
  if (a >= 0)
    H5Aclose(a);
  return H5I_INVALID_HID;
}

int mrvi_h5in_attr_number(const mrvi_h5in *in, const char *name, double lo,
                          double hi, int integer, double *v) {
  hid_t t;
  hid_t a = attr_open(in, name, MRVI_H5_NUMBER, &t);
  if (a < 0)
    return MRVI_EIO;
  double x = NAN;
  const herr_t rc = H5Aread(a, H5T_NATIVE_DOUBLE, &x);
  H5Tclose(t);
  H5Aclose(a);
  H5Eclear2(H5E_DEFAULT);
  if (rc < 0)
    return mrvi_fail(in->msg, in->len, MRVI_EIO, "%s: cannot read attribute %s",
                     in->path, name);
  if (!(x >= lo && x <= hi) || (integer && x != floor(x)))
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: attribute %s = %.17g, expected %s in [%.17g, "
                     "%.17g]",
                     in->path, name, x, integer ? "an integer" : "a number", lo,
                     hi);
  *v = x;
  return MRVI_OK;
}

int mrvi_h5in_attr_string(const mrvi_h5in *in, const char *name, char *buf,
                          size_t len) {
  buf[0] = '\0';
  hid_t t;
  hid_t a = attr_open(in, name, MRVI_H5_STRING, &t);
  if (a < 0)
    return MRVI_EIO;
  char *s = NULL;
  const int st = read_text(in, name, a, 1, t, 1, MRVI_H5_MAX_ATTR, &s);
  H5Tclose(t);
  H5Aclose(a);
  H5Eclear2(H5E_DEFAULT);
  if (st == MRVI_OK)
    mrvi_fmt(buf, len, "%s", s);
  free(s);
  return st;
}
