/* The one-step map (q_k, p_k) -> (q_{k+1}, p_{k+1}) solved by Newton. */
#include "integrator/integrator.h"
#include "util/simd.h"
#include "util/small.h"

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

struct mrvi_integrator {
  const mrvi_model *model;
  mrvi_settings settings;
  mrvi_step step;
  mrvi_newton *newton;
  mrvi_nullspace *nullspace;  /* null-space form only */
  int path;                   /* MRVI_PATH_* (doc/solver.md) */
  const struct path_ops *ops; /* its row of `paths` (end of the file) */
  mrvi_sweep *sweep;          /* explicit, sweep and sweep-cg paths */
  int sweep_tight;            /* mrvi_sweep_tight(sweep) */
  mrvi_blocks *blocks;        /* schur path */
  mrvi_skrylov *skrylov;      /* schur-krylov path */
  mrvi_outer *outer;          /* ... its matrix-free step (NULL: off) */
  mrvi_bordered *bordered;    /* schur-bordered path */
  mrvi_joint_sweep *jsweep;   /* its predictor's joint sweep (or NULL) */
  mrvi_predictor *predictor;  /* Newton paths */
  int factors_ok;             /* factors of this step's Jacobian are kept */
  char why[512];              /* reason for the path */
  double *qs_prev, *qf_prev;  /* q_k^s, q_k^{f,0} of the last step (packed) */
  mrvi_newton *jac_nw;        /* full-step factors for jacobian_solve */
  int jac_ready;              /* jac_nw holds the last step's Jacobian */
  double *rhs;                /* reduced right-hand side (null-space form) */
  double t0;                  /* time of node k = 0 */
  long k;
  double *q, *p;             /* model order, n */
  double *qs, *qf, *ps, *pf; /* rate blocks of the state */
  int packed; /* model order is slow then fast: the blocks alias q and p */
  /* Not packed, unconstrained and without torsional springs: the steps
   * keep the state in the rate blocks alone, and q and p are gathered from
   * them when asked (mrvi_integrator_q, _p): a step scatters nothing. */
  int blocks_only;
  double *x, *R, *dx; /* unknowns, residual, Newton update */
  double *rinv;       /* newton.criterion scaled: 1 / mass of each dynamic row
                         (n_unknowns), else NULL */
  double *ps1;        /* ns */
  double *micro_q, *micro_p; /* p x nf (1 x nf: node_stride 0) */
  /* Spacing of the fast nodes in x and micro_p: nf, or 0 where only the
   * last is kept (mrvi_integrator_keep_micro) */
  size_t node_stride;
  /* 1: every micro node is kept for output (the default); 0: the last
   * alone (mrvi_integrator_keep_micro): on the Newton paths, whose x holds
   * every node at stride nf, the interior nodes are then not copied and
   * their momenta not projected (project_micro) */
  int micro_all;
  double *lambda; /* constraint rows: multipliers at node k of the last step */
  double *micro_cres; /* p: max |g| at micro nodes 1..p of the last step */
  double *cg, *cGd, *cA, *cmu; /* constraint workspace: g, dense G, Gram, mu */
  double *settle_q; /* 2 n: settle_predictor's positions (NULL: off) */
  mrvi_gram *gram;  /* sparse Gram (more than MRVI_GRAM_DENSE_MAX rows) */
  double *mu_h;     /* projection impulse / h at the current node */
  int n_torsion;    /* torsional springs of the model */
  double *torsion;  /* their branches: unwrapped angles at node k (torsion.c) */
  /* Null-space form: constraint rows redundant at q0 (1), left out of the
   * step and the projection; their count; scratch for later checks. */
  unsigned char *c_drop, *c_drop_at;
  int n_drop;
  double *pGf, *pA, *pmu; /* micro-node projection: G_f (r x nf), Gram, mu */
  int *pnz;               /* the nonzero columns of a row of G_f (nf) */
  int last_iterations;
  int chord_mode;      /* schur path: MRVI_CHORD_AUTO, _OFF or _ON */
  int cchord_mode;     /* the constant chord: MRVI_CHORD_AUTO, _OFF or _ON */
  double cchord_e;     /* its a-priori measure, a run constant */
  int cchord_made;     /* its factors are made (counted once) */
  int const_kept;      /* the kept factors are the constant chord's */
  int shoot_mode;      /* shooting (mrvi_predict_shoot): MRVI_CHORD_AUTO,
                          _OFF or _ON */
  int shoot_ok;        /* the schur path's steps may shoot (a run constant) */
  long n_shoot;        /* steps solved by shooting in the run */
  long n_shoot_last;   /* ... of which with an unswept last update */
  long n_factor;       /* factorisations of the schur paths in the run */
  long roundoff_steps; /* steps accepted at the roundoff floor above tol */
  double last_residual;
  /* Timing (mrvi_integrator_timing): the sums over the timed steps and
   * the estimated blocks that ended; the block of steps under way. */
  double t_assemble, t_solve;
  long n_steps;           /* steps taken */
  int timed;              /* this step is timed */
  int block_exact;        /* every step of the block is timed */
  int timing_estimated;   /* an ended block was estimated */
  long block_n;           /* steps of the block so far */
  double block_t0;        /* clock at its start */
  double block_mark[2];   /* t_assemble, t_solve at its start */
  double block_sample[2]; /* its first step's times (estimated block) */
  char errmsg[512];
};

static int fail(mrvi_integrator *it, int status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

/* A step solver path (doc/solver.md) as the integrator drives it: its
 * set-up after the common part of mrvi_integrator_create, its macro step
 * and what it frees; the Newton paths also evaluate the residual (and
 * Jacobian) their way and make one Newton update from it. */
typedef struct path_ops {
  int (*create)(mrvi_integrator *it, char *msg, size_t len);
  int (*step)(mrvi_integrator *it);
  /* The residual at x (and, if jac, the Jacobian) into it->R. */
  int (*assemble)(mrvi_integrator *it, int jac, char *msg, size_t len);
  /* One Newton update (x -= dx) from it->R at x, factorised afresh when
   * `fresh`, else with the factors kept from an earlier iterate. */
  int (*update)(mrvi_integrator *it, int fresh, char *msg, size_t len);
  void (*free)(mrvi_integrator *it);
  int keeps_factors; /* updates may reuse the factors (simplified Newton) */
} path_ops;

/* The row of MRVI_PATH_* (the table, `paths`, ends the file). */
static const path_ops *path_ops_of(int path);

/* The tuning constants this file reads (mrvi.h, MRVI_TUNING_LIST; tn
 * below); what their defaults were measured on is in doc/performance/paths.md,
 * "Tuning constants: what the defaults were measured on":
 *  - reuse_rate, reuse_tighten: the largest residual ratio of an update with
 *    kept factors (schur path) for which they are kept for the next update,
 *    and the factor below the tolerance at which such updates stop.
 *  - chord_max: the largest a-priori error measure dT^2 |H_last - H_first|
 *    / m_min of the chord matrix (frozen Hessians, schur path) for which the
 *    first update of a step uses it (doc/solver.md, "Newton details"): a
 *    second update with the kept factors costs about what the chord saves.
 *  - const_chord_max: the largest a-priori measure e = dT^2 |hess Z(q0)|_inf
 *    / m_min of the constant chord (the Newton matrix without the Hessians
 *    that are not constant, factored once per run; doc/solver.md, "Newton
 *    details") for which the first update of a step uses it: above it the
 *    extra updates cost more than the factorisations saved.
 *  - shoot_max: the most slow updates of a shooting step
 *    (mrvi_predict_shoot) before Newton takes over from its iterate. */

/* The assembly and solve times (mrvi_integrator_timing) are measured on
 * each of the first MRVI_TIME_ALL steps, which carry the run's one-time
 * work (first factorisations, a constant chord).  The later steps come in
 * blocks of MRVI_TIME_EVERY: the first step of a block is timed; when it
 * took MRVI_TIME_STEP_MIN seconds or more, so are the others (a Newton
 * step's clock reads are then below 1 % of it), else it stands for every
 * step of its block, at most the block's elapsed time (read at the block's
 * ends): a clock read costs as much as a micro step of the explicit paths,
 * and a sampled step slowed by the machine's load must not count 64 times.
 * (doc/performance/paths.md, "Tuning constants"). */
#define MRVI_TIME_ALL 64
#define MRVI_TIME_EVERY 64
#define MRVI_TIME_STEP_MIN 50e-6

/* The clock on timed steps, else 0. */
static double tick(const mrvi_integrator *it) {
  return it->timed ? mrvi_clock() : 0.0;
}

static int fail(mrvi_integrator *it, int status, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(it->errmsg, sizeof it->errmsg, fmt, ap);
  va_end(ap);
  return status;
}

const char *mrvi_integrator_errmsg(const mrvi_integrator *it) {
  return it ? it->errmsg : "no integrator";
}

void mrvi_integrator_free(mrvi_integrator *it) {
  if (!it)
    return;
  if (it->ops)
    it->ops->free(it);
  mrvi_newton_free(it->jac_nw);
  free(it->qs_prev); /* qf_prev inside */
  free(it->rhs);
  mrvi_step_free(&it->step);
  free(it->q);
  free(it->p);
  free(it->torsion);
  if (!it->packed) {
    free(it->qs); /* qf inside */
    free(it->ps);
    free(it->pf);
  }
  free(it->x);
  free(it->R);
  free(it->rinv);
  free(it->dx);
  free(it->ps1);
  free(it->micro_q);
  free(it->micro_p);
  free(it->lambda);
  free(it->micro_cres);
  free(it->cg);
  free(it->cGd);
  free(it->cA);
  mrvi_gram_free(it->gram);
  free(it->cmu);
  free(it->settle_q);
  free(it->c_drop);
  free(it->mu_h);
  free(it->pGf);
  free(it->pA);
  free(it->pmu);
  free(it->pnz);
  free(it);
}

static double *alloc(size_t n) { return calloc(n > 0 ? n : 1, sizeof(double)); }
/* An array written whole before it is read, not zeroed: its pages are
 * first touched where it is written (those never written, never). */
static double *alloc_raw(size_t n) {
  return malloc((n > 0 ? n : 1) * sizeof(double));
}

/* Split model-order (q, p) into the rate blocks (packed: the blocks are
 * views of q and p already). */
static void split_state(mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  if (it->packed)
    return;
  for (int s = 0; s < m->n_slow; s++) {
    it->qs[s] = it->q[m->slow_index[s]];
    it->ps[s] = it->p[m->slow_index[s]];
  }
  for (int s = 0; s < m->n_fast; s++) {
    it->qf[s] = it->q[m->fast_index[s]];
    it->pf[s] = it->p[m->fast_index[s]];
  }
}

/* The initial state (q0, M v0) straight into the rate blocks, where the
 * steps keep it there alone (blocks_only): q and p are written when asked
 * (mrvi_integrator_q, _p), so their pages are not touched before. */
static void initial_blocks(mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  for (int s = 0; s < m->n_slow; s++) {
    const int i = m->slow_index[s];
    it->qs[s] = m->q0[i];
    it->ps[s] = MRVI_MASS(m, i) * m->v0[i];
  }
  for (int s = 0; s < m->n_fast; s++) {
    const int i = m->fast_index[s];
    it->qf[s] = m->q0[i];
    it->pf[s] = MRVI_MASS(m, i) * m->v0[i];
  }
}

/* Predictor: an explicit multirate sweep (solver/predict.c), as
 * displacements from the known nodes (the Newton paths solve for
 * increments, mrvi_step.increments, so that tiny steps keep their digits). */
static void predict(mrvi_integrator *it) {
  it->step.increments = 1;
  mrvi_predict_checked(it->predictor, &it->step, it->x);
}

/* The predictor's slow positions moved onto the slow constraints, nearest
 * in the mass metric (tuning predict_settle; mrvi_gram_settle with the Gram
 * factor at q_k).  The move lies in the range of M^-1 G^T, so the
 * multipliers' first update absorbs its force and that update starts from
 * the constraints held instead of from the predictor's violation (the
 * predictor leaves the constraint forces out): on long chains one Newton
 * update less per step (doc/performance/chains.md, "Chains").  A singular Gram
 * matrix leaves the predictor as it is (the step reports it).  The
 * joint-reduced null space settles its own start
 * (solver/nullspace_tree.c). */
static void settle_predictor(mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  const mrvi_step *st = &it->step;
  double *q = it->settle_q, *q1 = it->settle_q + m->n;
  if (mrvi_gram_factor(it->gram, m, it->q) != MRVI_OK)
    return;
  memcpy(q, it->q, (size_t)m->n * sizeof *q);
  for (int s = 0; s < st->ns; s++)
    q[m->slow_index[s]] = it->qs[s] + it->x[s];
  memcpy(q1, q, (size_t)m->n * sizeof *q1);
  mrvi_gram_settle(it->gram, m, q1, it->cmu, MRVI_GRAM_SETTLE_PASSES);
  /* (the moves alone: coordinates no constraint touches keep x exactly) */
  for (int s = 0; s < st->ns; s++)
    it->x[s] += q1[m->slow_index[s]] - q[m->slow_index[s]];
}

/* Displacements -> positions in x (after convergence), for ns, nf
 * constants on small blocks. */
ALWAYS_INLINE void to_positions_k(mrvi_integrator *it, const int ns,
                                  const int nf) {
  double *restrict x = it->x;
  const double *restrict qs = it->qs, *restrict qf = it->qf;
  UNROLL for (int s = 0; s < ns; s++) x[s] += qs[s];
  for (int mm = 1; mm <= it->step.p; mm++)
    UNROLL for (int s = 0; s < nf; s++) x[ns + (mm - 1) * nf + s] += qf[s];
}

static void to_positions(mrvi_integrator *it) {
  mrvi_step *st = &it->step;
  SMALL2(st->ns, NS, st->nf, NF, to_positions_k(it, NS, NF));
  st->increments = 0;
}

static double norm_inf(const double *v, int n) {
  /* max |v_i|, NaN if any v_i is NaN.  Four running maxima (exact, so the
   * same value in any order) and four partial sums z of |v_i|, all finite
   * unless some v_i is not finite or a sum overflows: then the entries are
   * looked at again, one by one.  Four independent chains per pass (the
   * pass is latency bound: one chain of additions took 2 cycles an entry),
   * in two pairs (util/simd.h: GCC keeps `a > r ? a : r` scalar, it may
   * not reorder it as a maximum because of NaNs). */
  int i = 0;
  mrvi_v2 ra = v2_zero(), rb = ra, za = ra, zb = ra;
  for (; i + 3 < n; i += 4) {
    const mrvi_v2 a = v2_abs(v2_load(v + i)), b = v2_abs(v2_load(v + i + 2));
    ra = v2_max(ra, a);
    rb = v2_max(rb, b);
    za = v2_add(za, a);
    zb = v2_add(zb, b);
  }
  ra = v2_max(ra, rb);
  za = v2_add(za, zb);
  const double r0 = v2_lo(ra), r1 = v2_hi(ra);
  double r = r0 > r1 ? r0 : r1;     /* the maximum */
  double z = v2_lo(za) + v2_hi(za); /* and the sum */
  for (; i < n; i++) {
    const double a = fabs(v[i]);
    r = a > r ? a : r;
    z += a;
  }
  if (z <= DBL_MAX)
    return r;
  for (i = 0; i < n; i++)
    if (v[i] != v[i])
      return NAN;
  return r; /* (infinite, or a sum that overflowed) */
}

/* dst[0..n) = src[0..n) in 16-byte loads and stores: memcpy of a few
 * hundred doubles per step went to glibc's `rep movsb`, whose start-up
 * cost is larger than the copy's at these sizes (a loop of plain
 * assignments GCC turns back into the memcpy call). */
static void copy_pairs(double *restrict dst, const double *restrict src,
                       size_t n) {
  size_t i = 0;
  for (; i + 4 <= n; i += 4) {
    const mrvi_v2 a = v2_load(src + i), b = v2_load(src + i + 2);
    v2_store(dst + i, a);
    v2_store(dst + i + 2, b);
  }
  if (i + 2 <= n) {
    v2_store(dst + i, v2_load(src + i));
    i += 2;
  }
  if (i < n)
    dst[i] = src[i];
}

/* Roundoff floor of the residual: its rows subtract momenta of size
 * M |q| / dt, so no iterate can push ||R|| below a few eps times that.  The
 * Newton test is ||R|| <= max(tol, floor); for the paper's set-ups the floor
 * is far below the tolerance (FPU, dt = 1e-3: about 1e-12).  With the
 * scaled criterion each row's floor is divided by its mass, as its
 * residual is (residual_norms). */
static double residual_floor(const mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  const mrvi_step *st = &it->step;
  const int scaled = it->rinv != NULL;
  double scale = 0.0;
  for (int s = 0; s < st->ns; s++) {
    const double M = MRVI_MASS(m, m->slow_index[s]);
    const double a =
        fabs(it->ps[s]) +
        M * (fabs(it->qs[s]) + fabs(it->qs[s] + it->x[s])) / st->dT;
    scale = fmax(scale, scaled ? a / M : a);
  }
  for (int s = 0; s < st->nf; s++) {
    double qmax = fabs(it->qf[s]);
    for (int mm = 1; mm <= st->p; mm++)
      qmax =
          fmax(qmax, fabs(it->qf[s] + it->x[st->ns + (mm - 1) * st->nf + s]));
    const double M = MRVI_MASS(m, m->fast_index[s]);
    const double a = fabs(it->pf[s]) + 4.0 * M * qmax / st->dt;
    scale = fmax(scale, scaled ? a / M : a);
  }
  return 16.0 * DBL_EPSILON * scale;
}

/* Constraints at q: g within the tolerance and independent gradients; in
 * the null-space form the redundant rows at q those found at q0 (the first
 * call sets them). */
static int check_constraints(mrvi_integrator *it, const double *q, char *msg,
                             size_t len) {
  const mrvi_model *m = it->model;
  const int R = m->constraint_rows;
  int st = mrvi_constraints_check_positions(m, q, it->settings.constraint_tol,
                                            "positions", NULL, msg, len);
  if (st < 0 || it->settings.constraint_form != MRVI_FORM_NULL_SPACE)
    return st < 0 ? st : mrvi_constraints_independent(m, q, msg, len);
  if (!it->c_drop) {
    if (!(it->c_drop = malloc(2 * (size_t)R + 1)))
      return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
    it->c_drop_at = it->c_drop + R;
    it->n_drop = mrvi_constraints_rank(m, q, it->c_drop, msg, len);
    if (it->n_drop > 0 && it->gram) {
      /* Redundant rows: the sparse Gram matrix is singular, so project()
       * takes the dense pass, whose G and Gram are full size. */
      const size_t n = (size_t)m->n;
      double *G = realloc(it->cGd, (size_t)R * n * sizeof *G);
      if (G)
        it->cGd = G;
      double *A = G ? realloc(it->cA, (size_t)R * (size_t)R * sizeof *A) : NULL;
      if (A)
        it->cA = A;
      if (!G || !A)
        return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
    }
    return it->n_drop < 0 ? it->n_drop : MRVI_OK;
  }
  st = mrvi_constraints_rank(m, q, it->c_drop_at, msg, len);
  if (st >= 0 && memcmp(it->c_drop, it->c_drop_at, (size_t)R) != 0)
    return mrvi_fail(
        msg, len, MRVI_ESINGULAR,
        "the redundant constraint rows differ here (%d) from those at "
        "the initial positions (%d): a singular configuration of a "
        "closed loop?",
        st, it->n_drop);
  return st < 0 ? st : MRVI_OK;
}

/* Momentum projection at the current macro node (doc/constraints.md,
 * RATTLE-style): p <- p - G^T mu with (G M^-1 G^T) mu = G M^-1 p, so that the
 * hidden constraint G M^-1 p = 0 holds.  The shift lies in the range of G^T at
 * the node, so the next step's lambda absorbs it: positions are unchanged. */
static int project(mrvi_integrator *it) {
  const int R = it->model->constraint_rows;
  /* The sparse Gram factorisation needs independent rows; a model with
   * redundant rows left out (null-space form) projects densely. */
  if (it->gram && it->n_drop == 0) {
    if (mrvi_gram_factor(it->gram, it->model, it->q) < 0)
      return MRVI_ESINGULAR;
    mrvi_gram_project(it->gram, it->model, it->p, it->cmu);
  } else if (mrvi_constraints_project(it->model, it->q, it->p, it->c_drop,
                                      it->cg, it->cGd, it->cA, it->cmu) < 0) {
    return MRVI_ESINGULAR;
  }
  /* The impulse G^T mu belongs to the node's multipliers: the next step
   * reports its multipliers (an impulse over dT) plus mu / dT, which equals
   * what it reports without projection. */
  for (int r = 0; r < R; r++)
    it->mu_h[r] = it->cmu[r] / it->settings.macro_step;
  return MRVI_OK;
}

/* Micro-node constraints must be independent through their fast
 * coordinates when p > 1.  A combination of them free of fast coordinates
 * is a constraint on the slow coordinates alone, enforced at every micro
 * node on their linear interpolation: p conditions on one unknown node
 * q_{k+1}^s, which no step can meet (the Newton matrix is singular).  The
 * redundant rows the null-space form leaves out (a closed loop of fast
 * bodies, it->c_drop) are not counted. */
static int check_micro_constraints(mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  const mrvi_step *st = &it->step;
  if (st->p == 1 || st->r_micro == 0)
    return MRVI_OK;
  int r = 0;
  for (int i = 0; i < st->n_micro_c; i++) {
    const mrvi_constraint *k = &m->constraints[st->micro_c[i]];
    for (int q = 0; q < k->rows; q++)
      r += !(it->c_drop && it->c_drop[k->first_row + q]);
  }
  const int nf = st->nf;
  if (r > nf || nf > MRVI_DENSE_MAX)
    return r > nf ? MRVI_ESINGULAR : MRVI_OK;
  double *A = it->pGf, *Q = malloc((size_t)nf * (size_t)nf * sizeof *Q);
  if (!Q)
    return MRVI_ENOMEM;
  /* G_f(q0)^T over the kept rows, nf x r */
  memset(A, 0, (size_t)r * (size_t)nf * sizeof *A);
  double y[MRVI_MAX_INPUTS];
  for (int i = 0, row = 0; i < st->n_micro_c; i++) {
    const mrvi_constraint *k = &m->constraints[st->micro_c[i]];
    for (int j = 0; j < k->n_in; j++)
      y[j] = m->q0[k->in[j]];
    mrvi_constraint_eval_at(k, y, it->cg, it->cGd, NULL);
    for (int q = 0; q < k->rows; q++) {
      if (it->c_drop && it->c_drop[k->first_row + q])
        continue;
      for (int j = 0; j < k->n_in; j++)
        if (m->rate[k->in[j]] == MRVI_FAST)
          A[m->slot[k->in[j]] * r + row] += it->cGd[q * k->n_in + j];
      row++;
    }
  }
  const int rank_ok = mrvi_dense_qr(nf, r, A, Q) == 0;
  free(Q);
  return rank_ok ? MRVI_OK : MRVI_ESINGULAR;
}

/* Message for check_micro_constraints: the constraints involved. */
static void explain_micro(const mrvi_integrator *it, char *msg, size_t len) {
  const mrvi_model *m = it->model;
  const mrvi_step *st = &it->step;
  char names[300] = "";
  size_t used = 0;
  for (int i = 0; i < st->n_micro_c && used + 8 < sizeof names; i++)
    used +=
        (size_t)snprintf(names + used, sizeof names - used, "%s'%s'",
                         i ? ", " : "", m->constraints[st->micro_c[i]].label);
  mrvi_fmt(msg, len,
           "the micro-node constraints %s are dependent through their fast "
           "coordinates (%d equations): a combination of them constrains "
           "slow coordinates alone, which p = %d micro nodes would enforce "
           "on their linear interpolation within a macro step; make those "
           "slow coordinates fast, or use micro_steps = 1",
           names, st->r_micro, st->p);
}

/* The explicit, sweep and sweep-cg paths (solver/sweep.c): no Newton
 * matrix of the whole step (the Jacobian pattern is built on demand by
 * mrvi_integrator_jacobian_solve). */
static int sweep_create(mrvi_integrator *it, char *msg, size_t len) {
  if (mrvi_sweep_create(&it->step, &it->settings, &it->sweep) < 0)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  it->sweep_tight = mrvi_sweep_tight(it->sweep);
  return MRVI_OK;
}

static void sweep_free(mrvi_integrator *it) { mrvi_sweep_free(it->sweep); }

/* The Newton paths' predictor, to Newton's tolerance. */
static int predictor_only(mrvi_integrator *it, char *msg, size_t len) {
  if (mrvi_predictor_create(it->model, &it->step, &it->predictor) < 0)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  mrvi_predictor_set_tolerance(it->predictor, it->settings.newton_tol);
  return MRVI_OK;
}

/* The predictor and x at it. */
static int predictor_create(mrvi_integrator *it, char *msg, size_t len) {
  const int st = predictor_only(it, msg, len);
  if (st == MRVI_OK)
    predict(it);
  return st;
}

/* The Jacobian pattern and the residual and Jacobian at the predictor
 * (pattern and symbolic analysis once per run). */
static int jacobian_create(mrvi_integrator *it, char *msg, size_t len) {
  if (mrvi_step_build_pattern(&it->step, it->x) < 0)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  mrvi_step_assemble(&it->step, it->x, it->R, 1);
  return MRVI_OK;
}

/* The Newton paths' common set-up: the predictor and the Jacobian. */
static int newton_paths_create(mrvi_integrator *it, char *msg, size_t len) {
  const int st = predictor_create(it, msg, len);
  return st < 0 ? st : jacobian_create(it, msg, len);
}

/* The general path: the sparse LU of the whole step's Jacobian, or in the
 * null-space form (constraints only) of its reduced rows. */
static int general_create(mrvi_integrator *it, char *msg, size_t len) {
  mrvi_step *sp = &it->step;
  int st = newton_paths_create(it, msg, len);
  if (st < 0)
    return st;
  if (it->settings.constraint_form == MRVI_FORM_NULL_SPACE &&
      sp->n_lambda > 0) {
    /* Values for the symbolic analysis: lambda(x) and the reduced rows at
     * the predictor. */
    if ((st = mrvi_nullspace_create(sp, it->c_drop, 1, &it->nullspace, msg,
                                    len)) < 0 ||
        (mrvi_step_assemble(sp, it->x, it->R, 0),
         st = mrvi_nullspace_lambda(it->nullspace, sp, it->x, it->R, msg,
                                    len)) < 0)
      return st;
    mrvi_step_assemble(sp, it->x, it->R, 1);
    mrvi_nullspace_reduce(it->nullspace, sp, it->R, it->rhs);
    it->newton = mrvi_newton_create(
        mrvi_nullspace_size(it->nullspace), mrvi_nullspace_Ap(it->nullspace),
        mrvi_nullspace_Ai(it->nullspace), mrvi_nullspace_Ax(it->nullspace),
        sp->tuning.newton_dense_max, msg, len);
  } else {
    it->newton = mrvi_newton_create(sp->n_total, sp->Ap, sp->Ai, sp->Ax,
                                    sp->tuning.newton_dense_max, msg, len);
  }
  return it->newton ? MRVI_OK : MRVI_ESINGULAR;
}

static void general_free(mrvi_integrator *it) {
  mrvi_newton_free(it->newton);
  mrvi_nullspace_free(it->nullspace);
  mrvi_predictor_free(it->predictor);
}

/* The schur path (solver/blocks.c): its blocks, the constant chord's
 * measure and whether its steps may shoot (run constants). */
static int schur_create(mrvi_integrator *it, char *msg, size_t len) {
  int st = newton_paths_create(it, msg, len);
  if (st < 0)
    return st;
  if (mrvi_blocks_create(&it->step, &it->blocks) < 0)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  it->cchord_e = it->step.dT * it->step.dT *
                 mrvi_blocks_const_measure(it->blocks, &it->step);
  it->shoot_ok = mrvi_predictor_shoot_ok(it->predictor, &it->step);
  return MRVI_OK;
}

static void schur_free(mrvi_integrator *it) {
  mrvi_blocks_free(it->blocks);
  mrvi_predictor_free(it->predictor);
}

/* schur-krylov's Newton: the whole step's CSC Jacobian pattern and the
 * elimination on it (solver/schur_krylov.c), built once and kept.  Where
 * the matrix-free outer iteration is the path's first choice, on the first
 * step left to Newton (or the first Jacobian solve): the pattern is
 * structural and the elimination reads only it at creation, so that step
 * does the arithmetic it does with the machinery built at creation. */
static int skrylov_newton(mrvi_integrator *it, char *msg, size_t len) {
  if (it->skrylov)
    return MRVI_OK;
  if (!it->step.Ap && mrvi_step_build_pattern(&it->step, it->x) < 0)
    return mrvi_fail(msg, len, MRVI_ENOMEM,
                     "out of memory for the step Jacobian of schur-krylov's "
                     "Newton");
  return mrvi_skrylov_create(&it->step, &it->skrylov, msg, len);
}

/* The schur-krylov path (solver/schur_krylov.c).  The predictor's x at
 * the initial state only where Newton's Jacobian is made here: every step
 * predicts x afresh (newton_step), and the outer iteration builds no
 * Jacobian at creation, so there no prediction is made before the first
 * step (the same steps, the prediction's time saved). */
static int skrylov_create(mrvi_integrator *it, char *msg, size_t len) {
  int st = predictor_only(it, msg, len);
  if (st < 0)
    return st;
  /* The matrix-free outer iteration on unconstrained steps (solver/outer.c)
   * where its Jacobi chord on the fast rows contracts by at most
   * chord_jacobi_max at the initial state, (omega_max dt)^2/4, as
   * sweep-cg's (doc/solver.md, "schur-krylov: the outer iteration"); then
   * Newton is built on the first step left to it. */
  const mrvi_step *sp = &it->step;
  const double a =
      mrvi_outer_contraction(mrvi_predictor_omega_max(it->predictor), sp->dt);
  if (sp->tuning.outer_max > 0 && sp->n_lambda == 0 &&
      a <= sp->tuning.chord_jacobi_max)
    return mrvi_outer_create(it->model, sp, &it->outer) < 0
               ? mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory")
               : MRVI_OK;
  predict(it);
  return (st = jacobian_create(it, msg, len)) < 0
             ? st
             : skrylov_newton(it, msg, len);
}

/* The schur-bordered path (solver/bordered.c) on the CSC Jacobian; with
 * micro-node constraints (tuning predict_joints) its predictor takes the
 * joint sweep (solver/predict_joints.c). */
static int bordered_create(mrvi_integrator *it, char *msg, size_t len) {
  const int st = newton_paths_create(it, msg, len);
  if (st < 0)
    return st;
  if (mrvi_bordered_create(&it->step, &it->bordered) < 0 ||
      (it->step.tuning.predict_joints &&
       (mrvi_joint_sweep_create(&it->step, &it->jsweep) < 0 ||
        mrvi_predictor_set_joints(it->predictor, it->jsweep, &it->step) < 0)))
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  return MRVI_OK;
}

static void bordered_free(mrvi_integrator *it) {
  mrvi_bordered_free(it->bordered);
  mrvi_joint_sweep_free(it->jsweep);
  mrvi_predictor_free(it->predictor);
}

static void skrylov_free(mrvi_integrator *it) {
  mrvi_skrylov_free(it->skrylov);
  mrvi_outer_free(it->outer);
  mrvi_predictor_free(it->predictor);
}

int mrvi_integrator_check_inputs(const mrvi_model *m, const mrvi_settings *s,
                                 char *msg, size_t len) {
  if (!m || !s) {
    mrvi_fmt(msg, len, "model and settings are required");
    return MRVI_EINVAL;
  }
  int st = mrvi_settings_check(s, msg, len);
  if (st < 0)
    return st;
  if (m->n == 0) {
    mrvi_fmt(msg, len, "the model has no coordinates");
    return MRVI_EMODEL;
  }
  const long R = m->constraint_rows, p = s->micro_steps;
  return mrvi_tuning_check_model(&s->tuning, (long)m->n + R,
                                 m->n_slow + p * (m->n_fast + R), msg, len);
}

/* mrvi_integrator_create, the step hooks (if any: hooks[0] = extra,
 * hooks[1] = end, ctx) set before the path objects are made. */
static int create(const mrvi_model *m, const mrvi_settings *s,
                  const mrvi_step *hooks, mrvi_integrator **out, char *msg,
                  size_t len) {
  *out = NULL;
  int st = mrvi_integrator_check_inputs(m, s, msg, len);
  if (st < 0)
    return st;
  mrvi_integrator *it = calloc(1, sizeof *it);
  if (!it) {
    mrvi_fmt(msg, len, "out of memory");
    return MRVI_ENOMEM;
  }
  it->model = m;
  it->settings = *s;
  /* (the step's pass over the elements first: the path choice takes what
   * it found) */
  if ((st = mrvi_step_init(&it->step, m, s)) < 0)
    goto oom;
  it->path =
      mrvi_sweep_path_of(m, s, it->step.fast_on_slow, it->why, sizeof it->why);
  if (it->path == MRVI_PATH_GENERAL && s->solver == MRVI_SOLVER_STRUCTURED) {
    mrvi_fmt(msg, len, "integrator.solver = structured: no structured path: %s",
             it->why);
    mrvi_integrator_free(it);
    return MRVI_EINVAL;
  }
  const size_t n = (size_t)m->n, ns = (size_t)m->n_slow, nf = (size_t)m->n_fast,
               p = (size_t)s->micro_steps, nu = (size_t)it->step.n_total;
  it->q = alloc_raw(n); /* (q0, M v0 below, or when asked: blocks_only) */
  it->p = alloc_raw(n);
  /* Slow coordinates first, then the fast ones, in their order (the usual
   * layout): the rate blocks are views of q and p, and a step's new state
   * is written once. */
  it->packed = 1;
  for (int i = 0; i < m->n_slow; i++)
    it->packed &= m->slow_index[i] == i;
  for (int i = 0; i < m->n_fast; i++)
    it->packed &= m->fast_index[i] == m->n_slow + i;
  if (it->packed && it->q && it->p) {
    it->qs = it->q;
    it->qf = it->q + ns;
    it->ps = it->p;
    it->pf = it->p + ns;
  } else {
    /* (written whole below: initial_blocks or split_state) */
    it->packed = 0;
    it->qs = alloc_raw(ns + nf); /* (qf after qs, as in x: swap_state) */
    it->ps = alloc_raw(ns);
    it->qf = it->qs ? it->qs + ns : NULL;
    it->pf = alloc_raw(nf);
  }
  /* The residual, the update and the reduced right-hand side are the Newton
   * paths' (update != NULL); the sweep paths' step Jacobian solve allocates
   * dx when first asked (mrvi_integrator_jacobian_solve). */
  const size_t nn = path_ops_of(it->path)->update ? nu : 0;
  /* The explicit path writes each node before it reads it and each step
   * writes the kept micro nodes: those arrays are not zeroed (with the
   * last node alone kept, mrvi_integrator_keep_micro, the other rows are
   * never touched). */
  const int explicit = it->path == MRVI_PATH_EXPLICIT;
  it->x = explicit ? alloc_raw(nu) : alloc(nu);
  it->R = alloc(nn);
  it->dx = alloc(nn);
  it->ps1 = explicit ? alloc_raw(ns) : alloc(ns);
  it->micro_q = explicit ? alloc_raw(p * nf) : alloc(p * nf);
  it->micro_p = explicit ? alloc_raw(p * nf) : alloc(p * nf);
  it->node_stride = nf;
  it->micro_all = 1;
  it->lambda = alloc((size_t)m->constraint_rows);
  it->micro_cres = alloc(p);
  it->rhs = alloc(nn); /* the joint-reduced system: at most n_total */
  const size_t R = (size_t)m->constraint_rows;
  it->cg = alloc(R);
  /* Dense G and Gram up to MRVI_GRAM_DENSE_MAX rows, the sparse Gram
   * beyond (cGd then holds one constraint's gradient). */
  const size_t cmax = (size_t)m->max_constraint_in;
  const int sparse_gram = m->constraint_rows > MRVI_GRAM_DENSE_MAX;
  it->cGd = alloc(sparse_gram ? cmax * cmax : R * n);
  it->cA = alloc(sparse_gram ? 1 : R * R);
  if (sparse_gram && mrvi_gram_create(m, &it->gram) < 0)
    goto oom;
  it->cmu = alloc(R);
  it->mu_h = alloc(R);
  /* settle_predictor: the multiplier form with the sparse Gram matrix and
   * slow constraints only */
  int all_slow = 1;
  for (int c = 0; c < m->n_constraints; c++)
    all_slow = all_slow && m->constraints[c].where == MRVI_SLOW;
  if (it->gram && all_slow && s->tuning.predict_settle &&
      s->constraint_form != MRVI_FORM_NULL_SPACE)
    it->settle_q = alloc(2 * n);
  const size_t rm = (size_t)it->step.r_micro;
  it->pGf = alloc(rm * nf);
  it->pA = alloc(rm * rm);
  it->pmu = alloc(rm);
  it->pnz = malloc((size_t)(nf > 0 ? nf : 1) * sizeof(int));
  /* (written by each step that keeps its micro nodes, new_state_blocks,
   * and read only after one: mrvi_integrator_jacobian_solve) */
  it->qs_prev = alloc_raw(ns + nf);
  if (!it->qs_prev)
    goto oom;
  it->qf_prev = it->qs_prev + ns;
  if (s->newton_criterion == MRVI_CRITERION_SCALED) {
    /* Rows: the slow unknowns, then the fast ones of micro nodes 1..p. */
    it->rinv = alloc((size_t)it->step.n_unknowns);
    for (size_t r = 0; it->rinv && r < (size_t)it->step.n_unknowns; r++)
      it->rinv[r] = 1.0 / MRVI_MASS(m, r < ns ? m->slow_index[r]
                                              : m->fast_index[(r - ns) % nf]);
    if (!it->rinv)
      goto oom;
  }
  if (!it->q || !it->p || !it->qs || !it->ps || !it->qf || !it->pf || !it->x ||
      !it->R || !it->dx || !it->ps1 || !it->micro_q || !it->micro_p ||
      !it->lambda || !it->micro_cres || !it->rhs || !it->cg || !it->cGd ||
      !it->cA || !it->cmu || !it->mu_h || !it->pGf || !it->pA || !it->pmu ||
      !it->pnz)
    goto oom;
  /* Initial state (q0, M v0) at t = 0; constraints must hold at q0. */
  it->n_torsion = mrvi_model_n_torsions(m);
  it->blocks_only = !it->packed && m->n_constraints == 0 && it->n_torsion == 0;
  if (it->blocks_only)
    initial_blocks(it);
  for (size_t i = 0; !it->blocks_only && i < n; i++) {
    it->q[i] = m->q0[i];
    it->p[i] = MRVI_MASS(m, i) * m->v0[i];
  }
  if (m->n_constraints > 0) {
    if ((st = check_constraints(it, m->q0, msg, len)) < 0) {
      mrvi_integrator_free(it);
      return st;
    }
    if (s->project_momenta && project(it) < 0)
      goto oom;
  }
  if (m->n_constraints > 0 && (st = check_micro_constraints(it)) < 0) {
    if (st == MRVI_ESINGULAR)
      explain_micro(it, msg, len);
    else
      mrvi_fmt(msg, len, "out of memory");
    mrvi_integrator_free(it);
    return st;
  }
  /* Torsional springs: their branches at q0, nearest their rest angles. */
  if (!(it->torsion = alloc((size_t)it->n_torsion)))
    goto oom;
  mrvi_model_torsion_init(m, it->q, it->torsion);
  if (!it->blocks_only)
    split_state(it);
  it->step.qs0 = it->qs;
  it->step.qf0 = it->qf;
  it->step.ps0 = it->ps;
  it->step.pf0 = it->pf;
  if (hooks) {
    it->step.extra = hooks->extra;
    it->step.extra_end = hooks->extra_end;
    it->step.extra_ctx = hooks->extra_ctx;
  }
  it->ops = path_ops_of(it->path);
  if ((st = it->ops->create(it, msg, len)) < 0) {
    mrvi_integrator_free(it);
    return st;
  }
  *out = it;
  return MRVI_OK;
oom:
  mrvi_integrator_free(it);
  mrvi_fmt(msg, len, "out of memory");
  return MRVI_ENOMEM;
}

int mrvi_integrator_create(const mrvi_model *m, const mrvi_settings *s,
                           mrvi_integrator **out, char *msg, size_t len) {
  return create(m, s, NULL, out, msg, len);
}

int mrvi_integrator_create_hooked(
    const mrvi_model *m, const mrvi_settings *s,
    void (*extra)(void *ctx, mrvi_step *st, const double *x, double *R,
                  int jac),
    void (*end)(void *ctx, mrvi_step *st, const double *x), void *ctx,
    mrvi_integrator **out, char *msg, size_t len) {
  mrvi_step hooks = {.extra = extra, .extra_end = end, .extra_ctx = ctx};
  return create(m, s, &hooks, out, msg, len);
}

int mrvi_integrator_set_state(mrvi_integrator *it, double t, const double *q,
                              const double *p) {
  const int n = it->model->n;
  for (int i = 0; i < n; i++)
    if (!isfinite(q[i]) || !isfinite(p[i]))
      return fail(it, MRVI_ENONFINITE, "state is not finite");
  memcpy(it->q, q, (size_t)n * sizeof *q);
  memcpy(it->p, p, (size_t)n * sizeof *p);
  mrvi_model_torsion_init(it->model, q, it->torsion);
  memset(it->mu_h, 0, (size_t)it->model->constraint_rows * sizeof(double));
  if (it->model->n_constraints > 0) {
    char msg[400];
    int st = check_constraints(it, it->q, msg, sizeof msg);
    if (st < 0)
      return fail(it, st, "%s", msg);
    if (it->settings.project_momenta && project(it) < 0)
      return fail(it, MRVI_ESINGULAR, "momentum projection failed");
  }
  split_state(it);
  mrvi_sweep_reset(it->sweep);
  it->jac_ready = 0;
  it->t0 = t;
  it->k = 0;
  return MRVI_OK;
}

int mrvi_integrator_resume_state(mrvi_integrator *it, long k, const double *q,
                                 const double *p) {
  const int n = it->model->n;
  if (k < 0)
    return fail(it, MRVI_EINVAL, "macro node %ld: must be >= 0", k);
  for (int i = 0; i < n; i++)
    if (!isfinite(q[i]) || !isfinite(p[i]))
      return fail(it, MRVI_ENONFINITE, "state is not finite");
  if (it->model->n_constraints > 0) {
    char msg[400];
    int st = check_constraints(it, q, msg, sizeof msg);
    if (st < 0)
      return fail(it, st, "%s", msg);
  }
  memcpy(it->q, q, (size_t)n * sizeof *q);
  memcpy(it->p, p, (size_t)n * sizeof *p);
  /* No projection: p_k of a stored node is projected already, and
   * projecting again would change its last bits.  Torsional springs start
   * on the branch nearest their rest angle until
   * mrvi_integrator_resume_torsion gives the stored ones. */
  mrvi_model_torsion_init(it->model, q, it->torsion);
  mrvi_model_torsion_set(it->model, it->torsion);
  memset(it->mu_h, 0, (size_t)it->model->constraint_rows * sizeof(double));
  split_state(it);
  mrvi_sweep_reset(it->sweep);
  it->jac_ready = 0;
  it->t0 = 0.0;
  it->k = k;
  return MRVI_OK;
}

int mrvi_integrator_resume_torsion(mrvi_integrator *it, const double *angle) {
  const int nt = it->n_torsion;
  if (nt == 0)
    return MRVI_OK;
  double *at = alloc((size_t)nt);
  if (!at)
    return fail(it, MRVI_ENOMEM, "out of memory");
  memcpy(at, angle, (size_t)nt * sizeof *at);
  /* at <- each spring's angle at q on the branch nearest the given one:
   * the given branch must be that angle (up to rounding), not just near. */
  mrvi_model_torsion_follow(it->model, it->q, at, NULL);
  for (int t = 0; t < nt; t++)
    if (!isfinite(angle[t]) || !(fabs(at[t] - angle[t]) <= 1e-6)) {
      const double want = at[t];
      free(at);
      mrvi_model_torsion_set(it->model, it->torsion);
      return fail(it, MRVI_EINVAL,
                  "torsional spring %d: branch %.17g is not its angle at the "
                  "node's configuration (nearest: %.17g) up to whole turns",
                  t, angle[t], want);
    }
  free(at);
  memcpy(it->torsion, angle, (size_t)nt * sizeof *angle);
  mrvi_model_torsion_set(it->model, it->torsion);
  return MRVI_OK;
}

int mrvi_integrator_chord_history(const mrvi_integrator *it,
                                  const double *part[5]) {
  return it->sweep ? mrvi_sweep_history(it->sweep, part) : 0;
}

int mrvi_integrator_resume_chord_history(mrvi_integrator *it, int n,
                                         const double *h) {
  char msg[300];
  const int st = it->sweep && n > 0 && h
                     ? mrvi_sweep_set_history(it->sweep, n, h, msg, sizeof msg)
                     : MRVI_EINVAL;
  if (st < 0)
    return fail(it, st, "%s",
                it->sweep && n > 0 && h
                    ? msg
                    : "a chord history was given, but this run's solver "
                      "keeps none");
  return MRVI_OK;
}

int mrvi_integrator_n_torsions(const mrvi_integrator *it) {
  return it->n_torsion;
}

const double *mrvi_integrator_torsion_angle(const mrvi_integrator *it) {
  return it->torsion;
}

/* Norms of the dynamic rows (momentum units) and of the constraint rows
 * (max |g| at the enforcing nodes). */
static void residual_norms(const mrvi_integrator *it, double *dyn,
                           double *con) {
  const mrvi_step *st = &it->step;
  if (it->rinv) { /* newton.criterion scaled: max |R_r| / M_r */
    double r = 0.0;
    for (int i = 0; i < st->n_unknowns; i++) {
      const double a = fabs(it->R[i]) * it->rinv[i];
      r = isnan(a) || a > r ? a : r;
    }
    *dyn = r;
  } else {
    *dyn = norm_inf(it->R, st->n_unknowns);
  }
  *con =
      st->n_lambda > 0 ? norm_inf(it->R + st->n_unknowns, st->n_lambda) : 0.0;
}

/* The general path's residual: in the null-space form the multipliers are
 * first set to lambda(x) from the residual at lambda = 0. */
static int general_assemble(mrvi_integrator *it, int jac, char *msg,
                            size_t len) {
  mrvi_step *st = &it->step;
  if (it->nullspace) {
    memset(it->x + st->n_unknowns, 0, (size_t)st->n_lambda * sizeof(double));
    mrvi_step_assemble(st, it->x, it->R, 0);
    int s = mrvi_nullspace_lambda(it->nullspace, st, it->x, it->R, msg, len);
    if (s < 0)
      return s;
  }
  mrvi_step_assemble(st, it->x, it->R, jac);
  return MRVI_OK;
}

/* The schur path assembles its blocks directly (no CSC) where it can. */
static int schur_assemble(mrvi_integrator *it, int jac, char *msg, size_t len) {
  (void)msg, (void)len;
  mrvi_step *st = &it->step;
  if (mrvi_blocks_assemble(it->blocks, st, it->x, it->R, jac) != MRVI_OK)
    mrvi_step_assemble(st, it->x, it->R, jac);
  return MRVI_OK;
}

/* The schur-krylov path reads the CSC Jacobian. */
static int csc_assemble(mrvi_integrator *it, int jac, char *msg, size_t len) {
  (void)msg, (void)len;
  mrvi_step_assemble(&it->step, it->x, it->R, jac);
  return MRVI_OK;
}

/* Residual (and, if jac, the Jacobian) at the current x, by the path. */
static int evaluate(mrvi_integrator *it, int jac, char *msg, size_t len) {
  const double t = tick(it);
  const int s = it->ops->assemble(it, jac, msg, len);
  if (s == MRVI_OK)
    it->t_assemble += tick(it) - t;
  return s;
}

/* The residual at x with the potential parts of the momenta (used if the
 * step is accepted there), and its norms. */
static int evaluate_momenta(mrvi_integrator *it, double *res, double *cres,
                            char *msg, size_t len) {
  mrvi_step *st = &it->step;
  st->mom_ps = it->ps1;
  st->mom_pf = it->micro_p;
  const int s = evaluate(it, 0, msg, len);
  st->mom_ps = st->mom_pf = NULL;
  residual_norms(it, res, cres);
  return s;
}

/* x -= dx on the first n unknowns. */
static void subtract_dx(mrvi_integrator *it, int n) {
  for (int i = 0; i < n; i++)
    it->x[i] -= it->dx[i];
}

/* The general path's update: the full saddle-point system in the
 * multiplier form, the reduced one in the null-space form, both
 * factorised afresh at x (the general path is full Newton). */
static int general_update(mrvi_integrator *it, int fresh, char *msg,
                          size_t len) {
  (void)fresh;
  mrvi_step *st = &it->step;
  int s;
  if (it->nullspace) {
    mrvi_nullspace_reduce(it->nullspace, st, it->R, it->rhs);
    s = mrvi_newton_solve(it->newton, mrvi_nullspace_Ax(it->nullspace), it->rhs,
                          it->dx, msg, len);
    if (s == MRVI_OK && mrvi_nullspace_reparametrised(it->nullspace))
      mrvi_nullspace_retract(it->nullspace, st, it->x, it->dx);
    else if (s == MRVI_OK)
      subtract_dx(it, st->n_unknowns);
    return s;
  }
  s = mrvi_newton_update(it->newton, st->Ax, it->R, it->dx, msg, len);
  if (s == MRVI_OK)
    subtract_dx(it, st->n_total);
  return s;
}

/* The schur path's update: the block elimination, with the constant
 * chord's factors where they are kept (x -= dx inside). */
static int schur_update(mrvi_integrator *it, int fresh, char *msg, size_t len) {
  mrvi_step *st = &it->step;
  int s = MRVI_OK;
  if (fresh) {
    it->factors_ok = 0;
    it->const_kept = 0;
    it->n_factor++;
    if ((s = mrvi_blocks_factor_solve(it->blocks, st, it->R, it->dx)) < 0)
      mrvi_fmt(msg, len, "singular Newton matrix (block elimination)");
    else
      it->factors_ok = 1;
  } else if (it->const_kept) {
    mrvi_blocks_const_solve(it->blocks, it->R, it->dx, it->x);
    return MRVI_OK;
  } else {
    mrvi_blocks_solve(it->blocks, it->R, it->dx);
  }
  if (s == MRVI_OK)
    subtract_dx(it, st->n_total);
  return s;
}

/* The schur-krylov path's update: GMRES on the slow unknowns. */
static int skrylov_update(mrvi_integrator *it, int fresh, char *msg,
                          size_t len) {
  if (fresh)
    mrvi_skrylov_factor(it->skrylov);
  it->factors_ok = 1;
  const int s = mrvi_skrylov_solve(it->skrylov, 0, it->R, it->dx, msg, len);
  if (s == MRVI_OK)
    subtract_dx(it, it->step.n_total);
  return s;
}

/* The schur-bordered path's update: the Jacobian at x factorised afresh
 * where `fresh`, else the factors kept from the step's last factorisation
 * (simplified Newton, the schur path's rule: doc/solver.md,
 * "schur-bordered"). */
static int bordered_update(mrvi_integrator *it, int fresh, char *msg,
                           size_t len) {
  int s;
  if (fresh) {
    it->factors_ok = 0;
    it->n_factor++;
    s = mrvi_bordered_factor_solve(it->bordered, &it->step, it->R, it->dx, msg,
                                   len);
    it->factors_ok = s == MRVI_OK;
  } else {
    s = mrvi_bordered_solve(it->bordered, &it->step, it->R, it->dx, msg, len);
  }
  if (s == MRVI_OK)
    subtract_dx(it, it->step.n_total);
  return s;
}

/* One Newton update dx (x -= dx) from the residual it->R at x by the
 * path, with the Jacobian at x first where `fresh` asks for it and
 * st->Ax does not hold it yet (jac_at_x). */
static int newton_update(mrvi_integrator *it, int fresh, int jac_at_x,
                         char *msg, size_t len) {
  int s;
  if (fresh && !jac_at_x) {
    /* The Jacobian at x (the residual is recomputed with it); exact: a
     * refactorisation follows an update that did not contract enough. */
    if (it->blocks)
      mrvi_blocks_chord(it->blocks, 0);
    if ((s = evaluate(it, 1, msg, len)) < 0)
      return s;
  }
  const double t = tick(it);
  s = it->ops->update(it, fresh, msg, len);
  it->t_solve += tick(it) - t;
  return s;
}

/* A singular Newton matrix with constraints is most often a redundant set:
 * name the constraints whose gradients are dependent at the current node. */
static void explain_singular(const mrvi_integrator *it, char *msg, size_t len) {
  const mrvi_model *m = it->model;
  if (m->n_constraints == 0)
    return;
  char why[400];
  if (mrvi_constraints_independent(m, it->q, why, sizeof why) < 0) {
    const size_t used = strlen(msg);
    mrvi_fmt(msg + used, len - used, " (%s)", why);
  }
}

/* After convergence: multipliers of node k, max |g| at micro nodes 1..p. */
static void constraint_outputs(mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  mrvi_step *st = &it->step;
  const int nu = st->n_unknowns, p = st->p;
  for (int i = 0; i < st->n_slow_c; i++) {
    const mrvi_constraint *k = &m->constraints[st->slow_c[i]];
    memcpy(it->lambda + k->first_row, it->x + nu + st->c_off[st->slow_c[i]],
           (size_t)k->rows * sizeof(double));
  }
  /* Micro-node constraints: the step average (1/p) sum_m lambda^m.  The
   * slow interpolation is linear, so the slow coordinates' acceleration is
   * concentrated at macro nodes; a constraint coupling them to fast ones
   * passes that kick as an impulse in lambda^0 (interior lambda^m lack it).
   * Single node values are therefore off by O(1) for p > 1; their average,
   * the impulse of the step over dT, is consistent. */
  for (int i = 0; i < st->n_micro_c; i++) {
    const int c = st->micro_c[i];
    const mrvi_constraint *k = &m->constraints[c];
    for (int r = 0; r < k->rows; r++) {
      double sum = 0.0;
      for (int mm = 0; mm < p; mm++)
        sum += it->x[nu + st->r_slow + mm * st->r_micro + st->c_off[c] + r];
      it->lambda[k->first_row + r] = sum / p;
    }
  }
  mrvi_step_micro_residuals(st, it->R, it->micro_cres);
  /* Add the projection impulse of node k (see project). */
  for (int r = 0; r < m->constraint_rows; r++) {
    it->lambda[r] += it->mu_h[r];
    it->mu_h[r] = 0.0;
  }
}

/* Output momenta at the interior micro nodes m = 1..p-1 meet the hidden
 * constraint of the micro-node constraints there: with the slow velocity
 * v_s = (q_{k+1}^s - q_k^s)/dT of the step, G_f M_f^-1 p_f = -G_s v_s,
 * by an M-orthogonal shift of p_f along G_f^T.  Outputs only (the state
 * holds no interior momenta). */
static int project_micro(mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  mrvi_step *st = &it->step;
  const int nf = st->nf, r = st->r_micro;
  for (int mm = 1; mm < st->p; mm++) {
    const mrvi_point pt = mrvi_step_node_point(st, mm, st->dt);
    double *pf = it->micro_p + (size_t)(mm - 1) * (size_t)nf;
    memset(it->pGf, 0, (size_t)r * (size_t)nf * sizeof(double));
    for (int i = 0; i < st->n_micro_c; i++) {
      const int c = st->micro_c[i], off = st->c_off[c];
      const mrvi_constraint *k = &m->constraints[c];
      mrvi_step_constraint_eval(st, c, &pt, it->x, 0);
      for (int q = 0; q < k->rows; q++) {
        double gv = 0.0; /* G_s v_s + G_f M_f^-1 p_f */
        for (int j = 0; j < k->n_in; j++) {
          const int idx = k->in[j], sl = m->slot[idx];
          const double G = st->cG[q * k->n_in + j];
          if (m->rate[idx] == MRVI_SLOW) {
            gv += G * (it->x[sl] - st->qs0[sl]) / st->dT;
          } else {
            gv += G * pf[sl] / MRVI_MASS(m, idx);
            it->pGf[(off + q) * nf + sl] += G;
          }
        }
        it->pmu[off + q] = gv;
      }
    }
    /* G_f M_f^-1 G_f^T: symmetric (the same products either way), the
     * zeros of row a of G_f skipped (listed once per row) */
    for (int a = 0; a < r; a++) {
      const double *ga = it->pGf + (size_t)a * (size_t)nf;
      int nz = 0;
      for (int f = 0; f < nf; f++)
        if (ga[f] != 0.0)
          it->pnz[nz++] = f;
      for (int b = a; b < r; b++) {
        const double *gb = it->pGf + (size_t)b * (size_t)nf;
        double t = 0.0;
        for (int i = 0; i < nz; i++) {
          const int f = it->pnz[i];
          t += ga[f] * gb[f] / MRVI_MASS(m, m->fast_index[f]);
        }
        it->pA[a * r + b] = it->pA[b * r + a] = t;
      }
    }
    if (mrvi_dense_solve(r, it->pA, it->pmu) < 0)
      return MRVI_ESINGULAR;
    for (int f = 0; f < nf; f++)
      for (int a = 0; a < r; a++)
        pf[f] -= it->pGf[a * nf + f] * it->pmu[a];
  }
  return MRVI_OK;
}

ALWAYS_INLINE int finish_step(mrvi_integrator *it);

/* Times of an estimated block at the clock `now`: its first step's times
 * for each of its steps, scaled down to its elapsed time if above. */
static void block_estimate(const mrvi_integrator *it, double now, double *a,
                           double *s) {
  *a = it->block_sample[0] * (double)it->block_n;
  *s = it->block_sample[1] * (double)it->block_n;
  const double elapsed = now - it->block_t0, sum = *a + *s;
  if (sum > elapsed && sum > 0.0) {
    *a *= elapsed / sum;
    *s *= elapsed / sum;
  }
}

/* Which steps are timed, called as a step starts (mrvi_integrator_timing). */
static void count_step(mrvi_integrator *it) {
  const long k = it->n_steps++;
  it->timed = 1;
  if (k < MRVI_TIME_ALL)
    return;
  const long j = (k - MRVI_TIME_ALL) % MRVI_TIME_EVERY; /* in its block */
  if (j == 1) { /* the block's first step ended: time the others? */
    it->block_sample[0] = it->t_assemble - it->block_mark[0];
    it->block_sample[1] = it->t_solve - it->block_mark[1];
    if (it->block_sample[0] + it->block_sample[1] < MRVI_TIME_STEP_MIN) {
      it->block_exact = 0; /* its sample is added when the block ends */
      it->t_assemble = it->block_mark[0];
      it->t_solve = it->block_mark[1];
    }
  } else if (j == 0) { /* a block ends, the next starts */
    const double now = mrvi_clock();
    if (!it->block_exact && it->block_n > 1) {
      double a, s;
      block_estimate(it, now, &a, &s);
      it->t_assemble += a;
      it->t_solve += s;
      it->timing_estimated = 1;
    }
    it->block_exact = 1;
    it->block_n = 0;
    it->block_t0 = now;
    it->block_mark[0] = it->t_assemble;
    it->block_mark[1] = it->t_solve;
  }
  it->block_n++;
  it->timed = it->block_exact;
}

/* A step of the structured paths (solver/sweep.c): solution and momenta at
 * once. */
static int structured_step(mrvi_integrator *it) {
  const mrvi_step *st = &it->step;
  char msg[400];
  msg[0] = '\0'; /* (not = "": that zeroes all 400 bytes every step) */
  it->jac_ready = 0;
  count_step(it);
  const double t = tick(it);
  int iters = 0;
  double res = 0.0;
  /* An uncontrolled explicit step at p = 1: the short entry. */
  const int s =
      it->sweep_tight && !st->f_rows && !st->f_end
          ? mrvi_sweep_explicit_p1(it->sweep, st, it->x, it->ps1, it->micro_p,
                                   msg, sizeof msg)
          : mrvi_sweep_step(it->sweep, st, it->x, it->ps1, it->micro_p, &iters,
                            &res, msg, sizeof msg);
  if (it->timed)
    it->t_solve += tick(it) - t;
  it->last_iterations = iters;
  it->last_residual = res;
  if (s < 0)
    return fail(it, s, "step %ld (t = %.10g -> %.10g): %s", it->k + 1,
                it->t0 + (double)it->k * st->dT,
                it->t0 + (double)(it->k + 1) * st->dT, msg);
  return finish_step(it);
}

/* Whether the first Newton matrix of a schur step is the chord matrix
 * (doc/solver.md, "Newton details"). */
static int use_chord(mrvi_integrator *it) {
  if (it->chord_mode == MRVI_CHORD_OFF || !mrvi_blocks_chord_ok(it->blocks))
    return 0;
  const double dT = it->step.dT;
  const double e =
      dT * dT * mrvi_blocks_chord_spread(it->blocks, &it->step, it->x);
  return it->chord_mode == MRVI_CHORD_ON || e <= it->step.tuning.chord_max;
}

void mrvi_integrator_set_chord(mrvi_integrator *it, int mode) {
  it->chord_mode = mode;
}

/* Whether the constant chord's mode and rule take a schur step's first
 * update (run constants alone). */
static int const_chord_rule(const mrvi_integrator *it) {
  const int mode = it->cchord_mode;
  return mode == MRVI_CHORD_ON ||
         (mode == MRVI_CHORD_AUTO &&
          it->cchord_e <= it->step.tuning.const_chord_max);
}

/* Whether the first update of a schur step takes the constant chord
 * (doc/solver.md, "Newton details"): by const_chord_rule, its factors
 * made on the first step that takes it. */
static int use_const_chord(mrvi_integrator *it) {
  if (!const_chord_rule(it))
    return 0;
  if (mrvi_blocks_const_factor(it->blocks, &it->step, it->x) != MRVI_OK)
    return 0;
  if (!it->cchord_made) {
    it->cchord_made = 1;
    it->n_factor++;
  }
  return 1;
}

void mrvi_integrator_set_const_chord(mrvi_integrator *it, int mode) {
  it->cchord_mode = mode;
}

/* Whether a schur step starts by shooting (doc/solver.md, "Newton
 * details"): where the predictor's sweep solves the fast rows exactly,
 * without control forces (the sweep does not see them), and where the
 * constant chord does not take the step (it is cheaper there). */
static int use_shoot(const mrvi_integrator *it) {
  const mrvi_step *st = &it->step;
  if (it->shoot_mode == MRVI_CHORD_OFF || !it->shoot_ok || st->f_rows ||
      st->f_end)
    return 0;
  return it->shoot_mode == MRVI_CHORD_ON || !const_chord_rule(it);
}

int mrvi_integrator_keep_micro(mrvi_integrator *it, int all) {
  const mrvi_step *st = &it->step;
  it->micro_all = all != 0;
  if (!it->sweep) { /* (the Newton paths solve all nodes at once: x keeps
                       them, the outputs do not) */
    it->jac_ready = 0;
    return all ? st->p : 1;
  }
  /* micro_q and micro_p resized to the rows kept (shrinking in place) */
  const size_t rows = all ? (size_t)st->p : 1, nf = (size_t)st->nf;
  double *q =
      realloc(it->micro_q, (rows * nf > 0 ? rows * nf : 1) * sizeof(double));
  if (q)
    it->micro_q = q;
  double *p =
      q ? realloc(it->micro_p, (rows * nf > 0 ? rows * nf : 1) * sizeof(double))
        : NULL;
  if (p)
    it->micro_p = p;
  /* x: the slow unknowns and the fast nodes kept */
  const size_t nx = (size_t)st->ns + rows * nf;
  double *x = p ? realloc(it->x, (nx > 0 ? nx : 1) * sizeof(double)) : NULL;
  if (x)
    it->x = x;
  if (!x) /* (growing failed: the last node alone is still kept) */
    return MRVI_ENOMEM;
  it->node_stride = all ? nf : 0;
  mrvi_sweep_set_last_only(it->sweep, !all);
  it->jac_ready = 0; /* (the last step's nodes are not all there) */
  return (int)rows;
}

void mrvi_integrator_set_shoot(mrvi_integrator *it, int mode) {
  it->shoot_mode = mode;
}

long mrvi_integrator_shoot_steps(const mrvi_integrator *it) {
  return it->n_shoot;
}

long mrvi_integrator_shoot_last_steps(const mrvi_integrator *it) {
  return it->n_shoot_last;
}

long mrvi_integrator_factorisations(const mrvi_integrator *it) {
  return it->n_factor;
}

/* A Newton-path step converged at x after iters updates, residual res:
 * the momenta at the new macro node and the fast micro nodes (eq:pkfm+;
 * their potential parts came with the last residual), the new state. */
static int accept_step(mrvi_integrator *it, int iters, double res) {
  it->last_iterations = iters;
  it->last_residual = res;
  mrvi_step_momenta_finish(&it->step, it->x, it->ps1, it->micro_p);
  to_positions(it);
  return finish_step(it);
}

/* Whether the next update keeps the factors (schur, schur-krylov and
 * schur-bordered paths; the general path, the reference, is full Newton):
 * where they contracted the residual well on the last update and, at that
 * rate, reach the target in two more.  The residual measured is the larger
 * of the dynamic rows' res and the constraint rows' cres (both before the
 * update: prev, cprev), these in the dynamic rows' units (tol / ctol
 * times their norm): on schur-bordered the constraint rows may be far
 * from converged where the dynamic rows are at round-off (trapezoidal
 * rules, whose dynamic rows are linear in the unknowns). */
static int keep_factors(const mrvi_integrator *it, double res, double cres,
                        double prev, double cprev, double tol, int iter) {
  const mrvi_tuning *tn = &it->step.tuning;
  const double r = cres > res ? cres : res, rp = cprev > prev ? cprev : prev;
  /* (the constant chord's factors: only if one more update reaches
   * the target at that rate; else an exact update from here costs
   * less than the kept factors' slow linear convergence) */
  const double rate = r / rp, target = tn->reuse_tighten * tol;
  const double phi = it->bordered && tn->keep_by_cost && tn->reuse_rate > 0.0
                         ? mrvi_bordered_refactor_cost(it->bordered)
                         : 0.0;
  if (phi > 0.0) {
    /* By cost (the chain elimination, whose factorisation costs phi kept
     * updates): kept while the updates that reach the target at this
     * contraction, m, cost less than a factorisation and its update (a
     * fresh update's own contraction taken as reaching it at once), and
     * within the iteration limit (a residual at its rounding floor stalls
     * and ends the step there: newton_step). */
    if (!(rate < 1.0))
      return 0;
    const double m = r > target ? ceil(log(target / r) / log(rate)) : 1.0;
    return m <= 1.0 + phi && iter + m < it->settings.newton_max_iter;
  }
  return !(rate > tn->reuse_rate ||
           r * rate * (it->const_kept ? 1.0 : rate) > target);
}

/* A step of the Newton paths. */
static int newton_step(mrvi_integrator *it) {
  mrvi_step *st = &it->step;
  const double tol = it->settings.newton_tol;
  const mrvi_tuning *tn = &st->tuning;
  const double ctol = it->settings.constraint_tol;
  const int max_it = it->settings.newton_max_iter;
  char msg[400];
  msg[0] = '\0';
  it->jac_ready = 0;
  count_step(it);

  /* Predictor for x, the multipliers from zero (or, with the joint sweep,
   * from the predictor's).  Nothing is carried from the last step
   * (multipliers, factors), so a step depends on (q_k, p_k) alone: a
   * restarted or resumed run continues bit for bit. */
  const int shoot = it->blocks && use_shoot(it);
  if (st->n_lambda > 0)
    memset(it->x + st->n_unknowns, 0, (size_t)st->n_lambda * sizeof(double));
  if (!shoot)
    predict(it);
  if (!shoot && it->settle_q)
    settle_predictor(it);
  if (it->nullspace && mrvi_nullspace_reparametrised(it->nullspace))
    mrvi_nullspace_start(it->nullspace, st, it->x);
  it->factors_ok = 0;
  /* Shooting on the slow unknowns: accepted where the exact residual is
   * within the tolerance after it; else Newton goes on from its iterate
   * (or from the predictor again after non-finite values). */
  int shot = 0;
  if (shoot) {
    it->step.increments = 1;
    const int sh =
        mrvi_predict_shoot(it->predictor, st, it->x, tn->reuse_tighten * tol,
                           tn->shoot_max, &shot);
    if (sh > 0) {
      double r0, c0;
      if (evaluate_momenta(it, &r0, &c0, msg, sizeof msg) == MRVI_OK &&
          r0 <= tn->reuse_tighten * tol) {
        it->n_shoot++;
        it->n_shoot_last += sh == 2;
        return accept_step(it, shot, r0);
      }
    } else if (sh < 0 || shot == 0) {
      predict(it);
    }
    /* (else Newton from the last iterate) */
  }
  /* schur-krylov's matrix-free outer iteration (solver/outer.c), to
   * reuse_tighten times the tolerance as Newton: its residual is the
   * step's at its solution (every row evaluated there, by the compiled
   * terms), with the potential parts of the momenta; where it does not
   * converge, Newton from the predictor. */
  if (it->outer && !st->f_rows && !st->f_end) {
    double r0 = 0.0;
    const int k = mrvi_outer_solve(it->outer, st, it->x, it->rinv,
                                   tn->reuse_tighten * tol, tn->outer_rate,
                                   tn->outer_max, it->ps1, it->micro_p, &r0);
    if (k > 0)
      return accept_step(it, k, r0);
    predict(it);
  }
  /* (schur-krylov's Newton built on the first step that needs it) */
  int s = it->path == MRVI_PATH_SCHUR_KRYLOV
              ? skrylov_newton(it, msg, sizeof msg)
              : MRVI_OK;
  if (s < 0)
    return fail(it, s, "step %ld (t = %.10g): %s", it->k + 1,
                it->t0 + (double)it->k * st->dT, msg);
  /* The constant chord: its factors stand for the kept ones of this
   * step, so that the first update uses them (prev = INFINITY: rate 0)
   * and the reuse rule below decides the next; else the Jacobian at the
   * predictor, assembled with its residual, for the first update. */
  const int cc = it->blocks && use_const_chord(it);
  it->const_kept = it->factors_ok = cc;
  if (it->blocks && !cc)
    mrvi_blocks_chord(it->blocks, use_chord(it));
  s = evaluate(it, !cc, msg, sizeof msg);
  int iter = 0, fresh = 0, jac_at_x = !cc;
  double res, cres, prev = INFINITY, pprev = 0.0, cprev = 0.0;
  residual_norms(it, &res, &cres);
  double best = res; /* the smallest residual of the step, at update */
  int best_iter = 0; /* best_iter (for the failure message) */
  /* Converged at the tolerance after at least one update (the predictor is
   * never accepted), or stalled at the roundoff floor after one (counted:
   * mrvi_integrator_roundoff_steps).  On the schur and schur-bordered
   * paths the factors of the first update are kept for the further updates
   * of the step while they contract the residual by reuse_rate per update
   * (simplified Newton; the residual is exact, so the converged solution is
   * the same) and refactorised otherwise (keep_factors).  Updates stop at
   * reuse_tighten times the tolerance (after kept factors, the constraint
   * rows too: they converge linearly, and a step left just below the
   * constraint tolerance drifts from full Newton's by that much per step);
   * or, the tolerance met, once a full Newton update contracts
   * the residual by less than 1/floor_rate (the rounding floor, which on
   * long chains lies near reuse_tighten times the tolerance:
   * doc/solver.md, "Newton details"); or when they stall at the roundoff
   * floor (counted if that is above the tolerance); or at the iteration
   * limit if the tolerance itself is met: a last update with kept factors
   * is cheap, and it takes the error as far below the tolerance as a full
   * Newton update typically lands. */
  int exact = 0; /* the last update was a full Newton update */
  while (s == MRVI_OK) {
    if (iter >= 1 && cres <= ctol) {
      const int tight = exact || cres <= tn->reuse_tighten * ctol;
      if (res <= tn->reuse_tighten * tol && tight)
        break;
      /* (the tolerance met and a full update contracted by less than
       * 1/floor_rate, or by less than the full update before it: Newton's
       * quadratic contraction has stopped, the residual is at the rounding
       * floor of its rows, and further updates only stir it) */
      if (exact && tn->floor_rate > 0.0 && res <= tol &&
          (res > tn->floor_rate * prev || res * pprev > prev * prev))
        break;
      if (tight && res <= residual_floor(it) && res > 0.5 * prev) {
        if (res > tol)
          it->roundoff_steps++;
        break;
      }
      if (iter == max_it && res <= tol)
        break;
    }
    if (!isfinite(res) || !isfinite(cres) || iter == max_it) {
      const int finite = isfinite(res) && isfinite(cres);
      it->last_iterations = iter;
      it->last_residual = res;
      char extra[300] = "";
      if (st->n_lambda > 0)
        mrvi_fmt(extra, sizeof extra,
                 ", constraint residual %.3e (tolerance %.3e)", cres, ctol);
      /* (Newton stagnant for many updates above the tolerance: no root
       * near the start, as where a macro step is beyond the scheme's step
       * size limit; doc/solver.md, "Newton details") */
      const size_t used = strlen(extra);
      if (finite && iter - best_iter >= 5 && best > tol)
        mrvi_fmt(extra + used, sizeof extra - used,
                 "; the residual has not fallen below %.3e (update %d) "
                 "since: the step equations may have no solution near the "
                 "predictor at this macro step (a smaller "
                 "integrator.macro_step may help)",
                 best, best_iter);
      return fail(it, finite ? MRVI_ENEWTON : MRVI_ENONFINITE,
                  "step %ld (t = %.10g -> %.10g): Newton %s after %d "
                  "iterations, residual %.3e (tolerance %.3e, roundoff floor "
                  "%.1e)%s",
                  it->k + 1, it->t0 + (double)it->k * st->dT,
                  it->t0 + (double)(it->k + 1) * st->dT,
                  finite ? "did not converge" : "produced non-finite values",
                  iter, res, tol, residual_floor(it), extra);
    }
    fresh = !it->ops->keeps_factors || !it->factors_ok ||
            !keep_factors(it, res, cres * (tol / ctol), prev,
                          cprev * (tol / ctol), tol, iter);
    /* (full Newton: the general path always; schur-bordered where it
     * refactorises (always at the iterate); schur where it refactorises at
     * the iterate, not on its first update, which may take a chord; not
     * schur-krylov, whose GMRES is inexact) */
    const int was_exact = exact;
    exact = !it->ops->keeps_factors ||
            (fresh && (it->bordered || (it->blocks && !jac_at_x)));
    pprev = exact && was_exact ? prev : 0.0;
    prev = res;
    cprev = cres;
    s = newton_update(it, fresh, jac_at_x, msg, sizeof msg);
    if (s < 0)
      break;
    iter++;
    /* The residual at the update, with the potential parts of the momenta
     * (used if it converges). */
    s = evaluate_momenta(it, &res, &cres, msg, sizeof msg);
    jac_at_x = 0;
    if (res < best) {
      best = res;
      best_iter = iter;
    }
  }
  if (s < 0) {
    it->last_iterations = iter;
    it->last_residual = res;
    if (s == MRVI_ESINGULAR)
      explain_singular(it, msg, sizeof msg);
    return fail(it, s, "step %ld (t = %.10g): %s, residual %.3e", it->k + 1,
                it->t0 + (double)it->k * st->dT, msg, res);
  }
  return accept_step(it, iter + shot, res);
}

/* A macro step.  Torsional springs are evaluated on this integrator's
 * branches (the model's elements are shared by every integrator of the
 * model), which then follow the new node; a step that turns one by pi/2
 * or more could have jumped a branch and is refused. */
int mrvi_integrator_step(mrvi_integrator *it) {
  if (it->n_torsion == 0)
    return it->ops->step(it);
  const mrvi_model *m = it->model;
  mrvi_model_torsion_set(m, it->torsion);
  const int st = it->ops->step(it);
  if (st < 0)
    return st;
  int worst;
  const double turn = mrvi_model_torsion_follow(m, it->q, it->torsion, &worst);
  if (turn >= 0.5 * M_PI) {
    char what[300];
    mrvi_model_describe_element(m, worst, what, sizeof what);
    return fail(it, MRVI_ENEWTON,
                "step %ld: the %s turned by %.3g rad in one macro step (at "
                "most pi/2 are followed: reduce integrator.macro_step)",
                it->k, what, turn);
  }
  return MRVI_OK;
}

/* The new state (x, ps1 and xf, pf1: the last fast node) into the rate
 * blocks qs, qf, ps, pf (in the packed layout: q and p), the last one
 * into qs_prev, qf_prev where the micro nodes are kept (only the step
 * Jacobian needs it, mrvi_integrator_jacobian_solve, and it needs every
 * node) and the fast nodes into micro_q (the last alone: micro_q is qf,
 * mrvi_integrator_micro_q), for ns, nf constants for small blocks. */
ALWAYS_INLINE void new_state_blocks(mrvi_integrator *it, const double *xf,
                                    const double *pf1, const int ns,
                                    const int nf) {
  const int p = it->step.p;
  double *restrict qs = it->qs, *restrict ps = it->ps, *restrict qf = it->qf,
                   *restrict pf = it->pf, *restrict prev = it->qs_prev;
  const double *restrict x = it->x, *restrict ps1 = it->ps1;
  if (it->micro_all) {
    UNROLL
    for (int i = 0; i < ns; i++)
      prev[i] = qs[i];
    UNROLL
    for (int i = 0; i < nf; i++)
      prev[ns + i] = qf[i];
    copy_pairs(it->micro_q, x + ns, (size_t)p * (size_t)nf);
  }
  UNROLL
  for (int i = 0; i < ns; i++) {
    qs[i] = x[i];
    ps[i] = ps1[i];
  }
  UNROLL
  for (int i = 0; i < nf; i++) {
    qf[i] = xf[i];
    pf[i] = pf1[i];
  }
}

/* Common end of a step: outputs, new state, projection. */
static int finish_step_general(mrvi_integrator *it) {
  const mrvi_model *m = it->model;
  mrvi_step *st = &it->step;
  if (st->n_lambda > 0)
    constraint_outputs(it);
  if (st->r_micro > 0 && it->settings.project_momenta && it->micro_all &&
      project_micro(it) < 0)
    return fail(it, MRVI_ESINGULAR,
                "step %ld: micro-node momentum projection failed (fast "
                "constraint gradients dependent)",
                it->k + 1);
  const int ns = st->ns, nf = st->nf, p = st->p;
  /* The new state in rate blocks and model order, the last one kept (loops:
   * these copies are short, a call each would cost more than the copying at
   * p = 1). */
  const size_t last = (size_t)(p - 1) * it->node_stride;
  const double *xf = it->x + ns + last, *pf1 = it->micro_p + last;
  SMALL2(ns, NS, nf, NF, new_state_blocks(it, xf, pf1, NS, NF));
  if (!it->packed && !it->blocks_only) {
    for (int i = 0; i < ns; i++) {
      it->q[m->slow_index[i]] = it->qs[i];
      it->p[m->slow_index[i]] = it->ps[i];
    }
    for (int i = 0; i < nf; i++) {
      it->q[m->fast_index[i]] = it->qf[i];
      it->p[m->fast_index[i]] = it->pf[i];
    }
  }
  if (m->n_constraints > 0 && it->settings.project_momenta) {
    if (project(it) < 0)
      return fail(it, MRVI_ESINGULAR,
                  "step %ld: momentum projection failed (constraint "
                  "gradients dependent at t = %.10g)",
                  it->k + 1, it->t0 + (double)(it->k + 1) * st->dT);
    split_state(it);
    for (int i = 0; i < nf; i++)
      it->micro_p[last + (size_t)i] = it->pf[i];
  }
  it->k++;
  it->jac_ready = 1;
  return MRVI_OK;
}

/* The new state of an unconstrained step whose last node alone was kept
 * (x is then ns + nf long, slow then fast, as the positions' block): the
 * positions by exchanging x with that block (q where packed, else the
 * block of qs and qf), the momenta by exchanging ps1 and micro_p with ps
 * and pf where not packed (packed: copied into p), so that the step's
 * results are not copied again. */
static void swap_state(mrvi_integrator *it) {
  mrvi_step *st = &it->step;
  const int ns = st->ns, nf = st->nf;
  double *const x = it->x;
  if (it->packed) {
    it->x = it->q;
    it->q = x;
    it->ps = it->p;
    it->pf = it->p + ns;
    copy_pairs(it->ps, it->ps1, (size_t)ns);
    copy_pairs(it->pf, it->micro_p, (size_t)nf);
  } else {
    it->x = it->qs;
    double *const ps = it->ps, *const pf = it->pf;
    it->ps = it->ps1;
    it->ps1 = ps;
    it->pf = it->micro_p;
    it->micro_p = pf;
  }
  it->qs = x;
  it->qf = x + ns;
  st->qs0 = it->qs;
  st->qf0 = it->qf;
  st->ps0 = it->ps;
  st->pf0 = it->pf;
}

ALWAYS_INLINE int finish_step(mrvi_integrator *it) {
  const mrvi_step *st = &it->step;
  if (!(it->packed || it->blocks_only) || it->model->n_constraints > 0)
    return finish_step_general(it);
  /* Unconstrained, in rate blocks (model order is q and p, or gathered
   * when asked): the new state only. */
  const int ns = st->ns, nf = st->nf, p = st->p;
  const size_t last = (size_t)(p - 1) * it->node_stride;
  const double *xf = it->x + ns + last, *pf1 = it->micro_p + last;
  if (it->node_stride == 0)
    swap_state(it);
  else
    SMALL2(ns, NS, nf, NF, new_state_blocks(it, xf, pf1, NS, NF));
  it->k++;
  it->jac_ready = 1;
  return MRVI_OK;
}

double mrvi_integrator_time(const mrvi_integrator *it) {
  return it->t0 + (double)it->k * it->settings.macro_step;
}
long mrvi_integrator_step_index(const mrvi_integrator *it) { return it->k; }
/* v (model order) from its rate blocks vs and vf, where the steps keep the
 * state in those alone (blocks_only); else v is the state itself. */
static const double *model_order(const mrvi_integrator *it, double *v,
                                 const double *vs, const double *vf) {
  const mrvi_model *m = it->model;
  if (!it->blocks_only)
    return v;
  for (int i = 0; i < m->n_slow; i++)
    v[m->slow_index[i]] = vs[i];
  for (int i = 0; i < m->n_fast; i++)
    v[m->fast_index[i]] = vf[i];
  return v;
}
const double *mrvi_integrator_q(const mrvi_integrator *it) {
  return model_order(it, it->q, it->qs, it->qf);
}
const double *mrvi_integrator_p(const mrvi_integrator *it) {
  return model_order(it, it->p, it->ps, it->pf);
}
/* (the last node alone kept: the new state's fast part) */
const double *mrvi_integrator_micro_q(const mrvi_integrator *it) {
  return it->micro_all ? it->micro_q : it->qf;
}
const double *mrvi_integrator_micro_p(const mrvi_integrator *it) {
  return it->micro_all ? it->micro_p : it->pf;
}
const double *mrvi_integrator_step_multipliers(const mrvi_integrator *it) {
  return it->x + it->step.n_unknowns;
}
const double *mrvi_integrator_lambda(const mrvi_integrator *it) {
  return it->lambda;
}
const double *
mrvi_integrator_micro_constraint_residual(const mrvi_integrator *it) {
  return it->micro_cres;
}
int mrvi_integrator_last_iterations(const mrvi_integrator *it) {
  return it->last_iterations;
}
double mrvi_integrator_last_residual(const mrvi_integrator *it) {
  return it->last_residual;
}
int mrvi_integrator_system_size(const mrvi_integrator *it) {
  return it->nullspace ? mrvi_nullspace_size(it->nullspace) : it->step.n_total;
}
long mrvi_integrator_system_nnz(const mrvi_integrator *it) {
  return it->nullspace ? mrvi_nullspace_nnz(it->nullspace) : it->step.nnz;
}
int mrvi_integrator_timing(const mrvi_integrator *it, double *assemble,
                           double *solve) {
  double a = it->t_assemble, s = it->t_solve;
  int estimated = it->timing_estimated;
  if (!it->block_exact && it->block_n > 1) { /* the block under way */
    double ba, bs;
    block_estimate(it, mrvi_clock(), &ba, &bs);
    a += ba;
    s += bs;
    estimated = 1;
  }
  if (assemble)
    *assemble = a;
  if (solve)
    *solve = s;
  return estimated;
}

const char *mrvi_integrator_solver_path(const mrvi_integrator *it) {
  return mrvi_path_name(it->path);
}

void mrvi_integrator_krylov_stats(const mrvi_integrator *it,
                                  mrvi_krylov_stats *out) {
  const mrvi_krylov_stats *k = it->skrylov ? mrvi_skrylov_stats(it->skrylov)
                                           : mrvi_sweep_stats(it->sweep);
  if (k)
    *out = *k;
  else
    memset(out, 0, sizeof *out);
  out->newton_built = it->skrylov != NULL;
  if (it->sweep) {
    mrvi_sweep_evals(it->sweep, &out->sweep_evals_w, &out->sweep_evals_v);
    out->sweep_products_w = mrvi_sweep_evals_lin(it->sweep);
    out->sweep_chord_sum = mrvi_sweep_chord_sum(it->sweep);
  }
  if (it->outer) {
    const mrvi_outer_stats *o = mrvi_outer_stats_of(it->outer);
    out->outer_fallbacks = o->failed;
    out->outer_steps = o->steps - out->outer_fallbacks;
    out->outer_sweeps = o->sweeps;
    out->outer_evals = o->site_evals;
    out->outer_grad_equivalents = o->grad_equiv;
  }
}

int mrvi_integrator_jacobian_size(const mrvi_integrator *it) {
  return it->step.n_total;
}

int mrvi_integrator_jacobian_solve(mrvi_integrator *it, int transpose,
                                   const double *b, double *x) {
  mrvi_step *st = &it->step;
  char msg[300] = "";
  if (!it->jac_ready && it->k == 0)
    return fail(it, MRVI_EINVAL, "no completed step to solve with");
  if (it->jac_ready && !it->micro_all)
    return fail(it, MRVI_EINVAL,
                "the step's micro nodes were not kept "
                "(mrvi_integrator_keep_micro): no Jacobian to solve with");
  if (it->jac_ready == 1) {
    /* Assemble the full Jacobian at the last step's solution, with that
     * step's known data, and factorise it once for any number of solves
     * (schur-krylov: its elimination takes it, run backwards for J^T; the
     * next step takes its own Jacobian afresh). */
    const double *qs0 = st->qs0, *qf0 = st->qf0;
    st->qs0 = it->qs_prev;
    st->qf0 = it->qf_prev;
    int s = it->path == MRVI_PATH_SCHUR_KRYLOV
                ? skrylov_newton(it, msg, sizeof msg)
            : !st->Ap ? mrvi_step_build_pattern(st, it->x)
                      : MRVI_OK;
    if (s < 0) {
      st->qs0 = qs0;
      st->qf0 = qf0;
      return fail(it, s, "%s", msg[0] ? msg : "out of memory");
    }
    if (!it->ops->update && !it->jac_nw) { /* (a sweep path: see create) */
      double *dx = realloc(it->dx, (size_t)st->n_total * sizeof *dx);
      if (!dx) {
        st->qs0 = qs0;
        st->qf0 = qf0;
        return fail(it, MRVI_ENOMEM, "out of memory");
      }
      it->dx = dx;
    }
    mrvi_step_assemble(st, it->x, it->dx, 1);
    st->qs0 = qs0;
    st->qf0 = qf0;
    if (it->skrylov)
      mrvi_skrylov_factor(it->skrylov);
    else if (!it->jac_nw &&
             !(it->jac_nw = mrvi_newton_create(
                   st->n_total, st->Ap, st->Ai, st->Ax,
                   st->tuning.newton_dense_max, msg, sizeof msg)))
      return fail(it, MRVI_ESINGULAR, "%s", msg);
    else if ((s = mrvi_newton_factor(it->jac_nw, st->Ax, msg, sizeof msg)) < 0)
      return fail(it, s, "step Jacobian: %s", msg);
    it->jac_ready = 2;
  }
  if (it->jac_ready != 2)
    return fail(it, MRVI_EINVAL, "the step Jacobian is no longer available");
  const int s = it->skrylov ? mrvi_skrylov_solve(it->skrylov, transpose, b, x,
                                                 msg, sizeof msg)
                            : mrvi_linsolve_solve(it->jac_nw, st->Ax, transpose,
                                                  b, x, msg, sizeof msg);
  return s < 0 ? fail(it, s, "step Jacobian: %s", msg) : MRVI_OK;
}

void mrvi_integrator_set_forces(mrvi_integrator *it, const double *f_rows,
                                const double *f_end) {
  it->step.f_rows = f_rows;
  it->step.f_end = f_end;
}

long mrvi_integrator_roundoff_steps(const mrvi_integrator *it) {
  return it->roundoff_steps;
}

/* The paths, by MRVI_PATH_* (their names: mrvi_path_name). */
static const path_ops paths[MRVI_N_PATHS] = {
    [MRVI_PATH_GENERAL] = {general_create, newton_step, general_assemble,
                           general_update, general_free, 0},
    [MRVI_PATH_EXPLICIT] = {sweep_create, structured_step, NULL, NULL,
                            sweep_free, 0},
    [MRVI_PATH_SWEEP] = {sweep_create, structured_step, NULL, NULL, sweep_free,
                         0},
    [MRVI_PATH_SCHUR] = {schur_create, newton_step, schur_assemble,
                         schur_update, schur_free, 1},
    [MRVI_PATH_SWEEP_CG] = {sweep_create, structured_step, NULL, NULL,
                            sweep_free, 0},
    [MRVI_PATH_SCHUR_KRYLOV] = {skrylov_create, newton_step, csc_assemble,
                                skrylov_update, skrylov_free, 1},
    [MRVI_PATH_SCHUR_BORDERED] = {bordered_create, newton_step, csc_assemble,
                                  bordered_update, bordered_free, 1},
};

static const path_ops *path_ops_of(int path) { return &paths[path]; }
