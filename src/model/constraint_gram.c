/* The Gram matrix A = G M^-1 G^T of the constraint rows, sparse.
 *
 * The momentum projection (doc/constraints.md, "Momentum projection")
 * solves A mu = G M^-1 p at every macro node, and the independence check
 * asks whether G has full row rank.  In dense storage both cost
 * O(R^2 n) (R rows, n coordinates; doc/performance/paths.md, "Constrained
 * chains on structured paths").  Rows a and b couple in A only where their
 * constraints share a coordinate, so for chains and trees A is banded in the
 * rows' natural order.  Here A is kept in skyline (envelope) storage in that
 * order: row r holds the entries first[r] .. r, first[r] the smallest row that
 * shares a coordinate with row r; the Cholesky factor A = L L^T fills only the
 * envelope (no pivoting: A is symmetric positive definite when G has full
 * rank).  Cost per factorisation: the coordinate-wise products, sum over
 * coordinates of (rows touching it)^2, plus sum_r (r - first[r])^2; for a
 * chain O(R).
 *
 * Independence: Gram-Schmidt on the rows in the metric M^-1 (what
 * mrvi_constraints_independent does densely) leaves row r a remainder of
 * norm L_rr.  Cholesky computes L_rr^2 with an absolute error of order
 * eps A_rr, so a pivot L_rr^2 > 1e-12 A_rr proves the row independent of
 * the earlier ones; anything smaller is left to the dense check, which
 * names the dependent constraints. */
#include "model/model.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

struct mrvi_gram {
  int R, n_entries;
  int *first;          /* R: first column of row r's envelope */
  int *start;          /* R + 1: offset of row r's envelope in L */
  double *L;           /* the envelope: A, then its Cholesky factor */
  double *grad;        /* the rows' gradients by constraint: rows x n_in each */
  int *coord_ptr;      /* n + 1: entries touching coordinate j */
  int *entry_row;      /* n_entries: the row of an entry */
  int *entry_grad;     /* n_entries: its value's index in grad */
  int *entry_coord;    /* n_entries: its coordinate (for G^T mu) */
  double *y;           /* max_constraint_in: inputs of one constraint */
  double *gs;          /* rows x n_in of one constraint (scratch) */
  unsigned char *drop; /* R: rows left out (mrvi_gram_drop), or NULL */
};

void mrvi_gram_free(mrvi_gram *gr) {
  if (!gr)
    return;
  free(gr->first);
  free(gr->start);
  free(gr->L);
  free(gr->grad);
  free(gr->coord_ptr);
  free(gr->entry_row);
  free(gr->entry_grad);
  free(gr->entry_coord);
  free(gr->y);
  free(gr->gs);
  free(gr->drop);
  free(gr);
}

int mrvi_gram_create(const mrvi_model *m, mrvi_gram **out) {
  *out = NULL;
  mrvi_gram *gr = calloc(1, sizeof *gr);
  if (!gr)
    return MRVI_ENOMEM;
  const int R = m->constraint_rows, n = m->n;
  int ne = 0, ne_max = 0;
  for (int c = 0; c < m->n_constraints; c++) {
    const int e = m->constraints[c].rows * m->constraints[c].n_in;
    ne += e;
    ne_max = e > ne_max ? e : ne_max;
  }
  gr->R = R;
  gr->n_entries = ne;
  gr->first = malloc(((size_t)R + 1) * sizeof *gr->first);
  gr->start = malloc(((size_t)R + 1) * sizeof *gr->start);
  gr->grad = malloc(((size_t)ne + 1) * sizeof *gr->grad);
  gr->coord_ptr = calloc((size_t)n + 1, sizeof *gr->coord_ptr);
  gr->entry_row = malloc(((size_t)ne + 1) * sizeof *gr->entry_row);
  gr->entry_grad = malloc(((size_t)ne + 1) * sizeof *gr->entry_grad);
  gr->entry_coord = malloc(((size_t)ne + 1) * sizeof *gr->entry_coord);
  gr->y = malloc(((size_t)m->max_constraint_in + 1) * sizeof *gr->y);
  gr->gs = malloc(((size_t)ne_max + 1) * sizeof *gr->gs);
  int *low = malloc(((size_t)n + 1) * sizeof *low);
  if (!gr->first || !gr->start || !gr->grad || !gr->coord_ptr ||
      !gr->entry_row || !gr->entry_grad || !gr->entry_coord || !gr->y ||
      !gr->gs || !low) {
    free(low);
    mrvi_gram_free(gr);
    return MRVI_ENOMEM;
  }
  /* Entries by coordinate (counting sort), and the lowest row touching
   * each coordinate. */
  for (int j = 0; j < n; j++)
    low[j] = R;
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    for (int j = 0; j < k->n_in; j++) {
      gr->coord_ptr[k->in[j] + 1] += k->rows;
      if (k->first_row < low[k->in[j]])
        low[k->in[j]] = k->first_row;
    }
  }
  for (int j = 0; j < n; j++)
    gr->coord_ptr[j + 1] += gr->coord_ptr[j];
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    for (int r = 0; r < k->rows; r++) {
      const int row = k->first_row + r;
      gr->first[row] = row;
      for (int j = 0; j < k->n_in; j++)
        if (low[k->in[j]] < gr->first[row])
          gr->first[row] = low[k->in[j]];
    }
  }
  gr->start[0] = 0;
  for (int r = 0; r < R; r++)
    gr->start[r + 1] = gr->start[r] + (r - gr->first[r] + 1);
  gr->L = malloc(((size_t)gr->start[R] + 1) * sizeof *gr->L);
  if (!gr->L) {
    free(low);
    mrvi_gram_free(gr);
    return MRVI_ENOMEM;
  }
  /* Fill the entry lists: fill[j] is the next free slot of coordinate j
   * (low is no longer needed). */
  int *fill = low, g = 0;
  for (int j = 0; j < n; j++)
    fill[j] = gr->coord_ptr[j];
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    for (int r = 0; r < k->rows; r++)
      for (int j = 0; j < k->n_in; j++) {
        const int e = fill[k->in[j]]++;
        gr->entry_row[e] = k->first_row + r;
        gr->entry_grad[e] = g + r * k->n_in + j;
        gr->entry_coord[e] = k->in[j];
      }
    g += k->rows * k->n_in;
  }
  free(low);
  *out = gr;
  return MRVI_OK;
}

int mrvi_gram_drop(mrvi_gram *gr, const unsigned char *drop) {
  if (!gr->drop && !(gr->drop = malloc((size_t)gr->R + 1)))
    return MRVI_ENOMEM;
  memcpy(gr->drop, drop, (size_t)gr->R);
  return MRVI_OK;
}

/* Is row r left out? */
static int dropped(const mrvi_gram *gr, int r) {
  return gr->drop && gr->drop[r];
}

/* Entry (a, b), b <= a, of the envelope. */
static double *at(mrvi_gram *gr, int a, int b) {
  return &gr->L[gr->start[a] + (b - gr->first[a])];
}

int mrvi_gram_factor(mrvi_gram *gr, const mrvi_model *m, const double *q) {
  /* The rows' gradients at q, constraint by constraint. */
  double gl[MRVI_MAX_INPUTS];
  int g = 0;
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    for (int j = 0; j < k->n_in; j++)
      gr->y[j] = q[k->in[j]];
    mrvi_constraint_eval_at(k, gr->y, gl, gr->grad + g, NULL);
    g += k->rows * k->n_in;
  }
  /* A = G M^-1 G^T coordinate by coordinate (lower triangle). */
  memset(gr->L, 0, (size_t)gr->start[gr->R] * sizeof *gr->L);
  for (int j = 0; j < m->n; j++) {
    const double w = 1.0 / MRVI_MASS(m, j);
    for (int e = gr->coord_ptr[j]; e < gr->coord_ptr[j + 1]; e++) {
      const int a = gr->entry_row[e];
      const double ga = gr->grad[gr->entry_grad[e]] * w;
      for (int f = gr->coord_ptr[j]; f < gr->coord_ptr[j + 1]; f++)
        if (gr->entry_row[f] <= a && !dropped(gr, a) &&
            !dropped(gr, gr->entry_row[f]))
          *at(gr, a, gr->entry_row[f]) += ga * gr->grad[gr->entry_grad[f]];
    }
  }
  /* A row left out: a unit pivot, coupled to none (its mu stays 0). */
  for (int a = 0; gr->drop && a < gr->R; a++)
    if (gr->drop[a])
      *at(gr, a, a) = 1.0;
  /* Cholesky in the envelope, row by row; a pivot not clearly above
   * round-off of the row's own Gram entry gives up. */
  for (int a = 0; a < gr->R; a++) {
    const int fa = gr->first[a];
    double *la = at(gr, a, fa);
    for (int b = fa; b <= a; b++) {
      const int fb = gr->first[b];
      const double *lb = at(gr, b, fb);
      double s = la[b - fa];
      for (int k = fa > fb ? fa : fb; k < b; k++)
        s -= la[k - fa] * lb[k - fb];
      if (b < a) {
        la[b - fa] = s / lb[b - fb];
      } else {
        const double d = la[a - fa];
        if (!(s > 1e-12 * d) || !isfinite(s))
          return MRVI_ESINGULAR;
        la[a - fa] = sqrt(s);
      }
    }
  }
  return MRVI_OK;
}

/* mu <- A^-1 mu by the factor: L y = mu, then L^T mu = y (the envelope of
 * row a: first[a] .. a). */
static void chol_solve(mrvi_gram *gr, double *mu) {
  for (int a = 0; a < gr->R; a++) {
    const int fa = gr->first[a];
    const double *la = at(gr, a, fa);
    double s = mu[a];
    for (int k = fa; k < a; k++)
      s -= la[k - fa] * mu[k];
    mu[a] = s / la[a - fa];
  }
  for (int a = gr->R - 1; a >= 0; a--) {
    const int fa = gr->first[a];
    const double *la = at(gr, a, fa);
    mu[a] /= la[a - fa];
    for (int k = fa; k < a; k++)
      mu[k] -= la[k - fa] * mu[a];
  }
}

void mrvi_gram_project(mrvi_gram *gr, const mrvi_model *m, double *p,
                       double *mu) {
  const int R = gr->R;
  /* mu = G M^-1 p */
  memset(mu, 0, (size_t)R * sizeof *mu);
  for (int e = 0; e < gr->n_entries; e++) {
    const int j = gr->entry_coord[e];
    mu[gr->entry_row[e]] +=
        gr->grad[gr->entry_grad[e]] * p[j] / MRVI_MASS(m, j);
  }
  for (int r = 0; gr->drop && r < R; r++)
    if (gr->drop[r])
      mu[r] = 0.0;
  chol_solve(gr, mu);
  /* p -= G^T mu */
  for (int e = 0; e < gr->n_entries; e++)
    p[gr->entry_coord[e]] -= gr->grad[gr->entry_grad[e]] * mu[gr->entry_row[e]];
}

double mrvi_gram_settle(mrvi_gram *gr, const mrvi_model *m, double *q,
                        double *mu, int max_pass) {
  double gmax = INFINITY;
  for (int pass = 0; pass <= max_pass; pass++) {
    /* mu = g(q) */
    double worst = 0.0;
    for (int c = 0; c < m->n_constraints; c++) {
      const mrvi_constraint *k = &m->constraints[c];
      for (int j = 0; j < k->n_in; j++)
        gr->y[j] = q[k->in[j]];
      mrvi_constraint_eval_at(k, gr->y, mu + k->first_row, gr->gs, NULL);
      for (int r = 0; r < k->rows; r++) {
        if (dropped(gr, k->first_row + r))
          mu[k->first_row + r] = 0.0;
        worst = fmax(worst, fabs(mu[k->first_row + r]));
      }
    }
    if (!isfinite(worst))
      return INFINITY;
    /* (at round-off, or no longer contracting: done) */
    const int stop = pass == max_pass || !(worst < 0.5 * gmax);
    gmax = fmin(gmax, worst);
    if (stop || worst == 0.0)
      break;
    /* (G M^-1 G^T) mu = g by the factor, then q -= M^-1 G^T mu */
    chol_solve(gr, mu);
    for (int e = 0; e < gr->n_entries; e++) {
      const int j = gr->entry_coord[e];
      q[j] -=
          gr->grad[gr->entry_grad[e]] * mu[gr->entry_row[e]] / MRVI_MASS(m, j);
    }
  }
  return gmax;
}
