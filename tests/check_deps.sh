#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# The dependency rules of docs/architecture.md, checked on every #include of the source tree:
# each module includes only its own headers and those of the modules below it; the rt loop
# never sees fem, sparse, cut or LCM (of the protocol only the evaluator, hapsim_model.h); only net (of the server) includes LCM, only sparse
# CHOLMOD, only the mesher gmsh; clients, the stylus and the web view see only the protocol
# (msgs/), the client and status headers. Prints every offending include as FILE:LINE.
#   tests/check_deps.sh SOURCE_DIR            check the tree
#   tests/check_deps.sh --self-test SOURCE_DIR  also show that a bad include is caught
set -u
self_test=0
if [ "${1:-}" = --self-test ]; then
    self_test=1
    shift
fi
src=${1:?usage: check_deps.sh [--self-test] SOURCE_DIR}

# Project headers each module may include besides its own folder's. base/X: server/base.
BASE="hapsim/base.h hapsim/status.h hapsim/version.h"
MESH="$BASE hapsim/mesh.h"
SPARSE="$BASE hapsim/sparse.h"
FEM="$MESH hapsim/sparse.h hapsim/fem.h hapsim/body.h hapsim/mooney.h hapsim/press.h"
CUT="$FEM hapsim/cut.h"
PROTO="hapsim/client.h hapsim/status.h hapsim/base.h hapsim/version.h msgs:*"
allowed() { # MODULE -> the list; "msgs:*" is any msgs/ header, "base/*" any server/base one
    case $1 in
    server/base) echo "$BASE" ;;
    server/mesh) echo "$MESH" ;;
    server/mesher) echo "$MESH hapsim/mesher.h hapsim/surface.h sys:gmshc.h" ;;
    server/sparse) echo "$SPARSE sys:cholmod.h" ;;
    server/fem) echo "$FEM" ;;
    server/cut) echo "$CUT" ;;
    server/rt) echo "$BASE base/* hapsim/haptic.h msgs:hapsim_model.h" ;;
    server/haptic) echo "$CUT base/* rt/* hapsim/haptic.h hapsim/compliance.h hapsim/haptic_sim.h hapsim/surface_press.h" ;;
    server/net) echo "$BASE base/* msgs:* sys:lcm/lcm.h" ;;
    server/scene) echo "$FEM base/* hapsim/scene.h msgs:hapsim_channels.h sys:cJSON.h" ;;
    server/daemon | server/tools) echo "*" ;;
    client | sim-device) echo "$PROTO sys:lcm/lcm.h sys:png.h" ;;
    web) echo "$PROTO sys:lcm/lcm.h sys:libwebsockets.h sys:cjson/cJSON.h" ;;
    msgs) echo "msgs:* sys:lcm/lcm.h" ;;
    esac
}
# The public headers belong to modules and follow their rules.
owner() {
    case $1 in
    base.h | status.h | version.h) echo server/base ;;
    mesh.h) echo server/mesh ;;
    mesher.h | surface.h) echo server/mesher ;;
    sparse.h) echo server/sparse ;;
    fem.h | body.h | mooney.h | press.h) echo server/fem ;;
    cut.h) echo server/cut ;;
    haptic.h) echo server/rt ;;
    compliance.h | haptic_sim.h | surface_press.h) echo server/haptic ;;
    scene.h) echo server/scene ;;
    client.h) echo client ;;
    *) echo unknown ;;
    esac
}
# Third-party headers that only some modules may include (system headers are free).
GUARDED="cholmod.h gmshc.h lcm/lcm.h cJSON.h cjson/cJSON.h libwebsockets.h"

check_tree() { # ROOT -> prints one line per offence (none: every include is allowed)
    root=$1
    for f in $(cd "$root" && ls server/*/*.c server/*/*.h client/*.c client/*.h sim-device/*.c \
        sim-device/*.h web/*.c web/*.h msgs/*.h include/hapsim/*.h 2>/dev/null); do
        case $f in
        include/hapsim/*) mod=$(owner "$(basename "$f")") ;;
        *) mod=$(dirname "$f") ;;
        esac
        rules=$(allowed "$mod")
        [ "$mod" = unknown ] && { echo "$f: no module owns this public header (tests/check_deps.sh)"; continue; }
        [ -z "$rules" ] && { echo "$f: module $mod has no rules (tests/check_deps.sh)"; continue; }
        [ "$rules" = "*" ] && continue
        # shellcheck disable=SC2013
        grep -n '^[[:space:]]*#[[:space:]]*include' "$root/$f" | while IFS= read -r line; do
            ln=${line%%:*}
            inc=$(echo "$line" | sed -n 's/.*#[[:space:]]*include[[:space:]]*[<"]\([^>"]*\)[>"].*/\1/p')
            quoted=0
            echo "$line" | grep -q '#[[:space:]]*include[[:space:]]*"' && quoted=1
            ok=0
            if [ $quoted = 0 ]; then
                guarded=0
                for g in $GUARDED; do [ "$inc" = "$g" ] && guarded=1; done
                if [ $guarded = 0 ]; then
                    ok=1
                else
                    for r in $rules; do [ "$r" = "sys:$inc" ] && ok=1; done
                fi
            else
                dir=$(dirname "$f")
                if [ -f "$root/$dir/$inc" ] && [ "${inc#*/}" = "$inc" ] && [ "$dir" != include/hapsim ]; then
                    ok=1 # the module's own header
                elif [ "${inc#*/}" = "$inc" ] && [ -f "$root/server/base/$inc" ] &&
                    case $mod in server/*) true ;; *) false ;; esac; then
                    ok=1 # base's internals (server/base is an include root): every server module
                elif [ "$dir" = include/hapsim ] && [ -f "$root/include/hapsim/${inc#hapsim/}" ] &&
                    [ "${inc#hapsim/}" != "$inc" ]; then
                    for r in $rules; do [ "$r" = "$inc" ] && ok=1; done
                    [ "$(owner "${inc#hapsim/}")" = "$mod" ] && ok=1
                else
                    for r in $rules; do
                        case $r in
                        "$inc") ok=1 ;;
                        base/\*) case $inc in base/*) ok=1 ;; esac ;;
                        rt/\*) case $inc in rt/*) ok=1 ;; esac ;;
                        msgs:\*) case $inc in hapsim_*.h) ok=1 ;; esac ;;
                        "msgs:$inc") ok=1 ;;
                        esac
                    done
                    # a public header of the module's own
                    case $inc in hapsim/*) [ "$(owner "${inc#hapsim/}")" = "$mod" ] && ok=1 ;; esac
                fi
            fi
            [ $ok = 1 ] ||
                echo "$f:$ln: includes $inc, which module $mod may not see (docs/architecture.md)"
        done
    done
}

out=$(check_tree "$src")
rc=0
[ -z "$out" ] || { echo "$out"; rc=1; }
if [ $self_test = 1 ]; then
    # A copy with an rt file that includes fem.h and a client file that includes server code
    # must fail, naming both.
    tmp=$(mktemp -d)
    trap 'rm -rf "$tmp"' EXIT
    (cd "$src" && tar cf - server client sim-device web msgs include) | (cd "$tmp" && tar xf -)
    printf '#include "hapsim/fem.h"\n' >"$tmp/server/rt/zz_bad.c"
    printf '#include "hapsim/haptic_sim.h"\n' >"$tmp/client/zz_bad.c"
    planted=$(check_tree "$tmp")
    if ! echo "$planted" | grep -q "server/rt/zz_bad.c:1: includes hapsim/fem.h" ||
        ! echo "$planted" | grep -q "client/zz_bad.c:1: includes hapsim/haptic_sim.h"; then
        echo "FAIL: the checker did not catch the planted includes: $planted"
        exit 1
    fi
    echo "self-test: planted includes caught"
fi
[ $rc = 0 ] && echo "dependency rules: every include allowed"
exit $rc
