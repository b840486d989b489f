// SPDX-License-Identifier: MIT
// hapsim base: status codes, error text, accounted allocation, assertions.
// Everything else in the library builds on this header.
#ifndef HAPSIM_BASE_H
#define HAPSIM_BASE_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/// Result of a fallible call. Negative is an error, positive a warning (as CHOLMOD's status).
typedef enum hs_status {
    HS_OK = 0,
    HS_ERR_NOMEM = -1,         ///< allocation failed; partial work was released
    HS_ERR_INVALID = -2,       ///< an argument or a definition is invalid
    HS_ERR_IO = -3,            ///< a file could not be opened or read
    HS_ERR_PARSE = -4,         ///< a file is malformed (the message names file, line, problem)
    HS_ERR_NOT_POSDEF = -5,    ///< a matrix that must be SPD is not
    HS_ERR_NOT_CONVERGED = -6, ///< an iteration stopped before its tolerance
    HS_ERR_NUMERIC = -7,       ///< NaN or Inf appeared
    HS_ERR_UNSUPPORTED = -8,   ///< valid input that this build does not handle
    HS_WARN_NOT_CONVERGED = 1, ///< result usable, tolerance not reached
    HS_WARN_MESH_REPAIRED = 2, ///< the mesh was loaded with repairs (see its report)
} hs_status;

/// Static text for a status; never NULL, never freed (cf. sqlite3_errstr).
const char* hs_status_str(hs_status s);

/// Error detail for fallible calls: a code and a human-readable message.
typedef struct hs_err {
    hs_status code;
    char msg[512];
} hs_err;

/// Set code and a printf-style message; accepts err == NULL. Returns code.
/// Thread: any | Allocates: no | not for the 1 kHz path (formats text)
hs_status hs_err_set(hs_err* err, hs_status code, const char* fmt, ...)
    __attribute__((format(printf, 3, 4)));

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
