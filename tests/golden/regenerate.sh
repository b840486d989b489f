#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# REGENERATE THE GOLDEN REFERENCE TRACES. This OVERWRITES tests/golden/*-offline.csv and
# tests/golden/*-live.csv with new runs; only do it deliberately (a change of the device model,
# the scene or the server physics that you have checked), and commit the new traces with a note
# saying why. The e2e_golden test (tests/test_e2e_stylus.sh golden) compares against them.
#   tests/golden/regenerate.sh BIN_DIR        (e.g. build/bin; needs root for the namespace)
# References keep every 10th row (hapsim-trace-diff interpolates the run at the reference's
# sample times), so they stay small.
set -eu
bin=${1:?usage: $0 BIN_DIR}
here=$(cd "$(dirname "$0")" && pwd)
src=$(cd "$here/../.." && pwd)
echo "=================================================================="
echo "  OVERWRITING the golden reference traces in $here"
echo "=================================================================="
if [ "${HS_NETNS_INSIDE:-0}" != 1 ]; then
    exec "$src/tests/netns.sh" "$0" "$@"
fi
H='udpm://239.255.76.67:7867?ttl=0'
M='udpm://239.255.76.67:7868?ttl=0'
tmp=$(mktemp -d /tmp/hs_golden.XXXXXX)
decimate() { awk -F, 'NR == 1 || /^#/ || (NR - 2) % 10 == 0' "$1" >"$2"; }
for s in press_short press_drag_short; do
    "$bin/hapsim-stylus" --script "$here/$s.probe" --offline-stiffness 300 --quiet \
        --trace "$tmp/$s-offline.csv"
    decimate "$tmp/$s-offline.csv" "$here/$s-offline.csv"
    echo "wrote $here/$s-offline.csv"
done
"$bin/hapsim-server" "$src/scenes/liver/liver.json" --haptic-url "$H" --mesh-url "$M" --quiet &
srv=$!
trap 'kill $srv 2>/dev/null; rm -rf "$tmp"' EXIT
sleep 2
for s in press_short press_drag_short; do
    "$bin/hapsim-stylus" --script "$here/$s.probe" --haptic-url "$H" --quiet \
        --trace "$tmp/$s-live.csv"
    decimate "$tmp/$s-live.csv" "$here/$s-live.csv"
    echo "wrote $here/$s-live.csv"
done
echo "golden traces overwritten: review 'git diff --stat tests/golden' before committing"
