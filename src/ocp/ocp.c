/* MDMOC problem: actuators, objective, terminal conditions and forward
 * shooting through the one-step map with control forces (see ocp.h).
 *
 * Discrete forces (virtual work of a piecewise-constant force u along the
 * linearly interpolated path of its coordinate, integrated exactly; the
 * hat function of node j on the coordinate's grid weights u):
 *   same grid, interval of length h:   f^- = f^+ = (h/2) u
 *   slow coordinate, fast actuator (u_m on micro interval m of a macro
 *   step, dt = dT/p):  f^- = sum_m dt (1 - (m + 1/2)/p) u_m,
 *                      f^+ = sum_m dt (m + 1/2)/p u_m
 *   fast coordinate, slow actuator (u on the whole macro step): every
 *   micro interval m gets f^- = f^+ = (dt/2) u.
 * Forces on interior fast nodes add up from both neighbouring intervals;
 * f^- of the step enters the residual rows of eq:DEL_ini, f^+ the momenta
 * p_{k+1}. */
#include "ocp/ocp_internal.h"

#include <float.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int mrvi_ocp_fail(mrvi_ocp *o, int status, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  mrvi_vfmt(o->errmsg, sizeof o->errmsg, fmt, ap);
  va_end(ap);
  return status;
}

const char *mrvi_ocp_errmsg(const mrvi_ocp *o) {
  return o ? o->errmsg : "no optimal control problem";
}

static double *dalloc(size_t n) {
  return calloc(n > 0 ? n : 1, sizeof(double));
}

/* Sizes of the problem against int indexing and the machine's memory,
 * before anything is allocated: the trajectory (N + 1) n_s + (N p + 1) n_f
 * nodes with momenta and outputs, and the adjoint's dense step Jacobian of
 * nv = 2 n_s + (p + 1) n_f + (multipliers) rows where it takes one
 * (tuning.adjoint_dense_max; beyond, its sparse rows are of the size of
 * the step's own Jacobian). */
static int ocp_check_sizes(const mrvi_model *m, const mrvi_settings *s,
                           char *msg, size_t len) {
  const double N = (double)mrvi_settings_n_steps(s), p = s->micro_steps;
  const double ns = m->n_slow, nf = m->n_fast, n = m->n;
  double r_slow = 0.0, r_micro = 0.0;
  for (int c = 0; c < m->n_constraints; c++)
    *(m->constraints[c].where == MRVI_SLOW ? &r_slow : &r_micro) +=
        m->constraints[c].rows;
  const double nl = r_slow + p * r_micro, nz = 2.0 * ns + (p + 1.0) * nf;
  const double nv = nz + nl, nodes = (N + 1.0) * ns + (N * p + 1.0) * nf;
  if (nv > INT_MAX || N * p > INT_MAX)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "the optimal control problem is too large: N × p = %.0f "
                     "× %.0f micro steps and %.0f unknowns per step "
                     "(at most %d each)",
                     N, p, nv, INT_MAX);
  /* doubles: step vectors, trajectory, momenta, outputs, multipliers,
   * the adjoint's Jacobian and workspace (one functional) */
  const double words =
      6.0 * nv + 4.0 * nodes + (N + 1.0) * (ns + 3.0 * nf) +
      N * p * (nf + 1.0) + 2.0 * (N + 1.0) * n + N * nl +
      (nv <= s->tuning.adjoint_dense_max ? 2.5 * nv * nv : 0.0);
  const double need = 8.0 * words, have = mrvi_machine_memory();
  if (have > 0 && need > have)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "the optimal control problem needs about %.3g GiB "
                     "(N = %.0f macro steps, p = %.0f micro steps, n_f = %.0f "
                     "fast coordinates, %.0f step variables), more than this "
                     "machine's %.3g GiB",
                     need / 1073741824.0, N, p, nf, nv, have / 1073741824.0);
  return MRVI_OK;
}

int mrvi_ocp_create(const mrvi_model *m, const mrvi_settings *s, mrvi_ocp **out,
                    char *msg, size_t len) {
  *out = NULL;
  int st = mrvi_integrator_check_inputs(m, s, msg, len);
  if (st < 0)
    return st;
  if (m->n_constraints > 0) {
    st = mrvi_constraints_check_positions(m, m->q0, s->constraint_tol,
                                          "initial positions", NULL, msg, len);
    if (st < 0)
      return st;
  }
  char why[300];
  if ((st = ocp_check_sizes(m, s, why, sizeof why)) < 0) {
    mrvi_fmt(msg, len, "%s", why);
    return st;
  }
  mrvi_ocp *o = calloc(1, sizeof *o);
  if (!o) {
    mrvi_fmt(msg, len, "out of memory");
    return MRVI_ENOMEM;
  }
  o->model = m;
  o->settings = *s;
  o->N = mrvi_settings_n_steps(s);
  o->p = s->micro_steps;
  o->ns = m->n_slow;
  o->nf = m->n_fast;
  o->nz = 2 * o->ns + (o->p + 1) * o->nf;
  o->n_nodes = (o->N + 1) * o->ns + (o->N * o->p + 1) * o->nf;
  o->algorithm = MRVI_OCP_SLSQP;
  o->ftol_rel = 1e-12;
  o->terminal_tol = 1e-8;
  o->max_eval = 2000;
  *out = o;
  return MRVI_OK;
}

int ocp_path(const mrvi_ocp *o, char *why, size_t len) {
  const int path = mrvi_sweep_path(o->model, &o->settings, why, len);
  /* The state actuators' forces depend on the positions (the step hook
   * mrvi_step.extra): the Newton paths on the CSC assembly take them into
   * their blocks (schur from its CSC fallback), their entries those of an
   * element on the same coordinates at the micro intervals' midpoints;
   * the sweeps and schur-krylov's outer iteration assemble no Jacobian. */
  if (o->n_state == 0 || path == MRVI_PATH_GENERAL || path == MRVI_PATH_SCHUR ||
      path == MRVI_PATH_SCHUR_BORDERED)
    return path;
  mrvi_fmt(why, len,
           "pair actuators (or actuators on bodies) on the %s path: their "
           "forces depend on the positions, which only the Newton paths "
           "general, schur and schur-bordered assemble",
           mrvi_path_name(path));
  return MRVI_PATH_GENERAL;
}

const char *mrvi_ocp_solver_path(const mrvi_ocp *o, char *why, size_t len) {
  const int path = ocp_path(o, why, len);
  if (path == MRVI_PATH_GENERAL && o->settings.solver == MRVI_SOLVER_STRUCTURED)
    return NULL;
  return mrvi_path_name(path);
}

/* The step and the trajectory buffers, at the first forward pass: a
 * problem that is only described (the loader's check, `mrvi check`)
 * allocates nothing proportional to N or p. */
int ocp_alloc(mrvi_ocp *o) {
  if (o->allocated)
    return MRVI_OK;
  const mrvi_model *m = o->model;
  if (mrvi_step_init(&o->step, m, &o->settings) < 0)
    goto oom;
  o->nl = o->step.n_lambda;
  o->nv = o->nz + o->nl;
  const size_t nu = (size_t)o->step.n_total, n = (size_t)m->n,
               N1 = (size_t)o->N + 1;
  o->x = dalloc(nu);
  o->R = dalloc(nu);
  o->dx = dalloc(nu);
  o->f_rows = dalloc(nu);
  o->f_end = dalloc(2 * (size_t)(o->ns + o->nf));
  o->ps1 = dalloc((size_t)o->ns);
  o->pf1 = dalloc((size_t)o->p * (size_t)o->nf);
  o->Q = dalloc((size_t)o->n_nodes);
  o->pN = dalloc((size_t)(o->ns + o->nf));
  o->ps_k = dalloc(N1 * (size_t)o->ns);
  o->pf_k = dalloc(N1 * (size_t)o->nf);
  o->pf_micro = dalloc(((size_t)o->N * (size_t)o->p + 1) * (size_t)o->nf);
  o->f_plus = dalloc(2 * (size_t)o->p * (size_t)o->nf);
  o->cres_micro = dalloc((size_t)o->N * (size_t)o->p);
  o->q_out = dalloc(N1 * n);
  o->p_out = dalloc(N1 * n);
  o->n_torsion = mrvi_model_n_torsions(m);
  o->branch = dalloc(N1 * (size_t)o->n_torsion);
  o->Lam = dalloc((size_t)o->N * (size_t)o->nl);
  o->rhs_ns = dalloc((size_t)o->step.n_unknowns);
  o->p0 = dalloc(n);
  if (!o->p0 || !o->x || !o->R || !o->dx || !o->f_rows || !o->f_end ||
      !o->ps1 || !o->pf1 || !o->Q || !o->pN || !o->ps_k || !o->pf_k ||
      !o->pf_micro || !o->f_plus || !o->cres_micro || !o->q_out || !o->p_out ||
      !o->Lam || !o->rhs_ns || !o->branch)
    goto oom;
  o->f_end_c = o->f_end + o->ns + o->nf;
  o->f_plus_c = o->f_plus + (size_t)o->p * (size_t)o->nf;
  o->step.f_rows = o->f_rows;
  o->step.f_end = o->f_end;
  if (o->n_state > 0) {
    o->step.extra = ocp_state_hook;
    o->step.extra_ctx = o;
  }
  o->allocated = 1;
  return MRVI_OK;
oom:
  return mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
}

void ocp_adjoint_free(mrvi_ocp *o) {
  double **d[] = {&o->r,        &o->mu,         &o->rhs,    &o->sol,
                  &o->Ak,       &o->h_val,      &o->H,      &o->pv,
                  &o->adj_work, &o->adj_blocks, &o->bd_work};
  for (size_t i = 0; i < sizeof d / sizeof *d; i++) {
    free(*d[i]);
    *d[i] = NULL;
  }
  mrvi_skrylov_free(o->skrylov);
  o->skrylov = NULL;
  mrvi_bordered_free(o->bordered);
  o->bordered = NULL;
  o->bd_factored = 0;
  for (int c = 0; c < 2; c++) {
    mrvi_terms_free(o->adj_terms[c]);
    o->adj_terms[c] = NULL;
  }
  o->adj_explicit = 0;
  ocp_forest_free(o->adj_forest);
  o->adj_forest = NULL;
  free(o->gz);
  free(o->act_kept);
  o->act_kept = NULL;
  o->n_act_kept = 0;
  free(o->h_of_a);
  free(o->h_ptr);
  free(o->h_col);
  free(o->h_slot);
  o->h_slot = NULL;
  o->n_h_slot = o->h_slot_cap = 0;
  o->gz = NULL;
  o->h_of_a = NULL;
  o->h_ptr = NULL;
  o->h_col = NULL;
  o->h_sparse = 0;
  o->nfun_alloc = 0;
}

void mrvi_ocp_free(mrvi_ocp *o) {
  if (!o)
    return;
  mrvi_newton_free(o->newton);
  mrvi_nullspace_free(o->nullspace);
  mrvi_newton_free(o->newton_full);
  mrvi_integrator_free(o->integ);
  free(o->p0);
  mrvi_step_free(&o->step);
  free(o->Lam);
  free(o->rhs_ns);
  free(o->act);
  free(o->trk);
  free(o->term);
  free(o->force);
  free(o->x);
  free(o->R);
  free(o->dx);
  free(o->f_rows);
  free(o->f_end);
  free(o->ps1);
  free(o->pf1);
  free(o->Q);
  free(o->pN);
  free(o->ps_k);
  free(o->pf_k);
  free(o->pf_micro);
  free(o->f_plus);
  free(o->cres_micro);
  free(o->q_out);
  free(o->p_out);
  free(o->branch);
  ocp_adjoint_free(o);
  free(o);
}

static int check_coord(mrvi_ocp *o, int c) {
  if (c < 0 || c >= o->model->n)
    return mrvi_ocp_fail(o, MRVI_EINVAL, "coordinate index %d out of range", c);
  return MRVI_OK;
}

/* Append one entry to the force template. */
static int push_force(mrvi_ocp *o, int z, int act, int j, int plus,
                      double coef) {
  ocp_force *f = realloc(o->force, (size_t)(o->n_force + 1) * sizeof *f);
  if (!f)
    return MRVI_ENOMEM;
  o->force = f;
  o->force[o->n_force++] = (ocp_force){z, act, j, plus, coef};
  return MRVI_OK;
}

int mrvi_ocp_add_actuator(mrvi_ocp *o, int c, mrvi_grid grid, double weight,
                          double lower, double upper) {
  int st = check_coord(o, c);
  if (st < 0)
    return st;
  if (!(weight > 0.0) || !isfinite(weight))
    return mrvi_ocp_fail(o, MRVI_EINVAL, "actuator weight must be > 0");
  if (!(lower <= upper))
    return mrvi_ocp_fail(o, MRVI_EINVAL, "actuator bounds: lower %g > upper %g",
                         lower, upper);
  const int per = grid == MRVI_GRID_MACRO ? 1 : o->p;
  if ((double)o->n_u + (double)o->N * per > INT_MAX)
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "too many controls: %d so far and %ld more for this "
                         "actuator (at most %d)",
                         o->n_u, o->N * per, INT_MAX);
  ocp_actuator *a = realloc(o->act, (size_t)(o->n_act + 1) * sizeof *a);
  if (!a)
    return mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
  o->act = a;
  const int ia = o->n_act++;
  o->act[ia] = (ocp_actuator){.coord = c,
                              .pi = -1,
                              .pj = -1,
                              .body = -1,
                              .joint = -1,
                              .grid = grid,
                              .weight = weight,
                              .lower = lower,
                              .upper = upper,
                              .offset = o->n_u,
                              .size = (int)(o->N * per)};
  mrvi_fmt(o->act[ia].name, sizeof o->act[ia].name, "%s",
           MRVI_CNAME(o->model, c));
  o->n_u += o->act[ia].size;
  /* Force template of one step (virtual work, see the file comment). */
  const mrvi_model *m = o->model;
  const int s = m->slot[c], ns = o->ns, nf = o->nf, p = o->p;
  const double dT = o->settings.macro_step, dt = dT / p;
  if (m->rate[c] == MRVI_SLOW) {
    if (grid == MRVI_GRID_MACRO) {
      st |= push_force(o, s, ia, 0, 0, 0.5 * dT);
      st |= push_force(o, ns + s, ia, 0, 1, 0.5 * dT);
    } else {
      for (int mm = 0; mm < p; mm++) {
        const double th = (mm + 0.5) / p;
        st |= push_force(o, s, ia, mm, 0, dt * (1.0 - th));
        st |= push_force(o, ns + s, ia, mm, 1, dt * th);
      }
    }
  } else {
    for (int mm = 0; mm < p; mm++) {
      const int j = grid == MRVI_GRID_MACRO ? 0 : mm;
      st |= push_force(o, 2 * ns + mm * nf + s, ia, j, 0, 0.5 * dt);
      st |= push_force(o, 2 * ns + (mm + 1) * nf + s, ia, j, 1, 0.5 * dt);
    }
  }
  if (st < 0)
    return mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
  return ia;
}

int mrvi_ocp_add_pair_actuator(mrvi_ocp *o, int pi, int pj, mrvi_grid grid,
                               double weight, double lower, double upper) {
  const mrvi_model *m = o->model;
  if (m->dimension < 1 || pi < 0 || pj < 0 || pi >= m->n_particles ||
      pj >= m->n_particles)
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "pair actuator: particle index out "
                         "of range (the model has %d)",
                         m->n_particles);
  if (pi == pj)
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "pair actuator: particle '%s' given twice",
                         MRVI_PNAME(m, pi));
  if (o->ready)
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "pair actuators must be added before the first "
                         "evaluation");
  /* The coordinate actuator's bookkeeping (sizes, bounds, weight) without
   * its force template: add one on particle i and drop the template
   * entries it pushed. */
  const int n_force = o->n_force;
  const int ia = mrvi_ocp_add_actuator(o, mrvi_particle_first(m, pi), grid,
                                       weight, lower, upper);
  if (ia < 0)
    return ia;
  o->n_force = n_force;
  o->act[ia].pi = pi;
  o->act[ia].pj = pj;
  const int d = m->dimension;
  o->act[ia].n_in = 2 * d;
  for (int k = 0; k < d; k++) {
    o->act[ia].in[k] = mrvi_particle_first(m, pi) + k;
    o->act[ia].in[d + k] = mrvi_particle_first(m, pj) + k;
  }
  mrvi_fmt(o->act[ia].name, sizeof o->act[ia].name, "%s-%s", MRVI_PNAME(m, pi),
           MRVI_PNAME(m, pj));
  o->n_state++; /* the step hook is set in ocp_alloc */
  return ia;
}

/* A state-dependent actuator on bodies: the coordinate actuator's
 * bookkeeping (sizes, bounds, weight) on coordinate c without its force
 * template; the caller fills the inputs and terms. */
static int add_state_actuator(mrvi_ocp *o, int c, const char *what,
                              mrvi_grid grid, double weight, double lower,
                              double upper) {
  if (o->ready)
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "%s actuators must be added before the first "
                         "evaluation",
                         what);
  const int n_force = o->n_force;
  const int ia = mrvi_ocp_add_actuator(o, c, grid, weight, lower, upper);
  if (ia < 0)
    return ia;
  o->n_force = n_force;
  o->n_state++;
  return ia;
}

/* Append the D^2 director coordinates of body b to the inputs of A; their
 * offset in the inputs. */
static int push_directors(const mrvi_model *m, ocp_actuator *A, int b) {
  const int D = m->dimension, first = mrvi_model_body_first(m, b) + D;
  const int off = A->n_in;
  for (int k = 0; k < D * D; k++)
    A->in[A->n_in++] = first + k;
  return off;
}

static int check_body(mrvi_ocp *o, int b, const char *what) {
  if (b < 0 || b >= mrvi_model_n_bodies(o->model))
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "%s: body index %d out of range (the model has %d)",
                         what, b, mrvi_model_n_bodies(o->model));
  return MRVI_OK;
}

int mrvi_ocp_add_torque_actuator(mrvi_ocp *o, int body, const double *axis,
                                 int body_frame, mrvi_grid grid, double weight,
                                 double lower, double upper) {
  const mrvi_model *m = o->model;
  int st = check_body(o, body, "torque actuator");
  if (st < 0)
    return st;
  const int D = m->dimension;
  double n2 = 0.0;
  for (int k = 0; k < 3; k++) {
    if (!isfinite(axis[k]))
      return mrvi_ocp_fail(o, MRVI_EINVAL, "torque actuator: axis not finite");
    n2 += axis[k] * axis[k];
  }
  if (!(n2 > 0.0) || (D == 2 && (axis[0] != 0.0 || axis[1] != 0.0)))
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "torque actuator: the axis must be nonzero%s",
                         D == 2 ? " and along z (a 2-D body turns about the "
                                  "normal only)"
                                : "");
  const int ia = add_state_actuator(o, mrvi_model_body_first(m, body), "torque",
                                    grid, weight, lower, upper);
  if (ia < 0)
    return ia;
  ocp_actuator *A = &o->act[ia];
  A->body = body;
  const int xo = push_directors(m, A, body);
  A->n_torque = 1;
  A->torque[0] = (ocp_torque){.x_off = xo, .y_off = -1, .s = 1.0};
  memcpy(A->torque[0].axis, axis, 3 * sizeof *axis);
  if (body_frame && D == 3)
    A->torque[0].y_off = xo;
  mrvi_fmt(A->name, sizeof A->name, "%s.torque", mrvi_model_body_name(m, body));
  return ia;
}

int mrvi_ocp_add_body_force_actuator(mrvi_ocp *o, int body, const double *at,
                                     const double *direction, mrvi_grid grid,
                                     double weight, double lower,
                                     double upper) {
  const mrvi_model *m = o->model;
  int st = check_body(o, body, "force actuator");
  if (st < 0)
    return st;
  const int D = m->dimension;
  double n2 = 0.0;
  for (int k = 0; k < D; k++) {
    if (!isfinite(direction[k]) || !isfinite(at ? at[k] : 0.0))
      return mrvi_ocp_fail(o, MRVI_EINVAL,
                           "force actuator: point and direction must be "
                           "finite");
    n2 += direction[k] * direction[k];
  }
  if (!(n2 > 0.0))
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "force actuator: the direction must be nonzero");
  const int first = mrvi_model_body_first(m, body);
  const int ia =
      add_state_actuator(o, first, "force", grid, weight, lower, upper);
  if (ia < 0)
    return ia;
  ocp_actuator *A = &o->act[ia];
  A->body = body;
  for (int k = 0; k < D * (D + 1); k++)
    A->in[A->n_in++] = first + k;
  for (int k = 0; k < D; k++) {
    A->at[k] = at ? at[k] : 0.0;
    A->dir[k] = direction[k];
  }
  mrvi_fmt(A->name, sizeof A->name, "%s.force", mrvi_model_body_name(m, body));
  return ia;
}

int mrvi_ocp_add_joint_torque_actuator(mrvi_ocp *o, int joint, mrvi_grid grid,
                                       double weight, double lower,
                                       double upper) {
  const mrvi_model *m = o->model;
  if (joint < 0 || joint >= m->n_constraints ||
      strcmp(m->constraints[joint].type->name, "revolute"))
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "joint torque actuator: constraint %d is not a "
                         "revolute joint",
                         joint);
  const mrvi_constraint *C = &m->constraints[joint];
  const int D = m->dimension, nb = (int)C->params[1];
  const int bodies[2] = {mrvi_model_body_of(m, C->in[0]),
                         nb == 2 ? mrvi_model_body_of(m, C->in[D * (D + 1)])
                                 : -1};
  const int ia = add_state_actuator(o, C->in[0], "joint torque", grid, weight,
                                    lower, upper);
  if (ia < 0)
    return ia;
  ocp_actuator *A = &o->act[ia];
  A->joint = joint;
  A->body = bodies[0];
  /* The hinge t_1 in A's frame (parameters of constraints/joint.h: D, the
   * number of bodies, the two points, then the frame in A's frame). */
  const double *t1 = C->params + 2 + 2 * D;
  const int xa = push_directors(m, A, bodies[0]);
  if (bodies[1] < 0) {
    /* To the ground: u about the hinge on the body. */
    A->n_torque = 1;
    A->torque[0] = (ocp_torque){.x_off = xa, .y_off = xa, .s = 1.0};
  } else {
    /* Between A and B: +u on B, -u on A, about the hinge fixed in A. */
    const int xb = push_directors(m, A, bodies[1]);
    A->n_torque = 2;
    A->torque[0] = (ocp_torque){.x_off = xb, .y_off = xa, .s = 1.0};
    A->torque[1] = (ocp_torque){.x_off = xa, .y_off = xa, .s = -1.0};
  }
  for (int t = 0; t < A->n_torque; t++)
    for (int k = 0; k < D; k++)
      A->torque[t].axis[D == 3 ? k : 2] = D == 3 ? t1[k] : 1.0;
  mrvi_fmt(A->name, sizeof A->name, "%s", C->label);
  return ia;
}

int mrvi_ocp_add_tracking(mrvi_ocp *o, int c, double weight, double ref) {
  int st = check_coord(o, c);
  if (st < 0)
    return st;
  if (!(weight >= 0.0) || !isfinite(ref))
    return mrvi_ocp_fail(o, MRVI_EINVAL, "tracking weight must be >= 0");
  ocp_tracking *t = realloc(o->trk, (size_t)(o->n_trk + 1) * sizeof *t);
  if (!t)
    return mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
  o->trk = t;
  o->trk[o->n_trk++] = (ocp_tracking){c, weight, ref};
  return MRVI_OK;
}

int mrvi_ocp_add_terminal(mrvi_ocp *o, mrvi_ocp_terminal_kind kind, int c,
                          double target, double penalty) {
  int st = check_coord(o, c);
  if (st < 0)
    return st;
  if (!(penalty >= 0.0) || !isfinite(target))
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "terminal penalty must be >= 0, target finite");
  ocp_terminal *t = realloc(o->term, (size_t)(o->n_term + 1) * sizeof *t);
  if (!t)
    return mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
  o->term = t;
  o->term[o->n_term++] = (ocp_terminal){.kind = kind,
                                        .coord = c,
                                        .target = target,
                                        .penalty = penalty,
                                        .body = -1};
  if (penalty > 0.0)
    return 0;
  /* An equality implied by the constraints and the earlier conditions
   * (a coordinate a constraint fixes, both coordinates of a pendulum's bob)
   * would make the optimiser's constraint Jacobian rank-deficient: refused
   * with the constraints on the coordinate named.  The rank is taken near
   * q0, not at it (ocp_terminal_redundant). */
  const int bad = ocp_terminal_redundant(o, o->n_term - 1);
  if (bad == -1)
    return o->n_con++;
  o->n_term--;
  if (bad == -2)
    return mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
  const mrvi_model *m = o->model;
  char names[300] = "";
  size_t used = 0;
  for (int k = 0; k < m->n_constraints; k++) {
    const mrvi_constraint *C = &m->constraints[k];
    int touches = 0;
    for (int j = 0; j < C->n_in; j++)
      touches |= C->in[j] == c;
    if (touches && used < sizeof names)
      used += (size_t)snprintf(names + used, sizeof names - used, "%s'%s'",
                               used ? ", " : "", C->label);
  }
  return mrvi_ocp_fail(
      o, MRVI_EINVAL,
      "terminal %s of '%s' is implied by the constraints %s and the "
      "conditions before it (redundant: the optimiser's constraint Jacobian "
      "would lose rank); give it a penalty instead, or drop it",
      kind == MRVI_OCP_POSITION ? "position" : "velocity", MRVI_CNAME(m, c),
      used ? names : "of the model");
}

/* Rows r0 .. r0 + nrows - 1 of the body terminal condition T0 (kind,
 * body, penalty, attitude target or direction frame), each with its target
 * (angular velocity; NULL: 0): appended, and an equality that the
 * constraints and the conditions before it already impose is refused with
 * the body's joints named. */
static int push_body_rows(mrvi_ocp *o, const ocp_terminal *T0, int r0,
                          int nrows, const double *target) {
  const mrvi_model *m = o->model;
  const int body = T0->body;
  ocp_terminal *t = realloc(o->term, (size_t)(o->n_term + nrows) * sizeof *t);
  if (!t)
    return mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
  o->term = t;
  const int first = o->n_con;
  for (int r = 0; r < nrows; r++) {
    ocp_terminal T = *T0;
    T.coord = mrvi_model_body_first(m, body);
    T.row = r0 + r;
    T.target = target ? target[r] : 0.0;
    o->term[o->n_term++] = T;
    if (T0->penalty == 0.0)
      o->n_con++;
  }
  if (T0->penalty > 0.0)
    return 0;
  /* Rows the constraints already impose (a jointed body has fewer than
   * three rotations) would make the constraint Jacobian of the optimiser
   * rank-deficient: refused, with the joints of the body named. */
  const int bad = ocp_terminal_redundant(o, o->n_term - nrows);
  if (bad == -1)
    return first;
  o->n_term -= nrows;
  o->n_con = first;
  if (bad == -2)
    return mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
  char names[300] = "";
  size_t used = 0;
  for (int c = 0; c < m->n_constraints; c++) {
    const mrvi_constraint *C = &m->constraints[c];
    int touches = 0;
    for (int j = 0; j < C->n_in && !touches; j++)
      touches = mrvi_model_body_of(m, C->in[j]) == body;
    if (touches && c != m->bodies[body].constraint && used < sizeof names)
      used += (size_t)snprintf(names + used, sizeof names - used, "%s'%s'",
                               used ? ", " : "", C->label);
  }
  const int rot =
      T0->kind == MRVI_OCP_ATTITUDE || T0->kind == MRVI_OCP_DIRECTION;
  return mrvi_ocp_fail(
      o, MRVI_EINVAL,
      "terminal %s of body '%s': row %d is implied by %s%s and the "
      "conditions before it (redundant: the body has fewer free %s); give "
      "it a penalty instead",
      T0->kind == MRVI_OCP_ATTITUDE    ? "attitude"
      : T0->kind == MRVI_OCP_DIRECTION ? "direction"
                                       : "angular velocity",
      mrvi_model_body_name(m, body), o->term[bad].row,
      used ? "its joints " : "the constraints", names,
      rot ? "rotations" : "angular velocities");
}

/* The checks every body terminal condition shares. */
static int check_body_terminal(mrvi_ocp *o, int body, double penalty) {
  int st = check_body(o, body, "body terminal condition");
  if (st < 0)
    return st;
  if (!(penalty >= 0.0))
    return mrvi_ocp_fail(o, MRVI_EINVAL, "terminal penalty must be >= 0");
  return MRVI_OK;
}

int mrvi_ocp_add_body_terminal(mrvi_ocp *o, mrvi_ocp_terminal_kind kind,
                               int body, const double *target, double penalty) {
  const mrvi_model *m = o->model;
  int st = check_body_terminal(o, body, penalty);
  if (st < 0)
    return st;
  const int D = m->dimension, rows = D == 3 ? 3 : 1;
  if (kind != MRVI_OCP_ATTITUDE && kind != MRVI_OCP_ANGULAR_VELOCITY &&
      kind != MRVI_OCP_ANGULAR_VELOCITY_BODY)
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "body terminal condition: kind %d is not attitude "
                         "or angular velocity",
                         (int)kind);
  const int nt = kind == MRVI_OCP_ATTITUDE ? D * D : rows;
  for (int k = 0; k < nt; k++)
    if (!isfinite(target[k]))
      return mrvi_ocp_fail(o, MRVI_EINVAL,
                           "body terminal condition: target not finite");
  ocp_terminal T = {.kind = kind, .penalty = penalty, .body = body};
  if (kind == MRVI_OCP_ATTITUDE) {
    /* A rotation: R^T R = I within 1e-6, det +1. */
    double err = 0.0, det;
    for (int a = 0; a < D; a++)
      for (int b = 0; b < D; b++) {
        double s = 0.0;
        for (int k = 0; k < D; k++)
          s += target[k * D + a] * target[k * D + b];
        err = fmax(err, fabs(s - (a == b)));
      }
    if (D == 2)
      det = target[0] * target[3] - target[1] * target[2];
    else
      det = target[0] * (target[4] * target[8] - target[5] * target[7]) -
            target[1] * (target[3] * target[8] - target[5] * target[6]) +
            target[2] * (target[3] * target[7] - target[4] * target[6]);
    if (err > 1e-6 || !(det > 0.0))
      return mrvi_ocp_fail(o, MRVI_EINVAL,
                           "body terminal attitude: the target is not a "
                           "rotation (|R^T R - I| = %.3g, det %.6g)",
                           err, det);
    memcpy(T.R_target, target, (size_t)(D * D) * sizeof *target);
    return push_body_rows(o, &T, 0, rows, NULL);
  }
  return push_body_rows(o, &T, 0, rows, target);
}

int mrvi_ocp_add_body_angular_velocity_component(mrvi_ocp *o, int body_frame,
                                                 int body, int component,
                                                 double target,
                                                 double penalty) {
  int st = check_body_terminal(o, body, penalty);
  if (st < 0)
    return st;
  const int rows = o->model->dimension == 3 ? 3 : 1;
  if (component < 0 || component >= rows)
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "terminal angular velocity component %d of a %d-D "
                         "body (0 .. %d)",
                         component, o->model->dimension, rows - 1);
  if (!isfinite(target))
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "body terminal condition: target not finite");
  const ocp_terminal T = {.kind = body_frame ? MRVI_OCP_ANGULAR_VELOCITY_BODY
                                             : MRVI_OCP_ANGULAR_VELOCITY,
                          .penalty = penalty,
                          .body = body};
  return push_body_rows(o, &T, component, 1, &target);
}

int mrvi_ocp_add_body_direction(mrvi_ocp *o, int body, int director,
                                const double *direction, double penalty) {
  const mrvi_model *m = o->model;
  int st = check_body_terminal(o, body, penalty);
  if (st < 0)
    return st;
  if (m->dimension != 3)
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "terminal direction of a director: 3-D bodies only "
                         "(in 2-D a director's direction is the attitude)");
  if (director < 0 || director > 2)
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "terminal direction: director %d (0 .. 2)", director);
  double ee = 0.0;
  for (int a = 0; a < 3; a++)
    ee += direction[a] * direction[a];
  if (!(isfinite(ee) && ee > 0.0))
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "terminal direction: the direction must be a nonzero "
                         "finite vector");
  /* Frame (u, v, e), right-handed, e the unit direction (stored in
   * R_target's rows; body_terminal.c). */
  double t[9];
  mrvi_joint_frame(3, direction, t);
  ocp_terminal T = {.kind = MRVI_OCP_DIRECTION,
                    .penalty = penalty,
                    .body = body,
                    .director = director};
  memcpy(T.R_target, t + 3, 6 * sizeof *t);
  memcpy(T.R_target + 6, t, 3 * sizeof *t);
  return push_body_rows(o, &T, 0, 2, NULL);
}

void mrvi_ocp_set_algorithm(mrvi_ocp *o, mrvi_ocp_algorithm a) {
  o->algorithm = a;
}
void mrvi_ocp_set_tolerances(mrvi_ocp *o, double ftol_rel,
                             double terminal_tol) {
  o->ftol_rel = ftol_rel;
  o->terminal_tol = terminal_tol;
}
void mrvi_ocp_set_max_evaluations(mrvi_ocp *o, int max_eval) {
  o->max_eval = max_eval;
}

int mrvi_ocp_max_evaluations(const mrvi_ocp *o) { return o->max_eval; }
void mrvi_ocp_set_callback(mrvi_ocp *o, mrvi_ocp_callback cb, void *data) {
  o->cb = cb;
  o->cb_data = data;
}
const double *mrvi_ocp_best_iterate(const mrvi_ocp *o) { return o->best_u; }
int mrvi_ocp_n_controls(const mrvi_ocp *o) { return o->n_u; }
int mrvi_ocp_n_constraints(const mrvi_ocp *o) { return o->n_con; }
long mrvi_ocp_n_steps(const mrvi_ocp *o) { return o->N; }
const double *mrvi_ocp_q(const mrvi_ocp *o) { return o->q_out; }
const double *mrvi_ocp_p(const mrvi_ocp *o) { return o->p_out; }
const double *mrvi_ocp_micro_q(const mrvi_ocp *o) {
  return o->Q + (o->N + 1) * o->ns;
}
const double *mrvi_ocp_micro_p(const mrvi_ocp *o) { return o->pf_micro; }
const double *mrvi_ocp_micro_constraint_residual(const mrvi_ocp *o) {
  return o->cres_micro;
}
int mrvi_ocp_actuator_offset(const mrvi_ocp *o, int a) {
  return o->act[a].offset;
}
int mrvi_ocp_actuator_size(const mrvi_ocp *o, int a) { return o->act[a].size; }
int mrvi_ocp_n_actuators(const mrvi_ocp *o) { return o->n_act; }
void mrvi_ocp_actuator_bounds(const mrvi_ocp *o, int a, double *lower,
                              double *upper) {
  *lower = o->act[a].lower;
  *upper = o->act[a].upper;
}
const char *mrvi_ocp_actuator_name(const mrvi_ocp *o, int a) {
  return o->act[a].name;
}
int mrvi_ocp_actuator_grid(const mrvi_ocp *o, int a) {
  return (int)o->act[a].grid;
}
int mrvi_ocp_actuator_coordinate(const mrvi_ocp *o, int a) {
  return o->act[a].n_in > 0 ? -1 : o->act[a].coord;
}
const char *mrvi_ocp_actuator_kind(const mrvi_ocp *o, int a) {
  const ocp_actuator *A = &o->act[a];
  if (A->n_in == 0)
    return "coordinate";
  if (A->pi >= 0)
    return "pair";
  if (A->joint >= 0)
    return "joint_torque";
  return A->n_torque > 0 ? "torque" : "force";
}
int mrvi_ocp_actuator_body(const mrvi_ocp *o, int a) { return o->act[a].body; }
void mrvi_ocp_actuator_pair(const mrvi_ocp *o, int a, int *pi, int *pj) {
  *pi = o->act[a].pi;
  *pj = o->act[a].pj;
}
int mrvi_ocp_n_terminals(const mrvi_ocp *o) { return o->n_term; }
const char *mrvi_ocp_terminal_kind_name(mrvi_ocp_terminal_kind kind) {
  static const char *const names[] = {"position",
                                      "velocity",
                                      "attitude",
                                      "angular_velocity",
                                      "angular_velocity_body",
                                      "direction"};
  return kind >= 0 && kind <= MRVI_OCP_DIRECTION ? names[kind] : "unknown";
}
int mrvi_ocp_terminal_body(const mrvi_ocp *o, int i, int *row) {
  if (row)
    *row = o->term[i].row;
  return o->term[i].body;
}
int mrvi_ocp_terminal_attitude(const mrvi_ocp *o, int i, double *R) {
  const ocp_terminal *t = &o->term[i];
  const int D = o->model->dimension;
  if (t->kind != MRVI_OCP_ATTITUDE)
    return 0;
  memcpy(R, t->R_target, (size_t)(D * D) * sizeof *R);
  return D;
}
void mrvi_ocp_terminal(const mrvi_ocp *o, int i, mrvi_ocp_terminal_kind *kind,
                       int *coordinate, double *target, double *penalty) {
  const ocp_terminal *t = &o->term[i];
  if (kind)
    *kind = t->kind;
  if (coordinate)
    *coordinate = t->coord;
  if (target)
    *target = t->target;
  if (penalty)
    *penalty = t->penalty;
}
const char *mrvi_ocp_algorithm_name(mrvi_ocp_algorithm a) {
  static const char *const names[] = {"slsqp", "auglag-lbfgs", "auglag-mma",
                                      "auglag-ccsaq"};
  return a >= 0 && a <= MRVI_OCP_AUGLAG_CCSAQ ? names[a] : "unknown";
}
mrvi_ocp_algorithm mrvi_ocp_get_algorithm(const mrvi_ocp *o) {
  return o->algorithm;
}
double mrvi_ocp_terminal_tolerance(const mrvi_ocp *o) {
  return o->terminal_tol;
}

int ocp_control_index(const mrvi_ocp *o, long k, const ocp_force *fe) {
  const ocp_actuator *a = &o->act[fe->act];
  const int per = a->grid == MRVI_GRID_MACRO ? 1 : o->p;
  return a->offset + (int)(k * per) + fe->j;
}

/* Control forces of step k into the residual rows and the end momenta;
 * f_plus gets the f^+ parts on the fast nodes 1..p (for the micro
 * momenta). */
static void step_forces(mrvi_ocp *o, long k, const double *u) {
  const int ns = o->ns, nf = o->nf, p = o->p;
  memset(o->f_rows, 0, (size_t)o->step.n_unknowns * sizeof(double));
  memset(o->f_end, 0, (size_t)(ns + nf) * sizeof(double));
  memset(o->f_plus, 0, (size_t)p * (size_t)nf * sizeof(double));
  for (int i = 0; i < o->n_force; i++) {
    const ocp_force *fe = &o->force[i];
    const double f = fe->coef * u[ocp_control_index(o, k, fe)];
    if (fe->z < ns) {
      o->f_rows[fe->z] += f;
    } else if (fe->z < 2 * ns) {
      o->f_end[fe->z - ns] += f;
    } else {
      const int zf = fe->z - 2 * ns, mm = zf / nf, s = zf % nf;
      if (mm < p)
        o->f_rows[ns + mm * nf + s] += f;
      else
        o->f_end[ns + s] += f;
      if (fe->plus)
        o->f_plus[(mm - 1) * nf + s] += f;
    }
  }
}

static double norm_inf(const double *v, int n) {
  double r = 0.0;
  for (int i = 0; i < n; i++) {
    if (isnan(v[i]))
      return v[i];
    r = fmax(r, fabs(v[i]));
  }
  return r;
}

/* Pattern, symbolic analysis (and null-space set-up) at the first step's
 * predictor; on schur-bordered the pattern alone (the adjoint factorises
 * with bordered.c, adjoint.c). */
static int prepare(mrvi_ocp *o) {
  mrvi_step *st = &o->step;
  char msg[300];
  if (mrvi_step_build_pattern(st, o->x) < 0)
    return mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
  mrvi_step_assemble(st, o->x, o->R, 1);
  if (o->path == MRVI_PATH_SCHUR_BORDERED) {
    o->ready = 1;
    return MRVI_OK;
  }
  if (o->settings.constraint_form == MRVI_FORM_NULL_SPACE && o->nl > 0) {
    int s = mrvi_nullspace_create(st, NULL, 0, &o->nullspace, msg, sizeof msg);
    if (s == 0) {
      mrvi_step_assemble(st, o->x, o->R, 0);
      s = mrvi_nullspace_lambda(o->nullspace, st, o->x, o->R, msg, sizeof msg);
    }
    if (s < 0)
      return mrvi_ocp_fail(o, s, "%s", msg);
    mrvi_step_assemble(st, o->x, o->R, 1);
    mrvi_nullspace_reduce(o->nullspace, st, o->R, o->rhs_ns);
    o->newton = mrvi_newton_create(
        st->n_unknowns, mrvi_nullspace_Ap(o->nullspace),
        mrvi_nullspace_Ai(o->nullspace), mrvi_nullspace_Ax(o->nullspace),
        st->tuning.newton_dense_max, msg, sizeof msg);
  } else {
    o->newton =
        mrvi_newton_create(st->n_total, st->Ap, st->Ai, st->Ax,
                           st->tuning.newton_dense_max, msg, sizeof msg);
  }
  if (!o->newton)
    return mrvi_ocp_fail(o, MRVI_ESINGULAR, "%s", msg);
  /* The adjoint always solves with the saddle-point matrix of the
   * multiplier form (same equations, same converged steps). */
  if (o->nullspace) {
    o->newton_full =
        mrvi_newton_create(st->n_total, st->Ap, st->Ai, st->Ax,
                           st->tuning.newton_dense_max, msg, sizeof msg);
    if (!o->newton_full)
      return mrvi_ocp_fail(o, MRVI_ESINGULAR, "%s", msg);
  }
  o->ready = 1;
  return MRVI_OK;
}

/* Residual and Jacobian at o->x (null-space form: lambda(x) first);
 * *res gets max |R| over dynamic and constraint rows. */
static int evaluate(mrvi_ocp *o, double *res, char *msg, size_t len) {
  mrvi_step *st = &o->step;
  if (o->nullspace) {
    memset(o->x + st->n_unknowns, 0, (size_t)st->n_lambda * sizeof(double));
    mrvi_step_assemble(st, o->x, o->R, 0);
    int s = mrvi_nullspace_lambda(o->nullspace, st, o->x, o->R, msg, len);
    if (s < 0)
      return s;
  }
  mrvi_step_assemble(st, o->x, o->R, 1);
  *res = norm_inf(o->R, st->n_total);
  return MRVI_OK;
}

/* Free-flight predictor of the step whose known data o->step holds. */
static void free_flight(mrvi_ocp *o) {
  const mrvi_model *m = o->model;
  const mrvi_step *st = &o->step;
  const int ns = o->ns, nf = o->nf, p = o->p;
  for (int s = 0; s < ns; s++)
    o->x[s] = st->qs0[s] + st->dT * st->ps0[s] / MRVI_MASS(m, m->slow_index[s]);
  for (int mm = 1; mm <= p; mm++)
    for (int s = 0; s < nf; s++)
      o->x[ns + (mm - 1) * nf + s] =
          st->qf0[s] +
          mm * st->dt * st->pf0[s] / MRVI_MASS(m, m->fast_index[s]);
}

/* Converged step k into the trajectory: slow node qs1 (ns), fast nodes
 * 1..p qf (p x nf), momenta ps1 (ns, f^+ included) and pf (p x nf: D_2 L_d
 * of the micro intervals, the last with f^+). */
static void store_step(mrvi_ocp *o, long k, const double *qs1, const double *qf,
                       const double *ps1, const double *pf) {
  const int ns = o->ns, nf = o->nf, p = o->p;
  double *Qs = o->Q, *Qf = o->Q + (o->N + 1) * ns;
  /* Fast micro momenta p^{m+1} = D_2 L_d^m + f^{+,m} (eq:pkfm+ with the
   * control force; the last one, p_{k+1}^f, has f_end already). */
  for (int mm = 0; mm < p; mm++)
    for (int s = 0; s < nf; s++)
      o->pf_micro[(k * p + mm + 1) * nf + s] =
          pf[mm * nf + s] + (mm < p - 1 ? o->f_plus[mm * nf + s] : 0.0);
  memcpy(Qs + (k + 1) * ns, qs1, (size_t)ns * sizeof(double));
  memcpy(Qf + (k * p + 1) * nf, qf, (size_t)p * (size_t)nf * sizeof(double));
  memcpy(o->ps_k + (k + 1) * ns, ps1, (size_t)ns * sizeof(double));
  memcpy(o->pf_k + (k + 1) * nf, pf + (p - 1) * nf,
         (size_t)nf * sizeof(double));
}

/* At the first forward pass: the path (ocp_path), the general path's
 * pattern and factorisation at the first step's predictor (the adjoint
 * solves with them on every path) and, on a structured path, the
 * integrator that takes the steps with the control forces. */
static int setup(mrvi_ocp *o, const double *u) {
  char why[300], msg[400];
  o->path = ocp_path(o, why, sizeof why);
  if (o->path == MRVI_PATH_GENERAL &&
      o->settings.solver == MRVI_SOLVER_STRUCTURED)
    return mrvi_ocp_fail(o, MRVI_EINVAL,
                         "integrator.solver = structured: no structured "
                         "path: %s",
                         why);
  if (o->path != MRVI_PATH_GENERAL && !o->integ) {
    /* The integrator's own path objects; no momentum projection (the step
     * equations of the problem have none). */
    mrvi_settings s = o->settings;
    s.project_momenta = 0;
    o->u_cur = u; /* (the step hooks at the integrator's first assembly) */
    o->k_cur = 0;
    /* Each forward run a function of its inputs, each step of (q_k, p_k)
     * alone, as the adjoint differentiates it: no chord history. */
    s.tuning.chord_carry = 0;
    const int st =
        o->n_state > 0
            ? mrvi_integrator_create_hooked(o->model, &s, ocp_state_hook,
                                            ocp_state_end_hook, o, &o->integ,
                                            msg, sizeof msg)
            : mrvi_integrator_create(o->model, &s, &o->integ, msg, sizeof msg);
    if (st < 0)
      return mrvi_ocp_fail(o, st, "%s", msg);
    mrvi_integrator_set_forces(o->integ, o->f_rows, o->f_end);
  }
  mrvi_step *st = &o->step;
  st->qs0 = o->Q;
  st->qf0 = o->Q + (o->N + 1) * o->ns;
  st->ps0 = o->ps_k;
  st->pf0 = o->pf_k;
  step_forces(o, 0, u);
  free_flight(o);
  o->u_cur = u;
  o->k_cur = 0;
  return prepare(o);
}

/* Step k on a structured path: the integrator's step with the control
 * forces of step k (it holds the state from step k - 1). */
static int structured_step(mrvi_ocp *o, long k, const double *u) {
  const mrvi_model *m = o->model;
  mrvi_integrator *it = o->integ;
  if (k == 0) {
    for (int i = 0; i < m->n; i++)
      o->p0[i] = MRVI_MASS(m, i) * m->v0[i];
    const int s = mrvi_integrator_resume_state(it, 0, m->q0, o->p0);
    if (s < 0)
      return mrvi_ocp_fail(o, s, "%s", mrvi_integrator_errmsg(it));
  }
  step_forces(o, k, u);
  if (o->n_state > 0) {
    /* for the step hooks: the controls, the step and the constant parts
     * of f^+ (ocp_state_end_hook) */
    o->u_cur = u;
    o->k_cur = k;
    memcpy(o->f_end_c, o->f_end, (size_t)(o->ns + o->nf) * sizeof(double));
    memcpy(o->f_plus_c, o->f_plus,
           (size_t)o->p * (size_t)o->nf * sizeof(double));
  }
  const int nt = o->n_torsion;
  if (nt > 0)
    memcpy(o->branch + k * nt, mrvi_integrator_torsion_angle(it),
           (size_t)nt * sizeof(double));
  const int s = mrvi_integrator_step(it);
  if (s < 0)
    return mrvi_ocp_fail(o, s, "%s", mrvi_integrator_errmsg(it));
  if (nt > 0)
    memcpy(o->branch + (k + 1) * nt, mrvi_integrator_torsion_angle(it),
           (size_t)nt * sizeof(double));
  /* schur-bordered: the multipliers of the step (the adjoint's J_k) and
   * the micro nodes' constraint residuals, as the general path keeps them */
  if (o->nl > 0) {
    memcpy(o->Lam + k * o->nl, mrvi_integrator_step_multipliers(it),
           (size_t)o->nl * sizeof(double));
    memcpy(o->cres_micro + k * o->p,
           mrvi_integrator_micro_constraint_residual(it),
           (size_t)o->p * sizeof(double));
  }
  const double *q = mrvi_integrator_q(it), *pm = mrvi_integrator_p(it);
  for (int i = 0; i < o->ns; i++) {
    o->ps1[i] = pm[m->slow_index[i]];
    o->x[i] = q[m->slow_index[i]];
  }
  store_step(o, k, o->x, mrvi_integrator_micro_q(it), o->ps1,
             mrvi_integrator_micro_p(it));
  return MRVI_OK;
}

/* The torsional springs' branches at node k + 1 from those at node k (the
 * integrator's rule, mrvi_integrator_step): the angle nearest the branch;
 * a step that turns a spring by pi/2 or more is refused. */
static int follow_torsion(mrvi_ocp *o, long k) {
  const mrvi_model *m = o->model;
  const int ns = o->ns, nf = o->nf, nt = o->n_torsion;
  const long N = o->N;
  double *q = o->q_out + (k + 1) * m->n, *b = o->branch + (k + 1) * nt;
  for (int s = 0; s < ns; s++)
    q[m->slow_index[s]] = o->Q[(k + 1) * ns + s];
  for (int s = 0; s < nf; s++)
    q[m->fast_index[s]] = o->Q[(N + 1) * ns + (k + 1) * o->p * nf + s];
  memcpy(b, b - nt, (size_t)nt * sizeof *b);
  int worst;
  const double turn = mrvi_model_torsion_follow(m, q, b, &worst);
  if (turn < 0.5 * M_PI)
    return MRVI_OK;
  char what[300];
  mrvi_model_describe_element(m, worst, what, sizeof what);
  return mrvi_ocp_fail(o, MRVI_ENEWTON,
                       "step %ld: the %s turned by %.3g rad in one macro "
                       "step (at most pi/2 are followed: reduce "
                       "integrator.macro_step)",
                       k + 1, what, turn);
}

int ocp_forward(mrvi_ocp *o, const double *u) {
  int s0 = ocp_alloc(o);
  if (s0 < 0)
    return s0;
  const mrvi_model *m = o->model;
  mrvi_step *st = &o->step;
  const int ns = o->ns, nf = o->nf, p = o->p, n = m->n;
  const long N = o->N;
  const double dT = st->dT, dt = st->dt;
  double *Qs = o->Q, *Qf = o->Q + (N + 1) * ns;
  char msg[300];
  memset(o->x, 0, (size_t)st->n_total * sizeof(double));
  /* Initial state (q0, M v0). */
  for (int s = 0; s < ns; s++) {
    const int c = m->slow_index[s];
    Qs[s] = m->q0[c];
    o->ps_k[s] = MRVI_MASS(m, c) * m->v0[c];
  }
  for (int s = 0; s < nf; s++) {
    const int c = m->fast_index[s];
    Qf[s] = m->q0[c];
    o->pf_k[s] = MRVI_MASS(m, c) * m->v0[c];
    o->pf_micro[s] = o->pf_k[s];
  }
  if (!o->ready && (s0 = setup(o, u)) < 0)
    return s0;
  for (long k = 0; k < N && o->integ; k++)
    if ((s0 = structured_step(o, k, u)) < 0)
      return s0;
  if (o->n_torsion > 0)
    mrvi_model_torsion_init(m, m->q0, o->branch);
  for (long k = 0; k < N && !o->integ; k++) {
    if (o->n_torsion > 0)
      mrvi_model_torsion_set(m, o->branch + k * o->n_torsion);
    st->qs0 = Qs + k * ns;
    st->qf0 = Qf + k * p * nf;
    st->ps0 = o->ps_k + k * ns;
    st->pf0 = o->pf_k + k * nf;
    step_forces(o, k, u);
    free_flight(o);
    o->u_cur = u; /* for the pair-force step hook */
    o->k_cur = k;
    int it = 0;
    double res;
    if ((s0 = evaluate(o, &res, msg, sizeof msg)) < 0)
      return mrvi_ocp_fail(o, s0, "step %ld: %s", k + 1, msg);
    /* Roundoff floor of the residual (as in the integrator): its rows
     * subtract momenta of size M |q| / dt. */
    double scale = 0.0;
    for (int i = 0; i < ns; i++)
      scale = fmax(scale, fabs(st->ps0[i]) +
                              MRVI_MASS(m, m->slow_index[i]) *
                                  (fabs(st->qs0[i]) + fabs(o->x[i])) / dT);
    for (int i = 0; i < nf; i++) {
      double qm = fabs(st->qf0[i]);
      for (int mm = 1; mm <= p; mm++)
        qm = fmax(qm, fabs(o->x[ns + (mm - 1) * nf + i]));
      scale = fmax(scale, fabs(st->pf0[i]) +
                              4.0 * MRVI_MASS(m, m->fast_index[i]) * qm / dt);
    }
    const double tol = fmax(o->settings.newton_tol, 16.0 * DBL_EPSILON * scale);
    while (!(res <= tol)) {
      if (!isfinite(res) || it == o->settings.newton_max_iter)
        return mrvi_ocp_fail(o, isfinite(res) ? MRVI_ENEWTON : MRVI_ENONFINITE,
                             "step %ld: Newton did not converge (residual "
                             "%.3e after %d iterations)",
                             k + 1, res, it);
      if (o->nullspace) {
        mrvi_nullspace_reduce(o->nullspace, st, o->R, o->rhs_ns);
        s0 = mrvi_newton_solve(o->newton, mrvi_nullspace_Ax(o->nullspace),
                               o->rhs_ns, o->dx, msg, sizeof msg);
      } else {
        s0 = mrvi_newton_solve(o->newton, st->Ax, o->R, o->dx, msg, sizeof msg);
      }
      if (s0 < 0)
        return mrvi_ocp_fail(o, s0, "step %ld: %s", k + 1, msg);
      const int nx = o->nullspace ? st->n_unknowns : st->n_total;
      for (int i = 0; i < nx; i++)
        o->x[i] -= o->dx[i];
      it++;
      if ((s0 = evaluate(o, &res, msg, sizeof msg)) < 0)
        return mrvi_ocp_fail(o, s0, "step %ld: %s", k + 1, msg);
    }
    memcpy(o->Lam + k * o->nl, o->x + st->n_unknowns,
           (size_t)o->nl * sizeof(double));
    if (o->n_state > 0)
      ocp_state_end_forces(o, k, u);
    mrvi_step_momenta(st, o->x, o->ps1, o->pf1);
    mrvi_step_micro_residuals(st, o->R, o->cres_micro + k * p);
    store_step(o, k, o->x, o->x + ns, o->ps1, o->pf1);
    if (o->n_torsion > 0 && (s0 = follow_torsion(o, k)) < 0)
      return s0;
  }
  memcpy(o->pN, o->ps_k + N * ns, (size_t)ns * sizeof(double));
  memcpy(o->pN + ns, o->pf_k + N * nf, (size_t)nf * sizeof(double));
  /* Macro-node outputs in model order. */
  for (long k = 0; k <= N; k++) {
    for (int s = 0; s < ns; s++) {
      o->q_out[k * n + m->slow_index[s]] = Qs[k * ns + s];
      o->p_out[k * n + m->slow_index[s]] = o->ps_k[k * ns + s];
    }
    for (int s = 0; s < nf; s++) {
      o->q_out[k * n + m->fast_index[s]] = Qf[k * p * nf + s];
      o->p_out[k * n + m->fast_index[s]] = o->pf_k[k * nf + s];
    }
  }
  return MRVI_OK;
}

void mrvi_ocp_lambda(const mrvi_ocp *o, long k, double *out) {
  const mrvi_model *m = o->model;
  const mrvi_step *st = &o->step;
  const double *x = o->Lam + k * o->nl;
  for (int i = 0; i < st->n_slow_c; i++) {
    const mrvi_constraint *c = &m->constraints[st->slow_c[i]];
    for (int r = 0; r < c->rows; r++)
      out[c->first_row + r] = x[st->c_off[st->slow_c[i]] + r];
  }
  /* Micro-node constraints: the step average (1/p) sum_m lambda^m, as the
   * integrator reports it. */
  for (int i = 0; i < st->n_micro_c; i++) {
    const int ci = st->micro_c[i];
    const mrvi_constraint *c = &m->constraints[ci];
    for (int r = 0; r < c->rows; r++) {
      double sum = 0.0;
      for (int mm = 0; mm < o->p; mm++)
        sum += x[st->r_slow + mm * st->r_micro + st->c_off[ci] + r];
      out[c->first_row + r] = sum / o->p;
    }
  }
}
