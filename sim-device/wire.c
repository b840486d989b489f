// SPDX-License-Identifier: MIT
// tool_force -> hs_stylus_model, with the driver-side checks (wire.h).
#include "wire.h"

#include <limits.h>
#include <math.h>
#include <string.h>

#include "hapsim_server_status_t.h"
#include "hapsim_wire_read.h"

void hs_stylus_rx_init(hs_stylus_rx_state* st, int device_id) {
    memset(st, 0, sizeof *st);
    st->device_id = device_id;
}

static hs_stylus_rx count(hs_stylus_rx_state* st, hs_stylus_rx r) {
    st->count[r]++;
    return r;
}

// The ranges the client library keeps too (hapsim_wire_read.h): a finite but huge model
// (1e200 N, or stiffness and radius 1e300) overflowed to a force the device then zeroed, while
// the message counted as accepted.
static int in_wire_ranges(const hapsim_tool_force_t* msg) {
    if (!(msg->validity_radius <= HS_WIRE_RADIUS_MAX_M) ||
        !(msg->timeout_us <= HS_WIRE_TIMEOUT_MAX_US))
        return 0;
    for (int i = 0; i < 3; ++i)
        if (!(fabs(msg->force[i]) <= HS_WIRE_FORCE_MAX_N) ||
            !(fabs(msg->anchor[i]) <= HS_WIRE_ANCHOR_MAX_M))
            return 0;
    for (int i = 0; i < 9; ++i)
        if (!(fabs(msg->stiffness[i]) <= HS_WIRE_STIFFNESS_MAX_N_M)) return 0;
    return 1;
}

hs_stylus_rx hs_stylus_rx_force(hs_stylus_rx_state* st, const hapsim_tool_force_t* msg,
                                int64_t now_ns, int64_t wall_us, hs_stylus_model* out) {
    if (msg->device_id != st->device_id) return count(st, HS_RX_OTHER_DEVICE);
    if (st->since_utime > 0 && msg->pose_utime > 0 && msg->pose_utime < st->since_utime)
        return count(st, HS_RX_OTHER_SESSION);
    hs_stylus_model m;
    memset(&m, 0, sizeof m);
    m.seq = msg->seq;
    m.version = msg->model_version;
    m.pose_seq = msg->pose_seq;
    m.state = msg->state;
    for (int i = 0; i < 3; ++i) {
        m.force_n[i] = msg->force[i];
        m.anchor_m[i] = msg->anchor[i];
    }
    for (int i = 0; i < 9; ++i) m.stiffness[i] = msg->stiffness[i];
    m.radius_m = msg->validity_radius;
    m.timeout_s = msg->timeout_us >= 0 ? (double)msg->timeout_us * 1e-6 : -1;
    if (!hs_stylus_model_valid(&m) || !in_wire_ranges(msg) ||
        msg->state < HAPSIM_TOOL_FORCE_T_STATE_FREE ||
        msg->state > HAPSIM_TOOL_FORCE_T_STATE_STOPPED || msg->seq < 0)
        return count(st, HS_RX_INVALID);
    // A restarted server's seq starts again from 1: told by its clock (it counted as a reorder
    // until the new seq passed the old one, up to ~100 s at 1 kHz). The differences are taken
    // unsigned where they are >= 0: exact, and no signed overflow for any network value.
    if (st->have_seq && msg->seq <= st->last_seq &&
        (uint64_t)st->last_seq - (uint64_t)msg->seq < HS_RX_RESTART_GAP &&
        msg->utime <= st->last_utime &&
        (uint64_t)st->last_utime - (uint64_t)msg->utime <= HS_RX_REORDER_US)
        return count(st, HS_RX_REORDERED);
    st->have_seq = 1;
    st->last_seq = msg->seq;
    st->last_utime = msg->utime;
    m.arrival_ns = now_ns;
    m.latency_us = msg->pose_utime > 0 ? wall_us - msg->pose_utime : -1;
    *out = m;
    return count(st, HS_RX_OK);
}

hs_stylus_rx hs_stylus_rx_bytes(hs_stylus_rx_state* st, const void* buf, size_t len, int64_t now_ns,
                                int64_t wall_us, hs_stylus_model* out) {
    hapsim_tool_force_t msg;
    // No strings or variable arrays in tool_force: decode allocates nothing.
    if (!buf || len > INT_MAX || hapsim_tool_force_t_decode(buf, 0, (int)len, &msg) != (int)len)
        return count(st, HS_RX_UNDECODABLE);
    return hs_stylus_rx_force(st, &msg, now_ns, wall_us, out);
}

// ---------------------------------------------------------------------------------------------
// SERVER_STATUS, read with hs_rd (hapsim_wire_read.h; LCM: big-endian, strings as int32
// length including the NUL, then the bytes).

static uint64_t rd_u(hs_rd* r, size_t k) {
    const uint8_t* q = hs_rd_take(r, k);
    uint64_t v = 0;
    for (size_t i = 0; q && i < k; ++i) v = v << 8 | q[i];
    return v;
}

static int32_t rd_count(hs_rd* r) {
    int32_t n = hs_rd_i32(r);
    if (n < 0 || n > 4096) r->bad = 1;
    return r->bad ? 0 : n;
}

static void rd_skip_f32(hs_rd* r, int32_t n) {
    for (int32_t i = 0; i < n && !r->bad; ++i) (void)hs_rd_f32(r);
}

// A rate (Hz) or a time (us) the status line shows: finite is not enough (FLT_MAX us made
// llround of its ms unspecified), so outside [0, 1e9] the message is malformed.
static float rd_stat(hs_rd* r) {
    float f = hs_rd_f32(r);
    if (!(f >= 0 && f <= 1e9f)) r->bad = 1;
    return f;
}

int hs_stylus_status_decode(const void* buf, size_t len, hs_stylus_srv_status* out) {
    memset(out, 0, sizeof *out);
    hs_rd r = {buf, buf ? len : 0, 0, 0};
    if ((int64_t)rd_u(&r, 8) != __hapsim_server_status_t_get_hash()) return -1;
    (void)rd_u(&r, 8 * 3 + 4); // utime, seq, uptime_us, state
    (void)hs_rd_str(&r);       // scene
    (void)rd_u(&r, 8);         // topology_version
    // Loops: names, then rate, p50, p99, max (float) and overruns (int64), n_loops each.
    int32_t n = rd_count(&r);
    int rt = -1;
    for (int32_t i = 0; i < n; ++i) {
        const char* s = hs_rd_str(&r);
        if (s && strcmp(s, "rt") == 0) rt = i; // the last one named rt, as before
    }
    for (int32_t i = 0; i < n; ++i) {
        float f = rd_stat(&r);
        if (i == rt) out->rt_rate_hz = f;
    }
    rd_skip_f32(&r, n); // p50
    for (int32_t i = 0; i < n; ++i) {
        float f = rd_stat(&r);
        if (i == rt) out->rt_p99_us = f;
    }
    rd_skip_f32(&r, n); // max
    (void)hs_rd_take(&r, (size_t)n * 8);
    out->has_rt = rt >= 0;
    // Steps: names, p50, p99, max.
    n = rd_count(&r);
    for (int32_t i = 0; i < n; ++i) (void)hs_rd_str(&r);
    rd_skip_f32(&r, n);
    for (int32_t i = 0; i < n; ++i) {
        float f = rd_stat(&r);
        if (f > out->step_p99_us) out->step_p99_us = f;
    }
    rd_skip_f32(&r, n);
    // Devices: id (int32), live (int8), age (f), received, lost (int64), p50, p99, force (f).
    n = rd_count(&r);
    (void)hs_rd_take(&r, (size_t)n * 5);
    rd_skip_f32(&r, n);
    (void)hs_rd_take(&r, (size_t)n * 16);
    rd_skip_f32(&r, 3 * n);
    // Rejects: channel, reason (strings), count (int64); then the warnings.
    n = rd_count(&r);
    for (int32_t i = 0; i < 2 * n; ++i) (void)hs_rd_str(&r);
    (void)hs_rd_take(&r, (size_t)n * 8);
    (void)hs_rd_str(&r);
    if (r.bad || r.off != r.n) {
        memset(out, 0, sizeof *out);
        return -1;
    }
    return 0;
}
