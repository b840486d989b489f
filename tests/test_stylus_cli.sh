#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# hapsim-stylus and hapsim-trace-diff command lines, offline (no network): bad values and
# unusable paths are refused up front with exit 2 and a message.
#   tests/test_stylus_cli.sh BIN_DIR SOURCE_DIR
set -u
bin=$1
src=$2
tmp=$(mktemp -d /tmp/hs_stylus_cli.XXXXXX)
trap 'rm -rf "$tmp"' EXIT
fail() { echo "FAIL: $*"; exit 1; }
script=$src/scenes/liver/scripts/press_hold.probe
sty() { "$bin/hapsim-stylus" --script "$script" --offline-stiffness 300 --quiet "$@"; }
# want_rc RC WHAT COMMAND...: COMMAND exits RC and, for 2, says something on stderr.
want_rc() {
    want=$1
    what=$2
    shift 2
    "$@" >"$tmp/out.log" 2>"$tmp/err.log"
    rc=$?
    [ $rc = "$want" ] || fail "$what: rc $rc (want $want): $(cat "$tmp/err.log")"
    [ "$want" != 2 ] || [ -s "$tmp/err.log" ] || fail "$what: rc 2 without a message"
}

# --trace that cannot be written: refused before the run (it ran, then failed to write).
mkdir "$tmp/dir"
: >"$tmp/file.csv"
for t in "$tmp/dir" "" "$tmp/file.csv/x.csv" "$tmp/missing/x.csv"; do
    want_rc 2 "--trace '$t'" sty --trace "$t"
    grep -q -- "--trace" "$tmp/err.log" || fail "--trace '$t': message names no --trace"
done
# A new trace is not left behind by the check when the run is refused later.
want_rc 1 "missing script" "$bin/hapsim-stylus" --script "$tmp/none.probe" \
    --offline-stiffness 300 --trace "$tmp/new.csv"
[ ! -e "$tmp/new.csv" ] || fail "the trace check left an empty trace"
want_rc 0 "a good run" sty --trace "$tmp/ok.csv"
[ "$(wc -l <"$tmp/ok.csv")" -gt 1000 ] || fail "a good run wrote no trace rows"

# Durations are bounded (--timeout-ms 1e13 overflowed the ramp's ns and ran without a ramp).
for bad in "--timeout-ms 1e13" "--timeout-ms 60001" "--timeout-ms 0" "--ramp-ms 1e13" \
    "--duration 1e8" "--rate 1e6"; do
    # shellcheck disable=SC2086 # the options split on purpose
    want_rc 2 "$bad" sty $bad --trace "$tmp/bad.csv"
    grep -q "bad value" "$tmp/err.log" || fail "$bad: not a 'bad value': $(cat "$tmp/err.log")"
done
[ ! -e "$tmp/bad.csv" ] || fail "a refused run wrote a trace"

# Device values beyond the integrator's stability limit were run (the handle bounced between the
# workspace walls, 1.45 kJ into it): refused, stating the limit. 2e5 N/m at 1 kHz is stable.
for bad in "--hand-stiffness 5e5" "--mass 2.3e-308 --hand-stiffness 1e10" \
    "--rate 100 --hand-stiffness 1e5"; do
    # shellcheck disable=SC2086 # the options split on purpose
    want_rc 2 "$bad" sty $bad --trace "$tmp/bad.csv"
    grep -q "stability limit" "$tmp/err.log" || fail "$bad: no limit given: $(cat "$tmp/err.log")"
done
want_rc 0 "--hand-stiffness 2e5" sty --hand-stiffness 2e5 --trace "$tmp/stiff.csv"

# --offline-plane normals: 1e200 overflowed the length (an internal error, exit 1), 1e-200
# underflowed it ("must not be zero"); only a zero normal is a bad value.
want_rc 0 "--offline-plane with a 1e200 normal" sty --offline-plane 0,0,0,1e200,1e200,0 \
    --trace "$tmp/plane.csv"
want_rc 0 "--offline-plane with a 1e-200 normal" sty --offline-plane 0,0,0,1e-200,0,0 \
    --trace "$tmp/plane.csv"
want_rc 2 "--offline-plane with a zero normal" sty --offline-plane 1,2,3,0,0,0 --trace "$tmp/bad.csv"
grep -q "bad value.*--offline-plane.*must not be zero" "$tmp/err.log" ||
    fail "zero normal: $(cat "$tmp/err.log")"

# With no model ever received (memq://: an in-process bus, no server), the status line and the
# summary said latency 0 us and max model age 0.0 ms, as if measured: "none".
want_rc 0 "a live run without a server" "$bin/hapsim-stylus" --script "$script" \
    --haptic-url memq:// --status --duration 1.2 --trace "$tmp/live.csv"
tr '\r' '\n' <"$tmp/err.log" | grep -q "forces rx 0 (bad 0)  latency  none" ||
    fail "status line without forces: $(cat "$tmp/err.log")"
grep -q "latency none; max model age none" "$tmp/out.log" ||
    fail "summary without forces: $(cat "$tmp/out.log")"
grep -q "^# model_age_max_ms=-1.000" "$tmp/live.csv" || fail "trace summary without forces"

# hapsim-trace-diff: only the trailing summary may be comments (a '#' line mid-file cut the
# reference short and passed); the header is the whole line; a row ends at its line end.
diff="$bin/hapsim-trace-diff"
want_rc 0 "trace-diff of a trace with itself" "$diff" "$tmp/ok.csv" "$tmp/ok.csv"
awk 'NR==3000{print "# note"}{print}' "$tmp/ok.csv" >"$tmp/mid.csv"
want_rc 2 "trace-diff with a '#' line mid-file" "$diff" "$tmp/mid.csv" "$tmp/ok.csv"
grep -q "mid.csv:3000:" "$tmp/err.log" || fail "mid-file '#': line not named: $(cat "$tmp/err.log")"
sed '1s/$/,extra/' "$tmp/ok.csv" >"$tmp/hdr.csv"
want_rc 2 "trace-diff with an extra header column" "$diff" "$tmp/ok.csv" "$tmp/hdr.csv"
grep -q "hdr.csv:1:" "$tmp/err.log" || fail "extra column: line not named: $(cat "$tmp/err.log")"
awk 'NR==5{printf "%s\rgarbage\n", $0; next}{print}' "$tmp/ok.csv" >"$tmp/cr.csv"
want_rc 2 "trace-diff with a row ending in \\rgarbage" "$diff" "$tmp/cr.csv" "$tmp/ok.csv"
grep -q "cr.csv:5:" "$tmp/err.log" || fail "\\rgarbage: line not named: $(cat "$tmp/err.log")"

echo "PASS"
