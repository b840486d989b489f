#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# hapsim-mesh on the organ surfaces at hand: each mesh's boundary (hapsim-mesh surface) meshed
# again with gmsh (hapsim-mesh tet), remeshed and with --keep-surface; one line per run with
# tets, volume error against the surface, dihedral range, slivers and wall time.
#   docs/data/mesher.sh BUILD_BIN [MESH_DIR]  > docs/data/mesher.txt
set -eu
bin=$1
dir=${2:-$(dirname "$0")/../../../shared/meshes}
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
echo "# gmsh $(dpkg-query -W -f='${Version}' libgmsh-dev 2>/dev/null || echo '?'); $(nproc) cores; $(date -u +%Y-%m-%d)"
printf '%-22s %-8s %7s %7s %9s %14s %8s %7s\n' mesh mode size_mm tets vol_err dihedral_deg below5 wall_s
for m in "$dir"/*.msh; do
    n=$(basename "$m" .msh)
    "$bin/hapsim-mesh" surface "$m" --out "$tmp/$n.stl" >/dev/null
    for size in 8 4; do
        for mode in remesh keep; do
            flag=
            [ $mode = keep ] && flag=--keep-surface
            t0=$(date +%s.%N)
            if "$bin/hapsim-mesh" tet "$tmp/$n.stl" --units m --size "0.00$size" $flag \
                --out "$tmp/$n.msh" >"$tmp/out" 2>&1; then
                t1=$(date +%s.%N)
                tets=$(sed -n 's/^tets *//p' "$tmp/out")
                err=$(sed -n 's/.*m^3, \(.*\) % from.*/\1/p' "$tmp/out")
                dih=$(sed -n 's/^dihedral angles \([^ ]*\) \.\. \([^ ]*\) degrees/\1-\2/p' "$tmp/out")
                b5=$(sed -n 's/^slivers *\([0-9]*\) tets.*/\1/p' "$tmp/out")
                printf '%-22s %-8s %7s %7s %8s%% %14s %8s %7.2f\n' "$n" $mode $size "$tets" "$err" \
                    "$dih" "$b5" "$(echo "$t1 - $t0" | bc)"
            else
                printf '%-22s %-8s %7s failed: %s\n' "$n" $mode $size "$(grep -m1 'hapsim-mesh:.*failed\|error' "$tmp/out")"
            fi
        done
    done
done
