// SPDX-License-Identifier: GPL-2.0-or-later
// SPSC ring: one producer, one consumer, nothing dropped (cuts, commands, telemetry).
//
// DESIGN. A power-of-two array of fixed-size items and two monotonically increasing counters:
// head (written by the producer only) and tail (written by the consumer only). The producer
// publishes an item with a release store of head after copying it in; the consumer acquires head
// before copying out and releases tail after, so the producer reuses a slot only once it has been
// read. When full, push fails and returns 0: the caller decides (count and drop, retry later).
// Each side caches the other's counter to touch the shared cache line only when needed.
#ifndef HS_BASE_SPSC_RING_H
#define HS_BASE_SPSC_RING_H

#include "base.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hs_spsc_ring hs_spsc_ring;

/// Create a ring of capacity items (a power of two >= 2) of elem_size bytes each. @param out OUT
/// Thread: any | Allocates: yes
hs_status hs_spsc_ring_create(size_t elem_size, size_t capacity, hs_spsc_ring** out, hs_err* err);
/// Release; accepts NULL or *ring == NULL and sets *ring = NULL. Both sides must have stopped.
void hs_spsc_ring_destroy(hs_spsc_ring** ring);

/// Copy one item in. Returns 1, or 0 when the ring is full (nothing written).
/// Thread: producer only | Allocates: no | Lock-free: yes | Blocks: no
int hs_spsc_ring_push(hs_spsc_ring* ring, const void* item);
/// Copy the oldest item to out and remove it. Returns 1, or 0 when empty (out untouched).
/// Thread: consumer only | Allocates: no | Lock-free: yes | Blocks: no
int hs_spsc_ring_pop(hs_spsc_ring* ring, void* out);

/// Items in the ring now; exact on either side's own thread, a snapshot elsewhere.
/// Thread: any | Allocates: no | Lock-free: yes | Blocks: no
size_t hs_spsc_ring_size(const hs_spsc_ring* ring);
/// Capacity in items.
size_t hs_spsc_ring_capacity(const hs_spsc_ring* ring);
/// Bytes per item.
size_t hs_spsc_ring_elem_size(const hs_spsc_ring* ring);

#ifdef __cplusplus
}
#endif
#endif
