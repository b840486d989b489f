// SPDX-License-Identifier: GPL-2.0-or-later
// The haptic sim's options from a scene, as hapsim-server runs it (hapsim-bench cut times the
// same path).
#include "scene_sim.h"

#include <string.h>

// Every listed device can have a sim tool of its own.
_Static_assert(HS_SCENE_MAX_TOOLS <= HS_MAX_TOOLS, "a scene lists more tools than a sim drives");

void hs_scene_sim_def(const hs_scene* sc, int realtime, hs_haptic_sim_def* d) {
    *d = hs_haptic_sim_default_def();
    d->body.fem.model = sc->model;
    d->body.fem.material = sc->material;
    d->body.fem.rotation = sc->rotation;
    d->body.fem.inversion = sc->inversion;
    d->body.fem.locking_free = sc->locking_free;
    // auto: the deformation thread chooses (a cutting scene keeps the warped solver, whose
    // rest factor each sweep updates in part instead of a refactor).
    // The warped factor's rotations are the co-rotated model's: auto chooses only for it (StVK
    // and the linear model keep the direct solver).
    const int corot = sc->model == HS_MODEL_COROTATED;
    d->auto_solver = sc->solver == HS_SCENE_SOLVER_AUTO && !sc->feature_cutting && corot;
    d->auto_exact_tangent = sc->exact_tangent;
    // The server starts (visual mesh, deformation) while the compliance is set up; haptics
    // answer zero force until it is ready (status warnings, a console line when it is).
    d->background_setup = 1;
    d->body.solver = sc->solver == HS_SCENE_SOLVER_DIRECT            ? HS_SOLVER_DIRECT
                     : sc->solver == HS_SCENE_SOLVER_PCG             ? HS_SOLVER_PCG
                     : sc->solver == HS_SCENE_SOLVER_WARPED || corot ? HS_SOLVER_WARPED
                                                                     : HS_SOLVER_DIRECT;
    memcpy(d->body.gravity, sc->gravity, sizeof d->body.gravity);
    d->body.dt = 1.0 / sc->sim_hz;
    for (int t = 0; t < sc->n_tools; ++t)
        if (sc->tools[t].kind == HS_TOOL_PROBE) {
            d->probe.radius_m = sc->tools[t].radius;
            break;
        }
    // Listed devices: one sim tool per device, each probe with its own radius (tool 0 is the
    // blade when a device drives the scalpel).
    int sim_tool[HS_SCENE_MAX_DEVICES], scene_tool[HS_SCENE_MAX_TOOLS];
    int n = hs_scene_device_tools(sc, sim_tool, scene_tool);
    d->tools = n > 1 ? n : 1;
    for (int t = 0; t < n && sc->devices_listed; ++t) {
        const hs_scene_tool* tl = &sc->tools[scene_tool[t]];
        if (tl->kind != HS_TOOL_PROBE) continue;
        if (t == 0)
            d->probe.radius_m = tl->radius;
        else
            d->tool_radius_m[t] = tl->radius;
    }
    d->safety.max_force_n = sc->force_max_n;
    d->safety.max_rate_n_s = sc->force_rate_max;
    d->safety.watchdog_timeout_s = sc->watchdog_s;
    d->rate_hz = sc->haptic_hz;
    d->fifo_priority = realtime ? 80 : 0;
    d->lock_memory = realtime;
}
