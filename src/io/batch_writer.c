/* The master file of `mrvi batch` (doc/batch.md): the case table and HDF5
 * external links to the case files, which are plain run files written by
 * mrvi_writer (each with its own crash safety).
 *
 * Crash safety of the table: every dataset of /cases has a fixed size (one
 * entry per case), contiguous layout and is written whole at creation, so
 * its storage is allocated then.  A finished case rewrites its entries in
 * place (raw data only: no object header, heap or B-tree changes) and
 * flushes the file, so a parent killed at any instant leaves a file whose
 * metadata is that of creation and whose rows are those written: readable,
 * each row either pending or complete (the status entry is written last).
 *
 * Layout: root attributes mrvi_version, batch_version, source, keys
 * ('\n'-separated), n_seeds, velocity_std, position_std, position_uniform,
 * temperature, rotation_std, rotation_uniform; /cases/ overrides (fixed strings
 * "KEY=VALUE" '\n'-separated), /cases/values/KEY (the value as a number, NAN
 * when it is not one), seed, status, steps, wall_time, energy_error,
 * stop_reason, file; /description (the text before overrides); /runs/case_CCCC
 * external links to "/" of each case file.  A batch of `optimize` cases
 * (root attribute command "optimize", control_std) also has /cases/cost,
 * violation, evaluations, nlopt_result and the scalar /best_case. */
#include "io/h5util.h"
#include "io/io.h"

#include <errno.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define OVERRIDES_BYTES 1024
#define FILE_BYTES 512
#define NLOPT_BYTES 48

struct mrvi_batch_file {
  char *path;
  hid_t file;
  int optimize; /* the table has the columns of optimize cases */
  mrvi_h5_quiet q;
};

void mrvi_batch_plan_free(mrvi_batch_plan *p) {
  if (!p)
    return;
  for (int j = 0; j < p->n_keys; j++)
    free(p->keys[j]);
  if (p->values)
    for (long i = 0; i < (long)p->n_cases * p->n_keys; i++)
      free(p->values[i]);
  free(p->keys);
  free(p->values);
  free(p->seed);
  free(p->description);
  free(p->source);
  memset(p, 0, sizeof *p);
}

int mrvi_batch_case_file(const char *master, int c, int relative, char *buf,
                         size_t len) {
  const char *base = master;
  if (relative) {
    const char *slash = strrchr(master, '/');
    if (slash)
      base = slash + 1;
  }
  size_t stem = strlen(base);
  if (stem > 3 && !strcmp(base + stem - 3, ".h5"))
    stem -= 3;
  int n = snprintf(buf, len, "%.*s.cases/case_%04d.h5", (int)stem, base, c);
  if (n < 0 || (size_t)n >= len) {
    mrvi_fmt(buf, len, "%s", "");
    return MRVI_EINVAL;
  }
  return 0;
}

/* Fixed-length string type of `size` bytes; close it. */
static hid_t fixed_string(size_t size) {
  hid_t t = H5Tcopy(H5T_C_S1);
  if (t >= 0 &&
      (H5Tset_size(t, size) < 0 || H5Tset_strpad(t, H5T_STR_NULLTERM) < 0 ||
       H5Tset_cset(t, H5T_CSET_UTF8) < 0)) {
    H5Tclose(t);
    return H5I_INVALID_HID;
  }
  return t;
}

/* "KEY=VALUE\n..." of case c into buf (size bytes, zero-padded); -1 when
 * it does not fit. */
static int case_overrides(const mrvi_batch_plan *p, int c, char *buf,
                          size_t size) {
  memset(buf, 0, size);
  size_t at = 0;
  for (int j = 0; j < p->n_keys && at < size; j++) {
    int n = snprintf(buf + at, size - at, "%s%s=%s", j ? "\n" : "", p->keys[j],
                     p->values[(long)c * p->n_keys + j]);
    if (n < 0)
      return -1;
    at += (size_t)n;
  }
  buf[size - 1] = '\0';
  return at < size ? 0 : -1;
}

/* The keys '\n'-joined (malloc'd). */
static char *join_keys(const mrvi_batch_plan *p) {
  size_t n = 1;
  for (int j = 0; j < p->n_keys; j++)
    n += strlen(p->keys[j]) + 1;
  char *s = calloc(n, 1);
  if (!s)
    return NULL;
  for (int j = 0; j < p->n_keys; j++) {
    if (j)
      strcat(s, "\n");
    strcat(s, p->keys[j]);
  }
  return s;
}

/* Fixed-string dataset `name` of g with count entries of size bytes. */
static void write_strings(mrvi_h5_batch *b, hid_t g, const char *name,
                          const char *data, hsize_t count, size_t size) {
  if (b->status)
    return;
  hid_t t = fixed_string(size);
  if (t < 0 || mrvi_h5_write_fixed(g, name, H5P_DEFAULT, t, t, count, 0, 0,
                                   data, NULL) < 0)
    mrvi_h5_batch_fail(b, name);
  if (t >= 0)
    H5Tclose(t);
}

static void write_longs(mrvi_h5_batch *b, hid_t g, const char *name,
                        const long *v, hsize_t count) {
  if (b->status == 0 &&
      mrvi_h5_write_fixed(g, name, H5P_DEFAULT, H5T_STD_I64LE, H5T_NATIVE_LONG,
                          count, 0, 0, v, NULL) < 0)
    mrvi_h5_batch_fail(b, name);
}

/* The file's content for plan: attributes, /cases and /runs. */
static void write_plan(mrvi_h5_batch *b, const char *path,
                       const mrvi_batch_plan *p) {
  const hsize_t n = (hsize_t)p->n_cases;
  hid_t root = b->file;
  mrvi_h5_batch_attr_string(b, root, "mrvi_version", MRVI_VERSION);
  mrvi_h5_batch_attr_int(b, root, "batch_version", 1);
  mrvi_h5_batch_attr_string(b, root, "source", p->source);
  if (b->status == 0 &&
      mrvi_h5_write_strings(root, "description", H5P_DEFAULT,
                            (const char *const *)&p->description, 0, 1,
                            "the description, before overrides") < 0)
    mrvi_h5_batch_fail(b, "description");
  char *keys = join_keys(p);
  if (!keys)
    mrvi_h5_batch_fail_text(b, MRVI_ENOMEM, "out of memory");
  mrvi_h5_batch_attr_string(b, root, "keys", keys);
  free(keys);
  mrvi_h5_batch_attr_int(b, root, "n_seeds", p->n_seeds);
  const mrvi_batch_perturb *pt = &p->pert;
  mrvi_h5_batch_attr_double(b, root, "velocity_std", pt->velocity_std);
  mrvi_h5_batch_attr_double(b, root, "position_std", pt->position_std);
  mrvi_h5_batch_attr_int(b, root, "position_uniform", pt->position_uniform);
  mrvi_h5_batch_attr_double(b, root, "temperature", pt->temperature);
  mrvi_h5_batch_attr_double(b, root, "rotation_std", pt->rotation_std);
  mrvi_h5_batch_attr_int(b, root, "rotation_uniform", pt->rotation_uniform);
  const int opt = p->command == MRVI_BATCH_OPTIMIZE;
  mrvi_h5_batch_attr_string(b, root, "command", opt ? "optimize" : "run");
  if (opt)
    mrvi_h5_batch_attr_double(b, root, "control_std", pt->control_std);

  char *over = calloc(n, OVERRIDES_BYTES);
  char *files = calloc(n, FILE_BYTES);
  double *num = malloc(n * sizeof *num);
  double *zero = calloc(n, sizeof *zero), *nan = malloc(n * sizeof *nan);
  char *nlopt = calloc(n, NLOPT_BYTES);
  int *status = calloc(n, sizeof *status);
  long *steps = calloc(n, sizeof *steps);
  char *reasons = calloc(n, MRVI_BATCH_REASON_BYTES);
  if (!over || !files || !num || !zero || !nan || !nlopt || !status || !steps ||
      !reasons)
    mrvi_h5_batch_fail_text(b, MRVI_ENOMEM, "out of memory");
  hid_t cases = mrvi_h5_batch_group(b, root, "cases");
  hid_t runs = mrvi_h5_batch_group(b, root, "runs");
  hid_t values =
      b->status ? H5I_INVALID_HID : mrvi_h5_batch_group(b, cases, "values");
  for (int c = 0; b->status == 0 && c < p->n_cases; c++) {
    if (case_overrides(p, c, over + (size_t)c * OVERRIDES_BYTES,
                       OVERRIDES_BYTES) < 0) {
      mrvi_h5_batch_fail_text(b, MRVI_EINVAL,
                              "a case's KEY=VALUE overrides exceed 1023 bytes");
      break;
    }
    char rel[FILE_BYTES], link[32];
    if (mrvi_batch_case_file(path, c, 1, rel, sizeof rel) < 0) {
      mrvi_h5_batch_fail_text(b, MRVI_EINVAL, "case file name too long");
      break;
    }
    memcpy(files + (size_t)c * FILE_BYTES, rel, strlen(rel));
    snprintf(link, sizeof link, "case_%04d", c);
    if (H5Lcreate_external(rel, "/", runs, link, H5P_DEFAULT, H5P_DEFAULT) < 0)
      mrvi_h5_batch_fail(b, "creating the external links");
  }
  for (int j = 0; b->status == 0 && j < p->n_keys; j++) {
    for (int c = 0; c < p->n_cases; c++) {
      const char *v = p->values[(long)c * p->n_keys + j];
      char *end;
      errno = 0;
      double x = strtod(v, &end);
      num[c] = *v && !*end && !errno ? x : NAN;
    }
    /* A key may name a dataset only without '/' ("a.b" is fine). */
    if (strchr(p->keys[j], '/'))
      continue;
    mrvi_h5_batch_doubles(b, values, p->keys[j], num, n, 0);
  }
  write_strings(b, cases, "overrides", over, n, OVERRIDES_BYTES);
  write_longs(b, cases, "seed", p->seed, n);
  write_longs(b, cases, "steps", steps, n);
  mrvi_h5_batch_doubles(b, cases, "wall_time", zero, n, 0);
  mrvi_h5_batch_doubles(b, cases, "energy_error", zero, n, 0);
  write_strings(b, cases, "stop_reason", reasons, n, MRVI_BATCH_REASON_BYTES);
  write_strings(b, cases, "file", files, n, FILE_BYTES);
  if (opt && nan) {
    for (hsize_t c = 0; c < n; c++)
      nan[c] = NAN;
    mrvi_h5_batch_doubles(b, cases, "cost", nan, n, 0);
    mrvi_h5_batch_doubles(b, cases, "violation", nan, n, 0);
    mrvi_h5_batch_ints(b, cases, "evaluations", status, n, 0);
    write_strings(b, cases, "nlopt_result", nlopt, n, NLOPT_BYTES);
    const long none = -1;
    if (b->status == 0 &&
        mrvi_h5_write_fixed(root, "best_case", H5P_DEFAULT, H5T_STD_I64LE,
                            H5T_NATIVE_LONG, 0, 0, 1, &none,
                            "the completed case of lowest cost (-1: none)") < 0)
      mrvi_h5_batch_fail(b, "best_case");
  }
  mrvi_h5_batch_ints(b, cases, "status", status, n, 0);
  if (values >= 0)
    H5Gclose(values);
  if (runs >= 0)
    H5Gclose(runs);
  if (cases >= 0)
    H5Gclose(cases);
  free(over);
  free(files);
  free(num);
  free(zero);
  free(nan);
  free(nlopt);
  free(status);
  free(steps);
  free(reasons);
}

static void file_free(mrvi_batch_file *f) {
  if (!f)
    return;
  if (f->file >= 0)
    H5Fclose(f->file);
  mrvi_h5_quiet_end(&f->q);
  free(f->path);
  free(f);
}

static mrvi_batch_file *file_new(const char *path) {
  mrvi_batch_file *f = calloc(1, sizeof *f);
  if (!f || !(f->path = strdup(path))) {
    free(f);
    return NULL;
  }
  f->file = H5I_INVALID_HID;
  mrvi_h5_quiet_begin(&f->q);
  return f;
}

int mrvi_batch_file_create(const char *path, const mrvi_batch_plan *plan,
                           mrvi_batch_file **out, char *msg, size_t len) {
  *out = NULL;
  mrvi_fmt(msg, len, "%s", "");
  if (plan->n_cases < 1) {
    mrvi_fmt(msg, len, "%s: a batch needs at least one case", path);
    return MRVI_EINVAL;
  }
  char dir[4096];
  if (mrvi_batch_case_file(path, 0, 0, dir, sizeof dir) < 0) {
    mrvi_fmt(msg, len, "%s: name too long", path);
    return MRVI_EINVAL;
  }
  *strrchr(dir, '/') = '\0';
  if (mkdir(dir, 0777) < 0 && errno != EEXIST) {
    mrvi_fmt(msg, len, "%s: cannot create the folder: %s", dir,
             strerror(errno));
    return MRVI_EIO;
  }
  mrvi_batch_file *f = file_new(path);
  if (!f) {
    mrvi_fmt(msg, len, "out of memory");
    return MRVI_ENOMEM;
  }
  mrvi_h5_batch b = {.path = path, .msg = msg, .len = len};
  b.file = H5Fcreate(path, H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  if (b.file < 0)
    mrvi_h5_batch_fail(&b, "cannot create the file");
  f->file = b.file;
  f->optimize = plan->command == MRVI_BATCH_OPTIMIZE;
  write_plan(&b, path, plan);
  if (b.status == 0 && H5Fflush(f->file, H5F_SCOPE_GLOBAL) < 0)
    mrvi_h5_batch_fail(&b, "flushing");
  if (b.status) { /* no half-written table stays behind */
    file_free(f);
    if (b.file >= 0)
      unlink(path);
    return b.status;
  }
  *out = f;
  return 0;
}

/* Longest case table read back (mrvi_batch_plan_build's limit too). */
#define MAX_CASES 1000000

/* The plan stored in a master file, read through the validated layer
 * (h5util.h: every shape and size checked before a read); 0, or a status
 * with "PATH: ..." in in->msg. */
static int read_plan(const mrvi_h5in *in, mrvi_batch_plan *p, int **status) {
  memset(p, 0, sizeof *p);
  *status = NULL;
  char **over = NULL, **text = NULL;
  hsize_t dims[1] = {0}, n = 0;
  double v;
  char *keys = malloc(MRVI_H5_MAX_ATTR + 1);
  p->source = malloc(MRVI_H5_MAX_ATTR + 1);
  int rc = keys && p->source ? 0 : MRVI_ENOMEM;
  if (rc == 0 &&
      (mrvi_h5in_attr_number(in, "batch_version", 1, 1, 1, &v) < 0 ||
       mrvi_h5in_attr_string(in, "source", p->source, MRVI_H5_MAX_ATTR + 1) <
           0 ||
       mrvi_h5in_attr_string(in, "keys", keys, MRVI_H5_MAX_ATTR + 1) < 0 ||
       mrvi_h5in_strings(in, "/description", 0, 0, MRVI_H5_MAX_TEXT, &text) <
           0))
    rc = MRVI_EIO;
  if (rc == 0 && mrvi_h5in_attr_number(in, "n_seeds", 0, MAX_CASES, 1, &v) < 0)
    rc = MRVI_EIO;
  p->n_seeds = (int)v;
  mrvi_batch_perturb *pt = &p->pert;
  if (rc == 0 && mrvi_h5in_attr_number(in, "velocity_std", 0, 1e300, 0,
                                       &pt->velocity_std) < 0)
    rc = MRVI_EIO;
  /* The other perturbations: absent in a file of an older writer. */
  const char *const names[] = {"position_std", "position_uniform",
                               "temperature", "rotation_std",
                               "rotation_uniform"};
  double *const into[] = {&pt->position_std, &v, &pt->temperature,
                          &pt->rotation_std, &v};
  const int flag[] = {0, 1, 0, 0, 1}; /* 0 or 1, else a number >= 0 */
  for (int i = 0; rc == 0 && i < 5; i++) {
    v = 0;
    if (mrvi_h5in_has_attr(in, names[i]) &&
        mrvi_h5in_attr_number(in, names[i], 0, flag[i] ? 1 : 1e300, flag[i],
                              into[i]) < 0)
      rc = MRVI_EIO;
    if (i == 1)
      pt->position_uniform = (int)v;
    if (i == 4)
      pt->rotation_uniform = (int)v;
  }
  /* command and control_std: absent in a run batch of an older writer. */
  char command[16] = "run";
  if (rc == 0 && mrvi_h5in_has_attr(in, "command") &&
      mrvi_h5in_attr_string(in, "command", command, sizeof command) < 0)
    rc = MRVI_EIO;
  p->command =
      !strcmp(command, "optimize") ? MRVI_BATCH_OPTIMIZE : MRVI_BATCH_RUN;
  if (rc == 0 && strcmp(command, "run") && strcmp(command, "optimize")) {
    mrvi_fmt(in->msg, in->len, "%s: command '%s' is neither run nor optimize",
             in->path, command);
    rc = MRVI_EIO;
  }
  if (rc == 0 && p->command == MRVI_BATCH_OPTIMIZE &&
      mrvi_h5in_attr_number(in, "control_std", 0, 1e300, 0, &pt->control_std) <
          0)
    rc = MRVI_EIO;
  if (rc == 0 &&
      mrvi_h5in_read_new(in, "/cases/status", H5T_NATIVE_INT, 1, NULL,
                         MRVI_H5_ANY, (void **)status, dims) < 0)
    rc = MRVI_EIO;
  n = dims[0];
  if (rc == 0 && (n < 1 || n > MAX_CASES)) {
    mrvi_fmt(in->msg, in->len, "%s: /cases/status: %llu cases (1..%d)",
             in->path, (unsigned long long)n, MAX_CASES);
    rc = MRVI_EIO;
  }
  const hsize_t want[1] = {n};
  if (rc == 0 &&
      (mrvi_h5in_read_new(in, "/cases/seed", H5T_NATIVE_LONG, 1, want,
                          MRVI_H5_ANY, (void **)&p->seed, NULL) < 0 ||
       mrvi_h5in_strings(in, "/cases/overrides", 1, n, OVERRIDES_BYTES, &over) <
           0))
    rc = MRVI_EIO;
  if (rc == 0) {
    p->n_cases = (int)n;
    p->description = strdup(text[0]);
    p->n_keys = 0;
    if (keys[0]) {
      p->n_keys = 1;
      for (const char *k = keys; *k; k++)
        p->n_keys += *k == '\n';
    }
    p->keys = calloc((size_t)p->n_keys + 1, sizeof *p->keys);
    p->values = calloc(n * (size_t)p->n_keys + 1, sizeof *p->values);
    if (!p->description || !p->keys || !p->values)
      rc = MRVI_ENOMEM;
  }
  char *save = NULL;
  char *k = rc == 0 ? strtok_r(keys, "\n", &save) : NULL;
  for (int j = 0; rc == 0 && j < p->n_keys;
       j++, k = strtok_r(NULL, "\n", &save))
    if (!k || !(p->keys[j] = strdup(k)))
      rc = k ? MRVI_ENOMEM : MRVI_EIO;
  for (hsize_t c = 0; rc == 0 && c < n; c++) {
    /* Row c: "KEY=VALUE" lines in the order of the keys. */
    char *line = strtok_r(over[c], "\n", &save);
    for (int j = 0; rc == 0 && j < p->n_keys;
         j++, line = strtok_r(NULL, "\n", &save)) {
      size_t kl = strlen(p->keys[j]);
      if (!line || strncmp(line, p->keys[j], kl) || line[kl] != '=') {
        mrvi_fmt(in->msg, in->len,
                 "%s: /cases/overrides: case %d does not match the keys",
                 in->path, (int)c);
        rc = MRVI_EIO;
      } else if (!(p->values[c * (size_t)p->n_keys + (size_t)j] =
                       strdup(line + kl + 1))) {
        rc = MRVI_ENOMEM;
      }
    }
  }
  if (rc == MRVI_ENOMEM)
    mrvi_fmt(in->msg, in->len, "%s: out of memory", in->path);
  mrvi_h5_strings_free(text, 1);
  mrvi_h5_strings_free(over, n);
  free(keys);
  if (rc) {
    mrvi_batch_plan_free(p);
    free(*status);
    *status = NULL;
  }
  return rc;
}

int mrvi_batch_file_open(const char *path, mrvi_batch_plan *plan, int **status,
                         mrvi_batch_file **out, char *msg, size_t len) {
  *out = NULL;
  if (status)
    *status = NULL;
  if (plan)
    memset(plan, 0, sizeof *plan);
  mrvi_batch_file *f = file_new(path);
  if (!f) {
    mrvi_fmt(msg, len, "out of memory");
    return MRVI_ENOMEM;
  }
  /* Without HDF5's file lock: a reader of the table (h5py, h5dump, holding
   * its shared lock) must not make a row unwritable, nor the batch stop.
   * Rows change raw data in place only (see the top), so a reader sees
   * each entry old or new. */
  hid_t fapl = H5Pcreate(H5P_FILE_ACCESS);
  if (fapl >= 0)
    H5Pset_file_locking(fapl, 0, 1);
  f->file = H5Fopen(path, H5F_ACC_RDWR, fapl >= 0 ? fapl : H5P_DEFAULT);
  if (fapl >= 0)
    H5Pclose(fapl);
  if (f->file < 0) {
    mrvi_h5_error_message(msg, len, path, "cannot open");
    file_free(f);
    return MRVI_EIO;
  }
  mrvi_h5in in = {.file = f->file, .path = path, .msg = msg, .len = len};
  int rc = plan ? read_plan(&in, plan, status) : 0;
  f->optimize = mrvi_h5in_exists(&in, "/best_case");
  if (rc) {
    file_free(f);
    return rc;
  }
  *out = f;
  return 0;
}

/* Entry c of dataset name of g from memory (mtype, one element). */
static herr_t write_entry(hid_t g, const char *name, hid_t mtype, int c,
                          const void *v) {
  hid_t d = H5Dopen2(g, name, H5P_DEFAULT);
  if (d < 0)
    return -1;
  hid_t fs = H5Dget_space(d);
  hsize_t start[1] = {(hsize_t)c}, one[1] = {1};
  hid_t ms = H5Screate_simple(1, one, NULL);
  herr_t rc = fs >= 0 && ms >= 0 &&
                      H5Sselect_hyperslab(fs, H5S_SELECT_SET, start, NULL, one,
                                          NULL) >= 0
                  ? H5Dwrite(d, mtype, ms, fs, H5P_DEFAULT, v)
                  : -1;
  if (ms >= 0)
    H5Sclose(ms);
  if (fs >= 0)
    H5Sclose(fs);
  H5Dclose(d);
  return rc;
}

/* The entries of an optimize case's row. */
static herr_t optimize_entries(hid_t cases, const mrvi_batch_result *res) {
  char nlopt[NLOPT_BYTES] = {0};
  snprintf(nlopt, sizeof nlopt, "%s", res->nlopt);
  hid_t t = fixed_string(NLOPT_BYTES);
  herr_t rc = t >= 0 ? 0 : -1;
  if (rc >= 0)
    rc = write_entry(cases, "cost", H5T_NATIVE_DOUBLE, res->c, &res->cost);
  if (rc >= 0)
    rc = write_entry(cases, "violation", H5T_NATIVE_DOUBLE, res->c,
                     &res->violation);
  if (rc >= 0)
    rc = write_entry(cases, "evaluations", H5T_NATIVE_INT, res->c,
                     &res->evaluations);
  if (rc >= 0)
    rc = write_entry(cases, "nlopt_result", t, res->c, nlopt);
  if (t >= 0)
    H5Tclose(t);
  return rc;
}

int mrvi_batch_file_row(mrvi_batch_file *f, const mrvi_batch_result *res,
                        char *msg, size_t len) {
  hid_t cases = H5Gopen2(f->file, "cases", H5P_DEFAULT);
  hid_t t = fixed_string(MRVI_BATCH_REASON_BYTES);
  char reason[MRVI_BATCH_REASON_BYTES] = {0};
  snprintf(reason, sizeof reason, "%s", res->reason);
  /* The status last: a row is complete once it says so. */
  herr_t rc = cases >= 0 && t >= 0 ? 0 : -1;
  if (rc >= 0)
    rc = write_entry(cases, "steps", H5T_NATIVE_LONG, res->c, &res->steps);
  if (rc >= 0)
    rc = write_entry(cases, "wall_time", H5T_NATIVE_DOUBLE, res->c,
                     &res->wall_time);
  if (rc >= 0)
    rc = write_entry(cases, "energy_error", H5T_NATIVE_DOUBLE, res->c,
                     &res->energy_error);
  if (rc >= 0)
    rc = write_entry(cases, "stop_reason", t, res->c, reason);
  if (rc >= 0 && f->optimize)
    rc = optimize_entries(cases, res);
  if (rc >= 0)
    rc = H5Fflush(f->file, H5F_SCOPE_GLOBAL);
  if (rc >= 0)
    rc = write_entry(cases, "status", H5T_NATIVE_INT, res->c, &res->status);
  if (rc >= 0)
    rc = H5Fflush(f->file, H5F_SCOPE_GLOBAL);
  if (rc < 0)
    mrvi_h5_error_message(msg, len, f->path, "writing the case table");
  if (t >= 0)
    H5Tclose(t);
  if (cases >= 0)
    H5Gclose(cases);
  return rc < 0 ? MRVI_EIO : 0;
}

int mrvi_batch_file_close(mrvi_batch_file *f, char *msg, size_t len) {
  if (!f)
    return 0;
  int rc = 0;
  if (H5Fclose(f->file) < 0) {
    mrvi_h5_error_message(msg, len, f->path, "closing");
    rc = MRVI_EIO;
  }
  f->file = H5I_INVALID_HID;
  file_free(f);
  return rc;
}

int mrvi_batch_file_best(mrvi_batch_file *f, int *best, double *cost, char *msg,
                         size_t len) {
  *best = -1;
  *cost = NAN;
  if (!f->optimize)
    return 0;
  mrvi_h5in in = {.file = f->file, .path = f->path, .msg = msg, .len = len};
  int *status = NULL;
  double *J = NULL;
  hsize_t dims[1] = {0};
  int rc = mrvi_h5in_read_new(&in, "/cases/status", H5T_NATIVE_INT, 1, NULL,
                              MRVI_H5_ANY, (void **)&status, dims);
  if (rc == 0)
    rc = mrvi_h5in_read_new(&in, "/cases/cost", H5T_NATIVE_DOUBLE, 1, dims,
                            MRVI_H5_ANY, (void **)&J, NULL);
  /* The lowest cost of the completed (converged) cases; ties: the first. */
  for (hsize_t c = 0; rc == 0 && c < dims[0]; c++)
    if (status[c] == MRVI_BATCH_COMPLETED && isfinite(J[c]) &&
        (*best < 0 || J[c] < *cost)) {
      *best = (int)c;
      *cost = J[c];
    }
  free(status);
  free(J);
  if (rc < 0)
    return MRVI_EIO;
  /* In place, raw data only, as a row. */
  const long b = *best;
  hid_t d = H5Dopen2(f->file, "best_case", H5P_DEFAULT);
  herr_t w =
      d >= 0 ? H5Dwrite(d, H5T_NATIVE_LONG, H5S_ALL, H5S_ALL, H5P_DEFAULT, &b)
             : -1;
  if (d >= 0)
    H5Dclose(d);
  if (w >= 0)
    w = H5Fflush(f->file, H5F_SCOPE_GLOBAL);
  if (w < 0) {
    mrvi_h5_error_message(msg, len, f->path, "writing /best_case");
    return MRVI_EIO;
  }
  return 0;
}
