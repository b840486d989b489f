// SPDX-License-Identifier: MIT
// Client wire edge: the protocol library's bounded decoders (hapsim_proto.h) and what only the
// client library adds. Internal to libhapsim-client.
#ifndef HS_CLIENT_WIRE_H
#define HS_CLIENT_WIRE_H

#include <stddef.h>
#include <stdint.h>

#include "hapsim/client.h"
#include "hapsim_proto.h"

/// The local model of a decoded tool_force (valid, arrival_us left 0).
hs_local_model hs_wire_local_model(const hs_wire_force* w);

/// The LCM handle of a client's bus (0 haptic, 1 mesh), NULL when not open: lets the memq://
/// tests publish server messages into a client.
struct _lcm_t* hs_client_lcm(hs_client* c, int bus);

#endif
