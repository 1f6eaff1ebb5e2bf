#!/usr/bin/env bash
# Fails, naming each file, when clang-format would change a C file of the
# repository.  One pinned version (Debian 12's clang-format-14, which .ci/run
# installs): another version may format differently.
#   tests/check_format.sh        check
#   tests/check_format.sh -i     format in place
set -euo pipefail
cd "$(dirname "$0")/.."
fmt=${CLANG_FORMAT:-clang-format-14}
if ! command -v "$fmt" >/dev/null 2>&1; then
  echo "check_format: $fmt not found (Debian package clang-format-14)" >&2
  exit 1
fi
mapfile -t files < <(git ls-files '*.c' '*.h')
if [ "${1:-}" = "-i" ]; then
  "$fmt" -i "${files[@]}"
  exit 0
fi
bad=0
for f in "${files[@]}"; do
  if ! "$fmt" --dry-run --Werror "$f" >/dev/null 2>&1; then
    echo "check_format: clang-format would change $f (run tests/check_format.sh -i)"
    bad=1
  fi
done
[ "$bad" -eq 0 ] && echo "check_format: ${#files[@]} C files formatted"
exit "$bad"
