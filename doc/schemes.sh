#!/usr/bin/env bash
# Regenerate the measured tables of doc/schemes.md ("which scheme").
#
# Usage: doc/schemes.sh [BUILD_DIR]       (default: build)
#
# Runs every named scheme on systems/fpu.yaml, systems/spring_ring.yaml and
# systems/lattice.yaml with p in {1, 5, 10} and prints three tables:
#   1. runs at each file's own (the paper's) step size and horizon: how the
#      run ended, max relative energy error, Newton iterations, wall time;
#   2. accuracy against a fine single-rate reference (`mrvi converge`,
#      t <= 0.5) at that step size, and the observed order at small steps;
#   3. a scan of the macro step: the largest step of a list below which every
#      run completes with a relative energy error under 50 % (bounded) and
#      under 1 % (accurate).
# The tables are also written to doc/results/schemes.txt (no machine paths).
# Work files go to BUILD_DIR/schemes (not committed).  Takes about two
# minutes on two cores; wall times depend on the machine, ratios less so.
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
build=$(cd "${1:-$root/build}" && pwd)
mrvi=$build/mrvi
work=$build/schemes
[ -x "$mrvi" ] || { echo "no $mrvi: run meson compile -C ${1:-build} first" >&2; exit 1; }
/usr/bin/python3 -c 'import h5py, numpy' || { echo "needs python3-h5py" >&2; exit 1; }
mkdir -p "$work" "$root/doc/results"
cp "$root"/systems/fpu.yaml "$root"/systems/spring_ring.yaml "$root"/systems/lattice.yaml "$work"/
cd "$work"

/usr/bin/python3 - "$mrvi" <<'PY' | tee "$root/doc/results/schemes.txt"
import csv
import re
import subprocess
import sys

import h5py
import numpy as np

mrvi = sys.argv[1]
schemes = ["midpoint-midpoint", "trapezoidal-midpoint", "trapezoidal-trapezoidal",
           "explicit-slow", "fully-explicit"]
ps = [1, 5, 10]
# system: (paper's macro step, steps for the order fit, macro-step scan)
systems = {
    "fpu": (0.3, [0.01, 0.005],
            [0.3, 0.25, 0.2, 0.15, 0.1, 0.075, 0.05, 0.04, 0.03, 0.02, 0.01]),
    "spring_ring": (0.01, [0.0025, 0.00125],
                    [0.05, 0.04, 0.03, 0.02, 0.015, 0.01, 0.0075, 0.005, 0.0025]),
    "lattice": (0.05, [0.005, 0.0025],
                [0.4, 0.3, 0.2, 0.15, 0.1, 0.075, 0.05, 0.03, 0.02]),
}


def run(system, scheme, p, dT=None):
    """One `mrvi run`; returns (completed, t reached, max rel dH, Newton its, wall s)."""
    out = "%s-%s-p%d%s.h5" % (system, scheme, p, "" if dT is None else "-%g" % dT)
    cmd = [mrvi, "run", system + ".yaml", "-o", out, "--set", "output.xdmf=false",
           "--set", "output.micro=false", "--set", "integrator.scheme=" + scheme,
           "--set", "integrator.micro_steps=%d" % p]
    if dT is not None:
        cmd += ["--set", "integrator.macro_step=%r" % dT]
    r = subprocess.run(cmd, capture_output=True, text=True)
    m = re.search(r"wall time\s+([0-9.]+) s", r.stdout)
    wall = float(m.group(1)) if m else float("nan")
    with h5py.File(out, "r") as f:
        H = f["/macro/energy"][:]
        t = f["/macro/t"][:]
        its = int(f["/solver/iterations"][:].sum()) if len(H) > 1 else 0
        done = f.attrs["stop_reason"] == "completed"
    H = H[np.isfinite(H)]
    err = np.abs(H - H[0]).max() / abs(H[0]) if len(H) else float("inf")
    return done, t[-1], err, its, wall


print("== 1. runs at the files' step sizes (fpu dT = 0.3, t_end = 200; "
      "spring_ring dT = 0.01, t_end = 50; lattice dT = 0.05, t_end = 5)")
print("%-12s %-24s %3s %-18s %10s %8s %9s" % ("system", "scheme", "p", "ended",
                                              "max|dH/H0|", "Newton", "wall [s]"))
for system, (dT, _, _) in systems.items():
    for scheme in schemes:
        for p in ps:
            done, t, err, its, wall = run(system, scheme, p)
            ended = "completed" if done else "FAILED after t=%.4g" % t
            print("%-12s %-24s %3d %-18s %10.2e %8d %9.3f" % (system, scheme, p, ended,
                                                              err, its, wall))

print()
print("== 2. error against a fine single-rate reference, t <= 0.5 (mrvi converge):")
print("   e_q = max_k |q_k - q_ref(t_k)| on macro nodes at the file's dT;")
print("   order = observed order of e_q between the two small steps given")
print("%-12s %-24s %3s %10s %10s %6s" % ("system", "scheme", "p", "dT", "e_q^mac", "order"))
for system, (dT, small, _) in systems.items():
    for scheme in schemes:
        dts = ",".join("%r" % x for x in [dT] + small)
        for p in ps:
            tab = "conv-%s-%s-p%d" % (system, scheme, p)
            r = subprocess.run([mrvi, "converge", system + ".yaml", "--dt", dts,
                                "--p", str(p), "--quiet", "-o", tab + ".h5", "--csv",
                                tab + ".csv", "--set", "integrator.scheme=" + scheme],
                               capture_output=True, text=True)
            if r.returncode != 0:  # a run of the study failed (unstable)
                print("%-12s %-24s %3d %10g %10s %6s" % (system, scheme, p, dT, "failed", ""))
                continue
            e = [float(x["e_q_mac"]) for x in csv.DictReader(open(tab + ".csv"))]
            order = np.log(e[1] / e[2]) / np.log(2) if e[2] > 0 else float("nan")
            print("%-12s %-24s %3d %10g %10.2e %6.2f" % (system, scheme, p, dT, e[0], order))

print()
print("== 3. scan of the macro step over the file's t_end, p fixed (dt = dT/p shrinks")
print("   with dT).  Each cell: B / A, the largest dT of the scan such that every run")
print("   at that dT and below completed with max|dH/H0| < 50 % (B, bounded) and")
print("   < 1 % (A, accurate); '-': not even the smallest dT of the scan")
for system, (_, _, scan) in systems.items():
    print("   %s scan: %s" % (system, " ".join("%g" % x for x in scan)))
print("%-12s %-24s %14s %14s %14s" % ("system", "scheme", "p=1", "p=5", "p=10"))
for system, (_, _, scan) in systems.items():
    for scheme in schemes:
        cells = []
        for p in ps:
            best = {0.5: "-", 0.01: "-"}
            ok = {0.5: True, 0.01: True}
            for dT in sorted(scan):
                done, _, err, _, _ = run(system, scheme, p, dT)
                for tol in best:
                    ok[tol] = ok[tol] and done and err < tol
                    if ok[tol]:
                        best[tol] = "%g" % dT
                if not ok[0.5]:
                    break
            cells.append("%s / %s" % (best[0.5], best[0.01]))
        print("%-12s %-24s %14s %14s %14s" % (system, scheme, *cells))
