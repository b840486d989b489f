#!/bin/sh
# hapsim-web end to end in a real browser, in a private network namespace (the script enters
# one itself through tests/netns.sh after installing puppeteer-core, which needs the registry): hapsim-server on the liver scene, hapsim-web, headless Debian
# chromium driven by puppeteer-core (tests/web/e2e.js), hapsim-stylus pressing the liver
# (tests/web/press_estop.probe). Screenshots and the stylus trace stay in OUT_DIR.
#   tests/test_web_e2e.sh BIN_DIR SOURCE_DIR NODE_DIR OUT_DIR
# NODE_DIR holds node_modules/puppeteer-core; when it is missing it is installed there with
# `npm ci` from tests/web/package-lock.json (the pinned version; no browser is downloaded).
# Exit 77 (skip, saying why) only without network namespaces (tests/netns.sh); a missing
# chromium, node or npm is a failure: they are in the Makefile's package list.
set -u
bin=$1
src=$2
nodedir=$3
out=$4
for p in hapsim-server hapsim-stylus hapsim-web; do
    [ -x "$bin/$p" ] || { echo "FAIL: $bin/$p not built"; exit 1; }
done
for t in chromium node npm; do
    command -v $t >/dev/null 2>&1 || { echo "FAIL: '$t' not found (apt-get install chromium nodejs npm)"; exit 1; }
done
mkdir -p "$out" "$nodedir" || exit 1
out=$(cd "$out" && pwd)
nodedir=$(cd "$nodedir" && pwd)
if [ "${HS_NETNS_INSIDE:-0}" != 1 ]; then
    if [ ! -f "$nodedir/node_modules/puppeteer-core/package.json" ] ||
       ! cmp -s "$src/tests/web/package-lock.json" "$nodedir/package-lock.json"; then
        echo "installing puppeteer-core (tests/web/package-lock.json) into $nodedir"
        cp "$src/tests/web/package.json" "$src/tests/web/package-lock.json" "$nodedir/" || exit 1
        (cd "$nodedir" && npm ci --no-audit --no-fund --loglevel=error --fetch-retries=1) ||
            { echo "FAIL: npm ci in $nodedir failed (no npm registry?)"; exit 1; }
    fi
    exec "$src/tests/netns.sh" "$0" "$bin" "$src" "$nodedir" "$out"
fi
tmp=$(mktemp -d /tmp/hs_web_e2e.XXXXXX)
server_pid=""
web_pid=""
cleanup() {
    [ -n "$web_pid" ] && kill "$web_pid" 2>/dev/null
    [ -n "$server_pid" ] && kill "$server_pid" 2>/dev/null
    wait 2>/dev/null
    cp "$tmp/server.log" "$tmp/web.log" "$out/" 2>/dev/null
    rm -rf "$tmp"
}
trap cleanup EXIT
cd "$src" || exit 1
"$bin/hapsim-server" scenes/liver/liver.json --realtime --duration 85 >"$tmp/server.log" 2>&1 &
server_pid=$!
i=0
until grep -q "running;" "$tmp/server.log" 2>/dev/null; do
    kill -0 $server_pid 2>/dev/null || { cat "$tmp/server.log"; echo "FAIL: hapsim-server exited"; exit 1; }
    i=$((i + 1)); [ $i -lt 300 ] || { echo "FAIL: hapsim-server not ready in 30 s"; exit 1; }
    sleep 0.1
done
port=18089
"$bin/hapsim-web" --port $port --duration 80 >"$tmp/web.log" 2>&1 &
web_pid=$!
i=0
until grep -q "open http" "$tmp/web.log" 2>/dev/null; do
    kill -0 $web_pid 2>/dev/null || { cat "$tmp/web.log"; echo "FAIL: hapsim-web exited"; exit 1; }
    i=$((i + 1)); [ $i -lt 100 ] || { echo "FAIL: hapsim-web not listening in 10 s"; exit 1; }
    sleep 0.1
done
NODE_PATH="$nodedir/node_modules" timeout 75 node "$src/tests/web/e2e.js" "http://127.0.0.1:$port/" "$out" \
    "$bin/hapsim-stylus" "$src/tests/web/press_estop.probe"
rc=$?
echo "screenshots and the stylus trace: $out"
exit $rc
