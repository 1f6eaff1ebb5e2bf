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
 * `mpiexec -n R mrvi converge|stability ...` use the same queue for the
 * runs of a study (mrvi_batch_mpi_map): every rank runs the study in step,
 * rank 0 hands out the runs of each step and sends the gathered records
 * to every rank (src/cli/cli_study.c).
 *
 * Messages: a rank asks rank 0 for an item (TAG_ASK: 0; 1 when it leaves,
 * stopped by a signal), rank 0 answers with an item number or -1 (none
 * left, or leaving: the rank asks no more); a finished item
 * goes to rank 0 as its record (TAG_RESULT: a case's mrvi_batch_result, a
 * study run's record; bytes: the ranks run one binary, checked at
 * MPI_Init).  Rank 0 is done when every rank has been told -1 and every
 * item handed out has come back.
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
#include <math.h>
#include <stddef.h>
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

/* What ranks exchanging raw structures must share: the version and the
 * sizes of the structures sent as bytes (the plan's perturbations, a
 * case's result). */
enum { SIGNATURE = 128 };
static void build_signature(char *buf) {
  memset(buf, 0, SIGNATURE);
  snprintf(buf, SIGNATURE, "mrvi %s (perturbation %zu bytes, result %zu)",
           MRVI_VERSION, sizeof(mrvi_batch_perturb), sizeof(mrvi_batch_result));
}

/* A broadcast from rank 0 that the other ranks may wait long for (rank 0
 * computing a reference, or its last runs): waited for by polling every
 * millisecond, since Open MPI's blocking collectives spin and would take
 * a core from the workers. */
static void bcast_patient(void *buf, int count, MPI_Datatype type) {
  MPI_Request req;
  MPI_Ibcast(buf, count, type, 0, MPI_COMM_WORLD, &req);
  for (;;) {
    int flag = 0;
    MPI_Test(&req, &flag, MPI_STATUS_IGNORE);
    if (flag)
      return;
    const struct timespec pause = {0, 1000000};
    nanosleep(&pause, NULL);
  }
}

/* The lowest rank for which bad is set, else -1 (collective). */
static int first_bad_rank(int bad) {
  int rank, first;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  int mine = bad ? rank : INT_MAX;
  MPI_Allreduce(&mine, &first, 1, MPI_INT, MPI_MIN, MPI_COMM_WORLD);
  return first == INT_MAX ? -1 : first;
}

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
  /* Every rank runs rank 0's build: the messages carry raw structures. */
  char mine[SIGNATURE], lead[SIGNATURE];
  build_signature(mine);
  memcpy(lead, mine, SIGNATURE);
  MPI_Bcast(lead, SIGNATURE, MPI_CHAR, 0, MPI_COMM_WORLD);
  const int other = first_bad_rank(memcmp(mine, lead, SIGNATURE) != 0);
  if (other < 0)
    return 0;
  if (*rank == 0)
    snprintf(msg, len,
             "MPI rank %d runs another mrvi build than rank 0 (%s): every "
             "rank must run the same mrvi binary",
             other, lead);
  MPI_Finalize();
  mpi_on = 0;
  return -1;
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
  bcast_patient(head, 2, MPI_INT); /* rank 0 checks every case first */
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

/* ---------------------------------------------------------------------------
 * The queue over ranks, for items of any fixed-size record: the cases of a
 * batch (records mrvi_batch_result) and the runs of a study.  A result
 * message is int item, int ran (0: given back not run), and the record
 * from HEAD on (aligned for any type).
 * ------------------------------------------------------------------------- */
#define HEAD _Alignof(max_align_t)

/* What the ranks share out. */
typedef struct spread {
  size_t size; /* bytes of a record */
  /* Run q's items on this rank's `jobs` worker processes. */
  int (*local)(const void *ctx, int jobs, const mrvi_batch_queue *q, char *msg,
               size_t len);
  const void *ctx;
  /* On rank 0: item i's record, run by `rank`; < 0 stops. */
  int (*done)(void *user, int i, const void *rec, int rank);
  /* On rank 0: item i given back not run by `rank` (no worker process
   * left there); < 0 stops. */
  int (*lost)(void *user, int i, int rank);
  void *user;
  /* The stop flag of this rank's signal handlers (NULL: none): once set,
   * this rank's running items stop early and it takes no more; on rank 0
   * no more are handed out to any rank. */
  volatile const int *stop;
} spread;

/* Rank 0: the queue of items and the ranks still asking. */
typedef struct lead {
  const spread *sp;
  const int *todo; /* NULL: items 0..n_todo-1 */
  int n_todo, next;
  int away; /* items at other ranks */
  int open; /* ranks not yet told "none left" */
  int stop; /* hand out nothing more */
  char *buf;
} lead;

static int halted(const spread *sp) { return sp->stop && *sp->stop; }

static int lead_take(void *user) {
  lead *l = user;
  if (l->stop || halted(l->sp) || l->next >= l->n_todo)
    return -1;
  const int i = l->next++;
  return l->todo ? l->todo[i] : i;
}

static int lead_done(void *user, int i, const void *rec) {
  lead *l = user;
  if (!l->stop && l->sp->done(l->sp->user, i, rec, 0) < 0)
    l->stop = 1;
  return l->stop ? -1 : 0;
}

/* One message of another rank (st: its probe). */
static void lead_serve_one(lead *l, const MPI_Status *st) {
  if (st->MPI_TAG == TAG_ASK) {
    int ask, c;
    MPI_Recv(&ask, 1, MPI_INT, st->MPI_SOURCE, TAG_ASK, MPI_COMM_WORLD,
             MPI_STATUS_IGNORE);
    c = ask ? -1 : lead_take(l);
    MPI_Send(&c, 1, MPI_INT, st->MPI_SOURCE, TAG_CASE, MPI_COMM_WORLD);
    l->away += c >= 0;
    l->open -= c < 0;
    return;
  }
  int head[2];
  MPI_Recv(l->buf, (int)(HEAD + l->sp->size), MPI_BYTE, st->MPI_SOURCE,
           TAG_RESULT, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
  memcpy(head, l->buf, sizeof head);
  l->away--;
  if (!l->stop &&
      (head[1]
           ? l->sp->done(l->sp->user, head[0], l->buf + HEAD, st->MPI_SOURCE)
           : l->sp->lost(l->sp->user, head[0], st->MPI_SOURCE)) < 0)
    l->stop = 1;
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

/* Another rank: items from rank 0, records to it; the items taken and not
 * yet sent back are given back if this rank's workers stop. */
typedef struct follow {
  const spread *sp;
  int done_asking;
  int *held, n_held, cap_held;
  char *buf;
} follow;

static void follow_send(follow *f, int i, const void *rec) {
  const int head[2] = {i, rec != NULL};
  memcpy(f->buf, head, sizeof head);
  if (rec)
    memcpy(f->buf + HEAD, rec, f->sp->size);
  else
    memset(f->buf + HEAD, 0, f->sp->size);
  MPI_Send(f->buf, (int)(HEAD + f->sp->size), MPI_BYTE, 0, TAG_RESULT,
           MPI_COMM_WORLD);
  for (int k = 0; k < f->n_held; k++)
    if (f->held[k] == i) {
      f->held[k] = f->held[--f->n_held];
      break;
    }
}

static int follow_take(void *user) {
  follow *f = user;
  int ask = halted(f->sp), c = -1; /* 1: leaving */
  if (f->done_asking)
    return -1;
  if (f->n_held == f->cap_held) {
    int cap = 2 * f->cap_held + 8;
    int *grown = realloc(f->held, (size_t)cap * sizeof *grown);
    if (!grown)
      return f->done_asking = 1, -1;
    f->held = grown, f->cap_held = cap;
  }
  MPI_Send(&ask, 1, MPI_INT, 0, TAG_ASK, MPI_COMM_WORLD);
  MPI_Recv(&c, 1, MPI_INT, 0, TAG_CASE, MPI_COMM_WORLD, MPI_STATUS_IGNORE);
  f->done_asking = c < 0;
  if (c >= 0)
    f->held[f->n_held++] = c;
  return c;
}

static int follow_done(void *user, int i, const void *rec) {
  follow_send(user, i, rec);
  return 0;
}

/* The items over the ranks: rank 0 hands todo[0..n_todo) (or 0..n_todo-1)
 * out and gets every record; the other ranks run what it hands them. */
static int spread_run(const spread *sp, const int *todo, int n_todo, int jobs,
                      char *msg, size_t len) {
  int rank, size;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  MPI_Comm_size(MPI_COMM_WORLD, &size);
  char *buf = malloc(HEAD + sp->size);
  if (!buf)
    MPI_Abort(MPI_COMM_WORLD, 1);
  int rc;
  if (rank != 0) {
    follow f = {.sp = sp, .buf = buf};
    mrvi_batch_queue q = {
        .next = follow_take, .done = follow_done, .stop = sp->stop, .user = &f};
    rc = sp->local(sp->ctx, jobs, &q, msg, len);
    /* No worker process left here: give back the items held and those
     * still asked for, until rank 0 says none are left (stopped by a
     * signal: say so at once, and leave). */
    while (f.n_held > 0)
      follow_send(&f, f.held[f.n_held - 1], NULL);
    for (int c; (c = follow_take(&f)) >= 0;)
      follow_send(&f, c, NULL);
    free(f.held);
    free(buf);
    return rc;
  }
  lead l = {
      .sp = sp, .todo = todo, .n_todo = n_todo, .open = size - 1, .buf = buf};
  mrvi_batch_queue q = {.next = lead_take,
                        .done = lead_done,
                        .idle = lead_serve,
                        .idle_ms = 2,
                        .stop = sp->stop,
                        .user = &l};
  rc = n_todo > 0 ? sp->local(sp->ctx, jobs, &q, msg, len) : 0;
  if (rc < 0)
    l.stop = 1; /* rank 0's workers failed: no more items go out */
  /* Rank 0's own workers are done: serve the other ranks to the end,
   * probing every millisecond (Open MPI's blocking MPI_Probe spins: it would
   * take a core from the other ranks' workers while their last items run). */
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
  free(buf);
  if (rc == 0 && l.stop)
    rc = MRVI_EIO;
  if (rc == 0 && l.next < n_todo && !halted(sp)) {
    snprintf(msg, len, "every worker process died; %d items not run",
             n_todo - l.next);
    rc = MRVI_EIO;
  }
  return rc;
}

/* The cases of a batch. */
typedef struct batch_spread {
  const mrvi_batch_plan *plan;
  const char *master;
  mrvi_batch_done done;
  void *user;
} batch_spread;

static int batch_local(const void *ctx, int jobs, const mrvi_batch_queue *q,
                       char *msg, size_t len) {
  const batch_spread *b = ctx;
  return mrvi_batch_pool_serve(b->plan, b->master, jobs, q, msg, len);
}

static int batch_done(void *user, int i, const void *rec, int rank) {
  const batch_spread *b = user;
  mrvi_batch_result res;
  (void)i;
  memcpy(&res, rec, sizeof res);
  res.rank = rank;
  return b->done(b->user, &res);
}

static int batch_lost(void *user, int c, int rank) {
  const batch_spread *b = user;
  mrvi_batch_result res;
  memset(&res, 0, sizeof res);
  res.c = c;
  res.rank = rank;
  res.status = MRVI_BATCH_PENDING;
  res.energy_error = res.cost = res.violation = NAN;
  snprintf(res.reason, sizeof res.reason,
           "rank %d has no worker process left (not run: --resume runs it)",
           rank);
  return b->done(b->user, &res);
}

int mrvi_batch_mpi_run(const mrvi_batch_plan *plan, const char *master,
                       const int *todo, int n_todo, int jobs,
                       volatile const int *stop, mrvi_batch_done done,
                       void *user, char *msg, size_t len) {
  if (!mpi_on)
    return mrvi_batch_pool_run(plan, master, todo, n_todo, jobs, stop, done,
                               user, msg, len);
  batch_spread b = {plan, master, done, user};
  const spread sp = {.size = sizeof(mrvi_batch_result),
                     .local = batch_local,
                     .ctx = &b,
                     .done = batch_done,
                     .lost = batch_lost,
                     .user = &b,
                     .stop = stop};
  return spread_run(&sp, n_todo > 0 ? todo : NULL, n_todo, jobs, msg, len);
}

/* ---------------------------------------------------------------------------
 * The runs of a study (mrvi converge, mrvi stability): every rank calls
 * with the same items; records gathered on rank 0, then sent to all.
 * ------------------------------------------------------------------------- */

typedef struct map_spread {
  size_t size;
  mrvi_batch_item fn;
  void *user;
  char *out;
  int done;
  char *msg;
  size_t len;
} map_spread;

static int map_local(const void *ctx, int jobs, const mrvi_batch_queue *q,
                     char *msg, size_t len) {
  const map_spread *m = ctx;
  return mrvi_batch_map_serve(jobs, m->size, m->fn, m->user, q, msg, len);
}

static int map_done(void *user, int i, const void *rec, int rank) {
  map_spread *m = user;
  (void)rank;
  memcpy(m->out + (size_t)i * m->size, rec, m->size);
  m->done++;
  return 0;
}

static int map_lost(void *user, int i, int rank) {
  map_spread *m = user;
  snprintf(m->msg, m->len, "MPI rank %d has no worker process left (item %d)",
           rank, i);
  return -1;
}

int mrvi_batch_mpi_map(int n, int jobs, size_t size, mrvi_batch_item fn,
                       void *user, void *out, char *msg, size_t len) {
  if (!mpi_on)
    return mrvi_batch_map(n, jobs, size, fn, user, out, msg, len);
  int rank;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  map_spread m = {size, fn, user, out, 0, msg, len};
  const spread sp = {.size = size,
                     .local = map_local,
                     .ctx = &m,
                     .done = map_done,
                     .lost = map_lost,
                     .user = &m};
  msg[0] = '\0';
  int rc = spread_run(&sp, NULL, n, jobs, msg, len);
  if (rank == 0 && rc == 0 && m.done < n) {
    snprintf(msg, len, "%d items not run", n - m.done);
    rc = MRVI_EIO;
  }
  /* Every rank leaves with rank 0's records, or its failure. */
  bcast_patient(&rc, 1, MPI_INT);
  if (rc < 0) {
    if (rank != 0)
      snprintf(msg, len, "failed on MPI rank 0");
    return rc;
  }
  for (size_t at = 0, total = (size_t)n * size; at < total;) {
    const size_t chunk = total - at < (1u << 30) ? total - at : (1u << 30);
    MPI_Bcast((char *)out + at, (int)chunk, MPI_BYTE, 0, MPI_COMM_WORLD);
    at += chunk;
  }
  return 0;
}

int mrvi_batch_mpi_agree(int ok) {
  if (!mpi_on)
    return ok ? -1 : 0;
  return first_bad_rank(!ok);
}

int mrvi_batch_mpi_share_trajectory(mrvi_trajectory **tr) {
  if (!mpi_on)
    return *tr ? 0 : -1;
  int rank;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  /* Header: n, n_fast, micro_steps, n_macro, n_micro, macro_step. */
  long head[5] = {0};
  double step = 0.0;
  int ok = rank == 0 && *tr;
  bcast_patient(&ok, 1, MPI_INT);
  if (!ok)
    return -1;
  mrvi_trajectory *t = *tr;
  if (rank == 0) {
    head[0] = t->n, head[1] = t->n_fast, head[2] = t->micro_steps;
    head[3] = t->n_macro, head[4] = t->n_micro;
    step = t->macro_step;
  }
  MPI_Bcast(head, 5, MPI_LONG, 0, MPI_COMM_WORLD);
  MPI_Bcast(&step, 1, MPI_DOUBLE, 0, MPI_COMM_WORLD);
  const long nm = head[3], nu = head[4];
  const int has_micro = nu > 0 && head[1] > 0;
  if (rank != 0) {
    t = calloc(1, sizeof *t);
    if (!t)
      MPI_Abort(MPI_COMM_WORLD, 1);
    t->n = (int)head[0], t->n_fast = (int)head[1];
    t->micro_steps = (int)head[2];
    t->n_macro = nm, t->n_micro = nu;
    t->macro_step = step;
    t->t = malloc((size_t)nm * sizeof(double));
    t->q = malloc((size_t)(nm * t->n) * sizeof(double));
    t->p = malloc((size_t)(nm * t->n) * sizeof(double));
    if (has_micro) {
      t->micro_t = malloc((size_t)nu * sizeof(double));
      t->micro_q = malloc((size_t)(nu * t->n_fast) * sizeof(double));
      t->micro_p = malloc((size_t)(nu * t->n_fast) * sizeof(double));
    }
    if (!t->t || !t->q || !t->p ||
        (has_micro && (!t->micro_t || !t->micro_q || !t->micro_p)))
      MPI_Abort(MPI_COMM_WORLD, 1);
  }
  struct {
    double *a;
    long n;
  } arrays[] = {{t->t, nm},
                {t->q, nm * t->n},
                {t->p, nm * t->n},
                {t->micro_t, has_micro ? nu : 0},
                {t->micro_q, has_micro ? nu * t->n_fast : 0},
                {t->micro_p, has_micro ? nu * t->n_fast : 0}};
  for (size_t k = 0; k < sizeof arrays / sizeof *arrays; k++)
    for (long at = 0; at < arrays[k].n;) {
      const long chunk =
          arrays[k].n - at < (1L << 26) ? arrays[k].n - at : (1L << 26);
      MPI_Bcast(arrays[k].a + at, (int)chunk, MPI_DOUBLE, 0, MPI_COMM_WORLD);
      at += chunk;
    }
  *tr = t;
  return 0;
}

int mrvi_batch_mpi_end(int rc) {
  if (!mpi_on)
    return rc;
  bcast_patient(&rc, 1, MPI_INT);
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
           "(--jobs N uses the cores of one machine), or build with meson "
           "setup -Dmpi=enabled (doc/batch.md)",
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
                       volatile const int *stop, mrvi_batch_done done,
                       void *user, char *msg, size_t len) {
  return mrvi_batch_pool_run(plan, master, todo, n_todo, jobs, stop, done, user,
                             msg, len);
}

int mrvi_batch_mpi_map(int n, int jobs, size_t size, mrvi_batch_item fn,
                       void *user, void *out, char *msg, size_t len) {
  return mrvi_batch_map(n, jobs, size, fn, user, out, msg, len);
}

int mrvi_batch_mpi_agree(int ok) { return ok ? -1 : 0; }

int mrvi_batch_mpi_share_trajectory(mrvi_trajectory **tr) {
  return *tr ? 0 : -1;
}

int mrvi_batch_mpi_end(int rc) { return rc; }

#endif
