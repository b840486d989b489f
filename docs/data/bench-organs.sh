#!/usr/bin/env bash
# SPDX-License-Identifier: GPL-2.0-or-later
# Writes docs/data/bench-organs.csv (and the progress lines, with each reference's outcome, to
# bench-organs.txt): hapsim-bench organs on the shared organ meshes. Run from the repository
# root after `make build`; give the meshes' folder as $1 (default: ../shared/meshes).
set -eu
MESHES="${1:-../shared/meshes}"
cd "$(dirname "$0")/../.."
build/bin/hapsim-bench organs --meshes "$MESHES" > docs/data/bench-organs.csv \
  2> docs/data/bench-organs.txt
cat docs/data/bench-organs.csv
