// SPDX-License-Identifier: GPL-2.0-or-later
// Triple buffer (see triple_buffer.h for the design).
#include "triple_buffer.h"

#include <stdatomic.h>
#include <string.h>

#define TB_FRESH 4u // bit next to the 2-bit slot index in tb->middle
#define TB_LINE  64

struct hs_triple_buffer {
    // Reader and writer fields sit on separate cache lines so the two threads do not fight.
    atomic_uint middle; // slot index | TB_FRESH
    char pad0[TB_LINE - sizeof(atomic_uint)];
    unsigned back; // writer only
    char pad1[TB_LINE - sizeof(unsigned)];
    unsigned front; // reader only
    char pad2[TB_LINE - sizeof(unsigned)];
    size_t elem_size;
    size_t stride;       // elem_size rounded up to a cache line
    unsigned char* data; // 3 * stride bytes
};

hs_status hs_triple_buffer_create(size_t elem_size, hs_triple_buffer** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "hs_triple_buffer_create: out is NULL");
    *out = NULL;
    if (elem_size == 0 || elem_size > ((size_t)1 << 30))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_triple_buffer_create: elem_size %zu not in [1, 2^30]", elem_size);
    hs_triple_buffer* tb = hs_calloc(1, sizeof *tb);
    size_t stride = (elem_size + TB_LINE - 1) / TB_LINE * TB_LINE;
    unsigned char* data = tb ? hs_calloc(3, stride) : NULL;
    if (!data) {
        hs_free(tb);
        return hs_err_set(err, HS_ERR_NOMEM, "hs_triple_buffer_create: out of memory (%zu bytes)",
                          3 * stride);
    }
    tb->elem_size = elem_size;
    tb->stride = stride;
    tb->data = data;
    tb->back = 0;
    atomic_init(&tb->middle, 1u);
    tb->front = 2;
    *out = tb;
    return HS_OK;
}

void hs_triple_buffer_destroy(hs_triple_buffer** tb) {
    if (!tb || !*tb) return;
    hs_free((*tb)->data);
    hs_free(*tb);
    *tb = NULL;
}

size_t hs_triple_buffer_elem_size(const hs_triple_buffer* tb) {
    return tb->elem_size;
}

void* hs_triple_buffer_back(hs_triple_buffer* tb) {
    return tb->data + tb->back * tb->stride;
}

void hs_triple_buffer_publish(hs_triple_buffer* tb) {
    // release: our writes to the back slot become visible with the index;
    // acquire: the reader's last reads of the slot we receive happened before we overwrite it.
    unsigned old = atomic_exchange_explicit(&tb->middle, tb->back | TB_FRESH, memory_order_acq_rel);
    tb->back = old & 3u;
}

void hs_triple_buffer_write(hs_triple_buffer* tb, const void* value) {
    memcpy(hs_triple_buffer_back(tb), value, tb->elem_size);
    hs_triple_buffer_publish(tb);
}

const void* hs_triple_buffer_read(hs_triple_buffer* tb, int* fresh) {
    int is_new = 0;
    // A relaxed peek first: the common "nothing new" case costs one load and no cache-line write.
    if (atomic_load_explicit(&tb->middle, memory_order_relaxed) & TB_FRESH) {
        unsigned old = atomic_exchange_explicit(&tb->middle, tb->front, memory_order_acq_rel);
        tb->front = old & 3u;
        is_new = (old & TB_FRESH) != 0;
    }
    if (fresh) *fresh = is_new;
    return tb->data + tb->front * tb->stride;
}

int hs_triple_buffer_read_copy(hs_triple_buffer* tb, void* out) {
    int fresh = 0;
    const void* p = hs_triple_buffer_read(tb, &fresh);
    memcpy(out, p, tb->elem_size);
    return fresh;
}
