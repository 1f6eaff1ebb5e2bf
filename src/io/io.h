/* What src/io offers the command-line tool beyond mrvi.h: the HDF5 files of
 * the study commands (study_writer.c) and of `mrvi optimize`
 * (optimize_output.c).  Layouts in doc/output.md.  Every function returns
 * a status (0 or a negative MRVI_E*) with a message in msg; none prints.
 * It includes the layer below (ocp/ocp_internal.h), through which the
 * files of src/io reach the model, the integrator and mrvi_ocp_parse; the
 * HDF5 helpers they share are h5util.h. */
#ifndef MRVI_IO_H
#define MRVI_IO_H

#include "ocp/ocp_internal.h"

#include <stddef.h>

/* ---------------------------------------------------------------------------
 * Study tables (study_writer.c): written whole under a temporary name and
 * renamed to path when complete, with path locked meanwhile (h5util.h).
 * ------------------------------------------------------------------------- */

/* Error columns of `mrvi converge`, listed once: X(dataset, mrvi_errors
 * field); the CSV table has the same columns. */
#define MRVI_ERROR_COLUMNS(X)                                                  \
  X(e_q_mac, q_mac)                                                            \
  X(e_p_mac, p_mac)                                                            \
  X(e_q_mic, q_mic)                                                            \
  X(e_p_mic, p_mic)                                                            \
  X(e_qs_mac, qs_mac)                                                          \
  X(e_qf_mac, qf_mac)                                                          \
  X(e_ps_mac, ps_mac)                                                          \
  X(e_pf_mac, pf_mac)

/* The rows of one p: group /convergence/p<p>. */
typedef struct mrvi_convergence_rows {
  int p, rows;
  const double *macro_step;  /* rows */
  const mrvi_errors *errors; /* rows */
} mrvi_convergence_rows;

typedef struct mrvi_convergence_table {
  const char *system, *scheme; /* root attributes */
  double t_end, reference_step;
  const char *reference_scheme;
  int n_p;
  const mrvi_convergence_rows *by_p; /* n_p */
} mrvi_convergence_table;

int mrvi_study_write_convergence(const char *path,
                                 const mrvi_convergence_table *t, char *msg,
                                 size_t len);

/* `mrvi stability`: the two rules of the slow potential on the micro grid
 * of Lemma lemma:stability_slow, in this order (dataset name prefixes). */
enum { MRVI_STABILITY_RULES = 2 };
extern const char *const mrvi_stability_rule_name[MRVI_STABILITY_RULES];

/* measured: the largest stable omega dT, analytic: the lemma's bound, per
 * rule and p; trace: of the propagation matrix at each omega_dT. */
typedef struct mrvi_stability_table {
  const char *system;
  double omega;
  int n_p;
  const int *p;                                 /* n_p */
  const double *measured[MRVI_STABILITY_RULES]; /* n_p each */
  const double *analytic[MRVI_STABILITY_RULES]; /* n_p each */
  int n_scan;
  const double *omega_dT; /* n_scan */
  const double *trace;    /* rules x n_p x n_scan */
} mrvi_stability_table;

int mrvi_study_write_stability(const char *path, const mrvi_stability_table *t,
                               char *msg, size_t len);

/* Columns of `mrvi timing`, listed once (datasets, CSV columns, fields). */
#define MRVI_TIMING_COLUMNS(X)                                                 \
  X(total_time)                                                                \
  X(iterations)                                                                \
  X(time_per_step)                                                             \
  X(assemble_per_step)                                                         \
  X(solve_per_step)                                                            \
  X(macro_steps)                                                               \
  X(system_size)

typedef struct mrvi_timing_row {
#define MRVI_TIMING_FIELD(name) double name;
  MRVI_TIMING_COLUMNS(MRVI_TIMING_FIELD)
#undef MRVI_TIMING_FIELD
} mrvi_timing_row;

typedef struct mrvi_timing_table {
  const char *system;
  double micro_step, t_end;
  int repeat; /* runs per row (times: medians) */
  int n_p, n_schemes;
  const int *p;                /* n_p */
  const char *const *schemes;  /* n_schemes: group names */
  const mrvi_timing_row *rows; /* n_schemes x n_p */
} mrvi_timing_table;

int mrvi_study_write_timing(const char *path, const mrvi_timing_table *t,
                            char *msg, size_t len);

/* ---------------------------------------------------------------------------
 * `mrvi optimize` (optimize_output.c)
 * ------------------------------------------------------------------------- */

/* The trajectory of o's last evaluation in the layout of `mrvi run`
 * (/macro and, with output.micro, /micro; through the run writer,
 * mrvi_writer_open), with the root attribute solver naming the forward
 * pass's path: what `mrvi run --controls` writes. */
int mrvi_ocp_trajectory_write(const char *path, const mrvi_system *sys,
                              const mrvi_ocp *o, char *msg, size_t len);

/* The controls /control/u stored by `mrvi optimize` at path into u (the
 * control vector of o): a column per actuator, a row per macro step or per
 * micro step (micro_steps per macro step), checked before they are read
 * (h5read.c); MRVI_EIO with a message when the file has none or they do
 * not fit o's actuators and steps. */
int mrvi_ocp_controls_read(const char *path, const mrvi_ocp *o, int micro_steps,
                           double *u, char *msg, size_t len);

/* The output of `mrvi optimize`: the trajectory (as
 * mrvi_ocp_trajectory_write), /control (the controls on the finest grid of
 * the actuators, their names and the terminal conditions) and /optimizer
 * (the history of cost, terminal violation, gradient norm and KKT
 * residual per evaluation, the result).  Opened before optimising, given every
 * evaluation, closed with the result:
 *   mrvi_ocp_output_open -> mrvi_ocp_output_start ->
 *   (mrvi_ocp_output_iteration, mrvi_ocp_output_progress) ... ->
 *   mrvi_ocp_output_close.
 * Open checks the path as the writer at close will take it (created or an
 * earlier mrvi output, not locked by a live writer, a temporary file
 * creatable beside it) and leaves it as it was; progress writes a progress
 * file (status "running", no trajectory) and close the whole file, each
 * renamed over the path when complete. */
typedef struct mrvi_ocp_output mrvi_ocp_output;

/* sys and o must outlive the output.  MRVI_EIO with "path: reason" when
 * the path is unusable. */
int mrvi_ocp_output_open(const char *path, const mrvi_system *sys,
                         const mrvi_ocp *o, mrvi_ocp_output **out, char *msg,
                         size_t len);
/* Before the optimiser starts: the first progress file (as
 * mrvi_ocp_output_progress, with the initial controls u0 and no history
 * row), so that a process killed before its first evaluation completes
 * leaves a readable file too.  Does not delay the progress file of the
 * first evaluation.  MRVI_EIO with a message when it cannot be written. */
int mrvi_ocp_output_start(mrvi_ocp_output *w, const double *u0, char *msg,
                          size_t len);
/* One evaluation: a row of /optimizer/history.  MRVI_ENOMEM when it cannot
 * be kept. */
int mrvi_ocp_output_iteration(mrvi_ocp_output *w, double cost, double violation,
                              double gradient_norm, double kkt_residual);
/* After an evaluation: when output.flush_interval seconds (default 2) have
 * passed since the last progress file (the first at once), replace the
 * file by one with the best controls so far u in /control, the history so
 * far in /optimizer, root attribute stop_reason and /optimizer's status
 * "running" (doc/output.md); what a killed optimisation leaves.  MRVI_EIO
 * with a message when it cannot be written (the optimisation may go on:
 * close writes the whole file again). */
int mrvi_ocp_output_progress(mrvi_ocp_output *w, const double *u, char *msg,
                             size_t len);
/* Write the file for the controls u (o's last evaluation is theirs) and
 * the result res; status is /optimizer's attribute status (res->status:
 * "converged", "max_evaluations", "interrupted", ...).  Frees w (also on
 * failure); NULL is accepted. */
int mrvi_ocp_output_close(mrvi_ocp_output *w, const double *u,
                          const mrvi_ocp_result *res, const char *status,
                          char *msg, size_t len);

/* ---------------------------------------------------------------------------
 * `mrvi batch` (batch_writer.c; doc/batch.md).  The plan and the results
 * live here because the master file stores them; src/batch builds and runs
 * them.
 * ------------------------------------------------------------------------- */

/* The `batch:` section of a description file (io/loader/batch.c): what
 * the command line of `mrvi batch` says, in the file.  Absent entries are
 * -1 (zip, seeds, jobs, command, position_uniform, rotation_uniform) or
 * NAN (the stds and temperature). */
typedef struct mrvi_batch_section {
  int n_vary;
  char **vary;  /* n_vary: "KEY=VALUES" as --vary takes it */
  char **where; /* n_vary: "file:line:col" of the entry, for messages */
  int zip, seeds, jobs;
  int command; /* MRVI_BATCH_RUN or MRVI_BATCH_OPTIMIZE; -1 absent */
  double velocity_std, control_std, position_std, temperature, rotation_std;
  int position_uniform, rotation_uniform; /* -1 absent */
} mrvi_batch_section;
/* Read the `batch:` section of sys's description (every key, type and
 * range checked: "file:line:col: message" otherwise); no section: n_vary
 * 0 and every entry absent. */
int mrvi_batch_section_read(const mrvi_system *sys, mrvi_batch_section *out,
                            char *msg, size_t len);
void mrvi_batch_section_free(mrvi_batch_section *sec); /* contents; NULL ok */

/* A case's status in the master table. */
enum {
  MRVI_BATCH_PENDING = 0,   /* not run yet (or killed while running) */
  MRVI_BATCH_COMPLETED = 1, /* the run completed */
  MRVI_BATCH_FAILED = 2     /* it ran and stopped: stop_reason says why */
};
#define MRVI_BATCH_REASON_BYTES 1024
/* What a case is. */
enum {
  MRVI_BATCH_RUN = 0,     /* `mrvi run` */
  MRVI_BATCH_OPTIMIZE = 1 /* `mrvi optimize` (multi-start: control_std) */
};

/* The perturbations of a seeded case (doc/batch.md, Ensembles); 0: none. */
typedef struct mrvi_batch_perturb {
  double velocity_std;  /* v0_i += std z_i */
  double control_std;   /* optimize: the guess u_j += std z_j (in bounds) */
  double position_std;  /* translational q0 += std z (particles, bodies'
                         * centres, plain coordinates), projected */
  int position_uniform; /* uniform numbers of that std instead of z */
  double temperature;   /* > 0: thermal velocities of that temperature,
                         * zero net momentum of particles and bodies
                         * (replace v0) */
  double rotation_std;  /* > 0: each body turned by a rotation vector of
                         * that std per component (radians) */
  int rotation_uniform; /* 1: each body turned uniformly on SO(D) */
} mrvi_batch_perturb;

/* The case table: case c is the description with the overrides
 * keys[j]=values[c * n_keys + j] and, when seed[c] >= 0, the initial
 * state (and for an optimize case the guess) perturbed by seed seed[c]
 * as pert says. */
typedef struct mrvi_batch_plan {
  char *description; /* the input text (before overrides) */
  char *source;      /* the file it came from (messages, root attribute) */
  int n_keys;
  char **keys; /* n_keys */
  int n_cases;
  char **values;           /* n_cases x n_keys, row-major */
  long *seed;              /* n_cases; -1: no perturbation */
  int n_seeds;             /* --seeds (0: none) */
  int command;             /* MRVI_BATCH_RUN or MRVI_BATCH_OPTIMIZE */
  mrvi_batch_perturb pert; /* of the seeded cases */
  /* settings.threads of every case's run (0: the settings' own), chosen by
   * the command line for its jobs; packed with the plan for the other MPI
   * ranks, not written to the master file */
  int threads;
} mrvi_batch_plan;
void mrvi_batch_plan_free(mrvi_batch_plan *plan); /* the contents; NULL ok */

/* What a case's run gave: a row of the table. */
typedef struct mrvi_batch_result {
  int c;      /* case index */
  int status; /* MRVI_BATCH_COMPLETED or MRVI_BATCH_FAILED */
  int rank;   /* the MPI rank that ran it (0 without MPI; not in the table) */
  long steps; /* macro steps completed */
  double wall_time, energy_error; /* s; max rel. energy error (mrvi_summary) */
  /* optimize cases (NAN, 0, "" for runs): the cost and largest terminal
   * violation at the returned controls, cost + gradient evaluations, and
   * NLopt's stop reason (mrvi_ocp_result). */
  double cost, violation;
  int evaluations;
  char nlopt[48];
  char reason[MRVI_BATCH_REASON_BYTES]; /* stop reason ("completed") */
} mrvi_batch_result;

/* The run file of case c of the batch whose master file is `master`:
 * "STEM.cases/case_CCCC.h5" beside it (STEM: master without ".h5").
 * relative: the name from the master's directory (the external link's
 * target), else the path to open.  MRVI_EINVAL when it does not fit. */
int mrvi_batch_case_file(const char *master, int c, int relative, char *buf,
                         size_t len);

/* The master file, open for writing rows. */
typedef struct mrvi_batch_file mrvi_batch_file;

/* Create the master file for plan (every case pending, external links
 * /runs/case_CCCC to the case files) and the case folder. */
int mrvi_batch_file_create(const char *path, const mrvi_batch_plan *plan,
                           mrvi_batch_file **out, char *msg, size_t len);
/* Reopen a master file for writing rows and, unless plan is NULL (for
 * --resume), read its plan and each case's status (*status: n_cases
 * entries, malloc'd). */
int mrvi_batch_file_open(const char *path, mrvi_batch_plan *plan, int **status,
                         mrvi_batch_file **out, char *msg, size_t len);
/* Write the row of res->c and flush the file: rows are raw data of
 * fixed-size datasets allocated at creation, so a row written is on disk
 * and a batch killed at any instant leaves a readable table. */
int mrvi_batch_file_row(mrvi_batch_file *f, const mrvi_batch_result *res,
                        char *msg, size_t len);
/* An optimize batch: the completed case of lowest cost (-1: none) into
 * *best and the master file's /best_case (written in place, as a row);
 * a run batch: *best = -1, nothing written. */
int mrvi_batch_file_best(mrvi_batch_file *f, int *best, double *cost, char *msg,
                         size_t len);
/* Close; NULL is accepted. */
int mrvi_batch_file_close(mrvi_batch_file *f, char *msg, size_t len);

#endif
