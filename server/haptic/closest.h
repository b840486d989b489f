// SPDX-License-Identifier: GPL-2.0-or-later
// Closest point of a triangle to a point, with the feature (vertex, edge, face interior) it lies
// on: the geometric core of the surface contact, shared by the rt solve (contact.c) and the
// snapshot's triangle search (haptic_sim.c). Pure, no allocation.
#ifndef HS_HAPTIC_CLOSEST_H
#define HS_HAPTIC_CLOSEST_H

#include <math.h>

/// Feature a closest point lies on.
enum { HS_FEAT_VERTEX = 1, HS_FEAT_EDGE = 2, HS_FEAT_FACE = 3 };

static inline double hs_dot3(const double a[3], const double b[3]) {
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/// Closest point x of triangle (a, b, c) to p: x = w[0] a + w[1] b + w[2] c, w >= 0, sum 1.
/// Returns the feature: HS_FEAT_VERTEX (one w is 1), HS_FEAT_EDGE (one w is exactly 0) or
/// HS_FEAT_FACE (all w > 0); 0 for a degenerate (zero-area) triangle. The region tests are the
/// usual Voronoi-region ones, so the feature is decided before any division.
static inline int hs_tri_closest(const double p[3], const double a[3], const double b[3],
                                 const double c[3], double w[3] /* OUT */, double x[3] /* OUT */) {
    double ab[3], ac[3], ap[3], bp[3], cp[3];
    for (int k = 0; k < 3; ++k) {
        ab[k] = b[k] - a[k];
        ac[k] = c[k] - a[k];
        ap[k] = p[k] - a[k];
        bp[k] = p[k] - b[k];
        cp[k] = p[k] - c[k];
    }
    int kind = HS_FEAT_FACE;
    double d1 = hs_dot3(ab, ap), d2 = hs_dot3(ac, ap);
    double d3 = hs_dot3(ab, bp), d4 = hs_dot3(ac, bp);
    double d5 = hs_dot3(ab, cp), d6 = hs_dot3(ac, cp);
    double va = d3 * d6 - d5 * d4, vb = d5 * d2 - d1 * d6, vc = d1 * d4 - d3 * d2;
    double den = va + vb + vc;
    // den = |ab x ac|^2: the triangle is degenerate when it vanishes against the edge lengths.
    if (!(den > 1e-24 * hs_dot3(ab, ab) * hs_dot3(ac, ac))) return 0;
    if (d1 <= 0 && d2 <= 0) {
        w[0] = 1, w[1] = 0, w[2] = 0, kind = HS_FEAT_VERTEX;
    } else if (d3 >= 0 && d4 <= d3) {
        w[0] = 0, w[1] = 1, w[2] = 0, kind = HS_FEAT_VERTEX;
    } else if (d6 >= 0 && d5 <= d6) {
        w[0] = 0, w[1] = 0, w[2] = 1, kind = HS_FEAT_VERTEX;
    } else if (vc <= 0 && d1 >= 0 && d3 <= 0) {
        double t = d1 / (d1 - d3);
        w[0] = 1 - t, w[1] = t, w[2] = 0, kind = HS_FEAT_EDGE;
    } else if (vb <= 0 && d2 >= 0 && d6 <= 0) {
        double t = d2 / (d2 - d6);
        w[0] = 1 - t, w[1] = 0, w[2] = t, kind = HS_FEAT_EDGE;
    } else if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
        double t = (d4 - d3) / ((d4 - d3) + (d5 - d6));
        w[0] = 0, w[1] = 1 - t, w[2] = t, kind = HS_FEAT_EDGE;
    } else {
        double inv = 1.0 / den;
        w[1] = vb * inv;
        w[2] = vc * inv;
        w[0] = 1 - w[1] - w[2];
    }
    for (int k = 0; k < 3; ++k) x[k] = w[0] * a[k] + w[1] * b[k] + w[2] * c[k];
    return kind;
}

#endif
