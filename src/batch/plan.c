/* The case table of `mrvi batch` (doc/batch.md): --vary axes, their
 * Cartesian product or zip, seeds; every case loaded before any runs; the
 * counter-based generator of ensembles. */
#include "batch/batch.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void mrvi_batch_axis_clear(mrvi_batch_axis *a) {
  if (!a)
    return;
  for (int i = 0; i < a->n; i++)
    free(a->values[i]);
  free(a->values);
  free(a->key);
  memset(a, 0, sizeof *a);
}

/* Append value text to the axis. */
static int axis_add(mrvi_batch_axis *a, const char *v, size_t n) {
  char **grown = realloc(a->values, (size_t)(a->n + 1) * sizeof *grown);
  if (!grown)
    return MRVI_ENOMEM;
  a->values = grown;
  if (!(a->values[a->n] = strndup(v, n)))
    return MRVI_ENOMEM;
  a->n++;
  return 0;
}

/* "linspace(a,b,n)" or "logspace(a,b,n)" after the '='; 1 when it is one
 * (0 when not), MRVI_EINVAL when malformed. */
static int axis_range(mrvi_batch_axis *a, const char *v, char *msg,
                      size_t len) {
  int log = !strncmp(v, "logspace(", 9);
  if (!log && strncmp(v, "linspace(", 9))
    return 0;
  double lo, hi;
  int n, used = 0;
  if (sscanf(v + 9, "%lf ,%lf ,%d )%n", &lo, &hi, &n, &used) != 3 || !used ||
      v[9 + used] != '\0' || n < 1 || n > 1000000 || !isfinite(lo) ||
      !isfinite(hi) || (n == 1 && lo != hi)) {
    mrvi_fmt(msg, len,
             "--vary %s=%s: expected %s(a,b,n) with finite a, b and "
             "1 <= n <= 1000000 (n = 1 only for a = b)",
             a->key, v, log ? "logspace" : "linspace");
    return MRVI_EINVAL;
  }
  for (int i = 0; i < n; i++) {
    /* Ends exactly a and b. */
    double x = i == n - 1 ? hi : lo + (hi - lo) * (double)i / (double)(n - 1);
    if (log)
      x = pow(10.0, x);
    char buf[40];
    snprintf(buf, sizeof buf, "%.17g", x);
    if (axis_add(a, buf, strlen(buf)) < 0) {
      mrvi_fmt(msg, len, "out of memory");
      return MRVI_ENOMEM;
    }
  }
  return 1;
}

int mrvi_batch_axis_parse(const char *spec, mrvi_batch_axis *a, char *msg,
                          size_t len) {
  memset(a, 0, sizeof *a);
  const char *eq = strchr(spec, '=');
  if (!eq || eq == spec || !eq[1]) {
    mrvi_fmt(msg, len,
             "--vary %s: expected KEY=V1,V2,... or "
             "KEY=linspace(a,b,n) or KEY=logspace(a,b,n)",
             spec);
    return MRVI_EINVAL;
  }
  if (!(a->key = strndup(spec, (size_t)(eq - spec)))) {
    mrvi_fmt(msg, len, "out of memory");
    return MRVI_ENOMEM;
  }
  if (strchr(spec, '\n')) { /* the master file separates lines by it */
    mrvi_fmt(msg, len, "--vary: a key or value contains a newline");
    mrvi_batch_axis_clear(a);
    return MRVI_EINVAL;
  }
  int rc = axis_range(a, eq + 1, msg, len);
  if (rc < 0) {
    mrvi_batch_axis_clear(a);
    return rc;
  }
  if (rc == 0) {
    /* A list: values between commas, none empty. */
    for (const char *v = eq + 1;;) {
      const char *comma = strchr(v, ',');
      size_t n = comma ? (size_t)(comma - v) : strlen(v);
      if (n == 0) {
        mrvi_fmt(msg, len, "--vary %s: empty value", spec);
        mrvi_batch_axis_clear(a);
        return MRVI_EINVAL;
      }
      if (axis_add(a, v, n) < 0) {
        mrvi_fmt(msg, len, "out of memory");
        mrvi_batch_axis_clear(a);
        return MRVI_ENOMEM;
      }
      if (!comma)
        break;
      v = comma + 1;
    }
  }
  return 0;
}

int mrvi_batch_plan_build(mrvi_batch_plan *p, const char *description,
                          const char *source, const mrvi_batch_axis *axes,
                          int n_axes, int zip, int n_seeds, int command,
                          const mrvi_batch_perturb *pert, char *msg,
                          size_t len) {
  memset(p, 0, sizeof *p);
  /* Number of parameter points: product, or the common length. */
  long points = 1;
  for (int j = 0; j < n_axes; j++) {
    for (int i = 0; i < j; i++)
      if (!strcmp(axes[i].key, axes[j].key)) {
        mrvi_fmt(msg, len, "--vary %s given twice", axes[j].key);
        return MRVI_EINVAL;
      }
    if (zip && j > 0 && axes[j].n != axes[0].n) {
      mrvi_fmt(msg, len,
               "--zip needs equal lengths: --vary %s has %d values, %s %d",
               axes[0].key, axes[0].n, axes[j].key, axes[j].n);
      return MRVI_EINVAL;
    }
    points = zip ? axes[0].n : points * axes[j].n;
    if (points > 1000000) {
      mrvi_fmt(msg, len, "more than 1000000 cases");
      return MRVI_EINVAL;
    }
  }
  const mrvi_batch_perturb *pt = pert;
  const double stds[] = {pt->velocity_std, pt->control_std, pt->position_std,
                         pt->temperature, pt->rotation_std};
  int any = pt->position_uniform || pt->rotation_uniform, bad_std = 0;
  for (int i = 0; i < 5; i++) {
    any = any || stds[i] != 0;
    bad_std = bad_std || !(stds[i] >= 0) || !isfinite(stds[i]);
  }
  if (n_seeds < 0 || n_seeds > 1000000 || bad_std || (any && n_seeds == 0)) {
    mrvi_fmt(msg, len,
             "--seeds N (0..1000000), and finite perturbations >= 0 "
             "(--velocity-std, --position-std, --temperature, "
             "--rotation-std, --control-std), which need --seeds");
    return MRVI_EINVAL;
  }
  if (pt->control_std != 0 && command != MRVI_BATCH_OPTIMIZE) {
    mrvi_fmt(msg, len, "--control-std S perturbs the guess of --optimize");
    return MRVI_EINVAL;
  }
  if (pt->temperature != 0 && pt->velocity_std != 0) {
    mrvi_fmt(msg, len,
             "--temperature sets the initial velocities: no --velocity-std "
             "with it");
    return MRVI_EINVAL;
  }
  if (pt->rotation_uniform && pt->rotation_std != 0) {
    mrvi_fmt(msg, len, "--rotations uniform or --rotation-std A, not both");
    return MRVI_EINVAL;
  }
  if (pt->position_uniform && pt->position_std == 0) {
    mrvi_fmt(msg, len,
             "--position-distribution uniform needs --position-std S");
    return MRVI_EINVAL;
  }
  const long per = n_seeds > 0 ? n_seeds : 1;
  if (points * per > 1000000) {
    mrvi_fmt(msg, len, "more than 1000000 cases");
    return MRVI_EINVAL;
  }
  p->n_cases = (int)(points * per);
  p->n_keys = n_axes;
  p->n_seeds = n_seeds;
  p->command = command;
  p->pert = *pert;
  p->description = strdup(description);
  p->source = strdup(source);
  p->keys = calloc((size_t)n_axes + 1, sizeof *p->keys);
  p->values =
      calloc((size_t)p->n_cases * (size_t)n_axes + 1, sizeof *p->values);
  p->seed = calloc((size_t)p->n_cases, sizeof *p->seed);
  int bad = !p->description || !p->source || !p->keys || !p->values || !p->seed;
  for (int j = 0; !bad && j < n_axes; j++)
    bad = !(p->keys[j] = strdup(axes[j].key));
  for (int c = 0; !bad && c < p->n_cases; c++) {
    long point = c / per, rest = point;
    p->seed[c] = n_seeds > 0 ? c % per : -1;
    /* Product: the last axis fastest; zip: index `point` of every axis. */
    for (int j = n_axes - 1; !bad && j >= 0; j--) {
      long i = zip ? point : rest % axes[j].n;
      rest = zip ? rest : rest / axes[j].n;
      bad = !(p->values[(long)c * n_axes + j] = strdup(axes[j].values[i]));
    }
  }
  if (bad) {
    mrvi_batch_plan_free(p);
    mrvi_fmt(msg, len, "out of memory");
    return MRVI_ENOMEM;
  }
  return 0;
}

/* ---------------------------------------------------------------------------
 * Generator
 * ------------------------------------------------------------------------- */
uint64_t mrvi_batch_random(uint64_t seed, uint64_t i) {
  /* splitmix64's output function on the counter (seed + 1) * golden + i. */
  uint64_t z = (seed + 1) * 0x9E3779B97F4A7C15ull + i;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

double mrvi_batch_normal(uint64_t seed, uint64_t j) {
  /* Box-Muller: u1 in (0, 1], u2 in [0, 1) from 53 random bits each. */
  const double scale = 1.0 / 9007199254740992.0; /* 2^-53 */
  double u1 = (double)((mrvi_batch_random(seed, 2 * j) >> 11) + 1) * scale;
  double u2 = (double)(mrvi_batch_random(seed, 2 * j + 1) >> 11) * scale;
  return sqrt(-2.0 * log(u1)) * cos(6.283185307179586 * u2);
}

/* ---------------------------------------------------------------------------
 * Loading a case
 * ------------------------------------------------------------------------- */

/* "case C (KEY=VALUE, ...)" into buf. */
static void case_name(const mrvi_batch_plan *p, int c, char *buf, size_t len) {
  size_t at = 0;
  int n = snprintf(buf, len, "case %d", c);
  at = n > 0 ? (size_t)n : 0;
  for (int j = 0; j < p->n_keys && at + 1 < len; j++) {
    n = snprintf(buf + at, len - at, "%s%s=%s", j ? ", " : " (", p->keys[j],
                 p->values[(long)c * p->n_keys + j]);
    at += n > 0 ? (size_t)n : 0;
  }
  if (p->n_keys > 0 && at + 1 < len)
    snprintf(buf + at, len - at, ")");
}

/* The start of an optimize case of seed `seed`: for actuator a the
 * override "control.actuators.a.initial=[...]" with value j of the
 * description's guess plus std times normal number j of the seed's control
 * stream (j over the control vector), held in the actuator's bounds.  The
 * guess is an override of the case's description, so its run file's
 * /model/description names it and `mrvi optimize FILE --set ...` with
 * the same overrides gives the same file.  Appended to *over (*n_over
 * strings, grown); with std 0 only checks that the control: section
 * loads. */
static int guess_overrides(const mrvi_system *sys, long seed, double std,
                           char ***over, int *n_over, char *msg, size_t len) {
  mrvi_ocp *o = NULL;
  double *u = NULL;
  if (mrvi_ocp_load(sys, &o, &u, msg, len) < 0)
    return MRVI_EPARSE;
  const int na = seed >= 0 && std > 0 ? mrvi_ocp_n_actuators(o) : 0;
  char **grown = realloc(*over, (size_t)(*n_over + na + 1) * sizeof **over);
  int rc = grown ? 0 : MRVI_ENOMEM;
  if (grown)
    *over = grown;
  for (int a = 0; rc == 0 && a < na; a++) {
    const int off = mrvi_ocp_actuator_offset(o, a);
    const int size = mrvi_ocp_actuator_size(o, a);
    double lo, hi;
    mrvi_ocp_actuator_bounds(o, a, &lo, &hi);
    const size_t cap = 64 + 26 * (size_t)size;
    char *s = malloc(cap);
    if (!s) {
      rc = MRVI_ENOMEM;
      break;
    }
    size_t at = (size_t)snprintf(s, cap, "control.actuators.%d.initial=[", a);
    for (int j = 0; j < size; j++) {
      const uint64_t k = MRVI_BATCH_STREAM_CONTROLS + (uint64_t)(off + j);
      const double v = u[off + j] + std * mrvi_batch_normal((uint64_t)seed, k);
      at += (size_t)snprintf(s + at, cap - at, "%s%.17g", j ? "," : "",
                             fmin(fmax(v, lo), hi));
    }
    snprintf(s + at, cap - at, "]");
    grown[(*n_over)++] = s;
  }
  if (rc < 0)
    mrvi_fmt(msg, len, "out of memory");
  free(u);
  mrvi_ocp_free(o);
  return rc;
}

int mrvi_batch_case_load(const mrvi_batch_plan *p, int c, mrvi_system **out,
                         char *msg, size_t len) {
  *out = NULL;
  int n_over = p->n_keys;
  char **over = calloc((size_t)p->n_keys + 1, sizeof *over);
  int rc = over ? 0 : MRVI_ENOMEM;
  for (int j = 0; rc == 0 && j < p->n_keys; j++) {
    const char *v = p->values[(long)c * p->n_keys + j];
    size_t n = strlen(p->keys[j]) + strlen(v) + 2;
    if (!(over[j] = malloc(n)))
      rc = MRVI_ENOMEM;
    else
      snprintf(over[j], n, "%s=%s", p->keys[j], v);
  }
  char name[256];
  case_name(p, c, name, sizeof name);
  char text[4096];
  text[0] = '\0';
  if (rc == 0)
    rc = mrvi_system_load_string(p->description, p->source,
                                 (const char *const *)over, n_over, out, text,
                                 sizeof text);
  /* An optimize case: its control: section loads; a multi-start case is
   * loaded again with its start as overrides. */
  if (rc == 0 && *out && p->command == MRVI_BATCH_OPTIMIZE) {
    const int n_keys = n_over;
    rc = guess_overrides(*out, p->seed[c], p->pert.control_std, &over, &n_over,
                         text, sizeof text);
    if (rc == 0 && n_over > n_keys) {
      mrvi_system_free(*out);
      *out = NULL;
      rc = mrvi_system_load_string(p->description, p->source,
                                   (const char *const *)over, n_over, out, text,
                                   sizeof text);
    }
  }
  int dof = 0;
  if (rc == 0 && *out &&
      (rc = mrvi_batch_perturb_apply(*out, p->seed[c], &p->pert, &dof, text,
                                     sizeof text)) == 0 &&
      mrvi_batch_perturb_note(*out, p->seed[c], &p->pert, dof) < 0) {
    mrvi_fmt(text, sizeof text, "out of memory");
    rc = MRVI_ENOMEM;
  }
  if (rc < 0 || !*out) {
    mrvi_system_free(*out);
    *out = NULL;
    mrvi_fmt(msg, len, "%s: %s", name,
             text[0] ? text : mrvi_strerror(rc < 0 ? rc : MRVI_EPARSE));
    rc = rc < 0 ? rc : MRVI_EPARSE;
  }
  for (int j = 0; over && j < n_over; j++)
    free(over[j]);
  free(over);
  return rc;
}

int mrvi_batch_plan_check(const mrvi_batch_plan *p, char *msg, size_t len) {
  for (int c = 0; c < p->n_cases; c++) {
    mrvi_system *sys = NULL;
    int rc = mrvi_batch_case_load(p, c, &sys, msg, len);
    mrvi_system_free(sys);
    if (rc < 0)
      return rc;
  }
  return 0;
}

/* ---------------------------------------------------------------------------
 * The plan as bytes: "MRVIPLN4", int32 n_cases, n_keys, n_seeds, command,
 * threads, mrvi_batch_perturb (raw: the ranks run one binary, which
 * src/cli/cli_batch_mpi.c checks when MPI starts), int64
 * seed[n_cases], then
 * '\0'-terminated strings:
 * description, source, keys, values (row-major).
 * ------------------------------------------------------------------------- */
static const char plan_magic[8] = {'M', 'R', 'V', 'I', 'P', 'L', 'N', '4'};

int mrvi_batch_plan_pack(const mrvi_batch_plan *p, char **buf, size_t *size) {
  const long nv = (long)p->n_cases * p->n_keys;
  size_t n = sizeof plan_magic + 5 * sizeof(int32_t) + sizeof p->pert +
             (size_t)p->n_cases * sizeof(int64_t) + strlen(p->description) +
             strlen(p->source) + 2;
  for (int j = 0; j < p->n_keys; j++)
    n += strlen(p->keys[j]) + 1;
  for (long i = 0; i < nv; i++)
    n += strlen(p->values[i]) + 1;
  char *b = malloc(n), *at = b;
  if (!b)
    return MRVI_ENOMEM;
  const int32_t counts[5] = {p->n_cases, p->n_keys, p->n_seeds, p->command,
                             p->threads};
  memcpy(at, plan_magic, sizeof plan_magic), at += sizeof plan_magic;
  memcpy(at, counts, sizeof counts), at += sizeof counts;
  memcpy(at, &p->pert, sizeof p->pert), at += sizeof p->pert;
  for (int c = 0; c < p->n_cases; c++) {
    int64_t s = p->seed[c];
    memcpy(at, &s, sizeof s), at += sizeof s;
  }
#define PUT(str) (at = stpcpy(at, (str)) + 1)
  PUT(p->description);
  PUT(p->source);
  for (int j = 0; j < p->n_keys; j++)
    PUT(p->keys[j]);
  for (long i = 0; i < nv; i++)
    PUT(p->values[i]);
#undef PUT
  *buf = b;
  *size = n;
  return 0;
}

/* The next '\0'-terminated string of [*at, end), copied; NULL when none. */
static char *take_string(const char **at, const char *end) {
  const char *z = memchr(*at, '\0', (size_t)(end - *at));
  if (!z)
    return NULL;
  char *s = strdup(*at);
  *at = z + 1;
  return s;
}

int mrvi_batch_plan_unpack(const char *buf, size_t size, mrvi_batch_plan *p) {
  memset(p, 0, sizeof *p);
  int32_t counts[5];
  const size_t head = sizeof plan_magic + sizeof counts + sizeof p->pert;
  if (size < head || memcmp(buf, plan_magic, sizeof plan_magic))
    return MRVI_EINVAL;
  memcpy(counts, buf + sizeof plan_magic, sizeof counts);
  memcpy(&p->pert, buf + sizeof plan_magic + sizeof counts, sizeof p->pert);
  if (counts[3] != MRVI_BATCH_RUN && counts[3] != MRVI_BATCH_OPTIMIZE)
    return MRVI_EINVAL;
  p->command = counts[3];
  if (counts[4] < 0 || counts[4] > 4096)
    return MRVI_EINVAL;
  p->threads = counts[4];
  if (counts[0] < 1 || counts[0] > 1000000 || counts[1] < 0 ||
      counts[1] > 1000000 || counts[2] < 0 ||
      (size - head) / sizeof(int64_t) < (size_t)counts[0] ||
      (long)counts[0] * counts[1] > (long)(size - head))
    return MRVI_EINVAL;
  p->n_cases = counts[0];
  p->n_keys = counts[1];
  p->n_seeds = counts[2];
  const long nv = (long)p->n_cases * p->n_keys;
  p->seed = malloc((size_t)p->n_cases * sizeof *p->seed);
  p->keys = calloc((size_t)p->n_keys + 1, sizeof *p->keys);
  p->values = calloc((size_t)nv + 1, sizeof *p->values);
  const char *at = buf + head, *end = buf + size;
  int bad = !p->seed || !p->keys || !p->values;
  for (int c = 0; !bad && c < p->n_cases; c++) {
    int64_t s;
    memcpy(&s, at, sizeof s), at += sizeof s;
    p->seed[c] = (long)s;
  }
  bad = bad || !(p->description = take_string(&at, end)) ||
        !(p->source = take_string(&at, end));
  for (int j = 0; !bad && j < p->n_keys; j++)
    bad = !(p->keys[j] = take_string(&at, end));
  for (long i = 0; !bad && i < nv; i++)
    bad = !(p->values[i] = take_string(&at, end));
  if (bad || at != end) {
    mrvi_batch_plan_free(p);
    return MRVI_EINVAL;
  }
  return 0;
}
