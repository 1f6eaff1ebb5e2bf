#!/usr/bin/env bash
# Keeps the library's layers one-way (doc/architecture.md): every
# `#include "..."` of src/**/*.c|h and constraints/*.c|h names a header of
# its own layer or of a lower one, in the order
#   util  <  constraints  <  model  <  step  <  solver  <  integrator
#         <  ocp  <  io  <  batch  <  cli
# (src/mrvi.h, the public header, counts as util; cli may include anything;
# tests/ and bench/ are exempt).  A file of src/ in no layer, or an include
# that names no file (looked up beside the file, then in src/), fails too.
# The checker is first shown to fail on a planted upward include.
#
#   test_layers.sh SOURCE_ROOT
#
# Prints "N passed, M failed" and exits non-zero on any failure.
set -u

root=${1:?usage: test_layers.sh SOURCE_ROOT}

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"

layers=(util constraints model step solver integrator ocp io batch cli)

# layer_of PATH (relative to the tree's root): the index of its layer in
# $layers, or -1.
layer_of() {
  case $1 in
  src/mrvi.h) echo 0 ;;
  constraints/*) echo 1 ;;
  src/*/*)
    local folder=${1#src/}
    folder=${folder%%/*}
    local i
    for i in "${!layers[@]}"; do
      if [ "${layers[$i]}" = "$folder" ]; then
        echo "$i"
        return
      fi
    done
    echo -1
    ;;
  *) echo -1 ;;
  esac
}

# check_tree ROOT: one line per violation on stdout, nothing if none.
check_tree() {
  local top=$1 file rel lf line inc target lt
  while IFS= read -r file; do
    rel=${file#"$top"/}
    lf=$(layer_of "$rel")
    if [ "$lf" -lt 0 ]; then
      echo "$rel: in no layer (add its folder to tests/test_layers.sh)"
      continue
    fi
    while IFS= read -r line; do
      inc=$(printf '%s\n' "$line" | sed -E 's/^[^"]*"([^"]*)".*/\1/')
      if [ -f "$(dirname "$file")/$inc" ]; then
        target=$(dirname "$rel")/$inc
      elif [ -f "$top/src/$inc" ]; then
        target=src/$inc
      else
        echo "$rel: #include \"$inc\" names no file"
        continue
      fi
      target=$(realpath -m --relative-to="$top" "$top/$target")
      lt=$(layer_of "$target")
      if [ "$lt" -lt 0 ]; then
        echo "$rel: #include \"$inc\" ($target is in no layer)"
      elif [ "$lt" -gt "$lf" ]; then
        echo "$rel: #include \"$inc\" (${layers[$lf]} must not include ${layers[$lt]})"
      fi
    done < <(grep -E '^[[:space:]]*#[[:space:]]*include[[:space:]]*"' "$file")
  done < <(find "$top/src" "$top/constraints" -type f \( -name '*.c' -o -name '*.h' \) | sort)
}

# --- the checker fails on a planted upward include ---
mkdir -p "$tmp/tree/src/util" "$tmp/tree/src/model" "$tmp/tree/constraints"
printf '#include "mrvi.h"\n' >"$tmp/tree/src/util/util.h"
printf '#include "util/util.h"\n' >"$tmp/tree/src/model/model.h"
printf '#include "util/util.h"\n' >"$tmp/tree/constraints/ok.c"
: >"$tmp/tree/src/mrvi.h"
if [ -z "$(check_tree "$tmp/tree")" ]; then
  pass "checker passes a layered tree"
else
  fail "checker passes a layered tree: $(check_tree "$tmp/tree")"
fi
printf '#include "model/model.h"\n' >"$tmp/tree/constraints/bad.c"
out=$(check_tree "$tmp/tree")
if [ "$out" = 'constraints/bad.c: #include "model/model.h" (constraints must not include model)' ]; then
  pass "checker names a planted upward include"
else
  fail "checker names a planted upward include: got '$out'"
fi
rm "$tmp/tree/constraints/bad.c"
printf '#include "internal.h"\n' >"$tmp/tree/src/model/m.c"
if check_tree "$tmp/tree" | grep -q 'src/model/m.c: #include "internal.h" names no file'; then
  pass "checker names an include of no file"
else
  fail "checker names an include of no file"
fi

# --- the library's sources ---
out=$(check_tree "$root")
if [ -z "$out" ]; then
  pass "every include of src/ and constraints/ names its own or a lower layer"
else
  fail "includes against the layers:"
  printf '%s\n' "$out" | sed 's/^/     /'
fi

test_finish
