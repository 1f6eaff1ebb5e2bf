/* Cost estimates of the two paths of a constrained step in the multiplier
 * form (doc/solver.md, "Choosing between general and schur-bordered";
 * measured with bench_paths: doc/performance.md, "Constrained paths"):
 * the work of one Newton update's linear algebra (factorisation and
 * solve), which is all the two paths do differently (both assemble the
 * same CSC Jacobian, step.c, and take the same updates).  Counted from
 * the structure alone, so that the choice is deterministic:
 *
 *  - schur-bordered (solver/bordered.c, blocks.c) eliminates dense node
 *    blocks: with the slow block of a unknowns and p fast blocks of b,
 *    each fast block's LU (2/3 b^3), its solve for the slow columns
 *    Y_c = D_c^-1 (A_fs,c - L1_c Y_{c-1} - L2_c Y_{c-2}) (6 b^2 a) and
 *    its product into S (2 a^2 b), then S's LU (2/3 a^3):
 *
 *        F_b = p (2/3 b^3 + 6 b^2 a + 2 a^2 b) + 2/3 a^3
 *              + w (a^2 + p (2 a b + 3 b^2)),
 *
 *    the last term the dense blocks it clears and fills (w flops per
 *    stored entry, the tuning constant path_entry_cost).  With micro-node
 *    constraints a = n_s + r_s and b = n_f + r_f (the multipliers joined to
 *    their nodes); with macro-node constraints only a = n_s, b = n_f, and
 *    the r_s multipliers border S: r_s solves with S, the dense system
 *    K = -C_s S^-1 B_s and its LU (2 r a^2 + 2 r^2 a + 2/3 r^3, and
 *    w (r a + r^2) stored).
 *  - general (solver/newton.c) factors the n x n step (n = a + p b) by an
 *    LU in dense storage that skips zeros: it clears, scans and lists
 *    n^2 entries, and its elimination, ordered by nonzero count, costs
 *    about 2/3 n nnz (nnz/n nonzeros per row and column meeting at each of
 *    n pivots, the fill of the slow border and the constraint rows
 *    included):
 *
 *        F_g = w n^2 + 2/3 n nnz,
 *
 *    nnz counted from the model's coupling pattern (below).  Beyond
 *    newton_dense_max the general path takes UMFPACK, whose fixed costs
 *    and fill this does not model: there the structured path is kept, as
 *    measured (the spacecraft and the flexible pendulum at p >= 5 and 20).
 *
 * The step's nonzeros: with P the coordinates' coupling pattern (the
 * diagonal, each non-linear potential element's and constraint's inputs
 * pairwise),
 * P_ss, P_ff, P_sf its slow-slow, fast-fast and slow-fast pairs, G_s and
 * G_m the gradient entries (rows x inputs) of the macro-node and
 * micro-node constraints: the slow block P_ss, the fast rows coupled to
 * three nodes each (3p - 3 node blocks of P_ff, 1 at p = 1), the slow row
 * to every node and every node to the slow unknowns (2 p P_sf), and the
 * constraint rows and multiplier columns (2 G_s + 2 p G_m). */
#include "solver/solver.h"

#include <stdlib.h>

/* Mark the pairs of inputs in[0..k) in the n x n pattern P. */
static void couple(unsigned char *P, int n, const int *in, int k) {
  for (int i = 0; i < k; i++)
    for (int j = 0; j < k; j++)
      P[(size_t)in[i] * (size_t)n + (size_t)in[j]] = 1;
}

int mrvi_path_costs(const mrvi_model *m, const mrvi_settings *s,
                    mrvi_path_cost *c) {
  const int n = m->n, p = s->micro_steps;
  unsigned char *P = calloc((size_t)n * (size_t)n + 1, 1);
  if (!P)
    return MRVI_ENOMEM;
  for (int i = 0; i < n; i++)
    P[(size_t)i * (size_t)n + (size_t)i] = 1;
  for (int e = 0; e < m->n_elements; e++) {
    const mrvi_element *el = &m->elements[e];
    /* (gravity and constant forces are linear: no Hessian) */
    if (el->kind != MRVI_ELEMENT_GRAVITY && el->kind != MRVI_ELEMENT_FORCE)
      couple(P, n, el->in, el->n_in);
  }
  long gs = 0, gm = 0;
  int rs = 0, rf = 0;
  for (int k = 0; k < m->n_constraints; k++) {
    const mrvi_constraint *ct = &m->constraints[k];
    couple(P, n, ct->in, ct->n_in);
    if (ct->where == MRVI_SLOW)
      gs += (long)ct->rows * ct->n_in, rs += ct->rows;
    else
      gm += (long)ct->rows * ct->n_in, rf += ct->rows;
  }
  long pss = 0, pff = 0, psf = 0;
  for (int i = 0; i < n; i++)
    for (int j = 0; j < n; j++) {
      if (!P[(size_t)i * (size_t)n + (size_t)j])
        continue;
      const int si = m->rate[i] == MRVI_SLOW, sj = m->rate[j] == MRVI_SLOW;
      pss += si && sj;
      pff += !si && !sj;
      psf += si && !sj;
    }
  free(P);
  const long node_blocks = p == 1 ? 1 : 3L * p - 3;
  c->r_slow = rs;
  c->r_micro = rf;
  c->n = m->n_slow + rs + (long)p * (m->n_fast + rf);
  c->nnz = pss + node_blocks * pff + 2L * p * psf + 2 * gs + 2L * p * gm;
  const double w = s->tuning.path_entry_cost, P1 = (double)p;
  const double nn = (double)c->n;
  c->general = w * nn * nn + 2.0 / 3.0 * nn * (double)c->nnz;
  double a, b, border = 0.0;
  if (rf > 0) {
    a = m->n_slow + rs, b = m->n_fast + rf;
  } else {
    const double r = rs;
    a = m->n_slow, b = m->n_fast;
    border = 2 * r * a * a + 2 * r * r * a + 2.0 / 3.0 * r * r * r +
             w * (r * a + r * r);
  }
  c->a = (int)a;
  c->b = (int)b;
  c->bordered = P1 * (2.0 / 3.0 * b * b * b + 6 * b * b * a + 2 * a * a * b) +
                2.0 / 3.0 * a * a * a +
                w * (a * a + P1 * (2 * a * b + 3 * b * b)) + border;
  return MRVI_OK;
}
