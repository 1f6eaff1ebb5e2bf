#!/usr/bin/env bash
# `mrvi batch` against one `mrvi run` per case (doc/performance/batches.md,
# "Batches (`bench_batch`)"): FPU cases of about a second each, run
#   - one after another by `mrvi run` (the reference: its wall time and the
#     sum of its file sizes),
#   - by `mrvi batch --jobs 1` and `--jobs 2`,
#   - and, when mrvi is built with MPI, by `mpiexec -n 1` and `-n 2` with
#     one job per rank.
# Reported: the speed-up of 2 workers over 1, the overhead per case of a
# 1-worker batch against the individual runs, and the batch's output size
# (master file + case files) against the sum of the individual files.
# With --converge, also `mrvi converge` on 1 and 2 jobs (and on 2 ranks of
# one job each): a fixed FPU study of 15 runs (p = 2, 5, 10; 5 macro steps
# from 0.02; t_end 200) with --no-cache: the reference (1.6 M steps) is
# computed first, serially, then the runs are spread.  (Reading the
# reference from the cache is slower than computing it, for this system.)
# The machine may be shared: the configurations are interleaved, every one
# is repeated and the best wall and CPU times are kept; the load average
# is printed before each measurement.
#
#   bench_batch.sh MRVI SOURCE_ROOT [mpi|no-mpi] [--quick] [--cases N]
#                  [--repeats R] [--t-end T] [--configs LIST] [--converge]
#
# --configs: some of runs,jobs1,jobs2,mpi1,mpi2 (default all; the mpi ones
# when built with MPI).
set -u
mrvi=$1 src=$2
shift 2
with_mpi=no-mpi
if [ "${1:-}" = mpi ] || [ "${1:-}" = no-mpi ]; then
  with_mpi=$1
  shift
fi
n_cases=8 repeats=3 t_end=25000 only="" converge=0
while [ $# -gt 0 ]; do
  case $1 in
  --quick) n_cases=4 repeats=1 t_end=4000 ;;
  --cases) n_cases=$2; shift ;;
  --repeats) repeats=$2; shift ;;
  --t-end) t_end=$2; shift ;;
  --configs) only=$2; shift ;;
  --converge) converge=1 ;;
  -h | --help) sed -n 2,26p "$0"; exit 0 ;;
  *) echo "bench_batch: unknown option '$1'" >&2; exit 2 ;;
  esac
  shift
done
fpu=$src/systems/fpu.yaml
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

# The cases: t_end from 0.9 T to 1.1 T (n values); the state every 10th
# macro step, no micro states, so that the run is the integration.
lo=$(awk -v t="$t_end" 'BEGIN { printf "%.10g", 0.9 * t }')
hi=$(awk -v t="$t_end" 'BEGIN { printf "%.10g", 1.1 * t }')
mapfile -t t_ends < <(awk -v a="$lo" -v b="$hi" -v n="$n_cases" 'BEGIN {
  for (i = 0; i < n; i++)
    printf "%.10g\n", (n == 1) ? a : a + (b - a) * i / (n - 1) }')
vary=(--vary "integrator.t_end=$(IFS=,; echo "${t_ends[*]}")"
      --vary output.every=10 --vary output.micro=false)

load() { cut -d' ' -f1-3 /proc/loadavg; }
fail() { echo "bench_batch: $*" >&2; exit 1; }

declare -A best  # best[config] = seconds
keep() {  # keep CONFIG SECONDS
  local old=${best[$1]:-}
  if [ -z "$old" ] || awk -v a="$2" -v b="$old" 'BEGIN { exit !(a < b) }'; then
    best[$1]=$2
  fi
}

runs() {  # every case by `mrvi run`, one after another
  local i=0
  rm -rf "$tmp/runs" && mkdir "$tmp/runs"
  for t in "${t_ends[@]}"; do
    "$mrvi" run "$fpu" -o "$tmp/runs/$i.h5" --set "integrator.t_end=$t" \
      --set output.every=10 --set output.micro=false >/dev/null ||
      fail "mrvi run (t_end $t) failed"
    i=$((i + 1))
  done
}

batch() {  # batch NAME [LAUNCHER...] -- JOBS
  local name=$1
  shift
  local launcher=()
  while [ "$1" != -- ]; do launcher+=("$1"); shift; done
  local jobs=$2
  rm -rf "$tmp/b.h5" "$tmp/b.cases"
  "${launcher[@]}" "$mrvi" batch "$fpu" -o "$tmp/b.h5" "${vary[@]}" \
    --jobs "$jobs" >"$tmp/$name.log" 2>&1 ||
    { cat "$tmp/$name.log" >&2; fail "$name failed"; }
}

# measure CONFIG COMMAND...: "WALL CPU" seconds (CPU: user + system of the
# command and its children).
measure() {
  local TIMEFORMAT='%R %U %S'
  shift
  { time "$@" >/dev/null; } 2>"$tmp/time" || exit 1
  awk '{ printf "%.3f %.3f", $1, $2 + $3 }' "$tmp/time"
}

mpirun=()
if [ "$with_mpi" = mpi ] && command -v mpiexec >/dev/null; then
  mpirun=(mpiexec --oversubscribe)
  [ "$(id -u)" = 0 ] && mpirun+=(--allow-run-as-root)
fi

configs=(runs jobs1 jobs2)
[ ${#mpirun[@]} -gt 0 ] && configs+=(mpi1 mpi2)
if [ -n "$only" ]; then
  wanted=()
  for c in "${configs[@]}"; do
    [[ ",$only," == *",$c,"* ]] && wanted+=("$c")
  done
  configs=("${wanted[@]}")
fi
# The converge study.
study=(converge "$fpu" --p 2,5,10 --dt0 0.02 --levels 5 --t-end 200
  --ref-step 1.25e-4 --no-cache -q -o "$tmp/conv.h5")
conv() {  # conv [LAUNCHER...] -- ARGS...
  local launcher=()
  while [ "$1" != -- ]; do launcher+=("$1"); shift; done
  shift
  "${launcher[@]}" "$mrvi" "${study[@]}" "$@" 2>/dev/null ||
    fail "converge $* failed"
}
if [ "$converge" = 1 ]; then
  configs+=(conv_j1 conv_j2)
  [ ${#mpirun[@]} -gt 0 ] && configs+=(conv_mpi2)
fi

echo "bench_batch: $n_cases FPU cases (systems/fpu.yaml, t_end $lo .. $hi," \
  "every 10th step, no micro states), best of $repeats"
echo "mrvi: $mrvi ($("$mrvi" --version | head -1))," \
  "MPI: $([ ${#mpirun[@]} -gt 0 ] && echo "yes ($(mpiexec --version | head -1))" || echo "no ($with_mpi)")"
echo "cores: $(nproc), $(date -u '+%Y-%m-%d %H:%M UTC')"
echo
printf '%-6s %-16s %9s %9s   %s\n' repeat config wall_s cpu_s \
  "load before (1, 5, 15 min)"
for ((r = 1; r <= repeats; r++)); do
  for c in "${configs[@]}"; do
    l=$(load)
    case $c in
    runs) m=$(measure "$c" runs) ;;
    jobs1) m=$(measure "$c" batch jobs1 -- 1) ;;
    jobs2) m=$(measure "$c" batch jobs2 -- 2) ;;
    mpi1) m=$(measure "$c" batch mpi1 "${mpirun[@]}" -n 1 -- 1) ;;
    mpi2) m=$(measure "$c" batch mpi2 "${mpirun[@]}" -n 2 -- 1) ;;
    conv_j1) m=$(measure "$c" conv -- -j 1) ;;
    conv_j2) m=$(measure "$c" conv -- -j 2) ;;
    conv_mpi2) m=$(measure "$c" conv "${mpirun[@]}" -n 2 -- -j 1) ;;
    esac
    [ -n "$m" ] || exit 1
    read -r s cpu <<<"$m"
    keep "$c" "$s"
    keep "cpu_$c" "$cpu"
    printf '%-6s %-16s %9s %9s   %s\n' "$r" "$c" "$s" "$cpu" "$l"
  done
done
echo
ratio() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.3f", a / b }'; }
pct() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%+.1f %%", 100 * (a / b - 1) }'; }
have() { for k in "$@"; do [ -n "${best[$k]:-}" ] || return 1; done; }
echo "best wall / CPU time (s):"
for c in "${configs[@]}"; do
  printf '  %-16s %9s %9s\n' "$c" "${best[$c]}" "${best[cpu_$c]}"
done
# speedup NAME BASE CONFIG: wall ratio, and the CPU time against the base.
speedup() {
  have "$2" "$3" || return 0
  echo "speed-up $1: $(ratio "${best[$2]}" "${best[$3]}") wall" \
    "(CPU $(pct "${best[cpu_$3]}" "${best[cpu_$2]}") against $2)"
}
speedup "--jobs 2 / --jobs 1        " jobs1 jobs2
speedup "mpiexec -n 2 / -n 1        " mpi1 mpi2
speedup "mpiexec -n 2 / --jobs 1    " jobs1 mpi2
speedup "converge -j 2 / -j 1          " conv_j1 conv_j2
speedup "converge 2 ranks x 1 / -j 1   " conv_j1 conv_mpi2
have jobs1 runs &&
  echo "overhead --jobs 1 against runs:   $(pct "${best[jobs1]}" "${best[runs]}") wall," \
    "$(pct "${best[cpu_jobs1]}" "${best[cpu_runs]}") CPU  (goal <= 5 %)"
have mpi1 runs &&
  echo "overhead mpiexec -n 1 against runs: $(pct "${best[mpi1]}" "${best[runs]}") wall," \
    "$(pct "${best[cpu_mpi1]}" "${best[cpu_runs]}") CPU"
if have runs && [ -e "$tmp/b.h5" ]; then
  # The files of the last repeat (the same in every one).
  size_runs=$(du -cb "$tmp"/runs/*.h5 | tail -1 | cut -f1)
  size_batch=$(du -cb "$tmp/b.h5" "$tmp/b.cases" | tail -1 | cut -f1)
  size_master=$(stat -c %s "$tmp/b.h5")
  echo "output: batch $size_batch B (master $size_master B + case files)," \
    "runs $size_runs B: $(pct "$size_batch" "$size_runs")"
fi
