// SPDX-License-Identifier: GPL-2.0-or-later
// The haptic sim's options from a scene, shared by hapsim-server and hapsim-bench.
#ifndef HS_SCENE_SIM_H
#define HS_SCENE_SIM_H

#include "haptic_sim.h"
#include "scene.h"

/// The sim options hapsim-server uses for scene sc: model, material, solver, rates, probe radius,
/// force limits, background compliance set-up; realtime: ask for SCHED_FIFO and locked memory.
/// Thread: any | Allocates: no
void hs_scene_sim_def(const hs_scene* sc, int realtime, hs_haptic_sim_def* d /* OUT */);

#endif
