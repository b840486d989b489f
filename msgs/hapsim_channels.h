// SPDX-License-Identifier: MIT
// hapsim protocol: channel names and default LCM URLs, shared by the server, the client library
// and the simulated stylus (the only hand-written header of hapsim_msgs). A channel is the
// configurable prefix followed by one of the suffixes below, e.g. "HAPSIM_" "TOOL_POSE".
// See docs/protocol.md for direction, bus, rate and units of each channel.
#ifndef HAPSIM_CHANNELS_H
#define HAPSIM_CHANNELS_H

#include <stddef.h>
#include <stdlib.h>
#include <string.h>

/// Default channel prefix; several servers on one LAN differ by prefix (and port).
#define HAPSIM_DEFAULT_PREFIX "HAPSIM_"
/// Haptic bus: 1 kHz poses in, forces out. Host-local (ttl=0).
#define HAPSIM_DEFAULT_HAPTIC_URL "udpm://239.255.76.67:7667?ttl=0"
/// Mesh bus: mesh, tool drawing, commands, acks, status. Receivers of mesh_state should add
/// recv_buf_size=N (N >= the largest message, e.g. 2097152) to their URL.
#define HAPSIM_DEFAULT_MESH_URL "udpm://239.255.76.67:7668?ttl=0"

// Haptic bus.
#define HAPSIM_CH_TOOL_POSE  "TOOL_POSE"  ///< in: hapsim_tool_pose_t, ~1 kHz per device
#define HAPSIM_CH_TOOL_FORCE "TOOL_FORCE" ///< out: hapsim_tool_force_t, per pose
// Mesh bus.
#define HAPSIM_CH_MESH_TOPOLOGY  "MESH_TOPOLOGY"  ///< out: hapsim_mesh_topology_t, on change + 1 Hz
#define HAPSIM_CH_MESH_STATE     "MESH_STATE"     ///< out: hapsim_mesh_state_t, keyframes 1-2 Hz
#define HAPSIM_CH_MESH_DELTA     "MESH_DELTA"     ///< out: hapsim_mesh_delta_t, per frame <= 60 Hz
#define HAPSIM_CH_TOPOLOGY_EVENT "TOPOLOGY_EVENT" ///< out: hapsim_topology_event_t, per cut
#define HAPSIM_CH_TOOL_STATE     "TOOL_STATE"     ///< out: hapsim_tool_state_t, per frame
#define HAPSIM_CH_COMMAND        "COMMAND"        ///< in: hapsim_command_t
#define HAPSIM_CH_COMMAND_ACK    "COMMAND_ACK"    ///< out: hapsim_command_ack_t, one per command
#define HAPSIM_CH_SERVER_STATUS  "SERVER_STATUS"  ///< out: hapsim_server_status_t, ~2 Hz

/// Longest channel name we build (prefix up to 47 bytes + suffix + NUL).
#define HAPSIM_CHANNEL_MAX 64

/// Write prefix + suffix into out[cap]. Returns 0, or -1 if it does not fit (out is then "").
static inline int hapsim_channel_name(char* out, size_t cap, const char* prefix,
                                      const char* suffix) {
    size_t np = prefix ? strlen(prefix) : 0, ns = strlen(suffix);
    if (cap == 0) return -1;
    if (np + ns + 1 > cap) {
        out[0] = '\0';
        return -1;
    }
    if (np) memcpy(out, prefix, np);
    memcpy(out + np, suffix, ns + 1);
    return 0;
}

/// Why url cannot serve as a hapsim bus, or NULL. A udpm URL that names a group must name a
/// port other than 0 (udpm://GROUP:PORT): without one LCM 1.3.1 uses port 0, a random port (in a
/// private namespace a publisher and a receiver on such URLs never met, and the receiver's
/// lcm_create hung), and the port must be a number alone ("7667x" is port 7667 to LCM).
/// "udpm://" alone is LCM's default group and port; other providers are left to LCM.
static inline const char* hapsim_url_problem(const char* url) {
    static const char udpm[] = "udpm://";
    if (!url || strncmp(url, udpm, sizeof udpm - 1)) return NULL;
    const char* net = url + sizeof udpm - 1;
    size_t n = strcspn(net, "?");
    if (n == 0) return NULL;
    const char* colon = memchr(net, ':', n);
    if (!colon || colon + 1 == net + n)
        return "names a group but no port (write udpm://GROUP:PORT: without a port LCM binds a "
               "random one and no other program hears the bus)";
    char* end;
    long port = strtol(colon + 1, &end, 0);
    // LCM reads the port with strtol too and ignores what follows: "7667x" is port 7667, which
    // another URL's text would not show (found in review: a mesh bus on the haptic one).
    if (end == colon + 1 || end != net + n)
        return "has a port that is not a number alone (write udpm://GROUP:PORT, options after ?)";
    if (port <= 0 || port > 65535) // LCM keeps it in an int: 2^32 is 0
        return "has port 0 or one outside 1..65535 (LCM would bind a random port: no other "
               "program hears the bus)";
    return NULL;
}

/// The port LCM binds for a udpm URL, read as LCM reads it (strtol, base 0; "udpm://" alone is
/// its default 7667), or -1 for another provider or a URL hapsim_url_problem refuses.
static inline long hapsim_url_port(const char* url) {
    static const char udpm[] = "udpm://";
    if (!url || strncmp(url, udpm, sizeof udpm - 1) || hapsim_url_problem(url)) return -1;
    const char* net = url + sizeof udpm - 1;
    size_t n = strcspn(net, "?");
    if (n == 0) return 7667;
    const char* colon = memchr(net, ':', n);
    return colon ? strtol(colon + 1, NULL, 0) : -1;
}

#endif
