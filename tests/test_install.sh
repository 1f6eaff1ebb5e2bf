#!/usr/bin/env bash
# `meson install` into a staging directory (DESTDIR) gives a working prefix:
# the installed mrvi finds the installed libmrvi.so through its relocatable
# rpath ($ORIGIN/../LIBDIR) with LD_LIBRARY_PATH unset, the description files
# are in share/mrvi/systems and run, the docs in share/doc/mrvi, and the
# installed mrvi-plot draws a run (skipped without python3-matplotlib/h5py).
#
#   test_install.sh MESON BUILD_ROOT
set -u
meson=${1:?usage: test_install.sh MESON BUILD_ROOT}
build=${2:?usage: test_install.sh MESON BUILD_ROOT}
# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
unset LD_LIBRARY_PATH

run_ok "meson install --destdir" "$meson" install -C "$build" --destdir "$tmp/D" --no-rebuild --quiet
exe=$(find "$tmp/D" -path '*/bin/mrvi' -type f | head -n 1)
if [ -z "$exe" ]; then
  fail "installed bin/mrvi exists"
  test_finish
  exit
fi
pass "installed bin/mrvi exists"
prefix=$(dirname "$(dirname "$exe")")
share=$prefix/share

# libmrvi resolves inside the staged prefix, not in the build directory.
lib=$(ldd "$exe" | sed -n 's/^[[:space:]]*libmrvi\.so[^ ]* => \([^ ]*\) .*/\1/p')
case $lib in
"$prefix"/*) pass "libmrvi found in the prefix ($lib)" ;;
*) fail "libmrvi found in the prefix (ldd: '${lib:-not found}')" ;;
esac

for f in "$share/mrvi/systems/fpu.yaml" "$share/doc/mrvi/README.md" \
  "$share/doc/mrvi/doc/description-files.md" "$share/doc/mrvi/doc/output.md"; do
  if [ -s "$f" ]; then pass "installed ${f#"$prefix"/}"; else fail "installed ${f#"$prefix"/}"; fi
done

cd "$tmp" || exit 1
run_ok "installed mrvi check" "$exe" check "$share/mrvi/systems/fpu.yaml"
if grep -q '^coordinates *6 (3 slow, 3 fast)$' "$tmp/out.txt"; then
  pass "check output: 6 coordinates"
else
  fail "check output: 6 coordinates ($(head -c 300 "$tmp/out.txt"))"
fi
run_ok "installed mrvi run" "$exe" run "$share/mrvi/systems/fpu.yaml" \
  --set integrator.t_end=3 -o "$tmp/fpu.h5"
if grep -q 'completed 10 of 10 macro steps' "$tmp/out.txt" && [ -s "$tmp/fpu.h5" ]; then
  pass "run completed: 10 steps and the file"
else
  fail "run completed ($(cat "$tmp/out.txt"))"
fi

if /usr/bin/python3 -c 'import matplotlib, h5py' >/dev/null 2>&1; then
  run_ok "installed mrvi-plot run" "$prefix/bin/mrvi-plot" run "$tmp/fpu.h5" -o "$tmp/figs"
  if ls "$tmp"/figs/*energy*.png >/dev/null 2>&1; then
    pass "mrvi-plot drew the energy figure"
  else
    fail "mrvi-plot drew the energy figure ($(ls "$tmp/figs" 2>&1))"
  fi
else
  echo "skip mrvi-plot: no /usr/bin/python3 with matplotlib and h5py"
fi
test_finish
