// SPDX-License-Identifier: GPL-2.0-or-later
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

/// The nearest symmetric positive semi-definite matrix to a (Frobenius norm): its symmetric
/// part with negative eigenvalues set to zero (cyclic Jacobi on the 3x3). out may alias a.
static inline void hs_mat3_psd_part(const double a[9], double out[9]) {
    double s[9], v[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) s[3 * i + j] = 0.5 * (a[3 * i + j] + a[3 * j + i]);
    for (int sweep = 0; sweep < 12; ++sweep) {
        double off = s[1] * s[1] + s[2] * s[2] + s[5] * s[5];
        double scale = s[0] * s[0] + s[4] * s[4] + s[8] * s[8];
        if (!(off > 1e-30 * scale)) break;
        for (int p = 0; p < 2; ++p)
            for (int q = p + 1; q < 3; ++q) {
                double apq = s[3 * p + q];
                if (apq == 0) continue;
                double theta = (s[3 * q + q] - s[3 * p + p]) / (2 * apq);
                double t = (theta >= 0 ? 1.0 : -1.0) / (fabs(theta) + sqrt(theta * theta + 1));
                double c = 1 / sqrt(t * t + 1), sn = t * c;
                for (int k = 0; k < 3; ++k) { // s <- J^T s J, columns then rows
                    double skp = s[3 * k + p], skq = s[3 * k + q];
                    s[3 * k + p] = c * skp - sn * skq;
                    s[3 * k + q] = sn * skp + c * skq;
                }
                for (int k = 0; k < 3; ++k) {
                    double spk = s[3 * p + k], sqk = s[3 * q + k];
                    s[3 * p + k] = c * spk - sn * sqk;
                    s[3 * q + k] = sn * spk + c * sqk;
                }
                for (int k = 0; k < 3; ++k) {
                    double vkp = v[3 * k + p], vkq = v[3 * k + q];
                    v[3 * k + p] = c * vkp - sn * vkq;
                    v[3 * k + q] = sn * vkp + c * vkq;
                }
            }
    }
    double w[3];
    for (int k = 0; k < 3; ++k) w[k] = s[4 * k] > 0 ? s[4 * k] : 0;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            out[3 * i + j] = v[3 * i] * w[0] * v[3 * j] + v[3 * i + 1] * w[1] * v[3 * j + 1] +
                             v[3 * i + 2] * w[2] * v[3 * j + 2];
}

#endif
