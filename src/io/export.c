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
#include <math.h>
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
  /* Rigid bodies and joints (NULL / 0 without; read_bodies). */
  int nb, nj;
  double *body_pos;       /* rows x nb x d: /bodies/position */
  double *body_rot;       /* rows x nb x d x d: /bodies/rotation */
  double *joint_pos;      /* rows x nj x d: /joints/position */
  int *joint_a, *joint_b; /* nj: /joints/body_a, /joints/body_b */
} run_file;

static void run_close(run_file *r) {
  if (r->file >= 0)
    H5Fclose(r->file);
  r->file = H5I_INVALID_HID;
  mrvi_h5_strings_free(r->name, (size_t)r->np);
  r->name = NULL;
  free(r->column);
  free(r->rate);
  free(r->t);
  free(r->body_pos);
  free(r->body_rot);
  free(r->joint_pos);
  free(r->joint_a);
  free(r->joint_b);
}

/* A run file with rigid bodies and no particles: the dimension (the last
 * one of /bodies/position; /model/dimension is a particles' dataset) and
 * the times (read_bodies reads the rest). */
static int run_open_bodies_only(run_file *r, const mrvi_h5in *in) {
  hsize_t dt[1], dp[3];
  int st;
  if ((st = mrvi_h5in_shape(in, "/macro/t", MRVI_H5_NUMBER, 1, NULL, dt)) < 0 ||
      (st = mrvi_h5in_shape(in, "/bodies/position", MRVI_H5_NUMBER, 3, NULL,
                            dp)) < 0)
    return st;
  const int d = (int)dp[2];
  if (d < 2 || d > 3)
    return mrvi_fail(in->msg, in->len, MRVI_EIO,
                     "%s: /model/dimension = %d: rigid bodies are 2-D or 3-D",
                     r->path, d);
  r->d = d;
  r->rows = dt[0];
  return mrvi_h5in_read_new(in, "/macro/t", H5T_NATIVE_DOUBLE, 1, NULL, r->rows,
                            (void **)&r->t, NULL);
}

/* Open a run file and read its particles, every dataset checked against
 * the others: /macro/q gives the coordinates n, /model/rate has n entries,
 * /model/particle_column at most n, /model/particle_name one per particle,
 * /model/dimension one value.  A message naming what is wrong otherwise
 * (no particles: MRVI_EINVAL). */
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
  const mrvi_h5in in = {r->file, path, msg, len};
  hsize_t dq[2], dt[1], dc[1], de[2];
  int st;
  if ((st = mrvi_h5in_shape(&in, "/macro/q", MRVI_H5_NUMBER, 2, NULL, dq)) <
          0 ||
      (st = mrvi_h5in_shape(&in, "/macro/t", MRVI_H5_NUMBER, 1, NULL, dt)) <
          0 ||
      (st = mrvi_h5in_read_new(&in, "/model/rate", H5T_NATIVE_INT, 1, &dq[1],
                               MRVI_H5_ANY, (void **)&r->rate, NULL)) < 0)
    return st;
  r->n = (int)dq[1];
  if (!mrvi_h5in_exists(&in, "/model/particle_column") &&
      mrvi_h5in_exists(&in, "/bodies/position"))
    return run_open_bodies_only(r, &in);
  if (!mrvi_h5in_exists(&in, "/model/particle_column"))
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: the model has no particles (generalised coordinates "
                     "only, or a file written before mrvi stored "
                     "/model/particle_column): nothing to show as points",
                     path);
  if ((st = mrvi_h5in_shape(&in, "/model/particle_column", MRVI_H5_NUMBER, 1,
                            NULL, dc)) < 0)
    return st;
  if (dc[0] > (hsize_t)r->n)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: /model/particle_column has %llu entries, more than "
                     "the %d coordinates of /macro/q",
                     path, (unsigned long long)dc[0], r->n);
  r->np = (int)dc[0];
  int d = 0;
  if ((st = mrvi_h5in_read(&in, "/model/dimension", H5T_NATIVE_INT, 0, NULL, 0,
                           1, &d, 1)) < 0)
    return st;
  r->d = d;
  r->rows = dt[0] < dq[0] ? dt[0] : dq[0];
  /* Bonds are optional: a missing or malformed /model/edges shows none. */
  const hsize_t two[2] = {MRVI_H5_ANY, 2};
  r->n_edges = mrvi_h5in_exists(&in, "/model/edges") &&
                       mrvi_h5in_shape(&in, "/model/edges", MRVI_H5_NUMBER, 2,
                                       two, de) == MRVI_OK &&
                       de[0] <= INT_MAX
                   ? (int)de[0]
                   : 0;
  mrvi_fmt(msg, len, "%s", "");
  if (d < 1 || d > 3 || (size_t)r->np * (size_t)d > (size_t)r->n)
    return mrvi_fail(msg, len, MRVI_EIO,
                     "%s: /model/dimension = %d does not fit %d particles "
                     "in %d coordinates",
                     path, d, r->np, r->n);
  if ((st = mrvi_h5in_read_new(&in, "/model/particle_column", H5T_NATIVE_INT, 1,
                               dc, MRVI_H5_ANY, (void **)&r->column, NULL)) <
          0 ||
      (st = mrvi_h5in_strings(&in, "/model/particle_name", 1, dc[0], 4096,
                              &r->name)) < 0 ||
      (st = mrvi_h5in_read_new(&in, "/macro/t", H5T_NATIVE_DOUBLE, 1, NULL,
                               r->rows, (void **)&r->t, NULL)) < 0)
    return st;
  int consecutive = 1;
  for (int i = 0; i < r->np; i++) {
    if (r->column[i] < 0 || r->column[i] > r->n - d)
      return mrvi_fail(msg, len, MRVI_EIO,
                       "%s: /model/particle_column[%d] = %d out of range", path,
                       i, r->column[i]);
    consecutive &= r->column[i] == r->column[0] + d * i;
  }
  r->first = consecutive ? r->column[0] : -1;
  return MRVI_OK;
}

/* The bodies and joints of an open run file (nothing without /bodies):
 * /bodies/position (rows, B, d) and /bodies/rotation (rows, B, d, d), with
 * /joints/position (rows, J, d), /joints/body_a and /joints/body_b (J,
 * bodies in [-1, B)) when the model has joints; the rows are those every
 * dataset has (a killed run may have flushed one further). */
static int read_bodies(run_file *r, char *msg, size_t len) {
  const mrvi_h5in in = {r->file, r->path, msg, len};
  if (!mrvi_h5in_exists(&in, "/bodies/position"))
    return MRVI_OK;
  const hsize_t d = (hsize_t)r->d;
  hsize_t dp[3], dr[4], dj[3];
  const hsize_t want_p[3] = {MRVI_H5_ANY, MRVI_H5_ANY, d};
  int st;
  if ((st = mrvi_h5in_shape(&in, "/bodies/position", MRVI_H5_NUMBER, 3, want_p,
                            dp)) < 0)
    return st;
  const hsize_t want_r[4] = {MRVI_H5_ANY, dp[1], d, d};
  if ((st = mrvi_h5in_shape(&in, "/bodies/rotation", MRVI_H5_NUMBER, 4, want_r,
                            dr)) < 0)
    return st;
  hsize_t rows = r->rows < dp[0] ? r->rows : dp[0];
  rows = rows < dr[0] ? rows : dr[0];
  const int joints = mrvi_h5in_exists(&in, "/joints/position");
  if (joints) {
    if ((st = mrvi_h5in_shape(&in, "/joints/position", MRVI_H5_NUMBER, 3,
                              want_p, dj)) < 0)
      return st;
    rows = rows < dj[0] ? rows : dj[0];
    r->nj = (int)dj[1];
  }
  r->nb = (int)dp[1];
  r->rows = rows;
  if ((st = mrvi_h5in_read_new(&in, "/bodies/position", H5T_NATIVE_DOUBLE, 3,
                               want_p, rows, (void **)&r->body_pos, NULL)) <
          0 ||
      (st = mrvi_h5in_read_new(&in, "/bodies/rotation", H5T_NATIVE_DOUBLE, 4,
                               want_r, rows, (void **)&r->body_rot, NULL)) < 0)
    return st;
  if (!joints || r->nj == 0)
    return MRVI_OK;
  const hsize_t nj = (hsize_t)r->nj;
  if ((st = mrvi_h5in_read_new(&in, "/joints/position", H5T_NATIVE_DOUBLE, 3,
                               want_p, rows, (void **)&r->joint_pos, NULL)) <
          0 ||
      (st = mrvi_h5in_read_new(&in, "/joints/body_a", H5T_NATIVE_INT, 1, &nj,
                               MRVI_H5_ANY, (void **)&r->joint_a, NULL)) < 0 ||
      (st = mrvi_h5in_read_new(&in, "/joints/body_b", H5T_NATIVE_INT, 1, &nj,
                               MRVI_H5_ANY, (void **)&r->joint_b, NULL)) < 0)
    return st;
  for (int j = 0; j < r->nj; j++)
    if (r->joint_a[j] < 0 || r->joint_a[j] >= r->nb || r->joint_b[j] < -1 ||
        r->joint_b[j] >= r->nb)
      return mrvi_fail(msg, len, MRVI_EIO,
                       "%s: /joints/body_a[%d] = %d, body_b = %d: not bodies "
                       "of /bodies/position (%d)",
                       r->path, j, r->joint_a[j], r->joint_b[j], r->nb);
  return MRVI_OK;
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

/* Length of the director segments of the bodies collection: half the
 * largest distance from a body's centre of mass to a joint point on it at
 * the first node, or 0.5 without joints. */
static double frame_scale(const run_file *r) {
  double s = 0.0;
  const int d = r->d;
  for (int j = 0; r->rows > 0 && j < r->nj; j++) {
    const double *x = r->joint_pos + j * d,
                 *c = r->body_pos + r->joint_a[j] * d;
    double a = 0.0;
    for (int i = 0; i < d; i++)
      a += (x[i] - c[i]) * (x[i] - c[i]);
    s = sqrt(a) > s ? sqrt(a) : s;
  }
  return s > 0.0 ? 0.5 * s : 0.5;
}

/* The bodies collection: per stored macro node a Polyline grid of the
 * bodies' frames (segments phi -> phi + s d_i) and the joints (phi_A -> x_A
 * and x_A -> phi_B, x_A = /joints/position); attribute `part` per line: i
 * for director d_i, 0 for a joint.  The points are computed from
 * /bodies/position, /bodies/rotation and /joints/position and written
 * inline. */
static void bodies_collection(FILE *f, const run_file *r) {
  const int d = r->d, nb = r->nb, nj = r->nj;
  int lines = nb * d, points = nb * (1 + d) + nj;
  for (int j = 0; j < nj; j++)
    lines += r->joint_b[j] >= 0 ? 2 : 1;
  const double s = frame_scale(r);
  fputs("    <Grid Name=\"bodies\" GridType=\"Collection\" "
        "CollectionType=\"Temporal\">\n",
        f);
  for (hsize_t k = 0; k < r->rows; k++) {
    fprintf(f, "      <Grid Name=\"bodies %llu\" GridType=\"Uniform\">\n",
            (unsigned long long)k);
    fputs("        <Time Value=\"", f);
    put_double(f, r->t[k]);
    fputs("\"/>\n", f);
    /* Lines: body b's centre is point b (1 + d), its frame tips follow;
     * joint j's point is nb (1 + d) + j. */
    fprintf(f,
            "        <Topology TopologyType=\"Polyline\" "
            "NumberOfElements=\"%d\" NodesPerElement=\"2\">\n"
            "          <DataItem Dimensions=\"%d 2\" NumberType=\"Int\" "
            "Format=\"XML\">",
            lines, lines);
    for (int b = 0; b < nb; b++)
      for (int i = 1; i <= d; i++)
        fprintf(f, " %d %d", b * (1 + d), b * (1 + d) + i);
    for (int j = 0; j < nj; j++) {
      const int x = nb * (1 + d) + j;
      fprintf(f, " %d %d", r->joint_a[j] * (1 + d), x);
      if (r->joint_b[j] >= 0)
        fprintf(f, " %d %d", x, r->joint_b[j] * (1 + d));
    }
    fputs("</DataItem>\n        </Topology>\n", f);
    fprintf(f,
            "        <Geometry GeometryType=\"%s\">\n"
            "          <DataItem Dimensions=\"%d %d\" NumberType=\"Float\" "
            "Precision=\"8\" Format=\"XML\">",
            d == 3 ? "XYZ" : "XY", points, d);
    const double *pos = r->body_pos + k * (hsize_t)(nb * d);
    const double *rot = r->body_rot + k * (hsize_t)(nb * d * d);
    for (int b = 0; b < nb; b++)
      for (int i = 0; i <= d; i++)
        for (int a = 0; a < d; a++) {
          /* i = 0: the centre; i >= 1: the tip of d_i (column i - 1). */
          const double x =
              pos[b * d + a] + (i ? s * rot[(b * d + a) * d + (i - 1)] : 0.0);
          fputc(' ', f);
          put_double(f, x);
        }
    for (int j = 0; j < nj; j++)
      for (int a = 0; a < d; a++) {
        fputc(' ', f);
        put_double(f, r->joint_pos[(k * (hsize_t)nj + (hsize_t)j) * (hsize_t)d +
                                   (hsize_t)a]);
      }
    fputs("</DataItem>\n        </Geometry>\n", f);
    fprintf(f,
            "        <Attribute Name=\"part\" AttributeType=\"Scalar\" "
            "Center=\"Cell\">\n"
            "          <DataItem Dimensions=\"%d\" NumberType=\"Int\" "
            "Format=\"XML\">",
            lines);
    for (int b = 0; b < nb; b++)
      for (int i = 1; i <= d; i++)
        fprintf(f, " %d", i);
    for (int j = 0; j < nj; j++)
      fputs(r->joint_b[j] >= 0 ? " 0 0" : " 0", f);
    fputs("</DataItem>\n        </Attribute>\n      </Grid>\n", f);
  }
  fputs("    </Grid>\n", f);
}

int mrvi_export_xdmf(const char *h5_path, const char *xdmf_path, char *msg,
                     size_t len) {
  mrvi_fmt(msg, len, "%s", "");
  if (!h5_path || !xdmf_path)
    return mrvi_fail(msg, len, MRVI_EINVAL, "mrvi_export_xdmf: no file name");
  mrvi_h5_quiet q;
  mrvi_h5_quiet_begin(&q);
  run_file r;
  int st = run_open(&r, h5_path, msg, len);
  if (st == 0)
    st = read_bodies(&r, msg, len);
  char h5[PATH_MAX + 8];
  if (st == 0 && r.np > 0 && r.first < 0)
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
    fprintf(f, "<!-- mrvi %s: the %s of ", MRVI_VERSION,
            r.np > 0 && r.nb > 0 ? "particles and bodies"
            : r.nb > 0           ? "bodies"
                                 : "particles");
    xml_escape(f, h5);
    fprintf(f,
            " over the %llu stored macro nodes (doc/output.md).  Open in "
            "ParaView (XDMF reader) or VisIt. -->\n",
            (unsigned long long)r.rows);
    fputs("<Xdmf Version=\"2.0\">\n  <Domain>\n", f);
    if (r.np > 0)
      collection(f, &r, h5, 0);
    if (r.np > 0 && r.n_edges > 0)
      collection(f, &r, h5, 1);
    if (r.nb > 0)
      bodies_collection(f, &r);
    fputs("  </Domain>\n</Xdmf>\n", f);
    if (ferror(f) | fclose(f))
      st = mrvi_fail(msg, len, MRVI_EIO, "%s: write error: %s", xdmf_path,
                     strerror(errno));
  }
  run_close(&r);
  mrvi_h5_quiet_end(&q);
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

/* The micro datasets of a run: /micro/t, /micro/q_fast with a column per
 * fast coordinate of /model/rate and, when present, /micro/q_slow with one
 * per slow coordinate; the frames are the rows all of them have (a killed
 * run may have flushed one dataset further than another). */
static int micro_setup(const run_file *r, micro_map *mm, char *msg,
                       size_t len) {
  const mrvi_h5in in = {r->file, r->path, msg, len};
  hsize_t df[2], ds[2], dt[1];
  memset(mm, 0, sizeof *mm);
  if (!mrvi_h5in_exists(&in, "/micro/t") ||
      !mrvi_h5in_exists(&in, "/micro/q_fast"))
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: no micro nodes (/micro; a model without fast "
                     "coordinates or output.micro: false)",
                     r->path);
  mm->src = malloc((size_t)r->n * sizeof *mm->src);
  mm->col = malloc((size_t)r->n * sizeof *mm->col);
  if (!mm->src || !mm->col)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  for (int c = 0; c < r->n; c++) {
    mm->src[c] = r->rate[c] == 1 ? 0 : 1;
    mm->col[c] = r->rate[c] == 1 ? mm->n_fast++ : mm->n_slow++;
  }
  const hsize_t want_fast[2] = {MRVI_H5_ANY, (hsize_t)mm->n_fast},
                want_slow[2] = {MRVI_H5_ANY, (hsize_t)mm->n_slow};
  const int have_slow = mrvi_h5in_exists(&in, "/micro/q_slow");
  int st;
  if ((st = mrvi_h5in_shape(&in, "/micro/t", MRVI_H5_NUMBER, 1, NULL, dt)) <
          0 ||
      (st = mrvi_h5in_shape(&in, "/micro/q_fast", MRVI_H5_NUMBER, 2, want_fast,
                            df)) < 0 ||
      (have_slow && (st = mrvi_h5in_shape(&in, "/micro/q_slow", MRVI_H5_NUMBER,
                                          2, want_slow, ds)) < 0))
    return st;
  mm->have_slow = have_slow;
  mm->rows = dt[0] < df[0] ? dt[0] : df[0];
  if (have_slow && ds[0] < mm->rows)
    mm->rows = ds[0];
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

/* Row k of the rank-2 dataset name, cols wide, into buf (cols values). */
static int read_row(const run_file *r, const char *name, hsize_t k, int cols,
                    double *buf, char *msg, size_t len) {
  const mrvi_h5in in = {r->file, r->path, msg, len};
  const hsize_t want[2] = {MRVI_H5_ANY, (hsize_t)cols};
  return mrvi_h5in_read(&in, name, H5T_NATIVE_DOUBLE, 2, want, k, 1, buf,
                        (size_t)cols);
}

/* The bodies as XYZ points (doc/output.md, "Extended XYZ"): per body its
 * centre and the tips of its D directors at length s, their names and rates
 * from /bodies/name and /model/rate at /bodies/column; with --micro the
 * fast bodies' rows of /micro/bodies (/bodies/fast) and the slow bodies
 * interpolated between the macro nodes around the micro node's time
 * (xyz_bodies_pose). */
typedef struct xyz_bodies {
  char **name;         /* nb: /bodies/name */
  int *fast;           /* nb: 1 for a fast body (rate of its phi_x) */
  int *micro_col;      /* nb: column of /micro/bodies, -1 for none */
  double *mpos, *mrot; /* micro rows x F x d, x d x d */
  int nf;              /* F: columns of /micro/bodies */
  hsize_t micro_rows;  /* rows of /micro/bodies/... */
  double *pos, *rot;   /* one frame: nb x d and nb x d x d */
  double s;            /* length of the director segments */
} xyz_bodies;

static void xyz_bodies_free(xyz_bodies *xb, int nb) {
  mrvi_h5_strings_free(xb->name, (size_t)nb);
  free(xb->fast);
  free(xb->micro_col);
  free(xb->mpos);
  free(xb->mrot);
  free(xb->pos);
  free(xb->rot);
}

/* The names and rates of the bodies of r (read_bodies done), and with
 * `micro` the fast bodies' micro rows. */
static int xyz_bodies_read(const run_file *r, int micro, xyz_bodies *xb,
                           char *msg, size_t len) {
  const mrvi_h5in in = {r->file, r->path, msg, len};
  const int nb = r->nb, d = r->d;
  const hsize_t want_nb[1] = {(hsize_t)nb};
  int *column = NULL, *fast_list = NULL;
  int st;
  memset(xb, 0, sizeof *xb);
  if (r->rows == 0) /* no frame to write */
    return MRVI_OK;
  xb->s = frame_scale(r);
  xb->fast = calloc((size_t)nb + 1, sizeof *xb->fast);
  xb->micro_col = malloc(((size_t)nb + 1) * sizeof *xb->micro_col);
  xb->pos = malloc(((size_t)nb + 1) * (size_t)d * sizeof *xb->pos);
  xb->rot = malloc(((size_t)nb + 1) * (size_t)(d * d) * sizeof *xb->rot);
  if (!xb->fast || !xb->micro_col || !xb->pos || !xb->rot)
    return mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
  if ((st = mrvi_h5in_strings(&in, "/bodies/name", 1, want_nb[0], 4096,
                              &xb->name)) < 0 ||
      (st = mrvi_h5in_read_new(&in, "/bodies/column", H5T_NATIVE_INT, 1,
                               want_nb, MRVI_H5_ANY, (void **)&column, NULL)) <
          0)
    return st;
  for (int b = 0; b < nb && st == 0; b++) {
    xb->micro_col[b] = -1;
    if (column[b] < 0 || column[b] >= r->n)
      st = mrvi_fail(msg, len, MRVI_EIO,
                     "%s: /bodies/column[%d] = %d out of range", r->path, b,
                     column[b]);
    else
      xb->fast[b] = r->rate[column[b]] == 1;
  }
  free(column);
  if (st < 0 || !micro)
    return st;
  int any_fast = 0;
  for (int b = 0; b < nb; b++)
    any_fast |= xb->fast[b];
  if (!any_fast)
    return MRVI_OK;
  /* The fast bodies' micro rows. */
  hsize_t df[1], dp[3], dr[4];
  if (!mrvi_h5in_exists(&in, "/bodies/fast") ||
      !mrvi_h5in_exists(&in, "/micro/bodies/position"))
    return mrvi_fail(msg, len, MRVI_EINVAL,
                     "%s: the fast bodies have no positions at the micro "
                     "nodes (/micro/bodies)",
                     r->path);
  if ((st = mrvi_h5in_read_new(&in, "/bodies/fast", H5T_NATIVE_INT, 1, NULL,
                               MRVI_H5_ANY, (void **)&fast_list, df)) < 0)
    return st;
  xb->nf = (int)df[0];
  const hsize_t want_p[3] = {MRVI_H5_ANY, df[0], (hsize_t)d},
                want_r[4] = {MRVI_H5_ANY, df[0], (hsize_t)d, (hsize_t)d};
  for (int f = 0; f < xb->nf && st == 0; f++)
    if (fast_list[f] < 0 || fast_list[f] >= nb || !xb->fast[fast_list[f]])
      st = mrvi_fail(msg, len, MRVI_EIO,
                     "%s: /bodies/fast[%d] = %d is not a fast body", r->path, f,
                     fast_list[f]);
    else
      xb->micro_col[fast_list[f]] = f;
  free(fast_list);
  for (int b = 0; b < nb && st == 0; b++)
    if (xb->fast[b] && xb->micro_col[b] < 0)
      st = mrvi_fail(msg, len, MRVI_EIO,
                     "%s: fast body %d is missing from /bodies/fast", r->path,
                     b);
  if (st < 0 ||
      (st = mrvi_h5in_shape(&in, "/micro/bodies/position", MRVI_H5_NUMBER, 3,
                            want_p, dp)) < 0 ||
      (st = mrvi_h5in_shape(&in, "/micro/bodies/rotation", MRVI_H5_NUMBER, 4,
                            want_r, dr)) < 0)
    return st;
  xb->micro_rows = dp[0] < dr[0] ? dp[0] : dr[0];
  if ((st = mrvi_h5in_read_new(&in, "/micro/bodies/position", H5T_NATIVE_DOUBLE,
                               3, want_p, xb->micro_rows, (void **)&xb->mpos,
                               NULL)) < 0 ||
      (st = mrvi_h5in_read_new(&in, "/micro/bodies/rotation", H5T_NATIVE_DOUBLE,
                               4, want_r, xb->micro_rows, (void **)&xb->mrot,
                               NULL)) < 0)
    return st;
  return MRVI_OK;
}

/* The bodies' poses of frame k into xb->pos and xb->rot: macro row k, or
 * (micro, time t) the fast bodies' micro row k and the slow bodies as the
 * scheme's slow rule sees them at the micro node: the linear interpolation
 * (1 - theta) x_j + theta x_{j+1} of their centre and directors between the
 * stored macro nodes j, j + 1 around t, theta = (t - t_j) / (t_{j+1} - t_j)
 * (= m/p at micro node m of the step, arXiv 2406.12991 (3.18),
 * doc/theory.md; as
 * /micro/q_slow; between stored nodes when output.every > 1). */
static void xyz_bodies_pose(const run_file *r, xyz_bodies *xb, hsize_t k,
                            int micro, double t) {
  const int d = r->d, dd = d * d;
  hsize_t row = k;
  double theta = 0.0;
  if (micro) { /* the last macro node not after t (up to round-off) */
    for (row = 0; row + 1 < r->rows &&
                  r->t[row + 1] <= t + 1e-9 * (fabs(t) + fabs(r->t[1]));
         row++)
      ;
    if (row + 1 < r->rows && r->t[row + 1] > r->t[row] && t > r->t[row])
      theta = (t - r->t[row]) / (r->t[row + 1] - r->t[row]);
  }
  for (int b = 0; b < r->nb; b++) {
    const int f = micro ? xb->micro_col[b] : -1;
    if (f >= 0) {
      memcpy(xb->pos + b * d,
             xb->mpos + (k * (hsize_t)xb->nf + (hsize_t)f) * (hsize_t)d,
             (size_t)d * sizeof *xb->pos);
      memcpy(xb->rot + b * dd,
             xb->mrot + (k * (hsize_t)xb->nf + (hsize_t)f) * (hsize_t)dd,
             (size_t)dd * sizeof *xb->rot);
      continue;
    }
    const hsize_t at = row * (hsize_t)r->nb + (hsize_t)b,
                  next = theta > 0.0 ? at + (hsize_t)r->nb : at;
    for (int a = 0; a < d; a++)
      xb->pos[b * d + a] =
          (1.0 - theta) * r->body_pos[at * (hsize_t)d + (hsize_t)a] +
          theta * r->body_pos[next * (hsize_t)d + (hsize_t)a];
    for (int a = 0; a < dd; a++)
      xb->rot[b * dd + a] =
          (1.0 - theta) * r->body_rot[at * (hsize_t)dd + (hsize_t)a] +
          theta * r->body_rot[next * (hsize_t)dd + (hsize_t)a];
  }
}

/* The 1 + d lines of body b: its centre ("NAME") and the tips of its
 * directors ("NAME.d1" ...), species X, body/d1/d2/d3 or the name. */
static void xyz_body_lines(FILE *f, const run_file *r, const xyz_bodies *xb,
                           int b, int species) {
  const int d = r->d;
  static const char *const tip[] = {"body", "d1", "d2", "d3"};
  for (int i = 0; i <= d; i++) {
    if (species == MRVI_XYZ_SPECIES_NAME) {
      put_name(f, xb->name[b]);
      if (i)
        fprintf(f, ".d%d", i);
    } else {
      fputs(species == MRVI_XYZ_SPECIES_RATE ? tip[i] : "X", f);
    }
    for (int a = 0; a < 3; a++) {
      /* i = 0: the centre; i >= 1: phi + s d_i (column i - 1). */
      const double x =
          a >= d ? 0.0
                 : xb->pos[b * d + a] +
                       (i ? xb->s * xb->rot[(b * d + a) * d + (i - 1)] : 0.0);
      fputc(' ', f);
      put_double(f, x);
    }
    fprintf(f, " %d ", xb->fast[b]);
    put_name(f, xb->name[b]);
    if (i)
      fprintf(f, ".d%d", i);
    fputc('\n', f);
  }
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
  mrvi_h5_quiet q;
  mrvi_h5_quiet_begin(&q);
  run_file r;
  micro_map mm = {0};
  xyz_bodies xb = {0};
  double *row = NULL, *fast = NULL, *slow = NULL, *mt = NULL;
  FILE *f = NULL;
  int st = run_open(&r, h5_path, msg, len);
  if (st == 0)
    st = read_bodies(&r, msg, len);
  if (st == 0 && r.nb > 0)
    st = xyz_bodies_read(&r, o.micro, &xb, msg, len);
  if (st == 0 && o.micro)
    st = micro_setup(&r, &mm, msg, len);
  hsize_t frames = o.micro ? mm.rows : r.rows;
  if (o.micro && xb.nf > 0 && xb.micro_rows < frames)
    frames = xb.micro_rows;
  if (r.nb > 0 && r.rows == 0) /* no pose of the bodies to show */
    frames = 0;
  /* A line per particle, then 1 + d per body. */
  const long atoms = (long)r.np + (long)r.nb * (1 + r.d);
  if (st == 0) {
    row = malloc((size_t)r.n * sizeof *row);
    fast = malloc((size_t)(mm.n_fast + 1) * sizeof *fast);
    slow = malloc((size_t)(mm.n_slow + 1) * sizeof *slow);
    if (!row || !fast || !slow)
      st = mrvi_fail(msg, len, MRVI_ENOMEM, "out of memory");
    else if (o.micro)
      st = mrvi_h5in_read_new(&(mrvi_h5in){r.file, h5_path, msg, len},
                              "/micro/t", H5T_NATIVE_DOUBLE, 1, NULL, frames,
                              (void **)&mt, NULL);
  }
  if (st == 0 && !(f = fopen(xyz_path, "w")))
    st = mrvi_fail(msg, len, MRVI_EIO, "%s: cannot write: %s", xyz_path,
                   strerror(errno));
  for (hsize_t k = 0; st == 0 && k < frames; k += (hsize_t)o.every) {
    /* Coordinates of frame k in model order. */
    if (o.micro) {
      if ((st = read_row(&r, "/micro/q_fast", k, mm.n_fast, fast, msg, len)) <
              0 ||
          (mm.have_slow && (st = read_row(&r, "/micro/q_slow", k, mm.n_slow,
                                          slow, msg, len)) < 0))
        break;
      for (int c = 0; c < r.n; c++)
        row[c] = mm.src[c] == 0 ? fast[mm.col[c]] : slow[mm.col[c]];
    } else if ((st = read_row(&r, "/macro/q", k, r.n, row, msg, len)) < 0) {
      break;
    }
    fprintf(f, "%ld\nProperties=species:S:1:pos:R:3:rate:I:1:name:S:1 Time=",
            atoms);
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
    if (r.nb > 0)
      xyz_bodies_pose(&r, &xb, k, o.micro, o.micro ? mt[k] : r.t[k]);
    for (int b = 0; b < r.nb; b++)
      xyz_body_lines(f, &r, &xb, b, o.species);
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
  xyz_bodies_free(&xb, r.nb);
  run_close(&r);
  mrvi_h5_quiet_end(&q);
  return st;
}
