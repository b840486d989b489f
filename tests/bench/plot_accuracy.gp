# SPDX-License-Identifier: GPL-2.0-or-later
# Error against time per step from `hapsim-bench accuracy` CSV, with the Pareto front
# (configurations that no other one beats in both time and error) drawn as a line.
# usage: gnuplot -e "csv='out/accuracy.csv'; scene='cantilever10x'; png='docs/plots/x.png'" \
#                tests/bench/plot_accuracy.gp
# metric='l2': the relative L2 error against the row's `ref` (column 12; the reference is named
# in the title) instead of the mean nodal error.
if (!exists("csv")) csv = 'out/accuracy.csv'
if (!exists("scene")) scene = 'cantilever10x'
if (!exists("metric")) metric = 'mean'
if (!exists("png")) png = 'docs/plots/accuracy_'.scene.(metric eq 'l2' ? '_l2' : '').'.png'
ycol = metric eq 'l2' ? 12 : 7
refname = system(sprintf("awk -F, '$1==\"%s\" && $11!=\"\" {print $11; exit}' %s", scene, csv))

set terminal pngcairo size 1000,700 noenhanced font ",10"
set output png
set datafile separator ","
set logscale xy
set grid
set key outside right top
set xlabel "time per step (dynamic rows) or per static solve, ms of thread CPU"
if (metric eq 'l2') {
    set ylabel "relative L2 error of the nodal displacements, % (100 ||u - u_ref|| / ||u_ref||)"
    set title "hapsim-bench accuracy: ".scene.", against ".refname
} else {
    set ylabel "mean nodal error, % of the bounding-box diagonal"
    set title "hapsim-bench accuracy: ".scene." (reference in docs/accuracy.md)"
}

# Rows of this scene with numbers: scene,model,option,tets,step_ms,iterations,err_mean,...
sel = sprintf("< awk -F, '$1==\"%s\" && $5+0>0' %s", scene, csv)
# Pareto front: sort by time, keep each row whose error is below every faster row's.
front = sprintf("< awk -F, '$1==\"%s\" && $5+0>0' %s | sort -t, -k5,5g | awk -F, 'BEGIN{b=1e300} $%d+0<b{b=$%d+0; print}'", scene, csv, ycol, ycol)

is(m) = sprintf("< awk -F, '$1==\"%s\" && $5+0>0 && $2==\"%s\"' %s", scene, m, csv)
plot front using 5:ycol with lines lw 2 lc rgb "black" title "Pareto front", \
     is("linear") using 5:ycol with points pt 7 ps 1.2 title "linear", \
     is("linear-lf") using 5:ycol with points pt 5 ps 1.2 title "linear + ANP", \
     is("linear-sns") using 5:ycol with points pt 4 ps 1.2 title "linear + SNS", \
     is("corotated") using 5:ycol with points pt 9 ps 1.2 title "co-rotated", \
     is("corotated-lf") using 5:ycol with points pt 11 ps 1.2 title "co-rotated + ANP", \
     is("corotated-sns") using 5:ycol with points pt 10 ps 1.2 title "co-rotated + SNS", \
     is("stvk") using 5:ycol with points pt 13 ps 1.2 title "StVK", \
     is("stvk-lf") using 5:ycol with points pt 15 ps 1.2 title "StVK + ANP", \
     is("mooney") using 5:ycol with points pt 3 ps 1.5 title "Mooney-Rivlin (static)", \
     front using 5:ycol:(sprintf("%s %s %s", stringcolumn(2), stringcolumn(3), stringcolumn(4))) \
        with labels left offset 0.6,0.4 font ",7" notitle
