// SPDX-License-Identifier: GPL-2.0-or-later
// Small 3-vector helpers for the geometry code of the mesh and surface modules.
#ifndef HAPSIM_VEC3_H
#define HAPSIM_VEC3_H

#include <math.h>

/// c = a - b
static inline void hs_vec3_sub(const double* a, const double* b, double* c) {
    c[0] = a[0] - b[0];
    c[1] = a[1] - b[1];
    c[2] = a[2] - b[2];
}

/// c = a x b (c must not alias a or b)
static inline void hs_vec3_cross(const double* a, const double* b, double* c) {
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

/// a . b
static inline double hs_vec3_dot(const double* a, const double* b) {
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/// |a|
static inline double hs_vec3_norm(const double* a) {
    return sqrt(hs_vec3_dot(a, a));
}

#endif
