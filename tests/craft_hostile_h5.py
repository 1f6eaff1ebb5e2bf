"""craft_hostile_h5.py KIND BASE.h5 OUT_DIR: hostile HDF5 inputs for
tests/test_hostile_h5.sh, one file per case, each a copy of a real mrvi
output BASE.h5 with one dataset or attribute replaced (or, for KIND
controls, crafted from nothing).  Prints one line per file: CASE FILE.

KIND:
  export    BASE: a 2-D run with particles and /micro/q_slow (lattice)
  resume    BASE: a run with /macro/lambda (cart pendulum), completed
  bodies    BASE: a completed run with rigid bodies (/bodies, ranks 3, 4)
  torsion   BASE: a completed run with one torsional spring
            (/macro/torsion_angle)
  from      BASE: a run without particles (fpu)
  controls  BASE: ignored; /control/u files for ocp_double_integrator.yaml
            (1 actuator on the macro grid, 10 macro steps)
  hang      BASE: a run file (written by mrvi, superblock version 3):
            truncated to 34 bytes, a superblock byte flipped, and both with
            the superblock flagged as open for writing (a killed writer's)
  tables    BASE: ignored; tables of mrvi converge, stability and timing
            crafted from nothing for mrvi-plot (a good one of each, then
            one dataset of another rank, type, length or a huge size)
  plotcontrol  BASE: a file of mrvi optimize; /control and
            /optimizer/history replaced, for mrvi-plot optimize
  flip SEED COUNT BASE OUT_DIR: COUNT copies of BASE with bytes flipped

Huge dimensions are declared on chunked datasets with no chunk written,
so a file that asks for 2^32 or 2^61 entries stays a few kB."""
import os
import random
import shutil
import sys

import h5py
import numpy as np


def copy(base, out, case):
    path = os.path.join(out, case + ".h5")
    shutil.copyfile(base, path)
    print(case, path)
    return h5py.File(path, "r+")


def replace(f, name, **kw):
    """Dataset name replaced by h5py's create_dataset(**kw)."""
    del f[name]
    return f.create_dataset(name, **kw)


def huge(f, name, shape, dtype="f8"):
    """Dataset name declared with shape, chunked, no data written."""
    if name in f:
        del f[name]
    chunks = tuple(1 for _ in shape)
    return f.create_dataset(name, shape=shape, dtype=dtype, chunks=chunks)


def strings(values):
    """Fixed-length strings (mrvi writes and reads no others)."""
    a = np.array(values)
    return a if a.dtype.kind == "S" else np.char.encode(a, "utf-8")


def vlen_strings(values):
    """Variable-length strings, which mrvi refuses unread (their data are
    in the global heap, which libhdf5 reads unchecked)."""
    return np.array(values, dtype=h5py.string_dtype("utf-8"))


def rank(k):
    """A float64 array of rank k, every dimension 1."""
    return np.zeros((1,) * k)


def resumable(f, steps):
    """A completed run turned into one stopped at node `steps`."""
    # The fixed-length form a stopped run has: 1024 bytes, UTF-8.
    f.attrs.create("stop_reason", "interrupted (SIGINT)",
                   dtype=h5py.string_dtype("utf-8", 1024))
    f.attrs.modify("steps_completed", steps)


def export_cases(base, out):
    with copy(base, out, "names_longer") as f:
        np_ = f["model/particle_column"].shape[0]
        replace(f, "model/particle_name",
                data=strings(["p%d" % i for i in range(np_ + 5)]))
    with copy(base, out, "names_huge") as f:
        huge(f, "model/particle_name", (2**32,), h5py.string_dtype("utf-8", 8))
    with copy(base, out, "names_vlen") as f:
        np_ = f["model/particle_column"].shape[0]
        replace(f, "model/particle_name",
                data=vlen_strings(["p%d" % i for i in range(np_)]))
    with copy(base, out, "names_matrix") as f:
        np_ = f["model/particle_column"].shape[0]
        replace(f, "model/particle_name",
                data=strings([["a", "b"]] * np_))
    with copy(base, out, "qfast_wider") as f:
        q = f["micro/q_fast"][...]
        replace(f, "micro/q_fast",
                data=np.hstack([q, np.zeros((q.shape[0], 7))]))
    with copy(base, out, "qslow_narrower") as f:
        q = f["micro/q_slow"][...]
        replace(f, "micro/q_slow", data=q[:, :3])
    with copy(base, out, "dimension_array") as f:
        replace(f, "model/dimension", data=np.array([2, 2, 2, 2], "i4"))
    with copy(base, out, "column_huge") as f:
        huge(f, "model/particle_column", (2**32 + 1,), "i4")
    with copy(base, out, "coordinates_huge") as f:
        n = 2**32 + f["model/rate"].shape[0]
        rows = f["macro/q"].shape[0]
        huge(f, "model/rate", (n,), "i4")
        huge(f, "macro/q", (rows, n))
    with copy(base, out, "rate_rank32") as f:
        replace(f, "model/rate", data=rank(32))
    with copy(base, out, "stop_reason_array") as f:
        f.attrs["stop_reason"] = strings(["completed"] * 64)


# (case, text in /model/description, replacement): the description says
# another run than the attributes and data (cart_pendulum.yaml's values).
DESCRIPTION_EDITS = [
    ("desc_macro_step", "macro_step: 0.02", "macro_step: 0.01"),
    ("desc_micro_steps", "micro_steps: 5", "micro_steps: 3"),
    ("desc_every", "every: 1", "every: 2"),
    ("desc_scheme", "scheme: midpoint-midpoint",
     "scheme: trapezoidal-trapezoidal"),
    ("desc_t_end", "t_end: 0.2", "t_end: 0.4"),
    ("desc_particle", "bob", "ball"),
    ("desc_rate", "rate: fast", "rate: slow"),
    ("desc_constraint", "- type: plane", "- type: plane\n  name: floor2\n"
     "  particle: bob\n  normal: [1, 0, 0]\n- type: plane"),
]
# (case, root attribute, value): a number no run writes.
ATTRIBUTE_EDITS = [
    ("macro_step_nan", "macro_step", np.nan),
    ("macro_step_huge", "macro_step", 1e300),
    ("micro_steps_huge", "micro_steps", 1e30),
    ("every_nan", "output_every", np.nan),
    ("every_1e30", "output_every", 1e30),
    ("steps_huge", "steps_completed", 1e300),
    ("t_end_inf", "t_end", np.inf),
    ("scheme_other", "scheme", np.bytes_(b"fully-explicit")),
]


def edit_description(f, old, new):
    text = f["model/description"][()].decode()
    assert old in text, old
    replace(f, "model/description",
            data=np.bytes_(text.replace(old, new).encode()))


def resume_cases(base, out):
    with copy(base, out, "ok") as f:
        resumable(f, 5)
    for k in (3, 32):
        with copy(base, out, "lambda_rank%d" % k) as f:
            resumable(f, 5)
            rows = f["macro/lambda"].shape[0]
            replace(f, "macro/lambda", data=np.zeros((rows,) + (1,) * (k - 1)),
                    maxshape=(None,) + (1,) * (k - 1))
    with copy(base, out, "lambda_wider") as f:
        resumable(f, 5)
        lam = f["macro/lambda"][...]
        replace(f, "macro/lambda",
                data=np.hstack([lam, np.zeros((lam.shape[0], 9))]),
                maxshape=(None, lam.shape[1] + 9), chunks=True)
    with copy(base, out, "lambda_huge") as f:
        resumable(f, 5)
        huge(f, "macro/lambda", (f["macro/t"].shape[0], 2**40))
    with copy(base, out, "residual_rank32") as f:
        resumable(f, 5)
        replace(f, "solver/residual", data=rank(32), maxshape=(None,) + (1,) * 31)
    with copy(base, out, "q_rank32") as f:
        resumable(f, 5)
        replace(f, "macro/q", data=rank(32))
    with copy(base, out, "stop_reason_text") as f:
        resumable(f, 5)  # then edited: the variable-length form
        f.attrs["stop_reason"] = "interrupted (SIGINT)"
    with copy(base, out, "steps_array") as f:
        resumable(f, 5)
        f.attrs["steps_completed"] = np.arange(1000.0)
    with copy(base, out, "steps_nan") as f:
        resumable(f, 5)
        f.attrs["steps_completed"] = np.nan
    with copy(base, out, "every_huge") as f:
        resumable(f, 5)
        f.attrs["output_every"] = 1e300
    with copy(base, out, "description_array") as f:
        resumable(f, 5)
        d = f["model/description"][()]
        replace(f, "model/description", data=strings([d] * 16))
    with copy(base, out, "stop_reason_array") as f:
        resumable(f, 5)
        f.attrs["stop_reason"] = strings(["interrupted"] * 64)
    # Class 2: description, attributes and data that disagree.
    for case, old, new in DESCRIPTION_EDITS:
        with copy(base, out, case) as f:
            resumable(f, 5)
            edit_description(f, old, new)
    for case, name, value in ATTRIBUTE_EDITS:
        with copy(base, out, case) as f:
            resumable(f, 5)
            f.attrs[name] = value
    with copy(base, out, "name_renamed") as f:
        resumable(f, 5)
        names = [s.decode() for s in f["model/name"][...]]
        names[-1] = "other.z"
        replace(f, "model/name", data=strings(names))
    with copy(base, out, "rate_flipped") as f:
        resumable(f, 5)
        f["model/rate"][0] = 1 - f["model/rate"][0]
    # The particles' names and columns (mrvi export's) against the
    # description, /model/name left as it is.
    with copy(base, out, "particle_renamed") as f:
        resumable(f, 5)
        names = [s.decode() for s in f["model/particle_name"][...]]
        names[-1] = "other"
        replace(f, "model/particle_name", data=strings(names))
    with copy(base, out, "particle_column_moved") as f:
        resumable(f, 5)
        f["model/particle_column"][-1] = 0
    with copy(base, out, "particle_fewer") as f:
        resumable(f, 5)
        names = f["model/particle_name"][...]
        replace(f, "model/particle_name", data=names[:1])
    with copy(base, out, "t_backwards") as f:
        resumable(f, 5)
        f["macro/t"][5] = -f["macro/t"][5]
    with copy(base, out, "controlled") as f:
        # A run of mrvi optimize killed while writing: it carries /control.
        resumable(f, 5)
        f["control/u"] = np.zeros((10, 1))


def bodies_cases(base, out):
    with copy(base, out, "ok") as f:
        resumable(f, 5)
    with copy(base, out, "rotation_rank5") as f:
        resumable(f, 5)
        rows = f["bodies/rotation"].shape[0]
        replace(f, "bodies/rotation", data=np.zeros((rows, 1, 2, 2, 1)),
                maxshape=(None, 1, 2, 2, 1))
    with copy(base, out, "rotation_wider") as f:
        resumable(f, 5)
        rows = f["bodies/rotation"].shape[0]
        replace(f, "bodies/rotation", data=np.zeros((rows, 1, 2, 3)),
                maxshape=(None, 1, 2, 3))
    with copy(base, out, "position_huge") as f:
        resumable(f, 5)
        huge(f, "bodies/position", (f["macro/t"].shape[0], 1, 2**40))


def torsion_cases(base, out):
    with copy(base, out, "ok") as f:
        resumable(f, 5)
    rows = None
    with copy(base, out, "torsion_wider") as f:
        resumable(f, 5)
        a = f["macro/torsion_angle"][...]
        rows = a.shape[0]
        replace(f, "macro/torsion_angle",
                data=np.hstack([a, np.zeros((rows, 2))]),
                maxshape=(None, 3), chunks=True)
    with copy(base, out, "torsion_rank3") as f:
        resumable(f, 5)
        replace(f, "macro/torsion_angle", data=np.zeros((rows, 1, 1)),
                maxshape=(None, 1, 1))
    with copy(base, out, "torsion_missing") as f:
        resumable(f, 5)
        del f["macro/torsion_angle"]
    with copy(base, out, "torsion_huge") as f:
        resumable(f, 5)
        huge(f, "macro/torsion_angle", (rows, 2**40))


def from_cases(base, out):
    with copy(base, out, "desc_macro_step") as f:
        edit_description(f, "macro_step: 0.3", "macro_step: 0.2")
    with copy(base, out, "every_nan") as f:
        f.attrs["output_every"] = np.nan
    with copy(base, out, "macro_step_nan") as f:
        f.attrs["macro_step"] = np.nan
    with copy(base, out, "rate_huge") as f:
        huge(f, "model/rate", (200000000,), "i4")
    with copy(base, out, "q_rank3") as f:
        q = f["macro/q"][...]
        replace(f, "macro/q", data=q[:, :, None])
    with copy(base, out, "t_rank32") as f:
        replace(f, "macro/t", data=rank(32))
    with copy(base, out, "q_wider") as f:
        q = f["macro/q"][...]
        replace(f, "macro/q", data=np.hstack([q, q]))


def control_file(out, case):
    path = os.path.join(out, case + ".h5")
    print(case, path)
    return h5py.File(path, "w")


def controls_cases(out):
    with control_file(out, "ok") as f:
        f["control/u"] = np.full((10, 1), 0.25)
    with control_file(out, "u_wrapping") as f:
        huge(f, "control/u", (10, 2**61 + 1))
    with control_file(out, "u_rows_huge") as f:
        huge(f, "control/u", (10 * 2**40, 1))
    with control_file(out, "u_rank3") as f:
        f["control/u"] = np.zeros((10, 1, 1))
    with control_file(out, "u_strings") as f:
        f["control/u"] = strings([["a"]] * 10)
    with control_file(out, "u_missing") as f:
        f["control/v"] = np.zeros((10, 1))
    # non-finite values (round 17: refused naming the file and entry;
    # before, a NaN failed the run's first step and inf was replayed)
    with control_file(out, "u_nan") as f:
        u = np.full((10, 1), 0.25)
        u[3, 0] = np.nan
        f["control/u"] = u
    with control_file(out, "u_inf") as f:
        u = np.full((10, 1), 0.25)
        u[9, 0] = -np.inf
        f["control/u"] = u
    path = os.path.join(out, "not_hdf5.h5")
    with open(path, "w") as t:
        t.write("not an HDF5 file\n")
    print("not_hdf5", path)


def table_file(out, case, kind, **edits):
    """A table of mrvi converge / stability / timing (kind) in the format
    tests/test_plot.sh draws, with edits {dataset: value} applied (a
    tuple value: a huge declared shape)."""
    f = control_file(out, case)
    n = 5
    if kind == "conv":
        g = f.create_group("convergence/p1")
        g["macro_step"] = 0.1 / 2.0 ** np.arange(n)
        for k in ("e_q_mac", "e_p_mac", "e_q_mic", "e_p_mic", "e_qs_mac",
                  "e_qf_mac", "e_ps_mac", "e_pf_mac"):
            g[k] = 0.5 * g["macro_step"][()] ** 2
    elif kind == "stab":
        s = f.create_group("stability")
        s["p"] = np.arange(1, n + 1, dtype=np.int32)
        for rule in ("trapezoidal", "midpoint"):
            for k in ("analytic", "measured"):
                s["%s_%s" % (rule, k)] = np.full(n, 3.0)
            s["scan/trace_" + rule] = np.zeros((n, 7))
        s["scan/omega_dT"] = np.linspace(0.0, 6.0, 7)
        s["scan/p"] = np.arange(1, n + 1, dtype=np.int32)
    else:
        t = f.create_group("timing")
        t["p"] = np.arange(1, n + 1, dtype=np.int32)
        for k in ("macro_steps", "system_size", "assemble_per_step",
                  "solve_per_step", "time_per_step", "total_time",
                  "iterations"):
            t["midpoint-midpoint/" + k] = np.arange(1.0, n + 1.0)
    for name, value in edits.items():
        if isinstance(value, tuple):
            huge(f, name, value)
        else:
            del f[name]
            f[name] = value
    f.close()


def tables_cases(out):
    conv, stab, tim = "convergence/p1/", "stability/", "timing/"
    table_file(out, "conv_ok", "conv")
    table_file(out, "conv_rank2", "conv", **{conv + "macro_step": rank(2)})
    table_file(out, "conv_strings", "conv", **{conv + "e_q_mac": strings(
        ["a"] * 5)})
    table_file(out, "conv_huge", "conv", **{conv + "e_p_mac": (2**40,)})
    table_file(out, "conv_shorter", "conv", **{conv + "e_q_mic": np.ones(3)})
    table_file(out, "stab_ok", "stab")
    table_file(out, "stab_trace_rank3", "stab",
               **{stab + "scan/trace_midpoint": rank(3)})
    table_file(out, "stab_trace_wider", "stab",
               **{stab + "scan/trace_midpoint": np.zeros((5, 9))})
    table_file(out, "stab_p_huge", "stab", **{stab + "p": (2**61,)})
    table_file(out, "stab_bound_longer", "stab",
               **{stab + "midpoint_measured": np.ones(8)})
    table_file(out, "timing_ok", "timing")
    table_file(out, "timing_p_strings", "timing",
               **{tim + "p": strings(["1"] * 5)})
    table_file(out, "timing_total_rank2", "timing",
               **{tim + "midpoint-midpoint/total_time": np.ones((5, 2))})
    table_file(out, "timing_iterations_huge", "timing",
               **{tim + "midpoint-midpoint/iterations": (2**33,)})


def plotcontrol_cases(base, out):
    with copy(base, out, "ok") as f:
        pass
    with copy(base, out, "u_rank3") as f:
        replace(f, "control/u", data=rank(3))
    with copy(base, out, "u_huge") as f:
        huge(f, "control/u", (2**31, 2**31))
    with copy(base, out, "u_wider") as f:
        u = f["control/u"][()]
        replace(f, "control/u", data=np.hstack([u, u]))
    with copy(base, out, "names_numbers") as f:
        replace(f, "control/names", data=np.zeros(1))
    with copy(base, out, "t_rank2") as f:
        replace(f, "control/t", data=np.zeros((10, 2)))
    with copy(base, out, "pair_wider") as f:
        replace(f, "control/actuator_pair", data=np.zeros((1, 5), "i4"))
    with copy(base, out, "terminal_kind_numbers") as f:
        n = f["control/terminal_kind"].shape[0]
        replace(f, "control/terminal_kind", data=np.zeros(n))
    with copy(base, out, "terminal_target_longer") as f:
        n = f["control/terminal_target"].shape[0]
        replace(f, "control/terminal_target", data=np.zeros(n + 3))
    with copy(base, out, "history_rank3") as f:
        replace(f, "optimizer/history", data=rank(3))
    with copy(base, out, "history_huge") as f:
        huge(f, "optimizer/history", (2**40, 4))


def hang_cases(base, out):
    """Files on which HDF5's SWMR-read retries spun for tens of minutes."""
    data = open(base, "rb").read()
    assert data[:8] == b"\x89HDF\r\n\x1a\n" and data[8] in (2, 3)
    cases = {"truncated34": bytearray(data[:34])}
    for at in (20, 44):          # end-of-file address, checksum
        b = bytearray(data)
        b[at] ^= 0x5A
        cases["superblock%d" % at] = b
    for name in list(cases):
        b = bytearray(cases[name])
        b[11] |= 0x05            # open for writing, SWMR writing
        cases[name + "_flagged"] = b
    for name, b in sorted(cases.items()):
        path = os.path.join(out, name + ".h5")
        open(path, "wb").write(b)
        print(name, path)


def flips(seed, count, base, out):
    """count copies of base, each with 1 to 8 bytes set to random values."""
    data = open(base, "rb").read()
    rng = random.Random(seed)
    for i in range(count):
        b = bytearray(data)
        for _ in range(rng.randint(1, 8)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        path = os.path.join(out, "flip%03d.h5" % i)
        open(path, "wb").write(b)
        print("flip%03d" % i, path)


def main():
    kind = sys.argv[1]
    if kind == "flip":
        flips(int(sys.argv[2]), int(sys.argv[3]), sys.argv[4], sys.argv[5])
        return
    base, out = sys.argv[2], sys.argv[3]
    os.makedirs(out, exist_ok=True)
    {"export": export_cases, "resume": resume_cases, "from": from_cases,
     "bodies": bodies_cases, "torsion": torsion_cases, "hang": hang_cases,
     "controls": lambda b, o: controls_cases(o),
     "tables": lambda b, o: tables_cases(o),
     "plotcontrol": plotcontrol_cases}[kind](base, out)


main()
