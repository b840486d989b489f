// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim mesh: linear tetrahedral meshes, readers, validation, boundary surface, adjacency.
// Pure functions of their inputs: no threads, no global state.
#ifndef HAPSIM_MESH_H
#define HAPSIM_MESH_H

#include "base.h"

#ifdef __cplusplus
extern "C" {
#endif

#define HS_MESH_REPORT_FIRST 4 ///< repaired elements named per kind in a report

/// What loading and validation found (repair counts are those of the last finalize).
typedef struct hs_mesh_report {
    int skipped_elements;    ///< non-tetrahedral elements in the file, skipped
    int reoriented_tets;     ///< negatively oriented tets flipped to positive
    int degenerate_tets;     ///< |volume| <= 1e-12 of the used nodes' bbox volume; removed
    int duplicate_tets;      ///< same 4 nodes as an earlier tet; removed
    int unreferenced_nodes;  ///< nodes no tet uses (kept, flagged; see hs_mesh.node_used)
    int components;          ///< connected components (tets sharing a node are connected)
    double min_dihedral_deg; ///< quality: smallest dihedral angle
    double max_aspect;       ///< quality: largest (longest edge / inradius) / (2 sqrt 6)
    double mean_aspect;      ///< quality: mean of the same normalised ratio (1 = regular)
    /// The first few repaired elements of each kind: element ids of the file for a loaded
    /// mesh (VTK: cell index), else input tet indices (0-based); -1 past the last.
    long long first_reoriented[HS_MESH_REPORT_FIRST];
    long long first_degenerate[HS_MESH_REPORT_FIRST];
    long long first_duplicate[HS_MESH_REPORT_FIRST];
} hs_mesh_report;

#define HS_MESH_REGION_NAME_MAX 64 ///< bytes for a region name, including the NUL

/// A named region: the nodes of the elements of one Gmsh physical group (surface or volume).
/// Nodes are file data: finalize keeps them (it never renumbers nodes).
typedef struct hs_mesh_region {
    char name[HS_MESH_REGION_NAME_MAX]; ///< $PhysicalNames name, or the tag in decimal
    int dim;                            ///< 0 points, 1 curves, 2 surfaces, 3 volumes
    int tag;                            ///< physical tag in the file
    int n_nodes;
    int* nodes; ///< [n_nodes] node indices, ascending, unique
} hs_mesh_region;

/// A linear tetrahedral mesh in metres. Tets are positively oriented:
/// det[x1-x0, x2-x0, x3-x0] > 0. Fields after `tets` are derived by hs_mesh_finalize.
typedef struct hs_mesh {
    int n_nodes;
    int n_tets;
    double* x0; ///< [3*n_nodes] rest positions, m
    int* tets;  ///< [4*n_tets] node indices, 0-based

    // derived (hs_mesh_finalize)
    int n_tris;               ///< boundary triangles
    int* tris;                ///< [3*n_tris] node indices, counter-clockwise seen from outside
    int* tri_tet;             ///< [n_tris] the tet that owns each boundary triangle
    int n_surf_nodes;         ///< nodes on the boundary
    int* surf_nodes;          ///< [n_surf_nodes] node index of each surface node, ascending
    int* node_surf;           ///< [n_nodes] index into surf_nodes, or -1 for interior nodes
    int* node_tet_start;      ///< [n_nodes+1] CSR offsets into node_tet
    int* node_tet;            ///< [4*n_tets] tets incident to each node, ascending
    int* node_nbr_start;      ///< [n_nodes+1] CSR offsets into node_nbr
    int* node_nbr;            ///< node-node adjacency through a shared tet, sorted, self excluded
    unsigned char* node_used; ///< [n_nodes] 1 if some tet references the node
    double bbox_min[3], bbox_max[3]; ///< m, over all nodes (used or not)
    double volume;                   ///< m^3, sum of tet volumes
    hs_mesh_report report;

    // file data kept by the readers (not derived): Gmsh physical groups
    int n_regions;
    hs_mesh_region* regions; ///< [n_regions] in file order of (dim, tag)
} hs_mesh;

/// Read a mesh; the format is chosen by extension (.msh Gmsh 2.2/4.1 ASCII, .node/.ele TetGen
/// (give either file), .vtk legacy ASCII unstructured grid, .vtu VTK XML unstructured grid with
/// ASCII data arrays). Gmsh physical groups become regions. Validates and finalizes.
/// On error returns NULL-filled *out, a negative status and err->msg naming file, line, problem.
/// Returns HS_WARN_MESH_REPAIRED (> 0, mesh usable) when tets were reoriented or removed.
/// @param out  OUT: new mesh, free with hs_mesh_destroy
hs_status hs_mesh_load(const char* path, hs_mesh** out, hs_err* err);

/// Parse from memory (for fuzzing and tests); `name` is used in error messages, `format` is
/// "msh", "vtk" or "vtu" (TetGen: hs_mesh_parse_tetgen). Status as hs_mesh_load.
hs_status hs_mesh_parse(const char* name, const char* format, const char* data, size_t len,
                        hs_mesh** out, hs_err* err);
/// Parse a TetGen pair held in memory; messages name `<name>.node` and `<name>.ele`.
hs_status hs_mesh_parse_tetgen(const char* name, const char* node_data, size_t node_len,
                               const char* ele_data, size_t ele_len, hs_mesh** out, hs_err* err);

/// Build a mesh from arrays (copied), then validate and finalize as a loaded one.
hs_status hs_mesh_create(int n_nodes, const double* x0, int n_tets, const int* tets, hs_mesh** out,
                         hs_err* err);

/// Structured box [0,lx]x[0,ly]x[0,lz] of nx*ny*nz hexahedra, each split into 6 Kuhn
/// tetrahedra (conforming). Used by tests and benchmarks (cantilevers). Node (i,j,k) is
/// i + (nx+1)*(j + (ny+1)*k) (x fastest) at (lx*i/nx, ly*j/ny, lz*k/nz); hex h has tets 6h..6h+5.
hs_status hs_mesh_create_box(double lx, double ly, double lz, int nx, int ny, int nz, hs_mesh** out,
                             hs_err* err);

/// Recompute the derived fields after nodes or tets changed. Reorients, drops degenerate
/// and duplicate tets (counted in report; HS_WARN_MESH_REPAIRED if any). Returns
/// HS_ERR_INVALID for out-of-range indices, non-finite or |x| > 1e30 coordinates, a face shared
/// by more than two tets, two tets on the same side of a face (overlap), or no tet left after
/// the repairs. On an error the tets and their count are as they were and the derived fields
/// are cleared (the mesh reads as not finalized).
hs_status hs_mesh_finalize(hs_mesh* mesh, hs_err* err);

/// Check invariants (orientation, ranges, surface closed and consistent, adjacency). Returns
/// HS_OK or HS_ERR_INVALID with err->msg saying what is wrong. Pure check, changes nothing.
/// Closed: each directed boundary edge a->b is matched by as many b->a (one on a manifold).
hs_status hs_mesh_check(const hs_mesh* mesh, hs_err* err);

/// Signed volume of tet t at positions x ([3*n_nodes]); positive when correctly oriented.
double hs_tet_volume(const double* x, const int* tet);

/// Write legacy VTK ASCII (unstructured grid) with optional per-node displacement u ([3n]).
hs_status hs_mesh_write_vtk(const hs_mesh* mesh, const double* u, const char* path, hs_err* err);

/// What a load or finalize repaired, one line each ("2 tets reoriented (negative volume)\n"),
/// or "" when nothing was. For tools to print: repairs are never silent.
void hs_mesh_report_str(const hs_mesh_report* r, char* buf, size_t cap);

/// The region called `name` (or whose tag is `name` in decimal); prefers a surface group over a
/// volume one of the same name. NULL when none.
const hs_mesh_region* hs_mesh_find_region(const hs_mesh* mesh, const char* name);

/// Add a region (nodes copied, sorted, duplicates dropped); HS_ERR_INVALID for a bad index or
/// an empty or too long name.
hs_status hs_mesh_add_region(hs_mesh* mesh, const char* name, int dim, int tag, int n_nodes,
                             const int* nodes, hs_err* err);

/// Write Gmsh MSH 2.2 ASCII: nodes, tets (physical volume of the first dim-3 region, else none),
/// and per surface region (dim 2) the boundary triangles whose three nodes it holds; region
/// names go to $PhysicalNames. hs_mesh_load reads it back with its regions.
hs_status hs_mesh_write_msh(const hs_mesh* mesh, const char* path, hs_err* err);

/// Read the triangles of a mesh file held in memory, for surfaces: `format` "msh" (element
/// type 2, MSH 2.2 or 4.1 ASCII) or "vtu" (cell type 5). x [3*n_nodes] and tris [3*n_tris]
/// (0-based) are hs_alloc'ed for the caller.
hs_status hs_mesh_parse_triangles(const char* name, const char* format, const char* data,
                                  size_t len, int* n_nodes, double** x, int* n_tris, int** tris,
                                  hs_err* err);

/// Release; accepts NULL and sets *mesh to NULL.
void hs_mesh_destroy(hs_mesh** mesh);

/// Mark nodes inside the closed box [box_min, box_max] (m). Returns how many, or -1 on bad args.
/// @param mask  OUT: [n_nodes] 1 inside, 0 outside
int hs_mesh_select_box(const hs_mesh* mesh, const double box_min[3], const double box_max[3],
                       unsigned char* mask);

/// Mark nodes within tol_m of the used nodes' min (side -1) or max (side +1) along axis 0..2
/// (an unreferenced node does not move the side).
/// Returns how many, or -1 on bad args. @param mask  OUT: [n_nodes] 1 selected, 0 not
int hs_mesh_select_plane(const hs_mesh* mesh, int axis, int side, double tol_m,
                         unsigned char* mask);

/// Outward unit normal of surface node `node` at rest: the area-weighted mean of its boundary
/// triangles' normals (a scan of the boundary: for set-up and tools, not per step).
/// Returns 0, or -1 for a bad argument (n zeroed unless NULL), a node not on the surface, or a
/// surface node whose triangles' normals cancel (two parts touching only there; n zeroed).
int hs_mesh_rest_normal(const hs_mesh* mesh, int node, double n[3]);

#ifdef __cplusplus
}
#endif
#endif
