// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim haptic_sim: the deformation thread and the 1 kHz rt thread of one deformable body and
// one probe, running in-process. hapsim-server wraps this with LCM; tests drive it directly.
//
// DESIGN. Three parties, each owning its data; only fixed-size values cross, lock-free:
//  - deformation thread (started here): owns the body (hs_body) and the condensed compliance
//    (hs_compliance). Each step it takes the newest contact from rt, applies its forces on the
//    tissue as nodal loads, steps the body (implicit Euler, def.body.dt, paced in real time),
//    and publishes a contact snapshot (hs_contact_snapshot) for rt and a displacement frame for
//    readers. With no contact and the body at rest it does not step; it only refreshes the
//    snapshot's candidate set when the tool wanders off.
//  - rt thread (hs_rt_loop + haptic tick of server/rt): per tick reads the newest pose from the
//    memory device, solves the contact against the newest snapshot (hs_contact_solve), hands
//    the result back to the deformation thread, blends, applies the safety chain and writes
//    force + local model to the memory device.
//  - the caller (test harness or the server's net thread): feeds poses, takes outputs, reads
//    frames and statistics.
#ifndef HAPSIM_HAPTIC_SIM_H
#define HAPSIM_HAPTIC_SIM_H

#include "base.h"
#include "body.h"
#include "compliance.h"
#include "cut.h"
#include "haptic.h"
#include "mesh.h"

#ifdef __cplusplus
extern "C" {
#endif

/// The probe: a sphere at the tool tip. Initialise with hs_probe_default_def().
typedef struct hs_probe_def {
    double radius_m;       ///< sphere radius, m
    double reach_margin_m; ///< candidates cover radius + margin around the tool, m
    int cache_nodes;     ///< column cache capacity, nodes (>= HS_CONTACT_MAX_CAND + HS_MAX_CONTACT)
    int max_new_columns; ///< column solves allowed per deformation step, nodes
    double min_radius_m; ///< local model validity radius, lower clamp, m
    double max_radius_m; ///< local model validity radius, upper clamp, m
    double model_timeout_s; ///< local model timeout sent with every force, s
    double free_relax;      ///< relaxation of the contact-free surface per step, (0, 1]
    int cookie;             ///< set by hs_probe_default_def
} hs_probe_def;

/// Defaults: radius 1 cm, margin 1 cm, 96 cached columns, 64 new columns per step, validity
/// radius in [0.2 mm, 5 mm], timeout 50 ms, contact-free relaxation 0.5.
hs_probe_def hs_probe_default_def(void);

/// Everything the in-process haptic simulation needs. Initialise with hs_haptic_sim_default_def.
typedef struct hs_haptic_sim_def {
    hs_body_def body;       ///< body model, material, dt (the deformation step and its pacing;
                            ///< at most 1 s)
    hs_probe_def probe;     ///< probe sphere and compliance cache
    hs_safety_def safety;   ///< force clamps and watchdog
    double rate_hz;         ///< rt tick rate, Hz (1..1e5)
    int fifo_priority;      ///< SCHED_FIFO priority to ask for (0: do not ask)
    int lock_memory;        ///< 1: mlockall when permitted
    int blend_ticks;        ///< blend length on a new snapshot, ticks
    double sleep_speed_m_s; ///< the body counts as at rest below this largest nodal speed, m/s
    double idle_poll_s;     ///< deformation thread wake-up period while at rest, s (<= 1)
    /// Optional hooks run on the rt thread before its first and after its last tick (tests use
    /// them to mark the thread, e.g. for allocation counting); may be NULL.
    void (*rt_on_start)(void* ctx);
    void (*rt_on_stop)(void* ctx);
    void* rt_hook_ctx; ///< passed to the hooks
    /// 1: the deformation thread picks the body's solver from its measured steps, the most
    /// accurate that keeps the step rate 1 / body.dt (direct, then PCG, then warped; with
    /// auto_exact_tangent only direct and PCG), starting with direct when the factor has at most
    /// 250k entries or the factorisation create times fits 35 % of the period, else with the
    /// cheapest (with step_cost: that hook's direct cost decides), and switches with
    /// hysteresis when the load changes (docs/server.md, "Solver choice"). body.solver is
    /// ignored. Only for the co-rotated model (else off: body.solver is used).
    int auto_solver;
    int auto_exact_tangent; ///< auto_solver: only solvers that solve with the exact tangent
    /// Optional (tests): the cost booked for a step (body + snapshot) that took `ms` with
    /// `solver`, and for the direct step at create (`ms`: the timed factorisation), ms; NULL:
    /// the measured wall times. No clock enters the solver choice then. Runs on the
    /// deformation thread (and in create).
    double (*step_cost)(void* ctx, hs_solver_kind solver, double ms);
    void* step_cost_ctx; ///< passed to step_cost
    /// 1: the compliance is set up on a worker thread started by create (which then returns
    /// without waiting for it); until the deformation thread takes it, rt answers zero force
    /// (no snapshot), the body steps and frames go out as usual (stats comp_state). 0: create
    /// sets it up (default). hs_haptic_sim_enable_cutting waits for it.
    int background_setup;
    /// Tools (1..HS_MAX_TOOLS), each a probe sphere driven by its own device (pose in, force
    /// out: hs_haptic_sim_feed_tool_pose, hs_haptic_sim_take_tool_output) with its own blend,
    /// safety chain and watchdog; all tools' contacts are one problem per tick
    /// (hs_contact_solve_tools) and the body takes all their forces. Tool 0 is the device of
    /// hs_haptic_sim_feed_pose / take_output. With cutting on, tool 0 is the blade and the
    /// others are probes on the cut tissue while the compliance matches the newest cut (stats
    /// comp_version == topology_version; no contact before that). Default 1.
    int tools;
    /// Sphere radius of tool t >= 1, m (0: probe.radius_m; [0] unused: tool 0 is probe).
    double tool_radius_m[HS_MAX_TOOLS];
    int cookie; ///< set by hs_haptic_sim_default_def
} hs_haptic_sim_def;

/// Defaults: hs_body_default_def (co-rotated model), probe and safety defaults, 1 kHz, FIFO 80,
/// lock memory, 10 blend ticks, at rest below 0.1 mm/s, 2 ms idle poll.
hs_haptic_sim_def hs_haptic_sim_default_def(void);

/// Statistics, copied out.
typedef struct hs_haptic_sim_stats {
    hs_rt_stats rt;            ///< loop period, tick cost, overruns
    int64_t rt_ticks;          ///< haptic ticks run
    int64_t poses;             ///< valid poses taken by rt
    int64_t blends;            ///< blends started (snapshot changes seen by rt)
    hs_safety_counters safety; ///< safety chain counters
    int64_t steps;             ///< deformation steps
    int64_t snapshots;         ///< snapshots published
    int64_t column_solves;     ///< compliance columns solved
    int64_t step_failures;     ///< body steps that failed (state kept)
    double step_ms_last;       ///< wall time of the last step + snapshot, ms
    double step_ms_max;        ///< worst step + snapshot, ms
    double snapshot_ms_last;   ///< of the last, the snapshot alone (incl. column solves), ms
    double snapshot_ms_max;    ///< worst snapshot alone, ms
    double setup_ms;           ///< compliance set-up (factor + diagonal blocks), ms
    int sleeping;              ///< 1 while the body is at rest and not stepping
    int candidates;            ///< candidates in the newest snapshot
    int coupled;               ///< of them with exact off-diagonal blocks
    hs_contact contact;        ///< the newest contact the deformation thread received
    int64_t cut_sweeps;        ///< blade sweeps run (cutting on)
    int64_t cut_steps;         ///< of them that changed the mesh (each bumps topology_version)
    int64_t cut_removed;       ///< tets removed so far
    int64_t topology_version;  ///< cut topology version (0 before the first cut)
    int64_t cut_failures;      ///< sweeps or compliance rebuilds that failed (state kept)
    double cut_ms_last;      ///< last changing cut step: sweep + body sync + topology hand-over, ms
    double cut_ms_max;       ///< worst of them, ms
    double sweep_ms_last;    ///< of the last, the sweep alone (the cut's geometry), ms
    double comp_ms_last;     ///< the last compliance update (in a cut step) or rebuild, ms
    int64_t comp_version;    ///< topology version the compliance was built on (0: uncut)
    int64_t comp_rebuilds;   ///< rebuilds swapped in
    int64_t comp_discarded;  ///< rebuilds dropped because a newer cut came meanwhile
    int64_t comp_updates;    ///< cut steps the compliance followed at once (no rebuild)
    int comp_building;       ///< 1 while a rebuild runs beside the deformation thread
    int64_t cut_done_ns;     ///< hs_now_ns when the last changing cut step ended (0: none)
    int64_t comp_swap_ns;    ///< hs_now_ns when the compliance last became valid (0: none)
    int64_t loops;           ///< deformation-loop passes (it keeps going during rebuilds)
    double cut_force_n[3];   ///< cutting resistance on the blade in the newest snapshot, N
    int cutting;             ///< 1 when the newest sweep cut tissue
    double free_relax_w;     ///< relaxation of the contact-free surface in use (<= free_relax)
    int64_t free_relax_cuts; ///< steps whose growing correction cut it (a diverging iteration)
    double depth_max_m;      ///< deepest press seen (hs_contact.depth_m), m
    int64_t deep_loops;      ///< deformation loops whose press was deeper than validated
                             ///< (hs_contact_validated_depth: the force is unchecked there)
    // Deformation step timing (step + snapshot, the deformation thread's own clock).
    double step_ms_p50;         ///< median over the newest HS_SIM_STEP_WINDOW steps, ms
    double step_ms_p99;         ///< 99th percentile over them, ms
    double step_ms_p50_all;     ///< median since start (0.1 ms bins, upper edge), ms
    double step_ms_p99_all;     ///< 99th percentile since start, ms
    double step_cpu_ms_p50_all; ///< the deformation thread's CPU time per step, median, ms
    double step_cpu_ms_p99_all; ///< and its 99th percentile since start (one core's cost), ms
    int64_t step_overruns;      ///< steps longer than body.dt (the nominal step period)
    double sim_hz_target;       ///< step rate the thread paces to now; < 1 / body.dt when lowered
    int64_t rate_changes;       ///< times that rate was lowered or raised again
    int solver;                 ///< hs_solver_kind the body steps with now
    int64_t solver_switches;    ///< auto_solver: switches made
    double solver_cost_ms[3];   ///< auto_solver: body step cost per hs_solver_kind, ms (0: unknown)
    double factor_ms;           ///< auto_solver: the factorisation timed at create, ms
    /// The compliance: 0 in use, 1 set-up running (background_setup; zero force meanwhile), 2
    /// set up but not yet taken by the deformation thread, -1 its set-up failed (zero force;
    /// hs_haptic_sim_setup_error says why)
    int comp_state;
} hs_haptic_sim_stats;

#define HS_SIM_STEP_WINDOW 128 ///< steps in the recent window of hs_haptic_sim_stats

typedef struct hs_haptic_sim hs_haptic_sim;

/// Build the body, the compliance (same material, same fixed nodes) and the threads' buffers.
/// fixed[n_nodes] (1 = fixed). The mesh must outlive the sim. Nothing runs yet. @param out OUT
/// Thread: control | Allocates: yes
hs_status hs_haptic_sim_create(const hs_mesh* mesh, const hs_haptic_sim_def* def,
                               const unsigned char* fixed, hs_haptic_sim** out, hs_err* err);
/// Stop if running, then release; accepts NULL, sets *sim = NULL.
void hs_haptic_sim_destroy(hs_haptic_sim** sim);
/// Start the deformation thread and the rt thread; again after hs_haptic_sim_stop, going on
/// from the kept state (the blade starts afresh: no sweep spans the stop). Thread: control
hs_status hs_haptic_sim_start(hs_haptic_sim* sim, hs_err* err);
/// Stop both threads and join them. Idempotent. Thread: control | Blocks: yes
void hs_haptic_sim_stop(hs_haptic_sim* sim);
/// A rebuild of the same scene (new material, reset): before sim's first start, with from
/// stopped, sim's 1 kHz loop goes on where from's left off: the device's last pose, watchdog
/// gain and rate clamp (the force does not ramp in again), and from's last force model, given
/// until sim's deformation thread publishes its first snapshot, which is then blended in (with
/// several tools, each goes on from its own last pose, gain, clamp and output). That
/// thread starts from from's last contact (its forces on the body, the tool position). The
/// body's state is not taken: hs_body_set_state does that. Pose seqs fed to sim must go on
/// growing from from's (lower ones are stale and dropped). HS_ERR_INVALID when sim has run,
/// from runs, or the meshes differ in node count. Thread: control | Allocates: no
hs_status hs_haptic_sim_take_over(hs_haptic_sim* sim, const hs_haptic_sim* from, hs_err* err);
/// New force limits (magnitude, rate, watchdog) without a rebuild, running or stopped: the rt
/// thread takes them at its next tick, keeping its state, so a lower force limit is reached at
/// the rate limit. HS_ERR_INVALID (nothing changed) for an invalid def. A cutting sim's blade
/// keeps the force limit it was created with as its own cap.
/// Thread: control | Allocates: no | Blocks: no
hs_status hs_haptic_sim_set_safety(hs_haptic_sim* sim, const hs_safety_def* safety);

/// Hand a tool pose to the rt thread (newest wins; pose->seq must grow).
/// Thread: one feeder | Allocates: no | Lock-free: yes | Blocks: no
void hs_haptic_sim_feed_pose(hs_haptic_sim* sim, const hs_haptic_pose* pose);
/// Newest rt output (force and local model). Returns 1 when new since the last call.
/// Thread: one consumer | Allocates: no | Lock-free: yes | Blocks: no
int hs_haptic_sim_take_output(hs_haptic_sim* sim, hs_haptic_output* out /* OUT */);
/// Tools the sim was created with (def.tools).
int hs_haptic_sim_tools(const hs_haptic_sim* sim);
/// Hand tool's pose to the rt thread (tool 0: as hs_haptic_sim_feed_pose; pose->seq must grow
/// per tool). Thread: one feeder per tool | Allocates: no | Lock-free: yes | Blocks: no
void hs_haptic_sim_feed_tool_pose(hs_haptic_sim* sim, int tool, const hs_haptic_pose* pose);
/// Newest rt output of tool (force and local model). Returns 1 when new since the last call.
/// Thread: one consumer per tool | Allocates: no | Lock-free: yes | Blocks: no
int hs_haptic_sim_take_tool_output(hs_haptic_sim* sim, int tool, hs_haptic_output* out /* OUT */);
struct hs_haptic_rt_counters;
/// The rt counters of tool's tick (poses, blends, safety: its own watchdog trips).
/// Thread: any | Allocates: no | Lock-free: yes
void hs_haptic_sim_tool_counters(hs_haptic_sim* sim, int tool,
                                 struct hs_haptic_rt_counters* out /* OUT */);
/// Newest displacement frame u[3 n_nodes] (m) and its step number. Returns 1 when new.
/// Thread: one reader | Allocates: no | Lock-free: yes | Blocks: no
int hs_haptic_sim_read_frame(hs_haptic_sim* sim, double* u /* OUT [3n] */,
                             int64_t* step /* OUT, may be NULL */);
/// Copy the statistics. Thread: one reader (control) | Allocates: no | Lock-free: yes
void hs_haptic_sim_stats_get(hs_haptic_sim* sim, hs_haptic_sim_stats* out /* OUT */);
struct hs_spsc_ring;
/// Per-tick telemetry ring of the rt thread (items: hs_haptic_telemetry of server/rt/haptic_rt.h;
/// pop with hs_spsc_ring_pop). One consumer. Thread: one consumer
struct hs_spsc_ring* hs_haptic_sim_telemetry(hs_haptic_sim* sim);
/// Cutting with a scalpel. Initialise with hs_haptic_cut_default_def().
typedef struct hs_haptic_cut_def {
    /// Cut rules. The orphan rule is forced to PIN (the body holds such a node where it is). The
    /// fragment rule: DROP (default: a piece the fixed region does not hold leaves the scene) or
    /// FIX (it stays in the body with its mass and falls under gravity or drifts; the
    /// compliance leaves it out, so the probe does not touch it).
    hs_cut_def cut;
    double blade_a[3]; ///< blade start, tool frame, m
    double blade_b[3]; ///< blade end, tool frame, m
    /// Cutting force per metre of mesh edge cut per min_travel_m of blade travel, N/m (a
    /// longer sweep's edge length is scaled down to min_travel_m: the force does not grow with
    /// the speed). A blade still for 50 ms feels none.
    double toughness_n_m;
    double max_force_n;      ///< cutting force cap, N
    double min_travel_m;     ///< blade travel (either end) gathered before a sweep runs, m
    uint32_t engage_buttons; ///< the blade cuts while any of these pose buttons is held (0: always)
    /// 1: while the buttons are released, the tool is the probe sphere (hs_haptic_sim_def.probe)
    /// on the cut tissue, from the moment the compliance matches the newest cut (stats
    /// comp_version == topology_version; no contact before that). 0 (default): never a probe.
    int probe_when_released;
    int cookie; ///< set by hs_haptic_cut_default_def
} hs_haptic_cut_def;

/// Defaults: hs_cut_default_def without validation, blade 0 .. 10 mm along tool z, toughness
/// 20 N/m, cap 1.5 N, 0.5 mm travel per sweep, engaged by button 0.
hs_haptic_cut_def hs_haptic_cut_default_def(void);

/// Turn cutting on (before hs_haptic_sim_start). mesh must be the mesh the sim was created on
/// (cuts move its x0; nobody else may read x0 while the sim runs: use
/// hs_haptic_sim_take_topology). The tool then is a blade: the probe contact is off, the felt
/// force is the cutting resistance (blended on each new snapshot); with probe_when_released
/// the released tool probes the cut tissue. The haptic compliance follows each cut step
/// exactly, in the step (hs_compliance_change_elements; stats comp_updates); where it cannot
/// (cut.fragment FIX, a failed update) it is rebuilt on a worker thread once the blade is
/// released and swapped in between two steps (stats comp_*). Allocates: yes (the compliance's
/// partial refactor data: one full factorisation, 2-3.5x the factor's memory)
hs_status hs_haptic_sim_enable_cutting(hs_haptic_sim* sim, hs_mesh* mesh,
                                       const hs_haptic_cut_def* def, hs_err* err);

/// What the cuts since the previous hs_haptic_sim_take_topology changed (caller storage).
typedef struct hs_haptic_cut_event {
    int64_t old_version;   ///< topology version at the previous take
    int64_t new_version;   ///< topology version now
    int n_removed;         ///< tets removed since then
    int* removed_tets;     ///< [n_tets of the mesh] caller storage; mesh tet indices
    int n_moved;           ///< distinct vertices moved since then
    int* moved_nodes;      ///< [n_nodes] caller storage; node indices
    double swept_quad[12]; ///< m: the newest changing sweep's P0, Q0, P1, Q1
} hs_haptic_cut_event;

/// Cut topology version now (0 before the first cut). Thread: any | Lock-free: yes
int64_t hs_haptic_sim_topology_version(hs_haptic_sim* sim);
/// Copy the topology after the newest cut: rest positions x0[3n] (m), the live boundary
/// triangles (node indices, outward) into tris[tri_cap * 3] with *n_tris, and the changes
/// since the previous take into ev (may be NULL). Returns the version copied.
/// Thread: one reader (control) | Allocates: no | Blocks: briefly (a mutex the deformation
/// thread holds while it copies a cut's result)
int64_t hs_haptic_sim_take_topology(hs_haptic_sim* sim, double* x0 /* OUT [3n] */,
                                    int* tris /* OUT */, int tri_cap, int* n_tris /* OUT */,
                                    hs_haptic_cut_event* ev /* OUT, may be NULL */);

/// Nodes the cuts pinned: nodes left without a tet (the cut removes every tet it crosses; the
/// body holds each where it was, hs_fem_held_nodes), and under FIX every node of a piece the
/// fixed region does not hold (the body lets the piece move). The compliance holds every node
/// no tet of a held piece uses; the probe cannot touch those.
/// Sets pinned[n_nodes] to 1 / 0 and returns how many (0 without cutting). Only while stopped.
int hs_haptic_sim_cut_pinned(hs_haptic_sim* sim, unsigned char* pinned /* OUT [n] */);
/// Why the background compliance set-up failed, or NULL. Thread: control
const char* hs_haptic_sim_setup_error(hs_haptic_sim* sim);
/// Wait for a background compliance set-up and take its result (the sim must be stopped).
/// HS_OK when the compliance is in use, else the set-up's error status. Thread: control |
/// Blocks: yes
hs_status hs_haptic_sim_wait_setup(hs_haptic_sim* sim);
/// The compliance (read-only use from the control thread only while the sim is stopped; NULL
/// while a background set-up runs).
hs_compliance* hs_haptic_sim_compliance(hs_haptic_sim* sim);
/// The body (use only while the sim is stopped).
hs_body* hs_haptic_sim_body(hs_haptic_sim* sim);

#ifdef __cplusplus
}
#endif
#endif
