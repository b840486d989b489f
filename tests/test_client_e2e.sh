#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# End to end (run through tests/netns.sh: private network namespace, multicast on lo, ttl=0):
# hapsim-server on the liver scene, hapsim-view writing PNG + VTK, hapsim-ctl commands and
# status, hapsim-stylus pressing the liver 5 mm (press_hold.probe). Checks: every command gets
# its ack (exit codes 0 / 3 / 2 / 1 as documented), bad command lines of hapsim-view and
# hapsim-ctl are refused before anything is created or sent, the PNGs change where the probe
# presses and not on the far side (test_client_press), the VTK series loads in meshio / Python's
# XML parser.
#   tests/test_client_e2e.sh BIN_DIR SOURCE_DIR
# Exit 77 (skip) when hapsim-server or hapsim-stylus is not built.
set -u
bin=$1
src=$2
for p in hapsim-server hapsim-stylus hapsim-view hapsim-ctl test_client_press; do
    if [ ! -x "$bin/$p" ]; then
        echo "SKIP: $bin/$p not built"
        exit 77
    fi
done
[ -f "$src/scenes/liver/liver.json" ] || { echo "SKIP: no scenes/liver/liver.json"; exit 77; }
tmp=$(mktemp -d /tmp/hs_client_e2e.XXXXXX)
server_pid=""
view_pid=""
cleanup() {
    [ -n "$view_pid" ] && kill "$view_pid" 2>/dev/null
    [ -n "$server_pid" ] && kill "$server_pid" 2>/dev/null
    wait 2>/dev/null
    if [ "${keep:-0}" = 1 ]; then echo "kept $tmp"; else rm -rf "$tmp"; fi
}
trap cleanup EXIT
fail() {
    echo "FAIL: $*"
    keep=1
    echo "--- server log"; tail -n 20 "$tmp/server.log"
    exit 1
}
cd "$src" || exit 1

# Flags out of range are refused with exit 2 (a duration or rate whose microseconds overflow an
# int64 once stopped the viewer at once or turned its output off).
for bad in "--duration 1e13" "--duration -1" "--rate 1e-30" "--rate 2000"; do
    # shellcheck disable=SC2086
    "$bin/hapsim-view" $bad >"$tmp/bad.txt" 2>&1
    rc=$?
    [ $rc = 2 ] && grep -q "expected" "$tmp/bad.txt" || fail "hapsim-view $bad: rc $rc, $(cat "$tmp/bad.txt")"
done
# --quiet wins over --status in either order (--quiet --status printed status lines).
for order in "--quiet --status" "--status --quiet"; do
    # shellcheck disable=SC2086
    "$bin/hapsim-view" --out "$tmp/quiet" $order --duration 1.2 >"$tmp/bad.txt" 2>&1
    ! grep -q "fps" "$tmp/bad.txt" || fail "hapsim-view $order printed a status line"
done
# A bad value is refused before the output folder or frames.csv exists.
"$bin/hapsim-view" --out "$tmp/pfx" --prefix lower --duration 0.5 >"$tmp/bad.txt" 2>&1
rc=$?
[ $rc = 2 ] && [ ! -e "$tmp/pfx" ] || fail "hapsim-view --prefix lower: rc $rc, $(ls "$tmp/pfx" 2>&1)"
# --size is decimal integers (0x10x16 read as 16x16: strtod takes hex).
for bad in 0x10x16 1e2x100 16.0x16 +16x16 " 16x16"; do
    "$bin/hapsim-view" --out "$tmp/size" --size "$bad" --duration 0.5 >"$tmp/bad.txt" 2>&1
    rc=$?
    [ $rc = 2 ] && grep -q "expected WxH" "$tmp/bad.txt" || fail "hapsim-view --size '$bad': rc $rc, $(cat "$tmp/bad.txt")"
done
# An unusable --out (empty, too long, an existing file) is bad usage (exit 2; '' exited 3 after
# connecting). The bogus bus shows it is checked before connecting.
: >"$tmp/afile"
long=$(printf '%04001d' 0)
for bad in "" "$tmp/afile" "$tmp/$long"; do
    "$bin/hapsim-view" --out "$bad" --mesh-url bogus://x --duration 0.5 >"$tmp/bad.txt" 2>&1
    rc=$?
    [ $rc = 2 ] && grep -q "^hapsim-view: --out .*expected" "$tmp/bad.txt" ||
        fail "hapsim-view --out '$(printf %.60s "$bad")': rc $rc, $(cat "$tmp/bad.txt")"
done
[ -f "$tmp/afile" ] && [ ! -s "$tmp/afile" ] || fail "hapsim-view --out FILE changed the file"
# hapsim-ctl: a bus LCM cannot open is a bad value (exit 1, URL named), not "no server";
# -h/--help anywhere prints the usage.
"$bin/hapsim-ctl" --timeout 400 --mesh-url bogus://x status >"$tmp/bad.txt" 2>&1
rc=$?
[ $rc = 2 ] && grep -q "bogus://x" "$tmp/bad.txt" || fail "hapsim-ctl --mesh-url bogus://x: rc $rc, $(cat "$tmp/bad.txt")"
# A group without a port is refused (LCM 1.3.1 would bind a random port: ctl said only "LCM self
# test failed" before, the server hung).
"$bin/hapsim-ctl" --timeout 400 --mesh-url "udpm://239.255.76.67?ttl=0" status >"$tmp/bad.txt" 2>&1
rc=$?
[ $rc = 2 ] && grep -q "no port" "$tmp/bad.txt" || fail "hapsim-ctl --mesh-url without a port: rc $rc, $(cat "$tmp/bad.txt")"
"$bin/hapsim-stylus" --script scenes/liver/scripts/press_hold.probe --haptic-url "udpm://239.255.76.67" \
    --duration 0.5 >"$tmp/bad.txt" 2>&1
rc=$?
[ $rc = 2 ] && grep -q "no port" "$tmp/bad.txt" || fail "hapsim-stylus --haptic-url without a port: rc $rc, $(cat "$tmp/bad.txt")"
for args in "status --help" "set -h" "--timeout 400 reset --help"; do
    # shellcheck disable=SC2086
    "$bin/hapsim-ctl" $args >"$tmp/bad.txt" 2>&1
    rc=$?
    [ $rc = 0 ] && grep -q "^usage: hapsim-ctl" "$tmp/bad.txt" || fail "hapsim-ctl $args: rc $rc, $(cat "$tmp/bad.txt")"
done

"$bin/hapsim-server" scenes/liver/liver.json --duration 30 --quiet >"$tmp/server.log" 2>&1 &
server_pid=$!
ctl="$bin/hapsim-ctl --timeout 3000"

# The server is up once it answers a status request.
$bin/hapsim-ctl --timeout 10000 status >"$tmp/status.txt" 2>&1 || fail "hapsim-ctl status: no server status (rc $?)"
grep -q "^server   running" "$tmp/status.txt" || fail "status: $(cat "$tmp/status.txt")"
grep -q "^rt " "$tmp/status.txt" || fail "status shows no rt loop"

# Commands and their exit codes.
for c in pause resume request-topology estop estop-release; do
    $ctl -q $c || fail "hapsim-ctl $c: rc $?"
done
$ctl status | grep -q "^server   running" || fail "not running after resume / estop-release"
$ctl set no_such_parameter 1 2>"$tmp/set.err"
rc=$?
[ $rc = 3 ] || fail "set of an unknown parameter: rc $rc (want 3: rejected)"
grep -q "unknown parameter 'no_such_parameter' (known: probe_radius_m force_max_n" "$tmp/set.err" ||
    fail "the refused set does not list the parameters: $(cat "$tmp/set.err")"
$ctl set --list >"$tmp/list.txt" || fail "set --list: rc $?"
for p in probe_radius_m force_max_n force_rate_max_n_per_s watchdog_ms youngs_pa poisson; do
    grep -q "^$p " "$tmp/list.txt" || fail "set --list lacks $p: $(cat "$tmp/list.txt")"
done
grep -q "^youngs_pa .* rebuild " "$tmp/list.txt" && grep -q "^force_max_n .* at once " "$tmp/list.txt" ||
    fail "set --list does not say which parameters rebuild: $(cat "$tmp/list.txt")"
$ctl frobnicate 2>/dev/null
rc=$?
[ $rc = 2 ] || fail "unknown command: rc $rc (want 2: usage)"
$bin/hapsim-ctl --timeout 400 --prefix NOBODY_ status 2>/dev/null
rc=$?
[ $rc = 1 ] || fail "status on a silent prefix: rc $rc (want 1)"
$bin/hapsim-ctl --timeout 400 --prefix NOBODY_ reset 2>/dev/null
rc=$?
[ $rc = 1 ] || fail "command on a silent prefix: rc $rc (want 1)"
echo "hapsim-ctl: acks and exit codes as documented"

# Viewer from +y (the probe's side), 30 degrees up; colour range 5 mm.
"$bin/hapsim-view" --out "$tmp/view" --png --vtk --rate 4 --duration 13 --view 90,30 \
    --size 480x360 --dmax 0.005 --quiet >"$tmp/view.log" 2>&1 &
view_pid=$!
sleep 1
"$bin/hapsim-stylus" --script scenes/liver/scripts/press_hold.probe --duration 10 --quiet \
    --trace "$tmp/trace.csv" >"$tmp/stylus.log" 2>&1 || fail "hapsim-stylus: rc $? $(tail -n 3 "$tmp/stylus.log")"
wait "$view_pid"
rc=$?
view_pid=""
[ $rc = 0 ] || fail "hapsim-view rc $rc: $(cat "$tmp/view.log")"
n_png=$(ls "$tmp/view"/frame_*.png 2>/dev/null | wc -l)
[ "$n_png" -ge 5 ] || fail "only $n_png PNGs"
echo "hapsim-view: $n_png frames"

# The pictures can only show a press if the server deforms the mesh: frames that all carry
# sim_step 0 mean the server never stepped its model, a failure (it was reported as a skip).
if ! awk -F, 'NR > 1 && $5 != 0 { found = 1 } END { exit !found }' "$tmp/view/frames.csv"; then
    fail "hapsim-server published no deformation step (sim_step 0 in every frame; forces in the stylus trace: $(awk -F, 'NR > 1 && ($8 != 0 || $9 != 0 || $10 != 0)' "$tmp/trace.csv" | wc -l) nonzero rows)"
fi
# Node 399 of liver2.msh (the press point) and a point on the far (+x) end of the top.
"$bin/test_client_press" "$tmp/view" -0.0602,0.0633,-0.0146 0.060,0.040,-0.010 ||
    { keep=1; fail "pictures"; }
"$src/tests/test_client_vtk.sh" none "$tmp/view" || fail "VTK series does not validate"
echo "OK"
