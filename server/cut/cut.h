// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim cut: vertex-preserving cutting (Nakao, Minato et al.): the geometry of a cut and the
// element changes it makes. It keeps no stiffness, factor or compliance: the owner of those (the
// haptic sim: its body and its compliance) follows each sweep's element-change list.
//
// DESIGN. Owned by the deformation thread; used by one thread at a time.
//  - Geometry. The blade is a segment PQ; between two steps it sweeps the quad (P0,Q0,Q1,P1),
//    split into the triangles (P0,Q0,Q1) and (P0,Q1,P1). A tet is cut when one of its edges (at
//    the current positions x = x0 + u) crosses the quad. Each vertex of a removed tet whose
//    plane projection falls inside the quad moves there; one outside it (ahead of the blade,
//    beyond its ends) stays, so nothing is dragged along the cut; a surface vertex moves only
//    within its tangent plane. Moves are mapped to rest space through the inverse of the
//    vertex's mean deformation gradient, so u keeps the deformation. Cut tets are removed; no
//    vertex is ever created (the node numbering never changes).
//  - Rules. A removal that would leave a vertex without elements either pins the vertex (default:
//    it leaves the system, the cut separates fully) or keeps the tet (the paper's rule). A move is
//    halved until every remaining incident tet keeps a volume ratio and a shape quality, in rest
//    and current positions, else dropped. A piece cut free of every fixed node is dropped (tets
//    removed, nodes pinned) or fixed in place (nodes pinned), per def, so a stiffness built on
//    the held pieces stays positive definite.
//  - Element changes. After each sweep: the removed tets, the remaining tets whose rest data
//    changed (a vertex moved), the moved vertices, the pinned nodes, and a topology version
//    (grows when anything changed), for the body, the compliance and the protocol's topology
//    events.
//  - Surface. Tangent planes come from the boundary faces around a vertex (face neighbours of
//    the full mesh + activity), so a sweep never needs the live mesh; that is rebuilt on demand.
#ifndef HAPSIM_CUT_H
#define HAPSIM_CUT_H

#include "base.h"
#include "fem.h"
#include "mesh.h"

#ifdef __cplusplus
extern "C" {
#endif

/// What a removal that would leave a vertex with no element does.
typedef enum hs_cut_orphan {
    HS_CUT_ORPHAN_PIN = 0,      ///< remove the tet, pin the vertex (it leaves the system)
    HS_CUT_ORPHAN_KEEP_TET = 1, ///< keep the tet (the paper's rule; the cut may not separate)
} hs_cut_orphan;

/// What a piece that no fixed node holds does.
typedef enum hs_cut_fragment {
    HS_CUT_FRAGMENT_DROP = 0, ///< remove its tets and pin its nodes (it leaves the scene)
    HS_CUT_FRAGMENT_FIX = 1,  ///< pin its nodes in place, keep its tets
} hs_cut_fragment;

/// Cutting options. Initialise with hs_cut_default_def().
typedef struct hs_cut_def {
    hs_cut_orphan orphan;     ///< orphan vertex rule
    hs_cut_fragment fragment; ///< free piece rule
    /// 1 (default): a pinned node holds a piece like a fixed one (for a caller that holds pinned
    /// nodes in place). 0: only fixed nodes hold, for a caller whose body lets pinned nodes move
    /// (a piece FIX pinned still moves there, so it must not hold the next one).
    int pins_hold;
    double min_volume_ratio; ///< guard: V_after / V_before of each remaining incident tet
    double min_quality;      ///< guard: floor of 6 sqrt(2) V / l_rms^3 (1 = regular tet)
    int max_bisections;      ///< guard: halvings of a move before it is dropped
    int tangent_surface;     ///< 1: surface vertices move only in their tangent plane (paper)
    int validate;            ///< 1: hs_mesh_check + own checks after every sweep
    int cookie;              ///< set by hs_cut_default_def
} hs_cut_def;

/// Defaults: ORPHAN_PIN, FRAGMENT_DROP, pins hold, volume ratio 0.1, quality 0.02, 8 bisections,
/// tangent moves on, validation on.
hs_cut_def hs_cut_default_def(void);

/// What one sweep did.
typedef struct hs_cut_result {
    int cut_tets; ///< tets with an edge crossing the sweep, or removed at a hinge
    /// Vertices on the blade's plane where it passed that still had tets on both sides (the
    /// sides stayed joined there) and lost the smaller side's tets there. Tets ORPHAN_KEEP_TET
    /// keeps at a hinge are not counted in `kept`.
    int hinges;
    int removed;   ///< tets removed (cut ones + dropped fragments)
    int kept;      ///< cut tets kept by ORPHAN_KEEP_TET
    int moved;     ///< vertices moved
    int clamped;   ///< of them shortened or dropped by the quality guard
    int pinned;    ///< nodes pinned by this sweep (orphans + fragments)
    int fragments; ///< free pieces dropped or fixed
    /// Tets the free-piece check visited: a search from the removed tets' neighbours that
    /// stops once they are connected again (typically a few hundred), or every tet when that
    /// cannot settle it (the first removal, a piece coming free, a hold touched). 0: no removal.
    int piece_check_tets;
    int changed_elements;     ///< removed + changed tets (hs_cut_last_removed, hs_cut_last_changed)
    double cut_length_m;      ///< summed length of distinct mesh edges crossing the sweep, m
    double geometry_ms;       ///< crossing test, moves, guard, fragments, change lists, ms
    double mesh_ms;           ///< validation incl. live mesh rebuild (def.validate only), ms
    double total_ms;          ///< whole sweep, ms
    int64_t topology_version; ///< after this sweep
} hs_cut_result;

typedef struct hs_cut hs_cut;

/// Set up cutting on mesh (its x0 is moved by cuts; its tets array is never changed, so a body
/// or fem built on it keeps its element numbering). fixed[n_nodes] (NULL: none) marks the
/// nodes that hold the pieces (at least one, used by a tet). The mesh must outlive the cut.
/// @param out OUT
/// Thread: deformation | Allocates: yes
hs_status hs_cut_create(hs_mesh* mesh, const unsigned char* fixed, const hs_cut_def* def,
                        hs_cut** out, hs_err* err);
/// Release; accepts NULL, sets *cut = NULL.
void hs_cut_destroy(hs_cut** cut);

/// Cut with the blade moving from segment (p0, q0) to (p1, q1), world coordinates, m.
/// u ([3n], m, may be NULL for a body at rest) is the current displacement: crossings use
/// x0 + u, and moved vertices get u updated so x0 + u lands where the move puts it.
/// On a negative status nothing in the mesh changed if err names the input; a failed check
/// (def.validate) is reported after the mesh changed (its topology version grew).
/// Thread: deformation | Allocates: only in the live mesh rebuild when def.validate is on
hs_status hs_cut_sweep(hs_cut* cut, const double p0[3], const double q0[3], const double p1[3],
                       const double q1[3], double* u, hs_cut_result* res /* OUT, may be NULL */,
                       hs_err* err);

/// Tets removed by the last sweep (indices into mesh->tets); valid until the next sweep.
int hs_cut_last_removed(const hs_cut* cut, const int** tets /* OUT */);
/// Vertices moved by the last sweep; valid until the next sweep.
int hs_cut_last_moved(const hs_cut* cut, const int** nodes /* OUT */);
/// Remaining tets whose rest data the last sweep changed (a vertex moved); valid until the
/// next sweep. With hs_cut_last_removed, what hs_body_change_elements takes.
int hs_cut_last_changed(const hs_cut* cut, const int** tets /* OUT */);
/// Grows by one per sweep that removed or moved anything (0 before the first).
int64_t hs_cut_topology_version(const hs_cut* cut);
/// 1 while tet (index into mesh->tets) is part of the body.
int hs_cut_tet_active(const hs_cut* cut, int tet);
/// 1 when node was pinned by a cut (orphan or free piece); its displacement is then zero.
int hs_cut_node_pinned(const hs_cut* cut, int node);
/// Rebuild the live mesh if a sweep changed it (hs_mesh_finalize: allocates; a few ms on large
/// meshes, so it is off the sweep itself unless def.validate). Called by the getters below.
hs_status hs_cut_update_live(hs_cut* cut, hs_err* err);
/// The body as it is now: the active tets (finalized: surface, adjacency), same nodes as mesh;
/// NULL if rebuilding failed. Valid until the next sweep.
const hs_mesh* hs_cut_live_mesh(hs_cut* cut);
/// Mesh tet index of live tet k (-1 if rebuilding failed).
int hs_cut_live_tet(hs_cut* cut, int k);
/// Connected pieces of the live mesh (tets sharing a node are connected); -1 on failure.
int hs_cut_components(hs_cut* cut);
/// Check the live mesh (hs_mesh_check) and the cut invariants: no used free vertex without an
/// element, every active tet positively oriented at rest, pinned nodes unused.
hs_status hs_cut_validate(hs_cut* cut, hs_err* err);

/// Mirror the cuts into a fem built on the same mesh before the first cut (e.g. a body's):
/// deactivate every removed tet and refresh the rest data of the tets whose vertices the LAST
/// sweep moved. Call after every sweep (a skipped sweep's moves are missed). Allocates: no.
hs_status hs_cut_sync_fem(const hs_cut* cut, hs_fem* other);

// ---------------------------------------------------------------------------------------------
/// Cutting resistance felt by the blade (a toughness model): separating tissue along the mesh
/// edges the sweep crossed resists the blade with force = toughness_n_m * cut_length_m, opposite
/// the blade travel, capped at max_n. Zero when nothing was cut or the blade did not move.
/// Pure. Thread: any | Allocates: no
void hs_cut_force(double toughness_n_m, double cut_length_m, const double travel_m[3], double max_n,
                  double force_n[3] /* OUT, on the tool */);

#ifdef __cplusplus
}
#endif
#endif
