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
    if (!hs_stylus_model_valid(&m) || msg->state < HAPSIM_TOOL_FORCE_T_STATE_FREE ||
        msg->state > HAPSIM_TOOL_FORCE_T_STATE_STOPPED)
        return count(st, HS_RX_INVALID);
    // A restarted server's seq starts again from 1: told by its clock (it counted as a reorder
    // until the new seq passed the old one, up to ~100 s at 1 kHz).
    if (st->have_seq && msg->seq <= st->last_seq && st->last_seq - msg->seq < HS_RX_RESTART_GAP &&
        msg->utime <= st->last_utime && st->last_utime - msg->utime <= HS_RX_REORDER_US)
        return count(st, HS_RX_REORDERED);
    st->have_seq = 1;
    st->last_seq = msg->seq;
    st->last_utime = msg->utime;
    m.arrival_ns = now_ns;
    m.latency_us = msg->pose_utime > 0 ? wall_us - msg->pose_utime : -1;
    *out = m;
    return count(st, HS_RX_OK);
}
