/* Description files: every broken file in tests/bad_input/ fails with
 * "file:line:col: message" (library and CLI), the shipped systems hold the
 * paper's set-ups (arXiv 2406.12991 §6, doc/reproduction.md), --set overrides
 * reach the model and the stored description, and constraints
 * (doc/constraints.md) are parsed, checked and their initial velocities
 * projected. */
#include "model/model.h"
#include "models.h"
#include "mrvi.h"
#include "testlib.h"
#include "util/util.h"

#include <dirent.h>
#include <fcntl.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#define MSG 1024

/* ---------------------------------------------------------------------------
 * Broken files.  Line 1: "# expect: LINE: SUBSTRING" or "# expect: LINE:COL:
 * SUBSTRING" (LINE and COL numbers; or `set` for an error reported against
 * an override); optional line 2: "# set: KEY=VALUE", an override to apply.
 * Every message located in the file carries a column (file:line:col:);
 * where the case names COL, it is that one.
 * ------------------------------------------------------------------------- */

typedef struct bad_case {
  char path[1024];
  int line;          /* expected line, 0 for an override error */
  int col;           /* expected column, 0 for any */
  char expect[1024]; /* message substring */
  char set[1024];    /* override, "" if none */
} bad_case;

static void chomp(char *s) {
  size_t n = strlen(s);
  while (n && (s[n - 1] == '\n' || s[n - 1] == '\r'))
    s[--n] = '\0';
}

static int read_case(const char *path, bad_case *c) {
  FILE *f = fopen(path, "r");
  char l1[1024] = "", l2[1024] = "";
  if (!f)
    return -1;
  if (!fgets(l1, sizeof l1, f))
    l1[0] = '\0';
  if (!fgets(l2, sizeof l2, f))
    l2[0] = '\0';
  fclose(f);
  chomp(l1);
  chomp(l2);
  memset(c, 0, sizeof *c);
  snprintf(c->path, sizeof c->path, "%s", path);
  const char *p = l1;
  if (strncmp(p, "# expect: ", 10))
    return -1;
  p += 10;
  if (!strncmp(p, "set: ", 5)) {
    c->line = 0;
    p += 5;
  } else {
    char *end;
    c->line = (int)strtol(p, &end, 10);
    if (end != p && end[0] == ':' && end[1] >= '0' && end[1] <= '9') {
      const char *col = end + 1;
      c->col = (int)strtol(col, &end, 10);
      if (c->col < 1)
        return -1;
    }
    if (end == p || strncmp(end, ": ", 2) || c->line < 1)
      return -1;
    p = end + 2;
  }
  snprintf(c->expect, sizeof c->expect, "%s", p);
  if (!strncmp(l2, "# set: ", 7))
    snprintf(c->set, sizeof c->set, "%s", l2 + 7);
  return 0;
}

static int cmp_str(const void *a, const void *b) {
  return strcmp(*(char *const *)a, *(char *const *)b);
}

/* Sorted list of the *.yaml of directory `where` (tests/bad_input/,
 * tests/fuzz/seeds/); returns the count. */
static int list_yaml_files(const char *where, char ***out) {
  char dir[1024];
  snprintf(dir, sizeof dir, "%s", test_source_path(where));
  DIR *d = opendir(dir);
  CHECK(d != NULL, "cannot open %s", dir);
  if (!d)
    return 0;
  char **names = NULL;
  int n = 0;
  struct dirent *e;
  while ((e = readdir(d))) {
    size_t len = strlen(e->d_name);
    if (len < 6 || strcmp(e->d_name + len - 5, ".yaml"))
      continue;
    names = realloc(names, (size_t)(n + 1) * sizeof *names);
    names[n] = malloc(strlen(dir) + len + 2);
    sprintf(names[n], "%s/%s", dir, e->d_name);
    n++;
  }
  closedir(d);
  qsort(names, (size_t)n, sizeof *names, cmp_str);
  *out = names;
  return n;
}

/* The message starts with the location the case expects: file:line:col:,
 * the column the case's if it names one. */
static int location_ok(const bad_case *c, const char *msg) {
  char want[1100];
  if (c->line == 0)
    return !strncmp(msg, "--set ", 6);
  snprintf(want, sizeof want, "%s:%d:", c->path, c->line);
  if (strncmp(msg, want, strlen(want)))
    return 0;
  const char *p = msg + strlen(want);
  char *end;
  const long col = strtol(p, &end, 10);
  return end != p && *p >= '0' && *p <= '9' && col >= 1 && *end == ':' &&
         (c->col == 0 || col == c->col);
}

static void test_bad_file(const bad_case *c) {
  char msg[MSG] = "";
  mrvi_system *sys = (mrvi_system *)&msg; /* must be reset to NULL */
  const char *ov[1] = {c->set};
  int st =
      mrvi_system_load(c->path, ov, c->set[0] ? 1 : 0, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EPARSE, "%s: status %d, expected MRVI_EPARSE", c->path, st);
  CHECK(sys == NULL, "%s: *out not NULL on failure", c->path);
  CHECK(location_ok(c, msg),
        "%s: message '%s' does not start at line %d, column %d (0: any)",
        c->path, msg, c->line, c->col);
  CHECK(strstr(msg, c->expect) != NULL, "%s: message '%s' lacks '%s'", c->path,
        msg, c->expect);
  mrvi_system_free(sys == (mrvi_system *)&msg ? NULL : sys);
}

/* Run `$MRVI_BIN run FILE -o OUT [--set X]`, stderr into a file; returns the
 * exit status (-1 if it did not exit normally). */
static int run_cli(const char *bin, const bad_case *c, const char *out,
                   const char *err_path) {
  pid_t pid = fork();
  if (pid < 0)
    return -1;
  if (pid == 0) {
    int fd = open(err_path, O_WRONLY | O_CREAT | O_TRUNC, 0600);
    int null = open("/dev/null", O_WRONLY);
    if (fd < 0 || null < 0)
      _exit(127);
    dup2(fd, 2);
    dup2(null, 1);
    char *argv[9];
    int k = 0;
    argv[k++] = (char *)bin;
    argv[k++] = "run";
    argv[k++] = (char *)c->path;
    argv[k++] = "-o";
    argv[k++] = (char *)out;
    if (c->set[0]) {
      argv[k++] = "--set";
      argv[k++] = (char *)c->set;
    }
    argv[k++] = "--quiet";
    argv[k] = NULL;
    execv(bin, argv);
    _exit(127);
  }
  int status;
  if (waitpid(pid, &status, 0) < 0 || !WIFEXITED(status))
    return -1;
  return WEXITSTATUS(status);
}

static char *slurp(const char *path) {
  FILE *f = fopen(path, "rb");
  if (!f)
    return NULL;
  size_t cap = 1 << 16, n = 0, got;
  char *buf = malloc(cap);
  while (buf && (got = fread(buf + n, 1, cap - 1 - n, f)) > 0) {
    n += got;
    if (n == cap - 1) { /* full: the file may be longer */
      char *more = realloc(buf, 2 * cap);
      if (!more) {
        free(buf);
        buf = NULL;
        break;
      }
      buf = more;
      cap *= 2;
    }
  }
  if (buf)
    buf[n] = '\0';
  fclose(f);
  return buf;
}

static void test_cli_bad_files(char **files, int n) {
  const char *bin = getenv("MRVI_BIN");
  if (!bin || access(bin, X_OK)) {
    printf("MRVI_BIN not set or not executable: CLI checks skipped\n");
    return;
  }
  char dir[] = "/tmp/mrvi_test_loader_XXXXXX";
  CHECK(mkdtemp(dir) != NULL, "mkdtemp failed");
  char out[256], err[256];
  snprintf(out, sizeof out, "%s/out.h5", dir);
  snprintf(err, sizeof err, "%s/stderr.txt", dir);
  for (int i = 0; i < n; i++) {
    bad_case c;
    if (read_case(files[i], &c))
      continue;
    int code = run_cli(bin, &c, out, err);
    CHECK(code > 0 && code != 127, "%s: mrvi exit status %d, expected failure",
          c.path, code);
    char *text = slurp(err);
    char want[1100];
    if (c.line && c.col)
      snprintf(want, sizeof want, "%s:%d:%d:", c.path, c.line, c.col);
    else if (c.line)
      snprintf(want, sizeof want, "%s:%d:", c.path, c.line);
    else
      snprintf(want, sizeof want, "--set");
    CHECK(text && strstr(text, want), "%s: stderr lacks '%s': %s", c.path, want,
          text ? text : "(none)");
    free(text);
    CHECK(access(out, F_OK) != 0, "%s: output file was created", c.path);
    unlink(out);
  }
  unlink(err);
  rmdir(dir);
}

/* ---------------------------------------------------------------------------
 * Shipped systems
 * ------------------------------------------------------------------------- */

static mrvi_system *load(const char *rel, const char *const *ov, int n_ov) {
  char msg[MSG] = "";
  mrvi_system *sys = NULL;
  int st =
      mrvi_system_load(test_source_path(rel), ov, n_ov, &sys, msg, sizeof msg);
  CHECK(st == MRVI_OK && sys, "loading %s: %s", rel, msg);
  CHECK(st != MRVI_OK || msg[0] == '\0', "message on success: %s", msg);
  return st == MRVI_OK ? sys : NULL;
}

static void check_fpu_file(void) {
  mrvi_system *sys = load("systems/fpu.yaml", NULL, 0);
  if (!sys)
    return;
  const mrvi_model *m = sys->model;
  const mrvi_settings *s = &sys->settings;
  CHECK(!strcmp(sys->name, "fpu"), "fpu name '%s'", sys->name);
  CHECK(mrvi_model_n(m) == 6, "fpu n = %d", mrvi_model_n(m));
  CHECK(mrvi_model_n_slow(m) == 3, "fpu n_s = %d", mrvi_model_n_slow(m));
  CHECK(mrvi_model_n_fast(m) == 3, "fpu n_f = %d", mrvi_model_n_fast(m));
  CHECK(mrvi_model_n_elements(m) == 7, "fpu elements = %d",
        mrvi_model_n_elements(m));
  /* qs0 = (1,0,0), qf0 = (1/omega,0,0), vs0 = vf0 = (1,0,0), unit masses. */
  const double q0[6] = {1, 0, 0, 0.02, 0, 0}, v0[6] = {1, 0, 0, 1, 0, 0};
  const char *names[6] = {"qs1", "qs2", "qs3", "qf1", "qf2", "qf3"};
  for (int i = 0; i < 6; i++) {
    CHECK(!strcmp(mrvi_model_coordinate_name(m, i, (char[MRVI_NAME_MAX]){0}),
                  names[i]),
          "fpu coordinate %d is %s", i,
          mrvi_model_coordinate_name(m, i, (char[MRVI_NAME_MAX]){0}));
    CHECK(mrvi_model_rate(m, i) == (i < 3 ? MRVI_SLOW : MRVI_FAST),
          "fpu rate of %s", names[i]);
    CHECK_NEAR(mrvi_model_mass(m, i), 1.0, 0.0, "fpu mass");
    CHECK_NEAR(mrvi_model_q0(m)[i], q0[i], 0.0, "fpu q0");
    CHECK_NEAR(mrvi_model_v0(m)[i], v0[i], 0.0, "fpu v0");
  }
  CHECK_NEAR(0.02, 1.0 / sqrt(2500.0), 1e-17, "qf0 = 1/omega");
  /* W = omega^2/2 |qf|^2 with omega^2 = 2500; V is the paper's quartic. */
  double q[6] = {0.3, -0.2, 0.5, 0.01, -0.03, 0.02};
  double W = mrvi_model_potential(m, MRVI_FAST, q, NULL, NULL);
  CHECK_NEAR(W, 1250.0 * (q[3] * q[3] + q[4] * q[4] + q[5] * q[5]), 1e-12,
             "fpu W");
  double a = q[0] - q[3], b = q[1] - q[4] - q[0] - q[3],
         c = q[2] - q[5] - q[1] - q[4], d = q[2] + q[5];
  double V = mrvi_model_potential(m, MRVI_SLOW, q, NULL, NULL);
  CHECK_NEAR(V, 0.25 * (pow(a, 4) + pow(b, 4) + pow(c, 4) + pow(d, 4)), 1e-15,
             "fpu V");
  CHECK(!strcmp(s->scheme, "midpoint-midpoint"), "fpu scheme %s", s->scheme);
  CHECK_NEAR(s->macro_step, 0.3, 0.0, "fpu dT");
  CHECK(s->micro_steps == 10, "fpu p = %d", s->micro_steps);
  CHECK_NEAR(s->t_end, 200.0, 0.0, "fpu t_end");
  CHECK_NEAR(s->newton_tol, 1e-9, 0.0, "fpu tolerance");
  CHECK_NEAR(s->slow.gamma, 0.5, 0.0, "fpu slow gamma");
  CHECK_NEAR(s->fast.gamma, 0.5, 0.0, "fpu fast gamma");
  CHECK(s->slow_grid == MRVI_GRID_MICRO, "fpu slow grid");
  /* Without overrides the description is the file verbatim. */
  char *text = slurp(test_source_path("systems/fpu.yaml"));
  CHECK(text && sys->description && !strcmp(text, sys->description),
        "fpu description is not the file text");
  free(text);
  mrvi_system_free(sys);
}

static void check_spring_ring_file(void) {
  mrvi_system *sys = load("systems/spring_ring.yaml", NULL, 0);
  if (!sys)
    return;
  const mrvi_model *m = sys->model;
  CHECK(mrvi_model_n(m) == 18, "ring n = %d", mrvi_model_n(m));
  CHECK(mrvi_model_n_slow(m) == 9, "ring n_s = %d", mrvi_model_n_slow(m));
  CHECK(mrvi_model_n_fast(m) == 9, "ring n_f = %d", mrvi_model_n_fast(m));
  CHECK(mrvi_model_dimension(m) == 3, "ring dimension");
  CHECK(mrvi_model_n_particles(m) == 6, "ring particles");
  /* 3 slow + 3 fast anchor springs, 6 ring springs, gravity. */
  CHECK(mrvi_model_n_elements(m) == 13, "ring elements = %d",
        mrvi_model_n_elements(m));
  /* Initial data equal to the C-API build of the paper's set-up
   * (tests/models.c, arXiv 2406.12991 §6, doc/reproduction.md): positions to
   * the 17 digits written in the file, velocities to rounding of the
   * normalisations. */
  mrvi_model *ref = test_spring_ring();
  double x[6][3];
  for (int i = 0; i < 6; i++)
    for (int k = 0; k < 3; k++) {
      int j = 3 * i + k;
      x[i][k] = mrvi_model_q0(ref)[j];
      CHECK_NEAR(mrvi_model_q0(m)[j], x[i][k], 1e-15, "ring q0");
      CHECK_NEAR(mrvi_model_v0(m)[j], mrvi_model_v0(ref)[j], 1e-14, "ring v0");
      CHECK_NEAR(mrvi_model_mass(m, j), 2.0, 0.0, "ring mass");
      CHECK(mrvi_model_rate(m, j) == (i % 2 ? MRVI_FAST : MRVI_SLOW),
            "ring rate of coordinate %d", j);
    }
  mrvi_model_free(ref);
  /* V and W at the initial positions against the paper's formulas:
   * V = (w1/2)|q^s|^2 + (eps/4) sum |q_{i+1} - q_i|^4 - sum m g^T q,
   * W = (w2/2)|q^f|^2, eps = 5, w1 = 2, w2 = 4000, g = -9.81 e3. */
  double V = 0, W = 0;
  for (int i = 0; i < 6; i++) {
    double sq = x[i][0] * x[i][0] + x[i][1] * x[i][1] + x[i][2] * x[i][2];
    if (i % 2)
      W += 0.5 * 4000 * sq;
    else
      V += 0.5 * 2 * sq;
    double d2 = 0;
    for (int k = 0; k < 3; k++) {
      double d = x[(i + 1) % 6][k] - x[i][k];
      d2 += d * d;
    }
    V += 1.25 * d2 * d2 + 2 * 9.81 * x[i][2];
  }
  const double *q = mrvi_model_q0(m);
  CHECK_NEAR(mrvi_model_potential(m, MRVI_SLOW, q, NULL, NULL), V, 1e-11,
             "ring V(q0)");
  CHECK_NEAR(mrvi_model_potential(m, MRVI_FAST, q, NULL, NULL), W, 1e-9,
             "ring W(q0)");
  const mrvi_settings *s = &sys->settings;
  CHECK_NEAR(s->macro_step, 0.01, 0.0, "ring dT");
  CHECK(s->micro_steps == 10, "ring p = %d", s->micro_steps);
  CHECK_NEAR(s->t_end, 50.0, 0.0, "ring t_end");
  CHECK_NEAR(s->newton_tol, 1e-8, 0.0, "ring tolerance");
  CHECK(!strcmp(sys->output_file, "spring_ring.h5"), "ring output %s",
        sys->output_file);
  mrvi_system_free(sys);
}

static void check_oscillator_file(void) {
  mrvi_system *sys = load("systems/oscillator.yaml", NULL, 0);
  if (!sys)
    return;
  const mrvi_model *m = sys->model;
  CHECK(mrvi_model_n(m) == 1 && mrvi_model_n_slow(m) == 1 &&
            mrvi_model_n_fast(m) == 0,
        "oscillator sizes");
  CHECK_NEAR(mrvi_model_mass(m, 0), 1.0, 0.0, "oscillator mass");
  CHECK_NEAR(mrvi_model_q0(m)[0], 1.0, 0.0, "oscillator q0");
  CHECK_NEAR(mrvi_model_v0(m)[0], 0.0, 0.0, "oscillator v0");
  double q = 0.7; /* V = 1/2 omega^2 q^2, omega = 1 */
  CHECK_NEAR(mrvi_model_potential(m, MRVI_SLOW, &q, NULL, NULL), 0.245, 1e-15,
             "oscillator V");
  CHECK_NEAR(sys->settings.macro_step, 0.1, 0.0, "oscillator dT");
  CHECK(sys->settings.micro_steps == 5, "oscillator p");
  CHECK_NEAR(sys->settings.t_end, 10.0, 0.0, "oscillator t_end");
  CHECK(!strcmp(sys->settings.scheme, "midpoint-midpoint"),
        "oscillator scheme");
  mrvi_system_free(sys);
}

/* ---------------------------------------------------------------------------
 * Constraints (doc/constraints.md)
 * ------------------------------------------------------------------------- */

static mrvi_system *load_text(const char *text, const char *const *ov,
                              int n_ov) {
  char msg[MSG] = "";
  mrvi_system *sys = NULL;
  int st = mrvi_system_load_string(text, "text.yaml", ov, n_ov, &sys, msg,
                                   sizeof msg);
  CHECK(st == MRVI_OK && sys, "loading text: %s", msg);
  return st == MRVI_OK ? sys : NULL;
}

/* max |g(q)| over all constraint rows. */
static double max_abs_g(const mrvi_model *m, const double *q) {
  const int R = mrvi_model_constraint_rows(m);
  double *g = calloc((size_t)R + 1, sizeof *g), worst = 0;
  mrvi_model_constraint_eval(m, q, g, NULL);
  for (int r = 0; r < R; r++)
    worst = fabs(g[r]) > worst ? fabs(g[r]) : worst;
  free(g);
  return worst;
}

/* G M^-1 p0 with p0 = M v0: the hidden constraint of the initial data. */
static double hidden0(const mrvi_model *m) {
  const int n = mrvi_model_n(m);
  double *p = malloc((size_t)n * sizeof *p);
  for (int i = 0; i < n; i++)
    p[i] = mrvi_model_mass(m, i) * mrvi_model_v0(m)[i];
  const double h = mrvi_model_hidden_residual(m, mrvi_model_q0(m), p);
  free(p);
  return h;
}

static const char constrained_text[] =
    "name: constrained\n"
    "dimension: 3\n"
    "coordinates:\n"
    "  - {name: q1, mass: 1, position: 0.5}\n"
    "  - {name: q2, mass: 2, position: 1.5, rate: fast}\n"
    "particles:\n"
    "  - {name: a, mass: 1, position: [0, 0, 0]}\n"
    "  - {name: b, mass: 3, position: [3, 4, 0], rate: fast}\n"
    "  - {name: c, mass: 2, position: [0, 0, -2]}\n"
    "constraints:\n"
    "  - {type: distance, between: [a, b]}\n"                 /* 0 */
    "  - {type: distance, between: [c], anchor: [0, 0, 0],\n" /* 1 */
    "     name: tether}\n"
    "  - {type: fixed, particle: a, axes: [z, x]}\n"        /* 2 */
    "  - {type: plane, particle: b, normal: [0, 0, 2]}\n"   /* 3 */
    "  - {type: linear, combination: {q1: 1, c.z: 0.25}}\n" /* 4 */
    "  - {type: linear, combination: {q2: 1, b.y: -1}, value: -2.5}\n"
    "  - {type: fixed, particle: c, axes: [x], position: [0, 7, 9]}\n";

static void test_constraints_parsed(void) {
  mrvi_system *sys = load_text(constrained_text, NULL, 0);
  if (!sys)
    return;
  const mrvi_model *m = sys->model;
  const int n = mrvi_model_n(m);
  CHECK(mrvi_model_n_constraints(m) == 7, "constraints: %d",
        mrvi_model_n_constraints(m));
  /* rows: 1 + 1 + 2 (x and z) + 1 + 1 + 1 + 1 */
  CHECK(mrvi_model_constraint_rows(m) == 8, "rows: %d",
        mrvi_model_constraint_rows(m));
  const int rows[7] = {1, 1, 2, 1, 1, 1, 1};
  /* Slow-only at macro nodes; touching fast b or q2 at every micro node. */
  const mrvi_rate where[7] = {MRVI_FAST, MRVI_SLOW, MRVI_SLOW, MRVI_FAST,
                              MRVI_SLOW, MRVI_FAST, MRVI_SLOW};
  const char *type[7] = {"distance", "distance", "fixed", "plane",
                         "linear",   "linear",   "fixed"};
  for (int c = 0; c < 7 && c < mrvi_model_n_constraints(m); c++) {
    CHECK(mrvi_model_constraint_n_rows(m, c) == rows[c], "rows of %d: %d", c,
          mrvi_model_constraint_n_rows(m, c));
    CHECK(mrvi_model_constraint_where(m, c) == where[c], "where of %d", c);
    CHECK(!strcmp(mrvi_model_constraint_type_name(m, c), type[c]),
          "type of %d: %s", c, mrvi_model_constraint_type_name(m, c));
  }
  CHECK(!strcmp(mrvi_model_constraint_label(m, 0), "distance a-b"),
        "default label '%s'", mrvi_model_constraint_label(m, 0));
  CHECK(!strcmp(mrvi_model_constraint_label(m, 1), "tether"),
        "name: label '%s'", mrvi_model_constraint_label(m, 1));
  /* Defaults hold at q0 (length 5 = initial distance, plane and linear
   * through the initial point); the explicit c.x = 0 holds too. */
  const double *q0 = mrvi_model_q0(m);
  CHECK(max_abs_g(m, q0) <= 1e-15, "g(q0) = %g", max_abs_g(m, q0));
  /* Away from q0 each row has the value its parameters give. */
  double *q = malloc((size_t)n * sizeof *q);
  double g[8];
  memcpy(q, q0, (size_t)n * sizeof *q);
  /* model order: q1, q2, a.x a.y a.z, b.x b.y b.z, c.x c.y c.z */
  q[0] = 1.0;         /* q1 */
  q[5] = 6, q[6] = 8; /* b = (6, 8, 0): |a - b| = 10 */
  q[7] = 0.5;         /* b.z */
  q[2] = 0.25;        /* a.x */
  q[10] = -3;         /* c.z: |c| = 3 */
  q[8] = 0.125;       /* c.x */
  mrvi_model_constraint_eval(m, q, g, NULL);
  /* rows in order: distance, tether, fixed a (x, z), plane, linear q1,
   * linear q2, fixed c.x */
  /* a - b = (-5.75, -8, -0.5), c = (0.125, 0, -3) */
  CHECK_NEAR(g[0], (5.75 * 5.75 + 64.0 + 0.25 - 25.0) / 10.0, 1e-14,
             "distance length 5");
  CHECK_NEAR(g[1], (0.125 * 0.125 + 9.0 - 4.0) / 4.0, 1e-14, "tether length 2");
  CHECK_NEAR(g[2], 0.25, 1e-15, "fixed a.x at 0");
  CHECK_NEAR(g[3], 0.0, 1e-15, "fixed a.z at 0");
  CHECK_NEAR(g[4], 0.5, 1e-15, "plane z = 0 (normal normalised)");
  /* q1 + c.z/4 = 0.5 - 0.5 = 0 at q0; now 1 - 0.75 */
  CHECK_NEAR(g[5], 0.25, 1e-15, "linear value from q0");
  /* q2 - b.y = 1.5 - 8 against -2.5 */
  CHECK_NEAR(g[6], 1.5 - 8.0 + 2.5, 1e-14, "linear value given");
  CHECK_NEAR(g[7], 0.125, 1e-15, "fixed c.x position given");
  free(q);
  /* Settings default without integrator.constraints. */
  CHECK(sys->settings.constraint_form == MRVI_FORM_MULTIPLIERS, "default form");
  CHECK_NEAR(sys->settings.constraint_tol, 1e-10, 0.0, "default tolerance");
  CHECK(sys->settings.project_momenta == 1, "default projection");
  CHECK(sys->notes == NULL, "note without velocities: %s", sys->notes);
  mrvi_system_free(sys);
}

static void test_constraint_settings(void) {
  const char *text = "name: s\ndimension: 1\n"
                     "particles: [{name: m, mass: 1, position: [1]}]\n"
                     "constraints: [{type: fixed, particle: m}]\n"
                     "integrator:\n"
                     "  constraints: {form: null-space, tolerance: 1.0e-8, "
                     "projection: false}\n";
  mrvi_system *sys = load_text(text, NULL, 0);
  if (sys) {
    CHECK(sys->settings.constraint_form == MRVI_FORM_NULL_SPACE, "form");
    CHECK_NEAR(sys->settings.constraint_tol, 1e-8, 0.0, "tolerance");
    CHECK(sys->settings.project_momenta == 0, "projection false");
    mrvi_system_free(sys);
  }
  /* The same through --set, on a file without integrator.constraints. */
  const char *ov[] = {"integrator.constraints.form=null-space",
                      "integrator.constraints.tolerance=1e-12",
                      "integrator.constraints.projection=false",
                      "integrator.constraints.form=multipliers"};
  sys = load("systems/cart_pendulum.yaml", ov, 3);
  if (sys) {
    CHECK(sys->settings.constraint_form == MRVI_FORM_NULL_SPACE, "--set form");
    CHECK_NEAR(sys->settings.constraint_tol, 1e-12, 0.0, "--set tolerance");
    CHECK(sys->settings.project_momenta == 0, "--set projection");
    mrvi_system_free(sys);
  }
  sys = load("systems/cart_pendulum.yaml", ov, 4);
  if (sys) {
    CHECK(sys->settings.constraint_form == MRVI_FORM_MULTIPLIERS,
          "last --set wins");
    mrvi_system_free(sys);
  }
  /* --set on a constraint: the rod of the chain made longer together with
   * the second link's position; the description reloads to the same. */
  const char *ov2[] = {"constraints.1.length=2",
                       "particles.1.position=[2.1213203435596428, "
                       "-2.1213203435596428]"};
  sys = load("systems/pendulum_chain.yaml", ov2, 2);
  if (sys) {
    double q[8];
    memcpy(q, mrvi_model_q0(sys->model), sizeof q);
    CHECK(max_abs_g(sys->model, q) <= 1e-12, "g(q0) after --set: %g",
          max_abs_g(sys->model, q));
    q[2] = 0.0, q[3] = -3.0; /* h2 at (0, -3), h1 at (1, -1)/sqrt 2 */
    double g[2];
    mrvi_model_constraint_eval(sys->model, q, g, NULL);
    const double h = 0.70710678118654757;
    const double d2 = h * h + (h - 3.0) * (h - 3.0);
    CHECK_NEAR(g[1], (d2 - 4.0) / 4.0, 1e-14, "rod 2 length 2 after --set");
    char msg[MSG];
    mrvi_system *again = NULL;
    int st = mrvi_system_load_string(sys->description, "description", NULL, 0,
                                     &again, msg, sizeof msg);
    CHECK(st == MRVI_OK, "description after --set does not load: %s", msg);
    mrvi_system_free(again);
    mrvi_system_free(sys);
  }
}

static void test_velocity_projection(void) {
  /* a (mass 1) moves along the rod towards b (mass 3, at rest): the
   * projection leaves both with the common velocity p/M = 1/4 along it and
   * keeps the tangential part of b (0, 0.5, 0). */
  const char *text = "name: p\ndimension: 3\nparticles:\n"
                     "  - {name: a, mass: 1, position: [0, 0, 0], "
                     "velocity: [1, 0, 0]}\n"
                     "  - {name: b, mass: 3, position: [2, 0, 0], "
                     "velocity: [0, 0.5, 0], rate: fast}\n"
                     "constraints:\n  - {type: distance, between: [a, b]}\n";
  mrvi_system *sys = load_text(text, NULL, 0);
  if (sys) {
    const double *v = mrvi_model_v0(sys->model);
    const double want[6] = {0.25, 0, 0, 0.25, 0.5, 0};
    for (int i = 0; i < 6; i++)
      CHECK_NEAR(v[i], want[i], 1e-15, "projected velocity");
    CHECK(hidden0(sys->model) <= 1e-12, "G M^-1 p0 = %g after load",
          hidden0(sys->model));
    CHECK(sys->notes && strstr(sys->notes, "initial velocities projected") &&
              strstr(sys->notes, "7.5e-01"),
          "projection note: %s", sys->notes ? sys->notes : "(none)");
    mrvi_system_free(sys);
  }
  /* Tangential velocities are kept exactly, without a note. */
  const char *tangent = "name: t\ndimension: 2\nparticles:\n"
                        "  - {name: a, mass: 1, position: [0, 1], "
                        "velocity: [2, 0]}\n"
                        "constraints:\n  - {type: distance, between: [a], "
                        "anchor: [0, 0]}\n";
  sys = load_text(tangent, NULL, 0);
  if (sys) {
    CHECK_NEAR(mrvi_model_v0(sys->model)[0], 2.0, 0.0, "tangential kept");
    CHECK(sys->notes == NULL, "note for tangential velocities: %s", sys->notes);
    mrvi_system_free(sys);
  }
}

/* A user type without its own syntax: coordinates and parameters. */
static int sum_check(int n_in, int n_params, const double *params, char *msg,
                     size_t len) {
  (void)params;
  if (n_params != 1) {
    snprintf(msg, len, "sum: one parameter (the total), got %d", n_params);
    return MRVI_EINVAL;
  }
  return n_in > 0 ? 1 : MRVI_EINVAL;
}
static void sum_eval(int n_in, int n_params, const double *params,
                     const double *y, double *g, double *G, double *H) {
  (void)n_params;
  g[0] = -params[0];
  for (int j = 0; j < n_in; j++) {
    g[0] += y[j];
    G[j] = 1.0;
  }
  if (H)
    memset(H, 0, (size_t)n_in * (size_t)n_in * sizeof *H);
}
static const mrvi_constraint_type sum_type = {.name = "sum",
                                              .summary = "sum of coordinates",
                                              .check = sum_check,
                                              .eval = sum_eval};

static void test_user_constraint_type(void) {
  CHECK(mrvi_constraint_type_register(&sum_type) == MRVI_OK,
        "register user type");
  const char *text = "name: u\ndimension: 1\ncoordinates:\n"
                     "  - {name: q1, mass: 1, position: 1}\n"
                     "particles: [{name: m, mass: 1, position: [2], "
                     "rate: fast}]\n"
                     "constraints:\n"
                     "  - {type: sum, coordinates: [q1, m.x], "
                     "parameters: [3]}\n";
  mrvi_system *sys = load_text(text, NULL, 0);
  if (sys) {
    const mrvi_model *m = sys->model;
    CHECK(mrvi_model_n_constraints(m) == 1, "user type count");
    CHECK(!strcmp(mrvi_model_constraint_type_name(m, 0), "sum"),
          "user type name");
    CHECK(mrvi_model_constraint_where(m, 0) == MRVI_FAST,
          "user type on a fast coordinate: micro nodes");
    double q[2] = {2, 5}, g;
    mrvi_model_constraint_eval(m, q, &g, NULL);
    CHECK_NEAR(g, 4.0, 0.0, "user type parameter");
    mrvi_system_free(sys);
  }
  /* Its errors: the type's own message at the entry, unknown names. */
  char bad[512], msg[MSG];
  snprintf(bad, sizeof bad, "%s", text);
  char *p = strstr(bad, "parameters: [3]");
  memcpy(p, "parameters: [ ]", 15);
  sys = NULL;
  int st =
      mrvi_system_load_string(bad, "u.yaml", NULL, 0, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EPARSE && !strncmp(msg, "u.yaml:7:", 9) &&
            strstr(msg, "one parameter (the total), got 0"),
        "user type check message: %s", msg);
  snprintf(bad, sizeof bad, "%s", text);
  p = strstr(bad, "m.x");
  memcpy(p, "m.y", 3);
  st = mrvi_system_load_string(bad, "u.yaml", NULL, 0, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EPARSE && strstr(msg, "u.yaml:7:") &&
            strstr(msg, "unknown coordinate 'm.y'; did you mean 'm.x'?"),
        "user type unknown coordinate: %s", msg);
}

/* A user type with its own keys (mrvi_constraint_key): read by the loader
 * with no code of its own.  height: a particle's last coordinate at a
 * level, g = y[d-1] - level; the level defaults to the initial one. */
static int height_check(int n_in, int n_params, const double *params, char *msg,
                        size_t len) {
  if (n_in < 1 || n_params != 1 || !(params[0] == params[0])) {
    snprintf(msg, len, "height: one level, got %d parameters", n_params);
    return MRVI_EINVAL;
  }
  return 1;
}
static void height_eval(int n_in, int n_params, const double *params,
                        const double *y, double *g, double *G, double *H) {
  (void)n_params;
  g[0] = y[n_in - 1] - params[0];
  for (int j = 0; j < n_in; j++)
    G[j] = j == n_in - 1;
  if (H)
    memset(H, 0, (size_t)n_in * (size_t)n_in * sizeof *H);
}
static int height_initial(int n_in, int n_params, double *params,
                          const double *y0, char *msg, size_t len) {
  (void)n_params, (void)msg, (void)len;
  if (params[0] != params[0]) /* NAN: not given */
    params[0] = y0[n_in - 1];
  return 0;
}
static const mrvi_constraint_key height_keys[] = {
    {"body", MRVI_KEY_PARTICLE, MRVI_KEY_REQUIRED, 0},
    {"level", MRVI_KEY_SCALAR, 0, 1},
    {0},
};
static const mrvi_constraint_type height_type = {.name = "height",
                                                 .summary = "y_d = level",
                                                 .check = height_check,
                                                 .eval = height_eval,
                                                 .initial = height_initial,
                                                 .keys = height_keys};

static void test_user_constraint_keys(void) {
  CHECK(mrvi_constraint_type_register(&height_type) == MRVI_OK,
        "register a type with keys");
  const char *text = "name: h\ndimension: 2\n"
                     "particles: [{name: m, mass: 1, position: [1, 3]},\n"
                     "            {name: n, mass: 1, position: [2, 5]}]\n"
                     "constraints:\n"
                     "  - {type: height, body: m, level: 3.00000000001}\n"
                     "  - {type: height, body: n}\n";
  mrvi_system *sys = load_text(text, NULL, 0);
  if (sys) {
    const mrvi_model *m = sys->model;
    CHECK(mrvi_model_n_constraints(m) == 2, "keyed type count");
    CHECK(!strcmp(mrvi_model_constraint_label(m, 0), "height m") &&
              !strcmp(mrvi_model_constraint_label(m, 1), "height n"),
          "keyed type labels '%s', '%s'", mrvi_model_constraint_label(m, 0),
          mrvi_model_constraint_label(m, 1));
    double q[4] = {0, 4, 0, 7}, g[2];
    mrvi_model_constraint_eval(m, q, g, NULL);
    CHECK_NEAR(g[0], 4.0 - 3.00000000001, 0.0, "keyed type: level read");
    CHECK_NEAR(g[1], 2.0, 0.0, "keyed type: level from the initial position");
    mrvi_system_free(sys);
  }
  /* Its keys in messages: a misspelt key, a missing one. */
  char bad[512], msg[MSG];
  snprintf(bad, sizeof bad, "%s", text);
  memcpy(strstr(bad, "level:"), "lever:", 6);
  sys = NULL;
  int st =
      mrvi_system_load_string(bad, "h.yaml", NULL, 0, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EPARSE && strstr(msg, "h.yaml:6:") &&
            strstr(msg, "unknown key 'lever' in constraints.0; did you mean "
                        "'level'?"),
        "keyed type unknown key: %s", msg);
  snprintf(bad, sizeof bad, "%s", text);
  memcpy(strstr(bad, "body: n"), "bod: n ", 7);
  st = mrvi_system_load_string(bad, "h.yaml", NULL, 0, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EPARSE && strstr(msg, "h.yaml:7:") &&
            strstr(msg, "unknown key 'bod' in constraints.1; did you mean "
                        "'body'?"),
        "keyed type misspelt key: %s", msg);
}

/* Shipped constrained systems: constraint counts and where they act, initial
 * data consistent, no hidden-constraint residual after loading. */
typedef struct constrained_file {
  const char *path;
  int n, n_constraints;
  mrvi_rate where[2];
  int note; /* the loader projected the velocities */
} constrained_file;

static mrvi_system *check_constrained_file(const constrained_file *f) {
  mrvi_system *sys = load(f->path, NULL, 0);
  if (!sys)
    return NULL;
  const mrvi_model *m = sys->model;
  CHECK(mrvi_model_n(m) == f->n, "%s: n = %d", f->path, mrvi_model_n(m));
  CHECK(mrvi_model_n_constraints(m) == f->n_constraints, "%s: %d constraints",
        f->path, mrvi_model_n_constraints(m));
  for (int c = 0; c < f->n_constraints && c < mrvi_model_n_constraints(m); c++)
    CHECK(mrvi_model_constraint_where(m, c) == f->where[c],
          "%s: constraint %d enforced at the wrong nodes", f->path, c);
  CHECK(max_abs_g(m, mrvi_model_q0(m)) <= 1e-12, "%s: |g(q0)| = %g", f->path,
        max_abs_g(m, mrvi_model_q0(m)));
  CHECK(hidden0(m) <= 1e-12, "%s: |G M^-1 p0| = %g", f->path, hidden0(m));
  CHECK(!f->note == !sys->notes, "%s: notes '%s'", f->path,
        sys->notes ? sys->notes : "(none)");
  return sys;
}

static void check_constrained_files(void) {
  const constrained_file cart = {
      "systems/cart_pendulum.yaml", 6, 2, {MRVI_SLOW, MRVI_FAST}, 0};
  mrvi_system *sys = check_constrained_file(&cart);
  if (sys) {
    const mrvi_model *m = sys->model;
    const double *q = mrvi_model_q0(m);
    double d[3] = {q[3] - q[0], q[4] - q[1], q[5] - q[2]};
    CHECK_NEAR(sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]), 0.2, 1e-16,
               "cart pendulum rod length");
    CHECK_NEAR(atan2(d[0], -d[2]) * 180.0 / acos(-1.0), 30.0, 1e-12,
               "cart pendulum rod at 30 degrees");
    /* Horizontal momentum 5 (0.1, 0) + 0.5 (0.1, 0.75). */
    double p[6], lin[3], ang[3];
    for (int i = 0; i < 6; i++)
      p[i] = mrvi_model_mass(m, i) * mrvi_model_v0(m)[i];
    mrvi_model_momentum(m, q, p, lin, ang);
    CHECK_NEAR(lin[0], 0.55, 1e-15, "cart pendulum momentum x");
    CHECK_NEAR(lin[1], 0.375, 1e-15, "cart pendulum momentum y");
    CHECK_NEAR(mrvi_model_mass(m, 0), 5.0, 0.0, "cart mass");
    CHECK_NEAR(mrvi_model_mass(m, 3), 0.5, 0.0, "bob mass");
    const mrvi_settings *s = &sys->settings;
    CHECK_NEAR(s->macro_step, 0.02, 0.0, "cart pendulum dT");
    CHECK(s->micro_steps == 5, "cart pendulum p");
    CHECK_NEAR(s->t_end, 10.0, 0.0, "cart pendulum t_end");
    CHECK_NEAR(s->newton_tol, 1e-10, 0.0, "cart pendulum tolerance");
    mrvi_system_free(sys);
  }

  const constrained_file ring = {
      "systems/spring_ring_rod.yaml", 18, 1, {MRVI_FAST, MRVI_FAST}, 1};
  sys = check_constrained_file(&ring);
  if (sys) {
    /* Same model as the C-API build, velocities projected the same way. */
    mrvi_model *ref = test_spring_ring_rod();
    for (int j = 0; j < 18; j++) {
      CHECK_NEAR(mrvi_model_q0(sys->model)[j], mrvi_model_q0(ref)[j], 1e-15,
                 "ring rod q0");
      CHECK_NEAR(mrvi_model_v0(sys->model)[j], mrvi_model_v0(ref)[j], 1e-13,
                 "ring rod v0");
    }
    mrvi_model_free(ref);
    CHECK(mrvi_model_n_elements(sys->model) == 13, "ring rod elements");
    CHECK(sys->settings.micro_steps == 10, "ring rod p");
    CHECK_NEAR(sys->settings.t_end, 2.0, 0.0, "ring rod t_end");
    mrvi_system_free(sys);
  }

  const constrained_file tri = {
      "systems/triatomic.yaml", 9, 2, {MRVI_FAST, MRVI_FAST}, 0};
  sys = check_constrained_file(&tri);
  if (sys) {
    const double *q = mrvi_model_q0(sys->model);
    /* Bond angle 104.5 degrees; the H-H spring starts at rest (W = 0). */
    double c = q[3] * q[6] + q[4] * q[7] + q[5] * q[8];
    CHECK_NEAR(acos(c) * 180.0 / acos(-1.0), 104.5, 1e-12, "bond angle");
    CHECK_NEAR(mrvi_model_potential(sys->model, MRVI_FAST, q, NULL, NULL), 0.0,
               1e-28, "triatomic W(q0)");
    CHECK(mrvi_model_n_slow(sys->model) == 3, "triatomic: O slow");
    /* Spin 0.5 about e3: angular momentum 2 * 0.5 sin^2(52.25 degrees). */
    double p[9], lin[3], ang[3];
    for (int i = 0; i < 9; i++)
      p[i] = mrvi_model_mass(sys->model, i) * mrvi_model_v0(sys->model)[i];
    mrvi_model_momentum(sys->model, q, p, lin, ang);
    const double s = sin(52.25 * acos(-1.0) / 180.0);
    CHECK_NEAR(ang[2], s * s, 1e-15, "triatomic angular momentum about e3");
    CHECK_NEAR(sys->settings.macro_step, 0.05, 0.0, "triatomic dT");
    CHECK(sys->settings.micro_steps == 10, "triatomic p");
    mrvi_system_free(sys);
  }

  const constrained_file chain = {
      "systems/pendulum_chain.yaml", 8, 2, {MRVI_SLOW, MRVI_SLOW}, 0};
  sys = check_constrained_file(&chain);
  if (sys) {
    const mrvi_model *m = sys->model;
    const double *q = mrvi_model_q0(m);
    CHECK(mrvi_model_dimension(m) == 2, "chain in 2-D");
    CHECK_NEAR(atan2(q[0], -q[1]) * 180.0 / acos(-1.0), 45.0, 1e-12,
               "chain at 45 degrees");
    CHECK_NEAR(atan2(q[2] - q[0], q[1] - q[3]) * 180.0 / acos(-1.0), 45.0,
               1e-12, "second link at 45 degrees");
    for (int i = 0; i < 8; i++)
      CHECK_NEAR(mrvi_model_v0(m)[i], 0.0, 0.0, "chain at rest");
    /* The three springs start at their rest lengths: V is gravity only. */
    double V = mrvi_model_potential(m, MRVI_SLOW, q, NULL, NULL);
    double Vg = 9.81 * (2 * q[1] + 2 * q[3] + 0.05 * q[5] + 0.05 * q[7]);
    CHECK_NEAR(V, Vg, 1e-12, "chain V(q0) = gravity");
    CHECK_NEAR(mrvi_model_potential(m, MRVI_FAST, q, NULL, NULL), 0.0, 1e-26,
               "chain W(q0)");
    CHECK_NEAR(sys->settings.t_end, 3.0, 0.0, "chain t_end");
    mrvi_system_free(sys);
  }
}

/* ---------------------------------------------------------------------------
 * Overrides and defaults
 * ------------------------------------------------------------------------- */

static void test_overrides(void) {
  /* Existing scalar; the description holds it and loads back the same. */
  const char *ov1[] = {"integrator.micro_steps=5"};
  mrvi_system *sys = load("systems/fpu.yaml", ov1, 1);
  if (sys) {
    CHECK(sys->settings.micro_steps == 5, "p after --set = %d",
          sys->settings.micro_steps);
    CHECK(sys->description && strstr(sys->description, "micro_steps: 5"),
          "description lacks the override:\n%s", sys->description);
    /* A replaced scalar is spliced into the text: comments survive. */
    CHECK(sys->description && strstr(sys->description, "Fermi-Pasta-Ulam") &&
              strstr(sys->description, "--set integrator.micro_steps=5"),
          "description lost the comments or the override note");
    char msg[MSG];
    mrvi_system *again = NULL;
    int st = mrvi_system_load_string(sys->description, "description", NULL, 0,
                                     &again, msg, sizeof msg);
    CHECK(st == MRVI_OK, "description does not load: %s", msg);
    if (again) {
      CHECK(again->settings.micro_steps == 5, "reloaded p");
      CHECK(mrvi_model_n_elements(again->model) == 7, "reloaded elements");
      CHECK_NEAR(mrvi_model_q0(again->model)[3], 0.02, 0.0, "reloaded q0");
    }
    mrvi_system_free(again);
    mrvi_system_free(sys);
  }

  /* List item by index (from 0): particles.2 is m3. */
  const char *ov2[] = {"particles.2.mass=3"};
  sys = load("systems/spring_ring.yaml", ov2, 1);
  if (sys) {
    for (int j = 0; j < 18; j++)
      CHECK_NEAR(mrvi_model_mass(sys->model, j), j / 3 == 2 ? 3.0 : 2.0, 0.0,
                 "mass after particles.2.mass=3");
    CHECK(sys->description && strstr(sys->description, "mass: 3"),
          "description lacks mass: 3");
    mrvi_system_free(sys);
  }

  /* A list value replaced: the description is the emitted document and
   * still loads to the same system. */
  const char *ov2b[] = {"gravity=[0, 0, -1]"};
  sys = load("systems/spring_ring.yaml", ov2b, 1);
  if (sys) {
    char msg[MSG];
    mrvi_system *again = NULL;
    int st = mrvi_system_load_string(sys->description, "description", NULL, 0,
                                     &again, msg, sizeof msg);
    CHECK(st == MRVI_OK, "emitted description does not load: %s", msg);
    if (again) {
      const double *q = mrvi_model_q0(sys->model);
      double V1 = mrvi_model_potential(sys->model, MRVI_SLOW, q, NULL, NULL);
      double V2 = mrvi_model_potential(again->model, MRVI_SLOW, q, NULL, NULL);
      CHECK_NEAR(V1, V2, 0.0, "reloaded V");
      CHECK(mrvi_model_n(again->model) == 18, "reloaded n");
    }
    mrvi_system_free(again);
    mrvi_system_free(sys);
  }

  /* Keys that do not exist are created; several overrides in order. */
  const char *ov3[] = {"integrator.newton.max_iterations=7", "output.every=4",
                       "integrator.t_end=20", "integrator.t_end=30"};
  sys = load("systems/oscillator.yaml", ov3, 4);
  if (sys) {
    CHECK(sys->settings.newton_max_iter == 7, "created newton key");
    CHECK_NEAR(sys->settings.newton_tol, 1e-9, 0.0, "default tolerance");
    CHECK(sys->output_every == 4, "output.every");
    CHECK_NEAR(sys->settings.t_end, 30.0, 0.0, "last override wins");
    mrvi_system_free(sys);
  }

  /* A flow value, and coordinate names that contain dots. */
  const char *text =
      "name: dots\n"
      "dimension: 2\n"
      "gravity: [0, -1]\n"
      "particles:\n"
      "  - {name: m1, mass: 2, position: [0, 1]}\n"
      "terms:\n"
      "  - {combination: {m1.x: 1}, law: linear, stiffness: 1}\n";
  const char *ov4[] = {"gravity=[0, -10]", "terms.0.combination.m1.x=3"};
  char msg[MSG];
  sys = NULL;
  int st =
      mrvi_system_load_string(text, "dots.yaml", ov4, 2, &sys, msg, sizeof msg);
  CHECK(st == MRVI_OK, "dots: %s", msg);
  if (sys) {
    double q[2] = {0.5, 1.5};
    /* V = 1/2 (3 * 0.5)^2 + m g y = 1.125 + 2 * 10 * 1.5 */
    CHECK_NEAR(mrvi_model_potential(sys->model, MRVI_SLOW, q, NULL, NULL),
               1.125 + 30.0, 1e-12, "V after overrides");
    mrvi_system_free(sys);
  }

  /* An error inside an override's value names the override. */
  const char *ov5[] = {"gravity=[0, x]"};
  sys = NULL;
  st =
      mrvi_system_load_string(text, "dots.yaml", ov5, 1, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EPARSE && !sys, "bad override value accepted");
  CHECK(!strncmp(msg, "--set gravity=[0, x]: gravity[1] must be a number", 49),
        "override value error: %s", msg);

  /* Errors in text name the display name; defaults apply. */
  const char *bad = "name: t\ncoordinates:\n  - {name: q, mass: 1, "
                    "position: 1, rate: quick}\n";
  st = mrvi_system_load_string(bad, "<text>", NULL, 0, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EPARSE && !strncmp(msg, "<text>:3:", 9),
        "load_string location: %s", msg);
  const char *good = "name: t\ncoordinates:\n  - {name: q, mass: 1, "
                     "position: 1}\n";
  st = mrvi_system_load_string(good, NULL, NULL, 0, &sys, msg, sizeof msg);
  CHECK(st == MRVI_OK, "minimal file: %s", msg);
  if (sys) {
    mrvi_settings def;
    mrvi_settings_default(&def);
    CHECK(!strcmp(sys->path, "<string>"), "default display name");
    CHECK(!strcmp(sys->output_file, "t.h5"), "default output %s",
          sys->output_file);
    CHECK(sys->output_every == 1 && sys->output_micro == 1, "output defaults");
    CHECK(mrvi_model_rate(sys->model, 0) == MRVI_SLOW, "default rate slow");
    CHECK_NEAR(mrvi_model_v0(sys->model)[0], 0.0, 0.0, "default velocity");
    CHECK_NEAR(sys->settings.macro_step, def.macro_step, 0.0, "default dT");
    CHECK(sys->settings.micro_steps == def.micro_steps, "default p");
    CHECK_NEAR(sys->settings.newton_tol, 1e-9, 0.0, "default tolerance");
    CHECK(sys->settings.newton_max_iter == 20, "default max_iterations");
    mrvi_system_free(sys);
  }

  /* Scheme first, then the rule overrides. */
  const char *rules = "name: r\ncoordinates:\n  - {name: q, mass: 1, "
                      "position: 1}\nintegrator:\n  slow: {gamma: 0, grid: "
                      "macro}\n  scheme: trapezoidal-midpoint\n";
  st = mrvi_system_load_string(rules, "r", NULL, 0, &sys, msg, sizeof msg);
  CHECK(st == MRVI_OK, "rules: %s", msg);
  if (sys) {
    CHECK_NEAR(sys->settings.slow.alpha, 1.0, 0.0, "alpha from scheme");
    CHECK_NEAR(sys->settings.slow.gamma, 0.0, 0.0, "gamma overridden");
    CHECK(sys->settings.slow_grid == MRVI_GRID_MACRO, "grid overridden");
    mrvi_system_free(sys);
  }

  /* A missing file is an I/O error. */
  st = mrvi_system_load("/nonexistent/x.yaml", NULL, 0, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EIO && !sys && strstr(msg, "/nonexistent/x.yaml"),
        "missing file: %d %s", st, msg);
}

/* The complete example of doc/description-files.md loads as documented. */
static void test_doc_example(void) {
  char *doc = slurp(test_source_path("doc/description-files.md"));
  CHECK(doc != NULL, "cannot read doc/description-files.md");
  if (!doc)
    return;
  char *start = strstr(doc, "## Complete example");
  start = start ? strstr(start, "```yaml\n") : NULL;
  char *end = start ? strstr(start + 8, "```") : NULL;
  CHECK(start && end, "no yaml block under 'Complete example'");
  if (start && end) {
    *end = '\0';
    char msg[MSG];
    mrvi_system *sys = NULL;
    int st = mrvi_system_load_string(start + 8, "example", NULL, 0, &sys, msg,
                                     sizeof msg);
    CHECK(st == MRVI_OK, "doc example: %s", msg);
    if (sys) {
      const char *names[5] = {"theta", "a.x", "a.y", "b.x", "b.y"};
      CHECK(mrvi_model_n(sys->model) == 5, "doc example n");
      for (int i = 0; i < 5 && i < mrvi_model_n(sys->model); i++)
        CHECK(!strcmp(mrvi_model_coordinate_name(sys->model, i,
                                                 (char[MRVI_NAME_MAX]){0}),
                      names[i]),
              "doc example order: %s", names[i]);
      CHECK(mrvi_model_n_fast(sys->model) == 2, "doc example n_f");
      CHECK(sys->output_every == 10 && !sys->output_micro,
            "doc example output");
      mrvi_system_free(sys);
    }
  }
  free(doc);
}

/* A w x h planar lattice: particle k at (1.1 x, y + 0.01 k mod 7), fast
 * where x + y is odd; slow springs to the right and upper neighbours with
 * stiffness 1 + k mod 5.  As description text (lattice_text) and through
 * the C API (lattice_model): the loader must build the same model. */
static double lattice_stiffness(int k) { return 1.0 + k % 5; }

static char *lattice_text(int w, int h) {
  size_t cap = (size_t)w * h * 400 + 256, off = 0;
  char *t = malloc(cap);
  if (!t)
    return NULL;
  off += (size_t)snprintf(t + off, cap - off,
                          "name: lattice\ndimension: 2\nparticles:\n");
  for (int k = 0; k < w * h; k++) {
    int x = k % w, y = k / w;
    off += (size_t)snprintf(
        t + off, cap - off,
        "  - {name: p%d, mass: %d, position: [%.17g, %.17g]%s}\n", k, 1 + k % 3,
        1.1 * x, y + 0.01 * (k % 7), (x + y) % 2 ? ", rate: fast" : "");
  }
  off += (size_t)snprintf(t + off, cap - off, "springs:\n");
  for (int k = 0; k < w * h; k++) {
    int x = k % w, y = k / w;
    for (int d = 0; d < 2; d++) {
      int j = d == 0 ? (x + 1 < w ? k + 1 : -1) : (y + 1 < h ? k + w : -1);
      if (j >= 0)
        off += (size_t)snprintf(t + off, cap - off,
                                "  - {between: [p%d, p%d], law: linear, "
                                "stiffness: %.17g, rest_length: 1}\n",
                                k, j, lattice_stiffness(k));
    }
  }
  return t;
}

static mrvi_model *lattice_model(int w, int h) {
  mrvi_model *m = mrvi_model_create();
  mrvi_model_set_dimension(m, 2);
  for (int k = 0; k < w * h; k++) {
    int x = k % w, y = k / w;
    char name[32];
    double x0[2] = {1.1 * x, y + 0.01 * (k % 7)}, v0[2] = {0, 0};
    snprintf(name, sizeof name, "p%d", k);
    mrvi_model_add_particle(m, name, 1 + k % 3,
                            (x + y) % 2 ? MRVI_FAST : MRVI_SLOW, x0, v0);
  }
  for (int k = 0; k < w * h; k++) {
    int x = k % w, y = k / w;
    double c = lattice_stiffness(k);
    if (x + 1 < w)
      mrvi_model_add_spring(m, MRVI_SLOW, k, k + 1, "linear", &c, 1.0);
    if (y + 1 < h)
      mrvi_model_add_spring(m, MRVI_SLOW, k, k + w, "linear", &c, 1.0);
  }
  return m;
}

static double seconds_now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

/* Load time of the w x h lattice (best of two), and its system. */
static double lattice_load(int w, int h, mrvi_system **sys) {
  char *text = lattice_text(w, h), msg[MSG];
  double best = 1e30;
  for (int rep = 0; rep < 2 && text; rep++) {
    mrvi_system_free(*sys);
    *sys = NULL;
    double t0 = seconds_now();
    int st =
        mrvi_system_load_string(text, "lattice", NULL, 0, sys, msg, sizeof msg);
    double dt = seconds_now() - t0;
    best = dt < best ? dt : best;
    CHECK(st == MRVI_OK, "lattice %dx%d: %s", w, h, msg);
  }
  free(text);
  return best;
}

/* Issue 8: the loader is linear in the file size (names by hash, lists
 * iterated once, the partition built once). */
static void test_large_lattice(void) {
  mrvi_system *sys = NULL, *small = NULL;
  double t_small = lattice_load(50, 50, &small);
  double t_big = lattice_load(100, 100, &sys);
  mrvi_model *ref = lattice_model(100, 100);
  fprintf(stderr, "lattice load: %.3f s (2500 particles), %.3f s (10^4)\n",
          t_small, t_big);
  if (sys && ref) {
    const mrvi_model *m = sys->model;
    int n = mrvi_model_n(ref);
    CHECK(mrvi_model_n(m) == n && n == 20000,
          "lattice: %d coordinates, C API %d", mrvi_model_n(m), n);
    CHECK(mrvi_model_n_fast(m) == mrvi_model_n_fast(ref) &&
              mrvi_model_n_slow(m) == mrvi_model_n_slow(ref) &&
              mrvi_model_n_fast(m) == 10000,
          "lattice: partition %d slow + %d fast, C API %d + %d",
          mrvi_model_n_slow(m), mrvi_model_n_fast(m), mrvi_model_n_slow(ref),
          mrvi_model_n_fast(ref));
    int same = mrvi_model_n(m) == n;
    for (int i = 0; same && i < mrvi_model_n_fast(m); i++)
      same = mrvi_model_fast_index(m)[i] == mrvi_model_fast_index(ref)[i];
    for (int i = 0; same && i < mrvi_model_n_slow(m); i++)
      same = mrvi_model_slow_index(m)[i] == mrvi_model_slow_index(ref)[i];
    CHECK(same, "lattice: slow/fast index maps differ from the C API's");
    /* The partition itself: each map increasing, of its rate, p_k's
     * coordinates 2k, 2k + 1 fast where x + y is odd. */
    int ok = mrvi_model_n_slow(m) + mrvi_model_n_fast(m) == n;
    for (int r = 0; r < 2 && ok; r++) {
      const int *ix = r ? mrvi_model_fast_index(m) : mrvi_model_slow_index(m);
      int cnt = r ? mrvi_model_n_fast(m) : mrvi_model_n_slow(m);
      for (int i = 0; i < cnt && ok; i++) {
        int k = ix[i] / 2, odd = (k % 100 + k / 100) % 2;
        ok = (i == 0 || ix[i] > ix[i - 1]) && odd == r &&
             (int)mrvi_model_rate(m, ix[i]) == r;
      }
    }
    CHECK(ok, "lattice: partition does not follow the rates");
    CHECK(mrvi_model_n_elements(m) == mrvi_model_n_elements(ref) &&
              mrvi_model_n_elements(m) == 2 * 100 * 99,
          "lattice: %d springs, C API %d", mrvi_model_n_elements(m),
          mrvi_model_n_elements(ref));
    if (same) {
      /* Same elements in the same order: the sums agree to rounding. */
      double v =
          mrvi_model_potential(m, MRVI_SLOW, mrvi_model_q0(m), NULL, NULL);
      double vr =
          mrvi_model_potential(ref, MRVI_SLOW, mrvi_model_q0(ref), NULL, NULL);
      CHECK_NEAR(v, vr, 1e-12 * fabs(vr), "lattice slow potential");
      CHECK(vr > 1.0, "lattice: potential %g, springs should be stretched", vr);
    }
  }
  /* 4x the particles: a linear loader takes ~4x the time, the old quadratic
   * one 16x and more. */
  CHECK(t_big < 10.0 * t_small + 0.05,
        "lattice load: %.3f s for 2500 particles, %.3f s for 10^4 (ratio "
        "%.1f, linear 4)",
        t_small, t_big, t_big / t_small);
  mrvi_model_free(ref);
  mrvi_system_free(sys);
  mrvi_system_free(small);
}

/* A --set path of 1600 segments is handled in linear time (was 51 s) and
 * refused: it would nest deeper than the document may. */
static void test_long_set_path(void) {
  size_t len = 11 + 2 * 1600 + 3;
  char *ov = malloc(len);
  if (!ov)
    return;
  strcpy(ov, "integrator");
  for (int i = 0; i < 1600; i++)
    strcat(ov, ".a");
  strcat(ov, "=1");
  const char *list[1] = {ov};
  char msg[8192];
  mrvi_system *sys = NULL;
  double t0 = seconds_now();
  int st = mrvi_system_load(test_source_path("systems/fpu.yaml"), list, 1, &sys,
                            msg, sizeof msg);
  double dt = seconds_now() - t0;
  CHECK(st == MRVI_EPARSE && !strncmp(msg, "--set integrator.a.a", 20) &&
            strstr(msg, ": the path is deeper than 256 levels"),
        "1600-segment --set: status %d, '%.80s'", st, msg);
  CHECK(dt < 5.0, "1600-segment --set took %.2f s", dt);
  mrvi_system_free(sys);
  free(ov);
}

/* Hostile input that cannot live in tests/bad_input/: an override value
 * that is not UTF-8, endless devices, a text beyond the size limit.  Each
 * fails with its message instead of hanging or growing memory. */
static void load_expect(const char *path, const char *set, const char *want) {
  char msg[MSG] = "";
  mrvi_system *sys = NULL;
  const char *ov[1] = {set};
  int st = mrvi_system_load(path, ov, set ? 1 : 0, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EPARSE && sys == NULL, "%s: status %d", path, st);
  CHECK(strstr(msg, want) != NULL, "%s: message '%s' lacks '%s'", path, msg,
        want);
  mrvi_system_free(sys);
}

static void test_hostile_input(void) {
  char fpu[1024];
  snprintf(fpu, sizeof fpu, "%s", test_source_path("systems/fpu.yaml"));
  /* libfyaml's directive scanner spins forever on "%\xff". */
  load_expect(fpu, "integrator.micro_steps=%\xff",
              "--set integrator.micro_steps=%\xff: invalid byte 0xff");
  load_expect(fpu, "integrator.micro_steps=1\x01", "control character U+0001");
  load_expect("/dev/zero", NULL, "/dev/zero:1:1: NUL byte");
  load_expect("/dev/urandom", NULL, "/dev/urandom:");
  /* Anchors, aliases and merge keys still work (resolved after the
   * expansion bound). */
  const char *merge = "name: merge\ndimension: 1\nparticles:\n"
                      "  - &base {name: m1, mass: 3, position: [0]}\n"
                      "  - {<<: *base, name: m2, position: [1.5]}\n";
  char mmsg[MSG] = "";
  mrvi_system *ms = NULL;
  int mst =
      mrvi_system_load_string(merge, "merge", NULL, 0, &ms, mmsg, sizeof mmsg);
  CHECK(mst == MRVI_OK && ms && mrvi_model_n(ms->model) == 2 &&
            mrvi_model_mass(ms->model, 1) == 3.0 &&
            mrvi_model_q0(ms->model)[1] == 1.5,
        "merge key: status %d '%s'", mst, mmsg);
  mrvi_system_free(ms);
  /* 64 MiB + 1 byte of valid text. */
  size_t big = ((size_t)64 << 20) + 1;
  char *text = malloc(big + 1);
  if (text) {
    memset(text, '#', big);
    text[big] = '\0';
    char msg[MSG] = "";
    mrvi_system *sys = NULL;
    int st =
        mrvi_system_load_string(text, "big", NULL, 0, &sys, msg, sizeof msg);
    CHECK(st == MRVI_EPARSE && strstr(msg, "larger than 64 MiB"),
          "64 MiB + 1: status %d, '%s'", st, msg);
    mrvi_system_free(sys);
    free(text);
  }
}

/* ---------------------------------------------------------------------------
 * Generators, angles, forces, rest_length: initial
 * ------------------------------------------------------------------------- */

/* Springs of model m by rate: counts[0] slow, counts[1] fast. */
static void count_springs(const mrvi_model *m, int counts[2]) {
  counts[0] = counts[1] = 0;
  for (int e = 0; e < mrvi_model_n_elements(m); e++) {
    char buf[512];
    mrvi_model_describe_element(m, e, buf, sizeof buf);
    if (!strncmp(buf, "slow spring", 11))
      counts[0]++;
    else if (!strncmp(buf, "fast spring", 11))
      counts[1]++;
  }
}

static void check_generated(const char *gen, int dim, int particles, int slow,
                            int slow_springs, int fast_springs) {
  char text[2048];
  snprintf(text, sizeof text,
           "name: g\ndimension: %d\ngenerate:\n  - %s\n"
           "integrator: {macro_step: 0.1, t_end: 1}\n",
           dim, gen);
  mrvi_system *sys = load_text(text, NULL, 0);
  if (!sys)
    return;
  const mrvi_model *m = sys->model;
  int sp[2];
  count_springs(m, sp);
  CHECK(mrvi_model_n_particles(m) == particles, "%s: %d particles", gen,
        mrvi_model_n_particles(m));
  CHECK(mrvi_model_n_slow(m) == slow * dim, "%s: %d slow coordinates", gen,
        mrvi_model_n_slow(m));
  CHECK(sp[0] == slow_springs && sp[1] == fast_springs,
        "%s: %d slow and %d fast springs", gen, sp[0], sp[1]);
  char note[256];
  snprintf(note, sizeof note, "%d particles (%d slow, %d fast), %d springs",
           particles, slow, particles - slow, slow_springs + fast_springs);
  CHECK(sys->notes && strstr(sys->notes, note), "%s: note '%s' in '%s'", gen,
        note, sys->notes ? sys->notes : "");
  mrvi_system_free(sys);
}

static void test_generators(void) {
  const char *k = "spring: {law: linear, stiffness: 2}";
  char g[512];
  /* n x m lattice: n(m-1) + m(n-1) springs; checkerboard rates join a slow
   * and a fast particle by every spring, so all springs are slow. */
  snprintf(g, sizeof g,
           "{kind: lattice2d, name: p, count: [3, 4], mass: 1, rates: "
           "alternate, %s}",
           k);
  check_generated(g, 2, 12, 6, 3 * 3 + 4 * 2, 0);
  /* n x m x l lattice: (n-1)ml + n(m-1)l + nm(l-1) springs, all fast. */
  snprintf(g, sizeof g,
           "{kind: lattice3d, name: c, count: [2, 3, 4], mass: 2, rates: "
           "all_fast, %s}",
           k);
  check_generated(g, 3, 24, 0, 0, 1 * 12 + 2 * 2 * 4 + 6 * 3);
  /* Ring of 7 with every third slow (0, 3, 6): 7 springs, fast only
   * between 1-2 and 4-5. */
  snprintf(g, sizeof g,
           "{kind: ring, name: r, count: 7, mass: 1, rates: {every: 3}, %s}",
           k);
  check_generated(g, 2, 7, 3, 5, 2);
  /* Chain of 10 alternating: 9 springs, all slow. */
  snprintf(g, sizeof g,
           "{kind: chain, name: q, count: 10, mass: 1, rates: alternate, %s}",
           k);
  check_generated(g, 1, 10, 5, 9, 0);
  /* Ring geometry: neighbours at the spacing. */
  mrvi_system *sys =
      load_text("name: r\ndimension: 2\ngenerate:\n  - {kind: ring, name: r, "
                "count: 5, spacing: 0.3, mass: 1}\n"
                "integrator: {macro_step: 0.1, t_end: 1}\n",
                NULL, 0);
  if (sys) {
    const double *q = mrvi_model_q0(sys->model);
    for (int i = 0; i < 5; i++) {
      const int j = (i + 1) % 5;
      CHECK_NEAR(hypot(q[2 * i] - q[2 * j], q[2 * i + 1] - q[2 * j + 1]), 0.3,
                 1e-14, "ring side");
    }
    mrvi_system_free(sys);
  }
}

/* A generated chain is the same model as the chain written by hand. */
static void test_generated_equals_hand(void) {
  static const char gen[] =
      "name: c\ndimension: 1\n"
      "generate:\n"
      "  - kind: chain\n    name: p\n    count: 4\n    spacing: 1.5\n"
      "    origin: [0.5]\n    mass: 2\n    rates: {every: 3}\n"
      "    slow_spring: {law: power, coefficient: 0.25, exponent: 4}\n"
      "    fast_spring: {law: linear, stiffness: 100}\n"
      "    initial:\n      - {index: 1, displacement: 0.25, velocity: -1}\n"
      "integrator: {macro_step: 0.1, t_end: 1}\n";
  static const char hand[] =
      "name: c\ndimension: 1\n"
      "particles:\n"
      "  - {name: p0, mass: 2, position: 0.5, rate: slow}\n"
      "  - {name: p1, mass: 2, position: 2.25, velocity: -1, rate: fast}\n"
      "  - {name: p2, mass: 2, position: 3.5, rate: fast}\n"
      "  - {name: p3, mass: 2, position: 5, rate: slow}\n"
      "springs:\n"
      "  - {between: [p0, p1], law: power, coefficient: 0.25, exponent: 4, "
      "rest_length: 1.5}\n"
      "  - {between: [p1, p2], law: linear, stiffness: 100, rest_length: 1.5, "
      "potential: fast}\n"
      "  - {between: [p2, p3], law: power, coefficient: 0.25, exponent: 4, "
      "rest_length: 1.5}\n"
      "integrator: {macro_step: 0.1, t_end: 1}\n";
  mrvi_system *a = load_text(gen, NULL, 0), *b = load_text(hand, NULL, 0);
  if (a && b) {
    CHECK(mrvi_model_hash(a->model) == mrvi_model_hash(b->model),
          "generated chain equals the hand-written chain");
    CHECK(mrvi_model_n_elements(a->model) == 3, "3 springs");
  }
  mrvi_system_free(a);
  mrvi_system_free(b);
  /* Generated particles are names the rest of the file can use. */
  mrvi_system *c = load_text(
      "name: c\ndimension: 1\n"
      "generate:\n  - {kind: chain, name: p, count: 3, mass: 1, spring: "
      "{law: linear, stiffness: 1}}\n"
      "springs:\n  - {between: [p0], anchor: [-1], law: linear, stiffness: 1, "
      "rest_length: initial}\n"
      "integrator: {macro_step: 0.1, t_end: 1}\n",
      NULL, 0);
  if (c) {
    char buf[512];
    mrvi_model_describe_element(c->model, 2, buf, sizeof buf);
    CHECK(strstr(buf, "p0-anchor [-1], rest length 1,") != NULL,
          "anchor spring on a generated particle: %s", buf);
  }
  mrvi_system_free(c);
}

/* The message of loading text, which must fail. */
static void load_fails(const char *text, const char *want) {
  char msg[MSG] = "";
  mrvi_system *sys = NULL;
  const int st =
      mrvi_system_load_string(text, "g.yaml", NULL, 0, &sys, msg, sizeof msg);
  CHECK(st < 0 && !sys && strstr(msg, want), "want '%s', got (%d) '%s'", want,
        st, msg);
  mrvi_system_free(sys);
}

/* Generated names are made by their generator's rule when asked, not
 * stored (src/model/model.c): every name reads as the generator wrote it,
 * every look-up finds it, and the look-ups that failed still fail with the
 * same messages; a prefix too long for a rule stores its names. */
static void test_generated_names(void) {
  static const char head[] =
      "name: g\ndimension: 3\nintegrator: {macro_step: 0.1, t_end: 1}\n"
      "coordinates:\n  - {name: th, mass: 1, position: 0}\n"
      "generate:\n  - {kind: lattice3d, name: p, count: [3, 2, 2], mass: 1}\n"
      "  - {kind: chain, name: c, count: 12, mass: 1}\n";
  char text[2048];
  snprintf(text, sizeof text,
           "%sforces:\n  - {coordinate: p2_1_1.z, force: 1}\n"
           "  - {coordinate: th, force: 1}\n"
           "springs:\n  - {between: [p1_0_1, c11], law: linear, stiffness: "
           "1}\n",
           head);
  mrvi_system *sys = load_text(text, NULL, 0);
  if (sys) {
    const mrvi_model *m = sys->model;
    char buf[MRVI_NAME_MAX], want[64];
    /* th, then p0_0_0.x .. p2_1_1.z (x fastest), then c0.x .. c11.z */
    CHECK(!strcmp(mrvi_model_coordinate_name(m, 0, buf), "th"), "own name %s",
          buf);
    for (int lin = 0; lin < 12; lin++)
      for (int a = 0; a < 3; a++) {
        snprintf(want, sizeof want, "p%d_%d_%d.%c", lin % 3, lin / 3 % 2,
                 lin / 6, "xyz"[a]);
        const char *got = mrvi_model_coordinate_name(m, 1 + 3 * lin + a, buf);
        CHECK(got && !strcmp(got, want), "coordinate %d: %s, want %s",
              1 + 3 * lin + a, got ? got : "(null)", want);
      }
    CHECK(!strcmp(mrvi_model_coordinate_name(m, 1 + 36 + 33 + 2, buf), "c11.z"),
          "chain coordinate %s", buf);
    CHECK(mrvi_model_coordinate_name(m, mrvi_model_n(m), buf) == NULL,
          "no name past the last coordinate");
    char d[512];
    mrvi_model_describe_element(m, 0, d, sizeof d);
    CHECK(strstr(d, "spring p1_0_1-c11,") != NULL, "spring by names: %s", d);
    mrvi_model_describe_element(m, 1, d, sizeof d);
    CHECK(strstr(d, "p2_1_1.z") != NULL, "force by name: %s", d);
  }
  mrvi_system_free(sys);
  static const struct {
    const char *tail, *want;
  } bad[] = {
      {"springs:\n  - {between: [p01_1_1, c0], law: linear, stiffness: 1}\n",
       "unknown particle 'p01_1_1'; did you mean 'p0_1_1'?"},
      {"springs:\n  - {between: [p3_0_0, c0], law: linear, stiffness: 1}\n",
       "unknown particle 'p3_0_0'; did you mean 'p0_0_0'?"},
      {"springs:\n  - {between: [c12, c0], law: linear, stiffness: 1}\n",
       "unknown particle 'c12'; did you mean 'c1'?"},
      {"forces:\n  - {coordinate: p1_1_1.w, force: 1}\n",
       "unknown coordinate 'p1_1_1.w'; did you mean 'p1_1_1.x'?"},
      {"bodies:\n  - {name: c3, mass: 1, inertia: [1, 1, 1], position: [5, 5, "
       "5]}\n",
       "body 'c3': a particle has that name"},
  };
  for (size_t i = 0; i < sizeof bad / sizeof *bad; i++) {
    snprintf(text, sizeof text, "%s%s", head, bad[i].tail);
    load_fails(text, bad[i].want);
  }
  load_fails("name: g\ndimension: 1\nintegrator: {macro_step: 0.1, t_end: 1}\n"
             "generate:\n  - {kind: chain, name: q, count: 12, mass: 1}\n"
             "  - {kind: chain, name: q1, count: 3, mass: 1}\n",
             "duplicate particle name 'q10'");
  load_fails("name: g\ndimension: 2\nintegrator: {macro_step: 0.1, t_end: 1}\n"
             "generate:\n  - {kind: lattice2d, name: p, count: [3, 3], mass: "
             "1}\n  - {kind: chain, name: p1_, count: 3, mass: 1}\n",
             "duplicate particle name 'p1_0'");
  load_fails("name: g\ndimension: 1\nintegrator: {macro_step: 0.1, t_end: 1}\n"
             "particles:\n  - {name: q2, mass: 1, position: 0}\n"
             "generate:\n  - {kind: chain, name: q, count: 3, mass: 1}\n",
             "duplicate particle name 'q2'");
  /* A prefix too long for a rule: its names stored, the same look-ups. */
  char prefix[240];
  memset(prefix, 'a', sizeof prefix - 1);
  prefix[sizeof prefix - 1] = '\0';
  snprintf(text, sizeof text,
           "name: g\ndimension: 1\nintegrator: {macro_step: 0.1, t_end: 1}\n"
           "generate:\n  - {kind: chain, name: %s, count: 3, mass: 1}\n"
           "springs:\n  - {between: [%s2], anchor: [9], law: linear, "
           "stiffness: 1}\n",
           prefix, prefix);
  if ((sys = load_text(text, NULL, 0))) {
    char buf[MRVI_NAME_MAX];
    const char *got = mrvi_model_coordinate_name(sys->model, 2, buf);
    CHECK(got && strlen(got) == sizeof prefix - 1 + 3 &&
              !strcmp(got + sizeof prefix - 1, "2.x"),
          "long generated name %s", got ? got : "(null)");
  }
  mrvi_system_free(sys);
}

/* Particles added one by one as PREFIX0, PREFIX1, ... are named by a
 * sequence rule (src/model/model.c, sequence_name), not stored: every name
 * reads as given, every look-up finds it, a name out of sequence (a gap, a
 * leading zero, another particle in between, a ninth sequence) is stored,
 * and a duplicate is refused as before. */
static void test_sequence_names(void) {
  static const char *const names[] = {
      "p0",   "p1",   "p2",   "b",    "p3", "q0", "q00",  "q1",
      "p4",   "r0",   "r1",   "r2",   "s7", "t0", "a0_0", "a1_0",
      "a2_0", "a3_0", "a4_0", "a5_0", "r3", "x"};
  const int np = (int)(sizeof names / sizeof *names);
  /* stored: b, p3, q00, q1, p4, s7, a4_0, a5_0 (the ninth and tenth
   * sequence), r3 (r's sequence is not the last rule), x */
  mrvi_model *m = mrvi_model_create();
  CHECK(m && mrvi_model_set_dimension(m, 2) == MRVI_OK, "model");
  if (!m)
    return;
  const double x0[2] = {0, 0}, v0[2] = {0, 0};
  for (int i = 0; i < np; i++)
    CHECK(mrvi_model_add_particle(m, names[i], 1.0, MRVI_SLOW, x0, v0) == i,
          "add %s: %s", names[i], mrvi_model_errmsg(m));
  CHECK(m->n_particle_table == 10 && m->n_rules == 8,
        "stored names %d (want 10), rules %d (want 8)", m->n_particle_table,
        m->n_rules);
  const char *all[64];
  char *block = mrvi_model_names(m, 1, all);
  for (int i = 0; i < np; i++) {
    char want[64], buf[MRVI_NAME_MAX];
    CHECK(!strcmp(MRVI_PNAME(m, i), names[i]), "particle %d: %s, want %s", i,
          MRVI_PNAME(m, i), names[i]);
    CHECK(block && !strcmp(all[i], names[i]), "names[%d]: %s, want %s", i,
          block ? all[i] : "(no memory)", names[i]);
    CHECK(mrvi_model_find_particle(m, names[i]) == i, "find %s: %d", names[i],
          mrvi_model_find_particle(m, names[i]));
    snprintf(want, sizeof want, "%s.y", names[i]);
    const char *got = mrvi_model_coordinate_name(m, 2 * i + 1, buf);
    CHECK(got && !strcmp(got, want), "coordinate %d: %s, want %s", 2 * i + 1,
          got ? got : "(null)", want);
    CHECK(mrvi_model_find_coordinate(m, want) == 2 * i + 1, "find %s", want);
  }
  free(block);
  static const char *const absent[] = {"p5", "q2", "r4",   "p01", "r",
                                       "t1", "s0", "a0_1", "p-1", "p 1"};
  for (size_t i = 0; i < sizeof absent / sizeof *absent; i++)
    CHECK(mrvi_model_find_particle(m, absent[i]) == -1, "%s found", absent[i]);
  CHECK(mrvi_model_add_particle(m, "r1", 1.0, MRVI_SLOW, x0, v0) < 0 &&
            strstr(mrvi_model_errmsg(m), "duplicate particle name 'r1'"),
        "duplicate r1: %s", mrvi_model_errmsg(m));
  CHECK(mrvi_model_add_particle(m, "p3", 1.0, MRVI_SLOW, x0, v0) < 0 &&
            strstr(mrvi_model_errmsg(m), "duplicate particle name 'p3'"),
        "duplicate p3: %s", mrvi_model_errmsg(m));
  /* a bad mass leaves no sequence behind: the next x0 begins one */
  CHECK(mrvi_model_add_particle(m, "y0", -1.0, MRVI_SLOW, x0, v0) < 0,
        "negative mass");
  CHECK(mrvi_model_find_particle(m, "y0") == -1 && m->n_rules == 8,
        "y0 after its failure: %d rules", m->n_rules);
  mrvi_model_free(m);
  /* Through the loader: the messages that name such particles. */
  load_fails("name: s\ndimension: 1\nintegrator: {macro_step: 0.1, t_end: 1}\n"
             "particles:\n  - {name: n0, mass: 1, position: 0}\n"
             "  - {name: n1, mass: 1, position: 1}\n"
             "springs:\n  - {between: [n0, n2], law: linear, stiffness: 1}\n",
             "unknown particle 'n2'; did you mean 'n0'?");
}

static void test_angles_forces_rest(void) {
  static const char text[] =
      "name: t\ndimension: 2\n"
      "particles:\n"
      "  - {name: a, mass: 1, position: [3, 0]}\n"
      "  - {name: b, mass: 1, position: [0, 0]}\n"
      "  - {name: c, mass: 1, position: [0, 4]}\n"
      "springs:\n"
      "  - {between: [a, c], law: linear, stiffness: 1, rest_length: "
      "initial}\n"
      "angles:\n"
      "  - {particles: [a, b, c], stiffness: 2}\n"
      "  - {particles: [b, a, c], stiffness: 3, rest_angle: 1.0}\n"
      "forces:\n"
      "  - {particle: a, force: [1, -2]}\n"
      "  - {coordinate: c.y, force: 0.5}\n"
      "integrator: {macro_step: 0.1, t_end: 1}\n";
  mrvi_system *sys = load_text(text, NULL, 0);
  if (!sys)
    return;
  const mrvi_model *m = sys->model;
  char buf[512];
  CHECK(mrvi_model_n_elements(m) == 5, "5 elements");
  mrvi_model_describe_element(m, 0, buf, sizeof buf);
  CHECK(strstr(buf, "rest length 5,") != NULL, "rest_length initial: %s", buf);
  mrvi_model_describe_element(m, 1, buf, sizeof buf);
  CHECK(strstr(buf, "angle a-b-c, stiffness 2, rest angle 1.5708") != NULL,
        "initial rest angle: %s", buf);
  /* At q0: spring and first angle at rest; second angle at theta =
   * atan(4/3) against 1.0; forces -f^T q = -(1*3 - 2*0) - 0.5*4. */
  const double th = atan2(4.0, 3.0);
  const double V =
      mrvi_model_potential(m, MRVI_SLOW, mrvi_model_q0(m), NULL, NULL);
  CHECK_NEAR(V, 3 * (1 - cos(th - 1.0)) - 3.0 - 2.0, 1e-13,
             "potential of angles and forces at q0");
  mrvi_system_free(sys);
}

/* Gravity acts on generated particles (doc/description-files.md,
 * generate): a generated lattice with gravity equals the same particles
 * written out by hand, its slow potential gains -sum_i m_i g.x_i over every
 * generated particle, and it runs.  Also through --set on
 * systems/lattice.yaml, which once failed with an empty message. */
static void test_generated_gravity(void) {
  static const char gen[] =
      "name: g\ndimension: 2\ngravity: [0.5, -9.81]\n"
      "generate:\n"
      "  - kind: lattice2d\n    name: p\n    count: [2, 2]\n    spacing: 1.5\n"
      "    mass: 2\n    rates: {every: 2}\n"
      "    slow_spring: {law: linear, stiffness: 10}\n"
      "    fast_spring: {law: linear, stiffness: 100}\n"
      "integrator: {macro_step: 0.01, micro_steps: 2, t_end: 0.2}\n";
  static const char hand[] =
      "name: g\ndimension: 2\ngravity: [0.5, -9.81]\n"
      "particles:\n"
      "  - {name: p0_0, mass: 2, position: [0, 0], rate: slow}\n"
      "  - {name: p1_0, mass: 2, position: [1.5, 0], rate: fast}\n"
      "  - {name: p0_1, mass: 2, position: [0, 1.5], rate: slow}\n"
      "  - {name: p1_1, mass: 2, position: [1.5, 1.5], rate: fast}\n"
      "springs:\n"
      "  - {between: [p0_0, p1_0], law: linear, stiffness: 10, "
      "rest_length: 1.5}\n"
      "  - {between: [p0_0, p0_1], law: linear, stiffness: 10, "
      "rest_length: 1.5}\n"
      "  - {between: [p1_0, p1_1], law: linear, stiffness: 100, "
      "rest_length: 1.5, potential: fast}\n"
      "  - {between: [p0_1, p1_1], law: linear, stiffness: 10, "
      "rest_length: 1.5}\n"
      "integrator: {macro_step: 0.01, micro_steps: 2, t_end: 0.2}\n";
  mrvi_system *a = load_text(gen, NULL, 0), *b = load_text(hand, NULL, 0);
  CHECK(a && b, "gravity with generate loads");
  if (a && b) {
    const mrvi_model *m = a->model;
    int n = mrvi_model_n(m);
    const double *q = mrvi_model_q0(m);
    /* Springs at rest length: V(q0) is the gravity potential alone. */
    double want = 0, g[2] = {0.5, -9.81};
    for (int i = 0; i < n; i++)
      want -= mrvi_model_mass(m, i) * g[i % 2] * q[i];
    double v = mrvi_model_potential(m, MRVI_SLOW, q, NULL, NULL);
    CHECK(n == 8 && fabs(v - want) <= 1e-12 * fabs(want) && want != 0,
          "V(q0) = %.17g, -sum m g.x = %.17g", v, want);
    /* Same elements; gravity comes after the generated springs (the hand
     * file puts it before them), so V sums in another order: the runs agree
     * to roundoff, not bitwise. */
    CHECK(mrvi_model_n_elements(m) == 5 && mrvi_model_n_elements(b->model) == 5,
          "4 springs and gravity");
    mrvi_summary sa, sb;
    int ra = mrvi_run(m, &a->settings, NULL, NULL, NULL, &sa);
    int rb = mrvi_run(b->model, &b->settings, NULL, NULL, NULL, &sb);
    CHECK(ra == MRVI_OK && rb == MRVI_OK && sa.steps == 20 &&
              fabs(sa.energy_last - sb.energy_last) <=
                  1e-12 * fabs(sb.energy_last) &&
              fabs(sa.max_rel_energy_error - sb.max_rel_energy_error) <= 1e-9,
          "runs: %d %d, %ld steps, H %.17g vs %.17g", ra, rb, sa.steps,
          sa.energy_last, sb.energy_last);
  }
  mrvi_system_free(a);
  mrvi_system_free(b);
  const char *ov[] = {"gravity=[0,-9.81]"};
  mrvi_system *l = load("systems/lattice.yaml", ov, 1);
  mrvi_system *l0 = load("systems/lattice.yaml", NULL, 0);
  if (l && l0) {
    const mrvi_model *m = l->model;
    const double *q = mrvi_model_q0(m);
    double want = 0; /* -sum m g.x = sum m 9.81 y over the 30 particles */
    for (int i = 1; i < mrvi_model_n(m); i += 2)
      want += mrvi_model_mass(m, i) * 9.81 * q[i];
    double v = mrvi_model_potential(m, MRVI_SLOW, q, NULL, NULL) -
               mrvi_model_potential(l0->model, MRVI_SLOW, q, NULL, NULL);
    CHECK(mrvi_model_n(m) == 60 && fabs(v - want) <= 1e-12 * fabs(want) &&
              want > 0,
          "lattice: V with gravity - V without = %.17g, sum m g y = %.17g", v,
          want);
  }
  mrvi_system_free(l);
  mrvi_system_free(l0);
}

/* mrvi check writes a term as one would: no "1*", "+ -" or "- 0". */
static void test_term_description(void) {
  mrvi_system *sys = load_text(
      "name: t\n"
      "coordinates:\n  - {name: a, mass: 1, position: 0}\n"
      "  - {name: b, mass: 1, position: 0}\n"
      "terms:\n"
      "  - {combination: {a: 1, b: -1}, law: linear, stiffness: 1}\n"
      "  - {combination: {a: -2, b: 0.5}, offset: -1, law: linear, "
      "stiffness: 1}\n"
      "  - {combination: {b: 1}, offset: 3, law: linear, stiffness: 1}\n"
      "integrator: {macro_step: 0.1, t_end: 1}\n",
      NULL, 0);
  static const char *const want[] = {"slow term on a - b, ",
                                     "slow term on -2*a + 0.5*b + 1, ",
                                     "slow term on b - 3, "};
  for (int e = 0; sys && e < 3; e++) {
    char buf[256];
    mrvi_model_describe_element(sys->model, e, buf, sizeof buf);
    CHECK(strncmp(buf, want[e], strlen(want[e])) == 0,
          "term %d described as '%s', want '%s...'", e, buf, want[e]);
  }
  mrvi_system_free(sys);
}

/* Body orientation as a unit quaternion equals {axis, angle} (q = (cos a/2,
 * sin a/2 k)), and `frame: body` takes velocity and angular velocity in the
 * body's frame: the loaded directors d_i and their rates give back
 * omega = 1/2 sum d_i x d_i' with d_i . omega = Omega_i and phi' = sum V_i d_i.
 */
static void test_body_orientation_forms(void) {
  const double a = 0.7, k[3] = {0, 0.6, 0.8}, W[3] = {1, -2, 3},
               V[3] = {0.5, 0.25, -1};
  char text[2][1024];
  for (int form = 0; form < 2; form++) {
    char orient[256];
    if (form == 0)
      snprintf(orient, sizeof orient,
               "{axis: [%.17g, %.17g, %.17g], angle: %.17g}", k[0], k[1], k[2],
               a);
    else
      snprintf(orient, sizeof orient,
               "{quaternion: [%.17g, %.17g, %.17g, %.17g]}", cos(a / 2),
               sin(a / 2) * k[0], sin(a / 2) * k[1], sin(a / 2) * k[2]);
    snprintf(
        text[form], sizeof text[form],
        "name: b\ndimension: 3\nbodies:\n"
        "  - {name: top, mass: 2, inertia: [1, 2, 2.5], position: [1, 2, 3],\n"
        "     orientation: %s, frame: body,\n"
        "     velocity: [%.17g, %.17g, %.17g],\n"
        "     angular_velocity: [%.17g, %.17g, %.17g]}\n"
        "integrator: {macro_step: 0.01, t_end: 0.1}\n",
        orient, V[0], V[1], V[2], W[0], W[1], W[2]);
  }
  mrvi_system *s0 = load_text(text[0], NULL, 0),
              *s1 = load_text(text[1], NULL, 0);
  if (!s0 || !s1) {
    mrvi_system_free(s0), mrvi_system_free(s1);
    return;
  }
  const double *q0 = mrvi_model_q0(s0->model), *q1 = mrvi_model_q0(s1->model),
               *v0 = mrvi_model_v0(s0->model), *v1 = mrvi_model_v0(s1->model);
  double dq = 0, dv = 0;
  for (int i = 0; i < 12; i++) {
    dq = fmax(dq, fabs(q0[i] - q1[i]));
    dv = fmax(dv, fabs(v0[i] - v1[i]));
  }
  CHECK(dq < 1e-15 && dv < 1e-14,
        "quaternion and axis-angle differ: q %.3g, v %.3g", dq, dv);
  double w[3] = {0, 0, 0}, phidot[3] = {0, 0, 0};
  for (int i = 0; i < 3; i++) {
    const double *d = q1 + 3 + 3 * i, *dd = v1 + 3 + 3 * i;
    w[0] += 0.5 * (d[1] * dd[2] - d[2] * dd[1]);
    w[1] += 0.5 * (d[2] * dd[0] - d[0] * dd[2]);
    w[2] += 0.5 * (d[0] * dd[1] - d[1] * dd[0]);
    for (int c = 0; c < 3; c++)
      phidot[c] += V[i] * d[c];
  }
  double err = 0;
  for (int i = 0; i < 3; i++) {
    const double *d = q1 + 3 + 3 * i;
    err = fmax(err, fabs(d[0] * w[0] + d[1] * w[1] + d[2] * w[2] - W[i]));
    err = fmax(err, fabs(v1[i] - phidot[i]));
  }
  CHECK(err < 1e-13, "frame: body: omega / velocity off by %.3g", err);
  mrvi_system_free(s0);
  mrvi_system_free(s1);
}

/* The fuzzer's own seeds (tests/fuzz/seeds/: the compact spring table,
 * several generators, state actuators, bench/'s problems) are valid files,
 * with their "# set: " lines applied, so that they lead the fuzzer into
 * what they were written for rather than into the first refusal. */
static void test_fuzz_seeds(void) {
  char **files = NULL;
  const int n = list_yaml_files("tests/fuzz/seeds", &files);
  CHECK(n >= 7, "only %d fuzz seeds", n);
  for (int i = 0; i < n; i++) {
    char *ov[4];
    int n_ov = 0;
    FILE *f = fopen(files[i], "r");
    char line[1024];
    while (f && fgets(line, sizeof line, f))
      if (!strncmp(line, "# set: ", 7) && n_ov < 4) {
        chomp(line);
        ov[n_ov++] = strdup(line + 7);
      }
    if (f)
      fclose(f);
    char msg[MSG] = "";
    mrvi_system *sys = NULL;
    const int st = mrvi_system_load(files[i], (const char *const *)ov, n_ov,
                                    &sys, msg, sizeof msg);
    CHECK(st == MRVI_OK && sys, "fuzz seed %s: %s", files[i], msg);
    mrvi_system_free(sys);
    for (int k = 0; k < n_ov; k++)
      free(ov[k]);
    free(files[i]);
  }
  free(files);
}

/* limits.max_coordinates (doc/description-files.md, "Limits"): the file's
 * bound on what `generate:` makes, raised by --set to exactly the model's
 * 1204 coordinates it loads; one below, refused naming the count to set. */
static void test_generate_limit(void) {
  char path[1024];
  snprintf(path, sizeof path, "%s",
           test_source_path("tests/bad_input/generate_over_limit.yaml"));
  const char *at[1] = {"limits.max_coordinates=1204"};
  const char *below[1] = {"limits.max_coordinates=1203"};
  char msg[MSG] = "";
  mrvi_system *sys = NULL;
  int st = mrvi_system_load(path, at, 1, &sys, msg, sizeof msg);
  CHECK(st == MRVI_OK && sys && mrvi_model_n(sys->model) == 1204,
        "limit 1204: status %d, %d coordinates (%s)", st,
        sys ? mrvi_model_n(sys->model) : -1, msg);
  mrvi_system_free(sys);
  sys = NULL;
  msg[0] = '\0';
  st = mrvi_system_load(path, below, 1, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EPARSE && !sys &&
            strstr(msg, "generate_over_limit.yaml:13:13: generate.2") &&
            strstr(msg, "more than limits.max_coordinates = 1203: to load "
                        "it, set `limits: {max_coordinates: 1204}`"),
        "limit 1203: status %d, '%s'", st, msg);
  mrvi_system_free(sys);
}

/* limits.max_memory (doc/description-files.md, "Limits"): the file's bound
 * on the integrator's step (and the model), the same on every machine:
 * tests/bad_input/memory_limit_step.yaml's 10^5 micro steps of one fast
 * coordinate need 64 (10^5 + 1) + 4 (10^5 + 1) 48 bytes = 0.02384 GiB,
 * loaded with the value the message says to set (0.024) and refused with
 * 0.023; the default limit (16 GiB) loads it too. */
static void test_memory_limit(void) {
  char path[1024];
  snprintf(path, sizeof path, "%s",
           test_source_path("tests/bad_input/memory_limit_step.yaml"));
  const char *at[1] = {"limits.max_memory=0.024"};
  const char *below[1] = {"limits.max_memory=0.023"};
  const char *dflt[1] = {"limits.max_memory=16"};
  char msg[MSG] = "";
  mrvi_system *sys = NULL;
  int st = mrvi_system_load(path, at, 1, &sys, msg, sizeof msg);
  CHECK(st == MRVI_OK && sys, "max_memory 0.024: status %d (%s)", st, msg);
  mrvi_system_free(sys);
  sys = NULL;
  st = mrvi_system_load(path, dflt, 1, &sys, msg, sizeof msg);
  CHECK(st == MRVI_OK && sys, "max_memory 16: status %d (%s)", st, msg);
  mrvi_system_free(sys);
  sys = NULL;
  msg[0] = '\0';
  st = mrvi_system_load(path, below, 1, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EPARSE && !sys &&
            strstr(msg, "memory_limit_step.yaml:9:14: integrator.micro_steps "
                        "× fast coordinates = 100000 × 1 (and 1 coordinates) "
                        "need per macro step about 0.02384 GiB, more than "
                        "limits.max_memory = 0.023 GiB: to load it, set "
                        "`limits: {max_memory: 0.024}`"),
        "max_memory 0.023: status %d, '%s'", st, msg);
  mrvi_system_free(sys);
}

int main(void) {
  char **files = NULL;
  int n = list_yaml_files("tests/bad_input", &files);
  CHECK(n >= 19, "only %d bad input files", n);
  for (int i = 0; i < n; i++) {
    bad_case c;
    int ok = read_case(files[i], &c) == 0;
    CHECK(ok, "%s: first line is not '# expect: LINE: TEXT'", files[i]);
    if (ok)
      test_bad_file(&c);
  }
  check_fpu_file();
  check_spring_ring_file();
  check_oscillator_file();
  test_overrides();
  test_constraints_parsed();
  test_constraint_settings();
  test_velocity_projection();
  test_user_constraint_type();
  test_user_constraint_keys();
  check_constrained_files();
  test_doc_example();
  test_hostile_input();
  test_large_lattice();
  test_generate_limit();
  test_memory_limit();
  test_long_set_path();
  test_generators();
  test_generated_equals_hand();
  test_generated_names();
  test_sequence_names();
  test_generated_gravity();
  test_term_description();
  test_body_orientation_forms();
  test_angles_forces_rest();
  test_cli_bad_files(files, n);
  test_fuzz_seeds();
  for (int i = 0; i < n; i++)
    free(files[i]);
  free(files);
  return test_finish();
}
