/* Helpers shared by the HDF5 writers of src/io (hdf5_writer.c,
 * study_writer.c, optimize_output.c): HDF5's errors as messages,
 * attributes, datasets written whole, files written in one go, and the
 * output file's lock and temporary name (h5util.h). */
#define _GNU_SOURCE /* F_OFD_SETLK */
#include "io/h5util.h"
#include "io/io.h"

#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

/* ---------------------------------------------------------------------------
 * HDF5 errors: no printing, messages instead.
 * ------------------------------------------------------------------------- */
void mrvi_h5_quiet_begin(mrvi_h5_quiet *q) {
  /* No H5close at exit: after a failed flush (disk full) or on a corrupted
   * input file HDF5 1.10 cannot shut down cleanly and prints "infinite
   * loop closing library" (or crashes); files are complete when H5Fclose
   * returns, so nothing is lost by leaving the library's memory to the
   * process exit.  Has an effect only before the library's first use:
   * this is the first HDF5 call of every reader and writer of src/io. */
  H5dont_atexit();
  q->saved = H5Eget_auto2(H5E_DEFAULT, &q->func, &q->data) >= 0;
  H5Eset_auto2(H5E_DEFAULT, NULL, NULL);
  H5Eclear2(H5E_DEFAULT);
}

void mrvi_h5_quiet_end(const mrvi_h5_quiet *q) {
  if (q->saved)
    H5Eset_auto2(H5E_DEFAULT, q->func, q->data);
}

hid_t mrvi_h5_keep_errors(herr_t rc) {
  return rc < 0 ? H5Eget_current_stack() : H5I_INVALID_HID;
}

void mrvi_h5_restore_errors(hid_t es) {
  if (es >= 0)
    H5Eset_current_stack(es); /* also releases es */
}

typedef struct h5_walk_data {
  const char *outer;  /* description at the API function */
  const char *inner;  /* most specific description */
  const char *system; /* "error message = '...'" of a failed system call */
  int system_len;
} h5_walk_data;

static herr_t h5_walk(unsigned n, const H5E_error2_t *e, void *data) {
  h5_walk_data *d = data;
  (void)n;
  if (!e->desc || !e->desc[0])
    return 0;
  if (!d->outer)
    d->outer = e->desc;
  d->inner = e->desc;
  const char *key = "error message = '", *s = strstr(e->desc, key);
  if (s) {
    s += strlen(key);
    const char *end = strchr(s, '\'');
    d->system = s;
    d->system_len = end ? (int)(end - s) : (int)strlen(s);
  }
  return 0;
}

void mrvi_h5_error_message(char *buf, size_t len, const char *path,
                           const char *what) {
  h5_walk_data d = {NULL, NULL, NULL, 0};
  H5Ewalk2(H5E_DEFAULT, H5E_WALK_DOWNWARD, h5_walk, &d);
  if (d.system)
    mrvi_fmt(buf, len, "%s: %s: %.*s", path, what, d.system_len, d.system);
  else if (d.outer && strcmp(d.outer, d.inner) != 0)
    mrvi_fmt(buf, len, "%s: %s: %s (%s)", path, what, d.outer, d.inner);
  else if (d.outer)
    mrvi_fmt(buf, len, "%s: %s: %s", path, what, d.outer);
  else
    mrvi_fmt(buf, len, "%s: %s: HDF5 error", path, what);
  H5Eclear2(H5E_DEFAULT);
}

/* ---------------------------------------------------------------------------
 * Attributes and datasets written whole
 * ------------------------------------------------------------------------- */
hid_t mrvi_h5_string_type(size_t size) {
  hid_t t = H5Tcopy(H5T_C_S1);
  if (t < 0)
    return t;
  if (H5Tset_size(t, size ? size : 1) < 0 ||
      H5Tset_strpad(t, H5T_STR_NULLTERM) < 0 ||
      H5Tset_cset(t, H5T_CSET_UTF8) < 0) {
    H5Tclose(t);
    return H5I_INVALID_HID;
  }
  return t;
}

int mrvi_h5_type_variable(hid_t t) {
  return t < 0 || H5Tis_variable_str(t) != 0 ||
         H5Tdetect_class(t, H5T_VLEN) != 0;
}

/* Attribute `name` of obj, when it exists: 1 when its type is ftype (it is
 * then rewritten in place), 0 when it is deleted first (another type: a
 * string of another length), -1 on failure or when it holds variable-length
 * data (deleting it would free them from the file's global heap, which an
 * untrusted file may have corrupted). */
static int attr_same_type(hid_t obj, const char *name, hid_t ftype) {
  hid_t a = H5Aopen(obj, name, H5P_DEFAULT);
  hid_t t = a >= 0 ? H5Aget_type(a) : H5I_INVALID_HID;
  const int variable = mrvi_h5_type_variable(t);
  const htri_t same = variable ? -1 : H5Tequal(t, ftype);
  if (t >= 0)
    H5Tclose(t);
  if (a >= 0)
    H5Aclose(a);
  if (same < 0)
    return -1;
  if (same > 0)
    return 1;
  return H5Adelete(obj, name) < 0 ? -1 : 0;
}

herr_t mrvi_h5_attr_write(hid_t obj, const char *name, hid_t ftype, hid_t mtype,
                          const void *value) {
  hid_t a, es;
  htri_t exists = H5Aexists(obj, name);
  if (exists > 0)
    exists = attr_same_type(obj, name, ftype);
  if (exists < 0)
    return -1;
  if (exists) {
    a = H5Aopen(obj, name, H5P_DEFAULT);
  } else {
    hid_t space = H5Screate(H5S_SCALAR);
    if (space < 0)
      return -1;
    a = H5Acreate2(obj, name, ftype, space, H5P_DEFAULT, H5P_DEFAULT);
    es = mrvi_h5_keep_errors((herr_t)(a < 0 ? -1 : 0));
    H5Sclose(space);
    mrvi_h5_restore_errors(es);
  }
  if (a < 0)
    return -1;
  herr_t rc = H5Awrite(a, mtype, value);
  es = mrvi_h5_keep_errors(rc);
  if (H5Aclose(a) < 0)
    rc = -1;
  mrvi_h5_restore_errors(es);
  return rc;
}

herr_t mrvi_h5_attr_string(hid_t obj, const char *name, const char *value) {
  const char *v = value ? value : "";
  return mrvi_h5_attr_fixed(obj, name, v, strlen(v) + 1, H5T_CSET_UTF8);
}

herr_t mrvi_h5_attr_fixed(hid_t obj, const char *name, const char *value,
                          size_t size, H5T_cset_t cset) {
  char *buf = calloc(size ? size : 1, 1);
  hid_t t = buf ? mrvi_h5_string_type(size) : H5I_INVALID_HID;
  if (t < 0) {
    free(buf);
    return -1;
  }
  mrvi_fmt(buf, size, "%s", value ? value : "");
  herr_t rc = -1;
  if (H5Tset_cset(t, cset) >= 0)
    rc = mrvi_h5_attr_write(obj, name, t, t, buf);
  hid_t es = mrvi_h5_keep_errors(rc);
  H5Tclose(t);
  mrvi_h5_restore_errors(es);
  free(buf);
  return rc;
}

herr_t mrvi_h5_attr_fixed_string(hid_t obj, const char *name,
                                 const char *value) {
  return mrvi_h5_attr_fixed(obj, name, value, MRVI_H5_FIXED_BYTES,
                            H5T_CSET_UTF8);
}

herr_t mrvi_h5_write_strings(hid_t loc, const char *path, hid_t lcpl,
                             const char *const *v, hsize_t count, int scalar,
                             const char *long_name) {
  const size_t n = scalar ? 1 : (size_t)count;
  size_t size = 1;
  for (size_t i = 0; i < n; i++) {
    const size_t l = v[i] ? strlen(v[i]) + 1 : 1;
    size = l > size ? l : size;
  }
  if (n > 0 && size > SIZE_MAX / n)
    return -1;
  char *buf = calloc(n ? n * size : 1, 1);
  hid_t t = buf ? mrvi_h5_string_type(size) : H5I_INVALID_HID;
  herr_t rc = -1;
  if (t >= 0) {
    for (size_t i = 0; i < n; i++)
      if (v[i])
        memcpy(buf + i * size, v[i], strlen(v[i]));
    rc = mrvi_h5_write_fixed(loc, path, lcpl, t, t, count, 0, scalar, buf,
                             long_name);
    hid_t es = mrvi_h5_keep_errors(rc);
    H5Tclose(t);
    mrvi_h5_restore_errors(es);
  }
  free(buf);
  return rc;
}

herr_t mrvi_h5_attr_double(hid_t obj, const char *name, double value) {
  return mrvi_h5_attr_write(obj, name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE,
                            &value);
}

herr_t mrvi_h5_attr_int(hid_t obj, const char *name, int value) {
  return mrvi_h5_attr_write(obj, name, H5T_STD_I32LE, H5T_NATIVE_INT, &value);
}

herr_t mrvi_h5_attr_long(hid_t obj, const char *name, long value) {
  return mrvi_h5_attr_write(obj, name, H5T_STD_I64LE, H5T_NATIVE_LONG, &value);
}

herr_t mrvi_h5_write_fixed(hid_t loc, const char *path, hid_t lcpl, hid_t ftype,
                           hid_t mtype, hsize_t count, hsize_t cols, int scalar,
                           const void *data, const char *long_name) {
  const hsize_t dims[2] = {count, cols};
  hid_t space = scalar ? H5Screate(H5S_SCALAR)
                       : H5Screate_simple(cols > 0 ? 2 : 1, dims, NULL);
  if (space < 0)
    return -1;
  hid_t d = H5Dcreate2(loc, path, ftype, space, lcpl, H5P_DEFAULT, H5P_DEFAULT);
  hid_t es = mrvi_h5_keep_errors((herr_t)(d < 0 ? -1 : 0));
  H5Sclose(space);
  mrvi_h5_restore_errors(es);
  if (d < 0)
    return -1;
  herr_t rc = 0;
  if (scalar || count > 0)
    rc = H5Dwrite(d, mtype, H5S_ALL, H5S_ALL, H5P_DEFAULT, data);
  if (rc >= 0 && long_name)
    rc = mrvi_h5_attr_string(d, "long_name", long_name);
  es = mrvi_h5_keep_errors(rc);
  if (H5Dclose(d) < 0)
    rc = -1;
  mrvi_h5_restore_errors(es);
  return rc;
}

/* ---------------------------------------------------------------------------
 * A file written in one go
 * ------------------------------------------------------------------------- */
int mrvi_h5_batch_fail(mrvi_h5_batch *b, const char *what) {
  if (b->status == 0) {
    mrvi_h5_error_message(b->msg, b->len, b->path, what);
    b->status = MRVI_EIO;
  }
  return b->status;
}

int mrvi_h5_batch_fail_text(mrvi_h5_batch *b, int status, const char *text) {
  if (b->status == 0) {
    mrvi_fmt(b->msg, b->len, "%s: %s", b->path, text);
    b->status = status;
  }
  return b->status;
}

/* A failure to write object `name`. */
static void batch_fail_writing(mrvi_h5_batch *b, const char *verb,
                               const char *name) {
  char what[160];
  mrvi_fmt(what, sizeof what, "%s %s", verb, name);
  mrvi_h5_batch_fail(b, what);
}

hid_t mrvi_h5_batch_group(mrvi_h5_batch *b, hid_t loc, const char *name) {
  if (b->status || loc < 0)
    return H5I_INVALID_HID;
  hid_t g = H5Gcreate2(loc, name, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  if (g < 0)
    batch_fail_writing(b, "creating group", name);
  return g;
}

void mrvi_h5_batch_doubles(mrvi_h5_batch *b, hid_t loc, const char *name,
                           const double *v, hsize_t n, hsize_t cols) {
  if (b->status == 0 &&
      mrvi_h5_write_fixed(loc, name, H5P_DEFAULT, H5T_IEEE_F64LE,
                          H5T_NATIVE_DOUBLE, n, cols, 0, v, NULL) < 0)
    batch_fail_writing(b, "writing", name);
}

void mrvi_h5_batch_ints(mrvi_h5_batch *b, hid_t loc, const char *name,
                        const int *v, hsize_t n, hsize_t cols) {
  if (b->status == 0 &&
      mrvi_h5_write_fixed(loc, name, H5P_DEFAULT, H5T_STD_I32LE, H5T_NATIVE_INT,
                          n, cols, 0, v, NULL) < 0)
    batch_fail_writing(b, "writing", name);
}

void mrvi_h5_batch_attr_string(mrvi_h5_batch *b, hid_t loc, const char *name,
                               const char *value) {
  if (b->status == 0 && mrvi_h5_attr_string(loc, name, value) < 0)
    batch_fail_writing(b, "writing attribute", name);
}

void mrvi_h5_batch_attr_double(mrvi_h5_batch *b, hid_t loc, const char *name,
                               double value) {
  if (b->status == 0 && mrvi_h5_attr_double(loc, name, value) < 0)
    batch_fail_writing(b, "writing attribute", name);
}

void mrvi_h5_batch_attr_int(mrvi_h5_batch *b, hid_t loc, const char *name,
                            int value) {
  if (b->status == 0 && mrvi_h5_attr_int(loc, name, value) < 0)
    batch_fail_writing(b, "writing attribute", name);
}

/* ---------------------------------------------------------------------------
 * The output file: lock, temporary name, rename
 * ------------------------------------------------------------------------- */
/* The whole file, for an open-file-description lock (fcntl F_OFD_*). */
static struct flock whole_file(short type) {
  struct flock l;
  memset(&l, 0, sizeof l);
  l.l_type = type;
  l.l_whence = SEEK_SET; /* l_start = l_len = 0: from 0 to any end */
  return l;
}

int mrvi_h5_lock_fd(int fd) {
  struct flock l = whole_file(F_WRLCK);
  if (fcntl(fd, F_OFD_SETLK, &l) == 0)
    return 0;
  if (errno == EACCES)
    errno = EAGAIN;
  return -1;
}

int mrvi_h5_held(const char *path) {
  int fd = open(path, O_RDONLY | O_CLOEXEC);
  if (fd < 0)
    return 0;
  struct flock l = whole_file(F_RDLCK);
  const int held = fcntl(fd, F_OFD_GETLK, &l) == 0 && l.l_type != F_UNLCK;
  close(fd);
  return held;
}

int mrvi_h5_lock_output(const char *path, int force, int *fd, int *created,
                        char *msg, size_t len) {
  struct stat st;
  int existed = stat(path, &st) == 0;
  *fd = -1;
  *created = 0;
  /* A symbolic link to nowhere: open(O_CREAT) would create its target,
   * wherever it points. */
  if (!existed && lstat(path, &st) == 0 && S_ISLNK(st.st_mode))
    return mrvi_fail(msg, len, MRVI_EIO,
                     "a symbolic link to a missing file; not followed");
  if (existed && !S_ISREG(st.st_mode))
    return mrvi_fail(msg, len, MRVI_EIO, "not a regular file");
  *fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0666);
  *created = !existed && *fd >= 0;
  if (*fd < 0)
    return mrvi_fail(msg, len, MRVI_EIO, "cannot create the file: %s",
                     strerror(errno));
  if (mrvi_h5_lock_fd(*fd) < 0) {
    int e = errno;
    close(*fd);
    *fd = -1;
    if (e == EAGAIN)
      return mrvi_fail(msg, len, MRVI_EIO,
                       "the file is in use by another run (locked); "
                       "not touched");
    return mrvi_fail(msg, len, MRVI_EIO, "cannot lock the file: %s",
                     strerror(e));
  }
  if (!existed || force || fstat(*fd, &st) < 0 || st.st_size == 0)
    return MRVI_OK;
  /* An existing non-empty file: an mrvi output has the root attribute
   * mrvi_version. */
  int ours = 0;
#if H5_VERSION_GE(1, 12, 0)
  htri_t is_h5 = H5Fis_accessible(path, H5P_DEFAULT);
#else
  htri_t is_h5 = H5Fis_hdf5(path);
#endif
  if (is_h5 > 0) {
    hid_t fapl = H5Pcreate(H5P_FILE_ACCESS);
#if H5_VERSION_GE(1, 10, 7)
    if (fapl >= 0)
      H5Pset_file_locking(fapl, 0, 1);
#endif
    hid_t f = mrvi_h5_open_read(path, fapl >= 0 ? fapl : H5P_DEFAULT);
    if (fapl >= 0)
      H5Pclose(fapl);
    if (f >= 0) {
      ours = H5Aexists(f, "mrvi_version") > 0;
      H5Fclose(f);
    }
  }
  H5Eclear2(H5E_DEFAULT);
  if (ours)
    return MRVI_OK;
  close(*fd);
  *fd = -1;
  return mrvi_fail(msg, len, MRVI_EIO,
                   "exists and is not an mrvi output file; not overwritten "
                   "(use --force to replace it)");
}

/* The temporary file is created with mode 0666 less the umask, as the
 * final output should be (and as fopen makes the .xdmf and .xyz beside
 * it); mkstemp would make it 0600.  Names OUT.partXXXXXX with six
 * characters mixed from the process id, the clock and a counter; a name
 * already taken is tried again. */
int mrvi_h5_part_create(const char *path, char **part, char *msg, size_t len) {
  static const char chars[] =
      "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789";
  static unsigned long counter;
  const size_t plen = strlen(path) + 16;
  *part = malloc(plen);
  if (!*part)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  /* The file name with ".partXXXXXX" (11 bytes) must stay within NAME_MAX:
   * a longer name is cut for the temporary file only. */
  const char *slash = strrchr(path, '/');
  const size_t dir = slash ? (size_t)(slash - path) + 1 : 0;
  size_t keep = strlen(path) - dir;
  if (keep + 11 > NAME_MAX)
    keep = NAME_MAX - 11;
  struct timespec ts;
  clock_gettime(CLOCK_REALTIME, &ts);
  unsigned long long x = (unsigned long long)getpid() * 0x9E3779B97F4A7C15ull ^
                         (unsigned long long)ts.tv_nsec ^
                         (unsigned long long)ts.tv_sec << 20;
  int fd = -1, e = EEXIST;
  for (int attempt = 0; attempt < 100 && fd < 0 && e == EEXIST; attempt++) {
    x = (x ^ ++counter) * 0x2545F4914F6CDD1Dull;
    char suffix[7];
    unsigned long long y = x >> 16;
    for (int i = 0; i < 6; i++, y /= 62)
      suffix[i] = chars[y % 62];
    suffix[6] = '\0';
    mrvi_fmt(*part, plen, "%.*s.part%s", (int)(dir + keep), path, suffix);
    fd = open(*part, O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    e = fd < 0 ? errno : 0;
  }
  if (fd < 0) {
    free(*part);
    *part = NULL;
    return mrvi_fail(msg, len, MRVI_EIO, "cannot create a file beside it: %s",
                     strerror(e));
  }
  close(fd);
  return MRVI_OK;
}

int mrvi_h5_part_commit(const char *part, const char *path, int *fd, char *msg,
                        size_t len) {
  int pfd = open(part, O_RDWR | O_CLOEXEC);
  if (pfd < 0 || mrvi_h5_lock_fd(pfd) < 0 || rename(part, path) < 0) {
    int e = errno;
    if (pfd >= 0)
      close(pfd);
    return mrvi_fail(msg, len, MRVI_EIO, "cannot rename %s to it: %s", part,
                     strerror(e));
  }
  if (*fd >= 0)
    close(*fd);
  *fd = pfd;
  return MRVI_OK;
}
