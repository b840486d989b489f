// SPDX-License-Identifier: GPL-2.0-or-later
// Accounted allocation, assertions, clock (status text and errors: status.c).
#define _POSIX_C_SOURCE 200809L
#include "base.h"

#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

// A 16-byte header keeps the size so hs_free needs no size argument and alignment stays 16.
typedef struct alloc_header {
    size_t size;
    size_t magic;
} alloc_header;
#define HS_ALLOC_MAGIC ((size_t)0x6873616c6c6f6321ull)

static atomic_llong g_bytes;
static atomic_llong g_calls;
static atomic_llong g_fail_countdown;

static int inject_fault(void) {
    atomic_fetch_add_explicit(&g_calls, 1, memory_order_relaxed);
    long long c = atomic_load_explicit(&g_fail_countdown, memory_order_relaxed);
    if (c <= 0) return 0;
    c = atomic_fetch_sub_explicit(&g_fail_countdown, 1, memory_order_relaxed);
    return c == 1;
}

void* hs_alloc(size_t n) {
    if (inject_fault()) return NULL;
    if (n > SIZE_MAX - sizeof(alloc_header)) return NULL;
    alloc_header* h = malloc(sizeof(alloc_header) + n);
    if (!h) return NULL;
    h->size = n;
    h->magic = HS_ALLOC_MAGIC;
    atomic_fetch_add_explicit(&g_bytes, (long long)n, memory_order_relaxed);
    return h + 1;
}

void* hs_calloc(size_t count, size_t size) {
    if (size && count > SIZE_MAX / size) return NULL;
    void* p = hs_alloc(count * size);
    if (p) memset(p, 0, count * size);
    return p;
}

void* hs_realloc(void* p, size_t n) {
    if (!p) return hs_alloc(n);
    if (inject_fault()) return NULL;
    alloc_header* h = (alloc_header*)p - 1;
    HS_ASSERT(h->magic == HS_ALLOC_MAGIC);
    size_t old = h->size;
    if (n > SIZE_MAX - sizeof(alloc_header)) return NULL;
    alloc_header* g = realloc(h, sizeof(alloc_header) + n);
    if (!g) return NULL;
    g->size = n;
    atomic_fetch_add_explicit(&g_bytes, (long long)n - (long long)old, memory_order_relaxed);
    return g + 1;
}

void hs_free(void* p) {
    if (!p) return;
    alloc_header* h = (alloc_header*)p - 1;
    HS_ASSERT(h->magic == HS_ALLOC_MAGIC);
    h->magic = 0;
    atomic_fetch_sub_explicit(&g_bytes, (long long)h->size, memory_order_relaxed);
    free(h);
}

size_t hs_alloc_size(const void* p) {
    if (!p) return 0;
    const alloc_header* h = (const alloc_header*)p - 1;
    HS_ASSERT(h->magic == HS_ALLOC_MAGIC);
    return h->size;
}

int64_t hs_byte_count(void) {
    return atomic_load(&g_bytes);
}
int64_t hs_alloc_calls(void) {
    return atomic_load(&g_calls);
}
void hs_alloc_fail_after(int64_t n) {
    atomic_store(&g_fail_countdown, n > 0 ? n : 0);
}

static int default_assert(const char* condition, const char* file, int line) {
    fprintf(stderr, "hapsim: assertion failed: %s (%s:%d)\n", condition, file, line);
    return 1;
}

static hs_assert_fcn* _Atomic g_assert_fcn = default_assert;

void hs_set_assert_fcn(hs_assert_fcn* fcn) {
    atomic_store(&g_assert_fcn, fcn ? fcn : default_assert);
}

int hs_assert_fail(const char* condition, const char* file, int line) {
    hs_assert_fcn* f = atomic_load(&g_assert_fcn);
    if (f(condition, file, line)) abort();
    return 0;
}

int64_t hs_now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}
