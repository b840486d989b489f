#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# make demo: hapsim-server on the bundled liver scene and hapsim-stylus on the bundled demo probe
# script (about 45 s), with the server's live one-line status (rt loop rate, jitter p99, force,
# deformation step time), then the stylus trace and a PNG plot of force against time in out/.
#   scripts/demo.sh [BUILD_DIR] [OUT_DIR]        (defaults: build, out/demo)
# Inside a private network namespace when this user may create one (root: tests/netns.sh), so
# the demo neither hears nor disturbs other LCM traffic; otherwise on the host with the scene's
# host-local URLs (ttl=0). HS_DEMO_SCENE=FILE serves another scene file.
# With hapsim-web built, the demo runs on the host (a browser outside a private namespace could
# not reach it) and prints the URL of the live view (http://127.0.0.1:HS_DEMO_WEB_PORT/, 8080);
# HS_DEMO_WEB=0 leaves it out (and keeps the namespace).
set -eu
root=$(cd "$(dirname "$0")/.." && pwd)
build=$(cd "${1:-$root/build}" && pwd)
out=${2:-$root/out/demo}
server=$build/bin/hapsim-server
stylus=$build/bin/hapsim-stylus
scene=${HS_DEMO_SCENE:-$root/scenes/liver/liver.json}
script=$root/scenes/liver/scripts/demo.probe
for exe in "$server" "$stylus"; do
    [ -x "$exe" ] || { echo "demo: $exe not built (make build)" >&2; exit 1; }
done
mkdir -p "$out"
out=$(cd "$out" && pwd)

web=$build/bin/hapsim-web
web_port=${HS_DEMO_WEB_PORT:-8080}
use_web=0
if [ "${HS_DEMO_WEB:-1}" != 0 ] && [ -x "$web" ]; then use_web=1; fi

if [ "${HS_NETNS_INSIDE:-0}" != 1 ] && [ $use_web = 1 ]; then
    echo "demo: on the host loopback (ttl=0), so that a browser here can open the live view"
elif [ "${HS_NETNS_INSIDE:-0}" != 1 ]; then
    if unshare -n true 2>/dev/null; then
        echo "demo: running inside a private network namespace"
        exec "$root/tests/netns.sh" "$0" "$build" "$out"
    fi
    echo "demo: no private network namespace (not root): host loopback, ttl=0"
fi

trace=$out/demo-trace.csv
plot=$out/demo-force.png
log=$out/demo-server.log
# A safety net: the server stops by itself even if this script is killed hard.
"$server" "$scene" --realtime --live --duration 90 >"$log" &
spid=$!
wpid=
trap 'kill -INT $spid $wpid 2>/dev/null || true' EXIT INT TERM
# Wait for the start-up summary (mesh, compliance set-up) before the stylus moves.
i=0
until grep -q "running;" "$log" 2>/dev/null; do
    kill -0 $spid 2>/dev/null || { cat "$log" >&2; echo "demo: hapsim-server exited at start-up" >&2; exit 1; }
    i=$((i + 1))
    [ $i -lt 200 ] || { echo "demo: hapsim-server not ready after 20 s" >&2; exit 1; }
    sleep 0.1
done
# The server's live line (stderr) is rewritten in place and ends without a newline; on a
# terminal, clear it before each line printed here, so that the two do not run together.
clr=
if [ -t 1 ] && [ -t 2 ]; then clr=$(printf '\r\033[K'); fi
show() { while IFS= read -r line; do printf '%s%s\n' "$clr" "$line"; done; }
sed 's/^/  /' "$log" | show
if [ $use_web = 1 ]; then
    weblog=$out/demo-web.log
    "$web" --port "$web_port" --duration 90 >"$weblog" 2>&1 &
    wpid=$!
    i=0
    until grep -q "open http" "$weblog" 2>/dev/null || ! kill -0 $wpid 2>/dev/null || [ $i -ge 50 ]; do
        i=$((i + 1)); sleep 0.1
    done
    if grep -q "open http" "$weblog"; then
        echo "demo: live view in a browser: http://127.0.0.1:$web_port/  (hapsim-web; the page stays" \
             "until the demo ends)" | show
        # On a terminal, a moment to open the page before the stylus moves.
        if [ -t 1 ]; then sleep 5; fi
    else
        echo "demo: hapsim-web did not start (port $web_port in use? HS_DEMO_WEB_PORT=N):" | show
        sed 's/^/  /' "$weblog" | show
        wpid=
    fi
fi
echo "demo: hapsim-stylus on $script (about 45 s); live server status:" | show
rcf=$out/.stylus-status
{
    rc=0
    stdbuf -oL "$stylus" --script "$script" --trace "$trace" --realtime 2>&1 || rc=$?
    echo $rc >"$rcf"
} | show
rc=$(cat "$rcf")
rm -f "$rcf"
[ "$rc" = 0 ] || { echo "demo: hapsim-stylus failed (exit status $rc)" >&2; exit 1; }
kill -INT $spid $wpid 2>/dev/null || true
wait $spid 2>/dev/null || true
[ -z "$wpid" ] || wait $wpid 2>/dev/null || true
trap - EXIT INT TERM
echo
tail -n 1 "$log"

if command -v gnuplot >/dev/null 2>&1; then
    if gnuplot -e "trace='$trace'; out='$plot'" "$root/scripts/plot_force.gp" 2>"$out/gnuplot.log"; then
        echo "demo: force plot  $plot"
    else
        cat "$out/gnuplot.log" >&2
        echo "demo: gnuplot failed: no plot" >&2
    fi
else
    echo "demo: gnuplot not installed (apt-get install gnuplot-nox): no plot"
fi
echo "demo: trace       $trace"
echo "demo: server log  $log"
