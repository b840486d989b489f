// SPDX-License-Identifier: GPL-2.0-or-later
// The 1 kHz loop thread (see rt_thread.h for the design). mlockall, SCHED_FIFO and
// clock_nanosleep(TIMER_ABSTIME) live here together.
#define _GNU_SOURCE
#include "rt_thread.h"

#include <errno.h>
#include <pthread.h>
#include <sched.h>
#include <stdatomic.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/resource.h>
#include <time.h>
#include <unistd.h>

#define RT_COOKIE         0x4b1d
#define RT_PREFAULT_BYTES (64 * 1024) // stack the tick may touch, faulted in before the first tick

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define RT_SANITIZED 1
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define RT_SANITIZED 1
#endif
#endif
#ifndef RT_SANITIZED
#define RT_SANITIZED 0
#endif

// Histogram written by the rt thread only. Plain load + store (no read-modify-write) suffices for
// a single writer; readers on other threads load each word atomically.
typedef struct rt_hist {
    _Atomic uint64_t count[HS_RT_HIST_BINS + 1];
    _Atomic int64_t max_ns;
    _Atomic int64_t recent_ns[HS_RT_HIST_RECENT]; // see hs_rt_hist
    _Atomic uint64_t recent_seq[HS_RT_HIST_RECENT];
} rt_hist;

struct hs_rt_loop {
    hs_rt_def def;
    int64_t period_ns;
    pthread_t thread;
    int started; // control thread only
    int joined;  // control thread only
    atomic_int stop;
    atomic_int running;
    _Atomic uint32_t obtained;
    atomic_int fifo_priority;
    _Atomic int64_t start_ns;
    _Atomic int64_t last_ns;
    _Atomic int64_t ticks;
    _Atomic int64_t overruns;
    _Atomic int64_t missed;
    _Atomic int64_t wake_late_max_ns;
    rt_hist tick_hist;
    rt_hist period_hist;
};

hs_rt_def hs_rt_default_def(void) {
    hs_rt_def d;
    memset(&d, 0, sizeof d);
    d.rate_hz = 1000.0;
    d.fifo_priority = 80;
    d.lock_memory = 1;
    d.max_ticks = 0;
    d.cookie = RT_COOKIE;
    return d;
}

static void add_relaxed(_Atomic int64_t* a, int64_t v) {
    atomic_store_explicit(a, atomic_load_explicit(a, memory_order_relaxed) + v,
                          memory_order_relaxed);
}

static void hist_add(rt_hist* h, int64_t ns) {
    if (ns < 0) ns = 0;
    int64_t bin = ns / 1000;
    if (bin > HS_RT_HIST_BINS) bin = HS_RT_HIST_BINS;
    _Atomic uint64_t* c = &h->count[bin];
    const uint64_t k = atomic_load_explicit(c, memory_order_relaxed) + 1;
    if (bin == HS_RT_HIST_BINS) { // a reader that sees the new seq sees this ns
        const int slot = (int)(k % HS_RT_HIST_RECENT);
        atomic_store_explicit(&h->recent_seq[slot], 0, memory_order_relaxed);
        atomic_thread_fence(memory_order_release);
        atomic_store_explicit(&h->recent_ns[slot], ns, memory_order_relaxed);
        atomic_store_explicit(&h->recent_seq[slot], k, memory_order_release);
    }
    // Release for the overflow bin: a reader that sees count k sees sample k in the ring.
    atomic_store_explicit(c, k,
                          bin == HS_RT_HIST_BINS ? memory_order_release : memory_order_relaxed);
    if (ns > atomic_load_explicit(&h->max_ns, memory_order_relaxed))
        atomic_store_explicit(&h->max_ns, ns, memory_order_relaxed);
}

static void hist_copy(const rt_hist* h, hs_rt_hist* out) {
    for (int i = 0; i < HS_RT_HIST_BINS; ++i)
        out->count[i] = atomic_load_explicit(&h->count[i], memory_order_relaxed);
    out->count[HS_RT_HIST_BINS] = // acquire: then the ring holds every sample counted
        atomic_load_explicit(&h->count[HS_RT_HIST_BINS], memory_order_acquire);
    out->max_ns = atomic_load_explicit(&h->max_ns, memory_order_relaxed);
    for (int k = 0; k < HS_RT_HIST_RECENT; ++k) { // a slot rewritten meanwhile reads as unused
        uint64_t s1 = atomic_load_explicit(&h->recent_seq[k], memory_order_acquire);
        int64_t ns = atomic_load_explicit(&h->recent_ns[k], memory_order_relaxed);
        atomic_thread_fence(memory_order_acquire);
        uint64_t s2 = atomic_load_explicit(&h->recent_seq[k], memory_order_relaxed);
        out->recent_ns[k] = ns;
        out->recent_seq[k] = s1 == s2 ? s1 : 0;
    }
}

static int64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

// Touch the stack the ticks will use so the first ticks take no page faults.
__attribute__((noinline)) static void prefault_stack(void) {
    volatile unsigned char buf[RT_PREFAULT_BYTES];
    for (size_t i = 0; i < sizeof buf; i += 1024) buf[i] = 0;
}

static void* rt_main(void* arg) {
    hs_rt_loop* L = arg;
    const hs_rt_tick tick = L->def.tick;
    const int64_t period = L->period_ns;
    const int64_t max_ticks = L->def.max_ticks;

    pthread_setname_np(pthread_self(), "hs-rt"); // for top -H, perf, gdb
    prefault_stack();
    atomic_fetch_or_explicit(&L->obtained, HS_RT_PREFAULTED, memory_order_relaxed);
    if (tick.on_start) tick.on_start(tick.ctx);

    int64_t start = now_ns();
    int64_t prev = start;
    int64_t deadline = start + period;
    atomic_store_explicit(&L->start_ns, start, memory_order_relaxed);
    int64_t n = atomic_load_explicit(&L->ticks, memory_order_relaxed); // a restart counts on
    while (!atomic_load_explicit(&L->stop, memory_order_acquire) &&
           (max_ticks == 0 || n < max_ticks)) {
        struct timespec ts = {(time_t)(deadline / 1000000000), (long)(deadline % 1000000000)};
        while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR) {
        }
        int64_t now = now_ns();
        hs_rt_clock clk = {n, now, deadline, (double)(now - prev) * 1e-9};
        if (tick.fn) tick.fn(tick.ctx, &clk);
        int64_t end = now_ns();

        int64_t err = now - prev - period;
        hist_add(&L->period_hist, err < 0 ? -err : err);
        hist_add(&L->tick_hist, end - now);
        if (now - deadline > atomic_load_explicit(&L->wake_late_max_ns, memory_order_relaxed))
            atomic_store_explicit(&L->wake_late_max_ns, now - deadline, memory_order_relaxed);
        prev = now;
        deadline += period;
        if (end >= deadline) {
            // Overrun: the next deadline(s) already passed. Skip them, so the loop resumes on
            // its grid with one tick (and one measured, longer dt) instead of a burst.
            int64_t skip = (end - deadline) / period + 1;
            deadline += skip * period;
            add_relaxed(&L->overruns, 1);
            add_relaxed(&L->missed, skip);
        }
        ++n;
        atomic_store_explicit(&L->last_ns, now, memory_order_relaxed);
        atomic_store_explicit(&L->ticks, n, memory_order_release);
    }
    if (tick.on_stop) tick.on_stop(tick.ctx);
    atomic_store_explicit(&L->running, 0, memory_order_release);
    return NULL;
}

hs_status hs_rt_loop_create(const hs_rt_def* def, hs_rt_loop** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "hs_rt_loop_create: out is NULL");
    *out = NULL;
    if (!def || def->cookie != RT_COOKIE)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_rt_loop_create: def not initialised with hs_rt_default_def()");
    if (!(def->rate_hz >= 1.0 && def->rate_hz <= 100000.0))
        return hs_err_set(err, HS_ERR_INVALID, "hs_rt_loop_create: rate_hz %g not in [1, 1e5]",
                          def->rate_hz);
    if (def->fifo_priority < 0 || def->fifo_priority > 99 || def->max_ticks < 0)
        return hs_err_set(err, HS_ERR_INVALID,
                          "hs_rt_loop_create: fifo_priority %d not in [0, 99] or max_ticks < 0",
                          def->fifo_priority);
    hs_rt_loop* L = hs_calloc(1, sizeof *L);
    if (!L) return hs_err_set(err, HS_ERR_NOMEM, "hs_rt_loop_create: out of memory");
    L->def = *def;
    L->period_ns = (int64_t)(1e9 / def->rate_hz + 0.5);
    *out = L;
    return HS_OK;
}

void hs_rt_loop_destroy(hs_rt_loop** loop) {
    if (!loop || !*loop) return;
    hs_rt_loop_stop(*loop);
    hs_free(*loop);
    *loop = NULL;
}

// Lock memory when it cannot backfire: without CAP_IPC_LOCK a finite RLIMIT_MEMLOCK would make
// every later allocation beyond it fail (MCL_FUTURE); sanitizers map terabytes of shadow.
static int lock_memory(void) {
    if (RT_SANITIZED) return 0;
    struct rlimit rl;
    if (geteuid() != 0 && (getrlimit(RLIMIT_MEMLOCK, &rl) != 0 || rl.rlim_cur != RLIM_INFINITY))
        return 0;
    return mlockall(MCL_CURRENT | MCL_FUTURE) == 0;
}

hs_status hs_rt_loop_start(hs_rt_loop* L, hs_err* err) {
    if (!L) return hs_err_set(err, HS_ERR_INVALID, "hs_rt_loop_start: loop is NULL");
    if (L->started && !L->joined)
        return hs_err_set(err, HS_ERR_INVALID, "hs_rt_loop_start: already started");
    L->started = L->joined = 0; // a stopped loop starts again
    atomic_store(&L->stop, 0);
    uint32_t obtained = 0;
    if (L->def.lock_memory && lock_memory()) obtained |= HS_RT_MLOCKED;
    atomic_store(&L->running, 1);
    int rc = EPERM;
    if (L->def.fifo_priority > 0) {
        pthread_attr_t attr;
        pthread_attr_init(&attr);
        struct sched_param sp;
        memset(&sp, 0, sizeof sp);
        int lo = sched_get_priority_min(SCHED_FIFO), hi = sched_get_priority_max(SCHED_FIFO);
        sp.sched_priority = L->def.fifo_priority < lo   ? lo
                            : L->def.fifo_priority > hi ? hi
                                                        : L->def.fifo_priority;
        if (pthread_attr_setinheritsched(&attr, PTHREAD_EXPLICIT_SCHED) == 0 &&
            pthread_attr_setschedpolicy(&attr, SCHED_FIFO) == 0 &&
            pthread_attr_setschedparam(&attr, &sp) == 0)
            rc = pthread_create(&L->thread, &attr, rt_main, L);
        pthread_attr_destroy(&attr);
        if (rc == 0) {
            obtained |= HS_RT_SCHED_FIFO;
            atomic_store(&L->fifo_priority, sp.sched_priority);
        }
    }
    // Not permitted (EPERM) or not asked: the same loop at normal priority, quietly.
    if (rc != 0) rc = pthread_create(&L->thread, NULL, rt_main, L);
    if (rc != 0) {
        atomic_store(&L->running, 0);
        return hs_err_set(err, HS_ERR_INVALID, "hs_rt_loop_start: pthread_create failed: %s",
                          strerror(rc));
    }
    atomic_fetch_or(&L->obtained, obtained);
    L->started = 1;
    return HS_OK;
}

void hs_rt_loop_stop(hs_rt_loop* L) {
    if (!L) return;
    atomic_store_explicit(&L->stop, 1, memory_order_release);
    hs_rt_loop_wait(L);
}

void hs_rt_loop_wait(hs_rt_loop* L) {
    if (!L || !L->started || L->joined) return;
    pthread_join(L->thread, NULL);
    L->joined = 1;
}

int hs_rt_loop_running(const hs_rt_loop* L) {
    return atomic_load_explicit(&L->running, memory_order_acquire);
}

void hs_rt_loop_stats(const hs_rt_loop* L, hs_rt_stats* out) {
    out->obtained = atomic_load_explicit(&L->obtained, memory_order_relaxed);
    out->fifo_priority = atomic_load_explicit(&L->fifo_priority, memory_order_relaxed);
    out->period_s = (double)L->period_ns * 1e-9;
    out->ticks = atomic_load_explicit(&L->ticks, memory_order_acquire);
    out->start_ns = atomic_load_explicit(&L->start_ns, memory_order_relaxed);
    out->last_ns = atomic_load_explicit(&L->last_ns, memory_order_relaxed);
    out->overruns = atomic_load_explicit(&L->overruns, memory_order_relaxed);
    out->missed_deadlines = atomic_load_explicit(&L->missed, memory_order_relaxed);
    out->wake_late_max_ns = atomic_load_explicit(&L->wake_late_max_ns, memory_order_relaxed);
    hist_copy(&L->tick_hist, &out->tick);
    hist_copy(&L->period_hist, &out->period_err);
}

hs_status hs_rt_bare_loop(const hs_rt_def* def, int64_t n_ticks, hs_rt_stats* out, hs_err* err) {
    if (!def || !out || n_ticks <= 0)
        return hs_err_set(err, HS_ERR_INVALID, "hs_rt_bare_loop: NULL def/out or n_ticks <= 0");
    hs_rt_def d = *def;
    memset(&d.tick, 0, sizeof d.tick);
    d.max_ticks = n_ticks;
    hs_rt_loop* L = NULL;
    hs_status st = hs_rt_loop_create(&d, &L, err);
    if (st != HS_OK) return st;
    st = hs_rt_loop_start(L, err);
    if (st == HS_OK) {
        hs_rt_loop_wait(L);
        hs_rt_loop_stats(L, out);
    }
    hs_rt_loop_destroy(&L);
    return st;
}
