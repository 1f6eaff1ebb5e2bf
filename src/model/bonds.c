/* The lines of a picture of the model (XDMF, animations; doc/output.md):
 * springs between two particles and rods (distance constraints) between
 * two particles.  Anchored springs and rods have one end at a fixed point
 * that is no particle, and pair interactions (the `lennard-jones` and
 * `inverse` laws) are no bonds: they are left out. */
#include "model/model.h"

#include <string.h>

/* A pair law acts between every pair it is written for, bonded or not. */
static int pair_law(const mrvi_law *law) {
  return law &&
         (!strcmp(law->name, "lennard-jones") || !strcmp(law->name, "inverse"));
}

/* Particle whose x coordinate is model coordinate c, or -1. */
static int particle_at(const mrvi_model *m, int c);

/* Store anchor (i, point, k) as number *count if it fits. */
static void push_anchor(const mrvi_model *m, int *particle, double *point,
                        int *kind, int cap, int *count, int i, const double *at,
                        int k) {
  if (*count < cap) {
    if (particle)
      particle[*count] = i;
    if (point)
      for (int a = 0; a < m->dimension; a++)
        point[(size_t)*count * (size_t)m->dimension + (size_t)a] = at[a];
    if (kind)
      kind[*count] = k;
  }
  (*count)++;
}

int mrvi_model_anchors(const mrvi_model *m, int *particle, double *point,
                       int *kind, int cap) {
  if (!m)
    return MRVI_EINVAL;
  int count = 0;
  for (int e = 0; e < m->n_elements; e++) {
    const mrvi_element *el = MRVI_ELEMENT(m, e);
    const int pi =
        el->kind == MRVI_ELEMENT_ANCHOR ? mrvi_element_particle(m, el, 0) : -1;
    if (pi >= 0)
      push_anchor(m, particle, point, kind, cap, &count, pi, el->anchor,
                  el->potential == MRVI_FAST ? 1 : 0);
  }
  const int d = m->dimension;
  for (int c = 0; c < m->n_constraints && d > 0; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    /* constraints/distance.c: a particle and an anchor, parameters the
     * length and the d anchor coordinates. */
    if (strcmp(k->type->name, "distance") != 0 || k->n_in != d ||
        k->n_params != d + 1)
      continue;
    const int i = particle_at(m, k->in[0]);
    if (i >= 0)
      push_anchor(m, particle, point, kind, cap, &count, i, k->params + 1, 2);
  }
  return count;
}

/* Particle whose x coordinate is model coordinate c, or -1. */
static int particle_at(const mrvi_model *m, int c) {
  for (int i = 0; i < m->n_particles; i++)
    if (mrvi_particle_first(m, i) == c)
      return i;
  return -1;
}

/* Store edge (i, j, kind) as number *count if it fits. */
static void push(int *pairs, int *kind, int cap, int *count, int i, int j,
                 int k) {
  if (*count < cap) {
    if (pairs) {
      pairs[2 * *count] = i;
      pairs[2 * *count + 1] = j;
    }
    if (kind)
      kind[*count] = k;
  }
  (*count)++;
}

int mrvi_model_edges(const mrvi_model *m, int *pairs, int *kind, int cap) {
  if (!m)
    return MRVI_EINVAL;
  int count = 0;
  for (int e = 0; e < m->n_elements; e++) {
    const mrvi_element *el = MRVI_ELEMENT(m, e);
    const int pi =
        el->kind == MRVI_ELEMENT_SPRING ? mrvi_element_particle(m, el, 0) : -1;
    if (pi >= 0 && !pair_law(el->law))
      push(pairs, kind, cap, &count, pi,
           mrvi_element_particle(m, el, m->dimension),
           el->potential == MRVI_FAST ? 1 : 0);
  }
  const int d = m->dimension;
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    if (strcmp(k->type->name, "distance") != 0 || k->n_params != 1 ||
        k->n_in != 2 * d)
      continue;
    const int i = particle_at(m, k->in[0]), j = particle_at(m, k->in[d]);
    if (i >= 0 && j >= 0)
      push(pairs, kind, cap, &count, i, j, 2);
  }
  return count;
}
