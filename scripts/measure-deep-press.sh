#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# Deep presses on the bundled liver and skin patch (docs/haptics.md): the held force at every
# probe radius down to max(3 r, 15 mm), from the in-process server loop (test_haptic_sim
# deep_press, holds of 300 deformation steps), and hold_probe's linear and co-rotated holds at
# node 399 against the full static reaction. Writes docs/data/deep-press.txt.
#   scripts/measure-deep-press.sh [BUILD_DIR]
set -eu
build=${1:-build}
here=$(cd "$(dirname "$0")/.." && pwd)
out=$here/docs/data/deep-press.txt
{
    echo "# scripts/measure-deep-press.sh $build"
    HS_HOLD_STEPS=300 "$build/bin/test_haptic_sim" deep_press
    for d in 0.005 0.010 0.015; do "$build/bin/hold_probe" 399 0.005 "$d" 3000; done
} >"$out" 2>&1
cat "$out"
