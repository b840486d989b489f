// SPDX-License-Identifier: GPL-2.0-or-later
// Memory device: a hs_device whose pose and output travel through triple buffers.
#include "device.h"

#include "triple_buffer.h"

struct hs_memdev {
    hs_triple_buffer* pose; // feeder -> rt
    hs_triple_buffer* out;  // rt -> consumer
};

static int memdev_read_pose(void* ctx, hs_haptic_pose* out) {
    hs_memdev* d = ctx;
    return hs_triple_buffer_read_copy(d->pose, out);
}

static int memdev_write_force(void* ctx, const hs_haptic_output* out) {
    hs_memdev* d = ctx;
    hs_triple_buffer_write(d->out, out);
    return 0;
}

static const hs_device_vtable memdev_vtable = {"memory", memdev_read_pose, memdev_write_force};

hs_status hs_memdev_create(hs_memdev** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "hs_memdev_create: out is NULL");
    *out = NULL;
    hs_memdev* d = hs_calloc(1, sizeof *d);
    if (!d) return hs_err_set(err, HS_ERR_NOMEM, "hs_memdev_create: out of memory");
    hs_status st = hs_triple_buffer_create(sizeof(hs_haptic_pose), &d->pose, err);
    if (st == HS_OK) st = hs_triple_buffer_create(sizeof(hs_haptic_output), &d->out, err);
    if (st != HS_OK) {
        hs_memdev_destroy(&d);
        return st;
    }
    *out = d;
    return HS_OK;
}

void hs_memdev_destroy(hs_memdev** dev) {
    if (!dev || !*dev) return;
    hs_triple_buffer_destroy(&(*dev)->pose);
    hs_triple_buffer_destroy(&(*dev)->out);
    hs_free(*dev);
    *dev = NULL;
}

hs_device hs_memdev_device(hs_memdev* dev) {
    hs_device d = {&memdev_vtable, dev};
    return d;
}

void hs_memdev_feed_pose(hs_memdev* dev, const hs_haptic_pose* pose) {
    hs_triple_buffer_write(dev->pose, pose);
}

int hs_memdev_take_output(hs_memdev* dev, hs_haptic_output* out) {
    return hs_triple_buffer_read_copy(dev->out, out);
}
