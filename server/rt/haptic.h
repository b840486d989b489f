// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim haptic: the local model (haptic proxy) that leaves the server with every force, the
// safety filters between a computed force and the device, and the 1 kHz loop's statistics.
// Pure functions over caller-owned structs: no threads, no allocation, usable at any rate.
//
// Frames and signs. Positions are in the scene frame, m. Every force here is the force ON THE
// TOOL (what the hand feels), N. A local model is first order around its anchor a:
//     f(p) = f0 - K (p - a)        for |p - a| <= r,
// so a positive definite K pushes the tool back toward where it came from (pressing deeper
// into tissue along -n raises the force along +n). Outside the validity radius the model is
// evaluated at the nearest point of its sphere: the force stays continuous and bounded, and
// nothing is extrapolated beyond what the server vouched for.
#ifndef HAPSIM_HAPTIC_H
#define HAPSIM_HAPTIC_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

// ---------------------------------------------------------------------------------------------
// Tool pose (in) and local model (out).

/// One tool sample from a device.
typedef struct hs_haptic_pose {
    int64_t seq;         ///< device sequence; a pose is new when seq grows
    int64_t stamp_ns;    ///< when the server received it, CLOCK_MONOTONIC ns
    double pos_m[3];     ///< tool tip position, scene frame, m
    double quat_wxyz[4]; ///< tool orientation (w, x, y, z), unit
    uint32_t buttons;    ///< bit i = button i pressed
} hs_haptic_pose;

/// First-order local model of the force around an anchor: f(p) = f0 - K (p - anchor).
/// A zeroed struct is the valid "no force" model.
typedef struct hs_haptic_model {
    int64_t seq;             ///< version: grows with every new model (snapshot) it comes from
    int64_t stamp_ns;        ///< when it was computed, CLOCK_MONOTONIC ns
    double force_n[3];       ///< f0: force on the tool at the anchor, N
    double stiffness_n_m[9]; ///< K, row-major 3x3, N/m (symmetric positive semidefinite usually)
    double anchor_m[3];      ///< tool position where force_n holds, m
    double radius_m;         ///< validity radius around the anchor, m (0: force_n everywhere)
    double timeout_s;        ///< a renderer ramps the force to zero when the model is older, s
} hs_haptic_model;

/// Force on the tool at tool_m ([3], m) from model m into f_n ([3], N). Returns 1 when tool_m is
/// within the validity radius, 0 when it was evaluated at the nearest point of the sphere.
/// Thread: any | Allocates: no
int hs_haptic_model_eval(const hs_haptic_model* m, const double tool_m[3], double f_n[3]);
/// The same force as a model anchored at tool_m: force_n = f(tool_m), K kept inside the radius
/// and zero outside (there f does not change with p), radius shrunk to what remains valid.
/// Thread: any | Allocates: no
void hs_haptic_model_reanchor(const hs_haptic_model* m, const double tool_m[3],
                              hs_haptic_model* out /* OUT */);
/// 1 when every number in m is finite, else 0. Thread: any | Allocates: no
int hs_haptic_model_finite(const hs_haptic_model* m);
/// sqrt(||K||_1 ||K||_inf), N/m: an upper bound of |K d| / |d| for any K (used in jump bounds).
double hs_haptic_model_stiffness_bound(const hs_haptic_model* m);

/// What leaves the server every tick: the force to render now and the local model to render
/// with until the next message (model.force_n == force_n at model.anchor_m == the tool position).
typedef struct hs_haptic_output {
    int64_t seq;           ///< rt tick number
    int64_t stamp_ns;      ///< wake time of the tick, CLOCK_MONOTONIC ns
    int64_t pose_seq;      ///< seq of the newest valid pose used (0: none yet)
    double force_n[3];     ///< force on the tool after the safety filters, N
    hs_haptic_model model; ///< local model at the tool, scaled and clamped like force_n
    uint32_t safety;       ///< HS_SAFETY_* flags of this tick
} hs_haptic_output;

// ---------------------------------------------------------------------------------------------
// Blending. When the source of the force changes (a new deformation snapshot, a cut, a new
// model from the server), the output moves from the old model to the new one over n ticks:
//     out_k = (1 - k/n) f_old(p_k) + (k/n) f_new(p_k),  k = 1..n,
// where f_old is the model that was being output when the switch happened, frozen. So the
// tick-to-tick change is at most max|K| |p_k - p_k-1| + |f_new - f_old| / n: the output never
// jumps. A switch during a blend freezes the current mix and starts again from it.

/// Blend state; initialise with hs_haptic_blend_init.
typedef struct hs_haptic_blend {
    hs_haptic_model from; ///< frozen output model at the last switch
    hs_haptic_model last; ///< the last output model (anchored at the last tool position)
    int64_t target_seq;   ///< seq of the model being blended toward
    int ticks;            ///< blend length, ticks (>= 1)
    int done;             ///< ticks of the current blend already output (== ticks: finished)
    int started;          ///< 0 until the first target arrived
} hs_haptic_blend;

/// Start from the zero model (no force); the first target blends in from zero. ticks >= 1.
/// Thread: any | Allocates: no
void hs_haptic_blend_init(hs_haptic_blend* b, int ticks);
/// One tick: target is the newest model (its seq tells whether it changed), evaluated at tool_m.
/// Writes the output force f_n ([3], N) and, if out != NULL, the output as a model anchored at
/// tool_m (the mix of both stiffnesses), which is what a driver renders until the next message.
/// Thread: owner only | Allocates: no
void hs_haptic_blend_step(hs_haptic_blend* b, const hs_haptic_model* target, const double tool_m[3],
                          double f_n[3], hs_haptic_model* out /* OUT, may be NULL */);
/// Drop any blend in progress and restart from zero force (after a fault).
void hs_haptic_blend_reset(hs_haptic_blend* b);

// ---------------------------------------------------------------------------------------------
// Safety filters. Each is a pure function of its inputs and a small state struct.

/// 1 when all three components are finite. Thread: any | Allocates: no
int hs_vec3_finite(const double v[3]);
/// NaN/Inf guard: a non-finite f becomes zero and *count (may be NULL) grows. Returns 1 if zeroed.
int hs_force_guard_finite(double f_n[3], int64_t* count);
/// Scale f down to |f| <= max_n (max_n >= 0), keeping its direction (also when |f| overflows).
/// Returns 1 if it was clamped. Thread: any | Allocates: no
int hs_force_clamp_magnitude(double f_n[3], double max_n);

/// Rate clamp state: the last force that left the filter.
typedef struct hs_rate_clamp {
    double prev_n[3];    ///< last output, N
    double max_rate_n_s; ///< largest |dF/dt|, N/s
} hs_rate_clamp;
/// Limit |f - prev| to max_rate * dt_s (the measured tick period, s) and remember f.
/// Returns 1 if it was clamped. Thread: owner only | Allocates: no
int hs_rate_clamp_apply(hs_rate_clamp* rc, double f_n[3], double dt_s);

/// Watchdog: a gain in [0, 1] on the force. It is 0 until the first fresh pose, ramps up over
/// ramp_s while poses arrive, and once no fresh pose came for timeout_s it ramps down so that
/// it is exactly 0 at timeout_s + ramp_s after the last fresh pose.
typedef struct hs_watchdog {
    double timeout_s;      ///< silence tolerated at full force, s (default 0.05)
    double ramp_s;         ///< ramp time down and up, s (> 0)
    double gain;           ///< current gain, [0, 1]
    int64_t last_fresh_ns; ///< time of the last fresh pose, CLOCK_MONOTONIC ns
    int seen;              ///< 1 once any fresh pose arrived
    int live;              ///< 1 while fresh poses arrive within the timeout
    int64_t trips;         ///< times the device went silent past the timeout
} hs_watchdog;
/// Initialise with gain 0 (no device yet).
void hs_watchdog_init(hs_watchdog* w, double timeout_s, double ramp_s);
/// Advance by one tick at now_ns after dt_s; fresh = 1 when a new valid pose arrived this tick.
/// Returns the gain. Thread: owner only | Allocates: no
double hs_watchdog_update(hs_watchdog* w, int fresh, int64_t now_ns, double dt_s);
/// Force the gain to 0 now (a fault); it ramps back in with fresh poses.
void hs_watchdog_trip(hs_watchdog* w);

/// Safety options. Initialise with hs_safety_default_def().
typedef struct hs_safety_def {
    double max_force_n;        ///< magnitude clamp, N
    double max_rate_n_s;       ///< rate clamp, N/s
    double watchdog_timeout_s; ///< no fresh pose for this long -> ramp down, s
    double ramp_s;             ///< watchdog ramp down / up, s (use the blend time)
    /// One output changes by at most max_rate_n_s x min(dt, this), s (the loop's period: a late
    /// tick does not allow a larger step); 0: x the measured dt.
    double step_period_s;
    int cookie; ///< set by hs_safety_default_def
} hs_safety_def;

/// Defaults: 10 N, 2000 N/s, 50 ms watchdog, 10 ms ramp, step period 0 (the measured dt).
hs_safety_def hs_safety_default_def(void);
/// 1 when def came from hs_safety_default_def and its values are finite and in range.
int hs_safety_def_valid(const hs_safety_def* def);

/// Flags describing what the filters did to one output (bitwise or).
enum {
    HS_SAFETY_NONFINITE = 1u << 0, ///< a NaN/Inf force or pose: the output was zeroed
    HS_SAFETY_MAGNITUDE = 1u << 1, ///< magnitude clamp engaged
    HS_SAFETY_RATE = 1u << 2,      ///< rate clamp engaged
    HS_SAFETY_WATCHDOG = 1u << 3,  ///< watchdog gain below 1 (no device or ramping)
};

/// Counters of the safety chain, for status reports.
typedef struct hs_safety_counters {
    int64_t nonfinite_force; ///< NaN/Inf forces zeroed
    int64_t nonfinite_pose;  ///< NaN/Inf poses rejected (output zeroed)
    int64_t magnitude;       ///< ticks the magnitude clamp engaged
    int64_t rate;            ///< ticks the rate clamp engaged
    int64_t watchdog_trips;  ///< device went silent past the timeout
} hs_safety_counters;

/// The whole chain in order: finite guard, magnitude clamp, rate clamp, watchdog gain. Between
/// faults the output changes per tick by at most (max_rate_n_s + max_force_n / ramp_s) * dt.
typedef struct hs_safety {
    hs_safety_def def;
    hs_watchdog watchdog;
    hs_rate_clamp rate;
    hs_safety_counters counters;
} hs_safety;

/// Initialise from a valid def (HS_ASSERT otherwise).
void hs_safety_init(hs_safety* s, const hs_safety_def* def);
/// New limits from a valid def (HS_ASSERT otherwise), keeping the state: the watchdog's gain
/// and the last output, so a lower force limit is reached at the rate limit, not in one step.
/// Thread: owner only | Allocates: no
void hs_safety_set_limits(hs_safety* s, const hs_safety_def* def);
/// Filter one tick's force f_n in place ([3], N). pose_fresh: a new valid pose arrived this tick;
/// pose_ok: 0 when the pose was non-finite (the output is zeroed and the watchdog tripped).
/// Magnitude clamp, watchdog gain, then the rate clamp on the force that is sent (so every
/// output differs from the previous one by at most max_rate_n_s min(dt_s, step_period_s)); a zero
/// gain gives exactly
/// zero. A non-finite force or pose gives zero at once and the force ramps back in.
/// Returns HS_SAFETY_* flags. Thread: owner only | Allocates: no
uint32_t hs_safety_apply(hs_safety* s, double f_n[3], int pose_fresh, int pose_ok, int64_t now_ns,
                         double dt_s);

// ---------------------------------------------------------------------------------------------
// Loop statistics: fixed-bin histograms from which a reader derives percentiles.

#define HS_RT_HIST_BINS   4000 ///< 1 us bins covering [0, 4 ms); one more bin counts the overflow
#define HS_RT_HIST_RECENT 32   ///< overflow samples kept, for the maximum of a window

/// Histogram of durations: count[i] holds samples in [i, i+1) us, count[HS_RT_HIST_BINS] the
/// samples >= 4 ms.
typedef struct hs_rt_hist {
    uint64_t count[HS_RT_HIST_BINS + 1];
    int64_t max_ns; ///< largest sample, ns
    /// The newest overflow samples of the rt loop's histograms: the k-th (k from 1, as
    /// count[HS_RT_HIST_BINS] reached k) is recent_ns[k % HS_RT_HIST_RECENT] with recent_seq
    /// k there; recent_seq 0 marks an unused (or torn, in a snapshot) slot.
    int64_t recent_ns[HS_RT_HIST_RECENT];
    uint64_t recent_seq[HS_RT_HIST_RECENT];
} hs_rt_hist;

/// Samples in h (sum of all bins).
uint64_t hs_rt_hist_total(const hs_rt_hist* h);
/// q-quantile (q in [0, 1]) in us: the upper edge of the bin where it falls (an upper bound),
/// max_ns for the overflow bin, 0 for an empty histogram.
double hs_rt_hist_quantile_us(const hs_rt_hist* h, double q);
/// Largest sample added between two snapshots of one cumulative rt histogram (older taken
/// first), ns: the upper edge of the highest bin that grew, or, when overflow samples were
/// added, the largest of them still in recent_ns (all of them unless more than
/// HS_RT_HIST_RECENT came in between: then of the newest HS_RT_HIST_RECENT, a lower bound).
/// 0 when nothing was added. Thread: any | Allocates: no
int64_t hs_rt_hist_window_max_ns(const hs_rt_hist* newer, const hs_rt_hist* older);

/// What the rt loop obtained from the OS (bitwise or).
enum {
    HS_RT_SCHED_FIFO = 1u << 0, ///< SCHED_FIFO granted
    HS_RT_MLOCKED = 1u << 1,    ///< mlockall(MCL_CURRENT | MCL_FUTURE) succeeded
    HS_RT_PREFAULTED = 1u << 2, ///< the stack was touched in advance
};

/// A snapshot of the loop's statistics (copied out; the loop keeps running).
typedef struct hs_rt_stats {
    uint32_t obtained;        ///< HS_RT_* flags
    int fifo_priority;        ///< SCHED_FIFO priority when granted, else 0
    double period_s;          ///< nominal period, s
    int64_t start_ns;         ///< loop start, CLOCK_MONOTONIC ns
    int64_t last_ns;          ///< wake time of the last tick, ns
    int64_t ticks;            ///< ticks run
    int64_t overruns;         ///< ticks that ended past the next deadline
    int64_t missed_deadlines; ///< deadlines skipped to catch up (no burst of late ticks)
    int64_t wake_late_max_ns; ///< worst wake-up after its deadline, ns
    hs_rt_hist tick;          ///< compute time of the tick callback
    hs_rt_hist period_err;    ///< |measured period - nominal period|
} hs_rt_stats;

/// Add run s into acc (histograms, counters, worst cases), e.g. to pool interleaved benchmark
/// segments. A zeroed acc starts empty. Thread: any | Allocates: no
void hs_rt_stats_accumulate(hs_rt_stats* acc, const hs_rt_stats* s);

#ifdef __cplusplus
}
#endif
#endif
