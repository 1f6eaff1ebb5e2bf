/* Holonomic constraints on a model (doc/constraints.md): the registry of
 * constraint types (one const table per file in constraints/), instances, and
 * the checks and projections of initial data. */
#include "model/model.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

extern const mrvi_constraint_type mrvi_constraint_distance;
extern const mrvi_constraint_type mrvi_constraint_fixed;
extern const mrvi_constraint_type mrvi_constraint_plane;
extern const mrvi_constraint_type mrvi_constraint_linear;
extern const mrvi_constraint_type mrvi_constraint_body;
extern const mrvi_constraint_type mrvi_constraint_spherical;
extern const mrvi_constraint_type mrvi_constraint_revolute;
extern const mrvi_constraint_type mrvi_constraint_weld;
extern const mrvi_constraint_type mrvi_constraint_prismatic;
extern const mrvi_constraint_type mrvi_constraint_cylindrical;
extern const mrvi_constraint_type mrvi_constraint_planar;
extern const mrvi_constraint_type mrvi_constraint_point;
extern const mrvi_constraint_type mrvi_constraint_universal;

static const mrvi_constraint_type *const builtin[] = {
    &mrvi_constraint_distance,  &mrvi_constraint_fixed,
    &mrvi_constraint_plane,     &mrvi_constraint_linear,
    &mrvi_constraint_body,      &mrvi_constraint_spherical,
    &mrvi_constraint_revolute,  &mrvi_constraint_weld,
    &mrvi_constraint_prismatic, &mrvi_constraint_cylindrical,
    &mrvi_constraint_planar,    &mrvi_constraint_point,
    &mrvi_constraint_universal,
};

#define N_BUILTIN ((int)(sizeof builtin / sizeof builtin[0]))
#define MAX_USER 64

static const mrvi_constraint_type *user[MAX_USER];
static int n_user = 0;

int mrvi_constraint_type_count(void) { return N_BUILTIN + n_user; }

const mrvi_constraint_type *mrvi_constraint_type_get(int i) {
  if (i < 0 || i >= mrvi_constraint_type_count())
    return NULL;
  return i < N_BUILTIN ? builtin[i] : user[i - N_BUILTIN];
}

const mrvi_constraint_type *mrvi_constraint_type_find(const char *name) {
  if (!name)
    return NULL;
  for (int i = 0; i < mrvi_constraint_type_count(); i++)
    if (strcmp(mrvi_constraint_type_get(i)->name, name) == 0)
      return mrvi_constraint_type_get(i);
  return NULL;
}

int mrvi_constraint_type_register(const mrvi_constraint_type *t) {
  if (!t || !t->name || !t->check || !t->eval)
    return MRVI_EINVAL;
  if (mrvi_constraint_type_find(t->name) || n_user == MAX_USER)
    return MRVI_EINVAL;
  user[n_user++] = t;
  return MRVI_OK;
}

void mrvi_constraint_eval_at(const mrvi_constraint *c, const double *y,
                             double *g, double *G, double *H) {
  c->type->eval(c->n_in, c->n_params, c->params, y, g, G, H);
}

int mrvi_model_add_constraint(mrvi_model *m, const char *type, int n_in,
                              const int *coords, int n_params,
                              const double *params, const char *label) {
  const mrvi_constraint_type *t = mrvi_constraint_type_find(type);
  if (!t) {
    const char *names[N_BUILTIN + MAX_USER];
    const int n = mrvi_constraint_type_count();
    for (int i = 0; i < n; i++)
      names[i] = mrvi_constraint_type_get(i)->name;
    const char *hint = type ? mrvi_closest(type, names, n) : NULL;
    return mrvi_model_fail(m, MRVI_EINVAL, "unknown constraint type '%s'%s%s%s",
                           type ? type : "(null)",
                           hint ? " (did you mean '" : "", hint ? hint : "",
                           hint ? "'?)" : "");
  }
  if (n_in < 1 || !coords)
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: no coordinates", t->name);
  if (n_in > MRVI_MAX_INPUTS)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "%s: at most %d coordinates per constraint", t->name,
                           MRVI_MAX_INPUTS);
  if (n_params < 0 || (n_params > 0 && !params))
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: parameters missing", t->name);
  for (int j = 0; j < n_in; j++) {
    if (coords[j] < 0 || coords[j] >= m->n)
      return mrvi_model_fail(m, MRVI_EINVAL,
                             "%s: coordinate index %d out of range", t->name,
                             coords[j]);
    for (int i = 0; i < j; i++)
      if (coords[i] == coords[j])
        return mrvi_model_fail(m, MRVI_EINVAL,
                               "%s: coordinate '%s' appears twice", t->name,
                               MRVI_CNAME(m, coords[j]));
  }
  char def[300];
  if (!label) {
    mrvi_fmt(def, sizeof def, "%s on %s%s", t->name, MRVI_CNAME(m, coords[0]),
             n_in > 1 ? ", ..." : "");
    label = def;
  }
  mrvi_constraint c = {.type = t,
                       .n_in = n_in,
                       .n_params = n_params,
                       .first_row = m->constraint_rows,
                       .where = MRVI_SLOW};
  c.params = malloc((size_t)(n_params > 0 ? n_params : 1) * sizeof *c.params);
  if (!c.params)
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  if (n_params > 0)
    memcpy(c.params, params, (size_t)n_params * sizeof *c.params);
  /* Parameters not given (NAN) from the initial inputs, then the check. */
  char msg[400];
  double y0[MRVI_MAX_INPUTS];
  for (int j = 0; j < n_in; j++)
    y0[j] = m->q0[coords[j]];
  int st = t->initial
               ? t->initial(n_in, n_params, c.params, y0, msg, sizeof msg)
               : 0;
  if (st < 0) {
    free(c.params);
    return mrvi_model_fail(m, st, "%s: %s", label, msg);
  }
  c.rows = t->check(n_in, n_params, c.params, msg, sizeof msg);
  if (c.rows < 1 || c.rows > n_in) {
    free(c.params);
    if (c.rows < 0)
      return mrvi_model_fail(m, c.rows, "%s", msg);
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "%s: check returned %d rows for %d inputs", t->name,
                           c.rows, n_in);
  }
  c.affine = t->affine && t->affine(n_in, n_params, c.params) == 1;
  for (int j = 0; j < n_in; j++)
    if (m->rate[coords[j]] == MRVI_FAST)
      c.where = MRVI_FAST;
  if (m->n_constraints == m->cap_constraints) {
    const int cap = m->cap_constraints ? 2 * m->cap_constraints : 8;
    mrvi_constraint *p =
        realloc(m->constraints, (size_t)cap * sizeof *m->constraints);
    if (!p) {
      free(c.params);
      return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
    }
    m->constraints = p;
    m->cap_constraints = cap;
  }
  c.label = strdup(label);
  c.in = malloc((size_t)n_in * sizeof *c.in);
  if (!c.label || !c.in) {
    free(c.label);
    free(c.in);
    free(c.params);
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  }
  memcpy(c.in, coords, (size_t)n_in * sizeof *c.in);
  m->constraints[m->n_constraints] = c;
  m->constraint_rows += c.rows;
  if (n_in > m->max_constraint_in)
    m->max_constraint_in = n_in;
  return m->n_constraints++;
}

/* Coordinates of particle i (dimension entries) into in; -1 if invalid. */
static int particle_coords(mrvi_model *m, const char *what, int i, int *in) {
  if (i < 0 || i >= m->n_particles)
    return mrvi_model_fail(m, MRVI_EINVAL, "%s: particle index %d out of range",
                           what, i);
  for (int a = 0; a < m->dimension; a++)
    in[a] = mrvi_particle_first(m, i) + a;
  return MRVI_OK;
}

int mrvi_model_add_distance(mrvi_model *m, int particle_i, int particle_j,
                            double length) {
  int in[6];
  const int d = m->dimension;
  int st;
  if ((st = particle_coords(m, "distance", particle_i, in)) < 0 ||
      (st = particle_coords(m, "distance", particle_j, in + d)) < 0)
    return st;
  if (particle_i == particle_j)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "distance: both ends are particle '%s'",
                           MRVI_PNAME(m, particle_i));
  char label[300];
  mrvi_fmt(label, sizeof label, "distance %s-%s", MRVI_PNAME(m, particle_i),
           MRVI_PNAME(m, particle_j));
  return mrvi_model_add_constraint(m, "distance", 2 * d, in, 1, &length, label);
}

int mrvi_model_add_distance_anchor(mrvi_model *m, int particle_i,
                                   const double *anchor, double length) {
  int in[3];
  const int d = m->dimension;
  int st = particle_coords(m, "distance", particle_i, in);
  if (st < 0)
    return st;
  if (!anchor)
    return mrvi_model_fail(m, MRVI_EINVAL, "distance: anchor is NULL");
  double par[4] = {length};
  for (int a = 0; a < d; a++)
    par[1 + a] = anchor[a];
  char label[300];
  mrvi_fmt(label, sizeof label, "distance %s-anchor",
           MRVI_PNAME(m, particle_i));
  return mrvi_model_add_constraint(m, "distance", d, in, d + 1, par, label);
}

int mrvi_model_add_fixed(mrvi_model *m, int particle_i, const int *axes,
                         const double *position) {
  int all[3], in[3];
  double target[3];
  const int d = m->dimension;
  int st = particle_coords(m, "fixed", particle_i, all);
  if (st < 0)
    return st;
  int n = 0;
  static const char axis_name[] = "xyz";
  char which[8] = "";
  for (int a = 0; a < d; a++)
    if (!axes || axes[a]) {
      in[n] = all[a];
      target[n] = position ? position[a] : NAN; /* NAN: initial */
      which[n] = axis_name[a];
      n++;
    }
  if (n == 0)
    return mrvi_model_fail(m, MRVI_EINVAL, "fixed %s: no axis selected",
                           MRVI_PNAME(m, particle_i));
  char label[300];
  mrvi_fmt(label, sizeof label, "fixed %s%s%s", MRVI_PNAME(m, particle_i),
           n < d ? "." : "", n < d ? which : "");
  return mrvi_model_add_constraint(m, "fixed", n, in, n, target, label);
}

int mrvi_model_add_plane(mrvi_model *m, int particle_i, const double *normal,
                         double offset) {
  int in[3];
  const int d = m->dimension;
  int st = particle_coords(m, "plane", particle_i, in);
  if (st < 0)
    return st;
  if (!normal)
    return mrvi_model_fail(m, MRVI_EINVAL, "plane: normal is NULL");
  double par[4];
  for (int a = 0; a < d; a++)
    par[a] = normal[a];
  par[d] = offset;
  char label[300];
  mrvi_fmt(label, sizeof label, "plane %s", MRVI_PNAME(m, particle_i));
  return mrvi_model_add_constraint(m, "plane", d, in, d + 1, par, label);
}

int mrvi_model_add_linear_constraint(mrvi_model *m, int n_terms,
                                     const int *coords, const double *coef,
                                     double rhs) {
  if (n_terms < 1 || n_terms > MRVI_MAX_INPUTS || !coords || !coef)
    return mrvi_model_fail(m, MRVI_EINVAL,
                           "linear: 1 to %d coordinates required",
                           MRVI_MAX_INPUTS);
  double par[MRVI_MAX_INPUTS + 1];
  for (int j = 0; j < n_terms; j++) {
    if (coords[j] < 0 || coords[j] >= m->n)
      return mrvi_model_fail(m, MRVI_EINVAL,
                             "linear: coordinate index %d out of range",
                             coords[j]);
    par[j] = coef[j];
  }
  par[n_terms] = rhs; /* NAN: initial */
  char label[300];
  mrvi_fmt(label, sizeof label, "linear on %s%s", MRVI_CNAME(m, coords[0]),
           n_terms > 1 ? ", ..." : "");
  return mrvi_model_add_constraint(m, "linear", n_terms, coords, n_terms + 1,
                                   par, label);
}

int mrvi_model_set_constraint_label(mrvi_model *m, int c, const char *label) {
  if (c < 0 || c >= m->n_constraints || !label)
    return mrvi_model_fail(m, MRVI_EINVAL, "constraint index %d out of range",
                           c);
  char *copy = strdup(label);
  if (!copy)
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  free(m->constraints[c].label);
  m->constraints[c].label = copy;
  return MRVI_OK;
}

int mrvi_model_n_constraints(const mrvi_model *m) { return m->n_constraints; }
int mrvi_model_constraint_rows(const mrvi_model *m) {
  return m->constraint_rows;
}
static const mrvi_constraint *get(const mrvi_model *m, int c) {
  return c >= 0 && c < m->n_constraints ? &m->constraints[c] : NULL;
}
const char *mrvi_model_constraint_label(const mrvi_model *m, int c) {
  return get(m, c) ? get(m, c)->label : NULL;
}
const char *mrvi_model_constraint_type_name(const mrvi_model *m, int c) {
  return get(m, c) ? get(m, c)->type->name : NULL;
}
int mrvi_model_constraint_n_rows(const mrvi_model *m, int c) {
  return get(m, c) ? get(m, c)->rows : 0;
}
mrvi_rate mrvi_model_constraint_where(const mrvi_model *m, int c) {
  return get(m, c) ? get(m, c)->where : MRVI_SLOW;
}
int mrvi_model_constraint_affine(const mrvi_model *m, int c) {
  return get(m, c) ? get(m, c)->affine : 0;
}

int mrvi_model_describe_constraint(const mrvi_model *m, int c, char *buf,
                                   size_t len) {
  const mrvi_constraint *k = get(m, c);
  if (!k)
    return MRVI_EINVAL;
  char par[200] = "";
  size_t used = 0;
  for (int i = 0; i < k->n_params && used + 24 < sizeof par; i++)
    used += (size_t)snprintf(par + used, sizeof par - used, "%s%.6g",
                             i ? ", " : "", k->params[i]);
  mrvi_fmt(buf, len, "%s (%s; %d row%s; parameters %s) at %s", k->label,
           k->type->name, k->rows, k->rows == 1 ? "" : "s", par,
           k->where == MRVI_FAST ? "every micro node" : "macro nodes");
  return MRVI_OK;
}

/* Inputs of constraint k at q (model order). */
static void gather_q(const mrvi_constraint *k, const double *q, double *y) {
  for (int j = 0; j < k->n_in; j++)
    y[j] = q[k->in[j]];
}

void mrvi_model_constraint_eval(const mrvi_model *m, const double *q, double *g,
                                double *G) {
  double y[MRVI_MAX_INPUTS], Gl[MRVI_MAX_INPUTS * MRVI_MAX_INPUTS];
  if (G)
    memset(G, 0, (size_t)m->constraint_rows * (size_t)m->n * sizeof *G);
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    gather_q(k, q, y);
    mrvi_constraint_eval_at(k, y, g + k->first_row, Gl, NULL);
    if (G)
      for (int r = 0; r < k->rows; r++)
        for (int j = 0; j < k->n_in; j++)
          G[(size_t)(k->first_row + r) * (size_t)m->n + (size_t)k->in[j]] +=
              Gl[r * k->n_in + j];
  }
}

double mrvi_model_hidden_residual(const mrvi_model *m, const double *q,
                                  const double *p) {
  double y[MRVI_MAX_INPUTS], g[MRVI_MAX_INPUTS],
      Gl[MRVI_MAX_INPUTS * MRVI_MAX_INPUTS];
  double worst = 0.0;
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    gather_q(k, q, y);
    mrvi_constraint_eval_at(k, y, g, Gl, NULL);
    for (int r = 0; r < k->rows; r++) {
      double s = 0.0;
      for (int j = 0; j < k->n_in; j++)
        s += Gl[r * k->n_in + j] * p[k->in[j]] / MRVI_MASS(m, k->in[j]);
      worst = fmax(worst, fabs(s));
    }
  }
  return worst;
}

int mrvi_constraints_check_positions(const mrvi_model *m, const double *q,
                                     double tol, const char *what, int *worst,
                                     char *msg, size_t len) {
  double y[MRVI_MAX_INPUTS], g[MRVI_MAX_INPUTS],
      Gl[MRVI_MAX_INPUTS * MRVI_MAX_INPUTS];
  int w = -1;
  double wv = 0.0;
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    gather_q(k, q, y);
    mrvi_constraint_eval_at(k, y, g, Gl, NULL);
    for (int r = 0; r < k->rows; r++)
      if (!(fabs(g[r]) <= wv)) {
        wv = fabs(g[r]);
        w = c;
      }
  }
  if (worst)
    *worst = w;
  if (w >= 0 && !(wv <= tol))
    return mrvi_fail(msg, len, MRVI_EMODEL,
                     "%s violate constraint '%s': |g| = %.3e exceeds the "
                     "tolerance %.3e",
                     what, m->constraints[w].label, wv, tol);
  return MRVI_OK;
}

int mrvi_model_check_initial_positions(mrvi_model *m, double tol, int *worst) {
  return mrvi_constraints_check_positions(m, m->q0, tol, "initial positions",
                                          worst, m->errmsg, sizeof m->errmsg);
}

/* Constraint owning row r. */
static int constraint_of_row(const mrvi_model *m, int r) {
  for (int c = 0; c < m->n_constraints; c++)
    if (r < m->constraints[c].first_row + m->constraints[c].rows)
      return c;
  return m->n_constraints - 1;
}

/* Message for redundant row r = sum_l (-t_l) row_l over earlier rows:
 * the constraints involved, and what to do in the multiplier form. */
static void name_dependency(const mrvi_model *m, int r, const double *t, int R,
                            char *msg, size_t len) {
  char names[400] = "";
  size_t used = 0;
  int count = 0, last = -1;
  double tmax = 0.0;
  (void)R;
  for (int l = 0; l < r; l++)
    tmax = fmax(tmax, fabs(t[l]));
  for (int l = 0; l <= r; l++) {
    if (l < r && !(fabs(t[l]) > 1e-8 * tmax))
      continue;
    const int c = constraint_of_row(m, l);
    if (c == last)
      continue;
    int seen = 0;
    for (int l2 = 0; l2 < l; l2++)
      if (fabs(t[l2]) > 1e-8 * tmax && constraint_of_row(m, l2) == c)
        seen = 1;
    if (seen)
      continue;
    last = c;
    if (used + 8 < sizeof names)
      used += (size_t)snprintf(names + used, sizeof names - used, "%s'%s'",
                               count ? ", " : "", m->constraints[c].label);
    count++;
  }
  mrvi_fail(msg, len, MRVI_ESINGULAR,
            count > 1
                ? "redundant constraints: the gradients of %s are linearly "
                  "dependent; the multiplier form needs independent rows: "
                  "remove one of them (a non-redundant joint set), model a "
                  "planar mechanism in 2-D, or use "
                  "integrator.constraints.form: null-space, which handles "
                  "redundant rows"
                : "constraint %s has a zero gradient (it is redundant or "
                  "degenerate here)",
            names);
}

int mrvi_model_check_independent(mrvi_model *m, const double *q) {
  return mrvi_constraints_independent(m, q, m->errmsg, sizeof m->errmsg);
}

/* Rank-revealing pass over the rows of G(q) in model order (modified
 * Gram-Schmidt twice, in the metric M^-1): a row within 1e-9 (relative) of
 * the span of the earlier rows is redundant.  drop (rows, may be NULL) gets
 * 1 for those; msg names the constraints of the first dependency.  Returns
 * the number of redundant rows, or MRVI_ENOMEM. */
/* 1 if the sparse Cholesky of the Gram matrix at q proves the rows
 * independent (O(R) for chains and trees; constraint_gram.c). */
static int gram_independent(const mrvi_model *m, const double *q) {
  mrvi_gram *gr = NULL;
  if (mrvi_gram_create(m, &gr) != MRVI_OK)
    return 0;
  const int ok = mrvi_gram_factor(gr, m, q) == MRVI_OK;
  mrvi_gram_free(gr);
  return ok;
}

int mrvi_constraints_rank(const mrvi_model *m, const double *q,
                          unsigned char *drop, char *msg, size_t len) {
  const int R = m->constraint_rows, n = m->n;
  if (drop)
    memset(drop, 0, (size_t)R);
  /* No redundant row where the Gram factor proves it (its pivot test,
   * a remainder above 1e-6 relative, is stricter than the 1e-9 below);
   * the dense pass costs O(R^2 n). */
  if (R == 0 || gram_independent(m, q))
    return 0;
  double *g = malloc((size_t)R * sizeof *g);
  double *G = malloc((size_t)R * (size_t)n * sizeof *G);
  /* Orthonormal basis E (rank x n) of the rows seen so far, in the metric
   * M^-1, and T (rank x R) writing each basis row in the original rows. */
  double *E = malloc((size_t)R * (size_t)n * sizeof *E);
  double *T = calloc((size_t)R * (size_t)R, sizeof *T);
  double *v = malloc((size_t)n * sizeof *v);
  double *t = malloc((size_t)R * sizeof *t);
  if (!g || !G || !E || !T || !v || !t) {
    free(g), free(G), free(E), free(T), free(v), free(t);
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  }
  mrvi_model_constraint_eval(m, q, g, G);
  int rank = 0, redundant = 0;
  for (int r = 0; r < R; r++) {
    double norm0 = 0.0;
    for (int j = 0; j < n; j++) {
      v[j] = G[(size_t)r * n + j] / sqrt(MRVI_MASS(m, j));
      norm0 += v[j] * v[j];
    }
    norm0 = sqrt(norm0);
    memset(t, 0, (size_t)R * sizeof *t);
    t[r] = 1.0;
    /* Two passes of modified Gram-Schmidt. */
    for (int pass = 0; pass < 2; pass++)
      for (int b = 0; b < rank; b++) {
        double s = 0.0;
        for (int j = 0; j < n; j++)
          s += E[(size_t)b * n + j] * v[j];
        for (int j = 0; j < n; j++)
          v[j] -= s * E[(size_t)b * n + j];
        for (int l = 0; l < R; l++)
          t[l] -= s * T[(size_t)b * R + l];
      }
    double norm = 0.0;
    for (int j = 0; j < n; j++)
      norm += v[j] * v[j];
    norm = sqrt(norm);
    if (norm <= 1e-9 * norm0 || norm0 == 0.0) {
      if (drop)
        drop[r] = 1;
      if (redundant++ == 0)
        name_dependency(m, r, t, R, msg, len);
      continue;
    }
    for (int j = 0; j < n; j++)
      E[(size_t)rank * n + j] = v[j] / norm;
    for (int l = 0; l < R; l++)
      T[(size_t)rank * R + l] = t[l] / norm;
    rank++;
  }
  free(g), free(G), free(E), free(T), free(v), free(t);
  return redundant;
}

int mrvi_constraints_independent(const mrvi_model *m, const double *q,
                                 char *msg, size_t len) {
  if (m->constraint_rows == 0)
    return MRVI_OK;
  /* The sparse Cholesky of the Gram matrix proves independence in O(R)
   * for chains and trees; where it cannot, the rank-revealing pass decides
   * and names the dependent constraints. */
  const int st = mrvi_constraints_rank(m, q, NULL, msg, len);
  return st > 0 ? MRVI_ESINGULAR : st;
}

/* mu (rows) = (G_k M^-1 G_k^T)^-1 b_k over the rows k that drop (may be
 * NULL) keeps, 0 on the others; G (rows x n) at q, A workspace (rows x
 * rows).  MRVI_ESINGULAR if the kept rows are dependent. */
static int solve_kept(const mrvi_model *m, const double *G,
                      const unsigned char *drop, const double *b, double *A,
                      double *mu) {
  const int R = m->constraint_rows, n = m->n;
  int k = 0;
  for (int a = 0; a < R; a++) {
    if (drop && drop[a])
      continue;
    mu[k] = b[a];
    int l = 0; /* symmetric: lower triangle mirrored */
    for (int c = 0; c <= a; c++) {
      if (drop && drop[c])
        continue;
      double t = 0.0;
      for (int j = 0; j < n; j++)
        t += G[(size_t)a * n + j] * G[(size_t)c * n + j] / MRVI_MASS(m, j);
      A[k * R + l] = A[l * R + k] = t;
      l++;
    }
    k++;
  }
  /* Compact to k x k and solve. */
  for (int a = 0; a < k; a++)
    memmove(A + a * k, A + a * R, (size_t)k * sizeof *A);
  if (mrvi_dense_solve(k, A, mu) < 0)
    return MRVI_ESINGULAR;
  for (int a = R - 1; a >= 0; a--)
    mu[a] = drop && drop[a] ? 0.0 : mu[--k];
  return MRVI_OK;
}

int mrvi_constraints_project(const mrvi_model *m, const double *q, double *p,
                             const unsigned char *drop, double *g, double *G,
                             double *A, double *mu) {
  const int R = m->constraint_rows, n = m->n;
  mrvi_model_constraint_eval(m, q, g, G);
  /* (G M^-1 G^T) mu = G M^-1 p over the kept rows */
  for (int a = 0; a < R; a++) {
    double s = 0.0;
    for (int j = 0; j < n; j++)
      s += G[(size_t)a * n + j] * p[j] / MRVI_MASS(m, j);
    g[a] = s;
  }
  if (solve_kept(m, G, drop, g, A, mu) < 0)
    return MRVI_ESINGULAR;
  for (int j = 0; j < n; j++)
    for (int a = 0; a < R; a++)
      p[j] -= G[(size_t)a * n + j] * mu[a];
  return MRVI_OK;
}

/* v0 <- M^-1 p; *correction (may be NULL) gets the largest change. */
static void store_velocities(mrvi_model *m, const double *p,
                             double *correction) {
  double worst = 0.0;
  for (int j = 0; j < m->n; j++) {
    const double v = p[j] / MRVI_MASS(m, j);
    worst = fmax(worst, fabs(v - m->v0[j]));
    m->v0[j] = v;
  }
  if (correction)
    *correction = worst;
}

/* Names of the constraints with |g(q)| > tol, quoted, into buf. */
static void name_violated(const mrvi_model *m, const double *q, double tol,
                          char *buf, size_t len) {
  double y[MRVI_MAX_INPUTS], g[MRVI_MAX_INPUTS],
      Gl[MRVI_MAX_INPUTS * MRVI_MAX_INPUTS];
  size_t used = 0;
  buf[0] = 0;
  for (int c = 0; c < m->n_constraints && used + 8 < len; c++) {
    const mrvi_constraint *k = &m->constraints[c];
    gather_q(k, q, y);
    mrvi_constraint_eval_at(k, y, g, Gl, NULL);
    double w = 0.0;
    for (int r = 0; r < k->rows; r++)
      w = fmax(w, fabs(g[r]));
    if (w > tol)
      used += (size_t)snprintf(buf + used, len - used, "%s'%s'",
                               used ? ", " : "", k->label);
  }
}

int mrvi_constraints_project_positions(const mrvi_model *m, double *q,
                                       double tol, double *change, int *worst,
                                       char *msg, size_t len) {
  const int R = m->constraint_rows, n = m->n;
  *change = 0.0;
  int st =
      mrvi_constraints_check_positions(m, q, tol, "positions", worst, msg, len);
  if (st == MRVI_OK || R == 0)
    return MRVI_OK;
  double *q0 = malloc((size_t)n * sizeof *q0);
  double *g = malloc((size_t)R * sizeof *g);
  double *G = malloc((size_t)R * (size_t)n * sizeof *G);
  double *A = malloc((size_t)R * (size_t)R * sizeof *A);
  double *mu = malloc((size_t)R * sizeof *mu);
  unsigned char *drop = malloc((size_t)R);
  if (!q0 || !g || !G || !A || !mu || !drop) {
    free(q0), free(g), free(G), free(A), free(mu), free(drop);
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  }
  memcpy(q0, q, (size_t)n * sizeof *q0);
  double size = 1.0;
  for (int j = 0; j < n; j++)
    size = fmax(size, fabs(q0[j]));
  const double limit = MRVI_PROJECT_POSITIONS_MAX * size;
  /* Newton on g with the minimum-norm correction in the metric M:
   * dq = -M^-1 G_k^T (G_k M^-1 G_k^T)^-1 g_k over the rows k that the
   * rank-revealing pass keeps (the others follow on the manifold). */
  double gmax = HUGE_VAL, prev = HUGE_VAL;
  int it = 0, ok = 0;
  for (; it < 30; it++) {
    char why[8];
    const int red = mrvi_constraints_rank(m, q, drop, why, sizeof why);
    if (red < 0) {
      st = red;
      break;
    }
    mrvi_model_constraint_eval(m, q, g, G);
    gmax = 0.0;
    for (int a = 0; a < R; a++)
      gmax = fmax(gmax, fabs(g[a]));
    if (gmax <= 1e-2 * tol || (gmax <= tol && gmax > 0.5 * prev)) {
      ok = 1;
      break;
    }
    if (!(gmax < HUGE_VAL) || solve_kept(m, G, drop, g, A, mu) < 0)
      break;
    for (int j = 0; j < n; j++) {
      double s = 0.0;
      for (int a = 0; a < R; a++)
        s += G[(size_t)a * n + j] * mu[a];
      q[j] -= s / MRVI_MASS(m, j);
    }
    prev = gmax;
  }
  for (int j = 0; j < n; j++)
    *change = fmax(*change, fabs(q[j] - q0[j]));
  if (st == MRVI_ENOMEM) {
    mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  } else if (!ok || !(*change <= limit)) {
    /* At q0: the worst constraint with its |g|, then every one off. */
    char names[300], head[200];
    int w = -1;
    mrvi_constraints_check_positions(m, q0, tol, "initial positions", &w, head,
                                     sizeof head);
    if (worst)
      *worst = w;
    name_violated(m, q0, tol, names, sizeof names);
    st = !ok ? mrvi_fail(msg, len, MRVI_EMODEL,
                         "%s, and Newton on the constraints did not project "
                         "the positions onto them (off: %s)",
                         head, names)
             : mrvi_fail(msg, len, MRVI_EMODEL,
                         "%s, and projecting the positions onto the "
                         "constraints would move a coordinate by %.3e, more "
                         "than %.3e (%g times the largest coordinate, at "
                         "least 1; off: %s)",
                         head, *change, limit, MRVI_PROJECT_POSITIONS_MAX,
                         names);
    memcpy(q, q0, (size_t)n * sizeof *q0);
  } else {
    st = MRVI_OK;
  }
  free(q0), free(g), free(G), free(A), free(mu), free(drop);
  return st;
}

int mrvi_model_project_velocities(mrvi_model *m, double *correction) {
  const int R = m->constraint_rows, n = m->n;
  if (correction)
    *correction = 0.0;
  if (R == 0)
    return MRVI_OK;
  int st = MRVI_OK;
  if (R > MRVI_GRAM_DENSE_MAX) {
    /* Sparse: p0 = M v0 projected, the velocities read back.  Where the
     * rows are dependent (redundant rows of a closed loop in the null-space
     * form) the factorisation fails and the dense projection below, which
     * leaves those rows out, takes over. */
    mrvi_gram *gr = NULL;
    double *p = malloc((size_t)n * sizeof *p);
    double *mu = malloc((size_t)R * sizeof *mu);
    if (!p || !mu || mrvi_gram_create(m, &gr) < 0) {
      free(p), free(mu);
      return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
    }
    const int sparse_ok = mrvi_gram_factor(gr, m, m->q0) == MRVI_OK;
    if (sparse_ok) {
      for (int j = 0; j < n; j++)
        p[j] = MRVI_MASS(m, j) * m->v0[j];
      mrvi_gram_project(gr, m, p, mu);
      store_velocities(m, p, correction);
    }
    mrvi_gram_free(gr);
    free(p), free(mu);
    if (sparse_ok)
      return MRVI_OK;
  }
  double *g = malloc((size_t)R * sizeof *g);
  double *G = malloc((size_t)R * (size_t)n * sizeof *G);
  double *A = malloc((size_t)R * (size_t)R * sizeof *A);
  double *mu = malloc((size_t)R * sizeof *mu);
  double *p = malloc((size_t)n * sizeof *p);
  unsigned char *drop = malloc((size_t)R);
  if (!g || !G || !A || !mu || !p || !drop ||
      mrvi_constraints_rank(m, m->q0, drop, m->errmsg, sizeof m->errmsg) < 0) {
    free(g), free(G), free(A), free(mu), free(p), free(drop);
    return mrvi_model_fail(m, MRVI_ENOMEM, "out of memory");
  }
  /* Project p0 = M v0 onto the tangent space of the independent rows (the
   * redundant ones add nothing to it) and read the velocities back. */
  for (int j = 0; j < n; j++)
    p[j] = MRVI_MASS(m, j) * m->v0[j];
  if (mrvi_constraints_project(m, m->q0, p, drop, g, G, A, mu) < 0) {
    st = mrvi_model_fail(m, MRVI_ESINGULAR,
                         "constraint gradients are dependent");
  } else {
    store_velocities(m, p, correction);
  }
  free(g), free(G), free(A), free(mu), free(p), free(drop);
  return st;
}

int mrvi_model_project_positions(mrvi_model *m, double tol, double *correction,
                                 int *worst) {
  double change = 0.0;
  const int st = mrvi_constraints_project_positions(
      m, m->q0, tol, &change, worst, m->errmsg, sizeof m->errmsg);
  if (correction)
    *correction = change;
  return st;
}
