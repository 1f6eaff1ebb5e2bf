/* HDF5 output (doc/output.md).
 *
 * The writer is an mrvi_observer.  Each record adds rows to three streams of
 * datasets (macro nodes, fast micro nodes, solver statistics); rows are
 * buffered in memory and appended with hyperslab writes to chunked datasets
 * whose first dimension is unlimited.  The file is set up under a temporary
 * name, switched to SWMR writing (every object exists by then) and renamed
 * to the output path; SWMR's ordered metadata flushes keep it consistent on
 * disk at every instant.  After every buffer write the file is flushed
 * (H5Fflush) twice, rows first and steps_completed (rewritten in place)
 * after them, so a process killed hard leaves a readable file with
 * everything written up to the last flush and a counter that never exceeds
 * the rows (flush); a run stopped by an error or by the stop flag reaches
 * mrvi_writer_close, which writes the rest and, last, the reason it stopped
 * (stop_reason "running" thus marks a run that never closed).
 *
 * The library never prints: HDF5's automatic error printer is switched off
 * around every HDF5 call we make (and restored after), and the error stack
 * is turned into a message instead. */
#define _GNU_SOURCE /* copy_file_range */
#include "io/h5util.h"
#include "io/io.h"

#include <hdf5.h>

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <errno.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <unistd.h>

/* Flush after this many records, or after this much wall time, whichever
 * comes first; fewer records when their rows would exceed BUFFER_BYTES. */
#define FLUSH_RECORDS 256
#define FLUSH_SECONDS 2.0 /* default of output.flush_interval */
#define BUFFER_BYTES ((size_t)8 << 20)
/* Target size of one chunk (never more rows than the run will write). */
#define CHUNK_BYTES ((size_t)64 << 10)

/* ---------------------------------------------------------------------------
 * Output table
 * ------------------------------------------------------------------------- */

/* Row streams: how many rows one record adds to a dataset. */
enum stream {
  MACRO,  /* 1 per kept macro node: k % every == 0, and the last one seen */
  MICRO,  /* micro_count per record: fast micro nodes (if output.micro) */
  SOLVER, /* 1 per step: records with k >= 1 */
  N_STREAMS
};

enum elem { F64, I32 };

/* Every appended dataset, listed once; doc/output.md mirrors this table.
 *   X(id, path, type, stream, rank, columns, row, long_name)
 * columns: row width as a function of the writer w; 0 omits the dataset.
 * row:     address of row i of record r (i < rows r adds to the stream).
 * rank 1:  shape (rows) and columns must be 1; rank 2: (rows, columns);
 *          rank 3 and 4: (rows, columns / d^(rank-2), d [, d]), d the
 *          model's dimension (output_shape).
 * long_name is also stored as the dataset attribute `long_name`.
 * The constraint datasets exist only for a model with constraints
 * (n_lambda rows of g).  The multipliers of a node come with the next
 * record (lambda_prev), so /macro/lambda is written as a NaN placeholder and
 * filled in when they arrive (fill_lambda); the last node keeps the NaN. */
#define MRVI_OUTPUT_LIST(X)                                                    \
  X(MACRO_T, "/macro/t", F64, MACRO, 1, 1, &r->t, "time t_k of macro node k")  \
  X(MACRO_Q, "/macro/q", F64, MACRO, 2, w->n, r->q,                            \
    "generalised coordinates q_k, model order")                                \
  X(MACRO_P, "/macro/p", F64, MACRO, 2, w->n, r->p,                            \
    "discrete momenta p_k, model order")                                       \
  X(MACRO_KINETIC, "/macro/kinetic", F64, MACRO, 1, 1, &r->kinetic,            \
    "kinetic energy 1/2 p^T M^-1 p")                                           \
  X(MACRO_POTENTIAL_SLOW, "/macro/potential_slow", F64, MACRO, 1, 1,           \
    &r->potential_slow, "slow potential V(q)")                                 \
  X(MACRO_POTENTIAL_FAST, "/macro/potential_fast", F64, MACRO, 1, 1,           \
    &r->potential_fast, "fast potential W(q)")                                 \
  X(MACRO_ENERGY, "/macro/energy", F64, MACRO, 1, 1, &r->energy,               \
    "total energy H = kinetic + V + W")                                        \
  X(MACRO_ENERGY_RUNNING, "/macro/energy_running", F64, MACRO, 2, 2,           \
    r->energy_running,                                                         \
    "max |H_j - H_0| and max T_j + |V_j| + |W_j| over all nodes j <= k")       \
  X(MACRO_TORSION_ANGLE, "/macro/torsion_angle", F64, MACRO, 2, w->n_torsion,  \
    r->torsion_angle,                                                          \
    "branch of each torsional spring: its unwrapped angle at macro node k")    \
  X(MACRO_LINEAR_MOMENTUM, "/macro/linear_momentum", F64, MACRO, 2, w->dim,    \
    r->linear_momentum, "linear momentum sum_i p_i of the particles")          \
  X(MACRO_ANGULAR_MOMENTUM, "/macro/angular_momentum", F64, MACRO, 2,          \
    w->n_ang, r->angular_momentum,                                             \
    "angular momentum sum_i x_i x p_i of the particles plus, of each body, "   \
    "phi x p_phi + sum_i d_i x p_{d_i}")                                       \
  X(MACRO_CONSTRAINT_RESIDUAL, "/macro/constraint_residual", F64, MACRO, 1,    \
    w->n_lambda > 0, &r->constraint_residual,                                  \
    "max |g| over the nodes completed at macro node k")                        \
  X(MACRO_HIDDEN_CONSTRAINT_RESIDUAL, "/macro/hidden_constraint_residual",     \
    F64, MACRO, 1, w->n_lambda > 0, &r->hidden_constraint_residual,            \
    "max |G M^-1 p| at macro node k")                                          \
  X(MACRO_LAMBDA, "/macro/lambda", F64, MACRO, 2, w->n_lambda, w->nan_row,     \
    "constraint multipliers at macro node k (NaN at the last node)")           \
  X(BODIES_POSITION, "/bodies/position", F64, MACRO, 3, w->nb * w->dim,        \
    w->body_rows, "centre of mass phi of each rigid body at macro node k")     \
  X(BODIES_ROTATION, "/bodies/rotation", F64, MACRO, 4,                        \
    w->nb * w->dim * w->dim, w->body_rows + (size_t)w->nb * (size_t)w->dim,    \
    "rotation matrix of each rigid body at macro node k: its columns are "     \
    "the directors d_1 .. d_D in space")                                       \
  X(BODIES_ANGULAR_VELOCITY, "/bodies/angular_velocity", F64, MACRO, 3,        \
    w->nb * w->n_ang, w->body_omega,                                           \
    "angular velocity in space of each rigid body at macro node k, "           \
    "(R J R^T)^-1 sum_i d_i x p_{d_i}")                                        \
  X(JOINTS_POSITION, "/joints/position", F64, MACRO, 3, w->nj * w->dim,        \
    w->joint_point, "point of each joint on its first body at macro node k")   \
  X(JOINTS_FORCE, "/joints/force", F64, MACRO, 3, w->nj * w->dim, w->nan_row,  \
    "force of each joint on its first body at macro node k, from the "         \
    "multipliers (NaN at the last node)")                                      \
  X(JOINTS_TORQUE, "/joints/torque", F64, MACRO, 3, w->nj * w->n_ang,          \
    w->nan_row,                                                                \
    "torque of each joint on its first body about the joint's point at "       \
    "macro node k, from the multipliers (NaN at the last node)")               \
  X(MICRO_T, "/micro/t", F64, MICRO, 1, 1, &w->micro_t[i],                     \
    "time of the fast micro node")                                             \
  X(MICRO_Q_FAST, "/micro/q_fast", F64, MICRO, 2, w->nf,                       \
    r->micro_q_fast + (size_t)i * (size_t)w->nf,                               \
    "fast coordinates at the micro node, model order")                         \
  X(MICRO_Q_SLOW, "/micro/q_slow", F64, MICRO, 2, w->micro_slow ? w->ns : 0,   \
    w->slow_rows + (size_t)i * (size_t)w->ns,                                  \
    "slow coordinates at the micro node, linear between macro nodes "          \
    "(output.micro_slow)")                                                     \
  X(MICRO_P_FAST, "/micro/p_fast", F64, MICRO, 2, w->nf,                       \
    r->micro_p_fast + (size_t)i * (size_t)w->nf,                               \
    "fast micro momenta (eq:pkfm-), model order")                              \
  X(MICRO_BODIES_POSITION, "/micro/bodies/position", F64, MICRO, 3,            \
    w->nfb * w->dim, w->micro_body_rows + (size_t)i * w->micro_body_width,     \
    "centre of mass of each fast rigid body at the micro node")                \
  X(MICRO_BODIES_ROTATION, "/micro/bodies/rotation", F64, MICRO, 4,            \
    w->nfb * w->dim * w->dim,                                                  \
    w->micro_body_rows + (size_t)i * w->micro_body_width +                     \
        (size_t)(w->nfb * w->dim),                                             \
    "rotation matrix of each fast rigid body at the micro node")               \
  X(MICRO_BODIES_ANGULAR_VELOCITY, "/micro/bodies/angular_velocity", F64,      \
    MICRO, 3, w->nfb * w->n_ang,                                               \
    w->micro_body_rows + (size_t)i * w->micro_body_width +                     \
        (size_t)(w->nfb * (w->dim + w->dim * w->dim)),                         \
    "angular velocity in space of each fast rigid body at the micro node")     \
  X(MICRO_CONSTRAINT_RESIDUAL, "/micro/constraint_residual", F64, MICRO, 1,    \
    w->n_lambda > 0, r->micro_constraint_residual + i,                         \
    "max |g| at the micro node")                                               \
  X(SOLVER_ITERATIONS, "/solver/iterations", I32, SOLVER, 1, 1,                \
    &r->iterations, "Newton iterations of macro step k-1 -> k")                \
  X(SOLVER_RESIDUAL, "/solver/residual", F64, SOLVER, 1, 1, &r->residual,      \
    "final max-norm residual of that step")

/* clang-format off */
enum output_id {
#define X_ENUM(id, ...) id,
  MRVI_OUTPUT_LIST(X_ENUM)
#undef X_ENUM
  N_OUTPUTS
};
/* clang-format on */

static const struct output_info {
  const char *path;
  enum elem type;
  enum stream stream;
  int rank;
  const char *long_name;
} output_info[N_OUTPUTS] = {
#define X_INFO(id, path, type, stream, rank, cols, row, long_name)             \
  {path, type, stream, rank, long_name},
    MRVI_OUTPUT_LIST(X_INFO)
#undef X_INFO
};

/* The macro datasets whose row of node k comes with record k+1: the
 * multipliers and the joint reactions computed from them (fill_lambda). */
static const int lambda_outputs[] = {MACRO_LAMBDA, JOINTS_FORCE, JOINTS_TORQUE};
#define N_LAMBDA_OUTPUTS                                                       \
  ((int)(sizeof lambda_outputs / sizeof lambda_outputs[0]))

/* Root attributes written at open, listed once; doc/output.md mirrors it.
 *   X(name, kind, value, present), kind: string, double, int or long.
 * Values may use the settings s, the writer w and the strings `system_name`,
 * `scheme` of mrvi_writer_open; an attribute is written when `present` is
 * true.  stop_reason and steps_completed are rewritten at every flush and at
 * close. */
#define MRVI_ATTRIBUTE_LIST(X)                                                 \
  X("mrvi_version", string, MRVI_VERSION, 1)                                   \
  X("system", string, system_name, 1)                                          \
  X("scheme", string, scheme, 1)                                               \
  X("alpha_slow", double, s->slow.alpha, 1)                                    \
  X("gamma_slow", double, s->slow.gamma, 1)                                    \
  X("slow_grid", string, s->slow_grid == MRVI_GRID_MACRO ? "macro" : "micro",  \
    1)                                                                         \
  X("alpha_fast", double, s->fast.alpha, 1)                                    \
  X("gamma_fast", double, s->fast.gamma, 1)                                    \
  X("macro_step", double, s->macro_step, 1)                                    \
  X("micro_steps", int, s->micro_steps, 1)                                     \
  X("t_end", double, s->t_end, 1)                                              \
  X("newton_tolerance", double, s->newton_tol, 1)                              \
  X("newton_max_iterations", int, s->newton_max_iter, 1)                       \
  X("newton_criterion", string, "scaled",                                      \
    s->newton_criterion == MRVI_CRITERION_SCALED)                              \
  X("constraint_form", string,                                                 \
    s->constraint_form == MRVI_FORM_NULL_SPACE ? "null-space" : "multipliers", \
    w->n_lambda > 0)                                                           \
  X("constraint_tolerance", double, s->constraint_tol, w->n_lambda > 0)        \
  X("project_momenta", int, s->project_momenta, w->n_lambda > 0)               \
  X("solver", string, solver_path, 1)                                          \
  X("output_every", int, w->every, 1)                                          \
  X("stop_reason", fixed_string, "running", 1)                                 \
  X("steps_completed", long, 0L, 1)

/* ---------------------------------------------------------------------------
 * Writer
 * ------------------------------------------------------------------------- */
typedef struct output {
  hid_t id;           /* H5I_INVALID_HID when the dataset is omitted */
  hsize_t cols;       /* row width */
  size_t row_bytes;   /* cols x element size */
  unsigned char *buf; /* cap[stream] rows */
} output;

struct mrvi_writer {
  char *path;
  int have_summary;      /* mrvi_writer_set_summary was called */
  mrvi_summary energy;   /* its energy error and warning */
  double energy_warning; /* settings.energy_warning */
  hid_t file;
  int n, nf, ns, dim, n_ang, p, every;
  int micro_slow;     /* write /micro/q_slow (ns > 0, micro output on) */
  int *slow_col;      /* ns: model index of each slow coordinate */
  double *prev_slow;  /* ns: slow coordinates of the previous record */
  double *slow_rows;  /* p x ns: /micro/q_slow rows of the current record */
  int n_lambda;       /* constraint rows (0: no constraint outputs) */
  int n_torsion;      /* torsional springs (0: no /macro/torsion_angle) */
  int nb;             /* rigid bodies (0: no /bodies datasets) */
  int *body_first;    /* nb: model index of each body's first coordinate */
  double *body_rows;  /* nb d positions, then nb d^2 rotations (row-major) */
  double *body_omega; /* nb n_ang: angular velocities */
  /* Derived body and joint outputs read the model at every record (it
   * outlives the writer, mrvi_writer_open). */
  const mrvi_model *model;
  int nj;                  /* joints (0: no /joints datasets) */
  double *joint_rows;      /* nj d forces, then nj n_ang torques */
  double *joint_point;     /* nj d: joint points of the current record */
  double *lambda_q;        /* n: q of the last record (its multipliers come
                              with the next one: fill_lambda) */
  int nfb;                 /* fast bodies with micro output (/micro/bodies) */
  int *fast_body;          /* nfb: body index of each */
  int *fast_slot;          /* nfb: column of /micro/q_fast of its phi_x */
  size_t micro_body_width; /* nfb (d + d^2 + n_ang): one micro node */
  double *micro_body_rows; /* p micro nodes of micro_body_width */
  double *scratch;         /* 2 n: q and p of a fast body in model order */
  int stream_on[N_STREAMS];
  long flush_records;         /* records per flush (<= FLUSH_RECORDS) */
  size_t cap[N_STREAMS];      /* buffer capacity in rows */
  size_t rows[N_STREAMS];     /* rows buffered */
  hsize_t written[N_STREAMS]; /* rows in the file */
  int pending;       /* the macro row at rows[MACRO] is the last record seen but
                        not kept by `every`; the next record overwrites it and
                        close keeps it */
  long records;      /* records buffered since the last flush */
  double flushed_at; /* mrvi_clock() at the last flush */
  double flush_interval; /* seconds between flushes (output.flush_interval) */
  long flushed_k;        /* steps_completed in the file */
  int new_file;          /* lock_and_check created the file */
  char *part_path;       /* the file while it is set up (writer_setup) */
  int lock_fd;           /* holds mrvi_h5_lock_fd's lock, -1 when none */
  int extend;            /* resume a completed run to a later t_end */
  long fail_after;       /* MRVI_TEST_WRITE_FAIL_AFTER: fail the first flush
                            after this many records (testing), -1: never */
  long last_k;           /* k of the last record, -1 before the first */
  int resume;            /* appending: the first record is in the file */
  int keep_lambda;       /* appending: the multipliers of the last row in the
                            file are final (resume_point) */
  double *micro_t;       /* p: times of the micro rows of a record */
  double *nan_row;       /* n_lambda NaNs: the /macro/lambda placeholder */
  double *lambda_patch;  /* n_lambda: multipliers of the last row in the file */
  int patch;             /* lambda_patch waits for the next flush */
  /* tuning.chord_carry: /resume/chord_history, the rows' history the step
   * after the last stored macro node takes ([k, n, 5 n entries],
   * chord_len in all; 0: none), rewritten with the rows at each flush, so
   * that a resumed run continues bit for bit (mrvi_stored_node_read). */
  hid_t chord_id;
  hsize_t chord_len;
  double *chord_buf;
  int chord_dirty; /* chord_buf holds a node the file lacks */
  int status;      /* first failure (0 if none) */
  int io_failed;   /* a write failed: the file is not touched again */
  char errmsg[512];
  output out[N_OUTPUTS];
};

/* Width of dataset id for writer w. */
static hsize_t output_columns(const mrvi_writer *w, int id) {
  switch (id) {
#define X_COLS(id_, path, type, stream, rank, cols, row, long_name)            \
  case id_:                                                                    \
    return (hsize_t)(cols);
    MRVI_OUTPUT_LIST(X_COLS)
#undef X_COLS
  default:
    return 0;
  }
}

/* Address of row i of dataset id in record r. */
static const void *output_row(const mrvi_writer *w, const mrvi_record *r,
                              int id, int i) {
  switch (id) {
#define X_ROW(id_, path, type, stream, rank, cols, row, long_name)             \
  case id_:                                                                    \
    return (const void *)(row);
    MRVI_OUTPUT_LIST(X_ROW)
#undef X_ROW
  default:
    return NULL;
  }
}

/* Last dimension of a rank-3 dataset: the angular quantities have n_ang
 * components (3 in 3-D, 1 in 2-D), the others d. */
static hsize_t output_inner(const mrvi_writer *w, int id) {
  const int angular = id == BODIES_ANGULAR_VELOCITY || id == JOINTS_TORQUE ||
                      id == MICRO_BODIES_ANGULAR_VELOCITY;
  const int k = angular ? w->n_ang : w->dim;
  return (hsize_t)(k > 0 ? k : 1);
}

/* Shape of dataset id with `rows` rows (rank entries of shape); returns
 * the rank.  Rank 3 splits the columns as (bodies or joints, inner),
 * rank 4 as (bodies, d, d). */
static int output_shape(const mrvi_writer *w, int id, hsize_t rows,
                        hsize_t *shape) {
  const int rank = output_info[id].rank;
  const hsize_t cols = w->out[id].cols, d = (hsize_t)(w->dim > 0 ? w->dim : 1);
  const hsize_t inner = rank == 3 ? output_inner(w, id) : d;
  shape[0] = rows;
  if (rank >= 2)
    shape[1] = rank == 2 ? cols : rank == 3 ? cols / inner : cols / (d * d);
  for (int a = 2; a < rank; a++)
    shape[a] = inner;
  return rank;
}

/* ---------------------------------------------------------------------------
 * HDF5 errors: no printing, messages instead.
 * ------------------------------------------------------------------------- */
/* Record the first failure as "path: what: reason" from the error stack
 * (mrvi_h5_error_message).  Returns status. */
static int fail_h5(mrvi_writer *w, int status, const char *what) {
  if (w->status)
    return w->status;
  mrvi_h5_error_message(w->errmsg, sizeof w->errmsg, w->path, what);
  w->status = status;
  return status;
}

/* Record the first failure as "path: message".  Returns status. */
static int fail(mrvi_writer *w, int status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
static int fail(mrvi_writer *w, int status, const char *fmt, ...) {
  if (w->status)
    return w->status;
  char text[400];
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(text, sizeof text, fmt, ap);
  va_end(ap);
  mrvi_fmt(w->errmsg, sizeof w->errmsg, "%s: %s", w->path, text);
  w->status = status;
  return status;
}

/* ---------------------------------------------------------------------------
 * Attributes and fixed datasets
 * ------------------------------------------------------------------------- */

/* Record a failure to write dataset `path`.  Returns the status. */
static int fail_dataset(mrvi_writer *w, const char *path) {
  char what[128];
  mrvi_fmt(what, sizeof what, "writing %s", path);
  return fail_h5(w, MRVI_EIO, what);
}

/* One dataset of /model: count elements of type (ftype, mtype), or one
 * scalar; STRINGS for strings (data: const char *[]; written fixed-length,
 * mrvi_h5_write_strings). */
typedef struct fixed_dataset {
  const char *path;
  hid_t ftype, mtype;
  hsize_t count;
  int scalar;
  const void *data; /* NULL: the dataset is left out */
  const char *long_name;
} fixed_dataset;

#define STRINGS H5I_INVALID_HID, H5I_INVALID_HID

/* Write the datasets d[0 .. count-1], stopping at the first failure. */
static int write_fixed_list(mrvi_writer *w, hid_t lcpl, const fixed_dataset *d,
                            int count) {
  int rc = 0;
  for (int i = 0; i < count && rc == 0; i++) {
    if (!d[i].data)
      continue;
    const herr_t h =
        d[i].ftype == H5I_INVALID_HID
            ? mrvi_h5_write_strings(w->file, d[i].path, lcpl,
                                    (const char *const *)d[i].data, d[i].count,
                                    d[i].scalar, d[i].long_name)
            : mrvi_h5_write_fixed(w->file, d[i].path, lcpl, d[i].ftype,
                                  d[i].mtype, d[i].count, 0, d[i].scalar,
                                  d[i].data, d[i].long_name);
    if (h < 0)
      rc = fail_dataset(w, d[i].path);
  }
  return rc;
}

/* /model: mass, rate, name, description. */
static int write_model(mrvi_writer *w, const mrvi_model *m,
                       const char *description, hid_t lcpl) {
  size_t n = (size_t)w->n;
  double *mass = malloc((n ? n : 1) * sizeof *mass);
  int *rate = malloc((n ? n : 1) * sizeof *rate);
  const char **name = malloc((n ? n : 1) * sizeof *name);
  /* (the names made on demand, mrvi_model_coordinate_name, in one block) */
  char *made = name ? mrvi_model_names(m, 0, name) : NULL;
  int rc = 0;
  if (!mass || !rate || !made) {
    rc = fail(w, MRVI_ENOMEM, "writing /model: out of memory");
    goto out;
  }
  for (size_t i = 0; i < n; i++) {
    mass[i] = mrvi_model_mass(m, (int)i);
    rate[i] = mrvi_model_rate(m, (int)i) == MRVI_FAST ? 1 : 0;
    if (!name[i])
      name[i] = "";
  }
  const fixed_dataset list[] = {
      {"/model/mass", H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, n, 0, mass,
       "mass of each coordinate (diagonal of M), model order"},
      {"/model/rate", H5T_STD_I32LE, H5T_NATIVE_INT, n, 0, rate,
       "rate of each coordinate: 0 slow, 1 fast"},
      {"/model/name", STRINGS, n, 0, name, "name of each coordinate"},
      {"/model/description", STRINGS, 0, 1, description ? &description : NULL,
       "the input description, verbatim"},
  };
  rc = write_fixed_list(w, lcpl, list, (int)(sizeof list / sizeof *list));
out:
  free(mass);
  free(rate);
  free(name);
  free(made);
  return rc;
}

/* /model/particle_*, edges and the conserved momentum maps of a model with
 * particles (nothing without): what pictures of the motion (XDMF, `mrvi
 * export`, `mrvi-plot animate`) and the plots need to know. */
static int write_particles(mrvi_writer *w, const mrvi_model *m, hid_t lcpl) {
  const int np = mrvi_model_n_particles(m);
  if (np <= 0)
    return 0;
  const int ne = mrvi_model_edges(m, NULL, NULL, 0);
  const int na = mrvi_model_anchors(m, NULL, NULL, NULL, 0);
  size_t cap = (size_t)(np > ne ? np : ne) + 1;
  if ((size_t)na + 1 > cap)
    cap = (size_t)na + 1;
  const char **name = malloc(cap * sizeof *name);
  int *column = malloc(cap * sizeof *column);
  int *pairs = malloc(2 * cap * sizeof *pairs);
  int *kind = malloc(cap * sizeof *kind);
  int *a_particle = malloc(cap * sizeof *a_particle);
  int *a_kind = malloc(cap * sizeof *a_kind);
  double *a_point = malloc(cap * 3 * sizeof *a_point);
  int lin[3] = {0, 0, 0}, ang[3] = {0, 0, 0};
  int rc = 0;
  char *made = name ? mrvi_model_names(m, 1, name) : NULL;
  if (!made || !column || !pairs || !kind || !a_particle || !a_kind ||
      !a_point || ne < 0 || na < 0 || mrvi_model_conserved(m, lin, ang) < 0) {
    rc = fail(w, MRVI_ENOMEM, "writing /model: out of memory");
    goto out;
  }
  mrvi_model_edges(m, pairs, kind, ne);
  mrvi_model_anchors(m, a_particle, a_point, a_kind, na);
  for (int i = 0; i < np; i++) {
    column[i] = mrvi_particle_first(m, i);
    if (!name[i])
      name[i] = "";
  }
  const int dim = w->dim;
  const fixed_dataset list[] = {
      {"/model/dimension", H5T_STD_I32LE, H5T_NATIVE_INT, 1, 1, &dim,
       "spatial dimension d of the particles"},
      {"/model/particle_name", STRINGS, (hsize_t)np, 0, name,
       "name of each particle"},
      {"/model/particle_column", H5T_STD_I32LE, H5T_NATIVE_INT, (hsize_t)np, 0,
       column, "column of /macro/q holding the particle's x (y, z follow)"},
      {"/model/edge_rate", H5T_STD_I32LE, H5T_NATIVE_INT, (hsize_t)ne, 0, kind,
       "each edge: 0 slow spring, 1 fast spring, 2 rod"},
      {"/model/anchor_particle", H5T_STD_I32LE, H5T_NATIVE_INT, (hsize_t)na, 0,
       na > 0 ? a_particle : NULL,
       "particle index of each anchored spring or rod"},
      {"/model/anchor_rate", H5T_STD_I32LE, H5T_NATIVE_INT, (hsize_t)na, 0,
       na > 0 ? a_kind : NULL,
       "each anchor: 0 slow spring, 1 fast spring, 2 rod"},
      {"/model/linear_momentum_conserved", H5T_STD_I32LE, H5T_NATIVE_INT,
       (hsize_t)w->dim, 0, lin,
       "1 where the symmetry of the model conserves that component"},
      {"/model/angular_momentum_conserved", H5T_STD_I32LE, H5T_NATIVE_INT,
       (hsize_t)w->n_ang, 0, w->n_ang > 0 ? ang : NULL,
       "1 where the symmetry of the model conserves that component"},
  };
  rc = write_fixed_list(w, lcpl, list, (int)(sizeof list / sizeof *list));
  if (rc == 0 && mrvi_h5_write_fixed(
                     w->file, "/model/edges", lcpl, H5T_STD_I32LE,
                     H5T_NATIVE_INT, (hsize_t)ne, 2, 0, pairs,
                     "particle indices of the springs and rods between two "
                     "particles") < 0)
    rc = fail_dataset(w, "/model/edges");
  if (rc == 0 && na > 0 &&
      mrvi_h5_write_fixed(w->file, "/model/anchor_position", lcpl,
                          H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, (hsize_t)na,
                          (hsize_t)dim, 0, a_point,
                          "fixed end of each anchored spring or rod") < 0)
    rc = fail_dataset(w, "/model/anchor_position");
out:
  free(a_particle);
  free(a_kind);
  free(a_point);
  free(name);
  free(made);
  free(column);
  free(pairs);
  free(kind);
  return rc;
}

/* /model/constraint_*: one entry per constraint, in model order (their rows
 * are the columns of /macro/lambda, in the same order).  Nothing without
 * constraints. */
static int write_constraints(mrvi_writer *w, const mrvi_model *m, hid_t lcpl) {
  const int nc = mrvi_model_n_constraints(m);
  if (nc <= 0)
    return 0;
  const char **label = malloc((size_t)nc * sizeof *label);
  const char **type = malloc((size_t)nc * sizeof *type);
  const char **where = malloc((size_t)nc * sizeof *where);
  int *rows = malloc((size_t)nc * sizeof *rows);
  int rc = 0;
  if (!label || !type || !where || !rows) {
    rc = fail(w, MRVI_ENOMEM, "writing /model: out of memory");
    goto out;
  }
  for (int c = 0; c < nc; c++) {
    label[c] = mrvi_model_constraint_label(m, c);
    type[c] = mrvi_model_constraint_type_name(m, c);
    label[c] = label[c] ? label[c] : "";
    type[c] = type[c] ? type[c] : "";
    rows[c] = mrvi_model_constraint_n_rows(m, c);
    where[c] = mrvi_model_constraint_where(m, c) == MRVI_FAST ? "micro nodes"
                                                              : "macro nodes";
  }
  const hsize_t count = (hsize_t)nc;
  const fixed_dataset list[] = {
      {"/model/constraint_label", STRINGS, count, 0, label,
       "label of each constraint"},
      {"/model/constraint_type", STRINGS, count, 0, type,
       "type of each constraint"},
      {"/model/constraint_rows", H5T_STD_I32LE, H5T_NATIVE_INT, count, 0, rows,
       "scalar equations of each constraint (its columns of /macro/lambda)"},
      {"/model/constraint_where", STRINGS, count, 0, where,
       "where each constraint is enforced: macro nodes or micro nodes"},
  };
  rc = write_fixed_list(w, lcpl, list, (int)(sizeof list / sizeof *list));
out:
  free(label);
  free(type);
  free(where);
  free(rows);
  return rc;
}

/* /joints/name, type, constraint, body_a and body_b of a model with
 * joints (nothing without; doc/multibody.md). */
static int write_joints(mrvi_writer *w, const mrvi_model *m, hid_t lcpl) {
  const int nj = w->nj;
  if (nj <= 0)
    return 0;
  const char **name = malloc((size_t)nj * sizeof *name);
  const char **type = malloc((size_t)nj * sizeof *type);
  int *idx = malloc(3 * (size_t)nj * sizeof *idx);
  int rc = 0;
  if (!name || !type || !idx) {
    rc = fail(w, MRVI_ENOMEM, "writing /joints: out of memory");
    goto out;
  }
  for (int j = 0; j < nj; j++) {
    const int c = mrvi_model_joint_constraint(m, j);
    idx[j] = c;
    mrvi_model_joint_bodies(m, j, idx + nj + j, idx + 2 * nj + j);
    name[j] = mrvi_model_constraint_label(m, c);
    type[j] = mrvi_model_constraint_type_name(m, c);
  }
  const hsize_t count = (hsize_t)nj;
  const fixed_dataset list[] = {
      {"/joints/name", STRINGS, count, 0, name, "name (label) of each joint"},
      {"/joints/type", STRINGS, count, 0, type, "type of each joint"},
      {"/joints/constraint", H5T_STD_I32LE, H5T_NATIVE_INT, count, 0, idx,
       "constraint index of each joint (/model/constraint_label)"},
      {"/joints/body_a", H5T_STD_I32LE, H5T_NATIVE_INT, count, 0, idx + nj,
       "first body of each joint (/bodies/name): the body the reaction "
       "acts on"},
      {"/joints/body_b", H5T_STD_I32LE, H5T_NATIVE_INT, count, 0, idx + 2 * nj,
       "second body of each joint, -1 for the ground"},
  };
  rc = write_fixed_list(w, lcpl, list, (int)(sizeof list / sizeof *list));
out:
  free(name);
  free(type);
  free(idx);
  return rc;
}

/* /bodies/name and /bodies/column of a model with rigid bodies (nothing
 * without; doc/multibody.md). */
static int write_bodies(mrvi_writer *w, const mrvi_model *m, hid_t lcpl) {
  if (w->nb <= 0)
    return 0;
  const char **name = malloc((size_t)w->nb * sizeof *name);
  if (!name)
    return fail(w, MRVI_ENOMEM, "writing /bodies: out of memory");
  for (int b = 0; b < w->nb; b++)
    name[b] = mrvi_model_body_name(m, b);
  const fixed_dataset list[] = {
      {"/bodies/name", STRINGS, (hsize_t)w->nb, 0, name,
       "name of each rigid body"},
      {"/bodies/column", H5T_STD_I32LE, H5T_NATIVE_INT, (hsize_t)w->nb, 0,
       w->body_first,
       "column of /macro/q holding the body's phi_x (phi, then the "
       "directors d_1 .. d_D, D entries each)"},
  };
  int rc = write_fixed_list(w, lcpl, list, (int)(sizeof list / sizeof *list));
  free(name);
  if (rc == 0 && w->nfb > 0) {
    const fixed_dataset fast = {
        "/bodies/fast",
        H5T_STD_I32LE,
        H5T_NATIVE_INT,
        (hsize_t)w->nfb,
        0,
        w->fast_body,
        "index of each fast body (in /bodies/name): the columns of "
        "/micro/bodies"};
    rc = write_fixed_list(w, lcpl, &fast, 1);
  }
  return rc == 0 ? write_joints(w, m, lcpl) : rc;
}

/* ---------------------------------------------------------------------------
 * Appended datasets
 * ------------------------------------------------------------------------- */

/* Create dataset id: chunked, first dimension unlimited, empty. */
static int create_output(mrvi_writer *w, int id, hid_t lcpl,
                         hsize_t expected_rows) {
  const struct output_info *info = &output_info[id];
  output *o = &w->out[id];
  hsize_t dims[4], maxdims[4], chunk[4];
  hsize_t chunk_rows = CHUNK_BYTES / o->row_bytes;
  if (chunk_rows > expected_rows)
    chunk_rows = expected_rows;
  if (chunk_rows < 1)
    chunk_rows = 1;
  output_shape(w, id, 0, dims);
  output_shape(w, id, H5S_UNLIMITED, maxdims);
  output_shape(w, id, chunk_rows, chunk);
  hid_t space = H5Screate_simple(info->rank, dims, maxdims);
  hid_t dcpl = H5Pcreate(H5P_DATASET_CREATE);
  hid_t ftype = info->type == F64 ? H5T_IEEE_F64LE : H5T_STD_I32LE;
  if (space >= 0 && dcpl >= 0 && H5Pset_chunk(dcpl, info->rank, chunk) >= 0)
    o->id =
        H5Dcreate2(w->file, info->path, ftype, space, lcpl, dcpl, H5P_DEFAULT);
  hid_t es = mrvi_h5_keep_errors((herr_t)(o->id < 0 ? -1 : 0));
  if (space >= 0)
    H5Sclose(space);
  if (dcpl >= 0)
    H5Pclose(dcpl);
  mrvi_h5_restore_errors(es);
  if (o->id < 0 ||
      mrvi_h5_attr_string(o->id, "long_name", info->long_name) < 0) {
    char what[128];
    mrvi_fmt(what, sizeof what, "creating %s", info->path);
    return fail_h5(w, MRVI_EIO, what);
  }
  return 0;
}

/* /resume/chord_history, node 0's (no history: [0, 0, zeros]). */
static int create_chord(mrvi_writer *w, hid_t lcpl) {
  hid_t space = H5Screate_simple(1, &w->chord_len, NULL);
  if (space >= 0)
    w->chord_id = H5Dcreate2(w->file, "/resume/chord_history", H5T_IEEE_F64LE,
                             space, lcpl, H5P_DEFAULT, H5P_DEFAULT);
  hid_t es = mrvi_h5_keep_errors((herr_t)(w->chord_id < 0 ? -1 : 0));
  if (space >= 0)
    H5Sclose(space);
  mrvi_h5_restore_errors(es);
  if (w->chord_id < 0 ||
      mrvi_h5_attr_string(w->chord_id, "long_name",
                          "tuning.chord_carry: [k, n, the five rows' implicit "
                          "forces (n each)] the step after stored macro node "
                          "k takes (mrvi run --resume)") < 0 ||
      H5Dwrite(w->chord_id, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT,
               w->chord_buf) < 0)
    return fail_h5(w, MRVI_EIO, "creating /resume/chord_history");
  return 0;
}

/* The chord history of a stored record (hdf5_writer's chord_buf). */
static void chord_keep(mrvi_writer *w, const mrvi_record *r) {
  const int n = r->n_chord == w->nf ? w->nf : 0;
  w->chord_buf[0] = (double)r->k;
  w->chord_buf[1] = (double)n;
  for (int i = 0; i < 5 && n > 0; i++)
    memcpy(w->chord_buf + 2 + (size_t)i * (size_t)n, r->chord_history[i],
           (size_t)n * sizeof(double));
  w->chord_dirty = 1;
}

/* Write `rows` rows from buf at row `start` of dataset id, extending the
 * dataset when they end past the rows in the file. */
static herr_t write_rows(mrvi_writer *w, int id, hsize_t start, size_t rows,
                         const void *buf) {
  const struct output_info *info = &output_info[id];
  output *o = &w->out[id];
  hsize_t offset[4] = {start, 0, 0, 0}, count[4], size[4];
  output_shape(w, id, (hsize_t)rows, count);
  output_shape(w, id, start + count[0], size);
  hid_t mtype = info->type == F64 ? H5T_NATIVE_DOUBLE : H5T_NATIVE_INT;
  if (size[0] > w->written[info->stream] && H5Dset_extent(o->id, size) < 0)
    return -1;
  hid_t fspace = H5Dget_space(o->id);
  hid_t mspace = H5Screate_simple(info->rank, count, NULL);
  herr_t rc = -1;
  if (fspace >= 0 && mspace >= 0 &&
      H5Sselect_hyperslab(fspace, H5S_SELECT_SET, offset, NULL, count, NULL) >=
          0)
    rc = H5Dwrite(o->id, mtype, mspace, fspace, H5P_DEFAULT, buf);
  hid_t es = mrvi_h5_keep_errors(rc);
  if (fspace >= 0)
    H5Sclose(fspace);
  if (mspace >= 0)
    H5Sclose(mspace);
  mrvi_h5_restore_errors(es);
  return rc;
}

/* Bytes that must stay free on the file system beyond the rows of a write:
 * a new chunk for every dataset the writer may create (the optional
 * /micro/q_slow only when it is written), twice, and 1 MiB for metadata. */
#define SPACE_RESERVE(w)                                                       \
  ((size_t)2 * (size_t)(N_OUTPUTS - !(w)->micro_slow) * CHUNK_BYTES +          \
   ((size_t)1 << 20))

/* Refuse a write of `bytes` that could run the file system full.  HDF5 1.10
 * does not recover from a failed write: its metadata cache may reach the
 * file only in part, leaving datasets unreadable or with fill-value rows.
 * So the writer stops first, with the file intact, when free space (for an
 * unprivileged user) drops below twice the rows plus SPACE_RESERVE.  (A
 * quota or a racing writer can still make a write fail; then close cuts the
 * datasets back, see mrvi_writer_close.) */
static int check_space(mrvi_writer *w, size_t bytes) {
  struct statvfs v;
  if (w->lock_fd < 0 || fstatvfs(w->lock_fd, &v) < 0)
    return 0; /* unknown: try */
  const double avail = (double)v.f_bavail * (double)v.f_frsize;
  const double need = 2.0 * (double)bytes + (double)SPACE_RESERVE(w);
  if (avail >= need)
    return 0;
  return fail(w, MRVI_EIO,
              "file system nearly full (%.0f KiB free, %.0f KiB needed for "
              "the next write and a reserve); stopped before writing",
              avail / 1024, need / 1024);
}

/* Write all buffered rows, update steps_completed and flush the file.
 * final: also keep a pending macro row (the last record seen). */
static int flush(mrvi_writer *w, int final) {
  if (w->io_failed)
    return w->status;
  if (final && w->pending) {
    w->rows[MACRO]++;
    w->pending = 0;
  }
  mrvi_h5_quiet q;
  mrvi_h5_quiet_begin(&q);
  int rc = 0;
  /* Injected failure (tests of the error path): as if the disk filled up
   * before these rows reached the file. */
  if (w->fail_after >= 0 && w->last_k >= w->fail_after)
    rc = fail(w, MRVI_EIO,
              "writing rows: injected write failure "
              "(MRVI_TEST_WRITE_FAIL_AFTER)");
  if (rc == 0) {
    size_t bytes = 0;
    for (int id = 0; id < N_OUTPUTS; id++)
      if (w->out[id].id >= 0)
        bytes += w->rows[output_info[id].stream] * w->out[id].row_bytes;
    rc = check_space(w, bytes);
  }
  /* The multipliers and joint reactions of the last row already in the
   * file (fill_lambda). */
  const unsigned char *patch = (const unsigned char *)w->lambda_patch;
  for (int i = 0; i < N_LAMBDA_OUTPUTS && rc == 0 && w->patch; i++) {
    const int id = lambda_outputs[i];
    if (w->out[id].cols == 0)
      continue;
    if (write_rows(w, id, w->written[MACRO] - 1, 1, patch) < 0)
      rc = fail_dataset(w, output_info[id].path);
    patch += w->out[id].row_bytes;
  }
  w->patch = 0;
  for (int id = 0; id < N_OUTPUTS && rc == 0; id++) {
    const enum stream st = output_info[id].stream;
    if (w->out[id].id < 0 || w->rows[st] == 0)
      continue;
    if (write_rows(w, id, w->written[st], w->rows[st], w->out[id].buf) < 0)
      rc = fail_dataset(w, output_info[id].path);
  }
  /* The chord history of the last stored node, with the rows. */
  if (rc == 0 && w->chord_dirty) {
    if (H5Dwrite(w->chord_id, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT,
                 w->chord_buf) < 0)
      rc = fail_dataset(w, "/resume/chord_history");
    w->chord_dirty = 0;
  }
  /* Two flushes, so that the counter never runs ahead of the data: the rows
   * and the datasets' new extents reach the file first; only then is
   * steps_completed raised and flushed.  A process killed between (or
   * during) the two leaves a counter that is at most the rows stored. */
  if (rc == 0 && H5Fflush(w->file, H5F_SCOPE_LOCAL) < 0)
    rc = fail_h5(w, MRVI_EIO, "flushing the file");
  if (rc == 0 && mrvi_h5_attr_long(w->file, "steps_completed",
                                   w->last_k > 0 ? w->last_k : 0) < 0)
    rc = fail_h5(w, MRVI_EIO, "writing attribute steps_completed");
  if (rc == 0 && H5Fflush(w->file, H5F_SCOPE_LOCAL) < 0)
    rc = fail_h5(w, MRVI_EIO, "flushing the file");
  mrvi_h5_quiet_end(&q);
  if (rc) {
    w->io_failed = 1;
    return rc;
  }
  /* The pending macro row moves to the front of the emptied buffers. */
  if (w->pending)
    for (int id = 0; id < N_OUTPUTS; id++)
      if (w->out[id].id >= 0 && output_info[id].stream == MACRO)
        memmove(w->out[id].buf,
                w->out[id].buf + w->rows[MACRO] * w->out[id].row_bytes,
                w->out[id].row_bytes);
  for (int s = 0; s < N_STREAMS; s++) {
    w->written[s] += w->rows[s];
    w->rows[s] = 0;
  }
  w->records = 0;
  w->flushed_k = w->last_k > 0 ? w->last_k : 0;
  w->flushed_at = mrvi_clock();
  return 0;
}

/* ---------------------------------------------------------------------------
 * Public API
 * ------------------------------------------------------------------------- */

/* Close the file and every object of it, recording the first failure.
 *
 * Order matters.  When the final flush of a file fails (disk full, file
 * size limit), HDF5 1.10 returns an error from H5Fclose but leaves the file
 * identifier registered and half destroyed: closing it again, or H5close at
 * process exit, then crashes (fixed upstream in HDF5 1.14, PR #2291).  With
 * the weak close degree, H5Fclose only releases the identifier while
 * datasets are open; the real close happens in the last H5Dclose, which
 * reports the failure and leaves no identifier behind.  (HDF5 may still
 * print "infinite loop closing library" at exit after such a failure.) */
static void close_handles(mrvi_writer *w) {
  if (w->file >= 0 && H5Fclose(w->file) < 0)
    fail_h5(w, MRVI_EIO, "closing the file");
  w->file = H5I_INVALID_HID;
  for (int id = 0; id < N_OUTPUTS; id++) {
    if (w->out[id].id >= 0 && H5Dclose(w->out[id].id) < 0)
      fail_h5(w, MRVI_EIO, "closing the file");
    w->out[id].id = H5I_INVALID_HID;
  }
  if (w->chord_id >= 0 && H5Dclose(w->chord_id) < 0)
    fail_h5(w, MRVI_EIO, "closing the file");
  w->chord_id = H5I_INVALID_HID;
}

/* Release the memory of a writer whose handles are closed. */
static void writer_free(mrvi_writer *w) {
  if (w->lock_fd >= 0)
    close(w->lock_fd); /* releases the lock */
  for (int id = 0; id < N_OUTPUTS; id++)
    free(w->out[id].buf);
  free(w->micro_t);
  free(w->slow_col);
  free(w->prev_slow);
  free(w->slow_rows);
  free(w->body_first);
  free(w->body_rows);
  free(w->body_omega);
  free(w->joint_rows);
  free(w->joint_point);
  free(w->lambda_q);
  free(w->fast_body);
  free(w->fast_slot);
  free(w->micro_body_rows);
  free(w->scratch);
  free(w->nan_row);
  free(w->lambda_patch);
  free(w->chord_buf);
  free(w->path);
  free(w->part_path);
  free(w);
}

/* Take an exclusive lock on the output file before anything truncates it,
 * and refuse a file that is not an earlier mrvi output unless force: a
 * second run must never destroy the file of a live run, nor a user's data
 * (mrvi_h5_lock_output; the lock is held until close). */
static int lock_and_check(mrvi_writer *w, int force) {
  char msg[400];
  if (mrvi_h5_lock_output(w->path, force, &w->lock_fd, &w->new_file, msg,
                          sizeof msg) < 0)
    return fail(w, MRVI_EIO, "%s", msg);
  return check_space(w, 0);
}

/* Rename the file set up under part_path to the output path, moving the
 * lock with it (mrvi_h5_part_commit). */
static int move_into_place(mrvi_writer *w) {
  char msg[400];
  const int rc =
      mrvi_h5_part_commit(w->part_path, w->path, &w->lock_fd, msg, sizeof msg);
  if (rc)
    return fail(w, rc, "%s", msg);
  free(w->part_path);
  w->part_path = NULL;
  return 0;
}

/* Copy the closed file at path into the empty file part, byte for byte,
 * and force it to the disk.  0 or -1 (errno set). */
static int copy_file(const char *path, const char *part) {
  int in = open(path, O_RDONLY | O_CLOEXEC);
  int out = in >= 0 ? open(part, O_WRONLY | O_TRUNC | O_CLOEXEC) : -1;
  int rc = in >= 0 && out >= 0 ? 0 : -1;
  int kernel_copy = 1;
  char buf[1 << 16];
  while (rc == 0) {
    ssize_t n = kernel_copy
                    ? copy_file_range(in, NULL, out, NULL, (size_t)1 << 30, 0)
                    : read(in, buf, sizeof buf);
    if (n < 0 && kernel_copy && errno != EINTR) {
      kernel_copy = 0; /* another file system or no kernel support */
      continue;
    }
    if (n < 0 && errno == EINTR)
      continue;
    if (n <= 0) {
      rc = n < 0 ? -1 : 0;
      break;
    }
    for (ssize_t done = 0; !kernel_copy && done < n;) {
      ssize_t m = write(out, buf + done, (size_t)(n - done));
      if (m < 0 && errno != EINTR) {
        rc = -1;
        break;
      }
      done += m > 0 ? m : 0;
    }
  }
  if (rc == 0 && fsync(out) < 0)
    rc = -1;
  const int e = errno;
  if (out >= 0)
    close(out);
  if (in >= 0)
    close(in);
  errno = e;
  return rc;
}

static herr_t attr_variable(hid_t loc, const char *name, const H5A_info_t *ai,
                            void *data) {
  (void)ai;
  hid_t a = H5Aopen(loc, name, H5P_DEFAULT);
  hid_t t = a >= 0 ? H5Aget_type(a) : H5I_INVALID_HID;
  const int variable = mrvi_h5_type_variable(t);
  if (t >= 0)
    H5Tclose(t);
  if (a >= 0)
    H5Aclose(a);
  if (variable)
    mrvi_fmt(data, 256, "%s", name);
  return variable ? 1 : 0;
}

/* The root attributes of the file being appended to or extended, which
 * close rewrites or deletes: none may hold variable-length data (an
 * older mrvi's file, or an edited one), whose rewriting would go through
 * the file's global heap (doc/output.md, "Strings"). */
static int variable_attributes(mrvi_writer *w, hid_t f) {
  char name[256] = "";
  hsize_t idx = 0;
  const herr_t rc =
      H5Aiterate2(f, H5_INDEX_NAME, H5_ITER_NATIVE, &idx, attr_variable, name);
  if (rc < 0)
    return fail_h5(w, MRVI_EIO, "reading the root attributes");
  if (rc > 0)
    return fail(w, MRVI_EIO,
                "attribute %s is a variable-length string (a file of an "
                "older mrvi, or edited): not appended to",
                name);
  return 0;
}

/* Extending a completed run (mrvi_writer_options.extend): lock the file,
 * copy it beside itself, give the copy this run's t_end and description,
 * the fixed-length stop_reason "running" (which SWMR writing rewrites) and
 * no energy attributes of the old end (close writes the whole run's), force
 * it to disk and rename it over the output with the lock moved to it.
 * Killed before the rename, the completed file is untouched and a .part
 * copy may remain beside it; after, the file is the run stopped at its old
 * end, which --resume continues. */
static int extend_prepare(mrvi_writer *w, double t_end,
                          const char *description) {
  w->lock_fd = open(w->path, O_RDWR | O_CLOEXEC);
  if (w->lock_fd < 0)
    return fail(w, MRVI_EIO, "cannot open: %s", strerror(errno));
  if (mrvi_h5_lock_fd(w->lock_fd) < 0)
    return fail(w, MRVI_EIO, "%s",
                errno == EAGAIN
                    ? "the file is in use by another run (locked); not touched"
                    : "cannot lock the file");
  char msg[400];
  int rc = mrvi_h5_part_create(w->path, &w->part_path, msg, sizeof msg);
  if (rc)
    return fail(w, rc, "%s", msg);
  if (copy_file(w->path, w->part_path) < 0)
    return fail(w, MRVI_EIO, "copying the file beside itself: %s",
                strerror(errno));
  hid_t fapl = H5Pcreate(H5P_FILE_ACCESS);
#if H5_VERSION_GE(1, 10, 7)
  if (fapl >= 0)
    H5Pset_file_locking(fapl, 0, 1); /* no one else knows the copy */
#endif
  if (fapl >= 0)
    H5Pset_libver_bounds(fapl, H5F_LIBVER_LATEST, H5F_LIBVER_LATEST);
  hid_t f = H5Fopen(w->part_path, H5F_ACC_RDWR, fapl >= 0 ? fapl : H5P_DEFAULT);
  if (fapl >= 0)
    H5Pclose(fapl);
  if (f < 0)
    return fail_h5(w, MRVI_EIO, "cannot open the copy");
  static const char *const old_end[] = {"energy_error_max", "energy_scale",
                                        "energy_scale_kind", "warning"};
  if (variable_attributes(w, f) < 0) {
    H5Fclose(f);
    return w->status;
  }
  int ok = H5Adelete(f, "stop_reason") >= 0 &&
           mrvi_h5_attr_fixed_string(f, "stop_reason", "running") >= 0 &&
           mrvi_h5_attr_double(f, "t_end", t_end) >= 0;
  for (size_t i = 0; ok && i < sizeof old_end / sizeof *old_end; i++)
    if (H5Aexists(f, old_end[i]) > 0)
      ok = H5Adelete(f, old_end[i]) >= 0;
  if (ok && description) {
    ok = H5Ldelete(f, "/model/description", H5P_DEFAULT) >= 0 &&
         mrvi_h5_write_strings(f, "/model/description", H5P_DEFAULT,
                               &description, 0, 1,
                               "the input description, verbatim") >= 0;
  }
  if (H5Fclose(f) < 0)
    ok = 0;
  if (!ok)
    return fail_h5(w, MRVI_EIO, "setting the copy's t_end and description");
  int fd = open(w->part_path, O_RDWR | O_CLOEXEC);
  ok = fd >= 0 && fsync(fd) == 0;
  if (fd >= 0)
    close(fd);
  if (!ok)
    return fail(w, MRVI_EIO, "writing the copy: %s", strerror(errno));
  rc = mrvi_h5_part_commit(w->part_path, w->path, &w->lock_fd, msg, sizeof msg);
  if (rc)
    return fail(w, rc, "%s", msg);
  free(w->part_path);
  w->part_path = NULL;
  return 0;
}

/* Appending (mrvi run --resume): open the existing output for SWMR writing
 * and cut every dataset back to macro node k, as a run that stopped after
 * node k would have left it.  The file keeps HDF5's "open for writing" flag
 * when its writer was killed; opening clears it (as h5clear -s does). */
static int resume_open(mrvi_writer *w, long k, hid_t fapl) {
  if (w->lock_fd < 0) /* extend_prepare holds it already */
    w->lock_fd = open(w->path, O_RDWR | O_CLOEXEC);
  if (w->lock_fd < 0)
    return fail(w, MRVI_EIO, "cannot open: %s", strerror(errno));
  if (!w->extend && mrvi_h5_lock_fd(w->lock_fd) < 0)
    return fail(w, MRVI_EIO, "%s",
                errno == EAGAIN
                    ? "the file is in use by another run (locked); not touched"
                    : "cannot lock the file");
  hbool_t clear = 1;
  H5Pset(fapl, "clear_status_flags", &clear);
  H5Pset_metadata_read_attempts(fapl, MRVI_H5_SWMR_READ_ATTEMPTS);
  w->file = H5Fopen(w->path, H5F_ACC_RDWR | H5F_ACC_SWMR_WRITE, fapl);
  if (w->file < 0)
    return fail_h5(w, MRVI_EIO, "cannot open the file for appending");
  /* A killed SWMR writer can leave the superblock's end of allocation
   * (EOA) behind the data its flushed metadata points to; appending then
   * fails with "addr overflow".  Raise the EOA to the file's end (as
   * h5clear --increment does). */
  if (H5Fincrement_filesize(w->file, 0) < 0)
    return fail_h5(w, MRVI_EIO, "cannot extend the file's end of allocation");
  /* stop_reason is rewritten in place, which SWMR can do only to a
   * fixed-length string (mrvi writes no other; a file edited by a tool
   * that replaced it may have a variable-length one). */
  {
    hid_t a = H5Aexists(w->file, "stop_reason") > 0
                  ? H5Aopen(w->file, "stop_reason", H5P_DEFAULT)
                  : H5I_INVALID_HID;
    hid_t t = a >= 0 ? H5Aget_type(a) : H5I_INVALID_HID;
    const int fixed =
        t >= 0 && H5Tget_class(t) == H5T_STRING && H5Tis_variable_str(t) == 0;
    if (t >= 0)
      H5Tclose(t);
    if (a >= 0)
      H5Aclose(a);
    if (!fixed)
      return fail(w, MRVI_EIO,
                  "attribute stop_reason is not the fixed-length string of "
                  "a run that stopped (the file was edited): not resumed");
  }
  if (variable_attributes(w, w->file) < 0)
    return w->status;
  /* From node 0 the run starts afresh: every row is written again. */
  hsize_t keep[N_STREAMS];
  keep[MACRO] = k > 0 ? (hsize_t)(k / w->every) + 1 : 0;
  keep[MICRO] = k > 0 ? (hsize_t)k * (hsize_t)w->p + 1 : 0;
  keep[SOLVER] = (hsize_t)k;
  for (int id = 0; id < N_OUTPUTS; id++) {
    output *o = &w->out[id];
    if (o->cols == 0)
      continue;
    const struct output_info *info = &output_info[id];
    /* The file is untrusted: rank and shape checked before use. */
    char why[400];
    const mrvi_h5in in = {w->file, w->path, why, sizeof why};
    hsize_t want[MRVI_H5_MAX_RANK], dims[MRVI_H5_MAX_RANK] = {0, 1, 1, 1};
    output_shape(w, id, MRVI_H5_ANY, want);
    o->id =
        mrvi_h5in_open(&in, info->path, MRVI_H5_NUMBER, info->rank, want, dims);
    if (o->id < 0) {
      if (!w->status)
        mrvi_fmt(w->errmsg, sizeof w->errmsg,
                 "%s (does not fit this model and settings)", why);
      return w->status ? w->status : (w->status = MRVI_EIO);
    }
    if (dims[0] < keep[info->stream])
      return fail(w, MRVI_EIO, "%s: %llu rows do not reach macro node %ld",
                  info->path, (unsigned long long)dims[0], k);
    hsize_t size[MRVI_H5_MAX_RANK];
    output_shape(w, id, keep[info->stream], size);
    if (H5Dset_extent(o->id, size) < 0) {
      char what[128];
      mrvi_fmt(what, sizeof what, "cutting %s back", info->path);
      return fail_h5(w, MRVI_EIO, what);
    }
  }
  for (int s = 0; s < N_STREAMS; s++)
    w->written[s] = w->stream_on[s] ? keep[s] : 0;
  /* The chord history where the file has one of this run's size (SWMR
   * creates no dataset: a file without it goes on without). */
  if (w->chord_len > 0) {
    char why[400];
    const mrvi_h5in in = {w->file, w->path, why, sizeof why};
    const hsize_t want[1] = {w->chord_len};
    hsize_t dims[1];
    if (mrvi_h5in_exists(&in, "/resume/chord_history") &&
        (w->chord_id = mrvi_h5in_open(&in, "/resume/chord_history",
                                      MRVI_H5_NUMBER, 1, want, dims)) < 0)
      return fail(w, MRVI_EIO, "%s (does not fit this model and settings)",
                  why);
    if (w->chord_id < 0)
      w->chord_len = 0;
  }
  if (mrvi_h5_attr_long(w->file, "steps_completed", k) < 0 ||
      mrvi_h5_attr_fixed_string(w->file, "stop_reason", "running") < 0)
    return fail_h5(w, MRVI_EIO,
                   "writing attributes steps_completed and stop_reason");
  if (H5Fflush(w->file, H5F_SCOPE_LOCAL) < 0)
    return fail_h5(w, MRVI_EIO, "flushing the file");
  w->resume = k > 0;
  w->keep_lambda = w->n_lambda > 0 && k > 0;
  w->flushed_k = k;
  return 0;
}

/* Sizes, buffers and chunking; then the file. */
static int writer_setup(mrvi_writer *w, const mrvi_model *m,
                        const mrvi_settings *s, const char *system_name,
                        const char *description, int force, long resume_k) {
  long n_steps = mrvi_settings_n_steps(s);
  hsize_t N = n_steps > 0 ? (hsize_t)n_steps : 1;
  hsize_t expected[N_STREAMS];
  expected[MACRO] = N / (hsize_t)w->every + 1 + (N % (hsize_t)w->every != 0);
  expected[MICRO] = N * (hsize_t)w->p + 1;
  expected[SOLVER] = N;

  /* Row widths, and the bytes one record adds to the buffers. */
  size_t record_bytes = 0;
  for (int id = 0; id < N_OUTPUTS; id++) {
    output *o = &w->out[id];
    enum stream st = output_info[id].stream;
    o->cols = w->stream_on[st] ? output_columns(w, id) : 0;
    o->row_bytes = (size_t)o->cols *
                   (output_info[id].type == F64 ? sizeof(double) : sizeof(int));
    record_bytes += (st == MICRO ? (size_t)w->p : 1) * o->row_bytes;
  }
  w->flush_records = (long)(BUFFER_BYTES / (record_bytes ? record_bytes : 1));
  if (w->flush_records > FLUSH_RECORDS)
    w->flush_records = FLUSH_RECORDS;
  if (w->flush_records < 1)
    w->flush_records = 1;
  size_t R = (size_t)w->flush_records;
  w->cap[MACRO] = R + 1; /* + the pending row */
  w->cap[MICRO] = R * (size_t)w->p;
  w->cap[SOLVER] = R;
  for (int id = 0; id < N_OUTPUTS; id++) {
    output *o = &w->out[id];
    if (o->cols == 0)
      continue;
    o->buf = malloc(w->cap[output_info[id].stream] * o->row_bytes);
    if (!o->buf)
      return fail(w, MRVI_ENOMEM, "out of memory for output buffers");
  }
  w->micro_t = malloc((size_t)w->p * sizeof *w->micro_t);
  if (w->micro_slow) {
    w->slow_col = malloc((size_t)w->ns * sizeof *w->slow_col);
    w->prev_slow = malloc((size_t)w->ns * sizeof *w->prev_slow);
    w->slow_rows = malloc((size_t)w->p * (size_t)w->ns * sizeof *w->slow_rows);
    if (!w->slow_col || !w->prev_slow || !w->slow_rows)
      return fail(w, MRVI_ENOMEM, "out of memory");
    memcpy(w->slow_col, mrvi_model_slow_index(m),
           (size_t)w->ns * sizeof *w->slow_col);
  }
  if (w->nb > 0) {
    w->body_first = malloc((size_t)w->nb * sizeof *w->body_first);
    w->body_rows = malloc((size_t)w->nb * (size_t)(w->dim + w->dim * w->dim) *
                          sizeof *w->body_rows);
    if (!w->body_first || !w->body_rows)
      return fail(w, MRVI_ENOMEM, "out of memory");
    for (int b = 0; b < w->nb; b++)
      w->body_first[b] = mrvi_model_body_first(m, b);
    w->body_omega =
        malloc((size_t)w->nb * (size_t)w->n_ang * sizeof *w->body_omega);
    w->lambda_q = malloc((size_t)w->n * sizeof *w->lambda_q);
    w->joint_rows = malloc(((size_t)w->nj * (size_t)(w->dim + w->n_ang) + 1) *
                           sizeof *w->joint_rows);
    w->joint_point =
        malloc(((size_t)w->nj * (size_t)w->dim + 1) * sizeof *w->joint_point);
    if (!w->body_omega || !w->lambda_q || !w->joint_rows || !w->joint_point)
      return fail(w, MRVI_ENOMEM, "out of memory");
  }
  if (w->nfb > 0) {
    w->fast_body = malloc((size_t)w->nfb * sizeof *w->fast_body);
    w->fast_slot = malloc((size_t)w->nfb * sizeof *w->fast_slot);
    if (!w->fast_body || !w->fast_slot)
      return fail(w, MRVI_ENOMEM, "out of memory");
    /* A body's coordinates are consecutive in the fast block too (a body
     * is added with one rate as a whole). */
    const int *fast = mrvi_model_fast_index(m);
    for (int b = 0, f = 0; b < w->nb; b++) {
      const int first = mrvi_model_body_first(m, b);
      if (mrvi_model_rate(m, first) != MRVI_FAST)
        continue;
      w->fast_body[f] = b;
      for (int j = 0; j < w->nf; j++)
        if (fast[j] == first)
          w->fast_slot[f] = j;
      f++;
    }
    w->micro_body_rows =
        malloc((size_t)w->p * w->micro_body_width * sizeof *w->micro_body_rows);
    w->scratch = calloc(2 * (size_t)w->n, sizeof *w->scratch);
    if (!w->micro_body_rows || !w->scratch)
      return fail(w, MRVI_ENOMEM, "out of memory");
  }
  /* The multipliers and the joint reactions computed from them share the
   * NaN placeholder and the patch of the last row in the file. */
  const size_t nl =
      (size_t)w->n_lambda + (size_t)w->nj * (size_t)(w->dim + w->n_ang) + 1;
  w->nan_row = malloc(nl * sizeof *w->nan_row);
  w->lambda_patch = malloc(nl * sizeof *w->lambda_patch);
  if (!w->micro_t || !w->nan_row || !w->lambda_patch)
    return fail(w, MRVI_ENOMEM, "out of memory");
  for (size_t i = 0; i < nl; i++)
    w->nan_row[i] = NAN;

  /* The file: locked, checked, then truncated. */
  int rc = resume_k >= 0 ? 0 : lock_and_check(w, force);
  if (rc)
    return rc;
  hid_t fapl = H5Pcreate(H5P_FILE_ACCESS);
#if H5_VERSION_GE(1, 10, 7)
  /* Our own lock (lock_and_check) guards the file; HDF5's lock on its own
   * descriptor would conflict with it. */
  if (fapl >= 0)
    H5Pset_file_locking(fapl, 0, 1);
#endif
  if (fapl >= 0)
    H5Pset_fclose_degree(fapl, H5F_CLOSE_WEAK); /* see close_handles */
  /* SWMR writing (below) needs the latest file format. */
  if (fapl >= 0 &&
      H5Pset_libver_bounds(fapl, H5F_LIBVER_LATEST, H5F_LIBVER_LATEST) < 0) {
    H5Pclose(fapl);
    return fail_h5(w, MRVI_EIO, "cannot select the HDF5 file format");
  }
  /* (the history: sweep-cg's alone, solver/sweep.c) */
  const char *path = mrvi_solver_path(m, s, NULL, 0);
  w->chord_len =
      s->tuning.chord_carry && w->nf > 0 && path && !strcmp(path, "sweep-cg")
          ? 2 + 5 * (hsize_t)w->nf
          : 0;
  if (w->chord_len > 0 &&
      !(w->chord_buf = calloc((size_t)w->chord_len, sizeof(double)))) {
    if (fapl >= 0)
      H5Pclose(fapl);
    return fail(w, MRVI_ENOMEM, "out of memory");
  }
  if (resume_k >= 0) {
    if (w->extend)
      rc = extend_prepare(w, s->t_end, description);
    if (rc == 0)
      rc = fapl >= 0 ? resume_open(w, resume_k, fapl)
                     : fail_h5(w, MRVI_EIO, "file access properties");
    if (fapl >= 0)
      H5Pclose(fapl);
    return rc;
  }
  /* The file is set up under a name of its own and renamed to the output
   * once it is complete and in SWMR mode: a run killed before leaves the
   * previous file (or an empty one) at the output path, never a half-built
   * one. */
  char msg[400];
  rc = mrvi_h5_part_create(w->path, &w->part_path, msg, sizeof msg);
  if (rc) {
    if (fapl >= 0)
      H5Pclose(fapl);
    return fail(w, rc, "%s", msg);
  }
  w->file = H5Fcreate(w->part_path, H5F_ACC_TRUNC, H5P_DEFAULT,
                      fapl >= 0 ? fapl : H5P_DEFAULT);
  hid_t es = mrvi_h5_keep_errors((herr_t)(w->file < 0 ? -1 : 0));
  if (fapl >= 0)
    H5Pclose(fapl);
  mrvi_h5_restore_errors(es);
  if (w->file < 0)
    return fail_h5(w, MRVI_EIO, "cannot create the file");

  /* Root attributes. */
  char scheme[sizeof s->scheme + 1];
  mrvi_fmt(scheme, sizeof scheme, "%.*s", (int)sizeof s->scheme, s->scheme);
  const char *solver_path = mrvi_solver_path(m, s, NULL, 0);
  if (!solver_path)
    solver_path = "none";
#define X_ATTR(name, kind, value, present)                                     \
  if ((present) && mrvi_h5_attr_##kind(w->file, name, value) < 0)              \
    return fail_h5(w, MRVI_EIO, "writing attribute " name);
  MRVI_ATTRIBUTE_LIST(X_ATTR)
#undef X_ATTR

  /* /model and the (empty) appended datasets; groups are created on the way. */
  hid_t lcpl = H5Pcreate(H5P_LINK_CREATE);
  if (lcpl < 0 || H5Pset_create_intermediate_group(lcpl, 1) < 0) {
    fail_h5(w, MRVI_EIO, "creating groups");
    if (lcpl >= 0)
      H5Pclose(lcpl);
    return w->status;
  }
  rc = write_model(w, m, description, lcpl);
  if (rc == 0)
    rc = write_particles(w, m, lcpl);
  if (rc == 0)
    rc = write_constraints(w, m, lcpl);
  if (rc == 0)
    rc = write_bodies(w, m, lcpl);
  for (int id = 0; id < N_OUTPUTS && rc == 0; id++)
    if (w->out[id].cols > 0)
      rc = create_output(w, id, lcpl, expected[output_info[id].stream]);
  if (rc == 0 && w->chord_len > 0)
    rc = create_chord(w, lcpl);
  H5Pclose(lcpl);
  if (rc == 0 && H5Fflush(w->file, H5F_SCOPE_LOCAL) < 0)
    rc = fail_h5(w, MRVI_EIO, "flushing the file");
  /* Every object exists: from here on the file is written in SWMR mode,
   * whose ordered metadata flushes keep it consistent at every instant. */
  if (rc == 0 && H5Fstart_swmr_write(w->file) < 0)
    rc = fail_h5(w, MRVI_EIO, "starting SWMR writing");
  return rc ? rc : move_into_place(w);
}

mrvi_writer_options mrvi_system_writer_options(const mrvi_system *sys) {
  mrvi_writer_options opt = {
      .system_name = sys->name ? sys->name : mrvi_model_name(sys->model),
      .description = sys->description,
      .every = sys->output_every > 0 ? sys->output_every : 1,
      .micro = sys->output_micro,
      .flush_interval = sys->output_flush_interval,
      .micro_slow = sys->output_micro_slow,
  };
  return opt;
}

int mrvi_writer_open(const char *path, const mrvi_model *m,
                     const mrvi_settings *s, const mrvi_writer_options *opt,
                     mrvi_writer **out, char *msg, size_t len) {
  mrvi_fmt(msg, len, "%s", "");
  if (out)
    *out = NULL;
  /* No H5close at exit (mrvi_h5_quiet_begin says why): before the
   * library's first use. */
  H5dont_atexit();
  if (!path || !path[0] || !m || !s || !out) {
    mrvi_fmt(msg, len, "mrvi_writer_open: %s",
             !out ? "no result pointer"
             : !m ? "no model"
             : !s ? "no settings"
                  : "no file name");
    return MRVI_EINVAL;
  }
  mrvi_writer_options o = {NULL, NULL, 1, 1, 0.0, 0, 0, 0, 0, 0};
  if (opt)
    o = *opt;
  if (o.every < 1) {
    mrvi_fmt(msg, len, "%s: output every %d: must be >= 1", path, o.every);
    return MRVI_EINVAL;
  }
  if (s->micro_steps < 1) {
    mrvi_fmt(msg, len, "%s: micro_steps %d: must be >= 1", path,
             s->micro_steps);
    return MRVI_EINVAL;
  }
  const char *system_name = o.system_name ? o.system_name : mrvi_model_name(m);

  mrvi_writer *w = calloc(1, sizeof *w);
  if (!w) {
    mrvi_fmt(msg, len, "%s: out of memory", path);
    return MRVI_ENOMEM;
  }
  w->path = strdup(path);
  if (!w->path) {
    free(w);
    mrvi_fmt(msg, len, "%s: out of memory", path);
    return MRVI_ENOMEM;
  }
  w->file = H5I_INVALID_HID;
  for (int id = 0; id < N_OUTPUTS; id++)
    w->out[id].id = H5I_INVALID_HID;
  w->chord_id = H5I_INVALID_HID;
  w->n = mrvi_model_n(m);
  w->nf = mrvi_model_n_fast(m);
  w->ns = mrvi_model_n_slow(m);
  w->dim = mrvi_model_dimension(m);
  w->n_ang = w->dim == 3 ? 3 : w->dim == 2 ? 1 : 0;
  w->p = s->micro_steps;
  w->every = o.every;
  w->energy_warning = s->energy_warning;
  w->n_lambda = mrvi_model_constraint_rows(m);
  w->n_torsion = mrvi_model_n_torsions(m);
  w->nb = mrvi_model_n_bodies(m);
  w->model = m;
  w->nj = mrvi_model_n_joints(m);
  w->stream_on[MACRO] = 1;
  w->stream_on[MICRO] = o.micro && w->nf > 0;
  for (int b = 0; w->stream_on[MICRO] && b < w->nb; b++)
    w->nfb += mrvi_model_rate(m, mrvi_model_body_first(m, b)) == MRVI_FAST;
  w->micro_body_width =
      (size_t)w->nfb * (size_t)(w->dim + w->dim * w->dim + w->n_ang);
  w->micro_slow = o.micro_slow && w->stream_on[MICRO] && w->ns > 0;
  w->stream_on[SOLVER] = 1;
  w->last_k = -1;
  w->flushed_at = mrvi_clock();
  w->flush_interval = o.flush_interval > 0 ? o.flush_interval : FLUSH_SECONDS;
  w->lock_fd = -1;
  w->fail_after = -1;
  const char *inject = getenv("MRVI_TEST_WRITE_FAIL_AFTER");
  if (inject && *inject)
    w->fail_after = strtol(inject, NULL, 10);

  mrvi_h5_quiet q;
  mrvi_h5_quiet_begin(&q);
  w->extend = o.resume && o.extend;
  int rc = writer_setup(w, m, s, system_name, o.description, o.force,
                        o.resume ? (o.resume_k >= 0 ? o.resume_k : 0) : -1);
  if (rc) {
    mrvi_fmt(msg, len, "%s", w->errmsg);
    int created = w->new_file;
    close_handles(w);
    if (w->part_path)
      remove(w->part_path);
    writer_free(w);
    /* A half-written file is no mrvi file: remove it (a regular file only,
     * never e.g. a device the user named). */
    struct stat st;
    if (created && lstat(path, &st) == 0 && S_ISREG(st.st_mode))
      remove(path);
    H5Eclear2(H5E_DEFAULT);
    mrvi_h5_quiet_end(&q);
    return rc;
  }
  mrvi_h5_quiet_end(&q);
  *out = w;
  return MRVI_OK;
}

/* Record k brings the multipliers of node k-1 (lambda_prev): fill in the
 * /macro/lambda row of node k-1 unless it is the pending row, which record k
 * replaces.  That row is the last buffered macro row or, right after a
 * flush, the last row in the file, which the next flush rewrites. */
static void fill_lambda(mrvi_writer *w, const mrvi_record *r) {
  if (w->out[MACRO_LAMBDA].cols == 0 || w->last_k < 0 || w->pending)
    return;
  if (w->keep_lambda) {
    w->keep_lambda = 0;
    return;
  }
  /* The joint reactions of node k-1: its q (lambda_q) and multipliers. */
  const int D = w->dim;
  for (int j = 0; j < w->nj; j++)
    mrvi_model_joint_reaction(
        w->model, j, w->lambda_q, r->lambda_prev, w->joint_rows + j * D,
        w->joint_rows + (size_t)w->nj * (size_t)D + (size_t)(j * w->n_ang));
  /* joint_rows is NULL without joints (no offset from it then: UB). */
  const double *angular =
      w->joint_rows ? w->joint_rows + (size_t)w->nj * (size_t)D : NULL;
  const void *src[N_LAMBDA_OUTPUTS] = {r->lambda_prev, w->joint_rows, angular};
  unsigned char *patch = (unsigned char *)w->lambda_patch;
  for (int i = 0; i < N_LAMBDA_OUTPUTS; i++) {
    output *o = &w->out[lambda_outputs[i]];
    if (o->cols == 0)
      continue;
    if (w->rows[MACRO] > 0)
      memcpy(o->buf + (w->rows[MACRO] - 1) * o->row_bytes, src[i],
             o->row_bytes);
    else
      memcpy(patch, src[i], o->row_bytes);
    patch += o->row_bytes;
  }
  if (w->rows[MACRO] == 0)
    w->patch = 1;
}

/* /micro/q_slow rows of record r (rows of them): the slow coordinates as
 * the scheme sees them at the micro nodes m = 1..p of step k-1 -> k, the
 * linear interpolation (1 - m/p) q_{k-1}^s + (m/p) q_k^s of the macro nodes
 * (mrvi_step_node_point); at k = 0 the initial node q_0^s. */
static void interpolate_slow(mrvi_writer *w, const mrvi_record *r,
                             size_t rows) {
  const int *slow = w->slow_col, ns = w->ns;
  for (size_t i = 0; i < rows; i++) {
    const double b = r->k == 0 ? 0.0 : (double)(i + 1) / (double)w->p;
    const double a = 1.0 - b;
    double *row = w->slow_rows + i * (size_t)ns;
    for (int j = 0; j < ns; j++)
      row[j] =
          r->k == 0 ? r->q[slow[j]] : a * w->prev_slow[j] + b * r->q[slow[j]];
  }
  for (int j = 0; j < ns; j++)
    w->prev_slow[j] = r->q[slow[j]];
}

/* /bodies/position and /bodies/rotation rows of record r: phi and
 * R = [d_1 .. d_D] (row-major, R_ai = d_i[a]) of every body from q. */
static void body_poses(mrvi_writer *w, const mrvi_record *r) {
  const int D = w->dim;
  double *pos = w->body_rows, *rot = w->body_rows + (size_t)w->nb * D;
  for (int b = 0; b < w->nb; b++) {
    const double *y = r->q + w->body_first[b];
    for (int a = 0; a < D; a++) {
      pos[b * D + a] = y[a];
      for (int i = 0; i < D; i++)
        rot[(b * D + a) * D + i] = y[D * (1 + i) + a];
    }
    mrvi_model_body_angular_velocity(w->model, b, r->q, r->p,
                                     w->body_omega + b * w->n_ang);
  }
  for (int j = 0; j < w->nj; j++)
    mrvi_model_joint_point(w->model, j, r->q, w->joint_point + j * D);
  if (w->nj > 0)
    memcpy(w->lambda_q, r->q, (size_t)w->n * sizeof *w->lambda_q);
}

/* /micro/bodies/... rows of record r (rows of them): position, rotation
 * and angular velocity of every fast body at each micro node, from the
 * micro coordinates and momenta (copied into model order in scratch). */
static void micro_body_poses(mrvi_writer *w, const mrvi_record *r,
                             size_t rows) {
  const int D = w->dim, nc = D * (D + 1), F = w->nfb;
  double *q = w->scratch, *p = w->scratch + w->n;
  for (size_t i = 0; i < rows; i++) {
    double *row = w->micro_body_rows + i * w->micro_body_width;
    double *pos = row, *rot = row + F * D, *om = row + F * (D + D * D);
    for (int f = 0; f < F; f++) {
      const int b = w->fast_body[f], first = w->body_first[b];
      const size_t at = i * (size_t)w->nf + (size_t)w->fast_slot[f];
      memcpy(q + first, r->micro_q_fast + at, (size_t)nc * sizeof *q);
      memcpy(p + first, r->micro_p_fast + at, (size_t)nc * sizeof *p);
      mrvi_model_body_pose(w->model, b, q, pos + f * D, rot + f * D * D);
      mrvi_model_body_angular_velocity(w->model, b, q, p, om + f * w->n_ang);
    }
  }
}

int mrvi_writer_observe(void *writer, const mrvi_record *r) {
  mrvi_writer *w = writer;
  if (!w)
    return MRVI_EINVAL;
  if (w->status)
    return w->status;
  if (!r || !r->q || !r->p)
    return fail(w, MRVI_EINVAL, "record without q or p");
  if (r->k < 0 || (w->last_k >= 0 && r->k != w->last_k + 1))
    return fail(w, MRVI_EINVAL,
                "record k = %ld after k = %ld (records must come in "
                "order)",
                r->k, w->last_k);
  /* Rows this record adds to each stream. */
  size_t add[N_STREAMS];
  /* The first record is an initial node: no solver row. */
  add[MACRO] = 1;
  add[SOLVER] = w->last_k >= 0;
  add[MICRO] = 0;
  if (w->stream_on[MICRO]) {
    if (r->micro_count < 0 || r->micro_count > w->p ||
        (r->micro_count > 0 && (!r->micro_q_fast || !r->micro_p_fast)))
      return fail(w, MRVI_EINVAL,
                  "record k = %ld has %d micro nodes (at most %d, "
                  "with q and p)",
                  r->k, r->micro_count, w->p);
    add[MICRO] = (size_t)r->micro_count;
  }
  if (w->n_lambda > 0 &&
      (r->n_lambda != w->n_lambda || (w->last_k >= 0 && !r->lambda_prev) ||
       (add[MICRO] > 0 && !r->micro_constraint_residual)))
    return fail(w, MRVI_EINVAL,
                "record k = %ld has %d constraint rows (the model %d)%s%s",
                r->k, r->n_lambda, w->n_lambda,
                w->last_k >= 0 && !r->lambda_prev ? ", no lambda_prev" : "",
                add[MICRO] > 0 && !r->micro_constraint_residual
                    ? ", no micro_constraint_residual"
                    : "");
  if (w->resume && w->last_k < 0) {
    /* Appending: node resume_k is in the file already. */
    if (w->micro_slow)
      interpolate_slow(w, r, 0);
    if (w->nj > 0)
      memcpy(w->lambda_q, r->q, (size_t)w->n * sizeof *w->lambda_q);
    if (w->chord_len > 0)
      chord_keep(w, r);
    w->last_k = r->k;
    return MRVI_OK;
  }
  fill_lambda(w, r);
  /* Make room (normally the record-count flush below keeps it). */
  for (int s = 0; s < N_STREAMS; s++)
    if (w->rows[s] + add[s] > w->cap[s]) {
      int rc = flush(w, 0);
      if (rc)
        return rc;
      break;
    }

  for (size_t i = 0; i < add[MICRO]; i++)
    w->micro_t[i] = r->micro_t0 + (double)i * r->micro_dt;
  if (w->micro_slow)
    interpolate_slow(w, r, add[MICRO]);
  if (w->nb > 0)
    body_poses(w, r);
  if (w->nfb > 0)
    micro_body_poses(w, r, add[MICRO]);
  /* Copy the rows; the macro row goes to rows[MACRO] (over a pending row). */
  for (int id = 0; id < N_OUTPUTS; id++) {
    output *o = &w->out[id];
    enum stream st = output_info[id].stream;
    if (o->cols == 0)
      continue;
    for (size_t i = 0; i < add[st]; i++)
      memcpy(o->buf + (w->rows[st] + i) * o->row_bytes,
             output_row(w, r, id, (int)i), o->row_bytes);
  }
  if (r->k % w->every == 0) {
    w->rows[MACRO]++;
    w->pending = 0;
    if (w->chord_len > 0)
      chord_keep(w, r);
  } else {
    w->pending = 1;
  }
  w->rows[MICRO] += add[MICRO];
  w->rows[SOLVER] += add[SOLVER];
  w->last_k = r->k;
  w->records++;

  if (w->records >= w->flush_records ||
      mrvi_clock() - w->flushed_at >= w->flush_interval)
    return flush(w, 0);
  return MRVI_OK;
}

void mrvi_writer_set_summary(mrvi_writer *w, const mrvi_summary *sum) {
  if (!w || !sum)
    return;
  w->have_summary = 1;
  w->energy.max_rel_energy_error = sum->max_rel_energy_error;
  w->energy.energy_scale = sum->energy_scale;
  w->energy.energy_scale_kind = sum->energy_scale_kind;
  mrvi_fmt(w->energy.warning, sizeof w->energy.warning, "%s", sum->warning);
}

/* The energy error attributes of mrvi_writer_set_summary (doc/output.md). */
static herr_t write_energy_attributes(mrvi_writer *w) {
  static const char *const kind[] = {"initial", "run", "absolute"};
  const mrvi_summary *e = &w->energy;
  const int k = e->energy_scale_kind >= 0 && e->energy_scale_kind <= 2
                    ? e->energy_scale_kind
                    : 2;
  if (mrvi_h5_attr_double(w->file, "energy_error_max",
                          e->max_rel_energy_error) < 0 ||
      mrvi_h5_attr_double(w->file, "energy_scale", e->energy_scale) < 0 ||
      mrvi_h5_attr_string(w->file, "energy_scale_kind", kind[k]) < 0 ||
      mrvi_h5_attr_double(w->file, "energy_warning", w->energy_warning) < 0 ||
      mrvi_h5_attr_string(w->file, "warning", e->warning) < 0)
    return -1;
  return 0;
}

int mrvi_writer_close(mrvi_writer *w, const char *stop_reason, char *msg,
                      size_t len) {
  mrvi_fmt(msg, len, "%s", "");
  if (!w)
    return MRVI_OK;
  mrvi_h5_quiet q;
  mrvi_h5_quiet_begin(&q);
  flush(w, 1);
  /* The reason is written even after a failed write (best effort), but a
   * later failure never replaces the first message. */
  const char *reason =
      stop_reason && stop_reason[0] ? stop_reason : "completed";
  char why[1200];
  if (w->io_failed) {
    /* Rows of the failed flush may have extended a dataset without their
     * data reaching the file: cut every dataset back to the rows of the
     * last successful flush, so that no fill-value rows remain. */
    for (int id = 0; id < N_OUTPUTS; id++) {
      if (w->out[id].id < 0)
        continue;
      hsize_t size[MRVI_H5_MAX_RANK];
      output_shape(w, id, w->written[output_info[id].stream], size);
      H5Dset_extent(w->out[id].id, size);
    }
    mrvi_fmt(why, sizeof why, "output error: %s", w->errmsg);
    reason = why;
  }
  /* The counter first, stop_reason last: a stop_reason other than
   * "running" marks a run that closed. */
  if (mrvi_h5_attr_long(w->file, "steps_completed", w->flushed_k) < 0 ||
      H5Fflush(w->file, H5F_SCOPE_LOCAL) < 0 ||
      mrvi_h5_attr_fixed_string(w->file, "stop_reason", reason) < 0)
    fail_h5(w, MRVI_EIO, "writing attribute stop_reason");
  if (w->have_summary && write_energy_attributes(w) < 0)
    fail_h5(w, MRVI_EIO, "writing the energy error attributes");
  H5Eclear2(H5E_DEFAULT);
  close_handles(w);
  H5Eclear2(H5E_DEFAULT);
  mrvi_h5_quiet_end(&q);
  int rc = w->status;
  if (rc)
    mrvi_fmt(msg, len, "%s", w->errmsg);
  writer_free(w);
  return rc;
}
