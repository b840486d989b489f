#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# What hapsim-web costs while a stylus presses the liver and one or two headless browsers watch:
# runs the web_e2e test (tests/test_web_e2e.sh) and keeps hapsim-web's end line (connections,
# frames and bytes sent, CPU) with the test's timings in docs/data/web_cost.txt.
#   docs/data/web_cost.sh [BUILD_DIR]      (default build)
set -eu
root=$(cd "$(dirname "$0")/../.." && pwd)
build=$(cd "${1:-$root/build}" && pwd)
out=$(mktemp -d /tmp/hs_web_cost.XXXXXX)
log=$out/run.log
"$root/tests/test_web_e2e.sh" "$build/bin" "$root" "$build/web-e2e" "$out" >"$log" 2>&1 || {
    cat "$log"; echo "web_cost: the test failed"; exit 1; }
{
    echo "# hapsim-web on the liver scene (432 visual nodes, 860 triangles), web_e2e run of $(date -u +%Y-%m-%d)"
    echo "# machine: $(nproc) cores, $(uname -m); headless chromium with SwiftShader on the same cores"
    grep -E "page has the mesh|readout vs|click took|hapsim-web: stopped" "$log"
} >"$root/docs/data/web_cost.txt"
cat "$root/docs/data/web_cost.txt"
rm -rf "$out"
