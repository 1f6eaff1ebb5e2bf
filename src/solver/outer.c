/* Matrix-free step of schur-krylov (doc/solver.md, "schur-krylov: the
 * outer iteration"): a nonlinear block Gauss-Seidel iteration on the slow
 * and fast rows of an unconstrained step, with no Jacobian assembled.
 *
 * Rows (step.c; x as displacements from (q_k^s, q_k^{f,0})):
 *   slow    G = p_k^s - M^s x_s/dT - sum_pts w a0 grad_s Z(z)
 *   fast m  F_m = p^{f,m} - M^f (d^{m+1} - d^m)/dt - sum_{pts of m} w cA
 *           grad_f Z(z),
 *           p^{f,m+1} = M^f (d^{m+1} - d^m)/dt - sum_{pts of m} w cB grad_f Z
 * (eq:pkfm+), every point z = (q_k^s + a1 x_s, q_k^{f,0} + cA d^m + cB
 * d^{m+1}).  With x_s held, fast row m involves d^{m-1}, d^m, d^{m+1}
 * only: the fast rows are solved by a forward sweep, row m for d^{m+1} by
 * the Jacobi chord d^{m+1} += (dt/M^f) F_m (one gradient of the interval's
 * points per update; dF_m/dd^{m+1} = -(M^f/dt + sum w cA cB hess_ff Z),
 * so it contracts by about (omega dt)^2/4).  The sweep also sums the slow
 * row's forces at the converged points, which gives G exactly; then x_s +=
 * (dT/M^s) G (dG/dx_s = -(M^s/dT + sum w a0 a1 hess_ss Z) - A_sf
 * A_ff^-1 A_fs, contracting by about dT^2 |M_s^-1 hess_ss V|/6 plus the
 * weak slow-fast coupling), mixed with the last iterates by Anderson's
 * acceleration (slow_update), and the sweep runs again from the fast nodes
 * of the last one, each shifted first by the change of the nodes before it
 * in this sweep, extrapolated (the response to the slow update is smooth
 * in m).  The rows of a sweep are solved only as far as the slow residual
 * makes worthwhile (OUTER_CUT).  It stops after a sweep in which the slow
 * row and every fast row met the target: that sweep evaluated each row at
 * the final x, so this is the step's exact residual.  A row or slow update
 * that contracts by less than outer_rate, more than outer_max sweeps or
 * row updates, or non-finite values end it unconverged: the caller then
 * takes Newton from its predictor.  A step depends on its known data and
 * x's start alone. */
#include "solver/solver.h"
#include "util/simd.h"

#include <float.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif

/* The factor of the inexact sweeps, and the depth of Anderson's
 * acceleration of the slow updates (mrvi_outer_solve). */
#define OUTER_CUT 1e-3
#define OUTER_AA 3
/* Doubles per lane in a slot of the partial sums (a cache line). */
#define RED 8

/* The points of one interval with the same configuration evaluated once:
 * a site (a0, a1, cA, cB) with the classes evaluated there and one weight
 * (points of V and W with the same coefficients and weight share a site,
 * midpoint-midpoint's). */
typedef struct site {
  double w, a0, a1, cA, cB;
  int cls;   /* bit c: class c is evaluated here */
  int grp;   /* its slow group (slow_group) */
  int rs;    /* its terms on fast columns read slow ones too (else g's slow
                part stays zero, and z's slow part is not needed) */
  double *g; /* gradient of the terms on fast columns at the site (ns + nf
                packed) */
} site;

/* The terms on slow columns alone depend on x_s alone, fixed during a
 * sweep: their gradient at a slow configuration (a1, the classes cls) is
 * evaluated once per sweep for all the sites that share it, and only the
 * slow row and p_{k+1}^s read it (a fast row reads the fast columns). */
typedef struct slow_group {
  double a1;
  int cls;
  double *g; /* ns */
} slow_group;

/* One thread of the iteration: mrvi_outer_solve runs on o->n_lanes
 * threads in one parallel region (where a class's gradient is in parts,
 * mrvi_terms_set_threads), every thread through the same rows and
 * decisions, each taking its span of the vector loops (a fixed share of
 * the columns), its share of the gradients' parts, and the team's
 * maxima and sums (team_reduce) from the same partial values in the same
 * order: the same bits for every thread count.  What the serial iteration
 * kept on the object and changes is the lane's own. */
typedef struct lane {
  int tid, nth;
  long sweep;            /* the sweep under way (its number in stats.sweeps) */
  const site *z_site[2]; /* zb[b]'s slow part: site z_site[b]'s in sweep
                            z_sweep[b] */
  long z_sweep[2];
  int own;         /* the fast-column classes in the lanes' own parts (o->own, a
                      full team): no barrier after their gradients */
  int own_ss;      /* the same for the slow-only classes (o->own_ss) */
  int dirty;       /* bit b: zb[b] (b = 2: o->zs) read by a gradient since
                      the team's last barrier (written only after one,
                      z_sync) */
  long *grp_sweep; /* per slow group: its g is at x_s of this sweep (0:
                      none yet) */
  double *dlt[3];  /* the changes of the last three nodes (o->dlt) */
  int met;         /* every row of the sweep met its target */
  int n_red;       /* reductions made (team_reduce's slot parity) */
} lane;

struct mrvi_outer {
  int ns, nf, p;
  /* V and W on the packed columns (q^s, q^f): the terms with an input
   * on a fast column, and those on slow columns alone */
  mrvi_terms *kc[2], *kss[2];
  int slow_in[2];               /* kc[c] has a term with a slow input */
  double share[2], share_ss[2]; /* kc[c]'s and kss[c]'s share of the terms
                                   of both classes (stats.grad_equiv) */
  site *sites;                  /* by interval */
  slow_group *grps;
  int n_grps;
  double *zs; /* a slow configuration (ns) */
  int *send;  /* p + 1: sites of interval m are send[m] .. send[m+1]-1 */
  double *minv_s, *minv_f, *m_s, *m_f;
  double *mdt, *dtm; /* M^f/dt, dt/M^f */
  int eq_f;          /* the fast masses are equal: mdt[0], dtm[0] for
                        every column (bitwise each column's) */
  double *zero;      /* nf zeros */
  double *zb[2];     /* packed configurations: the fused row pass
                        writes the next iterate's into the other one */
  int own;    /* kc's parts: n_lanes, part t the columns of lane t's spans of
                 the slow and the fast columns (mrvi_terms_set_threads_owner) */
  int own_ss; /* kss's the same */
  double *pm, *fexp, *F; /* p^{f,m}, the forces of node-m sites, F_m */
  double *fs;            /* slow-row force (ns) */
  /* the fused row pass (solve_row): the next iterate of d^{m+1} (nf) and
   * a spare gradient of the inside site, for sites whose terms on fast
   * columns read slow ones (galt[1]: its slow part zeroed before each use)
   * and for the others (galt[0]: its slow part stays zero) */
  double *nb, *galt[2];
  double *dlt[3]; /* the changes of the last three nodes, nf each */
  /* Anderson: the slow iterate and its update f = (dT/M^s) G before (ns
   * each) and the differences of the last OUTER_AA (ns x OUTER_AA each) */
  double *xp, *fp, *dX, *dF;
  /* the threads (lanes, up to n_lanes) and their partial maxima and sums
   * (team_reduce: two slots of RED doubles per lane) */
  lane *lanes;
  int n_lanes;
  double *red;
  long *grp_sweeps;       /* n_lanes x n_grps (the lanes' grp_sweep) */
  mrvi_outer_stats stats; /* of the run */
};

/* Lane L's span [*lo, *hi) of n items (all of them on one thread). */
static void span(const lane *L, int n, int *lo, int *hi) {
  *lo = (int)((long)n * L->tid / L->nth);
  *hi = (int)((long)n * (L->tid + 1) / L->nth);
}

void mrvi_outer_free(mrvi_outer *o) {
  if (!o)
    return;
  for (int c = 0; c < 2; c++) {
    mrvi_terms_free(o->kc[c]);
    mrvi_terms_free(o->kss[c]);
  }
  if (o->sites && o->send)
    for (int i = 0; i < o->send[o->p]; i++)
      free(o->sites[i].g);
  for (int i = 0; o->grps && i < o->n_grps; i++)
    free(o->grps[i].g);
  free(o->grps);
  free(o->zs);
  free(o->sites);
  free(o->send);
  free(o->minv_s);
  free(o->minv_f);
  free(o->m_s);
  free(o->m_f);
  free(o->mdt);
  free(o->dtm);
  free(o->zero);
  free(o->zb[0]);
  free(o->zb[1]);
  free(o->pm);
  free(o->fexp);
  free(o->F);
  free(o->fs);
  free(o->nb);
  free(o->galt[0]);
  free(o->galt[1]);
  for (int i = 0; i < 3; i++)
    free(o->dlt[i]);
  free(o->xp);
  free(o->fp);
  free(o->dX);
  free(o->dF);
  free(o->lanes);
  free(o->red);
  free(o->grp_sweeps);
  free(o);
}

static double *dalloc(size_t n) {
  return malloc((n > 0 ? n : 1) * sizeof(double));
}

int mrvi_outer_create(const mrvi_model *m, const mrvi_step *st,
                      mrvi_outer **out) {
  *out = NULL;
  mrvi_outer *o = calloc(1, sizeof *o);
  if (!o)
    return MRVI_ENOMEM;
  o->ns = st->ns;
  o->nf = st->nf;
  o->p = st->p;
  const size_t ns = (size_t)o->ns, nf = (size_t)o->nf, n = ns + nf;
  int *col = malloc((size_t)(m->n > 0 ? m->n : 1) * sizeof *col);
  const int npts = st->n_pts[0] + st->n_pts[1];
  o->sites = calloc((size_t)(npts > 0 ? npts : 1), sizeof *o->sites);
  o->grps = calloc((size_t)(npts > 0 ? npts : 1), sizeof *o->grps);
  o->zs = dalloc(ns);
  int *sel = NULL;
  {
    const int ne = st->n_elem_of_class[0] > st->n_elem_of_class[1]
                       ? st->n_elem_of_class[0]
                       : st->n_elem_of_class[1];
    sel = malloc((size_t)(ne > 0 ? ne : 1) * sizeof *sel);
  }
  o->send = calloc((size_t)o->p + 1, sizeof *o->send);
  o->minv_s = dalloc(ns);
  o->m_s = dalloc(ns);
  o->minv_f = dalloc(nf);
  o->m_f = dalloc(nf);
  o->mdt = dalloc(nf);
  o->dtm = dalloc(nf);
  o->zero = calloc(nf > 0 ? nf : 1, sizeof(double));
  o->zb[0] = dalloc(n);
  o->zb[1] = dalloc(n);
  o->pm = dalloc(nf);
  o->fexp = dalloc(nf);
  o->F = dalloc(nf);
  o->fs = dalloc(ns);
  o->nb = dalloc(nf);
  for (int i = 0; i < 3; i++)
    o->dlt[i] = dalloc(nf);
  o->xp = dalloc(ns);
  o->fp = dalloc(ns);
  o->dX = dalloc(ns * OUTER_AA);
  o->dF = dalloc(ns * OUTER_AA);
  if (!col || !sel || !o->sites || !o->grps || !o->zs || !o->send ||
      !o->minv_s || !o->m_s || !o->minv_f || !o->m_f || !o->mdt || !o->dtm ||
      !o->zero || !o->zb[0] || !o->zb[1] || !o->pm || !o->fexp || !o->F ||
      !o->fs || !o->nb || !o->dlt[0] || !o->dlt[1] || !o->dlt[2] || !o->xp ||
      !o->fp || !o->dX || !o->dF) {
    free(col);
    free(sel);
    mrvi_outer_free(o);
    return MRVI_ENOMEM;
  }
  for (int c = 0; c < m->n; c++)
    col[c] = (m->rate[c] == MRVI_SLOW ? 0 : m->n_slow) + m->slot[c];
  for (int s = 0; s < o->ns; s++) {
    o->m_s[s] = MRVI_MASS(m, m->slow_index[s]);
    o->minv_s[s] = 1.0 / o->m_s[s];
  }
  o->eq_f = 1;
  for (int f = 0; f < o->nf; f++) {
    o->m_f[f] = MRVI_MASS(m, m->fast_index[f]);
    o->eq_f &= o->m_f[f] == o->m_f[0];
    o->minv_f[f] = 1.0 / o->m_f[f];
    o->mdt[f] = o->m_f[f] / st->dt;
    o->dtm[f] = st->dt / o->m_f[f];
  }
  /* each class's terms split by their columns (the order kept); the
   * gradients of large spring classes on threads, in parts by records
   * (mrvi_terms_set_threads, the same bits for every count), doubled
   * until at most MRVI_TERMS_SPREAD of the records span parts; the
   * classes with a fast input in one part per thread instead, part t
   * owning lane t's spans of the slow and the fast columns (owner), so
   * that a lane reads in its spans only what it wrote there */
  int *owner = NULL;
  if (st->threads > 1) {
    owner = malloc((n > 0 ? n : 1) * sizeof *owner);
    if (!owner) {
      free(col);
      free(sel);
      mrvi_outer_free(o);
      return MRVI_ENOMEM;
    }
    for (int t = 0; t < st->threads; t++) {
      const lane L = {.tid = t, .nth = st->threads};
      int lo, hi;
      span(&L, o->ns, &lo, &hi);
      for (int s = lo; s < hi; s++)
        owner[s] = t;
      span(&L, o->nf, &lo, &hi);
      for (int f = lo; f < hi; f++)
        owner[o->ns + f] = t;
    }
  }
  o->own = o->own_ss = st->threads > 1;
  for (int c = 0; c < 2; c++)
    for (int part = 0; part < 2; part++) {
      int n_sel = 0;
      for (int i = 0; i < st->n_elem_of_class[c]; i++) {
        /* (col[j] < ns: input j slow) */
        const int r = mrvi_model_element_rates(m, MRVI_STEP_ELEM(st, c, i));
        const int slow_only = !(r & (1 << MRVI_FAST));
        if (slow_only == part)
          sel[n_sel++] = MRVI_STEP_ELEM(st, c, i);
        if (!part && !slow_only)
          o->slow_in[c] |= (r >> MRVI_SLOW) & 1;
      }
      mrvi_terms **kt = part ? &o->kss[c] : &o->kc[c];
      int rc =
          n_sel > 0 ? mrvi_terms_create_grad(m, sel, n_sel, col, kt) : MRVI_OK;
      if (rc == MRVI_OK && n_sel > 0 && owner &&
          n_sel >= 2 * st->tuning.thread_chunk)
        rc = mrvi_terms_set_threads_owner(*kt, st->threads, owner, (int)n,
                                          st->threads);
      if (part)
        o->own_ss &= !*kt || mrvi_terms_parts(*kt) == st->threads;
      else
        o->own &= !*kt || mrvi_terms_parts(*kt) == st->threads;
      if (rc == MRVI_OK && n_sel > 0)
        rc = mrvi_terms_set_threads_spread(
            *kt, st->threads, st->tuning.thread_chunk, 0, MRVI_TERMS_SPREAD);
      if (rc != MRVI_OK) {
        free(col);
        free(sel);
        free(owner);
        mrvi_outer_free(o);
        return MRVI_ENOMEM;
      }
    }
  free(col);
  free(sel);
  free(owner);
  const int n_terms = st->n_elem_of_class[0] + st->n_elem_of_class[1];
  for (int c = 0; c < 2 && n_terms > 0; c++) {
    o->share[c] = o->kc[c] ? (double)mrvi_terms_count(o->kc[c]) / n_terms : 0;
    o->share_ss[c] =
        o->kss[c] ? (double)mrvi_terms_count(o->kss[c]) / n_terms : 0;
  }
  /* Sites by interval: the points of both classes, merged where the
   * coefficients and weight agree. */
  int ns_ = 0;
  for (int mm = 0; mm < o->p; mm++) {
    o->send[mm] = ns_;
    for (int c = 0; c < 2; c++) {
      if (!o->kc[c] && !o->kss[c])
        continue;
      for (int ip = 0; ip < st->n_pts[c]; ip++) {
        const mrvi_point *pt = &st->pts[c][ip];
        if (pt->m != mm)
          continue;
        int at = -1;
        for (int i = o->send[mm]; i < ns_; i++) {
          const site *S = &o->sites[i];
          if (S->w == pt->w && S->a0 == pt->a0 && S->a1 == pt->a1 &&
              S->cA == pt->cA && S->cB == pt->cB && !(S->cls & (1 << c)))
            at = i;
        }
        if (at < 0) {
          at = ns_++;
          o->sites[at] = (site){.w = pt->w,
                                .a0 = pt->a0,
                                .a1 = pt->a1,
                                .cA = pt->cA,
                                .cB = pt->cB};
          if (!(o->sites[at].g = calloc(n, sizeof(double)))) {
            o->send[o->p] = ns_;
            mrvi_outer_free(o);
            return MRVI_ENOMEM;
          }
        }
        o->sites[at].cls |= 1 << c;
      }
    }
  }
  o->send[o->p] = ns_;
  /* the slow groups of the sites (those with slow-only terms) */
  for (int i = 0; i < ns_; i++) {
    site *S = &o->sites[i];
    const int cls = S->cls & ((o->kss[0] ? 1 : 0) | (o->kss[1] ? 2 : 0));
    S->grp = -1;
    for (int c = 0; c < 2; c++)
      S->rs |= (S->cls >> c & 1) && o->kc[c] && o->slow_in[c];
    /* (a spare gradient of each kind the inside sites need) */
    if (S->cA != 0.0 && S->cB != 0.0 && !o->galt[S->rs] &&
        !(o->galt[S->rs] = calloc(n, sizeof(double)))) {
      mrvi_outer_free(o);
      return MRVI_ENOMEM;
    }
    if (!cls)
      continue;
    for (int j = 0; j < o->n_grps; j++)
      if (o->grps[j].a1 == S->a1 && o->grps[j].cls == cls)
        S->grp = j;
    if (S->grp < 0) {
      slow_group *G = &o->grps[o->n_grps];
      *G = (slow_group){.a1 = S->a1, .cls = cls, .g = dalloc(ns)};
      if (!G->g) {
        mrvi_outer_free(o);
        return MRVI_ENOMEM;
      }
      S->grp = o->n_grps++;
    }
  }
  /* the lanes: the threads where a class's gradient is in parts */
  int parts = 0;
  for (int c = 0; c < 2; c++)
    parts |= (o->kc[c] && mrvi_terms_parts(o->kc[c]) > 0) ||
             (o->kss[c] && mrvi_terms_parts(o->kss[c]) > 0);
  o->n_lanes = parts && st->threads > 1 ? st->threads : 1;
#ifndef _OPENMP
  o->n_lanes = 1;
#endif
  o->lanes = calloc((size_t)o->n_lanes, sizeof *o->lanes);
  o->red = dalloc(2 * RED * (size_t)o->n_lanes);
  o->grp_sweeps = calloc((size_t)o->n_lanes * (size_t)(o->n_grps + 1),
                         sizeof *o->grp_sweeps);
  if (!o->lanes || !o->red || !o->grp_sweeps) {
    mrvi_outer_free(o);
    return MRVI_ENOMEM;
  }
  for (int t = 0; t < o->n_lanes; t++)
    o->lanes[t].grp_sweep = o->grp_sweeps + (size_t)t * (size_t)o->n_grps;
  *out = o;
  return MRVI_OK;
}

const mrvi_outer_stats *mrvi_outer_stats_of(const mrvi_outer *o) {
  return &o->stats;
}

/* Every thread of the team waits for the others (none on one). */
#ifdef _OPENMP
#define TEAM_BARRIER(L)                                                        \
  do {                                                                         \
    if ((L)->nth > 1) {                                                        \
      MRVI_PRAGMA(omp barrier)                                                 \
    }                                                                          \
  } while (0)
#else
#define TEAM_BARRIER(L) (void)(L)
#endif

/* TEAM_BARRIER, after which no buffer is read by a gradient. */
static void team_barrier(lane *L) {
  TEAM_BARRIER(L);
  L->dirty = 0;
}

/* Before a lane writes zb[b]: a barrier where a gradient read it since the
 * last one (every lane passes the same calls, so all agree). */
static void z_sync(lane *L, int b) {
  if (L->dirty >> b & 1)
    team_barrier(L);
}

/* v = (a maximum, a sum, a maximum) of the lane's span -> the team's, the
 * same in every lane: the lanes' values combined in lane order after a
 * barrier.  The maxima skip NaN, which the sum keeps (the callers test
 * it); two slots alternate, so that a lane writing the next reduction's
 * partials has passed a barrier after every lane read this one's. */
static void team_reduce(mrvi_outer *o, lane *L, double v[3]) {
  if (L->nth == 1)
    return;
  double *slot = o->red + (size_t)(L->n_red++ & 1) * RED * (size_t)o->n_lanes;
  memcpy(slot + (size_t)L->tid * RED, v, 3 * sizeof(double));
  team_barrier(L);
  v[0] = v[1] = v[2] = 0.0;
  for (int t = 0; t < L->nth; t++) {
    const double *u = slot + (size_t)t * RED;
    v[0] = u[0] > v[0] ? u[0] : v[0];
    v[1] += u[1];
    v[2] = fmax(v[2], u[2]);
  }
}

/* g += the gradient of class kc at z by the team: the parts of its
 * partition (mrvi_terms_set_threads) in equal runs per lane, else the
 * whole class by lane 0. */
static void grad_team(const lane *L, mrvi_terms *kc, const double *z,
                      double *g) {
  const int np = mrvi_terms_parts(kc);
  if (L->nth > 1 && np > 0) {
    int c0, c1;
    span(L, np, &c0, &c1);
    for (int c = c0; c < c1; c++)
      mrvi_terms_grad_part(kc, c, z, g);
  } else if (L->tid == 0)
    mrvi_terms_grad(kc, z, g);
}

/* The site's fast configuration zf = q^{f,0} + cA a + cB b on columns
 * [lo, hi), its gradient's entries gf zeroed in the same pass; with F, b
 * (= d^{m+1}) first takes the chord update b += (dt/M^f) F (eq: the
 * masses equal, dtm[0] for every column). */
static inline __attribute__((always_inline)) void
site_config(const mrvi_outer *o, double *restrict zf, double *restrict gf,
            const double *qf0, double cA, double cB, const double *a, double *b,
            const double *F, int lo, int hi, const int eq) {
  const double dtm0 = o->dtm[0];
  if (F)
    for (int f = lo; f < hi; f++) {
      b[f] += (eq ? dtm0 : o->dtm[f]) * F[f];
      zf[f] = qf0[f] + cA * a[f] + cB * b[f];
      gf[f] = 0.0;
    }
  else
    for (int f = lo; f < hi; f++) {
      zf[f] = qf0[f] + cA * a[f] + cB * b[f];
      gf[f] = 0.0;
    }
}

/* g (the site's S->g, or a spare) = grad Z at the site's configuration
 * (in zb[zi])
 * for the slow displacement xs and the fast displacements dm = d^m, dn =
 * d^{m+1} (NULL: zeros); with F, dn first takes the chord update dn +=
 * (dt/M^f) F (in the same pass over the fast columns).  By the team: each
 * lane's span of the configuration, then the gradient's parts.  ready: the
 * fast configuration and g's zeros were written by the fused row pass
 * before a barrier (solve_row), so only the gradient is left. */
static void eval_site(mrvi_outer *o, lane *L, const mrvi_step *st, site *S,
                      double *g, const double *xs, const double *dm, double *dn,
                      const double *F, int ready, int zi) {
  const int ns = o->ns;
  double *z = o->zb[zi];
  int lo, hi;
  span(L, ns, &lo, &hi);
  /* (z's slow part depends on a1 alone within a sweep) */
  int zs_new = 0;
  if (S->rs && (!L->z_site[zi] || L->z_site[zi]->a1 != S->a1 ||
                L->z_sweep[zi] != L->sweep)) {
    z_sync(L, zi);
    /* (and the other buffer's, free now, which the fused row pass fills
     * next for an inside site: no barrier for it at the next iterate) */
    const int both = S->cA != 0.0 && S->cB != 0.0 && !(L->dirty >> !zi & 1);
    double *z2 = o->zb[!zi];
    for (int s = lo; s < hi; s++) {
      z[s] = st->qs0[s] + S->a1 * xs[s];
      if (both)
        z2[s] = z[s];
    }
    for (int b = 0; b < 2; b++)
      if (b == zi || both) {
        L->z_site[b] = S;
        L->z_sweep[b] = L->sweep;
      }
    zs_new = 1;
  }
  if (!ready) {
    z_sync(L, zi);
    if (S->rs)
      memset(g + lo, 0, (size_t)(hi - lo) * sizeof(double));
    const double cB = dn ? S->cB : 0.0;
    const double *a = dm ? dm : o->zero;
    double *b = dn ? dn : o->zero; /* (written only with F, where dn is) */
    span(L, o->nf, &lo, &hi);
    if (o->eq_f)
      site_config(o, z + ns, g + ns, st->qf0, S->cA, cB, a, b, F, lo, hi, 1);
    else
      site_config(o, z + ns, g + ns, st->qf0, S->cA, cB, a, b, F, lo, hi, 0);
  }
  /* (a barrier after each class: the two classes' parts write the same
   * columns, in the serial order; none where each lane's part writes the
   * columns of its spans, which the lane alone reads and writes until z
   * is written again, z_sync) */
  if (!ready || zs_new)
    team_barrier(L);
  for (int c = 0; c < 2; c++)
    if (S->cls & (1 << c) && o->kc[c]) {
      grad_team(L, o->kc[c], z, g);
      if (L->tid == 0)
        o->stats.grad_equiv += o->share[c];
      if (L->own)
        L->dirty |= 1 << zi;
      else
        team_barrier(L);
    }
  if (L->tid == 0)
    o->stats.site_evals++;
}

/* The gradient of the slow-only terms at site S for the slow displacement
 * xs of this sweep (NULL: S has none), evaluated on its group's first
 * need in the sweep. */
static const double *slow_site(mrvi_outer *o, lane *L, const mrvi_step *st,
                               const site *S, const double *xs) {
  if (S->grp < 0)
    return NULL;
  slow_group *G = &o->grps[S->grp];
  if (L->grp_sweep[S->grp] != L->sweep) {
    /* (the slow configuration: z's where it is this one, else built) */
    int lo, hi;
    span(L, o->ns, &lo, &hi);
    /* (bit zi of L->dirty: zb[0], zb[1] or, 2, o->zs) */
    const double *zs = o->zs;
    int zi = 2;
    for (int b = 0; b < 2; b++)
      if (L->z_site[b] && L->z_site[b]->a1 == G->a1 &&
          L->z_sweep[b] == L->sweep) {
        zs = o->zb[b];
        zi = b;
      }
    if (zi == 2) {
      z_sync(L, 2);
      for (int s = lo; s < hi; s++)
        o->zs[s] = st->qs0[s] + G->a1 * xs[s];
    }
    memset(G->g + lo, 0, (size_t)(hi - lo) * sizeof(double));
    /* (with own parts, a barrier for a configuration just written alone:
     * zb[b]'s slow part was written before one, eval_site) */
    if (!L->own_ss || zi == 2)
      team_barrier(L);
    for (int c = 0; c < 2; c++)
      if (G->cls & (1 << c)) {
        grad_team(L, o->kss[c], zs, G->g);
        if (L->tid == 0)
          o->stats.grad_equiv += o->share_ss[c];
        if (L->own_ss)
          L->dirty |= 1 << zi;
        else
          team_barrier(L);
      }
    L->grp_sweep[S->grp] = L->sweep;
  }
  return G->g;
}

/* The next configuration written by the fused row pass (solve_row):
 * d^{m+1} after the chord update into nb, the site's fast configuration
 * qf0 + cA dp + cB nb into zf, and the spare gradient's fast part gz
 * zeroed (site_config's arithmetic). */
typedef struct row_next {
  double *nb, *zf, *gz;
  const double *qf0;
  double cA, cB;
} row_next;

/* Entry f of the row F_m = (p^{f,m} - the node-m sites' forces fx (NULL:
 * none, zeros), or F's partial sum where more than one site is inside:
 * one = 0) - w1 g1 -
 * M^f (dn - dp)/dt into o->F (with fuse, into the next configuration nx
 * instead), its weighted size (w NULL: 1) into the
 * running maximum *r and the sum *sum, and with c the size of its largest
 * term into *c (eq: the masses equal, mdt[0] for every column). */
static inline __attribute__((always_inline)) void
row_entry(mrvi_outer *o, const double *fx, int f, int one, double w1,
          const double *g1, const double *dn, const double *dp, const double *w,
          double *r, double *sum, double *c, const int eq, const row_next *nx,
          const int fuse) {
  const double mv = (eq ? o->mdt[0] : o->mdt[f]) * (dn[f] - dp[f]);
  const double x = fx ? fx[f] : 0.0;
  const double Ff = (one ? o->pm[f] - x : o->F[f]) - w1 * g1[f] - mv;
  if (fuse) {
    const double b = dn[f] + (eq ? o->dtm[0] : o->dtm[f]) * Ff;
    nx->nb[f] = b;
    nx->zf[f] = nx->qf0[f] + nx->cA * dp[f] + nx->cB * b;
    nx->gz[f] = 0.0;
  } else
    o->F[f] = Ff;
  const double wf = w ? w[f] : 1.0, a = fabs(Ff) * wf;
  *r = a > *r ? a : *r;
  *sum += a;
  if (c) {
    const double fi = o->pm[f] - x - mv - Ff;
    const double t = (fabs(o->pm[f]) + fabs(x) + fabs(fi) + fabs(mv)) * wf;
    *c = t > *c ? t : *c;
  }
}

/* Entries f, f + 1 of the row (row_entry's arithmetic lane by lane, in
 * pairs of doubles) into the pairs of running maxima *r, *c and sums *sum
 * (c with want_c; no node-m forces read where fx is NULL: p^{f,m} - 0 and
 * |p^{f,m}| + 0 are p^{f,m} and |p^{f,m}|). */
static inline __attribute__((always_inline)) void
row_pair(mrvi_outer *o, const double *fx, int f, int one, double w1,
         const double *g1, const double *dn, const double *dp, const double *w,
         mrvi_v2 *r, mrvi_v2 *sum, mrvi_v2 *c, const int want_c, const int eq,
         const row_next *nx, const int fuse) {
  const mrvi_v2 dnf = v2_load(dn + f), dpf = v2_load(dp + f);
  const mrvi_v2 mv =
      v2_mul(eq ? v2_set(o->mdt[0], o->mdt[0]) : v2_load(o->mdt + f),
             v2_sub(dnf, dpf));
  const mrvi_v2 pm = v2_load(o->pm + f);
  const mrvi_v2 x = fx ? v2_load(fx + f) : v2_zero();
  const mrvi_v2 p0 = fx ? v2_sub(pm, x) : pm;
  const mrvi_v2 Ff = v2_sub(
      v2_sub(one ? p0 : v2_load(o->F + f), v2_scale(w1, v2_load(g1 + f))), mv);
  if (fuse) {
    const mrvi_v2 bn = v2_add(
        dnf,
        v2_mul(eq ? v2_set(o->dtm[0], o->dtm[0]) : v2_load(o->dtm + f), Ff));
    v2_store(nx->nb + f, bn);
    v2_store(nx->zf + f,
             v2_add(v2_add(v2_load(nx->qf0 + f), v2_scale(nx->cA, dpf)),
                    v2_scale(nx->cB, bn)));
    v2_store(nx->gz + f, v2_zero());
  } else
    v2_store(o->F + f, Ff);
  const mrvi_v2 wf = w ? v2_load(w + f) : v2_set(1.0, 1.0);
  const mrvi_v2 a = v2_mul(v2_abs(Ff), wf);
  *r = v2_max(a, *r);
  *sum = v2_add(*sum, a);
  if (want_c) {
    const mrvi_v2 fi = v2_sub(v2_sub(p0, mv), Ff);
    const mrvi_v2 pa = fx ? v2_add(v2_abs(pm), v2_abs(x)) : v2_abs(pm);
    const mrvi_v2 t = v2_mul(v2_add(v2_add(pa, v2_abs(fi)), v2_abs(mv)), wf);
    *c = v2_max(t, *c);
  }
}

/* The row entries of columns [lo, hi) in four lanes (two pairs, row_pair;
 * the last ones by row_entry) of partial maxima and sums: v = (max, sum,
 * max of the largest terms where want_c).  The maxima are exact and the
 * sum only tells NaN, so the lanes' grouping does not matter. */
static inline __attribute__((always_inline)) void
row_pass(mrvi_outer *o, const double *fx, int lo, int hi, int one, double w1,
         const double *g1, const double *dn, const double *dp, const double *w,
         double v[3], const int want_c, const int eq, const row_next *nx,
         const int fuse) {
  mrvi_v2 ra = v2_zero(), rb = v2_zero(), sa = v2_zero(), sb = v2_zero(),
          ca = v2_zero(), cb = v2_zero();
  const int hi4 = lo + ((hi - lo) & ~3);
  for (int f0 = lo; f0 < hi4; f0 += 4) {
    row_pair(o, fx, f0, one, w1, g1, dn, dp, w, &ra, &sa, &ca, want_c, eq, nx,
             fuse);
    row_pair(o, fx, f0 + 2, one, w1, g1, dn, dp, w, &rb, &sb, &cb, want_c, eq,
             nx, fuse);
  }
  double rl = 0.0, sl = 0.0, cl = 0.0;
  for (int f = hi4; f < hi; f++)
    row_entry(o, fx, f, one, w1, g1, dn, dp, w, &rl, &sl, want_c ? &cl : NULL,
              eq, nx, fuse);
  ra = v2_max(ra, rb);
  sa = v2_add(sa, sb);
  ca = v2_max(ca, cb);
  v[0] = fmax(fmax(v2_lo(ra), v2_hi(ra)), rl);
  v[1] = v2_lo(sa) + v2_hi(sa) + sl;
  v[2] = fmax(fmax(v2_lo(ca), v2_hi(ca)), cl);
}

/* row_pass with its flags as constants: want_c (the first iterate), eq
 * (equal fast masses), fuse (nx: the next configuration too) and whether
 * there are node-m forces fx (without, none read). */
#define ROW_PASS_FX(FX, WC, EQ, FU)                                            \
  row_pass(o, FX, lo, hi, one, w1, g1, dn, dp, w, v, WC, EQ, nx, FU)
#define ROW_PASS_EQ(WC, EQ, FU)                                                \
  do {                                                                         \
    if (fx)                                                                    \
      ROW_PASS_FX(fx, WC, EQ, FU);                                             \
    else                                                                       \
      ROW_PASS_FX(NULL, WC, EQ, FU);                                           \
  } while (0)
#define ROW_PASS_FU(WC, FU)                                                    \
  do {                                                                         \
    if (eq)                                                                    \
      ROW_PASS_EQ(WC, 1, FU);                                                  \
    else                                                                       \
      ROW_PASS_EQ(WC, 0, FU);                                                  \
  } while (0)
#define ROW_PASS_WC(WC)                                                        \
  do {                                                                         \
    if (nx)                                                                    \
      ROW_PASS_FU(WC, 1);                                                      \
    else                                                                       \
      ROW_PASS_FU(WC, 0);                                                      \
  } while (0)
static void row_pass_run(mrvi_outer *o, const double *fx, int lo, int hi,
                         int one, double w1, const double *g1, const double *dn,
                         const double *dp, const double *w, double v[3],
                         int want_c, int eq, const row_next *nx) {
  if (want_c)
    ROW_PASS_WC(1);
  else
    ROW_PASS_WC(0);
}
#undef ROW_PASS_WC
#undef ROW_PASS_FU
#undef ROW_PASS_EQ
#undef ROW_PASS_FX

/* The row of interval m for d^{m+1} = dn by the Jacobi chord from dn as
 * given, with d^m = dm (NULL at m = 0), the slow displacement xs and
 * o->pm = p^{f,m}, to max(target, cut times its first residual); then
 * p^{f,m+1} into o->pm, its potential part into pfm (nf), and the sites'
 * slow forces added to o->fs, the potential part of p_{k+1}^s to ps1.
 * Returns the row's residual (weighted by rw, NULL: 1) or -1 where it did
 * not converge.  By the team: the lanes' spans of the fast and slow
 * columns (each lane reads in its span only what it wrote there, but
 * for the gradients, read after their barrier). */
static double solve_row(mrvi_outer *o, lane *L, const mrvi_step *st, int m,
                        const double *xs, const double *dm, double *dn,
                        const double *rw, double target, double cut,
                        double rate, int max_updates, double *ps1, double *pfm,
                        double *dl) {
  const int ns = o->ns, nf = o->nf;
  const double dt = st->dt;
  site *s0 = o->sites + o->send[m], *s1 = o->sites + o->send[m + 1];
  int lo, hi, slo, shi;
  span(L, nf, &lo, &hi);
  span(L, ns, &slo, &shi);
  /* the sites at node m (cB = 0) are known: their forces fx (NULL: none) */
  int inside = 0;
  const double *fx = NULL;
  for (site *S = s0; S < s1; S++)
    if (S->cB == 0.0)
      fx = o->fexp;
  if (fx)
    memset(o->fexp + lo, 0, (size_t)(hi - lo) * sizeof(double));
  for (site *S = s0; S < s1; S++) {
    if (S->cB != 0.0) {
      inside |= S->cA != 0.0;
      continue;
    }
    eval_site(o, L, st, S, S->g, xs, dm, NULL, NULL, 0, 1);
    for (int f = lo; f < hi; f++)
      o->fexp[f] += S->w * S->cA * S->g[ns + f];
  }
  int n_inside = 0;
  for (site *S = s0; S < s1; S++)
    n_inside += S->cB != 0.0 && S->cA != 0.0;
  const double *dp = dm ? dm : o->zero;
  double r = 0.0, r_prev = HUGE_VAL, floor = 0.0, *F = o->F;
  /* One site inside (midpoint-midpoint's, trapezoidal-midpoint's W): the
   * row pass also writes the next iterate's configuration (the chord
   * update into the other of dn and o->nb, the site's fast configuration
   * and the other of its gradient and a spare zeroed) before the
   * reduction's barrier, which then stands for eval_site's: one pass over
   * the fast columns and one barrier less per update.  The same
   * arithmetic as the unfused update (site_config). */
  site *sin = NULL;
  if (n_inside == 1)
    for (site *S = s0; S < s1; S++)
      if (S->cB != 0.0 && S->cA != 0.0)
        sin = S;
  double *gbuf[2] = {sin ? sin->g : NULL, sin ? o->galt[sin->rs] : NULL};
  double *dbuf[2] = {dn, o->nb};
  int cur = 0; /* gbuf[cur], dbuf[cur]: the iterate */
  for (int it = 0;; it++) {
    /* F_m at dn: the sites inside the interval at dn (no iteration where
     * there is none: the row is explicit in d^{m+1}); from the second
     * iterate on, dn takes the chord update first (eval_site) */
    if (!inside && it == 0)
      for (int f = lo; f < hi; f++)
        dn[f] = (dm ? dm[f] : 0.0) +
                dt * o->minv_f[f] * (o->pm[f] - (fx ? fx[f] : 0.0));
    /* F = p^{f,m} - the forces of the sites (the first inside one's in
     * the pass below) - M^f (d^{m+1} - d^m)/dt */
    const double *g1 = o->zero;
    double w1 = 0.0;
    int first = 1;
    for (site *S = s0; S < s1; S++) {
      if (S->cB == 0.0 || S->cA == 0.0)
        continue;
      if (S == sin)
        eval_site(o, L, st, S, gbuf[cur], xs, dm, dbuf[cur], NULL, it > 0, cur);
      else
        eval_site(o, L, st, S, S->g, xs, dm, dn, first && it > 0 ? F : NULL, 0,
                  0);
      if (first) {
        first = 0;
        g1 = (S == sin ? gbuf[cur] : S->g) + ns;
        w1 = S->w * S->cA;
        if (n_inside > 1)
          for (int f = lo; f < hi; f++)
            F[f] = o->pm[f] - (fx ? fx[f] : 0.0);
        continue;
      }
      const double wc = S->w * S->cA;
      for (int f = lo; f < hi; f++)
        F[f] -= wc * S->g[ns + f];
    }
    /* ... and its largest entry (NaN found by the sums, which it poisons;
     * partial maxima and sums in four lanes and per thread); at the first
     * iterate the roundoff floor, 16 eps times the largest term of the
     * row (the unknowns being displacements) */
    double v[3];
    const int one = n_inside <= 1;
    if (sin)
      z_sync(L, !cur);
    const row_next nx = {sin ? dbuf[!cur] : NULL,      o->zb[!cur] + ns,
                         sin ? gbuf[!cur] + ns : NULL, st->qf0,
                         sin ? sin->cA : 0.0,          sin ? sin->cB : 0.0};
    row_pass_run(o, fx, lo, hi, one, w1, g1, sin ? dbuf[cur] : dn, dp, rw, v,
                 it == 0, o->eq_f, sin ? &nx : NULL);
    /* (the spare's slow part, where the site's terms write there) */
    if (sin && sin->rs)
      memset(gbuf[!cur] + slo, 0, (size_t)(shi - slo) * sizeof(double));
    team_reduce(o, L, v);
    r = v[0];
    if (isnan(v[1]))
      return -1.0;
    if (it == 0) {
      floor = 16.0 * DBL_EPSILON * v[2];
      target = fmax(target, cut * r);
    }
    if (!inside || r <= fmax(target, floor))
      break;
    /* (stalled at the rounding of its terms: solved as far as it can be) */
    if (it >= 1 && !(r <= rate * r_prev) && r <= 8.0 * floor) {
      floor = r;
      break;
    }
    if (it >= max_updates || !(r <= rate * r_prev))
      return -1.0;
    r_prev = r;
    if (L->tid == 0)
      o->stats.row_updates++;
    /* (the update dn += (dt/M^f) F: by eval_site in the next iterate, or
     * made by the fused pass above) */
    cur = !cur;
  }
  /* (the iterate back into dn) */
  if (dbuf[cur] != dn)
    memcpy(dn + lo, dbuf[cur] + lo, (size_t)(hi - lo) * sizeof(double));
  /* the sites at node m + 1 (cA = 0), then p^{f,m+1} and the slow forces */
  for (site *S = s0; S < s1; S++)
    if (S->cA == 0.0)
      eval_site(o, L, st, S, S->g, xs, dm, dn, NULL, 0, 0);
  /* (one site with a node-(m+1) coefficient, midpoint-midpoint's: pfm,
   * p^{f,m+1} and the node's change in one pass below) */
  const site *sb = NULL;
  int n_b = 0;
  for (site *S = s0; S < s1; S++)
    if (S->w * S->cB != 0.0) {
      sb = S;
      n_b++;
    }
  if (n_b != 1)
    memset(pfm + lo, 0, (size_t)(hi - lo) * sizeof(double));
  for (site *S = s0; S < s1; S++) {
    const double wa = S->w * S->a0, w1 = S->w * S->a1, wb = S->w * S->cB;
    const double *Sg = S == sin ? gbuf[cur] : S->g;
    const double *gss =
        wa != 0.0 || w1 != 0.0 ? slow_site(o, L, st, S, xs) : NULL;
    if (gss)
      for (int s = slo; s < shi; s++) {
        const double gs = Sg[s] + gss[s];
        o->fs[s] += wa * gs;
        ps1[s] -= w1 * gs;
      }
    else if (S->rs && (wa != 0.0 || w1 != 0.0))
      for (int s = slo; s < shi; s++) {
        o->fs[s] += wa * Sg[s];
        ps1[s] -= w1 * Sg[s];
      }
    if (wb != 0.0 && n_b != 1)
      for (int f = lo; f < hi; f++)
        pfm[f] -= wb * Sg[ns + f];
  }
  const double mdt0 = o->mdt[0];
  if (n_b == 1) {
    const double wb = sb->w * sb->cB,
                 *gf = (sb == sin ? gbuf[cur] : sb->g) + ns;
    for (int f = lo; f < hi; f++) {
      pfm[f] = 0.0 - wb * gf[f];
      o->pm[f] = (o->eq_f ? mdt0 : o->mdt[f]) * (dn[f] - dp[f]) + pfm[f];
      dl[f] = dn[f] - dl[f];
    }
  } else {
    for (int f = lo; f < hi; f++) {
      o->pm[f] = (o->eq_f ? mdt0 : o->mdt[f]) * (dn[f] - dp[f]) + pfm[f];
      dl[f] = dn[f] - dl[f];
    }
  }
  /* (met: within the target, or at the rounding floor of the row's terms) */
  L->met &= inside ? r <= fmax(target, floor) : 1;
  return r;
}

/* xs += the slow update from G (o->fs) at the iterate's slow update j =
 * 0, 1, ...: the chord f = (dT/M^s) G, accelerated by Anderson's mixing of
 * the last min(j, OUTER_AA) iterates (Walker & Ni, SIAM J. Numer. Anal.
 * 49 (2011)): x + f - (dX + dF) gamma, gamma the least-squares solution of
 * dF gamma = f (normal equations; a singular one drops the history).
 * (On one thread: its sums in their serial order.) */
static void slow_update(mrvi_outer *o, double *xs, int j, double dT) {
  const int ns = o->ns;
  double *f = o->fs;
  for (int s = 0; s < ns; s++)
    f[s] *= dT * o->minv_s[s];
  const int slot = (j - 1) % OUTER_AA, depth = j < OUTER_AA ? j : OUTER_AA;
  if (j >= 1) {
    double *dx = o->dX + (size_t)slot * ns, *df = o->dF + (size_t)slot * ns;
    for (int s = 0; s < ns; s++) {
      dx[s] = xs[s] - o->xp[s];
      df[s] = f[s] - o->fp[s];
    }
  }
  memcpy(o->xp, xs, (size_t)ns * sizeof(double));
  memcpy(o->fp, f, (size_t)ns * sizeof(double));
  double A[OUTER_AA * OUTER_AA], b[OUTER_AA];
  int piv[OUTER_AA], ok = depth > 0;
  for (int a = 0; a < depth; a++) {
    const double *fa = o->dF + (size_t)a * ns;
    double t = 0.0;
    for (int s = 0; s < ns; s++)
      t += fa[s] * f[s];
    b[a] = t;
    for (int c = 0; c < depth; c++) {
      const double *fc = o->dF + (size_t)c * ns;
      double u = 0.0;
      for (int s = 0; s < ns; s++)
        u += fa[s] * fc[s];
      A[a * depth + c] = u;
    }
  }
  ok = ok && mrvi_dense_lu_factor(depth, A, piv) == 0;
  if (ok) {
    mrvi_dense_lu_solve(depth, A, piv, b, 1);
    for (int a = 0; a < depth; a++)
      ok &= isfinite(b[a]);
  }
  for (int s = 0; s < ns; s++) {
    double v = f[s];
    for (int a = 0; ok && a < depth; a++)
      v -= b[a] * (o->dX[(size_t)a * ns + s] + o->dF[(size_t)a * ns + s]);
    xs[s] += v;
  }
}

/* mrvi_outer_solve's iteration by lane L of the team (every lane returns
 * the same). */
static int outer_lane(mrvi_outer *o, lane *L, const mrvi_step *st, double *x,
                      const double *rw, double target, double rate,
                      int max_outer, double *ps1, double *pf, double *res) {
  const int ns = o->ns, nf = o->nf, p = o->p;
  const double dT = st->dT;
  double *xs = x, *xf = x + ns;
  double g_prev = HUGE_VAL;
  int lo, hi, slo, shi;
  span(L, nf, &lo, &hi);
  span(L, ns, &slo, &shi);
  for (int k = 1; k <= max_outer; k++) {
    /* Inexact sweeps: the rows are solved only as far as the slow row's
     * residual makes worthwhile -- in the first sweep by OUTER_CUT of
     * their first residual, then to OUTER_CUT times the slow residual of
     * the sweep before (the slow update changes them again) -- and to the
     * target where that is below: a sweep ends the iteration only where
     * every row met the target. */
    const double row_target =
        k == 1 ? target : fmax(target, OUTER_CUT * g_prev);
    double rows = 0.0;
    L->met = 1;
    L->sweep++;
    if (L->tid == 0)
      o->stats.sweeps++;
    memcpy(o->pm + lo, st->pf0 + lo, (size_t)(hi - lo) * sizeof(double));
    memset(o->fs + slo, 0, (size_t)(shi - slo) * sizeof(double));
    memset(ps1 + slo, 0, (size_t)(shi - slo) * sizeof(double));
    for (int mm = 0; mm < p; mm++) {
      double *dn = xf + (size_t)mm * (size_t)nf;
      const double *dm = mm == 0 ? NULL : dn - nf;
      /* start from the last sweep's node, moved by the change of the nodes
       * before in this sweep extrapolated (none in the first sweep; the
       * response to a slow update is smooth in m) */
      /* (the node before it into dl = dlt[2], read there first as d3;
       * solve_row leaves the node's change in dl) */
      const double *d1 = L->dlt[0], *d2 = L->dlt[1];
      double *dl = L->dlt[2];
      if (k > 1 && mm >= 3)
        for (int f = lo; f < hi; f++) {
          const double d3 = dl[f];
          dl[f] = dn[f];
          dn[f] += 3.0 * d1[f] - 3.0 * d2[f] + d3;
        }
      else if (k > 1 && mm == 2)
        for (int f = lo; f < hi; f++) {
          dl[f] = dn[f];
          dn[f] += 2.0 * d1[f] - d2[f];
        }
      else if (k > 1 && mm == 1)
        for (int f = lo; f < hi; f++) {
          dl[f] = dn[f];
          dn[f] += d1[f];
        }
      else
        memcpy(dl + lo, dn + lo, (size_t)(hi - lo) * sizeof(double));
      const double r = solve_row(o, L, st, mm, xs, dm, dn,
                                 rw ? rw + ns + (size_t)mm * nf : NULL,
                                 row_target, k == 1 ? OUTER_CUT : 0.0, rate,
                                 max_outer, ps1, pf + (size_t)mm * nf, dl);
      if (r < 0.0) {
        if (L->tid == 0)
          o->stats.failed++;
        return 0;
      }
      rows = fmax(rows, r);
      L->dlt[2] = L->dlt[1];
      L->dlt[1] = L->dlt[0];
      L->dlt[0] = dl;
    }
    /* the slow row at the swept nodes */
    double v[3] = {0.0, 0.0, 0.0};
    for (int s = slo; s < shi; s++) {
      const double G = st->ps0[s] - o->m_s[s] * xs[s] / dT - o->fs[s];
      const double w = rw ? rw[s] : 1.0, a = fabs(G) * w;
      v[0] = a > v[0] ? a : v[0];
      v[1] += a;
      v[2] = fmax(v[2], (fabs(st->ps0[s]) + o->m_s[s] * fabs(xs[s]) / dT +
                         fabs(o->fs[s])) *
                            w);
      o->fs[s] = G;
    }
    team_reduce(o, L, v);
    const double g = v[0];
    /* (at or stalled at the rounding of the slow row's terms) */
    const double floor = 16.0 * DBL_EPSILON * v[2];
    const int stalled = k > 1 && !(g <= rate * g_prev) && g <= 8.0 * floor;
    if (isnan(v[1]) || (k > 1 && !stalled && !(g <= rate * g_prev))) {
      if (L->tid == 0)
        o->stats.failed++;
      return 0;
    }
    if (k > 1 && (g <= fmax(target, floor) || stalled) && L->met &&
        row_target == target) {
      if (L->tid == 0)
        *res = fmax(g, rows);
      return k;
    }
    g_prev = g;
    /* (every lane's G complete after team_reduce's barrier; the update
     * complete before the next sweep reads xs) */
    if (L->tid == 0) {
      slow_update(o, xs, k - 1, dT);
      o->stats.slow_updates++;
    }
    team_barrier(L);
  }
  if (L->tid == 0)
    o->stats.failed++;
  return 0;
}

/* L's state at the start of a step: lane tid of nth. */
static void lane_start(const mrvi_outer *o, lane *L, int tid, int nth) {
  L->tid = tid;
  L->nth = nth;
  L->sweep = o->stats.sweeps;
  L->z_site[0] = L->z_site[1] = NULL;
  L->own = L->own_ss = 0;
  L->dirty = 0;
  L->met = 1;
  L->n_red = 0;
  for (int i = 0; i < 3; i++)
    L->dlt[i] = o->dlt[i];
}

int mrvi_outer_solve(mrvi_outer *o, const mrvi_step *st, double *x,
                     const double *rw, double target, double rate,
                     int max_outer, double *ps1, double *pf, double *res) {
  o->stats.steps++;
  /* (each lane's start before any lane counts a sweep) */
  for (int t = 0; t < o->n_lanes; t++)
    lane_start(o, &o->lanes[t], t, o->n_lanes);
  if (o->n_lanes == 1)
    return outer_lane(o, &o->lanes[0], st, x, rw, target, rate, max_outer, ps1,
                      pf, res);
  int k = 0;
#ifdef _OPENMP
#pragma omp parallel num_threads(o->n_lanes)
  {
    /* (the team may be smaller than asked: the spans follow its size) */
    lane *L = &o->lanes[omp_get_thread_num()];
    L->nth = omp_get_num_threads();
    L->own = o->own && L->nth == o->n_lanes;
    L->own_ss = o->own_ss && L->nth == o->n_lanes;
    const int kl =
        outer_lane(o, L, st, x, rw, target, rate, max_outer, ps1, pf, res);
    if (L->tid == 0)
      k = kl;
  }
#endif
  return k;
}
