#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
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
# Command line: bad options are refused (exit 2) before anything listens.
for bad in "--port 0" "--port 70000" "--port 12x" "--bogus" "--web-root /nonexistent" "--duration -1" \
           "--bind 192.0.2.1" "--bind nonsense"; do
    # shellcheck disable=SC2086
    "$bin/hapsim-web" $bad >"$tmp/cli.log" 2>&1
    rc=$?
    [ $rc = 2 ] || { cat "$tmp/cli.log"; echo "FAIL: hapsim-web $bad: exit $rc, want 2"; exit 1; }
done
"$bin/hapsim-web" --web-root /nonexistent 2>&1 | grep -q "no index.html in '/nonexistent'" ||
    { echo "FAIL: --web-root /nonexistent does not name the folder"; exit 1; }
"$bin/hapsim-web" --help | grep -q "usage: hapsim-web" || { echo "FAIL: --help"; exit 1; }
echo "ok   hapsim-web refuses bad command lines (exit 2) and prints --help"
# Static files from the build tree, nothing else (no server running yet: the page still loads).
"$bin/hapsim-web" --port 18088 --duration 10 --quiet &
cli_pid=$!
sleep 0.5
node -e '
const http = require("http");
const get = (p) => new Promise((res, rej) => http.get("http://127.0.0.1:18088" + p,
  (r) => { let b = ""; r.on("data", (d) => b += d); r.on("end", () => res([r.statusCode, b, r.headers["content-type"]])); }).on("error", rej));
(async () => {
  const [c1, b1] = await get("/"), [c2, b2, t2] = await get("/vendor/three.min.js"), [c3] = await get("/nope.html");
  const [c4] = await get("/../../etc/passwd");
  // WebSocket handshakes: the origin of our own page is let in, that of another web site refused.
  const ws = (origin) => new Promise((res) => {
    const req = http.request({ host: "127.0.0.1", port: 18088, path: "/", headers: { Connection: "Upgrade",
      Upgrade: "websocket", "Sec-WebSocket-Version": "13", "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==",
      "Sec-WebSocket-Protocol": "hapsim", Origin: origin } });
    req.on("upgrade", (r, sock) => { sock.destroy(); res("upgraded"); });
    req.on("response", (r) => res(`HTTP ${r.statusCode}`));
    req.on("error", (e) => res(`closed (${e.code})`));
    req.end();
  });
  const own = await ws("http://127.0.0.1:18088"), evil = await ws("http://evil.example");
  const wsOk = own === "upgraded" && evil !== "upgraded";
  console.log(`${wsOk ? "ok  " : "FAIL"} WebSocket: own origin ${own}, foreign origin ${evil}`);
  const ok = c1 === 200 && b1.includes("hapsim live view") && c2 === 200 && /REVISION="111"|REVISION:"111"|"111"/.test(b2) &&
    /javascript/.test(t2) && c3 === 404 && c4 !== 200 && wsOk;
  console.log(`${ok ? "ok  " : "FAIL"} HTTP: / ${c1}, /vendor/three.min.js ${c2} (${t2}, ${b2.length} bytes), /nope.html ${c3}, /../../etc/passwd ${c4}`);
  process.exit(ok ? 0 : 1);
})().catch((e) => { console.log("FAIL HTTP: " + e.message); process.exit(1); });' || exit 1
# A second one on the same port is refused (exit 1) and says why.
"$bin/hapsim-web" --port 18088 --duration 1 >"$tmp/cli.log" 2>&1
rc=$?
[ $rc = 1 ] && grep -q "cannot listen on 127.0.0.1 port 18088" "$tmp/cli.log" ||
    { cat "$tmp/cli.log"; echo "FAIL: a second hapsim-web on a port in use: exit $rc"; exit 1; }
echo "ok   a port in use (exit 1) and an address not of this host (exit 2) are refused"
kill $cli_pid; wait $cli_pid
"$bin/hapsim-server" scenes/liver/liver.json --realtime --duration 120 >"$tmp/server.log" 2>&1 &
server_pid=$!
i=0
until grep -q "running;" "$tmp/server.log" 2>/dev/null; do
    kill -0 $server_pid 2>/dev/null || { cat "$tmp/server.log"; echo "FAIL: hapsim-server exited"; exit 1; }
    i=$((i + 1)); [ $i -lt 300 ] || { echo "FAIL: hapsim-server not ready in 30 s"; exit 1; }
    sleep 0.1
done
port=18089
"$bin/hapsim-web" --port $port --duration 115 >"$tmp/web.log" 2>&1 &
web_pid=$!
i=0
until grep -q "open http" "$tmp/web.log" 2>/dev/null; do
    kill -0 $web_pid 2>/dev/null || { cat "$tmp/web.log"; echo "FAIL: hapsim-web exited"; exit 1; }
    i=$((i + 1)); [ $i -lt 100 ] || { echo "FAIL: hapsim-web not listening in 10 s"; exit 1; }
    sleep 0.1
done
NODE_PATH="$nodedir/node_modules" timeout 110 node "$src/tests/web/e2e.js" "http://127.0.0.1:$port/" "$out" \
    "$bin/hapsim-stylus" "$src/tests/web/press_estop.probe"
rc=$?
kill "$web_pid" 2>/dev/null
wait "$web_pid" 2>/dev/null
web_pid=""
tail -n 1 "$tmp/web.log"
echo "screenshots and the stylus trace: $out"
exit $rc
