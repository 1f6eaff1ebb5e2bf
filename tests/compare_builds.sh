#!/usr/bin/env bash
# Usage: tests/compare_builds.sh MRVI_A MRVI_B
#
# Runs a few shipped systems to t = 2 with two builds of the command-line
# tool -- in CI the default build and one with the plain-C twins
# (meson -Dsimd=false -Dsmall_kernels=false) -- and compares /macro and
# /micro of their output files with h5diff, bit for bit: the twins do the
# same operations in the same order (src/util/simd.h, src/solver/small.h),
# so any difference is a bug.  Prints one line per system and group; exits
# non-zero if any differs or a run fails.
set -euo pipefail

a=${1:?usage: compare_builds.sh MRVI_A MRVI_B}
b=${2:?usage: compare_builds.sh MRVI_A MRVI_B}
root=$(cd "$(dirname "$0")/.." && pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT

fail=0
for n in fpu spring_ring lattice pendulum_chain cart_pendulum; do
  for side in a b; do
    exe=$a
    [ "$side" = b ] && exe=$b
    if ! "$exe" run "$root/systems/$n.yaml" -o "$tmp/$n.$side.h5" \
      --set integrator.t_end=2 >"$tmp/$n.$side.log" 2>&1; then
      echo "FAILED $n ($exe):"
      cat "$tmp/$n.$side.log"
      fail=1
      continue 2
    fi
  done
  for g in /macro /micro; do
    h5ls "$tmp/$n.a.h5$g" >/dev/null 2>&1 || continue
    if h5diff "$tmp/$n.a.h5" "$tmp/$n.b.h5" "$g" "$g" >/dev/null 2>&1; then
      echo "same   $n $g"
    else
      echo "DIFFER $n $g"
      h5diff -r "$tmp/$n.a.h5" "$tmp/$n.b.h5" "$g" "$g" | head -n 20 || true
      fail=1
    fi
  done
done
exit $fail
