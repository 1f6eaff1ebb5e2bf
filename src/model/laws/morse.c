/* Morse law phi(s) = D (1 - exp(-a s))^2 with s = r - r_e: on a spring the
 * rest length is the equilibrium distance r_e, D the well depth and a the
 * width parameter (curvature 2 D a^2 at the minimum). */
#include "model/model.h"

#include <math.h>

static const char *const names[] = {"depth", "width"};

static int check(const double *par, char *msg, size_t len) {
  if (!isfinite(par[0]) || !(par[0] > 0) || !isfinite(par[1]) ||
      !(par[1] > 0)) {
    mrvi_fmt(msg, len, "morse law: depth and width must be finite and > 0");
    return MRVI_EINVAL;
  }
  return MRVI_OK;
}

static void eval(const double *par, double s, double *phi, double *dphi,
                 double *ddphi) {
  const double D = par[0], a = par[1], x = exp(-a * s);
  *phi = D * (1 - x) * (1 - x);
  *dphi = 2 * D * a * x * (1 - x);
  *ddphi = 2 * D * a * a * x * (2 * x - 1);
}

const mrvi_law mrvi_law_morse = {
    .name = "morse",
    .summary = "D (1 - exp(-a s))^2 with depth D, width a (s = r - r_e)",
    .n_params = 2,
    .param_names = names,
    .check = check,
    .eval = eval,
    .form = MRVI_LAW_FORM_MORSE,
};
