#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# The dependency rules of docs/architecture.md, checked on every #include of the source tree.
# A module is a folder; its headers sit beside its code. A file may include its own folder's
# headers, the exported headers of the modules its module may see, the installed API
# (include/hapsim) as its side allows, and the third-party headers its module owns. The rt loop
# never sees fem, sparse, cut or LCM (of the protocol only hapsim_model.h, the evaluator); only
# net (of the server) includes LCM, only sparse CHOLMOD, only the mesher gmsh; clients, the
# stylus and the web view see only the protocol (msgs/) and the installed API (the protocol
# library also status.h). Prints every offending include as FILE:LINE.
# The compiler enforces the same boundaries through each target's include directories (ctest
# deps_rt_no_fem); this check also covers private headers and third-party ones.
#   tests/check_deps.sh SOURCE_DIR            check the tree
#   tests/check_deps.sh --self-test SOURCE_DIR  also show that bad includes are caught
set -u
self_test=0
if [ "${1:-}" = --self-test ]; then
    self_test=1
    shift
fi
src=${1:?usage: check_deps.sh [--self-test] SOURCE_DIR}

# Headers a module offers to the modules that may see it (the rest of its folder is private).
exports() {
    case $1 in
    server/base) echo "base.h base_internal.h open_regular.h spsc_ring.h triple_buffer.h vec3.h worker.h" ;;
    server/mesh) echo "mesh.h" ;;
    server/mesher) echo "mesher.h surface.h" ;;
    server/sparse) echo "sparse.h" ;;
    server/fem) echo "fem.h body.h mooney.h press.h" ;;
    server/cut) echo "cut.h" ;;
    server/rt) echo "haptic.h device.h haptic_rt.h rt_thread.h" ;;
    server/haptic) echo "compliance.h haptic_sim.h surface_press.h" ;;
    server/net) echo "bus.h mesh_frames.h validate.h" ;;
    server/scene) echo "scene.h" ;;
    esac
}
SERVER_MODULES="server/base server/mesh server/mesher server/sparse server/fem server/cut server/rt
server/haptic server/net server/scene"
SERVER_API="hapsim/status.h hapsim/version.h"
CLIENT_API="hapsim/client.h hapsim/status.h hapsim/version.h"
# MODULE -> what it may see: modules, api:HEADER (include/hapsim), msgs (any msgs/ header or
# generated message type), msgs:HEADER (that one), a header by name (base.h alone; platform.h, the
# programs' BLAS set-up, which library modules may not call), sys:HEADER (a guarded third-party
# header).
sees() {
    case $1 in
    server/base) echo "$SERVER_API" ;;
    server/mesh) echo "server/base $SERVER_API" ;;
    server/mesher) echo "server/mesh server/base $SERVER_API sys:gmshc.h" ;;
    server/sparse) echo "server/base $SERVER_API sys:cholmod.h" ;;
    server/fem) echo "server/sparse server/mesh server/base $SERVER_API" ;;
    server/cut) echo "server/fem server/sparse server/mesh server/base $SERVER_API" ;;
    server/rt) echo "server/base $SERVER_API msgs:hapsim_model.h" ;;
    server/haptic) echo "server/cut server/fem server/sparse server/mesh server/rt server/base $SERVER_API" ;;
    server/net) echo "server/base $SERVER_API msgs sys:lcm/lcm.h" ;;
    server/scene) echo "server/fem server/sparse server/mesh server/base $SERVER_API msgs:hapsim_channels.h sys:cJSON.h" ;;
    server/daemon) echo "$SERVER_MODULES $SERVER_API platform.h msgs sys:lcm/lcm.h" ;;
    server/tools) echo "$SERVER_MODULES $SERVER_API platform.h" ;;
    client | client/examples) echo "$CLIENT_API msgs sys:lcm/lcm.h sys:png.h" ;;
    sim-device) echo "$CLIENT_API msgs sys:lcm/lcm.h" ;;
    web) echo "$CLIENT_API msgs sys:lcm/lcm.h sys:libwebsockets.h sys:cjson/cJSON.h" ;;
    msgs) echo "msgs hapsim/status.h sys:lcm/lcm.h" ;;
    include/hapsim) echo "api:* msgs:hapsim_wire_status.h" ;; # client.h: the decoded status
    esac
}
# Third-party headers that only some modules may include (system headers are free).
GUARDED="cholmod.h gmshc.h lcm/lcm.h cJSON.h cjson/cJSON.h libwebsockets.h png.h"

# FILE MODULE RULES INCLUDE QUOTED -> the reason INCLUDE is refused (nothing: allowed)
judge() {
    f=$1 mod=$2 rules=$3 inc=$4 quoted=$5
    if [ "$quoted" = 0 ] && [ "${inc#hapsim/}" = "$inc" ]; then
        for g in $GUARDED; do
            if [ "$inc" = "$g" ]; then
                for r in $rules; do [ "$r" = "sys:$inc" ] && return; done
                echo "third-party $inc, which module $mod may not use"
                return
            fi
        done
        return # a system header
    fi
    case $inc in
    hapsim/*)
        [ -f "$root/include/$inc" ] || { echo "$inc, which is not a header of the installed API (include/hapsim)"; return; }
        for r in $rules; do [ "$r" = "$inc" ] || [ "$r" = "api:*" ] && return; done
        echo "$inc, which module $mod may not see"
        return ;;
    */*)
        echo "$inc: a module header is included by its name alone (its folder is an include directory)"
        return ;;
    esac
    [ -f "$root/$(dirname "$f")/$inc" ] && return # the module's own header
    case $inc in
    hapsim_*.h)
        for r in $rules; do [ "$r" = msgs ] || [ "$r" = "msgs:$inc" ] && return; done
        echo "$inc (msgs), which module $mod may not see"
        return ;;
    esac
    owner=""
    for m in $SERVER_MODULES server/daemon; do
        [ -f "$root/$m/$inc" ] && owner=$m
    done
    [ -n "$owner" ] || { echo "$inc, which no module has"; return; }
    for r in $rules; do [ "$r" = "$inc" ] && return; done # named alone (base.h, platform.h)
    exported=0
    for e in $(exports "$owner"); do [ "$e" = "$inc" ] && exported=1; done
    [ $exported = 1 ] || { echo "$inc, a private header of $owner"; return; }
    for r in $rules; do [ "$r" = "$owner" ] && return; done
    echo "$inc ($owner), which module $mod may not see"
}

check_tree() { # ROOT -> prints one line per offence (none: every include is allowed)
    root=$1
    for f in $(cd "$root" && ls server/*/*.c server/*/*.h client/*.c client/*.h client/examples/*.c \
        sim-device/*.c sim-device/*.h web/*.c web/*.h msgs/*.c msgs/*.h include/hapsim/*.h \
        2>/dev/null); do
        mod=$(dirname "$f")
        rules=$(sees "$mod")
        [ -z "$rules" ] && { echo "$f: module $mod has no rules (tests/check_deps.sh)"; continue; }
        grep -n '^[[:space:]]*#[[:space:]]*include' "$root/$f" | while IFS= read -r line; do
            ln=${line%%:*}
            inc=$(echo "$line" | sed -n 's/.*#[[:space:]]*include[[:space:]]*[<"]\([^>"]*\)[>"].*/\1/p')
            quoted=0
            echo "$line" | grep -q '#[[:space:]]*include[[:space:]]*"' && quoted=1
            why=$(judge "$f" "$mod" "$rules" "$inc" $quoted)
            [ -z "$why" ] || echo "$f:$ln: includes $why (docs/architecture.md)"
        done
    done
}

out=$(check_tree "$src")
rc=0
[ -z "$out" ] || { echo "$out"; rc=1; }
if [ $self_test = 1 ]; then
    # A copy with planted offences: rt including fem.h, a server header by its old path and LCM;
    # haptic including fem's private header; a client including server code and base.h.
    tmp=$(mktemp -d)
    trap 'rm -rf "$tmp"' EXIT
    (cd "$src" && tar cf - server client sim-device web msgs include) | (cd "$tmp" && tar xf -)
    printf '#include <math.h>\n#include "fem.h"\n#include "hapsim/sparse.h"\n#include <lcm/lcm.h>\n' \
        >"$tmp/server/rt/zz_bad.c"
    printf '#include "fem_internal.h"\n' >"$tmp/server/haptic/zz_bad.c"
    printf '#include "hapsim/client.h"\n#include "haptic_sim.h"\n#include "base.h"\n' >"$tmp/client/zz_bad.c"
    planted=$(check_tree "$tmp")
    for want in "server/rt/zz_bad.c:2: includes fem.h (server/fem)" \
        "server/rt/zz_bad.c:3: includes hapsim/sparse.h, which is not" \
        "server/rt/zz_bad.c:4: includes third-party lcm/lcm.h" \
        "server/haptic/zz_bad.c:1: includes fem_internal.h, a private header of server/fem" \
        "client/zz_bad.c:2: includes haptic_sim.h (server/haptic)" \
        "client/zz_bad.c:3: includes base.h (server/base)"; do
        echo "$planted" | grep -qF "$want" || { echo "FAIL: the checker missed '$want' in: $planted"; exit 1; }
    done
    [ "$(echo "$planted" | grep -c zz_bad)" = 6 ] || { echo "FAIL: wrong offences: $planted"; exit 1; }
    echo "self-test: the 6 planted includes caught, nothing else"
fi
[ $rc = 0 ] && echo "dependency rules: every include allowed"
exit $rc
