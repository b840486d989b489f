#!/usr/bin/env bash
# SPDX-License-Identifier: GPL-2.0-or-later
# hs_platform_blas_select as the programs run it: OpenBLAS's generic fallback kernels are replaced
# by its AVX2 ones on an AVX2 processor, and a user's OPENBLAS_CORETYPE is never overridden.
set -u
BENCH="$1"
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
fail=0; pass=0
check() { # name, condition (0 = ok)
  if [ "$2" -eq 0 ]; then pass=$((pass+1)); else echo "FAIL: $1"; fail=$((fail+1)); fi
}
core() { sed -n 2p "$T/out"; }

# Options before or after the command; a missing value is named as such.
"$BENCH" --quick blas > "$T/out" 2> "$T/err"; rc=$?
check "--quick before the command: rc $rc, $(cat "$T/err")" $rc
"$BENCH" blas --meshes > /dev/null 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q "missing value for --meshes" "$T/err"; rc=$?
check "--meshes without a value named: $(cat "$T/err")" $rc

# A mesh missing from --meshes is taken from scenes/ when bundled (liver2 here).
"$BENCH" haptic --quick --meshes "$T/none" > "$T/out" 2> "$T/err"; rc=$?
[ $rc -eq 0 ] && grep -q '^liver2,' "$T/out"; rc=$?
check "bundled liver2 used when --meshes lacks it: $(tail -n 2 "$T/err")" $rc

# The organs benchmark's quick run (the server path on liver2 at three depths, and the static
# press reference): its CSV header and three rows whose felt force at the first depth pushes.
"$BENCH" organs --quick --meshes "$T/none" > "$T/out" 2> "$T/err"; rc=$?
[ $rc -eq 0 ] && head -n 1 "$T/out" | grep -q '^mesh,tets,solver,setup_ms,.*,force_err_pct,' &&
  [ "$(grep -c '^liver2,' "$T/out")" -eq 3 ] &&
  awk -F, '$1 == "liver2" && $8 == "5.0" { ok = ($9 > 0) } END { exit !ok }' "$T/out"
check "organs --quick: header, three liver2 depths, a force at 5 mm: $(tail -n 3 "$T/err")" $?
# The felt force is within 10 % of the surface-contact static press at r, 2r and 3r, and grows.
awk -F, '$1 == "liver2" { n++; if ($11 !~ /^[0-9.]+$/ || !($11 < 10) || !($10 > 0) || !($9 > last)) bad++; last = $9 }
    END { exit !(n == 3 && !bad) }' "$T/out"
check "organs --quick: felt force within 10 % of the reference and growing: $(grep '^liver2,' "$T/out" | cut -d, -f8-11 | tr '\n' ' ')" $?

OPENBLAS_CORETYPE=Prescott "$BENCH" blas > "$T/out" 2> "$T/err"; check "blas command exits 0" $?
if [ "$(core)" = "not OpenBLAS" ]; then
  echo "SKIP: the BLAS behind libblas.so.3 is not OpenBLAS"; exit 77
fi
[ "$(core)" = Prescott ]; check "a set OPENBLAS_CORETYPE is kept (got '$(core)')" $?
! grep -q restarting "$T/err"; check "no restart when OPENBLAS_CORETYPE is set" $?

env -u OPENBLAS_CORETYPE "$BENCH" blas > "$T/out" 2> "$T/err"; check "unset: exits 0" $?
if grep -qw avx2 /proc/cpuinfo && grep -qw fma /proc/cpuinfo; then
  case "$(core)" in
    Katmai|Coppermine|Northwood|Prescott|Banias|Atom|Core2|Penryn|Dunnington|Nehalem|Sandybridge|\
    Athlon|Opteron|Opteron_SSE3|Barcelona|Nano|Bobcat|Bulldozer|Piledriver|Steamroller) false ;;
    *) true ;;
  esac
  check "AVX2 processor runs AVX2-era kernels (got '$(core)')" $?
  if grep -q restarting "$T/err"; then
    [ "$(core)" = Haswell ]; check "after a restart the kernels are Haswell's (got '$(core)')" $?
    [ "$(grep -c restarting "$T/err")" -eq 1 ]; check "exactly one restart" $?
  fi
else
  ! grep -q restarting "$T/err"; check "no AVX2: no restart" $?
fi
# Asked for its usage, a program prints it and does not restart.
env -u OPENBLAS_CORETYPE "$BENCH" --help > "$T/out" 2> "$T/err"; check "--help exits 0" $?
grep -q "^usage:" "$T/out"; check "--help prints the usage" $?
! grep -q restarting "$T/err"; check "--help: no restart" $?
echo "blas_select: $pass passed, $fail failed (kernels: $(core))"
[ $fail -eq 0 ]
