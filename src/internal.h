/* Internal declarations shared by the library's source files and the tests. */
#ifndef MRVI_INTERNAL_H
#define MRVI_INTERNAL_H

#include "mrvi.h"

#include <stdarg.h>

#ifndef M_PI /* not in strict C11 */
#define M_PI 3.14159265358979323846
#endif

/* printf into a caller buffer (NULL-safe, always terminated). */
void mrvi_fmt(char *buf, size_t len, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
void mrvi_vfmt(char *buf, size_t len, const char *fmt, va_list ap);
/* Write a message into msg and return status (for `return mrvi_fail(...)`). */
int mrvi_fail(char *msg, size_t len, int status, const char *fmt, ...)
    __attribute__((format(printf, 4, 5)));

/* The candidate (of n) closest to `word` by edit distance if it is close
 * enough to be a likely typo, else NULL; ties go to the longer common
 * prefix (suggest.c). */
const char *mrvi_closest(const char *word, const char *const *cand, int n);

/* Optimal control (src/ocp/ocp_loader.c): build a problem from the
 * `control:` node of a description (path for file:line:col messages;
 * override_of, if not NULL, names the --set override that made a node). */
struct fy_node;
struct mrvi_ocp;
typedef const char *(*mrvi_override_of)(const void *ctx, struct fy_node *n);
int mrvi_ocp_parse(const mrvi_model *m, const mrvi_settings *s,
                   struct fy_node *control, const char *path,
                   mrvi_override_of override_of, const void *ctx,
                   struct mrvi_ocp **out, double **u0, char *msg, size_t len);
void mrvi_ocp_free(struct mrvi_ocp *o);

/* Wall clock in seconds (monotonic). */
double mrvi_clock(void);
/* The machine's physical memory in bytes (0 when unknown): sizes needing
 * more are refused before allocation.  A build may lower it with
 * -DMRVI_MEMORY_CAP=BYTES (the fuzz build does, so that what the checks
 * admit fits the fuzzer's memory limit; tests/fuzz/run.sh). */
double mrvi_machine_memory(void);
/* Particles one `generate:` entry may make (the fuzz build lowers it). */
#ifndef MRVI_MAX_GENERATED
#define MRVI_MAX_GENERATED 10000000
#endif

/* ---------------------------------------------------------------------------
 * Model
 * ------------------------------------------------------------------------- */
/* Largest number of inputs of a non-linear element (terms are limited to it). */
#define MRVI_MAX_INPUTS 64

typedef enum mrvi_element_kind {
  MRVI_ELEMENT_SPRING,  /* phi(|x_i - x_j| - L0) */
  MRVI_ELEMENT_ANCHOR,  /* phi(|x_i - a| - L0) */
  MRVI_ELEMENT_TERM,    /* phi(c^T y - b) */
  MRVI_ELEMENT_GRAVITY, /* c^T y (linear, no law) */
  MRVI_ELEMENT_ANGLE,   /* k [1 - cos(theta_ijk - theta0)], no law */
  MRVI_ELEMENT_FORCE    /* c^T y with c = -f (constant force, no law) */
} mrvi_element_kind;

typedef struct mrvi_element {
  mrvi_element_kind kind;
  mrvi_rate potential;          /* MRVI_SLOW: part of V, MRVI_FAST: part of W */
  const mrvi_law *law;          /* NULL for gravity */
  double params[MRVI_LAW_MAX_PARAMS];
  double shift;                 /* rest length (springs) or offset b (terms) */
  double anchor[3];
  int particle_i, particle_j;   /* springs; -1 if unused */
  int particle_k;               /* angles: i-j-k with the vertex at j */
  int n_in;                     /* number of input coordinates */
  int *in;                      /* n_in model indices */
  double *coef;                 /* n_in coefficients (terms, gravity) */
} mrvi_element;

typedef struct mrvi_particle {
  char *name;
  int first; /* model index of its x coordinate */
} mrvi_particle;

/* A constraint instance: type applied to model coordinates `in`. */
typedef struct mrvi_constraint {
  const mrvi_constraint_type *type;
  char *label;
  int n_in, *in;                /* model indices */
  int n_params;
  double *params;
  int rows;                     /* scalar equations */
  int first_row;                /* offset in the model's constraint rows */
  mrvi_rate where;              /* MRVI_SLOW: macro nodes; MRVI_FAST: micro */
} mrvi_constraint;

struct mrvi_model {
  char *name;
  int dimension;
  int n, cap;            /* coordinates */
  char **names;
  double *mass, *q0, *v0;
  mrvi_rate *rate;
  int n_particles, cap_particles;
  /* Name lookup (model.c): open-addressing tables of coordinate and
   * particle indices by name, 0 = empty, else index + 1. */
  int *coord_table, *particle_table;
  int coord_table_cap, particle_table_cap;
  mrvi_particle *particles;
  int n_elements, cap_elements;
  mrvi_element *elements;
  /* Partition, extended by every add. */
  int n_slow, n_fast;
  int *slow_index, *fast_index; /* slot -> model index */
  int *slot;                    /* model index -> slot within its rate block */
  int max_in;                   /* largest n_in of a non-linear element */
  int n_constraints, cap_constraints;
  mrvi_constraint *constraints;
  int constraint_rows;          /* sum of rows */
  int max_constraint_in;        /* largest n_in of a constraint */
  int n_bodies, cap_bodies;     /* rigid bodies (model/bodies.c) */
  struct mrvi_body *bodies;
  char errmsg[512];
};

/* A rigid body (model/bodies.c, doc/multibody.md): dimension d (d + 1)
 * consecutive coordinates from `first`: phi (d), then d_1 .. d_d (d each). */
typedef struct mrvi_body {
  char *name;
  int first;
  int dim;
  double mass, inertia[3]; /* M; J_1..J_3 (2-D: J in inertia[0]) */
  int constraint;          /* its internal constraint ("body") */
} mrvi_body;
/* Release the bodies of m (bodies.c). */
void mrvi_model_free_bodies(mrvi_model *m);
/* Body owning model coordinate c, or -1. */
int mrvi_model_body_of(const mrvi_model *m, int c);


/* Energy, gradient (n_in) and Hessian (n_in x n_in row-major, may be NULL)
 * of element e at its local inputs y (n_in). */
double mrvi_element_eval(const mrvi_model *m, const mrvi_element *e,
                         const double *y, double *grad, double *hess);

/* 1 if e's energy is a polynomial of degree <= 2 in its inputs (constant
 * Hessian): terms with the linear law or the power law of exponent 0, 1, 2,
 * gravity and constant forces (model.c). */
int mrvi_element_is_quadratic(const mrvi_element *e);

/* Keep a message on m (mrvi_model_errmsg) and return status (model.c). */
int mrvi_model_fail(mrvi_model *m, int status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
/* Release the constraint instances of m (constraints.c). */
void mrvi_model_free_constraints(mrvi_model *m);
/* Evaluate constraint c at its inputs y: g (rows), G (rows x n_in), H
 * (rows x n_in x n_in, may be NULL). */
void mrvi_constraint_eval_at(const mrvi_constraint *c, const double *y,
                             double *g, double *G, double *H);

/* max |g(q)| within tol; otherwise MRVI_EMODEL and "<what> violate
 * constraint '<label>': |g| = ..." in msg.  *worst (may be NULL) gets the
 * constraint with the largest |g| (-1 without constraints). */
int mrvi_constraints_check_positions(const mrvi_model *m, const double *q,
                                     double tol, const char *what, int *worst,
                                     char *msg, size_t len);
/* M-orthogonal projection of momenta p (n) at q onto G M^-1 p = 0:
 * p <- p - G^T mu with (G M^-1 G^T) mu = G M^-1 p.  Workspace g (rows),
 * G (rows x n), A (rows x rows); mu (rows) keeps the multiplier.
 * MRVI_ESINGULAR if the gradients are dependent. */
int mrvi_constraints_project(const mrvi_model *m, const double *q, double *p,
                             double *g, double *G, double *A, double *mu);
/* Gradients of all constraints independent at q (model order); otherwise
 * MRVI_ESINGULAR and a message naming the dependent constraints. */
int mrvi_constraints_independent(const mrvi_model *m, const double *q,
                                 char *msg, size_t len);

/* Dense helpers (dense.c).  Solve A x = b in place (A n x n row-major,
 * overwritten; b becomes x); -1 if singular. */
int mrvi_dense_solve(int n, double *A, double *b);
/* LU with partial pivoting of A (n x n row-major) in place, pivots in piv
 * (n); -1 if singular.  mrvi_dense_lu_solve: b (n x nrhs row-major)
 * becomes A^-1 b.  The small blocks of the structured step solvers. */
int mrvi_dense_lu_factor(int n, double *A, int *piv);
/* Step k of that factorisation's pivoting: the largest |A_ik|, i >= k, its
 * row in piv[k] and swapped with row k; -1 if that column is zero. */
int mrvi_dense_lu_pivot(int n, double *A, int *piv, int k);
void mrvi_dense_lu_solve(int n, const double *A, const int *piv, double *b,
                         int nrhs);
/* The same with A^T: b (n x nrhs row-major) becomes A^-T b. */
void mrvi_dense_lu_solve_transpose(int n, const double *A, const int *piv,
                                   double *b, int nrhs);
#define MRVI_DENSE_MAX 256
/* Householder QR of A (m x n row-major, m <= MRVI_DENSE_MAX): A is
 * overwritten with R in its upper triangle, Q (m x m row-major) is explicit
 * and orthogonal; A = Q R.  Returns -1 if a column is (numerically) in the
 * span of the previous ones. */
int mrvi_dense_qr(int m, int n, double *A, double *Q);

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
 * One step (arXiv 2406.12991 §3.1, doc/solver.md): residual, Jacobian pattern and values, momenta.
 * ------------------------------------------------------------------------- */
typedef struct mrvi_step {
  const mrvi_model *model;
  int p, ns, nf;
  double dT, dt;
  int n_unknowns;               /* ns + p nf */
  mrvi_point *pts[2];           /* [MRVI_SLOW] points of V, [MRVI_FAST] of W */
  int n_pts[2];
  int *elem_of_class[2];        /* element indices of V and W */
  int n_elem_of_class[2];
  /* Unknowns as displacements from (q_k^s, q_k^{f,0}) instead of
   * positions (0 by default; the integrator's Newton paths set it). */
  int increments;
  /* Known data of the step: q_k^s, q_k^{f,0}, p_k^s, p_k^{f,0}. */
  const double *qs0, *qf0, *ps0, *pf0;
  /* Jacobian as triplets mapped to CSC. */
  int recording;                /* 1 while the pattern is being recorded */
  long n_trip, cap_trip;
  int *Ti, *Tj;                 /* recorded pattern */
  int *map;                     /* triplet -> CSC index */
  double *Ax;                   /* CSC values */
  int *Ap, *Ai;
  long nnz;
  /* Workspace. */
  double *y, *g, *H;            /* element inputs, gradient, Hessian */
  /* Constraints (doc/constraints.md).  The full unknown vector is (x, lambda) of
   * size n_total = n_unknowns + n_lambda; the residual appends the
   * constraint equations.  Layout of lambda and of the equation rows:
   *   slow-only constraints: lambda_k (weight dT) at node 0, equations
   *     g(q_{k+1}^s) = 0                      n_unknowns + [0, r_slow)
   *   micro-node constraints: lambda^m at nodes m = 0..p-1 (weight dt),
   *     equations g(z^m) = 0 at nodes m = 1..p
   *     lambda^m: n_unknowns + r_slow + m r_micro + row
   *     g(z^m):   n_unknowns + r_slow + (m-1) r_micro + row */
  int n_lambda, n_total;
  int n_slow_c, n_micro_c;      /* constraint counts */
  int *slow_c, *micro_c;        /* model constraint indices */
  int *c_off;                   /* per model constraint: row within its block */
  int r_slow, r_micro;          /* rows per block */
  double *cy, *cg, *cG, *cH;    /* constraint inputs, g, G, second derivs */
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
  /* If not NULL, mrvi_step_assemble also sums the potential parts of the
   * momenta at x into mom_ps (ns) and mom_pf (p x nf), which
   * mrvi_step_momenta_finish completes: the gradients of the residual
   * serve both. */
  double *mom_ps, *mom_pf;
} mrvi_step;

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
void mrvi_step_momenta(mrvi_step *st, const double *x, double *ps1,
                       double *pf);
/* Add the kinetic, external-force and constraint parts of the momenta at x
 * to their potential parts in ps1, pf (as summed by mrvi_step_assemble into
 * mom_ps, mom_pf). */
void mrvi_step_momenta_finish(mrvi_step *st, const double *x, double *ps1,
                              double *pf);

/* ---------------------------------------------------------------------------
 * Discrete null-space form (nullspace.c, doc/constraints.md): the dynamic rows are
 * premultiplied by P^T with P^T C = 0, which removes the multipliers.
 * ------------------------------------------------------------------------- */
typedef struct mrvi_nullspace mrvi_nullspace;
/* After mrvi_step_build_pattern: reduced pattern (size n_unknowns). */
int mrvi_nullspace_create(const mrvi_step *st, mrvi_nullspace **out,
                          char *msg, size_t len);
void mrvi_nullspace_free(mrvi_nullspace *z);
/* Multipliers lambda(x) (written to x + n_unknowns) from the residual F of
 * the full system assembled at lambda = 0; also factors the node blocks
 * used by mrvi_nullspace_reduce. */
int mrvi_nullspace_lambda(mrvi_nullspace *z, mrvi_step *st, double *x,
                          const double *F, char *msg, size_t len);
/* Reduced matrix [P^T A; H] (values on its own pattern) and right-hand side
 * [P^T R; h] from the full system assembled at lambda(x). */
void mrvi_nullspace_reduce(mrvi_nullspace *z, const mrvi_step *st,
                           const double *R, double *rhs);
const int *mrvi_nullspace_Ap(const mrvi_nullspace *z);
const int *mrvi_nullspace_Ai(const mrvi_nullspace *z);
const double *mrvi_nullspace_Ax(const mrvi_nullspace *z);
long mrvi_nullspace_nnz(const mrvi_nullspace *z);

/* ---------------------------------------------------------------------------
 * Newton solver: UMFPACK, or a dense LU (dense.c) for matrices of at most
 * MRVI_NEWTON_DENSE_MAX rows (solver/newton.c); the caller sees one
 * interface.
 * ------------------------------------------------------------------------- */
#define MRVI_NEWTON_DENSE_MAX 128
typedef struct mrvi_newton mrvi_newton;
mrvi_newton *mrvi_newton_create(int n, const int *Ap, const int *Ai,
                                const double *Ax, char *msg, size_t len);
void mrvi_newton_free(mrvi_newton *nw);
/* Factorise A (values Ax on the fixed pattern) and solve A dx = b. */
int mrvi_newton_solve(mrvi_newton *nw, const double *Ax, const double *b,
                      double *dx, char *msg, size_t len);
/* Factorise A once and solve A^T x_i = b_i for nrhs right-hand sides
 * (b, x: nrhs x n, row i contiguous); the adjoint of optimal control. */
int mrvi_newton_solve_transpose(mrvi_newton *nw, const double *Ax, int nrhs,
                                const double *b, double *x, char *msg,
                                size_t len);

/* ---------------------------------------------------------------------------
 * Structured step solver (solver/sweep.c, doc/solver.md).
 * ------------------------------------------------------------------------- */
enum {
  MRVI_PATH_GENERAL = 0,
  MRVI_PATH_EXPLICIT = 1,
  MRVI_PATH_SWEEP = 2,
  MRVI_PATH_SCHUR = 3,
  MRVI_PATH_SWEEP_CG = 4,     /* sweep, micro steps by CG (sparse_block.c) */
  MRVI_PATH_SCHUR_KRYLOV = 5  /* Newton, GMRES on the slow unknowns and
                                 CG block sweeps (schur_krylov.c) */
};
/* Path for m and s (MRVI_PATH_*); why (may be NULL) gets the reason. */
int mrvi_sweep_path(const mrvi_model *m, const mrvi_settings *s, char *why,
                    size_t len);
typedef struct mrvi_sweep mrvi_sweep;
/* Workspace for the explicit and sweep paths of st (after mrvi_step_init). */
int mrvi_sweep_create(const mrvi_step *st, const mrvi_settings *s,
                      mrvi_sweep **out);
void mrvi_sweep_free(mrvi_sweep *sw);
/* Forget cached forces (after the state is set from outside). */
void mrvi_sweep_reset(mrvi_sweep *sw);
/* One step from the known data of st: x (n_unknowns) gets
 * (q_{k+1}^s, q^{f,1..p}), ps1 (ns) the slow momentum at k+1, pf (p x nf)
 * the fast momenta at nodes 1..p (eq:pkfm+).  *iterations: the largest
 * number of Newton iterations of a micro step (0 on the explicit path);
 * *residual: the largest converged micro-row residual. */
int mrvi_sweep_step(mrvi_sweep *sw, const mrvi_step *st, double *x,
                    double *ps1, double *pf, int *iterations, double *residual,
                    char *msg, size_t len);

/* 1 if the steps of sw are explicit at p = 1 with one W point at each
 * node (the trapezoidal fast rule): then an uncontrolled step (st->f_rows
 * and f_end NULL) may take mrvi_sweep_explicit_p1, mrvi_sweep_step's
 * arithmetic in the same order (iterations and residual 0) without its
 * set-up and tests. */
int mrvi_sweep_tight(const mrvi_sweep *sw);
int mrvi_sweep_explicit_p1(mrvi_sweep *sw, const mrvi_step *st, double *x,
                           double *ps1, double *pf, char *msg, size_t len);

/* Statistics of the micro-step blocks' iterative solves (NULL on the
 * dense and explicit paths). */
const mrvi_krylov_stats *mrvi_sweep_stats(const mrvi_sweep *sw);
/* Name of path MRVI_PATH_* ("general", "explicit", ...): the one list. */
const char *mrvi_path_name(int path);

/* Control forces of the next steps (optimal control, src/ocp/): f_rows
 * (n_unknowns of the step) and f_end (ns + nf) as in struct mrvi_step, read
 * at every step (the caller updates them in place between steps); NULL for
 * none.  Every path honours them (doc/solver.md). */
void mrvi_integrator_set_forces(mrvi_integrator *it, const double *f_rows,
                                const double *f_end);

/* ---------------------------------------------------------------------------
 * Krylov solvers (solver/krylov.c) for blocks beyond the dense limit.
 * ------------------------------------------------------------------------- */
enum { MRVI_CG_OK = 0, MRVI_CG_CURVATURE = 1, MRVI_CG_MAXIT = 2 };
/* Iteration cap of one CG solve (J = M/dt + O(dt K) needs a handful). */
#define MRVI_CG_MAX_IT 200
/* y = A x, returning x^T y (summed over i ascending, as a separate dot
 * product would). */
typedef double (*mrvi_matvec)(void *ctx, const double *x, double *y);
typedef int (*mrvi_matvec_status)(void *ctx, const double *x, double *y);
/* Jacobi-preconditioned CG on A x = b (n) from x = 0; stops at
 * ||r||_inf <= max(atol, rtol ||b||_inf).  MRVI_CG_CURVATURE (with
 * *curvature = p^T A p / p^T p) when A is not positive definite along a
 * search direction, MRVI_CG_MAXIT without convergence.  work: 3 n. */
int mrvi_pcg(int n, mrvi_matvec A, void *ctx, const double *dinv,
             const double *b, double *x, double rtol, double atol, int max_it,
             double *work, int *iterations, double *curvature);
/* Workspace (doubles) of mrvi_gmres. */
size_t mrvi_gmres_work(int n, int restart);
/* Restarted GMRES(restart) on A x = b from x = 0, right-preconditioned by
 * the diagonal dinv; stops at ||r||_2 <= max(atol, rtol ||b||_2) or after
 * max_it iterations (MRVI_CG_MAXIT); an operator status < 0 is returned.
 * If y is not NULL: when the solve ends within its first cycle, *ny = k
 * and x = sum_{j<k} y[j] t_j (up to rounding), t_j the argument of the
 * j-th operator call (y: restart doubles); *ny = -1 after a restart. */
int mrvi_gmres(int n, mrvi_matvec_status A, void *ctx, const double *dinv,
               const double *b, double *x, double rtol, double atol,
               int restart, int max_it, double *work, int *iterations,
               double *y, int *ny);

/* Micro-step Newton matrix J = diag + sum_e scale_e hess_ff(e) of the sweep
 * path on a fixed sparse pattern (solver/sparse_block.c, "sweep-cg"). */
typedef struct mrvi_sblock mrvi_sblock;
/* Pattern of the fast-fast Hessians of the elements elems (n_elems model
 * indices; the sweep's W elements) and the diagonal. */
int mrvi_sblock_create(const mrvi_model *m, const int *elems, int n_elems,
                       mrvi_sblock **out);
void mrvi_sblock_free(mrvi_sblock *sb);
/* Values to zero, then add scale H (n_in x n_in, element ie of the list). */
void mrvi_sblock_zero(mrvi_sblock *sb);
void mrvi_sblock_add_element(mrvi_sblock *sb, int ie, const double *H,
                             int n_in, double scale);
/* Add dscale diag (nf) to the diagonal and solve J x = b in place (b
 * becomes x) by CG, stopping at ||r||_inf <= atol or 1e-12 relative;
 * sparse LU where CG meets non-positive curvature or does not converge
 * (counted in the stats with the reason). */
int mrvi_sblock_solve(mrvi_sblock *sb, const double *diag, double dscale,
                      double *b, double atol, char *msg, size_t len);
const mrvi_krylov_stats *mrvi_sblock_stats(const mrvi_sblock *sb);

/* A potential class compiled for evaluation (solver/terms.c): the elements
 * elems (n_elems model indices) with input c read from and summed into
 * column col_of[c] (col_of NULL: column c) of a packed configuration. */
typedef struct mrvi_terms mrvi_terms;
int mrvi_terms_create(const mrvi_model *m, const int *elems, int n_elems,
                      const int *col_of, mrvi_terms **out);
void mrvi_terms_free(mrvi_terms *kc);
/* g += scale grad Z(z) and, if J, J += hscale hess Z(z) (ld x ld, row-major
 * on the columns). */
void mrvi_terms_eval(mrvi_terms *kc, const double *z, double scale, double *g,
                     double *J, int ld, double hscale);
/* g += grad Z(z) and J = hess Z(z) (ld x ld, cleared here: the caller
 * need not): mrvi_terms_eval at unit scales into a cleared J.  For a class
 * of compact terms (mrvi_terms_flat) with distinct inputs per term, a
 * term's product (phi'' a_j) a_l is formed for j < l only and its sum with
 * the entry (col_j, col_l) written to both (col_j, col_l) and
 * (col_l, col_j): J exactly symmetric, the gradient mrvi_terms_eval's
 * bitwise, the Hessian its sums in the same order with the products of one
 * triangle (round-off apart the same; bitwise where the products are
 * exact, e.g. coefficients +-1). */
void mrvi_terms_eval_set(mrvi_terms *kc, const double *z, double *g, double *J,
                         int ld);
/* g += grad Z(z): mrvi_terms_eval with scale 1 and no Hessian (the same
 * kernels without their Hessian part), bitwise the same. */
void mrvi_terms_grad(mrvi_terms *kc, const double *z, double *g);
/* Whether mrvi_terms_grad takes the flat loop (every term linear or a small
 * integer power on 2..4 inputs): 1 with one law for all, 2 with mixed laws,
 * 0 (the kernel per run) otherwise. */
int mrvi_terms_flat(const mrvi_terms *kc);
/* For a flat class (mrvi_terms_flat): the number of its terms; g +=
 * grad Z(z) (mrvi_terms_grad's, bitwise) with dsum[r] += w phi_r''(z) for
 * each term r; and J += sum_r dsum[r] a_r a_r^T over the columns below lim
 * (ld x ld, row-major): a weighted sum of Hessians at many points from
 * one scalar per term and point. */
int mrvi_terms_count(const mrvi_terms *kc);
void mrvi_terms_grad_d2(const mrvi_terms *kc, const double *z, double *g,
                        double w, double *dsum);
void mrvi_terms_hess_d2(const mrvi_terms *kc, const double *dsum, double *J,
                        int ld, int lim);
/* Whether every element of the class is quadratic
 * (mrvi_element_is_quadratic): its Hessian is constant. */
int mrvi_terms_quadratic(const mrvi_terms *kc);
/* The gradient of a quadratic class on n packed columns as the affine map
 * g0 + H z: g0 (n) and H (n x n, row-major) newly allocated, evaluated at
 * z = 0.  MRVI_ENOMEM (nothing allocated) or MRVI_OK. */
int mrvi_terms_affine(mrvi_terms *kc, int n, double **g0, double **H);
/* Z(z): the sum of the elements' values in their order, bitwise
 * mrvi_model_potential's (the same products and additions). */
double mrvi_terms_value(mrvi_terms *kc, const double *z);
/* phi'(s) and phi''(s) of term element e's law (the linear law and small
 * integer powers without the law table). */
void mrvi_term_derivs(const mrvi_element *e, double s, double *d1, double *d2);

/* Predictor of the Newton paths (solver/predict.c): an explicit multirate
 * sweep (Stoermer-Verlet on both grids) from the known data of st, written
 * into x (n_unknowns) as displacements from (q_k^s, q_k^{f,0}). */
typedef struct mrvi_predictor mrvi_predictor;
int mrvi_predictor_create(const mrvi_model *m, const mrvi_step *st,
                          mrvi_predictor **out);
void mrvi_predictor_free(mrvi_predictor *pr);
/* The Newton tolerance of the step: where the slow row is far from solved
 * the predictor solves it by Newton steps on the sweep (predict.c); without
 * a tolerance it makes the fixed-point update only. */
void mrvi_predictor_set_tolerance(mrvi_predictor *pr, double tol);
/* The sweep, or free flight where the sweep would be unstable (see
 * predict.c) or produces non-finite values. */
void mrvi_predict_checked(mrvi_predictor *pr, const mrvi_step *st, double *x);
/* Shooting on the slow unknowns, from the predictor's start, into x
 * (predict.c, mrvi_predict_shoot): 1 solved (*cycles updates; slow
 * residual within target, the fast rows solved by the sweep), 2 solved
 * but for the last update, made without the sweep after it (the caller
 * checks the exact residual), 0 not within max updates (x a Newton
 * iterate if *cycles > 0), -1 non-finite.  Available where the sweep
 * solves every fast row exactly (mrvi_predictor_shoot_ok). */
int mrvi_predict_shoot(mrvi_predictor *pr, const mrvi_step *st, double *x,
                       double target, int max, int *cycles);
int mrvi_predictor_shoot_ok(const mrvi_predictor *pr, const mrvi_step *st);
/* Whether the one-point sweep solves rows with points inside the micro
 * intervals exactly (a W affine and diagonal in the fast nodes alone,
 * inside; V not: predict.c, wexact), where the general sweep estimates
 * their force. */
int mrvi_predictor_exact_inside(const mrvi_predictor *pr);
/* Free flight: the momenta of node k held over the step (displacements). */
void mrvi_predict_free_flight(const mrvi_step *st, double *x);
/* The slow pre-solve (predict.c, pre_solve): whether the predictor uses
 * it (chosen at creation), switched off with on = 0 (tests: the path
 * without it); returns the previous setting. */
int mrvi_predictor_presolve(mrvi_predictor *pr, int on);
/* Sweeps of the fast nodes in the last prediction (1, or more where the
 * slow row's solve moved the slow path by more than the re-sweep
 * threshold; the pre-solve's linear sweep not counted). */
int mrvi_predictor_sweeps(const mrvi_predictor *pr);
/* The sweep for one point per micro interval in each class (predict.c,
 * sweep1_k): whether the predictor takes it (chosen at creation), switched
 * off with on = 0 and back on with 1 (tests: the generic sweep); returns the
 * previous setting. */
int mrvi_predictor_one_point(mrvi_predictor *pr, int on);
/* Largest frequency sqrt(max eig M^-1 hess(V + W)) at the initial state,
 * by power iteration (0 if not positive). */
double mrvi_predictor_omega_max(mrvi_predictor *pr);

/* Newton matrix of an unconstrained step by block elimination
 * (solver/blocks.c): Schur complement on the slow block, block forward
 * sweeps over the micro nodes for the fast block. */
typedef struct mrvi_blocks mrvi_blocks;
int mrvi_blocks_create(const mrvi_step *st, mrvi_blocks **out);
void mrvi_blocks_free(mrvi_blocks *b);
/* Factorise J by block elimination and keep the factors: the blocks of the
 * last mrvi_blocks_assemble with jac if not yet factored, else the CSC
 * values st->Ax (n_unknowns); MRVI_ESINGULAR if a block is singular. */
int mrvi_blocks_factor(mrvi_blocks *b, const mrvi_step *st);
/* The residual R (n_unknowns) of st at the displacements x
 * (st->increments; unconstrained, no step hook st->extra; the control
 * forces st->f_rows added) with the potential momenta
 * into st->mom_ps / mom_pf when set, as mrvi_step_assemble, and, if jac,
 * the Newton matrix straight into the blocks (no CSC); MRVI_EINVAL where
 * this does not apply (then use mrvi_step_assemble). */
int mrvi_blocks_assemble(mrvi_blocks *b, const mrvi_step *st, const double *x,
                         double *R, int jac);
/* Solve J dx = R with the kept factors. */
void mrvi_blocks_solve(const mrvi_blocks *b, const double *R, double *dx);
/* mrvi_blocks_factor, then mrvi_blocks_solve of R: the same dx, with
 * A_ff^-1 R_f computed in the forward sweep of the factorisation. */
int mrvi_blocks_factor_solve(mrvi_blocks *b, const mrvi_step *st,
                             const double *R, double *dx);
/* Chord matrix (doc/solver.md, "Newton details"): 1 if the step's
 * structure admits it (every class whose Hessian is not constant has one
 * point per micro interval, the points of intervals 1..p-1 have the same
 * weights, the constant part of the matrix is the same in the row blocks
 * from 2 on); then mrvi_blocks_chord(b, 1) makes the next assemblies with
 * jac freeze those Hessians (the mean of those at the step's first and
 * last points, mrvi_blocks_chord_spread): the fast row blocks from 2 on are then equal, assembled and
 * factored once.  The residual stays exact. */
int mrvi_blocks_chord_ok(const mrvi_blocks *b);
void mrvi_blocks_chord(mrvi_blocks *b, int on);
/* Largest entry of |H_last - H_first| over the classes whose Hessian is
 * not constant, H at the step's last and first points at x, over the
 * smallest mass (the a-priori measure of the chord matrix's error); keeps
 * their mean as the frozen Hessian of the next chord assembly (call it
 * before mrvi_blocks_chord(b, 1) at the predictor of every step). */
double mrvi_blocks_chord_spread(mrvi_blocks *b, const mrvi_step *st,
                                const double *x);
/* Constant chord (doc/solver.md, "Newton details"): factor the constant
 * part of the Newton matrix (kinetic rows, classes with a constant
 * Hessian) once, at the first call (x: the step's displacements, if the
 * constant part is not made yet), and keep its factors apart from the
 * step's; MRVI_EINVAL where the direct assembly does not apply, or the
 * factorisation's status (the same at every later call). */
int mrvi_blocks_const_factor(mrvi_blocks *b, const mrvi_step *st,
                             const double *x);
/* Solve J_const dx = R with those factors, and x -= dx (n_unknowns). */
void mrvi_blocks_const_solve(const mrvi_blocks *b, const double *R,
                             double *dx, double *x);
/* Largest row sum of |hess Z(q0)| over the classes whose Hessian is not
 * constant and enters the Newton matrix, at the model's initial
 * configuration, over the smallest mass (the a-priori measure of the
 * constant chord's error, times dT^2; 0 where the constant part is the
 * whole Newton matrix). */
double mrvi_blocks_const_measure(mrvi_blocks *b, const mrvi_step *st);
/* The integrator's choice of the chord matrix on the schur path (tests
 * force either): by its rule (auto, the default), never, or for the first
 * update of every step where the structure admits it. */
enum { MRVI_CHORD_AUTO = 0, MRVI_CHORD_OFF = 1, MRVI_CHORD_ON = 2 };
void mrvi_integrator_set_chord(mrvi_integrator *it, int mode);
/* The same for the constant chord (mrvi_blocks_const_factor): by its rule
 * (auto), never, or for the first update of every schur step. */
void mrvi_integrator_set_const_chord(mrvi_integrator *it, int mode);
/* The same for shooting (mrvi_predict_shoot; auto: where the predictor
 * admits it and the constant chord does not take the step), the steps it
 * solved in the run and, of those, the steps whose last update was made
 * without its sweep. */
void mrvi_integrator_set_shoot(mrvi_integrator *it, int mode);
long mrvi_integrator_shoot_steps(const mrvi_integrator *it);
long mrvi_integrator_shoot_last_steps(const mrvi_integrator *it);
/* Factorisations of the schur path so far (the constant chord's counted
 * once). */
long mrvi_integrator_factorisations(const mrvi_integrator *it);

/* The same elimination with iterative solves for blocks beyond the dense
 * limit (solver/schur_krylov.c): GMRES on the Schur complement of the slow
 * unknowns, CG on the diagonal blocks of the forward sweeps, working on
 * st's CSC Jacobian (after mrvi_step_build_pattern). */
typedef struct mrvi_skrylov mrvi_skrylov;
int mrvi_skrylov_create(const mrvi_step *st, mrvi_skrylov **out, char *msg,
                        size_t len);
void mrvi_skrylov_free(mrvi_skrylov *k);
/* Take the Jacobian now in st->Ax (preconditioners); solves use it until
 * the next call. */
void mrvi_skrylov_factor(mrvi_skrylov *k);
/* Solve J dx = R; a sparse LU of the whole step where CG meets
 * non-positive curvature or an iteration does not converge (counted with
 * the reason in the stats, kept until the next mrvi_skrylov_factor). */
int mrvi_skrylov_solve(mrvi_skrylov *k, const double *R, double *dx, char *msg,
                       size_t len);
const mrvi_krylov_stats *mrvi_skrylov_stats(const mrvi_skrylov *k);

/* ---------------------------------------------------------------------------
 * Linear solves with a factorisation kept between calls (solver/newton.c):
 * mrvi_newton_solve factorises and solves; mrvi_linsolve_solve solves again
 * with the kept factors, with A (transpose = 0) or A^T (transpose = 1) --
 * the one interface for Newton updates and adjoint solves, whichever the
 * backend.
 * ------------------------------------------------------------------------- */
/* Factorise A (values Ax on the fixed pattern) and keep the factors. */
int mrvi_newton_factor(mrvi_newton *nw, const double *Ax, char *msg,
                       size_t len);
/* Solve A x = b or A^T x = b with the kept factors (n = the create size). */
int mrvi_linsolve_solve(mrvi_newton *nw, const double *Ax, int transpose,
                        const double *b, double *x, char *msg, size_t len);

#endif
