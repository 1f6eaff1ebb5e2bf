#!/usr/bin/python3
"""Figures of doc/performance.md from the benchmark tables in doc/results/.

Usage: bench/plot_performance.py [--data FILE] [RESULTS_DIR [FIGURES_DIR]]
(defaults doc/results and doc/figures; needs python3-matplotlib).
Reads bench_fpu.txt, bench_mristep.txt, bench_lattice.txt, bench_floor.txt
and bench_chain.txt (the stdout of build/bench/bench_fpu, bench_mristep,
bench_lattice, bench_floor and bench_chain) and writes perf_fpu_p.png,
perf_mristep.png, perf_lattice.png, perf_floor.png, perf_floor_ratios.png
and perf_chain.png.  From the idle runs of bench_floor that idle_runs.txt
lists (see idle_runs() below) it writes perf_idle_ratios.png, the ratio to
the floor against n per scheme and network, goals dotted; --data FILE
also writes the points drawn there, one line each: network, ratio, n,
value and the run it came from."""
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker  # noqa: E402


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


def sections(path, lines=None):
    """{section: {key: rows}} of a file whose tables follow '## NAME' lines
    (bench_floor: one section per network).  A table is keyed by its first
    header, a later one whose first two headers differ by those two; a
    section or table that comes again (a second run appended) adds its
    rows.  lines: the file's lines to read instead of the whole file."""
    out, heads, name, header = {}, {}, None, None
    if lines is None:
        lines = open(path, encoding="utf-8").readlines()
    for line in lines:
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


# The ratio columns of bench_floor's "n" table drawn in perf_idle_ratios.png:
# (column, label, goal of issue 24).
IDLE_RATIOS = [("FE/RESPA", "fully-explicit ÷ r-RESPA floor", 1.3),
               ("ES/RESPA", "explicit-slow ÷ r-RESPA floor", 4.0),
               ("MM/Verlet", "midpoint-midpoint ÷ Verlet floor", 15.0),
               ("TM/Verlet", "trapezoidal-midpoint ÷ Verlet floor", 15.0)]
NETWORKS = ["lattice2d", "lattice3d", "random3d"]


def blocks(path, names):
    """The lines of the blocks NAME of a file of concatenated outputs, each
    headed by a line '=== NAME' and ending at the next '=== ' line; the
    whole file when names is empty."""
    lines = open(path, encoding="utf-8").readlines()
    if not names:
        return lines
    out, keep, found = [], False, set()
    for line in lines:
        if line.startswith("=== "):
            name = line[4:].strip()
            keep = name in names
            if keep:
                found.add(name)
            continue
        if keep:
            out.append(line)
    missing = [n for n in names if n not in found]
    if missing:
        raise SystemExit("%s: no block %s" % (path, ", ".join(missing)))
    return out


def idle_runs(res):
    """The points of perf_idle_ratios.png: {(network, column, n): (value,
    run)} from the runs RES/idle_runs.txt lists, oldest first, one a line:
    'DATE TIME FILE [BLOCK...]' (FILE in RES; BLOCKs: only those blocks of a
    file of concatenated outputs; '#' starts a comment).  A later run's
    value replaces an earlier one's, so each point is the latest idle
    figure; a listed run that adds no point is an error."""
    path = os.path.join(res, "idle_runs.txt")
    points, runs = {}, []
    for k, line in enumerate(open(path, encoding="utf-8"), 1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        if len(words) < 3:
            raise SystemExit("%s:%d: expected DATE TIME FILE [BLOCK...]"
                             % (path, k))
        run = "%s %s %s" % tuple(words[:3])
        lines = blocks(os.path.join(res, words[2]), words[3:])
        added = 0
        for net, tables in sections(None, lines).items():
            for r in tables.get("n", []):
                n = number(r.get("n", ""))
                for col, _, _ in IDLE_RATIOS:
                    v = number(r.get(col, ""))
                    if n and v:
                        points[(net, col, int(n))] = (v, run)
                        added += 1
        if not added:
            raise SystemExit("%s:%d: %s has no ratio to draw" % (path, k, run))
        runs.append(run)
    return points, runs


def plot_idle_ratios(res, fig, data):
    """perf_idle_ratios.png: one panel per network, a line per scheme
    (colour) through its latest idle points, the run of each point by its
    marker, the goals dotted."""
    points, runs = idle_runs(res)
    markers = dict(zip(runs, "osD^vP*X"))
    fig_, ax = plt.subplots(1, len(NETWORKS), figsize=(13, 4.6), sharey=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for col, net in enumerate(NETWORKS):
        a = ax[col]
        for k, (key, label, goal) in enumerate(IDLE_RATIOS):
            pts = sorted((n, v, run) for (nt, c, n), (v, run) in points.items()
                         if nt == net and c == key)
            colour = colours[k]
            a.axhline(goal, ls=":", lw=0.9, color=colour)
            if not pts:
                continue
            a.loglog([p[0] for p in pts], [p[1] for p in pts], "-", lw=1,
                     color=colour, label=label + " (goal %g)" % goal)
            for n, v, run in pts:
                a.loglog([n], [v], markers[run], color=colour, ms=6)
                if data:
                    data.write("%s %s %d %g %s\n" % (net, key, n, v, run))
        drawn = {c for (nt, c, _) in points if nt == net}
        absent = [lab.split(" ÷")[0] for key, lab, _ in IDLE_RATIOS
                  if key not in drawn]
        a.set_title(net + (" (no idle run: %s)" % ", ".join(absent)
                           if absent else ""), fontsize=9)
        a.set_xlabel("coordinates n")
        a.set_xlim(600, 2e6)
        a.grid(True, which="major", lw=0.3)
    ticks = sorted({1.0, 2.0, 10.0} | {g for _, _, g in IDLE_RATIOS})
    ax[0].set_yticks(ticks)
    ax[0].set_yticklabels(["%g" % t for t in ticks])
    ax[0].yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax[0].set_ylabel("CPU time per macro step ÷ the floor's (one thread)")
    lines, labels = ax[0].get_legend_handles_labels()
    for a in ax[1:]:  # a scheme drawn on one network only
        for h, lab in zip(*a.get_legend_handles_labels()):
            if lab not in labels:
                lines.append(h)
                labels.append(lab)
    fig_.legend(lines, labels, fontsize=7, loc="lower left", ncol=2,
                bbox_to_anchor=(0.01, 0.0))
    handles = [plt.Line2D([], [], ls="", marker=markers[r], color="k")
               for r in runs]
    fig_.legend(handles, ["run of " + r for r in runs], fontsize=7,
                loc="lower right", bbox_to_anchor=(0.99, 0.0))
    fig_.suptitle("bench_floor on an idle machine, dT = 0.05, p = 10: the "
                  "latest figure at each n (dotted: issue 24's goals)",
                  fontsize=10)
    rows = max(2, len(runs))
    fig_.tight_layout(rect=(0, 0.035 * rows + 0.02, 1, 1))
    fig_.savefig(os.path.join(fig, "perf_idle_ratios.png"), dpi=110)
    plt.close(fig_)


def main():
    args = sys.argv[1:]
    data = None
    if args[:1] == ["--data"] and len(args) > 1:
        data = open(args[1], "w", encoding="utf-8")
        args = args[2:]
    res = args[0] if len(args) > 0 else "doc/results"
    fig = args[1] if len(args) > 1 else "doc/figures"
    os.makedirs(fig, exist_ok=True)

    if os.path.exists(os.path.join(res, "idle_runs.txt")):
        plot_idle_ratios(res, fig, data)
    if data:
        data.close()

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
