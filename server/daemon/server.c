// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-server: scene -> world (mesh, visual set, sim), the net loop, publishing, commands.
// See server.h for the design. Everything here runs on the net thread except what
// hs_haptic_sim runs on its own two threads.
#define _GNU_SOURCE
#include "server.h"
#include "scene_sim.h"

#include <errno.h>
#include <math.h>
#include <poll.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "fem.h"
#include "haptic.h"
#include "haptic_sim.h"
#include "mesh.h"
#include "scene.h"
#include "hapsim_channels.h"
#include "hapsim_command_ack_t.h"
#include "hapsim_command_t.h"
#include "hapsim_mesh_delta_t.h"
#include "hapsim_mesh_state_t.h"
#include "hapsim_mesh_topology_t.h"
#include "hapsim_server_status_t.h"
#include "hapsim_tool_force_t.h"
#include "hapsim_tool_pose_t.h"
#include "hapsim_tool_state_t.h"
#include "hapsim_topology_event_t.h"
#include "bus.h"
#include "mesh_frames.h"
#include "validate.h"
#include "spsc_ring.h"
#include "haptic_rt.h"

#define MAX_DEV             HS_SCENE_MAX_DEVICES
#define POSE_RING           64           // fed poses remembered for echoing in rt-output forces
#define KEYFRAME_NS         1000000000LL // keyframe and topology period
#define LOADER_STOP_WAIT_MS 3000         // at a stop, how long a scene build may take to return
#define DELTA_EPS_M         1e-5f        // m: a visual node is listed in a delta when it moved more
#define LIVE_NS             500000000LL  // live status line period
#define PAUSE_RAMP_S        0.02         // forces ramp to zero over this after PAUSE, s
#define SIM_HIST_SCALE      16           // the deformation loop's histograms: 16 us bins
#define RT_GAP_NS           1500000LL    // publish rt outputs when no force went out for this long
#define HANDLE_BATCH        256          // messages handled per bus per loop iteration
#define POSE_QUEUE          8192         // LCM subscription queue (default 30 drops bursts)
#define HAPTIC_RCVBUF       4194304      // haptic bus receive buffer asked for, bytes
#define COMMAND_QUEUE       1024
#define CUT_SAMPLES         1024 // cut step times kept for the quantiles (cut steps take ms, not us)
#define LOAD_QUEUE          32   // commands kept while a scene loads; more are refused (busy)

// Everything that depends on the scene: rebuilt by load_scene, swapped only when complete.
typedef struct world {
    hs_scene scene;
    hs_mesh* mesh;
    unsigned char* fixed; // [n_nodes]
    int n_fixed;
    int haptics; // sim allocated
    int visual;  // mesh publishing on
    hs_haptic_sim_def def;
    hs_haptic_sim* sim;  // NULL: haptics off, or paused
    hs_haptic_sim* held; // a cut world's sim while paused: stopped and kept (a cut mesh cannot
                         // be rebuilt on), for RESUME to start again
    double* u;           // [3n] newest displacement frame, m
    double* v;           // [3n] velocity saved across a rebuild, m/s
    int n_vis;
    int32_t* vis_nodes; // [n_vis]
    float* rest;        // [3 n_vis]
    int n_tri_idx;
    int32_t* tri;           // [n_tri_idx] visual indices
    float* cur;             // [3 n_vis] current positions
    float* key;             // [3 n_vis] keyframe positions
    int32_t* d_index;       // [n_vis]
    float* d_delta;         // [3 n_vis]
    const char* probe_note; // why haptics is off, or NULL
    double surf_edge_m;     // median boundary edge of the mesh, m
    // cutting (scene features.cutting with a scalpel): visual arrays then have room for every
    // node and every live boundary triangle, and the rest positions come from the sim
    int cutting;
    int scalpel;    // scene tool index of the blade
    int probe_tool; // first probe tool, or -1
    // devices -> the sim's tools (hs_scene_device_tools): dev_sim[d] (-1: zero force), and
    // the scene tool of each sim tool (-1: the probe or the scalpel by the button)
    int dev_sim[MAX_DEV];
    int sim_scene_tool[HS_SCENE_MAX_TOOLS];
    hs_haptic_cut_def cdef;
    double* x0r;         // [3n] rest positions after the newest cut taken, m
    int tri_cap;         // boundary triangles the buffers hold
    int* ctris;          // [3 tri_cap] node indices
    int32_t* vis_of;     // [n] visual index of a node, -1 when not drawn
    int32_t* ev_removed; // [n_tets]
    int32_t* ev_moved;   // [n]
    float* ev_rest;      // [3n]
    int64_t cut_seen;    // sim topology version taken
    int cut_made;        // 1 once the mesh was cut (the sim cannot be rebuilt on it)
} world;

#define LOAD_STARTED (-100) // not an ack status: the final ack follows from finish_load

// A LOAD_SCENE builds its world on this thread while the running one goes on answering (the net
// loop would otherwise stand still for the whole build: no forces, no status, no e-stop).
typedef struct loader {
    pthread_t th;
    int active;      // started and not yet joined
    atomic_int done; // the thread has finished: st, err and nw are its results
    int abandoned;   // at the stop it had not returned (a file that blocks): never joined
    int realtime;
    char path[HS_SCENE_PATH_MAX]; // a LOAD_SCENE's argument or, for RESET, the running scene's
    int have_sc;                  // RESET, SET_PARAM: sc is the running scene as set
    int keep;                     // SET_PARAM: the running body's state goes on in the new one
    char ok_msg[128];             // SET_PARAM: the final ack's message when swapped in
    int64_t request_id;           // its final ack goes out at the swap
    int32_t kind;
    hs_scene sc;
    world nw; // built, not started; the net thread swaps it in
    hs_status st;
    hs_err err;
    // Commands that came during the build (all but the e-stop's two), run in order at the swap
    // so that they act on the new scene while the loop goes on answering meanwhile.
    int q_head, q_len;
    hs_net_command queued[LOAD_QUEUE];
} loader;

typedef struct dev_state {
    int64_t force_seq;
    int64_t last_rx_ns;  // newest accepted pose, CLOCK_MONOTONIC
    int64_t last_pub_ns; // newest tool_force published
    int seen;
    double pos[3], quat[4]; // the tool's pose (pos: the hand's + the clutch offset)
    double hand[3];         // the newest pose's position
    uint32_t buttons;
    double force[3]; // newest published force, N
    int contact;
    // Clutch (BUTTON_CLUTCH): tool position = hand position + offset (scene frame, m).
    int64_t session;    // the newest accepted pose's session: the offset's, echoed in forces
    double offset[3];   // grows by the hand's motion while the clutch was held
    int clutched;       // the clutch is held
    double hold[3];     // tool position while clutched
    double clutch_f[3]; // force published last before the clutch went down, N
    int64_t clutch_ns;  // clutch down
    int64_t engage_ns;  // clutch released (0: engaged since the session began)
    double engage_g0;   // the clutch gain at release: the ramp back in starts there
    int64_t pubs;       // forces published
    hs_rt_hist* lat;    // window: pose received -> force published, us
    // a device driving sim tool t > 0 (devices listed): its own feed and outputs
    int64_t feed_seq;            // poses fed to its tool
    hs_haptic_output out;        // newest rt output of its tool
    int have_out;                // out is from the running sim
    hs_haptic_model pause_model; // its output model at a pause, ramped to zero
} dev_state;

// The server's run state. Two latches lie over it, set and cleared in any state without
// changing it: the e-stop (every force zero) and a load in progress (commands but the e-stop's
// wait for it). srv_transition is the only code that changes the three.
typedef enum srv_state {
    SRV_RUNNING,    // the scene's simulation runs (haptics off: mesh and status only)
    SRV_PAUSED,     // no simulation; its body state is kept and RESUME builds it again
    SRV_PAUSED_CUT, // a cut world's simulation stopped and kept (world.held): RESUME starts it
} srv_state;

typedef enum srv_event {
    EV_PAUSE,         // PAUSE stopped the sim (a cut world's is held): forces ramp down
    EV_RESUME,        // RESUME started the sim again
    EV_SIM_STOPPED,   // a sim that did not start, or a reset kept at rest: zero force, no sim
    EV_SIM_HELD,      // a cut world's sim that did not start again: zero force, kept
    EV_SWAPPED,       // a built world took the running one's place (its sim not started yet)
    EV_ESTOP,         // ESTOP latched
    EV_ESTOP_RELEASE, // ESTOP_RELEASE: forces ramp back in (a repeated release does not re-ramp)
    EV_LOAD_BEGIN,    // a scene is being built (path: the status names it)
    EV_LOAD_END,      // the build is over (swapped in, failed or left behind)
} srv_event;

struct hs_server {
    hs_server_opts opt;
    world w;
    char haptic_url[HS_SCENE_URL_MAX], mesh_url[HS_SCENE_URL_MAX], prefix[HS_SCENE_PREFIX_MAX];
    hs_net_bus* hbus;
    hs_net_bus* mbus;
    char ch_pose[HAPSIM_CHANNEL_MAX], ch_force[HAPSIM_CHANNEL_MAX], ch_topo[HAPSIM_CHANNEL_MAX],
        ch_state[HAPSIM_CHANNEL_MAX], ch_delta[HAPSIM_CHANNEL_MAX], ch_tool[HAPSIM_CHANNEL_MAX],
        ch_cmd[HAPSIM_CHANNEL_MAX], ch_ack[HAPSIM_CHANNEL_MAX], ch_status[HAPSIM_CHANNEL_MAX],
        ch_tevent[HAPSIM_CHANNEL_MAX];

    hs_net_limits lim;
    hs_net_pose_state pst;
    hs_net_command_state cst;
    int64_t params_refused; // SET_PARAM acked INVALID: an unknown name or a value out of range
    int64_t kdrop0[2];      // the kernel's drops on the haptic / mesh bus sockets at start
    int listening;          // listening for another server before serving: poses go unanswered

    dev_state dev[MAX_DEV];
    int64_t feed_seq; // poses fed to rt (rt's pose seq)
    int64_t ring_feed[POSE_RING], ring_seq[POSE_RING], ring_utime[POSE_RING], ring_rx[POSE_RING],
        ring_session[POSE_RING];
    hs_haptic_output out; // newest rt output
    int have_out;

    // Changed only by srv_transition (docs/server.md, "States").
    srv_state state;     // RUNNING, PAUSED or PAUSED_CUT
    int estop;           // latch over every state: every force zero until released
    const char* loading; // latch: path of the scene being built (status says STATE_LOADING)
    loader load;         // a LOAD_SCENE being built on its own thread
    int64_t pause_ns;
    int64_t estop_release_ns;    // forces ramp back in from here (the rt chain never saw the stop)
    hs_haptic_model pause_model; // output model at the pause, ramped to zero

    int64_t topo_version, keyframe_id, frame_step, key_ns, sim_step_base;
    int have_key;
    int64_t seq_topo, seq_state, seq_delta, seq_tool, seq_ack, seq_status, seq_tevent;
    double cut_ms[CUT_SAMPLES];   // newest cut step times (deformation thread), ms, ring
    double cut_sort[CUT_SAMPLES]; // scratch for the quantiles
    int64_t n_cut_ms;
    int64_t last_cut_steps;
    int64_t cut_events; // topology events published
    int cutting_now;    // the newest sweep cut tissue

    // statistics
    int64_t start_ns, stat_ns;
    hs_haptic_sim_stats* st_prev; // at the previous status (window start)
    hs_haptic_sim_stats* st_now;
    hs_rt_hist* h_net;    // net loop period, window
    hs_rt_hist* h_step;   // deformation step + snapshot, sampled, window
    hs_rt_hist* h_handle; // pose handling (validate, feed, reply), window
    hs_rt_hist* h_diff;   // scratch for windowed rt histograms
    hs_rt_hist* h_simper; // deformation step period as seen by the net thread, window
    // h_step and h_simper hold ns / SIM_HIST_SCALE: 16 us bins over 0-64 ms (1 us bins end at
    // 4 ms, below a 60 Hz period, so every sample fell in the overflow and read as the max)
    int64_t last_step_ns;
    int64_t live_prev_ticks, live_prev_t, live_prev_deep;
    int64_t solver_switches_seen; // auto solver: switches already printed
    int comp_state_seen;          // compliance state last reported (hs_haptic_sim_stats)
    int64_t net_iters, last_iter_ns, last_steps;
    int64_t poses_total, forces_total;
    int64_t rmem_default, rmem_max; // the kernel's, at start, bytes (-1: unknown)
    int mesh_size_noted;            // the level of the last size note printed (hs_net_size_note)
    double live_force;
    uint32_t rt_obtained;
    int rt_prio;
    int stop;
};

static int srv_paused(const hs_server* s) {
    return s->state != SRV_RUNNING;
}

// ---------------------------------------------------------------------------------------------
// Helpers

static int64_t now_us(void) {
    return hs_now_ns() / 1000;
}

static double norm3(const double v[3]) {
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

static void hist_add(hs_rt_hist* h, int64_t ns) {
    if (ns < 0) ns = 0;
    int64_t us = ns / 1000;
    h->count[us < HS_RT_HIST_BINS ? us : HS_RT_HIST_BINS]++;
    if (ns > h->max_ns) h->max_ns = ns;
}

// d = a - b (a newer cumulative histogram, b an older one), with the window's own maximum.
static void hist_diff(const hs_rt_hist* a, const hs_rt_hist* b, hs_rt_hist* d) {
    for (int i = 0; i <= HS_RT_HIST_BINS; ++i) d->count[i] = a->count[i] - b->count[i];
    d->max_ns = hs_rt_hist_window_max_ns(a, b);
}

// Largest sample of a window histogram, us (the top non-empty bin's upper edge).
static double hist_max_us(const hs_rt_hist* h) {
    if (h->count[HS_RT_HIST_BINS]) return (double)h->max_ns * 1e-3;
    for (int i = HS_RT_HIST_BINS - 1; i >= 0; --i)
        if (h->count[i]) return (double)(i + 1);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// World: mesh, fixed nodes, visual set, sim

// The union of the scene's fixed regions over the used nodes; how many, or -1 (out of memory),
// or -2 (a region cannot select: err says why, *empty names it).
// *empty: the first region that selects no used node (or failed), or -1.
static int fixed_mask(const hs_scene* sc, const hs_mesh* m, unsigned char* fixed, int* empty,
                      hs_err* err) {
    *empty = -1;
    unsigned char* sel = hs_calloc((size_t)m->n_nodes, 1);
    if (!sel) return -1;
    memset(fixed, 0, (size_t)m->n_nodes);
    for (int r = 0; r < sc->n_fixed; ++r) {
        hs_status st = hs_scene_fixed_select(&sc->fixed[r], m, sel, err);
        if (st < 0) {
            hs_free(sel);
            *empty = r;
            return st == HS_ERR_NOMEM ? -1 : -2;
        }
        int any = 0;
        for (int i = 0; i < m->n_nodes; ++i) {
            fixed[i] |= sel[i] && m->node_used[i];
            any |= sel[i] && m->node_used[i];
        }
        if (!any && *empty < 0) *empty = r;
    }
    hs_free(sel);
    int n = 0;
    for (int i = 0; i < m->n_nodes; ++i) n += fixed[i] != 0;
    return n;
}

static void world_destroy(world* w) {
    hs_haptic_sim_destroy(&w->sim);
    hs_haptic_sim_destroy(&w->held);
    hs_mesh_destroy(&w->mesh);
    hs_free(w->fixed);
    hs_free(w->u);
    hs_free(w->v);
    hs_free(w->vis_nodes);
    hs_free(w->rest);
    hs_free(w->tri);
    hs_free(w->cur);
    hs_free(w->key);
    hs_free(w->d_index);
    hs_free(w->d_delta);
    hs_free(w->x0r);
    hs_free(w->ctris);
    hs_free(w->vis_of);
    hs_free(w->ev_removed);
    hs_free(w->ev_moved);
    hs_free(w->ev_rest);
    memset(w, 0, sizeof *w);
}

static int cmp_dbl(const void* pa, const void* pb) {
    double a = *(const double*)pa, b = *(const double*)pb;
    return (a > b) - (a < b);
}

// Median length of the boundary triangles' edges (each triangle's three), m; 0 without any.
static double median_surface_edge(const hs_mesh* m) {
    size_t n = 3 * (size_t)m->n_tris;
    double* l = n ? hs_alloc(n * sizeof(double)) : NULL;
    if (!l) return 0;
    for (int t = 0; t < m->n_tris; ++t)
        for (int k = 0; k < 3; ++k) {
            const double* a = m->x0 + 3 * m->tris[3 * t + k];
            const double* b = m->x0 + 3 * m->tris[3 * t + (k + 1) % 3];
            double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
            l[3 * t + k] = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        }
    qsort(l, n, sizeof *l, cmp_dbl);
    double med = l[n / 2];
    hs_free(l);
    return med;
}

// The contact resolves the surface at its nodes: a probe much smaller than the surface edges
// falls between them (forces snag and pop from node to node). Returns 1 with text in note.
static int edge_note(const world* w, char* note, size_t cap) {
    const double r = w->def.probe.radius_m;
    if (!w->haptics || !(r > 0) || w->surf_edge_m <= 2 * r) return 0;
    snprintf(note, cap,
             "mesh surface edges (median %.1f mm) are larger than 2 x the probe radius (%.1f mm): "
             "the contact resolves the surface at its nodes, so the force is coarse; refine the "
             "mesh or use a larger probe",
             w->surf_edge_m * 1e3, r * 1e3);
    return 1;
}

static const char* solver_name(int k) {
    return k == HS_SOLVER_DIRECT ? "direct" : k == HS_SOLVER_PCG ? "pcg" : "warped";
}

static hs_status refuse_cut(hs_err* err) {
    return hs_err_set(err, HS_ERR_INVALID,
                      "the mesh was cut: the simulation cannot be rebuilt on it (RESET reloads "
                      "the uncut scene)");
}

// (Re)create the sim of w from w->def, with the body state u/v when keep. Not started. A cut
// world is refused with its sim left as it is.
static hs_status world_sim_create(world* w, int keep, hs_err* err) {
    if (w->cut_made) return refuse_cut(err);
    hs_haptic_sim_destroy(&w->sim);
    hs_status s = hs_haptic_sim_create(w->mesh, &w->def, w->fixed, &w->sim, err);
    if (s != HS_OK) return s;
    if (w->cutting) {
        s = hs_haptic_sim_enable_cutting(w->sim, w->mesh, &w->cdef, err);
        if (s != HS_OK) {
            hs_haptic_sim_destroy(&w->sim);
            return s;
        }
    }
    if (keep) hs_body_set_state(hs_haptic_sim_body(w->sim), w->u, w->v);
    return HS_OK;
}

// Copy a stopped sim's body state to w->u / w->v.
static void world_save_state(world* w) {
    hs_body* b = hs_haptic_sim_body(w->sim);
    size_t n3 = 3 * (size_t)w->mesh->n_nodes;
    memcpy(w->u, hs_body_displacement(b), n3 * sizeof(double));
    memcpy(w->v, hs_body_velocity(b), n3 * sizeof(double));
}

// Stop the sim and keep its body state in w->u / w->v.
static void world_sim_stop(world* w) {
    if (!w->sim) return;
    hs_haptic_sim_stop(w->sim);
    world_save_state(w);
    hs_haptic_sim_destroy(&w->sim);
}

static void apply_cut(hs_server* s);

// PAUSE: stop the sim keeping its body state, first passing on a cut its threads finished
// after the net loop last looked (else it would be lost, and the sim could be rebuilt on a cut
// mesh). A cut world keeps the stopped sim itself for RESUME to start again; any other is
// rebuilt from the kept state then.
static void server_sim_pause(hs_server* s) {
    world* w = &s->w;
    if (!w->sim) return;
    hs_haptic_sim_stop(w->sim);
    if (w->cutting && hs_haptic_sim_topology_version(w->sim) != w->cut_seen) apply_cut(s);
    if (!w->cut_made) {
        world_sim_stop(w);
        return;
    }
    world_save_state(w);
    w->held = w->sim;
    w->sim = NULL;
}

static hs_status world_create(const hs_scene* sc, int realtime, world* w, hs_err* err) {
    memset(w, 0, sizeof *w);
    w->scene = *sc;
    // Mesh errors name the mesh file and line; say which scene key led there too.
    hs_err e2 = {0};
    hs_status s = hs_mesh_load(sc->mesh_path, &w->mesh, &e2);
    if (s < 0) return hs_err_set(err, s, "%s:%d: key 'mesh': %s", sc->path, sc->mesh_line, e2.msg);
    if (s == HS_WARN_MESH_REPAIRED) { // repairs are never silent
        char rep[512];
        hs_mesh_report_str(&w->mesh->report, rep, sizeof rep);
        fprintf(stderr, "hapsim-server: %s was repaired on loading:\n%s", sc->mesh_path, rep);
    }
    if (sc->units_scale != 1.0) {
        for (int i = 0; i < 3 * w->mesh->n_nodes; ++i) w->mesh->x0[i] *= sc->units_scale;
        s = hs_mesh_finalize(w->mesh, &e2);
        if (s < 0) {
            s = hs_err_set(err, s, "%s:%d: key 'units_scale' (%g): %s", sc->path, sc->units_line,
                           sc->units_scale, e2.msg);
            goto fail;
        }
    }
    const hs_mesh* m = w->mesh;
    if (m->report.min_dihedral_deg < sc->min_dihedral_deg) {
        s = hs_err_set(err, HS_ERR_INVALID,
                       "%s:%d: key 'mesh': %s: its flattest tet has a %.3g degree dihedral angle "
                       "(below mesh_quality.min_dihedral_deg %g): such slivers make element "
                       "stiffness and forces spike; remesh it (hapsim-mesh tet --size ...) or "
                       "accept it with \"mesh_quality\": {\"min_dihedral_deg\": 0}",
                       sc->path, sc->mesh_line, sc->mesh_path, m->report.min_dihedral_deg,
                       sc->min_dihedral_deg);
        goto fail;
    }
    size_t n = (size_t)m->n_nodes;
    w->fixed = hs_calloc(n, 1);
    w->u = hs_calloc(3 * n, sizeof(double));
    w->v = hs_calloc(3 * n, sizeof(double));
    if (!w->fixed || !w->u || !w->v) goto nomem;
    int empty = -1, used = 0;
    w->n_fixed = fixed_mask(sc, m, w->fixed, &empty, &e2);
    if (w->n_fixed == -2) {
        s = hs_err_set(err, HS_ERR_INVALID, "%s:%d: key 'fixed[%d]': %s: %s", sc->path,
                       sc->fixed[empty].line, empty, sc->mesh_path, e2.msg);
        goto fail;
    }
    if (w->n_fixed < 0) goto nomem;
    for (size_t i = 0; i < n; ++i) used += m->node_used[i] != 0;
    if (empty >= 0) { // a region that misses the mesh is a mistake even when others select
        s = hs_err_set(err, HS_ERR_INVALID,
                       "%s:%d: key 'fixed[%d]': the region selects no node of %s (mesh bounding "
                       "box [%g, %g] x [%g, %g] x [%g, %g] m)",
                       sc->path, sc->fixed[empty].line, empty, sc->mesh_path, m->bbox_min[0],
                       m->bbox_max[0], m->bbox_min[1], m->bbox_max[1], m->bbox_min[2],
                       m->bbox_max[2]);
        goto fail;
    }
    if (w->n_fixed == used) {
        s = hs_err_set(err, HS_ERR_INVALID,
                       "%s:%d: key 'fixed': the regions fix every node of %s (nothing left to "
                       "move)",
                       sc->path, sc->fixed_line, sc->mesh_path);
        goto fail;
    }

    w->scalpel = w->probe_tool = -1;
    for (int t = 0; t < sc->n_tools; ++t) {
        if (sc->tools[t].kind == HS_TOOL_SCALPEL && w->scalpel < 0) w->scalpel = t;
        if (sc->tools[t].kind == HS_TOOL_PROBE && w->probe_tool < 0) w->probe_tool = t;
    }
    w->cutting = sc->feature_cutting && w->scalpel >= 0;
    hs_scene_device_tools(sc, w->dev_sim, w->sim_scene_tool);
    w->x0r = hs_alloc(3 * n * sizeof(double));
    if (!w->x0r) goto nomem;
    memcpy(w->x0r, m->x0, 3 * n * sizeof(double));
    if (w->cutting) {
        w->cdef = hs_haptic_cut_default_def();
        memcpy(w->cdef.blade_a, sc->tools[w->scalpel].blade_a, sizeof w->cdef.blade_a);
        memcpy(w->cdef.blade_b, sc->tools[w->scalpel].blade_b, sizeof w->cdef.blade_b);
        w->cdef.max_force_n =
            sc->force_max_n < w->cdef.max_force_n ? sc->force_max_n : w->cdef.max_force_n;
        // A scene listing a probe as well: the released blade probes the (cut) tissue (with
        // devices listed, the probe has its own device and the blade only cuts).
        w->cdef.probe_when_released = w->probe_tool >= 0 && !sc->devices_listed;
        w->cdef.cut.fragment =
            sc->cut_free_pieces_fall ? HS_CUT_FRAGMENT_FIX : HS_CUT_FRAGMENT_DROP;
        w->tri_cap = 4 * m->n_tets;
        w->ctris = hs_alloc(3 * (size_t)w->tri_cap * sizeof(int) + 1);
        w->vis_of = hs_alloc(n * sizeof(int32_t) + 1);
        w->ev_removed = hs_alloc((size_t)m->n_tets * sizeof(int32_t) + 1);
        w->ev_moved = hs_alloc(n * sizeof(int32_t) + 1);
        w->ev_rest = hs_alloc(3 * n * sizeof(float) + 1);
        if (!w->ctris || !w->vis_of || !w->ev_removed || !w->ev_moved || !w->ev_rest) goto nomem;
    }

    w->visual = sc->feature_visual;
    if (w->visual) {
        int nv = m->n_surf_nodes;
        // a cut exposes inner nodes and faces: room for all of them
        size_t vcap = w->cutting ? n : (size_t)nv;
        size_t tcap = w->cutting ? 3 * (size_t)w->tri_cap : 3 * (size_t)m->n_tris;
        w->n_vis = nv;
        w->n_tri_idx = 3 * m->n_tris;
        w->vis_nodes = hs_alloc(vcap * sizeof(int32_t) + 1);
        w->rest = hs_alloc(3 * vcap * sizeof(float) + 1);
        w->tri = hs_alloc(tcap * sizeof(int32_t) + 1);
        w->cur = hs_alloc(3 * vcap * sizeof(float) + 1);
        w->key = hs_alloc(3 * vcap * sizeof(float) + 1);
        w->d_index = hs_alloc(vcap * sizeof(int32_t) + 1);
        w->d_delta = hs_alloc(3 * vcap * sizeof(float) + 1);
        if (!w->vis_nodes || !w->rest || !w->tri || !w->cur || !w->key || !w->d_index ||
            !w->d_delta)
            goto nomem;
        for (int i = 0; i < nv; ++i) {
            int node = m->surf_nodes[i];
            w->vis_nodes[i] = node;
            for (int k = 0; k < 3; ++k) w->rest[3 * i + k] = (float)m->x0[3 * node + k];
        }
        for (int i = 0; i < w->n_tri_idx; ++i) w->tri[i] = m->node_surf[m->tris[i]];
        memcpy(w->cur, w->rest, 3 * (size_t)nv * sizeof(float));
        memcpy(w->key, w->rest, 3 * (size_t)nv * sizeof(float));
    }

    w->surf_edge_m = median_surface_edge(m);
    int has_probe = w->cutting; // with cutting on, the scalpel is the haptic tool
    for (int t = 0; t < sc->n_tools; ++t) has_probe |= sc->tools[t].kind == HS_TOOL_PROBE;
    w->haptics = sc->feature_haptics && has_probe && sc->n_devices > 0;
    if (sc->feature_haptics && !w->haptics)
        w->probe_note = "haptics on but the scene has no probe tool or no device: not run";
    if (w->haptics) {
        // The compliance is the inverse of the static stiffness: rigid motion left free by the
        // fixed regions makes it singular (it said "stiffness not positive definite").
        if ((s = hs_fem_check_fixed(m, w->fixed, &e2)) != HS_OK) {
            s = hs_err_set(err, s, "%s:%d: key 'fixed': %s", sc->path, sc->fixed_line, e2.msg);
            goto fail;
        }
        hs_scene_sim_def(sc, realtime, &w->def);
        s = world_sim_create(w, 0, err);
        if (s != HS_OK) goto fail;
    }
    return HS_OK;
nomem:
    s = hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory building the scene", sc->path);
fail:
    world_destroy(w);
    return s;
}

// ---------------------------------------------------------------------------------------------
// Publishing

static hs_haptic_model zero_model(void) {
    hs_haptic_model m;
    memset(&m, 0, sizeof m);
    return m;
}

static int model_stiff(const hs_haptic_model* m) {
    for (int i = 0; i < 9; ++i)
        if (m->stiffness_n_m[i] != 0) return 1;
    return 0;
}

// Publish one tool_force for device d from model m (force at m->anchor_m, tool position: the
// wire carries the hand's, the clutch's offset off), answering the pose (session, pose_seq,
// pose_utime) of the driver session that sent it.
static void publish_force(hs_server* s, int d, const hs_haptic_model* m, int state, int64_t session,
                          int64_t pose_seq, int64_t pose_utime, int64_t rx_ns) {
    dev_state* ds = &s->dev[d];
    hapsim_tool_force_t f;
    memset(&f, 0, sizeof f);
    f.utime = now_us();
    f.seq = ++ds->force_seq;
    f.device_id = d;
    f.session = session;
    f.pose_seq = pose_seq;
    f.pose_utime = pose_utime;
    f.model_version = m->seq;
    f.state = state;
    for (int k = 0; k < 3; ++k) {
        f.force[k] = m->force_n[k];
        f.anchor[k] = m->anchor_m[k] - ds->offset[k];
    }
    for (int k = 0; k < 9; ++k) f.stiffness[k] = -m->stiffness_n_m[k]; // wire: dF/dp
    f.validity_radius = m->radius_m;
    f.timeout_us = (int64_t)(m->timeout_s * 1e6);
    hapsim_tool_force_t_publish(hs_net_bus_lcm(s->hbus), s->ch_force, &f);
    int64_t t = hs_now_ns();
    ds->last_pub_ns = t;
    memcpy(ds->force, m->force_n, sizeof ds->force);
    ds->contact = state == HAPSIM_TOOL_FORCE_T_STATE_CONTACT;
    ds->pubs++;
    s->forces_total++;
    if (rx_ns > 0 && ds->lat) hist_add(ds->lat, t - rx_ns);
}

// Scale force and stiffness so that |force| <= fmax.
static void clamp_model(hs_haptic_model* m, double fmax) {
    double fn = norm3(m->force_n);
    if (fn > fmax && fn > 0) {
        double g = fmax / fn;
        for (int k = 0; k < 3; ++k) m->force_n[k] *= g;
        for (int k = 0; k < 9; ++k) m->stiffness_n_m[k] *= g;
    }
}

static int state_of(const hs_haptic_output* o, const hs_haptic_model* m) {
    int active = norm3(m->force_n) > 0 || model_stiff(m);
    if (o->safety & HS_SAFETY_WATCHDOG)
        return active ? HAPSIM_TOOL_FORCE_T_STATE_RAMP : HAPSIM_TOOL_FORCE_T_STATE_STOPPED;
    return active ? HAPSIM_TOOL_FORCE_T_STATE_CONTACT : HAPSIM_TOOL_FORCE_T_STATE_FREE;
}

static void scale_model(hs_haptic_model* m, double g) {
    for (int k = 0; k < 3; ++k) m->force_n[k] *= g;
    for (int k = 0; k < 9; ++k) m->stiffness_n_m[k] *= g;
}

// How long a ramp between zero and full force takes: the safety ramp, or longer if the force
// limit at the rate limit needs it. The e-stop release and the clutch ramp over it.
static double ramp_time(const hs_server* s) {
    const hs_safety_def* sd = &s->w.def.safety;
    double ramp = sd->ramp_s;
    if (sd->max_rate_n_s > 0 && sd->max_force_n / sd->max_rate_n_s > ramp)
        ramp = sd->max_force_n / sd->max_rate_n_s;
    return ramp;
}

// Gain on the rt model at time t after an ESTOP_RELEASE: 0 -> 1 over the ramp time (a resume
// ramps in the same way, through its new sim's watchdog).
static double estop_gain(const hs_server* s, int64_t t) {
    if (s->estop) return 0.0;
    double g = (double)(t - s->estop_release_ns) * 1e-9 / ramp_time(s);
    return g >= 1.0 ? 1.0 : g > 0.0 ? g : 0.0;
}

// The clutch decouples the tool from the hand (docs/protocol.md, "Clutch"). Held: the tool stays
// where it was, the hand's motion is ignored, and the answers ramp the force felt at clutch-down
// to zero with no stiffness, so a driver's local model does not follow the hand. Released: the
// tool goes on from where it stayed by the hand's motion from then on (the hand-to-tool offset
// is kept, as a device's indexing) and the force ramps back in from where the ramp down was.
static void clutch_track(hs_server* s, dev_state* ds, const hs_net_pose* p, int64_t t) {
    int held = (p->buttons & HAPSIM_TOOL_POSE_T_BUTTON_CLUTCH) != 0;
    if (p->session != ds->session) { // a new driver: no offset left by another one's clutch
        ds->session = p->session;
        memset(ds->offset, 0, sizeof ds->offset);
        ds->clutched = 0;
        ds->engage_ns = 0;
    }
    if (held && !ds->clutched) {
        ds->clutched = 1;
        ds->clutch_ns = t;
        memcpy(ds->clutch_f, ds->force, sizeof ds->clutch_f);
        for (int k = 0; k < 3; ++k)
            ds->hold[k] = ds->seen ? ds->pos[k] : p->position[k] + ds->offset[k];
    } else if (!held && ds->clutched) {
        double g = 1.0 - (double)(t - ds->clutch_ns) * 1e-9 / ramp_time(s);
        ds->clutched = 0;
        ds->engage_ns = t;
        ds->engage_g0 = g > 0 ? g : 0;
        for (int k = 0; k < 3; ++k) ds->offset[k] = ds->hold[k] - p->position[k];
    }
}

// Gain on the engaged model at time t: 1, or ramping back in after a release.
static double engage_gain(const hs_server* s, const dev_state* ds, int64_t t) {
    if (ds->engage_ns == 0) return 1.0;
    double g = ds->engage_g0 + (double)(t - ds->engage_ns) * 1e-9 / ramp_time(s);
    return g >= 1.0 ? 1.0 : g;
}

// The answer while the clutch is held, at hand position hand (tool frame): the force at
// clutch-down ramped to zero, no stiffness. State RAMP, then FREE once it is zero.
static hs_haptic_model clutch_model(const hs_server* s, const dev_state* ds, int64_t t,
                                    const double hand[3], int* state) {
    hs_haptic_model m = zero_model();
    double g = 1.0 - (double)(t - ds->clutch_ns) * 1e-9 / ramp_time(s);
    if (g > 0)
        for (int k = 0; k < 3; ++k) m.force_n[k] = g * ds->clutch_f[k];
    memcpy(m.anchor_m, hand, sizeof m.anchor_m);
    m.timeout_s = s->have_out ? s->out.model.timeout_s : s->w.scene.watchdog_s;
    *state = norm3(m.force_n) > 0 ? HAPSIM_TOOL_FORCE_T_STATE_RAMP : HAPSIM_TOOL_FORCE_T_STATE_FREE;
    return m;
}

// The paused model at time t: the model at the pause scaled down linearly to zero, under the
// limits a running answer gets (force_max_n as set now, the e-stop release ramp): without them a
// pause lifted a lowered limit and cut a release ramp short (tests/test_server.c
// pause_keeps_limits has the numbers).
static hs_haptic_model paused_from(const hs_server* s, const hs_haptic_model* at_pause, int64_t t,
                                   const double pos[3]) {
    double g = (1.0 - (double)(t - s->pause_ns) * 1e-9 / PAUSE_RAMP_S) * estop_gain(s, t);
    if (!(g > 0)) return zero_model();
    hs_haptic_model m;
    hs_haptic_model_reanchor(at_pause, pos, &m);
    clamp_model(&m, s->w.scene.force_max_n);
    scale_model(&m, g);
    return m;
}

static hs_haptic_model paused_model(const hs_server* s, int64_t t, const double pos[3]) {
    return paused_from(s, &s->pause_model, t, pos);
}

// Devices driving sim tools t > 0: the newest output of each.
static void drain_tool_outputs(hs_server* s) {
    for (int d = 0; d < MAX_DEV && s->w.sim; ++d) {
        int t = s->w.dev_sim[d];
        if (t <= 0 || t >= hs_haptic_sim_tools(s->w.sim)) continue;
        while (hs_haptic_sim_take_tool_output(s->w.sim, t, &s->dev[d].out)) s->dev[d].have_out = 1;
    }
}

// Their outputs belong to a sim that is gone (rebuild, resume).
static void forget_tool_outputs(hs_server* s) {
    for (int d = 0; d < MAX_DEV; ++d) s->dev[d].have_out = 0;
}

// At a pause: each such device's output model, ramped to zero while paused.
static void pause_tools(hs_server* s) {
    drain_tool_outputs(s);
    for (int d = 0; d < MAX_DEV; ++d)
        s->dev[d].pause_model = s->dev[d].have_out ? s->dev[d].out.model : zero_model();
}

static void drain_outputs(hs_server* s) {
    if (!s->w.sim) return;
    drain_tool_outputs(s);
    hs_haptic_output o;
    while (hs_haptic_sim_take_output(s->w.sim, &o)) {
        s->out = o;
        s->have_out = 1;
    }
    hs_spsc_ring* tel = hs_haptic_sim_telemetry(s->w.sim);
    if (tel) {
        hs_haptic_telemetry t;
        while (hs_spsc_ring_pop(tel, &t)) {
        }
    }
}

static int ring_find(const hs_server* s, int64_t feed) {
    int i = (int)(feed % POSE_RING);
    return feed > 0 && s->ring_feed[i] == feed ? i : -1;
}

// rt outputs go out when the device's poses have stopped (watchdog ramp to zero) or slowed down.
static void publish_rt_output(hs_server* s) {
    if (srv_paused(s)) return;
    int64_t t = hs_now_ns();
    for (int d = 0; d < MAX_DEV; ++d) { // every device driving a sim tool, from its tool's output
        const int tool = s->w.dev_sim[d];
        dev_state* ds = &s->dev[d];
        if (tool < 0 || !(tool == 0 ? s->have_out : ds->have_out) || !ds->seen) continue;
        const hs_haptic_output* o = tool == 0 ? &s->out : &ds->out;
        double quiet_s = s->w.scene.watchdog_s + s->w.def.safety.ramp_s + 0.25;
        if (t - ds->last_rx_ns > (int64_t)(quiet_s * 1e9)) continue; // long dead: nothing to say
        if (t - ds->last_pub_ns < RT_GAP_NS) continue;
        hs_haptic_model m = s->estop ? zero_model() : o->model; // limited by the rt stage
        int state = s->estop ? HAPSIM_TOOL_FORCE_T_STATE_STOPPED : state_of(o, &m);
        // The clutch is tool 0's device's (clutch_track).
        double g = estop_gain(s, t) * (tool == 0 ? engage_gain(s, ds, t) : 1.0);
        if (!s->estop && tool == 0 && ds->clutched) {
            double hand[3];
            for (int k = 0; k < 3; ++k) hand[k] = ds->hand[k] + ds->offset[k];
            m = clutch_model(s, ds, t, hand, &state);
        } else if (!s->estop && g < 1.0) {
            scale_model(&m, g);
            state = HAPSIM_TOOL_FORCE_T_STATE_RAMP;
        }
        int i = tool == 0 ? ring_find(s, o->pose_seq) : -1; // the ring maps tool 0's poses
        // The session of the pose rt answered: after a takeover an output of the old session's
        // poses must not reach the new driver.
        publish_force(s, d, &m, state, i >= 0 ? s->ring_session[i] : ds->session,
                      i >= 0 ? s->ring_seq[i] : 0, i >= 0 ? s->ring_utime[i] : 0, 0);
    }
}

// The model an rt output o puts on the wire for a pose with these buttons received at rx_ns.
static hs_haptic_model output_model(const hs_server* s, const hs_haptic_output* o, double gain,
                                    int64_t rx_ns, int* state) {
    // The rt output as it is, anchored where rt took it: its force is the one the rt output
    // stage limited (magnitude, rate, watchdog), and a driver evaluating the model at this pose
    // gets what a re-anchored copy would say. Re-anchored here, the force on the wire was the
    // model's extrapolation, which no limit bounds. gain: a ramp of the caller's (the clutch).
    hs_haptic_model m = o->model;
    *state = state_of(o, &m);
    // A limit set since rt made this output holds from the set's ack on.
    clamp_model(&m, s->w.scene.force_max_n);
    double g = estop_gain(s, rx_ns) * gain;
    if (g < 1.0) {
        scale_model(&m, g);
        *state = HAPSIM_TOOL_FORCE_T_STATE_RAMP;
    }
    return m;
}

// The pose rt is fed for an accepted wire pose: its own seq, stamped when received.
static hs_haptic_pose rt_pose(const hs_net_pose* p, int64_t seq, int64_t rx_ns) {
    hs_haptic_pose hp;
    memset(&hp, 0, sizeof hp);
    hp.seq = seq;
    hp.stamp_ns = rx_ns;
    memcpy(hp.pos_m, p->position, sizeof hp.pos_m);
    memcpy(hp.quat_wxyz, p->orientation, sizeof hp.quat_wxyz);
    hp.buttons = p->buttons;
    return hp;
}

// A device driving sim tool t > 0: feeds its tool, answers from that tool's newest output.
static hs_haptic_model answer_tool(hs_server* s, int d, int t, const hs_net_pose* p, int64_t rx_ns,
                                   int* state) {
    dev_state* ds = &s->dev[d];
    if (srv_paused(s)) {
        *state = HAPSIM_TOOL_FORCE_T_STATE_RAMP;
        return paused_from(s, &ds->pause_model, rx_ns, p->position);
    }
    if (!(p->buttons & HAPSIM_TOOL_POSE_T_BUTTON_CLUTCH)) {
        hs_haptic_pose hp = rt_pose(p, ++ds->feed_seq, rx_ns);
        hs_haptic_sim_feed_tool_pose(s->w.sim, t, &hp);
    }
    drain_tool_outputs(s);
    if (!ds->have_out) return zero_model();
    return output_model(s, &ds->out, 1.0, rx_ns, state);
}

// Answer an accepted pose at once: the newest rt model evaluated at the new position.
static void answer_pose(hs_server* s, const hs_net_pose* p, int64_t rx_ns) {
    int d = p->device_id;
    dev_state* ds = &s->dev[d];
    if (s->w.dev_sim[d] == 0) clutch_track(s, ds, p, rx_ns); // the clutch: tool 0's device
    double hand[3]; // the hand in the tool's frame; the tool stays put while clutched
    for (int k = 0; k < 3; ++k) hand[k] = p->position[k] + ds->offset[k];
    ds->seen = 1;
    ds->session = p->session;
    ds->last_rx_ns = rx_ns;
    memcpy(ds->hand, p->position, sizeof ds->hand);
    memcpy(ds->pos, ds->clutched ? ds->hold : hand, sizeof ds->pos);
    memcpy(ds->quat, p->orientation, sizeof ds->quat);
    ds->buttons = p->buttons;
    world* w = &s->w;
    if (!w->haptics) return; // validated and counted, not answered (scene: haptics off)
    hs_haptic_model m = zero_model();
    int state = HAPSIM_TOOL_FORCE_T_STATE_STOPPED;
    const int t = w->dev_sim[d]; // the sim tool it drives (-1: none)
    if (t > 0 && (w->sim || srv_paused(s)) && !s->estop) {
        if (srv_paused(s) || t < hs_haptic_sim_tools(w->sim))
            m = answer_tool(s, d, t, p, rx_ns, &state);
    } else if (t == 0 && srv_paused(s)) {
        m = paused_model(s, rx_ns, hand);
        state = HAPSIM_TOOL_FORCE_T_STATE_RAMP;
    } else if (t == 0 && w->sim) {
        // rt gets the tool's position: it stays still while the clutch is held (no watchdog).
        hs_haptic_pose hp = rt_pose(p, ++s->feed_seq, rx_ns);
        memcpy(hp.pos_m, ds->pos, sizeof hp.pos_m);
        int i = (int)(hp.seq % POSE_RING);
        s->ring_feed[i] = hp.seq;
        s->ring_seq[i] = p->seq;
        s->ring_utime[i] = p->utime;
        s->ring_session[i] = p->session;
        s->ring_rx[i] = rx_ns;
        hs_haptic_sim_feed_pose(w->sim, &hp);
        drain_outputs(s);
        if (s->have_out && !s->estop && ds->clutched) {
            m = clutch_model(s, ds, rx_ns, hand, &state);
        } else if (s->have_out && !s->estop) {
            m = output_model(s, &s->out, engage_gain(s, ds, rx_ns), rx_ns, &state);
        }
    }
    if (s->estop) {
        m = zero_model();
        state = HAPSIM_TOOL_FORCE_T_STATE_STOPPED;
    }
    if (m.anchor_m[0] == 0 && m.anchor_m[1] == 0 && m.anchor_m[2] == 0)
        memcpy(m.anchor_m, hand, sizeof m.anchor_m);
    publish_force(s, d, &m, state, p->session, p->seq, p->utime, rx_ns);
}

// The haptic bus's URL as LCM gets it: a udpm:// URL that names no recv_buf_size asks for
// HAPTIC_RCVBUF, or net.core.rmem_max if that is less (LCM warns when it gets less than it
// asked for), so a foreign flood does not spill the driver's poses as soon (docs/server.md,
// "Floods").
static void haptic_bus_url(const hs_server* s, char* out, size_t cap) {
    int64_t want = s->rmem_max < HAPTIC_RCVBUF ? s->rmem_max : HAPTIC_RCVBUF;
    if (strncmp(s->haptic_url, "udpm://", 7) != 0 || strstr(s->haptic_url, "recv_buf_size=") ||
        want <= s->rmem_default)
        snprintf(out, cap, "%s", s->haptic_url);
    else if (snprintf(out, cap, "%s%crecv_buf_size=%lld", s->haptic_url,
                      strchr(s->haptic_url, '?') ? '&' : '?',
                      (long long)want) >= HS_SCENE_URL_MAX) // the bus keeps 255 bytes
        snprintf(out, cap, "%s", s->haptic_url);
}

static void on_pose(const lcm_recv_buf_t* rb, const char* ch, void* user) {
    (void)ch;
    hs_server* s = user;
    if (s->listening) return; // not serving yet: an answer would be heard as another server's
    int64_t t0 = hs_now_ns();
    hs_net_pose p;
    if (hs_net_validate_pose(&s->lim, &s->pst, rb->data, rb->data_size, t0 / 1000, &p) !=
        HS_NET_ACCEPT)
        return;
    s->poses_total++;
    answer_pose(s, &p, t0);
    hist_add(s->h_handle, hs_now_ns() - t0);
}

// A mesh message too large for a receiver's socket buffer is lost without a trace (LCM 1.3.1):
// say so, once per level (a cut can grow the topology past the next one).
static void note_mesh_size(hs_server* s, const char* what, int64_t bytes) {
    char note[400];
    int level = hs_net_size_note(what, bytes, s->rmem_default, s->rmem_max, note, sizeof note);
    if (level <= s->mesh_size_noted) return;
    s->mesh_size_noted = level;
    fprintf(stderr, "hapsim-server: note: %s\n", note);
}

// The topology message of the current visual mesh (utime and seq left 0).
static void fill_topology(const hs_server* s, hapsim_mesh_topology_t* out) {
    const world* w = &s->w;
    memset(out, 0, sizeof *out);
    out->topology_version = s->topo_version;
    out->n_nodes = w->mesh->n_nodes;
    out->n_vis = w->n_vis;
    out->vis_nodes = w->vis_nodes;
    out->n_rest = 3 * w->n_vis;
    out->rest_position = w->rest;
    out->n_tri_idx = w->n_tri_idx;
    out->triangles = w->tri;
    out->n_tet_idx = 0;
    out->tets = NULL;
}

static void publish_topology(hs_server* s) {
    if (!s->w.visual) return;
    hapsim_mesh_topology_t t;
    fill_topology(s, &t);
    t.utime = now_us();
    t.seq = ++s->seq_topo;
    note_mesh_size(s, "mesh topology", hapsim_mesh_topology_t_encoded_size(&t));
    hapsim_mesh_topology_t_publish(hs_net_bus_lcm(s->mbus), s->ch_topo, &t);
}

static double sim_time(const hs_server* s) {
    return (double)s->frame_step * s->w.def.body.dt;
}

static void publish_keyframe(hs_server* s) {
    world* w = &s->w;
    if (!w->visual) return;
    memcpy(w->key, w->cur, 3 * (size_t)w->n_vis * sizeof(float));
    hapsim_mesh_state_t m;
    memset(&m, 0, sizeof m);
    m.utime = now_us();
    m.seq = ++s->seq_state;
    m.topology_version = s->topo_version;
    m.keyframe_id = ++s->keyframe_id;
    m.sim_step = s->frame_step;
    m.sim_time = sim_time(s);
    m.n_pos = 3 * w->n_vis;
    m.position = w->key;
    m.n_stress = 0;
    m.stress = NULL;
    note_mesh_size(s, "mesh keyframe", hs_net_keyframe_bytes(w->n_vis, 0));
    hapsim_mesh_state_t_publish(hs_net_bus_lcm(s->mbus), s->ch_state, &m);
    s->key_ns = hs_now_ns();
    s->have_key = 1;
}

// Current positions from the newest frame; a delta (or a keyframe when due) if it is new.
static void publish_frame(hs_server* s, int64_t t) {
    world* w = &s->w;
    if (!w->visual) return;
    int fresh = 0;
    if (w->sim) {
        int64_t step = 0;
        fresh = hs_haptic_sim_read_frame(w->sim, w->u, &step);
        if (fresh) s->frame_step = s->sim_step_base + step;
    }
    if (!fresh) return;
    const double* x0 = w->x0r; // the mesh's own x0 belongs to the deformation thread (cuts)
    for (int i = 0; i < w->n_vis; ++i) {
        int node = w->vis_nodes[i];
        for (int k = 0; k < 3; ++k)
            w->cur[3 * i + k] = (float)(x0[3 * node + k] + w->u[3 * node + k]);
    }
    int nc = hs_net_delta_build(w->key, w->cur, w->n_vis, DELTA_EPS_M, w->d_index, w->d_delta);
    if (!s->have_key ||
        hs_net_keyframe_due(w->n_vis, nc, (t - s->key_ns) / 1000, 2 * KEYFRAME_NS / 1000)) {
        publish_keyframe(s);
        return;
    }
    hapsim_mesh_delta_t d;
    memset(&d, 0, sizeof d);
    d.utime = now_us();
    d.seq = ++s->seq_delta;
    d.topology_version = s->topo_version;
    d.keyframe_id = s->keyframe_id;
    d.sim_step = s->frame_step;
    d.sim_time = sim_time(s);
    d.n_changed = nc;
    d.index = w->d_index;
    d.n_delta = 3 * nc;
    d.delta = w->d_delta;
    hapsim_mesh_delta_t_publish(hs_net_bus_lcm(s->mbus), s->ch_delta, &d);
}

// v rotated by the unit quaternion q (w, x, y, z).
static void quat_rot(const double q[4], const double v[3], double out[3]) {
    const double w = q[0], x = q[1], y = q[2], z = q[3];
    double r[9] = {1 - 2 * (y * y + z * z), 2 * (x * y - w * z),     2 * (x * z + w * y),
                   2 * (x * y + w * z),     1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                   2 * (x * z - w * y),     2 * (y * z + w * x),     1 - 2 * (x * x + y * y)};
    for (int a = 0; a < 3; ++a)
        out[a] = r[3 * a] * v[0] + r[3 * a + 1] * v[1] + r[3 * a + 2] * v[2];
}

// Take the newest cut from the sim: publish a topology_event, bump the topology version,
// rebuild the visual set from the live boundary (inner nodes the cut exposed join it), and
// republish mesh_topology + a keyframe so every client (also one that missed the event)
// rebuilds.
static void apply_cut(hs_server* s) {
    world* w = &s->w;
    hs_haptic_cut_event ev;
    memset(&ev, 0, sizeof ev);
    ev.removed_tets = w->ev_removed;
    ev.moved_nodes = w->ev_moved;
    int nt = 0;
    w->cut_seen = hs_haptic_sim_take_topology(w->sim, w->x0r, w->ctris, w->tri_cap, &nt, &ev);
    w->cut_made = 1;
    int64_t old = s->topo_version++;

    hapsim_topology_event_t e;
    memset(&e, 0, sizeof e);
    e.utime = now_us();
    e.seq = ++s->seq_tevent;
    e.old_version = old;
    e.new_version = s->topo_version;
    e.device_id = 0; // the blade's device: the one driving sim tool 0
    for (int d = 0; d < MAX_DEV; ++d)
        if (w->dev_sim[d] == 0) {
            e.device_id = d;
            break;
        }
    e.n_removed = ev.n_removed;
    e.removed_tets = w->ev_removed;
    e.n_moved = ev.n_moved;
    e.moved_nodes = w->ev_moved;
    for (int k = 0; k < ev.n_moved; ++k)
        for (int a = 0; a < 3; ++a) w->ev_rest[3 * k + a] = (float)w->x0r[3 * w->ev_moved[k] + a];
    e.n_moved_rest = 3 * ev.n_moved;
    e.moved_rest = w->ev_rest;
    for (int k = 0; k < 12; ++k) e.swept_quad[k] = (float)ev.swept_quad[k];
    hapsim_topology_event_t_publish(hs_net_bus_lcm(s->mbus), s->ch_tevent, &e);
    s->cut_events++;

    if (!w->visual) return;
    const int n = w->mesh->n_nodes;
    for (int i = 0; i < n; ++i) w->vis_of[i] = -1;
    for (int k = 0; k < 3 * nt; ++k) w->vis_of[w->ctris[k]] = 0;
    int nv = 0;
    for (int i = 0; i < n; ++i)
        if (w->vis_of[i] == 0) {
            w->vis_of[i] = nv;
            w->vis_nodes[nv++] = i;
        }
    w->n_vis = nv;
    w->n_tri_idx = 3 * nt;
    for (int k = 0; k < 3 * nt; ++k) w->tri[k] = w->vis_of[w->ctris[k]];
    for (int i = 0; i < nv; ++i)
        for (int a = 0; a < 3; ++a) {
            int node = w->vis_nodes[i];
            w->rest[3 * i + a] = (float)w->x0r[3 * node + a];
            w->cur[3 * i + a] = (float)(w->x0r[3 * node + a] + w->u[3 * node + a]);
        }
    publish_topology(s);
    publish_keyframe(s);
}

static void publish_tool_states(hs_server* s, int64_t t) {
    const hs_scene* sc = &s->w.scene;
    for (int d = 0; d < sc->n_devices && d < MAX_DEV; ++d) {
        dev_state* ds = &s->dev[d];
        if (!ds->seen || t - ds->last_rx_ns > (int64_t)(sc->watchdog_s * 1e9)) continue;
        hapsim_tool_state_t ts;
        memset(&ts, 0, sizeof ts);
        ts.utime = now_us();
        ts.seq = ++s->seq_tool;
        ts.device_id = d;
        ts.tool_id = s->w.probe_tool > 0 ? s->w.probe_tool : 0;
        ts.kind = HAPSIM_TOOL_STATE_T_KIND_PROBE;
        for (int k = 0; k < 3; ++k) {
            ts.position[k] = ds->pos[k];
            ts.blade_a[k] = ds->pos[k];
            ts.blade_b[k] = ds->pos[k];
            ts.force[k] = ds->force[k];
        }
        for (int k = 0; k < 4; ++k) ts.orientation[k] = ds->quat[k];
        ts.radius = s->w.def.probe.radius_m;
        if (sc->devices_listed && sc->tools[sc->device_tool[d]].kind == HS_TOOL_PROBE) {
            ts.tool_id = sc->device_tool[d]; // its own probe
            ts.radius = sc->tools[ts.tool_id].radius;
        }
        ts.contact = (int8_t)ds->contact;
        ts.cutting = 0;
        if (s->w.cutting && s->w.dev_sim[d] == 0 &&
            !(s->w.cdef.probe_when_released && !(ds->buttons & s->w.cdef.engage_buttons))) {
            const hs_scene_tool* tl = &sc->tools[s->w.scalpel];
            double ra[3], rb[3];
            quat_rot(ds->quat, tl->blade_a, ra);
            quat_rot(ds->quat, tl->blade_b, rb);
            ts.tool_id = s->w.scalpel;
            ts.kind = HAPSIM_TOOL_STATE_T_KIND_SCALPEL;
            ts.radius = 0;
            for (int k = 0; k < 3; ++k) {
                ts.blade_a[k] = ds->pos[k] + ra[k];
                ts.blade_b[k] = ds->pos[k] + rb[k];
            }
            ts.cutting = (int8_t)(s->w.sim && s->cutting_now);
        }
        hapsim_tool_state_t_publish(hs_net_bus_lcm(s->mbus), s->ch_tool, &ts);
    }
}

// ---------------------------------------------------------------------------------------------
// Status

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return (x > y) - (x < y);
}

// Quantile q of the kept cut step times, ms (0 when there is none).
static double cut_quantile(hs_server* s, double q) {
    int n = s->n_cut_ms < CUT_SAMPLES ? (int)s->n_cut_ms : CUT_SAMPLES;
    if (n == 0) return 0;
    memcpy(s->cut_sort, s->cut_ms, (size_t)n * sizeof(double));
    qsort(s->cut_sort, (size_t)n, sizeof(double), cmp_double);
    int k = (int)(q * (n - 1) + 0.5);
    return s->cut_sort[k < n ? k : n - 1];
}

// Datagrams the kernel dropped on bus b (0 haptic, 1 mesh) since the server started (their
// messages never reached a handler to be counted); 0 when the kernel cannot tell.
static int64_t kernel_drops(const hs_server* s, int b) {
    int64_t v = hs_net_bus_kernel_drops(b ? s->mbus : s->hbus);
    return v >= 0 && s->kdrop0[b] >= 0 && v > s->kdrop0[b] ? v - s->kdrop0[b] : 0;
}

// The arrays a status message points into, filled step by step.
#define STATUS_REJECTS (2 * HS_NET_REJ_COUNT + 3)
typedef struct status_buf {
    char* lname[3]; // loops: rt, sim (when the sim runs), net
    float rate[3], p50[3], p99[3], pmax[3];
    int64_t over[3];
    int nl;
    char* sname[5]; // steps
    float s50[5], s99[5], smax[5];
    int ns;
    int32_t did[MAX_DEV];
    int8_t live[MAX_DEV];
    float age[MAX_DEV], l50[MAX_DEV], l99[MAX_DEV], fnorm[MAX_DEV];
    int64_t recv[MAX_DEV], lost[MAX_DEV];
    char* rch[STATUS_REJECTS];
    char* rreason[STATUS_REJECTS];
    char rname[STATUS_REJECTS][32];
    int64_t rcount[STATUS_REJECTS];
    int nr;
    char warn[1024];
    size_t wl;
} status_buf;

static void status_loop(status_buf* b, char* name, double rate, double p50, double p99, double pmax,
                        int64_t over) {
    b->lname[b->nl] = name;
    b->rate[b->nl] = (float)rate;
    b->p50[b->nl] = (float)p50;
    b->p99[b->nl] = (float)p99;
    b->pmax[b->nl] = (float)pmax;
    b->over[b->nl++] = over;
}

static void status_step(status_buf* b, char* name, double p50, double p99, double pmax) {
    b->sname[b->ns] = name;
    b->s50[b->ns] = (float)p50;
    b->s99[b->ns] = (float)p99;
    b->smax[b->ns++] = (float)pmax;
}

static void status_reject(status_buf* b, char* channel, const char* reason, int64_t count) {
    b->rch[b->nr] = channel;
    snprintf(b->rname[b->nr], sizeof b->rname[b->nr], "%s", reason);
    b->rreason[b->nr] = b->rname[b->nr];
    b->rcount[b->nr++] = count;
}

// One warning line (lines past the buffer are dropped).
__attribute__((format(printf, 2, 3))) static void status_warn(status_buf* b, const char* fmt, ...) {
    if (b->wl < sizeof b->warn)
        b->wl += (size_t)snprintf(b->warn + b->wl, sizeof b->warn - b->wl, "%s", b->wl ? "\n" : "");
    if (b->wl >= sizeof b->warn) return;
    va_list ap;
    va_start(ap, fmt);
    b->wl += (size_t)vsnprintf(b->warn + b->wl, sizeof b->warn - b->wl, fmt, ap);
    va_end(ap);
}

// The rt and sim loops and their steps over the window of win seconds (a running sim only).
static void status_sim_loops(hs_server* s, status_buf* b, double win) {
    world* w = &s->w;
    hs_haptic_sim_stats_get(w->sim, s->st_now);
    const hs_haptic_sim_stats* a = s->st_now;
    const hs_haptic_sim_stats* p = s->st_prev;
    double nominal_us = 1e6 / w->def.rate_hz;
    hist_diff(&a->rt.period_err, &p->rt.period_err, s->h_diff);
    status_loop(b, "rt", (double)(a->rt.ticks - p->rt.ticks) / win,
                nominal_us + hs_rt_hist_quantile_us(s->h_diff, 0.5),
                nominal_us + hs_rt_hist_quantile_us(s->h_diff, 0.99),
                nominal_us + hist_max_us(s->h_diff), a->rt.overruns);
    hist_diff(&a->rt.tick, &p->rt.tick, s->h_diff);
    status_step(b, "rt_tick", hs_rt_hist_quantile_us(s->h_diff, 0.5),
                hs_rt_hist_quantile_us(s->h_diff, 0.99), hist_max_us(s->h_diff));
    // Overruns: steps (+ snapshot) longer than 1 / sim_hz.
    status_loop(b, "sim", (double)(a->steps - p->steps) / win,
                SIM_HIST_SCALE * hs_rt_hist_quantile_us(s->h_simper, 0.5),
                SIM_HIST_SCALE * hs_rt_hist_quantile_us(s->h_simper, 0.99),
                SIM_HIST_SCALE * hist_max_us(s->h_simper), a->step_overruns);
    // The deformation thread's own figures over its newest HS_SIM_STEP_WINDOW steps (every
    // step; the net thread samples only some for the window's maximum).
    status_step(b, "sim_step", a->step_ms_p50 * 1e3, a->step_ms_p99 * 1e3,
                SIM_HIST_SCALE * hist_max_us(s->h_step));
    if (w->cutting) // since start: cut steps are rare
        status_step(b, "cut", cut_quantile(s, 0.5) * 1e3, cut_quantile(s, 0.99) * 1e3,
                    cut_quantile(s, 1.0) * 1e3);
    s->rt_obtained = a->rt.obtained;
    s->rt_prio = a->rt.fifo_priority;
    hs_haptic_sim_stats* tmp = s->st_prev;
    s->st_prev = s->st_now;
    s->st_now = tmp;
}

static void status_devices(const hs_server* s, status_buf* b, int nd, int64_t t) {
    const world* w = &s->w;
    for (int d = 0; d < nd; ++d) {
        const dev_state* ds = &s->dev[d];
        b->did[d] = d;
        double a_ms = ds->seen ? (double)(t - ds->last_rx_ns) * 1e-6 : -1.0;
        b->age[d] = (float)a_ms;
        b->live[d] = (int8_t)(ds->seen && a_ms <= w->scene.watchdog_s * 1e3);
        b->recv[d] = s->pst.dev[d].accepted;
        b->lost[d] = s->pst.dev[d].lost;
        b->l50[d] = (float)hs_rt_hist_quantile_us(ds->lat, 0.5);
        b->l99[d] = (float)hs_rt_hist_quantile_us(ds->lat, 0.99);
        b->fnorm[d] = (float)norm3(ds->force);
    }
}

static void status_rejects(hs_server* s, status_buf* b) {
    const hs_net_counters* cs[2] = {&s->pst.counters, &s->cst.counters};
    char* cn[2] = {HAPSIM_CH_TOOL_POSE, HAPSIM_CH_COMMAND};
    for (int c = 0; c < 2; ++c)
        for (int r = 1; r < HS_NET_REJ_COUNT; ++r)
            if (cs[c]->rejected[r])
                status_reject(b, cn[c], hs_net_reject_name((hs_net_reject)r),
                              (int64_t)cs[c]->rejected[r]);
    if (s->params_refused) // well-formed, but a name or value the server does not take
        status_reject(b, HAPSIM_CH_COMMAND, "parameter", s->params_refused);
    for (int k = 0; k < 2; ++k) { // lost before any handler saw them: a full receive buffer
        int64_t n = kernel_drops(s, k);
        if (n) status_reject(b, k ? "MESH_BUS" : "HAPTIC_BUS", "kernel_drop", n);
    }
}

static void status_warnings(const hs_server* s, status_buf* b) {
    const world* w = &s->w;
    const hs_haptic_sim_stats* st = s->st_prev;
    if (w->probe_note) status_warn(b, "%s", w->probe_note);
    // What the rt thread obtained from the OS is reported here (the message has no field for it).
    if (w->sim && !(s->rt_obtained & HS_RT_SCHED_FIFO))
        status_warn(b, "rt thread: ordinary scheduling, no SCHED_FIFO (%s)",
                    s->opt.realtime ? "refused by the OS" : "--realtime not given");
    if (w->sim && !(s->rt_obtained & HS_RT_MLOCKED))
        status_warn(b, "rt thread: memory not locked, no mlockall (%s)",
                    s->opt.realtime ? "refused or skipped" : "--realtime not given");
    if (w->scene.n_devices > 1 && w->haptics && !w->scene.devices_listed)
        status_warn(b,
                    "scene has %d devices: only device 0 drives the tools, others get zero force "
                    "(list the devices to give each its own tool: docs/scenes.md)",
                    w->scene.n_devices);
    if (w->sim && st->step_failures)
        status_warn(b, "%lld deformation steps failed", (long long)st->step_failures);
    if (s->estop) status_warn(b, "e-stop latched: every force is zero");
    if (s->loading)
        status_warn(b, "loading %s: the running scene goes on until it is built", s->loading);
    char note[256];
    if (edge_note(w, note, sizeof note)) status_warn(b, "%s", note);
    if (w->sim && st->comp_state > 0)
        status_warn(b, "haptics: compliance set-up running: zero force until it is ready");
    if (w->sim && st->comp_state < 0)
        status_warn(b, "haptics: compliance set-up failed (%s): zero force",
                    hs_haptic_sim_setup_error(w->sim) ? hs_haptic_sim_setup_error(w->sim) : "?");
    if (w->sim && st->sim_hz_target > 0 && st->sim_hz_target < 0.999 * w->scene.sim_hz)
        status_warn(b,
                    "deformation lowered to %.1f Hz (of %g): sim step p99 %.1f ms > %.1f ms; the "
                    "tissue moves slower than real time, haptics stay at %g Hz",
                    st->sim_hz_target, w->scene.sim_hz, st->step_ms_p99, 1e3 / w->scene.sim_hz,
                    w->scene.haptic_hz);
    if (w->sim && st->cut_failures)
        status_warn(b, "%lld cut steps failed (mesh kept consistent)", (long long)st->cut_failures);
    if (w->sim && st->deep_loops)
        status_warn(b,
                    "pressed %.1f mm deep, beyond the %.1f mm the contact is validated for (docs/"
                    "haptics.md): the force there is unchecked",
                    st->depth_max_m * 1e3, hs_contact_validated_depth(w->def.probe.radius_m) * 1e3);
}

static void publish_status(hs_server* s, int64_t t) {
    world* w = &s->w;
    double win = (double)(t - s->stat_ns) * 1e-9;
    if (win <= 0) win = 1e-9;
    hapsim_server_status_t m;
    memset(&m, 0, sizeof m);
    m.utime = now_us();
    m.seq = ++s->seq_status;
    m.uptime_us = (t - s->start_ns) / 1000;
    // An e-stop latched while a scene loads shows: it is the state that matters to the hand.
    m.state = s->estop        ? HAPSIM_SERVER_STATUS_T_STATE_ESTOP
              : s->loading    ? HAPSIM_SERVER_STATUS_T_STATE_LOADING
              : srv_paused(s) ? HAPSIM_SERVER_STATUS_T_STATE_PAUSED
                              : HAPSIM_SERVER_STATUS_T_STATE_RUNNING;
    m.scene = w->scene.path;
    m.topology_version = s->topo_version;

    status_buf b; // about 2 kB, the net thread's stack
    b.nl = b.ns = b.nr = 0;
    b.wl = 0;
    b.warn[0] = '\0';
    if (w->sim) status_sim_loops(s, &b, win);
    status_loop(&b, "net", (double)s->net_iters / win, hs_rt_hist_quantile_us(s->h_net, 0.5),
                hs_rt_hist_quantile_us(s->h_net, 0.99), hist_max_us(s->h_net), 0);
    status_step(&b, "pose_handling", hs_rt_hist_quantile_us(s->h_handle, 0.5),
                hs_rt_hist_quantile_us(s->h_handle, 0.99), hist_max_us(s->h_handle));
    m.n_loops = b.nl;
    m.loop_name = b.lname;
    m.rate_hz = b.rate;
    m.period_p50_us = b.p50;
    m.period_p99_us = b.p99;
    m.period_max_us = b.pmax;
    m.overruns = b.over;
    m.n_steps = b.ns;
    m.step_name = b.sname;
    m.step_p50_us = b.s50;
    m.step_p99_us = b.s99;
    m.step_max_us = b.smax;

    int nd = w->scene.n_devices < MAX_DEV ? w->scene.n_devices : MAX_DEV;
    status_devices(s, &b, nd, t);
    m.n_devices = nd;
    m.device_id = b.did;
    m.device_live = b.live;
    m.pose_age_ms = b.age;
    m.poses_received = b.recv;
    m.poses_lost = b.lost;
    m.latency_p50_us = b.l50;
    m.latency_p99_us = b.l99;
    m.force_norm = b.fnorm;

    status_rejects(s, &b);
    m.n_rejects = b.nr;
    m.reject_channel = b.rch;
    m.reject_reason = b.rreason;
    m.reject_count = b.rcount;

    status_warnings(s, &b);
    m.warnings = b.warn;
    hapsim_server_status_t_publish(hs_net_bus_lcm(s->mbus), s->ch_status, &m);

    // restart the windows
    memset(s->h_net, 0, sizeof *s->h_net);
    memset(s->h_step, 0, sizeof *s->h_step);
    memset(s->h_handle, 0, sizeof *s->h_handle);
    memset(s->h_simper, 0, sizeof *s->h_simper);
    for (int d = 0; d < MAX_DEV; ++d)
        if (s->dev[d].lat) memset(s->dev[d].lat, 0, sizeof *s->dev[d].lat);
    s->net_iters = 0;
    s->stat_ns = t;
}

// ---------------------------------------------------------------------------------------------
// Commands

static void send_ack(hs_server* s, int64_t id, int32_t kind, int32_t status, const char* msg) {
    hapsim_command_ack_t a;
    memset(&a, 0, sizeof a);
    a.utime = now_us();
    a.seq = ++s->seq_ack;
    a.request_id = id;
    a.kind = kind;
    a.status = status;
    char text[640];
    snprintf(text, sizeof text, "%s", msg ? msg : "");
    a.message = text;
    hapsim_command_ack_t_publish(hs_net_bus_lcm(s->mbus), s->ch_ack, &a);
}

static void reset_limits(hs_server* s) {
    const hs_scene* sc = &s->w.scene;
    s->lim = hs_net_default_limits();
    s->lim.n_devices = sc->n_devices;
    s->lim.n_tools = sc->n_tools;
    if (sc->has_workspace) {
        memcpy(s->lim.workspace_min, sc->workspace_min, sizeof s->lim.workspace_min);
        memcpy(s->lim.workspace_max, sc->workspace_max, sizeof s->lim.workspace_max);
    }
}

// A new frame numbering after a rebuild: the sim's step counter restarts. handed: the new sim
// took the old one's rt loop over, so poses are answered from its last output until the new
// sim's first (not with zero force).
static void after_rebuild(hs_server* s, int keep, int handed) {
    if (!handed) {
        s->have_out = 0;
        forget_tool_outputs(s);
    }
    s->sim_step_base = keep ? s->frame_step : 0;
    if (!keep) {
        s->frame_step = 0;
        memset(s->w.u, 0, 3 * (size_t)s->w.mesh->n_nodes * sizeof(double));
        memset(s->w.v, 0, 3 * (size_t)s->w.mesh->n_nodes * sizeof(double));
    }
    if (s->w.visual) {
        const double* x0 = s->w.x0r;
        for (int i = 0; i < s->w.n_vis; ++i)
            for (int k = 0; k < 3; ++k)
                s->w.cur[3 * i + k] =
                    (float)(x0[3 * s->w.vis_nodes[i] + k] + s->w.u[3 * s->w.vis_nodes[i] + k]);
    }
    memset(s->st_prev, 0, sizeof *s->st_prev);
    publish_keyframe(s);
}

static const char* const srv_state_name[] = {"RUNNING", "PAUSED", "PAUSED_CUT"};
static const char* const srv_event_name[] = {"PAUSE",         "RESUME",     "SIM_STOPPED",
                                             "SIM_HELD",      "SWAPPED",    "ESTOP",
                                             "ESTOP_RELEASE", "LOAD_BEGIN", "LOAD_END"};

// The server's one state transition (docs/server.md, "States"). The caller has done the work
// (stopped, held or started the sim); this checks that the event may happen in the current
// state and with the world as it is, and sets the state. A refused transition is a bug in the
// caller: it is said on stderr and the state stays. path: EV_LOAD_BEGIN's scene.
static int srv_transition(hs_server* s, srv_event ev, const char* path) {
    srv_state from = s->state, to = from;
    int ok = 1;
    switch (ev) {
    case EV_PAUSE: // from RUNNING only (PAUSE in a paused state does nothing); the caller took
                   // the model to ramp down and its time before stopping the sim
        ok = from == SRV_RUNNING && !s->w.sim;
        to = s->w.held ? SRV_PAUSED_CUT : SRV_PAUSED;
        break;
    case EV_RESUME:
        ok = from != SRV_RUNNING && !s->w.held;
        to = SRV_RUNNING;
        break;
    case EV_SIM_STOPPED:
        ok = !s->w.sim && !s->w.held;
        to = SRV_PAUSED;
        break;
    case EV_SIM_HELD:
        ok = from == SRV_RUNNING && !s->w.sim && s->w.held;
        to = SRV_PAUSED_CUT;
        break;
    case EV_SWAPPED: // a new world, uncut and not started: it runs unless stopped again
        ok = !s->w.held && !s->w.cut_made;
        to = SRV_RUNNING;
        break;
    case EV_ESTOP:
        s->estop = 1;
        return 0;
    case EV_ESTOP_RELEASE:
        if (s->estop) s->estop_release_ns = hs_now_ns();
        s->estop = 0;
        return 0;
    case EV_LOAD_BEGIN:
        ok = !s->loading;
        if (ok) s->loading = path ? path : "(no path)";
        break;
    case EV_LOAD_END:
        ok = s->loading != NULL;
        s->loading = NULL;
        break;
    }
    if (!ok) {
        fprintf(stderr, "hapsim-server: internal: event %s refused in state %s%s\n",
                srv_event_name[ev], srv_state_name[from], s->loading ? " (loading)" : "");
        return -1;
    }
    if (ev == EV_SIM_STOPPED || ev == EV_SIM_HELD) { // no model to ramp down from
        s->pause_model = zero_model();
        s->pause_ns = hs_now_ns();
    }
    s->state = to;
    return 0;
}

// Stop the world's sim keeping its state, and pause with zero force: RESUME rebuilds it (a
// reset kept paused, or a sim that would not start, for RESUME to retry).
static void pause_stopped(hs_server* s) {
    world_sim_stop(&s->w);
    srv_transition(s, EV_SIM_STOPPED, NULL);
}

// Start the stopped sim of a world found cut (it cannot be rebuilt); one that will not start is
// kept paused for RESUME to retry.
static void restart_cut_sim(hs_server* s) {
    world* w = &s->w;
    hs_err e = {0};
    if (hs_haptic_sim_start(w->sim, &e) == HS_OK) return;
    world_save_state(w);
    w->held = w->sim;
    w->sim = NULL;
    srv_transition(s, EV_SIM_HELD, NULL);
}

// Rebuild the running sim from w.def; keep: carry the body state over. Paused: rebuild later.
static hs_status rebuild_sim(hs_server* s, int keep, hs_err* err) {
    world* w = &s->w;
    if (!w->haptics) return HS_OK;
    if (w->sim && w->cutting && hs_haptic_sim_topology_version(w->sim) != w->cut_seen)
        apply_cut(s);                        // a cut not yet passed on counts too
    if (w->cut_made) return refuse_cut(err); // before stopping the sim, which could not return
    if (srv_paused(s)) {
        if (!keep) after_rebuild(s, 0, 0); // at rest now: say so (a keyframe), not at the resume
        return HS_OK;
    }
    if (w->sim && w->cutting) {
        // A cut can land between the look above and the stop: look again once stopped. If one
        // did, the same sim goes on with it (a stopped sim starts again) and the rebuild is
        // refused, as for a cut seen before.
        hs_haptic_sim_stop(w->sim);
        if (hs_haptic_sim_topology_version(w->sim) != w->cut_seen) {
            apply_cut(s);
            restart_cut_sim(s);
            return refuse_cut(err);
        }
    }
    world_sim_stop(w);
    if (!keep) {
        memset(w->u, 0, 3 * (size_t)w->mesh->n_nodes * sizeof(double));
        memset(w->v, 0, 3 * (size_t)w->mesh->n_nodes * sizeof(double));
    }
    hs_status st = world_sim_create(w, keep, err);
    if (st == HS_OK) st = hs_haptic_sim_start(w->sim, err);
    after_rebuild(s, keep, 0);
    return st;
}

static int loader_begin(hs_server* s, const char* path, const hs_scene* from,
                        const hs_net_command* c, int keep);
static int swap_world(hs_server* s, world* nw, int reset, char* msg, size_t cap);

static int set_param(hs_server* s, const hs_net_command* c, char* msg, size_t cap) {
    const char* name = hs_net_command_arg(c, "name");
    double v = c->number;
    world* w = &s->w;
    hs_haptic_sim_def d = w->def;
    hs_scene sc = w->scene;
    const hapsim_param_info* p = hapsim_param_find(name);
    if (!p || !hapsim_param_in_range(p, v)) {
        s->params_refused++;
        if (!p) {
            int n;
            const hapsim_param_info* t = hapsim_params(&n);
            size_t l = (size_t)snprintf(msg, cap, "unknown parameter '%s' (known:", name);
            for (int i = 0; i < n && l < cap; ++i)
                l += (size_t)snprintf(msg + l, cap - l, " %s", t[i].name);
            if (l < cap) snprintf(msg + l, cap - l, ")");
        } else {
            snprintf(msg, cap, "%s = %g out of range: %s%g .. %g%s%s", name, v,
                     p->min_open ? "above " : "", p->min, p->max, p->unit[0] ? " " : "", p->unit);
        }
        return HAPSIM_COMMAND_ACK_T_STATUS_INVALID;
    }
    if (!strcmp(name, "probe_radius_m")) {
        d.probe.radius_m = v;
        for (int t = 0; t < sc.n_tools; ++t)
            if (sc.tools[t].kind == HS_TOOL_PROBE) sc.tools[t].radius = v;
    } else if (!strcmp(name, "force_max_n")) {
        d.safety.max_force_n = v;
        sc.force_max_n = v;
    } else if (!strcmp(name, "force_rate_max_n_per_s")) {
        d.safety.max_rate_n_s = v;
        sc.force_rate_max = v;
    } else if (!strcmp(name, "watchdog_ms")) {
        d.safety.watchdog_timeout_s = v * 1e-3;
        sc.watchdog_s = v * 1e-3;
    } else if (!strcmp(name, "youngs_pa")) {
        d.body.fem.material.youngs_pa = v;
        sc.material.youngs_pa = v;
    } else { // poisson
        d.body.fem.material.poisson = v;
        sc.material.poisson = v;
    }
    if (!w->haptics) { // after the name check: an unknown name is INVALID in any scene
        snprintf(msg, cap, "haptics are off in this scene: no run-time parameters");
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    // Force limits go to the running sim (and a paused cut one) without a rebuild: no gap in
    // the force, and they can be changed after a cut, when the sim cannot be rebuilt.
    if (!p->rebuilds) {
        hs_haptic_sim* live[2] = {w->sim, w->held};
        for (int k = 0; k < 2; ++k)
            if (live[k] && hs_haptic_sim_set_safety(live[k], &d.safety) != HS_OK) {
                snprintf(msg, cap, "%s = %g: limits refused by the simulation", name, v);
                return HAPSIM_COMMAND_ACK_T_STATUS_INVALID;
            }
        w->def = d;
        w->scene = sc;
        snprintf(msg, cap, "%s = %g", name, v);
        return HAPSIM_COMMAND_ACK_T_STATUS_OK;
    }
    // A running simulation on an uncut mesh: the scene as set is built beside it on the loader
    // thread, and the body's state goes over at the swap (finish_load). Otherwise (paused: it
    // is rebuilt at the resume; or no thread) here.
    if (w->sim && w->cutting && hs_haptic_sim_topology_version(w->sim) != w->cut_seen)
        apply_cut(s); // a cut not yet passed on counts too
    if (w->cut_made) {
        hs_err e = {0};
        refuse_cut(&e);
        snprintf(msg, cap, "%s", e.msg);
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    if (w->sim && !srv_paused(s)) {
        snprintf(s->load.ok_msg, sizeof s->load.ok_msg, "%s = %g", name, v);
        if (loader_begin(s, NULL, &sc, c, 1) == 0) return LOAD_STARTED;
    }
    hs_haptic_sim_def old_d = w->def;
    hs_scene old_sc = w->scene;
    w->def = d;
    w->scene = sc;
    hs_err err = {0};
    if (rebuild_sim(s, 1, &err) != HS_OK) {
        w->def = old_d;
        w->scene = old_sc;
        hs_err e2 = {0};
        if (rebuild_sim(s, 1, &e2) != HS_OK) { // no sim runs: PAUSED (not RUNNING without one)
            pause_stopped(s);
            snprintf(msg, cap,
                     "%.250s; the old simulation did not start either (%.250s): paused, "
                     "RESUME retries",
                     err.msg, e2.msg);
            return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
        }
        snprintf(msg, cap, "%s", err.msg);
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    snprintf(msg, cap, "%s = %g", name, v);
    return HAPSIM_COMMAND_ACK_T_STATUS_OK;
}

// Swap the built world nw in for the running one and start it; the final ack's status.
// reset: nw is the running scene rebuilt at rest (RESET), not a LOAD_SCENE.
static int swap_world(hs_server* s, world* nw, int reset, char* msg, size_t cap) {
    hs_err err = {0};
    int stay_paused = reset && srv_paused(s); // a reset does not resume; a new scene starts
    world old = s->w; // freed once the new sim runs: the device meanwhile holds its last model
    if (old.sim) hs_haptic_sim_stop(old.sim);
    // A reset rebuilds the same scene: its rt loop goes on from the old one's (no gap, no ramp).
    // Not after a cut (the old contact and blade force belong to the cut body), nor for a new
    // scene: their force ramps in from zero.
    // A cut the sim made after the net loop last looked counts too (found in review, by reading:
    // a window of one loop pass during a drag).
    int cut = old.cut_made ||
              (old.sim && old.cutting && hs_haptic_sim_topology_version(old.sim) != old.cut_seen);
    int handed = reset && !stay_paused && old.sim && !cut && nw->sim &&
                 hs_haptic_sim_take_over(nw->sim, old.sim, &err) == HS_OK;
    memset(&err, 0, sizeof err);
    s->w = *nw;
    memset(nw, 0, sizeof *nw);
    srv_transition(s, EV_SWAPPED, NULL);
    reset_limits(s);
    s->topo_version++;
    s->last_cut_steps = 0; // the new sim counts its cut steps from 0
    if (stay_paused) {     // at rest, paused: RESUME builds the sim from this state
        world_destroy(&old);
        pause_stopped(s);
        publish_topology(s);
        after_rebuild(s, 0, 0);
        snprintf(msg, cap, "reset: %s rebuilt at rest (%d nodes), paused", s->w.scene.name,
                 s->w.mesh->n_nodes);
        return HAPSIM_COMMAND_ACK_T_STATUS_OK;
    }
    int started = !s->w.sim || hs_haptic_sim_start(s->w.sim, &err) == HS_OK;
    world_destroy(&old);
    if (!started) pause_stopped(s); // the old world is gone: paused, so RESUME can retry
    publish_topology(s); // before the keyframe (after_rebuild), which a client matches to it
    after_rebuild(s, 0, handed && started);
    if (!started) {
        snprintf(msg, cap,
                 "%s %.100s but its simulation did not start (%.300s): paused, "
                 "RESUME retries",
                 reset ? "rebuilt" : "loaded", s->w.scene.name, err.msg);
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    if (reset)
        snprintf(msg, cap, "reset: %s rebuilt at rest (%d nodes)", s->w.scene.name,
                 s->w.mesh->n_nodes);
    else
        snprintf(msg, cap, "loaded %s (%d nodes); buses and prefix unchanged", s->w.scene.name,
                 s->w.mesh->n_nodes);
    return HAPSIM_COMMAND_ACK_T_STATUS_OK;
}

// Load (sc NULL: from path) and build a scene on the net thread, then swap: where no loader
// thread could be started. Built while the old world still exists: a scene that fails leaves
// the running simulation as it was.
static int load_scene(hs_server* s, const char* path, const hs_scene* from, char* msg, size_t cap) {
    srv_transition(s, EV_LOAD_BEGIN, path);
    publish_status(s, hs_now_ns()); // the net loop stands still now: say so first
    srv_transition(s, EV_LOAD_END, NULL);
    hs_scene sc;
    hs_err err = {0};
    if (from)
        sc = *from;
    else if (hs_scene_load(path, &sc, &err) != HS_OK) {
        snprintf(msg, cap, "%s", err.msg);
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    world nw;
    if (world_create(&sc, s->opt.realtime, &nw, &err) != HS_OK) {
        snprintf(msg, cap, "%s", err.msg);
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    return swap_world(s, &nw, from != NULL, msg, cap);
}

static void* loader_main(void* arg) {
    loader* L = arg;
    L->st = L->have_sc ? HS_OK : hs_scene_load(L->path, &L->sc, &L->err);
    if (L->st == HS_OK) L->st = world_create(&L->sc, L->realtime, &L->nw, &L->err);
    atomic_store(&L->done, 1);
    return NULL;
}

// Start building a world on the loader thread: LOAD_SCENE (path), RESET (from: the running
// scene as set, at rest) or SET_PARAM (from, keep: the body's state goes on at the swap). The
// net loop goes on (forces from the running scene, status saying LOADING, e-stops) and
// finish_load swaps it in. 0 when started, -1 when no thread could be started.
static int loader_begin(hs_server* s, const char* path, const hs_scene* from,
                        const hs_net_command* c, int keep) {
    loader* L = &s->load;
    snprintf(L->path, sizeof L->path, "%s", from ? from->path : path ? path : "");
    L->have_sc = from != NULL;
    if (from) L->sc = *from;
    L->keep = keep;
    L->request_id = c->request_id;
    L->kind = c->kind;
    L->realtime = s->opt.realtime;
    L->st = HS_OK;
    memset(&L->err, 0, sizeof L->err);
    atomic_store(&L->done, 0);
    srv_transition(s, EV_LOAD_BEGIN, L->path);
    publish_status(s, hs_now_ns());
    if (pthread_create(&L->th, NULL, loader_main, L) == 0) {
        L->active = 1;
        return 0;
    }
    srv_transition(s, EV_LOAD_END, NULL);
    return -1;
}

// LOAD_SCENE or RESET: LOAD_STARTED (the final ack follows from finish_load), else the final
// status (the build ran here: no thread could be started).
static int load_scene_start(hs_server* s, const char* path, const hs_scene* from,
                            const hs_net_command* c, char* msg, size_t cap) {
    if (loader_begin(s, path, from, c, 0) == 0) return LOAD_STARTED;
    return load_scene(s, s->load.path, from, msg, cap);
}

// SET_PARAM's swap: the running body's state goes on in nw (the scene as set). A cut made during
// the build refuses it and the cut simulation goes on untouched; so does a mesh file that no
// longer holds the running mesh (nw read it again).
static int swap_keep(hs_server* s, world* nw, char* msg, size_t cap) {
    world* w = &s->w;
    if (!w->sim || srv_paused(s)) {
        snprintf(msg, cap, "the simulation stopped during the rebuild: not applied");
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    hs_err e = {0};
    if (w->cutting && hs_haptic_sim_topology_version(w->sim) != w->cut_seen) apply_cut(s);
    if (w->cut_made) { // before stopping: the running sim goes on as it is
        refuse_cut(&e);
        snprintf(msg, cap, "%s", e.msg);
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    // x0r is the net thread's copy of the uncut rest positions; a cutting sim's own tets may
    // be changing under its deformation thread, so they are compared only without cutting.
    const hs_mesh *a = w->mesh, *b = nw->mesh;
    if (b->n_nodes != a->n_nodes || b->n_tets != a->n_tets ||
        memcmp(nw->x0r, w->x0r, 3 * (size_t)a->n_nodes * sizeof(double)) != 0 ||
        (!w->cutting && memcmp(b->tets, a->tets, 4 * (size_t)a->n_tets * sizeof(int)) != 0)) {
        snprintf(msg, cap, "%.400s no longer holds the running mesh: not applied (RESET reads it)",
                 w->scene.mesh_path);
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    hs_haptic_sim_stop(w->sim);
    // A cut can land between the look above and the stop: the same sim goes on with it.
    if (w->cutting && hs_haptic_sim_topology_version(w->sim) != w->cut_seen) apply_cut(s);
    if (w->cut_made) {
        refuse_cut(&e);
        snprintf(msg, cap, "%s", e.msg);
        restart_cut_sim(s);
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    world_save_state(w);
    // The new sim takes the body's state and the rt loop's (no gap and no ramp in the force).
    if (nw->sim && (hs_body_set_state(hs_haptic_sim_body(nw->sim), w->u, w->v) != HS_OK ||
                    hs_haptic_sim_take_over(nw->sim, w->sim, &e) != HS_OK)) {
        snprintf(msg, cap, "the new simulation refused the body's or the rt state: not applied");
        if (hs_haptic_sim_start(w->sim, &e) != HS_OK) { // as a failed rebuild: paused
            pause_stopped(s);
        }
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    size_t n3 = 3 * (size_t)w->mesh->n_nodes;
    memcpy(nw->u, w->u, n3 * sizeof(double));
    memcpy(nw->v, w->v, n3 * sizeof(double));
    world old = *w; // freed once the new sim runs: the device meanwhile holds its last model
    s->w = *nw;
    memset(nw, 0, sizeof *nw);
    reset_limits(s);
    s->last_cut_steps = 0; // the new sim counts its cut steps from 0
    int started = !s->w.sim || hs_haptic_sim_start(s->w.sim, &e) == HS_OK;
    world_destroy(&old);
    if (!started) {
        pause_stopped(s);
        snprintf(msg, cap,
                 "%s applied but the simulation did not start (%.300s): paused, RESUME retries",
                 s->load.ok_msg, e.msg);
        after_rebuild(s, 1, 0);
        return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    after_rebuild(s, 1, s->w.sim != NULL);
    snprintf(msg, cap, "%s", s->load.ok_msg);
    return HAPSIM_COMMAND_ACK_T_STATUS_OK;
}

static void run_command(hs_server* s, const hs_net_command* c, int pending_sent);

// Join the loader (waiting if it is still building), swap its world in and send the final ack.
// stopping: the server is shutting down; the built world is dropped and the ack says so.
static void finish_load(hs_server* s, int stopping) {
    loader* L = &s->load;
    if (!L->active) return;
    // A stop always stops: a build blocked in the kernel (a mesh on a hung mount) is left
    // behind after a bounded wait, with the memory it writes to.
    for (int i = 0; stopping && i < LOADER_STOP_WAIT_MS / 10 && !atomic_load(&L->done); ++i) {
        struct timespec ts = {0, 10000000};
        nanosleep(&ts, NULL);
    }
    if (stopping && !atomic_load(&L->done)) {
        pthread_detach(L->th);
        L->active = 0;
        L->abandoned = 1;
        srv_transition(s, EV_LOAD_END, NULL);
        fprintf(stderr,
                "hapsim-server: the load of %s had not returned after %d ms (a file that "
                "blocks?): left behind\n",
                L->path, LOADER_STOP_WAIT_MS);
        if (s->mbus)
            send_ack(s, L->request_id, L->kind, HAPSIM_COMMAND_ACK_T_STATUS_FAILED,
                     "the server stopped; the load had not returned (a file that blocks?)");
        return;
    }
    pthread_join(L->th, NULL);
    L->active = 0;
    srv_transition(s, EV_LOAD_END, NULL);
    char msg[600];
    int st = HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    if (L->st != HS_OK)
        snprintf(msg, sizeof msg, "%s", L->err.msg);
    else if (stopping)
        snprintf(msg, sizeof msg, "the server stopped before %.400s was swapped in", L->path);
    else
        st = L->keep ? swap_keep(s, &L->nw, msg, sizeof msg)
                     : swap_world(s, &L->nw, L->have_sc, msg, sizeof msg);
    world_destroy(&L->nw); // zeroed by the swap; a dropped build is freed here
    hs_net_dedup_set_status(&s->cst.dedup, L->request_id, st);
    if (s->mbus) send_ack(s, L->request_id, L->kind, st, msg);
    // The commands that came meanwhile, in order, until one starts another load (the rest then
    // wait for that one).
    while (L->q_head < L->q_len && !L->active) {
        const hs_net_command* c = &L->queued[L->q_head++];
        if (stopping) {
            hs_net_dedup_set_status(&s->cst.dedup, c->request_id,
                                    HAPSIM_COMMAND_ACK_T_STATUS_FAILED);
            if (s->mbus)
                send_ack(s, c->request_id, c->kind, HAPSIM_COMMAND_ACK_T_STATUS_FAILED,
                         "the server stopped before it ran");
            continue;
        }
        run_command(s, c, 1);
    }
    // What waits for a load started from the queue moves to the front: full room for more.
    memmove(L->queued, L->queued + L->q_head, (size_t)(L->q_len - L->q_head) * sizeof *L->queued);
    L->q_len -= L->q_head;
    L->q_head = 0;
}

static int execute(hs_server* s, const hs_net_command* c, char* msg, size_t cap) {
    world* w = &s->w;
    hs_err err = {0};
    msg[0] = '\0';
    switch (c->kind) {
    case HAPSIM_COMMAND_T_KIND_RESET:
        // A running simulation, or a cut mesh (paused or not: it stays paused): the scene
        // (with its set parameters, on the mesh read again: uncut) is built at rest beside the
        // running one and swapped in. Paused uncut, or haptics off: nothing to build, only the
        // state to clear (rebuild_sim, which then meets no sim that could have cut).
        if (w->cut_made || (w->haptics && !srv_paused(s)))
            return load_scene_start(s, NULL, &w->scene, c, msg, cap);
        if (rebuild_sim(s, 0, &err) != HS_OK) {
            snprintf(msg, cap, "%s", err.msg);
            return HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
        }
        if (!w->haptics) publish_keyframe(s);
        return HAPSIM_COMMAND_ACK_T_STATUS_OK;
    case HAPSIM_COMMAND_T_KIND_PAUSE:
        if (srv_paused(s)) return HAPSIM_COMMAND_ACK_T_STATUS_OK;
        drain_outputs(s);
        s->pause_model = s->have_out ? s->out.model : zero_model();
        pause_tools(s);
        s->pause_ns = hs_now_ns();
        server_sim_pause(s);
        srv_transition(s, EV_PAUSE, NULL);
        return HAPSIM_COMMAND_ACK_T_STATUS_OK;
    case HAPSIM_COMMAND_T_KIND_RESUME:
        if (!srv_paused(s)) return HAPSIM_COMMAND_ACK_T_STATUS_OK;
        if (w->held) { // a cut world: its own sim goes on (step count and statistics too)
            w->sim = w->held;
            w->held = NULL;
            if (hs_haptic_sim_start(w->sim, &err) != HS_OK) {
                w->held = w->sim;
                w->sim = NULL;
                snprintf(msg, cap, "%s", err.msg);
                return HAPSIM_COMMAND_ACK_T_STATUS_FAILED; // still PAUSED_CUT
            }
            s->have_out = 0;
            forget_tool_outputs(s);
            hs_haptic_sim_stats_get(w->sim, s->st_prev); // status windows start at the resume
        } else if (w->haptics) {
            if (world_sim_create(w, 1, &err) != HS_OK ||
                hs_haptic_sim_start(w->sim, &err) != HS_OK) {
                snprintf(msg, cap, "%s", err.msg);
                return HAPSIM_COMMAND_ACK_T_STATUS_FAILED; // still PAUSED
            }
            s->have_out = 0;
            forget_tool_outputs(s);
            s->sim_step_base = s->frame_step;
            memset(s->st_prev, 0, sizeof *s->st_prev);
        }
        srv_transition(s, EV_RESUME, NULL);
        return HAPSIM_COMMAND_ACK_T_STATUS_OK;
    case HAPSIM_COMMAND_T_KIND_LOAD_SCENE:
        return load_scene_start(s, hs_net_command_arg(c, "path"), NULL, c, msg, cap);
    case HAPSIM_COMMAND_T_KIND_SET_PARAM:
        return set_param(s, c, msg, cap);
    case HAPSIM_COMMAND_T_KIND_ESTOP: {
        srv_transition(s, EV_ESTOP, NULL);
        hs_haptic_model z = zero_model();
        for (int d = 0; d < w->scene.n_devices && d < MAX_DEV; ++d)
            if (s->dev[d].seen && w->haptics) {
                memcpy(z.anchor_m, s->dev[d].pos, sizeof z.anchor_m);
                publish_force(s, d, &z, HAPSIM_TOOL_FORCE_T_STATE_STOPPED, s->dev[d].session, 0, 0,
                              0);
            }
        return HAPSIM_COMMAND_ACK_T_STATUS_OK;
    }
    case HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE:
        srv_transition(s, EV_ESTOP_RELEASE, NULL);
        return HAPSIM_COMMAND_ACK_T_STATUS_OK;
    case HAPSIM_COMMAND_T_KIND_REQUEST_TOPOLOGY:
        publish_topology(s);
        publish_keyframe(s);
        if (!w->visual) snprintf(msg, cap, "visual mesh is off in this scene");
        return HAPSIM_COMMAND_ACK_T_STATUS_OK;
    }
    snprintf(msg, cap, "unknown kind %d", c->kind);
    return HAPSIM_COMMAND_ACK_T_STATUS_INVALID;
}

static void on_command(const lcm_recv_buf_t* rb, const char* ch, void* user) {
    (void)ch;
    hs_server* s = user;
    hs_net_command c;
    int32_t prev = 0;
    hs_net_reject r = hs_net_validate_command(&s->cst, rb->data, rb->data_size, &c, &prev);
    if (r == HS_NET_REJ_DUPLICATE) {
        send_ack(s, c.request_id, c.kind, prev, "duplicate request_id: not executed again");
        return;
    }
    if (r != HS_NET_ACCEPT) {
        if (c.request_id != 0) {
            char why[300];
            snprintf(why, sizeof why, "%s%s%s", hs_net_reject_name(r), c.why ? ": " : "",
                     c.why ? c.why : "");
            send_ack(s, c.request_id, c.kind, HAPSIM_COMMAND_ACK_T_STATUS_INVALID, why);
        }
        return;
    }
    // Every command but the e-stop's two acts after a load in progress, on the new scene: it
    // is kept (PENDING) and runs at the swap. Past LOAD_QUEUE of them, the rest are refused.
    loader* L = &s->load;
    if (L->active && c.kind != HAPSIM_COMMAND_T_KIND_ESTOP &&
        c.kind != HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE) {
        if (L->q_len < LOAD_QUEUE) {
            L->queued[L->q_len++] = c;
            send_ack(s, c.request_id, c.kind, HAPSIM_COMMAND_ACK_T_STATUS_PENDING,
                     "runs when the scene being loaded is in");
        } else { // waiting here would stop the loop (poses, e-stops) until the build ends
            hs_net_dedup_set_status(&s->cst.dedup, c.request_id,
                                    HAPSIM_COMMAND_ACK_T_STATUS_FAILED);
            send_ack(s, c.request_id, c.kind, HAPSIM_COMMAND_ACK_T_STATUS_FAILED,
                     "busy: a scene is loading and 32 commands wait for it; send again (a new "
                     "request id) when it is in");
        }
        return;
    }
    run_command(s, &c, 0);
}

// Execute an accepted command and send its final ack; LOAD_SCENE sends a PENDING one first
// (unless one went out already) and its final one from finish_load.
static void run_command(hs_server* s, const hs_net_command* c, int pending_sent) {
    char msg[600];
    if (c->kind == HAPSIM_COMMAND_T_KIND_LOAD_SCENE && !pending_sent)
        send_ack(s, c->request_id, c->kind, HAPSIM_COMMAND_ACK_T_STATUS_PENDING, "loading");
    int st = execute(s, c, msg, sizeof msg);
    if (st == LOAD_STARTED) { // being built on the loader thread: finish_load acks it
        if (c->kind != HAPSIM_COMMAND_T_KIND_LOAD_SCENE && !pending_sent) // RESET, SET_PARAM
            send_ack(s, c->request_id, c->kind, HAPSIM_COMMAND_ACK_T_STATUS_PENDING,
                     c->kind == HAPSIM_COMMAND_T_KIND_RESET ? "building the scene at rest"
                                                            : "rebuilding the simulation");
        return;
    }
    hs_net_dedup_set_status(&s->cst.dedup, c->request_id, st);
    send_ack(s, c->request_id, c->kind, st, msg);
}

// ---------------------------------------------------------------------------------------------
// Life cycle

static hs_status channels(hs_server* s, hs_err* err) {
    const char* p = s->prefix;
    struct {
        char* out;
        const char* suffix;
    } t[] = {{s->ch_pose, HAPSIM_CH_TOOL_POSE},       {s->ch_force, HAPSIM_CH_TOOL_FORCE},
             {s->ch_topo, HAPSIM_CH_MESH_TOPOLOGY},   {s->ch_state, HAPSIM_CH_MESH_STATE},
             {s->ch_delta, HAPSIM_CH_MESH_DELTA},     {s->ch_tool, HAPSIM_CH_TOOL_STATE},
             {s->ch_cmd, HAPSIM_CH_COMMAND},          {s->ch_ack, HAPSIM_CH_COMMAND_ACK},
             {s->ch_status, HAPSIM_CH_SERVER_STATUS}, {s->ch_tevent, HAPSIM_CH_TOPOLOGY_EVENT}};
    for (size_t i = 0; i < sizeof t / sizeof t[0]; ++i)
        if (hapsim_channel_name(t[i].out, HAPSIM_CHANNEL_MAX, p, t[i].suffix) != 0)
            return hs_err_set(err, HS_ERR_INVALID, "--prefix '%s': too long", p);
    return HS_OK;
}

static int prefix_ok(const char* p) {
    size_t n = strlen(p);
    if (n >= HS_SCENE_PREFIX_MAX) return 0;
    for (size_t i = 0; i < n; ++i)
        if (!((p[i] >= 'A' && p[i] <= 'Z') || (p[i] >= '0' && p[i] <= '9') || p[i] == '_'))
            return 0;
    return 1;
}

hs_status hs_server_create(const hs_server_opts* opts, hs_server** out, hs_err* err) {
    *out = NULL;
    hs_scene sc;
    hs_status st = hs_scene_load(opts->scene_path, &sc, err);
    if (st != HS_OK) return st;
    // A longer URL would be cut to fit (losing e.g. its recv_buf_size): refuse it.
    if (opts->haptic_url && strlen(opts->haptic_url) >= sizeof sc.haptic_url)
        return hs_err_set(err, HS_ERR_INVALID, "--haptic-url: longer than %zu bytes",
                          sizeof sc.haptic_url - 1);
    if (opts->mesh_url && strlen(opts->mesh_url) >= sizeof sc.mesh_url)
        return hs_err_set(err, HS_ERR_INVALID, "--mesh-url: longer than %zu bytes",
                          sizeof sc.mesh_url - 1);
    if (opts->prefix && !prefix_ok(opts->prefix))
        return hs_err_set(err, HS_ERR_INVALID, "--prefix '%s': must match [A-Z0-9_]{0,47}",
                          opts->prefix);
    hs_server* s = hs_calloc(1, sizeof *s);
    if (!s) return hs_err_set(err, HS_ERR_NOMEM, "out of memory");
    s->opt = *opts;
    snprintf(s->haptic_url, sizeof s->haptic_url, "%s",
             opts->haptic_url ? opts->haptic_url : sc.haptic_url);
    snprintf(s->mesh_url, sizeof s->mesh_url, "%s", opts->mesh_url ? opts->mesh_url : sc.mesh_url);
    snprintf(s->prefix, sizeof s->prefix, "%s", opts->prefix ? opts->prefix : sc.prefix);
    if (hs_scene_same_bus(s->haptic_url, s->mesh_url)) {
        st = hs_err_set(err, HS_ERR_INVALID,
                        "haptic URL '%s' and mesh URL '%s' are the same bus (group and port): use "
                        "two buses (different ports)",
                        s->haptic_url, s->mesh_url);
        goto fail;
    }
    st = channels(s, err);
    if (st != HS_OK) goto fail;
    s->rmem_default = hs_net_rmem_default();
    s->rmem_max = hs_net_rmem_max();
    s->st_prev = hs_calloc(1, sizeof *s->st_prev);
    s->st_now = hs_calloc(1, sizeof *s->st_now);
    s->h_net = hs_calloc(1, sizeof *s->h_net);
    s->h_step = hs_calloc(1, sizeof *s->h_step);
    s->h_handle = hs_calloc(1, sizeof *s->h_handle);
    s->h_diff = hs_calloc(1, sizeof *s->h_diff);
    s->h_simper = hs_calloc(1, sizeof *s->h_simper);
    if (!s->st_prev || !s->st_now || !s->h_net || !s->h_step || !s->h_handle || !s->h_diff ||
        !s->h_simper) {
        st = hs_err_set(err, HS_ERR_NOMEM, "out of memory");
        goto fail;
    }
    for (int d = 0; d < MAX_DEV; ++d) {
        s->dev[d].lat = hs_calloc(1, sizeof(hs_rt_hist));
        if (!s->dev[d].lat) {
            st = hs_err_set(err, HS_ERR_NOMEM, "out of memory");
            goto fail;
        }
    }
    // Buses first (LCM's fds stay low), then the world.
    char hurl[HS_SCENE_URL_MAX + 40];
    haptic_bus_url(s, hurl, sizeof hurl);
    st = hs_net_bus_create(hurl, &s->hbus, err);
    if (st != HS_OK) goto fail;
    st = hs_net_bus_create(s->mesh_url, &s->mbus, err);
    if (st != HS_OK) goto fail;
    s->kdrop0[0] = hs_net_bus_kernel_drops(s->hbus);
    s->kdrop0[1] = hs_net_bus_kernel_drops(s->mbus);
    st = world_create(&sc, opts->realtime, &s->w, err);
    if (st != HS_OK) goto fail;
    reset_limits(s);
    hs_net_pose_state_init(&s->pst);
    hs_net_command_state_init(&s->cst);
    lcm_subscription_t* ps = lcm_subscribe(hs_net_bus_lcm(s->hbus), s->ch_pose, on_pose, s);
    lcm_subscription_t* cs = lcm_subscribe(hs_net_bus_lcm(s->mbus), s->ch_cmd, on_command, s);
    if (!ps || !cs) {
        st = hs_err_set(err, HS_ERR_INVALID, "cannot subscribe to %s / %s", s->ch_pose, s->ch_cmd);
        goto fail;
    }
    lcm_subscription_set_queue_capacity(ps, POSE_QUEUE);
    lcm_subscription_set_queue_capacity(cs, COMMAND_QUEUE);
    s->topo_version = 1;
    *out = s;
    return HS_OK;
fail:
    hs_server_destroy(&s);
    return st;
}

void hs_server_destroy(hs_server** ps) {
    if (!ps || !*ps) return;
    hs_server* s = *ps;
    finish_load(s, 1);
    const int keep = s->load.abandoned; // the abandoned loader may still write into s->load
    world_destroy(&s->w);
    hs_net_bus_destroy(&s->hbus);
    hs_net_bus_destroy(&s->mbus);
    hs_free(s->st_prev);
    hs_free(s->st_now);
    hs_free(s->h_net);
    hs_free(s->h_step);
    hs_free(s->h_handle);
    hs_free(s->h_diff);
    hs_free(s->h_simper);
    for (int d = 0; d < MAX_DEV; ++d) hs_free(s->dev[d].lat);
    if (!keep) hs_free(s);
    *ps = NULL;
}

void hs_server_print_summary(hs_server* s) {
    const world* w = &s->w;
    const hs_scene* sc = &w->scene;
    const hs_mesh* m = w->mesh;
    printf("hapsim-server: scene '%s' (%s)\n", sc->name, sc->path);
    printf("  mesh     %s: %d nodes, %d tets, %d surface nodes, %d fixed\n", sc->mesh_path,
           m->n_nodes, m->n_tets, m->n_surf_nodes, w->n_fixed);
    printf("  quality  smallest dihedral angle %.3g deg, worst aspect %.3g, mean %.3g (1 = "
           "regular), %d piece(s)%s\n",
           m->report.min_dihedral_deg, m->report.max_aspect, m->report.mean_aspect,
           m->report.components,
           m->report.min_dihedral_deg < 5 ? "; slivers: remesh with hapsim-mesh tet --size ..."
                                          : "");
    printf("  model    %s, E %g Pa, nu %g, %g kg/m^3; deformation up to %g Hz\n",
           hs_scene_model_name(sc->model), sc->material.youngs_pa, sc->material.poisson,
           sc->material.density_kg_m3, sc->sim_hz);
    if (w->haptics) {
        hs_haptic_sim_stats st;
        hs_haptic_sim_stats_get(w->sim, &st);
        if (w->def.auto_solver)
            printf("  solver   auto (%s): starts with %s (a factorisation %.1f ms of the %.1f ms "
                   "step), then the most accurate of %s that keeps %g Hz, switching as the load "
                   "changes\n",
                   sc->exact_tangent ? "exact tangent" : "equilibrium", solver_name(st.solver),
                   st.factor_ms, 1e3 / sc->sim_hz,
                   sc->exact_tangent ? "direct, pcg" : "direct, pcg, warped", sc->sim_hz);
        else
            printf("  solver   %s (%s)\n", solver_name(st.solver),
                   sc->solver != HS_SCENE_SOLVER_AUTO ? "the scene's"
                   : sc->model != HS_MODEL_COROTATED  ? "auto: the direct solver of this model"
                                                      : "auto: warped, the cutting scene's");
        char tool[64];
        if (w->cutting && w->cdef.probe_when_released)
            snprintf(tool, sizeof tool, "scalpel, released: probe radius %g mm",
                     w->def.probe.radius_m * 1e3);
        else if (w->cutting)
            snprintf(tool, sizeof tool, "scalpel (no probe sphere)");
        else
            snprintf(tool, sizeof tool, "probe radius %g mm", w->def.probe.radius_m * 1e3);
        s->comp_state_seen = st.comp_state; // a later change is printed by hs_server_run
        if (st.comp_state == 0)
            printf("  haptics  rt %g Hz, %s, force clamp %g N, watchdog %g ms; "
                   "compliance set-up %.1f ms\n",
                   sc->haptic_hz, tool, sc->force_max_n, sc->watchdog_s * 1e3, st.setup_ms);
        else
            printf("  haptics  rt %g Hz, %s, force clamp %g N, watchdog %g ms; compliance "
                   "set-up running in the background: zero force until it is ready\n",
                   sc->haptic_hz, tool, sc->force_max_n, sc->watchdog_s * 1e3);
        char note[256];
        if (edge_note(w, note, sizeof note)) printf("  warning  %s\n", note);
    } else {
        printf("  haptics  off (%s): no rt thread, poses validated and counted only\n",
               w->probe_note ? w->probe_note : "scene");
    }
    if (w->cutting) {
        const hs_scene_tool* tl = &sc->tools[w->scalpel];
        double l = 0;
        for (int k = 0; k < 3; ++k)
            l += (tl->blade_b[k] - tl->blade_a[k]) * (tl->blade_b[k] - tl->blade_a[k]);
        printf("  cutting  scalpel (tool %d, blade %.1f mm) cuts while button 0 is held; "
               "resistance %g N/m of edge cut, cap %g N; pieces cut free %s; topology events on "
               "%s\n",
               w->scalpel, sqrt(l) * 1e3, w->cdef.toughness_n_m, w->cdef.max_force_n,
               w->cdef.cut.fragment == HS_CUT_FRAGMENT_FIX ? "fall" : "are dropped", s->ch_tevent);
    }
    if (w->visual) {
        hapsim_mesh_topology_t t;
        fill_topology(s, &t);
        printf("  visual   %d nodes, %d triangles, %g Hz deltas, keyframe + topology every 1 s "
               "(keyframe %lld bytes, topology %d)\n",
               w->n_vis, w->n_tri_idx / 3, sc->visual_hz,
               (long long)hs_net_keyframe_bytes(w->n_vis, 0),
               hapsim_mesh_topology_t_encoded_size(&t));
    } else
        printf("  visual   off: no mesh messages\n");
    printf("  buses    haptic %s  (%s in, %s out)\n", s->haptic_url, s->ch_pose, s->ch_force);
    printf("           mesh   %s  (%s in; mesh, tool state, acks, status out)\n", s->mesh_url,
           s->ch_cmd);
    if (w->sim) {
        hs_haptic_sim_stats st;
        hs_haptic_sim_stats_get(w->sim, &st);
        printf("  threads  rt (%s%s), deformation, net\n",
               (st.rt.obtained & HS_RT_SCHED_FIFO) ? "SCHED_FIFO" : "ordinary scheduling",
               (st.rt.obtained & HS_RT_MLOCKED) ? ", mlockall" : ", no mlockall");
        if (s->opt.realtime && !(st.rt.obtained & HS_RT_SCHED_FIFO))
            printf("  note     --realtime: SCHED_FIFO not granted (needs CAP_SYS_NICE or an "
                   "rtprio limit)\n");
    } else {
        printf("  threads  net only\n");
    }
    printf("  running; SIGINT/SIGTERM stops%s\n", s->opt.duration_s > 0 ? " (or --duration)" : "");
    fflush(stdout);
}

static uint64_t retried_total(const hs_server* s) {
    return s->cst.counters.rejected[HS_NET_REJ_DUPLICATE];
}

// Messages refused, for the console: a command's retried copy (same request id) is answered with
// its first ack, not an error, so it is counted apart (status still lists it as "duplicate").
static uint64_t rejected_total(const hs_server* s) {
    return hs_net_counters_rejected(&s->pst.counters) + hs_net_counters_rejected(&s->cst.counters) -
           retried_total(s);
}

static void live_line(hs_server* s, int64_t t) {
    world* w = &s->w;
    double rate = 0, jit = 0, p50 = 0, p99 = 0, sim_hz = 0;
    long long over = 0;
    const char* solver = "-";
    int deep = 0;
    if (w->sim) {
        hs_haptic_sim_stats st;
        hs_haptic_sim_stats_get(w->sim, &st);
        if (s->live_prev_t)
            rate =
                (double)(st.rt.ticks - s->live_prev_ticks) / ((double)(t - s->live_prev_t) * 1e-9);
        s->live_prev_ticks = st.rt.ticks;
        s->live_prev_t = t;
        jit = hs_rt_hist_quantile_us(&st.rt.period_err, 0.99);
        p50 = st.step_ms_p50;
        p99 = st.step_ms_p99;
        sim_hz = st.sim_hz_target;
        over = (long long)st.step_overruns;
        solver = solver_name(st.solver);
        deep = st.deep_loops > s->live_prev_deep; // pressed beyond the validated depth lately
        s->live_prev_deep = st.deep_loops;
    }
    uint64_t rej = rejected_total(s);
    fprintf(stderr,
            "\rhapsim-server: rt %6.1f Hz  jitter p99 %5.0f us  force %5.2f N  sim %s %4.1f Hz "
            "step p50/p99 %5.2f/%5.2f ms overruns %lld  poses %lld  rejected %llu%s%s   ",
            rate, jit, norm3(s->dev[0].force), solver, sim_hz, p50, p99, over,
            (long long)s->poses_total, (unsigned long long)rej,
            deep ? "  TOO DEEP (force unchecked)" : "",
            s->estop        ? "  E-STOP"
            : srv_paused(s) ? "  PAUSED"
                            : "");
    fflush(stderr);
}

static int handle_ready(hs_net_bus* b) {
    lcm_t* l = hs_net_bus_lcm(b);
    struct pollfd p = {lcm_get_fileno(l), POLLIN, 0};
    for (int i = 0; i < HANDLE_BATCH; ++i) {
        if (poll(&p, 1, 0) <= 0 || !(p.revents & POLLIN)) return 0;
        if (lcm_handle(l) != 0) return -1;
    }
    return 0;
}

static void count_foreign(const lcm_recv_buf_t* rb, const char* ch, void* user) {
    (void)rb;
    (void)ch;
    ++*(int*)user;
}

// Another server on these buses and prefix would answer the same devices: a driver would get
// two interleaved force streams. Listen before serving: a running server publishes its
// topology every KEYFRAME_NS and its status, and forces while a device is live. 0: alone;
// 1: another one is there (err set); -1: stopped meanwhile.
static int another_server(hs_server* s, hs_err* err) {
    int heard[3] = {0, 0, 0};
    lcm_t* mb = hs_net_bus_lcm(s->mbus);
    lcm_t* hb = hs_net_bus_lcm(s->hbus);
    lcm_subscription_t* sub[3] = {lcm_subscribe(mb, s->ch_topo, count_foreign, &heard[0]),
                                  lcm_subscribe(mb, s->ch_status, count_foreign, &heard[1]),
                                  lcm_subscribe(hb, s->ch_force, count_foreign, &heard[2])};
    const int64_t end = hs_now_ns() + KEYFRAME_NS + KEYFRAME_NS / 4;
    int stopped = 0;
    while (!heard[0] && !heard[1] && !heard[2] && !stopped) {
        int64_t left = end - hs_now_ns();
        if (left <= 0) break;
        struct pollfd pf[3] = {{lcm_get_fileno(mb), POLLIN, 0},
                               {lcm_get_fileno(hb), POLLIN, 0},
                               {s->opt.stop_fd, POLLIN, 0}};
        int n = poll(pf, s->opt.stop_fd >= 0 ? 3 : 2, (int)(left / 1000000) + 1);
        if (n <= 0) continue;
        if (pf[0].revents & POLLIN) lcm_handle(mb);
        if (pf[1].revents & POLLIN) lcm_handle(hb);
        if (s->opt.stop_fd >= 0 && (pf[2].revents & POLLIN)) stopped = 1;
    }
    for (int i = 0; i < 3; ++i)
        if (sub[i]) lcm_unsubscribe(i < 2 ? mb : hb, sub[i]);
    if (stopped) return -1;
    if (!heard[0] && !heard[1] && !heard[2]) return 0;
    hs_err_set(err, HS_ERR_INVALID,
               "another hapsim-server is serving prefix %s on %s / %s (its %s arrived): a "
               "device would get two force streams. Stop it, or give this one other buses "
               "(--haptic-url, --mesh-url) or another --prefix",
               s->prefix, s->haptic_url, s->mesh_url,
               heard[2]   ? "forces"
               : heard[0] ? "topology"
                          : "status");
    return 1;
}

// Start the scene's sim and wait up to 0.5 s for a small mesh's compliance, so the start line
// can give its set-up time (a large one goes on in the background).
static hs_status run_start_sim(hs_server* s, hs_err* err) {
    world* w = &s->w;
    if (!w->sim) return HS_OK;
    hs_status st = hs_haptic_sim_start(w->sim, err);
    if (st != HS_OK) return st;
    hs_haptic_sim_stats hst;
    for (int i = 0; i < 100; ++i) {
        hs_haptic_sim_stats_get(w->sim, &hst);
        if (hst.comp_state <= 0) break;
        struct timespec ts = {0, 5000000};
        nanosleep(&ts, NULL);
    }
    return HS_OK;
}

// The deformation thread's news since the last pass: step and cut timings, compliance state,
// solver switches, a cut to pass on.
static void observe_sim(hs_server* s, int64_t t) {
    world* w = &s->w;
    hs_haptic_sim_stats st;
    hs_haptic_sim_stats_get(w->sim, &st);
    if (st.steps != s->last_steps) {
        hist_add(s->h_step, (int64_t)(st.step_ms_last * 1e6) / SIM_HIST_SCALE);
        if (s->last_step_ns && st.steps > s->last_steps)
            hist_add(s->h_simper,
                     (t - s->last_step_ns) / (st.steps - s->last_steps) / SIM_HIST_SCALE);
        s->last_steps = st.steps;
        s->last_step_ns = t;
    }
    if (st.cut_steps != s->last_cut_steps) {
        s->cut_ms[s->n_cut_ms++ % CUT_SAMPLES] = st.cut_ms_last;
        s->last_cut_steps = st.cut_steps;
    }
    s->cutting_now = st.cutting;
    const int say = !s->opt.quiet && !s->opt.live;
    if (st.comp_state != s->comp_state_seen) {
        if (say && (st.comp_state == 0 || st.comp_state == -1)) {
            const char* e = hs_haptic_sim_setup_error(w->sim);
            if (st.comp_state == 0)
                printf("hapsim-server: compliance ready after %.1f ms: haptics answer "
                       "with forces now\n",
                       st.setup_ms);
            else
                printf("hapsim-server: compliance set-up failed (%s): haptics answer "
                       "zero force\n",
                       e ? e : "?");
            fflush(stdout);
        }
        s->comp_state_seen = st.comp_state;
    }
    if (st.solver_switches > s->solver_switches_seen) {
        s->solver_switches_seen = st.solver_switches;
        if (say) {
            printf("hapsim-server: solver now %s (step cost direct %.1f, pcg %.1f, "
                   "warped %.1f ms, 0: not measured; budget %.1f ms)\n",
                   solver_name(st.solver), st.solver_cost_ms[HS_SOLVER_DIRECT],
                   st.solver_cost_ms[HS_SOLVER_PCG], st.solver_cost_ms[HS_SOLVER_WARPED],
                   1e3 / w->scene.sim_hz);
            fflush(stdout);
        }
    } else if (st.solver_switches < s->solver_switches_seen) {
        s->solver_switches_seen = st.solver_switches; // a new sim (reset, load)
    }
    if (w->cutting && hs_haptic_sim_topology_version(w->sim) != w->cut_seen) apply_cut(s);
}

// When the net loop publishes next.
typedef struct schedule {
    int64_t visual, status, topo, key, live, end;
} schedule;

static int64_t schedule_next(const hs_server* s, const schedule* c) {
    int64_t next = c->visual;
    if (c->status < next) next = c->status;
    if (c->topo < next) next = c->topo;
    if (c->key < next) next = c->key;
    if (s->opt.live && c->live < next) next = c->live;
    if (c->end < next) next = c->end;
    return next;
}

// What is due at t: mesh frames and tool states, keyframe, topology, status, the live line.
static void publish_due(hs_server* s, schedule* c, int64_t t) {
    const world* w = &s->w;
    if (t >= c->visual) {
        publish_frame(s, t);
        publish_tool_states(s, t);
        const int64_t visual_ns = (int64_t)(1e9 / w->scene.visual_hz); // a load may change it
        c->visual += visual_ns;
        if (c->visual < t) c->visual = t + visual_ns;
    }
    if (t >= c->key) {
        publish_keyframe(s);
        c->key = t + KEYFRAME_NS;
    }
    if (t >= c->topo) {
        publish_topology(s);
        c->topo = t + KEYFRAME_NS;
    }
    if (t >= c->status) {
        publish_status(s, t);
        c->status = t + (int64_t)(1e9 / w->scene.status_hz);
    }
    if (s->opt.live && t >= c->live) {
        live_line(s, t);
        c->live = t + LIVE_NS;
    }
    if (t >= c->end) s->stop = 1;
}

// One wait for input (or the next due time) and its handling; HS_OK, or the bus error.
static hs_status run_once(hs_server* s, const schedule* c, hs_err* err) {
    int64_t t = hs_now_ns();
    int64_t wait_ns = schedule_next(s, c) - t;
    // While a device is active, wake every millisecond to pass rt outputs on.
    if (s->w.sim && s->dev[0].seen && t - s->dev[0].last_rx_ns < 2000000000LL && wait_ns > 1000000)
        wait_ns = 1000000;
    if (s->load.active && wait_ns > 2000000) wait_ns = 2000000; // look for its end
    int timeout = wait_ns <= 0 ? 0 : (int)((wait_ns + 999999) / 1000000);
    int sfd = s->opt.stop_fd;
    struct pollfd pf[3] = {{lcm_get_fileno(hs_net_bus_lcm(s->hbus)), POLLIN, 0},
                           {lcm_get_fileno(hs_net_bus_lcm(s->mbus)), POLLIN, 0},
                           {sfd, POLLIN, 0}};
    int n = poll(pf, 3, timeout);
    if (n < 0 && errno != EINTR) return hs_err_set(err, HS_ERR_IO, "poll: %s", strerror(errno));
    t = hs_now_ns();
    hist_add(s->h_net, t - s->last_iter_ns);
    s->last_iter_ns = t;
    s->net_iters++;
    if (n > 0 && (pf[2].revents & POLLIN)) {
        char b[16];
        while (read(sfd, b, sizeof b) > 0) s->stop = 1;
    }
    if (n > 0 && (pf[0].revents & POLLIN) && handle_ready(s->hbus) < 0)
        return hs_err_set(err, HS_ERR_IO, "lcm_handle failed on %s", s->haptic_url);
    if (n > 0 && (pf[1].revents & POLLIN) && handle_ready(s->mbus) < 0)
        return hs_err_set(err, HS_ERR_IO, "lcm_handle failed on %s", s->mesh_url);
    if (s->load.active && atomic_load(&s->load.done)) finish_load(s, 0); // replaces the world
    drain_outputs(s);
    publish_rt_output(s);
    return HS_OK;
}

// The lines printed at the stop.
static void print_stop_summary(hs_server* s) {
    printf("hapsim-server: stopped after %.1f s: %lld poses accepted, %lld forces sent, "
           "%llu messages rejected, %llu command retries answered again\n",
           (double)(hs_now_ns() - s->start_ns) * 1e-9, (long long)s->poses_total,
           (long long)s->forces_total, (unsigned long long)rejected_total(s),
           (unsigned long long)retried_total(s));
    const int64_t kd[2] = {kernel_drops(s, 0), kernel_drops(s, 1)};
    if (kd[0] || kd[1])
        printf("hapsim-server: the kernel dropped %lld datagrams on the haptic bus and %lld on "
               "the mesh bus (receive buffers full: docs/server.md)\n",
               (long long)kd[0], (long long)kd[1]);
    if (s->w.sim) {
        hs_haptic_sim_stats st;
        hs_haptic_sim_stats_get(s->w.sim, &st);
        printf("hapsim-server: %lld deformation steps; sim step p50 %.2f ms, p99 %.2f ms "
               "(step + snapshot, since the last reset or load; thread CPU p50 %.2f ms, p99 "
               "%.2f ms), %lld overruns of %.1f ms; rate %.1f Hz of %g at the end; solver %s",
               (long long)st.steps, st.step_ms_p50_all, st.step_ms_p99_all, st.step_cpu_ms_p50_all,
               st.step_cpu_ms_p99_all, (long long)st.step_overruns, 1e3 / s->w.scene.sim_hz,
               st.sim_hz_target, s->w.scene.sim_hz, solver_name(st.solver));
        if (s->w.def.auto_solver)
            printf(" (auto, %lld switches; step cost direct %.1f, pcg %.1f, warped %.1f ms; "
                   "0: not measured)",
                   (long long)st.solver_switches, st.solver_cost_ms[HS_SOLVER_DIRECT],
                   st.solver_cost_ms[HS_SOLVER_PCG], st.solver_cost_ms[HS_SOLVER_WARPED]);
        printf("\n");
        if (st.depth_max_m > 0)
            printf("hapsim-server: deepest press %.1f mm (validated to %.1f mm)\n",
                   st.depth_max_m * 1e3, hs_contact_validated_depth(s->w.def.probe.radius_m) * 1e3);
        if (st.deep_loops)
            printf("hapsim-server: warning: pressed %.1f mm deep, beyond the %.1f mm the "
                   "contact is validated for, in %lld deformation loops\n",
                   st.depth_max_m * 1e3, hs_contact_validated_depth(s->w.def.probe.radius_m) * 1e3,
                   (long long)st.deep_loops);
    }
    if (s->w.cutting)
        printf("hapsim-server: %lld cut steps (topology events, over every reset), "
               "topology version %lld; cut step p50 %.1f ms, p99 %.1f ms, max %.1f ms "
               "(deformation thread: sweep, body and compliance sync, topology hand-over)\n",
               (long long)s->cut_events, (long long)s->topo_version, cut_quantile(s, 0.5),
               cut_quantile(s, 0.99), cut_quantile(s, 1.0));
    if (s->w.cutting && s->w.sim) {
        hs_haptic_sim_stats st;
        hs_haptic_sim_stats_get(s->w.sim, &st);
        printf("hapsim-server: %lld tets removed since the last reset or load; last sweep "
               "alone %.1f ms; haptic compliance: %lld cut steps followed, %lld rebuilds, the "
               "last in %.1f ms\n",
               (long long)st.cut_removed, st.sweep_ms_last, (long long)st.comp_updates,
               (long long)st.comp_rebuilds, st.comp_ms_last);
    }
    fflush(stdout);
}

hs_status hs_server_run(hs_server* s, hs_err* err) {
    s->listening = 1;
    int other = another_server(s, err);
    s->listening = 0;
    if (other > 0) return HS_ERR_INVALID;
    if (other < 0) return HS_OK; // SIGINT/SIGTERM while listening
    hs_status rc = run_start_sim(s, err);
    if (rc != HS_OK) return rc;
    if (!s->opt.quiet) hs_server_print_summary(s);
    int64_t t = hs_now_ns();
    s->start_ns = s->stat_ns = s->last_iter_ns = t;
    schedule c = {t, t, t, t, t, INT64_MAX};
    if (s->opt.duration_s > 0) c.end = t + (int64_t)(s->opt.duration_s * 1e9);
    publish_topology(s);
    while (!s->stop) {
        rc = run_once(s, &c, err);
        if (rc != HS_OK) break;
        t = hs_now_ns();
        if (s->w.sim) observe_sim(s, t);
        publish_due(s, &c, t);
    }
    finish_load(s, 1);
    if (s->w.sim) hs_haptic_sim_stop(s->w.sim);
    if (s->opt.live) fprintf(stderr, "\n");
    if (!s->opt.quiet) print_stop_summary(s);
    return rc;
}
