#!/bin/sh
# SPDX-License-Identifier: MIT
# Plot a hapsim-stylus trace: applied and received force magnitude against time, and the depth
# of the handle below its starting height along the force, with gnuplot.
#   sim-device/plot_trace.sh TRACE.csv [OUT.png|OUT.svg]
# Prints the path of the plot. The summary lines of the trace (# key=value) are skipped.
set -eu
if [ $# -lt 1 ] || [ ! -r "$1" ]; then
    echo "usage: $0 TRACE.csv [OUT.png|OUT.svg]" >&2
    exit 2
fi
trace=$1
out=${2:-${trace%.csv}.png}
if ! command -v gnuplot >/dev/null 2>&1; then
    echo "plot_trace: gnuplot not found (Debian: apt-get install gnuplot-nox)" >&2
    exit 1
fi
case $out in
    *.svg) term="svg size 1100,600 dynamic" ;;
    *) term="pngcairo size 1100,600" ;;
esac
peak=$(sed -n 's/^# peak_force_n=//p' "$trace")
steady=$(sed -n 's/^# steady_force_norm_n=//p' "$trace")
energy=$(sed -n 's/^# energy_j=//p' "$trace")
# Force axis from 0 to 10 % above the peak (1 N when there was no force at all).
ymax=$(awk -v p="${peak:-0}" 'BEGIN { print (p > 0 ? 1.1 * p : 1) }')
gnuplot <<GP
set terminal $term
set output '$out'
set datafile separator ','
set datafile commentschars '#'
set key top right
set grid
set multiplot layout 2,1 title "hapsim-stylus: $(basename "$trace")  (peak ${peak:-?} N, steady ${steady:-?} N, energy into handle ${energy:-?} J)"
set ylabel 'force (N)'
set yrange [0:$ymax]
plot '$trace' every ::1 using 1:(sqrt(\$11**2+\$12**2+\$13**2)) with lines lw 2 title '|F| applied', \
     '' every ::1 using 1:(sqrt(\$8**2+\$9**2+\$10**2)) with lines dt 2 title '|F| received (at anchor)'
set xlabel 'time (s)'
set ylabel 'mm, ms'
set yrange [0:*]
plot '$trace' every ::1 using 1:(1000*sqrt((\$5-\$2)**2+(\$6-\$3)**2+(\$7-\$4)**2)) with lines title '|handle - target|', \
     '' every ::1 using 1:(\$14 > 0 ? \$14 : 0) with lines title 'model age (ms)'
unset multiplot
GP
echo "$out"
