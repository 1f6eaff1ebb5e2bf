/* The `schur-bordered` path: constrained steps in the multiplier form by
 * block elimination of the step bordered by the constraint rows.
 *
 * The Newton matrix of a constrained step (doc/constraints.md) is
 *
 *     J = [ A  B ]   A: the n_unknowns rows and columns of x (with the
 *         [ C  E ]      constraint Hessians -h lambda^T hess g at the
 *                       unknown nodes), B: the multipliers' columns,
 *                       C: the constraint equations' gradients, E = 0,
 *
 * and A has the structure of an unconstrained step: a slow block coupled
 * to every micro node and a fast block lower-triangular by micro nodes
 * (row m: nodes m-2 .. m), which the schur path's block elimination
 * factors in O(p (n_f^3 + n_f^2 n_s) + n_s^3) (solver/blocks.c).  With
 * Y = A^-1 B (one block solve per multiplier) and z = A^-1 R_x,
 *
 *     (E - C Y) dlambda = R_c - C z,   dx = z - Y dlambda,
 *
 * a dense system of the n_lambda multipliers.  Cost per Newton update: one
 * factorisation of A, n_lambda + 1 block solves, nnz(C) n_lambda products
 * and n_lambda^3 / 3 for the bordered system.  Where every constraint is
 * enforced at macro nodes only (slow coordinates: B and C touch the slow
 * unknowns alone, E = 0), the slow block of A^-1 is S^-1, S the kept
 * Schur complement, so C Y = C_s S^-1 B_s costs n_lambda solves with S
 * (n_s^2 each) instead of block solves, and
 * dx = A^-1 (R_x - B dlambda) takes one more block solve.  The path is chosen
 * where n_s, n_f and n_lambda are at most bordered_max (solver/sweep.c,
 * mrvi_sweep_path); larger steps keep the sparse LU of the general path, whose
 * fill on chains and trees grows linearly with the length (doc/solver.md).  The
 * Jacobian is the general path's (the CSC assembled by step.c), factored
 * afresh at every update as on the general path: the iterates are the general
 * path's up to the round-off of the linear solve. */
#include "solver/solver.h"

#include <stdlib.h>
#include <string.h>

struct mrvi_bordered {
  mrvi_blocks *blocks;
  int nu, nl;
  double *Y;     /* nl x nu: A^-1 B by columns of B (B itself first) */
  double *K;     /* nl x nl: E - C Y, then its LU */
  int *piv;      /* nl */
  double *r;     /* nl */
  double *dz;    /* nu */
  int slow_only; /* B, C on the slow unknowns only, E = 0 */
  int ns;
  double *W; /* ns x nl: S^-1 B_s (slow_only) */
};

void mrvi_bordered_free(mrvi_bordered *bd) {
  if (!bd)
    return;
  mrvi_blocks_free(bd->blocks);
  free(bd->Y);
  free(bd->K);
  free(bd->piv);
  free(bd->r);
  free(bd->dz);
  free(bd->W);
  free(bd);
}

int mrvi_bordered_create(const mrvi_step *st, mrvi_bordered **out) {
  *out = NULL;
  mrvi_bordered *bd = calloc(1, sizeof *bd);
  if (!bd)
    return MRVI_ENOMEM;
  bd->nu = st->n_unknowns;
  bd->nl = st->n_lambda;
  const size_t nu = (size_t)bd->nu, nl = (size_t)bd->nl;
  bd->Y = malloc((nl * nu + 1) * sizeof *bd->Y);
  bd->K = malloc((nl * nl + 1) * sizeof *bd->K);
  bd->piv = malloc((nl + 1) * sizeof *bd->piv);
  bd->r = malloc((nl + 1) * sizeof *bd->r);
  bd->dz = malloc((nu + 1) * sizeof *bd->dz);
  bd->ns = st->ns;
  bd->W = malloc(((size_t)st->ns * nl + 1) * sizeof *bd->W);
  /* The pattern (fixed for the run) says whether the constraints touch
   * the slow unknowns only. */
  bd->slow_only = 1;
  for (int j = 0; j < st->n_total; j++)
    for (int q = st->Ap[j]; q < st->Ap[j + 1]; q++) {
      const int row_c = st->Ai[q] >= bd->nu, col_c = j >= bd->nu;
      if ((row_c && (col_c || j >= st->ns)) ||
          (col_c && !row_c && st->Ai[q] >= st->ns))
        bd->slow_only = 0;
    }
  if (!bd->Y || !bd->K || !bd->piv || !bd->r || !bd->dz || !bd->W ||
      mrvi_blocks_create(st, &bd->blocks) < 0) {
    mrvi_bordered_free(bd);
    return MRVI_ENOMEM;
  }
  *out = bd;
  return MRVI_OK;
}

/* The factors: A by block elimination (the constraint rows of x's columns
 * skipped), Y = A^-1 B (or W = S^-1 B_s where the constraints touch the
 * slow unknowns only), K = E - C Y and its LU. */
static int factor(mrvi_bordered *bd, const mrvi_step *st, char *msg,
                  size_t len) {
  const int nu = bd->nu, nl = bd->nl, ns = bd->ns;
  const int *Ap = st->Ap, *Ai = st->Ai;
  const double *Ax = st->Ax;
  int s = mrvi_blocks_factor(bd->blocks, st);
  if (s == MRVI_EINVAL)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "the step's Jacobian does not have the block structure "
                     "of the schur-bordered path");
  if (s < 0)
    return mrvi_fail(msg, len, MRVI_ESINGULAR,
                     "singular Newton matrix (block elimination)");
  memset(bd->K, 0, (size_t)nl * (size_t)nl * sizeof *bd->K);
  if (bd->slow_only) {
    /* W = S^-1 B_s (ns x nl row-major), K = -C_s W */
    memset(bd->W, 0, (size_t)ns * (size_t)nl * sizeof *bd->W);
    for (int l = 0; l < nl; l++)
      for (int q = Ap[nu + l]; q < Ap[nu + l + 1]; q++)
        bd->W[(size_t)Ai[q] * (size_t)nl + (size_t)l] += Ax[q];
    mrvi_blocks_slow_solve(bd->blocks, bd->W, nl);
    for (int j = 0; j < ns; j++)
      for (int q = Ap[j]; q < Ap[j + 1]; q++) {
        if (Ai[q] < nu)
          continue;
        double *ka = bd->K + (size_t)(Ai[q] - nu) * (size_t)nl;
        const double *wj = bd->W + (size_t)j * (size_t)nl;
        for (int l = 0; l < nl; l++)
          ka[l] -= Ax[q] * wj[l];
      }
  } else {
    /* Y = A^-1 B column by column, K = E - C Y */
    for (int l = 0; l < nl; l++) {
      double *y = bd->Y + (size_t)l * (size_t)nu;
      memset(bd->dz, 0, (size_t)nu * sizeof *bd->dz);
      for (int q = Ap[nu + l]; q < Ap[nu + l + 1]; q++) {
        if (Ai[q] < nu)
          bd->dz[Ai[q]] += Ax[q];
        else
          bd->K[(size_t)(Ai[q] - nu) * (size_t)nl + (size_t)l] += Ax[q];
      }
      mrvi_blocks_solve(bd->blocks, bd->dz, y);
    }
    for (int j = 0; j < nu; j++)
      for (int q = Ap[j]; q < Ap[j + 1]; q++) {
        if (Ai[q] < nu)
          continue;
        double *ka = bd->K + (size_t)(Ai[q] - nu) * (size_t)nl;
        for (int l = 0; l < nl; l++)
          ka[l] -= Ax[q] * bd->Y[(size_t)l * (size_t)nu + (size_t)j];
      }
  }
  if (mrvi_dense_lu_factor(nl, bd->K, bd->piv) < 0)
    return mrvi_fail(msg, len, MRVI_ESINGULAR,
                     "singular Newton matrix (constraint rows)");
  return MRVI_OK;
}

/* J dx = R with the factors. */
static void solve(mrvi_bordered *bd, const mrvi_step *st, const double *R,
                  double *dx) {
  const int nu = bd->nu, nl = bd->nl;
  const int *Ap = st->Ap, *Ai = st->Ai;
  const double *Ax = st->Ax;
  /* z = A^-1 R_x, K dlambda = R_c - C z */
  mrvi_blocks_solve(bd->blocks, R, bd->dz);
  for (int a = 0; a < nl; a++)
    bd->r[a] = R[nu + a];
  for (int j = 0; j < nu; j++)
    for (int q = Ap[j]; q < Ap[j + 1]; q++)
      if (Ai[q] >= nu)
        bd->r[Ai[q] - nu] -= Ax[q] * bd->dz[j];
  mrvi_dense_lu_solve(nl, bd->K, bd->piv, bd->r, 1);
  for (int l = 0; l < nl; l++)
    dx[nu + l] = bd->r[l];
  if (bd->slow_only) {
    /* dx = A^-1 (R_x - B dlambda) */
    for (int i = 0; i < nu; i++)
      bd->dz[i] = R[i];
    for (int l = 0; l < nl; l++)
      for (int q = Ap[nu + l]; q < Ap[nu + l + 1]; q++)
        bd->dz[Ai[q]] -= Ax[q] * bd->r[l];
    mrvi_blocks_solve(bd->blocks, bd->dz, dx);
  } else {
    /* dx = z - Y dlambda */
    for (int i = 0; i < nu; i++)
      dx[i] = bd->dz[i];
    for (int l = 0; l < nl; l++) {
      const double *y = bd->Y + (size_t)l * (size_t)nu, d = bd->r[l];
      for (int i = 0; i < nu; i++)
        dx[i] -= y[i] * d;
    }
  }
}

int mrvi_bordered_factor_solve(mrvi_bordered *bd, const mrvi_step *st,
                               const double *R, double *dx, char *msg,
                               size_t len) {
  const int s = factor(bd, st, msg, len);
  if (s == MRVI_OK)
    solve(bd, st, R, dx);
  return s;
}
