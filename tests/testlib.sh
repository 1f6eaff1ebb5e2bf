# Helpers shared by the shell tests (sourced).  Each check prints
# "ok   NAME" (nothing for a nameless pass) or "FAIL NAME"; the script ends
# with test_finish, which prints "N passed, M failed" and returns non-zero
# on a failure or when nothing passed.

passed=0
failed=0

pass() {
  passed=$((passed + 1))
  if [ -n "${1:-}" ]; then echo "ok   $1"; fi
}
fail() { failed=$((failed + 1)); echo "FAIL $1"; }

# $tmp: a scratch directory, removed when the script exits.
tmp=$(mktemp -d "${TMPDIR:-/tmp}/mrvi-test.XXXXXX") || exit 1
trap 'rm -rf "$tmp"' EXIT

# need_python MODULE...: $py is /usr/bin/python3 and imports the modules,
# or the test is skipped (exit 77).
need_python() {
  py=/usr/bin/python3
  if ! "$py" -c "import $(IFS=,; echo "$*")" 2>/dev/null; then
    echo "skipped: needs $py with $*"
    exit 77
  fi
}

# run_ok NAME CMD...: the command exits 0 (its output in $tmp/out.txt and
# $tmp/err.txt)
run_ok() {
  local name=$1
  shift
  if "$@" >"$tmp/out.txt" 2>"$tmp/err.txt"; then
    pass "$name"
  else
    fail "$name (exit $?)"
    sed 's/^/     /' "$tmp/err.txt" | head -20
  fi
}

# hold_lock FILE: a background process holds a write lock on FILE as a live
# mrvi writer does (a POSIX record lock, which conflicts with the OFD lock of
# mrvi_h5_lock_fd); its pid in $lock_holder (kill it to release).  Returns
# when the lock is held (1 if not within 5 s).
hold_lock() {
  rm -f "$tmp/lock.ready"
  python3 -c 'import fcntl, sys, time
f = open(sys.argv[1], "r+")
fcntl.lockf(f, fcntl.LOCK_EX)
print(flush=True)
time.sleep(60)' "$1" >"$tmp/lock.ready" &
  lock_holder=$!
  for _ in $(seq 100); do
    [ -s "$tmp/lock.ready" ] && return 0
    sleep 0.05
  done
  return 1
}

# busy_start: three busy tasks on core 0 (pids in $busy), so that under
# taskset -c 0,1 no core is idle (the fourth field of /proc/loadavg counts
# them; the machine's other tasks only add to it); returns 1, starting
# none, without two cores or taskset.  busy_stop ends them.
busy_start() {
  busy=()
  { [ "$(nproc)" -ge 2 ] && taskset -c 0,1 true 2>/dev/null; } || return 1
  for _ in 1 2 3; do
    taskset -c 0 sh -c 'while :; do :; done' &
    busy+=($!)
  done
  sleep 0.2
}

busy_stop() {
  kill "${busy[@]}"
  wait "${busy[@]}" 2>/dev/null
}

test_finish() {
  echo "$passed passed, $failed failed"
  [ "$failed" -eq 0 ] && [ "$passed" -gt 0 ]
}
