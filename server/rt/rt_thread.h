// SPDX-License-Identifier: GPL-2.0-or-later
// rt: the 1 kHz loop thread.
//
// DESIGN. One thread, started by hs_rt_loop_start, sleeps with clock_nanosleep(CLOCK_MONOTONIC,
// TIMER_ABSTIME) until each absolute deadline (start + k * period), measures the real time since
// the previous wake (dt), and calls the tick callback with it. It asks for SCHED_FIFO and
// mlockall(MCL_CURRENT | MCL_FUTURE) and prefaults its stack, and falls back quietly when the OS
// refuses (hs_rt_stats.obtained says what it got). After an overrun it skips the deadlines that
// already passed instead of running a burst of late ticks, and counts them.
// Owns: its statistics (single writer, read by any thread through atomics). Crosses: nothing
// itself; the tick callback reads its inputs from triple buffers and writes outputs to triple
// buffers and rings (see haptic_rt.h). Never on this thread: malloc, locks, printf, LCM.
#ifndef HS_RT_RT_THREAD_H
#define HS_RT_RT_THREAD_H

#include "base.h"
#include "haptic.h"

#ifdef __cplusplus
extern "C" {
#endif

/// Time as the tick sees it.
typedef struct hs_rt_clock {
    int64_t tick;        ///< 0, 1, 2, ... (ticks run, not deadlines)
    int64_t now_ns;      ///< wake time of this tick, CLOCK_MONOTONIC ns
    int64_t deadline_ns; ///< the deadline it woke for, ns
    double dt_s;         ///< measured time since the previous wake (first tick: since start), s
} hs_rt_clock;

/// The work done every tick, plugged in as a function and a context.
typedef struct hs_rt_tick {
    /// One tick. NULL: an empty tick (the bare loop). Thread: rt | Allocates: no | Blocks: no
    void (*fn)(void* ctx, const hs_rt_clock* clk);
    void* ctx;
    /// Called on the rt thread before the first tick and after the last one; may be NULL.
    void (*on_start)(void* ctx);
    void (*on_stop)(void* ctx);
} hs_rt_tick;

/// Loop options. Initialise with hs_rt_default_def().
typedef struct hs_rt_def {
    double rate_hz;    ///< tick rate, Hz (default 1000)
    int fifo_priority; ///< SCHED_FIFO priority to ask for, 1..99 (default 80); 0: do not ask
    int lock_memory;   ///< 1 (default): mlockall(MCL_CURRENT | MCL_FUTURE) when permitted. It is
                       ///< process-wide and kept; skipped in sanitizer builds and when the
                       ///< RLIMIT_MEMLOCK limit would make later allocations fail
    int64_t max_ticks; ///< stop by itself after this many ticks (in all, across restarts); 0:
                       ///< run until hs_rt_loop_stop
    hs_rt_tick tick;   ///< the work
    int cookie;        ///< set by hs_rt_default_def
} hs_rt_def;

/// Defaults: 1 kHz, SCHED_FIFO priority 80, lock memory, run until stopped, empty tick.
hs_rt_def hs_rt_default_def(void);

typedef struct hs_rt_loop hs_rt_loop;

/// Allocate a loop (statistics included); nothing runs yet. @param out OUT
/// Thread: any | Allocates: yes
hs_status hs_rt_loop_create(const hs_rt_def* def, hs_rt_loop** out, hs_err* err);
/// Stop if running, then release; accepts NULL or *loop == NULL and sets *loop = NULL.
void hs_rt_loop_destroy(hs_rt_loop** loop);
/// Start the thread; again after a stop, when the tick count and statistics go on from where
/// they were. Thread: control | Allocates: thread stack
hs_status hs_rt_loop_start(hs_rt_loop* loop, hs_err* err);
/// Ask the loop to stop (atomic flag, seen within one period) and join it. Idempotent.
/// Thread: control | Blocks: yes (join)
void hs_rt_loop_stop(hs_rt_loop* loop);
/// Join a loop that stops by itself (max_ticks > 0). Thread: control | Blocks: yes
void hs_rt_loop_wait(hs_rt_loop* loop);
/// 1 while the thread runs ticks. Thread: any | Lock-free: yes
int hs_rt_loop_running(const hs_rt_loop* loop);
/// Copy the statistics out; consistent per field, the histograms may trail the counters by a
/// tick while the loop runs. Thread: any | Allocates: no | Lock-free: yes | Blocks: no
void hs_rt_loop_stats(const hs_rt_loop* loop, hs_rt_stats* out /* OUT */);

/// Benchmark reference: run the same scheduling (same def: rate, priority, memory locking) with
/// an empty tick for n_ticks on a new thread and return its statistics. Blocks for the run.
/// Thread: control | Allocates: yes, before the run
hs_status hs_rt_bare_loop(const hs_rt_def* def, int64_t n_ticks, hs_rt_stats* out /* OUT */,
                          hs_err* err);

#ifdef __cplusplus
}
#endif
#endif
