#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# Slivers when remeshing coarse surfaces with sharp edges: the liver meshes' boundaries
# (hapsim-mesh surface) meshed again (hapsim-mesh tet) with gmsh's defaults and with the
# options that might remove slivers; one line per run with tets, volume error, smallest dihedral
# angle, tets below 5 and 10 degrees, and of those below 10 degrees how many have all four nodes
# on the surface (so no optimiser that keeps the surface can move them).
#   docs/data/mesher_slivers.sh BUILD_BIN [MESH_DIR]  > docs/data/mesher_slivers.txt
set -eu
bin=$1
dir=${2:-$(dirname "$0")/../../../shared/meshes}
where=$(dirname "$0")/slivers_where.py
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
echo "# gmsh $(dpkg-query -W -f='${Version}' libgmsh-dev 2>/dev/null || echo '?'); $(nproc) cores"
printf '%-13s %4s %-34s %6s %8s %7s %4s %4s %9s\n' mesh mm options tets vol_err min_deg '<5' '<10' on_surface
for n in liver_coarse liver2; do
    "$bin/hapsim-mesh" surface "$dir/$n.msh" --out "$tmp/$n.stl" >/dev/null
    for size in 8 4; do
        [ $n = liver2 ] && [ $size = 8 ] && continue
        for opt in "" "--gmsh Mesh.Algorithm3D=10" "--gmsh Mesh.OptimizeThreshold=0.6" \
            "--gmsh Mesh.Smoothing=10" "--gmsh Mesh.Algorithm=5" "--gmsh Mesh.Algorithm3D=7" \
            "--feature-angle 20" "--feature-angle 90" "--gmsh Mesh.OptimizeNetgen=1"; do
            # shellcheck disable=SC2086
            if "$bin/hapsim-mesh" tet "$tmp/$n.stl" --units m --size "0.00$size" $opt \
                --out "$tmp/o.msh" >"$tmp/out" 2>&1; then
                tets=$(sed -n 's/^tets *//p' "$tmp/out")
                err=$(sed -n 's/.*m^3, \(.*\) % from.*/\1/p' "$tmp/out")
                dmin=$(sed -n 's/^dihedral angles \([^ ]*\) \.\. .*/\1/p' "$tmp/out")
                b=$(sed -n 's/^slivers *\([0-9]*\) tets below 5 degrees, \([0-9]*\) below 10/\1 \2/p' "$tmp/out")
                s=$(python3 "$where" "$tmp/o.msh")
                printf '%-13s %4s %-34s %6s %7s%% %7s %4s %4s %9s\n' $n $size "${opt:-(defaults)}" \
                    "$tets" "$err" "$dmin" ${b% *} ${b#* } "$s"
            else
                printf '%-13s %4s %-34s failed: %s\n' $n $size "$opt" \
                    "$(grep -m1 'failed\|refused' "$tmp/out" | sed 's/.*: //')"
            fi
        done
    done
done
