#!/usr/bin/python3
"""Figures of doc/performance.md from the benchmark tables in doc/results/.

Usage: bench/plot_performance.py [RESULTS_DIR [FIGURES_DIR]]
(defaults doc/results and doc/figures; needs python3-matplotlib).
Reads bench_fpu.txt, bench_mristep.txt, bench_lattice.txt, bench_floor.txt
and bench_chain.txt (the stdout of build/bench/bench_fpu, bench_mristep,
bench_lattice, bench_floor and bench_chain) and writes perf_fpu_p.png,
perf_mristep.png, perf_lattice.png, perf_floor.png, perf_floor_ratios.png
and perf_chain.png."""
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


def sections(path):
    """{section: {key: rows}} of a file whose tables follow '## NAME' lines
    (bench_floor: one section per network).  A table is keyed by its first
    header, a later one whose first two headers differ by those two; a
    section or table that comes again (a second run appended) adds its
    rows."""
    out, heads, name, header = {}, {}, None, None
    for line in open(path, encoding="utf-8"):
        if line.startswith("## "):
            name, header = line[3:].strip(), None
            out.setdefault(name, {})
            continue
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if name is None or not line.startswith("|"):
            header = None
            continue
        if header is None:
            header = cells
            key = cells[0]
            if key in out[name] and heads[(name, key)][:2] != cells[:2]:
                key = " ".join(cells[:2])
            heads[(name, key)] = cells
            out[name].setdefault(key, [])
        elif not set(cells[0]) <= set("-:"):
            out[name][key].append(dict(zip(header, cells)))
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

    path = os.path.join(res, "bench_floor.txt")
    if os.path.exists(path):
        nets = {k: v for k, v in sections(path).items()
                if "method" in v and "n" in v}
        if nets:
            fig_, ax = plt.subplots(2, len(nets), figsize=(4.2 * len(nets), 7),
                                    squeeze=False)
            for col, (net, tables) in enumerate(nets.items()):
                table = tables["method"]
                for method in dict.fromkeys(r["method"] for r in table):
                    ok = [r for r in table if r["method"] == method
                          and number(r.get("step_s", ""))]
                    n = [number(r["n"]) for r in ok]
                    ax[0][col].loglog(n, [number(r["step_s"]) for r in ok],
                                      "o-", label=method)
                    ax[1][col].loglog(n, [number(r["B/coord"]) for r in ok],
                                      "o-", label=method)
                ax[0][col].set_title(net)
                ax[0][col].set_ylabel("CPU s per macro step")
                ax[1][col].set_ylabel("peak bytes per coordinate")
                ax[1][col].set_xlabel("coordinates n")
            ax[0][0].legend(fontsize=6)
            fig_.suptitle("networks, dT = 0.05, p = 10: floors, mrvi, LAMMPS")
            fig_.tight_layout()
            fig_.savefig(os.path.join(fig, "perf_floor.png"), dpi=110)
            plt.close(fig_)
            fig_, ax = plt.subplots(1, len(nets), figsize=(4.2 * len(nets), 3.8),
                                    squeeze=False)
            goals = {"FE/RESPA": 1.3, "ES/RESPA": 4, "MM/Verlet": 15,
                     "TM/Verlet": 15, "FE/LMP-R": 1, "ES/LMP-R": None}
            for col, (net, tables) in enumerate(nets.items()):
                table = tables["n"]
                for key in goals:
                    pts = [(number(r["n"]), number(r.get(key, "")))
                           for r in table if number(r.get(key, ""))]
                    if pts:
                        line, = ax[0][col].loglog(*zip(*pts), "o-", label=key)
                        if goals[key]:
                            ax[0][col].axhline(goals[key], ls=":", lw=0.8,
                                               color=line.get_color())
                ax[0][col].set_title(net + " (dotted: goals)")
                ax[0][col].set_xlabel("coordinates n")
            ax[0][0].set_ylabel("ratio of CPU time per macro step")
            ax[0][0].legend(fontsize=7)
            fig_.tight_layout()
            fig_.savefig(os.path.join(fig, "perf_floor_ratios.png"), dpi=110)
            plt.close(fig_)

    path = os.path.join(res, "bench_chain.txt")
    if os.path.exists(path):
        plt.figure(figsize=(6, 4))
        table = [r for r in rows(path, "scheme") if number(r.get("step_s", ""))]
        for key in dict.fromkeys((r["scheme"], r["chain"]) for r in table):
            ok = [r for r in table if (r["scheme"], r["chain"]) == key]
            plt.loglog([number(r["links"]) for r in ok],
                       [number(r["step_s"]) for r in ok],
                       "o-" if key[0].startswith("midpoint") else "s--",
                       label="%s, %s" % key)
        links = [10, 1000]
        plt.loglog(links, [1e-4 * x for x in links], "k:", label="slope 1")
        plt.xlabel("links")
        plt.ylabel("CPU s per macro step")
        plt.title("pendulum chains, dT = 0.01, p = 10")
        plt.legend(fontsize=6)
        plt.tight_layout()
        plt.savefig(os.path.join(fig, "perf_chain.png"), dpi=110)
        plt.close()


if __name__ == "__main__":
    main()
