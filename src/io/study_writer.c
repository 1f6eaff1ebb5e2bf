/* HDF5 tables of the study commands (doc/output.md): `mrvi converge`
 * (/convergence), `mrvi stability` (/stability) and `mrvi timing`
 * (/timing).
 *
 * A table is written whole: the output path is locked (a live run's file is
 * never replaced), the table is written to a file beside it and renamed to
 * it when complete, so that a process killed while writing leaves the
 * previous file at the path, never a half-written one (h5util.h).  The
 * renamed file keeps the permissions the path had (or would get). */
#include "io/h5util.h"
#include "io/io.h"

#include <stdlib.h>
#include <sys/stat.h>
#include <unistd.h>

const char *const mrvi_stability_rule_name[MRVI_STABILITY_RULES] = {
    "trapezoidal", "midpoint"};

/* ---------------------------------------------------------------------------
 * A table file
 * ------------------------------------------------------------------------- */
typedef struct table {
  mrvi_h5_batch b; /* the file being written (the part file) */
  char *part;      /* its name */
  int lock_fd;     /* holds the lock on the output path */
  int created;     /* the path did not exist before */
  mrvi_h5_quiet q;
} table;

/* Lock path and create the file beside it.  table_close follows, also on
 * failure. */
static int table_open(table *t, const char *path, char *msg, size_t len) {
  *t = (table){
      .b = {.path = path, .file = H5I_INVALID_HID, .msg = msg, .len = len},
      .lock_fd = -1};
  mrvi_fmt(msg, len, "%s", "");
  mrvi_h5_quiet_begin(&t->q);
  char text[400];
  /* force: a table replaces any regular file, as it always has. */
  int rc =
      mrvi_h5_lock_output(path, 1, &t->lock_fd, &t->created, text, sizeof text);
  if (rc == 0)
    rc = mrvi_h5_part_create(path, &t->part, text, sizeof text);
  if (rc)
    return mrvi_h5_batch_fail_text(&t->b, rc, text);
  t->b.file = H5Fcreate(t->part, H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  if (t->b.file < 0)
    return mrvi_h5_batch_fail(&t->b, "cannot create the file");
  return 0;
}

/* Close the file; when all went well give it the permissions of the path
 * and rename it to the path, else remove it (and the path, if created). */
static int table_close(table *t) {
  mrvi_h5_batch *b = &t->b;
  if (b->file >= 0 && H5Fclose(b->file) < 0)
    mrvi_h5_batch_fail(b, "closing the file");
  struct stat st;
  if (b->status == 0 && fstat(t->lock_fd, &st) == 0)
    chmod(t->part, st.st_mode & 07777);
  char text[400];
  if (b->status == 0 &&
      mrvi_h5_part_commit(t->part, b->path, &t->lock_fd, text, sizeof text) < 0)
    mrvi_h5_batch_fail_text(b, MRVI_EIO, text);
  if (b->status) {
    if (t->part)
      remove(t->part);
    if (t->created && lstat(b->path, &st) == 0 && S_ISREG(st.st_mode))
      remove(b->path);
  }
  if (t->lock_fd >= 0)
    close(t->lock_fd); /* releases the lock */
  free(t->part);
  H5Eclear2(H5E_DEFAULT);
  mrvi_h5_quiet_end(&t->q);
  return b->status;
}

static void group_close(hid_t g) {
  if (g >= 0)
    H5Gclose(g);
}

/* ---------------------------------------------------------------------------
 * The tables
 * ------------------------------------------------------------------------- */
int mrvi_study_write_convergence(const char *path,
                                 const mrvi_convergence_table *c, char *msg,
                                 size_t len) {
  table t;
  mrvi_h5_batch *b = &t.b;
  if (table_open(&t, path, msg, len) == 0) {
    mrvi_h5_batch_attr_string(b, b->file, "system", c->system);
    mrvi_h5_batch_attr_string(b, b->file, "scheme", c->scheme);
    mrvi_h5_batch_attr_double(b, b->file, "t_end", c->t_end);
    mrvi_h5_batch_attr_double(b, b->file, "reference_step", c->reference_step);
    mrvi_h5_batch_attr_string(b, b->file, "reference_scheme",
                              c->reference_scheme);
    mrvi_h5_batch_attr_string(b, b->file, "mrvi_version", mrvi_version());
    hid_t g = mrvi_h5_batch_group(b, b->file, "convergence");
    for (int i = 0; i < c->n_p && b->status == 0; i++) {
      const mrvi_convergence_rows *r = &c->by_p[i];
      char name[32];
      mrvi_fmt(name, sizeof name, "p%d", r->p);
      hid_t s = mrvi_h5_batch_group(b, g, name);
      mrvi_h5_batch_attr_int(b, s, "micro_steps", r->p);
      mrvi_h5_batch_doubles(b, s, "macro_step", r->macro_step, (hsize_t)r->rows,
                            0);
      double *col = malloc(((size_t)r->rows + 1) * sizeof *col);
      if (!col)
        mrvi_h5_batch_fail_text(b, MRVI_ENOMEM, "out of memory");
#define WRITE_COLUMN(dset, field)                                              \
  for (int k = 0; col && k < r->rows; k++)                                     \
    col[k] = r->errors[k].field;                                               \
  mrvi_h5_batch_doubles(b, s, #dset, col, (hsize_t)r->rows, 0);
      MRVI_ERROR_COLUMNS(WRITE_COLUMN)
#undef WRITE_COLUMN
      free(col);
      group_close(s);
    }
    group_close(g);
  }
  return table_close(&t);
}

int mrvi_study_write_stability(const char *path, const mrvi_stability_table *s,
                               char *msg, size_t len) {
  table t;
  mrvi_h5_batch *b = &t.b;
  if (table_open(&t, path, msg, len) == 0) {
    const hsize_t n_p = (hsize_t)s->n_p, K = (hsize_t)s->n_scan;
    mrvi_h5_batch_attr_string(b, b->file, "system", s->system);
    mrvi_h5_batch_attr_double(b, b->file, "omega", s->omega);
    mrvi_h5_batch_attr_string(b, b->file, "mrvi_version", mrvi_version());
    hid_t g = mrvi_h5_batch_group(b, b->file, "stability");
    mrvi_h5_batch_ints(b, g, "p", s->p, n_p, 0);
    for (int r = 0; r < MRVI_STABILITY_RULES; r++) {
      char name[64];
      mrvi_fmt(name, sizeof name, "%s_measured", mrvi_stability_rule_name[r]);
      mrvi_h5_batch_doubles(b, g, name, s->measured[r], n_p, 0);
      mrvi_fmt(name, sizeof name, "%s_analytic", mrvi_stability_rule_name[r]);
      mrvi_h5_batch_doubles(b, g, name, s->analytic[r], n_p, 0);
    }
    hid_t sg = mrvi_h5_batch_group(b, g, "scan");
    mrvi_h5_batch_doubles(b, sg, "omega_dT", s->omega_dT, K, 0);
    mrvi_h5_batch_ints(b, sg, "p", s->p, n_p, 0);
    for (int r = 0; r < MRVI_STABILITY_RULES; r++) {
      char name[64];
      mrvi_fmt(name, sizeof name, "trace_%s", mrvi_stability_rule_name[r]);
      mrvi_h5_batch_doubles(b, sg, name, s->trace + (size_t)r * n_p * K, n_p,
                            K);
    }
    group_close(sg);
    group_close(g);
  }
  return table_close(&t);
}

int mrvi_study_write_timing(const char *path, const mrvi_timing_table *tm,
                            char *msg, size_t len) {
  table t;
  mrvi_h5_batch *b = &t.b;
  if (table_open(&t, path, msg, len) == 0) {
    const int n_p = tm->n_p;
    mrvi_h5_batch_attr_string(b, b->file, "system", tm->system);
    mrvi_h5_batch_attr_double(b, b->file, "micro_step", tm->micro_step);
    mrvi_h5_batch_attr_double(b, b->file, "t_end", tm->t_end);
    mrvi_h5_batch_attr_int(b, b->file, "repeat", tm->repeat);
    mrvi_h5_batch_attr_string(b, b->file, "mrvi_version", mrvi_version());
    hid_t g = mrvi_h5_batch_group(b, b->file, "timing");
    mrvi_h5_batch_ints(b, g, "p", tm->p, (hsize_t)n_p, 0);
    double *col = malloc(((size_t)n_p + 1) * sizeof *col);
    if (!col)
      mrvi_h5_batch_fail_text(b, MRVI_ENOMEM, "out of memory");
    for (int i = 0; i < tm->n_schemes && b->status == 0; i++) {
      hid_t sg = mrvi_h5_batch_group(b, g, tm->schemes[i]);
#define TIMING_WRITE(name)                                                     \
  for (int j = 0; j < n_p; j++)                                                \
    col[j] = tm->rows[(size_t)i * n_p + j].name;                               \
  mrvi_h5_batch_doubles(b, sg, #name, col, (hsize_t)n_p, 0);
      MRVI_TIMING_COLUMNS(TIMING_WRITE)
#undef TIMING_WRITE
      group_close(sg);
    }
    free(col);
    group_close(g);
  }
  return table_close(&t);
}
