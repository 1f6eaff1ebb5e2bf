/* Helpers shared by the HDF5 readers and writers of src/io: opening a run
 * file for reading (hdf5_reader.c), and for writing (h5util.c) HDF5's
 * errors as messages, attributes, datasets written whole, files written in
 * one go, and the output file's lock and temporary name (the crash-safety
 * path of doc/output.md, "Crash safety"). */
#ifndef MRVI_H5UTIL_H
#define MRVI_H5UTIL_H

#include <hdf5.h>
#include <stddef.h>

/* Open an mrvi output read-only.  A run killed while writing (SIGKILL,
 * power loss) leaves HDF5's "open for writing" flag set in the file, which
 * a plain open refuses; such a file is opened for SWMR reading, which HDF5
 * allows for a file written in SWMR mode (doc/output.md, "Crash safety").
 * fapl: H5P_DEFAULT or a file access property list. */
hid_t mrvi_h5_open_read(const char *path, hid_t fapl);

/* The root attribute stop_reason of an open mrvi output into buf ("" when
 * absent or not one string), variable- or fixed-length.  "running" becomes
 * "incomplete (writer killed)" unless a live run still holds the file's lock
 * (then it stays "running"). */
void mrvi_h5_stop_reason(hid_t file, const char *path, char *buf, size_t len);

/* ---------------------------------------------------------------------------
 * HDF5 errors: no printing, messages instead (h5util.c).
 * ------------------------------------------------------------------------- */
typedef struct mrvi_h5_quiet {
  H5E_auto2_t func;
  void *data;
  int saved;
} mrvi_h5_quiet;

/* Switch HDF5's automatic error printing off (remembering the caller's
 * setting) and start from an empty error stack; _end restores it. */
void mrvi_h5_quiet_begin(mrvi_h5_quiet *q);
void mrvi_h5_quiet_end(const mrvi_h5_quiet *q);

/* Every successful HDF5 call clears the error stack, so the stack of a
 * failed call is set aside while the handles it leaves are closed:
 *   es = mrvi_h5_keep_errors(rc); ...close...; mrvi_h5_restore_errors(es); */
hid_t mrvi_h5_keep_errors(herr_t rc);
void mrvi_h5_restore_errors(hid_t es);

/* "path: what: reason" from the error stack into buf: the operating
 * system's message when there is one ("No such file or directory", "File
 * too large"), else HDF5's description at the API call and the most
 * specific one; then clear the stack. */
void mrvi_h5_error_message(char *buf, size_t len, const char *path,
                           const char *what);

/* ---------------------------------------------------------------------------
 * Validated reading (h5read.c): every HDF5 read of mrvi goes through these.
 * Files are untrusted; before any data is read a dataset's type class,
 * exact rank and every dimension are checked, sizes computed with overflow
 * checks and capped, and buffers sized from the checked shape.
 * ------------------------------------------------------------------------- */

/* Bytes one read of a file may allocate: a quarter of the machine's memory
 * (mrvi_machine_memory; 1 GiB when unknown). */
size_t mrvi_h5_read_cap(void);

/* A dimension the file decides (e.g. the rows a run stored). */
#define MRVI_H5_ANY ((hsize_t)-1)
/* Highest rank mrvi reads (/bodies/rotation: rows x bodies x d x d). */
#define MRVI_H5_MAX_RANK 4
/* Metadata read attempts of a file opened in SWMR mode, read or write
 * (HDF5's default: 100, each retrying the checksum failures of a whole
 * metadata cache load with sleeps, which on a corrupted superblock, a
 * truncated file or a corrupted chunk index spins for tens of minutes:
 * the readers, and the writer appending to a file for --resume, where
 * fuzz_h5 found it in H5Dset_extent). */
#define MRVI_H5_SWMR_READ_ATTEMPTS 10
/* Longest string attribute read (stop_reason, versions, settings). */
#define MRVI_H5_MAX_ATTR ((size_t)65536)
/* Longest /model/description read. */
#define MRVI_H5_MAX_TEXT ((size_t)64 << 20)

/* An input file: the open file, its name and the caller's message buffer,
 * which every failure below fills with "PATH: DATASET ... expected ..."
 * and a negative status. */
typedef struct mrvi_h5in {
  hid_t file;
  const char *path;
  char *msg;
  size_t len;
} mrvi_h5in;

enum { MRVI_H5_NUMBER = 0, MRVI_H5_STRING = 1 };

/* 1 when the absolute path name leads to an object through hard links. */
int mrvi_h5in_exists(const mrvi_h5in *in, const char *name);
/* Open dataset name, checked: type class kind (MRVI_H5_NUMBER: integer or
 * float; MRVI_H5_STRING), rank exactly `rank` (0: scalar, up to
 * MRVI_H5_MAX_RANK), each dimension equal to want[i] unless MRVI_H5_ANY
 * (want NULL: any), every dimension after the first at most INT_MAX.  dims
 * (rank entries) gets the shape.  The dataset id, or H5I_INVALID_HID with
 * the message. */
hid_t mrvi_h5in_open(const mrvi_h5in *in, const char *name, int kind, int rank,
                     const hsize_t *want, hsize_t *dims);
/* As mrvi_h5in_open, closing the dataset: MRVI_OK or MRVI_EIO. */
int mrvi_h5in_shape(const mrvi_h5in *in, const char *name, int kind, int rank,
                    const hsize_t *want, hsize_t *dims);
/* Rows [row, row + rows) of the numeric dataset name (checked as above) as
 * mtype into buf, which has room for cap elements (rows times the product
 * of the other dimensions must fit; rank 0: row 0, rows 1). */
int mrvi_h5in_read(const mrvi_h5in *in, const char *name, hid_t mtype, int rank,
                   const hsize_t *want, hsize_t row, hsize_t rows, void *buf,
                   size_t cap);
/* The first `rows` rows (MRVI_H5_ANY: all) of the numeric dataset name as
 * mtype into a new array (*out, free()), sized from the checked shape and
 * at most mrvi_h5_read_cap() bytes; dims (may be NULL) gets the shape. */
int mrvi_h5in_read_new(const mrvi_h5in *in, const char *name, hid_t mtype,
                       int rank, const hsize_t *want, hsize_t rows, void **out,
                       hsize_t *dims);
/* The strings of dataset name: rank 1 with `count` entries (MRVI_H5_ANY:
 * any) or rank 0 (one string), variable- or fixed-length, each at most
 * max_len bytes; *out gets malloc'ed copies (mrvi_h5_strings_free). */
int mrvi_h5in_strings(const mrvi_h5in *in, const char *name, int rank,
                      hsize_t count, size_t max_len, char ***out);
void mrvi_h5_strings_free(char **s, size_t count);

/* Root attributes: exactly one value each. */
int mrvi_h5in_has_attr(const mrvi_h5in *in, const char *name);
/* A number in [lo, hi] (an integer if `integer`) into *v. */
int mrvi_h5in_attr_number(const mrvi_h5in *in, const char *name, double lo,
                          double hi, int integer, double *v);
/* A string of at most MRVI_H5_MAX_ATTR bytes into buf ("" on failure). */
int mrvi_h5in_attr_string(const mrvi_h5in *in, const char *name, char *buf,
                          size_t len);

/* ---------------------------------------------------------------------------
 * Attributes and datasets written whole (h5util.c).  herr_t: < 0 on failure,
 * with the reason on HDF5's error stack.
 * ------------------------------------------------------------------------- */

/* Fixed-length UTF-8 string type of `size` bytes (at least 1), NUL-
 * terminated; close it.  mrvi writes no variable-length strings: their
 * data live in the file's global heap, which libhdf5 reads unchecked
 * (doc/output.md, "Strings"); h5py reads these as bytes. */
hid_t mrvi_h5_string_type(size_t size);
/* 1 when type t is (or holds) variable-length data, or is invalid. */
int mrvi_h5_type_variable(hid_t t);

/* Create or overwrite the scalar attribute `name` of obj (one of another
 * type is deleted and created again; one holding variable-length data is
 * refused, < 0). */
herr_t mrvi_h5_attr_write(hid_t obj, const char *name, hid_t ftype, hid_t mtype,
                          const void *value);
/* Fixed-length UTF-8 string of the value's length (NULL: ""). */
herr_t mrvi_h5_attr_string(hid_t obj, const char *name, const char *value);
/* Fixed-length string of `size` bytes (value truncated, NUL-terminated and
 * padded) in character set cset: rewritten in place in the object header,
 * never in the global heap, so SWMR writing may change it. */
herr_t mrvi_h5_attr_fixed(hid_t obj, const char *name, const char *value,
                          size_t size, H5T_cset_t cset);
/* The fixed-length string of MRVI_H5_FIXED_BYTES, UTF-8, that SWMR writing
 * rewrites: the root attribute stop_reason of a run file. */
#define MRVI_H5_FIXED_BYTES 1024
herr_t mrvi_h5_attr_fixed_string(hid_t obj, const char *name,
                                 const char *value);
/* Dataset `path` of loc: the strings v[0 .. count-1] (scalar: v[0] alone),
 * fixed-length UTF-8 of the longest one's size, with the attribute
 * long_name when not NULL. */
herr_t mrvi_h5_write_strings(hid_t loc, const char *path, hid_t lcpl,
                             const char *const *v, hsize_t count, int scalar,
                             const char *long_name);
herr_t mrvi_h5_attr_double(hid_t obj, const char *name, double value);
herr_t mrvi_h5_attr_int(hid_t obj, const char *name, int value);
herr_t mrvi_h5_attr_long(hid_t obj, const char *name, long value);

/* Dataset `path` of loc: count elements, or count x cols (cols > 0), or one
 * scalar, of file type ftype from memory type mtype; with the attribute
 * long_name unless long_name is NULL.  lcpl: link creation properties
 * (H5P_DEFAULT, or one creating intermediate groups). */
herr_t mrvi_h5_write_fixed(hid_t loc, const char *path, hid_t lcpl, hid_t ftype,
                           hid_t mtype, hsize_t count, hsize_t cols, int scalar,
                           const void *data, const char *long_name);

/* ---------------------------------------------------------------------------
 * A file written in one go (h5util.c): many objects, one error check.
 * Every call below is a no-op once a call failed; the first failure stays
 * as status, with "path: what: reason" in msg.
 * ------------------------------------------------------------------------- */
typedef struct mrvi_h5_batch {
  const char *path; /* names the file in messages */
  hid_t file;
  int status; /* first failure (0 if none) */
  char *msg;
  size_t len;
} mrvi_h5_batch;

/* Record a failure: the reason from HDF5's error stack; _text: text as the
 * reason.  Return the batch's status. */
int mrvi_h5_batch_fail(mrvi_h5_batch *b, const char *what);
int mrvi_h5_batch_fail_text(mrvi_h5_batch *b, int status, const char *text);
/* Group `name` of loc (H5I_INVALID_HID after a failure); close it. */
hid_t mrvi_h5_batch_group(mrvi_h5_batch *b, hid_t loc, const char *name);
/* Dataset `name` of loc without attributes: n float64 or int32 values, or
 * n x cols (cols > 0). */
void mrvi_h5_batch_doubles(mrvi_h5_batch *b, hid_t loc, const char *name,
                           const double *v, hsize_t n, hsize_t cols);
void mrvi_h5_batch_ints(mrvi_h5_batch *b, hid_t loc, const char *name,
                        const int *v, hsize_t n, hsize_t cols);
/* Attributes, as mrvi_h5_attr_*. */
void mrvi_h5_batch_attr_string(mrvi_h5_batch *b, hid_t loc, const char *name,
                               const char *value);
void mrvi_h5_batch_attr_double(mrvi_h5_batch *b, hid_t loc, const char *name,
                               double value);
void mrvi_h5_batch_attr_int(mrvi_h5_batch *b, hid_t loc, const char *name,
                            int value);

/* ---------------------------------------------------------------------------
 * The output file (h5util.c): locked while written, set up under a
 * temporary name beside it and renamed to it when complete, so that a
 * second writer never destroys the file of a live one and a process killed
 * before the rename leaves the previous file (or an empty one) at the path,
 * never a half-built one.  Messages go into msg without the path.
 * ------------------------------------------------------------------------- */

/* mrvi's own lock on an output file: an open-file-description write lock
 * over the whole file (fcntl F_OFD_SETLK), held until fd is closed.  Not
 * flock: HDF5 1.10 flocks the files it opens (a reader LOCK_SH), and an
 * flock(LOCK_EX) of the writer kept every reader with HDF5's default file
 * locking out ("unable to lock file" in h5py.File(f, "r", swmr=True)).  On
 * Linux flock and fcntl locks are independent (not on NFS, where flock is
 * emulated by byte-range locks); an OFD lock belongs to its open file
 * description, so HDF5 opening and closing the same file does not release
 * it (as it would a classic POSIX lock).  -1 with errno EAGAIN when another
 * open file description holds a lock on it. */
int mrvi_h5_lock_fd(int fd);
/* 1 when a live writer holds mrvi_h5_lock_fd's lock on path. */
int mrvi_h5_held(const char *path);

/* Take an exclusive lock (mrvi_h5_lock_fd, held on *fd until it is closed) on
 * the output path, creating it empty when absent (*created = 1), before
 * anything truncates it; refuse a file that is not a regular file, is
 * locked by a live writer, or (unless force) is not empty and not an mrvi
 * output (no root attribute mrvi_version).  MRVI_EIO with a message; on
 * failure *fd is -1 and *created still says whether the file was created
 * (the caller removes it). */
int mrvi_h5_lock_output(const char *path, int force, int *fd, int *created,
                        char *msg, size_t len);

/* A new empty file beside path ("path.partXXXXXX") into *part (malloc'd,
 * the caller frees); MRVI_EIO or MRVI_ENOMEM with a message. */
int mrvi_h5_part_create(const char *path, char **part, char *msg, size_t len);

/* Rename part to path, moving the lock with it: the new file is locked
 * (on a new descriptor, which replaces *fd) before it gets the name, so a
 * second writer never finds the path unlocked.  MRVI_EIO with a message. */
int mrvi_h5_part_commit(const char *part, const char *path, int *fd, char *msg,
                        size_t len);

#endif
