// SPDX-License-Identifier: MIT
// tool_force -> hs_stylus_model, with the driver-side checks (wire.h).
#include "wire.h"

#include <string.h>

void hs_stylus_rx_init(hs_stylus_rx_state* st, int device_id) {
    memset(st, 0, sizeof *st);
    st->device_id = device_id;
}

static hs_stylus_rx count(hs_stylus_rx_state* st, hs_stylus_rx r) {
    st->count[r]++;
    return r;
}

hs_stylus_rx hs_stylus_rx_force(hs_stylus_rx_state* st, const hs_wire_force* msg, int64_t now_ns,
                                int64_t wall_us, hs_stylus_model* out) {
    if (msg->device_id != st->device_id) return count(st, HS_RX_OTHER_DEVICE);
    if (st->session != 0 && msg->session != st->session) return count(st, HS_RX_OTHER_SESSION);
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
    if (hs_wire_force_check(msg)) return count(st, HS_RX_INVALID);
    // A restarted server's seq starts again from 1: told by its clock (it counted as a reorder
    // until the new seq passed the old one, up to ~100 s at 1 kHz). The differences are taken
    // unsigned where they are >= 0: exact, and no signed overflow for any network value.
    if (st->have_seq && msg->seq <= st->last_seq &&
        (uint64_t)st->last_seq - (uint64_t)msg->seq < HS_RX_RESTART_GAP &&
        hs_wire_reordered(msg->utime, st->last_utime))
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
    hs_wire_force msg;
    if (hs_wire_force_read(buf, len, &msg)) return count(st, HS_RX_UNDECODABLE);
    return hs_stylus_rx_force(st, &msg, now_ns, wall_us, out);
}

// A rate (Hz) or a time (us) the status line shows: finite is not enough (FLT_MAX us made
// llround of its ms unspecified).
static int shown_ok(double v) {
    return v >= 0 && v <= 1e9;
}

int hs_stylus_status_decode(const void* buf, size_t len, hs_stylus_srv_status* out) {
    memset(out, 0, sizeof *out);
    static _Thread_local hs_wire_status st; // 20 kB: off the receiving thread's stack
    if (hs_wire_status_decode(buf, len, &st)) return -1;
    int ok = 1;
    int n = st.n_loops < HS_WIRE_STATUS_LOOPS ? st.n_loops : HS_WIRE_STATUS_LOOPS;
    for (int i = 0; i < n; ++i) {
        ok = ok && shown_ok(st.loops[i].rate_hz) && shown_ok(st.loops[i].p99_us);
        if (strcmp(st.loops[i].name, "rt") == 0) { // the last one named rt
            out->has_rt = 1;
            out->rt_rate_hz = st.loops[i].rate_hz;
            out->rt_p99_us = st.loops[i].p99_us;
        }
    }
    n = st.n_steps < HS_WIRE_STATUS_STEPS ? st.n_steps : HS_WIRE_STATUS_STEPS;
    for (int i = 0; i < n; ++i) {
        ok = ok && shown_ok(st.steps[i].p99_us);
        if (st.steps[i].p99_us > out->step_p99_us) out->step_p99_us = st.steps[i].p99_us;
    }
    if (!ok) {
        memset(out, 0, sizeof *out);
        return -1;
    }
    return 0;
}
