// SPDX-License-Identifier: MIT
// libhapsim-client: the LCM connection (two buses), dispatch, poses, forces, commands, status.
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <fcntl.h>
#include <lcm/lcm.h>
#include <math.h>
#include <poll.h>
#include <stdio.h>
#include <stdatomic.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "hapsim_channels.h"
#include "hapsim_command_ack_t.h"
#include "hapsim_command_rules.h"
#include "hapsim_command_t.h"
#include "hapsim_tool_pose_t.h"
#include "wire.h"

// Refused forces counting up one after another this many times are another server's stream.
#define STALE_RUN_RESTART 8
enum { CH_FORCE, CH_TOPOLOGY, CH_STATE, CH_DELTA, CH_EVENT, CH_STATUS, CH_ACK, CH_COUNT };
#define ACK_RING 16

typedef struct route {
    hs_client* c;
    int ch;
} route;

struct hs_client {
    lcm_t* bus[2]; // 0 haptic, 1 mesh
    char prefix[48];
    char ch_pose[HAPSIM_CHANNEL_MAX], ch_command[HAPSIM_CHANNEL_MAX];
    char sender[64];
    int64_t session;
    int all_sessions; // config: take forces of every session
    route routes[CH_COUNT];
    hs_client_callbacks cb;
    void* user;
    int64_t handled; // messages handled (for poll's return value)
    // Callbacks run inside lcm_handle, which LCM does not allow to re-enter (it asserts) and
    // whose dispatch must not see its lcm_t destroyed: poll and destroy check these.
    int in_poll, destroy_refused;
    // Driver side.
    int64_t pose_seq[HS_CLIENT_MAX_DEVICES];
    hs_force_renderer force[HS_CLIENT_MAX_DEVICES];
    int64_t force_utime[HS_CLIENT_MAX_DEVICES]; // server utime of the model held
    int stale_run[HS_CLIENT_MAX_DEVICES];       // refused forces in a row, seq counting up
    int64_t stale_seq[HS_CLIENT_MAX_DEVICES];   // seq of the last refused one
    int64_t latency_us[HS_CLIENT_MAX_DEVICES];
    // Visualiser side.
    hs_mesh_sync* mesh;
    hs_client_status status, status_rx; // newest good one; decoding scratch
    int have_status;
    int64_t status_arrival_us;
    // Commands.
    int64_t next_request_id, command_seq;
    hs_wire_ack acks[ACK_RING];
    int n_acks, ack_head;
    // The request hs_client_command waits for (0: none) and its ack, kept apart from the ring:
    // other clients' acks arriving in the same poll could push it out (16 of them did).
    int64_t wait_id;
    hs_wire_ack wait_ack;
    int wait_have;
    hs_client_stats st;
    // hs_client_send_pose may run on a thread of its own beside the polling one, whose
    // hs_client_stats_get reads the count (a data race on a plain counter, found in review).
    atomic_llong poses_sent;
};

const char* hs_client_status_str(hs_status s) {
    // The client's two with their network meaning; the rest as everywhere.
    if (s == HS_ERR_IO) return "network failure or timeout";
    if (s == HS_ERR_PARSE) return "malformed message";
    return hs_status_str(s);
}

int64_t hs_client_now_us(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (int64_t)t.tv_sec * 1000000 + t.tv_nsec / 1000;
}

static int64_t wall_us(void) {
    struct timespec t;
    clock_gettime(CLOCK_REALTIME, &t);
    return (int64_t)t.tv_sec * 1000000 + t.tv_nsec / 1000;
}

int64_t hs_client_age_us(int64_t utime) {
    int64_t a = hs_wire_sub_sat(wall_us(), utime), b = hs_wire_sub_sat(hs_client_now_us(), utime);
    if (a >= -1000000 && a < 3600000000LL) return a < 0 ? 0 : a;
    if (b >= -1000000 && b < 3600000000LL) return b < 0 ? 0 : b;
    return -1;
}

// A nonzero positive random 62-bit number (urandom, else clock and pid).
static int64_t random_id(void) {
    uint64_t v = 0;
    int fd = open("/dev/urandom", O_RDONLY | O_CLOEXEC);
    if (fd >= 0) {
        if (read(fd, &v, sizeof v) != (ssize_t)sizeof v) v = 0;
        close(fd);
    }
    if (!v) v = (uint64_t)wall_us() * 6364136223846793005ull ^ (uint64_t)getpid();
    v &= 0x3fffffffffffffffull;
    return v ? (int64_t)v : 1;
}

void hs_client_config_default(hs_client_config* cfg) {
    memset(cfg, 0, sizeof *cfg);
    cfg->subscribe =
        HS_CLIENT_SUB_FORCE | HS_CLIENT_SUB_MESH | HS_CLIENT_SUB_STATUS | HS_CLIENT_SUB_COMMANDS;
}

// ---------------------------------------------------------------------------------------------
// Receive side.

static void on_force(hs_client* c, const void* buf, size_t len) {
    hs_wire_force w;
    if (hs_wire_force_decode(buf, len, &w)) {
        c->st.malformed++;
        return;
    }
    int32_t dev = w.device_id;
    int64_t utime = w.utime;
    hs_local_model m = hs_wire_local_model(&w);
    if (dev < 0 || dev >= HS_CLIENT_MAX_DEVICES) {
        c->st.forces_other++;
        return;
    }
    // A driver renders only answers to its own session's poses: a restarted driver must not
    // take what the server still sends its predecessor. A viewer watches every session.
    if (!c->all_sessions && w.session != c->session) {
        c->st.forces_session++;
        return;
    }
    hs_force_renderer* r = &c->force[dev];
    // A seq not newer is a reorder or a repeat if its utime is at most a reorder window older;
    // a later or far earlier utime is a restarted server (seq from 1, another clock).
    if (r->model.valid && m.seq <= r->model.seq && hs_wire_reordered(utime, c->force_utime[dev])) {
        // ... unless they keep coming, counting up: a restart whose clock tells nothing.
        int run = c->stale_run[dev] > 0 && m.seq > c->stale_seq[dev] ? c->stale_run[dev] + 1 : 1;
        c->stale_run[dev] = run;
        c->stale_seq[dev] = m.seq;
        if (run < STALE_RUN_RESTART) {
            c->st.forces_stale++;
            return;
        }
    }
    c->stale_run[dev] = 0;
    m.arrival_us = hs_client_now_us();
    hs_force_renderer_push(r, &m);
    c->force_utime[dev] = utime;
    c->latency_us[dev] = m.pose_utime > 0 ? wall_us() - m.pose_utime : -1;
    c->st.forces++;
    if (c->cb.on_force) c->cb.on_force(c, dev, &r->model, c->user);
}

static void on_ack(hs_client* c, const void* buf, size_t len) {
    hs_wire_ack a;
    if (hs_wire_ack_decode(buf, len, &a)) {
        c->st.malformed++;
        return;
    }
    c->st.acks++;
    if (c->wait_id != 0 && a.request_id == c->wait_id &&
        (!c->wait_have || c->wait_ack.status == HAPSIM_COMMAND_ACK_T_STATUS_PENDING)) {
        c->wait_ack = a;
        c->wait_have = 1;
    }
    // One entry per request: a final ack replaces a PENDING one, and the first final one stays
    // (a retry's copies, "not executed again", would push it out of the ring).
    for (int i = 0; i < c->n_acks; i++) {
        hs_wire_ack* e = &c->acks[(c->ack_head - 1 - i + 2 * ACK_RING) % ACK_RING];
        if (e->request_id != a.request_id) continue;
        if (e->status == HAPSIM_COMMAND_ACK_T_STATUS_PENDING) *e = a;
        return;
    }
    c->acks[c->ack_head] = a;
    c->ack_head = (c->ack_head + 1) % ACK_RING;
    if (c->n_acks < ACK_RING) c->n_acks++;
}

static void on_status(hs_client* c, const void* buf, size_t len) {
    // Decoded aside: a malformed status must not erase the last good one.
    if (hs_client_status_decode(buf, len, &c->status_rx) != HS_OK) {
        c->st.malformed++;
        return;
    }
    c->status = c->status_rx;
    c->have_status = 1;
    c->status_arrival_us = hs_client_now_us();
    c->st.statuses++;
    if (c->cb.on_status) c->cb.on_status(c, &c->status, c->user);
}

static void on_raw(const lcm_recv_buf_t* rbuf, const char* channel, void* user) {
    (void)channel;
    route* r = user;
    hs_client* c = r->c;
    c->handled++;
    c->st.messages++;
    const void* buf = rbuf->data;
    size_t len = rbuf->data_size;
    switch (r->ch) {
    case CH_FORCE:
        on_force(c, buf, len);
        return;
    case CH_STATUS:
        on_status(c, buf, len);
        return;
    case CH_ACK:
        on_ack(c, buf, len);
        return;
    default:
        break;
    }
    static const hs_sync_kind kinds[] = {[CH_TOPOLOGY] = HS_SYNC_TOPOLOGY,
                                         [CH_STATE] = HS_SYNC_STATE,
                                         [CH_DELTA] = HS_SYNC_DELTA,
                                         [CH_EVENT] = HS_SYNC_EVENT};
    int64_t frame = hs_mesh_sync_mesh(c->mesh)->frame;
    hs_sync_result res = hs_mesh_sync_feed(c->mesh, kinds[r->ch], buf, len);
    if (res == HS_SYNC_MALFORMED) c->st.malformed++;
    if (r->ch == CH_EVENT && res == HS_SYNC_HELD && c->cb.on_topology_event) {
        hs_sync_stats s;
        hs_mesh_sync_stats(c->mesh, &s);
        c->cb.on_topology_event(c, s.last_event_old, s.last_event_new, s.last_event_removed,
                                c->user);
    }
    const hs_client_mesh* m = hs_mesh_sync_mesh(c->mesh);
    if (m->frame != frame && c->cb.on_mesh) c->cb.on_mesh(c, m, c->user);
}

// ---------------------------------------------------------------------------------------------
// Life cycle.

static hs_status sub(hs_client* c, int bus, int ch, const char* suffix, hs_err* err) {
    char name[HAPSIM_CHANNEL_MAX];
    hapsim_channel_name(name, sizeof name, c->prefix, suffix);
    c->routes[ch].c = c;
    c->routes[ch].ch = ch;
    lcm_subscription_t* s = lcm_subscribe(c->bus[bus], name, on_raw, &c->routes[ch]);
    if (!s) return hs_err_set(err, HS_ERR_IO, "hs_client_create: cannot subscribe to %s", name);
    // Keep the newest messages rather than LCM's default 30 when a caller polls slowly.
    lcm_subscription_set_queue_capacity(s, ch == CH_FORCE ? 64 : 256);
    return HS_OK;
}

static int prefix_ok(const char* p) {
    size_t n = strlen(p);
    if (n >= 48) return 0;
    for (size_t i = 0; i < n; i++)
        if (!((p[i] >= 'A' && p[i] <= 'Z') || (p[i] >= '0' && p[i] <= '9') || p[i] == '_'))
            return 0;
    return 1;
}

hs_status hs_client_create(const hs_client_config* cfg, hs_client** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "hs_client_create: out is NULL");
    *out = NULL;
    hs_client_config def;
    if (!cfg) {
        hs_client_config_default(&def);
        cfg = &def;
    }
    const char* prefix = cfg->prefix ? cfg->prefix : HAPSIM_DEFAULT_PREFIX;
    if (!prefix_ok(prefix))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_client_create: prefix '%s' must be [A-Z0-9_]*, at most 47 bytes",
                          prefix);
    if (cfg->sender &&
        (strlen(cfg->sender) > HAPSIM_CMD_SENDER_MAX || !hapsim_cmd_text_ok(cfg->sender)))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_client_create: sender longer than 63 bytes or with control bytes");
    hs_client* c = hs_proto_calloc(1, sizeof *c);
    if (!c) return hs_err_set(err, HS_ERR_NOMEM, "hs_client_create: out of memory");
    atomic_init(&c->poses_sent, 0);
    snprintf(c->prefix, sizeof c->prefix, "%s", prefix);
    hapsim_channel_name(c->ch_pose, sizeof c->ch_pose, c->prefix, HAPSIM_CH_TOOL_POSE);
    hapsim_channel_name(c->ch_command, sizeof c->ch_command, c->prefix, HAPSIM_CH_COMMAND);
    if (cfg->sender)
        snprintf(c->sender, sizeof c->sender, "%s", cfg->sender);
    else
        snprintf(c->sender, sizeof c->sender, "hapsim-client:%ld", (long)getpid());
    c->session = cfg->session ? cfg->session : random_id();
    c->all_sessions = cfg->all_sessions != 0;
    c->next_request_id = random_id();
    for (int d = 0; d < HS_CLIENT_MAX_DEVICES; d++) {
        hs_force_renderer_init(&c->force[d]);
        c->latency_us[d] = -1;
    }
    hs_status s = hs_mesh_sync_create(&c->mesh, err);
    if (s != HS_OK) {
        hs_proto_free(c);
        return s;
    }
    char mesh_url[512];
    const char* hurl = cfg->haptic_url ? cfg->haptic_url : HAPSIM_DEFAULT_HAPTIC_URL;
    const char* murl = cfg->mesh_url;
    if (!murl) {
        snprintf(mesh_url, sizeof mesh_url, "%s&recv_buf_size=%d", HAPSIM_DEFAULT_MESH_URL,
                 HS_CLIENT_MESH_RECV_BUF);
        murl = mesh_url;
    }
    uint32_t sb = cfg->subscribe;
    const char* bad_url = hapsim_url_problem(hurl) ? hurl : murl;
    const char* why = hapsim_url_problem(bad_url);
    if (why) {
        s = hs_err_set(err, HS_ERR_INVALID, "hs_client_create: LCM URL '%s' %s", bad_url, why);
        goto bad;
    }
    if (hurl[0]) {
        c->bus[0] = lcm_create(hurl);
        if (!c->bus[0]) {
            s = hs_err_set(err, HS_ERR_IO, "hs_client_create: LCM cannot open the haptic URL '%s'",
                           hurl);
            goto bad;
        }
    }
    if (murl[0]) {
        c->bus[1] = lcm_create(murl);
        if (!c->bus[1]) {
            s = hs_err_set(err, HS_ERR_IO, "hs_client_create: LCM cannot open the mesh URL '%s'",
                           murl);
            goto bad;
        }
    }
    if ((sb & HS_CLIENT_SUB_FORCE) && !c->bus[0]) {
        s = hs_err_set(err, HS_ERR_INVALID, "hs_client_create: forces need the haptic bus");
        goto bad;
    }
    if ((sb & ~(uint32_t)HS_CLIENT_SUB_FORCE) && !c->bus[1]) {
        s = hs_err_set(err, HS_ERR_INVALID,
                       "hs_client_create: mesh/status/commands need the mesh bus");
        goto bad;
    }
    if ((sb & HS_CLIENT_SUB_FORCE) && (s = sub(c, 0, CH_FORCE, HAPSIM_CH_TOOL_FORCE, err)) != HS_OK)
        goto bad;
    if (sb & HS_CLIENT_SUB_MESH) {
        if ((s = sub(c, 1, CH_TOPOLOGY, HAPSIM_CH_MESH_TOPOLOGY, err)) != HS_OK ||
            (s = sub(c, 1, CH_STATE, HAPSIM_CH_MESH_STATE, err)) != HS_OK ||
            (s = sub(c, 1, CH_DELTA, HAPSIM_CH_MESH_DELTA, err)) != HS_OK ||
            (s = sub(c, 1, CH_EVENT, HAPSIM_CH_TOPOLOGY_EVENT, err)) != HS_OK)
            goto bad;
    }
    if ((sb & HS_CLIENT_SUB_STATUS) &&
        (s = sub(c, 1, CH_STATUS, HAPSIM_CH_SERVER_STATUS, err)) != HS_OK)
        goto bad;
    if ((sb & HS_CLIENT_SUB_COMMANDS) &&
        (s = sub(c, 1, CH_ACK, HAPSIM_CH_COMMAND_ACK, err)) != HS_OK)
        goto bad;
    *out = c;
    return HS_OK;
bad:
    hs_client_destroy(&c);
    return s;
}

void hs_client_destroy(hs_client** pc) {
    if (!pc || !*pc) return;
    hs_client* c = *pc;
    if (c->in_poll) { // from a callback: refused, the running poll reports it
        c->destroy_refused = 1;
        return;
    }
    for (int b = 0; b < 2; b++)
        if (c->bus[b]) lcm_destroy(c->bus[b]);
    hs_mesh_sync_destroy(&c->mesh);
    hs_proto_free(c);
    *pc = NULL;
}

void hs_client_set_callbacks(hs_client* c, const hs_client_callbacks* cb, void* user) {
    if (cb)
        c->cb = *cb;
    else
        memset(&c->cb, 0, sizeof c->cb);
    c->user = user;
}

struct _lcm_t* hs_client_lcm(hs_client* c, int bus) {
    return bus >= 0 && bus < 2 ? c->bus[bus] : NULL;
}

int hs_client_fileno(const hs_client* c, int bus) {
    return bus >= 0 && bus < 2 && c->bus[bus] ? lcm_get_fileno(c->bus[bus]) : -1;
}

static int poll_buses(hs_client* c, int timeout_ms, hs_err* err) {
    struct pollfd fds[2];
    int map[2], nf = 0;
    for (int b = 0; b < 2; b++)
        if (c->bus[b]) {
            fds[nf].fd = lcm_get_fileno(c->bus[b]);
            fds[nf].events = POLLIN;
            map[nf++] = b;
        }
    if (!nf) return hs_err_set(err, HS_ERR_INVALID, "hs_client_poll: no bus open");
    int64_t start = c->handled;
    // Wait once, then drain whatever is queued without waiting (bounded, so a flood cannot
    // keep the caller here forever).
    for (int round = 0; round < 4096; round++) {
        int r = poll(fds, (nfds_t)nf, round == 0 ? timeout_ms : 0);
        if (r < 0) {
            if (errno == EINTR) break;
            return hs_err_set(err, HS_ERR_IO, "hs_client_poll: poll: %s", strerror(errno));
        }
        if (r == 0) break;
        for (int i = 0; i < nf; i++) {
            if (fds[i].revents & (POLLERR | POLLNVAL))
                return hs_err_set(err, HS_ERR_IO, "hs_client_poll: LCM socket error");
            if ((fds[i].revents & POLLIN) && lcm_handle(c->bus[map[i]]) != 0)
                return hs_err_set(err, HS_ERR_IO, "hs_client_poll: lcm_handle failed");
            if (c->destroy_refused)
                return hs_err_set(
                    err, HS_ERR_INVALID,
                    "hs_client_destroy called from a callback: refused (the handle is "
                    "still open; destroy it after hs_client_poll returns)");
        }
    }
    return (int)(c->handled - start);
}

int hs_client_poll(hs_client* c, int timeout_ms, hs_err* err) {
    if (c->in_poll)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_client_poll: called from a callback (already inside hs_client_poll)");
    c->in_poll = 1;
    c->destroy_refused = 0;
    int r = poll_buses(c, timeout_ms, err);
    c->in_poll = 0;
    c->destroy_refused = 0;
    return r;
}

// ---------------------------------------------------------------------------------------------
// Driver side.

hs_status hs_client_send_pose(hs_client* c, const hs_client_pose* p, hs_err* err) {
    if (!c->bus[0]) return hs_err_set(err, HS_ERR_INVALID, "hs_client_send_pose: no haptic bus");
    if (p->device_id < 0 || p->device_id >= HS_CLIENT_MAX_DEVICES || p->tool_id < 0)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_client_send_pose: device %d / tool %d out of range", p->device_id,
                          p->tool_id);
    double qn = 0;
    for (int i = 0; i < 4; i++) qn += p->orientation[i] * p->orientation[i];
    for (int i = 0; i < 3; i++)
        if (!isfinite(p->position[i]))
            return hs_err_set(err, HS_ERR_INVALID, "hs_client_send_pose: position not finite");
    if (!isfinite(qn) || fabs(sqrt(qn) - 1) > 1e-3)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_client_send_pose: orientation is not a unit quaternion");
    if (p->buttons & ~(HAPSIM_TOOL_POSE_T_BUTTON_PRIMARY | HAPSIM_TOOL_POSE_T_BUTTON_CLUTCH))
        return hs_err_set(err, HS_ERR_INVALID, "hs_client_send_pose: unknown button bits 0x%x",
                          (unsigned)p->buttons);
    hapsim_tool_pose_t m;
    memset(&m, 0, sizeof m);
    m.utime = wall_us();
    m.seq = c->pose_seq[p->device_id]++;
    m.session = c->session;
    m.device_id = p->device_id;
    m.tool_id = p->tool_id;
    memcpy(m.position, p->position, sizeof m.position);
    memcpy(m.orientation, p->orientation, sizeof m.orientation);
    m.buttons = p->buttons;
    // Encode on the stack (lcm-gen's _publish mallocs a buffer per message).
    uint8_t buf[128];
    int len = hapsim_tool_pose_t_encoded_size(&m);
    if (len > (int)sizeof buf || hapsim_tool_pose_t_encode(buf, 0, len, &m) != len ||
        lcm_publish(c->bus[0], c->ch_pose, buf, (unsigned)len) != 0)
        return hs_err_set(err, HS_ERR_IO, "hs_client_send_pose: publish on %s failed", c->ch_pose);
    atomic_fetch_add_explicit(&c->poses_sent, 1, memory_order_relaxed);
    return HS_OK;
}

int32_t hs_client_force(const hs_client* c, int32_t dev, const double p[3], int64_t now_us,
                        double f[3]) {
    f[0] = f[1] = f[2] = 0;
    if (dev < 0 || dev >= HS_CLIENT_MAX_DEVICES) return -1;
    return hs_force_renderer_eval(&c->force[dev], p, now_us, f);
}

bool hs_client_force_model(const hs_client* c, int32_t dev, hs_local_model* out) {
    if (dev < 0 || dev >= HS_CLIENT_MAX_DEVICES || !c->force[dev].model.valid) return false;
    *out = c->force[dev].model;
    return true;
}

int64_t hs_client_force_latency_us(const hs_client* c, int32_t dev) {
    return dev >= 0 && dev < HS_CLIENT_MAX_DEVICES ? c->latency_us[dev] : -1;
}

// ---------------------------------------------------------------------------------------------
// Visualiser side and counters.

const hs_client_mesh* hs_client_mesh_view(const hs_client* c) {
    return hs_mesh_sync_mesh(c->mesh);
}
void hs_client_mesh_stats(const hs_client* c, hs_sync_stats* out) {
    hs_mesh_sync_stats(c->mesh, out);
}
bool hs_client_status_latest(const hs_client* c, hs_client_status* out, int64_t* age_us) {
    if (!c->have_status) return false;
    if (out) *out = c->status;
    if (age_us) *age_us = hs_client_now_us() - c->status_arrival_us;
    return true;
}
void hs_client_stats_get(const hs_client* c, hs_client_stats* out) {
    *out = c->st;
    out->poses_sent = atomic_load_explicit(&c->poses_sent, memory_order_relaxed);
}

// ---------------------------------------------------------------------------------------------
// Commands.

static const hs_wire_ack* find_ack(const hs_client* c, int64_t id) {
    for (int i = 0; i < c->n_acks; i++) {
        int k = (c->ack_head - 1 - i + 2 * ACK_RING) % ACK_RING;
        if (c->acks[k].request_id == id) return &c->acks[k];
    }
    return NULL;
}

hs_status hs_client_command(hs_client* c, int32_t kind, int n_args, const char* const* keys,
                            const char* const* values, int timeout_ms, int retry_ms,
                            hs_client_ack* ack, hs_err* err) {
    if (!c->bus[1]) return hs_err_set(err, HS_ERR_INVALID, "hs_client_command: no mesh bus");
    if (!c->routes[CH_ACK].c)
        return hs_err_set(err, HS_ERR_INVALID, "hs_client_command: created without SUB_COMMANDS");
    if (kind < HAPSIM_COMMAND_T_KIND_RESET || kind > HAPSIM_COMMAND_T_KIND_REQUEST_TOPOLOGY)
        return hs_err_set(err, HS_ERR_INVALID, "hs_client_command: unknown kind %d", kind);
    if (n_args < 0 || n_args > 8 || (n_args && (!keys || !values)))
        return hs_err_set(err, HS_ERR_INVALID, "hs_client_command: n_args %d not in 0..8", n_args);
    for (int i = 0; i < n_args; i++) // what the shared rules below take for granted
        if (!keys[i] || !values[i] || strlen(values[i]) > HAPSIM_CMD_TEXT_MAX)
            return hs_err_set(err, HS_ERR_INVALID,
                              "hs_client_command: argument %d missing or its value over 255 bytes",
                              i);
    // What the server would refuse as INVALID is refused here (its rules, shared).
    double number;
    const char* why;
    if (hapsim_cmd_args_check(kind, n_args, keys, values, &number, &why) != HAPSIM_CMD_ARGS_OK)
        return hs_err_set(err, HS_ERR_INVALID, "hs_client_command: %s", why);
    if (timeout_ms <= 0) timeout_ms = 2000;
    if (retry_ms <= 0) retry_ms = 250;
    hapsim_command_t m;
    memset(&m, 0, sizeof m);
    m.request_id = c->next_request_id++;
    if (c->next_request_id <= 0) c->next_request_id = 1;
    if (!c->in_poll) { // a command from a callback is sent once and not waited for
        c->wait_id = m.request_id;
        c->wait_have = 0;
    }
    m.kind = kind;
    m.n_args = n_args;
    char *kb[8], *vb[8]; // lcm-gen's type wants char**; the encoder only reads them
    for (int i = 0; i < n_args; i++) {
        kb[i] = (char*)(uintptr_t)keys[i];
        vb[i] = (char*)(uintptr_t)values[i];
    }
    m.keys = kb;
    m.values = vb;
    m.sender = c->sender;
    memset(ack, 0, sizeof *ack);
    ack->request_id = m.request_id;
    ack->kind = kind;
    ack->status = HAPSIM_COMMAND_ACK_T_STATUS_PENDING;
    int64_t t0 = hs_client_now_us(), deadline = t0 + (int64_t)timeout_ms * 1000, next_send = t0;
    int pending = 0;
    // Encoded on the stack (lcm-gen's _publish mallocs a buffer per message); the server takes
    // at most 8 arguments of 64 + 256 bytes, well inside this.
    uint8_t buf[4096];
    for (;;) {
        int64_t now = hs_client_now_us();
        if (now >= next_send) {
            m.utime = wall_us();
            m.seq = c->command_seq++;
            int len = hapsim_command_t_encoded_size(&m);
            if (len > (int)sizeof buf)
                return hs_err_set(err, HS_ERR_INVALID,
                                  "hs_client_command: %d bytes encoded (at most %d)", len,
                                  (int)sizeof buf);
            if (hapsim_command_t_encode(buf, 0, len, &m) != len ||
                lcm_publish(c->bus[1], c->ch_command, buf, (unsigned)len) != 0)
                return hs_err_set(err, HS_ERR_IO, "hs_client_command: publish on %s failed",
                                  c->ch_command);
            ack->attempts++;
            // From a callback (inside hs_client_poll) nothing can be waited for: sent once.
            if (c->in_poll) return HS_OK;
            // After PENDING the server is working on it: ask again less often.
            next_send = now + (int64_t)retry_ms * 1000 * (pending ? 4 : 1);
        }
        const hs_wire_ack* a =
            c->wait_have && c->wait_id == m.request_id ? &c->wait_ack : find_ack(c, m.request_id);
        if (a) {
            ack->status = a->status;
            snprintf(ack->message, sizeof ack->message, "%s", a->message);
            if (a->status != HAPSIM_COMMAND_ACK_T_STATUS_PENDING) {
                ack->rtt_us = hs_client_now_us() - t0;
                return HS_OK;
            }
            pending = 1;
        }
        now = hs_client_now_us();
        if (now >= deadline)
            return hs_err_set(err, HS_ERR_IO,
                              "hs_client_command: no %sack for request %lld after %d ms",
                              pending ? "final " : "", (long long)m.request_id, timeout_ms);
        int64_t wait = (next_send < deadline ? next_send : deadline) - now;
        int r = hs_client_poll(c, (int)((wait + 999) / 1000), err);
        if (r < 0) return (hs_status)r;
    }
}
