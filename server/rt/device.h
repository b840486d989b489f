// SPDX-License-Identifier: GPL-2.0-or-later
// rt: the device interface, a small vtable (after LCM's lcm_provider_vtable_t). Hardware is one
// implementation, the memory device below another (tests; the network-fed stylus, whose net
// thread feeds it), and the rt loop cannot tell them apart.
#ifndef HS_RT_DEVICE_H
#define HS_RT_DEVICE_H

#include "base.h"
#include "haptic.h"

#ifdef __cplusplus
extern "C" {
#endif

/// Operations of a device. Both run on the rt thread: Allocates: no | Blocks: no.
typedef struct hs_device_vtable {
    const char* name; ///< for status reports
    /// Newest pose if one arrived since the last call: fill *out, return 1; 0 when nothing new;
    /// negative when the device failed.
    int (*read_pose)(void* ctx, hs_haptic_pose* out);
    /// Hand one tick's output to the device. Returns 0, or negative when the device failed.
    int (*write_force)(void* ctx, const hs_haptic_output* out);
} hs_device_vtable;

/// A device: its operations and its state.
typedef struct hs_device {
    const hs_device_vtable* vt;
    void* ctx;
} hs_device;

// ---------------------------------------------------------------------------------------------
// Memory device: poses in and outputs out through two triple buffers (latest value wins).
// One feeder thread writes poses, the rt thread reads them and writes outputs, one consumer
// thread takes outputs.

typedef struct hs_memdev hs_memdev;

/// Allocate the two triple buffers. @param out OUT | Thread: any | Allocates: yes
hs_status hs_memdev_create(hs_memdev** out, hs_err* err);
/// Release; accepts NULL or *dev == NULL and sets *dev = NULL. The rt loop must have stopped.
void hs_memdev_destroy(hs_memdev** dev);
/// The device view for the rt loop (valid while dev lives).
hs_device hs_memdev_device(hs_memdev* dev);
/// Publish a pose (newest wins). Thread: feeder only | Allocates: no | Lock-free: yes | Blocks: no
void hs_memdev_feed_pose(hs_memdev* dev, const hs_haptic_pose* pose);
/// Copy the newest output to out; returns 1 if it is new since the last call, else 0.
/// Thread: consumer only | Allocates: no | Lock-free: yes | Blocks: no
int hs_memdev_take_output(hs_memdev* dev, hs_haptic_output* out /* OUT */);

#ifdef __cplusplus
}
#endif
#endif
