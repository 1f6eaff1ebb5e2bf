"""Particle positions stored in an mrvi run file, for the export tests
(test_export.sh, test_export_ase.sh): what an XYZ frame must hold."""
import h5py
import numpy as np


def run_positions(h5, grid):
    """Times (K), positions (K x P x 3: 2-D and 1-D padded with zeros), rate
    (P: 0 slow, 1 fast) and names (P) of the P particles at the K stored
    macro nodes (grid "macro") or micro nodes ("micro": /micro/q_fast and,
    when present, /micro/q_slow); P = 0 for a model of bodies alone."""
    with h5py.File(h5, "r") as f:
        rate = f["model/rate"][()]
        if "model/particle_column" in f:
            col = f["model/particle_column"][()]
            d = int(f["model/dimension"][()])
            names = list(f["model/particle_name"].asstr()[()])
        else:  # rigid bodies only
            col, d, names = np.zeros(0, int), 0, []
        if grid == "macro":
            t, q = f["macro/t"][()], f["macro/q"][()]
        else:
            t = f["micro/t"][()]
            q = np.zeros((t.size, rate.size))
            q[:, rate == 1] = f["micro/q_fast"][()]
            if "micro/q_slow" in f:
                q[:, rate == 0] = f["micro/q_slow"][()]
    pos = np.zeros((t.size, col.size, 3))
    for j, c in enumerate(col):
        pos[:, j, :d] = q[:, c:c + d]
    return t, pos, rate[col], names


def body_points(h5, grid, t):
    """The XYZ atoms of the rigid bodies at the times t of the frames
    (doc/output.md, "Extended XYZ"): positions (K x B(1 + d) x 3), rate and
    names of each body's centre ("NAME") and director tips ("NAME.d1" ...,
    phi + s d_i, s half the largest distance from a centre to a joint point
    on it at the first node, 0.5 without joints).  Micro frames take a fast
    body's /micro/bodies row and a slow body as the scheme's slow rule sees
    it at micro node m of step j (arXiv 2406.12991 (3.18), doc/theory.md):
    (1 - m/p) x_j + (m/p) x_{j+1} for its centre and each director, frame
    i = j p + m (the run stores every macro node: output.every 1).
    Empty arrays without /bodies."""
    with h5py.File(h5, "r") as f:
        if "bodies/position" not in f:
            return np.zeros((t.size, 0, 3)), np.zeros(0, int), []
        pos, rot = f["bodies/position"][()], f["bodies/rotation"][()]
        nb, d = pos.shape[1], pos.shape[2]
        names = list(f["bodies/name"].asstr()[()])
        rate = f["model/rate"][()][f["bodies/column"][()]]
        arms = [np.linalg.norm(f["joints/position"][0, j] - pos[0, a])
                for j, a in enumerate(f["joints/body_a"][()])] \
            if "joints/position" in f else []
        s = 0.5 * max(arms) if arms and max(arms) > 0 else 0.5
        if grid == "macro":
            pos, rot = pos[:t.size], rot[:t.size]
        else:
            p = int(f.attrs["micro_steps"])
            assert int(f.attrs["output_every"]) == 1, "needs every node"
            i = np.arange(t.size)
            j, m = i // p, i % p
            last = j + 1 >= pos.shape[0]  # the last node: m = 0 there
            j1 = np.where(last, j, j + 1)
            w = (m / p)[:, None, None]
            pos = (1 - w) * pos[j] + w * pos[j1]
            rot = (1 - w[..., None]) * rot[j] + w[..., None] * rot[j1]
            if "bodies/fast" in f:
                fast = f["bodies/fast"][()]
                pos[:, fast] = f["micro/bodies/position"][:t.size]
                rot[:, fast] = f["micro/bodies/rotation"][:t.size]
    out = np.zeros((t.size, nb * (1 + d), 3))
    for b in range(nb):
        out[:, b * (1 + d), :d] = pos[:, b]
        for i in range(d):
            out[:, b * (1 + d) + 1 + i, :d] = pos[:, b] + s * rot[:, b, :, i]
    tips = [n + (".d%d" % i if i else "") for n in names for i in range(d + 1)]
    return out, np.repeat(rate, 1 + d), tips
