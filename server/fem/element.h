// SPDX-License-Identifier: GPL-2.0-or-later
// Internal 3x3 helpers shared by the element kernels (element.c) and the FEM object (fem.c).
// Matrices are row-major double[9]. Everything is static inline so the hot loops stay inlined.
#ifndef HS_FEM_ELEMENT_H
#define HS_FEM_ELEMENT_H

#include <math.h>
#include <string.h>

static inline void m3_identity(double a[9]) {
    memset(a, 0, 9 * sizeof(double));
    a[0] = a[4] = a[8] = 1.0;
}

static inline double m3_det(const double a[9]) {
    return a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6]) +
           a[2] * (a[3] * a[7] - a[4] * a[6]);
}

/// c = a b
static inline void m3_mul(const double a[9], const double b[9], double c[9]) {
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            c[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
}

/// c = a^T b
static inline void m3_mul_tn(const double a[9], const double b[9], double c[9]) {
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            c[3 * i + j] = a[i] * b[j] + a[3 + i] * b[3 + j] + a[6 + i] * b[6 + j];
}

/// c = a b^T
static inline void m3_mul_nt(const double a[9], const double b[9], double c[9]) {
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            c[3 * i + j] =
                a[3 * i] * b[3 * j] + a[3 * i + 1] * b[3 * j + 1] + a[3 * i + 2] * b[3 * j + 2];
}

/// y = a x
static inline void m3_vec(const double a[9], const double x[3], double y[3]) {
    y[0] = a[0] * x[0] + a[1] * x[1] + a[2] * x[2];
    y[1] = a[3] * x[0] + a[4] * x[1] + a[5] * x[2];
    y[2] = a[6] * x[0] + a[7] * x[1] + a[8] * x[2];
}

static inline double m3_fro2(const double a[9]) {
    double s = 0;
    for (int k = 0; k < 9; k++) s += a[k] * a[k];
    return s;
}

/// Cofactor matrix: cof(a) = det(a) a^-T, defined also for singular a.
static inline void m3_cofactor(const double a[9], double c[9]) {
    c[0] = a[4] * a[8] - a[5] * a[7];
    c[1] = a[5] * a[6] - a[3] * a[8];
    c[2] = a[3] * a[7] - a[4] * a[6];
    c[3] = a[2] * a[7] - a[1] * a[8];
    c[4] = a[0] * a[8] - a[2] * a[6];
    c[5] = a[1] * a[6] - a[0] * a[7];
    c[6] = a[1] * a[5] - a[2] * a[4];
    c[7] = a[2] * a[3] - a[0] * a[5];
    c[8] = a[0] * a[4] - a[1] * a[3];
}

static inline void v3_cross(const double a[3], const double b[3], double c[3]) {
    c[0] = a[1] * b[2] - a[2] * b[1];
    c[1] = a[2] * b[0] - a[0] * b[2];
    c[2] = a[0] * b[1] - a[1] * b[0];
}

static inline double v3_dot(const double a[3], const double b[3]) {
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

/// Symmetric eigen-decomposition by cyclic Jacobi: a = V diag(w) V^T, w descending,
/// V's columns the eigenvectors (row-major: v[3*i+k] is component i of vector k).
void hs_sym_eig3(const double a[9], double w[3], double v[9]);

/// 1 when a rotation R is accepted as F's polar factor to tol, given rtf = R^T F and
/// fn2 = ||F||^2: the skew part of R^T F within tol (relative to F's rms singular value) and its
/// symmetric part positive definite; the test that ends hs_polar_higham_ex's warm phase.
int hs_polar_accepts(const double rtf[9], double fn2, double tol);

/// hs_polar_higham; trusted = 1 skips checking that r is a rotation (the caller made it);
/// rtf (may be NULL) receives R^T F at the result.
int hs_polar_higham_ex(const double f[9], double r[9], double tol, int max_iter, int trusted,
                       double rtf[9]);

/// The warm phase of hs_polar_higham_ex with a trusted start on 4 matrices at once, through
/// polar4_core (the co-rotated element pass runs it on registers; this wraps it for arrays, for
/// test_fem): lane l reads F from f[l] and its start, a rotation, from r[l] (row-major 3x3
/// each); the caller has checked det F > 0. Lane-wise the same IEEE operations in the same
/// order as the scalar code, so an accepted lane's rotation (written to r[l]) and R^T F (to
/// rtf[l]) are bit-identical to hs_polar_higham_ex's, and it[l] is its iteration count.
/// it[l] = -1 where the scalar code would leave the warm phase (degenerate F, stalled or out of
/// iterations, then cold start or SVD): r[l] is left as it was, and the caller redoes that lane
/// with hs_polar_higham_ex. Unused lanes may point at f = r = I.
void hs_polar_warm4(const double* const f[4], double* const r[4], double* const rtf[4], double tol,
                    int max_iter, int it[4]);

#endif
