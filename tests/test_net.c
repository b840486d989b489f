// SPDX-License-Identifier: GPL-2.0-or-later
// LCM over real UDP multicast, run inside a private network namespace (tests/netns.sh): poses
// in and forces out through the validators, garbage counted and dropped, a 10k-vertex float32
// keyframe arriving whole, command de-duplication over the wire. Every wait is bounded.
#include <stdint.h>
#include <stdlib.h>

#include "test_macros.h"

#include "base.h"
#include "hapsim_channels.h"
#include "hapsim_command_ack_t.h"
#include "hapsim_command_t.h"
#include "hapsim_mesh_state_t.h"
#include "hapsim_tool_force_t.h"
#include "hapsim_tool_pose_t.h"
#include "bus.h"
#include "validate.h"

// Private ports (never the defaults 7667/7668), ttl=0: nothing leaves the host.
#define URL_POSE    "udpm://239.255.76.67:7781?ttl=0"
#define URL_MESH_TX "udpm://239.255.76.68:7782?ttl=0"
#define URL_MESH_RX "udpm://239.255.76.68:7782?ttl=0&recv_buf_size=2097152"
#define URL_CMD     "udpm://239.255.76.69:7783?ttl=0"

// Handle both buses until *flag reaches want or timeout_ms passes. Returns 1 if reached.
static int pump(hs_net_bus* a, hs_net_bus* b, const int* flag, int want, int timeout_ms) {
    int64_t end = hs_now_ns() + (int64_t)timeout_ms * 1000000;
    while (*flag < want && hs_now_ns() < end) {
        if (hs_net_bus_handle(a, 1) < 0) return 0;
        if (b && hs_net_bus_handle(b, 0) < 0) return 0;
    }
    return *flag >= want;
}

// ---------------------------------------------------------------------------------------------
// Poses in, forces out

typedef struct server_side {
    hs_net_bus* bus;
    hs_net_limits lim;
    hs_net_pose_state st;
    int accepted;
    int64_t force_seq;
} server_side;

// A raw subscription: the bytes go to the validator, never to lcm-gen's trusting decode.
static void on_pose(const lcm_recv_buf_t* rb, const char* ch, void* user) {
    (void)ch;
    server_side* s = user;
    hs_net_pose p;
    if (hs_net_validate_pose(&s->lim, &s->st, rb->data, rb->data_size, hs_now_ns() / 1000, &p) !=
        HS_NET_ACCEPT)
        return;
    s->accepted++;
    hapsim_tool_force_t f;
    memset(&f, 0, sizeof f);
    f.utime = hs_now_ns() / 1000;
    f.seq = ++s->force_seq;
    f.device_id = p.device_id;
    f.pose_seq = p.seq;
    f.pose_utime = p.utime;
    f.state = HAPSIM_TOOL_FORCE_T_STATE_CONTACT;
    f.force[2] = 100.0 * (0.0 - p.position[2]); // a spring towards z = 0
    for (int i = 0; i < 3; ++i) f.anchor[i] = p.position[i];
    f.stiffness[8] = -100.0;
    f.validity_radius = 0.002;
    f.timeout_us = 20000;
    char ch_force[HAPSIM_CHANNEL_MAX];
    hapsim_channel_name(ch_force, sizeof ch_force, "T_", HAPSIM_CH_TOOL_FORCE);
    hapsim_tool_force_t_publish(hs_net_bus_lcm(s->bus), ch_force, &f);
}

typedef struct driver_side {
    int received;
    int64_t last_pose_seq;
    double last_fz;
    int64_t rtt_us[512];
} driver_side;

static void on_force(const lcm_recv_buf_t* rb, const char* ch, const hapsim_tool_force_t* f,
                     void* user) {
    (void)rb;
    (void)ch;
    driver_side* d = user;
    if (d->received < 512) d->rtt_us[d->received] = hs_now_ns() / 1000 - f->pose_utime;
    d->received++;
    d->last_pose_seq = f->pose_seq;
    d->last_fz = f->force[2];
}

static int cmp_i64(const void* a, const void* b) {
    int64_t x = *(const int64_t*)a, y = *(const int64_t*)b;
    return (x > y) - (x < y);
}

static int poses_in_forces_out(void) {
    int64_t bytes0 = hs_byte_count();
    hs_err err;
    server_side srv;
    memset(&srv, 0, sizeof srv);
    srv.lim = hs_net_default_limits();
    hs_net_bus* drv_bus = NULL;
    ENSURE(hs_net_bus_create(URL_POSE, &srv.bus, &err) == HS_OK);
    ENSURE(hs_net_bus_create(URL_POSE, &drv_bus, &err) == HS_OK);
    ENSURE(strcmp(hs_net_bus_url(drv_bus), URL_POSE) == 0);
    char ch_pose[HAPSIM_CHANNEL_MAX], ch_force[HAPSIM_CHANNEL_MAX];
    ENSURE(hapsim_channel_name(ch_pose, sizeof ch_pose, "T_", HAPSIM_CH_TOOL_POSE) == 0);
    ENSURE(hapsim_channel_name(ch_force, sizeof ch_force, "T_", HAPSIM_CH_TOOL_FORCE) == 0);
    lcm_subscription_t* sub = lcm_subscribe(hs_net_bus_lcm(srv.bus), ch_pose, on_pose, &srv);
    driver_side drv;
    memset(&drv, 0, sizeof drv);
    hapsim_tool_force_t_subscription_t* fsub =
        hapsim_tool_force_t_subscribe(hs_net_bus_lcm(drv_bus), ch_force, on_force, &drv);
    ENSURE(sub && fsub);

    enum { N = 300 };
    for (int i = 1; i <= N; ++i) {
        hapsim_tool_pose_t p = {.utime = hs_now_ns() / 1000,
                                .seq = i,
                                .session = 77,
                                .device_id = 0,
                                .tool_id = 0,
                                .position = {0.0, 0.0, -0.001 * (i % 5)},
                                .orientation = {1, 0, 0, 0}};
        // Every few poses a garbage payload on the same channel, before the pose
        // (one socket, in order): counted, dropped, harmless.
        if (i % 10 == 0) {
            uint8_t junk[64];
            for (int k = 0; k < 64; ++k) junk[k] = (uint8_t)(i * 31 + k * 7);
            ENSURE(lcm_publish(hs_net_bus_lcm(drv_bus), ch_pose, junk, (int)sizeof junk) == 0);
        }
        ENSURE(hapsim_tool_pose_t_publish(hs_net_bus_lcm(drv_bus), ch_pose, &p) == 0);
        ENSURE(pump(srv.bus, drv_bus, &drv.received, i, 1000));
        ENSURE(drv.last_pose_seq == i);
        ENSURE_NEAR(drv.last_fz, 0.1 * (i % 5), 1e-12);
    }
    ENSURE(srv.accepted == N && drv.received == N);
    ENSURE(srv.st.counters.accepted == N);
    ENSURE(srv.st.counters.rejected[HS_NET_REJ_DECODE] == N / 10);
    ENSURE(srv.st.counters.received == N + N / 10);
    ENSURE(srv.st.dev[0].lost == 0 && srv.st.dev[0].last_seq == N);
    qsort(drv.rtt_us, N, sizeof drv.rtt_us[0], cmp_i64);
    printf("  pose -> force round trip over udpm: p50 %lld us, p99 %lld us (N=%d)\n",
           (long long)drv.rtt_us[N / 2], (long long)drv.rtt_us[N * 99 / 100], N);

    hapsim_tool_force_t_unsubscribe(hs_net_bus_lcm(drv_bus), fsub);
    lcm_unsubscribe(hs_net_bus_lcm(srv.bus), sub);
    hs_net_bus_destroy(&srv.bus);
    hs_net_bus_destroy(&drv_bus);
    ENSURE(srv.bus == NULL && drv_bus == NULL);
    hs_net_bus_destroy(NULL);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// A 10k-vertex keyframe (float32, ~120 kB: two fragments' worth of datagrams) arrives whole.

typedef struct mesh_rx {
    int received;
    int whole;
    const float* expect;
    int n_pos;
    int64_t keyframe_id;
} mesh_rx;

static void on_mesh(const lcm_recv_buf_t* rb, const char* ch, const hapsim_mesh_state_t* m,
                    void* user) {
    (void)rb;
    (void)ch;
    mesh_rx* r = user;
    r->received++;
    if (m->n_pos == r->n_pos && m->keyframe_id == r->keyframe_id &&
        memcmp(m->position, r->expect, sizeof(float) * (size_t)m->n_pos) == 0)
        r->whole++;
}

static int mesh_keyframe_arrives_whole(void) {
    ENSURE(hs_net_url_recv_buf(URL_MESH_RX) == 2097152);
    ENSURE(hs_net_url_recv_buf(URL_MESH_TX) == 0);
    ENSURE(hs_net_url_recv_buf("udpm://1.2.3.4:5?recv_buf_size=12x") == 0);
    int64_t rmem = hs_net_rmem_max();
    printf("  net.core.rmem_max = %lld bytes\n", (long long)rmem);
    if (rmem >= 0 && rmem < hs_net_url_recv_buf(URL_MESH_RX))
        printf("  note: rmem_max below recv_buf_size: the kernel caps the socket buffer\n");

    enum { NV = 10000 };
    float* pos = malloc(sizeof(float) * 3 * NV);
    ENSURE(pos != NULL);
    hs_err err;
    hs_net_bus *tx = NULL, *rx = NULL;
    ENSURE(hs_net_bus_create(URL_MESH_TX, &tx, &err) == HS_OK);
    ENSURE(hs_net_bus_create(URL_MESH_RX, &rx, &err) == HS_OK);
    mesh_rx r = {.expect = pos, .n_pos = 3 * NV};
    hapsim_mesh_state_t_subscription_t* sub =
        hapsim_mesh_state_t_subscribe(hs_net_bus_lcm(rx), "T_MESH_STATE", on_mesh, &r);
    ENSURE(sub != NULL);
    enum { K = 20 };
    for (int k = 1; k <= K; ++k) {
        for (int i = 0; i < 3 * NV; ++i) pos[i] = 0.1f * sinf((float)(i + 7 * k));
        hapsim_mesh_state_t m = {.utime = hs_now_ns() / 1000,
                                 .seq = k,
                                 .topology_version = 1,
                                 .keyframe_id = k,
                                 .sim_step = k,
                                 .sim_time = 0.01 * k,
                                 .n_pos = 3 * NV,
                                 .position = pos,
                                 .n_stress = 0,
                                 .stress = NULL};
        ENSURE(hapsim_mesh_state_t_encoded_size(&m) > 120000);
        r.keyframe_id = k;
        ENSURE(hapsim_mesh_state_t_publish(hs_net_bus_lcm(tx), "T_MESH_STATE", &m) == 0);
        ENSURE(pump(rx, tx, &r.received, k, 2000));
        ENSURE(r.whole == k);
    }
    printf("  %d keyframes of %d vertices (%d bytes each) arrived whole\n", K, NV,
           8 + 5 * 8 + 8 + 4 + 12 * NV + 4);
    hapsim_mesh_state_t_unsubscribe(hs_net_bus_lcm(rx), sub);
    hs_net_bus_destroy(&tx);
    hs_net_bus_destroy(&rx);
    free(pos);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Commands over the wire: a retried request runs once, both copies are acked.

typedef struct cmd_srv {
    hs_net_bus* bus;
    hs_net_command_state st;
    int executed;
} cmd_srv;

static void on_command(const lcm_recv_buf_t* rb, const char* ch, void* user) {
    (void)ch;
    cmd_srv* s = user;
    hs_net_command c;
    int32_t prev = 0;
    hs_net_reject r = hs_net_validate_command(&s->st, rb->data, rb->data_size, &c, &prev);
    hapsim_command_ack_t a = {.utime = hs_now_ns() / 1000,
                              .seq = (int64_t)s->st.counters.received,
                              .request_id = c.request_id,
                              .kind = c.kind,
                              .message = ""};
    if (r == HS_NET_ACCEPT) {
        s->executed++;
        a.status = HAPSIM_COMMAND_ACK_T_STATUS_OK;
        hs_net_dedup_set_status(&s->st.dedup, c.request_id, a.status);
    } else if (r == HS_NET_REJ_DUPLICATE) {
        a.status = prev;
    } else {
        a.status = HAPSIM_COMMAND_ACK_T_STATUS_INVALID;
        a.message = (char*)(uintptr_t)hs_net_reject_name(r);
    }
    hapsim_command_ack_t_publish(hs_net_bus_lcm(s->bus), "T_COMMAND_ACK", &a);
}

typedef struct cmd_cli {
    int acks;
    int64_t last_id;
    int32_t last_status;
    char last_message[64];
} cmd_cli;

static void on_ack(const lcm_recv_buf_t* rb, const char* ch, const hapsim_command_ack_t* a,
                   void* user) {
    (void)rb;
    (void)ch;
    cmd_cli* c = user;
    c->acks++;
    c->last_id = a->request_id;
    c->last_status = a->status;
    snprintf(c->last_message, sizeof c->last_message, "%s", a->message);
}

static int commands_deduplicated(void) {
    hs_err err;
    cmd_srv s;
    memset(&s, 0, sizeof s);
    hs_net_bus* cli_bus = NULL;
    ENSURE(hs_net_bus_create(URL_CMD, &s.bus, &err) == HS_OK);
    ENSURE(hs_net_bus_create(URL_CMD, &cli_bus, &err) == HS_OK);
    lcm_subscription_t* sub = lcm_subscribe(hs_net_bus_lcm(s.bus), "T_COMMAND", on_command, &s);
    cmd_cli c;
    memset(&c, 0, sizeof c);
    hapsim_command_ack_t_subscription_t* asub =
        hapsim_command_ack_t_subscribe(hs_net_bus_lcm(cli_bus), "T_COMMAND_ACK", on_ack, &c);
    ENSURE(sub && asub);
    hapsim_command_t cmd = {.utime = 1,
                            .seq = 1,
                            .request_id = 0x1234567890ll,
                            .kind = HAPSIM_COMMAND_T_KIND_ESTOP,
                            .n_args = 0,
                            .sender = "t"};
    for (int attempt = 1; attempt <= 3; ++attempt) { // the client retries: runs once
        ENSURE(hapsim_command_t_publish(hs_net_bus_lcm(cli_bus), "T_COMMAND", &cmd) == 0);
        ENSURE(pump(cli_bus, s.bus, &c.acks, attempt, 1000));
        ENSURE(c.last_id == cmd.request_id && c.last_status == HAPSIM_COMMAND_ACK_T_STATUS_OK);
    }
    ENSURE(s.executed == 1 && s.st.counters.rejected[HS_NET_REJ_DUPLICATE] == 2);
    cmd.request_id = 99;
    cmd.kind = 42;
    ENSURE(hapsim_command_t_publish(hs_net_bus_lcm(cli_bus), "T_COMMAND", &cmd) == 0);
    ENSURE(pump(cli_bus, s.bus, &c.acks, 4, 1000));
    ENSURE(c.last_id == 99 && c.last_status == HAPSIM_COMMAND_ACK_T_STATUS_INVALID);
    ENSURE(strcmp(c.last_message, "unknown_kind") == 0 && s.executed == 1);
    hapsim_command_ack_t_unsubscribe(hs_net_bus_lcm(cli_bus), asub);
    lcm_unsubscribe(hs_net_bus_lcm(s.bus), sub);
    hs_net_bus_destroy(&s.bus);
    hs_net_bus_destroy(&cli_bus);
    return 0;
}

static int bus_errors(void) {
    hs_err err;
    hs_net_bus* b = (hs_net_bus*)&err; // must be reset to NULL on failure
    ENSURE(hs_net_bus_create("nosuchprovider://x", &b, &err) == HS_ERR_INVALID);
    ENSURE(b == NULL && strstr(err.msg, "nosuchprovider://x") != NULL);
    // Buses that serve no other program are refused with the reason.
    const char* useless[] = {"memq://", "file:///tmp/x.lcmlog?mode=w", "", "tcpq://127.0.0.1:1"};
    for (int i = 0; i < 4; ++i) {
        ENSURE(hs_net_bus_create(useless[i], &b, &err) == HS_ERR_INVALID && b == NULL);
        ENSURE(strstr(err.msg, "serve no other program") != NULL);
    }
    ENSURE(hs_net_bus_create(NULL, &b, &err) == HS_ERR_INVALID && b == NULL);
    // The port LCM binds, read as LCM reads it.
    ENSURE(hapsim_url_port("udpm://") == 7667);
    ENSURE(hapsim_url_port("udpm://239.255.76.67:0x1DF3?ttl=0") == 7667);
    ENSURE(hapsim_url_port("udpm://239.255.76.70:7784?ttl=0&recv_buf_size=4096") == 7784);
    ENSURE(hapsim_url_port("udpm://239.255.76.67?ttl=0") == -1); // refused: no port
    ENSURE(hapsim_url_port("memq://") == -1);
    return 0;
}

static void count_msg(const lcm_recv_buf_t* rb, const char* ch, void* u) {
    (void)rb;
    (void)ch;
    ++*(int*)u;
}

// Datagrams the kernel drops for a receiver that does not keep up are counted on its bus (they
// never reach a handler); a bus that kept up counts none.
static int kernel_drops_counted(void) {
    hs_err err = {0};
    hs_net_bus *rx = NULL, *tx = NULL;
    ENSURE(hs_net_bus_create("udpm://239.255.76.70:7784?ttl=0&recv_buf_size=4096", &rx, &err) ==
           HS_OK);
    ENSURE(hs_net_bus_create("udpm://239.255.76.70:7784?ttl=0", &tx, &err) == HS_OK);
    int got = 0;
    lcm_subscribe(hs_net_bus_lcm(rx), "DROPS", count_msg, &got);
    const int64_t d0 = hs_net_bus_kernel_drops(rx);
    ENSURE(d0 >= 0); // this process's socket on the port is found
    static unsigned char payload[1400];
    for (int i = 0; i < 400; ++i) lcm_publish(hs_net_bus_lcm(tx), "DROPS", payload, sizeof payload);
    for (int i = 0; i < 200 && hs_net_bus_handle(rx, 20) >= 0;) i += got == 400 ? 200 : 1;
    const int64_t d1 = hs_net_bus_kernel_drops(rx);
    printf("  400 datagrams into a 4 kB receive buffer unread: %d handled, %lld dropped by the "
           "kernel\n",
           got, (long long)(d1 - d0));
    ENSURE(got < 400 && d1 - d0 > 0);
    ENSURE(got + (d1 - d0) <= 400 + 1);
    hs_net_bus_destroy(&rx);
    hs_net_bus_destroy(&tx);
    return 0;
}

HS_TEST_MAIN(HS_CASE(poses_in_forces_out), HS_CASE(mesh_keyframe_arrives_whole),
             HS_CASE(commands_deduplicated), HS_CASE(bus_errors), HS_CASE(kernel_drops_counted))
