#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# Validate hapsim-view's VTK output with readers other than ours:
#  - meshio (Debian python3-meshio) reads every .vtu: points, triangle cells, point data, and the
#    numbers must match what was written (|displacement| == displacement_magnitude);
#  - Python's xml.etree parses the .pvd and the .vtu strictly (well-formed XML, the VTK
#    UnstructuredGrid/Collection structure ParaView expects, referenced files exist, increasing
#    timesteps).
# Without python3-meshio only the XML checks run, and the script says so.
#   tests/test_client_vtk.sh TEST_CLIENT_VIEW_BINARY [DIR_WITH_VTK]
# With DIR given (e.g. hapsim-view --out DIR) it validates that folder instead of generating one.
set -eu
bin=$1
if [ $# -ge 2 ]; then
    dir=$2
else
    dir=$(mktemp -d /tmp/hs_client_vtk.XXXXXX)
    trap 'rm -rf "$dir"' EXIT
    HS_CLIENT_VTK_DIR=$dir "$bin" test_vtk_series >/dev/null
fi
# Debian's interpreter first: python3-meshio lives in its dist-packages (a pyenv python3 earlier
# in PATH would not see it).
py=/usr/bin/python3
[ -x "$py" ] || py=$(command -v python3) || { echo "SKIP: python3 not found"; exit 77; }
"$py" - "$dir" <<'PY'
import glob, os, sys, math
import xml.etree.ElementTree as ET
d = sys.argv[1]
pvd = os.path.join(d, "hapsim.pvd")
root = ET.parse(pvd).getroot()
assert root.tag == "VTKFile" and root.get("type") == "Collection", root.attrib
sets = root.find("Collection").findall("DataSet")
assert sets, "empty collection"
times = [float(s.get("timestep")) for s in sets]
assert all(b > a for a, b in zip(times, times[1:])), times
files = [os.path.join(d, s.get("file")) for s in sets]
for f in files:
    assert os.path.exists(f), f
    r = ET.parse(f).getroot()
    assert r.tag == "VTKFile" and r.get("type") == "UnstructuredGrid", f
    piece = r.find("UnstructuredGrid/Piece")
    npts, ncells = int(piece.get("NumberOfPoints")), int(piece.get("NumberOfCells"))
    pts = piece.find("Points/DataArray").text.split()
    assert len(pts) == 3 * npts, (f, len(pts), npts)
    cells = {a.get("Name"): a.text.split() for a in piece.find("Cells").findall("DataArray")}
    assert len(cells["connectivity"]) == 3 * ncells and len(cells["types"]) == ncells
    assert all(t == "5" for t in cells["types"])
    assert [int(o) for o in cells["offsets"]] == [3 * (i + 1) for i in range(ncells)]
    assert all(0 <= int(c) < npts for c in cells["connectivity"])
    for a in piece.find("PointData").findall("DataArray"):
        comp = int(a.get("NumberOfComponents", "1"))
        assert len(a.text.split()) == comp * npts, (f, a.get("Name"))
print("xml: %d files in %s, timesteps %g .. %g" % (len(files), pvd, times[0], times[-1]))
try:
    import meshio, numpy as np
except ImportError:
    print("note: python3-meshio not installed: XML checks only")
    sys.exit(0)
for f in files:
    m = meshio.read(f)
    tri = m.cells_dict.get("triangle")
    assert tri is not None and tri.shape[1] == 3, f
    disp = np.asarray(m.point_data["displacement"])
    mag = np.asarray(m.point_data["displacement_magnitude"])
    assert disp.shape == (len(m.points), 3) and mag.shape == (len(m.points),), f
    assert np.allclose(np.linalg.norm(disp, axis=1), mag, rtol=1e-5, atol=1e-9), f
    assert np.isfinite(m.points).all()
    rest = np.asarray(m.point_data["rest_position"])
    assert np.allclose(m.points - rest, disp, rtol=1e-5, atol=1e-6), f
    fd = m.field_data
    assert fd["tool_force_n"].shape[-1] == 3 and fd["tool_position_m"].shape[-1] == 3, f
    assert len(fd["tool_device"].ravel()) == fd["tool_force_n"].reshape(-1, 3).shape[0], f
    assert np.isfinite(fd["TimeValue"]).all(), f
print("meshio %s: read %d .vtu files, %d points and %d triangles in the last; rest_position, "
      "TimeValue and tool field data consistent" % (meshio.__version__, len(files), len(m.points), len(tri)))
PY
