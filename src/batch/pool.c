/* Running the cases of `mrvi batch` (doc/batch.md): one case into its run
 * file, and a pool of worker processes fed case by case.
 *
 * Workers are forked before the parent starts any thread or opens any HDF5
 * file, so a worker inherits no lock and no half-written state; each
 * reads item indices (cases) from its task pipe, runs them and writes, in
 * one write per item, the index and a fixed-size record (a case's result)
 * to its result pipe, and leaves with _exit (no atexit handler of the
 * parent's libraries runs in it).  The parent hands an item to whichever
 * worker answers first (cases differ in cost by orders of magnitude: a
 * queue, not a static split) and closes a worker's task pipe when none are
 * left.  One loop (serve) runs the cases of a batch and the items of
 * mrvi_batch_map alike; they differ in what a worker's death means.  A
 * batch's stop flag (the caller's: SIGINT, SIGTERM) reaches the workers
 * through a shared page that their runs poll between macro steps. */
#define _GNU_SOURCE
#include "batch/batch.h"

#include <errno.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/wait.h>
#ifdef __linux__
#include <sys/prctl.h>
#endif
#include <unistd.h>

int mrvi_batch_cores(void) { return mrvi_cores(); }

/* An optimize case's output and problem, for its evaluations, and the
 * batch's stop flag (NULL: none). */
typedef struct case_progress {
  mrvi_ocp_output *out;
  const mrvi_ocp *o;
  volatile const int *stop;
} case_progress;

/* Each evaluation of an optimize case: a row of /optimizer/history and, at
 * most every output.flush_interval, the progress file (what a kill leaves;
 * a failure to write it does not stop the case: close writes the file);
 * the stop flag set stops the optimiser (MRVI_EINTERRUPTED). */
static int on_evaluation(void *data, int it, double cost, double viol,
                         double gnorm, double kkt) {
  (void)it;
  case_progress *cp = data;
  char msg[1024];
  if (mrvi_ocp_output_iteration(cp->out, cost, viol, gnorm, kkt) < 0)
    return 1;
  mrvi_ocp_output_progress(cp->out, mrvi_ocp_best_iterate(cp->o), msg,
                           sizeof msg);
  return cp->stop && *cp->stop;
}

/* An optimize case into `path`, as `mrvi optimize FILE --set ... -o path`
 * writes it, progress files included (the first before the optimiser
 * starts): completed when the optimiser converged, pending when stopped by
 * the flag, else failed with the status (max_evaluations,
 * terminal_not_met, ...). */
static void case_optimize(mrvi_system *sys, const char *path,
                          volatile const int *stop, mrvi_batch_result *res) {
  char msg[4096];
  mrvi_ocp *o = NULL;
  double *u = NULL;
  mrvi_ocp_output *out = NULL;
  if (mrvi_ocp_load(sys, &o, &u, msg, sizeof msg) < 0 ||
      mrvi_ocp_output_open(path, sys, o, &out, msg, sizeof msg) < 0) {
    mrvi_fmt(res->reason, sizeof res->reason, "%s", msg);
    free(u);
    mrvi_ocp_free(o);
    return;
  }
  case_progress cp = {.out = out, .o = o, .stop = stop};
  mrvi_ocp_set_callback(o, on_evaluation, &cp);
  mrvi_ocp_output_start(out, u, msg, sizeof msg);
  const double t0 = mrvi_clock();
  mrvi_ocp_result r;
  memset(&r, 0, sizeof r); /* a failure before NLopt starts sets nothing */
  r.cost = r.violation = NAN;
  const int st = mrvi_ocp_solve(o, u, &r);
  res->wall_time = mrvi_clock() - t0;
  if (!r.status[0]) /* failed before NLopt started */
    mrvi_fmt(r.status, sizeof r.status, "%s", "failed");
  res->steps = mrvi_ocp_n_steps(o);
  res->cost = r.cost;
  res->violation = r.violation;
  res->evaluations = r.evaluations;
  mrvi_fmt(res->nlopt, sizeof res->nlopt, "%s", r.nlopt_name);
  if (st == 0)
    mrvi_fmt(res->reason, sizeof res->reason, "completed");
  else
    mrvi_fmt(res->reason, sizeof res->reason, "%s: %s", r.status,
             mrvi_ocp_errmsg(o));
  if (mrvi_ocp_output_close(out, u, &r, r.status, msg, sizeof msg) < 0) {
    mrvi_fmt(res->reason, sizeof res->reason, "%s", msg);
  } else if (st == 0) {
    res->status = MRVI_BATCH_COMPLETED;
  } else if (st == MRVI_EINTERRUPTED) {
    res->status = MRVI_BATCH_PENDING;
  }
  free(u);
  mrvi_ocp_free(o);
}

void mrvi_batch_case_run(const mrvi_batch_plan *plan, int c, const char *path,
                         volatile const int *stop, mrvi_batch_result *res) {
  memset(res, 0, sizeof *res);
  res->c = c;
  res->status = MRVI_BATCH_FAILED;
  res->energy_error = NAN;
  res->cost = res->violation = NAN;
  char msg[4096];
  mrvi_system *sys = NULL;
  if (mrvi_batch_case_load(plan, c, &sys, msg, sizeof msg) < 0) {
    mrvi_fmt(res->reason, sizeof res->reason, "%s", msg);
    return;
  }
  if (plan->threads > 0)
    sys->settings.threads = plan->threads;
  if (plan->command == MRVI_BATCH_OPTIMIZE) {
    case_optimize(sys, path, stop, res);
    mrvi_system_free(sys);
    return;
  }
  /* The options of `mrvi run` for this description. */
  mrvi_writer_options opt = mrvi_system_writer_options(sys);
  sys->settings.micro_last_only = !opt.micro && !opt.micro_slow; /* as run */
  opt.force = 1;
  mrvi_writer *w = NULL;
  if (mrvi_writer_open(path, sys->model, &sys->settings, &opt, &w, msg,
                       sizeof msg) < 0 ||
      !w) {
    mrvi_fmt(res->reason, sizeof res->reason, "%s", msg);
    mrvi_system_free(sys);
    return;
  }
  mrvi_summary sum;
  memset(&sum, 0, sizeof sum);
  int st =
      mrvi_run(sys->model, &sys->settings, mrvi_writer_observe, w, stop, &sum);
  mrvi_writer_set_summary(w, &sum);
  const char *reason = "completed";
  if (st < 0)
    reason = sum.message[0] ? sum.message : mrvi_strerror(st);
  char close_msg[1024] = "";
  int cst = mrvi_writer_close(w, reason, close_msg, sizeof close_msg);
  res->steps = sum.steps;
  res->wall_time = sum.wall_time;
  res->energy_error = sum.max_rel_energy_error;
  if (cst == 0 && (st == 0 || st == MRVI_EINTERRUPTED))
    res->status = st == 0 ? MRVI_BATCH_COMPLETED : MRVI_BATCH_PENDING;
  mrvi_fmt(res->reason, sizeof res->reason, "%s",
           cst < 0 && st == 0 ? close_msg : reason);
  mrvi_system_free(sys);
}

/* Read or write all of n bytes (EINTR retried); 0, or -1 (short, EOF). */
static int read_all(int fd, void *buf, size_t n) {
  char *b = buf;
  while (n > 0) {
    ssize_t r = read(fd, b, n);
    if (r < 0 && errno == EINTR)
      continue;
    if (r <= 0)
      return -1;
    b += r;
    n -= (size_t)r;
  }
  return 0;
}

static int write_all(int fd, const void *buf, size_t n) {
  const char *b = buf;
  while (n > 0) {
    ssize_t r = write(fd, b, n);
    if (r < 0 && errno == EINTR)
      continue;
    if (r <= 0)
      return -1;
    b += r;
    n -= (size_t)r;
  }
  return 0;
}

/* ---------------------------------------------------------------------------
 * Worker processes: item indices in, fixed-size records out.  The cases of
 * a batch are items whose record is their mrvi_batch_result; the study
 * commands' runs are items of their own records (mrvi_batch_map).
 * ------------------------------------------------------------------------- */

/* A worker's message: the item's index, then its record from HEAD on (a
 * record of any type is aligned there: malloc's alignment). */
#define HEAD _Alignof(max_align_t)

/* A worker: item indices from fd_in until it closes; for each, the index
 * followed by its record (zeroed, then filled by fn) to fd_out in one
 * write. */
static void worker(size_t size, mrvi_batch_item fn, void *user, int fd_in,
                   int fd_out) {
  char *msg = malloc(HEAD + size);
  int i;
  while (msg && read_all(fd_in, &i, sizeof i) == 0) {
    memset(msg, 0, HEAD + size);
    memcpy(msg, &i, sizeof i);
    fn(user, i, msg + HEAD);
    if (write_all(fd_out, msg, HEAD + size) < 0)
      break;
  }
  free(msg);
}

typedef struct slot {
  pid_t pid;
  int task, result; /* the parent's ends */
  int busy;         /* item being run, or -1 */
} slot;

/* Close a worker's task pipe: it leaves after its current item. */
static void slot_retire(slot *s) {
  if (s->task >= 0)
    close(s->task);
  s->task = -1;
}

/* Fork up to `jobs` workers running fn into w[0..); the number started
 * (0: errno says why).  The caller ignores SIGPIPE: a worker that died
 * closes its pipe, and writing to it must fail, not kill the parent. */
static int start_workers(slot *w, int jobs, size_t size, mrvi_batch_item fn,
                         void *user) {
  fflush(NULL); /* nothing buffered is written twice */
  int started = 0;
  for (int k = 0; k < jobs; k++) {
    int tp[2], rp[2];
    if (pipe(tp) < 0)
      break;
    if (pipe(rp) < 0) {
      close(tp[0]), close(tp[1]);
      break;
    }
    const pid_t parent = getpid();
    pid_t pid = fork();
    if (pid == 0) {
#ifdef __linux__
      /* A worker dies with the parent (SIGKILL of the batch): no orphan
       * goes on writing a case that --resume runs again. */
      if (prctl(PR_SET_PDEATHSIG, SIGKILL) < 0 || getppid() != parent)
        _exit(1);
#endif
      for (int m = 0; m < started; m++) /* the other workers' pipes */
        close(w[m].task), close(w[m].result);
      close(tp[1]), close(rp[0]);
      worker(size, fn, user, tp[0], rp[1]);
      _exit(0);
    }
    close(tp[0]), close(rp[1]);
    if (pid < 0) {
      close(tp[1]), close(rp[0]);
      break;
    }
    w[started++] =
        (slot){.pid = pid, .task = tp[1], .result = rp[0], .busy = -1};
  }
  return started;
}

/* A pool's queue and what it does with an item that did not come back. */
typedef struct feed {
  const mrvi_batch_queue *q;
  /* Item i lost: its worker died with wait status ws, or (ws < 0) no
   * worker was left to take it.  < 0 stops the pool (msg set). */
  int (*lost)(const mrvi_batch_queue *q, int i, int ws, char *msg, size_t len);
  int kill_on_stop; /* a stop kills the workers (else each ends its item) */
  /* When q->stop is set: a flag the workers share (mmap'd before the fork),
   * set once *q->stop is seen, that their items poll. */
  volatile int *relay;
} feed;

/* `jobs` workers forked at once, each handed f->q->next() whenever it is
 * free, until the queue says none are left and every worker is idle, or,
 * once *q->stop is seen, until the items running come back (halted: no
 * more are handed out, and the workers are asked through f->relay to end
 * theirs early). */
static int serve(int jobs, size_t size, mrvi_batch_item fn, void *user,
                 const feed *f, char *msg, size_t len) {
  const mrvi_batch_queue *q = f->q;
  mrvi_fmt(msg, len, "%s", "");
  if (jobs < 1)
    jobs = 1;
  if (size > (size_t)1 << 30) {
    mrvi_fmt(msg, len, "record of %zu bytes too large", size);
    return MRVI_EINVAL;
  }
  slot *w = calloc((size_t)jobs, sizeof *w);
  struct pollfd *pfd = calloc((size_t)jobs, sizeof *pfd);
  char *rec = malloc(HEAD + size);
  if (!w || !pfd || !rec) {
    free(w), free(pfd), free(rec);
    mrvi_fmt(msg, len, "out of memory");
    return MRVI_ENOMEM;
  }
  struct sigaction ign = {.sa_handler = SIG_IGN}, old_pipe;
  sigemptyset(&ign.sa_mask);
  sigaction(SIGPIPE, &ign, &old_pipe);
  const int started = start_workers(w, jobs, size, fn, user);
  int rc = 0, stop = 0, exhausted = 0, halted = 0;
  int carry = -1; /* an item taken from q whose worker was gone */
  if (started == 0) {
    mrvi_fmt(msg, len, "cannot start a worker process: %s", strerror(errno));
    rc = MRVI_EIO;
    stop = 1;
  }
  for (;;) {
    if (!halted && q->stop && *q->stop) {
      halted = 1;
      if (f->relay)
        *f->relay = 1;
    }
    /* Hand out items to idle workers (none once halted). */
    int running = 0;
    for (int k = 0; k < started; k++) {
      slot *s = &w[k];
      if (s->busy < 0 && halted) {
        slot_retire(s);
      } else if (s->busy < 0 && s->task >= 0) {
        int i = carry;
        if (i < 0 && !stop && !exhausted && (i = q->next(q->user)) < 0)
          exhausted = 1;
        carry = -1;
        if (i >= 0 && write_all(s->task, &i, sizeof i) == 0)
          s->busy = i;
        else
          carry = i, slot_retire(s);
      }
      running += s->busy >= 0;
    }
    if (running == 0 || (stop && f->kill_on_stop))
      break;
    int np = 0;
    for (int k = 0; k < started; k++)
      if (w[k].busy >= 0)
        pfd[np++] = (struct pollfd){.fd = w[k].result, .events = POLLIN};
    /* A signal that sets *q->stop interrupts poll (EINTR); the timeout
     * covers one that lands just before it. */
    const int wait_ms = q->idle ? q->idle_ms : q->stop && !halted ? 50 : -1;
    int ready = poll(pfd, (nfds_t)np, wait_ms);
    if (ready < 0 && errno != EINTR) {
      mrvi_fmt(msg, len, "poll: %s", strerror(errno));
      rc = MRVI_EIO;
      stop = 1;
      break;
    }
    if (q->idle && !stop && q->idle(q->user) < 0) {
      stop = 1;
      rc = MRVI_EIO;
    }
    if (ready <= 0)
      continue;
    for (int k = 0, m = 0; k < started; k++) {
      slot *s = &w[k];
      if (s->busy < 0 || !pfd[m++].revents)
        continue;
      const int i = s->busy;
      int got = -1;
      s->busy = -1;
      if (read_all(s->result, rec, HEAD + size) == 0)
        memcpy(&got, rec, sizeof got);
      if (got != i) {
        /* The worker died mid-item (killed); it is gone. */
        int ws = 0;
        waitpid(s->pid, &ws, 0);
        slot_retire(s);
        close(s->result);
        s->result = -1;
        s->pid = -1;
        if (!stop && f->lost(q, i, ws, msg, len) < 0) {
          stop = 1;
          rc = MRVI_EIO;
        }
      } else if (!stop && q->done(q->user, i, rec + HEAD) < 0) {
        stop = 1;
        rc = MRVI_EIO;
      }
    }
  }
  /* An item taken and never started: every worker was gone (or the pool
   * halted: the caller counts it as not run). */
  if (carry >= 0 && !stop && !halted && f->lost(q, carry, -1, msg, len) < 0)
    rc = MRVI_EIO;
  for (int k = 0; k < started; k++) {
    slot_retire(&w[k]);
    if (w[k].result >= 0)
      close(w[k].result);
    if (w[k].pid > 0) {
      if (stop && f->kill_on_stop)
        kill(w[k].pid, SIGKILL);
      waitpid(w[k].pid, NULL, 0);
    }
  }
  sigaction(SIGPIPE, &old_pipe, NULL);
  free(rec);
  free(pfd);
  free(w);
  return rc;
}

/* ---------------------------------------------------------------------------
 * The cases of a batch
 * ------------------------------------------------------------------------- */

typedef struct case_job {
  const mrvi_batch_plan *plan;
  const char *master;
  volatile const int *stop; /* the pool's relay, or NULL */
} case_job;

/* Item c: case c into its run file; the record is its result. */
static void case_item(void *user, int c, void *out) {
  const case_job *job = user;
  mrvi_batch_result *res = out;
  char path[4096];
  if (mrvi_batch_case_file(job->master, c, 0, path, sizeof path) == 0) {
    mrvi_batch_case_run(job->plan, c, path, job->stop, res);
    return;
  }
  res->c = c;
  res->energy_error = res->cost = res->violation = NAN;
  res->status = MRVI_BATCH_FAILED;
  snprintf(res->reason, sizeof res->reason, "case file name too long");
}

/* A case whose worker died (killed) stays pending, to be run by --resume;
 * the cases left go to the workers left. */
static int case_lost(const mrvi_batch_queue *q, int c, int ws, char *msg,
                     size_t len) {
  (void)msg, (void)len;
  mrvi_batch_result res;
  memset(&res, 0, sizeof res);
  res.c = c;
  res.status = MRVI_BATCH_PENDING;
  res.energy_error = res.cost = res.violation = NAN;
  if (ws < 0)
    snprintf(res.reason, sizeof res.reason,
             "no worker process left (not run: --resume runs it)");
  else
    snprintf(res.reason, sizeof res.reason, "%s %d (not run: --resume runs it)",
             WIFSIGNALED(ws) ? "worker process killed by signal"
                             : "worker process exited with status",
             WIFSIGNALED(ws) ? WTERMSIG(ws) : WEXITSTATUS(ws));
  return q->done(q->user, c, &res);
}

int mrvi_batch_pool_serve(const mrvi_batch_plan *plan, const char *master,
                          int jobs, const mrvi_batch_queue *q, char *msg,
                          size_t len) {
  /* The workers' copy of the stop flag: an int shared with them. */
  volatile int *relay = NULL;
  if (q->stop) {
    void *page = mmap(NULL, sizeof *relay, PROT_READ | PROT_WRITE,
                      MAP_SHARED | MAP_ANONYMOUS, -1, 0);
    if (page == MAP_FAILED) {
      mrvi_fmt(msg, len, "mmap of the stop flag: %s", strerror(errno));
      return MRVI_ENOMEM;
    }
    relay = page;
    *relay = 0;
  }
  case_job job = {plan, master, relay};
  const feed f = {.q = q, .lost = case_lost, .relay = relay};
  const int rc =
      serve(jobs, sizeof(mrvi_batch_result), case_item, &job, &f, msg, len);
  if (relay)
    munmap((void *)relay, sizeof *relay);
  return rc;
}

/* The serial queue: todo[0..n) in order. */
typedef struct todo_queue {
  const int *todo;
  int n, next;
  mrvi_batch_done done;
  void *user;
} todo_queue;

static int todo_next(void *user) {
  todo_queue *t = user;
  return t->next < t->n ? t->todo[t->next++] : -1;
}

static int todo_done(void *user, int c, const void *res) {
  todo_queue *t = user;
  (void)c;
  return t->done(t->user, res);
}

int mrvi_batch_pool_run(const mrvi_batch_plan *plan, const char *master,
                        const int *todo, int n_todo, int jobs,
                        volatile const int *stop, mrvi_batch_done done,
                        void *user, char *msg, size_t len) {
  mrvi_fmt(msg, len, "%s", "");
  if (n_todo <= 0)
    return 0;
  todo_queue t = {.todo = todo, .n = n_todo, .done = done, .user = user};
  mrvi_batch_queue q = {
      .next = todo_next, .done = todo_done, .stop = stop, .user = &t};
  int rc = mrvi_batch_pool_serve(plan, master, jobs < n_todo ? jobs : n_todo,
                                 &q, msg, len);
  if (rc == 0 && t.next < n_todo && !(stop && *stop)) {
    mrvi_fmt(msg, len, "every worker process died; %d cases not run",
             n_todo - t.next);
    rc = MRVI_EIO;
  }
  return rc;
}

/* ---------------------------------------------------------------------------
 * A map over worker processes: items that return a small record (the
 * study commands, `mrvi converge`), no run files.
 * ------------------------------------------------------------------------- */

/* A worker that died stops the map, whose records would be incomplete. */
static int map_lost(const mrvi_batch_queue *q, int i, int ws, char *msg,
                    size_t len) {
  (void)q;
  if (ws < 0)
    mrvi_fmt(msg, len, "every worker process died (item %d not run)", i);
  else if (WIFSIGNALED(ws))
    mrvi_fmt(msg, len, "worker process killed by signal %d (item %d)",
             WTERMSIG(ws), i);
  else
    mrvi_fmt(msg, len, "worker process exited with status %d (item %d)",
             WEXITSTATUS(ws), i);
  return -1;
}

int mrvi_batch_map_serve(int jobs, size_t size, mrvi_batch_item fn, void *user,
                         const mrvi_batch_queue *q, char *msg, size_t len) {
  const feed f = {.q = q, .lost = map_lost, .kill_on_stop = 1};
  return serve(jobs, size, fn, user, &f, msg, len);
}

/* The map's queue: items 0..n-1 in order, records to out + i * size. */
typedef struct map_queue {
  int n, next, done;
  size_t size;
  char *out;
} map_queue;

static int map_next(void *user) {
  map_queue *m = user;
  return m->next < m->n ? m->next++ : -1;
}

static int map_done(void *user, int i, const void *rec) {
  map_queue *m = user;
  memcpy(m->out + (size_t)i * m->size, rec, m->size);
  m->done++;
  return 0;
}

int mrvi_batch_map(int n, int jobs, size_t size, mrvi_batch_item fn, void *user,
                   void *out, char *msg, size_t len) {
  mrvi_fmt(msg, len, "%s", "");
  char *rec = out;
  if (jobs > n)
    jobs = n;
  if (jobs <= 1) {
    for (int i = 0; i < n; i++)
      fn(user, i, rec + (size_t)i * size);
    return 0;
  }
  /* Items handed out in order to whichever worker is free; each record
   * lands at its index, so the gathered records do not depend on jobs. */
  map_queue m = {.n = n, .size = size, .out = out};
  const mrvi_batch_queue q = {.next = map_next, .done = map_done, .user = &m};
  int rc = mrvi_batch_map_serve(jobs, size, fn, user, &q, msg, len);
  if (rc == 0 && m.done < n) {
    mrvi_fmt(msg, len, "every worker process died; %d items not run",
             n - m.done);
    rc = MRVI_EIO;
  }
  return rc;
}
