// SPDX-License-Identifier: GPL-2.0-or-later
// Body: static and dynamic solves against beam theory, the paper's self-weight cantilever,
// energy behaviour of implicit Euler, inversion recovery, boundary conditions, solvers.
#include "body.h"
#include "mesh.h"
#include "test_macros.h"

#include <stdlib.h>
#include <string.h>

// Clamp x = 0 of a box mesh; returns the mask (caller frees).
static unsigned char* clamp_x0(const hs_mesh* m) {
    unsigned char* f = calloc((size_t)m->n_nodes, 1);
    hs_mesh_select_plane(m, 0, -1, 1e-9, f);
    return f;
}

// The shared aneurysm vessel as the tests run it: soft co-rotated tissue sagging under gravity.
static hs_body_def vessel_def(hs_solver_kind solver) {
    hs_body_def d = hs_body_default_def();
    d.fem.model = HS_MODEL_COROTATED;
    d.fem.material.youngs_pa = 5e4;
    d.fem.material.poisson = 0.45;
    d.fem.material.density_kg_m3 = 1060;
    d.gravity[2] = -9.81;
    d.solver = solver;
    return d;
}

// A co-rotated beam's definition: Young's modulus E, gravity along -z, the given solver.
static hs_body_def beam_def(double youngs_pa, hs_solver_kind solver) {
    hs_body_def d = hs_body_default_def();
    d.fem.model = HS_MODEL_COROTATED;
    d.fem.material.youngs_pa = youngs_pa;
    d.gravity[2] = -9.81;
    d.solver = solver;
    return d;
}

// |a - b| / |b| (infinite when b is zero).
static double rel_diff(const double* a, const double* b, int n) {
    double num = 0, den = 0;
    for (int k = 0; k < n; ++k) num += (a[k] - b[k]) * (a[k] - b[k]), den += b[k] * b[k];
    return den > 0 ? sqrt(num / den) : INFINITY;
}

// Mean displacement component c over the nodes at x = max.
static double end_mean(const hs_mesh* m, const double* u, int c) {
    double s = 0;
    int k = 0;
    for (int i = 0; i < m->n_nodes; ++i)
        if (m->x0[3 * i] > m->bbox_max[0] - 1e-9) s += u[3 * i + c], ++k;
    return k ? s / k : 0;
}

// Tip load P (N, -z) spread over the end face by tributary area of its boundary triangles.
static void load_end_face(hs_body* b, const hs_mesh* m, double p) {
    double* w = calloc((size_t)m->n_nodes, sizeof(double));
    double total = 0;
    for (int t = 0; t < m->n_tris; ++t) {
        const int* v = m->tris + 3 * t;
        int on = 1;
        for (int k = 0; k < 3; ++k) on &= m->x0[3 * v[k]] > m->bbox_max[0] - 1e-9;
        if (!on) continue;
        const double *a = m->x0 + 3 * v[0], *bb = m->x0 + 3 * v[1], *c = m->x0 + 3 * v[2];
        double e1[3], e2[3];
        for (int k = 0; k < 3; ++k) e1[k] = bb[k] - a[k], e2[k] = c[k] - a[k];
        double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2],
               cz = e1[0] * e2[1] - e1[1] * e2[0];
        double area = 0.5 * sqrt(cx * cx + cy * cy + cz * cz);
        for (int k = 0; k < 3; ++k) w[v[k]] += area / 3;
        total += area;
    }
    for (int i = 0; i < m->n_nodes; ++i)
        if (w[i] > 0) hs_body_set_force(b, i, (double[3]){0, 0, -p * w[i] / total});
    free(w);
}

// Tip deflection of a clamped cantilever (L x h x h, n x m x m cells) under tip load P.
static double cantilever_tip(int n, int m, double nu, int locking_free, double P) {
    hs_mesh* mesh = NULL;
    if (hs_mesh_create_box(0.1, 0.01, 0.01, n, m, m, &mesh, NULL) != HS_OK) return NAN;
    unsigned char* fx = clamp_x0(mesh);
    hs_body_def d = hs_body_default_def();
    d.fem.model = HS_MODEL_LINEAR;
    d.fem.locking_free = locking_free;
    d.fem.material.youngs_pa = 1e5;
    d.fem.material.poisson = nu;
    hs_body* b = NULL;
    double tip = NAN;
    if (hs_body_create(mesh, &d, fx, &b, NULL) == HS_OK) {
        load_end_face(b, mesh, P);
        if (hs_body_solve_static(b, NULL) == HS_OK)
            tip = -end_mean(mesh, hs_body_displacement(b), 2);
    }
    hs_body_destroy(&b);
    hs_mesh_destroy(&mesh);
    free(fx);
    return tip;
}

// Small tip load on a near-incompressible (nu 0.49) cantilever, L/h = 10: the locking-free
// option lands within 5 % of Timoshenko beam theory; the standard element locks badly.
// Linear tets converge at first order in bending (measured ratio 0.83, 0.936, 0.959 at
// 40x4x4, 80x8x8, 120x12x12 cells), so the check uses the fine mesh.
static int CantileverTimoshenko(void) {
    const double L = 0.1, h = 0.01, E = 1e5, nu = 0.49, P = 1e-3;
    const double I = h * h * h * h / 12, A = h * h, G = E / (2 * (1 + nu));
    const double kappa = 10 * (1 + nu) / (12 + 11 * nu);
    const double exact = P * L * L * L / (3 * E * I) + P * L / (kappa * G * A);
    double coarse_std = cantilever_tip(40, 4, nu, 0, P);
    double coarse_lf = cantilever_tip(40, 4, nu, 1, P);
    double fine_lf = cantilever_tip(120, 12, nu, 1, P);
    printf("  Timoshenko %.4e m; 40x4x4 standard %.3f, locking-free %.3f; 120x12x12 "
           "locking-free %.3f (ratios to theory)\n",
           exact, coarse_std / exact, coarse_lf / exact, fine_lf / exact);
    ENSURE(fabs(fine_lf / exact - 1) <= 0.05);
    ENSURE(coarse_std / exact < 0.5);     // volumetric locking without the option
    ENSURE(coarse_lf > 2.5 * coarse_std); // the option removes most of it on the same mesh
    return 0;
}

// The paper's cantilever under self-weight (0.10 x 0.02 x 0.02 m, E 1.5 MPa, nu 0.49,
// 960 kg/m^3, then 10x heavier): linear FEM swells, co-rotated keeps its volume.
static int SelfWeightVolume(void) {
    for (int heavy = 0; heavy < 2; ++heavy) {
        double ratio[2];
        for (int model = 0; model < 2; ++model) {
            hs_mesh* m = NULL;
            ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 20, 4, 4, &m, NULL) == HS_OK);
            unsigned char* fx = clamp_x0(m);
            hs_body_def d = hs_body_default_def();
            d.fem.model = model ? HS_MODEL_COROTATED : HS_MODEL_LINEAR;
            d.fem.material.youngs_pa = 1.5e6;
            d.fem.material.poisson = 0.49;
            d.fem.material.density_kg_m3 = heavy ? 9600 : 960;
            d.gravity[2] = -9.81;
            d.static_max_iter = 200;
            hs_body* b = NULL;
            ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
            hs_step_stats st;
            hs_status s = hs_body_solve_static(b, &st);
            ENSURE(s == HS_OK);
            ratio[model] = st.fem.volume_ratio_mean;
            printf("  density %g %s: tip %.4e m, mean volume ratio %.5f (%d iterations)\n",
                   d.fem.material.density_kg_m3, model ? "corotated" : "linear",
                   -end_mean(m, hs_body_displacement(b), 2), ratio[model], st.iterations);
            hs_body_destroy(&b);
            hs_mesh_destroy(&m);
            free(fx);
        }
        ENSURE(fabs(ratio[1] - 1) <= 0.01);
        ENSURE(ratio[0] - 1 > 4 * fabs(ratio[1] - 1));
    }
    return 0;
}

// The SVD rotation method's static solve settles as the polar method's does, on the same state
// to the rotation tolerance: recomputed exactly at every update, its rotations followed each
// Newton correction, which the rotation-frozen tangent leaves out, and the iteration converged
// only linearly (the paper's cantilever 10x heavy, 20 x 4 x 4 cells: 15 iterations against 7;
// 47-52 against 3-7 at 25 x 5 x 5).
static int SvdStaticConverges(void) {
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 20, 4, 4, &m, NULL) == HS_OK);
    unsigned char* fx = clamp_x0(m);
    double* u[2];
    int iters[2];
    for (int svd = 0; svd < 2; ++svd) {
        hs_body_def d = hs_body_default_def();
        d.fem.model = HS_MODEL_COROTATED;
        d.fem.rotation = svd ? HS_ROTATION_SVD : HS_ROTATION_POLAR;
        d.fem.material.youngs_pa = 1.5e6;
        d.fem.material.poisson = 0.49;
        d.fem.material.density_kg_m3 = 9600;
        d.gravity[2] = -9.81;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        hs_step_stats st;
        ENSURE(hs_body_solve_static(b, &st) == HS_OK);
        iters[svd] = st.iterations;
        u[svd] = malloc(sizeof(double) * 3 * (size_t)m->n_nodes);
        memcpy(u[svd], hs_body_displacement(b), sizeof(double) * 3 * (size_t)m->n_nodes);
        hs_body_destroy(&b);
    }
    double diff = rel_diff(u[1], u[0], 3 * m->n_nodes);
    printf("  static Newton iterations: polar %d, svd %d; displacements differ by %.2e "
           "(relative, polar_tol %.0e)\n",
           iters[0], iters[1], diff, hs_fem_default_def().polar_tol);
    ENSURE(iters[1] <= iters[0] + 2);
    ENSURE(diff <= 1e-5);
    free(u[0]);
    free(u[1]);
    free(fx);
    hs_mesh_destroy(&m);
    return 0;
}

// Undamped implicit Euler never gains energy: E = KE + W - f.u is non-increasing.
static int EnergyNeverGrows(void) {
    for (int model = 0; model < 2; ++model) {
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &m, NULL) == HS_OK);
        unsigned char* fx = clamp_x0(m);
        hs_body_def d = hs_body_default_def();
        d.fem.model = model ? HS_MODEL_COROTATED : HS_MODEL_LINEAR;
        d.fem.material.youngs_pa = 1e5;
        d.fem.material.poisson = 0.3;
        d.fem.material.density_kg_m3 = 1000;
        d.gravity[2] = -9.81;
        d.dt = 1e-3;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        double prev = 0, peak = 0;
        for (int k = 0; k < 300; ++k) {
            ENSURE(hs_body_step(b, NULL) == HS_OK);
            const double* u = hs_body_displacement(b);
            // Gravity potential from the lumped masses: -sum m_i g . u_i.
            const double* mass = hs_fem_lumped_mass(hs_body_fem(b));
            double grav = 0;
            for (int i = 0; i < m->n_nodes; ++i) grav += mass[i] * 9.81 * u[3 * i + 2];
            double e = hs_body_kinetic_energy(b) + hs_body_elastic_energy(b) + grav;
            double scale = fabs(e) + hs_body_kinetic_energy(b) + 1e-12;
            if (fabs(e) > peak) peak = fabs(e);
            if (model == 0)
                ENSURE(e <= prev + 1e-9 * scale);
            else
                ENSURE(e <= 1e-6 * peak); // co-rotated: never above the start (E = 0)
            prev = e;
        }
        ENSURE(peak > 0); // it moved
        hs_body_destroy(&b);
        hs_mesh_destroy(&m);
        free(fx);
    }
    return 0;
}

// A uniaxial bar with nu = 0 stretched by a prescribed end displacement: reaction = E A d / L
// exactly (linear tets reproduce linear fields), for both solvers.
static int PrescribedBarReaction(void) {
    for (int solver = 0; solver < 2; ++solver) {
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.1, 0.01, 0.01, 10, 2, 2, &m, NULL) == HS_OK);
        unsigned char* fx = calloc((size_t)m->n_nodes, 1);
        unsigned char* end = calloc((size_t)m->n_nodes, 1);
        hs_mesh_select_plane(m, 0, -1, 1e-9, fx);
        hs_mesh_select_plane(m, 0, +1, 1e-9, end);
        for (int i = 0; i < m->n_nodes; ++i) fx[i] |= end[i];
        hs_body_def d = hs_body_default_def();
        d.fem.material.youngs_pa = 2e5;
        d.fem.material.poisson = 0.0;
        d.solver = solver ? HS_SOLVER_PCG : HS_SOLVER_DIRECT;
        d.precond = HS_PRECOND_JACOBI;
        d.pcg_max_iter = 2000;
        d.pcg_tol = 1e-12;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        const double dl = 1e-4;
        for (int i = 0; i < m->n_nodes; ++i)
            if (end[i]) ENSURE(hs_body_set_prescribed(b, i, (double[3]){dl, 0, 0}) == HS_OK);
        ENSURE(hs_body_set_prescribed(b, m->n_nodes / 2 + 1, (double[3]){0, 0, 0}) ==
               (fx[m->n_nodes / 2 + 1] ? HS_OK : HS_ERR_INVALID));
        hs_step_stats st;
        ENSURE(hs_body_solve_static(b, &st) == HS_OK);
        double fsum = 0;
        for (int i = 0; i < m->n_nodes; ++i)
            if (end[i]) {
                double f[3];
                hs_body_reaction(b, i, f);
                fsum += f[0];
            }
        double expect = 2e5 * 0.01 * 0.01 * dl / 0.1;
        ENSURE_SMALL(fsum / expect - 1, 1e-6);
        // The interior follows the linear field exactly.
        const double* u = hs_body_displacement(b);
        for (int i = 0; i < m->n_nodes; ++i) ENSURE_SMALL(u[3 * i] - dl * m->x0[3 * i] / 0.1, 1e-9);
        hs_body_destroy(&b);
        hs_mesh_destroy(&m);
        free(fx);
        free(end);
    }
    return 0;
}

// Direct and PCG (rest-factor preconditioner, converged) give the same co-rotated step.
static int SolversAgree(void) {
    double* us[2] = {0, 0};
    int n = 0;
    for (int solver = 0; solver < 2; ++solver) {
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &m, NULL) == HS_OK);
        unsigned char* fx = clamp_x0(m);
        hs_body_def d = beam_def(1e4, solver ? HS_SOLVER_PCG : HS_SOLVER_DIRECT);
        d.pcg_max_iter = 200;
        d.pcg_tol = 1e-12;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        for (int k = 0; k < 20; ++k) ENSURE(hs_body_step(b, NULL) == HS_OK);
        n = 3 * m->n_nodes;
        us[solver] = malloc((size_t)n * sizeof(double));
        memcpy(us[solver], hs_body_displacement(b), (size_t)n * sizeof(double));
        hs_body_destroy(&b);
        hs_mesh_destroy(&m);
        free(fx);
    }
    double num = 0, den = 0;
    for (int k = 0; k < n; ++k)
        num += (us[0][k] - us[1][k]) * (us[0][k] - us[1][k]), den += us[0][k] * us[0][k];
    ENSURE(den > 0);
    ENSURE_SMALL(sqrt(num / den), 1e-7);
    free(us[0]);
    free(us[1]);
    return 0;
}

// The linear model keeps its assembled matrix and factor between steps; an element change
// (as a cut makes) must reach both. Body A steps, loses some elements, is reset and steps again;
// body B has lost them from the start. Same solver, same answer: direct and PCG.
static int LinearSeesElementChanges(void) {
    for (int solver = 0; solver < 2; ++solver) {
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &m, NULL) == HS_OK);
        unsigned char* fx = clamp_x0(m);
        hs_body_def d = hs_body_default_def();
        d.fem.model = HS_MODEL_LINEAR;
        d.fem.material.youngs_pa = 1e4;
        d.gravity[2] = -9.81;
        d.solver = solver ? HS_SOLVER_PCG : HS_SOLVER_DIRECT;
        d.precond = HS_PRECOND_FACTOR;
        d.pcg_max_iter = 200;
        d.pcg_tol = 1e-12;
        hs_body *a = NULL, *b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &a, NULL) == HS_OK);
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        for (int k = 0; k < 5; ++k) ENSURE(hs_body_step(a, NULL) == HS_OK);
        // Weaken the half of the beam nearest the clamp: a softer beam sags further.
        uint64_t v0 = hs_fem_stiffness_version(hs_body_fem(a));
        for (int e = 0; e < m->n_tets / 2; ++e) {
            ENSURE(hs_fem_set_element_stiffness_scale(hs_body_fem(a), e, 0.25) == HS_OK);
            ENSURE(hs_fem_set_element_stiffness_scale(hs_body_fem(b), e, 0.25) == HS_OK);
        }
        ENSURE(hs_fem_stiffness_version(hs_body_fem(a)) > v0);
        hs_body_reset(a);
        for (int k = 0; k < 20; ++k) {
            ENSURE(hs_body_step(a, NULL) == HS_OK);
            ENSURE(hs_body_step(b, NULL) == HS_OK);
        }
        ENSURE_SMALL(rel_diff(hs_body_displacement(a), hs_body_displacement(b), 3 * m->n_nodes),
                     1e-9);
        hs_body_destroy(&a);
        hs_body_destroy(&b);
        hs_mesh_destroy(&m);
        free(fx);
    }
    return 0;
}

// A node whose last element goes (a cut pins it) is held where it is: the dynamic system stays
// definite without a pin spring, the node neither falls nor keeps its velocity, and the rest
// of the body moves exactly as a body with that node fixed from the start. Both solvers that
// keep a factor (direct; warped, whose rest-state factor then refactors).
static int OrphanHeldInPlace(void) {
    for (int solver = 0; solver < 2; ++solver) {
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &m, NULL) == HS_OK);
        unsigned char* fx = clamp_x0(m);
        // The free-end corner node at (max, max, max) and the tets using it.
        int node = -1;
        for (int i = 0; i < m->n_nodes; ++i) {
            const double* x = m->x0 + 3 * i;
            if (x[0] > m->bbox_max[0] - 1e-9 && x[1] > m->bbox_max[1] - 1e-9 &&
                x[2] > m->bbox_max[2] - 1e-9)
                node = i;
        }
        ENSURE(node >= 0);
        int off[32], n_off = 0;
        for (int e = 0; e < m->n_tets; ++e)
            for (int a = 0; a < 4; ++a)
                if (m->tets[4 * e + a] == node && n_off < 32) off[n_off++] = e, a = 4;
        ENSURE(n_off > 0 && n_off < 32);
        hs_body_def d = beam_def(1e4, solver ? HS_SOLVER_WARPED : HS_SOLVER_DIRECT);
        unsigned char* fref = malloc((size_t)m->n_nodes);
        memcpy(fref, fx, (size_t)m->n_nodes);
        fref[node] = 1;
        hs_body *a = NULL, *b = NULL, *c = NULL;
        ENSURE(hs_body_create(m, &d, fx, &a, NULL) == HS_OK);
        ENSURE(hs_body_create(m, &d, fref, &b, NULL) == HS_OK);
        ENSURE(hs_body_create(m, &d, fx, &c, NULL) == HS_OK);
        // a: the node's elements go at rest; b: the node fixed from the start, same elements.
        for (int k = 0; k < 3; ++k) ENSURE(hs_body_step(a, NULL) == HS_OK); // a factor to follow
        hs_body_reset(a);
        ENSURE(hs_body_change_elements(a, n_off, off, 0, NULL, NULL) == HS_OK);
        ENSURE(hs_body_change_elements(b, n_off, off, 0, NULL, NULL) == HS_OK);
        ENSURE(hs_fem_held_nodes(hs_body_fem(a)) == 1);
        for (int k = 0; k < 20; ++k) {
            ENSURE(hs_body_step(a, NULL) == HS_OK);
            ENSURE(hs_body_step(b, NULL) == HS_OK);
        }
        ENSURE_SMALL(rel_diff(hs_body_displacement(a), hs_body_displacement(b), 3 * m->n_nodes),
                     1e-9);
        const double* ua = hs_body_displacement(a);
        ENSURE(ua[3 * node] == 0 && ua[3 * node + 1] == 0 && ua[3 * node + 2] == 0);
        // Static: the held node's row of K was empty, so its factorisation failed and Newton
        // crept on with the last step's factor (100 iterations, not converged; found in
        // review 2026-11-28). Now it solves as the body with the node fixed.
        hs_step_stats sa, sb;
        ENSURE(hs_body_solve_static(a, &sa) == HS_OK && hs_body_solve_static(b, &sb) == HS_OK);
        printf("  static with a held node: %d iterations (node fixed instead: %d)\n", sa.iterations,
               sb.iterations);
        ENSURE(sa.iterations <= sb.iterations + 1);
        ENSURE_SMALL(rel_diff(hs_body_displacement(a), hs_body_displacement(b), 3 * m->n_nodes),
                     1e-9);
        ENSURE(ua[3 * node] == 0 && ua[3 * node + 1] == 0 && ua[3 * node + 2] == 0);
        // c: the elements go while the beam swings; the node stays where it was then.
        for (int k = 0; k < 5; ++k) ENSURE(hs_body_step(c, NULL) == HS_OK);
        double held[3];
        memcpy(held, hs_body_displacement(c) + 3 * node, sizeof held);
        ENSURE(fabs(held[2]) > 0);
        ENSURE(hs_body_change_elements(c, n_off, off, 0, NULL, NULL) == HS_OK);
        // A force on the held node moves nothing (it flung the node 0.19 m per step).
        ENSURE(hs_body_set_force(c, node, (double[3]){0, 0, -0.01}) == HS_OK);
        for (int k = 0; k < 20; ++k) ENSURE(hs_body_step(c, NULL) == HS_OK);
        const double* uc = hs_body_displacement(c);
        for (int q = 0; q < 3; ++q) ENSURE(uc[3 * node + q] == held[q]);
        for (int k = 0; k < 3 * m->n_nodes; ++k) ENSURE(isfinite(uc[k]));
        hs_body_destroy(&a);
        hs_body_destroy(&b);
        hs_body_destroy(&c);
        hs_mesh_destroy(&m);
        free(fx);
        free(fref);
    }
    return 0;
}

// Definitions and setter values that would make every later step fail (or return infinite
// energies as success) are refused up front, and nothing changes.
static int BadInputRefused(void) {
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &m, NULL) == HS_OK);
    unsigned char* fx = clamp_x0(m);
    hs_body* b = NULL;
    for (int bad = 0; bad < 11; ++bad) {
        hs_body_def d = hs_body_default_def();
        if (bad == 0) d.gravity[2] = NAN;
        if (bad == 1) d.gravity[0] = -1e300;
        if (bad == 2) d.gravity[1] = 2e3;
        if (bad == 3) d.dt = 1e300;
        if (bad == 4) d.pcg_tol = NAN;
        if (bad == 5) d.pcg_tol = -1;
        if (bad == 6) d.static_tol = INFINITY;
        if (bad == 7) d.fem.material.rayleigh_mass = INFINITY;
        if (bad == 8) d.fem.material.rayleigh_stiffness = INFINITY;
        if (bad == 9) d.fem.material.youngs_pa = 1e300, d.fem.material.poisson = 0.49;
        if (bad == 10) d.fem.material.youngs_pa = 1e300, d.fem.material.poisson = -0.9999;
        hs_err e = {0};
        hs_status st = hs_body_create(m, &d, fx, &b, &e);
        if (st != HS_ERR_INVALID || b) printf("  case %d: status %d, %s\n", bad, (int)st, e.msg);
        ENSURE(st == HS_ERR_INVALID && !b);
        if (bad == 0 || bad == 9) printf("  %s\n", e.msg);
    }
    hs_body_def d = beam_def(1e6, HS_SOLVER_DIRECT);
    ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
    const size_t n3 = 3 * (size_t)m->n_nodes;
    ENSURE(hs_body_set_load_scale(b, NAN) == HS_ERR_INVALID);
    int clamp = 0;
    while (!fx[clamp]) clamp++;
    ENSURE(hs_body_set_prescribed(b, clamp, (double[3]){0, 0, 1e200}) == HS_ERR_INVALID);
    ENSURE(hs_body_step(b, NULL) == HS_OK);
    double* u0 = malloc(n3 * sizeof(double));
    double* w = malloc(n3 * sizeof(double));
    memcpy(u0, hs_body_displacement(b), n3 * sizeof(double));
    for (size_t k = 0; k < n3; ++k) w[k] = NAN;
    ENSURE(hs_body_set_state(b, w, NULL) == HS_ERR_INVALID);
    for (size_t k = 0; k < n3; ++k) w[k] = u0[k];
    ENSURE(hs_body_set_state(b, w, w) == HS_OK); // v may be anything finite
    w[n3 - 1] = INFINITY;
    ENSURE(hs_body_set_state(b, u0, w) == HS_ERR_INVALID);
    ENSURE(memcmp(u0, hs_body_displacement(b), n3 * sizeof(double)) == 0);
    hs_step_stats st;
    hs_status ss = hs_body_solve_static(b, &st); // the load scale is still 1: it sags
    printf("  static solve after the refusals: status %d, %d iterations\n", (int)ss, st.iterations);
    ENSURE(ss == HS_OK);
    ENSURE(st.iterations > 0 && isfinite(hs_body_elastic_energy(b)));
    free(u0);
    free(w);
    hs_body_destroy(&b);
    free(fx);
    hs_mesh_destroy(&m);
    return 0;
}

// An element pushed through itself recovers (both remedies), in a damped dynamic run.
static int InvertedRecovers(void) {
    for (int mode = 0; mode < 2; ++mode) {
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.02, 0.02, 0.02, 2, 2, 2, &m, NULL) == HS_OK);
        unsigned char* fx = calloc((size_t)m->n_nodes, 1);
        hs_mesh_select_plane(m, 2, -1, 1e-9, fx);
        hs_body_def d = hs_body_default_def();
        d.fem.model = HS_MODEL_COROTATED;
        d.fem.inversion = mode ? HS_INVERSION_KEEP_REFLECTION : HS_INVERSION_LINEAR_FALLBACK;
        d.fem.material.youngs_pa = 1e4;
        d.fem.material.rayleigh_mass = 5;
        d.dt = 1e-3;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        // Push the top centre node 1.5 cells down, through the layer below it.
        double* u = calloc(3 * (size_t)m->n_nodes, sizeof(double));
        int top = -1;
        for (int i = 0; i < m->n_nodes; ++i)
            if (fabs(m->x0[3 * i] - 0.01) < 1e-9 && fabs(m->x0[3 * i + 1] - 0.01) < 1e-9 &&
                fabs(m->x0[3 * i + 2] - 0.02) < 1e-9)
                top = i;
        ENSURE(top >= 0);
        u[3 * top + 2] = -0.015;
        hs_body_set_state(b, u, NULL);
        double* x = calloc(3 * (size_t)m->n_nodes, sizeof(double));
        for (int k = 0; k < 3 * m->n_nodes; ++k) x[k] = m->x0[k] + u[k];
        hs_fem_stats fs;
        hs_fem_update(hs_body_fem(b), x, &fs);
        int inverted_at_start = fs.inverted;
        free(x);
        hs_step_stats st;
        ENSURE(hs_body_step(b, &st) == HS_OK);
        for (int k = 0; k < 2000 && st.fem.inverted > 0; ++k) ENSURE(hs_body_step(b, &st) == HS_OK);
        for (int k = 0; k < 200; ++k) ENSURE(hs_body_step(b, &st) == HS_OK);
        printf("  mode %d: inverted %d -> %d, min volume ratio %.3f\n", mode, inverted_at_start,
               st.fem.inverted, st.fem.volume_ratio_min);
        ENSURE(inverted_at_start > 0);
        ENSURE(st.fem.inverted == 0);
        ENSURE(st.fem.volume_ratio_min > 0.5);
        free(u);
        free(fx);
        hs_body_destroy(&b);
        hs_mesh_destroy(&m);
    }
    return 0;
}

// Steps allocate nothing after set-up; everything is released; bad definitions are refused.
static int NoAllocAndErrors(void) {
    int64_t bytes0 = hs_byte_count();
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 8, 2, 2, &m, NULL) == HS_OK);
    unsigned char* fx = clamp_x0(m);
    hs_body_def d = hs_body_default_def();
    d.fem.model = HS_MODEL_COROTATED;
    d.gravity[2] = -9.81;
    hs_body* b = NULL;
    ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
    ENSURE(hs_body_step(b, NULL) == HS_OK); // first step may set up solver workspaces
    int64_t calls = hs_alloc_calls();
    for (int k = 0; k < 10; ++k) ENSURE(hs_body_step(b, NULL) == HS_OK);
    ENSURE(hs_alloc_calls() == calls);
    hs_body_destroy(&b);
    ENSURE(b == NULL);
    hs_body_destroy(&b);

    hs_err e = {0};
    hs_body_def bad;
    memset(&bad, 0, sizeof bad);
    ENSURE(hs_body_create(m, &bad, fx, &b, &e) == HS_ERR_INVALID && b == NULL);
    ENSURE(strstr(e.msg, "hs_body_default_def") != NULL);
    unsigned char* all = malloc((size_t)m->n_nodes);
    memset(all, 1, (size_t)m->n_nodes);
    ENSURE(hs_body_create(m, &d, all, &b, &e) == HS_ERR_INVALID && b == NULL);
    d.dt = -1;
    ENSURE(hs_body_create(m, &d, fx, &b, &e) == HS_ERR_INVALID && b == NULL);
    d.dt = 0.01;
    hs_parallel no_runner = {.width = 2};
    d.factor_parallel = &no_runner;
    ENSURE(hs_body_create(m, &d, fx, &b, &e) == HS_ERR_INVALID && b == NULL);
    ENSURE(strstr(e.msg, "without a runner") != NULL);
    free(all);
    free(fx);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// Co-rotated dynamics with large rotations (the 10x heavy cantilever): PCG with three
// iterations per step, preconditioned by the rest factor warped with the node rotations,
// follows the direct solve closely; the unwarped rest factor drifts far away.
static int WarpedPcgTracksDirect(void) {
    double tip[3];
    const hs_precond pc[3] = {HS_PRECOND_NONE, HS_PRECOND_WARPED, HS_PRECOND_FACTOR};
    for (int c = 0; c < 3; ++c) {
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 20, 4, 4, &m, NULL) == HS_OK);
        unsigned char* fx = clamp_x0(m);
        hs_body_def d = hs_body_default_def();
        d.fem.model = HS_MODEL_COROTATED;
        d.fem.material.youngs_pa = 1.5e6;
        d.fem.material.poisson = 0.45;
        d.fem.material.density_kg_m3 = 9600;
        d.gravity[2] = -9.81;
        d.dt = 0.01;
        d.solver = c == 0 ? HS_SOLVER_DIRECT : HS_SOLVER_PCG;
        d.precond = pc[c];
        d.pcg_max_iter = 3;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        for (int k = 0; k < 60; ++k) ENSURE(hs_body_step(b, NULL) == HS_OK);
        tip[c] = end_mean(m, hs_body_displacement(b), 2);
        hs_body_destroy(&b);
        hs_mesh_destroy(&m);
        free(fx);
    }
    printf("  tip after 60 steps: direct %.5e, pcg3 warped %.5e, pcg3 rest factor %.5e m\n", tip[0],
           tip[1], tip[2]);
    ENSURE(fabs(tip[0]) > 0.01); // large deflection: rotations matter
    ENSURE(fabs(tip[1] / tip[0] - 1) < 1e-3);
    ENSURE(fabs(tip[2] / tip[0] - 1) > 10 * fabs(tip[1] / tip[0] - 1));
    return 0;
}

// HS_SOLVER_WARPED approximates only the tangent, never the forces: damped dynamics settles in
// the static equilibrium of the direct solver, the linear model gives the direct answer, and
// the step's safeguard still keeps undamped energy from growing.
static int WarpedSolver(void) {
    double end[3];
    for (int c = 0; c < 3; ++c) { // 0: direct static, 1: direct dynamics, 2: warped dynamics
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 12, 3, 3, &m, NULL) == HS_OK);
        unsigned char* fx = clamp_x0(m);
        hs_body_def d = hs_body_default_def();
        d.fem.model = HS_MODEL_COROTATED;
        d.fem.material.youngs_pa = 2e4;
        d.fem.material.poisson = 0.45;
        d.fem.material.rayleigh_mass = 5;
        d.fem.material.rayleigh_stiffness = 0.01;
        d.gravity[2] = -9.81;
        d.solver = c == 2 ? HS_SOLVER_WARPED : HS_SOLVER_DIRECT;
        d.static_tol = 1e-10;
        d.static_max_iter = 200;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        if (c == 0) {
            ENSURE(hs_body_solve_static(b, NULL) == HS_OK);
        } else {
            hs_step_stats st;
            for (int k = 0; k < 600; ++k) ENSURE(hs_body_step(b, &st) == HS_OK);
            if (c == 2) ENSURE(st.linear_iterations == 1 && isnan(st.residual)); // one solve
        }
        end[c] = end_mean(m, hs_body_displacement(b), 2);
        hs_body_destroy(&b);
        hs_mesh_destroy(&m);
        free(fx);
    }
    printf("  tip: static %.6e m; after 6 s damped: direct %.6e, warped %.6e m\n", end[0], end[1],
           end[2]);
    ENSURE(end[0] < -0.05); // a large bend: rotations matter
    ENSURE(fabs(end[1] / end[0] - 1) < 1e-4);
    ENSURE(fabs(end[2] / end[0] - 1) < 1e-4);
    // Linear: the warped solver is the direct one.
    double lin[2];
    for (int c = 0; c < 2; ++c) {
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 12, 3, 3, &m, NULL) == HS_OK);
        unsigned char* fx = clamp_x0(m);
        hs_body_def d = hs_body_default_def();
        d.fem.model = HS_MODEL_LINEAR;
        d.gravity[2] = -9.81;
        d.solver = c ? HS_SOLVER_WARPED : HS_SOLVER_DIRECT;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        for (int k = 0; k < 20; ++k) ENSURE(hs_body_step(b, NULL) == HS_OK);
        lin[c] = end_mean(m, hs_body_displacement(b), 2);
        hs_body_destroy(&b);
        hs_mesh_destroy(&m);
        free(fx);
    }
    ENSURE(lin[0] < 0);
    ENSURE_SMALL(lin[1] / lin[0] - 1, 1e-12);
    // The thin-walled vessel sagging under gravity: the warped tangent is far off there (it
    // diverged to 1e48 m before the fallback existed). The steps the safeguard cannot fix are
    // redone with the exact tangent; the state stays close to the direct solver's.
    hs_mesh* vm = NULL;
    hs_err verr;
    if (hs_mesh_load(HS_SHARED_MESHES "/aneurysm_vessel.msh", &vm, &verr) < 0) {
        printf("  SKIP vessel part: %s\n", verr.msg);
    } else {
        double tipv[2];
        int fallbacks = 0;
        unsigned char* vf = calloc((size_t)vm->n_nodes, 1);
        hs_mesh_select_plane(vm, 2, -1, 0.1 * (vm->bbox_max[2] - vm->bbox_min[2]), vf);
        for (int c = 0; c < 2; ++c) {
            hs_body_def d = vessel_def(c ? HS_SOLVER_WARPED : HS_SOLVER_DIRECT);
            hs_body* b = NULL;
            ENSURE(hs_body_create(vm, &d, vf, &b, NULL) == HS_OK);
            hs_step_stats st;
            for (int k = 0; k < 40; ++k) {
                ENSURE(hs_body_step(b, &st) == HS_OK);
                fallbacks += st.exact_fallbacks;
            }
            ENSURE(fabs(st.fem.volume_ratio_mean - 1) < 0.02);
            const double* u = hs_body_displacement(b);
            tipv[c] = 0;
            for (int i = 0; i < vm->n_nodes; ++i)
                tipv[c] = fmax(tipv[c], sqrt(u[3 * i] * u[3 * i] + u[3 * i + 1] * u[3 * i + 1] +
                                             u[3 * i + 2] * u[3 * i + 2]));
            hs_body_destroy(&b);
        }
        printf("  vessel, 40 steps: max |u| direct %.4e, warped %.4e m, %d steps redone exactly\n",
               tipv[0], tipv[1], fallbacks);
        ENSURE(tipv[0] > 0.01 && isfinite(tipv[1]));
        ENSURE(fabs(tipv[1] / tipv[0] - 1) < 0.25);
        ENSURE(fallbacks > 0);
        free(vf);
        hs_mesh_destroy(&vm);
    }
    // Undamped release of a large bend at dt 33 ms: no energy gain.
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &m, NULL) == HS_OK);
    unsigned char* fx = clamp_x0(m);
    hs_body_def d = hs_body_default_def();
    d.fem.model = HS_MODEL_COROTATED;
    d.fem.material.youngs_pa = 1e5;
    d.fem.material.poisson = 0.3;
    d.dt = 0.033;
    d.static_load_steps = 8;
    d.static_max_iter = 300;
    d.solver = HS_SOLVER_WARPED;
    hs_body* b = NULL;
    ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
    load_end_face(b, m, 0.4);
    ENSURE(hs_body_solve_static(b, NULL) == HS_OK);
    ENSURE(-end_mean(m, hs_body_displacement(b), 2) > 0.04);
    hs_body_clear_forces(b);
    double e0 = hs_body_elastic_energy(b), emax = e0;
    for (int k = 0; k < 100; ++k) {
        ENSURE(hs_body_step(b, NULL) == HS_OK);
        emax = fmax(emax, hs_body_kinetic_energy(b) + hs_body_elastic_energy(b));
    }
    printf("  undamped release, dt 33 ms: energy max/start %.6f\n", emax / e0);
    ENSURE(emax <= e0 * (1 + 1e-6));
    hs_body_destroy(&b);
    hs_mesh_destroy(&m);
    free(fx);
    // Unknown solver kinds are refused, not run.
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 4, 1, 1, &m, NULL) == HS_OK);
    fx = clamp_x0(m);
    d = hs_body_default_def();
    d.solver = (hs_solver_kind)7;
    hs_err err;
    ENSURE(hs_body_create(m, &d, fx, &b, &err) == HS_ERR_INVALID && b == NULL);
    hs_mesh_destroy(&m);
    free(fx);
    return 0;
}

// A large bend released with undamped co-rotated dynamics at large time steps: the step's
// safeguard on the incremental potential keeps the energy from growing (a single linearised
// step gained up to 65x here at dt 33 ms before it).
static int LargeStepNoEnergyGain(void) {
    const double dts[2] = {0.033, 0.1};
    for (int c = 0; c < 2; ++c) {
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &m, NULL) == HS_OK);
        unsigned char* fx = clamp_x0(m);
        hs_body_def d = hs_body_default_def();
        d.fem.model = HS_MODEL_COROTATED;
        d.fem.material.youngs_pa = 1e5;
        d.fem.material.poisson = 0.3;
        d.dt = dts[c];
        d.static_load_steps = 8;
        d.static_max_iter = 300;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        load_end_face(b, m, 0.4); // bends the tip by about half the length
        ENSURE(hs_body_solve_static(b, NULL) == HS_OK);
        double bend = -end_mean(m, hs_body_displacement(b), 2);
        hs_body_clear_forces(b);
        double e0 = hs_body_elastic_energy(b), emax = e0;
        int cuts = 0;
        for (int k = 0; k < 100; ++k) {
            hs_step_stats st;
            ENSURE(hs_body_step(b, &st) == HS_OK);
            cuts += st.line_search_cuts;
            double e = hs_body_kinetic_energy(b) + hs_body_elastic_energy(b);
            if (e > emax) emax = e;
        }
        printf("  dt %g s: bend %.3f m, energy max/start %.6f, safeguard halvings %d\n", d.dt, bend,
               emax / e0, cuts);
        ENSURE(bend > 0.04);
        ENSURE(emax <= e0 * (1 + 1e-6));
        hs_body_destroy(&b);
        hs_mesh_destroy(&m);
        free(fx);
    }
    return 0;
}

/// A co-rotated body at rest with no load: its state is round-off (~1e-18 m), and the step's
/// line search must not chase it (it used to halve 7-12 times per step, and make the warped
/// solver refactor the exact tangent every step).
static int RestIsQuiet(void) {
    for (int solver = 0; solver < 2; ++solver) {
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.08, 0.08, 0.004, 16, 16, 1, &m, NULL) == HS_OK);
        unsigned char* fx = clamp_x0(m);
        hs_body_def d = hs_body_default_def();
        d.fem.model = HS_MODEL_COROTATED;
        d.fem.material.youngs_pa = 5e4;
        d.fem.material.poisson = 0.45;
        d.fem.material.rayleigh_mass = 0.5;
        d.fem.material.rayleigh_stiffness = 0.01;
        d.dt = 1.0 / 60;
        d.solver = solver ? HS_SOLVER_WARPED : HS_SOLVER_DIRECT;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        int cuts = 0, fallbacks = 0;
        for (int k = 0; k < 10; ++k) {
            hs_step_stats st;
            ENSURE(hs_body_step(b, &st) == HS_OK);
            cuts += st.line_search_cuts;
            fallbacks += st.exact_fallbacks;
        }
        double mx = 0;
        for (int i = 0; i < 3 * m->n_nodes; ++i) mx = fmax(mx, fabs(hs_body_displacement(b)[i]));
        printf("  %s: 10 steps at rest: %d halvings, %d exact fallbacks, max |u| %.1e m\n",
               solver ? "warped" : "direct", cuts, fallbacks, mx);
        ENSURE(cuts == 0 && fallbacks == 0);
        ENSURE(mx < 1e-12);
        hs_body_destroy(&b);
        free(fx);
        hs_mesh_destroy(&m);
    }
    return 0;
}

// A step's polar tolerance (hs_body_def.step_polar_tol): the warped transient of a large bend
// with the static tolerance (1e-6) and the step default (1e-4). The looser one takes fewer
// Newton steps per element and moves the result far less than the step's own error; 0 means
// fem.polar_tol; the static solve keeps fem.polar_tol; a reset body steps as a new one.
static hs_body* bend_body(const hs_mesh* m, const unsigned char* fx, double step_tol,
                          hs_solver_kind solver) {
    hs_body_def d = hs_body_default_def();
    d.fem.model = HS_MODEL_COROTATED;
    d.fem.material.youngs_pa = 2e4;
    d.fem.material.poisson = 0.45;
    d.gravity[2] = -9.81;
    d.dt = 1.0 / 60;
    d.solver = solver;
    d.step_polar_tol = step_tol;
    hs_body* b = NULL;
    return hs_body_create(m, &d, fx, &b, NULL) == HS_OK ? b : NULL;
}

static int StepPolarTol(void) {
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 12, 3, 3, &m, NULL) == HS_OK);
    unsigned char* fx = clamp_x0(m);
    const int n3 = 3 * m->n_nodes;
    // a: fem.polar_tol (0), b: 1e-6 given, c: the default 1e-4; e: the exact tangent (direct
    // solver, 1e-6), against which the warped step's own error shows.
    hs_body* a = bend_body(m, fx, 0, HS_SOLVER_WARPED);
    hs_body* b = bend_body(m, fx, 1e-6, HS_SOLVER_WARPED);
    hs_body* c = bend_body(m, fx, hs_body_default_def().step_polar_tol, HS_SOLVER_WARPED);
    hs_body* e = bend_body(m, fx, 0, HS_SOLVER_DIRECT);
    ENSURE(a && b && c && e);
    ENSURE(hs_body_default_def().step_polar_tol == 1e-4);
    int it_a = 0, it_c = 0;
    double worst = 0, solver = 0;
    for (int k = 0; k < 30; ++k) {
        hs_step_stats sa, sb, sc;
        ENSURE(hs_body_step(a, &sa) == HS_OK && hs_body_step(b, &sb) == HS_OK &&
               hs_body_step(c, &sc) == HS_OK && hs_body_step(e, NULL) == HS_OK);
        it_a += sa.fem.polar_iters_max;
        it_c += sc.fem.polar_iters_max;
        ENSURE(!memcmp(hs_body_displacement(a), hs_body_displacement(b), n3 * sizeof(double)));
        const double* ua = hs_body_displacement(a);
        worst = fmax(worst, rel_diff(hs_body_displacement(c), ua, n3));
        solver = fmax(solver, rel_diff(ua, hs_body_displacement(e), n3));
    }
    const double tip = end_mean(m, hs_body_displacement(a), 2);
    printf("  30 steps: tip %.4e m; worst Newton steps per update summed: tol 1e-6 %d, 1e-4 %d; "
           "largest relative difference of u: 1e-4 against 1e-6 %.2e, warped against direct "
           "%.2e\n",
           tip, it_a, it_c, worst, solver);
    ENSURE(tip < -0.01);           // a bend: the rotations move every step
    ENSURE(it_c < it_a);           // fewer Newton steps
    ENSURE(worst > 0);             // the tolerance reached the step...
    ENSURE(worst < 1e-3 * solver); // ...and moved it far less than the step's own error
    hs_body_destroy(&e);

    // Reset: c from rest again steps exactly as a new body.
    hs_body* fresh = bend_body(m, fx, 1e-4, HS_SOLVER_WARPED);
    ENSURE(fresh);
    hs_body_reset(c);
    for (int k = 0; k < 10; ++k) ENSURE(hs_body_step(c, NULL) == HS_OK);
    for (int k = 0; k < 10; ++k) ENSURE(hs_body_step(fresh, NULL) == HS_OK);
    ENSURE(!memcmp(hs_body_displacement(c), hs_body_displacement(fresh), n3 * sizeof(double)));

    // The static solve uses fem.polar_tol, whatever the step's: a (1e-6 given by the fem)
    // against a body whose steps would accept rotations 10 % off.
    hs_body* loose = bend_body(m, fx, 0.1, HS_SOLVER_WARPED);
    ENSURE(loose);
    hs_body_reset(a);
    ENSURE(hs_body_solve_static(a, NULL) == HS_OK);
    ENSURE(hs_body_solve_static(loose, NULL) == HS_OK);
    ENSURE(!memcmp(hs_body_displacement(a), hs_body_displacement(loose), n3 * sizeof(double)));

    // Bad tolerances are refused and change nothing.
    hs_body_def d = hs_body_default_def();
    hs_body* bad = NULL;
    d.step_polar_tol = -1e-4;
    ENSURE(hs_body_create(m, &d, fx, &bad, NULL) == HS_ERR_INVALID && !bad);
    d.step_polar_tol = NAN;
    ENSURE(hs_body_create(m, &d, fx, &bad, NULL) == HS_ERR_INVALID && !bad);
    d = hs_body_default_def(); // SVD reads polar_tol too: 0 would never keep a rotation
    d.fem.model = HS_MODEL_COROTATED;
    d.fem.rotation = HS_ROTATION_SVD;
    d.fem.polar_tol = 0;
    ENSURE(hs_body_create(m, &d, fx, &bad, NULL) == HS_ERR_INVALID && !bad);
    hs_fem* fem = hs_body_fem(a);
    ENSURE(hs_fem_set_polar_tol(fem, 0) == HS_ERR_INVALID);
    ENSURE(hs_fem_set_polar_tol(fem, NAN) == HS_ERR_INVALID);
    ENSURE(hs_fem_set_polar_tol(fem, INFINITY) == HS_ERR_INVALID);
    ENSURE(hs_fem_set_polar_tol(fem, 1e-3) == HS_OK);

    hs_body_destroy(&a);
    hs_body_destroy(&b);
    hs_body_destroy(&c);
    hs_body_destroy(&fresh);
    hs_body_destroy(&loose);
    hs_mesh_destroy(&m);
    free(fx);
    return 0;
}

// hs_body_change_elements with an element listed twice, or both moved and going off: the
// factor that follows must still be the rest matrix's (a repeat once took a share out twice:
// 26 % off).
static int ElementListsRepeat(void) {
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &m, NULL) == HS_OK);
    unsigned char* fx = clamp_x0(m);
    for (int c = 0; c < 4; ++c) {
        hs_body_def d = hs_body_default_def();
        d.fem.model = c < 2 ? HS_MODEL_COROTATED : HS_MODEL_LINEAR;
        d.solver = c < 2 ? HS_SOLVER_WARPED : HS_SOLVER_DIRECT;
        d.gravity[2] = -9.81;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        for (int k = 0; k < 3; ++k) ENSURE(hs_body_step(b, NULL) == HS_OK);
        const int e = 60, twice[2] = {60, 60}, other[1] = {61};
        int lr = -1;
        if (c % 2 == 0) // off {e, e}
            ENSURE(hs_body_change_elements(b, 2, twice, 0, NULL, &lr) == HS_OK);
        else // off {e}, moved {e, e, 61}: e only goes off
            ENSURE(hs_body_change_elements(b, 1, &e, 2, twice, &lr) == HS_OK &&
                   hs_body_change_elements(b, 0, NULL, 1, other, NULL) == HS_OK);
        ENSURE(!hs_fem_element_active(hs_body_fem(b), e));
        double rel = -1;
        ENSURE(lr == 1 && hs_body_rest_factor_difference(b, &rel) == HS_OK);
        printf("  case %d: factor after the change differs from a new one by %.2e\n", c, rel);
        ENSURE(rel < 1e-9);
        ENSURE(hs_body_step(b, NULL) == HS_OK);
        hs_body_destroy(&b);
    }
    free(fx);
    hs_mesh_destroy(&m);
    return 0;
}

// A warped step that falls back to the exact tangent and then fails (its refactor cannot
// allocate) leaves u and v as they were, and does not leave the tangent in `a` posing as the
// rest matrix: before, v kept the line search's last trial, and a cut after it followed the
// rest factor from the tangent (102 % off). Every step from the second on runs with the next
// allocation refused: only a fallback's refactor allocates, and only while the allocator's
// cache (shared by the process) has no block for it, so ctest also runs this case alone in a
// fresh process (body_fault), where HS_TEST_REQUIRE_FAULT makes the failure mandatory.
static int FailedFallbackKeepsState(void) {
    hs_mesh* vm = NULL;
    hs_err verr;
    if (hs_mesh_load(HS_SHARED_MESHES "/aneurysm_vessel.msh", &vm, &verr) < 0) {
        printf("  SKIP: %s\n", verr.msg);
        ENSURE(!getenv("HS_TEST_REQUIRE_FAULT")); // body_fault exists to run this: no mesh fails
        return 0;
    }
    unsigned char* vf = calloc((size_t)vm->n_nodes, 1);
    hs_mesh_select_plane(vm, 2, -1, 0.1 * (vm->bbox_max[2] - vm->bbox_min[2]), vf);
    hs_body_def d = vessel_def(HS_SOLVER_WARPED);
    hs_body* b = NULL;
    ENSURE(hs_body_create(vm, &d, vf, &b, NULL) == HS_OK);
    ENSURE(hs_body_step(b, NULL) == HS_OK); // the first factor
    const size_t n3 = 3 * (size_t)vm->n_nodes;
    double* u0 = malloc(n3 * sizeof(double));
    double* v0 = malloc(n3 * sizeof(double));
    int failed = 0, fallbacks = 0;
    for (int k = 1; k < 40 && !failed; ++k) {
        memcpy(u0, hs_body_displacement(b), n3 * sizeof(double));
        memcpy(v0, hs_body_velocity(b), n3 * sizeof(double));
        hs_step_stats st;
        hs_alloc_fail_after(1);
        hs_status s = hs_body_step(b, &st);
        hs_alloc_fail_after(0);
        fallbacks += st.exact_fallbacks;
        if (s == HS_OK) continue;
        failed = 1;
        printf("  step %d failed with the allocation refused (status %d)\n", k, (int)s);
        ENSURE(st.exact_fallbacks == 1);
        ENSURE(memcmp(u0, hs_body_displacement(b), n3 * sizeof(double)) == 0);
        ENSURE(memcmp(v0, hs_body_velocity(b), n3 * sizeof(double)) == 0);
        int off = vm->n_tets / 2, lr = -1;
        ENSURE(hs_body_change_elements(b, 1, &off, 0, NULL, &lr) == HS_OK);
        double rel = -1;
        if (lr) ENSURE(hs_body_rest_factor_difference(b, &rel) == HS_OK && rel < 1e-9);
        printf("  a cut after it: factor followed %d, difference %.2e\n", lr, rel);
        ENSURE(hs_body_step(b, NULL) == HS_OK);
    }
    if (!failed) {
        printf("  no step allocated (%d fallbacks; the allocator's cache served them)\n",
               fallbacks);
        ENSURE(!getenv("HS_TEST_REQUIRE_FAULT"));
    }
    free(u0);
    free(v0);
    hs_body_destroy(&b);
    free(vf);
    hs_mesh_destroy(&vm);
    return 0;
}

// A static solve that fails (an allocation refused: the warped body's first exact-tangent
// refactor) leaves u and v as they were; it cleared v before it started. (An error after u has
// moved, which it would also undo, is not reachable this way: the solves allocate only then.)
static int FailedStaticKeepsState(void) {
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 12, 3, 3, &m, NULL) == HS_OK);
    unsigned char* fx = clamp_x0(m);
    hs_body_def d = beam_def(2e4, HS_SOLVER_WARPED);
    hs_body* b = NULL;
    ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
    ENSURE(hs_body_step(b, NULL) == HS_OK); // moving under gravity: v is not zero
    for (int i = 0; i < m->n_nodes; ++i)
        if (fx[i]) ENSURE(hs_body_set_prescribed(b, i, (double[3]){0, 0.002, 0.001}) == HS_OK);
    const size_t n3 = 3 * (size_t)m->n_nodes;
    double* u0 = malloc(n3 * sizeof(double));
    double* v0 = malloc(n3 * sizeof(double));
    memcpy(u0, hs_body_displacement(b), n3 * sizeof(double));
    memcpy(v0, hs_body_velocity(b), n3 * sizeof(double));
    int failed = 0;
    for (int k = 1; k <= 200; ++k) {
        hs_alloc_fail_after(k);
        hs_status s = hs_body_solve_static(b, NULL);
        hs_alloc_fail_after(0);
        if (s >= 0) break; // k allocations were enough
        failed++;
        ENSURE(memcmp(u0, hs_body_displacement(b), n3 * sizeof(double)) == 0);
        ENSURE(memcmp(v0, hs_body_velocity(b), n3 * sizeof(double)) == 0);
    }
    printf("  %d solves failed; u and v kept each time\n", failed);
    if (failed == 0) ENSURE(!getenv("HS_TEST_REQUIRE_FAULT"));
    // The loop ended with a solve that succeeded: the clamp moved, the beam sags, v is zero.
    const double* u = hs_body_displacement(b);
    int clamp = 0, tip = 0;
    for (int i = 0; i < m->n_nodes; ++i) {
        if (fx[i]) clamp = i;
        if (m->x0[3 * i] > m->x0[3 * tip]) tip = i;
    }
    ENSURE(u[3 * clamp + 1] == 0.002 && u[3 * tip + 2] < 0);
    for (size_t k = 0; k < n3; ++k) ENSURE(hs_body_velocity(b)[k] == 0);
    free(u0);
    free(v0);
    hs_body_destroy(&b);
    free(fx);
    hs_mesh_destroy(&m);
    return 0;
}

// Found in review (2026-11-28), each failing before.

// StVK under axial compression on a mesh small enough for a simplicial factor: the indefinite
// tangent was reported as NaN/Inf there, so the step did not go on with its last good factor
// and failed from step 3 on (197 of 200).
static int StvkCompressionKeepsStepping(void) {
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &m, NULL) == HS_OK);
    unsigned char* fx = clamp_x0(m);
    hs_body_def d = hs_body_default_def();
    d.fem.model = HS_MODEL_STVK;
    d.fem.material.youngs_pa = 5e4;
    d.fem.material.rayleigh_mass = 1.0;
    d.dt = 0.01;
    hs_body* b = NULL;
    ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
    ENSURE(!hs_cholesky_is_supernodal(hs_body_factor(b)));
    int tip = 0;
    for (int i = 0; i < m->n_nodes; ++i) tip += m->x0[3 * i] > 0.1 - 1e-9;
    for (int i = 0; i < m->n_nodes; ++i)
        if (m->x0[3 * i] > 0.1 - 1e-9)
            ENSURE(hs_body_set_force(b, i, (double[3]){-6.0 / tip, 0, -0.2 / tip}) == HS_OK);
    int fails = 0;
    for (int k = 0; k < 200; ++k) fails += hs_body_step(b, NULL) != HS_OK;
    double ux = end_mean(m, hs_body_displacement(b), 0);
    printf("  200 steps: %d failed; end face moved %.4f m along x\n", fails, ux);
    ENSURE(fails == 0 && ux < -0.01);
    hs_body_destroy(&b);
    free(fx);
    hs_mesh_destroy(&m);
    return 0;
}

// A static solve whose factorisation fails (out of memory) left K in the system matrix, which
// the linear model's later steps read as kcoef K + mcoef M in their safeguard: every step was
// cut back 8 times. Now, wherever the solve fails, they step as a body started from the same
// state.
static int FailedStaticThenSteps(void) {
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 8, 2, 2, &m, NULL) == HS_OK);
    unsigned char* fx = clamp_x0(m);
    hs_body_def d = hs_body_default_def();
    d.fem.model = HS_MODEL_LINEAR;
    d.fem.locking_free = 1;
    d.fem.material.youngs_pa = 2e4;
    d.fem.material.rayleigh_stiffness = 0.01;
    d.gravity[2] = -9.81;
    const int n3 = 3 * m->n_nodes;
    int failed = 0, cuts = 0;
    double worst = 0;
    for (int k = 1; k <= 400; ++k) {
        hs_body *a = NULL, *c = NULL;
        ENSURE(hs_body_create(m, &d, fx, &a, NULL) == HS_OK);
        ENSURE(hs_body_create(m, &d, fx, &c, NULL) == HS_OK);
        for (int j = 0; j < 5; ++j) ENSURE(hs_body_step(a, NULL) == HS_OK);
        hs_alloc_fail_after(k);
        hs_status s = hs_body_solve_static(a, NULL);
        hs_alloc_fail_after(0);
        if (s >= 0) { // k allocations were enough
            hs_body_destroy(&a);
            hs_body_destroy(&c);
            break;
        }
        failed++;
        ENSURE(hs_body_set_state(c, hs_body_displacement(a), hs_body_velocity(a)) == HS_OK);
        for (int j = 0; j < 4; ++j) {
            hs_step_stats sa;
            ENSURE(hs_body_step(a, &sa) == HS_OK && hs_body_step(c, NULL) == HS_OK);
            cuts += sa.line_search_cuts;
            worst = fmax(worst, rel_diff(hs_body_displacement(a), hs_body_displacement(c), n3));
        }
        hs_body_destroy(&a);
        hs_body_destroy(&c);
    }
    printf("  %d static solves failed; the 4 steps after each: %d halvings, u at most %.2g from "
           "the same state stepped afresh\n",
           failed, cuts, worst);
    ENSURE(failed > 0 && cuts == 0 && worst < 1e-12);
    free(fx);
    hs_mesh_destroy(&m);
    return 0;
}

// A step whose state is not finite is refused and leaves u and v as they were: the last,
// unchecked halving returned HS_OK with a NaN energy (StVK with the locking-free term at nu
// 0.4999999999, dt 1000 s) or Inf in v (E 1e-10 Pa, no mass, dt 1e-12 s).
static int NonFiniteStepRefused(void) {
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 6, 2, 2, &m, NULL) == HS_OK);
    unsigned char* fx = clamp_x0(m);
    const size_t n3 = 3 * (size_t)m->n_nodes;
    double* u0 = malloc(n3 * sizeof(double));
    double* v0 = malloc(n3 * sizeof(double));
    const double cfg[2][3] = {{3000, 1000, 1000}, {1e-10, 1e-12, 0}}; // E, dt, density
    for (int c = 0; c < 2; ++c) {
        hs_body_def d = hs_body_default_def();
        d.fem.model = HS_MODEL_STVK;
        d.fem.locking_free = 1;
        d.fem.material.youngs_pa = cfg[c][0];
        d.fem.material.poisson = 0.4999999999;
        d.fem.material.density_kg_m3 = cfg[c][2];
        d.gravity[2] = -9.81;
        d.dt = cfg[c][1];
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        for (int i = 0; i < m->n_nodes; ++i)
            if (m->x0[3 * i] > 0.1 - 1e-9)
                ENSURE(hs_body_set_force(b, i, (double[3]){0, 0, -1e-3}) == HS_OK);
        int refused = 0;
        for (int k = 0; k < 6; ++k) {
            memcpy(u0, hs_body_displacement(b), n3 * sizeof(double));
            memcpy(v0, hs_body_velocity(b), n3 * sizeof(double));
            hs_status s = hs_body_step(b, NULL);
            const double *u = hs_body_displacement(b), *v = hs_body_velocity(b);
            for (size_t j = 0; j < n3; ++j) ENSURE(isfinite(u[j]) && isfinite(v[j]));
            if (s < 0) {
                refused++;
                ENSURE(memcmp(u0, u, n3 * sizeof(double)) == 0);
                ENSURE(memcmp(v0, v, n3 * sizeof(double)) == 0);
            } else {
                ENSURE(isfinite(hs_body_elastic_energy(b)));
            }
        }
        printf("  E %g Pa, dt %g s: %d of 6 steps refused, the state finite throughout\n",
               cfg[c][0], cfg[c][1], refused);
        ENSURE(refused > 0);
        hs_body_destroy(&b);
    }
    free(u0);
    free(v0);
    free(fx);
    hs_mesh_destroy(&m);
    return 0;
}

// Rigid motion left free by the fixed nodes (one node, two: a free axis) has no static
// equilibrium: refused, naming the piece (the linear model ran 100 iterations to ~1e13 m).
static int UnderConstrainedStaticRefused(void) {
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 8, 2, 2, &m, NULL) == HS_OK);
    const size_t n3 = 3 * (size_t)m->n_nodes;
    for (int nfix = 1; nfix <= 3; ++nfix) {
        // Nodes of the x = 0 face: (0,0,0), (0,0.02,0), then (0,0,0.02) off their line.
        unsigned char* fx = calloc((size_t)m->n_nodes, 1);
        const double want[3][3] = {{0, 0, 0}, {0, 0.02, 0}, {0, 0, 0.02}};
        for (int i = 0; i < m->n_nodes; ++i)
            for (int k = 0; k < nfix; ++k)
                if (fabs(m->x0[3 * i] - want[k][0]) + fabs(m->x0[3 * i + 1] - want[k][1]) +
                        fabs(m->x0[3 * i + 2] - want[k][2]) <
                    1e-12)
                    fx[i] = 1;
        hs_body_def d = hs_body_default_def();
        d.fem.model = HS_MODEL_LINEAR;
        d.gravity[2] = -9.81;
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        hs_err e = {0};
        hs_status chk = hs_body_check_static(b, &e);
        hs_status s = hs_body_solve_static(b, NULL);
        if (nfix < 3) {
            printf("  %d fixed: %s\n", nfix, e.msg);
            ENSURE(chk == HS_ERR_INVALID && strstr(e.msg, "rigid motion is free"));
            ENSURE(s == HS_ERR_INVALID);
            for (size_t j = 0; j < n3; ++j) ENSURE(hs_body_displacement(b)[j] == 0);
            ENSURE(hs_body_step(b, NULL) == HS_OK); // dynamics has the mass
        } else {
            ENSURE(chk == HS_OK && s >= 0);
        }
        hs_body_destroy(&b);
        free(fx);
    }
    hs_mesh_destroy(&m);
    return 0;
}

// hs_body_set_solver on a live body: switching every 20 steps between the three solvers tracks
// a direct-only run (the state carries over; each solver refactors what it needs), and a body
// whose dofs are not in fill order (PCG without a factor) refuses.
static int SolverSwitchLive(void) {
    double tip[2];
    for (int run = 0; run < 2; ++run) {
        hs_mesh* m = NULL;
        ENSURE(hs_mesh_create_box(0.1, 0.02, 0.02, 20, 4, 4, &m, NULL) == HS_OK);
        unsigned char* fx = clamp_x0(m);
        hs_body_def d = beam_def(1.5e6, HS_SOLVER_WARPED);
        d.fem.material.rayleigh_mass = 20; // settles within the run
        hs_body* b = NULL;
        ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
        const hs_solver_kind order[4] = {HS_SOLVER_WARPED, HS_SOLVER_DIRECT, HS_SOLVER_PCG,
                                         HS_SOLVER_WARPED};
        for (int k = 0; k < 400; ++k) {
            hs_solver_kind want = run == 0 ? HS_SOLVER_DIRECT : order[(k / 20) % 4];
            ENSURE(hs_body_set_solver(b, want, NULL) == HS_OK && hs_body_solver(b) == want);
            ENSURE(hs_body_step(b, NULL) == HS_OK);
        }
        ENSURE(hs_body_set_solver(b, HS_SOLVER_DIRECT, NULL) == HS_OK);
        ENSURE(hs_body_set_solver(b, (hs_solver_kind)7, NULL) == HS_ERR_INVALID);
        ENSURE(hs_body_solver(b) == HS_SOLVER_DIRECT);
        tip[run] = end_mean(m, hs_body_displacement(b), 2);
        hs_body_destroy(&b);
        if (run == 1) {
            d.solver = HS_SOLVER_PCG;
            d.precond = HS_PRECOND_JACOBI;
            hs_err err = {0};
            ENSURE(hs_body_create(m, &d, fx, &b, NULL) == HS_OK);
            ENSURE(hs_body_set_solver(b, HS_SOLVER_DIRECT, &err) == HS_ERR_INVALID);
            ENSURE(strstr(err.msg, "fill order") != NULL);
            ENSURE(hs_body_step(b, NULL) == HS_OK); // still steps with its own
            hs_body_destroy(&b);
        }
        hs_mesh_destroy(&m);
        free(fx);
    }
    printf("  tip after 400 steps: direct %.5e m, switching %.5e m\n", tip[0], tip[1]);
    ENSURE(fabs(tip[0]) > 1e-3); // settled: every solver has the same equilibrium
    ENSURE(fabs(tip[1] / tip[0] - 1) < 1e-3);
    return 0;
}

HS_TEST_MAIN(HS_CASE(SolverSwitchLive), HS_CASE(PrescribedBarReaction),
             HS_CASE(LinearSeesElementChanges), HS_CASE(OrphanHeldInPlace), HS_CASE(RestIsQuiet),
             HS_CASE(StepPolarTol), HS_CASE(WarpedSolver), HS_CASE(WarpedPcgTracksDirect),
             HS_CASE(SolversAgree), HS_CASE(NoAllocAndErrors), HS_CASE(EnergyNeverGrows),
             HS_CASE(LargeStepNoEnergyGain), HS_CASE(InvertedRecovers), HS_CASE(SelfWeightVolume),
             HS_CASE(SvdStaticConverges), HS_CASE(CantileverTimoshenko),
             HS_CASE(ElementListsRepeat), HS_CASE(FailedFallbackKeepsState),
             HS_CASE(FailedStaticKeepsState), HS_CASE(BadInputRefused),
             HS_CASE(StvkCompressionKeepsStepping), HS_CASE(FailedStaticThenSteps),
             HS_CASE(NonFiniteStepRefused), HS_CASE(UnderConstrainedStaticRefused))
