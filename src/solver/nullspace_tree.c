/* Joint-reduced null space of open chains and trees of rigid bodies
 * (doc/multibody.md, "Joint-reduced null space for chains and trees";
 * Betsch & Leyendecker 2006, Part II; Leyendecker, Marsden & Ortiz 2008).
 *
 * Every body i of dimension D moves by its twist t_i = (u_i, w_i) (D and
 * T - D = D (D - 1) / 2 entries, T in all) through its own analytic
 * null-space matrix, qdot_i = P_i t_i (mrvi_nullspace_body_rotation).  A
 * joint between i and its parent a(i) (or the ground) leaves
 *   t_i = X_i t_a + S_i nu_i,
 * X_i carrying i rigidly with its parent (w_i = w_a, u_i = u_a + w_a x
 * (phi_i - phi_a); X_i = 0 for a root) and S_i the joint's free directions
 * (u, w), rotations about the child's joint point x_J first, with r =
 * phi_i - x_J, then translations: ball (w x r, w) for the three rotations;
 * hinge (a_1 x r, a_1), a_1 the axis fixed in the joint's body A (2-D:
 * (J r, 1)); weld none; prismatic (b_1, 0), b_1 the axis fixed in body B
 * (or in space); cylindrical the hinge's column and the prismatic's;
 * universal (a_1 x r, a_1) and (b_2 x r, b_2), the cross's arms fixed in A
 * and in B; planar the hinge's column about the normal a_1 and (b_2, 0),
 * (b_3, 0) in the plane fixed in B; a body in no joint (a free root) S = I.
 * Each leaves the joint's rows constant to first order on the constraint
 * manifold (doc/multibody.md).  In tree order (parents first) (I - X) t = S nu,
 * so the null-space matrix is P = blkdiag(P_i) (I - X)^-1 S, dense down each
 * subtree.  It is never formed: with y = (I - X)^-T P_int^T (R - A dx) (one
 * twist y_i per body) the reduced Newton system P^T A dx = P^T R, H dx = h
 * becomes the square sparse system (I - X)^T y + P_int^T A dx = P_int^T R  (T
 * rows per body), S^T y                      = 0          (one row per joint
 * rate), H dx                       = h          (the constraint rows), with
 * the rows of the coordinates outside the bodies (slow particles, the fast
 * coordinates) as they are: (I - X)^T is block bidiagonal along the tree (a
 * body's rows hold its own y and its children's), so the matrix has O(n)
 * entries for n bodies and its sparse LU (UMFPACK through mrvi_newton) costs
 * O(n) for chains and trees.  dx is the first n_unknowns entries of the
 * solution.  Closed loops (slow bodies): the joints that close them are
 * cut, their rows' forces P_int^T G_c^T mu entering their bodies' rows, one
 * unknown mu per kept cut row (section "Closed loops" below).  P, X and S are
 * taken at q_k, where the constraint forces dT G(q_k)^T lambda act
 * (doc/constraints.md, "Null-space form").
 *
 * Multipliers lambda(x): the least-squares solution of dT G^T lambda = F on
 * the slow rows in the metric M^-1, by the sparse Gram factor of
 * model/constraint_gram.c (exact at the solution, where P^T F = 0).
 *
 * Nodal reparametrisation: a Newton update is applied body by body, parents
 * first: each body's rotation w from its director increments (the left
 * inverse of P_i), its turn relative to its parent projected on the joint's
 * free rotations (a cross: exp(al e_p^) exp(be e_c^), the parent's arm
 * outside, which keeps e_p . e_c), its frame the parent's update times that
 * turn, and its centre placed so that its joint point lies on the parent's
 * (or on the ground point), or, for a joint with translations, on the line
 * along (the plane normal to) b_1 through it nearest to the child's own
 * moved point.  The internal constraints, the joints' points and their
 * lines and planes hold to round-off at every iterate; the rows between
 * axes (hinge, cylindrical, planar, prismatic, universal, weld) keep the
 * value they have at q_0.  The slow forest's placed directors are made
 * orthonormal to one rounding (orthonormalise), so that the internal
 * constraints do not drift with the placements' roundings; a closed loop's
 * cut joints hold to the Newton tolerance. */
#include "solver/solver.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <suitesparse/umfpack.h>

#define JOINT_HEAD 2 /* params: d, bodies, then rho_A, rho_B (or p), frame */

/* A joint's free relative motion (module header): its rotations about the
 * child's joint point and its translations, by MRVI_JOINT_*. */
enum { ROT_NONE, ROT_ALL, ROT_AXIS, ROT_CROSS }; /* -, every, a_1, a_1 + b_2 */
enum { TR_NONE, TR_LINE, TR_PLANE }; /* -, along b_1, normal to b_1 */
static const struct {
  unsigned char rot, tr;
} motions[] = {
    [MRVI_JOINT_BALL] = {ROT_ALL, TR_NONE},
    [MRVI_JOINT_HINGE] = {ROT_AXIS, TR_NONE},
    [MRVI_JOINT_WELD] = {ROT_NONE, TR_NONE},
    [MRVI_JOINT_PRISMATIC] = {ROT_NONE, TR_LINE},
    [MRVI_JOINT_CYLINDRICAL] = {ROT_AXIS, TR_LINE},
    [MRVI_JOINT_UNIVERSAL] = {ROT_CROSS, TR_NONE},
    [MRVI_JOINT_PLANAR] = {ROT_AXIS, TR_PLANE},
};
#define N_MOTIONS ((int)(sizeof motions / sizeof motions[0]))

/* Rotations (out of T - D) and translations a joint of motion k leaves. */
static int n_rot(int k, int D) {
  const int r = motions[k].rot;
  return r == ROT_ALL     ? D * (D - 1) / 2
         : r == ROT_AXIS  ? 1
         : r == ROT_CROSS ? 2
                          : 0;
}
static int n_tr(int k) {
  return motions[k].tr == TR_LINE ? 1 : motions[k].tr == TR_PLANE ? 2 : 0;
}

struct mrvi_nstree {
  int D, T, nb, nu, n, ns, nf, p, n_lambda;
  int *order;  /* tree index -> body, parents first */
  int *parent; /* parent's tree index, -1 for a root */
  int *joint;  /* constraint joining t to its parent or the ground; -1 free */
  int *is_a;   /* t is its joint's body A */
  int *motion; /* MRVI_JOINT_* of that joint, 0 for a free root */
  int *slot;   /* slot of t's phi */
  int *dof;    /* joint rates of t (T for a free root) */
  int *child_start, *child; /* children of t, by tree index */
  int *in_body;             /* per slow slot */
  double *P, *X, *S;        /* at q_k: 2T x T, T x T, T x T per body */
  double *qk;               /* the q_k they were taken at */
  int have_qk;
  mrvi_gram *gram;
  double *qm, *pm, *mu; /* model-ordered q_k, forces, multipliers */
  double *qx;           /* model-ordered iterate (settle) */
  /* Rows of the extended system: combinations of the full rows (rec) and
   * entries in the y columns (ext). */
  int *rec_start, *rec_row, *ext_start, *ext_col;
  double *rec_coef, *ext_coef;
  long n_rec, n_ext, cap_rec, cap_ext;
  int *csr_start, *csr_col, *csr_idx;
  int *map, *Ap, *Ai;
  double *Ax;
  long nnz;
  double *pos, *npos, *th, *u, *Q; /* placement: nb x D(D+1), .., 3, 3, 9 */
  /* The fast forest (mrvi_nsfast_*): per tree body the row of pos / npos
   * after the nb bodies' that holds its moving ground, a slow body
   * interpolated at the micro node, or -1; per such row the slow body's
   * first slot; scratch twists (nb x T) and reached flags. */
  int fast, na, *anchor, *aslot, *reached;
  double *tw;
  /* Closed loops (slow plan): the cut joints (flags by constraint), their
   * kept rows (constraint, row in it, row among the step's multipliers,
   * the tree indices of its two bodies or -1), P_t^T g_c of each kept row
   * on each of its bodies at q_k (rc x 2 x T), the kept rows by body (CSR
   * of 2 i + side), the step's constraint rows kept (n_lambda flags), the
   * tree index of each body, scratch. */
  int *cut, rc, *cut_c, *cut_r, *cut_e, *cut_t, *body_cut_start, *body_cut;
  int *tree_of;
  unsigned char *keep;
  double *cv, *cz, *cg, *cG;
  /* Closed loops of the fast forest: the kept cut rows among the kept
   * micro-node rows (fq_n indices into them), scratch for the tree's
   * columns P_f (ncol x nfc), C^T = (G_c P_f)^T (ncol x fq_n) and the Q of
   * its QR (ncol x ncol). */
  int fq_n, *fq, ncol;
  double *Pf, *Ct, *Qc;
};

void mrvi_nstree_free(mrvi_nstree *z) {
  if (!z)
    return;
  free(z->order), free(z->parent), free(z->joint), free(z->is_a);
  free(z->motion), free(z->slot), free(z->dof), free(z->child_start);
  free(z->child), free(z->in_body), free(z->P), free(z->X), free(z->S);
  free(z->qk), mrvi_gram_free(z->gram), free(z->qm), free(z->pm);
  free(z->qx);
  free(z->mu), free(z->rec_start), free(z->rec_row), free(z->ext_start);
  free(z->ext_col), free(z->rec_coef), free(z->ext_coef);
  free(z->csr_start), free(z->csr_col), free(z->csr_idx), free(z->map);
  free(z->Ap), free(z->Ai), free(z->Ax), free(z->pos), free(z->npos);
  free(z->th), free(z->u), free(z->Q);
  free(z->anchor), free(z->aslot), free(z->reached), free(z->tw);
  free(z->cut), free(z->cut_c), free(z->cut_r), free(z->cut_e);
  free(z->cut_t), free(z->body_cut_start), free(z->body_cut);
  free(z->tree_of), free(z->keep);
  free(z->cv), free(z->cz), free(z->cg), free(z->cG);
  free(z->fq), free(z->Pf), free(z->Ct), free(z->Qc);
  free(z);
}

int mrvi_nstree_size(const mrvi_nstree *z) { return z->n; }
int mrvi_nstree_bodies(const mrvi_nstree *z) { return z->nb; }
const int *mrvi_nstree_Ap(const mrvi_nstree *z) { return z->Ap; }
const int *mrvi_nstree_Ai(const mrvi_nstree *z) { return z->Ai; }
const double *mrvi_nstree_Ax(const mrvi_nstree *z) { return z->Ax; }
long mrvi_nstree_nnz(const mrvi_nstree *z) { return z->nnz; }

/* ---------------------------------------------------------------------------
 * The forest of joints
 * ------------------------------------------------------------------------- */

/* Body B of joint constraint k (-1: the ground). */
static int body_b(const mrvi_model *m, const mrvi_constraint *k, int D) {
  return k->n_in > D * (D + 1) ? mrvi_model_body_of(m, k->in[D * (D + 1)]) : -1;
}

/* The forests a model's bodies form (plan): every body, all slow (the
 * joint-reduced basis); the fast bodies (their basis at the micro nodes);
 * the slow bodies beside those (their reparametrisation alone). */
enum { PLAN_SLOW, PLAN_FAST, PLAN_BESIDE };

/* Is body b a member of the forest of plan mode? */
static int member(const mrvi_model *m, int mode, int b) {
  const mrvi_rate r = b >= 0 ? m->rate[m->bodies[b].first] : MRVI_SLOW;
  return b >= 0 &&
         (mode == PLAN_SLOW || (mode == PLAN_FAST) == (r == MRVI_FAST));
}

/* The member at the other end of joint k from member b, or -1: the ground,
 * or (fast plan) a slow body, the fast tree's moving ground. */
static int other(const mrvi_model *m, int mode, const mrvi_constraint *k, int D,
                 int b) {
  const int a = mrvi_model_body_of(m, k->in[0]);
  const int o = a == b ? body_b(m, k, D) : a;
  return member(m, mode, o) ? o : -1;
}

/* The forest, parents first (order, parent, joint: n_bodies each; *count
 * members), or 0 and why the joint-reduced basis does not apply.  Slow
 * plan (fast 0): every body slow, every constraint a body's or a slow
 * joint's.  Fast plan (fast 1): the fast bodies, whose micro-node
 * constraints are their own and joints among them, to the ground or to a
 * slow body (spherical or revolute: the slow body interpolated at the
 * micro node is a moving ground); slow-only constraints are the slow
 * side's. */
static int plan(const mrvi_model *m, int mode, int *order, int *parent,
                int *joint, int *count, int *cut, char *why, size_t len) {
  const int nb = m->n_bodies;
  snprintf(why, len, "no joints");
  *count = 0;
  for (int c = 0; cut && c < m->n_constraints; c++)
    cut[c] = 0;
  if (nb == 0 || mrvi_model_free_bodies_only(m))
    return 0;
  const int D = m->bodies[0].dim;
  int n_members = 0;
  for (int b = 0; b < nb; b++) {
    const int f = m->bodies[b].first, s0 = m->slot[f];
    const mrvi_rate rate = m->rate[f];
    if (m->bodies[b].dim != D)
      return snprintf(why, len, "bodies of two dimensions"), 0;
    if (mode == PLAN_SLOW && rate != MRVI_SLOW)
      return snprintf(why, len, "body '%s' is fast", m->bodies[b].name), 0;
    for (int j = 0; j < D * (D + 1); j++)
      if (m->slot[f + j] != s0 + j || m->rate[f + j] != rate)
        return snprintf(why, len, "body '%s' is not contiguous",
                        m->bodies[b].name),
               0;
    n_members += member(m, mode, b);
  }
  if (n_members == 0)
    return snprintf(why, len, "no %s bodies",
                    mode == PLAN_FAST ? "fast" : "slow"),
           0;
  int *is_int = calloc((size_t)m->n_constraints + 1, sizeof *is_int);
  int *up = malloc(((size_t)nb + 2) * sizeof *up);
  int *adj_start = calloc((size_t)nb + 2, sizeof *adj_start);
  int *adj = malloc(2 * ((size_t)m->n_constraints + 1) * sizeof *adj);
  int ok = is_int && up && adj_start && adj;
  if (!ok)
    snprintf(why, len, "out of memory");
  for (int b = 0; ok && b < nb; b++)
    is_int[m->bodies[b].constraint] = 1;
  for (int b = 0; ok && b <= nb; b++)
    up[b] = b; /* nb: the ground (and, fast plan, the slow bodies) */
  /* Every other constraint of the forest's rate a joint with a reduction,
   * no loop. */
  for (int c = 0; ok && c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    if (is_int[c] ||
        (mode != PLAN_SLOW && (mode == PLAN_FAST) != (k->where == MRVI_FAST)))
      continue;
    if (k->type->joint_motion <= 0 || k->type->joint_motion >= N_MOTIONS ||
        (mode != PLAN_FAST && k->where != MRVI_SLOW)) {
      snprintf(why, len, "constraint '%s' (%s) has no joint reduction",
               k->label, k->type->name);
      ok = 0;
      break;
    }
    int a = mrvi_model_body_of(m, k->in[0]), b = body_b(m, k, D);
    if (mode == PLAN_FAST &&
        (!member(m, mode, a) || (b >= 0 && !member(m, mode, b)))) {
      /* a fast body on a slow one: a moving ground */
      const int mo = k->type->joint_motion;
      if (mo != MRVI_JOINT_BALL && mo != MRVI_JOINT_HINGE) {
        snprintf(why, len,
                 "joint '%s' (%s) joins a fast body to a slow one: a "
                 "moving root is spherical or revolute",
                 k->label, k->type->name);
        ok = 0;
        break;
      }
      if (!member(m, mode, a))
        a = b;
      b = -1;
    }
    const int ra = mrvi_uf_root(up, a), rb = mrvi_uf_root(up, b < 0 ? nb : b);
    if (ra == rb && cut) { /* a cut joint: its rows close the loop */
      cut[c] = 1;
      continue;
    }
    if (ra == rb) {
      snprintf(why, len, "joint '%s' closes a loop", k->label);
      ok = 0;
      break;
    }
    up[ra] = rb;
    adj_start[a + 1]++;
    if (b >= 0)
      adj_start[b + 1]++;
  }
  if (ok) {
    /* Joints by body (CSR), then a breadth-first walk from the bodies on
     * the ground, then from the first body of each free part. */
    for (int b = 0; b < nb; b++)
      adj_start[b + 1] += adj_start[b];
    int *fill = up; /* reused */
    memcpy(fill, adj_start, (size_t)(nb + 1) * sizeof *fill);
    for (int c = 0; c < m->n_constraints; c++) {
      const mrvi_constraint *k = &m->constraints[c];
      if (is_int[c] || (cut && cut[c]) ||
          (mode != PLAN_SLOW && (mode == PLAN_FAST) != (k->where == MRVI_FAST)))
        continue;
      const int a = mrvi_model_body_of(m, k->in[0]), b = body_b(m, k, D);
      if (member(m, mode, a))
        adj[fill[a]++] = c;
      if (member(m, mode, b))
        adj[fill[b]++] = c;
    }
    int *tree_of = is_int; /* reused: body -> tree index + 1 */
    memset(tree_of, 0, (size_t)(m->n_constraints + 1) * sizeof *tree_of);
    int n = 0;
    for (int pass = 0; pass < 2; pass++)
      for (int r = 0; r < nb; r++) {
        if (tree_of[r] || !member(m, mode, r))
          continue;
        int ground = -1;
        for (int e = adj_start[r]; e < adj_start[r + 1]; e++)
          if (other(m, mode, &m->constraints[adj[e]], D, r) < 0)
            ground = adj[e];
        if (pass == 0 && ground < 0)
          continue;
        order[n] = r, parent[n] = -1, joint[n] = ground;
        tree_of[r] = ++n;
        for (int h = n - 1; h < n; h++) {
          const int b = order[h];
          for (int e = adj_start[b]; e < adj_start[b + 1]; e++) {
            const int o = other(m, mode, &m->constraints[adj[e]], D, b);
            if (o < 0 || tree_of[o])
              continue;
            order[n] = o, parent[n] = h, joint[n] = adj[e];
            tree_of[o] = ++n;
          }
        }
      }
    *count = n;
    /* why: the cut joints, if any */
    size_t used = (size_t)snprintf(why, len, "%s", "");
    for (int c = 0, nc = 0; cut && c < m->n_constraints; c++)
      if (cut[c] && used + 8 < len)
        used += (size_t)snprintf(why + used, len - used, "%s'%s'",
                                 nc++ ? ", " : "", m->constraints[c].label);
  }
  free(is_int), free(up), free(adj_start), free(adj);
  return ok;
}

static int plan_only(const mrvi_model *m, int mode, char *why, size_t len) {
  const int nb = m->n_bodies;
  int *a =
      malloc((3 * ((size_t)nb + 1) + (size_t)m->n_constraints + 1) * sizeof *a);
  if (!a)
    return snprintf(why, len, "out of memory"), 0;
  int n;
  const int ok = plan(m, mode, a, a + nb + 1, a + 2 * (nb + 1), &n,
                      mode != PLAN_BESIDE ? a + 3 * (nb + 1) : NULL, why, len);
  free(a);
  return ok;
}

int mrvi_nullspace_tree_plan(const mrvi_model *m, char *why, size_t len) {
  return plan_only(m, PLAN_SLOW, why, len);
}

int mrvi_nullspace_fast_plan(const mrvi_model *m, char *why, size_t len) {
  int fast = 0;
  for (int b = 0; b < m->n_bodies; b++)
    fast |= member(m, PLAN_FAST, b);
  return fast ? plan_only(m, PLAN_FAST, why, len) : 0;
}

/* ---------------------------------------------------------------------------
 * Geometry at q_k
 * ------------------------------------------------------------------------- */

static void cross(const double *a, const double *b, double *c) {
  c[0] = a[1] * b[2] - a[2] * b[1];
  c[1] = a[2] * b[0] - a[0] * b[2];
  c[2] = a[0] * b[1] - a[1] * b[0];
}

static const double *params(const mrvi_model *m, const mrvi_nstree *z, int t) {
  return m->constraints[z->joint[t]].params;
}

/* rho^i of tree body t's joint point in its own frame (own = 1) or in its
 * parent's (own = 0; the ground point p for a root). */
static const double *rho(const mrvi_model *m, const mrvi_nstree *z, int t,
                         int own) {
  const double *par = params(m, z, t);
  return par + JOINT_HEAD + (own == z->is_a[t] ? 0 : z->D);
}

/* Frame vector t_k of tree body t's joint in space on the positions pos
 * (nb x D(D+1), tree order): fixed in body A (body 0) or body B (body 1;
 * the ground's t_k is in space). */
static void joint_vec(const mrvi_model *m, const mrvi_nstree *z, int t,
                      int body, int k, const double *pos, double *v) {
  const int D = z->D, w = D * (D + 1),
            own = body == 0 ? z->is_a[t] : !z->is_a[t];
  const double *tk =
      params(m, z, t) + JOINT_HEAD + 2 * D + D * D * body + D * k;
  v[0] = v[1] = v[2] = 0.0;
  const int ground = !own && z->parent[t] < 0;
  if (ground && !(z->anchor && z->anchor[t] >= 0)) {
    for (int c = 0; c < D; c++)
      v[c] = tk[c];
    return;
  }
  const double *d = pos +
                    (size_t)w * (own      ? t
                                 : ground ? z->anchor[t]
                                          : z->parent[t]) +
                    D;
  for (int i = 0; i < D; i++)
    for (int c = 0; c < D; c++)
      v[c] += tk[i] * d[D * i + c];
}

/* P_t, X_t, S_t at the positions pos (nb x D(D+1), tree order). */
static void geometry(mrvi_nstree *z, const mrvi_model *m, const double *pos) {
  const int D = z->D, T = z->T, w = D * (D + 1);
  for (int t = 0; t < z->nb; t++) {
    const double *y = pos + (size_t)w * t, *d = y + D;
    double *P = z->P + (size_t)2 * T * T * t, *X = z->X + (size_t)T * T * t;
    double *S = z->S + (size_t)T * T * t, v[9];
    memset(P, 0, (size_t)2 * T * T * sizeof *P);
    for (int a = 0; a < D; a++)
      P[a * T + a] = 1.0;
    for (int k = 0; k < T - D; k++) {
      mrvi_nullspace_body_rotation(D, d, k, v);
      for (int e = 0; e < D * D; e++)
        P[(D + e) * T + D + k] = v[e];
    }
    /* X: u += w x (phi_t - phi_a) */
    memset(X, 0, (size_t)T * T * sizeof *X);
    if (z->parent[t] >= 0) {
      const double *ya = pos + (size_t)w * z->parent[t];
      double r[3] = {0.0, 0.0, 0.0};
      for (int a = 0; a < D; a++)
        r[a] = y[a] - ya[a];
      for (int a = 0; a < T; a++)
        X[a * T + a] = 1.0;
      if (D == 2) {
        X[0 * T + 2] = -r[1];
        X[1 * T + 2] = r[0];
      } else {
        X[0 * T + 4] = r[2], X[0 * T + 5] = -r[1];
        X[1 * T + 3] = -r[2], X[1 * T + 5] = r[0];
        X[2 * T + 3] = r[1], X[2 * T + 4] = -r[0];
      }
    }
    /* S: the joint's rotations about x_J, r = phi_t - x_J = -rho^i d^i */
    const int nd = z->dof[t];
    memset(S, 0, (size_t)T * T * sizeof *S);
    if (z->joint[t] < 0) {
      for (int a = 0; a < T; a++)
        S[a * nd + a] = 1.0;
      continue;
    }
    /* rotations about the joint point (w x r, w), then translations (v, 0) */
    double r[3] = {0.0, 0.0, 0.0}, axis[3][3] = {{0}};
    const double *rh = rho(m, z, t, 1);
    for (int i = 0; i < D; i++)
      for (int a = 0; a < D; a++)
        r[a] -= rh[i] * d[D * i + a];
    const int mo = z->motion[t], nr = n_rot(mo, D);
    if (D == 2 && nr == 1)
      S[0 * nd] = -r[1], S[1 * nd] = r[0], S[2 * nd] = 1.0; /* (J r, 1) */
    if (D == 3 && motions[mo].rot == ROT_ALL)
      for (int k = 0; k < nr; k++)
        axis[k][k] = 1.0;
    if (D == 3 && motions[mo].rot != ROT_ALL)
      for (int k = 0; k < nr; k++) /* a_1 (fixed in A), b_2 (in B) */
        joint_vec(m, z, t, k, k, pos, axis[k]);
    for (int k = 0; D == 3 && k < nr; k++) {
      double c[3];
      cross(axis[k], r, c);
      for (int a = 0; a < 3; a++) {
        S[a * nd + k] = c[a];
        S[(3 + a) * nd + k] = axis[k][a];
      }
    }
    for (int k = 0; k < n_tr(mo); k++) { /* b_1; b_2, b_3 (fixed in B) */
      double v[3];
      joint_vec(m, z, t, 1, motions[mo].tr == TR_LINE ? 0 : 1 + k, pos, v);
      for (int a = 0; a < D; a++)
        S[a * nd + nr + k] = v[a];
    }
  }
}

/* Positions of the bodies (tree order) from the unknowns x (increments from
 * q0 if q0 is not NULL), or from q0 alone (x NULL). */
static void gather(const mrvi_nstree *z, const double *x, const double *q0,
                   double *pos) {
  const int w = z->D * (z->D + 1);
  for (int t = 0; t < z->nb; t++)
    for (int e = 0; e < w; e++) {
      const int s = z->slot[t] + e;
      pos[(size_t)w * t + e] = (x ? x[s] : 0.0) + (q0 ? q0[s] : 0.0);
    }
}

/* ---------------------------------------------------------------------------
 * Closed loops: the cut joints (doc/multibody.md, "Joint-reduced null space
 * of closed loops"; Betsch & Leyendecker 2006, Part II)
 *
 * The joints that close loops are left out of the forest (plan); their rows
 * G_c restrict the tree's rates nu to C nu = 0 with C = G_c P_tree (rc rows),
 * so the loop's null-space matrix is P = P_tree N, N spanning the null space
 * of C.  Its reduced rows N^T P_tree^T r = 0 (r = R - A dx) say that
 * P_tree^T r lies in the range of C^T = P_tree^T G_c^T: P_tree^T (r - G_c^T
 * mu) = 0 for some mu, one unknown per kept cut row.  With y = (I - X)^-T
 * P_int^T (r - G_c^T mu) the rows of the tree keep their form, the cut rows'
 * forces entering the rows of their two bodies:
 *   (I - X)^T y + P_int^T A dx + P_int^T G_c^T mu = P_int^T R,
 *   S^T y = 0,  H dx = h (the kept rows, the cut ones too).
 * C itself is formed once, at q_0, for the rank-revealing pass that leaves
 * out the redundant cut rows.
 * ------------------------------------------------------------------------- */

/* C's row for gradient row gr of cut constraint k (its inputs), into out
 * (rate0: each body's first rate): g^T P_int (I - X)^-1 S = (S^T z)^T with
 * (I - X)^T z = P_int^T g, z by one sweep from the leaves, z_a = v_a + sum
 * over a's children c of X_c^T z_c. */
static void cut_row(mrvi_nstree *z, const mrvi_model *m,
                    const mrvi_constraint *k, const double *gr,
                    const int *rate0, double *out) {
  const int T = z->T;
  memset(z->cz, 0, (size_t)z->nb * T * sizeof *z->cz);
  for (int j = 0; j < k->n_in; j++) {
    const int t = z->tree_of[mrvi_model_body_of(m, k->in[j])];
    const int e = m->slot[k->in[j]] - z->slot[t];
    const double *P = z->P + (size_t)2 * T * T * t;
    for (int a = 0; a < T; a++)
      z->cz[(size_t)T * t + a] += P[e * T + a] * gr[j];
  }
  for (int t = z->nb - 1; t >= 0; t--) {
    const int pa = z->parent[t];
    const double *X = z->X + (size_t)T * T * t, *zt = z->cz + (size_t)T * t;
    for (int b = 0; pa >= 0 && b < T; b++) {
      double v = 0.0;
      for (int a = 0; a < T; a++)
        v += X[a * T + b] * zt[a];
      z->cz[(size_t)T * pa + b] += v;
    }
  }
  for (int t = 0; t < z->nb; t++) {
    const double *S = z->S + (size_t)T * T * t, *zt = z->cz + (size_t)T * t;
    for (int j = 0; j < z->dof[t]; j++) {
      double v = 0.0;
      for (int a = 0; a < T; a++)
        v += S[a * z->dof[t] + j] * zt[a];
      out[rate0[t] + j] = v;
    }
  }
}

/* The gradient rows of cut constraint k at q_k (z->qm) into z->cG. */
static void cut_gradient(mrvi_nstree *z, const mrvi_constraint *k) {
  double y[MRVI_MAX_INPUTS];
  for (int j = 0; j < k->n_in; j++)
    y[j] = z->qm[k->in[j]];
  mrvi_constraint_eval_at(k, y, z->cg, z->cG, NULL);
}

/* P_t^T g_c of every kept cut row on each of its bodies at q_k and the
 * current geometry (z->cv). */
static void cut_forces(mrvi_nstree *z, const mrvi_model *m) {
  const int T = z->T;
  memset(z->cv, 0, (size_t)z->rc * 2 * T * sizeof *z->cv);
  for (int i = 0; i < z->rc; i++) {
    const mrvi_constraint *k = &m->constraints[z->cut_c[i]];
    if (i == 0 || z->cut_c[i] != z->cut_c[i - 1])
      cut_gradient(z, k);
    const double *gr = z->cG + (size_t)z->cut_r[i] * k->n_in;
    for (int j = 0; j < k->n_in; j++) {
      const int t = z->tree_of[mrvi_model_body_of(m, k->in[j])];
      const int e = m->slot[k->in[j]] - z->slot[t], side = t != z->cut_t[2 * i];
      const double *P = z->P + (size_t)2 * T * T * t;
      double *v = z->cv + ((size_t)2 * i + side) * T;
      for (int a = 0; a < T; a++)
        v[a] += P[e * T + a] * gr[j];
    }
  }
}

/* The kept rows among the cut joints' at q_k = st->qs0 (the geometry taken
 * there; every row of the other constraints is kept): a cut row whose row
 * of C is within 1e-9 (relative) of the span of the earlier ones (a planar
 * loop modelled in 3-D) is left out, which must be what the integrator's
 * rank-revealing pass found (drop, model rows; may be NULL).  rows: its
 * count of rows, nall of them cut rows.  0, 1 (they disagree), or
 * MRVI_ENOMEM. */
static int cut_rows(mrvi_nstree *z, const mrvi_step *st,
                    const unsigned char *drop, unsigned char *mdrop, int nall) {
  const mrvi_model *m = st->model;
  const int nb = z->nb;
  int *rate0 = malloc(((size_t)nb + 1) * sizeof *rate0);
  if (!rate0)
    return MRVI_ENOMEM;
  rate0[0] = 0;
  for (int t = 0; t < nb; t++)
    rate0[t + 1] = rate0[t] + z->dof[t];
  const size_t nr = (size_t)rate0[nb] + 1;
  double *C = malloc(nr * sizeof *C);
  double *E = malloc(((size_t)nall + 1) * nr * sizeof *E);
  if (!C || !E)
    return free(rate0), free(C), free(E), MRVI_ENOMEM;
  int differ = 0, kept = 0;
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    if (z->cut[c])
      cut_gradient(z, k);
    for (int r = 0; r < k->rows; r++) {
      int red = 0;
      if (z->cut[c]) {
        cut_row(z, m, k, z->cG + (size_t)r * k->n_in, rate0, C);
        red = !mrvi_dense_extend_basis(rate0[nb], E, kept, C, 1e-9);
        kept += !red;
      }
      differ |= drop && !drop[k->first_row + r] != !red;
      mdrop[k->first_row + r] = (unsigned char)red;
      z->keep[st->c_off[c] + r] = !red;
      if (!z->cut[c] || red)
        continue;
      const int i = z->rc++;
      z->cut_c[i] = c, z->cut_r[i] = r, z->cut_e[i] = st->c_off[c] + r;
      z->cut_t[2 * i] = z->tree_of[mrvi_model_body_of(m, k->in[0])];
      const int b =
          k->n_in > 2 * z->T ? mrvi_model_body_of(m, k->in[2 * z->T]) : -1;
      z->cut_t[2 * i + 1] = b >= 0 ? z->tree_of[b] : -1;
    }
  }
  free(rate0), free(C), free(E);
  return differ;
}

/* The cut joints' kept rows and their body lists at q_k = st->qs0: 1, 0
 * and why, or MRVI_ENOMEM. */
static int cut_setup(mrvi_nstree *z, const mrvi_step *st,
                     const unsigned char *drop, char *why, size_t len) {
  const mrvi_model *m = st->model;
  const int nb = z->nb, T = z->T;
  int nall = 0, rmax = 1;
  for (int c = 0; c < m->n_constraints; c++)
    if (z->cut[c]) {
      nall += m->constraints[c].rows;
      rmax = m->constraints[c].rows > rmax ? m->constraints[c].rows : rmax;
    }
  const size_t na = (size_t)nall + 1;
  z->tree_of = malloc(((size_t)m->n_bodies + 1) * sizeof(int));
  z->keep = malloc((size_t)st->n_lambda + 1);
  z->cut_c = malloc(na * sizeof(int));
  z->cut_r = malloc(na * sizeof(int));
  z->cut_e = malloc(na * sizeof(int));
  z->cut_t = malloc(2 * na * sizeof(int));
  z->body_cut_start = calloc((size_t)nb + 2, sizeof(int));
  z->body_cut = malloc(2 * na * sizeof(int));
  z->cv = malloc(2 * na * T * sizeof(double));
  z->cz = malloc(((size_t)nb * T + 1) * sizeof(double));
  z->cg = malloc((size_t)rmax * sizeof(double));
  z->cG = malloc((size_t)rmax * (m->max_constraint_in + 1) * sizeof(double));
  unsigned char *mdrop = calloc((size_t)m->constraint_rows + 1, 1);
  if (!z->tree_of || !z->keep || !z->cut_c || !z->cut_r || !z->cut_e ||
      !z->cut_t || !z->body_cut_start || !z->body_cut || !z->cv || !z->cz ||
      !z->cg || !z->cG || !mdrop)
    return free(mdrop), MRVI_ENOMEM;
  for (int t = 0; t < nb; t++)
    z->tree_of[z->order[t]] = t;
  const int differ = cut_rows(z, st, drop, mdrop, nall);
  if (differ < 0 || differ == 1) {
    free(mdrop);
    return differ < 0 ? differ
                      : (snprintf(why, len,
                                  "the redundant rows at q0 are not the rows "
                                  "of the joints that close loops dependent "
                                  "on the earlier ones"),
                         0);
  }
  /* the kept rows by body */
  for (int h = 0; h < 2 * z->rc; h++)
    if (z->cut_t[h] >= 0)
      z->body_cut_start[z->cut_t[h] + 1]++;
  for (int t = 0; t < nb; t++)
    z->body_cut_start[t + 1] += z->body_cut_start[t];
  int *fill = malloc(((size_t)nb + 1) * sizeof *fill);
  if (!fill)
    return free(mdrop), MRVI_ENOMEM;
  memcpy(fill, z->body_cut_start, (size_t)nb * sizeof *fill);
  for (int h = 0; h < 2 * z->rc; h++)
    if (z->cut_t[h] >= 0)
      z->body_cut[fill[z->cut_t[h]]++] = h;
  free(fill);
  cut_forces(z, m);
  const int s = z->rc < nall ? mrvi_gram_drop(z->gram, mdrop) : MRVI_OK;
  free(mdrop);
  return s < 0 ? s : 1;
}

/* ---------------------------------------------------------------------------
 * Creation: the forest, the recipe of the extended rows, its pattern
 * ------------------------------------------------------------------------- */

typedef struct walk {
  mrvi_nstree *z;
  int build, row;
  long e, x;
} walk;

static int grow(int **a, double **c, long *cap, long n) {
  if (n < *cap)
    return 0;
  const long k = *cap ? 2 * *cap : 1024;
  int *na = realloc(*a, (size_t)k * sizeof *na);
  if (!na)
    return -1;
  *a = na;
  double *nc = realloc(*c, (size_t)k * sizeof *nc);
  if (!nc)
    return -1;
  *c = nc;
  *cap = k;
  return 0;
}

/* Entry of the current row: c times full row `row` (x columns). */
static int full(walk *w, int row, double c) {
  mrvi_nstree *z = w->z;
  if (w->build) {
    if (grow(&z->rec_row, &z->rec_coef, &z->cap_rec, w->e) < 0)
      return -1;
    z->rec_row[w->e] = row;
  }
  z->rec_coef[w->e++] = c;
  return 0;
}

/* Entry of the current row: c in column col (a y column). */
static int ext(walk *w, int col, double c) {
  mrvi_nstree *z = w->z;
  if (w->build) {
    if (grow(&z->ext_col, &z->ext_coef, &z->cap_ext, w->x) < 0)
      return -1;
    z->ext_col[w->x] = col;
  }
  z->ext_coef[w->x++] = c;
  return 0;
}

static void next_row(walk *w) {
  if (w->build) {
    w->z->rec_start[w->row] = (int)w->e;
    w->z->ext_start[w->row] = (int)w->x;
  }
  w->row++;
}

/* The extended rows in order (module header), with their coefficients at
 * the current geometry; build: record the sources too. */
static int rows(walk *w, const mrvi_step *st) {
  mrvi_nstree *z = w->z;
  const int T = z->T, nu = z->nu;
  int s = 0;
  for (int t = 0; t < z->nb; t++) {
    const double *P = z->P + (size_t)2 * T * T * t;
    for (int a = 0; a < T; a++) {
      next_row(w);
      for (int e = 0; e < 2 * T; e++)
        if ((a < z->D) == (e < z->D)) /* P's zero blocks left out */
          s |= full(w, z->slot[t] + e, P[e * T + a]);
      s |= ext(w, nu + t * T + a, 1.0);
      for (int h = z->body_cut_start[t]; h < z->body_cut_start[t + 1]; h++)
        s |= ext(w, nu + z->nb * T + z->body_cut[h] / 2, /* P_t^T G_c^T mu */
                 z->cv[(size_t)z->body_cut[h] * T + a]);
      for (int h = z->child_start[t]; h < z->child_start[t + 1]; h++) {
        const int c = z->child[h];
        const double *X = z->X + (size_t)T * T * c;
        for (int b = 0; b < T; b++)
          s |= ext(w, nu + c * T + b, -X[b * T + a]);
      }
    }
  }
  for (int t = 0; t < z->nb; t++) {
    const double *S = z->S + (size_t)T * T * t;
    for (int j = 0; j < z->dof[t]; j++) {
      next_row(w);
      for (int a = 0; a < T; a++)
        s |= ext(w, nu + t * T + a, S[a * z->dof[t] + j]);
    }
  }
  for (int q = 0; q < z->ns; q++)
    if (!z->in_body[q]) {
      next_row(w);
      s |= full(w, q, 1.0);
    }
  for (int q = z->ns; q < nu + st->n_lambda; q++) {
    if (q >= nu && !z->keep[q - nu])
      continue; /* a redundant cut row */
    next_row(w);
    s |= full(w, q, 1.0);
  }
  return s;
}

static int build_pattern(mrvi_nstree *z) {
  long nt = z->n_ext;
  for (long e = 0; e < z->n_rec; e++)
    nt += z->csr_start[z->rec_row[e] + 1] - z->csr_start[z->rec_row[e]];
  if (nt > 2147483647L)
    return -1;
  int *Ti = malloc((size_t)(nt + 1) * sizeof *Ti);
  int *Tj = malloc((size_t)(nt + 1) * sizeof *Tj);
  z->map = malloc((size_t)(nt + 1) * sizeof *z->map);
  z->Ap = malloc(((size_t)z->n + 1) * sizeof *z->Ap);
  z->Ai = malloc((size_t)(nt + 1) * sizeof *z->Ai);
  if (!Ti || !Tj || !z->map || !z->Ap || !z->Ai) {
    free(Ti), free(Tj);
    return -1;
  }
  long t = 0;
  for (int i = 0; i < z->n; i++) {
    for (int e = z->rec_start[i]; e < z->rec_start[i + 1]; e++) {
      const int r = z->rec_row[e];
      for (int k = z->csr_start[r]; k < z->csr_start[r + 1]; k++)
        Ti[t] = i, Tj[t++] = z->csr_col[k];
    }
    for (int e = z->ext_start[i]; e < z->ext_start[i + 1]; e++)
      Ti[t] = i, Tj[t++] = z->ext_col[e];
  }
  const int status = umfpack_di_triplet_to_col(
      z->n, z->n, (int)nt, Ti, Tj, NULL, z->Ap, z->Ai, NULL, z->map);
  free(Ti), free(Tj);
  if (status != UMFPACK_OK)
    return -1;
  z->nnz = z->Ap[z->n];
  z->Ax = calloc((size_t)z->nnz + 1, sizeof *z->Ax);
  return z->Ax ? 0 : -1;
}

/* Body t's joint to its parent (or the ground): which side of it the body
 * is, the joint's motion and the body's degrees of freedom (T: free). */
static void body_motion(mrvi_nstree *z, const mrvi_model *m, int t, int D,
                        int T) {
  z->dof[t] = T;
  if (z->joint[t] < 0)
    return;
  const mrvi_constraint *k = &m->constraints[z->joint[t]];
  z->is_a[t] = mrvi_model_body_of(m, k->in[0]) == z->order[t];
  z->motion[t] = k->type->joint_motion;
  z->dof[t] = n_rot(z->motion[t], D) + n_tr(z->motion[t]);
}

/* The children of each of the nb bodies, in tree order, as CSR lists
 * (child_start, zeroed by the caller, and child); MRVI_ENOMEM or 0. */
static int link_children(mrvi_nstree *z, int nb) {
  for (int t = 0; t < nb; t++)
    if (z->joint[t] >= 0 && z->parent[t] >= 0)
      z->child_start[z->parent[t] + 1]++;
  for (int t = 0; t < nb; t++)
    z->child_start[t + 1] += z->child_start[t];
  int *fill = malloc(((size_t)nb + 1) * sizeof *fill);
  if (!fill)
    return MRVI_ENOMEM;
  memcpy(fill, z->child_start, ((size_t)nb + 1) * sizeof *fill);
  for (int t = 0; t < nb; t++)
    if (z->joint[t] >= 0 && z->parent[t] >= 0)
      z->child[fill[z->parent[t]]++] = t;
  free(fill);
  return 0;
}

/* A tree of plan mode `mode` with its order, parent and joint arrays
 * (plan's): 1 and *out (*n_tree its bodies), 0 and why (nothing kept), or
 * MRVI_ENOMEM. */
static int planned_tree(const mrvi_model *m, int mode, mrvi_nstree **out,
                        int *n_tree, char *why, size_t len) {
  *out = NULL;
  mrvi_nstree *z = calloc(1, sizeof *z);
  if (!z)
    return MRVI_ENOMEM;
  const size_t B = (size_t)m->n_bodies + 1;
  z->order = malloc(B * sizeof(int));
  z->parent = malloc(B * sizeof(int));
  z->joint = malloc(B * sizeof(int));
  if (mode != PLAN_BESIDE)
    z->cut = malloc(((size_t)m->n_constraints + 1) * sizeof(int));
  if (!z->order || !z->parent || !z->joint ||
      (mode != PLAN_BESIDE && !z->cut)) {
    mrvi_nstree_free(z);
    return MRVI_ENOMEM;
  }
  if (!plan(m, mode, z->order, z->parent, z->joint, n_tree, z->cut, why, len)) {
    mrvi_nstree_free(z);
    return 0;
  }
  *out = z;
  return 1;
}

int mrvi_nstree_create(const mrvi_step *st, const unsigned char *drop,
                       mrvi_nstree **out, char *why, size_t len) {
  const mrvi_model *m = st->model;
  *out = NULL;
  if (st->r_micro > 0)
    return snprintf(why, len, "constraints at micro nodes"), 0;
  mrvi_nstree *z;
  int n_tree;
  const int got = planned_tree(m, PLAN_SLOW, &z, &n_tree, why, len);
  if (got != 1)
    return got;
  const int nb = m->n_bodies;
  const size_t B = (size_t)nb + 1;
  z->nb = nb;
  const int D = m->bodies[0].dim, T = D * (D + 1) / 2, w = D * (D + 1);
  z->D = D, z->T = T;
  z->ns = st->ns, z->nf = st->nf, z->p = st->p;
  z->nu = st->n_unknowns, z->n_lambda = st->n_lambda;
  z->n = z->nu + nb * T;
  z->is_a = calloc(B, sizeof(int));
  z->motion = calloc(B, sizeof(int));
  z->slot = malloc(B * sizeof(int));
  z->dof = malloc(B * sizeof(int));
  z->child_start = calloc(B + 1, sizeof(int));
  z->child = malloc(B * sizeof(int));
  z->in_body = calloc((size_t)st->ns + 1, sizeof(int));
  z->P = malloc(B * 2 * T * T * sizeof(double));
  z->X = malloc(B * T * T * sizeof(double));
  z->S = malloc(B * T * T * sizeof(double));
  z->qk = malloc(((size_t)st->ns + 1) * sizeof(double));
  z->qm = calloc((size_t)m->n + 1, sizeof(double));
  z->pm = calloc((size_t)m->n + 1, sizeof(double));
  z->qx = calloc((size_t)m->n + 1, sizeof(double));
  z->mu = calloc((size_t)m->constraint_rows + 1, sizeof(double));
  z->pos = malloc(B * w * sizeof(double));
  z->npos = malloc(B * w * sizeof(double));
  z->th = malloc(B * 3 * sizeof(double));
  z->u = malloc(B * 3 * sizeof(double));
  z->Q = malloc(B * 9 * sizeof(double));
  if (!z->is_a || !z->motion || !z->slot || !z->dof || !z->child_start ||
      !z->child || !z->in_body || !z->P || !z->X || !z->S || !z->qk || !z->qm ||
      !z->pm || !z->qx || !z->mu || !z->pos || !z->npos || !z->th || !z->u ||
      !z->Q)
    goto oom;
  for (int t = 0; t < nb; t++) {
    const mrvi_body *bd = &m->bodies[z->order[t]];
    z->slot[t] = m->slot[bd->first];
    for (int e = 0; e < w; e++)
      z->in_body[z->slot[t] + e] = 1;
    body_motion(z, m, t, D, T);
  }
  if (link_children(z, nb) < 0)
    goto oom;
  for (int i = 0; i < m->n; i++)
    z->qm[i] = m->q0[i];
  for (int s = 0; s < z->ns; s++)
    z->qm[m->slow_index[s]] = st->qs0[s];
  if (mrvi_gram_create(m, &z->gram) < 0 ||
      mrvi_nullspace_csr(st, &z->csr_start, &z->csr_col, &z->csr_idx) < 0)
    goto oom;
  gather(z, NULL, st->qs0, z->pos);
  geometry(z, m, z->pos);
  /* Closed loops: the kept cut rows and C at q_k; one mu per row. */
  const int cs = cut_setup(z, st, drop, why, len);
  if (cs <= 0) {
    mrvi_nstree_free(z);
    return cs;
  }
  z->n += z->rc;
  z->rec_start = malloc(((size_t)z->n + 1) * sizeof(int));
  z->ext_start = malloc(((size_t)z->n + 1) * sizeof(int));
  if (!z->rec_start || !z->ext_start)
    goto oom;
  walk wk = {z, 1, 0, 0, 0};
  if (rows(&wk, st) < 0)
    goto oom;
  if (wk.row != z->n) {
    mrvi_nstree_free(z);
    return snprintf(why, len,
                    "the joints' rows (%d) do not match the bodies' "
                    "coordinates",
                    st->n_lambda),
           0;
  }
  z->rec_start[z->n] = (int)wk.e;
  z->ext_start[z->n] = (int)wk.x;
  z->n_rec = wk.e, z->n_ext = wk.x;
  if (build_pattern(z) < 0)
    goto oom;
  *out = z;
  return 1;
oom:
  mrvi_nstree_free(z);
  return MRVI_ENOMEM;
}

/* ---------------------------------------------------------------------------
 * Multipliers and the reduced system
 * ------------------------------------------------------------------------- */

/* P, X, S and the Gram factor at q_k, when q_k is new; 0, or -1 where the
 * Gram matrix is singular. */
static int at_qk(mrvi_nstree *z, const mrvi_step *st) {
  const mrvi_model *m = st->model;
  if (z->have_qk && memcmp(z->qk, st->qs0, (size_t)z->ns * sizeof *z->qk) == 0)
    return 0;
  memcpy(z->qk, st->qs0, (size_t)z->ns * sizeof *z->qk);
  for (int s = 0; s < z->ns; s++)
    z->qm[m->slow_index[s]] = st->qs0[s];
  gather(z, NULL, st->qs0, z->pos);
  geometry(z, m, z->pos);
  cut_forces(z, m);
  z->have_qk = mrvi_gram_factor(z->gram, m, z->qm) == MRVI_OK;
  return z->have_qk ? 0 : -1;
}

int mrvi_nstree_lambda(mrvi_nstree *z, mrvi_step *st, double *x,
                       const double *F, char *msg, size_t len) {
  const mrvi_model *m = st->model;
  if (at_qk(z, st) < 0)
    return mrvi_fail(msg, len, MRVI_ESINGULAR,
                     "null-space form: the joints' constraint gradients are "
                     "dependent");
  /* dT G^T lambda = F on the slow rows, least squares in M^-1. */
  for (int s = 0; s < z->ns; s++)
    z->pm[m->slow_index[s]] = F[s];
  mrvi_gram_project(z->gram, m, z->pm, z->mu);
  double *lam = x + z->nu;
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    for (int r = 0; r < k->rows; r++)
      lam[st->c_off[c] + r] = z->mu[k->first_row + r] / st->dT;
  }
  return MRVI_OK;
}

void mrvi_nstree_reduce(mrvi_nstree *z, const mrvi_step *st,
                        const double *Rfull, double *rhs) {
  walk wk = {z, 0, 0, 0, 0};
  rows(&wk, st);
  const mrvi_row_recipe rr = {z->n,         z->rec_start, z->rec_row,
                              z->ext_start, z->csr_start, z->csr_idx,
                              z->map,       z->rec_coef,  z->ext_coef};
  mrvi_row_recipe_apply(&rr, st, Rfull, z->Ax, z->nnz, rhs);
}

/* ---------------------------------------------------------------------------
 * Nodal reparametrisation
 * ------------------------------------------------------------------------- */

/* c = a b (D x D, row-major). */
static void matmul(int D, const double *a, const double *b, double *c) {
  for (int i = 0; i < D; i++)
    for (int j = 0; j < D; j++) {
      double s = 0.0;
      for (int k = 0; k < D; k++)
        s += a[i * D + k] * b[k * D + j];
      c[i * D + j] = s;
    }
}

/* A cross's turn: the relative turn th ~ al e_p + be e_c (least squares)
 * on its axes e_p, e_c fixed in the parent and the child (a_1 in A, b_2 in
 * B), unit, at the base positions; ep <- al e_p, ec <- be e_c. */
static void cross_turn(const mrvi_model *m, const mrvi_nstree *z, int t,
                       const double *th, double *ep, double *ec) {
  const int pb = z->is_a[t]; /* the parent's body: B if t is A */
  joint_vec(m, z, t, pb, pb, z->pos, ep);
  joint_vec(m, z, t, !pb, !pb, z->pos, ec);
  double np = 0.0, nc = 0.0, c = 0.0, fp = 0.0, fc = 0.0;
  for (int a = 0; a < 3; a++)
    np += ep[a] * ep[a], nc += ec[a] * ec[a];
  np = sqrt(np), nc = sqrt(nc);
  for (int a = 0; a < 3; a++) {
    ep[a] /= np, ec[a] /= nc;
    c += ep[a] * ec[a], fp += ep[a] * th[a], fc += ec[a] * th[a];
  }
  const double det = 1.0 - c * c; /* sin^2 of the axes' angle, > 0 */
  const double al = (fp - c * fc) / det, be = (fc - c * fp) / det;
  for (int a = 0; a < 3; a++)
    ep[a] *= al, ec[a] *= be;
}

/* A joint with free translations: its point xj (on the parent, placed) moved
 * to the child's own point, the base b moved by the child's shift and on
 * its placed directors, projected on the line along b_1 (TR_LINE) or on the
 * plane normal to b_1 (TR_PLANE), b_1 of the placed body B. */
static void slide(const mrvi_model *m, const mrvi_nstree *z, int t,
                  const double *b, const double *rc, double *xj) {
  const int D = z->D, w = D * (D + 1);
  const double *nw = z->npos + (size_t)w * t;
  double e[3], x[3], ee = 0.0, f = 0.0;
  joint_vec(m, z, t, 1, 0, z->npos, e);
  for (int a = 0; a < D; a++) {
    x[a] = b[a] + z->u[3 * t + a];
    for (int i = 0; i < D; i++)
      x[a] += rc[i] * nw[D + D * i + a];
    ee += e[a] * e[a], f += (x[a] - xj[a]) * e[a];
  }
  f /= ee;
  for (int a = 0; a < D; a++)
    xj[a] = motions[z->motion[t]].tr == TR_LINE ? xj[a] + f * e[a]
                                                : x[a] - f * e[a];
}

/* The turn Q (D x D) that a fast root on a moving ground takes from it
 * between the base positions z->pos and the new ones z->npos: a 3-D hinge
 * the shortest turn from the ground's invariant direction then to now (its
 * axis a_1, or b_2 x b_3 when the ground is body B), which keeps the rows
 * a_1 . b_2, a_1 . b_3 while the interpolated ground deforms; else the
 * identity (the rows are the point's alone). */
static void anchor_turn(const mrvi_model *m, const mrvi_nstree *z, int t,
                        double *Q) {
  const int D = z->D;
  for (int i = 0; i < D * D; i++)
    Q[i] = i % (D + 1) == 0 ? 1.0 : 0.0;
  if (D != 3 || z->motion[t] != MRVI_JOINT_HINGE)
    return;
  double v[2][3], th[3], c = 0.0, s2 = 0.0;
  for (int k = 0; k < 2; k++) {
    const double *pos = k ? z->npos : z->pos;
    if (!z->is_a[t])
      joint_vec(m, z, t, 0, 0, pos, v[k]); /* a_1 of the ground A */
    else {
      double b2[3], b3[3];
      joint_vec(m, z, t, 1, 1, pos, b2);
      joint_vec(m, z, t, 1, 2, pos, b3);
      cross(b2, b3, v[k]);
    }
    const double n =
        sqrt(v[k][0] * v[k][0] + v[k][1] * v[k][1] + v[k][2] * v[k][2]);
    for (int a = 0; a < 3; a++)
      v[k][a] /= n;
  }
  cross(v[0], v[1], th);
  for (int a = 0; a < 3; a++)
    c += v[0][a] * v[1][a], s2 += th[a] * th[a];
  const double sn = sqrt(s2);
  const double f = sn > 1e-300 ? atan2(sn, c) / sn : 1.0;
  for (int a = 0; a < 3; a++)
    th[a] *= f;
  for (int k = 0; k < 3; k++) {
    double e[3] = {0.0, 0.0, 0.0};
    e[k] = 1.0;
    mrvi_nullspace_rotate(3, th, e);
    for (int i = 0; i < 3; i++)
      Q[i * 3 + k] = e[i];
  }
}

/* The directors of base positions b turned by Q into nw (D(D+1) each). */
static void turn_frame(int D, const double *Q, const double *b, double *nw) {
  for (int i = 0; i < D; i++)
    for (int a = 0; a < D; a++) {
      double s = 0.0;
      for (int c = 0; c < D; c++)
        s += Q[a * D + c] * b[D + D * i + c];
      nw[D + D * i + a] = s;
    }
}

/* The directors d (D rows of D) made orthonormal to one rounding by a
 * step of the Newton-Schulz iteration d <- (3 I - d d^T) d / 2 (an error e
 * in d d^T becomes O(e^2)): turning a frame by rotations leaves its rows
 * orthonormal only to the roundings of all turns so far, a drift of the
 * internal constraints the iterates of a closed loop's step cannot follow
 * (the cut joints' rows settle at that drift, and the step's residual at
 * it times the constraint forces). */
static void orthonormalise(int D, double *d) {
  double g[9], e[9];
  for (int i = 0; i < D; i++)
    for (int j = 0; j < D; j++) {
      double s = 0.0;
      for (int a = 0; a < D; a++)
        s += d[D * i + a] * d[D * j + a];
      g[D * i + j] = (i == j ? 3.0 : 0.0) - s;
    }
  matmul(D, g, d, e);
  for (int k = 0; k < D * D; k++)
    d[k] = 0.5 * e[k];
}

/* The bodies from the base positions z->pos turned by z->th and (free
 * roots) moved by z->u, parents first (module header), written to x
 * (increments from q0 if not NULL). */
static void place(mrvi_nstree *z, const mrvi_model *m, double *x,
                  const double *q0) {
  const int D = z->D, w = D * (D + 1);
  for (int t = 0; t < z->nb; t++) {
    const double *b = z->pos + (size_t)w * t;
    double *nw = z->npos + (size_t)w * t, *Q = z->Q + 9 * t;
    const int pa = z->parent[t];
    double th[3], E[9], I[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    if (D == 2)
      I[2] = 0.0, I[3] = 1.0; /* 2 x 2 identity */
    const double *Qp = pa >= 0 ? z->Q + 9 * pa : I;
    double Qa[9];
    const int an = pa < 0 && z->anchor ? z->anchor[t] : -1;
    if (an >= 0) {
      anchor_turn(m, z, t, Qa);
      Qp = Qa;
    }
    for (int a = 0; a < 3; a++)
      th[a] = z->th[3 * t + a] - (pa >= 0 ? z->th[3 * pa + a] : 0.0);
    /* the turn relative to the parent on the joint's free rotations: E =
     * exp(th^), or for a cross exp(al e_p^) exp(be e_c^) with e_p, e_c its
     * axes fixed in the parent and the child, which keeps e_p . e_c */
    const int rot = z->joint[t] < 0 ? ROT_ALL : motions[z->motion[t]].rot;
    double ep[3] = {0.0, 0.0, 0.0}, ec[3] = {0.0, 0.0, 0.0};
    if (rot == ROT_NONE)
      th[0] = th[1] = th[2] = 0.0;
    if (rot == ROT_AXIS && D == 3) {
      double a[3];
      joint_vec(m, z, t, 0, 0, z->pos, a);
      const double f = (th[0] * a[0] + th[1] * a[1] + th[2] * a[2]) /
                       (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
      for (int c = 0; c < 3; c++)
        th[c] = f * a[c];
    }
    if (rot == ROT_CROSS)
      cross_turn(m, z, t, th, ep, ec);
    /* E by columns; Q_t = Q_parent E */
    for (int k = 0; k < D; k++) {
      double v[3] = {0.0, 0.0, 0.0};
      v[k] = 1.0;
      if (rot == ROT_CROSS) {
        mrvi_nullspace_rotate(D, ec, v);
        mrvi_nullspace_rotate(D, ep, v);
      } else
        mrvi_nullspace_rotate(D, th, v);
      for (int i = 0; i < D; i++)
        E[i * D + k] = v[i];
    }
    matmul(D, Qp, E, Q);
    turn_frame(D, Q, b, nw);
    if (z->cut) /* (the slow forest's; its loops are closed by Newton) */
      orthonormalise(D, nw + D);
    if (z->joint[t] < 0) {
      for (int a = 0; a < D; a++)
        nw[a] = b[a] + z->u[3 * t + a];
    } else {
      /* phi = x_J - rho^i d^i, x_J the parent's point (or the ground's),
       * moved along the joint's free translations by the child's own */
      const double *rp = rho(m, z, t, 0), *rc = rho(m, z, t, 1);
      const double *yp = pa >= 0   ? z->npos + (size_t)w * pa
                         : an >= 0 ? z->npos + (size_t)w * an
                                   : NULL;
      double xj[3];
      for (int a = 0; a < D; a++) {
        xj[a] = yp ? yp[a] : rp[a];
        for (int i = 0; yp && i < D; i++)
          xj[a] += rp[i] * yp[D + D * i + a];
      }
      if (motions[z->motion[t]].tr != TR_NONE)
        slide(m, z, t, b, rc, xj);
      for (int a = 0; a < D; a++) {
        double s = xj[a];
        for (int i = 0; i < D; i++)
          s -= rc[i] * nw[D + D * i + a];
        nw[a] = s;
      }
    }
    for (int e = 0; e < w; e++)
      x[z->slot[t] + e] = nw[e] - (q0 ? q0[z->slot[t] + e] : 0.0);
  }
}

/* Each body's turn and shift z->th, z->u from the update dx at the iterate
 * x (increments from q0 if not NULL), into the base positions z->pos: th =
 * 1/2 sum d^i x (-dd^i). */
static void turns(mrvi_nstree *z, const double *x, const double *q0,
                  const double *dx) {
  const int D = z->D;
  gather(z, x, q0, z->pos);
  for (int t = 0; t < z->nb; t++) {
    const double *d = z->pos + (size_t)D * (D + 1) * t + D;
    const double *v = dx + z->slot[t];
    double wv[9];
    for (int e = 0; e < D * D; e++)
      wv[e] = -v[D + e];
    mrvi_nullspace_rotation_of(D, d, wv, z->th + 3 * t);
    for (int a = 0; a < D; a++)
      z->u[3 * t + a] = -v[a];
  }
}

void mrvi_nstree_retract(mrvi_nstree *z, const mrvi_step *st, double *x,
                         const double *dx) {
  const double *q0 = st->increments ? st->qs0 : NULL;
  turns(z, x, q0, dx);
  for (int s = 0; s < z->nu; s++)
    x[s] -= dx[s];
  place(z, st->model, x, q0);
}

/* The bodies' coordinates in x moved onto the constraints, nearest in the
 * metric M (mrvi_gram_settle: a few chord corrections with the Gram factor
 * at q_k).  A move normal to the constraints in M changes the reduced
 * residual P^T R only to second order, while turning each body towards
 * the predictor's frame and placing it on its parent's joint point moves
 * the chain's far end along the constraints by the sum of the errors
 * above it (doc/performance/chains.md, "Chains: the joint-reduced null space").
 */
static void settle(mrvi_nstree *z, const mrvi_step *st, double *x) {
  const mrvi_model *m = st->model;
  const int w = z->D * (z->D + 1);
  const double *q0 = st->increments ? st->qs0 : NULL;
  if (at_qk(z, st) < 0)
    return; /* (the iteration reports it) */
  for (int t = 0; t < z->nb; t++)
    for (int e = 0; e < w; e++) {
      const int s = z->slot[t] + e;
      z->qx[m->slow_index[s]] = x[s] + (q0 ? q0[s] : 0.0);
    }
  mrvi_gram_settle(z->gram, m, z->qx, z->mu, MRVI_GRAM_SETTLE_PASSES);
  for (int t = 0; t < z->nb; t++)
    for (int e = 0; e < w; e++) {
      const int s = z->slot[t] + e;
      x[s] = z->qx[m->slow_index[s]] - (q0 ? q0[s] : 0.0);
    }
}

void mrvi_nstree_start(mrvi_nstree *z, const mrvi_step *st, double *x) {
  if (st->tuning.predict_settle)
    settle(z, st, x);
  mrvi_nsslow_start(z, st, x);
}

void mrvi_nsslow_start(mrvi_nstree *z, const mrvi_step *st, double *x) {
  const int D = z->D, w = D * (D + 1);
  const double *q0 = st->increments ? st->qs0 : NULL;
  /* The predictor's turns and shifts from q_k. */
  gather(z, x, q0, z->npos);
  gather(z, NULL, st->qs0, z->pos);
  for (int t = 0; t < z->nb; t++) {
    const double *b = z->pos + (size_t)w * t, *pr = z->npos + (size_t)w * t;
    mrvi_nullspace_nearest_rotation(D, b + D, pr + D, z->th + 3 * t);
    for (int a = 0; a < D; a++)
      z->u[3 * t + a] = pr[a] - b[a];
  }
  place(z, st->model, x, q0);
}

/* ---------------------------------------------------------------------------
 * The fast forest at the micro nodes
 *
 * Fast bodies in open chains and trees of joints among themselves, to the
 * ground, or to a slow body (doc/multibody.md, "Fast bodies in joints"):
 * at micro node m the slow body is interpolated, a0 q_k + a1 q_{k+1}, as
 * the step evaluates the slow-fast joint, and the fast tree hangs on its
 * joint point (and axis) as on a moving ground.  P_f = blkdiag(P_i) (I -
 * X)^-1 S at node m spans the null space of the fast part of the
 * micro-node constraints' gradient there; it is small (the fast bodies of
 * one model) and formed densely, column by column.
 * ------------------------------------------------------------------------- */

/* The moving grounds at node m into the rows nb.. of pos: each slow body
 * interpolated as the step interpolates it (step.c, slow_at). */
static void anchors(const mrvi_nstree *z, const mrvi_step *st, const double *x,
                    int m, double *pos) {
  const int w = z->D * (z->D + 1);
  const mrvi_point pt = mrvi_step_node_point(st, m, st->dt);
  for (int i = 0; i < z->na; i++)
    for (int e = 0; e < w; e++) {
      const int s = z->aslot[i] + e;
      pos[(size_t)w * (z->nb + i) + e] =
          st->increments ? st->qs0[s] + pt.a1 * x[s]
                         : pt.a0 * st->qs0[s] + pt.a1 * x[s];
    }
}

/* Fast node m of x (m >= 1) and the positions its entries are
 * displacements from (NULL unless st->increments). */
static double *node_of(const mrvi_nstree *z, const mrvi_step *st, double *x,
                       int m, const double **q0) {
  *q0 = st->increments ? st->qf0 : NULL;
  return x + z->ns + (size_t)(m - 1) * z->nf;
}

/* The fast forest's cut joints (closed loops of fast bodies): their kept
 * rows among the kept micro-node rows (fkeep: the step's micro-node row ->
 * its index among the kept ones, or -1) into z->fq, and the scratch of
 * mrvi_nsfast_columns; none (z->cut freed: no orthonormalisation, as for
 * open trees) without cut joints.  0, or MRVI_ENOMEM. */
static int fast_cuts(mrvi_nstree *z, const mrvi_step *st, const int *fkeep,
                     int nfc, int cols) {
  const mrvi_model *m = st->model;
  int any = 0;
  for (int c = 0; c < m->n_constraints; c++)
    any |= z->cut[c];
  if (!any) {
    free(z->cut);
    z->cut = NULL;
    return 0;
  }
  z->fq = malloc(((size_t)st->r_micro + 1) * sizeof(int));
  z->Pf = malloc(((size_t)cols * nfc + 1) * sizeof(double));
  z->Ct = malloc(((size_t)cols * st->r_micro + 1) * sizeof(double));
  z->Qc = malloc(((size_t)cols * cols + 1) * sizeof(double));
  if (!z->fq || !z->Pf || !z->Ct || !z->Qc)
    return MRVI_ENOMEM;
  for (int i = 0; i < st->n_micro_c; i++) {
    const int c = st->micro_c[i];
    for (int rr = 0; z->cut[c] && rr < m->constraints[c].rows; rr++)
      if (fkeep[st->c_off[c] + rr] >= 0)
        z->fq[z->fq_n++] = fkeep[st->c_off[c] + rr];
  }
  z->ncol = cols;
  return 0;
}

/* The forest of plan mode PLAN_FAST or PLAN_BESIDE for placement (and,
 * fast, the columns): 1 and *out, 0 and why, or MRVI_ENOMEM; fast: fpos,
 * nfc, r and fkeep as for mrvi_nsfast_create. */
static int forest_create(const mrvi_step *st, int mode, const int *fpos,
                         int nfc, int r, const int *fkeep, mrvi_nstree **out,
                         char *why, size_t len) {
  const mrvi_model *m = st->model;
  *out = NULL;
  mrvi_nstree *z;
  int nb;
  const int got = planned_tree(m, mode, &z, &nb, why, len);
  if (got != 1)
    return got;
  const size_t B = (size_t)m->n_bodies + 1;
  z->fast = mode == PLAN_FAST;
  const int D = m->bodies[0].dim, T = D * (D + 1) / 2, w = D * (D + 1);
  z->D = D, z->T = T, z->nb = nb;
  z->ns = st->ns, z->nf = st->nf, z->p = st->p;
  z->nu = st->n_unknowns;
  z->is_a = calloc(B, sizeof(int));
  z->motion = calloc(B, sizeof(int));
  z->slot = malloc(B * sizeof(int));
  z->dof = malloc(B * sizeof(int));
  z->child_start = calloc(B + 1, sizeof(int));
  z->child = malloc(B * sizeof(int));
  z->anchor = malloc(B * sizeof(int));
  z->aslot = malloc(B * sizeof(int));
  z->reached = malloc(B * sizeof(int));
  z->tw = malloc(B * T * sizeof(double));
  z->P = malloc(B * 2 * T * T * sizeof(double));
  z->X = malloc(B * T * T * sizeof(double));
  z->S = malloc(B * T * T * sizeof(double));
  z->pos = malloc(2 * B * w * sizeof(double));
  z->npos = malloc(2 * B * w * sizeof(double));
  z->th = malloc(B * 3 * sizeof(double));
  z->u = malloc(B * 3 * sizeof(double));
  z->Q = malloc(B * 9 * sizeof(double));
  if (!z->is_a || !z->motion || !z->slot || !z->dof || !z->child_start ||
      !z->child || !z->anchor || !z->aslot || !z->reached || !z->tw || !z->P ||
      !z->X || !z->S || !z->pos || !z->npos || !z->th || !z->u || !z->Q)
    goto oom;
  int cols = 0, in_fc = 1;
  for (int t = 0; t < nb; t++) {
    const mrvi_body *bd = &m->bodies[z->order[t]];
    z->slot[t] = m->slot[bd->first];
    for (int e = 0; z->fast && e < w; e++)
      in_fc &= fpos[z->slot[t] + e] >= 0;
    z->anchor[t] = -1;
    body_motion(z, m, t, D, T);
    if (z->joint[t] >= 0) {
      const mrvi_constraint *k = &m->constraints[z->joint[t]];
      const int o =
          z->is_a[t] ? body_b(m, k, D) : mrvi_model_body_of(m, k->in[0]);
      if (z->parent[t] < 0 && o >= 0) { /* a slow body: a moving ground */
        z->aslot[z->na] = m->slot[m->bodies[o].first];
        z->anchor[t] = nb + z->na++;
      }
    }
    cols += z->dof[t];
  }
  if (z->fast && fast_cuts(z, st, fkeep, nfc, cols) < 0)
    goto oom;
  if (z->fq_n && cols > MRVI_DENSE_MAX) { /* C's QR is dense */
    mrvi_nstree_free(z);
    return snprintf(why, len,
                    "the fast tree of a closed loop has %d joint rates, more "
                    "than %d",
                    cols, MRVI_DENSE_MAX),
           0;
  }
  if (z->fast && (!in_fc || cols - z->fq_n != nfc - r)) {
    mrvi_nstree_free(z);
    return snprintf(why, len,
                    "the fast joints' rows (%d) do not match the fast "
                    "bodies' coordinates",
                    r),
           0;
  }
  if (link_children(z, nb) < 0)
    goto oom;
  *out = z;
  return 1;
oom:
  mrvi_nstree_free(z);
  return MRVI_ENOMEM;
}

int mrvi_nsfast_create(const mrvi_step *st, const int *fpos, int nfc, int r,
                       const int *fkeep, mrvi_nstree **out, char *why,
                       size_t len) {
  return forest_create(st, PLAN_FAST, fpos, nfc, r, fkeep, out, why, len);
}

int mrvi_nsslow_create(const mrvi_step *st, mrvi_nstree **out, char *why,
                       size_t len) {
  return forest_create(st, PLAN_BESIDE, NULL, 0, 0, NULL, out, why, len);
}

int mrvi_nullspace_beside_plan(const mrvi_model *m, char *why, size_t len) {
  return plan_only(m, PLAN_BESIDE, why, len);
}

int mrvi_nsfast_bodies(const mrvi_nstree *z) { return z->nb; }
int mrvi_nsfast_cut_rows(const mrvi_nstree *z) { return z->fq_n; }

/* With cut joints: the tree's columns P_f (z->ncol of them) reduced to the
 * null space of the kept cut rows, P_f N, N spanning the null space of C =
 * G_c P_f (fq_n x ncol; G_c the kept cut rows of Gf), from the QR of C^T:
 * its last ncol - fq_n columns (doc/multibody.md, "Fast closed loops"). */
static int cut_columns(mrvi_nstree *z, int nfc, const double *Gf,
                       double *cols) {
  const int nc = z->ncol, k = z->fq_n;
  for (int j = 0; j < nc; j++)
    for (int i = 0; i < k; i++) {
      const double *g = Gf + (size_t)z->fq[i] * nfc,
                   *c = z->Pf + (size_t)j * nfc;
      double s = 0.0;
      for (int a = 0; a < nfc; a++)
        s += g[a] * c[a];
      z->Ct[(size_t)j * k + i] = s;
    }
  if (mrvi_dense_qr(nc, k, z->Ct, z->Qc) < 0)
    return -1;
  for (int o = 0; o < nc - k; o++) {
    double *col = cols + (size_t)o * nfc;
    memset(col, 0, (size_t)nfc * sizeof *col);
    for (int j = 0; j < nc; j++) {
      const double q = z->Qc[(size_t)j * nc + k + o];
      const double *c = z->Pf + (size_t)j * nfc;
      for (int a = 0; q != 0.0 && a < nfc; a++)
        col[a] += q * c[a];
    }
  }
  return 0;
}

int mrvi_nsfast_columns(mrvi_nstree *z, const mrvi_step *st, double *x, int m,
                        const int *fpos, int nfc, const double *Gf,
                        double *cols) {
  const int T = z->T, w = z->D * (z->D + 1);
  const double *q0 = st->qf0;
  const double *xm = m > 0 ? node_of(z, st, x, m, &q0) : NULL;
  gather(z, xm, q0, z->pos);
  anchors(z, st, x, m, z->pos);
  geometry(z, st->model, z->pos);
  /* Column (t, j): the twist S_t e_j carried rigidly down t's subtree
   * (parents first), each body's through its own P_i. */
  double *col = z->fq_n ? z->Pf : cols;
  for (int t = 0; t < z->nb; t++)
    for (int j = 0; j < z->dof[t]; j++, col += nfc) {
      memset(col, 0, (size_t)nfc * sizeof *col);
      for (int c = 0; c < z->nb; c++)
        z->reached[c] = c == t;
      for (int a = 0; a < T; a++)
        z->tw[(size_t)T * t + a] = z->S[(size_t)T * T * t + a * z->dof[t] + j];
      for (int c = t + 1; c < z->nb; c++) {
        const int pa = z->parent[c];
        if (!(z->reached[c] = pa >= 0 && z->reached[pa]))
          continue;
        const double *X = z->X + (size_t)T * T * c;
        for (int a = 0; a < T; a++) {
          double s = 0.0;
          for (int b = 0; b < T; b++)
            s += X[a * T + b] * z->tw[(size_t)T * pa + b];
          z->tw[(size_t)T * c + a] = s;
        }
      }
      for (int c = t; c < z->nb; c++) {
        if (!z->reached[c])
          continue;
        const double *P = z->P + (size_t)2 * T * T * c;
        for (int e = 0; e < w; e++) {
          double s = 0.0;
          for (int a = 0; a < T; a++)
            s += P[e * T + a] * z->tw[(size_t)T * c + a];
          col[fpos[z->slot[c] + e]] = s;
        }
      }
    }
  return z->fq_n ? cut_columns(z, nfc, Gf, cols) : 0;
}

void mrvi_nsslow_retract(mrvi_nstree *z, const mrvi_step *st,
                         const double *xold, double *x, const double *dx) {
  const double *q0 = st->increments ? st->qs0 : NULL;
  turns(z, xold, q0, dx);
  place(z, st->model, x, q0);
}

void mrvi_nsfast_retract(mrvi_nstree *z, const mrvi_step *st,
                         const double *xold, double *x, const double *dx) {
  for (int m = 1; m <= z->p; m++) {
    const double *q0;
    double *xn = node_of(z, st, x, m, &q0);
    const size_t o = (size_t)(xn - x);
    turns(z, xold + o, q0, dx + o);
    anchors(z, st, xold, m, z->pos);
    anchors(z, st, x, m, z->npos);
    place(z, st->model, xn, q0);
  }
}

void mrvi_nsfast_start(mrvi_nstree *z, const mrvi_step *st, double *x) {
  const int D = z->D, w = D * (D + 1);
  for (int m = 1; m <= z->p; m++) {
    const double *q0, *qb = st->qf0;
    double *xn = node_of(z, st, x, m, &q0);
    const double *xb = m > 1 ? node_of(z, st, x, m - 1, &qb) : NULL;
    /* node m - 1 as placed, the predictor's node m turned and moved from
     * it onto the joints */
    gather(z, xb, qb, z->pos);
    gather(z, xn, q0, z->npos);
    anchors(z, st, x, m - 1, z->pos);
    anchors(z, st, x, m, z->npos);
    for (int t = 0; t < z->nb; t++) {
      const double *b = z->pos + (size_t)w * t, *pr = z->npos + (size_t)w * t;
      mrvi_nullspace_nearest_rotation(D, b + D, pr + D, z->th + 3 * t);
      for (int a = 0; a < D; a++)
        z->u[3 * t + a] = pr[a] - b[a];
    }
    place(z, st->model, xn, q0);
  }
}
