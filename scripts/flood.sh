#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# A pose flood from another process against a live 1 kHz driver (tests/flood_probe.c): for each
# flood rate, the driver's poses the server lost, kernel drops, missing answers and the age of
# the driver's newest answer (p50/p99/max), with the server's haptic socket at the kernel's
# default receive buffer (recv_buf_size=212992 in its URL) and at the server's own choice (no
# recv_buf_size: 4 MB here), alternating, twice each. Runs in a
# private network namespace (tests/netns.sh); about 3 minutes. Writes docs/data/flood.csv.
#   scripts/flood.sh [BUILD_DIR]    (default build; needs flood_probe and hapsim-server built)
set -eu
src=$(cd "$(dirname "$0")/.." && pwd)
build=$(cd "${1:-$src/build}" && pwd)
for b in flood_probe hapsim-server; do
    [ -x "$build/bin/$b" ] || { echo "flood.sh: $build/bin/$b missing: make build" >&2; exit 1; }
done
out=$src/docs/data/flood.csv
HS_NETNS_RMEM=4194304 timeout 900 "$src/tests/netns.sh" "$build/bin/flood_probe" \
    "$build/bin/hapsim-server" "$src" 3 0,10000,25000,50000,100000,200000 \
    212992,0,212992,0 >"$out.tmp"
mv "$out.tmp" "$out"
cat "$out"
