/* Which components of the particles' momentum maps a model conserves by
 * symmetry (discrete Noether theorem, arXiv 2406.12991 §3; doc/output.md).
 *
 * The kinetic energy of particles is invariant under translations and
 * rotations, and so is the multirate discrete Lagrangian wherever V and W
 * are: the slow coordinates are interpolated linearly between macro nodes,
 * which commutes with both.  A momentum component is therefore conserved
 * when every potential element and every constraint is invariant under its
 * one-parameter group:
 *   linear momentum along e_a   translations x_i -> x_i + s e_a,
 *   angular momentum about e_a  rotations about the axis e_a through the
 *                               origin (2-D: about e_3 in the plane).
 * Elements by kind:
 *   spring, angle, distance between particles: functions of differences
 *     and distances, invariant under both;
 *   anchor spring, distance to an anchor a: no translation; a rotation
 *     about e_a iff a lies on that axis;
 *   gravity and forces: one linear potential c^T q, their coefficients
 *     added up first (opposite forces cancel under translations);
 *   term, that linear potential and the linear rows of the fixed, plane and
 *     linear constraints: functions of c^T y.  Per particle i the row has a
 * vector c_i; c^T y is invariant under translation along e_a iff sum_i c_i[a] =
 * 0, and under rotation about e_a iff every c_i is parallel to e_a (c_i x e_a =
 * 0).  Coordinates that are not particle coordinates do not move and do not
 * count; constraint types registered by users: unknown, so nothing they touch
 * is claimed conserved.  Rigid bodies (doc/multibody.md): the centre of mass
 * phi translates and rotates like a particle, the directors d_i only rotate
 * (a translation leaves them); their internal constraints d_i.d_j are
 * invariant under both, and so is a torsional spring between two bodies;
 * joints are not analysed (as unknown types). The tests
 * are exact (a zero sum, zero components): the answer concerns the model as
 * written, not a numerical tolerance. */
#include "model/model.h"

#include <stdlib.h>
#include <string.h>

typedef struct sym {
  int d;
  int lin[3]; /* translation along e_a keeps the model */
  int ang[3]; /* rotation about e_a keeps it (2-D: ang[2] only) */
} sym;

/* Rotation axes that exist in dimension d: 3-D all three, 2-D e_3. */
static int has_axis(int d, int a) { return d == 3 || (d == 2 && a == 2); }

/* part[c] for model coordinate c: -1 if it does not move under the groups,
 * else its axis, plus 3 for a director (rotates, does not translate). */
#define DIRECTOR 3
static int owner(const int *part, int c, int *axis) {
  if (part[c] < 0)
    return -1;
  *axis = part[c] % DIRECTOR;
  return part[c] >= DIRECTOR ? DIRECTOR : 0;
}

/* c^T y over model coordinates in (n entries, coefficients coef). */
static void linear_row(const int *part, sym *s, int n, const int *in,
                       const double *coef) {
  double sum[3] = {0, 0, 0};
  for (int j = 0; j < n; j++) {
    int a = 0;
    const int who = owner(part, in[j], &a);
    if (who < 0 || coef[j] == 0.0)
      continue;
    if (who != DIRECTOR)
      sum[a] += coef[j];
    /* c_i has a component along e_a: not parallel to any other axis. */
    for (int b = 0; b < 3; b++)
      if (b != a)
        s->ang[b] = 0;
  }
  for (int a = 0; a < s->d; a++)
    if (sum[a] != 0.0)
      s->lin[a] = 0;
}

/* Distance to the fixed point a (d entries). */
static void anchored(sym *s, const double *a) {
  for (int b = 0; b < 3; b++)
    s->lin[b] = 0;
  for (int ax = 0; ax < 3; ax++)
    for (int b = 0; b < s->d; b++)
      if (b != ax && a[b] != 0.0)
        s->ang[ax] = 0; /* a off the axis e_ax */
}

/* One element; gravity and forces are added to the linear potential
 * lin (n coefficients). */
static void element(const int *part, sym *s, const mrvi_element *e,
                    double *lin) {
  switch (e->kind) {
  case MRVI_ELEMENT_SPRING:
  case MRVI_ELEMENT_ANGLE:
    break;
  case MRVI_ELEMENT_ANCHOR:
    anchored(s, e->anchor);
    break;
  case MRVI_ELEMENT_TORSION:
    /* Between two bodies: dot products of directors, invariant under
     * both groups; to the ground: the ground's frame breaks rotations. */
    if (e->n_in == s->d * s->d)
      for (int a = 0; a < 3; a++)
        s->ang[a] = 0;
    break;
  case MRVI_ELEMENT_TERM:
    linear_row(part, s, e->n_in, e->in, e->coef);
    break;
  case MRVI_ELEMENT_GRAVITY:
  case MRVI_ELEMENT_FORCE:
    for (int j = 0; j < e->n_in; j++)
      lin[e->in[j]] += e->coef[j];
    break;
  }
}

static void constraint(const int *part, sym *s, const mrvi_constraint *c) {
  const char *type = c->type->name;
  const int d = s->d;
  if ((!strcmp(type, "distance") && c->n_params == 1) || !strcmp(type, "body"))
    return; /* between two particles; a body's directors */
  if (!strcmp(type, "distance") && c->n_params == c->n_in + 1) {
    anchored(s, c->params + 1);
    return;
  }
  if (!strcmp(type, "fixed")) {
    const double one = 1.0;
    for (int j = 0; j < c->n_in; j++)
      linear_row(part, s, 1, c->in + j, &one);
    return;
  }
  if ((!strcmp(type, "plane") && c->n_in == d) || !strcmp(type, "linear")) {
    linear_row(part, s, c->n_in, c->in, c->params);
    return;
  }
  /* Unknown type: every component it touches is lost. */
  for (int j = 0; j < c->n_in; j++) {
    int a = 0;
    if (owner(part, c->in[j], &a) >= 0) {
      memset(s->lin, 0, sizeof s->lin);
      memset(s->ang, 0, sizeof s->ang);
      return;
    }
  }
}

int mrvi_model_conserved(const mrvi_model *m, int *linear, int *angular) {
  if (!m)
    return MRVI_EINVAL;
  const int d = mrvi_model_dimension(m);
  sym s = {d, {0, 0, 0}, {0, 0, 0}};
  for (int a = 0; a < 3; a++) {
    s.lin[a] = a < d;
    s.ang[a] = has_axis(d, a);
  }
  const size_t n = (size_t)(m->n > 0 ? m->n : 1);
  int *part = malloc(n * sizeof *part), *all = malloc(n * sizeof *all);
  double *lin = calloc(n, sizeof *lin);
  if (!part || !all || !lin) {
    free(part);
    free(all);
    free(lin);
    return MRVI_ENOMEM;
  }
  for (int c = 0; c < m->n; c++) {
    part[c] = -1;
    all[c] = c;
  }
  for (int i = 0; i < m->n_particles; i++)
    for (int a = 0; a < d; a++)
      part[mrvi_particle_first(m, i) + a] = a;
  for (int b = 0; b < m->n_bodies; b++)
    for (int c = 0; c < d * (d + 1); c++)
      part[m->bodies[b].first + c] = c % d + (c < d ? 0 : DIRECTOR);
  for (int e = 0; e < m->n_elements; e++)
    element(part, &s, MRVI_ELEMENT(m, e), lin);
  linear_row(part, &s, m->n, all, lin);
  for (int c = 0; c < m->n_constraints; c++)
    constraint(part, &s, &m->constraints[c]);
  free(part);
  free(all);
  free(lin);
  if (linear)
    for (int a = 0; a < d; a++)
      linear[a] = s.lin[a];
  if (angular) {
    if (d == 3)
      memcpy(angular, s.ang, sizeof s.ang);
    else if (d == 2)
      angular[0] = s.ang[2];
  }
  return MRVI_OK;
}
