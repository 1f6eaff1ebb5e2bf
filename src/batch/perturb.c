/* The perturbations of an ensemble's case (doc/batch.md, Ensembles): its
 * initial state changed by numbers of its seed alone, in this order:
 *
 *   positions   q0_i += s x_i on the translational coordinates (particles,
 *               bodies' centres of mass, plain coordinates; not the
 *               directors), x_i standard normal or uniform of std 1
 *               (sqrt(3) (2u - 1));
 *   rotations   each body's directors d_k <- R d_k and their velocities
 *               with them (the body turned about its centre of mass, its
 *               angular velocity in the body frame kept), R uniform on
 *               SO(D) (Shoemake's quaternion from three uniforms; 2-D: an
 *               angle 2 pi u) or R = exp([theta]x), theta_k = s z_k
 *               (2-D: an angle s z);
 *   then the positions projected onto the constraints (the loader's
 *   projection, mrvi_model_project_positions: small corrections only);
 *   velocities  v0_i += s z_i, or thermal at temperature T: v_i = z_i /
 *               sqrt(m_i), the net momentum of every direction of the
 *               particles and bodies' centres removed (none on plain
 *               coordinates: their sum is no momentum), projected onto the
 *               constraints' tangent space, scaled to 2 KE / N_f = T
 *               (k_B = 1) with N_f the coordinates less the independent
 *               constraint rows less the momentum components removed;
 *   and the velocities projected onto the tangent space at the new
 *   positions.
 *
 * Numbers come from streams of the seed (batch.h): normal j of a stream
 * is mrvi_batch_normal(seed, STREAM + j); uniform j is the 53-bit uniform
 * of mrvi_batch_random(seed, 2 (STREAM + j)). */
#include "batch/batch.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static const double two_pi = 6.283185307179586;

static double uniform(uint64_t seed, uint64_t j) {
  return (double)(mrvi_batch_random(seed, 2 * j) >> 11) /
         9007199254740992.0; /* [0, 1) */
}

/* 1 for the coordinates that are a body's directors. */
static unsigned char *director_mask(const mrvi_model *m) {
  unsigned char *dir = calloc((size_t)m->n + 1, 1);
  for (int b = 0; dir && b < m->n_bodies; b++) {
    const mrvi_body *bd = &m->bodies[b];
    for (int k = bd->dim; k < bd->dim * (bd->dim + 1); k++)
      dir[bd->first + k] = 1;
  }
  return dir;
}

static void perturb_positions(mrvi_model *m, uint64_t seed, double s,
                              int uniform_numbers, const unsigned char *dir) {
  for (int i = 0; i < m->n; i++) {
    if (dir[i])
      continue;
    const uint64_t j = MRVI_BATCH_STREAM_POSITIONS + (uint64_t)i;
    const double x = uniform_numbers
                         ? sqrt(3.0) * (2.0 * uniform(seed, j) - 1.0)
                         : mrvi_batch_normal(seed, j);
    m->q0[i] += s * x;
  }
}

/* The rotation of body b (D x D, row-major). */
static void body_rotation(uint64_t seed, int b, int D, double s, int uni,
                          double *R) {
  const uint64_t j = MRVI_BATCH_STREAM_ROTATIONS + 4 * (uint64_t)b;
  if (D == 2) {
    const double a =
        uni ? two_pi * uniform(seed, j) : s * mrvi_batch_normal(seed, j);
    R[0] = cos(a), R[1] = -sin(a), R[2] = sin(a), R[3] = cos(a);
    return;
  }
  double w, x, y, z;
  if (uni) { /* Shoemake, Graphics Gems III (1992): uniform unit quaternion */
    const double u1 = uniform(seed, j), u2 = uniform(seed, j + 1),
                 u3 = uniform(seed, j + 2);
    const double r1 = sqrt(1.0 - u1), r2 = sqrt(u1);
    x = r1 * sin(two_pi * u2), y = r1 * cos(two_pi * u2);
    z = r2 * sin(two_pi * u3), w = r2 * cos(two_pi * u3);
  } else { /* rotation vector theta: the quaternion of exp([theta]x) */
    double t[3], a = 0.0;
    for (int k = 0; k < 3; k++) {
      t[k] = s * mrvi_batch_normal(seed, j + (uint64_t)k);
      a += t[k] * t[k];
    }
    a = sqrt(a);
    const double f = a > 0 ? sin(0.5 * a) / a : 0.5;
    w = cos(0.5 * a), x = f * t[0], y = f * t[1], z = f * t[2];
  }
  mrvi_quaternion_rotation(w, x, y, z, R);
}

static void rotate_bodies(mrvi_model *m, uint64_t seed, double s, int uni) {
  for (int b = 0; b < m->n_bodies; b++) {
    const mrvi_body *bd = &m->bodies[b];
    const int D = bd->dim;
    double R[9];
    body_rotation(seed, b, D, s, uni, R);
    for (int k = 0; k < D; k++) {
      double *vecs[2] = {m->q0 + bd->first + D * (k + 1),
                         m->v0 + bd->first + D * (k + 1)};
      for (int v = 0; v < 2; v++) {
        double old[3];
        memcpy(old, vecs[v], (size_t)D * sizeof *old);
        for (int r = 0; r < D; r++) {
          double acc = 0.0;
          for (int c = 0; c < D; c++)
            acc += R[r * D + c] * old[c];
          vecs[v][r] = acc;
        }
      }
    }
  }
}

/* Translational coordinates by direction: comp[i] = d (0..D-1) for
 * particles' and bodies' centres, -1 otherwise (plain coordinates, as the
 * elongations of a chain, have no net momentum: the sum of their momenta
 * is none).  Returns the number of directions: D, or 0 without particles
 * and bodies. */
static int directions(const mrvi_model *m, int *comp) {
  for (int i = 0; i < m->n; i++)
    comp[i] = -1;
  if (m->n_particles == 0 && m->n_bodies == 0)
    return 0;
  const int D = m->dimension;
  for (int k = 0; k < m->n_particles; k++)
    for (int d = 0; d < D; d++)
      comp[mrvi_particle_first(m, k) + d] = d;
  for (int b = 0; b < m->n_bodies; b++)
    for (int d = 0; d < D; d++)
      comp[m->bodies[b].first + d] = d;
  return D;
}

/* Thermal velocities (see the top); *dof gets N_f. */
static int thermal(mrvi_model *m, uint64_t seed, double T, int *dof, char *msg,
                   size_t len) {
  const int n = m->n;
  int *comp = malloc((size_t)n * sizeof *comp);
  unsigned char *drop = calloc((size_t)m->constraint_rows + 1, 1);
  if (!comp || !drop) {
    free(comp), free(drop);
    mrvi_fmt(msg, len, "out of memory");
    return MRVI_ENOMEM;
  }
  const int nd = directions(m, comp);
  for (int i = 0; i < n; i++)
    m->v0[i] =
        mrvi_batch_normal(seed, MRVI_BATCH_STREAM_VELOCITIES + (uint64_t)i) /
        sqrt(MRVI_MASS(m, i));
  /* Remove the centre-of-mass velocity of every direction. */
  for (int d = 0; d < nd; d++) {
    double P = 0.0, M = 0.0;
    for (int i = 0; i < n; i++)
      if (comp[i] == d)
        P += MRVI_MASS(m, i) * m->v0[i], M += MRVI_MASS(m, i);
    for (int i = 0; i < n; i++)
      if (comp[i] == d)
        m->v0[i] -= P / M;
  }
  int redundant = 0, st = MRVI_OK;
  if (m->constraint_rows > 0) {
    char why[512];
    redundant = mrvi_constraints_rank(m, m->q0, drop, why, sizeof why);
    st = redundant < 0 ? redundant : mrvi_model_project_velocities(m, NULL);
    if (st < 0)
      mrvi_fmt(msg, len, "thermal velocities: %s",
               redundant < 0 ? "out of memory" : mrvi_model_errmsg(m));
  }
  *dof = n - (m->constraint_rows - redundant) - nd;
  double ke = 0.0;
  for (int i = 0; i < n; i++)
    ke += 0.5 * MRVI_MASS(m, i) * m->v0[i] * m->v0[i];
  if (st == 0 && (*dof < 1 || !(ke > 0))) {
    mrvi_fmt(msg, len,
             "thermal velocities: %d degrees of freedom after the "
             "constraints and the net momentum",
             *dof);
    st = MRVI_EINVAL;
  }
  /* 2 KE / N_f = T: a scaling keeps zero momentum and the tangent space. */
  const double scale = st == 0 ? sqrt(T * *dof / (2.0 * ke)) : 0.0;
  for (int i = 0; st == 0 && i < n; i++)
    m->v0[i] *= scale;
  free(comp), free(drop);
  return st;
}

int mrvi_batch_perturb_apply(mrvi_system *sys, long seed,
                             const mrvi_batch_perturb *pt, int *dof, char *msg,
                             size_t len) {
  *dof = 0;
  mrvi_model *m = sys->model;
  const uint64_t s = (uint64_t)seed;
  const int moves =
      pt->position_std > 0 || pt->rotation_std > 0 || pt->rotation_uniform;
  if (seed < 0 || (!moves && pt->velocity_std == 0 && !(pt->temperature > 0)))
    return 0;
  if (pt->position_std > 0) {
    unsigned char *dir = director_mask(m);
    if (!dir) {
      mrvi_fmt(msg, len, "out of memory");
      return MRVI_ENOMEM;
    }
    perturb_positions(m, s, pt->position_std, pt->position_uniform, dir);
    free(dir);
  }
  if (pt->rotation_std > 0 || pt->rotation_uniform)
    rotate_bodies(m, s, pt->rotation_std, pt->rotation_uniform);
  if (moves && m->constraint_rows > 0) {
    double moved = 0.0;
    if (mrvi_model_project_positions(m, sys->settings.constraint_tol, &moved,
                                     NULL) < 0) {
      mrvi_fmt(msg, len, "perturbed positions: %s", mrvi_model_errmsg(m));
      return MRVI_EINVAL;
    }
  }
  int st = 0;
  if (pt->temperature > 0)
    return thermal(m, s, pt->temperature, dof, msg, len);
  for (int i = 0; pt->velocity_std > 0 && i < m->n; i++)
    m->v0[i] +=
        pt->velocity_std *
        mrvi_batch_normal(s, MRVI_BATCH_STREAM_VELOCITIES + (uint64_t)i);
  st = mrvi_model_project_velocities(m, NULL);
  if (st < 0)
    mrvi_fmt(msg, len, "perturbed velocities: %s", mrvi_model_errmsg(m));
  return st;
}

/* A number in the fewest digits that read back exactly. */
static void shortest(double x, char *buf, size_t len) {
  for (int prec = 15; prec <= 17; prec++) {
    snprintf(buf, len, "%.*g", prec, x);
    if (strtod(buf, NULL) == x)
      break;
  }
}

int mrvi_batch_perturb_note(mrvi_system *sys, long seed,
                            const mrvi_batch_perturb *pt, int dof) {
  if (seed < 0 || !sys->description)
    return 0;
  char note[2048], num[32];
  size_t at = 0;
  const size_t n = strlen(sys->description);
  if (n > 0 && sys->description[n - 1] != '\n')
    note[at++] = '\n';
  note[at] = '\0';
#define SAY(...)                                                               \
  (at += (size_t)snprintf(note + at, sizeof note - at, __VA_ARGS__),           \
   at = at < sizeof note ? at : sizeof note - 1)
  if (pt->position_std > 0) {
    shortest(pt->position_std, num, sizeof num);
    SAY("# mrvi batch, seed %ld: the translational positions are the above "
        "plus %s\n# times the %s numbers of seed %ld (doc/batch.md, "
        "Ensembles).\n",
        seed, num, pt->position_uniform ? "uniform (std 1)" : "standard normal",
        seed);
  }
  if (pt->rotation_uniform)
    SAY("# mrvi batch, seed %ld: every body turned by a uniform random "
        "rotation of seed %ld.\n",
        seed, seed);
  else if (pt->rotation_std > 0) {
    shortest(pt->rotation_std, num, sizeof num);
    SAY("# mrvi batch, seed %ld: every body turned by a rotation vector of "
        "std %s of seed %ld.\n",
        seed, num, seed);
  }
  if (pt->temperature > 0) {
    const mrvi_model *m = sys->model;
    shortest(pt->temperature, num, sizeof num);
    SAY("# mrvi batch, seed %ld: thermal initial velocities of seed %ld at "
        "temperature %s\n# over %d degrees of freedom, %s (doc/batch.md, "
        "Ensembles).\n",
        seed, seed, num, dof,
        m->n_particles == 0 && m->n_bodies == 0
            ? "plain coordinates: no net momentum removed"
            : "zero net momentum");
  } else if (pt->velocity_std > 0) {
    shortest(pt->velocity_std, num, sizeof num);
    SAY("# mrvi batch, seed %ld: the initial velocities are the above plus "
        "%s\n# times the standard normal numbers of seed %ld (doc/batch.md, "
        "Ensembles),\n# projected onto the constraints.\n",
        seed, num, seed);
  }
#undef SAY
  if (note[0] == '\0' || (note[0] == '\n' && note[1] == '\0'))
    return 0;
  char *grown = realloc(sys->description, n + at + 1);
  if (!grown)
    return MRVI_ENOMEM;
  memcpy(grown + n, note, at + 1);
  sys->description = grown;
  return 0;
}
