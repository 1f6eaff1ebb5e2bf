"""Run many mrvi-plot command lines in one Python process (the tests).

    plot_cases.py MRVI_PLOT CASES OUTDIR

CASES holds one case a line: an identifier, then the arguments of one
mrvi-plot command line, separated by tabs.  Each case runs through
mrvi-plot's main(argv) as `python3 mrvi-plot ARGS...` would, with its
stdout in OUTDIR/ID.out and its stderr (file descriptor 2, so HDF5's own
messages too) in OUTDIR/ID.err; its exit status goes to OUTDIR/ID.rc:
main's return value, a SystemExit's code, 1 with the traceback on stderr
for an exception that escapes main (as the interpreter does), 124 after
TIMEOUT seconds.  A case `ID --script FILE ARGS...` runs the Python file
FILE as `python3 FILE ARGS...` would instead (a test's own checks that
load mrvi-plot as a module), pyplot's close restored after it.
Importing matplotlib and h5py once instead of once per case is what this
saves (about half a CPU second per case).
"""

import importlib.machinery
import importlib.util
import os
import runpy
import signal
import sys
import traceback

TIMEOUT = 120      # seconds per case, as `timeout 120` did per process


class CaseTimeout(BaseException):
    """A case ran longer than TIMEOUT (not an Exception: main must not
    catch it)."""


def on_alarm(_signum, _frame):
    raise CaseTimeout()


def load(path):
    loader = importlib.machinery.SourceFileLoader("mrvi_plot", path)
    spec = importlib.util.spec_from_loader("mrvi_plot", loader)
    module = importlib.util.module_from_spec(spec)
    loader.exec_module(module)
    return module


def run_script(plt, argv):
    """Run the file argv[0] with sys.argv = argv as __main__."""
    saved = sys.argv, plt.close
    sys.argv = list(argv)
    try:
        runpy.run_path(argv[0], run_name="__main__")
        return 0
    finally:
        sys.argv, plt.close = saved


def run_case(plot, argv):
    """mrvi-plot's exit status for argv, as the interpreter would give it."""
    signal.alarm(TIMEOUT)
    try:
        if argv[:1] == ["--script"]:
            return run_script(plot.plt, argv[1:])
        return plot.main(argv)
    except SystemExit as exc:
        if exc.code is None or isinstance(exc.code, int):
            return exc.code or 0
        sys.stderr.write("%s\n" % exc.code)
        return 1
    except CaseTimeout:
        sys.stderr.write("plot_cases.py: timed out after %d s\n" % TIMEOUT)
        return 124
    except BaseException:  # as an uncaught exception ends `python3 mrvi-plot`
        traceback.print_exc()
        return 1
    finally:
        signal.alarm(0)
        plot.plt.close("all")


def main():
    if len(sys.argv) != 4:
        sys.exit("usage: plot_cases.py MRVI_PLOT CASES OUTDIR")
    plot = load(sys.argv[1])
    with open(sys.argv[2]) as f:
        cases = [line.rstrip("\n").split("\t") for line in f if line.strip()]
    signal.signal(signal.SIGALRM, on_alarm)
    saved = os.dup(1), os.dup(2)
    for case in cases:
        ident, argv = case[0], case[1:]
        out, err = (os.open(os.path.join(sys.argv[3], ident + ext),
                            os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
                    for ext in (".out", ".err"))
        sys.stdout.flush()
        sys.stderr.flush()
        os.dup2(out, 1)
        os.dup2(err, 2)
        os.close(out)
        os.close(err)
        try:
            rc = run_case(plot, argv)
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
        with open(os.path.join(sys.argv[3], ident + ".rc"), "w") as f:
            f.write("%d\n" % rc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
