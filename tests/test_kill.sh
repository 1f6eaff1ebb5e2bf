#!/usr/bin/env bash
# Crash safety of the HDF5 output (doc/output.md, "Crash safety"): runs of
# mrvi killed with SIGKILL at 20 random instants (FPU chain; 8 more for a
# constrained cart-pendulum) each leave a file that
# opens, whose rows agree bit for bit with an uninterrupted run, whose
# counter steps_completed is at most the rows it holds, and that the reader
# reports as "incomplete (writer killed)".  Also: a write failure injected
# after K steps (MRVI_TEST_WRITE_FAIL_AFTER) leaves exactly the flushed rows,
# no zero-filled ones, and no HDF5 messages on stderr.
#
# Killed files open for SWMR reading (h5py swmr=True, mrvi's readers) and,
# after `h5clear -s`, with h5dump.
#
#   test_kill.sh MRVI_BINARY SOURCE_ROOT
#
# Needs /usr/bin/python3 with h5py and numpy (exit 77 = skipped otherwise).
set -u
mrvi=${1:?usage: test_kill.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_kill.sh MRVI_BINARY SOURCE_ROOT}
# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
need_python h5py numpy

# compare REF FILE WHAT: every dataset of FILE is a prefix of REF's (bit for
# bit; the last macro row's multipliers are filled in only by the next
# record, so that row of /macro/lambda is skipped), counters <= rows.
compare() {
  "$py" - "$1" "$2" "$3" <<'PY'
import sys, h5py, numpy as np
ref, what = h5py.File(sys.argv[1], "r"), sys.argv[3]
try:
    f = h5py.File(sys.argv[2], "r")  # a file whose run closed
except OSError:
    # killed: HDF5's "open for writing" flag is set; SWMR reading opens it
    f = h5py.File(sys.argv[2], "r", swmr=True)
bad = []
def visit(name, obj):
    if not isinstance(obj, h5py.Dataset) or name.startswith("model"):
        return
    a, b = ref[name][()], obj[()]
    if a.ndim == 0:
        return
    n = b.shape[0]
    if name == "macro/lambda":
        n = max(n - 1, 0)
    if n > a.shape[0] or a[:n].tobytes() != b[:n].tobytes():
        bad.append(name)
f.visititems(visit)
k = int(f.attrs["steps_completed"])
if f["solver/iterations"].shape[0] < k or f["macro/t"].shape[0] < k + 1 and k > 0:
    bad.append("steps_completed %d > rows" % k)
reason = f.attrs["stop_reason"]
fixed = isinstance(reason, bytes)
reason = reason.decode() if fixed else reason
if reason == "running" and not fixed:
    bad.append("stop_reason 'running' not in the fixed form")
if reason == "completed" and not bad:
    sys.exit(3)  # finished before the kill (a loaded machine ran it fast)
if reason != "running":
    bad.append("stop_reason " + reason)
print(what, "rows", f["macro/t"].shape[0], "steps_completed", k,
      "bad:", bad or "none")
sys.exit(1 if bad else 0)
PY
}

export -f compare
export py

# keep_stuck FILE I: a killed file that a reader could not open in time is
# described (size, superblock flags) for the log.
keep_stuck() {
  echo "kill $2: $(stat -c %s "$1") bytes; h5clear -s says:"
  cp "$1" "$tmp/stuck.h5"
  timeout 20 h5clear -s "$tmp/stuck.h5" 2>&1 | head -n 5
  local out rc
  out=$(timeout 60 "$mrvi" converge "$sys" --reference "$1" 2>&1)
  rc=$?
  echo "mrvi's reader (exit $rc) says: $(echo "$out" | tail -n 1)"
  [ "$rc" -ne 124 ]
}

# kill_series SYSTEM T_END KILLS: a reference run, then KILLS runs killed
# with SIGKILL, each compared with the reference.
kill_series() {
  sys=$1
  set_=(--set "integrator.t_end=$2" --set integrator.micro_steps=1
    --set output.flush_interval=0.05)
  local t0 window i f pid ms rc t1 finished=0 plotted=0 stalled=0
  t0=$(date +%s%N)
  "$mrvi" run "$sys" "${set_[@]}" -o "$tmp/ref.h5" -q || fail "reference run"
  # A completed run's stop_reason is the fixed-length string SWMR wrote in
  # place (bytes in h5py; mrvi writes no variable-length strings), and no
  # .part copy is left behind.
  "$py" -c 'import sys, h5py
a = h5py.File(sys.argv[1], "r").attrs
t = h5py.check_string_dtype(a.get_id("stop_reason").dtype)
sys.exit(0 if a["stop_reason"] == b"completed" and t and t.length == 1024
         else 1)' "$tmp/ref.h5" &&
    pass || fail "reference run: stop_reason is not the fixed b'completed'"
  if compgen -G "$tmp/ref.h5.part*" >/dev/null; then
    fail "reference run left $(echo "$tmp"/ref.h5.part*)"
  else pass; fi
  # Kill instants: uniform in 0 .. 50 % of the reference run's wall time,
  # at most 1.5 s (on a loaded machine the reference run is slow, and 20
  # kills at up to half of it each overran the test's time limit).
  window=$((($(date +%s%N) - t0) * 5 / 10000000))
  [ "$window" -ge 10 ] || window=10
  [ "$window" -le 1500 ] || window=1500
  for i in $(seq 1 "$3"); do
    f=$tmp/k$i.h5
    # No file left from an earlier series (a run that finished before its
    # kill keeps its file): a run killed before its file exists must find
    # none.
    rm -f "$f" "$f".part*
    "$mrvi" run "$sys" "${set_[@]}" -o "$f" -q 2>/dev/null &
    pid=$!
    # A random instant (ms) before, during and after the first flushes.
    ms=$(((RANDOM * 32768 + RANDOM) % window))
    sleep "$((ms / 1000)).$(printf %03d $((ms % 1000)))"
    kill -KILL "$pid" 2>/dev/null
    wait "$pid" 2>/dev/null
    if [ ! -s "$f" ]; then
      pass # killed before the file existed: nothing to check
      continue
    fi
    # Every reader below runs under a time limit: HDF5's SWMR reading
    # retries a metadata checksum failure up to 100 times with growing
    # pauses (doc/output.md, "Reading untrusted files"), and h5py cannot
    # bound that; a reader that spins is reported by name, not left to the
    # test's time limit.
    t1=$(date +%s%N)
    timeout 30 bash -c 'compare "$@"' _ "$tmp/ref.h5" "$f" "kill $i" \
      >"$tmp/log" 2>&1
    rc=$?
    t1=$((($(date +%s%N) - t1) / 1000000))
    if [ "$rc" -eq 124 ]; then
      # h5py spun on the file for 30 s (doc/output.md, "Crash safety":
      # once in CI, cause not established; perhaps a kill inside a
      # metadata write of several pages, which HDF5's SWMR reading
      # retries).  mrvi's own readers bound the retries: they must answer.
      stalled=$((stalled + 1))
      echo "kill $i (after $ms ms): h5py did not open the file in 30 s"
      if keep_stuck "$f" "$i"; then pass; else
        fail "$(basename "$sys"): killed run $i: mrvi's reader did not answer in 60 s"
      fi
      continue
    fi
    case $rc in
    0) pass; echo "$(cat "$tmp/log") (read in $t1 ms)" ;;
    3)
      # Finished before its kill: the machine got faster than during the
      # reference run (another job ended); aim earlier from now on.
      finished=$((finished + 1))
      window=$((window * 2 / 3))
      [ "$window" -ge 10 ] || window=10
      continue
      ;;
    *) fail "$(basename "$sys"): killed run $i: $(cat "$tmp/log")" ;;
    esac
    # The reader (mrvi converge --reference uses it) names the cause.
    out=$(timeout 60 "$mrvi" converge "$sys" --reference "$f" 2>&1)
    case $out in
    *"incomplete (writer killed)"*) pass ;;
    *) fail "reader on killed file $i: $out" ;;
    esac
    # mrvi-plot reads the fixed form and says so in its note (first kill
    # only: starting matplotlib for every kill would double the test).
    if [ "$i" -eq 1 ] || [ "${plotted:-0}" -eq 0 ]; then
      plotted=1
      note=$(timeout 60 "$py" -c 'import importlib.machinery, importlib.util, sys, h5py
loader = importlib.machinery.SourceFileLoader("mp", sys.argv[1])
spec = importlib.util.spec_from_loader("mp", loader)
mp = importlib.util.module_from_spec(spec); loader.exec_module(mp)
print(mp.stop_note(h5py.File(sys.argv[2], "r", swmr=True)))' \
        "$root/src/cli/mrvi-plot" "$f" 2>&1)
      case $note in
      *"incomplete (writer killed)"*) pass ;;
      *) fail "mrvi-plot's note on killed file $i: $note" ;;
      esac
    fi
    # HDF5's tools open it once its "open for writing" flag is cleared.
    if command -v h5clear >/dev/null && command -v h5dump >/dev/null; then
      cp "$f" "$tmp/c.h5"
      timeout 30 h5clear -s "$tmp/c.h5" &&
        timeout 30 h5dump -H "$tmp/c.h5" >/dev/null
      case $? in
      0) pass ;;
      124)
        # Spun like h5py above (same count).
        stalled=$((stalled + 1))
        echo "kill $i: h5clear -s + h5dump did not finish in 30 s"
        ;;
      *) fail "h5clear -s + h5dump on killed file $i" ;;
      esac
    fi
    rm -f "$f" "$f".part*
  done
  # At most one file that h5py or h5clear + h5dump could not read in time
  # (above).
  if [ "$stalled" -le 1 ]; then pass; else
    fail "$(basename "$sys"): $stalled killed files not read in 30 s"
  fi
  # Most kills must have hit a running process.
  if [ $((finished * 2)) -le "$3" ]; then pass; else
    fail "$(basename "$sys"): $finished of $3 runs finished before their kill"
  fi
}
# A constrained system (multipliers, /macro/lambda), then the FPU chain,
# whose reference the tests below use.
kill_series "$root/systems/cart_pendulum.yaml" 1500 8
kill_series "$root/systems/fpu.yaml" 30000 20

# Injected write failure after K steps: rows up to the last good flush.
for K in 1 37 150; do
  f=$tmp/inj$K.h5
  MRVI_TEST_WRITE_FAIL_AFTER=$K "$mrvi" run "$sys" "${set_[@]}" \
    --set output.flush_interval=1e-9 -o "$f" -q >/dev/null 2>"$tmp/err"
  rc=$?
  [ $rc -eq 2 ] && pass || fail "injected failure K=$K: exit $rc"
  if grep -q 'HDF5\|infinite loop' "$tmp/err"; then
    fail "injected failure K=$K: HDF5 messages: $(cat "$tmp/err")"
  else pass; fi
  "$py" - "$tmp/ref.h5" "$f" "$K" <<'PY' && pass || fail "injected failure K=$K: rows"
import sys, h5py
ref, f, K = h5py.File(sys.argv[1], "r"), h5py.File(sys.argv[2], "r"), int(sys.argv[3])
r = f.attrs["stop_reason"]; r = r.decode() if isinstance(r, bytes) else r
k = int(f.attrs["steps_completed"])
ok = "injected write failure" in r and k == K - 1
for name in ("macro/q", "macro/p", "macro/energy", "solver/residual", "micro/q_fast"):
    n = f[name].shape[0]
    ok = ok and f[name][()].tobytes() == ref[name][:n].tobytes()
ok = ok and f["macro/t"].shape[0] == K and f["solver/iterations"].shape[0] == K - 1
print("K", K, "rows", f["macro/t"].shape[0], "steps_completed", k, r, "ok" if ok else "BAD")
sys.exit(0 if ok else 1)
PY
done

# A real full disk: a 16 MiB tmpfs filled to several sizes (needs root and
# mount; skipped otherwise).  The writer stops before HDF5 could hit ENOSPC
# (doc/output.md, "Errors writing the file"): exit 1 (nothing written) or 2,
# a file that opens with consistent rows and no zero-filled ones, no HDF5
# messages.
mnt=$tmp/tmpfs
mkdir -p "$mnt"
if [ "$(id -u)" = 0 ] && mount -t tmpfs -o size=16m tmpfs "$mnt" 2>/dev/null; then
  trap 'umount "$mnt" 2>/dev/null; rm -rf "$tmp"' EXIT
  for free in 200 2000 3500 5000 9000 14000; do
    rm -f "$mnt"/*
    dd if=/dev/zero of="$mnt/fill" bs=1k count=$((16384 - free)) 2>/dev/null
    f=$mnt/full.h5
    "$mrvi" run "$sys" "${set_[@]}" -o "$f" -q >/dev/null 2>"$tmp/err"
    rc=$?
    case $rc in 1 | 2) pass ;; *) fail "disk full ($free KiB free): exit $rc" ;; esac
    if grep -q 'HDF5\|infinite loop' "$tmp/err"; then
      fail "disk full ($free KiB free): HDF5 messages: $(head -c 300 "$tmp/err")"
    else pass; fi
    grep -q 'nearly full\|No space' "$tmp/err" && pass ||
      fail "disk full ($free KiB free): no clear message: $(cat "$tmp/err")"
    [ -e "$f" ] || continue
    "$py" - "$tmp/ref.h5" "$f" "$free" <<'PY' && pass || fail "disk full ($free KiB free): file"
import sys, h5py
ref, f = h5py.File(sys.argv[1], "r"), h5py.File(sys.argv[2], "r")
k = int(f.attrs["steps_completed"])
n = f["macro/t"].shape[0]
# Rows of nodes 0..k; or none at all when the first write was refused
# (then steps_completed is 0 and stop_reason says why).
ok = (n == k + 1 or (n == 0 and k == 0 and "full" in str(f.attrs["stop_reason"]))) \
    and f["solver/iterations"].shape[0] == k
for name in ("macro/t", "macro/q", "macro/p", "macro/energy", "solver/iterations",
             "solver/residual"):
    m = f[name].shape[0]
    ok = ok and f[name][()].tobytes() == ref[name][:m].tobytes()
print(sys.argv[3], "KiB free: rows", n, "steps_completed", k, "ok" if ok else "BAD")
sys.exit(0 if ok else 1)
PY
  done
  umount "$mnt"
else
  echo "disk-full test skipped: cannot mount a tmpfs (needs root)"
fi

test_finish
