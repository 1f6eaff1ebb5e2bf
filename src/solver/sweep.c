/* Structured step solver (doc/solver.md): an explicit slow update and a
 * forward sweep over the micro nodes, for schemes whose slow potential V is
 * evaluated on the macro grid (eq:slow_potential_affine) and models whose
 * fast potential W depends on fast coordinates only.
 *
 * Step equations (eq:DEL_ini in position-momentum form, see step.c):
 *   slow row   p_k^s - M^s (q_{k+1}^s - q_k^s)/dT - a dT grad_s V(q_k) = 0
 * (the end point of V_d has a0 = 0 and feeds no row), so q_{k+1}^s is
 * explicit.  Fast row of node m (0..p-1), with the discrete momentum
 *   p^{f,m} = M^f (q^m - q^{m-1})/dt - sum_{pts of interval m-1} w cB grad W
 * (eq:pkfm+; p^{f,0} = p_k^{f,0} - a dT grad_f V(q_k) for row 0):
 *   p^{f,m} - M^f (q^{m+1} - q^m)/dt - sum_{pts of interval m} w cA grad W(z)
 *   = 0,   z = cA q^m + cB q^{m+1}.
 * Control forces (optimal control, mrvi_step.f_rows / f_end) are constants
 * of the step: f_rows adds to the row's momentum, f_end to p_{k+1}.
 * It involves nodes up to m + 1 only (block lower-triangular), so the step is
 * a sweep m = 0..p-1 solving row m for q^{m+1}.  Its Jacobian in q^{m+1} is
 *   -(M^f/dt + sum w cA cB hess W(z)):
 * constant for the trapezoidal family (gamma in {0, 1}: every point has
 * cA cB = 0), so q^{m+1} is explicit; for other rules (midpoint) row m is an
 * nf x nf Newton problem, solved by dense LU up to dense_max (mrvi.h,
 * MRVI_TUNING_LIST) and by CG on a sparse pattern beyond ("sweep-cg",
 * solver/sparse_block.c). */
#include "solver/solver.h"
#include "util/simd.h"
#include "util/small.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>

struct mrvi_sweep {
  const mrvi_step *st;
  int ns, nf, p, implicit;
  /* W quadratic: every micro step is linear with the same matrix, factored
   * once (lu_ok), and the Hessians of the implicit points are kept (Hpt). */
  int linear, lu_ok;
  double *Hpt[2];
  double tol;
  int max_iter;
  /* newton.criterion: 1 / M^f for the scaled criterion (each fast row's
   * residual divided by its mass), else ones; the smallest fast mass or 1
   * (CG's tolerance is on the unscaled residual) */
  double *rw, cg_unit;
  int rw_one;      /* every rw 1 (the absolute criterion): rw not kept, each
                      reader takes the unweighted value (rweight) */
  double wv0, wv1; /* weights of V at the macro nodes k and k+1 */
  int n_w;         /* W points of one interval (the same in every one) */
  double w[2], cA[2], cB[2];
  /* explicit path: weights of the points at node m (wl) and at node m + 1
   * (wr = w cB) of interval m */
  int nl, nr;
  double wl[2], wr[2];
  int tight; /* explicit, p = 1, one point at each node (explicit_p1) */
  /* The spacing of the fast nodes in x and pf: nf (every micro node kept),
   * or 0 (mrvi_sweep_set_last_only: each node overwrites the last, which
   * every sweep reads entry by entry before it writes that entry). */
  size_t node_stride;
  /* The explicit path's step on `threads` threads (explicit_step_par) in
   * the fast class's parts (nf at least two thread_chunk; else 1); with
   * node_stride 0 the nodes alternate between x's fast part and qalt (nf),
   * so that a node is written while other parts read the last one. */
  int threads;
  double *qalt;
  /* explicit_step_par: the slow rows in n_cs parts (mrvi_even_parts, or
   * 1 below two thread_chunk), end_check's sums of the slow and fast
   * parts in csum; it writes grad V at the end node into gv_next while
   * this step's start still reads gv, then exchanges the two. */
  int n_cs;
  double *csum, *gv_next;
  double *minv_s, *minv_f, *m_f; /* 1/M^s, 1/M^f, M^f */
  /* The step between the entries of minv_f and m_f that explicit_row
   * reads: 0 where every fast mass is the same (entry 0 is each entry's
   * value: two streams fewer per micro step), else 1; the explicit path
   * then keeps entries 0 and 1 alone (explicit_row loads pairs), and so
   * does sweep-cg where every pass it takes reads them by mass_inc
   * (mass_small: the absolute criterion, one implicit point per
   * interval; the dense implicit rows read every entry).  inc_s: the same for
   * minv_s, one entry (every sweep path: the slow row alone reads it). */
  int mass_inc, inc_s, mass_small;
  double *zf;        /* point configuration of W */
  mrvi_terms *kc[2]; /* the potential classes compiled (solver/terms.c) */
  /* W quadratic on a block of at most 4 fast coordinates: grad W = wg0 +
   * wH z (affine_grad_k, evaluated at z = 0 once per run), else NULL. */
  double *wg0, *wH;
  /* wH diagonal (W a sum of one-coordinate quadratics), and then the kept
   * inverse of the micro-step matrix too: products by the diagonals alone
   * (the off-diagonal products are exact zeros) */
  int wdiag;
  /* grad V (unscaled, packed) at the last macro node where V was
   * evaluated; gv_ok: that node is the current one, the end node of the
   * last step (cleared by mrvi_sweep_reset when the state is set from
   * outside, like gnode).  zv: a packed copy of a node's configuration. */
  double *zv, *gv;
  int gv_ok;
  double *gzero; /* zeros in place of grad V when its weight is 0 */
  double *gnode; /* grad_f W at the current node (cache) */
  int gnode_ok;
  double *gpt[2];         /* grad_f W at the implicit points (converged) */
  double *rhs, *F, *fimp; /* row data, residual, last implicit force */
  /* rhs's array; general_sweep points rhs at the row's momentum itself
   * where that is the row's data (sweep-cg, one implicit point per
   * interval, no control force: no copy) */
  double *rhs_buf;
  double *dn;         /* q^{m+1} - q^m */
  double *dff;        /* row 0's free flight dt M^-1 rhs (predictor) */
  double *J;          /* nf x nf */
  double *Jinv, *del; /* linear: J^-1 (nf x nf) and the update (nf) */
  int *piv;
  /* sparse: J as the block sb instead (nf > dense_max), made when Newton
   * first needs it (sblock_ready; sb_dense_max its dense blocks' bound): a
   * run whose rows all converge on the chord below never builds it. */
  int sparse, sb_dense_max;
  mrvi_sblock *sb;
  /* sweep-cg's Jacobi chord (chord_setup, or chord_residual from row 0's
   * start): 1 / diag J of row 0's first Newton matrix (or of its last
   * chord iterate), mild (this step's rows extrapolate their predictor),
   * chord (they update by it; cleared where it contracts poorly), the
   * bound chord_jacobi_max; dprev: the iterate before a chord update;
   * fhist: the converged implicit forces of the four rows before the last.
   * fresh: W's class is springs and anchors alone, so that row 0 takes
   * the chord from its start (chord_residual's D and bound: the Hessian
   * diagonal is summed into jdinv itself and the off-diagonal sums into
   * dnx, each entry read before the pass writes it: fresh_bound).  dnx:
   * the next chord iterate, formed in the pass of the residual
   * (chord_residual) and taken by a rotation of dprev, dn and dnx where
   * the row goes on. */
  double *jdinv, *dprev, *dnx, *fhist[4];
  int mild, chord, fresh;
  double chord_max;
  /* The chord's relaxation (chord_residual): rho_c, the Gershgorin bound of
   * its D; lam, the ratio of the last two residuals of this step's chord
   * rows (0 at row 0). */
  double rho_c, lam;
  /* lam summed over the updates that set it (mrvi_sweep_chord_sum) */
  double lam_sum;
  /* chord_residual's pass in n_cpass parts of the rows (mrvi_even_parts
   * by tuning.thread_chunk, doubled while the fast class's records that
   * span parts exceed SPREAD of them, mrvi_terms_spread_chunk; nf at
   * least two thread_chunk, else 0: one pass),
   * each part's maximum and sums in cpass (4 per part; then row 0's bound
   * per part, fresh_parts) added in order, on
   * pthreads threads: the same bits for every thread count.  cfused: the
   * fast class is partitioned alike (on threads), so that one thread
   * takes a part's gradient rows and then its pass, in one parallel
   * region, the pass writing the next configuration into zalt (other
   * parts' gradients still read zf), which then becomes zf. */
  int n_cpass, pthreads, cfused;
  double *cpass, *zalt;
  /* With cfused, sweep-cg's step start (the slow row, p^{f,0}, row 0's
   * estimate and its first chord iterate: start_parts) and its end (the
   * last node, grad V there, the end momenta and end_check: end_parts)
   * each in one parallel region, the slow rows in n_cs parts; pstart:
   * row 0's estimate formed there (or, where the step carries the last
   * one's rows, its predictor: start_parts' carry), its r0, scale, first
   * residual and bound in pre[4] (solve_implicit takes them). */
  int pstart, pend;
  double pre[4];
  /* A row's end deferred to the next row's first chord update on threads
   * (end_predict_row, chord_residual: one parallel region for both, a
   * barrier between), or on one thread (serial) into its fused spring
   * loop (chord_stream: each entry formed just before the first spring
   * that reads it; one pass over the row instead of two): on, its order
   * q, cB and nodes. */
  struct {
    int on, serial, q;
    double cB;
    const double *qm;
    double *qn, *pn;
  } defer;
  /* The predictor of the next row formed at the end of the last one
   * (end_predict), with its round-off scale. */
  int predicted;
  double pred_scale;
  /* The updates the last chord row took (expect0: the last row 0, for
   * row 0): a chord row's residual from that many updates on is first
   * tested alone (chord_residual's light pass), the next iterate formed
   * only where it misses the tolerance. */
  int expect, expect0;
  /* tuning.chord_carry: the history of the step before is kept (carry:
   * its rows that this step's predictors take, 0 or PREDICTOR_ORDER;
   * carry_next: the next step's, set where this step's sweep ends on the
   * chord regime) */
  int carry_on, carry, carry_next;
  int imp; /* the interval's one implicit point, or -1 (several or none) */
  long evals_w, evals_v; /* gradient evaluations (mrvi_sweep_evals) */
  /* tuning.chord_linear (lin_n > 0): a chord row's first plain update
   * (after row 0's fresh one) evaluates the gradient with each spring's
   * Hessian kept (lin, mrvi_terms_grad_lin) at the configuration zl, and
   * its next lin_n updates take the residual linearised there
   * (g += cB hess W(zl) (dn - dprev), mrvi_terms_hv_lin: no square root,
   * no division); the rows' convergence is tested on exact residuals
   * alone.  evals_lin: the products (mrvi_sweep_evals_lin). */
  int lin_n;
  double *lin, *zl;
  long evals_lin;
  /* The chord's plain updates take the pass in the spring loop
   * (mrvi_terms_set_fused, chord_stream): one pass over the row. */
  int fuse;
};

/* The springs per block of the fused loop: the rows the pass takes after
 * each block stay in the cache from the block's sums. */
enum { FUSE_BLOCK = 128 };

/* The structure the sweep needs, or the reason it is missing. */
/* Path of a constrained model (doc/solver.md): schur-bordered in the
 * multiplier form where its dense blocks are small enough, else general
 * (solver/bordered.c): with constraints at macro nodes only, the slow and
 * fast blocks and the r_s multipliers at most bordered_max (mrvi.h,
 * MRVI_TUNING_LIST; beyond it the dense blocks cost more than the sparse LU
 * of chains: doc/performance/paths.md, "Constrained chains on structured
 * paths"); with micro-node constraints, the node blocks of n_s + r_s and
 * n_f + r_f unknowns (the multipliers joined to their nodes) at most
 * bordered_node_max, whatever p (measured on bodies:
 * doc/performance/multibody.md, "Multibody"). */
static int constrained_path(const mrvi_model *m, const mrvi_settings *s,
                            char *why, size_t len) {
  const char *bodies = mrvi_model_n_bodies(m) > 0
                           ? " (rigid bodies carry their internal constraints)"
                           : "";
  int r_slow = 0, r_micro = 0;
  for (int c = 0; c < m->n_constraints; c++)
    *(m->constraints[c].where == MRVI_SLOW ? &r_slow : &r_micro) +=
        m->constraints[c].rows;
  const long n_lambda = r_slow + (long)s->micro_steps * r_micro;
  const int bmax = s->tuning.bordered_max, nmax = s->tuning.bordered_node_max;
  if (s->constraint_form == MRVI_FORM_NULL_SPACE) {
    mrvi_fmt(why, len,
             "constrained model%s in the null-space form: Newton with a "
             "sparse LU of the reduced step (the structured path takes the "
             "multiplier form)",
             bodies);
    return MRVI_PATH_GENERAL;
  }
  int nb = 0, width = 0;
  const int chain =
      mrvi_chain_wanted(m, s->micro_steps, &s->tuning, &nb, &width);
  if (chain == 1) {
    mrvi_fmt(why, len,
             "constrained model%s: %d slow and %d fast unknowns per node and "
             "%d multipliers, beyond the dense limits (bordered_max, "
             "bordered_node_max), on a chain or tree of couplings: Newton with "
             "the step eliminated along it in %d blocks of at most %d "
             "unknowns (chain elimination, chain_block_max %d)",
             bodies, m->n_slow, m->n_fast, r_slow + r_micro, nb, width,
             s->tuning.chain_block_max);
    return MRVI_PATH_SCHUR_BORDERED;
  }
  if (r_micro == 0 && (m->n_slow > bmax || m->n_fast > bmax || r_slow > bmax)) {
    mrvi_fmt(why, len,
             "constrained model%s: %d slow and %d fast unknowns per node and "
             "%d multipliers, beyond the dense limit %d (bordered_max): "
             "Newton with a sparse LU of the whole step",
             bodies, m->n_slow, m->n_fast, r_slow, bmax);
    return MRVI_PATH_GENERAL;
  }
  if (r_micro > 0 && m->n_fast + r_micro > nmax &&
      s->tuning.bordered_slow_max > 0 &&
      m->n_slow + r_slow <= s->tuning.bordered_slow_max) {
    mrvi_fmt(why, len,
             "constrained model%s: node blocks of %d fast unknowns and "
             "multipliers, beyond the dense limit %d (bordered_node_max): "
             "Newton with a Schur complement on the %d slow unknowns and "
             "multipliers (at most bordered_slow_max %d) and block sweeps "
             "over %d micro nodes, each block a sparse LU",
             bodies, m->n_fast + r_micro, nmax, m->n_slow + r_slow,
             s->tuning.bordered_slow_max, s->micro_steps);
    return MRVI_PATH_SCHUR_BORDERED;
  }
  if (r_micro > 0 &&
      (m->n_slow + r_slow > nmax || m->n_fast + r_micro > nmax)) {
    mrvi_fmt(why, len,
             "constrained model%s: node blocks of %d slow and %d fast "
             "unknowns with their multipliers, beyond the dense limit %d "
             "(bordered_node_max): Newton with a sparse LU of the whole step",
             bodies, m->n_slow + r_slow, m->n_fast + r_micro, nmax);
    return MRVI_PATH_GENERAL;
  }
  /* Within the limits: the cheaper path by the structural estimates
   * (solver/path_cost.c), unless the structured path is requested. */
  mrvi_path_cost c = {0};
  const int costed =
      s->solver != MRVI_SOLVER_STRUCTURED && mrvi_path_costs(m, s, &c) == 0;
  char est[200] = "";
  if (costed && c.general_dense)
    mrvi_fmt(est, sizeof est,
             "; estimated %.3g flop per macro step of %g Newton updates "
             "against %.3g on general (%ld unknowns, about %ld nonzeros)",
             c.bordered, s->tuning.path_updates, c.general, c.n, c.nnz);
  else if (costed && c.n > s->tuning.newton_dense_max)
    mrvi_fmt(est, sizeof est,
             "; %ld unknowns, beyond the general path's dense LU "
             "(newton_dense_max %d)",
             c.n, s->tuning.newton_dense_max);
  else if (costed)
    mrvi_fmt(est, sizeof est,
             "; %ld unknowns, the general path's sparse LU by its flop "
             "estimate (not costed)",
             c.n);
  if (costed && c.general_dense && c.general < c.bordered) {
    mrvi_fmt(why, len,
             "constrained model%s: Newton with a sparse LU of the whole step "
             "(%ld unknowns, about %ld nonzeros), estimated %.3g flop per "
             "macro step of %g Newton updates against %.3g on schur-bordered "
             "(blocks %d and %d)",
             bodies, c.n, c.nnz, c.general, s->tuning.path_updates, c.bordered,
             c.a, c.b);
    return MRVI_PATH_GENERAL;
  }
  if (r_micro > 0) {
    mrvi_fmt(why, len,
             "constrained model%s: Newton with a Schur complement on the %d "
             "slow unknowns and multipliers and block sweeps over %d micro "
             "nodes of %d fast unknowns and multipliers each%s",
             bodies, m->n_slow + r_slow, s->micro_steps, m->n_fast + r_micro,
             est);
    return MRVI_PATH_SCHUR_BORDERED;
  }
  mrvi_fmt(why, len,
           "constrained model%s: Newton with a Schur complement on the %d "
           "slow unknowns and block sweeps over %d micro nodes, bordered by "
           "the %ld multipliers%s",
           bodies, m->n_slow, s->micro_steps, n_lambda, est);
  return MRVI_PATH_SCHUR_BORDERED;
}

int mrvi_sweep_path(const mrvi_model *m, const mrvi_settings *s, char *why,
                    size_t len) {
  int fast_on_slow = -1;
  for (int e = 0; fast_on_slow < 0 && e < m->n_elements; e++) {
    const mrvi_element *el = MRVI_ELEMENT(m, e);
    for (int j = 0; el->potential == MRVI_FAST && j < el->n_in; j++)
      if (m->rate[el->in[j]] == MRVI_SLOW) {
        fast_on_slow = e;
        break;
      }
  }
  return mrvi_sweep_path_of(m, s, fast_on_slow, why, len);
}

int mrvi_sweep_path_of(const mrvi_model *m, const mrvi_settings *s,
                       int fast_on_slow, char *why, size_t len) {
  if (s->solver == MRVI_SOLVER_GENERAL) {
    mrvi_fmt(why, len, "requested (integrator.solver = general)");
    return MRVI_PATH_GENERAL;
  }
  const int dense_max = s->tuning.dense_max;
  if (m->n_constraints > 0)
    return constrained_path(m, s, why, len);
  const int small = m->n_fast <= dense_max && m->n_slow <= dense_max;
  if (s->slow_grid != MRVI_GRID_MACRO) {
    if (!small) {
      mrvi_fmt(why, len,
               "slow potential on the micro grid couples q_{k+1}^s to every "
               "micro node, blocks beyond the dense limit %d: matrix-free "
               "outer iteration where it converges, else Newton with GMRES "
               "on the %d slow unknowns and CG block sweeps over %d micro "
               "nodes",
               dense_max, m->n_slow, s->micro_steps);
      return MRVI_PATH_SCHUR_KRYLOV;
    }
    mrvi_fmt(why, len,
             "slow potential on the micro grid couples q_{k+1}^s to every "
             "micro node: Newton with a Schur complement on the %d slow "
             "unknowns and block sweeps over %d micro nodes",
             m->n_slow, s->micro_steps);
    return MRVI_PATH_SCHUR;
  }
  if (fast_on_slow >= 0) {
    const mrvi_element *el = MRVI_ELEMENT(m, fast_on_slow);
    for (int j = 0; j < el->n_in; j++)
      if (m->rate[el->in[j]] == MRVI_SLOW) {
        mrvi_fmt(why, len,
                 "the fast potential depends on slow coordinate '%s', which "
                 "couples q_{k+1}^s to every micro node%s",
                 MRVI_CNAME(m, el->in[j]),
                 small ? ": Newton with a Schur complement on the slow "
                         "unknowns and block sweeps"
                       : ": matrix-free outer iteration where it converges, "
                         "else Newton with GMRES on the slow unknowns and CG "
                         "block sweeps (blocks beyond the dense limit)");
        return small ? MRVI_PATH_SCHUR : MRVI_PATH_SCHUR_KRYLOV;
      }
  }
  const double g = s->fast.gamma;
  if (g == 0.0 || g == 1.0 || m->n_fast == 0) {
    mrvi_fmt(why, len,
             "macro-grid slow rule and a trapezoidal-family fast rule: "
             "every node is explicit");
    return MRVI_PATH_EXPLICIT;
  }
  if (m->n_fast > dense_max) {
    mrvi_fmt(why, len,
             "macro-grid slow rule: explicit slow update and a sweep of %d "
             "implicit micro steps of size %d (beyond the dense limit %d): "
             "Jacobi chord updates where they contract "
             "(chord_jacobi_max), else Newton with Jacobi-preconditioned "
             "CG (a step's first update, where W is not springs and "
             "anchors alone)",
             s->micro_steps, m->n_fast, dense_max);
    return MRVI_PATH_SWEEP_CG;
  }
  mrvi_fmt(why, len,
           "macro-grid slow rule: explicit slow update and a sweep of %d "
           "implicit micro steps of size %d",
           s->micro_steps, m->n_fast);
  return MRVI_PATH_SWEEP;
}

const char *mrvi_path_name(int path) {
#define PATH_NAME(id, name) name,
  static const char *const names[] = {MRVI_PATH_LIST(PATH_NAME)};
#undef PATH_NAME
  return path >= 0 && path < MRVI_N_PATHS ? names[path] : "unknown";
}

const char *mrvi_solver_path(const mrvi_model *m, const mrvi_settings *s,
                             char *why, size_t len) {
  const int path = mrvi_sweep_path(m, s, why, len);
  if (path == MRVI_PATH_GENERAL && s->solver == MRVI_SOLVER_STRUCTURED)
    return NULL;
  return mrvi_path_name(path);
}

const mrvi_krylov_stats *mrvi_sweep_stats(const mrvi_sweep *sw) {
  return sw && sw->sb ? mrvi_sblock_stats(sw->sb) : NULL;
}

void mrvi_sweep_evals(const mrvi_sweep *sw, long *w, long *v) {
  *w = sw->evals_w;
  *v = sw->evals_v;
}

double mrvi_sweep_chord_sum(const mrvi_sweep *sw) { return sw->lam_sum; }

long mrvi_sweep_evals_lin(const mrvi_sweep *sw) { return sw->evals_lin; }

void mrvi_sweep_free(mrvi_sweep *sw) {
  if (!sw)
    return;
  free(sw->minv_s);
  free(sw->minv_f);
  free(sw->m_f);
  free(sw->zf);
  mrvi_terms_free(sw->kc[0]);
  mrvi_terms_free(sw->kc[1]);
  free(sw->wg0);
  free(sw->wH);
  free(sw->zv);
  free(sw->gv);
  free(sw->gzero);
  free(sw->gnode);
  free(sw->qalt);
  free(sw->csum);
  free(sw->gv_next);
  free(sw->cpass);
  free(sw->zalt);
  free(sw->zl);
  free(sw->lin);
  free(sw->gpt[0]);
  free(sw->gpt[1]);
  free(sw->rhs_buf);
  free(sw->F);
  free(sw->fimp);
  free(sw->dn);
  free(sw->dff);
  free(sw->rw);
  free(sw->J);
  free(sw->Jinv);
  free(sw->del);
  free(sw->Hpt[0]);
  free(sw->Hpt[1]);
  free(sw->piv);
  mrvi_sblock_free(sw->sb);
  free(sw->jdinv);
  free(sw->dprev);
  free(sw->dnx);
  free(sw->fhist[0]);
  free(sw->fhist[1]);
  free(sw->fhist[2]);
  free(sw->fhist[3]);
  free(sw);
}

/* The explicit path's classes and V's on every path on threads: parts of
 * thread_chunk doubled until the records that span parts add at most this
 * share of a class's (mrvi_terms_set_threads_spread). */
#define SPREAD 0.05

static double *dalloc(size_t n) {
  return calloc(n > 0 ? n : 1, sizeof(double));
}
/* An array written whole before it is read, not zeroed: its pages are
 * first touched where it is written (zv, where V's inputs are adjacent,
 * never). */
static double *dalloc_raw(size_t n) {
  return malloc((n > 0 ? n : 1) * sizeof(double));
}

/* a rw[f], or a where every weight is 1 (unit: rw not kept; a times 1
 * is a, the same bits). */
static inline double rweight(const double *rw, int unit, double a, int f) {
  return unit ? a : a * rw[f];
}

/* Whether the n coordinates idx[.] all have the first's mass. */
static int equal_masses(const mrvi_model *m, const int *idx, int n) {
  for (int i = 1; i < n; i++)
    if (MRVI_MASS(m, idx[i]) != MRVI_MASS(m, idx[0]))
      return 0;
  return 1;
}

int mrvi_sweep_create(const mrvi_step *st, const mrvi_settings *s,
                      mrvi_sweep **out) {
  const mrvi_model *m = st->model;
  mrvi_sweep *sw = calloc(1, sizeof *sw);
  *out = NULL;
  if (!sw)
    return MRVI_ENOMEM;
  sw->st = st;
  sw->ns = st->ns;
  sw->nf = st->nf;
  sw->p = st->p;
  sw->tol = s->newton_tol;
  sw->max_iter = s->newton_max_iter;
  /* V on the macro grid: points at tau = 0 (a0 = 1) and tau = 1 (a1 = 1). */
  for (int i = 0; i < st->n_pts[MRVI_SLOW]; i++) {
    const mrvi_point *pt = &st->pts[MRVI_SLOW][i];
    if (pt->a1 == 0.0)
      sw->wv0 += pt->w;
    else
      sw->wv1 += pt->w;
  }
  /* W points of interval 0 (every interval has the same). */
  for (int i = 0; i < st->n_pts[MRVI_FAST]; i++) {
    const mrvi_point *pt = &st->pts[MRVI_FAST][i];
    if (pt->m != 0 || sw->n_w == 2)
      continue;
    sw->w[sw->n_w] = pt->w;
    sw->cA[sw->n_w] = pt->cA;
    sw->cB[sw->n_w] = pt->cB;
    if (pt->cA != 0.0 && pt->cB != 0.0 && st->nf > 0)
      sw->implicit = 1;
    if (pt->cB == 0.0)
      sw->wl[sw->nl++] = pt->w;
    else
      sw->wr[sw->nr++] = pt->w * pt->cB;
    sw->n_w++;
  }
  sw->tight = !sw->implicit && sw->p == 1 && sw->nl == 1 && sw->nr == 1;
  sw->imp = -1;
  for (int i = 0, k = 0; i < sw->n_w; i++)
    if (sw->cA[i] != 0.0 && sw->cB[i] != 0.0)
      sw->imp = k++ == 0 ? i : -1;
  sw->node_stride = (size_t)st->nf;
  const size_t ns = (size_t)sw->ns, nf = (size_t)sw->nf;
  /* The masses (set below): one entry where they are all equal and every
   * reader steps by inc_s or mass_inc (two of the fast ones: explicit_row
   * loads pairs). */
  sw->inc_s = !equal_masses(m, m->slow_index, sw->ns);
  sw->mass_inc = !equal_masses(m, m->fast_index, sw->nf);
  const int scaled = s->newton_criterion == MRVI_CRITERION_SCALED;
  sw->mass_small = !sw->mass_inc && nf >= 2 &&
                   (!sw->implicit ||
                    (sw->nf > s->tuning.dense_max && !scaled && sw->n_w == 1));
  const size_t nfm = sw->mass_small ? 2 : nf;
  sw->minv_s = dalloc_raw(sw->inc_s ? ns : 1);
  sw->minv_f = dalloc_raw(nfm);
  sw->m_f = dalloc_raw(nfm);
  sw->zv = dalloc_raw(ns + nf); /* (slow_gradient: copied, zeroed there) */
  sw->gv = dalloc_raw(ns + nf);
  /* (zeros for grad V where V has no point at node k, and for the
   * implicit paths' zero displacement) */
  sw->gzero = dalloc(sw->wv0 == 0.0 || sw->implicit ? ns + nf : 0);
  /* Columns: (q^s, q^f) packed for V, q^f alone for W (no slow inputs:
   * the slots).  V's are listed in gv (ns + nf = n entries, written whole
   * before the step reads it), so that no other array's pages are
   * touched. */
  int *col = (int *)sw->gv;
  int s_ok = col != NULL;
  for (int c = 0; s_ok && c < m->n; c++)
    col[c] = (m->rate[c] == MRVI_SLOW ? 0 : sw->ns) + m->slot[c];
  /* (V's gradient alone; W's too on the explicit path, unless its affine
   * map is made below) */
  /* (each class from its list or its range: no temporary list) */
  s_ok = s_ok && mrvi_terms_create_range(m, st->elem_of_class[MRVI_SLOW],
                                         st->elem_first[MRVI_SLOW],
                                         st->n_elem_of_class[MRVI_SLOW], col, 1,
                                         &sw->kc[MRVI_SLOW]) == MRVI_OK;
  s_ok = s_ok &&
         mrvi_terms_create_range(
             m, st->elem_of_class[MRVI_FAST], st->elem_first[MRVI_FAST],
             st->n_elem_of_class[MRVI_FAST], m->slot,
             sw->implicit || nf <= 4 ? 0 : 1, &sw->kc[MRVI_FAST]) == MRVI_OK;
  /* The gradients of large spring classes on threads (the same bits).
   * V's parts (by records: each column summed in the serial order) spread
   * on every path; W's on the implicit path are the chord's parts (n_cpass
   * below), whose sums are per part: with a sparse block, thread_chunk
   * doubled by the same rule from the class alone, so the same parts (and
   * bits) on every thread count (fewer records in two parts: random3d's
   * 21 % at 4 096 columns, doc/performance/17-thr17.md). */
  const int threads = mrvi_threads_resolve(s->threads);
  const int sparse = sw->implicit && sw->nf > s->tuning.dense_max;
  int cchunk = s->tuning.thread_chunk;
  if (s_ok && sparse && (int)nf >= 2 * cchunk)
    cchunk =
        mrvi_terms_spread_chunk(sw->kc[MRVI_FAST], cchunk, (int)nf, SPREAD);
  for (int c = 0; s_ok && c < 2; c++)
    s_ok = mrvi_terms_set_threads_spread(
               sw->kc[c], threads,
               sw->implicit && c == MRVI_FAST ? cchunk : s->tuning.thread_chunk,
               c == MRVI_SLOW ? 0 : nf,
               sw->implicit && c == MRVI_FAST ? HUGE_VAL : SPREAD) == MRVI_OK;
  /* The explicit step's one parallel region: W's gradient by
   * parts of the fast rows (explicit_step_par). */
  sw->threads = s_ok && !sw->implicit && !sw->wH &&
                        mrvi_terms_parts(sw->kc[MRVI_FAST]) > 0
                    ? threads
                    : 1;
  if (!s_ok) {
    mrvi_sweep_free(sw);
    return MRVI_ENOMEM;
  }
  sw->gnode = dalloc(nf);
  sw->qalt = dalloc(sw->threads > 1 ? nf : 1);
  if (sw->threads > 1 || (sw->implicit && threads > 1)) { /* (end_parts) */
    const int chunk = s->tuning.thread_chunk;
    sw->n_cs =
        (int)ns >= 2 * chunk ? mrvi_even_parts((int)ns, chunk) : (ns > 0);
  }
  sw->csum =
      dalloc((size_t)sw->n_cs + (size_t)mrvi_terms_parts(sw->kc[MRVI_FAST]));
  sw->gv_next = dalloc_raw(sw->threads > 1 ? ns + nf : 1);
  /* The rows' workspace of the implicit paths (the explicit path needs
   * none of it: explicit_sweep and explicit_p1). */
  const size_t ni = sw->implicit ? nf : 0;
  sw->zf = dalloc(ni);
  sw->gpt[0] = dalloc(ni);
  sw->gpt[1] = dalloc(sw->n_w > 1 ? ni : 0);
  sw->rhs = sw->rhs_buf = dalloc(ni);
  sw->F = dalloc(ni);
  sw->fimp = dalloc(ni);
  sw->dn = dalloc(ni);
  sw->rw = dalloc(scaled ? ni : 0);
  sw->dff = dalloc(sparse ? 1 : ni); /* (sparse: in fhist[3], free_flight) */
  sw->sparse = sparse;
  sw->sb_dense_max = s->tuning.newton_dense_max;
  sw->J = dalloc(sw->implicit && !sparse ? nf * nf : 1);
  sw->chord_max = s->tuning.chord_jacobi_max;
  sw->expect = sw->expect0 = s->newton_max_iter;
  sw->carry_on = s->tuning.chord_carry;
  sw->jdinv = dalloc(sparse ? nf : 1);
  sw->fresh = sparse && mrvi_terms_springs_only(sw->kc[MRVI_FAST]);
  /* The chord's gradients with one division per Hooke spring, as the
   * explicit path's (the last bits differ from the Newton evaluations'). */
  if (sparse)
    mrvi_terms_set_recip(sw->kc[MRVI_FAST]);
  /* (the chord pass in the spring loop: blocks of FUSE_BLOCK springs) */
  const int fz =
      sparse ? mrvi_terms_set_fused(sw->kc[MRVI_FAST], (int)nf, FUSE_BLOCK) : 0;
  if (fz < 0) {
    mrvi_sweep_free(sw);
    return fz;
  }
  sw->fuse = fz == 1;
  sw->dprev = dalloc(sparse ? nf : 1);
  sw->dnx = dalloc(sparse ? nf : 1);
  sw->fhist[0] = dalloc(sparse ? nf : 1);
  sw->fhist[1] = dalloc(sparse ? nf : 1);
  sw->fhist[2] = dalloc(sparse ? nf : 1);
  sw->fhist[3] = dalloc(sparse ? nf : 1);
  sw->n_cpass = sparse && (int)nf >= 2 * s->tuning.thread_chunk
                    ? mrvi_even_parts((int)nf, cchunk)
                    : 0;
  sw->pthreads = threads;
  sw->cfused = sw->n_cpass > 0 && mrvi_terms_threads(sw->kc[MRVI_FAST]) > 1 &&
               mrvi_terms_parts(sw->kc[MRVI_FAST]) == sw->n_cpass;
  /* (+ fresh_parts' bounds, start_parts' r0 and scale) */
  sw->cpass = dalloc(7 * (size_t)sw->n_cpass);

  sw->zalt = dalloc(sw->cfused ? nf : 1);
  /* (the linearised updates: W's class of Hooke springs alone, the chord
   * from row 0's start) */
  const long nlin =
      sparse && sw->fresh ? mrvi_terms_lin_size(sw->kc[MRVI_FAST]) : 0;
  sw->lin_n = nlin > 0 ? s->tuning.chord_linear : 0;
  sw->lin = dalloc(sw->lin_n > 0 ? (size_t)nlin : 1);
  sw->zl = dalloc(sw->lin_n > 0 ? nf : 1);
  const int quad_w = mrvi_terms_quadratic(sw->kc[MRVI_FAST]);
  /* A quadratic W on a dense block: one factorisation per run. */
  sw->linear = sw->implicit && !sparse && quad_w;
  /* ... and on a block of at most 4: its gradient as an affine map. */
  if (quad_w && nf >= 1 && nf <= 4) {
    if (mrvi_terms_affine(sw->kc[MRVI_FAST], (int)nf, &sw->wg0, &sw->wH) !=
        MRVI_OK) {
      mrvi_sweep_free(sw);
      return MRVI_ENOMEM;
    }
    sw->wdiag = 1;
    for (size_t a = 0; a < nf; a++)
      for (size_t b = 0; b < nf; b++)
        if (a != b && sw->wH[a * nf + b] != 0.0)
          sw->wdiag = 0;
  }
  sw->Hpt[0] = dalloc(sw->linear ? nf * nf : 1);
  sw->Hpt[1] = dalloc(sw->linear ? nf * nf : 1);
  sw->Jinv = dalloc(sw->linear ? nf * nf : 1);
  sw->del = dalloc(sw->linear ? nf : 0);
  sw->piv = calloc(sw->implicit && !sparse && nf > 0 ? nf : 1, sizeof(int));
  if (!sw->minv_s || !sw->minv_f || !sw->m_f || !sw->zf || !sw->zv || !sw->gv ||
      !sw->gzero || !sw->gnode || !sw->qalt || !sw->csum || !sw->gv_next ||
      !sw->cpass || !sw->zalt || !sw->gpt[0] || !sw->gpt[1] || !sw->rhs ||
      !sw->F || !sw->fimp || !sw->dn || !sw->dff || !sw->rw || !sw->J ||
      !sw->Hpt[0] || !sw->Hpt[1] || !sw->piv || !sw->jdinv || !sw->dprev ||
      !sw->dnx || !sw->fhist[0] || !sw->fhist[1] || !sw->fhist[2] ||
      !sw->fhist[3] || !sw->lin || !sw->zl) {
    mrvi_sweep_free(sw);
    return MRVI_ENOMEM;
  }
  for (int i = 0; i < (sw->inc_s ? sw->ns : (sw->ns > 0)); i++)
    sw->minv_s[i] = 1.0 / MRVI_MASS(m, m->slow_index[i]);
  for (int i = 0; i < (int)nfm; i++) {
    sw->m_f[i] = MRVI_MASS(m, m->fast_index[i]);
    sw->minv_f[i] = 1.0 / sw->m_f[i];
  }
  sw->rw_one = !scaled;
  sw->cg_unit = 1.0;
  for (int i = 0; i < sw->nf; i++) {
    const double mi = MRVI_MASS(m, m->fast_index[i]);
    if (sw->implicit && scaled)
      sw->rw[i] = sw->minv_f[i * sw->mass_inc];
    if (scaled && (i == 0 || mi < sw->cg_unit))
      sw->cg_unit = mi;
  }
  *out = sw;
  return MRVI_OK;
}

void mrvi_sweep_set_last_only(mrvi_sweep *sw, int last_only) {
  sw->node_stride = last_only ? 0 : (size_t)sw->nf;
}

void mrvi_sweep_reset(mrvi_sweep *sw) {
  if (!sw)
    return;
  sw->gnode_ok = 0;
  sw->gv_ok = 0;
  sw->carry_next = 0;
  if (sw->implicit)
    memset(sw->fimp, 0, (size_t)sw->nf * sizeof(double));
}

/* The sparse block of the Newton matrix (its pattern, assembly maps and CG
 * vectors), made once, where Newton first assembles J: matrix-free where
 * W's class is springs and anchors kept as records and one point of the
 * interval has a Hessian (its configuration zf is the one the block
 * keeps: neither the residual nor the solve changes zf). */
static int sblock_ready(mrvi_sweep *sw, char *msg, size_t len) {
  if (sw->sb)
    return MRVI_OK;
  const mrvi_step *st = sw->st;
  int n_hess = 0;
  for (int i = 0; i < sw->n_w; i++)
    n_hess += sw->cA[i] != 0.0 && sw->cB[i] != 0.0;
  const int free_form =
      n_hess == 1 && mrvi_terms_springs_only(sw->kc[MRVI_FAST]);
  int *own = NULL;
  const int *list =
      free_form ? NULL : mrvi_step_class_list(st, MRVI_FAST, &own);
  const int made =
      free_form ? mrvi_sblock_create_free(sw->kc[MRVI_FAST], sw->nf,
                                          st->model->dimension,
                                          sw->sb_dense_max, &sw->sb)
      : list
          ? mrvi_sblock_create(st->model, list, st->n_elem_of_class[MRVI_FAST],
                               sw->sb_dense_max, &sw->sb)
          : MRVI_ENOMEM;
  free(own);
  if (made < 0 ||
      mrvi_sblock_set_parts(sw->sb, sw->n_cpass, sw->pthreads) < 0) {
    mrvi_fmt(msg, len,
             "out of memory for the micro-step Newton matrix "
             "(%d fast coordinates)",
             sw->nf);
    return MRVI_ENOMEM;
  }
  return MRVI_OK;
}

/* The fast class at zf: gf += grad W and, if J, J += hscale hess W
 * (nf x nf, or the sparse sw->sb when set). */
static void eval_fast(mrvi_sweep *sw, double *gf, double *J, double hscale) {
  const int cls = MRVI_FAST;
  sw->evals_w++;
  if (!(J && sw->sb)) {
    mrvi_terms_eval(sw->kc[cls], sw->zf, 1.0, gf, J, sw->nf, hscale);
    return;
  }
  /* Sparse block: each element's Hessian goes to its pattern entries
   * (springs and anchors by compiled kernels). */
  mrvi_sblock_add_terms(sw->sb, sw->kc[cls], sw->zf, gf, hscale);
}

/* The blocks of a few coordinates are copied and zeroed by loops (unrolled
 * for small blocks): a library call costs more than the work at these
 * sizes, and reads that span the scalar stores just made stall on store
 * forwarding. */
ALWAYS_INLINE void copy(double *restrict d, const double *restrict s, int n) {
  UNROLL
  for (int i = 0; i < n; i++)
    d[i] = s[i];
}

ALWAYS_INLINE void zero(double *d, int n) {
  UNROLL
  for (int i = 0; i < n; i++)
    d[i] = 0.0;
}

/* g = grad W at z (nf fast entries): the affine map of a quadratic W on a
 * small block (round-off apart, the terms' gradient), else the terms. */
ALWAYS_INLINE void fast_gradient(mrvi_sweep *sw, const double *z, double *g,
                                 const int nf) {
  sw->evals_w++;
  if (sw->wdiag) {
    UNROLL
    for (int i = 0; i < nf; i++)
      g[i] = sw->wg0[i] + sw->wH[i * nf + i] * z[i];
  } else if (sw->wH) {
    const double *restrict g0 = sw->wg0, *restrict H = sw->wH;
    UNROLL
    for (int i = 0; i < nf; i++) {
      double t = g0[i];
      UNROLL
      for (int j = 0; j < nf; j++)
        t += H[i * nf + j] * z[j];
      g[i] = t;
    }
  } else {
    zero(g, nf);
    mrvi_terms_grad(sw->kc[MRVI_FAST], z, g);
  }
}

/* sw->gv = grad V (unscaled, packed: ns slow then nf fast entries) at
 * (qs, qf), read in place when they are adjacent. */
ALWAYS_INLINE void slow_gradient(mrvi_sweep *sw, const double *qs,
                                 const double *qf, const int ns, const int nf) {
  const double *z = qs;
  sw->evals_v++;
  if (qf != qs + ns) {
    copy(sw->zv, qs, ns);
    copy(sw->zv + ns, qf, nf);
    z = sw->zv;
  }
  zero(sw->gv, ns + nf);
  mrvi_terms_grad(sw->kc[MRVI_SLOW], z, sw->gv);
}

static void set_zf(mrvi_sweep *sw, double a, const double *u, double b,
                   const double *v) {
  for (int f = 0; f < sw->nf; f++)
    sw->zf[f] = a * u[f] + b * v[f];
}

/* Factor the micro-step matrix J = M/dt + sum w cA cB hess W of a
 * quadratic W (its Hessians, constant, evaluated at qm + cB dn) and keep
 * its inverse and the Hessians. */
static int factor_linear(mrvi_sweep *sw, const double *qm, const double *dn,
                         char *msg, size_t len) {
  const int nf = sw->nf;
  const double dt = sw->st->dt;
  memset(sw->J, 0, (size_t)nf * (size_t)nf * sizeof(double));
  for (int i = 0; i < sw->n_w; i++) {
    memset(sw->Hpt[i], 0, (size_t)nf * (size_t)nf * sizeof(double));
    if (sw->cA[i] == 0.0 || sw->cB[i] == 0.0)
      continue;
    set_zf(sw, 1.0, qm, sw->cB[i], dn);
    memset(sw->gpt[i], 0, (size_t)nf * sizeof(double));
    eval_fast(sw, sw->gpt[i], sw->Hpt[i], 1.0);
    for (int k = 0; k < nf * nf; k++)
      sw->J[k] += sw->w[i] * sw->cA[i] * sw->cB[i] * sw->Hpt[i][k];
  }
  for (int f = 0; f < nf; f++)
    sw->J[f * nf + f] += sw->m_f[f] / dt;
  if (mrvi_dense_lu_factor(nf, sw->J, sw->piv) < 0) {
    mrvi_fmt(msg, len, "singular micro-step matrix");
    return MRVI_ESINGULAR;
  }
  /* The inverse (nf <= dense_max): a micro step's solve is then one
   * matrix-vector product. */
  memset(sw->Jinv, 0, (size_t)nf * (size_t)nf * sizeof(double));
  for (int f = 0; f < nf; f++)
    sw->Jinv[f * nf + f] = 1.0;
  mrvi_dense_lu_solve(nf, sw->J, sw->piv, sw->Jinv, nf);
  for (int k = 0; k < nf * nf; k++) /* (diagonal with a diagonal H) */
    if (k % (nf + 1) != 0 && sw->Jinv[k] != 0.0)
      sw->wdiag = 0;
  sw->lu_ok = 1;
  return MRVI_OK;
}

/* Row m for a quadratic W: F(dn) is affine with the constant matrix
 * -J = -(M/dt + sum w cA cB H), so one solve from the predictor is exact.
 * J is factored on the first call; the gradients at the implicit points
 * follow from the predictor's by the kept Hessians, and the residual
 * reported is the one of the updated dn (roundoff). */
static int solve_linear(mrvi_sweep *sw, const double *qm, double *dn,
                        int *iters, double *res, char *msg, size_t len) {
  const int nf = sw->nf;
  const double dt = sw->st->dt;
  for (int f = 0; f < nf; f++)
    dn[f] = dt * sw->minv_f[f] * (sw->rhs[f] - sw->fimp[f]);
  if (!sw->lu_ok) {
    const int s = factor_linear(sw, qm, dn, msg, len);
    if (s < 0)
      return s;
  }
  /* F at the predictor, then dn += J^-1 F. */
  memset(sw->fimp, 0, (size_t)nf * sizeof(double));
  for (int i = 0; i < sw->n_w; i++) {
    if (sw->cA[i] == 0.0 || sw->cB[i] == 0.0)
      continue;
    set_zf(sw, 1.0, qm, sw->cB[i], dn);
    memset(sw->gpt[i], 0, (size_t)nf * sizeof(double));
    eval_fast(sw, sw->gpt[i], NULL, 0.0);
    for (int f = 0; f < nf; f++)
      sw->fimp[f] += sw->w[i] * sw->cA[i] * sw->gpt[i][f];
  }
  for (int f = 0; f < nf; f++)
    sw->F[f] = sw->rhs[f] - sw->m_f[f] * dn[f] / dt - sw->fimp[f];
  for (int a = 0; a < nf; a++) {
    double d = 0.0;
    for (int b = 0; b < nf; b++)
      d += sw->Jinv[a * nf + b] * sw->F[b];
    sw->del[a] = d;
    dn[a] += d;
  }
  memcpy(sw->F, sw->del, (size_t)nf * sizeof(double));
  /* Gradients at the implicit points after the update: g += cB H delta. */
  memset(sw->fimp, 0, (size_t)nf * sizeof(double));
  for (int i = 0; i < sw->n_w; i++) {
    if (sw->cA[i] == 0.0 || sw->cB[i] == 0.0)
      continue;
    for (int a = 0; a < nf; a++) {
      double h = 0.0;
      for (int b = 0; b < nf; b++)
        h += sw->Hpt[i][a * nf + b] * sw->F[b];
      sw->gpt[i][a] += sw->cB[i] * h;
      sw->fimp[a] += sw->w[i] * sw->cA[i] * sw->gpt[i][a];
    }
  }
  double r = 0.0;
  for (int f = 0; f < nf; f++) {
    const double a = fabs(sw->rhs[f] - sw->m_f[f] * dn[f] / dt - sw->fimp[f]);
    r = isnan(a) || a > r ? a : r;
  }
  *iters = 1;
  *res = fmax(*res, r);
  if (!isfinite(r)) {
    mrvi_fmt(msg, len, "micro step produced non-finite values");
    return MRVI_ENONFINITE;
  }
  return MRVI_OK;
}

/* zf = qm + cB dn (set_zf's) in n_c parts of the nf rows: the loop of the
 * calling parallel region (its barrier at the end). */
static void set_zf_parts(double *zf, const double *qm, double cB,
                         const double *dn, int nf, int n_c) {
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
  for (int c = 0; c < n_c; c++)
    for (int f = mrvi_part_start(c, nf, n_c);
         f < mrvi_part_start(c + 1, nf, n_c); f++)
      zf[f] = 1.0 * qm[f] + cB * dn[f];
}

/* Whether the sparse block's assembly is in parts (implicit_force_parts:
 * the fast class partitioned as the block's rows, on threads). */
static int sblock_par(const mrvi_sweep *sw) {
  return sw->sb && mrvi_sblock_parts(sw->sb) > 0 &&
         mrvi_terms_sparse_parts(sw->kc[MRVI_FAST]) ==
             mrvi_sblock_parts(sw->sb);
}

/* implicit_force with the sparse block's J where the fast class is in the
 * block's parts (on threads), in one parallel region per point: the
 * configuration in the parts' rows, then (after the barrier) each part's
 * gradient and Hessian columns (the values' columns zeroed at the first
 * point) and its rows of fimp.  The serial path's values bitwise (each
 * column's sums in the serial order, the same entries). */
static void implicit_force_parts(mrvi_sweep *sw, const double *qm,
                                 const double *dn) {
  const int nf = sw->nf, n_c = mrvi_sblock_parts(sw->sb);
  int first = 1;
  for (int i = 0; i < sw->n_w; i++) {
    if (sw->cA[i] == 0.0 || sw->cB[i] == 0.0)
      continue;
    const double cB = sw->cB[i], wc = sw->w[i] * sw->cA[i], hs = wc * cB;
    double *g = sw->gpt[i], *zf = sw->zf, *fimp = sw->fimp;
    mrvi_sblock *sb = sw->sb;
    const mrvi_terms *kc = sw->kc[MRVI_FAST];
    sw->evals_w++;
#ifdef _OPENMP
#pragma omp parallel num_threads(sw->pthreads)
#endif
    {
      set_zf_parts(zf, qm, cB, dn, nf, n_c);
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
      for (int c = 0; c < n_c; c++) {
        const int f0 = mrvi_part_start(c, nf, n_c);
        const int f1 = mrvi_part_start(c + 1, nf, n_c);
        zero(g + f0, f1 - f0);
        mrvi_sblock_add_terms_part(sb, kc, c, zf, g, hs, first);
        for (int f = f0; f < f1; f++)
          fimp[f] = (first ? 0.0 : fimp[f]) + wc * g[f];
      }
    }
    first = 0;
  }
  if (first) { /* (no implicit point: zero, as the serial path) */
    memset(sw->fimp, 0, (size_t)nf * sizeof(double));
    mrvi_sblock_zero(sw->sb);
  }
}

/* fimp = sum w cA grad W(z) over the implicit points of the interval,
 * z = qm + cB dn, with the Newton matrix's w cA cB hess W(z) added to J
 * (sw->J or the sparse block) unless J is NULL. */
static void implicit_force(mrvi_sweep *sw, const double *qm, const double *dn,
                           double *J) {
  const int nf = sw->nf;
  if (J && sblock_par(sw)) {
    implicit_force_parts(sw, qm, dn);
    return;
  }
  memset(sw->fimp, 0, (size_t)nf * sizeof(double));
  for (int i = 0; i < sw->n_w; i++) {
    if (sw->cA[i] == 0.0 || sw->cB[i] == 0.0)
      continue;
    set_zf(sw, 1.0, qm, sw->cB[i], dn); /* cA qm + cB (qm + dn) */
    memset(sw->gpt[i], 0, (size_t)nf * sizeof(double));
    eval_fast(sw, sw->gpt[i], J, sw->w[i] * sw->cA[i] * sw->cB[i]);
    for (int f = 0; f < nf; f++)
      sw->fimp[f] += sw->w[i] * sw->cA[i] * sw->gpt[i][f];
  }
}

/* The predictor of row m >= 1 of sweep-cg in the mild regime (sw->mild):
 * the implicit force extrapolated from the rows before (of order q: quartic
 * from row 5 on, cubic at row 4, quadratic at row 3, linear at row 2, held
 * fixed at row 1) instead of held fixed, so that the row residual r0 =
 * fimp_pred - fimp(dn_pred) is the force's fifth difference over the
 * micro steps, not its first.  Measured on the benchmark lattice
 * (bench_floor, lattice2d, n = 1012, dT = 0.05, p = 10): r0 8.3e-2 held
 * fixed, 2.4e-2 linear, 6.6e-3 quadratic, 1.3e-3 cubic (medians); the
 * quartic leaves the chord rows of 10^5 coordinates within the tolerance
 * after three updates more often (doc/performance/explicit.md, "explicit-slow:
 * the cost model, fused row ends").  The history holds only rows of the current
 * step (a step depends on (q_k, p_k) alone).  f1: the last row's converged
 * implicit force, f2..f5 the rows' before it. */
enum { PREDICTOR_ORDER = 5 };
ALWAYS_INLINE double predicted_force(int q, double f1, double f2, double f3,
                                     double f4, double f5) {
  if (q == 2)
    return 2.0 * f1 - f2;
  if (q == 3)
    return 3.0 * f1 - 3.0 * f2 + f3;
  if (q == 4)
    return 4.0 * f1 - 6.0 * f2 + 4.0 * f3 - f4;
  if (q == 5)
    return 5.0 * f1 - 10.0 * f2 + 10.0 * f3 - 5.0 * f4 + f5;
  return f1;
}

/* Row 0's free flight dn0 (solve_implicit, start_parts): dff, or on
 * sweep-cg the oldest row of the force history, fhist[3]: dn0 is formed
 * only where no history is carried (sw->carry 0), and then row 0 reads no
 * history and its end hands fhist[3]'s array to fimp, which every path
 * writes whole before it reads it (rotate_history): 4 bytes a coordinate
 * less at n_f ~ n / 2 (doc/performance/16-es-mem16.md). */
static inline double *free_flight(const mrvi_sweep *sw) {
  return sw->sparse ? sw->fhist[3] : sw->dff;
}

/* The history moves one row on: the last force becomes fhist[0], and
 * fimp takes the oldest row's array (every path writes fimp whole before
 * it reads it). */
static void rotate_history(mrvi_sweep *sw) {
  double *t = sw->fhist[3];
  sw->fhist[3] = sw->fhist[2];
  sw->fhist[2] = sw->fhist[1];
  sw->fhist[1] = sw->fhist[0];
  sw->fhist[0] = sw->fimp;
  sw->fimp = t;
}

/* The order of row m's extrapolation. */
static int predictor_order(const mrvi_sweep *sw, int m) {
  m += sw->carry;
  return sw->mild ? (m >= PREDICTOR_ORDER ? PREDICTOR_ORDER : m) : 1;
}

/* The rows' history a step takes from the one before (tuning.chord_carry):
 * the last PREDICTOR_ORDER rows' converged implicit forces, f1 (fimp)
 * first, where the last step kept them (carry_next), else none. */
int mrvi_sweep_history(const mrvi_sweep *sw, const double *part[5]) {
  if (!sw || sw->carry_next != PREDICTOR_ORDER)
    return 0;
  part[0] = sw->fimp;
  for (int i = 0; i < 4; i++)
    part[i + 1] = sw->fhist[i];
  return sw->nf;
}

int mrvi_sweep_set_history(mrvi_sweep *sw, int n, const double *h, char *msg,
                           size_t len) {
  if (!sw || !(sw->carry_on && sw->implicit && sw->sparse && sw->fresh &&
               sw->p >= PREDICTOR_ORDER)) {
    mrvi_fmt(msg, len,
             "a chord history was given, but this run's solver keeps none "
             "(tuning.chord_carry off, or not explicit-slow on sweep-cg "
             "with springs and anchors and at least %d micro steps)",
             PREDICTOR_ORDER);
    return MRVI_EINVAL;
  }
  if (n != sw->nf) {
    mrvi_fmt(msg, len,
             "chord history of %d fast coordinates per row, the run has %d", n,
             sw->nf);
    return MRVI_EINVAL;
  }
  for (size_t i = 0; i < (size_t)PREDICTOR_ORDER * (size_t)n; i++)
    if (!isfinite(h[i])) {
      mrvi_fmt(msg, len, "chord history entry %zu is not finite", i);
      return MRVI_ENONFINITE;
    }
  memcpy(sw->fimp, h, (size_t)n * sizeof *h);
  for (int i = 0; i < 4; i++)
    memcpy(sw->fhist[i], h + (size_t)(i + 1) * (size_t)n,
           (size_t)n * sizeof *h);
  sw->carry_next = PREDICTOR_ORDER;
  return MRVI_OK;
}

/* Row m's predictor (above) where the last row's end did not form it
 * (end_predict): the displacement dn, in the same pass (one pass over the
 * row instead of three) the point's configuration zf = qm + cB dn where
 * cB is not 0 (the chord's first iterate), and the row's round-off scale,
 * returned (solve_implicit); predictor_rows: of order q over the rows
 * [f0, f1r), the history not moved on (start_parts: in parts). */
ALWAYS_INLINE double predictor_rows(mrvi_sweep *sw, int q,
                                    const double *restrict qm,
                                    double *restrict dn, double cB, int f0,
                                    int f1r) {
  const double dt = sw->st->dt;
  const double *restrict f1 = sw->fimp, *restrict f2 = sw->fhist[0],
                         *restrict f3 = sw->fhist[1],
                         *restrict f4 = sw->fhist[2],
                         *restrict f5 = sw->fhist[3];
  const double *restrict rhs = sw->rhs, *restrict minv = sw->minv_f,
                         *restrict mf = sw->m_f, *restrict rw = sw->rw;
  const int unit = sw->rw_one;
  const size_t inc = (size_t)sw->mass_inc;
  double *restrict zf = sw->zf;
  double scale = 0.0;
  for (int f = f0; f < f1r; f++) {
    const double fp = predicted_force(q, f1[f], f2[f], f3[f], f4[f], f5[f]);
    dn[f] = dt * minv[f * inc] * (rhs[f] - fp);
    if (cB != 0.0)
      zf[f] = 1.0 * qm[f] + cB * dn[f];
    /* (fmax's NaN rule, without its call) */
    const double v = rweight(
        rw, unit, fabs(rhs[f]) + 4.0 * mf[f * inc] * fabs(qm[f]) / dt, f);
    scale = v > scale ? v : scale;
  }
  return scale;
}

static double extrapolated_predictor(mrvi_sweep *sw, int m,
                                     const double *restrict qm,
                                     double *restrict dn, double cB) {
  const double scale =
      predictor_rows(sw, predictor_order(sw, m), qm, dn, cB, 0, sw->nf);
  rotate_history(sw);
  return scale;
}

/* The Jacobi chord of sweep-cg (doc/solver.md, "sweep-cg"): after row 0's
 * first Newton matrix J is assembled, the Gershgorin bound rho of the
 * Jacobi iteration dn += D^-1 F(dn), D = diag J, decides the regime: where
 * rho <= chord_jacobi_max (mrvi.h, MRVI_TUNING_LIST) the later rows of the
 * step take these updates (one gradient each, no assembly, no CG) and the
 * extrapolated predictor.  rho ~ (omega dt)^2/4 is the contraction of the
 * linear part; the residual that decides convergence is exact, so the
 * iteration stops where Newton would, at the same tolerance. */
static void chord_setup(mrvi_sweep *sw) {
  const double rho = mrvi_sblock_jacobi(sw->sb, sw->jdinv);
  sw->mild = sw->chord = rho <= sw->chord_max;
  sw->rho_c = rho;
}

/* The pass of chord_residual over the row, two entries at a time
 * (util/simd.h: each lane the scalar operations of the tail): F, its
 * largest |F| rw (returned; v2_max passes over NaN, so NaN is found by the
 * sum of the entries instead, which it poisons), the next iterate dnx and
 * its configuration zf, the sums F.F_old (on) and F_old.F_old (oo) with F
 * stored over F_old; rw read unless unit (every weight 1: the absolute
 * criterion), the implicit force fimp stored where keep (else
 * node_momentum stores it at the row's end: one point per interval).
 * M dn/dt is formed as M dn (1/dt): no division in the pass.  light: the
 * test of a row's expected last iterate, F's maximum, sum and the sums
 * alone, neither F nor the next iterate stored (4 streams read instead of
 * 6 read and 3 written); the same values of r, on and oo.  step: zf
 * gets the update om D^-1 F instead of the next configuration (the
 * linearised updates' product reads it, tuning.chord_linear).  cur: qm
 * holds the current iterate's configuration z = q^m + cB dn (the zf that
 * the gradient read) and the next one is z + cB om D^-1 F, formed from the
 * update instead of from q^m + cB dnx: the row's stream of q^m is not read
 * (an out-of-cache pass reads one array less); z differs from q^m + cB dn
 * by the rounding of these sums, at most a few units in the last place of
 * |q| in a row (end_predict forms each row's first configuration from q^m
 * afresh), which is the rounding q^m + cB dn itself carries. */
ALWAYS_INLINE void chord_pass(mrvi_sweep *sw, const double *qm,
                              const double *restrict dn,
                              const double *restrict g, double om, double wc,
                              double cB, double *zf, int f0, const int nf,
                              double out[4], mrvi_v2 acc[4], const int fin,
                              const int unit, const int keep, const int inc,
                              const int light, const int step, const int cur) {
  const double dt = sw->st->dt;
  const double *restrict rhs = sw->rhs, *restrict mf = sw->m_f,
                         *restrict rw = sw->rw, *restrict jd = sw->jdinv;
  double *restrict fimp = sw->fimp, *restrict dnx = sw->dnx,
                   *restrict F = sw->F;
  const double idt = 1.0 / dt;
  const mrvi_v2 vidt = v2_set(idt, idt), vm = v2_set(mf[0], mf[0]);
  mrvi_v2 vmax = acc[0], vsum = acc[1], von = acc[2], voo = acc[3];
  int f = f0;
  for (; f + 2 <= nf; f += 2) {
    const mrvi_v2 fi = v2_add(v2_zero(), v2_scale(wc, v2_load(g + f)));
    const mrvi_v2 d = v2_load(dn + f);
    const mrvi_v2 mv = v2_mul(v2_mul(inc ? v2_load(mf + f) : vm, d), vidt);
    const mrvi_v2 Ff = v2_sub(v2_sub(v2_load(rhs + f), mv), fi);
    const mrvi_v2 a = unit ? v2_abs(Ff) : v2_mul(v2_abs(Ff), v2_load(rw + f));
    const mrvi_v2 Fo = v2_load(F + f);
    von = v2_add(von, v2_mul(Ff, Fo));
    voo = v2_add(voo, v2_mul(Fo, Fo));
    if (keep)
      v2_store(fimp + f, fi);
    if (!light) {
      const mrvi_v2 s = v2_mul(v2_scale(om, v2_load(jd + f)), Ff);
      const mrvi_v2 dx = v2_add(d, s);
      v2_store(F + f, Ff);
      v2_store(dnx + f, dx);
      v2_store(zf + f, step  ? s
                       : cur ? v2_add(v2_load(qm + f), v2_scale(cB, s))
                             : v2_add(v2_scale(1.0, v2_load(qm + f)),
                                      v2_scale(cB, dx)));
    }
    vmax = v2_max(a, vmax);
    vsum = v2_add(vsum, a);
  }
  if (!fin) { /* (pairs alone: the sums go on in acc) */
    acc[0] = vmax;
    acc[1] = vsum;
    acc[2] = von;
    acc[3] = voo;
    return;
  }
  double r = fmax(v2_lo(vmax), v2_hi(vmax)), sum = v2_lo(vsum) + v2_hi(vsum);
  double on = v2_lo(von) + v2_hi(von), oo = v2_lo(voo) + v2_hi(voo);
  for (; f < nf; f++) {
    const double fi = 0.0 + wc * g[f];
    if (keep)
      fimp[f] = fi;
    const double Ff = rhs[f] - mf[inc ? f : 0] * dn[f] * idt - fi;
    on += Ff * F[f];
    oo += F[f] * F[f];
    if (!light) {
      const double s = om * jd[f] * Ff;
      dnx[f] = dn[f] + s;
      zf[f] = step ? s : cur ? qm[f] + cB * s : 1.0 * qm[f] + cB * dnx[f];
      F[f] = Ff;
    }
    const double a = unit ? fabs(Ff) : fabs(Ff) * rw[f];
    r = a > r ? a : r;
    sum += a;
  }
  out[0] = r;
  out[1] = sum;
  out[2] = on;
  out[3] = oo;
}

/* chord_pass over rows [f0, f1) in its four variants, the next
 * configuration into zn: the absolute criterion with one point per
 * interval (the common case) with every fast mass read from entry 0 where
 * they are equal (sw->mass_inc 0: a stream fewer) or from its own entry,
 * and the general pass.  Every variant stores fimp only where the
 * interval has several points (keep): with one, fimp holds the last row's
 * converged force until the history moves on, which a row end deferred
 * to this update's parallel region (defer_part) does only after the pass
 * (defer_end); a pass storing over it there gave threads other bits than
 * one thread's (the scaled criterion; tuning.chord_linear where the fast
 * masses differ). */
static void chord_pass_rows(mrvi_sweep *sw, const double *qm, const double *zc,
                            const double *dn, const double *g, double om,
                            double wc, double cB, double *zn, int f0, int f1,
                            double out[4], int light, int step, mrvi_v2 acc[4],
                            int fin) {
  const int unit = sw->rw_one, keep = sw->n_w != 1;
  mrvi_v2 a0[4] = {v2_zero(), v2_zero(), v2_zero(), v2_zero()};
  mrvi_v2 *a = acc ? acc : a0; /* (NULL: the whole of [f0, f1)) */
#define PASS(U, K, I, L, S, C)                                                 \
  chord_pass(sw, C ? zc : qm, dn, g, om, wc, cB, zn, f0, f1, out, a, fin, U,   \
             K, I, L, S, C)
  if (light && unit && !keep && !sw->mass_inc)
    PASS(1, 0, 0, 1, 0, 0);
  else if (light)
    PASS(unit, keep, 1, 1, 0, 0);
  else if (step && unit && !keep && !sw->mass_inc)
    PASS(1, 0, 0, 0, 1, 0);
  else if (step)
    PASS(unit, keep, 1, 0, 1, 0);
  else if (zc && unit && !keep && !sw->mass_inc)
    PASS(1, 0, 0, 0, 0, 1);
  else if (zc && unit && !keep)
    PASS(1, 0, 1, 0, 0, 1);
  else if (zc)
    PASS(unit, keep, 1, 0, 0, 1);
  else if (unit && !keep && !sw->mass_inc)
    PASS(1, 0, 0, 0, 0, 0);
  else if (unit && !keep)
    PASS(1, 0, 1, 0, 0, 0);
  else
    PASS(unit, keep, 1, 0, 0, 0);
#undef PASS
}

/* The chord pass fused into the spring loop (mrvi_terms_grad_fused, the
 * serial gradient): the pass over the rows whose gradient is complete,
 * each time the spring loop completes more, in chord_residual's parts
 * (n_c of them, or one part [0, nf) where n_c is 0), each part's pairs
 * in order with its sums carried in acc and its tail and sums at its end:
 * chord_pass_rows's values over each part, bitwise.  The next
 * configuration goes over zf in place (no later spring reads a complete
 * row). */
typedef struct chord_stream {
  mrvi_sweep *sw;
  const double *qm, *dn, *g;
  double om, wc, cB;
  double *zn, *out; /* out: 4 numbers per part */
  int light, n_c, c, pos, end;
  mrvi_v2 acc[4];
  /* the deferred row end (sw->defer.serial): formed up to epos, its
   * scale's pairs in eacc (defer_stream_to) */
  int epos;
  mrvi_v2 eacc;
} chord_stream;

static void chord_stream_to(void *ctx, int to) {
  chord_stream *s = ctx;
  const int nf = s->sw->nf;
  while (s->pos < to) {
    if (to >= s->end) { /* (the part's last rows and its sums) */
      chord_pass_rows(s->sw, s->qm, s->zn, s->dn, s->g, s->om, s->wc, s->cB,
                      s->zn, s->pos, s->end, s->out + 4 * s->c, s->light, 0,
                      s->acc, 1);
      s->pos = s->end;
      s->c++;
      s->end = s->n_c > 0 ? mrvi_part_start(s->c + 1, nf, s->n_c) : nf;
      s->acc[0] = s->acc[1] = s->acc[2] = s->acc[3] = v2_zero();
      continue;
    }
    const int e = s->pos + ((to - s->pos) & ~1); /* (pairs) */
    if (e > s->pos)
      chord_pass_rows(s->sw, s->qm, s->zn, s->dn, s->g, s->om, s->wc, s->cB,
                      s->zn, s->pos, e, NULL, s->light, 0, s->acc, 0);
    s->pos = e;
    return;
  }
}

/* The chord pass's part sums combined in order (the maximum, the sums). */
static void chord_parts_sum(const double *cp, int n_c, double t[4]) {
  t[0] = t[1] = t[2] = t[3] = 0.0;
  for (int c = 0; c < n_c; c++) {
    t[0] = cp[4 * c] > t[0] ? cp[4 * c] : t[0];
    t[1] += cp[4 * c + 1];
    t[2] += cp[4 * c + 2];
    t[3] += cp[4 * c + 3];
  }
}

/* Rows [f0, f1) of row 0's fresh D: D^-1 = 1 / (hd + M/dt) into jdinv
 * (M/dt added as mrvi_sblock_solve) and the Gershgorin bound max off D^-1
 * over them, HUGE_VAL where some D <= 0 or is NaN (so that the bounds of
 * parts combined by the same rule give the bound of the whole row).  hd,
 * the Hessian diagonal, is held in jdinv itself and off, the off-diagonal
 * sums, in dnx (fresh_hd, fresh_off): each entry is read before it is
 * written here or by the pass that follows. */
static double *fresh_hd(mrvi_sweep *sw) { return sw->jdinv; }
static double *fresh_off(mrvi_sweep *sw) { return sw->dnx; }
static double fresh_bound(mrvi_sweep *sw, int f0, int f1) {
  const double dt = sw->st->dt;
  const double *hd = fresh_hd(sw), *off = fresh_off(sw);
  double bound = 0.0;
  for (int f = f0; f < f1; f++) {
    const double d = hd[f] + (1.0 / dt) * sw->m_f[f * sw->mass_inc];
    sw->jdinv[f] = 1.0 / d;
    const double b = off[f] * sw->jdinv[f]; /* (fmax's NaN rule) */
    bound = d > 0.0 ? (b > bound ? b : bound) : HUGE_VAL;
  }
  return bound;
}

/* Part c of fresh_parts below (after its barrier): the part's gradient
 * rows with the Hessian diagonal and off-diagonal sums at zf, its D^-1
 * and bound, and its pass, the next configuration into zn. */
static void fresh_part(mrvi_sweep *sw, int c, const double *qm,
                       const double *dn, const double *zf, double *zn) {
  const int nf = sw->nf, i = sw->imp, n_c = sw->n_cpass;
  const double wc = sw->w[i] * sw->cA[i], cB = sw->cB[i];
  const double hs = wc * sw->cB[i], om = 1.0 / (1.0 - sw->lam);
  const int f0 = mrvi_part_start(c, nf, n_c);
  const int f1 = mrvi_part_start(c + 1, nf, n_c);
  double *g = sw->gpt[i];
  zero(g + f0, f1 - f0);
  zero(fresh_hd(sw) + f0, f1 - f0);
  zero(fresh_off(sw) + f0, f1 - f0);
  mrvi_terms_grad_hdiag_part(sw->kc[MRVI_FAST], c, zf, g, fresh_hd(sw),
                             fresh_off(sw), hs);
  sw->cpass[4 * n_c + c] = fresh_bound(sw, f0, f1); /* (after the sums) */
  chord_pass_rows(sw, qm, zf, dn, g, om, wc, cB, zn, f0, f1, sw->cpass + 4 * c,
                  0, 0, NULL, 1);
}

/* After the parts: zn becomes zf, the bound and row residual returned. */
static double fresh_end(mrvi_sweep *sw, double *zf, double *zn, double *rho) {
  const int n_c = sw->n_cpass;
  const double *bound = sw->cpass + 4 * n_c;
  sw->zalt = zf;
  sw->zf = zn;
  double b = 0.0, t[4];
  for (int c = 0; c < n_c; c++) /* (in order; no NaN among them) */
    b = bound[c] > b ? bound[c] : b;
  *rho = sw->rho_c = b;
  chord_parts_sum(sw->cpass, n_c, t);
  return isnan(t[1]) ? t[1] : t[0];
}

/* chord_residual's first iterate of row 0 (fresh) where the fast class is
 * in the chord's parts (sw->cfused, on threads), in one parallel region:
 * the configuration in the parts' rows, then (after the barrier) each
 * part's gradient rows with the Hessian diagonal and off-diagonal sums
 * (mrvi_terms_grad_hdiag_part), its D^-1 and bound, and its pass by one
 * thread, the next configuration into zalt (other parts' gradients still
 * read zf), which then becomes zf; the parts' bounds and sums added in
 * order.  The serial path's values bitwise (the same entries, the same
 * sums per part). */
static double fresh_parts(mrvi_sweep *sw, const double *qm, const double *dn,
                          int zf_ok, double *rho) {
  const int nf = sw->nf, n_c = sw->n_cpass;
  const double cB = sw->cB[sw->imp];
  double *zf = sw->zf, *zn = sw->zalt;
  sw->evals_w++;
#ifdef _OPENMP
#pragma omp parallel num_threads(sw->pthreads)
#endif
  {
    if (!zf_ok)
      set_zf_parts(zf, qm, cB, dn, nf, n_c);
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
    for (int c = 0; c < n_c; c++)
      fresh_part(sw, c, qm, dn, zf, zn);
  }
  return fresh_end(sw, zf, zn, rho);
}

/* The row residual of a chord iterate with one implicit point, whose
 * configuration sw->zf the update has set (zf_ok) or is set here: the
 * gradient, the implicit force and F in one pass over the row (the
 * arithmetic of implicit_force and of the residual in solve_implicit, but
 * M dn times 1/dt).
 * With fresh (row 0's first iterate, sw->fresh), D = diag J at this
 * iterate as well (bitwise the diagonal of the J that Newton would
 * assemble there) and, in rho, the Gershgorin bound of chord_setup from
 * the elements' off-diagonal entries (at least the assembled matrix's: no
 * assembly).  A fresh D at every update contracted no faster and cost
 * more (doc/performance/explicit.md, "explicit-slow: micro step 0 on the
 * chord").
 *
 * In the same pass, the next chord iterate dnx = dn + om D^-1 F and its
 * configuration, written over sw->zf: taken where the row goes on, else
 * dropped (every other path sets zf afresh).  The relaxation om =
 * 1/(1 - lam): the plain update (om = 1) maps F to about (I - J D^-1) F,
 * whose eigenvalues lie in [-rho, rho]; where the residual sits near one
 * eigenvalue lam (on the benchmark lattice each residual is within a few
 * degrees of minus the last: the fast chains' alternating modes, which the
 * predictor misses most), the plain update leaves the factor lam on it and
 * the relaxed one removes it.  With track (F of this row's last iterate
 * in sw->F), lam = F.F_old / F_old.F_old, within [-rho_c, rho_c], for the
 * next update: after a relaxed update that ratio is small and the next
 * update nearly plain, so plain and relaxed updates alternate
 * (doc/performance/explicit.md, "explicit-slow: relaxed chord").  Convergence
 * is decided by the exact residual F as before.
 *
 * With light (the iterate that the row is expected to end on, sw->expect),
 * the pass first only tests F against the tolerance (chord_pass's light
 * pass: where it is met, solve_implicit returns, which it does at r <=
 * tol whatever else holds from min_it on, and the next iterate is not
 * needed), and the full pass follows, with the gradient kept, where it is
 * not: the same r, lam and iterates either way, only a pass more or
 * less. */
static void defer_flush(mrvi_sweep *sw);
static void defer_part(mrvi_sweep *sw, int c, double *dn);
static void defer_end(mrvi_sweep *sw);
static void defer_stream_to(void *ctx, int to);

static double chord_residual(mrvi_sweep *sw, const double *qm, const double *dn,
                             int zf_ok, int fresh, int track, int light,
                             int lin, int step, double *rho) {
  const int nf = sw->nf, i = sw->imp;
  const double wc = sw->w[i] * sw->cA[i], cB = sw->cB[i];
  double *g = sw->gpt[i];
  light = light && !lin; /* (zl's configuration kept: the full pass) */
  /* the gradient and the pass in one loop (chord_stream; not where the
   * pass's parts run on threads) */
  int fuse = sw->fuse && !fresh && !lin && !sw->cfused &&
             (sw->n_cpass == 0 || sw->pthreads <= 1) &&
             mrvi_terms_fused(sw->kc[MRVI_FAST]);
  /* the last row's end, unless it runs in the first update's region or
   * (on one thread) in its spring loop */
  const int dfr = sw->defer.on && !fresh && sw->cfused && zf_ok && !light;
  const int dfs = sw->defer.on && sw->defer.serial && fuse && zf_ok && !light;
  if (sw->defer.on && !dfr && !dfs)
    defer_flush(sw);
  if (fresh && sw->cfused) /* (on threads: in the parts) */
    return fresh_parts(sw, qm, dn, zf_ok, rho);
  if (!zf_ok)
    set_zf(sw, 1.0, qm, cB, dn);
  if (fresh) {
    zero(g, nf);
    zero(fresh_hd(sw), nf);
    zero(fresh_off(sw), nf);
    sw->evals_w++;
    mrvi_terms_grad_hdiag(sw->kc[MRVI_FAST], sw->zf, g, fresh_hd(sw),
                          fresh_off(sw), sw->w[i] * sw->cA[i] * sw->cB[i]);
    *rho = sw->rho_c = fresh_bound(sw, 0, nf);
  } else if (!sw->cfused && lin == 2) { /* g += cB H(zl) (dn - dprev) */
    sw->evals_lin++;
    mrvi_terms_hv_lin(sw->kc[MRVI_FAST], sw->zl, sw->lin, sw->zf, cB, g);
  } else if (!sw->cfused && lin == 1) {
    sw->evals_w++;
    zero(g, nf);
    mrvi_terms_grad_lin(sw->kc[MRVI_FAST], sw->zf, g, sw->lin);
  } else if (!sw->cfused && !fuse) {
    fast_gradient(sw, sw->zf, g, nf);
  }
  if (lin == 1 && !sw->cfused) { /* (zl keeps this configuration) */
    double *z = sw->zl;
    sw->zl = sw->zf;
    sw->zf = z;
  }
  const double om = 1.0 / (1.0 - sw->lam);
  double t[4];
  const int n_c = sw->n_cpass;
  int grad = !fresh && sw->cfused;
  light = light && !fresh;
  const double *zl = sw->zl;
again:
  if (fuse) { /* (the gradient's rows with their pass as they complete) */
    fuse = 0;
    sw->evals_w++;
    chord_stream cs = {sw,
                       qm,
                       dn,
                       g,
                       om,
                       wc,
                       cB,
                       sw->zf,
                       n_c > 0 ? sw->cpass : t,
                       light,
                       n_c,
                       0,
                       0,
                       n_c > 0 ? mrvi_part_start(1, nf, n_c) : nf,
                       {v2_zero(), v2_zero(), v2_zero(), v2_zero()},
                       0,
                       v2_zero()};
    if (dfs) /* (before the pass, which may store fimp: defer_stream_to) */
      rotate_history(sw);
    mrvi_terms_grad_fused(sw->kc[MRVI_FAST], sw->zf, g,
                          dfs ? defer_stream_to : NULL, chord_stream_to, &cs);
    if (dfs) { /* (the tail and the scale formed at the last columns) */
      sw->pred_scale = v2_lo(cs.eacc);
      sw->defer.on = 0;
    }
    if (n_c > 0)
      chord_parts_sum(sw->cpass, n_c, t);
  } else if (n_c == 0) {
    chord_pass_rows(sw, qm, lin ? NULL : sw->zf, dn, g, om, wc, cB, sw->zf, 0,
                    nf, t, light, step, NULL, 1);
  } else {
    double *cp = sw->cpass, *zn = grad && !light ? sw->zalt : sw->zf;
    const double *zf = sw->zf;
    sw->evals_w += grad && lin != 2;
    sw->evals_lin += grad && lin == 2;
#ifdef _OPENMP
#pragma omp parallel num_threads(sw->pthreads)
#endif
    {
      if (dfr) { /* (the last row's end: this row's start, then a barrier) */
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
        for (int c = 0; c < n_c; c++)
          defer_part(sw, c, (double *)dn);
      }
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
      for (int c = 0; c < n_c; c++) {
        const int f0 = mrvi_part_start(c, nf, n_c);
        const int f1 = mrvi_part_start(c + 1, nf, n_c);
        if (grad && lin == 2) /* (mrvi_terms_hv_lin's rows) */
          mrvi_terms_hv_lin_part(sw->kc[MRVI_FAST], c, zl, sw->lin, zf, cB, g);
        else if (grad) { /* part c's gradient rows (fast_gradient's, bitwise) */
          zero(g + f0, f1 - f0);
          if (lin == 1)
            mrvi_terms_grad_lin_part(sw->kc[MRVI_FAST], c, zf, g, sw->lin);
          else
            mrvi_terms_grad_part(sw->kc[MRVI_FAST], c, zf, g);
        }
        chord_pass_rows(sw, qm, lin ? NULL : zf, dn, g, om, wc, cB, zn, f0, f1,
                        cp + 4 * c, light, step && !light, NULL, 1);
      }
    }
    if (dfr)
      defer_end(sw);
    if (grad && !light) { /* (zalt: the next configuration) */
      sw->zalt = sw->zf;
      sw->zf = zn;
      if (lin == 1) { /* (zl keeps this one) */
        sw->zalt = sw->zl;
        sw->zl = (double *)zf;
      }
    }
    chord_parts_sum(cp, n_c, t);
  }
  const double r = isnan(t[1]) ? t[1] : t[0], on = t[2], oo = t[3];
  if (light && !(r <= sw->tol)) { /* (the full pass, g kept) */
    light = grad = 0;
    goto again;
  }
  if (track && oo > 0.0 && isfinite(on)) { /* (the next update's lam) */
    sw->lam = fmin(sw->rho_c, fmax(-sw->rho_c, on / oo));
    sw->lam_sum += sw->lam;
  }
  return r;
}

/* fresh_exact's bound where the fast class is in the chord's parts
 * (sw->cfused, on threads), in one parallel region: the configuration z
 * in the parts' columns, then (after a barrier) each part's sums
 * (mrvi_terms_gershgorin_part's pass 0), then (after a barrier) each
 * part's largest row bound, combined in the parts' order by the serial
 * rule: mrvi_terms_gershgorin's value bitwise, for every thread count. */
static double fresh_exact_parts(mrvi_sweep *sw, const double *qm,
                                const double *dn, double *z, double hs) {
  const int nf = sw->nf, n_c = sw->n_cpass;
  const double cB = sw->cB[sw->imp];
  const mrvi_terms *kc = sw->kc[MRVI_FAST];
  double *bound = sw->cpass + 4 * n_c; /* (fresh_end has read them) */
#ifdef _OPENMP
#pragma omp parallel num_threads(sw->pthreads)
#endif
  {
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
    for (int c = 0; c < n_c; c++) {
      const int f1 = mrvi_part_start(c + 1, nf, n_c);
      for (int f = mrvi_part_start(c, nf, n_c); f < f1; f++)
        z[f] = 1.0 * qm[f] + cB * dn[f];
    }
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
    for (int c = 0; c < n_c; c++)
      mrvi_terms_gershgorin_part(kc, c, z, hs, sw->jdinv, sw->dprev, sw->fimp,
                                 0);
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
    for (int c = 0; c < n_c; c++)
      bound[c] = mrvi_terms_gershgorin_part(kc, c, z, hs, sw->jdinv, sw->dprev,
                                            sw->fimp, 1);
  }
  double m = 0.0;
  for (int c = 0; c < n_c; c++) /* (mrvi_terms_gershgorin's rule) */
    m = bound[c] > m || isnan(bound[c]) ? bound[c] : m;
  return isfinite(m) ? m : HUGE_VAL;
}

/* Row 0's fresh bound where the elements' (fresh_bound: each element's
 * off-diagonal entries by absolute value) exceeds chord_jacobi_max: the
 * bound of the matrix Newton would assemble at the same iterate dn (its
 * own-particle blocks summed with their signs, which cancel where a
 * particle has springs in several directions: random networks), one pass
 * more over the springs, in the arrays the row does not hold then (the
 * configuration in the gradient's, the sums in dprev and fimp: the next
 * update writes each whole before it reads it).  It decides the regime,
 * and the relaxation's bound rho_c becomes it.  The same bits for every
 * thread count (fresh_exact_parts on threads; bench_floor's random3d at
 * 1e5 took Newton at every step's row 0 with the elements' bound,
 * doc/performance/explicit.md). */
static double fresh_exact(mrvi_sweep *sw, const double *qm, const double *dn) {
  const int nf = sw->nf, i = sw->imp;
  const double cB = sw->cB[i], hs = sw->w[i] * sw->cA[i] * cB;
  double *z = sw->gpt[i];
  double b;
  if (sw->cfused) { /* (on threads: fresh_exact_parts) */
    b = fresh_exact_parts(sw, qm, dn, z, hs);
  } else {
    for (int f = 0; f < nf; f++)
      z[f] = 1.0 * qm[f] + cB * dn[f];
    b = mrvi_terms_gershgorin(sw->kc[MRVI_FAST], z, hs, sw->jdinv, sw->dprev,
                              sw->fimp, nf);
  }
  sw->rho_c = b <= sw->chord_max ? b : sw->rho_c;
  return b;
}

/* Solve row m for the displacement dn = q^{m+1} - q^m given qm = q^m and
 * rhs = p^{f,m} minus the forces of the points at node m (Newton on nf
 * unknowns, or the Jacobi chord above; displacements keep tiny steps'
 * digits).  Row 0's predictor has no last implicit force. */
static int solve_implicit(mrvi_sweep *sw, const double *qm, double *dn, int m,
                          int *iters, double *res, char *msg, size_t len) {
  const int nf = sw->nf, first = m == 0, inc = sw->mass_inc;
  const double dt = sw->st->dt;
  /* Predictor: the last implicit force held fixed (explicit in it).  Row 0
   * has none (nothing is carried from the last step, so a step depends on
   * (q_k, p_k) alone): its implicit points are evaluated once at the
   * estimate without implicit force, as in the predictor's interval 0
   * (solver/predict.c), which leaves a row error w cA cB |hess W| / (M/dt)
   * = (omega dt)^2/4 times that estimate's.  Without it the lattice
   * benchmark's row 0 (n = 312) starts at a residual about 10 times that of
   * the other rows (1e-1 against 8e-3, medians), and one update leaves 3e-9
   * > the tolerance 1e-9: two updates where the other rows take one (one
   * gradient against a Newton update); with it, 1.9e-4 and 3e-14. */
  /* That factor exceeds 1 where omega dt > 2 (a stiff W at a large step):
   * the estimate then moves away from the solution, and on a stiff
   * non-linear W (a quartic at dT = 0.3) Newton from there needs three
   * times the updates of Newton from the free flight dn0 = dt M^-1 rhs (the
   * general path's predictor at such steps, solver/predict.c).  So row 0
   * keeps dn0's residual r0 (free: its only term is the implicit force),
   * and the first iteration falls back to dn0 where the estimate's
   * residual is larger. */
  double r0 = HUGE_VAL;
  /* Row 0 takes the chord from its start where W is springs and anchors
   * alone and the bound at its first iterate holds (chord_residual),
   * else Newton, whose first matrix decides (chord_setup). */
  if (first) {
    sw->mild = sw->chord = sw->fresh && sw->imp >= 0 && sw->chord_max > 0.0;
    sw->lam = 0.0; /* (a step depends on (q_k, p_k) alone) */
  }
  double scale = 0.0;
  /* (row 0 too extrapolates where the last step's rows are kept) */
  int pred = (!first || sw->carry > 0) && sw->sparse, zf_ok = 0;
  const int pre = first && sw->pstart; /* (formed by start_parts) */
  if (pre) {
    r0 = sw->pre[0];
    scale = sw->pre[1];
  } else if (pred) {
    zf_ok = sw->chord && sw->imp >= 0;
    scale = sw->predicted ? sw->pred_scale
                          : extrapolated_predictor(
                                sw, m, qm, dn, zf_ok ? sw->cB[sw->imp] : 0.0);
    sw->predicted = 0;
  } else {
    for (int pass = first ? 0 : 1; pass < 2; pass++) {
      for (int f = 0; f < nf; f++)
        dn[f] = dt * sw->minv_f[f * inc] * (sw->rhs[f] - sw->fimp[f]);
      if (pass == 0) {
        implicit_force(sw, qm, dn, NULL);
        r0 = 0.0;
        for (int f = 0; f < nf; f++) {
          free_flight(sw)[f] = dn[f];
          const double a = rweight(
              sw->rw, sw->rw_one,
              fabs(sw->rhs[f] - sw->m_f[f * inc] * dn[f] / dt - sw->fimp[f]),
              f);
          r0 = isnan(a) || a > r0 ? a : r0;
        }
      }
    }
  }
  for (int f = 0; !pred && !pre && f < nf; f++) { /* (fmax's NaN rule) */
    const double v = rweight(
        sw->rw, sw->rw_one,
        fabs(sw->rhs[f]) + 4.0 * sw->m_f[f * inc] * fabs(qm[f]) / dt, f);
    scale = v > scale ? v : scale;
  }
  double floor = 16.0 * DBL_EPSILON * scale;
  /* (a deferred row end sets the scale in the first update: end_predict) */
  int deferred = pred && sw->defer.on;
  /* Newton evaluates J with the residual where an update follows for sure
   * (the first iterate), else the residual alone and J only where that
   * residual misses the tolerance (a second evaluation, the same values):
   * a micro step that converges in one update assembles J once. */
  int chord = sw->chord, with_j = !chord, min_it = 1;
  double r_prev = HUGE_VAL;
  /* tuning.chord_linear: the update (it) whose gradient keeps the springs'
   * Hessians, after it lin_n linearised residuals at most (lin_last the
   * last), each only where the last residual missed the tolerance: a
   * pattern fixed within the row, so that a step depends on its start
   * alone (and the threads' parts give the serial values).  The passes
   * before a linearised residual write the update into zf (its product
   * reads it), not the configuration. */
  const int lin_at = first && sw->fresh ? 1 : 0;
  const int lin_last = lin_at + sw->lin_n;
  int lin = 0;
  /* At least one update: the predictor is second-order accurate, so at tiny
   * steps its residual can pass the tolerance while its momentum error,
   * summed over many micro steps, exceeds the truncation error. */
  for (int it = 0;; it++) {
    /* F = rhs - M (qn - qm)/dt - sum w cA grad W(z); J = M/dt + w cA cB H. */
    double r = 0.0;
    if (chord && sw->imp >= 0) {
      double rho = 0.0;
      if (pre && it == 0 && sw->pstart) { /* (start_parts' first iterate) */
        r = sw->pre[2];
        rho = sw->pre[3];
        sw->pstart = 0;
      } else {
        lin = sw->lin_n <= 0 || it < lin_at || it > lin_last ? 0
              : it == lin_at                                 ? 1
              : lin == 0 || !(r_prev > sw->tol)              ? 0
                                                             : 2;
        r = chord_residual(
            sw, qm, dn, zf_ok, first && sw->fresh && it == 0, it >= 1,
            it >= min_it && it >= (first ? sw->expect0 : sw->expect), lin,
            lin && it < lin_last, &rho);
      }
      if (deferred) {
        floor = 16.0 * DBL_EPSILON * sw->pred_scale;
        deferred = 0;
      }
      zf_ok = 0; /* (zf: the next iterate's, taken by the update below) */
      if (!(rho <= sw->chord_max) && rho < HUGE_VAL && first && sw->fresh &&
          it == 0) /* (the elements' bound: the assembled one decides) */
        rho = fresh_exact(sw, qm, dn);
      if (!(rho <= sw->chord_max)) { /* Newton on row 0 (an evaluation) */
        chord = sw->chord = sw->mild = 0;
        with_j = 1;
        it--;
        continue;
      }
    } else {
      lin = 0; /* (Newton: exact residuals) */
      if (with_j && sw->sparse) {
        const int s = sblock_ready(sw, msg, len);
        if (s < 0)
          return s;
        if (!sblock_par(sw)) /* (else zeroed in its parts) */
          mrvi_sblock_zero(sw->sb);
      } else if (with_j)
        memset(sw->J, 0, (size_t)nf * (size_t)nf * sizeof(double));
      implicit_force(sw, qm, dn, with_j ? sw->J : NULL);
      for (int f = 0; f < nf; f++) {
        sw->F[f] = sw->rhs[f] - sw->m_f[f * inc] * dn[f] / dt - sw->fimp[f];
        const double a = rweight(sw->rw, sw->rw_one, fabs(sw->F[f]), f);
        r = isnan(a) || a > r ? a : r;
      }
    }
    if (it == 0 && r > r0) { /* (not for NaN r0: r > r0 is false) */
      memcpy(dn, free_flight(sw), (size_t)nf * sizeof(double));
      r0 = HUGE_VAL;
      it = -1; /* (the fallback is no update) */
      continue;
    }
    /* A chord row between the tolerance and the round-off floor goes on
     * while it contracts and is met where it stalls (the outer
     * iteration's rule, solver/outer.c): the floor, from M |q^m|/dt, is
     * the round-off of the general path's absolute positions, far above
     * that of this displacement form where |q| is large, and Newton's
     * last update lands far below the tolerance where the chord's lands
     * just below it. */
    const int stalled = !(chord && it >= 1 && r <= sw->chord_max * r_prev);
    if (it >= min_it && lin != 2 &&
        (r <= sw->tol || (r <= floor && (stalled || !chord)))) {
      if (chord && first)
        sw->expect0 = it;
      if (chord)
        sw->expect = it;
      *iters = it;
      *res = fmax(*res, r);
      return MRVI_OK;
    }
    if (chord && it >= 1 &&
        (!(r <= sw->chord_max * r_prev) || 2 * it >= sw->max_iter)) {
      /* The chord contracts poorly (or diverges), or has taken half the
       * updates allowed: Newton for the rest of the step, from the better
       * of the last two iterates. */
      chord = sw->chord = 0;
      if (r_prev < HUGE_VAL && !(r <= r_prev)) { /* (after a chord update) */
        memcpy(dn, sw->dprev, (size_t)nf * sizeof(double));
        min_it = it + 1;
      }
      with_j = 1;
      it--; /* (an evaluation, no update) */
      continue;
    }
    if (!isfinite(r) || it == sw->max_iter) {
      *iters = it;
      *res = r;
      mrvi_fmt(msg, len,
               "micro-step Newton %s after %d iterations, "
               "residual %.3e (tolerance %.3e, roundoff floor %.1e)",
               isfinite(r) ? "did not converge" : "produced non-finite values",
               it, r, sw->tol, floor);
      return isfinite(r) ? MRVI_ENEWTON : MRVI_ENONFINITE;
    }
    if (chord && sw->imp >= 0) {
      /* dn += D^-1 F and the next point's configuration, both formed by
       * chord_residual: dprev <- dn <- dnx. */
      r_prev = r;
      double *t = sw->dprev;
      sw->dprev = dn;
      dn = sw->dn = sw->dnx;
      sw->dnx = t;
      /* (zf holds the update where a linearised one was to follow: the
       * configuration set afresh where it does not) */
      zf_ok = !(lin && it < lin_last) || r > sw->tol;
      continue;
    }
    if (chord) { /* dn += D^-1 F */
      r_prev = r;
      for (int f = 0; f < nf; f++) {
        sw->dprev[f] = dn[f];
        dn[f] += sw->jdinv[f] * sw->F[f];
      }
      continue;
    }
    if (!with_j) { /* J at this iterate */
      with_j = 1;
      it--;
      continue;
    }
    with_j = 0;
    if (sw->sparse) {
      /* J d = F by CG to 1 % of the tolerance (inexact Newton: the
       * residual above is exact, so the solution is the same). */
      const int s = mrvi_sblock_solve(
          sw->sb, sw->m_f, (int)inc, 1.0 / dt, sw->F,
          0.01 * fmax(sw->tol, floor) * sw->cg_unit, msg, len);
      if (s < 0)
        return s;
      /* Row 0's first matrix sets the chord up; its later updates take
       * it too (the first Newton update leaves about the tolerance: one
       * gradient where a second Newton update would cost ten). */
      if (first && it == 0 && sw->chord_max > 0.0) {
        chord_setup(sw);
        chord = sw->chord;
      }
    } else {
      for (int f = 0; f < nf; f++)
        sw->J[f * nf + f] += sw->m_f[f] / dt;
      if (mrvi_dense_lu_factor(nf, sw->J, sw->piv) < 0) {
        mrvi_fmt(msg, len, "singular micro-step Newton matrix");
        return MRVI_ESINGULAR;
      }
      mrvi_dense_lu_solve(nf, sw->J, sw->piv, sw->F, 1);
    }
    for (int f = 0; f < nf; f++)
      dn[f] += sw->F[f];
  }
}

/* Control forces on fast row m (st->f_rows, optimal control), or NULL:
 * constants of the step that add to the row's momentum p^{f,m}. */
static const double *force_row(const mrvi_step *st, int m) {
  return st->f_rows ? st->f_rows + st->ns + (size_t)m * (size_t)st->nf : NULL;
}

/* Row m of the explicit sweep with one W point at each node and no
 * control force, for blocks beyond the small kernels: explicit_nodes'
 * operations entry by entry (r = p - wl g, dn = dt minv r, q^{m+1} =
 * q^m + dn, M dn / dt), two entries at a time (util/simd.h: the same
 * operations on each, so the same values; GCC's -O2 leaves the loop
 * scalar, and its division per entry bounds it).  The masses' entries
 * are read every inc (mass_inc: 0 for equal masses).  qn and pn may be qm
 * and pm (the last node alone kept): each pair is read before it is
 * written. */
static void explicit_row(int nf, double dt, double wl, const double *pm,
                         const double *gnode, const double *minv,
                         const double *mf, int inc, const double *qm,
                         double *qn, double *pn) {
  const mrvi_v2 vdt = v2_set(dt, dt);
  int f = 0;
  for (; f + 2 <= nf; f += 2) {
    const mrvi_v2 r = v2_sub(v2_load(pm + f), v2_scale(wl, v2_load(gnode + f)));
    const mrvi_v2 dn = v2_mul(v2_scale(dt, v2_load(minv + f * inc)), r);
    v2_store(qn + f, v2_add(v2_load(qm + f), dn));
    v2_store(pn + f, v2_div(v2_mul(v2_load(mf + f * inc), dn), vdt));
  }
  for (; f < nf; f++) {
    const double r = pm[f] - wl * gnode[f], dn = dt * minv[f * inc] * r;
    qn[f] = qm[f] + dn;
    pn[f] = mf[f * inc] * dn / dt;
  }
}

/* Rows f0..f1 of node m of the explicit path: q^{m+1} = q^m + dt M^-1 r,
 * r = p^{f,m} (+ the control force fm) - sum wl grad W(q^m), and the
 * momentum's first part p^{f,m+1} = M dn / dt. */
ALWAYS_INLINE void explicit_rows(const double *pm, const double *fm,
                                 const double *wl, const double *gnode,
                                 const double *mf, const double *minv, int inc,
                                 const double *qm, double *qn, double *pn,
                                 double dt, const int nl, int f0, int f1) {
  UNROLL
  for (int f = f0; f < f1; f++) {
    double r = pm[f];
    if (fm)
      r += fm[f];
    for (int i = 0; i < nl; i++)
      r -= wl[i] * gnode[f];
    const double dn = dt * minv[f * inc] * r;
    qn[f] = qm[f] + dn;
    pn[f] = mf[f * inc] * dn / dt;
  }
}

/* pn -= wr gnode (nf entries) in pairs, as explicit_row. */
static void explicit_end_force(int nf, double wr, const double *gnode,
                               double *pn) {
  int f = 0;
  for (; f + 2 <= nf; f += 2)
    v2_store(pn + f, v2_sub(v2_load(pn + f), v2_scale(wr, v2_load(gnode + f))));
  for (; f < nf; f++)
    pn[f] -= wr * gnode[f];
}

/* The fast nodes of the explicit path (every W point on a node): row m
 * gives q^{m+1} from p^{f,m} (in pf's row m - 1, row 0: pf's first row as
 * set by the caller) and grad W at node m; p^{f,m+1} follows with grad W at
 * node m + 1, which also serves row m + 1.  The arithmetic of the general
 * sweep below, in one pass per node. */
ALWAYS_INLINE void explicit_nodes(mrvi_sweep *sw, const mrvi_step *st,
                                  double *x, double *pf, const int nl,
                                  const int nr, const int nf, const int p) {
  const int ns = sw->ns;
  const double dt = st->dt, *wl = sw->wl, *wr = sw->wr;
  const double *mf = sw->m_f, *minv = sw->minv_f;
  double *gnode = sw->gnode;
  const size_t stride = sw->node_stride;
  const double *pm = pf;
  for (int m = 0; m < p; m++) {
    const double *qm = m == 0 ? st->qf0 : x + ns + (size_t)(m - 1) * stride;
    double *qn = x + ns + (size_t)m * stride, *pn = pf + (size_t)m * stride;
    const double *fm = force_row(st, m);
    if (nl > 0 && !sw->gnode_ok)
      fast_gradient(sw, qm, gnode, nf);
    const int pairs = nl == 1 && nr == 1 && !fm && nf > 4; /* (not small) */
    if (pairs) {
      explicit_row(nf, dt, wl[0], pm, gnode, minv, mf, sw->mass_inc, qm, qn,
                   pn);
    } else {
      explicit_rows(pm, fm, wl, gnode, mf, minv, sw->mass_inc, qm, qn, pn, dt,
                    nl, 0, nf);
    }
    sw->gnode_ok = 0;
    if (nr > 0) {
      fast_gradient(sw, qn, gnode, nf);
      sw->gnode_ok = 1;
      if (pairs) {
        explicit_end_force(nf, wr[0], gnode, pn);
      } else {
        UNROLL
        for (int f = 0; f < nf; f++)
          for (int i = 0; i < nr; i++)
            pn[f] -= wr[i] * gnode[f];
      }
    }
    pm = pn;
  }
}

/* Rows [c chunk, (c+1) chunk) of grad W at z into g (part c of the fast
 * class, mrvi_terms_grad_part: fast_gradient's sums, bitwise). */
static void fast_gradient_part(const mrvi_sweep *sw, int c, const double *z,
                               double *g) {
  int f0, f1;
  mrvi_terms_part_columns(sw->kc[MRVI_FAST], c, &f0, &f1);
  zero(g + f0, f1 - f0);
  mrvi_terms_grad_part(sw->kc[MRVI_FAST], c, z, g);
}

/* Part c of node m's end: grad W at qn into gnode and pn -= sum wr
 * grad W (explicit_nodes' arithmetic, in pairs as explicit_nodes with one
 * point at each end). */
static void end_force_part(const mrvi_sweep *sw, int c, const double *qn,
                           double *gnode, double *pn, const double *wr,
                           int nr) {
  fast_gradient_part(sw, c, qn, gnode);
  int f0, f1;
  mrvi_terms_part_columns(sw->kc[MRVI_FAST], c, &f0, &f1);
  if (nr == 1) {
    explicit_end_force(f1 - f0, wr[0], gnode + f0, pn + f0);
    return;
  }
  for (int f = f0; f < f1; f++)
    for (int i = 0; i < nr; i++)
      pn[f] -= wr[i] * gnode[f];
}

/* Part c's rows of node m (explicit_nodes' arithmetic: explicit_row where
 * it takes it). */
static void rows_part(const mrvi_sweep *sw, int c, const double *pm,
                      const double *fm, const double *qm, double *qn,
                      double *pn, double dt) {
  int f0, f1;
  mrvi_terms_part_columns(sw->kc[MRVI_FAST], c, &f0, &f1);
  const double *gnode = sw->gnode, *mf = sw->m_f, *minv = sw->minv_f;
  if (sw->nl == 1 && sw->nr == 1 && !fm)
    explicit_row(f1 - f0, dt, sw->wl[0], pm + f0, gnode + f0,
                 minv + f0 * sw->mass_inc, mf + f0 * sw->mass_inc, sw->mass_inc,
                 qm + f0, qn + f0, pn + f0);
  else
    explicit_rows(pm, fm, sw->wl, gnode, mf, minv, sw->mass_inc, qm, qn, pn, dt,
                  sw->nl, f0, f1);
}

/* The end of a step by end_check's sum: non-finite values propagate along
 * the step, so the new node suffices to notice them; a step taken keeps
 * grad V at its end node for the next one. */
static int end_status(mrvi_sweep *sw, double sum, char *msg, size_t len) {
  if (!isfinite(sum)) {
    sw->gnode_ok = 0;
    mrvi_fmt(msg, len, "the %s step produced non-finite values",
             sw->implicit ? "sweep" : "explicit");
    return MRVI_ENONFINITE;
  }
  sw->gv_ok = sw->wv1 != 0.0;
  return MRVI_OK;
}

/* end_check's sum over part c of n_part parts of n rows (mrvi_part_start). */
static double check_part(const double *x, const double *y, int c, int n,
                         int n_part) {
  const int i1 = mrvi_part_start(c + 1, n, n_part);
  double sum = 0.0;
  for (int i = mrvi_part_start(c, n, n_part); i < i1; i++)
    sum += x[i] * 0.0 + y[i] * 0.0;
  return sum;
}

/* Slow part c at the explicit step's start (sweep_step's slow row:
 * q_{k+1}^s and ps1 by grad V at node k), its rows of gn (unless NULL)
 * cleared for grad V at the end node and, where V reads a copy (zv not
 * x), x's copied. */
static void slow_start_part(const mrvi_sweep *sw, const mrvi_step *st, int c,
                            const double *gv, double *x, double *ps1,
                            double *gn, double *zv) {
  const int s1 = mrvi_part_start(c + 1, sw->ns, sw->n_cs);
  const double w0 = sw->wv0, dT = st->dT;
  const double *ps0 = st->ps0, *qs0 = st->qs0, *frow = st->f_rows;
  for (int s = mrvi_part_start(c, sw->ns, sw->n_cs); s < s1; s++) {
    double v = ps0[s] - w0 * gv[s]; /* M^s (q_{k+1}^s - q_k^s)/dT */
    if (frow)
      v += frow[s];
    ps1[s] = v;
    x[s] = qs0[s] + dT * sw->minv_s[s * sw->inc_s] * v;
    if (gn)
      gn[s] = 0.0;
    if (zv != x)
      zv[s] = x[s];
  }
}

/* Fast part c's p^{f,0} (sweep_step's row 0 momentum) into pm, its rows
 * of gn cleared. */
static void fast_start_part(const mrvi_sweep *sw, const mrvi_step *st, int c,
                            const double *gv, double *pm, double *gn) {
  int f0, f1;
  mrvi_terms_part_columns(sw->kc[MRVI_FAST], c, &f0, &f1);
  const int ns = sw->ns;
  const double w0 = sw->wv0, *pf0 = st->pf0;
  for (int f = f0; f < f1; f++) {
    pm[f] = pf0[f] - w0 * gv[ns + f];
    gn[ns + f] = 0.0;
  }
}

/* The end of part c of n rows (slow: x, ps1; fast: xe, pe) in the explicit
 * step (end_potential's V term and the control force f_end of
 * sweep_step, entry by entry), with the part's sum of end_check. */
static double end_part(const mrvi_sweep *sw, int c, int n, int n_part,
                       const double *gn, const double *fe, const double *q,
                       double *pe) {
  const int i1 = mrvi_part_start(c + 1, n, n_part);
  const double w1 = sw->wv1;
  for (int i = mrvi_part_start(c, n, n_part); i < i1; i++) {
    if (w1 != 0.0)
      pe[i] -= w1 * gn[i];
    if (fe)
      pe[i] += fe[i];
  }
  return check_part(q, pe, c, n, n_part);
}

/* In a parallel region (its loops shared by the region's threads): grad
 * V at the end node zv (complete) into gn (cleared) in V's parts, then the
 * end momenta and end_check's sums of the n_cs slow and n_f fast parts
 * (end_part) into csum, no barrier after them. */
static void end_v_parts(const mrvi_sweep *sw, const double *zv, double *gn,
                        const double *fe, const double *x, double *ps1,
                        const double *xe, double *pe, int n_f, double *csum) {
  const int ns = sw->ns, nf = sw->nf, n_cs = sw->n_cs;
  const int n_vpart = mrvi_terms_parts(sw->kc[MRVI_SLOW]);
  if (sw->wv1 != 0.0 && n_vpart > 0) {
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
    for (int c = 0; c < n_vpart; c++)
      mrvi_terms_grad_part(sw->kc[MRVI_SLOW], c, zv, gn);
  } else if (sw->wv1 != 0.0) {
#ifdef _OPENMP
#pragma omp single
#endif
    mrvi_terms_grad(sw->kc[MRVI_SLOW], zv, gn); /* (a serial class) */
  }
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
  for (int c = 0; c < n_cs; c++)
    csum[c] = end_part(sw, c, ns, n_cs, gn, fe, x, ps1);
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
  for (int c = 0; c < n_f; c++)
    csum[n_cs + c] =
        end_part(sw, c, nf, n_f, gn + ns, fe ? fe + ns : NULL, xe, pe);
}

/* The fast configuration of node m + 1 (row m's left end: st->qf0 for m =
 * -1) in explicit_step_par: x's row m, or with node_stride 0 x's fast
 * part and qalt alternately, node p in x. */
static double *node_q(const mrvi_sweep *sw, const mrvi_step *st, double *x,
                      int m) {
  if (m < 0)
    return (double *)st->qf0; /* (read only) */
  if (sw->node_stride > 0)
    return x + sw->ns + (size_t)m * sw->node_stride;
  return (sw->p - 1 - m) % 2 == 0 ? x + sw->ns : sw->qalt;
}

/* The explicit step (sweep_step's arithmetic, entry by entry the same)
 * on sw->threads threads in one parallel region, every loop in a
 * partition by the sizes and thread_chunk alone (the same bits for every
 * thread count): the slow row in n_cs parts; the fast rows in the fast
 * class's parts, each part's p^{f,0}, gradient rows and node updates by
 * one thread, one barrier per node where its configuration is complete
 * (two without an end force); grad V at the end node in V's parts (into
 * gv_next: the start still reads gv); the end momenta and end_check's
 * sums in the slow and fast parts. */
static int explicit_step_par(mrvi_sweep *sw, const mrvi_step *st, double *x,
                             double *ps1, double *pf, char *msg, size_t len) {
  const int ns = sw->ns, nf = sw->nf, p = sw->p, nl = sw->nl, nr = sw->nr;
  const int n_part = mrvi_terms_parts(sw->kc[MRVI_FAST]), n_cs = sw->n_cs;
  const double dt = st->dt, w0 = sw->wv0, w1 = sw->wv1, *wr = sw->wr;
  /* grad V at node k: kept from the last step's end node, else evaluated */
  if (w0 != 0.0 && !sw->gv_ok)
    slow_gradient(sw, st->qs0, st->qf0, ns, nf);
  sw->gv_ok = 0;
  const double *gv = w0 != 0.0 ? sw->gv : sw->gzero, *fe = st->f_end;
  double *gn = sw->gv_next, *gnode = sw->gnode, *csum = sw->csum;
  const size_t stride = sw->node_stride;
  double *xe = node_q(sw, st, x, p - 1), *pe = pf + (size_t)(p - 1) * stride;
  /* V's configuration at the end node: x itself where adjacent */
  double *zv = w1 == 0.0 || xe == x + ns ? x : sw->zv;
  const int g0 = nl > 0 && !sw->gnode_ok;
#ifdef _OPENMP
#pragma omp parallel num_threads(sw->threads)
#endif
  {
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
    for (int c = 0; c < n_cs; c++)
      slow_start_part(sw, st, c, gv, x, ps1, gn, zv);
    for (int m = 0; m < p; m++) {
      const double *qm = node_q(sw, st, x, m - 1);
      const double *pm = m == 0 ? pf : pf + (size_t)(m - 1) * stride;
      double *qn = node_q(sw, st, x, m), *pn = pf + (size_t)m * stride;
      const double *fm = force_row(st, m);
      /* grad W at node m, unless node m - 1's end left it */
      if (nl > 0 && (m == 0 ? g0 : nr == 0)) {
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
        for (int c = 0; c < n_part; c++)
          fast_gradient_part(sw, c, qm, gnode);
      }
      /* (p^{f,0} of part c by the thread that takes its rows: the same
       * static schedule) */
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
      for (int c = 0; c < n_part; c++) {
        if (m == 0)
          fast_start_part(sw, st, c, gv, pf, gn);
        rows_part(sw, c, pm, fm, qm, qn, pn, dt);
      }
      /* (after the barrier: node m + 1 complete) grad W there and the end
       * force; the next node's rows of part c read part c's rows alone,
       * which the same thread wrote (the same static schedule), and write
       * a configuration no part reads any more (node m's two before, or
       * another row of x), so no barrier follows. */
      if (nr > 0) {
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
        for (int c = 0; c < n_part; c++)
          end_force_part(sw, c, qn, gnode, pn, wr, nr);
      }
    }
    /* grad V at the end node (its configuration complete after the last
     * node's barrier; gn cleared before it) */
    if (w1 != 0.0 && zv != x) {
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
      for (int c = 0; c < n_part; c++) {
        int f0, f1;
        mrvi_terms_part_columns(sw->kc[MRVI_FAST], c, &f0, &f1);
        memcpy(zv + ns + f0, xe + f0, (size_t)(f1 - f0) * sizeof(double));
      }
    }
    /* the end momenta: each part's rows by the thread that wrote them
     * where V is not evaluated (the same static schedules) */
    end_v_parts(sw, zv, gn, fe, x, ps1, xe, pe, n_part, csum);
  }
  sw->gnode_ok = nr > 0;
  sw->evals_w += g0 + (long)(p - 1) * (nl > 0 && nr == 0) + (long)p * (nr > 0);
  if (w1 != 0.0) { /* grad V at the end node: the next step's gv */
    sw->evals_v++;
    sw->gv_next = sw->gv;
    sw->gv = gn;
  }
  double sum = 0.0;
  for (int c = 0; c < n_cs + n_part; c++)
    sum += csum[c];
  return end_status(sw, sum, msg, len);
}

/* The explicit sweep, unrolled for the trapezoidal rule (one point at each
 * node of an interval). */
ALWAYS_INLINE void explicit_sweep(mrvi_sweep *sw, const mrvi_step *st,
                                  double *x, double *pf, const int nf) {
  if (sw->nl == 1 && sw->nr == 1 && sw->p == 1)
    explicit_nodes(sw, st, x, pf, 1, 1, nf, 1); /* p = 1: no loop */
  else if (sw->nl == 1 && sw->nr == 1)
    explicit_nodes(sw, st, x, pf, 1, 1, nf, sw->p);
  else
    explicit_nodes(sw, st, x, pf, sw->nl, sw->nr, nf, sw->p);
}

/* y = A x (A: nf x nf, row-major). */
ALWAYS_INLINE void matvec(const double *restrict A, const double *restrict x,
                          double *restrict y, const int nf) {
  UNROLL
  for (int a = 0; a < nf; a++) {
    double d = 0.0;
    UNROLL
    for (int b = 0; b < nf; b++)
      d += A[a * nf + b] * x[b];
    y[a] = d;
  }
}

/* matvec, by the diagonal alone for a diagonal A. */
ALWAYS_INLINE void matvec_d(const double *restrict A, const double *restrict x,
                            double *restrict y, const int nf, const int diag) {
  if (diag) {
    UNROLL
    for (int a = 0; a < nf; a++)
      y[a] = A[a * nf + a] * x[a];
    return;
  }
  matvec(A, x, y, nf);
}

/* The end of a sweep whose largest micro-step residual is r. */
static int sweep_end(mrvi_sweep *sw, double r, double *residual, char *msg,
                     size_t len) {
  sw->gnode_ok = 0;
  if (r > *residual) /* fmax: a NaN r leaves it (and fails below) */
    *residual = r;
  if (!isfinite(r)) {
    mrvi_fmt(msg, len, "micro step produced non-finite values");
    return MRVI_ENONFINITE;
  }
  return MRVI_OK;
}

/* The fast nodes of the sweep path for a quadratic W with one (implicit)
 * point per interval, once the micro-step matrix is factored: the
 * arithmetic of solve_linear and of the general sweep below, in one pass
 * per node. */
ALWAYS_INLINE int linear_sweep(mrvi_sweep *sw, const mrvi_step *st, double *x,
                               double *pf, double *residual, char *msg,
                               size_t len, const int nf) {
  const int ns = sw->ns, p = sw->p;
  const double dt = st->dt, cB = sw->cB[0], wc = sw->w[0] * sw->cA[0];
  const double wb = sw->w[0] * sw->cB[0];
  const double *mf = sw->m_f, *Jinv = sw->Jinv, *H = sw->Hpt[0];
  double *g = sw->gpt[0], *fimp = sw->fimp, *F = sw->F, *del = sw->del;
  double *rhs = sw->rhs_buf, *dn = sw->dn, r = 0.0;
  const size_t stride = sw->node_stride;
  const double *pm = pf;
  for (int m = 0; m < p; m++) {
    const double *qm = m == 0 ? st->qf0 : x + ns + (size_t)(m - 1) * stride;
    double *qn = x + ns + (size_t)m * stride, *pn = pf + (size_t)m * stride;
    const double *fm = force_row(st, m);
    /* Predictor (the last implicit force held fixed) and F there. */
    UNROLL
    for (int f = 0; f < nf; f++) {
      rhs[f] = fm ? pm[f] + fm[f] : pm[f];
      dn[f] = dt * sw->minv_f[f] * (rhs[f] - fimp[f]);
      sw->zf[f] = 1.0 * qm[f] + cB * dn[f];
    }
    fast_gradient(sw, sw->zf, g, nf);
    UNROLL
    for (int f = 0; f < nf; f++) {
      fimp[f] = 0.0 + wc * g[f];
      F[f] = rhs[f] - mf[f] * dn[f] / dt - fimp[f];
    }
    /* dn += J^-1 F; the point's gradient follows by the kept Hessian. */
    matvec(Jinv, F, del, nf);
    UNROLL
    for (int a = 0; a < nf; a++)
      dn[a] += del[a];
    matvec(H, del, F, nf);
    UNROLL
    for (int a = 0; a < nf; a++) {
      g[a] += cB * F[a];
      fimp[a] = 0.0 + wc * g[a];
      const double mv = mf[a] * dn[a] / dt; /* M v_m, one division */
      const double ra = fabs(rhs[a] - mv - fimp[a]);
      r = isnan(ra) || ra > r ? ra : r;
      qn[a] = qm[a] + dn[a];
      pn[a] = mv;
      pn[a] -= wb * g[a];
    }
    pm = pn;
  }
  return sweep_end(sw, r, residual, msg, len);
}

/* linear_sweep for a W whose gradient is the affine map g0 + H z
 * (sw->wH): row m, rhs - M dn/dt - w cA (gq + cB H dn) = 0 with gq = grad W
 * at q^m, is solved directly, dn = J^-1 (rhs - w cA gq), where linear_sweep
 * corrects a predictor (the same solution, round-off apart): the chain from
 * one node to the next is shorter by the predictor's gradient. */
ALWAYS_INLINE int affine_sweep(mrvi_sweep *sw, const mrvi_step *st, double *x,
                               double *pf, double *residual, char *msg,
                               size_t len, const int nf) {
  const int ns = sw->ns, p = sw->p;
  const double dt = st->dt, cB = sw->cB[0], wc = sw->w[0] * sw->cA[0];
  const double wb = sw->w[0] * sw->cB[0];
  const double *mf = sw->m_f, *Jinv = sw->Jinv, *H = sw->wH;
  double *g = sw->gpt[0], *F = sw->F, *dn = sw->dn, *hd = sw->del, r = 0.0;
  const size_t stride = sw->node_stride;
  const double *pm = pf;
  for (int m = 0; m < p; m++) {
    const double *qm = m == 0 ? st->qf0 : x + ns + (size_t)(m - 1) * stride;
    double *qn = x + ns + (size_t)m * stride, *pn = pf + (size_t)m * stride;
    const double *fm = force_row(st, m);
    fast_gradient(sw, qm, g, nf); /* gq */
    UNROLL
    for (int f = 0; f < nf; f++) {
      F[f] = fm ? pm[f] + fm[f] : pm[f];
      F[f] -= wc * g[f];
    }
    matvec_d(Jinv, F, dn, nf, sw->wdiag);
    /* the point's gradient gq + cB H dn, the residual and the new node */
    matvec_d(H, dn, hd, nf, sw->wdiag);
    UNROLL
    for (int a = 0; a < nf; a++) {
      g[a] += cB * hd[a];
      const double mv = mf[a] * dn[a] / dt; /* M v_m */
      const double rhs = fm ? pm[a] + fm[a] : pm[a];
      const double ra = fabs(rhs - mv - wc * g[a]);
      r = isnan(ra) || ra > r ? ra : r;
      qn[a] = qm[a] + dn[a];
      pn[a] = mv - wb * g[a];
    }
    pm = pn;
  }
  return sweep_end(sw, r, residual, msg, len);
}

/* The fast nodes of the sweep path in general (row m solved by Newton, or
 * the explicit arithmetic of a general point set), with p^{f,0} in pf's
 * first row. */
/* The new node qn = qm + dn and its momentum pn = M dn/dt - wb g of an
 * interval whose one point is implicit (wb = w cB, g its gradient): the
 * arithmetic of general_sweep's loops in one pass, two entries at a time
 * (util/simd.h), and with fimp the row's implicit force wc g (wc = w cA;
 * implicit_force's arithmetic), which chord_residual leaves to this pass.
 * qn may be qm and pn the row's own momentum (the last node alone kept):
 * each entry is read before it is written. */
static void node_momentum(int nf, double dt, double wb, const double *qm,
                          const double *dn, const double *mf, size_t inc,
                          const double *g, double *qn, double *pn, double wc,
                          double *fimp) {
  const mrvi_v2 vdt = v2_set(dt, dt), vm = v2_set(mf[0], mf[0]);
  int f = 0;
  for (; f + 2 <= nf; f += 2) {
    const mrvi_v2 d = v2_load(dn + f);
    if (fimp)
      v2_store(fimp + f, v2_add(v2_zero(), v2_scale(wc, v2_load(g + f))));
    const mrvi_v2 mv = v2_div(v2_mul(inc ? v2_load(mf + f) : vm, d), vdt);
    const mrvi_v2 pv = v2_sub(mv, v2_scale(wb, v2_load(g + f)));
    v2_store(qn + f, v2_add(v2_load(qm + f), d));
    v2_store(pn + f, pv);
  }
  for (; f < nf; f++) {
    const double d = dn[f];
    if (fimp)
      fimp[f] = 0.0 + wc * g[f];
    qn[f] = qm[f] + d;
    pn[f] = mf[inc * (size_t)f] * d / dt - wb * g[f];
  }
}

/* The end of row m and the predictor of row m + 1 in one pass over the
 * entries [f0, f1) (sweep-cg with one implicit point per interval and no
 * control force, whose row m + 1 has p^{f,m+1} for its rhs): the node
 * qn, its momentum pn and the implicit force (node_momentum's
 * arithmetic), then row m + 1's predicted displacement over dn, its
 * configuration zf where cB is not 0 and its round-off scale, returned
 * (extrapolated_predictor's arithmetic of order q, from the values just
 * formed): one pass over the row instead of three, and no copy of the
 * momentum.  qn may be qm and pn the row's own momentum (each entry is
 * read before it is written).  The caller moves the history on. */
/* predicted_force on a pair of entries (the same operations lane by lane). */
ALWAYS_INLINE mrvi_v2 v2_predicted_force(int q, mrvi_v2 f1, mrvi_v2 f2,
                                         mrvi_v2 f3, mrvi_v2 f4, mrvi_v2 f5) {
  if (q == 2)
    return v2_sub(v2_scale(2.0, f1), f2);
  if (q == 3)
    return v2_add(v2_sub(v2_scale(3.0, f1), v2_scale(3.0, f2)), f3);
  if (q == 4)
    return v2_sub(
        v2_add(v2_sub(v2_scale(4.0, f1), v2_scale(6.0, f2)), v2_scale(4.0, f3)),
        f4);
  if (q == 5)
    return v2_add(v2_sub(v2_add(v2_sub(v2_scale(5.0, f1), v2_scale(10.0, f2)),
                                v2_scale(10.0, f3)),
                         v2_scale(5.0, f4)),
                  f5);
  return f1;
}

/* end_predict over the pairs of [f0, f1) from f0, the scale's pairs
 * carried in acc, and where fin its tail and the scale, returned (the
 * whole row in pieces: the same values as in one piece); the implicit
 * force into h[0], the history f2..f5 read from h[1..4]; with zg, g
 * zeroed once read (the next gradient's start). */
ALWAYS_INLINE double end_predict_k(mrvi_sweep *sw, int q, double cB,
                                   const double *qm, double *dn, double *g,
                                   double *qn, double *pn, double *const h[5],
                                   int f0, int f1, mrvi_v2 *acc, const int fin,
                                   const int zg) {
  const double dt = sw->st->dt, wb = sw->w[0] * sw->cB[0];
  const double wc = sw->w[0] * sw->cA[0];
  const size_t inc = (size_t)sw->mass_inc;
  const int unit = sw->rw_one;
  const double *restrict f2 = h[1], *restrict f3 = h[2], *restrict f4 = h[3],
                         *restrict f5 = h[4];
  const double *restrict minv = sw->minv_f, *restrict mf = sw->m_f,
                         *restrict rw = sw->rw;
  double *restrict fimp = h[0], *restrict zf = sw->zf;
  const double idt = 1.0 / dt, idt4 = 4.0 / dt;
  const mrvi_v2 vidt = v2_set(idt, idt), vidt4 = v2_set(idt4, idt4);
  const mrvi_v2 vm = v2_set(mf[0], mf[0]), vminv = v2_set(minv[0], minv[0]);
  mrvi_v2 vs = *acc;
  int f = f0;
  for (; f + 2 <= f1; f += 2) {
    const mrvi_v2 d = v2_load(dn + f), gf = v2_load(g + f);
    if (zg)
      v2_store(g + f, v2_zero());
    const mrvi_v2 m = inc ? v2_load(mf + f) : vm;
    const mrvi_v2 fi = v2_add(v2_zero(), v2_scale(wc, gf));
    const mrvi_v2 q1 = v2_add(v2_load(qm + f), d);
    const mrvi_v2 p1 = v2_sub(v2_mul(v2_mul(m, d), vidt), v2_scale(wb, gf));
    v2_store(fimp + f, fi);
    v2_store(qn + f, q1);
    v2_store(pn + f, p1);
    const mrvi_v2 fp = v2_predicted_force(
        q, fi, q >= 2 ? v2_load(f2 + f) : fi, q >= 3 ? v2_load(f3 + f) : fi,
        q >= 4 ? v2_load(f4 + f) : fi, q >= 5 ? v2_load(f5 + f) : fi);
    const mrvi_v2 mi = inc ? v2_load(minv + f) : vminv;
    const mrvi_v2 dp = v2_mul(v2_scale(dt, mi), v2_sub(p1, fp));
    v2_store(dn + f, dp);
    if (cB != 0.0)
      v2_store(zf + f, v2_add(v2_scale(1.0, q1), v2_scale(cB, dp)));
    const mrvi_v2 a = v2_add(v2_abs(p1), v2_mul(v2_mul(m, v2_abs(q1)), vidt4));
    vs = v2_max(unit ? a : v2_mul(a, v2_load(rw + f)), vs);
  }
  if (!fin) {
    *acc = vs;
    return 0.0;
  }
  double scale = v2_lo(vs) > v2_hi(vs) ? v2_lo(vs) : v2_hi(vs);
  for (; f < f1; f++) {
    const double d = dn[f], gf = g[f], m = mf[inc * (size_t)f];
    if (zg)
      g[f] = 0.0;
    const double fi = 0.0 + wc * gf;
    const double q1 = qm[f] + d, p1 = m * d * idt - wb * gf;
    fimp[f] = fi;
    qn[f] = q1;
    pn[f] = p1;
    const double fp = predicted_force(q, fi, f2[f], f3[f], f4[f], f5[f]);
    const double dp = dt * minv[inc * (size_t)f] * (p1 - fp);
    dn[f] = dp;
    if (cB != 0.0)
      zf[f] = 1.0 * q1 + cB * dp;
    const double a = fabs(p1) + m * fabs(q1) * idt4;
    const double v = rweight(rw, unit, a, f);
    scale = v > scale ? v : scale;
  }
  return scale;
}

static double end_predict(mrvi_sweep *sw, int q, double cB, const double *qm,
                          double *dn, const double *g, double *qn, double *pn,
                          int f0, int f1) {
  mrvi_v2 acc = v2_zero();
  double *const h[5] = {sw->fimp, sw->fhist[0], sw->fhist[1], sw->fhist[2],
                        sw->fhist[3]};
  return end_predict_k(sw, q, cB, qm, dn, (double *)g, qn, pn, h, f0, f1, &acc,
                       1, 0);
}

/* end_predict over the row, in the parts of chord_residual's pass on
 * threads (the largest scale is exact in any order), the history moved
 * on and the predictor kept for row m + 1 (solve_implicit). */
static void end_predict_row(mrvi_sweep *sw, int m, const double *qm, double *qn,
                            double *pn) {
  const int nf = sw->nf, n_c = sw->n_cpass, q = predictor_order(sw, m + 1);
  const double cB = sw->chord && sw->imp >= 0 ? sw->cB[sw->imp] : 0.0;
  double *dn = sw->dn, scale = 0.0;
  const double *g = sw->gpt[0];
  const int serial =
      sw->fuse && sw->lin_n <= 0 && !(n_c > 0 && sw->pthreads > 1);
  if (cB != 0.0 && (serial || (n_c > 0 && sw->pthreads > 1 && sw->cfused))) {
    /* (in the next row's first chord update: chord_residual) */
    sw->defer.on = 1;
    sw->defer.serial = serial;
    sw->defer.q = q;
    sw->defer.cB = cB;
    sw->defer.qm = qm;
    sw->defer.qn = qn;
    sw->defer.pn = pn;
    sw->predicted = 1;
    return;
  }
  if (n_c > 0 && sw->pthreads > 1) {
    double *cp = sw->cpass;
    MRVI_PARALLEL_FOR(sw->pthreads)
    for (int c = 0; c < n_c; c++)
      cp[4 * c] =
          end_predict(sw, q, cB, qm, dn, g, qn, pn, mrvi_part_start(c, nf, n_c),
                      mrvi_part_start(c + 1, nf, n_c));
    for (int c = 0; c < n_c; c++)
      scale = cp[4 * c] > scale ? cp[4 * c] : scale;
  } else {
    scale = end_predict(sw, q, cB, qm, dn, g, qn, pn, 0, nf);
  }
  rotate_history(sw);
  sw->pred_scale = scale;
  sw->predicted = 1;
}

/* The deferred row end (end_predict_row) of part c, its scale into the
 * slots after start_parts' (free then). */
static void defer_part(mrvi_sweep *sw, int c, double *dn) {
  const int nf = sw->nf, n_c = sw->n_cpass;
  sw->cpass[5 * n_c + c] =
      end_predict(sw, sw->defer.q, sw->defer.cB, sw->defer.qm, dn, sw->gpt[0],
                  sw->defer.qn, sw->defer.pn, mrvi_part_start(c, nf, n_c),
                  mrvi_part_start(c + 1, nf, n_c));
}

/* After the deferred row end's parts: the largest scale (exact in any
 * order), the history moved on. */
static void defer_end(mrvi_sweep *sw) {
  double scale = 0.0;
  for (int c = 0; c < sw->n_cpass; c++)
    scale = sw->cpass[5 * sw->n_cpass + c] > scale
                ? sw->cpass[5 * sw->n_cpass + c]
                : scale;
  rotate_history(sw);
  sw->pred_scale = scale;
  sw->defer.on = 0;
}

/* The deferred row end in a parallel region of its own (where the next
 * row's first update cannot take it), or in one pass (serial). */
static void defer_flush(mrvi_sweep *sw) {
  if (sw->defer.serial) {
    sw->pred_scale =
        end_predict(sw, sw->defer.q, sw->defer.cB, sw->defer.qm, sw->dn,
                    sw->gpt[0], sw->defer.qn, sw->defer.pn, 0, sw->nf);
    rotate_history(sw);
    sw->defer.on = 0;
    return;
  }
  MRVI_PARALLEL_FOR(sw->pthreads)
  for (int c = 0; c < sw->n_cpass; c++)
    defer_part(sw, c, sw->dn);
  defer_end(sw);
}

/* The deferred row end in the next row's fused spring loop
 * (mrvi_terms_grad_fused's first): the entries [epos, to) formed before
 * any spring reads their configuration or sums into their gradient (which
 * end_predict reads), in pairs from entry 0, one entry early where to is
 * odd (end_predict's pairs, the scale's pairs carried in eacc) and at the
 * last columns the tail, the scale left in eacc's low lane (end_predict's
 * values bitwise), g zeroed there for the loop's sums.  The history was
 * moved on before the loop (the pass may
 * store the new row's force in fimp, in entries formed here first): the
 * implicit force into fhist[0], the older rows' read from fhist[1..3] and
 * fimp. */
static void defer_stream_to(void *ctx, int to) {
  chord_stream *s = ctx;
  mrvi_sweep *sw = s->sw;
  const int nf = sw->nf, fin = to >= nf;
  const int e = fin ? nf : s->epos + ((to - s->epos + 1) & ~1); /* (>= to) */
  if (e <= s->epos && !fin)
    return;
  double *const h[5] = {sw->fhist[0], sw->fhist[1], sw->fhist[2], sw->fhist[3],
                        sw->fimp};
  const double r = end_predict_k(sw, sw->defer.q, sw->defer.cB, sw->defer.qm,
                                 (double *)s->dn, sw->gpt[0], sw->defer.qn,
                                 sw->defer.pn, h, s->epos, e, &s->eacc, fin, 1);
  if (fin)
    s->eacc = v2_set(r, r);
  s->epos = e;
}

static int general_sweep(mrvi_sweep *sw, const mrvi_step *st, double *x,
                         double *pf, int *iterations, double *residual,
                         char *msg, size_t len) {
  const int ns = sw->ns, nf = sw->nf, p = sw->p;
  const double dt = st->dt;
  double *pm = pf;
  const size_t stride = sw->node_stride;
  /* sweep-cg with one implicit point per interval and no control force:
   * rhs is the row's momentum, and each row's end forms the next row's
   * predictor (end_predict). */
  const int own = sw->sparse && sw->implicit && sw->n_w == 1 && !st->f_rows;
  sw->predicted = 0;
  for (int m = 0; m < p; m++) {
    const double *qm = m == 0 ? st->qf0 : x + ns + (size_t)(m - 1) * stride;
    double *qn = x + ns + (size_t)m * stride;
    /* rhs = p^{f,m} (+ control force) - forces of the points at node m
     * (cB = 0). */
    sw->rhs = own ? pm : sw->rhs_buf;
    if (!own)
      memcpy(sw->rhs, pm, (size_t)nf * sizeof(double));
    const double *fm = force_row(st, m);
    for (int f = 0; fm && f < nf; f++)
      sw->rhs[f] += fm[f];
    for (int i = 0; i < sw->n_w; i++) {
      if (sw->cB[i] != 0.0)
        continue;
      if (!sw->gnode_ok) {
        memcpy(sw->zf, qm, (size_t)nf * sizeof(double));
        memset(sw->gnode, 0, (size_t)nf * sizeof(double));
        eval_fast(sw, sw->gnode, NULL, 0.0);
        sw->gnode_ok = 1;
      }
      for (int f = 0; f < nf; f++)
        sw->rhs[f] -= sw->w[i] * sw->gnode[f];
    }
    if (sw->implicit) {
      int it = 0;
      const int s =
          sw->linear
              ? solve_linear(sw, qm, sw->dn, &it, residual, msg, len)
              : solve_implicit(sw, qm, sw->dn, m, &it, residual, msg, len);
      if (it > *iterations)
        *iterations = it;
      if (s < 0) {
        sw->gnode_ok = 0;
        mrvi_fmt(msg + strlen(msg), len - strlen(msg), " (micro step %d of %d)",
                 m + 1, p);
        return s;
      }
    } else {
      for (int f = 0; f < nf; f++)
        sw->dn[f] = dt * sw->minv_f[f] * sw->rhs[f];
    }
    /* p^{f,m+1} (eq:pkfm+): M v_m - sum w cB grad W of interval m. */
    double *pn = pf + (size_t)m * stride;
    sw->gnode_ok = 0;
    if (own && m + 1 < p) {
      end_predict_row(sw, m, qm, qn, pn);
      pm = pn;
      continue;
    }
    if (own && sw->pend) { /* (the last node: end_parts) */
      pm = pn;
      continue;
    }
    if (sw->implicit && sw->n_w == 1) { /* (midpoint: one pass) */
      node_momentum(nf, dt, sw->w[0] * sw->cB[0], qm, sw->dn, sw->m_f,
                    (size_t)sw->mass_inc, sw->gpt[0], qn, pn,
                    sw->w[0] * sw->cA[0], sw->linear ? NULL : sw->fimp);
      pm = pn;
      continue;
    }
    for (int f = 0; f < nf; f++)
      qn[f] = qm[f] + sw->dn[f];
    for (int f = 0; f < nf; f++)
      pn[f] = sw->m_f[f * sw->mass_inc] * sw->dn[f] / dt;
    for (int i = 0; i < sw->n_w; i++) {
      if (sw->cB[i] == 0.0)
        continue;
      const double *g = sw->gpt[i];
      if (sw->cA[i] == 0.0) { /* at node m + 1: also serves interval m+1 */
        if (!sw->gnode_ok) {
          memcpy(sw->zf, qn, (size_t)nf * sizeof(double));
          memset(sw->gnode, 0, (size_t)nf * sizeof(double));
          eval_fast(sw, sw->gnode, NULL, 0.0);
          sw->gnode_ok = 1;
        }
        g = sw->gnode;
      }
      for (int f = 0; f < nf; f++)
        pn[f] -= sw->w[i] * sw->cB[i] * g[f];
    }
    pm = pn;
  }
  /* The rows' history for the next step (tuning.chord_carry): the
   * converged forces of the last PREDICTOR_ORDER rows in fimp and fhist
   * (node_momentum stored the last row's), where every row extrapolated
   * (the chord regime on springs and anchors). */
  if (sw->carry_on && own && sw->fresh && sw->mild && p >= PREDICTOR_ORDER)
    sw->carry_next = PREDICTOR_ORDER;
  return MRVI_OK;
}

/* V at node k + 1 into the end momenta (ps1 and p^{f,p}: pe) alone, with
 * the new node x (slow) and xe (fast). */
ALWAYS_INLINE void end_potential(mrvi_sweep *sw, const double *x,
                                 const double *xe, double *ps1, double *pe,
                                 const int ns, const int nf) {
  if (sw->wv1 == 0.0)
    return;
  const double w1 = sw->wv1;
  slow_gradient(sw, x, xe, ns, nf);
  const double *gv = sw->gv;
  UNROLL
  for (int s = 0; s < ns; s++)
    ps1[s] -= w1 * gv[s];
  UNROLL
  for (int f = 0; f < nf; f++)
    pe[f] -= w1 * gv[ns + f];
}

/* The end of a step (end_status): x 0 + p 0 summed over the new node, 0
 * where every entry is finite, else NaN, in any order (explicit_step_par
 * sums it in parts: the same status for every thread count). */
ALWAYS_INLINE int end_check(mrvi_sweep *sw, const double *x, const double *xe,
                            const double *ps1, const double *pe, char *msg,
                            size_t len, const int ns, const int nf) {
  double sum = 0.0;
  UNROLL
  for (int s = 0; s < ns; s++)
    sum += x[s] * 0.0 + ps1[s] * 0.0;
  UNROLL
  for (int f = 0; f < nf; f++)
    sum += xe[f] * 0.0 + pe[f] * 0.0;
  return end_status(sw, sum, msg, len);
}

/* The explicit step at p = 1 without control forces (an uncontrolled run
 * of a trapezoidal fast rule: one W point at each node): the arithmetic of
 * sweep_step below, in the same order, kept in locals (no reloads through
 * possibly aliasing stores) and without the tests for forces and further
 * nodes. */
ALWAYS_INLINE int explicit_p1(mrvi_sweep *sw, const mrvi_step *st,
                              double *restrict x, double *restrict ps1,
                              double *restrict pf, char *msg, size_t len,
                              const int ns, const int nf) {
  const double dT = st->dT, dt = st->dt, w0 = sw->wv0;
  const double wl = sw->wl[0], wr = sw->wr[0];
  const double *restrict qs0 = st->qs0, *restrict qf0 = st->qf0;
  const double *restrict ps0 = st->ps0, *restrict pf0 = st->pf0;
  const double *restrict minv_s = sw->minv_s, *restrict minv = sw->minv_f;
  const double *restrict mf = sw->m_f;
  const int inc_s = sw->inc_s, inc = sw->mass_inc;
  if (w0 != 0.0 && !sw->gv_ok)
    slow_gradient(sw, qs0, qf0, ns, nf);
  sw->gv_ok = 0;
  if (!sw->gnode_ok)
    fast_gradient(sw, qf0, sw->gnode, nf);
  const double *gv = w0 != 0.0 ? sw->gv : sw->gzero;
  const double *gnode = sw->gnode;
  UNROLL
  for (int s = 0; s < ns; s++) {
    const double v = ps0[s] - w0 * gv[s]; /* M^s (q_{k+1}^s - q_k^s)/dT */
    ps1[s] = v;
    x[s] = qs0[s] + dT * minv_s[s * inc_s] * v;
  }
  UNROLL
  for (int f = 0; f < nf; f++) {
    double r = pf0[f] - w0 * gv[ns + f]; /* p^{f,0} */
    r -= wl * gnode[f];
    const double dn = dt * minv[f * inc] * r;
    x[ns + f] = qf0[f] + dn;
    pf[f] = mf[f * inc] * dn / dt;
  }
  fast_gradient(sw, x + ns, sw->gnode, nf);
  gnode = sw->gnode;
  UNROLL
  for (int f = 0; f < nf; f++)
    pf[f] -= wr * gnode[f];
  sw->gnode_ok = 1;
  end_potential(sw, x, x + ns, ps1, pf, ns, nf);
  return end_check(sw, x, x + ns, ps1, pf, msg, len, ns, nf);
}

/* sweep-cg's step start on threads (sw->cfused; row 0 from the free
 * flight with the chord from its start, one implicit point, no control
 * force: sweep_par): sweep_step's slow row and p^{f,0}, solve_implicit's
 * row 0 estimate (the free flight dn0 = dt M^-1 p^{f,0}, the implicit
 * force at it, its residual r0 and copy dff, the second free flight dn =
 * dt M^-1 (p^{f,0} - fimp) and the round-off scale) and the first chord
 * iterate (fresh_part) in one parallel region, two barriers where each
 * configuration is complete: the slow rows in n_cs parts, the fast rows
 * in the chord's parts, the gradients in W's (the same rows), each
 * entry's serial arithmetic (mrvi_terms_grad_part: mrvi_terms_eval's
 * gradient bitwise, test_kernels).  The maxima combined in order by the
 * serial loops' rules (r0's NaN absorbing), so the same bits for every
 * thread count; r0, the scale, the iterate's residual and bound into
 * sw->pre for solve_implicit.  With carry (the step carries the last
 * one's rows, tuning.chord_carry), row 0's extrapolated predictor
 * (predictor_rows, in the parts of p^{f,0}) instead of the estimate, one
 * barrier before the first iterate, r0 none (HUGE_VAL): before, three
 * serial passes (doc/performance/16-es-thr.md). */
static void start_parts(mrvi_sweep *sw, const mrvi_step *st, const double *gv,
                        double *x, double *ps1, double *pf, int carry) {
  const int nf = sw->nf, ns = sw->ns, n_c = sw->n_cpass, n_cs = sw->n_cs;
  const int i = sw->imp;
  const double dt = st->dt, w0 = sw->wv0, wc = sw->w[i] * sw->cA[i];
  const double cB = sw->cB[i], *qm = st->qf0, *pf0 = st->pf0;
  const double *minv = sw->minv_f, *mf = sw->m_f, *rw = sw->rw;
  const int unit = sw->rw_one;
  const size_t inc = (size_t)sw->mass_inc;
  double *dn = sw->dn, *g = sw->gpt[i], *fimp = sw->fimp,
         *dff = free_flight(sw);
  double *zf = sw->zf, *z1 = sw->zalt, *cp = sw->cpass + 5 * n_c;
  sw->rhs = pf; /* (general_sweep's row 0: its momentum) */
  sw->lam = 0.0;
  if (carry) /* (solve_implicit's row 0 on the chord) */
    sw->mild = sw->chord = 1;
  const int q = carry ? predictor_order(sw, 0) : 0;
  sw->evals_w += carry ? 1 : 2; /* (the estimate's gradient, the iterate's) */
#ifdef _OPENMP
#pragma omp parallel num_threads(sw->pthreads)
#endif
  {
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
    for (int c = 0; c < n_cs; c++)
      slow_start_part(sw, st, c, gv, x, ps1, NULL, x);
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
    for (int c = 0; c < n_c; c++) {
      const int f0 = mrvi_part_start(c, nf, n_c);
      const int f1 = mrvi_part_start(c + 1, nf, n_c);
      for (int f = f0; f < f1; f++) {
        pf[f] = pf0[f] - w0 * gv[ns + f]; /* p^{f,0} */
        if (carry)
          continue;
        dn[f] = dt * minv[f * inc] * (pf[f] - 0.0); /* (fimp 0) */
        zf[f] = 1.0 * qm[f] + cB * dn[f];
      }
      if (carry) /* (row 0's predictor and its configuration in zf) */
        cp[2 * c + 1] = predictor_rows(sw, q, qm, dn, cB, f0, f1);
    }
    if (!carry) { /* (row 0's estimate) */
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
      for (int c = 0; c < n_c; c++) {
        const int f0 = mrvi_part_start(c, nf, n_c);
        const int f1 = mrvi_part_start(c + 1, nf, n_c);
        double r0 = 0.0, scale = 0.0;
        zero(g + f0, f1 - f0);
        mrvi_terms_grad_part(sw->kc[MRVI_FAST], c, zf, g);
        for (int f = f0; f < f1; f++) {
          fimp[f] = 0.0 + wc * g[f];
          dff[f] = dn[f];
          const double a = rweight(
              rw, unit, fabs(pf[f] - mf[f * inc] * dn[f] / dt - fimp[f]), f);
          r0 = isnan(a) || a > r0 ? a : r0;
          dn[f] = dt * minv[f * inc] * (pf[f] - fimp[f]);
          const double v = rweight(
              rw, unit, fabs(pf[f]) + 4.0 * mf[f * inc] * fabs(qm[f]) / dt, f);
          scale = v > scale ? v : scale;
          z1[f] = 1.0 * qm[f] + cB * dn[f]; /* (zf still read) */
        }
        cp[2 * c] = r0;
        cp[2 * c + 1] = scale;
      }
    }
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
    for (int c = 0; c < n_c; c++)
      fresh_part(sw, c, qm, dn, carry ? zf : z1, carry ? z1 : zf);
  }
  double r0 = carry ? HUGE_VAL : 0.0, scale = 0.0;
  for (int c = 0; c < n_c; c++) {
    r0 = carry || !(isnan(cp[2 * c]) || cp[2 * c] > r0) ? r0 : cp[2 * c];
    scale = cp[2 * c + 1] > scale ? cp[2 * c + 1] : scale;
  }
  if (carry)
    rotate_history(sw);
  sw->pre[0] = r0;
  sw->pre[1] = scale;
  sw->pre[2] = carry ? fresh_end(sw, zf, z1, &sw->pre[3])
                     : fresh_end(sw, z1, zf, &sw->pre[3]);
  sw->pstart = 1;
}

/* sweep-cg's step end on threads (sw->pend): the last node and its
 * momentum (general_sweep's node_momentum), grad V at the end node and
 * the end momenta with end_check's sums (sweep_step's end_potential and
 * end_check) in one parallel region: the node in the chord's parts, with
 * the slow rows' and its rows of grad V cleared and of V's configuration
 * copied where V reads a copy; V's gradient in its parts; the momenta and
 * sums in the slow and fast parts (end_part), added in order. */
static int end_parts(mrvi_sweep *sw, const mrvi_step *st, double *x,
                     double *ps1, double *pf, char *msg, size_t len) {
  const int ns = sw->ns, nf = sw->nf, p = sw->p, n_c = sw->n_cpass;
  const int n_cs = sw->n_cs;
  const size_t stride = sw->node_stride;
  const double dt = st->dt, w1 = sw->wv1, wb = sw->w[0] * sw->cB[0];
  const double wc = sw->w[0] * sw->cA[0], *g = sw->gpt[0];
  const double *qm = p == 1 ? st->qf0 : x + ns + (size_t)(p - 2) * stride;
  double *xe = x + ns + (size_t)(p - 1) * stride;
  double *pe = pf + (size_t)(p - 1) * stride, *gv = sw->gv, *csum = sw->csum;
  double *zv = xe == x + ns ? x : sw->zv; /* (slow_gradient's) */
  sw->evals_v += w1 != 0.0;
#ifdef _OPENMP
#pragma omp parallel num_threads(sw->pthreads)
#endif
  {
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
    for (int c = 0; c < n_cs; c++) {
      const int s1 = w1 != 0.0 ? mrvi_part_start(c + 1, ns, n_cs) : 0;
      for (int s = mrvi_part_start(c, ns, n_cs); s < s1; s++) {
        gv[s] = 0.0;
        if (zv != x)
          zv[s] = x[s];
      }
    }
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
    for (int c = 0; c < n_c; c++) {
      const int f0 = mrvi_part_start(c, nf, n_c);
      const int f1 = mrvi_part_start(c + 1, nf, n_c);
      node_momentum(f1 - f0, dt, wb, qm + f0, sw->dn + f0,
                    sw->m_f + (size_t)f0 * (size_t)sw->mass_inc,
                    (size_t)sw->mass_inc, g + f0, xe + f0, pe + f0, wc,
                    sw->fimp + f0);
      for (int f = f0; w1 != 0.0 && f < f1; f++) {
        gv[ns + f] = 0.0;
        if (zv != x)
          zv[ns + f] = xe[f];
      }
    }
    end_v_parts(sw, zv, gv, NULL, x, ps1, xe, pe, n_c, csum);
  }
  double sum = 0.0;
  for (int c = 0; c < n_cs + n_c; c++)
    sum += csum[c];
  return end_status(sw, sum, msg, len);
}

/* mrvi_sweep_step for ns slow and nf fast coordinates (constants for small
 * blocks, so that the loops over them unroll). */
ALWAYS_INLINE int sweep_step(mrvi_sweep *sw, const mrvi_step *st, double *x,
                             double *ps1, double *pf, int *iterations,
                             double *residual, char *msg, size_t len,
                             const int ns, const int nf) {
  const int p = sw->p;
  const double dT = st->dT;
  *iterations = 0;
  *residual = 0.0;
  /* The first micro step's predictor holds no implicit force: nothing is
   * carried from the last step, so a step depends on (q_k, p_k) alone;
   * with tuning.chord_carry, the last step's rows where it kept them. */
  sw->carry = sw->carry_next;
  sw->carry_next = 0;
  /* sweep-cg on threads: its start and end each in one parallel region
   * (start_parts, end_parts) */
  const int own = sw->cfused && sw->n_w == 1 && !st->f_rows;
  sw->pend = own && !st->f_end;
  sw->pstart = 0;
  const int chord0 = own && sw->fresh && sw->imp >= 0 && sw->chord_max > 0.0 &&
                     sw->cB[sw->imp] != 0.0;
  const int pstart = chord0 && !sw->carry;
  const int cstart = chord0 && sw->carry; /* (start_parts' carry) */
  if (sw->implicit && !sw->carry && !pstart)
    zero(sw->fimp, nf);
  else if (sw->threads > 1)
    return explicit_step_par(sw, st, x, ps1, pf, msg, len);
  /* Slow row: q_{k+1}^s explicit; V at node k also enters fast row 0. */
  const double w0 = sw->wv0;
  /* grad V at node k: kept from the last step's end node (it is bitwise
   * q_k, so a step still depends on (q_k, p_k) alone), else evaluated. */
  if (w0 != 0.0 && !sw->gv_ok)
    slow_gradient(sw, st->qs0, st->qf0, ns, nf);
  sw->gv_ok = 0;
  const double *gv = w0 != 0.0 ? sw->gv : sw->gzero;
  const double *ps0 = st->ps0, *qs0 = st->qs0, *pf0 = st->pf0;
  const double *frow = st->f_rows, *minv_s = sw->minv_s;
  const int inc_s = sw->inc_s;
  if (pstart)
    start_parts(sw, st, gv, x, ps1, pf, 0);
  else if (cstart)
    start_parts(sw, st, gv, x, ps1, pf, 1);
  const int started = pstart || cstart;
  UNROLL
  for (int s = 0; !started && s < ns; s++) {
    double v = ps0[s] - w0 * gv[s]; /* M^s (q_{k+1}^s - q_k^s)/dT */
    if (frow)
      v += frow[s];
    ps1[s] = v;
    x[s] = qs0[s] + dT * minv_s[s * inc_s] * v;
  }
  /* p^{f,0} of row 0 (kept in pf's first row until node 1 overwrites it). */
  double *pm = pf; /* momentum at node m (row m's left part) */
  UNROLL
  for (int f = 0; !started && f < nf; f++)
    pm[f] = pf0[f] - w0 * gv[ns + f];
  int done = 0;
  if (!sw->implicit) {
    explicit_sweep(sw, st, x, pf, nf);
    done = 1;
  } else if (sw->linear && sw->n_w == 1 && (sw->lu_ok || sw->wH)) {
    /* The affine sweep from the first step on (factored here), so that
     * every step takes the same arithmetic: a restarted run continues bit
     * for bit. */
    const int fs =
        sw->lu_ok ? MRVI_OK : factor_linear(sw, st->qf0, sw->gzero, msg, len);
    if (fs < 0)
      return fs;
    const int s = sw->wH ? affine_sweep(sw, st, x, pf, residual, msg, len, nf)
                         : linear_sweep(sw, st, x, pf, residual, msg, len, nf);
    if (s < 0)
      return s;
    *iterations = 1;
    done = 1;
  }
  if (!done) {
    const int s = general_sweep(sw, st, x, pf, iterations, residual, msg, len);
    if (s < 0 || sw->pend)
      return s < 0 ? s : end_parts(sw, st, x, ps1, pf, msg, len);
  }
  /* V at node k+1 enters the momenta only: ps1 and p^{f,p}. */
  double *pe = pf + (size_t)(p - 1) * sw->node_stride;
  const double *xe = x + ns + (size_t)(p - 1) * sw->node_stride;
  end_potential(sw, x, xe, ps1, pe, ns, nf);
  /* Control forces f^+ of the step on the end momenta. */
  if (st->f_end) {
    const double *fe = st->f_end;
    UNROLL
    for (int s = 0; s < ns; s++)
      ps1[s] += fe[s];
    UNROLL
    for (int f = 0; f < nf; f++)
      pe[f] += fe[ns + f];
  }
  return end_check(sw, x, xe, ps1, pe, msg, len, ns, nf);
}

int mrvi_sweep_tight(const mrvi_sweep *sw) { return sw->tight; }

int mrvi_sweep_explicit_p1(mrvi_sweep *sw, const mrvi_step *st, double *x,
                           double *ps1, double *pf, char *msg, size_t len) {
  int s = MRVI_OK;
  SMALL2(sw->ns, NS, sw->nf, NF,
         s = explicit_p1(sw, st, x, ps1, pf, msg, len, NS, NF));
  return s;
}

int mrvi_sweep_step(mrvi_sweep *sw, const mrvi_step *st, double *x, double *ps1,
                    double *pf, int *iterations, double *residual, char *msg,
                    size_t len) {
  int s = MRVI_OK;
  SMALL2(sw->ns, NS, sw->nf, NF,
         s = sweep_step(sw, st, x, ps1, pf, iterations, residual, msg, len, NS,
                        NF));
  return s;
}
