#!/bin/bash
# The example programs of examples/ (README.md, "Use the library from C"),
# built by meson against libmrvi like a user's program, run and held to
# what the mathematics says they print:
#
# - load_and_run on systems/oscillator.yaml (omega = 1, q0 = 1, p0 = 0) with
#   explicit-slow at p = 1, which is the Stoermer-Verlet method: it keeps
#   the modified energy p^2/2 + (1 - a) omega^2 q^2/2, a = (omega h)^2/4,
#   so the relative energy error a (1 - q_k^2) lies in [0, a] and comes
#   within 1 % of a where q_k passes near 0 (h = 0.1: a = 0.0025).
# - build_model: a free planar molecule; the discrete Noether theorem keeps
#   linear and angular momentum to the Newton tolerance (1e-12 per step,
#   250 steps: drift <= 2.5e-10); the energy error stays below 1e-3.
# - optimal_control: the rest-to-rest double integrator; the discrete
#   optimum J_N = 300/99 within 1e-10 relative, the terminal conditions to
#   1e-10, and the optimal force antisymmetric about T/2.
#
#   test_examples.sh SOURCE_ROOT LOAD_AND_RUN BUILD_MODEL OPTIMAL_CONTROL
set -u
root=${1:?usage: test_examples.sh SOURCE_ROOT LOAD_AND_RUN BUILD_MODEL OPTIMAL_CONTROL}
load_and_run=$2
build_model=$3
optimal_control=$4
# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
cd "$tmp" || exit 1

# value LABEL FILE: the number after LABEL on its line of FILE
value() { sed -n "s/^$1 *\([-+0-9.eE]*\).*/\1/p" "$2" | head -n 1; }
# holds NAME AWK-CONDITION VAR=VALUE...: the condition on the values holds
holds() {
  local name=$1 cond=$2
  shift 2
  local args=()
  for kv in "$@"; do args+=(-v "$kv"); done
  if awk "${args[@]}" "BEGIN { exit !($cond) }"; then
    pass "$name ($*)"
  else
    fail "$name ($*)"
  fi
}

# --- load_and_run: Stoermer-Verlet's energy error --------------------------
run_ok "load_and_run oscillator (explicit-slow, p = 1)" "$load_and_run" \
  "$root/systems/oscillator.yaml" integrator.scheme=explicit-slow \
  integrator.micro_steps=1 integrator.macro_step=0.1
cp out.txt lr.txt
grep -q '^steps 100 of 100' lr.txt && pass "load_and_run: 100 steps" ||
  fail "load_and_run: 100 steps ($(cat lr.txt))"
holds "energy error in [0.99 a, a], a = (omega h)^2/4 = 0.0025" \
  'e != "" && e >= 0.99 * a && e <= a * (1 + 1e-9)' \
  e="$(value 'max relative energy error' lr.txt)" a=0.0025
# A description error comes back as file:line:col and exit status 1.
"$load_and_run" "$root/systems/oscillator.yaml" integrator.micro_steps=0 \
  >/dev/null 2>err.txt
[ $? -eq 1 ] && grep -q 'micro_steps must be >= 1' err.txt &&
  pass "load_and_run: a bad override is reported" ||
  fail "load_and_run: a bad override ($(cat err.txt))"

# --- build_model: Noether ----------------------------------------------------
run_ok "build_model" "$build_model"
cp out.txt bm.txt
holds "linear momentum drift <= 250 steps x 1e-12" 'd != "" && d <= 2.5e-10' \
  d="$(sed -n 's/^linear momentum .*max drift \(.*\)$/\1/p' bm.txt)"
holds "angular momentum drift <= 250 steps x 1e-12" 'd != "" && d <= 2.5e-10' \
  d="$(sed -n 's/^angular momentum .*max drift \(.*\)$/\1/p' bm.txt)"
holds "build_model: energy error below 1e-3" 'e != "" && e < 1e-3' \
  e="$(value 'max relative energy error' bm.txt)"

# --- optimal_control: the discrete optimum ------------------------------------
run_ok "optimal_control" "$optimal_control"
cp out.txt oc.txt
holds "optimal cost = 300/99 within 1e-10 relative" \
  'j != "" && (j - 300 / 99 < 3e-10) && (300 / 99 - j < 3e-10)' \
  j="$(value 'optimal cost' oc.txt)"
holds "terminal violation <= 1e-10" 'v != "" && v <= 1e-10' \
  v="$(value 'terminal violation' oc.txt)"
u=$(sed -n 's/^  u\[[0-9]*\] = //p' oc.txt | tr '\n' ' ')
echo "$u" | awk '{ if (NF != 10) exit 1
  for (j = 1; j <= 5; j++) { s = $j + $(11 - j); if (s > 1e-8 || s < -1e-8) exit 1 } }' &&
  pass "10 controls, antisymmetric about T/2 to 1e-8" ||
  fail "10 controls, antisymmetric about T/2 to 1e-8 ($u)"

test_finish
