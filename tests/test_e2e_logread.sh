#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# e2e_logdump and e2e_replay on a small hand-made LCM log (no network, no server): a complete log
# reads with exit 0; the same log cut off anywhere inside an event, or with bytes after its last
# event, is an error (exit 1, the message names the byte where the complete events end); a log
# path with '?' reads like any other. (Before: a truncated log read as complete, exit 0, 'bad 0';
# a '?' in the path broke LCM's file:// URL.)
#   tests/test_e2e_logread.sh E2E_LOGDUMP E2E_REPLAY SOURCE_DIR
set -u
logdump=$1
replay=$2
src=$3
scene=$src/scenes/liver/liver.json
py=/usr/bin/python3
[ -x "$py" ] || py=$(command -v python3) || { echo "SKIP: python3 not found"; exit 77; }
tmp=$(mktemp -d /tmp/hs_e2e_logread.XXXXXX)
trap 'rm -rf "$tmp"' EXIT
fail() {
    echo "FAIL: $*"
    exit 1
}

# 40 events in LCM's log framing (lcm/eventlog.c): 20 on HAPSIM_TOOL_POSE (bytes that do not
# decode as a pose: counted bad, and delivered to e2e_replay's subscription), 20 on HAPSIM_NOTE.
"$py" - "$tmp/full.lcmlog" <<'PY' || fail "cannot write the log"
import struct, sys
with open(sys.argv[1], "wb") as f:
    for i in range(40):
        ch = b"HAPSIM_TOOL_POSE" if i % 2 == 0 else b"HAPSIM_NOTE"
        data = bytes((i * 7 + k) % 256 for k in range(50 + i))
        f.write(struct.pack(">IqqII", 0xEDA1DA01, i, 1000 * i, len(ch), len(data)) + ch + data)
PY
size=$(wc -c <"$tmp/full.lcmlog")

"$logdump" "$tmp/full.lcmlog" >"$tmp/out.txt" 2>"$tmp/err.txt" ||
    fail "complete log: rc $?, $(cat "$tmp/err.txt")"
grep -q "^count HAPSIM_NOTE 20$" "$tmp/out.txt" && grep -q "^count HAPSIM_TOOL_POSE 20$" "$tmp/out.txt" &&
    grep -q "^bad 20$" "$tmp/out.txt" || fail "complete log: $(cat "$tmp/out.txt")"

# The last event (39: 28 header + 11 channel + 89 data bytes) ends at $size: cut it at its
# header, channel and data, and in an earlier event; then a log with bytes after its end.
last=$((size - 128))
for cut in $((size - 1)) $((size - 60)) $((last + 30)) $((last + 10)) 100; do
    head -c "$cut" "$tmp/full.lcmlog" >"$tmp/cut.lcmlog"
    "$logdump" "$tmp/cut.lcmlog" >"$tmp/out.txt" 2>"$tmp/err.txt"
    rc=$?
    [ $rc = 1 ] && grep -q "truncated\|cut off" "$tmp/err.txt" ||
        fail "log cut at $cut of $size: rc $rc, $(cat "$tmp/err.txt") $(tail -n 3 "$tmp/out.txt")"
done
grep -q "head -c 94 " "$tmp/err.txt" || fail "cut at 100: $(cat "$tmp/err.txt")"
head -c $((last + 30)) "$tmp/full.lcmlog" >"$tmp/cut.lcmlog"
"$logdump" "$tmp/cut.lcmlog" 2>"$tmp/err.txt" >/dev/null
grep -q "head -c $last " "$tmp/err.txt" || fail "cut in the last event: $(cat "$tmp/err.txt")"
# What the message says keeps the complete events, and reads back.
head -c "$last" "$tmp/full.lcmlog" >"$tmp/kept.lcmlog"
"$logdump" "$tmp/kept.lcmlog" >"$tmp/out.txt" 2>"$tmp/err.txt" &&
    grep -q "^count HAPSIM_NOTE 19$" "$tmp/out.txt" || fail "kept events: $(cat "$tmp/err.txt")"
{ cat "$tmp/full.lcmlog"; printf 'garbage!'; } >"$tmp/extra.lcmlog"
"$logdump" "$tmp/extra.lcmlog" >"$tmp/out.txt" 2>"$tmp/err.txt"
rc=$?
[ $rc = 1 ] && grep -q "byte $size " "$tmp/err.txt" || fail "trailing bytes: rc $rc, $(cat "$tmp/err.txt")"

# A '?' in the path (it went into the file:// URL, where it starts the options).
cp "$tmp/full.lcmlog" "$tmp/a?speed=1&b.lcmlog"
"$logdump" "$tmp/a?speed=1&b.lcmlog" >"$tmp/out.txt" 2>"$tmp/err.txt" &&
    grep -q "^count HAPSIM_NOTE 20$" "$tmp/out.txt" || fail "path with '?': $(cat "$tmp/err.txt")"

# e2e_replay: the same rules (it answers no pose here: none decodes).
if [ -f "$scene" ]; then
    "$replay" "$scene" "$tmp/a?speed=1&b.lcmlog" >"$tmp/out.txt" 2>"$tmp/err.txt" &&
        grep -q "^poses 0$" "$tmp/out.txt" || fail "e2e_replay, path with '?': $(cat "$tmp/err.txt")"
    head -c $((size - 1)) "$tmp/full.lcmlog" >"$tmp/cut.lcmlog"
    "$replay" "$scene" "$tmp/cut.lcmlog" >"$tmp/out.txt" 2>"$tmp/err.txt"
    rc=$?
    [ $rc = 1 ] && grep -q "truncated" "$tmp/err.txt" || fail "e2e_replay, cut log: rc $rc, $(cat "$tmp/err.txt")"
else
    echo "note: no $scene: e2e_replay not checked"
fi
echo "ok: complete, cut (5 places), trailing bytes, '?' in the path"
