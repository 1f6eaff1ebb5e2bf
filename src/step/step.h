/* What src/step/ offers the layers above it: the quadrature points of a
 * macro step and one macro step's equations -- residual, Jacobian pattern
 * and values, momenta (quadrature.c, step.c). */
#ifndef MRVI_STEP_H
#define MRVI_STEP_H

#include "model/model.h"

/* Tuning constants (step/tuning.c, MRVI_TUNING_LIST): the defaults, and
 * MRVI_EINVAL with a message if one is out of its range. */
void mrvi_tuning_default(mrvi_tuning *t);
int mrvi_tuning_check(const mrvi_tuning *t, char *msg, size_t len);
/* The dense blocks the tuning lets the step solvers form on a model of
 * `block` coordinates and constraint rows (n + rows) and `step` unknowns
 * per step (n_s + p n_f and the multipliers): MRVI_EINVAL, with a message
 * naming the constant, where a dense-size threshold exceeds
 * MRVI_DENSE_BLOCK_MAX and so could the blocks it governs (dense_max,
 * bordered_max, bordered_node_max, bordered_slow_max: per rate or node, at
 * most `block`; chain_block_max: a chain's blocks, at most `step`).  The
 * dense kernels index a block's n^2 entries with int and the loader's
 * memory estimate leaves dense blocks out: dense_max = 10^6 on 10^5 fast
 * coordinates would ask for an 80 GB matrix whose indices overflow
 * (doc/performance/17-audit17.md). */
#define MRVI_DENSE_BLOCK_MAX 32768
int mrvi_tuning_check_model(const mrvi_tuning *t, long block, long step,
                            char *msg, size_t len);

/* ---------------------------------------------------------------------------
 * Quadrature (eq:Zapprox and eq:slow_potential_affine as evaluation points)
 *
 * Within macro step k a point z is affine in the nodes:
 *   slow part  a0 q_k^s + a1 q_{k+1}^s
 *   fast part  cA q_k^{f,m} + cB q_k^{f,m+1}
 * with weight w (the quadrature weight times the step).
 * ------------------------------------------------------------------------- */
typedef struct mrvi_point {
  double w, a0, a1, cA, cB;
  int m; /* micro interval 0..p-1 */
} mrvi_point;

/* Evaluation points of one potential class for the given rule.  Writes at
 * most 2p points into pts (ordered by interval) and returns their number.
 * grid = MRVI_GRID_MACRO uses the macro-node rule (two points). */
int mrvi_quadrature_points(mrvi_rule rule, mrvi_grid grid, double macro_step,
                           int p, mrvi_point *pts);

/* ---------------------------------------------------------------------------
 * One step (arXiv 2406.12991 §3.1, doc/solver.md): residual, Jacobian pattern
 * and values, momenta.
 * ------------------------------------------------------------------------- */
typedef struct mrvi_step {
  const mrvi_model *model;
  int p, ns, nf;
  double dT, dt;
  int n_unknowns;     /* ns + p nf */
  mrvi_tuning tuning; /* the settings' (read at setup) */
  int threads;        /* settings.threads resolved (>= 1) */
  mrvi_point *pts[2]; /* [MRVI_SLOW] points of V, [MRVI_FAST] of W */
  int n_pts[2];
  /* The element indices of V and W (read through MRVI_STEP_ELEM and
   * mrvi_step_class_list): elem_of_class[c] NULL where class c is the
   * elements elem_first[c] .. elem_first[c] + n_elem_of_class[c] - 1 (no
   * list kept: 4 bytes an element less, doc/performance/16-es-mem16.md). */
  int *elem_of_class[2];
  int n_elem_of_class[2], elem_first[2];
  /* The first element of W with a slow input, or -1 (the path choice:
   * mrvi_sweep_path_of). */
  int fast_on_slow;
  /* Unknowns as displacements from (q_k^s, q_k^{f,0}) instead of
   * positions (0 by default; the integrator's Newton paths set it). */
  int increments;
  /* Known data of the step: q_k^s, q_k^{f,0}, p_k^s, p_k^{f,0}. */
  const double *qs0, *qf0, *ps0, *pf0;
  /* Jacobian as triplets mapped to CSC. */
  int recording; /* 1 while the pattern is being recorded */
  long n_trip, cap_trip;
  int *Ti, *Tj; /* recorded pattern */
  int *map;     /* triplet -> CSC index */
  double *Ax;   /* CSC values */
  int *Ap, *Ai;
  long nnz;
  /* Workspace. */
  double *y, *g, *H; /* element inputs, gradient, Hessian */
  double *kin; /* the kinetic rows' M, -M/dt, 2M/dt, last velocity (4 nf) */
  /* Constraints (doc/constraints.md).  The full unknown vector is (x, lambda)
   * of size n_total = n_unknowns + n_lambda; the residual appends the
   * constraint equations.  Layout of lambda and of the equation rows:
   *   slow-only constraints: lambda_k (weight dT) at node 0, equations
   *     g(q_{k+1}^s) = 0                      n_unknowns + [0, r_slow)
   *   micro-node constraints: lambda^m at nodes m = 0..p-1 (weight dt),
   *     equations g(z^m) = 0 at nodes m = 1..p
   *     lambda^m: n_unknowns + r_slow + m r_micro + row
   *     g(z^m):   n_unknowns + r_slow + (m-1) r_micro + row */
  int n_lambda, n_total;
  int n_slow_c, n_micro_c;   /* constraint counts */
  int *slow_c, *micro_c;     /* model constraint indices */
  int *c_off;                /* per model constraint: row within its block */
  int r_slow, r_micro;       /* rows per block */
  double *cy, *cg, *cG, *cH; /* constraint inputs, g, G, second derivs */
  /* External (control) forces of the discrete Lagrange-d'Alembert
   * principle (optimal control): f_rows (n_unknowns) is added to the
   * dynamic rows of R, f_end (ns + nf) to p_{k+1}^s and p_{k+1}^{f,0}.
   * NULL (the default) for none. */
  const double *f_rows, *f_end;
  /* Optional configuration-dependent terms (optimal control: pair-force
   * actuators): called by mrvi_step_assemble after f_rows with its
   * arguments; it adds to R and, through mrvi_step_jac_add, to the Jacobian
   * (making the same calls on every pass, so that the pattern recorded by
   * mrvi_step_build_pattern holds).  NULL (the default) for none. */
  void (*extra)(void *ctx, struct mrvi_step *st, const double *x, double *R,
                int jac);
  void *extra_ctx;
  /* Optional, with extra: called (with extra_ctx) by
   * mrvi_step_momenta_finish at the converged x before f_end is added, so
   * that f_end may take forces that depend on the converged nodes (the
   * state actuators' f^+).  NULL (the default) for none. */
  void (*extra_end)(void *ctx, struct mrvi_step *st, const double *x);
  /* If not NULL, mrvi_step_assemble also sums the potential parts of the
   * momenta at x into mom_ps (ns) and mom_pf (p x nf), which
   * mrvi_step_momenta_finish completes: the gradients of the residual
   * serve both. */
  double *mom_ps, *mom_pf;
} mrvi_step;

/* Element i of class c (0: V, 1: W). */
#define MRVI_STEP_ELEM(st, c, i)                                               \
  ((st)->elem_of_class[c] ? (st)->elem_of_class[c][i]                          \
                          : (st)->elem_first[c] + (i))
/* Class c's element indices as a list: elem_of_class[c], or a list made
 * into *own (the caller frees it; NULL out of memory). */
const int *mrvi_step_class_list(const mrvi_step *st, int c, int **own);

/* Point of constraint evaluation at node m (0..p) of the step: slow part
 * interpolated (1 - m/p, m/p), fast node m, weight w. */
mrvi_point mrvi_step_node_point(const mrvi_step *st, int m, double w);
/* 1 if V and W have the same points (both on the micro grid with the
 * same quadrature, e.g. midpoint-midpoint), else 0. */
int mrvi_step_same_points(const mrvi_step *st);
/* Evaluate constraint c (model index) at node point pt of x: fills st->cy,
 * st->cg, st->cG and, if hess, st->cH. */
void mrvi_step_constraint_eval(mrvi_step *st, int c, const mrvi_point *pt,
                               const double *x, int hess);
/* The same into the caller's arrays: inputs y (n_in), g (rows), G (rows x
 * n_in) and, if H is not NULL, the second derivatives (rows x n_in x n_in). */
void mrvi_step_constraint_at(const mrvi_step *st, int c, const mrvi_point *pt,
                             const double *x, double *y, double *g, double *G,
                             double *H);
/* Residual rows / unknown columns (at most 2) that model coordinate idx
 * feeds / depends on at point pt; return counts. */
int mrvi_step_rows_of(const mrvi_step *st, int idx, const mrvi_point *pt,
                      int *row, double *coef);
int mrvi_step_cols_of(const mrvi_step *st, int idx, const mrvi_point *pt,
                      int *col, double *coef);

int mrvi_step_init(mrvi_step *st, const mrvi_model *m, const mrvi_settings *s);
void mrvi_step_free(mrvi_step *st);
/* Record the Jacobian pattern (once) and build the CSC structure. */
int mrvi_step_build_pattern(mrvi_step *st, const double *x);
/* Residual R(x) (n_total) and, if jac, the CSC values st->Ax; x holds
 * (x, lambda) (n_total). */
void mrvi_step_assemble(mrvi_step *st, const double *x, double *R, int jac);
/* Add v to the Jacobian entry (row, col) of the step (for st->extra). */
void mrvi_step_jac_add(mrvi_step *st, int row, int col, double v);
/* max |g| over the constraint equations of the micro nodes m = 1..p in the
 * residual R of a step (p entries): the micro-node constraints at every
 * node, the slow-only ones too at m = p; zeros without constraints. */
void mrvi_step_micro_residuals(const mrvi_step *st, const double *R,
                               double *out);
/* Momenta after convergence (x with lambda): ps1 (ns) = D_{q_{k+1}^s} L_d
 * (with the constraint forces of the interior micro nodes) and the fast
 * micro momenta pf (p x nf) at nodes m = 1..p (eq:pkfm+). */
void mrvi_step_momenta(mrvi_step *st, const double *x, double *ps1, double *pf);
/* Add the kinetic, external-force and constraint parts of the momenta at x
 * to their potential parts in ps1, pf (as summed by mrvi_step_assemble into
 * mom_ps, mom_pf). */
void mrvi_step_momenta_finish(mrvi_step *st, const double *x, double *ps1,
                              double *pf);

#endif
