/* Predictor of the Newton paths (doc/solver.md): an explicit multirate
 * sweep from the known data of the step, written as displacements from
 * (q_k^s, q_k^{f,0}) (mrvi_step.increments).  It walks the rows of the step
 * (step.c) in the order of the micro nodes, with the quadrature points of
 * both potentials evaluated where they are known or well estimated:
 *
 *   slow row    p_k^s - M^s dq^s/dT - sum_pts w a0 grad_s Z(z) = 0, first
 *               with every point at node k (exact for the macro-grid rule,
 *               whose slow row holds node k only; a Stoermer-Verlet position
 *               update on the micro grid);
 *   fast row m  p^{f,m} - M^f (d^{m+1} - d^m)/dt - F_m^A = 0, F_m^A the sum
 *               over the points of interval m of w cA grad_f Z(z), with the
 *               implicit points (cA cB != 0) at the estimate d^{m+1} of the
 *               implicit force (in interval 0 its value at node k, in
 *               interval 1 interval 0's, then extrapolated from the last
 *               two intervals'); then
 *               p^{f,m+1} = M^f (d^{m+1} - d^m)/dt - F_m^B (eq:pkfm+).
 *
 * Rectangle and trapezoidal rules are reproduced exactly (their points lie
 * on nodes); for the midpoint rule the error of a row is w cA cB hess Z
 * times the estimate's error, a factor (omega dt)^2/4 below it.  Where the
 * slow row sees the micro nodes (V on the micro grid, or W depending on slow
 * coordinates), it is solved again with the forces of its points along the
 * swept path (summed during the sweep).  Cost: the gradients of V and W at
 * node k once (node_gradients_k: the slow row's first solve, interval 0's
 * estimate and the points at node k) and one evaluation of the gradients
 * at every other point, no Jacobian.
 *
 * Where the slow row is still far from solved after that (a large dT
 * with a non-linear V), it is solved by Broyden's method on a sample of
 * its points with the fast nodes held, and the fast nodes swept again
 * (slow_newton); where the slow row is known to be far from the
 * Stoermer-Verlet estimate (the fixed-point contraction at q0) and W has
 * a constant Hessian, it is solved before the sweep on a cheap linear
 * sweep of the fast nodes instead, so that the one sweep runs along a
 * slow path close to the solution (pre_solve).
 *
 * The sweep is explicit: it is used only where dt omega_max <= 1/2 at the
 * initial state (omega_max the largest frequency of hess(V + W) in the mass
 * metric, by power iteration), else, and for a step where it produces
 * non-finite values, free flight is the predictor. */
#include "solver/solver.h"
#include "util/small.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The tuning constants this file reads (mrvi.h, MRVI_TUNING_LIST; pr->tn);
 * what their defaults were measured on is in doc/performance/paths.md, "Tuning
 * constants: what the defaults were measured on":
 *  - slow_newton_max, slow_newton_n, slow_samples, slow_hess_samples: slow
 *    Newton steps of the predictor (slow_newton) take at most
 *    slow_newton_max Broyden iterations per solve, on models of at most
 *    slow_newton_n coordinates (the Hessian sum is dense), with at most
 *    slow_samples sampled points (enough to keep one Newton update per step
 *    at dT = 1) and the first Jacobian's Hessian from slow_hess_samples of
 *    them.
 *  - pre_kappa: the slow pre-solve (pre_solve) is used where dT^2 |M_s^-1
 *    hess_ss V| / 3 at the initial state, the fixed-point update's
 *    contraction factor kappa (row-sum norm), is above this.
 *  - shoot_pre_kappa: ... and before shooting (mrvi_predict_shoot) above
 *    this: the pre-solve lets the last update go without a sweep, where
 *    Newton's predictor saves no update by it.
 *  - shoot_kappa: shooting (mrvi_predict_shoot) is offered where kappa is
 *    at most this.
 *  - shoot_hess_kappa: ... and its Jacobian takes the sampled Hessian
 *    where kappa is above this (below, M / dT alone)
 *  - shoot_full_kappa: ... and the Hessians of every point where it is
 *    above this: the sampled Hessian misses the fast oscillation of hess V
 *    (summed from phi'' per term, mrvi_terms_grad_d2).
 *  - shoot_last: ... and its last update is made without the sweep after
 *    it where the last contraction, repeated, and the fast rows' share (3
 *    kappa / p of |G|, below) leave at most this times the target. */

/* Point kinds within an interval: at node m (cB = 0, explicit), inside
 * (cA cB != 0, implicit), at node m + 1 (cA = 0, momentum only). */
enum { AT_LEFT, INSIDE, AT_RIGHT };
static int kind(const mrvi_point *pt) {
  return pt->cB == 0.0 ? AT_LEFT : pt->cA == 0.0 ? AT_RIGHT : INSIDE;
}

struct mrvi_predictor {
  const mrvi_model *m;
  /* The micro-node constraints' moves (predict_joints.c; NULL: none) and
   * sweep_joints' row value u (nf). */
  mrvi_joint_sweep *js;
  double *ju;
  mrvi_tuning tn;   /* the step's tuning constants */
  int sweep_ok;     /* dt omega_max small enough for the explicit sweep */
  double omega;     /* omega_max at q0 (power_iteration, once), or an
                       upper bound that settles its tests (omega_bound) */
  int slow_coupled; /* the slow row sees the micro nodes */
  /* Vectors of n entries (model order in omega_max; packed (q^s, q^f) in
   * the sweep): configuration, gradient, slow-row force (ns), the explicit
   * and implicit parts of F_m^A, and F_m^B (nf each). */
  double *z, *g, *fs, *fexp, *fimp, *fb, *fimp1;
  /* The sweep in one parallel region of pthreads threads (sweep_par):
   * where each class is in parts (on threads) or empty, beyond the small
   * systems (so never with one). */
  int ppar, pthreads;
  double *pm;    /* p^{f,m} (nf) */
  double *H;     /* sum w a0 a1 hess Z along the sweep, packed (n x n, its
                    slow block; NULL for n > slow_newton_n: no Newton
                    steps), then a point's Hessian (n x n, point_gradient_k) */
  double *xs;    /* swept slow displacement, sampled forces (3 ns) */
  double *A, *b; /* slow Newton matrix (ns x ns), right-hand side and
                    fixed-point update (2 ns) */
  int *sample;   /* sampled points: ip of V, -1 - ip of W */
  int n_samples;
  int hstride; /* the Hessian from every hstride-th sample, */
  double hfac; /* scaled by hfac (choose_samples) */
  int h_ok;    /* H holds the sampled Hessian of this step (sampled_solve) */
  double sample_w[2]; /* weight of a sample relative to its point */
  double rstop;       /* slow-row residual above which the slow row is solved
                         by Newton steps (mrvi_predictor_set_tolerance) */
  double rsweep;      /* change of that solve above which the fast nodes are
                         swept again */
  double *minv;       /* 1 / mass, packed (n) */
  char *kinds[2];     /* kind of every point of V and W (see kind) */
  int has_kind[3];    /* some point of V or W is of that kind */
  mrvi_terms *kc[2];  /* V and W compiled on the packed columns (terms.c) */
  int *pend[2];       /* end of the points of interval m of V and W (p each) */
  /* A class with a constant Hessian on small blocks (ns, nf <= 4):
   * gradient g0 + Hq z (affine_grad_k), from column lo (the first fast
   * one if it has no slow inputs); Hq NULL otherwise. */
  double *g0[2], *Hq[2];
  int lo[2];
  int same; /* V and W have the same points (midpoint-midpoint): a point's
               two gradients are evaluated at one configuration, summed */
  /* Node k (node_gradients): the gradients of V and W there and, with
   * same, their sum (gnode, 3 n packed); the sums over a class's points
   * of w a0 (wnode: its slow-row force with every point at node k) and
   * over interval 0's implicit points of w cA (wins: their force F_0^A
   * estimated at node k, fimp0, nf). */
  double *gnode, *fimp0, wnode[2], wins[2];
  /* sweep1_k's vectors in its run-time-size copy (8 of n) */
  double *scr;
  int node_left; /* some point of interval 0 is at node k (AT_LEFT, a1 = 0) */
  /* The slow pre-solve (pre_solve): used at all (pre), done in this step
   * (presolved); the linear sweep's matrix K = (M^f/dt + S_AB H_ff)^-1
   * (nf x nf) and interval sums lsum (see linear_step); the slow-row
   * force of the points with a0 a1 != 0 at node k (fk, ns; V's gradient
   * there is gnode's first n) and their sums of w a0 per class (wk),
   * and the weight of a sample in the absolute force (sample_f). */
  int pre, presolved, n_sweeps;
  double *K, lsum[8], *fk, wk[2], sample_f[2];
  /* The nodes the samples read (jnode, n_jumps of them, increasing) and
   * the affine maps of the linear sweep from one to the next: the state
   * (d, p^f) (2 nf) goes to M s + S c with c = (c_A, c_B) (see
   * linear_nodes_k), M and S 2 nf x 2 nf each, in jmat. */
  int n_jumps, *jnode;
  double *jmat;
  /* One point per micro interval in each class (one_point): the kind of
   * class c's points (AT_LEFT or INSIDE; -1 for a class not evaluated on
   * its own: W with same, or a class without elements), for sweep1_k;
   * one_ok: chosen at creation (one: taken, mrvi_predictor_one_point). */
  int one, one_ok, one_kind[2];
  /* W has a constant Hessian on the fast columns alone (Hq[1], lo[1] = ns)
   * that is diagonal (a sum of one-coordinate quadratics, the FPU's): its
   * gradient g0 + H z by the diagonal alone. */
  int wdiag;
  /* With one: W's points are inside the intervals, V's are not, and W is
   * wdiag: sweep1_k solves each row exactly (W's force affine in
   * d^{m+1}), so that shooting applies. */
  int wexact;
  double kappa; /* slow_kappa (with H) */
  /* The sweep adds every point's w a0 a1 hess_ss Z to H (shooting's
   * Jacobian at large dT); a flat class's (dsum[c] not NULL,
   * one entry per term) as w a0 a1 phi'' per term into dsum[c], formed
   * into H after the sweep (mrvi_terms_hess_d2). */
  int hsum;
  double *dsum[2];
};

/* Whether an element of class c (0: V, 1: W) has a slow input. */
static int class_sees_slow(const mrvi_model *m, const mrvi_step *st, int c) {
  for (int ie = 0; ie < st->n_elem_of_class[c]; ie++)
    if (mrvi_model_element_rates(m, MRVI_STEP_ELEM(st, c, ie)) &
        (1 << MRVI_SLOW))
      return 1;
  return 0;
}

/* The points whose force on the slow row changes with q_{k+1}^s
 * (a0 a1 != 0, of a class with a slow input), every stride-th of each
 * class, stride such that at most slow_samples are taken in all; a
 * sample stands for the points around it by the ratio of the sums of
 * w a0 a1. */
static void choose_samples(mrvi_predictor *pr, const mrvi_step *st) {
  int slow_in[2] = {0, 0}, count = 0;
  for (int c = 0; c < 2; c++) {
    slow_in[c] = class_sees_slow(pr->m, st, c);
    for (int ip = 0; slow_in[c] && ip < st->n_pts[c]; ip++)
      count += st->pts[c][ip].a0 * st->pts[c][ip].a1 != 0.0;
  }
  const int stride = (count + pr->tn.slow_samples - 1) / pr->tn.slow_samples;
  pr->n_samples = 0;
  for (int c = 0; c < 2; c++) {
    /* (all, taken: sums of w a0 a1; fa, ft: of w a0, for sample_f) */
    double all = 0.0, taken = 0.0, fa = 0.0, ft = 0.0;
    for (int ip = 0, j = 0; slow_in[c] && ip < st->n_pts[c]; ip++) {
      const mrvi_point *pt = &st->pts[c][ip];
      const double w = pt->w * pt->a0 * pt->a1;
      if (w == 0.0)
        continue;
      all += w;
      fa += pt->w * pt->a0;
      if (j++ % stride == stride / 2) {
        taken += w;
        ft += pt->w * pt->a0;
        pr->sample[pr->n_samples++] = c == 0 ? ip : -ip - 1;
      }
    }
    pr->sample_w[c] = taken != 0.0 ? all / taken : 0.0;
    pr->sample_f[c] = ft != 0.0 ? fa / ft : 0.0;
    pr->wk[c] = fa;
  }
  /* The Hessian (the first Jacobian of sampled_solve) from every
   * hstride-th sample, scaled to the sum of all samples' w a0 a1. */
  pr->hstride =
      (pr->n_samples + pr->tn.slow_hess_samples - 1) / pr->tn.slow_hess_samples;
  if (pr->hstride < 1)
    pr->hstride = 1;
  double all = 0.0, taken = 0.0;
  for (int i = 0; i < pr->n_samples; i++) {
    const int c = pr->sample[i] < 0 ? 1 : 0;
    const int ip = pr->sample[i] < 0 ? -pr->sample[i] - 1 : pr->sample[i];
    const mrvi_point *pt = &st->pts[c][ip];
    const double w = pr->sample_w[c] * pt->w * pt->a0 * pt->a1;
    all += w;
    if (i % pr->hstride == pr->hstride / 2)
      taken += w;
  }
  pr->hfac = taken != 0.0 ? all / taken : 1.0;
}

/* Whether every interval has the points of interval 0 (the same w, cA,
 * cB in the same order) in class c. */
static int uniform_intervals(const mrvi_predictor *pr, const mrvi_step *st,
                             int c) {
  const int n0 = pr->pend[c][0];
  for (int mm = 1; mm < st->p; mm++) {
    const int first = pr->pend[c][mm - 1];
    if (pr->pend[c][mm] - first != n0)
      return 0;
    for (int i = 0; i < n0; i++) {
      const mrvi_point *a = &st->pts[c][i], *b = &st->pts[c][first + i];
      if (a->w != b->w || a->cA != b->cA || a->cB != b->cB)
        return 0;
    }
  }
  return 1;
}

/* One micro step of the linear sweep (linear_nodes_k): the state
 * s = (d^m, p^{f,m}) becomes (d^{m+1}, p^{f,m+1}),
 *   (M/dt + S_AB H) d^{m+1} = p^m + M d^m / dt - c_A - S_AA H d^m,
 *   p^{m+1} = M (d^{m+1} - d^m) / dt - c_B - S_BA H d^m - S_BB H d^{m+1},
 * with c = (c_A, c_B), H = H_ff of W and the sums S_AA = sum w cA cA,
 * S_AB = sum w cA cB, ... over an interval's W points (lsum). */
static void linear_step(const mrvi_predictor *pr, const mrvi_step *st,
                        double *s, const double *c) {
  const int ns = st->ns, nf = st->nf, nz = ns + nf;
  const double *H = pr->Hq[1] + (size_t)ns * nz + ns, *L = pr->lsum;
  double hd[4], r[4], dn[4];
  for (int f = 0; f < nf; f++) {
    hd[f] = 0.0;
    for (int j = 0; j < nf; j++)
      hd[f] += H[f * nz + j] * s[j];
  }
  for (int f = 0; f < nf; f++)
    r[f] = s[nf + f] + s[f] / (st->dt * pr->minv[ns + f]) - c[f] - L[1] * hd[f];
  for (int f = 0; f < nf; f++) {
    dn[f] = 0.0;
    for (int j = 0; j < nf; j++)
      dn[f] += pr->K[f * nf + j] * r[j];
  }
  for (int f = 0; f < nf; f++) {
    double hn = 0.0;
    for (int j = 0; j < nf; j++)
      hn += H[f * nz + j] * dn[j];
    s[nf + f] = (dn[f] - s[f]) / (st->dt * pr->minv[ns + f]) - c[nf + f] -
                L[4] * hd[f] - L[5] * hn;
  }
  for (int f = 0; f < nf; f++)
    s[f] = dn[f];
}

/* The nodes the samples read (d^m and d^{m+1} of a sample's interval m)
 * and the affine maps of the linear sweep between them (jnode, jmat),
 * composed from the one-step map s -> T s + P c.  0, or MRVI_ENOMEM. */
static int linear_jumps(mrvi_predictor *pr, const mrvi_step *st) {
  const int nf = st->nf, p = st->p, n2 = 2 * nf;
  const size_t sq = (size_t)n2 * (size_t)n2;
  char *need = calloc((size_t)p + 1, 1);
  double *T = malloc(6 * sq * sizeof(double));
  pr->jnode = malloc((size_t)(2 * pr->n_samples + 1) * sizeof(int));
  pr->jmat = malloc((size_t)(2 * pr->n_samples + 1) * 2 * sq * sizeof(double));
  if (!need || !T || !pr->jnode || !pr->jmat) {
    free(need);
    free(T);
    return MRVI_ENOMEM;
  }
  double *P = T + sq, *M = P + sq, *S = M + sq, *M1 = S + sq, *S1 = M1 + sq;
  for (int i = 0; i < pr->n_samples; i++) {
    const int c = pr->sample[i] < 0 ? 1 : 0;
    const int ip = pr->sample[i] < 0 ? -pr->sample[i] - 1 : pr->sample[i];
    need[st->pts[c][ip].m] = 1;
    need[st->pts[c][ip].m + 1] = 1;
  }
  /* T and P column by column */
  double e[8], z[8] = {0};
  for (int j = 0; j < n2; j++) {
    for (int i = 0; i < n2; i++)
      e[i] = i == j;
    linear_step(pr, st, e, z);
    for (int i = 0; i < n2; i++)
      T[i * n2 + j] = e[i];
    for (int i = 0; i < n2; i++)
      e[i] = 0.0;
    double cj[8] = {0};
    cj[j] = 1.0;
    linear_step(pr, st, e, cj);
    for (int i = 0; i < n2; i++)
      P[i * n2 + j] = e[i];
  }
  /* M = T^J, S = sum_{j < J} T^j P from the last needed node */
  pr->n_jumps = 0;
  for (size_t i = 0; i < sq; i++) {
    M[i] = i % (size_t)(n2 + 1) == 0;
    S[i] = 0.0;
  }
  for (int node = 1; node <= p; node++) {
    for (int i = 0; i < n2; i++)
      for (int j = 0; j < n2; j++) {
        double tm = 0.0, ts = P[i * n2 + j];
        for (int k = 0; k < n2; k++) {
          tm += T[i * n2 + k] * M[k * n2 + j];
          ts += T[i * n2 + k] * S[k * n2 + j];
        }
        M1[i * n2 + j] = tm;
        S1[i * n2 + j] = ts;
      }
    memcpy(M, M1, 2 * sq * sizeof(double)); /* M, S <- M1, S1 */
    if (!need[node])
      continue;
    pr->jnode[pr->n_jumps] = node;
    memcpy(pr->jmat + (size_t)pr->n_jumps * 2 * sq, M, 2 * sq * sizeof(double));
    pr->n_jumps++;
    for (size_t i = 0; i < sq; i++) {
      M[i] = i % (size_t)(n2 + 1) == 0;
      S[i] = 0.0;
    }
  }
  free(need);
  free(T);
  return 0;
}

/* The fixed-point update's contraction dT^2 |M_s^-1 hess_ss V(q0)|_inf / 3
 * at the initial state (a run constant; pr->H as scratch). */
static double slow_kappa(mrvi_predictor *pr, const mrvi_step *st) {
  const mrvi_model *m = pr->m;
  const int ns = st->ns, nz = ns + st->nf;
  /* hess_ss V at q0 (packed columns: q0 into pr->z) */
  for (int c = 0; c < m->n; c++)
    pr->z[(m->rate[c] == MRVI_SLOW ? 0 : ns) + m->slot[c]] = m->q0[c];
  memset(pr->g, 0, (size_t)nz * sizeof(double));
  memset(pr->H, 0, (size_t)nz * (size_t)nz * sizeof(double));
  mrvi_terms_eval(pr->kc[0], pr->z, 1.0, pr->g, pr->H, nz, 1.0);
  double norm = 0.0;
  for (int i = 0; i < ns; i++) {
    double r = 0.0;
    for (int j = 0; j < ns; j++)
      r += fabs(pr->H[i * nz + j]);
    norm = fmax(norm, r * pr->minv[i]);
  }
  return st->dT * st->dT * norm / 3.0;
}

/* The slow pre-solve (pre_solve) and its linear sweep: where W has a
 * constant Hessian and no slow input (Hq[1] on the fast columns), every
 * interval has the points of interval 0 and the fixed-point contraction
 * (slow_kappa) is above pre_kappa.  0, or MRVI_ENOMEM. */
static int linear_sweep_setup(mrvi_predictor *pr, const mrvi_step *st) {
  const int ns = st->ns, nf = st->nf, nz = ns + nf;
  if (!pr->Hq[1] || pr->lo[1] != ns || nf == 0 || ns == 0 || st->p < 1 ||
      !uniform_intervals(pr, st, 0) || !uniform_intervals(pr, st, 1))
    return 0;
  if (!(pr->kappa > fmin(pr->tn.pre_kappa, pr->tn.shoot_pre_kappa)))
    return 0;
  /* Interval sums: W's w cA, w cA cA, w cA cB, w cB, w cB cA, w cB cB,
   * V's w cA, w cB. */
  double *L = pr->lsum;
  memset(L, 0, sizeof pr->lsum);
  for (int c = 0; c < 2; c++)
    for (int i = 0; i < pr->pend[c][0]; i++) {
      const mrvi_point *pt = &st->pts[c][i];
      if (c == 1) {
        L[0] += pt->w * pt->cA;
        L[1] += pt->w * pt->cA * pt->cA;
        L[2] += pt->w * pt->cA * pt->cB;
        L[3] += pt->w * pt->cB;
        L[4] += pt->w * pt->cB * pt->cA;
        L[5] += pt->w * pt->cB * pt->cB;
      } else {
        L[6] += pt->w * pt->cA;
        L[7] += pt->w * pt->cB;
      }
    }
  /* K = (M^f/dt + S_AB H_ff)^-1, column by column (e after A) */
  double *A = malloc(((size_t)nf * (size_t)nf + (size_t)nf) * sizeof(double));
  int *piv = malloc((size_t)nf * sizeof(int));
  pr->K = malloc((size_t)nf * (size_t)nf * sizeof(double));
  if (!A || !piv || !pr->K) {
    free(A);
    free(piv);
    return MRVI_ENOMEM;
  }
  const double *Hff = pr->Hq[1] + (size_t)ns * nz + ns;
  for (int i = 0; i < nf; i++)
    for (int j = 0; j < nf; j++)
      A[i * nf + j] = L[2] * Hff[i * nz + j] +
                      (i == j ? 1.0 / (st->dt * pr->minv[ns + i]) : 0.0);
  int ok = mrvi_dense_lu_factor(nf, A, piv) == 0;
  for (int j = 0; ok && j < nf; j++) {
    double *e = A + (size_t)nf * (size_t)nf;
    for (int i = 0; i < nf; i++)
      e[i] = i == j;
    mrvi_dense_lu_solve(nf, A, piv, e, 1);
    for (int i = 0; i < nf; i++)
      pr->K[i * nf + j] = e[i];
  }
  free(A);
  free(piv);
  pr->pre = ok && linear_jumps(pr, st) == 0;
  return ok && !pr->pre ? MRVI_ENOMEM : 0;
}

/* Whether the sweep may take sweep1_k: fast coordinates, blocks of at most
 * 4, and in each class evaluated (class 0 alone with same) exactly one
 * point per micro interval, point m in interval m, all of one kind, at the
 * left end or inside (the midpoint rule, the trapezoidal rule of
 * alpha = gamma = 1 on the micro grid), with the same w, cA, cB. */
static void one_point(mrvi_predictor *pr, const mrvi_step *st) {
  pr->one = 0;
  if (st->nf < 1 || st->ns > 4 || st->nf > 4 || st->p < 1)
    return;
  for (int c = 0; c < 2; c++) {
    pr->one_kind[c] = -1;
    if ((c == 1 && pr->same) || st->n_elem_of_class[c] == 0)
      continue;
    for (int mm = 0; mm < st->p; mm++)
      if (pr->pend[c][mm] != mm + 1 || st->pts[c][mm].m != mm)
        return;
    const int k = pr->kinds[c][0];
    for (int mm = 1; mm < st->p; mm++)
      if (pr->kinds[c][mm] != k)
        return;
    if (k == AT_RIGHT || !uniform_intervals(pr, st, c))
      return;
    pr->one_kind[c] = k;
  }
  pr->one = 1;
}

static double power_iteration(mrvi_predictor *pr, double *Q, int nq,
                              double *wk);
static double omega_bound(mrvi_predictor *pr, const mrvi_step *st);

int mrvi_predictor_create(const mrvi_model *m, const mrvi_step *st,
                          mrvi_predictor **out) {
  mrvi_predictor *pr = calloc(1, sizeof *pr);
  *out = NULL;
  if (!pr)
    return MRVI_ENOMEM;
  const size_t n = (size_t)(m->n > 0 ? m->n : 1);
  pr->m = m;
  pr->tn = st->tuning;
  double **vec[] = {&pr->z,    &pr->g,  &pr->fs,    &pr->fexp,
                    &pr->fimp, &pr->fb, &pr->fimp1, &pr->fimp0};
  for (size_t i = 0; i < sizeof vec / sizeof *vec; i++)
    if (!(*vec[i] = malloc(n * sizeof(double)))) {
      mrvi_predictor_free(pr);
      return MRVI_ENOMEM;
    }
  if (!(pr->pm =
            malloc((size_t)(m->n_fast > 0 ? m->n_fast : 1) * sizeof(double))) ||
      !(pr->xs = malloc(3 * n * sizeof(double))) ||
      !(pr->b = malloc(4 * n * sizeof(double))) ||
      !(pr->fk = calloc(n, sizeof(double))) ||
      !(pr->gnode = calloc(3 * n, sizeof(double))) ||
      !(pr->scr = calloc(8 * n, sizeof(double)))) {
    mrvi_predictor_free(pr);
    return MRVI_ENOMEM;
  }
  /* Packed columns: q^s then q^f (as solver/blocks.c). */
  int *col = malloc(n * sizeof *col);
  pr->minv = malloc(n * sizeof(double));
  if (!col || !pr->minv) {
    free(col);
    mrvi_predictor_free(pr);
    return MRVI_ENOMEM;
  }
  for (int c = 0; c < m->n; c++) {
    col[c] = (m->rate[c] == MRVI_SLOW ? 0 : m->n_slow) + m->slot[c];
    pr->minv[col[c]] = 1.0 / MRVI_MASS(m, c);
  }
  /* Beyond the small systems (the affine classes of ns, nf <= 4 and the
   * slow Newton solve's Hessians up to slow_newton_n coordinates, below)
   * the classes' gradients alone: their compact records (16 or 24 bytes a
   * spring instead of 169), the same gradient bit for bit. */
  const int grad_only =
      !(st->ns <= 4 && st->nf <= 4) && m->n > pr->tn.slow_newton_n;
  for (int c = 0; c < 2; c++) {
    /* (a large spring class's gradient on the step's threads, in parts by
     * records as the outer iteration's, doubled until few records span
     * them: the same bits for every count) */
    const int made =
        mrvi_terms_create_range(m, st->elem_of_class[c], st->elem_first[c],
                                st->n_elem_of_class[c], col, grad_only ? 2 : 0,
                                &pr->kc[c]) == MRVI_OK;
    const int ok = made &&
                   mrvi_terms_set_threads_spread(
                       pr->kc[c], st->threads, st->tuning.thread_chunk, 0,
                       MRVI_TERMS_SPREAD) == MRVI_OK &&
                   (pr->kinds[c] = malloc((size_t)st->n_pts[c] + 1));
    if (!ok) {
      free(col);
      mrvi_predictor_free(pr);
      return MRVI_ENOMEM;
    }
    for (int i = 0; i < st->n_pts[c]; i++) {
      pr->kinds[c][i] = (char)kind(&st->pts[c][i]);
      pr->has_kind[(int)pr->kinds[c][i]] = 1;
    }
  }
  free(col);
  pr->ppar = grad_only;
  for (int c = 0; c < 2; c++) {
    const int parts = mrvi_terms_parts(pr->kc[c]) >= 2;
    pr->ppar &= parts || st->n_elem_of_class[c] == 0;
    if (parts && mrvi_terms_threads(pr->kc[c]) > pr->pthreads)
      pr->pthreads = mrvi_terms_threads(pr->kc[c]);
  }
  pr->ppar &= pr->pthreads > 1;
  for (int c = 0; c < 2; c++) {
    if (!(pr->pend[c] =
              malloc((size_t)(st->p > 0 ? st->p : 1) * sizeof(int)))) {
      mrvi_predictor_free(pr);
      return MRVI_ENOMEM;
    }
    for (int mm = 0, e = 0; mm < st->p; mm++) {
      while (e < st->n_pts[c] && st->pts[c][e].m == mm)
        e++;
      pr->pend[c][mm] = e;
    }
  }
  const size_t nz = (size_t)st->ns + (size_t)st->nf;
  for (int c = 0; c < 2 && st->ns <= 4 && st->nf <= 4 && nz > 0; c++) {
    if (!mrvi_terms_quadratic(pr->kc[c]))
      continue;
    const int slow = class_sees_slow(m, st, c);
    if (mrvi_terms_affine(pr->kc[c], (int)nz, &pr->g0[c], &pr->Hq[c]) !=
        MRVI_OK) {
      mrvi_predictor_free(pr);
      return MRVI_ENOMEM;
    }
    pr->lo[c] = slow ? 0 : st->ns;
  }
  pr->same = mrvi_step_same_points(st);
  pr->wdiag = pr->Hq[1] && pr->lo[1] == st->ns;
  for (int i = st->ns; pr->wdiag && i < (int)nz; i++)
    for (int j = st->ns; j < (int)nz; j++)
      if (i != j && pr->Hq[1][i * nz + j] != 0.0)
        pr->wdiag = 0;
  one_point(pr, st);
  pr->one_ok = pr->one;
  pr->wexact = pr->one && !pr->same && pr->one_kind[1] == INSIDE &&
               pr->one_kind[0] != INSIDE && pr->wdiag;
  for (int c = 0; c < 2; c++)
    for (int ip = 0; ip < st->n_pts[c]; ip++) {
      const mrvi_point *pt = &st->pts[c][ip];
      pr->wnode[c] += pt->w * pt->a0;
      if (pt->m == 0 && kind(pt) == INSIDE)
        pr->wins[c] += pt->w * pt->cA;
      if (pt->m == 0 && kind(pt) == AT_LEFT && pt->a1 == 0.0)
        pr->node_left = 1;
    }
  /* A point strictly inside the step with a slow input feeds the slow row
   * from the micro nodes. */
  for (int c = 0; c < 2 && !pr->slow_coupled; c++) {
    int inside = 0;
    for (int i = 0; i < st->n_pts[c]; i++)
      inside |= st->pts[c][i].a0 != 0.0 && st->pts[c][i].a1 != 0.0;
    pr->slow_coupled = inside && class_sees_slow(m, st, c);
  }
  /* (the Gershgorin bound where it settles every test of omega_max, the
   * sweep's and the outer iteration's; else the power iteration) */
  const double ob = omega_bound(pr, st);
  pr->omega = st->dt * ob <= 0.5 && mrvi_outer_contraction(ob, st->dt) <=
                                        pr->tn.chord_jacobi_max
                  ? ob
                  : power_iteration(pr, NULL, 0, NULL);
  pr->sweep_ok = st->dt * pr->omega <= 0.5;
  pr->rstop = pr->rsweep = INFINITY;
  if (pr->slow_coupled && m->n <= pr->tn.slow_newton_n) {
    const size_t ns = (size_t)(m->n_slow > 0 ? m->n_slow : 1);
    pr->H = malloc(2 * n * n * sizeof(double)); /* (and a point's, Ht) */
    pr->A = malloc(2 * ns * ns * sizeof(double));
    pr->sample =
        malloc((size_t)(st->n_pts[0] + st->n_pts[1] + 1) * sizeof(int));
    if (!pr->H || !pr->A || !pr->sample) {
      mrvi_predictor_free(pr);
      return MRVI_ENOMEM;
    }
    choose_samples(pr, st);
    pr->kappa = slow_kappa(pr, st);
    for (int c = 0; c < 2; c++)
      if (pr->kc[c] && mrvi_terms_flat(pr->kc[c]) &&
          !(pr->dsum[c] = calloc((size_t)mrvi_terms_count(pr->kc[c]) + 1,
                                 sizeof(double)))) {
        mrvi_predictor_free(pr);
        return MRVI_ENOMEM;
      }
    if (linear_sweep_setup(pr, st) < 0) {
      mrvi_predictor_free(pr);
      return MRVI_ENOMEM;
    }
  }
  *out = pr;
  return MRVI_OK;
}

void mrvi_predictor_free(mrvi_predictor *pr) {
  if (!pr)
    return;
  free(pr->z);
  free(pr->g);
  free(pr->fs);
  free(pr->fexp);
  free(pr->fimp);
  free(pr->fimp1);
  free(pr->ju);
  free(pr->fimp0);
  free(pr->gnode);
  free(pr->scr);
  free(pr->fb);
  free(pr->pm);
  free(pr->H);
  free(pr->xs);
  free(pr->fk);
  free(pr->K);
  free(pr->jnode);
  free(pr->jmat);
  free(pr->A);
  free(pr->b);
  free(pr->sample);
  free(pr->minv);
  free(pr->kinds[0]);
  free(pr->kinds[1]);
  free(pr->pend[0]);
  free(pr->pend[1]);
  free(pr->dsum[0]);
  free(pr->dsum[1]);
  for (int c = 0; c < 2; c++) {
    free(pr->g0[c]);
    free(pr->Hq[c]);
  }
  mrvi_terms_free(pr->kc[0]);
  mrvi_terms_free(pr->kc[1]);
  free(pr);
}

double mrvi_predictor_omega_max(mrvi_predictor *pr) { return pr->omega; }

double mrvi_predictor_omega_power(mrvi_predictor *pr) {
  return power_iteration(pr, NULL, 0, NULL);
}

/* An upper bound of omega_max at q0: Gershgorin's on M^-1 hess(V + W)(q0)
 * (its eigenvalues are those of M^-1/2 hess M^-1/2), max_i minv_i (H_ii +
 * sum_{j != i} |H_ij|), from each element's Hessian (mrvi_element_eval)
 * at q0: its entries on one coordinate added to the diagonal, the others'
 * absolute values to the row (at least the sum's: the bound holds).  One
 * Hessian per element, against the power iteration's 60 gradients.  The
 * power iteration's estimate is a Rayleigh quotient, at most the largest
 * eigenvalue (up to its central differences' O(h^2)), so where this bound
 * passes a test of omega_max, that estimate passes it too.  HUGE_VAL
 * where a value is not finite or out of memory.  g, fexp (model order)
 * serve as vectors (the steps write them before they read them). */
static double omega_bound(mrvi_predictor *pr, const mrvi_step *st) {
  const mrvi_model *m = pr->m;
  double *hd = pr->g, *off = pr->fexp;
  memset(hd, 0, (size_t)m->n * sizeof *hd);
  memset(off, 0, (size_t)m->n * sizeof *off);
  mrvi_element_buf eb = {.e.proto = NULL};
  double sy[6], sg[6], sh[36], *y = sy, *g = sg, *h = sh;
  int cap = 6, ok = 1;
  for (int c = 0; c < 2 && ok; c++)
    for (int ie = 0; ie < st->n_elem_of_class[c]; ie++) {
      const mrvi_element *e =
          mrvi_model_element(m, MRVI_STEP_ELEM(st, c, ie), &eb);
      const int ni = e->n_in;
      if (ni > cap) {
        if (y != sy)
          free(y);
        cap = ni;
        if (!(y = malloc((size_t)cap * (size_t)(cap + 2) * sizeof *y))) {
          ok = 0;
          break;
        }
        g = y + cap;
        h = y + 2 * cap;
      }
      for (int j = 0; j < ni; j++)
        y[j] = m->q0[e->in[j]];
      mrvi_element_eval(m, e, y, g, h);
      for (int j = 0; j < ni; j++)
        for (int k = 0; k < ni; k++) {
          const double v = h[j * ni + k];
          if (e->in[j] == e->in[k])
            hd[e->in[j]] += v;
          else
            off[e->in[j]] += fabs(v);
        }
    }
  if (y != sy)
    free(y);
  if (!ok)
    return HUGE_VAL;
  double b = 0.0;
  for (int i = 0; i < m->n; i++) {
    const double v = (hd[i] + off[i]) / MRVI_MASS(m, i);
    b = v > b || isnan(v) ? v : b;
  }
  return isfinite(b) ? sqrt(b) : HUGE_VAL;
}

/* omega_max at q0 (mrvi_predictor_omega_max): power iteration on M^-1/2
 * hess(V + W)(q0) M^-1/2 with Hessian-vector products from central
 * differences of the gradient (fs, fexp, fimp, fb and fimp1 serve as vectors
 * here), in the packed order of the compiled terms (coordinate c at
 * column (slow ? 0 : n_slow) + slot[c], its start entry 1 + 0.1 (c mod 7)
 * as in model order); computed once, by mrvi_predictor_create.  With Q
 * (nq orthonormal rows of nf entries, and a row nq of scratch): the slow
 * coordinates held and the fast ones on the subspace orthogonal to Q's
 * rows (joints_omega), in the vectors of wk (6 n) instead of the
 * predictor's, which hold the set-up by then. */
static double power_iteration(mrvi_predictor *pr, double *Q, int nq,
                              double *wk) {
  const mrvi_model *m = pr->m;
  const int n = m->n, ns = m->n_slow;
  double *u = wk ? wk : pr->fs, *gp = wk ? wk + n : pr->fexp,
         *gm = wk ? wk + 2 * n : pr->fimp, *q0 = wk ? wk + 3 * n : pr->fb,
         *z = wk ? wk + 4 * n : pr->z;
  double lambda = 0.0, h = 0.0;
  for (int c = 0; c < n; c++) {
    const int slow = m->rate[c] == MRVI_SLOW, j = (slow ? 0 : ns) + m->slot[c];
    u[j] = Q && slow ? 0.0 : 1.0 + 0.1 * (double)(c % 7);
    q0[j] = m->q0[c];
    h = fmax(h, fabs(m->q0[c]));
  }
  h = 1e-6 * (1.0 + h);
  /* M^-1/2 once (fimp1 serves: the steps write it before they read it) */
  double *sm = wk ? wk + 5 * n : pr->fimp1;
  for (int i = 0; i < n; i++)
    sm[i] = sqrt(pr->minv[i]);
  for (int it = 0; it < 30; it++) {
    /* (on the tangent space: u's fast part less its components along Q's
     * rows; Q's row nq is scratch) */
    if (Q)
      mrvi_dense_extend_basis(n - ns, Q, nq, u + ns, 0.0);
    double nu = 0.0;
    for (int i = 0; i < n; i++)
      nu += u[i] * u[i];
    nu = sqrt(nu);
    if (!(nu > 0.0))
      return 0.0;
    for (int i = 0; i < n; i++)
      u[i] /= nu;
    for (int sgn = 0; sgn < 2; sgn++) {
      double *g = sgn ? gm : gp;
      for (int i = 0; i < n; i++)
        z[i] = q0[i] + (sgn ? -h : h) * u[i] * sm[i];
      memset(g, 0, (size_t)n * sizeof(double));
      mrvi_terms_grad(pr->kc[0], z, g);
      mrvi_terms_grad(pr->kc[1], z, g);
    }
    lambda = 0.0;
    for (int i = 0; i < n; i++) {
      const double hu = Q && i < ns ? 0.0 : (gp[i] - gm[i]) / (2.0 * h) * sm[i];
      lambda += u[i] * hu;
      u[i] = hu;
    }
  }
  return lambda > 0.0 && isfinite(lambda) ? sqrt(lambda) : 0.0;
}

/* Free flight: the momenta of node k held over the step. */
void mrvi_predict_free_flight(const mrvi_step *st, double *x) {
  const mrvi_model *m = st->model;
  for (int s = 0; s < st->ns; s++)
    x[s] = st->dT * st->ps0[s] / MRVI_MASS(m, m->slow_index[s]);
  for (int mm = 1; mm <= st->p; mm++)
    for (int s = 0; s < st->nf; s++)
      x[st->ns + (size_t)(mm - 1) * st->nf + s] =
          mm * st->dt * st->pf0[s] / MRVI_MASS(m, m->fast_index[s]);
}

/* g <- grad Z_c at point pt of the step at the displacements x (fast nodes
 * m and m + 1 of pt's interval; node 0 is q_k^{f,0}), packed.  With both
 * (V at its point, pr->same), W's gradient too: an affine W (Hq[1]) formed
 * before V's call, so that it runs beside it, then added (G[i] += t, as
 * affine_grad_k; by the diagonal with wdiag).  A class with a constant
 * Hessian evaluated alone takes its affine map as well.  With J, the slow
 * block of the point's Hessian times hscale is added to J. */
ALWAYS_INLINE void point_gradient_k(mrvi_predictor *pr, const mrvi_step *st,
                                    const double *x, const mrvi_point *pt,
                                    int c, const int ns, const int nf,
                                    double *J, double hscale, int both) {
  double *restrict z = pr->z, *restrict g = pr->g;
  const double *restrict qs0 = st->qs0, *restrict qf0 = st->qf0;
  const double a1 = pt->a1, cA = pt->cA, cB = pt->cB;
  if (pr->Hq[c] && pr->lo[c] != 0)
    J = NULL; /* (a constant Hessian without a slow block) */
  const int nz = ns + nf;
  /* (of constant size: a variable-length array cost a stack save and
   * restore per call on the sweep's chain; W has an affine map only with
   * ns, nf <= 4) */
  double tw[8] = {0};
  UNROLL for (int s = 0; s < ns; s++) z[s] = qs0[s] + a1 * x[s];
  /* (the tests outside the loop: qf0 + cA d^m + cB d^{m+1}, a term 0.0
   * where its node is node k or its weight 0) */
  const double *dB = x + ns + (size_t)pt->m * nf;
  const double *dA = pt->m > 0 ? dB - nf : dB;
  if (pt->m > 0 && cB != 0.0)
    UNROLL for (int f = 0; f < nf; f++) z[ns + f] =
        qf0[f] + cA * dA[f] + cB * dB[f];
  else if (pt->m > 0)
    UNROLL for (int f = 0; f < nf; f++) z[ns + f] = qf0[f] + cA * dA[f] + 0.0;
  else if (cB != 0.0)
    UNROLL for (int f = 0; f < nf; f++) z[ns + f] = qf0[f] + 0.0 + cB * dB[f];
  else
    UNROLL for (int f = 0; f < nf; f++) z[ns + f] = qf0[f] + 0.0 + 0.0;
  const int wlo = pr->lo[1] == 0 ? 0 : ns;
  const double *restrict g0 = pr->g0[1], *restrict Hq = pr->Hq[1];
  if (!J && !both && pr->Hq[c]) { /* a class with a constant Hessian alone */
    /* (written, not added to zeros just stored: the zeros went out as
     * pairs, and reloading one entry of a pair missed store forwarding) */
    if (c == 1 && pr->wdiag) {
      UNROLL for (int i = 0; i < ns; i++) g[i] = 0.0;
      UNROLL for (int i = ns; i < nz; i++) g[i] =
          0.0 + (g0[i] + Hq[i * nz + i] * z[i]);
    } else if (pr->lo[c] == 0) /* (each with constant bounds) */
      affine_k(pr->g0[c], pr->Hq[c], z, g, 0, nz, 0);
    else {
      UNROLL for (int i = 0; i < ns; i++) g[i] = 0.0;
      affine_k(pr->g0[c], pr->Hq[c], z, g, ns, nz, 0);
    }
    return;
  }
  if (both && Hq && nz <= 8) { /* (each with constant bounds) */
    if (pr->wdiag)             /* (the off-diagonal products are zeros) */
      UNROLL for (int i = ns; i < nz; i++) tw[i] =
          g0[i] + Hq[i * nz + i] * z[i];
    else if (wlo == 0)
      affine_k(g0, Hq, z, tw, 0, nz, 0);
    else
      affine_k(g0, Hq, z, tw, ns, nz, 0);
  }
  UNROLL for (int i = 0; i < nz; i++) g[i] = 0.0;
  if (J && pr->hsum && pr->dsum[c]) /* (the Hessian as phi'' per term) */
    mrvi_terms_grad_d2(pr->kc[c], z, g, hscale, pr->dsum[c]);
  else if (J) { /* the slow solve's Hessian as well: at scale 1 (the flat
                 * kernels, mrvi_terms_eval), its slow block times hscale
                 * into J */
    double *restrict Ht = pr->H + (size_t)nz * (size_t)nz;
    UNROLL for (int i = 0; i < nz * nz; i++) Ht[i] = 0.0;
    mrvi_terms_eval(pr->kc[c], z, 1.0, g, Ht, nz, 1.0);
    UNROLL for (int i = 0; i < ns; i++) UNROLL for (int j = 0; j < ns; j++)
        J[i * nz + j] += hscale * Ht[i * nz + j];
  } else
    mrvi_terms_grad(pr->kc[c], z, g);
  if (!both) /* W at V's point (pr->same) */
    return;
  if (!Hq || nz > 8)
    mrvi_terms_grad(pr->kc[1], z, g);
  else if (wlo == 0)
    UNROLL for (int i = 0; i < nz; i++) g[i] += tw[i];
  else
    UNROLL for (int i = ns; i < nz; i++) g[i] += tw[i];
}

/* The sums fa += wa g_f, fb += wb g_f, fs += w0 g_s (NULL: not added)
 * in ranges of the coordinates, inside a parallel region (point_team). */
static void sums_team(const double *g, double *fa, double wa, double *fb,
                      double wb, double *fs, double w0, int ns, int nf) {
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
  for (int f = 0; f < nf; f++) {
    if (fa)
      fa[f] += wa * g[ns + f];
    if (fb)
      fb[f] += wb * g[ns + f];
  }
  if (fs) {
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
    for (int s = 0; s < ns; s++)
      fs[s] += w0 * g[s];
  }
}

/* point_gradient_k (without J, affine maps or a class out of parts:
 * pr->ppar) with its sums (sums_team), its loops shared by the threads of
 * the enclosing parallel region: the configuration and g's zeros in
 * ranges of the coordinates, the gradient in the class's parts (W's after
 * V's with both, a barrier between), the sums in the same ranges (no
 * barrier after them: the next loop over the same range runs on the same
 * thread, schedule(static)).  Each entry takes the serial arithmetic, each
 * part writes its own columns in the serial order (mrvi_terms_set_threads):
 * the same bits for every thread count. */
static void point_team(mrvi_predictor *pr, const mrvi_step *st, const double *x,
                       const mrvi_point *pt, int c, int both, double *fa,
                       double wa, double *fb, double wb, double *fs,
                       double w0) {
  const int ns = st->ns, nf = st->nf;
  double *restrict z = pr->z, *restrict g = pr->g;
  const double *restrict qs0 = st->qs0, *restrict qf0 = st->qf0;
  const double a1 = pt->a1, cA = pt->cA, cB = pt->cB;
  const double *dB = x + ns + (size_t)pt->m * nf;
  const double *dA = pt->m > 0 ? dB - nf : dB;
  const int mA = pt->m > 0, mB = cB != 0.0;
  mrvi_terms *kv = pr->kc[c], *kw = both ? pr->kc[1] : NULL;
  const int npv = mrvi_terms_parts(kv), npw = kw ? mrvi_terms_parts(kw) : 0;
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
  for (int s = 0; s < ns; s++) {
    z[s] = qs0[s] + a1 * x[s];
    g[s] = 0.0;
  }
  /* (point_gradient_k's four cases, term by term) */
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
  for (int f = 0; f < nf; f++) {
    z[ns + f] = mA && mB ? qf0[f] + cA * dA[f] + cB * dB[f]
                : mA     ? qf0[f] + cA * dA[f] + 0.0
                : mB     ? qf0[f] + 0.0 + cB * dB[f]
                         : qf0[f] + 0.0 + 0.0;
    g[ns + f] = 0.0;
  }
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
  for (int k = 0; k < npv; k++)
    mrvi_terms_grad_part(kv, k, z, g);
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
  for (int k = 0; k < npw; k++)
    mrvi_terms_grad_part(kw, k, z, g);
  sums_team(g, fa, wa, fb, wb, fs, w0, ns, nf);
}

ALWAYS_INLINE void axpy(const int n, double a, const double *restrict g,
                        double *restrict acc) {
  UNROLL for (int i = 0; i < n; i++) acc[i] += a * g[i];
}

/* The gradients of V and W at node k, z = (q_k^s, q_k^{f,0}), into gnode
 * (and their sum, with same); fs = the slow-row force with every point at
 * node k, fimp0 = interval 0's implicit force F_0^A estimated there. */
ALWAYS_INLINE void node_gradients_k(mrvi_predictor *pr, const mrvi_step *st,
                                    const int ns, const int nf) {
  const int n = ns + nf;
  double *restrict z = pr->z, *restrict gv = pr->gnode,
                   *restrict gw = pr->gnode + n;
  UNROLL for (int s = 0; s < ns; s++) z[s] = st->qs0[s];
  UNROLL for (int f = 0; f < nf; f++) z[ns + f] = st->qf0[f];
  UNROLL for (int i = 0; i < n; i++) gv[i] = gw[i] = 0.0;
  for (int c = 0; c < 2; c++) {
    if (st->n_elem_of_class[c] == 0)
      continue;
    double *g = c == 0 ? gv : gw;
    if (!pr->Hq[c])
      mrvi_terms_grad(pr->kc[c], z, g);
    else if (pr->lo[c] == 0) /* (each with constant bounds) */
      affine_grad_k(pr->g0[c], pr->Hq[c], z, g, 0, n);
    else
      affine_grad_k(pr->g0[c], pr->Hq[c], z, g, ns, n);
  }
  const double v0 = pr->wnode[0], w0 = pr->wnode[1];
  UNROLL for (int s = 0; s < ns; s++) pr->fs[s] = v0 * gv[s] + w0 * gw[s];
  const double v1 = pr->wins[0], w1 = pr->wins[1];
  UNROLL for (int f = 0; f < nf; f++) pr->fimp0[f] =
      v1 * gv[ns + f] + w1 * gw[ns + f];
  if (pr->same && pr->node_left)
    UNROLL for (int i = 0; i < n; i++) pr->gnode[2 * n + i] = gv[i] + gw[i];
}

/* node_gradients_k on the step's threads in one parallel region
 * (pr->ppar: no affine maps): the configuration and zeros in ranges of
 * the coordinates, V's parts and W's parts (into their own arrays) in one
 * shared loop, the sums in ranges; each entry node_gradients_k's
 * arithmetic, each part writing its own columns in the serial order. */
static __attribute__((noinline)) void node_gradients_par(mrvi_predictor *pr,
                                                         const mrvi_step *st) {
  const int ns = st->ns, nf = st->nf, n = ns + nf;
  double *restrict z = pr->z, *restrict gv = pr->gnode,
                   *restrict gw = pr->gnode + n;
  const int npv = st->n_elem_of_class[0] ? mrvi_terms_parts(pr->kc[0]) : 0,
            npw = st->n_elem_of_class[1] ? mrvi_terms_parts(pr->kc[1]) : 0;
  const double v0 = pr->wnode[0], w0 = pr->wnode[1];
  const double v1 = pr->wins[0], w1 = pr->wins[1];
  const int sum = pr->same && pr->node_left;
#ifdef _OPENMP
#pragma omp parallel num_threads(pr->pthreads)
#endif
  {
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
    for (int i = 0; i < n; i++) {
      z[i] = i < ns ? st->qs0[i] : st->qf0[i - ns];
      gv[i] = gw[i] = 0.0;
    }
#ifdef _OPENMP
#pragma omp for schedule(static)
#endif
    for (int k = 0; k < npv + npw; k++)
      if (k < npv)
        mrvi_terms_grad_part(pr->kc[0], k, z, gv);
      else
        mrvi_terms_grad_part(pr->kc[1], k - npv, z, gw);
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
    for (int s = 0; s < ns; s++)
      pr->fs[s] = v0 * gv[s] + w0 * gw[s];
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
    for (int f = 0; f < nf; f++)
      pr->fimp0[f] = v1 * gv[ns + f] + w1 * gw[ns + f];
    if (sum) {
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
      for (int i = 0; i < n; i++)
        pr->gnode[2 * n + i] = gv[i] + gw[i];
    }
  }
}

/* Evaluate the points of kind k in [first[c], end[c]) of both classes:
 * fa += w cA g_f, fb += w cB g_f and, with sum_slow, fs += w a0 g_s.  With
 * at_k (interval 0), a point at node k (AT_LEFT with a1 = 0) takes the
 * gradient kept from node_gradients_k. */
ALWAYS_INLINE void eval_points_k(mrvi_predictor *pr, const mrvi_step *st,
                                 const double *x, const int *first,
                                 const int *end, int k, double *fa, double *fb,
                                 double *fs, int sum_slow, int at_k,
                                 const int ns, const int nf) {
  if (!pr->has_kind[k])
    return;
  const int same = pr->same;
  for (int c = 0; c < (same ? 1 : 2); c++)
    for (int ip = first[c]; ip < end[c]; ip++) {
      if (pr->kinds[c][ip] != k)
        continue;
      const mrvi_point *pt = &st->pts[c][ip];
      const double *g = pr->g;
      if (at_k && pt->a1 == 0.0)
        g = pr->gnode + (size_t)(same ? 2 : c) * (size_t)(ns + nf);
      else
        point_gradient_k(pr, st, x, pt, c, ns, nf, pr->hsum ? pr->H : NULL,
                         pt->w * pt->a0 * pt->a1, same);
      if (fa && pt->cA != 0.0)
        axpy(nf, pt->w * pt->cA, g + ns, fa);
      if (fb && pt->cB != 0.0)
        axpy(nf, pt->w * pt->cB, g + ns, fb);
      if (sum_slow && pt->a0 != 0.0)
        axpy(ns, pt->w * pt->a0, g, fs);
    }
}

/* The fast nodes d^1 .. d^p for the slow displacement x_s; with sum_slow,
 * fs gets the slow-row force of every point along the swept path. */
static void eval_points(mrvi_predictor *pr, const mrvi_step *st,
                        const double *x, const int *first, const int *end,
                        int k, double *fa, double *fb, int sum_slow) {
  eval_points_k(pr, st, x, first, end, k, fa, fb, pr->fs, sum_slow, 0, st->ns,
                st->nf);
}

/* The estimate of interval mm's implicit force from the last intervals'
 * (fimp the last, fimp1 the one before; both updated): in interval 0 its
 * value at node k (fimp0, node_gradients_k), in interval 1 interval 0's,
 * from interval 2 on extrapolated linearly from the last two intervals' (an
 * error O(dt^2) instead of O(dt)). */
ALWAYS_INLINE void extrapolate_k(const int mm, double *restrict fimp,
                                 double *restrict fimp1, const int nf) {
  if (mm >= 2)
    UNROLL for (int f = 0; f < nf; f++) {
      const double fi = fimp[f];
      fimp[f] = 2.0 * fi - fimp1[f];
      fimp1[f] = fi;
    }
  else
    UNROLL for (int f = 0; f < nf; f++) fimp1[f] = fimp[f];
}

/* The sweep's vectors (slow-row force, F^A explicit and implicit, the
 * last F^A implicit, F^B, p^{f,m}) are local arrays for small blocks (ns,
 * nf <= 4: held in registers, nothing that x may alias), else pr's; fs is
 * copied to pr->fs at the end. */
ALWAYS_INLINE void sweep_k(mrvi_predictor *pr, const mrvi_step *st, double *x,
                           int sum_slow, const int ns, const int nf) {
  const int p = st->p;
  const double dt = st->dt, *minv = pr->minv + ns;
  const int loc = ns <= 4 && nf <= 4;
  double lfs[4], lfexp[4], lfimp[4], lfimp1[4] = {0}, lfb[4], lpm[4];
  double *restrict fs = loc ? lfs : pr->fs,
                   *restrict fexp = loc ? lfexp : pr->fexp,
                   *restrict fimp = loc ? lfimp : pr->fimp,
                   *restrict fimp1 = loc ? lfimp1 : pr->fimp1,
                   *restrict fb = loc ? lfb : pr->fb,
                   *restrict pm = loc ? lpm : pr->pm;
  if (sum_slow)
    UNROLL for (int s = 0; s < ns; s++) fs[s] = 0.0;
  UNROLL for (int f = 0; f < nf; f++) fimp[f] = pr->fimp0[f];
  UNROLL for (int f = 0; f < nf; f++) pm[f] = st->pf0[f];
  double cm[nf > 0 ? nf : 1]; /* dt / M */
  UNROLL for (int f = 0; f < nf; f++) cm[f] = dt * minv[f];
  int first[2] = {0, 0}, end[2];
  for (int mm = 0; mm < p; mm++) {
    end[0] = pr->pend[0][mm];
    end[1] = pr->pend[1][mm];
    const double *d = mm == 0 ? NULL : x + ns + (size_t)(mm - 1) * nf;
    double *dn = x + ns + (size_t)mm * nf;
    /* Row mm with F^A = explicit points + the implicit force fimp. */
#define SOLVE_ROW()                                                            \
  UNROLL for (int f = 0; f < nf; f++) dn[f] =                                  \
      (d ? d[f] : 0.0) + cm[f] * (pm[f] - fexp[f] - fimp[f]);
    UNROLL for (int f = 0; f < nf; f++) fexp[f] = 0.0;
    eval_points_k(pr, st, x, first, end, AT_LEFT, fexp, NULL, fs, sum_slow,
                  mm == 0, ns, nf);
    extrapolate_k(mm, fimp, fimp1, nf);
    SOLVE_ROW();
    UNROLL for (int f = 0; f < nf; f++) fimp[f] = 0.0;
    UNROLL for (int f = 0; f < nf; f++) fb[f] = 0.0;
    eval_points_k(pr, st, x, first, end, INSIDE, fimp, fb, fs, sum_slow, 0, ns,
                  nf);
#undef SOLVE_ROW
    /* The row again with the implicit force at the estimate: u = p^{f,m} -
     * F_m^A = M (d^{m+1} - d^m) / dt, so that p^{f,m+1} = u - F_m^B
     * follows from u without dividing the difference of the nodes by dt / M
     * (a division on the chain from node to node; the same to round-off). */
    double u[nf > 0 ? nf : 1];
    UNROLL for (int f = 0; f < nf; f++) {
      u[f] = pm[f] - fexp[f] - fimp[f];
      dn[f] = (d ? d[f] : 0.0) + cm[f] * u[f];
    }
    eval_points_k(pr, st, x, first, end, AT_RIGHT, NULL, fb, fs, sum_slow, 0,
                  ns, nf);
    if (mm + 1 < p) /* (p^{f,p} is not needed) */
      UNROLL for (int f = 0; f < nf; f++) pm[f] = u[f] - fb[f];
    first[0] = end[0];
    first[1] = end[1];
  }
  if (loc && sum_slow)
    UNROLL for (int s = 0; s < ns; s++) pr->fs[s] = fs[s];
  /* Without fast coordinates the points still feed the slow row. */
  if (nf == 0 && sum_slow)
    for (int k = AT_LEFT; k <= AT_RIGHT; k++)
      eval_points(pr, st, x, (int[2]){0, 0}, st->n_pts, k, NULL, NULL, 1);
}

/* The sweep where every class has one point per interval, all of one kind
 * (pr->one: the midpoint and the alpha = gamma = 1 trapezoidal rule on the
 * micro grid): sweep_k's arithmetic in its order (the same predictor),
 * without its loops over the points and kinds, so that fewer values live
 * across the gradients' calls; the row is solved once at the estimate only
 * where some class has implicit points. */
ALWAYS_INLINE void sweep1_k(mrvi_predictor *pr, const mrvi_step *st, double *x,
                            int sum_slow, const int ns, const int nf) {
  const int p = st->p, n = ns + nf, same = pr->same;
  const int k0 = pr->one_kind[0], k1 = pr->one_kind[1];
  const int implicit = k0 == INSIDE || k1 == INSIDE;
  const double dt = st->dt, *minv = pr->minv + ns;
  const mrvi_point *pts[2] = {st->pts[0], st->pts[1]};
  /* The sweep's short vectors: local arrays of constant size for blocks of
   * at most 4, which the compiler can scalarise (as variable-length
   * arrays they stayed in memory, each += a store and a reload on the
   * chain from node to node, and cost a stack save and restore per node);
   * pr->scr's in the copy with run-time sizes, compiled but not taken
   * (one_point: ns, nf <= 4). */
  const int loc = ns <= 4 && nf <= 4;
  double lv[8][4];
  double *sv = pr->scr;
  double *restrict fs = loc ? lv[0] : sv, *restrict fimp = loc ? lv[1] : sv + n,
                   *restrict fimp1 = loc ? lv[2] : sv + 2 * n,
                   *restrict pm = loc ? lv[3] : sv + 3 * n,
                   *restrict cm = loc ? lv[4] : sv + 4 * n,
                   *restrict fexp = loc ? lv[5] : sv + 5 * n,
                   *restrict fi = loc ? lv[6] : sv + 6 * n,
                   *restrict fb = loc ? lv[7] : sv + 7 * n;
  UNROLL for (int s = 0; s < ns; s++) fs[s] = 0.0;
  UNROLL for (int f = 0; f < nf; f++) {
    fimp[f] = pr->fimp0[f];
    fimp1[f] = 0.0;
    pm[f] = st->pf0[f];
    cm[f] = dt * minv[f]; /* dt / M */
  }
  /* (wexact: with W's gradient g0 + h z (h its diagonal) on the fast
   * columns and a = dt/M, per fast coordinate the row's solution
   * d^{m+1} = e0 d^m + e1 (p^{f,m} - F^A_exp - c0), e0 = (1 - a w cA h cA)
   * / r, e1 = a / r, r = 1 + a w cA cB h, c0 = w cA (g0 + h q^f_0), and
   * the gradient there k0 + kA d^m + kB d^{m+1}) */
  const int wex = pr->wexact && loc; /* (one implies loc) */
  double we0[4] = {0}, we1[4] = {0}, wc0[4] = {0}, wk0[4] = {0}, wkA[4] = {0},
         wkB[4] = {0}, wxa = 0.0, wxb = 0.0;
  if (wex) {
    const mrvi_point *pt = &pts[1][0];
    wxa = pt->w * pt->cA;
    wxb = pt->w * pt->cB;
    UNROLL for (int f = 0; f < nf; f++) {
      const double g0 = pr->g0[1][ns + f], h = pr->Hq[1][(ns + f) * n + ns + f];
      const double r = 1.0 + cm[f] * wxa * pt->cB * h;
      we0[f] = (1.0 - cm[f] * wxa * h * pt->cA) / r;
      we1[f] = cm[f] / r;
      wk0[f] = g0 + h * st->qf0[f];
      wc0[f] = wxa * wk0[f];
      wkA[f] = h * pt->cA;
      wkB[f] = h * pt->cB;
    }
  }
  for (int mm = 0; mm < p; mm++) {
    const double *d = mm == 0 ? NULL : x + ns + (size_t)(mm - 1) * nf;
    double *dn = x + ns + (size_t)mm * nf;
    UNROLL for (int f = 0; f < nf; f++) fexp[f] = fi[f] = fb[f] = 0.0;
    /* The points at node m (explicit): F^A, the slow row. */
    for (int c = 0; c < 2; c++) {
      if ((c == 0 ? k0 : k1) != AT_LEFT)
        continue;
      const mrvi_point *pt = &pts[c][mm];
      const double *g = pr->g;
      if (mm == 0 && pt->a1 == 0.0)
        g = pr->gnode + (size_t)(same ? 2 : c) * (size_t)n;
      else
        point_gradient_k(pr, st, x, pt, c, ns, nf, pr->hsum ? pr->H : NULL,
                         pt->w * pt->a0 * pt->a1, same);
      const double wa = pt->w * pt->cA, w0 = pt->w * pt->a0;
      UNROLL for (int f = 0; f < nf; f++) fexp[f] += wa * g[ns + f];
      if (sum_slow && pt->a0 != 0.0)
        UNROLL for (int s = 0; s < ns; s++) fs[s] += w0 * g[s];
    }
    if (implicit) {
      if (wex) {
        /* W's point inside the interval, its gradient affine and
         * diagonal in the fast nodes alone (pr->wexact): the row
         * M (d^{m+1} - d^m) / dt = p^{f,m} - F^A_exp - w cA (g0 + h (q^f_0
         * + cA d^m + cB d^{m+1})) solved for d^{m+1} exactly, and its
         * forces F^A, F^B there (no slow row: no slow input) */
        UNROLL for (int f = 0; f < nf; f++) {
          const double dA = d ? d[f] : 0.0;
          dn[f] = we0[f] * dA + we1[f] * (pm[f] - fexp[f] - wc0[f]);
          const double gw = wk0[f] + wkA[f] * dA + wkB[f] * dn[f];
          fi[f] = wxa * gw;
          fb[f] = wxb * gw;
        }
      } else {
        /* The row at the estimate of the implicit force (sweep_k) */
        extrapolate_k(mm, fimp, fimp1, nf);
        UNROLL for (int f = 0; f < nf; f++) dn[f] =
            (d ? d[f] : 0.0) + cm[f] * (pm[f] - fexp[f] - fimp[f]);
      }
      /* ... and the implicit points there: F^A, F^B, the slow row. */
      for (int c = 0; c < 2 && !wex; c++) {
        if ((c == 0 ? k0 : k1) != INSIDE)
          continue;
        const mrvi_point *pt = &pts[c][mm];
        point_gradient_k(pr, st, x, pt, c, ns, nf, pr->hsum ? pr->H : NULL,
                         pt->w * pt->a0 * pt->a1, same);
        const double *g = pr->g;
        const double wa = pt->w * pt->cA, wb = pt->w * pt->cB,
                     w0 = pt->w * pt->a0;
        UNROLL for (int f = 0; f < nf; f++) {
          fi[f] += wa * g[ns + f];
          fb[f] += wb * g[ns + f];
        }
        if (sum_slow && pt->a0 != 0.0)
          UNROLL for (int s = 0; s < ns; s++) fs[s] += w0 * g[s];
      }
    }
    /* The row with the implicit force at the solved node, and p^{f,m+1} =
     * u - F_m^B (sweep_k). */
    UNROLL for (int f = 0; f < nf; f++) {
      const double u = pm[f] - fexp[f] - fi[f];
      dn[f] = (d ? d[f] : 0.0) + cm[f] * u;
      pm[f] = u - fb[f];
      fimp[f] = fi[f];
    }
  }
  if (sum_slow)
    UNROLL for (int s = 0; s < ns; s++) pr->fs[s] = fs[s];
}

/* eval_points_k inside a parallel region, its loops shared (point_team;
 * the points at node k with the kept gradient, sums_team). */
static void eval_team(mrvi_predictor *pr, const mrvi_step *st, const double *x,
                      const int *first, const int *end, int k, double *fa,
                      double *fb, double *fs, int sum_slow, int at_k) {
  if (!pr->has_kind[k])
    return;
  const int same = pr->same, ns = st->ns, nf = st->nf;
  for (int c = 0; c < (same ? 1 : 2); c++)
    for (int ip = first[c]; ip < end[c]; ip++) {
      if (pr->kinds[c][ip] != k)
        continue;
      const mrvi_point *pt = &st->pts[c][ip];
      double *ta = fa && pt->cA != 0.0 ? fa : NULL,
             *tb = fb && pt->cB != 0.0 ? fb : NULL,
             *ts = sum_slow && pt->a0 != 0.0 ? fs : NULL;
      if (at_k && pt->a1 == 0.0)
        sums_team(pr->gnode + (size_t)(same ? 2 : c) * (size_t)(ns + nf), ta,
                  pt->w * pt->cA, tb, pt->w * pt->cB, ts, pt->w * pt->a0, ns,
                  nf);
      else
        point_team(pr, st, x, pt, c, same, ta, pt->w * pt->cA, tb,
                   pt->w * pt->cB, ts, pt->w * pt->a0);
    }
}

/* sweep_k (nf > 0, without the small blocks' local arrays) on the step's
 * threads in one parallel region (pr->ppar): every thread walks the rows
 * and points, the row updates in ranges of the fast coordinates (the
 * same ranges as point_team's sums: schedule(static), so no barrier
 * between them), the points by point_team.  Each entry takes sweep_k's
 * arithmetic in its order: the same bits for every thread count. */
static __attribute__((noinline)) void
sweep_par(mrvi_predictor *pr, const mrvi_step *st, double *x, int sum_slow) {
  const int p = st->p, ns = st->ns, nf = st->nf;
  const double dt = st->dt, *minv = pr->minv + ns;
  double *restrict fs = pr->fs, *restrict fexp = pr->fexp,
                   *restrict fimp = pr->fimp, *restrict fimp1 = pr->fimp1,
                   *restrict fb = pr->fb, *restrict pm = pr->pm,
                   *restrict u = pr->scr, *restrict cm = pr->scr + nf;
#ifdef _OPENMP
#pragma omp parallel num_threads(pr->pthreads)
#endif
  {
    if (sum_slow) {
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
      for (int s = 0; s < ns; s++)
        fs[s] = 0.0;
    }
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
    for (int f = 0; f < nf; f++) {
      fimp[f] = pr->fimp0[f];
      pm[f] = st->pf0[f];
      cm[f] = dt * minv[f];
    }
    int first[2] = {0, 0}, end[2];
    for (int mm = 0; mm < p; mm++) {
      end[0] = pr->pend[0][mm];
      end[1] = pr->pend[1][mm];
      const double *d = mm == 0 ? NULL : x + ns + (size_t)(mm - 1) * nf;
      double *dn = x + ns + (size_t)mm * nf;
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
      for (int f = 0; f < nf; f++)
        fexp[f] = 0.0;
      eval_team(pr, st, x, first, end, AT_LEFT, fexp, NULL, fs, sum_slow,
                mm == 0);
      /* (extrapolate_k, the row at the estimate, the zeros) */
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
      for (int f = 0; f < nf; f++) {
        if (mm >= 2) {
          const double fi = fimp[f];
          fimp[f] = 2.0 * fi - fimp1[f];
          fimp1[f] = fi;
        } else
          fimp1[f] = fimp[f];
        dn[f] = (d ? d[f] : 0.0) + cm[f] * (pm[f] - fexp[f] - fimp[f]);
        fimp[f] = 0.0;
        fb[f] = 0.0;
      }
      eval_team(pr, st, x, first, end, INSIDE, fimp, fb, fs, sum_slow, 0);
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
      for (int f = 0; f < nf; f++) {
        u[f] = pm[f] - fexp[f] - fimp[f];
        dn[f] = (d ? d[f] : 0.0) + cm[f] * u[f];
      }
      eval_team(pr, st, x, first, end, AT_RIGHT, NULL, fb, fs, sum_slow, 0);
      if (mm + 1 < p) {
#ifdef _OPENMP
#pragma omp for schedule(static) nowait
#endif
        for (int f = 0; f < nf; f++)
          pm[f] = u[f] - fb[f];
      }
      first[0] = end[0];
      first[1] = end[1];
    }
  }
}

/* The sweep with the micro-node constraints' forces (pr->js,
 * predict_joints.c; doc/solver.md, "The joint sweep"), on the points of
 * any rule as sweep_k.  At each node: the row solved with the implicit
 * force at its estimate (sweep_k), the node moved onto the constraints
 * (lambda^m), the implicit points evaluated at the moved node (the move is
 * of the size of the constraint force's effect over the micro step, far
 * above the estimate's error, and W's force changes with it), the row
 * solved again with them plus the move, and the node moved onto the
 * constraints again with the matrix kept; p^{f,m+1} = M (d^{m+1} - d^m) /
 * dt - F_m^B of the moved node.  The slow-row force is the points' (the
 * multipliers' is mrvi_joint_sweep_slow_force).  With reuse (the sweep
 * after the slow correction) each node keeps the last sweep's matrix. */
static void sweep_joints(mrvi_predictor *pr, const mrvi_step *st, double *x,
                         int sum_slow, int reuse) {
  const int p = st->p, ns = st->ns, nf = st->nf;
  const double dt = st->dt, *minv = pr->minv + ns;
  double *fs = pr->fs, *fexp = pr->fexp, *fimp = pr->fimp, *fimp1 = pr->fimp1,
         *fb = pr->fb, *pm = pr->pm, *u = pr->ju;
  if (sum_slow)
    memset(fs, 0, (size_t)ns * sizeof *fs);
  memcpy(fimp, pr->fimp0, (size_t)nf * sizeof *fimp);
  memcpy(pm, st->pf0, (size_t)nf * sizeof *pm);
  int first[2] = {0, 0}, end[2];
  for (int mm = 0; mm < p; mm++) {
    end[0] = pr->pend[0][mm];
    end[1] = pr->pend[1][mm];
    const double *d = mm == 0 ? NULL : x + ns + (size_t)(mm - 1) * nf;
    double *dn = x + ns + (size_t)mm * nf;
    memset(fexp, 0, (size_t)nf * sizeof *fexp);
    eval_points_k(pr, st, x, first, end, AT_LEFT, fexp, NULL, fs, sum_slow,
                  mm == 0, ns, nf);
    extrapolate_k(mm, fimp, fimp1, nf);
    for (int f = 0; f < nf; f++)
      dn[f] = (d ? d[f] : 0.0) + dt * minv[f] * (pm[f] - fexp[f] - fimp[f]);
    const double *c = mrvi_joint_sweep_node(pr->js, st, x, mm, reuse ? 2 : 0);
    memset(fimp, 0, (size_t)nf * sizeof *fimp);
    memset(fb, 0, (size_t)nf * sizeof *fb);
    eval_points_k(pr, st, x, first, end, INSIDE, fimp, fb, fs, sum_slow, 0, ns,
                  nf);
    for (int f = 0; f < nf; f++) {
      u[f] = pm[f] - fexp[f] - fimp[f];
      dn[f] = (d ? d[f] : 0.0) + dt * minv[f] * u[f] + c[f];
    }
    c = mrvi_joint_sweep_node(pr->js, st, x, mm, 1);
    eval_points_k(pr, st, x, first, end, AT_RIGHT, NULL, fb, fs, sum_slow, 0,
                  ns, nf);
    for (int f = 0; f < nf; f++)
      pm[f] = u[f] + c[f] / (dt * minv[f]) - fb[f];
    first[0] = end[0];
    first[1] = end[1];
  }
}

static void sweep(mrvi_predictor *pr, const mrvi_step *st, double *x,
                  int sum_slow) {
  pr->n_sweeps++;
  if (pr->js) {
    sweep_joints(pr, st, x, sum_slow, 0);
    return;
  }
  if (pr->one) {
    SMALL2(st->ns, NS, st->nf, NF, sweep1_k(pr, st, x, sum_slow, NS, NF));
  } else if (pr->ppar && !pr->hsum && st->nf > 0) {
    sweep_par(pr, st, x, sum_slow);
  } else {
    SMALL2(st->ns, NS, st->nf, NF, sweep_k(pr, st, x, sum_slow, NS, NF));
  }
}

ALWAYS_INLINE double slow_update_k(mrvi_predictor *pr, const mrvi_step *st,
                                   double *restrict x, int keep, const int ns) {
  double r = 0.0;
  UNROLL for (int s = 0; s < ns; s++) {
    const double xn = st->dT * pr->minv[s] * (st->ps0[s] - pr->fs[s]);
    if (keep) {
      const double d = fabs(xn - x[s]) / (st->dT * pr->minv[s]);
      r = d > r ? d : r;
      pr->xs[s] = x[s];
    }
    x[s] = xn;
  }
  return r;
}

/* Slow row solved for dq^s = x_s with the slow force fs; with keep, the
 * old x_s kept in xs and the change M |x_s' - x_s| / dT (slow_change)
 * returned, else 0. */
static double slow_update(mrvi_predictor *pr, const mrvi_step *st, double *x,
                          int keep) {
  double r = 0.0;
  SMALL(st->ns, NS, r = slow_update_k(pr, st, x, keep, NS));
  return r;
}

/* Slow-row force of the sampled points (see slow_newton) at the slow
 * displacement x_s = x[0..ns) with the fast nodes of x: f = sum over the
 * samples of sw w a0 grad_s Z (the change of the force: sw scaled to the
 * sum of w a0 a1), fa (if not NULL) = sum of sf w a0 grad_s Z (the force
 * itself: sf scaled to the sum of w a0 of the points with a0 a1 != 0),
 * and, with hess, H = sum over every hstride-th sample of
 * hfac sw w a0 a1 hess Z (packed, n x n, the slow block). */
ALWAYS_INLINE void sampled_force_k(mrvi_predictor *pr, const mrvi_step *st,
                                   const double *x, double *f, double *fa,
                                   int hess, const int ns, const int nf) {
  const int n = ns + nf;
  UNROLL for (int s = 0; s < ns; s++) f[s] = 0.0;
  if (fa)
    UNROLL for (int s = 0; s < ns; s++) fa[s] = 0.0;
  if (hess)
    memset(pr->H, 0, (size_t)n * (size_t)n * sizeof(double));
  for (int i = 0; i < pr->n_samples; i++) {
    const int c = pr->sample[i] < 0 ? 1 : 0;
    const int ip = pr->sample[i] < 0 ? -pr->sample[i] - 1 : pr->sample[i];
    const mrvi_point *pt = &st->pts[c][ip];
    const double w = pr->sample_w[c] * pt->w * pt->a0;
    const int h = hess && i % pr->hstride == pr->hstride / 2;
    point_gradient_k(pr, st, x, pt, c, ns, nf, h ? pr->H : NULL,
                     pr->hfac * w * pt->a1, 0);
    axpy(ns, w, pr->g, f);
    if (fa)
      axpy(ns, pr->sample_f[c] * pt->w * pt->a0, pr->g, fa);
  }
}

static void sampled_force(mrvi_predictor *pr, const mrvi_step *st,
                          const double *x, double *f, double *fa, int hess) {
  SMALL2(st->ns, NS, st->nf, NF,
         sampled_force_k(pr, st, x, f, fa, hess, NS, NF));
}

/* The fast nodes the samples read (jnode) for the slow displacement x_s,
 * with V held at its gradient at node k (gnode) and W's constant Hessian:
 * every fast row is then linear with the same matrix (linear_step), the
 * state (d, p^f) goes from one needed node to the next by the affine map
 * kept for that jump, with c_A = S_A c + V_A g, c_B = S_B c + V_B g,
 * c = g0 + H q_k^f, g the fast part of V's gradient in gnode, S_A = sum w cA,
 * S_B = sum w cB over an interval's W points and V_A, V_B over its V points
 * (lsum). Two products of size 2 nf per needed node, whatever p; the other fast
 * nodes of x are left as they are (the sweep after the pre-solve writes
 * them all). */
ALWAYS_INLINE void linear_nodes_k(mrvi_predictor *pr, const mrvi_step *st,
                                  double *x, const int ns, const int nf) {
  const int nz = ns + nf, n2 = 2 * nf;
  const double *restrict H = pr->Hq[1] + (size_t)ns * nz + ns;
  const double *restrict g0 = pr->g0[1] + ns, *restrict gv = pr->gnode + ns;
  const double *L = pr->lsum;
  double c[2 * nf], s[2 * nf], t[2 * nf];
  UNROLL for (int f = 0; f < nf; f++) {
    double a = g0[f];
    UNROLL for (int j = 0; j < nf; j++) a += H[f * nz + j] * st->qf0[j];
    c[f] = L[0] * a + L[6] * gv[f];
    c[nf + f] = L[3] * a + L[7] * gv[f];
    s[f] = 0.0;
    s[nf + f] = st->pf0[f];
  }
  for (int k = 0; k < pr->n_jumps; k++) {
    const double *restrict M = pr->jmat + (size_t)k * 2 * n2 * n2;
    const double *restrict S = M + n2 * n2;
    UNROLL for (int i = 0; i < n2; i++) {
      double a = 0.0;
      UNROLL for (int j = 0; j < n2; j++) a +=
          M[i * n2 + j] * s[j] + S[i * n2 + j] * c[j];
      t[i] = a;
    }
    UNROLL for (int i = 0; i < n2; i++) s[i] = t[i];
    double *restrict d = x + ns + (size_t)(pr->jnode[k] - 1) * nf;
    UNROLL for (int f = 0; f < nf; f++) d[f] = s[f];
  }
}

static void linear_nodes(mrvi_predictor *pr, const mrvi_step *st, double *x) {
  SMALL2(st->ns, NS, st->nf, NF, linear_nodes_k(pr, st, x, NS, NF));
}

static double slow_change(const mrvi_predictor *pr, const mrvi_step *st,
                          const double *x) {
  double r = 0.0;
  for (int s = 0; s < st->ns; s++) {
    const double d = fabs(x[s] - pr->xs[s]) / (st->dT * pr->minv[s]);
    r = d > r ? d : r;
  }
  return r;
}

/* J (ns x ns) = M / dT + (with hess) the slow block of pr->H: the first
 * Jacobian of the slow row's secant solves (broyden, mrvi_predict_shoot). */
static void slow_jacobian(const mrvi_predictor *pr, const mrvi_step *st,
                          int hess, double *J) {
  const int ns = st->ns, n = ns + st->nf;
  for (int i = 0; i < ns; i++) {
    const double mdt = 1.0 / (st->dT * pr->minv[i]);
    for (int j = 0; j < ns; j++)
      J[i * ns + j] = (hess ? pr->H[i * n + j] : 0.0) + (i == j ? mdt : 0.0);
  }
}

/* Broyden's rank-one update of a row Ji (n) of the Jacobian from the
 * change du of its residual over the step dy (dd = dy^T dy):
 * Ji += (du - Ji dy) dy^T / dd; none for dd = 0. */
static void broyden_row(double *Ji, double du, const double *dy, double dd,
                        int n) {
  if (!(dd > 0.0))
    return;
  double u = du;
  for (int j = 0; j < n; j++)
    u -= Ji[j] * dy[j];
  for (int j = 0; j < n; j++)
    Ji[j] += u * dy[j] / dd;
}

/* dy = -J^-1 r (ns; J copied to pr->A and factored there); -1 if J is
 * singular. */
static int secant_step(mrvi_predictor *pr, int ns, const double *J,
                       const double *r, double *dy) {
  memcpy(pr->A, J, (size_t)ns * (size_t)ns * sizeof(double));
  memcpy(dy, r, (size_t)ns * sizeof(double));
  if (mrvi_dense_solve(ns, pr->A, dy) < 0)
    return -1;
  for (int i = 0; i < ns; i++)
    dy[i] = -dy[i];
  return 0;
}

/* Broyden's method for the slow row with the fast nodes held, from
 * y = x[0..ns) (written to x): the Jacobian M / dT + H~ with the sampled
 * Hessian H~ evaluated once per step (at the first call's y, pr->h_ok),
 * then corrected by a rank-one update from every iteration's change of
 * the residual (superlinear convergence from gradients alone).  The
 * residual: with pre, M (y - x_V) / dT + F(y) - F_k (pre_solve: x_V the
 * slow update with every point at node k, in xv, F the absolute sampled
 * force, F_k its value with every point at node k, fk); else
 * M (y - x_s') / dT + F~(y) - F~(x_s) (sampled_solve: x_s' in xv, F~ the
 * sampled force, f0 = F~(x_s)).  Stops where an update moves y by at
 * most stop (in M |dy| / dT). */
static void broyden(mrvi_predictor *pr, const mrvi_step *st, double *x,
                    const double *xv, int pre, double stop) {
  const int ns = st->ns;
  double *f0 = pr->xs + ns, *f = pr->xs + 2 * ns;
  double *J = pr->A + ns * ns, *r = pr->b + 2 * ns, *dy = pr->b + 3 * ns;
  sampled_force(pr, st, x, f0, pre ? f : NULL, !pr->h_ok);
  pr->h_ok = 1;
  slow_jacobian(pr, st, 1, J);
  for (int i = 0; i < ns; i++) {
    const double mdt = 1.0 / (st->dT * pr->minv[i]);
    r[i] = mdt * (x[i] - xv[i]) + (pre ? f[i] - pr->fk[i] : 0.0);
  }
  for (int it = 0; it < pr->tn.slow_newton_max; it++) {
    if (it > 0) {
      /* r at the new y; J += (r_new - r - J dy) dy^T / (dy^T dy) */
      sampled_force(pr, st, x, pre ? f0 : f, pre ? f : NULL, 0);
      double dd = 0.0;
      for (int i = 0; i < ns; i++)
        dd += dy[i] * dy[i];
      for (int i = 0; i < ns; i++) {
        const double mdt = 1.0 / (st->dT * pr->minv[i]);
        const double rn =
            mdt * (x[i] - xv[i]) + f[i] - (pre ? pr->fk[i] : f0[i]);
        broyden_row(J + i * ns, rn - r[i], dy, dd, ns);
        r[i] = rn;
      }
    }
    if (secant_step(pr, ns, J, r, dy) < 0)
      return;
    double step = 0.0;
    for (int i = 0; i < ns; i++) {
      x[i] += dy[i];
      step = fmax(step, fabs(dy[i]) / (st->dT * pr->minv[i]));
    }
    if (!(step > stop))
      return;
  }
}

/* y solving M (y - x_s') / dT + F~(y) - F~(x_s) = 0 (x_s, the swept path,
 * in xs; x_s' in x, y written to x) from y = x_s. */
static void sampled_solve(mrvi_predictor *pr, const mrvi_step *st, double *x) {
  const int ns = st->ns;
  double *xf = pr->b + ns;
  memcpy(xf, x, (size_t)ns * sizeof(double));
  memcpy(x, pr->xs, (size_t)ns * sizeof(double));
  broyden(pr, st, x, xf, 0, 1e-3 * pr->rstop);
}

/* The slow row solved before the sweep (where pr->pre): the fast nodes
 * from linear_nodes along the slow update x_V = x[0..ns) with every point
 * at node k, then the slow row M (y - x_V) / dT + F(y) - F_k = 0 on the
 * samples along them (broyden), to 0.1 rsweep: the sweep then runs along
 * a slow path that the sampled solve after it moves by less than rsweep,
 * and no second sweep is needed (FPU, dT = 1: the change after it
 * 2e-4 .. 1e-3, against 0.16 .. 0.57 from x_V). */
static void pre_solve(mrvi_predictor *pr, const mrvi_step *st, double *x) {
  const int ns = st->ns;
  double *xv = pr->b + ns;
  linear_nodes(pr, st, x);
  memcpy(xv, x, (size_t)ns * sizeof(double));
  broyden(pr, st, x, xv, 1, 0.1 * pr->rsweep);
  pr->presolved = 1;
}

/* The slow row solved along the swept path (doc/solver.md, "Predictor").
 * On entry x_s = x[0..ns) is the slow displacement the fast nodes were
 * swept along and fs the slow-row force of the points of that path.  The
 * fixed-point update x_s' = dT M^-1 (p_k^s - fs) contracts by about
 * dT^2 |M^-1 hess V| / 3, enough at small dT.  Where the change it makes,
 * r = M |x_s' - x_s| / dT (the slow row's residual on the swept path), is
 * above rstop (or after a pre-solve), the slow row is instead solved by
 * Broyden's method with the fast nodes held, the change of the force along the
 * path taken from a sample of its points (sampled_solve, cost independent of
 * p); where that moves x_s by more than rsweep (same measure), the fast nodes
 * are swept again along the new slow path and the slow row solved again.  What
 * the sampled solve leaves out, the response of the fast nodes to x_s and the
 * sample's quadrature error, is a small fraction of its change (about 1e-3
 * of it on the FPU chain; doc/performance/paths.md, "Tuning constants").  Every
 * step of this depends on (q_k, p_k) only. */
static void slow_newton(mrvi_predictor *pr, const mrvi_step *st, double *x) {
  const double r = slow_update(pr, st, x, 1);
  /* (after the pre-solve the slow row is close, but not to the
   * tolerance: always solved) */
  if (!pr->H || !(r > (pr->presolved ? 0.0 : pr->rstop)))
    return;
  for (int k = 0; k < pr->tn.slow_newton_max; k++) {
    sampled_solve(pr, st, x);
    if (!(slow_change(pr, st, x) > pr->rsweep) ||
        k == pr->tn.slow_newton_max - 1)
      return;
    sweep(pr, st, x, 1);
    slow_update(pr, st, x, 1);
  }
}

/* Whether the prediction for Newton (or, with shoot, for shooting) takes
 * the pre-solve: where it is available (pr->pre) and the fixed-point
 * contraction is above that one's threshold. */
static int use_pre(const mrvi_predictor *pr, int shoot) {
  return pr->pre &&
         pr->kappa > (shoot ? pr->tn.shoot_pre_kappa : pr->tn.pre_kappa);
}

/* The prediction up to the sweep: the gradients at node k, the slow row
 * with every point there and, with pre, the pre-solve. */
static void predict_start(mrvi_predictor *pr, const mrvi_step *st, double *x,
                          int pre) {
  pr->h_ok = 0;
  /* Slow row with every point at node k: sum_pts w a0 grad Z_c(q_k). */
  if (pr->ppar)
    node_gradients_par(pr, st);
  else
    SMALL2(st->ns, NS, st->nf, NF, node_gradients_k(pr, st, NS, NF));
  if (pre) { /* for pre_solve */
    const int n = st->ns + st->nf;
    for (int s = 0; s < st->ns; s++)
      pr->fk[s] = pr->wk[0] * pr->gnode[s] + pr->wk[1] * pr->gnode[n + s];
  }
  slow_update(pr, st, x, 0);
  pr->presolved = 0;
  if (pre && pr->slow_coupled)
    pre_solve(pr, st, x);
}

/* With the micro-node constraints (pr->js): q_{k+1}^s against the force of
 * the swept multipliers (M_s dq^s / dT moved by dT M_s^-1 of it) and onto
 * the slow-only constraints, and the fast nodes swept again along it.  The
 * elbow of a light link hanging on a heavy slow body follows the slow
 * path interpolated ((4.8)), so its multipliers at node 0 are as wrong as
 * q_{k+1}^s / p, and their error is carried through every later node;
 * the slow body's response to the links is small (their mass over its),
 * so one correction suffices (doc/solver.md, "The joint sweep"). */
static void joints_slow_end(mrvi_predictor *pr, const mrvi_step *st,
                            double *x) {
  double *fj = pr->b; /* (ns) */
  memset(fj, 0, (size_t)st->ns * sizeof *fj);
  mrvi_joint_sweep_slow_force(pr->js, st, x, fj);
  for (int s = 0; s < st->ns; s++)
    x[s] -= st->dT * pr->minv[s] * fj[s];
  mrvi_joint_sweep_slow(pr->js, st, x);
  pr->n_sweeps++;
  sweep_joints(pr, st, x, 0, 1);
}

static void predict_sweep(mrvi_predictor *pr, const mrvi_step *st, double *x) {
  pr->n_sweeps = 0;
  if (!pr->sweep_ok) {
    mrvi_predict_free_flight(st, x);
    return;
  }
  predict_start(pr, st, x, use_pre(pr, 0));
  if (!pr->slow_coupled || st->ns == 0) {
    sweep(pr, st, x, 0);
  } else {
    /* The slow row again with its points along the swept path.  (Sweeping
     * the fast nodes once more along the corrected slow path saves no
     * Newton update: doc/performance/paths.md, "Tuning constants".) */
    sweep(pr, st, x, 1);
    slow_newton(pr, st, x);
  }
  if (pr->js && st->ns > 0)
    joints_slow_end(pr, st, x);
}

void mrvi_predict_checked(mrvi_predictor *pr, const mrvi_step *st, double *x) {
  predict_sweep(pr, st, x);
  /* Any entry NaN or infinite (x * 0 is NaN exactly then; no branch per
   * entry): free flight instead (and, with the joint sweep, the
   * multipliers it set from zero). */
  const int nx = pr->js ? st->n_total : st->n_unknowns;
  double bad;
  if (pr->ppar) { /* (on threads in CHECK_PARTS parts of nx: the sum is a
                     zero or NaN in any order, the same test) */
    enum { CHECK_PARTS = 8 };
    double bp[CHECK_PARTS];
    MRVI_PARALLEL_FOR(pr->pthreads)
    for (int c = 0; c < CHECK_PARTS; c++) {
      double b = 0.0;
      for (int i = mrvi_part_start(c, nx, CHECK_PARTS);
           i < mrvi_part_start(c + 1, nx, CHECK_PARTS); i++)
        b += x[i] * 0.0;
      bp[c] = b;
    }
    bad = 0.0;
    for (int c = 0; c < CHECK_PARTS; c++)
      bad += bp[c];
  } else {
    double b4[4] = {0.0, 0.0, 0.0, 0.0}; /* (four independent sums) */
    int i = 0;
    for (; i + 4 <= nx; i += 4)
      for (int j = 0; j < 4; j++)
        b4[j] += x[i + j] * 0.0;
    for (; i < nx; i++)
      b4[0] += x[i] * 0.0;
    bad = (b4[0] + b4[1]) + (b4[2] + b4[3]);
  }
  if (bad != 0.0 || bad != bad) {
    mrvi_predict_free_flight(st, x);
    if (pr->js)
      memset(x + st->n_unknowns, 0, (size_t)st->n_lambda * sizeof *x);
  }
}

/* Shooting (doc/solver.md, "Newton details"): where the sweep solves
 * every fast row exactly (no implicit points, or W's alone and affine
 * (wexact); mrvi_predictor_shoot_ok),
 * the fast nodes are a function of the slow displacement x_s and the step
 * reduces to the slow row G(x_s) = M x_s / dT - p_k^s + F(x_s) = 0, F the
 * slow-row force of the points along the fast nodes swept for x_s.  From
 * the predictor's start (predict_start: x_s the Stoermer-Verlet slow
 * update, or the pre-solve's), each cycle sweeps the fast nodes along x_s
 * (G exact, the fast rows solved to round-off) and, unless G is within
 * target after at least one update, updates x_s by -J^-1 G: J = M / dT +
 * a Hessian term chosen by kappa (below; the response of the fast nodes
 * left out), corrected by Broyden's rank-one update from each cycle's
 * change of G, which brings that response in along the updates made.
 * Where the last contraction says the next update lands an order below
 * target, that update is made without its sweep: it moves x_s by so
 * little that the fast rows it leaves change by about (3 kappa / p) |G|,
 * far below target too; the caller accepts on the exact residual.
 * Returns 1 with x solved (*cycles updates, the fast nodes swept for x's
 * x_s), 2 with the last update unswept, 0 after max updates without
 * reaching target (x usable as a Newton iterate; *cycles 0: not
 * predicted), -1 on non-finite values (x unusable). */
int mrvi_predict_shoot(mrvi_predictor *pr, const mrvi_step *st, double *x,
                       double target, int max, int *cycles) {
  const int ns = st->ns, n = ns + st->nf;
  double *J = pr->A + (size_t)ns * (size_t)ns;
  double *G = pr->b, *Gp = pr->b + ns, *ds = pr->b + 2 * ns;
  double rp = INFINITY; /* the last cycle's |G| */
  *cycles = 0;
  pr->n_sweeps = 0;
  predict_start(pr, st, x, use_pre(pr, 1));
  /* The Hessian term: where the fixed-point update contracts enough, none
   * (M / dT alone: the samples' Hessians cost as much as a sweep at
   * p = 10); at large dT every point's, summed in the first sweep (the
   * samples' misses the fast oscillation of hess V: 10 % of the update at
   * dT = 1 on the FPU); else the samples'. */
  const int hess = pr->kappa > pr->tn.shoot_hess_kappa,
            full = pr->kappa > pr->tn.shoot_full_kappa;
  for (int c = 0;; c++) {
    if (full && c == 0) {
      memset(pr->H, 0, (size_t)n * (size_t)n * sizeof(double));
      for (int k = 0; k < 2; k++)
        if (pr->dsum[k])
          memset(pr->dsum[k], 0,
                 (size_t)mrvi_terms_count(pr->kc[k]) * sizeof(double));
      pr->hsum = 1;
      sweep(pr, st, x, 1);
      pr->hsum = 0;
      for (int k = 0; k < 2; k++)
        if (pr->dsum[k])
          mrvi_terms_hess_d2(pr->kc[k], pr->dsum[k], pr->H, n, ns);
    } else
      sweep(pr, st, x, 1);
    if (c == 0 && hess && !full && !pr->h_ok) { /* (f scratch) */
      sampled_force(pr, st, x, pr->xs + ns, NULL, 1);
      pr->h_ok = 1;
    }
    if (c == 0)
      slow_jacobian(pr, st, hess, J);
    double r = 0.0;
    for (int i = 0; i < ns; i++) {
      G[i] = x[i] / (st->dT * pr->minv[i]) - st->ps0[i] + pr->fs[i];
      r = fmax(r, fabs(G[i]));
    }
    if (!isfinite(r))
      return -1;
    *cycles = c;
    if (c >= 1 && r <= target)
      return 1;
    if (c == max)
      return 0;
    /* The last update without its sweep (above): a fast row's residual
     * changes by about dt |hess_fs Z| |ds| ~ 3 kappa |G| / p. */
    const double fast = 3.0 * pr->kappa / st->p;
    const int last =
        c >= 1 && r * fmax(r / rp, fast) <= pr->tn.shoot_last * target;
    rp = r;
    if (c >= 1) { /* J += (G - Gp - J ds) ds^T / (ds^T ds) */
      double dd = 0.0;
      for (int i = 0; i < ns; i++)
        dd += ds[i] * ds[i];
      for (int i = 0; i < ns; i++)
        broyden_row(J + i * ns, G[i] - Gp[i], ds, dd, ns);
    }
    if (secant_step(pr, ns, J, G, ds) < 0)
      return 0;
    for (int i = 0; i < ns; i++) {
      x[i] += ds[i];
      Gp[i] = G[i];
    }
    if (last) {
      *cycles = c + 1;
      return 2;
    }
  }
}

int mrvi_predictor_exact_inside(const mrvi_predictor *pr) {
  return pr->one && pr->wexact;
}

int mrvi_predictor_shoot_ok(const mrvi_predictor *pr, const mrvi_step *st) {
  return pr->sweep_ok && pr->slow_coupled && pr->H && st->ns >= 1 &&
         st->p >= 2 &&
         (!pr->has_kind[INSIDE] || mrvi_predictor_exact_inside(pr)) &&
         pr->kappa <= pr->tn.shoot_kappa;
}

void mrvi_predictor_set_tolerance(mrvi_predictor *pr, double tol) {
  /* A Newton step from a slow-row residual r leaves about r^2 (the
   * quadratic constant of the FPU's slow row is 0.2..1 per unit momentum):
   * above rstop = (0.01 tol)^(1/4), a fixed-point update would leave more
   * than sqrt(0.01 tol), from where one Newton update of the step lands at
   * the 0.01 tol where the updates stop (integrator.c).  The fast path,
   * swept along the old slow path, lags a sampled solve's change by a
   * small fraction of it, hence a new sweep only above 10 rstop (the factor
   * and its measurement: doc/performance/paths.md, "Tuning constants"). */
  pr->rstop = pow(0.01 * tol, 0.25);
  pr->rsweep = 10.0 * pr->rstop;
}

int mrvi_predictor_presolve(mrvi_predictor *pr, int on) {
  const int was = use_pre(pr, 0);
  pr->pre = was && on;
  return was;
}

int mrvi_predictor_sweeps(const mrvi_predictor *pr) { return pr->n_sweeps; }

/* omega_max of the fast part on the micro-node constraints at q0, the slow
 * part held: power iteration on P M_f^-1/2 hess_ff(V + W)(q0) M_f^-1/2 P,
 * P the projector onto the null space of G_f(q0) M_f^-1/2 (G_f the
 * micro-node constraints' gradient in the fast coordinates; the
 * multipliers' curvature, sum lambda hess g, left out).  The joint sweep
 * keeps the fast nodes on these constraints, so the frequencies it meets
 * are these, not those of the unconstrained hess(V + W): on the flexible
 * pendulum 320 rad/s unconstrained (the wrist spring on one link's
 * directors) against the wrist's 156 with the arm held (doc/solver.md,
 * "The joint sweep's step bound on the constrained frequencies").  -1 if
 * out of memory. */
static double joints_omega(mrvi_predictor *pr, const mrvi_step *st) {
  const mrvi_model *m = pr->m;
  const int nf = st->nf, ns = st->ns;
  const size_t ni = (size_t)(m->max_constraint_in > 0 ? m->max_constraint_in
                                                      : 1),
               r = (size_t)st->r_micro;
  double *Q = malloc((r + 1) * (size_t)nf * sizeof *Q),
         *y = malloc((ni + r + r * ni) * sizeof *y),
         *wk = malloc(6 * (size_t)m->n * sizeof *wk);
  if (!Q || !y || !wk) {
    free(Q);
    free(y);
    free(wk);
    return -1.0;
  }
  double *g = y + ni, *G = g + r;
  int nq = 0;
  for (int i = 0; i < st->n_micro_c; i++) {
    const mrvi_constraint *k = &m->constraints[st->micro_c[i]];
    for (int j = 0; j < k->n_in; j++)
      y[j] = m->q0[k->in[j]];
    mrvi_constraint_eval_at(k, y, g, G, NULL);
    for (int row = 0; row < k->rows; row++) {
      double *b = Q + (size_t)nq * (size_t)nf;
      memset(b, 0, (size_t)nf * sizeof *b);
      for (int j = 0; j < k->n_in; j++) {
        const int c = k->in[j], s = m->slot[c];
        if (m->rate[c] == MRVI_FAST)
          b[s] += G[row * k->n_in + j] * sqrt(pr->minv[ns + s]);
      }
      nq += mrvi_dense_extend_basis(nf, Q, nq, b, 1e-10);
    }
  }
  const double w = power_iteration(pr, Q, nq, wk);
  free(Q);
  free(y);
  free(wk);
  return w;
}

int mrvi_predictor_set_joints(mrvi_predictor *pr, mrvi_joint_sweep *w,
                              const mrvi_step *st) {
  if (w && !pr->ju &&
      !(pr->ju = malloc((size_t)(pr->m->n_fast + 1) * sizeof(double))))
    return MRVI_ENOMEM;
  pr->js = w;
  /* (the explicit sweep's bound dt omega_max <= 1/2 on the frequencies
   * the joint sweep meets, and dt omega_max <= 1 on the unconstrained ones:
   * its explicit rows take the unconstrained forces before each move, and
   * Stoermer-Verlet is stable on them only for dt omega < 2; the
   * spacecraft's panels, 36 rad/s on their joints and 1 225 unconstrained,
   * blew up to 1e175 at p = 5 under the first bound alone) */
  if (w && st->tuning.joints_omega) {
    const double om = joints_omega(pr, st);
    if (om < 0.0)
      return MRVI_ENOMEM;
    pr->sweep_ok = st->dt * om <= 0.5 && st->dt * pr->omega <= 1.0;
  }
  return MRVI_OK;
}

int mrvi_predictor_one_point(mrvi_predictor *pr, int on) {
  const int was = pr->one;
  pr->one = pr->one_ok && on;
  return was;
}
