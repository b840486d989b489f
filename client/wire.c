// SPDX-License-Identifier: MIT
// The client's part of the wire (the decoders are the protocol library's, hapsim_proto.h):
// tool_force into the local model, the status decoder's public face, the allocator's count.
#include "wire.h"

#include <string.h>

#include "hapsim_server_status_t.h"

_Static_assert(HS_CLIENT_MAX_VIS == HS_WIRE_MAX_VIS, "the client's limit is the decoder's");

int64_t hs_client_byte_count(void) {
    return hs_proto_byte_count();
}

// The local model of a decoded tool_force (arrival_us left 0).
hs_local_model hs_wire_local_model(const hs_wire_force* w) {
    hs_local_model m;
    memset(&m, 0, sizeof m);
    m.valid = 1;
    m.state = w->state;
    m.seq = w->seq;
    m.session = w->session;
    m.model_version = w->model_version;
    m.pose_seq = w->pose_seq;
    m.pose_utime = w->pose_utime;
    m.timeout_us = w->timeout_us;
    memcpy(m.force, w->force, sizeof m.force);
    memcpy(m.anchor, w->anchor, sizeof m.anchor);
    memcpy(m.stiffness, w->stiffness, sizeof m.stiffness);
    m.validity_radius = w->validity_radius;
    return m;
}

// ---------------------------------------------------------------------------------------------
hs_status hs_client_status_decode(const void* buf, size_t len, hs_client_status* o) {
    if (!o) return HS_ERR_INVALID;
    return hs_wire_status_decode(buf, len, o) ? HS_ERR_PARSE : HS_OK;
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
