// SPDX-License-Identifier: MIT
// Bounds-checked decoding of the messages a client receives (see wire.h).
#include "wire.h"

#include <math.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>

#include "hapsim_wire_read.h"

#include "hapsim_command_ack_t.h"
#include "hapsim_mesh_delta_t.h"
#include "hapsim_mesh_state_t.h"
#include "hapsim_mesh_topology_t.h"
#include "hapsim_server_status_t.h"
#include "hapsim_tool_force_t.h"
#include "hapsim_topology_event_t.h"

// ---------------------------------------------------------------------------------------------
// Counted allocation: a 16-byte header keeps the size so free can subtract it.

static atomic_llong g_bytes;
static atomic_llong g_fail_countdown;

void hs_client_alloc_fail_after(int64_t n) {
    atomic_store(&g_fail_countdown, n > 0 ? n : 0);
}

void* hs_client_alloc(size_t n) {
    if (atomic_load(&g_fail_countdown) > 0 && atomic_fetch_sub(&g_fail_countdown, 1) == 1)
        return NULL;
    if (n > SIZE_MAX - 16) return NULL;
    unsigned char* p = malloc(n + 16);
    if (!p) return NULL;
    memcpy(p, &n, sizeof n);
    atomic_fetch_add(&g_bytes, (long long)n);
    return p + 16;
}

void* hs_client_calloc(size_t count, size_t size) {
    if (size && count > SIZE_MAX / size) return NULL;
    void* p = hs_client_alloc(count * size);
    if (p) memset(p, 0, count * size);
    return p;
}

void hs_client_free(void* p) {
    if (!p) return;
    unsigned char* b = (unsigned char*)p - 16;
    size_t n;
    memcpy(&n, b, sizeof n);
    atomic_fetch_sub(&g_bytes, (long long)n);
    free(b);
}

int64_t hs_client_byte_count(void) {
    return atomic_load(&g_bytes);
}

// ---------------------------------------------------------------------------------------------
// Reader.

static int64_t rd_i64(hs_rd* r) {
    const uint8_t* q = hs_rd_take(r, 8);
    return q ? (int64_t)hs_be64(q) : 0;
}
static int8_t rd_i8(hs_rd* r) {
    const uint8_t* q = hs_rd_take(r, 1);
    return q ? (int8_t)q[0] : 0;
}
static double rd_f64(hs_rd* r) {
    const uint8_t* q = hs_rd_take(r, 8);
    if (!q) return 0;
    uint64_t u = hs_be64(q);
    double d;
    memcpy(&d, &u, 8);
    if (!isfinite(d)) r->bad = 1;
    return d;
}
// LCM string: int32 length including the NUL, then the bytes; copied (truncated) into out[cap].
static void rd_str(hs_rd* r, char* out, size_t cap) {
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
static int rd_begin(hs_rd* r, const void* buf, size_t len, int64_t hash) {
    r->p = buf;
    r->n = buf ? len : 0;
    r->off = 0;
    r->bad = 0;
    return rd_i64(r) == hash && !r->bad;
}
static int rd_end(const hs_rd* r) {
    return !r->bad && r->off == r->n ? 0 : -1;
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

#define MAXV HS_CLIENT_MAX_VIS
#define MAX3 (3 * HS_CLIENT_MAX_VIS)

// ---------------------------------------------------------------------------------------------
// Mesh messages.

int hs_wire_topology_decode(const void* buf, size_t len, hs_wire_topology* o) {
    hs_rd r;
    if (!rd_begin(&r, buf, len, __hapsim_mesh_topology_t_get_hash())) return -1;
    o->utime = rd_i64(&r);
    o->seq = rd_i64(&r);
    o->topology_version = rd_i64(&r);
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
    if (rd_end(&r)) return -1;
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
    if (!rd_begin(&r, buf, len, __hapsim_mesh_state_t_get_hash())) return -1;
    o->utime = rd_i64(&r);
    o->seq = rd_i64(&r);
    o->topology_version = rd_i64(&r);
    o->keyframe_id = rd_i64(&r);
    o->sim_step = rd_i64(&r);
    o->sim_time = rd_f64(&r);
    int32_t n_pos = hs_rd_i32(&r);
    if (n_pos < 0 || n_pos % 3) return -1;
    o->pos = rd_arr4(&r, n_pos, MAX3);
    int32_t n_stress = hs_rd_i32(&r);
    if (n_stress != 0 && n_stress != n_pos / 3) return -1;
    o->stress = rd_arr4(&r, n_stress, MAXV);
    if (rd_end(&r) || o->seq < 0 || o->topology_version < 0) return -1;
    return arr_finite(o->pos) && arr_finite(o->stress) ? 0 : -1;
}

int hs_wire_delta_decode(const void* buf, size_t len, hs_wire_delta* o) {
    hs_rd r;
    if (!rd_begin(&r, buf, len, __hapsim_mesh_delta_t_get_hash())) return -1;
    o->utime = rd_i64(&r);
    o->seq = rd_i64(&r);
    o->topology_version = rd_i64(&r);
    o->keyframe_id = rd_i64(&r);
    o->sim_step = rd_i64(&r);
    o->sim_time = rd_f64(&r);
    int32_t n_changed = hs_rd_i32(&r);
    o->index = rd_arr4(&r, n_changed, MAXV);
    int32_t n_delta = hs_rd_i32(&r);
    if (r.bad || n_delta != 3 * n_changed) return -1;
    o->delta = rd_arr4(&r, n_delta, MAX3);
    if (rd_end(&r) || o->seq < 0 || o->topology_version < 0) return -1;
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
    if (!rd_begin(&r, buf, len, __hapsim_topology_event_t_get_hash())) return -1;
    o->utime = rd_i64(&r);
    o->seq = rd_i64(&r);
    o->old_version = rd_i64(&r);
    o->new_version = rd_i64(&r);
    o->device_id = hs_rd_i32(&r);
    o->n_removed = hs_rd_i32(&r);
    hs_wire_arr rem = rd_arr4(&r, o->n_removed, INT32_MAX / 4);
    o->n_moved = hs_rd_i32(&r);
    hs_wire_arr mv = rd_arr4(&r, o->n_moved, MAXV);
    int32_t n_rest = hs_rd_i32(&r);
    if (r.bad || n_rest != 3 * o->n_moved) return -1;
    hs_wire_arr mr = rd_arr4(&r, n_rest, MAX3);
    for (int i = 0; i < 12; i++) hs_rd_f32(&r);
    if (rd_end(&r) || o->seq < 0 || o->new_version < 0 || o->old_version < 0) return -1;
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
    if (!rd_begin(&r, buf, len, __hapsim_command_ack_t_get_hash())) return -1;
    o->utime = rd_i64(&r);
    o->seq = rd_i64(&r);
    o->request_id = rd_i64(&r);
    o->kind = hs_rd_i32(&r);
    o->status = hs_rd_i32(&r);
    rd_str(&r, o->message, sizeof o->message);
    if (rd_end(&r)) return -1;
    return o->status >= HAPSIM_COMMAND_ACK_T_STATUS_FAILED &&
                   o->status <= HAPSIM_COMMAND_ACK_T_STATUS_PENDING
               ? 0
               : -1;
}

int hs_wire_force_decode(const void* buf, size_t len, int32_t* device_id, int64_t* utime,
                         hs_local_model* m) {
    hs_rd r;
    if (!rd_begin(&r, buf, len, __hapsim_tool_force_t_get_hash())) return -1;
    memset(m, 0, sizeof *m);
    int64_t t = rd_i64(&r); // server clock, not comparable with ours
    if (utime) *utime = t;
    m->seq = rd_i64(&r);
    *device_id = hs_rd_i32(&r);
    m->pose_seq = rd_i64(&r);
    m->pose_utime = rd_i64(&r);
    m->model_version = rd_i64(&r);
    m->state = hs_rd_i32(&r);
    for (int i = 0; i < 3; i++) m->force[i] = rd_f64(&r);
    for (int i = 0; i < 3; i++) m->anchor[i] = rd_f64(&r);
    for (int i = 0; i < 9; i++) m->stiffness[i] = rd_f64(&r);
    m->validity_radius = rd_f64(&r);
    m->timeout_us = rd_i64(&r);
    if (rd_end(&r)) return -1;
    if (m->state < HAPSIM_TOOL_FORCE_T_STATE_FREE || m->state > HAPSIM_TOOL_FORCE_T_STATE_STOPPED)
        return -1;
    if (m->validity_radius < 0 || m->timeout_us < 0 || m->seq < 0) return -1;
    // Physical ranges (docs/protocol.md): within them F(p) stays finite wherever the device is.
    if (m->validity_radius > HS_WIRE_RADIUS_MAX_M || m->timeout_us > HS_WIRE_TIMEOUT_MAX_US)
        return -1;
    for (int i = 0; i < 3; i++)
        if (fabs(m->force[i]) > HS_WIRE_FORCE_MAX_N || fabs(m->anchor[i]) > HS_WIRE_ANCHOR_MAX_M)
            return -1;
    for (int i = 0; i < 9; i++)
        if (fabs(m->stiffness[i]) > HS_WIRE_STIFFNESS_MAX_N_M) return -1;
    m->valid = 1;
    return 0;
}

// A status array travels one field at a time (one column per field, n entries each); read a
// column of n, keeping the first k (the capacity of the decoded struct).
#define READ_COLUMN(read, arr, field)                                                              \
    for (int32_t i = 0; i < n; i++) {                                                              \
        if (i < k)                                                                                 \
            o->arr[i].field = read(&r);                                                            \
        else                                                                                       \
            (void)read(&r);                                                                        \
    }

static hs_status status_decode(const void* buf, size_t len, hs_client_status* o) {
    hs_rd r;
    memset(o, 0, sizeof *o);
    if (!rd_begin(&r, buf, len, __hapsim_server_status_t_get_hash())) return HS_ERR_PARSE;
    o->utime = rd_i64(&r);
    o->seq = rd_i64(&r);
    o->uptime_us = rd_i64(&r);
    o->state = hs_rd_i32(&r);
    rd_str(&r, o->scene, sizeof o->scene);
    o->topology_version = rd_i64(&r);
    char skip[8];
    // Loops: name[], then 4 float arrays and one int64 array, each n_loops long.
    int32_t n = o->n_loops = hs_rd_i32(&r);
    if (n < 0 || n > 4096) return HS_ERR_PARSE;
    int32_t k = n < HS_CLIENT_STATUS_LOOPS ? n : HS_CLIENT_STATUS_LOOPS;
    for (int32_t i = 0; i < n; i++)
        if (i < k)
            rd_str(&r, o->loops[i].name, sizeof o->loops[i].name);
        else
            rd_str(&r, skip, sizeof skip);
    READ_COLUMN(hs_rd_f32, loops, rate_hz);
    READ_COLUMN(hs_rd_f32, loops, p50_us);
    READ_COLUMN(hs_rd_f32, loops, p99_us);
    READ_COLUMN(hs_rd_f32, loops, max_us);
    READ_COLUMN(rd_i64, loops, overruns);
    // Steps.
    n = o->n_steps = hs_rd_i32(&r);
    if (r.bad || n < 0 || n > 4096) return HS_ERR_PARSE;
    k = n < HS_CLIENT_STATUS_STEPS ? n : HS_CLIENT_STATUS_STEPS;
    for (int32_t i = 0; i < n; i++)
        if (i < k)
            rd_str(&r, o->steps[i].name, sizeof o->steps[i].name);
        else
            rd_str(&r, skip, sizeof skip);
    READ_COLUMN(hs_rd_f32, steps, p50_us);
    READ_COLUMN(hs_rd_f32, steps, p99_us);
    READ_COLUMN(hs_rd_f32, steps, max_us);
    // Devices.
    n = o->n_devices = hs_rd_i32(&r);
    if (r.bad || n < 0 || n > 4096) return HS_ERR_PARSE;
    k = n < HS_CLIENT_STATUS_DEVICES ? n : HS_CLIENT_STATUS_DEVICES;
    READ_COLUMN(hs_rd_i32, devices, id);
    READ_COLUMN(rd_i8, devices, live);
    READ_COLUMN(hs_rd_f32, devices, pose_age_ms);
    READ_COLUMN(rd_i64, devices, poses_received);
    READ_COLUMN(rd_i64, devices, poses_lost);
    READ_COLUMN(hs_rd_f32, devices, latency_p50_us);
    READ_COLUMN(hs_rd_f32, devices, latency_p99_us);
    READ_COLUMN(hs_rd_f32, devices, force_norm);
    // Rejects.
    n = o->n_rejects = hs_rd_i32(&r);
    if (r.bad || n < 0 || n > 4096) return HS_ERR_PARSE;
    k = n < HS_CLIENT_STATUS_REJECTS ? n : HS_CLIENT_STATUS_REJECTS;
    for (int32_t i = 0; i < n; i++)
        if (i < k)
            rd_str(&r, o->rejects[i].channel, sizeof o->rejects[i].channel);
        else
            rd_str(&r, skip, sizeof skip);
    for (int32_t i = 0; i < n; i++)
        if (i < k)
            rd_str(&r, o->rejects[i].reason, sizeof o->rejects[i].reason);
        else
            rd_str(&r, skip, sizeof skip);
    READ_COLUMN(rd_i64, rejects, count);
    rd_str(&r, o->warnings, sizeof o->warnings);
    return rd_end(&r) ? HS_ERR_PARSE : HS_OK;
}

hs_status hs_client_status_decode(const void* buf, size_t len, hs_client_status* o) {
    if (!o) return HS_ERR_INVALID;
    hs_status s = status_decode(buf, len, o);
    // Every error path leaves all zeros: a count read before the failure (n_loops 5000, -1)
    // must not reach a caller that indexes with it.
    if (s != HS_OK) memset(o, 0, sizeof *o);
    return s;
}

const char* hs_client_state_name(int32_t state) {
    switch (state) {
    case HAPSIM_SERVER_STATUS_T_STATE_RUNNING:
        return "running";
    case HAPSIM_SERVER_STATUS_T_STATE_PAUSED:
        return "paused";
    case HAPSIM_SERVER_STATUS_T_STATE_ESTOP:
        return "estop";
    case HAPSIM_SERVER_STATUS_T_STATE_LOADING:
        return "loading";
    default:
        return "unknown";
    }
}
