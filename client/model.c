// SPDX-License-Identifier: MIT
// The local force model of tool_force_t (docs/protocol.md "Driving a device").
#include <math.h>
#include <string.h>

#include "hapsim_model.h"
#include "hapsim_tool_force_t.h"
#include "wire.h"

double hs_local_model_eval(const hs_local_model* m, const double p[3], int64_t now_us,
                           double f[3]) {
    f[0] = f[1] = f[2] = 0;
    if (!m || !m->valid || m->state == HAPSIM_TOOL_FORCE_T_STATE_STOPPED) return 0;
    // Full strength for timeout_us after arrival, then a linear ramp to zero over timeout_us.
    // In double: clocks far apart must not overflow.
    double age = (double)now_us - (double)m->arrival_us, to = (double)m->timeout_us;
    double s = 1;
    if (age > to) {
        s = to > 0 ? 1.0 - (age - to) / to : 0;
        if (!(s > 0)) return 0;
    }
    // A non-finite p (a lost encoder) or a model built by hand beyond the decoder's ranges: no
    // force rather than an infinite or NaN one.
    if (hapsim_model_force(m->force, m->anchor, m->stiffness, 1, m->validity_radius, p, f) ==
        HAPSIM_MODEL_NONFINITE) {
        f[0] = f[1] = f[2] = 0;
        return 0;
    }
    for (int i = 0; i < 3; i++) f[i] *= s;
    return s;
}

void hs_force_renderer_init(hs_force_renderer* r) {
    memset(r, 0, sizeof *r);
    r->blend_us = 3000;
}

void hs_force_renderer_push(hs_force_renderer* r, const hs_local_model* m) {
    if (r->model.valid && m->model_version != r->model.model_version) {
        r->old_model = r->model;
        r->blend_start_us = m->arrival_us;
    }
    r->model = *m;
}

int32_t hs_force_renderer_eval(const hs_force_renderer* r, const double p[3], int64_t now_us,
                               double f[3]) {
    hs_local_model_eval(&r->model, p, now_us, f);
    if (!r->model.valid) return -1;
    // A stop is zero at once: blending out of the last contact would hand a stopped (e-stopped,
    // paused) device the old force for another blend_us.
    if (r->model.state == HAPSIM_TOOL_FORCE_T_STATE_STOPPED) return r->model.state;
    int64_t t = hs_wire_sub_sat(now_us, r->blend_start_us);
    if (r->old_model.valid && r->blend_us > 0 && t < r->blend_us) {
        double fo[3];
        hs_local_model_eval(&r->old_model, p, now_us, fo);
        hapsim_model_blend(fo, f, (double)t, (double)r->blend_us, f);
    }
    return r->model.state;
}
