/* Generators: chains, rings and lattices of particles with nearest-neighbour
 * springs and a slow/fast assignment by rule. */
#include "model/model.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

/* Particles along each axis (1 for unused axes). */
static void extent(const mrvi_generator *g, int n[3]) {
  const int axes = g->kind == MRVI_GEN_LATTICE3D   ? 3
                   : g->kind == MRVI_GEN_LATTICE2D ? 2
                                                   : 1;
  for (int a = 0; a < 3; a++)
    n[a] = a < axes ? g->count[a] : 1;
}

long mrvi_generator_particles(const mrvi_generator *g, char *msg, size_t len) {
  int n[3];
  extent(g, n);
  const int min = g->kind == MRVI_GEN_RING ? 3 : g->kind == MRVI_GEN_CHAIN;
  for (int a = 0; a < 3; a++)
    if (n[a] < (a == 0 ? min : 1) || n[a] > 1000000)
      return mrvi_fail(msg, len, MRVI_EINVAL,
                       "%s needs %d to 1000000 particles per axis (got %d)",
                       g->kind == MRVI_GEN_RING ? "a ring" : "a generator",
                       min > 1 ? min : 1, n[a]);
  const long total = (long)n[0] * n[1] * n[2];
  if (total < 2 || total > MRVI_MAX_GENERATED)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "a generator makes 2 to %ld particles (got %ld)",
                     (long)MRVI_MAX_GENERATED, total);
  return total;
}

long mrvi_generator_springs(const mrvi_generator *g) {
  int n[3];
  extent(g, n);
  const long total = (long)n[0] * n[1] * n[2];
  /* along each axis, (n_a - 1) per line of the others; a ring's closing
   * one */
  long springs = g->kind == MRVI_GEN_RING;
  for (int a = 0; a < 3; a++)
    springs += (long)(n[a] - 1) * (total / n[a]);
  return springs;
}

void mrvi_generated_name(int kind, const char *prefix, const int n[3], long lin,
                         char *buf, size_t len) {
  const int i = (int)(lin % n[0]), j = (int)(lin / n[0] % n[1]),
            k = (int)(lin / ((long)n[0] * n[1]));
  if (kind == MRVI_GEN_LATTICE2D)
    mrvi_fmt(buf, len, "%s%d_%d", prefix, i, j);
  else if (kind == MRVI_GEN_LATTICE3D)
    mrvi_fmt(buf, len, "%s%d_%d_%d", prefix, i, j, k);
  else
    mrvi_fmt(buf, len, "%s%ld", prefix, lin);
}

static mrvi_rate rate_of(const mrvi_generator *g, const int idx[3], long lin) {
  switch (g->rates) {
  case MRVI_RATES_ALL_FAST:
    return MRVI_FAST;
  case MRVI_RATES_ALTERNATE:
    return (idx[0] + idx[1] + idx[2]) % 2 == 0 ? MRVI_SLOW : MRVI_FAST;
  case MRVI_RATES_EVERY:
    return lin % g->every == 0 ? MRVI_SLOW : MRVI_FAST;
  default:
    return MRVI_SLOW;
  }
}

/* Spring between generated particles a and b (model particle indices). */
static int join(mrvi_model *m, const mrvi_generator *g, int a, int b,
                int counts[4]) {
  const int fast = m->rate[mrvi_particle_first(m, a)] == MRVI_FAST &&
                   m->rate[mrvi_particle_first(m, b)] == MRVI_FAST;
  const mrvi_spring_spec *sp = fast ? &g->fast : &g->slow;
  if (!sp->law)
    return MRVI_OK;
  const double L0 = isnan(sp->rest_length) ? g->spacing : sp->rest_length;
  const int e = mrvi_model_add_spring(m, fast ? MRVI_FAST : MRVI_SLOW, a, b,
                                      sp->law, sp->params, L0);
  if (e < 0)
    return e;
  counts[fast ? 3 : 2]++;
  return MRVI_OK;
}

int mrvi_model_generate(mrvi_model *m, const mrvi_generator *g,
                        int counts_out[4]) {
  char msg[256];
  const long total = mrvi_generator_particles(g, msg, sizeof msg);
  if (total < 0)
    return mrvi_model_fail(m, (int)total, "%s", msg);
  const int d = m->dimension;
  const int need = g->kind == MRVI_GEN_RING        ? 2
                   : g->kind == MRVI_GEN_LATTICE2D ? 2
                   : g->kind == MRVI_GEN_LATTICE3D ? 3
                                                   : 1;
  if (d < need)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "this generator needs dimension >= %d (got %d)",
                           need, d);
  if (!g->prefix || !*g->prefix)
    return mrvi_model_fail(m, MRVI_EINVAL, "generator: empty name prefix");
  if (!(g->spacing > 0) || !isfinite(g->spacing))
    return mrvi_model_fail(
        m, MRVI_EINVAL, "generator: spacing must be > 0 (got %g)", g->spacing);
  if (g->rates == MRVI_RATES_EVERY && g->every < 1)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "generator: every must be >= 1 (got %d)", g->every);
  int n[3], counts[4] = {0, 0, 0, 0};
  extent(g, n);
  const int first = m->n_particles;
  int st0 = mrvi_model_reserve(m, (int)total, (int)mrvi_generator_springs(g));
  if (st0 < 0)
    return st0;
  /* The names by a rule, made when asked (model.c), not stored: a network
   * would hold a name and a pointer per particle and per coordinate. */
  const int ruled = strlen(g->prefix) <= MRVI_RULE_PREFIX_MAX;
  if (ruled) {
    const int st = mrvi_model_add_rule(m, g->kind, g->prefix, n);
    if (st < 0)
      return st;
  }
  /* Particles in linear order, x fastest. */
  for (long lin = 0; lin < total; lin++) {
    const int idx[3] = {(int)(lin % n[0]), (int)(lin / n[0] % n[1]),
                        (int)(lin / ((long)n[0] * n[1]))};
    double x[3] = {0, 0, 0}, v[3] = {0, 0, 0};
    char name[256];
    for (int a = 0; a < d; a++)
      x[a] = g->origin[a];
    if (g->kind == MRVI_GEN_RING) {
      /* Regular polygon with side `spacing` about the origin. */
      const double R = g->spacing / (2 * sin(M_PI / (double)total)),
                   phi = 2 * M_PI * (double)lin / (double)total;
      x[0] += R * cos(phi);
      x[1] += R * sin(phi);
    } else {
      for (int a = 0; a < need; a++)
        x[a] += g->spacing * idx[a];
    }
    for (int a = 0; a < d; a++) {
      if (g->displacement)
        x[a] += g->displacement[lin * d + a];
      if (g->velocity)
        v[a] = g->velocity[lin * d + a];
    }
    mrvi_generated_name(g->kind, g->prefix, n, lin, name, sizeof name);
    const mrvi_rate r = rate_of(g, idx, lin);
    const int p = ruled
                      ? mrvi_model_add_ruled_particle(m, name, g->mass, r, x, v)
                      : mrvi_model_add_particle(m, name, g->mass, r, x, v);
    if (p < 0)
      return p;
    counts[1] += r == MRVI_SLOW;
  }
  counts[0] = (int)total;
  /* Springs: each particle to its +x, +y, +z neighbour; the ring closes. */
  for (long lin = 0; lin < total; lin++) {
    const int idx[3] = {(int)(lin % n[0]), (int)(lin / n[0] % n[1]),
                        (int)(lin / ((long)n[0] * n[1]))};
    long stride = 1;
    for (int a = 0; a < 3; a++) {
      if (idx[a] + 1 < n[a]) {
        int st =
            join(m, g, first + (int)lin, first + (int)(lin + stride), counts);
        if (st < 0)
          return st;
      }
      stride *= n[a];
    }
  }
  if (g->kind == MRVI_GEN_RING) {
    int st = join(m, g, first + (int)total - 1, first, counts);
    if (st < 0)
      return st;
  }
  if (counts_out)
    for (int i = 0; i < 4; i++)
      counts_out[i] = counts[i];
  return first;
}
