#!/usr/bin/env bash
# Regenerate every number and figure of doc/reproduction.md (paper §5-§6).
#
# Usage: doc/reproduce.sh [BUILD_DIR]       (default: build)
#
# Needs build/mrvi (meson compile -C build) and Debian's python3-matplotlib
# and python3-h5py for the figures.  Writes
#   BUILD_DIR/reproduction/*.h5   the runs and study tables (not committed)
#   doc/results/*.txt             the tables quoted in the report
#   doc/figures/*.png             the figures embedded in the report
# Takes about two minutes on two cores.
set -euo pipefail

root=$(cd "$(dirname "$0")/.." && pwd)
build=$(cd "${1:-$root/build}" && pwd)
mrvi=$build/mrvi
plot=$root/src/cli/mrvi-plot
work=$build/reproduction
figs=$root/doc/figures
results=$root/doc/results
py=/usr/bin/python3
mkdir -p "$work" "$figs" "$results"
cd "$work"
[ -x "$mrvi" ] || { echo "no $mrvi: run meson compile -C ${1:-build} first" >&2; exit 1; }
"$py" -c 'import matplotlib, h5py' || { echo "needs python3-matplotlib and python3-h5py" >&2; exit 1; }

section() { printf '\n== %s\n' "$*"; }
# Tables quoted in the report name files relative to the repository (and the
# reproduction directory), never by this machine's absolute paths.
neutral() { sed -e "s|$work/||g" -e "s|$build/||g" -e "s|$root/||g"; }
short() { case $1 in midpoint-midpoint) echo Q1 ;; trapezoidal-midpoint) echo Q2 ;; trapezoidal-trapezoidal) echo Q3 ;; esac; }

# Summary of a run: energy error, FPU stiff energies or angular momentum.
summarise() { # summarise FILE...
  "$py" - "$@" <<'PY'
import sys
import h5py
import numpy as np

for path in sys.argv[1:]:
    f = h5py.File(path, "r")
    a = f.attrs
    t = f["/macro/t"][:]
    H = f["/macro/energy"][:]
    err = np.abs(H - H[0]) / abs(H[0])
    half = t <= t[-1] / 2
    head = "%-26s %-24s dT=%-6g p=%-3d" % (path.split("/")[-1], a["scheme"],
                                            a["macro_step"], a["micro_steps"])
    line = "%s max|dH/H0| %.2e (1st half %.2e, 2nd half %.2e)" % (
        head, err.max(), err[half].max(), err[~half].max())
    if "angular_momentum" in f["/macro"]:
        J = f["/macro/angular_momentum"][:]
        line += "  max|J3-J3(0)| %.2e  range J1 %.3g J2 %.3g" % (
            np.abs(J[:, 2] - J[0, 2]).max(), np.ptp(J[:, 0]), np.ptp(J[:, 1]))
    else:
        # FPU oscillatory energies I_j = (p_fj^2 + omega^2 q_fj^2)/2, omega^2 = 2500
        rate = f["/model/rate"][:]
        q = f["/macro/q"][:][:, rate == 1]
        p = f["/macro/p"][:][:, rate == 1]
        I = 0.5 * (p ** 2 + 2500.0 * q ** 2)
        Isum = I.sum(axis=1)
        # Time where I_2 is smallest after t = 20, on a running mean over
        # 5 time units (the fast oscillation of I_j itself averaged out).
        w = max(1, int(round(5.0 / a["macro_step"])))
        smooth = np.convolve(I[:, 1], np.ones(w) / w, mode="same")
        late = (t > 20) & (t < t[-1] - 5)
        t2 = t[late][np.argmin(smooth[late])]
        line += "  I: mean %.3f min %.3f max %.3f  I_2 smallest at t=%.0f" % (
            Isum.mean(), Isum.min(), Isum.max(), t2)
        if a["alpha_fast"] == 1.0 and a["gamma_fast"] == 1.0:
            # The left rectangle rule keeps p^2 + w^2 q^2 - dt w^2 p q of
            # the fast oscillator, not p^2 + w^2 q^2.
            dt = a["macro_step"] / a["micro_steps"]
            J = 0.5 * (p ** 2 + 2500.0 * q ** 2 - dt * 2500.0 * p * q).sum(1)
            line += "  I~ (with -dt w^2 p q): %.3f..%.3f" % (J.min(), J.max())
    print(line)
PY
}

section "FPU, t_N = 200 (Figs. fpu invariance imim/exim/exex)"
: >"$results/fpu.txt"
for spec in midpoint-midpoint:0.3 trapezoidal-midpoint:0.3 trapezoidal-trapezoidal:0.03; do
  scheme=${spec%%:*}
  dT=${spec##*:}
  files=()
  for p in 1 5 10; do
    out=fpu-$(short "$scheme")-p$p.h5
    "$mrvi" run "$root/systems/fpu.yaml" --quiet -o "$out" \
      --set integrator.scheme="$scheme" --set integrator.macro_step="$dT" \
      --set integrator.micro_steps=$p --set integrator.t_end=200
    "$plot" run "$out" -o "$figs" >/dev/null
    files+=("$out")
  done
  summarise "${files[@]}" | neutral | tee -a "$results/fpu.txt"
done

section "Spring ring, t_N = 50, dT = 0.01 (Figs. sr energy, sr ang mom)"
: >"$results/spring_ring.txt"
for scheme in midpoint-midpoint trapezoidal-midpoint trapezoidal-trapezoidal; do
  files=()
  for p in 1 5 10; do
    out=sr-$(short "$scheme")-p$p.h5
    "$mrvi" run "$root/systems/spring_ring.yaml" --quiet -o "$out" \
      --set integrator.scheme="$scheme" --set integrator.micro_steps=$p \
      --set output.micro=false
    "$plot" run "$out" -o "$figs" >/dev/null
    files+=("$out")
  done
  summarise "${files[@]}" | neutral | tee -a "$results/spring_ring.txt"
done

section "Convergence (Table tab:convergence rates), reference: single-rate midpoint"
for sys in fpu:0.02 spring_ring:0.01; do
  name=${sys%%:*}
  dt0=${sys##*:}
  for scheme in midpoint-midpoint trapezoidal-midpoint trapezoidal-trapezoidal; do
    tag=$name-$(short "$scheme")
    "$mrvi" converge "$root/systems/$name.yaml" --set integrator.scheme="$scheme" \
      --p 5,10 --dt0 "$dt0" --levels 5 --t-end 0.5 --cache "$work/cache" \
      -o "conv-$tag.h5" --csv "$results/conv-$tag.csv" | neutral | tee "$results/conv-$tag.txt"
    "$plot" convergence "conv-$tag.h5" -o "$figs" >/dev/null
  done
  # Trapezoidal-midpoint again where its first-order slow error dominates.
  tag=$name-Q2-fine
  "$mrvi" converge "$root/systems/$name.yaml" --set integrator.scheme=trapezoidal-midpoint \
    --p 5,10 --dt0 5e-4 --levels 4 --t-end 0.1 --cache "$work/cache" \
    -o "conv-$tag.h5" --csv "$results/conv-$tag.csv" | neutral | tee "$results/conv-$tag.txt"
  "$plot" convergence "conv-$tag.h5" -o "$figs" >/dev/null
done

# Least-squares orders of every error column, per table and p.
"$py" - "$results"/conv-*.csv <<'PY' | tee "$results/orders.txt"
import csv
import sys
import numpy as np

cols = ["e_q_mac", "e_p_mac", "e_q_mic", "e_p_mic",
        "e_qs_mac", "e_qf_mac", "e_ps_mac", "e_pf_mac"]
print("%-18s %-4s %-17s " % ("table", "p", "dT range")
      + " ".join("%7s" % c[2:] for c in cols))
for path in sys.argv[1:]:
    rows = list(csv.DictReader(open(path)))
    for p in sorted({int(r["p"]) for r in rows}):
        R = [r for r in rows if int(r["p"]) == p]
        h = np.log([float(r["macro_step"]) for r in R])
        fit = [np.polyfit(h, np.log([float(r[c]) for r in R]), 1)[0]
               for c in cols]
        name = path.split("/")[-1][5:-4]
        print("%-18s %-4d %-17s " % (name, p, "%.3g..%.3g" % (
            float(R[0]["macro_step"]), float(R[-1]["macro_step"])))
              + " ".join("%7.2f" % o for o in fit))
PY

section "Linear stability (Lemma lemma:stability_slow)"
"$mrvi" stability "$root/systems/oscillator.yaml" --p 1,2,3,4,5,6,7,8,9,10,20,50 \
  --at 3.5 -o stability.h5 | neutral | tee "$results/stability.txt"
"$plot" stability stability.h5 -o "$figs" >/dev/null

section "Computing time (§6.3): FPU, dt = 0.001"
"$mrvi" timing "$root/systems/fpu.yaml" --dt 0.001 --t-end 20 \
  -o timing.h5 --csv "$results/timing.csv" | neutral | tee "$results/timing.txt"
"$plot" timing timing.h5 -o "$figs" >/dev/null

section "done"
echo "tables in $results, figures in $figs"
