#!/usr/bin/env bash
# Regenerate the figures of doc/batch.md (doc/figures/batch_*.png):
#
#   batch_fpu_ensemble.png    the FPU (systems/fpu.yaml, t_end 200, the
#                             paper's dT = 0.3, p = 10) over 64 random
#                             initial energies (--velocity-std 0.5), per
#                             scheme: the maximal relative energy error of
#                             every case against its initial energy, and
#                             their distribution;
#   batch_multistart.png      64 starts of the gantry crane's optimal
#                             control (systems/ocp_gantry_crane.yaml,
#                             --control-std 5): the cost each start reached
#                             (sorted) and the controls of the distinct
#                             local optima.
#
# Usage: doc/batch_figures.sh [BUILD_DIR]       (default: build)
#
# Needs BUILD_DIR/mrvi and Debian's python3-matplotlib and python3-h5py;
# about a minute on 2 cores.
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
build=$(cd "${1:-$root/build}" && pwd)
mrvi=$build/mrvi
py=/usr/bin/python3
figs=$root/doc/figures
work=$build/batch_figures
[ -x "$mrvi" ] || { echo "no $mrvi: run meson compile -C ${1:-build} first" >&2; exit 1; }
"$py" -c 'import matplotlib, h5py' || { echo "needs python3-matplotlib and python3-h5py" >&2; exit 1; }
rm -rf "$work"
mkdir -p "$work" "$figs"
cd "$work"

"$mrvi" batch "$root/systems/fpu.yaml" -o fpu.h5 -q \
  --vary integrator.scheme=midpoint-midpoint,trapezoidal-midpoint \
  --vary integrator.micro_steps=10 --seeds 64 --velocity-std 0.5
# Cases that do not converge are part of the picture: exit 2 is fine.
"$mrvi" batch "$root/systems/ocp_gantry_crane.yaml" -o crane.h5 -q \
  --optimize --seeds 64 --control-std 5 || [ $? = 2 ]

FIGS=$figs "$py" - <<'EOF'
import os
import h5py
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

figs = os.environ["FIGS"]

# --- FPU ensemble: energy error against initial energy, per scheme ---
with h5py.File("fpu.h5") as f:
    over = [o.decode().split("\n")[0].split("=", 1)[1] for o in f["/cases/overrides"][:]]
    err = f["/cases/energy_error"][:]
    status = f["/cases/status"][:]
    e0 = np.array([f["/runs/case_%04d/macro/energy" % c][0] for c in range(len(err))])
schemes = sorted(set(over))
fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
for k, s in enumerate(schemes):
    sel = np.array([o == s for o in over]) & (status == 1)
    a.loglog(e0[sel], err[sel], "o", ms=4, label="%s (%d cases)" % (s, sel.sum()))
    b.hist(np.log10(err[sel]), bins=16, alpha=0.6, label=s)
a.set_xlabel("initial energy")
a.set_ylabel("max relative energy error")
a.set_title("FPU, dT = 0.3, p = 10, 64 random initial velocities")
a.legend(fontsize=8)
b.set_xlabel("log10 max relative energy error")
b.set_ylabel("cases")
b.set_title("distribution per scheme")
b.legend(fontsize=8)
fig.tight_layout()
fig.savefig(os.path.join(figs, "batch_fpu_ensemble.png"), dpi=110)
for s in schemes:
    sel = np.array([o == s for o in over]) & (status == 1)
    print("fpu %s: %d completed, energy error median %.3g, range %.3g .. %.3g"
          % (s, sel.sum(), np.median(err[sel]), err[sel].min(), err[sel].max()))

# --- multi-start: sorted costs, and the controls of the distinct optima ---
with h5py.File("crane.h5") as f:
    J = f["/cases/cost"][:]
    status = f["/cases/status"][:]
    best = int(f["/best_case"][()])
    order = np.argsort(J)
    optima = {}
    for c in order:
        if status[c] == 1:
            key = round(float(J[c]), 4)
            if key not in optima:
                g = f["/runs/case_%04d/control" % c]
                optima[key] = (g["t"][:], g["u"][:, 0])
fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
x = np.arange(len(J))
ok = status[order] == 1
a.semilogy(x[ok], J[order][ok], "o", ms=4, label="converged")
a.semilogy(x[~ok], J[order][~ok], "x", ms=6, color="tab:red",
           label="evaluation limit")
a.set_xlabel("start (sorted by cost)")
a.set_ylabel("cost J")
a.set_title("gantry crane: 64 starts, best case %d" % best)
a.legend(fontsize=8)
for k, (key, (t, u)) in enumerate(sorted(optima.items())):
    b.step(t, u, where="post", lw=2.0 if k == 0 else 0.8,
           label="J = %.4g" % key)
b.set_xlabel("t")
b.set_ylabel("cart force u")
b.set_title("controls of the distinct local optima")
b.legend(fontsize=7, ncol=2)
fig.tight_layout()
fig.savefig(os.path.join(figs, "batch_multistart.png"), dpi=110)
print("crane: %d converged, %d distinct optima (J %s), best case %d"
      % ((status == 1).sum(), len(optima),
         ", ".join("%.4g" % k for k in sorted(optima)), best))
EOF
