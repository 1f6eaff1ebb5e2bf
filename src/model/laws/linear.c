/* Linear (Hookean) law phi(s) = k s^2 / 2. */
#include "model/model.h"

#include <math.h>

static const char *const names[] = {"stiffness"};

static int check(const double *par, char *msg, size_t len) {
  if (!isfinite(par[0])) {
    mrvi_fmt(msg, len, "linear law: stiffness must be finite");
    return MRVI_EINVAL;
  }
  return MRVI_OK;
}

static void eval(const double *par, double s, double *phi, double *dphi,
                 double *ddphi) {
  const double k = par[0];
  *phi = 0.5 * k * s * s;
  *dphi = k * s;
  *ddphi = k;
}

static int degree(const double *par) {
  (void)par;
  return 2;
}

const mrvi_law mrvi_law_linear = {
    .name = "linear",
    .summary = "k s^2 / 2 with stiffness k",
    .n_params = 1,
    .param_names = names,
    .check = check,
    .eval = eval,
    .degree = degree,
    .form = MRVI_LAW_FORM_HOOKE,
};
