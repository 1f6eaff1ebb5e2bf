/* `integrator:` of a description file: scheme and rules, steps, Newton,
 * solver and constraint settings; and the sizes a run would allocate. */
#include "io/loader/loader_internal.h"

#include "step/step.h"

#include <limits.h>
#include <stdio.h>
#include <string.h>

static const char *const integrator_keys[] = {
    "scheme", "slow",        "fast",   "macro_step",     "micro_steps", "t_end",
    "newton", "constraints", "solver", "energy_warning", "tuning"};

static const char *const slow_rule_keys[] = {"alpha", "gamma", "grid"};

static const char *const fast_rule_keys[] = {"alpha", "gamma"};

static const char *const newton_keys[] = {"tolerance", "max_iterations",
                                          "criterion"};

static const char *const constraint_setting_keys[] = {"form", "tolerance",
                                                      "projection"};

/* alpha and gamma of one rule, each in [0, 1]. */
static int load_rule(loader *L, struct fy_node *map, const char *where,
                     mrvi_rule *r) {
  static const char *const keys[] = {"alpha", "gamma"};
  double *val[] = {&r->alpha, &r->gamma};
  for (int i = 0; i < 2; i++) {
    struct fy_node *n = mrvi_ld_get(map, keys[i]);
    char what[64];
    mrvi_fmt(what, sizeof what, "%s.%s", where, keys[i]);
    if (!n)
      continue;
    int st = mrvi_ld_as_number(L, n, what, val[i]);
    if (st)
      return st;
    if (*val[i] < 0 || *val[i] > 1)
      return mrvi_ld_fail(L, n, "%s must be in [0, 1], got %s", what,
                          mrvi_ld_scalar0(n));
  }
  return MRVI_OK;
}

/* integrator.constraints: {form, tolerance, projection} (doc/constraints.md).
 */
static int load_constraint_settings(loader *L, struct fy_node *map) {
  static const char *const forms[] = {"multipliers", "null-space"};
  mrvi_settings *s = &L->sys->settings;
  struct fy_node *v;
  int st, form;
  if ((st = mrvi_ld_want_mapping(L, map, "integrator.constraints")) ||
      (st = mrvi_ld_check_keys(L, map, "integrator.constraints",
                               constraint_setting_keys,
                               COUNT(constraint_setting_keys), NULL, 0)))
    return st;
  if ((v = mrvi_ld_get(map, "form"))) {
    if ((st = mrvi_ld_as_choice(L, v, "constraint form", forms, 2, &form)))
      return st;
    s->constraint_form = form ? MRVI_FORM_NULL_SPACE : MRVI_FORM_MULTIPLIERS;
  }
  if ((st = mrvi_ld_opt_positive(L, map, "tolerance", "constraint tolerance",
                                 &s->constraint_tol, NULL)))
    return st;
  if ((v = mrvi_ld_get(map, "projection")))
    return mrvi_ld_as_bool(L, v, "projection", &s->project_momenta);
  return MRVI_OK;
}

/* integrator.tuning: {name: value} of MRVI_TUNING_LIST (mrvi.h;
 * doc/solver.md, "Tuning"). */
static int load_tuning(loader *L, struct fy_node *map) {
  int count, st;
  const mrvi_tuning_info *t = mrvi_tuning_table(&count);
  const char *names[MAX_KEYS];
  const int n_names = count < MAX_KEYS ? count : MAX_KEYS;
  for (int i = 0; i < n_names; i++)
    names[i] = t[i].name;
  if ((st = mrvi_ld_want_mapping(L, map, "integrator.tuning")) ||
      (st = mrvi_ld_check_keys(L, map, "integrator.tuning", names, n_names,
                               NULL, 0)))
    return st;
  for (int i = 0; i < count; i++) {
    struct fy_node *v = mrvi_ld_get(map, t[i].name);
    double value;
    char msg[200];
    if (!v)
      continue;
    if ((st = mrvi_ld_as_number(L, v, t[i].name, &value)))
      return st;
    if (mrvi_settings_set_tuning(&L->sys->settings, t[i].name, value, msg,
                                 sizeof msg) < 0)
      return mrvi_ld_fail(L, v, "%s", msg);
  }
  return MRVI_OK;
}

int mrvi_ld_integrator(loader *L, struct fy_node *in) {
  mrvi_settings *s = &L->sys->settings;
  struct fy_node *n, *dT_node, *t_node;
  int st;
  if ((st = mrvi_ld_want_mapping(L, in, "integrator")) ||
      (st = mrvi_ld_check_keys(L, in, "integrator", integrator_keys,
                               COUNT(integrator_keys), NULL, 0)))
    return st;
  /* The scheme sets both rules; slow/fast then override parts of them. */
  if ((n = mrvi_ld_get(in, "scheme"))) {
    const char *const *names = mrvi_scheme_names();
    int count = 0, which;
    while (names[count])
      count++;
    if ((st = mrvi_ld_as_choice(L, n, "scheme", names, count, &which)))
      return st;
    if ((st = mrvi_settings_set_scheme(s, names[which])))
      return mrvi_ld_fail(L, n, "cannot set scheme '%s'", names[which]);
  }
  if ((n = mrvi_ld_get(in, "slow"))) {
    static const char *const grids[] = {"micro", "macro"};
    struct fy_node *g;
    int grid;
    if ((st = mrvi_ld_want_mapping(L, n, "integrator.slow")) ||
        (st = mrvi_ld_check_keys(L, n, "integrator.slow", slow_rule_keys,
                                 COUNT(slow_rule_keys), NULL, 0)) ||
        (st = load_rule(L, n, "integrator.slow", &s->slow)))
      return st;
    if ((g = mrvi_ld_get(n, "grid"))) {
      if ((st = mrvi_ld_as_choice(L, g, "grid", grids, 2, &grid)))
        return st;
      s->slow_grid = grid ? MRVI_GRID_MACRO : MRVI_GRID_MICRO;
    }
  }
  if ((n = mrvi_ld_get(in, "fast")) &&
      ((st = mrvi_ld_want_mapping(L, n, "integrator.fast")) ||
       (st = mrvi_ld_check_keys(L, n, "integrator.fast", fast_rule_keys,
                                COUNT(fast_rule_keys), NULL, 0)) ||
       (st = load_rule(L, n, "integrator.fast", &s->fast))))
    return st;
  if ((st = mrvi_ld_opt_positive(L, in, "macro_step", "macro_step",
                                 &s->macro_step, &dT_node)))
    return st;
  if ((n = mrvi_ld_get(in, "micro_steps"))) {
    if ((st = mrvi_ld_as_int(L, n, "micro_steps", &s->micro_steps)))
      return st;
    if (s->micro_steps < 1)
      return mrvi_ld_fail(L, n, "micro_steps must be >= 1, got %d",
                          s->micro_steps);
  }
  if ((t_node = mrvi_ld_get(in, "t_end")) &&
      (st = mrvi_ld_as_number(L, t_node, "t_end", &s->t_end)))
    return st;
  if (s->t_end < s->macro_step)
    return mrvi_ld_fail(L, t_node ? t_node : dT_node,
                        "t_end (%g) must be >= macro_step (%g)", s->t_end,
                        s->macro_step);
  if ((n = mrvi_ld_get(in, "newton"))) {
    struct fy_node *v;
    if ((st = mrvi_ld_want_mapping(L, n, "integrator.newton")) ||
        (st = mrvi_ld_check_keys(L, n, "integrator.newton", newton_keys,
                                 COUNT(newton_keys), NULL, 0)))
      return st;
    if ((st = mrvi_ld_opt_positive(L, n, "tolerance", "tolerance",
                                   &s->newton_tol, NULL)))
      return st;
    if ((v = mrvi_ld_get(n, "max_iterations"))) {
      if ((st = mrvi_ld_as_int(L, v, "max_iterations", &s->newton_max_iter)))
        return st;
      if (s->newton_max_iter < 1)
        return mrvi_ld_fail(L, v, "max_iterations must be >= 1, got %d",
                            s->newton_max_iter);
    }
    if ((v = mrvi_ld_get(n, "criterion"))) {
      static const char *const criteria[] = {"absolute", "scaled"};
      int which;
      if ((st = mrvi_ld_as_choice(L, v, "criterion", criteria, 2, &which)))
        return st;
      s->newton_criterion = (mrvi_newton_criterion)which;
    }
  }
  if ((n = mrvi_ld_get(in, "energy_warning"))) {
    if ((st = mrvi_ld_as_number(L, n, "energy_warning", &s->energy_warning)))
      return st;
    if (!(s->energy_warning >= 0))
      return mrvi_ld_fail(L, n,
                          "energy_warning must be >= 0 (0: never warn), got %g",
                          s->energy_warning);
  }
  if ((n = mrvi_ld_get(in, "solver"))) { /* doc/solver.md */
    static const char *const solvers[] = {"auto", "structured", "general"};
    int which;
    if ((st = mrvi_ld_as_choice(L, n, "solver", solvers, 3, &which)))
      return st;
    s->solver = (mrvi_solver)which;
  }
  if ((n = mrvi_ld_get(in, "tuning")) && (st = load_tuning(L, n)))
    return st;
  if ((n = mrvi_ld_get(in, "constraints")))
    return load_constraint_settings(L, n);
  return MRVI_OK;
}

/* Sizes the integrator allocates per macro step: p n_f micro unknowns in
 * an int, and their storage within limits.max_memory. */
int mrvi_ld_check_sizes(loader *L, struct fy_node *at) {
  const mrvi_settings *s = &L->sys->settings;
  long long pn = (long long)s->micro_steps * mrvi_model_n_fast(L->sys->model);
  if (pn > INT_MAX / 8)
    return mrvi_ld_fail(
        L, at,
        "integrator.micro_steps × fast coordinates = %d × %d is too "
        "large (at most %d)",
        s->micro_steps, mrvi_model_n_fast(L->sys->model), INT_MAX / 8);
  /* the dense blocks the tuning allows, against the model's size */
  char why[400];
  const mrvi_model *m = L->sys->model;
  const long R = mrvi_model_constraint_rows(m);
  if (mrvi_tuning_check_model(&s->tuning, (long)mrvi_model_n(m) + R,
                              mrvi_model_n(m) - mrvi_model_n_fast(m) +
                                  (long)s->micro_steps *
                                      (mrvi_model_n_fast(m) + R),
                              why, sizeof why) < 0) {
    /* (at the constant's value: the message starts "tuning NAME =") */
    char name[64] = "";
    sscanf(why, "tuning %63s", name);
    struct fy_node *t = at ? mrvi_ld_get(at, "tuning") : NULL;
    struct fy_node *k =
        t && fy_node_is_mapping(t) ? mrvi_ld_get(t, name) : NULL;
    return mrvi_ld_fail(L, k ? k : t ? t : at, "%s", why);
  }
  /* eight vectors of the step's unknowns, and the quadrature points of
   * both potentials (2p + 2 each), within limits.max_memory (not the
   * machine's memory: the same refusal on every machine) */
  const double need = 8.0 * 8.0 * (double)(pn + mrvi_model_n(L->sys->model)) +
                      4.0 * ((double)s->micro_steps + 1.0) * sizeof(mrvi_point);
  return mrvi_ld_check_memory(
      L, at, need,
      "integrator.micro_steps × fast coordinates = %d × %d (and %d "
      "coordinates) need per macro step",
      s->micro_steps, mrvi_model_n_fast(L->sys->model),
      mrvi_model_n(L->sys->model));
}
