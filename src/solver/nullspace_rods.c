/* Link-local null space of open chains and trees of particles on rods
 * (doc/constraints.md, "Particles on rods: the link-local basis"; the
 * particle case of the joint-reduced basis of nullspace_tree.c, Betsch &
 * Leyendecker 2006, Part II).
 *
 * Slow particles joined by slow rods (constraints/distance.c: between two
 * particles or from a particle to an anchor) into a forest, every
 * constraint of the model such a rod.  In tree order (parents first; a
 * root is a particle on a rod to an anchor, or a free one) particle t moves
 * with its parent and by the directions its rod leaves:
 *   v_t = v_a(t) + S_t nu_t,
 * S_t the d - 1 directions normal to the rod's unit direction n_t (x_t -
 * x_a(t), or x_t - anchor, normalised; S_t = I for a free root, whose
 * parent term is absent as for an anchored root).  In tree order (I - X) v =
 * S nu with X_t = I (v_t = v_a), so the null-space matrix is P = (I - X)^-1
 * S, dense down each subtree.  It is never formed: with y = (I - X)^-T r
 * (y_t the sum of r over t's subtree), r = R - A dx the member rows of the
 * dynamic residual after the update, the reduced rows P^T r = 0 read
 * S_t^T y_t = 0, i.e. y_t = n_t b_t with one number b_t per rod (y_t = 0 at
 * a free root).  Put back into (I - X)^T y = r:
 *   (A dx)_t + n_t b_t - sum_{c child of t} n_c b_c = R_t,   H dx = h,
 * the square sparse system [A N; H 0] (dx, b) = (R, h) of size n_unknowns
 * + rods, N the rods' unit directions at q_k (O(n) entries), solved by the
 * general path's sparse LU; dx is its first n_unknowns entries.  N spans
 * the range of G(q_k)^T, so the equations are the null-space form's (P^T F
 * = 0, h = 0, with any basis of the null space of G(q_k)): the numerical
 * basis and the multiplier form (whose slow-only forces dT G(q_k)^T lambda
 * are columns parallel to N) give the same step to the Newton tolerance,
 * and N has the multiplier form's pattern.
 *
 * Multipliers lambda(x): as nullspace_tree.c, the least-squares solution of
 * dT G^T lambda = F on the slow rows in the metric M^-1 by the sparse Gram
 * factor (model/constraint_gram.c), exact at the solution.  No nodal
 * reparametrisation: x -= dx, the rods held to the Newton tolerance; the
 * predictor is settled onto the rods where the multiplier form settles it
 * (tuning predict_settle, more than MRVI_GRAM_DENSE_MAX rods:
 * mrvi_gram_settle with the factor at q_k; on long chains one Newton update
 * less per step, doc/performance/chains.md "Chains"). */
#include "solver/solver.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

extern const mrvi_constraint_type mrvi_constraint_distance;

struct mrvi_nsrods {
  int D, n, nu, ns, nrod;
  int *row;    /* per rod: its row among the step's multipliers */
  int *ends;   /* per rod: 2 D slots (end i, then end j or -1: the anchor) */
  double *dir; /* per rod: D entries of n at q_k */
  int *pos;    /* per rod: 2 D places of its column's entries in Ax, or -1 */
  double *qk;
  int have_qk, settle;
  mrvi_gram *gram;
  double *qm, *pm, *mu, *qs; /* model-ordered q_k, forces, mu, settled q */
  int *Ap, *Ai;
  double *Ax;
  long nnz, nnz_x; /* entries, those of the x columns */
};

void mrvi_nsrods_free(mrvi_nsrods *z) {
  if (!z)
    return;
  free(z->row), free(z->ends), free(z->dir), free(z->pos), free(z->qk);
  mrvi_gram_free(z->gram), free(z->qm), free(z->pm), free(z->mu);
  free(z->qs);
  free(z->Ap), free(z->Ai), free(z->Ax);
  free(z);
}

int mrvi_nsrods_size(const mrvi_nsrods *z) { return z->n; }
int mrvi_nsrods_settles(const mrvi_nsrods *z) { return z->settle; }
const int *mrvi_nsrods_Ap(const mrvi_nsrods *z) { return z->Ap; }
const int *mrvi_nsrods_Ai(const mrvi_nsrods *z) { return z->Ai; }
const double *mrvi_nsrods_Ax(const mrvi_nsrods *z) { return z->Ax; }
long mrvi_nsrods_nnz(const mrvi_nsrods *z) { return z->nnz; }

/* Does the link-local basis apply: every constraint a slow rod between slow
 * particles (or to an anchor), the rods a forest?  1, or 0 and why. */
int mrvi_nullspace_rods_plan(const mrvi_model *m, char *why, size_t len) {
  const int D = m->dimension;
  snprintf(why, len, "no rods");
  if (m->n_constraints == 0)
    return 0;
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    if (k->type != &mrvi_constraint_distance) {
      snprintf(why, len, "constraint '%s' (%s) is not a rod", k->label,
               k->type->name);
      return 0;
    }
    int slow = k->where == MRVI_SLOW && (k->n_in == D || k->n_in == 2 * D);
    for (int j = 0; j < k->n_in && slow; j++)
      slow = m->rate[k->in[j]] == MRVI_SLOW;
    if (!slow) {
      snprintf(why, len, "rod '%s' is not between slow particles", k->label);
      return 0;
    }
  }
  /* A particle is the D coordinates a rod's end names, the same at every
   * rod; node m->n: the ground (every anchor). */
  int *first = malloc(((size_t)m->n + 1) * sizeof *first);
  int *up = malloc(((size_t)m->n + 1) * sizeof *up);
  int ok = first && up;
  if (!ok)
    snprintf(why, len, "out of memory");
  for (int i = 0; ok && i <= m->n; i++)
    first[i] = -1, up[i] = i;
  for (int c = 0; ok && c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    int node[2] = {m->n, m->n};
    for (int e = 0; e < k->n_in / D; e++) {
      const int *in = k->in + e * D;
      for (int a = 0; a < D && ok; a++) {
        ok = first[in[a]] < 0 || first[in[a]] == in[0];
        first[in[a]] = in[0];
      }
      node[e] = in[0];
    }
    if (!ok) {
      snprintf(why, len, "rod '%s' does not end at particles", k->label);
      break;
    }
    const int ra = mrvi_uf_root(up, node[0]), rb = mrvi_uf_root(up, node[1]);
    if (ra == rb) {
      snprintf(why, len, "rod '%s' closes a loop", k->label);
      ok = 0;
      break;
    }
    up[ra] = rb;
  }
  free(first), free(up);
  if (ok)
    snprintf(why, len, "%s", "");
  return ok;
}

/* Unit directions of the rods at q_k; -1 if a rod has zero length. */
static int directions(mrvi_nsrods *z, const mrvi_step *st) {
  const int D = z->D;
  for (int k = 0; k < z->nrod; k++) {
    const int *e = z->ends + 2 * D * k;
    const mrvi_constraint *c = &st->model->constraints[z->row[k]];
    double *n = z->dir + D * k, rr = 0.0;
    for (int a = 0; a < D; a++) {
      n[a] = st->qs0[e[a]] - (e[D] >= 0 ? st->qs0[e[D + a]] : c->params[1 + a]);
      rr += n[a] * n[a];
    }
    if (!(rr > 0.0))
      return -1;
    for (int a = 0; a < D; a++)
      n[a] /= sqrt(rr);
  }
  return 0;
}

/* The pattern: the step's x columns as they are, then one column per rod
 * with its ends' rows (ascending). */
static int build_pattern(mrvi_nsrods *z, const mrvi_step *st) {
  const int D = z->D, nu = z->nu;
  z->nnz_x = st->Ap[nu];
  z->nnz = z->nnz_x;
  for (int k = 0; k < z->nrod; k++)
    z->nnz += z->ends[2 * D * k + D] >= 0 ? 2 * D : D;
  z->Ap = malloc(((size_t)z->n + 1) * sizeof *z->Ap);
  z->Ai = malloc((size_t)(z->nnz + 1) * sizeof *z->Ai);
  z->Ax = calloc((size_t)(z->nnz + 1), sizeof *z->Ax);
  if (!z->Ap || !z->Ai || !z->Ax)
    return -1;
  memcpy(z->Ap, st->Ap, ((size_t)nu + 1) * sizeof *z->Ap);
  memcpy(z->Ai, st->Ai, (size_t)z->nnz_x * sizeof *z->Ai);
  long t = z->nnz_x;
  for (int k = 0; k < z->nrod; k++) {
    const int *e = z->ends + 2 * D * k, ne = e[D] >= 0 ? 2 * D : D;
    int *p = z->pos + 2 * D * k;
    for (int a = 0; a < 2 * D; a++)
      p[a] = -1;
    /* entry a of the ends at the place of its row among the column's */
    for (int a = 0; a < ne; a++) {
      int before = 0;
      for (int b = 0; b < ne; b++)
        before += e[b] < e[a];
      p[a] = (int)(t + before);
      z->Ai[t + before] = e[a];
    }
    t += ne;
    z->Ap[nu + k + 1] = (int)t;
  }
  return 0;
}

int mrvi_nsrods_create(const mrvi_step *st, const unsigned char *drop,
                       mrvi_nsrods **out, char *why, size_t len) {
  const mrvi_model *m = st->model;
  *out = NULL;
  if (!mrvi_nullspace_rods_plan(m, why, len))
    return 0;
  for (int r = 0; drop && r < m->constraint_rows; r++)
    if (drop[r])
      return snprintf(why, len, "redundant rows"), 0;
  if (st->r_micro > 0 || st->n_lambda != m->n_constraints)
    return snprintf(why, len, "constraints at micro nodes"), 0;
  mrvi_nsrods *z = calloc(1, sizeof *z);
  if (!z)
    return MRVI_ENOMEM;
  const int D = m->dimension, nr = m->n_constraints;
  z->D = D, z->nrod = nr, z->nu = st->n_unknowns, z->ns = st->ns;
  z->n = z->nu + nr;
  z->row = malloc((size_t)nr * sizeof *z->row);
  z->ends = malloc((size_t)nr * 2 * D * sizeof *z->ends);
  z->pos = malloc((size_t)nr * 2 * D * sizeof *z->pos);
  z->dir = malloc((size_t)nr * D * sizeof *z->dir);
  z->qk = malloc(((size_t)st->ns + 1) * sizeof *z->qk);
  z->qm = calloc((size_t)m->n + 1, sizeof *z->qm);
  z->pm = calloc((size_t)m->n + 1, sizeof *z->pm);
  z->mu = calloc((size_t)m->constraint_rows + 1, sizeof *z->mu);
  z->qs = calloc(2 * (size_t)m->n + 1, sizeof *z->qs);
  /* settled where the multiplier form settles (integrator.c: the sparse
   * Gram matrix), so that both start from the same predictor */
  z->settle = st->tuning.predict_settle && nr > MRVI_GRAM_DENSE_MAX;
  if (!z->row || !z->ends || !z->pos || !z->dir || !z->qk || !z->qm || !z->pm ||
      !z->mu || !z->qs)
    goto oom;
  /* Rod k is constraint k; its column is that of its multiplier's row. */
  for (int c = 0; c < nr; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    int *e = z->ends + 2 * D * c;
    z->row[c] = c;
    if (st->c_off[c] != c) {
      mrvi_nsrods_free(z);
      return snprintf(why, len, "rows out of order"), 0;
    }
    for (int a = 0; a < 2 * D; a++)
      e[a] = a < k->n_in ? m->slot[k->in[a]] : -1;
  }
  for (int i = 0; i < m->n; i++)
    z->qm[i] = m->q0[i];
  if (mrvi_gram_create(m, &z->gram) < 0 || build_pattern(z, st) < 0)
    goto oom;
  *out = z;
  return 1;
oom:
  mrvi_nsrods_free(z);
  return MRVI_ENOMEM;
}

/* The rods' directions and the Gram factor at q_k, when q_k is new; 0, or
 * -1 where a rod has zero length or the Gram matrix is singular. */
static int at_qk(mrvi_nsrods *z, const mrvi_step *st) {
  const mrvi_model *m = st->model;
  if (!z->have_qk || memcmp(z->qk, st->qs0, (size_t)z->ns * sizeof *z->qk)) {
    memcpy(z->qk, st->qs0, (size_t)z->ns * sizeof *z->qk);
    for (int s = 0; s < z->ns; s++)
      z->qm[m->slow_index[s]] = st->qs0[s];
    z->have_qk = directions(z, st) == 0 &&
                 mrvi_gram_factor(z->gram, m, z->qm) == MRVI_OK;
  }
  return z->have_qk ? 0 : -1;
}

void mrvi_nsrods_start(mrvi_nsrods *z, const mrvi_step *st, double *x) {
  const mrvi_model *m = st->model;
  if (!z->settle || at_qk(z, st) < 0)
    return; /* (a singular Gram matrix: the step reports it) */
  double *q = z->qs, *q1 = z->qs + m->n;
  memcpy(q, z->qm, (size_t)m->n * sizeof *q);
  for (int s = 0; s < z->ns; s++)
    q[m->slow_index[s]] = x[s] + (st->increments ? st->qs0[s] : 0.0);
  memcpy(q1, q, (size_t)m->n * sizeof *q1);
  mrvi_gram_settle(z->gram, m, q1, z->mu, MRVI_GRAM_SETTLE_PASSES);
  /* (the moves alone: coordinates no rod touches keep x exactly) */
  for (int s = 0; s < z->ns; s++)
    x[s] += q1[m->slow_index[s]] - q[m->slow_index[s]];
}

void mrvi_nsrods_retract(const mrvi_nsrods *z, double *x, const double *dx) {
  for (int s = 0; s < z->nu; s++)
    x[s] -= dx[s];
}

int mrvi_nsrods_lambda(mrvi_nsrods *z, mrvi_step *st, double *x,
                       const double *F, char *msg, size_t len) {
  const mrvi_model *m = st->model;
  if (at_qk(z, st) < 0)
    return mrvi_fail(msg, len, MRVI_ESINGULAR,
                     "null-space form: the rods' constraint gradients are "
                     "dependent (a rod of zero length)");
  /* dT G^T lambda = F on the slow rows, least squares in M^-1. */
  for (int s = 0; s < z->ns; s++)
    z->pm[m->slow_index[s]] = F[s];
  mrvi_gram_project(z->gram, m, z->pm, z->mu);
  for (int c = 0; c < z->nrod; c++)
    x[z->nu + c] = z->mu[m->constraints[c].first_row] / st->dT;
  return MRVI_OK;
}

void mrvi_nsrods_reduce(mrvi_nsrods *z, const mrvi_step *st,
                        const double *Rfull, double *rhs) {
  const int D = z->D;
  memcpy(z->Ax, st->Ax, (size_t)z->nnz_x * sizeof *z->Ax);
  for (int k = 0; k < z->nrod; k++) {
    const int *p = z->pos + 2 * D * k;
    const double *n = z->dir + D * k;
    for (int a = 0; a < 2 * D; a++)
      if (p[a] >= 0)
        z->Ax[p[a]] = a < D ? n[a] : -n[a - D];
  }
  memcpy(rhs, Rfull, (size_t)z->n * sizeof *rhs);
}
