#!/bin/sh
# SPDX-License-Identifier: GPL-2.0-or-later
# Every program answers --version with "NAME VERSION" and exit status 0.
#   tests/test_version.sh BIN_DIR VERSION
bin=$1
ver=$2
pass=0
fail=0
for p in hapsim-server hapsim-mesh hapsim-view hapsim-ctl hapsim-stylus hapsim-trace-diff hapsim-solve \
    hapsim-web hapsim-bench e2e_logdump e2e_replay; do
    out=$("$bin/$p" --version 2>&1)
    rc=$?
    if [ $rc = 0 ] && [ "$out" = "$p $ver" ]; then
        pass=$((pass + 1))
    else
        echo "FAIL: $p --version: exit $rc, '$out' (want '$p $ver')"
        fail=$((fail + 1))
    fi
done
echo "$pass passed, $fail failed"
[ $fail = 0 ]
