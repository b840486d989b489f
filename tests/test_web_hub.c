// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-web's hub (web/hub.h): a producer thread publishing frames and events while a consumer
// thread takes references and drops them, as the LCM and lws threads do. Checks: the consumer
// only ever sees whole frames in increasing order, the newest wins, events are kept in a
// bounded ring, and every buffer is freed (the count of live blobs returns to zero). Run under
// ThreadSanitizer by make test-tsan (label tsan).
#define _POSIX_C_SOURCE 200809L
#include <pthread.h>
#include <stdatomic.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "hub.h"
#include "test_macros.h"

#define FRAMES 20000

static hs_web_hub g_hub;
static atomic_int g_done;

static void* producer(void* arg) {
    (void)arg;
    for (uint32_t i = 1; i <= FRAMES; i++) {
        hs_web_blob* b = hs_web_blob_new(&g_hub, 64, 1);
        if (!b) abort();
        unsigned char* p = b->data + g_hub.pre;
        for (int k = 0; k < 16; k++) memcpy(p + 4 * k, &i, 4); // a frame is 16 copies of i
        hs_web_hub_publish(&g_hub, HS_WEB_POS, b);
        if (i % 50 == 0) { // let the consumer in now and then (frames come at 30 Hz for real)
            struct timespec ts = {0, 20000};
            nanosleep(&ts, NULL);
        }
        if (i % 100 == 0) {
            char t[64];
            snprintf(t, sizeof t, "{\"t\":\"ack\",\"n\":%u}", i / 100);
            hs_web_hub_event(&g_hub, 0, hs_web_blob_text(&g_hub, t));
        }
    }
    atomic_store(&g_done, 1);
    return NULL;
}

static int test_hub_threads(void) {
    memset(&g_hub, 0, sizeof g_hub);
    pthread_mutex_init(&g_hub.mu, NULL);
    g_hub.pre = 16;
    pthread_t th;
    ENSURE(pthread_create(&th, NULL, producer, NULL) == 0);
    uint32_t last = 0;
    uint64_t seen_gen = 0;
    int frames = 0, torn = 0, backwards = 0;
    for (;;) {
        int done = atomic_load(&g_done);
        hs_web_blob* b = NULL;
        pthread_mutex_lock(&g_hub.mu);
        if (g_hub.latest[HS_WEB_POS] && g_hub.gen[HS_WEB_POS] != seen_gen) {
            b = g_hub.latest[HS_WEB_POS];
            b->refs++;
            seen_gen = g_hub.gen[HS_WEB_POS];
        }
        pthread_mutex_unlock(&g_hub.mu);
        if (b) { // outside the lock, as the lws thread writes it
            uint32_t v[16];
            memcpy(v, b->data + g_hub.pre, sizeof v);
            for (int k = 1; k < 16; k++) torn += v[k] != v[0];
            backwards += v[0] <= last;
            last = v[0];
            frames++;
            hs_web_blob_unref(&g_hub, b);
        } else if (done) {
            break;
        }
    }
    pthread_join(th, NULL);
    ENSURE(torn == 0 && backwards == 0);
    ENSURE(last == FRAMES); // the newest frame is the one left
    ENSURE(frames > 10 && frames <= FRAMES);
    printf("  consumer saw %d of %d frames (the rest skipped as a slow browser would)\n", frames,
           FRAMES);
    // Events: 200 pushed into a 64-entry ring; the newest 64 are kept, in order.
    ENSURE(g_hub.n_events == FRAMES / 100);
    for (uint64_t e = g_hub.n_events - HS_WEB_EVENTS; e < g_hub.n_events; e++) {
        char want[64];
        snprintf(want, sizeof want, "{\"t\":\"ack\",\"n\":%llu}", (unsigned long long)e + 1);
        hs_web_blob* b = g_hub.events[e % HS_WEB_EVENTS];
        ENSURE(b && !b->binary && b->len == strlen(want) &&
               !memcmp(b->data + g_hub.pre, want, b->len));
    }
    for (int i = 0; i < HS_WEB_EVENTS; i++) hs_web_blob_unref(&g_hub, g_hub.events[i]);
    ENSURE(g_hub.latest[HS_WEB_POS]->refs == 1);
    hs_web_blob_unref(&g_hub, g_hub.latest[HS_WEB_POS]);
    pthread_mutex_destroy(&g_hub.mu);
    return 0;
}

HS_TEST_MAIN(HS_CASE(test_hub_threads))
