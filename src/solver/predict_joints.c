/* The predictor's constraint forces at the micro nodes (doc/solver.md,
 * "The joint sweep").  The explicit sweep (predict.c) leaves them out: over
 * a macro step its fast nodes drift from the micro-node constraints by what
 * those forces would have moved them (about (omega m dt)^2 at node m, against
 * (omega dt)^2 over a single-rate step), and Newton starts the multipliers
 * from zero, so that a macro step took two Newton updates more than a
 * single-rate step.  The sweep with joints solves each node's constrained
 * fast row in its turn instead.  Row m of a fast node (doc/constraints.md,
 * "The constrained discrete action"; arXiv 2406.12991, (4.8)),
 *
 *   M^f (q^m - q^{m-1}) / dt - M^f (q^{m+1} - q^m) / dt - F_m
 *       - dt G_f(z^m)^T lambda^m = 0,      g(z^{m+1}) = 0,
 *
 * changes by -M^f delta / dt when q^{m+1} moves by delta, so the node the
 * explicit row gives moves by
 *
 *   delta = M_f^-1 G_f(z^m)^T mu,   lambda^m = -mu / dt^2,
 *
 * mu (r_micro) the root of g(z^{m+1} + delta) = 0: the SHAKE update, here
 * one Newton update on K = G_f(z^{m+1}) M_f^-1 G_f(z^m)^T per call (the
 * sweep calls it twice per node, the second time with K kept; the sweep
 * after the slow correction keeps the K of the sweep before, again = 2:
 * the correction moves the nodes by little, doc/solver.md, "The joint
 * sweep").  The slow
 * part of z^m is the predictor's q_{k+1}^s interpolated ((4.8)) and held;
 * mrvi_joint_sweep_slow_force gives the slow row the multipliers' force
 * and mrvi_joint_sweep_slow moves q_{k+1}^s onto the slow-only
 * constraints the same way (weight dT, G at q_k).  Every step of this
 * depends on (q_k, p_k) alone. */
#include "solver/solver.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* The pattern of one set of constraints (the micro-node ones, or the
 * slow-only ones) in G's rows, so that K and the moves take the products
 * of structural nonzeros only (in the order of the dense loops: the same
 * sums, the zeros' terms left out): the columns [lo, lo + ny) of K's sum
 * and of the move. */
typedef struct {
  const int *cons; /* the set (model indices, nc) */
  int nc, rows, lo, ny;
  int *rcon; /* the constraint (position in the set) of each row (rows) */
  int *r0;   /* (nc + 1) the first row of each constraint */
  int *col;  /* each input's column in G (sum of n_in, from in0) */
  int *in0;  /* (nc + 1) */
  int *kp;   /* (nc^2 + 1) offsets into kc, by pair of constraints */
  int *kc;   /* the columns (- lo) both of a pair read, ascending */
  int *cp;   /* (ny + 1) offsets into cr */
  int *cr;   /* the rows reading column lo + j, ascending */
} joint_set;

struct mrvi_joint_sweep {
  int n, rmax;  /* ns + nf; the most rows of one block (r_micro, r_slow) */
  double *minv; /* 1 / mass, slow slots then fast (n) */
  /* G (rmax x n, slow slots then fast): at node m in block m (m = 0..p),
   * the slow-only constraints' at q_k and at q_{k+1}^s in blocks p + 1
   * and p + 2; entries outside the set's pattern stay zero */
  double *G;
  double *K;           /* node m's K factored in block m, the slow one's in p */
  int *piv;            /* (p + 1) rmax */
  int *nzc;            /* the factorisation's workspace (rmax) */
  int *ok;             /* node m's K is regular (p) */
  int reuse;           /* the current node takes the last sweep's G and K */
  double *g, *mu;      /* g at the equation's node, one update (rmax each) */
  double *mut;         /* the updates' sum at the current node (rmax) */
  double *c;           /* the current node's move (nf) */
  double *y, *cg, *cG; /* one constraint's inputs, g and G */
  joint_set micro, slow;
};

static void set_free(joint_set *s) {
  free(s->rcon);
  free(s->r0);
  free(s->col);
  free(s->in0);
  free(s->kp);
  free(s->kc);
  free(s->cp);
  free(s->cr);
}

/* The pattern of the constraints cons[0..nc) (rows rows) on the columns
 * [lo, lo + ny); MRVI_ENOMEM. */
static int set_init(joint_set *s, const mrvi_step *st, const int *cons, int nc,
                    int rows, int lo, int ny) {
  const mrvi_model *md = st->model;
  *s = (joint_set){.cons = cons, .nc = nc, .rows = rows, .lo = lo, .ny = ny};
  int n_in = 0;
  for (int i = 0; i < nc; i++)
    n_in += md->constraints[cons[i]].n_in;
  const size_t c2 = (size_t)nc * (size_t)nc, y1 = (size_t)(ny > 0 ? ny : 1);
  unsigned char *pat = calloc((size_t)(nc > 0 ? nc : 1) * y1, 1);
  s->rcon = malloc((size_t)(rows > 0 ? rows : 1) * sizeof(int));
  s->r0 = malloc((size_t)(nc + 1) * sizeof(int));
  s->col = malloc((size_t)(n_in > 0 ? n_in : 1) * sizeof(int));
  s->in0 = malloc((size_t)(nc + 1) * sizeof(int));
  s->kp = malloc((c2 + 1) * sizeof(int));
  s->kc = malloc((c2 > 0 ? c2 : 1) * y1 * sizeof(int));
  s->cp = malloc((y1 + 1) * sizeof(int));
  s->cr = malloc((size_t)(rows > 0 ? rows : 1) * y1 * sizeof(int));
  if (!pat || !s->rcon || !s->r0 || !s->col || !s->in0 || !s->kp || !s->kc ||
      !s->cp || !s->cr) {
    free(pat);
    return MRVI_ENOMEM;
  }
  s->in0[0] = 0;
  for (int i = 0; i < nc; i++) {
    const mrvi_constraint *k = &md->constraints[cons[i]];
    s->r0[i] = st->c_off[cons[i]];
    s->r0[i + 1] = s->r0[i] + k->rows;
    for (int r = 0; r < k->rows; r++)
      s->rcon[s->r0[i] + r] = i;
    for (int j = 0; j < k->n_in; j++) {
      const int idx = k->in[j];
      const int col = md->slot[idx] + (md->rate[idx] == MRVI_FAST ? st->ns : 0);
      s->col[s->in0[i] + j] = col;
      if (col >= lo && col < lo + ny)
        pat[(size_t)i * y1 + (size_t)(col - lo)] = 1;
    }
    s->in0[i + 1] = s->in0[i] + k->n_in;
  }
  int t = 0;
  for (size_t q = 0; q < c2; q++) {
    s->kp[q] = t;
    const unsigned char *pa = pat + (q / (size_t)nc) * y1,
                        *pb = pat + (q % (size_t)nc) * y1;
    for (int j = 0; j < ny; j++)
      if (pa[j] && pb[j])
        s->kc[t++] = j;
  }
  s->kp[c2] = t;
  t = 0;
  for (int j = 0; j < ny; j++) {
    s->cp[j] = t;
    for (int a = 0; a < rows; a++)
      if (pat[(size_t)s->rcon[a] * y1 + (size_t)j])
        s->cr[t++] = a;
  }
  s->cp[ny] = t;
  free(pat);
  return MRVI_OK;
}

int mrvi_joint_sweep_create(const mrvi_step *st, mrvi_joint_sweep **out) {
  *out = NULL;
  if (st->r_micro == 0 || st->nf == 0)
    return MRVI_OK;
  mrvi_joint_sweep *w = calloc(1, sizeof *w);
  if (!w)
    return MRVI_ENOMEM;
  const mrvi_model *m = st->model;
  const size_t n = (size_t)(st->ns + st->nf), p = (size_t)st->p;
  const size_t r =
      (size_t)(st->r_micro > st->r_slow ? st->r_micro : st->r_slow);
  const size_t ni =
      (size_t)(m->max_constraint_in > 0 ? m->max_constraint_in : 1);
  w->n = (int)n;
  w->rmax = (int)r;
  w->minv = malloc(n * sizeof(double));
  w->G = calloc((p + 3) * r * n, sizeof(double));
  w->K = malloc((p + 1) * r * r * sizeof(double));
  w->piv = malloc((p + 1) * r * sizeof(int));
  w->nzc = malloc(r * sizeof(int));
  w->ok = calloc(p, sizeof(int));
  w->g = malloc(3 * r * sizeof(double));
  w->c = malloc((size_t)st->nf * sizeof(double));
  w->y = malloc((ni + r + r * ni) * sizeof(double));
  int status = !w->minv || !w->G || !w->K || !w->piv || !w->nzc || !w->ok ||
                       !w->g || !w->c || !w->y
                   ? MRVI_ENOMEM
                   : set_init(&w->micro, st, st->micro_c, st->n_micro_c,
                              st->r_micro, st->ns, st->nf);
  if (status == MRVI_OK)
    status =
        set_init(&w->slow, st, st->slow_c, st->n_slow_c, st->r_slow, 0, st->ns);
  if (status < 0) {
    mrvi_joint_sweep_free(w);
    return status;
  }
  w->mu = w->g + r;
  w->mut = w->g + 2 * r;
  w->cg = w->y + ni;
  w->cG = w->cg + r;
  for (int s = 0; s < st->ns; s++)
    w->minv[s] = 1.0 / MRVI_MASS(m, m->slow_index[s]);
  for (int s = 0; s < st->nf; s++)
    w->minv[st->ns + s] = 1.0 / MRVI_MASS(m, m->fast_index[s]);
  *out = w;
  return MRVI_OK;
}

void mrvi_joint_sweep_free(mrvi_joint_sweep *w) {
  if (!w)
    return;
  set_free(&w->micro);
  set_free(&w->slow);
  free(w->minv);
  free(w->G);
  free(w->K);
  free(w->piv);
  free(w->nzc);
  free(w->ok);
  free(w->g);
  free(w->c);
  free(w->y);
  free(w);
}

/* G block b (rmax x n) and K block b (rmax x rmax), pivots of block b. */
static double *gblock(const mrvi_joint_sweep *w, int b) {
  return w->G + (size_t)b * (size_t)w->rmax * (size_t)w->n;
}
static double *kblock(const mrvi_joint_sweep *w, int b) {
  return w->K + (size_t)b * (size_t)w->rmax * (size_t)w->rmax;
}
static int *pblock(const mrvi_joint_sweep *w, int b) {
  return w->piv + (size_t)b * (size_t)w->rmax;
}

/* g (if not NULL) and G (if not NULL: rows x n, slow slots then fast, on
 * the set's pattern) of the set's constraints at node m of the
 * displacements x (st->increments), the slow part interpolated ((4.8)). */
static void rows_at(mrvi_joint_sweep *w, const joint_set *set,
                    const mrvi_step *st, const double *x, int m, double *g,
                    double *G) {
  const mrvi_model *md = st->model;
  const int n = w->n;
  const mrvi_point pt = mrvi_step_node_point(st, m, st->dt);
  for (int i = 0; i < set->nc; i++) {
    const int c = set->cons[i], off = st->c_off[c];
    const mrvi_constraint *k = &md->constraints[c];
    const int *col = set->col + set->in0[i];
    mrvi_step_constraint_at(st, c, &pt, x, w->y, w->cg, w->cG, NULL);
    if (g)
      memcpy(g + off, w->cg, (size_t)k->rows * sizeof *g);
    if (!G)
      continue;
    for (int r = 0; r < k->rows; r++) {
      double *Gr = G + (size_t)(off + r) * (size_t)n;
      for (int j = 0; j < k->n_in; j++)
        Gr[col[j]] = 0.0;
      for (int j = 0; j < k->n_in; j++)
        Gr[col[j]] += w->cG[r * k->n_in + j];
    }
  }
}

/* K = B M^-1 A^T on the set's columns, factored; -1 if singular.  By
 * pairs of constraints, each entry's terms in the order of the columns
 * (the dense dot products' order, their zero terms left out). */
static int project_matrix(const mrvi_joint_sweep *w, const joint_set *set,
                          const double *A, const double *B, double *K,
                          int *piv) {
  const int n = w->n, r = set->rows, nc = set->nc;
  const double *mi = w->minv + set->lo;
  A += set->lo;
  B += set->lo;
  memset(K, 0, (size_t)r * (size_t)r * sizeof *K);
  for (int ia = 0; ia < nc; ia++) {
    const int a0 = set->r0[ia], a1 = set->r0[ia + 1];
    for (int ib = 0; ib < nc; ib++) {
      const int b0 = set->r0[ib], b1 = set->r0[ib + 1];
      const int *kp = set->kp + ia * nc + ib;
      for (int t = kp[0]; t < kp[1]; t++) {
        const int j = set->kc[t];
        for (int a = a0; a < a1; a++) {
          const double bm = B[a * n + j] * mi[j];
          for (int b = b0; b < b1; b++)
            K[a * r + b] += bm * A[b * n + j];
        }
      }
    }
  }
  return mrvi_dense_lu_factor_nz(r, K, piv, w->nzc);
}

/* mu = -K^-1 g added to w->mut, and the move M^-1 A^T mu on the set's
 * columns added to y (their unknowns) and to c (if not NULL). */
static void project_update(mrvi_joint_sweep *w, const joint_set *set,
                           const double *A, const double *K, const int *piv,
                           double *y, double *c) {
  const int n = w->n, r = set->rows;
  const double *mi = w->minv + set->lo;
  A += set->lo;
  for (int a = 0; a < r; a++)
    w->mu[a] = -w->g[a];
  mrvi_dense_lu_solve(r, K, piv, w->mu, 1);
  for (int j = 0; j < set->ny; j++) {
    double d = 0.0;
    for (int t = set->cp[j]; t < set->cp[j + 1]; t++) {
      const int a = set->cr[t];
      d += A[a * n + j] * w->mu[a];
    }
    d *= mi[j];
    y[j] += d;
    if (c)
      c[j] += d;
  }
  for (int a = 0; a < r; a++)
    w->mut[a] += w->mu[a];
}

const double *mrvi_joint_sweep_node(mrvi_joint_sweep *w, const mrvi_step *st,
                                    double *x, int m, int again) {
  const int ns = st->ns, nf = st->nf, rm = st->r_micro;
  const joint_set *set = &w->micro;
  const double *A = gblock(w, m);
  double *B = gblock(w, m + 1), *K = kblock(w, m);
  int *piv = pblock(w, m);
  if (again != 1) {
    w->reuse = again == 2;
    if (m == 0 && !w->reuse) /* (node 0 is q_k: its G stays) */
      rows_at(w, set, st, x, 0, NULL, gblock(w, 0));
    memset(w->c, 0, (size_t)nf * sizeof *w->c);
    memset(w->mut, 0, (size_t)rm * sizeof *w->mut);
  }
  /* g and G at z^{m+1}; that G stays as the next node's (from before the
   * second update, which moves the node by the square of the first's
   * residual); with K kept, G is needed from the second update on only */
  rows_at(w, set, st, x, m + 1, w->g, again == 2 ? NULL : B);
  if (again == 0)
    w->ok[m] = project_matrix(w, set, A, B, K, piv) == 0;
  if (w->ok[m])
    project_update(w, set, A, K, piv, x + ns + (size_t)m * nf, w->c);
  double *lam = x + st->n_unknowns + st->r_slow + (size_t)m * rm;
  const double idt2 = 1.0 / (st->dt * st->dt);
  for (int a = 0; a < rm; a++)
    lam[a] = -w->mut[a] * idt2;
  return w->c;
}

void mrvi_joint_sweep_slow_force(const mrvi_joint_sweep *w, const mrvi_step *st,
                                 const double *x, double *fs) {
  const int n = w->n, rm = st->r_micro, ns = st->ns;
  for (int m = 0; m < st->p; m++) {
    const double *A = gblock(w, m);
    const double *lam = x + st->n_unknowns + st->r_slow + (size_t)m * rm;
    const double h = st->dt * (1.0 - m / (double)st->p);
    for (int a = 0; a < rm; a++)
      for (int s = 0; s < ns; s++)
        fs[s] += h * A[a * n + s] * lam[a];
  }
}

int mrvi_joint_sweep_slow(mrvi_joint_sweep *w, const mrvi_step *st, double *x) {
  const int rs = st->r_slow, p = st->p;
  if (rs == 0)
    return MRVI_OK;
  double *A = gblock(w, p + 1), *B = gblock(w, p + 2), *K = kblock(w, p);
  int *piv = pblock(w, p);
  const joint_set *set = &w->slow;
  rows_at(w, set, st, x, 0, NULL, A);
  rows_at(w, set, st, x, p, w->g, B);
  if (project_matrix(w, set, A, B, K, piv) < 0)
    return MRVI_ESINGULAR;
  memset(w->mut, 0, (size_t)rs * sizeof *w->mut);
  /* two updates, the second with K kept */
  project_update(w, set, A, K, piv, x, NULL);
  rows_at(w, set, st, x, p, w->g, NULL);
  project_update(w, set, A, K, piv, x, NULL);
  double *lam = x + st->n_unknowns;
  const double idT2 = 1.0 / (st->dT * st->dT);
  for (int a = 0; a < rs; a++)
    lam[a] = -w->mut[a] * idT2;
  return MRVI_OK;
}
