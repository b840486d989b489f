// SPDX-License-Identifier: GPL-2.0-or-later
// A stand-in mesh server for the client tests (test_client_liver.sh): publishes the bundled
// liver's surface as topology + keyframes + deltas with a dent growing under node 399 (5 mm
// along its inward normal, Gaussian of 8 mm), a server status, and answers commands: the first
// copy of every request id is ignored (as if lost) so a client must retry with the same id;
// SET_PARAM of "bad" is refused;
// LOAD_SCENE is answered PENDING, then OK 300 ms later. Random bytes go out on the mesh and force
// channels too. Links the server's mesh reader (a test tool, not the client).
// With a third argument no-topology it never publishes the topology (as when a receiver's
// socket buffer is too small for it) but still its garbage; no-topology-at-all sends neither.
//   test_client_fakesrv MESH SECONDS [no-topology | no-topology-at-all]
#define _POSIX_C_SOURCE 200809L
#include <lcm/lcm.h>
#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

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

static int64_t now_us(void) {
    struct timespec t;
    clock_gettime(CLOCK_REALTIME, &t);
    return (int64_t)t.tv_sec * 1000000 + t.tv_nsec / 1000;
}

typedef struct cmdstate {
    lcm_t* lcm;
    int64_t ids[256];
    int seen[256];
    int n;
    int executed, ignored, duplicates;
    int64_t ack_seq;
    int64_t load_id, load_done_us; // a LOAD_SCENE in progress: final ack due at load_done_us
} cmdstate;

static void on_command(const lcm_recv_buf_t* rb, const char* ch, const hapsim_command_t* m,
                       void* user) {
    (void)rb;
    (void)ch;
    cmdstate* s = user;
    int k = -1;
    for (int i = 0; i < s->n; i++)
        if (s->ids[i] == m->request_id) k = i;
    if (k < 0 && s->n < 256) {
        k = s->n++;
        s->ids[k] = m->request_id;
        s->seen[k] = 0;
    }
    if (k < 0) return;
    if (s->seen[k]++ == 0) { // first copy: "lost"
        s->ignored++;
        return;
    }
    if (s->seen[k] == 2)
        s->executed++;
    else
        s->duplicates++; // answered again with the recorded status, not executed
    hapsim_command_ack_t a;
    memset(&a, 0, sizeof a);
    a.utime = now_us();
    a.seq = s->ack_seq++;
    a.request_id = m->request_id;
    a.kind = m->kind;
    a.status = HAPSIM_COMMAND_ACK_T_STATUS_OK;
    a.message = "";
    if (m->kind == HAPSIM_COMMAND_T_KIND_LOAD_SCENE) { // PENDING now, final OK 300 ms later
        a.status = HAPSIM_COMMAND_ACK_T_STATUS_PENDING;
        if (!s->load_id) {
            s->load_id = m->request_id;
            s->load_done_us = now_us() + 300000;
        }
    }
    if (m->kind == HAPSIM_COMMAND_T_KIND_SET_PARAM && m->n_args == 2 &&
        !strcmp(m->values[0], "bad")) {
        a.status = HAPSIM_COMMAND_ACK_T_STATUS_INVALID;
        a.message = "unknown parameter 'bad'";
    }
    hapsim_command_ack_t_publish(s->lcm, "HAPSIM_COMMAND_ACK", &a);
}

// Poses answered by an elastic half-space y <= 0.0683 m (300 N/m), like a probe on the liver top.
typedef struct hapstate {
    lcm_t* lcm;
    int64_t seq, poses;
} hapstate;

static void on_pose(const lcm_recv_buf_t* rb, const char* ch, const hapsim_tool_pose_t* p,
                    void* user) {
    (void)rb;
    (void)ch;
    hapstate* h = user;
    h->poses++;
    double pen = 0.0683 - p->position[1];
    hapsim_tool_force_t f;
    memset(&f, 0, sizeof f);
    f.utime = now_us();
    f.seq = h->seq++;
    f.device_id = p->device_id;
    f.pose_seq = p->seq;
    f.pose_utime = p->utime;
    f.model_version = 1;
    f.state = pen > 0 ? HAPSIM_TOOL_FORCE_T_STATE_CONTACT : HAPSIM_TOOL_FORCE_T_STATE_FREE;
    f.force[1] = pen > 0 ? 300 * pen : 0;
    f.stiffness[4] = pen > 0 ? -300 : 0;
    memcpy(f.anchor, p->position, sizeof f.anchor);
    f.validity_radius = 0.002;
    f.timeout_us = 50000;
    hapsim_tool_force_t_publish(h->lcm, "HAPSIM_TOOL_FORCE", &f);
}

int main(int argc, char** argv) {
    if (argc < 3 || argc > 4 ||
        (argc == 4 && strcmp(argv[3], "no-topology") && strcmp(argv[3], "no-topology-at-all"))) {
        fprintf(stderr,
                "usage: test_client_fakesrv MESH SECONDS [no-topology | no-topology-at-all]\n");
        return 2;
    }
    const int send_topology = argc == 3;
    const int junk_topology = argc == 3 || !strcmp(argv[3], "no-topology");
    hs_mesh* mesh = NULL;
    hs_err err = {0};
    if (hs_mesh_load(argv[1], &mesh, &err) < 0) {
        fprintf(stderr, "fakesrv: %s\n", err.msg);
        return 1;
    }
    double seconds = atof(argv[2]);
    lcm_t* lcm = lcm_create(HAPSIM_DEFAULT_MESH_URL);
    if (!lcm) return 1;
    hapstate hs = {lcm_create(HAPSIM_DEFAULT_HAPTIC_URL), 0, 0};
    if (!hs.lcm) return 1;
    hapsim_tool_pose_t_subscription_t* psub =
        hapsim_tool_pose_t_subscribe(hs.lcm, "HAPSIM_TOOL_POSE", on_pose, &hs);
    cmdstate cs;
    memset(&cs, 0, sizeof cs);
    cs.lcm = lcm;
    hapsim_command_t_subscription_t* sub =
        hapsim_command_t_subscribe(lcm, "HAPSIM_COMMAND", on_command, &cs);

    int n = mesh->n_surf_nodes, press = mesh->node_surf[399];
    float* rest = malloc((size_t)n * 3 * sizeof(float));
    float* pos = malloc((size_t)n * 3 * sizeof(float));
    float* kf = malloc((size_t)n * 3 * sizeof(float));
    float* dl = malloc((size_t)n * 3 * sizeof(float));
    int32_t* idx = malloc((size_t)n * sizeof(int32_t));
    int32_t* vis = malloc((size_t)n * sizeof(int32_t));
    int32_t* tri = malloc((size_t)mesh->n_tris * 3 * sizeof(int32_t));
    for (int i = 0; i < n; i++) {
        vis[i] = mesh->surf_nodes[i];
        for (int k = 0; k < 3; k++) rest[3 * i + k] = (float)mesh->x0[3 * vis[i] + k];
    }
    for (int t = 0; t < 3 * mesh->n_tris; t++) tri[t] = mesh->node_surf[mesh->tris[t]];
    const double nrm[3] = {0.105, 0.993, -0.045};
    hapsim_mesh_topology_t top = {0};
    top.topology_version = 1;
    top.n_nodes = mesh->n_nodes;
    top.n_vis = n;
    top.vis_nodes = vis;
    top.n_rest = 3 * n;
    top.rest_position = rest;
    top.n_tri_idx = 3 * mesh->n_tris;
    top.triangles = tri;
    top.tets = tri; // n_tet_idx = 0: not read, but must not be NULL for LCM's encoder
    int64_t t0 = now_us(), next_top = t0, next_kf = t0, next_status = t0, kf_id = 0;
    int64_t seq_t = 0, seq_s = 0, seq_d = 0, seq_st = 0, step = 0;
    memcpy(pos, rest, (size_t)n * 3 * sizeof(float));
    memcpy(kf, rest, (size_t)n * 3 * sizeof(float));
    while (now_us() - t0 < (int64_t)(seconds * 1e6)) {
        int64_t now = now_us();
        double t = (double)(now - t0) * 1e-6;
        double depth = t < 1 ? 0 : t < 3 ? 0.005 * (t - 1) / 2 : 0.005;
        for (int i = 0; i < n; i++) {
            double r2 = 0;
            for (int k = 0; k < 3; k++) {
                double d = (double)rest[3 * i + k] - rest[3 * press + k];
                r2 += d * d;
            }
            double w = depth * exp(-r2 / (2 * 0.008 * 0.008));
            for (int k = 0; k < 3; k++) pos[3 * i + k] = (float)(rest[3 * i + k] - w * nrm[k]);
        }
        step++;
        if (send_topology && now >= next_top) {
            top.utime = now;
            top.seq = seq_t++;
            hapsim_mesh_topology_t_publish(lcm, "HAPSIM_MESH_TOPOLOGY", &top);
            next_top = now + 1000000;
        }
        if (now >= next_kf) {
            memcpy(kf, pos, (size_t)n * 3 * sizeof(float));
            hapsim_mesh_state_t st = {0};
            st.utime = now;
            st.seq = seq_s++;
            st.topology_version = 1;
            st.keyframe_id = ++kf_id;
            st.sim_step = step;
            st.sim_time = t;
            st.n_pos = 3 * n;
            st.position = kf;
            hapsim_mesh_state_t_publish(lcm, "HAPSIM_MESH_STATE", &st);
            next_kf = now + 500000;
        } else {
            hapsim_mesh_delta_t d = {0};
            d.utime = now;
            d.seq = seq_d++;
            d.topology_version = 1;
            d.keyframe_id = kf_id;
            d.sim_step = step;
            d.sim_time = t;
            for (int i = 0; i < n; i++)
                if (memcmp(pos + 3 * i, kf + 3 * i, 12)) {
                    idx[d.n_changed] = i;
                    for (int k = 0; k < 3; k++)
                        dl[3 * d.n_changed + k] = pos[3 * i + k] - kf[3 * i + k];
                    d.n_changed++;
                }
            d.index = idx;
            d.n_delta = 3 * d.n_changed;
            d.delta = dl;
            hapsim_mesh_delta_t_publish(lcm, "HAPSIM_MESH_DELTA", &d);
        }
        // Garbage on the mesh and haptic channels: clients must count and drop it.
        uint8_t junk[64];
        for (int k = 0; k < 64; k++) junk[k] = (uint8_t)(rand() & 0xff);
        lcm_publish(lcm, step % 2 || !junk_topology ? "HAPSIM_MESH_DELTA" : "HAPSIM_MESH_TOPOLOGY",
                    junk, (unsigned)(8 + rand() % 56));
        lcm_publish(hs.lcm, "HAPSIM_TOOL_FORCE", junk, (unsigned)(rand() % 64));
        if (cs.load_id && now >= cs.load_done_us) {
            hapsim_command_ack_t a;
            memset(&a, 0, sizeof a);
            a.utime = now;
            a.seq = cs.ack_seq++;
            a.request_id = cs.load_id;
            a.kind = HAPSIM_COMMAND_T_KIND_LOAD_SCENE;
            a.status = HAPSIM_COMMAND_ACK_T_STATUS_OK;
            a.message = "scene loaded";
            hapsim_command_ack_t_publish(lcm, "HAPSIM_COMMAND_ACK", &a);
            cs.load_id = 0;
        }
        if (now >= next_status) {
            hapsim_server_status_t s = {0};
            s.utime = now;
            s.seq = seq_st++;
            s.uptime_us = now - t0;
            s.scene = "fake-liver";
            s.topology_version = 1;
            s.warnings = "";
            // Empty arrays still need valid pointers (LCM's encoder memcpy's them).
            static char* no_str[1];
            static float no_f[1];
            static int64_t no_i64[1];
            static int32_t no_i32[1];
            static int8_t no_i8[1];
            s.loop_name = s.step_name = s.reject_channel = s.reject_reason = no_str;
            s.rate_hz = s.period_p50_us = s.period_p99_us = s.period_max_us = no_f;
            s.step_p50_us = s.step_p99_us = s.step_max_us = no_f;
            s.pose_age_ms = s.latency_p50_us = s.latency_p99_us = s.force_norm = no_f;
            s.overruns = s.poses_received = s.poses_lost = s.reject_count = no_i64;
            s.device_id = no_i32;
            s.device_live = no_i8;
            hapsim_server_status_t_publish(lcm, "HAPSIM_SERVER_STATUS", &s);
            next_status = now + 500000;
        }
        // ~30 frames per second; commands are handled while waiting.
        int64_t until = now + 33000;
        for (;;) {
            int64_t left = until - now_us();
            if (left <= 0) break;
            struct pollfd p[2] = {{lcm_get_fileno(lcm), POLLIN, 0},
                                  {lcm_get_fileno(hs.lcm), POLLIN, 0}};
            if (poll(p, 2, (int)(left / 1000) + 1) > 0) {
                if (p[0].revents & POLLIN) lcm_handle(lcm);
                if (p[1].revents & POLLIN) lcm_handle(hs.lcm);
            }
        }
    }
    printf("fakesrv: %lld poses answered\n", (long long)hs.poses);
    printf("fakesrv: %lld frames; commands: %d executed, %d first copies ignored, %d duplicates "
           "answered\n",
           (long long)step, cs.executed, cs.ignored, cs.duplicates);
    hapsim_command_t_unsubscribe(lcm, sub);
    hapsim_tool_pose_t_unsubscribe(hs.lcm, psub);
    lcm_destroy(hs.lcm);
    lcm_destroy(lcm);
    hs_mesh_destroy(&mesh);
    free(rest);
    free(pos);
    free(kf);
    free(dl);
    free(idx);
    free(vis);
    free(tri);
    return cs.executed == cs.ignored ? 0 : 3;
}
