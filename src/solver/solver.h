/* What src/solver/ offers the layers above it: one step's equations
 * solved -- Newton with kept factorisations (newton.c), the null-space
 * form (nullspace.c), the structured paths (sweep.c, blocks.c,
 * schur_krylov.c), Krylov solvers (krylov.c, sparse_block.c), compiled
 * potential classes (terms.c) and the predictor (predict.c). */
#ifndef MRVI_SOLVER_H
#define MRVI_SOLVER_H

#include "step/step.h"

/* ---------------------------------------------------------------------------
 * Discrete null-space form (nullspace.c, doc/constraints.md): the dynamic rows
 * are premultiplied by P^T with P^T C = 0, which removes the multipliers.
 * ------------------------------------------------------------------------- */
typedef struct mrvi_nullspace mrvi_nullspace;
/* After mrvi_step_build_pattern: reduced pattern (size mrvi_nullspace_size).
 * drop (model rows, may be NULL): the redundant rows to leave out.
 * tree 1: open chains, trees and slow closed loops of bodies in joints take
 * the joint-reduced basis where st->tuning.nullspace_tree allows
 * (nullspace_tree.c), open chains and trees of slow particles on rods the
 * link-local basis (nullspace_rods.c), whose
 * system is larger than n_unknowns (the first n_unknowns entries of its
 * solution are dx); 0: the numerical basis always. */
int mrvi_nullspace_create(const mrvi_step *st, const unsigned char *drop,
                          int tree, mrvi_nullspace **out, char *msg,
                          size_t len);
void mrvi_nullspace_free(mrvi_nullspace *z);
/* Of the redundant rows the rank-revealing pass finds at q
 * (mrvi_constraints_rank), how many are enforced at micro nodes (a closed
 * loop of fast bodies: the numerical basis leaves them out at every micro
 * node); MRVI_ENOMEM. */
int mrvi_nullspace_micro_redundant(const mrvi_model *m, const double *q);
/* Multipliers lambda(x) (written to x + n_unknowns) from the residual F of
 * the full system assembled at lambda = 0; also factors the node blocks
 * used by mrvi_nullspace_reduce. */
int mrvi_nullspace_lambda(mrvi_nullspace *z, mrvi_step *st, double *x,
                          const double *F, char *msg, size_t len);
/* Reduced matrix [P^T A; H] (values on its own pattern) and right-hand side
 * [P^T R; h] from the full system assembled at lambda(x). */
void mrvi_nullspace_reduce(mrvi_nullspace *z, const mrvi_step *st,
                           const double *R, double *rhs);
/* Nodal reparametrisation (doc/multibody.md): the number of free bodies
 * whose new nodes (a slow body's new macro node, a fast body's micro nodes
 * z^1..z^p) are the previous node's phi + u, exp(th^) d^i (2-D: R(th) d^i)
 * (0: none, the basis is numerical and x -= dx).  mrvi_nullspace_start puts
 * the predictor's directors on that form; mrvi_nullspace_retract makes the
 * Newton update x -= dx with the bodies' directors rotated (th from dx), so
 * that the internal constraints hold to round-off at every iterate. */
int mrvi_nullspace_reparametrised(const mrvi_nullspace *z);
void mrvi_nullspace_start(mrvi_nullspace *z, const mrvi_step *st, double *x);
void mrvi_nullspace_retract(mrvi_nullspace *z, const mrvi_step *st, double *x,
                            const double *dx);
/* Column k (0..D(D-1)/2-1) of the rotation block of a free body's analytic
 * null-space matrix at directors d (D x D, rows d^1..d^D), written to v
 * (D x D, the director increments): e_k x d^i in 3-D (the columns of
 * -d^i^), J d^i in 2-D (J the rotation by +pi/2).  G P = 0 for any d
 * (doc/multibody.md, "Analytic null space"). */
void mrvi_nullspace_body_rotation(int D, const double *d, int k, double *v);
const int *mrvi_nullspace_Ap(const mrvi_nullspace *z);
const int *mrvi_nullspace_Ai(const mrvi_nullspace *z);
const double *mrvi_nullspace_Ax(const mrvi_nullspace *z);
long mrvi_nullspace_nnz(const mrvi_nullspace *z);
/* Size of the reduced system; 1 if it is the joint-reduced one. */
int mrvi_nullspace_size(const mrvi_nullspace *z);
int mrvi_nullspace_joint_reduced(const mrvi_nullspace *z);
/* 1 if m's bodies and joints form open chains, trees or slow closed loops
 * the joint-reduced basis covers (nullspace_tree.c; constraints at micro
 * nodes aside), why then naming the joints cut to close the loops ("" for
 * none), else 0 and why (e.g. the constraint without a joint reduction). */
int mrvi_nullspace_tree_plan(const mrvi_model *m, char *why, size_t len);
/* 1 if m's fast bodies form open chains and trees of joints among
 * themselves, to the ground or on spherical and revolute joints to slow
 * bodies (their moving grounds), which the joint-reduced basis at the micro
 * nodes covers (nullspace_tree.c, doc/multibody.md "Fast bodies in
 * joints"), else 0 and why (untouched if m has no fast body). */
int mrvi_nullspace_fast_plan(const mrvi_model *m, char *why, size_t len);
/* 1 if every constraint outside the micro nodes is a body's internal one:
 * beside the fast forest, the slow bodies are free (nullspace.c). */
int mrvi_nullspace_slow_side_free(const mrvi_model *m);
/* 1 if m's slow bodies form open chains and trees of slow joints (the
 * micro-node constraints aside), else 0 and why (nullspace_tree.c). */
int mrvi_nullspace_beside_plan(const mrvi_model *m, char *why, size_t len);
/* v <- exp(th^) v (2-D: the rotation by th[0]); th = 1/2 sum_i d^i x w^i,
 * the left inverse of a body's null-space matrix at directors d applied to
 * director increments w; th of the rotation that takes the frame ref
 * closest to the frame w (nullspace.c). */
void mrvi_nullspace_rotate(int D, const double *th, double *v);
void mrvi_nullspace_rotation_of(int D, const double *d, const double *w,
                                double *th);
void mrvi_nullspace_nearest_rotation(int D, const double *ref, const double *w,
                                     double *th);
/* CSR view (x columns only) of the step's CSC matrix (nullspace.c). */
int mrvi_nullspace_csr(const mrvi_step *st, int **start, int **col, int **idx);
/* A reduced system whose row i combines full rows of the step's system:
 * sum over k in rec_start[i] .. rec_start[i+1]-1 of rec_coef[k] times row
 * rec_row[k] (of st->Ax through the CSR view csr_start/csr_idx, and of R),
 * plus, if ext_start is not NULL, the entries ext_coef[ext_start[i] ..
 * ext_start[i+1]-1] in columns of its own.  map takes the matrix's entries,
 * in that order, to their places in Ax (nnz entries of the reduced
 * pattern). */
typedef struct mrvi_row_recipe {
  int n;
  const int *rec_start, *rec_row, *ext_start, *csr_start, *csr_idx, *map;
  const double *rec_coef, *ext_coef;
} mrvi_row_recipe;
/* The reduced matrix (Ax, nnz) and right-hand side rhs (n) of recipe r from
 * the full system st->Ax, R (nullspace.c). */
void mrvi_row_recipe_apply(const mrvi_row_recipe *r, const mrvi_step *st,
                           const double *R, double *Ax, long nnz, double *rhs);
/* The joint-reduced basis (nullspace_tree.c), behind mrvi_nullspace_*:
 * create returns 1 (made), 0 (does not apply: why) or a status < 0. */
typedef struct mrvi_nstree mrvi_nstree;
int mrvi_nstree_create(const mrvi_step *st, const unsigned char *drop,
                       mrvi_nstree **out, char *why, size_t len);
void mrvi_nstree_free(mrvi_nstree *z);
int mrvi_nstree_size(const mrvi_nstree *z);
int mrvi_nstree_bodies(const mrvi_nstree *z);
const int *mrvi_nstree_Ap(const mrvi_nstree *z);
const int *mrvi_nstree_Ai(const mrvi_nstree *z);
const double *mrvi_nstree_Ax(const mrvi_nstree *z);
long mrvi_nstree_nnz(const mrvi_nstree *z);
int mrvi_nstree_lambda(mrvi_nstree *z, mrvi_step *st, double *x,
                       const double *F, char *msg, size_t len);
void mrvi_nstree_reduce(mrvi_nstree *z, const mrvi_step *st, const double *R,
                        double *rhs);
void mrvi_nstree_retract(mrvi_nstree *z, const mrvi_step *st, double *x,
                         const double *dx);
void mrvi_nstree_start(mrvi_nstree *z, const mrvi_step *st, double *x);
/* The link-local basis of open chains and trees of particles on rods
 * (nullspace_rods.c), behind mrvi_nullspace_*: create returns 1 (made), 0
 * (does not apply: why) or a status < 0; its system is [A N; H 0] of size
 * n_total.  _settles: 1 if _start settles the predictor onto the rods
 * (tuning predict_settle, more than MRVI_GRAM_DENSE_MAX rods), which
 * mrvi_nullspace_reparametrised reports;
 * _retract is x -= dx.  _plan: 1 if a model's constraints are slow rods in
 * a forest, else 0 and why. */
typedef struct mrvi_nsrods mrvi_nsrods;
int mrvi_nullspace_rods_plan(const mrvi_model *m, char *why, size_t len);
int mrvi_nsrods_create(const mrvi_step *st, const unsigned char *drop,
                       mrvi_nsrods **out, char *why, size_t len);
void mrvi_nsrods_free(mrvi_nsrods *z);
int mrvi_nsrods_size(const mrvi_nsrods *z);
const int *mrvi_nsrods_Ap(const mrvi_nsrods *z);
const int *mrvi_nsrods_Ai(const mrvi_nsrods *z);
const double *mrvi_nsrods_Ax(const mrvi_nsrods *z);
long mrvi_nsrods_nnz(const mrvi_nsrods *z);
int mrvi_nsrods_settles(const mrvi_nsrods *z);
void mrvi_nsrods_start(mrvi_nsrods *z, const mrvi_step *st, double *x);
void mrvi_nsrods_retract(const mrvi_nsrods *z, double *x, const double *dx);
int mrvi_nsrods_lambda(mrvi_nsrods *z, mrvi_step *st, double *x,
                       const double *F, char *msg, size_t len);
void mrvi_nsrods_reduce(mrvi_nsrods *z, const mrvi_step *st, const double *R,
                        double *rhs);
/* The fast forest (nullspace_tree.c): 1 and *out if mrvi_nullspace_fast_plan
 * holds and its joints' free directions less the kept rows of its cut
 * joints (closed loops) number nfc - r (the fast slots fpos of the
 * micro-node constraints, r their kept rows, fkeep: micro-node row -> its
 * index among the kept ones or -1), 0 and why if not, < 0 out of memory.
 * _columns: the nfc - r columns (nfc entries each, over fpos) of the
 * joint-reduced basis at micro node m of x, Gf the kept rows' fast
 * gradient there (r x nfc; its cut rows reduce the tree's columns), -1 if
 * the cut rows are dependent there; _start, _retract: the nodal
 * reparametrisation of micro nodes 1..p after the slow unknowns are final
 * (the predictor's; xold the iterate before x -= dx). */
int mrvi_nsfast_create(const mrvi_step *st, const int *fpos, int nfc, int r,
                       const int *fkeep, mrvi_nstree **out, char *why,
                       size_t len);
int mrvi_nsfast_bodies(const mrvi_nstree *z);
/* The kept rows of its cut joints (0: an open forest). */
int mrvi_nsfast_cut_rows(const mrvi_nstree *z);
/* The slow bodies beside a fast forest, in open chains and trees of slow
 * joints (mrvi_nullspace_beside_plan): their joint-reduced nodal
 * reparametrisation alone (their basis stays the QR one): _create as
 * mrvi_nsfast_create; _start puts the predictor's q_{k+1} on the joints from
 * q_k, _retract makes x -= dx on their slots the joints' turns and slides
 * (xold the iterate before it; the other slots are the caller's). */
int mrvi_nsslow_create(const mrvi_step *st, mrvi_nstree **out, char *why,
                       size_t len);
void mrvi_nsslow_start(mrvi_nstree *z, const mrvi_step *st, double *x);
void mrvi_nsslow_retract(mrvi_nstree *z, const mrvi_step *st,
                         const double *xold, double *x, const double *dx);
int mrvi_nsfast_columns(mrvi_nstree *z, const mrvi_step *st, double *x, int m,
                        const int *fpos, int nfc, const double *Gf,
                        double *cols);
void mrvi_nsfast_start(mrvi_nstree *z, const mrvi_step *st, double *x);
void mrvi_nsfast_retract(mrvi_nstree *z, const mrvi_step *st,
                         const double *xold, double *x, const double *dx);

/* ---------------------------------------------------------------------------
 * Newton solver: UMFPACK, or a dense LU (dense.c) for matrices of at most
 * dense_max rows (the tuning constant newton_dense_max; solver/newton.c);
 * the caller sees one interface.
 * ------------------------------------------------------------------------- */
/* UMFPACK orders by AMD (its default); matrices of at least this many rows
 * are analysed by METIS (nested dissection) as well, and the ordering whose
 * factors are estimated to have fewer nonzeros is kept.  Below it the
 * second analysis would cost more than it can save (doc/solver.md,
 * "Orderings"). */
#define MRVI_NEWTON_METIS_TRY 4000
/* Up to dense_max rows (newton_dense_max) the dense LU that skips zeros,
 * always up to MRVI_NEWTON_DENSE_SURE rows (UMFPACK's fixed cost per
 * factorisation dominates there); above, UMFPACK where the dense LU's
 * flops in its ordering (a symbolic elimination of the pattern) exceed
 * MRVI_NEWTON_DENSE_RATIO times UMFPACK's estimate (its symbolic analysis):
 * measured on rod chains and bodies, doc/performance/kernels.md ("The
 * dense/sparse switch by flops"). */
#define MRVI_NEWTON_DENSE_SURE 128
#define MRVI_NEWTON_DENSE_RATIO 0.55
typedef struct mrvi_newton mrvi_newton;
mrvi_newton *mrvi_newton_create(int n, const int *Ap, const int *Ai,
                                const double *Ax, int dense_max, char *msg,
                                size_t len);
/* 1 where mrvi_newton_create(n, Ap, Ai, Ax, dense_max, ..) takes the dense
 * LU, 0 where it takes UMFPACK, < 0 out of memory: the same decision (the
 * flops of the dense LU in its ordering against UMFPACK's estimate) without
 * the backends' storage; Ax may be NULL (the pattern's entries all taken
 * as nonzero by UMFPACK's analysis).  The general path's cost estimate
 * (solver/path_cost.c) takes it. */
int mrvi_newton_dense_chosen(int n, const int *Ap, const int *Ai,
                             const double *Ax, int dense_max);
/* The fill-reducing ordering kept: UMFPACK_ORDERING_AMD or
 * UMFPACK_ORDERING_METIS (umfpack.h), -1 for the dense backend. */
int mrvi_newton_ordering(const mrvi_newton *nw);
void mrvi_newton_free(mrvi_newton *nw);
/* Factorise A (values Ax on the fixed pattern) and solve A dx = b. */
int mrvi_newton_solve(mrvi_newton *nw, const double *Ax, const double *b,
                      double *dx, char *msg, size_t len);
/* The same without the backend's iterative refinement (UMFPACK_IRSTEP):
 * for Newton updates whose residual the caller re-evaluates exactly. */
int mrvi_newton_update(mrvi_newton *nw, const double *Ax, const double *b,
                       double *dx, char *msg, size_t len);
/* Factorise A once and solve A^T x_i = b_i for nrhs right-hand sides
 * (b, x: nrhs x n, row i contiguous); the adjoint of optimal control. */
int mrvi_newton_solve_transpose(mrvi_newton *nw, const double *Ax, int nrhs,
                                const double *b, double *x, char *msg,
                                size_t len);
/* x_c solving A^T x_c = b_c (A: CSC n x n; b, x: nrhs x n, each
 * contiguous) from solve (nrhs solves with factors kept from an earlier
 * matrix of the same pattern), refined against A to the round-off of each
 * residual (newton.c), the corrections of the right-hand sides not yet
 * there solved together: 1 if all got there, 0 if one gave up after
 * max_refine corrections, a correction that reduced its residual by less
 * than 4, or (phi > 0) where the corrections still needed at its last
 * contraction are more than phi, the cost of a factorisation in
 * corrections (factorise A then); or solve's status; work:
 * 2 MRVI_REFINE_BLOCK n doubles (the right-hand sides go in blocks of that
 * many).  *units: the work done, in corrections (a solve and a residual,
 * sigma the solve's part), summed over the right-hand sides.  The
 * adjoint's transposed steps on schur-bordered. */
enum { MRVI_REFINE_BLOCK = 8 };
typedef int (*mrvi_tsolve_fn)(void *ctx, int nrhs, const double *b, double *x,
                              char *msg, size_t len);
int mrvi_refine_transpose(int n, const int *Ap, const int *Ai, const double *Ax,
                          int nrhs, const double *b, double *x, int max_refine,
                          double phi, double sigma, double *units, double *work,
                          mrvi_tsolve_fn solve, void *ctx, char *msg,
                          size_t len);
/* The same solves starting from the factors kept from an earlier matrix of
 * the same pattern (a previous step, the forward Newton iteration),
 * refined against A (at most max_refine corrections, each a solve with the
 * kept factors) to the round-off of the residual; A is factorised, as by
 * mrvi_newton_solve_transpose, where no factors are kept, max_refine <= 0
 * or the refinement does not get there (*refactored = 1; then its factors
 * are the kept ones).  by_cost: it also gives up where the corrections
 * still needed at the last contraction cost more than a factorisation
 * (mrvi_newton_refactor_cost). */
int mrvi_newton_solve_transpose_kept(mrvi_newton *nw, const double *Ax,
                                     int nrhs, const double *b, double *x,
                                     int max_refine, int by_cost,
                                     int *refactored, char *msg, size_t len);
/* A factorisation's cost over a refinement correction's (a solve with the
 * factors and a residual, A^T x): multiply-adds estimated from the
 * pattern of A and the factors (the dense LU's elimination in its
 * ordering, or UMFPACK's counts of its last factorisation); 0 where
 * unknown (nothing factorised yet). */
double mrvi_newton_refactor_cost(mrvi_newton *nw);

/* ---------------------------------------------------------------------------
 * Structured step solver (solver/sweep.c, doc/solver.md).
 * ------------------------------------------------------------------------- */
/* The step solver paths (doc/solver.md), listed once: X(ID, name) gives
 * MRVI_PATH_ID and the name in output files, `mrvi check` and the
 * integrator's table of paths (integrator/integrator.c). */
#define MRVI_PATH_LIST(X)                                                      \
  X(GENERAL, "general")           /* Newton, sparse LU of the whole step */    \
  X(EXPLICIT, "explicit")         /* no Newton (sweep.c) */                    \
  X(SWEEP, "sweep")               /* explicit slow update, micro steps by      \
                                     dense Newton (sweep.c) */                 \
  X(SCHUR, "schur")               /* Newton, Schur complement on the slow      \
                                     unknowns (blocks.c) */                    \
  X(SWEEP_CG, "sweep-cg")         /* sweep, micro steps by CG                  \
                                     (sparse_block.c) */                       \
  X(SCHUR_KRYLOV, "schur-krylov") /* Newton, GMRES on the slow unknowns        \
                                     and CG block sweeps (schur_krylov.c) */   \
  X(SCHUR_BORDERED, "schur-bordered") /* constrained: Newton, the schur        \
                                         elimination bordered by the           \
                                         constraint rows (bordered.c) */
#define MRVI_PATH_ENUM(id, name) MRVI_PATH_##id,
enum { MRVI_PATH_LIST(MRVI_PATH_ENUM) MRVI_N_PATHS };
#undef MRVI_PATH_ENUM
/* Structural cost estimates of a constrained step's linear algebra per
 * macro step (tuning path_updates Newton updates) on the general and
 * schur-bordered paths, in flops (solver/path_cost.c): the step's size n
 * and estimated nonzeros nnz (multiplier form), the dense slow block a and
 * fast node block b of schur-bordered, the rows at macro and micro nodes;
 * general is HUGE_VAL and bordered 0 beyond newton_dense_max, general
 * HUGE_VAL where general's Newton solver takes UMFPACK within it
 * (general_dense 0: mrvi_newton_dense_chosen on the estimated pattern). */
typedef struct mrvi_path_cost {
  long n, nnz;
  int a, b, r_slow, r_micro;
  int general_dense; /* 1: general's dense LU (costed), 0: UMFPACK */
  double general, bordered;
} mrvi_path_cost;
int mrvi_path_costs(const mrvi_model *m, const mrvi_settings *s,
                    mrvi_path_cost *c);
/* Path for m and s (MRVI_PATH_*); why (may be NULL) gets the reason. */
int mrvi_sweep_path(const mrvi_model *m, const mrvi_settings *s, char *why,
                    size_t len);
/* mrvi_sweep_path with the first element of W that has a slow input
 * known (mrvi_step.fast_on_slow, -1: none), without its pass over the
 * elements. */
int mrvi_sweep_path_of(const mrvi_model *m, const mrvi_settings *s,
                       int fast_on_slow, char *why, size_t len);
typedef struct mrvi_sweep mrvi_sweep;
/* Workspace for the explicit and sweep paths of st (after mrvi_step_init). */
int mrvi_sweep_create(const mrvi_step *st, const mrvi_settings *s,
                      mrvi_sweep **out);
void mrvi_sweep_free(mrvi_sweep *sw);
/* Forget cached forces (after the state is set from outside). */
void mrvi_sweep_reset(mrvi_sweep *sw);
/* last_only 1: mrvi_sweep_step writes every fast node over the last,
 * so that x holds q^{f,p} alone (at x + ns) and pf p^{f,p} alone (nf);
 * 0 (the default): all p nodes.  The arithmetic is the same. */
void mrvi_sweep_set_last_only(mrvi_sweep *sw, int last_only);
/* One step from the known data of st: x (n_unknowns) gets
 * (q_{k+1}^s, q^{f,1..p}), ps1 (ns) the slow momentum at k+1, pf (p x nf)
 * the fast momenta at nodes 1..p (eq:pkfm+).  *iterations: the largest
 * number of Newton iterations of a micro step (0 on the explicit path);
 * *residual: the largest converged micro-row residual. */
int mrvi_sweep_step(mrvi_sweep *sw, const mrvi_step *st, double *x, double *ps1,
                    double *pf, int *iterations, double *residual, char *msg,
                    size_t len);

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
/* Evaluations of grad W (fast class) and grad V (slow class) so far. */
void mrvi_sweep_evals(const mrvi_sweep *sw, long *w, long *v);
/* The linearised chord updates' Hessian-vector products of W
 * (tuning.chord_linear). */
long mrvi_sweep_evals_lin(const mrvi_sweep *sw);
/* sweep-cg: the chord's relaxation ratios summed since creation
 * (mrvi_krylov_stats.sweep_chord_sum). */
double mrvi_sweep_chord_sum(const mrvi_sweep *sw);
/* sweep-cg with tuning.chord_carry: the history the next step takes from
 * this one (the converged implicit forces of the last five rows, the last
 * row's first), part[i] nf entries each; returns nf, or 0 where the next
 * step takes none.  set_history restores it (h: the five parts one after
 * the other, n entries each) after mrvi_sweep_reset, so that a resumed run
 * continues bit for bit; MRVI_EINVAL where this run keeps no history or n
 * is not its nf, MRVI_ENONFINITE for a non-finite entry. */
int mrvi_sweep_history(const mrvi_sweep *sw, const double *part[5]);
int mrvi_sweep_set_history(mrvi_sweep *sw, int n, const double *h, char *msg,
                           size_t len);
/* Name of path MRVI_PATH_* ("general", "explicit", ...): the one list. */
const char *mrvi_path_name(int path);

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
/* mrvi_pcg's pass over rows [i0, i1): x += alpha p, r -= alpha q, and the
 * rows' ||r||_inf and r^T D^-1 r (pcg_parts' parts, sparse_block.c). */
void mrvi_pcg_update(double *x, double *r, const double *p, const double *q,
                     const double *dinv, double alpha, int i0, int i1,
                     double *r_inf, double *rz);
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
typedef struct mrvi_terms mrvi_terms; /* (below) */
/* Pattern of the fast-fast Hessians of the elements elems (n_elems model
 * indices; the sweep's W elements) and the diagonal. */
int mrvi_sblock_create(const mrvi_model *m, const int *elems, int n_elems,
                       int dense_max, mrvi_sblock **out);
void mrvi_sblock_free(mrvi_sblock *sb);
/* The block matrix-free (solver/sparse_block.c, "matrix-free") on the
 * records of kc (mrvi_terms_springs_only; its columns the block's nf
 * rows; dim the model's; kept by the block): no pattern and no values, each
 * product forming the records' Hessian blocks at the configuration of the last
 * assembly (mrvi_sblock_add_terms or its parts, once after a zero: one
 * configuration, which the caller keeps unchanged until the solve and
 * mrvi_sblock_jacobi).  MRVI_EINVAL for another class, MRVI_ENOMEM.
 * mrvi_sblock_free_form: whether sb is. */
int mrvi_sblock_create_free(mrvi_terms *kc, int nf, int dim, int dense_max,
                            mrvi_sblock **out);
int mrvi_sblock_free_form(const mrvi_sblock *sb);
/* Values to zero, then add scale H (n_in x n_in, element ie of the list). */
void mrvi_sblock_zero(mrvi_sblock *sb);
void mrvi_sblock_add_element(mrvi_sblock *sb, int ie, const double *H, int n_in,
                             double scale);
/* An element's compact map (inputs in nb = n / dim blocks of dim
 * coordinates, n <= MRVI_SBLOCK_COMPACT_MAX): cm[bj nb + bi] the index in
 * the values of the entry (row: block bi's first input, column: block bj's
 * first), -1 where either block is slow, and cm[nb nb + bj] the length of
 * block bj's columns; expanded into its n x n indices (row-major, -1 a
 * slow pair): entry (i, j) is base + (j % dim) length + i % dim. */
#define MRVI_SBLOCK_COMPACT_MAX 12
void mrvi_sblock_map_expand(const int *cm, int n, int dim, int *map);
/* g += grad W(z) of the class kc (compiled from the same elems) and
 * scale hess W(z) added to the values (mrvi_terms_eval_sparse): the
 * elements' evaluation and mrvi_sblock_add_element, bitwise. */
void mrvi_sblock_add_terms(mrvi_sblock *sb, mrvi_terms *kc, const double *z,
                           double *g, double scale);
/* The values (nnz, CSC order of the pattern) and y = J x with them as
 * they stand (nf; the CG's product: in row form where the block is in
 * parts, mrvi_sblock_set_parts), for tests. */
const double *mrvi_sblock_values(const mrvi_sblock *sb, long *nnz);
/* The ints of the elements' maps (compact and full), for tests. */
long mrvi_sblock_map_ints(const mrvi_sblock *sb);
void mrvi_sblock_matvec(const mrvi_sblock *sb, const double *x, double *y);
/* Add dscale diag to the diagonal (entry f of diag at f inc: inc 0 where
 * every entry is diag[0]) and solve J x = b in place (b becomes x) by CG,
 * stopping at ||r||_inf <= atol or 1e-12 relative; sparse LU where CG
 * meets non-positive curvature or does not converge (counted in the stats
 * with the reason). */
int mrvi_sblock_solve(mrvi_sblock *sb, const double *diag, int inc,
                      double dscale, double *b, double atol, char *msg,
                      size_t len);
const mrvi_krylov_stats *mrvi_sblock_stats(const mrvi_sblock *sb);
/* After mrvi_sblock_solve: dinv (nf) = 1 / J_ff, and the return value the
 * Gershgorin bound max_f sum_{g != f} |J_fg| / J_ff on the contraction of
 * the Jacobi iteration x += D^-1 (b - J x); HUGE_VAL where a J_ff <= 0. */
double mrvi_sblock_jacobi(const mrvi_sblock *sb, double *dinv);
/* Threads: the block's rows (and columns) in n_part parts,
 * mrvi_part_start(c, nf, n_part) (n_part >= 2, a partition that depends
 * on nf alone; else serial), on threads threads: mrvi_sblock_jacobi's
 * columns, and the CG's product in row form, each row by one thread, its
 * x.y summed per part and the parts' sums in order, so that any number of
 * threads gives the same bits (the serial scatter's to round-off: the
 * values are symmetric to round-off).  MRVI_ENOMEM without memory. */
int mrvi_sblock_set_parts(mrvi_sblock *sb, int n_part, int threads);
int mrvi_sblock_parts(const mrvi_sblock *sb);
/* Part c of mrvi_sblock_add_terms (its columns zeroed first where zero):
 * the gradient and the values of the columns part c owns, the class kc
 * partitioned in the block's parts (mrvi_terms_sparse_parts), so the parts
 * give mrvi_sblock_zero and mrvi_sblock_add_terms's values bitwise. */
void mrvi_sblock_add_terms_part(mrvi_sblock *sb, const mrvi_terms *kc, int c,
                                const double *z, double *g, double scale,
                                int zero);

/* A potential class compiled for evaluation (solver/terms.c): the elements
 * elems (n_elems model indices) with input c read from and summed into
 * column col_of[c] (col_of NULL: column c) of a packed configuration. */
typedef struct mrvi_terms mrvi_terms;
int mrvi_terms_create(const mrvi_model *m, const int *elems, int n_elems,
                      const int *col_of, mrvi_terms **out);
/* The same for gradients alone: mrvi_terms_grad, mrvi_terms_eval with
 * scale 1 and no J, _set_threads, _count, _threads, _flat, _quadratic and
 * _springs_only (no Hessian, value or scaled evaluation), without the full
 * spring records where every spring is a Hooke spring on consecutive
 * columns (the explicit paths' classes). */
int mrvi_terms_create_grad(const mrvi_model *m, const int *elems, int n_elems,
                           const int *col_of, mrvi_terms **out);
/* mrvi_terms_create_grad's records with mrvi_terms_create's gradient bit
 * for bit (its two divisions per Hooke spring, not the one of a
 * gradient-only class of Hooke springs): the predictor's classes, which
 * need the gradient alone beyond the small systems (solver/predict.c). */
int mrvi_terms_create_grad_exact(const mrvi_model *m, const int *elems,
                                 int n_elems, const int *col_of,
                                 mrvi_terms **out);
/* mrvi_terms_create (mode 0), _grad (1) or _grad_exact (2) of the elements
 * elems[0 .. n_elems - 1], or without elems (NULL) of the consecutive
 * elements first .. first + n_elems - 1 (a step class without a list,
 * mrvi_step.elem_first: no temporary list made). */
int mrvi_terms_create_range(const mrvi_model *m, const int *elems, int first,
                            int n_elems, const int *col_of, int mode,
                            mrvi_terms **out);
/* The same for values alone (mrvi_terms_value; col_of NULL): a class of
 * Hooke springs on consecutive columns keeps its khooke records alone, as
 * mrvi_terms_create_grad's, any other class is mrvi_terms_create's. */
int mrvi_terms_create_value(const mrvi_model *m, const int *elems, int n_elems,
                            mrvi_terms **out);
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
/* mrvi_terms_grad on `threads` threads (resolved: >= 1) for a class of
 * springs and anchors alone, in parts that depend on the class, `chunk`
 * (tuning.thread_chunk) and ncol alone, not on the thread count: the
 * number of chunks rounded up to an even count (two threads take equal
 * shares), of sizes equal to within one.  With ncol > 0, part c owns a
 * range of the ncol columns (mrvi_terms_part_columns; the explicit
 * sweep's rows); with ncol = 0, the records in such parts and each
 * column owned by the part of the first record that writes it (few records span
 * parts wherever the records' order follows the columns', whatever the columns'
 * order).  Each part writes its own columns from its records in the serial
 * order, so the gradient is the serial one bitwise for every thread count.
 * Fewer than two parts: one thread.  MRVI_ENOMEM, else MRVI_OK. */
int mrvi_terms_set_threads(mrvi_terms *kc, int threads, int chunk, int ncol);
/* mrvi_terms_set_threads in the caller's n_part parts: owner[col] (n_col
 * entries) the part owning column col (solver/outer.c: each thread's range
 * of the slow and of the fast columns, so that a thread's part writes the
 * columns the thread's own vector loops read).  Each part writes its own
 * columns from its records in the serial order: the serial gradient
 * bitwise, whatever the owners.  A class that is not springs and anchors
 * alone, or that writes a column without an owner, stays serial. */
int mrvi_terms_set_threads_owner(mrvi_terms *kc, int threads, const int *owner,
                                 int n_col, int n_part);
/* mrvi_terms_set_threads in parts of chunk 2^j, the smallest j >= 0 at
 * which the records listed in two parts or more add at most `spread` of
 * the class's records (each is evaluated once per part), or at which a
 * doubling would leave fewer than two parts: fewer, larger parts where
 * many records span parts (a 3-D lattice's records between layers). */
int mrvi_terms_set_threads_spread(mrvi_terms *kc, int threads, int chunk,
                                  int ncol, double spread);
/* The chunk that mrvi_terms_set_threads_spread takes on threads, from the
 * class and ncol alone (whatever the thread count): sweep-cg's chord parts
 * (doc/performance/17-thr17.md).  chunk unchanged where kc is partitioned
 * already, is not springs alone or has no records. */
int mrvi_terms_spread_chunk(mrvi_terms *kc, int chunk, int ncol, double spread);
/* The share for the Newton paths' classes (solver/outer.c,
 * solver/predict.c): on random3d's slow class in parts of 4 096 records
 * most records span two parts (a column belongs to the part of the first
 * record that writes it, a layer back), so each was evaluated twice. */
#define MRVI_TERMS_SPREAD 0.05
/* mrvi_terms_grad and mrvi_terms_grad_part on kc's Hooke springs with one
 * division per spring (u = d / r by the reciprocal of r, as in a
 * gradient-only class) instead of spring_eval's division per axis, where
 * kc is Hooke springs alone (returns whether it is; else nothing
 * changes): the last bits differ from mrvi_terms_eval's gradient. */
int mrvi_terms_set_recip(mrvi_terms *kc);
/* sweep-cg's linearised chord updates (doc/solver.md, "sweep-cg"), on a
 * class of Hooke springs alone after mrvi_terms_set_recip: the doubles of
 * the per-spring Hessian records (2 per spring: t = phi'/r and
 * a = (c - t)/r^2, the Hessian t I + a d d^T of d = x_i - x_j), 0 where
 * the class is not such a class.  mrvi_terms_grad_lin: g += grad Z(z)
 * (mrvi_terms_grad's bits) and the records at z into lin;
 * mrvi_terms_hv_lin: g += s hess Z(z0) x from them (z0 the z of
 * mrvi_terms_grad_lin), no square root, no division.  The _part forms:
 * part c's columns (mrvi_terms_grad_part), the serial values bitwise. */
long mrvi_terms_lin_size(const mrvi_terms *kc);
void mrvi_terms_grad_lin(const mrvi_terms *kc, const double *z, double *g,
                         double *lin);
void mrvi_terms_grad_lin_part(const mrvi_terms *kc, int c, const double *z,
                              double *g, double *lin);
void mrvi_terms_hv_lin(const mrvi_terms *kc, const double *z0,
                       const double *lin, const double *x, double s, double *g);
void mrvi_terms_hv_lin_part(const mrvi_terms *kc, int c, const double *z0,
                            const double *lin, const double *x, double s,
                            double *g);
/* sweep-cg's chord pass fused into the spring loop (doc/solver.md,
 * "sweep-cg"): on a class of Hooke springs alone after
 * mrvi_terms_set_recip whose records are in the serial order, the
 * records in blocks of `block` and, after each, the columns [0, c) that
 * no later record reads or writes (1; 0 where the class is not such a
 * class, nothing kept; MRVI_ENOMEM).  mrvi_terms_fused: kept, and the
 * gradient serial.  mrvi_terms_grad_fused: g = grad Z(z) over the ncol
 * columns (zeroed here, each just before its first sum), mrvi_terms_grad's
 * values bitwise, calling done(ctx, c) each time the complete columns
 * grow to [0, c), last with c = ncol: done may then read g and write z
 * in those columns.  first (or NULL): first(ctx, c) before any record
 * reads z or any sum writes g in the columns beyond the last call's c,
 * with c increasing to ncol: first may read g (its values before this
 * call) and write z in [last c, c), and must zero g there (in place of
 * the kernel's own zeroing: one pass over those columns). */
typedef void (*mrvi_cols_fn)(void *ctx, int c);
int mrvi_terms_set_fused(mrvi_terms *kc, int ncol, int block);
int mrvi_terms_fused(const mrvi_terms *kc);
void mrvi_terms_grad_fused(const mrvi_terms *kc, const double *z, double *g,
                           mrvi_cols_fn first, mrvi_cols_fn done, void *ctx);
/* The threads mrvi_terms_grad runs on (1: the serial loop). */
int mrvi_terms_threads(const mrvi_terms *kc);
/* The parts of a partitioned class (0: not partitioned), and g +=
 * part c's columns of grad Z(z) (the other columns untouched): for a
 * caller's own parallel loop over the parts (the explicit sweep). */
int mrvi_terms_parts(const mrvi_terms *kc);
/* The parts of n items (n >= 1) for threads: the number of `chunk` items
 * rounded up to an even count (two threads take equal shares), part c
 * the items [mrvi_part_start(c), mrvi_part_start(c + 1)) = [c n / n_part,
 * (c+1) n / n_part).  They depend on n and chunk alone. */
int mrvi_even_parts(int n, int chunk);
int mrvi_part_start(int c, int n, int n_part);
/* The columns [*c0, *c1) part c owns (a class partitioned with ncol > 0:
 * mrvi_even_parts of the ncol columns). */
void mrvi_terms_part_columns(const mrvi_terms *kc, int c, int *c0, int *c1);
void mrvi_terms_grad_part(const mrvi_terms *kc, int c, const double *z,
                          double *g);
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
/* Whether kc is a gradient-only class (mrvi_terms_create_grad) of springs
 * of one law and one parameter set on consecutive columns, kept as their
 * columns and rest lengths alone (the law once: 16 bytes a spring). */
int mrvi_terms_shared_law(const mrvi_terms *kc);
/* The bytes kc keeps per element's records (the kterms, columns,
 * coefficients, compact and spring records, run lists; not the few
 * scratch and thread arrays): a full class of springs and anchors alone
 * keeps no kterm (97 bytes an element: its kspring and khooke records and
 * a flag), one of Hooke springs on consecutive columns alone no kspring
 * either (25 bytes). */
long mrvi_terms_bytes(const mrvi_terms *kc);
void mrvi_terms_grad_d2(const mrvi_terms *kc, const double *z, double *g,
                        double w, double *dsum);
void mrvi_terms_hess_d2(const mrvi_terms *kc, const double *dsum, double *J,
                        int ld, int lim);
/* Whether every term of kc is a spring or an anchor; for such a class,
 * g += grad Z(z) (spring_eval's products: mrvi_terms_grad's gradient,
 * bitwise) and hd += hscale times the diagonal of hess Z(z): the diagonal
 * mrvi_terms_eval_sparse adds with the same hscale, bitwise (the same
 * products summed in the same order); unless off is NULL, off += each
 * row's sum of |hscale x| over the elements' off-diagonal Hessian entries
 * x (at least the assembled matrix's off-diagonal row sum: a Gershgorin
 * bound without the assembly). */
int mrvi_terms_springs_only(const mrvi_terms *kc);
/* The Gershgorin bound of D^-1 (H - diag H), H = M/dt + hscale hess Z(z)
 * as assembled, over the rows (max_i sum_{j != i} |H_ij| dinv_i) for such
 * a class: each particle's own off-diagonal block entries summed with
 * their signs over its elements (as the assembly adds them; in s, the
 * pair k < l of a particle's columns at its column k + l - 1) and the
 * entries between the two ends of a spring by absolute value (in o by
 * row; at least the assembled matrix's where two springs join the same
 * pair), s and o (ncol) overwritten; HUGE_VAL where a value is not
 * finite.  The bound of mrvi_terms_grad_hdiag's off without the
 * within-particle sums' cancellations taken as losses (sweep-cg's row 0,
 * doc/solver.md). */
double mrvi_terms_gershgorin(const mrvi_terms *kc, const double *z,
                             double hscale, const double *dinv, double *s,
                             double *o, int ncol);
/* mrvi_terms_gershgorin on part c of a class partitioned by columns
 * (mrvi_terms_set_threads with ncol > 0): pass 0 zeroes the part's
 * columns of s and o and adds its records' entries there, each column's
 * sums in the serial order; pass 1 (after every part's pass 0) returns the
 * largest row bound over the part's columns (NaN where one is).  The
 * parts' pass-1 maxima combined by the same rule, HUGE_VAL where not
 * finite, are mrvi_terms_gershgorin's bound bitwise (sweep-cg's row 0 on
 * threads). */
double mrvi_terms_gershgorin_part(const mrvi_terms *kc, int c, const double *z,
                                  double hscale, const double *dinv, double *s,
                                  double *o, int pass);
void mrvi_terms_grad_hdiag(const mrvi_terms *kc, const double *z, double *g,
                           double *hd, double *off, double hscale);
/* mrvi_terms_grad_hdiag on part c's columns of a partitioned class
 * (mrvi_terms_parts; the other columns untouched): each column's sums in
 * the serial order, so the parts in any order give the serial g, hd and
 * off bitwise (sweep-cg's row 0 on threads). */
void mrvi_terms_grad_hdiag_part(const mrvi_terms *kc, int c, const double *z,
                                double *g, double *hd, double *off,
                                double hscale);
/* g += grad Z(z) and hscale times each element's Hessian added into the
 * values Ax of a sparse matrix: entry k of element i's n_in x n_in Hessian
 * (row-major; i in the order of elems) into Ax[emap[off[i] + k]], or where
 * off[i] < -1 into index k of the compact map at emap - 2 - off[i]
 * (mrvi_sblock_map_expand); left out where off[i] == -1 or that index is
 * < 0.  Springs and anchors by the
 * compiled kernels, the others by mrvi_element_eval; bitwise a scatter of
 * mrvi_element_eval's Hessians element by element. */
void mrvi_terms_eval_sparse(mrvi_terms *kc, const double *z, double *g,
                            double *Ax, const long *off, const int *emap,
                            double hscale);
/* Threads: the parts of a partitioned class (mrvi_terms_set_threads) whose
 * terms are springs and anchors alone, record i element i (else 0), and
 * part c of mrvi_terms_eval_sparse: the gradient and the Hessian entries
 * of the columns part c owns (mrvi_terms_part_columns; in the values, the
 * pattern's columns), each entry's sum in the serial order, so the parts
 * on any threads give mrvi_terms_eval_sparse's values bitwise.  A record
 * with off == -1 adds its gradient alone (the sparse block sets -1 for
 * linear elements only, none of them a spring). */
int mrvi_terms_sparse_parts(const mrvi_terms *kc);
void mrvi_terms_eval_sparse_part(const mrvi_terms *kc, int c, const double *z,
                                 double *g, double *Ax, const long *off,
                                 const int *emap, double hscale);
/* y += scale hess Z(z) x, each record's block formed at z and applied
 * (mrvi_terms_hessvec's spring_block, none assembled) on the columns of
 * part c (mrvi_terms_set_threads; c < 0: every record, all columns), in
 * the records' order: the parts give c = -1's y bitwise.  A class of
 * springs and anchors alone (mrvi_terms_springs_only), partitioned where
 * c >= 0 (mrvi_terms_sparse_parts). */
void mrvi_terms_hessvec_part(const mrvi_terms *kc, int c, const double *z,
                             const double *x, double *y, double scale);
/* The off-diagonal entries of hscale hess Z(z) on the rows of part c
 * (c < 0: all), mrvi_terms_eval_sparse's products: within a particle's
 * own dim x dim block summed into own[0] and own[1] by row (the row's
 * other components in their order; dim 3: both, 2: own[0]), and the
 * absolute values of the entries between the two particles of each
 * spring added into nbr by row, so that |own[0]| + |own[1]| + nbr is
 * the assembled row's off-diagonal absolute sum (more where two springs
 * join the same two particles).  The classes of mrvi_terms_hessvec_part. */
void mrvi_terms_offdiag_part(const mrvi_terms *kc, int c, const double *z,
                             double hscale, double *const own[2], double *nbr);
/* y_v += scale hess Z(z) x_v for the nvec vectors x_v = x + v xs, y_v =
 * y + v ys (on the columns): each element's Hessian formed once and
 * applied to every vector, none assembled (springs and anchors by the
 * compiled kernels' derivatives, the others by mrvi_element_eval; a class
 * of mrvi_terms_create).  The explicit paths' adjoint (ocp/adjoint_explicit.c).
 */
void mrvi_terms_hessvec(mrvi_terms *kc, const double *z, int nvec,
                        const double *x, long xs, double *y, long ys,
                        double scale);
/* The Hessian of a class kept for several products at one z (the
 * explicit-slow adjoint's CG, ocp/adjoint_explicit.c): the number of
 * doubles mrvi_terms_hessblocks writes (per spring or anchor the upper
 * triangle of its block A, dim (dim + 1) / 2; per other element its
 * n x n Hessian; gravity none), -1 for a class without element records
 * (mrvi_terms_create_grad's). */
long mrvi_terms_hessblocks_size(const mrvi_terms *kc);
/* The blocks of hess Z(z) into B (mrvi_terms_hessblocks_size doubles):
 * each formed as mrvi_terms_hessvec forms it, at scale 1. */
void mrvi_terms_hessblocks(mrvi_terms *kc, const double *z, double *B);
/* y_v += scale hess Z x_v for the nvec vectors x_v = x + v xs, y_v = y + v
 * ys, by the blocks B of mrvi_terms_hessblocks: mrvi_terms_hessvec's
 * products without forming the Hessian again (round-off apart the same:
 * the scale multiplies the block here, the block's terms there); unless
 * xhx is NULL, xhx[v] += x_v^T (scale hess Z x_v) as well, element by
 * element (CG's curvature without a pass over y). */
void mrvi_terms_hessblocks_apply(const mrvi_terms *kc, const double *B,
                                 int nvec, const double *x, long xs, double *y,
                                 long ys, double scale, double *xhx);
/* The columns of the blocks of mrvi_terms_hessblocks where each is a
 * spring's or an anchor's (gravity apart): per block, in their order, the
 * dim columns of its first particle into ci + dim b and those of its
 * second into cj + dim b (-1 for an anchor); block b adds A on the
 * diagonal blocks of both particles and -A on the two between them (an
 * anchor: A on its one).  Returns the number of blocks, or -1 where an
 * element has another block (its n x n Hessian) or the class keeps no
 * element records.  ci, cj: room for dim ints per element. */
int mrvi_terms_hessblocks_springs(const mrvi_terms *kc, int *ci, int *cj);
/* Whether every element of the class is quadratic
 * (mrvi_element_is_quadratic): its Hessian is constant. */
int mrvi_terms_quadratic(const mrvi_terms *kc);
/* The gradient of a quadratic class on n packed columns as the affine map
 * g0 + H z: g0 (n) and H (n x n, row-major) newly allocated, evaluated at
 * z = 0.  MRVI_ENOMEM (nothing allocated) or MRVI_OK. */
int mrvi_terms_affine(mrvi_terms *kc, int n, double **g0, double **H);
/* Z(z): the sum of the elements' values in their order, bitwise
 * mrvi_model_potential's (the same products and additions); after
 * mrvi_terms_set_value_chunks on a class of at least two chunks, the sums
 * of chunks of `chunk` elements added in order (round-off apart the same;
 * bitwise the same for every thread count). */
double mrvi_terms_value(mrvi_terms *kc, const double *z);
/* mrvi_terms_value in chunks of `chunk` elements (a class of fewer than
 * two: one sum, unchanged), on `threads` threads where no element needs
 * the class's shared scratch.  MRVI_ENOMEM, else MRVI_OK. */
int mrvi_terms_set_value_chunks(mrvi_terms *kc, int threads, int chunk);

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
 * by power iteration at creation (0 if not positive); or, where it settles
 * every test the paths make of omega_max (dt omega_max <= 1/2 for the
 * predictor's sweep, (omega_max dt)^2 / 4 <= chord_jacobi_max for the
 * outer iteration), Gershgorin's upper bound of it instead, which takes one
 * Hessian per element against the power iteration's 60 gradients: the
 * same decisions (doc/solver.md, "Predictor"). */
double mrvi_predictor_omega_max(mrvi_predictor *pr);
/* The power iteration's estimate of omega_max at the initial state, made
 * afresh (tests: omega_max against it; the predictor's vectors are
 * overwritten, which the steps write before they read). */
double mrvi_predictor_omega_power(mrvi_predictor *pr);

/* The predictor's constraint forces at the micro nodes
 * (solver/predict_joints.c, doc/solver.md "The joint sweep").  create
 * leaves *out NULL (and returns MRVI_OK) where the step has no micro-node
 * constraint. */
typedef struct mrvi_joint_sweep mrvi_joint_sweep;
int mrvi_joint_sweep_create(const mrvi_step *st, mrvi_joint_sweep **out);
void mrvi_joint_sweep_free(mrvi_joint_sweep *w);
/* In a sweep of the displacements x (st->increments; n_total with the
 * multipliers), fast node m + 1 just solved from row m: one Newton update
 * of its move onto the micro-node constraints along M_f^-1 G_f(z^m)^T
 * (again = 0: a new node, its matrix formed; 1: the same node again, the
 * matrix kept; 2: a new node with the matrix of the last sweep's node m,
 * in a sweep along a slightly moved slow path), lambda^m set from the
 * moves.  Returns the node's move so far (nf). */
const double *mrvi_joint_sweep_node(mrvi_joint_sweep *w, const mrvi_step *st,
                                    double *x, int m, int again);
/* fs (ns) += the slow-row force of the micro-node multipliers of x, sum
 * over m of dt (1 - m/p) G_s(z^m)^T lambda^m (G of the last sweep). */
void mrvi_joint_sweep_slow_force(const mrvi_joint_sweep *w, const mrvi_step *st,
                                 const double *x, double *fs);
/* q_{k+1}^s of x onto the slow-only constraints along M_s^-1 G(q_k)^T (two
 * Newton updates), their multipliers set; MRVI_ESINGULAR (x unchanged)
 * where the matrix is singular. */
int mrvi_joint_sweep_slow(mrvi_joint_sweep *w, const mrvi_step *st, double *x);
/* The predictor's sweeps take w's moves (NULL: not) and, with tuning
 * joints_omega, the explicit sweep's bound dt omega_max <= 1/2 is checked
 * on the fast part's frequencies on st's micro-node constraints at the
 * initial state; MRVI_ENOMEM. */
int mrvi_predictor_set_joints(mrvi_predictor *pr, mrvi_joint_sweep *w,
                              const mrvi_step *st);

/* schur-bordered's node blocks beyond bordered_node_max
 * (solver/bordered_sparse.c): each fast node block factored on its own
 * sparse pattern by mrvi_newton, the slow Schur complement dense.  rblk,
 * roff (kept, not copied): the node block (-1 slow) and offset of each of
 * J's rows, ascending within a block.  mrvi_nsparse_factor: st->Ax;
 * MRVI_ESINGULAR where a block or S is singular.  mrvi_nsparse_solve:
 * J dx = R (transpose 0) or J^T dx = R (1) with the last factors. */
typedef struct mrvi_nsparse mrvi_nsparse;
/* The block of schur-bordered's matrix that an entry of J lies in, from
 * the node blocks of its row (rb) and column (cb), -1 slow: the slow
 * block, A_sf, A_fs, a fast node block's D, the blocks L1 and L2 one and
 * two nodes below D, or none (a fast row coupled to a column block after
 * it or more than two before it).  bordered.c's node_create and
 * bordered_sparse.c's lists classify J's entries by it. */
enum {
  MRVI_NODE_SS,
  MRVI_NODE_SF,
  MRVI_NODE_FS,
  MRVI_NODE_D,
  MRVI_NODE_L1,
  MRVI_NODE_L2,
  MRVI_NODE_OUTSIDE
};
static inline int mrvi_node_class(int rb, int cb) {
  if (rb < 0)
    return cb < 0 ? MRVI_NODE_SS : MRVI_NODE_SF;
  if (cb < 0)
    return MRVI_NODE_FS;
  return cb == rb       ? MRVI_NODE_D
         : cb == rb - 1 ? MRVI_NODE_L1
         : cb == rb - 2 ? MRVI_NODE_L2
                        : MRVI_NODE_OUTSIDE;
}
int mrvi_nsparse_create(const mrvi_step *st, const int *rblk, const int *roff,
                        mrvi_nsparse **out);
void mrvi_nsparse_free(mrvi_nsparse *ns);
int mrvi_nsparse_factor(mrvi_nsparse *ns, const mrvi_step *st, char *msg,
                        size_t len);
int mrvi_nsparse_solve(mrvi_nsparse *ns, int transpose, const double *R,
                       double *dx, char *msg, size_t len);

/* The schur-bordered path (solver/bordered.c): a constrained step's
 * Newton matrix [A B; C E] in the multiplier form by the block elimination
 * of A (blocks.c) bordered by the multipliers. */
typedef struct mrvi_bordered mrvi_bordered;
int mrvi_bordered_create(const mrvi_step *st, mrvi_bordered **out);
void mrvi_bordered_free(mrvi_bordered *bd);
/* Factorise the CSC Jacobian st->Ax (n_total) and solve J dx = R
 * (n_total); MRVI_ESINGULAR with a message if it is singular. */
int mrvi_bordered_factor_solve(mrvi_bordered *bd, const mrvi_step *st,
                               const double *R, double *dx, char *msg,
                               size_t len);
/* Solve J dx = R with the factors of the last mrvi_bordered_factor_solve
 * (st->Ax still the Jacobian it factorised): the kept factors of a
 * simplified Newton update. */
int mrvi_bordered_solve(mrvi_bordered *bd, const mrvi_step *st, const double *R,
                        double *dx, char *msg, size_t len);
/* Factorise st->Ax alone (the adjoint's steps, src/ocp/adjoint.c), and
 * solve J^T dx = R with the factors of the last factorisation (st->Ax still
 * the Jacobian it factorised): the transposed step by the same block
 * elimination run backwards. */
int mrvi_bordered_factor(mrvi_bordered *bd, const mrvi_step *st, char *msg,
                         size_t len);
int mrvi_bordered_solve_transpose(mrvi_bordered *bd, const mrvi_step *st,
                                  const double *R, double *dx, char *msg,
                                  size_t len);
/* The same for nrhs right-hand sides (R, dx: nrhs x n_total, each
 * contiguous), with work (nrhs n_total doubles): on the chain elimination
 * all in one pass over the factors (mrvi_chain_solve_transpose_n), else
 * one after the other; each as alone (the same operations in order). */
int mrvi_bordered_solve_transpose_n(mrvi_bordered *bd, const mrvi_step *st,
                                    int nrhs, const double *R, double *dx,
                                    double *work, char *msg, size_t len);
/* Whether bd solves with the chain elimination (solver/chain.c; not
 * fallen back to the LU of the whole step). */
int mrvi_bordered_on_chain(const mrvi_bordered *bd);
/* A factorisation's cost in kept-factor updates (a solve and a residual)
 * where the factors are the chain elimination's (its flop ratio over 3: the
 * residual measured at 1.5-2 times the solve, doc/solver.md, "Newton
 * details"); 0 elsewhere (no estimate: the reuse_rate rule alone). */
double mrvi_bordered_refactor_cost(const mrvi_bordered *bd);
/* The same for the adjoint's transposed solves (src/ocp/adjoint.c), also
 * where the factors are the node blocks' (multiply-adds from their sizes
 * and lists; st the step bd was made for), with in *solve_share the
 * solve's part of an update (0.5 where not estimated); 0 for the bordered
 * slow block and the whole step's LU.  (The forward pass's rule,
 * mrvi_bordered_refactor_cost, keeps the chain elimination's alone.) */
double mrvi_bordered_transpose_cost(const mrvi_bordered *bd,
                                    const mrvi_step *st, double *solve_share);

/* The chain elimination of schur-bordered (solver/chain.c): the step of a
 * model whose coupling graph is a chain or a tree, block tridiagonal along
 * its breadth-first levels.  mrvi_chain_levels: the level of each of m's
 * coordinates; returns the number of levels, 0 if the levels' parts form a
 * cycle (a closed loop).  mrvi_chain_blocks: the levels merged into blocks
 * (blk: m->n), the widest in step unknowns at p micro nodes in *width;
 * returns their number (0: a loop).  mrvi_chain_wanted: 1 where s puts the
 * constrained step beyond schur-bordered's dense limits (bordered_max,
 * bordered_node_max) and m is a chain or a tree of at least two blocks of
 * at most chain_block_max unknowns (their number and width set), else 0.
 * mrvi_chain_create: the chain elimination of st where mrvi_chain_wanted
 * (with st's model, p and tuning) is 1, else *out NULL and MRVI_OK (the
 * blocks found once); MRVI_EINVAL if st's Jacobian pattern is not block
 * tridiagonal in those blocks; mrvi_chain_factor: the CSC values Ax (st's
 * pattern), MRVI_ESINGULAR if a block is singular; mrvi_chain_solve:
 * J dx = R with the factors; mrvi_chain_solve_transpose: J^T dx = R with
 * the same factors (the elimination run backwards);
 * mrvi_chain_factor_ratio: the flops of a factorisation over a solve's
 * (the pattern's estimate). */
typedef struct mrvi_chain mrvi_chain;
int mrvi_chain_levels(const mrvi_model *m, int *level);
int mrvi_chain_blocks(const mrvi_model *m, int p, int *blk, int *width);
int mrvi_chain_wanted(const mrvi_model *m, int p, const mrvi_tuning *t,
                      int *n_blocks, int *width);
int mrvi_chain_create(const mrvi_step *st, mrvi_chain **out);
int mrvi_chain_factor(mrvi_chain *ch, const double *Ax);
void mrvi_chain_solve(const mrvi_chain *ch, const double *R, double *dx);
void mrvi_chain_solve_transpose(const mrvi_chain *ch, const double *R,
                                double *dx);
/* J^T dx_c = R_c for nrhs right-hand sides (R, dx: nrhs x n, each
 * contiguous) in one pass over the factors (y: nrhs n doubles), each as
 * mrvi_chain_solve_transpose alone. */
void mrvi_chain_solve_transpose_n(const mrvi_chain *ch, int nrhs,
                                  const double *R, double *dx, double *y);
double mrvi_chain_factor_ratio(const mrvi_chain *ch);
void mrvi_chain_free(mrvi_chain *ch);

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
/* Solve J^T dx = R with the kept factors (the adjoint's transposed step,
 * src/ocp/adjoint.c, through bordered.c). */
void mrvi_blocks_solve_transpose(const mrvi_blocks *b, const double *R,
                                 double *dx);
/* r (ns x nrhs row-major) becomes S^-1 r, S = A_ss - A_sf A_ff^-1 A_fs the
 * kept Schur complement: the slow block of J^-1 (bordered.c). */
void mrvi_blocks_slow_solve(const mrvi_blocks *b, double *r, int nrhs);
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
 * last points, mrvi_blocks_chord_spread): the fast row blocks from 2 on are
 * then equal, assembled and factored once.  The residual stays exact. */
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
void mrvi_blocks_const_solve(const mrvi_blocks *b, const double *R, double *dx,
                             double *x);
/* Largest row sum of |hess Z(q0)| over the classes whose Hessian is not
 * constant and enters the Newton matrix, at the model's initial
 * configuration, over the smallest mass (the a-priori measure of the
 * constant chord's error, times dT^2; 0 where the constant part is the
 * whole Newton matrix). */
double mrvi_blocks_const_measure(mrvi_blocks *b, const mrvi_step *st);

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
/* The same with the values Ax on st's pattern (another step's Jacobian,
 * e.g. the adjoint's); Ax must stay valid while solves use it. */
void mrvi_skrylov_factor_values(mrvi_skrylov *k, const double *Ax);
/* Solve J dx = R (transpose = 0) or J^T dx = R (1: the same elimination
 * run backwards, doc/solver.md, "schur-krylov"); a sparse LU of the whole
 * step where CG meets non-positive curvature or an iteration does not
 * converge (counted with the reason in the stats, kept until the next
 * mrvi_skrylov_factor). */
int mrvi_skrylov_solve(mrvi_skrylov *k, int transpose, const double *R,
                       double *dx, char *msg, size_t len);
/* The relative tolerances of its block CG solves and of GMRES (default:
 * tuning.krylov_cg_rtol, tuning.krylov_gmres_rtol). */
void mrvi_skrylov_set_rtol(mrvi_skrylov *k, double cg_rtol, double gmres_rtol);
const mrvi_krylov_stats *mrvi_skrylov_stats(const mrvi_skrylov *k);

/* schur-krylov's matrix-free step (solver/outer.c, doc/solver.md,
 * "schur-krylov: the outer iteration"): a nonlinear block Gauss-Seidel
 * iteration of fast sweeps by the Jacobi chord and slow chord updates on
 * an unconstrained step, no Jacobian.  mrvi_outer_solve starts from x
 * (displacements, mrvi_step.increments; the predictor's) and returns the
 * sweeps made (> 0) where every row of the step came within target
 * (residuals weighted by rw, n_unknowns, NULL: unweighted; or at the
 * rounding floor of its terms), with the largest in *res and the potential
 * parts of the momenta at x (as mrvi_step_assemble's mom_ps, mom_pf) in
 * ps1 (ns) and pf (p x nf), 0 where an
 * update contracted by less than rate, more than max_sweeps were needed
 * or values were non-finite (x then holds no solution).  Where a class's
 * gradient is in parts (mrvi_terms_set_threads), a step runs on
 * mrvi_step.threads threads in one parallel region, with the same bits
 * for every count. */
typedef struct mrvi_outer mrvi_outer;
typedef struct mrvi_outer_stats {
  long steps;        /* steps tried */
  long sweeps;       /* fast sweeps (outer iterations) */
  long slow_updates; /* slow chord updates */
  long row_updates;  /* fast-row chord updates */
  long site_evals;   /* gradient evaluations at a configuration */
  double grad_equiv; /* the evaluations (and the slow-only terms' once a
                        sweep) weighted by their share of V's and W's
                        terms: gradients of V + W they are worth */
  long failed;       /* steps that did not converge */
} mrvi_outer_stats;
int mrvi_outer_create(const mrvi_model *m, const mrvi_step *st,
                      mrvi_outer **out);
/* The outer iteration's Jacobi chord contraction on the fast rows at
 * omega_max, (omega_max dt)^2 / 4: the outer iteration is chosen where it
 * is at most chord_jacobi_max (integrator.c), and the predictor takes a
 * Gershgorin bound of omega_max in place of the power iteration only where
 * the bound passes this test too (predict.c). */
static inline double mrvi_outer_contraction(double omega, double dt) {
  return 0.25 * (omega * dt) * (omega * dt);
}
void mrvi_outer_free(mrvi_outer *o);
int mrvi_outer_solve(mrvi_outer *o, const mrvi_step *st, double *x,
                     const double *rw, double target, double rate,
                     int max_sweeps, double *ps1, double *pf, double *res);
const mrvi_outer_stats *mrvi_outer_stats_of(const mrvi_outer *o);

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
/* UMFPACK's iterative refinement off for every later solve of nw (the
 * sparse node blocks of schur-bordered, solver/bordered_sparse.c: a step
 * of a solve there, whose caller checks the whole step's residual). */
void mrvi_newton_no_refine(mrvi_newton *nw);
/* Solve A x = b or A^T x = b with the kept factors (n = the create size). */
int mrvi_linsolve_solve(mrvi_newton *nw, const double *Ax, int transpose,
                        const double *b, double *x, char *msg, size_t len);

#endif
