// SPDX-License-Identifier: MIT
// hapsim-web's hub: the newest frame of each kind, shared between the LCM thread (producer)
// and the libwebsockets thread (consumer), plus the mouse-probe target. One mutex; every
// buffer is immutable once published and reference counted, so the lws thread sends it
// without holding the lock. A slow browser skips frames: only the newest of each kind waits.
#ifndef HS_WEB_HUB_H
#define HS_WEB_HUB_H

#include <pthread.h>
#include <stddef.h>
#include <stdint.h>

/// An immutable, reference-counted message ready for lws_write (LWS_PRE bytes of head room).
typedef struct hs_web_blob {
    int refs;            ///< guarded by the hub mutex
    int binary;          ///< 1: binary frame, 0: text
    size_t len;          ///< payload bytes (after the head room)
    unsigned char* data; ///< [pre + len]; payload at data + pre
} hs_web_blob;

/// Kinds of latest-value streams, in send priority order.
enum { HS_WEB_TOPO = 0, HS_WEB_POS, HS_WEB_STATUS, HS_WEB_TOOLS, HS_WEB_KINDS };

/// Depth of the per-hub event ring (acks, probe replies); older events are overwritten.
#define HS_WEB_EVENTS 64

/// The mouse probe as the browsers ask for it (read by the pose thread).
typedef struct hs_web_probe {
    int active;         ///< 1 while a browser owns the probe
    int owner;          ///< session number of the owning browser connection
    int32_t device_id;  ///< device the mouse drives
    int32_t tool_id;    ///< scene tool it holds
    double position[3]; ///< m, newest target (tool reference point)
    int64_t updated_us; ///< hs_client_now_us() of the newest target from the browser
    int64_t sent;       ///< poses published
} hs_web_probe;

/// Live-device picture from the newest status (for choosing a free device).
typedef struct hs_web_devices {
    int known;    ///< 1 once a status arrived
    int n;        ///< devices of the scene
    int live[16]; ///< 1 while poses arrive for that id
} hs_web_devices;

typedef struct hs_web_hub {
    pthread_mutex_t mu;
    hs_web_blob* latest[HS_WEB_KINDS];  ///< newest of each kind (NULL before the first)
    uint64_t gen[HS_WEB_KINDS];         ///< increments on each publish
    hs_web_blob* events[HS_WEB_EVENTS]; ///< ring of events for every browser
    int event_target[HS_WEB_EVENTS];    ///< browser session an event is for (0: all)
    uint64_t n_events;                  ///< events ever pushed
    hs_web_probe probe;
    hs_web_devices dev;
    size_t pre; ///< head room (LWS_PRE)
} hs_web_hub;

/// New blob with len payload bytes (refs 1, caller fills data + pre). NULL when out of memory.
hs_web_blob* hs_web_blob_new(const hs_web_hub* h, size_t len, int binary);
/// Text blob from a NUL-terminated string. NULL when out of memory.
hs_web_blob* hs_web_blob_text(const hs_web_hub* h, const char* s);
/// Drop a reference taken under the hub mutex (frees at zero). Takes the lock itself.
void hs_web_blob_unref(hs_web_hub* h, hs_web_blob* b);
/// Replace the newest blob of a kind (takes over the caller's reference).
void hs_web_hub_publish(hs_web_hub* h, int kind, hs_web_blob* b);
/// Append an event for one browser session (0: all); takes over the caller's reference.
void hs_web_hub_event(hs_web_hub* h, int target, hs_web_blob* b);

#endif
