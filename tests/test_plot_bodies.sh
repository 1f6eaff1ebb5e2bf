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
import importlib.machinery, importlib.util, sys
loader = importlib.machinery.SourceFileLoader("mrvi_plot", sys.argv[1])
spec = importlib.util.spec_from_loader("mrvi_plot", loader)
mp = importlib.util.module_from_spec(spec)
loader.exec_module(mp)
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

# mrvi-plot optimize with body terminal conditions (attitude, angular
# velocity): their rows carry the body's first column but are no target of
# it; they are counted, not drawn as targets on that coordinate.  The
# reorientation's actuators are body torques (no column), so no coordinate
# panel remains and no trajectory figure is written.
run_ok "optimize reorientation" "$mrvi" optimize \
  "$root/systems/ocp_reorient.yaml" -o "$tmp/reor.h5" -q
run_ok "plot optimize (body terminals)" "$py" "$plot" optimize \
  "$tmp/reor.h5" -o "$tmp/reor"
if "$py" - "$plot" "$tmp/reor.h5" >"$tmp/log" 2>&1 <<'PY'; then
import importlib.machinery, importlib.util, sys
import h5py
loader = importlib.machinery.SourceFileLoader("mrvi_plot", sys.argv[1])
spec = importlib.util.spec_from_loader("mrvi_plot", loader)
mp = importlib.util.module_from_spec(spec)
loader.exec_module(mp)
with h5py.File(sys.argv[2], "r") as h5:
    opt = mp.Optimal(h5)
    cols = mp.ocp_coordinates(opt)
bad = []
if opt.terminal:
    bad.append("coordinate terminals %s" % opt.terminal)
if opt.body_terminals != 6:
    bad.append("%d body terminal rows, want 6" % opt.body_terminals)
if cols:
    bad.append("coordinate panels %s" % cols)
print("FAIL " + "; ".join(bad) if bad else
      "6 body rows counted, no coordinate target")
sys.exit(1 if bad else 0)
PY
  pass "optimize plot skips body terminals: $(tail -1 "$tmp/log")"
else
  fail "optimize plot with body terminals: $(tail -3 "$tmp/log")"
fi
if [ -e "$tmp/reor/reor_trajectory.png" ]; then
  fail "a trajectory figure was drawn for body-only terminal conditions"
else
  pass "no trajectory figure for body-only terminal conditions"
fi

test_finish
