// SPDX-License-Identifier: MIT
// hapsim-stylus wire edge: tool_force messages (msgs/tool_force_t.lcm) into device models, with
// the checks a driver owes the network: another device's message, or an answer to a pose sent
// before this driver started (another session's), is skipped; non-finite numbers, a negative
// radius, timeout or seq, an unknown state, or an older seq are dropped.
#ifndef HS_STYLUS_WIRE_H
#define HS_STYLUS_WIRE_H

#include <stddef.h>
#include <stdint.h>

#include "hapsim_tool_force_t.h"
#include "stylus.h"

#ifdef __cplusplus
extern "C" {
#endif

/// What became of one received tool_force.
typedef enum hs_stylus_rx {
    HS_RX_OK = 0,            ///< accepted: *out holds the model
    HS_RX_OTHER_DEVICE = 1,  ///< for another device id: ignored
    HS_RX_INVALID = 2,       ///< non-finite, negative radius, timeout or seq, unknown state, or
                             ///< beyond the wire ranges (HS_WIRE_*_MAX)
    HS_RX_REORDERED = 3,     ///< seq not newer than the last accepted one
    HS_RX_OTHER_SESSION = 4, ///< answers a pose older than since_utime (an earlier session's)
    HS_RX_UNDECODABLE = 5,   ///< not a tool_force: wrong hash, short, or bytes left over
} hs_stylus_rx;

/// Receive-side state of one device. Initialise with hs_stylus_rx_init.
typedef struct hs_stylus_rx_state {
    int device_id;      ///< our device id
    int have_seq;       ///< 1 once a message was accepted
    int64_t last_seq;   ///< seq of the last accepted message
    int64_t last_utime; ///< its server utime, us
    /// Wall-clock us this driver started at (0: not checked). The server goes on answering a
    /// replaced session's last poses for a while (its rt outputs ramp to zero); those are not
    /// this driver's model.
    int64_t since_utime;
    int64_t count[6]; ///< messages per hs_stylus_rx outcome
} hs_stylus_rx_state;

/// A seq not newer than the last one is a reorder or a repeat when its server utime is at most
/// HS_RX_REORDER_US older; a later utime, or one far older (a reboot, another host), means a
/// restarted server (seq from 1 again): accepted. So is a seq HS_RX_RESTART_GAP behind.
#define HS_RX_RESTART_GAP 100000
#define HS_RX_REORDER_US  1000000

/// What the status line shows of a SERVER_STATUS (msgs/server_status_t.lcm).
typedef struct hs_stylus_srv_status {
    int has_rt;         ///< 1 when a loop named "rt" was reported
    double rt_rate_hz;  ///< its measured rate
    double rt_p99_us;   ///< its period p99
    double step_p99_us; ///< the slowest step's p99 (0 without steps)
} hs_stylus_srv_status;

/// Decode SERVER_STATUS bytes with every length checked (lcm-gen's decoder does not check that
/// strings end in a NUL within their length): wrong hash, a count out of range, a string that
/// is not NUL-terminated or holds a NUL, a non-finite float, a shown rate or time outside
/// [0, 1e9], short or trailing bytes: -1 (*out zeroed), nothing read past len. Returns 0 and
/// fills *out otherwise. Thread: any | Allocates: no
int hs_stylus_status_decode(const void* buf, size_t len, hs_stylus_srv_status* out /* OUT */);

/// Start with no message seen, for device_id.
void hs_stylus_rx_init(hs_stylus_rx_state* st, int device_id);
/// Check msg (finite, state known, seq >= 0, within HS_WIRE_*_MAX of hapsim_wire_read.h as the
/// client library checks) and convert it into *out (arrival_ns = now_ns, latency = wall_us -
/// pose_utime when pose_utime > 0, else -1). Thread: the receiving thread | Allocates: no
hs_stylus_rx hs_stylus_rx_force(hs_stylus_rx_state* st, const hapsim_tool_force_t* msg,
                                int64_t now_ns, int64_t wall_us, hs_stylus_model* out /* OUT */);

/// hs_stylus_rx_force on the raw bytes of a message (lcm_subscribe): bytes that do not decode
/// to exactly one tool_force are HS_RX_UNDECODABLE (counted, nothing printed).
/// Thread: the receiving thread | Allocates: no
hs_stylus_rx hs_stylus_rx_bytes(hs_stylus_rx_state* st, const void* buf, size_t len, int64_t now_ns,
                                int64_t wall_us, hs_stylus_model* out /* OUT */);

#ifdef __cplusplus
}
#endif
#endif
