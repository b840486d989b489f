// SPDX-License-Identifier: MIT
// The stylus device model: a handle of some mass with viscous and Coulomb friction, pulled by a
// virtual hand (spring-damper to the scripted target) and pushed by a force-limited motor that
// renders the newest local model from the server. Semi-implicit Euler on the real elapsed dt.
// Also the offline half-space server, the deterministic offline run, and the model mailbox.
#include "stylus.h"

#include "hapsim_model.h"

#include <math.h>
#include <string.h>

#define STYLUS_COOKIE 0x5791
#define STATE_STOPPED 3 // HAPSIM_TOOL_FORCE_STATE_STOPPED (no msgs dependency in the core)
#define MAX_DELAY     63

static double dot3(const double a[3], const double b[3]) {
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

static double norm3(const double v[3]) {
    return sqrt(dot3(v, v));
}

static int finite3(const double v[3]) {
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

int hs_stylus_model_valid(const hs_stylus_model* m) {
    int ok = finite3(m->force_n) && finite3(m->anchor_m) && isfinite(m->radius_m) &&
             isfinite(m->timeout_s) && m->radius_m >= 0 && m->timeout_s >= 0;
    for (int i = 0; i < 9; ++i) ok = ok && isfinite(m->stiffness[i]);
    return ok;
}

int hs_stylus_model_eval(const hs_stylus_model* m, const double p[3], double f_n[3]) {
    // The protocol's one evaluator (msgs/hapsim_model.h), clamped to the radius; a non-finite
    // force (a NaN position) is zeroed by the device step.
    return hapsim_model_force(m->force_n, m->anchor_m, m->stiffness, 1, m->radius_m, p, f_n) ==
           HAPSIM_MODEL_INSIDE;
}

hs_stylus_def hs_stylus_default_def(void) {
    hs_stylus_def d;
    memset(&d, 0, sizeof d);
    d.mass_kg = 0.05;
    d.viscous_n_s_m = 0.2;
    d.coulomb_n = 0.02;
    d.hand_stiffness_n_m = 400;
    d.hand_damping_n_s_m = 8;
    d.max_force_n = 3.3;
    d.max_rate_n_s = 2000;
    d.workspace_m[0] = 0.160;
    d.workspace_m[1] = 0.120;
    d.workspace_m[2] = 0.070;
    d.timeout_s = 0.1;
    d.ramp_s = 0.02;
    d.outside_ramp_s = 0.02;
    d.max_dt_s = 0.002;
    d.tick_s = 0.001;
    d.cookie = STYLUS_COOKIE;
    return d;
}

hs_status hs_stylus_def_check(const hs_stylus_def* d, hs_err* err) {
    if (!d || d->cookie != STYLUS_COOKIE)
        return hs_err_set(err, HS_ERR_INVALID, "stylus def: not from hs_stylus_default_def()");
#define NEED(cond, what)                                                                           \
    if (!(cond)) return hs_err_set(err, HS_ERR_INVALID, "stylus def: %s", what)
    NEED(isfinite(d->mass_kg) && d->mass_kg > 0, "mass_kg must be > 0");
    NEED(isfinite(d->viscous_n_s_m) && d->viscous_n_s_m >= 0, "viscous_n_s_m must be >= 0");
    NEED(isfinite(d->coulomb_n) && d->coulomb_n >= 0, "coulomb_n must be >= 0");
    NEED(isfinite(d->hand_stiffness_n_m) && d->hand_stiffness_n_m > 0,
         "hand_stiffness_n_m must be > 0");
    NEED(isfinite(d->hand_damping_n_s_m) && d->hand_damping_n_s_m >= 0,
         "hand_damping_n_s_m must be >= 0");
    NEED(isfinite(d->max_force_n) && d->max_force_n > 0, "max_force_n must be > 0");
    NEED(isfinite(d->max_rate_n_s) && d->max_rate_n_s > 0, "max_rate_n_s must be > 0");
    for (int i = 0; i < 3; ++i) {
        NEED(isfinite(d->workspace_m[i]) && d->workspace_m[i] > 0, "workspace_m must be > 0");
        NEED(isfinite(d->origin_m[i]), "origin_m must be finite");
    }
    NEED(isfinite(d->timeout_s) && d->timeout_s > 0 && d->timeout_s <= HS_STYLUS_MAX_TIMEOUT_S,
         "timeout_s must be in (0, 60] s");
    NEED(isfinite(d->ramp_s) && d->ramp_s > 0 && d->ramp_s <= d->timeout_s,
         "ramp_s must be in (0, timeout_s]");
    NEED(isfinite(d->outside_ramp_s) && d->outside_ramp_s > 0, "outside_ramp_s must be > 0");
    NEED(isfinite(d->max_dt_s) && d->max_dt_s > 0, "max_dt_s must be > 0");
    NEED(isfinite(d->tick_s) && d->tick_s > 0 && d->tick_s < 1, "tick_s must be in (0, 1) s");
#undef NEED
    // Stability of hs_stylus_device_step: per axis, with the spring explicit and the dampers
    // implicit, x' = x + h v', v' = (v - h k/m x) / (1 + h c/m). Its matrix has determinant
    // 1 / (1 + h c/m) < 1 and trace 1 + det - h^2 k/m det, stable (Jury) while
    // k h^2 < 4 m + 2 h c. Beyond it the handle swings ever wider into the workspace walls.
    // The model's contact stiffness is left out: the motor's magnitude and rate clamps bound
    // what it can put in (an offline wall of 1e6 N/m runs smoothly at 1 kHz).
    int n = d->tick_s > d->max_dt_s ? (int)ceil(d->tick_s / d->max_dt_s) : 1;
    if (n > 1000) n = 1000;
    double h = d->tick_s / n, c = d->hand_damping_n_s_m + d->viscous_n_s_m;
    double k_max = (4 * d->mass_kg + 2 * h * c) / (h * h);
    if (!(d->hand_stiffness_n_m < k_max))
        return hs_err_set(err, HS_ERR_INVALID,
                          "stylus def: hand_stiffness_n_m %g N/m is beyond the stability limit "
                          "%.4g N/m for mass %g kg, damping %g N s/m and %g s ticks (%d substeps): "
                          "need k h^2 < 4 m + 2 h c",
                          d->hand_stiffness_n_m, k_max, d->mass_kg, c, d->tick_s, n);
    return HS_OK;
}

// Keeps p inside the workspace box; stops the velocity component that pushes outward.
static int workspace_limit(const hs_stylus_def* def, double p[3], double v[3]) {
    int hit = 0;
    for (int i = 0; i < 3; ++i) {
        double lo = def->origin_m[i] - 0.5 * def->workspace_m[i];
        double hi = def->origin_m[i] + 0.5 * def->workspace_m[i];
        if (p[i] < lo) {
            p[i] = lo;
            if (v && v[i] < 0) v[i] = 0;
            hit = 1;
        } else if (p[i] > hi) {
            p[i] = hi;
            if (v && v[i] > 0) v[i] = 0;
            hit = 1;
        }
    }
    return hit;
}

void hs_stylus_device_init(hs_stylus_device* d, const hs_stylus_def* def, const double p0_m[3]) {
    memset(d, 0, sizeof *d);
    d->def = *def;
    memcpy(d->pos_m, p0_m, sizeof d->pos_m);
    workspace_limit(def, d->pos_m, NULL);
}

void hs_stylus_device_set_model(hs_stylus_device* d, const hs_stylus_model* m) {
    d->model = *m;
    d->has_model = 1;
    d->outside_s = 0;
}

// The model's force at p (f_n) and the gain the age, radius and state allow (*gain_out).
static uint32_t render_parts(const hs_stylus_device* d, const double p[3], int64_t now_ns,
                             double f_n[3], double* gain_out) {
    f_n[0] = f_n[1] = f_n[2] = 0;
    *gain_out = 0;
    if (!d->has_model) return HS_TICK_NO_MODEL;
    const hs_stylus_model* m = &d->model;
    const hs_stylus_def* def = &d->def;
    uint32_t flags = 0;
    int inside = hs_stylus_model_eval(m, p, f_n);
    double gain = 1;
    // Age: full strength for min(model timeout, own timeout - ramp), then a linear ramp that
    // reaches exactly zero no later than the device's own timeout. Integer ns: no rounding at
    // the edges.
    int64_t age = now_ns - m->arrival_ns;
    double hold_s =
        m->timeout_s < def->timeout_s - def->ramp_s ? m->timeout_s : def->timeout_s - def->ramp_s;
    int64_t hold = hold_s > 0 ? (int64_t)llround(hold_s * 1e9) : 0;
    if (age > hold) {
        flags |= HS_TICK_TIMEOUT;
        gain = 1 - (double)(age - hold) * 1e-9 / def->ramp_s;
        if (age >= (int64_t)llround(def->timeout_s * 1e9) || gain < 0) gain = 0;
    }
    if (!inside) {
        flags |= HS_TICK_OUTSIDE;
        double g = 1 - d->outside_s / def->outside_ramp_s;
        gain *= g > 0 ? g : 0;
    }
    if (m->state == STATE_STOPPED) gain = 0;
    *gain_out = gain;
    return flags;
}

uint32_t hs_stylus_device_render(const hs_stylus_device* d, const double p[3], int64_t now_ns,
                                 double f_n[3]) {
    double gain;
    uint32_t flags = render_parts(d, p, now_ns, f_n, &gain);
    for (int i = 0; i < 3; ++i) f_n[i] *= gain;
    return flags;
}

void hs_stylus_device_step(hs_stylus_device* d, const double target_m[3],
                           const double target_vel[3], int64_t now_ns, double dt_s,
                           hs_stylus_tick* out) {
    const hs_stylus_def* def = &d->def;
    memset(out, 0, sizeof *out);
    if (!(dt_s > 0) || !isfinite(dt_s)) dt_s = 0;
    double p0[3];
    memcpy(p0, d->pos_m, sizeof p0);

    double f[3], gain;
    uint32_t flags = render_parts(d, d->pos_m, now_ns, f, &gain);
    // The gain falls as fast as render asks but rises over ramp_s: after a timeout, a stop or
    // leaving the radius the force fades back in instead of jumping.
    double up = d->gain + dt_s / def->ramp_s;
    d->gain = gain < up ? gain : up;
    for (int i = 0; i < 3; ++i) f[i] *= d->gain;
    if (!finite3(f)) f[0] = f[1] = f[2] = 0;
    double fn = norm3(f);
    if (fn > def->max_force_n) {
        for (int i = 0; i < 3; ++i) f[i] *= def->max_force_n / fn;
        flags |= HS_TICK_MAGNITUDE;
    }
    double df[3] = {f[0] - d->prev_force_n[0], f[1] - d->prev_force_n[1],
                    f[2] - d->prev_force_n[2]};
    double dfn = norm3(df), dmax = def->max_rate_n_s * dt_s;
    if (dfn > dmax) {
        for (int i = 0; i < 3; ++i) f[i] = d->prev_force_n[i] + df[i] * (dmax / dfn);
        flags |= HS_TICK_RATE;
    }
    // Zero where the rules above ask for zero (timed out, STOPPED, long outside): the rate clamp
    // smooths a force, it must not keep one on (found in review: at 10 N/s it held 2.8 N
    // 100 ms after the model arrived, and 2.98 N 2 ms after a stop).
    if (!(d->gain > 0)) f[0] = f[1] = f[2] = 0;
    memcpy(d->prev_force_n, f, sizeof f);
    d->outside_s = (flags & HS_TICK_OUTSIDE) ? d->outside_s + dt_s : 0;

    // Semi-implicit Euler; both dampers implicit so a long tick cannot make them unstable.
    int n = dt_s > def->max_dt_s ? (int)ceil(dt_s / def->max_dt_s) : 1;
    if (n > 1000) n = 1000;
    double h = dt_s / n, m = def->mass_kg;
    double c = def->hand_damping_n_s_m + def->viscous_n_s_m;
    // The friction impulse shrinks with the implicit damping like the other forces do, so the
    // handle sticks exactly while the net force stays below coulomb_n.
    double stick = def->coulomb_n * h / m / (1 + h * c / m);
    int hit = 0;
    for (int s = 0; s < n && h > 0; ++s) {
        double v[3];
        for (int i = 0; i < 3; ++i) {
            double force = def->hand_stiffness_n_m * (target_m[i] - d->pos_m[i]) +
                           def->hand_damping_n_s_m * (target_vel ? target_vel[i] : 0) + f[i];
            v[i] = (d->vel_m_s[i] + h / m * force) / (1 + h * c / m);
        }
        double vn = norm3(v);
        // Coulomb friction: an impulse opposite to the motion, sticking when it would reverse it.
        double k = vn > stick ? 1 - stick / vn : 0;
        for (int i = 0; i < 3; ++i) {
            d->vel_m_s[i] = v[i] * k;
            d->pos_m[i] += h * d->vel_m_s[i];
        }
        hit |= workspace_limit(def, d->pos_m, d->vel_m_s);
    }
    if (hit) {
        flags |= HS_TICK_WORKSPACE;
        d->workspace_hits++;
    }
    memcpy(out->target_m, target_m, sizeof out->target_m);
    memcpy(out->handle_m, d->pos_m, sizeof out->handle_m);
    memcpy(out->handle_vel, d->vel_m_s, sizeof out->handle_vel);
    memcpy(out->f_applied, f, sizeof out->f_applied);
    double dp[3] = {d->pos_m[0] - p0[0], d->pos_m[1] - p0[1], d->pos_m[2] - p0[2]};
    out->work_j = dot3(f, dp);
    if (d->has_model) {
        memcpy(out->f_received, d->model.force_n, sizeof out->f_received);
        out->model_age_s = (double)(now_ns - d->model.arrival_ns) * 1e-9;
        out->latency_us = (double)d->model.latency_us;
    } else {
        out->model_age_s = -1;
        out->latency_us = -1;
    }
    out->flags = flags;
}

void hs_halfspace_model(const hs_halfspace* h, const double p[3], hs_stylus_model* out) {
    memset(out, 0, sizeof *out);
    double d[3] = {p[0] - h->point_m[0], p[1] - h->point_m[1], p[2] - h->point_m[2]};
    double depth = -dot3(h->normal, d);
    memcpy(out->anchor_m, p, sizeof out->anchor_m);
    out->radius_m = h->radius_m;
    out->timeout_s = h->timeout_s;
    out->state = depth > 0 ? 1 : 0;
    if (depth > 0) {
        for (int i = 0; i < 3; ++i) {
            out->force_n[i] = h->stiffness_n_m * depth * h->normal[i];
            for (int j = 0; j < 3 && !h->force_only; ++j)
                out->stiffness[3 * i + j] = -h->stiffness_n_m * h->normal[i] * h->normal[j];
        }
    }
}

hs_status hs_stylus_run_offline(const hs_script* script, const hs_stylus_def* def,
                                const hs_offline_def* off, hs_stylus_trace* trace,
                                hs_stylus_device* dev_out, hs_err* err) {
    hs_status st = hs_stylus_def_check(def, err);
    if (st) return st;
    if (!(off->dt_s > 0 && off->dt_s < 1) || off->period_ticks < 1 || off->delay_ticks < 1 ||
        off->delay_ticks > MAX_DELAY || !(off->surface.stiffness_n_m >= 0) ||
        !(off->surface.radius_m >= 0) || !(off->surface.timeout_s >= 0) ||
        !finite3(off->surface.point_m) || !(fabs(norm3(off->surface.normal) - 1) < 1e-6) ||
        !(off->duration_s <= 1e7))
        return hs_err_set(err, HS_ERR_INVALID,
                          "offline: need 0 < dt < 1 s, period >= 1, 1 <= delay <= %d, "
                          "stiffness/radius/timeout >= 0, a unit normal, duration <= 1e7 s",
                          MAX_DELAY);

    hs_stylus_device dev;
    hs_stylus_device_init(&dev, def, script->start_m);
    // Answers in flight, indexed by the tick they arrive at (mod MAX_DELAY + 1).
    hs_stylus_model pending[MAX_DELAY + 1];
    int has_pending[MAX_DELAY + 1];
    memset(has_pending, 0, sizeof has_pending);
    const int64_t dt_ns = (int64_t)llround(off->dt_s * 1e9);
    const int64_t base_ns = 1000000000; // virtual clock, ns
    hs_script_runner run;
    hs_script_runner_init(&run, script);
    double felt[3] = {0, 0, 0};
    int64_t pose_seq = 0;
    for (int64_t k = 0;; ++k) {
        // Without a given duration the run ends 0.5 s after the script, whose end moves when a
        // touch finds the surface early.
        double duration = off->duration_s > 0 ? off->duration_s : hs_script_runner_end(&run) + 0.5;
        if (k >= (int64_t)ceil(duration / off->dt_s - 1e-9)) break;
        if (off->stop && atomic_load_explicit(off->stop, memory_order_relaxed)) break;
        int64_t now = base_ns + k * dt_ns;
        int slot = (int)(k % (MAX_DELAY + 1));
        if (has_pending[slot]) {
            pending[slot].arrival_ns = now;
            hs_stylus_device_set_model(&dev, &pending[slot]);
            has_pending[slot] = 0;
        }
        double t = (double)k * off->dt_s, target[3], tvel[3];
        hs_stylus_tick tick;
        uint32_t events;
        int seg = hs_script_runner_eval(&run, t, felt, target, tvel, NULL, &events);
        hs_stylus_device_step(&dev, target, tvel, now, off->dt_s, &tick);
        memcpy(felt, tick.f_applied, sizeof felt);
        tick.t_s = t;
        tick.segment = seg;
        if (events & HS_TOUCH_FOUND) tick.flags |= HS_TICK_TOUCH_FOUND;
        if (events & HS_TOUCH_MISSED) tick.flags |= HS_TICK_TOUCH_MISSED;
        if (trace) hs_stylus_trace_add(trace, &tick);
        // The pose leaves at the end of the tick; the half-space answers delay ticks later.
        if (pose_seq++ % off->period_ticks == 0) {
            int at = (int)((k + off->delay_ticks) % (MAX_DELAY + 1));
            hs_halfspace_model(&off->surface, dev.pos_m, &pending[at]);
            pending[at].seq = pose_seq;
            pending[at].version = pose_seq;
            pending[at].pose_seq = pose_seq;
            pending[at].latency_us = (int64_t)llround(off->delay_ticks * off->dt_s * 1e6);
            has_pending[at] = 1;
        }
    }
    if (dev_out) *dev_out = dev;
    return HS_OK;
}

void hs_stylus_mailbox_init(hs_stylus_mailbox* mb) {
    memset(mb->slot, 0, sizeof mb->slot);
    hapsim_triple_init(&mb->idx);
}

void hs_stylus_mailbox_put(hs_stylus_mailbox* mb, const hs_stylus_model* m) {
    mb->slot[mb->idx.back] = *m;
    hapsim_triple_publish(&mb->idx);
}

int hs_stylus_mailbox_take(hs_stylus_mailbox* mb, hs_stylus_model* out) {
    if (!hapsim_triple_take(&mb->idx)) return 0;
    *out = mb->slot[mb->idx.front];
    return 1;
}
