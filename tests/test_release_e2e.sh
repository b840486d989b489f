#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# Releasing the scalpel inside the tissue, end to end (run through tests/netns.sh):
# hapsim-server on scenes/skin and hapsim-stylus playing scenes/skin/scripts/release_inside.probe
# (a zig-zag cut from the patch's edge to its middle, the button released there with the blade
# inside, held 2 s: the released tool is the scene's 3 mm probe with tissue all round it).
# Every force the stylus received (its trace, one row per stylus tick) is checked against the
# scene's limits (haptics.force_max_n 3.3 N, force_rate_max_n_per_s 500: 0.5 N per ms between
# the times the two forces were sent), and the hold against a kick (peak <= 1.2 x the larger of
# the force at the release and at the end, + 0.05 N; it was 2.4 N) and chatter (range over its
# last 0.5 s <= 0.02 N; it was 0.08-0.47 N).
#   tests/test_release_e2e.sh BIN_DIR SOURCE_DIR
set -u
bin=$1
src=$2
for p in hapsim-server hapsim-stylus hapsim-ctl; do
    [ -x "$bin/$p" ] || { echo "SKIP: $bin/$p not built"; exit 77; }
done
tmp=$(mktemp -d /tmp/hs_release_e2e.XXXXXX)
server_pid=""
cleanup() {
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

"$bin/hapsim-server" scenes/skin/skin.json --duration 60 >"$tmp/server.log" 2>&1 &
server_pid=$!
"$bin/hapsim-ctl" --timeout 10000 status >"$tmp/status0.txt" 2>&1 || fail "no server status"
"$bin/hapsim-stylus" --script scenes/skin/scripts/release_inside.probe --trace "$tmp/trace.csv" \
    >"$tmp/stylus.log" 2>&1 || fail "hapsim-stylus rc $?: $(cat "$tmp/stylus.log")"
kill -0 $server_pid 2>/dev/null || fail "the server died"
"$bin/hapsim-ctl" --timeout 3000 status >"$tmp/status1.txt" 2>&1 || fail "no status after the cut"
ver=$(sed -n 's/^topology version \([0-9]*\).*/\1/p' "$tmp/status1.txt")
[ -n "$ver" ] && [ "$ver" -gt 1 ] || fail "the blade cut nothing: topology version '$ver'"

# Segments of the script: 0 down, 1-5 the cut, 6 the hold (released inside), 7 up.
awk -F, -v fmax=3.3 -v rate=0.5 -v hold=6 '
NR == 1 { for (i = 1; i <= NF; ++i) col[$i] = i; next }
/^#/ { next }
{
    fx = $(col["f_recv_x"]); fy = $(col["f_recv_y"]); fz = $(col["f_recv_z"])
    if (tolower(fx " " fy " " fz) ~ /nan|inf/) { bad = 1 }
    f = sqrt(fx * fx + fy * fy + fz * fz); if (f > peak) peak = f
    t = $(col["t_s"]) * 1000; age = $(col["model_age_ms"]); seg = $(col["segment"])
    # the two forces were sent about (t - age) - (pt - page) ms apart (at least one rt tick)
    if (n && age >= 0 && page >= 0 && seg >= hold) {
        d = sqrt((fx - px)^2 + (fy - py)^2 + (fz - pz)^2)
        ms = (t - age) - (pt - page); if (ms < 1) ms = 1
        if (d / ms > dmax) { dmax = d / ms; at = t / 1000 }
    }
    if (seg == hold) { if (!nh) f0 = pf; ++nh; ht[nh] = t; hf[nh] = f; if (f > hpeak) hpeak = f }
    pf = f
    px = fx; py = fy; pz = fz; pt = t; page = age; ++n
}
END {
    lo = 1e9; hi = 0
    for (k = 1; k <= nh; ++k) if (ht[k] >= ht[nh] - 500) { if (hf[k] < lo) lo = hf[k]; if (hf[k] > hi) hi = hf[k] }
    steady = hf[nh]
    printf "trace: %d rows, peak %.3f N (limit %g); from the release: largest change %.4f N/ms (limit %g, at %.3f s); hold: from %.3f N, peak %.3f N, end %.3f N, range over its last 0.5 s %.4f N\n", n, peak, fmax, dmax, rate, at, f0, hpeak, steady, hi - lo
    if (bad) { print "FAIL: non-finite force"; exit 1 }
    if (nh < 100 || ht[nh] - ht[1] < 1500) { print "FAIL: short hold"; exit 1 }
    if (peak > fmax + 1e-6) { print "FAIL: beyond the force limit"; exit 1 }
    if (dmax > rate + 1e-6) { print "FAIL: beyond the rate limit"; exit 1 }
    top = f0 > steady ? f0 : steady
    if (hpeak > 1.2 * top + 0.05) { print "FAIL: a kick after the release"; exit 1 }
    if (hi - lo > 0.02) { print "FAIL: the held force chatters"; exit 1 }
}' "$tmp/trace.csv" || fail "force trace"
echo "PASS"
