#!/usr/bin/env bash
# mrvi run --resume / --from (doc/output.md, "Resuming a run").
#
# Runs of a free system (FPU chain, also with output.every = 7) and of a
# constrained one (cart pendulum, multiplier and null-space form) are
# stopped by SIGINT, SIGKILL (then the resumed run is interrupted by SIGINT
# and resumed again) and an injected write failure, resumed with
# `mrvi run --resume OUT.h5`, and compared with an uninterrupted run: every
# dataset and every root attribute bit for bit (q, p, micro data,
# energies, momenta, Newton iterations and residuals, constraint residuals
# and multipliers, rigid-body outputs and joint reactions), also of a
# wheel whose torsional spring is wound several turns.  `--from
# OUT.h5[:k]` must reproduce the uninterrupted run's rows from node k on.  Error cases: exit status and message.
#
#   test_resume.sh MRVI_BINARY SOURCE_ROOT
#
# Needs /usr/bin/python3 with h5py and numpy (exit 77 = skipped otherwise).
set -u
mrvi=${1:?usage: test_resume.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_resume.sh MRVI_BINARY SOURCE_ROOT}
# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
need_python h5py numpy

# same.py REF FILE [K]: without K, FILE equals REF (every dataset, every
# root attribute, bit for bit).  With K (a run --from node K): FILE's rows
# are REF's from node K on, and its last node is REF's.
cat >"$tmp/same.py" <<'PY'
import sys, h5py, numpy as np
def op(p):
    try:
        return h5py.File(p, "r")
    except OSError:  # a killed writer's file (SWMR reading)
        return h5py.File(p, "r", swmr=True)
ref, f = op(sys.argv[1]), op(sys.argv[2])
K = int(sys.argv[3]) if len(sys.argv) > 3 else None
every = int(ref.attrs["output_every"])
p = int(ref.attrs["micro_steps"])
bad, count = [], 0
def visit(name, d):
    global count
    if not isinstance(d, h5py.Dataset):
        return
    if name not in f:
        bad.append("missing " + name)
        return
    a, b = d[()], f[name][()]
    # (bodies/ and joints/ per-node data: rank >= 2; their rank-1
    # datasets describe the model)
    if K is not None and (name.startswith(("macro", "micro", "solver")) or
                          (name.startswith(("bodies", "joints")) and a.ndim >= 2)):
        start = {"macro": K // every, "micro": K * p, "solver": K, "bodies": K // every,
                 "joints": K // every}[name.split("/")[0]]
        a = a[start:]
        # Row K of the new run is its initial node: its multipliers lack
        # the projection impulse, its constraint residual is |g(q_K)|.
        # The new run's energy error counts from its own node K.
        if name == "macro/energy_running":
            return
        if name in ("macro/lambda", "macro/constraint_residual",
                    "micro/constraint_residual", "joints/force",
                    "joints/torque"):
            a, b = a[1:], b[1:]
    count += 1
    if isinstance(a, bytes) or a.dtype.kind == "O":
        same = np.asarray(a).tolist() == np.asarray(b).tolist()
    else:
        same = a.shape == b.shape and a.tobytes() == b.tobytes()
    if not same:
        bad.append("%s %s vs %s" % (name, np.shape(a), np.shape(b)))
ref.visititems(visit)
if K is None:
    for key in ref.attrs:
        count += 1
        if str(ref.attrs[key]) != str(f.attrs.get(key)):
            bad.append("attribute %s: %s vs %s" % (key, ref.attrs[key], f.attrs.get(key)))
    extra = set(f.attrs) - set(ref.attrs)
    if extra:
        bad.append("extra attributes %s" % sorted(extra))
print("%d compared" % count, "identical" if not bad else "DIFFER: %s" % bad[:6])
sys.exit(1 if bad else 0)
PY

# wait_rc PID: its exit status
wait_rc() {
  wait "$1" 2>/dev/null
  echo $?
}

# interrupt SIGNAL DELAY_MS OUT ARGS...: start `mrvi run ARGS -o OUT`, send
# SIGNAL after DELAY_MS; prints the exit status.
interrupt() {
  local sig=$1 ms=$2 out=$3
  shift 3
  "$mrvi" "$@" -o "$out" -q >/dev/null 2>&1 &
  local pid=$!
  sleep "$((ms / 1000)).$(printf %03d $((ms % 1000)))"
  kill -"$sig" "$pid" 2>/dev/null
  wait_rc "$pid"
}

# resume OUT [SIGNAL DELAY_MS]: mrvi run --resume OUT, optionally itself
# interrupted; prints the exit status.
resume() {
  if [ $# -gt 1 ]; then
    "$mrvi" run --resume "$1" -q >/dev/null 2>"$tmp/err.txt" &
    local pid=$!
    sleep "$(($3 / 1000)).$(printf %03d $(($3 % 1000)))"
    kill -"$2" "$pid" 2>/dev/null
    wait_rc "$pid"
  else
    "$mrvi" run --resume "$1" -q >/dev/null 2>"$tmp/err.txt"
    echo $?
  fi
}

steps_of() {
  "$py" - "$1" <<'PY'
import sys, h5py
try:
    f = h5py.File(sys.argv[1], "r")
except OSError:
    f = h5py.File(sys.argv[1], "r", swmr=True)
print(int(f.attrs["steps_completed"]))
PY
}

# same_as_ref WHAT FILE: FILE equals the uninterrupted run's ref.h5 bit for
# bit (same.py).
same_as_ref() {
  if "$py" "$tmp/same.py" "$tmp/ref.h5" "$2" >"$tmp/log"; then
    pass "$1 = uninterrupted ($(cat "$tmp/log"))"
  else
    fail "$1: $(cat "$tmp/log")"
  fi
}

# resume_case NAME N ARGS...: reference run of N steps, then the three
# interruptions, each resumed and compared with the reference.
resume_case() {
  local name=$1 N=$2
  shift 2
  local args=(run "$@" --set output.flush_interval=0.05)
  local t0 ms rc k
  t0=$(date +%s%N)
  run_ok "$name: reference run" "$mrvi" "${args[@]}" -o "$tmp/ref.h5" -q
  ms=$((($(date +%s%N) - t0) / 1000000))
  [ "$ms" -ge 20 ] || ms=20

  # SIGINT at about a third of the run.
  rc=$(interrupt INT $((ms / 3)) "$tmp/a.h5" "${args[@]}")
  k=$(steps_of "$tmp/a.h5")
  if [ "$rc" = 130 ] && [ "$k" -lt "$N" ]; then
    pass "$name: SIGINT after $k of $N steps (exit 130)"
    rc=$(resume "$tmp/a.h5")
    [ "$rc" = 0 ] && pass "$name: resumed after SIGINT" ||
      fail "$name: resume after SIGINT: exit $rc: $(cat "$tmp/err.txt")"
    same_as_ref "$name: SIGINT + resume" "$tmp/a.h5"
  else
    echo "note: $name: SIGINT missed the run (exit $rc, $k steps)"
  fi

  # SIGKILL at about a quarter, the resumed run stopped by SIGINT, resumed.
  rc=$(interrupt KILL $((ms / 4)) "$tmp/b.h5" "${args[@]}")
  k=$(steps_of "$tmp/b.h5" 2>/dev/null || echo none)
  if [ "$rc" = 137 ] && [ "$k" != none ] && [ "$k" -lt "$N" ]; then
    pass "$name: SIGKILL after $k flushed steps"
    rc=$(resume "$tmp/b.h5" INT $((ms / 4)))
    k=$(steps_of "$tmp/b.h5")
    case $rc in
    130 | 0) pass "$name: resumed killed run, stopped again at $k (exit $rc)" ;;
    *) fail "$name: resume after SIGKILL: exit $rc: $(cat "$tmp/err.txt")" ;;
    esac
    if [ "$rc" = 130 ]; then
      rc=$(resume "$tmp/b.h5")
      [ "$rc" = 0 ] && pass "$name: resumed a second time" ||
        fail "$name: second resume: exit $rc: $(cat "$tmp/err.txt")"
    fi
    same_as_ref "$name: SIGKILL + 2 resumes" "$tmp/b.h5"
  else
    echo "note: $name: SIGKILL missed the run (exit $rc, $k steps)"
  fi

  # Injected write failure after step N/2 (exit 2, output error).
  MRVI_TEST_WRITE_FAIL_AFTER=$((N / 2)) "$mrvi" "${args[@]}" -o "$tmp/c.h5" \
    -q >/dev/null 2>&1
  rc=$?
  k=$(steps_of "$tmp/c.h5")
  [ "$rc" = 2 ] && [ "$k" -lt "$N" ] &&
    pass "$name: injected failure: exit 2 after $k stored steps" ||
    fail "$name: injected failure: exit $rc, $k steps"
  rc=$(resume "$tmp/c.h5")
  [ "$rc" = 0 ] && pass "$name: resumed after the write failure" ||
    fail "$name: resume after the failure: exit $rc: $(cat "$tmp/err.txt")"
  same_as_ref "$name: failure + resume" "$tmp/c.h5"
}

fpu=$root/systems/fpu.yaml
cart=$root/systems/cart_pendulum.yaml

# A run that failed at its first write (node 0 stored, its multipliers not)
# is resumed from node 0, as a new start.
cargs=(run "$cart" --set integrator.t_end=20 --set output.flush_interval=0.05)
run_ok "cart, t_end 20" "$mrvi" "${cargs[@]}" -o "$tmp/c20.h5" -q
MRVI_TEST_WRITE_FAIL_AFTER=1 "$mrvi" "${cargs[@]}" -o "$tmp/c0.h5" -q \
  >/dev/null 2>&1
k=$(steps_of "$tmp/c0.h5")
[ "$k" = 0 ] && pass "failure at the first write: 0 steps stored" ||
  fail "failure at the first write: $k steps stored"
rc=$(resume "$tmp/c0.h5")
[ "$rc" = 0 ] && pass "resumed from node 0" ||
  fail "resume from node 0: exit $rc: $(cat "$tmp/err.txt")"
"$py" "$tmp/same.py" "$tmp/c20.h5" "$tmp/c0.h5" >"$tmp/log" &&
  pass "resume from node 0 = uninterrupted ($(cat "$tmp/log"))" ||
  fail "resume from node 0: $(cat "$tmp/log")"
resume_case "fpu" 20000 "$fpu" --set integrator.t_end=6000
resume_case "fpu every 7" 20000 "$fpu" --set integrator.t_end=6000 \
  --set output.every=7
# A fast rigid body on a joint: /bodies, /micro/bodies and the joint
# reactions (filled in with the multipliers) continue bit for bit.
sed -e 's/^    mass: 1$/    mass: 1\n    rate: fast/' "$root/systems/heavy_top.yaml" \
  >"$tmp/fast_top.yaml"
resume_case "fast top every 3" 10000 "$tmp/fast_top.yaml" \
  --set integrator.t_end=100 --set integrator.micro_steps=2 \
  --set output.micro=true --set output.every=3
# A writer killed inside a flush can leave a row's multipliers on disk and
# not the joint reactions computed from them (written in the same flush):
# made here by hand (a stop at a known step, then that row's /joints/force
# set to NaN).  The resume must start from a row that has both, so that the
# run still ends bit for bit the uninterrupted one.
fargs=(run "$tmp/fast_top.yaml" --set integrator.t_end=100
  --set integrator.micro_steps=2 --set output.micro=true --set output.every=3
  --set output.flush_interval=0.05)
MRVI_TEST_WRITE_FAIL_AFTER=4000 "$mrvi" "${fargs[@]}" -o "$tmp/d.h5" -q \
  >/dev/null 2>&1
if "$py" - "$tmp/d.h5" >"$tmp/log" <<'PY'; then
import sys, h5py, numpy as np
f = h5py.File(sys.argv[1], "r+")
lam = f["macro/lambda"][()]
rows = int(f.attrs["steps_completed"]) // int(f.attrs["output_every"]) + 1
r = max(i for i in range(min(rows, len(lam))) if np.isfinite(lam[i]).all())
f["joints/force"][r] = np.nan
print("row", r)
PY
  rc=$(resume "$tmp/d.h5")
  [ "$rc" = 0 ] && pass "resumed with a row's joint reactions missing ($(cat "$tmp/log"))" ||
    fail "resume with a row's joint reactions missing: exit $rc: $(cat "$tmp/err.txt")"
  same_as_ref "joint reactions missing + resume" "$tmp/d.h5"
else
  fail "could not prepare the file with a missing reaction row: $(cat "$tmp/log")"
fi
resume_case "cart multipliers" 15000 "$cart" --set integrator.t_end=300
resume_case "cart null-space" 15000 "$cart" --set integrator.t_end=300 \
  --set integrator.constraints.form=null-space

# --- --from: a new run from a stored node -----------------------------------
# The reference of the last case (cart, null-space) and the FPU chain with
# every = 7: the new file's rows are the reference's from node k on.
cset=(--set integrator.t_end=300 --set integrator.constraints.form=null-space
  --set output.flush_interval=0.05)
run_ok "--from ref.h5:6000 (cart)" "$mrvi" run "$cart" "${cset[@]}" \
  --from "$tmp/ref.h5:6000" -o "$tmp/from.h5" -q
"$py" "$tmp/same.py" "$tmp/ref.h5" "$tmp/from.h5" 6000 >"$tmp/log" &&
  pass "--from node 6000 continues the reference ($(cat "$tmp/log"))" ||
  fail "--from node 6000: $(cat "$tmp/log")"
fset=(--set integrator.t_end=6000 --set output.every=7)
run_ok "fpu every 7, t_end 6000" "$mrvi" run "$fpu" "${fset[@]}" \
  -o "$tmp/f7.h5" -q
run_ok "--from f7.h5:7000 (every 7)" "$mrvi" run "$fpu" "${fset[@]}" \
  --from "$tmp/f7.h5:7000" -o "$tmp/from7.h5" -q
"$py" "$tmp/same.py" "$tmp/f7.h5" "$tmp/from7.h5" 7000 >"$tmp/log" &&
  pass "--from node 7000 (every 7) continues the reference ($(cat "$tmp/log"))" ||
  fail "--from node 7000: $(cat "$tmp/log")"
# Extending a completed run: --from its last node with a later t_end
# equals a run to that t_end.
run_ok "fpu to t_end 6300" "$mrvi" run "$fpu" --set integrator.t_end=6300 \
  -o "$tmp/long.h5" -q
run_ok "fpu t_end 6000 (every 1)" "$mrvi" run "$fpu" \
  --set integrator.t_end=6000 -o "$tmp/short.h5" -q
run_ok "--from short.h5 (last node) to t_end 6300" "$mrvi" run "$fpu" \
  --set integrator.t_end=6300 --from "$tmp/short.h5" -o "$tmp/ext.h5" -q
"$py" "$tmp/same.py" "$tmp/long.h5" "$tmp/ext.h5" 20000 >"$tmp/log" &&
  pass "extended run = run to the later t_end ($(cat "$tmp/log"))" ||
  fail "extended run: $(cat "$tmp/log")"

# A wheel on a soft torsional spring (k = 0.01, omega0 = 2: J theta'' =
# -k theta, amplitude 20 rad) wound past +-pi several times: its branch
# (/macro/torsion_angle) is stored, so a resumed run continues wound.
cat >"$tmp/wheel.yaml" <<'YAML'
name: wound_wheel
dimension: 2
bodies:
  - {name: wheel, mass: 1, inertia: 1, position: [0, 0], angular_velocity: 2}
joints:
  - type: revolute
    name: axle
    bodies: [wheel]
    point: [0, 0]
    spring: {law: linear, stiffness: 0.01}
integrator:
  scheme: midpoint-midpoint
  macro_step: 0.05
  micro_steps: 1
  t_end: 60
  newton: {tolerance: 1.0e-12, max_iterations: 20}
  constraints: {form: multipliers, tolerance: 1.0e-12, projection: true}
YAML
resume_case "wound wheel" 1200 "$tmp/wheel.yaml"
# --from a wound node (theta = 20 rad at node 300): the new run is the
# reference's from there on (energy included, so continuous).
run_ok "wheel reference" "$mrvi" run "$tmp/wheel.yaml" -o "$tmp/w.h5" -q
"$py" -c 'import sys, h5py; a = h5py.File(sys.argv[1], "r")["macro/torsion_angle"][()]
sys.exit(0 if a.shape == (1201, 1) and a[300, 0] > 19 else 1)' "$tmp/w.h5" &&
  pass "wheel: /macro/torsion_angle (1201, 1), wound to > 19 rad at node 300" ||
  fail "wheel: /macro/torsion_angle missing or not wound"
run_ok "--from w.h5:300 (wound)" "$mrvi" run "$tmp/wheel.yaml" \
  --from "$tmp/w.h5:300" -o "$tmp/wfrom.h5" -q
"$py" "$tmp/same.py" "$tmp/w.h5" "$tmp/wfrom.h5" 300 >"$tmp/log" &&
  pass "--from a wound node continues on its branch ($(cat "$tmp/log"))" ||
  fail "--from a wound node: $(cat "$tmp/log")"
# A branch that is not the spring's angle at q (off by 1 rad) is refused.
cp "$tmp/w.h5" "$tmp/wbad.h5"
"$py" -c 'import sys, h5py; h5py.File(sys.argv[1], "r+")["macro/torsion_angle"][300, 0] += 1' \
  "$tmp/wbad.h5"

# --- errors -----------------------------------------------------------------
# expect_error NAME STATUS PATTERN CMD...: exit STATUS, PATTERN on stderr.
expect_error() {
  local name=$1 want=$2 pattern=$3
  shift 3
  "$@" >/dev/null 2>"$tmp/err.txt"
  local rc=$?
  if [ "$rc" != "$want" ]; then
    fail "$name: exit $rc, expected $want: $(head -c 300 "$tmp/err.txt")"
  elif ! grep -q -- "$pattern" "$tmp/err.txt"; then
    fail "$name: no '$pattern' in: $(head -c 300 "$tmp/err.txt")"
  else
    pass "$name ($(head -1 "$tmp/err.txt"))"
  fi
}
expect_error "resume a completed run" 1 "the run completed; nothing to resume" \
  "$mrvi" run --resume "$tmp/short.h5"
cp "$tmp/short.h5" "$tmp/ctl.h5"
"$py" -c 'import sys, h5py; h5py.File(sys.argv[1], "r+")["control/u"] = [1.0]' \
  "$tmp/ctl.h5"
expect_error "resume a controlled run" 1 "resuming a controlled run is not" \
  "$mrvi" run --resume "$tmp/ctl.h5"
echo "not hdf5" >"$tmp/text.h5"
expect_error "resume a text file" 1 "cannot open as an HDF5 file" \
  "$mrvi" run --resume "$tmp/text.h5"
"$py" -c 'import sys, h5py; h5py.File(sys.argv[1], "w")["x"] = [1.0]' \
  "$tmp/other.h5"
expect_error "resume an HDF5 file not written by mrvi" 1 \
  "not an mrvi output" "$mrvi" run --resume "$tmp/other.h5"
expect_error "resume a missing file" 1 "cannot open" \
  "$mrvi" run --resume "$tmp/none.h5"
expect_error "--from node out of range" 1 "macro node 99999 is not stored" \
  "$mrvi" run "$fpu" --from "$tmp/short.h5:99999" -o "$tmp/x.h5"
expect_error "--from a node that thinning dropped" 1 \
  "macro node 7001 is not stored (stored: 0 to 20000 in steps of 7" \
  "$mrvi" run "$fpu" --set integrator.t_end=6000 --set output.every=7 \
  --from "$tmp/f7.h5:7001" -o "$tmp/x.h5"
expect_error "--from another macro step" 1 "differs from integrator.macro_step" \
  "$mrvi" run "$fpu" --set integrator.macro_step=0.1 \
  --from "$tmp/short.h5:10" -o "$tmp/x.h5"
expect_error "--from the last node of a run at its t_end" 1 \
  "is not before the last node" \
  "$mrvi" run "$fpu" --set integrator.t_end=6000 --from "$tmp/short.h5" \
  -o "$tmp/x.h5"
# (refused by the run, as a start state off the constraints: exit 2)
expect_error "--from a node whose spring branch is not its angle" 2 \
  "is not its angle at the node's configuration" \
  "$mrvi" run "$tmp/wheel.yaml" --from "$tmp/wbad.h5:300" -o "$tmp/wx.h5"
expect_error "--from into the same file" 1 "is the --from file" \
  "$mrvi" run "$fpu" --from "$tmp/short.h5:10" -o "$tmp/short.h5"
expect_error "--resume with FILE" 1 "give no FILE, -o or --from" \
  "$mrvi" run "$fpu" --resume "$tmp/a.h5"
[ ! -e "$tmp/x.h5" ] && pass "no output file from a refused --from" ||
  fail "a refused --from wrote $tmp/x.h5"
# A live run holds its file: a resume is refused and the file untouched.
"$mrvi" run "$fpu" --set integrator.t_end=1e6 -o "$tmp/live.h5" -q \
  >/dev/null 2>&1 &
pid=$!
for _ in $(seq 1 100); do
  [ -s "$tmp/live.h5" ] && break
  sleep 0.05
done
sleep 0.2
expect_error "resume a file a live run holds" 1 "in use by another run" \
  "$mrvi" run --resume "$tmp/live.h5"
kill -INT $pid
wait $pid
rc=$?
[ "$rc" = 130 ] && pass "the live run went on undisturbed (exit 130)" ||
  fail "the live run: exit $rc"

# --- extending a completed run in place: --resume OUT --set integrator.t_end
# The extended file equals a run to the later t_end from the start (every
# dataset but /model/description, whose header comment records the two
# steps, and every root attribute), for a free and a constrained system,
# also extended twice; stop_reason is "completed" again (the fixed-length
# string: mrvi writes no variable-length ones) and no copy is left beside
# the file.
cat >"$tmp/ext.py" <<'PY'
import sys, h5py, numpy as np
ref, f = h5py.File(sys.argv[1], "r"), h5py.File(sys.argv[2], "r")
bad, count = [], 0
def visit(name, d):
    global count
    if isinstance(d, h5py.Dataset) and name != "model/description":
        count += 1
        a = d[()]
        b = f[name][()] if name in f else None
        if isinstance(a, bytes) or a.dtype.kind == "O":
            same = b is not None and np.asarray(a).tolist() == np.asarray(b).tolist()
        else:
            same = b is not None and a.shape == b.shape and a.tobytes() == b.tobytes()
        if not same:
            bad.append(name)
ref.visititems(visit)
for key in ref.attrs:
    count += 1
    if str(ref.attrs[key]) != str(f.attrs.get(key)):
        bad.append("attribute " + key)
if set(f.attrs) != set(ref.attrs):
    bad.append("attributes %s" % sorted(set(f.attrs) ^ set(ref.attrs)))
r = f.attrs["stop_reason"]
if not (isinstance(r, bytes) and r == b"completed"):
    bad.append("stop_reason %r" % (r,))
d = f["model/description"][()].decode()
if "--set " + sys.argv[3] not in d.split("\n")[1]:
    bad.append("description header: %s" % d.split("\n")[:2])
print("%d compared" % count, "identical" if not bad else "DIFFER: %s" % bad[:6])
sys.exit(1 if bad else 0)
PY
for sys_ in fpu cart; do
  file=$root/systems/$([ $sys_ = fpu ] && echo fpu || echo cart_pendulum).yaml
  "$mrvi" run "$file" --set integrator.t_end=3 -o "$tmp/ext_$sys_.h5" -q
  "$mrvi" run "$file" --set integrator.t_end=6 -o "$tmp/ext_ref_$sys_.h5" -q
  "$mrvi" run "$file" --set integrator.t_end=9 -o "$tmp/ext_ref9_$sys_.h5" -q
  if "$mrvi" run --resume "$tmp/ext_$sys_.h5" --set integrator.t_end=6 -q \
    2>"$tmp/err.txt" &&
    "$py" "$tmp/ext.py" "$tmp/ext_ref_$sys_.h5" "$tmp/ext_$sys_.h5" \
      integrator.t_end=6 >"$tmp/log"; then
    pass "$sys_: extended from t_end 3 to 6 = a run to 6 ($(cat "$tmp/log"))"
  else
    fail "$sys_: extended to 6: $(cat "$tmp/err.txt" "$tmp/log")"
  fi
  if "$mrvi" run --resume "$tmp/ext_$sys_.h5" --set integrator.t_end=9 -q \
    2>"$tmp/err.txt" &&
    "$py" "$tmp/ext.py" "$tmp/ext_ref9_$sys_.h5" "$tmp/ext_$sys_.h5" \
      integrator.t_end=9 >"$tmp/log"; then
    pass "$sys_: extended again to 9 = a run to 9 ($(cat "$tmp/log"))"
  else
    fail "$sys_: extended to 9: $(cat "$tmp/err.txt" "$tmp/log")"
  fi
  if compgen -G "$tmp/ext_$sys_.h5.part*" >/dev/null; then
    fail "$sys_: the extension left $(echo "$tmp"/ext_"$sys_".h5.part*)"
  else pass "$sys_: no copy left beside the extended file"; fi
done
expect_error "extend to an earlier t_end" 1 "must give more steps" \
  "$mrvi" run --resume "$tmp/ext_fpu.h5" --set integrator.t_end=5
expect_error "resume with another --set" 1 "no --set but integrator.t_end" \
  "$mrvi" run --resume "$tmp/ext_fpu.h5" --set integrator.micro_steps=5
"$mrvi" run "$fpu" --set integrator.t_end=2.1 --set output.every=4 \
  -o "$tmp/ext_every.h5" -q
expect_error "extend a run whose last node output.every skips" 1 \
  "not a multiple of output.every" \
  "$mrvi" run --resume "$tmp/ext_every.h5" --set integrator.t_end=6
MRVI_TEST_WRITE_FAIL_AFTER=3 "$mrvi" run "$fpu" --set integrator.t_end=3 \
  -o "$tmp/ext_stopped.h5" -q 2>/dev/null
expect_error "extend a run that did not complete" 1 "did not complete" \
  "$mrvi" run --resume "$tmp/ext_stopped.h5" --set integrator.t_end=6

# tuning.chord_carry (explicit-slow on sweep-cg, doc/solver.md "sweep-cg"):
# the rows' history a step takes from the one before is part of the state
# (/resume/chord_history, the last stored node's): the resumed runs continue
# bit for bit.  Without it (the dataset removed) the resumed run continues
# within the tolerance but not bit for bit (the history matters); a damaged
# history is refused.
lat=("$root/systems/lattice.yaml" --set integrator.scheme=explicit-slow
  --set integrator.micro_steps=10 --set integrator.tuning.chord_carry=1
  --set "generate.0.count=[40,20]")
resume_case "lattice, chord_carry, every 3" 300 "${lat[@]}" \
  --set integrator.t_end=15 --set output.every=3
"$py" -c 'import sys, h5py; h = h5py.File(sys.argv[1], "r")["resume/chord_history"]; sys.exit(0 if h[0] == 300 and h[1] == 800 and len(h) == 2 + 5 * 800 else 1)' \
  "$tmp/ref.h5" && pass "chord_carry: the last node's history (800 per row) stored" ||
  fail "chord_carry: /resume/chord_history is not node 300's of 800 entries per row"
# tuning.chord_linear (the linearised chord updates: a pattern fixed within
# each row) with the history: bit for bit as well.
resume_case "lattice, chord_carry, chord_linear" 300 "${lat[@]}" \
  --set integrator.tuning.chord_linear=2 --set integrator.t_end=15 \
  --set output.every=3
# (flushes every 0.1 ms: the stop at step 150 leaves stored nodes; ch_ref:
# the uninterrupted run of the same description)
lat+=(--set integrator.t_end=15 --set output.every=3
  --set output.flush_interval=0.0001)
run_ok "chord_carry: reference run" "$mrvi" run "${lat[@]}" -o "$tmp/ch_ref.h5" -q
MRVI_TEST_WRITE_FAIL_AFTER=150 "$mrvi" run "${lat[@]}" -o "$tmp/ch.h5" -q \
  >/dev/null 2>&1
k=$(steps_of "$tmp/ch.h5")
[ "$k" -gt 3 ] && pass "chord_carry: stopped after $k stored steps" ||
  fail "chord_carry: the stopped run stored $k steps (its flushes every 0.1 ms)"
cp "$tmp/ch.h5" "$tmp/ch_none.h5"
cp "$tmp/ch.h5" "$tmp/ch_nan.h5"
cp "$tmp/ch.h5" "$tmp/ch_n.h5"
"$py" -c 'import sys, h5py; del h5py.File(sys.argv[1], "r+")["resume/chord_history"]' \
  "$tmp/ch_none.h5"
"$py" -c 'import sys, h5py; h5py.File(sys.argv[1], "r+")["resume/chord_history"][9] = float("nan")' \
  "$tmp/ch_nan.h5"
"$py" -c 'import sys, h5py; h5py.File(sys.argv[1], "r+")["resume/chord_history"][1] = 7' \
  "$tmp/ch_n.h5"
rc=$(resume "$tmp/ch_none.h5")
if [ "$rc" = 0 ] &&
  "$py" -c 'import sys, h5py, numpy as np; a, b = (h5py.File(p, "r")["macro/q"][()] for p in sys.argv[1:]); d = np.abs(a - b).max(); print("%.3g" % d); sys.exit(0 if 0 < d < 1e-8 else 1)' \
    "$tmp/ch_ref.h5" "$tmp/ch_none.h5" >"$tmp/log"; then
  pass "chord_carry: resumed without the history: q within $(cat "$tmp/log") of the uninterrupted run, not bit for bit"
else
  fail "chord_carry: resume without the history: exit $rc, |dq| $(cat "$tmp/log")"
fi
expect_error "resume with a non-finite chord history" 1 "not a node's chord history" \
  "$mrvi" run --resume "$tmp/ch_nan.h5"
expect_error "resume with a chord history of another size" 1 "not a node's chord history" \
  "$mrvi" run --resume "$tmp/ch_n.h5"
rc=$(resume "$tmp/ch.h5")
[ "$rc" = 0 ] && "$py" "$tmp/same.py" "$tmp/ch_ref.h5" "$tmp/ch.h5" >"$tmp/log" &&
  pass "chord_carry: the same file resumed = uninterrupted ($(cat "$tmp/log"))" ||
  fail "chord_carry: resumed: exit $rc, $(cat "$tmp/log")"

run_ok "mrvi help run" "$mrvi" help run
grep -q -- "--resume OUT.h5" "$tmp/out.txt" && grep -q -- "--from" "$tmp/out.txt" &&
  pass "help run explains --resume and --from" ||
  fail "help run: no --resume / --from"

test_finish
