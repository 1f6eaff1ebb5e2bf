#!/usr/bin/env bash
# Tests of the mrvi command-line tool: help and version, `check` output,
# `run` with overrides and the HDF5 file it writes, exit statuses, error
# messages with file:line:col, no output on bad input, Ctrl-C handling.
#
#   test_cli.sh MRVI_BINARY SOURCE_ROOT [PROJECT_VERSION]
#
# Prints "N passed, M failed" and exits non-zero on any failure.
set -u

mrvi=${1:?usage: test_cli.sh MRVI_BINARY SOURCE_ROOT [VERSION]}
root=${2:?usage: test_cli.sh MRVI_BINARY SOURCE_ROOT [VERSION]}
version=${3:-$(sed -n "s/^ *version *: *'\([^']*\)'.*/\1/p" "$root/meson.build" | head -n 1)}
fpu=$root/systems/fpu.yaml

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
cd "$tmp" || exit 1

passed=0
failed=0
pass() { passed=$((passed + 1)); }
fail() {
  failed=$((failed + 1))
  printf 'FAIL: %s\n' "$*" >&2
}
check() { # check DESCRIPTION COMMAND...
  local what=$1
  shift
  if "$@"; then pass; else fail "$what"; fi
}

# run_mrvi ARGS...: run mrvi, keep stdout, stderr and the exit status.
run_mrvi() {
  "$mrvi" "$@" >"$tmp/out" 2>"$tmp/err" </dev/null
  rc=$?
  out=$(cat "$tmp/out")
  err=$(cat "$tmp/err")
}
expect_rc() { # expect_rc WANT DESCRIPTION
  if [ "$rc" -eq "$1" ]; then
    pass
  else
    fail "$2: exit status $rc, expected $1; stderr: $err"
  fi
}
contains() { # contains HAYSTACK REGEX DESCRIPTION
  if printf '%s\n' "$1" | grep -Eq -- "$2"; then
    pass
  else
    fail "$3: no match for /$2/ in: $1"
  fi
}
no_h5_files() { # nothing written into the working directory or $tmp/o
  ! ls "$tmp"/*.h5 "$tmp"/o/*.h5 >/dev/null 2>&1
}

# HDF5 inspection: h5dump (hdf5-tools) if present, else Debian's h5py.
h5tool=none
if command -v h5dump >/dev/null 2>&1; then
  h5tool=h5dump
elif /usr/bin/python3 -c 'import h5py' >/dev/null 2>&1; then
  h5tool=h5py
fi
# rows FILE DATASET: first dimension of a dataset
rows() {
  case $h5tool in
  h5dump) h5dump -H -d "$2" "$1" 2>/dev/null |
    sed -n 's/.*DATASPACE *SIMPLE *{ *( *\([0-9]*\).*/\1/p' | head -n 1 ;;
  h5py) /usr/bin/python3 -c 'import sys, h5py
print(h5py.File(sys.argv[1], "r")[sys.argv[2]].shape[0])' "$1" "$2" ;;
  esac
}
# cols FILE DATASET: second dimension
cols() {
  case $h5tool in
  h5dump) h5dump -H -d "$2" "$1" 2>/dev/null |
    sed -n 's/.*DATASPACE *SIMPLE *{ *( *[0-9]*, *\([0-9]*\).*/\1/p' | head -n 1 ;;
  h5py) /usr/bin/python3 -c 'import sys, h5py
print(h5py.File(sys.argv[1], "r")[sys.argv[2]].shape[1])' "$1" "$2" ;;
  esac
}
# root_attr FILE NAME: value of a string attribute of /
root_attr() {
  case $h5tool in
  h5dump) h5dump -a "/$2" "$1" 2>/dev/null | sed -n 's/.*(0): *"\(.*\)".*/\1/p' ;;
  h5py) /usr/bin/python3 -c 'import sys, h5py
v = h5py.File(sys.argv[1], "r").attrs[sys.argv[2]]
print(v.decode() if isinstance(v, bytes) else v)' "$1" "$2" ;;
  esac
}

# root_num FILE NAME: value of a numeric attribute of /
root_num() {
  case $h5tool in
  h5dump) h5dump -a "/$2" "$1" 2>/dev/null | sed -n 's/.*(0): *\([-+0-9.eEinfa]*\).*/\1/p' ;;
  h5py) /usr/bin/python3 -c 'import sys, h5py
print(repr(float(h5py.File(sys.argv[1], "r").attrs[sys.argv[2]])))' "$1" "$2" ;;
  esac
}
# num_in VALUE LOW HIGH: LOW <= VALUE <= HIGH
num_in() { awk -v v="$1" -v a="$2" -v b="$3" 'BEGIN { exit !(v != "" && v + 0 >= a && v + 0 <= b) }'; }

mkdir -p "$tmp/o"

# --- version and help ------------------------------------------------------
run_mrvi --version
expect_rc 0 "--version"
check "--version prints 'mrvi $version' (got '$out')" [ "$out" = "mrvi $version" ]

run_mrvi --help
expect_rc 0 "--help"
contains "$out" '^ +run FILE' "--help lists run"
contains "$out" '^ +check FILE' "--help lists check"
check "--help writes nothing to stderr" [ -z "$err" ]

run_mrvi help run
expect_rc 0 "help run"
contains "$out" '--set KEY=VALUE' "help run documents --set"
contains "$out" '130' "help run documents the interrupt status"
# Every option `run` accepts is in its help: the options of the parser's
# table run_options in cli.c and those the --controls replay accepts in
# cli_optimize.c (is_run branches), read from the source so that a new
# option without help fails here.
run_opts=$( (sed -n '/run_options\[\] = {/,/NULL};/p' "$root/src/cli/cli.c" |
  grep -o '"--[a-z-]*"'
  grep -o 'is_run && !strn*cmp(a, "--[a-z-]*' "$root/src/cli/cli_optimize.c" |
    grep -o '"--[a-z-]*') | tr -d '"' | sort -u)
check "run options found in the source ($(echo $run_opts))" \
  [ "$(echo "$run_opts" | wc -l)" -ge 8 ]
for o in $run_opts; do
  contains "$out" "(^|[ ,])$o( |=|\$)" "help run documents $o"
done

run_mrvi run --help
expect_rc 0 "run --help"
contains "$out" '^Usage: mrvi run FILE' "run --help shows run usage"

run_mrvi check -h
expect_rc 0 "check -h"
contains "$out" '^Usage: mrvi check FILE' "check -h shows check usage"

run_mrvi
expect_rc 1 "no arguments"
contains "$err" '^Usage: mrvi' "no arguments prints usage on stderr"

# --- usage errors ----------------------------------------------------------
run_mrvi rnu "$fpu"
expect_rc 1 "misspelt command"
contains "$err" "unknown command 'rnu'; did you mean 'run'\\?" "suggests run"
contains "$err" '^Usage: mrvi' "misspelt command prints usage"

run_mrvi --versoin
expect_rc 1 "misspelt global option"
contains "$err" "did you mean '--version'" "suggests --version"

run_mrvi run "$fpu" --quite -o "$tmp/o/x.h5"
expect_rc 1 "unknown option"
contains "$err" "unknown option '--quite'; did you mean '--quiet'" \
  "unknown option is named, closest suggested"
check "unknown option writes no output" no_h5_files

run_mrvi run
expect_rc 1 "run without FILE"
contains "$err" 'missing FILE' "run without FILE says so"
check "run without FILE: the usage lines, not the whole help ($(printf '%s\n' "$err" | wc -l) lines)" \
  [ "$(printf '%s\n' "$err" | wc -l)" -le 8 ]
contains "$err" 'mrvi help run' "run without FILE points at 'mrvi help run'"

# Every command, given no FILE or an unknown option: its usage lines and a
# pointer to `mrvi help CMD`, never the whole help text.
for cmd in check optimize converge stability timing export batch; do
  run_mrvi "$cmd"
  expect_rc 1 "$cmd without FILE"
  contains "$err" "^Usage: mrvi $cmd" "$cmd without FILE: its usage line"
  contains "$err" "mrvi help $cmd" "$cmd without FILE points at 'mrvi help $cmd'"
  check "$cmd without FILE: not the whole help ($(printf '%s\n' "$err" | wc -l) lines)" \
    [ "$(printf '%s\n' "$err" | wc -l)" -le 8 ]
  run_mrvi "$cmd" "$fpu" --no-such-option
  expect_rc 1 "$cmd with an unknown option"
  contains "$err" "no-such-option" "$cmd names the unknown option"
  contains "$err" "mrvi help $cmd" "$cmd unknown option points at 'mrvi help $cmd'"
  check "$cmd unknown option: not the whole help ($(printf '%s\n' "$err" | wc -l) lines)" \
    [ "$(printf '%s\n' "$err" | wc -l)" -le 8 ]
done
run_mrvi run "$fpu" --controls
expect_rc 1 "run --controls without a value"
contains "$err" "'--controls' needs a value" "run --controls without a value says so"

run_mrvi run "$fpu" --set integrator.micro_steps
expect_rc 1 "--set without '='"
contains "$err" 'KEY=VALUE' "--set without '=' explains the form"

run_mrvi run "$fpu" -o
expect_rc 1 "-o without value"

run_mrvi check "$fpu" "$fpu"
expect_rc 1 "two files"

not_contains_control() { ! grep -q '^control ' <<<"$out"; }

# --- check -----------------------------------------------------------------
run_mrvi check "$fpu"
expect_rc 0 "check fpu.yaml"
contains "$out" '^coordinates +6 \(3 slow, 3 fast\)$' "fpu: 6 coordinates, 3 slow, 3 fast"
contains "$out" '^slow +3: qs1, qs2, qs3$' "fpu: slow partition"
contains "$out" '^fast +3: qf1, qf2, qf3$' "fpu: fast partition"
contains "$out" '^particles +0$' "fpu: no particles"
contains "$out" '^elements +[1-9][0-9]*$' "fpu: elements counted"
contains "$out" '^ +slow \(V\) +alpha = [0-9.]+, gamma = [0-9.]+, (micro|macro) grid$' \
  "check prints the slow rule"
contains "$out" '^ +fast \(W\) +alpha = [0-9.]+, gamma = [0-9.]+, micro grid$' \
  "check prints the fast rule"
contains "$out" '^macro step +0.3$' "fpu: macro step 0.3"
contains "$out" '^newton +tolerance ' "check prints the Newton settings"
contains "$out" '^output +[^ ]+\.h5' "check prints the output file"
check "check writes no file" no_h5_files

run_mrvi check "$fpu" --set integrator.micro_steps=7 --set integrator.t_end=3 \
  --set integrator.scheme=trapezoidal-midpoint
expect_rc 0 "check with --set"
contains "$out" '^micro steps +7 ' "--set integrator.micro_steps=7 is applied"
contains "$out" '^t_end +3 \(10 macro steps' "--set t_end=3 gives N = 10 at dT = 0.3"
contains "$out" '^scheme +trapezoidal-midpoint$' "--set scheme is applied"
contains "$out" '^ +slow \(V\) +alpha = 1, gamma = 1, micro grid$' \
  "trapezoidal-midpoint: slow rule alpha = gamma = 1"
contains "$out" '^ +fast \(W\) +alpha = 0.5, gamma = 0.5, micro grid$' \
  "trapezoidal-midpoint: fast midpoint rule"

# A control: section is listed: actuators, terminal conditions, algorithm.
run_mrvi check "$root/systems/ocp_gantry_crane.yaml"
expect_rc 0 "check ocp_gantry_crane.yaml"
contains "$out" '^control +40 controls, 4 terminal constraints, slsqp$' \
  "check lists the control problem (40 controls, 4 terminal constraints)"
contains "$out" '^estimate +one cost \+ gradient: wall time [0-9.e+-]+ s \(measured' \
  "check measures one cost + gradient evaluation"
contains "$out" 'at most 2000 \(control.solver.max_evaluations\): wall time up to [0-9.e+-]+ s$' \
  "check bounds the optimisation's time by the evaluation cap"
contains "$out" '^ +0  cart_force \(on cart\.x; macro grid, 40 values\)$' \
  "check lists the actuator, its coordinate and grid"
contains "$out" '^ +3  velocity of load\.x = 0$' "check lists terminal velocities"
run_mrvi check "$root/systems/ocp_gantry_crane.yaml" --set control.solver.algorithm=auglag-mma
contains "$out" '^control +40 controls, 4 terminal constraints, auglag-mma$' \
  "check shows the --set algorithm"
run_mrvi check "$fpu"
check "no control section, no control lines" not_contains_control

for sys in spring_ring oscillator; do
  run_mrvi check "$root/systems/$sys.yaml"
  expect_rc 0 "check $sys.yaml"
done
run_mrvi check "$root/systems/spring_ring.yaml"
contains "$out" '^coordinates +18 \(9 slow, 9 fast\)$' "spring ring: 18 coordinates, 9 slow, 9 fast"
contains "$out" '^particles +6 in 3-D$' "spring ring: 6 particles in 3-D"
contains "$out" '^slow +9: m1\.x, m1\.y, m1\.z, m3\.x' "spring ring: odd masses slow"
contains "$out" '^  m2\.y +2 +-1\.2 +11\.4771$' "spring ring: mass, position, velocity of m2.y"

# --- generators: counts in the notes, masses and initial velocities --------
run_mrvi check "$root/systems/lattice.yaml"
expect_rc 0 "check lattice.yaml"
contains "$out" "^note: generate\.0: lattice2d 'p' generated 30 particles \(15 slow, 15 fast\), 49 springs \(37 slow, 12 fast\)$" \
  "lattice: generated counts"
contains "$out" '^  p2_2\.y +1 +2\.05 +0\.5$' "lattice: mass, position, velocity of p2_2.y"

# --- constraints: check lists them with their nodes, settings, notes -------
for sys in cart_pendulum spring_ring_rod triatomic pendulum_chain; do
  run_mrvi check "$root/systems/$sys.yaml"
  expect_rc 0 "check $sys.yaml"
  contains "$out" '^constraints +[0-9]+ \([0-9]+ equations?\)$' "$sys: constraints counted"
done
cart=$root/systems/cart_pendulum.yaml
run_mrvi check "$cart"
contains "$out" '^constraints +2 \(2 equations\)$' "cart pendulum: 2 constraints"
contains "$out" '^ +0 +floor \(plane; 1 row; .*\) at macro nodes$' \
  "slow-only plane enforced at macro nodes"
contains "$out" '^ +1 +rod \(distance; 1 row; parameters 0\.2\) at every micro node$' \
  "slow-fast rod enforced at every micro node"
contains "$out" '^constraints +multipliers form, tolerance 1e-10, momentum projection on$' \
  "constraint settings printed"
check "cart pendulum: no note (velocities already tangent)" \
  test -z "$(printf '%s\n' "$out" | grep 'note:')"
run_mrvi check "$cart" --set integrator.constraints.form=null-space \
  --set integrator.constraints.tolerance=1e-12 \
  --set integrator.constraints.projection=false
expect_rc 0 "check with constraint settings overridden"
contains "$out" '^constraints +null-space form, tolerance 1e-12, momentum projection off$' \
  "--set integrator.constraints.* applied"
# The null space a model gets: analytic for free bodies (2-D and fast too),
# joint-reduced for open chains and trees of joints (fast ones at the micro
# nodes) and, with cut joints, closed loops of slow bodies; numerical for a
# fast body on a slow one by a weld or nullspace_tree 0.
cat >"$tmp/wheel.yaml" <<'EOF'
name: wheel
dimension: 2
bodies:
  - {name: w, mass: 1, inertia: 0.5, position: [0, 0], angular_velocity: 2, rate: fast}
integrator: {macro_step: 0.01, micro_steps: 2, t_end: 0.02, constraints: {form: null-space}}
EOF
run_mrvi check "$tmp/wheel.yaml"
contains "$out" '^  null space  analytic \(free planar rigid bodies: P = \[\[I, 0\], \[0, J d1\], \[0, J d2\]\]\)' \
  "free fast 2-D body: analytic null space"
run_mrvi check "$root/systems/rigid_pendulum.yaml" \
  --set integrator.constraints.form=null-space
contains "$out" '^  null space  joint-reduced \(open chains and trees of joints' \
  "a body on a joint: joint-reduced null space"
run_mrvi check "$root/systems/rigid_pendulum.yaml" \
  --set integrator.constraints.form=null-space \
  --set integrator.tuning.nullspace_tree=0
contains "$out" '^  null space  numerical \(QR.*; not joint-reduced: nullspace_tree 0$' \
  "nullspace_tree 0: numerical null space"
run_mrvi check "$root/systems/slider_crank.yaml" \
  --set integrator.constraints.form=null-space
contains "$out" "^  null space  joint-reduced with cut joints \\(closed loops, cut at 'guide': .*; 0 redundant rows left out; .*Newton tolerance$" \
  "slider-crank: joint-reduced null space, the joint closing the loop cut"
run_mrvi check "$root/systems/slider_crank.yaml" \
  --set integrator.constraints.form=null-space \
  --set integrator.tuning.nullspace_tree=0
contains "$out" '^  null space  numerical \(QR.*; 0 redundant rows left out; not joint-reduced: nullspace_tree 0$' \
  "slider-crank, nullspace_tree 0: numerical null space"
run_mrvi check "$root/tests/fast_fourbar.yaml"
contains "$out" "^  null space  joint-reduced at the micro nodes with cut joints \\(closed loops of fast bodies, cut at 'rocker_pivot': .*; 3 redundant rows left out; .*the cut joints held to the Newton tolerance; no slow bodies$" \
  "fast four-bar in 3-D (no slow body, a slow particle): cut at the rocker's pivot, redundant rows left out"
run_mrvi check "$root/tests/fast_fourbar.yaml" \
  --set integrator.tuning.nullspace_tree=0
contains "$out" "^  null space  numerical \\(QR.*; 3 redundant rows left out \\(3 of them enforced at the micro nodes: a closed loop of fast bodies, left out of the QR at every micro node\\); not joint-reduced: nullspace_tree 0$" \
  "fast four-bar in 3-D, nullspace_tree 0: redundant micro-node rows left out of the QR"
cat >"$tmp/cart_pole.yaml" <<'EOF'
name: cart-pole
dimension: 2
gravity: [0, -9.81]
bodies:
  - {name: cart, mass: 2, inertia: 0.1, position: [0, 0]}
  - {name: pole, mass: 1, inertia: 0.08, position: [0.5, 0], angular_velocity: 1}
joints:
  - {type: prismatic, name: rail, bodies: [cart], point: [0, 0], axis: [1, 0]}
  - {type: revolute, name: pivot, bodies: [pole, cart], point: [0, 0]}
integrator: {macro_step: 0.01, micro_steps: 1, t_end: 0.02, constraints: {form: null-space}}
EOF
run_mrvi check "$tmp/cart_pole.yaml"
contains "$out" "^  null space  joint-reduced \\(open chains and trees of joints.*joint's free turns and slides$" \
  "a pole on a cart on a rail: joint-reduced null space"
sed 's/^integrator/constraints:\n  - {type: distance, name: tether, between: [{body: pole, at: [0.5, 0]}], anchor: [1, 1], length: 1}\nintegrator/' \
  "$tmp/cart_pole.yaml" >"$tmp/cart_tether.yaml"
run_mrvi check "$tmp/cart_tether.yaml"
contains "$out" "^  null space  numerical \\(QR.*; not joint-reduced: constraint 'tether' \\(point\\) has no joint reduction$" \
  "a tethered pole: numerical null space, the tether named"
run_mrvi check "$root/systems/pendulum_chain.yaml" \
  --set integrator.constraints.form=null-space
contains "$out" '^  null space  link-local \(open chains and trees of slow particles on rods: P = \(I - X\)\^-1 S' \
  "a chain of particles on rods: link-local null space"
run_mrvi check "$root/systems/pendulum_chain.yaml" \
  --set integrator.constraints.form=null-space \
  --set integrator.tuning.nullspace_tree=0
contains "$out" '^  null space  numerical \(QR.*; not link-local: nullspace_tree 0$' \
  "a chain of particles on rods, nullspace_tree 0: numerical null space"
run_mrvi check "$root/systems/flexible_pendulum.yaml" \
  --set integrator.constraints.form=null-space
contains "$out" "^  null space  joint-reduced at the micro nodes \\(fast bodies in open chains and trees of joints.*; slow bodies: numerical \\(QR at q_k\\), reparametrised on their joints$" \
  "flexible pendulum: fast joint-reduced null space, the arm's numerical"
run_mrvi check "$root/systems/spacecraft.yaml" \
  --set integrator.constraints.form=null-space
contains "$out" "^  null space  joint-reduced at the micro nodes .*; slow bodies: analytic \\(free rigid bodies\\), reparametrised$" \
  "spacecraft: fast joint-reduced null space, the hub's analytic"
cat >"$tmp/arm_link.yaml" <<'EOF'
name: arm-link
dimension: 2
gravity: [0, -9.81]
bodies:
  - {name: arm, mass: 5, inertia: 0.4, position: [0.5, 0]}
  - {name: link, mass: 0.1, inertia: 0.002, position: [1.25, 0], rate: fast}
joints:
  - {type: revolute, name: shoulder, bodies: [arm], point: [0, 0]}
  - {type: revolute, name: elbow, bodies: [arm, link], point: [1, 0]}
integrator: {macro_step: 0.01, micro_steps: 4, t_end: 0.02, constraints: {form: null-space}}
EOF
run_mrvi check "$tmp/arm_link.yaml"
contains "$out" "^  null space  joint-reduced at the micro nodes " \
  "a fast link on a slow arm: fast joint-reduced null space"
sed 's/type: revolute, name: elbow/type: weld, name: elbow/' \
  "$tmp/arm_link.yaml" >"$tmp/arm_weld.yaml"
run_mrvi check "$tmp/arm_weld.yaml"
contains "$out" "^  null space  numerical \\(QR.*; not joint-reduced: joint 'elbow' \\(weld\\) joins a fast body to a slow one: a moving root is spherical or revolute$" \
  "a fast body welded to a slow one: numerical null space, the joint named"
sed 's/^joints:/joints:\n  - {type: revolute, name: pin, bodies: [link], point: [1.5, 0]}/' \
  "$tmp/arm_link.yaml" >"$tmp/arm_loop.yaml"
run_mrvi check "$tmp/arm_loop.yaml"
contains "$out" "^  null space  joint-reduced at the micro nodes with cut joints \\(closed loops of fast bodies, cut at 'elbow': " \
  "a fast link pinned to the ground and to a slow arm: the elbow cut"
run_mrvi check "$fpu"
contains "$out" '^constraints +0$' "fpu: no constraints"
check "fpu: no constraint settings line" \
  test -z "$(printf '%s\n' "$out" | grep -E '^constraints +(multipliers|null-space)')"

rod=$root/systems/spring_ring_rod.yaml
run_mrvi check "$rod"
contains "$out" '^ +0 +distance m1-m2 \(distance; .*\) at every micro node$' \
  "spring ring rod: default label, micro nodes"
contains "$out" "^note: initial velocities projected onto the constraints' tangent space \(largest change [0-9.]+e[-+][0-9]+\)\$" \
  "check prints the projection note"
run_mrvi run "$rod" --set integrator.t_end=0.02 -o "$tmp/o/rod.h5" -q
contains "$err" "spring_ring_rod\.yaml: note: initial velocities projected" \
  "run prints the projection note on stderr"
check "run: no note on stdout" test -z "$(printf '%s\n' "$out" | grep 'note:')"
rm -f "$tmp/o/rod.h5"

# Inconsistent initial positions: reported at the constraint's entry.
line=$(grep -n 'name: rod' "$cart" | cut -d: -f1)
run_mrvi check "$cart" --set constraints.1.length=0.3
expect_rc 1 "rod length that the initial positions violate"
contains "$err" "cart_pendulum\.yaml:$line:[0-9]+: initial positions violate constraint 'rod': \|g\| = " \
  "inconsistent rod: file:line:col of the entry, constraint named"

run_mrvi check "$tmp/does-not-exist.yaml"
expect_rc 1 "check of a missing file"
contains "$err" 'does-not-exist\.yaml' "missing file is named"

# --- run -------------------------------------------------------------------
x=$tmp/o/x.h5
run_mrvi run "$fpu" --set integrator.t_end=3 -o "$x" --quiet
expect_rc 0 "run --quiet"
check "run creates the output file" [ -s "$x" ]
check "--quiet prints nothing on stdout (got '$out')" [ -z "$out" ]
# The output follows the umask, like the .xdmf beside it (not mkstemp's 0600).
for mask in 022 077; do
  (umask $mask && "$mrvi" run "$fpu" --set integrator.t_end=0.6 -o "$tmp/m$mask.h5" -q)
  m=$(stat -c %a "$tmp/m$mask.h5" 2>/dev/null)
  want=$(printf '%o' $((0666 & ~0$mask)))
  check "umask $mask: output mode $want (got '$m')" \
    [ "$m" = "$want" ]
done
check "--quiet prints nothing on stderr (got '$err')" [ -z "$err" ]
if [ "$h5tool" = none ]; then
  printf 'note: neither h5dump nor h5py found; HDF5 contents not inspected\n' >&2
else
  r=$(rows "$x" /macro/t)
  check "/macro/t has N+1 = 11 rows for t_end 3, dT 0.3 (got '$r')" [ "$r" = 11 ]
  r=$(rows "$x" /macro/q)
  c=$(cols "$x" /macro/q)
  check "/macro/q is 11 x 6 (got '$r x $c')" [ "$r x $c" = "11 x 6" ]
  a=$(root_attr "$x" stop_reason)
  check "stop_reason is 'completed' (got '$a')" [ "$a" = completed ]
  a=$(root_attr "$x" mrvi_version)
  check "mrvi_version attribute is $version (got '$a')" [ "$a" = "$version" ]
fi

# Summary on stdout without --quiet; --output= form; options before FILE.
y=$tmp/o/y.h5
run_mrvi run --set=integrator.t_end=3 --output="$y" "$fpu"
expect_rc 0 "run with summary"
check "run (--output=) creates the file" [ -s "$y" ]
contains "$out" 'completed 10 of 10 macro steps' "summary: macro steps"
contains "$out" 'Newton iterations +[0-9]+ total, max [0-9]+ per step' "summary: Newton iterations"
contains "$out" 'max rel\. energy error +[0-9.]+e[-+][0-9]+' "summary: energy error"
contains "$out" 'wall time +[0-9.]+ s \(assemble [0-9.]+ s, solve [0-9.]+ s\)$' \
  "summary: wall time, 10 steps: assembly and solve measured (no estimate)"
contains "$out" "output +$y\$" "summary: output file"
check "no progress bar when stderr is not a terminal (got '$err')" [ -z "$err" ]
# Assembly and solve never above the wall time: cart_pendulum's costly
# first step, scaled to every step, once made the solve time 14 times the
# wall time.  (Measured or estimated, depending on the machine's speed.)
run_mrvi run "$root/systems/cart_pendulum.yaml" -o "$tmp/o/cp.h5" --set output.xdmf=false
line=$(printf '%s\n' "$out" | grep 'wall time')
read -r w a s < <(printf '%s\n' "$line" |
  sed -n 's/.*wall time *\([0-9.]*\) s (assemble ≈*\([0-9.]*\) s, solve ≈*\([0-9.]*\) s.*/\1 \2 \3/p')
# (printed to 1 ms: each rounded by at most 0.0005)
check "summary: assemble + solve <= wall time ($line)" \
  awk -v w="${w:-}" -v a="${a:-}" -v s="${s:-}" 'BEGIN { exit !(w != "" && a + s <= w + 0.001) }'
# 1000 explicit FPU steps of a few microseconds (also under ASan): timed
# on one step in 64, said so.
run_mrvi run "$fpu" -o "$tmp/o/fpu-long.h5" --set integrator.scheme=fully-explicit \
  --set integrator.micro_steps=1 --set integrator.macro_step=0.01 --set integrator.t_end=10
contains "$out" 'wall time +[0-9.]+ s \(assemble ≈[0-9.]+ s, solve ≈[0-9.]+ s: partly estimated from sampled steps\)$' \
  "summary: an estimate says so"

# Default output name from the description, written to the working directory.
run_mrvi run "$fpu" --set integrator.t_end=0.6 --set output.file=named.h5 -q
expect_rc 0 "run with output.file override"
check "output.file is used without -o" [ -s "$tmp/named.h5" ]
rm -f "$tmp/named.h5"

# The description file is never overwritten by the output.
cp "$fpu" "$tmp/o/copy.yaml"
run_mrvi run "$tmp/o/copy.yaml" --set integrator.t_end=0.6 -o "$tmp/o/copy.yaml" -q
expect_rc 1 "output onto the description file"
check "description file left intact" cmp -s "$fpu" "$tmp/o/copy.yaml"
rm -f "$tmp/o/copy.yaml"

# --- bad input: exit 1, file:line:col message, no output ---------------------
rm -f "$tmp"/o/*.h5
# An override's value is not in the file: the loader points at the --set
# argument (or at the key's line in the file).
run_mrvi run "$fpu" --set integrator.micro_steps=0 -o "$tmp/o/bad.h5"
expect_rc 1 "--set micro_steps=0"
contains "$err" '^(.*fpu\.yaml:[0-9]+:[0-9]+|--set integrator\.micro_steps=0): .*micro_steps' \
  "--set micro_steps=0: located message naming the key"
check "--set micro_steps=0 writes no output" no_h5_files
check "--set micro_steps=0 prints no summary" [ -z "$out" ]

# The same error inside a file: file:line:col of the value.
bad=$tmp/o/p0.yaml
sed 's/^\( *micro_steps: *\)[0-9][0-9]*/\10/' "$fpu" >"$bad"
line=$(grep -n '^ *micro_steps: *0' "$bad" | cut -d: -f1)
check "test set-up: micro_steps: 0 written into a copy of fpu.yaml" [ -n "$line" ]
run_mrvi run "$bad" -o "$tmp/o/bad.h5"
expect_rc 1 "micro_steps: 0 in the file"
contains "$err" "^$bad:$line:[0-9]+: .*micro_steps" \
  "micro_steps: 0: file:line:col message at line $line"
check "micro_steps: 0 writes no output" no_h5_files
run_mrvi check "$bad"
expect_rc 1 "check of micro_steps: 0"
contains "$err" "^$bad:$line:[0-9]+: " "check reports file:line:col"
rm -f "$bad"

run_mrvi run "$fpu" --set integrator.micro_stepz=3 -o "$tmp/o/bad.h5"
expect_rc 1 "misspelt --set key"
check "misspelt --set key writes no output" no_h5_files

# Hostile input stops at once with a message (issue 11): endless devices,
# libfyaml's directive-scanner hang ("%\xff") through a --set value.
for dev in /dev/zero /dev/urandom; do
  run_mrvi check "$dev"
  expect_rc 1 "$dev as description"
  # (a random first line may end in a newline byte: any line number)
  contains "$err" "^$dev:[0-9]+:[0-9]+: (NUL byte|invalid byte|control character)" \
    "$dev refused as not text"
done
run_mrvi run "$fpu" --set "integrator.micro_steps=$(printf '%%\377')" \
  -o "$tmp/o/bad.h5"
expect_rc 1 "--set value that is not UTF-8"
contains "$err" "^--set integrator\.micro_steps=" "--set value that is not UTF-8 is named"
contains "$err" "invalid byte 0xff: not UTF-8 text" "--set value that is not UTF-8: message"

run_mrvi run "$tmp/nope.yaml" -o "$tmp/o/bad.h5"
expect_rc 1 "nonexistent file"
contains "$err" 'nope\.yaml' "nonexistent file is named"
check "nonexistent file writes no output" no_h5_files

printf 'name: broken\ncoordinates: [\n' >"$tmp/o/broken.yaml"
run_mrvi run "$tmp/o/broken.yaml" -o "$tmp/o/bad.h5"
expect_rc 1 "YAML syntax error"
contains "$err" 'broken\.yaml:[0-9]+:[0-9]+: ' "YAML syntax error: file:line:col"
check "YAML syntax error writes no output" no_h5_files
rm -f "$tmp/o/broken.yaml"

run_mrvi run "$fpu" -o "$tmp/no/such/dir/x.h5"
expect_rc 1 "output in a missing directory"
check "unwritable output: message on stderr" [ -n "$err" ]

# --- run failure: exit 2, the file records why -------------------------------
# A tolerance below round-off cannot be met: Newton fails in the first step.
f=$tmp/o/newton.h5
run_mrvi run "$fpu" --set integrator.newton.tolerance=1e-300 \
  --set integrator.newton.max_iterations=3 -o "$f"
expect_rc 2 "Newton failure"
contains "$err" '^mrvi run: error: .*[Nn]ewton' "Newton failure reported on stderr"
contains "$out" 'stopped after 0 of 667 macro steps' "summary of a failed run"
check "the reason is printed once (stderr), not again in the summary" \
  test "$(cat "$tmp/out" "$tmp/err" | grep -c 'did not converge')" -eq 1
check "failed run leaves its file" [ -s "$f" ]
if [ "$h5tool" != none ]; then
  a=$(root_attr "$f" stop_reason)
  contains "$a" '[Nn]ewton' "stop_reason of a failed run names Newton"
  r=$(rows "$f" /macro/t)
  check "failed run: file holds the initial node only (got '$r' rows)" [ "$r" = 1 ]
fi
rm -f "$f"

# --- energy error: warning above integrator.energy_warning -------------------
# explicit-slow at the FPU's dT = 0.3, p = 10 completes with an energy error
# of 567 % (paper-scale wrong answer): exit 0, one warning, attributes.
f=$tmp/o/es.h5
run_mrvi run "$fpu" --set integrator.scheme=explicit-slow -o "$f"
expect_rc 0 "explicit-slow dT = 0.3 completes"
contains "$out" 'completed 667 of 667' "explicit-slow: completed"
contains "$err" '^mrvi run: warning: relative energy error [0-9.]+ exceeds integrator\.energy_warning = 0\.1: .*reduce macro_step$' \
  "energy warning on stderr"
check "energy warning printed once" test "$(grep -c 'energy_warning' "$tmp/err")" -eq 1
s_err=$(sed -n 's/^ *max rel\. energy error *//p' "$tmp/out")
check "summary: energy error $s_err > 1" num_in "$s_err" 1 100
run_mrvi run "$fpu" --set integrator.scheme=explicit-slow -o "$f" -q
contains "$err" '^mrvi run: warning: relative energy error' "energy warning also with --quiet"
if [ "$h5tool" != none ]; then
  a=$(root_attr "$f" warning)
  contains "$a" '^relative energy error [0-9.]+ exceeds integrator\.energy_warning = 0\.1' "attribute warning"
  v=$(root_num "$f" energy_error_max)
  check "attribute energy_error_max $v = summary $s_err (4 digits)" \
    awk -v a="$v" -v b="$s_err" 'BEGIN { exit !(a - b < 1e-3 * b && b - a < 1e-3 * b) }'
  check "attribute energy_scale_kind initial" test "$(root_attr "$f" energy_scale_kind)" = initial
  v=$(root_num "$f" energy_scale)
  check "attribute energy_scale = H_0 = 2.0012 (got $v)" num_in "$v" 2.00119 2.00121
  check "attribute energy_warning 0.1" num_in "$(root_num "$f" energy_warning)" 0.1 0.1
fi
# The threshold from --set: no warning, the attributes say so.
run_mrvi run "$fpu" --set integrator.scheme=explicit-slow --set integrator.energy_warning=10 -o "$f" -q
expect_rc 0 "energy_warning = 10"
check "energy_warning = 10: no warning (stderr: $err)" test -z "$err"
if [ "$h5tool" != none ]; then
  check "energy_warning = 10: attribute warning empty" test -z "$(root_attr "$f" warning)"
  check "energy_warning = 10: attribute" num_in "$(root_num "$f" energy_warning)" 10 10
fi
run_mrvi check "$fpu" --set integrator.energy_warning=-1
expect_rc 1 "negative energy_warning"
contains "$err" 'energy_warning must be >= 0' "negative energy_warning refused"
# midpoint-midpoint at the same step: no warning.
run_mrvi run "$fpu" --set integrator.t_end=20 -o "$f" -q
check "midpoint-midpoint: no warning (stderr: $err)" test -z "$err"
# H_0 = 0: a unit mass falling from rest under a unit force; the error is
# relative to the largest T + |V| of the run (= t_end^2 = 1), and says so.
printf 'name: fall\ncoordinates: [{name: x, mass: 1, position: 0, velocity: 0}]\nforces: [{coordinate: x, force: 1}]\nintegrator: {macro_step: 0.1, t_end: 1}\n' >"$tmp/fall.yaml"
run_mrvi run "$tmp/fall.yaml" -o "$tmp/o/fall.h5"
expect_rc 0 "H_0 = 0 run"
contains "$out" 'max energy error +[0-9.e+-]+ \(H0 = 0: relative to the largest energy magnitude of the run, 1\.000e\+00\)' \
  "H_0 = 0: the summary says what the error is relative to"
if [ "$h5tool" != none ]; then
  check "H_0 = 0: attribute energy_scale_kind run" test "$(root_attr "$tmp/o/fall.h5" energy_scale_kind)" = run
  check "H_0 = 0: attribute energy_scale 1" num_in "$(root_num "$tmp/o/fall.h5" energy_scale)" 0.999999999 1.000000001
fi
printf 'name: rest\ncoordinates: [{name: x, mass: 1, position: 0}]\nintegrator: {macro_step: 0.1, t_end: 1}\n' >"$tmp/rest.yaml"
run_mrvi run "$tmp/rest.yaml" -o "$tmp/o/rest.h5"
contains "$out" 'max abs\. energy error +0\.000e\+00 \(absolute: every energy is 0\)' "every energy 0: absolute"
# Instability: the pendulum chain fully explicit; Newton fails after the
# energy grew, the message says so once.
f=$tmp/o/chain.h5
run_mrvi run "$root/systems/pendulum_chain.yaml" --set integrator.scheme=fully-explicit -o "$f"
expect_rc 2 "unstable pendulum chain"
contains "$err" '^mrvi run: error: step 40 .*Newton did not converge.*; energy grew from -42\.7589 to [0-9.e+]+ by t = 0\.39 .*the macro step 0\.01 is probably beyond the stability limit of this scheme; reduce macro_step$' \
  "instability hint on stderr"
check "instability: one message in all (stdout + stderr)" \
  test "$(cat "$tmp/out" "$tmp/err" | grep -c 'Newton did not converge')" -eq 1
check "instability: no separate energy warning" test "$(grep -c 'warning' "$tmp/err")" -eq 0
if [ "$h5tool" != none ]; then
  contains "$(root_attr "$f" stop_reason)" 'stability limit of this scheme' "instability hint in stop_reason"
fi

# --- non-finite states: exit 2, never "completed", finite rows kept -----------
osc=$root/systems/oscillator.yaml
f=$tmp/o/nonfinite.h5
run_mrvi run "$osc" --set coordinates.0.position=1e200 -o "$f" -q
expect_rc 2 "position 1e200 (infinite energy)"
contains "$err" 'non-finite state at macro node 0 .*potential = inf' \
  "position 1e200: the non-finite energy is named"
if [ "$h5tool" != none ]; then
  a=$(root_attr "$f" stop_reason)
  contains "$a" '^non-finite state' "position 1e200: stop_reason says why"
fi
run_mrvi run "$osc" --set coordinates.0.mass=1e308 \
  --set coordinates.0.velocity=10 -o "$f" -q
expect_rc 2 "mass 1e308 (infinite momentum)"
contains "$err" 'non-finite state at macro node 0 .*p\[0\] = inf' \
  "mass 1e308: the non-finite momentum is named"
# An unstable explicit-like run (trapezoidal, omega dT = 4 > sqrt(6)) grows
# until the energy overflows at node 135; nodes 0..134 are finite and kept.
run_mrvi run "$osc" --set integrator.scheme=trapezoidal-trapezoidal \
  --set integrator.macro_step=4 --set integrator.micro_steps=1 \
  --set integrator.t_end=4000 -o "$f" -q
expect_rc 2 "unstable run"
contains "$err" 'non-finite state at macro node 135 ' "unstable run: node named"
if [ "$h5tool" != none ]; then
  a=$(root_attr "$f" stop_reason)
  check "unstable run: not completed (got '$a')" test "$a" != completed
  r=$(rows "$f" /macro/energy)
  check "unstable run: the 135 finite nodes are kept (got '$r')" [ "$r" = 135 ]
  if [ "$h5tool" = h5py ] || /usr/bin/python3 -c 'import h5py' 2>/dev/null; then
    check "unstable run: every stored energy is finite" /usr/bin/python3 -c '
import sys, h5py, numpy as np
e = h5py.File(sys.argv[1], "r")["/macro/energy"][:]
sys.exit(0 if np.all(np.isfinite(e)) else 1)' "$f"
  fi
fi
rm -f "$f"

# --- existing files: a live run's file, foreign files, names ------------------
# A second run refuses the file a live run holds, and leaves it intact.
f=$tmp/o/live.h5
"$mrvi" run "$fpu" --set integrator.t_end=1e7 -o "$f" -q 2>/dev/null &
pid=$!
i=0
while [ ! -s "$f" ] && [ $i -lt 100 ]; do sleep 0.1; i=$((i + 1)); done
sleep 0.3
run_mrvi run "$fpu" -o "$f" -q
expect_rc 1 "second run on a live run's file"
contains "$err" 'in use by another run' "second run: the lock is named"
kill -INT "$pid"
wait "$pid"
check "first run ends normally after the refused second run (got $?)" true
if [ "$h5tool" != none ]; then
  a=$(root_attr "$f" stop_reason)
  contains "$a" 'interrupted' "the live run's file survives a second writer"
fi
rm -f "$f"
# A file that is not an mrvi output is not replaced without --force.
f=$tmp/o/foreign.h5
printf 'precious data\n' >"$f"
run_mrvi run "$root/systems/oscillator.yaml" -o "$f" -q
expect_rc 1 "non-HDF5 file as output"
contains "$err" 'not an mrvi output file.*--force' "non-HDF5 file: refusal names --force"
check "non-HDF5 file left as it was" [ "$(cat "$f")" = "precious data" ]
run_mrvi run "$root/systems/oscillator.yaml" -o "$f" -q --force
expect_rc 0 "--force replaces a non-mrvi file"
if /usr/bin/python3 -c 'import h5py' 2>/dev/null; then
  /usr/bin/python3 -c 'import sys, h5py
h5py.File(sys.argv[1], "w")["x"] = [1.0]' "$f"
  run_mrvi run "$root/systems/oscillator.yaml" -o "$f" -q
  expect_rc 1 "HDF5 file without mrvi's marker as output"
  contains "$err" 'not an mrvi output' "foreign HDF5 file refused"
fi
# An earlier mrvi output is replaced (that is how reruns work).
run_mrvi run "$root/systems/oscillator.yaml" -o "$tmp/o/again.h5" -q
run_mrvi run "$root/systems/oscillator.yaml" -o "$tmp/o/again.h5" -q
expect_rc 0 "an earlier mrvi output is replaced"
rm -f "$tmp/o/foreign.h5" "$tmp/o/again.h5"
# name: gives the default output name; it must not leave the directory.
mkdir -p "$tmp/o/nm"
run_in_nm() { # mrvi run $tmp/named.yaml in $tmp/o/nm: rc, err
  (cd "$tmp/o/nm" && "$mrvi" run "$tmp/named.yaml" -q >"$tmp/out" 2>"$tmp/err")
  rc=$?
  err=$(cat "$tmp/err")
}
sed '/^output:/d' "$root/systems/oscillator.yaml" >"$tmp/noout.yaml"
for bad in '../../escape' 'a/b' '"two\\nlines"'; do
  sed "s|^name:.*|name: $bad|" "$tmp/noout.yaml" >"$tmp/named.yaml"
  run_in_nm
  expect_rc 1 "name '$bad' as output name"
  contains "$err" 'leaves the current directory or contains control' "name '$bad' refused"
done
check "bad names wrote nothing" [ -z "$(ls -A "$tmp/o/nm")" ] && \
  ! ls "$tmp"/escape.h5 "$tmp"/o/escape.h5 >/dev/null 2>&1
# output.file from a description is confined the same way: not absolute, no
# "..", and an earlier mrvi output there is not replaced.
"$mrvi" run "$root/systems/oscillator.yaml" -o "$tmp/o/earlier.h5" -q
cp "$tmp/o/earlier.h5" "$tmp/o/earlier.copy"
for bad in '../../o/earlier.h5' "$tmp/o/earlier.h5" 'sub/../../earlier.h5'; do
  sed "s|^output:.*|output: {file: '$bad'}|" "$root/systems/oscillator.yaml" \
    >"$tmp/named.yaml"
  run_in_nm
  expect_rc 1 "output.file '$bad'"
  contains "$err" 'is absolute, leaves the current directory' "output.file '$bad' refused"
done
check "an earlier output outside the directory is untouched" \
  cmp -s "$tmp/o/earlier.h5" "$tmp/o/earlier.copy"
sed "s|^output:.*|output: {file: 'sub/x.h5'}|" "$root/systems/oscillator.yaml" \
  >"$tmp/named.yaml"
mkdir -p "$tmp/o/nm/sub"
run_in_nm
expect_rc 0 "output.file 'sub/x.h5' (below the directory) is written"
rm -rf "$tmp/o/nm" "$tmp/o/earlier.h5" "$tmp/o/earlier.copy"

# --- paths: symbolic links, long names (issue 26, class 8) ----------------------
# A dangling symbolic link as -o: refused, its target not created.
ln -s "$tmp/o/nowhere/target.h5" "$tmp/o/dangling.h5"
ln -s "$tmp/o/target.h5" "$tmp/o/dangling2.h5"
for link in dangling dangling2; do
  run_mrvi run "$root/systems/oscillator.yaml" -o "$tmp/o/$link.h5" -q
  expect_rc 1 "-o a dangling symbolic link ($link)"
  contains "$err" 'symbolic link to a missing file' "$link: refusal names the link"
done
check "a dangling link's target is not created" [ ! -e "$tmp/o/target.h5" ]
check "the dangling links stay links" [ -L "$tmp/o/dangling2.h5" ]
rm -f "$tmp/o/dangling.h5" "$tmp/o/dangling2.h5"
# A 254-byte file name is written: its temporary name is cut so that it
# stays within NAME_MAX = 255 with ".partXXXXXX".
long=$(printf 'L%.0s' $(seq 251)).h5
run_mrvi run "$root/systems/oscillator.yaml" -o "$tmp/o/$long" -q
expect_rc 0 "a 254-byte output file name ($err)"
check "the 254-byte file exists, no temporary file left" \
  [ -s "$tmp/o/$long" ] && [ -z "$(ls "$tmp/o" | grep -F '.part')" ]
rm -f "$tmp/o/$long"
# A --from path longer than PATH_MAX is refused, not cut.
deep=$(printf 'd/%.0s' $(seq 2100))x.h5
run_mrvi run "$root/systems/oscillator.yaml" --from "$deep" -o "$tmp/o/x.h5" -q
expect_rc 1 "--from a path of ${#deep} bytes"
contains "$err" "a path of ${#deep} bytes, longer than" "--from: a long path refused"

# --- interrupt: valid file with stop_reason, exit 128 + signal ----------------
interrupt() { # interrupt SIGNAL WANT_RC
  local f=$tmp/o/int-$1.h5 i=0
  "$mrvi" run "$fpu" --set integrator.t_end=1e7 -o "$f" -q \
    >"$tmp/out" 2>"$tmp/err" </dev/null &
  local pid=$!
  # Wait until the file exists and some steps have run.
  while [ ! -s "$f" ] && [ $i -lt 100 ]; do
    sleep 0.1
    i=$((i + 1))
  done
  sleep 0.5
  kill -s "$1" "$pid"
  wait "$pid"
  rc=$?
  err=$(cat "$tmp/err")
  expect_rc "$2" "SIG$1"
  contains "$err" "^mrvi run: SIG$1: .*interrupted" "SIG$1: reported on stderr"
  if [ "$h5tool" != none ]; then
    local a r
    a=$(root_attr "$f" stop_reason)
    check "SIG$1: stop_reason is set and not 'completed' (got '$a')" \
      test -n "$a" -a "$a" != completed
    r=$(rows "$f" /macro/t)
    check "SIG$1: file holds the completed steps (got '$r' rows)" \
      test "${r:-0}" -ge 1
  fi
}
interrupt INT 130
interrupt TERM 143

# --- large networks: the iterative solver paths (doc/solver.md) -------------
# A 12 x 8 lattice from a generator (96 slow and 96 fast coordinates, beyond
# the dense limit 64): check names the path and why, run prints the
# iterations, the file records the path.
cat >"$tmp/net.yaml" <<'EOF_NET'
name: net
dimension: 2
generate:
  - {kind: lattice2d, name: p, count: [12, 8], mass: 1, rates: {every: 2},
     slow_spring: {law: linear, stiffness: 1},
     fast_spring: {law: linear, stiffness: 2500},
     initial: [{index: [3, 3], displacement: [0.1, 0.05], velocity: [0, 0.5]}]}
integrator: {scheme: explicit-slow, macro_step: 0.01, micro_steps: 10, t_end: 0.1}
EOF_NET
run_mrvi check "$tmp/net.yaml"
contains "$out" "^solver +sweep-cg: .*CG" "lattice explicit-slow: check names sweep-cg"
run_mrvi check "$tmp/net.yaml" --set integrator.scheme=midpoint-midpoint
contains "$out" "^solver +schur-krylov: .*GMRES" "lattice midpoint-midpoint: check names schur-krylov"
run_mrvi run "$tmp/net.yaml" --set integrator.scheme=midpoint-midpoint -o "$tmp/o/net.h5"
expect_rc 0 "lattice run"
contains "$out" "solver path +schur-krylov" "lattice run: path in the summary"
contains "$out" "outer iteration +10 steps, .* 0 left to Newton" "lattice run: the outer iteration's steps in the summary"
run_mrvi run "$tmp/net.yaml" --set integrator.scheme=midpoint-midpoint --set integrator.tuning.outer_max=0 -o "$tmp/o/net0.h5"
expect_rc 0 "lattice run, outer iteration off"
contains "$out" "GMRES \(slow unknowns\) +10 solves" "lattice run: GMRES iterations in the summary"
contains "$out" "CG \(micro blocks\) +[0-9]+ block solves" "lattice run: CG iterations in the summary"
if [ "$h5tool" != none ]; then
  a=$(root_attr "$tmp/o/net.h5" solver)
  check "lattice run: solver attribute schur-krylov (got '$a')" test "$a" = schur-krylov
fi
# 70 fast masses on a line, half of them on anchor springs of negative
# stiffness: at dt = 0.05 the micro-step matrix is indefinite, CG meets
# non-positive curvature and the solves fall back to a sparse LU, said once.
{
  printf 'name: anchors\ndimension: 1\nparticles:\n'
  printf '  - {name: s, mass: 1, rate: slow, position: [9], velocity: [0.1]}\n'
  for i in $(seq 0 69); do
    printf '  - {name: c%d, mass: 1, rate: fast, position: [%s]}\n' "$i" "$((20 + i))"
  done
  printf 'springs:\n  - {between: [s, c0], law: linear, stiffness: 1, rest_length: 0.9}\n'
  for i in $(seq 0 69); do
    k=2500
    [ $((i % 2)) -eq 0 ] && k=-2500
    printf '  - {between: [c%d], anchor: [0], law: linear, stiffness: %s, rest_length: initial, potential: fast}\n' "$i" "$k"
  done
  printf 'integrator: {scheme: explicit-slow, macro_step: 0.1, micro_steps: 2, t_end: 0.2}\n'
} >"$tmp/anchors.yaml"
run_mrvi run "$tmp/anchors.yaml" -o "$tmp/o/anchors.h5"
expect_rc 0 "anchors run"
contains "$out" "solver path +sweep-cg" "anchors: sweep-cg"
contains "$err" "^warning: 4 linear solves fell back to a sparse LU \(first: non-positive curvature" "anchors: one fallback warning"
check "anchors: the warning is printed once" test "$(printf '%s\n' "$err" | grep -c 'fell back')" -eq 1

# Without micro output `mrvi run` keeps a step's last micro node alone
# (settings.micro_last_only): the macro trajectory is bit for bit that of
# the run that keeps and writes them all, on the explicit and sweep paths.
if command -v h5diff >/dev/null 2>&1; then
  for scheme in fully-explicit explicit-slow trapezoidal-trapezoidal; do
    for micro in true false; do
      "$mrvi" run "$root/systems/lattice.yaml" -o "$tmp/o/keep_$micro.h5" \
        --set integrator.scheme=$scheme --set integrator.micro_steps=5 \
        --set integrator.t_end=1 --set output.micro=$micro --quiet \
        >/dev/null 2>&1 </dev/null
    done
    check "$scheme: /macro without micro output equals the run with it" \
      h5diff "$tmp/o/keep_true.h5" "$tmp/o/keep_false.h5" /macro
  done
  # ... and on schur-bordered with micro-node constraints, whose interior
  # nodes' momentum projection an output without them leaves out
  for micro in true false; do
    "$mrvi" run "$root/systems/flexible_pendulum.yaml" \
      -o "$tmp/o/flex_$micro.h5" --set integrator.t_end=0.1 \
      --set output.micro=$micro --quiet >/dev/null 2>&1 </dev/null
  done
  check "flexible_pendulum: /macro without micro output equals the run with it" \
    h5diff "$tmp/o/flex_true.h5" "$tmp/o/flex_false.h5" /macro
fi

printf '%d passed, %d failed\n' "$passed" "$failed"
[ "$failed" -eq 0 ] && [ "$passed" -gt 0 ]
