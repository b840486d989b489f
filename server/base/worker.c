// SPDX-License-Identifier: GPL-2.0-or-later
#include "worker.h"

#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>

struct hs_worker {
    pthread_t th;
    pthread_mutex_t mu;
    pthread_cond_t cv;
    atomic_int spin; // a burst is running: poll for work (set under mu, cleared without)
    int quit;        // under mu
    int ready;       // under mu: init has returned
    uint32_t seq;    // caller's count of postings
    // Posting seq, next task to take and task count in one word, so that a task is taken only
    // from the posting the taker saw: seq << 32 | next << 16 | n.
    _Atomic uint64_t ticket;
    atomic_int finished; // tasks of the current posting the helper has completed
    atomic_llong helped; // tasks the helper has run, in all
    void (*task)(int i, void* ctx);
    void* ctx;
    void (*init)(void* arg);
    void* init_arg;
};

static inline void cpu_relax(void) {
#if defined(__x86_64__) || defined(__i386__)
    __builtin_ia32_pause();
#endif
}

// Take the next task of posting seq; -1 when none is left (or a newer posting came).
static int take(hs_worker* w, uint64_t seq) {
    uint64_t v = atomic_load_explicit(&w->ticket, memory_order_acquire);
    for (;;) {
        unsigned next = (unsigned)(v >> 16) & 0xffffu, n = (unsigned)v & 0xffffu;
        if ((v >> 32) != seq || next >= n) return -1;
        if (atomic_compare_exchange_weak_explicit(&w->ticket, &v, v + (1u << 16),
                                                  memory_order_acq_rel, memory_order_acquire))
            return (int)next;
    }
}

static void* worker_main(void* arg) {
    hs_worker* w = arg;
    uint64_t seen = 0;
    unsigned idle = 0;
    if (w->init) w->init(w->init_arg);
    pthread_mutex_lock(&w->mu);
    w->ready = 1;
    pthread_cond_broadcast(&w->cv);
    pthread_mutex_unlock(&w->mu);
    for (;;) {
        pthread_mutex_lock(&w->mu);
        while (!atomic_load(&w->spin) && !w->quit) pthread_cond_wait(&w->cv, &w->mu);
        int quit = w->quit;
        pthread_mutex_unlock(&w->mu);
        if (quit) return NULL;
        while (atomic_load_explicit(&w->spin, memory_order_acquire)) {
            uint64_t seq = atomic_load_explicit(&w->ticket, memory_order_acquire) >> 32;
            if (seq == seen) {
                // Yield now and then: woken onto the caller's core, it would otherwise spin
                // there until the scheduler moves it.
                if ((++idle & 63) == 0)
                    sched_yield();
                else
                    cpu_relax();
                continue;
            }
            seen = seq;
            // Holding a task keeps the caller from posting again, so task and ctx are this
            // posting's while it runs.
            for (int i; (i = take(w, seq)) >= 0;) {
                w->task(i, w->ctx);
                atomic_fetch_add_explicit(&w->helped, 1, memory_order_relaxed);
                atomic_fetch_add_explicit(&w->finished, 1, memory_order_release);
            }
        }
    }
}

hs_status hs_worker_create(void (*init)(void* arg), void* arg, hs_worker** out) {
    if (!out) return HS_ERR_INVALID;
    hs_worker* w = hs_calloc(1, sizeof *w);
    if (!w) return HS_ERR_NOMEM;
    w->init = init;
    w->init_arg = arg;
    if (pthread_mutex_init(&w->mu, NULL) != 0) {
        hs_free(w);
        return HS_ERR_NOMEM;
    }
    if (pthread_cond_init(&w->cv, NULL) != 0) {
        pthread_mutex_destroy(&w->mu);
        hs_free(w);
        return HS_ERR_NOMEM;
    }
    if (pthread_create(&w->th, NULL, worker_main, w) != 0) {
        pthread_cond_destroy(&w->cv);
        pthread_mutex_destroy(&w->mu);
        hs_free(w);
        return HS_ERR_NOMEM;
    }
    pthread_mutex_lock(&w->mu);
    while (!w->ready) pthread_cond_wait(&w->cv, &w->mu);
    pthread_mutex_unlock(&w->mu);
    *out = w;
    return HS_OK;
}

void hs_worker_destroy(hs_worker** pw) {
    hs_worker* w = pw ? *pw : NULL;
    if (!w) return;
    pthread_mutex_lock(&w->mu);
    w->quit = 1;
    atomic_store(&w->spin, 0);
    pthread_cond_signal(&w->cv);
    pthread_mutex_unlock(&w->mu);
    pthread_join(w->th, NULL);
    pthread_cond_destroy(&w->cv);
    pthread_mutex_destroy(&w->mu);
    hs_free(w);
    *pw = NULL;
}

void hs_worker_begin(void* user) {
    hs_worker* w = user;
    pthread_mutex_lock(&w->mu);
    atomic_store(&w->spin, 1);
    pthread_cond_signal(&w->cv);
    pthread_mutex_unlock(&w->mu);
}

void hs_worker_end(void* user) {
    hs_worker* w = user;
    atomic_store_explicit(&w->spin, 0, memory_order_release);
}

void hs_worker_run(int n, void (*task)(int i, void* ctx), void* ctx, void* user) {
    hs_worker* w = user;
    uint64_t seq = ++w->seq;
    w->task = task;
    w->ctx = ctx;
    atomic_store_explicit(&w->finished, 0, memory_order_relaxed);
    atomic_store_explicit(&w->ticket, seq << 32 | (uint64_t)n, memory_order_release);
    int mine = 0;
    for (int i; (i = take(w, seq)) >= 0; mine++) task(i, ctx);
    while (atomic_load_explicit(&w->finished, memory_order_acquire) != n - mine) cpu_relax();
}

int64_t hs_worker_tasks(const hs_worker* w) {
    return w ? (int64_t)atomic_load(&w->helped) : 0;
}
