#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# End to end, two hands: hapsim-server on scenes/skin/skin_two_hands.json and two hapsim-stylus
# processes over real LCM, device 0 cutting the patch across with the scalpel, device 1 pressing
# the cut tissue beside the cut with the probe. Run inside tests/netns.sh; own ports; < 40 s.
#   tests/test_two_hands_e2e.sh BIN_DIR SOURCE_DIR
# Exit 0 pass, 1 fail. HS_KEEP=1 keeps the work folder.
set -u
bin=$1
src=$2
H='udpm://239.255.76.67:7877?ttl=0'
M='udpm://239.255.76.67:7878?ttl=0'
tmp=$(mktemp -d /tmp/hs_two_hands.XXXXXX)
srv=
s0=
cleanup() {
    for p in $s0 $srv; do kill "$p" 2>/dev/null; done
    wait 2>/dev/null
    [ "${keep:-0}" = 1 ] || rm -rf "$tmp"
}
trap cleanup EXIT
[ "${HS_KEEP:-0}" = 1 ] && keep=1
fail() { echo "FAIL: $*"; keep=1; echo "kept $tmp"; exit 1; }

"$bin/hapsim-server" "$src/scenes/skin/skin_two_hands.json" --haptic-url "$H" --mesh-url "$M" \
    >"$tmp/srv.log" 2>&1 &
srv=$!
i=0
until grep -q "running;" "$tmp/srv.log"; do
    i=$((i + 1))
    [ $i -gt 100 ] && fail "server did not start: $(cat "$tmp/srv.log")"
    kill -0 $srv 2>/dev/null || fail "server exited: $(cat "$tmp/srv.log")"
    sleep 0.1
done
sleep 1 # the compliance set-up (zero force until then)
scripts=$src/scenes/skin/scripts
"$bin/hapsim-stylus" --device-id 0 --script "$scripts/two_hands_scalpel.probe" --haptic-url "$H" \
    --trace "$tmp/d0.csv" >"$tmp/d0.log" 2>&1 &
s0=$!
"$bin/hapsim-stylus" --device-id 1 --script "$scripts/two_hands_probe.probe" --haptic-url "$H" \
    --trace "$tmp/d1.csv" >"$tmp/d1.log" 2>&1 || fail "device 1's stylus: $(tail -n 3 "$tmp/d1.log")"
wait $s0 || fail "device 0's stylus: $(tail -n 3 "$tmp/d0.log")"
s0=
kill -TERM $srv
wait $srv || fail "server exit status: $(tail -n 3 "$tmp/srv.log")"
srv=

# Device 0 cut (the server counted cut steps) and felt the blade; device 1 found the surface
# beside the cut and felt its 1 mm press there (~0.01 N); neither saw the other's forces as its own.
steps=$(sed -n 's/.* \([0-9][0-9]*\) cut steps (.*/\1/p' "$tmp/srv.log" | head -n 1)
peak0=$(sed -n 's/.*peak force \([0-9.]*\) N.*/\1/p' "$tmp/d0.log")
peak1=$(sed -n 's/.*peak force \([0-9.]*\) N.*/\1/p' "$tmp/d1.log")
found1=$(sed -n 's/.*surface found \([0-9]*\) time.*/\1/p' "$tmp/d1.log")
echo "cut steps ${steps:-?}; device 0 peak ${peak0:-?} N; device 1 surface found ${found1:-?}, peak ${peak1:-?} N"
[ "${steps:-0}" -gt 5 ] || fail "device 0 did not cut: $(grep 'cut steps' "$tmp/srv.log")"
awk -v f="${peak0:-0}" 'BEGIN { exit !(f > 0.02) }' || fail "device 0 felt no blade"
[ "${found1:-0}" -ge 1 ] || fail "device 1 did not find the surface: $(tail -n 4 "$tmp/d1.log")"
awk -v f="${peak1:-0}" 'BEGIN { exit !(f > 0.005) }' || fail "device 1 felt no press"
grep -q "rejected" "$tmp/d1.log" && ! grep -q " 0 rejected" "$tmp/d1.log" && fail "device 1 rejected forces"
echo "PASS"
