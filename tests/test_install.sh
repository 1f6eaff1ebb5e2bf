#!/usr/bin/env bash
# `meson install` into a staging directory (DESTDIR) gives a working prefix:
# the installed mrvi finds the installed libmrvi.so through its relocatable
# rpath ($ORIGIN/../LIBDIR) with LD_LIBRARY_PATH unset, the description files
# are in share/mrvi/systems and run, the docs in share/doc/mrvi, and the
# installed mrvi-plot draws a run (skipped without python3-matplotlib/h5py).
# A C program is built against the staged prefix exactly as README.md says
# ("Use the library from C": PKG_CONFIG_PATH at PREFIX/lib/MULTIARCH/
# pkgconfig, pkg-config --cflags --libs mrvi, an rpath from pkg-config
# --variable=libdir mrvi) from the installed examples, and runs without
# LD_LIBRARY_PATH on the installed library.
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

# --- a C program against the installed library, as README.md says ---------
# (The staged prefix is a real one for pkg-config: mrvi.pc is relocatable,
# prefix=${pcfiledir}/../../.., meson's pkgconfig.relocatable.)
multiarch=$(cc -print-multiarch 2>/dev/null)
pcdir=$prefix/lib${multiarch:+/$multiarch}/pkgconfig
# The build's libdir and sanitizers (a program linked to a sanitized
# libmrvi is built with the same -fsanitize, as CI's ASan build needs).
read -r libdir_opt sanitize < <(cd "$build" &&
  "$meson" introspect --buildoptions 2>/dev/null | /usr/bin/python3 -c '
import json, sys
o = {x["name"]: x["value"] for x in json.load(sys.stdin)}
print(o["libdir"], ",".join(o["b_sanitize"]) if isinstance(o["b_sanitize"], list) else o["b_sanitize"])')
san_flags=()
case ${sanitize:-none} in none | "") ;; *) san_flags=(-fsanitize="$sanitize") ;; esac
if [ "$libdir_opt" != "lib${multiarch:+/$multiarch}" ]; then
  echo "skip README's pkg-config path: this build has libdir $libdir_opt"
  pcdir=$prefix/$libdir_opt/pkgconfig
elif [ -f "$pcdir/mrvi.pc" ]; then
  pass "mrvi.pc in PREFIX/lib/$multiarch/pkgconfig (README)"
else
  fail "mrvi.pc in PREFIX/lib/$multiarch/pkgconfig ($(find "$prefix" -name mrvi.pc))"
fi
if ! grep -q '^prefix=${pcfiledir}' "$pcdir/mrvi.pc" 2>/dev/null; then
  echo "skip the C program: $build was configured without"
  echo "     pkgconfig.relocatable (meson configure $build -Dpkgconfig.relocatable=true)"
else
  export PKG_CONFIG_PATH=$pcdir
  examples=$share/doc/mrvi/examples
  for ex in load_and_run optimal_control; do
    # shellcheck disable=SC2046 # pkg-config's words are meant to split
    run_ok "cc $ex.c against the installed mrvi" cc "${san_flags[@]}" -o "$tmp/$ex" \
      "$examples/$ex.c" $(pkg-config --cflags --libs mrvi) \
      -Wl,-rpath,"$(pkg-config --variable=libdir mrvi)"
  done
  unset PKG_CONFIG_PATH
  lib=$(ldd "$tmp/load_and_run" 2>/dev/null |
    sed -n 's/^[[:space:]]*libmrvi\.so[^ ]* => \([^ ]*\) .*/\1/p')
  case $(realpath -m "${lib:-/none}") in
  "$(realpath -m "$prefix")"/*) pass "the program finds libmrvi in the prefix ($lib)" ;;
  *) fail "the program finds libmrvi in the prefix (ldd: '${lib:-not found}')" ;;
  esac
  run_ok "installed load_and_run runs" "$tmp/load_and_run" \
    "$share/mrvi/systems/fpu.yaml" integrator.t_end=3
  if grep -q '^steps 10 of 10' "$tmp/out.txt" &&
    grep -q '^max relative energy error [0-9.e+-]*$' "$tmp/out.txt"; then
    pass "load_and_run: 10 steps and the energy error"
  else
    fail "load_and_run output ($(cat "$tmp/out.txt"))"
  fi
  run_ok "installed optimal_control runs" "$tmp/optimal_control"
  if grep -q '^optimal cost 3\.0303030303' "$tmp/out.txt"; then
    pass "optimal_control: cost 300/99 (mrvi_ocp.h installed)"
  else
    fail "optimal_control output ($(cat "$tmp/out.txt"))"
  fi
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
