/* libFuzzer target: the readers of an mrvi output file, the HDF5 inputs a
 * user can point mrvi at (run --resume / --from, export, converge
 * --reference, the status line of mrvi export).
 *
 * The input is the bytes of an HDF5 file; it is written to a file of its
 * own (the readers take a path) and read as each command reads it:
 *   - mrvi_run_file_status;
 *   - mrvi_stored_node_read of the last node and of the node a resume
 *     continues from; when one is read, its /model/description is loaded
 *     and mrvi_stored_run_check compares the file with it (--resume,
 *     --from); the node is also read for a model of the file's own width
 *     (--from with a model);
 *   - mrvi_trajectory_read (converge --reference);
 *   - mrvi_export_xyz (macro and micro frames) and mrvi_export_xdmf;
 *   - the writer's resume path (run --resume): the node a resume or an
 *     extension (a completed run to a later t_end) continues from, the
 *     system of the file's description, and mrvi_writer_open appending to
 *     the file, then closed -- whether or not mrvi_stored_run_check agrees
 *     (the writer reads the file's datasets itself and must check them);
 *   - the --controls reader, mrvi_ocp_controls_read, for the problem of
 *     systems/ocp_double_integrator.yaml (seeds: its mrvi optimize output,
 *     tests/fuzz/run.sh), with one macro and one micro actuator;
 *   - a batch's master file as mrvi batch --resume reads it
 *     (mrvi_batch_file_open with the plan and the cases' status), a row
 *     written for a case of the plan and mrvi_batch_file_best (seeds: a
 *     run batch and an optimize batch, tests/fuzz/run.sh).
 * Any crash, sanitizer report, leak or timeout is a finding; a refused
 * file is not.  So is an HDF5 object (file, dataset, attribute, ...) the
 * readers leave open: that is mrvi's leak even where LeakSanitizer can only
 * see libhdf5's allocation (tests/fuzz/lsan.supp hides those).  Reports inside
 * libhdf5 itself are told apart by tests/fuzz/run.sh (see there). */
#include "mrvi.h"
#include "io/io.h"
#include "ocp/ocp.h"

#include <hdf5.h>
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define MSG 1024

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* The contract of every reader: a message on failure. */
static void refused_with_message(int st, const char *msg) {
  if (st < 0 && !msg[0])
    abort();
}

/* --resume / --from: the node, then the file against its own description. */
static void read_node(const char *path, long which, int n) {
  char msg[MSG] = "";
  mrvi_stored_node *node = NULL;
  int st = mrvi_stored_node_read(path, which, n, &node, msg, sizeof msg);
  refused_with_message(st, msg);
  if ((st == MRVI_OK) != (node != NULL))
    abort();
  if (!node)
    return;
  if (node->n > 0 && n == 0 && which == MRVI_NODE_LAST)
    read_node(path, MRVI_NODE_LAST, node->n);
  if (node->description && n == 0) {
    mrvi_system *sys = NULL;
    msg[0] = '\0';
    st = mrvi_system_load_string(node->description, "fuzz.h5:/description",
                                 NULL, 0, &sys, msg, sizeof msg);
    refused_with_message(st, msg);
    if (sys) {
      msg[0] = '\0';
      refused_with_message(mrvi_stored_run_check(path, sys, msg, sizeof msg),
                           msg);
    }
    mrvi_system_free(sys);
  }
  mrvi_stored_node_free(node);
}

/* run --resume (which: MRVI_NODE_RESUME) or its extension to a later t_end
 * (MRVI_NODE_EXTEND): the writer opened on the file to append. */
static void resume_writer(const char *path, long which) {
  char msg[MSG] = "";
  mrvi_stored_node *node = NULL;
  int st = mrvi_stored_node_read(path, which, 0, &node, msg, sizeof msg);
  refused_with_message(st, msg);
  mrvi_system *sys = NULL;
  if (node && node->description) {
    msg[0] = '\0';
    st = mrvi_system_load_string(node->description, "fuzz.h5:/description",
                                 NULL, 0, &sys, msg, sizeof msg);
    refused_with_message(st, msg);
  }
  if (sys) {
    if (which == MRVI_NODE_EXTEND)
      sys->settings.t_end += 2.0 * sys->settings.macro_step;
    mrvi_writer_options opt = mrvi_system_writer_options(sys);
    opt.resume = 1;
    opt.resume_k = node->k;
    opt.extend = which == MRVI_NODE_EXTEND;
    mrvi_writer *w = NULL;
    msg[0] = '\0';
    st = mrvi_writer_open(path, sys->model, &sys->settings, &opt, &w, msg,
                          sizeof msg);
    refused_with_message(st, msg);
    if (w) {
      msg[0] = '\0';
      refused_with_message(mrvi_writer_close(w, "fuzz", msg, sizeof msg), msg);
    }
  }
  mrvi_system_free(sys);
  mrvi_stored_node_free(node);
}

/* The problem the --controls reader reads for (built once): the double
 * integrator of systems/ocp_double_integrator.yaml with a second actuator
 * on the micro grid. */
static const char ocp_text[] =
    "name: ocp_double_integrator\n"
    "coordinates:\n"
    "  - {name: x, mass: 2, rate: slow, position: 0, velocity: 0}\n"
    "  - {name: y, mass: 0.3, rate: fast, position: 0.01, velocity: 0.2}\n"
    "terms:\n"
    "  - {combination: {y: 1}, law: linear, potential: fast, stiffness: 750}\n"
    "integrator: {macro_step: 0.2, micro_steps: 5, t_end: 2}\n"
    "control:\n"
    "  terminal: [{coordinate: x, position: 1, velocity: 0}]\n"
    "  actuators:\n"
    "    - {name: push, coordinate: x, grid: macro}\n";
static const char ocp_micro[] =
    "    - {name: nudge, coordinate: y, grid: micro}\n";

static void read_controls(const char *path) {
  static mrvi_system *sys[2];
  static mrvi_ocp *o[2];
  static double *u[2];
  for (int k = 0; k < 2; k++) {
    char msg[MSG] = "";
    if (!o[k]) {
      char text[sizeof ocp_text + sizeof ocp_micro];
      snprintf(text, sizeof text, "%s%s", ocp_text, k ? ocp_micro : "");
      double *u0 = NULL;
      if (mrvi_system_load_string(text, "ocp.yaml", NULL, 0, &sys[k], msg,
                                  sizeof msg) < 0 ||
          mrvi_ocp_load(sys[k], &o[k], &u0, msg, sizeof msg) < 0) {
        fprintf(stderr, "fuzz_h5: the controls problem: %s\n", msg);
        abort();
      }
      u[k] = u0;
    }
    msg[0] = '\0';
    refused_with_message(mrvi_ocp_controls_read(path, o[k],
                                                sys[k]->settings.micro_steps,
                                                u[k], msg, sizeof msg),
                         msg);
  }
}

/* mrvi batch --resume (and mrvi batch's own reopening): the master file's
 * plan and the cases' status, a row written for the last case of the plan
 * (as a resumed case's), then the best case of an optimize batch (written
 * in place). */
static void read_batch(const char *path) {
  char msg[MSG] = "";
  mrvi_batch_plan plan;
  int *status = NULL;
  mrvi_batch_file *f = NULL;
  int st = mrvi_batch_file_open(path, &plan, &status, &f, msg, sizeof msg);
  refused_with_message(st, msg);
  if ((st == MRVI_OK) != (f != NULL))
    abort();
  if (f) {
    if (plan.n_cases > 0) {
      mrvi_batch_result res = {.c = plan.n_cases - 1,
                               .status = MRVI_BATCH_COMPLETED,
                               .steps = 1,
                               .cost = plan.command ? 1.0 : NAN,
                               .reason = "completed"};
      msg[0] = '\0';
      refused_with_message(mrvi_batch_file_row(f, &res, msg, sizeof msg), msg);
    }
    int best = -1;
    double cost = 0;
    msg[0] = '\0';
    refused_with_message(mrvi_batch_file_best(f, &best, &cost, msg, sizeof msg),
                         msg);
    if (best >= plan.n_cases)
      abort();
    mrvi_batch_plan_free(&plan);
  }
  free(status);
  msg[0] = '\0';
  refused_with_message(mrvi_batch_file_close(f, msg, sizeof msg), msg);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  /* One file per process: libFuzzer's -fork and -jobs run several. */
  static char path[64], out[64];
  if (!path[0]) {
    const char *dir = access("/dev/shm", W_OK) == 0 ? "/dev/shm" : "/tmp";
    snprintf(path, sizeof path, "%s/mrvi-fuzz-%ld.h5", dir, (long)getpid());
    snprintf(out, sizeof out, "%s/mrvi-fuzz-%ld.out", dir, (long)getpid());
  }
  FILE *f = fopen(path, "wb");
  if (!f)
    abort();
  if (fwrite(data, 1, size, f) != size || fclose(f) != 0)
    abort();

  char msg[MSG] = "";
  char reason[MSG] = "";
  int st = mrvi_run_file_status(path, reason, sizeof reason);
  refused_with_message(st, reason);

  read_node(path, MRVI_NODE_LAST, 0);
  read_node(path, MRVI_NODE_RESUME, 0);
  read_node(path, 0, 0);

  mrvi_trajectory *tr = NULL;
  st = mrvi_trajectory_read(path, &tr, msg, sizeof msg);
  refused_with_message(st, msg);
  mrvi_trajectory_free(tr);

  mrvi_xyz_options opt = {1, 0, MRVI_XYZ_SPECIES_NAME};
  msg[0] = '\0';
  refused_with_message(mrvi_export_xyz(path, out, &opt, msg, sizeof msg), msg);
  opt.micro = 1;
  opt.species = MRVI_XYZ_SPECIES_RATE;
  msg[0] = '\0';
  refused_with_message(mrvi_export_xyz(path, out, &opt, msg, sizeof msg), msg);
  msg[0] = '\0';
  refused_with_message(mrvi_export_xdmf(path, out, msg, sizeof msg), msg);

  read_controls(path);
  /* Last: the batch file's row and the writer change the file. */
  read_batch(path);
  resume_writer(path, MRVI_NODE_RESUME);
  resume_writer(path, MRVI_NODE_EXTEND);

  ssize_t open = H5Fget_obj_count(H5F_OBJ_ALL, H5F_OBJ_ALL);
  if (open != 0) {
    fprintf(stderr, "fuzz_h5: %ld HDF5 objects left open\n", (long)open);
    abort();
  }
  unlink(out);
  unlink(path);
  return 0;
}
