# Error against time per step from `hapsim-bench accuracy` CSV, with the Pareto front
# (configurations that no other one beats in both time and error) drawn as a line.
# usage: gnuplot -e "csv='out/accuracy.csv'; scene='cantilever10x'; png='docs/plots/x.png'" \
#                tests/bench/plot_accuracy.gp
if (!exists("csv")) csv = 'out/accuracy.csv'
if (!exists("scene")) scene = 'cantilever10x'
if (!exists("png")) png = 'docs/plots/accuracy_'.scene.'.png'

set terminal pngcairo size 1000,700 noenhanced font ",10"
set output png
set datafile separator ","
set logscale xy
set grid
set key outside right top
set xlabel "time per step (dynamic rows) or per static solve, ms of thread CPU"
set ylabel "mean nodal error, % of the bounding-box diagonal"
set title "hapsim-bench accuracy: ".scene." (reference in docs/accuracy.md)"

# Rows of this scene with numbers: scene,model,option,tets,step_ms,iterations,err_mean,...
sel = sprintf("< awk -F, '$1==\"%s\" && $5+0>0' %s", scene, csv)
# Pareto front: sort by time, keep each row whose error is below every faster row's.
front = sprintf("< awk -F, '$1==\"%s\" && $5+0>0' %s | sort -t, -k5,5g | awk -F, 'BEGIN{b=1e300} $7+0<b{b=$7+0; print}'", scene, csv)

is(m) = sprintf("< awk -F, '$1==\"%s\" && $5+0>0 && $2==\"%s\"' %s", scene, m, csv)
plot front using 5:7 with lines lw 2 lc rgb "black" title "Pareto front", \
     is("linear") using 5:7 with points pt 7 ps 1.2 title "linear", \
     is("linear-lf") using 5:7 with points pt 5 ps 1.2 title "linear + ANP", \
     is("corotated") using 5:7 with points pt 9 ps 1.2 title "co-rotated", \
     is("corotated-lf") using 5:7 with points pt 11 ps 1.2 title "co-rotated + ANP", \
     is("stvk") using 5:7 with points pt 13 ps 1.2 title "StVK", \
     is("stvk-lf") using 5:7 with points pt 15 ps 1.2 title "StVK + ANP", \
     is("mooney") using 5:7 with points pt 3 ps 1.5 title "Mooney-Rivlin (static)", \
     front using 5:7:(sprintf("%s %s %s", stringcolumn(2), stringcolumn(3), stringcolumn(4))) \
        with labels left offset 0.6,0.4 font ",7" notitle
