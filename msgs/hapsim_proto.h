// SPDX-License-Identifier: MIT
// hapsim_proto: the protocol library linked by the server's net layer, the client library and
// the simulated stylus. Bounded decoders for the types the programs read (below), the channel
// names (hapsim_channels.h), the command rules (hapsim_command_rules.h), the local-model
// evaluator and blend (hapsim_model.h), and the counted allocator the client library and the
// stylus share.
//
// Every decoder reads the raw LCM bytes with hs_rd (hapsim_wire_read.h), never lcm-gen's
// _decode, which trusts length fields: it checks the fingerprint, every count against the bytes
// left and the type's rules, strings for a final NUL and no inner NUL, and the message for
// trailing bytes; nothing is read past len and nothing is allocated. Big arrays are not copied:
// the mesh decoders return views on the wire bytes (big-endian).
#ifndef HAPSIM_PROTO_H
#define HAPSIM_PROTO_H

#include <stddef.h>
#include <stdint.h>

#include "hapsim_channels.h"
#include "hapsim_command_rules.h"
#include "hapsim_model.h"
#include "hapsim_wire_read.h"
#include "hapsim_wire_status.h"

#ifdef __cplusplus
extern "C" {
#endif

/// An LCM string (hs_rd_str) copied into out[cap], truncated to cap - 1 bytes ("" when bad).
void hs_rd_str_copy(hs_rd* r, char* out, size_t cap);

/// Largest visual node count a mesh decoder accepts (a larger topology is malformed).
#define HS_WIRE_MAX_VIS 4000000

/// A big-endian array on the wire: n elements of 4 bytes at p.
typedef struct hs_wire_arr {
    const uint8_t* p; ///< first byte
    int32_t n;        ///< elements
} hs_wire_arr;

/// Element i of an int32 / float array view (0 <= i < a.n).
int32_t hs_wire_i32_at(hs_wire_arr a, int32_t i);
float hs_wire_f32_at(hs_wire_arr a, int32_t i);

/// mesh_topology_t.
typedef struct hs_wire_topology {
    int64_t utime, seq, topology_version;
    int32_t n_nodes, n_vis, n_tri, n_tet;
    hs_wire_arr vis_nodes; ///< [n_vis], each in [0, n_nodes)
    hs_wire_arr rest;      ///< [3 n_vis], finite
    hs_wire_arr tri;       ///< [3 n_tri], each in [0, n_vis)
    hs_wire_arr tet;       ///< [4 n_tet], each in [0, n_vis)
} hs_wire_topology;

/// mesh_state_t (a keyframe).
typedef struct hs_wire_state {
    int64_t utime, seq, topology_version, keyframe_id, sim_step;
    double sim_time;
    hs_wire_arr pos;    ///< [n_pos] finite, n_pos % 3 == 0
    hs_wire_arr stress; ///< [0 or n_pos / 3] finite
} hs_wire_state;

/// mesh_delta_t.
typedef struct hs_wire_delta {
    int64_t utime, seq, topology_version, keyframe_id, sim_step;
    double sim_time;
    hs_wire_arr index; ///< [n_changed] strictly increasing, >= 0
    hs_wire_arr delta; ///< [3 n_changed] finite
} hs_wire_delta;

/// topology_event_t (the id arrays are checked, not kept).
typedef struct hs_wire_event {
    int64_t utime, seq, old_version, new_version;
    int32_t device_id, n_removed, n_moved;
} hs_wire_event;

/// command_ack_t.
typedef struct hs_wire_ack {
    int64_t utime, seq, request_id;
    int32_t kind, status;
    char message[256]; ///< truncated to 255 bytes
} hs_wire_ack;

/// tool_force_t, every field.
typedef struct hs_wire_force {
    int64_t utime, seq;
    int32_t device_id;
    int64_t session; ///< the answered pose's session (0: no pose of this device yet)
    int64_t pose_seq, pose_utime, model_version;
    int32_t state;
    double force[3], anchor[3], stiffness[9], validity_radius;
    int64_t timeout_us;
} hs_wire_force;

/// tool_pose_t, every field as sent (numbers unchecked: the server counts its reasons apart).
typedef struct hs_wire_pose {
    int64_t utime, seq, session;
    int32_t device_id, tool_id;
    double position[3], orientation[4];
    int32_t buttons;
} hs_wire_pose;

/// tool_state_t, every field.
typedef struct hs_wire_tool_state {
    int64_t utime, seq;
    int32_t device_id, tool_id, kind;
    double position[3], orientation[4], radius, blade_a[3], blade_b[3], force[3];
    int8_t contact, cutting;
} hs_wire_tool_state;

/// command_t in fixed storage (limits of hapsim_command_rules.h, with the NUL).
typedef struct hs_wire_command {
    int64_t utime, seq, request_id;
    int32_t kind, n_args;
    char keys[HAPSIM_CMD_MAX_ARGS][HAPSIM_CMD_KEY_MAX + 1];
    char values[HAPSIM_CMD_MAX_ARGS][HAPSIM_CMD_TEXT_MAX + 1];
    char sender[HAPSIM_CMD_SENDER_MAX + 1];
} hs_wire_command;

/// Results of hs_wire_command_decode.
enum {
    HS_WIRE_OK = 0,
    HS_WIRE_MALFORMED = -1, ///< not an encoding of the type
    HS_WIRE_TOO_LONG = -2,  ///< well formed, but a count or a string beyond the limits
};

/// Each returns 0 when the bytes are a valid message of the type, -1 otherwise (*out then
/// undefined). Thread: any | Allocates: no
int hs_wire_topology_decode(const void* buf, size_t len, hs_wire_topology* out /* OUT */);
int hs_wire_state_decode(const void* buf, size_t len, hs_wire_state* out /* OUT */);
int hs_wire_delta_decode(const void* buf, size_t len, hs_wire_delta* out /* OUT */);
int hs_wire_event_decode(const void* buf, size_t len, hs_wire_event* out /* OUT */);
int hs_wire_ack_decode(const void* buf, size_t len, hs_wire_ack* out /* OUT */);
/// hs_wire_force_read, then hs_wire_force_check.
int hs_wire_force_decode(const void* buf, size_t len, hs_wire_force* out /* OUT */);
/// Structure only: fingerprint and exact length, numbers as sent.
int hs_wire_force_read(const void* buf, size_t len, hs_wire_force* out /* OUT */);
/// 0 when every number is finite, the state known, seq, radius and timeout >= 0, and within the
/// ranges HS_WIRE_*_MAX (hapsim_wire_read.h), where the model's force is finite everywhere.
int hs_wire_force_check(const hs_wire_force* m);
/// Also checks: every number finite, device_id >= 0.
int hs_wire_tool_state_decode(const void* buf, size_t len, hs_wire_tool_state* out /* OUT */);
/// Structure only: fingerprint and exact length (the pose's values are the server's to judge).
int hs_wire_pose_decode(const void* buf, size_t len, hs_wire_pose* out /* OUT */);
/// HS_WIRE_OK, HS_WIRE_MALFORMED, or HS_WIRE_TOO_LONG (n_args outside 0..8, a key, value or
/// sender beyond its limit; every string is walked first, so a long one cannot hide a broken
/// encoding). out is zeroed first; request_id and kind hold what could be read on failure.
int hs_wire_command_decode(const void* buf, size_t len, hs_wire_command* out /* OUT */);

/// us: how much older (utime) than the newest one a message of the same server can arrive
/// (reordered on the network). A seq that did not grow with a utime later than the newest, or
/// older than this, comes from a restarted server (another clock after a reboot or on another
/// host).
#define HS_WIRE_REORDER_US 1000000

/// a - b saturated to the int64 range (clocks at its ends must not overflow).
static inline int64_t hs_wire_sub_sat(int64_t a, int64_t b) {
    if (b < 0 && a > INT64_MAX + b) return INT64_MAX;
    if (b > 0 && a < INT64_MIN + b) return INT64_MIN;
    return a - b;
}

/// 1 when utime is within HS_WIRE_REORDER_US at or before newest (no overflow).
static inline int hs_wire_reordered(int64_t utime, int64_t newest) {
    return utime <= newest && (uint64_t)newest - (uint64_t)utime <= HS_WIRE_REORDER_US;
}

/// Counted allocation of the client library and the stylus (hs_client_byte_count): a 16-byte
/// header keeps the size. Thread: any (atomic counters)
void* hs_proto_alloc(size_t n);
void* hs_proto_calloc(size_t count, size_t size);
/// Accepts NULL.
void hs_proto_free(void* p);
/// Bytes held now.
int64_t hs_proto_byte_count(void);
/// Fault injection for tests: the n-th allocation from now fails (n <= 0: none).
void hs_proto_alloc_fail_after(int64_t n);

#ifdef __cplusplus
}
#endif
#endif
