// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-bench stress: numerical stress cases for the deformation core. Every case runs
// unattended and reports NaN/Inf count, worst energy growth, worst element volume ratios,
// inverted elements left, solver failures and what the engine did. tests/test_stress.c runs the
// quick set with assertions; `make stress` runs the long set (100,000-step soaks).
#define _POSIX_C_SOURCE 200809L
#include "bench.h"
#include "body.h"
#include "mesh.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/// What one stress case measured.
typedef struct hs_stress_result {
    char name[48];
    char model[24];
    char option[48];
    int steps;             ///< steps (or solves) attempted
    int nan_count;         ///< non-finite entries seen in u or v after any call
    double energy_growth;  ///< max over the run of E_k / E_0 (undamped, unforced runs), else NAN
    double vol_min;        ///< smallest element V/V0 seen
    double vol_max;        ///< largest element V/V0 seen
    int inverted_max;      ///< most inverted elements at one time
    int inverted_left;     ///< inverted elements at the end
    int failures;          ///< calls that returned an error status
    int state_kept;        ///< 1 if every failed call left u and v bit-identical
    hs_status first_error; ///< status of the first failed call (HS_OK if none)
    double wall_s;         ///< run time, s
    char action[160];      ///< what the engine did
} hs_stress_result;

typedef struct stress_rng {
    uint64_t s;
} stress_rng;

static double rng_uniform(stress_rng* r) { // xorshift64*, in [0, 1)
    r->s ^= r->s >> 12;
    r->s ^= r->s << 25;
    r->s ^= r->s >> 27;
    return (double)((r->s * 2685821657736338717ULL) >> 11) * (1.0 / 9007199254740992.0);
}

static void result_init(hs_stress_result* r, const char* name, const char* model,
                        const char* option) {
    memset(r, 0, sizeof *r);
    snprintf(r->name, sizeof r->name, "%s", name);
    snprintf(r->model, sizeof r->model, "%s", model);
    snprintf(r->option, sizeof r->option, "%s", option);
    r->energy_growth = NAN;
    r->vol_min = INFINITY;
    r->vol_max = -INFINITY;
    r->state_kept = 1;
    r->first_error = HS_OK;
}

// A body on a box, clamped at x = 0. density and gravity per case.
typedef struct stress_setup {
    hs_mesh* mesh;
    unsigned char* fixed;
    hs_body* body;
    double* save_u;
    double* save_v;
} stress_setup;

static void setup_free(stress_setup* s) {
    hs_body_destroy(&s->body);
    hs_mesh_destroy(&s->mesh);
    free(s->fixed);
    free(s->save_u);
    free(s->save_v);
    memset(s, 0, sizeof *s);
}

static int setup_body(stress_setup* s, hs_mesh* mesh, const hs_body_def* def, int clamp_axis) {
    hs_err err = {0};
    s->mesh = mesh;
    int n = mesh->n_nodes;
    s->fixed = calloc((size_t)n, 1);
    s->save_u = calloc(3 * (size_t)n, sizeof(double));
    s->save_v = calloc(3 * (size_t)n, sizeof(double));
    if (clamp_axis >= 0) hs_mesh_select_plane(mesh, clamp_axis, -1, 1e-9, s->fixed);
    if (hs_body_create(mesh, def, s->fixed, &s->body, &err) < 0) {
        fprintf(stderr, "stress: %s\n", err.msg);
        return 1;
    }
    return 0;
}

static int setup_box(stress_setup* s, int nx, int ny, int nz, const hs_body_def* def) {
    hs_err err = {0};
    hs_mesh* m = NULL;
    memset(s, 0, sizeof *s);
    if (hs_mesh_create_box(0.1, 0.02, 0.02, nx, ny, nz, &m, &err) < 0) {
        fprintf(stderr, "stress: %s\n", err.msg);
        return 1;
    }
    return setup_body(s, m, def, 0);
}

static int count_nonfinite(const double* x, int n) {
    int c = 0;
    for (int i = 0; i < n; ++i) c += !isfinite(x[i]);
    return c;
}

static double total_energy(hs_body* b) {
    return hs_body_kinetic_energy(b) + hs_body_elastic_energy(b);
}

// One call (step or static solve) with bookkeeping: NaN count, failures, state preservation,
// volume ratios and inversions from the call's statistics.
static hs_status checked_call(stress_setup* s, hs_stress_result* r, int is_static) {
    const int n3 = 3 * s->mesh->n_nodes;
    memcpy(s->save_u, hs_body_displacement(s->body), (size_t)n3 * sizeof(double));
    memcpy(s->save_v, hs_body_velocity(s->body), (size_t)n3 * sizeof(double));
    hs_step_stats st;
    hs_status st_code = is_static ? hs_body_solve_static(s->body, &st) : hs_body_step(s->body, &st);
    r->steps++;
    const double* u = hs_body_displacement(s->body);
    const double* v = hs_body_velocity(s->body);
    r->nan_count += count_nonfinite(u, n3) + count_nonfinite(v, n3);
    if (st_code < 0) {
        r->failures++;
        if (r->first_error == HS_OK) r->first_error = st_code;
        if (!is_static && (memcmp(u, s->save_u, (size_t)n3 * sizeof(double)) ||
                           memcmp(v, s->save_v, (size_t)n3 * sizeof(double))))
            r->state_kept = 0;
        return st_code;
    }
    if (st.fem.volume_ratio_min < r->vol_min) r->vol_min = st.fem.volume_ratio_min;
    if (st.fem.volume_ratio_max > r->vol_max) r->vol_max = st.fem.volume_ratio_max;
    if (st.fem.inverted > r->inverted_max) r->inverted_max = st.fem.inverted;
    r->inverted_left = st.fem.inverted;
    return st_code;
}

static void finish(hs_stress_result* r, const char* action) {
    if (r->failures)
        snprintf(r->action, sizeof r->action, "%.80s; %d calls returned %.30s, state %s", action,
                 r->failures, hs_status_str(r->first_error),
                 r->state_kept ? "untouched" : "CHANGED");
    else
        snprintf(r->action, sizeof r->action, "%s", action);
}

static hs_body_def cantilever_def(hs_model model, double nu, double dt) {
    hs_body_def d = hs_body_default_def();
    d.fem.model = model;
    d.fem.material = (hs_material){1.5e6, nu, 960, 0, 0};
    d.dt = dt;
    return d;
}

// --- cases ------------------------------------------------------------------------------------

/// Undamped free vibration from a bent state (tip load solved statically, then released):
/// backward Euler must never add energy. E_k / E_0 over `steps` steps.
static void case_free_vibration(hs_stress_result* r, hs_model model, double dt, int steps,
                                double tip_n, hs_solver_kind solver) {
    char opt[48];
    snprintf(opt, sizeof opt, "dt%gms;tip%gN%s", dt * 1e3, tip_n,
             solver == HS_SOLVER_WARPED ? ";warped" : "");
    result_init(r, "free-vibration", model == HS_MODEL_LINEAR ? "linear" : "corotated", opt);
    hs_body_def d = cantilever_def(model, 0.45, dt);
    d.solver = solver;
    stress_setup s;
    if (setup_box(&s, 10, 2, 2, &d)) {
        r->failures = 1;
        finish(r, "set-up failed");
        return;
    }
    int64_t t0 = hs_now_ns();
    for (int i = 0; i < s.mesh->n_nodes; ++i)
        if (s.mesh->x0[3 * i] > 0.1 - 1e-9)
            hs_body_set_force(s.body, i, (double[3]){0, 0, -tip_n / 9});
    checked_call(&s, r, 1);
    hs_body_clear_forces(s.body);
    double e0 = total_energy(s.body), worst = 1;
    for (int k = 0; k < steps; ++k) {
        if (checked_call(&s, r, 0) < 0) continue;
        double e = total_energy(s.body);
        if (e0 > 0 && e / e0 > worst) worst = e / e0;
    }
    r->energy_growth = worst;
    r->wall_s = (double)(hs_now_ns() - t0) * 1e-9;
    finish(r, worst <= 1 + 1e-9 ? "energy decays (backward Euler dissipation)"
                                : "ENERGY GREW in an undamped run");
    setup_free(&s);
}

/// Near-incompressible materials under gravity with dynamic steps.
static void case_poisson(hs_stress_result* r, double nu, int locking_free, int steps) {
    char opt[48];
    snprintf(opt, sizeof opt, "nu%g;dt10ms;heavy10x%s", nu,
             locking_free == 2 ? ";sns"
             : locking_free    ? ";anp"
                               : "");
    result_init(r, "near-incompressible", "corotated", opt);
    hs_body_def d = cantilever_def(HS_MODEL_COROTATED, nu, 0.01);
    d.fem.material.density_kg_m3 *= 10;
    d.fem.locking_free = locking_free;
    d.gravity[2] = -9.81;
    stress_setup s;
    if (setup_box(&s, 10, 2, 2, &d)) {
        r->failures = 1;
        finish(r, "set-up failed");
        return;
    }
    int64_t t0 = hs_now_ns();
    for (int k = 0; k < steps; ++k) checked_call(&s, r, 0);
    r->wall_s = (double)(hs_now_ns() - t0) * 1e-9;
    finish(r, r->nan_count ? "NaN in state" : "stable");
    setup_free(&s);
}

/// A range of time steps with gravity on the 10x cantilever (large sag, overshoot).
static void case_dt(hs_stress_result* r, hs_model model, double dt, int steps) {
    char opt[48];
    snprintf(opt, sizeof opt, "dt%gms;heavy10x;gravity", dt * 1e3);
    result_init(r, "time-step", model == HS_MODEL_LINEAR ? "linear" : "corotated", opt);
    hs_body_def d = cantilever_def(model, 0.45, dt);
    d.fem.material.density_kg_m3 *= 10;
    d.gravity[2] = -9.81;
    stress_setup s;
    if (setup_box(&s, 10, 2, 2, &d)) {
        r->failures = 1;
        finish(r, "set-up failed");
        return;
    }
    int64_t t0 = hs_now_ns();
    for (int k = 0; k < steps; ++k) checked_call(&s, r, 0);
    r->wall_s = (double)(hs_now_ns() - t0) * 1e-9;
    finish(r, r->nan_count ? "NaN in state" : "stable");
    setup_free(&s);
}

/// Random large nodal forces (a new draw every 5 steps, up to `scale` times each node's weight),
/// then released with damping: the body must come back without inverted elements.
static void case_random_forces(hs_stress_result* r, hs_inversion inv, double scale, int steps,
                               uint64_t seed, hs_solver_kind solver) {
    char opt[48];
    snprintf(opt, sizeof opt, "%s;x%g;seed%llu%s",
             inv == HS_INVERSION_LINEAR_FALLBACK ? "fallback" : "reflection", scale,
             (unsigned long long)seed, solver == HS_SOLVER_WARPED ? ";warped" : "");
    result_init(r, "random-forces", "corotated", opt);
    hs_body_def d = cantilever_def(HS_MODEL_COROTATED, 0.45, 0.01);
    d.solver = solver;
    d.fem.inversion = inv;
    d.fem.material.rayleigh_mass = 5;
    stress_setup s;
    if (setup_box(&s, 10, 2, 2, &d)) {
        r->failures = 1;
        finish(r, "set-up failed");
        return;
    }
    int64_t t0 = hs_now_ns();
    stress_rng g = {seed * 0x9E3779B97F4A7C15ULL + 1};
    const double* m = hs_fem_lumped_mass(hs_body_fem(s.body));
    int n = s.mesh->n_nodes;
    for (int k = 0; k < steps; ++k) {
        for (int i = 0; i < n && k % 5 == 0; ++i) {
            double f[3];
            for (int c = 0; c < 3; ++c) f[c] = (2 * rng_uniform(&g) - 1) * scale * m[i] * 9.81;
            hs_body_set_force(s.body, i, f);
        }
        checked_call(&s, r, 0);
    }
    hs_body_clear_forces(s.body);
    int loaded_inv = r->inverted_max;
    // Release: strong damping until the body settles (bounded).
    for (int k = 0; k < 3 * steps; ++k) checked_call(&s, r, 0);
    r->wall_s = (double)(hs_now_ns() - t0) * 1e-9;
    char act[160];
    snprintf(act, sizeof act, "%d elements inverted at worst under load, %d left after release",
             loaded_inv, r->inverted_left);
    finish(r, act);
    setup_free(&s);
}

/// Every element mirrored (x -> -x through the clamp plane is not allowed since the clamp holds
/// x = 0, so the free end is folded back through the body: u_x = -2 x), then released.
static void case_inversion(hs_stress_result* r, hs_inversion inv, int locking_free, int steps) {
    char opt[48];
    snprintf(opt, sizeof opt, "%s%s",
             inv == HS_INVERSION_LINEAR_FALLBACK ? "fallback" : "reflection",
             locking_free == 2 ? ";sns"
             : locking_free    ? ";anp"
                               : "");
    result_init(r, "fold-through", "corotated", opt);
    hs_body_def d = cantilever_def(HS_MODEL_COROTATED, 0.45, 0.01);
    d.fem.inversion = inv;
    d.fem.locking_free = locking_free;
    d.fem.material.rayleigh_mass = 20;
    stress_setup s;
    if (setup_box(&s, 10, 2, 2, &d)) {
        r->failures = 1;
        finish(r, "set-up failed");
        return;
    }
    int64_t t0 = hs_now_ns();
    int n = s.mesh->n_nodes;
    double* u = calloc(3 * (size_t)n, sizeof(double));
    for (int i = 0; i < n; ++i) u[3 * i] = -2.0 * s.mesh->x0[3 * i]; // x -> -x: all inverted
    hs_body_set_state(s.body, u, NULL);
    for (int k = 0; k < 3 * n; ++k) u[k] += s.mesh->x0[k];
    for (int t = 0; t < s.mesh->n_tets; ++t) {
        double q = hs_tet_volume(u, s.mesh->tets + 4 * t) /
                   hs_tet_volume(s.mesh->x0, s.mesh->tets + 4 * t);
        r->inverted_max += q <= 0;
        r->vol_min = fmin(r->vol_min, q);
        r->vol_max = fmax(r->vol_max, q);
    }
    free(u);
    for (int k = 0; k < steps; ++k) checked_call(&s, r, 0);
    r->wall_s = (double)(hs_now_ns() - t0) * 1e-9;
    char act[160];
    snprintf(act, sizeof act, "%d inverted at start, %d left after %d steps", r->inverted_max,
             r->inverted_left, steps);
    finish(r, act);
    setup_free(&s);
}

/// A slab with one layer of slivers (thickness `ratio` of the other cells: near-degenerate,
/// min dihedral ~0) under gravity and a tip load.
static void case_slivers(hs_stress_result* r, double ratio, hs_model model, int steps) {
    char opt[48];
    snprintf(opt, sizeof opt, "layer%g", ratio);
    result_init(r, "sliver-layer", model == HS_MODEL_LINEAR ? "linear" : "corotated", opt);
    hs_err err = {0};
    hs_mesh* m = NULL;
    // 10 cells along x; the 5th cell is squeezed to `ratio` of the others.
    if (hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &m, &err) < 0) {
        r->failures = 1;
        finish(r, "set-up failed");
        return;
    }
    double h = 0.1 / (9 + ratio);
    for (int i = 0; i < m->n_nodes; ++i) {
        int ix = (int)lround(m->x0[3 * i] / 0.01);
        m->x0[3 * i] = ix <= 4 ? ix * h : (ix - 1 + ratio) * h;
    }
    if (hs_mesh_finalize(m, &err) < 0) {
        hs_mesh_destroy(&m);
        r->failures = 1;
        finish(r, "mesh rejected");
        return;
    }
    snprintf(r->option, sizeof r->option, "layer%g;mindihedral%.2gdeg", ratio,
             m->report.min_dihedral_deg);
    hs_body_def d = cantilever_def(model, 0.45, 0.01);
    d.fem.material.density_kg_m3 *= 10;
    d.gravity[2] = -9.81;
    stress_setup s;
    memset(&s, 0, sizeof s);
    if (setup_body(&s, m, &d, 0)) {
        setup_free(&s);
        r->failures = 1;
        finish(r, "body rejected the mesh");
        return;
    }
    int64_t t0 = hs_now_ns();
    for (int k = 0; k < steps; ++k) checked_call(&s, r, 0);
    r->wall_s = (double)(hs_now_ns() - t0) * 1e-9;
    finish(r, r->nan_count ? "NaN in state" : "stable");
    setup_free(&s);
}

/// Two materials in one cantilever: the clamped half `contrast` times stiffer than the free half
/// (hs_fem_set_element_stiffness_scale), under gravity. Also checks that a stiffness scale is
/// refused with ANP and for bad values.
static void case_contrast(hs_stress_result* r, double contrast, double dt, int steps) {
    char opt[48];
    snprintf(opt, sizeof opt, "contrast%g;dt%gms", contrast, dt * 1e3);
    result_init(r, "stiffness-contrast", "corotated", opt);
    hs_body_def d = cantilever_def(HS_MODEL_COROTATED, 0.45, dt);
    d.fem.material.youngs_pa = 1.5e6 / sqrt(contrast); // soft 15 kPa .. stiff 150 MPa at 1e4
    d.gravity[2] = -9.81;
    stress_setup s;
    if (setup_box(&s, 10, 2, 2, &d)) {
        r->failures = 1;
        finish(r, "set-up failed");
        return;
    }
    int64_t t0 = hs_now_ns();
    hs_fem* fem = hs_body_fem(s.body);
    int bad = 0;
    for (int t = 0; t < s.mesh->n_tets; ++t) {
        // Kuhn box: hex h has tets 6h..6h+5 and hex i runs fastest along x.
        int hx = (t / 6) % 10;
        bad |= hs_fem_set_element_stiffness_scale(fem, t, hx < 5 ? contrast : 1.0) != HS_OK;
    }
    bad |= hs_fem_set_element_stiffness_scale(fem, 0, NAN) != HS_ERR_INVALID;
    bad |= hs_fem_set_element_stiffness_scale(fem, 0, -1) != HS_ERR_INVALID;
    bad |= hs_fem_set_element_stiffness_scale(fem, s.mesh->n_tets, 1) != HS_ERR_INVALID;
    for (int k = 0; k < steps; ++k) checked_call(&s, r, 0);
    // Then the static equilibrium of the same state.
    hs_step_stats st;
    hs_status ss = hs_body_solve_static(s.body, &st);
    r->wall_s = (double)(hs_now_ns() - t0) * 1e-9;
    if (bad) r->failures++, r->first_error = HS_ERR_INVALID;
    char act[160];
    snprintf(act, sizeof act, "%s; static solve: %s after %d Newton iterations, residual %.1e",
             bad            ? "element stiffness scale not applied as documented"
             : r->nan_count ? "NaN in state"
                            : "steps stable",
             ss == HS_OK ? "converged" : hs_status_str(ss), st.iterations, st.residual);
    finish(r, act);
    setup_free(&s);
}

/// Bad input: NaN / Inf forces and prescribed values must return an error and keep the state.
static void case_bad_input(hs_stress_result* r, int kind) {
    static const char* names[] = {"nan-force", "inf-force", "nan-prescribed", "huge-force"};
    result_init(r, "bad-input", "corotated", names[kind]);
    hs_body_def d = cantilever_def(HS_MODEL_COROTATED, 0.45, 0.01);
    d.gravity[2] = -9.81;
    stress_setup s;
    if (setup_box(&s, 10, 2, 2, &d)) {
        r->failures = 1;
        finish(r, "set-up failed");
        return;
    }
    int64_t t0 = hs_now_ns();
    for (int k = 0; k < 5; ++k) checked_call(&s, r, 0); // some motion first
    int n = s.mesh->n_nodes, tip = n - 1;
    // The setters refuse bad values (nothing changes); a step would refuse what got through.
    hs_status set = HS_OK;
    if (kind == 0) set = hs_body_set_force(s.body, tip, (double[3]){NAN, 0, 0});
    if (kind == 1) set = hs_body_set_force(s.body, tip, (double[3]){0, INFINITY, 0});
    if (kind == 2) set = hs_body_set_prescribed(s.body, 0, (double[3]){0, 0, NAN});
    if (kind == 3) set = hs_body_set_force(s.body, tip, (double[3]){0, 0, 1e300});
    if (set < 0) {
        if (r->failures == 0) r->first_error = set;
        ++r->failures;
    }
    int f0 = r->failures - (set < 0);
    for (int k = 0; k < 3; ++k) checked_call(&s, r, 0);
    int rejected = r->failures - f0;
    // Remove the bad input: stepping must work again from the kept state.
    hs_body_clear_forces(s.body);
    hs_body_set_prescribed(s.body, 0, (double[3]){0, 0, 0});
    int before = r->failures;
    for (int k = 0; k < 5; ++k) checked_call(&s, r, 0);
    r->wall_s = (double)(hs_now_ns() - t0) * 1e-9;
    const char* what = !rejected ? "ACCEPTED without an error"
                       : r->failures == before
                           ? "rejected; stepping resumes after the input is removed"
                           : "rejected; still failing after the input was removed";
    char act[160];
    snprintf(act, sizeof act, "%s; %d inverted left", what, r->inverted_left);
    finish(r, act);
    setup_free(&s);
}

/// Long soak: a tip force switching direction every 0.25 s, co-rotated, light damping.
static void case_soak(hs_stress_result* r, int steps, double dt) {
    char opt[48];
    snprintf(opt, sizeof opt, "dt%gms;%dsteps", dt * 1e3, steps);
    result_init(r, "soak", "corotated", opt);
    hs_body_def d = cantilever_def(HS_MODEL_COROTATED, 0.45, dt);
    d.fem.material.rayleigh_mass = 1;
    d.gravity[2] = -9.81;
    stress_setup s;
    if (setup_box(&s, 10, 2, 2, &d)) {
        r->failures = 1;
        finish(r, "set-up failed");
        return;
    }
    int64_t t0 = hs_now_ns();
    int n = s.mesh->n_nodes, period = (int)lround(0.25 / dt);
    for (int k = 0; k < steps; ++k) {
        if (k % period == 0) {
            double sgn = (k / period) % 2 ? -1 : 1;
            for (int i = 0; i < n; ++i)
                if (s.mesh->x0[3 * i] > 0.1 - 1e-9)
                    hs_body_set_force(s.body, i, (double[3]){0, 2.0 * sgn, 3.0 * sgn});
        }
        checked_call(&s, r, 0);
    }
    r->wall_s = (double)(hs_now_ns() - t0) * 1e-9;
    finish(r, r->nan_count ? "NaN in state" : "stable");
    setup_free(&s);
}

/// A body with nothing fixed: the static stiffness is singular (rigid modes).
static void case_floating(hs_stress_result* r) {
    result_init(r, "floating-static", "linear", "no-fixed-nodes");
    hs_body_def d = cantilever_def(HS_MODEL_LINEAR, 0.45, 0.01);
    d.gravity[2] = -9.81;
    stress_setup s;
    hs_err err = {0};
    hs_mesh* m = NULL;
    memset(&s, 0, sizeof s);
    if (hs_mesh_create_box(0.1, 0.02, 0.02, 10, 2, 2, &m, &err) < 0 || setup_body(&s, m, &d, -1)) {
        setup_free(&s);
        r->failures = 1;
        finish(r, "set-up failed");
        return;
    }
    int64_t t0 = hs_now_ns();
    hs_status st = checked_call(&s, r, 1);
    // Dynamics of a free body is well posed (M > 0): it falls.
    for (int k = 0; k < 10; ++k) checked_call(&s, r, 0);
    r->wall_s = (double)(hs_now_ns() - t0) * 1e-9;
    char act[160];
    snprintf(act, sizeof act, "static solve returned %s; dynamics: the body falls",
             hs_status_str(st));
    finish(r, act);
    setup_free(&s);
}

// --- the runner ---------------------------------------------------------------------------

typedef void (*stress_sink)(const hs_stress_result* r, void* ctx);

/// Run every case (quick or long) and hand each result to sink. Returns the number of cases.
static int hs_stress_run(int quick, stress_sink sink, void* ctx) {
    hs_stress_result r;
    int n = 0;
    const double dts[] = {0.001, 0.01, 0.033, 0.1};
    for (int i = 0; i < 4; ++i) {
        int steps = quick ? 200 : (int)fmin(3000, ceil(10.0 / dts[i]));
        case_free_vibration(&r, HS_MODEL_LINEAR, dts[i], steps, 5, HS_SOLVER_DIRECT);
        sink(&r, ctx), ++n;
        case_free_vibration(&r, HS_MODEL_COROTATED, dts[i], steps, 20, HS_SOLVER_DIRECT);
        sink(&r, ctx), ++n;
        case_free_vibration(&r, HS_MODEL_COROTATED, dts[i], steps, 20, HS_SOLVER_WARPED);
        sink(&r, ctx), ++n;
        case_dt(&r, HS_MODEL_COROTATED, dts[i], quick ? 100 : 1000);
        sink(&r, ctx), ++n;
    }
    const double nus[] = {0.49, 0.499, 0.4999};
    for (int i = 0; i < 3; ++i)
        for (int lf = 0; lf < 3; ++lf) { // none, ANP, SNS
            case_poisson(&r, nus[i], lf, quick ? 50 : 500);
            sink(&r, ctx), ++n;
        }
    for (int inv = 0; inv < 2; ++inv) {
        int seeds = quick ? 1 : 5;
        for (int sd = 1; sd <= seeds; ++sd)
            for (int w = 0; w < 2; ++w) {
                case_random_forces(&r, (hs_inversion)inv, 3000, quick ? 30 : 200, (uint64_t)sd,
                                   w ? HS_SOLVER_WARPED : HS_SOLVER_DIRECT);
                sink(&r, ctx), ++n;
            }
        for (int lf = 0; lf < 3; ++lf) {
            case_inversion(&r, (hs_inversion)inv, lf, quick ? 150 : 1000);
            sink(&r, ctx), ++n;
        }
    }
    const double contrast_dt[] = {0.001, 0.01, 0.1};
    for (int i = 0; i < 3; ++i)
        for (int c = 0; c < 2; ++c) {
            case_contrast(&r, c ? 1e4 : 1e2, contrast_dt[i], quick ? 50 : 500);
            sink(&r, ctx), ++n;
        }
    const double ratios[] = {1e-2, 1e-3, 1e-4};
    for (int i = 0; i < 3; ++i) {
        case_slivers(&r, ratios[i], HS_MODEL_COROTATED, quick ? 50 : 500);
        sink(&r, ctx), ++n;
    }
    for (int k = 0; k < 4; ++k) {
        case_bad_input(&r, k);
        sink(&r, ctx), ++n;
    }
    case_floating(&r);
    sink(&r, ctx), ++n;
    case_soak(&r, quick ? 2000 : 100000, 0.001);
    sink(&r, ctx), ++n;
    if (!quick) {
        case_soak(&r, 100000, 0.01);
        sink(&r, ctx), ++n;
    }
    return n;
}

#ifndef HS_STRESS_NO_BENCH
static void print_header(void) {
    printf("case,model,option,steps,nan_inf,energy_growth,vol_ratio_min,vol_ratio_max,"
           "inverted_max,inverted_left,solver_failures,first_error,wall_s,action\n");
}

static void print_result(const hs_stress_result* r, void* ctx) {
    int* bad = ctx;
    printf("%s,%s,%s,%d,%d,", r->name, r->model, r->option, r->steps, r->nan_count);
    if (isnan(r->energy_growth))
        printf(",");
    else
        printf("%.9f,", r->energy_growth);
    printf("%.4g,%.4g,%d,%d,%d,%s,%.2f,\"%s\"\n", r->vol_min, r->vol_max, r->inverted_max,
           r->inverted_left, r->failures, r->failures ? hs_status_str(r->first_error) : "",
           r->wall_s, r->action);
    fflush(stdout);
    if (r->nan_count || !r->state_kept) ++*bad;
}

int hs_bench_stress(const hs_bench_args* a) {
    int bad = 0;
    print_header();
    hs_stress_run(a->quick, print_result, &bad);
    return bad != 0;
}
#endif
