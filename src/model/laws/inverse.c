/* Inverse-distance (Coulomb, Newtonian gravity) law phi(s) = k / s.  Use it
 * on springs with rest length 0, so s is the distance r.  k > 0 repels
 * (like charges: k = q_i q_j / (4 pi eps_0)); k < 0 attracts (gravity:
 * k = -G m_i m_j). */
#include "model/model.h"

#include <math.h>

static const char *const names[] = {"constant"};

static int check(const double *par, char *msg, size_t len) {
  if (!isfinite(par[0])) {
    mrvi_fmt(msg, len, "inverse law: constant must be finite");
    return MRVI_EINVAL;
  }
  return MRVI_OK;
}

static void eval(const double *par, double s, double *phi, double *dphi,
                 double *ddphi) {
  const double k = par[0];
  *phi = k / s;
  *dphi = -k / (s * s);
  *ddphi = 2 * k / (s * s * s);
}

const mrvi_law mrvi_law_inverse = {
    .name = "inverse",
    .summary = "k / s with constant k (> 0 repels: Coulomb; < 0 attracts: "
               "gravity)",
    .n_params = 1,
    .param_names = names,
    .check = check,
    .eval = eval,
};
