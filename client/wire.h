// SPDX-License-Identifier: MIT
// Client wire edge: a bounds-checked reader over raw LCM message bytes. Every decoder checks the
// fingerprint, every length field against the bytes left and the type's rules, strings for a
// final NUL and no inner NUL, floats for NaN/Inf and the message for trailing bytes. Big arrays
// are not copied: the decoders return views on the wire bytes (big-endian) that the mesh sync
// converts while copying. Internal to libhapsim-client.
#ifndef HS_CLIENT_WIRE_H
#define HS_CLIENT_WIRE_H

#include <stddef.h>
#include <stdint.h>

#include "hapsim/client.h"
#include "hapsim_wire_read.h" // HS_WIRE_*_MAX

/// A big-endian array on the wire: n elements of 4 bytes at p.
typedef struct hs_wire_arr {
    const uint8_t* p; ///< first byte
    int32_t n;        ///< elements
} hs_wire_arr;

int32_t hs_wire_i32_at(hs_wire_arr a, int32_t i);
float hs_wire_f32_at(hs_wire_arr a, int32_t i);

typedef struct hs_wire_topology {
    int64_t utime, seq, topology_version;
    int32_t n_nodes, n_vis, n_tri, n_tet;
    hs_wire_arr vis_nodes; ///< [n_vis], each in [0, n_nodes)
    hs_wire_arr rest;      ///< [3 n_vis], finite
    hs_wire_arr tri;       ///< [3 n_tri], each in [0, n_vis)
    hs_wire_arr tet;       ///< [4 n_tet], each in [0, n_vis)
} hs_wire_topology;

typedef struct hs_wire_state {
    int64_t utime, seq, topology_version, keyframe_id, sim_step;
    double sim_time;
    hs_wire_arr pos;    ///< [n_pos] finite, n_pos % 3 == 0
    hs_wire_arr stress; ///< [0 or n_pos / 3] finite
} hs_wire_state;

typedef struct hs_wire_delta {
    int64_t utime, seq, topology_version, keyframe_id, sim_step;
    double sim_time;
    hs_wire_arr index; ///< [n_changed] strictly increasing, >= 0
    hs_wire_arr delta; ///< [3 n_changed] finite
} hs_wire_delta;

typedef struct hs_wire_event {
    int64_t utime, seq, old_version, new_version;
    int32_t device_id, n_removed, n_moved;
} hs_wire_event;

typedef struct hs_wire_ack {
    int64_t utime, seq, request_id;
    int32_t kind, status;
    char message[256];
} hs_wire_ack;

/// Each returns 0 when the bytes are a valid message of the type, -1 otherwise.
int hs_wire_topology_decode(const void* buf, size_t len, hs_wire_topology* out);
int hs_wire_state_decode(const void* buf, size_t len, hs_wire_state* out);
int hs_wire_delta_decode(const void* buf, size_t len, hs_wire_delta* out);
int hs_wire_event_decode(const void* buf, size_t len, hs_wire_event* out);
int hs_wire_ack_decode(const void* buf, size_t len, hs_wire_ack* out);
/// tool_force into a local model (arrival_us left 0); also checks state, and the ranges
/// HS_WIRE_*_MAX (hapsim_wire_read.h).
/// *utime (may be NULL) gets the message's utime (server clock).
int hs_wire_force_decode(const void* buf, size_t len, int32_t* device_id, int64_t* utime,
                         hs_local_model* out);

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

/// Counted allocation of the client library (hs_client_byte_count).
void* hs_client_alloc(size_t n);
void* hs_client_calloc(size_t count, size_t size);
void hs_client_free(void* p);
/// Fault injection for tests: the n-th allocation from now fails (n <= 0: none).
void hs_client_alloc_fail_after(int64_t n);

/// The LCM handle of a client's bus (0 haptic, 1 mesh), NULL when not open: lets the memq://
/// tests publish server messages into a client.
struct _lcm_t* hs_client_lcm(hs_client* c, int bus);

#endif
