#!/usr/bin/env bash
# SPDX-License-Identifier: GPL-2.0-or-later
# Writes docs/data/bench-cut.csv (and the per-mesh progress lines to docs/data/bench-cut.txt):
# hapsim-bench cut, the server's cutting path on the skin patch, a 5,043-vertex plate and the
# tongue. Run from anywhere after `make build`; give the meshes' folder as $1 (default:
# ../shared/meshes beside the repository).
set -eu
cd "$(dirname "$0")/.."
MESHES="${1:-../shared/meshes}"
build/bin/hapsim-bench cut --meshes "$MESHES" > docs/data/bench-cut.csv 2> docs/data/bench-cut.txt
cat docs/data/bench-cut.csv
