#!/usr/bin/env bash
# SPDX-License-Identifier: GPL-2.0-or-later
# The targets table of docs/benchmarks.md, its result and met columns computed from the
# measurements in docs/data/ (each cell names the file it read).
#   scripts/bench-table.sh                  print the table; reads docs/data/, runs nothing
#   scripts/bench-table.sh --update         also write it into docs/benchmarks.md (between the
#                                           bench-table markers)
#   scripts/bench-table.sh --run [NAME...]  first run the benchmarks NAME (core haptic tools
#                                           cut protocol organ_timing; default all) into docs/data/,
#                                           then --update. Long: run on an otherwise idle machine.
# --run uses BUILD_BIN (default build/bin) and HS_MESHES (the organ meshes; default: hapsim-bench's
# own). Exit status: 0 done, 1 a data file or a run failed, 2 bad usage.
# shellcheck disable=SC2016 # backticks in single quotes are Markdown, not expansions
set -eu
root=$(cd "$(dirname "$0")/.." && pwd)
data=$root/docs/data
doc=$root/docs/benchmarks.md
bin=${BUILD_BIN:-$root/build/bin}

usage() {
    sed -n '3,12p' "$0" | sed 's/^# \{0,1\}//'
}

update=0
run=()
case "${1:-}" in
"") ;;
--update) update=1 ;;
--run)
    update=1
    shift
    run=("$@")
    [ ${#run[@]} -gt 0 ] || run=(core haptic tools cut protocol organ_timing)
    ;;
-h | --help)
    usage
    exit 0
    ;;
*)
    echo "bench-table: unknown argument '$1'" >&2
    usage >&2
    exit 2
    ;;
esac
[ "${1:-}" = --update ] && [ $# -gt 1 ] && {
    echo "bench-table: --update takes no argument" >&2
    exit 2
}

# Run one benchmark, stdout (CSV) to docs/data/bench-NAME.csv, stderr to bench-NAME.txt.
run_bench() {
    local name=$1 meshes=()
    [ -n "${HS_MESHES:-}" ] && meshes=(--meshes "$HS_MESHES")
    case $name in
    core | haptic | tools | cut | protocol)
        [ -x "$bin/hapsim-bench" ] || {
            echo "bench-table: $bin/hapsim-bench not built (make build)" >&2
            return 1
        }
        echo "bench-table: hapsim-bench $name ..." >&2
        # into temporary files first, so that a failed run leaves the recorded files as they were
        "$bin/hapsim-bench" "$name" "${meshes[@]}" >"$data/.bench-$name.csv" 2>"$data/.bench-$name.txt" || {
            tail -n 3 "$data/.bench-$name.txt" >&2
            rm -f "$data/.bench-$name.csv" "$data/.bench-$name.txt"
            return 1
        }
        mv "$data/.bench-$name.csv" "$data/bench-$name.csv"
        mv "$data/.bench-$name.txt" "$data/bench-$name.txt"
        ;;
    organ_timing)
        echo "bench-table: scripts/organ_timing.sh ..." >&2
        "$root/scripts/organ_timing.sh" "$bin" "$data/.organ_timing.csv" "direct default" || {
            rm -f "$data/.organ_timing.csv"
            return 1
        }
        mv "$data/.organ_timing.csv" "$data/organ_timing.csv"
        ;;
    *)
        echo "bench-table: unknown benchmark '$name' (core haptic tools cut protocol organ_timing)" >&2
        return 2
        ;;
    esac
}
for b in "${run[@]}"; do
    rc=0
    run_bench "$b" || rc=$?
    [ $rc -eq 0 ] || exit $rc
done

# CSV rows under every header line that starts with PREFIX, in FILE..., as "block<TAB>row".
# A header is a line of three or more lower-case names; a row has the header's field count and
# no space or colon in its first field (stderr lines interleaved with the CSV are skipped).
rows() {
    local prefix=$1
    shift
    awk -F, -v pre="$prefix" '
        function header(   i) {
            if (NF < 3) return 0
            for (i = 1; i <= NF; i++) if ($i !~ /^[a-z][a-z0-9_.]*$/) return 0
            return 1
        }
        index($0, pre) == 1 { blk++; nf = NF; on = 1; next }
        header() { on = 0; next }
        on && NF == nf && $1 !~ /[ :#]/ { print blk "\t" $0 }' "$@"
}

# The first of FILE... (names in docs/data/) that holds rows under PREFIX; fails when none does.
pick() {
    local prefix=$1 f
    shift
    for f in "$@"; do
        [ -f "$data/$f" ] || continue
        if [ -n "$(rows "$prefix" "$data/$f" | head -n 1)" ]; then
            echo "$f"
            return 0
        fi
    done
    echo "bench-table: no rows under '$prefix' in any of: $*" >&2
    return 1
}

# The first of FILE... (names in docs/data/) that has a line matching the regex RE.
pick_line() {
    local re=$1 f
    shift
    for f in "$@"; do
        [ -f "$data/$f" ] && grep -Eq "$re" "$data/$f" && {
            echo "$f"
            return 0
        }
    done
    return 1
}

link() { printf '[%s](data/%s)' "$1" "$1"; }

# awk helpers shared by the rows: a range "a-b" (or "a" when equal) with a printf format.
AWK_LIB='
function rng(lo, hi, fmt) { return (sprintf(fmt, lo) == sprintf(fmt, hi)) ? sprintf(fmt, lo) : sprintf(fmt "-" fmt, lo, hi) }
function upd(k, v) { if (!(k in mn) || v < mn[k]) mn[k] = v; if (!(k in mx) || v > mx[k]) mx[k] = v }'

fail=0
line() { printf '| %s | %s | %s | %s |\n' "$1" "$2" "$3" "$4"; }
# One row per TARGET, with COMMAND, from the "result|met" lines on stdin.
emit() {
    local c=$1 t r m
    shift
    for t in "$@"; do
        IFS='|' read -r r m
        line "$t" "$c" "$r" "$m"
    done
}
na() { # a row whose data file is missing
    fail=1
    line "$1" "$2" "no data file in docs/data/ (scripts/bench-table.sh --run $3)" "not measured"
}

core_row_step() {
    local t='co-rotated implicit step, 10k tets, one core: <= 10 ms' c='`hapsim-bench core`'
    local files=() f
    for f in bench-core.csv bench-core.txt; do [ -f "$data/$f" ] && files+=("$data/$f"); done
    if [ ${#files[@]} -eq 0 ] || [ -z "$(rows model,tets,dofs,solver,step_ms "${files[@]}" | head -n 1)" ]; then
        na "$t" "$c" core
        return
    fi
    rows model,tets,dofs,solver,step_ms "${files[@]}" | cut -f2 | awk -F, -v src="$(link bench-core.txt)" "$AWK_LIB"'
        $10 == "cantilever-10k" && $1 == "corotated" && $4 == "warped" { upd("w", $5); n++ }
        $10 == "cantilever-10k" && $1 == "linear" && $4 == "cholmod" { upd("l", $5) }
        $10 == "cantilever-10k" && $1 == "corotated" && $4 == "cholmod" { upd("r", $5) }
        END {
            printf "cantilever-10k, %d runs: `warped` %s ms; linear %s ms; a CHOLMOD refactor every step %s ms (%s)|%s\n",
                n, rng(mn["w"], mx["w"], "%.2f"), rng(mn["l"], mx["l"], "%.2f"),
                rng(mn["r"], mx["r"], "%.1f"), src, (n && mx["w"] <= 10) ? "yes" : "no"
        }' | emit "$c" "$t"
}

core_row_ratio() {
    local t='co-rotated (`warped`) step <= 1.3x the linear step' c='`hapsim-bench core` (stderr: "alternating runs")'
    local f
    f=$(pick_line '^[^ ]+: [0-9]+ alternating runs:' bench-core.txt) || { na "$t" "$c" core; return; }
    grep -E '^[^ ]+: [0-9]+ alternating runs:.*median [0-9.]+x' "$data/$f" |
        sed -E 's/^([^ ]+): .*median ([0-9.]+)x.*/\1 \2/' |
        awk -v src="$(link "$f")" "$AWK_LIB"'
            !($1 in mn) { order[++k] = $1 }
            { upd($1, $2) }
            END {
                for (i = 1; i <= k; i++) {
                    s = s (i > 1 ? ", " : "") order[i] " " rng(mn[order[i]], mx[order[i]], "%.2f") "x"
                    if (mx[order[i]] <= 1.3) ok++
                }
                met = ok == k ? "yes" : ok == 0 ? "no" : sprintf("partly (%d of %d meshes)", ok, k)
                printf "median of 5 alternating runs per mesh: %s (%s)|%s\n", s, src, met
            }' | emit "$c" "$t"
}

haptic_rows() {
    local c='`hapsim-bench haptic`' f
    local t1='force computation (rt tick) p99 <= 20 us, up to 16 contact nodes'
    local t2='1 kHz loop: period error p99 <= a bare loop p99 + 50 us'
    f=$(pick mesh,surface_nodes,contact_nodes,tick_us_p50 bench-haptic.csv bench-all.txt) ||
        { na "$t1" "$c" haptic; na "$t2" "$c" haptic; return; }
    rows mesh,surface_nodes,contact_nodes,tick_us_p50 "$data/$f" | awk -F'\t' '{ print $1 "," $2 }' |
        awk -F, -v src="$(link "$f")" "$AWK_LIB"'
            $1 != lastb { nr++; lastb = $1 }
            { n++; upd("t", $6); upd("b", $11)
              if ($6 > 20) { over++; if ($6 > worst) { worst = $6; wm = $2 " with " $4 " contacts" } }
              if ($8 <= $11 + 50) within++; else upd("e", $8) }
            END {
                m1 = over == 0 ? "yes" : over * 2 > n ? "no" : "partly"
                printf "%d cases in %d run%s: tick p99 %s us, %d above 20 us (most: %s, %g us) (%s)|%s\n",
                    n, nr, (nr > 1 ? "s" : ""), rng(mn["t"], mx["t"], "%g"), over, wm, worst, src, m1
                m2 = within == n ? "yes" : within * 2 < n ? "no" : "partly"
                printf "%d of %d cases within; the bare loop p99 itself %s us (%s)|%s\n",
                    within, n, rng(mn["b"], mx["b"], "%g"), src, m2
            }' | emit "$c" "$t1" "$t2"
}

tools_row() {
    local t='two tools in one contact problem, 16 contact nodes each: rt contact solve p99 <= 60 us (thread CPU time)'
    local c='`hapsim-bench tools`' f
    f=$(pick case,tools,contact_nodes_tool0 bench-tools.csv) || { na "$t" "$c" tools; return; }
    rows case,tools,contact_nodes_tool0 "$data/$f" | cut -f2 |
        awk -F, -v src="$(link "$f")" '
            $1 == "cap16" && $2 == 2 { p50 = $9; p99 = $10; wall = $7; n0 = $3; n1 = $4 }
            $1 == "cap16" && $2 == 1 { one = $10 }
            $1 == "block-2.5mm" && $2 == 2 { blk = $10; bn = $3 }
            END {
                printf "%d + %d contact nodes: CPU p50 %g us, p99 %g us (wall p99 %g us on a shared machine); one tool with 16: CPU p99 %g us; a block, %d nodes each: CPU p99 %g us (%s)|%s\n",
                    n0, n1, p50, p99, wall, one, bn, blk, src, (p99 != "" && p99 <= 60) ? "yes" : "no"
            }' | emit "$c" "$t"
}

protocol_row() {
    local t='server pose -> force round trip p50 <= 1.5x a bare LCM echo' c='`hapsim-bench protocol`' f
    f=$(pick rtt_us_p50,rtt_us_p99,bare_lcm_rtt_us_p50 bench-protocol.csv bench-protocol.txt) ||
        { na "$t" "$c" protocol; return; }
    rows rtt_us_p50,rtt_us_p99,bare_lcm_rtt_us_p50 "$data/$f" | awk -F'\t' '{ print $1 "," $2 }' |
        awk -F, -v src="$(link "$f")" "$AWK_LIB"'
            { b[NR] = $1; s[NR] = $2; e[NR] = $4; last = $1 }
            END {
                for (i = 1; i <= NR; i++) if (b[i] == last) {
                    n++; r[n] = s[i] / e[i]; upd("s", s[i]); upd("e", e[i]); if (r[n] > 1.5) over++ }
                for (i = 2; i <= n; i++) for (j = i; j > 1 && r[j-1] > r[j]; j--) { x = r[j]; r[j] = r[j-1]; r[j-1] = x }
                med = n % 2 ? r[(n + 1) / 2] : (r[n / 2] + r[n / 2 + 1]) / 2
                met = over == 0 ? "yes" : over * 2 > n ? "no" : "partly"
                printf "%d runs: server p50 %s us, echo p50 %s us; ratio %s, median %.2fx, %d run%s above 1.5x (%s)|%s\n",
                    n, rng(mn["s"], mx["s"], "%.1f"), rng(mn["e"], mx["e"], "%.1f"),
                    rng(r[1], r[n], "%.2f") "x", med, over, over == 1 ? "" : "s", src,
                    met == "partly" ? "partly (at the median, not in every run)" : met
            }' | emit "$c" "$t"
}

cut_server_row() {
    local c='`hapsim-bench cut`' f=bench-cut.csv
    local t='cut step plus compliance valid again, p99, one core, on the server'"'"'s path: <= 2 ms at ~1.3k vertices, <= 10 ms at ~5k, <= 30 ms on a 10k-tet organ'
    [ -n "$(rows mesh,vertices,tets,cut_steps "$data/$f" 2>/dev/null | head -n 1)" ] ||
        { na "$t" "$c" cut; return; }
    rows mesh,vertices,tets,cut_steps "$data/$f" | cut -f2 | awk -F, -v src="$(link "$f")" '
        { lim = $1 == "skin_patch" ? 2 : $1 == "plate5043" ? 10 : 30
          r = r (NR > 1 ? "; " : "") sprintf("%s valid %.1f ms after the step began (the step %.1f ms)", $1, $9, $7)
          n++; if ($9 <= lim) ok++ }
        END {
            met = ok == n ? "yes" : ok == 0 ? "no (the compliance follows each cut step exactly, within the step; the step, with the body'"'"'s and the compliance'"'"'s partial refactors, is slower than the target)" : sprintf("partly (%d of %d)", ok, n)
            printf "%s (%s)|%s\n", r, src, met
        }' | emit "$c" "$t"
}

organ_rows() {
    local c='`scripts/organ_timing.sh`' f=organ_timing.csv
    local t1='deformation step p99 <= 1/60 s inside the running server, default settings, one core: tongue, vessel (10-13k tets), a 25k-tet liver'
    local t2='compliance set-up <= 1 s at 25k tets'
    [ -n "$(rows mesh,tets,scene_solver "$data/$f" 2>/dev/null | head -n 1)" ] ||
        { na "$t1" "$c" organ_timing; na "$t2" "$c" organ_timing; return; }
    rows mesh,tets,scene_solver "$data/$f" | cut -f2 | awk -F, -v src="$(link "$f")" '
        $3 == "default" { n++; w = w (n > 1 ? ", " : "") $1 " " ($10 + 0); u = u (n > 1 ? ", " : "") ($12 + 0)
                          sol = $5; if ($10 <= 1000 / 60) ok++
                          if ($2 > bt) { bt = $2; bs = $7; bm = $1 } }
        $3 == "direct" { d = d (d != "" ? ", " : "") ($10 + 0) }
        END {
            met = ok == n ? "yes" : ok == 0 ? "no" : sprintf("partly (%d of %d)", ok, n)
            printf "default (`auto`, which kept `%s`): wall p99 %s ms; thread CPU p99 %s ms; the `direct` solver %s ms (%s)|%s\n",
                sol, w, u, d, src, met
            printf "%s (%d tets) %.2f s; in the background: the server runs and answers zero force until it is ready (%s)|%s\n",
                bm, bt, bs / 1000, src, bs <= 1000 ? "yes" : "no"
        }' | emit "$c" "$t1" "$t2"
}

tmp=$(mktemp)
trap 'rm -f "$tmp" "$tmp.doc"' EXIT
{
    echo '| target | command | result | met |'
    echo '|---|---|---|---|'
    core_row_step
    core_row_ratio
    haptic_rows
    tools_row
    line 'compliance blocks for a new contact within one deformation step' '-' \
        'by design: a new contact node'"'"'s column block is one sparse solve before the next snapshot; not timed' \
        'not measured'
    protocol_row
    cut_server_row
    organ_rows
} >"$tmp"
cat "$tmp"

if [ $update = 1 ]; then
    if ! grep -q '^<!-- bench-table: begin' "$doc" || ! grep -q '^<!-- bench-table: end' "$doc"; then
        echo "bench-table: no bench-table markers in $doc" >&2
        exit 1
    fi
    awk -v t="$tmp" '
        /^<!-- bench-table: begin/ { print; while ((getline l < t) > 0) print l; skip = 1; next }
        /^<!-- bench-table: end/ { skip = 0 }
        !skip' "$doc" >"$tmp.doc" && cat "$tmp.doc" >"$doc"
    echo "bench-table: $doc updated" >&2
fi
exit $fail
