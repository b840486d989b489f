// SPDX-License-Identifier: MIT
// hapsim protocol: the index logic of a triple buffer (one writer, one reader, wait-free, the
// latest value wins, never torn) over three slots the caller keeps, e.g. T slot[3]. The writer
// fills slot[back] and publishes; the reader takes and reads slot[front]. The third index lives
// with a fresh bit in one atomic word: publishing swaps back and middle and sets the bit
// (acq_rel: the slot's contents travel with its index); taking swaps front and middle only
// when the bit is set. Header only; used where a driver hands the newest force model from its
// receiving thread to its servo loop.
#ifndef HAPSIM_TRIPLE_H
#define HAPSIM_TRIPLE_H

#include <stdatomic.h>

#define HAPSIM_TRIPLE_FRESH 4u

/// Slot indices. Initialise with hapsim_triple_init before either side starts.
typedef struct hapsim_triple {
    atomic_uint middle; ///< index of the middle slot | HAPSIM_TRIPLE_FRESH when unread
    unsigned back;      ///< the writer's slot (writer only)
    unsigned front;     ///< the reader's slot (reader only)
} hapsim_triple;

static inline void hapsim_triple_init(hapsim_triple* t) {
    atomic_init(&t->middle, 1u);
    t->back = 0;
    t->front = 2;
}

/// The writer filled slot[t->back]: make it the newest; t->back names a free slot after.
/// Thread: writer only | Lock-free: yes
static inline void hapsim_triple_publish(hapsim_triple* t) {
    unsigned old =
        atomic_exchange_explicit(&t->middle, t->back | HAPSIM_TRIPLE_FRESH, memory_order_acq_rel);
    t->back = old & 3u;
}

/// 1 when a value newer than the last taken was published: slot[t->front] now holds it; 0
/// otherwise (slot[t->front] unchanged). Thread: reader only | Lock-free: yes
static inline int hapsim_triple_take(hapsim_triple* t) {
    if (!(atomic_load_explicit(&t->middle, memory_order_relaxed) & HAPSIM_TRIPLE_FRESH)) return 0;
    unsigned old = atomic_exchange_explicit(&t->middle, t->front, memory_order_acq_rel);
    t->front = old & 3u;
    return 1;
}

#endif
