// SPDX-License-Identifier: GPL-2.0-or-later
// rt: the haptic tick, what the 1 kHz loop does every period.
//
// DESIGN. Runs on the rt thread as the hs_rt_tick of an hs_rt_loop. Each tick:
//   1. read the newest pose from the device (hs_device); reject NaN/Inf and stale seq;
//   2. ask the force source for the force at the tool as a local model (hs_haptic_source: the
//      condensed-compliance contact plugs in here; hs_model_source serves models published by
//      another thread);
//   3. blend when the source's seq changed (a new snapshot), so the force never jumps;
//   4. safety chain: NaN guard, magnitude clamp, rate clamp, then the watchdog gain (last,
//      so that it alone decides when the force is zero);
//   5. write force + local model to the device and one telemetry record to a ring.
// Owns: the blend and safety state, the last good pose (rt thread only). Crosses: pose in and
// output out through the device; telemetry out through an SPSC ring (a full ring drops the
// record and counts it, never blocks); counters through atomics. No malloc, lock or printf.
#ifndef HS_RT_HAPTIC_RT_H
#define HS_RT_HAPTIC_RT_H

#include "spsc_ring.h"
#include "device.h"
#include "base.h"
#include "haptic.h"
#include "rt_thread.h"

#ifdef __cplusplus
extern "C" {
#endif

/// Where the force comes from: a function and its context, evaluated on the rt thread.
typedef struct hs_haptic_source {
    /// The force on the tool at pose->pos_m from the newest data the source holds, as a local
    /// model anchored there (out->force_n = the force, out->stiffness_n_m = -dF/dp, radius and
    /// timeout), out->seq = version of that data: a change starts a blend. A NaN/Inf anywhere in
    /// *out zeroes the force and is counted. Thread: rt | Allocates: no | Blocks: no
    void (*eval)(void* ctx, const hs_rt_clock* clk, const hs_haptic_pose* pose,
                 hs_haptic_model* out);
    void* ctx;
} hs_haptic_source;

/// One record per tick, rt -> any consumer (net, tests).
typedef struct hs_haptic_telemetry {
    int64_t tick;      ///< loop tick number
    int64_t now_ns;    ///< wake time, CLOCK_MONOTONIC ns
    double dt_s;       ///< measured period, s
    int64_t pose_seq;  ///< newest valid pose used (0: none yet)
    int32_t pose_new;  ///< 1 when a new valid pose arrived this tick
    uint32_t safety;   ///< HS_SAFETY_* flags
    double tool_m[3];  ///< tool position used, m
    double force_n[3]; ///< force sent, N
    double gain;       ///< watchdog gain, [0, 1]
    int64_t model_seq; ///< seq of the source data being blended toward
} hs_haptic_telemetry;

/// Counters for status reports (copied out atomically per field).
typedef struct hs_haptic_rt_counters {
    int64_t ticks;             ///< haptic ticks run
    int64_t poses;             ///< new valid poses taken
    int64_t stale_poses;       ///< poses whose seq did not grow (reordered or repeated), dropped
    int64_t device_errors;     ///< read_pose / write_force failures
    int64_t telemetry_dropped; ///< records lost because the ring was full
    int64_t blends;            ///< blends started (source seq changes)
    hs_safety_counters safety; ///< NaN/Inf, clamps, watchdog trips
} hs_haptic_rt_counters;

/// Options. Initialise with hs_haptic_rt_default_def(), then set device and source.
typedef struct hs_haptic_rt_def {
    hs_device device;          ///< required
    hs_haptic_source source;   ///< required
    hs_safety_def safety;      ///< defaults from hs_safety_default_def()
    int blend_ticks;           ///< blend length on a new snapshot, ticks (default 10)
    size_t telemetry_capacity; ///< ring capacity (power of two, default 4096); 0: no telemetry
    int cookie;                ///< set by hs_haptic_rt_default_def
} hs_haptic_rt_def;

/// Defaults: safety defaults, 10 blend ticks, 4096 telemetry records; no device, no source.
hs_haptic_rt_def hs_haptic_rt_default_def(void);

typedef struct hs_haptic_rt hs_haptic_rt;

/// Allocate the tick state and telemetry ring. @param out OUT | Thread: any | Allocates: yes
hs_status hs_haptic_rt_create(const hs_haptic_rt_def* def, hs_haptic_rt** out, hs_err* err);
/// Release; accepts NULL or *h == NULL and sets *h = NULL. The loop running it must have stopped.
void hs_haptic_rt_destroy(hs_haptic_rt** h);
/// The tick to put in hs_rt_def.tick (valid while h lives).
hs_rt_tick hs_haptic_rt_tick(hs_haptic_rt* h);
/// Telemetry ring (items are hs_haptic_telemetry); NULL when disabled. One consumer pops it.
hs_spsc_ring* hs_haptic_rt_telemetry(hs_haptic_rt* h);
/// Copy the counters out. Thread: any | Allocates: no | Lock-free: yes | Blocks: no
void hs_haptic_rt_get_counters(const hs_haptic_rt* h, hs_haptic_rt_counters* out /* OUT */);
/// New safety limits while the loop runs (or stands): the rt thread takes them at its next tick,
/// keeping the watchdog and rate state (hs_safety_set_limits). HS_ERR_INVALID (nothing changed)
/// for an invalid def. Thread: one writer thread | Allocates: no | Lock-free: yes | Blocks: no
hs_status hs_haptic_rt_set_safety(hs_haptic_rt* h, const hs_safety_def* def);
/// Before the loop starts again after a stop: nothing is blended from the output before the
/// stop, and the force ramps in from zero (the watchdog's ramp) as for a new device.
/// Thread: control, while the loop is stopped | Allocates: no
void hs_haptic_rt_restart(hs_haptic_rt* h);
/// Before h's first start, with from's loop stopped (a rebuild of the same scene): h goes on
/// where from left off: its last pose, watchdog gain and rate clamp (the force does not ramp in
/// again) and its last output, reached (a blend from was in the middle of is over; the next
/// snapshot blends from there). *held (OUT) = from's last output model before the safety chain,
/// anchored at its last pose: what h's source should give until it has data of its own.
/// Thread: control, both loops stopped | Allocates: no
void hs_haptic_rt_take_over(hs_haptic_rt* h, const hs_haptic_rt* from, hs_haptic_model* held);

// ---------------------------------------------------------------------------------------------
// Model source: a force source that evaluates the newest hs_haptic_model published by another
// thread (a triple buffer, newest wins). Before the first publish it gives the zero model.

typedef struct hs_model_source hs_model_source;

/// @param out OUT | Thread: any | Allocates: yes
hs_status hs_model_source_create(hs_model_source** out, hs_err* err);
/// Release; accepts NULL or *s == NULL and sets *s = NULL. Its users must have stopped.
void hs_model_source_destroy(hs_model_source** s);
/// Publish a model (its seq must change for a blend to start).
/// Thread: producer only | Allocates: no | Lock-free: yes | Blocks: no
void hs_model_source_publish(hs_model_source* s, const hs_haptic_model* m);
/// The source view for hs_haptic_rt_def.source (valid while s lives).
hs_haptic_source hs_model_source_source(hs_model_source* s);

#ifdef __cplusplus
}
#endif
#endif
