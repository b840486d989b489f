#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# hapsim-view and hapsim-ctl against a stand-in server (test_client_fakesrv) that publishes the
# bundled liver with a 5 mm dent growing under the probe point, and drops the first copy of
# every command. Run through tests/netns.sh. Checks: the PNGs change where the dent is and not
# on the far side; the VTK series validates with meshio / Python's XML parser; hapsim-ctl gets
# its acks through retries with the same request id (exit 0), a refused command exits 3.
#   tests/test_client_liver.sh BIN_DIR SOURCE_DIR
set -u
bin=$1
src=$2
tmp=$(mktemp -d /tmp/hs_client_liver.XXXXXX)
trap 'kill $srv 2>/dev/null; wait 2>/dev/null; [ "${keep:-0}" = 1 ] || rm -rf "$tmp"' EXIT
fail() { echo "FAIL: $*"; keep=1; echo "kept $tmp"; exit 1; }
[ "${HS_KEEP:-0}" = 1 ] && keep=1

"$bin/test_client_fakesrv" "$src/scenes/liver/liver2.msh" 9 >"$tmp/srv.log" 2>&1 &
srv=$!
"$bin/hapsim-view" --out "$tmp/view" --rate 4 --duration 5 --view 90,30 --size 480x360 \
    --dmax 0.005 >"$tmp/view.log" 2>&1 || fail "hapsim-view rc $?: $(cat "$tmp/view.log")"
cat "$tmp/view.log"
# The stand-in sends garbage every frame: counted and dropped, never shown.
grep -Eq "malformed [1-9][0-9]*$" "$tmp/view.log" || fail "hapsim-view counted no malformed messages"
ctl="$bin/hapsim-ctl --timeout 3000 --retry 100"
out=$($ctl pause) || fail "pause rc $?"
echo "$out"
echo "$out" | grep -q "2 attempts" || fail "expected a retry: $out"
$ctl -q request-topology || fail "request-topology rc $?"
out=$($ctl load-scene /scenes/other.json) || fail "load-scene rc $?"
echo "$out"
echo "$out" | grep -q "scene loaded" || fail "load-scene: no final ack after PENDING: $out"
$ctl set bad 1 2>/dev/null
rc=$?
[ $rc = 3 ] || fail "refused set: rc $rc (want 3)"
$ctl status | grep -q "scene fake-liver" || fail "status"
# The examples' arguments: --help is usage (it read as 0 s), a word or a partial circle an error.
for ex in hapsim-example-driver hapsim-example-viewer; do
    "$bin/$ex" --help | grep -q "^usage: $ex" || fail "$ex --help: no usage"
    "$bin/$ex" abc 2>/dev/null
    rc=$?
    [ $rc = 2 ] || fail "$ex abc: rc $rc (want 2)"
done
"$bin/hapsim-example-driver" 1 0 0 2>/dev/null
[ $? = 2 ] || fail "driver with a partial circle did not refuse"
# The example driver: a 1 cm circle 2.3 mm inside the stand-in's half-space (300 N/m) gets
# forces near 0.69 N along +y back through the local model.
"$bin/hapsim-example-driver" 1.5 -0.060 0.066 -0.015 0.010 >"$tmp/driver.log" 2>&1 ||
    fail "driver rc $?: $(tail -n 3 "$tmp/driver.log")"
tail -n 1 "$tmp/driver.log"
awk '/^driver:/ { sent = $2; got = $5 } END { exit !(sent > 1000 && got > 0.8 * sent) }' \
    "$tmp/driver.log" || fail "driver: too few forces: $(tail -n 1 "$tmp/driver.log")"
awk '/^t / && $2 > 0.3 { n++; if ($11 < 0.6 || $11 > 0.78) bad++ }
     END { exit !(n > 5 && !bad) }' "$tmp/driver.log" ||
    fail "driver forces not near 0.69 N: $(sed -n 5,8p "$tmp/driver.log")"
wait $srv
rc=$?
srv=
cat "$tmp/srv.log"
[ $rc = 0 ] || fail "fake server: a command was executed twice or not at all (rc $rc)"
# Keyframes without their topology: none came (lost to a small socket buffer), or only the
# stand-in's garbage on its channel; the view says which rather than "no mesh received".
for mode in no-topology-at-all no-topology; do
    "$bin/test_client_fakesrv" "$src/scenes/liver/liver2.msh" 3 $mode >"$tmp/srv2.log" 2>&1 &
    srv=$!
    "$bin/hapsim-view" --out "$tmp/view2-$mode" --duration 2 --quiet >"$tmp/view2.log" 2>&1
    rc=$?
    kill $srv 2>/dev/null
    wait $srv 2>/dev/null
    srv=
    if [ $mode = no-topology ]; then
        want="keyframes but no topology accepted: [1-9][0-9]* topology messages came, none usable"
    else
        want="keyframes but no topology received: a topology larger than"
    fi
    [ $rc = 1 ] && grep -q "$want" "$tmp/view2.log" ||
        fail "hapsim-view, stand-in $mode: rc $rc, $(cat "$tmp/view2.log")"
done
"$bin/test_client_press" "$tmp/view" -0.0602,0.0633,-0.0146 0.060,0.040,-0.010 || fail "pictures"
"$src/tests/test_client_vtk.sh" none "$tmp/view" || fail "VTK series"
echo OK
