// SPDX-License-Identifier: GPL-2.0-or-later
// Triple buffer: one writer, one reader, the latest value wins (pose, snapshot, haptic model).
//
// DESIGN. Three slots of elem_size bytes. The writer owns the back slot, the reader the front
// slot; the third ("middle") index lives in one atomic word with a fresh bit. Publishing swaps
// back and middle and sets the bit (acq_rel exchange); reading swaps front and middle only when
// the bit is set. Neither side ever waits and a slot is never read while written, so values are
// never torn. Values older than the newest are overwritten unread: use hs_spsc_ring when nothing
// may be dropped.
#ifndef HS_BASE_TRIPLE_BUFFER_H
#define HS_BASE_TRIPLE_BUFFER_H

#include "base.h"

#ifdef __cplusplus
extern "C" {
#endif

typedef struct hs_triple_buffer hs_triple_buffer;

/// Create with three zeroed slots of elem_size bytes (> 0). @param out OUT
/// Thread: any | Allocates: yes
hs_status hs_triple_buffer_create(size_t elem_size, hs_triple_buffer** out, hs_err* err);
/// Release; accepts NULL or *tb == NULL and sets *tb = NULL. Both sides must have stopped.
void hs_triple_buffer_destroy(hs_triple_buffer** tb);
/// Bytes per value.
size_t hs_triple_buffer_elem_size(const hs_triple_buffer* tb);

/// The back slot for the writer to fill in place; valid until the next publish.
/// Thread: writer only | Allocates: no | Lock-free: yes | Blocks: no
void* hs_triple_buffer_back(hs_triple_buffer* tb);
/// Hand the filled back slot to the reader (it becomes the newest value).
/// Thread: writer only | Allocates: no | Lock-free: yes | Blocks: no
void hs_triple_buffer_publish(hs_triple_buffer* tb);
/// Copy elem_size bytes from value into the back slot and publish.
/// Thread: writer only | Allocates: no | Lock-free: yes | Blocks: no
void hs_triple_buffer_write(hs_triple_buffer* tb, const void* value);

/// Take the newest value if one was published since the last call; return the front slot
/// (zeroed before the first publish), valid until the next read. *fresh (may be NULL) is 1 when
/// the returned value is new to this reader.
/// Thread: reader only | Allocates: no | Lock-free: yes | Blocks: no
const void* hs_triple_buffer_read(hs_triple_buffer* tb, int* fresh);
/// As hs_triple_buffer_read, copying the front slot to out. Returns 1 when it is new, else 0.
/// Thread: reader only | Allocates: no | Lock-free: yes | Blocks: no
int hs_triple_buffer_read_copy(hs_triple_buffer* tb, void* out);

#ifdef __cplusplus
}
#endif
#endif
