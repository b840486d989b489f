#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# hapsim-mesh on the command line: required units, broken input named, repairs printed, info
# and points as JSON, a scene from a surface in millimetres with a group made from a plane.
#   tests/test_mesh_cli.sh BIN_DIR SOURCE_DIR
set -u
bin=$1
src=$2
hm="$bin/hapsim-mesh"
tmp=$(mktemp -d /tmp/hs_mesh_cli.XXXXXX)
trap 'rm -rf "$tmp"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

# A surface in millimetres (the liver's boundary scaled), as a segmentation exports it.
"$hm" surface "$src/scenes/liver/liver2.msh" --out "$tmp/liver_m.obj" >/dev/null || fail surface
awk '/^v / { printf "v %.9g %.9g %.9g\n", $2 * 1000, $3 * 1000, $4 * 1000; next } { print }' \
    "$tmp/liver_m.obj" >"$tmp/liver.obj"

# No --units: refused (exit 2) with the reason.
"$hm" tet "$tmp/liver.obj" --size 10 >"$tmp/o" 2>&1
[ $? = 2 ] && grep -q "units mm|m is required" "$tmp/o" || fail "tet without --units: $(cat "$tmp/o")"
# Millimetres read as metres: warned.
"$hm" tet "$tmp/liver.obj" --size 10 --units m --out "$tmp/x.msh" >"$tmp/o" 2>&1
grep -q "is it in millimetres" "$tmp/o" || fail "no units warning: $(cat "$tmp/o")"

# An open surface: exit 1, the file and the problem named; --repair closes it and says so.
head -n -1 "$tmp/liver.obj" >"$tmp/open.obj"
"$hm" tet "$tmp/open.obj" --size 12 --units mm >"$tmp/o" 2>&1
[ $? = 1 ] && grep -q "$tmp/open.obj: open surface: 3 boundary edges" "$tmp/o" ||
    fail "open surface: $(cat "$tmp/o")"
"$hm" tet "$tmp/open.obj" --size 12 --units mm --repair --out "$tmp/open.msh" >"$tmp/o" 2>&1 ||
    fail "repair: $(cat "$tmp/o")"
grep -q "1 holes closed" "$tmp/o" || fail "repair not reported: $(cat "$tmp/o")"

# A mesh with an inverted tet: every tool prints the repair.
cat >"$tmp/inv.msh" <<'MSH'
$MeshFormat
2.2 0 8
$EndMeshFormat
$Nodes
5
1 0 0 0
2 1 0 0
3 0 1 0
4 0 0 1
5 1 1 1
$EndNodes
$Elements
2
1 4 2 0 1 1 2 3 4
2 4 2 0 1 2 3 5 4
$EndElements
MSH
"$hm" info "$tmp/inv.msh" >"$tmp/o" 2>&1 || fail "info inv: $(cat "$tmp/o")"
grep -q "repaired on loading" "$tmp/o" && grep -q "1 tets reoriented .*: element 2$" "$tmp/o" ||
    fail "repair not printed: $(cat "$tmp/o")"

# Quality as JSON; points as JSON and as probe-script lines.
"$hm" info "$tmp/open.msh" --json >"$tmp/info.json" || fail "info json"
python3 -c "
import json, sys
d = json.load(open('$tmp/info.json'))
assert d['tets'] > 1000 and d['pieces'] == 1 and d['below_5deg'] == 0, d
assert sum(d['radius_ratio_hist']) == d['tets'] and 0.0011 < d['volume_m3'] < 0.00114, d
" || fail "info json content: $(cat "$tmp/info.json")"
"$hm" points "$tmp/open.msh" --count 5 --up 0,1,0 --json >"$tmp/pts.json" || fail "points json"
python3 -c "
import json
d = json.load(open('$tmp/pts.json'))
assert len(d['points']) == 5 and d['top']['normal'][1] > 0.9, d
" || fail "points json content: $(cat "$tmp/pts.json")"
"$hm" points "$tmp/open.msh" --count 3 >"$tmp/pts.probe" || fail "points"
[ "$(grep -c '^touch ' "$tmp/pts.probe")" = 3 ] && [ "$(grep -c '^surface ' "$tmp/pts.probe")" = 3 ] ||
    fail "points lines: $(cat "$tmp/pts.probe")"

# Graded: finer near a group (--refine): the group holds several times the nodes.
"$hm" tet "$tmp/liver.obj" --units mm --size 12 --group hilum:plane:0,-43.3,0,0,1,0 \
    --out "$tmp/u.msh" >"$tmp/u.log" 2>&1 || fail "uniform: $(cat "$tmp/u.log")"
"$hm" tet "$tmp/liver.obj" --units mm --size 12 --group hilum:plane:0,-43.3,0,0,1,0 \
    --refine hilum:4,20 --out "$tmp/r.msh" >"$tmp/r.log" 2>&1 || fail "refine: $(cat "$tmp/r.log")"
nu=$(sed -n "s/^region *'hilum' .*: \([0-9]*\) nodes/\1/p" "$tmp/u.log")
nr=$(sed -n "s/^region *'hilum' .*: \([0-9]*\) nodes/\1/p" "$tmp/r.log")
echo "hilum nodes: uniform $nu, refined $nr"
[ -n "$nu" ] && [ -n "$nr" ] && [ "$nr" -gt $((3 * nu)) ] || fail "--refine did not refine ($nu -> $nr)"
"$hm" tet "$tmp/liver.obj" --units mm --size 12 --refine nope:4 >"$tmp/o" 2>&1
[ $? = 1 ] && grep -q "refine 'nope:4'" "$tmp/o" || fail "bad --refine: $(cat "$tmp/o")"

# gmsh options: one gmsh knows is used (HXT makes a different mesh), an unknown one is refused
# with gmsh's words; a bad --feature-angle is a usage error.
"$hm" tet "$tmp/liver.obj" --units mm --size 12 --gmsh Mesh.Algorithm3D=10 --feature-angle 30 \
    --out "$tmp/h.msh" >"$tmp/h.log" 2>&1 || fail "--gmsh: $(cat "$tmp/h.log")"
nh=$(sed -n 's/^tets *//p' "$tmp/h.log")
[ -n "$nh" ] && [ "$nh" != "$nu" ] || fail "--gmsh Mesh.Algorithm3D=10 changed nothing ($nu, $nh)"
"$hm" tet "$tmp/liver.obj" --units mm --size 12 --gmsh Mesh.NoSuchOption=1 >"$tmp/o" 2>&1
[ $? = 1 ] && grep -q "gmsh option Mesh.NoSuchOption=1 refused: .*Could not set option" "$tmp/o" ||
    fail "unknown gmsh option: $(cat "$tmp/o")"
"$hm" tet "$tmp/liver.obj" --units mm --size 12 --feature-angle 200 >"$tmp/o" 2>&1
[ $? = 2 ] && grep -q "bad --feature-angle" "$tmp/o" || fail "bad --feature-angle: $(cat "$tmp/o")"

# A surface as legacy VTK POLYDATA (ASCII, quads) meshes like the others.
cat >"$tmp/box.vtk" <<'VTK'
# vtk DataFile Version 3.0
box in mm
ASCII
DATASET POLYDATA
POINTS 8 float
0 0 0 40 0 0 40 30 0 0 30 0
0 0 20 40 0 20 40 30 20 0 30 20
POLYGONS 6 30
4 0 3 2 1
4 4 5 6 7
4 0 1 5 4
4 1 2 6 5
4 2 3 7 6
4 3 0 4 7
VTK
"$hm" tet "$tmp/box.vtk" --units mm --size 8 --out "$tmp/box.msh" >"$tmp/o" 2>&1 ||
    fail "vtk surface: $(cat "$tmp/o")"
grep -q "volume 2.4e-05 m^3, -*0.000 % from" "$tmp/o" || fail "vtk box volume: $(cat "$tmp/o")"
sed 's/^4 2 3 7 6$/4 2 3 9 6/' "$tmp/box.vtk" >"$tmp/badbox.vtk"
"$hm" tet "$tmp/badbox.vtk" --units mm --size 8 >"$tmp/o" 2>&1
[ $? = 1 ] && grep -q "badbox.vtk:13: point index 9 out of range \[0, 7\]" "$tmp/o" ||
    fail "bad vtk: $(cat "$tmp/o")"

# A scene from the millimetre surface with a group from a plane; it loads as a scene.
"$hm" scene "$tmp/liver.obj" --size 12 --units mm --group hilum:plane:0,-43.3,0,0,1,0 \
    --fix hilum --out "$tmp/organ" >"$tmp/o" 2>&1 || fail "scene: $(cat "$tmp/o")"
grep -q "fixed .* of .* nodes" "$tmp/o" || fail "scene output: $(cat "$tmp/o")"
for f in organ.msh scene.json probe.probe; do [ -s "$tmp/organ/$f" ] || fail "no $f"; done
# A group the mesh lacks: named, with the groups it has.
"$hm" scene "$tmp/organ/organ.msh" --units m --fix hilus --out "$tmp/o2" >"$tmp/o" 2>&1
[ $? = 1 ] && grep -q "no group 'hilus'.*'hilum'" "$tmp/o" || fail "missing group: $(cat "$tmp/o")"
echo PASS
