// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim mesher: a closed, checked triangle surface -> quality linear tetrahedra, with gmsh's C
// API (GPL-2.0-or-later, Debian libgmsh-dev; docs/mesh-formats.md says why gmsh). gmsh keeps
// global state: calls are serialised by a lock inside, one mesh at a time per process.
#ifndef HAPSIM_MESHER_H
#define HAPSIM_MESHER_H

#include "mesh.h"
#include "surface.h"

#ifdef __cplusplus
extern "C" {
#endif

/// Options for hs_mesher_tet. Lengths are in the surface's units.
typedef struct hs_mesher_def {
    double size;              ///< target edge length of the tets (> 0)
    int keep_surface;         ///< 1: the surface's own triangles bound the tets (no remeshing)
    double feature_angle_deg; ///< remeshing: surface patches split where normals turn more (40)
    int optimize;             ///< 1: gmsh's tet optimiser after meshing (default)
    int verbose;              ///< 1: gmsh prints its progress on stderr
    /// Optional grading: the target size at a point (surface units), clamped to
    /// [size_min, size]; NULL: uniform. Called by gmsh while meshing (same thread).
    double (*size_at)(const double x[3], void* ctx);
    void* size_ctx;  ///< passed to size_at
    double size_min; ///< smallest size size_at may ask for (0: size / 2)
    /// Extra gmsh options set last, "Name=value" joined by ';' ("Mesh.Algorithm3D=10"); a
    /// value that is not a number is set as a string; NULL: none. An unknown name fails.
    const char* gmsh_options;
} hs_mesher_def;

/// Defaults: size 0 (must be set), remesh the surface, 40 degrees, optimise, quiet.
hs_mesher_def hs_mesher_default_def(void);

/// Tetrahedralise a closed surface (run hs_surface_clean first). The mesh is in the surface's
/// units; its nodes are the tets' nodes only. Errors carry gmsh's last message.
/// Thread: any (serialised) | Allocates: yes | Blocks: for the meshing
hs_status hs_mesher_tet(const hs_surface* s, const hs_mesher_def* def, hs_mesh** out, hs_err* err);

/// gmsh's version string ("4.8.4").
const char* hs_mesher_gmsh_version(void);

#ifdef __cplusplus
}
#endif
#endif
