// SPDX-License-Identifier: MIT
// hapsim-web: bridges a hapsim-server's LCM buses to browsers (docs/client.md "hapsim-web").
// Three threads: the LCM thread (libhapsim-client + a TOOL_STATE subscriber, commands with
// retry), the pose thread (the mouse probe's steady tool_pose stream) and the libwebsockets
// service loop (main thread: static files + one WebSocket per browser). They meet in the hub
// (hub.h): newest-value slots and a bounded event ring, so a slow browser skips frames and
// nothing ever waits on a browser.
#define _GNU_SOURCE
#include "hapsim/version.h"
#include <cjson/cJSON.h>
#include <errno.h>
#include <libwebsockets.h>
#include <lcm/lcm.h>
#include <limits.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdatomic.h>
#include <sys/resource.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include "hapsim/client.h"
#include "hapsim_channels.h"
#include "hapsim_command_t.h"
#include "hapsim_proto.h"
#include "hub.h"

#define WEB_MAX_DEV    HS_CLIENT_MAX_DEVICES
#define FRAME_US       33333    // positions and tools at most 30 Hz
#define POSE_PERIOD_NS 4000000L // mouse probe poses at 250 Hz
#define PROBE_STALE_US 1000000  // no target from the browser for this long: stop sending poses
#define CMD_QUEUE      16

typedef struct web_cmd {
    int session;
    int32_t kind;
    int n_args;
    char label[32];
    char keys[2][64];
    char vals[2][256];
} web_cmd;

typedef struct web_app {
    hs_web_hub hub;
    struct lws_context* ctx;
    hs_client* client;
    lcm_t* ts_lcm; // TOOL_STATE subscriber on the mesh bus
    char prefix[64];
    int wake[2];             // pipe: lws thread -> LCM thread (commands queued)
    web_cmd cmds[CMD_QUEUE]; // guarded by hub.mu
    int n_cmds;
    atomic_int stop; // set by a signal, --duration or a failure; read by every thread
    int64_t t_end;   // hs_client_now_us() to stop at, 0: run until a signal
    // LCM thread only:
    hs_wire_tool_state tools[WEB_MAX_DEV];
    int64_t tool_arrival[WEB_MAX_DEV];
    hs_local_model models[WEB_MAX_DEV];
    int tools_dirty, mesh_dirty;
    int64_t last_topo, last_pos_us, last_tools_us;
    uint64_t topo_hash;         // FNV-1a of the published rest positions and triangles
    int64_t topologies_seen;    // hs_sync_stats.topologies at the last check
    int64_t topo_recheck_until; // us: compare contents until then (a restarted server may
                                // reuse a version number for another mesh)
    int64_t tool_states, tool_states_bad;
    // lws thread only:
    int64_t ws_frames, ws_bytes, ws_sessions;
    char scene[256];
} web_app;

static web_app g_app;
static int g_next_session = 1;

static void on_signal(int sig) {
    (void)sig;
    g_app.stop = 1; // the LCM thread sees it within 10 ms and wakes the lws loop
}

static void wake_lws(web_app* a) {
    if (a->ctx) lws_cancel_service(a->ctx);
}

// --- JSON helpers --------------------------------------------------------------------------

typedef struct jbuf {
    char* p;
    size_t n, cap;
    int oom;
} jbuf;

static void jb_printf(jbuf* b, const char* fmt, ...) {
    if (b->oom) return;
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        int k = vsnprintf(b->p + b->n, b->cap - b->n, fmt, ap);
        va_end(ap);
        if (k < 0) {
            b->oom = 1;
            return;
        }
        if ((size_t)k < b->cap - b->n) {
            b->n += (size_t)k;
            return;
        }
        size_t nc = b->cap * 2 + (size_t)k + 64;
        char* np = realloc(b->p, nc);
        if (!np) {
            b->oom = 1;
            return;
        }
        b->p = np;
        b->cap = nc;
    }
}

// A JSON string literal of s (control bytes escaped).
static void jb_str(jbuf* b, const char* s) {
    jb_printf(b, "\"");
    for (; *s; ++s) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\')
            jb_printf(b, "\\%c", c);
        else if (c < 0x20)
            jb_printf(b, "\\u%04x", c);
        else
            jb_printf(b, "%c", c);
    }
    jb_printf(b, "\"");
}

// A finite number or null (JSON has no NaN).
static void jb_num(jbuf* b, double v) {
    if (isfinite(v))
        jb_printf(b, "%.9g", v);
    else
        jb_printf(b, "null");
}

static void jb_vec(jbuf* b, const double* v, int n) {
    jb_printf(b, "[");
    for (int i = 0; i < n; ++i) {
        if (i) jb_printf(b, ",");
        jb_num(b, v[i]);
    }
    jb_printf(b, "]");
}

static void jb_init(jbuf* b) {
    b->cap = 1024;
    b->n = 0;
    b->oom = 0;
    b->p = malloc(b->cap);
    if (!b->p)
        b->oom = 1;
    else
        b->p[0] = '\0';
}

// Hand the text to the hub as a blob (frees the buffer).
static hs_web_blob* jb_blob(web_app* a, jbuf* b) {
    hs_web_blob* blob = b->oom ? NULL : hs_web_blob_text(&a->hub, b->p);
    free(b->p);
    b->p = NULL;
    return blob;
}

static void send_event(web_app* a, int target, const char* type, const char* fmt, ...) {
    char body[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(body, sizeof body, fmt, ap);
    va_end(ap);
    jbuf b;
    jb_init(&b);
    jb_printf(&b, "{\"t\":");
    jb_str(&b, type);
    if (body[0]) jb_printf(&b, ",%s", body);
    jb_printf(&b, "}");
    hs_web_hub_event(&a->hub, target, jb_blob(a, &b));
    wake_lws(a);
}

// --- LCM thread: frames for the browsers ---------------------------------------------------

static void put_u32(unsigned char* p, uint32_t v) {
    memcpy(p, &v, 4);
}
static void put_f64(unsigned char* p, double v) {
    memcpy(p, &v, 8);
}

// Binary topology frame: u32 kind 1, u32 n_vis, u32 n_tri, u32 0, f64 version, f32 rest[3 n_vis],
// u32 triangles[3 n_tri] (little endian, as the browsers are).
static void publish_topology(web_app* a, const hs_client_mesh* m) {
    size_t n3 = (size_t)m->n_vis * 3, t3 = (size_t)m->n_tri * 3;
    hs_web_blob* b = hs_web_blob_new(&a->hub, 24 + 4 * n3 + 4 * t3, 1);
    if (!b) return;
    unsigned char* p = b->data + a->hub.pre;
    put_u32(p, 1);
    put_u32(p + 4, (uint32_t)m->n_vis);
    put_u32(p + 8, (uint32_t)m->n_tri);
    put_u32(p + 12, 0);
    put_f64(p + 16, (double)m->topology_version);
    memcpy(p + 24, m->rest, 4 * n3);
    memcpy(p + 24 + 4 * n3, m->triangles, 4 * t3);
    hs_web_hub_publish(&a->hub, HS_WEB_TOPO, b);
}

// Binary positions frame: u32 kind 2, u32 n_vis, f64 version, f64 sim_time, f64 sim_step,
// u32 has_stress, u32 0, f32 position[3 n_vis], then f32 stress[n_vis] when has_stress.
static uint64_t fnv1a(uint64_t h, const void* p, size_t n) {
    const unsigned char* c = p;
    for (size_t i = 0; i < n; ++i) h = (h ^ c[i]) * 1099511628211ull;
    return h;
}

static uint64_t topo_hash(const hs_client_mesh* m) {
    uint64_t h = fnv1a(14695981039346656037ull, m->rest, 12 * (size_t)m->n_vis);
    return fnv1a(h, m->triangles, 12 * (size_t)m->n_tri);
}

static void publish_positions(web_app* a, const hs_client_mesh* m) {
    size_t n3 = (size_t)m->n_vis * 3, ns = m->stress ? (size_t)m->n_vis : 0;
    hs_web_blob* b = hs_web_blob_new(&a->hub, 40 + 4 * (n3 + ns), 1);
    if (!b) return;
    unsigned char* p = b->data + a->hub.pre;
    put_u32(p, 2);
    put_u32(p + 4, (uint32_t)m->n_vis);
    put_f64(p + 8, (double)m->topology_version);
    put_f64(p + 16, m->sim_time);
    put_f64(p + 24, (double)m->sim_step);
    put_u32(p + 32, m->stress ? 1u : 0u);
    put_u32(p + 36, 0);
    memcpy(p + 40, m->position, 4 * n3);
    if (ns) memcpy(p + 40 + 4 * n3, m->stress, 4 * ns);
    hs_web_hub_publish(&a->hub, HS_WEB_POS, b);
}

static void publish_tools(web_app* a, int64_t now) {
    jbuf b;
    jb_init(&b);
    jb_printf(&b, "{\"t\":\"tools\",\"tools\":[");
    int first = 1;
    for (int d = 0; d < WEB_MAX_DEV; ++d) {
        if (!a->tool_arrival[d] || now - a->tool_arrival[d] > 500000) continue;
        const hs_wire_tool_state* t = &a->tools[d];
        jb_printf(&b, "%s{\"dev\":%d,\"tool\":%d,\"kind\":%d,\"p\":", first ? "" : ",",
                  t->device_id, t->tool_id, t->kind);
        jb_vec(&b, t->position, 3);
        jb_printf(&b, ",\"q\":");
        jb_vec(&b, t->orientation, 4);
        jb_printf(&b, ",\"r\":");
        jb_num(&b, t->radius);
        jb_printf(&b, ",\"a\":");
        jb_vec(&b, t->blade_a, 3);
        jb_printf(&b, ",\"b\":");
        jb_vec(&b, t->blade_b, 3);
        jb_printf(&b, ",\"f\":");
        jb_vec(&b, t->force, 3);
        jb_printf(&b, ",\"contact\":%d,\"cutting\":%d,\"utime\":%lld}", t->contact, t->cutting,
                  (long long)t->utime);
        first = 0;
    }
    jb_printf(&b, "],\"models\":[");
    first = 1;
    for (int d = 0; d < WEB_MAX_DEV; ++d) {
        const hs_local_model* m = &a->models[d];
        if (!m->valid || now - m->arrival_us > 500000) continue;
        jb_printf(&b, "%s{\"dev\":%d,\"state\":%d,\"f\":", first ? "" : ",", d, m->state);
        jb_vec(&b, m->force, 3);
        jb_printf(&b, ",\"anchor\":");
        jb_vec(&b, m->anchor, 3);
        jb_printf(&b, "}");
        first = 0;
    }
    pthread_mutex_lock(&a->hub.mu);
    hs_web_probe pr = a->hub.probe;
    pthread_mutex_unlock(&a->hub.mu);
    jb_printf(&b, "],\"mouse\":{\"active\":%d,\"dev\":%d,\"sent\":%lld}}", pr.active, pr.device_id,
              (long long)pr.sent);
    hs_web_hub_publish(&a->hub, HS_WEB_TOOLS, jb_blob(a, &b));
}

static void on_status(hs_client* c, const hs_client_status* st, void* user) {
    (void)c;
    web_app* a = user;
    jbuf b;
    jb_init(&b);
    jb_printf(&b, "{\"t\":\"status\",\"state\":");
    jb_str(&b, hs_client_state_name(st->state));
    jb_printf(&b, ",\"scene\":");
    jb_str(&b, st->scene);
    jb_printf(&b, ",\"uptime_s\":%.3f,\"topology_version\":%lld,\"seq\":%lld,\"loops\":[",
              (double)st->uptime_us * 1e-6, (long long)st->topology_version, (long long)st->seq);
    int nl = st->n_loops < HS_CLIENT_STATUS_LOOPS ? st->n_loops : HS_CLIENT_STATUS_LOOPS;
    for (int i = 0; i < nl; ++i) {
        jb_printf(&b, "%s{\"name\":", i ? "," : "");
        jb_str(&b, st->loops[i].name);
        jb_printf(&b, ",\"rate_hz\":");
        jb_num(&b, st->loops[i].rate_hz);
        jb_printf(&b, ",\"p50_us\":");
        jb_num(&b, st->loops[i].p50_us);
        jb_printf(&b, ",\"p99_us\":");
        jb_num(&b, st->loops[i].p99_us);
        jb_printf(&b, ",\"max_us\":");
        jb_num(&b, st->loops[i].max_us);
        jb_printf(&b, ",\"overruns\":%lld}", (long long)st->loops[i].overruns);
    }
    jb_printf(&b, "],\"steps\":[");
    int ns = st->n_steps < HS_CLIENT_STATUS_STEPS ? st->n_steps : HS_CLIENT_STATUS_STEPS;
    for (int i = 0; i < ns; ++i) {
        jb_printf(&b, "%s{\"name\":", i ? "," : "");
        jb_str(&b, st->steps[i].name);
        jb_printf(&b, ",\"p50_us\":");
        jb_num(&b, st->steps[i].p50_us);
        jb_printf(&b, ",\"p99_us\":");
        jb_num(&b, st->steps[i].p99_us);
        jb_printf(&b, ",\"max_us\":");
        jb_num(&b, st->steps[i].max_us);
        jb_printf(&b, "}");
    }
    jb_printf(&b, "],\"devices\":[");
    int nd = st->n_devices < HS_CLIENT_STATUS_DEVICES ? st->n_devices : HS_CLIENT_STATUS_DEVICES;
    hs_web_devices dev = {.known = 1, .n = nd};
    for (int i = 0; i < nd; ++i) {
        jb_printf(&b, "%s{\"id\":%d,\"live\":%d,\"age_ms\":", i ? "," : "", st->devices[i].id,
                  st->devices[i].live);
        jb_num(&b, st->devices[i].pose_age_ms);
        jb_printf(&b, ",\"received\":%lld,\"lost\":%lld,\"lat_p99_us\":",
                  (long long)st->devices[i].poses_received, (long long)st->devices[i].poses_lost);
        jb_num(&b, st->devices[i].latency_p99_us);
        jb_printf(&b, ",\"force_n\":");
        jb_num(&b, st->devices[i].force_norm);
        jb_printf(&b, "}");
        int id = st->devices[i].id;
        if (id >= 0 && id < 16) dev.live[id] = st->devices[i].live != 0;
    }
    jb_printf(&b, "],\"rejects\":[");
    int nr = st->n_rejects < HS_CLIENT_STATUS_REJECTS ? st->n_rejects : HS_CLIENT_STATUS_REJECTS;
    for (int i = 0; i < nr; ++i) {
        jb_printf(&b, "%s{\"channel\":", i ? "," : "");
        jb_str(&b, st->rejects[i].channel);
        jb_printf(&b, ",\"reason\":");
        jb_str(&b, st->rejects[i].reason);
        jb_printf(&b, ",\"count\":%lld}", (long long)st->rejects[i].count);
    }
    jb_printf(&b, "],\"warnings\":");
    jb_str(&b, st->warnings);
    hs_sync_stats ss;
    hs_client_mesh_stats(c, &ss);
    jb_printf(&b, ",\"mesh_lost\":%lld,\"malformed\":%lld,\"tool_states\":%lld}",
              (long long)(ss.lost[0] + ss.lost[1] + ss.lost[2] + ss.lost[3]),
              (long long)ss.malformed, (long long)a->tool_states);
    hs_web_hub_publish(&a->hub, HS_WEB_STATUS, jb_blob(a, &b));
    pthread_mutex_lock(&a->hub.mu);
    a->hub.dev = dev;
    pthread_mutex_unlock(&a->hub.mu);
    snprintf(a->scene, sizeof a->scene, "%s", st->scene);
    wake_lws(a);
}

static void on_mesh(hs_client* c, const hs_client_mesh* m, void* user) {
    (void)c;
    (void)m;
    ((web_app*)user)->mesh_dirty = 1;
}

static void on_force(hs_client* c, int32_t id, const hs_local_model* m, void* user) {
    (void)c;
    web_app* a = user;
    if (id >= 0 && id < WEB_MAX_DEV) a->models[id] = *m;
}

// TOOL_STATE through the protocol library's bounded decoder: a message of another length, or
// with non-finite numbers, is dropped.
static void on_tool_state(const lcm_recv_buf_t* rbuf, const char* ch, void* user) {
    (void)ch;
    web_app* a = user;
    hs_wire_tool_state t;
    if (hs_wire_tool_state_decode(rbuf->data, rbuf->data_size, &t)) {
        a->tool_states_bad++;
        return;
    }
    if (t.device_id < 0 || t.device_id >= WEB_MAX_DEV) {
        a->tool_states_bad++;
        return;
    }
    a->tools[t.device_id] = t;
    a->tool_arrival[t.device_id] = hs_client_now_us();
    a->tool_states++;
    a->tools_dirty = 1;
}

static int32_t cmd_kind(const char* name) {
    static const struct {
        const char* n;
        int32_t k;
    } t[] = {{"reset", HAPSIM_COMMAND_T_KIND_RESET},
             {"pause", HAPSIM_COMMAND_T_KIND_PAUSE},
             {"resume", HAPSIM_COMMAND_T_KIND_RESUME},
             {"estop", HAPSIM_COMMAND_T_KIND_ESTOP},
             {"estop-release", HAPSIM_COMMAND_T_KIND_ESTOP_RELEASE},
             {"request-topology", HAPSIM_COMMAND_T_KIND_REQUEST_TOPOLOGY},
             {"set", HAPSIM_COMMAND_T_KIND_SET_PARAM}};
    for (size_t i = 0; i < sizeof t / sizeof t[0]; ++i)
        if (!strcmp(name, t[i].n)) return t[i].k;
    return -1;
}

static void run_command(web_app* a, const web_cmd* cmd) {
    const char* keys[2] = {cmd->keys[0], cmd->keys[1]};
    const char* vals[2] = {cmd->vals[0], cmd->vals[1]};
    hs_client_ack ack;
    memset(&ack, 0, sizeof ack);
    hs_err err = {0};
    hs_status s =
        hs_client_command(a->client, cmd->kind, cmd->n_args, keys, vals, 3000, 250, &ack, &err);
    jbuf b;
    jb_init(&b);
    jb_printf(&b, "{\"t\":\"ack\",\"cmd\":");
    jb_str(&b, cmd->label);
    if (s == HS_OK) {
        static const char* names[] = {"failed", "invalid", "ok", "pending"};
        int si = ack.status + 2;
        jb_printf(&b, ",\"ok\":%d,\"status\":", ack.status == 0);
        jb_str(&b, si >= 0 && si < 4 ? names[si] : "unknown");
        jb_printf(&b, ",\"attempts\":%d,\"rtt_ms\":%.1f,\"message\":", ack.attempts,
                  (double)ack.rtt_us * 1e-3);
        jb_str(&b, ack.message);
    } else {
        jb_printf(&b, ",\"ok\":0,\"status\":\"%s\",\"message\":",
                  s == HS_ERR_IO ? "no answer" : "refused");
        jb_str(&b, err.msg[0] ? err.msg : hs_client_status_str(s));
    }
    jb_printf(&b, "}");
    hs_web_hub_event(&a->hub, cmd->session, jb_blob(a, &b));
    wake_lws(a);
}

static void* lcm_thread(void* arg) {
    web_app* a = arg;
    hs_client_callbacks cb = {.on_mesh = on_mesh, .on_force = on_force, .on_status = on_status};
    hs_client_set_callbacks(a->client, &cb, a);
    hs_err err = {0};
    while (!a->stop) {
        struct pollfd pf[4];
        int n = 0;
        for (int bus = 0; bus < 2; ++bus) {
            int fd = hs_client_fileno(a->client, bus);
            if (fd >= 0) pf[n++] = (struct pollfd){.fd = fd, .events = POLLIN};
        }
        int ts_i = n;
        pf[n++] = (struct pollfd){.fd = lcm_get_fileno(a->ts_lcm), .events = POLLIN};
        int wk_i = n;
        pf[n++] = (struct pollfd){.fd = a->wake[0], .events = POLLIN};
        int r = poll(pf, (nfds_t)n, 10);
        if (r < 0 && errno != EINTR) {
            fprintf(stderr, "hapsim-web: poll failed: %s\n", strerror(errno));
            a->stop = 1;
            break;
        }
        if (r > 0) {
            int any = 0;
            for (int i = 0; i < ts_i; ++i) any |= (pf[i].revents & POLLIN) != 0;
            if (any && hs_client_poll(a->client, 0, &err) < 0)
                fprintf(stderr, "hapsim-web: LCM receive failed: %s\n", err.msg);
            for (int k = 0; k < 64 && (pf[ts_i].revents & POLLIN); ++k) {
                if (lcm_handle(a->ts_lcm) != 0) break;
                struct pollfd q = {.fd = pf[ts_i].fd, .events = POLLIN};
                if (poll(&q, 1, 0) <= 0) break;
            }
            if (pf[wk_i].revents & POLLIN) {
                char drain[64];
                if (read(a->wake[0], drain, sizeof drain) < 0) { /* nothing queued */
                }
            }
        }
        for (;;) {
            web_cmd cmd;
            pthread_mutex_lock(&a->hub.mu);
            int have = a->n_cmds > 0;
            if (have) {
                cmd = a->cmds[0];
                memmove(a->cmds, a->cmds + 1, (size_t)(a->n_cmds - 1) * sizeof a->cmds[0]);
                a->n_cmds--;
            }
            pthread_mutex_unlock(&a->hub.mu);
            if (!have) break;
            run_command(a, &cmd);
        }
        int64_t now = hs_client_now_us();
        if (a->t_end && now >= a->t_end) a->stop = 1;
        int woke = 0;
        const hs_client_mesh* m = hs_client_mesh_view(a->client);
        hs_sync_stats ss;
        hs_client_mesh_stats(a->client, &ss);
        if (ss.topologies != a->topologies_seen) {
            a->topologies_seen = ss.topologies;
            a->topo_recheck_until = now + 3000000;
        }
        int topo_new = m->ready && m->topology_version != a->last_topo;
        if (m->ready && !topo_new && now < a->topo_recheck_until && a->mesh_dirty)
            topo_new = topo_hash(m) != a->topo_hash;
        if (topo_new) {
            publish_topology(a, m);
            a->topo_hash = topo_hash(m);
            a->last_topo = m->topology_version;
            a->mesh_dirty = 1;
            a->last_pos_us = 0;
            woke = 1;
        }
        if (m->ready && a->mesh_dirty && now - a->last_pos_us >= FRAME_US) {
            publish_positions(a, m);
            a->mesh_dirty = 0;
            a->last_pos_us = now;
            woke = 1;
        }
        // Tools go out while any tool is shown (so a vanished tool disappears too).
        int any_tool = a->tools_dirty;
        for (int d = 0; d < WEB_MAX_DEV && !any_tool; ++d)
            any_tool = a->tool_arrival[d] && now - a->tool_arrival[d] < 1000000;
        if (any_tool && now - a->last_tools_us >= FRAME_US) {
            publish_tools(a, now);
            a->tools_dirty = 0;
            a->last_tools_us = now;
            woke = 1;
        }
        if (woke) wake_lws(a);
    }
    wake_lws(a); // lets the service loop see stop
    return NULL;
}

// --- pose thread: the mouse probe -----------------------------------------------------------

static void* pose_thread(void* arg) {
    web_app* a = arg;
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    while (!a->stop) {
        next.tv_nsec += POSE_PERIOD_NS;
        if (next.tv_nsec >= 1000000000L) {
            next.tv_nsec -= 1000000000L;
            next.tv_sec++;
        }
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL) == EINTR) {
        }
        // After a stall (a loaded machine) go on from now rather than send a burst to catch up.
        struct timespec nowts;
        clock_gettime(CLOCK_MONOTONIC, &nowts);
        if ((nowts.tv_sec - next.tv_sec) * 1000000000L + (nowts.tv_nsec - next.tv_nsec) >
            POSE_PERIOD_NS)
            next = nowts;
        pthread_mutex_lock(&a->hub.mu);
        hs_web_probe p = a->hub.probe;
        pthread_mutex_unlock(&a->hub.mu);
        int64_t now = hs_client_now_us();
        if (!p.active || !p.updated_us || now - p.updated_us > PROBE_STALE_US) continue;
        hs_client_pose pose = {.device_id = p.device_id,
                               .tool_id = p.tool_id,
                               .position = {p.position[0], p.position[1], p.position[2]},
                               .orientation = {1, 0, 0, 0}};
        hs_err err = {0};
        if (hs_client_send_pose(a->client, &pose, &err) == HS_OK) {
            pthread_mutex_lock(&a->hub.mu);
            a->hub.probe.sent++;
            pthread_mutex_unlock(&a->hub.mu);
        }
    }
    return NULL;
}

// --- the WebSocket side (lws service thread) -------------------------------------------------

typedef struct web_session {
    int id;
    uint64_t sent_gen[HS_WEB_KINDS];
    uint64_t next_event;
    char rx[4096];
    size_t rx_len;
    int rx_overflow;
} web_session;

static void queue_command(web_app* a, int session, const char* label, int32_t kind, int n_args,
                          const char* k0, const char* v0, const char* k1, const char* v1) {
    pthread_mutex_lock(&a->hub.mu);
    int ok = a->n_cmds < CMD_QUEUE;
    if (ok) {
        web_cmd* c = &a->cmds[a->n_cmds++];
        memset(c, 0, sizeof *c);
        c->session = session;
        c->kind = kind;
        c->n_args = n_args;
        snprintf(c->label, sizeof c->label, "%s", label);
        if (n_args > 0) {
            snprintf(c->keys[0], sizeof c->keys[0], "%s", k0);
            snprintf(c->vals[0], sizeof c->vals[0], "%s", v0);
        }
        if (n_args > 1) {
            snprintf(c->keys[1], sizeof c->keys[1], "%s", k1);
            snprintf(c->vals[1], sizeof c->vals[1], "%s", v1);
        }
    }
    pthread_mutex_unlock(&a->hub.mu);
    if (!ok) {
        send_event(a, session, "ack",
                   "\"cmd\":\"%s\",\"ok\":0,\"status\":\"busy\","
                   "\"message\":\"16 commands already waiting\"",
                   label);
        return;
    }
    if (write(a->wake[1], "c", 1) < 0) { /* the LCM thread polls every 10 ms anyway */
    }
}

static void probe_start(web_app* a, int session) {
    char why[256] = "";
    int dev = -1;
    pthread_mutex_lock(&a->hub.mu);
    hs_web_probe* p = &a->hub.probe;
    if (p->active && p->owner != session) {
        snprintf(why, sizeof why, "another browser is probing with the mouse (device %d)",
                 p->device_id);
    } else if (p->active) {
        dev = p->device_id;
    } else if (!a->hub.dev.known) {
        snprintf(why, sizeof why, "no server status yet: is hapsim-server running on this bus?");
    } else if (a->hub.dev.n <= 0) {
        snprintf(why, sizeof why, "the scene has no devices (haptics off)");
    } else {
        for (int d = 0; d < a->hub.dev.n && d < 16; ++d)
            if (!a->hub.dev.live[d]) {
                dev = d;
                break;
            }
        if (dev < 0)
            snprintf(why, sizeof why,
                     "no free device: the scene has %d device%s and every one is driven "
                     "(stop a driver or give the scene more devices)",
                     a->hub.dev.n, a->hub.dev.n == 1 ? "" : "s");
        else {
            p->active = 1;
            p->owner = session;
            p->device_id = dev;
            p->tool_id = 0;
            p->updated_us = 0;
        }
    }
    pthread_mutex_unlock(&a->hub.mu);
    if (dev < 0)
        send_event(a, session, "probe", "\"active\":0,\"refused\":1,\"message\":\"%s\"", why);
    else
        send_event(a, session, "probe", "\"active\":1,\"dev\":%d,\"message\":\"%s\"", dev,
                   dev == 0 ? ""
                            : "this server drives the probe from device 0 only: "
                              "the mouse gets zero force");
}

static void probe_stop(web_app* a, int session, int quiet) {
    pthread_mutex_lock(&a->hub.mu);
    int mine = a->hub.probe.active && a->hub.probe.owner == session;
    if (mine) {
        a->hub.probe.active = 0;
        a->hub.probe.updated_us = 0;
    }
    pthread_mutex_unlock(&a->hub.mu);
    if (mine && !quiet) send_event(a, session, "probe", "\"active\":0,\"message\":\"\"");
}

static void probe_pose(web_app* a, int session, const cJSON* pv) {
    double p[3];
    if (!cJSON_IsArray(pv) || cJSON_GetArraySize(pv) != 3) return;
    for (int i = 0; i < 3; ++i) {
        const cJSON* e = cJSON_GetArrayItem(pv, i);
        if (!cJSON_IsNumber(e) || !isfinite(e->valuedouble) || fabs(e->valuedouble) > 10) return;
        p[i] = e->valuedouble;
    }
    pthread_mutex_lock(&a->hub.mu);
    if (a->hub.probe.active && a->hub.probe.owner == session) {
        memcpy(a->hub.probe.position, p, sizeof p);
        a->hub.probe.updated_us = hs_client_now_us();
    }
    pthread_mutex_unlock(&a->hub.mu);
}

static void handle_text(web_app* a, web_session* s, const char* txt) {
    cJSON* j = cJSON_Parse(txt);
    if (!j) {
        send_event(a, s->id, "error", "\"message\":\"not JSON\"");
        return;
    }
    const cJSON* cmd = cJSON_GetObjectItemCaseSensitive(j, "cmd");
    const cJSON* probe = cJSON_GetObjectItemCaseSensitive(j, "probe");
    if (cJSON_IsString(cmd)) {
        int32_t kind = cmd_kind(cmd->valuestring);
        if (kind < 0) {
            send_event(a, s->id, "ack",
                       "\"cmd\":\"?\",\"ok\":0,\"status\":\"refused\","
                       "\"message\":\"unknown command\"");
        } else if (kind == HAPSIM_COMMAND_T_KIND_SET_PARAM) {
            const cJSON* name = cJSON_GetObjectItemCaseSensitive(j, "name");
            const cJSON* value = cJSON_GetObjectItemCaseSensitive(j, "value");
            if (!cJSON_IsString(name) || !cJSON_IsString(value) || strlen(name->valuestring) > 63 ||
                strlen(value->valuestring) > 255)
                send_event(a, s->id, "ack",
                           "\"cmd\":\"set\",\"ok\":0,\"status\":\"refused\","
                           "\"message\":\"set needs a name and a value\"");
            else
                queue_command(a, s->id, "set", kind, 2, "name", name->valuestring, "value",
                              value->valuestring);
        } else {
            queue_command(a, s->id, cmd->valuestring, kind, 0, NULL, NULL, NULL, NULL);
        }
    } else if (cJSON_IsString(probe)) {
        if (!strcmp(probe->valuestring, "start"))
            probe_start(a, s->id);
        else if (!strcmp(probe->valuestring, "stop"))
            probe_stop(a, s->id, 0);
        else if (!strcmp(probe->valuestring, "pose"))
            probe_pose(a, s->id, cJSON_GetObjectItemCaseSensitive(j, "p"));
    }
    cJSON_Delete(j);
}

// Next blob for a session: the newest of each kind it has not had, then its events.
static hs_web_blob* next_blob(web_app* a, web_session* s, int* more) {
    hs_web_blob* out = NULL;
    *more = 0;
    pthread_mutex_lock(&a->hub.mu);
    hs_web_hub* h = &a->hub;
    if (h->n_events > s->next_event + HS_WEB_EVENTS) s->next_event = h->n_events - HS_WEB_EVENTS;
    for (int k = 0; k < HS_WEB_KINDS; ++k) {
        if (h->latest[k] && s->sent_gen[k] != h->gen[k]) {
            if (!out) {
                out = h->latest[k];
                out->refs++;
                s->sent_gen[k] = h->gen[k];
            } else {
                *more = 1;
            }
        }
    }
    while (s->next_event < h->n_events) {
        size_t i = (size_t)(s->next_event % HS_WEB_EVENTS);
        if (h->event_target[i] != 0 && h->event_target[i] != s->id) {
            s->next_event++;
            continue;
        }
        if (out) {
            *more = 1;
            break;
        }
        out = h->events[i];
        out->refs++;
        s->next_event++;
    }
    pthread_mutex_unlock(&a->hub.mu);
    return out;
}

static int cb_ws(struct lws* wsi, enum lws_callback_reasons reason, void* user, void* in,
                 size_t len) {
    web_app* a = &g_app;
    web_session* s = user;
    switch (reason) {
    case LWS_CALLBACK_FILTER_PROTOCOL_CONNECTION: {
        // A browser sends its page's Origin: only our own page may connect (another web site
        // open in the same browser must not be able to send commands to the server). Clients
        // that send no Origin (scripts, not browsers) are let in.
        char origin[256] = "", host[256] = "";
        if (lws_hdr_copy(wsi, origin, sizeof origin, WSI_TOKEN_ORIGIN) <= 0) break;
        if (lws_hdr_copy(wsi, host, sizeof host, WSI_TOKEN_HOST) <= 0) return 1;
        const char* o = origin;
        if (!strncmp(o, "http://", 7))
            o += 7;
        else if (!strncmp(o, "https://", 8))
            o += 8;
        if (strcmp(o, host) != 0) {
            fprintf(stderr, "hapsim-web: WebSocket from origin '%s' refused (this is %s)\n", origin,
                    host);
            return 1;
        }
        break;
    }
    case LWS_CALLBACK_ESTABLISHED:
        memset(s, 0, sizeof *s);
        s->id = g_next_session++;
        a->ws_sessions++;
        pthread_mutex_lock(&a->hub.mu);
        s->next_event = a->hub.n_events;
        pthread_mutex_unlock(&a->hub.mu);
        send_event(a, s->id, "hello", "\"session\":%d,\"prefix\":\"%s\",\"version\":%d", s->id,
                   a->prefix, HS_CLIENT_VERSION);
        lws_callback_on_writable(wsi);
        break;
    case LWS_CALLBACK_CLOSED:
        probe_stop(a, s->id, 1);
        break;
    case LWS_CALLBACK_RECEIVE:
        if (s->rx_len + len >= sizeof s->rx)
            s->rx_overflow = 1;
        else {
            memcpy(s->rx + s->rx_len, in, len);
            s->rx_len += len;
        }
        if (lws_is_final_fragment(wsi) && !lws_remaining_packet_payload(wsi)) {
            if (s->rx_overflow)
                send_event(a, s->id, "error", "\"message\":\"message too long\"");
            else {
                s->rx[s->rx_len] = '\0';
                handle_text(a, s, s->rx);
            }
            s->rx_len = 0;
            s->rx_overflow = 0;
        }
        break;
    case LWS_CALLBACK_SERVER_WRITEABLE: {
        if (lws_send_pipe_choked(wsi)) {
            lws_callback_on_writable(wsi);
            break;
        }
        int more = 0;
        hs_web_blob* b = next_blob(a, s, &more);
        if (b) {
            // lws takes the whole frame (buffering what the socket does not) or fails.
            int w = lws_write(wsi, b->data + a->hub.pre, b->len,
                              b->binary ? LWS_WRITE_BINARY : LWS_WRITE_TEXT);
            a->ws_frames++;
            a->ws_bytes += w > 0 ? w : 0;
            hs_web_blob_unref(&a->hub, b);
            if (w < 0) return -1;
        }
        if (more) lws_callback_on_writable(wsi);
        break;
    }
    default:
        break;
    }
    return 0;
}

static int cb_http(struct lws* wsi, enum lws_callback_reasons reason, void* user, void* in,
                   size_t len);

static struct lws_protocols g_protocols[] = {
    {"http", cb_http, 0, 0, 0, NULL, 0},
    {"hapsim", cb_ws, sizeof(web_session), 4096, 0, NULL, 0},
    {NULL, NULL, 0, 0, 0, NULL, 0},
};

static int cb_http(struct lws* wsi, enum lws_callback_reasons reason, void* user, void* in,
                   size_t len) {
    if (reason == LWS_CALLBACK_EVENT_WAIT_CANCELLED) {
        lws_callback_on_writable_all_protocol(lws_get_context(wsi), &g_protocols[1]);
        return 0;
    }
    return lws_callback_http_dummy(wsi, reason, user, in, len);
}

// --- main --------------------------------------------------------------------------------------

static void usage(FILE* f) {
    fprintf(f, "usage: hapsim-web [--port N] [--bind ADDR] [--web-root DIR] [--mesh-url URL]\n"
               "                  [--haptic-url URL] [--prefix P] [--duration S] [--quiet]\n"
               "Serves a live view of a running hapsim-server at http://ADDR:N/ (default\n"
               "127.0.0.1:8080): the deforming surface, tools, forces, status, commands and a\n"
               "mouse probe. --bind 0.0.0.0 opens it to the LAN (the page can send commands).\n"
               "Exit status: 0 ok, 1 a port in use or the buses cannot be opened, 2 bad usage.\n");
}

// Can this host listen on addr:port? lws would otherwise start without a listening socket on an
// address that is not this host's (and say so only in its log). 0, or with why[] filled -2 for
// an address that is bad usage (not numeric, not this host's), -1 otherwise (a port in use).
static int check_bind(const char* addr, int port, char* why, size_t n) {
    struct sockaddr_storage ss;
    memset(&ss, 0, sizeof ss);
    socklen_t len;
    struct sockaddr_in* v4 = (struct sockaddr_in*)&ss;
    struct sockaddr_in6* v6 = (struct sockaddr_in6*)&ss;
    if (inet_pton(AF_INET, addr, &v4->sin_addr) == 1) {
        v4->sin_family = AF_INET;
        v4->sin_port = htons((uint16_t)port);
        len = sizeof *v4;
    } else if (inet_pton(AF_INET6, addr, &v6->sin6_addr) == 1) {
        v6->sin6_family = AF_INET6;
        v6->sin6_port = htons((uint16_t)port);
        len = sizeof *v6;
    } else {
        snprintf(why, n, "not a numeric IPv4 or IPv6 address");
        return -2;
    }
    int fd = socket(ss.ss_family, SOCK_STREAM, 0);
    if (fd < 0) {
        snprintf(why, n, "socket: %s", strerror(errno));
        return -1;
    }
    int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    int rc = bind(fd, (struct sockaddr*)&ss, len), e = errno;
    if (rc != 0) snprintf(why, n, "%s", strerror(e));
    close(fd);
    return rc == 0 ? 0 : e == EADDRNOTAVAIL ? -2 : -1;
}

// The folder holding index.html: --web-root, else <exe>/../share/hapsim/web (build and install).
static int find_web_root(char* out, size_t n, const char* given) {
    if (given) {
        snprintf(out, n, "%s", given);
    } else {
        char exe[PATH_MAX];
        ssize_t k = readlink("/proc/self/exe", exe, sizeof exe - 1);
        if (k <= 0) return -1;
        exe[k] = '\0';
        char* slash = strrchr(exe, '/');
        if (!slash) return -1;
        *slash = '\0';
        if ((size_t)snprintf(out, n, "%s/../share/hapsim/web", exe) >= n) return -1;
    }
    char idx[PATH_MAX + 32];
    snprintf(idx, sizeof idx, "%s/index.html", out);
    char real[PATH_MAX];
    if (access(idx, R_OK) != 0 || !realpath(out, real)) return -1;
    snprintf(out, n, "%s", real);
    return 0;
}

// The command line outside the client's configuration.
typedef struct web_opts {
    int port;
    const char* bind_addr;
    const char* web_root_opt;
    double duration;
    int quiet;
} web_opts;

// Reads the command line into w and cfg; -1 to go on, else the exit status.
static int parse_args(int argc, char** argv, web_opts* w, hs_client_config* cfg) {
    for (int i = 1; i < argc; ++i) {
        const char* o = argv[i];
        const char* v = i + 1 < argc ? argv[i + 1] : NULL;
        char* end = NULL;
        if (!strcmp(o, "-h") || !strcmp(o, "--help")) {
            usage(stdout);
            return 0;
        } else if (!strcmp(o, "--quiet")) {
            w->quiet = 1;
            continue;
        }
        if (!v) {
            fprintf(stderr, "hapsim-web: %s needs a value\n", o);
            usage(stderr);
            return 2;
        }
        ++i;
        if (!strcmp(o, "--port")) {
            long p = strtol(v, &end, 10);
            if (!*v || *end || p < 1 || p > 65535) {
                fprintf(stderr, "hapsim-web: --port '%s': want 1..65535\n", v);
                return 2;
            }
            w->port = (int)p;
        } else if (!strcmp(o, "--bind"))
            w->bind_addr = v;
        else if (!strcmp(o, "--web-root"))
            w->web_root_opt = v;
        else if (!strcmp(o, "--mesh-url"))
            cfg->mesh_url = v;
        else if (!strcmp(o, "--haptic-url"))
            cfg->haptic_url = v;
        else if (!strcmp(o, "--prefix"))
            cfg->prefix = v;
        else if (!strcmp(o, "--duration")) {
            w->duration = strtod(v, &end);
            if (!*v || *end || !(w->duration >= 0) || w->duration > 1e7) {
                fprintf(stderr, "hapsim-web: --duration '%s': want seconds 0..1e7\n", v);
                return 2;
            }
        } else {
            fprintf(stderr, "hapsim-web: unknown option '%s'\n", o);
            usage(stderr);
            return 2;
        }
    }
    return -1;
}

// The client and the tool-state subscriber, the wake pipe; 0, else the exit status.
static int open_buses(web_app* a, const hs_client_config* cfg) {
    hs_err err = {0};
    if (hs_client_create(cfg, &a->client, &err) != HS_OK) {
        fprintf(stderr, "hapsim-web: cannot open the LCM buses: %s\n", err.msg);
        return 1;
    }
    // TOOL_STATE is not taken by the client library: a second mesh-bus subscriber of our own.
    const char* murl = cfg->mesh_url ? cfg->mesh_url : HAPSIM_DEFAULT_MESH_URL;
    a->ts_lcm = lcm_create(murl);
    if (!a->ts_lcm) {
        fprintf(stderr, "hapsim-web: LCM cannot open '%s'\n", murl);
        hs_client_destroy(&a->client);
        return 1;
    }
    char ch[sizeof a->prefix + HAPSIM_CHANNEL_MAX];
    snprintf(ch, sizeof ch, "%.63s%s", a->prefix, HAPSIM_CH_TOOL_STATE);
    lcm_subscribe(a->ts_lcm, ch, on_tool_state, a);
    if (pipe(a->wake) != 0) {
        perror("hapsim-web: pipe");
        return 1;
    }
    return 0;
}

// The HTTP and WebSocket server on bind_addr:port serving web_root; 0, else the exit status.
static int create_context(web_app* a, const char* web_root, const web_opts* w) {
    lws_set_log_level(LLL_ERR, NULL);
    static struct lws_http_mount mount;
    memset(&mount, 0, sizeof mount);
    mount.mountpoint = "/";
    mount.mountpoint_len = 1;
    mount.origin = web_root;
    mount.def = "index.html";
    mount.origin_protocol = LWSMPRO_FILE;
    mount.cache_max_age = 0;
    struct lws_context_creation_info info;
    memset(&info, 0, sizeof info);
    info.port = w->port;
    info.iface = w->bind_addr;
    info.protocols = g_protocols;
    info.mounts = &mount;
    info.gid = -1;
    info.uid = -1;
    a->ctx = lws_create_context(&info);
    if (!a->ctx) {
        fprintf(stderr,
                "hapsim-web: cannot listen on %s:%d (in use, or not an address of "
                "this host?)\n",
                w->bind_addr, w->port);
        lcm_destroy(a->ts_lcm);
        hs_client_destroy(&a->client);
        return 1;
    }
    return 0;
}

// The closing line: what was served and the CPU it took.
static void print_summary(const web_app* a, int64_t t_start) {
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    double cpu = (double)ru.ru_utime.tv_sec + ru.ru_utime.tv_usec * 1e-6 +
                 (double)ru.ru_stime.tv_sec + ru.ru_stime.tv_usec * 1e-6;
    printf("hapsim-web: stopped after %.1f s: %lld browser connection(s), %lld frames and "
           "%.1f MB sent, %lld tool states; CPU %.2f s (%.1f %% of one core)\n",
           (double)(hs_client_now_us() - t_start) * 1e-6, (long long)a->ws_sessions,
           (long long)a->ws_frames, (double)a->ws_bytes * 1e-6, (long long)a->tool_states, cpu,
           100.0 * cpu / fmax((double)(hs_client_now_us() - t_start) * 1e-6, 1e-3));
}

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "hapsim-web")) return 0;
    web_opts w = {.port = 8080, .bind_addr = "127.0.0.1"};
    hs_client_config cfg;
    hs_client_config_default(&cfg);
    cfg.sender = "hapsim-web";
    cfg.all_sessions = 1; // shows every driver's force
    int rc = parse_args(argc, argv, &w, &cfg);
    if (rc >= 0) return rc;
    web_app* a = &g_app;
    char web_root[PATH_MAX];
    if (find_web_root(web_root, sizeof web_root, w.web_root_opt) != 0) {
        fprintf(stderr,
                "hapsim-web: no index.html in '%s' (build tree: build/share/hapsim/web; "
                "give --web-root DIR)\n",
                w.web_root_opt ? w.web_root_opt : "<exe>/../share/hapsim/web");
        return 2;
    }
    char why[256];
    int bound = check_bind(w.bind_addr, w.port, why, sizeof why);
    if (bound != 0) {
        fprintf(stderr, "hapsim-web: cannot listen on %s port %d: %s\n", w.bind_addr, w.port, why);
        return bound == -2 ? 2 : 1;
    }
    snprintf(a->prefix, sizeof a->prefix, "%s", cfg.prefix ? cfg.prefix : HAPSIM_DEFAULT_PREFIX);
    pthread_mutex_init(&a->hub.mu, NULL);
    a->hub.pre = LWS_PRE;
    a->last_topo = -1;
    if ((rc = open_buses(a, &cfg)) != 0) return rc;
    if ((rc = create_context(a, web_root, &w)) != 0) return rc;
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGPIPE, SIG_IGN);
    int64_t t_start = hs_client_now_us();
    a->t_end = w.duration > 0 ? hs_client_now_us() + (int64_t)(w.duration * 1e6) : 0;
    pthread_t lt, pt;
    if (pthread_create(&lt, NULL, lcm_thread, a) != 0 ||
        pthread_create(&pt, NULL, pose_thread, a) != 0) {
        fprintf(stderr, "hapsim-web: cannot start threads\n");
        return 1;
    }
    if (!w.quiet) {
        printf("hapsim-web: open http://%s:%d/  (web root %s)\n",
               strcmp(w.bind_addr, "0.0.0.0") ? w.bind_addr : "<this host>", w.port, web_root);
        fflush(stdout);
    }
    while (!a->stop)
        if (lws_service(a->ctx, 0) < 0) break;
    a->stop = 1;
    pthread_join(pt, NULL);
    pthread_join(lt, NULL);
    lws_context_destroy(a->ctx);
    a->ctx = NULL;
    lcm_destroy(a->ts_lcm);
    hs_client_destroy(&a->client);
    for (int k = 0; k < HS_WEB_KINDS; ++k) hs_web_blob_unref(&a->hub, a->hub.latest[k]);
    for (int i = 0; i < HS_WEB_EVENTS; ++i) hs_web_blob_unref(&a->hub, a->hub.events[i]);
    close(a->wake[0]);
    close(a->wake[1]);
    if (!w.quiet) print_summary(a, t_start);
    return 0;
}
