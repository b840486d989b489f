// SPDX-License-Identifier: GPL-2.0-or-later
// Keyframe / delta encoding of the visual mesh. See mesh_frames.h.
#include "mesh_frames.h"

#include <math.h>
#include <string.h>

int hs_net_delta_build(const float* key, const float* cur, int n, float eps, int32_t* index,
                       float* delta) {
    int m = 0;
    for (int i = 0; i < n; ++i) {
        float dx = cur[3 * i] - key[3 * i];
        float dy = cur[3 * i + 1] - key[3 * i + 1];
        float dz = cur[3 * i + 2] - key[3 * i + 2];
        // A NaN difference counts as moved, so it reaches the client's own checks.
        if (!(fabsf(dx) <= eps && fabsf(dy) <= eps && fabsf(dz) <= eps)) {
            index[m] = i;
            delta[3 * m] = dx;
            delta[3 * m + 1] = dy;
            delta[3 * m + 2] = dz;
            ++m;
        }
    }
    return m;
}

int hs_net_delta_apply(const float* key, int n, const int32_t* index, const float* delta,
                       int n_changed, float* out) {
    if (n < 0 || n_changed < 0 || n_changed > n) return -1;
    for (int i = 0; i < n_changed; ++i)
        if (index[i] < 0 || index[i] >= n || (i > 0 && index[i] <= index[i - 1])) return -1;
    memcpy(out, key, sizeof(float) * 3 * (size_t)n);
    for (int i = 0; i < n_changed; ++i)
        for (int c = 0; c < 3; ++c) out[3 * index[i] + c] += delta[3 * i + c];
    return 0;
}

// Fingerprint, utime, seq, topology_version, keyframe_id, sim_step, sim_time.
enum { FRAME_HEADER_BYTES = 8 + 6 * 8 };

int64_t hs_net_keyframe_bytes(int n, int with_stress) {
    return FRAME_HEADER_BYTES + 4 + 12 * (int64_t)n + 4 + (with_stress ? 4 * (int64_t)n : 0);
}

int64_t hs_net_delta_bytes(int n_changed) {
    return FRAME_HEADER_BYTES + 4 + 4 * (int64_t)n_changed + 4 + 12 * (int64_t)n_changed;
}

int hs_net_keyframe_due(int n, int n_changed, int64_t keyframe_age_us, int64_t max_age_us) {
    return hs_net_delta_bytes(n_changed) >= hs_net_keyframe_bytes(n, 0) ||
           keyframe_age_us >= max_age_us;
}
