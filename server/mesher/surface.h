// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim surface: triangle surfaces as organs arrive from segmentation (STL, OBJ, PLY, OFF, VTK,
// MSH triangles), their check and repair before tetrahedralisation, writers, and mesh quality.
// Pure functions of their inputs: no threads, no global state. The mesher (mesher.h)
// turns a checked surface into tetrahedra.
#ifndef HAPSIM_SURFACE_H
#define HAPSIM_SURFACE_H

#include "base.h"
#include "mesh.h"

#ifdef __cplusplus
extern "C" {
#endif

/// A triangle surface. Units are those of the file until scaled (hs_surface_scale).
typedef struct hs_surface {
    int n_verts;
    double* x; ///< [3*n_verts]
    int n_tris;
    int* tris; ///< [3*n_tris] vertex indices, 0-based; outward counter-clockwise after a clean
    int merged_on_read; ///< exact duplicate vertices merged by the reader
} hs_surface;

/// Read a surface; the format is chosen by extension: .stl (ASCII or binary), .obj, .ply
/// (ASCII, binary little or big endian), .off, .vtk (legacy POLYDATA, ASCII or binary; an
/// unstructured grid gives its boundary), .msh/.vtu (their triangles; a volume mesh gives its
/// boundary), .node/.ele (a volume mesh: its boundary). Polygons are fanned into
/// triangles; exact duplicate vertices are merged. Errors name file, line (or byte, or
/// triangle) and problem: a NaN vertex, an index out of range, a short binary file.
/// @param out  OUT: new surface, free with hs_surface_destroy
hs_status hs_surface_load(const char* path, hs_surface** out, hs_err* err);

/// Parse from memory; `format` is "stl", "obj", "ply", "off", "vtk", "msh" or "vtu"; `name` is
/// used in error messages.
hs_status hs_surface_parse(const char* name, const char* format, const char* data, size_t len,
                           hs_surface** out, hs_err* err);

/// The boundary triangles of a tetrahedral mesh as a surface (only the nodes on it).
hs_status hs_surface_from_mesh(const hs_mesh* mesh, hs_surface** out, hs_err* err);

/// Multiply every coordinate by k (units: 0.001 turns millimetres into metres).
void hs_surface_scale(hs_surface* s, double k);

/// Write by extension: .stl (binary), .obj, .ply (ASCII), .off. Coordinates as stored.
hs_status hs_surface_write(const hs_surface* s, const char* path, hs_err* err);

/// Release; accepts NULL and sets *s to NULL.
void hs_surface_destroy(hs_surface** s);

/// What hs_surface_clean found and changed.
typedef struct hs_surface_report {
    int merged_vertices;       ///< exact duplicates merged on reading (STL stores each corner)
    int unused_vertices;       ///< vertices no triangle uses (dropped)
    int degenerate_tris;       ///< repeated vertex or zero area (removed with repair)
    int duplicate_tris;        ///< same three vertices as an earlier triangle (removed with repair)
    int flipped_tris;          ///< turned to agree with their neighbours / to face outward
    int boundary_edges;        ///< edges of one triangle (holes), after repair
    int nonmanifold_edges;     ///< edges of more than two triangles
    int nonmanifold_verts;     ///< vertices where surfaces touch at a point (several fans)
    int holes_closed;          ///< repair: holes filled (a fan around their centre)
    int hole_tris_added;       ///< repair: triangles those fans added
    int pieces;                ///< connected pieces before repair
    int pieces_dropped;        ///< repair: pieces other than the largest, removed
    int self_intersections;    ///< pairs of triangles that cross (sharing no edge)
    double where[3];           ///< a point at the first problem found (file units)
    double area;               ///< surface area
    double volume;             ///< enclosed volume (divergence theorem; closed surfaces)
    double edge_min, edge_max; ///< shortest and longest edge
    double bbox_min[3], bbox_max[3];
} hs_surface_report;

/// Limits for hs_surface_clean's repairs.
typedef struct hs_surface_clean_def {
    int repair;          ///< 1: remove duplicate/degenerate triangles, close small holes, keep
                         ///< the largest piece; 0: fail on them, saying where
    int max_hole_edges;  ///< repair: holes with at most this many edges are closed (default 64)
    int check_crossings; ///< 1: look for self-intersections (a grid over the triangles)
} hs_surface_clean_def;

/// Defaults: no repair, holes up to 64 edges, crossings checked.
hs_surface_clean_def hs_surface_clean_default_def(void);

/// Check a surface before meshing: orient consistently and outward, and either repair or fail
/// (HS_ERR_INVALID) on an open, non-manifold, self-intersecting or degenerate surface, the
/// message naming `name`, the problem, how many and where. Returns HS_WARN_MESH_REPAIRED when
/// the repair changed something (the report says what).
hs_status hs_surface_clean(hs_surface* s, const char* name, const hs_surface_clean_def* def,
                           hs_surface_report* report /* OUT */, hs_err* err);

/// One line per repair the report holds ("3 duplicate triangles removed\n"...), or "" if none.
void hs_surface_report_str(const hs_surface_report* r, char* buf, size_t cap);

// ---------------------------------------------------------------------------------------------
// Quality of a tetrahedral mesh (hapsim-mesh info).

#define HS_QUALITY_BINS 10 ///< radius-ratio histogram bins over [0, 1]

/// Mesh statistics for a report (lengths in the mesh's units).
typedef struct hs_mesh_quality {
    int n_nodes, n_tets, n_tris;
    double bbox_min[3], bbox_max[3];
    double volume, area;         ///< sum of tet volumes; boundary area
    double min_dihedral_deg;     ///< smallest dihedral angle over all tets
    double max_dihedral_deg;     ///< largest
    int below_5deg, below_10deg; ///< tets with some dihedral angle below 5 / 10 degrees
    double min_radius_ratio;     ///< 3 inradius / circumradius (1 regular, 0 flat)
    double mean_radius_ratio;
    int ratio_hist[HS_QUALITY_BINS];     ///< tets with radius ratio in [i/10, (i+1)/10)
    int pieces;                          ///< connected pieces (tets sharing a node)
    double surf_edge_min, surf_edge_max; ///< boundary edge lengths
} hs_mesh_quality;

/// Compute the statistics of a finalized mesh.
void hs_mesh_quality_compute(const hs_mesh* mesh, hs_mesh_quality* q /* OUT */);

#ifdef __cplusplus
}
#endif
#endif
