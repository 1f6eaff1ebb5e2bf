/* The tuning constants of the step solvers (MRVI_TUNING_LIST in mrvi.h,
 * doc/solver.md "Tuning"): their table, defaults, range checks and setting
 * by name.  The solvers read them from mrvi_settings.tuning (through
 * mrvi_step.tuning) at setup or once per step, never per element. */
#include "internal.h"

#include <math.h>
#include <stddef.h>
#include <string.h>

/* One row of the list with where its value lives in mrvi_tuning. */
typedef struct tuning_row {
  mrvi_tuning_info info;
  size_t offset;
} tuning_row;

#define IS_INT_int 1
#define IS_INT_double 0
#define TUNING_ROW(type, name, def, lo, hi, meaning)                           \
  {{#name, def, lo, hi, IS_INT_##type, meaning}, offsetof(mrvi_tuning, name)},
static const tuning_row rows[] = {MRVI_TUNING_LIST(TUNING_ROW)};
#undef TUNING_ROW

#define N_ROWS ((int)(sizeof rows / sizeof rows[0]))

const mrvi_tuning_info *mrvi_tuning_table(int *count) {
  static mrvi_tuning_info info[N_ROWS];
  for (int i = 0; i < N_ROWS; i++)
    info[i] = rows[i].info;
  *count = N_ROWS;
  return info;
}

void mrvi_tuning_default(mrvi_tuning *t) {
#define TUNING_DEFAULT(type, name, def, lo, hi, meaning) t->name = def;
  MRVI_TUNING_LIST(TUNING_DEFAULT)
#undef TUNING_DEFAULT
}

static const tuning_row *find(const char *name) {
  for (int i = 0; name && i < N_ROWS; i++)
    if (strcmp(rows[i].info.name, name) == 0)
      return &rows[i];
  return NULL;
}

static double get(const mrvi_tuning *t, const tuning_row *r) {
  const char *p = (const char *)t + r->offset;
  if (r->info.integer) {
    int v;
    memcpy(&v, p, sizeof v);
    return v;
  }
  double v;
  memcpy(&v, p, sizeof v);
  return v;
}

/* Whether v is a value of row r: in its range, integral for an integer. */
static int valid(const tuning_row *r, double v, char *msg, size_t len) {
  if (!(v >= r->info.lowest && v <= r->info.highest)) {
    mrvi_fmt(msg, len, "tuning %s must lie in [%g, %g] (got %g)", r->info.name,
             r->info.lowest, r->info.highest, v);
    return 0;
  }
  if (r->info.integer && v != floor(v)) {
    mrvi_fmt(msg, len, "tuning %s must be an integer (got %g)", r->info.name,
             v);
    return 0;
  }
  return 1;
}

int mrvi_settings_set_tuning(mrvi_settings *s, const char *name, double value,
                             char *msg, size_t len) {
  const tuning_row *r = find(name);
  if (!r) {
    const char *names[N_ROWS];
    for (int i = 0; i < N_ROWS; i++)
      names[i] = rows[i].info.name;
    const char *hint = name ? mrvi_closest(name, names, N_ROWS) : NULL;
    mrvi_fmt(msg, len,
             "unknown tuning constant '%s'%s%s%s (doc/solver.md, "
             "\"Tuning\", lists them)",
             name ? name : "(null)", hint ? " (did you mean '" : "",
             hint ? hint : "", hint ? "'?)" : "");
    return MRVI_EINVAL;
  }
  if (!valid(r, value, msg, len))
    return MRVI_EINVAL;
  char *p = (char *)&s->tuning + r->offset;
  if (r->info.integer) {
    const int v = (int)value;
    memcpy(p, &v, sizeof v);
  } else {
    memcpy(p, &value, sizeof value);
  }
  return MRVI_OK;
}

int mrvi_settings_get_tuning(const mrvi_settings *s, const char *name,
                             double *value) {
  const tuning_row *r = find(name);
  if (!r)
    return MRVI_EINVAL;
  *value = get(&s->tuning, r);
  return MRVI_OK;
}

int mrvi_tuning_check(const mrvi_tuning *t, char *msg, size_t len) {
  for (int i = 0; i < N_ROWS; i++)
    if (!valid(&rows[i], get(t, &rows[i]), msg, len))
      return MRVI_EINVAL;
  return MRVI_OK;
}
