/* Lennard-Jones law with a cutoff, truncated and shifted:
 *   phi(s) = 4 eps [(sig/s)^12 - (sig/s)^6] - phi_LJ(r_c)   for s < r_c,
 *   phi(s) = 0                                              for s >= r_c.
 * The energy is continuous at the cutoff (energy shift only, as LAMMPS's
 * lj/cut with `pair_modify shift yes`); the force jumps there by
 * phi_LJ'(r_c) (about 0.039 eps/sig at r_c = 2.5 sig).  Use it on springs
 * with rest length 0, so s is the distance r. */
#include "model/model.h"

#include <math.h>

static const char *const names[] = {"epsilon", "sigma", "cutoff"};

static int check(const double *par, char *msg, size_t len) {
  for (int i = 0; i < 3; i++)
    if (!isfinite(par[i]) || !(par[i] > 0)) {
      mrvi_fmt(msg, len, "lennard-jones law: %s must be finite and > 0",
               names[i]);
      return MRVI_EINVAL;
    }
  return MRVI_OK;
}

static double lj(double eps, double sig, double s) {
  const double x6 = pow(sig / s, 6);
  return 4 * eps * (x6 * x6 - x6);
}

static void eval(const double *par, double s, double *phi, double *dphi,
                 double *ddphi) {
  const double eps = par[0], sig = par[1], rc = par[2];
  if (s >= rc) {
    *phi = *dphi = *ddphi = 0.0;
    return;
  }
  const double x6 = pow(sig / s, 6), x12 = x6 * x6;
  *phi = 4 * eps * (x12 - x6) - lj(eps, sig, rc);
  *dphi = 4 * eps * (-12 * x12 + 6 * x6) / s;
  *ddphi = 4 * eps * (156 * x12 - 42 * x6) / (s * s);
}

const mrvi_law mrvi_law_lennard_jones = {
    .name = "lennard-jones",
    .summary = "4 eps [(sig/s)^12 - (sig/s)^6], cut at s = cutoff and "
               "shifted to 0 there",
    .n_params = 3,
    .param_names = names,
    .check = check,
    .eval = eval,
};
