// SPDX-License-Identifier: MIT
// hapsim protocol: a bounded reader of LCM-encoded bytes (big-endian; it never reads past the
// end), for the client library and the simulated stylus, which check some messages field by
// field before any decode (header only, like hapsim_channels.h).
#ifndef HAPSIM_WIRE_READ_H
#define HAPSIM_WIRE_READ_H

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

/// Bytes p[0..n), read from off; bad once anything was missing or malformed (sticky).
typedef struct hs_rd {
    const uint8_t* p;
    size_t n, off;
    int bad;
} hs_rd;

static inline uint32_t hs_be32(const uint8_t* p) {
    return (uint32_t)p[0] << 24 | (uint32_t)p[1] << 16 | (uint32_t)p[2] << 8 | (uint32_t)p[3];
}

static inline uint64_t hs_be64(const uint8_t* p) {
    return (uint64_t)hs_be32(p) << 32 | hs_be32(p + 4);
}

/// The next k bytes, or NULL (and bad set) when fewer remain or the reader is already bad.
static inline const uint8_t* hs_rd_take(hs_rd* r, size_t k) {
    if (r->bad || r->off > r->n || r->n - r->off < k) {
        r->bad = 1;
        return NULL;
    }
    const uint8_t* q = r->p + r->off;
    r->off += k;
    return q;
}

static inline int32_t hs_rd_i32(hs_rd* r) {
    const uint8_t* q = hs_rd_take(r, 4);
    return q ? (int32_t)hs_be32(q) : 0;
}

/// A float; a non-finite one sets bad and reads 0 (nothing downstream sees a NaN).
static inline float hs_rd_f32(hs_rd* r) {
    const uint8_t* q = hs_rd_take(r, 4);
    if (!q) return 0;
    uint32_t u = hs_be32(q);
    float f;
    memcpy(&f, &u, 4);
    if (!isfinite(f)) {
        r->bad = 1;
        return 0;
    }
    return f;
}

/// An LCM string (int32 length including the NUL, then the bytes): its text, NUL-terminated
/// inside the message, or NULL (bad set) for a length < 1, a missing final NUL or one inside
/// (a reader that stops at it would see another name than one that counts the length).
static inline const char* hs_rd_str(hs_rd* r) {
    int32_t len = hs_rd_i32(r);
    if (len < 1) r->bad = 1;
    const uint8_t* q = r->bad ? NULL : hs_rd_take(r, (size_t)len);
    if (!q || q[len - 1] != 0 || memchr(q, 0, (size_t)len - 1)) {
        r->bad = 1;
        return NULL;
    }
    return (const char*)q;
}

/// Ranges a tool_force_t must keep (docs/protocol.md), checked by the client library and the
/// simulated stylus alike: within them |F| stays below ~3e10 N wherever the device is.
#define HS_WIRE_FORCE_MAX_N       1e4
#define HS_WIRE_STIFFNESS_MAX_N_M 1e9
#define HS_WIRE_ANCHOR_MAX_M      1e3
#define HS_WIRE_RADIUS_MAX_M      10.0
#define HS_WIRE_TIMEOUT_MAX_US    60000000

#endif
