#!/usr/bin/env bash
# Threads (doc/performance/threads.md, "Threads"): the planar lattice of
# systems/lattice.yaml grown to 40 x 20 particles (1600 coordinates), its
# threaded loops in parts of 16 coordinates (integrator.tuning.thread_chunk;
# fully-explicit's, the whole step in one region, doubled until few
# records span them),
# run by fully-explicit, explicit-slow, midpoint-midpoint and
# trapezoidal-midpoint (schur-krylov's outer iteration: one parallel region
# per step, its vector loops in spans and its gradients in parts; the
# predictor's gradients in parts, its sweep and its node-k gradients each
# in one parallel region, sweep_par and node_gradients_par, and its finite
# check in parts; explicit-slow's row 0 with its Hessian
# diagonal in the chord's parts, fresh_parts) on 1, 2
# and 3 threads: /macro/q, /macro/p, /micro/q_fast, /micro/p_fast and the
# energies (summed per chunk of elements) the same bit for bit; and each of
# the five schemes under both Newton criteria, in parts of 16 and
# unchunked, to t = 0.2, the same on 1, 2 and 3 threads.  A run on
# 2 threads to t = 0.25 extended by `--resume --set integrator.t_end` on 3
# threads equals the uninterrupted run on 1 (explicit-slow and
# trapezoidal-midpoint).  `mrvi check` shows the
# count; a build without OpenMP refuses --threads 2 with a message that
# says so.  explicit-slow's chord sums (the summary's relaxation sum, to
# the last bit) the same on 1, 2 and 3 threads; and with row 0's
# assembled bound in the chord's parts (fresh_exact_parts).  The automatic
# count (the
# default, `--threads auto`, MRVI_THREADS=auto): 1 for the 6 x 5 and the
# 40 x 20 lattice in parts of 4096 (no loop of two parts) and bound to one
# core (taskset); in parts of 16 the cores available (nproc) less those
# other tasks run on, with the reason in `mrvi check`; the trajectory of 1
# thread bit for bit.  A command on threads sets
# libgomp's GOMP_SPINCOUNT to 1000 (a
# short spin, then sleep) unless the environment sets it or
# OMP_WAIT_POLICY.
#
#   test_threads.sh MRVI_BINARY SOURCE_ROOT
set -u
mrvi=${1:?usage: test_threads.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_threads.sh MRVI_BINARY SOURCE_ROOT}
# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
if ! command -v h5diff >/dev/null 2>&1; then
  echo "skipped: needs h5diff (hdf5-tools)"
  exit 77
fi
sys=$root/systems/lattice.yaml
common=(--set generate.0.count.0=40 --set generate.0.count.1=20
  --set integrator.tuning.thread_chunk=16 --set integrator.t_end=0.5
  --set output.micro=true --set output.xdmf=false --quiet)

# same A B: the trajectories of A and B bit for bit
same() {
  for g in /macro/q /macro/p /micro/q_fast /micro/p_fast /macro/potential_slow \
    /macro/potential_fast /macro/energy; do
    if ! h5diff "$1" "$2" "$g" "$g" >/dev/null 2>&1; then
      h5diff -r "$1" "$2" "$g" "$g" | head -n 5
      return 1
    fi
  done
}

if ! "$mrvi" check "$sys" --threads 3 >"$tmp/check.txt" 2>&1; then
  if grep -q "this build has no threads" "$tmp/check.txt"; then
    pass "no OpenMP: --threads 3 refused with its reason"
    run_ok "no OpenMP: --threads 1 runs" "$mrvi" run "$sys" "${common[@]}" \
      --threads 1 -o "$tmp/one.h5"
    run_ok "no OpenMP: the default (auto) runs" "$mrvi" run "$sys" \
      "${common[@]}" -o "$tmp/auto.h5"
    test_finish
    exit $?
  fi
  fail "mrvi check --threads 3"
  cat "$tmp/check.txt"
fi
if grep -q "^threads *3 " "$tmp/check.txt"; then
  pass "mrvi check shows the thread count"
else
  fail "mrvi check shows the thread count: $(grep threads "$tmp/check.txt")"
fi

# libgomp's wait: a spin of 1000 when the command asks for threads and
# the environment leaves it to mrvi, the user's setting otherwise.
if env -u OMP_WAIT_POLICY -u GOMP_SPINCOUNT "$mrvi" check "$sys" --threads 2 |
  grep -q "^threads .*OMP_WAIT_POLICY unset, GOMP_SPINCOUNT 1000)"; then
  pass "--threads 2: libgomp spins 1000 iterations before it sleeps"
else
  fail "--threads 2: libgomp spins 1000 iterations before it sleeps"
fi
if env -u GOMP_SPINCOUNT OMP_WAIT_POLICY=active "$mrvi" check "$sys" \
  --threads 2 | grep -q "^threads .*OMP_WAIT_POLICY active, GOMP_SPINCOUNT unset)"; then
  pass "--threads 2: the user's OMP_WAIT_POLICY stands"
else
  fail "--threads 2: the user's OMP_WAIT_POLICY stands"
fi
if env -u OMP_WAIT_POLICY GOMP_SPINCOUNT=5 "$mrvi" check "$sys" --threads 2 |
  grep -q "^threads .*OMP_WAIT_POLICY unset, GOMP_SPINCOUNT 5)"; then
  pass "--threads 2: the user's GOMP_SPINCOUNT stands"
else
  fail "--threads 2: the user's GOMP_SPINCOUNT stands"
fi
if env -u OMP_WAIT_POLICY -u GOMP_SPINCOUNT -u MRVI_THREADS "$mrvi" check "$sys" |
  grep -q "^threads .*OMP_WAIT_POLICY unset, GOMP_SPINCOUNT unset)"; then
  pass "one thread: the environment unchanged"
else
  fail "one thread: the environment unchanged"
fi

# The automatic count (the default, --threads auto, MRVI_THREADS=auto):
# the cores available (nproc: the affinity mask) when a loop has at least
# two parts of tuning.thread_chunk, else 1 without a restart.
cores=$(nproc)
big=(--set generate.0.count.0=40 --set generate.0.count.1=20
  --set integrator.tuning.thread_chunk=16)
auto_ok() { # NAME WANT-COUNT WANT-REASON ARGS...: mrvi check's threads line
  local name=$1 want=$2 why=$3 line
  shift 3
  line=$(env -u OMP_WAIT_POLICY -u GOMP_SPINCOUNT "$@" 2>&1 | grep "^threads ")
  if [[ $line == "threads       $want (auto: $why"* ]]; then
    pass "$name: ${line:0:110}"
  else
    fail "$name: $line"
  fi
}
auto_ok "auto, 30 particles: 1" 1 "no loop long enough" \
  "$mrvi" check "$sys"
auto_ok "auto, 800 particles in parts of 4096: 1" 1 \
  "no loop long enough for threads: the longest, 1160 elements of V," \
  "$mrvi" check "$sys" --set generate.0.count.0=40 --set generate.0.count.1=20
# big_ok NAME ARGS...: the 40 x 20 lattice in parts of 16 on auto: the
# cores, the idle ones (others busy) or 1 when other tasks run on all of
# them (/proc/loadavg; the suite's other tests may), each with its reason,
# and libgomp's short spin whenever more than one thread is chosen.
big_ok() {
  local name=$1 line n ok=0
  shift
  line=$(env -u OMP_WAIT_POLICY -u GOMP_SPINCOUNT "$@" 2>&1 | grep "^threads ")
  n=$(echo "$line" | awk '{print $2}')
  case $line in
  "threads       $cores (auto: the cores available to this process: 1160 elements of V"*"GOMP_SPINCOUNT 1000)")
    [ "$cores" -gt 1 ] && ok=1 ;;
  *"(auto: the idle cores available to this process (others busy): 1160 elements of V"*"GOMP_SPINCOUNT 1000)")
    [ "$n" -gt 1 ] && [ "$n" -lt "$cores" ] && ok=1 ;;
  "threads       1 (auto: "*" other task"*" running on the $cores cores available to this process (a loop of 1160 elements of V"*"GOMP_SPINCOUNT "*)
    ok=1 ;; # (1000 when the load rose between the choice and the restart)
  "threads       1 (auto: one core available"*"GOMP_SPINCOUNT unset)")
    [ "$cores" -eq 1 ] && ok=1 ;;
  esac
  if [ $ok = 1 ]; then
    pass "$name: ${line:0:120}"
  else
    fail "$name: $line"
  fi
}
big_ok "auto, 800 particles in parts of 16" "$mrvi" check "$sys" "${big[@]}"
big_ok "MRVI_THREADS=auto" env MRVI_THREADS=auto "$mrvi" check "$sys" "${big[@]}"
big_ok "--threads auto over MRVI_THREADS=1" env MRVI_THREADS=1 "$mrvi" check \
  "$sys" "${big[@]}" --threads auto
if command -v taskset >/dev/null 2>&1; then
  auto_ok "auto bound to one core (taskset -c 0): 1" 1 "one core available" \
    taskset -c 0 "$mrvi" check "$sys" "${big[@]}"
fi
if grep -q "^threads *3 (--threads or MRVI_THREADS" "$tmp/check.txt"; then
  pass "--threads 3: as given"
else
  fail "--threads 3: as given: $(grep "^threads" "$tmp/check.txt")"
fi

# three_same NAME KEY ARGS...: the 40 x 20 lattice with ARGS on 1, 2 and
# 3 threads into $tmp/KEY.T.h5, 2 and 3 threads 1's trajectory bit for bit.
three_same() {
  local name=$1 key=$2 t
  shift 2
  for t in 1 2 3; do
    run_ok "$name on $t threads" "$mrvi" run "$sys" "${common[@]}" "$@" \
      --threads $t -o "$tmp/$key.$t.h5"
  done
  for t in 2 3; do
    if same "$tmp/$key.1.h5" "$tmp/$key.$t.h5"; then
      pass "$name: $t threads give the trajectory of 1 bit for bit"
    else
      fail "$name: $t threads give the trajectory of 1 bit for bit"
    fi
  done
}
schemes=(fully-explicit explicit-slow midpoint-midpoint trapezoidal-midpoint
  trapezoidal-trapezoidal)
for scheme in "${schemes[@]}"; do
  three_same "$scheme" "$scheme" --set integrator.scheme=$scheme
done

# Every scheme under both Newton criteria (newton.criterion: absolute, as
# above, and scaled: each row's residual times 1/M, sweep-cg's general
# chord pass) in parts of 16 coordinates and unchunked (the default parts
# of 4096: no loop of two), to t = 0.2, on 1, 2 and 3 threads: bit for
# bit.  (explicit-slow under the scaled criterion in parts once stored a
# row's first chord force over the last row's converged one before the
# history moved on, where the last row's end runs in the first update's
# parallel region: 8e-12 apart at the first macro node on 2 threads.)
for chunk in 16 4096; do
  for crit in absolute scaled; do
    [ $chunk = 16 ] && [ $crit = absolute ] && continue # (above)
    for scheme in "${schemes[@]}"; do
      three_same "$scheme, $crit criterion, parts of $chunk" \
        "$scheme.$crit.$chunk" --set integrator.t_end=0.2 \
        --set integrator.tuning.thread_chunk=$chunk \
        --set integrator.newton.criterion=$crit --set integrator.scheme=$scheme
    done
  done
done

# A constrained lattice: systems/lattice.yaml at 20 x 10 with rods between
# the pairs of its bottom row, in parts of 16 coordinates, on
# schur-bordered (multiplier form, forced) on 1, 2 and 3 threads and on the
# general path (null-space form) on 1 and 3: bit for bit; and resumed, 2
# threads to t = 0.25 extended on 3, the uninterrupted run on 1.
{
  sed -e '/^integrator:/,$d' -e 's/count: \[6, 5\]/count: [20, 10]/' "$sys"
  echo "constraints:"
  for i in $(seq 0 2 18); do
    echo "  - {type: distance, between: [p${i}_0, p$((i + 1))_0]}"
  done
  cat <<'EOF'
integrator:
  scheme: midpoint-midpoint
  macro_step: 0.05
  micro_steps: 10
  t_end: 0.5
  constraints: {form: multipliers, tolerance: 1.0e-11}
  tuning: {thread_chunk: 16, bordered_max: 100000, bordered_node_max: 100000}
output: {file: rods.h5, every: 1, micro: true, xdmf: false}
EOF
} >"$tmp/rods.yaml"
structured=(--set integrator.solver=structured)
if "$mrvi" check "$tmp/rods.yaml" "${structured[@]}" |
  grep -q "^solver *schur-bordered"; then
  pass "constrained lattice: schur-bordered"
else
  fail "constrained lattice: schur-bordered: $("$mrvi" check "$tmp/rods.yaml" "${structured[@]}" 2>&1 | grep solver)"
fi
for t in 1 2 3; do
  run_ok "constrained lattice, schur-bordered, on $t threads" "$mrvi" run \
    "$tmp/rods.yaml" "${structured[@]}" --quiet --threads $t \
    -o "$tmp/rods.$t.h5"
done
for t in 1 3; do
  run_ok "constrained lattice, null-space form, on $t threads" "$mrvi" run \
    "$tmp/rods.yaml" --set integrator.constraints.form=null-space --quiet \
    --threads $t -o "$tmp/rodsn.$t.h5"
done
run_ok "constrained lattice to t = 0.25 on 2 threads" "$mrvi" run \
  "$tmp/rods.yaml" "${structured[@]}" --set integrator.t_end=0.25 --quiet \
  --threads 2 -o "$tmp/rodspart.h5"
run_ok "constrained lattice extended to t = 0.5 on 3 threads" env \
  MRVI_THREADS=3 "$mrvi" run --resume "$tmp/rodspart.h5" \
  --set integrator.t_end=0.5 --quiet
for pair in "rods.1 rods.2" "rods.1 rods.3" "rodsn.1 rodsn.3" \
  "rods.1 rodspart"; do
  read -r one other <<<"$pair"
  if same "$tmp/$one.h5" "$tmp/$other.h5"; then
    pass "constrained lattice: $other gives $one bit for bit"
  else
    fail "constrained lattice: $other gives $one bit for bit"
  fi
done

# sweep-cg's chord sums over the parts (F.F_old, F_old.F_old) set the
# relaxation of the next update; their last bits are rounded away in the
# trajectory, so the summary prints their sum over the run to the last bit:
# a pre-stressed lattice (every part moving; 21 rows and parts of 12
# coordinates, so that the parts' sums differ) on 1, 2 and 3 threads gives
# the same line, which summing the parts in another order on threads (an
# OpenMP reduction) would change.
chord=(--set generate.0.count.0=40 --set generate.0.count.1=21
  --set generate.0.fast_spring.rest_length=0.97
  --set generate.0.slow_spring.rest_length=1.02
  --set integrator.tuning.thread_chunk=12 --set integrator.t_end=0.2
  --set integrator.macro_step=0.02 --set integrator.micro_steps=5
  --set integrator.scheme=explicit-slow --set output.xdmf=false)
for t in 1 2 3; do
  "$mrvi" run "$sys" "${chord[@]}" --threads $t -o "$tmp/chord.$t.h5" \
    2>/dev/null | grep "chord (sweep-cg)" >"$tmp/chord.$t.txt"
done
if [ -s "$tmp/chord.1.txt" ] && cmp -s "$tmp/chord.1.txt" "$tmp/chord.2.txt" &&
  cmp -s "$tmp/chord.1.txt" "$tmp/chord.3.txt" &&
  same "$tmp/chord.1.h5" "$tmp/chord.3.h5"; then
  pass "explicit-slow: the chord's sums the same bit for bit on 1, 2, 3 threads"
else
  fail "explicit-slow: the chord's sums the same bit for bit on 1, 2, 3 threads: $(cat "$tmp"/chord.?.txt)"
fi

# Micro output off: only the last fast node is kept, and the threaded
# explicit sweep alternates the nodes between the output row and a
# scratch row, one barrier per node (p = 10: the last node in the row).
for t in 1 3; do
  run_ok "fully-explicit, micro output off, on $t threads" "$mrvi" run "$sys" \
    "${common[@]}" --set output.micro=false \
    --set integrator.scheme=fully-explicit --threads $t -o "$tmp/last.$t.h5"
done
if h5diff "$tmp/last.1.h5" "$tmp/last.3.h5" /macro/q /macro/q >/dev/null 2>&1 &&
  h5diff "$tmp/last.1.h5" "$tmp/last.3.h5" /macro/p /macro/p >/dev/null 2>&1 &&
  h5diff "$tmp/last.1.h5" "$tmp/fully-explicit.1.h5" /macro/q /macro/q \
    >/dev/null 2>&1; then
  pass "fully-explicit, micro output off: 3 threads give 1's macro nodes bit for bit"
else
  fail "fully-explicit, micro output off: 3 threads give 1's macro nodes bit for bit"
fi
# ... and explicit-slow (sweep-cg's last node in place, grad V read from x
# itself: end_parts).
run_ok "explicit-slow, micro output off, on 3 threads" "$mrvi" run "$sys" \
  "${common[@]}" --set output.micro=false \
  --set integrator.scheme=explicit-slow --threads 3 -o "$tmp/eslast.3.h5"
if h5diff "$tmp/eslast.3.h5" "$tmp/explicit-slow.1.h5" /macro /macro \
  >/dev/null 2>&1; then
  pass "explicit-slow, micro output off: 3 threads give 1's macro nodes bit for bit"
else
  fail "explicit-slow, micro output off: 3 threads give 1's macro nodes bit for bit"
fi

# Resume across thread counts: 2 threads to t = 0.25, extended on 3
# (explicit-slow's sweep-cg; trapezoidal-midpoint's predictor sweep in one
# parallel region, sweep_par).
for scheme in explicit-slow trapezoidal-midpoint; do
  run_ok "$scheme to t = 0.25 on 2 threads" "$mrvi" run "$sys" "${common[@]}" \
    --set integrator.scheme=$scheme --set integrator.t_end=0.25 --threads 2 \
    -o "$tmp/part.$scheme.h5"
  run_ok "$scheme extended to t = 0.5 on 3 threads" env MRVI_THREADS=3 \
    "$mrvi" run --resume "$tmp/part.$scheme.h5" --set integrator.t_end=0.5 \
    --quiet
  if same "$tmp/$scheme.1.h5" "$tmp/part.$scheme.h5"; then
    pass "$scheme resumed on other thread counts: the uninterrupted run bit for bit"
  else
    fail "$scheme resumed on other thread counts: the uninterrupted run bit for bit"
  fi
done

# explicit-slow on a random network (bench_floor's random3d at 6 x 6 x 6
# sites: 309 fast coordinates, parts of 16) with Newton on every row
# (chord_jacobi_max = 0): the micro-step Newton matrix's sparse block on
# threads (its assembly and Jacobi bound in parts, the CG's product in row
# form, mrvi_sblock_set_parts) on 1, 2 and 3 threads bit for bit, and
# resumed from 2 threads to t = 0.25 on 3: the uninterrupted run on 1.
awk 'BEGIN {
  srand(7); n = 6; np = 0
  print "name: random3d\ndimension: 3\nparticles:"
  for (k = 0; k < n; k++) for (j = 0; j < n; j++) for (i = 0; i < n; i++) {
    x[np] = i + 0.2 * rand(); y[np] = j + 0.2 * rand(); z[np] = k + 0.2 * rand()
    f[np] = rand() < 0.5
    printf "  - {name: p%d, mass: 1, rate: %s, position: [%.17g, %.17g, %.17g], velocity: [%.17g, %.17g, %.17g]}\n",
      np, f[np] ? "fast" : "slow", x[np], y[np], z[np], 0.1 * rand() - 0.05,
      0.1 * rand() - 0.05, 0.1 * rand() - 0.05
    np++
  }
  print "springs:"
  for (a = 0; a < np; a++) for (b = a + 1; b < np; b++) {
    r = sqrt((x[a] - x[b]) ^ 2 + (y[a] - y[b]) ^ 2 + (z[a] - z[b]) ^ 2)
    if (r >= 1.45) continue
    if (f[a] && f[b])
      printf "  - {between: [p%d, p%d], law: linear, stiffness: 1000, rest_length: %.17g, potential: fast}\n", a, b, r
    else
      printf "  - {between: [p%d, p%d], law: morse, depth: 5, width: 1, rest_length: %.17g, potential: slow}\n", a, b, r
  }
  print "integrator: {scheme: explicit-slow, macro_step: 0.05, micro_steps: 10, t_end: 0.5,"
  print "  tuning: {thread_chunk: 16, chord_jacobi_max: 0}}"
  print "output: {file: random3d.h5, every: 1, micro: true, xdmf: false}"
}' >"$tmp/random3d.yaml"
for t in 1 2 3; do
  "$mrvi" run "$tmp/random3d.yaml" --threads $t -o "$tmp/rnd.$t.h5" \
    >"$tmp/rnd.$t.txt" 2>&1 || fail "random network on $t threads: $(cat "$tmp/rnd.$t.txt")"
done
if grep -q "^  CG (micro blocks) .*[1-9][0-9]* block solves" "$tmp/rnd.1.txt" &&
  grep -q "^coordinates .* fast)" <("$mrvi" check "$tmp/random3d.yaml"); then
  pass "random network, explicit-slow: Newton's sparse block ($(grep -o "[0-9]* block solves" "$tmp/rnd.1.txt"))"
else
  fail "random network, explicit-slow: Newton's sparse block: $(cat "$tmp/rnd.1.txt")"
fi
run_ok "random network to t = 0.25 on 2 threads" "$mrvi" run \
  "$tmp/random3d.yaml" --set integrator.t_end=0.25 --quiet --threads 2 \
  -o "$tmp/rndpart.h5"
run_ok "random network extended to t = 0.5 on 3 threads" env MRVI_THREADS=3 \
  "$mrvi" run --resume "$tmp/rndpart.h5" --set integrator.t_end=0.5 --quiet
for other in rnd.2 rnd.3 rndpart; do
  if same "$tmp/rnd.1.h5" "$tmp/$other.h5"; then
    pass "random network, explicit-slow: $other gives 1 thread's trajectory bit for bit"
  else
    fail "random network, explicit-slow: $other gives 1 thread's trajectory bit for bit"
  fi
done

# ... and on the chord with chord_jacobi_max 0.02, which the elements'
# bound exceeds at every step's row 0: the assembled matrix's bound there
# (fresh_exact) in the chord's parts on threads (fresh_exact_parts, its
# own parallel region): 1, 2 and 3 threads bit for bit.
sed -e 's/chord_jacobi_max: 0}/chord_jacobi_max: 0.02}/' "$tmp/random3d.yaml" \
  >"$tmp/rndex.yaml"
for t in 1 2 3; do
  run_ok "random network, chord_jacobi_max 0.02, on $t threads" "$mrvi" run \
    "$tmp/rndex.yaml" --threads $t -o "$tmp/rndex.$t.h5" --quiet
done
if grep -q "chord_jacobi_max: 0.02}" "$tmp/rndex.yaml" &&
  same "$tmp/rndex.1.h5" "$tmp/rndex.2.h5" &&
  same "$tmp/rndex.1.h5" "$tmp/rndex.3.h5"; then
  pass "random network, row 0's assembled bound: 1, 2, 3 threads bit for bit"
else
  fail "random network, row 0's assembled bound: 1, 2, 3 threads bit for bit"
fi

# ... and with unequal fast masses (every odd particle of mass 2: each
# entry of M^f read) and the chord's linearised updates
# (tuning.chord_linear 2: the pass that writes the update into zf) on the
# chord (chord_jacobi_max as set by default): 1, 2 and 3 threads the same
# trajectory and chord sums bit for bit.  (That pass once stored the first
# update's implicit force over the last row's converged one, before the
# history moved on: other sums on threads.)
sed -E -e 's/name: (p[0-9]*[13579]), mass: 1,/name: \1, mass: 2,/' \
  -e 's/chord_jacobi_max: 0/chord_linear: 2/' "$tmp/random3d.yaml" \
  >"$tmp/rndlin.yaml"
for t in 1 2 3; do
  "$mrvi" run "$tmp/rndlin.yaml" --threads $t -o "$tmp/rndlin.$t.h5" 2>&1 |
    grep "chord (sweep-cg)" >"$tmp/rndlin.$t.txt"
done
if grep -q "mass: 2," "$tmp/rndlin.yaml" && [ -s "$tmp/rndlin.1.txt" ] &&
  cmp -s "$tmp/rndlin.1.txt" "$tmp/rndlin.2.txt" &&
  cmp -s "$tmp/rndlin.1.txt" "$tmp/rndlin.3.txt" &&
  same "$tmp/rndlin.1.h5" "$tmp/rndlin.2.h5" &&
  same "$tmp/rndlin.1.h5" "$tmp/rndlin.3.h5"; then
  pass "random network, unequal masses, chord_linear: 1, 2, 3 threads bit for bit"
else
  fail "random network, unequal masses, chord_linear: 1, 2, 3 threads bit for bit: $(cat "$tmp"/rndlin.?.txt)"
fi

# The default (auto) run gives the trajectory of 1 thread bit for bit.
run_ok "fully-explicit, threads auto" env -u MRVI_THREADS "$mrvi" run "$sys" \
  "${common[@]}" --set integrator.scheme=fully-explicit -o "$tmp/auto.h5"
if same "$tmp/fully-explicit.1.h5" "$tmp/auto.h5"; then
  pass "fully-explicit: the automatic count gives the trajectory of 1 bit for bit"
else
  fail "fully-explicit: the automatic count gives the trajectory of 1 bit for bit"
fi

# Bad counts are refused before anything is written.
if "$mrvi" run "$sys" "${common[@]}" --threads 0 -o "$tmp/bad.h5" \
  2>"$tmp/err.txt"; then
  fail "--threads 0 refused"
elif grep -q "thread count 1..4096 or auto" "$tmp/err.txt" && [ ! -e "$tmp/bad.h5" ]; then
  pass "--threads 0 refused"
else
  fail "--threads 0 refused: $(cat "$tmp/err.txt")"
fi
test_finish
