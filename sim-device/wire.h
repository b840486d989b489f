// SPDX-License-Identifier: MIT
// hapsim-stylus wire edge: tool_force messages (msgs/tool_force_t.lcm), read and checked by the
// protocol library (hapsim_proto.h), into device models, with the checks a driver owes the
// network: another device's message, or an answer to another session's pose (a driver that ran
// before this one), is skipped; an invalid message (hs_wire_force_check) or an older seq is
// dropped.
#ifndef HS_STYLUS_WIRE_H
#define HS_STYLUS_WIRE_H

#include <stddef.h>
#include <stdint.h>

#include "hapsim_proto.h"
#include "stylus.h"

#ifdef __cplusplus
extern "C" {
#endif

/// What became of one received tool_force.
typedef enum hs_stylus_rx {
    HS_RX_OK = 0,            ///< accepted: *out holds the model
    HS_RX_OTHER_DEVICE = 1,  ///< for another device id: ignored
    HS_RX_INVALID = 2,       ///< refused by hs_wire_force_check (non-finite, negative, unknown
                             ///< state, beyond the wire ranges HS_WIRE_*_MAX)
    HS_RX_REORDERED = 3,     ///< seq not newer than the last accepted one
    HS_RX_OTHER_SESSION = 4, ///< answers another session's pose (session != ours)
    HS_RX_UNDECODABLE = 5,   ///< not a tool_force: wrong hash, short, or bytes left over
} hs_stylus_rx;

/// Receive-side state of one device. Initialise with hs_stylus_rx_init.
typedef struct hs_stylus_rx_state {
    int device_id;      ///< our device id
    int have_seq;       ///< 1 once a message was accepted
    int64_t last_seq;   ///< seq of the last accepted message
    int64_t last_utime; ///< its server utime, us
    /// This driver's pose session (0: not checked). The server goes on answering a replaced
    /// session's last poses for a while (its rt outputs ramp to zero); those are not this
    /// driver's model.
    int64_t session;
    int64_t count[6]; ///< messages per hs_stylus_rx outcome
} hs_stylus_rx_state;

/// A seq not newer than the last one is a reorder or a repeat when its server utime is at most
/// HS_RX_REORDER_US older; a later utime, or one far older (a reboot, another host), means a
/// restarted server (seq from 1 again): accepted. So is a seq HS_RX_RESTART_GAP behind.
#define HS_RX_RESTART_GAP 100000
#define HS_RX_REORDER_US  HS_WIRE_REORDER_US

/// What the status line shows of a SERVER_STATUS (msgs/server_status_t.lcm).
typedef struct hs_stylus_srv_status {
    int has_rt;         ///< 1 when a loop named "rt" was reported
    double rt_rate_hz;  ///< its measured rate
    double rt_p99_us;   ///< its period p99
    double step_p99_us; ///< the slowest step's p99 (0 without steps)
} hs_stylus_srv_status;

/// Decode SERVER_STATUS bytes with the protocol library's bounded decoder
/// (hs_wire_status_decode), then keep what the line shows: a shown rate or time outside
/// [0, 1e9] makes the message malformed. -1 (*out zeroed) when refused, else 0.
/// Thread: any | Allocates: no
int hs_stylus_status_decode(const void* buf, size_t len, hs_stylus_srv_status* out /* OUT */);

/// Start with no message seen, for device_id.
void hs_stylus_rx_init(hs_stylus_rx_state* st, int device_id);
/// Check msg (hs_wire_force_check, as the client library checks) and convert it into *out
/// (arrival_ns = now_ns, latency = wall_us - pose_utime when pose_utime > 0, else -1).
/// Thread: the receiving thread | Allocates: no
hs_stylus_rx hs_stylus_rx_force(hs_stylus_rx_state* st, const hs_wire_force* msg, int64_t now_ns,
                                int64_t wall_us, hs_stylus_model* out /* OUT */);

/// hs_stylus_rx_force on the raw bytes of a message (lcm_subscribe): bytes that do not decode
/// to exactly one tool_force are HS_RX_UNDECODABLE (counted, nothing printed).
/// Thread: the receiving thread | Allocates: no
hs_stylus_rx hs_stylus_rx_bytes(hs_stylus_rx_state* st, const void* buf, size_t len, int64_t now_ns,
                                int64_t wall_us, hs_stylus_model* out /* OUT */);

#ifdef __cplusplus
}
#endif
#endif
