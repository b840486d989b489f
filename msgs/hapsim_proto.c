// SPDX-License-Identifier: MIT
// hapsim_proto: the bounded decoders and the shared counted allocator (hapsim_proto.h).
#include "hapsim_proto.h"

#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

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

// ---------------------------------------------------------------------------------------------
// Counted allocation: a 16-byte header keeps the size so free can subtract it.

static atomic_llong g_bytes;
static atomic_llong g_fail_countdown;

void hs_proto_alloc_fail_after(int64_t n) {
    atomic_store(&g_fail_countdown, n > 0 ? n : 0);
}

void* hs_proto_alloc(size_t n) {
    if (atomic_load(&g_fail_countdown) > 0 && atomic_fetch_sub(&g_fail_countdown, 1) == 1)
        return NULL;
    if (n > SIZE_MAX - 16) return NULL;
    unsigned char* p = malloc(n + 16);
    if (!p) return NULL;
    memcpy(p, &n, sizeof n);
    atomic_fetch_add(&g_bytes, (long long)n);
    return p + 16;
}

void* hs_proto_calloc(size_t count, size_t size) {
    if (size && count > SIZE_MAX / size) return NULL;
    void* p = hs_proto_alloc(count * size);
    if (p) memset(p, 0, count * size);
    return p;
}

void hs_proto_free(void* p) {
    if (!p) return;
    unsigned char* b = (unsigned char*)p - 16;
    size_t n;
    memcpy(&n, b, sizeof n);
    atomic_fetch_sub(&g_bytes, (long long)n);
    free(b);
}

int64_t hs_proto_byte_count(void) {
    return atomic_load(&g_bytes);
}

// ---------------------------------------------------------------------------------------------
// Reader helpers.

void hs_rd_str_copy(hs_rd* r, char* out, size_t cap) {
    const char* q = hs_rd_str(r);
    if (!cap) return;
    if (!q) {
        out[0] = 0;
        return;
    }
    size_t len = strlen(q), k = len < cap - 1 ? len : cap - 1;
    memcpy(out, q, k);
    out[k] = 0;
}
// An array of n 4-byte elements; n must be in [0, max].
static hs_wire_arr rd_arr4(hs_rd* r, int32_t n, int32_t max) {
    hs_wire_arr a = {NULL, 0};
    if (n < 0 || n > max) {
        r->bad = 1;
        return a;
    }
    a.p = hs_rd_take(r, (size_t)n * 4);
    a.n = a.p ? n : 0;
    return a;
}
static int arr_finite(hs_wire_arr a) {
    for (int32_t i = 0; i < a.n; i++)
        if (!isfinite(hs_wire_f32_at(a, i))) return 0;
    return 1;
}

// Check the fingerprint and read the utime and seq every type starts with; 1 when readable.
static int rd_head(hs_rd* r, const void* buf, size_t len, int64_t hash, int64_t* utime,
                   int64_t* seq) {
    if (!hs_rd_begin(r, buf, len, hash)) return 0;
    *utime = hs_rd_i64(r);
    *seq = hs_rd_i64(r);
    return !r->bad;
}

int32_t hs_wire_i32_at(hs_wire_arr a, int32_t i) {
    return (int32_t)hs_be32(a.p + (size_t)i * 4);
}
float hs_wire_f32_at(hs_wire_arr a, int32_t i) {
    uint32_t u = hs_be32(a.p + (size_t)i * 4);
    float f;
    memcpy(&f, &u, 4);
    return f;
}

#define MAXV HS_WIRE_MAX_VIS
#define MAX3 (3 * HS_WIRE_MAX_VIS)

// ---------------------------------------------------------------------------------------------
// Mesh messages.

int hs_wire_topology_decode(const void* buf, size_t len, hs_wire_topology* o) {
    hs_rd r;
    if (!rd_head(&r, buf, len, __hapsim_mesh_topology_t_get_hash(), &o->utime, &o->seq)) return -1;
    o->topology_version = hs_rd_i64(&r);
    o->n_nodes = hs_rd_i32(&r);
    o->n_vis = hs_rd_i32(&r);
    if (o->n_nodes < 0 || o->n_vis < 0 || o->n_vis > MAXV) return -1;
    o->vis_nodes = rd_arr4(&r, o->n_vis, MAXV);
    int32_t n_rest = hs_rd_i32(&r);
    if (n_rest != 3 * o->n_vis) return -1;
    o->rest = rd_arr4(&r, n_rest, MAX3);
    int32_t n_tri = hs_rd_i32(&r);
    if (n_tri < 0 || n_tri % 3) return -1;
    o->tri = rd_arr4(&r, n_tri, INT32_MAX / 4);
    int32_t n_tet = hs_rd_i32(&r);
    if (n_tet < 0 || n_tet % 4) return -1;
    o->tet = rd_arr4(&r, n_tet, INT32_MAX / 4);
    if (!hs_rd_done(&r)) return -1;
    o->n_tri = n_tri / 3;
    o->n_tet = n_tet / 4;
    if (o->topology_version < 0 || o->seq < 0 || !arr_finite(o->rest)) return -1;
    for (int32_t i = 0; i < o->n_vis; i++) {
        int32_t v = hs_wire_i32_at(o->vis_nodes, i);
        if (v < 0 || v >= o->n_nodes) return -1;
    }
    for (int32_t i = 0; i < o->tri.n; i++) {
        int32_t v = hs_wire_i32_at(o->tri, i);
        if (v < 0 || v >= o->n_vis) return -1;
    }
    for (int32_t i = 0; i < o->tet.n; i++) {
        int32_t v = hs_wire_i32_at(o->tet, i);
        if (v < 0 || v >= o->n_vis) return -1;
    }
    return 0;
}

int hs_wire_state_decode(const void* buf, size_t len, hs_wire_state* o) {
    hs_rd r;
    if (!rd_head(&r, buf, len, __hapsim_mesh_state_t_get_hash(), &o->utime, &o->seq)) return -1;
    o->topology_version = hs_rd_i64(&r);
    o->keyframe_id = hs_rd_i64(&r);
    o->sim_step = hs_rd_i64(&r);
    o->sim_time = hs_rd_f64(&r);
    int32_t n_pos = hs_rd_i32(&r);
    if (n_pos < 0 || n_pos % 3) return -1;
    o->pos = rd_arr4(&r, n_pos, MAX3);
    int32_t n_stress = hs_rd_i32(&r);
    if (n_stress != 0 && n_stress != n_pos / 3) return -1;
    o->stress = rd_arr4(&r, n_stress, MAXV);
    if (!hs_rd_done(&r) || o->seq < 0 || o->topology_version < 0) return -1;
    return arr_finite(o->pos) && arr_finite(o->stress) ? 0 : -1;
}

int hs_wire_delta_decode(const void* buf, size_t len, hs_wire_delta* o) {
    hs_rd r;
    if (!rd_head(&r, buf, len, __hapsim_mesh_delta_t_get_hash(), &o->utime, &o->seq)) return -1;
    o->topology_version = hs_rd_i64(&r);
    o->keyframe_id = hs_rd_i64(&r);
    o->sim_step = hs_rd_i64(&r);
    o->sim_time = hs_rd_f64(&r);
    int32_t n_changed = hs_rd_i32(&r);
    o->index = rd_arr4(&r, n_changed, MAXV);
    int32_t n_delta = hs_rd_i32(&r);
    if (r.bad || n_delta != 3 * n_changed) return -1;
    o->delta = rd_arr4(&r, n_delta, MAX3);
    if (!hs_rd_done(&r) || o->seq < 0 || o->topology_version < 0) return -1;
    int32_t prev = -1;
    for (int32_t i = 0; i < o->index.n; i++) {
        int32_t v = hs_wire_i32_at(o->index, i);
        if (v <= prev) return -1;
        prev = v;
    }
    return arr_finite(o->delta) ? 0 : -1;
}

int hs_wire_event_decode(const void* buf, size_t len, hs_wire_event* o) {
    hs_rd r;
    if (!rd_head(&r, buf, len, __hapsim_topology_event_t_get_hash(), &o->utime, &o->seq)) return -1;
    o->old_version = hs_rd_i64(&r);
    o->new_version = hs_rd_i64(&r);
    o->device_id = hs_rd_i32(&r);
    o->n_removed = hs_rd_i32(&r);
    hs_wire_arr rem = rd_arr4(&r, o->n_removed, INT32_MAX / 4);
    o->n_moved = hs_rd_i32(&r);
    hs_wire_arr mv = rd_arr4(&r, o->n_moved, MAXV);
    int32_t n_rest = hs_rd_i32(&r);
    if (r.bad || n_rest != 3 * o->n_moved) return -1;
    hs_wire_arr mr = rd_arr4(&r, n_rest, MAX3);
    for (int i = 0; i < 12; i++) hs_rd_f32(&r);
    if (!hs_rd_done(&r) || o->seq < 0 || o->new_version < 0 || o->old_version < 0) return -1;
    for (int32_t i = 0; i < rem.n; i++)
        if (hs_wire_i32_at(rem, i) < 0) return -1;
    for (int32_t i = 0; i < mv.n; i++)
        if (hs_wire_i32_at(mv, i) < 0) return -1;
    return arr_finite(mr) ? 0 : -1;
}

// ---------------------------------------------------------------------------------------------
// Small messages.

int hs_wire_ack_decode(const void* buf, size_t len, hs_wire_ack* o) {
    hs_rd r;
    if (!rd_head(&r, buf, len, __hapsim_command_ack_t_get_hash(), &o->utime, &o->seq)) return -1;
    o->request_id = hs_rd_i64(&r);
    o->kind = hs_rd_i32(&r);
    o->status = hs_rd_i32(&r);
    hs_rd_str_copy(&r, o->message, sizeof o->message);
    if (!hs_rd_done(&r)) return -1;
    return o->status >= HAPSIM_COMMAND_ACK_T_STATUS_FAILED &&
                   o->status <= HAPSIM_COMMAND_ACK_T_STATUS_PENDING
               ? 0
               : -1;
}

int hs_wire_force_read(const void* buf, size_t len, hs_wire_force* m) {
    hs_rd r;
    memset(m, 0, sizeof *m);
    if (!rd_head(&r, buf, len, __hapsim_tool_force_t_get_hash(), &m->utime, &m->seq)) return -1;
    m->device_id = hs_rd_i32(&r);
    m->session = hs_rd_i64(&r);
    m->pose_seq = hs_rd_i64(&r);
    m->pose_utime = hs_rd_i64(&r);
    m->model_version = hs_rd_i64(&r);
    m->state = hs_rd_i32(&r);
    for (int i = 0; i < 3; i++) m->force[i] = hs_rd_f64_raw(&r);
    for (int i = 0; i < 3; i++) m->anchor[i] = hs_rd_f64_raw(&r);
    for (int i = 0; i < 9; i++) m->stiffness[i] = hs_rd_f64_raw(&r);
    m->validity_radius = hs_rd_f64_raw(&r);
    m->timeout_us = hs_rd_i64(&r);
    return hs_rd_done(&r) ? 0 : -1;
}

int hs_wire_force_check(const hs_wire_force* m) {
    if (m->state < HAPSIM_TOOL_FORCE_T_STATE_FREE || m->state > HAPSIM_TOOL_FORCE_T_STATE_STOPPED)
        return -1;
    if (m->timeout_us < 0 || m->seq < 0 || m->timeout_us > HS_WIRE_TIMEOUT_MAX_US) return -1;
    // Physical ranges (docs/protocol.md): within them F(p) stays finite wherever the device is.
    // Written so that a NaN fails each.
    if (!(m->validity_radius >= 0 && m->validity_radius <= HS_WIRE_RADIUS_MAX_M)) return -1;
    for (int i = 0; i < 3; i++)
        if (!(fabs(m->force[i]) <= HS_WIRE_FORCE_MAX_N) ||
            !(fabs(m->anchor[i]) <= HS_WIRE_ANCHOR_MAX_M))
            return -1;
    for (int i = 0; i < 9; i++)
        if (!(fabs(m->stiffness[i]) <= HS_WIRE_STIFFNESS_MAX_N_M)) return -1;
    return 0;
}

int hs_wire_force_decode(const void* buf, size_t len, hs_wire_force* m) {
    return hs_wire_force_read(buf, len, m) || hs_wire_force_check(m) ? -1 : 0;
}

static void rd_f64s(hs_rd* r, double* out, int n) {
    for (int i = 0; i < n; ++i) out[i] = hs_rd_f64(r);
}

int hs_wire_tool_state_decode(const void* buf, size_t len, hs_wire_tool_state* t) {
    hs_rd r;
    memset(t, 0, sizeof *t);
    if (!rd_head(&r, buf, len, __hapsim_tool_state_t_get_hash(), &t->utime, &t->seq)) return -1;
    t->device_id = hs_rd_i32(&r);
    t->tool_id = hs_rd_i32(&r);
    t->kind = hs_rd_i32(&r);
    rd_f64s(&r, t->position, 3);
    rd_f64s(&r, t->orientation, 4);
    t->radius = hs_rd_f64(&r);
    rd_f64s(&r, t->blade_a, 3);
    rd_f64s(&r, t->blade_b, 3);
    rd_f64s(&r, t->force, 3);
    t->contact = hs_rd_i8(&r);
    t->cutting = hs_rd_i8(&r);
    return hs_rd_done(&r) && t->device_id >= 0 ? 0 : -1;
}

// ---------------------------------------------------------------------------------------------
// Inbound to the server: tool_pose, command.

int hs_wire_pose_decode(const void* buf, size_t len, hs_wire_pose* p) {
    hs_rd r;
    memset(p, 0, sizeof *p);
    if (!rd_head(&r, buf, len, __hapsim_tool_pose_t_get_hash(), &p->utime, &p->seq)) return -1;
    p->session = hs_rd_i64(&r);
    p->device_id = hs_rd_i32(&r);
    p->tool_id = hs_rd_i32(&r);
    for (int i = 0; i < 3; ++i) p->position[i] = hs_rd_f64_raw(&r);
    for (int i = 0; i < 4; ++i) p->orientation[i] = hs_rd_f64_raw(&r);
    p->buttons = hs_rd_i32(&r);
    return hs_rd_done(&r) ? 0 : -1;
}

// A string into out[cap]: HS_WIRE_MALFORMED for a broken encoding, HS_WIRE_TOO_LONG when it
// is well formed but does not fit (out then "").
static int rd_str_fit(hs_rd* r, char* out, size_t cap) {
    out[0] = 0;
    const char* q = hs_rd_str(r);
    if (!q) return HS_WIRE_MALFORMED;
    size_t n = strlen(q);
    if (n >= cap) return HS_WIRE_TOO_LONG;
    memcpy(out, q, n + 1);
    return HS_WIRE_OK;
}

int hs_wire_command_decode(const void* buf, size_t len, hs_wire_command* c) {
    hs_rd r;
    memset(c, 0, sizeof *c);
    if (!rd_head(&r, buf, len, __hapsim_command_t_get_hash(), &c->utime, &c->seq))
        return HS_WIRE_MALFORMED;
    int64_t id = hs_rd_i64(&r);
    int32_t kind = hs_rd_i32(&r);
    int32_t n_args = hs_rd_i32(&r);
    if (r.bad) return HS_WIRE_MALFORMED;
    c->request_id = id;
    c->kind = kind;
    if (n_args < 0 || n_args > HAPSIM_CMD_MAX_ARGS) return HS_WIRE_TOO_LONG;
    c->n_args = n_args;
    int worst = HS_WIRE_OK;
    for (int k = 0; k < 2 * n_args + 1; ++k) {
        int i = k < n_args ? k : k - n_args;
        int s = k < n_args       ? rd_str_fit(&r, c->keys[i], sizeof c->keys[i])
                : k < 2 * n_args ? rd_str_fit(&r, c->values[i], sizeof c->values[i])
                                 : rd_str_fit(&r, c->sender, sizeof c->sender);
        if (s == HS_WIRE_MALFORMED) return s;
        if (s != HS_WIRE_OK) worst = s;
    }
    if (!hs_rd_done(&r)) return HS_WIRE_MALFORMED;
    return worst;
}

// ---------------------------------------------------------------------------------------------
// server_status

// A status array travels one field at a time (one column per field, n entries each); read a
// column of n, keeping the first k (the capacity of the decoded struct). Strings are truncated.
#define READ_COLUMN(read, arr, field)                                                              \
    for (int32_t i = 0; i < n; i++) {                                                              \
        if (i < k)                                                                                 \
            o->arr[i].field = read(&r);                                                            \
        else                                                                                       \
            (void)read(&r);                                                                        \
    }
#define READ_NAMES(arr, field)                                                                     \
    for (int32_t i = 0; i < n; i++) {                                                              \
        if (i < k)                                                                                 \
            hs_rd_str_copy(&r, o->arr[i].field, sizeof o->arr[i].field);                           \
        else                                                                                       \
            (void)hs_rd_str(&r);                                                                   \
    }

// An array count (0 .. 4096, else bad and 0) and in *k how many of them fit cap.
static int32_t rd_count(hs_rd* r, int32_t cap, int32_t* k) {
    int32_t n = hs_rd_i32(r);
    if (n < 0 || n > 4096) r->bad = 1;
    if (r->bad) n = 0;
    *k = n < cap ? n : cap;
    return n;
}

static int status_decode(const void* buf, size_t len, hs_wire_status* o) {
    hs_rd r;
    memset(o, 0, sizeof *o);
    if (!rd_head(&r, buf, len, __hapsim_server_status_t_get_hash(), &o->utime, &o->seq)) return -1;
    o->uptime_us = hs_rd_i64(&r);
    o->state = hs_rd_i32(&r);
    hs_rd_str_copy(&r, o->scene, sizeof o->scene);
    o->topology_version = hs_rd_i64(&r);
    int32_t n, k;
    // Loops: name[], then 4 float arrays and one int64 array, each n_loops long.
    n = o->n_loops = rd_count(&r, HS_WIRE_STATUS_LOOPS, &k);
    READ_NAMES(loops, name);
    READ_COLUMN(hs_rd_f32, loops, rate_hz);
    READ_COLUMN(hs_rd_f32, loops, p50_us);
    READ_COLUMN(hs_rd_f32, loops, p99_us);
    READ_COLUMN(hs_rd_f32, loops, max_us);
    READ_COLUMN(hs_rd_i64, loops, overruns);
    n = o->n_steps = rd_count(&r, HS_WIRE_STATUS_STEPS, &k);
    READ_NAMES(steps, name);
    READ_COLUMN(hs_rd_f32, steps, p50_us);
    READ_COLUMN(hs_rd_f32, steps, p99_us);
    READ_COLUMN(hs_rd_f32, steps, max_us);
    n = o->n_devices = rd_count(&r, HS_WIRE_STATUS_DEVICES, &k);
    READ_COLUMN(hs_rd_i32, devices, id);
    READ_COLUMN(hs_rd_i8, devices, live);
    READ_COLUMN(hs_rd_f32, devices, pose_age_ms);
    READ_COLUMN(hs_rd_i64, devices, poses_received);
    READ_COLUMN(hs_rd_i64, devices, poses_lost);
    READ_COLUMN(hs_rd_f32, devices, latency_p50_us);
    READ_COLUMN(hs_rd_f32, devices, latency_p99_us);
    READ_COLUMN(hs_rd_f32, devices, force_norm);
    n = o->n_rejects = rd_count(&r, HS_WIRE_STATUS_REJECTS, &k);
    READ_NAMES(rejects, channel);
    READ_NAMES(rejects, reason);
    READ_COLUMN(hs_rd_i64, rejects, count);
    hs_rd_str_copy(&r, o->warnings, sizeof o->warnings);
    return hs_rd_done(&r) ? 0 : -1;
}

int hs_wire_status_decode(const void* buf, size_t len, hs_wire_status* o) {
    int s = status_decode(buf, len, o);
    if (s) memset(o, 0, sizeof *o);
    return s;
}
