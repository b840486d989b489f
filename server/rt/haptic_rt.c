// SPDX-License-Identifier: GPL-2.0-or-later
// The haptic tick (see haptic_rt.h for the design) and the model source.
#include "haptic_rt.h"

#include "triple_buffer.h"

#include <math.h>
#include <stdatomic.h>
#include <string.h>

#define HAPTIC_RT_COOKIE 0x4a9d

// Counters written by the rt thread only (load + store, no read-modify-write), read by any.
typedef struct counters_atomic {
    _Atomic int64_t ticks, poses, stale_poses, device_errors, telemetry_dropped, blends;
    _Atomic int64_t nonfinite_force, nonfinite_pose, magnitude, rate, watchdog_trips;
} counters_atomic;

struct hs_haptic_rt {
    hs_haptic_rt_def def;
    hs_spsc_ring* telemetry;
    hs_triple_buffer* limits; // new hs_safety_def values, writer -> rt thread
    // rt thread only:
    hs_haptic_blend blend;
    int stopped; // the watchdog held the output at zero on the last tick
    hs_safety safety;
    hs_haptic_pose pose; // last valid pose
    int have_pose;
    hs_haptic_rt_counters local;
    // shared:
    counters_atomic shared;
};

hs_haptic_rt_def hs_haptic_rt_default_def(void) {
    hs_haptic_rt_def d;
    memset(&d, 0, sizeof d);
    d.safety = hs_safety_default_def();
    d.blend_ticks = 10;
    d.telemetry_capacity = 4096;
    d.cookie = HAPTIC_RT_COOKIE;
    return d;
}

hs_status hs_haptic_rt_create(const hs_haptic_rt_def* def, hs_haptic_rt** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "hs_haptic_rt_create: out is NULL");
    *out = NULL;
    if (!def || def->cookie != HAPTIC_RT_COOKIE)
        return hs_err_set(
            err, HS_ERR_INVALID,
            "hs_haptic_rt_create: def not initialised with hs_haptic_rt_default_def()");
    if (!def->device.vt || !def->device.vt->read_pose || !def->device.vt->write_force)
        return hs_err_set(err, HS_ERR_INVALID, "hs_haptic_rt_create: no device (def.device)");
    if (!def->source.eval)
        return hs_err_set(err, HS_ERR_INVALID, "hs_haptic_rt_create: no force source (def.source)");
    if (!hs_safety_def_valid(&def->safety))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_rt_create: def.safety invalid (use hs_safety_default_def(); "
                          "limits >= 0, ramp_s > 0)");
    if (def->blend_ticks < 1 || def->blend_ticks > 100000)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_rt_create: blend_ticks %d not in [1, 1e5]", def->blend_ticks);
    hs_haptic_rt* h = hs_calloc(1, sizeof *h);
    if (!h) return hs_err_set(err, HS_ERR_NOMEM, "hs_haptic_rt_create: out of memory");
    if (def->telemetry_capacity > 0) {
        hs_status st = hs_spsc_ring_create(sizeof(hs_haptic_telemetry), def->telemetry_capacity,
                                           &h->telemetry, err);
        if (st != HS_OK) {
            hs_free(h);
            return st;
        }
    }
    hs_status st = hs_triple_buffer_create(sizeof(hs_safety_def), &h->limits, err);
    if (st != HS_OK) {
        hs_spsc_ring_destroy(&h->telemetry);
        hs_free(h);
        return st;
    }
    h->def = *def;
    hs_haptic_blend_init(&h->blend, def->blend_ticks);
    hs_safety_init(&h->safety, &def->safety);
    *out = h;
    return HS_OK;
}

void hs_haptic_rt_destroy(hs_haptic_rt** h) {
    if (!h || !*h) return;
    hs_spsc_ring_destroy(&(*h)->telemetry);
    hs_triple_buffer_destroy(&(*h)->limits);
    hs_free(*h);
    *h = NULL;
}

hs_spsc_ring* hs_haptic_rt_telemetry(hs_haptic_rt* h) {
    return h->telemetry;
}

void hs_haptic_rt_restart(hs_haptic_rt* h) {
    hs_haptic_blend_reset(&h->blend);
    memset(h->safety.rate.prev_n, 0, sizeof h->safety.rate.prev_n);
    hs_watchdog_trip(&h->safety.watchdog);
}

void hs_haptic_rt_take_over(hs_haptic_rt* h, const hs_haptic_rt* from, hs_haptic_model* held) {
    // The held model is the old loop's last output, reached: a blend the old loop was in the
    // middle of is over (copied, it went on from its start toward the held model, so the force
    // first fell back toward that start; found in review).
    hs_haptic_blend_init(&h->blend, h->def.blend_ticks);
    h->blend.from = from->blend.last;
    h->blend.last = from->blend.last;
    h->blend.started = 1;
    h->stopped = from->stopped;
    h->pose = from->pose;
    h->have_pose = from->have_pose;
    // The device's state, under h's own limits.
    const hs_watchdog* fw = &from->safety.watchdog;
    h->safety.watchdog.gain = fw->gain;
    h->safety.watchdog.last_fresh_ns = fw->last_fresh_ns;
    h->safety.watchdog.seen = fw->seen;
    h->safety.watchdog.live = fw->live;
    memcpy(h->safety.rate.prev_n, from->safety.rate.prev_n, sizeof h->safety.rate.prev_n);
    *held = from->blend.last;
    // A seq no snapshot has: the new source numbers its snapshots afresh, and its first must
    // start a blend even when its number equals the old one's.
    held->seq = -1;
    h->blend.target_seq = -1;
}

hs_status hs_haptic_rt_set_safety(hs_haptic_rt* h, const hs_safety_def* def) {
    if (!h || !def || !hs_safety_def_valid(def)) return HS_ERR_INVALID;
    hs_triple_buffer_write(h->limits, def);
    return HS_OK;
}

static void store(_Atomic int64_t* a, int64_t v) {
    atomic_store_explicit(a, v, memory_order_relaxed);
}
static int64_t load(const _Atomic int64_t* a) {
    return atomic_load_explicit(a, memory_order_relaxed);
}

static void publish_counters(hs_haptic_rt* h) {
    const hs_haptic_rt_counters* c = &h->local;
    counters_atomic* s = &h->shared;
    store(&s->ticks, c->ticks);
    store(&s->poses, c->poses);
    store(&s->stale_poses, c->stale_poses);
    store(&s->device_errors, c->device_errors);
    store(&s->telemetry_dropped, c->telemetry_dropped);
    store(&s->blends, c->blends);
    store(&s->nonfinite_force, h->safety.counters.nonfinite_force);
    store(&s->nonfinite_pose, h->safety.counters.nonfinite_pose);
    store(&s->magnitude, h->safety.counters.magnitude);
    store(&s->rate, h->safety.counters.rate);
    store(&s->watchdog_trips, h->safety.counters.watchdog_trips);
}

void hs_haptic_rt_get_counters(const hs_haptic_rt* h, hs_haptic_rt_counters* out) {
    const counters_atomic* s = &h->shared;
    out->ticks = load(&s->ticks);
    out->poses = load(&s->poses);
    out->stale_poses = load(&s->stale_poses);
    out->device_errors = load(&s->device_errors);
    out->telemetry_dropped = load(&s->telemetry_dropped);
    out->blends = load(&s->blends);
    out->safety.nonfinite_force = load(&s->nonfinite_force);
    out->safety.nonfinite_pose = load(&s->nonfinite_pose);
    out->safety.magnitude = load(&s->magnitude);
    out->safety.rate = load(&s->rate);
    out->safety.watchdog_trips = load(&s->watchdog_trips);
}

static int pose_finite(const hs_haptic_pose* p) {
    return hs_vec3_finite(p->pos_m) && isfinite(p->quat_wxyz[0]) && isfinite(p->quat_wxyz[1]) &&
           isfinite(p->quat_wxyz[2]) && isfinite(p->quat_wxyz[3]);
}

static void haptic_tick(void* ctx, const hs_rt_clock* clk) {
    hs_haptic_rt* h = ctx;
    const hs_device dev = h->def.device;
    hs_haptic_rt_counters* c = &h->local;

    // 1. pose
    hs_haptic_pose p;
    int fresh = 0, pose_ok = 1;
    int r = dev.vt->read_pose(dev.ctx, &p);
    if (r < 0) {
        ++c->device_errors;
    } else if (r > 0) {
        if (!pose_finite(&p)) {
            pose_ok = 0; // counted by the safety chain
        } else if (h->have_pose && p.seq <= h->pose.seq) {
            ++c->stale_poses;
        } else {
            h->pose = p;
            h->have_pose = 1;
            fresh = 1;
            ++c->poses;
        }
    }

    // 2-3. force from the source, blended across source changes
    double f[3] = {0, 0, 0};
    hs_haptic_model model;
    memset(&model, 0, sizeof model);
    if (h->have_pose && pose_ok) {
        hs_haptic_model target;
        h->def.source.eval(h->def.source.ctx, clk, &h->pose, &target);
        if (!hs_haptic_model_finite(&target)) {
            f[0] = NAN; // the safety chain zeroes and counts it
            hs_haptic_blend_reset(&h->blend);
        } else {
            if (!h->stopped && (!h->blend.started || target.seq != h->blend.target_seq))
                ++c->blends;
            hs_haptic_blend_step(&h->blend, &target, h->pose.pos_m, f, &model);
        }
    }

    // 4. safety (with the newest limits)
    hs_safety_def lim;
    if (hs_triple_buffer_read_copy(h->limits, &lim)) hs_safety_set_limits(&h->safety, &lim);
    uint32_t flags = hs_safety_apply(&h->safety, f, fresh, pose_ok, clk->now_ns, clk->dt_s);
    double gain = h->safety.watchdog.gain;
    // After a full watchdog stop there is no force to blend from: a resumed device (perhaps
    // elsewhere, perhaps a new session) ramps in from zero and never gets the old contact back.
    h->stopped = gain == 0;
    if (h->stopped) hs_haptic_blend_reset(&h->blend);
    if ((flags & HS_SAFETY_NONFINITE) || gain == 0) {
        int64_t seq = model.seq;
        memset(&model, 0, sizeof model);
        model.seq = seq;
    } else {
        // The local model must agree with the force sent: scale its stiffness like the force;
        // a saturated force does not grow with penetration.
        for (int i = 0; i < 9; ++i)
            model.stiffness_n_m[i] =
                (flags & HS_SAFETY_MAGNITUDE) ? 0 : gain * model.stiffness_n_m[i];
    }
    memcpy(model.force_n, f, sizeof model.force_n);
    memcpy(model.anchor_m, h->pose.pos_m, sizeof model.anchor_m);
    if (!(model.timeout_s > 0)) model.timeout_s = h->safety.def.watchdog_timeout_s;

    // 5. out
    hs_haptic_output out;
    out.seq = clk->tick;
    out.stamp_ns = clk->now_ns;
    out.pose_seq = h->have_pose ? h->pose.seq : 0;
    memcpy(out.force_n, f, sizeof out.force_n);
    out.model = model;
    out.safety = flags;
    if (dev.vt->write_force(dev.ctx, &out) < 0) ++c->device_errors;

    if (h->telemetry) {
        hs_haptic_telemetry t;
        t.tick = clk->tick;
        t.now_ns = clk->now_ns;
        t.dt_s = clk->dt_s;
        t.pose_seq = out.pose_seq;
        t.pose_new = fresh;
        t.safety = flags;
        memcpy(t.tool_m, h->pose.pos_m, sizeof t.tool_m);
        memcpy(t.force_n, f, sizeof t.force_n);
        t.gain = gain;
        t.model_seq = h->blend.target_seq;
        if (!hs_spsc_ring_push(h->telemetry, &t)) ++c->telemetry_dropped;
    }
    ++c->ticks;
    publish_counters(h);
}

hs_rt_tick hs_haptic_rt_tick(hs_haptic_rt* h) {
    hs_rt_tick t;
    memset(&t, 0, sizeof t);
    t.fn = haptic_tick;
    t.ctx = h;
    return t;
}

// ---------------------------------------------------------------------------------------------
// Model source

struct hs_model_source {
    hs_triple_buffer* tb; // producer -> rt, hs_haptic_model
};

static void model_source_eval(void* ctx, const hs_rt_clock* clk, const hs_haptic_pose* pose,
                              hs_haptic_model* out) {
    (void)clk;
    hs_model_source* s = ctx;
    const hs_haptic_model* m = hs_triple_buffer_read(s->tb, NULL);
    hs_haptic_model_reanchor(m, pose->pos_m, out);
}

hs_status hs_model_source_create(hs_model_source** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "hs_model_source_create: out is NULL");
    *out = NULL;
    hs_model_source* s = hs_calloc(1, sizeof *s);
    if (!s) return hs_err_set(err, HS_ERR_NOMEM, "hs_model_source_create: out of memory");
    hs_status st = hs_triple_buffer_create(sizeof(hs_haptic_model), &s->tb, err);
    if (st != HS_OK) {
        hs_free(s);
        return st;
    }
    *out = s;
    return HS_OK;
}

void hs_model_source_destroy(hs_model_source** s) {
    if (!s || !*s) return;
    hs_triple_buffer_destroy(&(*s)->tb);
    hs_free(*s);
    *s = NULL;
}

void hs_model_source_publish(hs_model_source* s, const hs_haptic_model* m) {
    hs_triple_buffer_write(s->tb, m);
}

hs_haptic_source hs_model_source_source(hs_model_source* s) {
    hs_haptic_source src = {model_source_eval, s};
    return src;
}
