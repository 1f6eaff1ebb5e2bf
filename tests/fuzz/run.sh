#!/usr/bin/env bash
# Build the loader's libFuzzer target (clang, ASan + UBSan) in its own build
# directory and run it for a bounded time, seeded by systems/ and
# tests/bad_input/ with the key dictionary tests/fuzz/loader.dict.
#
#   tests/fuzz/run.sh [SECONDS [BUILD_DIR]]     (default 120, build-fuzz)
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
    -Dc_args="-fsanitize=fuzzer-no-link -DMRVI_SMALL_KERNELS=0" \
    -Dbuildtype=debugoptimized >/dev/null
fi
meson compile -C "$build" tests/fuzz/fuzz_loader >/dev/null
mkdir -p "$build/corpus" "$build/artifacts"
export ASAN_OPTIONS=${ASAN_OPTIONS:-detect_leaks=1}
export LSAN_OPTIONS=${LSAN_OPTIONS:-suppressions=$root/tests/fuzz/lsan.supp}
export UBSAN_OPTIONS=${UBSAN_OPTIONS:-halt_on_error=1:print_stacktrace=1}
"$build/tests/fuzz/fuzz_loader" \
  -max_total_time="$secs" -timeout=10 -rss_limit_mb=2048 -max_len=16384 \
  -dict="$root/tests/fuzz/loader.dict" \
  -artifact_prefix="$build/artifacts/" -print_final_stats=1 \
  "$build/corpus" "$root/systems" "$root/tests/bad_input"
