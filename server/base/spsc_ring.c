// SPDX-License-Identifier: GPL-2.0-or-later
// SPSC ring (see spsc_ring.h for the design).
#include "spsc_ring.h"

#include <stdatomic.h>
#include <string.h>

#define RING_LINE 64

struct hs_spsc_ring {
    atomic_size_t head; // next index to write; producer stores, consumer loads
    char pad0[RING_LINE - sizeof(atomic_size_t)];
    atomic_size_t tail; // next index to read; consumer stores, producer loads
    char pad1[RING_LINE - sizeof(atomic_size_t)];
    size_t tail_cache; // producer only: last tail it saw
    char pad2[RING_LINE - sizeof(size_t)];
    size_t head_cache; // consumer only: last head it saw
    char pad3[RING_LINE - sizeof(size_t)];
    size_t mask; // capacity - 1
    size_t elem_size;
    unsigned char* data; // capacity * elem_size bytes
};

hs_status hs_spsc_ring_create(size_t elem_size, size_t capacity, hs_spsc_ring** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "hs_spsc_ring_create: out is NULL");
    *out = NULL;
    if (elem_size == 0 || elem_size > ((size_t)1 << 30))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_spsc_ring_create: elem_size %zu not in [1, 2^30]", elem_size);
    if (capacity < 2 || (capacity & (capacity - 1)) != 0 || capacity > ((size_t)1 << 40))
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_spsc_ring_create: capacity %zu is not a power of two in [2, 2^40]",
                          capacity);
    hs_spsc_ring* r = hs_calloc(1, sizeof *r);
    unsigned char* data = r ? hs_calloc(capacity, elem_size) : NULL;
    if (!data) {
        hs_free(r);
        return hs_err_set(err, HS_ERR_NOMEM, "hs_spsc_ring_create: out of memory (%zu x %zu bytes)",
                          capacity, elem_size);
    }
    atomic_init(&r->head, 0);
    atomic_init(&r->tail, 0);
    r->mask = capacity - 1;
    r->elem_size = elem_size;
    r->data = data;
    *out = r;
    return HS_OK;
}

void hs_spsc_ring_destroy(hs_spsc_ring** ring) {
    if (!ring || !*ring) return;
    hs_free((*ring)->data);
    hs_free(*ring);
    *ring = NULL;
}

int hs_spsc_ring_push(hs_spsc_ring* r, const void* item) {
    size_t head = atomic_load_explicit(&r->head, memory_order_relaxed);
    if (head - r->tail_cache > r->mask) {
        // Looks full: refresh tail. acquire pairs with the consumer's release after its copy-out.
        r->tail_cache = atomic_load_explicit(&r->tail, memory_order_acquire);
        if (head - r->tail_cache > r->mask) return 0;
    }
    memcpy(r->data + (head & r->mask) * r->elem_size, item, r->elem_size);
    atomic_store_explicit(&r->head, head + 1, memory_order_release);
    return 1;
}

int hs_spsc_ring_pop(hs_spsc_ring* r, void* out) {
    size_t tail = atomic_load_explicit(&r->tail, memory_order_relaxed);
    if (tail == r->head_cache) {
        r->head_cache = atomic_load_explicit(&r->head, memory_order_acquire);
        if (tail == r->head_cache) return 0;
    }
    memcpy(out, r->data + (tail & r->mask) * r->elem_size, r->elem_size);
    atomic_store_explicit(&r->tail, tail + 1, memory_order_release);
    return 1;
}

size_t hs_spsc_ring_size(const hs_spsc_ring* r) {
    // Load tail first: head only grows, so head - tail cannot underflow.
    size_t tail = atomic_load_explicit(&r->tail, memory_order_acquire);
    size_t head = atomic_load_explicit(&r->head, memory_order_acquire);
    return head - tail;
}

size_t hs_spsc_ring_capacity(const hs_spsc_ring* r) {
    return r->mask + 1;
}
size_t hs_spsc_ring_elem_size(const hs_spsc_ring* r) {
    return r->elem_size;
}
