// SPDX-License-Identifier: MIT
// hapsim-web's hub (hub.h): newest-frame slots and an event ring under one mutex.
#include "hub.h"

#include <stdlib.h>
#include <string.h>

hs_web_blob* hs_web_blob_new(const hs_web_hub* h, size_t len, int binary) {
    hs_web_blob* b = calloc(1, sizeof *b);
    if (!b) return NULL;
    b->data = malloc(h->pre + len + 1);
    if (!b->data) {
        free(b);
        return NULL;
    }
    b->refs = 1;
    b->binary = binary;
    b->len = len;
    return b;
}

hs_web_blob* hs_web_blob_text(const hs_web_hub* h, const char* s) {
    size_t n = strlen(s);
    hs_web_blob* b = hs_web_blob_new(h, n, 0);
    if (b) memcpy(b->data + h->pre, s, n + 1);
    return b;
}

static void blob_unref_locked(hs_web_blob* b) {
    if (b && --b->refs == 0) {
        free(b->data);
        free(b);
    }
}

void hs_web_blob_unref(hs_web_hub* h, hs_web_blob* b) {
    if (!b) return;
    pthread_mutex_lock(&h->mu);
    blob_unref_locked(b);
    pthread_mutex_unlock(&h->mu);
}

void hs_web_hub_publish(hs_web_hub* h, int kind, hs_web_blob* b) {
    if (!b) return;
    pthread_mutex_lock(&h->mu);
    blob_unref_locked(h->latest[kind]);
    h->latest[kind] = b;
    h->gen[kind]++;
    pthread_mutex_unlock(&h->mu);
}

void hs_web_hub_event(hs_web_hub* h, int target, hs_web_blob* b) {
    if (!b) return;
    pthread_mutex_lock(&h->mu);
    size_t i = (size_t)(h->n_events % HS_WEB_EVENTS);
    blob_unref_locked(h->events[i]);
    h->events[i] = b;
    h->event_target[i] = target;
    h->n_events++;
    pthread_mutex_unlock(&h->mu);
}
