#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# The locking-free study of docs/fem.md and docs/accuracy.md: every locking-free option and SNS
# share against CalculiX's converged solution (tests/accuracy/refs), with its cost.
# usage (from the repository root, after make build): docs/data/lockfree.sh
set -eu
build/bin/hapsim-bench lockfree > docs/data/lockfree.csv
cp tests/accuracy/refs/summary.csv docs/data/ccx-summary.csv
