/* Pictures of the motion from a run file (doc/output.md, "Viewing the
 * motion"): an XDMF description of the particles over time that points into
 * the HDF5 datasets (ParaView, VisIt), and extended XYZ frames (OVITO, VMD,
 * ASE).
 *
 * Both read only what the file holds, so they describe exactly the steps a
 * run stored, also when it stopped early or was killed. */
#define _DEFAULT_SOURCE /* realpath */
#include "io/h5util.h"
#include "io/io.h"

#include <hdf5.h>

#include <errno.h>
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ---------------------------------------------------------------------------
 * Reading the run file
 * ------------------------------------------------------------------------- */

/* What both exports need to know about the particles of a run file. */
typedef struct run_file {
  const char *path;
  hid_t file;
  int d;        /* /model/dimension */
  int n, np;    /* coordinates, particles */
  hsize_t rows; /* macro nodes stored: rows of /macro/t and /macro/q */
  int *column;  /* np: /model/particle_column */
  int *rate;    /* n: /model/rate */
  char **name;  /* np: /model/particle_name */
  double *t;    /* rows: /macro/t */
  int first;    /* column of particle 0 if the particles fill consecutive
                   columns (c, c + d, ...), else -1 */
  int n_edges;  /* rows of /model/edges */
} run_file;

/* Shape of dataset `name` (dims[1] = 1 for rank 1); its rank, or -1. */
static int shape(hid_t file, const char *name, hsize_t dims[2]) {
  dims[0] = dims[1] = 1;
  if (H5Lexists(file, name, H5P_DEFAULT) <= 0)
    return -1;
  hid_t ds = H5Dopen2(file, name, H5P_DEFAULT);
  if (ds < 0)
    return -1;
  hid_t sp = H5Dget_space(ds);
  int rank = sp >= 0 ? H5Sget_simple_extent_ndims(sp) : -1;
  if (rank < 1 || rank > 2 || H5Sget_simple_extent_dims(sp, dims, NULL) < 0)
    rank = -1;
  if (sp >= 0)
    H5Sclose(sp);
  H5Dclose(ds);
  return rank;
}

/* Read `count` elements of dataset name as mtype into a new array, or rows
 * [row, row + 1) of a rank-2 dataset when row >= 0 (into buf, count = its
 * columns).  0 or -1. */
static int read_data(hid_t file, const char *name, hid_t mtype, hssize_t row,
                     void *buf) {
  hid_t ds = H5Dopen2(file, name, H5P_DEFAULT);
  if (ds < 0)
    return -1;
  herr_t rc;
  if (row < 0) {
    rc = H5Dread(ds, mtype, H5S_ALL, H5S_ALL, H5P_DEFAULT, buf);
  } else {
    hid_t fs = H5Dget_space(ds);
    hsize_t dims[2] = {0, 0};
    H5Sget_simple_extent_dims(fs, dims, NULL);
    hsize_t start[2] = {(hsize_t)row, 0}, count[2] = {1, dims[1]};
    hid_t ms = H5Screate_simple(1, &count[1], NULL);
    rc = H5Sselect_hyperslab(fs, H5S_SELECT_SET, start, NULL, count, NULL);
    if (rc >= 0)
      rc = H5Dread(ds, mtype, ms, fs, H5P_DEFAULT, buf);
    H5Sclose(ms);
    H5Sclose(fs);
  }
  H5Dclose(ds);
  return rc < 0 ? -1 : 0;
}

/* A whole dataset of `count` elements of size `size` as mtype, or NULL. */
static void *read_all(hid_t file, const char *name, hid_t mtype, size_t count,
                      size_t size) {
  void *buf = malloc((count ? count : 1) * size);
  if (buf && read_data(file, name, mtype, -1, buf) < 0) {
    free(buf);
    buf = NULL;
  }
  return buf;
}

/* Variable-length string dataset of count entries as malloc'ed copies. */
static char **read_strings(hid_t file, const char *name, size_t count) {
  char **raw = calloc(count ? count : 1, sizeof *raw);
  char **out = calloc(count ? count : 1, sizeof *out);
  hid_t st = H5Tcopy(H5T_C_S1);
  int ok = raw && out && st >= 0 && H5Tset_size(st, H5T_VARIABLE) >= 0 &&
           H5Tset_cset(st, H5T_CSET_UTF8) >= 0 &&
           read_data(file, name, st, -1, raw) == 0;
  for (size_t i = 0; ok && i < count; i++)
    ok = (out[i] = strdup(raw[i] ? raw[i] : "")) != NULL;
  if (raw) {
    for (size_t i = 0; i < count; i++)
      H5free_memory(raw[i]);
    free(raw);
  }
  if (st >= 0)
    H5Tclose(st);
  if (!ok && out) {
    for (size_t i = 0; i < count; i++)
      free(out[i]);
    free(out);
    out = NULL;
  }
  return out;
}

static void run_close(run_file *r) {
  if (r->file >= 0)
    H5Fclose(r->file);
  r->file = H5I_INVALID_HID;
  if (r->name)
    for (int i = 0; i < r->np; i++)
      free(r->name[i]);
  free(r->name);
  free(r->column);
  free(r->rate);
  free(r->t);
}

/* Open a run file and read its particles; a message naming what is wrong
 * otherwise (no particles: MRVI_EINVAL). */
static int run_open(run_file *r, const char *path, char *msg, size_t len) {
  memset(r, 0, sizeof *r);
  r->path = path;
  r->first = -1;
  r->file = mrvi_h5_open_read(path, H5P_DEFAULT);
  if (r->file < 0)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: cannot open as an HDF5 file (missing, not HDF5, or "
                     "still being written by a run)",
                     path);
  hsize_t dq[2], dt[2], dr[2], dc[2], de[2];
  if (shape(r->file, "/macro/q", dq) != 2 ||
      shape(r->file, "/macro/t", dt) != 1 ||
      shape(r->file, "/model/rate", dr) != 1 || dr[0] != dq[1])
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: not an mrvi run file (/macro/q, /macro/t or "
                     "/model/rate missing or inconsistent)",
                     path);
  if (shape(r->file, "/model/particle_column", dc) != 1)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: the model has no particles (generalised coordinates "
                     "only, or a file written before mrvi stored "
                     "/model/particle_column): nothing to show as points",
                     path);
  int d = 0;
  if (H5Lexists(r->file, "/model/dimension", H5P_DEFAULT) <= 0 ||
      read_data(r->file, "/model/dimension", H5T_NATIVE_INT, -1, &d) < 0)
    d = 0;
  r->d = d;
  r->n = (int)dq[1];
  r->np = (int)dc[0];
  r->rows = dt[0] < dq[0] ? dt[0] : dq[0];
  r->n_edges =
      shape(r->file, "/model/edges", de) == 2 && de[1] == 2 ? (int)de[0] : 0;
  if (d < 1 || d > 3 || (size_t)r->np * (size_t)d > (size_t)r->n)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: /model/dimension = %d does not fit %d particles "
                     "in %d coordinates",
                     path, d, r->np, r->n);
  r->column = read_all(r->file, "/model/particle_column", H5T_NATIVE_INT,
                       (size_t)r->np, sizeof *r->column);
  r->rate = read_all(r->file, "/model/rate", H5T_NATIVE_INT, (size_t)r->n,
                     sizeof *r->rate);
  r->name = read_strings(r->file, "/model/particle_name", (size_t)r->np);
  r->t = read_all(r->file, "/macro/t", H5T_NATIVE_DOUBLE, (size_t)dt[0],
                  sizeof *r->t);
  if (!r->column || !r->rate || !r->name || !r->t)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: cannot read /model/particle_column, "
                     "/model/particle_name, /model/rate or /macro/t",
                     path);
  int consecutive = 1;
  for (int i = 0; i < r->np; i++) {
    if (r->column[i] < 0 || r->column[i] + d > r->n)
      return mrvi_fail(msg, len, MRVI_EIO,
                       "%s: /model/particle_column[%d] = %d out of range", path,
                       i, r->column[i]);
    consecutive &= r->column[i] == r->column[0] + d * i;
  }
  r->first = consecutive ? r->column[0] : -1;
  return MRVI_OK;
}

/* Quiet HDF5 around an export: messages instead of printing. */
typedef struct quiet {
  H5E_auto2_t func;
  void *data;
} quiet;

static void quiet_begin(quiet *q) {
  H5Eget_auto2(H5E_DEFAULT, &q->func, &q->data);
  H5Eset_auto2(H5E_DEFAULT, NULL, NULL);
}

static void quiet_end(const quiet *q) {
  H5Eclear2(H5E_DEFAULT);
  H5Eset_auto2(H5E_DEFAULT, q->func, q->data);
}

/* ---------------------------------------------------------------------------
 * XDMF
 * ------------------------------------------------------------------------- */

/* Directory part of path ("." for none) into buf. */
static void dir_of(const char *path, char *buf, size_t len) {
  const char *slash = strrchr(path, '/');
  if (!slash)
    mrvi_fmt(buf, len, ".");
  else if (slash == path)
    mrvi_fmt(buf, len, "/");
  else
    mrvi_fmt(buf, len, "%.*s", (int)(slash - path), path);
}

/* How the XDMF file names the HDF5 file: its base name when both are in one
 * directory (the files move together), else its absolute path. */
static int h5_reference(const char *h5_path, const char *xdmf_path, char *buf,
                        size_t len) {
  char d1[PATH_MAX], d2[PATH_MAX], r1[PATH_MAX], r2[PATH_MAX];
  dir_of(h5_path, d1, sizeof d1);
  dir_of(xdmf_path, d2, sizeof d2);
  if (!realpath(d1, r1) || !realpath(d2, r2))
    return -1;
  const char *slash = strrchr(h5_path, '/');
  const char *base = slash ? slash + 1 : h5_path;
  if (!strcmp(r1, r2))
    mrvi_fmt(buf, len, "%s", base);
  else
    mrvi_fmt(buf, len, "%s/%s", r1, base);
  return 0;
}

/* x with the fewest significant digits (up to 17) that read back as x. */
static void put_double(FILE *f, double x) {
  char buf[40];
  for (int digits = 15; digits <= 17; digits++) {
    snprintf(buf, sizeof buf, "%.*g", digits, x);
    if (strtod(buf, NULL) == x)
      break;
  }
  fputs(buf, f);
}

/* s with the five XML special characters escaped. */
static void xml_escape(FILE *f, const char *s) {
  for (; *s; s++)
    switch (*s) {
    case '&':
      fputs("&amp;", f);
      break;
    case '<':
      fputs("&lt;", f);
      break;
    case '>':
      fputs("&gt;", f);
      break;
    case '"':
      fputs("&quot;", f);
      break;
    case '\'':
      fputs("&apos;", f);
      break;
    default:
      fputc(*s, f);
    }
}

/* A DataItem naming dataset `name` of the HDF5 file (dims: its shape). */
static void hdf_item(FILE *f, const char *h5, const char *name, int rank,
                     const hsize_t *dims, int is_float, const char *indent) {
  fprintf(f, "%s<DataItem Dimensions=\"%llu", indent,
          (unsigned long long)dims[0]);
  if (rank == 2)
    fprintf(f, " %llu", (unsigned long long)dims[1]);
  fprintf(f, "\" NumberType=\"%s\" Precision=\"%d\" Format=\"HDF\">",
          is_float ? "Float" : "Int", is_float ? 8 : 4);
  xml_escape(f, h5);
  fprintf(f, ":%s</DataItem>\n", name);
}

/* Geometry of macro node `row`: the particle columns of row `row` of
 * /macro/q, as XY (2-D) or XYZ (3-D) points; 1-D: X with Y = Z = 0. */
static void geometry(FILE *f, const run_file *r, const char *h5, hsize_t row) {
  const int d = r->d, np = r->np;
  const hsize_t dims[2] = {r->rows, (hsize_t)r->n};
  const char *type = d == 3 ? "XYZ" : d == 2 ? "XY" : "X_Y_Z";
  fprintf(f, "        <Geometry GeometryType=\"%s\">\n", type);
  /* The comment gives the geometry a text of its own per node: ParaView's
   * XDMF reader caches a grid's points under that text. */
  fprintf(f,
          "          <DataItem ItemType=\"HyperSlab\" Dimensions=\"1 %d\">"
          "<!-- macro node %llu -->\n",
          d * np, (unsigned long long)row);
  fprintf(f,
          "            <DataItem Dimensions=\"3 2\" Format=\"XML\">%llu %d 1 1 "
          "1 %d</DataItem>\n",
          (unsigned long long)row, r->first, d * np);
  hdf_item(f, h5, "/macro/q", 2, dims, 1, "            ");
  fputs("          </DataItem>\n", f);
  for (int zero = 0; d == 1 && zero < 2; zero++) {
    fprintf(f,
            "          <DataItem Dimensions=\"%d\" NumberType=\"Float\" "
            "Precision=\"8\" Format=\"XML\">",
            np);
    for (int i = 0; i < np; i++)
      fputs(i ? " 0" : "0", f);
    fputs("</DataItem>\n", f);
  }
  fputs("        </Geometry>\n", f);
}

/* The rate of each particle: every d-th entry of /model/rate from the
 * first particle column. */
static void rate_attribute(FILE *f, const run_file *r, const char *h5) {
  const hsize_t dims[2] = {(hsize_t)r->n, 1};
  fputs("        <Attribute Name=\"rate\" AttributeType=\"Scalar\" "
        "Center=\"Node\">\n",
        f);
  fprintf(f, "          <DataItem ItemType=\"HyperSlab\" Dimensions=\"%d\">\n",
          r->np);
  fprintf(f,
          "            <DataItem Dimensions=\"3 1\" Format=\"XML\">%d %d "
          "%d</DataItem>\n",
          r->first, r->d, r->np);
  hdf_item(f, h5, "/model/rate", 1, dims, 0, "            ");
  fputs("          </DataItem>\n        </Attribute>\n", f);
}

/* One temporal collection: a uniform grid per stored macro node.  bonds:
 * the edges as lines (Polyline, /model/edges) with the cell attribute
 * edge_rate; else the particles as points (Polyvertex) with the node
 * attribute rate. */
static void collection(FILE *f, const run_file *r, const char *h5, int bonds) {
  const char *what = bonds ? "bonds" : "particles";
  fprintf(f,
          "    <Grid Name=\"%s\" GridType=\"Collection\" "
          "CollectionType=\"Temporal\">\n",
          what);
  const hsize_t edims[2] = {(hsize_t)r->n_edges, 2};
  for (hsize_t k = 0; k < r->rows; k++) {
    fprintf(f, "      <Grid Name=\"%s %llu\" GridType=\"Uniform\">\n", what,
            (unsigned long long)k);
    fputs("        <Time Value=\"", f);
    put_double(f, r->t[k]);
    fputs("\"/>\n", f);
    if (bonds) {
      fprintf(f,
              "        <Topology TopologyType=\"Polyline\" "
              "NumberOfElements=\"%d\" NodesPerElement=\"2\">\n",
              r->n_edges);
      hdf_item(f, h5, "/model/edges", 2, edims, 0, "          ");
      fputs("        </Topology>\n", f);
    } else {
      fprintf(f,
              "        <Topology TopologyType=\"Polyvertex\" "
              "NumberOfElements=\"%d\" NodesPerElement=\"1\"/>\n",
              r->np);
    }
    geometry(f, r, h5, k);
    if (bonds) {
      fputs("        <Attribute Name=\"edge_rate\" AttributeType=\"Scalar\" "
            "Center=\"Cell\">\n",
            f);
      hdf_item(f, h5, "/model/edge_rate", 1, edims, 0, "          ");
      fputs("        </Attribute>\n", f);
    } else {
      rate_attribute(f, r, h5);
    }
    fputs("      </Grid>\n", f);
  }
  fputs("    </Grid>\n", f);
}

int mrvi_export_xdmf(const char *h5_path, const char *xdmf_path, char *msg,
                     size_t len) {
  mrvi_fmt(msg, len, "%s", "");
  if (!h5_path || !xdmf_path)
    return mrvi_fail(msg, len, MRVI_EINVAL, "mrvi_export_xdmf: no file name");
  quiet q;
  quiet_begin(&q);
  run_file r;
  int st = run_open(&r, h5_path, msg, len);
  char h5[PATH_MAX + 8];
  if (st == 0 && r.first < 0)
    st = mrvi_fail(msg, len, MRVI_EINVAL,
                   "%s: the particles do not occupy consecutive columns of "
                   "/macro/q (a generalised coordinate was declared between "
                   "them): no XDMF",
                   h5_path);
  if (st == 0 && h5_reference(h5_path, xdmf_path, h5, sizeof h5) < 0)
    st = mrvi_fail(msg, len, MRVI_EIO, "%s: %s", xdmf_path, strerror(errno));
  FILE *f = st == 0 ? fopen(xdmf_path, "w") : NULL;
  if (st == 0 && !f)
    st = mrvi_fail(msg, len, MRVI_EIO, "%s: cannot write: %s", xdmf_path,
                   strerror(errno));
  if (f) {
    fputs("<?xml version=\"1.0\" ?>\n", f);
    fprintf(f, "<!-- mrvi %s: the particles of ", MRVI_VERSION);
    xml_escape(f, h5);
    fprintf(f,
            " over the %llu stored macro nodes (doc/output.md).  Open in "
            "ParaView (XDMF reader) or VisIt. -->\n",
            (unsigned long long)r.rows);
    fputs("<Xdmf Version=\"2.0\">\n  <Domain>\n", f);
    collection(f, &r, h5, 0);
    if (r.n_edges > 0)
      collection(f, &r, h5, 1);
    fputs("  </Domain>\n</Xdmf>\n", f);
    if (ferror(f) | fclose(f))
      st = mrvi_fail(msg, len, MRVI_EIO, "%s: write error: %s", xdmf_path,
                     strerror(errno));
  }
  run_close(&r);
  quiet_end(&q);
  return st;
}

/* ---------------------------------------------------------------------------
 * Extended XYZ
 * ------------------------------------------------------------------------- */

/* Micro grid sources: for each particle coordinate its dataset (0 fast,
 * 1 slow) and column there. */
typedef struct micro_map {
  int *src, *col;
  int n_fast, n_slow;
  int have_slow; /* /micro/q_slow exists */
  hsize_t rows;
} micro_map;

static int micro_setup(const run_file *r, micro_map *mm, char *msg,
                       size_t len) {
  hsize_t df[2], ds[2], dt[2];
  memset(mm, 0, sizeof *mm);
  if (shape(r->file, "/micro/t", dt) != 1 ||
      shape(r->file, "/micro/q_fast", df) != 2)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: no micro nodes (/micro; a model without fast "
                     "coordinates or output.micro: false)",
                     r->path);
  const int have_slow = shape(r->file, "/micro/q_slow", ds) == 2;
  mm->have_slow = have_slow;
  mm->rows = dt[0] < df[0] ? dt[0] : df[0];
  if (have_slow && ds[0] < mm->rows)
    mm->rows = ds[0];
  mm->src = malloc((size_t)r->n * sizeof *mm->src);
  mm->col = malloc((size_t)r->n * sizeof *mm->col);
  if (!mm->src || !mm->col)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  for (int c = 0; c < r->n; c++) {
    mm->src[c] = r->rate[c] == 1 ? 0 : 1;
    mm->col[c] = r->rate[c] == 1 ? mm->n_fast++ : mm->n_slow++;
  }
  int slow_particles = 0;
  for (int i = 0; i < r->np; i++)
    slow_particles |= r->rate[r->column[i]] != 1;
  if (slow_particles && !have_slow)
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: slow particles have no positions at the micro nodes "
                     "(/micro/q_slow): run with output.micro_slow: true",
                     r->path);
  return MRVI_OK;
}

/* A particle name as one column: blanks become '_', "" becomes "_". */
static void put_name(FILE *f, const char *name) {
  if (!*name)
    fputc('_', f);
  for (const char *c = name; *c; c++)
    fputc(*c == ' ' || *c == '\t' ? '_' : *c, f);
}

int mrvi_export_xyz(const char *h5_path, const char *xyz_path,
                    const mrvi_xyz_options *opt, char *msg, size_t len) {
  mrvi_fmt(msg, len, "%s", "");
  mrvi_xyz_options o = {1, 0, 0};
  if (opt)
    o = *opt;
  if (!h5_path || !xyz_path)
    return mrvi_fail(msg, len, MRVI_EINVAL, "mrvi_export_xyz: no file name");
  if (o.every < 1)
    return mrvi_fail(msg, len, MRVI_EINVAL, "every %d: must be >= 1", o.every);
  quiet q;
  quiet_begin(&q);
  run_file r;
  micro_map mm = {0};
  double *row = NULL, *fast = NULL, *slow = NULL, *mt = NULL;
  FILE *f = NULL;
  int st = run_open(&r, h5_path, msg, len);
  if (st == 0 && o.micro)
    st = micro_setup(&r, &mm, msg, len);
  const hsize_t frames = o.micro ? mm.rows : r.rows;
  if (st == 0) {
    row = malloc((size_t)r.n * sizeof *row);
    fast = malloc((size_t)(mm.n_fast + 1) * sizeof *fast);
    slow = malloc((size_t)(mm.n_slow + 1) * sizeof *slow);
    mt = o.micro ? read_all(r.file, "/micro/t", H5T_NATIVE_DOUBLE,
                            (size_t)frames, sizeof *mt)
                 : NULL;
    if (!row || !fast || !slow || (o.micro && !mt))
      st =
          mrvi_fail(msg, len, MRVI_ENOMEM, "%s: cannot read /micro/t", h5_path);
  }
  if (st == 0 && !(f = fopen(xyz_path, "w")))
    st = mrvi_fail(msg, len, MRVI_EIO, "%s: cannot write: %s", xyz_path,
                   strerror(errno));
  for (hsize_t k = 0; st == 0 && k < frames; k += (hsize_t)o.every) {
    /* Coordinates of frame k in model order. */
    if (o.micro) {
      if (read_data(r.file, "/micro/q_fast", H5T_NATIVE_DOUBLE, (hssize_t)k,
                    fast) < 0 ||
          (mm.have_slow && read_data(r.file, "/micro/q_slow", H5T_NATIVE_DOUBLE,
                                     (hssize_t)k, slow) < 0)) {
        st = mrvi_fail(msg, len, MRVI_EIO, "%s: cannot read micro row %llu",
                       h5_path, (unsigned long long)k);
        break;
      }
      for (int c = 0; c < r.n; c++)
        row[c] = mm.src[c] == 0 ? fast[mm.col[c]] : slow[mm.col[c]];
    } else if (read_data(r.file, "/macro/q", H5T_NATIVE_DOUBLE, (hssize_t)k,
                         row) < 0) {
      st = mrvi_fail(msg, len, MRVI_EIO, "%s: cannot read /macro/q row %llu",
                     h5_path, (unsigned long long)k);
      break;
    }
    fprintf(f, "%d\nProperties=species:S:1:pos:R:3:rate:I:1:name:S:1 Time=",
            r.np);
    put_double(f, o.micro ? mt[k] : r.t[k]);
    fputs(" pbc=\"F F F\"\n", f);
    for (int i = 0; i < r.np; i++) {
      const double *x = row + r.column[i];
      const int fast_particle = r.rate[r.column[i]] == 1;
      if (o.species == MRVI_XYZ_SPECIES_NAME)
        put_name(f, r.name[i]);
      else if (o.species == MRVI_XYZ_SPECIES_RATE)
        fputs(fast_particle ? "fast" : "slow", f);
      else
        fputc('X', f); /* a chemical symbol: ASE's dummy element */
      for (int a = 0; a < 3; a++) {
        fputc(' ', f);
        put_double(f, a < r.d ? x[a] : 0.0);
      }
      fprintf(f, " %d ", fast_particle);
      put_name(f, r.name[i]);
      fputc('\n', f);
    }
  }
  if (f && (ferror(f) | fclose(f)) && st == 0)
    st = mrvi_fail(msg, len, MRVI_EIO, "%s: write error: %s", xyz_path,
                   strerror(errno));
  free(row);
  free(fast);
  free(slow);
  free(mt);
  free(mm.src);
  free(mm.col);
  run_close(&r);
  quiet_end(&q);
  return st;
}
