// SPDX-License-Identifier: GPL-2.0-or-later
// Numerical stress suite, quick version (the long one is `make stress`): the cases of
// tests/bench/bench_stress.c with assertions on what they measured.
#define HS_STRESS_NO_BENCH
#include "bench/bench_stress.c"
#include "test_macros.h"

typedef struct collected {
    hs_stress_result r[64];
    int n;
} collected;

static void collect(const hs_stress_result* r, void* ctx) {
    collected* c = ctx;
    if (c->n < 64) c->r[c->n++] = *r;
    printf("  %-20s %-10s %-34s nan %d  E %.3g  vol [%.3g, %.3g]  inv %d/%d  fail %d\n", r->name,
           r->model, r->option, r->nan_count, r->energy_growth, r->vol_min, r->vol_max,
           r->inverted_max, r->inverted_left, r->failures);
}

static collected g_all;
static int64_t g_bytes_before, g_bytes_after;

// The suite runs once; every case reads its results (so a filtered run works too).
static void run_suite(void) {
    if (g_all.n) return;
    g_bytes_before = hs_byte_count();
    hs_stress_run(1, collect, &g_all);
    g_bytes_after = hs_byte_count();
}

static int is(const hs_stress_result* r, const char* name) {
    return !strcmp(r->name, name);
}

// The whole quick suite: no NaN or Inf ever reaches the state; a failed call never changes it.
static int stress_quick_suite_no_nan(void) {
    run_suite();
    int n = g_all.n;
    ENSURE(n >= 20);
    ENSURE(g_bytes_after == g_bytes_before);
    for (int i = 0; i < n; ++i) {
        const hs_stress_result* r = &g_all.r[i];
        if (r->nan_count || !r->state_kept) printf("  case %s %s\n", r->name, r->option);
        ENSURE(r->nan_count == 0);
        ENSURE(r->state_kept);
        ENSURE(r->steps > 0);
    }
    return 0;
}

// Undamped, unforced linear runs: implicit Euler never adds energy, at any dt in 1 ms .. 0.1 s.
static int stress_linear_energy_never_grows(void) {
    run_suite();
    int seen = 0;
    for (int i = 0; i < g_all.n; ++i) {
        const hs_stress_result* r = &g_all.r[i];
        if (!is(r, "free-vibration") || strcmp(r->model, "linear")) continue;
        ++seen;
        ENSURE(r->failures == 0);
        ENSURE(r->energy_growth <= 1.0 + 1e-9);
    }
    ENSURE(seen == 4);
    return 0;
}

// Undamped co-rotated runs: with the exact tangent or the warped one, the step's safeguard keeps
// the energy from growing at any dt in 1 ms .. 0.1 s.
static int stress_corotated_energy_never_grows(void) {
    run_suite();
    int seen = 0;
    for (int i = 0; i < g_all.n; ++i) {
        const hs_stress_result* r = &g_all.r[i];
        if (!is(r, "free-vibration") || strcmp(r->model, "corotated")) continue;
        ++seen;
        printf("  corotated %s: energy max/start %.9f\n", r->option, r->energy_growth);
        ENSURE(r->failures == 0);
        ENSURE(r->energy_growth <= 1.0 + 1e-6);
    }
    ENSURE(seen == 8);
    return 0;
}

// Inverted elements recover: the fold-through cases start with every element mirrored and end
// with none inverted, for both inversion remedies. The random-forces cases invert none in
// these runs (the step's energy safeguard stops the overshoots; 0 in every case, 2026-11-27):
// for them this checks only that nothing fails and nothing is left inverted.
static int stress_inversion_recovers(void) {
    run_suite();
    int seen = 0, folds = 0;
    for (int i = 0; i < g_all.n; ++i) {
        const hs_stress_result* r = &g_all.r[i];
        if (!is(r, "fold-through") && !is(r, "random-forces")) continue;
        ++seen;
        ENSURE(r->failures == 0);
        ENSURE(r->inverted_left == 0);
        if (is(r, "fold-through")) {
            ENSURE(r->inverted_max == 60 * 4); // every element at the start
            ++folds;
        }
    }
    ENSURE(seen == 10 && folds == 6); // fold-through: 2 remedies x none, ANP, SNS
    return 0;
}

// Non-finite or absurd input is refused by its setter with HS_ERR_INVALID, the state is kept,
// and stepping works on; a singular static problem is an error, not garbage.
static int stress_failures_are_errors(void) {
    run_suite();
    int seen = 0;
    for (int i = 0; i < g_all.n; ++i) {
        const hs_stress_result* r = &g_all.r[i];
        if (is(r, "bad-input")) { // refused by the setter; the following steps succeed
            ++seen;
            ENSURE(r->failures == 1);
            ENSURE(r->first_error == HS_ERR_INVALID);
            ENSURE(r->state_kept);
            ENSURE(r->inverted_left == 0);
        }
        if (is(r, "floating-static")) {
            ++seen;
            ENSURE(r->failures == 1);
            ENSURE(r->first_error < 0);
        }
    }
    ENSURE(seen == 5);
    return 0;
}

// Near incompressibility (nu to 0.4999), slivers (min dihedral < 0.01 deg), stiffness contrasts
// of 1e4 and time steps up to 0.1 s stay finite, error-free and without inverted elements.
static int stress_hard_materials_and_meshes(void) {
    run_suite();
    int seen = 0;
    for (int i = 0; i < g_all.n; ++i) {
        const hs_stress_result* r = &g_all.r[i];
        if (!is(r, "near-incompressible") && !is(r, "sliver-layer") && !is(r, "time-step") &&
            !is(r, "soak") && !is(r, "stiffness-contrast"))
            continue;
        ++seen;
        ENSURE(r->failures == 0);
        ENSURE(r->inverted_left == 0);
        ENSURE(r->vol_min > 0 || is(r, "soak"));
        // The static solve after the steps reaches its round-off floor and says converged
        // (it stalled at 100 iterations with a floor that ignored the stiff half).
        if (is(r, "stiffness-contrast")) {
            if (!strstr(r->action, "static solve: converged")) printf("  %s\n", r->action);
            ENSURE(strstr(r->action, "static solve: converged") != NULL);
        }
    }
    ENSURE(seen == 4 + 9 + 3 + 1 + 6); // near-incompressible: 3 nu x none, ANP, SNS
    return 0;
}

// hs_fem_set_element_stiffness_scale: scaling every element by s divides a linear static
// displacement by s; scaling half the beam stiffens it; ANP refuses.
static int stress_stiffness_scale_applies(void) {
    int64_t bytes = hs_byte_count();
    double tip[3];
    for (int k = 0; k < 3; ++k) {
        hs_body_def d = cantilever_def(HS_MODEL_LINEAR, 0.45, 0.01);
        d.gravity[2] = -9.81;
        stress_setup s;
        ENSURE(setup_box(&s, 10, 2, 2, &d) == 0);
        hs_fem* fem = hs_body_fem(s.body);
        for (int t = 0; t < s.mesh->n_tets; ++t) {
            double sc = k == 0 ? 1.0 : k == 1 ? 4.0 : ((t / 6) % 10 < 5 ? 1e4 : 1.0);
            ENSURE(hs_fem_set_element_stiffness_scale(fem, t, sc) == HS_OK);
        }
        hs_step_stats st;
        hs_status ss = hs_body_solve_static(s.body, &st);
        // With a 1e4 contrast the residual stalls at round-off (~3e-7 of the load) above the
        // 1e-8 tolerance: HS_WARN_NOT_CONVERGED with a usable state (reported to the lead).
        ENSURE(ss == HS_OK || (k == 2 && ss == HS_WARN_NOT_CONVERGED && st.residual < 1e-5));
        tip[k] = hs_body_displacement(s.body)[3 * (s.mesh->n_nodes - 1) + 2];
        setup_free(&s);
    }
    ENSURE(tip[0] < 0);
    ENSURE_NEAR(tip[1] / tip[0], 0.25, 1e-9);
    // Rigid clamped half: the free half bends as a 5 cm cantilever, (1/2)^4 of the deflection
    // of the full beam (plus shear terms), far below the uniform beam and above zero.
    ENSURE(tip[2] / tip[0] > 0.03 && tip[2] / tip[0] < 0.2);
    hs_body_def d = cantilever_def(HS_MODEL_LINEAR, 0.45, 0.01);
    d.fem.locking_free = 1;
    stress_setup s;
    ENSURE(setup_box(&s, 10, 2, 2, &d) == 0);
    ENSURE(hs_fem_set_element_stiffness_scale(hs_body_fem(s.body), 0, 2.0) == HS_ERR_UNSUPPORTED);
    setup_free(&s);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

HS_TEST_MAIN(HS_CASE(stress_quick_suite_no_nan), HS_CASE(stress_linear_energy_never_grows),
             HS_CASE(stress_corotated_energy_never_grows), HS_CASE(stress_inversion_recovers),
             HS_CASE(stress_failures_are_errors), HS_CASE(stress_hard_materials_and_meshes),
             HS_CASE(stress_stiffness_scale_applies))
