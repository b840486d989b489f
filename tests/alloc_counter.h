// SPDX-License-Identifier: GPL-2.0-or-later
// Counting every malloc-family call made on one thread (the rt thread between its first and
// last tick): malloc, calloc, realloc, free and the aligned variants are interposed in the test
// executable and count while the calling thread's flag is on. Include in exactly one file of a
// test executable. Sanitizers interpose malloc themselves: there HS_COUNT_MALLOC is 0 and tests
// fall back to hs_alloc_calls() (and say so).
#ifndef HS_ALLOC_COUNTER_H
#define HS_ALLOC_COUNTER_H

#include <stdatomic.h>
#include <stddef.h>

#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
#define HS_COUNT_MALLOC 0
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer)
#define HS_COUNT_MALLOC 0
#endif
#endif
#ifndef HS_COUNT_MALLOC
#define HS_COUNT_MALLOC 1
#endif

static _Thread_local int t_count_allocs;
static atomic_llong g_rt_allocs; // allocator calls counted so far

#if HS_COUNT_MALLOC
extern void* __libc_malloc(size_t n);
extern void* __libc_calloc(size_t c, size_t n);
extern void* __libc_realloc(void* p, size_t n);
extern void* __libc_memalign(size_t a, size_t n);
extern void __libc_free(void* p);
void* malloc(size_t n);
void* calloc(size_t c, size_t n);
void* realloc(void* p, size_t n);
void free(void* p);
void* memalign(size_t a, size_t n);
void* aligned_alloc(size_t a, size_t n);
int posix_memalign(void** out, size_t a, size_t n);

static void note_alloc(void) {
    if (t_count_allocs) atomic_fetch_add_explicit(&g_rt_allocs, 1, memory_order_relaxed);
}
void* malloc(size_t n) {
    note_alloc();
    return __libc_malloc(n);
}
void* calloc(size_t c, size_t n) {
    note_alloc();
    return __libc_calloc(c, n);
}
void* realloc(void* p, size_t n) {
    note_alloc();
    return __libc_realloc(p, n);
}
void free(void* p) {
    if (p) note_alloc();
    __libc_free(p);
}
void* memalign(size_t a, size_t n) {
    note_alloc();
    return __libc_memalign(a, n);
}
void* aligned_alloc(size_t a, size_t n) {
    note_alloc();
    return __libc_memalign(a, n);
}
int posix_memalign(void** out, size_t a, size_t n) {
    note_alloc();
    void* p = __libc_memalign(a, n);
    if (!p) return 12; // ENOMEM
    *out = p;
    return 0;
}
#endif

/// Thread hooks (e.g. the rt loop's on_start / on_stop): count on the calling thread or stop.
static void count_on(void* ctx) {
    (void)ctx;
    t_count_allocs = 1;
}
static void count_off(void* ctx) {
    (void)ctx;
    t_count_allocs = 0;
}

#endif
