// SPDX-License-Identifier: MIT
// hapsim protocol: a bounded reader of LCM-encoded bytes (big-endian; it never reads past the
// end), under every decoder of hapsim_proto (hapsim_proto.h). Header only.
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

/// The next k (4 or 8) bytes as a big-endian number; 0 when missing.
static inline uint64_t hs_rd_bits(hs_rd* r, size_t k) {
    const uint8_t* q = hs_rd_take(r, k);
    return !q ? 0 : k == 8 ? hs_be64(q) : hs_be32(q);
}

static inline int32_t hs_rd_i32(hs_rd* r) {
    return (int32_t)(uint32_t)hs_rd_bits(r, 4);
}

static inline int64_t hs_rd_i64(hs_rd* r) {
    return (int64_t)hs_rd_bits(r, 8);
}

static inline int8_t hs_rd_i8(hs_rd* r) {
    const uint8_t* q = hs_rd_take(r, 1);
    return q ? (int8_t)q[0] : 0;
}

/// A float; a non-finite one sets bad and reads 0 (nothing downstream sees a NaN).
static inline float hs_rd_f32(hs_rd* r) {
    uint32_t u = (uint32_t)hs_rd_bits(r, 4);
    float f;
    memcpy(&f, &u, 4);
    if (isfinite(f)) return f;
    r->bad = 1;
    return 0;
}

/// A double as sent, NaN and Inf included (for readers that count them apart).
static inline double hs_rd_f64_raw(hs_rd* r) {
    uint64_t u = hs_rd_bits(r, 8);
    double d;
    memcpy(&d, &u, 8);
    return d;
}

/// A double; a non-finite one sets bad.
static inline double hs_rd_f64(hs_rd* r) {
    double d = hs_rd_f64_raw(r);
    if (!isfinite(d)) r->bad = 1;
    return d;
}

/// Start reading buf[0..len) (buf NULL: nothing) and check the type fingerprint; 1 when it
/// matches.
static inline int hs_rd_begin(hs_rd* r, const void* buf, size_t len, int64_t hash) {
    r->p = (const uint8_t*)buf;
    r->n = buf ? len : 0;
    r->off = 0;
    r->bad = 0;
    return hs_rd_i64(r) == hash && !r->bad;
}

/// 1 when every read succeeded and nothing is left over.
static inline int hs_rd_done(const hs_rd* r) {
    return !r->bad && r->off == r->n;
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
