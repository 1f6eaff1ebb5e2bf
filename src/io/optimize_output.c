/* The HDF5 output of `mrvi optimize` and its replay (doc/output.md,
 * doc/optimal-control.md):
 *
 *   the trajectory of the controls   layout of `mrvi run` (/macro, /micro),
 *                                    through the run writer (hdf5_writer.c)
 *   root attribute solver            the forward pass's step solver path
 *   /control                         t, u on the finest grid of the
 *                                    actuators; actuators; terminal
 *                                    conditions
 *   /optimizer                       history (cost, violation, gradient
 *                                    norm, KKT residual per evaluation),
 *                                    result
 *
 * and the controls read back from /control/u (`mrvi run --controls`).
 *
 * mrvi_ocp_output_open checks the path before the optimisation starts:
 * the file can be created (or is an earlier mrvi output), is not locked by
 * a live writer, and its directory takes the temporary file of the
 * crash-safe write; so a read-only target or a locked file fails at once.
 * The lock is not held during the optimisation (the run writer takes it
 * again at close), so a writer starting on the same path meanwhile is
 * found only at close.
 *
 * While optimising, mrvi_ocp_output_progress replaces the file, at most
 * every output.flush_interval seconds (the first evaluation at once), by a
 * progress file: the best controls so far in /control, the history so far
 * in /optimizer, status "running" there and root stop_reason "running", no
 * trajectory; each built under a temporary name and renamed to the path.
 * The first one, with the initial controls and no history row, is
 * written before the optimiser starts (mrvi_ocp_output_start).  So a
 * process killed (SIGKILL) at any instant after that leaves the last
 * progress file, which `mrvi run --controls` replays and mrvi-plot
 * optimize draws as incomplete.
 * At close the trajectory is written crash-safe by the run writer (again
 * a rename over the path); the solver attribute, /control and /optimizer
 * are added after it closed, in a second open of the file, so one killed
 * in that second open may leave a trajectory without /control.  That
 * second open also turns the run writer's root stop_reason "completed" (the
 * replay's, kept as replay_stop_reason) into the optimisation's outcome
 * (write_stop_reason).  SIGINT and SIGTERM are turned into status
 * interrupted by the caller (cli_optimize.c). */
#include "io/h5util.h"
#include "io/io.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define PROGRESS_SECONDS 2.0 /* default of output.flush_interval (as run) */

/* ---------------------------------------------------------------------------
 * The trajectory
 * ------------------------------------------------------------------------- */

/* Macro node k of o's last evaluation as a record of the run writer: the
 * node, its energies and momenta, the micro nodes it completes (t_0 at
 * k = 0, else m = 1..p of step k-1) and, with constraints, the multipliers
 * of step k-1 and the residuals.  lam, g: n_lambda each; cres0: the
 * residual of node 0. */
static void node_record(const mrvi_system *sys, const mrvi_ocp *o, long k,
                        double *lam, double *g, double *cres0, mrvi_record *r) {
  const mrvi_model *m = sys->model;
  const int n = mrvi_model_n(m), nr = mrvi_model_constraint_rows(m);
  const int nf = mrvi_model_n_fast(m), p = sys->settings.micro_steps;
  const double dT = sys->settings.macro_step, dt = dT / p;
  memset(r, 0, sizeof *r);
  r->k = k;
  r->t = k * dT;
  r->q = mrvi_ocp_q(o) + k * n;
  r->p = mrvi_ocp_p(o) + k * n;
  mrvi_model_energy(m, r->q, r->p, &r->kinetic, &r->potential_slow,
                    &r->potential_fast);
  r->energy = r->kinetic + r->potential_slow + r->potential_fast;
  mrvi_model_momentum(m, r->q, r->p, r->linear_momentum, r->angular_momentum);
  const long first = k == 0 ? 0 : (k - 1) * p + 1;
  r->micro_count = k == 0 ? 1 : p;
  r->micro_t0 = first * dt;
  r->micro_dt = dt;
  r->micro_q_fast = mrvi_ocp_micro_q(o) + first * nf;
  r->micro_p_fast = mrvi_ocp_micro_p(o) + first * nf;
  r->n_lambda = nr;
  if (nr == 0)
    return;
  if (k >= 1) {
    mrvi_ocp_lambda(o, k - 1, lam);
    r->lambda_prev = lam;
    r->micro_constraint_residual =
        mrvi_ocp_micro_constraint_residual(o) + (k - 1) * p;
    for (int j = 0; j < p; j++)
      r->constraint_residual =
          fmax(r->constraint_residual, r->micro_constraint_residual[j]);
  } else {
    mrvi_model_constraint_eval(m, r->q, g, NULL);
    for (int i = 0; i < nr; i++)
      *cres0 = fmax(*cres0, fabs(g[i]));
    r->constraint_residual = *cres0;
    r->micro_constraint_residual = cres0;
  }
  r->hidden_constraint_residual = mrvi_model_hidden_residual(m, r->q, r->p);
}

/* The trajectory through the run writer: macro nodes and, with
 * output.micro, the fast coordinates at every micro node. */
static int write_trajectory(const char *path, const mrvi_system *sys,
                            const mrvi_ocp *o, char *msg, size_t len) {
  const mrvi_model *m = sys->model;
  mrvi_writer_options opt = {
      .system_name = sys->name ? sys->name : mrvi_model_name(m),
      .description = sys->description,
      .every = 1,
      .micro = sys->output_micro,
      .micro_slow = sys->output_micro_slow,
  };
  mrvi_writer *w = NULL;
  int st = mrvi_writer_open(path, m, &sys->settings, &opt, &w, msg, len);
  if (st < 0)
    return st;
  const int nr = mrvi_model_constraint_rows(m);
  double *lam = calloc((size_t)(nr > 0 ? nr : 1), sizeof *lam);
  double *g = calloc((size_t)(nr > 0 ? nr : 1), sizeof *g);
  double cres0 = 0.0;
  if (!lam || !g)
    st = mrvi_fail(msg, len, MRVI_ENOMEM, "%s: out of memory", path);
  const long N = mrvi_ocp_n_steps(o);
  for (long k = 0; k <= N && st == 0; k++) {
    mrvi_record r;
    node_record(sys, o, k, lam, g, &cres0, &r);
    st = mrvi_writer_observe(w, &r);
  }
  free(lam);
  free(g);
  char cmsg[512] = "";
  const int cst = mrvi_writer_close(w, st ? "writing failed" : "completed",
                                    cmsg, sizeof cmsg);
  if (st == 0 && cst < 0) {
    mrvi_fmt(msg, len, "%s", cmsg);
    st = cst;
  }
  return st;
}

/* ---------------------------------------------------------------------------
 * Adding to the closed trajectory file
 * ------------------------------------------------------------------------- */
typedef struct addition {
  mrvi_h5_batch b;
  mrvi_h5_quiet q;
} addition;

/* Open the closed file again; add_close follows, also on failure. */
static int add_open(addition *a, const char *path, char *msg, size_t len) {
  *a = (addition){.b = {.path = path, .msg = msg, .len = len}};
  mrvi_h5_quiet_begin(&a->q);
  a->b.file = H5Fopen(path, H5F_ACC_RDWR, H5P_DEFAULT);
  return a->b.file < 0 ? mrvi_h5_batch_fail(&a->b, "cannot open the file") : 0;
}

static int add_close(addition *a) {
  if (a->b.file >= 0 && H5Fclose(a->b.file) < 0)
    mrvi_h5_batch_fail(&a->b, "closing the file");
  H5Eclear2(H5E_DEFAULT);
  mrvi_h5_quiet_end(&a->q);
  return a->b.status;
}

/* Fixed-length ASCII string attribute of the string's length. */
static void attr_text(mrvi_h5_batch *b, hid_t loc, const char *name,
                      const char *value) {
  if (b->status == 0 && mrvi_h5_attr_fixed(loc, name, value, strlen(value) + 1,
                                           H5T_CSET_ASCII) < 0)
    mrvi_h5_batch_fail(b, name);
}

/* Dataset `name` of loc: n fixed-length strings. */
static void strings(mrvi_h5_batch *b, hid_t loc, const char *name,
                    const char **v, hsize_t n) {
  if (b->status == 0 &&
      mrvi_h5_write_strings(loc, name, H5P_DEFAULT, v, n, 0, NULL) < 0)
    mrvi_h5_batch_fail(b, name);
}

/* Root attribute "solver": the step solver path of the forward pass (the
 * run writer wrote the integrator's, which pair actuators change to
 * general), fixed-length. */
static void write_solver_path(mrvi_h5_batch *b, const mrvi_ocp *o) {
  const char *path = mrvi_ocp_solver_path(o, NULL, 0);
  if (b->status == 0 && H5Aexists(b->file, "solver") > 0 &&
      H5Adelete(b->file, "solver") < 0)
    mrvi_h5_batch_fail(b, "solver");
  attr_text(b, b->file, "solver", path ? path : "none");
}

int mrvi_ocp_trajectory_write(const char *path, const mrvi_system *sys,
                              const mrvi_ocp *o, char *msg, size_t len) {
  int st = write_trajectory(path, sys, o, msg, len);
  if (st < 0)
    return st;
  addition a;
  if (add_open(&a, path, msg, len) == 0)
    write_solver_path(&a.b, o);
  return add_close(&a);
}

/* ---------------------------------------------------------------------------
 * /control and /optimizer
 * ------------------------------------------------------------------------- */
struct mrvi_ocp_output {
  char *path;
  const mrvi_system *sys;
  const mrvi_ocp *o;
  int n, cap;
  double *history;    /* n x 4: cost, violation, gradient norm, KKT residual */
  double snapshot_at; /* mrvi_clock of the last progress file */
};

/* /control/terminal_attitude: R_target of every attitude row (row-major
 * D x D per row, NaN on the rows of other kinds), when there is one, so
 * that the targets of a run are in its file even where --set changed the
 * description's. */
static void write_attitudes(mrvi_h5_batch *b, hid_t gc, const mrvi_ocp *o) {
  const int nterm = mrvi_ocp_n_terminals(o);
  int D = 0;
  double R[9];
  for (int i = 0; i < nterm && !D; i++)
    D = mrvi_ocp_terminal_attitude(o, i, R);
  if (!D)
    return;
  const size_t dd = (size_t)(D * D);
  double *v = malloc((size_t)nterm * dd * sizeof *v);
  if (!v) {
    mrvi_h5_batch_fail_text(b, MRVI_ENOMEM, "out of memory");
    return;
  }
  for (int i = 0; i < nterm; i++)
    if (!mrvi_ocp_terminal_attitude(o, i, v + (size_t)i * dd))
      for (size_t k = 0; k < dd; k++)
        v[(size_t)i * dd + k] = NAN;
  mrvi_h5_batch_doubles(b, gc, "terminal_attitude", v, (hsize_t)nterm,
                        (hsize_t)dd);
  free(v);
}

/* /control: t and u on the finest grid of the actuators (the micro grid if
 * any actuator is on it), per actuator its name, grid, coordinate and pair,
 * per terminal condition its coordinate, kind, target and penalty (for
 * mrvi-plot optimize). */
static void write_control(mrvi_h5_batch *b, const mrvi_system *sys,
                          const mrvi_ocp *o, const double *u) {
  const int na = mrvi_ocp_n_actuators(o), nterm = mrvi_ocp_n_terminals(o);
  const long N = mrvi_ocp_n_steps(o);
  int p = 1;
  for (int k = 0; k < na; k++)
    if (mrvi_ocp_actuator_grid(o, k) == MRVI_GRID_MICRO)
      p = sys->settings.micro_steps;
  const long nt = N * p;
  const double h_t = sys->settings.macro_step / p;
  const int nmax = na > nterm ? na : nterm;
  double *t = malloc(((size_t)nt + 1) * sizeof *t);
  double *U = malloc(((size_t)nt * (size_t)na + 1) * sizeof *U);
  const char **sv = malloc((size_t)(nmax + 1) * sizeof *sv);
  int *iv = malloc((size_t)(2 * nmax + 1) * sizeof *iv);
  double *tv = malloc((size_t)(2 * nterm + 1) * sizeof *tv);
  hid_t gc = H5I_INVALID_HID;
  if (!t || !U || !sv || !iv || !tv) {
    mrvi_h5_batch_fail_text(b, MRVI_ENOMEM, "out of memory");
    goto out;
  }
  for (long j = 0; j < nt; j++) {
    t[j] = j * h_t;
    for (int k = 0; k < na; k++) {
      const int micro = mrvi_ocp_actuator_grid(o, k) == MRVI_GRID_MICRO;
      U[j * na + k] = u[mrvi_ocp_actuator_offset(o, k) + (micro ? j : j / p)];
    }
  }
  gc = mrvi_h5_batch_group(b, b->file, "control");
  mrvi_h5_batch_doubles(b, gc, "t", t, (hsize_t)nt, 0);
  mrvi_h5_batch_doubles(b, gc, "u", U, (hsize_t)nt, (hsize_t)na);
  for (int k = 0; k < na; k++)
    sv[k] = mrvi_ocp_actuator_name(o, k);
  strings(b, gc, "names", sv, (hsize_t)na);
  for (int k = 0; k < na; k++) {
    sv[k] = mrvi_ocp_actuator_grid(o, k) == MRVI_GRID_MICRO ? "micro" : "macro";
    iv[k] = mrvi_ocp_actuator_coordinate(o, k);
  }
  strings(b, gc, "actuator_grid", sv, (hsize_t)na);
  mrvi_h5_batch_ints(b, gc, "actuator_coordinate", iv, (hsize_t)na, 0);
  for (int k = 0; k < na; k++)
    mrvi_ocp_actuator_pair(o, k, &iv[2 * k], &iv[2 * k + 1]);
  mrvi_h5_batch_ints(b, gc, "actuator_pair", iv, (hsize_t)na, 2);
  for (int i = 0; i < nterm; i++) {
    mrvi_ocp_terminal_kind kind;
    mrvi_ocp_terminal(o, i, &kind, &iv[i], &tv[i], &tv[nterm + i]);
    sv[i] = mrvi_ocp_terminal_kind_name(kind);
  }
  mrvi_h5_batch_ints(b, gc, "terminal_coordinate", iv, (hsize_t)nterm, 0);
  strings(b, gc, "terminal_kind", sv, (hsize_t)nterm);
  mrvi_h5_batch_doubles(b, gc, "terminal_target", tv, (hsize_t)nterm, 0);
  mrvi_h5_batch_doubles(b, gc, "terminal_penalty", tv + nterm, (hsize_t)nterm,
                        0);
  write_attitudes(b, gc, o);
  attr_text(b, gc, "grid", p > 1 ? "micro" : "macro");
out:
  if (gc >= 0)
    H5Gclose(gc);
  free(t);
  free(U);
  free(sv);
  free(iv);
  free(tv);
}

/* /optimizer: the history and the result. */
static void write_optimizer(mrvi_h5_batch *b, const mrvi_ocp_output *w,
                            const mrvi_ocp_result *res, const char *status) {
  const mrvi_ocp *o = w->o;
  hid_t go = mrvi_h5_batch_group(b, b->file, "optimizer");
  mrvi_h5_batch_doubles(b, go, "history", w->history, (hsize_t)w->n, 4);
  attr_text(b, go, "columns", "cost, violation, gradient_norm, kkt_residual");
  attr_text(b, go, "algorithm",
            mrvi_ocp_algorithm_name(mrvi_ocp_get_algorithm(o)));
  attr_text(b, go, "status", status);
  if (res) {
    attr_text(b, go, "nlopt_result", res->nlopt_name);
    mrvi_h5_batch_attr_double(b, go, "cost", res->cost);
    mrvi_h5_batch_attr_double(b, go, "terminal_violation", res->violation);
  }
  mrvi_h5_batch_attr_double(b, go, "terminal_tolerance",
                            mrvi_ocp_terminal_tolerance(o));
  mrvi_h5_batch_attr_double(b, go, "evaluations",
                            res ? res->evaluations : w->n);
  if (go >= 0)
    H5Gclose(go);
}

/* Root attributes stop_reason and replay_stop_reason of the closed file
 * (doc/output.md, "Optimal control"): the run writer closed the trajectory
 * of the returned controls with stop_reason "completed", which is the
 * replay's own outcome and is kept as replay_stop_reason; stop_reason
 * becomes the optimisation's: "completed" only when it converged, else
 * its status ("interrupted", "max_evaluations", ...), so that a reader of
 * the root alone does not take a stopped optimisation for a finished one.
 * Variable-length UTF-8, as the run writer writes a closed run's. */
static void write_stop_reason(mrvi_h5_batch *b, const char *status) {
  const char *reason = strcmp(status, "converged") ? status : "completed";
  if (b->status == 0 &&
      (H5Aexists(b->file, "stop_reason") <= 0 ||
       H5Adelete(b->file, "stop_reason") < 0 ||
       mrvi_h5_attr_string(b->file, "stop_reason", reason) < 0 ||
       mrvi_h5_attr_string(b->file, "replay_stop_reason", "completed") < 0))
    mrvi_h5_batch_fail(b, "stop_reason");
}

int mrvi_ocp_output_open(const char *path, const mrvi_system *sys,
                         const mrvi_ocp *o, mrvi_ocp_output **out, char *msg,
                         size_t len) {
  mrvi_fmt(msg, len, "%s", "");
  if (!out)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "mrvi_ocp_output_open: no result pointer");
  *out = NULL;
  if (!path || !path[0] || !sys || !o)
    return mrvi_fail(msg, len, MRVI_EINVAL, "mrvi_ocp_output_open: %s",
                     !sys ? "no system"
                     : !o ? "no problem"
                          : "no file name");
  /* The path as the run writer will take it: lock (creating the file when
   * absent), then a temporary file beside it; both undone. */
  int fd = -1, created = 0;
  char why[400];
  int st = mrvi_h5_lock_output(path, 0, &fd, &created, why, sizeof why);
  if (st == 0) {
    char *part = NULL;
    st = mrvi_h5_part_create(path, &part, why, sizeof why);
    if (part)
      unlink(part);
    free(part);
  }
  if (fd >= 0)
    close(fd);
  if (created)
    unlink(path);
  if (st < 0)
    return mrvi_fail(msg, len, st, "%s: %s", path, why);
  mrvi_ocp_output *w = calloc(1, sizeof *w);
  if (w)
    w->path = strdup(path);
  if (!w || !w->path) {
    free(w);
    return mrvi_fail(msg, len, MRVI_ENOMEM, "%s: out of memory", path);
  }
  w->sys = sys;
  w->o = o;
  w->snapshot_at = -HUGE_VAL;
  *out = w;
  return MRVI_OK;
}

int mrvi_ocp_output_iteration(mrvi_ocp_output *w, double cost, double violation,
                              double gradient_norm, double kkt_residual) {
  if (!w)
    return MRVI_EINVAL;
  if (w->n == w->cap) {
    int cap = w->cap ? 2 * w->cap : 64;
    double *r = realloc(w->history, (size_t)cap * 4 * sizeof *r);
    if (!r)
      return MRVI_ENOMEM;
    w->history = r;
    w->cap = cap;
  }
  w->history[4 * w->n] = cost;
  w->history[4 * w->n + 1] = violation;
  w->history[4 * w->n + 2] = gradient_norm;
  w->history[4 * w->n + 3] = kkt_residual;
  w->n++;
  return MRVI_OK;
}

/* The progress file: root attributes mrvi_version, system, micro_steps,
 * macro_step, solver and stop_reason "running", /control with the best
 * controls so far and /optimizer with the history and status "running";
 * built under a temporary name beside the path and renamed to it
 * (h5util.c), so that a process killed at any instant leaves the last
 * complete one. */
static int write_progress(mrvi_ocp_output *w, const double *u, char *msg,
                          size_t len) {
  int fd = -1, created = 0;
  char *part = NULL;
  int st = mrvi_h5_lock_output(w->path, 0, &fd, &created, msg, len);
  if (st == 0)
    st = mrvi_h5_part_create(w->path, &part, msg, len);
  if (st == 0) {
    mrvi_h5_batch b = {.path = part, .msg = msg, .len = len};
    mrvi_h5_quiet q;
    mrvi_h5_quiet_begin(&q);
    b.file = H5Fcreate(part, H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    if (b.file < 0) {
      mrvi_h5_batch_fail(&b, "cannot create the file");
    } else {
      const mrvi_system *sys = w->sys;
      attr_text(&b, b.file, "mrvi_version", MRVI_VERSION);
      attr_text(&b, b.file, "system",
                sys->name ? sys->name : mrvi_model_name(sys->model));
      mrvi_h5_batch_attr_int(&b, b.file, "micro_steps",
                             sys->settings.micro_steps);
      mrvi_h5_batch_attr_double(&b, b.file, "macro_step",
                                sys->settings.macro_step);
      attr_text(&b, b.file, "stop_reason", "running");
      write_solver_path(&b, w->o);
      write_control(&b, sys, w->o, u);
      write_optimizer(&b, w, NULL, "running");
      if (H5Fclose(b.file) < 0)
        mrvi_h5_batch_fail(&b, "closing the file");
    }
    H5Eclear2(H5E_DEFAULT);
    mrvi_h5_quiet_end(&q);
    st = b.status;
  }
  if (st == 0)
    st = mrvi_h5_part_commit(part, w->path, &fd, msg, len);
  else if (part)
    unlink(part);
  free(part);
  if (fd >= 0)
    close(fd);
  if (st < 0 && created)
    unlink(w->path);
  return st;
}

int mrvi_ocp_output_progress(mrvi_ocp_output *w, const double *u, char *msg,
                             size_t len) {
  mrvi_fmt(msg, len, "%s", "");
  if (!w || !u)
    return MRVI_OK;
  const double interval = w->sys->output_flush_interval > 0
                              ? w->sys->output_flush_interval
                              : PROGRESS_SECONDS;
  const double now = mrvi_clock();
  if (now - w->snapshot_at < interval)
    return MRVI_OK;
  w->snapshot_at = now;
  return write_progress(w, u, msg, len);
}

int mrvi_ocp_output_start(mrvi_ocp_output *w, const double *u0, char *msg,
                          size_t len) {
  mrvi_fmt(msg, len, "%s", "");
  if (!w || !u0)
    return MRVI_OK;
  return write_progress(w, u0, msg, len);
}

int mrvi_ocp_output_close(mrvi_ocp_output *w, const double *u,
                          const mrvi_ocp_result *res, const char *status,
                          char *msg, size_t len) {
  mrvi_fmt(msg, len, "%s", "");
  if (!w)
    return MRVI_OK;
  int st = MRVI_EINVAL;
  if (!u || !res || !status)
    mrvi_fmt(msg, len, "mrvi_ocp_output_close: no %s",
             !u     ? "controls"
             : !res ? "result"
                    : "status");
  else
    st = write_trajectory(w->path, w->sys, w->o, msg, len);
  if (st == 0) {
    addition a;
    if (add_open(&a, w->path, msg, len) == 0) {
      write_solver_path(&a.b, w->o);
      write_control(&a.b, w->sys, w->o, u);
      write_optimizer(&a.b, w, res, status);
      write_stop_reason(&a.b, status);
    }
    st = add_close(&a);
  }
  free(w->history);
  free(w->path);
  free(w);
  return st;
}

/* ---------------------------------------------------------------------------
 * Replay: the stored controls
 * ------------------------------------------------------------------------- */
int mrvi_ocp_controls_read(const char *path, const mrvi_ocp *o, int micro_steps,
                           double *u, char *msg, size_t len) {
  mrvi_h5_quiet q;
  mrvi_h5_quiet_begin(&q);
  hid_t f = mrvi_h5_open_read(path, H5P_DEFAULT);
  const mrvi_h5in in = {f, path, msg, len};
  const int na = mrvi_ocp_n_actuators(o);
  const long N = mrvi_ocp_n_steps(o);
  /* Rows: one per macro step, or one per micro step when an actuator of
   * the run that stored them was on the micro grid (as written above). */
  const hsize_t most =
      (hsize_t)N * (hsize_t)(micro_steps > 1 ? micro_steps : 1);
  const hsize_t want[2] = {MRVI_H5_ANY, (hsize_t)na};
  hsize_t dims[2] = {0, 0};
  double *U = NULL;
  int st = MRVI_OK;
  if (f < 0)
    st = mrvi_fail(msg, len, MRVI_EIO,
                   "%s: cannot open as an HDF5 file (missing or not HDF5)",
                   path);
  else if ((st = mrvi_h5in_shape(&in, "/control/u", MRVI_H5_NUMBER, 2, want,
                                 dims)) < 0)
    ;
  else if (N < 1 || (dims[0] != (hsize_t)N && dims[0] != most))
    st = mrvi_fail(msg, len, MRVI_EIO,
                   "%s: /control/u has %llu rows, expected %ld (one per "
                   "macro step) or %llu (one per micro step)",
                   path, (unsigned long long)dims[0], N,
                   (unsigned long long)most);
  else
    st = mrvi_h5in_read_new(&in, "/control/u", H5T_NATIVE_DOUBLE, 2, dims,
                            MRVI_H5_ANY, (void **)&U, NULL);
  const long pt = st == MRVI_OK ? (long)dims[0] / N : 0;
  for (int a = 0; a < na && st == MRVI_OK; a++) {
    const int micro = mrvi_ocp_actuator_grid(o, a) == MRVI_GRID_MICRO;
    const int size = mrvi_ocp_actuator_size(o, a);
    const hsize_t need = micro ? (hsize_t)size : (hsize_t)size * (hsize_t)pt;
    if ((micro && (hsize_t)size != dims[0]) || need > dims[0])
      st = mrvi_fail(msg, len, MRVI_EIO,
                     "%s: actuator '%s' needs %d values, /control/u has %llu",
                     path, mrvi_ocp_actuator_name(o, a), size,
                     (unsigned long long)dims[0]);
    /* The values the problem admits: finite and within the actuator's
     * bounds (a crafted or edited file, or a description whose bounds
     * changed since; mrvi optimize stores values within them).  Before
     * round 17 a NaN failed the run's first step, not naming the file, and
     * a value beyond the bounds was replayed. */
    double lo = -HUGE_VAL, hi = HUGE_VAL;
    mrvi_ocp_actuator_bounds(o, a, &lo, &hi);
    for (int j = 0; st == MRVI_OK && j < size; j++) {
      const long row = micro ? j : (long)j * pt;
      const double v = U[row * na + a];
      if (isfinite(v) && v >= lo && v <= hi)
        u[mrvi_ocp_actuator_offset(o, a) + j] = v;
      else
        st = mrvi_fail(msg, len, MRVI_EIO,
                       "%s: /control/u[%ld, %d] = %.17g: actuator '%s' takes "
                       "finite values in [%g, %g]",
                       path, row, a, v, mrvi_ocp_actuator_name(o, a), lo, hi);
    }
  }
  free(U);
  if (f >= 0)
    H5Fclose(f);
  mrvi_h5_quiet_end(&q);
  return st;
}
