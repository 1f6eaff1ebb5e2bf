#!/usr/bin/env bash
# Named perturbations of mrvi batch (doc/batch.md, Ensembles): a thermal
# ensemble hits its temperature 2 KE / N_f = T to round-off with zero net
# momentum, on a free lattice of particles (spring_ring) and on a
# constrained molecule (triatomic: two rigid bonds), and with momenta drawn
# per coordinate, nothing removed, on plain coordinates (fpu), whose perturbed
# positions stay on the constraints; uniform position perturbations stay
# within sqrt(3) S; random rotations of a free body (ocp_reorient) keep its
# directors orthonormal, uniform ones differ per seed and small ones stay
# small; a body held by a joint is refused before any case runs; the same
# seed gives the same numbers at --jobs 1 and 2 and in another batch.
#
#   test_batch_perturb.sh MRVI_BINARY SOURCE_ROOT
#
# Prints "N passed, M failed" and exits non-zero on any failure.
set -u

mrvi=${1:?usage: test_batch_perturb.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_batch_perturb.sh MRVI_BINARY SOURCE_ROOT}
sys=$root/systems

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
# shellcheck source=tests/batchlib.sh
. "$(dirname "$0")/batchlib.sh"
need_python h5py numpy

cd "$tmp" || exit 1
short=(--vary integrator.t_end=0.05)

# check NAME PYTHON: the Python code exits 0 (it prints what it measured).
check() {
  local name=$1 out
  if out=$("$py" -c "$2" 2>&1); then
    pass "$name: $out"
  else
    fail "$name: $out"
  fi
}

# Measured in the case files' first rows: KE = sum p^2 / 2m, the net
# momentum of every direction, N_f from the case's description note.
thermal_check='
import h5py, numpy as np, re, sys
master, T, D, nf_expected = sys.argv[1], float(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
worst_T = worst_P = 0.0
with h5py.File(master) as f:
    n = len(f["/cases/status"])
    for c in range(n):
        r = f["/runs/case_%04d" % c]
        p, m = r["macro/p"][0], r["model/mass"][:]
        text = r["model/description"][()].decode()
        nf = int(re.search(r"over (\d+) degrees of freedom", text).group(1))
        assert nf == nf_expected, (c, nf)
        ke = 0.5 * np.sum(p * p / m)
        worst_T = max(worst_T, abs(2 * ke / nf - T) / T)
        worst_P = max(worst_P, np.abs(p.reshape(-1, D).sum(0)).max() / np.abs(p).max())
ok = worst_T < 1e-14 and worst_P < 1e-14
print("max |2KE/N_f - T|/T = %.1e, max |P|/max|p| = %.1e over %d cases" % (worst_T, worst_P, n))
sys.exit(0 if ok else 1)
'

# --- a free lattice: 6 particles in 3-D, N_f = 18 - 3 ---
run_ok "thermal spring_ring, 4 seeds" "$mrvi" batch "$sys/spring_ring.yaml" \
  -o ring.h5 -q -j 2 --seeds 4 --temperature 2.5 "${short[@]}"
check "spring_ring: temperature and zero net momentum" \
  "$(printf '%s\n' "$thermal_check" | sed 's/sys.argv\[1\], float(sys.argv\[2\]), int(sys.argv\[3\]), int(sys.argv\[4\])/"ring.h5", 2.5, 3, 15/')"

# --- constrained: the triatomic molecule (two bonds), N_f = 9 - 2 - 3 ---
run_ok "thermal + positions triatomic, 4 seeds" "$mrvi" batch \
  "$sys/triatomic.yaml" -o tri.h5 -q -j 2 --seeds 4 --temperature 0.5 \
  --position-std 1e-4 "${short[@]}"
check "triatomic: temperature and zero net momentum" \
  "$(printf '%s\n' "$thermal_check" | sed 's/sys.argv\[1\], float(sys.argv\[2\]), int(sys.argv\[3\]), int(sys.argv\[4\])/"tri.h5", 0.5, 3, 4/')"
check "triatomic: perturbed positions on the bonds" '
import h5py, numpy as np
worst = moved = 0.0
with h5py.File("tri.h5") as f:
    for c in range(4):
        x = f["/runs/case_%04d/macro/q" % c][0].reshape(3, 3)
        worst = max(worst, abs(np.linalg.norm(x[1] - x[0]) - 1), abs(np.linalg.norm(x[2] - x[0]) - 1))
        if c:
            moved = max(moved, np.abs(x - f["/runs/case_0000/macro/q"][0].reshape(3, 3)).max())
print("max bond error %.1e (tolerance 1e-10), seeds differ by %.1e" % (worst, moved))
assert worst < 1e-10 and moved > 1e-5
'

# --- plain coordinates (FPU elongations): no net momentum removed ---
# The sum of the momenta of elongations is no momentum: --temperature draws
# p_i = c sqrt(m_i) z_i per coordinate (z_i normal number i of the seed,
# one c per case: 2 KE / N_f = T with N_f = n), says so on stderr and in the
# case's description note, and removes nothing (the sum stays nonzero).
"$mrvi" batch "$sys/fpu.yaml" -o fpu.h5 -j 2 --seeds 3 --temperature 0.7 \
  --vary integrator.t_end=0.6 >out.txt 2>err.txt
rc=$?
[ $rc = 0 ] && grep -q "plain coordinates only: --temperature draws Maxwell-Boltzmann momenta per coordinate, no net momentum removed" err.txt &&
  pass "fpu --temperature: the plain-coordinate note on stderr" ||
  fail "fpu --temperature (exit $rc): $(cat err.txt)"
check "fpu: temperature, momenta per coordinate, nothing removed" '
import h5py, numpy as np, re, math
M64 = (1 << 64) - 1
def rnd(seed, i):  # mrvi_batch_random (src/batch/batch.h)
    z = ((seed + 1) * 0x9E3779B97F4A7C15 + i) & M64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & M64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & M64
    return z ^ (z >> 31)
def normal(seed, j):  # mrvi_batch_normal
    u1 = ((rnd(seed, 2 * j) >> 11) + 1) * 2.0 ** -53
    u2 = (rnd(seed, 2 * j + 1) >> 11) * 2.0 ** -53
    return math.sqrt(-2 * math.log(u1)) * math.cos(6.283185307179586 * u2)
T, worst_T, least_P, worst_z = 0.7, 0.0, np.inf, 0.0
with h5py.File("fpu.h5") as f:
    for c in range(3):
        r = f["/runs/case_%04d" % c]
        p, m = r["macro/p"][0], r["model/mass"][:]
        text = r["model/description"][()].decode()
        assert "plain coordinates: no net momentum removed" in text, text[-300:]
        nf = int(re.search(r"over (\d+) degrees of freedom", text).group(1))
        assert nf == len(p), (nf, len(p))
        worst_T = max(worst_T, abs(np.sum(p * p / m) / nf - T) / T)
        least_P = min(least_P, abs(p.sum()) / np.abs(p).max())
        ratio = p / (np.sqrt(m) * np.array([normal(c, i) for i in range(len(p))]))
        worst_z = max(worst_z, np.ptp(ratio) / abs(ratio[0]))
print("max |2KE/N_f - T|/T = %.1e, min |sum p|/max|p| = %.2f, p_i/(sqrt(m_i) z_i) within %.1e of one c" % (worst_T, least_P, worst_z))
assert worst_T < 1e-14 and least_P > 1e-3 and worst_z < 1e-13
'

# --- uniform positions: |dq| <= sqrt(3) S on a free lattice ---
run_ok "uniform positions spring_ring" "$mrvi" batch "$sys/spring_ring.yaml" \
  -o uni.h5 -q --seeds 3 --position-std 0.01 --position-distribution uniform \
  "${short[@]}"
"$mrvi" run "$sys/spring_ring.yaml" -q -o ref.h5 --set integrator.t_end=0.05 \
  >/dev/null 2>&1
check "uniform positions within sqrt(3) S" '
import h5py, numpy as np
q0 = h5py.File("ref.h5")["/macro/q"][0]
with h5py.File("uni.h5") as f:
    d = np.array([f["/runs/case_%04d/macro/q" % c][0] - q0 for c in range(3)])
print("max |dq| %.4f, bound %.4f, std %.4f" % (np.abs(d).max(), 3 ** 0.5 * 0.01, d.std()))
assert np.abs(d).max() <= 3 ** 0.5 * 0.01 and np.abs(d).max() > 0.01 and 0.005 < d.std() < 0.015
'

# --- the same numbers on 1 and 2 jobs, and in another batch ---
run_ok "triatomic --jobs 1" "$mrvi" batch "$sys/triatomic.yaml" -o tri1.h5 -q \
  -j 1 --seeds 4 --temperature 0.5 --position-std 1e-4 "${short[@]}"
printf '%s\n' 0:0 1:1 2:2 3:3 | same_runs tri.h5 tri1.h5 &&
  same_table tri.h5 tri1.h5 && pass "--jobs 1 equals --jobs 2 (h5diff)" ||
  fail "--jobs 1 equals --jobs 2 (h5diff)"
run_ok "a batch of another key" "$mrvi" batch "$sys/triatomic.yaml" -o two.h5 \
  -q -j 2 --seeds 4 --temperature 0.5 --position-std 1e-4 \
  --vary integrator.t_end=0.05,0.1
check "seed s: the same initial state in another batch" '
import h5py, numpy as np
a, b = h5py.File("tri.h5"), h5py.File("two.h5")
d = max(np.abs(a["/runs/case_%04d/macro/%s" % (s, k)][0] - b["/runs/case_%04d/macro/%s" % (4 + s, k)][0]).max()
        for s in range(4) for k in ("q", "p"))
print("max difference %.1e" % d)
assert d == 0
'

# --- rotations of a free body ---
run_ok "uniform rotations ocp_reorient" "$mrvi" batch "$sys/ocp_reorient.yaml" \
  -o rot.h5 -q -j 2 --seeds 4 --rotations uniform --vary integrator.t_end=0.2
run_ok "small rotations ocp_reorient" "$mrvi" batch "$sys/ocp_reorient.yaml" \
  -o small.h5 -q -j 2 --seeds 4 --rotation-std 1e-3 --vary integrator.t_end=0.2
"$mrvi" run "$sys/ocp_reorient.yaml" -q -o reo.h5 --set integrator.t_end=0.2 \
  >/dev/null 2>&1
check "rotated directors orthonormal, uniform ones far apart, small ones small" '
import h5py, numpy as np
R0 = h5py.File("reo.h5")["/macro/q"][0][3:12].reshape(3, 3)
def frames(name):
    with h5py.File(name) as f:
        return [f["/runs/case_%04d/macro/q" % c][0][3:12].reshape(3, 3) for c in range(4)]
def angle(A, B):
    return np.arccos(np.clip((np.trace(A.T @ B) - 1) / 2, -1, 1))
ortho = max(np.abs(R @ R.T - np.eye(3)).max() for R in frames("rot.h5") + frames("small.h5"))
dets = [np.linalg.det(R) for R in frames("rot.h5")]
far = min(angle(R0, R) for R in frames("rot.h5"))
small = max(angle(R0, R) for R in frames("small.h5"))
print("orthonormal to %.1e, det %.15f..%.15f, uniform: angles >= %.2f rad, std 1e-3: angles <= %.1e rad" % (ortho, min(dets), max(dets), far, small))
assert ortho < 1e-14 and abs(min(dets) - 1) < 1e-14 and far > 0.1 and 0 < small < 1e-2
'
"$mrvi" batch "$sys/rigid_pendulum.yaml" -o pin.h5 -q --seeds 2 \
  --rotation-std 0.5 2>err.txt
[ $? = 1 ] && [ ! -e pin.h5 ] && grep -q "case 0.*perturbed positions.*hinge" err.txt &&
  pass "a body held by a joint: refused before any case, naming the joint" ||
  fail "a body held by a joint: $(cat err.txt)"

# --- refusals ---
"$mrvi" batch "$sys/fpu.yaml" -o bad.h5 --seeds 2 --temperature 1 \
  --velocity-std 0.1 2>err.txt
[ $? = 1 ] && grep -q "no --velocity-std with it" err.txt &&
  pass "--temperature with --velocity-std refused" ||
  fail "--temperature with --velocity-std refused: $(cat err.txt)"
"$mrvi" batch "$sys/fpu.yaml" -o bad.h5 --temperature 1 2>err.txt
[ $? = 1 ] && grep -q "which need --seeds" err.txt &&
  pass "--temperature without --seeds refused" ||
  fail "--temperature without --seeds refused: $(cat err.txt)"

test_finish
