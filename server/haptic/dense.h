// Small dense symmetric positive definite solves for the haptic path (at most 3 * 16 = 48
// unknowns): row-major, caller-owned storage, no allocation. Used on the rt thread.
#ifndef HS_HAPTIC_DENSE_H
#define HS_HAPTIC_DENSE_H

#include <math.h>

/// In-place Cholesky a = L L^T of an n x n row-major SPD matrix (lower triangle written, upper
/// untouched). Returns 0, or -1 when a pivot is not positive (not SPD).
static inline int hs_dense_cholesky(double* a, int n) {
    for (int j = 0; j < n; ++j) {
        double* rj = a + (size_t)j * n;
        double s = rj[j];
        for (int k = 0; k < j; ++k) s -= rj[k] * rj[k];
        if (!(s > 0)) return -1;
        double d = sqrt(s), inv = 1.0 / d;
        rj[j] = d;
        for (int i = j + 1; i < n; ++i) {
            double* ri = a + (size_t)i * n;
            double t = ri[j];
            for (int k = 0; k < j; ++k) t -= ri[k] * rj[k];
            ri[j] = t * inv;
        }
    }
    return 0;
}

/// Solve L L^T x = b in place (x holds b on entry) with the factor from hs_dense_cholesky.
static inline void hs_dense_cholesky_solve(const double* l, int n, double* x) {
    for (int i = 0; i < n; ++i) {
        const double* ri = l + (size_t)i * n;
        double s = x[i];
        for (int k = 0; k < i; ++k) s -= ri[k] * x[k];
        x[i] = s / ri[i];
    }
    for (int i = n - 1; i >= 0; --i) {
        double s = x[i];
        for (int k = i + 1; k < n; ++k) s -= l[(size_t)k * n + i] * x[k];
        x[i] = s / l[(size_t)i * n + i];
    }
}

/// out = a * b for row-major 3x3 matrices.
static inline void hs_mat3_mul(const double a[9], const double b[9], double out[9]) {
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            out[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
}

/// out = a * b^T for row-major 3x3 matrices.
static inline void hs_mat3_mul_bt(const double a[9], const double b[9], double out[9]) {
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            out[3 * i + j] =
                a[3 * i] * b[3 * j] + a[3 * i + 1] * b[3 * j + 1] + a[3 * i + 2] * b[3 * j + 2];
}

/// out = r c r2^T: a compliance block rotated by the rotations of its two nodes.
static inline void hs_mat3_rotate(const double r[9], const double c[9], const double r2[9],
                                  double out[9]) {
    double t[9];
    hs_mat3_mul(r, c, t);
    hs_mat3_mul_bt(t, r2, out);
}

#endif
