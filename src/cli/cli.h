/* The mrvi command-line tool: one function per command (argv[0] is the
 * command name; each returns the process exit status), the help text of
 * each, and the helpers the commands share.
 *
 *   cli.c           main, run, check, help
 *   cli_study.c     converge, stability, timing
 *   cli_optimize.c  optimize, and run --controls (replay)
 *   cli_export.c    export, and the XDMF file beside a run
 *   cli_batch.c     batch
 *   cli_batch_mpi.c batch, converge and stability over MPI ranks
 */
#ifndef MRVI_CLI_H
#define MRVI_CLI_H

#include "batch/batch.h"
#include "mrvi.h"

#include <signal.h>
#include <stddef.h>

extern const char mrvi_usage_converge[];
extern const char mrvi_usage_stability[];
extern const char mrvi_usage_timing[];
extern const char mrvi_usage_optimize[];
extern const char mrvi_usage_export[];
extern const char mrvi_usage_batch[];

int mrvi_cmd_converge(int argc, char **argv);
int mrvi_cmd_stability(int argc, char **argv);
int mrvi_cmd_timing(int argc, char **argv);
int mrvi_cmd_optimize(int argc, char **argv);
int mrvi_cmd_export(int argc, char **argv);
int mrvi_cmd_batch(int argc, char **argv);

/* cli.c: the signal number of SIGINT or SIGTERM once received (0 before),
 * polled by run and optimize; the handlers that set it (a second Ctrl-C
 * terminates at once). */
extern volatile sig_atomic_t mrvi_cli_stop_signal;
void mrvi_cli_install_handlers(void);

/* cli_optimize.c, for `mrvi check`: print the problem of the system's
 * `control:` section, if any (actuators, terminal conditions, algorithm).
 * 0, or 1 when the section is invalid (its message printed). */
int mrvi_cli_check_control(const mrvi_system *sys);

/* After a mistake in a command's arguments: print to stderr only the
 * "Usage:" lines of its help text (up to the first blank line) and where
 * the rest is ("mrvi help CMD"), not the whole help. */
void mrvi_cli_usage_short(const char *cmd, const char *usage);

/* The thread count `value` of option (or variable) `what`: 1..4096 (1
 * alone in a build without OpenMP), or "auto": 0 (mrvi_threads_auto);
 * else -1 after printing why. */
int mrvi_cli_threads(const char *cmd, const char *what, const char *value);

/* path with a trailing ".h5" replaced by ext (or ext appended) into buf. */
void mrvi_cli_replace_extension(const char *path, const char *ext, char *buf,
                                size_t len);

/* Write OUT.xdmf beside the run file OUT.h5 (a line in the summary unless
 * quiet; a warning on stderr when it cannot be written, or when OUT.xdmf
 * is a file mrvi did not write and force is 0).  0 or -1. */
int mrvi_cli_write_xdmf(const char *h5_path, int quiet, int force);

/* MPI ranks (cli_batch_mpi.c; without MPI they run one process).
 *
 * begin: under an MPI launcher with more than one rank, MPI_Init and this
 * rank and the number of ranks (else 0 of 1); -1 with a message where the
 * launcher gave ranks and mrvi was built without MPI. */
int mrvi_batch_mpi_begin(int *rank, int *size, char *msg, size_t len);
/* The default --jobs of a rank: the cores available over the ranks on this
 * machine, at least 1. */
int mrvi_batch_mpi_jobs(void);
/* Rank 0 sends go (0: every rank ends) and, when go, the plan, the master
 * file's path (malloc'd on the other ranks) and --jobs (0: each rank's
 * default) to the other ranks, which receive them; returns go. */
int mrvi_batch_mpi_share(int go, mrvi_batch_plan *plan, const char **master,
                         int *jobs);
/* Run the cases over the ranks: rank 0 hands todo[0..n_todo) out and calls
 * done for every result (its own workers' and the other ranks'); the other
 * ranks run what it hands them.  stop: this rank's signal flag (a rank
 * where it is set ends its running cases at their next macro step and
 * takes no more; on rank 0 none are handed out any more). */
int mrvi_batch_mpi_run(const mrvi_batch_plan *plan, const char *master,
                       const int *todo, int n_todo, int jobs,
                       volatile const int *stop, mrvi_batch_done done,
                       void *user, char *msg, size_t len);
/* mrvi_batch_map over the ranks (collective: every rank calls it with the
 * same items): rank 0 hands the items out, each rank runs its share on its
 * own `jobs` worker processes (forked even for one job), and every rank
 * gets every record in out, or rank 0's failure (its message on rank 0).
 * Without MPI: mrvi_batch_map. */
int mrvi_batch_mpi_map(int n, int jobs, size_t size, mrvi_batch_item fn,
                       void *user, void *out, char *msg, size_t len);
/* Collective: the lowest rank where ok is 0, or -1 when it is 1
 * everywhere. */
int mrvi_batch_mpi_agree(int ok);
/* Collective: rank 0's *tr to every rank (the others' *tr allocated, as
 * mrvi_trajectory_read would); -1 on every rank when rank 0's is NULL. */
int mrvi_batch_mpi_share_trajectory(mrvi_trajectory **tr);
/* Every rank leaves with rank 0's exit status rc (MPI_Finalize). */
int mrvi_batch_mpi_end(int rc);

#endif
