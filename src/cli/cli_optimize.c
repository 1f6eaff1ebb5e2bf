/* mrvi optimize FILE [-o OUT.h5] [--set KEY=VALUE]... [--quiet]
 *
 * Optimal control (doc/optimal-control.md): read the system and its
 * `control:` section, optimise the controls with NLopt (single shooting,
 * exact discrete adjoint), print a line per iteration and a summary, and
 * write the optimal trajectory (layout of `mrvi run`, /micro included)
 * plus /control and /optimizer to HDF5 (doc/output.md).
 * Exit status: 0 optimum found with the terminal conditions met, 1 bad
 * input, 2 the optimiser failed or the terminal conditions are not met. */
#include "io/h5util.h"
#include "internal.h"
#include "ocp/ocp.h"

#include <hdf5.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

const char mrvi_usage_optimize[] =
    "Usage: mrvi optimize FILE [-o OUT.h5] [--set KEY=VALUE]... [--quiet]\n"
    "\n"
    "Solve the optimal control problem of the `control:` section of FILE\n"
    "(multirate DMOC: discrete Lagrange-d'Alembert on the integrator's\n"
    "discrete Lagrangian, single shooting, exact discrete adjoint, NLopt).\n"
    "Prints one line per evaluation (cost, largest terminal violation,\n"
    "gradient norm) and a summary; writes the optimal trajectory (/macro\n"
    "and /micro, as `mrvi run` writes them), /control and /optimizer to\n"
    "OUT.h5 (default: output.file with '.h5' replaced by '_opt.h5').\n"
    "Figures: src/cli/mrvi-plot optimize OUT.h5 -o DIR (controls, trajectory,\n"
    "optimiser history).\n"
    "\n"
    "Options:\n"
    "  -o, --output OUT.h5    output file\n"
    "  -s, --set KEY=VALUE    override a key of the description\n"
    "  -q, --quiet            no per-iteration lines\n"
    "  -h, --help             show this help\n"
    "\n"
    "Replay: `mrvi run FILE --controls OPT.h5 [-o OUT.h5]` runs the stored\n"
    "controls /control/u of OPT.h5 through the discrete equations of FILE,\n"
    "writes the trajectory and checks the terminal conditions.\n"
    "\n"
    "Exit status: 0 success, 1 invalid input, 2 the optimiser failed or the\n"
    "terminal conditions are not met to control.solver.terminal_tolerance.\n";

typedef struct history {
  int n, cap, quiet;
  double *rows; /* n x 3: cost, violation, gradient norm */
} history;

static int on_iteration(void *data, int it, double cost, double viol,
                        double gnorm) {
  history *h = data;
  if (h->n == h->cap) {
    int cap = h->cap ? 2 * h->cap : 64;
    double *r = realloc(h->rows, (size_t)cap * 3 * sizeof *r);
    if (!r)
      return 1;
    h->rows = r;
    h->cap = cap;
  }
  h->rows[3 * h->n] = cost;
  h->rows[3 * h->n + 1] = viol;
  h->rows[3 * h->n + 2] = gnorm;
  h->n++;
  if (!h->quiet) {
    printf("%5d  cost %.12e  violation %.3e  |grad| %.3e\n", it, cost, viol,
           gnorm);
    fflush(stdout);
  }
  return 0;
}

/* Trajectory in the `mrvi run` layout through the HDF5 writer: macro nodes
 * and, with output.micro, the fast coordinates at every micro node
 * (/micro, as `mrvi run` writes them). */
static int write_trajectory(const char *out, const mrvi_system *sys,
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
  int st = mrvi_writer_open(out, m, &sys->settings, &opt, &w, msg, len);
  if (st < 0)
    return st;
  const int n = mrvi_model_n(m), nr = mrvi_model_constraint_rows(m);
  const int nf = mrvi_model_n_fast(m), p = sys->settings.micro_steps;
  const double dT = sys->settings.macro_step, dt = dT / p;
  const long N = mrvi_ocp_n_steps(o);
  double *lam = calloc((size_t)(nr > 0 ? nr : 1), sizeof *lam);
  double *g = calloc((size_t)(nr > 0 ? nr : 1), sizeof *g);
  double cres0 = 0.0;
  for (long k = 0; k <= N && st == 0; k++) {
    mrvi_record r;
    memset(&r, 0, sizeof r);
    r.k = k;
    r.t = k * dT;
    r.q = mrvi_ocp_q(o) + k * n;
    r.p = mrvi_ocp_p(o) + k * n;
    mrvi_model_energy(m, r.q, r.p, &r.kinetic, &r.potential_slow,
                      &r.potential_fast);
    r.energy = r.kinetic + r.potential_slow + r.potential_fast;
    mrvi_model_momentum(m, r.q, r.p, r.linear_momentum, r.angular_momentum);
    /* Micro nodes this record completes: t_0 at k = 0, else m = 1..p of
     * step k-1. */
    const long first = k == 0 ? 0 : (k - 1) * p + 1;
    r.micro_count = k == 0 ? 1 : p;
    r.micro_t0 = first * dt;
    r.micro_dt = dt;
    r.micro_q_fast = mrvi_ocp_micro_q(o) + first * nf;
    r.micro_p_fast = mrvi_ocp_micro_p(o) + first * nf;
    r.n_lambda = nr;
    if (nr > 0) {
      if (k >= 1) {
        mrvi_ocp_lambda(o, k - 1, lam);
        r.lambda_prev = lam;
        r.micro_constraint_residual =
            mrvi_ocp_micro_constraint_residual(o) + (k - 1) * p;
        for (int j = 0; j < p; j++)
          r.constraint_residual =
              fmax(r.constraint_residual, r.micro_constraint_residual[j]);
      } else {
        mrvi_model_constraint_eval(m, r.q, g, NULL);
        for (int i = 0; i < nr; i++)
          cres0 = fmax(cres0, fabs(g[i]));
        r.constraint_residual = cres0;
        r.micro_constraint_residual = &cres0;
      }
      r.hidden_constraint_residual = mrvi_model_hidden_residual(m, r.q, r.p);
    }
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

static void attr_string(hid_t loc, const char *name, const char *value) {
  hid_t t = H5Tcopy(H5T_C_S1);
  H5Tset_size(t, strlen(value) + 1);
  hid_t sp = H5Screate(H5S_SCALAR);
  hid_t a = H5Acreate2(loc, name, t, sp, H5P_DEFAULT, H5P_DEFAULT);
  H5Awrite(a, t, value);
  H5Aclose(a);
  H5Sclose(sp);
  H5Tclose(t);
}

/* Root attribute "solver": the step solver path of the forward pass (the
 * writer has the integrator's, which pair actuators change to general). */
static int write_solver_path(const char *out, const mrvi_ocp *o, char *msg,
                             size_t len) {
  const char *path = mrvi_ocp_solver_path(o, NULL, 0);
  hid_t f = H5Fopen(out, H5F_ACC_RDWR, H5P_DEFAULT);
  const int rc = f < 0                        ? -1
                 : H5Aexists(f, "solver") > 0 ? H5Adelete(f, "solver")
                                              : 0;
  if (rc >= 0)
    attr_string(f, "solver", path ? path : "none");
  else
    mrvi_fmt(msg, len, "cannot set the attribute 'solver'");
  if (f >= 0)
    H5Fclose(f);
  return rc < 0 ? -1 : 0;
}

static void attr_double(hid_t loc, const char *name, double v) {
  hid_t sp = H5Screate(H5S_SCALAR);
  hid_t a =
      H5Acreate2(loc, name, H5T_NATIVE_DOUBLE, sp, H5P_DEFAULT, H5P_DEFAULT);
  H5Awrite(a, H5T_NATIVE_DOUBLE, &v);
  H5Aclose(a);
  H5Sclose(sp);
}

static int dataset(hid_t loc, const char *name, int rank, const hsize_t *dims,
                   const double *data) {
  hid_t sp = H5Screate_simple(rank, dims, NULL);
  hid_t d = H5Dcreate2(loc, name, H5T_NATIVE_DOUBLE, sp, H5P_DEFAULT,
                       H5P_DEFAULT, H5P_DEFAULT);
  herr_t e = d < 0 ? -1
                   : H5Dwrite(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL,
                              H5P_DEFAULT, data);
  if (d >= 0)
    H5Dclose(d);
  H5Sclose(sp);
  return d < 0 || e < 0 ? -1 : 0;
}

/* 1-D dataset of n variable-length strings. */
static int strings(hid_t loc, const char *name, int n, const char **v) {
  hid_t t = H5Tcopy(H5T_C_S1);
  H5Tset_size(t, H5T_VARIABLE);
  hsize_t dn[1] = {(hsize_t)n};
  hid_t sp = H5Screate_simple(1, dn, NULL);
  hid_t d = H5Dcreate2(loc, name, t, sp, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  const int rc =
      d < 0 || (n > 0 && H5Dwrite(d, t, H5S_ALL, H5S_ALL, H5P_DEFAULT, v) < 0)
          ? -1
          : 0;
  if (d >= 0)
    H5Dclose(d);
  H5Sclose(sp);
  H5Tclose(t);
  return rc;
}

/* int32 dataset of n rows and cols columns (cols 0: 1-D). */
static int ints(hid_t loc, const char *name, int n, int cols, const int *v) {
  hsize_t dn[2] = {(hsize_t)n, (hsize_t)cols};
  hid_t sp = H5Screate_simple(cols ? 2 : 1, dn, NULL);
  hid_t d = H5Dcreate2(loc, name, H5T_STD_I32LE, sp, H5P_DEFAULT, H5P_DEFAULT,
                       H5P_DEFAULT);
  const int rc = d < 0 || (n > 0 && H5Dwrite(d, H5T_NATIVE_INT, H5S_ALL,
                                             H5S_ALL, H5P_DEFAULT, v) < 0)
                     ? -1
                     : 0;
  if (d >= 0)
    H5Dclose(d);
  H5Sclose(sp);
  return rc;
}

/* /control (t, u on the finest grid of the actuators, names) and
 * /optimizer (history, attributes). */
static int write_control(const char *out, const mrvi_system *sys,
                         const mrvi_ocp *o, const double *u, const history *h,
                         const mrvi_ocp_result *res, int status) {
  hid_t f = H5Fopen(out, H5F_ACC_RDWR, H5P_DEFAULT);
  if (f < 0)
    return -1;
  const int na = mrvi_ocp_n_actuators(o);
  const long N = mrvi_ocp_n_steps(o);
  int p = 1;
  for (int a = 0; a < na; a++)
    if (mrvi_ocp_actuator_grid(o, a) == MRVI_GRID_MICRO)
      p = sys->settings.micro_steps;
  const long nt = N * p;
  const double h_t = sys->settings.macro_step / p;
  double *t = malloc((size_t)nt * sizeof *t);
  double *U = malloc((size_t)nt * (size_t)na * sizeof *U);
  int rc = -1;
  if (t && U) {
    for (long j = 0; j < nt; j++) {
      t[j] = j * h_t;
      for (int a = 0; a < na; a++) {
        const int micro = mrvi_ocp_actuator_grid(o, a) == MRVI_GRID_MICRO;
        U[j * na + a] = u[mrvi_ocp_actuator_offset(o, a) + (micro ? j : j / p)];
      }
    }
    hid_t gc = H5Gcreate2(f, "control", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    hsize_t d1[1] = {(hsize_t)nt}, d2[2] = {(hsize_t)nt, (hsize_t)na};
    rc = dataset(gc, "t", 1, d1, t) | dataset(gc, "u", 2, d2, U);
    /* Per actuator: name, grid, coordinate; per terminal condition:
     * coordinate, kind, target, penalty (for mrvi-plot optimize). */
    const int nterm = mrvi_ocp_n_terminals(o), nmax = na > nterm ? na : nterm;
    const char **sv = malloc((size_t)(nmax + 1) * sizeof *sv);
    int *iv = malloc((size_t)(2 * nmax + 1) * sizeof *iv);
    double *tv = malloc((size_t)(2 * nterm + 1) * sizeof *tv);
    if (sv && iv && tv) {
      for (int a = 0; a < na; a++)
        sv[a] = mrvi_ocp_actuator_name(o, a);
      rc |= strings(gc, "names", na, sv);
      for (int a = 0; a < na; a++) {
        sv[a] =
            mrvi_ocp_actuator_grid(o, a) == MRVI_GRID_MICRO ? "micro" : "macro";
        iv[a] = mrvi_ocp_actuator_coordinate(o, a);
      }
      rc |= strings(gc, "actuator_grid", na, sv) |
            ints(gc, "actuator_coordinate", na, 0, iv);
      for (int a = 0; a < na; a++)
        mrvi_ocp_actuator_pair(o, a, &iv[2 * a], &iv[2 * a + 1]);
      rc |= ints(gc, "actuator_pair", na, 2, iv);
      for (int i = 0; i < nterm; i++) {
        mrvi_ocp_terminal_kind kind;
        mrvi_ocp_terminal(o, i, &kind, &iv[i], &tv[i], &tv[nterm + i]);
        sv[i] = kind == MRVI_OCP_POSITION ? "position" : "velocity";
      }
      hsize_t dt1[1] = {(hsize_t)nterm};
      rc |= ints(gc, "terminal_coordinate", nterm, 0, iv) |
            strings(gc, "terminal_kind", nterm, sv) |
            dataset(gc, "terminal_target", 1, dt1, tv) |
            dataset(gc, "terminal_penalty", 1, dt1, tv + nterm);
    } else {
      rc = -1;
    }
    free(sv);
    free(iv);
    free(tv);
    attr_string(gc, "grid", p > 1 ? "micro" : "macro");
    H5Gclose(gc);
    hid_t go =
        H5Gcreate2(f, "optimizer", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    hsize_t dh[2] = {(hsize_t)h->n, 3};
    double none[3] = {0, 0, 0};
    rc |= dataset(go, "history", 2, dh, h->n ? h->rows : none);
    attr_string(go, "columns", "cost, violation, gradient_norm");
    attr_string(go, "algorithm",
                mrvi_ocp_algorithm_name(mrvi_ocp_get_algorithm(o)));
    attr_string(go, "status", status == 0 ? "converged" : "failed");
    attr_string(go, "nlopt_result", res->nlopt_name);
    attr_double(go, "cost", res->cost);
    attr_double(go, "terminal_violation", res->violation);
    attr_double(go, "terminal_tolerance", mrvi_ocp_terminal_tolerance(o));
    attr_double(go, "evaluations", res->evaluations);
    H5Gclose(go);
  }
  free(t);
  free(U);
  H5Fclose(f);
  return rc;
}

/* Default output: output.file with ".h5" -> "_opt.h5". */
/* `mrvi check`: the problem of the `control:` section, if any (actuators,
 * terminal conditions, algorithm).  Returns 0, or 1 when the section is
 * invalid (its message printed). */
int mrvi_cli_check_control(const mrvi_system *sys) {
  if (!mrvi_ocp_has_control(sys))
    return 0;
  char msg[2048];
  mrvi_ocp *o = NULL;
  double *u = NULL;
  if (mrvi_ocp_load(sys, &o, &u, msg, sizeof msg) < 0) {
    fprintf(stderr, "%s\n", msg);
    return 1;
  }
  const mrvi_model *m = sys->model;
  const int na = mrvi_ocp_n_actuators(o), nt = mrvi_ocp_n_terminals(o);
  printf("\n%-14s%d controls, %d terminal constraints, %s\n", "control",
         mrvi_ocp_n_controls(o), mrvi_ocp_n_constraints(o),
         mrvi_ocp_algorithm_name(mrvi_ocp_get_algorithm(o)));
  {
    char why[300] = "";
    const char *path = mrvi_ocp_solver_path(o, why, sizeof why);
    printf("%-14s%s: %s\n", "control path", path ? path : "none", why);
  }
  printf("%-14s%d\n", "actuators", na);
  for (int a = 0; a < na; a++) {
    const int c = mrvi_ocp_actuator_coordinate(o, a);
    char on[300];
    if (c >= 0) {
      snprintf(on, sizeof on, "on %s", mrvi_model_coordinate_name(m, c));
    } else {
      int pi, pj;
      mrvi_ocp_actuator_pair(o, a, &pi, &pj);
      snprintf(on, sizeof on, "pair %s - %s", m->particles[pi].name,
               m->particles[pj].name);
    }
    printf("  %3d  %s (%s; %s grid, %d values)\n", a,
           mrvi_ocp_actuator_name(o, a), on,
           mrvi_ocp_actuator_grid(o, a) == MRVI_GRID_MACRO ? "macro" : "micro",
           mrvi_ocp_actuator_size(o, a));
  }
  printf("%-14s%d (tolerance %g)\n", "terminal", nt,
         mrvi_ocp_terminal_tolerance(o));
  for (int i = 0; i < nt; i++) {
    mrvi_ocp_terminal_kind kind;
    int c;
    double target, penalty;
    mrvi_ocp_terminal(o, i, &kind, &c, &target, &penalty);
    printf("  %3d  %s of %s = %g", i,
           kind == MRVI_OCP_POSITION ? "position" : "velocity",
           mrvi_model_coordinate_name(m, c), target);
    if (penalty > 0)
      printf(" (penalty %g)", penalty);
    putchar('\n');
  }
  free(u);
  mrvi_ocp_free(o);
  return 0;
}

static char *default_output(const mrvi_system *sys) {
  const char *base = sys->output_file ? sys->output_file : "optimal.h5";
  size_t n = strlen(base);
  char *s = malloc(n + 8);
  if (!s)
    return NULL;
  strcpy(s, base);
  if (n > 3 && !strcmp(s + n - 3, ".h5"))
    s[n - 3] = '\0';
  strcat(s, "_opt.h5");
  return s;
}

/* Controls stored by `mrvi optimize` (/control/u) into the control vector
 * of o; 0 or -1 with a message. */
static int read_controls(const char *path, const mrvi_ocp *o, double *u,
                         char *msg, size_t len) {
  hid_t f = mrvi_h5_open_read(path, H5P_DEFAULT);
  if (f < 0) {
    mrvi_fmt(msg, len, "cannot open '%s'", path);
    return -1;
  }
  int rc = -1;
  hid_t d = H5Dopen2(f, "/control/u", H5P_DEFAULT);
  hid_t sp = d >= 0 ? H5Dget_space(d) : -1;
  hsize_t dims[2] = {0, 0};
  const int na = mrvi_ocp_n_actuators(o);
  const long N = mrvi_ocp_n_steps(o);
  if (sp < 0 || H5Sget_simple_extent_ndims(sp) != 2 ||
      H5Sget_simple_extent_dims(sp, dims, NULL) < 0) {
    mrvi_fmt(msg, len, "'%s' has no 2-D /control/u", path);
  } else if ((int)dims[1] != na || dims[0] == 0 || dims[0] % (hsize_t)N) {
    mrvi_fmt(msg, len,
             "/control/u of '%s' is %llu x %llu; the problem has %d "
             "actuators on %ld macro steps",
             path, (unsigned long long)dims[0], (unsigned long long)dims[1], na,
             N);
  } else {
    double *U = malloc((size_t)(dims[0] * dims[1]) * sizeof *U);
    if (U &&
        H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, U) >= 0) {
      const long pt = (long)dims[0] / N;
      rc = 0;
      for (int a = 0; a < na && rc == 0; a++) {
        const int micro = mrvi_ocp_actuator_grid(o, a) == MRVI_GRID_MICRO;
        const int size = mrvi_ocp_actuator_size(o, a);
        if (micro && size != (int)dims[0]) {
          mrvi_fmt(msg, len, "actuator '%s' needs %d values, '%s' has %llu",
                   mrvi_ocp_actuator_name(o, a), size, path,
                   (unsigned long long)dims[0]);
          rc = -1;
        }
        for (int j = 0; rc == 0 && j < size; j++)
          u[mrvi_ocp_actuator_offset(o, a) + j] =
              U[(micro ? j : j * pt) * na + a];
      }
    } else {
      mrvi_fmt(msg, len, "cannot read /control/u of '%s'", path);
    }
    free(U);
  }
  if (sp >= 0)
    H5Sclose(sp);
  if (d >= 0)
    H5Dclose(d);
  H5Fclose(f);
  return rc;
}

/* mrvi run FILE --controls STORED.h5 [-o OUT.h5] [--set ...]: replay. */
static int replay(const char *file, const char *controls, const char *out,
                  const char **ov, int n_ov) {
  static char msg[8192];
  mrvi_system *sys = NULL;
  if (mrvi_system_load(file, ov, n_ov, &sys, msg, sizeof msg) < 0) {
    fprintf(stderr, "%s\n", msg);
    return 1;
  }
  mrvi_ocp *o = NULL;
  double *u = NULL;
  int rc = 1;
  if (mrvi_ocp_load(sys, &o, &u, msg, sizeof msg) < 0 ||
      read_controls(controls, o, u, msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi run: %s\n", msg);
    goto done;
  }
  const int nc = mrvi_ocp_n_constraints(o);
  double J, *c = calloc((size_t)nc + 1, sizeof *c);
  rc = 2;
  if (c && mrvi_ocp_evaluate(o, u, &J, NULL, c, NULL) == 0) {
    double viol = 0.0;
    for (int i = 0; i < nc; i++)
      viol = fmax(viol, fabs(c[i]));
    const char *dst = out ? out : sys->output_file;
    if (write_trajectory(dst, sys, o, msg, sizeof msg) < 0 ||
        write_solver_path(dst, o, msg, sizeof msg) < 0) {
      fprintf(stderr, "mrvi run: writing '%s' failed: %s\n", dst, msg);
    } else {
      const int met = viol <= mrvi_ocp_terminal_tolerance(o);
      printf("%s: replayed the controls of %s\n", file, controls);
      printf("  %-22s%.12e\n", "cost", J);
      printf("  %-22s%.3e (tolerance %.1e)%s\n", "terminal violation", viol,
             mrvi_ocp_terminal_tolerance(o), met ? "" : " NOT MET");
      printf("  %-22s%s\n", "output", dst);
      rc = met ? 0 : 2;
    }
  } else {
    fprintf(stderr, "mrvi run: %s\n", mrvi_ocp_errmsg(o));
  }
  free(c);
done:
  free(u);
  mrvi_ocp_free(o);
  mrvi_system_free(sys);
  return rc;
}

int mrvi_cmd_optimize(int argc, char **argv) {
  const char *file = NULL, *out = NULL, *controls = NULL;
  const int is_run = !strcmp(argv[0], "run"); /* mrvi run --controls */
  const char **ov = calloc((size_t)argc + 1, sizeof *ov);
  int n_ov = 0, quiet = 0;
  if (!ov)
    return 1;
  for (int i = 1; i < argc; i++) {
    const char *a = argv[i];
    if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
      fputs(mrvi_usage_optimize, stdout);
      free(ov);
      return 0;
    } else if (!strcmp(a, "-q") || !strcmp(a, "--quiet")) {
      quiet = 1;
    } else if ((!strcmp(a, "-o") || !strcmp(a, "--output")) && i + 1 < argc) {
      out = argv[++i];
    } else if (!strncmp(a, "--output=", 9)) {
      out = a + 9;
    } else if ((!strcmp(a, "-s") || !strcmp(a, "--set")) && i + 1 < argc) {
      ov[n_ov++] = argv[++i];
    } else if (is_run && !strcmp(a, "--controls") && i + 1 < argc) {
      controls = argv[++i];
    } else if (is_run && !strncmp(a, "--controls=", 11)) {
      controls = a + 11;
    } else if (!strncmp(a, "--set=", 6)) {
      ov[n_ov++] = a + 6;
    } else if (a[0] == '-' && a[1]) {
      fprintf(stderr, "mrvi optimize: unknown option '%s'\n%s", a,
              mrvi_usage_optimize);
      free(ov);
      return 1;
    } else if (!file) {
      file = a;
    } else {
      fprintf(stderr, "mrvi optimize: unexpected argument '%s'\n", a);
      free(ov);
      return 1;
    }
  }
  if (!file) {
    fprintf(stderr, "mrvi optimize: missing FILE\n%s", mrvi_usage_optimize);
    free(ov);
    return 1;
  }
  if (is_run) {
    const int rc = replay(file, controls, out, ov, n_ov);
    free(ov);
    return rc;
  }
  static char msg[8192];
  mrvi_system *sys = NULL;
  int st = mrvi_system_load(file, ov, n_ov, &sys, msg, sizeof msg);
  free(ov);
  if (st < 0) {
    fprintf(stderr, "%s\n", msg);
    return 1;
  }
  mrvi_ocp *o = NULL;
  double *u = NULL;
  if (mrvi_ocp_load(sys, &o, &u, msg, sizeof msg) < 0) {
    fprintf(stderr, "%s\n", msg);
    mrvi_system_free(sys);
    return 1;
  }
  char *def = out ? NULL : default_output(sys);
  if (!out)
    out = def;
  history h = {.quiet = quiet};
  mrvi_ocp_set_callback(o, on_iteration, &h);
  printf("%s: %d controls, %d terminal constraints, %ld macro steps, p = %d, "
         "%s\n",
         file, mrvi_ocp_n_controls(o), mrvi_ocp_n_constraints(o),
         mrvi_ocp_n_steps(o), sys->settings.micro_steps,
         mrvi_ocp_algorithm_name(mrvi_ocp_get_algorithm(o)));
  const double t0 = mrvi_clock();
  mrvi_ocp_result res;
  st = mrvi_ocp_solve(o, u, &res);
  const double wall = mrvi_clock() - t0;
  int rc = st == 0 ? 0 : 2;
  printf("%s\n", st == 0 ? "optimum found" : "optimisation FAILED");
  printf("  %-22s%.12e\n", "cost", res.cost);
  printf("  %-22s%.3e (tolerance %.1e)\n", "terminal violation", res.violation,
         mrvi_ocp_terminal_tolerance(o));
  printf("  %-22s%d (NLopt: %s)\n", "evaluations", res.evaluations,
         res.nlopt_name);
  {
    char why[300] = "";
    const char *path = mrvi_ocp_solver_path(o, why, sizeof why);
    printf("  %-22s%s (%s)\n", "solver path", path ? path : "none", why);
  }
  printf("  %-22s%.3f s\n", "wall time", wall);
  if (st != 0)
    fprintf(stderr, "mrvi optimize: %s\n", mrvi_ocp_errmsg(o));
  /* The trajectory of the returned controls (re-evaluated by solve). */
  if (write_trajectory(out, sys, o, msg, sizeof msg) < 0 ||
      write_solver_path(out, o, msg, sizeof msg) < 0 ||
      write_control(out, sys, o, u, &h, &res, st) < 0) {
    fprintf(stderr, "mrvi optimize: writing '%s' failed: %s\n", out, msg);
    rc = 2;
  } else {
    printf("  %-22s%s\n", "output", out);
  }
  free(h.rows);
  free(u);
  free(def);
  mrvi_ocp_free(o);
  mrvi_system_free(sys);
  return rc;
}
