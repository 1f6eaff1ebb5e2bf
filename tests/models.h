/* The paper's validation systems built with the C API (arXiv 2406.12991 §6,
 * doc/reproduction.md), so the numerical tests do not depend on the
 * description-file loader. */
#ifndef MRVI_TEST_MODELS_H
#define MRVI_TEST_MODELS_H

#include "mrvi.h"

#include <stddef.h>

/* FPU (§6): l = 3, unit masses, omega^2 = 2500. */
mrvi_model *test_fpu(void);
/* The same with the laws of V and W named (tables like power's and
 * linear's). */
mrvi_model *test_fpu_laws(const char *power, const char *linear);
/* Spring ring (§6): 6 particles of mass 2 in 3-D, odd slow, even fast. */
mrvi_model *test_spring_ring(void);
/* Harmonic oscillator, slow only: V = omega^2 q^2 / 2, unit mass. */
mrvi_model *test_oscillator(double omega);

/* Cart pendulum (doc/constraints.md): slow cart (mass 5) on the plane z = 0,
 * fast bob (mass 0.5) on a rod of length 0.2 at 30 degrees, gravity -9.81 e3.
 * Constraints: 0 = plane (macro nodes), 1 = rod (micro nodes). */
mrvi_model *test_cart_pendulum(void);
/* Spring ring with a rod between m1 (slow) and m2 (fast). */
mrvi_model *test_spring_ring_rod(void);

/* Jacobian of an assembled step (st->Ax at x, n_total unknowns) against
 * central differences of its residual: returns the largest entry error and
 * writes the largest Jacobian entry to *scale.  x is restored. */
struct mrvi_step;
double test_step_fd_error(struct mrvi_step *st, double *x, double *scale);

/* Settings for a named scheme with dT, p, t_end and Newton tolerance. */
/* Known data of a step at the model's initial state: q0 and M v0 split
 * into the rate blocks qs, ps (n_slow) and qf, pf (n_fast), set on st. */
void test_initial_data(struct mrvi_step *st, double *qs, double *qf, double *ps,
                       double *pf);

/* schur-bordered's transposed solve (the adjoint of optimal control) on
 * m's step with s (multiplier form): after mrvi_bordered_factor of the
 * step's Jacobian J at its free-flight predictor (multipliers
 * 0.1 cos(1.3 i): their Hessian terms), y = mrvi_bordered_solve_transpose
 * of c, and x = mrvi_bordered_solve of b.  *res: max |c - J^T y| (J^T y
 * from the CSC entries) relative to the largest row sum of |terms|;
 * *dual: |c.x - y.b| relative to the sum of |terms|; *on_chain:
 * mrvi_bordered_on_chain; *multi: the largest difference between the
 * columns of mrvi_bordered_solve_transpose_n of three right-hand sides
 * (c, b, and c zero at the even rows) and their single solves, relative
 * to the largest entry (0: each column equal to its single solve).
 * Returns the first failing status (its message in msg). */
int test_bordered_transpose_solve(const mrvi_model *m, const mrvi_settings *s,
                                  double *res, double *dual, int *on_chain,
                                  double *multi, char *msg, size_t len);

mrvi_settings test_settings(const char *scheme, double dT, int p, double t_end,
                            double tol);

#endif
