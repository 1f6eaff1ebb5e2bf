#!/bin/bash
# The extended XYZ export read by a real reader, ASE (Debian python3-ase;
# doc/output.md advertises the file for ASE): every frame of `mrvi export
# --format xyz` read with ase.io.read(..., index=':') equals the run file
# read with h5py -- the number of frames, the time of each (atoms.info
# Time), every position to the last digit, the species (X, ASE's dummy
# element) and the extra columns rate and name.  2-D macro and micro nodes,
# every 3rd frame, 3-D; rigid bodies (the heavy top, 3-D, bodies alone; the
# flexible pendulum's slow arm and fast bars, 2-D, macro and micro nodes;
# the robot arm's fast particles and slow links, micro nodes) as their
# centres and director tips after the particles.
#
#   test_export_ase.sh MRVI_BINARY SOURCE_ROOT
#
# Skipped (exit 77) with a message when Debian's /usr/bin/python3 lacks ASE
# (apt-get install python3-ase) or h5py.

set -u

mrvi=${1:?usage: test_export_ase.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_export_ase.sh MRVI_BINARY SOURCE_ROOT}

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
if ! /usr/bin/python3 -c 'import ase.io' 2>/dev/null; then
  echo "skipped: ASE is not installed (Debian: apt-get install python3-ase);"
  echo "         the XYZ export is then not checked against ASE's reader"
  exit 77
fi
need_python ase.io h5py numpy
export MRVI_TESTS
MRVI_TESTS=$(cd "$(dirname "$0")" && pwd)
cd "$tmp" || exit 1

cat >check_ase.py <<'EOF'
"""check_ase.py FILE.xyz FILE.h5 EVERY GRID: read every frame with ASE and
compare with the run file (GRID macro or micro)."""
import os
import sys
import warnings

import ase.io
import numpy as np

sys.path.insert(0, os.environ["MRVI_TESTS"])
from run_positions import body_points, run_positions  # noqa: E402

xyz, h5, every, grid = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
with warnings.catch_warnings():
    warnings.simplefilter("error")  # a reader warning is a failure too
    frames = ase.io.read(xyz, index=":", format="extxyz")
t, pos, rate, names = run_positions(h5, grid)
bpos, brate, bnames = body_points(h5, grid, t)
nb = len(bnames)
pos = np.concatenate([pos, bpos], axis=1)
rate = np.concatenate([rate, brate])
names = names + bnames
rows = list(range(0, t.size, every))
if len(frames) != len(rows):
    print("FAIL ASE read %d frames, the file has %d" % (len(frames), len(rows)))
    sys.exit(1)
for atoms, k in zip(frames, rows):
    x = atoms.get_positions()
    checks = {
        "atoms": x.shape == pos[k].shape,
        "particle positions": np.array_equal(x[:x.shape[0] - nb],
                                             pos[k][:pos.shape[1] - nb]),
        "body points": x.shape == pos[k].shape and
        np.abs(x - pos[k]).max(initial=0.0) < 1e-14,
        "Time": atoms.info.get("Time") == t[k],
        "symbols X": set(atoms.get_chemical_symbols()) == {"X"},
        "rate": np.array_equal(atoms.arrays["rate"], rate),
        "name": list(atoms.arrays["name"]) == names,
        "no periodic cell": not atoms.pbc.any(),
    }
    bad = [c for c, ok in checks.items() if not ok]
    if bad:
        print("FAIL frame %d (t = %r): %s" % (k, t[k], ", ".join(bad)))
        sys.exit(1)
print("ok ASE read %d frames of %d particles and %d body points equal to %s" %
      (len(frames), len(names) - nb, nb,
       "/macro/q" if grid == "macro" else "/micro"))
EOF

# py_ok NAME ARGS...: check_ase.py prints only "ok ..." lines
py_ok() {
  local name=$1
  shift
  if "$py" check_ase.py "$@" >py.txt 2>&1 && ! grep -qv '^ok' py.txt; then
    pass "$name: $(cat py.txt)"
  else
    fail "$name"
    sed 's/^/     /' py.txt | tail -20
  fi
}

run_ok "mrvi run lattice (2-D, micro_slow)" "$mrvi" run \
  "$root/systems/lattice.yaml" -o lattice.h5 --set integrator.t_end=0.5 \
  --set output.micro_slow=true --quiet
run_ok "mrvi run spring_ring (3-D)" "$mrvi" run \
  "$root/systems/spring_ring.yaml" -o ring.h5 --set integrator.t_end=0.05 \
  --quiet

run_ok "export lattice.xyz" "$mrvi" export lattice.h5 -f xyz
py_ok "ASE: lattice, macro nodes" lattice.xyz lattice.h5 1 macro
run_ok "export every 3rd micro node" "$mrvi" export lattice.h5 -f xyz \
  --micro --every 3 -o micro3.xyz
py_ok "ASE: lattice, every 3rd micro node" micro3.xyz lattice.h5 3 micro
run_ok "export ring.xyz" "$mrvi" export ring.h5 -f xyz
py_ok "ASE: spring ring, 3-D" ring.xyz ring.h5 1 macro

run_ok "mrvi run heavy_top (3-D, a body alone)" "$mrvi" run \
  "$root/systems/heavy_top.yaml" -o top.h5 --set integrator.t_end=0.1 --quiet
run_ok "export top.xyz" "$mrvi" export top.h5 -f xyz
py_ok "ASE: heavy top's centre and director tips" top.xyz top.h5 1 macro
run_ok "mrvi run flexible_pendulum (2-D, slow and fast bodies)" "$mrvi" run \
  "$root/systems/flexible_pendulum.yaml" -o flex.h5 \
  --set integrator.t_end=0.02 --set output.micro=true --quiet
run_ok "export flex.xyz" "$mrvi" export flex.h5 -f xyz
py_ok "ASE: flexible pendulum, macro nodes" flex.xyz flex.h5 1 macro
run_ok "export flex micro" "$mrvi" export flex.h5 -f xyz --micro -o flexm.xyz
py_ok "ASE: flexible pendulum, micro nodes (fast bars move, the slow arm
  interpolated as (1 - m/p) x_j + (m/p) x_{j+1})" \
  flexm.xyz flex.h5 1 micro
run_ok "mrvi run robot_arm_payload (particles and bodies)" "$mrvi" run \
  "$root/systems/robot_arm_payload.yaml" -o arm.h5 \
  --set integrator.t_end=0.03 --set output.micro=true --quiet
run_ok "export arm micro" "$mrvi" export arm.h5 -f xyz --micro -o arm.xyz
py_ok "ASE: robot arm, particles then bodies, micro nodes" arm.xyz arm.h5 1 \
  micro

test_finish
