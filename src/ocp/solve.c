/* NLopt driver: single shooting over the controls with adjoint gradients.
 * NLopt asks for the cost and the constraints separately at the same
 * point, so the last evaluation is cached.  SLSQP can report success with
 * violated constraints: the terminal residuals are re-checked here, and
 * the outcome is one status of mrvi_ocp_result (doc/optimal-control.md,
 * "Status"): converged only for a tolerance reached with the terminal
 * conditions met. */
#include "ocp/ocp_internal.h"

#include <math.h>
#include <nlopt.h>
#include <stdlib.h>
#include <string.h>

typedef struct cache {
  mrvi_ocp *o;
  double *u, *grad, *c, *cgrad;
  double J;
  int valid, status, evaluations, stop;
  nlopt_opt opt; /* for nlopt_force_stop */
  /* The best iterate so far (the result of an interruption): the lowest
   * cost among the iterates meeting the terminal conditions, else the
   * lowest violation; have_best = 0 before the first evaluation. */
  double *best_u, best_J, best_violation;
  int have_best;
  /* Bounds and workspace of the KKT residual (stationarity). */
  const double *lb, *ub;
  double *kkt; /* n + m (m + 1) */
} cache;

static int cached_eval(cache *cc, const double *u) {
  const int n = cc->o->n_u;
  if (cc->valid && memcmp(u, cc->u, (size_t)n * sizeof *u) == 0)
    return cc->status;
  memcpy(cc->u, u, (size_t)n * sizeof *u);
  cc->status = mrvi_ocp_evaluate(cc->o, u, &cc->J, cc->grad, cc->c, cc->cgrad);
  cc->valid = 1;
  return cc->status;
}

static double violation(const cache *cc) {
  double v = 0.0;
  for (int i = 0; i < cc->o->n_con; i++)
    v = fmax(v, fabs(cc->c[i]));
  return v;
}

/* Keep u (just evaluated) if it is better than the best so far. */
static void keep_best(cache *cc, const double *u) {
  const double tol = cc->o->terminal_tol, v = violation(cc);
  const int met = v <= tol, best_met = cc->best_violation <= tol;
  const int better = !cc->have_best ||
                     (met && (!best_met || cc->J < cc->best_J)) ||
                     (!met && !best_met && v < cc->best_violation);
  if (!better)
    return;
  memcpy(cc->best_u, u, (size_t)cc->o->n_u * sizeof *u);
  cc->best_J = cc->J;
  cc->best_violation = v;
  cc->have_best = 1;
}

/* KKT residual of the last evaluation at u: the norm of the projected
 * gradient of the Lagrangian,
 *   r = grad J + A^T mu,   A = d(terminal conditions)/du (m x n),
 * with the least-squares multipliers mu of the free controls F (those
 * strictly inside their bounds): (A_F A_F^T) mu = -A_F (grad J)_F.  A
 * control at its lower bound counts with min(r_i, 0), at its upper bound
 * with max(r_i, 0) (the sign the bound's own multiplier cannot absorb).
 * 0 at a KKT point of the bound- and equality-constrained problem, where
 * |grad J| itself need not vanish; |grad J| without constraints and
 * active bounds.  (A dependent A_F gets a relative ridge of 1e-14.) */
static double stationarity(cache *cc, const double *u) {
  const int n = cc->o->n_u, m = cc->o->n_con;
  const double *g = cc->grad, *A = cc->cgrad;
  double *r = cc->kkt, *N = cc->kkt + n, *mu = N + (size_t)m * (size_t)m;
  for (int a = 0; a < m; a++) {
    mu[a] = 0.0;
    for (int i = 0; i < n; i++)
      if (u[i] > cc->lb[i] && u[i] < cc->ub[i])
        mu[a] -= A[(size_t)a * n + i] * g[i];
    for (int b = 0; b < m; b++) {
      double s = 0.0;
      for (int i = 0; i < n; i++)
        if (u[i] > cc->lb[i] && u[i] < cc->ub[i])
          s += A[(size_t)a * n + i] * A[(size_t)b * n + i];
      N[a * m + b] = s;
    }
  }
  double trace = 0.0;
  for (int a = 0; a < m; a++)
    trace += N[a * m + a];
  for (int a = 0; a < m; a++)
    N[a * m + a] += 1e-14 * (trace > 0.0 ? trace / m : 1.0);
  if (m > 0 && mrvi_dense_solve(m, N, mu) < 0)
    for (int a = 0; a < m; a++)
      mu[a] = 0.0;
  double r2 = 0.0;
  for (int i = 0; i < n; i++) {
    r[i] = g[i];
    for (int a = 0; a < m; a++)
      r[i] += A[(size_t)a * n + i] * mu[a];
    const double v = u[i] <= cc->lb[i]   ? fmin(r[i], 0.0)
                     : u[i] >= cc->ub[i] ? fmax(r[i], 0.0)
                                         : r[i];
    r2 += v * v;
  }
  return sqrt(r2);
}

static double objective(unsigned n, const double *u, double *grad, void *data) {
  cache *cc = data;
  if (cached_eval(cc, u) < 0) {
    cc->stop = 1;
    return HUGE_VAL;
  }
  keep_best(cc, u);
  if (grad)
    memcpy(grad, cc->grad, n * sizeof *grad);
  cc->evaluations++;
  mrvi_ocp *o = cc->o;
  if (o->cb) {
    double g2 = 0.0;
    for (unsigned i = 0; i < n; i++)
      g2 += cc->grad[i] * cc->grad[i];
    o->best_u = cc->best_u;
    const int stop = o->cb(o->cb_data, cc->evaluations, cc->J, violation(cc),
                           sqrt(g2), stationarity(cc, u));
    o->best_u = NULL;
    if (stop) {
      cc->stop = 2;
      nlopt_force_stop(cc->opt);
    }
  }
  return cc->J;
}

static void constraints(unsigned m, double *result, unsigned n, const double *u,
                        double *grad, void *data) {
  cache *cc = data;
  if (cached_eval(cc, u) < 0) {
    cc->stop = 1;
    for (unsigned i = 0; i < m; i++)
      result[i] = HUGE_VAL;
    return;
  }
  memcpy(result, cc->c, m * sizeof *result);
  if (grad)
    memcpy(grad, cc->cgrad, (size_t)m * n * sizeof *grad);
}

/* The status of NLopt's outcome r at the re-checked result res (cost,
 * violation set) into res->status; MRVI_OK only for "converged".  stop
 * = 2: the callback asked to stop.  (An evaluation that failed, stop = 1,
 * is a step NLopt may back off from; the re-check judges the result.) */
static int classify(mrvi_ocp *o, nlopt_result r, int stop,
                    mrvi_ocp_result *res) {
  const char *s;
  const int met = res->violation <= o->terminal_tol;
  int st = MRVI_EOPTIMIZE;
  if (stop == 2) {
    s = "interrupted";
    st = mrvi_ocp_fail(o, MRVI_EINTERRUPTED,
                       "optimisation interrupted after %d evaluations; the "
                       "best iterate is returned",
                       res->evaluations);
  } else if (r == NLOPT_MAXEVAL_REACHED || r == NLOPT_MAXTIME_REACHED) {
    s = r == NLOPT_MAXEVAL_REACHED ? "max_evaluations" : "max_time";
    st = mrvi_ocp_fail(
        o, MRVI_EOPTIMIZE,
        "not converged: NLopt stopped at its %s (%d evaluations; raise "
        "control.solver.max_evaluations); terminal violation %.3e",
        r == NLOPT_MAXEVAL_REACHED ? "evaluation limit" : "time limit",
        res->evaluations, res->violation);
  } else if (r == NLOPT_ROUNDOFF_LIMITED) {
    s = "roundoff_limited";
    st = mrvi_ocp_fail(o, MRVI_EOPTIMIZE,
                       "not converged: NLopt stopped by roundoff before its "
                       "tolerance; terminal violation %.3e%s",
                       res->violation, met ? " (met)" : " (NOT met)");
  } else if (r < 0) {
    s = "failed";
    st = mrvi_ocp_fail(o, MRVI_EOPTIMIZE, "NLopt failed: %s", res->nlopt_name);
  } else if (!isfinite(res->cost)) {
    /* NLopt may call a NaN or infinite cost a success (no constraints to
     * re-check): never converged. */
    s = "failed";
    st = mrvi_ocp_fail(o, MRVI_EOPTIMIZE,
                       "the cost at the returned controls is %g (NLopt: %s)",
                       res->cost, res->nlopt_name);
  } else if (!met) {
    /* NLOPT_SUCCESS, STOPVAL, FTOL or XTOL reached, constraints violated. */
    s = "terminal_not_met";
    st = mrvi_ocp_fail(
        o, MRVI_EOPTIMIZE,
        "terminal conditions not met: max violation %.3e > tolerance %.3e "
        "(NLopt: %s)",
        res->violation, o->terminal_tol, res->nlopt_name);
  } else {
    s = "converged";
    st = MRVI_OK;
  }
  mrvi_fmt(res->status, sizeof res->status, "%s", s);
  return st;
}

int mrvi_ocp_solve(mrvi_ocp *o, double *u, mrvi_ocp_result *res) {
  memset(res, 0, sizeof *res);
  const int n = o->n_u, m = o->n_con;
  if (n == 0)
    return mrvi_ocp_fail(o, MRVI_EINVAL, "the problem has no actuators");
  cache cc = {.o = o};
  cc.u = calloc((size_t)n, sizeof(double));
  cc.grad = calloc((size_t)n, sizeof(double));
  cc.c = calloc((size_t)m + 1, sizeof(double));
  cc.cgrad = calloc((size_t)m * (size_t)n + 1, sizeof(double));
  cc.best_u = calloc((size_t)n, sizeof(double));
  double *lb = calloc((size_t)n, sizeof(double));
  double *ub = calloc((size_t)n, sizeof(double));
  double *tol = calloc((size_t)m + 1, sizeof(double));
  cc.kkt = calloc((size_t)n + (size_t)m * (size_t)(m + 1) + 1, sizeof(double));
  cc.lb = lb;
  cc.ub = ub;
  nlopt_opt opt = NULL, local = NULL;
  int status = MRVI_OK;
  if (!cc.u || !cc.grad || !cc.c || !cc.cgrad || !cc.best_u || !lb || !ub ||
      !tol || !cc.kkt) {
    status = mrvi_ocp_fail(o, MRVI_ENOMEM, "out of memory");
    goto done;
  }
  for (int a = 0; a < o->n_act; a++)
    for (int j = 0; j < o->act[a].size; j++) {
      lb[o->act[a].offset + j] = o->act[a].lower;
      ub[o->act[a].offset + j] = o->act[a].upper;
      double *v = &u[o->act[a].offset + j];
      *v = fmin(fmax(*v, o->act[a].lower), o->act[a].upper);
    }
  for (int i = 0; i < m; i++)
    tol[i] = o->terminal_tol;
  static const nlopt_algorithm inner[] = {NLOPT_LD_SLSQP, NLOPT_LD_LBFGS,
                                          NLOPT_LD_MMA, NLOPT_LD_CCSAQ};
  if (o->algorithm == MRVI_OCP_SLSQP) {
    opt = nlopt_create(NLOPT_LD_SLSQP, (unsigned)n);
  } else {
    opt = nlopt_create(NLOPT_LD_AUGLAG, (unsigned)n);
    local = nlopt_create(inner[o->algorithm], (unsigned)n);
    if (local) {
      nlopt_set_ftol_rel(local, o->ftol_rel);
      nlopt_set_xtol_rel(local, 1e-14);
      nlopt_set_local_optimizer(opt, local);
    }
  }
  if (!opt || (o->algorithm != MRVI_OCP_SLSQP && !local)) {
    status = mrvi_ocp_fail(o, MRVI_ENOMEM, "NLopt could not be created");
    goto done;
  }
  cc.opt = opt;
  nlopt_set_lower_bounds(opt, lb);
  nlopt_set_upper_bounds(opt, ub);
  nlopt_set_min_objective(opt, objective, &cc);
  if (m > 0)
    nlopt_add_equality_mconstraint(opt, (unsigned)m, constraints, &cc, tol);
  nlopt_set_ftol_rel(opt, o->ftol_rel);
  nlopt_set_xtol_rel(opt, 1e-14);
  nlopt_set_maxeval(opt, o->max_eval);
  double fmin = 0.0;
  const nlopt_result r = nlopt_optimize(opt, u, &fmin);
  res->nlopt_result = (int)r;
  mrvi_fmt(res->nlopt_name, sizeof res->nlopt_name, "%s",
           nlopt_result_to_string(r));
  res->evaluations = cc.evaluations;
  /* An interrupted optimisation returns its best iterate (NLopt's x after
   * a forced stop is not documented to be one). */
  if (cc.stop == 2 && cc.have_best)
    memcpy(u, cc.best_u, (size_t)n * sizeof *u);
  /* Re-check at the returned controls. */
  cc.valid = 0;
  const int se = cached_eval(&cc, u);
  if (se < 0) {
    status = se;
    mrvi_fmt(res->status, sizeof res->status, "%s", "failed");
    goto done;
  }
  res->cost = cc.J;
  res->violation = violation(&cc);
  status = classify(o, r, cc.stop, res);
done:
  nlopt_destroy(local);
  nlopt_destroy(opt);
  free(cc.u);
  free(cc.grad);
  free(cc.c);
  free(cc.cgrad);
  free(cc.best_u);
  free(cc.kkt);
  free(lb);
  free(ub);
  free(tol);
  return status;
}
