/* Reading mrvi HDF5 files back (doc/output.md): a run into a trajectory
 * (e.g. a cached reference solution of a convergence study), a stored
 * macro node to resume or continue from.  Every
 * read goes through the validated layer of h5read.c. */
#include "io/h5util.h"
#include "io/io.h"

#include <hdf5.h>
#include <errno.h>
#include <limits.h>
#include <fcntl.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* 1 when the superblock at the start of the file (versions 2 and 3, those
 * of SWMR files) says it is open for writing or SWMR writing: its file
 * consistency flags (byte 11) have bit 0 or 2 set.  A file without them
 * was closed and is not opened for SWMR reading at all. */
static int flagged_open_for_writing(const char *path) {
  unsigned char sb[12];
  int fd = open(path, O_RDONLY | O_CLOEXEC);
  if (fd < 0)
    return 0;
  const ssize_t got = read(fd, sb, sizeof sb);
  close(fd);
  return got == (ssize_t)sizeof sb && !memcmp(sb, "\x89HDF\r\n\x1a\n", 8) &&
         sb[8] >= 2 && sb[8] <= 3 && (sb[11] & 0x05) != 0;
}

hid_t mrvi_h5_open_read(const char *path, hid_t fapl) {
  hid_t f = H5Fopen(path, H5F_ACC_RDONLY, fapl);
  if (f < 0 && flagged_open_for_writing(path)) {
    hid_t swmr = H5Pcopy(fapl == H5P_DEFAULT ? H5P_FILE_ACCESS_DEFAULT : fapl);
    if (swmr >= 0 &&
        H5Pset_metadata_read_attempts(swmr, MRVI_H5_SWMR_READ_ATTEMPTS) >= 0)
      f = H5Fopen(path, H5F_ACC_RDONLY | H5F_ACC_SWMR_READ, swmr);
    if (swmr >= 0)
      H5Pclose(swmr);
  }
  H5Eclear2(H5E_DEFAULT);
  return f;
}

void mrvi_h5_stop_reason(hid_t file, const char *path, char *buf, size_t len) {
  char scratch[256];
  const mrvi_h5in in = {file, path, scratch, sizeof scratch};
  if (mrvi_h5in_has_attr(&in, "stop_reason"))
    mrvi_h5in_attr_string(&in, "stop_reason", buf, len);
  else
    buf[0] = '\0';
  if (!strcmp(buf, "running") && !mrvi_h5_held(path))
    mrvi_fmt(buf, len, "%s", "incomplete (writer killed)");
}

int mrvi_run_file_status(const char *path, char *reason, size_t len) {
  mrvi_h5_quiet q;
  mrvi_h5_quiet_begin(&q);
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
  mrvi_h5_quiet_end(&q);
  return st;
}

/* The largest count of coordinates a file may declare: the per-node
 * vectors a reader keeps (q, p and their like, a few of each) within
 * mrvi_h5_read_cap(). */
static hsize_t max_coordinates(void) {
  const size_t n = mrvi_h5_read_cap() / (8 * sizeof(double));
  return n < INT_MAX ? (hsize_t)n : INT_MAX;
}

/* /model/rate (rank 1, n entries: the model's, or any up to
 * max_coordinates() when n = 0) and /macro/q (rank 2, n columns): *nq gets
 * n, rows of /macro/q in *rows (may be NULL). */
static int coordinates(const mrvi_h5in *in, int n, int *nq, hsize_t *rows) {
  hsize_t dq[2], dr[1];
  const hsize_t want[2] = {MRVI_H5_ANY, n > 0 ? (hsize_t)n : MRVI_H5_ANY};
  int st = mrvi_h5in_shape(in, "/macro/q", MRVI_H5_NUMBER, 2, want, dq);
  if (st < 0)
    return st;
  if (dq[1] < 1 || dq[1] > max_coordinates())
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: /macro/q has %llu columns (coordinates), expected "
                     "1 to %llu",
                     in->path, (unsigned long long)dq[1],
                     (unsigned long long)max_coordinates());
  if ((st = mrvi_h5in_shape(in, "/model/rate", MRVI_H5_NUMBER, 1, &dq[1], dr)) <
      0)
    return st;
  *nq = (int)dq[1];
  if (rows)
    *rows = dq[0];
  return MRVI_OK;
}

int mrvi_trajectory_read(const char *path, mrvi_trajectory **out, char *msg,
                         size_t len) {
  *out = NULL;
  mrvi_h5_quiet q;
  mrvi_h5_quiet_begin(&q);
  int st = MRVI_OK;
  mrvi_trajectory *tr = calloc(1, sizeof *tr);
  hid_t file = mrvi_h5_open_read(path, H5P_DEFAULT);
  const mrvi_h5in in = {file, path, msg, len};
  if (!tr) {
    st = mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
    goto done;
  }
  if (file < 0) {
    st = mrvi_fail(msg, len, MRVI_EIO, "%s: cannot open as an HDF5 file", path);
    goto done;
  }
  /* A whole trajectory: a completed run, or the replay of the controls of
   * an optimisation that stopped short (replay_stop_reason, written by
   * mrvi_ocp_output_close beside the optimisation's stop_reason). */
  char reason[256], replay[32] = "";
  mrvi_h5_stop_reason(file, path, reason, sizeof reason);
  if (mrvi_h5in_has_attr(&in, "replay_stop_reason"))
    mrvi_h5in_attr_string(&in, "replay_stop_reason", replay, sizeof replay);
  if (strcmp(reason, "completed") != 0 && strcmp(replay, "completed") != 0) {
    st = mrvi_fail(msg, len, MRVI_EIO,
                   "%s: the run did not complete (stop_reason: %s)", path,
                   reason[0] ? reason : "missing");
    goto done;
  }
  double dT = 0, p = 0;
  if ((st = mrvi_h5in_attr_number(&in, "macro_step", 0, HUGE_VAL, 0, &dT)) <
          0 ||
      (st = mrvi_h5in_attr_number(&in, "micro_steps", 1, INT_MAX, 1, &p)) < 0)
    goto done;
  if (!(dT > 0)) {
    st = mrvi_fail(msg, len, MRVI_EIO, "%s: attribute macro_step = %g", path,
                   dT);
    goto done;
  }
  tr->macro_step = dT;
  tr->micro_steps = (int)p;
  int n = 0;
  hsize_t rows = 0, dims[2];
  int *rate = NULL;
  if ((st = coordinates(&in, 0, &n, &rows)) < 0 ||
      (st = mrvi_h5in_read_new(&in, "/model/rate", H5T_NATIVE_INT, 1, NULL,
                               MRVI_H5_ANY, (void **)&rate, NULL)) < 0)
    goto done;
  for (int i = 0; i < n; i++)
    tr->n_fast += rate[i] != 0;
  free(rate);
  tr->n = n;
  tr->n_macro = (long)rows;
  const hsize_t macro[2] = {rows, (hsize_t)n};
  if ((st = mrvi_h5in_read_new(&in, "/macro/t", H5T_NATIVE_DOUBLE, 1, macro,
                               MRVI_H5_ANY, (void **)&tr->t, NULL)) < 0 ||
      (st = mrvi_h5in_read_new(&in, "/macro/q", H5T_NATIVE_DOUBLE, 2, macro,
                               MRVI_H5_ANY, (void **)&tr->q, NULL)) < 0 ||
      (st = mrvi_h5in_read_new(&in, "/macro/p", H5T_NATIVE_DOUBLE, 2, macro,
                               MRVI_H5_ANY, (void **)&tr->p, NULL)) < 0)
    goto done;
  /* The micro datasets are optional (output.micro: false); present, they
   * are (N p + 1) x n_fast each. */
  if (mrvi_h5in_exists(&in, "/micro/t") &&
      mrvi_h5in_exists(&in, "/micro/q_fast") &&
      mrvi_h5in_exists(&in, "/micro/p_fast")) {
    if ((st = mrvi_h5in_read_new(&in, "/micro/t", H5T_NATIVE_DOUBLE, 1, NULL,
                                 MRVI_H5_ANY, (void **)&tr->micro_t, dims)) < 0)
      goto done;
    const hsize_t micro[2] = {dims[0], (hsize_t)tr->n_fast};
    tr->n_micro = (long)dims[0];
    if ((st = mrvi_h5in_read_new(&in, "/micro/q_fast", H5T_NATIVE_DOUBLE, 2,
                                 micro, MRVI_H5_ANY, (void **)&tr->micro_q,
                                 NULL)) < 0 ||
        (st = mrvi_h5in_read_new(&in, "/micro/p_fast", H5T_NATIVE_DOUBLE, 2,
                                 micro, MRVI_H5_ANY, (void **)&tr->micro_p,
                                 NULL)) < 0)
      goto done;
  }
done:
  if (file >= 0)
    H5Fclose(file);
  mrvi_h5_quiet_end(&q);
  if (st < 0) {
    mrvi_trajectory_free(tr);
    return st;
  }
  *out = tr;
  return MRVI_OK;
}

/* Row `row` of the float64 dataset name, cols wide (rank 1 when cols = 0)
 * into buf (room for cols values, one for rank 1). */
static int read_row(const mrvi_h5in *in, const char *name, hsize_t row,
                    int cols, double *buf) {
  const hsize_t want[2] = {MRVI_H5_ANY, (hsize_t)cols};
  return mrvi_h5in_read(in, name, H5T_NATIVE_DOUBLE, cols > 0 ? 2 : 1, want,
                        row, 1, buf, cols > 0 ? (size_t)cols : 1);
}

/* node->torsion_angle <- row `row` of /macro/torsion_angle, when the file
 * has it (a model with torsional springs): rank 2, at most
 * max_coordinates() columns (its width against the model:
 * mrvi_stored_run_check, mrvi_run_from). */
static int read_torsion_row(const mrvi_h5in *in, hsize_t row,
                            mrvi_stored_node *node) {
  static const char name[] = "/macro/torsion_angle";
  if (!mrvi_h5in_exists(in, name))
    return MRVI_OK;
  hsize_t d[2];
  int st = mrvi_h5in_shape(in, name, MRVI_H5_NUMBER, 2, NULL, d);
  if (st < 0)
    return st;
  if (d[1] == 0 || d[1] > max_coordinates() ||
      (node->torsion_angle && d[1] != (hsize_t)node->n_torsion))
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: %s has %llu columns, expected 1 to %llu", in->path,
                     name, (unsigned long long)d[1],
                     (unsigned long long)max_coordinates());
  if (!node->torsion_angle) {
    node->n_torsion = (int)d[1];
    node->torsion_angle = calloc(d[1], sizeof *node->torsion_angle);
    if (!node->torsion_angle)
      return mrvi_fail(in->msg, in->len, MRVI_ENOMEM, "out of memory");
  }
  return read_row(in, name, row, node->n_torsion, node->torsion_angle);
}

/* Fill node from row `row` of /macro/t, q and p; the node index is
 * t / macro_step and must reproduce t exactly. */
static int read_node_row(const mrvi_h5in *in, hsize_t row,
                         mrvi_stored_node *node) {
  double t = 0;
  int st;
  if ((st = read_row(in, "/macro/t", row, 0, &t)) < 0 ||
      (st = read_row(in, "/macro/q", row, node->n, node->q)) < 0 ||
      (st = read_row(in, "/macro/p", row, node->n, node->p)) < 0 ||
      (st = read_torsion_row(in, row, node)) < 0)
    return st;
  const double kd = t / node->macro_step;
  const long k = (long)(kd >= -0.5 && kd < 9.0e15 ? kd + 0.5 : -1);
  if (k < 0 || (double)k * node->macro_step != t)
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: /macro/t[%llu] = %.17g is not a multiple of "
                     "macro_step %.17g",
                     in->path, (unsigned long long)row, t, node->macro_step);
  node->k = k;
  node->t = t;
  return MRVI_OK;
}

/* *finite <- 1 if row `row` of the numeric dataset name (rank 2 or 3) exists
 * and holds no NaN; 1 as well if the file has no such dataset. */
static int row_finite(const mrvi_h5in *in, const char *name, int rank,
                      hsize_t row, int *finite) {
  *finite = 1;
  if (!mrvi_h5in_exists(in, name))
    return MRVI_OK;
  hsize_t any[MRVI_H5_MAX_RANK] = {MRVI_H5_ANY, MRVI_H5_ANY, MRVI_H5_ANY,
                                   MRVI_H5_ANY};
  hsize_t dims[MRVI_H5_MAX_RANK] = {1, 1, 1, 1};
  int st = mrvi_h5in_shape(in, name, MRVI_H5_NUMBER, rank, any, dims);
  if (st < 0)
    return st;
  hsize_t cols = 1;
  for (int i = 1; i < rank; i++)
    cols =
        dims[i] <= max_coordinates() ? cols * dims[i] : max_coordinates() + 1;
  if (cols == 0 || cols > max_coordinates())
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: %s has rows of %llu entries, expected 1 to %llu",
                     in->path, name, (unsigned long long)cols,
                     (unsigned long long)max_coordinates());
  if (row >= dims[0]) { /* rows past its end have no values */
    *finite = 0;
    return MRVI_OK;
  }
  double *v = malloc((size_t)cols * sizeof *v);
  if (!v)
    return mrvi_fail(in->msg, in->len, MRVI_ENOMEM, "out of memory");
  dims[0] = MRVI_H5_ANY;
  st = mrvi_h5in_read(in, name, H5T_NATIVE_DOUBLE, rank, dims, row, 1, v,
                      (size_t)cols);
  for (hsize_t i = 0; i < cols && st == MRVI_OK && *finite; i++)
    *finite = v[i] == v[i];
  free(v);
  if (st != MRVI_OK)
    *finite = 0;
  return MRVI_OK;
}

/* Resume: the row of the last kept node within steps_completed whose
 * multipliers arrived (the next step reports them; its projection impulse
 * cannot be recomputed, so a node without them is not resumed from).  The
 * joint reactions computed from them are written in the same flush, but a
 * killed writer may leave some of those rows on disk and not others, so
 * every one of them must be there. */
static int resume_row(const mrvi_h5in *in, long K, long e, hsize_t rows,
                      hsize_t *row) {
  if ((hsize_t)(K / e) >= rows)
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: steps_completed = %ld but /macro/t has %llu rows",
                     in->path, K, (unsigned long long)rows);
  *row = (hsize_t)(K / e);
  static const struct {
    const char *name;
    int rank;
  } from_lambda[] = {
      {"/macro/lambda", 2}, {"/joints/force", 3}, {"/joints/torque", 3}};
  for (; *row > 0; --*row) {
    int finite = 1;
    for (size_t i = 0; i < sizeof from_lambda / sizeof *from_lambda && finite;
         i++) {
      const int st = row_finite(in, from_lambda[i].name, from_lambda[i].rank,
                                *row, &finite);
      if (st < 0)
        return st;
    }
    if (finite)
      break;
  }
  mrvi_fmt(in->msg, in->len, "%s", "");
  return MRVI_OK;
}

static int stored_node_read(const mrvi_h5in *in, long which, int n,
                            mrvi_stored_node *node) {
  /* An extension reads the node a resume would, of a completed run. */
  const int extend = which == MRVI_NODE_EXTEND;
  if (extend)
    which = MRVI_NODE_RESUME;
  const char *path = in->path;
  char *msg = in->msg;
  const size_t len = in->len;
  if (!mrvi_h5in_has_attr(in, "mrvi_version"))
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: not an mrvi output (no root attribute "
                     "mrvi_version)",
                     path);
  if (which == MRVI_NODE_RESUME && mrvi_h5in_has_attr(in, "stop_reason")) {
    int st = mrvi_h5in_attr_string(in, "stop_reason", node->stop_reason,
                                   sizeof node->stop_reason);
    if (st < 0)
      return st;
  }
  mrvi_h5_stop_reason(in->file, path, node->stop_reason,
                      sizeof node->stop_reason);
  if (which == MRVI_NODE_RESUME && mrvi_h5in_exists(in, "/control"))
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: written by mrvi optimize or run --controls; "
                     "resuming a controlled run is not supported",
                     path);
  if (extend && strcmp(node->stop_reason, "completed") != 0)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: the run did not complete (stop_reason: %s); resume "
                     "it first (mrvi run --resume %s), then extend it",
                     path, node->stop_reason, path);
  if (!extend && which == MRVI_NODE_RESUME &&
      !strcmp(node->stop_reason, "completed"))
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: the run completed; nothing to resume (to go on "
                     "past t_end: mrvi run --resume %s --set "
                     "integrator.t_end=LATER, in place; or a new file: mrvi "
                     "run FILE --from %s -o NEW.h5)",
                     path, path, path);
  if (which == MRVI_NODE_RESUME && !strcmp(node->stop_reason, "running"))
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: the file is in use by another run (locked); not "
                     "touched",
                     path);
  /* Counts below 2^53: exact as doubles. */
  double every = 1, steps = 0;
  int st;
  if ((st = mrvi_h5in_attr_number(in, "macro_step", 0, HUGE_VAL, 0,
                                  &node->macro_step)) < 0 ||
      (st = mrvi_h5in_attr_number(in, "steps_completed", 0, 0x1p53, 1,
                                  &steps)) < 0 ||
      (st = mrvi_h5in_attr_number(in, "output_every", 1, INT_MAX, 1, &every)) <
          0)
    return st;
  if (!(node->macro_step > 0) || isinf(node->macro_step))
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: attribute macro_step = %g, expected > 0", path,
                     node->macro_step);
  const long K = (long)steps;
  node->every = (int)every;
  node->steps_completed = K;
  char **text = NULL;
  if ((st = mrvi_h5in_strings(in, "/model/description", 0, 1, MRVI_H5_MAX_TEXT,
                              &text)) < 0)
    return st;
  node->description = text[0];
  free(text);
  hsize_t rows = 0, dt[1];
  if ((st = coordinates(in, n, &node->n, NULL)) < 0 ||
      (st = mrvi_h5in_shape(in, "/macro/t", MRVI_H5_NUMBER, 1, NULL, dt)) < 0)
    return st;
  rows = dt[0];
  if (rows == 0 && which != MRVI_NODE_RESUME)
    return mrvi_fail(msg, len, MRVI_EIO, "%s: /macro/t is empty", path);
  node->q = calloc((size_t)node->n, sizeof *node->q);
  node->p = calloc((size_t)node->n, sizeof *node->p);
  if (!node->q || !node->p)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  if (rows == 0)
    return MRVI_OK; /* killed before its first row: resume from node 0 */
  const long e = node->every;
  if (which == MRVI_NODE_LAST)
    return read_node_row(in, rows - 1, node);
  if (which >= 0) {
    if ((st = read_node_row(in, rows - 1, node)) < 0)
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
    return read_node_row(in, row, node);
  }
  hsize_t row = 0;
  if ((st = resume_row(in, K, e, rows, &row)) < 0 ||
      (st = read_node_row(in, row, node)) < 0)
    return st;
  if (node->k != (long)row * e)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: /macro/t[%llu] is node %ld, expected %ld", path,
                     (unsigned long long)row, node->k, (long)row * e);
  return MRVI_OK;
}

/* node->energy: H_0 and T_0 + |V_0| + |W_0| from row 0, the running energy
 * error of node k from its row (k / every). */
static int read_node_energy(const mrvi_h5in *in, mrvi_stored_node *node) {
  double e[3] = {0};
  const hsize_t row = (hsize_t)(node->k / (node->every > 0 ? node->every : 1));
  int st;
  if ((st = read_row(in, "/macro/energy", 0, 0, &node->energy[0])) < 0 ||
      (st = read_row(in, "/macro/kinetic", 0, 0, &e[0])) < 0 ||
      (st = read_row(in, "/macro/potential_slow", 0, 0, &e[1])) < 0 ||
      (st = read_row(in, "/macro/potential_fast", 0, 0, &e[2])) < 0 ||
      (st = read_row(in, "/macro/energy_running", row, 2, &node->energy[2])) <
          0) {
    char why[512];
    mrvi_fmt(why, sizeof why, "%s", in->msg);
    return mrvi_fail(in->msg, in->len, st,
                     "%s (the energies of rows 0 and %llu; a file of an "
                     "earlier mrvi cannot be resumed)",
                     why, (unsigned long long)row);
  }
  node->energy[1] = fabs(e[0]) + fabs(e[1]) + fabs(e[2]);
  return MRVI_OK;
}

/* node->chord_history <- /resume/chord_history (tuning.chord_carry: the
 * rows' history the step after the stored node takes, hdf5_writer.c),
 * where the file has it for node->k: [k, n, then 5 n entries] with n 0 or
 * the fast coordinates (at most node->n); checked (rank, size, k and n
 * whole numbers, finite entries) before use. */
static int read_node_chord(const mrvi_h5in *in, mrvi_stored_node *node) {
  static const char name[] = "/resume/chord_history";
  if (!mrvi_h5in_exists(in, name))
    return MRVI_OK;
  const hsize_t most = 2 + 5 * (hsize_t)node->n;
  double *h = NULL;
  hsize_t d[1] = {0};
  int st = mrvi_h5in_shape(in, name, MRVI_H5_NUMBER, 1, NULL, d);
  if (st == MRVI_OK && (d[0] < 2 || d[0] > most))
    st = mrvi_fail(in->msg, in->len, MRVI_EIO,
                   "%s: %s has %llu entries (2 to %llu for %d coordinates)",
                   in->path, name, (unsigned long long)d[0],
                   (unsigned long long)most, node->n);
  if (st == MRVI_OK)
    st = mrvi_h5in_read_new(in, name, H5T_NATIVE_DOUBLE, 1, d, MRVI_H5_ANY,
                            (void **)&h, NULL);
  if (st < 0)
    return st;
  const double k = h[0], nc = h[1];
  int bad =
      !(k >= 0.0 && k < 9.0e15 && k == floor(k) && nc >= 0.0 && nc <= node->n &&
        nc == floor(nc) && (nc == 0.0 || 2 + 5 * (hsize_t)nc == d[0]));
  for (hsize_t i = 2; !bad && nc > 0.0 && i < d[0]; i++)
    bad = !isfinite(h[i]);
  if (bad) {
    free(h);
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: %s is not a node's chord history (node %.17g, "
                     "%.17g entries per part, %llu in all, or a non-finite "
                     "entry)",
                     in->path, name, k, nc, (unsigned long long)d[0]);
  }
  /* The history of another node (a writer killed between the rows and
   * their history) is not this node's: none, the run then continues
   * within the tolerance. */
  if ((long)k != node->k || nc == 0.0) {
    free(h);
    return MRVI_OK;
  }
  memmove(h, h + 2, (size_t)(d[0] - 2) * sizeof *h);
  node->n_chord = (int)nc;
  node->chord_history = h;
  return MRVI_OK;
}

int mrvi_stored_node_read(const char *path, long which, int n,
                          mrvi_stored_node **out, char *msg, size_t len) {
  *out = NULL;
  mrvi_fmt(msg, len, "%s", "");
  mrvi_h5_quiet q;
  mrvi_h5_quiet_begin(&q);
  mrvi_stored_node *node = calloc(1, sizeof *node);
  const int live = mrvi_h5_held(path);
  hid_t f =
      node && !live ? mrvi_h5_open_read(path, H5P_DEFAULT) : H5I_INVALID_HID;
  const mrvi_h5in in = {f, path, msg, len};
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
    st = stored_node_read(&in, which, n, node);
  if (st == MRVI_OK &&
      (which == MRVI_NODE_RESUME || which == MRVI_NODE_EXTEND) && node->k > 0)
    st = read_node_energy(&in, node);
  if (st == MRVI_OK &&
      (which == MRVI_NODE_RESUME || which == MRVI_NODE_EXTEND) && node->k > 0)
    st = read_node_chord(&in, node);
  if (f >= 0)
    H5Fclose(f);
  mrvi_h5_quiet_end(&q);
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
  free(node->torsion_angle);
  free(node->chord_history);
  free(node->description);
  free(node);
}

/* ---------------------------------------------------------------------------
 * A run file against its own description (issue: a file whose attributes or
 * data say another run than /model/description must not be continued)
 * ------------------------------------------------------------------------- */

/* The root attribute name against the number `want`: MRVI_OK when equal
 * (bitwise for doubles written by the writer), else the disagreement. */
static int same_number(const mrvi_h5in *in, const char *name, double want) {
  double v = 0;
  const int st = mrvi_h5in_attr_number(in, name, -HUGE_VAL, HUGE_VAL, 0, &v);
  if (st < 0)
    return st;
  if (v != want)
    return mrvi_fail(in->msg, in->len, MRVI_EINVAL,
                     "%s: attribute %s = %.17g but /model/description says "
                     "%.17g",
                     in->path, name, v, want);
  return MRVI_OK;
}

static int same_string(const mrvi_h5in *in, const char *name,
                       const char *want) {
  char v[256];
  const int st = mrvi_h5in_attr_string(in, name, v, sizeof v);
  if (st < 0)
    return st;
  if (strcmp(v, want) != 0)
    return mrvi_fail(in->msg, in->len, MRVI_EINVAL,
                     "%s: attribute %s = '%s' but /model/description says "
                     "'%s'",
                     in->path, name, v, want);
  return MRVI_OK;
}

/* /model/particle_name and /model/particle_column against the model's
 * particles (mrvi export names and places the particles by them; a run
 * continued from a file whose particles say another model than its
 * description would export under names and columns not the run's). */
static int same_particles(const mrvi_h5in *in, const mrvi_model *m) {
  const int np = mrvi_model_n_particles(m);
  const hsize_t dn = (hsize_t)np;
  int *column = NULL, st;
  char **name = NULL;
  /* (a model without particles: the writer leaves both out) */
  if (np == 0 && !mrvi_h5in_exists(in, "/model/particle_column") &&
      !mrvi_h5in_exists(in, "/model/particle_name"))
    return MRVI_OK;
  if ((st = mrvi_h5in_read_new(in, "/model/particle_column", H5T_NATIVE_INT, 1,
                               &dn, MRVI_H5_ANY, (void **)&column, NULL)) < 0 ||
      (st = mrvi_h5in_strings(in, "/model/particle_name", 1, dn,
                              MRVI_H5_MAX_ATTR, &name)) < 0) {
    free(column);
    return st;
  }
  for (int i = 0; i < np && st == MRVI_OK; i++) {
    char buf[MRVI_NAME_MAX];
    const char *want = mrvi_model_particle_name(m, i, buf);
    if (strcmp(name[i], want) != 0)
      st = mrvi_fail(in->msg, in->len, MRVI_EINVAL,
                     "%s: /model/particle_name[%d] = '%s' but "
                     "/model/description names particle %d '%s'",
                     in->path, i, name[i], i, want);
    else if (column[i] != mrvi_particle_first(m, i))
      st = mrvi_fail(in->msg, in->len, MRVI_EINVAL,
                     "%s: /model/particle_column[%d] = %d but "
                     "/model/description puts particle '%s' at column %d",
                     in->path, i, column[i], want, mrvi_particle_first(m, i));
  }
  free(column);
  mrvi_h5_strings_free(name, (size_t)np);
  return st;
}

/* /model/rate and /model/name against the model, /macro/lambda's width
 * against its constraint rows, its particles (same_particles). */
static int same_coordinates(const mrvi_h5in *in, const mrvi_model *m) {
  const int n = mrvi_model_n(m);
  int nq = 0, st;
  if ((st = coordinates(in, 0, &nq, NULL)) < 0)
    return st;
  if (nq != n)
    return mrvi_fail(in->msg, in->len, MRVI_EINVAL,
                     "%s: /macro/q has %d coordinates but the model of "
                     "/model/description %d",
                     in->path, nq, n);
  int *rate = NULL;
  char **name = NULL;
  const hsize_t dn = (hsize_t)n;
  if ((st = mrvi_h5in_read_new(in, "/model/rate", H5T_NATIVE_INT, 1, &dn,
                               MRVI_H5_ANY, (void **)&rate, NULL)) < 0 ||
      (st = mrvi_h5in_strings(in, "/model/name", 1, dn, MRVI_H5_MAX_ATTR,
                              &name)) < 0) {
    free(rate);
    return st;
  }
  for (int i = 0; i < n && st == MRVI_OK; i++) {
    char buf[MRVI_NAME_MAX];
    const char *want = mrvi_model_coordinate_name(m, i, buf);
    const int fast = mrvi_model_rate(m, i) == MRVI_FAST;
    if (strcmp(name[i], want ? want : "") != 0)
      st = mrvi_fail(in->msg, in->len, MRVI_EINVAL,
                     "%s: /model/name[%d] = '%s' but /model/description "
                     "names coordinate %d '%s'",
                     in->path, i, name[i], i, want ? want : "");
    else if (rate[i] != fast)
      st = mrvi_fail(in->msg, in->len, MRVI_EINVAL,
                     "%s: /model/rate[%d] = %d but /model/description makes "
                     "'%s' %s",
                     in->path, i, rate[i], name[i], fast ? "fast" : "slow");
  }
  free(rate);
  mrvi_h5_strings_free(name, (size_t)n);
  if (st < 0 || (st = same_particles(in, m)) < 0)
    return st;
  const int nt = mrvi_model_n_torsions(m);
  hsize_t dt[2] = {0, 0};
  const int has_t = mrvi_h5in_exists(in, "/macro/torsion_angle");
  if (has_t && (st = mrvi_h5in_shape(in, "/macro/torsion_angle", MRVI_H5_NUMBER,
                                     2, NULL, dt)) < 0)
    return st;
  if (dt[1] != (hsize_t)nt)
    return mrvi_fail(in->msg, in->len, MRVI_EINVAL,
                     "%s: /macro/torsion_angle has %llu columns%s but the "
                     "model of /model/description %d torsional springs%s",
                     in->path, (unsigned long long)dt[1],
                     has_t ? "" : " (no such dataset)", nt,
                     has_t ? ""
                           : " (a file of an earlier mrvi: its springs' "
                             "winding is not stored)");
  const int rows = mrvi_model_constraint_rows(m);
  hsize_t dl[2];
  if (mrvi_h5in_exists(in, "/macro/lambda") &&
      ((st = mrvi_h5in_shape(in, "/macro/lambda", MRVI_H5_NUMBER, 2, NULL,
                             dl)) < 0 ||
       dl[1] != (hsize_t)rows))
    return st < 0 ? st
                  : mrvi_fail(in->msg, in->len, MRVI_EINVAL,
                              "%s: /macro/lambda has %llu columns but the "
                              "model of /model/description %d constraint rows",
                              in->path, (unsigned long long)dl[1], rows);
  return MRVI_OK;
}

int mrvi_stored_run_check(const char *path, const mrvi_system *sys, char *msg,
                          size_t len) {
  mrvi_h5_quiet q;
  mrvi_h5_quiet_begin(&q);
  hid_t f = mrvi_h5_open_read(path, H5P_DEFAULT);
  const mrvi_h5in in = {f, path, msg, len};
  const mrvi_settings *s = &sys->settings;
  const mrvi_writer_options o = mrvi_system_writer_options(sys);
  char scheme[sizeof s->scheme + 1];
  mrvi_fmt(scheme, sizeof scheme, "%.*s", (int)sizeof s->scheme, s->scheme);
  int st;
  if (f < 0)
    st = mrvi_fail(msg, len, MRVI_EIO, "%s: cannot open as an HDF5 file", path);
  else if ((st = same_number(&in, "macro_step", s->macro_step)) == MRVI_OK &&
           (st = same_number(&in, "micro_steps", s->micro_steps)) == MRVI_OK &&
           (st = same_number(&in, "output_every", o.every)) == MRVI_OK &&
           (st = same_number(&in, "t_end", s->t_end)) == MRVI_OK &&
           (st = same_string(&in, "scheme", scheme)) == MRVI_OK &&
           (st = same_number(&in, "alpha_slow", s->slow.alpha)) == MRVI_OK &&
           (st = same_number(&in, "gamma_slow", s->slow.gamma)) == MRVI_OK &&
           (st = same_number(&in, "alpha_fast", s->fast.alpha)) == MRVI_OK &&
           (st = same_number(&in, "gamma_fast", s->fast.gamma)) == MRVI_OK &&
           (st = same_string(&in, "slow_grid",
                             s->slow_grid == MRVI_GRID_MACRO ? "macro"
                                                             : "micro")) ==
               MRVI_OK)
    st = same_coordinates(&in, sys->model);
  if (f >= 0)
    H5Fclose(f);
  mrvi_h5_quiet_end(&q);
  return st;
}
