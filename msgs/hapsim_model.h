// SPDX-License-Identifier: MIT
// hapsim protocol: the local force model of tool_force_t (docs/protocol.md "Driving a device"),
// evaluated by one function for the server's rt loop, the client library and the stylus, and
// the time blend between two models. Pure arithmetic, header only: no LCM, no allocation.
#ifndef HAPSIM_MODEL_H
#define HAPSIM_MODEL_H

#include <math.h>

/// Results of hapsim_model_force.
enum {
    HAPSIM_MODEL_NONFINITE = -1, ///< the force is not finite (left as computed)
    HAPSIM_MODEL_CLAMPED = 0,    ///< p outside the validity radius: evaluated on its sphere
    HAPSIM_MODEL_INSIDE = 1,     ///< p within the validity radius
};

/// d = p - anchor pulled back onto the validity sphere (radius <= 0: d = 0) when outside, into
/// d[3]; *dist (may be NULL) gets |p - anchor|. |d| beyond ~1e154 m overflows when squared, so
/// such a d is scaled by its largest component first: any finite p, however far, is clamped.
/// Returns HAPSIM_MODEL_INSIDE or HAPSIM_MODEL_CLAMPED (also for a NaN p, whose d stays NaN).
static inline int hapsim_model_offset(const double anchor[3], double radius, const double p[3],
                                      double d[3], double* dist) {
    for (int i = 0; i < 3; ++i) d[i] = p[i] - anchor[i];
    double n = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    if (dist) *dist = n;
    double r = radius > 0 ? radius : 0;
    if (n <= r) return HAPSIM_MODEL_INSIDE;
    if (isinf(n)) {
        double mx = fmax(fabs(d[0]), fmax(fabs(d[1]), fabs(d[2])));
        if (isfinite(mx)) {
            for (int i = 0; i < 3; ++i) d[i] /= mx;
            n = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        }
    }
    double s = n > 0 ? r / n : 0;
    for (int i = 0; i < 3; ++i) d[i] *= s;
    return HAPSIM_MODEL_CLAMPED;
}

/// The model's force at p: F = f0 + k_sign K d, d from hapsim_model_offset. K is row-major 3x3;
/// k_sign is +1 for the wire's dF/dp and -1 for a stiffness stored as -dF/dp (the server's).
/// A non-finite F (a NaN p, or a model beyond the wire ranges) returns HAPSIM_MODEL_NONFINITE
/// with f as computed: the caller's safety stage acts on it (drivers render zero, the server's
/// safety filter counts the fault and zeroes). Thread: any | Allocates: no
static inline int hapsim_model_force(const double f0[3], const double anchor[3], const double k[9],
                                     double k_sign, double radius, const double p[3], double f[3]) {
    double d[3];
    int r = hapsim_model_offset(anchor, radius, p, d, NULL);
    for (int i = 0; i < 3; ++i)
        f[i] = f0[i] + k_sign * (k[3 * i] * d[0] + k[3 * i + 1] * d[1] + k[3 * i + 2] * d[2]);
    return isfinite(f[0]) && isfinite(f[1]) && isfinite(f[2]) ? r : HAPSIM_MODEL_NONFINITE;
}

/// Blend after a model change: f = (1 - w) f_old + w f_new, w = t / blend (0 for t <= 0, 1 from
/// t >= blend or blend <= 0); t and blend in the same unit. Thread: any | Allocates: no
static inline void hapsim_model_blend(const double f_old[3], const double f_new[3], double t,
                                      double blend, double f[3]) {
    double w = blend <= 0 || t >= blend ? 1 : t <= 0 ? 0 : t / blend;
    for (int i = 0; i < 3; ++i) f[i] = (1 - w) * f_old[i] + w * f_new[i];
}

#endif
