// SPDX-License-Identifier: MIT
// hapsim protocol: server_status_t decoded into fixed-size storage (names truncated to 31
// bytes), for the client library's public API (hs_client_status) and the stylus. No LCM here:
// the decoder is in hapsim_proto.
#ifndef HAPSIM_WIRE_STATUS_H
#define HAPSIM_WIRE_STATUS_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define HS_WIRE_STATUS_LOOPS   8  ///< loops kept
#define HS_WIRE_STATUS_STEPS   16 ///< timed steps kept
#define HS_WIRE_STATUS_DEVICES 16 ///< devices kept
#define HS_WIRE_STATUS_REJECTS 32 ///< reject entries kept

/// One server_status_t (entries beyond the limits above are counted in n_* but not stored).
typedef struct hs_wire_status {
    int64_t utime, seq, uptime_us; ///< us, server clock; seq; us since server start
    int32_t state;                 ///< HAPSIM_SERVER_STATUS_T_STATE_* (0 running, 1 paused, ...)
    char scene[256];               ///< scene path
    int64_t topology_version;      ///< current topology version
    int32_t n_loops, n_steps, n_devices, n_rejects; ///< counts as sent
    struct {
        char name[32];                         ///< "rt", "sim", "net"
        float rate_hz, p50_us, p99_us, max_us; ///< Hz; us period percentiles
        int64_t overruns;                      ///< since start
    } loops[HS_WIRE_STATUS_LOOPS];             ///< [min(n_loops, LOOPS)]
    struct {
        char name[32];                ///< e.g. "fem_step"
        float p50_us, p99_us, max_us; ///< us
    } steps[HS_WIRE_STATUS_STEPS];    ///< [min(n_steps, STEPS)]
    struct {
        int32_t id, live;                     ///< device id; 1 while poses arrive
        float pose_age_ms;                    ///< ms since the newest pose
        int64_t poses_received, poses_lost;   ///< since start
        float latency_p50_us, latency_p99_us; ///< us, inside the server
        float force_norm;                     ///< N
    } devices[HS_WIRE_STATUS_DEVICES];        ///< [min(n_devices, DEVICES)]
    struct {
        char channel[32], reason[32];  ///< e.g. "TOOL_POSE", "nonfinite"
        int64_t count;                 ///< since start
    } rejects[HS_WIRE_STATUS_REJECTS]; ///< [min(n_rejects, REJECTS)]
    char warnings[1024];               ///< newline-separated, "" when all is well
} hs_wire_status;

/// Decode server_status_t bytes (hapsim_proto.h's rules: nothing read past len, strings with
/// their NUL and no other). Returns 0, or -1 with *out all zeros: a count read before a failure
/// (n_loops 5000, -1) must not reach a caller that indexes with it.
/// Thread: any | Allocates: no
int hs_wire_status_decode(const void* buf, size_t len, hs_wire_status* out /* OUT */);

#ifdef __cplusplus
}
#endif
#endif
