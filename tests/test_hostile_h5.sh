#!/bin/bash
# Hostile HDF5 inputs (issue 26, classes 1 and 4): every reader of an HDF5
# file -- mrvi export, run --resume, run --from, run --controls -- given
# files crafted from real outputs by tests/craft_hostile_h5.py (a dataset
# longer, wider or of another rank than the model implies, rank 32, an
# attribute that is an array, sizes of 2^32 to 2^61 declared on chunked
# datasets of a few kB) refuses each with an exit status in 1..127 and a
# message naming the dataset or attribute; no HDF5 error stack on stderr,
# no sanitizer report (the ASan + UBSan build runs this script too).  Then
# bytes of real outputs are flipped (fixed seeds) and export and resume run
# on each: no sanitizer report, no death by a signal.
#
#   test_hostile_h5.sh MRVI_BINARY SOURCE_ROOT [FLIPS]
#
# FLIPS: mutated files per base file (default: 20 in an ASan build, none
# otherwise; a longer run: tests/test_hostile_h5.sh build-san/mrvi . 500).
# Skipped (exit 77) when Debian's /usr/bin/python3 lacks h5py.

set -u

mrvi=${1:?usage: test_hostile_h5.sh MRVI_BINARY SOURCE_ROOT [FLIPS]}
root=${2:?usage: test_hostile_h5.sh MRVI_BINARY SOURCE_ROOT [FLIPS]}
flips=${3:-20}

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
need_python h5py numpy
craft=$root/tests/craft_hostile_h5.py
sys=$root/systems
cd "$tmp" || exit 1

# What no input may cause: a sanitizer report, an HDF5 error stack.
sanitizer='ERROR: AddressSanitizer\|ERROR: LeakSanitizer\|runtime error:'

# clean NAME RC: 0 if the last command (stderr in err.txt) ended by itself
# (RC < 128, no timeout) without a sanitizer report or HDF5 error stack;
# else records the failure and returns 1.
clean() {
  local name=$1 rc=$2
  if [ "$rc" -ge 124 ]; then
    fail "$name: exit $rc (signal or timeout): $(grep -m1 . err.txt)"
  elif grep -q "$sanitizer" err.txt; then
    fail "$name: $(grep -m1 "$sanitizer" err.txt)"
    grep -m8 '^ *#[0-9]' err.txt | sed 's/^/     /'
  elif grep -q 'HDF5-DIAG' err.txt; then
    fail "$name: HDF5 error stack printed: $(grep -m1 'HDF5-DIAG' err.txt)"
  else
    return 0
  fi
  return 1
}

# refuses NAME PATTERN CMD...: exit 1..123 with PATTERN on stderr, clean.
refuses() {
  local name=$1 pattern=$2
  shift 2
  timeout 60 "$@" >out.txt 2>err.txt
  refused "$name" "$pattern" $?
}

# refused NAME PATTERN RC: judges a command that ended with RC, its stderr
# in err.txt, as refuses does.
refused() {
  local name=$1 pattern=$2 rc=$3
  clean "$name" $rc || return
  if [ $rc -eq 0 ]; then
    fail "$name: accepted (exit 0)"
  elif ! grep -q -- "$pattern" err.txt; then
    fail "$name: exit $rc, no '$pattern' in: $(head -c 300 err.txt)"
  else
    pass "$name ($(head -1 err.txt | cut -c1-160))"
  fi
}

# accepts NAME CMD...: exit 0, clean.
accepts() {
  local name=$1
  shift
  timeout 60 "$@" >out.txt 2>err.txt
  accepted "$name" $?
}

# accepted NAME RC: judges a command that ended with RC, as accepts does.
accepted() {
  local name=$1 rc=$2
  clean "$name" $rc || return
  if [ $rc -ne 0 ]; then
    fail "$name: exit $rc: $(head -c 300 err.txt)"
  else
    pass "$name"
  fi
}

# --- real outputs to craft from --------------------------------------------
run_ok "lattice (2-D particles, micro_slow)" "$mrvi" run "$sys/lattice.yaml" \
  -o lat.h5 --set integrator.t_end=0.1 --set output.micro_slow=true \
  --set output.xdmf=false -q
run_ok "cart pendulum (multipliers)" "$mrvi" run "$sys/cart_pendulum.yaml" \
  -o cart.h5 --set integrator.t_end=0.2 --set output.xdmf=false -q
run_ok "fpu (no particles)" "$mrvi" run "$sys/fpu.yaml" -o fpu.h5 \
  --set integrator.t_end=1 -q
run_ok "rigid pendulum (bodies)" "$mrvi" run "$sys/rigid_pendulum.yaml" \
  -o body.h5 --set integrator.t_end=0.2 --set output.xdmf=false -q
cat >wheel.yaml <<'YAML'
name: wheel
dimension: 2
bodies:
  - {name: wheel, mass: 1, inertia: 1, position: [0, 0], angular_velocity: 2}
joints:
  - {type: revolute, name: axle, bodies: [wheel], point: [0, 0],
     spring: {law: linear, stiffness: 0.01}}
integrator: {scheme: midpoint-midpoint, macro_step: 0.05, micro_steps: 1,
             t_end: 1}
output: {xdmf: false}
YAML
run_ok "wheel on a torsional spring" "$mrvi" run wheel.yaml -o wheel.h5 -q
for kind in export:lat.h5 resume:cart.h5 from:fpu.h5 controls:- \
  bodies:body.h5 torsion:wheel.h5; do
  "$py" "$craft" "${kind%%:*}" "${kind#*:}" "${kind%%:*}" >/dev/null ||
    fail "crafting the ${kind%%:*} cases"
done

# --- no variable-length data in mrvi's outputs ----------------------------
# Their data would be in the global heap, which libhdf5 reads unchecked
# (doc/output.md, "Strings"): every output mrvi writes -- runs (with
# bodies, joints, constraints), a resumed run, an extended one, mrvi
# optimize, a batch master file and its case files, mrvi converge --
# holds only fixed-length strings, in datasets and attributes.
cp cart.h5 ext.h5
"$py" -c 'import sys, h5py
with h5py.File(sys.argv[1], "r+") as f:
    f.attrs.create("stop_reason", "interrupted (SIGINT)",
                   dtype=h5py.string_dtype("utf-8", 1024))
    f.attrs.modify("steps_completed", 4)' ext.h5
run_ok "resume (for the string types)" "$mrvi" run --resume ext.h5 -q
run_ok "extend (for the string types)" "$mrvi" run --resume ext.h5 -q \
  --set integrator.t_end=0.3
run_ok "optimize (for the string types)" "$mrvi" optimize \
  "$sys/ocp_double_integrator.yaml" -o vopt.h5 -q
run_ok "batch (for the string types)" "$mrvi" batch "$sys/fpu.yaml" \
  -o vbatch.h5 -q --vary integrator.micro_steps=1,2 \
  --vary integrator.t_end=1
run_ok "converge (for the string types)" "$mrvi" converge "$sys/fpu.yaml" \
  --p 5 --dt0 0.05 --levels 2 --no-cache -o vconv.h5 -q
if "$py" - lat.h5 fpu.h5 body.h5 wheel.h5 ext.h5 vopt.h5 vbatch.h5 \
  vbatch.cases/*.h5 vconv.h5 >vlen.txt 2>&1 <<'PY'; then
import sys, h5py
bad = []
for path in sys.argv[1:]:
    with h5py.File(path, "r") as f:
        objs = [("/", f)]
        f.visititems(lambda n, o: objs.append((n, o)))
        for name, o in objs:
            kinds = [("@" + a, o.attrs.get_id(a).dtype) for a in o.attrs]
            if isinstance(o, h5py.Dataset):
                kinds.append(("", o.dtype))
            for a, t in kinds:
                if h5py.check_vlen_dtype(t) is not None or (
                        h5py.check_string_dtype(t) and
                        h5py.check_string_dtype(t).length is None):
                    bad.append("%s:%s%s" % (path, name, a))
    print(path)
print("variable-length:", " ".join(bad) or "none")
sys.exit(1 if bad else 0)
PY
  pass "no variable-length string in $(($(wc -l <vlen.txt) - 1)) output files"
else
  fail "variable-length data in mrvi's outputs: $(tail -c 400 vlen.txt)"
fi

# --- mrvi export -----------------------------------------------------------
accepts "export the uncrafted file (xyz --micro)" "$mrvi" export lat.h5 \
  --format xyz --micro --species name -o lat.xyz
accepts "export the uncrafted file (xdmf)" "$mrvi" export lat.h5 \
  --format xdmf -o lat.xdmf
xyz=(--format xyz --micro --species name -o x.xyz)
while read -r case pattern formats; do
  for fmt in $formats; do
    args=("${xyz[@]}")
    [ "$fmt" = xdmf ] && args=(--format xdmf -o x.xdmf)
    refuses "export $fmt: $case" "$pattern" "$mrvi" export "export/$case.h5" \
      "${args[@]}"
  done
done <<'EOF'
names_longer /model/particle_name xyz xdmf
names_huge /model/particle_name xyz
names_vlen /model/particle_name:.variable-length xyz xdmf
names_matrix /model/particle_name xyz
qfast_wider /micro/q_fast xyz
qslow_narrower /micro/q_slow xyz
dimension_array /model/dimension xyz xdmf
column_huge /model/particle_column xyz xdmf
coordinates_huge /macro/q xyz xdmf
rate_rank32 /model/rate xyz xdmf
EOF
# stop_reason is only read for the closing note: exported, the note left out.
accepts "export: stop_reason an array of 64" "$mrvi" export \
  export/stop_reason_array.h5 "${xyz[@]}"

# --- mrvi run --resume -----------------------------------------------------
accepts "resume the uncrafted file (stopped at node 5)" "$mrvi" run \
  --resume resume/ok.h5 -q
while read -r case pattern; do
  refuses "resume: $case" "$pattern" "$mrvi" run --resume "resume/$case.h5" -q
done <<'EOF'
lambda_rank3 /macro/lambda
lambda_rank32 /macro/lambda
lambda_wider /macro/lambda
lambda_huge /macro/lambda
residual_rank32 /solver/residual
q_rank32 /macro/q
steps_array steps_completed
steps_nan steps_completed
every_huge output_every
description_array /model/description
stop_reason_array stop_reason
stop_reason_text stop_reason: variable-length strings
desc_macro_step attribute macro_step = 0.02 but /model/description says 0.01
desc_micro_steps attribute micro_steps = 5 but /model/description says 3
desc_every attribute output_every = 1 but /model/description says 2
desc_scheme attribute scheme = 'midpoint-midpoint' but /model/description
desc_t_end attribute t_end
desc_particle /model/name\[3\] = 'bob.x' but /model/description
desc_rate /model/rate\[3\] = 1 but /model/description makes 'bob.x' slow
desc_constraint /macro/lambda has 2 columns but the model of /model/description
macro_step_nan attribute macro_step = nan
macro_step_huge macro_step
micro_steps_huge attribute micro_steps = 1e+30
every_nan attribute output_every = nan
every_1e30 attribute output_every = 1e+30
steps_huge attribute steps_completed = 1.0000000000000001e+300
t_end_inf attribute t_end = inf
scheme_other attribute scheme = 'fully-explicit'
name_renamed /model/name\[5\] = 'other.z'
rate_flipped /model/rate\[0\] = 1
particle_renamed /model/particle_name\[1\] = 'other' but /model/description names particle 1 'bob'
particle_column_moved /model/particle_column\[1\] = 0 but /model/description puts particle 'bob' at column 3
particle_fewer /model/particle_name
t_backwards /macro/t\[5\] = -0.1
controlled resuming a controlled run is not supported
EOF

# The writer reopens every dataset to append, /bodies of ranks 3 and 4 too.
accepts "resume the uncrafted body file (stopped at node 5)" "$mrvi" run \
  --resume bodies/ok.h5 -q
while read -r case pattern; do
  refuses "resume: $case" "$pattern" "$mrvi" run --resume "bodies/$case.h5" -q
done <<'EOF'
rotation_rank5 /bodies/rotation
rotation_wider /bodies/rotation
position_huge /bodies/position
EOF

# /macro/torsion_angle: one column per torsional spring of the model.
accepts "resume the uncrafted wheel file (stopped at node 5)" "$mrvi" run \
  --resume torsion/ok.h5 -q
while read -r case pattern; do
  refuses "resume: $case" "$pattern" "$mrvi" run --resume "torsion/$case.h5" -q
  refuses "--from: $case" "$pattern" "$mrvi" run wheel.yaml \
    --from "torsion/$case.h5:5" -o wfrom.h5 -q
done <<'EOF'
torsion_wider /macro/torsion_angle has 3 columns
torsion_rank3 /macro/torsion_angle
torsion_missing no such dataset
torsion_huge /macro/torsion_angle
EOF

# --- mrvi run --from -------------------------------------------------------
accepts "--from the uncrafted file" "$mrvi" run "$sys/fpu.yaml" \
  --set integrator.t_end=2 --from fpu.h5 -o from.h5 -q
while read -r case pattern; do
  refuses "--from: $case" "$pattern" "$mrvi" run "$sys/fpu.yaml" \
    --set integrator.t_end=2 --from "from/$case.h5" -o from.h5 -q
done <<'EOF'
rate_huge /model/rate
q_rank3 /macro/q
t_rank32 /macro/t
q_wider /macro/q
desc_macro_step attribute macro_step = 0.29999999999999999 but /model/description says 0.2
every_nan attribute output_every = nan
macro_step_nan attribute macro_step = nan
EOF
# The refusal of a declared 2e8-entry /model/rate reads none of it.
if [ -x /usr/bin/time ] && ! grep -q asan <<<"$(ldd "$mrvi" 2>/dev/null)"; then
  /usr/bin/time -f %M -o rss.txt "$mrvi" run "$sys/fpu.yaml" \
    --from from/rate_huge.h5 -o from.h5 -q >/dev/null 2>&1
  kb=$(tail -1 rss.txt)
  [ "$kb" -lt 100000 ] && pass "--from a 2e8-entry /model/rate: $kb kB" ||
    fail "--from a 2e8-entry /model/rate used $kb kB"
fi

# --- mrvi run --controls ---------------------------------------------------
ocp=$sys/ocp_double_integrator.yaml
# Replayed (exit 2: these controls miss the terminal conditions).
timeout 60 "$mrvi" run "$ocp" --controls controls/ok.h5 -o replay.h5 \
  >out.txt 2>err.txt
rc=$?
if clean "--controls: a 10 x 1 /control/u" $rc; then
  { [ $rc = 0 ] || [ $rc = 2 ]; } && grep -q "replayed the controls" out.txt &&
    pass "--controls: a 10 x 1 /control/u replayed" ||
    fail "--controls: a 10 x 1 /control/u: exit $rc: $(head -c 300 err.txt)"
fi
while read -r case pattern; do
  refuses "--controls: $case" "$pattern" "$mrvi" run "$ocp" \
    --controls "controls/$case.h5" -o replay.h5 -q
done <<'EOF'
u_wrapping /control/u
u_rows_huge /control/u
u_rank3 /control/u
u_strings /control/u
u_missing /control/u
u_nan /control/u\[3, 0\] = nan: actuator 'push' takes finite values
u_inf /control/u\[9, 0\] = -inf: actuator 'push' takes finite values
not_hdf5 not_hdf5.h5
EOF
# Controls outside the description's bounds (round 17: refused; before,
# replayed): ok.h5's 0.25 against an upper bound of 0.1.
refuses "--controls: beyond the bounds" \
  "/control/u\[0, 0\] = 0.25: actuator 'push' takes finite values in \[-inf, 0.1\]" \
  "$mrvi" run "$ocp" --controls controls/ok.h5 -o replay.h5 -q \
  --set control.actuators.0.upper=0.1

# --- mrvi-plot (class 9) ---------------------------------------------------
# Crafted run files: drawn (exit 0) or refused with one line naming the
# file (exit 1), never a Python traceback (TypeError, IndexError,
# MemoryError before); the shape refusals name the dataset or attribute,
# before anything is read (8 TiB declared).  The command lines are queued
# and run in one Python process (tests/plot_cases.py: matplotlib imported
# once, not once a case), then judged one by one as refuses and accepts
# judge a command.
plot=$root/src/cli/mrvi-plot
# The hang files of "hangs" below, crafted here for mrvi-plot's cases too.
"$py" "$craft" hang resume/ok.h5 hang >/dev/null || fail "crafting hang files"
# plot_case ID ARGS...: queue mrvi-plot ARGS as case ID.
plot_case() {
  (IFS=$'\t' && echo "$*") >>plot/cases.txt
}
# plot_result ID: case ID's stderr into err.txt; returns its exit status
# (125 when it has none: the batch ended before it).
plot_result() {
  if [ -f "plot/$1.rc" ]; then
    cp "plot/$1.err" err.txt
    return "$(cat "plot/$1.rc")"
  fi
  echo "no result for case $1: tests/plot_cases.py ended before it" >err.txt
  return 125
}
if "$py" -c "import matplotlib" 2>/dev/null; then
  mkdir -p figs plot
  : >plot/cases.txt
  # Tables of mrvi converge / stability / timing and files of mrvi
  # optimize (/control, /optimizer/history): every dataset drawn checked
  # for rank, type, size and length before it is read, a crafted one
  # refused with one line naming it (before: 6 of 21 drawn without a word,
  # e.g. /timing/p of strings, a longer /control/terminal_target, others
  # refused naming another dataset or a Python exception; h5py's int64
  # size of a 2^61-entry dataset wrapped to 0 and passed the read cap).
  "$py" "$craft" tables none tables >/dev/null &&
    "$mrvi" optimize "$ocp" -o di_opt.h5 -q >/dev/null 2>&1 &&
    "$py" "$craft" plotcontrol di_opt.h5 plotcontrol >/dev/null ||
    fail "crafting the table and control files for mrvi-plot"

  # Drawn whole (seconds each on a loaded machine): the crafted files whose
  # crafted part mrvi-plot does not read or can draw; the refusals below.
  drawn=(resume/{ok,lambda_wider,lambda_rank32,residual_rank32}.h5
    resume/{every_huge,description_array,t_backwards}.h5
    bodies/{rotation_rank5,position_huge}.h5 from/every_nan.h5)
  i=0
  for f in "${drawn[@]}"; do
    plot_case draw$((i++)) run "$f" -o figs
  done
  runs=$(cat <<'EOF'
export/names_longer.h5 /model/particle_name' does not have one entry
export/names_huge.h5 /model/particle_name' declares 4294967296 values
export/names_matrix.h5 /model/particle_name' has rank 2
export/qfast_wider.h5 /micro/q_fast' has 37 columns, expected 30
export/qslow_narrower.h5 /micro/q_slow' has 3 columns, expected 30
export/dimension_array.h5 /model/dimension' is not one number
export/column_huge.h5 /model/particle_column' declares 4294967297 values
export/coordinates_huge.h5 /model/rate' declares 4294967356 values
export/rate_rank32.h5 /model/rate' has shape
export/stop_reason_array.h5 attribute stop_reason holds 64 values
resume/q_rank32.h5 /macro/q' has rank 32
resume/steps_array.h5 attribute steps_completed holds 1000 values
from/q_wider.h5 /macro/q' has 12 columns, expected 6
from/rate_huge.h5 /macro/q' has 6 columns, expected 200000000
from/t_rank32.h5 /macro/t' has rank 32
hang/truncated34.h5 not a readable HDF5 file
hang/superblock44_flagged.h5 not a readable HDF5 file
EOF
  )
  i=0
  while read -r case pattern; do
    plot_case run$((i++)) run "$case" -o figs
  done <<<"$runs"
  good=(convergence:conv stability:stab timing:timing)
  for t in "${good[@]}"; do
    plot_case "good_${t#*:}" "${t%%:*}" "tables/${t#*:}_ok.h5" -o figs
  done
  plot_case optimize_ok optimize plotcontrol/ok.h5 -o figs
  tables=$(cat <<'EOF'
convergence tables/conv_rank2.h5 /convergence/p1/macro_step' has rank 2
convergence tables/conv_strings.h5 /convergence/p1/e_q_mac' does not hold numbers
convergence tables/conv_huge.h5 /convergence/p1/e_p_mac' declares 1099511627776
convergence tables/conv_shorter.h5 /convergence/p1/e_q_mic' has shape (3,), expected (5,)
stability tables/stab_trace_rank3.h5 /stability/scan/trace_midpoint' has rank 3
stability tables/stab_trace_wider.h5 /stability/scan/trace_midpoint' has shape (5, 9)
stability tables/stab_p_huge.h5 /stability/p' declares 2305843009213693952
stability tables/stab_bound_longer.h5 /stability/midpoint_measured' has shape (8,)
timing tables/timing_p_strings.h5 /timing/p' does not hold numbers
timing tables/timing_total_rank2.h5 /timing/midpoint-midpoint/total_time' has rank 2
timing tables/timing_iterations_huge.h5 /timing/midpoint-midpoint/iterations' declares
optimize plotcontrol/u_rank3.h5 /control/u' has rank 3
optimize plotcontrol/u_huge.h5 /control/u' declares 2147483648 x 2147483648
optimize plotcontrol/u_wider.h5 /control/u' has shape (10, 2)
optimize plotcontrol/names_numbers.h5 /control/names' does not hold strings
optimize plotcontrol/t_rank2.h5 /control/t' has rank 2
optimize plotcontrol/pair_wider.h5 /control/actuator_pair' has shape (1, 5)
optimize plotcontrol/terminal_kind_numbers.h5 /control/terminal_kind' does not hold strings
optimize plotcontrol/terminal_target_longer.h5 /control/terminal_target' has shape
optimize plotcontrol/history_rank3.h5 /optimizer/history' has rank 3
optimize plotcontrol/history_huge.h5 /optimizer/history' declares
EOF
  )
  i=0
  while read -r sub case pattern; do
    plot_case table$((i++)) "$sub" "$case" -o figs
  done <<<"$tables"

  # One process for every case queued (each case bounded by 120 s inside).
  timeout 1800 "$py" "$root/tests/plot_cases.py" "$plot" plot/cases.txt plot ||
    fail "tests/plot_cases.py: exit $?"

  traced=""
  i=0
  for f in "${drawn[@]}"; do
    plot_result draw$((i++))
    rc=$?
    if [ $rc -ne 0 ] && [ $rc -ne 1 ] || grep -q Traceback err.txt ||
      { [ $rc -eq 1 ] && ! grep -q "^mrvi-plot: error: $f" err.txt; }; then
      traced="$traced $f(exit $rc: $(grep -m1 'Error' err.txt))"
    fi
  done
  [ -z "$traced" ] && pass "mrvi-plot run on every crafted file: no traceback" ||
    fail "mrvi-plot run:$traced"
  i=0
  while read -r case pattern; do
    plot_result run$((i++))
    refused "mrvi-plot: $case" "$pattern" $?
  done <<<"$runs"
  for t in "${good[@]}"; do
    plot_result "good_${t#*:}"
    accepted "mrvi-plot ${t%%:*}: a good table" $?
  done
  plot_result optimize_ok
  accepted "mrvi-plot optimize: the uncrafted file" $?
  i=0
  while read -r sub case pattern; do
    plot_result table$((i++))
    refused "mrvi-plot $sub: $case" "$pattern" $?
    { [ "$(wc -l <err.txt)" -eq 1 ] && ! grep -q Traceback err.txt; } ||
      fail "mrvi-plot $sub: $case: not one line: $(head -3 err.txt)"
  done <<<"$tables"
else
  echo "note: mrvi-plot not run (no matplotlib for $py)"
fi

# --- live reading (class 5) --------------------------------------------------
# While mrvi run writes, a reader with HDF5's default file locking opens the
# file as a user would (h5py, swmr=True) and sees it grow, mrvi-plot draws
# it, and a second writer and a resume are still refused.  mrvi's own lock
# is an OFD lock (fcntl), HDF5's an flock: they no longer collide.
"$mrvi" run "$sys/fpu.yaml" --set integrator.t_end=1e7 -o live.h5 -q \
  2>live.err &
writer=$!
for _ in $(seq 100); do
  [ -s live.h5 ] && "$py" -c 'import h5py, sys
f = h5py.File(sys.argv[1], "r", swmr=True)
sys.exit(f["macro/t"].shape[0] < 2)' live.h5 2>/dev/null && break
  sleep 0.1
done
env -u HDF5_USE_FILE_LOCKING "$py" -c 'import h5py, sys, time
f = h5py.File(sys.argv[1], "r", swmr=True)
t = f["macro/t"]
n0 = t.shape[0]
for _ in range(100):
    time.sleep(0.1)
    t.refresh()
    if t.shape[0] > n0:
        break
print(n0, t.shape[0], f.attrs["stop_reason"].decode())
sys.exit(0 if t.shape[0] > n0 else 1)' live.h5 >out.txt 2>err.txt
[ $? -eq 0 ] && pass "h5py.File(live, 'r', swmr=True) during mrvi run: /macro/t rows $(cut -d' ' -f1,2 out.txt | tr ' ' '>') ($(cut -d' ' -f3 out.txt))" ||
  fail "h5py SWMR read of a live file: $(tail -1 err.txt)"
if "$py" -c "import matplotlib" 2>/dev/null; then
  accepts "mrvi-plot run on the live file" env -u HDF5_USE_FILE_LOCKING \
    "$py" "$plot" run live.h5 -o figs
fi
refuses "a second writer on the live file" "in use by another run" \
  "$mrvi" run "$sys/fpu.yaml" -o live.h5 -q
refuses "--resume of the live file" "in use by another run" \
  "$mrvi" run --resume live.h5 -q
kill -INT $writer
wait $writer
rc=$?
[ $rc -eq 130 ] && pass "the writer stops at SIGINT (exit 130)" ||
  fail "the writer: exit $rc: $(tail -1 live.err)"
left=$(ls -a | grep -c '^live\.h5\..*')
[ "$left" -eq 0 ] && pass "no lock or temporary file left beside live.h5" ||
  fail "files left beside live.h5: $(ls -a | grep '^live\.h5\.')"

# --- hangs (class 3) -------------------------------------------------------
# A truncated file or a damaged superblock made every reader spin in HDF5's
# SWMR-read retries for tens of minutes.  Each reader refuses them within
# the timeout of `refuses` (a hang fails the test); mrvi-plot's refusals of
# two of them are among its cases above.
for f in hang/*.h5; do
  refuses "export: $f" "cannot open" "$mrvi" export "$f" "${xyz[@]}"
  cp "$f" hang.h5
  refuses "resume: $f" "cannot open" "$mrvi" run --resume hang.h5 -q
  refuses "--from: $f" "cannot open" "$mrvi" run "$sys/cart_pendulum.yaml" \
    --from "$f" -o from.h5 -q
done
# A read that does not return (here: a FIFO nobody writes, as an HDF5 call
# that spins) ends at the first SIGTERM, exit 143, nothing written.
rm -f stuck.h5 && mkfifo stuck.h5
"$mrvi" run --resume stuck.h5 -q 2>/dev/null &
reader=$!
sleep 0.5
kill -TERM $reader
for _ in $(seq 50); do kill -0 $reader 2>/dev/null || break; sleep 0.1; done
if kill -0 $reader 2>/dev/null; then
  kill -KILL $reader
  wait $reader 2>/dev/null
  fail "a stuck read survives SIGTERM"
else
  wait $reader
  rc=$?
  [ $rc -eq 143 ] && pass "a stuck read ends at the first SIGTERM (exit 143)" ||
    fail "a stuck read after SIGTERM: exit $rc"
fi
rm -f stuck.h5

# --- flipped bytes ---------------------------------------------------------
# Each mutated file: export xyz --micro and xdmf (lattice), resume (cart).
# A refusal is fine; a sanitizer report in mrvi's code or a death by a
# signal is not.  They run by default in the ASan build only, where a report
# tells whose code it was (a plain build sees only the signal).  Found in
# libhdf5 itself and counted, shown, not failed (issue 26):
#   - sanitizer reports with no frame in mrvi's sources: Debian 12's HDF5
#     1.10.8 overruns its global heap in H5HG_read (vlen strings, e.g.
#     /model/particle_name) on some corrupted files, and leaks a file it
#     cannot close ("HDF5: infinite loop closing library");
#   - hangs: none expected since the SWMR-read fallback is bounded (see
#     "hangs" above); one would be counted here (killed after 8 s).
# MRVI_HOSTILE_KEEP=DIR keeps each file that failed or was counted.
# hdf5_own: 0 when the sanitizer report in err.txt is libhdf5's own
# (tests/hdf5_own.awk says how that is told).
hdf5_own() {
  awk -f "$root/tests/hdf5_own.awk" err.txt
}
hangs=""
hdf5_own=""
# flip_check NAME FILE CMD...: run CMD on the mutated FILE and judge it.
flip_check() {
  local name=$1 file=$2
  shift 2
  timeout -k 2 8 "$@" >/dev/null 2>err.txt
  local rc=$?
  local before=$failed
  if [ $rc -eq 124 ] || [ $rc -eq 137 ]; then
    hangs="$hangs $name"
  elif grep -q "$sanitizer" err.txt && hdf5_own; then
    local what where
    what=$(grep -m1 -o 'LeakSanitizer\|AddressSanitizer: [a-z-]*' err.txt)
    where=$(grep -m1 -o ' in H5[A-Za-z_0-9]*' err.txt)
    hdf5_own="$hdf5_own $name (${what#AddressSanitizer: }$where);"
  else
    clean "$name" $rc && return
  fi
  if [ -n "${MRVI_HOSTILE_KEEP:-}" ]; then
    mkdir -p "$MRVI_HOSTILE_KEEP" && cp "$file" "$MRVI_HOSTILE_KEEP/"
  fi
  return 0
}
[ -z "${3:-}" ] && ! ldd "$mrvi" 2>/dev/null | grep -q libasan && flips=0
if [ "$flips" -gt 0 ]; then
  mkdir -p flip/lat flip/cart
  "$py" "$craft" flip 26 "$flips" lat.h5 flip/lat >/dev/null
  "$py" "$craft" flip 62 "$flips" resume/ok.h5 flip/cart >/dev/null
  before=$failed
  for f in flip/lat/*.h5; do
    flip_check "$f: export xyz" "$f" "$mrvi" export "$f" "${xyz[@]}"
    flip_check "$f: export xdmf" "$f" "$mrvi" export "$f" --format xdmf \
      -o x.xdmf
  done
  for f in flip/cart/*.h5; do
    cp "$f" resumed.h5
    flip_check "$f: resume" "$f" "$mrvi" run --resume resumed.h5 -q
  done
  [ "$failed" -eq "$before" ] &&
    pass "$((2 * flips)) files with flipped bytes: no signal, no sanitizer report in mrvi's code"
  [ -n "$hangs" ] && echo "note: HDF5 spun on (killed after 8 s):$hangs"
  [ -n "$hdf5_own" ] && echo "note: sanitizer reports inside libhdf5:$hdf5_own"
else
  echo "note: no flipped files (a build without ASan; give FLIPS to run them)"
fi

test_finish
