"""Particle positions stored in an mrvi run file, for the export tests
(test_export.sh, test_export_ase.sh): what an XYZ frame must hold."""
import h5py
import numpy as np


def run_positions(h5, grid):
    """Times (K), positions (K x P x 3: 2-D and 1-D padded with zeros), rate
    (P: 0 slow, 1 fast) and names (P) of the P particles at the K stored
    macro nodes (grid "macro") or micro nodes ("micro": /micro/q_fast and,
    when present, /micro/q_slow)."""
    with h5py.File(h5, "r") as f:
        col = f["model/particle_column"][()]
        rate = f["model/rate"][()]
        d = int(f["model/dimension"][()])
        names = list(f["model/particle_name"].asstr()[()])
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
