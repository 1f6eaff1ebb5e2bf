/* What src/batch offers the command-line tool: `mrvi batch` (doc/batch.md).
 * A batch is a table of cases, each a `mrvi run` of one description with
 * its own overrides ("KEY=VALUE", as `--set`) and, for an ensemble, a seed
 * that perturbs the initial velocities.  plan.c builds and checks the
 * table, pool.c runs cases in worker processes (fork, before any thread)
 * and reports each result back through a pipe.  The master file (case
 * table and links to the case files) is written by src/io (io.h).  Nothing
 * here prints or exits; every function returns a status with a message. */
#ifndef MRVI_BATCH_H
#define MRVI_BATCH_H

#include "io/io.h"

#include <stddef.h>
#include <stdint.h>

/* ---------------------------------------------------------------------------
 * The plan (plan.c)
 * ------------------------------------------------------------------------- */

/* One --vary: a key and its values (text, as --set takes them). */
typedef struct mrvi_batch_axis {
  char *key;
  int n;
  char **values;
} mrvi_batch_axis;

/* Parse "KEY=V1,V2,..." or "KEY=linspace(a,b,n)" / "KEY=logspace(a,b,n)"
 * (n values from a to b, resp. from 10^a to 10^b, printed with %.17g).
 * MRVI_EINVAL with a message. */
int mrvi_batch_axis_parse(const char *spec, mrvi_batch_axis *axis, char *msg,
                          size_t len);
void mrvi_batch_axis_clear(mrvi_batch_axis *axis);

/* Build the case table: the Cartesian product of the axes (the last axis
 * varies fastest), or with zip the i-th values of every axis together
 * (equal lengths), each repeated for seeds 0..n_seeds-1 when n_seeds > 0
 * (seed fastest).  command: MRVI_BATCH_RUN or MRVI_BATCH_OPTIMIZE; pert:
 * the perturbations of the seeded cases (control_std, with optimize, the
 * initial guess: a multi-start).  The plan owns copies of everything. */
int mrvi_batch_plan_build(mrvi_batch_plan *plan, const char *description,
                          const char *source, const mrvi_batch_axis *axes,
                          int n_axes, int zip, int n_seeds, int command,
                          const mrvi_batch_perturb *pert, char *msg,
                          size_t len);

/* Load every case's description with its overrides (and perturbation)
 * before any case runs: the first refused case gives MRVI_EPARSE with
 * "case C (KEY=VALUE ...): loader message" in msg. */
int mrvi_batch_plan_check(const mrvi_batch_plan *plan, char *msg, size_t len);

/* The system of case c: the plan's description with the case's overrides. */
int mrvi_batch_case_load(const mrvi_batch_plan *plan, int c, mrvi_system **out,
                         char *msg, size_t len);

/* The plan as one buffer (malloc'd, *size bytes) and back, to hand it to
 * other processes of the same program (MPI ranks).  unpack checks every
 * count and string against the buffer's size: MRVI_EINVAL otherwise. */
int mrvi_batch_plan_pack(const mrvi_batch_plan *plan, char **buf, size_t *size);
int mrvi_batch_plan_unpack(const char *buf, size_t size, mrvi_batch_plan *plan);

/* ---------------------------------------------------------------------------
 * Ensembles (plan.c): a counter-based generator, so that a case's random
 * numbers depend on its seed alone (not on the job that runs it, nor on the
 * other cases).  Number i of seed s is splitmix64 applied to
 * (s + 1) * 0x9E3779B97F4A7C15 + i (Steele, Lea, Flood 2014); normals by
 * Box-Muller from numbers 2j and 2j+1.
 * ------------------------------------------------------------------------- */
uint64_t mrvi_batch_random(uint64_t seed, uint64_t i);
/* Streams: the normal numbers j of one use of a seed are numbers
 * STREAM + j, so that the uses do not share numbers (j < 2^40). */
#define MRVI_BATCH_STREAM_VELOCITIES 0ull
#define MRVI_BATCH_STREAM_CONTROLS (1ull << 40)
#define MRVI_BATCH_STREAM_POSITIONS (2ull << 40)
#define MRVI_BATCH_STREAM_ROTATIONS (3ull << 40)

/* ---------------------------------------------------------------------------
 * Perturbations (perturb.c): positions, body rotations and velocities of
 * a seeded case, onto the constraints (doc/batch.md, Ensembles).
 * ------------------------------------------------------------------------- */

/* Perturb sys's initial state by seed (nothing for seed < 0); *dof gets
 * the degrees of freedom of a thermal case (0 otherwise).  MRVI_EINVAL
 * with a message when the projection onto the constraints fails. */
int mrvi_batch_perturb_apply(mrvi_system *sys, long seed,
                             const mrvi_batch_perturb *pt, int *dof, char *msg,
                             size_t len);
/* Say in sys's description (its run file's /model/description) how the
 * initial state differs from the text: YAML comments appended. */
int mrvi_batch_perturb_note(mrvi_system *sys, long seed,
                            const mrvi_batch_perturb *pt, int dof);
/* Standard normal number j of seed s. */
double mrvi_batch_normal(uint64_t seed, uint64_t j);

/* ---------------------------------------------------------------------------
 * Running cases (pool.c)
 * ------------------------------------------------------------------------- */

/* Run case c of the plan into the run file `path` (the layout of `mrvi
 * run`, written by mrvi_writer) and fill *res.  A case that fails (load,
 * Newton, non-finite state) is a result with status MRVI_BATCH_FAILED and
 * its reason, not an error of the batch.  stop (NULL: none) is polled
 * before every macro step (an optimize case: after every evaluation);
 * once non-zero the case stops there, its file closed and valid with the
 * reason ("interrupted after ..."), and the result is MRVI_BATCH_PENDING
 * with that reason (--resume runs it again). */
void mrvi_batch_case_run(const mrvi_batch_plan *plan, int c, const char *path,
                         volatile const int *stop, mrvi_batch_result *res);

/* Called by the pool in the parent for every finished case; a status < 0
 * stops the batch (no new cases are handed out). */
typedef int (*mrvi_batch_done)(void *user, const mrvi_batch_result *res);

/* Run the cases todo[0..n_todo) on `jobs` worker processes forked at
 * once (call before any thread is started and with no HDF5 file open), a
 * case handed to the next free worker, into the run file
 * mrvi_batch_case_file(master, c).  A worker that dies mid-case (killed)
 * gives that case a result with status MRVI_BATCH_PENDING (for --resume);
 * the cases left go to the workers left.  The
 * parent calls done for each result as it arrives.  stop: as the queue's
 * (the cases not handed out get no result; 0 is returned). */
int mrvi_batch_pool_run(const mrvi_batch_plan *plan, const char *master,
                        const int *todo, int n_todo, int jobs,
                        volatile const int *stop, mrvi_batch_done done,
                        void *user, char *msg, size_t len);

/* Where a pool's items come from and where their records go, for a pool
 * that does not own its list of items (an MPI rank asks its manager for
 * each: src/cli/cli_batch_mpi.c). */
typedef struct mrvi_batch_queue {
  /* The next item to run, or -1: none left (not asked again). */
  int (*next)(void *user);
  /* Item i's record (a case's: its mrvi_batch_result); < 0 stops the
   * pool. */
  int (*done)(void *user, int i, const void *rec);
  /* When set: called at least every idle_ms milliseconds while workers
   * run (to serve other ranks); < 0 stops the batch. */
  int (*idle)(void *user);
  int idle_ms;
  /* When set (a flag the caller's signal handler raises; the library
   * installs none): polled while workers run.  Once non-zero no item is
   * handed out and the running cases stop at their next macro step (the
   * pool copies the flag into a page shared with its workers, which their
   * runs poll); their results still come to done.  mrvi_batch_pool_serve
   * only (a map ignores it). */
  volatile const int *stop;
  void *user;
} mrvi_batch_queue;

/* mrvi_batch_pool_run with cases from q->next: `jobs` workers forked at
 * once, each handed q->next() whenever it is free, until q->next() says
 * none are left and every worker is idle. */
int mrvi_batch_pool_serve(const mrvi_batch_plan *plan, const char *master,
                          int jobs, const mrvi_batch_queue *q, char *msg,
                          size_t len);

/* One item of mrvi_batch_map: fill the record `out` (zeroed, `size` bytes,
 * plain data: it is copied between processes) for item i. */
typedef void (*mrvi_batch_item)(void *user, int i, void *out);

/* mrvi_batch_pool_serve for items: `jobs` workers forked at once (even
 * one), each running fn on the item q->next() hands it; q->done gets each
 * record.  A worker that dies mid-item stops the pool (the others are
 * killed): MRVI_EIO with the signal or exit status and the item in msg. */
int mrvi_batch_map_serve(int jobs, size_t size, mrvi_batch_item fn, void *user,
                         const mrvi_batch_queue *q, char *msg, size_t len);

/* Items 0..n-1 on `jobs` worker processes forked at once (call before any
 * thread is started and with no HDF5 file open): item i's record goes to
 * out + i * size in this process, whichever worker ran it, so that the
 * records do not depend on jobs.  Items are handed out in order to the
 * next free worker.  jobs <= 1 runs fn here, in order, without forking.
 * A worker that dies mid-item stops the map: MRVI_EIO with the signal or
 * exit status and the item in msg. */
int mrvi_batch_map(int n, int jobs, size_t size, mrvi_batch_item fn, void *user,
                   void *out, char *msg, size_t len);

/* The cores this process may run on (sched_getaffinity, else
 * sysconf(_SC_NPROCESSORS_ONLN)), at least 1. */
int mrvi_batch_cores(void);

#endif
