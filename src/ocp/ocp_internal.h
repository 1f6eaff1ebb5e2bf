/* Private layout of mrvi_ocp shared by the files of src/ocp/, and what the
 * folder offers the layers above it beyond ocp/ocp.h (the description
 * file's `control:` node parsed for the loader). */
#ifndef MRVI_OCP_INTERNAL_H
#define MRVI_OCP_INTERNAL_H

#include "integrator/integrator.h"
#include "ocp/ocp.h"

/* Optimal control (src/ocp/ocp_loader.c): build a problem from the
 * `control:` node of a description (path for file:line:col messages;
 * override_of, if not NULL, names the --set override that made a node). */
struct fy_node;
typedef const char *(*mrvi_override_of)(const void *ctx, struct fy_node *n);
int mrvi_ocp_parse(const mrvi_model *m, const mrvi_settings *s,
                   struct fy_node *control, const char *path,
                   mrvi_override_of override_of, const void *ctx,
                   mrvi_ocp **out, double **u0, char *msg, size_t len);

/* Inputs of a state-dependent actuator (at most two 3-D bodies). */
#define OCP_MAX_IN 24

/* A torque term (state_forces.c) on the directors at inputs x_off.. of an
 * actuator: sign s, axis in space (y_off < 0) or fixed in the body whose
 * directors are at inputs y_off.. (axis = its components along them);
 * 2-D: the scalar torque s axis[2]. */
typedef struct ocp_torque {
  int x_off, y_off;
  double s, axis[3];
} ocp_torque;

typedef struct ocp_actuator {
  int coord;  /* model index (pair: particle i's first coordinate) */
  int pi, pj; /* pair actuator: particles i, j; -1 otherwise */
  /* State-dependent actuators (pair, torque, body force, joint torque;
   * state_forces.c): their model input coordinates (n_in = 0: a
   * coordinate actuator), torque terms, or (no torque term) the body
   * force's point `at` (body frame) and direction `dir` (space). */
  int n_in, in[OCP_MAX_IN];
  int n_torque;
  ocp_torque torque[2];
  double at[3], dir[3];
  int body, joint; /* body (torque, force) or joint constraint; -1 */
  mrvi_grid grid;  /* MRVI_GRID_MACRO or MRVI_GRID_MICRO */
  double weight, lower, upper;
  int offset, size; /* in the control vector */
  char name[64];    /* default: the coordinate's name */
} ocp_actuator;

typedef struct ocp_tracking {
  int coord;
  double weight, ref;
} ocp_tracking;

typedef struct ocp_terminal {
  mrvi_ocp_terminal_kind kind;
  int coord;              /* coordinate; a body's first for body kinds */
  double target, penalty; /* penalty 0: equality constraint */
  /* Body kinds (attitude, angular velocity, direction): body, row (0..2),
   * target rotation (D x D row-major; attitude) or the direction's frame
   * (rows u, v, e, right-handed, e the unit direction; direction) and the
   * director (0..2; direction). */
  int body, row, director;
  double R_target[9];
} ocp_terminal;

/* One entry of the linear map u -> node forces of a step: z index (layout
 * of struct mrvi_ocp), actuator, control within the step, coefficient;
 * plus = 1 for f^+ of the interval ending at node z (it enters the
 * momentum there), 0 for f^- of the interval starting at z. */
typedef struct ocp_force {
  int z, act, j, plus;
  double coef;
} ocp_force;

struct mrvi_ocp {
  const mrvi_model *model;
  mrvi_settings settings;
  long N;
  int p, ns, nf, nz; /* nz = 2 ns + (p+1) nf nodes of one step */
  int nl, nv;        /* multipliers of a step; nv = nz + nl step variables */
  int n_act, n_trk, n_term, n_con, n_u;
  ocp_actuator *act;
  ocp_tracking *trk;
  ocp_terminal *term;
  /* Forces of a step (same template every step). */
  int n_force;
  ocp_force *force;
  /* State-dependent actuators (state_forces.c): their number, and the controls
   * and step of the forward sweep for the step hook. */
  int n_state;
  struct ocp_act_kept *act_kept; /* a step's forces, n_state p */
  int n_act_kept;
  const double *u_cur;
  long k_cur;
  /* Step solver.  The forward pass takes the path the integrator would
   * (ocp_path): the structured ones through an integrator with the control
   * forces (integ), the general one here (step, newton, nullspace), which
   * also serves every adjoint solve. */
  int path;               /* MRVI_PATH_*, set in ocp_alloc */
  mrvi_integrator *integ; /* structured paths */
  double *p0;             /* initial momenta M v0, model order */
  mrvi_step step;
  mrvi_newton *newton;
  mrvi_nullspace *nullspace; /* null-space form of the forward solve */
  mrvi_newton *newton_full;  /* saddle-point matrix for the adjoint */
  double *rhs_ns;            /* its reduced right-hand side */
  int ready;
  int allocated; /* ocp_alloc done: step and trajectory buffers */
  double *x, *R, *dx, *f_rows, *f_end, *ps1, *pf1;
  /* Trajectory: global nodes: slow (N+1) x ns, then fast (N p + 1) x nf. */
  long n_nodes;
  double *Q;
  double *pN;          /* final momenta ns + nf */
  double *Lam;         /* multipliers of every step, N x nl */
  double *ps_k, *pf_k; /* momenta p_k per step (N+1) x ns, (N+1) x nf */
  double *pf_micro;    /* fast momenta at every micro node (N p + 1) x nf */
  double *f_plus;      /* f^+ of a step on fast nodes 1..p, p x nf */
  /* The coordinate actuators' parts of f_end and f_plus of the step (the
   * state actuators' f^+ is added to them at the integrator's converged
   * step: ocp_state_end_hook); in the second halves of f_end, f_plus. */
  double *f_end_c, *f_plus_c;
  double *cres_micro;    /* max |g| at micro nodes 1..p of every step, N p */
  double *q_out, *p_out; /* (N+1) x n model order */
  /* Torsional springs: each one's branch at every macro node, (N+1) x
   * n_torsion; step k (forward and adjoint) evaluates on row k, as the
   * integrator does (src/model/torsion.c). */
  int n_torsion;
  double *branch;
  /* Adjoint workspace.  The step Jacobian H (nv x nv) is assembled dense
   * (H) for nv <= tuning.adjoint_dense_max, then gathered into the sparse
   * rows of the assembly's pattern; beyond, straight into those rows
   * (pattern found once, the same for every step). */
  double *H, *r, *mu, *rhs, *sol;
  long *gz;             /* global node of every z of the step (nz) */
  long *h_of_a;         /* entry of H (dense: row nv + col; sparse: slot in
                           h_val; -1: none) of every CSC entry of A_k */
  double *Ak;           /* A_k on the step's CSC pattern, gathered from H */
  long *h_ptr;          /* H's rows (CSR on the assembly's pattern) */
  int *h_slot;          /* slot in h_val of every entry of the assembly */
  long n_h_slot;        /* their number (0: not recorded) */
  long h_slot_cap;      /* room in h_slot: the assembly's entries */
  int *h_col, h_sparse; /* h_sparse: the pattern is made (either mode) */
  double *h_val;
  int nfun_alloc; /* functionals the adjoint workspace is sized for */
  long adjoint_factorisations; /* step factorisations of the adjoints */
  /* The transposed step solves of the adjoint on the schur-krylov
   * elimination (forward path schur-krylov or an explicit one,
   * tuning.adjoint_krylov), on step's pattern with the values Ak; its
   * solves and those that fell back to the sparse LU. */
  mrvi_skrylov *skrylov;
  long adjoint_krylov_solves, adjoint_krylov_fallbacks;
  /* The transposed step solves of the adjoint where the forward pass takes
   * schur-bordered: its block elimination (bordered.c) of A_k, factorised
   * on step's pattern with the values step.Ax (bd_factored: it holds
   * factors), run backwards; bd_work: 2 MRVI_REFINE_BLOCK n_total for the
   * refinement and nfun n_total for the blocked solves. */
  mrvi_bordered *bordered;
  int bd_factored;
  /* bordered_transpose: the refinement's cost per functional in
   * corrections, a running mean over the steps (0: none yet), and the
   * number of steps it has seen (up to 8) */
  double bd_ref_units;
  int bd_ref_count;
  double *bd_work;
  /* The explicit path's adjoint (adjoint_explicit.c, ocp_explicit_ok):
   * V and W compiled for Hessian-vector products (columns: V's slow slots,
   * then ns + fast slots; W's fast slots) and its workspace. */
  int adj_explicit;
  mrvi_terms *adj_terms[2];
  double *adj_work;
  /* W's kept Hessian blocks (2 adj_hb doubles: at two points; adj_hb =
   * mrvi_terms_hessblocks_size, 0 or less: none kept) */
  long adj_hb;
  double *adj_blocks;
  int adj_one; /* (tuning.adjoint_one_point) */
  /* explicit-slow's transposed micro steps solved by block elimination
   * along W's springs where they form a forest (adjoint_explicit.c,
   * tuning.adjoint_forest; NULL: by the CG alone); the micro steps solved
   * so, those solved by the CG and the CG's products (every evaluation) */
  struct ocp_forest *adj_forest;
  long adjoint_forest_solves, adjoint_cg_solves, adjoint_cg_products;
  /* Terminal velocities of a constrained model (projected_velocity):
   * q, p, p projected, a unit vector, d/dq, d/dp (6 n), then the projection's
   * workspace g, G, A, mu (R, R n, R R, R); NULL without constraints. */
  double *pv;
  /* Solver settings. */
  mrvi_ocp_algorithm algorithm;
  double ftol_rel, terminal_tol;
  int max_eval;
  mrvi_ocp_callback cb;
  void *cb_data;
  const double *best_u; /* during a callback of solve: the best iterate */
  char errmsg[512];
};

int mrvi_ocp_fail(mrvi_ocp *o, int status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
/* z index of step k -> global node index (times ns/nf offsets included). */
static inline long ocp_global(const mrvi_ocp *o, long k, int z) {
  const int ns = o->ns, nf = o->nf;
  if (z < ns)
    return k * ns + z;
  if (z < 2 * ns)
    return (k + 1) * ns + (z - ns);
  const int zf = z - 2 * ns, mm = zf / nf, s = zf % nf;
  return (o->N + 1) * ns + (k * o->p + mm) * nf + s;
}
/* Step solver path of the forward pass (MRVI_PATH_*) and its reason: the
 * integrator's for the model and settings (mrvi_sweep_path), the general
 * one with pair actuators. */
int ocp_path(const mrvi_ocp *o, char *why, size_t len);
/* Free the adjoint workspace (sized lazily per functional count by
 * adjoint.c; freed with the problem by ocp.c). */
void ocp_adjoint_free(mrvi_ocp *o);
/* The step and trajectory buffers (once, at the first forward pass). */
int ocp_alloc(mrvi_ocp *o);
/* Forward shooting at u: fills Q, pN, momenta, trajectory outputs. */
int ocp_forward(mrvi_ocp *o, const double *u);
/* Control index of force entry fe in step k. */
int ocp_control_index(const mrvi_ocp *o, long k, const ocp_force *fe);
/* Where ocp_jacobian puts the entries of a step Jacobian (nv x nv): dense
 * (J, row-major), or sparse rows (CSR: ptr, col ascending within a row,
 * val) on a pattern found by two symbolic passes over the same assembly:
 * OCP_JAC_COUNT counts every row's entries into ptr[row + 1],
 * OCP_JAC_LIST writes their columns at col[fill[row]++] (duplicates
 * included).  An entry outside the sparse pattern sets miss. */
typedef enum {
  OCP_JAC_DENSE,
  OCP_JAC_COUNT,
  OCP_JAC_LIST,
  OCP_JAC_SPARSE,
  OCP_JAC_SLOTS
} ocp_jac_mode;
/* OCP_JAC_SPARSE finds every entry's slot by bisection in its row and,
 * with slot not NULL, records it at slot[n_slot++] (n_slot < max_slot;
 * beyond, slot is dropped); OCP_JAC_SLOTS replays the recorded slots (the
 * assembly adds the same entries in the same order at every step). */
typedef struct ocp_jac {
  ocp_jac_mode mode;
  int nv, miss;
  double *J;
  long *ptr;
  int *col;
  long *fill;
  double *val;
  int *slot;
  long n_slot, max_slot;
} ocp_jac;
/* Entry (i, j) += v. */
static inline void ocp_jac_add(ocp_jac *a, int i, int j, double v) {
  switch (a->mode) {
  case OCP_JAC_DENSE:
    a->J[(size_t)i * (size_t)a->nv + (size_t)j] += v;
    return;
  case OCP_JAC_COUNT:
    a->ptr[i + 1]++;
    return;
  case OCP_JAC_LIST:
    a->col[a->fill[i]++] = j;
    return;
  case OCP_JAC_SPARSE: {
    long lo = a->ptr[i], hi = a->ptr[i + 1];
    while (lo < hi) {
      const long mid = lo + (hi - lo) / 2;
      if (a->col[mid] < j)
        lo = mid + 1;
      else
        hi = mid;
    }
    if (lo < a->ptr[i + 1] && a->col[lo] == j) {
      a->val[lo] += v;
      if (a->slot && a->n_slot < a->max_slot)
        a->slot[a->n_slot] = (int)lo;
      a->n_slot++;
    } else {
      a->miss = 1;
    }
    return;
  }
  case OCP_JAC_SLOTS:
    if (a->n_slot < a->max_slot)
      a->val[a->slot[a->n_slot]] += v;
    a->n_slot++;
    return;
  }
}
/* The Jacobian of the equations of step k in its variables v = (z_k,
 * lambda_k) at the stored trajectory, added into a (cleared by the
 * caller): rows 0..nz-1 are D_z of L_d^k - sum h lambda^T g (all nodes of
 * the step), rows nz.. the step's constraint equations g (step row order).
 * Also fills o->gz (the global node of every z of step k; the adjoint
 * workspace). */
void ocp_jacobian(mrvi_ocp *o, long k, ocp_jac *a);

/* The explicit paths' adjoint (adjoint_explicit.c).  Whether it applies
 * (path explicit, sweep or sweep-cg; no multipliers, state actuators or
 * torsional springs; tuning.adjoint_explicit) */
int ocp_explicit_ok(const mrvi_ocp *o);
/* Its compiled classes and workspace for nfun functionals (MRVI_ENOMEM) */
int ocp_explicit_alloc(mrvi_ocp *o, int nfun);
/* The forest of ocp_explicit_alloc (NULL: nothing) */
void ocp_forest_free(struct ocp_forest *F);
/* The backward sweep: o->mu (nfun x n_nodes; final nodes set) on every
 * equation node from gQ (nfun x n_nodes, d Phi / dY; overwritten).
 * MRVI_ESINGULAR (message on o) where a micro step's transposed solve
 * (the sweep paths) does not converge. */
int ocp_explicit_adjoint(mrvi_ocp *o, int nfun, double *gQ);

/* z indices and coefficients of the (two) nodes that model coordinate idx
 * interpolates at point pt of a step. */
static inline int ocp_znodes(const mrvi_ocp *o, int idx, const mrvi_point *pt,
                             int *zi, double *zc) {
  const mrvi_model *m = o->model;
  const int s = m->slot[idx], ns = o->ns, nf = o->nf;
  if (m->rate[idx] == MRVI_SLOW) {
    zi[0] = s;
    zi[1] = ns + s;
    zc[0] = pt->a0;
    zc[1] = pt->a1;
  } else {
    zi[0] = 2 * ns + pt->m * nf + s;
    zi[1] = zi[0] + nf;
    zc[0] = pt->cA;
    zc[1] = pt->cB;
  }
  return 2;
}
/* State-dependent actuators: pair forces, body torques and forces, joint
 * torques (state_forces.c, doc/optimal-control.md).  Step hook
 * (mrvi_step.extra): their forces f^- on the residual rows of step o->k_cur
 * at x and their derivatives. */
void ocp_state_hook(void *ctx, mrvi_step *st, const double *x, double *R,
                    int jac);
/* After convergence of step k at o->x under controls u: their f^+ into
 * o->f_end (end nodes) and o->f_plus (fast nodes 1..p). */
void ocp_state_end_forces(mrvi_ocp *o, long k, const double *u);
/* The same as the integrator's step hook (mrvi_step.extra_end) at its
 * converged step x (step o->k_cur, controls o->u_cur): o->f_end and
 * o->f_plus set to the coordinate actuators' parts (f_end_c, f_plus_c)
 * plus the state actuators' f^+. */
void ocp_state_end_hook(void *ctx, mrvi_step *st, const double *x);
/* Their second derivatives in the step's nodes added to the step
 * Jacobian a of step k at the stored trajectory (controls o->u_cur); their
 * forces kept for ocp_state_gradient (o->act_kept, sized by
 * ocp_state_alloc: MRVI_OK or MRVI_ENOMEM). */
void ocp_state_jacobian(mrvi_ocp *o, long k, ocp_jac *a);
int ocp_state_alloc(mrvi_ocp *o);
/* Value of body terminal condition T at the final nodes; its derivatives in
 * the final positions gq and momenta gp of the body's D (D + 1)
 * coordinates (body_terminal.c). */
double ocp_body_terminal(const mrvi_ocp *o, const ocp_terminal *T,
                         const double *q, const double *p, double *gq,
                         double *gp);
/* The first equality terminal condition at index >= first implied, to first
 * order near the initial state (q0 moved a little and projected back: the
 * generic rank, not an accident of q0), by the model's constraints (positions:
 * G q' = 0; momenta: the hidden constraints G M^-1 p = 0) and the conditions
 * before it, or -1 (-2: out of memory) (body_terminal.c). */
int ocp_terminal_redundant(const mrvi_ocp *o, int first);
/* gu[f n_u + control] -= mu_f^T d(forces of step k)/du for every state
 * control of step k and functional f < nfun (mu: nfun rows of global node
 * adjoints), from the forces ocp_state_jacobian kept at step k. */
void ocp_state_gradient(const mrvi_ocp *o, long k, int nfun, const double *mu,
                        double *gu);

#endif
