/* mrvi — variational multirate integrators for mechanical systems.
 *
 * Public C API.  Equation labels (eq:..., th:...) refer to the source paper
 * "Variational multirate integrators" (Ober-Blöbaum, Wenger, Gail, Leyendecker,
 * arXiv 2406.12991); doc/theory.md maps each label to its equation number.
 *
 * Conventions
 * - Every function that can fail returns an int status: 0 (MRVI_OK) or a
 *   negative MRVI_E* code.  The library never prints and never exits; the
 *   message of the last failure is kept on the object (mrvi_model_errmsg,
 *   mrvi_integrator_errmsg) or written into a caller buffer (loader, writer).
 * - Vectors of generalised coordinates are in model order: the order in which
 *   coordinates and particles were added (a particle adds `dimension`
 *   consecutive coordinates x, y, z).
 * - _create/_free pairs; every _free accepts NULL.
 */
#ifndef MRVI_H
#define MRVI_H

#include <stddef.h>

#ifdef __cplusplus
extern "C" {
#endif

#define MRVI_VERSION "0.1.0"

/* ---------------------------------------------------------------------------
 * Status codes: one list pairs every code with its message.
 * ------------------------------------------------------------------------- */
#define MRVI_STATUS_LIST(X)                                                    \
  X(MRVI_OK, 0, "success")                                                     \
  X(MRVI_ENOMEM, -1, "out of memory")                                          \
  X(MRVI_EINVAL, -2, "invalid argument")                                       \
  X(MRVI_EMODEL, -3, "invalid model")                                          \
  X(MRVI_EPARSE, -4, "invalid description file")                               \
  X(MRVI_ENEWTON, -5, "Newton iteration did not converge")                     \
  X(MRVI_ESINGULAR, -6, "singular Newton matrix")                              \
  X(MRVI_EIO, -7, "input/output error")                                        \
  X(MRVI_EINTERRUPTED, -8, "run interrupted")                                  \
  X(MRVI_ENONFINITE, -9, "non-finite value")                                   \
  X(MRVI_EOPTIMIZE, -10, "optimisation failed")

enum mrvi_status {
#define MRVI_STATUS_ENUM(name, code, msg) name = code,
  MRVI_STATUS_LIST(MRVI_STATUS_ENUM)
#undef MRVI_STATUS_ENUM
};

/* Message of a status code ("unknown status" for codes not in the list). */
const char *mrvi_strerror(int status);

/* Library version string (MRVI_VERSION of the build). */
const char *mrvi_version(void);
/* 1 if this build runs element loops on threads (OpenMP), else 0. */
int mrvi_threads_supported(void);

/* ---------------------------------------------------------------------------
 * Potential laws: scalar functions phi(s) of a strain-like scalar s.
 *
 * An element maps the coordinates to s (spring: s = |x_i - x_j| - L0,
 * anchor spring: s = |x_i - a| - L0, term: s = a^T q - b) and its energy is
 * phi(s).  A law is one const table; register user laws with
 * mrvi_law_register before building models that name them.
 * ------------------------------------------------------------------------- */
#define MRVI_LAW_MAX_PARAMS 8

/* Closed forms of phi a law may declare (mrvi_law.form): the solvers
 * evaluate them inline, from the parameters, instead of calling eval. */
typedef enum mrvi_law_form {
  MRVI_LAW_FORM_NONE = 0,  /* phi by eval alone */
  MRVI_LAW_FORM_HOOKE = 1, /* phi(s) = k s^2 / 2, k = params[0] */
  MRVI_LAW_FORM_POWER = 2, /* phi(s) = c s^e, c = params[0], e = params[1] */
  MRVI_LAW_FORM_MORSE = 3  /* phi(s) = D (1 - exp(-a s))^2, D = params[0],
                              a = params[1] */
} mrvi_law_form;

typedef struct mrvi_law {
  const char *name;    /* e.g. "power", "linear" */
  const char *summary; /* one line for `mrvi check` and docs */
  int n_params;        /* <= MRVI_LAW_MAX_PARAMS */
  const char *const
      *param_names; /* n_params names, e.g. {"coefficient", "exponent"} */
  /* Validate parameter values; on failure write a message and return < 0. */
  int (*check)(const double *params, char *msg, size_t msg_len);
  /* phi(s), phi'(s), phi''(s). */
  void (*eval)(const double *params, double s, double *phi, double *dphi,
               double *ddphi);
  /* Properties (optional: NULL / 0 declare none), read when a model is
   * set up.  The degree of phi as a polynomial in s for these parameters,
   * or -1 where it is none: a degree <= 2 is a constant Hessian (the
   * element is quadratic in the coordinates, solved once per run). */
  int (*degree)(const double *params);
  mrvi_law_form form; /* consistent with eval and degree */
} mrvi_law;

/* Add a law to the registry (the pointer must stay valid).  Fails with
 * MRVI_EINVAL if the name is taken or the table is incomplete. */
int mrvi_law_register(const mrvi_law *law);
/* Law by name, or NULL. */
const mrvi_law *mrvi_law_find(const char *name);
/* Iterate over the registry: i = 0 .. mrvi_law_count()-1. */
int mrvi_law_count(void);
const mrvi_law *mrvi_law_get(int i);

/* ---------------------------------------------------------------------------
 * Model: what a description file defines.
 * ------------------------------------------------------------------------- */
typedef enum mrvi_rate { MRVI_SLOW = 0, MRVI_FAST = 1 } mrvi_rate;

typedef struct mrvi_model mrvi_model;

mrvi_model *mrvi_model_create(void);
void mrvi_model_free(mrvi_model *m);
/* Message of the last failed call on m ("" if none). */
const char *mrvi_model_errmsg(const mrvi_model *m);

/* Spatial dimension of particles (1, 2 or 3); set before adding particles. */
int mrvi_model_set_dimension(mrvi_model *m, int dimension);

/* Add a generalised coordinate; returns its index (>= 0) or a status < 0.
 * mass > 0, finite q0, v0; unique name. */
int mrvi_model_add_coordinate(mrvi_model *m, const char *name, double mass,
                              mrvi_rate rate, double q0, double v0);

/* Add a particle of `dimension` coordinates named NAME.x, NAME.y, NAME.z, all
 * of one rate and one mass; x0, v0 have `dimension` entries.  Returns the
 * particle index (>= 0) or a status < 0. */
int mrvi_model_add_particle(mrvi_model *m, const char *name, double mass,
                            mrvi_rate rate, const double *x0, const double *v0);

/* Spring between particles i and j with energy phi(|x_i - x_j| - rest_length).
 * `potential` is MRVI_SLOW (part of V) or MRVI_FAST (part of W); a fast
 * element touching a slow coordinate is rejected.  params has law->n_params
 * entries.  Returns the element index or a status < 0. */
int mrvi_model_add_spring(mrvi_model *m, mrvi_rate potential, int particle_i,
                          int particle_j, const char *law, const double *params,
                          double rest_length);

/* Spring between particle i and the fixed point `anchor` (dimension entries).
 */
int mrvi_model_add_anchor_spring(mrvi_model *m, mrvi_rate potential,
                                 int particle_i, const double *anchor,
                                 const char *law, const double *params,
                                 double rest_length);

/* An end of a spring: particle `particle` (>= 0), or (particle < 0) the
 * point of body `body` with body-frame components `at` (dimension entries,
 * relative to its centre of mass along its principal axes), at
 * x = phi + sum_i at[i] d_i, affine in the body's coordinates
 * (doc/multibody.md, "Body points"). */
typedef struct mrvi_end {
  int particle;
  int body;
  double at[3];
} mrvi_end;

/* Spring with energy phi(|x_a - x_b| - rest_length) between two ends, or
 * (b NULL) between end a and the fixed point `anchor`.  Two particles give
 * the element of mrvi_model_add_spring (mrvi_model_add_anchor_spring);
 * with a body point the element's inputs are the coordinates of its ends
 * with the constant coefficients of x (1 for a particle or phi, at[i] for
 * d_i).  The rate rule is the particles': a fast spring may touch fast
 * coordinates only.  rest_length NAN: the initial distance. */
int mrvi_model_add_end_spring(mrvi_model *m, mrvi_rate potential,
                              const mrvi_end *a, const mrvi_end *b,
                              const double *anchor, const char *law,
                              const double *params, double rest_length);

/* Position x (dimension entries) of end e at the coordinates q (model
 * order); MRVI_EINVAL for an invalid end. */
int mrvi_model_end_position(const mrvi_model *m, const mrvi_end *e,
                            const double *q, double *x);

/* Term phi(sum_j coef[j] q[coords[j]] - offset) on n_terms coordinates. */
int mrvi_model_add_term(mrvi_model *m, mrvi_rate potential, int n_terms,
                        const int *coords, const double *coef, double offset,
                        const char *law, const double *params);

/* Uniform gravity: slow potential -sum_i m_i g^T x_i over all particles
 * (dimension entries).  Call after adding the particles.  Returns the
 * element's index (>= 0), like the mrvi_model_add_* functions, or a
 * negative status. */
int mrvi_model_set_gravity(mrvi_model *m, const double *g);

/* Bending term on the angle theta at particle j between particles i and k
 * (dimension 2 or 3): k [1 - cos(theta - theta0)], which is
 * (k/2)(theta - theta0)^2 + O((theta - theta0)^4) and smooth everywhere
 * for theta0 = 0 or pi (straight chains); for other theta0 its gradient is
 * singular where i, j, k are collinear (as every angle potential's).
 * rest_angle theta0 in radians in [0, pi], or NAN for the initial angle.
 * Returns the element index or a status < 0. */
int mrvi_model_add_angle(mrvi_model *m, mrvi_rate potential, int particle_i,
                         int particle_j, int particle_k, double stiffness,
                         double rest_angle);

/* Constant external force: potential -sum_j f[j] q[coords[j]] on n_terms
 * coordinates (linear, like gravity; slow or fast by `potential`). */
int mrvi_model_add_force(mrvi_model *m, mrvi_rate potential, int n_terms,
                         const int *coords, const double *f);

/* Distance of particle i from particle j (j >= 0) or from the point anchor
 * (j < 0; dimension entries) at the initial positions (rest_length
 * "initial" of springs).  NAN for an invalid index. */
double mrvi_model_initial_distance(const mrvi_model *m, int particle_i,
                                   int particle_j, const double *anchor);

/* Generators (doc/description-files.md, `generate:`): particles on a chain
 * (along x), a ring (a regular polygon in the x-y plane), a planar or a
 * cubic lattice, joined by springs between nearest neighbours.  A spring is
 * fast only if both its ends are fast particles; it then takes the fast
 * law, otherwise the slow one. */
typedef enum mrvi_generator_kind {
  MRVI_GEN_CHAIN = 0,
  MRVI_GEN_RING = 1,
  MRVI_GEN_LATTICE2D = 2,
  MRVI_GEN_LATTICE3D = 3
} mrvi_generator_kind;

/* Which particles are slow; the others are fast. */
typedef enum mrvi_rate_rule {
  MRVI_RATES_ALL_SLOW = 0,
  MRVI_RATES_ALL_FAST = 1,
  MRVI_RATES_ALTERNATE = 2, /* slow where the index sum is even */
  MRVI_RATES_EVERY = 3      /* slow where the linear index % every == 0 */
} mrvi_rate_rule;

typedef struct mrvi_spring_spec {
  const char *law;                    /* NULL: no springs of this rate */
  double params[MRVI_LAW_MAX_PARAMS]; /* law->n_params entries */
  double rest_length;                 /* NAN: the spacing */
} mrvi_spring_spec;

typedef struct mrvi_generator {
  mrvi_generator_kind kind;
  const char *prefix; /* names prefix0.. (chain, ring), prefixI_J(_K) */
  int count[3];       /* chain/ring: count[0]; lattices: per axis */
  double spacing;     /* nearest-neighbour distance > 0 */
  double origin[3];   /* position of particle 0 (ring: its centre) */
  double mass;        /* > 0, every particle */
  mrvi_rate_rule rates;
  int every; /* for MRVI_RATES_EVERY, >= 1 */
  mrvi_spring_spec slow, fast;
  /* Optional (may be NULL): per particle (linear index, x fastest) and
   * dimension entries: displacement from the lattice site, velocity. */
  const double *displacement, *velocity;
} mrvi_generator;

/* Number of particles the generator makes, or a status < 0 with a message
 * in msg when its counts are invalid (chain >= 2, ring >= 3, lattices >= 1
 * per axis and >= 2 particles). */
long mrvi_generator_particles(const mrvi_generator *g, char *msg, size_t len);
/* Add the particles (after those already in m) and springs; counts (may be
 * NULL) receive particles, slow particles, slow springs, fast springs.
 * Returns the index of the first generated particle or a status < 0. */
int mrvi_model_generate(mrvi_model *m, const mrvi_generator *g, int counts[4]);

/* Name of the model (free text). */
int mrvi_model_set_name(mrvi_model *m, const char *name);

/* Sizes and read access. */
int mrvi_model_n(const mrvi_model *m); /* all coordinates */
int mrvi_model_n_slow(const mrvi_model *m);
int mrvi_model_n_fast(const mrvi_model *m);
int mrvi_model_dimension(const mrvi_model *m); /* 0 if no particles */
int mrvi_model_n_particles(const mrvi_model *m);
int mrvi_model_n_elements(const mrvi_model *m);
const char *mrvi_model_name(const mrvi_model *m);
/* Room for a name made on demand (mrvi_model_coordinate_name). */
#define MRVI_NAME_MAX 256
/* Name of coordinate i (NULL for an invalid i): a coordinate of its own
 * points into m; a particle's (its name, '.', the axis letter: NAME.x) is
 * made in buf (MRVI_NAME_MAX bytes) when asked, not stored, so the pointer
 * lasts as long as buf does. */
const char *mrvi_model_coordinate_name(const mrvi_model *m, int i, char *buf);
double mrvi_model_mass(const mrvi_model *m, int i);
mrvi_rate mrvi_model_rate(const mrvi_model *m, int i);
/* Initial data in model order (n entries). */
const double *mrvi_model_q0(const mrvi_model *m);
const double *mrvi_model_v0(const mrvi_model *m);
/* Indices of the slow (n_slow) and fast (n_fast) coordinates in model order. */
const int *mrvi_model_slow_index(const mrvi_model *m);
const int *mrvi_model_fast_index(const mrvi_model *m);
/* One-line description of element e, e.g. "slow spring m1-m2, power(...)". */
int mrvi_model_describe_element(const mrvi_model *m, int e, char *buf,
                                size_t len);

/* Energy parts at (q, p): kinetic 1/2 p^T M^-1 p, slow V(q), fast W(q). */
void mrvi_model_energy(const mrvi_model *m, const double *q, const double *p,
                       double *kinetic, double *slow, double *fast);
/* Potential energy of one class (MRVI_SLOW: V, MRVI_FAST: W) with gradient
 * (n entries, may be NULL) and dense Hessian (n x n row-major, may be NULL),
 * both accumulated (+=) into the given arrays.  Returns the energy. */
double mrvi_model_potential(const mrvi_model *m, mrvi_rate potential,
                            const double *q, double *grad, double *hess);
/* Momentum maps of the particles: linear (dimension entries) and angular
 * momentum sum_i x_i x p_i (3 entries in 3-D, 1 in 2-D, 0 in 1-D). */
void mrvi_model_momentum(const mrvi_model *m, const double *q, const double *p,
                         double *linear, double *angular);
/* Which components of those momentum maps the model's symmetries conserve
 * (1) or not (0): linear (dimension entries) is conserved along e_a when
 * every potential element and constraint is invariant under translations
 * along e_a; angular (3 entries in 3-D, 1 in 2-D) about e_a when they are
 * invariant under rotations about the axis e_a through the origin.  Pair
 * springs, angles and rods between particles keep both; anchors, gravity,
 * forces, terms, fixed, plane and linear constraints keep what their
 * direction allows (src/model/symmetry.c); user constraint types keep nothing
 * they touch.  Either pointer may be NULL. */
int mrvi_model_conserved(const mrvi_model *m, int *linear, int *angular);
/* Lines of a picture of the model: springs between two particles (kind 0
 * slow, 1 fast potential), then distance constraints between two particles
 * (kind 2, rods), in model order.  Anchored springs and rods and pair laws
 * (lennard-jones, inverse) are not lines.  Writes at most cap edges into
 * pairs (2 x cap particle indices) and kind (cap), either may be NULL, and
 * returns the number of edges (call with cap = 0 to count). */
int mrvi_model_edges(const mrvi_model *m, int *pairs, int *kind, int cap);
/* The fixed points of a picture of the model: anchored springs (kind 0
 * slow, 1 fast potential), then distance constraints between a particle
 * and a fixed point (kind 2, rods), in model order.  Writes at most cap
 * anchors into particle (cap particle indices), point (cap x dimension
 * coordinates) and kind (cap), any may be NULL, and returns the number of
 * anchors (call with cap = 0 to count). */
int mrvi_model_anchors(const mrvi_model *m, int *particle, double *point,
                       int *kind, int cap);

/* ---------------------------------------------------------------------------
 * Holonomic constraints g(q) = 0 (doc/constraints.md).
 *
 * A constraint type is one const table in constraints/ (distance, fixed,
 * plane, linear); an instance applies it to n_in model coordinates with
 * type-specific parameters and has `rows` scalar equations.  Register user
 * types with mrvi_constraint_type_register.  Where an instance is enforced
 * follows from its inputs: on slow coordinates only at macro nodes, involving
 * a fast coordinate at every micro node (slow part interpolated).
 * ------------------------------------------------------------------------- */

/* How the description file reads one key of a constraint entry
 * (doc/constraints.md).  Names give the inputs, in the order of the keys;
 * numbers give the parameters, in the order of the keys' `param` ranks. */
typedef enum mrvi_key_kind {
  /* Inputs. */
  MRVI_KEY_PARTICLE = 1, /* a particle name: its d coordinates */
  /* [a, b], or [a] with the entry's MRVI_KEY_ANCHOR vector as the other
   * end: the particles' coordinates. */
  MRVI_KEY_ENDS,
  /* A subset of x, y, z: only those coordinates of the entry's particle, and
   * those entries of its vectors, count (default: every axis). */
  MRVI_KEY_AXES,
  MRVI_KEY_COORDINATES, /* a list of coordinate names */
  /* {coordinate: coefficient}: the coordinates are inputs, the coefficients
   * parameters. */
  MRVI_KEY_COMBINATION,
  /* Parameters. */
  MRVI_KEY_SCALAR, /* a number; absent: NAN (see `initial`) */
  MRVI_KEY_VECTOR, /* d numbers (a point or a direction); absent: NAN */
  MRVI_KEY_NUMBERS /* a list of numbers; absent: none */
} mrvi_key_kind;

/* Flags of a key. */
#define MRVI_KEY_REQUIRED 1 /* the key must be given */
#define MRVI_KEY_POSITIVE 2 /* SCALAR: > 0 */
/* VECTOR: the fixed end of an ENDS key naming one particle (given then). */
#define MRVI_KEY_ANCHOR 4
/* The key the model's errors on the entry point at (default: the entry). */
#define MRVI_KEY_REPORT 8

typedef struct mrvi_constraint_key {
  const char *name; /* the key, e.g. "between" */
  mrvi_key_kind kind;
  int flags; /* MRVI_KEY_* above */
  int param; /* rank of its numbers among the parameters (1 first); 0 none */
} mrvi_constraint_key;

typedef struct mrvi_constraint_type {
  const char *name;    /* e.g. "distance" */
  const char *summary; /* one line for `mrvi check` and docs */
  /* Validate sizes and parameters of an instance; return its number of rows
   * (1 <= rows <= n_in) or a status < 0 with a message. */
  int (*check)(int n_in, int n_params, const double *params, char *msg,
               size_t msg_len);
  /* At inputs y (n_in): g (rows), G = dg/dy (rows x n_in, row-major) and,
   * if H is not NULL, the second derivatives (rows x n_in x n_in). */
  void (*eval)(int n_in, int n_params, const double *params, const double *y,
               double *g, double *G, double *H);
  /* Optional, before check: replace the parameters left NAN (not given) by
   * values from the initial inputs y0 (n_in), e.g. a rod's length by the
   * initial distance; 0, or a status < 0 with a message (the model puts the
   * constraint's label before it). */
  int (*initial)(int n_in, int n_params, double *params, const double *y0,
                 char *msg, size_t msg_len);
  /* Keys of an entry in a description file, ended by {NULL}; NULL: the
   * generic {coordinates: [names], parameters: [numbers]}. */
  const mrvi_constraint_key *keys;
  /* Optional, after check: 1 if the instance's g is affine in its inputs
   * (every second derivative identically zero, whatever the inputs), else
   * 0; NULL: never.  Asked once per instance (mrvi_constraint.affine); the
   * step then leaves out the constraint's Hessian (doc/constraints.md).
   * E.g. fixed, plane, linear; a 2-D revolute joint (its rows are the
   * components of x_A - x_B), any joint to the ground; not a 3-D revolute
   * between two bodies (a_1 . b_2 is a product of the two bodies'
   * directors), nor distance or body. */
  int (*affine)(int n_in, int n_params, const double *params);
  /* Joints between rigid bodies only: the relative motion the joint leaves
   * free, MRVI_JOINT_BALL (every rotation about its point), _HINGE (the
   * rotation about the frame's first axis a_1 fixed in A; in 2-D the one
   * rotation), _WELD (none), _PRISMATIC (the translation along b_1 fixed in
   * B), _CYLINDRICAL (the hinge's rotation and the prismatic's
   * translation), _UNIVERSAL (the rotations about a_1 fixed in A and b_2
   * fixed in B) or _PLANAR (the rotation about a_1 and the translations
   * normal to b_1), which the null-space form's joint-reduced basis of open
   * chains and trees builds on (doc/multibody.md); 0 for every other type
   * (the null-space form then takes its numerical basis). */
  int joint_motion;
} mrvi_constraint_type;
enum {
  MRVI_JOINT_BALL = 1,
  MRVI_JOINT_HINGE = 2,
  MRVI_JOINT_WELD = 3,
  MRVI_JOINT_PRISMATIC = 4,
  MRVI_JOINT_CYLINDRICAL = 5,
  MRVI_JOINT_UNIVERSAL = 6,
  MRVI_JOINT_PLANAR = 7
};

/* Add a type to the registry (the pointer must stay valid).  MRVI_EINVAL if
 * the name is taken or the table is incomplete. */
int mrvi_constraint_type_register(const mrvi_constraint_type *type);
/* Type by name, or NULL; iterate with count/get. */
const mrvi_constraint_type *mrvi_constraint_type_find(const char *name);
int mrvi_constraint_type_count(void);
const mrvi_constraint_type *mrvi_constraint_type_get(int i);

/* Generic instance: type by name on n_in model coordinates with n_params
 * parameters (NAN ones completed by the type's `initial`, if it has one);
 * label names it in messages (NULL: "<type> on <first coordinate>, ...").
 * Returns the constraint index (>= 0) or a status < 0. */
int mrvi_model_add_constraint(mrvi_model *m, const char *type, int n_in,
                              const int *coords, int n_params,
                              const double *params, const char *label);
/* Rigid rod |x_i - x_j| = length between two particles; NAN length: the
 * initial distance.  g = (|d|^2 - length^2) / (2 length), d = x_i - x_j. */
int mrvi_model_add_distance(mrvi_model *m, int particle_i, int particle_j,
                            double length);
/* Rod between particle i and the fixed point `anchor` (dimension entries). */
int mrvi_model_add_distance_anchor(mrvi_model *m, int particle_i,
                                   const double *anchor, double length);
/* Pin the axes of particle i with axes[a] != 0 (dimension entries; NULL: all)
 * at `position` (dimension entries; NULL: the initial position). */
int mrvi_model_add_fixed(mrvi_model *m, int particle_i, const int *axes,
                         const double *position);
/* Particle i on the plane n.x = offset (n normalised; NAN offset: through
 * the initial position). */
int mrvi_model_add_plane(mrvi_model *m, int particle_i, const double *normal,
                         double offset);
/* The same three on ends (mrvi_end: a particle or a body point; doc/
 * multibody.md, "Constraints on body points"): the particles' types for
 * particles, else the type "point" on x = phi + sum_i at[i] d_i.
 * distance: between a and b, or (b NULL) a and `anchor`; NAN length: the
 * initial distance.  fixed: axes and position as mrvi_model_add_fixed
 * (NULL position: the initial one).  plane: as mrvi_model_add_plane. */
int mrvi_model_add_end_distance(mrvi_model *m, const mrvi_end *a,
                                const mrvi_end *b, const double *anchor,
                                double length);
int mrvi_model_add_end_fixed(mrvi_model *m, const mrvi_end *a, const int *axes,
                             const double *position);
int mrvi_model_add_end_plane(mrvi_model *m, const mrvi_end *a,
                             const double *normal, double offset);
/* sum_j coef[j] q[coords[j]] = rhs (NAN rhs: the initial value). */
int mrvi_model_add_linear_constraint(mrvi_model *m, int n_terms,
                                     const int *coords, const double *coef,
                                     double rhs);

/* Rename constraint c (the builders label it "distance a-b" and so on). */
int mrvi_model_set_constraint_label(mrvi_model *m, int c, const char *label);

int mrvi_model_n_constraints(const mrvi_model *m);
/* Total number of scalar constraint equations (rows of g). */
int mrvi_model_constraint_rows(const mrvi_model *m);
const char *mrvi_model_constraint_label(const mrvi_model *m, int c);
const char *mrvi_model_constraint_type_name(const mrvi_model *m, int c);
int mrvi_model_constraint_n_rows(const mrvi_model *m, int c);
/* MRVI_SLOW: enforced at macro nodes; MRVI_FAST: at every micro node. */
mrvi_rate mrvi_model_constraint_where(const mrvi_model *m, int c);
/* 1 if constraint c is affine in its coordinates (its type's `affine`). */
int mrvi_model_constraint_affine(const mrvi_model *m, int c);
/* One-line description, e.g. "distance cart-bob, length 0.5 (micro nodes)". */
int mrvi_model_describe_constraint(const mrvi_model *m, int c, char *buf,
                                   size_t len);
/* g(q) of every constraint in order (constraint_rows entries) and, if G is
 * not NULL, the dense gradient (constraint_rows x n, row-major). */
void mrvi_model_constraint_eval(const mrvi_model *m, const double *q, double *g,
                                double *G);
/* max_i |(G M^-1 p)_i|: the hidden (velocity) constraint at (q, p). */
double mrvi_model_hidden_residual(const mrvi_model *m, const double *q,
                                  const double *p);
/* Initial positions: MRVI_EMODEL with a message naming the constraint with
 * the largest |g(q0)| if that exceeds tol; *worst gets its index (or -1). */
int mrvi_model_check_initial_positions(mrvi_model *m, double tol, int *worst);
/* Gradients independent at q (model order): MRVI_ESINGULAR with a message
 * naming the constraints whose gradients are linearly dependent. */
int mrvi_model_check_independent(mrvi_model *m, const double *q);
/* Largest change of a coordinate, relative to max(1, max |q0_i|), that
 * the projection of initial positions may make (doc/constraints.md). */
#define MRVI_PROJECT_POSITIONS_MAX 1e-3
/* Project the initial positions onto the constraints if some |g(q0)|
 * exceeds tol (the positions of a closed loop cannot be typed exactly):
 * Newton on g with the minimum-norm correction in the metric M, redundant
 * rows skipped.  *correction gets max_i |dq_i|.  MRVI_EMODEL, q0 unchanged
 * and a message naming the violated constraints if Newton fails or the
 * change exceeds MRVI_PROJECT_POSITIONS_MAX max(1, max |q0_i|); *worst (may
 * be NULL) the constraint with the largest |g(q0)|. */
int mrvi_model_project_positions(mrvi_model *m, double tol, double *correction,
                                 int *worst);
/* Project the initial velocities onto the tangent space G(q0) v = 0
 * (M-orthogonally, so that p0 = M v0 meets G M^-1 p = 0; redundant rows
 * skipped); *correction gets max_i |dv_i|. */
int mrvi_model_project_velocities(mrvi_model *m, double *correction);

/* ---------------------------------------------------------------------------
 * Rigid bodies and joints (doc/multibody.md).
 *
 * A rigid body of dimension D (2 or 3) is its centre of mass phi and its
 * directors d_1..d_D, the columns of its rotation matrix (Betsch &
 * Leyendecker 2006, Part II; Leyendecker, Marsden & Ortiz 2008): D (D + 1)
 * coordinates in model order NAME.x NAME.y [NAME.z] NAME.d1x NAME.d1y
 * [NAME.d1z] NAME.d2x ... with the constant masses M (phi) and
 * E_i = (J_j + J_k - J_i)/2 (d_i; 2-D: E_1 = E_2 = J/2), so that the
 * kinetic energy 1/2 M |phi'|^2 + 1/2 sum_i E_i |d_i'|^2 is that of the
 * body, and the D (D + 1)/2 internal constraints (d_i.d_i - 1)/2 = 0,
 * d_i.d_j = 0 (constraint type "body", labelled "body NAME"), enforced at
 * the nodes of the body's rate.  A body point with body-frame components
 * rho is x = phi + sum_i rho^i d_i.  Gravity (mrvi_model_set_gravity)
 * acts on bodies as -M g.phi.
 * ------------------------------------------------------------------------- */

/* Add a rigid body of `dimension` (2 or 3; the model's dimension, which the
 * first particle or body sets) and one rate as a whole.
 *   mass     M > 0
 *   inertia  principal moments about the centre of mass along d_1..d_D:
 *            3-D J_1, J_2, J_3 > 0 with the strict triangle inequality
 *            J_i < J_j + J_k (every E_i > 0); 2-D J > 0 (1 entry)
 *   x0       initial centre of mass (D entries)
 *   R0       initial rotation (D x D, row-major; column i is d_i in space)
 *            with det +1 and R0^T R0 = I within 1e-6 (then orthonormalised
 *            to round-off); NULL: identity
 *   v0       initial velocity of the centre of mass (D entries; NULL: 0)
 *   omega0   initial angular velocity in space (3 entries in 3-D, 1 in
 *            2-D; NULL: 0); d_i' = omega x d_i
 * Returns the body index (>= 0) or a status < 0 with the reason. */
int mrvi_model_add_body(mrvi_model *m, const char *name, int dimension,
                        mrvi_rate rate, double mass, const double *inertia,
                        const double *x0, const double *R0, const double *v0,
                        const double *omega0);
int mrvi_model_n_bodies(const mrvi_model *m);
/* Body index by name, or -1. */
int mrvi_model_find_body(const mrvi_model *m, const char *name);
const char *mrvi_model_body_name(const mrvi_model *m, int b);
/* Model index of the body's first coordinate (NAME.x); its D (D + 1)
 * coordinates follow in the order above.  -1 for an invalid index. */
int mrvi_model_body_first(const mrvi_model *m, int b);
/* Position (D entries) and rotation R = [d_1 .. d_D] (D x D row-major) of
 * body b at the coordinates q (model order). */
void mrvi_model_body_pose(const mrvi_model *m, int b, const double *q,
                          double *position, double *R);

/* Joint of constraint type `type` (doc/multibody.md, "Joints") between
 * body_a and body_b, or body_a and the ground (body_b < 0):
 *   spherical    3-D, 3 rows; no axis
 *   revolute     2-D 2 rows (no axis), 3-D 5 rows (axis: the hinge)
 *   weld         2-D 3 rows, 3-D 6 rows; no axis
 *   prismatic    2-D 2 rows, 3-D 5 rows; axis: the sliding direction
 *   cylindrical  3-D, 4 rows; axis: of rotation and sliding
 *   planar       3-D, 3 rows; axis: the plane's normal
 *   universal    3-D, 4 rows; axis: fixed in A, second axis: fixed in B
 *                (the Hooke joint's cross; the two keep the angle they
 *                make at the initial configuration, perpendicular or
 *                oblique, not parallel)
 * point: the joint's point in space at the initial configuration (D
 * entries), stored in each body's frame so that the initial positions meet
 * the joint; axis: in space at the initial configuration (D entries, not
 * zero), NULL for the types that take none.  Refused with a message:
 * unknown body, a body joined to itself, an unknown type or one not of the
 * bodies' dimension, an axis missing, zero or not taken.  Returns the
 * constraint index (>= 0) or a status < 0. */
int mrvi_model_add_joint(mrvi_model *m, const char *type, int body_a,
                         int body_b, const double *point, const double *axis);
/* Torsional spring (doc/multibody.md, "Torsional springs"): energy
 * phi(theta - rest_angle) with law `law` (params: law->n_params entries) of
 * the angle theta by which body_b turns relative to body_a (body_b < 0:
 * body_a relative to the ground) about `axis` (3-D: in space at the initial
 * configuration, as a revolute joint's; 2-D: NULL, the plane's normal).
 * theta is 0 at the initial configuration and counted continuously through
 * +-pi over any number of turns: the integrator follows its branch from
 * node to node (a step may turn it by less than pi/2).  The rate rule is
 * the springs': a fast torsional spring may join fast bodies (or a fast
 * body and the ground) only.  Returns the element index or a status < 0. */
int mrvi_model_add_torsion(mrvi_model *m, mrvi_rate potential, int body_a,
                           int body_b, const double *axis, const char *law,
                           const double *params, double rest_angle);
/* The same with a second axis (D entries, in space at the initial
 * configuration; NULL for the types that take none): the universal
 * joint's axis fixed in body B (or the ground), at a constant angle to
 * `axis`, perpendicular or oblique (parallel axes are refused with a
 * message). */
int mrvi_model_add_joint_axes(mrvi_model *m, const char *type, int body_a,
                              int body_b, const double *point,
                              const double *axis, const double *second);
/* Names of the joint types above, NULL-terminated. */
const char *const *mrvi_joint_type_names(void);

/* Angular velocity in space of body b (3 entries in 3-D, 1 in 2-D) from
 * the coordinates q and the discrete momenta p (model order):
 * omega = (R J R^T)^-1 sum_i d_i x p_{d_i}, J = diag(J_1..J_D) the principal
 * inertia (2-D: omega = (d_1 x p_{d_1} + d_2 x p_{d_2}) / J); the internal
 * constraint forces drop out of the sum (doc/multibody.md, "Angular
 * velocity"). */
void mrvi_model_body_angular_velocity(const mrvi_model *m, int b,
                                      const double *q, const double *p,
                                      double *omega);
/* Joints of the model: the constraints of a joint type above, in the order
 * they were added; joint j is constraint mrvi_model_joint_constraint(m, j)
 * (-1 for an invalid j). */
int mrvi_model_n_joints(const mrvi_model *m);
int mrvi_model_joint_constraint(const mrvi_model *m, int j);
/* Bodies of joint j: *body_a, *body_b (-1: the ground); either may be
 * NULL.  MRVI_EINVAL for an invalid j. */
int mrvi_model_joint_bodies(const mrvi_model *m, int j, int *body_a,
                            int *body_b);
/* Point of joint j on its first body in space at the coordinates q
 * (D entries): x_A = phi_A + sum_i rho_A^i d_i.  MRVI_EINVAL for an
 * invalid j. */
int mrvi_model_joint_point(const mrvi_model *m, int j, const double *q,
                           double *x);
/* Reaction of joint j on its first body at the coordinates q (model order)
 * from the multipliers lambda (all constraint rows of the model, the
 * columns of /macro/lambda): the constraint force -G^T lambda on that
 * body's coordinates, as the force on its centre of mass (D entries) and
 * the torque about the joint's point on it (3 entries in 3-D, 1 in 2-D;
 * doc/multibody.md, "Joint reactions").  MRVI_EINVAL for an invalid j. */
int mrvi_model_joint_reaction(const mrvi_model *m, int j, const double *q,
                              const double *lambda, double *force,
                              double *torque);

/* ---------------------------------------------------------------------------
 * Integrator settings (arXiv 2406.12991 §3.3): rule (alpha, gamma) of
 * eq:Zapprox for the slow potential V and the fast potential W, the grid V is
 * evaluated on.
 * ------------------------------------------------------------------------- */
typedef enum mrvi_grid { MRVI_GRID_MICRO = 0, MRVI_GRID_MACRO = 1 } mrvi_grid;

typedef struct mrvi_rule {
  double alpha; /* weight of the first point, [0, 1] */
  double gamma; /* 1/2 midpoint, 0 or 1 trapezoidal family, [0, 1] */
} mrvi_rule;

/* How constraints enter the Newton system: multipliers (x, lambda) solved
 * together, or the discrete null-space form (lambda eliminated). */
typedef enum mrvi_constraint_form {
  MRVI_FORM_MULTIPLIERS = 0,
  MRVI_FORM_NULL_SPACE = 1
} mrvi_constraint_form;

/* Step solver (doc/solver.md): auto takes the structured path where the
 * scheme and model allow it, else the general one; structured insists on
 * it (integrator creation fails with the reason otherwise); general is the
 * full Newton iteration with sparse LU on the whole step, the reference. */
typedef enum mrvi_solver {
  MRVI_SOLVER_AUTO = 0,
  MRVI_SOLVER_STRUCTURED = 1,
  MRVI_SOLVER_GENERAL = 2
} mrvi_solver;

/* Newton stopping criterion (doc/description-files.md, integrator.newton):
 * absolute, ||R||_inf <= tol on the momentum rows as they stand; scaled,
 * ||M^-1 R||_inf <= tol, each row divided by the mass of its coordinate
 * (a velocity: the same relative accuracy whatever the mass scale). */
typedef enum mrvi_newton_criterion {
  MRVI_CRITERION_ABSOLUTE = 0,
  MRVI_CRITERION_SCALED = 1
} mrvi_newton_criterion;

/* Tuning constants of the step solvers (doc/solver.md, "Tuning"): the
 * thresholds, caps and tolerances their rules were measured with (the FPU
 * chain of arXiv 2406.12991 §6), listed once, one row each:
 *   X(type, name, default, lowest, highest, meaning)
 * kappa is the slow fixed-point update's contraction dT^2 |M_s^-1 hess_ss
 * V| / 3 at the initial state, m_min the smallest mass.  The defaults are
 * set by mrvi_settings_default; mrvi_settings_set_tuning sets one by name
 * (a description file: integrator.tuning: {name: value}), so that a
 * benchmark can vary them on systems other than the one they were tuned
 * on.  Integer rows take integral values alone. */
#define MRVI_TUNING_LIST(X)                                                    \
  X(double, pre_kappa, 0.1, 0.0, 1e300,                                        \
    "the predictor solves the slow row before Newton where kappa exceeds "     \
    "this")                                                                    \
  X(double, shoot_pre_kappa, 0.01, 0.0, 1e300,                                 \
    "... and before shooting where kappa exceeds this")                        \
  X(int, slow_newton_max, 8, 1, 1000,                                          \
    "Broyden iterations of one slow solve of the predictor")                   \
  X(int, slow_newton_n, 64, 0, 4096,                                           \
    "largest model (coordinates) on which the predictor makes slow Newton "    \
    "steps and shoots (dense Hessian sum)")                                    \
  X(int, slow_samples, 16, 1, 1000000,                                         \
    "points sampled for the slow row's force in the predictor")                \
  X(int, slow_hess_samples, 8, 1, 1000000,                                     \
    "samples whose Hessians make the slow solve's first Jacobian")             \
  X(double, shoot_kappa, 30.0, 0.0, 1e300,                                     \
    "schur steps shoot on the slow unknowns where kappa is at most this")      \
  X(double, shoot_hess_kappa, 1e-3, 0.0, 1e300,                                \
    "shooting's Jacobian takes the sampled Hessian where kappa exceeds "       \
    "this (else M/dT alone)")                                                  \
  X(double, shoot_full_kappa, 1.0, 0.0, 1e300,                                 \
    "... and the Hessians of every point where kappa exceeds this")            \
  X(double, shoot_last, 0.1, 0.0, 1e300,                                       \
    "shooting's last update goes without its sweep where the predicted "       \
    "slow residual is at most this times the target")                          \
  X(int, shoot_max, 4, 0, 1000,                                                \
    "slow updates of a shooting step before Newton takes over")                \
  X(double, chord_max, 4e-4, 0.0, 1e300,                                       \
    "the chord matrix (frozen Hessians) takes a schur step's first update "    \
    "where dT^2 norm(H_last - H_first) / m_min is at most this")               \
  X(double, const_chord_max, 3e-4, 0.0, 1e300,                                 \
    "the constant chord (factored once per run) takes it where dT^2 "          \
    "norm(hess Z(q0)) / m_min is at most this")                                \
  X(int, const_chord_dense, 16, 0, 4096,                                       \
    "the constant chord's inverse is kept for steps of at most this many "     \
    "unknowns")                                                                \
  X(double, reuse_rate, 0.1, 0.0, 1.0,                                         \
    "kept factors (schur, schur-bordered) serve the next update while an "     \
    "update contracts the residual by at most this (0: full Newton)")          \
  X(double, reuse_tighten, 0.01, 0.0, 1.0,                                     \
    "Newton and shooting stop at this times the Newton tolerance")             \
  X(double, floor_rate, 0.1, 0.0, 1.0,                                         \
    "... or, the tolerance met, where a full Newton update left more than "    \
    "this fraction of the residual (the rounding floor; 0: off)")              \
  X(double, chord_jacobi_max, 0.1, 0.0, 1.0,                                   \
    "sweep-cg: the micro steps take Jacobi updates (diagonal of micro step "   \
    "0's Newton matrix; micro step 0 itself where W is springs and anchors "   \
    "alone, else after its first Newton update) where their Gershgorin "       \
    "bound, and each update's residual ratio, is at most this (0: Newton)")    \
  X(int, chord_carry, 1, 0, 1,                                                 \
    "sweep-cg: each step's first rows extrapolate the implicit force from "    \
    "the last rows of the step before, as the later rows do from their "       \
    "own step's (p >= 5, W springs and anchors alone, the chord regime): "     \
    "fewer chord updates; the history is part of the state "                   \
    "(mrvi_integrator_chord_history, /resume/chord_history), so mrvi run "     \
    "--resume continues bit for bit, a run restarted from (q, p) alone "       \
    "(--from, set_state) within the Newton tolerance (0: off)")                \
  X(int, chord_linear, 0, 0, 8,                                                \
    "sweep-cg: a chord row's first plain update keeps each Hooke spring's "    \
    "Hessian and its next chord_linear updates take the residual "             \
    "linearised there (a Hessian-vector product, no square root or "           \
    "division, instead of a gradient); rows end on an exact residual "         \
    "alone (0: off; W Hooke springs alone)")                                   \
  X(int, outer_max, 12, 0, 1000,                                               \
    "schur-krylov: the most sweeps of its matrix-free outer iteration "        \
    "before Newton takes the step from the predictor (0: off)")                \
  X(double, outer_rate, 0.5, 0.0, 1.0,                                         \
    "schur-krylov: ... and the largest residual ratio of one of its row or "   \
    "slow updates")                                                            \
  X(int, dense_max, 64, 0, 1000000,                                            \
    "largest block (fast, and slow on schur) solved densely; beyond: "         \
    "sweep-cg and schur-krylov")                                               \
  X(int, bordered_max, 32, 0, 1000000,                                         \
    "largest slow block, fast block and number of multipliers of a "           \
    "constrained step solved by schur-bordered; beyond: general")              \
  X(int, newton_dense_max, 512, 0, 4096,                                       \
    "largest Newton matrix of the general path (whole step) factored by "      \
    "the dense LU that skips zeros; beyond: UMFPACK")                          \
  X(int, bordered_node_max, 192, 0, 1000000,                                   \
    "largest node block (fast unknowns and a micro node's multipliers, or "    \
    "slow unknowns and the slow multipliers) of a step with micro-node "       \
    "constraints solved by schur-bordered; beyond: general")                   \
  X(int, bordered_slow_max, 0, 0, 1000000,                                     \
    "largest slow block with its multipliers (a dense Schur complement) of "   \
    "a step with micro-node constraints whose fast node blocks, beyond "       \
    "bordered_node_max, schur-bordered factors sparse (0, the default: "       \
    "off, general)")                                                           \
  X(int, chain_block_max, 160, 0, 1000000,                                     \
    "largest block of schur-bordered's chain elimination, which takes "        \
    "constrained chains and trees beyond bordered_max and "                    \
    "bordered_node_max (0: off, general)")                                     \
  X(int, keep_by_cost, 1, 0, 1,                                                \
    "schur-bordered's chain elimination keeps its factors while the "          \
    "updates they need at their last contraction cost less than a "            \
    "factorisation (flop estimate; 0: the reuse_rate rule alone)")             \
  X(double, path_entry_cost, 5.0, 0.0, 1e300,                                  \
    "cost of an entry of the general path's dense LU storage per "             \
    "factorisation, in its flops, in the estimate that chooses general or "    \
    "schur-bordered (doc/solver.md)")                                          \
  X(double, path_index_cost, 0.7, 0.0, 1e300,                                  \
    "cost of a flop of the general path's LU that skips zeros, in flops of "   \
    "schur-bordered's dense blocks, in the same estimate")                     \
  X(double, path_updates, 2.5, 1.0, 1000.0,                                    \
    "Newton updates per macro step the same estimate assumes: general "        \
    "factorises for each, schur-bordered for the first and solves the "        \
    "others with its kept factors")                                            \
  X(double, path_factor_general, 300.0, 0.0, 1e300,                            \
    "fixed cost of one factorisation on the general path, in flops of the "    \
    "dense blocks, in the same estimate")                                      \
  X(double, path_factor_bordered, 1000.0, 0.0, 1e300,                          \
    "fixed cost of one factorisation on schur-bordered, in flops of its "      \
    "dense blocks, in the same estimate")                                      \
  X(double, krylov_cg_rtol, 1e-13, 0.0, 1.0,                                   \
    "relative tolerance of schur-krylov's block CG solves")                    \
  X(double, krylov_gmres_rtol, 1e-11, 0.0, 1.0,                                \
    "relative tolerance of schur-krylov's GMRES on the slow unknowns")         \
  X(int, krylov_restart, 20, 1, 10000, "GMRES restart length of schur-krylov") \
  X(int, krylov_max_it, 100, 1, 1000000, "GMRES iterations of schur-krylov")   \
  X(int, thread_chunk, 4096, 1, 100000000,                                     \
    "largest part of a threaded loop (settings.threads), in coordinates "      \
    "or records: a loop is cut into an even number of equal parts of at "      \
    "most this size (fully-explicit's and explicit-slow's chord parts: "       \
    "this size doubled until records spanning parts add at most 5 %); a "      \
    "loop of fewer than two such parts runs on one thread")                    \
  X(int, adjoint_dense_max, 64, 0, 1000000,                                    \
    "largest step (nodes and multipliers) whose optimal-control adjoint "      \
    "assembles the step Jacobian dense; beyond: sparse rows")                  \
  X(int, adjoint_refine_max, 8, 0, 1000,                                       \
    "refinement steps of an adjoint step solved with the factors of the "      \
    "step after it (or the forward pass's); beyond: factorised anew "          \
    "(0: every step)")                                                         \
  X(int, adjoint_refine_by_cost, 1, 0, 1,                                      \
    "that refinement also gives up where the steps still needed at its "       \
    "last contraction cost more than a factorisation, and is skipped where "   \
    "a factorisation and the solves cost less than its mean cost so far "      \
    "(flop estimates of the dense LU, UMFPACK, the chain elimination and "     \
    "the node blocks; the bordered slow block has none: 2 steps there; 0: "    \
    "the adjoint_refine_max and factor-4 rules alone)")                        \
  X(int, adjoint_krylov, 1, 0, 1,                                              \
    "where the forward pass takes schur-krylov, or an explicit path on "       \
    "steps beyond adjoint_dense_max with adjoint_explicit = 0, the "           \
    "adjoint's transposed step solves run schur-krylov's elimination "         \
    "backwards (GMRES, CG sweeps; 0: the sparse LU with kept factors)")        \
  X(double, adjoint_krylov_rtol, 1e-10, 0.0, 1.0,                              \
    "relative tolerance of those solves' block CG and GMRES, and of the "      \
    "CG of adjoint_explicit's micro steps")                                    \
  X(int, adjoint_explicit, 1, 0, 1,                                            \
    "on the explicit, sweep and sweep-cg paths (fully-explicit, "              \
    "explicit-slow), the adjoint runs the steps' recursion backwards with "    \
    "Hessian-vector products of W and V (and a CG per micro step where W's "   \
    "points lie inside the micro intervals; 0: the step Hessian assembled "    \
    "and the transposed step solved)")                                         \
  X(int, adjoint_hessblocks, 1, 0, 1,                                          \
    "adjoint_explicit's Hessians of W formed in one loop (a block per "        \
    "spring) and kept for their products: each micro node's, and that "        \
    "CG's at a point inside a micro interval, once per interval (0: formed "   \
    "anew within each product)")                                               \
  X(int, adjoint_one_point, 1, 0, 1,                                           \
    "that CG, where a micro interval has one point inside (the midpoint), "    \
    "solves for cA mu_{g-1} + cB mu_g and takes the interval's other "         \
    "products from the CG's residual (0: two products more per interval)")     \
  X(int, adjoint_forest, 1, 0, 1,                                              \
    "that CG's micro-step matrix, where W's elements are springs and "         \
    "anchors whose springs join the fast particles in a forest (chains, "      \
    "trees), solved instead by block elimination along the forest, leaves "    \
    "first (0: the CG)")                                                       \
  X(int, nullspace_tree, 1, 0, 1,                                              \
    "the null-space form of bodies in open chains and trees of spherical, "    \
    "revolute and weld joints takes the joint-reduced basis, of slow "         \
    "particles in open chains and trees of slow rods the link-local basis "    \
    "(0: the numerical QR basis)")                                             \
  X(int, nullspace_gram_min, 0, 0, 4096,                                       \
    "fast bodies in open chains and trees of joints with at least this many "  \
    "constrained fast coordinates take the Gram matrix G_f G_f^T for their "   \
    "multipliers and slow coupling at the micro nodes, fewer the QR of G_f "   \
    "(closed fast loops and more than 256 coordinates: the Gram matrix)")      \
  X(int, predict_settle, 1, 0, 1,                                              \
    "steps with more than 32 rows of slow constraints start Newton from the "  \
    "predictor moved onto the constraints, nearest in the mass metric (0: "    \
    "from the predictor)")                                                     \
  X(int, predict_joints, 1, 0, 1,                                              \
    "schur-bordered steps with micro-node constraints: the predictor's "       \
    "sweep moves each fast node onto them and sets their multipliers (the "    \
    "joint sweep; 0: the explicit sweep, multipliers from zero)")              \
  X(int, joints_omega, 1, 0, 1,                                                \
    "with the joint sweep, its bound dt omega_max <= 1/2 (else free flight) "  \
    "takes omega_max of the fast part on the micro-node constraints at the "   \
    "initial state, with dt omega_max <= 1 on the unconstrained hess(V + W) "  \
    "(0: dt omega_max <= 1/2 on the unconstrained one)")

typedef struct mrvi_tuning {
#define MRVI_TUNING_FIELD(type, name, def, lo, hi, meaning) type name;
  MRVI_TUNING_LIST(MRVI_TUNING_FIELD)
#undef MRVI_TUNING_FIELD
} mrvi_tuning;

typedef struct mrvi_settings {
  char scheme[48];     /* name of the scheme the rules came from */
  mrvi_rule slow;      /* rule for V */
  mrvi_grid slow_grid; /* grid for V; macro: V_d = dT[a V(q_k) + (1-a)
                          V(q_k+1)] */
  mrvi_rule fast;      /* rule for W (always micro grid) */
  double macro_step;   /* Delta T > 0 */
  int micro_steps;     /* p >= 1 */
  double t_end;        /* >= macro_step; N = ceil(t_end/dT - 1e-9) steps */
  double newton_tol;   /* stop when ||R||_inf <= tol (default 1e-9) */
  int newton_max_iter; /* default 20 */
  mrvi_newton_criterion newton_criterion; /* default ABSOLUTE */
  /* Constraints (doc/constraints.md). */
  mrvi_constraint_form constraint_form; /* default MRVI_FORM_MULTIPLIERS */
  double constraint_tol;                /* max |g| at enforced nodes (1e-10) */
  int project_momenta;                  /* project p onto G M^-1 p = 0 (1) */
  mrvi_solver solver;                   /* default MRVI_SOLVER_AUTO */
  /* Warn when the run's maximal energy error (mrvi_summary) exceeds this
   * (default 0.1); 0 never warns. */
  double energy_warning;
  mrvi_tuning tuning; /* MRVI_TUNING_LIST's defaults */
  /* Threads of the element loops (OpenMP; doc/performance/threads.md,
   * "Threads"): 1 (default) none, 0 the cores this process may use;
   * mrvi_threads_auto chooses by the model's size and the idle cores (the mrvi
   * command's default).  Results are the same bit for bit for every count.
   * Above 1 in a build without OpenMP, mrvi_settings_check refuses it
   * (mrvi_threads_supported). */
  int threads;
  /* 1: mrvi_run's steps keep the last fast micro node alone
   * (mrvi_integrator_keep_micro): its observers see micro_count 1, the new
   * macro node, at t_{k+1}; for runs whose micro nodes nobody reads (the
   * CLI sets it when output.micro is off).  The trajectory is the same bit
   * for bit.  0 (default): all p micro nodes. */
  int micro_last_only;
} mrvi_settings;

/* Defaults: midpoint-midpoint, dT = 0.01, p = 1, t_end = 1, tol 1e-9, 20
 * it, energy warning above 10 %. */
void mrvi_settings_default(mrvi_settings *s);
/* Set both rules and the slow grid from a named scheme:
 * midpoint-midpoint, trapezoidal-midpoint, trapezoidal-trapezoidal,
 * explicit-slow, fully-explicit.  MRVI_EINVAL for an unknown name. */
int mrvi_settings_set_scheme(mrvi_settings *s, const char *scheme);
/* Set the tuning constant `name` of MRVI_TUNING_LIST to value: MRVI_EINVAL
 * with a message (msg may be NULL) for an unknown name (naming the closest
 * one), a value outside its range or a fraction for an integer constant. */
int mrvi_settings_set_tuning(mrvi_settings *s, const char *name, double value,
                             char *msg, size_t len);
/* The tuning constant `name` into *value; MRVI_EINVAL for an unknown name.
 */
int mrvi_settings_get_tuning(const mrvi_settings *s, const char *name,
                             double *value);
/* One row of MRVI_TUNING_LIST: its name, default, range and meaning
 * (integer: 1 for an int constant). */
typedef struct mrvi_tuning_info {
  const char *name;
  double value, lowest, highest;
  int integer;
  const char *meaning;
} mrvi_tuning_info;
/* The rows of MRVI_TUNING_LIST in its order; *count gets their number. */
const mrvi_tuning_info *mrvi_tuning_table(int *count);
/* Step solver path for model m and settings s (doc/solver.md): "explicit"
 * (no Newton), "sweep" (explicit slow update, forward sweep of p implicit
 * micro steps), "schur" (Newton, Schur complement on the slow block),
 * "sweep-cg" and "schur-krylov" (the same with CG and GMRES for blocks
 * beyond tuning.dense_max, 64, coordinates), "schur-bordered" (constrained,
 * multiplier form: the schur elimination bordered by the multipliers) or
 * "general" (Newton with sparse LU on the whole step).  why (may be NULL)
 * gets the reason for the choice.  With s->solver = structured and no
 * structured path, returns NULL (why says why). */
const char *mrvi_solver_path(const mrvi_model *m, const mrvi_settings *s,
                             char *why, size_t len);
/* Names of the schemes, NULL-terminated. */
const char *const *mrvi_scheme_names(void);
/* Validate: alpha, gamma in [0,1], p >= 1, dT > 0, t_end >= dT, tol > 0,
 * max_iter >= 1.  Writes a message on failure. */
int mrvi_settings_check(const mrvi_settings *s, char *msg, size_t len);

/* The thread count for a run of m with s (`mrvi run --threads auto`, the
 * command's default; doc/performance/threads.md, "The automatic thread count"):
 * the cores this process may use (its affinity mask) less the tasks running on
 * them now (Linux's /proc/loadavg) when some loop of the step can run on
 * threads -- the fast or slow coordinates or the elements of V or W number
 * at least two parts of s->tuning.thread_chunk -- else 1 (a smaller model
 * never enters a parallel region); 1 on a busy machine and in a build
 * without OpenMP.  why (may be NULL) gets the reason in words.  Results do
 * not depend on the count. */
int mrvi_threads_auto(const mrvi_model *m, const mrvi_settings *s, char *why,
                      size_t len);
/* Number of macro steps N = ceil(t_end/dT - 1e-9). */
long mrvi_settings_n_steps(const mrvi_settings *s);

/* ---------------------------------------------------------------------------
 * Integrator: one-step position-momentum map (arXiv 2406.12991 §3.1,
 * doc/solver.md), solved by Newton with UMFPACK (pattern and symbolic
 * analysis once, numeric per iteration).
 * -------------------------------------------------------------------------
 */
typedef struct mrvi_integrator mrvi_integrator;

/* Create for a model (must outlive the integrator) and settings (copied).
 * The state is set to (q0, M v0) at t = 0.  On failure *out is NULL and a
 * message is written to msg. */
int mrvi_integrator_create(const mrvi_model *m, const mrvi_settings *s,
                           mrvi_integrator **out, char *msg, size_t len);
void mrvi_integrator_free(mrvi_integrator *it);
const char *mrvi_integrator_errmsg(const mrvi_integrator *it);

/* Set the state at macro node k = 0 (model order, n entries each). */
int mrvi_integrator_set_state(mrvi_integrator *it, double t, const double *q,
                              const double *p);
/* Set the state to that of macro node k of an earlier run with the same
 * settings (t = k * macro_step), exactly as stored: no momentum projection
 * (the stored p_k is projected already), the constraints only checked.  The
 * steps that follow equal the earlier run's bit for bit, except that the
 * multipliers reported by the first one lack the projection impulse of
 * node k (doc/output.md, "Resuming a run"). */
int mrvi_integrator_resume_state(mrvi_integrator *it, long k, const double *q,
                                 const double *p);
/* Torsional springs: their count and their branches at the current node
 * (unwrapped angles, in the order they were added). */
int mrvi_integrator_n_torsions(const mrvi_integrator *it);
const double *mrvi_integrator_torsion_angle(const mrvi_integrator *it);
/* After mrvi_integrator_resume_state: the branches (n_torsions entries) of
 * that node as the earlier run had them (resume_state puts each spring on
 * the branch nearest its rest angle).  Each must be the spring's angle at
 * the node's q up to 2 pi turns (to 1e-6 rad), else MRVI_EINVAL.  Taken
 * exactly as given, so that the steps equal the earlier run's bit for bit.
 */
int mrvi_integrator_resume_torsion(mrvi_integrator *it, const double *angle);
/* tuning.chord_carry (explicit-slow on sweep-cg, doc/solver.md "sweep-cg"):
 * the rows' history the next step takes from the last one, part of the
 * state a resumed run needs to continue bit for bit.  Sets part[0..4] to
 * its five arrays (valid until the next step or state change) and returns
 * their length (the fast coordinates); 0 where the next step takes no
 * history (it then depends on (q_k, p_k) alone). */
int mrvi_integrator_chord_history(const mrvi_integrator *it,
                                  const double *part[5]);
/* After mrvi_integrator_resume_state: the history of that node as the
 * earlier run had it (h: the five parts one after the other, n entries
 * each).  MRVI_EINVAL where this run keeps none or n differs,
 * MRVI_ENONFINITE for a non-finite entry (the file it came from is
 * untrusted). */
int mrvi_integrator_resume_chord_history(mrvi_integrator *it, int n,
                                         const double *h);
/* Advance one macro step.  On failure the state is unchanged and the
 * message gives the step, time and residual. */
int mrvi_integrator_step(mrvi_integrator *it);

double mrvi_integrator_time(const mrvi_integrator *it);
long mrvi_integrator_step_index(const mrvi_integrator *it); /* k */
/* The state at the current node, model order (n each).  Call again after
 * each step: the arrays may move (mrvi_integrator_keep_micro) or be
 * gathered at the call from the rate blocks the steps keep. */
const double *mrvi_integrator_q(const mrvi_integrator *it); /* n */
const double *mrvi_integrator_p(const mrvi_integrator *it); /* n */
/* Fast micro nodes m = 1..p of the last step: p x n_fast, row-major, fast
 * coordinates in model order (row p-1 is the new macro node). */
const double *mrvi_integrator_micro_q(const mrvi_integrator *it);
const double *mrvi_integrator_micro_p(const mrvi_integrator *it);
/* Which fast micro nodes the steps keep from the next step on: all = 1
 * (the default) all p, all = 0 the last alone (mrvi_integrator_micro_q and
 * _p then give one row, the new macro node's fast part): on the explicit
 * and sweep paths each node is written over the last, which saves
 * (p - 1) n_fast doubles of each and their copying; on the Newton paths,
 * which solve all nodes at once, the interior nodes are not copied out and
 * their momenta are not projected onto the hidden constraints (an output
 * only); the trajectory is the same bit for bit;
 * mrvi_integrator_jacobian_solve then refuses (the Jacobian needs every
 * node).  With the last node alone, micro_q's and micro_p's row is the
 * state's fast part itself (no copy kept).  Returns the rows kept (p or
 * 1), or MRVI_ENOMEM. */
int mrvi_integrator_keep_micro(mrvi_integrator *it, int all);
int mrvi_integrator_last_iterations(const mrvi_integrator *it);
/* Solve J x = b (transpose = 0) or J^T x = b (transpose = 1) with the
 * Jacobian J of the last completed step's residual (multiplier form, size
 * mrvi_integrator_jacobian_size: unknowns (q_{k+1}^s, q_k^{f,1..p}) then
 * multipliers) at its converged solution; b, x of that size.  Works on
 * every solver path; valid until the next step or set_state. */
int mrvi_integrator_jacobian_solve(mrvi_integrator *it, int transpose,
                                   const double *b, double *x);
int mrvi_integrator_jacobian_size(const mrvi_integrator *it);
/* Step solver path of the integrator ("explicit", "sweep", "schur",
 * "sweep-cg", "schur-krylov", "schur-bordered", "general"). */
const char *mrvi_integrator_solver_path(const mrvi_integrator *it);
/* Iterative linear solves of the sweep-cg and schur-krylov paths
 * (doc/solver.md), accumulated since creation; zero on the other paths. */
typedef struct mrvi_krylov_stats {
  long cg_solves;        /* CG solves of micro-step blocks */
  long cg_iterations;    /* their iterations in total */
  int cg_max;            /* most iterations of one CG solve */
  long gmres_solves;     /* GMRES solves on the slow unknowns (schur-krylov) */
  long gmres_iterations; /* their iterations in total */
  int gmres_max;         /* most iterations of one GMRES solve */
  long fallbacks;        /* linear solves done by sparse LU instead */
  char fallback_reason[320]; /* why the first of them was */
  /* schur-krylov's matrix-free outer iteration (doc/solver.md) */
  long outer_steps;  /* steps it solved */
  long outer_sweeps; /* its fast sweeps in those and the failed tries */
  long outer_evals;  /* its gradient evaluations (a point's V and W) */
  double outer_grad_equivalents; /* ... weighted by their share of the
                                    terms of V and W */
  long outer_fallbacks;          /* steps it tried and left to Newton */
  /* schur-krylov's Newton (the whole step's Jacobian and its elimination)
   * is built: at creation, or where the outer iteration is the first
   * choice, on the first step left to Newton or Jacobian solve */
  int newton_built;
  /* explicit, sweep and sweep-cg paths: evaluations of grad W over the
   * whole fast class (at a node or an implicit point, with or without its
   * Hessian) and of grad V over the slow class, for the cost model of the
   * benchmarks (doc/performance.md) */
  long sweep_evals_w, sweep_evals_v;
  /* sweep-cg with tuning.chord_linear: the linearised updates' Hessian-
   * vector products of W over the fast class (no square root, no division;
   * not among sweep_evals_w) */
  long sweep_products_w;
  /* sweep-cg: the sum over the chord updates of the ratio of the last two
   * residuals that relaxes the next one (doc/solver.md, "sweep-cg"): a
   * diagnostic whose last bits depend on the order of the sums over the
   * row, which tests compare across thread counts (the trajectory does
   * not show them: the relaxation 1 / (1 - ratio) rounds them away) */
  double sweep_chord_sum;
} mrvi_krylov_stats;
void mrvi_integrator_krylov_stats(const mrvi_integrator *it,
                                  mrvi_krylov_stats *out);
/* Steps whose Newton iteration stopped at the roundoff floor above the
 * requested tolerance (0 when every step met it). */
long mrvi_integrator_roundoff_steps(const mrvi_integrator *it);
double mrvi_integrator_last_residual(const mrvi_integrator *it);
/* Size of the Newton system (n_slow + p n_fast, plus the multipliers in
 * the multiplier form) and its nonzeros (0 on the explicit and sweep
 * paths, which form no matrix of the whole step, and on schur-krylov until
 * its Newton is built: mrvi_krylov_stats.newton_built). */
int mrvi_integrator_system_size(const mrvi_integrator *it);
long mrvi_integrator_system_nnz(const mrvi_integrator *it);
/* Constraint multipliers of the last step, k -> k+1 (model constraint
 * order, constraint_rows entries), as forces: the action carries
 * -h lambda^T g at every enforcing node (h = dT at macro nodes, dt at micro
 * nodes).  Slow-only constraints: lambda_k.  Micro-node constraints: the
 * step average (1/p) sum_{m<p} lambda_k^m, i.e. the step's constraint
 * impulse over dT (single micro-node values carry the slow kick at macro
 * nodes, doc/constraints.md).  With momentum projection the projection
 * impulse at node k is included, so the values do not depend on it. */
const double *mrvi_integrator_lambda(const mrvi_integrator *it);
/* max |g| over the constraints enforced at the micro nodes m = 1..p of the
 * last step (p entries): the micro-node constraints at every node and, at
 * m = p (the new macro node), the slow-only ones too; zeros without
 * constraints. */
const double *
mrvi_integrator_micro_constraint_residual(const mrvi_integrator *it);
/* Accumulated wall time in seconds spent assembling residual+Jacobian and
 * in the linear solves (UMFPACK numeric + solve).  Measured on each of the
 * first 64 steps; later steps come in blocks of 64 whose first step is
 * timed: a block whose first step took 50 us or more is timed on every
 * step, else its first step's times stand for all its steps (reading the
 * clock costs as much as a micro step of the explicit paths), at most the
 * block's elapsed time, so that the sum never exceeds the wall time of the
 * steps.  Returns 1 when part of the times is such an estimate, 0 when
 * every step was measured. */
int mrvi_integrator_timing(const mrvi_integrator *it, double *assemble,
                           double *solve);

/* ---------------------------------------------------------------------------
 * Run driver: integrate to t_end, calling an observer at every macro node.
 * -------------------------------------------------------------------------
 */
typedef struct mrvi_record {
  long k;              /* macro node index */
  double t;            /* t_k */
  const double *q, *p; /* n, model order */
  double kinetic, potential_slow, potential_fast, energy;
  double linear_momentum[3];  /* dimension entries used */
  double angular_momentum[3]; /* 3 in 3-D, 1 in 2-D */
  int iterations;  /* Newton iterations of the step ending here (0 at k = 0)
                    */
  double residual; /* final ||R||_inf of that step (0 at k = 0) */
  /* Fast micro nodes that this record completes: at k = 0 the single node
   * t_0; otherwise nodes m = 1..p of step k-1.  micro_count x n_fast. */
  int micro_count;
  double micro_t0; /* time of the first of them */
  double micro_dt; /* spacing */
  const double *micro_q_fast, *micro_p_fast;
  /* Constraints (all 0 / NULL without them). */
  int n_lambda; /* constraint rows */
  /* Multipliers of node k-1 (computed by the step k-1 -> k that ends here;
   * NULL at k = 0): a node's multipliers are known one record late. */
  const double *lambda_prev;
  double constraint_residual;              /* max |g| over the nodes this record
                                              completes */
  double hidden_constraint_residual;       /* max |G M^-1 p| at node k */
  const double *micro_constraint_residual; /* micro_count entries */
  /* The run's energy error so far, over every node j <= k (stored or not):
   * max |H_j - H_0| and max T_j + |V_j| + |W_j| (mrvi_summary's error and
   * scale follow from them; a resumed run continues from them). */
  double energy_running[2];
  /* Torsional springs (doc/multibody.md "Torsional springs"): the branch of
   * each, its unwrapped angle at node k, in the order they were added
   * (n_torsion entries; NULL without them).  A run continued from node k
   * needs them (mrvi_start.torsion_angle). */
  int n_torsion;
  const double *torsion_angle;
  /* tuning.chord_carry: the history the next step takes from this node's
   * step (mrvi_integrator_chord_history: n_chord entries in each of the
   * five parts; 0 and NULLs without).  A run resumed from node k needs it
   * to continue bit for bit (mrvi_start.chord_history). */
  int n_chord;
  const double *chord_history[5];
} mrvi_record;

/* Observer: return 0 to continue, a status < 0 to stop the run with it. */
typedef int (*mrvi_observer)(void *user, const mrvi_record *r);

typedef struct mrvi_summary {
  long steps; /* macro steps completed */
  long iterations_total;
  int iterations_max; /* max per step */
  /* Energy error (doc/output.md, Energy error): max_k |H_k - H_0| / E, with
   * E = T_0 + |V_0| + |W_0| (= |H_0| unless an energy part is negative)
   * when that is nonzero, else the largest T_k + |V_k| + |W_k| of the run
   * (energy_scale_kind 1), else 1: the error is then absolute (kind 2). */
  double max_rel_energy_error;
  double energy_scale;   /* E */
  int energy_scale_kind; /* 0: initial, 1: largest along the run, 2: none */
  double energy_initial; /* H_0 */
  double energy_last;    /* H at the last completed macro node */
  /* Set when max_rel_energy_error exceeds settings.energy_warning: what
   * the error is and what to do ("" otherwise).  The run still completes.
   */
  char warning[512];
  double wall_time; /* seconds */
  /* Time spent assembling and solving (mrvi_integrator_timing): measured
   * when timing_estimated is 0, else partly estimated from sampled steps;
   * their sum is at most wall_time. */
  double assemble_time, solve_time;
  int timing_estimated;
  long roundoff_steps;      /* steps stopped at the roundoff floor above the
                               Newton      tolerance (doc/solver.md) */
  mrvi_krylov_stats krylov; /* iterative solves (sweep-cg, schur-krylov) */
  int status;               /* final status */
  /* Why it stopped ("" when completed).  A failed step after an energy
   * error above settings.energy_warning adds that the macro step is
   * probably beyond the stability limit of the scheme. */
  char message[1024];
} mrvi_summary;

/* Integrate from (q0, M v0) over N macro steps; the observer sees k = 0..N.
 * Stops at the first failure (step, observer or `*stop_flag` set nonzero by
 * e.g. a signal handler, giving MRVI_EINTERRUPTED).  stop_flag may be NULL.
 * The summary is filled in every case. */
int mrvi_run(const mrvi_model *m, const mrvi_settings *s,
             mrvi_observer observer, void *user, volatile const int *stop_flag,
             mrvi_summary *summary);
/* Macro node a run starts from: node k with state (q, p), model order. */
typedef struct mrvi_start {
  long k;
  const double *q, *p;
  /* NULL: the energy error counts from node k (a new run).  Else the
   * resumed run's H_0, T_0 + |V_0| + |W_0| and energy_running at node k, so
   * that its summary equals the uninterrupted run's. */
  const double *energy;
  /* NULL: each torsional spring starts on the branch nearest its rest
   * angle.  Else the branches at node k (n_torsion entries, which must be
   * the model's count; mrvi_record.torsion_angle of the run that stored
   * node k), so that a wound spring continues wound. */
  int n_torsion;
  const double *torsion_angle;
  /* NULL: the first step takes no chord history (tuning.chord_carry).
   * Else node k's (5 n_chord entries: mrvi_record.chord_history of the run
   * that stored node k, the parts one after the other). */
  int n_chord;
  const double *chord_history;
} mrvi_start;
/* mrvi_run from node start->k (mrvi_integrator_resume_state) instead of
 * node 0: the first record is node k (as the initial record of mrvi_run:
 * one micro node, no solver statistics), then steps k+1 .. N.  start NULL:
 * mrvi_run. */
int mrvi_run_from(const mrvi_model *m, const mrvi_settings *s,
                  const mrvi_start *start, mrvi_observer observer, void *user,
                  volatile const int *stop_flag, mrvi_summary *summary);

/* ---------------------------------------------------------------------------
 * Description files (YAML 1.2, doc/description-files.md).
 * -------------------------------------------------------------------------
 */
typedef struct mrvi_system {
  char *name; /* `name:` */
  char *path; /* file it came from ("<string>" for text) */
  mrvi_model *model;
  mrvi_settings settings;
  char *output_file;            /* output.file (default: <name>.h5) */
  int output_every;             /* output.every (default 1) */
  int output_micro;             /* output.micro (default 1) */
  int output_micro_slow;        /* output.micro_slow (default 0) */
  int output_xdmf;              /* output.xdmf: write OUT.xdmf (default 1) */
  double output_flush_interval; /* output.flush_interval, s (0: default) */
  char *description;            /* the input text after overrides */
  /* What the loader changed or wants the user to know, one note per line
   * ('\n'-separated, no trailing newline), e.g. that the initial velocities
   * were projected onto the constraints' tangent space; NULL when there is
   * nothing to say.  Freed by mrvi_system_free. */
  char *notes;
} mrvi_system;

/* Load a description file, applying overrides "dotted.path=value" (e.g.
 * "integrator.micro_steps=5", "particles.2.mass=3") before interpretation.
 * On failure returns MRVI_EPARSE (or MRVI_EIO / MRVI_ENOMEM) and writes
 * "file:line:col: message" into msg; *out is NULL. */
int mrvi_system_load(const char *path, const char *const *overrides,
                     int n_overrides, mrvi_system **out, char *msg, size_t len);
/* Same from text in memory; `display_name` stands in for the file name. */
int mrvi_system_load_string(const char *text, const char *display_name,
                            const char *const *overrides, int n_overrides,
                            mrvi_system **out, char *msg, size_t len);
void mrvi_system_free(mrvi_system *sys);

/* ---------------------------------------------------------------------------
 * HDF5 output (doc/output.md).  The writer is an observer for mrvi_run;
 * rows are buffered and appended to chunked, extendible datasets.
 * -------------------------------------------------------------------------
 */
typedef struct mrvi_writer mrvi_writer;

typedef struct mrvi_writer_options {
  const char *system_name; /* root attribute `system` */
  const char *description; /* /model/description (may be NULL) */
  int every;               /* write every `every`-th macro node (>= 1) */
  int micro;               /* write /micro datasets */
  double flush_interval;   /* seconds between flushes (<= 0: default 2) */
  int force;               /* replace an existing non-mrvi file */
  int micro_slow;          /* with micro: also /micro/q_slow, the slow
                              coordinates interpolated at the micro nodes */
  int resume;              /* append to the existing output (mrvi run
                              --resume): cut its datasets back to macro node
                              resume_k, which the first record repeats and
                              is not written again */
  long resume_k;
  int extend; /* with resume: the file is a completed run that
                 goes on to a later t_end.  It is copied beside
                 itself, its t_end, stop_reason and
                 /model/description are set to this run's in
                 the copy, and the copy is renamed over it
                 before appending: killed before the rename,
                 the completed file is untouched */
} mrvi_writer_options;

/* The writer options a description's `output:` section asks for (name,
 * description, every, micro, flush interval, micro_slow); force and resume
 * are left 0 for the caller to set. */
mrvi_writer_options mrvi_system_writer_options(const mrvi_system *sys);

/* Create (truncate) the file and write attributes and /model.  The model
 * must outlive the writer: the body and joint outputs are computed from it
 * at every record. */
int mrvi_writer_open(const char *path, const mrvi_model *m,
                     const mrvi_settings *s, const mrvi_writer_options *opt,
                     mrvi_writer **out, char *msg, size_t len);
/* Observer callback: user = the writer. */
int mrvi_writer_observe(void *writer, const mrvi_record *r);
/* Record the energy error and the warning of a run's summary: close
 * writes them as the root attributes energy_error_max, energy_scale,
 * energy_scale_kind, energy_warning and warning (doc/output.md). */
void mrvi_writer_set_summary(mrvi_writer *w, const mrvi_summary *sum);
/* Flush buffered rows, write the root attribute `stop_reason`
 * ("completed" or the message) and close.  Frees w. */
int mrvi_writer_close(mrvi_writer *w, const char *stop_reason, char *msg,
                      size_t len);
/* The root attribute stop_reason of an mrvi output into reason:
 * "completed", the message of a run that stopped, "incomplete (writer
 * killed)" for a run that never closed, or "running" while a live run holds
 * the file.  Opens a killed file too (SWMR reading).  MRVI_EIO with a
 * message in reason for a file that is not an mrvi output. */
int mrvi_run_file_status(const char *path, char *reason, size_t len);

/* A macro node stored in an mrvi output, to continue a run from it (mrvi
 * run --resume / --from, doc/output.md "Resuming a run"). */
typedef struct mrvi_stored_node {
  long k;               /* macro node index: t = k * macro_step */
  long steps_completed; /* root attribute */
  int every;            /* output_every of the file */
  int n;                /* coordinates */
  double t, macro_step;
  double *q, *p; /* n each, model order */
  /* H_0, T_0 + |V_0| + |W_0| (row 0) and /macro/energy_running of node k:
   * mrvi_start.energy of a resumed run. */
  double energy[4];
  /* /macro/torsion_angle of node k (n_torsion entries; 0 and NULL when the
   * file has none): mrvi_start.torsion_angle. */
  int n_torsion;
  double *torsion_angle;
  /* /resume/chord_history where it holds node k's (tuning.chord_carry;
   * MRVI_NODE_RESUME and _EXTEND only; 0 and NULL otherwise):
   * mrvi_start.chord_history, 5 n_chord entries. */
  int n_chord;
  double *chord_history;
  char *description;      /* /model/description: the input after overrides */
  char stop_reason[1024]; /* as mrvi_run_file_status */
} mrvi_stored_node;
#define MRVI_NODE_LAST (-1L)   /* the last stored macro node */
#define MRVI_NODE_RESUME (-2L) /* the node a resumed run continues from */
#define MRVI_NODE_EXTEND                                                       \
  (-3L) /* the same, of a completed run (its extension) */
/* Read node `which` (a node index k >= 0 that the file stores, or one of
 * the two above) of the mrvi output at path.  MRVI_NODE_RESUME: the last
 * stored node k <= steps_completed with k a multiple of `every` whose
 * multipliers (/macro/lambda) are in the file; a completed run or a file a
 * live run holds is refused.  MRVI_NODE_EXTEND: the same node of a
 * completed run (mrvi run --resume with a later t_end); other runs are
 * refused.  n: the coordinates of the model the node
 * is for (/macro/q and /model/rate must have n; 0 when the model is the
 * file's own, as for a resume: any count whose vectors fit in memory).
 * Every dataset and attribute is checked before it is read (the file is
 * untrusted).  Errors (MRVI_EIO, MRVI_EINVAL) with a message: not an mrvi
 * output, a dataset of another shape, node not stored or out of range. */
int mrvi_stored_node_read(const char *path, long which, int n,
                          mrvi_stored_node **out, char *msg, size_t len);
void mrvi_stored_node_free(mrvi_stored_node *node);
/* The run file at path against sys, the system of its own
 * /model/description: the root attributes macro_step, micro_steps,
 * output_every, t_end, scheme, alpha/gamma and slow_grid, the coordinates
 * (/macro/q's width, /model/name, /model/rate) and /macro/lambda's width
 * must be what that description gives.  MRVI_EINVAL naming the first
 * disagreement (a file edited or crafted after it was written must not be
 * continued: mrvi run --resume and --from check it before they read a
 * node). */
int mrvi_stored_run_check(const char *path, const mrvi_system *sys, char *msg,
                          size_t len);

/* ---------------------------------------------------------------------------
 * Viewing the motion (doc/output.md): files for ParaView, OVITO, VMD made
 * from a run file, for the macro nodes it stores (also of a run that
 * stopped early or was killed).  Both need a model with particles: a run
 * file of generalised coordinates only gives MRVI_EINVAL ("no particles").
 * -------------------------------------------------------------------------
 */

/* XDMF 2 file describing the particles of run file h5_path over time,
 * pointing into its datasets (no data copied): two temporal collections of
 * one uniform grid per macro node, "particles" (points from /macro/q, node
 * attribute rate) and, when /model/edges has rows, "bonds" (springs and
 * rods as lines, cell attribute edge_rate).  The HDF5 file is named by its
 * base name when both files are in one directory, else by absolute path. */
int mrvi_export_xdmf(const char *h5_path, const char *xdmf_path, char *msg,
                     size_t len);

/* What the species column holds: X (ASE's dummy element, a chemical symbol
 * every reader takes), slow/fast, or the particle name (OVITO and VMD take
 * any word there, ASE only chemical symbols); for a body's points X,
 * body/d1/d2/d3, or NAME/NAME.d1/... */
enum {
  MRVI_XYZ_SPECIES_X = 0,
  MRVI_XYZ_SPECIES_RATE = 1,
  MRVI_XYZ_SPECIES_NAME = 2
};

typedef struct mrvi_xyz_options {
  int every;   /* write every every-th frame (>= 1) */
  int micro;   /* frames at the micro nodes (/micro; slow particles need
                  /micro/q_slow, output.micro_slow) instead of macro nodes */
  int species; /* MRVI_XYZ_SPECIES_X, _RATE or _NAME */
} mrvi_xyz_options;

/* Extended XYZ frames (OVITO, VMD, ASE): per frame the number of points, a
 * comment line "Properties=species:S:1:pos:R:3:rate:I:1:name:S:1 Time=t
 * pbc="F F F"" and a line "species x y z rate name" per particle (2-D and
 * 1-D padded with zeros; rate 0 slow, 1 fast; name with blanks as '_'),
 * then 1 + d lines per rigid body: its centre of mass (name NAME) and the
 * tips phi + s d_i of its directors (NAME.d1 ...; s as in the XDMF file;
 * species X, body/d1/d2/d3 or the name), values with at most 17
 * significant digits.  opt may be NULL (every frame, macro nodes, species
 * X). */
int mrvi_export_xyz(const char *h5_path, const char *xyz_path,
                    const mrvi_xyz_options *opt, char *msg, size_t len);

/* ---------------------------------------------------------------------------
 * Analysis (paper §4-§6): trajectories, errors against a reference,
 * propagation matrices and linear stability.
 * -------------------------------------------------------------------------
 */

/* Every node of a run, kept in memory. */
typedef struct mrvi_trajectory {
  int n, n_fast;
  double macro_step;
  int micro_steps;
  long n_macro;              /* N + 1 */
  long n_micro;              /* N p + 1 */
  double *t, *q, *p;         /* n_macro; n_macro x n; n_macro x n */
  double *micro_t;           /* n_micro */
  double *micro_q, *micro_p; /* n_micro x n_fast */
} mrvi_trajectory;

/* Run and keep every node.  On failure *out is NULL and summary->message
 * says why. */
int mrvi_trajectory_run(const mrvi_model *m, const mrvi_settings *s,
                        mrvi_trajectory **out, mrvi_summary *summary);
void mrvi_trajectory_free(mrvi_trajectory *tr);

/* Read the nodes of a completed run from an mrvi HDF5 file (/macro/t, q, p
 * and, when present, /micro).  Fails with a message for a run that did not
 * complete or a file without these datasets. */
int mrvi_trajectory_read(const char *path, mrvi_trajectory **out, char *msg,
                         size_t len);

/* 64-bit fingerprint of everything that defines the dynamics of a model
 * (coordinates, masses, rates, initial data, elements and their
 * parameters); equal models give equal hashes.  Used to key cached
 * reference runs. */
unsigned long long mrvi_model_hash(const mrvi_model *m);

/* Errors of a run against a reference (eq:err_mac, eq:err_mic): sup over
 * nodes of the Euclidean norm of the difference.  Macro errors use all
 * coordinates and are also split into slow and fast parts; micro errors use
 * the fast coordinates at the micro nodes m = 1..p-1 (NAN when p = 1). */
typedef struct mrvi_errors {
  double macro_step;
  int micro_steps;
  double q_mac, p_mac, q_mic, p_mic;
  double qs_mac, qf_mac, ps_mac, pf_mac;
} mrvi_errors;

/* The reference must be a single-rate run (micro_steps = 1) whose step
 * divides the run's micro step and that reaches the run's last node. */
int mrvi_trajectory_errors(const mrvi_model *m, const mrvi_trajectory *run,
                           const mrvi_trajectory *ref, mrvi_errors *e,
                           char *msg, size_t len);

/* Propagation matrix of one macro step of a linear model: P (2n x 2n,
 * row-major) maps (q_k, p_k) to (q_{k+1}, p_{k+1}); column j is one step
 * from the j-th unit state.  The model must be linear (quadratic V, W). */
int mrvi_propagation_matrix(const mrvi_model *m, const mrvi_settings *s,
                            double *P, char *msg, size_t len);

/* Harmonic oscillator (one coordinate, V = omega^2 M q^2/2 at q0, no W;
 * Lemma lemma:stability_slow): its frequency omega = sqrt(V''/M). */
int mrvi_oscillator_omega(const mrvi_model *m, double *omega, char *msg,
                          size_t len);
/* det and trace of the propagation matrix at omega dT = x (dT = x/omega,
 * the rules and p of s). */
int mrvi_stability_at(const mrvi_model *m, const mrvi_settings *s, double x,
                      double *det, double *trace, char *msg, size_t len);
/* Largest x = omega dT such that |trace| < 2 on (0, x): scanned in steps
 * of `step` up to x_max and refined by bisection.  INFINITY if stable on
 * the whole scan. */
int mrvi_stability_limit(const mrvi_model *m, const mrvi_settings *s,
                         double x_max, double step, double *limit, char *msg,
                         size_t len);
/* Analytic bound of Lemma lemma:stability_slow on omega dT for the slow
 * rule on the micro grid: trapezoidal family (gamma = 0 or 1) sqrt(12
 * p^2/(p^2+2)), midpoint (gamma = 1/2) sqrt(12 p^2/(p^2-1)) (INFINITY for p
 * = 1); NAN for other rules. */
double mrvi_stability_bound(mrvi_rule slow, int p);

#ifdef __cplusplus
}
#endif

#endif /* MRVI_H */
