#!/usr/bin/env bash
# Body and joint outputs (doc/output.md, "Rigid bodies" and "Joints";
# doc/multibody.md, "Angular velocity" and "Joint reactions"), checked
# against what is known exactly:
#
#   - /bodies/angular_velocity of an isotropic free body equals its initial
#     omega to round-off (the discrete map conserves L = J omega exactly);
#     of an asymmetric free body with projected momenta, 1/2 omega.J omega
#     is the kinetic energy of rotation to round-off;
#   - the heavy top in steady precession: omega = w_p e3 + w_s d3 (d3 of the
#     exact motion) to the truncation error, order 2 by halving dT;
#   - 2-D: the pendulum's omega against the central difference of its
#     angle, O(dT^2);
#   - /joints/force of a rigid pendulum hanging at rest is M g up, its
#     torque 0, in both constraint forms; the spherical joint's torque
#     about its point is 0; on a swinging pendulum the two forms give the
#     same reactions to the solver tolerance;
#   - /micro/bodies/* of a fast body: every p-th row equals /bodies/*.
#
#   test_body_output.sh MRVI_BINARY SOURCE_ROOT
#
# Needs /usr/bin/python3 with h5py and numpy (exit 77 = skipped otherwise).
set -u
mrvi=${1:?usage: test_body_output.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_body_output.sh MRVI_BINARY SOURCE_ROOT}
# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
need_python h5py numpy

top=$root/systems/heavy_top.yaml
pend=$root/systems/rigid_pendulum.yaml

# check NAME PYTHON-EXPRESSION-SCRIPT FILES...: the script prints a line
# and exits 0 (pass) or 1 (fail).
check() {
  local name=$1 script=$2
  shift 2
  if "$py" -c "$script" "$@" >"$tmp/log" 2>&1; then
    pass "$name: $(tail -1 "$tmp/log")"
  else
    fail "$name: $(tail -3 "$tmp/log")"
  fi
}

# --- free bodies (no gravity, no joints) ---
cat >"$tmp/free.yaml" <<'YAML'
name: free
dimension: 3
bodies:
  - {name: iso, mass: 2, inertia: [1.5, 1.5, 1.5], position: [0, 0, 0],
     orientation: {axis: [0.2672612419124244, 0.5345224838248488, 0.8017837257372732], angle: 0.7},
     velocity: [0.1, 0, 0], angular_velocity: [0.3, -0.7, 1.1]}
  - {name: asym, mass: 1, inertia: [1, 2, 2.5], position: [5, 0, 0],
     orientation: {axis: [0, 0.7071067811865476, 0.7071067811865476], angle: 0.4},
     angular_velocity: [1.2, -0.4, 0.8]}
integrator:
  scheme: midpoint-midpoint
  macro_step: 0.05
  micro_steps: 1
  t_end: 10
  newton: {tolerance: 1.0e-12, max_iterations: 20}
  constraints: {form: multipliers, tolerance: 1.0e-13, projection: true}
output: {file: free.h5, every: 1, micro: false}
YAML
run_ok "free bodies run" "$mrvi" run "$tmp/free.yaml" -o "$tmp/free.h5" -q
check "isotropic body: omega = omega_0" '
import sys, h5py, numpy as np
f = h5py.File(sys.argv[1])
w = f["bodies/angular_velocity"][:, 0, :]
e = np.abs(w - [0.3, -0.7, 1.1]).max()
print("shape %s, max |omega - omega_0| = %.1e" % (f["bodies/angular_velocity"].shape, e))
sys.exit(0 if f["bodies/angular_velocity"].shape == (201, 2, 3) and e < 1e-12 else 1)
' "$tmp/free.h5"
check "asymmetric body: 1/2 omega.J omega = rotational kinetic energy" '
import sys, h5py, numpy as np
f = h5py.File(sys.argv[1])
J = np.array([1, 2, 2.5]); E = (J.sum() - 2 * J) / 2
w = f["bodies/angular_velocity"][:, 1, :]
R = f["bodies/rotation"][:, 1]
c = int(f["bodies/column"][1]); p = f["macro/p"][:, c + 3:c + 12].reshape(-1, 3, 3)
T = 0.5 * sum((p[:, i] ** 2).sum(1) / E[i] for i in range(3))
wb = np.einsum("kai,ka->ki", R, w)  # body-frame components R^T omega
e = np.abs(0.5 * (J * wb ** 2).sum(1) - T).max() / T.max()
print("max relative difference %.1e" % e)
sys.exit(0 if e < 1e-12 else 1)
' "$tmp/free.h5"

# --- heavy top: omega against the steady precession, order 2 ---
for h in 0.02 0.01 0.005; do
  run_ok "heavy top dT = $h" "$mrvi" run "$top" -o "$tmp/top$h.h5" -q \
    --set integrator.t_end=2 --set integrator.macro_step=$h
done
check "heavy top: omega = w_p e3 + w_s d3, order 2" '
import sys, h5py, numpy as np
a, wp, ws = 0.5, 2.0, 9.052582561890373
errs = []
for path in sys.argv[1:]:
    f = h5py.File(path)
    t = f["macro/t"][:]; w = f["bodies/angular_velocity"][:, 0, :]
    d3 = np.stack([np.sin(a) * np.cos(wp * t), np.sin(a) * np.sin(wp * t),
                   np.cos(a) * np.ones_like(t)], 1)
    errs.append(np.abs(w - (wp * np.array([0, 0, 1.0]) + ws * d3)).max())
    xp = np.abs(f["joints/position"][:]).max()  # the pivot: the origin
    if xp > 1e-10:
        print("joint point %.1e from the pivot" % xp); sys.exit(1)
    tq = np.abs(f["joints/torque"][:-1]).max()
    if tq > 1e-12 or not np.isnan(f["joints/torque"][-1]).all():
        print("spherical torque %.1e (last row must be NaN)" % tq); sys.exit(1)
orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
print("errors %s, orders %s; spherical torque 0, joint point at the pivot" % (
    " ".join("%.2e" % e for e in errs), " ".join("%.2f" % o for o in orders)))
sys.exit(0 if all(abs(o - 2) < 0.1 for o in orders) and errs[-1] < 3e-3 else 1)
' "$tmp/top0.02.h5" "$tmp/top0.01.h5" "$tmp/top0.005.h5"

# --- 2-D: the pendulum's omega against its angle ---
run_ok "pendulum run" "$mrvi" run "$pend" -o "$tmp/pend.h5" -q \
  --set integrator.t_end=2
check "2-D pendulum: omega = dtheta/dt" '
import sys, h5py, numpy as np
f = h5py.File(sys.argv[1])
R = f["bodies/rotation"][:, 0]; w = f["bodies/angular_velocity"][:, 0, 0]
th = np.unwrap(np.arctan2(R[:, 1, 0], R[:, 0, 0])); h = 0.01
e = np.abs((th[2:] - th[:-2]) / (2 * h) - w[1:-1]).max()
print("shape %s, max |omega - central difference| = %.1e (|omega| up to %.1f)"
      % (f["bodies/angular_velocity"].shape, e, np.abs(w).max()))
sys.exit(0 if f["bodies/angular_velocity"].shape == (201, 1, 1) and e < 5e-3 else 1)
' "$tmp/pend.h5"

# --- joint reactions ---
sed -e 's/position: \[0.4330127018922193, -0.25\]/position: [0, -0.5]/' \
  -e 's/orientation: 1.0471975511965976/orientation: 0/' "$pend" \
  >"$tmp/rest.yaml"
for form in multipliers null-space; do
  run_ok "pendulum at rest, $form" "$mrvi" run "$tmp/rest.yaml" \
    -o "$tmp/rest-$form.h5" -q --set integrator.t_end=1 \
    --set integrator.constraints.form=$form
  check "pendulum at rest, $form: reaction M g up, no torque" '
import sys, h5py, numpy as np
f = h5py.File(sys.argv[1])
F = f["joints/force"][:, 0]; T = f["joints/torque"][:, 0]
names = [s.decode() for s in f["joints/name"][:]]
# Rows 1 .. M-2: node 0 carries the first half-impulse only (as
# /macro/lambda), the last row is NaN.
e = np.abs(F[1:-1] - [0, 9.81]).max(); et = np.abs(T[1:-1]).max()
print("joints %s, max |F - (0, M g)| = %.1e, max |torque| = %.1e" % (names, e, et))
ok = names == ["hinge"] and list(f["joints/body_b"][:]) == [-1]
sys.exit(0 if ok and e < 1e-9 and et < 1e-9 and np.isnan(F[-1]).all() else 1)
' "$tmp/rest-$form.h5"
done
for form in multipliers null-space; do
  run_ok "swinging pendulum, $form" "$mrvi" run "$pend" -o "$tmp/sw-$form.h5" \
    -q --set integrator.t_end=2 --set integrator.constraints.form=$form
done
check "swinging pendulum: both forms give the same reactions" '
import sys, h5py, numpy as np
a, b = h5py.File(sys.argv[1]), h5py.File(sys.argv[2])
d = max(np.abs(a[k][:-1] - b[k][:-1]).max() for k in ("joints/force", "joints/torque"))
F = a["joints/force"][1:-1, 0]
# Newton: F = M (a_cm - g); the centre of mass moves on a circle of 0.5.
print("max difference %.1e (|F| up to %.1f)" % (d, np.abs(F).max()))
sys.exit(0 if d < 1e-8 and np.abs(F).max() > 9.81 else 1)
' "$tmp/sw-multipliers.h5" "$tmp/sw-null-space.h5"
check "swinging pendulum: F = M (a_cm - g) (central difference of phi)" '
import sys, h5py, numpy as np
f = h5py.File(sys.argv[1])
x = f["bodies/position"][:, 0]; F = f["joints/force"][:, 0]; h = 0.01
acc = (x[2:] - 2 * x[1:-1] + x[:-2]) / h ** 2
e = np.abs(F[1:-1] - (acc - [0, -9.81])).max()
print("max |F - M (a - g)| = %.1e" % e)
sys.exit(0 if e < 1e-8 else 1)
' "$tmp/sw-multipliers.h5"

# --- micro outputs of a fast body ---
sed -e 's/^    mass: 1$/    mass: 1\n    rate: fast/' "$top" >"$tmp/fast.yaml"
run_ok "fast top, micro output" "$mrvi" run "$tmp/fast.yaml" \
  -o "$tmp/fast.h5" -q --set integrator.t_end=1 \
  --set integrator.micro_steps=4 --set output.micro=true
check "fast top: /micro/bodies rows k p = /bodies rows k" '
import sys, h5py, numpy as np
f = h5py.File(sys.argv[1]); p = 4
shapes = [f["micro/bodies/" + k].shape for k in ("position", "rotation", "angular_velocity")]
e = max(np.abs(f["micro/bodies/" + k][::p] - f["bodies/" + k][:]).max()
        for k in ("position", "rotation", "angular_velocity"))
qf = f["micro/q_fast"][:, 0:3]
e2 = np.abs(f["micro/bodies/position"][:, 0] - qf).max()
print("shapes %s, fast %s, max difference %.1e, %.1e" % (shapes, list(f["bodies/fast"][:]), e, e2))
sys.exit(0 if shapes == [(401, 1, 3), (401, 1, 3, 3), (401, 1, 3)]
         and list(f["bodies/fast"][:]) == [0] and e == 0 and e2 == 0 else 1)
' "$tmp/fast.h5"

# --- XDMF: each body as its frame, each joint as lines ---
run_ok "heavy top with XDMF" "$mrvi" run "$top" -o "$tmp/x.h5" -q \
  --set integrator.t_end=0.5
check "XDMF bodies: frames and joint lines match /bodies and /joints" '
import sys, h5py, numpy as np, xml.etree.ElementTree as ET
f = h5py.File(sys.argv[1]); root = ET.parse(sys.argv[2]).getroot()
grids = [g for g in root.iter("Grid") if g.get("GridType") == "Uniform"]
pos, rot = f["bodies/position"][:], f["bodies/rotation"][:]
jp = f["joints/position"][:]
ok, err = len(grids) == len(f["macro/t"]), 0.0
for k, g in enumerate(grids):
    conn = np.array(g.find("Topology/DataItem").text.split(), int).reshape(-1, 2)
    x = np.array(g.find("Geometry/DataItem").text.split(), float).reshape(-1, 3)
    part = np.array(g.find("Attribute/DataItem").text.split(), int)
    s = np.linalg.norm(x[1] - x[0])  # the segment length
    want = np.vstack([pos[k, 0], pos[k, 0] + s * rot[k, 0].T, jp[k, 0]])
    err = max(err, np.abs(x - want).max(), abs(float(g.find("Time").get("Value")) - f["macro/t"][k]))
    ok &= conn.tolist() == [[0, 1], [0, 2], [0, 3], [0, 4]] and part.tolist() == [1, 2, 3, 0]
print("%d grids, max |point - (phi, phi + s d_i, x_joint)| = %.1e, s = %g" % (len(grids), err, s))
sys.exit(0 if ok and err < 1e-14 and abs(s - 0.25) < 1e-12 else 1)
' "$tmp/x.h5" "$tmp/x.xdmf"
# --- XYZ: the body as its centre and director tips (no ASE needed) ---
# Each frame: the count line 4 (no particles, 1 + 3 points), the comment
# line, then top, top.d1, top.d2, top.d3 with species X (default), body
# d1 d2 d3 (--species rate) or the names (--species name); each tip 0.25
# (s, as in the XDMF file) from the centre; a frame per macro node.
frames=$("$py" -c 'import sys, h5py; print(len(h5py.File(sys.argv[1])["macro/t"]))' "$tmp/x.h5")
for kind in x rate name; do
  case $kind in
  x) want="X X X X" ;;
  rate) want="body d1 d2 d3" ;;
  name) want="top top.d1 top.d2 top.d3" ;;
  esac
  if ! "$mrvi" export "$tmp/x.h5" -f xyz --species "$kind" \
    -o "$tmp/x-$kind.xyz" >"$tmp/out.txt" 2>&1; then
    fail "XYZ of the heavy top (--species $kind): $(head -1 "$tmp/out.txt")"
    continue
  fi
  got=$(awk -v want="$want" -v frames="$frames" '
    function bad(why) { print why; err = 1; exit 1 }
    (NR - 1) % 6 == 0 { if ($0 != "4") bad("line " NR ": count " $0); n++ }
    (NR - 1) % 6 == 1 && $1 !~ /^Properties=species:S:1:pos:R:3:rate:I:1:name:S:1$/ {
      bad("line " NR ": " $1) }
    (NR - 1) % 6 >= 2 {
      i = (NR - 1) % 6 - 2
      sp = sp (i ? " " : "") $1
      nm = nm (i ? " " : "") $6
      if (i == 0) { cx = $2; cy = $3; cz = $4 }
      else {
        l = sqrt(($2 - cx)^2 + ($3 - cy)^2 + ($4 - cz)^2)
        if (l < 0.25 - 1e-12 || l > 0.25 + 1e-12) bad("line " NR ": tip at " l)
      }
      if (NF != 6 || $5 != "0") bad("line " NR ": " $0)
      if (i == 3) {
        if (sp != want) bad("species " sp)
        if (nm != "top top.d1 top.d2 top.d3") bad("names " nm)
        sp = nm = ""
      }
    }
    END { if (!err && (n != frames || NR != 6 * frames)) print n " frames, " NR " lines for " frames " nodes"
          else if (!err) print "ok" }' "$tmp/x-$kind.xyz")
  [ "$got" = ok ] &&
    pass "XYZ of the heavy top (--species $kind): $frames frames of 4 points, species $want" ||
    fail "XYZ of the heavy top (--species $kind): $got"
done

test_finish
