#!/bin/sh
# make demo: hapsim-server on the bundled liver scene and hapsim-stylus on the bundled demo probe
# script (about 45 s), with the server's live one-line status (rt loop rate, jitter p99, force,
# deformation step time), then the stylus trace and a PNG plot of force against time in out/.
#   scripts/demo.sh [BUILD_DIR] [OUT_DIR]        (defaults: build, out/demo)
# Inside a private network namespace when this user may create one (root: tests/netns.sh), so
# the demo neither hears nor disturbs other LCM traffic; otherwise on the host with the scene's
# host-local URLs (ttl=0). HS_DEMO_SCENE=FILE serves another scene file.
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

if [ "${HS_NETNS_INSIDE:-0}" != 1 ]; then
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
trap 'kill -INT $spid 2>/dev/null || true' EXIT INT TERM
# Wait for the start-up summary (mesh, compliance set-up) before the stylus moves.
i=0
until grep -q "running;" "$log" 2>/dev/null; do
    kill -0 $spid 2>/dev/null || { cat "$log" >&2; echo "demo: hapsim-server exited at start-up" >&2; exit 1; }
    i=$((i + 1))
    [ $i -lt 200 ] || { echo "demo: hapsim-server not ready after 20 s" >&2; exit 1; }
    sleep 0.1
done
sed 's/^/  /' "$log"
echo "demo: hapsim-stylus on $script (about 45 s); live server status:"
"$stylus" --script "$script" --trace "$trace" --realtime
kill -INT $spid 2>/dev/null || true
wait $spid 2>/dev/null || true
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
