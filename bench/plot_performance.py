#!/usr/bin/python3
"""Figures of doc/performance.md from the benchmark tables in doc/results/.

Usage: bench/plot_performance.py [RESULTS_DIR [FIGURES_DIR]]
(defaults doc/results and doc/figures; needs python3-matplotlib).
Reads bench_fpu.txt, bench_mristep.txt and bench_lattice.txt (the stdout of
build/bench/bench_fpu, bench_mristep and bench_lattice) and writes
perf_fpu_p.png, perf_mristep.png and perf_lattice.png."""
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def rows(path, first_header):
    """Rows of the markdown table whose first header cell is first_header."""
    out, inside = [], False
    for line in open(path, encoding="utf-8"):
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("|") and cells[0] == first_header:
            inside, out = True, []
            header = cells
            continue
        if inside and line.startswith("|"):
            if set(cells[0]) <= set("-:"):
                continue
            out.append(dict(zip(header, cells)))
        elif inside and not line.strip():
            return out  # a blank line ends the table; stderr lines do not
    return out


def number(s):
    try:
        v = float(s)
        return v if math.isfinite(v) else None
    except ValueError:
        return None


def main():
    res = sys.argv[1] if len(sys.argv) > 1 else "doc/results"
    fig = sys.argv[2] if len(sys.argv) > 2 else "doc/figures"
    os.makedirs(fig, exist_ok=True)

    path = os.path.join(res, "bench_fpu.txt")
    if os.path.exists(path):
        plt.figure(figsize=(6, 4))
        table = rows(path, "scheme")
        for scheme in dict.fromkeys(r["scheme"] for r in table):
            pts = [(number(r["p"]), number(r["step_us"])) for r in table
                   if r["scheme"] == scheme and number(r["step_us"])]
            plt.loglog(*zip(*pts), "o-", label=scheme)
        ps = [1, 1000]
        plt.loglog(ps, [5 * p for p in ps], "k:", label="slope 1")
        plt.xlabel("p (dt = 0.001 fixed)")
        plt.ylabel("CPU time per macro step [us]")
        plt.title("FPU: cost per macro step vs p")
        plt.legend(fontsize=7)
        plt.tight_layout()
        plt.savefig(os.path.join(fig, "perf_fpu_p.png"), dpi=110)
        plt.close()

    path = os.path.join(res, "bench_mristep.txt")
    if os.path.exists(path):
        plt.figure(figsize=(6, 4))
        table = rows(path, "method")
        for method in dict.fromkeys(r["method"] for r in table):
            pts = [(number(r["error q"]), number(r["CPU s"])) for r in table
                   if r["method"] == method and number(r["error q"])
                   and number(r["error q"]) < 1]
            plt.loglog(*zip(*pts), "o-", label=method)
        plt.xlabel("error in q at t = 20")
        plt.ylabel("CPU time [s]")
        plt.title("FPU, p = 10: mrvi vs MRIStep")
        plt.gca().invert_xaxis()
        plt.legend(fontsize=7)
        plt.tight_layout()
        plt.savefig(os.path.join(fig, "perf_mristep.png"), dpi=110)
        plt.close()

    path = os.path.join(res, "bench_lattice.txt")
    if os.path.exists(path):
        fig_, ax = plt.subplots(1, 2, figsize=(9, 3.8))
        table = rows(path, "scheme")
        for scheme in dict.fromkeys(r["scheme"] for r in table):
            ok = [r for r in table
                  if r["scheme"] == scheme and number(r.get("step_s", ""))]
            n = [number(r["n"]) for r in ok]
            ax[0].loglog(n, [number(r["step_s"]) for r in ok], "o-",
                         label=scheme + " step")
            # Loads below the table's 1 ms resolution print as 0.000: a
            # gap on the log axis, not a drop.
            ax[0].loglog(n, [number(r["load_s"]) or math.nan for r in ok],
                         "s--", label=scheme + " load")
            ax[1].loglog(n, [number(r["peak_MB"]) for r in ok], "o-",
                         label=scheme)
        ax[0].set_xlabel("coordinates n")
        ax[0].set_ylabel("CPU time [s]")
        ax[0].legend(fontsize=7)
        ax[1].set_xlabel("coordinates n")
        ax[1].set_ylabel("peak memory [MB]")
        ax[1].legend(fontsize=7)
        fig_.suptitle("planar lattices, p = 10")
        fig_.tight_layout()
        fig_.savefig(os.path.join(fig, "perf_lattice.png"), dpi=110)
        plt.close(fig_)


if __name__ == "__main__":
    main()
