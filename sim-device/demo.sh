#!/bin/sh
# The hapsim demo: hapsim-server on the bundled liver scene and hapsim-stylus on the bundled
# demo script (about 42 s) with a live one-line status, then the trace and a force plot.
#   sim-device/demo.sh [BUILD_DIR] [OUT_DIR]
# BUILD_DIR defaults to build/, OUT_DIR to BUILD_DIR/demo. Inside a private network namespace
# when this user may create one (tests/netns.sh), so the demo neither hears nor disturbs other
# LCM traffic. Without a built hapsim-server the stylus runs offline against an elastic
# half-space (300 N/m) standing in for the liver, and says so.
set -eu
root=$(cd "$(dirname "$0")/.." && pwd)
build=${1:-$root/build}
out=${2:-$build/demo}
server=$build/bin/hapsim-server
stylus=$build/bin/hapsim-stylus
scene=$root/scenes/liver/liver.json
script=$root/scenes/liver/scripts/demo.probe
trace=$out/demo-trace.csv
plot=$out/demo-force.png
mkdir -p "$out"
[ -x "$stylus" ] || { echo "demo: $stylus not built (make build)" >&2; exit 1; }

if [ "${HS_DEMO_INSIDE:-0}" != 1 ] && [ -x "$server" ] && unshare -n true 2>/dev/null; then
    HS_DEMO_INSIDE=1 exec "$root/tests/netns.sh" "$0" "$build" "$out"
fi

if [ -x "$server" ]; then
    echo "demo: hapsim-server on $scene, hapsim-stylus on $script"
    "$server" "$scene" &
    spid=$!
    trap 'kill $spid 2>/dev/null || true' EXIT INT TERM
    sleep 1
    kill -0 $spid 2>/dev/null || { echo "demo: hapsim-server exited at start-up" >&2; exit 1; }
    # The status line adds the server's rt rate, jitter and step time from its SERVER_STATUS.
    "$stylus" --script "$script" --trace "$trace" --status \
        --status-url "${HS_MESH_URL:-udpm://239.255.76.67:7668?ttl=0}"
    kill -TERM $spid 2>/dev/null || true  # background jobs of sh ignore SIGINT
    wait $spid 2>/dev/null || true
    trap - EXIT INT TERM
else
    echo "demo: $server not built: the stylus runs offline against a 300 N/m half-space"
    "$stylus" --script "$script" --trace "$trace" --offline-stiffness 300
fi
"$root/sim-device/plot_trace.sh" "$trace" "$plot" >/dev/null
echo "demo: trace $trace"
echo "demo: plot  $plot"
