// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim compliance: condensed compliance of a body (Bro-Nielsen & Cotin) and probe contact.
//
// DESIGN. Two halves with one fixed-size value between them.
//  - hs_compliance (deformation thread): C = K0^-1 over the free dofs, K0 the rest-state linear
//    stiffness (fixed nodes eliminated, the same dof map as hs_body). The 3x3 diagonal block
//    C_kk of every surface node is precomputed; whole column blocks C(:, k) (k's coupling to
//    every surface node: one 3-rhs sparse solve) are computed on demand and kept in a bounded
//    cache, allocated up front. Never a dense surface-by-surface matrix.
//  - hs_contact_snapshot + hs_contact_solve (rt thread): the deformation thread packs, for the
//    few surface nodes near the tool, their current (deformed) positions, the displacement the
//    contact forces already in the body cause there, normals, the rotated
//    blocks R_i C_ij R_j^T and the boundary triangles between them; the rt tick solves the
//    frictionless contact of the probe sphere with the surface: one contact point per
//    triangle (its closest point to the centre, on a vertex, an edge or the face interior,
//    each geometric point once), a linear complementarity problem over at most HS_MAX_CONTACT
//    points on at most HS_MAX_CONTACT nodes (only pushes, every point ends on or outside the
//    sphere), forces distributed to the vertices by the barycentric weights, and derives force
//    and stiffness. Pure function: no allocation, lock or I/O.
#ifndef HAPSIM_COMPLIANCE_H
#define HAPSIM_COMPLIANCE_H

#include "base.h"
#include "fem.h"
#include "haptic.h"
#include "mesh.h"
#include "sparse.h"

#ifdef __cplusplus
extern "C" {
#endif

#define HS_MAX_CONTACT      16  ///< contact points and their nodes per tick (the deepest first)
#define HS_CONTACT_MAX_CAND 64  ///< candidate nodes in one snapshot (nearest the tool)
#define HS_CONTACT_MAX_TRI  128 ///< surface triangles in one snapshot
#define HS_MAX_TOOLS        4   ///< tools in one contact problem, HS_MAX_CONTACT points each
/// Contact compliance added to every contact point, relative to the mean diagonal compliance
/// of the snapshot's nodes: keeps the contact problem positive definite when contact points
/// nearly coincide (moves a held force by about this fraction).
#define HS_CONTACT_SOFTNESS 1e-5
/// Contact points considered: within this many probe radii of the centre (a point outside the
/// sphere can be carried into it by the push on its neighbours: the sphere's flank).
#define HS_CONTACT_BAND 2.0
/// Past HS_MAX_CONTACT, a solved point's penetration tapers to zero over this many probe radii
/// (or less: the band's width beyond r) as its depth nears the deepest point left out, so the
/// force is continuous when the deepest points change places.
#define HS_CONTACT_TAPER 0.05

// ---------------------------------------------------------------------------------------------
// Condensed compliance (deformation thread).

typedef struct hs_compliance hs_compliance;

/// Factor the rest-state stiffness of a linear model with def's material over the free dofs
/// (fixed[i] != 0 or an unused node: eliminated) and precompute every surface node's diagonal
/// block (sparse solves along the factor's elimination tree, hs_cholesky_inverse_diag3).
/// cache_nodes (>= 1): column blocks kept at once.
/// Thread: one at a time | Allocates: yes. @param out OUT
hs_status hs_compliance_create(const hs_mesh* mesh, const hs_fem_def* def,
                               const unsigned char* fixed, int cache_nodes, hs_compliance** out,
                               hs_err* err);
/// As hs_compliance_create, the diagonal blocks split by par (hs_cholesky_inverse_diag3_par;
/// NULL: on this thread). The same compliance bit for bit.
hs_status hs_compliance_create_par(const hs_mesh* mesh, const hs_fem_def* def,
                                   const unsigned char* fixed, int cache_nodes,
                                   const hs_parallel* par, hs_compliance** out, hs_err* err);
/// Release; accepts NULL, sets *c = NULL.
void hs_compliance_destroy(hs_compliance** c);
/// Follow a cut exactly: elements off[n_off] of the mesh c was created on are removed and
/// moved[n_moved] have new rest positions in its x0 (hs_cut_last_removed / _changed). The
/// stiffness changes by their shares only, a low-rank change; the factor follows by a partial
/// refactor of the supernodes on their elimination-tree paths (or a refactor when simplicial).
/// A node left without an element is held by a diagonal and couples to nothing. surface (same
/// nodes; the cut's live mesh, kept by the caller until the next call or destroy) gives the
/// contactable nodes from now on. Cached columns are dropped and the diagonal blocks become
/// stale: each is recomputed when hs_compliance_ensure asks for its node. On an error c answers
/// for no stiffness: rebuild it. Thread: the owner's | Allocates: the first time, and when the
/// surface grows.
hs_status hs_compliance_change_elements(hs_compliance* c, int n_off, const int* off, int n_moved,
                                        const int* moved, const hs_mesh* surface);
/// Set up what hs_compliance_change_elements needs (scratch; a supernodal factor's partial
/// refactor data, with one full factorisation), so the first change costs no more than the
/// next. Optional. Allocates: yes (the factor's update matrices: 2-3.5x its memory).
hs_status hs_compliance_prepare_changes(hs_compliance* c);
/// The mesh c was created on (its element numbering is the one changes refer to).
const hs_mesh* hs_compliance_mesh(const hs_compliance* c);
/// Changes followed so far (hs_compliance_change_elements that succeeded).
int64_t hs_compliance_updates(const hs_compliance* c);
/// Wall time of the last hs_compliance_change_elements, ms.
double hs_compliance_update_ms(const hs_compliance* c);
/// Wall time of hs_compliance_create (factor + all diagonal blocks), ms.
double hs_compliance_setup_ms(const hs_compliance* c);
/// Column solves done so far (each one 3-rhs solve); for tests and statistics.
int64_t hs_compliance_column_solves(const hs_compliance* c);
/// Capacity of the column cache, nodes.
int hs_compliance_cache_capacity(const hs_compliance* c);
/// 1 when node is a surface node with free dofs (a possible contact node), else 0.
int hs_compliance_contactable(const hs_compliance* c, int node);
/// Diagonal block C_kk of a surface node, row-major, m/N (zero for a fixed node, and for one
/// whose block a change made stale until hs_compliance_ensure asks for it).
void hs_compliance_diag(const hs_compliance* c, int node, double out[9] /* OUT */);

/// Start a deformation step: columns used from now on are pinned until the next call, so a
/// snapshot's columns cannot evict each other. Allocates: no.
void hs_compliance_begin_step(hs_compliance* c);
/// Make the column blocks of nodes[n] (surface nodes) available, solving the missing ones in one
/// batched solve of at most max_new nodes (the first missing ones in the given order); pins all.
/// After a change (hs_compliance_change_elements) it also recomputes the stale diagonal blocks
/// of nodes[] that got no column. Returns how many of nodes[] have a column now (negative
/// hs_status on a solver failure).
/// Allocates: no (after the first solve, CHOLMOD's workspaces are reused).
int hs_compliance_ensure(hs_compliance* c, int n, const int* nodes, int max_new);
/// 1 when the column block of node is cached.
int hs_compliance_has_column(const hs_compliance* c, int node);
/// Block C_ij (surface nodes i, j), row-major, m/N, from the diagonal table or a cached column
/// of j or i. Returns 1 when known exactly, 0 when neither column is cached or a change made a
/// diagonal block stale (out = zero).
int hs_compliance_block(const hs_compliance* c, int i, int j, double out[9] /* OUT */);
/// Displacement of every surface node caused by forces f[3n] at nodes[n] (all with cached
/// columns): u_surf[3*s] for surface index s, without rotation. Returns 0, or -1 when a column
/// is missing (u_surf untouched). Allocates: no.
int hs_compliance_surface_displacement(const hs_compliance* c, int n, const int* nodes,
                                       const double* f, double* u_surf /* OUT [3*n_surf] */);
/// v = C g for a full force vector g[3n] (m/N times N): one sparse solve over the free dofs,
/// zero at fixed nodes. v may alias g. HS_ERR_INVALID (v untouched) if a free dof's g is not
/// finite. Allocates: no.
hs_status hs_compliance_apply(hs_compliance* c, const double* g, double* v /* OUT [3n] */);
/// Forces f[3m] at nodes[m] that impose displacements d[3m]: f = C_SS^-1 d, with each block
/// rotated R_i C_ij R_j^T when rot ([9m] row-major per node) is given. Solves the missing
/// columns (ignoring pins). m <= HS_MAX_CONTACT. For tests and tools. Allocates: no.
hs_status hs_compliance_solve_set(hs_compliance* c, int m, const int* nodes, const double* rot,
                                  const double* d, double* f /* OUT */);

// ---------------------------------------------------------------------------------------------
// Probe contact (rt thread): a fixed-size snapshot in, a fixed-size result out.

/// What the deformation thread hands to the rt thread (newest wins, through a triple buffer).
typedef struct hs_contact_snapshot {
    int64_t version;       ///< grows with every snapshot; 0: none yet (no contact possible)
    int64_t stamp_ns;      ///< when it was built, CLOCK_MONOTONIC ns
    double probe_radius_m; ///< sphere radius, m
    double centre_m[3];    ///< tool position the candidates were chosen around, m
    double reach_m;        ///< candidates cover every contactable node within this of centre_m
    /// Tool t >= 1 of a several-tool snapshot (hs_contact_solve_tools): its candidates cover
    /// every contactable node within tool_reach_m[t] of tool_centre_m[t] (tool 0: centre_m,
    /// reach_m; [0] unused).
    double tool_centre_m[HS_MAX_TOOLS][3];
    double tool_reach_m[HS_MAX_TOOLS];    ///< m; 0: no cover (the tool's clearance is 0)
    double tool_radius_m[HS_MAX_TOOLS];   ///< sphere radius of tool t, m; 0: probe_radius_m
    unsigned char tool_off[HS_MAX_TOOLS]; ///< 1: tool t has no sphere now (a blade): no contact
    int n_cand;                           ///< candidates (<= HS_CONTACT_MAX_CAND)
    int node[HS_CONTACT_MAX_CAND];        ///< mesh node index
    unsigned char coupled[HS_CONTACT_MAX_CAND]; ///< 1 when the node's column block is known
    /// Position the contact geometry is taken on (closest points, push directions), m: the
    /// deformed surface, so a press deeper than r still finds the surface around the sphere.
    double surf_m[HS_CONTACT_MAX_CAND][3];
    /// Displacement the contact forces already applied to the body cause at the node (to first
    /// order, C f), m: surf_m - pre_m is the contact-free position the gaps are measured from.
    /// All zero: the surface is contact-free (the linearisation about the rest shape).
    double pre_m[HS_CONTACT_MAX_CAND][3];
    double normal[HS_CONTACT_MAX_CAND][3]; ///< outward unit surface normal
    /// Boundary triangles whose three vertices are candidates (0: node contact, every
    /// candidate a contact point).
    int n_tri;
    int tri[HS_CONTACT_MAX_TRI][3]; ///< candidate indices, counter-clockwise seen from outside
    /// Bounding sphere of each triangle's surf_m vertices: centre (m), radius (m); lets
    /// the rt solve skip far triangles (hs_contact_snapshot_bound_tris).
    double tri_bound[HS_CONTACT_MAX_TRI][4];
    /// Rotated compliance R_i C_ij R_j^T, row-major 3x3, m/N: exact on the diagonal and where
    /// coupled[i] or coupled[j]; zero otherwise (the diagonal-only approximation).
    double c[HS_CONTACT_MAX_CAND][HS_CONTACT_MAX_CAND][9];
} hs_contact_snapshot;

/// The contact at one tool position (rt -> deformation thread, and the local model's source).
typedef struct hs_contact {
    int64_t version;          ///< snapshot version it came from
    double tool_m[3];         ///< probe centre, m
    int n;                    ///< contact nodes: vertices of pushing points (<= HS_MAX_CONTACT)
    int node[HS_MAX_CONTACT]; ///< mesh node index
    double d_m[HS_MAX_CONTACT][3];      ///< node displacement the contact forces cause, m
    double f_n[HS_MAX_CONTACT][3];      ///< force ON THE TISSUE at each node (sum w lambda n), N
    double force_n[3];                  ///< force ON THE TOOL, -sum f_n, N
    double stiffness_n_m[9];            ///< -dforce_n/dtool, row-major, N/m (contact set fixed)
    double clearance_m;                 ///< tool travel before a contact point enters or leaves, m
    int penetrating;                    ///< contact points (contact-free) inside the sphere
    int dropped;                        ///< pivots that removed a point (it would have pulled)
    int passes;                         ///< solves (pivots) used
    int approx;                         ///< 1 when an off-diagonal block was missing
    int failed;                         ///< 1 when C_SS was not SPD (result zeroed)
    int features;                       ///< contact points (vertex, edge or face points) pushing
    int point_nodes[HS_MAX_CONTACT][3]; ///< mesh nodes of each pushing point, ascending, -1 pad
} hs_contact;

/// Depth of a press (hs_haptic_sim_stats.depth_max_m) up to which the contact has been checked
/// against a converged static solve with a rigid sphere: 3 radii or 15 mm, whichever is larger.
static inline double hs_contact_validated_depth(double radius_m) {
    return 3 * radius_m > 0.015 ? 3 * radius_m : 0.015;
}

typedef struct hs_contact_work hs_contact_work;

/// Frictionless contact of a probe sphere centred at tool_m with the snapshot's surface: contact
/// points = each triangle's closest point to the centre (or each candidate node when n_tri is
/// 0), those within HS_CONTACT_BAND r, deepest first, at most HS_MAX_CONTACT on at most
/// HS_MAX_CONTACT nodes; forces lambda_i n_i >= 0 (n_i away from the centre; a face point's along
/// the inward face normal) such that every point's displaced position (to first order) is on or
/// outside the sphere and only points on it push (an edge or vertex point whose n_i is more
/// than 75 degrees from its triangle's inward normal pushes through a softer contact, not at
/// all along the surface or beyond: docs/haptics.md); node forces sum_i w_ia lambda_i n_i; tool
/// force -sum f, stiffness -dF/dp for the active set. warm_nodes[warm_n] (the previous tick's
/// contact nodes, or warm_n = 0) only choose where the pivoting starts; the result does not depend
/// on them. out must not alias warm_nodes. Thread: any (rt) | Allocates: no | Blocks: no
void hs_contact_solve(const hs_contact_snapshot* s, const double tool_m[3], int warm_n,
                      const int* warm_nodes, hs_contact* out);
/// hs_contact_solve warm-started from the previous tick's contact points (prev->point_nodes;
/// exact where the pushing points did not change, so usually one solve); prev NULL: cold. The
/// result does not depend on prev. out must not alias prev.
/// Thread: any (rt) | Allocates: no | Blocks: no
void hs_contact_solve_from(const hs_contact_snapshot* s, const double tool_m[3],
                           const hs_contact* prev, hs_contact* out);
/// Scratch of hs_contact_solve_tools for up to n_tools tools (1..HS_MAX_TOOLS), allocated once
/// so the 1 kHz tick allocates nothing. Allocates: yes. @param out OUT
hs_status hs_contact_work_create(int n_tools, hs_contact_work** out);
/// Release; accepts NULL, sets *w = NULL.
void hs_contact_work_destroy(hs_contact_work** w);
/// Tools w was created for (0 for NULL).
int hs_contact_work_tools(const hs_contact_work* w);
/// The contact of n_tools spheres (centres tool_m[3t..3t+2], m; radius s->tool_radius_m[t]) with
/// the snapshot's surface as one problem: each tool's points chosen as by hs_contact_solve (at most
/// HS_MAX_CONTACT points on as many nodes per tool), then one complementarity problem over all of
/// them, so W's blocks between different tools' points (the compliance between their nodes) couple
/// them: one tool's push moves the tissue under the other, and both feel it. out[t] is tool t's
/// contact: its points' forces on their nodes, those nodes' displacements under all tools' forces,
/// the force on tool t and its own stiffness -dF_t/dp_t (the other tools held). prev[n_tools]
/// (previous tick, or NULL) only picks the start. With one tool it equals hs_contact_solve_from.
/// out must not alias prev. Thread: any (rt; one thread per workspace) | Allocates: no | Blocks: no
void hs_contact_solve_tools(const hs_contact_snapshot* s, int n_tools, const double* tool_m,
                            const hs_contact* prev, hs_contact_work* w, hs_contact* out);
/// Fill s->n_tri/tri with the boundary triangles of mesh whose three vertices are all among
/// s->node[0..n_cand) (mesh order, at most HS_CONTACT_MAX_TRI), and their bounds (surf_m must
/// be set). For tools and tests that build snapshots themselves. Returns n_tri.
/// Thread: any | Allocates: no
int hs_contact_snapshot_add_tris(hs_contact_snapshot* s, const hs_mesh* mesh);
/// Set s->tri_bound from s->tri and s->surf_m (after either changed). Allocates: no
void hs_contact_snapshot_bound_tris(hs_contact_snapshot* s);
/// The local model of a contact: anchor = tool, force, stiffness (the passive part of the
/// contact's: symmetric, positive semi-definite as -dF/dp), validity radius =
/// clamp(clearance, min_radius_m, max_radius_m), timeout. Thread: any | Allocates: no
void hs_contact_model(const hs_contact* c, double min_radius_m, double max_radius_m,
                      double timeout_s, hs_haptic_model* m /* OUT */);

#ifdef __cplusplus
}
#endif
#endif
