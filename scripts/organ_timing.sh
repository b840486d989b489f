#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# Sim step timing inside the running server on organ meshes (docs/benchmarks.md, "Organs in
# the running server"): for each mesh and solver setting, a scene from scripts/organ_scene.py (held
# at its lowest 10 % in z), hapsim-server over LCM and hapsim-stylus pressing its top node one
# probe radius deep and holding 6 s; prints CSV of the server's own start line and exit summary.
#   scripts/organ_timing.sh [BIN_DIR] [OUT_CSV] [SOLVERS]
# BIN_DIR: build/bin; OUT_CSV: stdout; SOLVERS: "direct default" ("default": the scene says
# nothing, i.e. auto). Runs itself inside tests/netns.sh (private network, ttl=0). The 25k-tet
# liver is made from liver2's surface with the gmsh command line (apt-get install gmsh).
# HS_MESHES (default /work/shared/meshes, else ../shared/meshes) holds tongue and
# aneurysm_vessel. HS_KEEP=1 keeps the work folder.
set -eu
here=$(cd "$(dirname "$0")" && pwd)
src=$(dirname "$here")
bin=${1:-$src/build/bin}
out=${2:-}
solvers=${3:-direct default}
if [ "${HS_NETNS_INSIDE:-0}" != 1 ]; then
    exec "$src/tests/netns.sh" "$0" "$bin" "$out" "$solvers"
fi
meshes=${HS_MESHES:-/work/shared/meshes}
[ -d "$meshes" ] || meshes=$src/../shared/meshes
for f in "$bin/hapsim-server" "$bin/hapsim-stylus"; do
    [ -x "$f" ] || { echo "organ_timing: $f not built (make build)" >&2; exit 1; }
done
command -v gmsh >/dev/null || { echo "organ_timing: gmsh not found (apt-get install gmsh)" >&2; exit 1; }
tmp=$(mktemp -d /tmp/hs_organs.XXXXXX)
srv=
cleanup() {
    [ -n "$srv" ] && kill "$srv" 2>/dev/null
    wait 2>/dev/null || true
    [ "${HS_KEEP:-0}" = 1 ] || rm -rf "$tmp"
}
trap cleanup EXIT

# The 25k-tet liver: liver2's boundary as STL, remeshed and filled by gmsh at 6.1 mm.
python3 - "$meshes/liver2.msh" "$tmp/liver2_surf.stl" <<'PY'
import sys
L = open(sys.argv[1]).read().split("\n")
i = L.index("$Nodes"); n = int(L[i + 1]); P = {}
for l in L[i + 2:i + 2 + n]:
    t = l.split(); P[int(t[0])] = tuple(float(x) for x in t[1:4])
j = L.index("$Elements"); m = int(L[j + 1]); F = {}
for l in L[j + 2:j + 2 + m]:
    t = l.split()
    if t[1] != "4":
        continue
    nt = int(t[2]); v = [int(x) for x in t[3 + nt:7 + nt]]
    for f in ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)):
        tri = tuple(v[k] for k in f); F.setdefault(tuple(sorted(tri)), []).append(tri)
o = open(sys.argv[2], "w"); o.write("solid s\n")
for v in F.values():
    if len(v) == 1:
        o.write("facet normal 0 0 0\n outer loop\n")
        for k in v[0]:
            o.write("  vertex %.9g %.9g %.9g\n" % P[k])
        o.write(" endloop\nendfacet\n")
o.write("endsolid s\n")
PY
cat >"$tmp/liver25k.geo" <<GEO
Merge "liver2_surf.stl";
ClassifySurfaces{40*Pi/180, 1, 1, Pi};
CreateGeometry;
Surface Loop(1) = Surface{:};
Volume(1) = {1};
Physical Volume(1) = {1};
Mesh.MeshSizeMin = 0.0061;
Mesh.MeshSizeMax = 0.0061;
Mesh.MshFileVersion = 2.2;
GEO
(cd "$tmp" && gmsh -3 liver25k.geo -o liver25k.msh >gmsh.log 2>&1) ||
    { echo "organ_timing: gmsh failed: $(tail -n 3 "$tmp/gmsh.log")" >&2; exit 1; }

H='udpm://239.255.76.67:7967?ttl=0'
M='udpm://239.255.76.67:7968?ttl=0'
row() { # NAME MESH RADIUS SOLVER
    name=$1
    python3 "$here/organ_scene.py" "$2" "$3" "$4" "$tmp/$name.json" "$tmp/$name.probe" 6 1 >/dev/null
    log=$tmp/$name-$4.log
    : >"$log"
    "$bin/hapsim-server" "$tmp/$name.json" --haptic-url "$H" --mesh-url "$M" --duration 30 \
        >"$log" 2>&1 &
    srv=$!
    i=0
    until grep -q "running;" "$log"; do
        i=$((i + 1))
        if [ $i -gt 600 ] || ! kill -0 $srv 2>/dev/null; then
            echo "organ_timing: server did not start on $name: $(tail -n 3 "$log")" >&2
            exit 1
        fi
        sleep 0.1
    done
    "$bin/hapsim-stylus" --script "$tmp/$name.probe" --haptic-url "$H" \
        --trace "$tmp/$name-$4.csv" >"$tmp/$name-$4.sty" 2>&1 || true
    kill -INT $srv 2>/dev/null || true
    wait $srv || true
    srv=
    tets=$(sed -n 's/.* nodes, \([0-9]*\) tets,.*/\1/p' "$log" | head -n 1)
    # The compliance is set up in the background: the start line or the "ready" line.
    setup=$(sed -n -e 's/.*compliance set-up \([0-9.]*\) ms.*/\1/p' \
        -e 's/.*compliance ready after \([0-9.]*\) ms.*/\1/p' "$log" | head -n 1)
    start=$(sed -n 's/^  solver   \([a-z]*\).*/\1/p' "$log" | head -n 1)
    s=$(grep "deformation steps; sim step" "$log" | head -n 1)
    steps=$(echo "$s" | sed -n 's/^hapsim-server: \([0-9]*\) deformation.*/\1/p')
    p50=$(echo "$s" | sed -n 's/.*sim step p50 \([0-9.]*\) ms.*/\1/p')
    p99=$(echo "$s" | sed -n 's/.*, p99 \([0-9.]*\) ms (step.*/\1/p')
    over=$(echo "$s" | sed -n 's/.*), \([0-9]*\) overruns.*/\1/p')
    c50=$(echo "$s" | sed -n 's/.*thread CPU p50 \([0-9.]*\) ms.*/\1/p')
    c99=$(echo "$s" | sed -n 's/.*thread CPU p50 [0-9.]* ms, p99 \([0-9.]*\) ms.*/\1/p')
    rate=$(echo "$s" | sed -n 's/.*; rate \([0-9.]*\) Hz.*/\1/p')
    solver=$(echo "$s" | sed -n 's/.*; solver \([a-z]*\).*/\1/p')
    sw=$(echo "$s" | sed -n 's/.*auto, \([0-9]*\) switches.*/\1/p')
    steady=$(sed -n 's/.*steady \([0-9.]*\) N.*/\1/p' "$tmp/$name-$4.sty" | head -n 1)
    load=$(cut -d' ' -f1 /proc/loadavg)
    echo "$name,$tets,$4,$start,${solver:-?},${sw:-0},$setup,$steps,$p50,$p99,$c50,$c99,$over,$rate,$3,${steady:-},$load"
}
{
    echo "mesh,tets,scene_solver,start_solver,end_solver,switches,setup_ms,steps,sim_step_ms_p50,sim_step_ms_p99,cpu_ms_p50,cpu_ms_p99,overruns_16.7ms,sim_hz_end,probe_radius_m,steady_force_n,load1"
    for sv in $solvers; do
        row tongue "$meshes/tongue.msh" 0.005 "$sv"
        row vessel "$meshes/aneurysm_vessel.msh" 0.002 "$sv"
        row liver25k "$tmp/liver25k.msh" 0.005 "$sv"
    done
} | if [ -n "$out" ]; then tee "$out"; else cat; fi
