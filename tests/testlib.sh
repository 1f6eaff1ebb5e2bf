# Helpers shared by the shell tests (sourced; the caller sets $tmp, a
# scratch directory).  Each check prints "ok   NAME" or "FAIL NAME"; the
# script ends with test_finish, which prints "N passed, M failed" and
# returns non-zero on a failure.

passed=0
failed=0

pass() { passed=$((passed + 1)); echo "ok   $1"; }
fail() { failed=$((failed + 1)); echo "FAIL $1"; }

# run_ok NAME CMD...: the command exits 0 (its output in $tmp/out.txt and
# $tmp/err.txt)
run_ok() {
  local name=$1
  shift
  if "$@" >"$tmp/out.txt" 2>"$tmp/err.txt"; then
    pass "$name"
  else
    fail "$name (exit $?)"
    sed 's/^/     /' "$tmp/err.txt" | head -20
  fi
}

test_finish() {
  echo "$passed passed, $failed failed"
  [ "$failed" -eq 0 ]
}
