"""Re-run what README.md and doc/*.md show being run, and compare the output.

    doc_outputs.py MRVI_BINARY SOURCE_ROOT [FILE.md ...]

A ```console block whose lines start with `$ ./build/mrvi` (or
`$ build/mrvi`, `$ mrvi`) is a command and the lines after it, up to the
next `$ ` line, its output.  A ```python block followed directly by a
```console block without `$ ` lines is a program and its output (run with
this interpreter; skipped with a message when it lacks h5py).  Commands run
in a scratch folder where `systems/` points at the shipped systems, in the
order of the file, so a program finds the files the commands before it
wrote.

Each shown output line must equal a line of the real output, in order: the
next one, or any later one after a `…` line; a line ending in `…` only
its beginning.  Words must be equal; numbers
are compared with these tolerances:
  - integers (counts, steps, iterations): exactly;
  - other numbers: relative difference at most REL = 1e-3 (energy errors
    are printed with 4 digits; roundoff between builds is far below);
  - numbers below TINY = 1e-8 in the docs (residuals and differences at the
    solver tolerance or roundoff, which move with compiler flags): within a
    factor of 10;
  - timings are not compared: on lines with `wall time` (wall, assemble and
    solve times) only the words before the first number must agree.
Prints one line per compared block and exits 1 if any differ.
"""

import os
import re
import shlex
import subprocess
import sys
import tempfile

REL, TINY = 1e-3, 1e-8
NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?(?![\w])")
COMMAND = re.compile(r"^\$ (?:\./)?(?:build/)?mrvi(?= )")


def blocks(path):
    """Fenced blocks of a markdown file: (language, first line number, lines)."""
    out, lang, start, body = [], None, 0, []
    with open(path, encoding="utf-8") as f:
        for n, line in enumerate(f, 1):
            line = line.rstrip("\n")
            if lang is None and line.startswith("```"):
                lang, start, body = line[3:].strip(), n + 1, []
            elif lang is not None and line.startswith("```"):
                out.append((lang, start, body))
                lang = None
            elif lang is not None:
                body.append(line)
    return out


def cases(path):
    """(line, kind, code, shown output lines) to re-run from one file."""
    found, bl = [], blocks(path)
    for i, (lang, start, body) in enumerate(bl):
        if lang == "console":
            cmd = None
            for j, line in enumerate(body + ["$ "]):
                if line.startswith("$ "):
                    if cmd is not None:
                        found.append(cmd)
                    cmd = None
                    if COMMAND.match(line):
                        cmd = (start + j, "sh", line[2:], [])
                elif cmd is not None:
                    cmd[3].append(line)
        elif lang == "python" and i + 1 < len(bl):
            nlang, nstart, nbody = bl[i + 1]
            if nlang == "console" and not any(l.startswith("$ ") for l in nbody):
                found.append((start, "python", "\n".join(body), nbody))
    return found


def same_line(shown, real):
    """None when the real line matches the shown one, else why not."""
    timing = "wall time" in shown
    if shown.endswith("…"):  # a line cut short: its beginning must agree
        shown = shown[:-1].rstrip()
        real = real[: len(shown)]
    ws, wr = NUMBER.split(shown), NUMBER.split(real)
    ns, nr = NUMBER.findall(shown), NUMBER.findall(real)
    if timing:
        return None if " ".join(ws[0].split()) == " ".join(wr[0].split()) else "words"
    if [" ".join(w.split()) for w in ws] != [" ".join(w.split()) for w in wr]:
        return "words"
    for a, b in zip(ns, nr):
        if re.fullmatch(r"[-+]?\d+", a):
            if a != b:
                return "%s != %s" % (a, b)
            continue
        x, y = float(a), float(b)
        if abs(x) < TINY:
            if not (x == y or (y != 0 and 0.1 <= abs(y / x) <= 10 and x * y > 0)):
                return "%s vs %s (not within a factor of 10)" % (a, b)
        elif abs(x - y) > REL * abs(y):
            return "%s vs %s (relative difference %.1e > %g)" % (
                a, b, abs(x - y) / abs(y), REL)
    return None


def compare(shown, real):
    """None when every shown line is found in order, else a message."""
    real = [l for l in real if l.strip()]
    at, skip = 0, False
    for line in shown:
        if not line.strip():
            continue
        if line.strip() == "…":
            skip = True
            continue
        if skip:
            hit = next((k for k in range(at, len(real))
                        if same_line(line, real[k]) is None), None)
            if hit is None:
                return "shown  %s\n    not found in the output after line %d" % (
                    line, at)
            at = hit + 1
        else:
            got = real[at] if at < len(real) else "(no more output)"
            why = same_line(line, got) if at < len(real) else "missing"
            if why:
                return "shown  %s\n    got    %s (%s)" % (line, got, why)
            at += 1
        skip = False
    return None


def main():
    mrvi, root = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
    files = sys.argv[3:] or [os.path.join(root, "README.md")] + sorted(
        os.path.join(root, "doc", f) for f in os.listdir(os.path.join(root, "doc"))
        if f.endswith(".md"))
    try:
        import h5py  # noqa: F401
        have_h5py = True
    except ImportError:
        have_h5py = False
    bad = total = 0
    for path in files:
        name = os.path.relpath(path, root)
        with tempfile.TemporaryDirectory() as tmp:
            os.symlink(os.path.join(root, "systems"), os.path.join(tmp, "systems"))
            for line, kind, code, shown in cases(path):
                if kind == "sh":
                    argv = [mrvi] + shlex.split(code)[1:]
                else:
                    if not have_h5py:
                        print("skip %s:%d: python without h5py" % (name, line))
                        continue
                    argv = [sys.executable, "-c", code]
                r = subprocess.run(argv, cwd=tmp, capture_output=True, text=True,
                                   env=dict(os.environ, MPLBACKEND="Agg"))
                why = compare(shown, (r.stdout + r.stderr).splitlines())
                total += 1
                if why:
                    bad += 1
                    print("FAIL %s:%d: %s\n    %s" % (name, line, code.split("\n")[0], why))
                else:
                    print("ok   %s:%d: %s" % (name, line, code.split("\n")[0]))
    print("%d shown outputs compared, %d differ" % (total, bad))
    return 1 if bad or total == 0 else 0


if __name__ == "__main__":
    sys.exit(main())
