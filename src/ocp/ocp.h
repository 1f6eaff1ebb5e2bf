/* Multirate discrete mechanics and optimal control (MDMOC), see
 * doc/optimal-control.md.
 *
 * Dynamics: the discrete Lagrange-d'Alembert principle on mrvi's multirate
 * discrete Lagrangian L_d (arXiv 2406.12991, eq:DEL_ini in one-step form):
 *   p_k + D_1 L_d + f_k^- = 0 (with the micro-node rows),
 *   p_{k+1} = D_2 L_d + f_k^+.
 * Controls are piecewise constant on the macro grid (slow actuator) or the
 * micro grid (fast actuator) and act along one generalised coordinate (or,
 * pair actuators, along the line between two particles; or as torques and
 * forces on rigid bodies); the
 * discrete forces f^+- are the exact virtual work of that force along the
 * linearly interpolated path of the coordinate.  Single shooting over the
 * controls with gradients from the exact discrete adjoint, optimised with
 * NLopt.
 *
 * Control vector layout: actuator by actuator (in the order added), each
 * with N values (macro grid) or N p values (micro grid), in time order. */
#ifndef MRVI_OCP_H
#define MRVI_OCP_H

#include "mrvi.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct mrvi_ocp mrvi_ocp;

/* Optimisation algorithms (NLopt). */
typedef enum mrvi_ocp_algorithm {
  MRVI_OCP_SLSQP = 0,        /* dense SQP; default, up to a few hundred u */
  MRVI_OCP_AUGLAG_LBFGS = 1, /* augmented Lagrangian, L-BFGS inner solver */
  MRVI_OCP_AUGLAG_MMA = 2,   /* augmented Lagrangian, MMA inner solver */
  MRVI_OCP_AUGLAG_CCSAQ = 3  /* augmented Lagrangian, CCSAQ inner solver */
} mrvi_ocp_algorithm;

/* Terminal quantity of a coordinate or (mrvi_ocp_add_body_terminal) of a
 * rigid body. */
typedef enum mrvi_ocp_terminal_kind {
  MRVI_OCP_POSITION = 0,              /* q_N */
  MRVI_OCP_VELOCITY = 1,              /* p_N / M (final discrete momentum) */
  MRVI_OCP_ATTITUDE = 2,              /* rotation vector of R_target^T R_N */
  MRVI_OCP_ANGULAR_VELOCITY = 3,      /* omega_N in space */
  MRVI_OCP_ANGULAR_VELOCITY_BODY = 4, /* Omega_N = R_N^T omega_N */
  MRVI_OCP_DIRECTION = 5 /* a director along a direction in space */
} mrvi_ocp_terminal_kind;

/* Create a problem on model m (must outlive it; no constraints yet) with the
 * integrator settings s (copied; N = mrvi_settings_n_steps(s) steps).  The
 * initial state is the model's (q0, M v0). */
int mrvi_ocp_create(const mrvi_model *m, const mrvi_settings *s, mrvi_ocp **out,
                    char *msg, size_t len);
/* Free a problem (NULL is accepted). */
void mrvi_ocp_free(mrvi_ocp *o);
/* Message of the last failure on o. */
const char *mrvi_ocp_errmsg(const mrvi_ocp *o);

/* Add an actuator: force u along model coordinate `coordinate`, piecewise
 * constant on grid (MRVI_GRID_MACRO: slow, N values; MRVI_GRID_MICRO: fast,
 * N p values), effort weight w > 0 in 1/2 int w u^2 dt, bounds
 * lower <= u <= upper (+-HUGE_VAL for none).  Returns the actuator index. */
int mrvi_ocp_add_actuator(mrvi_ocp *o, int coordinate, mrvi_grid grid,
                          double weight, double lower, double upper);
/* Add a pair actuator: equal and opposite forces of magnitude u along the
 * line between particles i and j (model particle indices, i != j; u > 0
 * pushes them apart), piecewise constant on grid, weight and bounds as for
 * mrvi_ocp_add_actuator; default name "I-J".  Its discrete forces depend
 * on the configuration (doc/optimal-control.md).  Add it before the first
 * evaluation.  Returns the actuator index. */
int mrvi_ocp_add_pair_actuator(mrvi_ocp *o, int particle_i, int particle_j,
                               mrvi_grid grid, double weight, double lower,
                               double upper);
/* Actuators on rigid bodies (doc/optimal-control.md, "Bodies"); weight,
 * bounds and grid as for mrvi_ocp_add_actuator, added before the first
 * evaluation; they return the actuator index.
 * Torque u axis on body `body`: axis (3 entries, nonzero) in space, or
 * (body_frame = 1) fixed in the body, components along d_1 d_2 d_3; 2-D:
 * axis = (0, 0, a), the torque u a about the normal.  It acts on the
 * directors as f_{d_i} = 1/2 tau x d_i.  Default name "BODY.torque". */
int mrvi_ocp_add_torque_actuator(mrvi_ocp *o, int body, const double *axis,
                                 int body_frame, mrvi_grid grid, double weight,
                                 double lower, double upper);
/* Force u direction (space, D entries, nonzero) at the body point with
 * body-frame components `at` (D entries; NULL: the centre of mass).
 * Default name "BODY.force". */
int mrvi_ocp_add_body_force_actuator(mrvi_ocp *o, int body, const double *at,
                                     const double *direction, mrvi_grid grid,
                                     double weight, double lower, double upper);
/* Torque u about the hinge of revolute joint `joint` (its constraint
 * index): +u on the second body, -u on the first (to the ground: +u on the
 * body), the hinge fixed in the first body.  Default name: the joint's. */
int mrvi_ocp_add_joint_torque_actuator(mrvi_ocp *o, int joint, mrvi_grid grid,
                                       double weight, double lower,
                                       double upper);
/* Running tracking term 1/2 int weight (q_c - ref)^2 dt, integrated exactly
 * along the linearly interpolated path on the coordinate's grid. */
int mrvi_ocp_add_tracking(mrvi_ocp *o, int coordinate, double weight,
                          double ref);
/* Terminal condition on coordinate c: an equality constraint
 * (penalty = 0) value - target = 0, or the penalty
 * 1/2 penalty (value - target)^2 in the cost (penalty > 0).  Returns the
 * constraint index (>= 0) or, for a penalty, 0. */
int mrvi_ocp_add_terminal(mrvi_ocp *o, mrvi_ocp_terminal_kind kind,
                          int coordinate, double target, double penalty);

/* Terminal condition on rigid body `body`: kind MRVI_OCP_ATTITUDE (target
 * a rotation, D x D row-major; the rows are the rotation vector of
 * R_target^T R_N, defined for angles below pi) or MRVI_OCP_ANGULAR_VELOCITY
 * (_BODY) (target: omega in space, or in the body frame; 3 entries, 2-D:
 * 1), with omega from the final discrete momenta.  Three rows in 3-D, one
 * in 2-D, each an equality (penalty = 0) or a penalty term.  Returns the
 * index of the first constraint row, or 0 for penalties. */
int mrvi_ocp_add_body_terminal(mrvi_ocp *o, mrvi_ocp_terminal_kind kind,
                               int body, const double *target, double penalty);
/* One component of a body's terminal angular velocity (in space, or with
 * body_frame in the body frame): row `component` (0 .. 2; 2-D: 0) of
 * mrvi_ocp_add_body_terminal's rows, equal to target.  Returns as above. */
int mrvi_ocp_add_body_angular_velocity_component(mrvi_ocp *o, int body_frame,
                                                 int body, int component,
                                                 double target, double penalty);
/* Terminal direction of director d_{director+1} (director 0 .. 2) of a 3-D
 * body: at t_N it points along `direction` (3 entries in space, not zero;
 * its length does not matter), the rotation about it free.  Two rows: the
 * components normal to e = direction/|direction| of the rotation vector
 * taking e to d, theta (e x d)/|e x d| with theta = atan2(|e x d|, e . d)
 * (0 only for d = e, not for d = -e; defined below half a turn).
 * Returns as above. */
int mrvi_ocp_add_body_direction(mrvi_ocp *o, int body, int director,
                                const double *direction, double penalty);

/* Solver settings: algorithm, relative tolerance on the cost (default
 * 1e-12), terminal tolerance (default 1e-8, also the NLopt constraint
 * tolerance), evaluation limit (default 2000). */
void mrvi_ocp_set_algorithm(mrvi_ocp *o, mrvi_ocp_algorithm a);
void mrvi_ocp_set_tolerances(mrvi_ocp *o, double ftol_rel, double terminal_tol);
void mrvi_ocp_set_max_evaluations(mrvi_ocp *o, int max_eval);
/* The cap on cost + gradient evaluations (default 2000). */
int mrvi_ocp_max_evaluations(const mrvi_ocp *o);
/* Called after every cost evaluation of the optimiser with its count, cost,
 * largest terminal violation, gradient norm |grad J| and KKT residual (the
 * norm of the projected gradient of the Lagrangian with least-squares
 * multipliers of the terminal conditions and the active bounds: 0 at a
 * constrained optimum, where |grad J| need not be; doc/optimal-control.md);
 * a non-zero return stops the optimisation (MRVI_EINTERRUPTED). */
typedef int (*mrvi_ocp_callback)(void *data, int evaluation, double cost,
                                 double violation, double grad_norm,
                                 double kkt_residual);
void mrvi_ocp_set_callback(mrvi_ocp *o, mrvi_ocp_callback cb, void *data);
/* Inside the callback: the best iterate so far (the controls solve returns
 * when stopped there; n_controls values, owned by solve); else NULL. */
const double *mrvi_ocp_best_iterate(const mrvi_ocp *o);

/* Sizes: controls, terminal equality constraints, macro steps N. */
int mrvi_ocp_n_controls(const mrvi_ocp *o);
int mrvi_ocp_n_constraints(const mrvi_ocp *o);
long mrvi_ocp_n_steps(const mrvi_ocp *o);

/* Forward shooting and exact discrete adjoint at controls u (n_controls):
 * cost J, its gradient grad (n_controls, may be NULL), terminal constraint
 * values c (n_constraints, may be NULL) and their gradients cgrad
 * (n_constraints x n_controls row-major, may be NULL). */
int mrvi_ocp_evaluate(mrvi_ocp *o, const double *u, double *J, double *grad,
                      double *c, double *cgrad);

/* Result of mrvi_ocp_solve. */
typedef struct mrvi_ocp_result {
  int nlopt_result;    /* NLopt's return code */
  char nlopt_name[48]; /* its name */
  double cost;         /* J at the returned controls */
  double violation;    /* max |c_i| re-checked at the returned controls */
  int evaluations;     /* cost+gradient evaluations */
  /* The outcome (doc/optimal-control.md, "Status"): "converged" (NLopt
   * reached its tolerance and the terminal conditions hold to the terminal
   * tolerance), "terminal_not_met" (tolerance reached, conditions not
   * met), "max_evaluations", "max_time", "roundoff_limited", "failed"
   * (NLopt failed or the re-check's forward pass failed), "interrupted"
   * (the callback asked to stop: u is the best iterate so far). */
  char status[24];
} mrvi_ocp_result;

/* Optimise: u (n_controls) holds the initial guess and receives the result.
 * MRVI_OK only when res->status is "converged"; MRVI_EINTERRUPTED when the
 * callback stopped it (u: the best iterate so far, the lowest cost among
 * iterates meeting the terminal conditions, else the lowest violation);
 * MRVI_EOPTIMIZE otherwise.  u and res are set in every case except a
 * failure before NLopt starts (res->status "" then). */
int mrvi_ocp_solve(mrvi_ocp *o, double *u, mrvi_ocp_result *res);

/* Trajectory of the last evaluation: macro-node positions and momenta
 * ((N+1) x n, model order) and fast micro-node positions ((N p + 1) x n_fast).
 * Valid until the next evaluation. */
const double *mrvi_ocp_q(const mrvi_ocp *o);
const double *mrvi_ocp_p(const mrvi_ocp *o);
/* Fast coordinates (in model order of the fast coordinates) at every micro
 * node of the last evaluation: positions and momenta, (N p + 1) x n_fast;
 * the momenta are p^{m+1} = D_2 L_d^m + f^{+,m} (the control force of the
 * micro interval ending at the node included).  Valid until the next
 * evaluation. */
const double *mrvi_ocp_micro_q(const mrvi_ocp *o);
const double *mrvi_ocp_micro_p(const mrvi_ocp *o);
/* max |g| at the micro nodes m = 1..p of every step (N p), as
 * mrvi_integrator_micro_constraint_residual reports them per step. */
const double *mrvi_ocp_micro_constraint_residual(const mrvi_ocp *o);
/* Multipliers of step k (0..N-1) of the last evaluation in the model's
 * constraint-row order (micro-node constraints: the step average), as
 * mrvi_integrator_lambda reports them; out has constraint_rows entries. */
void mrvi_ocp_lambda(const mrvi_ocp *o, long k, double *out);
/* Time of control j of actuator a (start of its interval) and its offset in
 * the control vector; number of values of actuator a. */
int mrvi_ocp_actuator_offset(const mrvi_ocp *o, int a);
int mrvi_ocp_actuator_size(const mrvi_ocp *o, int a);
/* Number of actuators; name (default: its coordinate's) and grid
 * (mrvi_grid) of actuator a. */
int mrvi_ocp_n_actuators(const mrvi_ocp *o);
/* Bounds of every value of actuator a (+-HUGE_VAL: none). */
void mrvi_ocp_actuator_bounds(const mrvi_ocp *o, int a, double *lower,
                              double *upper);
const char *mrvi_ocp_actuator_name(const mrvi_ocp *o, int a);
int mrvi_ocp_actuator_grid(const mrvi_ocp *o, int a);
/* Model coordinate actuator a acts on (-1 for a pair actuator), and the
 * particles of a pair actuator (-1, -1 otherwise). */
int mrvi_ocp_actuator_coordinate(const mrvi_ocp *o, int a);
void mrvi_ocp_actuator_pair(const mrvi_ocp *o, int a, int *pi, int *pj);
/* Kind of actuator a: "coordinate", "pair", "torque", "force",
 * "joint_torque"; the body of a torque or force actuator and the first
 * body of a joint torque (-1 otherwise). */
const char *mrvi_ocp_actuator_kind(const mrvi_ocp *o, int a);
int mrvi_ocp_actuator_body(const mrvi_ocp *o, int a);
/* Terminal conditions (equalities and penalties, in the order added, one
 * per row of a body condition): their number, and kind, coordinate (a
 * body's first coordinate for the body kinds), target (0 for an attitude
 * row) and penalty (0: equality) of condition i (any output pointer may be
 * NULL). */
int mrvi_ocp_n_terminals(const mrvi_ocp *o);
void mrvi_ocp_terminal(const mrvi_ocp *o, int i, mrvi_ocp_terminal_kind *kind,
                       int *coordinate, double *target, double *penalty);
/* Name of a terminal kind ("position", "velocity", "attitude",
 * "angular_velocity", "angular_velocity_body"); body of terminal condition
 * i (-1 for a coordinate) and its row (0..2) in the body's condition. */
const char *mrvi_ocp_terminal_kind_name(mrvi_ocp_terminal_kind kind);
int mrvi_ocp_terminal_body(const mrvi_ocp *o, int i, int *row);
/* Target rotation of terminal condition i when it is an attitude row: R
 * gets R_target (D x D row-major, D the model's dimension) and D is
 * returned; 0 for every other kind (R untouched). */
int mrvi_ocp_terminal_attitude(const mrvi_ocp *o, int i, double *R);
/* Name of an algorithm ("slsqp", "auglag-lbfgs", "auglag-mma",
 * "auglag-ccsaq"); the problem's algorithm and terminal tolerance. */
const char *mrvi_ocp_algorithm_name(mrvi_ocp_algorithm a);
mrvi_ocp_algorithm mrvi_ocp_get_algorithm(const mrvi_ocp *o);
double mrvi_ocp_terminal_tolerance(const mrvi_ocp *o);

/* Step solver path of the forward pass ("explicit", "sweep", "schur", ...,
 * "general"; doc/solver.md): the one the integrator takes for the model
 * and settings (integrator.solver honoured), except that pair actuators
 * need the general path; why (may be NULL) gets the reason.  NULL when
 * integrator.solver = structured and no structured path applies (the
 * evaluation then fails). */
const char *mrvi_ocp_solver_path(const mrvi_ocp *o, char *why, size_t len);

/* 1 when the loaded description has a `control:` section, else 0. */
int mrvi_ocp_has_control(const mrvi_system *sys);

/* Build the problem from the `control:` section of a loaded description
 * (doc/optimal-control.md): actuators, objective, terminal conditions,
 * solver settings.  *u0 (malloc'ed, n_controls) gets the initial guess.
 * On failure MRVI_EPARSE with "file:line:col: message" in msg. */
int mrvi_ocp_load(const mrvi_system *sys, mrvi_ocp **out, double **u0,
                  char *msg, size_t len);

#ifdef __cplusplus
}
#endif

#endif
