// SPDX-License-Identifier: GPL-2.0-or-later
// In-process haptic simulation: deformation thread + rt thread (haptic_sim.h).
//
// DESIGN. The deformation thread (this file, `deform_main`) owns the body, the compliance and
// every work array; the rt thread runs the rt helper's haptic tick with `probe_eval` as its
// force source. Crossing, lock-free and fixed-size:
//   snap   (triple buffer, deformation -> rt):  hs_contact_snapshot, newest wins
//   contact(triple buffer, rt -> deformation):  hs_contact, the newest tick's contact
//   frame  (triple buffer, deformation -> reader): step number + u[3n]
//   status (triple buffer, deformation -> control): hs_haptic_sim_stats without the rt part
//   pose / output through the rt helper's memory device.
// With cutting on, the topology a cut step shares with the net thread is handed over under a
// mutex (`tmx`; never taken by the rt thread), and the compliance rebuild after a cut allocates
// (the live mesh, its worker thread). Otherwise the deformation thread allocates nothing after
// create; the rt tick never allocates or locks.
#define _POSIX_C_SOURCE 200809L
#include "haptic_sim.h"

#include "spsc_ring.h"
#include "triple_buffer.h"
#include "worker.h"
#include "closest.h"
#include "cut_surface.h"
#include "dense.h"
#include "device.h"
#include "haptic_rt.h"
#include "rt_thread.h"

#include <float.h>
#include <math.h>
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#define PROBE_COOKIE     0x50524f42
#define SIM_COOKIE       0x48534d31
#define CUT_COOKIE       0x48534354
#define CUT_FORCE_SMOOTH 0.3 // weight of the newest sweep's resistance
// A blade that moved less than CUT_STILL_M in CUT_STILL_NS (1 mm/s) has stopped: it cuts
// nothing, so it feels no resistance (it kept the last sweep's for as long as it stood).
#define CUT_STILL_M  5e-5
#define CUT_STILL_NS 50000000LL
// Where a tool without a pose yet is put (several tools): far from any scene, no contact.
#define TOOL_AWAY_M 1e3

// What crosses to rt: the contact snapshot and the cutting resistance computed with it, in one
// buffer so a new resistance always comes with a new model version (rt blends across it).
// What the feeder hands the deformation thread when cutting: the newest pose, and where the
// tool was when the blade's buttons last changed (the deformation thread sees only the newest
// pose, up to a step late: a release it noticed late put the released probe's fit where the
// tool had moved on to, pressing into the tissue with a sphere of no size, 0 N).
typedef struct cut_pose {
    hs_haptic_pose pose;
    double flip_m[3]; // tool position at the newest engage or release, m
} cut_pose;

typedef struct sim_snapshot {
    hs_contact_snapshot s;
    double cut_force_n[3];
} sim_snapshot;

hs_haptic_cut_def hs_haptic_cut_default_def(void) {
    hs_haptic_cut_def d;
    memset(&d, 0, sizeof d);
    d.cut = hs_cut_default_def();
    d.cut.validate = 0;
    // The cut is geometry only: the body follows each sweep's element changes
    // (hs_body_change_elements) and the haptic compliance is rebuilt from the live mesh.
    d.cut.orphan = HS_CUT_ORPHAN_PIN;
    d.cut.fragment = HS_CUT_FRAGMENT_DROP;
    d.blade_b[2] = 0.01;
    d.toughness_n_m = 20.0;
    d.max_force_n = 1.5;
    d.min_travel_m = 0.0005;
    d.engage_buttons = 1u;
    d.cookie = CUT_COOKIE;
    return d;
}

hs_probe_def hs_probe_default_def(void) {
    hs_probe_def d;
    memset(&d, 0, sizeof d);
    d.radius_m = 0.01;
    d.reach_margin_m = 0.01;
    d.cache_nodes = 96;
    d.max_new_columns = 64;
    d.min_radius_m = 0.0002;
    d.max_radius_m = 0.005;
    d.model_timeout_s = 0.05;
    d.free_relax = 0.5;
    d.cookie = PROBE_COOKIE;
    return d;
}

hs_haptic_sim_def hs_haptic_sim_default_def(void) {
    hs_haptic_sim_def d;
    memset(&d, 0, sizeof d);
    d.body = hs_body_default_def();
    d.body.fem.model = HS_MODEL_COROTATED;
    d.probe = hs_probe_default_def();
    d.safety = hs_safety_default_def();
    d.rate_hz = 1000;
    d.fifo_priority = 80;
    d.lock_memory = 1;
    d.blend_ticks = 10;
    d.sleep_speed_m_s = 1e-4;
    d.idle_poll_s = 0.002;
    d.tools = 1;
    d.cookie = SIM_COOKIE;
    return d;
}

// What the deformation thread reports (the rt part of hs_haptic_sim_stats is read elsewhere;
// its histograms are too big to copy every step).
typedef struct deform_status {
    int64_t steps, snapshots, column_solves, step_failures;
    double step_ms_last, step_ms_max, snapshot_ms_last, snapshot_ms_max;
    int sleeping, candidates, coupled;
    hs_contact contact;
    int64_t cut_sweeps, cut_steps, cut_removed, cut_failures;
    double cut_ms_last, cut_ms_max, sweep_ms_last, comp_ms_last;
    double cut_force_n[3];
    int cutting;
    int64_t loops, comp_version, comp_rebuilds, comp_discarded, comp_updates;
    int64_t cut_done_ns, comp_swap_ns;
    int comp_building;
    double relax_w;
    int64_t relax_cuts;
    double depth_max;
    int64_t deep_loops;
    double step_p50, step_p99, step_p50_all, step_p99_all, step_cpu_p50_all, step_cpu_p99_all;
    int64_t step_overruns, rate_changes, solver_switches;
    double sim_hz_target;
    int solver;
    double solver_ms[3];
    double factor_ms;
} deform_status;

// Step timing on the deformation thread: 0.1 ms bins over [0, 400 ms) and an overflow bin.
#define STEP_BINS   4000
#define STEP_BIN_MS 0.1
#define RATE_WINDOW 32 // newest steps the pacing looks at
#define RATE_EVERY  16 // steps between two pacing decisions
#define RATE_MARGIN                                                                                \
    1.05                 // paced period = RATE_MARGIN x the window's median (a slower step
                         // starts the next at once: the rate is what the steps allow)
#define RATE_RAISE   0.7 // raise the rate again when that is below this share of the period
#define RATE_FAST    8   // newest steps whose slowest decides a raise (checked every step)
#define RATE_MAX_DIV 8   // the rate goes down to 1 / (RATE_MAX_DIV dt) at the lowest
// Solver choice (auto_solver): ranks from the most accurate to the cheapest.
#define AUTO_SETTLE      2      // steps after a switch not booked (its refactor, the warm starts)
#define AUTO_DOWN        3      // net steps over the budget before a cheaper solver
#define AUTO_UP_STEPS    30     // steps with a solver before a more accurate one is tried
#define AUTO_UP_KNOWN    0.7    // a measured more accurate solver is taken when it fits this share
#define AUTO_UP_PROBE    0.5    // an unmeasured one is tried when the current fits this share
#define AUTO_RETRY_S     5.0    // wait after a solver failed its budget, doubled per failure
#define AUTO_START       0.35   // start with direct when one factorisation fits this share
#define AUTO_START_NNZ   250000 // or when the factor is this small (deterministic: no clock)
#define AUTO_RETRY_MAX_S 160.0
static const hs_solver_kind auto_rank[3] = {HS_SOLVER_DIRECT, HS_SOLVER_PCG, HS_SOLVER_WARPED};

// A boundary triangle and its distance from the tool (snapshot search).
typedef struct near_tri {
    double dist;
    int tri;
} near_tri;

// Nearest first; ties by triangle index, so the choice depends on the positions only.
static int near_tri_cmp(const void* pa, const void* pb) {
    const near_tri *a = pa, *b = pb;
    if (a->dist != b->dist) return a->dist < b->dist ? -1 : 1;
    return (a->tri > b->tri) - (a->tri < b->tri);
}

// The rt side of the probe: the force source plugged into the haptic tick.
typedef struct probe_src {
    hs_triple_buffer* snap;    // reader: rt
    hs_triple_buffer* contact; // writer: rt
    double min_r, max_r, timeout_s;
    hs_contact last; // the previous tick's contact (warm start)
    // Taken over from a stopped sim: rt gives `held` while the snapshot is still the empty
    // initial one (hold_version), so the force goes on until the first snapshot at the tool.
    int hold;
    int64_t hold_version;
    hs_haptic_model held;
    // Several tools (n_tools > 1): tool 0's tick solves all tools' contact as one problem
    // (work) with the newest pose each other tool's tick recorded (tool_p; 1 tick old at most)
    // and leaves each tool's model in model[t] for that tool's next tick.
    int n_tools;
    hs_contact_work* work;
    double tool_p[HS_MAX_TOOLS][3]; // newest pose of each tool (tool_seen: one came), m
    int tool_seen[HS_MAX_TOOLS];
    hs_contact lastv[HS_MAX_TOOLS]; // the previous tick's contacts (warm start)
    hs_haptic_model model[HS_MAX_TOOLS];
} probe_src;

// The force source of tool t >= 1.
typedef struct tool_src {
    probe_src* p;
    int t;
} tool_src;

typedef struct face_key {
    int k[3]; // nodes, ascending
    int o[3]; // nodes, outward order
} face_key;

struct hs_haptic_sim {
    hs_haptic_sim_def def;
    const hs_mesh* mesh;
    hs_body* body;
    // The partial refactor's helper thread (factor_helper) and the parallelism the body's
    // factor gets from it; factor_own: the body was given factor_par (no def's own).
    hs_worker* factor_worker;
    hs_parallel factor_par;
    int factor_own, factor_tried;
    hs_compliance* comp;
    int corotated;

    // crossing
    hs_triple_buffer* snap;
    hs_triple_buffer* contact;
    hs_triple_buffer* frame;  // [int64 step][double u[3n]]
    hs_triple_buffer* status; // hs_haptic_sim_stats
    hs_memdev* dev;
    hs_haptic_rt* hrt;
    hs_rt_loop* loop;
    probe_src src;
    hs_rt_tick inner; // the haptic tick of server/rt, wrapped to run the def's hooks
    // tools 1 .. n_tools-1: each its own device, tick (blend, safety, watchdog) and source
    int n_tools;
    hs_memdev* xdev[HS_MAX_TOOLS];
    hs_haptic_rt* xhrt[HS_MAX_TOOLS];
    hs_rt_tick xinner[HS_MAX_TOOLS];
    tool_src xsrc[HS_MAX_TOOLS];

    // deformation thread
    pthread_t thread;
    int thread_started;
    atomic_int stop;
    size_t frame_size;
    const hs_mesh* smesh; // the surface the probe touches: the mesh, or comp_mesh after cuts
    int tri_cap;          // boundary triangles tri_list / near_tri can hold
    int* tri_start;       // [n+1] CSR: boundary triangles of smesh per node
    int* tri_list;        // [3 tri_cap]
    double* x;            // [3n] current positions
    double* g;            // [3n] force holding the current shape beyond the non-contact loads
    double* v;            // [3n] C g (in the rest frame of each node), then the surface targets
    double* rot;          // [9n] node rotations at the current state (identity for linear)
    double* q;            // [3n] contact-free positions of smesh's surface nodes (relaxed)
    int q_reset;          // the surface changed: set q exactly at the next snapshot
    double* dq;           // [3n] last snapshot's correction target - q (oscillation test)
    double* pre;          // [3n] the contact geometry's preload R C R^T f at candidates (relaxed)
    int64_t* pre_at;      // [n] snapshot version pre was last set at
    double relax_e;       // largest correction |target - q| of the last snapshot (< 0: none yet)
    int* near_node;       // [n+1] scratch (triangle adjacency)
    near_tri* near_tri;   // [tri_cap] triangles within reach of the tool, scratch
    int* cand_of;         // [n] candidate index of a node while a snapshot is built, else -1
    int applied_n;        // contact forces in the body now (all tools', summed per node)
    int applied_node[HS_MAX_TOOLS * HS_MAX_CONTACT];
    double applied_f[HS_MAX_TOOLS * HS_MAX_CONTACT][3]; // N
    int64_t version;
    deform_status st;    // deformation thread's copy, published through `status`
    int was_probing;     // the previous snapshot had a probe contact (cutting on)
    hs_contact entry_c;  // settle_entry's scratch
    int entry_left;      // snapshots still settled after the probe's entry
    double release_p[3]; // tool position where the blade was last released, m
    int release_fit;     // a probe appearing near release_p is fitted (released, not re-engaged)
    double probe_r;      // the probe's contact radius now, m (def.probe.radius_m, or less while
                         // a released blade's sphere still fits its cut)

    // cutting (cut == NULL: off); owned by the deformation thread after start
    hs_haptic_cut_def cdef;
    hs_cut* cut;
    hs_cut_surface* fsurf;   // the live boundary while the compliance follows the cuts
    unsigned char* fixed0;   // [n] the fixed nodes given at create
    double* cu;              // [3n] displacement handed to the sweep
    double* cv;              // [3n] velocity kept across the sweep
    hs_triple_buffer* cpose; // cut_pose, feeder -> deformation
    int feed_engaged;        // feeder: the blade's buttons held in the newest pose
    double feed_flip[3];     // feeder: tool position at the newest engage or release, m
    int blade_have;
    double bp[3], bq[3]; // blade ends at the last sweep, m
    double cut_force[3]; // resistance in the newest snapshot, N
    int comp_stale;      // the compliance predates the newest cut (rebuilt once the blade stops)
    int cols_cold;       // the compliance followed a cut: its columns come COLD_COLUMNS a step
    int wake_steps;      // steps the body takes whatever its speed: a start or a cut moves its
                         // equilibrium
    int engaged;         // the blade's buttons are held (cutting on)
    int64_t pose_floor;  // poses up to this seq came before a restart: the blade ignores them
    int started_once;    // hs_haptic_sim_start ran before (a restart resets the rt side)
    int64_t still_ns;    // when the blade last moved CUT_STILL_M; longer still: no resistance
    double still_p[3], still_q[3]; // the blade ends then, m
    hs_mesh* comp_mesh;            // the mesh h->comp was built on once cuts replaced it (owned)
    // Background compliance rebuild: the deformation thread copies the live mesh into cw_*,
    // a worker builds mesh + compliance from it, and the deformation thread swaps the result
    // in when the topology has not moved on meanwhile (else it is dropped).
    pthread_t cw_thread;
    int cw_running;        // started and not yet joined (deformation thread)
    atomic_int cw_done;    // worker: the result fields below are final
    int64_t cw_version;    // topology version the job was copied at
    double* cw_x0;         // [3n] job input
    int* cw_tets;          // [4 n_tets] job input
    int cw_ntets;          // tets in cw_tets: the live ones of held pieces
    unsigned char* cw_fix; // [n] worker: fixed0 + nodes no tet of cw_tets uses
    double* cw_u;          // [3n] job input: the body's displacement when it was copied
    double* cw_xw;         // [3n] worker: cw_x0 + cw_u (comp_warm)
    near_tri* cw_near;     // [tri_cap] worker scratch (comp_warm)
    int* cw_cand;          // [n] worker scratch, all -1 (comp_warm)
    pthread_mutex_t cw_mx; // guards cw_tool (deformation thread, worker; never rt)
    double cw_tool[3];     // the tool now, for comp_warm, m
    hs_mesh* cw_mesh;      // job output
    hs_compliance* cw_comp;
    hs_status cw_status;
    double cw_ms;
    // topology after the newest cut, shared with the control thread under tmx
    pthread_mutex_t tmx;
    int tmx_init;
    double* t_x0; // [3n]
    int* t_tris;  // [3 t_cap] live boundary; the reader's own (built in take_topology)
    int t_cap, t_ntris;
    // reader side: the live boundary is derived from the removed tets, off the deformation
    // thread (a live-mesh rebuild there cost ~3 ms of a ~11 ms cut step on the skin patch)
    unsigned char* r_gone; // [n_tets] removed so far
    face_key* r_keys;      // [4 n_tets] faces of the live tets
    face_key* r_sorted;    // [4 n_tets] the same, by smallest node
    int* r_start;          // [n + 1] bucket starts
    int* r_cur;            // [n + 1] bucket cursors
    int* t_removed;        // [n_tets]
    int t_nremoved;
    int* t_moved;           // [n]
    unsigned char* t_mflag; // [n] 1 when listed in t_moved
    int t_nmoved;
    double t_quad[12];
    int64_t t_taken; // version at the previous take
    _Atomic int64_t topo_version;
    double setup_ms; // the first compliance's set-up

    // step timing, pacing and solver choice (deformation thread)
    uint32_t* step_hist;                  // [2 (STEP_BINS + 1)] wall, then thread CPU
    int64_t step_hist_n;                  // samples in it
    double recent_ms[HS_SIM_STEP_WINDOW]; // ring of the newest step times, ms
    int64_t recent_n;                     // steps recorded (ring position)
    int64_t period_ns;                    // paced step period (>= body.dt)
    int rate_count;                       // steps since the last pacing decision
    int au_last;                          // auto: cheapest allowed rank
    int au_since, au_over;                // steps with the current solver; net over-budget
    double au_snap_ms;                    // auto: snapshot cost estimate, ms
    int64_t au_retry_ns[3];               // per kind: not tried again before
    double au_backoff_s[3];               // per kind: the next wait after a failure

    // background compliance set-up (def.background_setup)
    pthread_t su_thread;
    int su_running;        // started and not joined (joined by setup_take)
    atomic_int su_done;    // worker: su_* below are final
    atomic_int comp_state; // hs_haptic_sim_stats.comp_state as far as it is known here
    hs_compliance* su_comp;
    hs_status su_status;
    hs_err su_err;
    double su_ms;
};

// ---------------------------------------------------------------------------------------------
// rt side

// Every tool's contact as one problem: tool 0 at p0, the others where their newest poses were
// (a tool with none yet is far off: no contact). Each tool's model is kept for its own tick.
static void solve_tools(probe_src* p, const hs_contact_snapshot* s, const double p0[3],
                        hs_contact* c /* [n_tools] */) {
    double tm[3 * HS_MAX_TOOLS];
    for (int t = 0; t < p->n_tools; ++t)
        for (int k = 0; k < 3; ++k)
            tm[3 * t + k] = t == 0 ? p0[k] : p->tool_seen[t] ? p->tool_p[t][k] : TOOL_AWAY_M;
    hs_contact_solve_tools(s, p->n_tools, tm, p->lastv, p->work, c);
    memcpy(p->lastv, c, (size_t)p->n_tools * sizeof *c);
    p->last = c[0];
    for (int t = 1; t < p->n_tools; ++t)
        hs_contact_model(&c[t], p->min_r, p->max_r, p->timeout_s, &p->model[t]);
}

// Tool t >= 1: records its pose for the next joint solve and gives the model tool 0's tick
// left for it, re-anchored at its pose.
static void tool_eval(void* ctx, const hs_rt_clock* clk, const hs_haptic_pose* pose,
                      hs_haptic_model* out) {
    tool_src* ts = ctx;
    probe_src* p = ts->p;
    memcpy(p->tool_p[ts->t], pose->pos_m, sizeof p->tool_p[ts->t]);
    p->tool_seen[ts->t] = 1;
    hs_haptic_model_reanchor(&p->model[ts->t], pose->pos_m, out);
    out->stamp_ns = clk->now_ns;
}

static void probe_eval(void* ctx, const hs_rt_clock* clk, const hs_haptic_pose* pose,
                       hs_haptic_model* out) {
    probe_src* p = ctx;
    const sim_snapshot* ss = hs_triple_buffer_read(p->snap, NULL);
    const hs_contact_snapshot* s = &ss->s;
    if (p->hold && s->version == p->hold_version) {
        *out = p->held; // its seq is the one rt blends toward: no new blend until a snapshot
        out->stamp_ns = clk->now_ns;
        return;
    }
    p->hold = 0;
    hs_contact* c = hs_triple_buffer_back(p->contact);
    if (p->n_tools > 1) {
        solve_tools(p, s, pose->pos_m, c);
    } else {
        hs_contact_solve_from(s, pose->pos_m, &p->last, c);
        p->last = *c;
    }
    hs_triple_buffer_publish(p->contact);
    // From the copy: the published slot is the deformation thread's to read now.
    hs_contact_model(&p->last, p->min_r, p->max_r, p->timeout_s, out);
    for (int k = 0; k < 3; ++k) out->force_n[k] += ss->cut_force_n[k];
    out->stamp_ns = clk->now_ns;
}

static void rt_tick(void* ctx, const hs_rt_clock* clk) {
    hs_haptic_sim* h = ctx;
    // The other tools first: their poses go into tool 0's joint solve of this tick.
    for (int t = 1; t < h->n_tools; ++t) h->xinner[t].fn(h->xinner[t].ctx, clk);
    h->inner.fn(h->inner.ctx, clk);
}

static void rt_start(void* ctx) {
    hs_haptic_sim* h = ctx;
    if (h->inner.on_start) h->inner.on_start(h->inner.ctx);
    for (int t = 1; t < h->n_tools; ++t)
        if (h->xinner[t].on_start) h->xinner[t].on_start(h->xinner[t].ctx);
    if (h->def.rt_on_start) h->def.rt_on_start(h->def.rt_hook_ctx);
}

static void rt_stop(void* ctx) {
    hs_haptic_sim* h = ctx;
    if (h->def.rt_on_stop) h->def.rt_on_stop(h->def.rt_hook_ctx);
    if (h->inner.on_stop) h->inner.on_stop(h->inner.ctx);
    for (int t = 1; t < h->n_tools; ++t)
        if (h->xinner[t].on_stop) h->xinner[t].on_stop(h->xinner[t].ctx);
}

// ---------------------------------------------------------------------------------------------
// deformation side

static double dist3(const double a[3], const double b[3]) {
    double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
}

// Outward unit normal of a surface node: area-weighted mean of its triangles' normals.
static void node_normal(const hs_haptic_sim* h, int node, double n[3]) {
    const int* tris = h->smesh->tris;
    n[0] = n[1] = n[2] = 0;
    for (int k = h->tri_start[node]; k < h->tri_start[node + 1]; ++k) {
        const int* t = tris + 3 * h->tri_list[k];
        const double *a = h->x + 3 * t[0], *b = h->x + 3 * t[1], *c = h->x + 3 * t[2];
        double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        n[0] += e1[1] * e2[2] - e1[2] * e2[1];
        n[1] += e1[2] * e2[0] - e1[0] * e2[2];
        n[2] += e1[0] * e2[1] - e1[1] * e2[0];
    }
    double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (l > 0)
        for (int k = 0; k < 3; ++k) n[k] /= l;
}

static void node_rot(hs_haptic_sim* h, int node, double r[9]) {
    if (h->corotated) {
        hs_fem_node_rotation(hs_body_fem(h->body), node, r);
    } else {
        static const double id[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
        memcpy(r, id, sizeof id);
    }
}

// A correction counts as diverging when it grows RELAX_GROWTH-fold in a step and exceeds twice
// the body's largest displacement plus this share of the probe radius: a converging one is
// about the contact's displacement or less.
#define RELAX_FLOOR  0.25
#define RELAX_GROWTH 1.5
// A reversing correction below this share of r is round-off and ringing, not an overshoot.
#define RELAX_TINY 1e-3

// Weight of the newest preload in the relaxed one: the geometry follows the forces rt found on
// it, a fixed-point iteration that can swing from step to step unrelaxed.
#define PRELOAD_RELAX 0.5

// The contact geometry: where the applied contact forces hold the surface, q + R C R^T f
// (pre_m = R C R^T f, relaxed from snapshot to snapshot), the quasi-static shape of the press
// rather than the body's dynamic one, which rings and would shake the contact's normals with
// it. surf_m holds q on entry. A contact node without a compliance block to a candidate (no
// column cached for either) adds nothing there.
// The forces are n_f at nodes f_node; relax < 0: PRELOAD_RELAX after a snapshot that had the
// node, else 1.
static void preload_surface(hs_haptic_sim* h, hs_contact_snapshot* s, int n_f, const int* f_node,
                            const double (*f_n)[3], double relax) {
    for (int i = 0; i < s->n_cand; ++i) {
        double pre[3] = {0, 0, 0};
        const double* ri = h->rot + 9 * (size_t)s->node[i];
        for (int k = 0; k < n_f; ++k) {
            const int node = f_node[k];
            const double* f = f_n[k];
            int j = 0;
            while (j < s->n_cand && s->node[j] != node) ++j;
            double blk[9];
            const double* b = blk;
            if (j < s->n_cand) {
                b = s->c[i][j];
            } else {
                double raw[9];
                if (!hs_compliance_block(h->comp, s->node[i], node, raw)) continue;
                hs_mat3_rotate(ri, raw, h->rot + 9 * (size_t)node, blk);
            }
            for (int a = 0; a < 3; ++a)
                pre[a] += b[3 * a] * f[0] + b[3 * a + 1] * f[1] + b[3 * a + 2] * f[2];
        }
        const int node = s->node[i];
        double* ps = h->pre + 3 * (size_t)node;
        const double w = relax >= 0                          ? relax
                         : h->pre_at[node] == s->version - 1 ? PRELOAD_RELAX
                                                             : 1.0;
        h->pre_at[node] = s->version;
        for (int a = 0; a < 3; ++a) {
            ps[a] += w * (pre[a] - ps[a]);
            s->pre_m[i][a] = ps[a];
            s->surf_m[i][a] += ps[a];
        }
    }
    hs_contact_snapshot_bound_tris(s);
}

// A probe entering tissue (a blade released in its cut): the contact geometry follows the
// forces rt finds on it only from step to step, and a sphere that appears with tissue inside
// it is far from where that settles (on the skin patch the first answers reached 0.7-1.5 N,
// 2.4 N through the server, and fell to ~0.1 N within three steps). So iterate it here, with the
// contact rt would find, until the force settles (ENTRY_TOL) or ENTRY_ITERS, and publish the
// settled geometry.
#define ENTRY_ITERS     24
#define ENTRY_TOL       1e-3 // N
#define ENTRY_SNAPSHOTS 30   // settled snapshots after an entry (0.5 s at 60 Hz)
#define PROBE_MIN_FIT   1e-3 // smallest fitted radius, share of the probe's
static void settle_entry(hs_haptic_sim* h, hs_contact_snapshot* s, const double p[3]) {
    hs_contact* c = &h->entry_c;
    double prev[3] = {0, 0, 0};
    for (int it = 0; it < ENTRY_ITERS; ++it) {
        hs_contact_solve(s, p, 0, NULL, c);
        if (c->failed || c->n == 0) break;
        double d[3] = {c->force_n[0] - prev[0], c->force_n[1] - prev[1], c->force_n[2] - prev[2]};
        if (it > 0 && sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) < ENTRY_TOL) break;
        memcpy(prev, c->force_n, sizeof prev);
        for (int i = 0; i < s->n_cand; ++i)
            memcpy(s->surf_m[i], h->q + 3 * (size_t)s->node[i], sizeof s->surf_m[i]);
        preload_surface(h, s, c->n, c->node, (const double(*)[3])c->f_n, PRELOAD_RELAX);
    }
}

// The vertices of the triangles near[nn] (nearest first) as the candidates (nodes, returned
// count; tri: their triangles by candidate index, *n_tri), until either list is full; *cover:
// every surface point within it of the tool is on a listed triangle. cand_of ([n], all -1) is
// scratch and left all -1.
static int take_candidates(const hs_mesh* sm, const near_tri* near, int nn, double reach,
                           int* cand_of, int nodes[HS_CONTACT_MAX_CAND], int (*tri)[3], int* n_tri,
                           double* cover) {
    *cover = reach;
    int n_cand = 0, nt = 0;
    for (int k = 0; k < nn; ++k) {
        const int* tv = sm->tris + 3 * near[k].tri;
        int add = 0;
        for (int j = 0; j < 3; ++j) add += cand_of[tv[j]] < 0;
        if (nt == HS_CONTACT_MAX_TRI || n_cand + add > HS_CONTACT_MAX_CAND) {
            *cover = near[k].dist;
            break;
        }
        for (int j = 0; j < 3; ++j) {
            if (cand_of[tv[j]] < 0) {
                cand_of[tv[j]] = n_cand;
                nodes[n_cand++] = tv[j];
            }
            tri[nt][j] = cand_of[tv[j]];
        }
        ++nt;
    }
    for (int i = 0; i < n_cand; ++i) cand_of[nodes[i]] = -1;
    *n_tri = nt;
    return n_cand;
}

// Contact surface: the boundary triangles of sm (all three vertices contactable in comp) within
// reach of p on the surface at positions x, nearest first (near: scratch of sm->n_tris; *n_near
// of them), and their vertices as the candidates (nodes, returned count; tri: their triangles
// by candidate index, *n_tri), until either list is full; *cover: every surface point within it
// of p is on a listed triangle. cand_of ([n], all -1) is scratch and left all -1. A linear scan:
// microseconds per step; this plays the role of the per-step acceleration structure, which at
// these sizes would cost more than it saves.
static int find_candidates(const hs_mesh* sm, const hs_compliance* comp, const double* x,
                           const double p[3], double reach, near_tri* near, int* cand_of,
                           int nodes[HS_CONTACT_MAX_CAND], int (*tri)[3], int* n_near, int* n_tri,
                           double* cover) {
    int nn = 0;
    for (int t = 0; t < sm->n_tris; ++t) {
        const int* tv = sm->tris + 3 * t;
        if (!hs_compliance_contactable(comp, tv[0]) || !hs_compliance_contactable(comp, tv[1]) ||
            !hs_compliance_contactable(comp, tv[2]))
            continue;
        double wb[3], cp[3];
        if (!hs_tri_closest(p, x + 3 * (size_t)tv[0], x + 3 * (size_t)tv[1], x + 3 * (size_t)tv[2],
                            wb, cp))
            continue;
        double dist = dist3(cp, p);
        if (dist >= reach) continue;
        near[nn].dist = dist;
        near[nn].tri = t;
        ++nn;
    }
    qsort(near, (size_t)nn, sizeof *near, near_tri_cmp);
    *n_near = nn;
    return take_candidates(sm, near, nn, reach, cand_of, nodes, tri, n_tri, cover);
}

// Build and publish the snapshot around the tool positions p[3 n_tools] (tool 0 first) from
// the body's current state: the candidates cover the surface near every tool.
// Contact-free positions of the surface nodes (h->q) from the body's state u (h->x set).
static void update_free_surface(hs_haptic_sim* h, const double* u) {
    const hs_mesh* mesh = h->mesh;
    const hs_mesh* sm = h->smesh;
    const int ns = sm->n_surf_nodes;
    const double r = h->def.probe.radius_m;
    // Contact-free positions. g = -(f_el + gravity load) is the force that holds the current
    // shape beyond the loads that are not contact: the contact forces, plus inertia and damping
    // while the body moves. Removing its static response R C R^T g leaves the shape the tissue
    // would have without the probe: for the linear model exactly the rest (or gravity-loaded)
    // shape whatever the dynamics, so the force does not depend on how far the body lags; for
    // the co-rotated one each step is one defect-correction iteration toward its own
    // equilibrium (see docs/haptics.md).
    hs_body_elastic_energy(h->body); // evaluates the model at the current state if needed
    hs_fem* fem = hs_body_fem(h->body);
    const double* mass = hs_fem_lumped_mass(fem);
    const double* grav = h->def.body.gravity;
    hs_fem_forces(fem, h->g);
    for (int i = 0; i < mesh->n_nodes; ++i) {
        double* gi = h->g + 3 * i;
        for (int a = 0; a < 3; ++a) gi[a] = -(gi[a] + mass[i] * grav[a]);
        double* R = h->rot + 9 * (size_t)i;
        node_rot(h, i, R);
        if (h->corotated) {
            double t[3] = {gi[0], gi[1], gi[2]};
            for (int a = 0; a < 3; ++a) gi[a] = R[a] * t[0] + R[3 + a] * t[1] + R[6 + a] * t[2];
        }
    }
    if (hs_compliance_apply(h->comp, h->g, h->v) != HS_OK)
        memset(h->v, 0, 3 * (size_t)mesh->n_nodes * sizeof(double));
    hs_compliance_begin_step(h->comp);

    // Relaxed update of the contact-free surface (q += w (x - R C R^T g - q)): exact and
    // immediate for the linear model (the target is constant), and for the co-rotated one an
    // under-relaxed defect correction, which keeps converging where a large indentation makes
    // the true compliance much larger than the rest-state one (see docs/haptics.md).
    // A new surface (after a cut) starts from its exact target: its new nodes have no history.
    // Safeguard: where the body answers a force much less (or more) than C predicts (beyond
    // ~0.8 r deep; after cuts whose pieces C and the body hold differently) the iteration
    // diverges through the body's dynamics: q ran 0.5 m off within three steps (a 10 N kick).
    // So a correction that grows 1.5x past 2 |u|max + r / 4 cuts w 4x, down to free_relax / 64;
    // one that reverses (and exceeds r / 1000) halves it; one that shrinks without reversing
    // lets it recover 1.25x.
    // The targets x - R (C R^T g) replace C R^T g in h->v (nothing else reads it).
    double e = 0, um = 0, flip = 0, d2sum = 0;
    for (int si = 0; si < ns; ++si) {
        int node = sm->surf_nodes[si];
        const double* xs = h->x + 3 * (size_t)node;
        double* t = h->v + 3 * (size_t)node;
        const double* R = h->rot + 9 * (size_t)node;
        const double uc[3] = {t[0], t[1], t[2]};
        for (int a = 0; a < 3; ++a)
            t[a] = xs[a] - (R[3 * a] * uc[0] + R[3 * a + 1] * uc[1] + R[3 * a + 2] * uc[2]);
        const double* q = h->q + 3 * (size_t)node;
        const double* un = u + 3 * (size_t)node;
        double d2 = 0, u2 = un[0] * un[0] + un[1] * un[1] + un[2] * un[2];
        double* dp = h->dq + 3 * (size_t)node;
        for (int a = 0; a < 3; ++a) {
            double d = t[a] - q[a];
            d2 += d * d;
            flip += d * dp[a];
            dp[a] = d;
        }
        d2sum += d2;
        if (d2 > e) e = d2;
        if (u2 > um) um = u2;
    }
    e = sqrt(e);
    um = sqrt(um);
    const double w_max = h->def.probe.free_relax, w_min = w_max / 64;
    if (h->q_reset) {
        h->st.relax_w = w_max;
    } else if (h->relax_e >= 0 && e > RELAX_GROWTH * h->relax_e && e > 2 * um + RELAX_FLOOR * r) {
        h->st.relax_w = fmax(w_min, 0.25 * h->st.relax_w);
        h->st.relax_cuts++;
    } else if (h->relax_e >= 0 && flip < -0.25 * d2sum && e > RELAX_TINY * r) {
        // The correction reverses from step to step: the iteration overshoots (a deep press
        // with a small sphere, large local rotations). Halve w until it converges monotonically.
        h->st.relax_w = fmax(w_min, 0.5 * h->st.relax_w);
    } else if (h->relax_e >= 0 && e < h->relax_e && flip > 0) {
        h->st.relax_w = fmin(w_max, 1.25 * h->st.relax_w);
    }
    const double w = h->q_reset ? 1.0 : h->st.relax_w;
    h->relax_e = h->q_reset ? -1 : e;
    h->q_reset = 0;
    for (int si = 0; si < ns; ++si) {
        int node = sm->surf_nodes[si];
        const double* t = h->v + 3 * (size_t)node;
        double* q = h->q + 3 * (size_t)node;
        for (int a = 0; a < 3; ++a) q[a] += w * (t[a] - q[a]);
    }
}

// The boundary triangles (all three vertices contactable) whose closest point on the current
// surface is within reach of a tool (tool 0 when probing, the others when others), into
// h->near_tri, nearest first. Returns how many.
static int near_triangles(hs_haptic_sim* h, const double* p, int probing, int others,
                          double reach) {
    const hs_mesh* sm = h->smesh;
    int n_near = 0;
    for (int t = 0; t < sm->n_tris && (probing || others); ++t) {
        const int* tv = sm->tris + 3 * t;
        if (!hs_compliance_contactable(h->comp, tv[0]) ||
            !hs_compliance_contactable(h->comp, tv[1]) ||
            !hs_compliance_contactable(h->comp, tv[2]))
            continue;
        const double* a = h->x + 3 * (size_t)tv[0];
        const double* b = h->x + 3 * (size_t)tv[1];
        const double* c = h->x + 3 * (size_t)tv[2];
        double wb[3], x[3], dist = INFINITY;
        for (int k = 0; k < h->n_tools; ++k) {
            const double* pk = p + 3 * k;
            if (k == 0 ? !probing : !others || !(fabs(pk[0]) < 0.5 * TOOL_AWAY_M))
                continue; // a blade, or no pose yet
            if (hs_tri_closest(pk, a, b, c, wb, x)) dist = fmin(dist, dist3(x, pk));
        }
        if (!(dist < reach)) continue;
        h->near_tri[n_near].dist = dist;
        h->near_tri[n_near].tri = t;
        ++n_near;
    }
    qsort(h->near_tri, (size_t)n_near, sizeof *h->near_tri, near_tri_cmp);
    return n_near;
}

// The candidates nodes[n_cand] into s: node, coupling, contact-free position, normal, and the
// rotated blocks R_i C_ij R_j^T. Returns how many are coupled.
static int fill_blocks(hs_haptic_sim* h, hs_contact_snapshot* s, const int* nodes, int n_cand) {
    int coupled = 0;
    for (int i = 0; i < n_cand; ++i) {
        int node = nodes[i];
        s->node[i] = node;
        s->coupled[i] = (unsigned char)hs_compliance_has_column(h->comp, node);
        coupled += s->coupled[i];
        memcpy(s->surf_m[i], h->q + 3 * (size_t)node, sizeof s->surf_m[i]);
        node_normal(h, node, s->normal[i]);
    }
    for (int i = 0; i < n_cand; ++i) {
        const double* ri = h->rot + 9 * (size_t)nodes[i];
        for (int j = i; j < n_cand; ++j) {
            const double* rj = h->rot + 9 * (size_t)nodes[j];
            double blk[9];
            if (!hs_compliance_block(h->comp, nodes[i], nodes[j], blk)) {
                memset(s->c[i][j], 0, sizeof s->c[i][j]);
                memset(s->c[j][i], 0, sizeof s->c[j][i]);
                continue;
            }
            hs_mat3_rotate(ri, blk, rj, s->c[i][j]);
            if (i == j) {
                // Exact symmetry for the rt Cholesky.
                double* b = s->c[i][i];
                for (int a = 0; a < 3; ++a)
                    for (int c = a + 1; c < 3; ++c)
                        b[3 * a + c] = b[3 * c + a] = 0.5 * (b[3 * a + c] + b[3 * c + a]);
            } else {
                for (int a = 0; a < 3; ++a)
                    for (int c = 0; c < 3; ++c) s->c[j][i][3 * c + a] = s->c[i][j][3 * a + c];
            }
        }
    }
    return coupled;
}

#define COLD_COLUMNS 8 // new columns per snapshot while a followed compliance has few
static void build_snapshot(hs_haptic_sim* h, const double* p) {
    const hs_mesh* mesh = h->mesh;
    const hs_mesh* sm = h->smesh; // same nodes and x0; its own boundary
    const double* u = hs_body_displacement(h->body);
    const double r = h->def.probe.radius_m;
    double r_max = r; // the largest tool sphere: the search reach
    for (int k = 1; k < h->n_tools; ++k) r_max = fmax(r_max, h->def.tool_radius_m[k]);
    const double reach = r_max + h->def.probe.reach_margin_m;
    for (int k = 0; k < 3 * mesh->n_nodes; ++k) h->x[k] = mesh->x0[k] + u[k];
    const int new_surface = h->q_reset; // the compliance was just swapped in

    update_free_surface(h, u);

    // Contact surface (near_triangles, take_candidates) on the current (deformed) surface. The
    // geometry is the deformed surface, not the contact-free one: pressed deeper than r, the
    // contact-free surface lies behind the centre and its closest points say nothing about
    // where the tissue touches the sphere, while the deformed surface wraps it (the gap is
    // still measured from the contact-free positions: pre_m below).
    sim_snapshot* wrap = hs_triple_buffer_back(h->snap);
    memcpy(wrap->cut_force_n, h->cut_force, sizeof wrap->cut_force_n);
    hs_contact_snapshot* s = &wrap->s;
    // A blade has no contact sphere. A released one probes when the def says so, once the
    // compliance matches the cut body (a stale one would answer for the uncut tissue).
    // The other tools are probes whenever the compliance matches the cut body.
    const int comp_now = !h->cut || h->st.comp_version == hs_cut_topology_version(h->cut);
    int probing = !h->cut || (h->cdef.probe_when_released && !h->engaged && comp_now);
    const int others = h->n_tools > 1 && comp_now;
    const int n_near = near_triangles(h, p, probing, others, reach);
    double cover;
    int n_tri;
    int nodes[HS_CONTACT_MAX_CAND];
    const int n_cand =
        take_candidates(sm, h->near_tri, n_near, reach, h->cand_of, nodes, s->tri, &n_tri, &cover);
    const int n_near_nodes = n_cand;

    // A released blade that turns probe (or a probe whose surface was just replaced) may find
    // tissue inside its sphere: settle its contact geometry before rt sees it, for as long as
    // the cut tissue moves to its new equilibrium under it.
    // Where the blade was released its sphere fits: the radius is the clearance to the nearest
    // surface (in the blade's own cut, about zero) and grows only with that clearance, back to r
    // once the tool has room (lifted out of the cut), so the sphere never appears around tissue. A
    // full sphere in the cut held the tissue below the blade's tip inside it: pushed up through the
    // sphere (the contact pushes along a face's inward normal), that tissue ended on top of it
    // and was carried up when the tool was lifted out (up to 0.76 N pulling down, 3.3 N once
    // through the server).
    const double clear = n_near > 0 ? h->near_tri[0].dist : reach;
    if (!h->cut || !probing) {
        h->probe_r = r;
    } else if (!h->was_probing || new_surface) {
        // Where the blade was released: elsewhere (moved off meanwhile) it is a plain probe.
        const int at_release = h->release_fit && dist3(p, h->release_p) < r;
        h->probe_r = at_release ? fmin(r, fmax(clear, PROBE_MIN_FIT * r)) : r;
        h->entry_left = ENTRY_SNAPSHOTS;
    } else if (h->probe_r < r) {
        h->probe_r = fmin(r, fmax(h->probe_r, clear));
    }
    if (!probing) h->entry_left = 0;
    const int entering = h->entry_left > 0;
    if (entering) h->entry_left--;
    h->was_probing = probing;

    s->version = ++h->version;
    s->probe_radius_m = h->probe_r;
    memcpy(s->centre_m, p, sizeof s->centre_m);
    s->reach_m = cover;
    s->tool_off[0] = (unsigned char)!probing;
    for (int k = 1; k < h->n_tools; ++k) { // every tool covered as far as tool 0
        memcpy(s->tool_centre_m[k], p + 3 * k, sizeof s->tool_centre_m[k]);
        s->tool_reach_m[k] = cover;
        s->tool_radius_m[k] = h->def.tool_radius_m[k] > 0 ? h->def.tool_radius_m[k] : r;
        s->tool_off[k] = (unsigned char)!others;
    }
    s->n_cand = n_cand;
    s->n_tri = n_tri;
    // Columns for the candidates, nearest first, within this step's budget.
    // After a cut step the compliance has no columns: a few per snapshot (the nearest), so the
    // first contact is published within milliseconds on the exact diagonal blocks and the
    // coupling fills in over the next steps (64 at once took ~0.15 s on a 5k-vertex plate).
    const int budget = h->cols_cold && h->def.probe.max_new_columns > COLD_COLUMNS
                           ? COLD_COLUMNS
                           : h->def.probe.max_new_columns;
    int got = hs_compliance_ensure(h->comp, n_cand, nodes, budget);
    (void)got; // a solver failure leaves the diagonal-only approximation
    const int coupled = fill_blocks(h, s, nodes, n_cand);
    preload_surface(h, s, h->applied_n, h->applied_node, (const double(*)[3])h->applied_f, -1);
    if (entering) settle_entry(h, s, p);
    s->stamp_ns = hs_now_ns();
    hs_triple_buffer_publish(h->snap);
    h->st.snapshots++;
    h->st.candidates = n_near_nodes;
    h->st.coupled = coupled;
    if (n_cand > 0 && coupled == n_cand) h->cols_cold = 0;
}

// Replace the body's contact loads by those of every tool's contact c[n] (a node two tools
// push takes the sum).
static void apply_contact(hs_haptic_sim* h, const hs_contact* c, int n) {
    for (int k = 0; k < h->applied_n; ++k) {
        static const double zero[3] = {0, 0, 0};
        hs_body_set_force(h->body, h->applied_node[k], zero);
    }
    h->applied_n = 0;
    for (int t = 0; t < n; ++t)
        for (int k = 0; k < c[t].n; ++k) {
            int j = 0;
            while (j < h->applied_n && h->applied_node[j] != c[t].node[k]) ++j;
            if (j == h->applied_n) {
                h->applied_node[h->applied_n++] = c[t].node[k];
                memset(h->applied_f[j], 0, sizeof h->applied_f[j]);
            }
            for (int a = 0; a < 3; ++a) h->applied_f[j][a] += c[t].f_n[k][a];
        }
    for (int k = 0; k < h->applied_n; ++k)
        hs_body_set_force(h->body, h->applied_node[k], h->applied_f[k]);
}

static double max_speed(const hs_haptic_sim* h) {
    const double* v = hs_body_velocity(h->body);
    double m = 0;
    for (int i = 0; i < h->mesh->n_nodes; ++i) {
        double s = v[3 * i] * v[3 * i] + v[3 * i + 1] * v[3 * i + 1] + v[3 * i + 2] * v[3 * i + 2];
        if (s > m) m = s;
    }
    return sqrt(m);
}

static void publish_frame(hs_haptic_sim* h) {
    unsigned char* f = hs_triple_buffer_back(h->frame);
    int64_t step = h->st.steps;
    memcpy(f, &step, sizeof step);
    memcpy(f + sizeof(int64_t), hs_body_displacement(h->body),
           3 * (size_t)h->mesh->n_nodes * sizeof(double));
    hs_triple_buffer_publish(h->frame);
}

// ---------------------------------------------------------------------------------------------
// cutting (deformation side)

static void quat_rotate(const double q[4], const double v[3], double out[3]) {
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    double r[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - w * z),     2 * (x * z + w * y),
                   2 * (x * y + w * z),     1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                   2 * (x * z - w * y),     2 * (y * z + w * x),     1 - 2 * (x * x + y * y)};
    for (int a = 0; a < 3; ++a)
        out[a] = r[3 * a] * v[0] + r[3 * a + 1] * v[1] + r[3 * a + 2] * v[2];
}

static hs_status build_tri_adjacency(hs_haptic_sim* h);

// Worker, once the job's compliance c on mesh m is built: solve its columns for the candidates
// at the tool now, so that the swap brings them along. The first snapshot on a compliance
// without them solved them on the deformation thread (64 columns: ~0.23 s on a 5k-vertex plate,
// more under load) while rt kept the stale compliance's empty snapshot: a press beside the cut
// felt nothing although the compliance was valid. The tool moves meanwhile: again while it went
// on by more than half the reach margin (when the sleeping loop would look again), a few times.
#define WARM_PASSES 3
static void comp_warm(hs_haptic_sim* h, const hs_mesh* m, hs_compliance* c) {
    if (!h->cdef.probe_when_released || m->n_tris > h->tri_cap) return; // nothing probes
    for (int k = 0; k < 3 * h->mesh->n_nodes; ++k) h->cw_xw[k] = h->cw_x0[k] + h->cw_u[k];
    const double margin = h->def.probe.reach_margin_m, reach = h->def.probe.radius_m + margin;
    double at[3] = {0, 0, 0};
    for (int pass = 0; pass < WARM_PASSES; ++pass) {
        double p[3];
        pthread_mutex_lock(&h->cw_mx);
        memcpy(p, h->cw_tool, sizeof p);
        pthread_mutex_unlock(&h->cw_mx);
        if (pass > 0 && dist3(p, at) <= 0.5 * margin) break;
        memcpy(at, p, sizeof at);
        int nodes[HS_CONTACT_MAX_CAND], tri[HS_CONTACT_MAX_TRI][3], n_near, n_tri;
        double cover;
        const int nc = find_candidates(m, c, h->cw_xw, p, reach, h->cw_near, h->cw_cand, nodes, tri,
                                       &n_near, &n_tri, &cover);
        hs_compliance_begin_step(c);
        // A failed solve leaves them to the deformation thread, as before.
        if (hs_compliance_ensure(c, nc, nodes, nc) < 0) break;
    }
}

// Worker: the haptic compliance of the job's mesh (see comp_start for what it holds).
// Recreated rather than updated (hs_compliance has no update entry point); it costs 0.1-0.2 s
// on the skin patch (0.4-0.7 s before its sparse diagonal blocks), which is why it runs beside
// the deformation thread instead of in it.
static void* comp_worker(void* arg) {
    hs_haptic_sim* h = arg;
    int64_t t0 = hs_now_ns();
    hs_err err = {0};
    hs_mesh* m = NULL;
    hs_compliance* c = NULL;
    const int n = h->mesh->n_nodes;
    memset(h->cw_fix, 1, (size_t)n);
    for (int k = 0; k < 4 * h->cw_ntets; ++k) h->cw_fix[h->cw_tets[k]] = 0;
    for (int i = 0; i < n; ++i) h->cw_fix[i] |= h->fixed0[i];
    hs_status s = hs_mesh_create(h->mesh->n_nodes, h->cw_x0, h->cw_ntets, h->cw_tets, &m, &err);
    if (s == HS_OK)
        s = hs_compliance_create(m, &h->def.body.fem, h->cw_fix, h->def.probe.cache_nodes, &c,
                                 &err);
    else if (s > HS_OK)
        s = HS_ERR_NUMERIC; // the live mesh passed its checks; a repair here means a bad copy
    if (s != HS_OK) {
        hs_compliance_destroy(&c);
        hs_mesh_destroy(&m);
    } else {
        comp_warm(h, m, c);
    }
    h->cw_mesh = m;
    h->cw_comp = c;
    h->cw_status = s;
    h->cw_ms = (double)(hs_now_ns() - t0) * 1e-6;
    atomic_store_explicit(&h->cw_done, 1, memory_order_release);
    return NULL;
}

// Start a rebuild on a copy of the live mesh. Returns 0 when it could not start.
static int comp_start(hs_haptic_sim* h) {
    hs_err err = {0};
    if (hs_cut_update_live(h->cut, &err) != HS_OK) return 0;
    const hs_mesh* live = hs_cut_live_mesh(h->cut);
    if (!live || live->n_tets > h->mesh->n_tets) return 0;
    const int n = h->mesh->n_nodes;
    memcpy(h->cw_x0, live->x0, 3 * (size_t)n * sizeof(double));
    memcpy(h->cw_u, hs_body_displacement(h->body), 3 * (size_t)n * sizeof(double));
    memcpy(h->cw_tool, h->st.contact.tool_m, sizeof h->cw_tool); // the previous pass's tool
    // The compliance sees the pieces the fixed region holds. Under DROP those are all the live
    // tets (the cut pins only nodes left without a tet). Under FIX the cut pins every node of
    // a piece it does not hold, and the body lets that piece move with its mass: its tets are
    // left out (a piece hanging on by a hinge carries no static load). Nodes no tet kept here
    // uses are held (and not contactable).
    int k = 0;
    for (int e = 0; e < live->n_tets; ++e) {
        const int* t = live->tets + 4 * e;
        int free_node = h->cdef.cut.fragment == HS_CUT_FRAGMENT_DROP;
        for (int a = 0; a < 4; ++a) free_node |= !hs_cut_node_pinned(h->cut, t[a]);
        if (free_node) memcpy(h->cw_tets + 4 * k++, t, 4 * sizeof(int));
    }
    h->cw_ntets = k;
    h->cw_version = hs_cut_topology_version(h->cut);
    h->cw_mesh = NULL;
    h->cw_comp = NULL;
    atomic_store_explicit(&h->cw_done, 0, memory_order_relaxed);
    if (pthread_create(&h->cw_thread, NULL, comp_worker, h) != 0) return 0;
    h->cw_running = 1;
    h->st.comp_building = 1;
    return 1;
}

// Take a finished rebuild (or wait for a running one): swap it in when it matches the newest
// topology, else drop it (a newer cut came meanwhile; the next release starts another).
// Returns 1 when swapped in (the probe's surface changed: a snapshot is due).
static int comp_poll(hs_haptic_sim* h, int wait) {
    if (!h->cw_running) return 0;
    if (!wait && !atomic_load_explicit(&h->cw_done, memory_order_acquire)) return 0;
    pthread_join(h->cw_thread, NULL);
    h->cw_running = 0;
    h->st.comp_building = 0;
    if (h->cw_status != HS_OK || h->cw_mesh->n_tris > h->tri_cap) {
        h->st.cut_failures++; // the old compliance stays; the next cut retries
        hs_compliance_destroy(&h->cw_comp);
        hs_mesh_destroy(&h->cw_mesh);
        return 0;
    }
    if (h->cw_version != hs_cut_topology_version(h->cut)) {
        h->st.comp_discarded++;
        hs_compliance_destroy(&h->cw_comp);
        hs_mesh_destroy(&h->cw_mesh);
        return 0;
    }
    hs_compliance_destroy(&h->comp);
    hs_mesh_destroy(&h->comp_mesh);
    h->comp = h->cw_comp;
    h->comp_mesh = h->cw_mesh;
    h->cw_comp = NULL;
    h->cw_mesh = NULL;
    h->smesh = h->comp_mesh; // the probe now touches the cut surface
    build_tri_adjacency(h);  // fits: n_tris <= tri_cap checked above
    h->q_reset = 1;
    h->st.comp_ms_last = h->cw_ms;
    h->st.comp_version = h->cw_version;
    h->st.comp_rebuilds++;
    h->st.comp_swap_ns = hs_now_ns();
    return 1;
}

// The compliance follows the cut step at once (hs_compliance_change_elements: the stiffness
// changes by the removed and moved elements' shares, the factor by a partial refactor), exact
// for the new topology before the next snapshot; the probe touches the cut's live surface.
// Returns 0 when it cannot: a compliance rebuilt on a copy (other element numbering), already
// stale, the FIX rule (its pinned pieces stay in the body but not in the compliance) or a failed
// update; the rebuild once the blade is released then takes over.
static int comp_follow(hs_haptic_sim* h) {
    if (h->comp_stale || h->cdef.cut.fragment != HS_CUT_FRAGMENT_DROP || !h->fsurf ||
        hs_compliance_mesh(h->comp) != h->mesh)
        return 0;
    const int *off, *mv;
    const int n_off = hs_cut_last_removed(h->cut, &off), n_mv = hs_cut_last_changed(h->cut, &mv);
    // The live boundary by the removals alone (a live-mesh rebuild took 10-60 ms on the tongue).
    hs_cut_surface_remove(h->fsurf, n_off, off);
    const hs_mesh* live = hs_cut_surface_mesh(h->fsurf);
    if (live->n_tris > h->tri_cap || live->n_surf_nodes < 1) return 0;
    if (hs_compliance_change_elements(h->comp, n_off, off, n_mv, mv, live) != HS_OK) return 0;
    h->smesh = live;
    build_tri_adjacency(h);
    h->q_reset = 1;
    h->cols_cold = 1;
    h->st.comp_ms_last = hs_compliance_update_ms(h->comp);
    h->st.comp_version = hs_cut_topology_version(h->cut);
    h->st.comp_updates++;
    return 1;
}

// Hand the cut's result to the control thread (rest positions, event lists; the reader
// derives the live surface from the removed tets).
static void share_topology(hs_haptic_sim* h, const double quad[12]) {
    const int* rem = NULL;
    const int* mov = NULL;
    int nr = hs_cut_last_removed(h->cut, &rem), nm = hs_cut_last_moved(h->cut, &mov);
    pthread_mutex_lock(&h->tmx);
    memcpy(h->t_x0, h->mesh->x0, 3 * (size_t)h->mesh->n_nodes * sizeof(double));
    for (int k = 0; k < nr && h->t_nremoved < h->mesh->n_tets; ++k)
        h->t_removed[h->t_nremoved++] = rem[k];
    for (int k = 0; k < nm; ++k)
        if (!h->t_mflag[mov[k]]) {
            h->t_mflag[mov[k]] = 1;
            h->t_moved[h->t_nmoved++] = mov[k];
        }
    memcpy(h->t_quad, quad, sizeof h->t_quad);
    atomic_store(&h->topo_version, hs_cut_topology_version(h->cut));
    pthread_mutex_unlock(&h->tmx);
}

// Once the body's factor refactors partially (its first cut with a rest-state factor it can
// refactor in part), a helper thread shares the large supernodes when two or more processors
// are online: a core the haptic thread barely uses. Started here, on the deformation thread,
// after the first (one-thread) full pass, as the factor's parallelism; none if it cannot start.
static void factor_helper(hs_haptic_sim* h) {
    hs_cholesky* f = hs_body_factor(h->body);
    if (!h->factor_own || h->factor_tried || !f || hs_cholesky_partial_share(f) <= 0) return;
    h->factor_tried = 1;
    if (sysconf(_SC_NPROCESSORS_ONLN) < 2 ||
        hs_worker_create(hs_sparse_thread_init, NULL, &h->factor_worker) != HS_OK)
        return;
    h->factor_par = (hs_parallel){.run = hs_worker_run,
                                  .user = h->factor_worker,
                                  .width = 2,
                                  .begin = hs_worker_begin,
                                  .end = hs_worker_end};
    (void)hs_cholesky_set_partial_parallel(f, &h->factor_par);
}

// One blade step: sweep from the last blade pose to the newest one when it travelled far
// enough, mirror the cut into the body and the compliance, and set the resistance. Returns 1
// when a new snapshot is due (the resistance or the body changed).
static int cut_step(hs_haptic_sim* h) {
    cut_pose cp;
    hs_triple_buffer_read_copy(h->cpose, &cp);
    const hs_haptic_pose pose = cp.pose;
    if (pose.seq <= 0 || pose.seq <= h->pose_floor) return 0;
    const hs_haptic_cut_def* cd = &h->cdef;
    int engaged = !cd->engage_buttons || (pose.buttons & cd->engage_buttons);
    // Pressing or releasing switches the probe contact (probe_when_released): a snapshot is due.
    int flipped = engaged != h->engaged;
    h->engaged = engaged;
    static const double zero[3] = {0, 0, 0};
    if (flipped) {
        // Where the blade let go: the probe sphere that appears there is fitted (build_snapshot).
        memcpy(h->release_p, cp.flip_m, sizeof h->release_p);
        h->release_fit = !engaged;
    }
    if (!engaged) {
        h->blade_have = 0;
        h->st.cutting = 0;
        if (memcmp(h->cut_force, zero, sizeof zero)) { // first the zero-force snapshot
            memset(h->cut_force, 0, sizeof h->cut_force);
            memset(h->st.cut_force_n, 0, sizeof h->st.cut_force_n);
            return 1;
        }
        if (h->comp_stale && !h->cw_running) {
            // The blade has no contact sphere, so nothing reads the compliance while it cuts:
            // rebuild it once the blade is withdrawn, in the background.
            if (!comp_start(h)) h->st.cut_failures++;
            h->comp_stale = 0;
        }
        return flipped;
    }
    double p1[3], q1[3], ra[3], rb[3];
    quat_rotate(pose.quat_wxyz, cd->blade_a, ra);
    quat_rotate(pose.quat_wxyz, cd->blade_b, rb);
    for (int k = 0; k < 3; ++k) {
        p1[k] = pose.pos_m[k] + ra[k];
        q1[k] = pose.pos_m[k] + rb[k];
    }
    int64_t now = hs_now_ns();
    if (!h->blade_have) {
        memcpy(h->bp, p1, sizeof p1);
        memcpy(h->bq, q1, sizeof q1);
        memcpy(h->still_p, p1, sizeof p1);
        memcpy(h->still_q, q1, sizeof q1);
        h->still_ns = now;
        h->blade_have = 1;
        return flipped;
    }
    if (dist3(p1, h->still_p) > CUT_STILL_M || dist3(q1, h->still_q) > CUT_STILL_M) {
        memcpy(h->still_p, p1, sizeof p1); // either end: a blade turning about one moves
        memcpy(h->still_q, q1, sizeof q1);
        h->still_ns = now;
    } else if (now - h->still_ns > CUT_STILL_NS && memcmp(h->cut_force, zero, sizeof zero)) {
        memset(h->cut_force, 0, sizeof h->cut_force); // rt blends it out
        memset(h->st.cut_force_n, 0, sizeof h->st.cut_force_n);
        return 1;
    }
    double tp = dist3(p1, h->bp), tq = dist3(q1, h->bq);
    if ((tp > tq ? tp : tq) < cd->min_travel_m) return 0;

    int64_t t0 = hs_now_ns();
    const size_t n3 = 3 * (size_t)h->mesh->n_nodes;
    memcpy(h->cu, hs_body_displacement(h->body), n3 * sizeof(double));
    hs_cut_result res;
    memset(&res, 0, sizeof res);
    hs_err err = {0};
    hs_status s = hs_cut_sweep(h->cut, h->bp, h->bq, p1, q1, h->cu, &res, &err);
    h->st.cut_sweeps++;
    double quad[12];
    memcpy(quad, h->bp, 3 * sizeof(double));
    memcpy(quad + 3, h->bq, 3 * sizeof(double));
    memcpy(quad + 6, p1, 3 * sizeof(double));
    memcpy(quad + 9, q1, 3 * sizeof(double));
    double travel[3];
    for (int k = 0; k < 3; ++k) travel[k] = 0.5 * (p1[k] + q1[k] - h->bp[k] - h->bq[k]);
    memcpy(h->bp, p1, sizeof p1);
    memcpy(h->bq, q1, sizeof q1);
    double f[3] = {0, 0, 0};
    // The edge length a sweep crosses grows with its length, which is the blade's travel in a
    // step (at least min_travel_m): per min_travel_m of travel, so that the force follows the
    // tissue and not the speed (it doubled from 0.5 to 1 mm sweeps).
    double tlen = sqrt(travel[0] * travel[0] + travel[1] * travel[1] + travel[2] * travel[2]);
    double per = cd->min_travel_m > 0 && tlen > cd->min_travel_m ? cd->min_travel_m / tlen : 1.0;
    if (s == HS_OK)
        hs_cut_force(cd->toughness_n_m, res.cut_length_m * per, travel, cd->max_force_n, f);
    else
        h->st.cut_failures++;
    // A sweep that failed after it changed the mesh still changed it (its topology version
    // grew): the body, the compliance and the net thread follow it all the same.
    int changed = res.removed > 0 || res.moved > 0;
    h->st.cutting = res.cut_tets > 0;
    if (!changed && s != HS_OK) (void)hs_cut_sync_fem(h->cut, hs_body_fem(h->body));
    if (changed) {
        double sweep_ms = (double)(hs_now_ns() - t0) * 1e-6;
        memcpy(h->cv, hs_body_velocity(h->body), n3 * sizeof(double));
        // The body follows the sweep (by a low-rank update of its factor when it keeps a
        // rest-state one); after a failed sweep, or should that fail, mirror every removal and
        // refactor instead.
        const int *off, *mv;
        int n_off = hs_cut_last_removed(h->cut, &off), n_mv = hs_cut_last_changed(h->cut, &mv);
        if ((s != HS_OK || hs_body_change_elements(h->body, n_off, off, n_mv, mv, NULL) != HS_OK) &&
            hs_cut_sync_fem(h->cut, hs_body_fem(h->body)) != HS_OK)
            h->st.cut_failures++;
        factor_helper(h);
        hs_body_set_state(h->body, h->cu, h->cv);
        if (s != HS_OK || !comp_follow(h)) h->comp_stale = 1;
        share_topology(h, quad);
        h->st.cut_steps++;
        h->st.cut_removed += res.removed;
        h->st.sweep_ms_last = sweep_ms;
        h->st.cut_done_ns = hs_now_ns();
        if (!h->comp_stale) h->st.comp_swap_ns = h->st.cut_done_ns; // valid with the step
        double ms = (double)(h->st.cut_done_ns - t0) * 1e-6;
        h->st.cut_ms_last = ms;
        if (ms > h->st.cut_ms_max) h->st.cut_ms_max = ms;
    }
    // First-order smoothing over sweeps: whether a short sweep happens to cross an edge is a
    // matter of the grid, not of the tissue; rt then blends each change over blend_ticks.
    for (int k = 0; k < 3; ++k)
        f[k] = h->cut_force[k] + CUT_FORCE_SMOOTH * (f[k] - h->cut_force[k]);
    int due = changed || memcmp(f, h->cut_force, sizeof f) != 0;
    memcpy(h->cut_force, f, sizeof f);
    memcpy(h->st.cut_force_n, f, sizeof f);
    return due;
}

static void timespec_add(struct timespec* t, int64_t ns) {
    t->tv_nsec += ns;
    while (t->tv_nsec >= 1000000000L) {
        t->tv_nsec -= 1000000000L;
        t->tv_sec++;
    }
}

// How deep the sphere presses: its reach past the rest surface at the contact nodes along the
// force (their mean rest position, weighted by their forces; on a flat surface the centre's
// depth + r). 0 without a force.
static double press_depth(const hs_haptic_sim* h, const hs_contact* c) {
    const double* f = c->force_n;
    const double fl = sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
    double x[3] = {0, 0, 0}, wsum = 0;
    for (int k = 0; k < c->n; ++k) {
        const double* fk = c->f_n[k];
        const double w = sqrt(fk[0] * fk[0] + fk[1] * fk[1] + fk[2] * fk[2]);
        for (int a = 0; a < 3; ++a) x[a] += w * h->mesh->x0[3 * (size_t)c->node[k] + a];
        wsum += w;
    }
    if (!(fl > 0) || !(wsum > 0)) return 0;
    double d = h->def.probe.radius_m;
    for (int a = 0; a < 3; ++a) d -= (c->tool_m[a] - x[a] / wsum) * f[a] / fl;
    return d > 0 ? d : 0;
}

static int cmp_double(const void* pa, const void* pb) {
    double a = *(const double*)pa, b = *(const double*)pb;
    return (a > b) - (a < b);
}

// q-quantile of the newest n recorded step times (n <= HS_SIM_STEP_WINDOW), ms.
static double recent_quantile(const hs_haptic_sim* h, int n, double q) {
    double v[HS_SIM_STEP_WINDOW];
    if (n > h->recent_n) n = (int)h->recent_n;
    if (n <= 0) return 0;
    for (int k = 0; k < n; ++k) v[k] = h->recent_ms[(h->recent_n - 1 - k) % HS_SIM_STEP_WINDOW];
    qsort(v, (size_t)n, sizeof v[0], cmp_double);
    int i = (int)ceil(q * n) - 1;
    return v[i < 0 ? 0 : i >= n ? n - 1 : i];
}

// Thread CPU time, ns: what a step costs on one core whatever else the machine runs.
static int64_t thread_cpu_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return (int64_t)t.tv_sec * 1000000000LL + t.tv_nsec;
}

static double hist_quantile(const hs_haptic_sim* h, const uint32_t* hist, double q) {
    if (h->step_hist_n <= 0) return 0;
    int64_t want = (int64_t)ceil(q * (double)h->step_hist_n), acc = 0;
    if (want < 1) want = 1;
    for (int b = 0; b <= STEP_BINS; ++b) {
        acc += hist[b];
        if (acc >= want) return b == STEP_BINS ? h->st.step_ms_max : (b + 1) * STEP_BIN_MS;
    }
    return h->st.step_ms_max;
}

// Book a step (+ snapshot) of ms: histogram, recent window, overruns; and every RATE_EVERY
// steps the pacing: a rate the thread cannot keep is lowered to what it can (no bursts to catch
// up, a steady cadence), and raised again with hysteresis. The haptic rate is not touched.
static void record_step(hs_haptic_sim* h, double ms, double cpu_ms) {
    const int64_t step_ns = (int64_t)(h->def.body.dt * 1e9);
    int b = (int)(ms / STEP_BIN_MS);
    h->step_hist[b < 0 ? 0 : b > STEP_BINS ? STEP_BINS : b]++;
    b = (int)(cpu_ms / STEP_BIN_MS);
    h->step_hist[STEP_BINS + 1 + (b < 0 ? 0 : b > STEP_BINS ? STEP_BINS : b)]++;
    h->step_hist_n++;
    h->recent_ms[h->recent_n++ % HS_SIM_STEP_WINDOW] = ms;
    if (ms * 1e6 > (double)step_ns) h->st.step_overruns++;
    h->st.step_p50 = recent_quantile(h, HS_SIM_STEP_WINDOW, 0.5);
    h->st.step_p99 = recent_quantile(h, HS_SIM_STEP_WINDOW, 0.99);
    if ((h->step_hist_n & 15) == 1) {
        h->st.step_p50_all = hist_quantile(h, h->step_hist, 0.5);
        h->st.step_p99_all = hist_quantile(h, h->step_hist, 0.99);
        h->st.step_cpu_p50_all = hist_quantile(h, h->step_hist + STEP_BINS + 1, 0.5);
        h->st.step_cpu_p99_all = hist_quantile(h, h->step_hist + STEP_BINS + 1, 0.99);
    }
    // With cutting on, the blade's sweeps and the compliance swaps run once per loop pass: the
    // loop keeps the nominal pacing (late: at once, no burst) rather than a lowered rate.
    if (h->cut) return;
    int64_t p = h->period_ns;
    if (p > step_ns && h->recent_n >= RATE_FAST) {
        // Up quickly: the newest RATE_FAST steps all fit well (a lowered rate would otherwise
        // hold for RATE_EVERY of its own long periods after the load is gone).
        double fast = RATE_MARGIN * recent_quantile(h, RATE_FAST, 1.0) * 1e6; // ns
        if (fast < RATE_RAISE * (double)p) p = (int64_t)fmax(fast, (double)step_ns);
    }
    if (p == h->period_ns && ++h->rate_count >= RATE_EVERY && h->recent_n >= RATE_WINDOW &&
        !(h->def.auto_solver && h->au_since < RATE_WINDOW)) { // (not while a switch settles)
        // Down slowly: the median of the newest RATE_WINDOW steps does not fit.
        h->rate_count = 0;
        double want = RATE_MARGIN * recent_quantile(h, RATE_WINDOW, 0.5) * 1e6; // ns
        if (want > (double)p) p = (int64_t)fmin(want, (double)(RATE_MAX_DIV * step_ns));
    }
    if (p != h->period_ns) {
        h->period_ns = p;
        h->st.rate_changes++;
        h->st.sim_hz_target = 1e9 / (double)p;
    }
}

static int auto_rank_of(hs_solver_kind k) {
    for (int r = 0; r < 3; ++r)
        if (auto_rank[r] == k) return r;
    return 2;
}

static void auto_switch(hs_haptic_sim* h, hs_solver_kind k) {
    hs_err err = {0};
    if (hs_body_set_solver(h->body, k, &err) != HS_OK) return; // set up at create: cannot fail
    h->st.solver = (int)k;
    h->st.solver_switches++;
    h->au_since = 0;
    h->au_over = 0;
}

// Solver choice after a step whose body part took body_ms and snapshot snap_ms: the most
// accurate solver whose step fits the nominal period. Over the budget AUTO_DOWN steps (net):
// the next cheaper one, and the failed one waits AUTO_RETRY_S (doubling) before it is measured
// again. Well inside the budget: the next more accurate one, when its estimate fits
// AUTO_UP_KNOWN of the budget or, unmeasured, the current fits AUTO_UP_PROBE.
static void auto_solver_step(hs_haptic_sim* h, double body_ms, double snap_ms) {
    const hs_solver_kind k = hs_body_solver(h->body);
    // The hook books the whole step (body + snapshot): no clock enters the choice then.
    const double c =
        h->def.step_cost ? h->def.step_cost(h->def.step_cost_ctx, k, body_ms + snap_ms) : body_ms;
    if (h->def.step_cost) snap_ms = 0;
    if (++h->au_since <= AUTO_SETTLE) return;
    double* e = &h->st.solver_ms[k];
    *e = *e > 0 ? *e + 0.25 * (c - *e) : c;
    h->au_snap_ms = h->au_snap_ms > 0 ? h->au_snap_ms + 0.25 * (snap_ms - h->au_snap_ms) : snap_ms;
    const double budget = h->def.body.dt * 1e3;
    if (c + h->au_snap_ms > budget)
        h->au_over++;
    else if (h->au_over > 0)
        h->au_over--;
    const int64_t now = hs_now_ns();
    const int r = auto_rank_of(k);
    if (h->au_over >= AUTO_DOWN && r < h->au_last) {
        double w = h->au_backoff_s[k] > 0 ? h->au_backoff_s[k] : AUTO_RETRY_S;
        h->au_retry_ns[k] = now + (int64_t)(w * 1e9);
        h->au_backoff_s[k] = fmin(2 * w, AUTO_RETRY_MAX_S);
        auto_switch(h, auto_rank[r + 1]);
        return;
    }
    if (r == 0 || h->au_since < AUTO_UP_STEPS) return;
    const hs_solver_kind up = auto_rank[r - 1];
    if (now < h->au_retry_ns[up]) return;
    if (h->au_retry_ns[up]) { // its wait is over: measure it afresh (the load may have changed)
        h->st.solver_ms[up] = 0;
        h->au_retry_ns[up] = 0;
    }
    const double eu = h->st.solver_ms[up];
    if (eu > 0 ? eu + h->au_snap_ms <= AUTO_UP_KNOWN * budget
               : *e + h->au_snap_ms <= AUTO_UP_PROBE * budget)
        auto_switch(h, up);
}

// hs_parallel on threads of its own: task 0 on the caller, the others each on a new thread
// (in turn on the caller when one cannot be started).
typedef struct par_arg {
    hs_task_fn* task;
    void* ctx;
    int i;
} par_arg;

static void* par_main(void* a) {
    par_arg* p = a;
    p->task(p->i, p->ctx);
    return NULL;
}

static void par_run(int n, hs_task_fn* task, void* ctx, void* user) {
    (void)user;
    pthread_t t[HS_PARALLEL_MAX];
    par_arg a[HS_PARALLEL_MAX];
    int started[HS_PARALLEL_MAX] = {0};
    for (int i = 1; i < n && i < HS_PARALLEL_MAX; ++i) {
        a[i] = (par_arg){task, ctx, i};
        started[i] = pthread_create(&t[i], NULL, par_main, &a[i]) == 0;
        if (!started[i]) task(i, ctx);
    }
    task(0, ctx);
    for (int i = 1; i < n && i < HS_PARALLEL_MAX; ++i)
        if (started[i]) pthread_join(t[i], NULL);
}

// Background compliance set-up (def.background_setup): the worker builds it from the mesh, the
// def and fixed0 (none of which change meanwhile: cutting waits for it). Nothing else is busy
// then (no force until it is ready): its diagonal blocks use every core.
static void* setup_worker(void* arg) {
    hs_haptic_sim* h = arg;
    int64_t t0 = hs_now_ns();
    long cores = sysconf(_SC_NPROCESSORS_ONLN);
    hs_parallel par = {.run = par_run, .width = cores < 1 ? 1 : cores > 4 ? 4 : (int)cores};
    h->su_status =
        hs_compliance_create_par(h->mesh, &h->def.body.fem, h->fixed0, h->def.probe.cache_nodes,
                                 &par, &h->su_comp, &h->su_err);
    h->su_ms = (double)(hs_now_ns() - t0) * 1e-6;
    atomic_store_explicit(&h->su_done, 1, memory_order_release);
    return NULL;
}

// Take the finished set-up (or wait for it): the deformation thread while it runs, else the
// control thread. Returns 1 when the compliance is now in use.
static int setup_take(hs_haptic_sim* h, int wait) {
    if (!h->su_running) return 0;
    if (!wait && !atomic_load_explicit(&h->su_done, memory_order_acquire)) return 0;
    pthread_join(h->su_thread, NULL);
    h->su_running = 0;
    if (h->su_status != HS_OK) {
        hs_compliance_destroy(&h->su_comp);
        atomic_store_explicit(&h->comp_state, -1, memory_order_release);
        return 0;
    }
    h->comp = h->su_comp;
    h->su_comp = NULL;
    atomic_store_explicit(&h->comp_state, 0, memory_order_release);
    return 1;
}

static void* deform_main(void* arg) {
    hs_haptic_sim* h = arg;
    const int64_t idle_ns = (int64_t)(h->def.idle_poll_s * 1e9);
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    hs_contact cs[HS_MAX_TOOLS];
    memset(cs, 0, sizeof cs);
    hs_contact* const cp = &cs[0]; // tool 0's
    double centre[3 * HS_MAX_TOOLS], tools[3 * HS_MAX_TOOLS];
    for (int k = 0; k < 3 * HS_MAX_TOOLS; ++k) centre[k] = k < 3 ? 0 : TOOL_AWAY_M;
    for (int t = 1; t < HS_MAX_TOOLS; ++t) cs[t].tool_m[0] = TOOL_AWAY_M;
    int have_snapshot = 0;
    while (!atomic_load_explicit(&h->stop, memory_order_acquire)) {
        int fresh = hs_triple_buffer_read_copy(h->contact, cs);
        (void)fresh;
        hs_contact c = *cp;
        int loaded = h->applied_n > 0;
        for (int t = 0; t < h->n_tools; ++t) {
            loaded = loaded || cs[t].n > 0;
            memcpy(tools + 3 * t, cs[t].tool_m, sizeof cs[t].tool_m);
        }
        if (h->cw_running) { // where the rebuild's worker solves the first columns
            pthread_mutex_lock(&h->cw_mx);
            memcpy(h->cw_tool, cp->tool_m, sizeof h->cw_tool);
            pthread_mutex_unlock(&h->cw_mx);
        }
        int64_t t0 = hs_now_ns(), c0 = thread_cpu_ns();
        int rebuild = 0, cut_changed = 0;
        h->st.loops++;
        if (h->su_running) setup_take(h, 0);
        if (h->cut) {
            int swapped = comp_poll(h, 0);
            // Say so before the snapshot with the new contact goes out (a step may come
            // first): a reader never sees that contact while the status still says stale.
            if (swapped) hs_triple_buffer_write(h->status, &h->st);
            int64_t before = h->st.cut_steps;
            rebuild = cut_step(h) || swapped;
            cut_changed = h->st.cut_steps != before;
            // A body at rest under gravity or pre-stress is no longer in equilibrium after a
            // cut (a lip opens, a piece cut free falls): it must step before it may sleep.
            if (cut_changed) h->wake_steps = 10;
        }
        int moving = loaded || h->wake_steps > 0 || max_speed(h) > h->def.sleep_speed_m_s;
        if (h->wake_steps > 0) h->wake_steps--;
        double body_ms = 0;
        if (moving) {
            // The forces rt computed from the last snapshot drive this step.
            apply_contact(h, cs, h->n_tools);
            int64_t tb = hs_now_ns();
            hs_status s = hs_body_step(h->body, NULL);
            body_ms = (double)(hs_now_ns() - tb) * 1e-6;
            if (s != HS_OK)
                h->st.step_failures++;
            else
                h->st.steps++;
            rebuild = 1;
        } else {
            // At rest: refresh the candidates only when the tool wandered toward their edge.
            // A fitted probe grows with its clearance: refresh it as the tool moves.
            const double refresh = h->probe_r < h->def.probe.radius_m
                                       ? 0.05 * h->def.probe.radius_m
                                       : 0.5 * h->def.probe.reach_margin_m;
            rebuild = rebuild || !have_snapshot;
            for (int t = 0; t < h->n_tools; ++t)
                rebuild = rebuild || dist3(tools + 3 * t, centre + 3 * t) > refresh;
        }
        if (rebuild) {
            int64_t t1 = hs_now_ns();
            // No compliance yet (background set-up): no snapshot, rt answers zero force.
            if (h->comp) {
                build_snapshot(h, tools);
                memcpy(centre, tools, 3 * (size_t)h->n_tools * sizeof(double));
                have_snapshot = 1;
            }
            double sms = (double)(hs_now_ns() - t1) * 1e-6;
            h->st.snapshot_ms_last = sms;
            if (sms > h->st.snapshot_ms_max) h->st.snapshot_ms_max = sms;
            if (moving || cut_changed) publish_frame(h);
            double ms = (double)(hs_now_ns() - t0) * 1e-6;
            h->st.step_ms_last = ms;
            if (ms > h->st.step_ms_max) h->st.step_ms_max = ms;
            if (moving) {
                record_step(h, ms, (double)(thread_cpu_ns() - c0) * 1e-6);
                if (h->def.auto_solver) auto_solver_step(h, body_ms, sms);
            }
        }
        h->st.sleeping = !moving;
        if (!moving && h->period_ns != (int64_t)(h->def.body.dt * 1e9)) {
            // At rest: the next contact starts at the nominal rate (the load may be gone).
            h->period_ns = (int64_t)(h->def.body.dt * 1e9);
            h->st.sim_hz_target = 1.0 / h->def.body.dt;
            h->st.rate_changes++;
        }
        h->st.contact = c;
        const double depth = press_depth(h, &c);
        if (depth > h->st.depth_max) h->st.depth_max = depth;
        if (depth > hs_contact_validated_depth(h->def.probe.radius_m)) h->st.deep_loops++;
        if (h->comp) h->st.column_solves = hs_compliance_column_solves(h->comp);
        hs_triple_buffer_write(h->status, &h->st);

        if (moving) {
            const int64_t step_ns = h->period_ns;
            timespec_add(&next, step_ns);
            // Fell behind by more than a step: restart the pacing instead of bursting.
            struct timespec now;
            clock_gettime(CLOCK_MONOTONIC, &now);
            int64_t late =
                ((int64_t)now.tv_sec - next.tv_sec) * 1000000000LL + (now.tv_nsec - next.tv_nsec);
            if (late > step_ns) next = now;
        } else {
            clock_gettime(CLOCK_MONOTONIC, &next);
            timespec_add(&next, idle_ns);
        }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL);
    }
    return NULL;
}

// ---------------------------------------------------------------------------------------------
// Life cycle

// Node -> boundary triangles of h->smesh (CSR). Fits the arrays sized at create / enable.
static hs_status build_tri_adjacency(hs_haptic_sim* h) {
    const hs_mesh* m = h->smesh;
    const int n = h->mesh->n_nodes;
    if (m->n_tris > h->tri_cap) return HS_ERR_NOMEM;
    memset(h->tri_start, 0, ((size_t)n + 1) * sizeof(int));
    for (int t = 0; t < m->n_tris; ++t)
        for (int k = 0; k < 3; ++k) h->tri_start[m->tris[3 * t + k] + 1]++;
    for (int i = 0; i < n; ++i) h->tri_start[i + 1] += h->tri_start[i];
    int* fill = h->near_node;
    memcpy(fill, h->tri_start, (size_t)n * sizeof(int));
    for (int t = 0; t < m->n_tris; ++t)
        for (int k = 0; k < 3; ++k) h->tri_list[fill[m->tris[3 * t + k]]++] = t;
    return HS_OK;
}

/// The cutting workspace, allocated by hs_haptic_sim_enable_cutting (again on each call).
static void free_cut_scratch(hs_haptic_sim* h) {
    hs_cut_surface_destroy(&h->fsurf);
    hs_free(h->cw_x0);
    hs_free(h->cw_tets);
    hs_free(h->cw_fix);
    hs_free(h->cw_u);
    hs_free(h->cw_xw);
    hs_free(h->cw_near);
    hs_free(h->cw_cand);
    hs_free(h->cu);
    hs_free(h->cv);
    hs_free(h->t_x0);
    hs_free(h->t_tris);
    hs_free(h->t_removed);
    hs_free(h->t_moved);
    hs_free(h->t_mflag);
    hs_free(h->r_gone);
    hs_free(h->r_keys);
    hs_free(h->r_sorted);
    hs_free(h->r_start);
    hs_free(h->r_cur);
}

void hs_haptic_sim_destroy(hs_haptic_sim** ph) {
    if (!ph || !*ph) return;
    hs_haptic_sim* h = *ph;
    hs_haptic_sim_stop(h);
    setup_take(h, 1);
    hs_rt_loop_destroy(&h->loop);
    hs_haptic_rt_destroy(&h->hrt);
    hs_memdev_destroy(&h->dev);
    for (int t = 1; t < HS_MAX_TOOLS; ++t) {
        hs_haptic_rt_destroy(&h->xhrt[t]);
        hs_memdev_destroy(&h->xdev[t]);
    }
    hs_contact_work_destroy(&h->src.work);
    hs_triple_buffer_destroy(&h->snap);
    hs_triple_buffer_destroy(&h->contact);
    hs_triple_buffer_destroy(&h->frame);
    hs_triple_buffer_destroy(&h->status);
    hs_compliance_destroy(&h->comp);
    hs_mesh_destroy(&h->comp_mesh);
    hs_body_destroy(&h->body);
    hs_worker_destroy(&h->factor_worker); // after the factor that used it
    hs_free(h->tri_start);
    hs_free(h->tri_list);
    hs_free(h->x);
    hs_free(h->g);
    hs_free(h->v);
    hs_free(h->rot);
    hs_free(h->q);
    hs_free(h->dq);
    hs_free(h->pre);
    hs_free(h->pre_at);
    hs_free(h->near_node);
    hs_free(h->near_tri);
    hs_free(h->cand_of);
    hs_free(h->step_hist);
    hs_triple_buffer_destroy(&h->cpose);
    hs_cut_destroy(&h->cut);
    hs_free(h->fixed0);
    free_cut_scratch(h);
    if (h->tmx_init) {
        pthread_mutex_destroy(&h->tmx);
        pthread_mutex_destroy(&h->cw_mx);
    }
    hs_free(h);
    *ph = NULL;
}

// Tools 1 .. n_tools-1: a device and a tick each, with tool 0's options (hd), and the joint
// solve's workspace.
static hs_status create_tools(hs_haptic_sim* h, const hs_haptic_rt_def* hd, hs_err* err) {
    h->src.n_tools = h->n_tools;
    if (h->n_tools == 1) return HS_OK;
    if (hs_contact_work_create(h->n_tools, &h->src.work) != HS_OK)
        return hs_err_set(err, HS_ERR_NOMEM, "hs_haptic_sim_create: out of memory");
    for (int t = 1; t < h->n_tools; ++t) {
        hs_status s = hs_memdev_create(&h->xdev[t], err);
        if (s != HS_OK) return s;
        h->xsrc[t].p = &h->src;
        h->xsrc[t].t = t;
        hs_haptic_rt_def d = *hd;
        d.device = hs_memdev_device(h->xdev[t]);
        d.source.eval = tool_eval;
        d.source.ctx = &h->xsrc[t];
        d.telemetry_capacity = 0;
        s = hs_haptic_rt_create(&d, &h->xhrt[t], err);
        if (s != HS_OK) return s;
    }
    return HS_OK;
}

// The definition's checks, before anything is made.
static hs_status check_def(const hs_haptic_sim_def* def, hs_err* err) {
    if (def->cookie != SIM_COOKIE || def->probe.cookie != PROBE_COOKIE)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_create: definition not initialised with "
                          "hs_haptic_sim_default_def()");
    if (def->tools < 1 || def->tools > HS_MAX_TOOLS)
        return hs_err_set(err, HS_ERR_INVALID, "hs_haptic_sim_create: tools %d not in 1..%d",
                          def->tools, HS_MAX_TOOLS);
    for (int t = 0; t < HS_MAX_TOOLS; ++t)
        if (!(def->tool_radius_m[t] >= 0 && def->tool_radius_m[t] <= 1))
            return hs_err_set(err, HS_ERR_INVALID,
                              "hs_haptic_sim_create: tool_radius_m[%d] %g m not in [0, 1]", t,
                              def->tool_radius_m[t]);
    const hs_probe_def* pd = &def->probe;
    if (!(pd->radius_m > 0) || !isfinite(pd->radius_m) || !(pd->reach_margin_m >= 0) ||
        !isfinite(pd->reach_margin_m))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_create: probe radius %g m / margin %g m invalid",
                          pd->radius_m, pd->reach_margin_m);
    if (pd->cache_nodes < HS_CONTACT_MAX_CAND + HS_MAX_CONTACT)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_create: probe cache_nodes %d < %d (candidates + contacts)",
                          pd->cache_nodes, HS_CONTACT_MAX_CAND + HS_MAX_CONTACT);
    if (!(pd->free_relax > 0 && pd->free_relax <= 1))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_create: probe free_relax %g not in (0, 1]",
                          pd->free_relax);
    if (pd->max_new_columns < 0 || !(pd->min_radius_m >= 0) ||
        !(pd->max_radius_m >= pd->min_radius_m) || !(pd->model_timeout_s > 0))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_create: probe column budget, validity radius or timeout "
                          "invalid");
    // The threads sleep a tick, a step or an idle poll at a time and stopping waits for that
    // sleep: each is at most 1 s (a 1e6 s poll made stop block for days, Inf spun the thread).
    if (!(def->rate_hz >= 1 && def->rate_hz <= 1e5) || def->blend_ticks < 1 ||
        !(def->idle_poll_s > 0 && def->idle_poll_s <= 1) || !(def->body.dt <= 1) ||
        !(def->sleep_speed_m_s >= 0))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_create: rate %g Hz (1..1e5), blend %d ticks (>= 1), "
                          "idle poll %g s or body dt %g s (each in (0, 1]) invalid",
                          def->rate_hz, def->blend_ticks, def->idle_poll_s, def->body.dt);
    if (!hs_safety_def_valid(&def->safety))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_create: safety definition invalid (use "
                          "hs_safety_default_def())");
    return HS_OK;
}

// The deformable body; with auto_solver, the solver it starts with.
static hs_status create_body(hs_haptic_sim* h, const hs_haptic_sim_def* def,
                             const unsigned char* fixed, hs_err* err) {
    const hs_mesh* mesh = h->mesh;
    hs_body_def bd = def->body;
    if (!bd.factor_parallel) { // filled by factor_helper
        bd.factor_parallel = &h->factor_par;
        h->def.body.factor_parallel = &h->factor_par;
        h->factor_own = 1;
    }
    if (h->def.auto_solver) {
        // Start with the cheapest allowed solver; the PCG workspace is made now, so a switch
        // on the deformation thread allocates nothing.
        h->au_last = def->auto_exact_tangent ? 1 : 2;
        bd.solver = auto_rank[h->au_last];
        bd.precond = HS_PRECOND_WARPED;
        h->def.body = bd;
    }
    hs_status s = hs_body_create(mesh, &bd, fixed, &h->body, err);
    if (s != HS_OK) return s;
    if (h->def.auto_solver && (hs_body_set_solver(h->body, HS_SOLVER_PCG, err) != HS_OK ||
                               hs_body_set_solver(h->body, bd.solver, err) != HS_OK)) {
        return HS_ERR_NOMEM;
    }
    if (h->def.auto_solver) {
        // The first step's factorisation, made now and timed: a direct step refactors about
        // that every step, plus the element pass, a back-solve and the snapshot. When it fits
        // AUTO_START of the period, start with the most accurate solver (a small mesh never
        // steps with a cheaper one); else with the cheapest, whose factor it is.
        double f_ms = 0;
        if (hs_body_prepare_step(h->body, &f_ms) == HS_OK) {
            h->st.factor_ms = f_ms;
            double c =
                def->step_cost ? def->step_cost(def->step_cost_ctx, HS_SOLVER_DIRECT, f_ms) : f_ms;
            // A small factor starts direct whatever the clock says (a loaded machine must not
            // change a small scene's solver); the test hook stands for any size.
            const int small = !def->step_cost && hs_body_factor(h->body) &&
                              hs_cholesky_factor_nnz(hs_body_factor(h->body)) <= AUTO_START_NNZ;
            if (small || c <= AUTO_START * def->body.dt * 1e3) {
                hs_body_set_solver(h->body, HS_SOLVER_DIRECT, NULL);
                bd.solver = HS_SOLVER_DIRECT;
            }
        }
    }
    h->st.solver = (int)bd.solver;
    return HS_OK;
}

// The per-node and per-triangle arrays of the contact search; -1 when out of memory.
static int alloc_arrays(hs_haptic_sim* h, const hs_haptic_sim_def* def) {
    const hs_mesh* mesh = h->mesh;
    const size_t n = (size_t)mesh->n_nodes;
    h->x = hs_calloc(3 * n, sizeof(double));
    h->g = hs_calloc(3 * n, sizeof(double));
    h->v = hs_calloc(3 * n, sizeof(double));
    h->rot = hs_calloc(9 * n, sizeof(double));
    h->q = hs_calloc(3 * n, sizeof(double));
    h->dq = hs_calloc(3 * n, sizeof(double));
    h->pre = hs_calloc(3 * n, sizeof(double));
    h->pre_at = hs_calloc(n + 1, sizeof(int64_t));
    h->near_node = hs_calloc(n + 1, sizeof(int));
    h->smesh = mesh;
    h->tri_cap = mesh->n_tris;
    h->near_tri = hs_calloc((size_t)h->tri_cap + 1, sizeof *h->near_tri);
    h->tri_start = hs_calloc(n + 1, sizeof(int));
    h->tri_list = hs_alloc(3 * (size_t)h->tri_cap * sizeof(int) + sizeof(int));
    h->cand_of = hs_alloc((n + 1) * sizeof(int));
    if (!h->x || !h->g || !h->v || !h->rot || !h->q || !h->dq || !h->pre || !h->pre_at ||
        !h->near_node || !h->near_tri || !h->cand_of || !h->tri_start || !h->tri_list)
        return -1;
    for (size_t i = 0; i < n; ++i) h->cand_of[i] = -1;
    if (build_tri_adjacency(h) != HS_OK) return -1;
    memcpy(h->q, mesh->x0, 3 * n * sizeof(double));
    h->st.relax_w = def->probe.free_relax;
    h->relax_e = -1;
    h->probe_r = def->probe.radius_m;
    return 0;
}

// The buffers between the threads, the device, the haptic loops and the 1 kHz loop.
static hs_status create_loops(hs_haptic_sim* h, const hs_haptic_sim_def* def, hs_err* err) {
    const hs_probe_def* pd = &def->probe;
    const size_t n = (size_t)h->mesh->n_nodes;
    hs_status s;
    h->frame_size = sizeof(int64_t) + 3 * n * sizeof(double);
    s = hs_triple_buffer_create(sizeof(sim_snapshot), &h->snap, err);
    h->n_tools = def->tools;
    if (s == HS_OK)
        s = hs_triple_buffer_create((size_t)h->n_tools * sizeof(hs_contact), &h->contact, err);
    if (s == HS_OK) s = hs_triple_buffer_create(h->frame_size, &h->frame, err);
    if (s == HS_OK) s = hs_triple_buffer_create(sizeof(deform_status), &h->status, err);
    if (s == HS_OK) s = hs_memdev_create(&h->dev, err);
    if (s != HS_OK) return s;

    h->src.snap = h->snap;
    h->src.contact = h->contact;
    h->src.min_r = pd->min_radius_m;
    h->src.max_r = pd->max_radius_m;
    h->src.timeout_s = pd->model_timeout_s;
    hs_haptic_rt_def hd = hs_haptic_rt_default_def();
    hd.device = hs_memdev_device(h->dev);
    hd.source.eval = probe_eval;
    hd.source.ctx = &h->src;
    hd.safety = def->safety;
    // Every answer within the rate limit per period, however late its tick (the wire's bound).
    if (!(hd.safety.step_period_s > 0)) hd.safety.step_period_s = 1.0 / def->rate_hz;
    hd.blend_ticks = def->blend_ticks;
    s = hs_haptic_rt_create(&hd, &h->hrt, err);
    if (s == HS_OK) s = create_tools(h, &hd, err);
    if (s != HS_OK) return s;
    hs_rt_def rd = hs_rt_default_def();
    rd.rate_hz = def->rate_hz;
    rd.fifo_priority = def->fifo_priority;
    rd.lock_memory = def->lock_memory;
    h->inner = hs_haptic_rt_tick(h->hrt);
    rd.tick.fn = rt_tick;
    rd.tick.ctx = h;
    rd.tick.on_start = rt_start;
    rd.tick.on_stop = rt_stop;
    for (int t = 1; t < h->n_tools; ++t) h->xinner[t] = hs_haptic_rt_tick(h->xhrt[t]);
    return hs_rt_loop_create(&rd, &h->loop, err);
}

hs_status hs_haptic_sim_create(const hs_mesh* mesh, const hs_haptic_sim_def* def,
                               const unsigned char* fixed, hs_haptic_sim** out, hs_err* err) {
    if (out) *out = NULL;
    if (!mesh || !def || !out)
        return hs_err_set(err, HS_ERR_INVALID, "hs_haptic_sim_create: NULL argument");
    hs_status s = check_def(def, err);
    if (s != HS_OK) return s;

    hs_haptic_sim* h = hs_calloc(1, sizeof *h);
    if (!h) return hs_err_set(err, HS_ERR_NOMEM, "hs_haptic_sim_create: out of memory");
    h->def = *def;
    h->mesh = mesh;
    h->corotated = def->body.fem.model != HS_MODEL_LINEAR;
    atomic_init(&h->stop, 0);
    // The warped factor follows the co-rotated model's rotations: only there is there a choice
    // (the linear model's warped solver is the direct one).
    if (def->body.fem.model != HS_MODEL_COROTATED) h->def.auto_solver = 0;
    s = create_body(h, def, fixed, err);
    if (s != HS_OK) goto fail;
    h->period_ns = (int64_t)(def->body.dt * 1e9);
    h->st.sim_hz_target = 1.0 / def->body.dt;
    h->step_hist = hs_calloc(2 * (STEP_BINS + 1), sizeof *h->step_hist);
    if (!h->step_hist) goto nomem;
    h->fixed0 = hs_calloc((size_t)mesh->n_nodes + 1, 1);
    if (!h->fixed0) goto nomem;
    if (fixed) memcpy(h->fixed0, fixed, (size_t)mesh->n_nodes);
    if (def->background_setup) {
        atomic_store(&h->comp_state, 1);
        if (pthread_create(&h->su_thread, NULL, setup_worker, h) != 0) {
            s = hs_err_set(err, HS_ERR_NOMEM, "hs_haptic_sim_create: cannot start the set-up");
            goto fail;
        }
        h->su_running = 1;
    } else {
        s = hs_compliance_create(mesh, &def->body.fem, fixed, def->probe.cache_nodes, &h->comp,
                                 err);
        if (s != HS_OK) goto fail;
        h->setup_ms = hs_compliance_setup_ms(h->comp);
    }

    if (alloc_arrays(h, def)) goto nomem;

    s = create_loops(h, def, err);
    if (s != HS_OK) goto fail;
    hs_triple_buffer_write(h->status, &h->st); // the solver and rate, before the first pass
    *out = h;
    return HS_OK;
nomem:
    hs_haptic_sim_destroy(&h);
    return hs_err_set(err, HS_ERR_NOMEM, "hs_haptic_sim_create: out of memory");
fail:
    hs_haptic_sim_destroy(&h);
    return s;
}

hs_status hs_haptic_sim_set_safety(hs_haptic_sim* h, const hs_safety_def* safety) {
    if (!h || !safety) return HS_ERR_INVALID;
    hs_safety_def d = *safety;
    if (!(d.step_period_s > 0)) d.step_period_s = 1.0 / h->def.rate_hz;
    hs_status st = hs_haptic_rt_set_safety(h->hrt, &d);
    for (int t = 1; t < h->n_tools && st == HS_OK; ++t)
        st = hs_haptic_rt_set_safety(h->xhrt[t], &d);
    if (st == HS_OK) h->def.safety = *safety;
    return st;
}

hs_status hs_haptic_sim_start(hs_haptic_sim* h, hs_err* err) {
    if (h->thread_started)
        return hs_err_set(err, HS_ERR_INVALID, "hs_haptic_sim_start: already started");
    // No snapshot is built here: rt reads the empty initial one (no contact nodes) until the
    // thread publishes its first at the tool.
    memset(&h->st.contact, 0, sizeof h->st.contact);
    // After a stop, the blade starts again at the first pose fed from now on: no sweep spans
    // the gap, not even from the last pose fed before it; and with no resistance (it held the
    // last sweep's, felt at once on resume with the blade lifted out meanwhile).
    h->blade_have = 0;
    if (h->cpose) {
        cut_pose last;
        hs_triple_buffer_read_copy(h->cpose, &last);
        h->pose_floor = last.pose.seq;
    }
    if (h->started_once) {
        memset(h->cut_force, 0, sizeof h->cut_force);
        memset(h->st.cut_force_n, 0, sizeof h->st.cut_force_n);
        // rt reads an empty snapshot, as at the first start, until the thread publishes one at
        // the tool; it blends nothing from before the stop and ramps in from zero. Both
        // threads are stopped: this thread may write what they own.
        sim_snapshot* wrap = hs_triple_buffer_back(h->snap);
        memset(wrap, 0, sizeof *wrap);
        wrap->s.version = ++h->version;
        hs_triple_buffer_publish(h->snap);
        hs_haptic_rt_restart(h->hrt);
        for (int t = 1; t < h->n_tools; ++t) {
            hs_haptic_rt_restart(h->xhrt[t]);
            memset(&h->src.model[t], 0, sizeof h->src.model[t]);
            h->src.tool_seen[t] = 0;
        }
        memset(h->src.lastv, 0, sizeof h->src.lastv);
    }
    h->started_once = 1;
    // A still body under gravity or displaced (a state handed over) need not be in
    // equilibrium: it must step before the speed test may put it to sleep (it never sagged).
    const double* g = h->def.body.gravity;
    int off_rest = g[0] != 0 || g[1] != 0 || g[2] != 0;
    const double* u = hs_body_displacement(h->body);
    for (size_t i = 0; i < 3 * (size_t)h->mesh->n_nodes && !off_rest; ++i) off_rest = u[i] != 0;
    if (off_rest) h->wake_steps = 10;
    atomic_store(&h->stop, 0);
    if (pthread_create(&h->thread, NULL, deform_main, h) != 0)
        return hs_err_set(err, HS_ERR_UNSUPPORTED,
                          "hs_haptic_sim_start: cannot create the deformation thread");
    h->thread_started = 1;
    hs_status s = hs_rt_loop_start(h->loop, err);
    if (s != HS_OK) {
        hs_haptic_sim_stop(h);
        return s;
    }
    return HS_OK;
}

hs_status hs_haptic_sim_take_over(hs_haptic_sim* h, const hs_haptic_sim* from, hs_err* err) {
    if (!h || !from || h == from)
        return hs_err_set(err, HS_ERR_INVALID, "hs_haptic_sim_take_over: NULL or the same sim");
    if (h->started_once || from->thread_started || hs_rt_loop_running(from->loop))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_take_over: the new sim has run, or the old one runs");
    if (h->mesh->n_nodes != from->mesh->n_nodes)
        return hs_err_set(err, HS_ERR_INVALID, "hs_haptic_sim_take_over: meshes of %d and %d nodes",
                          h->mesh->n_nodes, from->mesh->n_nodes);
    hs_haptic_rt_take_over(h->hrt, from->hrt, &h->src.held);
    h->src.hold = 1;
    h->src.hold_version = h->version; // the empty snapshot published at create
    h->src.last = from->src.last;
    // The deformation thread's first pass applies the old contact and builds the first
    // snapshot where the tool is (not at the origin, where an empty contact would put it).
    hs_contact* c = hs_triple_buffer_back(h->contact);
    *c = from->src.last;
    // The other tools as well: each goes on from its last output, given until the first joint
    // solve (it runs once tool 0's hold ends), and its last contact is applied.
    const int n = h->n_tools < from->n_tools ? h->n_tools : from->n_tools;
    for (int t = 1; t < n; ++t) {
        hs_haptic_rt_take_over(h->xhrt[t], from->xhrt[t], &h->src.model[t]);
        memcpy(h->src.tool_p[t], from->src.tool_p[t], sizeof h->src.tool_p[t]);
        h->src.tool_seen[t] = from->src.tool_seen[t];
        h->src.lastv[t] = from->src.lastv[t];
        c[t] = from->src.lastv[t];
    }
    hs_triple_buffer_publish(h->contact);
    return HS_OK;
}

void hs_haptic_sim_stop(hs_haptic_sim* h) {
    if (!h) return;
    // The deformation thread first: its step (and a compliance rebuild finished below) can
    // take tens of ms, while rt goes on sending forces from the last snapshot.
    if (h->thread_started) {
        atomic_store_explicit(&h->stop, 1, memory_order_release);
        pthread_join(h->thread, NULL);
        h->thread_started = 0;
        setup_take(h, 0);    // a finished background set-up is the control thread's to take now
        if (h->cw_running) { // the thread is gone: finish its rebuild here (cannot be cut short)
            comp_poll(h, 1);
            hs_triple_buffer_write(h->status, &h->st);
        }
    }
    if (h->loop) hs_rt_loop_stop(h->loop);
}

// Feeder: the pose for the blade, with where its buttons last changed.
static void feed_cut_pose(hs_haptic_sim* h, const hs_haptic_pose* pose) {
    const unsigned eb = h->cdef.engage_buttons;
    const int engaged = !eb || (pose->buttons & eb);
    if (engaged != h->feed_engaged) memcpy(h->feed_flip, pose->pos_m, sizeof h->feed_flip);
    h->feed_engaged = engaged;
    cut_pose cp;
    cp.pose = *pose;
    memcpy(cp.flip_m, h->feed_flip, sizeof cp.flip_m);
    hs_triple_buffer_write(h->cpose, &cp);
}

void hs_haptic_sim_feed_pose(hs_haptic_sim* h, const hs_haptic_pose* pose) {
    if (h->cpose) feed_cut_pose(h, pose);
    hs_memdev_feed_pose(h->dev, pose);
}

hs_status hs_haptic_sim_enable_cutting(hs_haptic_sim* h, hs_mesh* mesh,
                                       const hs_haptic_cut_def* def, hs_err* err) {
    if (!h || !mesh || !def)
        return hs_err_set(err, HS_ERR_INVALID, "hs_haptic_sim_enable_cutting: NULL argument");
    if (def->cookie != CUT_COOKIE)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_enable_cutting: definition not initialised with "
                          "hs_haptic_cut_default_def()");
    if (mesh != h->mesh)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_enable_cutting: not the mesh the sim was created on");
    if (h->thread_started || h->cut)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_enable_cutting: sim already running or cutting");

    if (hs_haptic_sim_wait_setup(h) != HS_OK) // cuts move x0, which the set-up reads
        return hs_err_set(err, h->su_status, "hs_haptic_sim_enable_cutting: %s", h->su_err.msg);
    if (!(def->toughness_n_m >= 0) || !(def->max_force_n >= 0) || !(def->min_travel_m >= 0) ||
        !isfinite(def->toughness_n_m) || !isfinite(def->max_force_n) ||
        dist3(def->blade_a, def->blade_b) <= 0 || !isfinite(dist3(def->blade_a, def->blade_b)))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_enable_cutting: blade of zero length, or toughness, "
                          "force cap or travel negative");
    if (def->cut.fragment != HS_CUT_FRAGMENT_DROP && def->cut.fragment != HS_CUT_FRAGMENT_FIX)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_haptic_sim_enable_cutting: cut.fragment %d is neither DROP nor FIX",
                          (int)def->cut.fragment);
    h->cdef = *def;
    // Every cut tet goes and a node left without one is held where it is (the body keeps its
    // mass on the diagonal: hs_fem_held_nodes). The paper's keep-tet rule left fine cuts
    // joined through kept tets, where the body and the haptic compliance then disagreed
    // (docs/haptics.md). A piece no fixed node holds goes (DROP) or stays in the body (FIX).
    h->cdef.cut.orphan = HS_CUT_ORPHAN_PIN;
    h->cdef.cut.pins_hold = 0; // the body has no pin springs
    const size_t n = (size_t)mesh->n_nodes, nt = (size_t)mesh->n_tets;
    // A retry after a failed call starts clean.
    free_cut_scratch(h);
    hs_triple_buffer_destroy(&h->cpose);
    h->cw_x0 = hs_calloc(3 * n, sizeof(double));
    h->cw_tets = hs_calloc(4 * nt + 1, sizeof(int));
    h->cw_fix = hs_calloc(n + 1, 1);
    h->cw_u = hs_calloc(3 * n, sizeof(double));
    h->cw_xw = hs_calloc(3 * n, sizeof(double));
    h->cw_near = hs_calloc(4 * nt + 1, sizeof *h->cw_near);
    h->cw_cand = hs_alloc((n + 1) * sizeof(int));
    h->cu = hs_calloc(3 * n, sizeof(double));
    h->cv = hs_calloc(3 * n, sizeof(double));
    h->t_x0 = hs_calloc(3 * n, sizeof(double));
    h->t_cap = 4 * (int)nt;
    h->t_tris = hs_calloc(3 * nt * 4 + 1, sizeof(int));
    h->t_removed = hs_calloc(nt + 1, sizeof(int));
    h->t_moved = hs_calloc(n + 1, sizeof(int));
    h->t_mflag = hs_calloc(n + 1, 1);
    h->r_gone = hs_calloc(nt + 1, 1);
    h->r_keys = hs_alloc((4 * nt + 1) * sizeof(face_key));
    h->r_sorted = hs_alloc((4 * nt + 1) * sizeof(face_key));
    h->r_start = hs_alloc((n + 2) * sizeof(int));
    h->r_cur = hs_alloc((n + 2) * sizeof(int));
    if (!h->r_gone || !h->r_keys || !h->r_sorted || !h->r_start || !h->r_cur)
        return hs_err_set(err, HS_ERR_NOMEM, "hs_haptic_sim_enable_cutting: out of memory");
    if (!h->cw_x0 || !h->cw_tets || !h->cw_fix || !h->cw_u || !h->cw_xw || !h->cw_near ||
        !h->cw_cand || !h->cu || !h->cv || !h->t_x0 || !h->t_tris || !h->t_removed || !h->t_moved ||
        !h->t_mflag)
        return hs_err_set(err, HS_ERR_NOMEM, "hs_haptic_sim_enable_cutting: out of memory");
    for (size_t i = 0; i <= n; ++i) h->cw_cand[i] = -1;
    if (!h->tmx_init) {
        if (pthread_mutex_init(&h->tmx, NULL) != 0)
            return hs_err_set(err, HS_ERR_NOMEM, "hs_haptic_sim_enable_cutting: mutex");
        if (pthread_mutex_init(&h->cw_mx, NULL) != 0) {
            pthread_mutex_destroy(&h->tmx);
            return hs_err_set(err, HS_ERR_NOMEM, "hs_haptic_sim_enable_cutting: mutex");
        }
        h->tmx_init = 1;
    }
    // Room for the boundary of any live mesh (at most 4 faces per tet), for the probe.
    if (h->tri_cap < 4 * (int)nt) {
        int* tl = hs_alloc(3 * 4 * nt * sizeof(int) + sizeof(int));
        near_tri* nr = hs_calloc(4 * nt + 1, sizeof *nr);
        if (!tl || !nr) {
            hs_free(tl);
            hs_free(nr);
            return hs_err_set(err, HS_ERR_NOMEM, "hs_haptic_sim_enable_cutting: out of memory");
        }
        memcpy(tl, h->tri_list, 3 * (size_t)h->tri_cap * sizeof(int));
        hs_free(h->tri_list);
        hs_free(h->near_tri);
        h->tri_list = tl;
        h->near_tri = nr;
        h->tri_cap = 4 * (int)nt;
    }
    hs_status s = hs_triple_buffer_create(sizeof(cut_pose), &h->cpose, err);
    if (s != HS_OK) return s;
    s = hs_cut_create(mesh, h->fixed0, &h->cdef.cut, &h->cut, err);
    if (s != HS_OK) return s;
    // The compliance follows each cut step (comp_follow): its one full pass now, not in a step.
    // Should this fail, the first cut step tries again, or the rebuild takes over.
    (void)hs_compliance_prepare_changes(h->comp);
    s = hs_cut_surface_create(mesh, &h->fsurf);
    if (s != HS_OK)
        return hs_err_set(err, s, "hs_haptic_sim_enable_cutting: live surface: %s",
                          hs_status_str(s));
    memcpy(h->t_x0, mesh->x0, 3 * n * sizeof(double));
    h->t_ntris = mesh->n_tris <= h->t_cap ? mesh->n_tris : 0;
    memcpy(h->t_tris, mesh->tris, 3 * (size_t)h->t_ntris * sizeof(int));
    atomic_store(&h->topo_version, 0);
    return HS_OK;
}

int64_t hs_haptic_sim_topology_version(hs_haptic_sim* h) {
    return atomic_load(&h->topo_version);
}

static void sort3(int k[3]) {
    if (k[0] > k[1]) {
        int t = k[0];
        k[0] = k[1];
        k[1] = t;
    }
    if (k[1] > k[2]) {
        int t = k[1];
        k[1] = k[2];
        k[2] = t;
    }
    if (k[0] > k[1]) {
        int t = k[0];
        k[0] = k[1];
        k[1] = t;
    }
}

static int key_less(const face_key* a, const face_key* b) {
    return a->k[1] < b->k[1] || (a->k[1] == b->k[1] && a->k[2] < b->k[2]);
}

// Reader side: the boundary of the tets not removed (the faces used once), outward, into
// t_tris. Tets stay positively oriented at rest through cuts (the cut's quality guard), so a
// tet's faces in this order point out of it.
static void build_boundary(hs_haptic_sim* h) {
    static const int fv[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
    const hs_mesh* m = h->mesh;
    const int nn = m->n_nodes;
    face_key* key = h->r_keys;
    int nk = 0;
    memset(h->r_start, 0, ((size_t)nn + 1) * sizeof(int));
    for (int t = 0; t < m->n_tets; ++t) {
        if (h->r_gone[t]) continue;
        const int* tv = m->tets + 4 * t;
        for (int f = 0; f < 4; ++f) {
            face_key* q = key + nk++;
            for (int j = 0; j < 3; ++j) q->o[j] = q->k[j] = tv[fv[f][j]];
            sort3(q->k);
            h->r_start[q->k[0] + 1]++;
        }
    }
    for (int v = 0; v < nn; ++v) h->r_start[v + 1] += h->r_start[v];
    memcpy(h->r_cur, h->r_start, ((size_t)nn + 1) * sizeof(int));
    for (int i = 0; i < nk; ++i) h->r_sorted[h->r_cur[key[i].k[0]]++] = key[i];
    h->t_ntris = 0;
    for (int v = 0; v < nn; ++v) {
        face_key* b = h->r_sorted + h->r_start[v];
        int nb = h->r_start[v + 1] - h->r_start[v];
        for (int i = 1; i < nb; ++i) { // buckets hold the few faces around one node
            face_key x = b[i];
            int j = i;
            for (; j > 0 && key_less(&x, &b[j - 1]); --j) b[j] = b[j - 1];
            b[j] = x;
        }
        for (int i = 0; i < nb;) {
            int j = i + 1;
            while (j < nb && b[j].k[1] == b[i].k[1] && b[j].k[2] == b[i].k[2]) ++j;
            if (j - i == 1 && h->t_ntris < h->t_cap)
                memcpy(h->t_tris + 3 * h->t_ntris++, b[i].o, 3 * sizeof(int));
            i = j;
        }
    }
}

int64_t hs_haptic_sim_take_topology(hs_haptic_sim* h, double* x0, int* tris, int tri_cap,
                                    int* n_tris, hs_haptic_cut_event* ev) {
    if (!h->tmx_init) return 0;
    pthread_mutex_lock(&h->tmx);
    int64_t v = atomic_load(&h->topo_version);
    if (x0) memcpy(x0, h->t_x0, 3 * (size_t)h->mesh->n_nodes * sizeof(double));
    int grew = h->t_nremoved > 0;
    for (int k = 0; k < h->t_nremoved; ++k) h->r_gone[h->t_removed[k]] = 1;
    if (ev) {
        ev->old_version = h->t_taken;
        ev->new_version = v;
        ev->n_removed = h->t_nremoved;
        if (ev->removed_tets)
            memcpy(ev->removed_tets, h->t_removed, (size_t)h->t_nremoved * sizeof(int));
        ev->n_moved = h->t_nmoved;
        if (ev->moved_nodes) memcpy(ev->moved_nodes, h->t_moved, (size_t)h->t_nmoved * sizeof(int));
        memcpy(ev->swept_quad, h->t_quad, sizeof ev->swept_quad);
    }
    for (int k = 0; k < h->t_nmoved; ++k) h->t_mflag[h->t_moved[k]] = 0;
    h->t_nremoved = h->t_nmoved = 0;
    h->t_taken = v;
    pthread_mutex_unlock(&h->tmx);
    if (grew) build_boundary(h);
    int nt = h->t_ntris <= tri_cap ? h->t_ntris : 0;
    if (tris) memcpy(tris, h->t_tris, 3 * (size_t)nt * sizeof(int));
    if (n_tris) *n_tris = nt;
    return v;
}

int hs_haptic_sim_take_output(hs_haptic_sim* h, hs_haptic_output* out) {
    return hs_memdev_take_output(h->dev, out);
}

int hs_haptic_sim_tools(const hs_haptic_sim* h) {
    return h ? h->n_tools : 0;
}

void hs_haptic_sim_feed_tool_pose(hs_haptic_sim* h, int tool, const hs_haptic_pose* pose) {
    HS_ASSERT(tool >= 0 && tool < h->n_tools);
    if (tool == 0)
        hs_haptic_sim_feed_pose(h, pose);
    else
        hs_memdev_feed_pose(h->xdev[tool], pose);
}

int hs_haptic_sim_take_tool_output(hs_haptic_sim* h, int tool, hs_haptic_output* out) {
    HS_ASSERT(tool >= 0 && tool < h->n_tools);
    return hs_memdev_take_output(tool == 0 ? h->dev : h->xdev[tool], out);
}

void hs_haptic_sim_tool_counters(hs_haptic_sim* h, int tool, hs_haptic_rt_counters* out) {
    HS_ASSERT(tool >= 0 && tool < h->n_tools);
    hs_haptic_rt_get_counters(tool == 0 ? h->hrt : h->xhrt[tool], out);
}

int hs_haptic_sim_read_frame(hs_haptic_sim* h, double* u, int64_t* step) {
    int fresh = 0;
    const unsigned char* f = hs_triple_buffer_read(h->frame, &fresh);
    if (step) memcpy(step, f, sizeof *step);
    if (u) memcpy(u, f + sizeof(int64_t), 3 * (size_t)h->mesh->n_nodes * sizeof(double));
    return fresh;
}

void hs_haptic_sim_stats_get(hs_haptic_sim* h, hs_haptic_sim_stats* out) {
    deform_status ds;
    hs_triple_buffer_read_copy(h->status, &ds);
    memset(out, 0, sizeof *out);
    out->steps = ds.steps;
    out->snapshots = ds.snapshots;
    out->column_solves = ds.column_solves;
    out->step_failures = ds.step_failures;
    out->step_ms_last = ds.step_ms_last;
    out->step_ms_max = ds.step_ms_max;
    out->snapshot_ms_last = ds.snapshot_ms_last;
    out->snapshot_ms_max = ds.snapshot_ms_max;
    out->sleeping = ds.sleeping;
    out->candidates = ds.candidates;
    out->coupled = ds.coupled;
    out->contact = ds.contact;
    out->cut_sweeps = ds.cut_sweeps;
    out->cut_steps = ds.cut_steps;
    out->cut_removed = ds.cut_removed;
    out->cut_failures = ds.cut_failures;
    out->cut_ms_last = ds.cut_ms_last;
    out->cut_ms_max = ds.cut_ms_max;
    out->sweep_ms_last = ds.sweep_ms_last;
    out->comp_ms_last = ds.comp_ms_last;
    out->loops = ds.loops;
    out->comp_version = ds.comp_version;
    out->comp_rebuilds = ds.comp_rebuilds;
    out->comp_discarded = ds.comp_discarded;
    out->comp_updates = ds.comp_updates;
    out->comp_building = ds.comp_building;
    out->cut_done_ns = ds.cut_done_ns;
    out->comp_swap_ns = ds.comp_swap_ns;
    out->free_relax_w = ds.relax_w;
    out->free_relax_cuts = ds.relax_cuts;
    out->depth_max_m = ds.depth_max;
    out->deep_loops = ds.deep_loops;
    out->step_ms_p50 = ds.step_p50;
    out->step_ms_p99 = ds.step_p99;
    out->step_ms_p50_all = ds.step_p50_all;
    out->step_ms_p99_all = ds.step_p99_all;
    out->step_cpu_ms_p50_all = ds.step_cpu_p50_all;
    out->step_cpu_ms_p99_all = ds.step_cpu_p99_all;
    out->step_overruns = ds.step_overruns;
    out->sim_hz_target = ds.sim_hz_target;
    out->rate_changes = ds.rate_changes;
    out->solver = ds.solver;
    out->solver_switches = ds.solver_switches;
    memcpy(out->solver_cost_ms, ds.solver_ms, sizeof out->solver_cost_ms);
    out->factor_ms = ds.factor_ms;
    memcpy(out->cut_force_n, ds.cut_force_n, sizeof out->cut_force_n);
    out->cutting = ds.cutting;
    out->topology_version = atomic_load(&h->topo_version);
    out->setup_ms = h->setup_ms; // h->comp is replaced by cuts on the deformation thread
    out->comp_state = atomic_load_explicit(&h->comp_state, memory_order_acquire);
    if (h->def.background_setup && atomic_load_explicit(&h->su_done, memory_order_acquire)) {
        out->setup_ms = h->su_ms;
        if (out->comp_state == 1) out->comp_state = h->su_status == HS_OK ? 2 : -1;
    }
    hs_rt_loop_stats(h->loop, &out->rt);
    hs_haptic_rt_counters rc;
    hs_haptic_rt_get_counters(h->hrt, &rc);
    out->rt_ticks = rc.ticks;
    out->poses = rc.poses;
    out->blends = rc.blends;
    out->safety = rc.safety;
}

struct hs_spsc_ring* hs_haptic_sim_telemetry(hs_haptic_sim* h) {
    return hs_haptic_rt_telemetry(h->hrt);
}

int hs_haptic_sim_cut_pinned(hs_haptic_sim* h, unsigned char* pinned) {
    int k = 0;
    for (int i = 0; i < h->mesh->n_nodes; ++i) {
        pinned[i] = (unsigned char)(h->cut && hs_cut_node_pinned(h->cut, i));
        k += pinned[i];
    }
    return k;
}

const char* hs_haptic_sim_setup_error(hs_haptic_sim* h) {
    return atomic_load_explicit(&h->su_done, memory_order_acquire) && h->su_status != HS_OK
               ? h->su_err.msg
               : NULL;
}

hs_status hs_haptic_sim_wait_setup(hs_haptic_sim* h) {
    if (h->thread_started) return HS_ERR_INVALID;
    setup_take(h, 1);
    return h->comp ? HS_OK : h->su_status != HS_OK ? h->su_status : HS_ERR_INVALID;
}

hs_compliance* hs_haptic_sim_compliance(hs_haptic_sim* h) {
    return h->comp;
}
hs_body* hs_haptic_sim_body(hs_haptic_sim* h) {
    return h->body;
}
