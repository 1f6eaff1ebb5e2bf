#!/bin/bash
# Test of src/cli/mrvi-plot: renders every figure from small runs and synthetic
# study tables and checks the PNG files.  The runs and tables are made
# first; then every mrvi-plot command line and every check that loads
# mrvi-plot as a module run in one Python process (tests/plot_cases.py:
# matplotlib imported once, not once a case), and each is judged in turn.
#
#   test_plot.sh MRVI_BINARY SOURCE_ROOT
#
# Skipped (exit 77) when Debian's /usr/bin/python3 lacks matplotlib or h5py.

set -u

mrvi=${1:?usage: test_plot.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_plot.sh MRVI_BINARY SOURCE_ROOT}
plot="$root/src/cli/mrvi-plot"

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
need_python matplotlib h5py

# png_ok FILE: exists, > 10 kB, PNG signature
png_ok() {
  local f=$1 size sig
  if [ ! -f "$f" ]; then
    fail "$(basename "$f") missing"
    return
  fi
  size=$(stat -c %s "$f")
  sig=$(head -c 8 "$f" | od -An -tx1 | tr -d ' \n')
  if [ "$size" -le 10240 ]; then
    fail "$(basename "$f") too small ($size bytes)"
  elif [ "$sig" != "89504e470d0a1a0a" ]; then
    fail "$(basename "$f") is not a PNG (signature $sig)"
  else
    pass "$(basename "$f") ($size bytes)"
  fi
}

# absent FILE: a figure that must not be drawn for this kind of run
absent() {
  if [ -e "$1" ]; then fail "$(basename "$1") should not exist"
  else pass "$(basename "$1") not drawn"; fi
}

out="$tmp/figs"
cases="$tmp/plot"
mkdir -p "$cases"
: >"$cases/cases.txt"

# case ID ARGS...: queue `mrvi-plot ARGS` as case ID.
case_() {
  (IFS=$'\t' && echo "$*") >>"$cases/cases.txt"
}
# script ID ARGS...: queue `python3 $tmp/ID.py ARGS` (written before) as
# case ID.
script() {
  local id=$1
  shift
  case_ "$id" --script "$tmp/$id.py" "$@"
}
# result ID: case ID's stdout and stderr into $tmp/out.txt and
# $tmp/err.txt; returns its exit status (125 when it has none: the batch
# ended before it).
result() {
  if [ -f "$cases/$1.rc" ]; then
    cp "$cases/$1.out" "$tmp/out.txt"
    cp "$cases/$1.err" "$tmp/err.txt"
    return "$(cat "$cases/$1.rc")"
  fi
  : >"$tmp/out.txt"
  echo "no result for case $1: tests/plot_cases.py ended before it" \
    >"$tmp/err.txt"
  return 125
}
# ok NAME ID: case ID exited 0
ok() {
  local name=$1 rc
  result "$2"
  rc=$?
  if [ $rc -eq 0 ]; then
    pass "$name"
  else
    fail "$name (exit $rc)"
    sed 's/^/     /' "$tmp/err.txt" | head -20
  fi
}
# fails_with NAME PATTERN ID: non-zero exit and PATTERN on stderr
fails_with() {
  local name=$1 pattern=$2 rc
  result "$3"
  rc=$?
  if [ $rc -eq 0 ]; then
    fail "$name: exit 0, expected failure"
  elif ! grep -q -- "$pattern" "$tmp/err.txt"; then
    fail "$name: no '$pattern' in the message"
    sed 's/^/     /' "$tmp/err.txt" | head -5
  else
    pass "$name ($(head -1 "$tmp/err.txt"))"
  fi
}
# warns NAME PATTERN ID: exit 0 and PATTERN on stderr
warns() {
  local name=$1 pattern=$2
  if result "$3" && grep -q -- "$pattern" "$tmp/err.txt"; then
    pass "$name ($(head -1 "$tmp/err.txt"))"
  else
    fail "$name: $(head -1 "$tmp/err.txt")"
  fi
}
# output ID: what case ID printed (its stdout; its traceback on stderr
# shown when it failed)
output() {
  result "$1" || sed 's/^/     /' "$tmp/err.txt" >&2
  cat "$tmp/out.txt"
}

# =============================================================================
# The inputs: runs, optimal control and batch files, synthetic tables
# =============================================================================

run_ok "mrvi run fpu" "$mrvi" run "$root/systems/fpu.yaml" -o "$tmp/fpu.h5" \
  --set integrator.t_end=6 --quiet
run_ok "mrvi run spring_ring" "$mrvi" run "$root/systems/spring_ring.yaml" \
  -o "$tmp/ring.h5" --set integrator.t_end=0.5 --quiet
# Particle systems: lattice (2-D, springs only, micro_slow), cart pendulum
# (J_z conserved), pendulum chain (nothing conserved).
run_ok "mrvi run lattice" "$mrvi" run "$root/systems/lattice.yaml" \
  -o "$tmp/lattice.h5" --set integrator.t_end=0.3 \
  --set output.micro_slow=true --quiet
run_ok "mrvi run cart_pendulum" "$mrvi" run "$root/systems/cart_pendulum.yaml" \
  -o "$tmp/cart.h5" --set integrator.t_end=0.4 --quiet
run_ok "mrvi run pendulum_chain" "$mrvi" run \
  "$root/systems/pendulum_chain.yaml" -o "$tmp/chain.h5" \
  --set integrator.t_end=0.1 --quiet
# H_0 = 0: a unit mass falling from rest under a unit force.
printf 'name: fall\ncoordinates: [{name: x, mass: 1, position: 0, velocity: 0}]\nforces: [{coordinate: x, force: 1}]\nintegrator: {macro_step: 0.1, t_end: 1}\n' >"$tmp/fall.yaml"
run_ok "mrvi run fall" "$mrvi" run "$tmp/fall.yaml" -o "$tmp/fall.h5" --quiet

# A constrained run: fpu.h5 plus the constraint datasets of doc/output.md
# (zeros and a NaN in the residual, as a real run can have).
if ! "$py" - "$tmp" <<'EOF' 2>"$tmp/err.txt"
import shutil
import sys

import h5py
import numpy as np

tmp = sys.argv[1]
shutil.copy(tmp + "/fpu.h5", tmp + "/cons.h5")
with h5py.File(tmp + "/cons.h5", "r+") as f:
    m = f["macro/t"].shape[0]
    res = 1e-12 * (1.0 + np.sin(np.arange(m))) ** 2
    res[::5] = 0.0
    res[3] = np.nan
    f["macro/constraint_residual"] = res
    f["macro/hidden_constraint_residual"] = np.zeros(m)
    lam = np.ones((m, 2))
    lam[-1] = np.nan
    f["macro/lambda"] = lam
    f.attrs["constraint_tolerance"] = 1e-10
EOF
then
  fail "building the constrained run file"
  sed 's/^/     /' "$tmp/err.txt" | head -20
else
  pass "constrained run file built"
fi

# Optimal control files (mrvi optimize): the gantry crane (macro actuator,
# constrained, fast load on /micro) and the double integrator with a slow
# macro and a fast micro actuator.
sed '/^control:/,$d' "$root/systems/ocp_double_integrator.yaml" \
  >"$tmp/di2.yaml"
cat >>"$tmp/di2.yaml" <<'EOF'
control:
  actuators:
    - {name: push, coordinate: x, grid: macro, weight: 1}
    - {name: nudge, coordinate: y, grid: micro, weight: 1}
  terminal:
    - {coordinate: x, position: 1, velocity: 0}
    - {coordinate: y, position: 0, velocity: 0}
  solver: {algorithm: slsqp, tolerance: 1.0e-12, terminal_tolerance: 1.0e-9}
EOF
# A pair actuator (a slow and a fast particle pushed apart or pulled
# together along their line, micro grid): no coordinate of its own.
cat >"$tmp/pair.yaml" <<'EOF'
name: pair_demo
dimension: 2
particles:
  - {name: a, mass: 1, rate: slow, position: [0, 0], velocity: [0, 0]}
  - {name: b, mass: 0.1, rate: fast, position: [1, 0], velocity: [0, 0.5]}
springs:
  - {between: [a, b], law: linear, stiffness: 5, rest_length: 1, potential: slow}
integrator: {scheme: midpoint-midpoint, macro_step: 0.1, micro_steps: 4, t_end: 2}
control:
  actuators:
    - {pair: [a, b], grid: micro}
  terminal:
    - {coordinate: b.x, position: 1.5, velocity: 0}
EOF
run_ok "mrvi optimize pair actuator" "$mrvi" optimize "$tmp/pair.yaml" \
  -o "$tmp/pair.h5" -q
run_ok "mrvi optimize gantry crane" "$mrvi" optimize \
  "$root/systems/ocp_gantry_crane.yaml" -o "$tmp/crane.h5" -q
run_ok "mrvi optimize two actuators" "$mrvi" optimize "$tmp/di2.yaml" \
  -o "$tmp/di2.h5" -q

# Batch master files (mrvi batch): 3 macro steps x 2 micro step counts;
# the step 2 fails (Newton: t_end 40), so two cases are not drawn.
"$mrvi" batch "$root/systems/fpu.yaml" -o "$tmp/bt.h5" -q -j 1 \
  --vary integrator.macro_step=0.01,0.02,2 --vary integrator.micro_steps=5,10 \
  --vary integrator.t_end=40 >/dev/null 2>&1
[ $? = 2 ] && pass "mrvi batch for mrvi-plot batch (two cases fail)" ||
  fail "mrvi batch for mrvi-plot batch (two cases fail)"
run_ok "mrvi batch, three varied keys" "$mrvi" batch "$root/systems/fpu.yaml" \
  -o "$tmp/bt3.h5" -q -j 1 --vary integrator.macro_step=0.01,0.02 \
  --vary integrator.micro_steps=1,2 --vary integrator.t_end=10,20

# Synthetic study tables in the formats of mrvi converge / stability /
# timing.
if ! "$py" - "$tmp" <<'EOF' 2>"$tmp/err.txt"
import math
import sys

import h5py
import numpy as np

tmp = sys.argv[1]
str_t = h5py.string_dtype("utf-8", 32)  # fixed-length, as mrvi writes

# mrvi converge: errors C dT^2 on 5 halvings, p in {1, 5, 10}
with h5py.File(tmp + "/conv.h5", "w") as f:
    # The longest title of the reproduction (doc/reproduce.sh).
    for k, v in dict(system="spring_ring", scheme="trapezoidal-trapezoidal",
                     reference_scheme="midpoint-midpoint").items():
        f.attrs.create(k, v, dtype=str_t)
    f.attrs["t_end"] = 0.5
    f.attrs["reference_step"] = 7.8125e-6
    dT = 0.1 / 2.0 ** np.arange(5)
    for p in (1, 5, 10):
        g = f.create_group("convergence/p%d" % p)
        g.attrs["micro_steps"] = np.int32(p)
        g["macro_step"] = dT
        g["e_q_mac"] = 0.8 * dT ** 2
        g["e_p_mac"] = 3.0 * dT ** 2
        nan = np.full_like(dT, np.nan)
        g["e_q_mic"] = nan if p == 1 else 1.1 * dT ** 2
        g["e_p_mic"] = nan if p == 1 else 4.0 * dT ** 2
        g["e_qs_mac"] = 0.5 * dT ** 2
        g["e_qf_mac"] = 0.7 * dT ** 2
        g["e_ps_mac"] = 2.0 * dT ** 2
        g["e_pf_mac"] = 0.05 * dT

# mrvi stability: bounds for p = 1..10, trace scan
with h5py.File(tmp + "/stab.h5", "w") as f:
    p = np.arange(1, 11)
    tra = np.sqrt(12.0 * p ** 2 / (p ** 2 + 2.0))
    with np.errstate(divide="ignore"):
        mid = np.sqrt(12.0 * p ** 2 / (p ** 2 - 1.0))
    s = f.create_group("stability")
    s["p"] = p.astype(np.int32)
    s["trapezoidal_analytic"] = tra
    s["trapezoidal_measured"] = tra * (1 - 1e-3)
    s["midpoint_analytic"] = mid
    s["midpoint_measured"] = mid * (1 - 1e-3)
    x = np.linspace(0.0, 6.0, 241)
    sc = s.create_group("scan")
    sc["omega_dT"] = x
    sc["p"] = p.astype(np.int32)
    def trace(bound):
        c = 0.0 if not np.isfinite(bound) else (bound ** 2 - 4) / bound ** 4
        return 2 - x ** 2 + c * x ** 4 if np.isfinite(bound) else \
            2 * (1 - x ** 2 / 4) / (1 + x ** 2 / 4)
    sc["trace_trapezoidal"] = np.array([trace(b) for b in tra])
    sc["trace_midpoint"] = np.array([trace(b) for b in mid])

# mrvi timing: three schemes, p from 1 to 1000
with h5py.File(tmp + "/timing.h5", "w") as f:
    f.attrs.create("system", "fpu", dtype=str_t)
    f.attrs["micro_step"] = 0.001
    p = np.array([1, 5, 10, 20, 50, 100, 200, 500, 1000])
    t = f.create_group("timing")
    t["p"] = p.astype(np.int32)
    for i, name in enumerate(("midpoint-midpoint", "trapezoidal-midpoint",
                              "trapezoidal-trapezoidal")):
        g = t.create_group(name)
        steps = np.ceil(10.0 / (0.001 * p))
        size = 6 + 3 * (p - 1)
        per = 1e-5 * (1 + i) * size ** 1.1
        g["macro_steps"] = steps.astype(np.int64)
        g["system_size"] = size.astype(np.int32)
        g["assemble_per_step"] = per
        g["solve_per_step"] = 0.6 * per
        g["time_per_step"] = 1.8 * per
        g["total_time"] = 1.8 * per * steps
        g["iterations"] = (steps * (3 + i)).astype(np.int64)

# a stability table with one dataset missing
with h5py.File(tmp + "/broken.h5", "w") as f:
    s = f.create_group("stability")
    s["p"] = np.arange(1, 4, dtype=np.int32)
    s["trapezoidal_measured"] = np.ones(3)
    s["trapezoidal_analytic"] = np.ones(3)
    s["midpoint_analytic"] = np.ones(3)
EOF
then
  fail "building the synthetic tables"
  sed 's/^/     /' "$tmp/err.txt" | head -20
else
  pass "synthetic tables built"
fi

# For the readable figures: FPU Q3 with p = 1, and 1601 macro nodes (more
# than DENSE_NODES = 1500).
run_ok "mrvi run fpu Q3 p = 1" "$mrvi" run "$root/systems/fpu.yaml" \
  -o "$tmp/fpu3.h5" --set integrator.scheme=trapezoidal-trapezoidal \
  --set integrator.macro_step=0.03 --set integrator.micro_steps=1 \
  --set integrator.t_end=6 --quiet
run_ok "mrvi run spring_ring, 1601 nodes" "$mrvi" run \
  "$root/systems/spring_ring.yaml" -o "$tmp/ring_long.h5" \
  --set integrator.t_end=16 --set output.micro=false --quiet
# For the still picture: a rigid body (heavy_top, 3-D).
run_ok "mrvi run heavy_top" "$mrvi" run "$root/systems/heavy_top.yaml" \
  -o "$tmp/top.h5" -q --set integrator.t_end=1

# =============================================================================
# The cases, queued in the order they are judged below
# =============================================================================

# --- help ---
case_ help --help
for sub in run optimize convergence stability timing animate batch all; do
  case_ "help_$sub" "$sub" --help
done

# --- run files ---
case_ run_fpu run "$tmp/fpu.h5" -o "$out"
case_ run_ring run "$tmp/ring.h5" -o "$out" --prefix ring --window 0.2
case_ run_omega run "$tmp/ring.h5" -o "$out" --prefix ring_omega --omega 44.72
case_ run_lattice run "$tmp/lattice.h5" -o "$out"
case_ run_cart run "$tmp/cart.h5" -o "$out"
case_ run_chain run "$tmp/chain.h5" -o "$out"
case_ omega_lattice run "$tmp/lattice.h5" -o "$out" --prefix lattice_omega \
  --omega 40

# What the figures are made of, asserted on the numbers.
cat >"$tmp/checks.py" <<'PYEOF'
import sys
from importlib.machinery import SourceFileLoader
import h5py
import numpy as np
mod = SourceFileLoader("mrvi_plot", sys.argv[1]).load_module()
tmp = sys.argv[2]
out = []


def run(name):
    return mod.Run(h5py.File("%s/%s.h5" % (tmp, name), "r"))


# Stiffnesses fitted to W: FPU 2500, spring ring 4000 (fast anchors), none
# for the lattice (fast springs between particles) and the cart (W = 0).
k_fpu = mod.fitted_stiffness(run("fpu"))
k_ring = mod.fitted_stiffness(run("ring"))
out.append("fit-fpu:%s" % np.allclose(k_fpu, 2500, rtol=1e-9))
out.append("fit-ring:%s" % np.allclose(k_ring, 4000, rtol=1e-9))
out.append("fit-lattice:%s" % (mod.fitted_stiffness(run("lattice")) is None))
out.append("fit-cart:%s" % (mod.fitted_stiffness(run("cart")) is None))
k, why = mod.stiffnesses(run("lattice"), 40.0)
out.append("omega-refused:%s" % (k is None and "not" in why))

# The energy error is divided by what the run summary divides it by: the
# attribute energy_scale (cart pendulum: T0 + |V0| + |W0|, V0 < 0), for
# H0 = 0 the largest T + |V| + |W| (falling mass: t_end^2 = 1), also
# recomputed from the datasets for a file without the attribute.
h = run("cart").h5
mag0 = sum(abs(float(h["macro/" + d][0])) for d in
           ("kinetic", "potential_slow", "potential_fast"))
scale, name = mod.energy_scale(h)
out.append("escale-cart:%s" % (abs(scale - mag0) <= 1e-15 * mag0 and
                              float(h.attrs["energy_scale"]) == scale and
                              name.startswith("(H − H₀)/E₀")))
scale, name = mod.energy_scale(run("fall").h5)
out.append("escale-fall:%s" % (abs(scale - 1.0) <= 1e-12 and "H₀ = 0" in name))
import shutil
shutil.copy("%s/fall.h5" % tmp, "%s/fall_old.h5" % tmp)
with h5py.File("%s/fall_old.h5" % tmp, "r+") as f:
    for a in ("energy_scale", "energy_scale_kind"):
        del f.attrs[a]
scale, name = mod.energy_scale(run("fall_old").h5)
out.append("escale-noattr:%s" % (abs(scale - 1.0) <= 1e-12 and "H₀ = 0" in name))

# Micro figure of the lattice: the 6 of 15 fast particles that move most.
r = run("lattice")
tm = mod.read(r.h5, "micro/t")
sel = tm <= tm[0] + 1.0
chosen, note = mod.pick_particles(r, tm, sel, None)
out.append("pick:%s" % (len(chosen) == 6 and "6 of 15" in note and
                        all(r.rate[r.columns[i]] == 1 for i in chosen)))
# The slow coordinates interpolated linearly between the macro nodes equal
# the stored /micro/q_slow (the writer's formula) to 1e-15.
stored = r.h5["micro/q_slow"][()]
qmac = r.h5["macro/q"][()]
slow = np.flatnonzero(r.rate == 0)
interp = np.column_stack([np.interp(tm, r.t, qmac[:, c]) for c in slow])
out.append("q_slow:%s" % (np.max(np.abs(interp - stored)) <= 1e-15 *
                          max(1.0, np.max(np.abs(stored)))))

# A conserved (flat) series gets short tick labels, not 1.0500000000010.
import matplotlib.pyplot as plt
fig, ax = plt.subplots()
y = 1.05 + 1e-14 * np.sin(np.arange(50.0))
ax.plot(y)
mod.flat_ylim(ax, y)
fig.canvas.draw()
labels = [t.get_text().replace("$\\mathdefault{", "").rstrip("}$")
          for t in ax.get_yticklabels() if t.get_text()]
out.append("ticks:%s" % (max(len(lab) for lab in labels) <= 5))
# Log axis of p = 1 ... 1000 in a narrow panel: labels at the decades only.
fig, ax = plt.subplots()
p = [1, 5, 10, 20, 50, 100, 200, 500, 1000]
ax.loglog(p, p)
mod.plain_log_ticks(ax.xaxis, p, most=12, labels=4)
major = list(ax.xaxis.get_major_locator()())
out.append("decades:%s" % (major == [1, 10, 100, 1000]))
print(" ".join(out))
PYEOF
script checks "$plot" "$tmp"

# --- animate ---
case_ anim_lattice animate "$tmp/lattice.h5" -o "$tmp/lattice.gif" --every 5
case_ anim_ring animate "$tmp/ring.h5" -o "$tmp/ring.gif" --every 10 --fps 10
# MP4 asked for where matplotlib finds no ffmpeg: a GIF and a note (a
# process of its own: matplotlib reads MATPLOTLIBRC as it is imported).
mkdir -p "$tmp/rc"
echo "animation.ffmpeg_path: $tmp/no-such-ffmpeg" >"$tmp/rc/matplotlibrc"
MATPLOTLIBRC="$tmp/rc" "$py" "$plot" animate "$tmp/cart.h5" \
  -o "$tmp/cart.mp4" --every 4 >"$tmp/ffmpeg.out" 2>"$tmp/ffmpeg.err"
echo $? >"$tmp/ffmpeg.rc"
cat >"$tmp/frames.py" <<'PYEOF'
import math
import sys
import h5py
from PIL import Image
tmp = sys.argv[1]
res = []
# The cart is slow and the file has no /micro/q_slow: macro nodes.
for name, grid, every in (("lattice", "micro", 5), ("ring", "macro", 10),
                          ("cart", "macro", 4)):
    rows = h5py.File("%s/%s.h5" % (tmp, name), "r")[grid + "/t"].shape[0]
    im = Image.open("%s/%s.gif" % (tmp, name))
    want = math.ceil(rows / every)
    ok = im.format == "GIF" and im.n_frames == want and im.size[0] > 300
    res.append("%s:%s:%d/%d" % (name, ok, im.n_frames, want))
print(" ".join(res))
PYEOF
script frames "$tmp"
case_ anim_fpu animate "$tmp/fpu.h5" -o "$tmp/fpu.gif"
case_ anim_grid animate "$tmp/ring.h5" -o "$tmp/x.gif" --grid micro

# --- constrained run ---
case_ run_cons run "$tmp/cons.h5" -o "$out"
cat >"$tmp/floor.py" <<'EOF'
import sys
from importlib.machinery import SourceFileLoader
import numpy as np
mod = SourceFileLoader("mrvi_plot", sys.argv[1]).load_module()
y, floor, n = mod.log_floor(np.array([0.0, 3e-12, np.nan, 1e-10, -0.0]))
ok = y[0] == floor and np.isclose(floor, 3e-13) and y[1] == 3e-12 and \
    np.isnan(y[2]) and n == 2
y0, floor0, n0 = mod.log_floor(np.zeros(3))
print("ok" if ok and floor0 == 1e-16 and n0 == 3 and (y0 == 1e-16).all()
      else "bad: %r %r %r / %r %r" % (y, floor, n, y0, floor0))
EOF
script floor "$plot"

# --- optimal control files ---
for f in crane di2 pair; do
  case_ "opt_$f" optimize "$tmp/$f.h5" -o "$out"
done
# `all` recognises the file and draws the run figures too.
case_ all_crane all "$tmp/crane.h5" -o "$out/all" --prefix x
case_ opt_fpu optimize "$tmp/fpu.h5" -o "$out"
# The drawn steps are the stored controls: per actuator, the step values
# repeated over the intervals of /control/t equal /control/u exactly, the
# step edges are /control/t and T (macro actuator: every p-th), the panel
# is labelled with /control/names; the trajectory figure shows the actuated
# and terminal coordinates.
cat >"$tmp/ocp.py" <<'PYEOF'
import sys
from importlib.machinery import SourceFileLoader
import h5py
import matplotlib.patches
import numpy as np
mod = SourceFileLoader("mrvi_plot", sys.argv[1]).load_module()
tmp = sys.argv[2]
res = []
for name, sizes, want in (("crane", [40], [0, 2]),
                          ("di2", [10, 50], [0, 1]), ("pair", [80], [2])):
    h5 = h5py.File("%s/%s.h5" % (tmp, name), "r")
    opt = mod.Optimal(h5)
    u, t = h5["control/u"][()], h5["control/t"][()]
    T = h5["macro/t"][-1]
    fig = mod.controls_figure(opt)
    ok = len(fig.axes) == u.shape[1]
    for a, ax in enumerate(fig.axes):
        steps = [s for s in ax.patches
                 if isinstance(s, matplotlib.patches.StepPatch)]
        if len(steps) != 1:
            ok = False
            continue
        values, edges, _ = steps[0].get_data()
        rep = u.shape[0] // values.size
        ok = ok and values.size == sizes[a] and \
            np.array_equal(np.repeat(values, rep), u[:, a]) and \
            np.array_equal(edges, np.append(t, T)[::rep]) and \
            ax.get_ylabel() == mod.text(h5["control/names"][a])
    ok = ok and mod.ocp_coordinates(opt) == want
    if name == "pair":
        # The distance panel: on the 81 micro nodes (b is fast), equal to
        # |x_a - x_b| of /macro/q at the macro nodes.
        tr, r = mod.pair_distance(opt.run, 0, 1)
        q = h5["macro/q"][()]
        rm = np.hypot(q[:, 0] - q[:, 2], q[:, 1] - q[:, 3])
        ok = ok and opt.pairs == [(0, 1)] and r.size == 81 and \
            np.allclose(r[::4], rm, rtol=0, atol=1e-14)
    res.append("%s:%s" % (name, ok))
print(" ".join(res))
PYEOF
script ocp "$plot" "$tmp"

# --- batch master files: a column against a varied key ---
case_ batch_plot batch "$tmp/bt.h5" -o "$out" --x integrator.macro_step \
  --y energy_error
case_ batch_data batch "$tmp/bt.h5" -o "$out" --x integrator.micro_steps \
  --y steps --data
# The drawn lines are the table: one per micro step count, x the completed
# macro steps ascending, y /cases/energy_error of the matching case; the
# --data lines (the stdout of batch_data) are the same points.
cat >"$tmp/bt.py" <<'PYEOF'
import sys
from importlib.machinery import SourceFileLoader
import h5py
import numpy as np
mod = SourceFileLoader("mrvi_plot", sys.argv[1]).load_module()
h5 = h5py.File(sys.argv[2], "r")
dt = h5["cases/values/integrator.macro_step"][()]
p = h5["cases/values/integrator.micro_steps"][()]
err = h5["cases/energy_error"][()]
steps = h5["cases/steps"][()]
ok_status = h5["cases/status"][()] == 1
table = mod.BatchTable(h5)
group = mod.batch_group(table, "integrator.macro_step", None)
fig, _ = mod.batch_figure(table, "integrator.macro_step", "energy_error", group)
lines = fig.axes[0].get_lines()
ok = group == "integrator.micro_steps" and len(lines) == 2
for line, pv in zip(lines, (5, 10)):
    sel = ok_status & (p == pv)
    order = np.argsort(dt[sel])
    ok = ok and line.get_label() == "integrator.micro_steps = %d" % pv and \
        np.array_equal(line.get_xdata(), dt[sel][order]) and \
        np.array_equal(line.get_ydata(), err[sel][order]) and \
        line.get_xdata().size == 2
# --data of --x integrator.micro_steps --y steps: group, x, y per point.
rows = [l.split("\t") for l in open(sys.argv[3]) if "\t" in l]
want = sorted((float(d), float(q), float(s)) for d, q, s, c in
              zip(dt, p, steps, ok_status) if c)
got = sorted(tuple(float(v) for v in r) for r in rows)
ok = ok and got == want and len(got) == 4
print(ok)
PYEOF
script bt "$plot" "$tmp/bt.h5" "$cases/batch_data.out"
case_ batch_fpu batch "$tmp/fpu.h5" --x integrator.macro_step -o "$out"
case_ batch_dt batch "$tmp/bt.h5" --x integrator.dt -o "$out"
case_ batch_bt3 batch "$tmp/bt3.h5" --x integrator.macro_step -o "$out"
# all: a master file is told apart by /cases and batch_version; each varied
# key against the other, energy_error and wall_time (the figures of
# mrvi-plot batch); three varied keys: no figure, a note, exit 0.
rm -rf "$tmp/all_bt" && mkdir "$tmp/all_bt"
case_ all_bt all "$tmp/bt.h5" "$tmp/bt3.h5" -o "$tmp/all_bt"
case_ all_bt3 all "$tmp/bt3.h5" -o "$tmp/all_bt"

# --- synthetic study tables ---
case_ conv convergence "$tmp/conv.h5" -o "$out"
cat >"$tmp/slope.py" <<'EOF'
import sys
from importlib.machinery import SourceFileLoader
import numpy as np
mod = SourceFileLoader("mrvi_plot", sys.argv[1]).load_module()
x = 0.1 / 2.0 ** np.arange(5)
print("%.2f %.2f" % (mod.slope(x, 3 * x ** 2), mod.slope(x, 0.1 * x)))
EOF
script slope "$plot"
case_ stab stability "$tmp/stab.h5" -o "$out"
case_ timing timing "$tmp/timing.h5" -o "$out"

# --- what a reader needs to see, asserted on the figures themselves ---
cat >"$tmp/readable.py" <<'PYEOF'
import argparse
import contextlib
import io
import sys
import traceback
from importlib.machinery import SourceFileLoader
import h5py
import numpy as np
mod = SourceFileLoader("mrvi_plot", sys.argv[1]).load_module()
tmp = sys.argv[2]
figs = []
# Keep the figures to inspect (not "all", which matplotlib may close).
mod.plt.close = lambda fig=None: isinstance(fig, mod.plt.Figure) and \
    figs.append(fig)
out = []


def check(name):
    """Decorator: run the check now, record name:True/False (an exception
    is False, its traceback on stderr)."""
    def wrap(func):
        try:
            ok = bool(func())
        except Exception:
            traceback.print_exc()
            ok = False
        out.append("%s:%s" % (name, ok))
    return wrap


def draw(func, *args):
    """The figures `func` saves (drawn, so text extents are known)."""
    figs.clear()
    with contextlib.redirect_stdout(io.StringIO()):   # the paths printed
        func(*args)
    return list(figs)


def texts(ax):
    return [t.get_text() for t in ax.texts]


def legend(ax):
    leg = ax.get_legend()
    return [t.get_text() for t in leg.get_texts()] if leg else []


def overlap(fig):
    """Pairs of neighbouring x tick labels whose drawn extents intersect,
    plus figure texts (titles) wider than the figure."""
    r = fig.canvas.get_renderer()
    width = fig.bbox.width
    bad = sum(t.get_window_extent(r).x0 < 0 or
              t.get_window_extent(r).x1 > width for t in fig.texts)
    for ax in fig.axes:
        boxes = sorted((lab.get_window_extent(r) for lab in
                        ax.get_xticklabels() if lab.get_visible() and
                        lab.get_text()), key=lambda b: b.x0)
        bad += sum(a.x1 > b.x0 for a, b in zip(boxes, boxes[1:]))
    return bad


def png(name):
    return "%s/%s.png" % (tmp, name)


def run(name):
    return mod.Run(h5py.File("%s/%s.h5" % (tmp, name), "r"))


def table(kind, name):
    args = argparse.Namespace(file="%s/%s.h5" % (tmp, name), outdir=tmp,
                              prefix="r_" + name)
    return draw(getattr(mod, "cmd_" + kind), args)


# FPU Q3, p = 1: I sits below the dashed I(0) = 1 and the figure says why.
@check("q3-note")
def _():
    ax = draw(mod.plot_stiff_energy, run("fpu3"), png("s3"), None)[0].axes[0]
    note = " ".join(texts(ax))
    return ("not about I(0) = 1" in note and "ωΔt = 1.5" in note
            and "I(0) = 1, initial value" in legend(ax))


# The dotted Ĩ, kept exactly by the left rectangle rule for the harmonic
# springs, moves by at most 10 % of I's swing (the quartic slow coupling
# moves it; I swings by the cross term).
@check("q3-tilde")
def _():
    ax = draw(mod.plot_stiff_energy, run("fpu3"), png("s3"), None)[0].axes[0]
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    tilde = [ln for lab, ln in lines.items() if lab.startswith("Ĩ")]
    total = lines["I = Σ I_j"].get_ydata()
    return len(tilde) == 1 and \
        np.ptp(tilde[0].get_ydata()) <= 0.1 * np.ptp(total)


# Q1 (implicit midpoint fast rule): neither Ĩ nor the note.
@check("q1-no-note")
def _():
    ax = draw(mod.plot_stiff_energy, run("fpu"), png("s1"), None)[0].axes[0]
    return not any(t.startswith("Ĩ") for t in legend(ax)) and \
        not any("I(0)" in t for t in texts(ax))


# Long spring-ring run: H at every node, exactly; T as its running mean
# with the min-max band of the data; a zoom panel at every node.
@check("dense-H")
def _():
    r = run("ring_long")
    ax = draw(mod.plot_energy, r, png("e"))[0].axes[0]
    h = [ln for ln in ax.get_lines()
         if ln.get_label() == "total H (every node)"]
    return len(h) == 1 and np.array_equal(h[0].get_ydata(),
                                          mod.read(r.h5, "macro/energy"))


@check("dense-T")
def _():
    r = run("ring_long")
    fig = draw(mod.plot_energy, r, png("e"))[0]
    ax = fig.axes[0]
    kin = mod.read(r.h5, "macro/kinetic")
    mean = [ln for ln in ax.get_lines() if ln.get_label() == "kinetic T"]
    band = ax.collections[0].get_paths()[0].vertices[:, 1]
    return (len(mean) == 1 and np.ptp(mean[0].get_ydata()) < 0.2 * np.ptp(kin)
            and np.isclose(band.max(), kin.max(), rtol=1e-12)
            and np.isclose(band.min(), kin.min(), rtol=1e-12)
            and fig.axes[-1].get_xlabel() == "t (zoom)")


# The slow trend the micro_fast figure removes: a straight line is its own
# trend to round-off (ends included), and a sine whose period is the window
# (p + 1 samples) leaves its whole amplitude, the line under it none.
@check("trend")
def _():
    t = np.linspace(0.0, 3.0, 301)
    line = np.column_stack([2.0 + 0.5 * t, -1.0 + 3.0 * t])
    e1 = np.max(np.abs(mod.slow_trend(line, 10) - line))
    wave = np.sin(2 * np.pi * np.arange(301) / 11)[:, None]
    inner = slice(10, 291)
    e2 = np.max(np.abs(mod.slow_trend(line[:, :1] + wave, 10)
                       - line[:, :1])[inner])
    return e1 < 1e-12 and e2 < 1e-12

# Running min/max and mean of a sine with 20 samples per period over 61
# points: the extremes +-1 exactly, the mean within one sample, 1/61; the
# O(n) min/max equal to the brute-force ones.
@check("range")
def _():
    x = np.sin(2 * np.pi * np.arange(400) / 20)
    lo, hi = mod.running_range(x, 60)
    mean = mod.running_mean(x, 60)
    inner = slice(30, 370)
    # Random data with NaN: equal to the brute-force window extrema.
    y = np.random.default_rng(1).normal(size=997)
    y[::37] = np.nan
    win = np.lib.stride_tricks.sliding_window_view(np.pad(y, 30, "edge"), 61)
    ylo, yhi = mod.running_range(y, 60)
    return (np.allclose(lo[inner], -1, atol=1e-12) and
            np.allclose(hi[inner], 1, atol=1e-12) and
            np.max(np.abs(mean[inner])) <= 1 / 61 + 1e-12 and
            np.array_equal(ylo, np.nanmin(win, axis=1)) and
            np.array_equal(yhi, np.nanmax(win, axis=1)))


# Spring ring: the Newton tolerance is written beside the J_z drift panel,
# not beside the upper panel where J_y ends.
@check("j-tol")
def _():
    top, drift = draw(mod.plot_angular_momentum, run("ring"), png("j"))[0].axes
    return (drift.get_title(loc="right").startswith("J_z")
            and any("Newton tolerance" in t for t in texts(drift))
            and not any("Newton" in t for t in texts(top)))


# Convergence: the reference's step is h, not ΔT (the x axis is ΔT).
@check("conv-h")
def _():
    title = table("convergence", "conv")[0].texts[0].get_text()
    return "single rate, h = 7.8125e-06" in title and "ΔT" not in title


# Stability: the infinite midpoint p = 1 bound is said in words.
@check("stab-inf")
def _():
    ax = table("stability", "stab")[0].axes[0]
    words = " ".join(texts(ax))
    return ("midpoint, p = 1: ∞ (stable at every ωΔT)" in words and
            any("unconditionally stable" in t for t in legend(ax)))


# No two x tick labels touch and every title fits (extents as drawn) in the
# timing, stability and convergence figures.
@check("no-overlap")
def _():
    drawn = table("timing", "timing") + table("stability", "stab") + \
        table("convergence", "conv")
    return len(drawn) == 10 and sum(overlap(f) for f in drawn) == 0


print(" ".join(out))
PYEOF
script readable "$plot" "$tmp"
case_ all_fpu all "$tmp/fpu.h5" "$tmp/stab.h5" -o "$tmp/all"

# --- still: a picture of the motion ---
# Particles (pendulum_chain, 2-D) and a rigid body (heavy_top, 3-D): the
# traces drawn are the stored positions, the body's director segments start
# at its centre of mass along the stored rotation's columns, and 3-D axes
# have equal scales.  A model of coordinates only is refused with a reason.
case_ still_chain still "$tmp/chain.h5" -o "$out"
case_ still_top still "$tmp/top.h5" -o "$out"
cat >"$tmp/still.py" <<'PY'
import sys
import numpy as np, h5py
from importlib.machinery import SourceFileLoader
mod = SourceFileLoader("mrvi_plot", sys.argv[1]).load_module()
ok = []
with h5py.File(sys.argv[2], "r") as h5:
    run = mod.Run(h5)
    fig = mod.still_figure(run, 6)
    q = h5["macro/q"][()]
    traces = [l for l in fig.axes[0].lines if l.get_xdata().size == q.shape[0]]
    want = [q[:, c] for c in run.columns]
    ok.append(len(traces) == run.columns.size and all(
        np.array_equal(l.get_xdata(), w) for l, w in zip(traces, want)))
    # The rod of h1 to the origin is an anchor (/model/anchor_*): stored
    # with its particle and kind, and drawn from the origin to h1 at every
    # instant drawn (6 segments).
    part, point, kind = mod.read_anchors(h5, run.columns.size, 2)
    h1 = run.pnames.index("h1")
    c = run.columns[h1]
    segs = [(l.get_xdata(), l.get_ydata()) for l in fig.axes[0].lines
            if l.get_xdata().size == 2 and l.get_xdata()[0] == 0.0
            and l.get_ydata()[0] == 0.0]
    ends = {(x[1], y[1]) for x, y in segs}
    ok.append(part.tolist() == [h1] and point.tolist() == [[0.0, 0.0]]
              and kind.tolist() == [2] and len(segs) == 6 and
              all((q[k, c], q[k, c + 1]) in ends for k in
                  np.unique(np.linspace(0, q.shape[0] - 1, 6).round()
                            .astype(int))))
with h5py.File(sys.argv[3], "r") as h5:
    run = mod.Run(h5)
    fig = mod.still_figure(run, 6)
    ax = fig.axes[0]
    pos, rot = h5["bodies/position"][()], h5["bodies/rotation"][()]
    trace = [l for l in ax.lines if len(l.get_data_3d()[0]) == pos.shape[0]]
    ok.append(len(trace) == 1 and np.array_equal(
        np.array(trace[0].get_data_3d()).T, pos[:, 0]))
    segs = [np.array(l.get_data_3d()).T for l in ax.lines
            if len(l.get_data_3d()[0]) == 2]
    k = pos.shape[0] - 1  # the last instant drawn: its three directors
    last = segs[-3:]
    arm = np.linalg.norm(last[0][1] - last[0][0])
    ok.append(len(segs) == 18 and all(
        np.allclose(s[0], pos[k, 0]) and
        np.allclose((s[1] - s[0]) / arm, rot[k, 0][:, a], atol=1e-12)
        for a, s in enumerate(last)))
    lim = [ax.get_xlim(), ax.get_ylim(), ax.get_zlim()]
    ok.append(np.allclose([b - a for a, b in lim], lim[0][1] - lim[0][0]))
print(" ".join(str(v) for v in ok))
PY
script still "$plot" "$tmp/chain.h5" "$tmp/top.h5"
case_ still_fpu still "$tmp/fpu.h5" -o "$out"

# --- errors ---
case_ err_missing run "$tmp/does-not-exist.h5" -o "$out"
case_ err_broken stability "$tmp/broken.h5" -o "$out"
case_ err_conv convergence "$tmp/fpu.h5" -o "$out"
case_ err_none

# One process for every case queued (each case bounded by 120 s inside).
timeout 1800 "$py" "$root/tests/plot_cases.py" "$plot" "$cases/cases.txt" \
  "$cases" || fail "tests/plot_cases.py: exit $?"

# =============================================================================
# The judgements
# =============================================================================

# --- help ---
ok "mrvi-plot --help" help
for sub in run optimize convergence stability timing animate batch all; do
  ok "mrvi-plot $sub --help" "help_$sub"
done

# --- run files ---
ok "mrvi-plot run fpu" run_fpu
for f in energy stiff_energy micro; do png_ok "$out/fpu_$f.png"; done
absent "$out/fpu_angular_momentum.png"
ok "mrvi-plot run spring_ring" run_ring
# W = (omega2/2) |q_f|^2: the stiff-spring energies mean something here.
for f in energy angular_momentum micro stiff_energy; do
  png_ok "$out/ring_$f.png"
done
ok "mrvi-plot run --omega" run_omega
png_ok "$out/ring_omega_stiff_energy.png"
ok "mrvi-plot run lattice" run_lattice
for f in energy angular_momentum micro micro_fast; do png_ok "$out/lattice_$f.png"; done
absent "$out/lattice_stiff_energy.png"
ok "mrvi-plot run cart_pendulum" run_cart
png_ok "$out/cart_angular_momentum.png"
ok "mrvi-plot run pendulum_chain" run_chain
absent "$out/chain_angular_momentum.png"
if grep -q "conserves no component" "$tmp/out.txt"; then
  pass "pendulum chain: says why there is no angular momentum figure"
else
  fail "pendulum chain: no reason given: $(cat "$tmp/out.txt")"
fi
warns "--omega where W is not quadratic per coordinate" \
  "no stiff-energy figure" omega_lattice
absent "$out/lattice_omega_stiff_energy.png"
checks=$(output checks)
for c in fit-fpu fit-ring fit-lattice fit-cart omega-refused pick q_slow ticks \
  decades escale-cart escale-fall escale-noattr; do
  case " $checks " in
    *" $c:True "*) pass "$c" ;;
    *) fail "$c (got: $checks)" ;;
  esac
done

# --- animate ---
ok "mrvi-plot animate lattice (micro nodes)" anim_lattice
ok "mrvi-plot animate spring_ring (macro nodes)" anim_ring
if [ "$(cat "$tmp/ffmpeg.rc")" = 0 ] &&
  grep -q "ffmpeg not found" "$tmp/ffmpeg.err" && [ ! -e "$tmp/cart.mp4" ]; then
  pass "no ffmpeg: $(head -1 "$tmp/ffmpeg.err")"
else
  fail "no ffmpeg: GIF fallback ($(head -1 "$tmp/ffmpeg.err"))"
fi
frames=$(output frames)
for n in lattice ring cart; do
  case " $frames " in
    *" $n:True:"*) pass "animation $n: one GIF frame per node kept ($frames)" ;;
    *) fail "animation $n: frames ($frames)" ;;
  esac
done
fails_with "animate a run without particles" "no particles" anim_fpu
fails_with "animate --grid micro without q_slow" "micro_slow" anim_grid

# --- constrained run ---
ok "mrvi-plot run constrained" run_cons
png_ok "$out/cons_energy.png"
# The constraint panel makes the energy figure taller than the FPU one
# (PNG height: bytes 20-23, in the IHDR chunk).
png_height() {
  od -An -j20 -N4 -tu1 "$1" | awk '{print $1*16777216+$2*65536+$3*256+$4}'
}
h_fpu=$(png_height "$out/fpu_energy.png")
h_cons=$(png_height "$out/cons_energy.png")
if [ "${h_cons:-0}" -gt "${h_fpu:-0}" ]; then
  pass "constraint panel added (height $h_cons > $h_fpu px)"
else
  fail "constraint panel added (height ${h_cons:-?} vs ${h_fpu:-?} px)"
fi
floor=$(output floor)
if [ "$floor" = "ok" ]; then
  pass "log_floor raises exact zeros to a decade below the smallest value"
else
  fail "log_floor: $floor"
fi

# --- optimal control files ---
for f in crane di2 pair; do
  ok "mrvi-plot optimize $f" "opt_$f"
  for g in controls trajectory history; do png_ok "$out/${f}_$g.png"; done
done
ok "mrvi-plot all (optimize file)" all_crane
for g in energy micro controls trajectory history; do
  png_ok "$out/all/x_crane_$g.png"
done
fails_with "mrvi-plot optimize on a run file" \
  "missing dataset or group '/control'" opt_fpu
ocp=$(output ocp)
for n in crane di2 pair; do
  case " $ocp " in
    *" $n:True "*) pass "optimize $n: drawn steps equal /control/u, panels" ;;
    *) fail "optimize $n: drawn steps vs /control/u, panels ($ocp)" ;;
  esac
done

# --- batch master files ---
ok "mrvi-plot batch" batch_plot
png_ok "$out/bt_energy_error_vs_integrator.macro_step.png"
ok "mrvi-plot batch --data" batch_data
bt=$(output bt)
[ "$bt" = True ] && pass "batch: drawn lines and --data equal the case table" ||
  fail "batch: drawn lines and --data equal the case table ($bt)"
fails_with "batch: not a master file" "not the master file of mrvi batch" \
  batch_fpu
fails_with "batch: --x not a varied key" "'integrator.dt' is not a varied key" \
  batch_dt
fails_with "batch: two other varied keys need --group" "also varies" batch_bt3
ok "mrvi-plot all (batch master files)" all_bt
for y in energy_error wall_time; do
  for x in macro_step micro_steps; do
    png_ok "$tmp/all_bt/bt_${y}_vs_integrator.$x.png"
  done
done
n_png=$(ls "$tmp/all_bt" | wc -l)
[ "$n_png" = 4 ] && pass "all: four batch figures, none of bt3" ||
  fail "all: four batch figures, none of bt3 (got $n_png)"
result all_bt3
[ $? = 0 ] && grep -q "no figure of the batch" "$tmp/err.txt" &&
  pass "all: a batch varying three keys: a note" ||
  fail "all: a batch varying three keys: a note ($(cat "$tmp/err.txt"))"

# --- synthetic study tables ---
ok "mrvi-plot convergence" conv
for p in 1 5 10; do
  png_ok "$out/conv_p$p.png"
  png_ok "$out/conv_p${p}_split.png"
done
slope=$(output slope)
if [ "$slope" = "2.00 1.00" ]; then
  pass "fitted slopes of C dT^2 and C dT: $slope"
else
  fail "fitted slopes of C dT^2 and C dT: $slope (expected 2.00 1.00)"
fi
ok "mrvi-plot stability" stab
png_ok "$out/stab_bounds.png"
png_ok "$out/stab_trace.png"
ok "mrvi-plot timing" timing
png_ok "$out/timing_total.png"
png_ok "$out/timing_per_step.png"

# --- readable figures ---
readable=$(output readable)
for c in q3-note q3-tilde q1-no-note dense-H dense-T range trend j-tol \
  conv-h stab-inf no-overlap; do
  case " $readable " in
    *" $c:True "*) pass "readable figure: $c" ;;
    *) fail "readable figure: $c (got: $readable)" ;;
  esac
done
ok "mrvi-plot all" all_fpu
png_ok "$tmp/all/fpu_energy.png"
png_ok "$tmp/all/stab_trace.png"

# --- still ---
ok "mrvi-plot still pendulum_chain" still_chain
png_ok "$out/chain_still.png"
ok "mrvi-plot still heavy_top" still_top
png_ok "$out/top_still.png"
still=$(output still)
case $still in
"True True True True True") pass "still: traces are the stored positions, anchors drawn from their stored points, directors the stored rotation, equal 3-D scales" ;;
*) fail "still: traces, directors or scales (got: $still)" ;;
esac
fails_with "still: a model of coordinates only" \
  "no particles or bodies\|needs particles" still_fpu

# --- errors ---
fails_with "missing input file" "no such file" err_missing
fails_with "missing dataset named" "/stability/midpoint_measured" err_broken
fails_with "run file given to convergence" "/convergence" err_conv
fails_with "no subcommand" "usage" err_none

test_finish
