#!/usr/bin/env bash
# mrvi-plot animate with rigid bodies and joints (doc/output.md,
# "Animation"): the heavy top's GIF has one frame per kept node, shows the
# three director colours, the joint and the pivot, and its frame turns
# (the top precesses: the d1 segment's pixels move between frames); 3-D
# axes get equal scales; a 2-D pendulum animates too.
#
#   test_plot_bodies.sh MRVI_BINARY SOURCE_ROOT
#
# Skipped (exit 77) when Debian's /usr/bin/python3 lacks matplotlib or h5py.
set -u
mrvi=${1:?usage: test_plot_bodies.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_plot_bodies.sh MRVI_BINARY SOURCE_ROOT}
plot="$root/src/cli/mrvi-plot"
# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
need_python matplotlib h5py numpy PIL

run_ok "heavy top run" "$mrvi" run "$root/systems/heavy_top.yaml" \
  -o "$tmp/top.h5" -q --set integrator.t_end=1.6
run_ok "animate heavy top" "$py" "$plot" animate "$tmp/top.h5" \
  -o "$tmp/top.gif" --every 4
run_ok "pendulum run" "$mrvi" run "$root/systems/rigid_pendulum.yaml" \
  -o "$tmp/pend.h5" -q --set integrator.t_end=1
run_ok "animate pendulum (2-D)" "$py" "$plot" animate "$tmp/pend.h5" \
  -o "$tmp/pend.gif" --every 5

if "$py" - "$tmp" >"$tmp/log" 2>&1 <<'PY'; then
import math, sys
import numpy as np
from PIL import Image
tmp = sys.argv[1]
colors = {"d1": (214, 39, 40), "d2": (44, 160, 44), "d3": (31, 119, 180)}


def pixels(im, k, rgb):
    im.seek(k)
    a = np.asarray(im.convert("RGB")).astype(int)
    hit = np.abs(a - rgb).sum(2) < 40
    # not the legend's swatches (upper right in 3-D, right of the plot
    # in 2-D)
    hit[: int(a.shape[0] * 0.3), int(a.shape[1] * 0.55):] = False
    return np.argwhere(hit)


bad = []
for name, rows, every in (("top", 161, 4), ("pend", 101, 5)):
    im = Image.open("%s/%s.gif" % (tmp, name))
    if im.n_frames != math.ceil(rows / every):
        bad.append("%s: %d frames, want %d" % (name, im.n_frames,
                                                math.ceil(rows / every)))
    d = 3 if name == "top" else 2
    for c in list(colors)[:d]:
        if len(pixels(im, 0, colors[c])) < 20:
            bad.append("%s: no %s segment in frame 0" % (name, c))
    black = pixels(im, 0, (0, 0, 0))
    if len(black) < 30:
        bad.append("%s: no joint line or pivot" % name)
    # The frame turns: the d1 segment moves (top: a quarter precession
    # period pi / 4 later; pendulum: it swings).
    k = im.n_frames // 2
    p0 = pixels(im, 0, colors["d1"]).mean(0)
    p1 = pixels(im, k, colors["d1"]).mean(0)
    if np.linalg.norm(p1 - p0) < 5:
        bad.append("%s: the d1 segment did not move (%s -> %s)" % (name, p0,
                                                                  p1))
print("FAIL " + "; ".join(bad) if bad else
      "frames, director colours, joint and pivot, motion")
sys.exit(1 if bad else 0)
PY
  pass "GIFs show the bodies: $(tail -1 "$tmp/log")"
else
  fail "GIFs: $(tail -3 "$tmp/log")"
fi

# 3-D axes have equal scales: the animation's limits span one length.
if "$py" - "$plot" >"$tmp/log" 2>&1 <<'PY'; then
import sys
from importlib.machinery import SourceFileLoader
mp = SourceFileLoader("mrvi_plot", sys.argv[1]).load_module()
import numpy as np
fig = mp.plt.figure()
ax = fig.add_subplot(1, 1, 1, projection="3d")
mp.equal_3d_limits(ax, np.array([0, -1, 5]), np.array([4, 0, 5.5]), 0.1)
spans = [np.diff(g()).item() for g in (ax.get_xlim, ax.get_ylim, ax.get_zlim)]
ok = np.allclose(spans, 4.2) and np.allclose(ax.get_box_aspect(),
                                             ax.get_box_aspect()[0])
print("spans %s" % spans)
sys.exit(0 if ok else 1)
PY
  pass "3-D animation axes equal: $(tail -1 "$tmp/log")"
else
  fail "3-D animation axes: $(tail -3 "$tmp/log")"
fi

# On the micro grid a joint's point on a fast body moves with that body:
# flexible_pendulum's wrist joins the fast links upper (its first body) and
# lower, so at every micro row the drawn joint point is lower's point too
# (its arm in lower's frame taken at macro node 0), to the constraint
# tolerance; drawn at the macro node, it was off by the links' motion
# within a macro step.  A slow body is drawn where the scheme's slow rule
# sees it, as `mrvi export --micro` writes it: the slow arm (its centre, d1
# tip and the elbow, a point of the arm) at every micro row equals the
# interpolation (1 - m/p) x_k + (m/p) x_{k+1} that the writer stores in
# /micro/q_slow, to round-off; drawn at the last macro node (before
# 2026-11-28) it was off by the arm's motion within a macro step.
run_ok "flexible pendulum run (micro output)" "$mrvi" run \
  "$root/systems/flexible_pendulum.yaml" -o "$tmp/flex.h5" -q \
  --set integrator.t_end=0.2 --set output.micro=true \
  --set output.micro_slow=true
if "$py" - "$plot" "$tmp/flex.h5" >"$tmp/log" 2>&1 <<'PY'; then
import sys
from importlib.machinery import SourceFileLoader
import h5py
import numpy as np
mp = SourceFileLoader("mrvi_plot", sys.argv[1]).load_module()
with h5py.File(sys.argv[2], "r") as h5:
    b = mp.animation_bodies(h5)
    names = [mp.text(n) for n in h5["bodies/name"][()]]
    col = [int(c) for c in h5["bodies/column"][()]]
    rate = h5["model/rate"][()]
    qs, tm, tM = (h5[k][()] for k in ("micro/q_slow", "micro/t", "macro/t"))
fig = mp.plt.figure()
ax = fig.add_subplot(1, 1, 1)
artists = {"moving": [], "handles": []}
update = mp.body_artists(ax, b, artists, tM)
d = b["d"]
frames, joints = artists["moving"][0], artists["moving"][d]


def joint_of(body):
    """The first joint of `body` (as body A) to another body."""
    return [k for k in range(b["ja"].size)
            if names[b["ja"][k]] == body and b["jb"][k] >= 0][0]


def drawn_joint_points():
    """Per joint its drawn point: segments [phi_A, x] and, to a body,
    [x, phi_B]."""
    segs = [np.asarray(s) for s in joints.get_segments()]
    k, xs = 0, []
    for jj in range(b["ja"].size):
        xs.append(segs[k][1])
        k += 2 if b["jb"][jj] >= 0 else 1
    return xs


wrist, elbow = joint_of("upper"), joint_of("arm")
lo, arm = b["jb"][wrist], names.index("arm")
f = list(b["fast"]).index(lo)
lever_lo = b["rot"][0][lo].T @ (b["jpos"][0, wrist] - b["pos"][0][lo])
lever_arm = b["rot"][0][arm].T @ (b["jpos"][0, elbow] - b["pos"][0][arm])
# the arm's centre and directors in /micro/q_slow (slow columns in order)
slot = {c: i for i, c in enumerate(np.flatnonzero(rate == 0))}
cols = [[slot[col[arm] + i * d + a] for a in range(d)] for i in range(d + 1)]
gap, moved, sgap, stale = 0.0, 0.0, 0.0, 0.0
for row in range(1, b["mpos"].shape[0]):
    node = max(0, int(np.searchsorted(tM, tm[row] + 1e-12)) - 1)
    update(node, row, tm[row])
    xs = drawn_joint_points()
    want = b["mpos"][row, f] + b["mrot"][row, f] @ lever_lo
    gap = max(gap, np.linalg.norm(xs[wrist] - want))
    moved = max(moved, np.linalg.norm(b["jpos"][node, wrist] - want))
    phi = qs[row, cols[0]]
    R = np.column_stack([qs[row, c] for c in cols[1:]])
    seg = np.asarray(frames.get_segments()[arm])
    sgap = max(sgap, np.linalg.norm(seg[0] - phi),
               np.linalg.norm(seg[1] - (phi + b["scale"] * R[:, 0])),
               np.linalg.norm(xs[elbow] - (phi + R @ lever_arm)))
    stale = max(stale, np.linalg.norm(b["pos"][node][arm] - phi))
ok = gap <= 1e-8 and moved > 1e3 * max(gap, 1e-15)
sok = sgap <= 1e-12 and stale > 1e6 * max(sgap, 1e-18)
print(("" if ok else "FAIL ") + "wrist point on lower within %.1e at every "
      "micro row (macro-node point off by up to %.1e); " % (gap, moved) +
      ("" if sok else "FAIL ") + "slow arm (centre, d1 tip, elbow) within "
      "%.1e of /micro/q_slow (its macro-node pose off by up to %.1e)"
      % (sgap, stale))
sys.exit(0 if ok and sok else 1)
PY
  pass "joint points follow fast bodies, slow bodies interpolated: $(tail -1 "$tmp/log")"
else
  fail "bodies on the micro grid: $(tail -3 "$tmp/log")"
fi

# mrvi-plot optimize with body terminal conditions (attitude, angular
# velocity): their rows carry the body's first column but are no target of
# it, so no coordinate panel and no trajectory figure (the reorientation's
# actuators are body torques, no column); the attitude figure draws them.
# Its angle curve is |rotation vector of R_target^T R(t)|, checked here
# against the angle computed from /bodies/rotation and the target of the
# description by quaternion (2 atan2(|v|, w)), to 1e-12 at every macro
# node; the omega lines are /bodies/angular_velocity, the targets the
# angular_velocity rows, the dashed line the terminal tolerance.
run_ok "optimize reorientation" "$mrvi" optimize \
  "$root/systems/ocp_reorient.yaml" -o "$tmp/reor.h5" -q
run_ok "plot optimize (body terminals)" "$py" "$plot" optimize \
  "$tmp/reor.h5" -o "$tmp/reor"
if "$py" - "$plot" "$tmp/reor.h5" >"$tmp/log" 2>&1 <<'PY'; then
import math, sys
from importlib.machinery import SourceFileLoader
import h5py
import numpy as np
mp = SourceFileLoader("mrvi_plot", sys.argv[1]).load_module()
bad = []
with h5py.File(sys.argv[2], "r") as h5:
    opt = mp.Optimal(h5)
    cols = mp.ocp_coordinates(opt)
    fig = mp.attitude_figure(opt, mp.attitude_series(opt))
    R = h5["bodies/rotation"][:, 0]
    W = h5["bodies/angular_velocity"][:, 0]
    tol = h5["optimizer"].attrs["terminal_tolerance"]
# The target of systems/ocp_reorient.yaml: 2 rad about (1, 1, 1)/sqrt 3.
k = np.ones(3) / math.sqrt(3.0)
K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
Rt = np.eye(3) + math.sin(2.0) * K + (1 - math.cos(2.0)) * K @ K
want = []
for Rk in R:
    A = Rt.T @ Rk
    w = math.sqrt(max(1.0 + np.trace(A), 0.0)) / 2.0
    v = np.array([A[2, 1] - A[1, 2], A[0, 2] - A[2, 0],
                  A[1, 0] - A[0, 1]]) / (4.0 * w)
    want.append(2.0 * math.atan2(np.linalg.norm(v), w))
want = np.array(want)
if opt.terminal:
    bad.append("coordinate terminals %s" % opt.terminal)
if len(opt.body_rows) != 6:
    bad.append("%d body terminal rows, want 6" % len(opt.body_rows))
if cols:
    bad.append("coordinate panels %s" % cols)
ax_angle, ax_omega = fig.axes[0], fig.axes[1]
line = ax_angle.get_lines()[0]
got = np.asarray(line.get_ydata(), dtype=float)
err = np.max(np.abs(got - want)) if got.size == want.size else np.inf
if not err <= 1e-12:
    bad.append("drawn angle differs from /bodies/rotation by %s" % err)
if not abs(got[-1] - want[-1]) <= 1e-12 or not want[0] > 1.9:
    bad.append("final angle %s, want %s (start %s)"
               % (got[-1], want[-1], want[0]))
tl = [l for l in ax_angle.get_lines() if l.get_label().startswith("tol")]
if len(tl) != 1 or tl[0].get_ydata()[0] != tol:
    bad.append("tolerance line %s" % [l.get_ydata() for l in tl])
om = ax_omega.get_lines()
if len(om) != 6 or any(not np.array_equal(om[j].get_ydata(), W[:, j])
                       for j in range(3)) or \
        any(list(om[j].get_ydata()) != [0.0] for j in range(3, 6)):
    bad.append("omega lines/targets differ from the file")
print("FAIL " + "; ".join(bad) if bad else
      "6 body rows; angle = quaternion angle to %.1e, final %.3g rad, "
      "start %.3g" % (err, got[-1], want[0]))
sys.exit(1 if bad else 0)
PY
  pass "optimize attitude panel: $(tail -1 "$tmp/log")"
else
  fail "optimize attitude panel: $(tail -3 "$tmp/log")"
fi
if [ -e "$tmp/reor/reor_trajectory.png" ]; then
  fail "a trajectory figure was drawn for body-only terminal conditions"
else
  pass "no trajectory figure for body-only terminal conditions"
fi
if [ -s "$tmp/reor/reor_attitude.png" ]; then
  pass "attitude figure written"
else
  fail "no attitude figure for body terminal conditions"
fi

# A target changed by --set (1 rad instead of the description's 2) is the
# one drawn: mrvi optimize stores R_target in /control/terminal_attitude,
# so the angle starts at 1 and ends at the terminal tolerance (drawn from
# the description's target it would end near 1 rad).
run_ok "optimize reorientation, target by --set" "$mrvi" optimize \
  "$root/systems/ocp_reorient.yaml" -o "$tmp/reor1.h5" -q \
  --set control.terminal.0.attitude.angle=1
if "$py" - "$plot" "$tmp/reor1.h5" >"$tmp/log" 2>&1 <<'PY'; then
import sys
from importlib.machinery import SourceFileLoader
import h5py
import numpy as np
mp = SourceFileLoader("mrvi_plot", sys.argv[1]).load_module()
with h5py.File(sys.argv[2], "r") as h5:
    opt = mp.Optimal(h5)
    (name, t, angle, omega, kinds), = mp.attitude_series(opt)
    tol = h5["optimizer"].attrs["terminal_tolerance"]
ok = abs(angle[0] - 1.0) <= 1e-12 and angle[-1] <= tol
print(("" if ok else "FAIL ") + "start %.15g rad, final %.3g (tolerance %.1g)"
      % (angle[0], angle[-1], tol))
sys.exit(0 if ok else 1)
PY
  pass "attitude target from --set drawn: $(tail -1 "$tmp/log")"
else
  fail "attitude target from --set: $(tail -3 "$tmp/log")"
fi

# Crafted files: a description that is not YAML, or without the attitude
# (files without /control/terminal_attitude, as earlier versions wrote),
# a stored target that is not a rotation or of the wrong shape, or a
# rotation of the wrong shape: an error naming the dataset, no traceback.
craft() {
  cp "$tmp/reor.h5" "$tmp/$1.h5"
  "$py" - "$tmp/$1.h5" "$2" "$3" <<'PY'
import sys
import h5py
import numpy as np
with h5py.File(sys.argv[1], "r+") as h5:
    if sys.argv[2] == "description":
        del h5["control/terminal_attitude"]
        del h5["model/description"]
        h5["model/description"] = np.array([sys.argv[3].encode()])
    elif sys.argv[2] == "stored":
        a = h5["control/terminal_attitude"][()]
        del h5["control/terminal_attitude"]
        h5["control/terminal_attitude"] = (
            2.0 * a if sys.argv[3] == "scaled" else a[:, :4])
    else:
        del h5["bodies/rotation"]
        h5["bodies/rotation"] = np.zeros((3, 1, 3, 2))
PY
}
for c in "notyaml|description|name: [unclosed|unreadable as YAML" \
         "noatt|description|name: x|no 3 x 3 terminal attitude" \
         "notrot|stored|scaled|terminal_attitude' row 0 is not" \
         "attshape|stored|cut|terminal_attitude' has shape" \
         "shape|rotation||bodies/rotation"; do
  IFS='|' read -r n what val pat <<<"$c"
  craft "$n" "$what" "$val"
  if "$py" "$plot" optimize "$tmp/$n.h5" -o "$tmp/reor" >"$tmp/log" 2>&1; then
    fail "crafted $n: exit 0"
  elif grep -q Traceback "$tmp/log" || ! grep -q "$pat" "$tmp/log"; then
    fail "crafted $n: $(tail -2 "$tmp/log")"
  else
    pass "crafted $n refused: $(grep -m1 "$pat" "$tmp/log")"
  fi
done

test_finish
