/* Integrator settings and the named schemes of arXiv 2406.12991 §3.3. */
#include "step/step.h"

#include <math.h>
#include <string.h>

typedef struct scheme_def {
  const char *name;
  mrvi_rule slow;
  mrvi_grid slow_grid;
  mrvi_rule fast;
} scheme_def;

/* The paper's experiments use the left rectangle (alpha = gamma = 1) where
 * they say trapezoidal (§6). */
static const scheme_def schemes[] = {
    /* th:midfmids, "Q1" */
    {"midpoint-midpoint", {0.5, 0.5}, MRVI_GRID_MICRO, {0.5, 0.5}},
    /* th:midftraps, "Q2" */
    {"trapezoidal-midpoint", {1.0, 1.0}, MRVI_GRID_MICRO, {0.5, 0.5}},
    /* th:trapftraps, "Q3" */
    {"trapezoidal-trapezoidal", {1.0, 1.0}, MRVI_GRID_MICRO, {1.0, 1.0}},
    /* ex:slow_ex__fast_im: eq:slow_potential_affine + midpoint W */
    {"explicit-slow", {0.5, 0.5}, MRVI_GRID_MACRO, {0.5, 0.5}},
    /* ex:fully_ex: eq:slow_potential_affine + eq:fast_potential_trapezoidal */
    {"fully-explicit", {0.5, 0.5}, MRVI_GRID_MACRO, {0.5, 1.0}},
};

#define N_SCHEMES ((int)(sizeof schemes / sizeof schemes[0]))

const char *const *mrvi_scheme_names(void) {
  static const char *names[N_SCHEMES + 1];
  for (int i = 0; i < N_SCHEMES; i++)
    names[i] = schemes[i].name;
  names[N_SCHEMES] = NULL;
  return names;
}

int mrvi_settings_set_scheme(mrvi_settings *s, const char *scheme) {
  for (int i = 0; i < N_SCHEMES; i++)
    if (scheme && strcmp(schemes[i].name, scheme) == 0) {
      mrvi_fmt(s->scheme, sizeof s->scheme, "%s", schemes[i].name);
      s->slow = schemes[i].slow;
      s->slow_grid = schemes[i].slow_grid;
      s->fast = schemes[i].fast;
      return MRVI_OK;
    }
  return MRVI_EINVAL;
}

void mrvi_settings_default(mrvi_settings *s) {
  memset(s, 0, sizeof *s);
  mrvi_settings_set_scheme(s, "midpoint-midpoint");
  s->macro_step = 0.01;
  s->micro_steps = 1;
  s->t_end = 1.0;
  s->newton_tol = 1e-9;
  s->newton_max_iter = 20;
  s->constraint_form = MRVI_FORM_MULTIPLIERS;
  s->constraint_tol = 1e-10;
  s->project_momenta = 1;
  s->solver = MRVI_SOLVER_AUTO;
  s->energy_warning = 0.1;
  s->threads = 1;
  mrvi_tuning_default(&s->tuning);
}

static int unit(double v) { return isfinite(v) && v >= 0.0 && v <= 1.0; }

int mrvi_settings_check(const mrvi_settings *s, char *msg, size_t len) {
  if (!unit(s->slow.alpha) || !unit(s->slow.gamma) || !unit(s->fast.alpha) ||
      !unit(s->fast.gamma)) {
    mrvi_fmt(msg, len, "alpha and gamma must lie in [0, 1]");
    return MRVI_EINVAL;
  }
  if (s->slow_grid != MRVI_GRID_MICRO && s->slow_grid != MRVI_GRID_MACRO) {
    mrvi_fmt(msg, len, "slow grid must be micro or macro");
    return MRVI_EINVAL;
  }
  if (!(isfinite(s->macro_step) && s->macro_step > 0)) {
    mrvi_fmt(msg, len, "macro_step must be positive (got %g)", s->macro_step);
    return MRVI_EINVAL;
  }
  if (s->micro_steps < 1) {
    mrvi_fmt(msg, len, "micro_steps must be at least 1 (got %d)",
             s->micro_steps);
    return MRVI_EINVAL;
  }
  if (!(isfinite(s->t_end) && s->t_end >= s->macro_step)) {
    mrvi_fmt(msg, len, "t_end (%g) must be at least macro_step (%g)", s->t_end,
             s->macro_step);
    return MRVI_EINVAL;
  }
  /* N = ceil(t_end / macro_step) and N p stay exact integers in a double
   * and a long (2^53). */
  const double max_steps = 9007199254740992.0;
  if (!(s->t_end / s->macro_step < max_steps) ||
      !((double)mrvi_settings_n_steps(s) * s->micro_steps < max_steps)) {
    mrvi_fmt(msg, len,
             "t_end / macro_step × micro_steps = %g / %g × %d: too many steps "
             "(at most 2^53)",
             s->t_end, s->macro_step, s->micro_steps);
    return MRVI_EINVAL;
  }
  if (!(isfinite(s->newton_tol) && s->newton_tol > 0)) {
    mrvi_fmt(msg, len, "newton tolerance must be positive (got %g)",
             s->newton_tol);
    return MRVI_EINVAL;
  }
  if (!(isfinite(s->energy_warning) && s->energy_warning >= 0)) {
    mrvi_fmt(msg, len, "energy_warning must be >= 0 (got %g)",
             s->energy_warning);
    return MRVI_EINVAL;
  }
  if (s->threads < 0) {
    mrvi_fmt(msg, len, "threads must be >= 0 (0: the cores available; got %d)",
             s->threads);
    return MRVI_EINVAL;
  }
  if (s->threads > 1 && !mrvi_threads_supported()) {
    mrvi_fmt(msg, len,
             "threads = %d: this build has no threads (built without OpenMP; "
             "meson setup -Dopenmp=enabled)",
             s->threads);
    return MRVI_EINVAL;
  }
  if (s->newton_max_iter < 1) {
    mrvi_fmt(msg, len, "newton max_iterations must be at least 1 (got %d)",
             s->newton_max_iter);
    return MRVI_EINVAL;
  }
  if (s->constraint_form != MRVI_FORM_MULTIPLIERS &&
      s->constraint_form != MRVI_FORM_NULL_SPACE) {
    mrvi_fmt(msg, len, "constraint form must be multipliers or null-space");
    return MRVI_EINVAL;
  }
  if (s->solver != MRVI_SOLVER_AUTO && s->solver != MRVI_SOLVER_STRUCTURED &&
      s->solver != MRVI_SOLVER_GENERAL) {
    mrvi_fmt(msg, len, "solver must be auto, structured or general");
    return MRVI_EINVAL;
  }
  if (!(isfinite(s->constraint_tol) && s->constraint_tol > 0)) {
    mrvi_fmt(msg, len, "constraint tolerance must be positive (got %g)",
             s->constraint_tol);
    return MRVI_EINVAL;
  }
  return mrvi_tuning_check(&s->tuning, msg, len);
}

long mrvi_settings_n_steps(const mrvi_settings *s) {
  return (long)ceil(s->t_end / s->macro_step - 1e-9);
}
