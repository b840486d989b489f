// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim net: one LCM bus (an lcm_t on one URL) with a poll()-based handle loop.
// The only server header that includes lcm.h.
//
// DESIGN: the net thread owns one bus per traffic class (haptic, mesh) so a bulky mesh publish
// never queues behind, or delays, a 1 kHz force. lcm_handle_timeout() aborts when the LCM fd
// is >= FD_SETSIZE, so waiting is done with poll() on lcm_get_fileno() and lcm_handle().
#ifndef HS_NET_BUS_H
#define HS_NET_BUS_H

#include <stdint.h>

#include <lcm/lcm.h>

#include "base.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hs_net_bus hs_net_bus;

/// Open an LCM instance on url (e.g. "udpm://239.255.76.67:7667?ttl=0"). @param out OUT
/// Thread: any (then owned by one thread) | Allocates: yes
hs_status hs_net_bus_create(const char* url, hs_net_bus** out, hs_err* err);
/// Close and release; accepts NULL, sets *bus = NULL.
void hs_net_bus_destroy(hs_net_bus** bus);
/// The underlying lcm_t, for subscribe/publish. Valid until destroy.
lcm_t* hs_net_bus_lcm(hs_net_bus* bus);
/// The URL the bus was opened with.
const char* hs_net_bus_url(const hs_net_bus* bus);
/// Wait up to timeout_ms (0: do not wait) for traffic and dispatch one batch to the handlers.
/// Returns 1 when something was handled, 0 on timeout (or EINTR), -1 on error.
/// Thread: the bus owner only (LCM allows one handling thread) | Blocks: up to timeout_ms
int hs_net_bus_handle(hs_net_bus* bus, int timeout_ms);

/// Datagrams the kernel dropped, since they were opened, for this process's sockets on the
/// bus's port (a full receive buffer: /proc/net/udp's drops), or -1 when it cannot tell.
/// Thread: any | Allocates: no | not for the 1 kHz path (reads /proc)
int64_t hs_net_bus_kernel_drops(const hs_net_bus* bus);
/// recv_buf_size=N requested in an LCM URL, bytes; 0 when absent or malformed.
int64_t hs_net_url_recv_buf(const char* url);
/// The kernel's net.core.rmem_max, bytes, or -1 when unreadable. A socket receive buffer larger
/// than this is silently capped, and fragmented mesh messages get lost.
int64_t hs_net_rmem_max(void);
/// The kernel's net.core.rmem_default (the buffer of a socket that asks for none), or -1.
int64_t hs_net_rmem_default(void);

/// Whether a message of `bytes` reaches a receiver on this host, given the kernel's
/// rmem_default and rmem_max (-1: unknown). LCM 1.3.1 loses a fragmented message that overflows
/// the receiving socket's buffer, and the kernel charges a datagram's overhead too, so a message
/// needs about twice its bytes. 0: a socket that asks for nothing gets it (out is ""); 1: only a
/// receiver whose URL asks for recv_buf_size surely gets it; 2: none does until rmem_max is
/// raised.
/// For 1 and 2 out[cap] says so and what to do; `what` names the message.
/// Thread: any | Allocates: no
int hs_net_size_note(const char* what, int64_t bytes, int64_t rmem_default, int64_t rmem_max,
                     char* out, size_t cap);

#ifdef __cplusplus
}
#endif
#endif
