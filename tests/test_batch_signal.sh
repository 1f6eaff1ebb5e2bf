#!/usr/bin/env bash
# SIGINT and SIGTERM stop `mrvi batch` as they stop `mrvi run` (doc/batch.md,
# "Ctrl-C and SIGTERM"): for five cases far too long to finish, a signal to
# the batch process (--jobs 2) or to its whole process group, workers
# included (--jobs 1, as Ctrl-C and Slurm send it), ends the batch with exit
# status 128 + signal; every case that ran has a valid case file (h5dump
# opens it) whose stop_reason says it was interrupted, and its table row has
# that reason, its steps and status 0 (pending: --resume runs it); every case
# not started has no file and a row "not run: ... stopped by SIG...".  An
# optimize batch stops each optimiser after its evaluation.  Built
# with MPI, the same after Ctrl-C of `mpiexec -n 2` (Open MPI sends SIGTERM
# to the ranks), and a SIGINT to rank 0 alone lets rank 1's case finish.
#
#   test_batch_signal.sh MRVI_BINARY SOURCE_ROOT mpi|no-mpi
#
# Prints "N passed, M failed" and exits non-zero on any failure.
set -u

mrvi=${1:?usage: test_batch_signal.sh MRVI_BINARY SOURCE_ROOT mpi|no-mpi}
root=${2:?usage: test_batch_signal.sh MRVI_BINARY SOURCE_ROOT mpi|no-mpi}
built=${3:-no-mpi}
fpu=$root/systems/fpu.yaml

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
# shellcheck source=tests/batchlib.sh
. "$(dirname "$0")/batchlib.sh"

cd "$tmp" || exit 1

# Five cases of 3.3e7 macro steps each: none finishes within the test.
slow=(--vary integrator.t_end=1e7 --vary integrator.micro_steps=1,2,3,4,5)

# started MASTER N: wait (at most 60 s) until N case files exist, then a
# little longer (their runs are stepping); 1 if they never appear.
started() {
  local dir=${1%.h5}.cases i
  for i in $(seq 600); do
    [ "$(find "$dir" -name 'case_*.h5' -size +0 2>/dev/null | wc -l)" -ge "$2" ] &&
      sleep 0.5 && return 0
    sleep 0.1
  done
  return 1
}

# ended PID: wait (at most 60 s) until PID has left, else kill it (its
# group, if it leads one; its workers die with it).
ended() {
  local i
  for i in $(seq 600); do
    kill -0 "$1" 2>/dev/null || return 0
    sleep 0.1
  done
  kill -KILL -- "-$1" 2>/dev/null || kill -KILL "$1"
  return 1
}

# attr FILE NAME: a root attribute of a case file (h5dump: the file opens).
attr() {
  h5dump -a "/$2" "$1" 2>/dev/null | sed -n 's/^ *(0): *"\{0,1\}\([^"]*\)"\{0,1\}$/\1/p'
}

# check_stopped NAME MASTER SIGNAL: the table and case files of a batch
# stopped by SIGNAL (INT or TERM).
check_stopped() {
  local name=$1 m=$2 sig=$3 c ran=0 skipped=0 bad=""
  local status reasons steps
  mapfile -t status < <(column "$m" status)
  mapfile -t steps < <(column "$m" steps)
  mapfile -t reasons < <(column "$m" stop_reason | sed 's/^"//;s/"$//')
  [ "${#status[@]}" = 5 ] || bad="$bad table of ${#status[@]} rows;"
  for c in 0 1 2 3 4; do
    local f=${m%.h5}.cases/case_000$c.h5
    [ "${status[$c]:-x}" = 0 ] || bad="$bad case $c status ${status[$c]:-?};"
    if [ -e "$f" ]; then
      local why k
      why=$(attr "$f" stop_reason)
      k=$(attr "$f" steps_completed)
      case $why in
      "interrupted after "*) ;;
      *) bad="$bad case $c file says '$why';" ;;
      esac
      [ "$why" = "${reasons[$c]:-}" ] ||
        bad="$bad case $c row '${reasons[$c]:-}' != file '$why';"
      [ -n "$k" ] && [ "$k" = "${steps[$c]:-}" ] ||
        bad="$bad case $c row steps ${steps[$c]:-?} != file $k;"
      ran=$((ran + 1))
    else
      case ${reasons[$c]:-} in
      "not run: the batch was stopped by SIG$sig "*) ;;
      *) bad="$bad case $c (no file) row '${reasons[$c]:-}';" ;;
      esac
      skipped=$((skipped + 1))
    fi
  done
  [ "$ran" -ge 1 ] && [ "$skipped" -ge 1 ] ||
    bad="$bad $ran cases ran, $skipped not started;"
  if [ -z "$bad" ]; then
    pass "$name: $ran case files interrupted and valid, $skipped rows not run"
  else
    fail "$name:$bad"
  fi
}

# interrupt NAME PID TARGET MASTER N SIGNAL: once N case files of MASTER
# exist, send SIGNAL to TARGET (PID, or -PID: its process group) and wait
# for PID to end; its exit status in $rc.  1 (a failure said) when no case
# started within 60 s.
interrupt() {
  local name=$1 pid=$2 target=$3
  if ! started "$4" "$5"; then
    kill -KILL -- "$target"
    wait "$pid"
    fail "$name: no case started within 60 s"
    return 1
  fi
  kill "-$6" -- "$target"
  ended "$pid" || fail "$name: the batch did not stop within 60 s"
  wait "$pid"
  rc=$?
}

# --- SIGINT to the batch process alone, 2 jobs ---
"$mrvi" batch "$fpu" -o i.h5 -j 2 "${slow[@]}" >out.txt 2>err.txt &
if interrupt SIGINT $! $! i.h5 2 INT; then
  [ $rc = 130 ] && pass "SIGINT: exit 130" || fail "SIGINT: exit $rc"
  grep -q "^i.h5: interrupted: 0 of 5 cases completed" out.txt &&
    pass "SIGINT: the summary says interrupted" ||
    fail "SIGINT: summary $(cat out.txt)"
  grep -q "SIGINT: 2 running cases stopped" err.txt &&
    pass "SIGINT: the two running cases stopped" ||
    fail "SIGINT: $(tail -n 3 err.txt)"
  check_stopped "SIGINT" i.h5 INT
fi

# --- SIGTERM to the process group (workers too), 1 job ---
setsid "$mrvi" batch "$fpu" -o t.h5 -j 1 -q "${slow[@]}" >out.txt 2>err.txt &
if interrupt "SIGTERM to the group" $! "-$!" t.h5 1 TERM; then
  [ $rc = 143 ] && pass "SIGTERM to the group: exit 143" ||
    fail "SIGTERM to the group: exit $rc"
  check_stopped "SIGTERM to the group" t.h5 TERM
fi

# --- an optimize batch: SIGINT stops each optimiser after its evaluation ---
"$mrvi" batch "$root/systems/ocp_gantry_crane.yaml" -o o.h5 -j 2 -q --optimize \
  --seeds 5 --control-std 5 --vary integrator.macro_step=0.004 >out.txt \
  2>err.txt &
if interrupt optimize $! $! o.h5 2 INT; then
  mapfile -t status < <(column o.h5 status)
  stopped=$(column o.h5 stop_reason |
    grep -c '^"interrupted: optimisation interrupted after')
  skipped=$(column o.h5 stop_reason | grep -c '^"not run: .* by SIGINT ')
  # (a case may complete before the signal on a fast machine)
  done_=$(printf '%s\n' "${status[@]}" | grep -c '^1$')
  opened=1
  for f in o.cases/case_*.h5; do h5dump -H "$f" >/dev/null 2>&1 || opened=0; done
  if [ $rc = 130 ] && [ "$stopped" -ge 1 ] && [ "$skipped" -ge 1 ] &&
    [ $((stopped + skipped + done_)) = 5 ] && [ $opened = 1 ]; then
    pass "optimize: exit 130, $stopped stopped, $skipped not run, files valid"
  else
    fail "optimize: exit $rc, $stopped stopped, $skipped not run, $done_ done, files valid $opened"
  fi
fi

# --- Ctrl-C of mpiexec -n 2: Open MPI sends SIGTERM to every rank (the
# exit status is mpiexec's own) ---
if [ "$built" = mpi ] && command -v mpiexec >/dev/null; then
  mpirun=(mpiexec -n 2 --oversubscribe)
  [ "$(id -u)" = 0 ] && mpirun+=(--allow-run-as-root)
  export ASAN_OPTIONS="${ASAN_OPTIONS:+$ASAN_OPTIONS:}detect_leaks=0"
  "${mpirun[@]}" "$mrvi" batch "$fpu" -o m.h5 -j 1 -q "${slow[@]}" \
    >out.txt 2>err.txt &
  interrupt mpiexec $! $! m.h5 2 INT &&
    check_stopped "mpiexec -n 2, SIGINT to mpiexec" m.h5 TERM

  # --- SIGINT to rank 0 alone (doc/batch.md, "Rank 0 alone"): rank 0 stops
  # its running case and hands out no more; rank 1's case runs to its end
  # (three cases of 2e5 macro steps, a second or two each) and gets its
  # row; the batch ends as interrupted with rank 0's status 130 (Open
  # MPI's mpiexec passes it on).  Which rank takes which case does not
  # matter: the cases cost the same. ---
  short=(--vary integrator.macro_step=0.1 --vary output.micro=false
    --vary output.every=1000 --vary integrator.t_end=20000,20001,20002)
  "${mpirun[@]}" "$mrvi" batch "$fpu" -o r.h5 -j 1 "${short[@]}" \
    >out.txt 2>err.txt &
  launcher=$!
  if started r.h5 2; then
    # Rank 0: the child of mpiexec that Open MPI gave rank 0.
    rank0=""
    for p in $(pgrep -P $launcher); do
      tr '\0' '\n' <"/proc/$p/environ" 2>/dev/null |
        grep -qx OMPI_COMM_WORLD_RANK=0 && rank0=$p
    done
    [ -n "$rank0" ] && kill -INT "$rank0"
    ended $launcher || fail "rank 0 alone: the batch did not stop within 60 s"
    wait $launcher
    rc=$?
    mapfile -t status < <(column r.h5 status)
    mapfile -t reasons < <(column r.h5 stop_reason | sed 's/^"//;s/"$//')
    bad=""
    [ -n "$rank0" ] || bad="$bad no rank 0 among the children of mpiexec;"
    [ $rc = 130 ] || bad="$bad exit $rc;"
    grep -q "^r.h5: interrupted: 1 of 3 cases completed, 0 failed, 2 not run" \
      out.txt || bad="$bad summary '$(cat out.txt)';"
    grep -q "(rank 0): interrupted after " err.txt &&
      grep -q "(rank 1): completed" err.txt ||
      bad="$bad rank lines: $(grep '(rank' err.txt | tr '\n' ' ');"
    ran="" skipped=0
    for c in 0 1 2; do
      f=r.cases/case_000$c.h5
      if [ -e "$f" ]; then
        why=$(attr "$f" stop_reason)
        [ "$why" = "${reasons[$c]:-}" ] ||
          bad="$bad case $c row '${reasons[$c]:-}' != file '$why';"
        case "${status[$c]:-}:$why" in
        "1:completed") ran="${ran}c" ;;
        "0:interrupted after "*) ran="${ran}i" ;;
        *) bad="$bad case $c status ${status[$c]:-?} '$why';" ;;
        esac
      else
        case "${status[$c]:-}:${reasons[$c]:-}" in
        "0:not run: the batch was stopped by SIGINT "*)
          skipped=$((skipped + 1)) ;;
        *) bad="$bad case $c (no file) ${status[$c]:-?} '${reasons[$c]:-}';" ;;
        esac
      fi
    done
    case $ran in ci | ic) ;; *) bad="$bad case files '$ran' (c completed, i interrupted);" ;; esac
    [ $skipped = 1 ] || bad="$bad $skipped cases not started;"
    [ -z "$bad" ] &&
      pass "rank 0 alone: exit 130, rank 1's case completed, rank 0's interrupted, 1 not run" ||
      fail "rank 0 alone:$bad"
  else
    kill -KILL $launcher
    wait $launcher
    fail "rank 0 alone: no case started within 60 s"
  fi
else
  echo "skipped: the mpiexec run (built without MPI, or no mpiexec)"
fi

test_finish
