// SPDX-License-Identifier: GPL-2.0-or-later
// Local model evaluation, blending, safety filters and histogram percentiles (haptic.h).
// All pure functions over caller-owned state: safe on the rt thread (no allocation, no locks).
#include "haptic.h"
#include "base.h"

#include <math.h>
#include <string.h>

#define SAFETY_COOKIE 0x5afe7

static void mat3_vec(const double k[9], const double v[3], double out[3]) {
    for (int i = 0; i < 3; ++i)
        out[i] = k[3 * i] * v[0] + k[3 * i + 1] * v[1] + k[3 * i + 2] * v[2];
}

static double norm3(const double v[3]) {
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

// Offset from the anchor at which the model is evaluated: p - a, pulled back onto the validity
// sphere when outside. Returns 1 when inside; *dist gets |p - a|.
static int model_offset(const hs_haptic_model* m, const double p[3], double d[3], double* dist) {
    for (int i = 0; i < 3; ++i) d[i] = p[i] - m->anchor_m[i];
    double n = norm3(d);
    *dist = n;
    double r = m->radius_m > 0 ? m->radius_m : 0;
    if (n <= r) return 1;
    double s = n > 0 ? r / n : 0;
    for (int i = 0; i < 3; ++i) d[i] *= s;
    return 0;
}

int hs_haptic_model_eval(const hs_haptic_model* m, const double tool_m[3], double f_n[3]) {
    double d[3], dist, kd[3];
    int inside = model_offset(m, tool_m, d, &dist);
    mat3_vec(m->stiffness_n_m, d, kd);
    for (int i = 0; i < 3; ++i) f_n[i] = m->force_n[i] - kd[i];
    return inside;
}

void hs_haptic_model_reanchor(const hs_haptic_model* m, const double tool_m[3],
                              hs_haptic_model* out) {
    double d[3], dist, kd[3];
    int inside = model_offset(m, tool_m, d, &dist);
    mat3_vec(m->stiffness_n_m, d, kd);
    hs_haptic_model r = *m;
    for (int i = 0; i < 3; ++i) {
        r.force_n[i] = m->force_n[i] - kd[i];
        r.anchor_m[i] = tool_m[i];
    }
    double left = (m->radius_m > 0 ? m->radius_m : 0) - dist;
    r.radius_m = left > 0 ? left : 0;
    // On or beyond the sphere the force no longer changes with the tool position.
    if (!inside || r.radius_m == 0) memset(r.stiffness_n_m, 0, sizeof r.stiffness_n_m);
    *out = r;
}

int hs_haptic_model_finite(const hs_haptic_model* m) {
    int ok = isfinite(m->radius_m) && isfinite(m->timeout_s);
    for (int i = 0; i < 3; ++i) ok &= isfinite(m->force_n[i]) && isfinite(m->anchor_m[i]);
    for (int i = 0; i < 9; ++i) ok &= isfinite(m->stiffness_n_m[i]);
    return ok;
}

double hs_haptic_model_stiffness_bound(const hs_haptic_model* m) {
    // ||K||_2 <= sqrt(||K||_1 ||K||_inf) for any K; the contact K is not symmetric, so the row
    // sums alone are not a bound (1.11x short, measured on a slab's edge).
    const double* k = m->stiffness_n_m;
    double row = 0, col = 0;
    for (int i = 0; i < 3; ++i) {
        row = fmax(row, fabs(k[3 * i]) + fabs(k[3 * i + 1]) + fabs(k[3 * i + 2]));
        col = fmax(col, fabs(k[i]) + fabs(k[3 + i]) + fabs(k[6 + i]));
    }
    return sqrt(row * col);
}

// ---------------------------------------------------------------------------------------------
// Blend

void hs_haptic_blend_init(hs_haptic_blend* b, int ticks) {
    HS_ASSERT(ticks >= 1);
    memset(b, 0, sizeof *b);
    b->ticks = ticks >= 1 ? ticks : 1;
    b->done = b->ticks;
}

void hs_haptic_blend_reset(hs_haptic_blend* b) {
    hs_haptic_blend_init(b, b->ticks);
}

void hs_haptic_blend_step(hs_haptic_blend* b, const hs_haptic_model* target, const double tool_m[3],
                          double f_n[3], hs_haptic_model* out) {
    if (!b->started || target->seq != b->target_seq) {
        // Freeze what is being output now (already anchored at the last tool position); the new
        // target is reached over b->ticks from there.
        b->from = b->last;
        b->target_seq = target->seq;
        b->done = 0;
        b->started = 1;
    }
    if (b->done < b->ticks) ++b->done;
    double w = (double)b->done / (double)b->ticks;

    hs_haptic_model tgt;
    hs_haptic_model_reanchor(target, tool_m, &tgt);
    hs_haptic_model mix = tgt;
    if (b->done < b->ticks) {
        hs_haptic_model old;
        hs_haptic_model_reanchor(&b->from, tool_m, &old);
        for (int i = 0; i < 3; ++i) mix.force_n[i] = (1 - w) * old.force_n[i] + w * tgt.force_n[i];
        for (int i = 0; i < 9; ++i)
            mix.stiffness_n_m[i] = (1 - w) * old.stiffness_n_m[i] + w * tgt.stiffness_n_m[i];
        mix.radius_m = old.radius_m < tgt.radius_m ? old.radius_m : tgt.radius_m;
    }
    for (int i = 0; i < 3; ++i) f_n[i] = mix.force_n[i];
    b->last = mix;
    if (out) *out = mix;
}

// ---------------------------------------------------------------------------------------------
// Safety filters

int hs_vec3_finite(const double v[3]) {
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

int hs_force_guard_finite(double f_n[3], int64_t* count) {
    if (hs_vec3_finite(f_n)) return 0;
    f_n[0] = f_n[1] = f_n[2] = 0;
    if (count) ++*count;
    return 1;
}

int hs_force_clamp_magnitude(double f_n[3], double max_n) {
    double n = norm3(f_n);
    if (n <= max_n) return 0;
    if (isinf(n) && hs_vec3_finite(f_n)) { // squares overflow: scale first, keep the direction
        double a = fmax(fabs(f_n[0]), fmax(fabs(f_n[1]), fabs(f_n[2])));
        for (int i = 0; i < 3; ++i) f_n[i] /= a;
        n = norm3(f_n);
    }
    double s = max_n > 0 ? max_n / n : 0;
    for (int i = 0; i < 3; ++i) f_n[i] *= s;
    return 1;
}

int hs_rate_clamp_apply(hs_rate_clamp* rc, double f_n[3], double dt_s) {
    double d[3] = {f_n[0] - rc->prev_n[0], f_n[1] - rc->prev_n[1], f_n[2] - rc->prev_n[2]};
    double step = rc->max_rate_n_s * (dt_s > 0 ? dt_s : 0);
    double n = norm3(d);
    int clamped = 0;
    if (n > step && isfinite(n)) {
        double s = n > 0 ? step / n : 0;
        for (int i = 0; i < 3; ++i) f_n[i] = rc->prev_n[i] + d[i] * s;
        clamped = 1;
    } else if (n > step) { // the difference overflowed (found in review: Inf * 0 gave NaN)
        double h[3], a = 0;
        for (int i = 0; i < 3; ++i) {
            h[i] = 0.5 * f_n[i] - 0.5 * rc->prev_n[i];
            a = fmax(a, fabs(h[i]));
        }
        if (a > 0 && isfinite(a)) {
            for (int i = 0; i < 3; ++i) h[i] /= a;
            double s = step / norm3(h);
            for (int i = 0; i < 3; ++i) f_n[i] = rc->prev_n[i] + h[i] * s;
        } else {
            memcpy(f_n, rc->prev_n, sizeof rc->prev_n); // not finite: hold
        }
        clamped = 1;
    }
    memcpy(rc->prev_n, f_n, sizeof rc->prev_n);
    return clamped;
}

void hs_watchdog_init(hs_watchdog* w, double timeout_s, double ramp_s) {
    memset(w, 0, sizeof *w);
    w->timeout_s = timeout_s;
    w->ramp_s = ramp_s;
}

double hs_watchdog_update(hs_watchdog* w, int fresh, int64_t now_ns, double dt_s) {
    double up = w->ramp_s > 0 ? dt_s / w->ramp_s : 1;
    if (fresh) {
        w->last_fresh_ns = now_ns;
        w->seen = 1;
        w->live = 1;
        w->gain = fmin(1.0, w->gain + up);
        return w->gain;
    }
    if (!w->seen) return w->gain = 0;
    double stale = (double)(now_ns - w->last_fresh_ns) * 1e-9 - w->timeout_s;
    if (stale > 0) {
        if (w->live) ++w->trips;
        w->live = 0;
        // A function of time, not of tick count: zero exactly at timeout + ramp however late
        // the ticks come.
        double g = w->ramp_s > 0 ? 1 - stale / w->ramp_s : 0;
        if (g < 0) g = 0;
        if (g < w->gain) w->gain = g;
    } else if (w->live) {
        w->gain = fmin(1.0, w->gain + up); // a device slower than the loop keeps ramping in
    }
    return w->gain;
}

void hs_watchdog_trip(hs_watchdog* w) {
    w->gain = 0;
    w->live = 0; // back only with a fresh pose, not by the slow-device ramp
}

hs_safety_def hs_safety_default_def(void) {
    hs_safety_def d;
    d.max_force_n = 10.0;
    d.max_rate_n_s = 2000.0;
    d.watchdog_timeout_s = 0.050;
    d.ramp_s = 0.010;
    d.step_period_s = 0;
    d.cookie = SAFETY_COOKIE;
    return d;
}

int hs_safety_def_valid(const hs_safety_def* d) {
    return d && d->cookie == SAFETY_COOKIE && isfinite(d->max_force_n) && d->max_force_n >= 0 &&
           isfinite(d->max_rate_n_s) && d->max_rate_n_s >= 0 && isfinite(d->watchdog_timeout_s) &&
           d->watchdog_timeout_s >= 0 && isfinite(d->ramp_s) && d->ramp_s > 0 &&
           isfinite(d->step_period_s) && d->step_period_s >= 0;
}

void hs_safety_init(hs_safety* s, const hs_safety_def* def) {
    HS_ASSERT(hs_safety_def_valid(def));
    memset(s, 0, sizeof *s);
    s->def = *def;
    hs_watchdog_init(&s->watchdog, def->watchdog_timeout_s, def->ramp_s);
    s->rate.max_rate_n_s = def->max_rate_n_s;
}

void hs_safety_set_limits(hs_safety* s, const hs_safety_def* def) {
    HS_ASSERT(hs_safety_def_valid(def));
    s->def = *def;
    s->watchdog.timeout_s = def->watchdog_timeout_s;
    s->watchdog.ramp_s = def->ramp_s;
    s->rate.max_rate_n_s = def->max_rate_n_s;
}

static uint32_t safety_zero(hs_safety* s, double f_n[3]) {
    f_n[0] = f_n[1] = f_n[2] = 0;
    memset(s->rate.prev_n, 0, sizeof s->rate.prev_n);
    hs_watchdog_trip(&s->watchdog); // ramp back in, never step back to full force
    return HS_SAFETY_NONFINITE | HS_SAFETY_WATCHDOG;
}

uint32_t hs_safety_apply(hs_safety* s, double f_n[3], int pose_fresh, int pose_ok, int64_t now_ns,
                         double dt_s) {
    if (!pose_ok) {
        ++s->counters.nonfinite_pose;
        return safety_zero(s, f_n);
    }
    double gain = hs_watchdog_update(&s->watchdog, pose_fresh, now_ns, dt_s);
    s->counters.watchdog_trips = s->watchdog.trips;
    if (hs_force_guard_finite(f_n, &s->counters.nonfinite_force)) return safety_zero(s, f_n);
    uint32_t flags = 0;
    if (hs_force_clamp_magnitude(f_n, s->def.max_force_n)) {
        flags |= HS_SAFETY_MAGNITUDE;
        ++s->counters.magnitude;
    }
    if (gain < 1) flags |= HS_SAFETY_WATCHDOG;
    for (int i = 0; i < 3; ++i) f_n[i] *= gain;
    if (gain == 0) { // the watchdog alone decides when the force is zero
        memset(s->rate.prev_n, 0, sizeof s->rate.prev_n);
        f_n[0] = f_n[1] = f_n[2] = 0;
        return flags;
    }
    // The rate clamp comes after the gain, on the force that is sent: a gain ramp or a new
    // model reaches the output at the rate limit (the gain ramp itself is slower
    // than the rate limit at full force for the defaults; before, gain and rate steps added up).
    const double step_dt =
        s->def.step_period_s > 0 && dt_s > s->def.step_period_s ? s->def.step_period_s : dt_s;
    if (hs_rate_clamp_apply(&s->rate, f_n, step_dt)) {
        flags |= HS_SAFETY_RATE;
        ++s->counters.rate;
    }
    // The magnitude limit is hard: a limit lowered under a force the rate clamp still holds
    // above it is met at once (a step down), not at the rate limit.
    if (hs_force_clamp_magnitude(f_n, s->def.max_force_n)) {
        if (!(flags & HS_SAFETY_MAGNITUDE)) ++s->counters.magnitude;
        flags |= HS_SAFETY_MAGNITUDE;
        memcpy(s->rate.prev_n, f_n, sizeof s->rate.prev_n);
    }
    return flags;
}

// ---------------------------------------------------------------------------------------------
// Histograms

uint64_t hs_rt_hist_total(const hs_rt_hist* h) {
    uint64_t n = 0;
    for (int i = 0; i <= HS_RT_HIST_BINS; ++i) n += h->count[i];
    return n;
}

double hs_rt_hist_quantile_us(const hs_rt_hist* h, double q) {
    uint64_t n = hs_rt_hist_total(h);
    if (n == 0) return 0;
    if (!(q > 0)) q = 0;
    if (q > 1) q = 1;
    uint64_t rank = (uint64_t)ceil(q * (double)n);
    if (rank < 1) rank = 1;
    uint64_t cum = 0;
    for (int i = 0; i < HS_RT_HIST_BINS; ++i) {
        cum += h->count[i];
        if (cum >= rank) return (double)(i + 1);
    }
    return (double)h->max_ns * 1e-3;
}

int64_t hs_rt_hist_window_max_ns(const hs_rt_hist* newer, const hs_rt_hist* older) {
    const uint64_t lo = older->count[HS_RT_HIST_BINS], hi = newer->count[HS_RT_HIST_BINS];
    if (hi > lo) {
        int64_t m = 0;
        for (int k = 0; k < HS_RT_HIST_RECENT; ++k) {
            uint64_t seq = newer->recent_seq[k];
            if (seq > lo && seq <= hi && newer->recent_ns[k] > m) m = newer->recent_ns[k];
        }
        // A torn or overwritten ring: at least the overflow's lower edge.
        return m > 0 ? m : (int64_t)HS_RT_HIST_BINS * 1000;
    }
    for (int i = HS_RT_HIST_BINS - 1; i >= 0; --i)
        if (newer->count[i] > older->count[i]) return (int64_t)(i + 1) * 1000;
    return 0;
}

void hs_rt_stats_accumulate(hs_rt_stats* acc, const hs_rt_stats* s) {
    int empty = acc->ticks == 0 && acc->start_ns == 0;
    acc->obtained = empty ? s->obtained : (acc->obtained & s->obtained);
    acc->fifo_priority = empty ? s->fifo_priority : acc->fifo_priority;
    acc->period_s = s->period_s;
    if (empty || s->start_ns < acc->start_ns) acc->start_ns = s->start_ns;
    if (s->last_ns > acc->last_ns) acc->last_ns = s->last_ns;
    acc->ticks += s->ticks;
    acc->overruns += s->overruns;
    acc->missed_deadlines += s->missed_deadlines;
    if (s->wake_late_max_ns > acc->wake_late_max_ns) acc->wake_late_max_ns = s->wake_late_max_ns;
    for (int i = 0; i <= HS_RT_HIST_BINS; ++i) {
        acc->tick.count[i] += s->tick.count[i];
        acc->period_err.count[i] += s->period_err.count[i];
    }
    if (s->tick.max_ns > acc->tick.max_ns) acc->tick.max_ns = s->tick.max_ns;
    if (s->period_err.max_ns > acc->period_err.max_ns)
        acc->period_err.max_ns = s->period_err.max_ns;
}
