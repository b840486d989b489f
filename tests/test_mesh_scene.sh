#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# hapsim-mesh end to end: a surface (the bundled liver's boundary, written as STL) becomes a
# scene folder with `hapsim-mesh scene` (gmsh tets, a named group fixed), hapsim-server runs the
# scene as it is, and hapsim-stylus runs the probe scripts it wrote: the touch finds the organ,
# the press is felt, and the cut script cuts (--cut: a scalpel, cutting on). Inside a private network namespace (tests/netns.sh), ttl=0, own ports.
#   tests/test_mesh_scene.sh BIN_DIR SOURCE_DIR
# Exit 0 pass, 1 fail, 77 skipped. HS_KEEP=1 keeps the work folder.
set -u
bin=$1
src=$2
H='udpm://239.255.76.67:7877?ttl=0'
M='udpm://239.255.76.67:7878?ttl=0'
tmp=$(mktemp -d /tmp/hs_mesh_scene.XXXXXX)
srv=
cleanup() {
    [ -n "$srv" ] && kill "$srv" 2>/dev/null
    wait 2>/dev/null
    [ "${keep:-0}" = 1 ] || rm -rf "$tmp"
}
trap cleanup EXIT
[ "${HS_KEEP:-0}" = 1 ] && keep=1
fail() { echo "FAIL: $*"; keep=1; echo "kept $tmp"; exit 1; }

"$bin/hapsim-mesh" surface "$src/scenes/liver/liver2.msh" --out "$tmp/liver.stl" ||
    fail "surface extraction"
# The scene from the volume mesh (metres, like its surface).
"$bin/hapsim-mesh" tet "$tmp/liver.stl" --units m --size 0.012 --out "$tmp/liver.msh" \
    >"$tmp/tet.log" 2>&1 || fail "tet: $(cat "$tmp/tet.log")"
"$bin/hapsim-mesh" scene "$tmp/liver.msh" --units m \
    --group hilum:plane:0,-0.0433,0,0,1,0 --fix hilum --cut --out "$tmp/organ" >"$tmp/scene.log" 2>&1 ||
    fail "scene: $(cat "$tmp/scene.log")"
cat "$tmp/scene.log"
grep -q '"type": "group", "name": "hilum"' "$tmp/organ/scene.json" || fail "no group in the scene"

# A mesh with a sliver (a tet 0.1 degree from flat) is refused, saying how to accept it.
cat >"$tmp/sliver.msh" <<'MSH'
$MeshFormat
2.2 0 8
$EndMeshFormat
$Nodes
5
1 0 0 0
2 0.1 0 0
3 0 0.1 0
4 0 0 0.1
5 0.03 0.03 -0.0001
$EndNodes
$Elements
2
1 4 2 0 1 1 2 3 4
2 4 2 0 1 1 3 2 5
$EndElements
MSH
printf '{ "mesh": "sliver.msh", "fixed": [ {"type": "box", "min": [-1, -1, -1], "max": [0.01, 1, 1]} ] }\n' >"$tmp/sliver.json"
"$bin/hapsim-server" "$tmp/sliver.json" --haptic-url "$H" --mesh-url "$M" >"$tmp/sl.log" 2>&1
rc=$?
cat "$tmp/sl.log"
[ $rc != 0 ] && grep -q 'mesh_quality.min_dihedral_deg' "$tmp/sl.log" || fail "sliver mesh not refused (rc $rc)"

"$bin/hapsim-server" "$tmp/organ/scene.json" --haptic-url "$H" --mesh-url "$M" \
    >"$tmp/srv.log" 2>&1 &
srv=$!
i=0
until grep -q "running;" "$tmp/srv.log"; do
    i=$((i + 1))
    [ $i -gt 150 ] && fail "server did not start: $(cat "$tmp/srv.log")"
    kill -0 $srv 2>/dev/null || fail "server exited: $(cat "$tmp/srv.log")"
    sleep 0.1
done
"$bin/hapsim-stylus" --script "$tmp/organ/probe.probe" --haptic-url "$H" \
    --trace "$tmp/trace.csv" >"$tmp/sty.log" 2>&1 || fail "stylus rc $?: $(cat "$tmp/sty.log")"
"$bin/hapsim-stylus" --script "$tmp/organ/cut.probe" --haptic-url "$H" \
    --trace "$tmp/cut.csv" >"$tmp/cut.log" 2>&1 || fail "stylus (cut) rc $?: $(cat "$tmp/cut.log")"
kill -TERM $srv
wait $srv
rc=$?
srv=
[ $rc = 0 ] || fail "server exit status $rc: $(tail -n 3 "$tmp/srv.log")"
cat "$tmp/sty.log"
found=$(sed -n 's/^# touches_found=//p' "$tmp/trace.csv")
[ "$found" = 1 ] || fail "the touch did not find the organ (touches_found=$found)"
steady=$(sed -n 's/^# steady_force_n=//p' "$tmp/trace.csv")
echo "$steady" | tr ',' ' ' | awk '{ f = sqrt($1^2 + $2^2 + $3^2); printf "steady press force %.4g N\n", f; exit !(f > 0.01) }' ||
    fail "the press is not felt (steady force $steady N)"
# The first force is felt within 1 mm of where hapsim-mesh said contact begins (the `surface`
# line: the probe centre one radius out along the normal, mm).
exp=$(sed -n 's/^surface \([^ ]*\) \([^ ]*\) \([^ ]*\) .*/\1 \2 \3/p' "$tmp/organ/probe.probe")
awk -F, -v want="$exp" 'BEGIN { split(want, e, " ") }
    NR > 1 && !/^#/ { if (sqrt($11^2 + $12^2 + $13^2) > 0) {
        d = sqrt(($2 * 1e3 - e[1])^2 + ($3 * 1e3 - e[2])^2 + ($4 * 1e3 - e[3])^2)
        printf "first force at %.2f %.2f %.2f mm, %.3f mm from the reported contact point\n", $2 * 1e3, $3 * 1e3, $4 * 1e3, d
        found = 1; exit !(d <= 1.0) } }
    END { if (!found) exit 1 }' "$tmp/trace.csv" || fail "first contact not within 1 mm of the reported point"
steps=$(sed -n 's/^hapsim-server: \([0-9]*\) cut steps.*/\1/p' "$tmp/srv.log")
echo "cut steps: $steps"
[ -n "$steps" ] && [ "$steps" -gt 0 ] || fail "the cut script did not cut: $(tail -n 3 "$tmp/srv.log")"
echo "PASS"
