// SPDX-License-Identifier: MIT
// hapsim base: status codes (hapsim/status.h), accounted allocation, assertions, clock.
// Everything else in the library builds on this header.
#ifndef HAPSIM_BASE_H
#define HAPSIM_BASE_H

#include <stddef.h>
#include <stdint.h>

#include "hapsim/status.h" // hs_status, hs_err, hs_status_str, hs_err_set

#ifdef __cplusplus
extern "C" {
#endif

// ---------------------------------------------------------------------------------------------
// Allocation. Every library allocation goes through these so tests can check the byte count
// returns to zero and inject failures. Thread-safe (atomic counters).

/// Allocate n bytes (16-byte aligned). Returns NULL on failure or injected fault.
void* hs_alloc(size_t n);
/// Allocate zeroed count*size bytes, with overflow check.
void* hs_calloc(size_t count, size_t size);
/// Resize; on failure the old block is untouched and NULL is returned.
void* hs_realloc(void* p, size_t n);
/// Release; accepts NULL.
void hs_free(void* p);
/// Size in bytes of a block from hs_alloc/hs_calloc/hs_realloc (0 for NULL).
size_t hs_alloc_size(const void* p);
/// Bytes currently allocated through hs_alloc.
int64_t hs_byte_count(void);
/// Number of hs_alloc/hs_calloc/hs_realloc calls since start (monotonic).
int64_t hs_alloc_calls(void);
/// Fault injection for tests: the n-th allocation from now fails (n >= 1); 0 disables.
void hs_alloc_fail_after(int64_t n);

// ---------------------------------------------------------------------------------------------
// Assertions for programmer errors. On in every build type except when HS_DISABLE_ASSERT.

/// Assert hook: return 0 to continue, nonzero to abort.
typedef int hs_assert_fcn(const char* condition, const char* file, int line);
/// Replace the assert handler (NULL restores the default, which prints and aborts).
void hs_set_assert_fcn(hs_assert_fcn* fcn);
int hs_assert_fail(const char* condition, const char* file, int line);

#ifndef HS_DISABLE_ASSERT
#define HS_ASSERT(c)                                                                               \
    do {                                                                                           \
        if (!(c)) hs_assert_fail(#c, __FILE__, __LINE__);                                          \
    } while (0)
#else
#define HS_ASSERT(c) ((void)0)
#endif

/// Monotonic clock in nanoseconds (CLOCK_MONOTONIC). Thread: any | Allocates: no
int64_t hs_now_ns(void);

#ifdef __cplusplus
}
#endif
#endif
