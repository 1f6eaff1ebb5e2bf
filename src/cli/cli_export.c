/* mrvi export FILE.h5 --format xyz|xdmf [-o OUT] [--every N] [--micro]
 *                     [--species x|rate|name]
 *
 * Files for viewers from the particles and bodies of a run file (doc/output.md,
 * "Viewing the motion"), and the XDMF file `mrvi run` writes beside its
 * output.  Exit status: 0 written, 1 bad arguments or a file that cannot
 * be exported (no particles or bodies, not a run file, cannot write). */
#include "cli.h"
#include "io/io.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

const char mrvi_usage_export[] =
    "Usage: mrvi export FILE.h5 --format xyz|xdmf [-o OUT] [--every N]\n"
    "                   [--micro] [--species x|rate|name]\n"
    "\n"
    "Write the particles and rigid bodies of a run file (mrvi run) for a\n"
    "viewer:\n"
    "  xyz    extended XYZ frames for OVITO, VMD or ASE: a frame per stored\n"
    "         macro node with the time (Time=...), each particle as\n"
    "         'species x y z rate name' (2-D and 1-D padded with zeros; rate\n"
    "         0 slow, 1 fast), 17 digits; then each body as 1 + d points,\n"
    "         its centre (name NAME) and the tips of its directors (NAME.d1\n"
    "         ...), as in the XDMF file\n"
    "  xdmf   the XDMF file for ParaView or VisIt that `mrvi run` writes\n"
    "         beside its output: particles as points and springs and rods as\n"
    "         lines over time, pointing into FILE.h5 (no copy); rewrite it\n"
    "         here, e.g. for a run that was killed\n"
    "Runs of generalised coordinates only have nothing to export.\n"
    "\n"
    "Options:\n"
    "  -f, --format FMT      xyz or xdmf (required)\n"
    "  -o, --output OUT      output file (default: FILE with .h5 replaced by\n"
    "                        .xyz or .xdmf)\n"
    "      --every N         xyz: every N-th frame (default 1)\n"
    "      --micro           xyz: a frame per micro node (/micro; slow\n"
    "                        particles need output.micro_slow: true; slow\n"
    "                        bodies step with the macro nodes)\n"
    "      --species KIND    xyz: the species column: x (ASE's dummy\n"
    "                        element X, default), rate (slow/fast) or name\n"
    "                        (the particle names); bodies: X, body/d1/d2/d3\n"
    "                        or NAME/NAME.d1...; OVITO and VMD read all\n"
    "                        three, ASE only x\n"
    "  -h, --help            show this help\n"
    "\n"
    "Exit status: 0 written, 1 bad arguments or FILE cannot be exported.\n";

void mrvi_cli_replace_extension(const char *path, const char *ext, char *buf,
                                size_t len) {
  size_t n = strlen(path);
  if (n > 3 && !strcmp(path + n - 3, ".h5"))
    n -= 3;
  snprintf(buf, len, "%.*s%s", (int)n, path, ext);
}

/* 1 if path exists and is not an XDMF file mrvi wrote (its first line
 * after the XML declaration is the "<!-- mrvi" comment). */
static int foreign_file(const char *path) {
  FILE *f = fopen(path, "r");
  if (!f)
    return 0;
  char head[256] = "";
  size_t got = fread(head, 1, sizeof head - 1, f);
  head[got] = '\0';
  fclose(f);
  return strstr(head, "<!-- mrvi ") == NULL;
}

int mrvi_cli_write_xdmf(const char *h5_path, int quiet, int force) {
  char xdmf[4096], msg[1024];
  mrvi_cli_replace_extension(h5_path, ".xdmf", xdmf, sizeof xdmf);
  if (!force && foreign_file(xdmf)) {
    fprintf(stderr,
            "mrvi run: warning: no XDMF file: %s exists and was not written "
            "by mrvi; not overwritten (--force replaces it)\n",
            xdmf);
    return -1;
  }
  if (mrvi_export_xdmf(h5_path, xdmf, msg, sizeof msg) < 0) {
    fprintf(stderr, "mrvi run: warning: no XDMF file: %s\n", msg);
    return -1;
  }
  if (!quiet)
    printf("  %-23s%s (ParaView: particles and bonds over time)\n", "XDMF",
           xdmf);
  return 0;
}

/* A positive integer option value, or -1 with a message. */
static int positive(const char *opt, const char *v) {
  char *end = NULL;
  long x = strtol(v, &end, 10);
  if (!*v || *end || x < 1 || x > 1000000000L) {
    fprintf(stderr, "mrvi export: %s expects a positive integer, got '%s'\n",
            opt, v);
    return -1;
  }
  return (int)x;
}

int mrvi_cmd_export(int argc, char **argv) {
  const char *file = NULL, *format = NULL, *out = NULL, *species = "x";
  mrvi_xyz_options opt = {1, 0, MRVI_XYZ_SPECIES_X};
  for (int i = 1; i < argc; i++) {
    const char *arg = argv[i], *value = NULL;
    if (!strcmp(arg, "-h") || !strcmp(arg, "--help")) {
      fputs(mrvi_usage_export, stdout);
      return 0;
    }
    if (arg[0] != '-' || !arg[1]) {
      if (file) {
        fprintf(stderr, "mrvi export: unexpected argument '%s' (one FILE)\n",
                arg);
        return 1;
      }
      file = arg;
      continue;
    }
    if (!strcmp(arg, "--micro")) {
      opt.micro = 1;
      continue;
    }
    /* Options with a value: --name=value, --name value, -o value. */
    char name[32];
    const char *eq = strchr(arg, '=');
    snprintf(name, sizeof name, "%.*s", eq ? (int)(eq - arg) : (int)strlen(arg),
             arg);
    static const char *const with_value[] = {
        "-f", "--format", "-o", "--output", "--every", "--species", NULL};
    int known = 0;
    for (int k = 0; with_value[k]; k++)
      known |= !strcmp(name, with_value[k]);
    if (!known) {
      static const char *const all[] = {"--format",  "--output", "--every",
                                        "--species", "--micro",  "--help"};
      const char *hint = mrvi_closest(name, all, 6);
      fprintf(stderr, "mrvi export: unknown option '%s'%s%s%s\n", arg,
              hint ? "; did you mean '" : "", hint ? hint : "",
              hint ? "'?" : "");
      mrvi_cli_usage_short("export", mrvi_usage_export);
      return 1;
    }
    if (eq)
      value = eq + 1;
    else if (i + 1 < argc)
      value = argv[++i];
    else {
      fprintf(stderr, "mrvi export: option '%s' needs a value\n", arg);
      return 1;
    }
    if (!strcmp(name, "-f") || !strcmp(name, "--format"))
      format = value;
    else if (!strcmp(name, "-o") || !strcmp(name, "--output"))
      out = value;
    else if (!strcmp(name, "--every") &&
             (opt.every = positive(name, value)) < 0)
      return 1;
    else if (!strcmp(name, "--species"))
      species = value;
  }
  if (!file || !format) {
    fprintf(stderr, "mrvi export: missing %s\n",
            !file ? "FILE.h5" : "--format xyz|xdmf");
    mrvi_cli_usage_short("export", mrvi_usage_export);
    return 1;
  }
  const int xyz = !strcmp(format, "xyz");
  if (!xyz && strcmp(format, "xdmf") != 0) {
    fprintf(stderr, "mrvi export: unknown format '%s' (xyz or xdmf)\n", format);
    return 1;
  }
  if (!strcmp(species, "name"))
    opt.species = MRVI_XYZ_SPECIES_NAME;
  else if (!strcmp(species, "rate"))
    opt.species = MRVI_XYZ_SPECIES_RATE;
  else if (strcmp(species, "x") != 0) {
    fprintf(stderr, "mrvi export: --species x, rate or name, got '%s'\n",
            species);
    return 1;
  }
  if (!xyz && (opt.every != 1 || opt.micro)) {
    fprintf(stderr, "mrvi export: --every and --micro are options of "
                    "--format xyz (the XDMF file has every stored macro "
                    "node)\n");
    return 1;
  }
  char path[4096], msg[1024];
  if (out)
    snprintf(path, sizeof path, "%s", out);
  else
    mrvi_cli_replace_extension(file, xyz ? ".xyz" : ".xdmf", path, sizeof path);
  if (!strcmp(path, file)) {
    fprintf(stderr, "mrvi export: the output file is FILE itself\n");
    return 1;
  }
  const int st = xyz ? mrvi_export_xyz(file, path, &opt, msg, sizeof msg)
                     : mrvi_export_xdmf(file, path, msg, sizeof msg);
  if (st < 0) {
    fprintf(stderr, "mrvi export: %s\n", msg[0] ? msg : mrvi_strerror(st));
    return 1;
  }
  char reason[1024];
  if (mrvi_run_file_status(file, reason, sizeof reason) == MRVI_OK &&
      strcmp(reason, "completed") != 0)
    fprintf(stderr,
            "mrvi export: note: %s did not complete (stop_reason: %s); its "
            "stored nodes were exported%s%s%s\n",
            file, reason,
            xyz ? "" : "; other HDF5 readers (ParaView) need `h5clear -s ",
            xyz ? "" : file, xyz ? "" : "` first when the writer was killed");
  printf("%s\n", path);
  return 0;
}
