// SPDX-License-Identifier: GPL-2.0-or-later
// Four warm polar steps at once, on registers: the core of hs_polar_warm4 and of the fused
// co-rotated element pass in fem.c. GCC vector extensions keep the code portable (SSE2: two
// instructions per operation; an AVX2 clone of the caller: one) and, with -ffp-contract=off,
// each lane performs exactly the operations of the scalar hs_polar_higham_ex.
#ifndef HS_FEM_POLAR4_H
#define HS_FEM_POLAR4_H

#include <float.h>
#include <math.h>

typedef double v4d __attribute__((vector_size(32)));
typedef long long v4l __attribute__((vector_size(32)));

#define HS_INLINE static inline __attribute__((always_inline))

HS_INLINE int any4(const v4l* m) {
    return ((*m)[0] | (*m)[1] | (*m)[2] | (*m)[3]) != 0;
}

/// Warm polar steps of the lanes in *lanes (-1 true, 0 false): x holds each lane's start, a
/// rotation (hs_polar_higham_ex's trusted start: no orthogonality checks), and receives its
/// rotation, y receives X^T F of it. *lanes returns the accepted ones; itv[l] counts
/// the Newton steps of lane l. A lane not accepted (stalled, out of iterations, not the polar
/// factor) keeps neither x nor y meaningful: the caller redoes it with the scalar code from
/// its stored start.
HS_INLINE void polar4_core(const v4d f[9], v4d x[9], v4d y[9], double tol, int max_iter, v4l* lanes,
                           v4l* itv_out) {
    v4l act = *lanes;
    for (int k = 0; k < 9; k++) y[k] = (v4d){0, 0, 0, 0}; // defined if no lane iterates
    v4d s[9];
    v4d fn2 = {0, 0, 0, 0}; // m3_fro2
    for (int k = 0; k < 9; k++) fn2 += f[k] * f[k];
    if (!(tol > 0)) tol = 1e-12;
    const v4d tol2 = tol * tol * fn2 / 3.0;
    v4d prev = {INFINITY, INFINITY, INFINITY, INFINITY};
    v4l acc = {0, 0, 0, 0}, itv = {0, 0, 0, 0};
    act &= (fn2 > 0) & (fn2 <= DBL_MAX);
    for (int it = 0; it <= max_iter && any4(&act); it++) {
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                y[3 * i + j] = x[i] * f[j] + x[3 + i] * f[3 + j] + x[6 + i] * f[6 + j];
        v4d a0 = 0.5 * (y[7] - y[5]), a1 = 0.5 * (y[2] - y[6]), a2 = 0.5 * (y[3] - y[1]);
        v4d skew2 = a0 * a0 + a1 * a1 + a2 * a2;
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) s[3 * i + j] = 0.5 * (y[3 * i + j] + y[3 * j + i]);
        v4l conv = act & (skew2 <= tol2);
        if (any4(&conv)) {
            // spd3(s)
            v4d sm2 = s[0] * s[4] - s[1] * s[3];
            v4d sdet = s[0] * (s[4] * s[8] - s[5] * s[7]) - s[1] * (s[3] * s[8] - s[5] * s[6]) +
                       s[2] * (s[3] * s[7] - s[4] * s[6]);
            v4l ok = (s[0] > 0) & (sm2 > 0) & (sdet > 0);
            acc |= conv & ok; // x stays; y is recomputed from it unchanged
        }
        // Not yet converged: stalled (-> cold start) or out of iterations leave; others step.
        v4l step = act & ~conv & ~(skew2 > 0.25 * prev);
        if (it >= max_iter) step &= (v4l){0, 0, 0, 0};
        if (!any4(&step)) break; // the common end: every lane accepted, no system to form
        prev = (v4d)(((v4l)skew2 & step) | ((v4l)prev & ~step));
        v4d tr = s[0] + s[4] + s[8];
        v4d m[9] = {tr - s[0], -s[1], -s[2], -s[3], tr - s[4], -s[5], -s[6], -s[7], tr - s[8]};
        // m is symmetric bit for bit (s is), so its cofactor is: six entries, and det m from
        // the first row (x - (-y) = x + y and a (-b) = -(a b) exactly: the scalar's numbers).
        v4d mc[9];
        mc[0] = m[4] * m[8] - m[5] * m[7];
        mc[1] = m[5] * m[6] - m[3] * m[8];
        mc[2] = m[3] * m[7] - m[4] * m[6];
        v4d dm = m[0] * mc[0] + m[1] * mc[1] + m[2] * mc[2];
        step &= dm > 0;
        act = step;
        if (!any4(&step)) break;
        mc[3] = mc[1];
        mc[4] = m[0] * m[8] - m[2] * m[6];
        mc[5] = m[1] * m[6] - m[0] * m[7];
        mc[6] = mc[2];
        mc[7] = mc[5];
        mc[8] = m[0] * m[4] - m[1] * m[3];
        v4d idm = 1.0 / dm, c[3];
        for (int i = 0; i < 3; i++)
            c[i] = idm * (mc[3 * i] * a0 + mc[3 * i + 1] * a1 + mc[3 * i + 2] * a2);
        v4d c2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
        v4d kk = 2.0 / (1.0 + c2), d = 1.0 - kk * c2;
        v4d q[9] = {d + kk * c[0] * c[0],      kk * (c[0] * c[1] - c[2]), kk * (c[0] * c[2] + c[1]),
                    kk * (c[1] * c[0] + c[2]), d + kk * c[1] * c[1],      kk * (c[1] * c[2] - c[0]),
                    kk * (c[2] * c[0] - c[1]), kk * (c[2] * c[1] + c[0]), d + kk * c[2] * c[2]};
        const int all = (step[0] & step[1] & step[2] & step[3]) != 0;
        for (int i = 0; i < 3; i++) {
            v4d xi[3] = {x[3 * i], x[3 * i + 1], x[3 * i + 2]};
            for (int j = 0; j < 3; j++) {
                v4d xn = xi[0] * q[j] + xi[1] * q[3 + j] + xi[2] * q[6 + j];
                x[3 * i + j] = all ? xn : (v4d)(((v4l)xn & step) | ((v4l)x[3 * i + j] & ~step));
            }
        }
        itv -= step; // +1 where stepped
    }
    *itv_out = itv;
    *lanes = acc;
}

#endif
