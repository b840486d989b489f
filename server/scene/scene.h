// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim scene: what a server runs. A scene file (JSON, schema in docs/scenes.md) names the mesh,
// units, material and model, fixed regions, gravity, tools, rates, features and LCM settings.
// Loading fills a plain fixed-size struct; a malformed file gives an error naming the file, the
// line and the key. Pure parsing: no threads, no network, no global state.
#ifndef HAPSIM_SCENE_H
#define HAPSIM_SCENE_H

#include "base.h"
#include "fem.h"
#include "mesh.h"

#ifdef __cplusplus
extern "C" {
#endif

#define HS_SCENE_PATH_MAX    512 ///< bytes for file paths, including the NUL
#define HS_SCENE_URL_MAX     256 ///< bytes for LCM URLs, including the NUL
#define HS_SCENE_PREFIX_MAX  48  ///< bytes for the channel prefix, including the NUL
#define HS_SCENE_NAME_MAX    64  ///< bytes for the scene name, including the NUL
#define HS_SCENE_MAX_FIXED   8   ///< fixed regions per scene
#define HS_SCENE_MAX_TOOLS   4   ///< tools per scene
#define HS_SCENE_MAX_DEVICES 16  ///< devices per scene (matches the net validator)

/// How a fixed region selects nodes (positions in metres, after units_scale).
typedef enum hs_fixed_kind {
    HS_FIXED_PLANE = 0,     ///< nodes with (x - point) . normal <= tolerance
    HS_FIXED_BOX = 1,       ///< nodes with min <= x <= max componentwise
    HS_FIXED_BBOX_SIDE = 2, ///< nodes within depth of the mesh bounding box's min or max side
    HS_FIXED_GROUP = 3,     ///< the nodes of a named region (Gmsh physical group) of the mesh
    HS_FIXED_SPHERE = 4,    ///< nodes with |x - point| <= radius
    HS_FIXED_PATCH = 5,     ///< surface nodes within radius of point, connected over the surface
                            ///< to the surface node nearest point
    HS_FIXED_NODES = 6,     ///< the nodes listed in a text file (0-based indices in file order)
} hs_fixed_kind;

typedef struct hs_scene_fixed {
    hs_fixed_kind kind;
    double point[3];  ///< m, PLANE: a point on the plane
    double normal[3]; ///< PLANE: unit normal pointing into the free part of the body
    double tolerance; ///< m, PLANE: nodes up to this far in front of the plane are fixed too
    double min[3];    ///< m, BOX: lower corner
    double max[3];    ///< m, BOX: upper corner
    int axis;         ///< BBOX_SIDE: 0 = x, 1 = y, 2 = z
    int side;         ///< BBOX_SIDE: -1 = min side, +1 = max side
    double depth;     ///< m, BBOX_SIDE: slab thickness measured from that side
    double radius;    ///< m, SPHERE / PATCH: around point
    char group[HS_MESH_REGION_NAME_MAX]; ///< GROUP: region name (or its tag in decimal)
    char file[HS_SCENE_PATH_MAX];        ///< NODES: the list, resolved against the scene folder
    int line; ///< line of the region in the scene file (for messages; 0 if unknown)
} hs_scene_fixed;

typedef enum hs_tool_kind {
    HS_TOOL_PROBE = 0,   ///< a sphere at the tool point
    HS_TOOL_SCALPEL = 1, ///< a blade segment in the tool frame
} hs_tool_kind;

typedef struct hs_scene_tool {
    hs_tool_kind kind;
    double radius;     ///< m, probe sphere radius (scalpel: 0)
    double blade_a[3]; ///< m, tool frame: blade start (scalpel)
    double blade_b[3]; ///< m, tool frame: blade end (scalpel)
} hs_scene_tool;

/// model.solver.
typedef enum hs_scene_solver {
    HS_SCENE_SOLVER_AUTO = 0,
    HS_SCENE_SOLVER_DIRECT = 1,
    HS_SCENE_SOLVER_WARPED = 2,
    HS_SCENE_SOLVER_PCG = 3,
} hs_scene_solver;

/// Scene file name of a solver: "auto", "direct", "warped", "pcg".
const char* hs_scene_solver_name(hs_scene_solver s);

/// A loaded scene. Initialise with hs_scene_default() or fill by hs_scene_load().
typedef struct hs_scene {
    char path[HS_SCENE_PATH_MAX];      ///< the scene file as given
    char name[HS_SCENE_NAME_MAX];      ///< display name (default: file name)
    char mesh_path[HS_SCENE_PATH_MAX]; ///< mesh file, resolved against the scene's folder
    double units_scale;                ///< metres per mesh unit (1 for a mesh in m, 0.001 in mm)
    int mesh_line, units_line, fixed_line; ///< lines of those keys (messages; 0: unknown/absent)
    /// degrees: the server refuses a mesh whose smallest dihedral angle is below this
    /// (mesh_quality.min_dihedral_deg; 0 accepts any)
    double min_dihedral_deg;

    hs_model model;         ///< element model
    hs_rotation rotation;   ///< co-rotated: how element rotations are extracted
    hs_inversion inversion; ///< what inverted elements do
    int locking_free;       ///< hs_locking_free mode (true in a scene: the model's default)
    /// model.solver: AUTO picks from measured steps (docs/server.md, "Solver choice"); DIRECT
    /// the exact tangent, refactored each step for a nonlinear model; WARPED one solve per step
    /// with the rest factor rotated by the node rotations (cuts update that factor by low rank);
    /// PCG conjugate gradients on the exact tangent, preconditioned by the warped factor
    hs_scene_solver solver;
    /// model.solver_accuracy "tangent": auto takes only solvers that solve with the exact
    /// tangent (direct, PCG); 0 ("equilibrium", default): the warped solver too
    int exact_tangent;
    hs_material material; ///< E, nu, density, Rayleigh damping

    double gravity[3];                        ///< m/s^2, scene frame
    int n_fixed;                              ///< used entries of fixed[]
    hs_scene_fixed fixed[HS_SCENE_MAX_FIXED]; ///< fixed (Dirichlet) regions
    int n_tools;                              ///< used entries of tools[]
    hs_scene_tool tools[HS_SCENE_MAX_TOOLS];  ///< tool ids index this array
    int n_devices;                            ///< device ids 0 .. n_devices-1 accepted
    int has_workspace;                        ///< 1 when workspace_min/max were given
    double workspace_min[3];                  ///< m, scene frame: poses outside are rejected
    double workspace_max[3];                  ///< m

    double haptic_hz; ///< Hz, rt loop rate
    double sim_hz;    ///< Hz, deformation steps per second (upper bound)
    double visual_hz; ///< Hz, mesh delta / tool state publishing rate
    double status_hz; ///< Hz, server_status rate

    int feature_haptics; ///< 1: run the rt thread and answer poses with forces
    int feature_cutting; ///< 1: allocate and run cutting (needs a scalpel tool)
    /// cutting.free_pieces: 0 "drop" (a piece cut free of the fixed region leaves the scene),
    /// 1 "fall" (it stays, with its mass, and falls under gravity; the probe does not touch it)
    int cut_free_pieces_fall;
    int feature_visual;    ///< 1: publish mesh topology / keyframes / deltas
    double force_max_n;    ///< N, force magnitude clamp
    double force_rate_max; ///< N/s, force rate clamp
    double watchdog_s;     ///< s, a device silent this long is ramped to zero force

    char haptic_url[HS_SCENE_URL_MAX]; ///< LCM URL of the haptic bus
    char mesh_url[HS_SCENE_URL_MAX];   ///< LCM URL of the mesh bus
    char prefix[HS_SCENE_PREFIX_MAX];  ///< channel prefix, [A-Z0-9_]*
} hs_scene;

/// Defaults (as documented in docs/scenes.md); mesh_path empty.
void hs_scene_default(hs_scene* s /* OUT */);

/// Read and validate a scene file. On error *out is left with defaults and err names the file,
/// line (when known) and key. Thread: any | Allocates: temporarily
hs_status hs_scene_load(const char* path, hs_scene* out /* OUT */, hs_err* err);

/// Parse scene JSON from memory; path names the file in messages and anchors a relative mesh
/// path (it need not exist unless check_files). @param check_files 1: the mesh file must exist
hs_status hs_scene_parse(const char* text, const char* path, int check_files,
                         hs_scene* out /* OUT */, hs_err* err);

/// 1 when two LCM URLs open the same bus: same provider and network (group and port), whatever
/// their options after '?' (ttl, recv_buf_size); "udpm://" is LCM's default 239.255.76.67:7667.
/// Other providers are compared as text. A udpm URL with a group and no port (also compared as
/// text) is refused by hs_scene_parse and every hapsim program (hapsim_url_problem: LCM 1.3.1
/// binds a random port; docs/protocol.md).
/// Thread: any | Allocates: no
int hs_scene_same_bus(const char* a, const char* b);

/// Mark the nodes region f selects in mesh m (positions in the mesh's metres, after
/// units_scale); sel [n_nodes] is overwritten (1 selected). HS_ERR_INVALID with the reason (a
/// group the mesh does not have, listing those it has; a node list's file:line and problem),
/// HS_ERR_IO (a node list that cannot be read) or HS_ERR_NOMEM.
/// Thread: any | Allocates: temporarily
hs_status hs_scene_fixed_select(const hs_scene_fixed* f, const hs_mesh* m, unsigned char* sel,
                                hs_err* err);

/// Short names used in scene files: "linear", "corotated", "stvk"; "probe", "scalpel"; ...
const char* hs_scene_model_name(hs_model m);

#ifdef __cplusplus
}
#endif
#endif
