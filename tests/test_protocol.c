// SPDX-License-Identifier: GPL-2.0-or-later
// Protocol: encode/decode round trips of every message type, the inbound validators (one case
// per rejection reason, good input accepted), and a flood of random and corrupted payloads.
#include <stdint.h>
#include <stdlib.h>

#include "test_macros.h"

#include "base.h"
#include "hapsim_channels.h"
#include "hapsim_command_t.h"
#include "hapsim_command_ack_t.h"
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

// Encode any lcm-gen type into a fresh malloc'd buffer (LCM's own allocator, as its publish does).
#define ENCODE(type, msg, buf, len)                                                                \
    do {                                                                                           \
        len = type##_encoded_size(msg);                                                            \
        buf = malloc((size_t)len);                                                                 \
        ENSURE(buf != NULL);                                                                       \
        ENSURE(type##_encode(buf, 0, len, msg) == len);                                            \
    } while (0)

static uint64_t rng_state = 0x9e3779b97f4a7c15ull;
static uint64_t rng(void) {
    rng_state ^= rng_state << 13;
    rng_state ^= rng_state >> 7;
    rng_state ^= rng_state << 17;
    return rng_state;
}

// ---------------------------------------------------------------------------------------------
// Round trips

static int roundtrip_tool_pose_force_state(void) {
    hapsim_tool_pose_t p = {.utime = 123456789,
                            .seq = 42,
                            .session = -7,
                            .device_id = 1,
                            .tool_id = 0,
                            .position = {0.01, -0.02, 0.03},
                            .orientation = {0.5, 0.5, -0.5, 0.5},
                            .buttons = 3};
    uint8_t* b;
    int n;
    ENCODE(hapsim_tool_pose_t, &p, b, n);
    ENSURE(n == 100); // the validator's fixed wire size
    hapsim_tool_pose_t q;
    ENSURE(hapsim_tool_pose_t_decode(b, 0, n, &q) == n);
    ENSURE(q.utime == p.utime && q.seq == p.seq && q.session == p.session);
    ENSURE(q.device_id == 1 && q.tool_id == 0 && q.buttons == 3);
    ENSURE(memcmp(q.position, p.position, sizeof q.position) == 0);
    ENSURE(memcmp(q.orientation, p.orientation, sizeof q.orientation) == 0);
    free(b);

    hapsim_tool_force_t f;
    memset(&f, 0, sizeof f);
    f.utime = 99;
    f.seq = 5;
    f.device_id = 2;
    f.pose_seq = 41;
    f.pose_utime = 123456000;
    f.model_version = 8;
    f.state = HAPSIM_TOOL_FORCE_T_STATE_CONTACT;
    for (int i = 0; i < 3; ++i) f.force[i] = 0.1 * (i + 1), f.anchor[i] = -0.01 * i;
    for (int i = 0; i < 9; ++i) f.stiffness[i] = -100.0 * i;
    f.validity_radius = 0.002;
    f.timeout_us = 20000;
    ENCODE(hapsim_tool_force_t, &f, b, n);
    hapsim_tool_force_t g;
    memset(&g, 0, sizeof g); // padding too, so the structs compare bytewise
    ENSURE(hapsim_tool_force_t_decode(b, 0, n, &g) == n);
    ENSURE(memcmp(&f, &g, sizeof f) == 0); // no pointers: the whole struct compares
    free(b);

    hapsim_tool_state_t s;
    memset(&s, 0, sizeof s);
    s.utime = 1;
    s.seq = 2;
    s.device_id = 0;
    s.tool_id = 1;
    s.kind = HAPSIM_TOOL_STATE_T_KIND_SCALPEL;
    s.orientation[0] = 1;
    s.radius = 0.005;
    s.blade_b[2] = 0.02;
    s.force[1] = -1.5;
    s.contact = 1;
    s.cutting = 1;
    ENCODE(hapsim_tool_state_t, &s, b, n);
    hapsim_tool_state_t t;
    memset(&t, 0, sizeof t);
    ENSURE(hapsim_tool_state_t_decode(b, 0, n, &t) == n);
    ENSURE(memcmp(&s, &t, sizeof s) == 0);
    free(b);
    return 0;
}

static int roundtrip_mesh(void) {
    enum { NV = 1000, NT = 600 };
    static int32_t vis[NV], tris[3 * NT], tets[4 * 10], idx[NV];
    static float rest[3 * NV], pos[3 * NV], stress[NV], delta[3 * NV];
    for (int i = 0; i < NV; ++i) vis[i] = 2 * i, stress[i] = (float)i * 10.0f, idx[i] = i;
    for (int i = 0; i < 3 * NV; ++i) {
        rest[i] = (float)(rng() % 1000) * 1e-4f;
        pos[i] = rest[i] + 1e-3f;
        delta[i] = -1e-4f * (float)(i % 7);
    }
    for (int i = 0; i < 3 * NT; ++i) tris[i] = (int32_t)(rng() % NV);
    for (int i = 0; i < 40; ++i) tets[i] = i;

    hapsim_mesh_topology_t top = {.utime = 10,
                                  .seq = 1,
                                  .topology_version = 3,
                                  .n_nodes = 2 * NV,
                                  .n_vis = NV,
                                  .vis_nodes = vis,
                                  .n_rest = 3 * NV,
                                  .rest_position = rest,
                                  .n_tri_idx = 3 * NT,
                                  .triangles = tris,
                                  .n_tet_idx = 40,
                                  .tets = tets};
    uint8_t* b;
    int n;
    ENCODE(hapsim_mesh_topology_t, &top, b, n);
    hapsim_mesh_topology_t top2;
    memset(&top2, 0, sizeof top2);
    ENSURE(hapsim_mesh_topology_t_decode(b, 0, n, &top2) == n);
    ENSURE(top2.topology_version == 3 && top2.n_vis == NV && top2.n_nodes == 2 * NV);
    ENSURE(memcmp(top2.vis_nodes, vis, sizeof vis) == 0);
    ENSURE(memcmp(top2.rest_position, rest, sizeof rest) == 0);
    ENSURE(memcmp(top2.triangles, tris, sizeof tris) == 0);
    ENSURE(memcmp(top2.tets, tets, sizeof tets) == 0);
    hapsim_mesh_topology_t_decode_cleanup(&top2);
    free(b);

    hapsim_mesh_state_t ks = {.utime = 11,
                              .seq = 2,
                              .topology_version = 3,
                              .keyframe_id = 9,
                              .sim_step = 100,
                              .sim_time = 0.5,
                              .n_pos = 3 * NV,
                              .position = pos,
                              .n_stress = NV,
                              .stress = stress};
    ENCODE(hapsim_mesh_state_t, &ks, b, n);
    // float32 keeps a keyframe near 12 bytes per node (+ 4 for stress) plus a fixed header.
    ENSURE(n == 8 + 5 * 8 + 8 + 4 + 12 * NV + 4 + 4 * NV);
    hapsim_mesh_state_t ks2;
    memset(&ks2, 0, sizeof ks2);
    ENSURE(hapsim_mesh_state_t_decode(b, 0, n, &ks2) == n);
    ENSURE(ks2.keyframe_id == 9 && ks2.sim_time == 0.5 && ks2.n_pos == 3 * NV);
    ENSURE(memcmp(ks2.position, pos, sizeof pos) == 0);
    ENSURE(memcmp(ks2.stress, stress, sizeof stress) == 0);
    hapsim_mesh_state_t_decode_cleanup(&ks2);
    free(b);

    hapsim_mesh_delta_t d = {.utime = 12,
                             .seq = 3,
                             .topology_version = 3,
                             .keyframe_id = 9,
                             .sim_step = 101,
                             .sim_time = 0.51,
                             .n_changed = NV / 2,
                             .index = idx,
                             .n_delta = 3 * (NV / 2),
                             .delta = delta};
    ENCODE(hapsim_mesh_delta_t, &d, b, n);
    hapsim_mesh_delta_t d2;
    memset(&d2, 0, sizeof d2);
    ENSURE(hapsim_mesh_delta_t_decode(b, 0, n, &d2) == n);
    ENSURE(d2.n_changed == NV / 2 && d2.n_delta == 3 * (NV / 2) && d2.keyframe_id == 9);
    ENSURE(memcmp(d2.index, idx, sizeof(int32_t) * (NV / 2)) == 0);
    ENSURE(memcmp(d2.delta, delta, sizeof(float) * 3 * (NV / 2)) == 0);
    hapsim_mesh_delta_t_decode_cleanup(&d2);
    free(b);

    int32_t removed[3] = {5, 6, 70}, moved[2] = {1, 400};
    float moved_rest[6] = {1, 2, 3, 4, 5, 6};
    hapsim_topology_event_t ev = {.utime = 13,
                                  .seq = 4,
                                  .old_version = 3,
                                  .new_version = 4,
                                  .device_id = 0,
                                  .n_removed = 3,
                                  .removed_tets = removed,
                                  .n_moved = 2,
                                  .moved_nodes = moved,
                                  .n_moved_rest = 6,
                                  .moved_rest = moved_rest};
    for (int i = 0; i < 12; ++i) ev.swept_quad[i] = 0.001f * (float)i;
    ENCODE(hapsim_topology_event_t, &ev, b, n);
    hapsim_topology_event_t ev2;
    memset(&ev2, 0, sizeof ev2);
    ENSURE(hapsim_topology_event_t_decode(b, 0, n, &ev2) == n);
    ENSURE(ev2.new_version == 4 && ev2.n_removed == 3 && ev2.removed_tets[2] == 70);
    ENSURE(ev2.moved_nodes[1] == 400 && ev2.moved_rest[5] == 6.0f);
    ENSURE(memcmp(ev2.swept_quad, ev.swept_quad, sizeof ev.swept_quad) == 0);
    hapsim_topology_event_t_decode_cleanup(&ev2);
    free(b);
    return 0;
}

static int roundtrip_command_ack_status(void) {
    char* keys[2] = {"name", "value"};
    char* vals[2] = {"haptic.k_max", "1500"};
    hapsim_command_t c = {.utime = 5,
                          .seq = 6,
                          .request_id = 77,
                          .kind = HAPSIM_COMMAND_T_KIND_SET_PARAM,
                          .n_args = 2,
                          .keys = keys,
                          .values = vals,
                          .sender = "test"};
    uint8_t* b;
    int n;
    ENCODE(hapsim_command_t, &c, b, n);
    hapsim_command_t c2;
    memset(&c2, 0, sizeof c2);
    ENSURE(hapsim_command_t_decode(b, 0, n, &c2) == n);
    ENSURE(c2.request_id == 77 && c2.n_args == 2 && strcmp(c2.values[0], "haptic.k_max") == 0);
    ENSURE(strcmp(c2.sender, "test") == 0);
    hapsim_command_t_decode_cleanup(&c2);
    free(b);

    hapsim_command_ack_t a = {.utime = 1,
                              .seq = 2,
                              .request_id = 77,
                              .kind = 5,
                              .status = HAPSIM_COMMAND_ACK_T_STATUS_FAILED,
                              .message = "no such"};
    ENCODE(hapsim_command_ack_t, &a, b, n);
    hapsim_command_ack_t a2;
    memset(&a2, 0, sizeof a2);
    ENSURE(hapsim_command_ack_t_decode(b, 0, n, &a2) == n);
    ENSURE(a2.status == -2 && a2.request_id == 77 && strcmp(a2.message, "no such") == 0);
    hapsim_command_ack_t_decode_cleanup(&a2);
    free(b);

    char* loops[3] = {"rt", "sim", "net"};
    float rate[3] = {1000, 60, 500}, p50[3] = {1000, 16000, 2000}, p99[3] = {1300, 20000, 3000};
    float pmax[3] = {2000, 30000, 9000};
    int64_t over[3] = {3, 0, 0};
    char* steps[1] = {"solve"};
    float s50[1] = {800}, s99[1] = {1200}, smax[1] = {1500};
    int32_t dev[1] = {0};
    int8_t live[1] = {1};
    float age[1] = {0.4f}, l50[1] = {60}, l99[1] = {300}, fn[1] = {1.2f};
    int64_t rx[1] = {12345}, lost[1] = {2};
    char* rch[2] = {"TOOL_POSE", "COMMAND"};
    char* rre[2] = {"nonfinite", "duplicate"};
    int64_t rc[2] = {10, 1};
    hapsim_server_status_t st = {.utime = 3,
                                 .seq = 4,
                                 .uptime_us = 1000000,
                                 .state = HAPSIM_SERVER_STATUS_T_STATE_RUNNING,
                                 .scene = "scenes/liver/liver.json",
                                 .topology_version = 1,
                                 .n_loops = 3,
                                 .loop_name = loops,
                                 .rate_hz = rate,
                                 .period_p50_us = p50,
                                 .period_p99_us = p99,
                                 .period_max_us = pmax,
                                 .overruns = over,
                                 .n_steps = 1,
                                 .step_name = steps,
                                 .step_p50_us = s50,
                                 .step_p99_us = s99,
                                 .step_max_us = smax,
                                 .n_devices = 1,
                                 .device_id = dev,
                                 .device_live = live,
                                 .pose_age_ms = age,
                                 .poses_received = rx,
                                 .poses_lost = lost,
                                 .latency_p50_us = l50,
                                 .latency_p99_us = l99,
                                 .force_norm = fn,
                                 .n_rejects = 2,
                                 .reject_channel = rch,
                                 .reject_reason = rre,
                                 .reject_count = rc,
                                 .warnings = ""};
    ENCODE(hapsim_server_status_t, &st, b, n);
    hapsim_server_status_t st2;
    memset(&st2, 0, sizeof st2);
    ENSURE(hapsim_server_status_t_decode(b, 0, n, &st2) == n);
    ENSURE(st2.n_loops == 3 && strcmp(st2.loop_name[2], "net") == 0 && st2.rate_hz[1] == 60);
    ENSURE(st2.overruns[0] == 3 && st2.poses_lost[0] == 2 && st2.device_live[0] == 1);
    ENSURE(st2.n_rejects == 2 && strcmp(st2.reject_reason[1], "duplicate") == 0);
    ENSURE(st2.reject_count[0] == 10 && strcmp(st2.scene, "scenes/liver/liver.json") == 0);
    hapsim_server_status_t_decode_cleanup(&st2);
    free(b);

    char ch[HAPSIM_CHANNEL_MAX];
    ENSURE(hapsim_channel_name(ch, sizeof ch, HAPSIM_DEFAULT_PREFIX, HAPSIM_CH_TOOL_POSE) == 0);
    ENSURE(strcmp(ch, "HAPSIM_TOOL_POSE") == 0);
    ENSURE(hapsim_channel_name(ch, 8, "LONGPREFIX_", HAPSIM_CH_TOOL_POSE) == -1 && ch[0] == 0);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Pose validation

static hs_net_limits test_limits(void) {
    hs_net_limits l = hs_net_default_limits();
    l.n_devices = 2;
    l.n_tools = 2;
    return l;
}

static hapsim_tool_pose_t good_pose(int64_t seq) {
    hapsim_tool_pose_t p = {.utime = 1000 + seq,
                            .seq = seq,
                            .session = 0x5eed,
                            .device_id = 0,
                            .tool_id = 1,
                            .position = {0.01, 0.02, -0.03},
                            .orientation = {1, 0, 0, 0},
                            .buttons = 0};
    return p;
}

static hs_net_reject send_pose(const hs_net_limits* l, hs_net_pose_state* s,
                               const hapsim_tool_pose_t* p, int64_t now, hs_net_pose* out) {
    uint8_t b[128];
    int n = hapsim_tool_pose_t_encode(b, 0, (int)sizeof b, p);
    if (n != 100) return HS_NET_REJ_COUNT; // cannot happen; makes a test fail loudly
    return hs_net_validate_pose(l, s, b, n, now, out);
}

static int pose_accepts_good(void) {
    hs_net_limits l = test_limits();
    hs_net_pose_state s;
    hs_net_pose_state_init(&s);
    hs_net_pose out;
    hapsim_tool_pose_t p = good_pose(1);
    p.orientation[0] = 0.7071;
    p.orientation[3] = 0.7071; // |q| = 0.99999 within tolerance: renormalised
    p.buttons = HAPSIM_TOOL_POSE_T_BUTTON_PRIMARY;
    ENSURE(send_pose(&l, &s, &p, 10, &out) == HS_NET_ACCEPT);
    ENSURE(out.device_id == 0 && out.tool_id == 1 && out.seq == 1 && out.lost == 0);
    ENSURE(out.position[2] == -0.03 && out.buttons == 1 && out.rx_us == 10);
    ENSURE_NEAR(out.orientation[0] * out.orientation[0] + out.orientation[3] * out.orientation[3],
                1.0, 1e-12);
    p = good_pose(2);
    ENSURE(send_pose(&l, &s, &p, 11, &out) == HS_NET_ACCEPT && out.lost == 0);
    p = good_pose(7); // 3..6 lost
    ENSURE(send_pose(&l, &s, &p, 12, &out) == HS_NET_ACCEPT && out.lost == 4);
    ENSURE(s.dev[0].lost == 4 && s.dev[0].accepted == 3 && s.dev[0].last_seq == 7);
    // The second device has its own seq track.
    p = good_pose(1);
    p.device_id = 1;
    ENSURE(send_pose(&l, &s, &p, 13, &out) == HS_NET_ACCEPT && out.device_id == 1);
    ENSURE(s.counters.received == 4 && s.counters.accepted == 4);
    ENSURE(hs_net_counters_rejected(&s.counters) == 0);
    return 0;
}

// Each bad pose is rejected for its reason, counted once, and leaves the track as it was.
static int pose_rejects_each_reason(void) {
    hs_net_limits l = test_limits();
    hs_net_pose_state s;
    hs_net_pose_state_init(&s);
    hapsim_tool_pose_t p = good_pose(10);
    ENSURE(send_pose(&l, &s, &p, 1000, NULL) == HS_NET_ACCEPT);
    hs_net_device_track before = s.dev[0];

    uint8_t b[128];
    p = good_pose(11);
    int n = hapsim_tool_pose_t_encode(b, 0, (int)sizeof b, &p);
    int64_t expect[HS_NET_REJ_COUNT] = {0};
#define REJ(reason, call)                                                                          \
    do {                                                                                           \
        ENSURE((call) == (reason));                                                                \
        expect[reason]++;                                                                          \
        ENSURE(s.counters.rejected[reason] == (uint64_t)expect[reason]);                           \
        ENSURE(memcmp(&s.dev[0], &before, sizeof before) == 0);                                    \
    } while (0)

    // decode: truncated, trailing byte, empty, NULL, wrong fingerprint (a tool_force).
    REJ(HS_NET_REJ_DECODE, hs_net_validate_pose(&l, &s, b, n - 1, 1001, NULL));
    b[n] = 0;
    REJ(HS_NET_REJ_DECODE, hs_net_validate_pose(&l, &s, b, n + 1, 1001, NULL));
    REJ(HS_NET_REJ_DECODE, hs_net_validate_pose(&l, &s, b, 0, 1001, NULL));
    REJ(HS_NET_REJ_DECODE, hs_net_validate_pose(&l, &s, NULL, 100, 1001, NULL));
    uint8_t wrong[100];
    memcpy(wrong, b, 100);
    wrong[3] ^= 0x10; // fingerprint bit
    REJ(HS_NET_REJ_DECODE, hs_net_validate_pose(&l, &s, wrong, 100, 1001, NULL));

    hapsim_tool_pose_t q = p;
    q.position[1] = NAN;
    REJ(HS_NET_REJ_NONFINITE, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.orientation[2] = INFINITY;
    REJ(HS_NET_REJ_NONFINITE, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.orientation[0] = 1.01;
    REJ(HS_NET_REJ_QUATERNION, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.orientation[0] = 0.0;
    REJ(HS_NET_REJ_QUATERNION, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.position[0] = 5.0; // outside the 2 m box
    REJ(HS_NET_REJ_RANGE, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.buttons = 4; // unknown button bit
    REJ(HS_NET_REJ_RANGE, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.session = 0;
    REJ(HS_NET_REJ_RANGE, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.utime = -1;
    REJ(HS_NET_REJ_RANGE, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.device_id = 2;
    REJ(HS_NET_REJ_UNKNOWN_DEVICE, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.device_id = -1;
    REJ(HS_NET_REJ_UNKNOWN_DEVICE, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.tool_id = 2;
    REJ(HS_NET_REJ_UNKNOWN_TOOL, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.seq = 10; // repeated
    REJ(HS_NET_REJ_SEQ, send_pose(&l, &s, &q, 1001, NULL));
    q.seq = 9; // reordered
    REJ(HS_NET_REJ_SEQ, send_pose(&l, &s, &q, 1001, NULL));
    q.seq = 10 + l.max_seq_jump + 1; // implausible jump (e.g. a corrupted seq)
    REJ(HS_NET_REJ_SEQ, send_pose(&l, &s, &q, 1001, NULL));
    q = p;
    q.session = 0xbad; // a second driver while the first is live
    REJ(HS_NET_REJ_SESSION, send_pose(&l, &s, &q, 1000 + l.session_takeover_us - 1, NULL));
#undef REJ
    // Nothing above changed the track: the next pose in sequence is accepted with no loss.
    hs_net_pose out;
    ENSURE(send_pose(&l, &s, &p, 1002, &out) == HS_NET_ACCEPT && out.lost == 0);
    // A restarted driver (new session, seq from 0) takes over once the old one went quiet.
    q = good_pose(0);
    q.session = 0xbad;
    ENSURE(send_pose(&l, &s, &q, 1002 + l.session_takeover_us, &out) == HS_NET_ACCEPT);
    ENSURE(s.dev[0].session == 0xbad && s.dev[0].last_seq == 0);
    uint64_t rejected = 0;
    for (int r = 0; r < HS_NET_REJ_COUNT; ++r) rejected += (uint64_t)expect[r];
    ENSURE(s.counters.rejected[HS_NET_ACCEPT] == 0);
    ENSURE(hs_net_counters_rejected(&s.counters) == rejected);
    ENSURE(s.counters.received == s.counters.accepted + rejected && s.counters.accepted == 3);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Command validation

static int encode_command(uint8_t* b, int cap, int64_t id, int kind, int n_args, char** keys,
                          char** vals, const char* sender) {
    hapsim_command_t c = {.utime = 1,
                          .seq = 1,
                          .request_id = id,
                          .kind = kind,
                          .n_args = n_args,
                          .keys = keys,
                          .values = vals,
                          .sender = (char*)(uintptr_t)sender};
    return hapsim_command_t_encode(b, 0, cap, &c);
}

static int command_accepts_good(void) {
    hs_net_command_state s;
    hs_net_command_state_init(&s);
    hs_net_command c;
    uint8_t b[4096];
    int n = encode_command(b, sizeof b, 1, HAPSIM_COMMAND_T_KIND_RESET, 0, NULL, NULL, "ctl");
    ENSURE(hs_net_validate_command(&s, b, n, &c, NULL) == HS_NET_ACCEPT);
    ENSURE(c.request_id == 1 && c.kind == HAPSIM_COMMAND_T_KIND_RESET && c.n_args == 0);
    ENSURE(strcmp(c.sender, "ctl") == 0);
    char* k1[1] = {"path"};
    char* v1[1] = {"/tmp/scene with space.json"};
    n = encode_command(b, sizeof b, 2, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, 1, k1, v1, "");
    ENSURE(hs_net_validate_command(&s, b, n, &c, NULL) == HS_NET_ACCEPT);
    ENSURE(strcmp(hs_net_command_arg(&c, "path"), v1[0]) == 0);
    ENSURE(hs_net_command_arg(&c, "name") == NULL);
    char* k2[2] = {"value", "name"};
    char* v2[2] = {"-2.5e3", "haptic.force_max"};
    n = encode_command(b, sizeof b, 3, HAPSIM_COMMAND_T_KIND_SET_PARAM, 2, k2, v2, "x");
    ENSURE(hs_net_validate_command(&s, b, n, &c, NULL) == HS_NET_ACCEPT);
    ENSURE(c.number == -2500.0 && strcmp(hs_net_command_arg(&c, "name"), v2[1]) == 0);
    for (int k = HAPSIM_COMMAND_T_KIND_PAUSE; k <= HAPSIM_COMMAND_T_KIND_REQUEST_TOPOLOGY; ++k) {
        if (k == HAPSIM_COMMAND_T_KIND_LOAD_SCENE || k == HAPSIM_COMMAND_T_KIND_SET_PARAM) continue;
        n = encode_command(b, sizeof b, 100 + k, k, 0, NULL, NULL, "");
        ENSURE(hs_net_validate_command(&s, b, n, &c, NULL) == HS_NET_ACCEPT && c.kind == k);
    }
    ENSURE(s.counters.received == s.counters.accepted && s.counters.accepted == 8);
    return 0;
}

static int command_rejects_each_reason(void) {
    hs_net_command_state s;
    hs_net_command_state_init(&s);
    hs_net_command c;
    uint8_t b[8192];
    int64_t expect[HS_NET_REJ_COUNT] = {0};
#define REJ(reason, len)                                                                           \
    do {                                                                                           \
        ENSURE(hs_net_validate_command(&s, b, (len), &c, NULL) == (reason));                       \
        expect[reason]++;                                                                          \
        ENSURE(s.counters.rejected[reason] == (uint64_t)expect[reason]);                           \
        ENSURE(s.dedup.count == 0);                                                                \
    } while (0)

    // decode: truncated, trailing bytes, wrong fingerprint, string without NUL, string length
    // negative / beyond the buffer, a NUL inside a string.
    int n = encode_command(b, sizeof b, 5, HAPSIM_COMMAND_T_KIND_RESET, 0, NULL, NULL, "abc");
    REJ(HS_NET_REJ_DECODE, n - 1);
    b[n] = 7;
    REJ(HS_NET_REJ_DECODE, n + 1);
    REJ(HS_NET_REJ_DECODE, 5);
    b[0] ^= 1;
    REJ(HS_NET_REJ_DECODE, n);
    b[0] ^= 1;
    // The sender string starts after fingerprint 8 + 3*8 + 4 + 4 = 40 bytes.
    ENSURE(b[43] == 4 && b[40 + 4 + 3] == 0); // length 4 ("abc" + NUL)
    b[47] = 'd';                              // no terminating NUL
    REJ(HS_NET_REJ_DECODE, n);
    b[47] = 0;
    b[45] = 0; // NUL inside
    REJ(HS_NET_REJ_DECODE, n);
    b[45] = 'b';
    b[40] = 0xff; // negative length
    REJ(HS_NET_REJ_DECODE, n);
    b[40] = 0;
    b[43] = 200; // beyond the buffer
    REJ(HS_NET_REJ_DECODE, n);
    b[43] = 4;
    ENSURE(hs_net_validate_command(&s, b, n, &c, NULL) == HS_NET_ACCEPT); // repaired
    hs_net_command_state_init(&s);
    memset(expect, 0, sizeof expect);

    // length: too many arguments, a key longer than 63 bytes, n_args negative on the wire.
    char* keys[9] = {"a", "b", "c", "d", "e", "f", "g", "h", "i"};
    n = encode_command(b, sizeof b, 6, HAPSIM_COMMAND_T_KIND_RESET, 9, keys, keys, "");
    REJ(HS_NET_REJ_LENGTH, n);
    char longkey[65];
    memset(longkey, 'k', 64);
    longkey[64] = 0;
    char* lk[1] = {longkey};
    char* lv[1] = {"x"};
    n = encode_command(b, sizeof b, 6, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, 1, lk, lv, "");
    REJ(HS_NET_REJ_LENGTH, n);
    ENSURE(c.request_id == 6); // readable id: the server can ack INVALID
    n = encode_command(b, sizeof b, 6, HAPSIM_COMMAND_T_KIND_RESET, 0, NULL, NULL, "");
    b[36] = 0xff; // n_args = -1 (bytes 36..39)
    REJ(HS_NET_REJ_LENGTH, n);

    char* kv[2] = {"name", "value"};
    char* vnan[2] = {"a.b", "nan"};
    n = encode_command(b, sizeof b, 7, HAPSIM_COMMAND_T_KIND_SET_PARAM, 2, kv, vnan, "");
    REJ(HS_NET_REJ_NONFINITE, n);
    n = encode_command(b, sizeof b, 0, HAPSIM_COMMAND_T_KIND_RESET, 0, NULL, NULL, "");
    REJ(HS_NET_REJ_RANGE, n); // request id 0
    n = encode_command(b, sizeof b, 8, 99, 0, NULL, NULL, "");
    REJ(HS_NET_REJ_UNKNOWN_KIND, n);
    n = encode_command(b, sizeof b, 8, 0, 0, NULL, NULL, "");
    REJ(HS_NET_REJ_UNKNOWN_KIND, n);
    // argument: missing path, non-numeric value, args where none belong, repeated key,
    // control character, bad key characters.
    n = encode_command(b, sizeof b, 9, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, 0, NULL, NULL, "");
    REJ(HS_NET_REJ_ARGUMENT, n);
    char* vbad[2] = {"a.b", "12abc"};
    n = encode_command(b, sizeof b, 9, HAPSIM_COMMAND_T_KIND_SET_PARAM, 2, kv, vbad, "");
    REJ(HS_NET_REJ_ARGUMENT, n);
    char* k1[1] = {"path"};
    char* v1[1] = {"x.json"};
    n = encode_command(b, sizeof b, 9, HAPSIM_COMMAND_T_KIND_RESET, 1, k1, v1, "");
    REJ(HS_NET_REJ_ARGUMENT, n);
    char* kk[2] = {"path", "path"};
    char* vv[2] = {"a", "b"};
    n = encode_command(b, sizeof b, 9, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, 2, kk, vv, "");
    REJ(HS_NET_REJ_ARGUMENT, n);
    char* vctl[1] = {"a\nb"};
    n = encode_command(b, sizeof b, 9, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, 1, k1, vctl, "");
    REJ(HS_NET_REJ_ARGUMENT, n);
    char* kup[1] = {"Path"};
    n = encode_command(b, sizeof b, 9, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, 1, kup, v1, "");
    REJ(HS_NET_REJ_ARGUMENT, n);
#undef REJ

    // duplicate: the second copy is not executed; its recorded ack status comes back.
    n = encode_command(b, sizeof b, 42, HAPSIM_COMMAND_T_KIND_ESTOP, 0, NULL, NULL, "");
    int32_t prev = 99;
    ENSURE(hs_net_validate_command(&s, b, n, &c, &prev) == HS_NET_ACCEPT && prev == 99);
    ENSURE(hs_net_validate_command(&s, b, n, &c, &prev) == HS_NET_REJ_DUPLICATE);
    ENSURE(prev == HAPSIM_COMMAND_ACK_T_STATUS_PENDING && c.request_id == 42);
    ENSURE(hs_net_dedup_set_status(&s.dedup, 42, HAPSIM_COMMAND_ACK_T_STATUS_OK) == 0);
    ENSURE(hs_net_validate_command(&s, b, n, &c, &prev) == HS_NET_REJ_DUPLICATE);
    ENSURE(prev == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    ENSURE(s.counters.rejected[HS_NET_REJ_DUPLICATE] == 2);
    // The ring remembers the last HS_NET_DEDUP_SIZE ids; older ones may run again.
    for (int i = 0; i < HS_NET_DEDUP_SIZE; ++i) {
        n = encode_command(b, sizeof b, 1000 + i, HAPSIM_COMMAND_T_KIND_PAUSE, 0, NULL, NULL, "");
        ENSURE(hs_net_validate_command(&s, b, n, &c, NULL) == HS_NET_ACCEPT);
    }
    ENSURE(hs_net_dedup_set_status(&s.dedup, 42, 0) == -1);
    n = encode_command(b, sizeof b, 42, HAPSIM_COMMAND_T_KIND_ESTOP, 0, NULL, NULL, "");
    ENSURE(hs_net_validate_command(&s, b, n, &c, NULL) == HS_NET_ACCEPT);
    n = encode_command(b, sizeof b, 1000 + HS_NET_DEDUP_SIZE - 1, HAPSIM_COMMAND_T_KIND_PAUSE, 0,
                       NULL, NULL, "");
    ENSURE(hs_net_validate_command(&s, b, n, &c, NULL) == HS_NET_REJ_DUPLICATE);
    // An id still PENDING (a scene load) outlives finished ones: 100 commands later it is
    // still a duplicate, and its final status still lands.
    n = encode_command(b, sizeof b, 77, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, 1, k1, v1, "");
    ENSURE(hs_net_validate_command(&s, b, n, &c, NULL) == HS_NET_ACCEPT);
    for (int i = 0; i < 100; ++i) {
        n = encode_command(b, sizeof b, 2000 + i, HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE, 0, NULL,
                           NULL, "");
        ENSURE(hs_net_validate_command(&s, b, n, &c, NULL) == HS_NET_ACCEPT);
        ENSURE(hs_net_dedup_set_status(&s.dedup, 2000 + i, HAPSIM_COMMAND_ACK_T_STATUS_OK) == 0);
    }
    n = encode_command(b, sizeof b, 77, HAPSIM_COMMAND_T_KIND_LOAD_SCENE, 1, k1, v1, "");
    ENSURE(hs_net_validate_command(&s, b, n, &c, &prev) == HS_NET_REJ_DUPLICATE);
    ENSURE(prev == HAPSIM_COMMAND_ACK_T_STATUS_PENDING);
    ENSURE(hs_net_dedup_set_status(&s.dedup, 77, HAPSIM_COMMAND_ACK_T_STATUS_OK) == 0);
    ENSURE(s.counters.received == s.counters.accepted + hs_net_counters_rejected(&s.counters));
    for (int r = 0; r < HS_NET_REJ_COUNT; ++r) ENSURE(strlen(hs_net_reject_name(r)) > 0);
    ENSURE(strcmp(hs_net_reject_name(HS_NET_REJ_SEQ), "seq") == 0);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Flood: random bytes, bit-flipped and truncated valid messages. Nothing crashes or allocates,
// and the counters account for every buffer exactly.

static int flood_counts_add_up(void) {
    int64_t bytes0 = hs_byte_count();
    hs_net_limits l = test_limits();
    hs_net_pose_state ps;
    hs_net_command_state cs;
    hs_net_pose_state_init(&ps);
    hs_net_command_state_init(&cs);
    enum { N = 200000 };
    static uint8_t buf[1024];
    uint64_t sent_pose = 0, sent_cmd = 0, accepted_pose = 0, accepted_cmd = 0;
    int64_t seq = 1;
    char* kv[2] = {"name", "value"};
    char* vals[2] = {"solver.tol", "1e-6"};
    for (int i = 0; i < N; ++i) {
        int mode = (int)(rng() % 4);
        int len;
        if (mode == 0) { // random bytes, sometimes with a valid fingerprint in front
            len = (int)(rng() % 300);
            for (int k = 0; k < len; ++k) buf[k] = (uint8_t)rng();
            if (len >= 8 && (rng() & 1)) {
                hapsim_tool_pose_t p = good_pose(1);
                uint8_t tmp[128];
                hapsim_tool_pose_t_encode(tmp, 0, sizeof tmp, &p);
                memcpy(buf, tmp, 8);
            }
        } else if (mode == 1) { // a valid pose, then 1-4 bit flips or a truncation
            hapsim_tool_pose_t p = good_pose(seq++);
            p.device_id = (int32_t)(rng() % 2);
            len = hapsim_tool_pose_t_encode(buf, 0, sizeof buf, &p);
            if (rng() % 8 == 0)
                len = (int)(rng() % (uint64_t)len);
            else
                for (int f = 1 + (int)(rng() % 4); f > 0; --f)
                    buf[rng() % (uint64_t)len] ^= (uint8_t)(1u << (rng() % 8));
        } else { // a valid command, then bit flips or a truncation
            int id = (int)(rng() % 200) + 1;
            len = encode_command(buf, sizeof buf, id, HAPSIM_COMMAND_T_KIND_SET_PARAM, 2, kv, vals,
                                 "flood");
            if (rng() % 8 == 0)
                len = (int)(rng() % (uint64_t)len);
            else if (rng() % 4 != 0)
                for (int f = 1 + (int)(rng() % 4); f > 0; --f)
                    buf[rng() % (uint64_t)len] ^= (uint8_t)(1u << (rng() % 8));
        }
        // Every buffer goes to both validators: garbage can arrive on any channel.
        hs_net_pose po;
        hs_net_command co;
        sent_pose++;
        if (hs_net_validate_pose(&l, &ps, buf, len, i, &po) == HS_NET_ACCEPT) {
            accepted_pose++;
            ENSURE(po.device_id >= 0 && po.device_id < 2 && isfinite(po.position[0]));
        }
        sent_cmd++;
        int32_t prev;
        if (hs_net_validate_command(&cs, buf, len, &co, &prev) == HS_NET_ACCEPT) {
            accepted_cmd++;
            ENSURE(co.kind >= 1 && co.kind <= 8 && co.n_args >= 0 && co.n_args <= 8);
        }
    }
    ENSURE(ps.counters.received == sent_pose && cs.counters.received == sent_cmd);
    ENSURE(ps.counters.accepted == accepted_pose && cs.counters.accepted == accepted_cmd);
    ENSURE(ps.counters.received == ps.counters.accepted + hs_net_counters_rejected(&ps.counters));
    ENSURE(cs.counters.received == cs.counters.accepted + hs_net_counters_rejected(&cs.counters));
    // The flood exercised the interesting paths, not only "decode".
    ENSURE(accepted_pose > 0 && accepted_cmd > 0);
    ENSURE(ps.counters.rejected[HS_NET_REJ_DECODE] > 0 &&
           ps.counters.rejected[HS_NET_REJ_RANGE] > 0);
    ENSURE(cs.counters.rejected[HS_NET_REJ_DECODE] > 0);
    ENSURE(cs.counters.rejected[HS_NET_REJ_DUPLICATE] > 0);
    ENSURE(hs_byte_count() == bytes0);
    printf("  flood: %llu buffers per validator; pose accepted %llu, command accepted %llu\n",
           (unsigned long long)sent_pose, (unsigned long long)accepted_pose,
           (unsigned long long)accepted_cmd);
    for (int r = 1; r < HS_NET_REJ_COUNT; ++r)
        if (ps.counters.rejected[r] || cs.counters.rejected[r])
            printf("    %-15s pose %8llu  command %8llu\n", hs_net_reject_name(r),
                   (unsigned long long)ps.counters.rejected[r],
                   (unsigned long long)cs.counters.rejected[r]);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Keyframes and deltas: a delta against its keyframe reproduces the frame; only the newest
// delta is needed; the byte counts agree with LCM's encoder.

static int mesh_frames_roundtrip(void) {
    enum { NV = 2000 };
    static float key[3 * NV], f1[3 * NV], f2[3 * NV], out[3 * NV], delta[3 * NV];
    static int32_t idx[NV];
    for (int i = 0; i < 3 * NV; ++i) key[i] = (float)(rng() % 2000) * 1e-4f - 0.1f;
    memcpy(f1, key, sizeof key);
    memcpy(f2, key, sizeof key);
    int moved1 = 0, moved2 = 0;
    for (int i = 0; i < NV; ++i) {
        if (i % 7 == 0) f1[3 * i + 1] += 1e-3f, moved1++;
        if (i % 5 == 0) f2[3 * i + 2] -= 2e-3f, moved2++;
    }
    f2[3 * 1 + 0] += 1e-7f; // below eps: stays at the keyframe
    const float eps = 1e-6f;
    int n1 = hs_net_delta_build(key, f1, NV, eps, idx, delta);
    ENSURE(n1 == moved1);
    for (int i = 1; i < n1; ++i) ENSURE(idx[i] > idx[i - 1]);
    int n2 = hs_net_delta_build(key, f2, NV, eps, idx, delta);
    ENSURE(n2 == moved2);

    // Frame 1's delta is lost; frame 2's delta alone, through the wire, gives frame 2.
    hapsim_mesh_delta_t d = {.utime = 1,
                             .seq = 2,
                             .topology_version = 1,
                             .keyframe_id = 1,
                             .n_changed = n2,
                             .index = idx,
                             .n_delta = 3 * n2,
                             .delta = delta};
    uint8_t* b;
    int n;
    ENCODE(hapsim_mesh_delta_t, &d, b, n);
    ENSURE(n == hs_net_delta_bytes(n2));
    hapsim_mesh_delta_t d2;
    memset(&d2, 0, sizeof d2);
    ENSURE(hapsim_mesh_delta_t_decode(b, 0, n, &d2) == n);
    ENSURE(hs_net_delta_apply(key, NV, d2.index, d2.delta, d2.n_changed, out) == 0);
    double worst = 0.0;
    for (int i = 0; i < 3 * NV; ++i) worst = fmax(worst, fabs((double)out[i] - (double)f2[i]));
    ENSURE(worst <= 1e-6); // eps plus float rounding of key + (f2 - key)
    ENSURE(out[3 * 1 + 0] == key[3 * 1 + 0]);
    hapsim_mesh_delta_t_decode_cleanup(&d2);
    free(b);

    hapsim_mesh_state_t ks = {.utime = 1,
                              .seq = 1,
                              .topology_version = 1,
                              .keyframe_id = 1,
                              .n_pos = 3 * NV,
                              .position = key,
                              .n_stress = 0,
                              .stress = NULL};
    ENCODE(hapsim_mesh_state_t, &ks, b, n);
    ENSURE(n == hs_net_keyframe_bytes(NV, 0));
    free(b);
    ks.n_stress = NV;
    ks.stress = out;
    ENCODE(hapsim_mesh_state_t, &ks, b, n);
    ENSURE(n == hs_net_keyframe_bytes(NV, 1));
    free(b);

    // Bad deltas are refused and leave out untouched.
    int32_t bad[2] = {5, 5};
    out[0] = 42.0f;
    ENSURE(hs_net_delta_apply(key, NV, bad, delta, 2, out) == -1 && out[0] == 42.0f);
    bad[1] = NV;
    ENSURE(hs_net_delta_apply(key, NV, bad, delta, 2, out) == -1);
    bad[0] = -1;
    ENSURE(hs_net_delta_apply(key, NV, bad, delta, 1, out) == -1);
    ENSURE(hs_net_delta_apply(key, NV, idx, delta, NV + 1, out) == -1);

    // A keyframe is due when a delta would not be smaller, or the keyframe is old.
    ENSURE(!hs_net_keyframe_due(NV, n2, 0, 1000000));
    ENSURE(hs_net_keyframe_due(NV, n2, 1000000, 1000000));
    ENSURE(hs_net_keyframe_due(NV, NV, 0, 1000000));
    ENSURE(!hs_net_keyframe_due(NV, NV * 3 / 4 - 10, 0, 1000000));
    return 0;
}

// What a receiver needs for a message of a given size (the server prints it).
static int size_notes(void) {
    char note[400];
    ENSURE(hs_net_size_note("mesh topology", 100000, 212992, 4194304, note, sizeof note) == 0);
    ENSURE(note[0] == '\0');
    ENSURE(hs_net_size_note("mesh topology", 150000, 212992, 4194304, note, sizeof note) == 1);
    ENSURE(hs_net_size_note("mesh topology", 400000, 212992, 4194304, note, sizeof note) == 1);
    ENSURE(strstr(note, "400000 bytes") && strstr(note, "rmem_default (212992,") &&
           strstr(note, "recv_buf_size=800000"));
    ENSURE(hs_net_size_note("mesh keyframe", 5000000, 212992, 4194304, note, sizeof note) == 2);
    ENSURE(strstr(note, "mesh keyframe message") && strstr(note, "rmem_max=10000000") &&
           strstr(note, "recv_buf_size=10000000"));
    ENSURE(hs_net_size_note("x", 5000000, -1, -1, note, sizeof note) == 0); // unknown limits
    ENSURE(hs_net_size_note("x", 5000000, 212992, -1, note, 8) == 1 && strlen(note) == 7);
    return 0;
}

HS_TEST_MAIN(HS_CASE(size_notes), HS_CASE(roundtrip_tool_pose_force_state), HS_CASE(roundtrip_mesh),
             HS_CASE(roundtrip_command_ack_status), HS_CASE(pose_accepts_good),
             HS_CASE(pose_rejects_each_reason), HS_CASE(command_accepts_good),
             HS_CASE(command_rejects_each_reason), HS_CASE(flood_counts_add_up),
             HS_CASE(mesh_frames_roundtrip))
