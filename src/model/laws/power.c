/* Power law phi(s) = c s^e (springs: s = |d| - L0; terms: s = a^T q - b). */
#include "model/model.h"

#include <math.h>

static const char *const names[] = {"coefficient", "exponent"};

static int check(const double *par, char *msg, size_t len) {
  if (!isfinite(par[0]) || !isfinite(par[1])) {
    mrvi_fmt(msg, len, "power law: coefficient and exponent must be finite");
    return MRVI_EINVAL;
  }
  if (par[1] < 0) {
    mrvi_fmt(msg, len, "power law: exponent must be >= 0 (got %g)", par[1]);
    return MRVI_EINVAL;
  }
  return MRVI_OK;
}

/* s^k for an integer k >= 0 by repeated squaring (exact sign for s < 0). */
static double ipow(double s, long k) {
  double r = 1.0;
  while (k > 0) {
    if (k & 1)
      r *= s;
    s *= s;
    k >>= 1;
  }
  return r;
}

static void eval(const double *par, double s, double *phi, double *dphi,
                 double *ddphi) {
  const double c = par[0], e = par[1];
  if (e == floor(e) && e < 64) {
    const long k = (long)e;
    *phi = c * ipow(s, k);
    *dphi = k >= 1 ? c * e * ipow(s, k - 1) : 0.0;
    *ddphi = k >= 2 ? c * e * (e - 1) * ipow(s, k - 2) : 0.0;
  } else {
    /* Real exponent: defined for s >= 0 only. */
    *phi = c * pow(s, e);
    *dphi = c * e * pow(s, e - 1);
    *ddphi = c * e * (e - 1) * pow(s, e - 2);
  }
}

/* A polynomial of degree e for an integer exponent e. */
static int degree(const double *par) {
  const double e = par[1];
  return e == floor(e) && e >= 0 && e <= 1e6 ? (int)e : -1;
}

const mrvi_law mrvi_law_power = {
    .name = "power",
    .summary = "c s^e with coefficient c, exponent e",
    .n_params = 2,
    .param_names = names,
    .check = check,
    .eval = eval,
    .degree = degree,
    .form = MRVI_LAW_FORM_POWER,
};
