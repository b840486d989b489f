// SPDX-License-Identifier: MIT
// libhapsim-client: talk to a running hapsim-server over LCM (docs/protocol.md, docs/client.md).
// Drivers send tool poses and render the server's local force model between messages;
// visualisers keep an always-consistent copy of the deforming mesh; tools send commands and
// read the server status.
//
// Threading model: a handle is driven by ONE thread at a time. The library starts no thread;
// hs_client_poll() waits on the LCM sockets with poll() and dispatches what arrived (it never
// calls lcm_handle_timeout). Every function taking an hs_client* must be called from the thread
// that polls, unless its comment says otherwise. Callbacks run inside hs_client_poll() on that
// thread. Several handles may live in one process, each driven by its own thread.
//
// Everything received is validated by a bounds-checked reader on the raw bytes (never lcm-gen's
// decoder, which trusts length fields): a malformed message is counted and dropped.
//
// Of base.h the client uses the hs_status enum and the hs_err struct only; its functions
// (hs_alloc, hs_err_set, ...) belong to the server core and are NOT part of libhapsim-client.
#ifndef HAPSIM_CLIENT_H
#define HAPSIM_CLIENT_H

#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>

#include "hapsim/status.h"
#include "hapsim_wire_status.h" // hs_wire_status: a decoded server_status

#ifdef __cplusplus
extern "C" {
#endif

/// Library version (major * 10000 + minor * 100 + patch).
#define HS_CLIENT_VERSION 100
/// Highest device id a client tracks forces for (ids 0 .. HS_CLIENT_MAX_DEVICES-1).
#define HS_CLIENT_MAX_DEVICES 16
/// Largest visual node count the client accepts in a mesh_topology (larger ones are dropped).
#define HS_CLIENT_MAX_VIS 4000000
/// Receive buffer size (bytes) asked for on the default mesh URL (large keyframes fragment).
#define HS_CLIENT_MESH_RECV_BUF 4194304

/// Static text for a status, e.g. "invalid argument"; never NULL.
/// Thread: any | Allocates: no
const char* hs_client_status_str(hs_status s);

// ---------------------------------------------------------------------------------------------
// Local force model (the tool_force_t formula of docs/protocol.md). Pure functions, no network.

/// One tool_force_t as received, in the client's clock.
typedef struct hs_local_model {
    int32_t valid;          ///< 1 once a model was received
    int32_t state;          ///< HAPSIM_TOOL_FORCE_T_STATE_* (0 free, 1 contact, 2 ramp, 3 stopped)
    int64_t seq;            ///< message seq
    int64_t session;        ///< the answered pose's session (echo)
    int64_t model_version;  ///< changes when anchor or stiffness change
    int64_t pose_seq;       ///< echoed pose seq
    int64_t pose_utime;     ///< echoed pose utime, us (sender's CLOCK_REALTIME)
    int64_t arrival_us;     ///< us, hs_client_now_us() when it arrived
    int64_t timeout_us;     ///< us, render at full strength this long after arrival
    double force[3];        ///< N, scene frame, at the anchor
    double anchor[3];       ///< m, scene frame
    double stiffness[9];    ///< N/m, row-major dF/dp
    double validity_radius; ///< m, |p - anchor| is clamped to this
} hs_local_model;

/// F(p) = force + stiffness * d, d = p - anchor clamped to |d| <= validity_radius; full strength
/// until timeout_us after arrival, then a linear ramp to zero over another timeout_us; zero for
/// STATE_STOPPED or an invalid model (|d| is computed without overflow: any finite p, however
/// far, is clamped). Writes f[3] (N); returns the strength factor in [0, 1].
/// Never a non-finite force: a non-finite p, or a hand-built model whose F would overflow, gives
/// zero (and returns 0). Thread: any | Allocates: no
double hs_local_model_eval(const hs_local_model* m, const double p[3], int64_t now_us,
                           double f[3] /* OUT */);

/// Model blending: after model_version changes, F = (1 - w) F_old + w F_new with w rising
/// linearly from 0 to 1 over blend_us (default 3000 us, a few servo ticks). A STATE_STOPPED
/// model is zero at once, with no blend out of the model before it.
typedef struct hs_force_renderer {
    hs_local_model old_model; ///< the model before the last version change
    hs_local_model model;     ///< the newest model
    int64_t blend_start_us;   ///< us, arrival of the model that started the current blend
    int64_t blend_us;         ///< us, blend duration (0: switch at once)
} hs_force_renderer;

/// Start empty with the default blend (3 ms). Thread: any | Allocates: no
void hs_force_renderer_init(hs_force_renderer* r);
/// Take a new model (blend starts when model_version differs from the current one).
/// Thread: the caller owning r | Allocates: no
void hs_force_renderer_push(hs_force_renderer* r, const hs_local_model* m);
/// Blended, timed-out force at p (m) now (us, any int64: differences saturate); writes f[3] (N);
/// returns the newest model's state (-1 before any model).
/// Thread: the caller owning r | Allocates: no
int32_t hs_force_renderer_eval(const hs_force_renderer* r, const double p[3], int64_t now_us,
                               double f[3] /* OUT */);

// ---------------------------------------------------------------------------------------------
// Mesh synchronisation: topology + keyframes + deltas -> one consistent mesh. Usable without a
// network: feed it raw LCM message bytes (what lcm-gen's _encode writes, fingerprint first).

typedef struct hs_mesh_sync hs_mesh_sync;

/// What a mesh message did. Negative values are drops.
typedef enum hs_sync_result {
    HS_SYNC_APPLIED = 0,    ///< the visible mesh changed (new keyframe or delta)
    HS_SYNC_HELD = 1,       ///< stored (a topology waiting for its keyframe, a repeat, an event)
    HS_SYNC_STALE = -1,     ///< older than what is held (reordered or repeated)
    HS_SYNC_MISMATCH = -2,  ///< for another topology version or keyframe: waiting for a keyframe
    HS_SYNC_MALFORMED = -3, ///< failed validation (counted in malformed)
    HS_SYNC_NOMEM = -4,     ///< could not grow the buffers for a larger topology (state kept)
} hs_sync_result;

/// Message kinds the mesh sync takes.
typedef enum hs_sync_kind {
    HS_SYNC_TOPOLOGY = 0, ///< hapsim_mesh_topology_t bytes
    HS_SYNC_STATE = 1,    ///< hapsim_mesh_state_t bytes (keyframe)
    HS_SYNC_DELTA = 2,    ///< hapsim_mesh_delta_t bytes
    HS_SYNC_EVENT = 3,    ///< hapsim_topology_event_t bytes
} hs_sync_kind;

/// The visible mesh: a topology and positions that belong to it. Arrays are owned by the sync
/// object and stay valid until the next hs_mesh_sync_feed (or hs_client_poll) call.
typedef struct hs_client_mesh {
    int32_t ready;            ///< 1 once a topology and a keyframe for it arrived
    int64_t topology_version; ///< version of the topology shown
    int64_t keyframe_id;      ///< keyframe the positions derive from
    int64_t delta_seq;        ///< seq of the delta applied on top (-1: keyframe alone)
    int64_t sim_step;         ///< server deformation step of these positions
    double sim_time;          ///< s, simulated time of these positions
    int64_t utime;            ///< us, server clock of the message that made these positions
    int64_t frame;            ///< increments on every change of the visible mesh (topology,
                              ///< positions or stress; a keyframe of the same shape is none)
    int32_t n_nodes;          ///< nodes of the server's volume mesh
    int32_t n_vis;            ///< visual nodes
    int32_t n_tri;            ///< surface triangles
    int32_t n_tet;            ///< tetrahedra (0 unless the server sends them)
    const int32_t* vis_nodes; ///< [n_vis] server node id of each visual node
    const float* rest;        ///< [3 n_vis] m, rest positions
    const float* position;    ///< [3 n_vis] m, current positions
    const int32_t* triangles; ///< [3 n_tri] visual indices, counter-clockwise from outside
    const int32_t* tets;      ///< [4 n_tet] visual indices, or NULL
    const float* stress;      ///< [n_vis] Pa von Mises, or NULL when the server sends none
} hs_client_mesh;

/// Counters of one mesh sync (or of a client's mesh channels).
typedef struct hs_sync_stats {
    int64_t received[4];        ///< per hs_sync_kind, messages fed
    int64_t applied;            ///< visible-mesh changes
    int64_t stale;              ///< HS_SYNC_STALE results
    int64_t mismatched;         ///< HS_SYNC_MISMATCH results
    int64_t malformed;          ///< HS_SYNC_MALFORMED results
    int64_t lost[4];            ///< per hs_sync_kind, messages missing by seq gaps
    int64_t topologies;         ///< topologies accepted (new versions or a restarted server)
    int64_t events;             ///< topology events accepted
    int64_t last_event_old;     ///< old_version of the newest topology event (-1: none)
    int64_t last_event_new;     ///< new_version of the newest topology event (-1: none)
    int32_t last_event_removed; ///< tets removed by the newest topology event
} hs_sync_stats;

/// Create an empty sync object. Returns HS_OK or HS_ERR_NOMEM.
/// Thread: any | Allocates: yes (small; arrays grow with the first topology)
hs_status hs_mesh_sync_create(hs_mesh_sync** out /* OUT */, hs_err* err);
/// Release; accepts NULL and *s == NULL; sets *s = NULL. Thread: the owner
void hs_mesh_sync_destroy(hs_mesh_sync** s);
/// Feed one message (raw bytes, fingerprint first). Rules (docs/client.md "Watching the mesh"):
/// a topology with a newer version (or any version from a restarted server) is held until a
/// keyframe of that version arrives; a keyframe is shown when its topology version is held and
/// its keyframe_id is newer; a delta only when topology version and keyframe_id match the shown
/// keyframe and its seq is newer. A restarted server: a topology whose seq and utime do not both
/// go on from the newest one (other than a reorder: seq not newer, utime at most 1 s older) or
/// whose version went back; or a keyframe whose id went back while its seq or utime went on
/// (the shown version then waits for the next topology). A topology version or keyframe_id
/// more than 1e6 + 1 per ms of server time (utime) ahead of the newest is a corrupt message:
/// HS_SYNC_MALFORMED. Never crashes on any bytes.
/// Thread: the owner | Allocates: only when a topology needs larger arrays
hs_sync_result hs_mesh_sync_feed(hs_mesh_sync* s, hs_sync_kind kind, const void* buf, size_t len);
/// The visible mesh (valid until the next feed). Thread: the owner | Allocates: no
const hs_client_mesh* hs_mesh_sync_mesh(const hs_mesh_sync* s);
/// Counters. Thread: the owner | Allocates: no
void hs_mesh_sync_stats(const hs_mesh_sync* s, hs_sync_stats* out /* OUT */);
/// Newest topology version seen (held or shown), -1 before any. Thread: the owner
int64_t hs_mesh_sync_newest_topology(const hs_mesh_sync* s);

// ---------------------------------------------------------------------------------------------
// Server status, decoded into fixed-size storage (names truncated to 31 bytes).

#define HS_CLIENT_STATUS_LOOPS   HS_WIRE_STATUS_LOOPS   ///< loops kept
#define HS_CLIENT_STATUS_STEPS   HS_WIRE_STATUS_STEPS   ///< timed steps kept
#define HS_CLIENT_STATUS_DEVICES HS_WIRE_STATUS_DEVICES ///< devices kept
#define HS_CLIENT_STATUS_REJECTS HS_WIRE_STATUS_REJECTS ///< reject entries kept

/// One server_status_t (the protocol library's struct, msgs/hapsim_wire_status.h).
typedef hs_wire_status hs_client_status;

/// Decode server_status_t bytes with full validation. Returns HS_OK or HS_ERR_PARSE (out all
/// zeros), HS_ERR_INVALID for a NULL out.
/// Thread: any | Allocates: no
hs_status hs_client_status_decode(const void* buf, size_t len, hs_client_status* out /* OUT */);

/// Name of a server state ("running", "paused", "estop", "loading", "unknown"). Thread: any
const char* hs_client_state_name(int32_t state);

// ---------------------------------------------------------------------------------------------
// The connection.

typedef struct hs_client hs_client;

/// What a client listens to (bit mask for hs_client_config.subscribe).
enum {
    HS_CLIENT_SUB_FORCE = 1u << 0,   ///< haptic bus: tool_force for the local model
    HS_CLIENT_SUB_MESH = 1u << 1,    ///< mesh bus: topology, keyframes, deltas, events
    HS_CLIENT_SUB_STATUS = 1u << 2,  ///< mesh bus: server_status
    HS_CLIENT_SUB_COMMANDS = 1u << 3 ///< mesh bus: command acks (needed by hs_client_command)
};

/// Connection settings. Start from hs_client_config_default().
typedef struct hs_client_config {
    const char* haptic_url; ///< NULL: HAPSIM_DEFAULT_HAPTIC_URL; "": no haptic bus
    const char* mesh_url;   ///< NULL: HAPSIM_DEFAULT_MESH_URL + recv_buf_size; "": no mesh bus
    const char* prefix;     ///< channel prefix, NULL: HAPSIM_DEFAULT_PREFIX ("HAPSIM_")
    const char* sender;     ///< command sender text (<= 63 bytes), NULL: "hapsim-client:<pid>"
    uint32_t subscribe;     ///< HS_CLIENT_SUB_* bits
    int64_t session;        ///< pose session id, 0: random nonzero
    /// 0 (a driver): take only forces answering this client's session (others are counted in
    /// forces_session); 1 (a viewer): take every session's.
    int32_t all_sessions;
} hs_client_config;

/// Defaults: default URLs and prefix, subscribe = FORCE | MESH | STATUS | COMMANDS.
/// Thread: any | Allocates: no
void hs_client_config_default(hs_client_config* cfg /* OUT */);

/// Callbacks, all optional (NULL), called inside hs_client_poll on the polling thread. The
/// pointers passed are valid during the call only. A callback may use its handle, except that
/// it cannot wait for it: hs_client_poll there returns HS_ERR_INVALID, hs_client_command sends
/// once without waiting, and hs_client_destroy is refused (see each).
typedef struct hs_client_callbacks {
    void (*on_mesh)(hs_client* c, const hs_client_mesh* mesh, void* user); ///< visible mesh changed
    void (*on_force)(hs_client* c, int32_t device_id, const hs_local_model* m, void* user);
    void (*on_status)(hs_client* c, const hs_client_status* st, void* user);
    void (*on_topology_event)(hs_client* c, int64_t old_version, int64_t new_version,
                              int32_t n_removed, void* user);
} hs_client_callbacks;

/// Open the buses and subscribe. Returns HS_OK, HS_ERR_INVALID (bad config), HS_ERR_IO (LCM
/// could not open a URL) or HS_ERR_NOMEM; *out is NULL on failure.
/// Thread: any (the handle then belongs to the creating thread) | Allocates: yes
hs_status hs_client_create(const hs_client_config* cfg, hs_client** out /* OUT */, hs_err* err);
/// Close the buses and free everything; accepts NULL and *c == NULL; sets *c = NULL.
/// From a callback it is refused (LCM is dispatching on the buses): nothing is freed, *c is
/// kept, and the running hs_client_poll stops and returns HS_ERR_INVALID saying so.
void hs_client_destroy(hs_client** c);

/// Set the callbacks (copied) and their user pointer. Thread: the polling thread
void hs_client_set_callbacks(hs_client* c, const hs_client_callbacks* cb, void* user);

/// Wait up to timeout_ms (0: do not wait, < 0: forever) for traffic on either bus, then handle
/// everything that is ready. Returns the number of LCM messages handled (>= 0), or a negative
/// hs_status on a socket failure. From a callback (already inside hs_client_poll) it handles
/// nothing and returns HS_ERR_INVALID. Thread: the polling thread | Allocates: only on topology
/// growth
int hs_client_poll(hs_client* c, int timeout_ms, hs_err* err);

/// The LCM socket of a bus (0 haptic, 1 mesh) for a caller's own poll loop, -1 when not open.
/// After it becomes readable call hs_client_poll(c, 0, err). Thread: any
int hs_client_fileno(const hs_client* c, int bus);

/// Monotonic clock in microseconds (the clock of arrival_us). Thread: any | Allocates: no
int64_t hs_client_now_us(void);

/// Age (us) of a server timestamp (utime) when the server runs on this host: now - utime on
/// CLOCK_REALTIME (the LCM convention) or, if that is implausible (not within -1 s .. 1 h), on
/// CLOCK_MONOTONIC; -1 when neither fits (another host; any int64 utime, no overflow).
/// Thread: any | Allocates: no
int64_t hs_client_age_us(int64_t utime);

/// A pose to send (the client fills utime, seq and session).
typedef struct hs_client_pose {
    int32_t device_id;     ///< 0 .. devices-1 of the scene
    int32_t tool_id;       ///< scene tool index
    double position[3];    ///< m, scene frame
    double orientation[4]; ///< unit quaternion (w, x, y, z), tool -> scene
    int32_t buttons;       ///< HAPSIM_TOOL_POSE_T_BUTTON_* bits
} hs_client_pose;

/// Publish one tool_pose on the haptic bus (seq +1 per device). Returns HS_OK, HS_ERR_INVALID
/// (non-finite, bad quaternion, id out of range, no haptic bus) or HS_ERR_IO.
/// Thread: the polling thread, or one other thread if that thread never polls (LCM publish is
/// internally locked) | Allocates: no
hs_status hs_client_send_pose(hs_client* c, const hs_client_pose* pose, hs_err* err);

/// Force to render for device_id at position p (m) now (us, hs_client_now_us clock): the
/// blended local model with the timeout ramp. Writes f[3] (N). Returns the model state, or -1
/// when no force message arrived yet (f = 0). Thread: the polling thread | Allocates: no
int32_t hs_client_force(const hs_client* c, int32_t device_id, const double p[3], int64_t now_us,
                        double f[3] /* OUT */);
/// Copy the newest local model of device_id. Returns false when none arrived.
/// Thread: the polling thread | Allocates: no
bool hs_client_force_model(const hs_client* c, int32_t device_id, hs_local_model* out /* OUT */);
/// Force round-trip latency of the newest message of device_id (us, now - pose_utime on this
/// host's CLOCK_REALTIME), -1 when unknown. Thread: the polling thread
int64_t hs_client_force_latency_us(const hs_client* c, int32_t device_id);

/// The visible mesh (valid until the next poll). Thread: the polling thread | Allocates: no
const hs_client_mesh* hs_client_mesh_view(const hs_client* c);
/// Mesh channel counters. Thread: the polling thread | Allocates: no
void hs_client_mesh_stats(const hs_client* c, hs_sync_stats* out /* OUT */);
/// Newest server status (a malformed one is dropped and keeps the last good one); returns false
/// when none arrived. *age_us (may be NULL) is how long ago it arrived. Thread: the polling thread
/// | Allocates: no
bool hs_client_status_latest(const hs_client* c, hs_client_status* out /* OUT */, int64_t* age_us);

/// Client-wide counters.
typedef struct hs_client_stats {
    int64_t messages;       ///< messages handled on both buses
    int64_t malformed;      ///< dropped by validation (all channels)
    int64_t forces;         ///< tool_force messages accepted
    int64_t forces_other;   ///< tool_force for a device id outside 0..MAX_DEVICES-1
    int64_t forces_stale;   ///< tool_force not newer (seq) than the last of its device and at
                            ///< most 1 s older (utime): reordered (newer utime or older: restart;
                            ///< after 7 refused in a row with seq counting up, the next is taken)
    int64_t forces_session; ///< tool_force answering another session's poses (dropped unless
                            ///< the config's all_sessions)
    int64_t poses_sent;     ///< tool_pose published
    int64_t statuses;       ///< server_status accepted
    int64_t acks;           ///< command acks accepted
} hs_client_stats;
/// Counters. Thread: the polling thread (poses_sent may be counted meanwhile by a thread that
/// only sends poses) | Allocates: no
void hs_client_stats_get(const hs_client* c, hs_client_stats* out /* OUT */);

/// A command's answer.
typedef struct hs_client_ack {
    int64_t request_id; ///< the request this answers
    int32_t kind;       ///< HAPSIM_COMMAND_T_KIND_* echoed
    int32_t status;     ///< HAPSIM_COMMAND_ACK_T_STATUS_* (0 ok, 1 pending, -1 invalid, -2 failed)
    int32_t attempts;   ///< how many times the command was published
    int64_t rtt_us;     ///< us, first publish -> final ack
    char message[256];  ///< server detail, "" when OK
} hs_client_ack;

/// Send a command (kind HAPSIM_COMMAND_T_KIND_*, n_args 0..8 key/value strings) and wait for
/// its final ack, polling the client meanwhile (callbacks run). Re-publishes with the SAME
/// request_id every retry_ms until an ack arrives (the server runs a request id once and re-sends
/// its ack); after a PENDING ack waits for the final one. Returns HS_OK when a final ack arrived
/// (look at ack->status: the server may have refused), HS_ERR_INVALID for bad arguments
/// (checked locally as the server would), HS_ERR_IO when no final ack came within timeout_ms.
/// From a callback it cannot wait: it publishes the command once and returns HS_OK with
/// ack->status STATUS_PENDING and attempts 1 (no retry, the final ack is not reported).
/// Thread: the polling thread | Allocates: no
hs_status hs_client_command(hs_client* c, int32_t kind, int n_args, const char* const* keys,
                            const char* const* values, int timeout_ms, int retry_ms,
                            hs_client_ack* ack /* OUT */, hs_err* err);

/// Bytes currently allocated by the client library (tests check it returns to its start value).
/// Thread: any (atomic) | Allocates: no
int64_t hs_client_byte_count(void);

#ifdef __cplusplus
}
#endif
#endif
