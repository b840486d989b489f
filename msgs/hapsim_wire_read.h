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
    if (r->bad || r->n - r->off < k) {
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

/// A float; a non-finite one sets bad.
static inline float hs_rd_f32(hs_rd* r) {
    const uint8_t* q = hs_rd_take(r, 4);
    if (!q) return 0;
    uint32_t u = hs_be32(q);
    float f;
    memcpy(&f, &u, 4);
    if (!isfinite(f)) r->bad = 1;
    return f;
}

#endif
