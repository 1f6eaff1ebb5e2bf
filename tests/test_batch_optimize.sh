#!/usr/bin/env bash
# mrvi batch --optimize (doc/batch.md, "Multi-start optimal control"): four
# seeds of systems/ocp_double_integrator.yaml start from four distinct
# initial guesses, every case is an `mrvi optimize` whose file equals the
# standalone `mrvi optimize --set control.actuators.0.initial=[...]` of its
# guess (h5diff), all reach the discrete optimum J_N = 300/99 (a convex
# problem: one optimum whatever the start), the table holds cost,
# violation, evaluations and NLopt's reason and /best_case the argmin;
# --jobs 1 equals --jobs 2; a case that does not converge is recorded as
# failed with the optimiser's status; --control-std is refused without
# --optimize; the batch: section's command: optimize gives the same batch;
# --resume runs only the pending cases and gives the uninterrupted batch;
# a batch killed while optimising leaves each started case's progress file.
#
#   test_batch_optimize.sh MRVI_BINARY SOURCE_ROOT
#
# Prints "N passed, M failed" and exits non-zero on any failure.
set -u

mrvi=${1:?usage: test_batch_optimize.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_batch_optimize.sh MRVI_BINARY SOURCE_ROOT}
ocp=$root/systems/ocp_double_integrator.yaml

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
# shellcheck source=tests/batchlib.sh
. "$(dirname "$0")/batchlib.sh"

cd "$tmp" || exit 1

# guess CASE_FILE: the start's override, as the case's description names it.
guess() {
  h5dump -d /model/description "$1" 2>/dev/null |
    grep -o -- 'control\.actuators\.0\.initial=\[[^]]*\]'
}

# numbers FILE NAME: /cases/NAME to 17 digits, one per line.
numbers() {
  h5dump -m %.17g -d "/cases/$2" "$1" 2>/dev/null | sed -n '/DATA {/,/}/p' |
    sed '1d;$d' | sed 's/([0-9]*)://' | tr ',' '\n' | sed 's/ //g;/^$/d'
}

# --- four starts ---
run_ok "batch --optimize, 4 seeds, --jobs 2" "$mrvi" batch "$ocp" -o ms.h5 \
  -j 2 --optimize --seeds 4 --control-std 2
if [ "$(column ms.h5 status | tr '\n' ' ')" = "1 1 1 1 " ]; then
  pass "four optimize cases converged"
else
  fail "four optimize cases converged: $(column ms.h5 status | tr '\n' ' ')"
fi
for c in 0 1 2 3; do guess "ms.cases/case_000$c.h5"; done >guesses.txt
if [ "$(wc -l <guesses.txt)" = 4 ] && [ "$(sort -u guesses.txt | wc -l)" = 4 ]; then
  pass "four distinct initial guesses"
else
  fail "four distinct initial guesses: $(cat guesses.txt)"
fi
# 10 values each, not all equal (a perturbation per value, not per actuator)
n=$(sed -n 1p guesses.txt | sed 's/.*\[//;s/\]//' | tr ',' '\n' | sort -u | wc -l)
[ "$n" = 10 ] && pass "a start has 10 distinct values" ||
  fail "a start has 10 distinct values ($n)"
ok=1
for c in 0 3; do
  "$mrvi" optimize "$ocp" -q -o "alone$c.h5" \
    --set "$(guess "ms.cases/case_000$c.h5")" >/dev/null 2>&1 || ok=0
  h5diff "ms.cases/case_000$c.h5" "alone$c.h5" >/dev/null 2>&1 || ok=0
done
[ "$ok" = 1 ] && pass "case files equal mrvi optimize --set of their guess (h5diff)" ||
  fail "case files equal mrvi optimize --set of their guess (h5diff)"
# J_N = J* N^2 / (N^2 - 1) = 300/99 for every start (the problem is convex).
if numbers ms.h5 cost | awk '{ d = $1 - 300 / 99; if (d < 0) d = -d;
    if (d > 1e-9) bad = 1 } END { exit bad }' &&
  [ "$(numbers ms.h5 cost | wc -l)" = 4 ]; then
  pass "every start reaches J_N = 300/99 to 1e-9"
else
  fail "every start reaches J_N = 300/99: $(numbers ms.h5 cost | tr '\n' ' ')"
fi
column ms.h5 violation | awk '{ if ($1 > 1e-10 || $1 != $1) bad = 1 }
  END { exit bad }' && pass "terminal violations below 1e-10" ||
  fail "terminal violations: $(column ms.h5 violation | tr '\n' ' ')"
column ms.h5 evaluations | awk '{ if ($1 < 2) bad = 1 } END { exit bad }' &&
  pass "evaluations recorded" ||
  fail "evaluations: $(column ms.h5 evaluations | tr '\n' ' ')"
[ "$(column ms.h5 nlopt_result | sort -u)" = '"FTOL_REACHED"' ] &&
  pass "NLopt's stop reason recorded" ||
  fail "NLopt's stop reason: $(column ms.h5 nlopt_result | tr '\n' ' ')"
# /best_case: the index of the lowest cost, named in the summary.
best=$(h5dump -d /best_case ms.h5 | sed -n 's/^ *(0): *//p' | head -1)
argmin=$(numbers ms.h5 cost | awk '{ v = $1 + 0;
  if (n == 0 || v < m) { m = v; i = n } n++ } END { print i }')
if [ -n "$best" ] && [ "$best" = "$argmin" ] &&
  grep -q "best case $best, cost" "$tmp/out.txt"; then
  pass "/best_case $best is the lowest cost and named in the summary"
else
  fail "/best_case '$best', lowest cost at '$argmin': $(cat "$tmp/out.txt")"
fi

# --- --jobs 1 equals --jobs 2 ---
run_ok "batch --optimize --jobs 1" "$mrvi" batch "$ocp" -o j1.h5 -q -j 1 \
  --optimize --seeds 4 --control-std 2
printf '%s\n' 0:0 1:1 2:2 3:3 | same_runs ms.h5 j1.h5 &&
  same_table ms.h5 j1.h5 && pass "--jobs 1 equals --jobs 2" ||
  fail "--jobs 1 equals --jobs 2"

# --- the batch: section ---
cp "$ocp" sec.yaml
cat >>sec.yaml <<'EOF'
batch:
  command: optimize
  seeds: 4
  control_std: 2
EOF
run_ok "batch: section with command: optimize" "$mrvi" batch sec.yaml -o sec.h5 -q
for c in 0 1 2 3; do guess "sec.cases/case_000$c.h5"; done >sec_guesses.txt
cmp -s guesses.txt sec_guesses.txt && same_table sec.h5 ms.h5 &&
  pass "the section's starts and table equal the command line's" ||
  fail "the section's starts and table equal the command line's"
sed 's/command: optimize/command: optimise/' sec.yaml >bad.yaml
"$mrvi" batch bad.yaml -o bad.h5 2>err.txt
[ $? = 1 ] && grep -q "batch.command must be 'run' or 'optimize'" err.txt &&
  pass "batch.command: a bad value refused" ||
  fail "batch.command: a bad value refused: $(cat err.txt)"

# --- refusals and a failing case ---
"$mrvi" batch "$ocp" -o bad.h5 --seeds 2 --control-std 1 2>err.txt
[ $? = 1 ] && grep -q -- "--control-std" err.txt && [ ! -e bad.h5 ] &&
  pass "--control-std without --optimize refused" ||
  fail "--control-std without --optimize refused: $(cat err.txt)"
"$mrvi" batch "$root/systems/fpu.yaml" -o bad.h5 --optimize 2>err.txt
[ $? = 1 ] && [ ! -e bad.h5 ] && grep -q "case 0" err.txt &&
  pass "--optimize of a file without control: refused before any case" ||
  fail "--optimize of a file without control: $(cat err.txt)"
"$mrvi" batch "$ocp" -o fail.h5 -q --optimize --seeds 2 --control-std 2 \
  --vary control.solver.max_evaluations=2,100 2>err.txt
rc=$?
if [ $rc = 2 ] && [ "$(column fail.h5 status | tr '\n' ' ')" = "2 2 1 1 " ] &&
  column fail.h5 stop_reason | sed -n 1p | grep -q max_evaluations &&
  [ -e fail.cases/case_0000.h5 ]; then
  pass "a case that does not converge is recorded failed, the others complete"
else
  fail "non-converged case (exit $rc): $(column fail.h5 status | tr '\n' ' ') $(column fail.h5 stop_reason | sed -n 1p)"
fi

# --- --resume runs only the pending cases ---
if /usr/bin/python3 -c "import h5py" 2>/dev/null; then
  cp ms.h5 r.h5 && mkdir -p r.cases && cp ms.cases/case_0000.h5 \
    ms.cases/case_0002.h5 r.cases/
  # Cases 1 and 3 never ran: pending, no file, no row.
  /usr/bin/python3 - <<'EOF'
import h5py, math
with h5py.File("r.h5", "r+") as f:
    for c in (1, 3):
        f["/cases/status"][c] = 0
        f["/cases/cost"][c] = math.nan
        f["/cases/evaluations"][c] = 0
    f["/best_case"][()] = -1
EOF
  "$mrvi" batch --resume r.h5 -j 2 >out.txt 2>err.txt
  rc=$?
  if [ $rc = 0 ] && grep -q "2 cases left" err.txt &&
    [ "$(grep -c 'case [0-9]*: completed' err.txt)" = 2 ] &&
    grep -q "case 1: completed" err.txt && grep -q "case 3: completed" err.txt; then
    pass "--resume ran only the 2 pending cases"
  else
    fail "--resume (exit $rc): $(cat err.txt)"
  fi
  printf '%s\n' 0:0 1:1 2:2 3:3 | same_runs r.h5 ms.h5 && same_table r.h5 ms.h5 &&
    h5diff r.h5 ms.h5 /best_case /best_case >/dev/null 2>&1 &&
    pass "resumed batch equals the uninterrupted one, /best_case included" ||
    fail "resumed batch equals the uninterrupted one"
else
  echo "skipped: --resume of an optimize batch (needs python3-h5py)"
fi


# --- a batch killed while optimising leaves each started case's progress
# file (as mrvi optimize does): readable, stop_reason and status running,
# /control/u of the problem's shape (ocp_fpu to t = 40: 400 x 1), no
# /macro, history rows = its evaluations.  The parent is killed (SIGKILL)
# half a second after both case files exist; its workers die with it. ---
if /usr/bin/python3 -c "import h5py" 2>/dev/null; then
  "$mrvi" batch "$root/systems/ocp_fpu.yaml" -o kb.h5 -q -j 2 --optimize \
    --seeds 2 --control-std 0.5 --vary integrator.t_end=40 >/dev/null 2>&1 &
  pid=$!
  for _ in $(seq 1 1000); do # at most 10 s
    [ -s kb.cases/case_0000.h5 ] && [ -s kb.cases/case_0001.h5 ] && break
    sleep 0.01
  done
  sleep 0.5
  kill -KILL $pid 2>/dev/null
  wait $pid 2>/dev/null
  rc=$?
  check=$(/usr/bin/python3 - <<'EOF' 2>&1
import h5py
t = lambda v: v.decode() if isinstance(v, bytes) else v
out = []
for c in (0, 1):
    f = h5py.File("kb.cases/case_%04d.h5" % c, "r")
    o = f["optimizer"]
    h = o["history"]
    out.append(t(f.attrs["stop_reason"]) == "running" and
               t(o.attrs["status"]) == "running" and "macro" not in f and
               f["control/u"].shape == (400, 1) and h.shape[1] == 4 and
               int(o.attrs["evaluations"]) == h.shape[0])
print(out)
EOF
)
  if [ "$rc" = 137 ] && [ "$check" = "[True, True]" ]; then
    pass "batch killed while optimising: both case files are progress files (running, 400 x 1 controls, history = evaluations)"
  else
    fail "batch killed while optimising (exit $rc): $check"
  fi
else
  echo "skipped: kill of an optimize batch (needs python3-h5py)"
fi

test_finish
