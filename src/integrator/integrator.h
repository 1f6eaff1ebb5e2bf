/* What src/integrator/ offers the layers above it beyond mrvi.h: the
 * control forces of optimal control and the switches and counters of the
 * step paths that the tests force and read (integrator.c). */
#ifndef MRVI_INTEGRATOR_H
#define MRVI_INTEGRATOR_H

#include "solver/solver.h"

/* Control forces of the next steps (optimal control, src/ocp/): f_rows
 * (n_unknowns of the step) and f_end (ns + nf) as in struct mrvi_step, read
 * at every step (the caller updates them in place between steps); NULL for
 * none.  Every path honours them (doc/solver.md). */
void mrvi_integrator_set_forces(mrvi_integrator *it, const double *f_rows,
                                const double *f_end);

/* mrvi_integrator_create with configuration-dependent control forces
 * (optimal control's state actuators, src/ocp/state_forces.c): the step
 * hooks extra (residual and Jacobian entries, mrvi_step.extra) and end
 * (f^+ into f_end at the converged step, mrvi_step.extra_end), called with
 * ctx, set before the path builds its Jacobian pattern.  The Newton paths
 * take them through the CSC assembly (schur's direct block assembly falls
 * back to it); the callers choose those paths (ocp.c, ocp_path). */
int mrvi_integrator_create_hooked(
    const mrvi_model *m, const mrvi_settings *s,
    void (*extra)(void *ctx, mrvi_step *st, const double *x, double *R,
                  int jac),
    void (*end)(void *ctx, mrvi_step *st, const double *x), void *ctx,
    mrvi_integrator **out, char *msg, size_t len);

/* The multipliers of the last step in the step's layout (mrvi_step:
 * n_lambda, slow rows then the micro nodes'), as the Newton iteration
 * converged to them: optimal control keeps them for its adjoint. */
const double *mrvi_integrator_step_multipliers(const mrvi_integrator *it);

/* The integrator's choice of the chord matrix on the schur path (tests
 * force either): by its rule (auto, the default), never, or for the first
 * update of every step where the structure admits it. */
enum { MRVI_CHORD_AUTO = 0, MRVI_CHORD_OFF = 1, MRVI_CHORD_ON = 2 };
void mrvi_integrator_set_chord(mrvi_integrator *it, int mode);
/* The same for the constant chord (mrvi_blocks_const_factor): by its rule
 * (auto), never, or for the first update of every schur step. */
void mrvi_integrator_set_const_chord(mrvi_integrator *it, int mode);
/* The same for shooting (mrvi_predict_shoot; auto: where the predictor
 * admits it and the constant chord does not take the step), the steps it
 * solved in the run and, of those, the steps whose last update was made
 * without its sweep. */
void mrvi_integrator_set_shoot(mrvi_integrator *it, int mode);
long mrvi_integrator_shoot_steps(const mrvi_integrator *it);
long mrvi_integrator_shoot_last_steps(const mrvi_integrator *it);
/* Factorisations of the schur and schur-bordered paths so far (the
 * constant chord's counted once). */
long mrvi_integrator_factorisations(const mrvi_integrator *it);

/* The checks every user of a model and settings starts with (integrator,
 * optimal control): both given, the settings valid, at least one
 * coordinate; MRVI_OK or a status with the message. */
int mrvi_integrator_check_inputs(const mrvi_model *m, const mrvi_settings *s,
                                 char *msg, size_t len);

#endif
