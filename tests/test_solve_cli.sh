#!/usr/bin/env bash
# SPDX-License-Identifier: GPL-2.0-or-later
# hapsim-solve as a user runs it: help, clear errors for bad flags and files, CSV output.
set -u
SOLVE="$1"; SRC="$2"
MESH="$SRC/scenes/liver/liver2.msh"
T=$(mktemp -d); trap 'rm -rf "$T"' EXIT
fail=0; pass=0
check() { # name, condition (0 = ok)
  if [ "$2" -eq 0 ]; then pass=$((pass+1)); else echo "FAIL: $1"; fail=$((fail+1)); fi
}
"$SOLVE" --help > "$T/help" 2>&1; check "help exits 0" $?
grep -q -- "--fix-box" "$T/help"; check "help lists --fix-box" $?

"$SOLVE" --mesh "$MESH" --out "$T/o.csv" > /dev/null 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q "required" "$T/err"; check "missing --model is an error" $?
"$SOLVE" --mesh "$MESH" --model foo --static --out "$T/o.csv" 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q "bad value for --model: 'foo'" "$T/err"; check "bad model named" $?
"$SOLVE" --mesh "$MESH" --model linear --nu 0.5 --static --out "$T/o.csv" 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q "Poisson" "$T/err"; check "nu 0.5 refused" $?
"$SOLVE" --mesh "$MESH" --model linear --fix-box 1,2,3 --static --out "$T/o.csv" 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q -- "--fix-box" "$T/err"; check "short --fix-box refused" $?
"$SOLVE" --mesh "$MESH" --model linear --static --steps 3 --dt 0.01 --out "$T/o.csv" 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q "exactly one" "$T/err"; check "static and steps together refused" $?
"$SOLVE" --mesh "$MESH" --model linear --static --fix-box 9,9,9,10,10,10 --out "$T/o.csv" 2> "$T/err"; rc=$?
[ $rc -eq 1 ] && grep -q "no node of a tet is fixed" "$T/err"; check "empty fixed region explained" $?
for bad in z,min,nan z,min,inf z,min,0.01junk w,min,1 z,mid,1 z,min,-1; do
  "$SOLVE" --mesh "$MESH" --model linear --static --fix-plane "$bad" --out "$T/o.csv" 2> "$T/err"; rc=$?
  [ $rc -eq 2 ] && grep -q "AXIS,SIDE,TOL" "$T/err"; check "--fix-plane $bad refused" $?
done
printf '$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n2\n1 0 0 x\n' > "$T/bad.msh"
"$SOLVE" --mesh "$T/bad.msh" --model linear --static --fix-plane z,min,1 --out "$T/o.csv" 2> "$T/err"; rc=$?
[ $rc -eq 1 ] && grep -q "bad.msh:6" "$T/err"; check "malformed mesh names file and line" $?
"$SOLVE" --mesh "$T/missing.msh" --model linear --static --fix-plane z,min,1 --out "$T/o.csv" 2> "$T/err"; rc=$?
[ $rc -eq 1 ] && grep -q "missing.msh" "$T/err"; check "missing file named" $?

# An output that cannot be written is refused before the solve (it failed after it): no summary.
for flag in --out --vtk; do
  "$SOLVE" --mesh "$MESH" --model linear --static --fix-plane y,min,0.005 --out "$T/o.csv" \
    $flag /nonexistent/d.x > "$T/sum" 2> "$T/err"; rc=$?
  [ $rc -eq 2 ] && grep -q "cannot write /nonexistent/d.x" "$T/err" && [ ! -s "$T/sum" ]
  check "$flag into a missing folder refused before the solve" $?
done
"$SOLVE" --mesh "$MESH" --model linear --static --fix-plane y,min,0.005 --out "$T" > "$T/sum" 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q "cannot write" "$T/err" && [ ! -s "$T/sum" ]; check "--out a folder refused" $?
# A flag the chosen model, mode or solver never reads is a bad command line, named with why.
ignored() { # flag, args...
  flag=$1; shift
  "$SOLVE" --mesh "$MESH" --fix-plane y,min,0.005 --out "$T/o.csv" "$@" > /dev/null 2> "$T/err"; rc=$?
  [ $rc -eq 2 ] && grep -q -- "$flag has no effect" "$T/err"; check "$* refused naming $flag" $?
}
ignored --dt --model linear --static --dt 0.01
ignored --damping --model corotated --static --damping 0.1,0.01
ignored --tol --model linear --steps 2 --dt 0.01 --tol 1e-6
ignored --max-iter --model linear --steps 2 --dt 0.01 --max-iter 5
ignored --load-steps --model linear --steps 2 --dt 0.01 --load-steps 2
ignored --precond --model linear --static --precond jacobi
ignored --pcg-iters --model corotated --steps 2 --dt 0.01 --solver warped --pcg-iters 5
ignored --locking-free --model mooney --static --locking-free
ignored --solver --model mooney --static --solver pcg
ignored --beta --model corotated --static --beta 1
ignored --rotation --model linear --static --rotation svd
ignored --inversion --model stvk --static --inversion reflect
ignored --polar-tol --model linear --static --polar-tol 1e-6
# ... and where it is read, it is accepted.
"$SOLVE" --mesh "$MESH" --model corotated --rotation svd --fix-plane y,min,0.005 --static \
  --polar-tol 1e-5 --out "$T/o.csv" > /dev/null; check "svd rotations take --polar-tol" $?
"$SOLVE" --mesh "$MESH" --model linear --fix-plane y,min,0.005 --steps 2 --dt 0.01 --solver warped \
  --polar-tol 1e-5 --damping 0.1,0.01 --out "$T/o.csv" > /dev/null; check "warped steps take --polar-tol and --damping" $?
"$SOLVE" --mesh "$MESH" --model stvk --fix-plane y,min,0.005 --static --solver pcg --pcg-iters 50 \
  --precond factor --tol 1e-6 --locking-free --out "$T/o.csv" > /dev/null; check "static pcg takes --precond, --pcg-iters" $?
# --locking-free MODE: the modes by name (bare: the model's default), bad ones named.
for mode in sns anp none; do
  "$SOLVE" --mesh "$MESH" --model corotated --E 50000 --nu 0.45 --fix-plane y,min,0.005 \
    --gravity 0,0,-9.81 --static --locking-free $mode --out "$T/lf_$mode.csv" > /dev/null; check "--locking-free $mode solves" $?
done
"$SOLVE" --mesh "$MESH" --model corotated --E 50000 --nu 0.45 --fix-plane y,min,0.005 \
  --gravity 0,0,-9.81 --static --locking-free --out "$T/lf_bare.csv" > /dev/null; check "bare --locking-free solves" $?
cmp -s "$T/lf_bare.csv" "$T/lf_sns.csv"; check "bare --locking-free is sns for corotated" $?
! cmp -s "$T/lf_sns.csv" "$T/lf_anp.csv"; check "sns and anp differ" $?
"$SOLVE" --mesh "$MESH" --model corotated --fix-plane y,min,0.005 --static --locking-free fbar \
  --out "$T/o.csv" 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q "'fbar' is not none|anp|sns" "$T/err"; check "bad --locking-free mode named" $?
"$SOLVE" --mesh "$MESH" --model corotated --fix-plane y,min,0.005 --static --locking-free anp \
  --locking-free-alpha 0.5 --out "$T/o.csv" 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q "needs --locking-free sns" "$T/err"; check "alpha without sns refused" $?

# A real solve: header + one line per node, finite numbers, summary printed.
"$SOLVE" --mesh "$MESH" --model corotated --E 50000 --nu 0.45 --density 1060 --gravity 0,0,-9.81 \
  --fix-plane y,min,0.005 --static --load-steps 2 --out "$T/u.csv" > "$T/sum"; check "corotated static solves" $?
[ "$(head -1 "$T/u.csv")" = "ux,uy,uz" ]; check "CSV header" $?
[ "$(($(wc -l < "$T/u.csv") - 1))" -eq 507 ]; check "one line per node" $?
! grep -qiE "nan|inf" "$T/u.csv"; check "finite output" $?
grep -q "max |u|" "$T/sum"; check "summary printed" $?
"$SOLVE" --mesh "$MESH" --model mooney --beta 1 --E 20000 --nu 0.45 --density 1060 --gravity 0,0,-9.81 \
  --fix-plane y,min,0.005 --static --load-steps 2 --out "$T/m.csv" > /dev/null; check "mooney static solves" $?
"$SOLVE" --mesh "$MESH" --model linear --E 20000 --gravity 0,0,-9.81 --fix-plane y,min,0.005 \
  --steps 5 --dt 0.01 --solver pcg --precond jacobi --out "$T/d.csv" > /dev/null; check "dynamics with pcg" $?

# Each of these failed before.
# A write that fails says why and the summary does not claim it.
if [ -w /dev/full ]; then
  "$SOLVE" --mesh "$MESH" --model linear --static --fix-plane y,min,0.005 --out /dev/full \
    > "$T/sum" 2> "$T/err"; rc=$?
  [ $rc -eq 1 ] && grep -q "error writing /dev/full: No space" "$T/err" && \
    grep -q "wrote           nothing" "$T/sum"; check "a failed write is not reported as written" $?
fi
# The last --model counts.
"$SOLVE" --mesh "$MESH" --model mooney --model linear --fix-plane y,min,0.005 --static \
  --out "$T/o.csv" > "$T/sum" 2> "$T/err"; rc=$?
[ $rc -eq 0 ] && grep -q "volume ratio    mean" "$T/sum"; check "the last --model counts" $?
# --out and --vtk the same file: refused.
"$SOLVE" --mesh "$MESH" --model linear --static --fix-plane y,min,0.005 --out "$T/same" \
  --vtk "$T/same" > /dev/null 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q "same file" "$T/err"; check "--out and --vtk the same file refused" $?
( cd "$T" && "$SOLVE" --mesh "$MESH" --model linear --static --fix-plane y,min,0.005 --out new \
  --vtk ./new > /dev/null 2> "$T/err" ); rc=$?
[ $rc -eq 2 ] && grep -q "same file" "$T/err" && [ ! -e "$T/new" ]
check "--out F --vtk ./F (F new) refused" $?
# One tet and a node no tet uses (node 5): fixing only that node fixes nothing.
printf '$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 0 0 -5\n$EndNodes\n$Elements\n1\n1 4 2 0 1 1 2 3 4\n$EndElements\n' > "$T/unref.msh"
"$SOLVE" --mesh "$T/unref.msh" --model linear --static --gravity 0,0,-9.81 \
  --fix-box -1,-1,-6,1,1,-4 --out "$T/o.csv" > /dev/null 2> "$T/err"; rc=$?
[ $rc -eq 1 ] && grep -q "no node of a tet is fixed" "$T/err"; check "a fixed unused node fixes nothing" $?
# Two fixed nodes (collinear): rigid rotation about their line is free, no static solution;
# every model refuses the static solve (linear wrote |u| ~ 1e14 m), dynamics is fine.
for model in linear corotated stvk mooney; do
  "$SOLVE" --mesh "$T/unref.msh" --model $model --static --gravity 0,0,-9.81 \
    --fix-box -0.1,-0.1,-0.1,1.1,0.1,0.1 --out "$T/o.csv" > /dev/null 2> "$T/err"; rc=$?
  [ $rc -eq 1 ] && grep -q "rigid motion is free" "$T/err"; check "$model: collinear fixed nodes refused for --static" $?
done
"$SOLVE" --mesh "$T/unref.msh" --model corotated --steps 3 --dt 0.01 --gravity 0,0,-9.81 \
  --fix-box -0.1,-0.1,-0.1,1.1,0.1,0.1 --out "$T/o.csv" > /dev/null; check "collinear fixed nodes: dynamics runs" $?
# Every node fixed: refused for every model (mooney returned u = 0 with exit 0).
for model in linear mooney; do
  "$SOLVE" --mesh "$MESH" --model $model --static --fix-box -10,-10,-10,10,10,10 \
    --out "$T/o.csv" > /dev/null 2> "$T/err"; rc=$?
  [ $rc -eq 1 ] && grep -q "nothing is left to move" "$T/err"; check "$model: every node fixed refused" $?
done
# Moduli that overflow are refused up front (E 1e308 Pa: the solve failed on NaN).
"$SOLVE" --mesh "$MESH" --model linear --E 1e308 --static --fix-plane y,min,0.005 \
  --out "$T/o.csv" > /dev/null 2> "$T/err"; rc=$?
[ $rc -eq 1 ] && grep -q "beyond 1e20 Pa" "$T/err"; check "E 1e308 refused" $?
# A solve that fails writes nothing (the CSV was written and "wrote" printed).
"$SOLVE" --mesh "$MESH" --model stvk --E 1e-300 --gravity 0,1000,0 --static --fix-plane y,min,0.005 \
  --out "$T/failed.csv" > "$T/sum" 2> "$T/err"; rc=$?
[ $rc -eq 3 ] && [ ! -e "$T/failed.csv" ] && grep -q "wrote           nothing" "$T/sum"
check "a failed solve writes nothing" $?
# The static probe reference: a press on the liver's top node; a sphere that never reaches
# the surface (exit 1), a probe without its radius, a probe in a dynamic run (exit 2) are refused.
PROBE=(--mesh "$MESH" --model corotated --E 5000 --fix-box -1,-1,-1,1,1,-0.0718 --static)
"$SOLVE" "${PROBE[@]}" --probe 0.07756132,0.00306969,0.0484151 --probe-radius 0.005 \
  --probe-dir 0,0,-1 --out "$T/p.csv" > "$T/sum" 2> "$T/err"; rc=$?
[ $rc -eq 0 ] && [ -s "$T/p.csv" ] && \
  awk -F'[ ,]' '/^probe force N:/ { ok = ($6 > 0) } END { exit !ok }' "$T/sum"
check "probe 2.5 mm deep: solved, the tool pushed out (+z)" $?
"$SOLVE" "${PROBE[@]}" --probe 0.07756132,0.00306969,0.08 --probe-radius 0.005 \
  --probe-dir 0,0,-1 --out "$T/p2.csv" > /dev/null 2> "$T/err"; rc=$?
[ $rc -eq 1 ] && grep -q "touches no free surface node" "$T/err" && [ ! -e "$T/p2.csv" ]
check "a sphere that never reaches the surface: exit 1, named, nothing written" $?
"$SOLVE" "${PROBE[@]}" --probe 0.07756132,0.00306969,0.0484151 --out "$T/p.csv" \
  > /dev/null 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q "go together" "$T/err"; check "--probe without --probe-radius refused" $?
# Surface contact is the default: the summary counts triangles; --probe-contact nodes counts
# nodes; anything else is refused.
grep -q "contact triangles" "$T/sum"; check "probe: surface contact by default" $?
"$SOLVE" "${PROBE[@]}" --probe 0.07756132,0.00306969,0.0484151 --probe-radius 0.005 \
  --probe-dir 0,0,-1 --probe-contact nodes --out "$T/p3.csv" > "$T/sum3" 2> "$T/err"; rc=$?
[ $rc -eq 0 ] && grep -q "contact nodes" "$T/sum3"; check "--probe-contact nodes" $?
"$SOLVE" "${PROBE[@]}" --probe 0.07756132,0.00306969,0.0484151 --probe-radius 0.005 \
  --probe-contact edges --out "$T/p4.csv" > /dev/null 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q "surface or nodes" "$T/err"; check "--probe-contact edges refused" $?
"$SOLVE" --mesh "$MESH" --model corotated --fix-plane y,min,0.005 --steps 2 --dt 0.01 \
  --probe 0,0,0 --probe-radius 0.005 --out "$T/p.csv" > /dev/null 2> "$T/err"; rc=$?
[ $rc -eq 2 ] && grep -q -- "--probe has no effect" "$T/err"; check "--probe with --steps refused" $?
echo "$pass passed, $fail failed"
[ $fail -eq 0 ]
