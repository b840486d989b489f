// SPDX-License-Identifier: MIT
// hapsim-stylus core: a simulated 3-DoF haptic stylus. Probe scripts (parse, target(t)), the
// device model (handle mass, friction, motor limits, workspace, virtual hand), rendering of the
// server's local force model between messages, an offline elastic half-space standing in for the
// server, the trace with its summary, and a lock-free mailbox for the newest force model.
// No LCM here: hs_stylus_core is pure and testable; main.c adds the network and the clock.
//
// Frames and signs: positions in the scene frame, m; forces are ON THE HANDLE, N, scene frame.
// The local model follows the wire (msgs/tool_force_t.lcm): F(p) = force + stiffness * d with
// d = p - anchor clamped to |d| <= validity_radius, so stiffness = dF/dp (negative semidefinite
// for a passive contact).
#ifndef HS_STYLUS_H
#define HS_STYLUS_H

#include <stdatomic.h>
#include <stdint.h>
#include <stdio.h>

#include "base.h"

#ifdef __cplusplus
extern "C" {
#endif

// ---------------------------------------------------------------------------------------------
// Probe scripts (format: docs/stylus.md). Parsed into a fixed array of timed segments.

#define HS_SCRIPT_MAX_SEGMENTS   4096    ///< after loop expansion
#define HS_SCRIPT_MAX_LOOP_DEPTH 8       ///< nested loop ... end
#define HS_SCRIPT_MAX_LINE       512     ///< bytes per line, including the newline
#define HS_SCRIPT_MAX_EXECUTED   1000000 ///< lines loops read again, in all (no endless parse)
#define HS_SCRIPT_MAX_LENGTH_M   1e3     ///< |coordinate|, depth, lift, m (after units)
#define HS_SCRIPT_MAX_DURATION_S 1e6     ///< the whole script, s (a typo, not a session)

/// What a segment does with the target.
typedef enum hs_seg_kind {
    HS_SEG_MOVE = 0, ///< straight line from -> to (move_to, press, drag, release, cut)
    HS_SEG_HOLD = 1, ///< stay at `from` for dur_s
} hs_seg_kind;

/// Velocity profile of a move.
typedef enum hs_profile {
    HS_PROFILE_MINJERK = 0,   ///< s(u) = 10u^3 - 15u^4 + 6u^5; peak speed = the given speed
    HS_PROFILE_TRAPEZOID = 1, ///< accelerate at accel, cruise at speed, decelerate
} hs_profile;

/// The command that produced a segment (for traces and error messages).
typedef enum hs_seg_cmd {
    HS_CMD_MOVE_TO = 0,
    HS_CMD_PRESS = 1,
    HS_CMD_DRAG = 2,
    HS_CMD_RELEASE = 3,
    HS_CMD_HOLD = 4,
    HS_CMD_CUT = 5,
    HS_CMD_TOUCH = 6,
} hs_seg_cmd;

/// One timed piece of the target trajectory.
typedef struct hs_script_segment {
    int kind;              ///< hs_seg_kind
    int cmd;               ///< hs_seg_cmd
    int line;              ///< source line of the command
    int profile;           ///< hs_profile (moves)
    double t0_s;           ///< start time, s from script start
    double dur_s;          ///< duration, s (>= 0)
    double from_m[3];      ///< start point, m, scene frame
    double to_m[3];        ///< end point, m (== from for a hold)
    double speed_m_s;      ///< requested (peak) speed, m/s (moves)
    double accel_m_s2;     ///< trapezoid acceleration, m/s^2
    uint32_t buttons;      ///< tool_pose button bits held during the segment (cut: PRIMARY)
    double touch_force_n;  ///< touch: force along the normal that ends the search, N
    double touch_ref_m[3]; ///< touch: where the script expects the surface (see hs_script_runner)
    double quat_wxyz[4];   ///< tool orientation published during the segment (set by `cut`)
} hs_script_segment;

/// A parsed script. Create with hs_script_create (large: fixed segment array).
typedef struct hs_script {
    char name[256]; ///< file name (or the name given to parse_string), for messages
    int n_segments;
    double duration_s;         ///< end of the last segment, s
    double start_m[3];         ///< target (and handle) position at t = 0, m
    int has_start;             ///< 1 when the script set `start` (else start = origin, or 0)
    int start_line;            ///< line that set the start (0: default)
    int has_origin;            ///< 1 when the script set `origin`
    double origin_m[3];        ///< workspace centre the script asks for, m
    int has_surface;           ///< 1 when the script set `surface`
    double surface_point_m[3]; ///< a point of the surface the script presses, m
    double surface_normal[3];  ///< its outward unit normal
    hs_script_segment seg[HS_SCRIPT_MAX_SEGMENTS];
} hs_script;

/// Allocate an empty script (duration 0, start at the origin). @param out OUT
hs_status hs_script_create(hs_script** out, hs_err* err);
/// Release; accepts NULL, sets *s = NULL.
void hs_script_destroy(hs_script** s);
/// Parse text (NUL-terminated) named `name` into s (replacing its content). On error s is empty
/// and err->msg reads "name:line: problem". Allocates: no
hs_status hs_script_parse_string(hs_script* s, const char* text, const char* name, hs_err* err);
/// Read and parse a file. HS_ERR_IO when it cannot be read, HS_ERR_PARSE on bad content.
hs_status hs_script_parse_file(hs_script* s, const char* path, hs_err* err);

/// Target at t_s (clamped to [0, duration]): position pos_m ([3], m), velocity vel_m_s ([3],
/// m/s, may be NULL), buttons (may be NULL). Returns the segment index (-1 when empty).
/// *hint (may be NULL) caches the last index for O(1) sequential lookups.
/// Thread: any | Allocates: no
int hs_script_eval(const hs_script* s, double t_s, double pos_m[3], double vel_m_s[3],
                   uint32_t* buttons, int* hint);

/// Runs a script with its `touch` searches resolved against the force the handle feels: a
/// touch ends as soon as the force along its normal reaches its threshold, and everything
/// after it is shifted in space (by where the surface was found relative to where the script
/// expected it: the crossing of the search line with the `surface` plane, or without one the
/// touch's start) and in time (the rest of the search is skipped). Without touches it is
/// hs_script_eval.
typedef struct hs_script_runner {
    const hs_script* s;
    double t_off_s;  ///< script time = run time - t_off_s
    double off_m[3]; ///< added to the script's positions after the last resolved touch
    int hint;
    int touch_seg;     ///< the touch being searched (-1: none)
    int has_onset;     ///< the search felt a first force (contact onset)
    double onset_m[3]; ///< script position of the target at the onset, m
    int64_t found;     ///< touches that found the surface
    int64_t missed;    ///< touches that ran their whole depth without a force
} hs_script_runner;

/// Touch events of one runner step (bitwise or).
enum {
    HS_TOUCH_FOUND = 1u << 0,  ///< the surface was found this step
    HS_TOUCH_MISSED = 1u << 1, ///< a touch ended without finding it
};

/// Start at run time 0 without offsets.
void hs_script_runner_init(hs_script_runner* r, const hs_script* s);
/// Target at run time t_s given the force the handle felt in the last tick (force_n [3], N).
/// Fills pos/vel/buttons as hs_script_eval (vel, buttons may be NULL) and *events (may be NULL)
/// with HS_TOUCH_* bits. Returns the segment index. Thread: device loop | Allocates: no
int hs_script_runner_eval(hs_script_runner* r, double t_s, const double force_n[3], double pos_m[3],
                          double vel_m_s[3], uint32_t* buttons, uint32_t* events);
/// Run time at which the script ends with the offsets found so far, s.
double hs_script_runner_end(const hs_script_runner* r);

// ---------------------------------------------------------------------------------------------
// The force model received from the server (one tool_force message, in device terms).

/// A local model as the driver keeps it. A zeroed struct renders zero force.
typedef struct hs_stylus_model {
    int64_t seq;         ///< tool_force seq (0: none yet)
    int64_t version;     ///< model_version
    int64_t pose_seq;    ///< echoed pose seq
    int64_t arrival_ns;  ///< device clock (CLOCK_MONOTONIC or virtual) when it arrived, ns
    int64_t latency_us;  ///< arrival (wall clock) - echoed pose utime, us; -1 unknown
    int32_t state;       ///< HAPSIM_TOOL_FORCE_STATE_* (3 = stopped renders zero)
    double force_n[3];   ///< N, force at the anchor
    double anchor_m[3];  ///< m
    double stiffness[9]; ///< N/m, row-major dF/dp
    double radius_m;     ///< validity radius, m (0: force_n everywhere, no stiffness)
    double timeout_s;    ///< render at full strength at most this long after arrival, s
} hs_stylus_model;

/// 1 when every number is finite, radius >= 0 and timeout >= 0.
int hs_stylus_model_valid(const hs_stylus_model* m);
/// The model's force at p ([3], m) into f_n ([3], N), d clamped to the radius. Returns 1 inside.
int hs_stylus_model_eval(const hs_stylus_model* m, const double p[3], double f_n[3]);

// ---------------------------------------------------------------------------------------------
// Device model.

/// Device parameters. Initialise with hs_stylus_default_def().
typedef struct hs_stylus_def {
    double mass_kg;            ///< handle mass, kg
    double viscous_n_s_m;      ///< handle viscous friction, N s/m
    double coulomb_n;          ///< handle Coulomb friction, N
    double hand_stiffness_n_m; ///< virtual hand spring to the target, N/m
    double hand_damping_n_s_m; ///< virtual hand damper on (target velocity - handle velocity)
    double max_force_n;        ///< motor force limit (magnitude clamp), N
    double max_rate_n_s;       ///< motor force rate limit, N/s
    double workspace_m[3];     ///< workspace box size, m (x, y, z), centred on origin_m
    double origin_m[3];        ///< workspace centre in scene coordinates, m
    double timeout_s;          ///< the rendered force is exactly 0 at this model age, s
    double ramp_s;             ///< ramp-down length inside timeout_s, s
    double outside_ramp_s;     ///< outside the validity radius the force ramps to 0 over this, s
    double max_dt_s;           ///< longest integration substep; longer ticks are split, s
    double tick_s;             ///< nominal tick (1 / loop rate), s: sets the stability limit
    int cookie;                ///< set by hs_stylus_default_def
} hs_stylus_def;

/// Longest timeout_s (and so ramp_s) a def may have: a device's own timeout is a safety limit
/// of milliseconds; far above, the ns arithmetic of the ramp overflows (~9.2e9 s).
#define HS_STYLUS_MAX_TIMEOUT_S 60.0

/// 50 g, 0.2 N s/m, 0.02 N, hand 400 N/m / 8 N s/m, 3.3 N, 2000 N/s, 160 x 120 x 70 mm at the
/// scene origin, timeout 100 ms with a 20 ms ramp, 20 ms outside ramp, 2 ms substeps, 1 ms
/// ticks.
hs_stylus_def hs_stylus_default_def(void);
/// HS_OK when def came from hs_stylus_default_def and every value is finite and in range;
/// else HS_ERR_INVALID naming the field. In range includes a stable integrator:
/// hand_stiffness_n_m h^2 < 4 mass_kg + 2 h (hand_damping + viscous), h the substep of a tick_s
/// tick.
hs_status hs_stylus_def_check(const hs_stylus_def* def, hs_err* err);

/// What happened in a tick (bitwise or).
enum {
    HS_TICK_MAGNITUDE = 1u << 0,    ///< motor magnitude clamp engaged
    HS_TICK_RATE = 1u << 1,         ///< rate clamp engaged
    HS_TICK_WORKSPACE = 1u << 2,    ///< the handle hit the workspace box
    HS_TICK_TIMEOUT = 1u << 3,      ///< model older than its hold time: ramping / zero
    HS_TICK_OUTSIDE = 1u << 4,      ///< handle outside the model's validity radius
    HS_TICK_NO_MODEL = 1u << 5,     ///< no model received yet
    HS_TICK_TOUCH_FOUND = 1u << 6,  ///< a `touch` found the surface at this tick
    HS_TICK_TOUCH_MISSED = 1u << 7, ///< a `touch` ended without finding it
};

/// One tick of the device, as traced.
typedef struct hs_stylus_tick {
    double t_s;           ///< script time, s
    double target_m[3];   ///< virtual hand target, m
    double handle_m[3];   ///< handle position after the tick, m
    double handle_vel[3]; ///< handle velocity after the tick, m/s
    double f_received[3]; ///< force field of the newest model message, N
    double f_applied[3];  ///< motor force applied during the tick, N
    double model_age_s;   ///< age of the newest model, s (-1: none)
    double latency_us;    ///< latency of the newest model, us (-1: unknown)
    double work_j;        ///< f_applied . (handle after - handle before), J
    int segment;          ///< script segment index
    uint32_t flags;       ///< HS_TICK_*
} hs_stylus_tick;

/// Device state (caller storage; init/no deinit needed).
typedef struct hs_stylus_device {
    hs_stylus_def def;
    double pos_m[3];        ///< handle position, m
    double vel_m_s[3];      ///< handle velocity, m/s
    double prev_force_n[3]; ///< last applied motor force (rate clamp), N
    double outside_s;       ///< time spent outside the current model's radius, s
    double gain;            ///< applied share of the rendered force, [0, 1]; rises over ramp_s
    hs_stylus_model model;  ///< newest model
    int has_model;
    int64_t workspace_hits; ///< ticks the box stopped the handle
} hs_stylus_device;

/// Initialise from a checked def with the handle at rest at p0_m ([3], m; pulled into the box).
void hs_stylus_device_init(hs_stylus_device* d, const hs_stylus_def* def, const double p0_m[3]);
/// Replace the model (a newer message arrived). Thread: device loop | Allocates: no
void hs_stylus_device_set_model(hs_stylus_device* d, const hs_stylus_model* m);
/// The force the device would render at p now (model, age and outside gains, clamps not applied)
/// into f_n ([3], N). Returns HS_TICK_* flags. Does not change state.
uint32_t hs_stylus_device_render(const hs_stylus_device* d, const double p[3], int64_t now_ns,
                                 double f_n[3]);
/// Advance by the real elapsed dt_s: render the model at the current handle position (its gain
/// drops at once but rises back over ramp_s, from 0 at init), clamp (magnitude, rate), integrate
/// the handle semi-implicitly under hand + motor + friction forces, keep it in the workspace box,
/// fill *out (its t_s / segment are left to the caller). Thread: device loop | Allocates: no
void hs_stylus_device_step(hs_stylus_device* d, const double target_m[3],
                           const double target_vel[3], int64_t now_ns, double dt_s,
                           hs_stylus_tick* out /* OUT */);

// ---------------------------------------------------------------------------------------------
// Offline server: an elastic half-space that answers each pose with a local model.

/// Half-space {x : n . (x - point) < 0} pushing out along n with stiffness k.
typedef struct hs_halfspace {
    double point_m[3];    ///< a point of the plane, m
    double normal[3];     ///< outward unit normal
    double stiffness_n_m; ///< N/m
    double radius_m;      ///< validity radius of the models it sends, m
    double timeout_s;     ///< timeout of the models it sends, s
    int force_only;       ///< 1: send no stiffness (a zero-order server, for contrast in tests)
} hs_halfspace;

/// The model the half-space sends for a pose at p ([3], m): anchored at p.
void hs_halfspace_model(const hs_halfspace* h, const double p[3], hs_stylus_model* out /* OUT */);

// ---------------------------------------------------------------------------------------------
// Trace: rows in memory (allocated before the run), CSV and summary at the end.

/// Numbers at the end of a run.
typedef struct hs_stylus_summary {
    int64_t rows;               ///< ticks traced
    int64_t dropped;            ///< ticks not traced (capacity)
    double duration_s;          ///< time of the last row, s
    double peak_force_n;        ///< max |f_applied|, N
    double steady_force_n[3];   ///< mean f_applied over the 2nd half of the longest hold, N
    double steady_force_norm_n; ///< |steady_force_n|, N
    int steady_segment;         ///< the hold used (-1: no hold in the script)
    double max_force_step_n;    ///< max |f_k - f_k-1| over ticks, N
    double energy_j;            ///< sum of f_applied . dp: energy passed into the handle, J
    double energy_in_j;         ///< sum of the positive parts, J
    double energy_out_j;        ///< sum of the negative parts (<= 0), J
    double latency_p50_us;      ///< median latency over rows that have one, us (-1: none)
    double latency_p99_us;      ///< us (-1: none)
    double model_age_max_s;     ///< largest model age seen, s (-1: no model)
    int64_t clamp_magnitude;    ///< ticks with HS_TICK_MAGNITUDE
    int64_t clamp_rate;         ///< ticks with HS_TICK_RATE
    int64_t timeouts;           ///< ticks with HS_TICK_TIMEOUT
    int64_t workspace_hits;     ///< ticks with HS_TICK_WORKSPACE
    int64_t touches_found;      ///< ticks with HS_TICK_TOUCH_FOUND
    int64_t touches_missed;     ///< ticks with HS_TICK_TOUCH_MISSED
} hs_stylus_summary;

typedef struct hs_stylus_trace hs_stylus_trace;

/// Room for `capacity` rows. @param out OUT
hs_status hs_stylus_trace_create(int64_t capacity, hs_stylus_trace** out, hs_err* err);
/// Release; accepts NULL, sets *t = NULL.
void hs_stylus_trace_destroy(hs_stylus_trace** t);
/// Append one tick (counted as dropped when full). Thread: device loop | Allocates: no
void hs_stylus_trace_add(hs_stylus_trace* t, const hs_stylus_tick* tick);
/// Rows held.
int64_t hs_stylus_trace_rows(const hs_stylus_trace* t);
/// Row i (0 <= i < rows). Valid until destroy.
const hs_stylus_tick* hs_stylus_trace_row(const hs_stylus_trace* t, int64_t i);
/// Compute the summary; script (may be NULL) tells which segments are holds.
void hs_stylus_trace_summary(const hs_stylus_trace* t, const hs_script* script,
                             hs_stylus_summary* out /* OUT */);
/// Write the CSV (header, rows, then "# key=value" summary lines) to path.
hs_status hs_stylus_trace_write_csv(const hs_stylus_trace* t, const hs_stylus_summary* sum,
                                    const char* path, hs_err* err);
/// Print the summary in a few human-readable lines (trace_path may be NULL).
void hs_stylus_summary_print(FILE* f, const hs_stylus_summary* sum, const char* trace_path);

/// The CSV header line (no newline), for readers and tests.
extern const char hs_stylus_trace_header[];

/// Read a trace CSV written by hs_stylus_trace_write_csv back into a new trace (rows only; the
/// work column is recomputed from consecutive handle positions). Errors name file and line.
hs_status hs_stylus_trace_read_csv(const char* path, hs_stylus_trace** out, hs_err* err);

/// Tolerances of a trace comparison: a sample passes when |F_run - F_ref| <= abs_n + rel *
/// peak |F_ref|.
typedef struct hs_trace_tol {
    double abs_n;  ///< N
    double rel;    ///< share of the reference's peak force
    double skip_s; ///< ignore samples before this time, s
} hs_trace_tol;

/// Result of comparing a run against a reference trace.
typedef struct hs_trace_diff {
    int64_t samples;    ///< reference rows compared
    int64_t failed;     ///< samples outside the tolerance
    double max_err_n;   ///< largest |F_run(t) - F_ref(t)|, N
    double max_err_t_s; ///< where, s
    double rms_err_n;   ///< N
    double ref_peak_n;  ///< peak |F_ref|, N
    double allowed_n;   ///< abs_n + rel * ref_peak_n, N
    double coverage_s;  ///< time both traces cover, s
} hs_trace_diff;

/// Compare the applied force of run against ref at ref's sample times (run linearly
/// interpolated, so runs with jittery ticks compare fairly). Returns 1 when every sample passes
/// and run spans ref from max(its start, tol->skip_s) to its end, within 10 ms at each end,
/// else 0.
int hs_stylus_trace_compare(const hs_stylus_trace* ref, const hs_stylus_trace* run,
                            const hs_trace_tol* tol, hs_trace_diff* out /* OUT */);

// ---------------------------------------------------------------------------------------------
// Offline run: the device against the half-space in virtual time (deterministic).

/// Offline run options.
typedef struct hs_offline_def {
    hs_halfspace surface;   ///< the stand-in server
    double dt_s;            ///< tick, s (1 ms)
    int period_ticks;       ///< the half-space answers every period_ticks poses (>= 1)
    int delay_ticks;        ///< an answer arrives delay_ticks after its pose (1..63)
    double duration_s;      ///< run length, s (<= 0: the script's duration + 0.5 s; <= 1e7)
    const atomic_int* stop; ///< the run ends early once this reads nonzero (a signal); may be NULL
} hs_offline_def;

/// Run script on device def against the offline half-space; rows into trace (may be NULL).
/// The final device state goes to *dev_out (may be NULL). Allocates: no
hs_status hs_stylus_run_offline(const hs_script* script, const hs_stylus_def* def,
                                const hs_offline_def* off, hs_stylus_trace* trace,
                                hs_stylus_device* dev_out, hs_err* err);

// ---------------------------------------------------------------------------------------------
// Mailbox: a triple buffer handing the newest model from the receive thread to the device
// loop. One writer, one reader, wait-free, the latest value wins, never torn.

#define HS_MAILBOX_FRESH 4u

typedef struct hs_stylus_mailbox {
    hs_stylus_model slot[3];
    atomic_uint middle; ///< index of the middle slot | HS_MAILBOX_FRESH when unread
    unsigned back;      ///< writer's slot (writer only)
    unsigned front;     ///< reader's slot (reader only)
} hs_stylus_mailbox;

/// Empty mailbox. Thread: before both sides start.
void hs_stylus_mailbox_init(hs_stylus_mailbox* mb);
/// Publish m as the newest value. Thread: writer only | Lock-free: yes | Allocates: no
void hs_stylus_mailbox_put(hs_stylus_mailbox* mb, const hs_stylus_model* m);
/// If a value newer than the last read arrived, copy it to *out and return 1, else 0.
/// Thread: reader only | Lock-free: yes | Allocates: no
int hs_stylus_mailbox_take(hs_stylus_mailbox* mb, hs_stylus_model* out /* OUT */);

#ifdef __cplusplus
}
#endif
#endif
