#!/usr/bin/env bash
# mrvi batch over MPI ranks (doc/batch.md, "Across machines: MPI").
#
# Built with MPI: `mpiexec -n 2` equals a serial batch (every case file by
# h5diff, the table except wall times) with 1 and 2 jobs per rank, for
# seeded cases, multi-start optimize cases and a failing case too; a bad override is refused once,
# before any case runs; --resume under mpiexec runs only the pending cases
# and gives the uninterrupted batch; `mrvi converge` and `mrvi stability`
# under mpiexec print and write what they print and write serially.
# Built without MPI: a run under an MPI launcher with more than one rank is
# refused with a message (instead of every rank running every case); the
# mpiexec runs are skipped with a message.
#
#   test_batch_mpi.sh MRVI_BINARY SOURCE_ROOT mpi|no-mpi
#
# Prints "N passed, M failed" and exits non-zero on any failure.
set -u

mrvi=${1:?usage: test_batch_mpi.sh MRVI_BINARY SOURCE_ROOT mpi|no-mpi}
root=${2:?usage: test_batch_mpi.sh MRVI_BINARY SOURCE_ROOT mpi|no-mpi}
built=${3:?usage: test_batch_mpi.sh MRVI_BINARY SOURCE_ROOT mpi|no-mpi}
fpu=$root/systems/fpu.yaml

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
# shellcheck source=tests/batchlib.sh
. "$(dirname "$0")/batchlib.sh"

cd "$tmp" || exit 1

grid=(--vary integrator.micro_steps=1,2,4 --vary integrator.macro_step=0.01,0.02
  --vary integrator.t_end=20)

if [ "$built" != mpi ]; then
  # What an MPI launcher sets (Open MPI, PMI launchers as MPICH's, srun).
  for env in OMPI_COMM_WORLD_SIZE=2 PMI_SIZE=3 SLURM_STEP_NUM_TASKS=4; do
    env "$env" "$mrvi" batch "$fpu" -o r.h5 -q "${grid[@]}" 2>err.txt
    rc=$?
    if [ $rc = 1 ] && grep -q "built without MPI" err.txt && [ ! -e r.h5 ]; then
      pass "$env without MPI: refused, nothing run"
    else
      fail "$env without MPI (exit $rc): $(cat err.txt)"
    fi
  done
  OMPI_COMM_WORLD_SIZE=2 OMPI_COMM_WORLD_RANK=1 "$mrvi" batch "$fpu" -o r.h5 \
    -q "${grid[@]}" 2>err.txt
  [ $? = 1 ] && [ ! -s err.txt ] && pass "only rank 0 prints the refusal" ||
    fail "only rank 0 prints the refusal: $(cat err.txt)"
  run_ok "one rank of a launcher runs the batch" env OMPI_COMM_WORLD_SIZE=1 \
    "$mrvi" batch "$fpu" -o r.h5 -q "${grid[@]}"
  for study in converge stability; do
    env OMPI_COMM_WORLD_SIZE=2 "$mrvi" $study "$root/systems/oscillator.yaml" \
      -q -o st.h5 2>err.txt
    rc=$?
    [ $rc = 1 ] && grep -q "built without MPI" err.txt && [ ! -e st.h5 ] &&
      pass "$study under a launcher without MPI: refused" ||
      fail "$study under a launcher without MPI (exit $rc): $(cat err.txt)"
  done
  echo "skipped: the mpiexec runs (built without MPI: meson setup -Dmpi=enabled)"
  test_finish
  exit
fi

if ! command -v mpiexec >/dev/null; then
  echo "skipped: built with MPI, but no mpiexec (openmpi-bin)"
  exit 77
fi
# Two ranks on however many cores (--oversubscribe); Open MPI refuses root
# without --allow-run-as-root (CI runs as root).  Open MPI's own allocations
# at MPI_Init read as leaks to LeakSanitizer: no leak check under mpiexec.
mpirun=(mpiexec -n 2 --oversubscribe)
[ "$(id -u)" = 0 ] && mpirun+=(--allow-run-as-root)
export ASAN_OPTIONS="${ASAN_OPTIONS:+$ASAN_OPTIONS:}detect_leaks=0"

# --- 2 ranks equal one process ---
run_ok "serial batch" "$mrvi" batch "$fpu" -o s.h5 -q -j 1 "${grid[@]}"
run_ok "mpiexec -n 2, 1 job per rank" "${mpirun[@]}" "$mrvi" batch "$fpu" \
  -o m1.h5 -j 1 "${grid[@]}"
grep -q "6 cases on 2 ranks x 1 job" err.txt && pass "header names the ranks" ||
  fail "header names the ranks: $(head -n 1 err.txt)"
grep -q "(rank 0): completed" err.txt && grep -q "(rank 1): completed" err.txt &&
  pass "both ranks ran cases" || fail "both ranks ran cases: $(cat err.txt)"
[ "$(grep -c 'cases completed' out.txt)" = 1 ] &&
  pass "one summary line (rank 0)" || fail "one summary line: $(cat out.txt)"
seq 0 5 | sed 's/.*/&:&/' | same_runs s.h5 m1.h5 && same_table s.h5 m1.h5 &&
  pass "2 ranks x 1 job equal the serial batch (h5diff)" ||
  fail "2 ranks x 1 job equal the serial batch (h5diff)"
run_ok "mpiexec -n 2, 2 jobs per rank" "${mpirun[@]}" "$mrvi" batch "$fpu" \
  -o m2.h5 -q -j 2 "${grid[@]}"
seq 0 5 | sed 's/.*/&:&/' | same_runs s.h5 m2.h5 && same_table s.h5 m2.h5 &&
  pass "2 ranks x 2 jobs equal the serial batch (h5diff)" ||
  fail "2 ranks x 2 jobs equal the serial batch (h5diff)"
h5dump -d /runs/case_0004/macro/t m2.h5 >/dev/null 2>&1 &&
  pass "external link of a case run by either rank" ||
  fail "external link of a case run by either rank"

# --- seeds: the same perturbation on 1 and 2 ranks ---
ens=(--vary integrator.micro_steps=1,2 --seeds 3 --velocity-std 0.05
  --vary integrator.t_end=20)
run_ok "ensemble, one process" "$mrvi" batch "$fpu" -o e1.h5 -q -j 1 "${ens[@]}"
run_ok "ensemble, 2 ranks" "${mpirun[@]}" "$mrvi" batch "$fpu" -o e2.h5 -q \
  -j 1 "${ens[@]}"
seq 0 5 | sed 's/.*/&:&/' | same_runs e1.h5 e2.h5 && same_table e1.h5 e2.h5 &&
  pass "seeded cases equal on 1 process and 2 ranks" ||
  fail "seeded cases equal on 1 process and 2 ranks"

# --- multi-start optimize cases: the same starts and files on 2 ranks ---
ocp=$root/systems/ocp_double_integrator.yaml
ms=(--optimize --seeds 4 --control-std 2)
run_ok "multi-start, one process" "$mrvi" batch "$ocp" -o o1.h5 -q -j 1 "${ms[@]}"
run_ok "multi-start, 2 ranks" "${mpirun[@]}" "$mrvi" batch "$ocp" -o o2.h5 -q \
  -j 1 "${ms[@]}"
seq 0 3 | sed 's/.*/&:&/' | same_runs o1.h5 o2.h5 && same_table o1.h5 o2.h5 &&
  h5diff o1.h5 o2.h5 /best_case /best_case >/dev/null 2>&1 &&
  pass "optimize cases and /best_case equal on 1 process and 2 ranks" ||
  fail "optimize cases and /best_case equal on 1 process and 2 ranks"

# --- a failing case is recorded, the others complete ---
"${mpirun[@]}" "$mrvi" batch "$fpu" -o f.h5 -q -j 1 \
  --vary integrator.macro_step=0.02,2,0.01 --vary integrator.t_end=40 \
  >out.txt 2>err.txt
rc=$?
if [ $rc = 2 ] && [ "$(column f.h5 status | tr '\n' ' ')" = "1 2 1 " ] &&
  column f.h5 stop_reason | sed -n 2p | grep -q "Newton did not converge"; then
  pass "failing case recorded under mpiexec (exit 2 from every rank)"
else
  fail "failing case under mpiexec (exit $rc): $(column f.h5 status)"
fi

# --- a bad override: refused once, before any case runs ---
"${mpirun[@]}" "$mrvi" batch "$fpu" -o bad.h5 \
  --vary integrator.micro_steps=1,2,x --vary integrator.macro_step=0.01,0.02 \
  >out.txt 2>err.txt
rc=$?
if [ $rc = 1 ] && [ "$(grep -c 'case 4 (integrator.micro_steps=x' err.txt)" = 1 ] &&
  [ ! -e bad.h5 ] && [ ! -e bad.cases ]; then
  pass "bad override refused once under mpiexec, nothing written"
else
  fail "bad override under mpiexec (exit $rc): $(cat err.txt)"
fi

# --- --resume under mpiexec ---
# A batch left with cases 1, 3 and 4 pending (as a kill leaves it): the
# serial batch's files with those rows set back to pending and their case
# files removed.
if /usr/bin/python3 -c "import h5py" 2>/dev/null; then
  cp s.h5 p.h5
  cp -r s.cases p.cases
  rm p.cases/case_0001.h5 p.cases/case_0003.h5 p.cases/case_0004.h5
  /usr/bin/python3 - <<'EOF'
import h5py
with h5py.File("p.h5", "r+") as f:
    for c in (1, 3, 4):
        f["/cases/status"][c] = 0
EOF
  run_ok "mpiexec -n 2 --resume" "${mpirun[@]}" "$mrvi" batch --resume p.h5
  grep -q "3 cases left on 2 ranks" err.txt &&
    pass "--resume runs only the 3 pending cases" ||
    fail "--resume runs only the 3 pending cases: $(head -n 1 err.txt)"
  seq 0 5 | sed 's/.*/&:&/' | same_runs s.h5 p.h5 && same_table s.h5 p.h5 &&
    pass "resumed on 2 ranks equals the uninterrupted batch" ||
    fail "resumed on 2 ranks equals the uninterrupted batch"
else
  echo "skipped: --resume under mpiexec (needs python3-h5py)"
fi

# --- mrvi converge and mrvi stability over 2 ranks: the serial output ---
# Every rank runs the study in step; rank 0 hands out the runs (its own and
# rank 1's workers), prints and writes; rank 1 prints nothing.  The chosen
# range (rows deepened with the reference, then one at a time) and a fixed
# range with 2 p; the table, the printed output, the warnings, the CSV.
for mode in chosen fixed; do
  case $mode in
  chosen) range=() ;;
  fixed) range=(--dt0 0.05 --levels 4) ;;
  esac
  "$mrvi" converge "$fpu" --p 5,10 "${range[@]}" --no-cache -j 1 -o cs.h5 \
    --csv cs.csv >cs.out 2>cs.err
  for j in 1 2; do
    "${mpirun[@]}" "$mrvi" converge "$fpu" --p 5,10 "${range[@]}" --no-cache \
      -j $j -o cm.h5 --csv cm.csv >cm.out 2>cm.err
    rc=$?
    sed -i '/^table: /d' cs.out cm.out
    [ $rc = 0 ] && cmp -s cs.out cm.out && cmp -s cs.err cm.err &&
      cmp -s cs.csv cm.csv && h5diff -q cs.h5 cm.h5 &&
      pass "converge ($mode) on 2 ranks x $j jobs: the serial table and output" ||
      fail "converge ($mode) on 2 ranks x $j jobs (exit $rc): $(diff cs.out cm.out | head -5) $(cat cm.err)"
  done
done
# The reference is computed once, by rank 0, and cached once.
rm -rf cache
"${mpirun[@]}" "$mrvi" converge "$fpu" --p 5 --dt0 0.05 --levels 3 \
  --cache cache -o cc.h5 >cc.out 2>cc.err
[ $? = 0 ] && [ "$(grep -c '^reference: ' cc.out)" = 1 ] &&
  [ "$(find cache -name '*.h5' | wc -l)" = 1 ] &&
  pass "converge on 2 ranks: one reference, cached once" ||
  fail "converge on 2 ranks: one reference, cached once: $(cat cc.out cc.err)"
"${mpirun[@]}" "$mrvi" converge "$fpu" --p 5 --dt0 0.05 --levels 3 \
  --cache cache -o cc2.h5 >cc2.out 2>cc2.err
[ $? = 0 ] && grep -q '(cached)' cc2.out && h5diff -q cc.h5 cc2.h5 &&
  pass "converge on 2 ranks: the cached reference read by rank 0, sent to rank 1" ||
  fail "converge on 2 ranks, cached reference: $(cat cc2.out cc2.err)"
# A failing run is reported as by the serial study, once.
"$mrvi" converge "$fpu" --p 5 --dt0 0.125 --levels 3 -j 1 \
  --set integrator.newton.max_iterations=2 -q -o cf.h5 2>cfs.err
echo $? >>cfs.err
"${mpirun[@]}" "$mrvi" converge "$fpu" --p 5 --dt0 0.125 --levels 3 \
  --set integrator.newton.max_iterations=2 -q -o cf.h5 2>cfm.err
echo $? >>cfm.err
grep -v '^mpiexec\|^-\|^ \|^$\|Primary job\|a non-zero exit\|the job to be\|Process name\|Exit code\|the job has been' cfm.err >cfm2.err
cmp -s cfs.err cfm2.err && [ "$(tail -1 cfm.err)" = 2 ] &&
  pass "converge on 2 ranks: a failed run reported once, exit 2" ||
  fail "converge on 2 ranks, failed run: $(cat cfs.err) vs $(cat cfm.err)"
# A file rank 1 cannot read: stopped by rank 0 with the rank named, not a
# hang (the description is read by every rank).
"${mpirun[@]}" "$mrvi" stability nonexistent.yaml -q 2>nf.err
[ $? = 1 ] && [ "$(grep -c 'nonexistent.yaml' nf.err)" = 1 ] &&
  pass "a missing FILE reported once on 2 ranks" ||
  fail "a missing FILE on 2 ranks: $(cat nf.err)"
osc=$root/systems/oscillator.yaml
"$mrvi" stability "$osc" --at 3.5 -j 1 -o ss.h5 >ss.out 2>&1
for j in 1 2; do
  "${mpirun[@]}" "$mrvi" stability "$osc" --at 3.5 -j $j -o sm.h5 >sm.out 2>&1
  rc=$?
  sed -i '/^table: /d' ss.out sm.out
  [ $rc = 0 ] && cmp -s ss.out sm.out && h5diff -q ss.h5 sm.h5 &&
    pass "stability on 2 ranks x $j jobs: the serial table and output" ||
    fail "stability on 2 ranks x $j jobs (exit $rc): $(diff ss.out sm.out | head -5)"
done

test_finish
