// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim cut: vertex-preserving cutting (Nakao, Minato et al.) with the stiffness factor kept
// consistent by low-rank updates.
//
// DESIGN. Owned by the deformation thread; used by one thread at a time.
//  - Geometry. The blade is a segment PQ; between two steps it sweeps the quad (P0,Q0,Q1,P1),
//    split into the triangles (P0,Q0,Q1) and (P0,Q1,P1). A tet is cut when one of its edges (at
//    the current positions x = x0 + u) crosses the quad. Each vertex of a removed tet whose
//    plane projection falls inside the quad moves there; one outside it (ahead of the blade,
//    beyond its ends) stays, so nothing is dragged along the cut; a surface vertex moves only
//    within its tangent plane. Moves are mapped to rest space through the inverse of the
//    vertex's mean deformation gradient, so u keeps the deformation. Cut tets are removed; no
//    vertex is ever created (K keeps its size).
//  - Rules. A removal that would leave a vertex without elements either pins the vertex (default:
//    it leaves the system, the cut separates fully) or keeps the tet (the paper's rule). A move is
//    halved until every remaining incident tet keeps a volume ratio and a shape quality, in rest
//    and current positions, else dropped. A piece cut free of every fixed node is dropped (tets
//    removed, nodes pinned) or fixed in place (nodes pinned), per def, so K stays SPD.
//  - Physics. The cut keeps the rest-state linear stiffness K (free dofs; fixed nodes
//    eliminated; pinned nodes held by a diagonal spring) and its sparse Cholesky factor. Each
//    sweep changes K by the 12x12 blocks of removed tets and of tets touching moved vertices
//    (+ pin blocks). Policy PARTIAL keeps K itself current and refactors only the supernodes
//    of L the change reaches (hs_cholesky_refactor_partial): the fastest exact path in the
//    benchmark. UPDATE sums the blocks over the union of their dofs and applies one CHOLMOD
//    update/downdate of rank <= that union (hs_cholesky_update_parts). AUTO (default) is
//    PARTIAL where the factor allows it, else UPDATE unless its predicted cost (union x
//    measured cost per rank) exceeds a numeric refactor with the kept analysis; a failed
//    update also refactors. An optional update
//    window orders the dofs near the blade last so in-window updates and partial refactors
//    walk short paths; leaving it rebuilds the factor (in the sweep, or on another thread:
//    hs_cut_window_*; PARTIAL only the latter). Either way the factor is that of the new K;
//    tests compare it with a fresh factorisation.
//  - Surface. Tangent planes come from the boundary faces around a vertex (face neighbours of
//    the full mesh + activity), so a sweep never needs the live mesh; that is rebuilt on demand.
//  - Events. After each sweep: the removed tets, the moved vertices and a topology version
//    (grows when anything changed), for the protocol's topology events.
#ifndef HAPSIM_CUT_H
#define HAPSIM_CUT_H

#include "hapsim/base.h"
#include "hapsim/fem.h"
#include "hapsim/mesh.h"
#include "hapsim/sparse.h"

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

/// How the factor of K follows a sweep's element changes.
typedef enum hs_cut_factor_policy {
    /// PARTIAL where the factor allows it (supernodal, its kept data within 4x the factor, no
    /// window or a background one); else the low-rank update unless a numeric refactor is
    /// cheaper (measured).
    HS_CUT_FACTOR_AUTO = 0,
    HS_CUT_FACTOR_UPDATE = 1,   ///< always the low-rank update (CHOLMOD update/downdate)
    HS_CUT_FACTOR_REFACTOR = 2, ///< numeric refactor with the kept analysis (reference)
    /// No factor at all: geometry, pins and element changes only, for a caller whose own
    /// solver follows the changed elements (the server's co-rotated body refactors its tangent
    /// every step anyway). hs_cut_solve, hs_cut_refactor, compliance tracking and the update
    /// window are unavailable; hs_cut_factor returns NULL.
    HS_CUT_FACTOR_NONE = 3,
    /// Partial refactor (hs_cholesky_refactor_partial): K's changed entries are added into the
    /// kept matrix and only the supernodes of L holding a changed dof, and their ancestors, are
    /// recomputed from the kept update matrices; the rest of L is reused. Exact, no window
    /// needed; about a third to a half of a refactor's flops on a localised cut. Compliance
    /// tracking re-solves its blocks (RESOLVE) in either mode.
    HS_CUT_FACTOR_PARTIAL = 4,
} hs_cut_factor_policy;

/// Cutting options. Initialise with hs_cut_default_def().
typedef struct hs_cut_def {
    hs_material material;     ///< material of the linear stiffness kept factorised
    hs_cut_orphan orphan;     ///< orphan vertex rule
    hs_cut_fragment fragment; ///< free piece rule
    /// 1 (default): a pinned node holds a piece like a fixed one (K has its spring). 0: only
    /// fixed nodes hold, for a caller whose own body has no pin springs (a piece FIX pinned
    /// still moves there, so it must not hold the next one).
    int pins_hold;
    double min_volume_ratio; ///< guard: V_after / V_before of each remaining incident tet
    double min_quality;      ///< guard: floor of 6 sqrt(2) V / l_rms^3 (1 = regular tet)
    int max_bisections;      ///< guard: halvings of a move before it is dropped
    int tangent_surface;     ///< 1: surface vertices move only in their tangent plane (paper)
    hs_cut_factor_policy factor_policy; ///< how K's factor follows the cuts
    int validate;                       ///< 1: hs_mesh_check + own checks after every sweep
    /// Update window (UPDATE / AUTO / PARTIAL; 0: off). The factor is ordered with the free
    /// dofs of the nodes within this distance of the blade (extended window_ahead_m along its
    /// travel) eliminated last, so updates and partial refactors there walk short paths. A
    /// sweep touching a dof outside it rebuilds the factor (new ordering + numeric factor)
    /// around the blade, m. PARTIAL needs window_background.
    double window_radius_m;
    double window_ahead_m; ///< how far ahead of the blade, along its travel, the window reaches, m
    /// 1: a sweep leaving the window updates the current factor (longer paths) instead of
    /// rebuilding it; the caller rebuilds the window off the critical path (hs_cut_window_*),
    /// or the cut itself does with window_thread.
    int window_background;
    /// 1 (needs window_background): the cut rebuilds its window on a thread of its own.
    /// hs_cut_sweep starts a build when one is due (hs_cut_window_due) and swaps a finished
    /// one in; under PARTIAL in a sweep that changed nothing, or at the latest in the 5th that
    /// did after the build ended (the swap's partial refactor costs about an in-window sweep).
    /// The begin and finish costs count in the sweep's times; hs_cut_window_begin, _build and
    /// _finish then refuse; hs_cut_window_stats reports the builds.
    int window_thread;
    /// PARTIAL: keep windows only where they pay. At create, a probe window in the middle of
    /// the mesh: if a partial refactor of all its dofs would redo more than this fraction of
    /// the flops in the window's order than in the default one (CHOLMOD's symbolic analyses,
    /// hs_cholesky_order_shares), the mesh is too compact or too small for windows and none is
    /// ever due (hs_cut_window_stats.off). 0 (default): no probe; hs_cut_def_auto_window sets
    /// 0.5.
    double window_accept_ratio;
    /// A rebuild is due (hs_cut_window_due) once the blade has travelled this fraction of
    /// window_ahead_m from where the window was chosen; in (0, 1], default 0.5. Lower it when
    /// a build takes longer than the blade needs for the rest of the window.
    double window_due_fraction;
    /// Threads of the partial refactor (PARTIAL, and AUTO when it takes that path): 1, or 2 to
    /// share its large supernodes with a helper thread (hs_cholesky_set_partial_threads);
    /// 0: 2 when two or more processors are online, else 1; 1 with window_thread (unless its
    /// probe turned windows off), whose builds take the second core.
    int factor_threads;
    int cookie; ///< set by hs_cut_default_def
} hs_cut_def;

/// Turn on an update window sized to the mesh, rebuilt by the cut's own thread and kept only
/// where it pays (PARTIAL, or AUTO taking it): with h the mean length of the tets' first
/// edges (the mesh's edge length), radius 3 h (a
/// sweep's changes reach ~2.7 h from the blade), 14 h ahead, due a third of the way in,
/// window_background and window_thread on, window_accept_ratio 0.5 (tuned on hapsim-bench
/// cut: on plate5043 a sweep then redoes ~5 % of a factorisation instead of 25 %).
void hs_cut_def_auto_window(hs_cut_def* def, const hs_mesh* mesh);

/// Defaults: hs_fem_default_def()'s material, ORPHAN_PIN, FRAGMENT_DROP, volume ratio 0.1,
/// quality 0.02, 8 bisections, tangent moves on, AUTO factor policy, validation on, no window,
/// factor threads by the processors online.
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
    int changed_elements;     ///< element changes applied to the factor (+ pin blocks)
    int refactored;           ///< 1 when the factor was rebuilt instead of updated
    int rewindowed;           ///< 1 when it was rebuilt with a new window (def.window_radius_m)
    int window_started;       ///< 1 when the cut's window thread began a build (window_thread)
    double cut_length_m;      ///< summed length of distinct mesh edges crossing the sweep, m
    double geometry_ms;       ///< crossing test, moves, guard, fragments, ms
    double factor_ms;         ///< element matrices + factor update, ms
    double mesh_ms;           ///< validation incl. live mesh rebuild (def.validate only), ms
    double total_ms;          ///< whole sweep, ms
    int64_t topology_version; ///< after this sweep
} hs_cut_result;

typedef struct hs_cut hs_cut;

/// Set up cutting on mesh (its x0 is moved by cuts; its tets array is never changed, so a body
/// or fem built on it keeps its element numbering). fixed[n_nodes] (NULL: none) marks the
/// nodes eliminated from K. Factors K. The mesh must outlive the cut. @param out OUT
/// Thread: deformation | Allocates: yes
hs_status hs_cut_create(hs_mesh* mesh, const unsigned char* fixed, const hs_cut_def* def,
                        hs_cut** out, hs_err* err);
/// Release; accepts NULL, sets *cut = NULL.
void hs_cut_destroy(hs_cut** cut);

/// Cut with the blade moving from segment (p0, q0) to (p1, q1), world coordinates, m.
/// u ([3n], m, may be NULL for a body at rest) is the current displacement: crossings use
/// x0 + u, and moved vertices get u updated so x0 + u lands where the move puts it.
/// On a negative status nothing in the mesh changed if err names the input; a failure after
/// the geometry changed (a failed refactor) is reported and leaves a consistent mesh: the
/// topology version grows and the next sweep first refactors (and re-solves tracked blocks).
/// Thread: deformation | Allocates: only for more element changes than any earlier sweep, when
/// the first update converts the factor, when a window is rebuilt in the sweep, while a
/// background window is being built (its record grows), in the live mesh rebuild when
/// def.validate is on, and in every re-solve of tracked compliance blocks (RESOLVE, or a
/// partial refactor)
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

/// Background window rebuild (def.window_radius_m > 0, typically with def.window_background):
/// 1 when a rebuild is due: the last sweep changed dofs outside the window, or the blade has
/// travelled def.window_due_fraction of its reach ahead; PARTIAL also when there is no window
/// yet or the blade's midpoint has left its strip (farther than window_radius_m from the line
/// it was chosen along, or behind its start), cutting or not. 0 while a rebuild is under way,
/// always under PARTIAL on a factor too small to be supernodal (no partial refactor), and when
/// the probe of def.window_accept_ratio said windows do not pay on this mesh.
/// Thread: deformation | Allocates: no
int hs_cut_window_due(const hs_cut* cut);
/// Snapshot K and choose a new window around the last sweep's blade; sweeps from here on are
/// recorded for hs_cut_window_finish (PARTIAL: the union of the dofs they changed).
/// Thread: deformation | Allocates: yes (first call; the record grows with the sweeps until
/// finish)
hs_status hs_cut_window_begin(hs_cut* cut, hs_err* err);
/// Order and factor the snapshot (analysis + numeric factor, the expensive part; PARTIAL: the
/// factor with its kept update matrices, hs_cholesky_create_last_partial, ~0.1 s at 5,043
/// vertices). Touches only the snapshot and the factor the last finish replaced (freed here,
/// off the sweeps' thread), so it may run on another thread while sweeps go on; the caller
/// orders it between begin and finish (join it before finish or hs_cut_destroy). Low-rank
/// policies: it also applies the sweeps recorded meanwhile, as they come.
/// Thread: any one | Allocates: yes
hs_status hs_cut_window_build(hs_cut* cut, hs_err* err);
/// Bring the new factor up to date with the sweeps since begin and swap it in: one aggregated
/// update inside its window (a numeric refactor if that is impossible); PARTIAL: a partial
/// refactor of the dofs K changed in since begin, about one in-window sweep's cost, so call
/// it in a step that cut nothing where possible. The replaced factor is kept until the next
/// build. Thread: deformation | Allocates: on growth only
hs_status hs_cut_window_finish(hs_cut* cut, hs_err* err);

/// Window rebuilds by the cut's own thread (def.window_thread), and the probe of
/// def.window_accept_ratio.
typedef struct hs_cut_window_stats {
    int builds;  ///< builds started
    int swapped; ///< finished builds swapped in
    int failed;  ///< builds that failed (the sweeps went on with the factor they had)
    int off;     ///< 1: the probe at create said windows do not pay (no rebuilds)
    double probe_share_default; ///< the probe's share in the default order (0: no probe)
    double probe_share_window;  ///< and in the window's order
    int running;                ///< 1 while a build is under way
    double build_ms;            ///< mean wall time of the finished builds, ms
} hs_cut_window_stats;
/// Thread: deformation | Allocates: no
void hs_cut_window_stats_get(const hs_cut* cut, hs_cut_window_stats* out);

/// Static linear solve K u = f with the kept factor: f[3n] nodal forces (N) in, u[3n] (m) out;
/// fixed and pinned nodes get zero; HS_ERR_INVALID without a factor (NONE). Allocates: no.
hs_status hs_cut_solve(hs_cut* cut, const double* f, double* u /* OUT */);
/// The kept factor (order hs_cut_free_dofs); NULL with HS_CUT_FACTOR_NONE.
hs_cholesky* hs_cut_factor(hs_cut* cut);
/// Number of free dofs of K.
int hs_cut_free_dofs(const hs_cut* cut);
/// Free dof index of (node, comp), or -1 for a fixed node.
int hs_cut_dof(const hs_cut* cut, int node, int comp);
/// A new matrix with K's pattern (values zero). @param out OUT
hs_status hs_cut_create_matrix(const hs_cut* cut, hs_csc** out);
/// Assemble K as it is now from scratch (fem assembly of the active tets + pins) into a.
void hs_cut_assemble(const hs_cut* cut, hs_csc* a);
/// Rebuild the factor from a fresh assembly (the fallback; also resets update drift);
/// HS_ERR_INVALID without a factor (NONE).
hs_status hs_cut_refactor(hs_cut* cut);
/// The linear fem the cut keeps (element activity and rest data follow the cuts).
const hs_fem* hs_cut_fem(const hs_cut* cut);
/// Mirror the cuts into another fem built on the same mesh before the first cut (e.g. a body's):
/// deactivate every removed tet and refresh the rest data of the tets whose vertices the LAST
/// sweep moved. Call after every sweep (a skipped sweep's moves are missed). Allocates: no.
hs_status hs_cut_sync_fem(const hs_cut* cut, hs_fem* other);

// ---------------------------------------------------------------------------------------------
// Compliance: diagonal blocks C_kk of K^-1 for a tracked node set, updated exactly per sweep by
// Woodbury on the changed dofs (or re-solved, per mode), for the haptic path.

typedef enum hs_cut_compliance_mode {
    HS_CUT_COMPLIANCE_WOODBURY = 0, ///< C' = C - C_:D (I + dK_DD C_DD)^-1 dK_DD C_D: (old factor)
    HS_CUT_COMPLIANCE_RESOLVE = 1,  ///< re-solve every tracked block with the updated factor
} hs_cut_compliance_mode;

/// Track nodes[n] (any nodes; fixed ones give zero blocks): compute their blocks now and keep
/// them current on every later sweep. Replaces an earlier set. HS_ERR_INVALID without a
/// factor (NONE) or for an unknown mode (nothing changed then). When the factor follows by partial
/// refactor (PARTIAL, or AUTO where it takes it) the blocks are re-solved whatever the mode:
/// Woodbury needs the low-rank columns. On failure nothing is tracked. Allocates: yes.
hs_status hs_cut_track_compliance(hs_cut* cut, int n, const int* nodes,
                                  hs_cut_compliance_mode mode);
/// Block C_kk (m/N, row-major) of tracked node index k (0..n-1 of the tracked set).
void hs_cut_compliance_block(const hs_cut* cut, int k, double out[9] /* OUT */);
/// Wall time of the last compliance update, ms.
double hs_cut_compliance_ms(const hs_cut* cut);

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
