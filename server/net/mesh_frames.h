// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim net: keyframe / delta encoding of the visual mesh (mesh_state_t / mesh_delta_t).
// Pure functions on caller storage: no LCM, no allocation, safe to call every visual frame.
//
// DESIGN: a delta lists every visual node whose position differs from the current keyframe by
// more than eps in any component, so the newest delta alone reproduces the shape (to eps) and
// a lost delta costs nothing. When a delta would be larger than a keyframe, or the keyframe is
// old, a new keyframe is due (hs_net_keyframe_due).
#ifndef HS_NET_MESH_FRAMES_H
#define HS_NET_MESH_FRAMES_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

/// Nodes of cur ([3n], m) that moved more than eps (m, per component) from key ([3n]):
/// writes their indices (increasing) to index[] ([n]) and cur - key to delta[] ([3n]).
/// Returns the number of nodes listed. Thread: any | Allocates: no
int hs_net_delta_build(const float* key, const float* cur, int n, float eps,
                       int32_t* index /* OUT [n] */, float* delta /* OUT [3n] */);

/// Apply a delta to a keyframe: out = key, then out[index[i]] += delta[i] for each listed node.
/// Returns 0, or -1 (out untouched) when an index is out of [0, n) or not increasing.
int hs_net_delta_apply(const float* key, int n, const int32_t* index, const float* delta,
                       int n_changed, float* out /* OUT [3n] */);

/// Wire bytes of a mesh_state_t keyframe with n visual nodes (and n stress values if
/// with_stress), and of a mesh_delta_t listing n_changed nodes.
int64_t hs_net_keyframe_bytes(int n, int with_stress);
int64_t hs_net_delta_bytes(int n_changed);

/// 1 when a keyframe should replace this delta: the delta would be at least as large as a
/// keyframe, or the keyframe is older than max_age_us.
int hs_net_keyframe_due(int n, int n_changed, int64_t keyframe_age_us, int64_t max_age_us);

#ifdef __cplusplus
}
#endif
#endif
