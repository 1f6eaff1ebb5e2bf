#!/usr/bin/env bash
# Build the libFuzzer targets (clang, ASan + UBSan) in their own build
# directory and run each for a bounded time:
#   - fuzz_loader, the description loader, seeded by systems/,
#     tests/bad_input/ and tests/fuzz/seeds/ (valid files of features the
#     shipped systems leave out: the compact spring table's laws and big
#     generators, state actuators on bodies, joints and pairs, and links to
#     bench/'s problems, and the edge cases of a network: no springs, one
#     particle, the smallest chain, ring and lattices 1 x N, every spring
#     fast or slow, more threads than records) with the key dictionary
#     tests/fuzz/loader.dict; a model it admits with at most 64
#     coordinates and 16 micro steps then takes two macro steps on two
#     threads (fuzz_loader.c), so that a crafted file reaches the
#     integrator's creation and its solvers too;
#   - fuzz_h5, the readers of an mrvi output (HDF5) file, seeded by small
#     outputs made here by the fuzz build's mrvi (BUILD_DIR/h5seeds: FPU,
#     a constrained cart pendulum, the heavy top (a body), a lattice with
#     particles and /micro (its springs in the compact table), the robot
#     arm (bodies, joints, particles on body points), bench/ocp_winch.yaml
#     run without its controls (a rail, a fast load), and for the
#     --controls reader the output of mrvi optimize on
#     systems/ocp_double_integrator.yaml, and for mrvi batch --resume's
#     the master files of a run batch and of an optimize batch).
#
#   - fuzz_load, the same target built without the steps (-DFUZZ_STEP=0):
#     the loader alone at several times the inputs a second, run first for
#     LOAD_SECONDS on the same corpus, which fuzz_loader then starts from;
#
#   tests/fuzz/run.sh [SECONDS [BUILD_DIR [H5_SECONDS [LOAD_SECONDS]]]]
#                         (default 120, build-fuzz, 60, LOAD_SECONDS = SECONDS)
#
# FUZZ_SEED (default 1) fixes libFuzzer's random seed, so that a run of the
# same code on the same seeds repeats its inputs (CI runs this way: what
# passed here passes there); FUZZ_SEED=0 lets libFuzzer pick one, for
# exploratory runs:  FUZZ_SEED=0 tests/fuzz/run.sh 3600
#
# The fuzz build lowers two limits so that every input the loader admits
# fits the fuzzer's 2 GiB: the memory the size checks allow
# (MRVI_MEMORY_CAP, 256 MiB: limits.max_memory, default 16 GiB, is capped
# there, also where the file raises it) and the particles per generator
# (MRVI_MAX_GENERATED, 20000; a 3000 x 3000 lattice takes 42 s and 6 GB to
# load, legitimately).  The checks themselves are the same code.  It also
# keeps at most 4 spring prototypes in the compact element table
# (MRVI_EREC_LP_MAX, 2^24 in other builds; src/model/model.h), so that a
# file with a few parameter sets of one law takes the path of a model
# beyond 2^24: the later sets' springs kept in full beside compact ones.
#
# FUZZ_LOW=1 (default BUILD_DIR build-fuzz-low) lowers the limits further,
# so that small crafted files reach the paths of large models: one spring
# prototype (MRVI_EREC_LP_MAX=1), 64 particles a generator, 128
# coordinates by default, 16 MiB of memory, and the sparse Gram matrix
# from 3 constraint rows (MRVI_GRAM_DENSE_MAX=2, src/model/model.h; 32 in
# other builds).  Round 17 ran both builds 1200 s a target
# (doc/performance/17-audit17.md).
#
# Exits non-zero when the fuzzer finds a crash, sanitizer report, leak or
# timeout; the input that triggered it is left in BUILD_DIR/artifacts/.
# Keep every finding as a regression file in tests/bad_input/ (loader) or
# tests/test_hostile_h5.sh (HDF5 readers).
#
# libhdf5 1.10.8 (Debian 12) has findings of its own on corrupted files
# (tests/test_hostile_h5.sh): it leaks the metadata of an object header it
# fails to read (H5Dopen2 -> H5O_protect -> H5FL_reg_calloc) and
# dereferences wild pointers in H5C_protect (SEGV).  It also overruns its
# global heap in H5HG_read (memcpy-param-overlap), loops there, and
# allocates whatever length a corrupted vlen string declares
# (H5T__conv_vlen): since 2026-11-28 (branch tidy10) mrvi writes no
# variable-length strings and its readers refuse them unread
# (doc/output.md, "Strings"), so the global heap of an input is never
# read; the run of this script before that change (120 s, 60 s for
# fuzz_h5, seed 1, load 17 on 2 cores) had 1 finding inside libhdf5, a
# timeout in H5C_protect under H5HG_read <- H5T__conv_vlen <- read_text
# (725 inputs), and the runs after it none (348 and 1 231 inputs; the
# earlier 15-input corpus and that artifact replay clean on the new
# readers).  For fuzz_h5:
#   - leaks: tests/fuzz/lsan.supp suppresses every leak allocated inside
#     libhdf5.  That would also hide an HDF5 object mrvi forgets to close,
#     so fuzz_h5 itself fails when any HDF5 object is still open after the
#     readers (H5Fget_obj_count), and the ASan test suite runs on valid
#     files without suppressions;
#   - crashes: fuzz_h5 runs with -fork=1 -ignore_crashes=1 so that one
#     inside libhdf5 does not end the run; every crash artifact is then run
#     again and judged by tests/hdf5_own.awk: a report whose every stack
#     (access, allocation) starts in libhdf5 is libhdf5's (counted, kept in
#     BUILD_DIR/artifacts-h5/, not failed); any frame of mrvi's first, a
#     UBSan report, a leak or a timeout that interrupted mrvi's code fails
#     the run (a timeout that interrupted libhdf5, which loops on some
#     corrupted global heaps, is libhdf5's, as test_hostile_h5.sh's hangs).  So does an
#     out-of-memory (> 2 GiB) unless libhdf5 asked for it (as it did, 4 GiB,
#     for a corrupted vlen string before mrvi refused them unread).
#     ASan's quarantine is lowered to 8 MiB (twice the executions/s: HDF5
#     callocs fresh pages for every file).
set -euo pipefail
secs=${1:-120}
root=$(cd "$(dirname "$0")/../.." && pwd)
limits="-DMRVI_MEMORY_CAP=268435456 -DMRVI_MAX_GENERATED=20000 -DMRVI_EREC_LP_MAX=4"
build=${2:-$root/build-fuzz}
if [ "${FUZZ_LOW:-0}" = 1 ]; then
  limits="-DMRVI_MEMORY_CAP=16777216 -DMRVI_MAX_GENERATED=64 -DMRVI_MAX_COORDINATES=128 -DMRVI_EREC_LP_MAX=1 -DMRVI_GRAM_DENSE_MAX=2"
  build=${2:-$root/build-fuzz-low}
fi
h5secs=${3:-60}
loadsecs=${4:-$secs}
if [ ! -d "$build" ]; then
  CC=clang meson setup "$build" "$root" -Dfuzz=true \
    -Db_sanitize=address,undefined -Db_lundef=false \
    -Dc_args="-fsanitize=fuzzer-no-link -DMRVI_SMALL_KERNELS=0 $limits" \
    -Dbuildtype=debugoptimized >/dev/null
fi
meson compile -C "$build" tests/fuzz/fuzz_load tests/fuzz/fuzz_loader tests/fuzz/fuzz_h5 \
  mrvi:executable >/dev/null
mkdir -p "$build/corpus" "$build/artifacts"
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$root/tests/fuzz/lsan.supp}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}
# fuzz_load (the loader alone, LOAD_SECONDS) first, then fuzz_loader
# (stepping what it loads, SECONDS) on the corpus the first one grew.
for target in fuzz_load fuzz_loader; do
  t=$secs
  [ $target = fuzz_load ] && t=$loadsecs
  [ "$t" -gt 0 ] || continue
  "$build/tests/fuzz/$target" \
    -seed="${FUZZ_SEED:-1}" -max_total_time="$t" -timeout=10 -rss_limit_mb=2048 -max_len=16384 \
    -dict="$root/tests/fuzz/loader.dict" \
    -artifact_prefix="$build/artifacts/" -print_final_stats=1 \
    "$build/corpus" "$root/systems" "$root/tests/bad_input" \
    "$root/tests/fuzz/seeds"
done

# --- the HDF5 readers -------------------------------------------------------
seeds=$build/h5seeds
if [ ! -f "$seeds/ocp.h5" ] || [ ! -f "$seeds/winch.h5" ] ||
  [ ! -f "$seeds/batch_opt.h5" ]; then
  mkdir -p "$seeds"
  run() { ASAN_OPTIONS=detect_leaks=0 "$build/mrvi" run -q --force "$@"; }
  run "$root/systems/fpu.yaml" --set integrator.t_end=0.6 -o "$seeds/fpu.h5"
  run "$root/systems/cart_pendulum.yaml" --set integrator.t_end=0.2 \
    -o "$seeds/cart.h5"
  run "$root/systems/heavy_top.yaml" --set integrator.t_end=0.05 \
    -o "$seeds/top.h5" 2>/dev/null
  run "$root/systems/lattice.yaml" --set integrator.t_end=0.05 \
    -o "$seeds/lat.h5" 2>/dev/null
  run "$root/systems/robot_arm_payload.yaml" --set integrator.t_end=0.02 \
    -o "$seeds/arm.h5" 2>/dev/null
  run "$root/bench/ocp_winch.yaml" --set integrator.t_end=0.1 \
    -o "$seeds/winch.h5" 2>/dev/null
  # the --controls reader's: a file of mrvi optimize for its problem
  ASAN_OPTIONS=detect_leaks=0 "$build/mrvi" optimize -q \
    "$root/systems/ocp_double_integrator.yaml" -o "$seeds/ocp.h5" >/dev/null
  # mrvi batch --resume's: the master files of a run batch (2 x 2 cases,
  # seeded) and of an optimize batch (2 cases); their case folders go
  ASAN_OPTIONS=detect_leaks=0 "$build/mrvi" batch -q "$root/systems/fpu.yaml" \
    -o "$seeds/batch_run.h5" --vary integrator.t_end=0.6 \
    --vary integrator.micro_steps=1,2 --seeds 2 --velocity-std 0.1 >/dev/null
  ASAN_OPTIONS=detect_leaks=0 "$build/mrvi" batch -q --optimize \
    "$root/systems/ocp_double_integrator.yaml" -o "$seeds/batch_opt.h5" \
    --vary integrator.t_end=2,2.2 >/dev/null
  rm -rf "$seeds"/*.xdmf "$seeds"/*.cases
fi
art=$build/artifacts-h5
mkdir -p "$build/corpus-h5" "$art"
rm -f "$art"/*.txt
export ASAN_OPTIONS=detect_leaks=1:quarantine_size_mb=8
"$build/tests/fuzz/fuzz_h5" \
  -seed="${FUZZ_SEED:-1}" -max_total_time="$h5secs" -timeout=10 -rss_limit_mb=2048 -max_len=65536 \
  -fork=1 -ignore_crashes=1 -artifact_prefix="$art/" -print_final_stats=1 \
  "$build/corpus-h5" "$seeds" 2>"$art/fuzz.log" || true
grep -E '^#[0-9]+: cov|INFO: exiting|DONE' "$art/fuzz.log" | tail -2
hdf5=0 ours=0
for f in "$art"/crash-* "$art"/leak-* "$art"/timeout-* "$art"/oom-*; do
  [ -e "$f" ] || continue
  "$build/tests/fuzz/fuzz_h5" -timeout=10 -rss_limit_mb=2048 "$f" >"$f.txt" 2>&1 && continue
  case $f in
  */crash-* | */oom-* | */timeout-*) if awk -f "$root/tests/hdf5_own.awk" "$f.txt"; then
      hdf5=$((hdf5 + 1))
      echo "fuzz_h5: inside libhdf5 (not failed): $f: $(grep -m1 -o 'AddressSanitizer: [A-Za-z-]*\|libFuzzer: timeout' "$f.txt")$(grep -m1 -o ' in H5[A-Za-z_0-9]*' "$f.txt")"
      continue
    fi ;;
  esac
  ours=$((ours + 1))
  echo "fuzz_h5: FINDING $f (report: $f.txt)"
  grep -m3 'ERROR\|runtime error\|left open' "$f.txt" || true
done
echo "fuzz_h5: $ours findings in mrvi, $hdf5 inside libhdf5"
[ "$ours" -eq 0 ]
