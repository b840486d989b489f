// SPDX-License-Identifier: GPL-2.0-or-later
// Lock-free SPSC primitives: triple buffer (never torn, monotonic, newest wins) and SPSC ring
// (in order, nothing lost or duplicated), hammered by two threads. Runs under ThreadSanitizer
// (ctest label tsan).
#define _POSIX_C_SOURCE 200809L
#include "spsc_ring.h"
#include "triple_buffer.h"
#include "base.h"
#include "test_macros.h"

#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <stdint.h>

// ---------------------------------------------------------------------------------------------
// Single-threaded behaviour and bad input.

static int TripleBufferBasics(void) {
    int64_t bytes = hs_byte_count();
    hs_err err = {0};
    hs_triple_buffer* tb = NULL;
    ENSURE(hs_triple_buffer_create(0, &tb, &err) == HS_ERR_INVALID && tb == NULL);
    ENSURE(strstr(err.msg, "elem_size") != NULL);
    ENSURE(hs_triple_buffer_create(8, NULL, &err) == HS_ERR_INVALID);
    hs_alloc_fail_after(2); // the slot array fails: nothing leaks
    ENSURE(hs_triple_buffer_create(8, &tb, &err) == HS_ERR_NOMEM && tb == NULL);
    hs_alloc_fail_after(0);
    ENSURE(hs_byte_count() == bytes);

    ENSURE(hs_triple_buffer_create(3 * sizeof(double), &tb, &err) == HS_OK);
    ENSURE(hs_triple_buffer_elem_size(tb) == 3 * sizeof(double));
    double v[3] = {9, 9, 9};
    ENSURE(hs_triple_buffer_read_copy(tb, v) == 0); // nothing published: zeros, not fresh
    ENSURE(v[0] == 0 && v[1] == 0 && v[2] == 0);
    for (int i = 1; i <= 5; ++i) {
        double w[3] = {i, 2 * i, 3 * i};
        hs_triple_buffer_write(tb, w);
    }
    ENSURE(hs_triple_buffer_read_copy(tb, v) == 1); // newest wins
    ENSURE(v[0] == 5 && v[1] == 10 && v[2] == 15);
    ENSURE(hs_triple_buffer_read_copy(tb, v) == 0); // same value, not fresh again
    ENSURE(v[0] == 5);
    double* back = hs_triple_buffer_back(tb); // in-place fill
    back[0] = 42;
    back[1] = back[2] = 0;
    hs_triple_buffer_publish(tb);
    int fresh = 0;
    const double* front = hs_triple_buffer_read(tb, &fresh);
    ENSURE(fresh == 1 && front[0] == 42);
    hs_triple_buffer_destroy(&tb);
    ENSURE(tb == NULL);
    hs_triple_buffer_destroy(&tb);
    hs_triple_buffer_destroy(NULL);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

static int RingBasics(void) {
    int64_t bytes = hs_byte_count();
    hs_err err = {0};
    hs_spsc_ring* r = NULL;
    ENSURE(hs_spsc_ring_create(4, 6, &r, &err) == HS_ERR_INVALID && r == NULL);
    ENSURE(strstr(err.msg, "power of two") != NULL);
    ENSURE(hs_spsc_ring_create(4, 1, &r, &err) == HS_ERR_INVALID);
    ENSURE(hs_spsc_ring_create(0, 8, &r, &err) == HS_ERR_INVALID);
    hs_alloc_fail_after(1);
    ENSURE(hs_spsc_ring_create(4, 8, &r, &err) == HS_ERR_NOMEM && r == NULL);
    hs_alloc_fail_after(0);
    ENSURE(hs_byte_count() == bytes);

    ENSURE(hs_spsc_ring_create(sizeof(int), 4, &r, &err) == HS_OK);
    ENSURE(hs_spsc_ring_capacity(r) == 4 && hs_spsc_ring_elem_size(r) == sizeof(int));
    int x = -1;
    ENSURE(hs_spsc_ring_pop(r, &x) == 0 && x == -1);
    int next_in = 0, next_out = 0;
    // Wrap around several times with the ring full and empty at each turn.
    for (int round = 0; round < 5; ++round) {
        for (int i = 0; i < 4; ++i, ++next_in) ENSURE(hs_spsc_ring_push(r, &next_in) == 1);
        ENSURE(hs_spsc_ring_size(r) == 4);
        ENSURE(hs_spsc_ring_push(r, &next_in) == 0); // full: refused, nothing overwritten
        for (int i = 0; i < 3; ++i) {
            ENSURE(hs_spsc_ring_pop(r, &x) == 1);
            ENSURE(x == next_out++);
        }
        ENSURE(hs_spsc_ring_push(r, &next_in) == 1);
        ++next_in;
        while (hs_spsc_ring_pop(r, &x)) ENSURE(x == next_out++);
        ENSURE(hs_spsc_ring_size(r) == 0);
    }
    ENSURE(next_out == next_in);
    hs_spsc_ring_destroy(&r);
    ENSURE(r == NULL);
    hs_spsc_ring_destroy(NULL);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Triple buffer under two threads: a 64-byte payload whose every word equals the sequence.

#define TB_WORDS     8
#define TB_PUBLISHES 2000000

typedef struct stamped {
    uint64_t w[TB_WORDS];
} stamped;

typedef struct tb_ctx {
    hs_triple_buffer* tb;
    atomic_int done;
} tb_ctx;

static void* tb_writer(void* arg) {
    tb_ctx* c = arg;
    for (uint64_t seq = 1; seq <= TB_PUBLISHES; ++seq) {
        stamped* s = hs_triple_buffer_back(c->tb);
        for (int i = 0; i < TB_WORDS; ++i) s->w[i] = seq;
        hs_triple_buffer_publish(c->tb);
    }
    atomic_store_explicit(&c->done, 1, memory_order_release);
    return NULL;
}

static int TripleBufferTwoThreads(void) {
    int64_t bytes = hs_byte_count();
    tb_ctx c;
    ENSURE(hs_triple_buffer_create(sizeof(stamped), &c.tb, NULL) == HS_OK);
    atomic_init(&c.done, 0);
    pthread_t th;
    ENSURE(pthread_create(&th, NULL, tb_writer, &c) == 0);
    uint64_t last = 0, reads = 0, fresh_reads = 0, torn = 0, backwards = 0, stale_fresh = 0;
    for (;;) {
        int finished = atomic_load_explicit(&c.done, memory_order_acquire);
        int fresh = 0;
        const stamped* s = hs_triple_buffer_read(c.tb, &fresh);
        ++reads;
        for (int i = 1; i < TB_WORDS; ++i) torn += s->w[i] != s->w[0];
        backwards += s->w[0] < last;
        if (fresh) {
            ++fresh_reads;
            stale_fresh += s->w[0] <= last; // a fresh value must be strictly newer
        } else {
            stale_fresh += s->w[0] != last; // not fresh: the same value as before
        }
        last = s->w[0];
        if (finished) break; // this read happened after the last publish
    }
    pthread_join(th, NULL);
    printf("  %llu reads, %llu fresh, last seq %llu\n", (unsigned long long)reads,
           (unsigned long long)fresh_reads, (unsigned long long)last);
    ENSURE(torn == 0);
    ENSURE(backwards == 0);
    ENSURE(stale_fresh == 0);
    ENSURE(last == TB_PUBLISHES); // after the writer finished, the newest value is visible
    ENSURE(fresh_reads >= 1 && fresh_reads <= TB_PUBLISHES);
    hs_triple_buffer_destroy(&c.tb);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Ring under two threads: 1e6 items through a small ring, in order, none lost or duplicated.

#define RING_ITEMS 1000000

typedef struct ring_item {
    uint64_t seq;
    uint64_t check; // ~seq: catches a half-copied item
    uint64_t pad[2];
} ring_item;

typedef struct ring_ctx {
    hs_spsc_ring* r;
    uint64_t full; // producer only: pushes refused because the ring was full
} ring_ctx;

static void* ring_producer(void* arg) {
    ring_ctx* c = arg;
    for (uint64_t seq = 0; seq < RING_ITEMS; ++seq) {
        ring_item it = {seq, ~seq, {seq, seq}};
        while (!hs_spsc_ring_push(c->r, &it)) {
            ++c->full;
            sched_yield();
        }
    }
    return NULL;
}

static int RingTwoThreads(void) {
    int64_t bytes = hs_byte_count();
    ring_ctx c = {NULL, 0};
    ENSURE(hs_spsc_ring_create(sizeof(ring_item), 256, &c.r, NULL) == HS_OK);
    pthread_t th;
    ENSURE(pthread_create(&th, NULL, ring_producer, &c) == 0);
    uint64_t expect = 0, bad = 0, empty = 0;
    while (expect < RING_ITEMS) {
        ring_item it;
        if (!hs_spsc_ring_pop(c.r, &it)) {
            ++empty;
            if ((empty & 63) == 0) sched_yield();
            continue;
        }
        bad +=
            it.seq != expect || it.check != ~expect || it.pad[0] != expect || it.pad[1] != expect;
        ++expect;
    }
    pthread_join(th, NULL);
    ring_item extra;
    int leftover = hs_spsc_ring_pop(c.r, &extra);
    printf("  %llu items, producer saw full %llu times, consumer empty %llu times\n",
           (unsigned long long)expect, (unsigned long long)c.full, (unsigned long long)empty);
    ENSURE(bad == 0);      // every item in order, whole (the loop above ran until all arrived)
    ENSURE(leftover == 0); // nothing duplicated beyond the last item
    ENSURE(hs_spsc_ring_size(c.r) == 0);
    hs_spsc_ring_destroy(&c.r);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

HS_TEST_MAIN(HS_CASE(TripleBufferBasics), HS_CASE(RingBasics), HS_CASE(TripleBufferTwoThreads),
             HS_CASE(RingTwoThreads))
