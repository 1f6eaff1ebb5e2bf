/* The tuning constants of the step solvers (MRVI_TUNING_LIST in mrvi.h,
 * doc/solver.md "Tuning"): their table, defaults, range checks and setting
 * by name.  The solvers read them from mrvi_settings.tuning (through
 * mrvi_step.tuning) at setup or once per step, never per element. */
#include "step/step.h"

#include <math.h>
#include <stddef.h>
#include <string.h>

/* The rows of the list, and where each value lives in mrvi_tuning. */
#define IS_INT_int 1
#define IS_INT_double 0
#define TUNING_INFO(type, name, def, lo, hi, meaning)                          \
  {#name, def, lo, hi, IS_INT_##type, meaning},
#define TUNING_OFFSET(type, name, def, lo, hi, meaning)                        \
  offsetof(mrvi_tuning, name),
static const mrvi_tuning_info rows[] = {MRVI_TUNING_LIST(TUNING_INFO)};
static const size_t offsets[] = {MRVI_TUNING_LIST(TUNING_OFFSET)};
#undef TUNING_INFO
#undef TUNING_OFFSET

#define N_ROWS ((int)(sizeof rows / sizeof rows[0]))

const mrvi_tuning_info *mrvi_tuning_table(int *count) {
  *count = N_ROWS;
  return rows;
}

void mrvi_tuning_default(mrvi_tuning *t) {
#define TUNING_DEFAULT(type, name, def, lo, hi, meaning) t->name = def;
  MRVI_TUNING_LIST(TUNING_DEFAULT)
#undef TUNING_DEFAULT
}

/* The row named `name`, or -1. */
static int find(const char *name) {
  for (int i = 0; name && i < N_ROWS; i++)
    if (strcmp(rows[i].name, name) == 0)
      return i;
  return -1;
}

/* The value of row i in t. */
static double get(const mrvi_tuning *t, int i) {
  const char *p = (const char *)t + offsets[i];
  if (rows[i].integer) {
    int v;
    memcpy(&v, p, sizeof v);
    return v;
  }
  double v;
  memcpy(&v, p, sizeof v);
  return v;
}

/* Whether v is a value of row i: in its range, integral for an integer. */
static int valid(int i, double v, char *msg, size_t len) {
  const mrvi_tuning_info *r = &rows[i];
  if (!(v >= r->lowest && v <= r->highest)) {
    mrvi_fmt(msg, len, "tuning %s must lie in [%g, %g] (got %g)", r->name,
             r->lowest, r->highest, v);
    return 0;
  }
  if (r->integer && v != floor(v)) {
    mrvi_fmt(msg, len, "tuning %s must be an integer (got %g)", r->name, v);
    return 0;
  }
  return 1;
}

int mrvi_settings_set_tuning(mrvi_settings *s, const char *name, double value,
                             char *msg, size_t len) {
  const int i = find(name);
  if (i < 0) {
    const char *names[N_ROWS];
    for (int j = 0; j < N_ROWS; j++)
      names[j] = rows[j].name;
    const char *hint = name ? mrvi_closest(name, names, N_ROWS) : NULL;
    mrvi_fmt(msg, len,
             "unknown tuning constant '%s'%s%s%s (doc/solver.md, "
             "\"Tuning\", lists them)",
             name ? name : "(null)", hint ? " (did you mean '" : "",
             hint ? hint : "", hint ? "'?)" : "");
    return MRVI_EINVAL;
  }
  if (!valid(i, value, msg, len))
    return MRVI_EINVAL;
  char *p = (char *)&s->tuning + offsets[i];
  if (rows[i].integer) {
    const int v = (int)value;
    memcpy(p, &v, sizeof v);
  } else {
    memcpy(p, &value, sizeof value);
  }
  return MRVI_OK;
}

int mrvi_settings_get_tuning(const mrvi_settings *s, const char *name,
                             double *value) {
  const int i = find(name);
  if (i < 0)
    return MRVI_EINVAL;
  *value = get(&s->tuning, i);
  return MRVI_OK;
}

int mrvi_tuning_check(const mrvi_tuning *t, char *msg, size_t len) {
  for (int i = 0; i < N_ROWS; i++)
    if (!valid(i, get(t, i), msg, len))
      return MRVI_EINVAL;
  return MRVI_OK;
}

int mrvi_tuning_check_model(const mrvi_tuning *t, long block, long step,
                            char *msg, size_t len) {
  static const char *const dense[] = {"dense_max", "bordered_max",
                                      "bordered_node_max", "bordered_slow_max",
                                      "chain_block_max"};
  for (size_t k = 0; k < sizeof dense / sizeof *dense; k++) {
    const double v = get(t, find(dense[k]));
    const long most = k + 1 < sizeof dense / sizeof *dense ? block : step;
    if (v > MRVI_DENSE_BLOCK_MAX && most > MRVI_DENSE_BLOCK_MAX) {
      mrvi_fmt(msg, len,
               "tuning %s = %.0f would let the step solvers factorise "
               "blocks of up to %ld unknowns as dense matrices (%s); a dense "
               "block has at most %d rows: set %s to at most %d",
               dense[k], v, most,
               most == block ? "this model's coordinates and constraint rows"
                             : "this model's step",
               MRVI_DENSE_BLOCK_MAX, dense[k], MRVI_DENSE_BLOCK_MAX);
      return MRVI_EINVAL;
    }
  }
  return MRVI_OK;
}
