/* `mpiexec -n R mrvi batch ...`: the cases of a batch over MPI ranks
 * (doc/batch.md, "Across machines: MPI").
 *
 * MPI distributes work only.  Rank 0 reads the command line, checks every
 * case, creates the master file and writes its rows, as a batch of one
 * process does; it sends the plan to the other ranks and then serves them
 * case numbers from one queue (a manager-worker queue: cases differ in
 * cost by orders of magnitude).  Every rank, rank 0 included, runs its
 * cases on its own --jobs worker processes (src/batch/pool.c), which write
 * each case file with the serial HDF5 library, exactly as without MPI; a
 * rank sends each result to rank 0, which writes the row.  So no parallel
 * HDF5 is needed, every case file keeps the run writer's SWMR crash safety
 * (the MPI-IO driver has none), and the files equal a serial batch's.
 *
 * Messages: a rank asks rank 0 for a case (TAG_ASK), rank 0 answers with a
 * case number or -1 (none left: the rank asks no more); a finished case
 * goes to rank 0 as its mrvi_batch_result (TAG_RESULT, bytes: the ranks
 * run one binary).  Rank 0 is done when every rank has been told -1 and
 * every case handed out has come back.
 *
 * The worker processes are forked after MPI_Init; they never call MPI and
 * leave with _exit, which Open MPI supports outside its InfiniBand
 * transports (doc/batch.md).
 *
 * Built without MPI (meson -Dmpi=disabled, or no MPI found), the functions
 * below refuse a run under an MPI launcher with more than one rank: R
 * copies of a serial batch would each run every case into the same
 * files. */
#include "batch/batch.h"
#include "cli.h"

#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* The size an MPI launcher gave this process (Open MPI's mpiexec, a PMI
 * launcher: MPICH's hydra, or Slurm's srun, which says it in
 * SLURM_STEP_NUM_TASKS whatever its --mpi plugin), else 1. */
static int launcher_size(void) {
  const char *names[] = {"OMPI_COMM_WORLD_SIZE", "PMI_SIZE",
                         "SLURM_STEP_NUM_TASKS"};
  for (size_t i = 0; i < sizeof names / sizeof *names; i++) {
    const char *v = getenv(names[i]);
    if (v && atoi(v) > 0)
      return atoi(v);
  }
  return 1;
}

#ifdef MRVI_MPI
#include <mpi.h>

enum { TAG_ASK = 1, TAG_CASE, TAG_RESULT };

static int mpi_on; /* MPI_Init was called */

int mrvi_batch_mpi_begin(int *rank, int *size, char *msg, size_t len) {
  *rank = 0;
  *size = 1;
  msg[0] = '\0';
  (void)len;
  if (launcher_size() <= 1)
    return 0; /* one process: no MPI at all */
  if (MPI_Init(NULL, NULL) != MPI_SUCCESS) {
    snprintf(msg, len, "MPI_Init failed");
    return -1;
  }
  mpi_on = 1;
  MPI_Comm_rank(MPI_COMM_WORLD, rank);
  MPI_Comm_size(MPI_COMM_WORLD, size);
  return 0;
}

int mrvi_batch_mpi_jobs(void) {
  int local = 1;
  if (mpi_on) {
    /* The ranks on this machine share its cores. */
    MPI_Comm node;
    MPI_Comm_split_type(MPI_COMM_WORLD, MPI_COMM_TYPE_SHARED, 0, MPI_INFO_NULL,
                        &node);
    MPI_Comm_size(node, &local);
    MPI_Comm_free(&node);
  }
  int jobs = mrvi_batch_cores() / (local > 0 ? local : 1);
  return jobs > 0 ? jobs : 1;
}

/* A broadcast from rank 0 of n bytes (sent first as a count). */
static void share_bytes(char **buf, size_t *n) {
  unsigned long long count = *n;
  MPI_Bcast(&count, 1, MPI_UNSIGNED_LONG_LONG, 0, MPI_COMM_WORLD);
  if (count > (unsigned long long)INT_MAX)
    MPI_Abort(MPI_COMM_WORLD, 1);
  if (!*buf && !(*buf = malloc(count ? count : 1)))
    MPI_Abort(MPI_COMM_WORLD, 1);
  *n = count;
  MPI_Bcast(*buf, (int)count, MPI_BYTE, 0, MPI_COMM_WORLD);
}

int mrvi_batch_mpi_share(int go, mrvi_batch_plan *plan, const char **master,
                         int *jobs) {
  if (!mpi_on)
    return go;
  int rank, head[2] = {go, *jobs};
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  MPI_Bcast(head, 2, MPI_INT, 0, MPI_COMM_WORLD);
  if (!head[0])
    return 0;
  *jobs = head[1];
  char *buf = NULL, *path = rank == 0 ? (char *)*master : NULL;
  size_t n = 0, np = path ? strlen(path) + 1 : 0;
  if (rank == 0 && mrvi_batch_plan_pack(plan, &buf, &n) < 0)
    MPI_Abort(MPI_COMM_WORLD, 1);
  share_bytes(&buf, &n);
  share_bytes(&path, &np);
  if (rank != 0 && (mrvi_batch_plan_unpack(buf, n, plan) < 0 || np < 1 ||
                    path[np - 1] != '\0'))
    MPI_Abort(MPI_COMM_WORLD, 1);
  free(buf);
  if (rank != 0)
    *master = path;
  return 1;
}

/* Rank 0: the queue of cases and the ranks still asking. */
typedef struct lead {
  const int *todo;
  int n_todo, next;
  int away; /* cases at other ranks */
  int open; /* ranks not yet told "none left" */
  int stop; /* the master file failed: hand out nothing more */
  mrvi_batch_done done;
  void *user;
} lead;

static int lead_take(void *user) {
  lead *l = user;
  return !l->stop && l->next < l->n_todo ? l->todo[l->next++] : -1;
}

static int lead_done(void *user, const mrvi_batch_result *res) {
  lead *l = user;
  if (!l->stop && l->done(l->user, res) < 0)
    l->stop = 1;
  return l->stop ? -1 : 0;
}

/* One message of another rank (st: its probe). */
static void lead_serve_one(lead *l, const MPI_Status *st) {
  if (st->MPI_TAG == TAG_ASK) {
    int ask, c;
    MPI_Recv(&ask, 1, MPI_INT, st->MPI_SOURCE, TAG_ASK, MPI_COMM_WORLD,
             MPI_STATUS_IGNORE);
    c = lead_take(l);
    MPI_Send(&c, 1, MPI_INT, st->MPI_SOURCE, TAG_CASE, MPI_COMM_WORLD);
    l->away += c >= 0;
    l->open -= c < 0;
  } else {
    mrvi_batch_result res;
    MPI_Recv(&res, (int)sizeof res, MPI_BYTE, st->MPI_SOURCE, TAG_RESULT,
             MPI_COMM_WORLD, MPI_STATUS_IGNORE);
    l->away--;
    lead_done(l, &res);
  }
}

/* The messages waiting (the pool's idle hook). */
static int lead_serve(void *user) {
  lead *l = user;
  for (;;) {
    int flag = 0;
    MPI_Status st;
    MPI_Iprobe(MPI_ANY_SOURCE, MPI_ANY_TAG, MPI_COMM_WORLD, &flag, &st);
    if (!flag)
      return 0;
    lead_serve_one(l, &st);
  }
}

/* Another rank: cases from rank 0, results to it. */
typedef struct follow {
  int rank, done_asking;
} follow;

static int follow_take(void *user) {
  follow *f = user;
  int ask = 0, c = -1;
  if (f->done_asking)
    return -1;
  MPI_Send(&ask, 1, MPI_INT, 0, TAG_ASK, MPI_COMM_WORLD);
  MPI_Recv(&c, 1, MPI_INT, 0, TAG_CASE, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
  f->done_asking = c < 0;
  return c;
}

static int follow_done(void *user, const mrvi_batch_result *res) {
  const follow *f = user;
  mrvi_batch_result r = *res;
  r.rank = f->rank;
  MPI_Send(&r, (int)sizeof r, MPI_BYTE, 0, TAG_RESULT, MPI_COMM_WORLD);
  return 0;
}

int mrvi_batch_mpi_run(const mrvi_batch_plan *plan, const char *master,
                       const int *todo, int n_todo, int jobs,
                       mrvi_batch_done done, void *user, char *msg,
                       size_t len) {
  if (!mpi_on)
    return mrvi_batch_pool_run(plan, master, todo, n_todo, jobs, done, user,
                               msg, len);
  int rank, size;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  MPI_Comm_size(MPI_COMM_WORLD, &size);
  if (rank != 0) {
    follow f = {.rank = rank};
    mrvi_batch_queue q = {.next = follow_take, .done = follow_done, .user = &f};
    int rc = mrvi_batch_pool_serve(plan, master, jobs, &q, msg, len);
    /* No worker process left here: give back the cases still asked for,
     * pending, until rank 0 says none are left. */
    for (int c; (c = follow_take(&f)) >= 0;) {
      mrvi_batch_result res;
      memset(&res, 0, sizeof res);
      res.c = c;
      res.status = MRVI_BATCH_PENDING;
      snprintf(res.reason, sizeof res.reason,
               "rank %d has no worker process left (not run: --resume runs "
               "it)",
               rank);
      follow_done(&f, &res);
    }
    return rc;
  }
  lead l = {.todo = todo,
            .n_todo = n_todo,
            .open = size - 1,
            .done = done,
            .user = user};
  mrvi_batch_queue q = {.next = lead_take,
                        .done = lead_done,
                        .idle = lead_serve,
                        .idle_ms = 2,
                        .user = &l};
  int rc =
      n_todo > 0 ? mrvi_batch_pool_serve(plan, master, jobs, &q, msg, len) : 0;
  /* Rank 0's own workers are done: serve the other ranks to the end,
   * probing every millisecond (Open MPI's blocking MPI_Probe spins: it would
   * take a core from the other ranks' workers while their last cases run). */
  while (l.away > 0 || l.open > 0) {
    const struct timespec pause = {0, 1000000};
    int flag = 0;
    MPI_Status st;
    MPI_Iprobe(MPI_ANY_SOURCE, MPI_ANY_TAG, MPI_COMM_WORLD, &flag, &st);
    if (flag)
      lead_serve_one(&l, &st);
    else
      nanosleep(&pause, NULL);
  }
  if (rc == 0 && l.stop)
    rc = MRVI_EIO;
  if (rc == 0 && l.next < n_todo) {
    snprintf(msg, len, "every worker process died; %d cases not run",
             n_todo - l.next);
    rc = MRVI_EIO;
  }
  return rc;
}

int mrvi_batch_mpi_end(int rc) {
  if (!mpi_on)
    return rc;
  MPI_Bcast(&rc, 1, MPI_INT, 0, MPI_COMM_WORLD);
  MPI_Finalize();
  mpi_on = 0;
  return rc;
}

#else /* built without MPI */

int mrvi_batch_mpi_begin(int *rank, int *size, char *msg, size_t len) {
  *rank = 0;
  *size = 1;
  msg[0] = '\0';
  int r = launcher_size();
  if (r <= 1)
    return 0;
  /* One message, from the launcher's rank 0. */
  const char *me = getenv("OMPI_COMM_WORLD_RANK");
  if (!me)
    me = getenv("PMI_RANK");
  if (!me)
    me = getenv("SLURM_PROCID");
  if (me && atoi(me) != 0)
    return -1;
  snprintf(msg, len,
           "started by an MPI launcher with %d ranks, but this mrvi was built "
           "without MPI: every rank would run every case.  Run one process "
           "(mrvi batch ... --jobs N uses the cores of one machine), or "
           "build with meson setup -Dmpi=enabled (doc/batch.md)",
           r);
  return -1;
}

int mrvi_batch_mpi_jobs(void) { return mrvi_batch_cores(); }

int mrvi_batch_mpi_share(int go, mrvi_batch_plan *plan, const char **master,
                         int *jobs) {
  (void)plan, (void)master, (void)jobs;
  return go;
}

int mrvi_batch_mpi_run(const mrvi_batch_plan *plan, const char *master,
                       const int *todo, int n_todo, int jobs,
                       mrvi_batch_done done, void *user, char *msg,
                       size_t len) {
  return mrvi_batch_pool_run(plan, master, todo, n_todo, jobs, done, user, msg,
                             len);
}

int mrvi_batch_mpi_end(int rc) { return rc; }

#endif
