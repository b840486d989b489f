// SPDX-License-Identifier: GPL-2.0-or-later
// Mooney-Rivlin reference solver: element kernel, homogeneous deformation, small-strain limit,
// pressure stabilisation, Newton convergence, bad input.
#include "mooney.h"
#include "test_macros.h"

#include <stdlib.h>

static int on_box_boundary(const hs_mesh* m, int i) {
    const double* x = m->x0 + 3 * i;
    for (int c = 0; c < 3; c++) {
        double tol = 1e-9 * (m->bbox_max[c] - m->bbox_min[c] + 1.0);
        if (fabs(x[c] - m->bbox_min[c]) < tol || fabs(x[c] - m->bbox_max[c]) < tol) return 1;
    }
    return 0;
}

static void mat_mul(const double* a, const double* b, double* c) {
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double s = 0;
            for (int k = 0; k < 3; k++) s += a[i * 3 + k] * b[k * 3 + j];
            c[i * 3 + j] = s;
        }
}

static double det3(const double* a) {
    return a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6]) +
           a[2] * (a[3] * a[7] - a[4] * a[6]);
}

// Analytic Cauchy stress of the mixed Mooney-Rivlin model, in the spatial (b) form:
// sigma = 2/J [(c1 J^-2/3 + c2 J^-4/3 I1) b - c2 J^-4/3 b^2]
//         - 2/(3J) (c1 J^-2/3 I1 + 2 c2 J^-4/3 I2) I + p I.
static void analytic_cauchy(double c1, double c2, double p, const double* f, double* s) {
    double ft[9], b[9], b2[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) ft[i * 3 + j] = f[j * 3 + i];
    mat_mul(f, ft, b);
    mat_mul(b, b, b2);
    double j = det3(f), i1 = b[0] + b[4] + b[8];
    double i2 = 0.5 * (i1 * i1 - (b2[0] + b2[4] + b2[8]));
    double j23 = pow(j, -2.0 / 3.0), j43 = pow(j, -4.0 / 3.0);
    for (int k = 0; k < 9; k++) {
        s[k] = 2.0 / j * ((c1 * j23 + c2 * j43 * i1) * b[k] - c2 * j43 * b2[k]);
        if (k % 4 == 0) s[k] += -2.0 / (3.0 * j) * (c1 * j23 * i1 + 2.0 * c2 * j43 * i2) + p;
    }
}

// ---------------------------------------------------------------------------------------------

static int mooney_kernel(void) {
    double c1 = 400, c2 = 300, p = -250;
    double f[9] = {1.1, 0.2, -0.05, 0.03, 0.95, 0.1, -0.08, 0.04, 1.2};
    double pk[9], a[81];
    double w = hs_mooney_pk1(c1, c2, p, f, pk, a);
    ENSURE(w > 0);
    // P is the derivative of W_iso + p (J - 1); A the derivative of P (central differences).
    double hstep = 1e-6;
    for (int kl = 0; kl < 9; kl++) {
        double fp[9], fm[9], pp[9], pm[9];
        memcpy(fp, f, sizeof fp);
        memcpy(fm, f, sizeof fm);
        fp[kl] += hstep;
        fm[kl] -= hstep;
        double wp = hs_mooney_pk1(c1, c2, p, fp, pp, NULL) + p * (det3(fp) - 1.0);
        double wm = hs_mooney_pk1(c1, c2, p, fm, pm, NULL) + p * (det3(fm) - 1.0);
        ENSURE_NEAR(pk[kl], (wp - wm) / (2 * hstep), 1e-6 * 1000);
        for (int ij = 0; ij < 9; ij++)
            ENSURE_NEAR(a[ij * 9 + kl], (pp[ij] - pm[ij]) / (2 * hstep), 1e-6 * 1000);
        // major symmetry of the elasticity tensor
        for (int ij = 0; ij < 9; ij++) ENSURE_NEAR(a[ij * 9 + kl], a[kl * 9 + ij], 1e-9 * 1000);
    }
    // Cauchy stress sigma = P F^T / J against the spatial closed form.
    double ft[9], s[9], sa[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) ft[i * 3 + j] = f[j * 3 + i];
    mat_mul(pk, ft, s);
    analytic_cauchy(c1, c2, p, f, sa);
    for (int k = 0; k < 9; k++) ENSURE_NEAR(s[k] / det3(f), sa[k], 1e-9 * 1000);
    // Stress free at F = I, p = 0; isochoric part traceless for any F.
    double id[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    hs_mooney_pk1(c1, c2, 0, id, pk, NULL);
    for (int k = 0; k < 9; k++) ENSURE_SMALL(pk[k], 1e-12);
    analytic_cauchy(c1, c2, 0, f, sa);
    ENSURE_SMALL(sa[0] + sa[4] + sa[8], 1e-9);
    return 0;
}

// Homogeneous F prescribed on every boundary node: the solution is homogeneous, its element
// stress is the analytic one, pressures are kappa (J - 1) whatever beta is, and the internal
// force at interior nodes vanishes.
static int homogeneous_case(double beta) {
    int64_t bytes0 = hs_byte_count();
    hs_err err;
    hs_mesh* mesh = NULL;
    ENSURE(hs_mesh_create_box(1.0, 1.0, 1.0, 3, 3, 3, &mesh, &err) == HS_OK);
    int n = mesh->n_nodes;
    unsigned char* fixed = calloc((size_t)n, 1);
    double* u = calloc(3 * (size_t)n, sizeof(double));
    double* q = calloc(3 * (size_t)n, sizeof(double));
    double f[9] = {1.15, 0.1, 0.0, 0.0, 0.92, 0.05, 0.02, 0.0, 1.03};
    int n_interior = 0;
    for (int i = 0; i < n; i++) {
        fixed[i] = (unsigned char)on_box_boundary(mesh, i);
        n_interior += !fixed[i];
        for (int r = 0; r < 3; r++) {
            double s = 0;
            for (int c = 0; c < 3; c++) s += (f[r * 3 + c] - (r == c)) * mesh->x0[3 * i + c];
            u[3 * i + r] = s;
        }
    }
    ENSURE(n_interior == 8);
    hs_mooney_def def = hs_mooney_default_def();
    def.youngs_pa = 5000;
    def.poisson = 0.45;
    def.beta = beta;
    def.load_steps = 2;
    hs_mooney* m = NULL;
    ENSURE(hs_mooney_create(mesh, &def, fixed, &m, &err) == HS_OK);
    double c1, c2, kappa;
    hs_mooney_constants(&def, &c1, &c2, &kappa);
    ENSURE_NEAR(c1 + c2, def.youngs_pa / (4 * (1 + def.poisson)), 1e-9);
    // (a) residual of the exact homogeneous field at interior nodes is zero.
    ENSURE(hs_mooney_set_displacement(m, u, &err) == HS_OK);
    hs_mooney_internal_forces(m, q);
    double qmax_fixed = 0, qmax_free = 0;
    for (int i = 0; i < n; i++)
        for (int c = 0; c < 3; c++) {
            double v = fabs(q[3 * i + c]);
            if (fixed[i])
                qmax_fixed = fmax(qmax_fixed, v);
            else
                qmax_free = fmax(qmax_free, v);
        }
    ENSURE(qmax_fixed > 1.0); // boundary carries the reactions
    ENSURE_SMALL(qmax_free / qmax_fixed, 1e-12);
    // (b) solve from rest with the boundary prescribed: interior nodes land on the field.
    double* zero = calloc(3 * (size_t)n, sizeof(double));
    ENSURE(hs_mooney_set_displacement(m, zero, &err) == HS_OK);
    ENSURE(hs_mooney_set_prescribed(m, u) == HS_OK);
    hs_mooney_stats st;
    hs_status s = hs_mooney_solve_static(m, &st, &err);
    if (s != HS_OK) printf("  solve: %s\n", err.msg);
    ENSURE(s == HS_OK);
    const double* us = hs_mooney_displacement(m);
    for (int d = 0; d < 3 * n; d++) ENSURE_NEAR(us[d], u[d], 1e-9);
    double jd = det3(f), sa[9], sg[9];
    analytic_cauchy(c1, c2, kappa * (jd - 1.0), f, sa);
    const double* p = hs_mooney_pressure(m);
    for (int e = 0; e < mesh->n_tets; e++) {
        ENSURE_NEAR(p[e], kappa * (jd - 1.0), 1e-7 * kappa);
        hs_mooney_element_stress(m, e, sg);
        for (int k = 0; k < 9; k++) ENSURE_NEAR(sg[k], sa[k], 1e-7 * kappa);
    }
    ENSURE_SMALL(hs_mooney_pressure_oscillation(m), 1e-6);
    printf("  beta %g: %d increments, Newton %d iterations, final ratio %.2e, p %.4g Pa\n", beta,
           st.increments, st.newton_total, st.final_ratio, p[0]);
    hs_mooney_destroy(&m);
    ENSURE(m == NULL);
    hs_mesh_destroy(&mesh);
    free(fixed);
    free(u);
    free(q);
    free(zero);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int mooney_homogeneous(void) {
    if (homogeneous_case(0.0)) return 1;
    return homogeneous_case(0.5);
}

// ---------------------------------------------------------------------------------------------
// Linear elasticity on the same mesh (independent dense assembly) for the small-strain check.

static void shape_gradients(const hs_mesh* mesh, int e, double g[12], double* vol) {
    const int* t = mesh->tets + 4 * e;
    double dm[9];
    for (int c = 0; c < 3; c++)
        for (int i = 0; i < 3; i++)
            dm[i * 3 + c] = mesh->x0[3 * t[c + 1] + i] - mesh->x0[3 * t[0] + i];
    double d = det3(dm), inv[9];
    *vol = d / 6.0;
    // inverse by cofactors: inv = adj(dm) / d
    inv[0] = (dm[4] * dm[8] - dm[5] * dm[7]) / d;
    inv[1] = -(dm[1] * dm[8] - dm[2] * dm[7]) / d;
    inv[2] = (dm[1] * dm[5] - dm[2] * dm[4]) / d;
    inv[3] = -(dm[3] * dm[8] - dm[5] * dm[6]) / d;
    inv[4] = (dm[0] * dm[8] - dm[2] * dm[6]) / d;
    inv[5] = -(dm[0] * dm[5] - dm[2] * dm[3]) / d;
    inv[6] = (dm[3] * dm[7] - dm[4] * dm[6]) / d;
    inv[7] = -(dm[0] * dm[7] - dm[1] * dm[6]) / d;
    inv[8] = (dm[0] * dm[4] - dm[1] * dm[3]) / d;
    for (int a = 1; a < 4; a++)
        for (int j = 0; j < 3; j++) g[3 * a + j] = inv[(a - 1) * 3 + j];
    for (int j = 0; j < 3; j++) g[j] = -(g[3 + j] + g[6 + j] + g[9 + j]);
}

// Solve K u = f with K the linear-elastic stiffness, fixed nodes clamped. Dense Cholesky.
static int linear_solution(const hs_mesh* mesh, double e_mod, double nu, const unsigned char* fixed,
                           const double* f, double* u) {
    int n = mesh->n_nodes;
    int* map = malloc(sizeof(int) * 3 * (size_t)n);
    int nf = 0;
    for (int i = 0; i < n; i++)
        for (int c = 0; c < 3; c++) map[3 * i + c] = fixed[i] ? -1 : nf++;
    double* k = calloc((size_t)nf * (size_t)nf, sizeof(double));
    double* b = calloc((size_t)nf, sizeof(double));
    double lam = e_mod * nu / ((1 + nu) * (1 - 2 * nu)), mu = e_mod / (2 * (1 + nu));
    for (int e = 0; e < mesh->n_tets; e++) {
        double g[12], v;
        shape_gradients(mesh, e, g, &v);
        const int* t = mesh->tets + 4 * e;
        for (int a = 0; a < 4; a++)
            for (int i = 0; i < 3; i++)
                for (int bb = 0; bb < 4; bb++)
                    for (int kk = 0; kk < 3; kk++) {
                        int r = map[3 * t[a] + i], c = map[3 * t[bb] + kk];
                        if (r < 0 || c < 0) continue;
                        double gg = 0;
                        for (int j = 0; j < 3; j++) gg += g[3 * a + j] * g[3 * bb + j];
                        double val = lam * g[3 * a + i] * g[3 * bb + kk] +
                                     mu * g[3 * a + kk] * g[3 * bb + i] + (i == kk ? mu * gg : 0);
                        k[(size_t)r * nf + c] += v * val;
                    }
    }
    for (int d = 0; d < 3 * n; d++)
        if (map[d] >= 0) b[map[d]] = f[d];
    for (int j = 0; j < nf; j++) { // in-place Cholesky, lower triangle
        double s = k[(size_t)j * nf + j];
        for (int p = 0; p < j; p++) s -= k[(size_t)j * nf + p] * k[(size_t)j * nf + p];
        if (!(s > 0)) return 1;
        s = sqrt(s);
        k[(size_t)j * nf + j] = s;
        for (int i = j + 1; i < nf; i++) {
            double t = k[(size_t)i * nf + j];
            for (int p = 0; p < j; p++) t -= k[(size_t)i * nf + p] * k[(size_t)j * nf + p];
            k[(size_t)i * nf + j] = t / s;
        }
    }
    for (int i = 0; i < nf; i++) {
        double s = b[i];
        for (int p = 0; p < i; p++) s -= k[(size_t)i * nf + p] * b[p];
        b[i] = s / k[(size_t)i * nf + i];
    }
    for (int i = nf - 1; i >= 0; i--) {
        double s = b[i];
        for (int p = i + 1; p < nf; p++) s -= k[(size_t)p * nf + i] * b[p];
        b[i] = s / k[(size_t)i * nf + i];
    }
    for (int d = 0; d < 3 * n; d++) u[d] = map[d] >= 0 ? b[map[d]] : 0.0;
    free(map);
    free(k);
    free(b);
    return 0;
}

// A cantilever (clamped at x = 0) under a small tip load and gravity agrees with linear FEM.
static int small_strain_case(double nu, double* rel_out) {
    hs_err err;
    hs_mesh* mesh = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &mesh, &err) == HS_OK);
    int n = mesh->n_nodes;
    unsigned char* fixed = calloc((size_t)n, 1);
    double* f = calloc(3 * (size_t)n, sizeof(double));
    double* ul = calloc(3 * (size_t)n, sizeof(double));
    int n_tip = 0;
    for (int i = 0; i < n; i++) {
        fixed[i] = mesh->x0[3 * i] < 1e-9;
        if (mesh->x0[3 * i] > 0.1 - 1e-9) n_tip++;
    }
    double e_mod = 3000, load = 1e-5; // N in total: tip deflection ~0.3 % of the length
    for (int i = 0; i < n; i++)
        if (mesh->x0[3 * i] > 0.1 - 1e-9) f[3 * i + 2] = -load / n_tip;
    ENSURE(linear_solution(mesh, e_mod, nu, fixed, f, ul) == 0);
    hs_mooney_def def = hs_mooney_default_def();
    def.youngs_pa = e_mod;
    def.poisson = nu;
    hs_mooney* m = NULL;
    ENSURE(hs_mooney_create(mesh, &def, fixed, &m, &err) == HS_OK);
    ENSURE(hs_mooney_set_forces(m, f) == HS_OK);
    hs_mooney_stats st;
    hs_status s = hs_mooney_solve_static(m, &st, &err);
    if (s != HS_OK) printf("  solve: %s\n", err.msg);
    ENSURE(s == HS_OK);
    const double* u = hs_mooney_displacement(m);
    double dmax = 0, umax = 0;
    for (int d = 0; d < 3 * n; d++) {
        dmax = fmax(dmax, fabs(u[d] - ul[d]));
        umax = fmax(umax, fabs(ul[d]));
    }
    ENSURE(umax > 1e-4 * 0.1); // the load does bend the beam
    *rel_out = dmax / umax;
    printf("  nu %g: tip deflection linear %.4e m, max |u_mr - u_lin| / max |u_lin| = %.2e, "
           "Newton %d\n",
           nu, umax, *rel_out, st.newton_total);
    hs_mooney_destroy(&m);
    hs_mesh_destroy(&mesh);
    free(fixed);
    free(f);
    free(ul);
    return 0;
}

static int mooney_small_strain(void) {
    double rel;
    if (small_strain_case(0.3, &rel)) return 1;
    ENSURE(rel < 0.01);
    if (small_strain_case(0.45, &rel)) return 1;
    ENSURE(rel < 0.01);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Nearly incompressible block compressed between clamped plates: P1/P0 without stabilisation
// shows a checkerboard pressure; beta > 0 smooths it.

static int compress_block(double beta, double nu, double* osc, hs_mooney_stats* st) {
    hs_err err;
    hs_mesh* mesh = NULL;
    ENSURE(hs_mesh_create_box(1.0, 1.0, 1.0, 4, 4, 4, &mesh, &err) == HS_OK);
    int n = mesh->n_nodes;
    unsigned char* fixed = calloc((size_t)n, 1);
    double* up = calloc(3 * (size_t)n, sizeof(double));
    for (int i = 0; i < n; i++) {
        double z = mesh->x0[3 * i + 2];
        if (z < 1e-9) fixed[i] = 1;
        if (z > 1.0 - 1e-9) fixed[i] = 1, up[3 * i + 2] = -0.1;
    }
    hs_mooney_def def = hs_mooney_default_def();
    def.poisson = nu;
    def.beta = beta;
    def.load_steps = 2;
    hs_mooney* m = NULL;
    ENSURE(hs_mooney_create(mesh, &def, fixed, &m, &err) == HS_OK);
    ENSURE(hs_mooney_set_prescribed(m, up) == HS_OK);
    hs_status s = hs_mooney_solve_static(m, st, &err);
    if (s != HS_OK) printf("  solve: %s\n", err.msg);
    ENSURE(s == HS_OK);
    ENSURE(st->final_ratio <= def.tolerance || st->final_ratio == 0);
    *osc = hs_mooney_pressure_oscillation(m);
    const double* p = hs_mooney_pressure(m);
    double pmean = 0;
    for (int e = 0; e < mesh->n_tets; e++) pmean += p[e] / mesh->n_tets;
    ENSURE(pmean < 0); // compressed: negative mean stress
    printf("  beta %-5g nu %g: oscillation %.3f, mean p %.1f Pa, J in [%.4f, %.4f], V/V0 %.5f, "
           "Newton %d, %d unknowns, %.0f ms\n",
           beta, nu, *osc, pmean, st->volume_ratio_min, st->volume_ratio_max,
           st->volume_ratio_total, st->newton_total, st->system_size, st->solve_ms);
    hs_mooney_destroy(&m);
    hs_mesh_destroy(&mesh);
    free(fixed);
    free(up);
    return 0;
}

static int mooney_stabilisation(void) {
    int64_t bytes0 = hs_byte_count();
    double o0, o1, o2;
    hs_mooney_stats st;
    // beta multiplies h / kappa, so the strength relative to shear is beta mu / kappa:
    // at nu = 0.499 (kappa / mu = 499) beta of order 100 is needed (docs/mooney.md).
    if (compress_block(0.0, 0.499, &o0, &st)) return 1;
    if (compress_block(100.0, 0.499, &o1, &st)) return 1;
    ENSURE(st.system_size > 3 * 75); // beta > 0 adds one unknown per interior face
    if (compress_block(1000.0, 0.499, &o2, &st)) return 1;
    ENSURE(o0 > 0.8);      // checkerboard without stabilisation (jumps ~ RMS pressure)
    ENSURE(o1 < 0.3 * o0); // much smoother with it
    ENSURE(o2 < 0.5 * o1);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Large deflection in one increment: Newton converges, quadratically at the end.

static int newton_case(double beta) {
    hs_err err;
    hs_mesh* mesh = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &mesh, &err) == HS_OK);
    int n = mesh->n_nodes;
    unsigned char* fixed = calloc((size_t)n, 1);
    for (int i = 0; i < n; i++) fixed[i] = mesh->x0[3 * i] < 1e-9;
    hs_mooney_def def = hs_mooney_default_def();
    def.youngs_pa = 3000;
    def.poisson = 0.45;
    def.beta = beta;
    hs_mooney* m = NULL;
    ENSURE(hs_mooney_create(mesh, &def, fixed, &m, &err) == HS_OK);
    double g[3] = {0, 0, -9.81};
    ENSURE(hs_mooney_set_gravity(m, g) == HS_OK);
    hs_mooney_stats st;
    hs_status s = hs_mooney_solve_static(m, &st, &err);
    if (s != HS_OK) printf("  solve: %s\n", err.msg);
    ENSURE(s == HS_OK);
    const double* u = hs_mooney_displacement(m);
    double tip = 0;
    for (int i = 0; i < n; i++) tip = fmin(tip, u[3 * i + 2]);
    printf("  beta %g: tip deflection %.4f m, %d Newton iterations, ratios:", beta, tip,
           st.n_ratio - 1);
    for (int k = 0; k < st.n_ratio; k++) printf(" %.1e", st.ratio[k]);
    printf("\n");
    ENSURE(tip < -0.02); // large deflection (20 % of the length)
    ENSURE(st.final_ratio <= 1e-8);
    ENSURE(st.n_ratio >= 4);
    // Quadratic: once the ratio is below 1e-2, the next is at most about its square
    // (log-ratio at least 1.6), for every step that starts above the round-off floor.
    int checked = 0;
    for (int k = 1; k + 1 < st.n_ratio; k++) {
        double a = st.ratio[k], b = st.ratio[k + 1];
        if (a > 1e-2 || a < 1e-12) continue;
        ENSURE(log(b) / log(a) >= 1.6);
        checked++;
    }
    ENSURE(checked >= 1);
    hs_mooney_destroy(&m);
    hs_mesh_destroy(&mesh);
    free(fixed);
    return 0;
}

static int mooney_newton_quadratic(void) {
    int64_t bytes0 = hs_byte_count();
    if (newton_case(0.0)) return 1;
    if (newton_case(0.5)) return 1;
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int mooney_bad_input(void) {
    int64_t bytes0 = hs_byte_count();
    hs_err err;
    hs_mesh* mesh = NULL;
    ENSURE(hs_mesh_create_box(1, 1, 1, 2, 2, 2, &mesh, &err) == HS_OK);
    int n = mesh->n_nodes;
    unsigned char* fixed = calloc((size_t)n, 1);
    for (int i = 0; i < n; i++) fixed[i] = mesh->x0[3 * i + 2] < 1e-9;
    hs_mooney* m = NULL;
    hs_mooney_def def;
    memset(&def, 0, sizeof def);
    ENSURE(hs_mooney_create(mesh, &def, fixed, &m, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "hs_mooney_default_def") != NULL);
    def = hs_mooney_default_def();
    def.poisson = 0.5;
    ENSURE(hs_mooney_create(mesh, &def, fixed, &m, &err) == HS_ERR_INVALID);
    ENSURE(m == NULL);
    def = hs_mooney_default_def();
    def.beta = -1;
    ENSURE(hs_mooney_create(mesh, &def, fixed, &m, &err) == HS_ERR_INVALID);
    def = hs_mooney_default_def();
    ENSURE(hs_mooney_create(NULL, &def, fixed, &m, &err) == HS_ERR_INVALID);
    // Rigid motion left free: nothing fixed, or only nodes on one line.
    ENSURE(hs_mooney_create(mesh, &def, NULL, &m, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "no fixed node") != NULL);
    unsigned char* line = calloc((size_t)n, 1);
    for (int i = 0; i < n; i++)
        line[i] = mesh->x0[3 * i + 1] < 1e-9 && mesh->x0[3 * i + 2] < 1e-9; // the x axis
    ENSURE(hs_mooney_create(mesh, &def, line, &m, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "collinear") != NULL);
    ENSURE(m == NULL);
    // Allocation failures at every point of create (CHOLMOD's included) clean up.
    def.beta = 0.5;
    int succeeded = 0;
    for (int k = 1; k < 5000 && !succeeded; k++) {
        hs_alloc_fail_after(k);
        hs_status s = hs_mooney_create(mesh, &def, fixed, &m, &err);
        hs_alloc_fail_after(0);
        if (s == HS_OK) {
            succeeded = 1;
            hs_mooney_destroy(&m);
            break;
        }
        ENSURE(s == HS_ERR_NOMEM);
        ENSURE(m == NULL);
    }
    ENSURE(succeeded);
    // Inverting or non-finite input is rejected with a clear error.
    ENSURE(hs_mooney_create(mesh, &def, fixed, &m, &err) == HS_OK);
    double* u = calloc(3 * (size_t)n, sizeof(double));
    for (int i = 0; i < n; i++) u[3 * i] = -2.0 * mesh->x0[3 * i];
    ENSURE(hs_mooney_set_displacement(m, u, &err) == HS_ERR_NUMERIC);
    ENSURE(strstr(err.msg, "inverts") != NULL);
    u[0] = NAN;
    ENSURE(hs_mooney_set_displacement(m, u, &err) == HS_ERR_INVALID);
    ENSURE(hs_mooney_set_forces(m, u) == HS_ERR_INVALID);
    ENSURE(hs_mooney_set_prescribed(m, u) == HS_ERR_INVALID);
    double g[3] = {0, INFINITY, 0};
    ENSURE(hs_mooney_set_gravity(m, g) == HS_ERR_INVALID);
    // Finite but absurd: the residual norm overflowed and the solve read it as converged.
    g[1] = -1e200;
    ENSURE(hs_mooney_set_gravity(m, g) == HS_ERR_INVALID);
    u[0] = 1e200;
    ENSURE(hs_mooney_set_forces(m, u) == HS_ERR_INVALID);
    // A refused (inverting) state loses nothing: the solve still works from the old one (it
    // kept the inverted u, and every later solve failed).
    for (int i = 0; i < n; i++) u[3 * i] = -2.0 * mesh->x0[3 * i];
    ENSURE(hs_mooney_set_displacement(m, u, &err) == HS_ERR_NUMERIC);
    for (int d = 0; d < 3 * n; d++) ENSURE(hs_mooney_displacement(m)[d] == 0);
    g[1] = -9.81;
    ENSURE(hs_mooney_set_gravity(m, g) == HS_OK);
    hs_mooney_stats st;
    ENSURE(hs_mooney_solve_static(m, &st, &err) == HS_OK);
    free(u);
    free(line);
    free(fixed);
    hs_mooney_destroy(&m);
    hs_mooney_destroy(&m); // NULL is fine
    hs_mesh_destroy(&mesh);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// Solving again after a load change continues from the solved state and reaches the same
// state as one solve of the final load.
static int mooney_continuation(void) {
    hs_err err;
    hs_mesh* mesh = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 8, 2, 2, &mesh, &err) == HS_OK);
    int n = mesh->n_nodes;
    unsigned char* fixed = calloc((size_t)n, 1);
    for (int i = 0; i < n; i++) fixed[i] = mesh->x0[3 * i] < 1e-9;
    hs_mooney_def def = hs_mooney_default_def();
    def.youngs_pa = 20000;
    def.beta = 1.0;
    def.load_steps = 2;
    hs_mooney *a = NULL, *b = NULL;
    ENSURE(hs_mooney_create(mesh, &def, fixed, &a, &err) == HS_OK);
    ENSURE(hs_mooney_create(mesh, &def, fixed, &b, &err) == HS_OK);
    double g1[3] = {0, 0, -4.9}, g2[3] = {0, 0, -9.81};
    hs_mooney_stats st;
    ENSURE(hs_mooney_set_gravity(a, g1) == HS_OK);
    ENSURE(hs_mooney_solve_static(a, &st, &err) == HS_OK);
    ENSURE(hs_mooney_set_gravity(a, g2) == HS_OK);
    // The solve keeps no memory (CHOLMOD's refactorisation allocates transiently inside).
    int64_t bytes0 = hs_byte_count();
    ENSURE(hs_mooney_solve_static(a, &st, &err) == HS_OK);
    ENSURE(hs_byte_count() == bytes0);
    ENSURE(hs_mooney_set_gravity(b, g2) == HS_OK);
    ENSURE(hs_mooney_solve_static(b, &st, &err) == HS_OK);
    const double *ua = hs_mooney_displacement(a), *ub = hs_mooney_displacement(b);
    double dmax = 0, umax = 0;
    for (int d = 0; d < 3 * n; d++) {
        dmax = fmax(dmax, fabs(ua[d] - ub[d]));
        umax = fmax(umax, fabs(ub[d]));
    }
    printf("  tip %.4f m, two-stage vs one-stage max difference %.1e m\n", umax, dmax);
    ENSURE(umax > 0.005);
    ENSURE(dmax < 1e-9 * umax);
    hs_mooney_destroy(&a);
    hs_mooney_destroy(&b);
    hs_mesh_destroy(&mesh);
    free(fixed);
    return 0;
}

HS_TEST_MAIN(HS_CASE(mooney_kernel), HS_CASE(mooney_homogeneous), HS_CASE(mooney_small_strain),
             HS_CASE(mooney_stabilisation), HS_CASE(mooney_newton_quadratic),
             HS_CASE(mooney_bad_input), HS_CASE(mooney_continuation))
