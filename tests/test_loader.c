/* Description files: every broken file in tests/bad_input/ fails with
 * "file:line:col: message" (library and CLI), the shipped systems hold the
 * paper's set-ups (DESIGN §5), and --set overrides reach the model and the
 * stored description. */
#include "mrvi.h"
#include "models.h"
#include "testlib.h"

#include <dirent.h>
#include <fcntl.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#define MSG 1024

/* ---------------------------------------------------------------------------
 * Broken files.  Line 1: "# expect: LINE: SUBSTRING" (LINE is a number, or
 * `set` for an error reported against an override); optional line 2:
 * "# set: KEY=VALUE", an override to apply.
 * ------------------------------------------------------------------------- */

typedef struct bad_case {
  char path[1024];
  int line;          /* expected line, 0 for an override error */
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

/* Sorted list of tests/bad_input/ *.yaml; returns the count. */
static int list_bad_files(char ***out) {
  char dir[1024];
  snprintf(dir, sizeof dir, "%s", test_source_path("tests/bad_input"));
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

/* The message starts with the location the case expects. */
static int location_ok(const bad_case *c, const char *msg) {
  char want[1100];
  if (c->line == 0)
    return !strncmp(msg, "--set ", 6);
  snprintf(want, sizeof want, "%s:%d:", c->path, c->line);
  return !strncmp(msg, want, strlen(want));
}

static void test_bad_file(const bad_case *c) {
  char msg[MSG] = "";
  mrvi_system *sys = (mrvi_system *)&msg; /* must be reset to NULL */
  const char *ov[1] = {c->set};
  int st =
      mrvi_system_load(c->path, ov, c->set[0] ? 1 : 0, &sys, msg, sizeof msg);
  CHECK(st == MRVI_EPARSE, "%s: status %d, expected MRVI_EPARSE", c->path, st);
  CHECK(sys == NULL, "%s: *out not NULL on failure", c->path);
  CHECK(location_ok(c, msg), "%s: message '%s' does not start at line %d",
        c->path, msg, c->line);
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
  size_t cap = 1 << 16, n;
  char *buf = malloc(cap);
  n = fread(buf, 1, cap - 1, f);
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
    if (c.line)
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
    CHECK(!strcmp(mrvi_model_coordinate_name(m, i), names[i]),
          "fpu coordinate %d is %s", i, mrvi_model_coordinate_name(m, i));
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
   * (tests/models.c, DESIGN §5): positions to the 17 digits written in the
   * file, velocities to rounding of the normalisations. */
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
        CHECK(!strcmp(mrvi_model_coordinate_name(sys->model, i), names[i]),
              "doc example order: %s", names[i]);
      CHECK(mrvi_model_n_fast(sys->model) == 2, "doc example n_f");
      CHECK(sys->output_every == 10 && !sys->output_micro,
            "doc example output");
      mrvi_system_free(sys);
    }
  }
  free(doc);
}

int main(void) {
  char **files = NULL;
  int n = list_bad_files(&files);
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
  test_doc_example();
  test_cli_bad_files(files, n);
  for (int i = 0; i < n; i++)
    free(files[i]);
  free(files);
  return test_finish();
}
