#!/bin/sh
# A `set` while the blade cuts (run through tests/netns.sh): hapsim-server on scenes/skin,
# hapsim-stylus dragging the scalpel across the patch, and `hapsim-ctl set youngs_pa` sent every
# 50 ms meanwhile. A set rebuilds the simulation; a cut finished while the rebuild stopped the
# old one was lost (the new sim was built on the cut mesh, the topology version stayed 1 and a
# late client never got a consistent mesh). Checks: the server runs on; the cuts are passed on
# (topology version > 1); sets before the first cut succeed and those after it are refused,
# nothing else; a client joining afterwards gets a consistent mesh at the server's version.
#   tests/test_cut_set_race.sh BIN_DIR CLIENT_BIN SOURCE_DIR
set -u
bin=$1
client=$2
src=$3
for p in hapsim-server hapsim-stylus hapsim-ctl; do
    [ -x "$bin/$p" ] || { echo "SKIP: $bin/$p not built"; exit 77; }
done
[ -f "$src/scenes/skin/skin.json" ] || { echo "SKIP: no scenes/skin/skin.json"; exit 77; }
tmp=$(mktemp -d /tmp/hs_cut_set_race.XXXXXX)
server_pid=""
stylus_pid=""
cleanup() {
    [ -n "$stylus_pid" ] && kill "$stylus_pid" 2>/dev/null
    [ -n "$server_pid" ] && kill "$server_pid" 2>/dev/null
    wait 2>/dev/null
    if [ "${keep:-0}" = 1 ]; then echo "kept $tmp"; else rm -rf "$tmp"; fi
}
trap cleanup EXIT
fail() {
    echo "FAIL: $*"
    keep=1
    echo "--- server log"; tail -n 5 "$tmp/server.log"
    exit 1
}
cd "$src" || exit 1

"$bin/hapsim-server" scenes/skin/skin.json --duration 40 >"$tmp/server.log" 2>&1 &
server_pid=$!
"$bin/hapsim-ctl" --timeout 10000 status >/dev/null 2>&1 || fail "no server status"
"$bin/hapsim-stylus" --script scenes/skin/scripts/cut_then_press.probe --quiet \
    >"$tmp/stylus.log" 2>&1 &
stylus_pid=$!
ok=0 refused=0 other=0 after_refusal=0 i=0
while kill -0 $stylus_pid 2>/dev/null && [ $i -lt 400 ]; do
    out=$("$bin/hapsim-ctl" --timeout 2000 set youngs_pa 50000 2>&1)
    case $? in
    0) ok=$((ok + 1)); [ $refused -gt 0 ] && after_refusal=$((after_refusal + 1)) ;;
    3) refused=$((refused + 1)); echo "$out" | grep -q cut || other=$((other + 1)) ;;
    *) other=$((other + 1)); echo "set: $out" ;;
    esac
    i=$((i + 1))
    sleep 0.05
done
wait $stylus_pid || fail "hapsim-stylus rc $?: $(cat "$tmp/stylus.log")"
stylus_pid=""
echo "set during the cut: $ok accepted, $refused refused (cut), $other other, $after_refusal accepted after a refusal"
kill -0 $server_pid 2>/dev/null || fail "the server died"
"$bin/hapsim-ctl" status >"$tmp/status.txt" 2>&1 || fail "no status after the cut"
ver=$(sed -n 's/^topology version \([0-9]*\).*/\1/p' "$tmp/status.txt")
echo "topology version $ver"
[ -n "$ver" ] && [ "$ver" -gt 1 ] || fail "the cuts were lost: topology version '$ver'"
[ $refused -gt 0 ] && [ $other = 0 ] && [ $after_refusal = 0 ] ||
    fail "sets: $ok accepted, $refused refused, $other other, $after_refusal accepted after a refusal"
"$client" late 8 1920 >"$tmp/late.log" 2>&1 || fail "late client: $(cat "$tmp/late.log")"
echo "$(tail -n 1 "$tmp/late.log")"
echo OK
