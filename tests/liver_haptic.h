// SPDX-License-Identifier: GPL-2.0-or-later
// The default liver scene's tissue (scenes/liver/liver.json: 5 kPa, nu 0.45, 1060 kg/m^3,
// Rayleigh 0.5 / 0.01) as an hs_haptic_sim_def for the tests, hold_probe and the haptic bench,
// stepped every 10 ms (the scene steps at 60 Hz).
#ifndef HS_TESTS_LIVER_HAPTIC_H
#define HS_TESTS_LIVER_HAPTIC_H

#include "haptic_sim.h"

static inline hs_haptic_sim_def hs_liver_haptic_def(hs_model model, double radius_m) {
    hs_haptic_sim_def d = hs_haptic_sim_default_def();
    d.body.fem.model = model;
    d.body.fem.material.youngs_pa = 5000;
    d.body.fem.material.poisson = 0.45;
    d.body.fem.material.density_kg_m3 = 1060;
    d.body.fem.material.rayleigh_mass = 0.5;
    d.body.fem.material.rayleigh_stiffness = 0.01;
    d.body.dt = 0.01;
    d.probe.radius_m = radius_m;
    return d;
}

#endif
