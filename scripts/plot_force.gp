# SPDX-License-Identifier: GPL-2.0-or-later
# Force against time from a hapsim-stylus trace (docs/stylus.md): gnuplot -e "trace='T'; out='P'" scripts/plot_force.gp
# Columns used: 1 t_s, 8-10 f_recv (server's model, N), 11-13 f_app (applied by the motor, N), 16 segment.
if (!exists("trace")) trace = 'out/demo/demo-trace.csv'
if (!exists("out")) out = 'out/demo/demo-force.png'
set datafile separator ','
set terminal pngcairo size 1200,700 font ',11' noenhanced
set output out
set multiplot layout 2,1 title sprintf('hapsim demo: %s', trace)
set grid
set key top right
set ylabel 'force magnitude (N)'
fmag(x, y, z) = sqrt(x*x + y*y + z*z)
plot trace every ::1 using 1:(fmag($11, $12, $13)) with lines lw 2 title '|F| applied to the handle', \
     trace every ::1 using 1:(fmag($8, $9, $10)) with lines lw 1 dt 2 title '|F| from the server model'
set xlabel 'time (s)'
set ylabel 'force (N)'
plot trace every ::1 using 1:11 with lines title 'F_x', \
     trace every ::1 using 1:12 with lines title 'F_y', \
     trace every ::1 using 1:13 with lines title 'F_z'
unset multiplot
