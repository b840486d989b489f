// SPDX-License-Identifier: GPL-2.0-or-later
// rt: local model, blending, safety filters (pure), the 1 kHz loop (timing invariants, overrun
// catch-up), the haptic tick end to end through the memory device (watchdog, NaN, clamps,
// telemetry), and zero allocations on the rt thread.
//
// Timing on this machine is shared and noisy: the loop cases assert counts and invariants
// (every deadline accounted for, histograms consistent), never tight latency numbers.
// HS_RT_SECONDS sets the zero-allocation run length (default 2 s; the issue asks for 10 s by hand:
// HS_RT_SECONDS=10 ./test_rt ZeroAlloc).
#define _GNU_SOURCE
#include "base.h"
#include "haptic.h"
#include "device.h"
#include "haptic_rt.h"
#include "rt_thread.h"
#include "test_macros.h"

#include <math.h>
#include <stdatomic.h>
#include <stdint.h>
#include <stdlib.h>
#include <time.h>

// Allocation counting on the rt thread: see alloc_counter.h.
#include "alloc_counter.h"

// ---------------------------------------------------------------------------------------------
// Helpers

static uint64_t g_rng = 0x9e3779b97f4a7c15ull;
static double urand(void) { // [0, 1)
    g_rng = g_rng * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(g_rng >> 11) * (1.0 / 9007199254740992.0);
}
static double srand1(void) {
    return 2 * urand() - 1;
}

static double norm3(const double v[3]) {
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}
static double dist3(const double a[3], const double b[3]) {
    double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return norm3(d);
}

// A spring model: force f0 at the anchor, symmetric positive definite K.
static hs_haptic_model random_model(int64_t seq) {
    hs_haptic_model m;
    memset(&m, 0, sizeof m);
    m.seq = seq;
    for (int i = 0; i < 3; ++i) {
        m.force_n[i] = 2 * srand1();
        m.anchor_m[i] = 0.01 * srand1();
    }
    double k = 100 + 300 * urand();
    double off = 50 * srand1();
    for (int i = 0; i < 3; ++i) m.stiffness_n_m[4 * i] = k;
    m.stiffness_n_m[1] = m.stiffness_n_m[3] = off;
    m.radius_m = 0.005 + 0.015 * urand();
    m.timeout_s = 0.1;
    return m;
}

static void sleep_ns(int64_t ns) {
    struct timespec ts = {(time_t)(ns / 1000000000), (long)(ns % 1000000000)};
    nanosleep(&ts, NULL);
}

static double env_seconds(const char* name, double def) {
    const char* s = getenv(name);
    if (!s) return def;
    double v = atof(s);
    return v > 0 && v < 3600 ? v : def;
}

// ---------------------------------------------------------------------------------------------
// Local model

static int ModelEval(void) {
    hs_haptic_model m;
    memset(&m, 0, sizeof m);
    m.force_n[2] = 1.0;
    for (int i = 0; i < 3; ++i) m.stiffness_n_m[4 * i] = 200.0;
    m.anchor_m[2] = 0.05;
    m.radius_m = 0.01;
    double f[3];
    // At the anchor: f0.
    ENSURE(hs_haptic_model_eval(&m, m.anchor_m, f) == 1);
    ENSURE(f[0] == 0 && f[1] == 0 && f[2] == 1.0);
    // 3 mm deeper into the tissue (along -z): the force on the tool grows along +z.
    double p[3] = {0, 0, 0.047};
    ENSURE(hs_haptic_model_eval(&m, p, f) == 1);
    ENSURE_NEAR(f[2], 1.0 + 200 * 0.003, 1e-12);
    // Outside the radius: the value at the nearest point of the sphere (bounded, continuous).
    double far[3] = {0, 0, 0.0};
    ENSURE(hs_haptic_model_eval(&m, far, f) == 0);
    ENSURE_NEAR(f[2], 1.0 + 200 * 0.01, 1e-12);
    double edge[3] = {0, 0, 0.04 + 1e-12};
    double fe[3];
    hs_haptic_model_eval(&m, edge, fe);
    ENSURE_NEAR(fe[2], f[2], 1e-6);
    // Reanchoring keeps the force; the stiffness vanishes outside, the radius shrinks inside.
    hs_haptic_model r;
    hs_haptic_model_reanchor(&m, p, &r);
    ENSURE_NEAR(r.force_n[2], 1.6, 1e-12);
    ENSURE_NEAR(r.radius_m, 0.007, 1e-12);
    ENSURE(r.stiffness_n_m[0] == 200.0 && r.anchor_m[2] == 0.047);
    double f2[3];
    hs_haptic_model_eval(&r, p, f2);
    ENSURE_NEAR(f2[2], 1.6, 1e-12);
    hs_haptic_model_reanchor(&m, far, &r);
    ENSURE(r.stiffness_n_m[0] == 0 && r.radius_m == 0);
    ENSURE(hs_haptic_model_stiffness_bound(&m) == 200.0);
    { // not symmetric: every row sums to 1, yet |K (1,0,0)| = sqrt(3)
        hs_haptic_model u = m;
        memset(u.stiffness_n_m, 0, sizeof u.stiffness_n_m);
        u.stiffness_n_m[0] = u.stiffness_n_m[3] = u.stiffness_n_m[6] = 1.0;
        ENSURE(hs_haptic_model_stiffness_bound(&u) >= sqrt(3.0) - 1e-12);
    }
    ENSURE(hs_haptic_model_finite(&m));
    m.stiffness_n_m[5] = NAN;
    ENSURE(!hs_haptic_model_finite(&m));
    return 0;
}

// The blend over 1,000 switches, many of them in the middle of a blend, with the tool moving.
// Returns the worst ratio of a tick's force change to the derived bound.
static double blend_worst_ratio(int ticks, int* settled_ok, int switches) {
    const int n_blend = 10; // the bound is derived for this blend length
    g_rng = 12345;
    hs_haptic_blend b;
    hs_haptic_blend_init(&b, ticks);
    hs_haptic_model target = random_model(1);
    double kmax = 0, fmax = 0;
    double prev_f[3] = {0, 0, 0}, prev_p[3] = {0, 0, 0};
    double worst = 0;
    int k = 0, left = 0, sw = 0;
    *settled_ok = 1;
    while (sw < switches) {
        if (left == 0) {
            target = random_model(target.seq + 1);
            double kb = hs_haptic_model_stiffness_bound(&target);
            double fb = norm3(target.force_n) + kb * target.radius_m;
            kmax = kb > kmax ? kb : kmax;
            fmax = fb > fmax ? fb : fmax;
            left = (sw % 50 == 0) ? 30 : 1 + (int)(15 * urand());
            ++sw;
        }
        // Tool on a smooth path, < 0.3 m/s (0.3 mm per 1 ms tick).
        double t = k * 1e-3;
        double p[3] = {0.01 * sin(7 * t), 0.008 * cos(11 * t), 0.005 * sin(13 * t)};
        double f[3];
        hs_haptic_model out;
        hs_haptic_blend_step(&b, &target, p, f, &out);
        if (out.force_n[0] != f[0] || out.force_n[2] != f[2] || out.anchor_m[1] != p[1])
            *settled_ok = 0; // the output model must carry the output force at the tool
        if (k > 0) {
            double dp = dist3(p, prev_p);
            double bound = kmax * dp * (1.0 + 1.0 / n_blend) + 2 * fmax / n_blend + 1e-9;
            double r = dist3(f, prev_f) / bound;
            worst = r > worst ? r : worst;
        }
        --left;
        if (left == 0 && b.done == b.ticks) {
            // A finished blend outputs exactly the target.
            double ft[3];
            hs_haptic_model_eval(&target, p, ft);
            if (dist3(ft, f) > 1e-12) *settled_ok = 0;
        }
        memcpy(prev_f, f, sizeof f);
        memcpy(prev_p, p, sizeof p);
        ++k;
    }
    return worst;
}

static int BlendNeverJumps(void) {
    int settled = 0;
    double worst = blend_worst_ratio(10, &settled, 1000);
    printf("  blend over 10 ticks: worst |dF| / bound = %.3f\n", worst);
    ENSURE(worst <= 1.0);
    ENSURE(settled);
    // The same sequence without blending breaks the bound: the check can tell.
    double unblended = blend_worst_ratio(1, &settled, 1000);
    printf("  no blend: worst |dF| / bound = %.3f\n", unblended);
    ENSURE(unblended > 1.5);
    // From nothing, the first model blends in from zero force.
    hs_haptic_blend b;
    hs_haptic_blend_init(&b, 4);
    hs_haptic_model m;
    memset(&m, 0, sizeof m);
    m.seq = 7;
    m.force_n[0] = 4.0;
    double p[3] = {0, 0, 0}, f[3];
    for (int i = 1; i <= 5; ++i) {
        hs_haptic_blend_step(&b, &m, p, f, NULL);
        ENSURE_NEAR(f[0], 4.0 * (i < 4 ? i : 4) / 4.0, 1e-12);
    }
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Safety filters

static int Clamps(void) {
    double f[3] = {30, 40, 0};
    ENSURE(hs_force_clamp_magnitude(f, 10) == 1);
    ENSURE_NEAR(norm3(f), 10, 1e-12);
    ENSURE_NEAR(f[0] / f[1], 0.75, 1e-12); // direction kept
    ENSURE(hs_force_clamp_magnitude(f, 10.5) == 0);
    // Finite but huge: clamped along its direction (the squares overflowed and it became zero).
    double huge[3] = {3e200, -4e200, 0};
    ENSURE(hs_force_clamp_magnitude(huge, 10) == 1);
    ENSURE_NEAR(huge[0], 6, 1e-12);
    ENSURE_NEAR(huge[1], -8, 1e-12);

    hs_rate_clamp rc = {{0, 0, 0}, 1000.0};
    double g[3] = {0, 0, 5};
    ENSURE(hs_rate_clamp_apply(&rc, g, 1e-3) == 1);
    ENSURE_NEAR(g[2], 1.0, 1e-12);
    g[2] = 5;
    ENSURE(hs_rate_clamp_apply(&rc, g, 2.5e-3) == 1); // a longer measured dt allows more
    ENSURE_NEAR(g[2], 3.5, 1e-12);
    g[2] = 3.0;
    ENSURE(hs_rate_clamp_apply(&rc, g, 1e-3) == 0);
    ENSURE(g[2] == 3.0 && rc.prev_n[2] == 3.0);
    // A difference that overflows (finite ends 3.4e308 apart): a step along it, not NaN (found in
    // review: Inf * 0 gave NaN, and a public filter must never output one).
    hs_rate_clamp big = {{-1.7e308, 0, 0}, 1000.0};
    double far[3] = {1.7e308, 0, 0};
    ENSURE(hs_rate_clamp_apply(&big, far, 1e-3) == 1);
    ENSURE(hs_vec3_finite(far) && far[0] == -1.7e308 && far[1] == 0 && far[2] == 0); // 1 N < ulp
    hs_rate_clamp diag = {{-1e308, -1e308, 0}, 1000.0};
    double far2[3] = {1e308, 1e308, 0};
    ENSURE(hs_rate_clamp_apply(&diag, far2, 1e-3) == 1 && hs_vec3_finite(far2));
    ENSURE(far2[0] == far2[1]);

    int64_t count = 0;
    double h[3] = {1, NAN, 2};
    ENSURE(hs_force_guard_finite(h, &count) == 1 && count == 1);
    ENSURE(h[0] == 0 && h[1] == 0 && h[2] == 0);
    double inf[3] = {INFINITY, 0, 0};
    ENSURE(hs_force_guard_finite(inf, &count) == 1 && count == 2);
    ENSURE(hs_force_guard_finite(h, &count) == 0 && count == 2);
    return 0;
}

static int WatchdogRamps(void) {
    hs_watchdog w;
    hs_watchdog_init(&w, 0.050, 0.010);
    int64_t t = 1000000000;
    // No device yet: no force.
    for (int i = 0; i < 5; ++i, t += 1000000) ENSURE(hs_watchdog_update(&w, 0, t, 1e-3) == 0);
    // Poses arrive: ramp in, never faster than dt / ramp.
    double g = 0;
    for (int i = 0; i < 20; ++i, t += 1000000) {
        double ng = hs_watchdog_update(&w, 1, t, 1e-3);
        ENSURE(ng >= g && ng - g <= 0.1 + 1e-12);
        g = ng;
    }
    ENSURE(g == 1.0);
    int64_t last = t - 1000000;
    // Poses stop; irregular tick times (0.2..3 ms). Full force until the timeout, exactly zero
    // from timeout + ramp on, monotone in between.
    g_rng = 99;
    while (t < last + 200000000) {
        double dt = 0.2e-3 + 2.8e-3 * urand();
        t += (int64_t)(dt * 1e9);
        double ng = hs_watchdog_update(&w, 0, t, dt);
        double since = (double)(t - last) * 1e-9;
        if (since <= 0.050) ENSURE(ng == 1.0);
        if (since >= 0.060) ENSURE(ng == 0.0);
        ENSURE(ng <= g);
        g = ng;
    }
    ENSURE(w.trips == 1 && !w.live);
    // Poses resume: ramps back in.
    for (int i = 0; i < 15; ++i, t += 1000000) {
        double ng = hs_watchdog_update(&w, 1, t, 1e-3);
        ENSURE(ng >= g && ng - g <= 0.1 + 1e-12);
        g = ng;
    }
    ENSURE(g == 1.0 && w.trips == 1);
    // A trip (a fault, e.g. a non-finite pose): zero at once, and no way back without a fresh
    // pose (it used to ramp back in within 10 ms on the last good pose alone).
    hs_watchdog_trip(&w);
    for (int i = 0; i < 30; ++i, t += 1000000) ENSURE(hs_watchdog_update(&w, 0, t, 1e-3) == 0);
    ENSURE(hs_watchdog_update(&w, 1, t, 1e-3) > 0);
    return 0;
}

static int SafetyChain(void) {
    hs_safety_def def = hs_safety_default_def();
    ENSURE(hs_safety_def_valid(&def));
    hs_safety_def bad = def;
    bad.ramp_s = 0;
    ENSURE(!hs_safety_def_valid(&bad));
    bad = def;
    bad.cookie = 0;
    ENSURE(!hs_safety_def_valid(&bad));

    hs_safety s;
    hs_safety_init(&s, &def);
    int64_t t = 5000000000;
    const double dt = 1e-3, step = def.max_rate_n_s * dt;
    double prev = 0;
    // Constant 5 N with fresh poses: ramps in (watchdog gain, the rate clamp on the output: the
    // two no longer add up), then holds 5 N.
    for (int i = 0; i < 40; ++i, t += 1000000) {
        double f[3] = {0, 0, 5};
        hs_safety_apply(&s, f, 1, 1, t, dt);
        ENSURE(fabs(f[2] - prev) <= step + 1e-12 && f[2] <= 5.0 + 1e-12);
        prev = f[2];
    }
    ENSURE_NEAR(prev, 5.0, 1e-12);
    // A step to 50 N: rate-limited, then magnitude-limited at 10 N.
    int saw_rate = 0, saw_mag = 0;
    for (int i = 0; i < 20; ++i, t += 1000000) {
        double f[3] = {0, 0, 50};
        uint32_t fl = hs_safety_apply(&s, f, 1, 1, t, dt);
        saw_rate |= (fl & HS_SAFETY_RATE) != 0;
        saw_mag |= (fl & HS_SAFETY_MAGNITUDE) != 0;
        ENSURE(f[2] - prev <= step + 1e-12 && norm3(f) <= def.max_force_n + 1e-12);
        prev = f[2];
    }
    ENSURE(saw_rate && saw_mag && prev == def.max_force_n);
    ENSURE(s.counters.rate > 0 && s.counters.magnitude > 0);
    // The limit lowered under a slow rate limit: met on the next answer, not at 1 N/s (the
    // rate clamp alone would hold 10 N for seconds), and the force holds at the new limit.
    hs_safety_def low = def;
    low.max_force_n = 0.5;
    low.max_rate_n_s = 1.0;
    hs_safety_set_limits(&s, &low);
    for (int i = 0; i < 5; ++i, t += 1000000) {
        double f[3] = {0, 0, 50};
        uint32_t lf = hs_safety_apply(&s, f, 1, 1, t, dt);
        ENSURE((lf & HS_SAFETY_MAGNITUDE) && norm3(f) <= low.max_force_n + 1e-12);
        ENSURE_NEAR(f[2], low.max_force_n, 1e-12);
    }
    hs_safety_set_limits(&s, &def);
    // NaN force: zero at once, counted, then ramps back in (no step back to 10 N).
    double fn[3] = {0, NAN, 1};
    uint32_t fl = hs_safety_apply(&s, fn, 1, 1, t, dt);
    t += 1000000;
    ENSURE((fl & HS_SAFETY_NONFINITE) && fn[0] == 0 && fn[1] == 0 && fn[2] == 0);
    ENSURE(s.counters.nonfinite_force == 1);
    double f1[3] = {0, 0, 8};
    hs_safety_apply(&s, f1, 1, 1, t, dt);
    t += 1000000;
    // gain and rate both restart from 0: the gain's first step (0.1) and the rate's
    ENSURE(f1[2] > 0 && f1[2] <= fmin(0.1 * 8, step) + 1e-12);
    // NaN pose: zero and counted.
    double f2[3] = {0, 0, 8};
    fl = hs_safety_apply(&s, f2, 0, 0, t, dt);
    ENSURE((fl & HS_SAFETY_NONFINITE) && f2[2] == 0 && s.counters.nonfinite_pose == 1);

    // step_period_s: a late tick (2.5 ms) steps no further than one period (1 ms) allows, and
    // while the watchdog ramps in, gain and rate together stay within it (the rate clamp acts
    // on the output). Without the cap the same tick steps 2.5x as far.
    hs_safety_def capped = def;
    capped.step_period_s = 1e-3;
    ENSURE(hs_safety_def_valid(&capped));
    hs_safety sc, su;
    hs_safety_init(&sc, &capped);
    hs_safety_init(&su, &def);
    double pc = 0, pu = 0, worst = 0;
    for (int i = 0; i < 30; ++i, t += 2500000) {
        double a[3] = {0, 0, 9}, b[3] = {0, 0, 9};
        hs_safety_apply(&sc, a, 1, 1, t, 2.5e-3);
        hs_safety_apply(&su, b, 1, 1, t, 2.5e-3);
        worst = fmax(worst, fabs(a[2] - pc));
        ENSURE(fabs(a[2] - pc) <= capped.max_rate_n_s * 1e-3 + 1e-12);
        ENSURE(i > 0 || b[2] > a[2]); // the first: gain 0.25 x 9 N beyond 2 N, capped at 2 N
        pc = a[2];
        pu = b[2];
    }
    ENSURE_NEAR(pc, 9.0, 1e-12);
    ENSURE_NEAR(pu, 9.0, 1e-12);
    ENSURE(worst > 0.9 * capped.max_rate_n_s * 1e-3); // the cap was the binding limit
    capped.step_period_s = -1;
    ENSURE(!hs_safety_def_valid(&capped));
    return 0;
}

// ---------------------------------------------------------------------------------------------
// The loop

typedef struct count_tick {
    int64_t n, bad_tick, bad_dt, prev_now;
    double dt_sum;
    int slow_every;   // busy-wait in every slow_every-th tick (0: never)
    int64_t slow_ns;  // for this long
    int64_t short_dt; // ticks with dt < period / 4 within 3 ticks after a slow one
    int after_slow;   // ticks left to watch after a slow tick
    double period_s;
} count_tick;

static void counting_tick(void* ctx, const hs_rt_clock* clk) {
    count_tick* c = ctx;
    c->bad_tick += clk->tick != c->n;
    c->bad_dt += !(clk->dt_s > 0) ||
                 (c->n > 0 && clk->now_ns - c->prev_now != (int64_t)llround(clk->dt_s * 1e9));
    if (c->after_slow > 0) {
        c->short_dt += clk->dt_s < 0.25 * c->period_s;
        --c->after_slow;
    }
    c->dt_sum += clk->dt_s;
    c->prev_now = clk->now_ns;
    ++c->n;
    if (c->slow_every && c->n % c->slow_every == 0) {
        int64_t until = hs_now_ns() + c->slow_ns;
        while (hs_now_ns() < until) {
        }
        c->after_slow = 3;
    }
}

// A 1 kHz loop definition whose tick is counting_tick on a zeroed c.
static hs_rt_def counting_def(count_tick* c) {
    memset(c, 0, sizeof *c);
    c->period_s = 1e-3;
    hs_rt_def def = hs_rt_default_def();
    def.tick.fn = counting_tick;
    def.tick.ctx = c;
    return def;
}

static int check_stats(const hs_rt_stats* s, int64_t ticks) {
    ENSURE(s->ticks == ticks);
    ENSURE(hs_rt_hist_total(&s->tick) == (uint64_t)ticks);
    ENSURE(hs_rt_hist_total(&s->period_err) == (uint64_t)ticks);
    double p50 = hs_rt_hist_quantile_us(&s->period_err, 0.5);
    double p99 = hs_rt_hist_quantile_us(&s->period_err, 0.99);
    double mx = (double)s->period_err.max_ns * 1e-3;
    ENSURE(p50 <= p99 && p99 <= mx + 1.0);
    ENSURE(hs_rt_hist_quantile_us(&s->tick, 0.5) <= hs_rt_hist_quantile_us(&s->tick, 0.99));
    ENSURE(s->overruns <= s->missed_deadlines);
    // Every deadline between start and the last wake is either a tick or a skipped deadline
    // (the last tick may have skipped a few more while it ran).
    double deadlines = (double)(s->last_ns - s->start_ns) / (s->period_s * 1e9);
    double slack = 2.0 + (double)s->tick.max_ns / (s->period_s * 1e9);
    ENSURE(fabs((double)(s->ticks + s->missed_deadlines) - deadlines) <= slack);
    return 0;
}

static int print_stats(const char* what, const hs_rt_stats* s) {
    printf("  %s: %lld ticks, fifo %d (prio %d) mlock %d prefault %d, overruns %lld, missed %lld,"
           " period err p50 %.0f p99 %.0f max %.0f us, tick p99 %.0f us, wake late max %.0f us\n",
           what, (long long)s->ticks, (s->obtained & HS_RT_SCHED_FIFO) != 0, s->fifo_priority,
           (s->obtained & HS_RT_MLOCKED) != 0, (s->obtained & HS_RT_PREFAULTED) != 0,
           (long long)s->overruns, (long long)s->missed_deadlines,
           hs_rt_hist_quantile_us(&s->period_err, 0.5),
           hs_rt_hist_quantile_us(&s->period_err, 0.99), (double)s->period_err.max_ns * 1e-3,
           hs_rt_hist_quantile_us(&s->tick, 0.99), (double)s->wake_late_max_ns * 1e-3);
    return 0;
}

static hs_rt_stats g_stats; // 64 kB: keep off the stack

static int LoopTiming(void) {
    int64_t bytes = hs_byte_count();
    hs_err err = {0};
    hs_rt_loop* L = NULL;
    hs_rt_def bad = hs_rt_default_def();
    bad.rate_hz = 0;
    ENSURE(hs_rt_loop_create(&bad, &L, &err) == HS_ERR_INVALID && L == NULL);
    ENSURE(strstr(err.msg, "rate_hz") != NULL);
    bad = hs_rt_default_def();
    bad.cookie = 0;
    ENSURE(hs_rt_loop_create(&bad, &L, &err) == HS_ERR_INVALID);

    count_tick c;
    hs_rt_def def = counting_def(&c);
    ENSURE(hs_rt_loop_create(&def, &L, &err) == HS_OK);
    int64_t t0 = hs_now_ns();
    ENSURE(hs_rt_loop_start(L, &err) == HS_OK);
    ENSURE(hs_rt_loop_start(L, &err) == HS_ERR_INVALID); // once
    sleep_ns(1000000000);
    ENSURE(hs_rt_loop_running(L));
    hs_rt_loop_stop(L);
    double elapsed = (double)(hs_now_ns() - t0) * 1e-9;
    ENSURE(!hs_rt_loop_running(L));
    hs_rt_loop_stats(L, &g_stats);
    print_stats("1 s loop", &g_stats);
    ENSURE(c.n == g_stats.ticks && c.bad_tick == 0 && c.bad_dt == 0);
    ENSURE(check_stats(&g_stats, c.n) == 0);
    // Sane against the wall clock: a quarter of the nominal ticks at least (shared machine),
    // never more than nominal.
    ENSURE(c.n >= (int64_t)(0.25 * elapsed * 1000) && c.n <= (int64_t)(elapsed * 1000) + 1);
    // dt is measured: the sum of dt is the time from start to the last wake.
    ENSURE_NEAR(c.dt_sum, (double)(g_stats.last_ns - g_stats.start_ns) * 1e-9, 1e-6);
    hs_rt_loop_stop(L); // idempotent
    hs_rt_loop_destroy(&L);
    ENSURE(L == NULL);
    hs_rt_loop_destroy(NULL);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

// A stopped loop starts again: the tick count goes on, and the first tick after the restart
// measures its dt from the restart, not across the stop.
static int LoopRestarts(void) {
    int64_t bytes = hs_byte_count();
    count_tick c;
    hs_rt_def def = counting_def(&c);
    hs_rt_loop* L = NULL;
    ENSURE(hs_rt_loop_create(&def, &L, NULL) == HS_OK);
    ENSURE(hs_rt_loop_start(L, NULL) == HS_OK);
    sleep_ns(200000000);
    hs_rt_loop_stop(L);
    int64_t n1 = c.n;
    ENSURE(n1 > 20 && !hs_rt_loop_running(L));
    double dt1 = c.dt_sum;
    sleep_ns(300000000); // the gap a restart must not measure
    int64_t t_restart = hs_now_ns();
    ENSURE(hs_rt_loop_start(L, NULL) == HS_OK);
    ENSURE(hs_rt_loop_start(L, NULL) == HS_ERR_INVALID); // running: once
    sleep_ns(200000000);
    ENSURE(hs_rt_loop_running(L));
    hs_rt_loop_stop(L);
    double run2 = (double)(hs_now_ns() - t_restart) * 1e-9;
    hs_rt_loop_stats(L, &g_stats);
    printf("  %lld ticks before the stop, %lld after the restart; dt sum after %.3f s of %.3f s\n",
           (long long)n1, (long long)(c.n - n1), c.dt_sum - dt1, run2);
    ENSURE(c.n > n1 + 20 && g_stats.ticks == c.n && c.bad_tick == 0);
    ENSURE(c.bad_dt == 1);          // the one tick whose previous wake was before the stop
    ENSURE(c.dt_sum - dt1 <= run2); // no dt spans the 0.3 s gap
    hs_rt_loop_destroy(&L);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

static int LoopOverrunCatchUp(void) {
    count_tick c;
    hs_rt_def def = counting_def(&c);
    c.slow_every = 50;
    c.slow_ns = 3500000; // 3.5 periods
    def.max_ticks = 800;
    hs_rt_loop* L = NULL;
    ENSURE(hs_rt_loop_create(&def, &L, NULL) == HS_OK);
    ENSURE(hs_rt_loop_start(L, NULL) == HS_OK);
    hs_rt_loop_wait(L); // stops by itself
    hs_rt_loop_stats(L, &g_stats);
    print_stats("overrun loop", &g_stats);
    int64_t slow = c.n / c.slow_every;
    ENSURE(c.n == 800 && g_stats.ticks == 800);
    ENSURE(check_stats(&g_stats, c.n) == 0);
    ENSURE(g_stats.overruns >= slow);
    ENSURE(g_stats.missed_deadlines >= 3 * slow);
    ENSURE(hs_rt_hist_quantile_us(&g_stats.tick, 1.0) >= 3500.0);
    // No burst after an overrun: catching up by running the missed ticks back to back would
    // give about three very short periods after each slow tick (a stray late wake-up may give one).
    printf("  %lld slow ticks, %lld ticks with dt < 0.25 ms just after them\n", (long long)slow,
           (long long)c.short_dt);
    ENSURE(c.short_dt <= slow / 4);
    hs_rt_loop_destroy(&L);
    return 0;
}

// The maximum of a window between two snapshots is the window's, not the run's: the server's
// status showed a 30 ms tick in every later window (the cumulative max when the window's
// overflow bin was non-empty).
static int WindowMaxFromSnapshots(void) {
    static hs_rt_hist a, b;
    memset(&a, 0, sizeof a);
    b = a;
    ENSURE(hs_rt_hist_window_max_ns(&b, &a) == 0);
    b.count[10] = 2; // two samples in [10, 11) us
    ENSURE(hs_rt_hist_window_max_ns(&b, &a) == 11000);
    // Overflow samples 1..3 (the 2nd 30 ms) before a, 4 and 5 (5 and 6 ms) between a and b.
    a.count[HS_RT_HIST_BINS] = 3;
    b.count[HS_RT_HIST_BINS] = 5;
    const int64_t ns[6] = {0, 4100000, 30000000, 4200000, 5000000, 6000000};
    for (int k = 1; k <= 5; ++k) {
        b.recent_ns[k % HS_RT_HIST_RECENT] = ns[k];
        b.recent_seq[k % HS_RT_HIST_RECENT] = (uint64_t)k;
    }
    b.max_ns = 30000000;
    ENSURE(hs_rt_hist_window_max_ns(&b, &a) == 6000000);
    b.recent_seq[5 % HS_RT_HIST_RECENT] = 0; // torn: the other one
    ENSURE(hs_rt_hist_window_max_ns(&b, &a) == 5000000);
    b.recent_seq[4 % HS_RT_HIST_RECENT] = 0; // none left: the overflow's lower edge
    ENSURE(hs_rt_hist_window_max_ns(&b, &a) == HS_RT_HIST_BINS * 1000);
    return 0;
}

typedef struct stall_tick {
    _Atomic int64_t n;
} stall_tick;

// Tick 5 takes 30 ms, tick 600 takes 5 ms, the others nothing.
static void stalling_tick(void* ctx, const hs_rt_clock* clk) {
    (void)clk;
    stall_tick* c = ctx;
    int64_t n = atomic_fetch_add(&c->n, 1) + 1;
    int64_t ns = n == 5 ? 30000000 : n == 600 ? 5000000 : 0;
    int64_t until = hs_now_ns() + ns;
    while (ns && hs_now_ns() < until) {
    }
}

// The same through the rt loop's own histograms.
static int LoopWindowMax(void) {
    static hs_rt_stats older, newer;
    stall_tick c = {0};
    hs_rt_def def = hs_rt_default_def();
    def.tick.fn = stalling_tick;
    def.tick.ctx = &c;
    def.max_ticks = 700;
    hs_rt_loop* L = NULL;
    ENSURE(hs_rt_loop_create(&def, &L, NULL) == HS_OK);
    ENSURE(hs_rt_loop_start(L, NULL) == HS_OK);
    int64_t end = hs_now_ns() + 5000000000LL; // the first window: up to the 30 ms tick
    do {
        struct timespec ts = {0, 5000000};
        nanosleep(&ts, NULL);
        hs_rt_loop_stats(L, &older);
    } while (atomic_load(&c.n) < 50 && hs_now_ns() < end);
    hs_rt_loop_wait(L);
    hs_rt_loop_stats(L, &newer);
    hs_rt_loop_destroy(&L);
    int64_t w = hs_rt_hist_window_max_ns(&newer.tick, &older.tick);
    printf("  tick max: run %.2f ms, second window (ticks %lld..%lld) %.2f ms\n",
           (double)newer.tick.max_ns * 1e-6, (long long)older.ticks, (long long)newer.ticks,
           (double)w * 1e-6);
    ENSURE(older.tick.count[HS_RT_HIST_BINS] == 1 && older.ticks < 600);
    ENSURE(newer.tick.count[HS_RT_HIST_BINS] == 2 && newer.tick.max_ns >= 30000000);
    ENSURE(w >= 5000000 && w < 25000000);
    return 0;
}

static int BareLoop(void) {
    hs_rt_def def = hs_rt_default_def();
    hs_err err = {0};
    ENSURE(hs_rt_bare_loop(&def, 0, &g_stats, &err) == HS_ERR_INVALID);
    ENSURE(hs_rt_bare_loop(&def, 300, &g_stats, &err) == HS_OK);
    print_stats("bare loop", &g_stats);
    ENSURE(check_stats(&g_stats, 300) == 0);
    // Pooling two segments: counts add up, worst cases are kept.
    static hs_rt_stats acc, second;
    memset(&acc, 0, sizeof acc);
    hs_rt_stats_accumulate(&acc, &g_stats);
    ENSURE(hs_rt_bare_loop(&def, 100, &second, &err) == HS_OK);
    hs_rt_stats_accumulate(&acc, &second);
    ENSURE(acc.ticks == 400 && hs_rt_hist_total(&acc.period_err) == 400);
    ENSURE(acc.period_err.max_ns == (g_stats.period_err.max_ns > second.period_err.max_ns
                                         ? g_stats.period_err.max_ns
                                         : second.period_err.max_ns));
    ENSURE(acc.start_ns == g_stats.start_ns && acc.last_ns == second.last_ns);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// The haptic tick end to end: memory device, model source, telemetry.

typedef struct rig {
    hs_memdev* dev;
    hs_model_source* src;
    hs_haptic_rt* hap;
    hs_rt_loop* loop;
    hs_haptic_rt_def hdef;
    int64_t pose_seq;
    int64_t model_seq;
} rig;

static int rig_create(rig* r, size_t telemetry_capacity) {
    memset(r, 0, sizeof *r);
    ENSURE(hs_memdev_create(&r->dev, NULL) == HS_OK);
    ENSURE(hs_model_source_create(&r->src, NULL) == HS_OK);
    r->hdef = hs_haptic_rt_default_def();
    r->hdef.device = hs_memdev_device(r->dev);
    r->hdef.source = hs_model_source_source(r->src);
    r->hdef.telemetry_capacity = telemetry_capacity;
    ENSURE(hs_haptic_rt_create(&r->hdef, &r->hap, NULL) == HS_OK);
    hs_rt_def def = hs_rt_default_def();
    def.tick = hs_haptic_rt_tick(r->hap);
    def.tick.on_start = count_on;
    def.tick.on_stop = count_off;
    ENSURE(hs_rt_loop_create(&def, &r->loop, NULL) == HS_OK);
    return 0;
}

static void rig_destroy(rig* r) {
    hs_rt_loop_destroy(&r->loop);
    hs_haptic_rt_destroy(&r->hap);
    hs_model_source_destroy(&r->src);
    hs_memdev_destroy(&r->dev);
}

static void tool_at(double t, double p[3]) {
    p[0] = 0.004 * sin(5 * t);
    p[1] = 0.003 * cos(3 * t);
    p[2] = 0.002 * sin(7 * t);
}

static void feed(rig* r, double t, int nan_pose) {
    hs_haptic_pose p;
    memset(&p, 0, sizeof p);
    p.seq = ++r->pose_seq;
    p.stamp_ns = hs_now_ns();
    tool_at(t, p.pos_m);
    p.quat_wxyz[0] = 1;
    if (nan_pose) p.pos_m[1] = NAN;
    hs_memdev_feed_pose(r->dev, &p);
}

static void publish_model(rig* r, int nan_force) {
    hs_haptic_model m = random_model(++r->model_seq);
    m.force_n[2] += 3.0;                            // clearly nonzero at the tool
    if (r->model_seq % 5 == 0) m.force_n[2] = 40.0; // beyond the magnitude clamp
    if (nan_force) m.force_n[0] = NAN;
    m.stamp_ns = hs_now_ns();
    hs_model_source_publish(r->src, &m);
}

#define MAX_TEL 16384
static hs_haptic_telemetry g_tel[MAX_TEL];

// Feed poses at ~1 kHz (this thread is not real-time) and a new model every 20 ms, for the given
// time; pose_gap skips feeding; nan_pose / nan_model inject one bad input at the start.
static int drive(rig* r, double seconds, int feed_poses, int nan_pose, int nan_model, int* n_tel,
                 int64_t* t_first_ns) {
    int64_t t0 = hs_now_ns();
    *t_first_ns = t0;
    int64_t next_model = t0;
    int first = 1;
    hs_spsc_ring* ring = hs_haptic_rt_telemetry(r->hap);
    for (;;) {
        int64_t now = hs_now_ns();
        if (now - t0 > (int64_t)(seconds * 1e9)) break;
        if (now >= next_model) {
            publish_model(r, first && nan_model);
            next_model += 20000000;
        }
        if (feed_poses) feed(r, (double)now * 1e-9, first && nan_pose);
        if (first && nan_pose) {
            // Newest wins: let the rt thread take the bad pose before a good one replaces it.
            hs_haptic_rt_counters c;
            for (int i = 0; i < 1000; ++i) {
                hs_haptic_rt_get_counters(r->hap, &c);
                if (c.safety.nonfinite_pose > 0) break;
                sleep_ns(100000);
            }
        }
        first = 0;
        while (*n_tel < MAX_TEL && hs_spsc_ring_pop(ring, &g_tel[*n_tel])) ++*n_tel;
        sleep_ns(1000000);
    }
    return 0;
}

static int HapticLoop(void) {
    int64_t bytes = hs_byte_count();
    rig r;
    ENSURE(rig_create(&r, 8192) == 0);
    hs_haptic_rt_def bad = r.hdef;
    bad.source.eval = NULL;
    hs_haptic_rt* h = NULL;
    hs_err err = {0};
    ENSURE(hs_haptic_rt_create(&bad, &h, &err) == HS_ERR_INVALID && h == NULL);
    ENSURE(strstr(err.msg, "source") != NULL);
    const hs_safety_def sd = r.hdef.safety;

    int n = 0;
    int64_t t_a, t_stop, t_resume, t_nanpose, t_nanmodel;
    ENSURE(hs_rt_loop_start(r.loop, NULL) == HS_OK);
    sleep_ns(20000000);                                     // no device yet
    ENSURE(drive(&r, 0.40, 1, 0, 0, &n, &t_a) == 0);        // normal, model switches
    ENSURE(drive(&r, 0.15, 0, 0, 0, &n, &t_stop) == 0);     // poses stop
    ENSURE(drive(&r, 0.20, 1, 0, 0, &n, &t_resume) == 0);   // poses resume
    ENSURE(drive(&r, 0.10, 1, 1, 0, &n, &t_nanpose) == 0);  // one NaN pose
    ENSURE(drive(&r, 0.10, 1, 0, 1, &n, &t_nanmodel) == 0); // one NaN model (20 ms)
    hs_rt_loop_stop(r.loop);
    hs_spsc_ring* ring = hs_haptic_rt_telemetry(r.hap);
    while (n < MAX_TEL && hs_spsc_ring_pop(ring, &g_tel[n])) ++n;
    hs_rt_loop_stats(r.loop, &g_stats);
    print_stats("haptic loop", &g_stats);
    hs_haptic_rt_counters c;
    hs_haptic_rt_get_counters(r.hap, &c);
    printf("  %lld ticks, %lld poses, %lld blends, nan pose %lld, nan force %lld, rate %lld, "
           "magnitude %lld, watchdog trips %lld, telemetry dropped %lld\n",
           (long long)c.ticks, (long long)c.poses, (long long)c.blends,
           (long long)c.safety.nonfinite_pose, (long long)c.safety.nonfinite_force,
           (long long)c.safety.rate, (long long)c.safety.magnitude,
           (long long)c.safety.watchdog_trips, (long long)c.telemetry_dropped);

    // Telemetry: one record per tick, none dropped, in order.
    ENSURE(c.telemetry_dropped == 0 && n == (int)c.ticks && c.ticks == g_stats.ticks);
    for (int i = 0; i < n; ++i) ENSURE(g_tel[i].tick == i);
    // Counters: the injected faults are seen exactly once each; the source changed many times.
    ENSURE(c.safety.nonfinite_pose == 1);
    ENSURE(c.safety.nonfinite_force >= 1);
    ENSURE(c.safety.watchdog_trips >= 1);
    ENSURE(c.blends >= 10);
    ENSURE(c.safety.magnitude > 0 && c.safety.rate > 0); // the clamps were exercised
    ENSURE(c.poses >= 100 && c.stale_poses == 0 && c.device_errors == 0);

    int64_t zero_after = 0, last_fresh_before_stop = 0, nonzero_before_stop = 0;
    int64_t nonzero_after_resume = 0, nan_pose_zero = 0, nan_model_zero = 0;
    for (int i = 0; i < n; ++i) {
        const hs_haptic_telemetry* t = &g_tel[i];
        double fm = norm3(t->force_n);
        // Clamps hold on every tick.
        ENSURE(fm <= sd.max_force_n + 1e-9);
        // Rate clamp (plus the watchdog ramp) holds on every tick except a fault, which zeroes
        // at once.
        if (i > 0 && !(t->safety & HS_SAFETY_NONFINITE))
            ENSURE(dist3(t->force_n, g_tel[i - 1].force_n) <=
                   (sd.max_rate_n_s + sd.max_force_n / sd.ramp_s) * t->dt_s + 1e-9);
        // No device before the first pose: zero.
        if (t->pose_seq == 0) ENSURE(fm == 0);
        if (t->now_ns < t_resume && t->pose_new) last_fresh_before_stop = t->now_ns;
        if (t->now_ns > t_a + 100000000 && t->now_ns < t_stop) nonzero_before_stop += fm > 0.5;
        if (t->now_ns > t_resume + 50000000 && t->now_ns < t_nanpose)
            nonzero_after_resume += fm > 0.5;
        if ((t->safety & HS_SAFETY_NONFINITE) && t->now_ns >= t_nanpose && t->now_ns < t_nanmodel) {
            ENSURE(fm == 0);
            ++nan_pose_zero;
        }
        if ((t->safety & HS_SAFETY_NONFINITE) && t->now_ns >= t_nanmodel) {
            ENSURE(fm == 0);
            ++nan_model_zero;
        }
    }
    ENSURE(nonzero_before_stop > 50 && nonzero_after_resume > 20);
    ENSURE(nan_pose_zero == 1 && nan_model_zero >= 1);
    // Watchdog: zero from the last fresh pose + timeout + ramp on, until poses resume.
    int64_t limit = last_fresh_before_stop + (int64_t)((sd.watchdog_timeout_s + sd.ramp_s) * 1e9);
    for (int i = 0; i < n; ++i) {
        const hs_haptic_telemetry* t = &g_tel[i];
        if (t->now_ns >= limit && t->now_ns < t_resume) {
            ENSURE(t->force_n[0] == 0 && t->force_n[1] == 0 && t->force_n[2] == 0);
            ENSURE(t->gain == 0);
            ++zero_after;
        }
    }
    printf("  watchdog: %lld zero-force ticks after timeout + ramp\n", (long long)zero_after);
    ENSURE(zero_after >= 50);
    // The device saw the last output.
    hs_haptic_output out;
    ENSURE(hs_memdev_take_output(r.dev, &out) == 1);
    ENSURE(out.seq == n - 1 && out.force_n[2] == g_tel[n - 1].force_n[2]);
    ENSURE(out.model.force_n[2] == out.force_n[2] &&
           out.model.anchor_m[0] == g_tel[n - 1].tool_m[0]);
    rig_destroy(&r);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

// Check that the allocation counter sees an allocation on the rt thread (so zero means zero).
#if HS_COUNT_MALLOC
static void allocating_tick(void* ctx, const hs_rt_clock* clk) {
    if (clk->tick == 3) {
        void* volatile p = hs_alloc(64);
        hs_free(p);
    }
    (void)ctx;
}
#endif

static int AllocCounterWorks(void) {
#if HS_COUNT_MALLOC
    hs_rt_def def = hs_rt_default_def();
    def.tick.fn = allocating_tick;
    def.tick.on_start = count_on;
    def.tick.on_stop = count_off;
    def.max_ticks = 10;
    hs_rt_loop* L = NULL;
    ENSURE(hs_rt_loop_create(&def, &L, NULL) == HS_OK);
    atomic_store(&g_rt_allocs, 0);
    ENSURE(hs_rt_loop_start(L, NULL) == HS_OK);
    hs_rt_loop_wait(L);
    long long seen = atomic_load(&g_rt_allocs);
    hs_rt_loop_destroy(&L);
    ENSURE(seen == 2); // one malloc, one free
#else
    printf("  sanitizer build: malloc is not interposed here\n");
#endif
    return 0;
}

static int ZeroAlloc(void) {
    double seconds = env_seconds("HS_RT_SECONDS", 2.0);
    rig r;
    ENSURE(rig_create(&r, 8192) == 0);
    atomic_store(&g_rt_allocs, 0);
    int64_t hs_calls = hs_alloc_calls();
    ENSURE(hs_rt_loop_start(r.loop, NULL) == HS_OK);
    // Poses and model switches throughout; telemetry drained as it comes.
    int64_t t0 = hs_now_ns(), next_model = t0;
    hs_spsc_ring* ring = hs_haptic_rt_telemetry(r.hap);
    hs_haptic_telemetry tel;
    int64_t popped = 0;
    while (hs_now_ns() - t0 < (int64_t)(seconds * 1e9)) {
        int64_t now = hs_now_ns();
        if (now >= next_model) {
            publish_model(&r, 0);
            next_model += 10000000;
        }
        feed(&r, (double)now * 1e-9, 0);
        while (hs_spsc_ring_pop(ring, &tel)) ++popped;
        sleep_ns(1000000);
    }
    hs_rt_loop_stop(r.loop);
    while (hs_spsc_ring_pop(ring, &tel)) ++popped;
    hs_rt_loop_stats(r.loop, &g_stats);
    hs_haptic_rt_counters c;
    hs_haptic_rt_get_counters(r.hap, &c);
    long long allocs = atomic_load(&g_rt_allocs);
    printf(
        "  %.1f s: %lld ticks, %lld blends, %lld telemetry records, rt-thread allocations %lld%s\n",
        seconds, (long long)c.ticks, (long long)c.blends, (long long)popped, allocs,
        HS_COUNT_MALLOC ? "" : " (not interposed: sanitizer build)");
    print_stats("zero-alloc loop", &g_stats);
    ENSURE(c.ticks >= (int64_t)(seconds * 250) && popped == c.ticks);
    ENSURE(c.blends >= (int64_t)(seconds * 20));
    ENSURE(allocs == 0);
    ENSURE(hs_alloc_calls() == hs_calls); // nor through hs_alloc on any thread
    rig_destroy(&r);
    return 0;
}

// Every allocation in the set-up can fail: a clean error, nothing leaked.
static int CreateFailures(void) {
    int64_t bytes = hs_byte_count();
    int ok = 0;
    for (int k = 1; k <= 40 && !ok; ++k) {
        hs_memdev* dev = NULL;
        hs_model_source* src = NULL;
        hs_haptic_rt* hap = NULL;
        hs_rt_loop* loop = NULL;
        hs_err err = {0};
        hs_alloc_fail_after(k);
        hs_status st = hs_memdev_create(&dev, &err);
        if (st == HS_OK) st = hs_model_source_create(&src, &err);
        if (st == HS_OK) {
            hs_haptic_rt_def hd = hs_haptic_rt_default_def();
            hd.device = hs_memdev_device(dev);
            hd.source = hs_model_source_source(src);
            st = hs_haptic_rt_create(&hd, &hap, &err);
        }
        if (st == HS_OK) {
            hs_rt_def rd = hs_rt_default_def();
            rd.tick = hs_haptic_rt_tick(hap);
            st = hs_rt_loop_create(&rd, &loop, &err);
        }
        hs_alloc_fail_after(0);
        ENSURE(st == HS_OK || (st == HS_ERR_NOMEM && strstr(err.msg, "out of memory") != NULL));
        ok = st == HS_OK;
        hs_rt_loop_destroy(&loop);
        hs_haptic_rt_destroy(&hap);
        hs_model_source_destroy(&src);
        hs_memdev_destroy(&dev);
        ENSURE(hs_byte_count() == bytes);
    }
    ENSURE(ok); // a late enough failure point lets everything succeed
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Take-over: a new rt loop goes on from an old one's last force.

typedef struct fixed_src {
    hs_haptic_model m;
} fixed_src;

static void fixed_eval(void* ctx, const hs_rt_clock* clk, const hs_haptic_pose* pose,
                       hs_haptic_model* out) {
    (void)clk;
    hs_haptic_model_reanchor(&((fixed_src*)ctx)->m, pose->pos_m, out);
}

typedef struct tdrive {
    hs_memdev* dev;
    fixed_src src;
    hs_haptic_rt* h;
    hs_rt_tick tick;
} tdrive;

static int tdrive_create(tdrive* d) {
    memset(d, 0, sizeof *d);
    ENSURE(hs_memdev_create(&d->dev, NULL) == HS_OK);
    hs_haptic_rt_def def = hs_haptic_rt_default_def();
    def.device = hs_memdev_device(d->dev);
    def.source.eval = fixed_eval;
    def.source.ctx = &d->src;
    ENSURE(hs_haptic_rt_create(&def, &d->h, NULL) == HS_OK);
    d->tick = hs_haptic_rt_tick(d->h);
    return 0;
}

static void tdrive_destroy(tdrive* d) {
    hs_haptic_rt_destroy(&d->h);
    hs_memdev_destroy(&d->dev);
}

// One tick at t (ns) with a fresh pose at the origin; the force's z.
static double tdrive_step(tdrive* d, int64_t* seq, int64_t t) {
    hs_haptic_pose p;
    memset(&p, 0, sizeof p);
    p.seq = ++*seq;
    p.stamp_ns = t;
    p.quat_wxyz[0] = 1;
    hs_memdev_feed_pose(d->dev, &p);
    hs_rt_clock c = {*seq, t, t, 1e-3};
    d->tick.fn(d->tick.ctx, &c);
    hs_haptic_output o;
    memset(&o, 0, sizeof o);
    hs_memdev_take_output(d->dev, &o);
    return o.force_n[2];
}

// The old loop stops in the middle of a blend (0 -> 2 N, half way): the new one, holding the
// old one's last model, goes on from the last force, not back toward the blend's start (found
// in review: 1.0 N, then 0.6, 0.7, ... 1.0 N; a step of 0.4 N where the blend allows 0.2 N).
static int TakeOverMidBlend(void) {
    tdrive a, b;
    ENSURE(tdrive_create(&a) == 0 && tdrive_create(&b) == 0);
    int64_t seq = 0, t = 1000000000;
    a.src.m.seq = 1;
    a.src.m.radius_m = 0.01;
    a.src.m.timeout_s = 1;
    double f = 0;
    for (int i = 0; i < 300; ++i) f = tdrive_step(&a, &seq, t += 1000000); // watchdog at full
    ENSURE(fabs(f) < 1e-12);
    a.src.m.seq = 2;
    a.src.m.force_n[2] = 2.0;
    int half = hs_haptic_rt_default_def().blend_ticks / 2;
    for (int i = 0; i < half; ++i) f = tdrive_step(&a, &seq, t += 1000000);
    ENSURE(f > 0.5 && f < 1.5);
    hs_haptic_model held;
    hs_haptic_rt_take_over(b.h, a.h, &held);
    b.src.m = held; // what the new sim's source answers until its first snapshot
    double prev = f;
    for (int i = 0; i < 20; ++i) {
        double g = tdrive_step(&b, &seq, t += 1000000);
        if (fabs(g - f) > 1e-9)
            printf("  tick %d after the take-over: %.4f N (last %.4f)\n", i, g, f);
        ENSURE(fabs(g - f) <= 1e-9 && fabs(g - prev) <= 1e-9);
        prev = g;
    }
    // The new sim's first snapshot then blends in from there.
    b.src.m.seq = 1;
    b.src.m.force_n[2] = 3.0;
    int ticks = hs_haptic_rt_default_def().blend_ticks;
    for (int i = 0; i < ticks; ++i) {
        double g = tdrive_step(&b, &seq, t += 1000000);
        ENSURE(g - prev <= (3.0 - f) / ticks + 1e-9 && g >= prev - 1e-12);
        prev = g;
    }
    ENSURE(fabs(prev - 3.0) < 1e-9);
    tdrive_destroy(&a);
    tdrive_destroy(&b);
    return 0;
}

HS_TEST_MAIN(HS_CASE(CreateFailures), HS_CASE(ModelEval), HS_CASE(BlendNeverJumps), HS_CASE(Clamps),
             HS_CASE(WatchdogRamps), HS_CASE(SafetyChain), HS_CASE(LoopTiming),
             HS_CASE(LoopRestarts), HS_CASE(LoopOverrunCatchUp), HS_CASE(WindowMaxFromSnapshots),
             HS_CASE(LoopWindowMax), HS_CASE(BareLoop), HS_CASE(HapticLoop),
             HS_CASE(AllocCounterWorks), HS_CASE(ZeroAlloc), HS_CASE(TakeOverMidBlend))
