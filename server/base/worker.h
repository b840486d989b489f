// SPDX-License-Identifier: GPL-2.0-or-later
// A helper thread for short bursts of parallel work (the partial refactor's large supernodes,
// hs_cholesky_set_partial_parallel). A job is cut into tasks that write disjoint outputs; the
// caller and the helper take tasks from a shared counter, so the load balances itself and a slow
// or busy helper costs at most the task it holds. Between hs_worker_begin and hs_worker_end the
// helper spins (hand-over in well under a microsecond); otherwise it sleeps on a condition.
// Its functions have the shape of hs_parallel's (server/sparse/sparse.h), user being the worker.
#ifndef HS_WORKER_H
#define HS_WORKER_H

#include "base.h"

#include <stdint.h>

typedef struct hs_worker hs_worker;

/// Start the helper thread; init(arg) runs on it first (e.g. a BLAS call that maps the thread's
/// buffers during set-up rather than in the first job; NULL: none). Allocates: yes.
hs_status hs_worker_create(void (*init)(void* arg), void* arg, hs_worker** out);
/// Join the thread and release; accepts NULL, sets *w = NULL.
void hs_worker_destroy(hs_worker** w);
/// Wake the helper (user: the hs_worker): it polls for tasks until hs_worker_end.
void hs_worker_begin(void* user);
/// Let the helper sleep again (user: the hs_worker).
void hs_worker_end(void* user);
/// task(i, ctx) for every i in [0, n) (n < 65536), on this thread and, between begin and end,
/// the helper; returns when all have returned. Outside a burst every task runs here, in order.
void hs_worker_run(int n, void (*task)(int i, void* ctx), void* ctx, void* user);
/// Tasks the helper thread has run since it started.
int64_t hs_worker_tasks(const hs_worker* w);

#endif
