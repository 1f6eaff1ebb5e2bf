#!/usr/bin/env bash
# mrvi batch (doc/batch.md): a 3 x 2 batch equals the six `mrvi run --set`
# results bit for bit; --jobs 2 equals --jobs 1; --zip pairs; a bad value
# in one case is refused before any case runs, naming the case and key; a
# failing case is recorded and the others complete; the batch: section of
# the description gives the command line's batch, the command line
# overrides or extends it, and its errors carry file:line:col; a reader
# holding the
# master file open does not stop the batch; SIGKILL of the parent
# and of a worker mid-batch, then --resume, gives every case completed once
# and the results of an uninterrupted batch; seeded cases are the same in
# another batch and on any number of jobs, and perturbed velocities of a
# constrained model stay on the constraints.
#
#   test_batch.sh MRVI_BINARY SOURCE_ROOT
#
# Prints "N passed, M failed" and exits non-zero on any failure.
set -u

mrvi=${1:?usage: test_batch.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_batch.sh MRVI_BINARY SOURCE_ROOT}
fpu=$root/systems/fpu.yaml

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
# shellcheck source=tests/batchlib.sh
. "$(dirname "$0")/batchlib.sh"

cd "$tmp" || exit 1

short=integrator.t_end=20

# --- help ---
run_ok "mrvi help batch" "$mrvi" help batch
grep -q -- "--resume OUT.h5" "$tmp/out.txt" && pass || fail "help names --resume"

# --- 3 x 2 product equals six runs ---
run_ok "batch 3 x 2, --jobs 2" "$mrvi" batch "$fpu" -o b.h5 -q -j 2 \
  --vary integrator.micro_steps=1,2,4 --vary integrator.macro_step=0.01,0.02 \
  --vary "$short"
if [ "$(column b.h5 status | tr '\n' ' ')" = "1 1 1 1 1 1 " ]; then
  pass "six cases completed"
else
  fail "six cases completed: $(column b.h5 status | tr '\n' ' ')"
fi
c=0 ok=1
for p in 1 2 4; do
  for dt in 0.01 0.02; do
    "$mrvi" run "$fpu" -q -o "run$c.h5" --set integrator.micro_steps=$p \
      --set integrator.macro_step=$dt --set "$short" >/dev/null 2>&1 || ok=0
    h5diff "b.cases/case_000$c.h5" "run$c.h5" >/dev/null 2>&1 || ok=0
    c=$((c + 1))
  done
done
[ "$ok" = 1 ] && pass "each case equals mrvi run --set (h5diff)" ||
  fail "each case equals mrvi run --set (h5diff)"
h5dump -d /runs/case_0005/macro/t b.h5 >/dev/null 2>&1 &&
  pass "external link /runs/case_0005 reads the case file" ||
  fail "external link /runs/case_0005 reads the case file"
grep -q "H5" "$root/src/cli/cli_batch.c" && fail "cli_batch.c makes H5 calls" ||
  pass "cli_batch.c makes no H5 calls"

# --- the batch: section: the same batch from the file ---
cp "$fpu" sec.yaml
cat >>sec.yaml <<'EOF'
batch:
  vary:
    integrator.micro_steps: [1, 2, 4]
    integrator.macro_step: 0.01,0.02
    integrator.t_end: 20
  jobs: 2
EOF
run_ok "batch from the batch: section" "$mrvi" batch sec.yaml -o sec.h5 -q
same_table sec.h5 b.h5 && pass "the section's cases equal the command line's" ||
  fail "the section's cases equal the command line's"
"$mrvi" run sec.yaml -q -o sec5.h5 --set integrator.micro_steps=4 \
  --set integrator.macro_step=0.02 --set integrator.t_end=20 >/dev/null 2>&1
h5diff sec.cases/case_0005.h5 sec5.h5 >/dev/null 2>&1 &&
  pass "a section case equals mrvi run --set of the file" ||
  fail "a section case equals mrvi run --set of the file"
# The command line over the file: a --vary of a file key replaces it in
# place, a new key follows, --seeds over the file's.
run_ok "command line over the section" "$mrvi" batch sec.yaml -o over.h5 -q \
  --vary integrator.micro_steps=4,1 --vary output.micro=false --seeds 2
if [ "$(column over.h5 'values/integrator.micro_steps' | tr '\n' ' ')" = \
  "4 4 4 4 1 1 1 1 " ] && [ "$(column over.h5 seed | tr '\n' ' ')" = \
  "0 1 0 1 0 1 0 1 " ] && h5dump -a keys over.h5 | tr -d '\n' |
  grep -q 'integrator.micro_steps.*integrator.macro_step.*integrator.t_end.*output.micro'; then
  pass "--vary replaces the file's key in place, new keys follow, --seeds"
else
  fail "command line over the section: $(column over.h5 'values/integrator.micro_steps' | tr '\n' ' ')"
fi
# Errors in the section: file:line:col, before anything is written.
bad_section() { # NAME SED-EXPRESSION EXPECTED-MESSAGE
  sed "$2" sec.yaml >bs.yaml
  "$mrvi" batch bs.yaml -o bs.h5 -q 2>err.txt
  local rc=$?
  if [ $rc = 1 ] && grep -q -F -- "$3" err.txt && [ ! -e bs.h5 ]; then
    pass "batch: section, $1"
  else
    fail "batch: section, $1 (exit $rc): $(cat err.txt)"
  fi
}
line=$(grep -n '^  jobs: 2' sec.yaml | cut -d: -f1)
bad_section "unknown key" 's/^  jobs: 2/  sedes: 2/' \
  "bs.yaml:$line:3: unknown key 'sedes' in batch; did you mean 'seeds'?"
bad_section "seeds out of range" 's/^  jobs: 2/  seeds: -3/' \
  "bs.yaml:$line:10: batch.seeds must be 0..1000000, got -3"
line=$(grep -n 'macro_step: 0.01,0.02' sec.yaml | cut -d: -f1)
bad_section "malformed linspace" 's/0.01,0.02/linspace(1,2)/' \
  "bs.yaml:$line:28: batch.vary: --vary integrator.macro_step=linspace(1,2): expected linspace(a,b,n)"
bad_section "a list item not a value" 's/\[1, 2, 4\]/[1, {a: 2}]/' \
  "batch.vary.integrator.micro_steps: a value must be a number or a word"
"$mrvi" check bs.yaml >/dev/null 2>err.txt
[ $? != 0 ] && grep -q "a value must be a number or a word" err.txt &&
  pass "mrvi check refuses a bad batch: section too" ||
  fail "mrvi check refuses a bad batch: section too: $(cat err.txt)"

# --- --jobs 1 equals --jobs 2 ---
run_ok "batch --jobs 1" "$mrvi" batch "$fpu" -o j1.h5 -q -j 1 \
  --vary integrator.micro_steps=1,2,4 --vary integrator.macro_step=0.01,0.02 \
  --vary "$short"
printf '%s\n' 0:0 1:1 2:2 3:3 4:4 5:5 | same_runs b.h5 j1.h5 &&
  same_table b.h5 j1.h5 && pass "--jobs 2 equals --jobs 1" ||
  fail "--jobs 2 equals --jobs 1"

# --- the default jobs: the idle cores (as --threads auto counts them) ---
# Under taskset -c 0,1 with three busy tasks running (the fourth field of
# /proc/loadavg counts them, the machine's other tasks only add to it) no
# core is idle: the default is 1 job, --threads 2 alone 1 job of 2
# threads, and only --jobs with --threads goes above (asked for).
if busy_start; then
  grid=(--vary integrator.micro_steps=1,2,4 --vary "$short")
  taskset -c 0,1 "$mrvi" batch "$fpu" -o idle1.h5 "${grid[@]}" 2>err1.txt
  rc1=$?
  threads_ok=0
  if "$mrvi" check "$fpu" --threads 2 >/dev/null 2>&1; then
    threads_ok=1
    taskset -c 0,1 "$mrvi" batch "$fpu" -o idle2.h5 --threads 2 "${grid[@]}" \
      2>err2.txt
    rc2=$?
    taskset -c 0,1 "$mrvi" batch "$fpu" -o idle3.h5 --threads 2 -j 3 \
      "${grid[@]}" 2>err3.txt
    rc3=$?
  fi
  busy_stop
  [ $rc1 = 0 ] && grep -q "3 cases on 1 job x 1 thread " err1.txt &&
    pass "busy cores: the default batch runs 1 job x 1 thread" ||
    fail "busy cores: the default batch (exit $rc1): $(grep cases err1.txt)"
  if [ $threads_ok = 1 ]; then
    [ $rc2 = 0 ] && grep -q "3 cases on 1 job x 2 threads " err2.txt &&
      pass "busy cores: --threads 2 alone runs 1 job x 2 threads" ||
      fail "busy cores: --threads 2 (exit $rc2): $(grep cases err2.txt)"
    [ $rc3 = 0 ] && grep -q "3 cases on 3 jobs x 2 threads " err3.txt &&
      pass "busy cores: --jobs 3 --threads 2 as asked" ||
      fail "busy cores: --jobs 3 --threads 2 (exit $rc3): $(grep cases err3.txt)"
  fi
fi
# Without them: jobs x threads within the cores available.
if "$mrvi" check "$fpu" --threads 2 >/dev/null 2>&1; then
  run_ok "batch --threads 2" "$mrvi" batch "$fpu" -o t2.h5 --threads 2 \
    --vary integrator.micro_steps=1,2,4 --vary integrator.macro_step=0.01,0.02 \
    --vary "$short"
  cores=$(nproc)
  jobs=$(sed -n 's/.*6 cases on \([0-9]*\) jobs\{0,1\} x 2 threads.*/\1/p' \
    "$tmp/err.txt")
  if [ -n "$jobs" ] && [ "$jobs" -ge 1 ] &&
    { [ "$jobs" = 1 ] || [ $((jobs * 2)) -le "$cores" ]; }; then
    pass "--threads 2: $jobs jobs x 2 threads on $cores cores"
  else
    fail "--threads 2 on $cores cores: $(grep cases "$tmp/err.txt")"
  fi
fi

# --- --zip ---
run_ok "batch --zip" "$mrvi" batch "$fpu" -o z.h5 -q --zip \
  --vary integrator.micro_steps=1,4 --vary integrator.macro_step=0.01,0.02 \
  --vary integrator.t_end=20,20
printf '%s\n' 0:0 1:5 | same_runs z.h5 b.h5 && pass "--zip pairs the values" ||
  fail "--zip pairs the values"
"$mrvi" batch "$fpu" -o z2.h5 --zip --vary integrator.micro_steps=1,2 \
  --vary integrator.macro_step=0.01 2>err.txt
[ $? = 1 ] && grep -q "equal lengths" err.txt && pass "--zip needs equal lengths" ||
  fail "--zip needs equal lengths"

# --- a bad value in case 4 is refused before any case runs ---
"$mrvi" batch "$fpu" -o bad.h5 --vary integrator.micro_steps=1,2,x \
  --vary integrator.macro_step=0.01,0.02 2>err.txt
rc=$?
if [ $rc = 1 ] && grep -q "case 4 (integrator.micro_steps=x" err.txt &&
  [ ! -e bad.h5 ] && [ ! -e bad.cases ]; then
  pass "bad override refused before any case, naming case and key"
else
  fail "bad override refused before any case (exit $rc): $(cat err.txt)"
fi
"$mrvi" batch "$fpu" -o bad.h5 --vary 'integrator.macro_step=linspace(1,2)' \
  2>err.txt
[ $? = 1 ] && grep -q "linspace(a,b,n)" err.txt && pass "malformed linspace" ||
  fail "malformed linspace"

# --- linspace / logspace values ---
run_ok "linspace" "$mrvi" batch "$fpu" -o lin.h5 -q \
  --vary 'integrator.macro_step=logspace(-2,-1,3)' --vary "$short"
if [ "$(column lin.h5 'values/integrator.macro_step' | tr '\n' ' ')" = \
  "0.01 0.0316228 0.1 " ]; then
  pass "logspace(-2,-1,3) values"
else
  fail "logspace values: $(column lin.h5 'values/integrator.macro_step')"
fi

# --- a failing case is recorded, the others complete ---
"$mrvi" batch "$fpu" -o f.h5 -q -j 2 --vary integrator.macro_step=0.02,2,0.01 \
  --vary integrator.t_end=40 2>err.txt
rc=$?
if [ $rc = 2 ] && [ "$(column f.h5 status | tr '\n' ' ')" = "1 2 1 " ] &&
  column f.h5 stop_reason | sed -n 2p | grep -q "Newton did not converge"; then
  pass "failing case recorded with its reason, others completed"
else
  fail "failing case recorded (exit $rc): $(column f.h5 status | tr '\n' ' ')"
fi

# --- a reader holding the master file open does not stop the batch ---
# HDF5 readers (h5py, h5dump) hold a shared flock on the file; the rows are
# written without HDF5's lock, so they are written all the same (before,
# the row failed with "Resource temporarily unavailable", the batch stopped
# and the finished case's row was lost).
"$mrvi" batch "$fpu" -o rd.h5 -q -j 1 --vary integrator.micro_steps=1,2 \
  --vary integrator.t_end=3000 --vary output.every=100 2>err.txt &
pid=$!
for _ in $(seq 1 200); do
  [ -s rd.h5 ] && break
  sleep 0.01
done
(
  flock -s 9
  while kill -0 $pid 2>/dev/null; do sleep 0.02; done
) 9<rd.h5
wait $pid
rc=$?
if [ $rc = 0 ] && [ "$(column rd.h5 status | tr '\n' ' ')" = "1 1 " ]; then
  pass "rows written while a reader holds the master file"
else
  fail "rows written while a reader holds the master file (exit $rc): $(cat err.txt)"
fi

# --- SIGKILL of the parent, then --resume ---
# Cases long enough (a few tenths of a second each in the plain build) that
# a kill lands while cases run, however fast the machine.
long=(--vary integrator.micro_steps=1,2,3,4 --vary integrator.macro_step=0.01,0.02
  --vary integrator.t_end=3000 --vary output.every=100 --vary output.micro=false)
run_ok "uninterrupted batch" "$mrvi" batch "$fpu" -o full.h5 -q -j 2 "${long[@]}"
# Kill once some but not all cases are done.  Where no completed case was
# seen before the kill (a machine too loaded to see one within the polls),
# the kill proves nothing: start again, at most three times.  A case seen
# completed and missing from the table after the kill fails.
for attempt in 1 2 3; do
  rm -rf k.h5 k.cases
  "$mrvi" batch "$fpu" -o k.h5 -q -j 2 "${long[@]}" 2>/dev/null &
  pid=$!
  seen=0
  for _ in $(seq 1 200); do
    n=$(column k.h5 status 2>/dev/null | grep -c '^1$')
    if [ "${n:-0}" -ge 1 ]; then
      seen=1
      break
    fi
    sleep 0.05
  done
  workers=$(pgrep -P $pid)
  {
    kill -9 $pid
    wait $pid
  } 2>/dev/null
  # The workers die with the parent; wait until they are gone (a loaded
  # machine may take a while), so that none still holds a case file.
  for _ in $(seq 1 500); do
    alive=0
    for w in $workers; do kill -0 "$w" 2>/dev/null && alive=1; done
    [ $alive = 0 ] && break
    sleep 0.02
  done
  done_before=$(column k.h5 status | grep -c '^1$')
  [ $seen = 1 ] && break
done
if [ "$done_before" -ge 1 ] && [ "$done_before" -lt 8 ]; then
  pass "killed mid-batch: table readable, $done_before of 8 completed"
else
  fail "killed mid-batch: $done_before of 8 completed (a completed case seen before the kill: $seen)"
fi
"$mrvi" batch --resume k.h5 -j 2 >out.txt 2>err.txt
rc=$?
left=$(sed -n 's/.*: \([0-9]*\) cases* left.*/\1/p' err.txt)
if [ $rc = 0 ] && [ "$left" = $((8 - done_before)) ] &&
  [ "$(column k.h5 status | grep -c '^1$')" = 8 ]; then
  pass "--resume ran only the $left unfinished cases"
else
  fail "--resume (exit $rc, left '$left', done before $done_before)"
fi
seq 0 7 | sed 's/.*/&:&/' | same_runs k.h5 full.h5 && same_table k.h5 full.h5 &&
  pass "resumed batch equals the uninterrupted one" ||
  fail "resumed batch equals the uninterrupted one"

# --- SIGKILL of a worker: its case stays pending, --resume runs it ---
"$mrvi" batch "$fpu" -o w.h5 -q -j 2 "${long[@]}" 2>err.txt &
pid=$!
# Kill a worker as soon as a case has started (its file exists): both
# workers are then inside a case.
worker=
for _ in $(seq 1 400); do
  if compgen -G 'w.cases/case_*.h5' >/dev/null; then
    worker=$(pgrep -P $pid | head -n 1)
    [ -n "$worker" ] && break
  fi
  sleep 0.01
done
[ -n "$worker" ] && kill -9 "$worker"
wait $pid
rc=$?
pending=$(column w.h5 status | grep -c '^0$')
if [ $rc = 2 ] && [ "$pending" -ge 1 ] && grep -q "killed by signal 9" err.txt; then
  pass "killed worker: its case pending, the others ran ($pending pending)"
else
  fail "killed worker (exit $rc, $pending pending)"
fi
run_ok "--resume after a killed worker" "$mrvi" batch --resume w.h5 -q
seq 0 7 | sed 's/.*/&:&/' | same_runs w.h5 full.h5 && same_table w.h5 full.h5 &&
  pass "batch with a killed worker, resumed, equals the uninterrupted one" ||
  fail "batch with a killed worker, resumed, equals the uninterrupted one"
"$mrvi" batch --resume run0.h5 2>err.txt
[ $? = 1 ] && grep -q "batch_version" err.txt &&
  pass "--resume of a run file is refused" ||
  fail "--resume of a run file is refused: $(cat err.txt)"
"$mrvi" batch --resume full.h5 -q 2>err.txt
[ $? = 0 ] && pass "--resume of a finished batch runs nothing" ||
  fail "--resume of a finished batch"

# --- ensembles: seeds ---
ens=(--seeds 3 --velocity-std 0.05 --vary "$short")
run_ok "ensemble, --jobs 1" "$mrvi" batch "$fpu" -o e1.h5 -q -j 1 \
  --vary integrator.micro_steps=1,2 "${ens[@]}"
run_ok "ensemble, --jobs 2" "$mrvi" batch "$fpu" -o e2.h5 -q -j 2 \
  --vary integrator.micro_steps=1,2 "${ens[@]}"
run_ok "ensemble, one parameter point" "$mrvi" batch "$fpu" -o e3.h5 -q -j 1 \
  --vary integrator.micro_steps=2 "${ens[@]}"
[ "$(column e1.h5 seed | tr '\n' ' ')" = "0 1 2 0 1 2 " ] &&
  pass "seed column" || fail "seed column: $(column e1.h5 seed)"
seq 0 5 | sed 's/.*/&:&/' | same_runs e1.h5 e2.h5 &&
  pass "seeded cases equal on 1 and 2 jobs" ||
  fail "seeded cases equal on 1 and 2 jobs"
printf '%s\n' 3:0 4:1 5:2 | same_runs e1.h5 e3.h5 &&
  pass "a seeded case equals itself run in another batch" ||
  fail "a seeded case equals itself run in another batch"
printf '%s\n' 3:4 | same_runs e1.h5 e1.h5 &&
  fail "seeds 0 and 1 give different perturbations" ||
  pass "seeds 0 and 1 give different perturbations"
# The case file says how its velocities differ from its description text.
if h5dump -d /model/description e1.cases/case_0004.h5 |
  grep -q "mrvi batch, seed 1: the initial velocities are the above plus 0.05" &&
  ! h5dump -d /model/description b.cases/case_0000.h5 | grep -q "mrvi batch"; then
  pass "the perturbation is noted in a seeded case's /model/description"
else
  fail "the perturbation is noted in a seeded case's /model/description"
fi
h5diff "e3.cases/case_0000.h5" run2.h5 >/dev/null 2>&1 &&
  fail "a perturbed case differs from the unperturbed run" ||
  pass "a perturbed case differs from the unperturbed run"

# A perturbed constrained model: the velocities stay on the constraints'
# tangent space (|G M^-1 p| at node 0 at roundoff level), and differ by seed.
run_ok "ensemble of a constrained model" "$mrvi" batch \
  "$root/systems/pendulum_chain.yaml" -o pc.h5 -q --seeds 2 \
  --velocity-std 0.1 --vary integrator.t_end=0.2
ok=1
for c in 0 1; do
  h=$(h5dump -y -d "/macro/hidden_constraint_residual[0;;1;]" \
    "pc.cases/case_000$c.h5" | sed -n '/DATA {/,/}/p' | sed '1d;$d' | tr -d ' ')
  awk -v h="$h" 'BEGIN { exit !(h != "" && h + 0 < 1e-12) }' || ok=0
done
h5diff pc.cases/case_0000.h5 pc.cases/case_0001.h5 "/macro/p" "/macro/p" \
  >/dev/null 2>&1 && ok=0
[ "$ok" = 1 ] && pass "perturbed velocities satisfy the constraints" ||
  fail "perturbed velocities satisfy the constraints"

test_finish
