// SPDX-License-Identifier: GPL-2.0-or-later
// libFuzzer target: the stylus probe-script parser (hs_script_parse_string) on arbitrary text.
// A script it accepts must be one the device can play: segments in time order, every time and
// point finite, and its target finite wherever it is sampled, also with touch searches resolved
// against the force felt (none, then a large one). A script it refuses must leave the script
// empty and name the input and the line ("fuzz:LINE: problem").
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "stylus.h"

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size);

static hs_script* g_script; // large (fixed segment array): made once

static int finite3(const double v[3]) {
    return isfinite(v[0]) && isfinite(v[1]) && isfinite(v[2]);
}

static void check_played(const hs_script* s) {
    if (s->n_segments < 0 || s->n_segments > HS_SCRIPT_MAX_SEGMENTS) abort();
    if (!(s->duration_s >= 0) || !isfinite(s->duration_s) || !finite3(s->start_m)) abort();
    double t = 0;
    for (int i = 0; i < s->n_segments; i++) {
        const hs_script_segment* g = &s->seg[i];
        if (!(g->t0_s >= t - 1e-9) || !(g->dur_s >= 0) || !isfinite(g->t0_s + g->dur_s) ||
            !finite3(g->from_m) || !finite3(g->to_m) || g->line < 1)
            abort();
        t = g->t0_s + g->dur_s;
    }
    int hint = -1;
    for (int k = 0; k <= 64; k++) {
        double pos[3], vel[3];
        uint32_t buttons;
        hs_script_eval(s, s->duration_s * k / 64.0, pos, vel, &buttons, &hint);
        if (!finite3(pos) || !finite3(vel)) abort();
    }
    // Played by the runner: touches search until a force is felt (here: never, then at once).
    static const double felt[2][3] = {{0, 0, 0}, {1e3, -1e3, 1e3}};
    for (int f = 0; f < 2; f++) {
        hs_script_runner r;
        hs_script_runner_init(&r, s);
        double end = hs_script_runner_end(&r);
        if (!isfinite(end)) abort();
        for (int k = 0; k <= 64; k++) {
            double pos[3], vel[3];
            uint32_t buttons, events;
            hs_script_runner_eval(&r, end * k / 64.0, felt[f], pos, vel, &buttons, &events);
            if (!finite3(pos) || !finite3(vel) || !isfinite(r.t_off_s) || !finite3(r.off_m))
                abort();
        }
    }
}

int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
    if (size > (1u << 16)) return 0;
    if (!g_script && hs_script_create(&g_script, NULL) != HS_OK) abort();
    char* text = malloc(size + 1);
    if (!text) return 0;
    memcpy(text, data, size);
    text[size] = 0; // the parser takes a C string: text after a NUL is not seen
    hs_err err = {0};
    hs_status st = hs_script_parse_string(g_script, text, "fuzz", &err);
    if (st == HS_OK) {
        check_played(g_script);
    } else {
        if (g_script->n_segments != 0) abort();
        // "fuzz:LINE: problem", LINE >= 1
        char* end = NULL;
        if (strncmp(err.msg, "fuzz:", 5) != 0 || strtol(err.msg + 5, &end, 10) < 1 || *end != ':')
            abort();
    }
    free(text);
    return 0;
}
