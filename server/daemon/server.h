// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-server: the daemon. One scene, three threads: rt (1 kHz haptic tick) and deformation
// (both from hs_haptic_sim), and net, which is the thread calling hs_server_run and the only
// one that touches LCM.
//
// DESIGN. The net thread owns two LCM buses (haptic: poses in, forces out; mesh: everything
// else) and waits with poll() on both LCM fds plus a signalfd, never lcm_handle_timeout.
// Inbound bytes go through the hs_net validators (raw lcm_subscribe; a bad message is counted
// per reason and dropped). An accepted pose of device 0 is fed to the rt thread through the
// memory device and answered at once with the rt thread's newest local model evaluated at the
// new pose (what a driver would render: no extra tick of latency); the rt outputs themselves
// are published when poses stop arriving (watchdog ramp, e-stop). Commands that rebuild the
// simulation (pause/resume) stop and join the sim threads, keep the body state, and start a new
// sim; load_scene, reset and a rebuilding set_param build the new world on a loader thread while
// the old one runs, and the net loop swaps it in (set_param handing the body state over). The rt
// thread never waits on the net thread.
#ifndef HS_DAEMON_SERVER_H
#define HS_DAEMON_SERVER_H

#include "base.h"

#ifdef __cplusplus
extern "C" {
#endif

/// Command-line options. Zero-initialise; NULL strings take the scene's values.
typedef struct hs_server_opts {
    const char* scene_path; ///< scene file (required)
    const char* haptic_url; ///< overrides the scene's lcm.haptic_url
    const char* mesh_url;   ///< overrides the scene's lcm.mesh_url
    const char* prefix;     ///< overrides the scene's lcm.prefix
    int realtime;           ///< 1: ask for SCHED_FIFO and mlockall for the rt thread
    double duration_s;      ///< > 0: stop by itself after this long, s
    int quiet;              ///< 1: no start-up summary and no exit line
    int live;               ///< 1: one status line on stderr, rewritten in place twice a second
    int stop_fd; ///< readable (a byte per stop signal) when the server should stop; -1: none
} hs_server_opts;

typedef struct hs_server hs_server;

/// Load the scene and mesh, open both buses, subscribe, build the simulation (not started).
/// Errors name the file, line and key (scene) or the URL (bus). @param out OUT
hs_status hs_server_create(const hs_server_opts* opts, hs_server** out, hs_err* err);
/// Print the start-up summary to stdout (scene, mesh, model, buses, threads, RT privileges).
void hs_server_print_summary(hs_server* s);
/// Start the sim threads and run the net loop until opts->stop_fd becomes readable (the
/// caller's SIGINT/SIGTERM handler writes to it) or the duration ends. Joins the threads.
hs_status hs_server_run(hs_server* s, hs_err* err);
/// Release everything; accepts NULL, sets *s = NULL.
void hs_server_destroy(hs_server** s);

#ifdef __cplusplus
}
#endif
#endif
