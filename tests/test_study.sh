#!/usr/bin/env bash
# The analysis commands end to end: mrvi converge (orders on the FPU, p = 5:
# 2 +- 0.25 midpoint-midpoint, 1 +- 0.25 the two trapezoidal schemes; cache
# and --reference give the same table; without --dt0 the range is chosen and
# the README command gives 2 and 1; a coarse range warns), mrvi stability (measured bounds
# within 1 % of Lemma lemma:stability_slow), mrvi timing (table, failures).
# Usage: test_study.sh MRVI SOURCE_ROOT
set -u
mrvi=$1
root=$2
# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
cd "$tmp" || exit 1
passed=0
failed=0
check() { # check DESCRIPTION CONDITION-STATUS
  if [ "$2" -eq 0 ]; then
    passed=$((passed + 1))
  else
    failed=$((failed + 1))
    echo "FAIL: $1" >&2
  fi
}
# within VALUE TARGET TOL -> status 0 when |VALUE - TARGET| <= TOL
within() { awk -v v="$1" -v t="$2" -v d="$3" 'BEGIN { exit !(v != "" && (v - t <= d) && (t - v <= d)) }'; }
fitted() { sed -n 's/^fitted order on macro nodes: q \([-0-9.na]*\), p \([-0-9.na]*\)$/\1 \2/p' "$1"; }

fpu=$root/systems/fpu.yaml
# --- converge: orders ------------------------------------------------------
study() { # study NAME EXPECTED ARGS...: orders within 0.25 of EXPECTED
  local name=$1 expect=$2
  shift 2
  "$mrvi" converge "$fpu" --p 5 -o "$name.h5" --csv "$name.csv" "$@" >"$name.out" 2>"$name.err"
  check "$name: exit status" $?
  read -r oq op < <(fitted "$name.out" | head -n 1)
  within "${oq:-}" "$expect" 0.25
  check "$name: order in q ${oq:-none} (expected $expect)" $?
  within "${op:-}" "$expect" 0.25
  check "$name: order in p ${op:-none} (expected $expect)" $?
  echo "$name: fitted orders q ${oq:-?} p ${op:-?}"
}
study midmid 2 --levels 4 --dt0 0.02 --t-end 0.5
study trapmid 1 --levels 4 --dt0 5e-4 --t-end 0.1 --set integrator.scheme=trapezoidal-midpoint
study traptrap 1 --levels 4 --dt0 0.02 --t-end 0.5 --set integrator.scheme=trapezoidal-trapezoidal

# The README's command: without --dt0 the range is chosen (halving until
# the orders of the last 4 rows agree within 0.3), orders within 0.25 of
# the theory, no warning.  Before, it started at dT = 0.3 (0.96 / 0.52).
readme() { # readme NAME EXPECTED ARGS...
  study "$@"
  [ ! -s "$1.err" ]
  check "$1: no warning ($(cat "$1.err"))" $?
  grep -q '^skipped the macro steps 0.125 \.\.\. ' "$1.out"
  check "$1: the pre-asymptotic steps are named" $?
}
readme readme-midmid 2
readme readme-trapmid 1 --set integrator.scheme=trapezoidal-midpoint
# Newton limited to 2 iterations fails at dT = 0.125 and 0.0625: the chosen
# range halves on past the failed runs; a fixed range stops with exit 2.
readme readme-newton2 2 --set integrator.newton.max_iterations=2
grep -q '^dT = 0.125, p = 5 failed, trying smaller steps: step 1 .*Newton' readme-newton2.out
check "converge: a failed coarse run is named and skipped" $?
"$mrvi" converge "$fpu" --p 5 --dt0 0.125 --levels 2 --set integrator.newton.max_iterations=2 -q -o fixed.h5 2>fixed.err
[ $? -eq 2 ] && grep -q 'run dT = 0.125, p = 5 failed' fixed.err
check "converge --dt0: a failed run stops the study (exit 2)" $?
# An invalid description: its error once, exit 1.
"$mrvi" converge "$fpu" --set integrator.micro_steps=0 -q 2>bad.err
[ $? -eq 1 ] && [ "$(wc -l <bad.err)" -eq 1 ] && grep -q '^--set integrator.micro_steps=0: micro_steps must be >= 1' bad.err
check "converge: an invalid description is reported once ($(cat bad.err))" $?
# A given range outside the asymptotic one is computed, with a warning.
"$mrvi" converge "$fpu" --p 5 --dt0 0.3 --levels 4 -o coarse.h5 >coarse.out 2>coarse.err
check "converge --dt0 0.3: exit status" $?
grep -q '^mrvi converge: warning: p = 5: consecutive observed orders of e_[qp]^mac differ by up to [0-9.]* (more than 0.3): the macro steps 0.3 \.\.\. 0.0375 are not all in the asymptotic range' coarse.err
check "converge --dt0 0.3: warning that the orders disagree ($(cat coarse.err))" $?
[ "$(wc -l <coarse.err)" -eq 1 ]
check "converge --dt0 0.3: one warning line" $?

# The second run of a study reads the cached reference and gives the same table.
"$mrvi" converge "$fpu" --p 5 --levels 4 --dt0 0.02 --t-end 0.5 -o again.h5 --csv again.csv >again.out 2>&1
grep -q "(cached)" again.out
check "converge: reference read from the cache" $?
cmp -s midmid.csv again.csv
check "converge: cached reference gives the same table" $?

# A reference given as an mrvi run file (h = 0.0025/5/8 = 6.25e-5, p = 1).
"$mrvi" run "$fpu" --set integrator.macro_step=6.25e-5 --set integrator.micro_steps=1 \
  --set integrator.t_end=0.5 -o ref.h5 --quiet
check "converge: reference run" $?
"$mrvi" converge "$fpu" --p 5 --levels 4 --dt0 0.02 --t-end 0.5 --reference ref.h5 \
  --csv given.csv -q
check "converge --reference: exit status" $?
cmp -s midmid.csv given.csv
check "converge --reference gives the computed-reference table" $?
# A reference whose step does not divide the micro step is refused.
"$mrvi" converge "$fpu" --p 3 --levels 2 --dt0 0.02 --t-end 0.5 --reference ref.h5 -q 2>bad.err
[ $? -eq 1 ] && grep -q "does not divide" bad.err
check "converge: non-dividing reference refused" $?
"$mrvi" converge "$fpu" --dt 0.02,abc -q 2>bad.err
[ $? -eq 1 ] && grep -q "not a finite number" bad.err
check "converge: bad --dt refused" $?
[ -f midmid.h5 ] && [ "$(wc -l <midmid.csv)" -eq 5 ]
check "converge: table files (HDF5 and 4 CSV rows)" $?

# --- converge --jobs: the runs on worker processes, the same table --------
# Fixed range (every row in one map) with 2 p, and the chosen range (rows
# deepened with the reference, the last ones one at a time); --jobs 1 is the
# serial path in this process.
for mode in fixed chosen; do
  case $mode in
  fixed) range="--dt0 0.05 --levels 4" ;;
  chosen) range="" ;;
  esac
  for j in 1 2 3; do
    # shellcheck disable=SC2086
    "$mrvi" converge "$fpu" --p 5,10 $range --no-cache --jobs $j -o "j$mode$j.h5" \
      --csv "j$mode$j.csv" >"j$mode$j.out" 2>"j$mode$j.err"
    check "converge --jobs $j ($mode): exit status ($(cat "j$mode$j.err"))" $?
    sed -i '/^table: /d' "j$mode$j.out"
  done
  for j in 2 3; do
    cmp -s "j${mode}1.csv" "j$mode$j.csv" && cmp -s "j${mode}1.out" "j$mode$j.out" &&
      cmp -s "j${mode}1.err" "j$mode$j.err"
    check "converge --jobs $j ($mode): the table, output and warnings of --jobs 1" $?
    if command -v h5diff >/dev/null; then
      h5diff -q "j${mode}1.h5" "j$mode$j.h5"
      check "converge --jobs $j ($mode): h5diff of the table files" $?
    fi
  done
done
# A run that fails in a worker: reported as by the serial path.
for j in 1 2; do
  "$mrvi" converge "$fpu" --p 5 --dt0 0.125 --levels 3 --jobs $j \
    --set integrator.newton.max_iterations=2 -q -o jfail$j.h5 2>jfail$j.err
  echo $? >>jfail$j.err
done
cmp -s jfail1.err jfail2.err && grep -q 'run dT = 0.125, p = 5 failed' jfail2.err &&
  [ "$(tail -1 jfail2.err)" = 2 ]
check "converge --jobs 2: a failed run reported as with --jobs 1 ($(cat jfail2.err))" $?
readme readme-newton2-j2 2 --set integrator.newton.max_iterations=2 --jobs 2
sed '/^table: /d;/^reference: /d' readme-newton2.out >jn1.out
sed '/^table: /d;/^reference: /d' readme-newton2-j2.out >jn2.out
cmp -s jn1.out jn2.out
check "converge --jobs 2: failed coarse runs skipped as with the default jobs" $?
# A worker killed mid-run stops the study, naming the signal and the run
# (the runs of t_end = 40 take long enough to be caught running).
"$mrvi" converge "$fpu" --no-cache --jobs 2 --dt0 0.01 --levels 5 --p 5,10 \
  --t-end 40 --ref-step 6.25e-5 -q -o jkill.h5 2>jkill.err &
study_pid=$!
kid=
for _ in $(seq 1200); do
  kid=$(pgrep -P "$study_pid" | head -1)
  [ -n "$kid" ] && break
  sleep 0.05
done
[ -n "$kid" ] && kill -KILL "$kid"
wait "$study_pid"
[ $? -eq 2 ] && grep -q '^mrvi converge: worker process killed by signal 9 (item [0-9]*)$' jkill.err &&
  [ -z "$(pgrep -P "$study_pid")" ]
check "converge --jobs 2: a killed worker is reported, exit 2 ($(cat jkill.err))" $?
"$mrvi" converge "$fpu" --jobs 0 -q 2>bad.err
[ $? -eq 1 ] && grep -q -- '--jobs must be an integer' bad.err
check "converge: --jobs 0 refused" $?

# doc/reproduce.sh keeps machine paths out of the tracked result tables.
bad=$(grep -rlE '(^|[[:space:](,=:])/[A-Za-z_.-]+/' "$root/doc/results" 2>/dev/null)
[ -z "$bad" ]
check "doc/results names no absolute path (${bad:-none})" $?

# --- stability -------------------------------------------------------------
"$mrvi" stability "$root/systems/oscillator.yaml" --at 3.5 -o stab.h5 >stab.out 2>&1
check "stability: exit status" $?
# Rows "p measured analytic rel.diff measured analytic rel.diff" (midpoint p = 1: stable).
rows=$(awk '$1 ~ /^[0-9]+$/ && NF >= 7 && $3 != "" { n++ } END { print n + 0 }' stab.out)
[ "$rows" -ge 5 ]
check "stability: 5 table rows (got $rows)" $?
worst=$(awk '$1 ~ /^[0-9]+$/ && NF >= 7 { for (i = 4; i <= NF; i += 3) if ($i != "-" && $i + 0 > w) w = $i + 0 } END { print w + 0 }' stab.out)
within "$worst" 0 0.01
check "stability: measured within 1 % of analytic (worst $worst)" $?
awk '$1 == 1 && /stable +uncond/ { found = 1 } END { exit !found }' stab.out
check "stability: midpoint p = 1 unconditionally stable" $?
# --jobs: the 2 x 5 limits and scans on worker processes, the same table.
for j in 1 2 3; do
  "$mrvi" stability "$root/systems/oscillator.yaml" --at 3.5 --jobs $j -o stabj$j.h5 >stabj$j.out 2>&1
  check "stability --jobs $j: exit status" $?
  sed -i '/^table: /d' stabj$j.out
done
for j in 2 3; do
  cmp -s stabj1.out stabj$j.out
  check "stability --jobs $j: the output of --jobs 1" $?
  if command -v h5diff >/dev/null; then
    h5diff -q stabj1.h5 stabj$j.h5
    check "stability --jobs $j: h5diff of the table files" $?
  fi
done
# The default --jobs: the idle cores, as for mrvi batch (test_batch.sh).
# Under taskset -c 0,1 beside three busy tasks no core is idle: the default
# runs the limits and scans in this process (no worker process seen), while
# --jobs 2 beside the same tasks forks its workers (seen: the polling
# catches them).
if busy_start; then
  # workers_seen ARGS...: runs stability ARGS, prints 1 if a child of it
  # was seen while it ran, else 0, then its exit status. Leak detection off:
  # under AddressSanitizer its check at exit runs in a child process.
  workers_seen() {
    ASAN_OPTIONS="${ASAN_OPTIONS:+$ASAN_OPTIONS:}detect_leaks=0" \
      taskset -c 0,1 "$mrvi" stability "$root/systems/oscillator.yaml" -q "$@" &
    local pid=$! seen=0
    while kill -0 "$pid" 2>/dev/null; do
      [ -n "$(pgrep -P "$pid")" ] && seen=1
      sleep 0.02
    done
    wait "$pid"
    echo "$seen $?"
  }
  def=$(workers_seen -o stabdef.h5)
  two=$(workers_seen -o stabtwo.h5 --jobs 2)
  busy_stop
  [ "$def" = "0 0" ] && [ "$two" = "1 0" ]
  check "stability: busy cores, the default runs in this process, --jobs 2 forks (workers seen, exit: default $def, --jobs 2 $two)" $?
fi
"$mrvi" stability "$fpu" -q 2>bad.err
[ $? -eq 1 ] && grep -q "one slow coordinate" bad.err
check "stability: a non-oscillator is refused" $?

# --- writing a table (src/io/study_writer.c) ---------------------------------
# Written beside the output and renamed to it: the replaced file keeps its
# permissions and no temporary file stays behind.
chmod 640 stab.h5
"$mrvi" stability "$root/systems/oscillator.yaml" --p 2 -o stab.h5 -q
[ $? -eq 0 ] && [ "$(stat -c %a stab.h5)" = 640 ] && [ -z "$(ls stab.h5.part* 2>/dev/null)" ]
check "stability: table replaced in place (mode $(stat -c %a stab.h5), no .part file)" $?
"$mrvi" stability "$root/systems/oscillator.yaml" --p 2 -o nodir/stab.h5 -q 2>nodir.err
[ $? -eq 2 ] && grep -q '^mrvi stability: nodir/stab.h5: cannot create the file' nodir.err && [ ! -e nodir ]
check "stability: an output in a missing directory is refused ($(cat nodir.err))" $?
# A file locked by a live writer (as `mrvi run` holds its output) is not
# replaced.
printf 'data\n' >locked.h5
if hold_lock locked.h5; then
  "$mrvi" stability "$root/systems/oscillator.yaml" --p 2 -o locked.h5 -q 2>locked.err
  st=$?
  kill "$lock_holder"
  wait "$lock_holder" 2>/dev/null
  [ $st -eq 2 ] && grep -q 'in use by another run' locked.err && [ "$(cat locked.h5)" = data ]
  check "stability: a locked output is not touched ($(cat locked.err))" $?
else
  check "stability: could not hold a lock on locked.h5" 1
fi

# --- timing ----------------------------------------------------------------
"$mrvi" timing "$fpu" --p 1,10 --t-end 0.5 -o time.h5 --csv time.csv -q
check "timing: exit status" $?
[ -f time.h5 ] && [ "$(grep -c '^[a-z-]*,\(1\|10\),' time.csv)" -eq 6 ]
check "timing: 3 schemes x 2 p rows" $?
awk -F, 'NR > 1 && $1 == "midpoint-midpoint" && $2 == 10 { exit !($8 == 50 && $9 == 33) }' time.csv
check "timing: p = 10 takes 50 macro steps on a 33-unknown system" $?
# --repeat: medians of N runs, said in the header and the file; the
# iterations and steps of every row equal the single run's.
"$mrvi" timing "$fpu" --p 1,10 --t-end 0.5 --repeat 3 -o time3.h5 --csv time3.csv >time3.out
check "timing --repeat 3: exit status" $?
grep -q '^computing time of fpu, .*, times: medians of 3 runs$' time3.out
check "timing --repeat 3: the header says medians of 3 runs" $?
[ "$(cut -d, -f1,2,4,8,9 time3.csv)" = "$(cut -d, -f1,2,4,8,9 time.csv)" ]
check "timing --repeat 3: iterations, steps and sizes of the single run" $?
if command -v h5dump >/dev/null 2>&1; then
  h5dump -a /repeat time3.h5 | grep -q '(0): 3$'
  check "timing --repeat 3: root attribute repeat = 3" $?
fi
"$mrvi" timing "$fpu" --repeat 0 -q 2>rep.err
[ $? -eq 1 ] && grep -q "not a positive integer" rep.err
check "timing --repeat 0 is refused" $?
# p = 1000 (dT = 1) goes unstable on the FPU before t = 100: a NaN row, exit 2.
"$mrvi" timing "$fpu" --p 1000 --schemes midpoint-midpoint --t-end 100 --csv fail.csv -o fail.h5 -q 2>fail.err
[ $? -eq 2 ] && grep -q "failed" fail.err && grep -q ",nan," fail.csv
check "timing: a failed run is a NaN row and exit status 2" $?

echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]
