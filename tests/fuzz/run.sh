#!/usr/bin/env bash
# Build the loader's libFuzzer target (clang, ASan + UBSan) in its own build
# directory and run it for a bounded time, seeded by systems/ and
# tests/bad_input/ with the key dictionary tests/fuzz/loader.dict.
#
#   tests/fuzz/run.sh [SECONDS [BUILD_DIR]]     (default 120, build-fuzz)
#
# FUZZ_SEED (default 1) fixes libFuzzer's random seed, so that a run of the
# same code on the same seeds repeats its inputs (CI runs this way: what
# passed here passes there); FUZZ_SEED=0 lets libFuzzer pick one, for
# exploratory runs:  FUZZ_SEED=0 tests/fuzz/run.sh 3600
#
# The fuzz build lowers two limits so that every input the loader admits
# fits the fuzzer's 2 GiB: the memory the size checks assume
# (MRVI_MEMORY_CAP, 256 MiB) and the particles per generator
# (MRVI_MAX_GENERATED, 20000; a 3000 x 3000 lattice takes 42 s and 6 GB to
# load, legitimately).  The checks themselves are the same code.
#
# Exits non-zero when the fuzzer finds a crash, sanitizer report, leak or
# timeout; the input that triggered it is left in BUILD_DIR/artifacts/.
# Keep every finding as a regression file in tests/bad_input/.
set -euo pipefail
secs=${1:-120}
root=$(cd "$(dirname "$0")/../.." && pwd)
build=${2:-$root/build-fuzz}
if [ ! -d "$build" ]; then
  CC=clang meson setup "$build" "$root" -Dfuzz=true \
    -Db_sanitize=address,undefined -Db_lundef=false \
    -Dc_args="-fsanitize=fuzzer-no-link -DMRVI_SMALL_KERNELS=0 -DMRVI_MEMORY_CAP=268435456 -DMRVI_MAX_GENERATED=20000" \
    -Dbuildtype=debugoptimized >/dev/null
fi
meson compile -C "$build" tests/fuzz/fuzz_loader >/dev/null
mkdir -p "$build/corpus" "$build/artifacts"
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$root/tests/fuzz/lsan.supp}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}
"$build/tests/fuzz/fuzz_loader" \
  -seed="${FUZZ_SEED:-1}" -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 -max_len=16384 \
  -dict="$root/tests/fuzz/loader.dict" \
  -artifact_prefix="$build/artifacts/" -print_final_stats=1 \
  "$build/corpus" "$root/systems" "$root/tests/bad_input"
