/* What src/model/ offers the layers above it: the model's layout (struct
 * mrvi_model, its elements, particles and constraint instances), element
 * and constraint evaluation, the built-in law tables (model.c,
 * constraints.c, laws.c, laws/). */
#ifndef MRVI_MODEL_H
#define MRVI_MODEL_H

#include "util/util.h"

/* Largest number of inputs of a non-linear element (terms are limited to it).
 */
#define MRVI_MAX_INPUTS 64

typedef enum mrvi_element_kind {
  MRVI_ELEMENT_SPRING,  /* phi(|x_i - x_j| - L0) */
  MRVI_ELEMENT_ANCHOR,  /* phi(|x_i - a| - L0) */
  MRVI_ELEMENT_TERM,    /* phi(c^T y - b) */
  MRVI_ELEMENT_GRAVITY, /* c^T y (linear, no law) */
  MRVI_ELEMENT_ANGLE,   /* k [1 - cos(theta_ijk - theta0)], no law */
  MRVI_ELEMENT_FORCE,   /* c^T y with c = -f (constant force, no law) */
  MRVI_ELEMENT_TORSION  /* phi(theta - theta0), theta the unwrapped relative
                           angle of two bodies about an axis (bodies.c) */
} mrvi_element_kind;

typedef struct mrvi_element {
  /* (Fields ordered and narrowed so that an element takes 56 bytes: a
   * network holds about one per coordinate.) */
  const mrvi_law *law; /* NULL for gravity */
  /* law->n_params values (angles: 3), one copy per distinct set shared by
   * the elements that have it (model.c, intern_params); NULL for elements
   * without parameters */
  const double *params;
  double shift; /* rest length (springs) or offset b (terms) */
  union {
    /* anchors: the point (3 values, unused ones 0), shared like params */
    const double *anchor;
    /* Torsion (bodies.c): the frame vectors r_u, r_v of the reference (body
     * A in its frame, or the ground in space) and m_u of the moving body
     * (its frame), dimension entries each, then at MRVI_TORSION_BRANCH the
     * branch of the angle, the unwrapped angle at the last accepted node
     * (run state: mrvi_model_torsion_set). */
    double *axes;
  };       /* NULL for the other kinds */
  int *in; /* n_in model indices (in blocks: mrvi_model_inputs) */
  /* n_in coefficients (terms, gravity, forces, springs between body points);
   * NULL for the others, whose particles are those of their inputs
   * (mrvi_element_particle) */
  double *coef;
  int n_in;                /* number of input coordinates */
  unsigned char kind;      /* mrvi_element_kind */
  unsigned char potential; /* mrvi_rate: MRVI_SLOW: part of V, MRVI_FAST: W */
  unsigned char form;      /* mrvi_law_form: law->form (set with the law) */
  /* A view of a compact spring (mrvi_model_element): its law's prototype,
   * which lasts as long as the model (mrvi_element_stable); NULL for an
   * element stored in full. */
  const struct mrvi_element *proto;
} mrvi_element;

/* The model's element table (model.c): one 24-byte record per element.  A
 * spring between two particles (mrvi_model_add_spring: no coefficients,
 * each end a particle's consecutive coordinates) is kept in its record
 * alone: its rest length, the first coordinates of its ends and the index
 * of its law, parameter set and rate in the model's prototypes (laws with
 * equal parameters shared), instead of an mrvi_element (64 bytes) and its
 * inputs (2 dim ints).  Every other element is kept in full (m->full[ci]).
 * Read an element through mrvi_model_element or MRVI_ELEMENT.  The 32-bit
 * fields hold the model's own int counts (coordinates, the element's
 * index in m->full): mrvi_model_reserve and mrvi_model_room refuse a model
 * beyond INT_MAX of any, the tables (parameter sets, names) stop at
 * INT_MAX / 4 entries (out of memory) and every array grows to at most
 * INT_MAX entries; a compact spring's prototype index has 24 bits (a
 * spring of a law beyond MRVI_EREC_LP_MAX distinct ones is kept in full).
 * The record is packed to 4-byte alignment: 20 bytes (the rest length
 * read unaligned on every machine mrvi builds on). */
/* 20 bytes a record, not 24 (a network holds about two a coordinate). */
#pragma pack(push, 4)
typedef struct mrvi_erec {
  double shift; /* compact spring: its rest length */
  int ci, cj;   /* compact spring: first coordinates of x_i, x_j; else ci is the
                   element's index in m->full */
  unsigned lp : 24;       /* compact spring: its prototype m->protos[lp] */
  unsigned kind : 4;      /* mrvi_element_kind */
  unsigned potential : 1; /* mrvi_rate */
  unsigned compact : 1;
} mrvi_erec;
#pragma pack(pop)
/* Prototypes a compact spring can name (lp); a spring of a further law is
 * kept in full.  The fuzz build lowers it (tests/fuzz/run.sh: 4), so that
 * crafted files reach springs of one law both compact and in full. */
#ifndef MRVI_EREC_LP_MAX
#define MRVI_EREC_LP_MAX (1 << 24)
#endif

/* Room for a view of an element (mrvi_model_element). */
typedef struct mrvi_element_buf {
  mrvi_element e;
  int in[6]; /* a spring's 2 dim inputs */
} mrvi_element_buf;

typedef struct mrvi_particle {
  /* NULL for a generated particle, whose name its generator's rule makes
   * when asked (mrvi_model_particle_name) */
  char *name;
  int first; /* model index of its x coordinate */
} mrvi_particle;

/* The names of one generator's particles (generators.c), made when asked
 * instead of stored: particles first .. first + count - 1 are those of
 * linear index 0 .. count - 1 (x fastest) on n[0] x n[1] x n[2]. */
typedef struct mrvi_name_rule {
  char *prefix;
  int kind; /* mrvi_generator_kind */
  int n[3];
  int first, count;
} mrvi_name_rule;
/* The longest prefix a rule takes (longer ones: names stored, as a name
 * of MRVI_NAME_MAX - 1 characters or more would be cut). */
#define MRVI_RULE_PREFIX_MAX 200
/* A rule's kind for particles added one by one with the names PREFIX0,
 * PREFIX1, ... (mrvi_model_add_particle: the name of the next index of
 * the last rule of that prefix, or PREFIX0 for a new one; at most
 * MRVI_SEQUENCE_RULES such rules, so that a lookup tries few): made
 * "PREFIX%ld" as a chain's (n = INT_MAX, 1, 1), not stored. */
#define MRVI_RULE_SEQUENCE (-1)
#define MRVI_SEQUENCE_RULES 8

/* A constraint instance: type applied to model coordinates `in`. */
typedef struct mrvi_constraint {
  const mrvi_constraint_type *type;
  char *label;
  int n_in, *in; /* model indices */
  int n_params;
  double *params;
  int rows;        /* scalar equations */
  int first_row;   /* offset in the model's constraint rows */
  mrvi_rate where; /* MRVI_SLOW: macro nodes; MRVI_FAST: micro */
  int affine;      /* g affine in the inputs: no Hessian (type->affine) */
} mrvi_constraint;

struct mrvi_model {
  char *name;
  int dimension;
  int n, cap; /* coordinates */
  /* Names of the coordinates that are not a particle's (own_coord[k], in
   * increasing order, is named own_names[k]); a particle's coordinates are
   * named after it (mrvi_model_coordinate_name). */
  char **own_names;
  int *own_coord;
  int n_own, cap_own;
  /* The masses, read through MRVI_MASS: mass_inc 0 while every
   * coordinate's mass is the first's (one entry kept: 8 bytes a coordinate
   * less on the benchmark's networks, doc/performance/16-es-mem16.md), 1
   * once one differs (every entry). */
  double *mass, *q0, *v0;
  int mass_inc;
  /* a mrvi_rate each, one byte (the hash reads each as a mrvi_rate) */
  unsigned char *rate;
  int n_particles, cap_particles;
  /* particles[] is kept (1) from the first particle whose name is stored
   * or whose first coordinate is not its index times the dimension; until
   * then (0) no record is kept (16 bytes a particle less: names made by
   * their rules, doc/performance/17-mem17.md).  Read a particle through
   * mrvi_particle_first and mrvi_particle_stored. */
  int particles_kept;
  /* Name lookup (model.c): open-addressing tables by name, 0 = empty, else
   * index + 1: of own_names (the coordinates that are not a particle's: a
   * particle's are found through its name) and of the n_particle_table
   * particles with a stored name (a generated one's is found through its
   * rule). */
  int *coord_table, *particle_table;
  int coord_table_cap, particle_table_cap, n_particle_table;
  mrvi_particle *particles;
  mrvi_name_rule *rules; /* generators' names (generators.c) */
  int n_rules, cap_rules;
  int n_elements, cap_elements;
  mrvi_erec *erecs;   /* the element table (mrvi_erec) */
  mrvi_element *full; /* the elements not kept in their record alone */
  int n_full, cap_full;
  /* The compact springs' laws: one prototype element per distinct law,
   * parameter set and rate (kind spring, no inputs, rest length NaN), each
   * its own allocation (the compiled terms keep pointers to them while
   * more are added), found by an open-addressing table (0 = empty, else
   * index + 1). */
  mrvi_element **protos;
  int n_protos, cap_protos;
  int *proto_table, proto_table_cap;
  /* Partition, extended by every add. */
  int n_slow, n_fast;
  int *slow_index, *fast_index; /* slot -> model index */
  int *slot;                    /* model index -> slot within its rate block */
  int max_in;                   /* largest n_in of a non-linear element */
  int n_torsions;               /* elements of kind MRVI_ELEMENT_TORSION */
  int n_constraints, cap_constraints;
  mrvi_constraint *constraints;
  int constraint_rows;   /* sum of rows */
  int max_constraint_in; /* largest n_in of a constraint */
  /* The elements' parameter sets (model.c, intern_params): each distinct
   * one once (MRVI_LAW_MAX_PARAMS values, unused ones 0), found by an
   * open-addressing table of set indices (0 = empty, else index + 1). */
  double **param_sets;
  int n_param_sets, cap_param_sets;
  int *param_table, param_table_cap;
  /* The names of the coordinates of their own and of the particles not
   * generated, and the elements' inputs (`in`), packed in blocks (model.c,
   * block_alloc) instead of one allocation each. */
  char **blocks;
  int n_blocks, cap_blocks;
  size_t block_used, block_cap; /* in the last block */
  int n_bodies, cap_bodies;     /* rigid bodies (model/bodies.c) */
  struct mrvi_body *bodies;
  char errmsg[512];
};

/* Particle p's first coordinate and its stored name (NULL: made by its
 * rule, mrvi_model_particle_name) (m->particles_kept). */
static inline int mrvi_particle_first(const mrvi_model *m, int p) {
  return m->particles_kept ? m->particles[p].first : p * m->dimension;
}
static inline const char *mrvi_particle_stored(const mrvi_model *m, int p) {
  return m->particles_kept ? m->particles[p].name : NULL;
}

/* The mass of coordinate i (m->mass_inc). */
#define MRVI_MASS(m, i) ((m)->mass[(size_t)(i) * (size_t)(m)->mass_inc])

/* A rigid body (model/bodies.c, doc/multibody.md): dimension d (d + 1)
 * consecutive coordinates from `first`: phi (d), then d_1 .. d_d (d each). */
typedef struct mrvi_body {
  char *name;
  int first;
  int dim;
  double mass, inertia[3]; /* M; J_1..J_3 (2-D: J in inertia[0]) */
  int constraint;          /* its internal constraint ("body") */
} mrvi_body;
/* Torsional springs (bodies.c, doc/multibody.md "Torsional springs"): the
 * unwrapped angle is a function of the path, not of q, so its branch is run
 * state kept by the integrator (ref: one entry per torsion element, in
 * element order) and handed to the elements before each step.  The
 * elements' energy is evaluated on the branch nearest their `unwrap`. */
int mrvi_model_n_torsions(const mrvi_model *m);
/* ref <- each torsion's angle at q on the branch nearest its rest angle. */
void mrvi_model_torsion_init(const mrvi_model *m, const double *q, double *ref);
/* The elements' branches <- ref (writes the elements' run state `unwrap`:
 * the one field of a model that a run changes). */
void mrvi_model_torsion_set(const mrvi_model *m, const double *ref);
/* ref <- each torsion's angle at q on the branch nearest ref; returns the
 * largest |change| (the relative rotation across one step), *worst (may be
 * NULL) its element index. */
double mrvi_model_torsion_follow(const mrvi_model *m, const double *q,
                                 double *ref, int *worst);
/* Index in a torsion element's axes of its branch (after 3 x 3 frame
 * entries). */
#define MRVI_TORSION_BRANCH 9
/* Name of particle p: its stored name, or its rule's made in buf
 * (MRVI_NAME_MAX bytes) (model.c). */
const char *mrvi_model_particle_name(const mrvi_model *m, int p, char *buf);
/* mrvi_model_particle_name and mrvi_model_coordinate_name with a buffer
 * that lasts to the end of the enclosing block (messages). */
#define MRVI_PNAME(m, p)                                                       \
  mrvi_model_particle_name((m), (p), (char[MRVI_NAME_MAX]){""})
#define MRVI_CNAME(m, c)                                                       \
  mrvi_model_coordinate_name((m), (c), (char[MRVI_NAME_MAX]){""})
/* Index of the particle (coordinate) named `name`, or -1 (model.c). */
int mrvi_model_find_particle(const mrvi_model *m, const char *name);
int mrvi_model_find_coordinate(const mrvi_model *m, const char *name);
/* Every particle's name (particles = 1: n_particles of them) or every
 * coordinate's (n), in index order, into out: pointers into m or into the
 * returned block, which the caller frees; NULL when out of memory. */
char *mrvi_model_names(const mrvi_model *m, int particles, const char **out);
/* Room for `particles` more particles (their coordinates) and `elements`
 * more elements, made at once: a network grown by doubling leaves the
 * touched arrays it outgrew on the heap (model.c). */
int mrvi_model_reserve(mrvi_model *m, int particles, int elements);
/* Whether m has room for `particles` more particles (of its dimension) and
 * `springs` more two-particle springs: coordinates, particles and elements
 * each within an int, else a status < 0 with a message in msg; *bytes
 * (bytes may be NULL) gets the storage of the model so grown (its
 * per-coordinate arrays, particle table and element records), which the
 * caller holds against its own bound (the loader: limits.max_memory; not
 * the machine's memory, so that a refusal is the same on every machine).
 * mrvi_model_reserve checks the counts; the loader checks the sum of all
 * `generate:` entries before making any (io/loader/generate.c) (model.c). */
int mrvi_model_room(const mrvi_model *m, double particles, double springs,
                    double *bytes, char *msg, size_t len);
/* The springs generator g joins (nearest neighbours, a ring's closing one;
 * those of a rate without a law included), its counts valid
 * (generators.c). */
long mrvi_generator_springs(const mrvi_generator *g);
/* A rule (a generator's kind, prefix and counts n) that names the
 * particles mrvi_model_add_ruled_particle adds next (model.c). */
int mrvi_model_add_rule(mrvi_model *m, int kind, const char *prefix,
                        const int n[3]);
/* mrvi_model_add_particle for a particle named by the last rule (name: the
 * rule's, checked for duplicates like any other) (model.c). */
int mrvi_model_add_ruled_particle(mrvi_model *m, const char *name, double mass,
                                  mrvi_rate rate, const double *x0,
                                  const double *v0);
/* Name of the particle of linear index lin made by a generator of kind
 * `kind` with `prefix` on n[0] x n[1] x n[2] particles (generators.c). */
void mrvi_generated_name(int kind, const char *prefix, const int n[3], long lin,
                         char *buf, size_t len);

/* Element i of m: a pointer to it where it is kept in full, else its view
 * made in b (valid while b is; in points into b).  The fields are those the
 * element was added with.  b's proto is NULL or that of the view b last
 * held (a buffer reused across a loop: the prototype's fields are copied
 * only when it changes); b may be NULL where element i is kept in full
 * (mrvi_model_compact(m, i) NULL). */
static inline const mrvi_element *mrvi_model_element(const mrvi_model *m, int i,
                                                     mrvi_element_buf *b) {
  const mrvi_erec *r = &m->erecs[i];
  if (!r->compact)
    return &m->full[r->ci];
  const int d = m->dimension;
  const mrvi_element *p = m->protos[r->lp];
  if (b->e.proto != p) /* (a buffer reused for springs of one prototype) */
    b->e = *p;
  b->e.shift = r->shift;
  b->e.in = b->in;
  b->e.proto = p;
  for (int k = 0; k < d; k++) {
    b->in[k] = r->ci + k;
    b->in[d + k] = r->cj + k;
  }
  return &b->e;
}
/* Element i's prototype where it is a compact spring, else NULL (it is
 * kept in full).  A compact spring is its prototype (law, parameters,
 * form, rate, kind spring, 2 d inputs, no coefficients) with the rest
 * length erecs[i].shift and the inputs erecs[i].ci + k, then erecs[i].cj +
 * k (k < d): the loops over a network's elements read these (and
 * mrvi_model_element for the others) instead of making views. */
static inline const mrvi_element *mrvi_model_compact(const mrvi_model *m,
                                                     int i) {
  const mrvi_erec *r = &m->erecs[i];
  return r->compact ? m->protos[r->lp] : NULL;
}
/* The rates of element i's inputs: bit 1 << MRVI_SLOW set where one of
 * them is slow, 1 << MRVI_FAST where one is fast (a compact spring's read
 * from its record). */
static inline int mrvi_model_element_rates(const mrvi_model *m, int i) {
  const mrvi_erec *r = &m->erecs[i];
  int mask = 0;
  if (r->compact) {
    for (int k = 0; k < m->dimension; k++)
      mask |= (1 << m->rate[r->ci + k]) | (1 << m->rate[r->cj + k]);
    return mask;
  }
  const mrvi_element *e = mrvi_model_element(m, i, NULL);
  for (int j = 0; j < e->n_in; j++)
    mask |= 1 << m->rate[e->in[j]];
  return mask;
}
/* mrvi_model_element with a buffer that lasts to the end of the enclosing
 * block. */
#define MRVI_ELEMENT(m, i)                                                     \
  mrvi_model_element((m), (i), &(mrvi_element_buf){.e.proto = NULL})
/* An element of the same law, parameters, kind, rate and coefficients as
 * e that lasts as long as the model: e itself where it is kept in full,
 * else its prototype (no inputs, no rest length).  For the compiled terms,
 * which keep a pointer to each element's law. */
static inline const mrvi_element *mrvi_element_stable(const mrvi_element *e) {
  return e->proto ? e->proto : e;
}

/* Particle owning input j of element e (springs, anchors and angles of
 * particles: particle i's inputs first, then j's, k's), or -1 (model.c). */
int mrvi_element_particle(const mrvi_model *m, const mrvi_element *e, int j);
/* Energy of torsion element e at its inputs y (bodies.c). */
double mrvi_torsion_eval(const mrvi_element *e, int dim, const double *y,
                         double *grad, double *hess);
/* Append element e (its inputs set) after the rate rule's check; on
 * failure e's coef and axes are freed (its inputs stay in the model's
 * blocks) (model.c).  Returns its index. */
int mrvi_model_push_element(mrvi_model *m, mrvi_element *e, const char *what);
/* Room for an element's n inputs in the model's blocks (freed with the
 * model, never alone), or NULL when out of memory (model.c). */
int *mrvi_model_inputs(mrvi_model *m, int n);
/* e's law `law` with params, checked (model.c). */
int mrvi_model_set_law(mrvi_model *m, mrvi_element *e, const char *law,
                       const double *params, const char *what);
/* The frame t_1..t_D (D x D, row m = t_m) of a joint with `axis` (NULL:
 * e_1), and the body-frame components R^T v of body b at the initial
 * configuration (bodies.c). */
void mrvi_joint_frame(int D, const double *axis, double *t);
void mrvi_body_frame_of(const mrvi_model *m, int b, const double *v,
                        double *out);
/* Release the bodies of m (bodies.c). */
void mrvi_model_free_bodies(mrvi_model *m);
/* 1 if m has bodies and every constraint is the internal one of a body,
 * 2-D or 3-D, slow or fast (no joints, no other constraints): the null-space
 * form then uses the free body's analytic null space and the nodal
 * reparametrisation (solver/nullspace.c, doc/multibody.md). */
int mrvi_model_free_bodies_only(const mrvi_model *m);
/* Body owning model coordinate c, or -1. */
int mrvi_model_body_of(const mrvi_model *m, int c);

/* Energy, gradient (n_in) and Hessian (n_in x n_in row-major, may be NULL)
 * of element e at its local inputs y (n_in). */
double mrvi_element_eval(const mrvi_model *m, const mrvi_element *e,
                         const double *y, double *grad, double *hess);

/* 1 if e's energy is a polynomial of degree <= 2 in its inputs (constant
 * Hessian): terms whose law's degree (mrvi_law.degree) is 0, 1 or 2,
 * gravity and constant forces (model.c). */
int mrvi_element_is_quadratic(const mrvi_element *e);

/* phi' and phi'' of c s^e for a small integer e = k (laws/power.c without
 * phi, by repeated multiplication), from ce = c e and ce1 = c e (e - 1). */
static inline void mrvi_power_derivs_ce(double ce, double ce1, int k, double s,
                                        double *d1, double *d2) {
  double sk = 1.0; /* s^(k-2), the product order of laws/power.c */
  switch (k) {
  case 3:
    sk = 1.0 * s;
    break;
  case 4:
    sk = (1.0 * s) * s;
    break;
  default:
    for (int i = 2; i < k; i++)
      sk *= s;
  }
  *d1 = k >= 1 ? ce * (k >= 2 ? sk * s : 1.0) : 0.0;
  *d2 = k >= 2 ? ce1 * sk : 0.0;
}

static inline void mrvi_power_derivs(double c, double e, int k, double s,
                                     double *d1, double *d2) {
  mrvi_power_derivs_ce(c * e, c * e * (e - 1), k, s, d1, d2);
}

/* Whether term element e's law has the power form (mrvi_law.form) with a
 * small integer exponent (0..8: evaluated inline by mrvi_power_derivs). */
static inline int mrvi_element_small_power(const mrvi_element *e) {
  const double x = e->params[1];
  return e->form == MRVI_LAW_FORM_POWER && x >= 0.0 && x <= 8.0 &&
         (double)(int)x == x;
}

/* phi'(s) and phi''(s) of term element e's law (the Hooke and small
 * integer power forms without calling eval; model.c). */
void mrvi_term_derivs(const mrvi_element *e, double s, double *d1, double *d2);

/* Keep a message on m (mrvi_model_errmsg) and return status (model.c). */
int mrvi_model_fail(mrvi_model *m, int status, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));
/* Evaluate constraint c at its inputs y: g (rows), G (rows x n_in), H
 * (rows x n_in x n_in, may be NULL). */
void mrvi_constraint_eval_at(const mrvi_constraint *c, const double *y,
                             double *g, double *G, double *H);

/* max |g(q)| within tol; otherwise MRVI_EMODEL and "<what> violate
 * constraint '<label>': |g| = ..." in msg.  *worst (may be NULL) gets the
 * constraint with the largest |g| (-1 without constraints). */
int mrvi_constraints_check_positions(const mrvi_model *m, const double *q,
                                     double tol, const char *what, int *worst,
                                     char *msg, size_t len);
/* M-orthogonal projection of momenta p (n) at q onto G M^-1 p = 0:
 * p <- p - G^T mu with (G M^-1 G^T) mu = G M^-1 p over the rows that drop
 * (rows, may be NULL: all) keeps; mu is 0 on the dropped rows.  Workspace g
 * (rows), G (rows x n), A (rows x rows); mu (rows) keeps the multiplier.
 * MRVI_ESINGULAR if the kept gradients are dependent. */
int mrvi_constraints_project(const mrvi_model *m, const double *q, double *p,
                             const unsigned char *drop, double *g, double *G,
                             double *A, double *mu);
/* Rank-revealing pass over G(q) in model order: drop (rows, may be NULL)
 * marks each row in the span of the earlier ones; msg names the
 * constraints of the first such dependency (with what the multiplier form
 * asks to do).  Returns the number of redundant rows or MRVI_ENOMEM. */
int mrvi_constraints_rank(const mrvi_model *m, const double *q,
                          unsigned char *drop, char *msg, size_t len);
/* Project positions q (n) onto g = 0 if some |g| exceeds tol: Newton on g
 * with the minimum-norm correction in the metric M over the independent
 * rows (doc/constraints.md, initial data).  *change gets max |dq_i|;
 * MRVI_EMODEL, q unchanged and a message naming the violated constraints
 * if Newton fails or *change exceeds MRVI_PROJECT_POSITIONS_MAX times
 * max(1, max |q_i|); *worst the constraint with the largest |g(q)|. */
int mrvi_constraints_project_positions(const mrvi_model *m, double *q,
                                       double tol, double *change, int *worst,
                                       char *msg, size_t len);
/* Gradients of all constraints independent at q (model order); otherwise
 * MRVI_ESINGULAR and a message naming the dependent constraints. */
int mrvi_constraints_independent(const mrvi_model *m, const double *q,
                                 char *msg, size_t len);

/* The Gram matrix G M^-1 G^T of the constraint rows in sparse (envelope)
 * storage with its Cholesky factor (constraint_gram.c): the momentum
 * projection and the independence check in O(R) for chains and trees,
 * where the dense ones cost O(R^2 n).  The projection takes it above
 * MRVI_GRAM_DENSE_MAX rows (below, the dense solve keeps the shipped
 * systems' numbers).  A second fuzz build lowers it (tests/fuzz/run.sh,
 * FUZZ_LOW=1) so that small crafted models reach the sparse Gram. */
#ifndef MRVI_GRAM_DENSE_MAX
#define MRVI_GRAM_DENSE_MAX 32
#endif
typedef struct mrvi_gram mrvi_gram;
int mrvi_gram_create(const mrvi_model *m, mrvi_gram **out);
void mrvi_gram_free(mrvi_gram *gr);
/* Leave the rows drop marks (R flags: the redundant rows of closed loops)
 * out of the factor, the projection and the settling: their multipliers
 * are 0.  MRVI_ENOMEM or 0. */
int mrvi_gram_drop(mrvi_gram *gr, const unsigned char *drop);
/* Gradients at q, the Gram matrix and its factor; MRVI_ESINGULAR where a
 * pivot is not clearly above round-off (the rows may be dependent: the
 * dense check decides and names them). */
int mrvi_gram_factor(mrvi_gram *gr, const mrvi_model *m, const double *q);
/* After mrvi_gram_factor at q: p <- p - G^T mu with (G M^-1 G^T) mu =
 * G M^-1 p; mu (rows) gets the multiplier. */
void mrvi_gram_project(mrvi_gram *gr, const mrvi_model *m, double *p,
                       double *mu);
/* After mrvi_gram_factor at q_k: q moved onto g(q) = 0 nearest in the
 * metric M by chord corrections q <- q - M^-1 G^T mu, (G M^-1 G^T) mu =
 * g(q), with G and the factor at q_k (each contracts g by about the angle
 * q has turned from q_k), until g stops halving or after max_pass; mu
 * (rows) is workspace.  Returns the smallest max |g| seen. */
double mrvi_gram_settle(mrvi_gram *gr, const mrvi_model *m, double *q,
                        double *mu, int max_pass);
/* Its passes for a predictor (a step's turn from q_k: each pass gains
 * about two digits on chains). */
#define MRVI_GRAM_SETTLE_PASSES 8

#endif
