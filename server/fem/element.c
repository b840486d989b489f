// SPDX-License-Identifier: GPL-2.0-or-later
// Element kernels: the rotation of a deformation gradient by Higham's polar iteration (with a
// warm start) and by a 3x3 SVD built on a Jacobi eigen-decomposition of F^T F.
#include "fem.h"

#include "element.h"
#include "polar4.h"

#include <float.h>
#include <math.h>

void hs_sym_eig3(const double a_in[9], double w[3], double v[9]) {
    double a[9];
    memcpy(a, a_in, sizeof a);
    // Symmetrise: callers pass F^T F, whose round-off may differ across the diagonal.
    a[1] = a[3] = 0.5 * (a[1] + a[3]);
    a[2] = a[6] = 0.5 * (a[2] + a[6]);
    a[5] = a[7] = 0.5 * (a[5] + a[7]);
    m3_identity(v);
    double scale = fabs(a[0]) + fabs(a[4]) + fabs(a[8]) + DBL_MIN;
    for (int sweep = 0; sweep < 32; sweep++) {
        double off = a[1] * a[1] + a[2] * a[2] + a[5] * a[5];
        if (off <= 1e-34 * scale * scale) break;
        for (int p = 0; p < 2; p++) {
            for (int q = p + 1; q < 3; q++) {
                double apq = a[3 * p + q];
                if (fabs(apq) <= 1e-300) continue;
                double app = a[3 * p + p], aqq = a[3 * q + q];
                // Classic Jacobi rotation annihilating a[p][q] (Golub & Van Loan 8.5.2).
                double tau = (aqq - app) / (2.0 * apq);
                double t = (tau >= 0 ? 1.0 : -1.0) / (fabs(tau) + sqrt(1.0 + tau * tau));
                double c = 1.0 / sqrt(1.0 + t * t), s = t * c;
                // a <- J^T a J with J the rotation in the (p,q) plane.
                for (int k = 0; k < 3; k++) {
                    double akp = a[3 * k + p], akq = a[3 * k + q];
                    a[3 * k + p] = c * akp - s * akq;
                    a[3 * k + q] = s * akp + c * akq;
                }
                for (int k = 0; k < 3; k++) {
                    double apk = a[3 * p + k], aqk = a[3 * q + k];
                    a[3 * p + k] = c * apk - s * aqk;
                    a[3 * q + k] = s * apk + c * aqk;
                }
                for (int k = 0; k < 3; k++) {
                    double vkp = v[3 * k + p], vkq = v[3 * k + q];
                    v[3 * k + p] = c * vkp - s * vkq;
                    v[3 * k + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    w[0] = a[0];
    w[1] = a[4];
    w[2] = a[8];
    // Sort descending (three elements: a small insertion sort over columns).
    for (int i = 1; i < 3; i++) {
        for (int j = i; j > 0 && w[j] > w[j - 1]; j--) {
            double t = w[j];
            w[j] = w[j - 1];
            w[j - 1] = t;
            for (int k = 0; k < 3; k++) {
                t = v[3 * k + j];
                v[3 * k + j] = v[3 * k + j - 1];
                v[3 * k + j - 1] = t;
            }
        }
    }
}

void hs_polar_svd(const double f[9], double r[9]) {
    double ftf[9], w[3], v[9];
    m3_mul_tn(f, f, ftf);
    hs_sym_eig3(ftf, w, v);
    // Proper V; then U = [u1, u2, u1 x u2] is proper too, so R = U V^T has det +1 and the
    // sign of det F ends up on the smallest singular value (Irving et al. 2004).
    if (m3_det(v) < 0) {
        v[2] = -v[2];
        v[5] = -v[5];
        v[8] = -v[8];
    }
    double v1[3] = {v[0], v[3], v[6]}, v2[3] = {v[1], v[4], v[7]};
    double u1[3], u2[3], u3[3];
    m3_vec(f, v1, u1);
    m3_vec(f, v2, u2);
    double fn = sqrt(m3_fro2(f));
    double n1 = sqrt(v3_dot(u1, u1));
    if (!(n1 > 1e-14 * fn) || !(fn > DBL_MIN)) {
        m3_identity(r); // F ~ 0: every rotation fits; take the identity
        return;
    }
    for (int k = 0; k < 3; k++) u1[k] /= n1;
    double d = v3_dot(u1, u2);
    for (int k = 0; k < 3; k++) u2[k] -= d * u1[k];
    double n2 = sqrt(v3_dot(u2, u2));
    if (!(n2 > 1e-12 * n1)) {
        // Rank one: any unit vector orthogonal to u1 completes the frame.
        double e[3] = {0, 0, 0};
        int k = fabs(u1[0]) < fabs(u1[1]) ? (fabs(u1[0]) < fabs(u1[2]) ? 0 : 2)
                                          : (fabs(u1[1]) < fabs(u1[2]) ? 1 : 2);
        e[k] = 1.0;
        v3_cross(u1, e, u2);
        n2 = sqrt(v3_dot(u2, u2));
    }
    for (int k = 0; k < 3; k++) u2[k] /= n2;
    v3_cross(u1, u2, u3);
    double u[9] = {u1[0], u2[0], u3[0], u1[1], u2[1], u3[1], u1[2], u2[2], u3[2]};
    m3_mul_nt(u, v, r);
}

/// ||I - X^T X||_F
static double orth_err(const double x[9]) {
    double xtx[9];
    m3_mul_tn(x, x, xtx);
    xtx[0] -= 1.0;
    xtx[4] -= 1.0;
    xtx[8] -= 1.0;
    return sqrt(m3_fro2(xtx));
}

/// One step of Higham's iteration X <- X (I + (I - X^T X)/2).
static void higham_step(double x[9]) {
    double xtx[9], m[9], y[9];
    m3_mul_tn(x, x, xtx);
    for (int k = 0; k < 9; k++) m[k] = -0.5 * xtx[k];
    m[0] += 1.5;
    m[4] += 1.5;
    m[8] += 1.5;
    m3_mul(x, m, y);
    memcpy(x, y, sizeof y);
}

/// 1 if the symmetric s is positive definite (Sylvester's criterion).
static int spd3(const double s[9]) {
    return s[0] > 0 && s[0] * s[4] - s[1] * s[3] > 0 && m3_det(s) > 0;
}

int hs_polar_accepts(const double rtf[9], double fn2, double tol) {
    const double* y = rtf;
    double a[3] = {0.5 * (y[7] - y[5]), 0.5 * (y[2] - y[6]), 0.5 * (y[3] - y[1])}, s[9];
    if (!(v3_dot(a, a) <= tol * tol * fn2 / 3.0)) return 0;
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) s[3 * i + j] = 0.5 * (y[3 * i + j] + y[3 * j + i]);
    return spd3(s);
}

// Warm start. Higham's iteration converges to the polar factor of the matrix it starts from,
// so a previous rotation cannot be its start (it is already orthogonal: nothing would move).
// Instead the previous rotation X is corrected by Newton steps on the condition "X^T F is
// symmetric": with Y = X^T F, S = sym(Y), a = axial(skew(Y)), the correction X <- X Q(w),
// w = 2 (tr(S) I - S)^-1 a, Q the Cayley rotation, converges quadratically when X is near R.
// Higham steps then remove the round-off drift from orthogonality. The result is accepted only
// if X^T F is symmetric positive definite (the defining property of the polar factor); any
// failure falls back to the cold Higham iteration, then to the SVD.
int hs_polar_higham(const double f[9], double r[9], double tol, int max_iter) {
    return hs_polar_higham_ex(f, r, tol, max_iter, 0, NULL);
}

int hs_polar_higham_ex(const double f[9], double r[9], double tol, int max_iter, int trusted,
                       double rtf[9]) {
    double det = m3_det(f);
    double fn2 = m3_fro2(f);
    if (!(det > 0) || !(fn2 > 0) || !isfinite(fn2)) {
        hs_polar_svd(f, r);
        if (rtf) m3_mul_tn(r, f, rtf);
        return 0;
    }
    if (!(tol > 0)) tol = 1e-12;
    int it = 0;
    double x[9], y[9], s[9];
    if (trusted || (orth_err(r) <= 1e-3 && m3_det(r) > 0)) {
        memcpy(x, r, sizeof x);
        // rotation error ~ |axial(skew(Y))| / sigma_rms, sigma_rms^2 = ||F||^2 / 3
        double prev = INFINITY, tol2 = tol * tol * fn2 / 3.0;
        while (it <= max_iter) {
            m3_mul_tn(x, f, y);
            double a[3] = {0.5 * (y[7] - y[5]), 0.5 * (y[2] - y[6]), 0.5 * (y[3] - y[1])};
            double skew2 = v3_dot(a, a);
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) s[3 * i + j] = 0.5 * (y[3 * i + j] + y[3 * j + i]);
            if (skew2 <= tol2) {
                // Accept only the polar factor: X^T F symmetric positive definite, X orthogonal.
                // A trusted start is orthogonal, and Cayley rotations keep it so up to a few
                // ulps per step, so only an untrusted start needs the orthogonality check.
                if (!spd3(s)) break;
                if (trusted || orth_err(x) <= tol) {
                    memcpy(r, x, sizeof x);
                    if (rtf) memcpy(rtf, y, sizeof y);
                    return it;
                }
                if (it >= max_iter) break;
                higham_step(x);
                it++;
                continue;
            }
            if (skew2 > 0.25 * prev || it >= max_iter) break; // not converging: go cold
            prev = skew2;
            // Newton-like step on axial(skew(Q^T Y)) = 0 at Q = I, dropping the small skew part
            // of Y from the Jacobian (measured: fewer iterations than the full Jacobian):
            // (tr(S) I - S) w = 2a, SPD when S is (eigenvalues s_i + s_j).
            double tr = s[0] + s[4] + s[8];
            double m[9] = {tr - s[0], -s[1], -s[2], -s[3],    tr - s[4],
                           -s[5],     -s[6], -s[7], tr - s[8]};
            double dm = m3_det(m);
            if (!(dm > 0)) break;
            double mc[9];
            m3_cofactor(m, mc);          // m symmetric: m^-1 = cof(m) / det(m)
            double c[3], idm = 1.0 / dm; // c = w / 2
            for (int i = 0; i < 3; i++)
                c[i] = idm * (mc[3 * i] * a[0] + mc[3 * i + 1] * a[1] + mc[3 * i + 2] * a[2]);
            // Cayley rotation: Q = I + 2/(1 + c.c) (C + C^2), C = [c]x, C^2 = c c^T - (c.c) I.
            double c2 = v3_dot(c, c), k = 2.0 / (1.0 + c2), d = 1.0 - k * c2;
            double q[9] = {
                d + k * c[0] * c[0],      k * (c[0] * c[1] - c[2]), k * (c[0] * c[2] + c[1]),
                k * (c[1] * c[0] + c[2]), d + k * c[1] * c[1],      k * (c[1] * c[2] - c[0]),
                k * (c[2] * c[0] - c[1]), k * (c[2] * c[1] + c[0]), d + k * c[2] * c[2]};
            m3_mul(x, q, y);
            memcpy(x, y, sizeof y);
            it++;
        }
    }
    double sig = sqrt(fn2 / 3.0); // root-mean-square singular value
    // Cold start: F / sigma_rms has singular values below sqrt(3) (strictly unless F has rank 1),
    // the convergence region of Higham's iteration; its limit is the polar factor of F.
    for (int k = 0; k < 9; k++) x[k] = f[k] / sig;
    int cold = 0;
    while (cold < max_iter) {
        if (orth_err(x) <= tol) break;
        higham_step(x);
        cold++;
    }
    if (orth_err(x) <= tol)
        memcpy(r, x, sizeof x);
    else
        hs_polar_svd(f, r);
    if (rtf) m3_mul_tn(r, f, rtf);
    return it + cold;
}

// ---------------------------------------------------------------------------------------------
// Four warm polar steps at once (polar4.h), gathered from and scattered to the callers' arrays.

static inline __attribute__((always_inline)) void
polar_warm4_body(const double* const f_[4], double* const r_[4], double* const rtf_[4], double tol,
                 int max_iter, int itl[4]) {
    v4d f[9], x[9], y[9];
    for (int k = 0; k < 9; k++) {
        f[k] = (v4d){f_[0][k], f_[1][k], f_[2][k], f_[3][k]};
        x[k] = (v4d){r_[0][k], r_[1][k], r_[2][k], r_[3][k]};
    }
    v4l itv, acc = {-1, -1, -1, -1};
    polar4_core(f, x, y, tol, max_iter, &acc, &itv);
    // Accepted lanes: x and the y computed from it last. Others keep their start.
    for (int l = 0; l < 4; l++) {
        if (!acc[l]) {
            itl[l] = -1;
            continue;
        }
        itl[l] = (int)itv[l];
        for (int k = 0; k < 9; k++) {
            r_[l][k] = x[k][l];
            rtf_[l][k] = y[k][l];
        }
    }
}

__attribute__((target("avx2"))) static void polar_warm4_avx2(const double* const f[4],
                                                             double* const r[4],
                                                             double* const rtf[4], double tol,
                                                             int max_iter, int it[4]) {
    polar_warm4_body(f, r, rtf, tol, max_iter, it);
}

static void polar_warm4_base(const double* const f[4], double* const r[4], double* const rtf[4],
                             double tol, int max_iter, int it[4]) {
    polar_warm4_body(f, r, rtf, tol, max_iter, it);
}

void hs_polar_warm4(const double* const f[4], double* const r[4], double* const rtf[4], double tol,
                    int max_iter, int it[4]) {
    if (__builtin_cpu_supports("avx2"))
        polar_warm4_avx2(f, r, rtf, tol, max_iter, it);
    else
        polar_warm4_base(f, r, rtf, tol, max_iter, it);
}
