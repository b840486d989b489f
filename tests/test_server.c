// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-server end to end: the real daemon as a child process and real LCM clients over UDP
// multicast, inside a private network namespace (tests/netns.sh; ttl=0, private ports).
// Poses in -> forces out on the liver, the watchdog, commands with acks, a 10k-vertex keyframe,
// delta loss recovered at the next keyframe, a 50k-message flood of malformed payloads with
// exact reject counters and a bitwise-identical mesh, a malformed scene, refused command lines.
// Every wait is bounded.
#define _GNU_SOURCE
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include "test_macros.h"

#include "base.h"
#include "mesh.h"
#include "hapsim_channels.h"
#include "hapsim_command_ack_t.h"
#include "hapsim_command_t.h"
#include "hapsim_mesh_delta_t.h"
#include "hapsim_mesh_state_t.h"
#include "hapsim_mesh_topology_t.h"
#include "hapsim_server_status_t.h"
#include "hapsim_tool_force_t.h"
#include "hapsim_tool_pose_t.h"
#include "bus.h"
#include "mesh_frames.h"

#define URL_H    "udpm://239.255.76.91:7791?ttl=0"
#define URL_M    "udpm://239.255.76.92:7792?ttl=0"
#define URL_H_RX "udpm://239.255.76.91:7791?ttl=0&recv_buf_size=4194304"
#define URL_M_RX "udpm://239.255.76.92:7792?ttl=0&recv_buf_size=4194304"
#define PREFIX   "T_"

// Node 399 of liver2.msh, the top of the liver, and its outward normal (scenes/liver/scripts).
static const double P399[3] = {-0.0601965072, 0.0632736481, -0.0146254244};
static const double N399[3] = {0.105, 0.993, -0.045};
#define PROBE_R 0.005
#ifndef PRESS_D
#define PRESS_D 0.003
#endif

static char tmpdir[256];
static pid_t child = -1;

static void kill_child(void) {
    if (child > 0) {
        kill(child, SIGKILL);
        waitpid(child, NULL, 0);
        child = -1;
    }
}

// Scenes, meshes and server logs go to a fresh folder, removed at exit unless HS_TEST_KEEP=1.
static void cleanup(void) {
    kill_child();
    const char* keep = getenv("HS_TEST_KEEP");
    if (tmpdir[0] && !(keep && !strcmp(keep, "1"))) {
        char cmd[300];
        snprintf(cmd, sizeof cmd, "rm -rf '%s'", tmpdir);
        if (system(cmd) != 0) fprintf(stderr, "could not remove %s\n", tmpdir);
    }
}

__attribute__((constructor)) static void setup(void) {
    snprintf(tmpdir, sizeof tmpdir, "/tmp/hs_test_server_XXXXXX");
    if (!mkdtemp(tmpdir)) tmpdir[0] = '\0';
    atexit(cleanup);
}

static void write_file(const char* path, const char* text) {
    FILE* f = fopen(path, "w");
    if (f) {
        fputs(text, f);
        fclose(f);
    }
}

// A liver scene without gravity (the press script's surface is the rest surface), mesh by path.
static void liver_scene(const char* path, const char* extra) {
    char text[2048];
    snprintf(text, sizeof text,
             "{ \"mesh\": \"%s/scenes/liver/liver2.msh\",\n"
             "  \"material\": {\"youngs_pa\": 5000, \"poisson\": 0.45, \"density_kg_m3\": 1060,\n"
             "               \"rayleigh_mass\": 0.5, \"rayleigh_stiffness\": 0.01},\n"
             "  \"fixed\": [{\"type\": \"plane\", \"point\": [0, -0.0433, 0], \"normal\": [0, 1, "
             "0]}],\n"
             "  \"gravity\": [0, 0, 0],\n"
             "  \"tools\": [{\"kind\": \"probe\", \"radius\": %g}],\n"
             "  \"workspace\": {\"min\": [-0.25, -0.2, -0.2], \"max\": [0.25, 0.25, 0.2]}%s }\n",
             HS_SOURCE_DIR, PROBE_R, extra ? extra : "");
    write_file(path, text);
}

// Start hapsim-server on scene with the test URLs; stdout/stderr to files in tmpdir.
static int start_server(const char* scene, const char* tag) {
    kill_child();
    char out[512];
    snprintf(out, sizeof out, "%s/server-%s.log", tmpdir, tag);
    fflush(stdout);
    child = fork();
    if (child < 0) return -1;
    if (child == 0) {
        FILE* f = freopen(out, "w", stdout);
        (void)f;
        dup2(fileno(stdout), 2);
        execl(HS_SERVER_BIN, HS_SERVER_BIN, scene, "--haptic-url", URL_H, "--mesh-url", URL_M,
              "--prefix", PREFIX, "--duration", "120", (char*)NULL);
        _exit(127);
    }
    return 0;
}

// The server log of start_server(..., tag) into text (NUL-terminated); 0, or -1 if unreadable.
static int read_server_log(const char* tag, char* text, size_t cap) {
    char log[600];
    snprintf(log, sizeof log, "%s/server-%s.log", tmpdir, tag);
    FILE* f = fopen(log, "r");
    if (!f) return -1;
    size_t n = fread(text, 1, cap - 1, f);
    fclose(f);
    text[n] = '\0';
    return 0;
}

// Signal sig; returns the exit status (or -1 if it did not exit within 5 s).
static int stop_server_with(int sig) {
    if (child <= 0) return -1;
    kill(child, sig);
    int64_t end = hs_now_ns() + 5000000000LL;
    int st = 0;
    while (hs_now_ns() < end) {
        pid_t r = waitpid(child, &st, WNOHANG);
        if (r == child) {
            child = -1;
            int code = WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
            if (code != 0) printf("  hapsim-server exit status %d\n", code);
            return code;
        }
        usleep(10000);
    }
    kill_child();
    return -1;
}

static int stop_server(void) {
    return stop_server_with(SIGTERM);
}

static int server_alive(void) {
    return child > 0 && waitpid(child, NULL, WNOHANG) == 0;
}

// ---------------------------------------------------------------------------------------------
// The client: both buses, the newest of everything, a consistent mesh copy.

// What the tests read from server_status_t, copied into fixed storage.
typedef struct status_info {
    int32_t state;
    int n_loops;
    char loop_name[8][16];
    float rate_hz[8];
    int64_t overruns[8];
    int n_steps;
    char step_name[8][16];
    float step_p50_us[8], step_p99_us[8];
    char warnings[1024];
    int n_devices;
    int64_t poses_received[4];
    int n_rejects;
    char reject_channel[32][32];
    char reject_reason[32][32];
    int64_t reject_count[32];
} status_info;

typedef struct client {
    hs_net_bus* h;
    hs_net_bus* m;
    int64_t session, seq;
    // forces
    int n_force;
    hapsim_tool_force_t force; // newest (arrays are fixed-size)
    int64_t force_rx_ns;
    // status
    int n_status, n_loading; // n_loading: statuses saying STATE_LOADING
    status_info* status;     // newest
    // acks
    int n_ack;
#define ACK_RING 256 // acks remembered (a load with 40 commands queued behind it: 80)
    int64_t ack_id[ACK_RING];
    int32_t ack_status[ACK_RING];
    int64_t ack_utime[ACK_RING]; // the server's clock
    char ack_msg[ACK_RING][200];
    // every force received: the server's utime, its norm and state
    int n_flog;
    int64_t flog_utime[8192];
    double flog_norm[8192];
    int32_t flog_state[8192];
    double flog_stiff[8192]; // largest |stiffness| entry, N/m
    // mesh
    int n_topo, n_key, n_delta;
    int64_t topo_version;
    int n_vis;
    float* rest;
    int64_t key_id;
    float* key;   // newest keyframe [3 n_vis]
    float* shape; // keyframe + newest matching delta
    int drop_deltas;
    int n_delta_applied;
    hapsim_tool_force_t_subscription_t* s_force;
    hapsim_server_status_t_subscription_t* s_status;
    hapsim_command_ack_t_subscription_t* s_ack;
    hapsim_mesh_topology_t_subscription_t* s_topo;
    hapsim_mesh_state_t_subscription_t* s_key;
    hapsim_mesh_delta_t_subscription_t* s_delta;
    int64_t hist_id[8]; // the last keyframes, by id
    float* hist[8];
} client;

static void on_force(const lcm_recv_buf_t* rb, const char* ch, const hapsim_tool_force_t* f,
                     void* u) {
    (void)rb;
    (void)ch;
    client* c = u;
    c->force = *f;
    c->force_rx_ns = hs_now_ns();
    c->n_force++;
    if (c->n_flog < 8192) {
        c->flog_utime[c->n_flog] = f->utime;
        c->flog_norm[c->n_flog] =
            sqrt(f->force[0] * f->force[0] + f->force[1] * f->force[1] + f->force[2] * f->force[2]);
        double st = 0;
        for (int k = 0; k < 9; ++k) st = fmax(st, fabs(f->stiffness[k]));
        c->flog_stiff[c->n_flog] = st;
        c->flog_state[c->n_flog++] = f->state;
    }
}

static void on_status(const lcm_recv_buf_t* rb, const char* ch, const hapsim_server_status_t* s,
                      void* u) {
    (void)rb;
    (void)ch;
    client* c = u;
    if (!c->status) c->status = calloc(1, sizeof *c->status);
    status_info* i = c->status;
    memset(i, 0, sizeof *i);
    i->state = s->state;
    c->n_loading += s->state == HAPSIM_SERVER_STATUS_T_STATE_LOADING;
    for (int k = 0; k < s->n_loops && k < 8; ++k) {
        snprintf(i->loop_name[k], sizeof i->loop_name[k], "%s", s->loop_name[k]);
        i->rate_hz[k] = s->rate_hz[k];
        i->overruns[k] = s->overruns[k];
        i->n_loops = k + 1;
    }
    for (int k = 0; k < s->n_steps && k < 8; ++k) {
        snprintf(i->step_name[k], sizeof i->step_name[k], "%s", s->step_name[k]);
        i->step_p50_us[k] = s->step_p50_us[k];
        i->step_p99_us[k] = s->step_p99_us[k];
        i->n_steps = k + 1;
    }
    snprintf(i->warnings, sizeof i->warnings, "%s", s->warnings);
    i->n_devices = s->n_devices;
    for (int k = 0; k < s->n_devices && k < 4; ++k) i->poses_received[k] = s->poses_received[k];
    for (int k = 0; k < s->n_rejects && k < 32; ++k) {
        snprintf(i->reject_channel[k], 32, "%s", s->reject_channel[k]);
        snprintf(i->reject_reason[k], 32, "%s", s->reject_reason[k]);
        i->reject_count[k] = s->reject_count[k];
        i->n_rejects = k + 1;
    }
    c->n_status++;
}

static void on_ack(const lcm_recv_buf_t* rb, const char* ch, const hapsim_command_ack_t* a,
                   void* u) {
    (void)rb;
    (void)ch;
    client* c = u;
    c->ack_id[c->n_ack % ACK_RING] = a->request_id;
    c->ack_status[c->n_ack % ACK_RING] = a->status;
    c->ack_utime[c->n_ack % ACK_RING] = a->utime;
    snprintf(c->ack_msg[c->n_ack % ACK_RING], sizeof c->ack_msg[0], "%s", a->message);
    c->n_ack++;
}

static void on_topo(const lcm_recv_buf_t* rb, const char* ch, const hapsim_mesh_topology_t* t,
                    void* u) {
    (void)rb;
    (void)ch;
    client* c = u;
    if (t->n_rest != 3 * t->n_vis || t->n_vis <= 0) return;
    if (c->n_vis != t->n_vis) {
        free(c->rest);
        free(c->key);
        free(c->shape);
        c->n_vis = t->n_vis;
        c->rest = malloc(sizeof(float) * 3 * (size_t)t->n_vis);
        c->key = calloc(3 * (size_t)t->n_vis, sizeof(float));
        c->shape = calloc(3 * (size_t)t->n_vis, sizeof(float));
        c->key_id = 0;
    }
    memcpy(c->rest, t->rest_position, sizeof(float) * 3 * (size_t)t->n_vis);
    c->topo_version = t->topology_version;
    c->n_topo++;
}

static void on_key(const lcm_recv_buf_t* rb, const char* ch, const hapsim_mesh_state_t* m,
                   void* u) {
    (void)rb;
    (void)ch;
    client* c = u;
    if (!c->n_topo || m->topology_version != c->topo_version || m->n_pos != 3 * c->n_vis) return;
    memcpy(c->key, m->position, sizeof(float) * (size_t)m->n_pos);
    memcpy(c->shape, m->position, sizeof(float) * (size_t)m->n_pos);
    c->key_id = m->keyframe_id;
    int h = c->n_key % 8;
    free(c->hist[h]);
    c->hist[h] = malloc(sizeof(float) * (size_t)m->n_pos);
    memcpy(c->hist[h], m->position, sizeof(float) * (size_t)m->n_pos);
    c->hist_id[h] = m->keyframe_id;
    c->n_key++;
}

static void on_delta(const lcm_recv_buf_t* rb, const char* ch, const hapsim_mesh_delta_t* d,
                     void* u) {
    (void)rb;
    (void)ch;
    client* c = u;
    c->n_delta++;
    if (c->drop_deltas || !c->key_id || d->keyframe_id != c->key_id ||
        d->topology_version != c->topo_version || d->n_delta != 3 * d->n_changed)
        return;
    if (hs_net_delta_apply(c->key, c->n_vis, d->index, d->delta, d->n_changed, c->shape) == 0)
        c->n_delta_applied++;
}

static int client_open(client* c) {
    memset(c, 0, sizeof *c);
    hs_err err = {0};
    if (hs_net_bus_create(URL_H_RX, &c->h, &err) != HS_OK) return -1;
    if (hs_net_bus_create(URL_M_RX, &c->m, &err) != HS_OK) return -1;
    c->session = 0x5eed0000 + getpid();
    c->s_force =
        hapsim_tool_force_t_subscribe(hs_net_bus_lcm(c->h), PREFIX "TOOL_FORCE", on_force, c);
    c->s_status = hapsim_server_status_t_subscribe(hs_net_bus_lcm(c->m), PREFIX "SERVER_STATUS",
                                                   on_status, c);
    c->s_ack =
        hapsim_command_ack_t_subscribe(hs_net_bus_lcm(c->m), PREFIX "COMMAND_ACK", on_ack, c);
    c->s_topo =
        hapsim_mesh_topology_t_subscribe(hs_net_bus_lcm(c->m), PREFIX "MESH_TOPOLOGY", on_topo, c);
    c->s_key = hapsim_mesh_state_t_subscribe(hs_net_bus_lcm(c->m), PREFIX "MESH_STATE", on_key, c);
    c->s_delta =
        hapsim_mesh_delta_t_subscribe(hs_net_bus_lcm(c->m), PREFIX "MESH_DELTA", on_delta, c);
    // LCM queues 30 messages per subscription and drops the newest beyond: a burst of acks (a
    // load with 41 commands behind it) lost its last ones when this client ran late.
    hapsim_command_ack_t_subscription_set_queue_capacity(c->s_ack, 1024);
    hapsim_tool_force_t_subscription_set_queue_capacity(c->s_force, 1024);
    return 0;
}

static void client_close(client* c) {
    if (c->h) hapsim_tool_force_t_unsubscribe(hs_net_bus_lcm(c->h), c->s_force);
    if (c->m) {
        lcm_t* l = hs_net_bus_lcm(c->m);
        hapsim_server_status_t_unsubscribe(l, c->s_status);
        hapsim_command_ack_t_unsubscribe(l, c->s_ack);
        hapsim_mesh_topology_t_unsubscribe(l, c->s_topo);
        hapsim_mesh_state_t_unsubscribe(l, c->s_key);
        hapsim_mesh_delta_t_unsubscribe(l, c->s_delta);
    }
    hs_net_bus_destroy(&c->h);
    hs_net_bus_destroy(&c->m);
    free(c->status);
    free(c->rest);
    free(c->key);
    free(c->shape);
    for (int i = 0; i < 8; ++i) free(c->hist[i]);
    memset(c, 0, sizeof *c);
}

// Handle both buses for up to ms milliseconds.
static void pump_ms(client* c, int ms) {
    int64_t end = hs_now_ns() + (int64_t)ms * 1000000;
    while (hs_now_ns() < end) {
        hs_net_bus_handle(c->h, 0);
        hs_net_bus_handle(c->m, 1);
    }
}

// Pump until *counter exceeds start or timeout; returns 1 when it did.
static int wait_more(client* c, const int* counter, int timeout_ms) {
    int start = *counter;
    int64_t end = hs_now_ns() + (int64_t)timeout_ms * 1000000;
    while (*counter <= start && hs_now_ns() < end) {
        hs_net_bus_handle(c->h, 0);
        hs_net_bus_handle(c->m, 1);
    }
    return *counter > start;
}

static void send_pose(client* c, const double p[3], uint32_t buttons) {
    hapsim_tool_pose_t m;
    memset(&m, 0, sizeof m);
    m.utime = hs_now_ns() / 1000;
    m.seq = ++c->seq;
    m.session = c->session;
    m.device_id = 0;
    m.tool_id = 0;
    for (int k = 0; k < 3; ++k) m.position[k] = p[k];
    m.orientation[0] = 1;
    m.buttons = (int32_t)buttons;
    hapsim_tool_pose_t_publish(hs_net_bus_lcm(c->h), PREFIX "TOOL_POSE", &m);
}

// Probe centre at depth d (m, > 0: pressed in) along the normal at node 399.
static void probe_at(double depth, double p[3]) {
    double l = sqrt(N399[0] * N399[0] + N399[1] * N399[1] + N399[2] * N399[2]);
    for (int k = 0; k < 3; ++k) p[k] = P399[k] + (PROBE_R - depth) * N399[k] / l;
}

// Stream poses at ~1 kHz for ms, moving linearly from depth d0 to d1 with these buttons held;
// handles traffic between.
static void stream_buttons(client* c, double d0, double d1, int ms, uint32_t buttons) {
    int64_t t0 = hs_now_ns();
    for (int i = 0; i < ms; ++i) {
        double p[3];
        probe_at(d0 + (d1 - d0) * (i + 1) / ms, p);
        send_pose(c, p, buttons);
        int64_t next = t0 + (int64_t)(i + 1) * 1000000;
        while (hs_now_ns() < next) {
            hs_net_bus_handle(c->h, 0);
            hs_net_bus_handle(c->m, 0);
        }
    }
    // The answer to the last pose may still be in flight on a loaded machine: wait for it
    // (bounded), so callers can check it.
    int64_t end = hs_now_ns() + 500000000LL;
    while (c->force.pose_seq != c->seq && hs_now_ns() < end) {
        hs_net_bus_handle(c->h, 0);
        hs_net_bus_handle(c->m, 0);
    }
}

static void stream(client* c, double d0, double d1, int ms) {
    stream_buttons(c, d0, d1, ms, 0);
}

static int64_t next_request = 1000;

static void send_command(client* c, int64_t id, int kind, const char* k1, const char* v1,
                         const char* k2, const char* v2) {
    hapsim_command_t m;
    memset(&m, 0, sizeof m);
    char* keys[2] = {(char*)(uintptr_t)k1, (char*)(uintptr_t)k2};
    char* values[2] = {(char*)(uintptr_t)v1, (char*)(uintptr_t)v2};
    m.utime = hs_now_ns() / 1000;
    m.seq = id;
    m.request_id = id;
    m.kind = kind;
    m.n_args = k2 ? 2 : k1 ? 1 : 0;
    m.keys = keys;
    m.values = values;
    m.sender = "test_server";
    hapsim_command_t_publish(hs_net_bus_lcm(c->m), PREFIX "COMMAND", &m);
}

// Send a command (retrying) and wait for its ack; returns the ack status or 99 on timeout.
// After a PENDING ack the server is at work: wait (up to 20 s) without sending it again, so
// a slow build (sanitizers) does not add retries to the server's count.
static int command(client* c, int kind, const char* k1, const char* v1, const char* k2,
                   const char* v2, int64_t* id_out) {
    int64_t id = ++next_request;
    if (id_out) *id_out = id;
    int pending = 0;
    for (int attempt = 0; attempt < 5; ++attempt) {
        if (!pending) send_command(c, id, kind, k1, v1, k2, v2);
        int64_t end = hs_now_ns() + (pending ? 4000000000LL : 600000000LL);
        while (hs_now_ns() < end) {
            hs_net_bus_handle(c->m, 1);
            hs_net_bus_handle(c->h, 0);
            for (int i = 0; i < ACK_RING && i < c->n_ack; ++i)
                if (c->ack_id[i] == id) {
                    if (c->ack_status[i] != HAPSIM_COMMAND_ACK_T_STATUS_PENDING)
                        return c->ack_status[i];
                    pending = 1;
                }
        }
    }
    return 99;
}

// The message of the newest ack of request id, or "".
static const char* ack_message(const client* c, int64_t id) {
    const char* m = "";
    for (int i = 0; i < ACK_RING && i < c->n_ack; ++i)
        if (c->ack_id[i] == id) m = c->ack_msg[i];
    return m;
}

static double dot_n(const double f[3]) {
    double l = sqrt(N399[0] * N399[0] + N399[1] * N399[1] + N399[2] * N399[2]);
    return (f[0] * N399[0] + f[1] * N399[1] + f[2] * N399[2]) / l;
}

static double norm3(const double v[3]) {
    return sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

static int wait_up(client* c) {
    // The server is up once its status arrives (set-up: mesh, buses) and no longer says that
    // the compliance is being set up (haptics answer zero force until then).
    int64_t end = hs_now_ns() + 20000000000LL;
    while ((c->n_status == 0 || strstr(c->status->warnings, "compliance set-up")) &&
           hs_now_ns() < end && server_alive())
        pump_ms(c, 20);
    return c->n_status > 0 && !strstr(c->status->warnings, "compliance set-up");
}

static int64_t reject_count(const status_info* s, const char* ch, const char* reason) {
    for (int i = 0; i < s->n_rejects; ++i)
        if (!strcmp(s->reject_channel[i], ch) && !strcmp(s->reject_reason[i], reason))
            return s->reject_count[i];
    return 0;
}

// ---------------------------------------------------------------------------------------------

static int poses_in_forces_out(void) {
    char scene[512];
    snprintf(scene, sizeof scene, "%s/liver.json", tmpdir);
    liver_scene(scene, NULL);
    ENSURE(start_server(scene, "forces") == 0);
    client c;
    ENSURE(client_open(&c) == 0);
    ENSURE(wait_up(&c));

    // Free space, 10 mm above the surface: answers echo the pose, force exactly zero.
    stream(&c, -0.010, -0.010, 300);
    pump_ms(&c, 20);
    ENSURE(c.n_force > 200);
    ENSURE(c.force.pose_seq == c.seq && c.force.device_id == 0);
    ENSURE(norm3(c.force.force) == 0.0);
    ENSURE(c.force.state == HAPSIM_TOOL_FORCE_T_STATE_FREE);

    // Press 4 mm along -n and hold: the force pushes back along +n.
    stream(&c, -0.010, 0.004, 700);
    stream(&c, 0.004, 0.004, 800);
    // 20 ms: the rt outputs published once the poses stop echo the pose rt used, which is the
    // newest one only after rt's next tick (a loaded machine can delay it past a few ms).
    pump_ms(&c, 20);
    double fn = dot_n(c.force.force);
    printf("  pressed 4 mm: force %.4f %.4f %.4f N (along n %.4f), state %d\n", c.force.force[0],
           c.force.force[1], c.force.force[2], fn, c.force.state);
    ENSURE(fn > 0.02);
    ENSURE(fn > 0.9 * norm3(c.force.force)); // opposing the press, mostly normal
    ENSURE(c.force.state == HAPSIM_TOOL_FORCE_T_STATE_CONTACT);
    ENSURE(c.force.pose_seq == c.seq);
    // The local model stiffens against a deeper press: n^T (dF/dp) n < 0.
    double kn = 0;
    for (int a = 0; a < 3; ++a)
        for (int b = 0; b < 3; ++b) kn += N399[a] * c.force.stiffness[3 * a + b] * N399[b];
    ENSURE(kn < 0);

    // Clamp through SET_PARAM, then restore.
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "force_max_n", "value", "0.01",
                   NULL) == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    stream(&c, 0.004, 0.004, 400);
    ENSURE(norm3(c.force.force) <= 0.01 + 1e-12);
    // Refusals say what was wrong, and the status counts them.
    int64_t rid = 0;
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "no_such_param", "value", "1",
                   &rid) == HAPSIM_COMMAND_ACK_T_STATUS_INVALID);
    ENSURE(
        strstr(ack_message(&c, rid), "unknown parameter 'no_such_param' (known: probe_radius_m"));
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "poisson", "value", "0.5", &rid) ==
           HAPSIM_COMMAND_ACK_T_STATUS_INVALID);
    ENSURE(strstr(ack_message(&c, rid), "poisson = 0.5 out of range: above -1 .. 0.4999"));
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "force_max_n", "value", "0x10",
                   &rid) == HAPSIM_COMMAND_ACK_T_STATUS_INVALID);
    ENSURE(strstr(ack_message(&c, rid), "argument: SET_PARAM's value is not a number"));
    ENSURE(wait_more(&c, &c.n_status, 2000));
    ENSURE(wait_more(&c, &c.n_status, 2000));
    ENSURE(reject_count(c.status, "COMMAND", "parameter") == 2);
    ENSURE(reject_count(c.status, "COMMAND", "argument") == 1);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "force_max_n", "value", "3.3",
                   NULL) == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    stream(&c, 0.004, 0.004, 400);
    ENSURE(dot_n(c.force.force) > 0.02);

    // E-stop: zero at once, even while pressed; a repeated request id is not executed again.
    const double f_full = dot_n(c.force.force);
    int64_t id = 0;
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_ESTOP, NULL, NULL, NULL, NULL, &id) ==
           HAPSIM_COMMAND_ACK_T_STATUS_OK);
    stream(&c, 0.004, 0.004, 50);
    ENSURE(norm3(c.force.force) == 0.0 && c.force.state == HAPSIM_TOOL_FORCE_T_STATE_STOPPED);
    // The release ramps the force back in over at least the 10 ms safety ramp: the server
    // released after t_rel, so an answer received within 10 ms of it has a gain below 1.
    int64_t t_rel = hs_now_ns();
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE, NULL, NULL, NULL, NULL, NULL) ==
           HAPSIM_COMMAND_ACK_T_STATUS_OK);
    double pr[3];
    probe_at(0.004, pr);
    send_pose(&c, pr, 0);
    for (int64_t end = hs_now_ns() + 500000000LL; c.force.pose_seq != c.seq && hs_now_ns() < end;)
        hs_net_bus_handle(c.h, 1);
    ENSURE(c.force.pose_seq == c.seq);
    double dt_rel_ms = (double)(c.force_rx_ns - t_rel) * 1e-6;
    printf("  e-stop released: first force %.4f N along n, %.2f ms after the release was sent "
           "(%.4f N before the stop), state %d\n",
           dot_n(c.force.force), dt_rel_ms, f_full, c.force.state);
    if (dt_rel_ms < 10.0) {
        ENSURE(c.force.state == HAPSIM_TOOL_FORCE_T_STATE_RAMP);
        ENSURE(norm3(c.force.force) <= 1.5 * fabs(f_full) * dt_rel_ms / 10.0 + 1e-4);
    }
    stream(&c, 0.004, 0.004, 300);
    ENSURE(dot_n(c.force.force) > 0.02);
    ENSURE(c.force.state == HAPSIM_TOOL_FORCE_T_STATE_CONTACT);
    int acks = c.n_ack;
    send_command(&c, id, HAPSIM_COMMAND_T_KIND_ESTOP, NULL, NULL, NULL, NULL); // duplicate
    ENSURE(wait_more(&c, &c.n_ack, 2000) && c.n_ack == acks + 1);
    stream(&c, 0.004, 0.004, 100);
    ENSURE(dot_n(c.force.force) > 0.02); // not latched again

    // Stop sending mid-contact: zero force within the watchdog (100 ms) and its ramp.
    int64_t last = hs_now_ns();
    int64_t t_zero = -1;
    int64_t end = last + 1000000000LL;
    while (hs_now_ns() < end && t_zero < 0) {
        int n = c.n_force;
        hs_net_bus_handle(c.h, 1);
        if (c.n_force > n && norm3(c.force.force) == 0.0) t_zero = c.force_rx_ns - last;
    }
    printf("  device stopped: zero force after %.1f ms\n", (double)t_zero * 1e-6);
    ENSURE(t_zero > 0 && t_zero < 100000000LL + 10000000LL + 60000000LL);
    ENSURE(c.force.state == HAPSIM_TOOL_FORCE_T_STATE_STOPPED);

    // Status reports the device and the loops.
    ENSURE(wait_more(&c, &c.n_status, 2000));
    ENSURE(c.status->n_devices == 1 && c.status->poses_received[0] == c.seq);
    int has_rt = 0, has_sim = 0, has_step = 0;
    for (int i = 0; i < c.status->n_loops; ++i) {
        if (!strcmp(c.status->loop_name[i], "rt")) has_rt = c.status->rate_hz[i] > 500;
        // Overruns of the deformation step (since start): counted, never more than the steps
        // of the run (60 Hz over a few seconds).
        if (!strcmp(c.status->loop_name[i], "sim"))
            has_sim = c.status->overruns[i] >= 0 && c.status->overruns[i] < 60 * 60;
    }
    for (int i = 0; i < c.status->n_steps; ++i)
        if (!strcmp(c.status->step_name[i], "sim_step")) {
            // The deformation thread's step percentiles (the body was pressed: it stepped).
            printf("  status: sim_step p50 %.0f us, p99 %.0f us\n", c.status->step_p50_us[i],
                   c.status->step_p99_us[i]);
            has_step = c.status->step_p50_us[i] > 0 &&
                       c.status->step_p50_us[i] <= c.status->step_p99_us[i] &&
                       c.status->step_p99_us[i] < 10e6;
        }
    ENSURE(has_rt && has_sim && has_step);
    // liver2's boundary edges (median 13.5 mm) are longer than twice the 5 mm probe radius.
    ENSURE(strstr(c.status->warnings, "surface edges (median 13.5 mm)") != NULL);
    ENSURE(c.status->state == HAPSIM_SERVER_STATUS_T_STATE_RUNNING && c.n_loading == 0);

    // Load a scene: a LOADING status goes out at once (ahead of the final ack on the same bus),
    // more while it is built, and RUNNING after.
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, "path", scene, NULL, NULL, NULL) ==
           HAPSIM_COMMAND_ACK_T_STATUS_OK);
    const int loading = c.n_loading;
    ENSURE(loading >= 1);
    ENSURE(wait_more(&c, &c.n_status, 2000));
    ENSURE(c.status->state == HAPSIM_SERVER_STATUS_T_STATE_RUNNING && c.n_loading == loading);
    ENSURE(stop_server_with(SIGHUP) == 0); // a closed terminal: exit 0 with the exit line
    client_close(&c);
    // The e-stop's retried copy is a retry answered again, not a rejected message.
    char text[8192];
    ENSURE(read_server_log("forces", text, sizeof text) == 0);
    const char* end_line = strstr(text, "hapsim-server: stopped after");
    ENSURE(end_line);
    // The start line names the solver choice; the exit summary the step figures.
    // liver2 is small: one factorisation fits the period many times over, so direct first.
    ENSURE(strstr(text, "  solver   auto (equilibrium): starts with direct (a factorisation"));
    ENSURE(strstr(text, "  warning  mesh surface edges (median 13.5 mm) are larger than 2 x"));
    const char* steps_line = strstr(text, "deformation steps; sim step p50");
    ENSURE(steps_line && strstr(steps_line, "overruns of 16.7 ms"));
    printf("  %.*s", (int)strcspn(steps_line, "\n") + 1, steps_line);
    printf("  %.*s", (int)strcspn(end_line, "\n") + 1, end_line);
    // The one rejection: the SET_PARAM of "0x10" (refused names and values are counted apart).
    ENSURE(strstr(end_line, " 1 messages rejected, 1 command retries answered again"));
    return 0;
}

// The ack of request id with a status other than PENDING (final), or PENDING; its index in the
// client's ack ring, or -1.
static int find_ack(const client* c, int64_t id, int final) {
    for (int i = 0; i < ACK_RING && i < c->n_ack; ++i)
        if (c->ack_id[i] == id &&
            (c->ack_status[i] != HAPSIM_COMMAND_ACK_T_STATUS_PENDING) == (final != 0))
            return i;
    return -1;
}

// Press 4 mm at ~1 kHz until request id has its final ack (at most 10 s). Returns the final
// ack's index or -1.
static int press_until_final(client* c, int64_t id) {
    int64_t end = hs_now_ns() + 10000000000LL;
    while (hs_now_ns() < end) {
        double p[3];
        probe_at(0.004, p);
        send_pose(c, p, 0);
        int64_t next = hs_now_ns() + 1000000;
        while (hs_now_ns() < next) {
            hs_net_bus_handle(c->h, 0);
            hs_net_bus_handle(c->m, 0);
        }
        int f = find_ack(c, id, 1);
        if (f >= 0) return f;
    }
    return -1;
}

// Forces the server sent strictly between two of its times (us); how many, and how many of
// them nonzero.
static int forces_between(const client* c, int64_t t0, int64_t t1, int* nonzero) {
    int n = 0;
    *nonzero = 0;
    for (int i = 0; i < c->n_flog; ++i)
        if (c->flog_utime[i] > t0 && c->flog_utime[i] < t1) {
            n++;
            *nonzero += c->flog_norm[i] != 0.0;
        }
    return n;
}

// LOAD_SCENE is built on a thread of its own: the running scene goes on answering poses until
// the new one is swapped in, an e-stop sent during the build acts before the swap, and a scene
// that fails to load leaves the running one as it was. (The net loop used to stand still for
// the whole build: no forces, no status and no e-stop until the new scene ran.)
static int load_goes_on_answering(void) {
    char scene[512];
    snprintf(scene, sizeof scene, "%s/liver_load.json", tmpdir);
    liver_scene(scene, NULL);
    ENSURE(start_server(scene, "load") == 0);
    client c;
    ENSURE(client_open(&c) == 0);
    ENSURE(wait_up(&c));
    stream(&c, -0.010, 0.004, 500);
    stream(&c, 0.004, 0.004, 300);
    ENSURE(dot_n(c.force.force) > 0.02);

    // During the build: a command that waits for the new scene (REQUEST_TOPOLOGY: kept, run at
    // the swap), then an e-stop, which must not wait behind it (it did: the first version
    // joined the loader for any such command, and the loop stood still; found in review). Both
    // are sent right behind the load, so they are waiting when the build starts (sent after its
    // PENDING ack by a client slow to run on a loaded machine, they came after a short build).
    int64_t load_id = ++next_request, topo_id = ++next_request, stop_id = ++next_request;
    send_command(&c, load_id, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, "path", scene, NULL, NULL);
    send_command(&c, topo_id, HAPSIM_COMMAND_T_KIND_REQUEST_TOPOLOGY, NULL, NULL, NULL, NULL);
    send_command(&c, stop_id, HAPSIM_COMMAND_T_KIND_ESTOP, NULL, NULL, NULL, NULL);
    int fin = press_until_final(&c, load_id);
    ENSURE(fin >= 0 && c.ack_status[fin] == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    int pend = find_ack(&c, load_id, 0), est = find_ack(&c, stop_id, 1);
    ENSURE(pend >= 0 && est >= 0 && c.ack_status[est] == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    pump_ms(&c, 50);
    int tpend = find_ack(&c, topo_id, 0), tfin = find_ack(&c, topo_id, 1);
    ENSURE(tpend >= 0 && tfin >= 0 && c.ack_status[tfin] == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    ENSURE(c.ack_utime[tpend] < c.ack_utime[est] && c.ack_utime[fin] <= c.ack_utime[tfin]);
    int64_t t_pend = c.ack_utime[pend], t_stop = c.ack_utime[est], t_fin = c.ack_utime[fin];
    int nz_build = 0, nz_stopped = 0;
    int n_build = forces_between(&c, t_pend, t_stop, &nz_build);
    int n_stopped = forces_between(&c, t_stop, t_fin, &nz_stopped);
    printf("  load: built in %.1f ms; %d forces before the e-stop (%d nonzero), %d after it "
           "(%d nonzero), e-stop acked %.1f ms before the swap, %d LOADING statuses\n",
           (double)(t_fin - t_pend) * 1e-3, n_build, nz_build, n_stopped, nz_stopped,
           (double)(t_fin - t_stop) * 1e-3, c.n_loading);
    ENSURE(t_pend < t_stop && t_stop < t_fin); // the e-stop did not wait for the build
    ENSURE(n_build + n_stopped >= 3);          // the running scene answered during the build
    ENSURE(nz_stopped == 0);                   // and stopped at once
    ENSURE(c.n_loading >= 1);
    // The swap keeps the latch; the release ramps the new scene's force in.
    stream(&c, 0.004, 0.004, 100);
    ENSURE(norm3(c.force.force) == 0.0 && c.force.state == HAPSIM_TOOL_FORCE_T_STATE_STOPPED);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE, NULL, NULL, NULL, NULL, NULL) ==
           HAPSIM_COMMAND_ACK_T_STATUS_OK);
    stream(&c, 0.004, 0.004, 500);
    ENSURE(dot_n(c.force.force) > 0.02);

    // A scene that cannot be loaded: FAILED naming it, and the running scene went on.
    char bad[600];
    snprintf(bad, sizeof bad, "%s/no_such_scene.json", tmpdir);
    int64_t bad_id = ++next_request;
    send_command(&c, bad_id, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, "path", bad, NULL, NULL);
    fin = press_until_final(&c, bad_id);
    ENSURE(fin >= 0 && c.ack_status[fin] == HAPSIM_COMMAND_ACK_T_STATUS_FAILED);
    stream(&c, 0.004, 0.004, 200);
    ENSURE(dot_n(c.force.force) > 0.02 && c.force.state == HAPSIM_TOOL_FORCE_T_STATE_CONTACT);
    ENSURE(wait_more(&c, &c.n_status, 2000));
    ENSURE(c.status->state == HAPSIM_SERVER_STATUS_T_STATE_RUNNING);

    // A load, then at once a command that must act on the new scene: it waits for the swap.
    int64_t load2 = ++next_request;
    send_command(&c, load2, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, "path", scene, NULL, NULL);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "force_max_n", "value", "0.01",
                   NULL) == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    fin = find_ack(&c, load2, 1);
    ENSURE(fin >= 0 && c.ack_status[fin] == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    stream(&c, 0.004, 0.004, 400);
    ENSURE(norm3(c.force.force) <= 0.01 + 1e-12); // the limit holds in the new scene

    // More commands during a load than are kept (32): the rest are refused at once (busy), and
    // an e-stop after them is still acked before the swap (the loop waited for the build).
    next_request += 100;
    int64_t load3 = ++next_request, many = next_request + 1, stop3 = next_request + 60;
    next_request += 100;
    // Sent right behind the load, not after its PENDING ack: they are then already waiting when
    // the build starts, so they arrive during it even when this client is slow to run (waiting
    // for the ack, a build finished on a loaded machine before they came: all 40 ran).
    send_command(&c, load3, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, "path", scene, NULL, NULL);
    for (int k = 0; k < 40; ++k)
        send_command(&c, many + k, HAPSIM_COMMAND_T_KIND_REQUEST_TOPOLOGY, NULL, NULL, NULL, NULL);
    send_command(&c, stop3, HAPSIM_COMMAND_T_KIND_ESTOP, NULL, NULL, NULL, NULL);
    fin = press_until_final(&c, load3);
    ENSURE(fin >= 0 && c.ack_status[fin] == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    pump_ms(&c, 200);
    est = find_ack(&c, stop3, 1);
    ENSURE(est >= 0 && c.ack_utime[est] < c.ack_utime[fin]);
    int ok = 0, busy = 0;
    for (int k = 0; k < 40; ++k) {
        int a = find_ack(&c, many + k, 1);
        ENSURE(a >= 0);
        ok += c.ack_status[a] == HAPSIM_COMMAND_ACK_T_STATUS_OK;
        busy += c.ack_status[a] == HAPSIM_COMMAND_ACK_T_STATUS_FAILED;
    }
    printf("  40 commands during a load: %d run after the swap, %d refused as busy; e-stop "
           "acked %.1f ms before the swap\n",
           ok, busy, (double)(c.ack_utime[fin] - c.ack_utime[est]) * 1e-3);
    ENSURE(ok + busy == 40 && ok <= 32);

    // RESET is built beside the running scene as well (the net loop stood still for the rebuild,
    // no PENDING ack, no force), from the scene as set: a limit set before it holds after it.
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE, NULL, NULL, NULL, NULL, NULL) ==
           HAPSIM_COMMAND_ACK_T_STATUS_OK);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "force_max_n", "value", "0.05",
                   NULL) == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    stream(&c, 0.004, 0.004, 300);
    ENSURE(dot_n(c.force.force) > 0.02);
    int64_t reset_id = ++next_request;
    send_command(&c, reset_id, HAPSIM_COMMAND_T_KIND_RESET, NULL, NULL, NULL, NULL);
    fin = press_until_final(&c, reset_id);
    ENSURE(fin >= 0 && c.ack_status[fin] == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    pend = find_ack(&c, reset_id, 0);
    ENSURE(pend >= 0);
    int nz_reset = 0;
    int n_reset = forces_between(&c, c.ack_utime[pend], c.ack_utime[fin], &nz_reset);
    printf("  reset: built in %.1f ms, %d forces meanwhile (%d nonzero)\n",
           (double)(c.ack_utime[fin] - c.ack_utime[pend]) * 1e-3, n_reset, nz_reset);
    ENSURE(nz_reset >= 3);
    stream(&c, 0.004, 0.004, 500);
    ENSURE(dot_n(c.force.force) > 0.02 && norm3(c.force.force) <= 0.05 + 1e-12);

    // A `set` that rebuilds the simulation (youngs_pa) is built beside it too (the body's state
    // goes over at the swap: not checked here; frames right after it were as deformed with the
    // new body started at rest, which re-deforms within a frame under the pressed probe).
    int64_t set_id = ++next_request;
    send_command(&c, set_id, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "youngs_pa", "value",
                 "30000");
    fin = press_until_final(&c, set_id);
    ENSURE(fin >= 0 && c.ack_status[fin] == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    pend = find_ack(&c, set_id, 0);
    ENSURE(pend >= 0);
    int nz_set = 0;
    int n_set = forces_between(&c, c.ack_utime[pend], c.ack_utime[fin], &nz_set);
    printf("  set youngs_pa: built in %.1f ms, %d forces meanwhile (%d nonzero)\n",
           (double)(c.ack_utime[fin] - c.ack_utime[pend]) * 1e-3, n_set, nz_set);
    ENSURE(nz_set >= 3);
    stream(&c, 0.004, 0.004, 300);
    ENSURE(dot_n(c.force.force) > 0.02 && norm3(c.force.force) <= 0.05 + 1e-12);
    ENSURE(stop_server() == 0);
    client_close(&c);
    return 0;
}

static int mesh_10k_arrives_whole(void) {
    // A 71 x 71 x 1 slab: every one of its 10368 nodes is on the surface.
    hs_mesh* box = NULL;
    hs_err err = {0};
    ENSURE(hs_mesh_create_box(0.2, 0.2, 0.004, 71, 71, 1, &box, &err) == HS_OK);
    char mesh[512], scene[512], text[1024];
    snprintf(mesh, sizeof mesh, "%s/slab.vtk", tmpdir);
    ENSURE(hs_mesh_write_vtk(box, NULL, mesh, &err) == HS_OK);
    ENSURE(box->n_surf_nodes == 10368);
    snprintf(scene, sizeof scene, "%s/slab.json", tmpdir);
    snprintf(text, sizeof text,
             "{ \"mesh\": \"slab.vtk\", \"fixed\": [{\"type\": \"bbox_side\", \"axis\": \"x\", "
             "\"side\": \"min\", \"depth\": 0.001}],\n"
             "  \"features\": {\"haptics\": false, \"visual_mesh\": true} }\n");
    write_file(scene, text);
    ENSURE(start_server(scene, "mesh10k") == 0);
    client c;
    ENSURE(client_open(&c) == 0);
    ENSURE(wait_up(&c));
    int64_t end = hs_now_ns() + 10000000000LL;
    while ((c.n_topo == 0 || c.n_key == 0) && hs_now_ns() < end) pump_ms(&c, 20);
    ENSURE(c.n_vis == 10368 && c.n_key > 0);
    ENSURE(hs_net_keyframe_bytes(c.n_vis, 0) > 65000); // really fragmented
    for (int i = 0; i < c.n_vis; ++i)
        for (int k = 0; k < 3; ++k) {
            ENSURE(c.key[3 * i + k] == c.rest[3 * i + k]);
            ENSURE(c.rest[3 * i + k] == (float)box->x0[3 * box->surf_nodes[i] + k]);
        }
    // Haptics off: poses are validated and counted, never answered; no rt loop.
    double p[3] = {0.1, 0.1, 0.01};
    for (int i = 0; i < 20; ++i) send_pose(&c, p, 0);
    pump_ms(&c, 200);
    ENSURE(c.n_force == 0);
    // An unknown parameter is INVALID here too (the haptics-off answer FAILED came first).
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "bogus", "value", "1", NULL) ==
           HAPSIM_COMMAND_ACK_T_STATUS_INVALID);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "youngs_pa", "value", "5000",
                   NULL) == HAPSIM_COMMAND_ACK_T_STATUS_FAILED);
    ENSURE(wait_more(&c, &c.n_status, 2000));
    ENSURE(c.status->poses_received[0] == 20);
    for (int i = 0; i < c.status->n_loops; ++i) ENSURE(strcmp(c.status->loop_name[i], "rt") != 0);
    ENSURE(stop_server() == 0);
    // Its topology is larger than a socket's default buffer: the server says what receivers need
    // (the start-up summary gives the size).
    char log[4096];
    ENSURE(read_server_log("mesh10k", log, sizeof log) == 0);
    int topo_bytes = 0;
    const char* at = strstr(log, "topology ");
    while (at && sscanf(at, "topology %d)", &topo_bytes) != 1) at = strstr(at + 1, "topology ");
    printf("  topology message %d bytes, rmem_default %lld\n", topo_bytes,
           (long long)hs_net_rmem_default());
    ENSURE(topo_bytes > 100000);
    if (hs_net_rmem_default() > 0 && hs_net_rmem_default() < topo_bytes)
        ENSURE(strstr(log, "note: a mesh topology message is") && strstr(log, "recv_buf_size="));
    client_close(&c);
    hs_mesh_destroy(&box);
    return 0;
}

static int dropped_deltas_recover(void) {
    char scene[512];
    snprintf(scene, sizeof scene, "%s/liver_d.json", tmpdir);
    liver_scene(scene, NULL);
    ENSURE(start_server(scene, "deltas") == 0);
    client c, ref;
    ENSURE(client_open(&c) == 0);
    ENSURE(client_open(&ref) == 0);
    c.session = 77; // only c sends poses
    ENSURE(wait_up(&c));
    int64_t end = hs_now_ns() + 5000000000LL;
    while ((c.n_key == 0 || ref.n_key == 0) && hs_now_ns() < end) {
        pump_ms(&c, 10);
        pump_ms(&ref, 10);
    }
    ENSURE(c.n_key > 0 && ref.n_key > 0);
    // Press: the tissue moves; the reference applies every delta, c drops them all for a while.
    c.drop_deltas = 1;
    int differed = 0; // c was stale while ref followed the deltas
    int64_t t0 = hs_now_ns();
    for (int i = 0; i < 900; ++i) {
        differed |= memcmp(c.shape, ref.shape, sizeof(float) * 3 * (size_t)c.n_vis) != 0;
        double p[3];
        probe_at(-0.002 + PRESS_D * (i + 1) / 900.0, p);
        send_pose(&c, p, 0);
        int64_t next = t0 + (int64_t)(i + 1) * 1000000;
        while (hs_now_ns() < next) {
            hs_net_bus_handle(c.h, 0);
            hs_net_bus_handle(c.m, 0);
            hs_net_bus_handle(ref.m, 0);
        }
    }
    printf("  ref: %d keyframes, %d deltas (%d applied)\n", ref.n_key, ref.n_delta,
           ref.n_delta_applied);
    ENSURE(ref.n_delta_applied >= 2);
    ENSURE(differed);
    // Keep the tool pressed and listen again: the next keyframe restores c exactly.
    c.drop_deltas = 0;
    int keys = c.n_key;
    t0 = hs_now_ns();
    for (int i = 0; i < 2500 && c.n_key == keys; ++i) {
        double p[3];
        probe_at(PRESS_D - 0.002, p);
        send_pose(&c, p, 0);
        int64_t next = t0 + (int64_t)(i + 1) * 1000000;
        while (hs_now_ns() < next) {
            hs_net_bus_handle(c.h, 0);
            hs_net_bus_handle(c.m, 0);
            hs_net_bus_handle(ref.m, 0);
        }
    }
    ENSURE(c.n_key > keys);
    pump_ms(&ref, 50);
    const float* ref_key = NULL;
    for (int i = 0; i < 8; ++i)
        if (ref.hist[i] && ref.hist_id[i] == c.key_id) ref_key = ref.hist[i];
    ENSURE(ref_key != NULL);
    ENSURE(memcmp(c.key, ref_key, sizeof(float) * 3 * (size_t)c.n_vis) == 0);
    ENSURE(memcmp(c.shape, ref_key, sizeof(float) * 3 * (size_t)c.n_vis) == 0);
    // ... and the deltas after it apply again, identically on both.
    int applied = c.n_delta_applied;
    for (int i = 0; i < 200; ++i) {
        double p[3];
        probe_at(PRESS_D - 0.002 - 0.0005 * i / 200.0, p);
        send_pose(&c, p, 0);
        pump_ms(&c, 1);
        hs_net_bus_handle(ref.m, 0);
    }
    pump_ms(&ref, 30);
    pump_ms(&c, 1);
    ENSURE(c.n_delta_applied > applied);
    if (c.key_id == ref.key_id)
        ENSURE(memcmp(c.shape, ref.shape, sizeof(float) * 3 * (size_t)c.n_vis) == 0);
    ENSURE(stop_server() == 0);
    client_close(&c);
    client_close(&ref);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Flood

enum { F_DECODE, F_NONFINITE, F_QUAT, F_RANGE, F_DEVICE, F_TOOL, F_SESSION, F_SEQ, F_NP };
static const char* const pose_reason[F_NP] = {
    "decode",         "nonfinite",    "quaternion", "range",
    "unknown_device", "unknown_tool", "session",    "seq"};
enum { C_DECODE, C_LENGTH, C_RANGE, C_KIND, C_ARG, C_NONFINITE, C_DUP, C_NC };
static const char* const cmd_reason[C_NC] = {"decode",   "length",    "range",    "unknown_kind",
                                             "argument", "nonfinite", "duplicate"};

static uint64_t rng = 0x9e3779b97f4a7c15ULL;
static uint32_t rnd(void) {
    rng ^= rng << 13;
    rng ^= rng >> 7;
    rng ^= rng << 17;
    return (uint32_t)(rng >> 11);
}

// One malformed pose of category k, inside the liver whenever the category allows (a pose
// that slipped through would press the tissue and change the mesh).
static int bad_pose(client* c, int k, uint8_t* buf, int cap) {
    hapsim_tool_pose_t m;
    memset(&m, 0, sizeof m);
    double inside[3];
    probe_at(0.008, inside);
    m.utime = hs_now_ns() / 1000;
    m.seq = c->seq + 1 + (int64_t)(rnd() % 100);
    m.session = 424242;
    for (int i = 0; i < 3; ++i) m.position[i] = inside[i];
    m.orientation[0] = 1;
    switch (k) {
    case F_NONFINITE:
        m.position[rnd() % 3] = (rnd() & 1) ? NAN : INFINITY;
        break;
    case F_QUAT:
        m.orientation[1] = 0.5;
        break;
    case F_RANGE:
        m.buttons = 1 << (2 + rnd() % 20);
        break;
    case F_DEVICE:
        m.device_id = 1 + (int32_t)(rnd() % 1000);
        break;
    case F_TOOL:
        m.tool_id = 1 + (int32_t)(rnd() % 9);
        break;
    case F_SESSION:
        break; // another session while the real driver is live
    case F_SEQ:
        m.session = c->session;
        int64_t back = (int64_t)(rnd() % 50);
        if (back >= c->seq) back = c->seq - 1;
        m.seq = c->seq - back; // repeated or reordered, >= 1
        break;
    }
    int n = hapsim_tool_pose_t_encode(buf, 0, cap, &m);
    if (k == F_DECODE) {
        switch (rnd() % 3) {
        case 0: // random bytes
            n = (int)(rnd() % 200);
            for (int i = 0; i < n; ++i) buf[i] = (uint8_t)rnd();
            break;
        case 1: // truncated
            n -= 1 + (int)(rnd() % (unsigned)(n - 1));
            break;
        default: // trailing byte
            buf[n++] = (uint8_t)rnd();
            break;
        }
    }
    return n;
}

static int bad_command(int k, int64_t dup_id, uint8_t* buf, int cap) {
    hapsim_command_t m;
    memset(&m, 0, sizeof m);
    char* keys[9] = {"name", "value", "c", "d", "e", "f", "g", "h", "i"};
    char* values[9] = {"youngs_pa", "1", "", "", "", "", "", "", ""};
    m.utime = hs_now_ns() / 1000;
    m.request_id = 1000000 + (int64_t)rnd();
    m.kind = HAPSIM_COMMAND_T_KIND_SET_PARAM;
    m.n_args = 2;
    m.keys = keys;
    m.values = values;
    m.sender = "flood";
    switch (k) {
    case C_LENGTH:
        m.n_args = 9;
        break;
    case C_RANGE:
        m.request_id = 0;
        break;
    case C_KIND:
        m.kind = 9 + (int32_t)(rnd() % 100);
        m.n_args = 0;
        break;
    case C_ARG:
        values[1] = "12abc";
        break;
    case C_NONFINITE:
        values[1] = (rnd() & 1) ? "nan" : "inf";
        break;
    case C_DUP:
        m.request_id = dup_id;
        m.kind = HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE;
        m.n_args = 0;
        break;
    }
    int n = hapsim_command_t_encode(buf, 0, cap, &m);
    if (k == C_DECODE) {
        if (rnd() & 1) {
            n = 1 + (int)(rnd() % 300);
            for (int i = 0; i < n; ++i) buf[i] = (uint8_t)rnd();
        } else {
            n -= 1 + (int)(rnd() % (unsigned)(n - 1));
        }
    }
    return n;
}

// UDP datagrams the kernel dropped for full socket buffers in this network namespace (the
// test's own, tests/netns.sh); -1 when /proc/net/snmp cannot be read.
static long long udp_rcvbuf_errors(void) {
    FILE* f = fopen("/proc/net/snmp", "r");
    if (!f) return -1;
    char head[1024], vals[1024];
    long long r = -1;
    while (r < 0 && fgets(head, sizeof head, f)) {
        if (strncmp(head, "Udp:", 4) || !fgets(vals, sizeof vals, f)) continue;
        char *hs = NULL, *vs = NULL;
        char* h = strtok_r(head, " \n", &hs);
        char* v = strtok_r(vals, " \n", &vs);
        while (h && v) {
            if (!strcmp(h, "RcvbufErrors")) r = atoll(v);
            h = strtok_r(NULL, " \n", &hs);
            v = strtok_r(NULL, " \n", &vs);
        }
    }
    fclose(f);
    return r;
}

// Hover 3 mm off the surface for hover_ms while (optionally) flooding; then ask for a keyframe.
// *drops: datagrams the kernel dropped meanwhile (any socket here, the test's own included).
static int flood_run(const char* tag, int flood, float** mesh_out, int* n_vis_out,
                     int64_t* pose_expect, int64_t* cmd_expect, status_info* st_out,
                     long long* drops) {
    long long drops0 = udp_rcvbuf_errors();
    char scene[512];
    snprintf(scene, sizeof scene, "%s/liver_%s.json", tmpdir, tag);
    liver_scene(scene, NULL);
    ENSURE(start_server(scene, tag) == 0);
    client c;
    ENSURE(client_open(&c) == 0);
    ENSURE(wait_up(&c));
    int64_t dup_id = 0;
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE, NULL, NULL, NULL, NULL, &dup_id) ==
           HAPSIM_COMMAND_ACK_T_STATUS_OK);
    uint8_t buf[4096];
    // 12 per ms: at 25, a receiver slowed by a loaded machine (TSan, or other builds beside)
    // fell behind LCM's own receive buffers (2000 messages), which drop without a count, and
    // up to 3,500 more went missing than the kernel reported dropped (2026-11-28).
    const int total = 50000, per_ms = 12;
    int sent = 0;
    int64_t t0 = hs_now_ns();
    for (int ms = 0; (flood && sent < total) || ms < 1000; ++ms) {
        double p[3];
        probe_at(-0.003, p);
        send_pose(&c, p, 0);
        for (int j = 0; flood && j < per_ms && sent < total; ++j, ++sent) {
            if (rnd() % 4 != 0) {
                int k = (int)(rnd() % F_NP);
                int n = bad_pose(&c, k, buf, sizeof buf);
                lcm_publish(hs_net_bus_lcm(c.h), PREFIX "TOOL_POSE", buf, (unsigned)n);
                pose_expect[k]++;
            } else {
                int k = (int)(rnd() % C_NC);
                int n = bad_command(k, dup_id, buf, sizeof buf);
                lcm_publish(hs_net_bus_lcm(c.m), PREFIX "COMMAND", buf, (unsigned)n);
                cmd_expect[k]++;
            }
        }
        int64_t next = t0 + (int64_t)(ms + 1) * 1000000;
        while (hs_now_ns() < next) {
            hs_net_bus_handle(c.h, 0);
            hs_net_bus_handle(c.m, 0);
        }
    }
    ENSURE(server_alive());
    // The server still answers, and only the real driver's poses were accepted.
    stream(&c, -0.003, -0.003, 200);
    ENSURE(c.force.pose_seq == c.seq && norm3(c.force.force) == 0.0);
    int keys = c.n_key;
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_REQUEST_TOPOLOGY, NULL, NULL, NULL, NULL, NULL) ==
           HAPSIM_COMMAND_ACK_T_STATUS_OK);
    int64_t end = hs_now_ns() + 3000000000LL;
    while (c.n_key == keys && hs_now_ns() < end) pump_ms(&c, 10);
    ENSURE(c.n_key > keys);
    int st = c.n_status;
    end = hs_now_ns() + 3000000000LL;
    while (c.n_status < st + 2 && hs_now_ns() < end) pump_ms(&c, 10);
    ENSURE(c.n_status >= st + 2);
    long long d1 = udp_rcvbuf_errors();
    *drops = drops0 >= 0 && d1 >= 0 ? d1 - drops0 : 0;
    // Every driver pose the kernel delivered was counted (all of them unless the machine
    // stalled the receiver long enough for a socket buffer to fill: then it says so).
    if (*drops > 0)
        printf("  %s: the kernel dropped %lld datagrams (socket buffers full: the 2 cores were "
               "busy); counts checked as at most sent and at least sent - dropped\n",
               tag, *drops);
    ENSURE(c.status->poses_received[0] <= c.seq && c.status->poses_received[0] + *drops >= c.seq);
    *n_vis_out = c.n_vis;
    *mesh_out = malloc(sizeof(float) * 3 * (size_t)c.n_vis);
    memcpy(*mesh_out, c.key, sizeof(float) * 3 * (size_t)c.n_vis);
    *st_out = *c.status;
    printf("  %s: %d flood messages, %lld driver poses, %d keyframes\n", tag, sent,
           (long long)c.seq, c.n_key);
    ENSURE(stop_server() == 0);
    client_close(&c);
    return 0;
}

static int flood_leaves_server_intact(void) {
    int64_t pe[F_NP] = {0}, ce[C_NC] = {0}, pe0[F_NP] = {0}, ce0[C_NC] = {0};
    float *clean = NULL, *flooded = NULL;
    int nv_clean = 0, nv_flood = 0;
    static status_info s_clean_v, s_flood_v;
    status_info *s_clean = &s_clean_v, *s_flood = &s_flood_v;
    long long drops0 = 0, drops = 0;
    ENSURE(flood_run("clean", 0, &clean, &nv_clean, pe0, ce0, s_clean, &drops0) == 0);
    ENSURE(flood_run("flood", 1, &flooded, &nv_flood, pe, ce, s_flood, &drops) == 0);
    int64_t sum = 0, missing = 0;
    for (int k = 0; k < F_NP; ++k) {
        int64_t got = reject_count(s_flood, "TOOL_POSE", pose_reason[k]);
        printf("  TOOL_POSE %-14s sent %6lld counted %6lld\n", pose_reason[k], (long long)pe[k],
               (long long)got);
        ENSURE(got <= pe[k]); // exact unless the kernel dropped some (below)
        missing += pe[k] - got;
        sum += pe[k];
    }
    for (int k = 0; k < C_NC; ++k) {
        int64_t got = reject_count(s_flood, "COMMAND", cmd_reason[k]);
        printf("  COMMAND   %-14s sent %6lld counted %6lld\n", cmd_reason[k], (long long)ce[k],
               (long long)got);
        ENSURE(got <= ce[k]);
        missing += ce[k] - got;
        sum += ce[k];
    }
    printf("  %lld sent messages not counted, %lld datagrams dropped by the kernel\n",
           (long long)missing, drops);
    ENSURE(missing <= drops); // nothing the server received went uncounted
    ENSURE(sum >= 50000);
    ENSURE(s_clean->n_rejects == 0);
    ENSURE(nv_clean == nv_flood && nv_clean > 0);
    ENSURE(memcmp(clean, flooded, sizeof(float) * 3 * (size_t)nv_clean) == 0);
    free(clean);
    free(flooded);
    return 0;
}

// Waits up to ns for the server child to exit: its exit status, or -1 (still running, or
// killed by a signal).
static int wait_exit(int64_t ns) {
    int64_t end = hs_now_ns() + ns;
    while (hs_now_ns() < end) {
        int w = 0;
        if (waitpid(child, &w, WNOHANG) == child) {
            child = -1;
            return WIFEXITED(w) ? WEXITSTATUS(w) : -1;
        }
        usleep(10000);
    }
    return -1;
}

static int malformed_scene_exits_1(void) {
    char scene[512];
    snprintf(scene, sizeof scene, "%s/bad.json", tmpdir);
    write_file(scene, "{\n  \"mesh\": \"x.msh\",\n  \"material\": {\"poisson\": 0.7},\n"
                      "  \"fixed\": []\n}\n");
    ENSURE(start_server(scene, "bad") == 0);
    ENSURE(wait_exit(5000000000LL) == 1);
    char text[2048];
    ENSURE(read_server_log("bad", text, sizeof text) == 0);
    printf("  %s", text);
    ENSURE(strstr(text, "bad.json:") && strstr(text, "key '"));
    // A region that selects no node is named with its line, even beside one that does (it was
    // ignored); regions that fix every node are named as such (the message came from the body).
    // Errors found after parsing name the scene's line and key too (found in review,
    // 2026-11-28): regions that leave rigid motion free ("stiffness not positive definite"),
    // a units_scale that crushes the mesh, a mesh file that is not a mesh (its own file:line
    // only).
    char garbage[600];
    snprintf(garbage, sizeof garbage, "%s/garbage.msh", tmpdir);
    write_file(garbage, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\nmany\n");
    const char* liver = HS_SOURCE_DIR "/scenes/liver/liver2.msh";
    const char* regions[5][4] = {
        {"[{\"type\": \"bbox_side\", \"axis\": \"y\", \"side\": \"min\", \"depth\": 0.01},\n"
         "            {\"type\": \"box\", \"min\": [5, 5, 5], \"max\": [6, 6, 6]}]",
         "", liver, "regions0.json:3: key 'fixed[1]': the region selects no node"},
        {"[{\"type\": \"box\", \"min\": [-1, -1, -1], \"max\": [1, 1, 1]}]", "", liver,
         "regions1.json:2: key 'fixed': the regions fix every node"},
        {"[{\"type\": \"bbox_side\", \"axis\": \"y\", \"side\": \"max\", \"depth\": 0}]", "", liver,
         "regions2.json:2: key 'fixed': the piece of the mesh containing tet"},
        {"[{\"type\": \"bbox_side\", \"axis\": \"y\", \"side\": \"min\", \"depth\": 0.01}]",
         ",\n  \"units_scale\": 1e-300", liver, "regions3.json:4: key 'units_scale' (1e-300): "},
        {"[{\"type\": \"bbox_side\", \"axis\": \"y\", \"side\": \"min\", \"depth\": 0.01}]", "",
         garbage, "key 'mesh': "}};
    for (int k = 0; k < 5; ++k) {
        char body[1024];
        snprintf(scene, sizeof scene, "%s/regions%d.json", tmpdir, k);
        snprintf(body, sizeof body,
                 "{ \"mesh\": \"%s\",\n  \"fixed\": %s,\n"
                 "  \"tools\": [{\"kind\": \"probe\", \"radius\": 0.005}], \"devices\": 1%s }\n",
                 regions[k][2], regions[k][0], regions[k][1]);
        write_file(scene, body);
        ENSURE(start_server(scene, "bad") == 0);
        ENSURE(wait_exit(5000000000LL) == 1);
        ENSURE(read_server_log("bad", text, sizeof text) == 0);
        printf("  %s", text);
        ENSURE(strstr(text, regions[k][3]));
        if (k == 4)
            ENSURE(strstr(text, "regions4.json:1: key 'mesh'") && strstr(text, "garbage.msh:5"));
    }
    return 0;
}

// Runs hapsim-server with argv (after the scene) for at most 8 s; its exit status (-1: still
// running, killed) and its output in text.
static int run_server_args(const char* scene, const char* const* args, char* text, size_t cap) {
    char log[600];
    snprintf(log, sizeof log, "%s/server-args.log", tmpdir);
    static char store[16][400]; // execv takes char*: copies rather than casts
    char* argv[16] = {store[0], store[1]};
    snprintf(store[0], sizeof store[0], "%s", HS_SERVER_BIN);
    snprintf(store[1], sizeof store[1], "%s", scene);
    int n = 2;
    for (; args[n - 2] && n < 15; ++n) {
        snprintf(store[n], sizeof store[n], "%s", args[n - 2]);
        argv[n] = store[n];
    }
    argv[n] = NULL;
    kill_child();
    fflush(stdout);
    child = fork();
    if (child < 0) return -2;
    if (child == 0) {
        FILE* f = freopen(log, "w", stdout);
        (void)f;
        dup2(fileno(stdout), 2);
        execv(HS_SERVER_BIN, argv);
        _exit(127);
    }
    int st = wait_exit(8000000000LL);
    kill_child();
    FILE* f = fopen(log, "r");
    size_t k = f ? fread(text, 1, cap - 1, f) : 0;
    if (f) fclose(f);
    text[k] = '\0';
    printf("  exit %d: %s", st, text);
    return st;
}

// Command lines the server must refuse before it opens a bus (each would otherwise run 2 s).
static int bad_command_lines_refused(void) {
    char scene[512], text[4096];
    snprintf(scene, sizeof scene, "%s/liver.json", tmpdir);
    liver_scene(scene, NULL);
    // One group and port, only the options differ: both buses would be one.
    const char* same[] = {"--haptic-url", "udpm://239.255.76.93:7793",
                          "--mesh-url",   "udpm://239.255.76.93:7793?ttl=0",
                          "--duration",   "2",
                          "--quiet",      NULL};
    ENSURE(run_server_args(scene, same, text, sizeof text) == 1);
    ENSURE(strstr(text, "same bus") && strstr(text, "udpm://239.255.76.93:7793?ttl=0"));
    // A group without a port: LCM 1.3.1 would bind a random port (no one would hear the server).
    const char* noport[] = {"--haptic-url", "udpm://239.255.76.93?ttl=0",
                            "--mesh-url",   URL_M,
                            "--duration",   "2",
                            "--quiet",      NULL};
    ENSURE(run_server_args(scene, noport, text, sizeof text) == 1);
    ENSURE(strstr(text, "udpm://239.255.76.93?ttl=0") && strstr(text, "no port"));
    // 300 bytes: cut to 255 it would lose its recv_buf_size.
    char url[320];
    int n = snprintf(url, sizeof url, "%s", URL_M "&");
    while (n < 280) n += snprintf(url + n, sizeof url - (size_t)n, "a=1&");
    snprintf(url + n, sizeof url - (size_t)n, "recv_buf_size=4194304");
    const char* mlong[] = {"--haptic-url", URL_H, "--mesh-url", url,
                           "--duration",   "2",   "--quiet",    NULL};
    ENSURE(run_server_args(scene, mlong, text, sizeof text) == 1);
    ENSURE(strstr(text, "--mesh-url") && strstr(text, "longer than 255 bytes"));
    const char* hlong[] = {"--haptic-url", url, "--mesh-url", URL_M,
                           "--duration",   "2", "--quiet",    NULL};
    ENSURE(run_server_args(scene, hlong, text, sizeof text) == 1);
    ENSURE(strstr(text, "--haptic-url") && strstr(text, "longer than 255 bytes"));
    // Beyond the limit: the message says the limit.
    const char* dur[] = {"--duration", "1e8", NULL};
    ENSURE(run_server_args(scene, dur, text, sizeof text) == 2);
    ENSURE(strstr(text, "--duration") && strstr(text, "1e7"));
    return 0;
}

// A set rebuilds the scene from its files on the loader thread and hands the running body's
// state over: when the mesh file no longer holds the running mesh (edited on disk since the
// load; same node count) that state would land on other nodes, so the set is refused and the
// running simulation goes on (it was applied: the rebuild used the mesh in memory before).
// Largest displacement of the client's shape from the rest shape, m.
static double max_disp(const client* c) {
    double d = 0;
    for (int i = 0; i < c->n_vis; ++i) {
        double e[3];
        for (int k = 0; k < 3; ++k) e[k] = (double)c->shape[3 * i + k] - c->rest[3 * i + k];
        d = fmax(d, norm3(e));
    }
    return d;
}

/// A `set` that rebuilds a running simulation hands the body's state over: the liver sagging
/// under gravity (heavily damped, settled) keeps its sag across `set youngs_pa` to the value it
/// has, in the frames right after the swap and later. A body restarted at rest would show the
/// rest shape there and sag again over ~0.3 s.
static int set_keeps_body_state(void) {
    char scene[512], text[2048];
    snprintf(scene, sizeof scene, "%s/liver_sag.json", tmpdir);
    snprintf(text, sizeof text,
             "{ \"mesh\": \"%s/scenes/liver/liver2.msh\",\n"
             "  \"material\": {\"youngs_pa\": 5000, \"poisson\": 0.45, \"density_kg_m3\": 1060,\n"
             "               \"rayleigh_mass\": 20, \"rayleigh_stiffness\": 0.01},\n"
             "  \"fixed\": [{\"type\": \"plane\", \"point\": [0, -0.0433, 0], \"normal\": [0, 1, "
             "0]}],\n"
             "  \"gravity\": [0, 0, -9.81],\n"
             "  \"tools\": [{\"kind\": \"probe\", \"radius\": %g}],\n"
             "  \"workspace\": {\"min\": [-0.25, -0.2, -0.2], \"max\": [0.25, 0.25, 0.2]} }\n",
             HS_SOURCE_DIR, PROBE_R);
    write_file(scene, text);
    ENSURE(start_server(scene, "sag") == 0);
    client c;
    ENSURE(client_open(&c) == 0);
    ENSURE(wait_up(&c));
    // The tool held 5 cm off the surface until the sag settles: two samples 500 ms apart
    // within 2 % (bounded: a loaded machine may take longer than the usual ~1.5 s).
    stream(&c, -0.05, -0.05, 1000);
    double d0 = -1, sag = max_disp(&c);
    for (int k = 0; k < 20 && !(d0 > 0 && fabs(sag - d0) <= 0.02 * sag); ++k) {
        d0 = sag;
        stream(&c, -0.05, -0.05, 500);
        sag = max_disp(&c);
    }
    ENSURE(sag > 0.002 && fabs(sag - d0) <= 0.02 * sag); // sagged and settled
    int64_t id = ++next_request;
    send_command(&c, id, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "youngs_pa", "value", "5000");
    int fin = -1;
    for (int k = 0; k < 1000 && fin < 0; ++k) {
        stream(&c, -0.05, -0.05, 5);
        fin = find_ack(&c, id, 1);
    }
    ENSURE(fin >= 0 && c.ack_status[fin] == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    ENSURE(find_ack(&c, id, 0) >= 0); // built beside the running sim (PENDING first)
    // The keyframe sent at the swap shows the state handed over, not what the new sim made of
    // it: the samples are taken from its own frames, the first after the final ack on (a delta,
    // or a keyframe when most nodes moved: a body falling again from rest).
    int frames = c.n_delta_applied + c.n_key, waited = 0;
    while (c.n_delta_applied + c.n_key == frames && waited < 2000) {
        stream(&c, -0.05, -0.05, 1);
        waited++;
    }
    ENSURE(c.n_delta_applied + c.n_key > frames);
    double after[3];
    after[0] = max_disp(&c);
    stream(&c, -0.05, -0.05, 80);
    after[1] = max_disp(&c);
    stream(&c, -0.05, -0.05, 220);
    after[2] = max_disp(&c);
    printf("  sag %.2f mm before the set; after it %.2f mm in the new sim's first frame (%d "
           "poses after the ack), %.2f / %.2f mm 80 / 300 ms later\n",
           sag * 1e3, after[0] * 1e3, waited, after[1] * 1e3, after[2] * 1e3);
    for (int k = 0; k < 3; ++k) ENSURE(fabs(after[k] - sag) <= 0.05 * sag);
    ENSURE(stop_server() == 0);
    client_close(&c);
    return 0;
}

/// A rebuild of the running scene while the tool presses (set youngs_pa, set probe_radius_m,
/// reset): every force answered through the swap still pushes back, none says STOPPED. The new
/// simulation takes the old one's rt loop over (its last model until its own first snapshot,
/// the device's watchdog gain); before, the answers were zero for 12-29 ms (no output from the
/// new simulation yet), then ramped in over the watchdog's ramp, then overshot.
static int rebuild_keeps_force(void) {
    char scene[512];
    snprintf(scene, sizeof scene, "%s/liver_rebuild.json", tmpdir);
    liver_scene(scene, NULL);
    ENSURE(start_server(scene, "rebuild") == 0);
    client c;
    ENSURE(client_open(&c) == 0);
    ENSURE(wait_up(&c));
    stream(&c, -0.010, 0.004, 500);
    const char* const name[3] = {"youngs_pa", "probe_radius_m", NULL}; // NULL: RESET
    const char* const value[3] = {"10000", "0.006", NULL};
    for (int k = 0; k < 3; ++k) {
        stream(&c, 0.004, 0.004, 300);
        double f0 = norm3(c.force.force);
        if (!(dot_n(c.force.force) > 0.02))
            printf("  before %s: force %.4f N (along n %.4f N), state %d, pose_seq %lld of %lld, "
                   "answered %.1f ms ago\n",
                   name[k] ? name[k] : "reset", f0, dot_n(c.force.force), (int)c.force.state,
                   (long long)c.force.pose_seq, (long long)c.seq,
                   (double)(hs_now_ns() - c.force_rx_ns) * 1e-6);
        ENSURE(dot_n(c.force.force) > 0.02);
        int64_t id = ++next_request;
        int from = c.n_flog;
        if (name[k])
            send_command(&c, id, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", name[k], "value",
                         value[k]);
        else
            send_command(&c, id, HAPSIM_COMMAND_T_KIND_RESET, NULL, NULL, NULL, NULL);
        int fin = press_until_final(&c, id);
        ENSURE(fin >= 0 && c.ack_status[fin] == HAPSIM_COMMAND_ACK_T_STATUS_OK);
        stream(&c, 0.004, 0.004, 100);
        ENSURE(c.n_flog < 8192);
        double least = INFINITY;
        int stopped = 0;
        for (int i = from; i < c.n_flog; ++i) {
            least = fmin(least, c.flog_norm[i]);
            stopped += c.flog_state[i] == HAPSIM_TOOL_FORCE_T_STATE_STOPPED;
        }
        printf("  %s: %.3f N before, %d forces through the swap and 100 ms on: least %.3f N, "
               "%d STOPPED\n",
               name[k] ? name[k] : "reset", f0, c.n_flog - from, least, stopped);
        ENSURE(c.n_flog - from >= 50 && stopped == 0 && least >= 0.5 * f0);
    }
    ENSURE(stop_server() == 0);
    client_close(&c);
    return 0;
}

/// The largest force answered since flog entry `from`.
static double max_force_since(const client* c, int from) {
    double mx = 0;
    for (int i = from; i < c->n_flog; ++i) mx = fmax(mx, c->flog_norm[i]);
    return mx;
}

/// Paused answers keep the limits a running answer has (found in review): the e-stop release
/// ramp, also when the release comes right behind the pause, and a lowered force_max_n, which a
/// running answer meets from the set's ack on (the rate clamp held it above the new limit once).
/// Before, a pause 30 ms into a 330 ms release ramp jumped from 0.016 to 0.083 N (this test on the
/// old server; it stops there); the reviewer's scratch test also had a release sent with a pause
/// give 0.059 N at once, and a pause lift a 0.01 N limit to 0.024 N.
static int pause_keeps_limits(void) {
    char scene[512];
    snprintf(scene, sizeof scene, "%s/liver_pause.json", tmpdir);
    liver_scene(scene, NULL);
    ENSURE(start_server(scene, "pause") == 0);
    client c;
    ENSURE(client_open(&c) == 0);
    ENSURE(wait_up(&c));
    const int OK = HAPSIM_COMMAND_ACK_T_STATUS_OK;
    // 10 N/s: the release ramp takes force_max_n / 10 N/s (330 ms), longer than the pause's 20 ms
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "force_rate_max_n_per_s", "value",
                   "10", NULL) == OK);
    stream(&c, -0.010, 0.004, 500);
    stream(&c, 0.004, 0.004, 800);
    double full = norm3(c.force.force);
    ENSURE(dot_n(c.force.force) > 0.02);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_ESTOP, NULL, NULL, NULL, NULL, NULL) == OK);
    stream(&c, 0.004, 0.004, 50);
    ENSURE(norm3(c.force.force) == 0);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE, NULL, NULL, NULL, NULL, NULL) == OK);
    stream(&c, 0.004, 0.004, 30);
    double ramp = norm3(c.force.force);
    int from = c.n_flog;
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_PAUSE, NULL, NULL, NULL, NULL, NULL) == OK);
    stream(&c, 0.004, 0.004, 25);
    double paused = max_force_since(&c, from);
    printf("  full %.4f N; 30 ms into the release ramp %.4f N; paused then at most %.4f N\n", full,
           ramp, paused);
    ENSURE(ramp < 0.5 * full && paused <= 1.2 * ramp + 1e-3);

    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_RESUME, NULL, NULL, NULL, NULL, NULL) == OK);
    stream(&c, 0.004, 0.004, 1200);
    full = norm3(c.force.force);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_ESTOP, NULL, NULL, NULL, NULL, NULL) == OK);
    stream(&c, 0.004, 0.004, 20);
    from = c.n_flog;
    send_command(&c, ++next_request, HAPSIM_COMMAND_T_KIND_PAUSE, NULL, NULL, NULL, NULL);
    send_command(&c, ++next_request, HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE, NULL, NULL, NULL, NULL);
    stream(&c, 0.004, 0.004, 25);
    paused = max_force_since(&c, from);
    printf("  full %.4f N; e-stop, then pause and release together: at most %.4f N\n", full,
           paused);
    ENSURE(paused <= 0.05 * full);

    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_RESUME, NULL, NULL, NULL, NULL, NULL) == OK);
    stream(&c, 0.004, 0.004, 1200);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "force_rate_max_n_per_s", "value",
                   "1", NULL) == OK); // the rate clamp alone would hold the force above 0.01 N
    stream(&c, 0.004, 0.004, 100);
    double before = norm3(c.force.force);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "force_max_n", "value", "0.01",
                   NULL) == OK);
    from = c.n_flog;
    stream(&c, 0.004, 0.004, 30);
    double running = max_force_since(&c, from);
    printf("  %.4f N, then force_max_n 0.01 N under a 1 N/s rate limit: at most %.4f N\n", before,
           running);
    ENSURE(before > 0.05 && c.n_flog - from >= 20 && running <= 0.01 + 1e-9);
    from = c.n_flog;
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_PAUSE, NULL, NULL, NULL, NULL, NULL) == OK);
    stream(&c, 0.004, 0.004, 30);
    paused = max_force_since(&c, from);
    printf("  force_max_n 0.01 N, then paused: at most %.4f N\n", paused);
    ENSURE(paused <= 0.01 + 1e-9);
    // Repeated commands in each state are no-ops, and no transition was refused (the server's
    // state machine says "internal: event ... refused" on stderr when one is).
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_PAUSE, NULL, NULL, NULL, NULL, NULL) == OK);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_RESUME, NULL, NULL, NULL, NULL, NULL) == OK);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_RESUME, NULL, NULL, NULL, NULL, NULL) == OK);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE, NULL, NULL, NULL, NULL, NULL) == OK);
    ENSURE(stop_server() == 0);
    client_close(&c);
    static char log[1 << 16];
    ENSURE(read_server_log("pause", log, sizeof log) == 0);
    ENSURE(strstr(log, "hapsim-server: stopped after") && !strstr(log, "internal: event"));
    return 0;
}

/// The clutch decouples the tool from the hand (docs/protocol.md, "Clutch"). Before, the force
/// followed the hand for the whole watchdog (0.20 -> 0.38 N while labelled RAMP), jumped 0.19 N
/// within 2 ms and ended STOPPED. Held while the hand presses 8 mm deeper: no answer exceeds the
/// force at clutch-down, none carries stiffness, RAMP then FREE at zero. Released there: the tool
/// goes on from where it stayed (the force comes back to about the clutch-down force, anchored at
/// the hand) and no two answers differ by more than the rate limit allows.
static int clutch_ignores_motion(void) {
    char scene[512];
    snprintf(scene, sizeof scene, "%s/liver_clutch.json", tmpdir);
    liver_scene(scene, NULL);
    ENSURE(start_server(scene, "clutch") == 0);
    client c;
    ENSURE(client_open(&c) == 0);
    ENSURE(wait_up(&c));
    const double rate = 20; // N/s
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "force_rate_max_n_per_s", "value",
                   "20", NULL) == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    stream(&c, -0.010, 0.004, 500);
    stream(&c, 0.004, 0.004, 800);
    double down = norm3(c.force.force);
    ENSURE(c.force.state == HAPSIM_TOOL_FORCE_T_STATE_CONTACT && dot_n(c.force.force) > 0.02);
    int from = c.n_flog;
    const uint32_t CLUTCH = HAPSIM_TOOL_POSE_T_BUTTON_CLUTCH;
    stream_buttons(&c, 0.004, 0.012, 400, CLUTCH);
    int held = c.n_flog, free_from = -1, bad_state = 0;
    double stiff = 0;
    for (int i = from; i < held; ++i) {
        stiff = fmax(stiff, c.flog_stiff[i]);
        if (c.flog_state[i] == HAPSIM_TOOL_FORCE_T_STATE_FREE && free_from < 0) free_from = i;
        if (c.flog_state[i] !=
            (free_from < 0 ? HAPSIM_TOOL_FORCE_T_STATE_RAMP : HAPSIM_TOOL_FORCE_T_STATE_FREE))
            bad_state++;
    }
    double clutched_max = max_force_since(&c, from);
    printf("  %.4f N at clutch-down; clutched, hand 8 mm deeper: at most %.4f N, zero after %d of "
           "%d answers, %d in a wrong state, stiffness up to %.1f N/m, end %.4f N state %d\n",
           down, clutched_max, free_from - from, held - from, bad_state, stiff,
           norm3(c.force.force), c.force.state);
    ENSURE(held - from > 300 && clutched_max <= down + 1e-9 && bad_state == 0 && free_from > from);
    ENSURE(norm3(c.force.force) == 0 && stiff == 0 &&
           c.force.state == HAPSIM_TOOL_FORCE_T_STATE_FREE);
    stream(&c, 0.012, 0.012, 600); // released where the hand is now
    double hand[3], off = 0;
    probe_at(0.012, hand);
    for (int k = 0; k < 3; ++k) off = fmax(off, fabs(c.force.anchor[k] - hand[k]));
    double back = norm3(c.force.force), jump = 0;
    for (int i = from + 1; i < c.n_flog; ++i) {
        double dt = (double)(c.flog_utime[i] - c.flog_utime[i - 1]) * 1e-6;
        double over = fabs(c.flog_norm[i] - c.flog_norm[i - 1]) - rate * (fabs(dt) + 1e-3);
        jump = fmax(jump, over);
    }
    printf("  released: %.4f N, anchor %.2f mm from the hand, state %d; worst step over the rate "
           "limit %.5f N\n",
           back, off * 1e3, c.force.state, jump);
    ENSURE(c.force.state == HAPSIM_TOOL_FORCE_T_STATE_CONTACT);
    ENSURE(back > 0.7 * down && back < 1.3 * down && off < 1e-3 && jump <= 1e-6);
    // A quick clutch: released 30 ms into the ramp down, the ramp back in starts where it was.
    from = c.n_flog;
    stream_buttons(&c, 0.012, 0.012, 30, CLUTCH);
    double low = c.flog_norm[c.n_flog - 1];
    stream(&c, 0.012, 0.012, 400);
    jump = 0;
    for (int i = from + 1; i < c.n_flog; ++i) {
        double dt = (double)(c.flog_utime[i] - c.flog_utime[i - 1]) * 1e-6;
        jump = fmax(jump, fabs(c.flog_norm[i] - c.flog_norm[i - 1]) - rate * (fabs(dt) + 1e-3));
    }
    printf("  quick clutch: %.4f N after 30 ms held, %.4f N 400 ms after release; worst step over "
           "the rate limit %.5f N\n",
           low, norm3(c.force.force), jump);
    ENSURE(low > 0.5 * back && low < back && jump <= 1e-6);
    ENSURE(norm3(c.force.force) > 0.7 * down && c.force.state == HAPSIM_TOOL_FORCE_T_STATE_CONTACT);
    ENSURE(stop_server() == 0);
    client_close(&c);
    return 0;
}

/// A server started while a driver streams serves it. Before, it answered the poses while it
/// listened for another server, heard its own forces and refused to start as a second server.
static int starts_under_a_streaming_driver(void) {
    char scene[512];
    snprintf(scene, sizeof scene, "%s/liver_streamed.json", tmpdir);
    liver_scene(scene, NULL);
    client c;
    ENSURE(client_open(&c) == 0);
    stream(&c, -0.003, -0.003, 100);
    ENSURE(start_server(scene, "streamed") == 0);
    int64_t end = hs_now_ns() + 20000000000LL;
    while ((c.n_status == 0 || strstr(c.status->warnings, "compliance set-up")) &&
           hs_now_ns() < end && server_alive())
        stream(&c, -0.003, -0.003, 20);
    ENSURE(server_alive() && c.n_status > 0);
    stream(&c, -0.003, -0.003, 100);
    ENSURE(c.force.pose_seq == c.seq);
    ENSURE(stop_server() == 0);
    client_close(&c);
    return 0;
}

static int set_after_mesh_changed(void) {
    char mesh[512], scene[512], src[512];
    snprintf(src, sizeof src, "%s/scenes/liver/liver2.msh", HS_SOURCE_DIR);
    snprintf(mesh, sizeof mesh, "%s/liver_copy.msh", tmpdir);
    snprintf(scene, sizeof scene, "%s/liver_copy.json", tmpdir);
    FILE* f = fopen(src, "rb");
    ENSURE(f);
    static char text[4 << 20];
    size_t n = fread(text, 1, sizeof text - 1, f);
    fclose(f);
    ENSURE(n > 0 && n < sizeof text - 1);
    text[n] = '\0';
    f = fopen(mesh, "wb");
    ENSURE(f && fwrite(text, 1, n, f) == n && fclose(f) == 0);
    char body[1024];
    snprintf(
        body, sizeof body,
        "{ \"mesh\": \"liver_copy.msh\",\n"
        "  \"material\": {\"youngs_pa\": 5000, \"poisson\": 0.45, \"density_kg_m3\": 1060},\n"
        "  \"fixed\": [{\"type\": \"plane\", \"point\": [0, -0.0433, 0], \"normal\": [0, 1, 0]}],\n"
        "  \"gravity\": [0, 0, 0],\n"
        "  \"tools\": [{\"kind\": \"probe\", \"radius\": %g}],\n"
        "  \"workspace\": {\"min\": [-0.25, -0.2, -0.2], \"max\": [0.25, 0.25, 0.2]} }\n",
        PROBE_R);
    write_file(scene, body);
    ENSURE(start_server(scene, "meshchg") == 0);
    client c;
    ENSURE(client_open(&c) == 0);
    ENSURE(wait_up(&c));
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "youngs_pa", "value", "6000",
                   NULL) == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    // The first node moved by 1 mm in x: same counts, another mesh.
    char* nodes = strstr(text, "$Nodes\n");
    ENSURE(nodes);
    char* line = strchr(nodes + 7, '\n') + 1; // past the count: "1 x y z"
    char* end = strchr(line, '\n');
    int id = 0;
    double x, y, z;
    ENSURE(sscanf(line, "%d %lf %lf %lf", &id, &x, &y, &z) == 4 && id == 1);
    f = fopen(mesh, "wb");
    ENSURE(f);
    fwrite(text, 1, (size_t)(line - text), f);
    fprintf(f, "1 %.17g %.17g %.17g", x + 1e-3, y, z);
    fwrite(end, 1, n - (size_t)(end - text), f);
    ENSURE(fclose(f) == 0);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "youngs_pa", "value", "7000",
                   NULL) == HAPSIM_COMMAND_ACK_T_STATUS_FAILED);
    // The running scene went on, and a reset reads the edited file (a new topology).
    int64_t topo = c.topo_version;
    stream(&c, -0.010, 0.003, 300);
    ENSURE(dot_n(c.force.force) > 0.005);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_RESET, NULL, NULL, NULL, NULL, NULL) ==
           HAPSIM_COMMAND_ACK_T_STATUS_OK);
    ENSURE(command(&c, HAPSIM_COMMAND_T_KIND_SET_PARAM, "name", "youngs_pa", "value", "7000",
                   NULL) == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    pump_ms(&c, 200);
    ENSURE(c.topo_version > topo);
    ENSURE(stop_server() == 0);
    client_close(&c);
    return 0;
}

HS_TEST_MAIN(HS_CASE(malformed_scene_exits_1), HS_CASE(bad_command_lines_refused),
             HS_CASE(poses_in_forces_out), HS_CASE(load_goes_on_answering),
             HS_CASE(set_after_mesh_changed), HS_CASE(set_keeps_body_state),
             HS_CASE(rebuild_keeps_force), HS_CASE(pause_keeps_limits),
             HS_CASE(clutch_ignores_motion), HS_CASE(starts_under_a_streaming_driver),
             HS_CASE(mesh_10k_arrives_whole), HS_CASE(dropped_deltas_recover),
             HS_CASE(flood_leaves_server_intact))
