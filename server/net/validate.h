// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim net: validation of every inbound message (tool_pose, command) straight from the bytes
// LCM hands over. Pure functions: all state (per-device seq tracks, the command de-duplication
// ring, the per-reason counters) lives in structs the net thread owns and passes in.
//
// DESIGN: the network edge is hostile. Inbound messages are never decoded with the lcm-gen
// _decode functions, which trust length fields (malloc of a negative or huge count, strings
// without a NUL). A bounds-checked scanner walks the wire format instead, checks the type
// fingerprint and the exact length, and copies into fixed-size structs (no allocation).
// A rejected message changes no state except its counter.
#ifndef HS_NET_VALIDATE_H
#define HS_NET_VALIDATE_H

#include <stdint.h>

#include "base.h"
#include "hapsim_command_rules.h" // the command limits

#ifdef __cplusplus
extern "C" {
#endif

/// Why an inbound message was dropped (HS_NET_ACCEPT when it was not).
typedef enum hs_net_reject {
    HS_NET_ACCEPT = 0,
    HS_NET_REJ_DECODE = 1,     ///< truncated, trailing bytes, wrong fingerprint, bad string
    HS_NET_REJ_LENGTH = 2,     ///< a count or string length out of range / inconsistent
    HS_NET_REJ_NONFINITE = 3,  ///< NaN or Inf in a number
    HS_NET_REJ_QUATERNION = 4, ///< orientation not a unit quaternion within tolerance
    HS_NET_REJ_RANGE = 5,      ///< absurd value: outside workspace, bad bits, negative time, id 0
    HS_NET_REJ_UNKNOWN_DEVICE = 6, ///< device id not in the scene
    HS_NET_REJ_UNKNOWN_TOOL = 7,   ///< tool id not in the scene
    HS_NET_REJ_UNKNOWN_KIND = 8,   ///< command kind not known
    HS_NET_REJ_ARGUMENT = 9,       ///< command arguments missing, repeated, malformed
    HS_NET_REJ_SEQ = 10,           ///< seq repeated, reordered, or an implausible jump
    HS_NET_REJ_SESSION = 11,       ///< another live driver session owns this device
    HS_NET_REJ_DUPLICATE = 12,     ///< command request_id already seen (re-send its ack)
    HS_NET_REJ_COUNT = 13
} hs_net_reject;

/// Short lower-case name of a reason ("decode", "nonfinite", ...); static, never NULL.
const char* hs_net_reject_name(hs_net_reject r);

/// Per-channel counters. Invariant: received == accepted + sum(rejected).
typedef struct hs_net_counters {
    uint64_t received;
    uint64_t accepted;
    uint64_t rejected[HS_NET_REJ_COUNT]; ///< indexed by hs_net_reject; [0] stays 0
} hs_net_counters;

/// Sum of rejected[] over all reasons.
uint64_t hs_net_counters_rejected(const hs_net_counters* c);

#define HS_NET_MAX_DEVICES 16

/// What the scene accepts. Initialise with hs_net_default_limits().
typedef struct hs_net_limits {
    int n_devices;               ///< valid device ids 0 .. n_devices-1 (<= HS_NET_MAX_DEVICES)
    int n_tools;                 ///< valid tool ids 0 .. n_tools-1
    double workspace_min[3];     ///< m, scene frame: poses outside this box are absurd
    double workspace_max[3];     ///< m
    double quat_tol;             ///< accepted | |q| - 1 | (orientation is renormalised)
    int64_t max_seq_jump;        ///< a seq more than this ahead of the last is implausible
    int64_t session_takeover_us; ///< us a device must be silent before a new session may take it
} hs_net_limits;

/// One device, 2 m workspace box around the origin, quat_tol 1e-3, max_seq_jump 1e6 (~17 min
/// of total loss at 1 kHz), session takeover after 0.5 s of silence.
hs_net_limits hs_net_default_limits(void);

/// A validated tool pose (tool_pose on the wire), in the server's terms.
typedef struct hs_net_pose {
    int64_t utime; ///< us, sender's clock
    int64_t seq;
    int64_t session;
    int64_t rx_us; ///< us, receiver clock passed to the validator
    int64_t lost;  ///< poses missed just before this one (seq gap)
    int device_id;
    int tool_id;
    double position[3];    ///< m, scene frame
    double orientation[4]; ///< unit quaternion (w, x, y, z), renormalised
    uint32_t buttons;      ///< HAPSIM_TOOL_POSE_T_BUTTON_* bits
} hs_net_pose;

/// Seq tracking for one device.
typedef struct hs_net_device_track {
    int64_t session; ///< 0 until the first accepted pose
    int64_t last_seq;
    int64_t last_rx_us; ///< us, receiver clock of the last accepted pose
    int64_t accepted;   ///< poses accepted since start
    int64_t lost;       ///< seq gaps since start
} hs_net_device_track;

/// Everything pose validation remembers. Zero-initialise (or hs_net_pose_state_init).
typedef struct hs_net_pose_state {
    hs_net_device_track dev[HS_NET_MAX_DEVICES];
    hs_net_counters counters;
} hs_net_pose_state;

/// Reset to the state before any message.
void hs_net_pose_state_init(hs_net_pose_state* s);

/// Validate one tool_pose from its wire bytes. On HS_NET_ACCEPT fills *out and advances the
/// device's track; otherwise only the counter for the returned reason changes.
/// Thread: net | Allocates: no | Blocks: no
hs_net_reject hs_net_validate_pose(const hs_net_limits* lim, hs_net_pose_state* st, const void* buf,
                                   int64_t len, int64_t now_us, hs_net_pose* out /* OUT */);

// The protocol's limits (msgs/hapsim_command_rules.h, shared with the client), with the NUL.
#define HS_NET_CMD_MAX_ARGS   HAPSIM_CMD_MAX_ARGS
#define HS_NET_CMD_KEY_MAX    (HAPSIM_CMD_KEY_MAX + 1)
#define HS_NET_CMD_VALUE_MAX  (HAPSIM_CMD_TEXT_MAX + 1)
#define HS_NET_CMD_SENDER_MAX (HAPSIM_CMD_SENDER_MAX + 1)

/// A validated command (command on the wire), in fixed storage.
typedef struct hs_net_command {
    int64_t utime;
    int64_t seq;
    int64_t request_id; ///< nonzero
    int kind;           ///< HAPSIM_COMMAND_T_KIND_*
    int n_args;
    char keys[HS_NET_CMD_MAX_ARGS][HS_NET_CMD_KEY_MAX];
    char values[HS_NET_CMD_MAX_ARGS][HS_NET_CMD_VALUE_MAX];
    char sender[HS_NET_CMD_SENDER_MAX];
    double number;   ///< SET_PARAM: the parsed "value"; 0 otherwise
    const char* why; ///< rejected arguments: what was wrong (static text); NULL otherwise
} hs_net_command;

/// Value of argument key, or NULL when absent.
const char* hs_net_command_arg(const hs_net_command* c, const char* key);

#define HS_NET_DEDUP_SIZE 64

/// The most recent accepted request ids with the status of their ack.
typedef struct hs_net_dedup {
    int64_t id[HS_NET_DEDUP_SIZE];
    int32_t kind[HS_NET_DEDUP_SIZE];
    int32_t status[HS_NET_DEDUP_SIZE]; ///< HAPSIM_COMMAND_ACK_T_STATUS_*
    int head;                          ///< next slot to overwrite
    int count;                         ///< valid entries, <= HS_NET_DEDUP_SIZE
} hs_net_dedup;

/// Everything command validation remembers. Zero-initialise (or hs_net_command_state_init).
typedef struct hs_net_command_state {
    hs_net_dedup dedup;
    hs_net_counters counters;
} hs_net_command_state;

/// Reset to the state before any message.
void hs_net_command_state_init(hs_net_command_state* s);

/// Validate one command from its wire bytes. On HS_NET_ACCEPT fills *out and records the
/// request id as PENDING. On HS_NET_REJ_DUPLICATE fills *out too (so the ack can be re-sent) and
/// sets *prev_status to the recorded status. On other rejections out->request_id and out->kind
/// hold what could be read (0 if nothing), so a nonzero id can be acked INVALID.
/// Thread: net | Allocates: no | Blocks: no
hs_net_reject hs_net_validate_command(hs_net_command_state* st, const void* buf, int64_t len,
                                      hs_net_command* out /* OUT */,
                                      int32_t* prev_status /* OUT, may be NULL */);

/// Record the final ack status of an accepted request (found in the ring). Returns 0, or -1 when
/// the id has already left the ring.
int hs_net_dedup_set_status(hs_net_dedup* d, int64_t request_id, int32_t status);

#ifdef __cplusplus
}
#endif
#endif
