#!/usr/bin/env bash
# Kill/resume stress test of `mrvi run --resume` (doc/output.md, "Resuming
# a run"; not part of the test suite: it runs for minutes).
#
# For each system: one uninterrupted reference run, then rounds of
#   mrvi run SYSTEM -o out.h5        (a fresh start)
#   repeat: after a random delay, SIGKILL or SIGINT (chosen at random) to
#           the running process; mrvi run --resume out.h5
#   until a run completes (exit 0); then out.h5 must equal the reference
#   bit for bit (h5diff /macro, /micro, /bodies and /joints where the
#   reference has them; root stop_reason completed).
# A round is also cut short (no more signals, the run left to finish) once
# the system's cycle budget is spent.  Every exit status is recorded:
# 130 (SIGINT), 137 (SIGKILL) and 0 (completed) are expected; a resume that
# refuses (the file too short to resume from: killed before its first
# flush) starts the round afresh and is counted; a resume refused because
# the run completed (the signal came as it closed its file) ends the round
# as a completion, counted with the exit status it followed; any other
# status, or a
# completed file that differs, is a failure (its stderr kept in the work
# directory).
#
#   bench/stress_resume.sh MRVI SOURCE_ROOT [CYCLES] [SYSTEM.yaml ...]
#
# CYCLES: signals per system (default 100).  Systems (default): fpu.yaml
# (free chain), cart_pendulum.yaml (multipliers), slider_crank.yaml (a
# closed loop of joints), each lengthened so that a run lasts a few
# seconds, flushing every 0.05 s.  MAX_DELAY (s, default 0.8) bounds the
# delay before a signal.  Exit status 0 when every round matched.  Work
# directory: $STRESS_DIR, else a temporary one (removed on success).
set -u
mrvi=${1:?usage: stress_resume.sh MRVI SOURCE_ROOT [CYCLES] [SYSTEM.yaml ...]}
root=${2:?usage: stress_resume.sh MRVI SOURCE_ROOT [CYCLES] [SYSTEM.yaml ...]}
cycles=${3:-100}
shift $(($# < 3 ? $# : 3))
max_delay=${MAX_DELAY:-0.8}
command -v h5diff >/dev/null || {
  echo "stress_resume: h5diff (hdf5-tools) not found" >&2
  exit 2
}
dir=${STRESS_DIR:-$(mktemp -d)}
mkdir -p "$dir"

# System and the --set that makes a run last a few seconds.
declare -A lengthen=(
  [fpu.yaml]="integrator.t_end=5000"
  [cart_pendulum.yaml]="integrator.t_end=1000"
  [slider_crank.yaml]="integrator.t_end=500"
)
systems=("$@")
[ ${#systems[@]} -gt 0 ] || systems=(fpu.yaml cart_pendulum.yaml slider_crank.yaml)

failures=0
for sys in "${systems[@]}"; do
  file=$root/systems/$sys
  [ -f "$file" ] || file=$sys
  name=$(basename "$sys" .yaml)
  sets=(--set output.flush_interval=0.05 --set output.xdmf=false)
  [ -n "${lengthen[$sys]:-}" ] && sets+=(--set "${lengthen[$sys]}")
  ref=$dir/$name.ref.h5 out=$dir/$name.h5
  t0=$SECONDS
  "$mrvi" run "$file" "${sets[@]}" -o "$ref" -q >/dev/null 2>"$dir/$name.ref.err" || {
    echo "$name: the reference run failed: $(cat "$dir/$name.ref.err")"
    failures=$((failures + 1))
    continue
  }
  echo "$name: reference run $((SECONDS - t0)) s"
  declare -A seen=() late=()
  sent=0 rounds=0 restarts=0 bad=0
  while [ $sent -lt "$cycles" ]; do
    rounds=$((rounds + 1))
    rm -f "$out"
    fresh=1
    while :; do
      if [ $fresh = 1 ]; then
        "$mrvi" run "$file" "${sets[@]}" -o "$out" -q >/dev/null 2>"$dir/$name.err" &
      else
        "$mrvi" run --resume "$out" -q >/dev/null 2>"$dir/$name.err" &
      fi
      pid=$!
      if [ $sent -lt "$cycles" ]; then
        sleep "$(awk -v m="$max_delay" -v r=$RANDOM 'BEGIN { printf "%.3f", 0.01 + m * r / 32768 }')"
        sig=$([ $((RANDOM % 2)) = 0 ] && echo KILL || echo INT)
        kill -$sig $pid 2>/dev/null
        sent=$((sent + 1))
      fi
      wait $pid 2>/dev/null
      rc=$?
      kind=$([ $fresh = 1 ] && echo start || echo resume)
      seen["$kind $rc"]=$((${seen["$kind $rc"]:-0} + 1))
      case $rc in
      0) break ;;
      130 | 137) fresh=0 ;;
      1)
        if [ $fresh = 0 ] && grep -q "the run completed; nothing to resume" "$dir/$name.err"; then
          # the signal came as the run closed its completed file
          late["$prev"]=$((${late["$prev"]:-0} + 1))
          rc=0
          break
        elif [ $fresh = 0 ] && grep -q "cannot open as an HDF5 file" "$dir/$name.err"; then
          # killed before the first flush: nothing to resume from
          restarts=$((restarts + 1))
          cp "$dir/$name.err" "$dir/$name.restart$restarts.err"
          rm -f "$out"
          fresh=1
        else
          echo "$name: round $rounds: $kind exit 1: $(cat "$dir/$name.err")"
          bad=$((bad + 1))
          break
        fi
        ;;
      *)
        echo "$name: round $rounds: $kind exit $rc: $(cat "$dir/$name.err")"
        cp "$dir/$name.err" "$dir/$name.round$rounds.err"
        bad=$((bad + 1))
        break
        ;;
      esac
      prev="$kind $rc" # the status a refusal as completed follows
    done
    [ $rc = 0 ] || continue
    for g in /macro /micro /bodies /joints; do
      h5ls "$ref$g" >/dev/null 2>&1 || continue # (no fast part, no bodies)
      if ! h5diff -q "$ref" "$out" $g $g >/dev/null 2>&1; then
        echo "$name: round $rounds: $g differs from the reference"
        h5diff "$ref" "$out" $g $g 2>&1 | head -n 5
        cp "$out" "$dir/$name.round$rounds.h5"
        bad=$((bad + 1))
      fi
    done
    reason=$(h5dump -a /stop_reason "$out" 2>/dev/null | grep -o '(0): "[^"]*"')
    [ "$reason" = '(0): "completed"' ] || {
      echo "$name: round $rounds: stop_reason $reason"
      bad=$((bad + 1))
    }
  done
  statuses=$(for k in "${!seen[@]}"; do echo "$k: ${seen[$k]}"; done | sort | paste -sd, -)
  completed=$(for k in "${!late[@]}"; do echo "$k: ${late[$k]}"; done | sort | paste -sd, -)
  echo "$name: $sent signals, $rounds rounds, $restarts restarts (killed before the first flush), $bad failures, $((SECONDS - t0)) s; exit statuses {$statuses}; completed file after a signal {$completed}"
  failures=$((failures + bad))
  unset seen late
done
if [ $failures -eq 0 ] && [ -z "${STRESS_DIR:-}" ]; then
  rm -rf "$dir"
else
  echo "work directory: $dir"
fi
[ $failures -eq 0 ]
