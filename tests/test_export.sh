#!/bin/bash
# Test of the pictures of the motion (src/io/export.c, src/cli/cli_export.c,
# doc/output.md "Viewing the motion"): the XDMF file `mrvi run` writes and
# `mrvi export --format xdmf` rewrites is checked against the HDF5 file it
# names (every referenced dataset exists with the stated shape and type,
# every HyperSlab fits, the points it selects are the particles of
# /macro/q, one grid per stored macro node at its time), also for a run
# stopped by SIGINT and one killed by SIGKILL; the extended XYZ frames read
# back equal to /macro/q (or the micro nodes) to the printed digits.
# ParaView is not needed: the XML is read with xml.etree and the data with
# h5py.
#
#   test_export.sh MRVI_BINARY SOURCE_ROOT
#
# Skipped (exit 77) when Debian's /usr/bin/python3 lacks h5py.

set -u

mrvi=${1:?usage: test_export.sh MRVI_BINARY SOURCE_ROOT}
root=${2:?usage: test_export.sh MRVI_BINARY SOURCE_ROOT}

# shellcheck source=tests/testlib.sh
. "$(dirname "$0")/testlib.sh"
need_python h5py numpy xml.etree.ElementTree
export MRVI_TESTS
MRVI_TESTS=$(cd "$(dirname "$0")" && pwd)
cd "$tmp" || exit 1

# fails_with NAME PATTERN CMD...: exit 1 and PATTERN on stderr
fails_with() {
  local name=$1 pattern=$2
  shift 2
  "$@" >out.txt 2>err.txt
  local rc=$?
  if [ $rc -ne 1 ]; then
    fail "$name: exit $rc, expected 1"
  elif ! grep -q -- "$pattern" err.txt; then
    fail "$name: no '$pattern' in: $(head -1 err.txt)"
  else
    pass "$name ($(head -1 err.txt))"
  fi
}

# py_ok NAME SCRIPT ARGS...: the Python check prints "ok ..." lines only
py_ok() {
  local name=$1 script=$2
  shift 2
  if "$py" "$script" "$@" >py.txt 2>&1 && ! grep -qv '^ok' py.txt; then
    pass "$name: $(tr '\n' ' ' <py.txt | cut -c1-150)"
  else
    fail "$name"
    sed 's/^/     /' py.txt | head -20
  fi
}

# --- the XDMF checker -------------------------------------------------------
cat >check_xdmf.py <<'EOF'
"""check_xdmf.py FILE.xdmf [ROWS]: every DataItem of the XDMF file against
the HDF5 file it names; ROWS: the expected number of stored macro nodes."""
import os
import sys
import xml.etree.ElementTree as ET

import h5py
import numpy as np

path = sys.argv[1]
base = os.path.dirname(os.path.abspath(path))
tree = ET.parse(path)
files = {}


def fail(msg):
    print("FAIL " + msg)
    sys.exit(1)


def dims_of(item):
    return [int(x) for x in item.get("Dimensions").split()]


def hdf(item):
    """The dataset an HDF DataItem names, checked against the item."""
    ref = item.text.strip()
    fname, dset = ref.rsplit(":", 1)
    full = fname if os.path.isabs(fname) else os.path.join(base, fname)
    if full not in files:
        if not os.path.exists(full):
            fail("%s: no such HDF5 file" % fname)
        files[full] = h5py.File(full, "r")
    f = files[full]
    if dset not in f:
        fail("%s: no dataset %s" % (fname, dset))
    d = f[dset]
    if list(d.shape) != dims_of(item):
        fail("%s: shape %s, the XDMF says %s" % (dset, d.shape, dims_of(item)))
    kind = item.get("NumberType")
    prec = int(item.get("Precision"))
    if (kind == "Float") != (d.dtype.kind == "f") or prec != d.dtype.itemsize:
        fail("%s: %s, the XDMF says %s %d" % (dset, d.dtype, kind, prec))
    return d[()]


def values(item):
    """The values a DataItem stands for (HDF, XML or HyperSlab)."""
    if item.get("ItemType") == "HyperSlab":
        sel, src = list(item.findall("DataItem"))
        data = values(src)
        s = np.array(sel.text.split(), dtype=int).reshape(dims_of(sel))
        if s.shape != (3, data.ndim):
            fail("HyperSlab selection %s for rank %d" % (s.shape, data.ndim))
        start, stride, count = s
        last = start + (count - 1) * stride
        if np.any(start < 0) or np.any(count < 1) or np.any(stride < 1) or \
                np.any(last >= data.shape):
            fail("HyperSlab %s does not fit shape %s" % (s.tolist(),
                                                         data.shape))
        out = data[tuple(slice(a, b + 1, c)
                         for a, b, c in zip(start, last, stride))]
        if int(np.prod(dims_of(item))) != out.size:
            fail("HyperSlab selects %d values, Dimensions say %s"
                 % (out.size, dims_of(item)))
        return out.reshape(-1)
    if item.get("Format") == "XML":
        return np.array(item.text.split(), dtype=float)
    return hdf(item)


root = tree.getroot()
domain = root.find("Domain")
colls = domain.findall("Grid")
h5 = None
nodes = 0
for coll in colls:
    if coll.get("GridType") != "Collection" or \
            coll.get("CollectionType") != "Temporal":
        fail("top-level grid %s is not a temporal collection"
             % coll.get("Name"))
    grids = coll.findall("Grid")
    for k, g in enumerate(grids):
        if g.get("GridType") != "Uniform":
            fail("grid %s is not uniform" % g.get("Name"))
        geo = g.find("Geometry")
        gtype = geo.get("GeometryType")
        items = geo.findall("DataItem")
        pts = [values(i) for i in items]
        if gtype in ("XY", "XYZ"):
            ncomp = len(gtype)
            xyz = pts[0].reshape(-1, ncomp)
        elif gtype == "X_Y_Z":
            xyz = np.stack(pts, axis=1)
        else:
            fail("geometry type %s" % gtype)
        # The points are the particles of /macro/q, row k.
        slab = items[0]
        src = slab.findall("DataItem")[1]
        fname = src.text.strip().rsplit(":", 1)[0]
        fname = fname if os.path.isabs(fname) else os.path.join(base, fname)
        f = files[fname]
        h5 = f
        q = f["macro/q"][k]
        col = f["model/particle_column"][()]
        d = int(f["model/dimension"][()])
        want = np.stack([q[col + a] for a in range(d)], axis=1)
        if xyz.shape[0] != col.size or \
                not np.array_equal(xyz[:, :d], want) or \
                np.any(xyz[:, d:] != 0):
            fail("grid %s: points differ from /macro/q row %d" % (k, k))
        t = float(g.find("Time").get("Value"))
        if t != f["macro/t"][k]:
            fail("grid %d: Time %r, /macro/t %r" % (k, t, f["macro/t"][k]))
        topo = g.find("Topology")
        ne = int(topo.get("NumberOfElements"))
        npe = int(topo.get("NodesPerElement"))
        conn = topo.find("DataItem")
        if topo.get("TopologyType") == "Polyvertex":
            if conn is not None or ne != col.size or npe != 1:
                fail("points topology %s" % topo.attrib)
        elif topo.get("TopologyType") == "Polyline":
            e = values(conn).reshape(-1, 2)
            if npe != 2 or e.shape[0] != ne or e.min() < 0 or \
                    e.max() >= col.size:
                fail("lines topology %s" % topo.attrib)
        else:
            fail("topology %s" % topo.get("TopologyType"))
        for a in g.findall("Attribute"):
            v = values(a.find("DataItem"))
            size = col.size if a.get("Center") == "Node" else ne
            if v.size != size:
                fail("attribute %s: %d values for %d" % (a.get("Name"),
                                                         v.size, size))
            if a.get("Name") == "rate" and \
                    not np.array_equal(v, f["model/rate"][()][col]):
                fail("attribute rate differs from /model/rate")
    nodes = len(grids)
    if nodes != f["macro/t"].shape[0]:
        fail("%s: %d grids for %d macro nodes" % (coll.get("Name"), nodes,
                                                   f["macro/t"].shape[0]))
names = [c.get("Name") for c in colls]
print("ok %s, %d nodes each, %d datasets checked" % (
    "+".join(names), nodes, sum(1 for _ in root.iter("DataItem"))))
if len(sys.argv) > 2 and nodes != int(sys.argv[2]):
    print("FAIL %d nodes, expected %s" % (nodes, sys.argv[2]))
    sys.exit(1)
EOF

# --- the XYZ reader -----------------------------------------------------------
cat >check_xyz.py <<'EOF'
"""check_xyz.py FILE.xyz FILE.h5 EVERY GRID SPECIES: read the extended XYZ
frames back and compare them with the run file (GRID macro or micro)."""
import os
import sys

import numpy as np

sys.path.insert(0, os.environ["MRVI_TESTS"])
from run_positions import run_positions  # noqa: E402

xyz, h5, every, grid, species = sys.argv[1:6]
every = int(every)
t, pos, rate, names = run_positions(h5, grid)
lines = open(xyz).read().split("\n")
frames = []
i = 0
while i < len(lines) and lines[i].strip():
    n = int(lines[i])
    head = lines[i + 1]
    body = [ln.split() for ln in lines[i + 2:i + 2 + n]]
    frames.append((head, body))
    i += 2 + n
rows = list(range(0, t.size, every))
assert len(frames) == len(rows), "%d frames, expected %d" % (len(frames),
                                                            len(rows))
worst = 0.0
for (head, body), k in zip(frames, rows):
    keys = dict(kv.split("=", 1) for kv in head.replace('"F F F"', "F").split())
    assert keys["Properties"] == \
        "species:S:1:pos:R:3:rate:I:1:name:S:1", head
    assert float(keys["Time"]) == t[k], (head, t[k])
    assert "Lattice" not in keys
    assert len(body) == len(names)
    for j, fields in enumerate(body):
        want_species = {"name": names[j], "x": "X",
                        "rate": "fast" if rate[j] == 1 else "slow"}
        assert fields[0] == want_species[species], (fields[0], species)
        assert len(fields) == 6 and int(fields[4]) == rate[j] and \
            fields[5] == names[j], fields
        x = np.array(fields[1:4], dtype=float)
        worst = max(worst, float(np.max(np.abs(x - pos[k, j]))))
assert worst == 0.0, "positions differ from the file by %g" % worst
print("ok %d frames of %d particles equal to %s to the last digit"
      % (len(frames), len(names), "/macro/q" if grid == "macro" else
         "/micro (q_slow, q_fast)"))
EOF

# --- runs ---------------------------------------------------------------------
run_ok "mrvi run lattice (2-D, micro_slow)" "$mrvi" run \
  "$root/systems/lattice.yaml" -o lattice.h5 --set integrator.t_end=0.5 \
  --set output.micro_slow=true
grep -q "lattice.xdmf" out.txt && pass "summary names lattice.xdmf" ||
  fail "summary names lattice.xdmf: $(cat out.txt)"
[ -f lattice.xdmf ] && pass "lattice.xdmf written beside lattice.h5" ||
  fail "no lattice.xdmf"
py_ok "lattice.xdmf against lattice.h5 (11 nodes)" check_xdmf.py lattice.xdmf 11

run_ok "mrvi run spring_ring (3-D)" "$mrvi" run \
  "$root/systems/spring_ring.yaml" -o ring.h5 --set integrator.t_end=0.05
py_ok "ring.xdmf against ring.h5 (6 nodes)" check_xdmf.py ring.xdmf 6

run_ok "mrvi run cart_pendulum (rod)" "$mrvi" run \
  "$root/systems/cart_pendulum.yaml" -o cart.h5 --set integrator.t_end=0.1 \
  --quiet
py_ok "cart.xdmf against cart.h5 (6 nodes)" check_xdmf.py cart.xdmf 6
if "$py" -c '
import h5py, sys
f = h5py.File("cart.h5", "r")
ok = f["model/edges"][()].tolist() == [[0, 1]] and \
    f["model/edge_rate"][()].tolist() == [2]
sys.exit(0 if ok else 1)'; then
  pass "cart_pendulum: the rod is edge 0-1 with edge_rate 2"
else
  fail "cart_pendulum: the rod is edge 0-1 with edge_rate 2"
fi
grep -q 'Name="bonds"' cart.xdmf && pass "cart.xdmf has the bonds" ||
  fail "cart.xdmf has the bonds"

run_ok "mrvi run fpu (no particles)" "$mrvi" run "$root/systems/fpu.yaml" \
  -o fpu.h5 --set integrator.t_end=0.6
[ ! -e fpu.xdmf ] && pass "no XDMF for generalised coordinates" ||
  fail "fpu.xdmf written for a model without particles"
grep -q XDMF out.txt && fail "fpu summary mentions XDMF" ||
  pass "fpu summary does not mention XDMF"
fails_with "export of a run without particles" "no particles" \
  "$mrvi" export fpu.h5 --format xyz

run_ok "output.xdmf: false" "$mrvi" run "$root/systems/lattice.yaml" \
  -o noxdmf.h5 --set integrator.t_end=0.1 --set output.xdmf=false --quiet
[ ! -e noxdmf.xdmf ] && pass "output.xdmf: false writes no XDMF" ||
  fail "output.xdmf: false still wrote noxdmf.xdmf"

# A file of the user's with the XDMF name is not overwritten (--force does).
echo "my notes" >mine.xdmf
run_ok "run beside a foreign mine.xdmf" "$mrvi" run \
  "$root/systems/lattice.yaml" -o mine.h5 --set integrator.t_end=0.1 --quiet
grep -q "not overwritten" err.txt && [ "$(cat mine.xdmf)" = "my notes" ] &&
  pass "a foreign .xdmf is kept, with a warning" ||
  fail "a foreign .xdmf is kept: $(cat err.txt)"
run_ok "--force replaces it" "$mrvi" run "$root/systems/lattice.yaml" \
  -o mine.h5 --set integrator.t_end=0.1 --quiet --force
py_ok "mine.xdmf written with --force" check_xdmf.py mine.xdmf 3

# --- mrvi export --format xdmf -------------------------------------------------
run_ok "mrvi export --format xdmf" "$mrvi" export lattice.h5 --format xdmf \
  -o again.xdmf
sed 's/again\.xdmf/lattice.xdmf/' again.xdmf | cmp -s - lattice.xdmf &&
  pass "export rewrites the XDMF of mrvi run byte for byte" ||
  fail "export --format xdmf differs from the XDMF of mrvi run"
mkdir -p sub
run_ok "XDMF in another directory" "$mrvi" export lattice.h5 -f xdmf \
  -o sub/lattice.xdmf
grep -q "$tmp/lattice.h5:/macro/q" sub/lattice.xdmf &&
  pass "another directory: the HDF5 file by absolute path" ||
  fail "another directory: the HDF5 file by absolute path"
py_ok "sub/lattice.xdmf against lattice.h5" check_xdmf.py sub/lattice.xdmf 11

# A run stopped by SIGINT: the XDMF has the nodes the file holds.
"$mrvi" run "$root/systems/lattice.yaml" -o stopped.h5 \
  --set integrator.t_end=2000 --quiet >/dev/null 2>stopped.err &
pid=$!
sleep 1.5
kill -INT $pid
wait $pid
rc=$?
rows=$("$py" -c 'import h5py; print(h5py.File("stopped.h5","r")["macro/t"].shape[0])')
if [ $rc -eq 130 ] && [ "${rows:-0}" -gt 1 ] && [ "$rows" -lt 40001 ]; then
  pass "SIGINT stops the run (exit 130, $rows of 40001 nodes stored)"
else
  fail "SIGINT stops the run (exit $rc, ${rows:-?} nodes)"
fi
py_ok "stopped.xdmf: the $rows stored nodes" check_xdmf.py stopped.xdmf "$rows"

# A run killed by SIGKILL writes no XDMF; mrvi export writes one for the
# nodes of the last flush.
"$mrvi" run "$root/systems/lattice.yaml" -o killed.h5 \
  --set integrator.t_end=2000 --set output.flush_interval=0.2 --quiet \
  >/dev/null 2>&1 &
pid=$!
sleep 1.5
kill -KILL $pid
wait $pid 2>/dev/null
[ ! -e killed.xdmf ] && pass "SIGKILL: no XDMF" || fail "SIGKILL: XDMF exists"
run_ok "mrvi export --format xdmf of the killed run" "$mrvi" export killed.h5 \
  --format xdmf
rows=$("$py" -c 'import h5py; print(h5py.File("killed.h5","r",swmr=True)["macro/t"].shape[0])')
grep -q 'incomplete (writer killed)' "$tmp/err.txt" &&
  pass "mrvi export notes the killed run" ||
  fail "mrvi export: no note on the killed run: $(cat "$tmp/err.txt")"
# HDF5's own tools need its "open for writing" flag cleared (doc/output.md).
h5clear -s killed.h5 2>/dev/null
py_ok "killed.xdmf: the $rows flushed nodes" check_xdmf.py killed.xdmf "$rows"

# --- mrvi export --format xyz --------------------------------------------------
run_ok "mrvi export --format xyz" "$mrvi" export lattice.h5 --format xyz
[ "$(cat out.txt)" = lattice.xyz ] && pass "prints lattice.xyz" ||
  fail "prints the output name: $(cat out.txt)"
py_ok "XYZ round trip (macro nodes)" check_xyz.py lattice.xyz lattice.h5 1 \
  macro x
run_ok "xyz --every 3 --species name" "$mrvi" export lattice.h5 -f xyz \
  --every 3 --species name -o every3.xyz
py_ok "XYZ every 3rd frame with names" check_xyz.py every3.xyz lattice.h5 3 \
  macro name
run_ok "xyz --micro" "$mrvi" export lattice.h5 -f xyz --micro -o micro.xyz
py_ok "XYZ on the micro grid (q_slow, q_fast)" check_xyz.py micro.xyz \
  lattice.h5 1 micro x
run_ok "xyz 3-D --species rate" "$mrvi" export ring.h5 -f xyz --species rate
py_ok "XYZ round trip 3-D" check_xyz.py ring.xyz ring.h5 1 macro rate
fails_with "--micro without /micro/q_slow" "output.micro_slow: true" \
  "$mrvi" export ring.h5 -f xyz --micro

# --- bad arguments ---------------------------------------------------------------
fails_with "missing --format" "missing --format" "$mrvi" export lattice.h5
fails_with "unknown format" "unknown format 'pdb'" "$mrvi" export lattice.h5 \
  --format pdb
fails_with "--species pdb" "--species x, rate or name" "$mrvi" export \
  lattice.h5 -f xyz --species pdb
fails_with "--every 0" "positive integer" "$mrvi" export lattice.h5 -f xyz \
  --every 0
fails_with "misspelt option" "did you mean '--every'" "$mrvi" export \
  lattice.h5 -f xyz --evry 2
fails_with "missing file" "cannot open" "$mrvi" export nothing.h5 -f xyz
fails_with "--every with xdmf" "options of --format xyz" "$mrvi" export \
  lattice.h5 -f xdmf --every 2
run_ok "mrvi help export" "$mrvi" help export
grep -q "extended XYZ" out.txt && pass "help export explains xyz" ||
  fail "help export explains xyz"

test_finish
