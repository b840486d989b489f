// SPDX-License-Identifier: GPL-2.0-or-later
// Cutting: geometry and rules, separation and wounds on the skin patch, 1,000 random cuts on the
// liver, and the element changes consistent with a stiffness built from scratch on the cut mesh.
#define _POSIX_C_SOURCE 200809L // access
#include "body.h"
#include "cut.h"
#include "sparse.h"
#include "test_macros.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#define MM 1e-3

static unsigned long long g_rng = 0x9e3779b97f4a7c15ull;
static double urand(void) { // xorshift64*, uniform in [0, 1)
    g_rng ^= g_rng >> 12;
    g_rng ^= g_rng << 25;
    g_rng ^= g_rng >> 27;
    return (double)((g_rng * 2685821657736338717ull) >> 11) / 9007199254740992.0;
}

// The skin patch is bundled in scenes/skin; other meshes come from the shared folder beside
// the project (absent on a user's machine).
static hs_mesh* load_shared(const char* name) {
    char path[512];
    snprintf(path, sizeof path, "%s/scenes/skin/%s", HS_SOURCE_DIR, name);
    if (access(path, R_OK) != 0) snprintf(path, sizeof path, "%s/%s", HS_SHARED_MESHES, name);
    hs_mesh* m = NULL;
    hs_err e;
    if (hs_mesh_load(path, &m, &e) < 0) {
        printf("  cannot load %s: %s\n", path, e.msg);
        return NULL;
    }
    return m;
}

/// The nodes on both x ends of m's bounding box (hs_calloc'd mask): held, the cut between.
static unsigned char* held_x_ends(const hs_mesh* m) {
    unsigned char* fixed = hs_calloc((size_t)m->n_nodes, 1);
    unsigned char* far = hs_calloc((size_t)m->n_nodes, 1);
    if (!fixed || !far) {
        hs_free(fixed);
        hs_free(far);
        return NULL;
    }
    hs_mesh_select_plane(m, 0, -1, 1e-6, fixed);
    hs_mesh_select_plane(m, 0, +1, 1e-6, far);
    for (int i = 0; i < m->n_nodes; i++) fixed[i] |= far[i];
    hs_free(far);
    return fixed;
}

/// A linear fem on the cut body as it is now (the live mesh: the active tets at their rest
/// positions now; the removed ones may be inverted there) over the dofs of dof[3n] (nf of them).
static hs_status fem_now(hs_cut* c, const int* dof, int nf, hs_fem** out) {
    const hs_mesh* live = hs_cut_live_mesh(c);
    if (!live) return HS_ERR_INVALID;
    hs_fem_def fd = hs_fem_default_def();
    fd.model = HS_MODEL_LINEAR;
    hs_err e;
    hs_status st = hs_fem_create(live, &fd, dof, nf, out, &e);
    if (st != HS_OK) {
        printf("  fem on the live mesh: %s\n", e.msg);
        return st;
    }
    hs_fem_update(*out, live->x0, NULL);
    return HS_OK;
}

/// Static linear solve K u = f on the cut body from scratch (fem_now; fixed and pinned nodes and
/// nodes without a tet held, u = 0 there): the reference a compliance built on the cut mesh
/// follows. A negative status when K is singular (a piece no fixed node holds).
static hs_status fresh_solve(hs_cut* c, hs_mesh* m, const unsigned char* fixed, const double* f,
                             double* u) {
    const int n = m->n_nodes;
    int* dof = hs_alloc(sizeof(int) * 3 * (size_t)n);
    int* used = hs_calloc((size_t)n, sizeof(int));
    int nf = 0;
    for (int t = 0; t < m->n_tets; t++)
        if (hs_cut_tet_active(c, t))
            for (int a = 0; a < 4; a++) used[m->tets[4 * t + a]] = 1;
    for (int i = 0; i < n; i++)
        for (int q = 0; q < 3; q++)
            dof[3 * i + q] = used[i] && !fixed[i] && !hs_cut_node_pinned(c, i) ? nf++ : -1;
    hs_fem* fem = NULL;
    hs_csc* a = NULL;
    hs_cholesky* fac = NULL;
    double* b = hs_calloc(2 * (size_t)nf + 1, sizeof(double));
    hs_err e;
    hs_status st = fem_now(c, dof, nf, &fem);
    if (st == HS_OK) st = hs_fem_create_matrix(fem, &a);
    if (st == HS_OK) {
        hs_fem_assemble(fem, 1.0, 0.0, a);
        st = hs_cholesky_create(a, &fac, &e);
    }
    if (st == HS_OK) {
        for (int k = 0; k < 3 * n; k++)
            if (dof[k] >= 0) b[dof[k]] = f[k];
        st = hs_cholesky_solve(fac, b, b + nf);
    }
    for (int k = 0; k < 3 * n && st == HS_OK; k++) {
        u[k] = dof[k] >= 0 ? b[nf + dof[k]] : 0.0;
        if (!isfinite(u[k])) st = HS_ERR_NUMERIC;
    }
    hs_cholesky_destroy(&fac);
    hs_csc_destroy(&a);
    hs_fem_destroy(&fem);
    hs_free(b);
    hs_free(used);
    hs_free(dof);
    return st;
}

/// Max relative difference of K x between a fem kept in step with the cuts (hs_cut_sync_fem after
/// every sweep) and one built from scratch on the cut mesh (fem_now), over the same dofs.
static double synced_vs_rebuilt(hs_cut* c, const hs_fem* synced, const int* dof, int nf) {
    hs_fem* fem = NULL;
    hs_csc *a1 = NULL, *a2 = NULL;
    double worst = INFINITY;
    if (fem_now(c, dof, nf, &fem) == HS_OK && hs_fem_create_matrix(fem, &a2) == HS_OK &&
        hs_fem_create_matrix(synced, &a1) == HS_OK) {
        hs_fem_assemble(synced, 1.0, 0.0, a1);
        hs_fem_assemble(fem, 1.0, 0.0, a2);
        double* x = hs_alloc(sizeof(double) * 3 * (size_t)nf);
        double *y1 = x + nf, *y2 = x + 2 * nf;
        for (int i = 0; i < nf; i++) x[i] = urand() - 0.5;
        hs_csc_spmv(a1, x, y1);
        hs_csc_spmv(a2, x, y2);
        double dn = 0, nn = 0;
        for (int i = 0; i < nf; i++) {
            dn += (y1[i] - y2[i]) * (y1[i] - y2[i]);
            nn += y2[i] * y2[i];
        }
        worst = sqrt(dn / nn);
        hs_free(x);
    }
    hs_fem_destroy(&fem);
    hs_csc_destroy(&a1);
    hs_csc_destroy(&a2);
    return worst;
}

static int test_force_model(void) {
    double f[3], t[3] = {0, 2 * MM, 0};
    hs_cut_force(100.0, 0.01, t, 50.0, f); // 100 N/m * 1 cm = 1 N against +y
    ENSURE_NEAR(f[0], 0, 1e-15);
    ENSURE_NEAR(f[1], -1.0, 1e-12);
    hs_cut_force(100.0, 1.0, t, 5.0, f); // capped
    ENSURE_NEAR(f[1], -5.0, 1e-12);
    double z[3] = {0, 0, 0};
    hs_cut_force(100.0, 0.01, z, 50.0, f); // blade at rest: no force
    ENSURE(f[0] == 0 && f[1] == 0 && f[2] == 0);
    hs_cut_force(100.0, 0.0, t, 50.0, f); // nothing cut
    ENSURE(f[1] == 0);
    return 0;
}

/// The skin patch cut fully across/// The skin patch cut fully across at x = 1 mm by a blade
/// spanning the thickness, swept in y.
static int cut_across(hs_cut* c, double xc, double step, hs_err* e) {
    for (double y = -0.045; y < 0.045 - 1e-9; y += step) {
        double p0[3] = {xc, y, -1 * MM}, q0[3] = {xc, y, 5 * MM};
        double p1[3] = {xc, y + step, -1 * MM}, q1[3] = {xc, y + step, 5 * MM};
        hs_cut_result r;
        if (hs_cut_sweep(c, p0, q0, p1, q1, NULL, &r, e) != HS_OK) return 1;
        if (y > -0.04 && y < 0.035 && r.removed == 0) return 2; // the wound forms under the blade
    }
    return 0;
}

static int test_skin_full_separation(void) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = load_shared("skin_patch_synthetic.msh");
    ENSURE(m);
    const int n = m->n_nodes;
    double* xorig = hs_alloc(sizeof(double) * 3 * (size_t)n);
    memcpy(xorig, m->x0, sizeof(double) * 3 * (size_t)n);
    unsigned char* fixed = held_x_ends(m); // the cut between
    hs_cut_def def = hs_cut_default_def();
    hs_cut* c = NULL;
    hs_err e;
    ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
    ENSURE(hs_cut_components(c) == 1);

    // Pull the nodes of the far piece next to the cut in +z: before the cut the near piece moves.
    double* f = hs_calloc(3 * (size_t)n, sizeof(double));
    double* u = hs_calloc(3 * (size_t)n, sizeof(double));
    for (int i = 0; i < n; i++)
        if (xorig[3 * i] > 4.5 * MM && xorig[3 * i] < 9 * MM) f[3 * i + 2] = 1e-3;
    ENSURE(fresh_solve(c, m, fixed, f, u) == HS_OK);
    double near_before = 0;
    for (int i = 0; i < n; i++)
        if (xorig[3 * i] < 0) near_before = fmax(near_before, fabs(u[3 * i + 2]));
    ENSURE(near_before > 1e-5);

    int rc = cut_across(c, 1 * MM, 5 * MM, &e);
    if (rc) printf("  cut failed (%d): %s\n", rc, e.msg);
    ENSURE(rc == 0);
    ENSURE(hs_cut_components(c) == 2);
    ENSURE(hs_cut_validate(c, &e) == HS_OK);
    ENSURE(hs_cut_topology_version(c) > 0);
    // Vertices moved onto the blade plane, none created.
    ENSURE(hs_cut_live_mesh(c)->n_nodes == n);
    int on_plane = 0;
    for (int i = 0; i < n; i++) on_plane += fabs(m->x0[3 * i] - 1 * MM) < 1e-9;
    ENSURE(on_plane > 20);

    ENSURE(fresh_solve(c, m, fixed, f, u) == HS_OK);
    double near = 0, pulled = 0;
    for (int i = 0; i < n; i++) {
        if (xorig[3 * i] < 1 * MM)
            near = fmax(near, sqrt(u[3 * i] * u[3 * i] + u[3 * i + 1] * u[3 * i + 1] +
                                   u[3 * i + 2] * u[3 * i + 2]));
        else
            pulled = fmax(pulled, u[3 * i + 2]);
    }
    printf("  fig. 7e: fixed piece max |u| %.3g m (before the cut %.3g), pulled piece %.3g m\n",
           near, near_before, pulled);
    ENSURE(pulled > 1e-4);
    ENSURE(near <= 1e-10 * pulled); // exactly decoupled

    hs_cut_destroy(&c);
    ENSURE(c == NULL);
    hs_free(f);
    hs_free(u);
    hs_free(fixed);
    hs_free(xorig);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// A straight cut across the skin patch (as cut_across.probe: x = 1 mm, tool point at z = 2 mm,
/// blade 3 mm below to 5 mm above it along the tool axis) in 0.5 mm sweeps, as the server makes
/// them, with a vertical and a 17-degree tilted blade, validated after every sweep. A vertex of
/// a cut tet belongs on the cut surface, so over the whole cut it need not move farther than
/// its distance to the blade's plane (the tangent-plane rule only shortens a move); anything
/// beyond that is the drag found in review: vertices ahead of the blade went to the quad's
/// front edge, were dragged along the cut and moved again by later sweeps (11.3 mm tilted, 3.6
/// mm vertical, against at most 3.45 mm to the plane). Allowed: 5 % of the vertex's shortest
/// edge beyond it. The patch must come apart in two pieces, also in sweeps of 0.2 and 0.02 mm
/// (a slow hand at the deformation rate): a vertex moved onto the blade's plane kept tets on
/// both sides there and joined them (one piece, 0.2 and 0.02 mm vertical) until the sweep
/// removed the smaller side's tets at such hinges.
static int test_straight_cut_drag(void) {
    int64_t bytes = hs_byte_count();
    int fail = 0;
    static const double k_sweep[3] = {0.5 * MM, 0.2 * MM, 0.02 * MM};
    for (int run = 0; run < 6; run++) {
        const int tilt = run % 2;
        const double sweep = k_sweep[run / 2];
        hs_mesh* m = load_shared("skin_patch_synthetic.msh");
        ENSURE(m);
        const int n = m->n_nodes;
        double* xorig = hs_alloc(sizeof(double) * 3 * (size_t)n);
        memcpy(xorig, m->x0, sizeof(double) * 3 * (size_t)n);
        double* hmin = hs_alloc(sizeof(double) * (size_t)n);
        for (int i = 0; i < n; i++) hmin[i] = INFINITY;
        for (int t = 0; t < m->n_tets; t++)
            for (int a = 0; a < 4; a++)
                for (int b = a + 1; b < 4; b++) {
                    int i = m->tets[4 * t + a], j = m->tets[4 * t + b];
                    double d[3] = {xorig[3 * i] - xorig[3 * j], xorig[3 * i + 1] - xorig[3 * j + 1],
                                   xorig[3 * i + 2] - xorig[3 * j + 2]};
                    double l = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                    hmin[i] = fmin(hmin[i], l);
                    hmin[j] = fmin(hmin[j], l);
                }
        unsigned char* fixed = held_x_ends(m); // the cut between
        hs_cut_def def = hs_cut_default_def(); // validated after every sweep
        hs_cut* c = NULL;
        hs_err e;
        ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
        // Tool axis (0.3, 0, 1) as cut_across.probe, or vertical; the blade's plane contains
        // the axis and the travel (y), so its normal is axis x y.
        double ax[3] = {tilt ? 0.3 : 0.0, 0, 1}, al = sqrt(ax[0] * ax[0] + 1.0);
        ax[0] /= al, ax[2] /= al;
        double nrm[3] = {-ax[2], 0, ax[0]};
        const double tip[3] = {1 * MM, 0, 2 * MM};
        int removed = 0, hinges = 0;
        for (double y = -0.05; y < 0.05 - 1e-9; y += sweep) {
            double p0[3], q0[3], p1[3], q1[3];
            for (int d = 0; d < 3; d++) {
                p0[d] = p1[d] = tip[d] - 3 * MM * ax[d];
                q0[d] = q1[d] = tip[d] + 5 * MM * ax[d];
            }
            p0[1] += y, q0[1] += y, p1[1] += y + sweep, q1[1] += y + sweep;
            hs_cut_result r;
            ENSURE(hs_cut_sweep(c, p0, q0, p1, q1, NULL, &r, &e) == HS_OK);
            removed += r.removed;
            hinges += r.hinges;
        }
        ENSURE(removed > 0);
        int comps = hs_cut_components(c);
        ENSURE(hs_cut_live_mesh(c)->n_nodes == n);
        double worst_move = 0, worst_excess = 0, worst_in = 0;
        int moved = 0, worst_v = -1;
        for (int i = 0; i < n; i++) {
            double d[3], dist = 0, dn = 0;
            for (int k = 0; k < 3; k++) {
                d[k] = m->x0[3 * i + k] - xorig[3 * i + k];
                dist += (xorig[3 * i + k] - tip[k]) * nrm[k];
                dn += d[k] * nrm[k];
            }
            double mv = sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            if (mv == 0) continue;
            moved++;
            worst_move = fmax(worst_move, mv);
            worst_in = fmax(worst_in, sqrt(fmax(0, mv * mv - dn * dn))); // within the plane
            if ((mv - fabs(dist)) / hmin[i] > worst_excess)
                worst_excess = (mv - fabs(dist)) / hmin[i], worst_v = i;
        }
        printf("  %.2f mm sweeps, %s blade: %d tets removed, %d hinges, %d vertices moved, %d "
               "piece(s); largest move %.2f mm, within the blade's plane %.2f mm; largest move "
               "beyond the plane distance %.3f of the shortest edge (node %d)\n",
               sweep / MM, tilt ? "tilted" : "vertical", removed, hinges, moved, comps,
               worst_move / MM, worst_in / MM, worst_excess, worst_v);
        ENSURE(moved > 20);
        // Every run reported first. The drag also left the tilted cut's sides joined. The drag
        // bound is the 0.5 mm sweeps' (the server's); the 0.2 mm tilted one reaches 0.052.
        fail |= (sweep == k_sweep[0] && !(worst_excess <= 0.05)) || comps != 2;
        hs_cut_destroy(&c);
        hs_free(fixed);
        hs_free(hmin);
        hs_free(xorig);
        hs_mesh_destroy(&m);
    }
    ENSURE(!fail);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// Partial-depth cut from the top of the patch, opened by a 5 mm lateral pull: the wound's faces
/// separate in a V whose angle is measured from the gap at the top and one layer down.
static int test_skin_wound_angle(void) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = load_shared("skin_patch_synthetic.msh");
    ENSURE(m);
    const int n = m->n_nodes;
    double* xorig = hs_alloc(sizeof(double) * 3 * (size_t)n);
    memcpy(xorig, m->x0, sizeof(double) * 3 * (size_t)n);
    unsigned char* fixed = held_x_ends(m); // the cut between
    hs_cut_def def = hs_cut_default_def();
    hs_cut* c = NULL;
    hs_err e;
    ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
    // The body that will be opened exists before the cut (as in the simulator) and follows it.
    hs_body_def bd = hs_body_default_def();
    hs_body* b = NULL;
    ENSURE(hs_body_create(m, &bd, fixed, &b, &e) == HS_OK);
    // Blade from 1 mm above the bottom to above the top, along y in [-20, 20] mm, in 4 sweeps.
    const double xc = 1 * MM;
    for (int k = 0; k < 4; k++) {
        double y0 = -0.02 + 0.01 * k, y1 = y0 + 0.01;
        double p0[3] = {xc, y0, 1 * MM}, q0[3] = {xc, y0, 6 * MM};
        double p1[3] = {xc, y1, 1 * MM}, q1[3] = {xc, y1, 6 * MM};
        ENSURE(hs_cut_sweep(c, p0, q0, p1, q1, NULL, NULL, &e) == HS_OK);
        ENSURE(hs_cut_sync_fem(c, hs_body_fem(b)) == HS_OK);
    }
    ENSURE(hs_cut_components(c) == 1); // partial: still one piece
    int pinned = 0;
    for (int i = 0; i < n; i++) pinned += hs_cut_node_pinned(c, i);
    ENSURE(pinned == 0); // the body has no pin springs: a pinned node would make it singular

    // Open it: the ends move 2.5 mm apart each (prescribed displacements).
    for (int i = 0; i < n; i++) {
        if (!fixed[i]) continue;
        double up[3] = {xorig[3 * i] < 0 ? -2.5 * MM : 2.5 * MM, 0, 0};
        ENSURE(hs_body_set_prescribed(b, i, up) == HS_OK);
    }
    ENSURE(hs_body_solve_static(b, NULL) == HS_OK);
    const double* u = hs_body_displacement(b);
    // Gap across the wound at the top (z = 4 mm) and at z = 2 mm, near y = 0.
    double g[2] = {0, 0};
    for (int layer = 0; layer < 2; layer++) {
        double z = layer == 0 ? 4 * MM : 2 * MM, a = 0, bb = 0;
        int na = 0, nb = 0;
        for (int i = 0; i < n; i++) {
            if (fabs(m->x0[3 * i] - xc) > 1e-9 || fabs(m->x0[3 * i + 2] - z) > 1e-9 ||
                fabs(m->x0[3 * i + 1]) > 8.5 * MM)
                continue;
            if (xorig[3 * i] < xc) {
                a += u[3 * i];
                na++;
            } else {
                bb += u[3 * i];
                nb++;
            }
        }
        ENSURE(na > 0 && nb > 0);
        g[layer] = bb / nb - a / na;
    }
    double angle = 2.0 * atan((g[0] - g[1]) / 2.0 / (2 * MM)) * 180.0 / 3.14159265358979323846;
    printf("  wound gap %.3f mm at the top, %.3f mm 2 mm down: opening angle %.1f deg\n", g[0] / MM,
           g[1] / MM, angle);
    ENSURE(g[0] > 0.1 * MM); // the faces separate
    ENSURE(g[0] > g[1]);
    ENSURE(angle > 1.0 && angle < 170.0);
    hs_body_destroy(&b);
    hs_cut_destroy(&c);
    hs_free(fixed);
    hs_free(xorig);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// A 6 x 6 x 2-cell plate held at both x ends, cut along its plane of vertices x = 30 mm by a
/// blade from its tip at zt up to zq (leaning by tilt in x per unit of z), in 2 mm sweeps from y0
/// to y1, the tip as the quad's p end (or q with flip), then (pivot) one sweep that turns the
/// blade about its tip (p0 == p1: a flat triangle in the quad). Reports the hinges, the tets
/// removed and of them those lying at or below the tip, and the pieces.
typedef struct plane_blade {
    double zt, zq, y0, y1;
    int flip, pivot;
    double tilt, dx; // dx: the blade's tip at x = 30 mm + dx
} plane_blade;

static int plane_cut(plane_blade b, int out[4]) {
    const double zt = b.zt;
    hs_mesh* m = NULL;
    hs_err e;
    ENSURE(hs_mesh_create_box(0.06, 0.06, 0.01, 6, 6, 2, &m, &e) == HS_OK);
    unsigned char* fixed = held_x_ends(m); // the cut between
    hs_cut_def def = hs_cut_default_def();
    hs_cut* c = NULL;
    ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
    memset(out, 0, 4 * sizeof(int));
    for (int k = 0; b.y0 + 2 * MM * k < b.y1 - 1e-9; k++) {
        double ya = b.y0 + 2 * MM * k, yb = b.y0 + 2 * MM * (k + 1);
        const double xt = 0.03 + b.dx, xq = xt + b.tilt * (b.zq - zt);
        double t0[3] = {xt, ya, zt}, u0[3] = {xq, ya, b.zq};
        double t1[3] = {xt, yb, zt}, u1[3] = {xq, yb, b.zq};
        hs_cut_result r;
        if (b.flip)
            ENSURE(hs_cut_sweep(c, u0, t0, u1, t1, NULL, &r, &e) == HS_OK);
        else
            ENSURE(hs_cut_sweep(c, t0, u0, t1, u1, NULL, &r, &e) == HS_OK);
        out[0] += r.hinges;
        out[1] += r.removed;
    }
    if (b.pivot) { // back over the plate about the tip, from y = 30 mm
        double p[3] = {0.03, 0.03, zt}, q0[3] = {0.03, 0.03, 11 * MM};
        double q1[3] = {0.03, 0.03 + 8 * MM, zt + 2 * MM};
        hs_cut_result r;
        ENSURE(hs_cut_sweep(c, p, q0, p, q1, NULL, &r, &e) == HS_OK);
        out[0] += r.hinges;
        out[1] += r.removed;
    }
    ENSURE(hs_cut_validate(c, &e) == HS_OK);
    for (int t = 0; t < m->n_tets; t++) {
        if (hs_cut_tet_active(c, t)) continue;
        double zmax = -INFINITY;
        for (int a = 0; a < 4; a++) zmax = fmax(zmax, m->x0[3 * m->tets[4 * t + a] + 2]);
        out[2] += zmax <= zt + 1e-9;
    }
    out[3] = hs_cut_components(c);
    {
        double* f = hs_calloc(6 * (size_t)m->n_nodes, sizeof(double));
        for (int i = 0; i < m->n_nodes; i++) f[3 * i + 2] = -1e-3;
        ENSURE(fresh_solve(c, m, fixed, f, f + 3 * m->n_nodes) == HS_OK); // every piece held
        hs_free(f);
    }
    hs_cut_destroy(&c);
    hs_free(fixed);
    hs_mesh_destroy(&m);
    return 0;
}

/// A blade along a plane of mesh vertices: no edge crosses it, so no tet was cut and the plate
/// stayed whole. The vertices on the blade's path are hinges; the smaller side's tets at each
/// go and the plate comes apart. A vertex on the path of the blade's tip (or on its leading
/// edge) is not a hinge: it has tets on both sides because the cut ends there (with it, a tip
/// 1 nm above the middle layer removed 34 tets below the tip, 100 nm above none). A blade
/// turning about its tip (a flat triangle in the quad, whose zero normal once let every nearby
/// vertex in: an overflow under ASan) changes nothing it should not.
static int test_cut_along_mesh_plane(void) {
    int64_t bytes = hs_byte_count();
    // Through the plate: past its faces, or ending exactly on them (nothing lies beyond an end
    // there, so its vertices are hinges too), starting on vertices or between them; the last
    // two leaning, the tip on the bottom face (the tets' corners off the blade's plane, taken
    // for tissue past its end, left those tip vertices joining the sides).
    static const plane_blade k_through[] = {
        {-1 * MM, 11 * MM, -5 * MM, 65 * MM, 0, 0, 0, 0},
        {-1 * MM, 11 * MM, -4 * MM, 60 * MM, 0, 0, 0, 0},
        {0, 11 * MM, -5 * MM, 65 * MM, 0, 0, 0, 0},
        {-1 * MM, 10 * MM, -5 * MM, 65 * MM, 1, 0, 0, 0},
        {0, 10 * MM, -4 * MM, 60 * MM, 1, 0, 0, 0},
        {0, 11 * MM, -5 * MM, 65 * MM, 0, 0, 0.05, 0},
        {0, 11 * MM, -5 * MM, 65 * MM, 0, 0, 0.3, 0},
    };
    for (size_t k = 0; k < sizeof k_through / sizeof k_through[0]; k++) {
        const plane_blade* b = &k_through[k];
        int o[4];
        ENSURE(plane_cut(*b, o) == 0);
        printf("  through, z %g..%g mm, y %g..%g mm, tilt %g: %d hinges, %d tets removed of 432, "
               "%d piece(s)\n",
               b->zt / MM, b->zq / MM, b->y0 / MM, b->y1 / MM, b->tilt, o[0], o[1], o[3]);
        ENSURE(o[0] > 0 && o[3] == 2);
        // Upright, one layer of cells at most: the tets of one side touching the plane.
        ENSURE(o[1] > 0 && (b->tilt != 0 || o[1] <= 6 * 6 * 2));
    }
    // Down to the middle layer, the tip as either end of the quad, sweeps starting between
    // vertices or on them (y0 = -4 mm: p0 lands on y = 0, 10, ... mm).
    static const double k_tip[3] = {5 * MM, 5 * MM + 1e-9, 5 * MM + 1e-7};
    for (int k = 0; k < 3; k++)
        for (int v = 0; v < 8; v++) {
            plane_blade b = {
                k_tip[k], 11 * MM, v & 1 ? -4 * MM : -5 * MM, 65 * MM, v >> 1 & 1, v >> 2, 0, 0};
            int o[4];
            ENSURE(plane_cut(b, o) == 0);
            printf("  tip %.7f mm as %c, from y %g mm%s: %d hinges, %d tets removed, %d at or "
                   "below the tip, %d piece(s)\n",
                   b.zt / MM, b.flip ? 'q' : 'p', b.y0 / MM, b.pivot ? ", then a pivot" : "", o[0],
                   o[1], o[2], o[3]);
            ENSURE(o[0] > 0 && o[1] > 0); // the upper layer's hinges
            ENSURE(o[2] == 0 && o[3] == 1);
        }
    // Off the vertex plane (x = 31 mm), the tip exactly on the middle layer: that layer's edges
    // cross the blade's plane on the tip's path, which counted as a crossing (18 tets below the
    // tip went).
    for (int tilt = 0; tilt < 2; tilt++) {
        plane_blade b = {5 * MM, 11 * MM, -5 * MM, 65 * MM, 0, 0, 0.3 * tilt, 1 * MM};
        int o[4];
        ENSURE(plane_cut(b, o) == 0);
        printf("  tip on the middle layer at x = 31 mm, tilt %g: %d tets removed, %d at or below "
               "the tip, %d piece(s)\n",
               b.tilt, o[1], o[2], o[3]);
        ENSURE(o[1] > 0 && o[2] == 0 && o[3] == 1);
    }
    // A 1 x 4 x 2-cell bar swept whole at once, by a blade turning about its tip and by a full
    // quad: every vertex is a candidate, and the moved ones were listed again, past the list's
    // n entries (a heap overflow under ASan, found in review).
    for (int flat = 0; flat < 2; flat++) {
        hs_mesh* m = NULL;
        hs_err e;
        ENSURE(hs_mesh_create_box(0.01, 0.04, 0.01, 1, 4, 2, &m, &e) == HS_OK);
        unsigned char* fixed = hs_calloc((size_t)m->n_nodes, 1);
        hs_mesh_select_plane(m, 1, -1, 1e-6, fixed);
        hs_cut_def def = hs_cut_default_def();
        hs_cut* c = NULL;
        ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
        const double X = 0.0037;
        double p0[3] = {X, -0.01, -0.005}, q0[3] = {X, -0.01, 0.03}, q1[3] = {X, 0.05, 0.03};
        double p1[3] = {X, flat ? -0.01 : 0.05, -0.005};
        hs_cut_result r;
        ENSURE(hs_cut_sweep(c, p0, q0, p1, q1, NULL, &r, &e) == HS_OK);
        ENSURE(r.moved > 0 && hs_cut_validate(c, &e) == HS_OK);
        hs_cut_destroy(&c);
        hs_free(fixed);
        hs_mesh_destroy(&m);
    }
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// ~20 cuts on a small plate (progressive, curved, random): after each, a fem built before the
/// cuts and kept in step by hs_cut_sync_fem equals one built from scratch on the cut mesh (K x),
/// and the cut body's stiffness from scratch is positive definite (every piece held).
static int test_consistency(void) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    hs_err e;
    ENSURE(hs_mesh_create_box(0.06, 0.06, 0.01, 6, 6, 2, &m, &e) == HS_OK);
    const int n = m->n_nodes;
    unsigned char* fixed = hs_calloc((size_t)n, 1);
    hs_mesh_select_plane(m, 0, -1, 1e-6, fixed);
    int* dof = hs_alloc(sizeof(int) * 3 * (size_t)n);
    int nf = 0;
    for (int k = 0; k < 3 * n; k++) dof[k] = fixed[k / 3] ? -1 : nf++;
    hs_cut_def def = hs_cut_default_def();
    hs_cut* c = NULL;
    ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
    hs_fem* synced = NULL; // on the mesh before the first cut, as a body's
    hs_fem_def fd = hs_fem_default_def();
    fd.model = HS_MODEL_LINEAR;
    ENSURE(hs_fem_create(m, &fd, dof, nf, &synced, &e) == HS_OK);
    hs_fem_update(synced, m->x0, NULL);
    double* f = hs_calloc(6 * (size_t)n, sizeof(double));
    for (int i = 0; i < n; i++) f[3 * i + 2] = -1e-3;
    int with_change = 0;
    for (int k = 0; k < 20; k++) {
        double p0[3], q0[3], p1[3], q1[3];
        if (k < 8) { // a curved progressive cut: the blade turns while it advances
            double a0 = 0.12 * k, a1 = 0.12 * (k + 1);
            double cx0 = 0.033 + 0.005 * sin(a0), cx1 = 0.033 + 0.005 * sin(a1);
            p0[0] = q0[0] = cx0;
            p1[0] = q1[0] = cx1;
            p0[1] = q0[1] = 0.005 + 0.005 * k;
            p1[1] = q1[1] = 0.005 + 0.005 * (k + 1);
            p0[2] = p1[2] = 0.004;
            q0[2] = q1[2] = 0.02;
        } else { // random short sweeps
            for (int d = 0; d < 3; d++) {
                double ctr = (d == 2 ? 0.01 : 0.06) * urand();
                double bl = (urand() - 0.5) * 0.02, mv = (urand() - 0.5) * 0.01;
                p0[d] = ctr - bl;
                q0[d] = ctr + bl;
                p1[d] = p0[d] + mv;
                q1[d] = q0[d] + mv;
            }
        }
        hs_cut_result r;
        hs_status st = hs_cut_sweep(c, p0, q0, p1, q1, NULL, &r, &e);
        if (st != HS_OK) printf("  sweep %d: %s\n", k, e.msg);
        ENSURE(st == HS_OK);
        ENSURE(hs_cut_sync_fem(c, synced) == HS_OK);
        ENSURE(r.changed_elements == hs_cut_last_removed(c, NULL) + hs_cut_last_changed(c, NULL));
        if (r.changed_elements == 0) continue;
        with_change++;
        ENSURE(synced_vs_rebuilt(c, synced, dof, nf) <= 1e-10);
        ENSURE(fresh_solve(c, m, fixed, f, f + 3 * n) == HS_OK);
    }
    printf("  %d cuts with changes\n", with_change);
    ENSURE(with_change >= 10);
    hs_free(f);
    hs_fem_destroy(&synced);
    hs_free(dof);
    hs_free(fixed);
    hs_cut_destroy(&c);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// Rules on a small box (40 x 40 x 10 mm, 4 x 4 x 1 hexes, x = 0 held): a far piece cut free is
/// dropped (DROP) or pinned in place (FIX); a corner sliced off orphans its vertices, which are
/// pinned (ORPHAN_PIN) or keep their tets (the paper's rule) unless those hang on by an edge.
static int test_rules(void) {
    int64_t bytes = hs_byte_count();
    for (int variant = 0; variant < 4; variant++) {
        hs_mesh* m = NULL;
        hs_err e;
        ENSURE(hs_mesh_create_box(0.04, 0.04, 0.01, 4, 4, 1, &m, &e) == HS_OK);
        const int n = m->n_nodes;
        unsigned char* fixed = hs_calloc((size_t)n, 1);
        hs_mesh_select_plane(m, 0, -1, 1e-6, fixed);
        hs_cut_def def = hs_cut_default_def();
        if (variant == 1) def.fragment = HS_CUT_FRAGMENT_FIX;
        if (variant == 3) def.orphan = HS_CUT_ORPHAN_KEEP_TET;
        hs_cut* c = NULL;
        ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
        int ne0 = hs_cut_live_mesh(c)->n_tets;
        hs_cut_result r;
        if (variant < 2) {
            // A blade spanning the depth at x = 25 mm swept across y: the hexes in [20, 30] mm
            // go, those in [30, 40] mm form a free piece.
            double p0[3] = {0.025, -0.005, -0.005}, q0[3] = {0.025, -0.005, 0.015};
            double p1[3] = {0.025, 0.045, -0.005}, q1[3] = {0.025, 0.045, 0.015};
            ENSURE(hs_cut_sweep(c, p0, q0, p1, q1, NULL, &r, &e) == HS_OK);
        } else {
            // Slice the corner (40, 0, *) off: every tet of its two vertices is cut.
            double p0[3] = {0.035, -0.005, -0.005}, q0[3] = {0.035, -0.005, 0.015};
            double p1[3] = {0.035, 0.003, -0.005}, q1[3] = {0.035, 0.003, 0.015};
            ENSURE(hs_cut_sweep(c, p0, q0, p1, q1, NULL, &r, &e) == HS_OK);
        }
        ENSURE(r.cut_tets > 0);
        ENSURE(hs_cut_validate(c, &e) == HS_OK); // includes: no free vertex without a tet
        int pinned = 0;
        for (int i = 0; i < n; i++) pinned += hs_cut_node_pinned(c, i);
        int ne1 = hs_cut_live_mesh(c)->n_tets;
        printf("  variant %d: cut %d removed %d kept %d moved %d clamped %d pinned %d pieces %d\n",
               variant, r.cut_tets, r.removed, r.kept, r.moved, r.clamped, pinned, r.fragments);
        if (variant == 0) { // dropped: only the held piece remains
            ENSURE(r.fragments == 1);
            ENSURE(hs_cut_components(c) == 1);
            ENSURE(pinned > 0 && ne1 < ne0 - r.cut_tets);
        } else if (variant == 1) { // fixed in place: two pieces, the free one pinned
            ENSURE(r.fragments == 1);
            ENSURE(hs_cut_components(c) == 2);
            ENSURE(pinned > 0 && ne1 == ne0 - r.removed);
        } else if (variant == 2) { // orphans pinned, the tets go
            ENSURE(r.fragments == 0 && r.kept == 0);
            ENSURE(pinned > 0 && r.removed == r.cut_tets);
        } else {
            // The paper's rule keeps a tet holding the corner; here it then hangs on by an edge
            // (a mechanism: K singular), so the free-piece rule drops it after all.
            ENSURE(r.kept > 0);
            ENSURE(pinned == 0 || r.fragments > 0);
            ENSURE(r.removed <= r.cut_tets - r.kept + (r.fragments > 0 ? r.kept : 0));
        }
        // What is left is held: its stiffness from scratch is positive definite.
        double* f = hs_calloc(3 * (size_t)n, sizeof(double));
        double* u = hs_calloc(3 * (size_t)n, sizeof(double));
        for (int i = 0; i < n; i++) f[3 * i + 2] = -1e-3;
        ENSURE(fresh_solve(c, m, fixed, f, u) == HS_OK);
        hs_free(f);
        hs_free(u);
        hs_free(fixed);
        hs_cut_destroy(&c);
        hs_mesh_destroy(&m);
    }
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// The free-piece check: a progressive cut across a plate held at x = 0 settles each step by a
/// short search from the removed tets' neighbours, until the step that frees the far piece,
/// which the full check finds (and drops or pins), in both fragment modes.
static int test_piece_check(void) {
    int64_t bytes = hs_byte_count();
    for (int variant = 0; variant < 2; variant++) {
        hs_mesh* m = NULL;
        hs_err e;
        ENSURE(hs_mesh_create_box(0.04, 0.04, 0.01, 8, 8, 2, &m, &e) == HS_OK);
        const int n = m->n_nodes, ne = m->n_tets;
        unsigned char* fixed = hs_calloc((size_t)n, 1);
        hs_mesh_select_plane(m, 0, -1, 1e-6, fixed);
        hs_cut_def def = hs_cut_default_def(); // validated after every sweep
        if (variant == 1) def.fragment = HS_CUT_FRAGMENT_FIX;
        hs_cut* c = NULL;
        ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
        int short_checks = 0, full_checks = 0, freed_at = -1;
        for (int s = 0; s < 12; s++) {
            double y0 = -0.004 + 0.004 * s, y1 = y0 + 0.004;
            double p0[3] = {0.0255, y0, -0.005}, q0[3] = {0.0255, y0, 0.015};
            double p1[3] = {0.0255, y1, -0.005}, q1[3] = {0.0255, y1, 0.015};
            hs_cut_result r;
            ENSURE(hs_cut_sweep(c, p0, q0, p1, q1, NULL, &r, &e) == HS_OK);
            if (r.removed == 0) {
                ENSURE(r.piece_check_tets == 0);
                continue;
            }
            if (r.piece_check_tets < ne)
                short_checks++;
            else
                full_checks++;
            if (r.fragments) {
                ENSURE(freed_at < 0 && r.fragments == 1 && r.piece_check_tets >= ne);
                freed_at = s;
            }
        }
        printf("  variant %d: %d steps settled by the short search, %d full checks, the far "
               "piece freed at step %d\n",
               variant, short_checks, full_checks, freed_at);
        ENSURE(freed_at >= 8);     // the blade leaves the plate at y = 40 mm
        ENSURE(short_checks >= 5); // the steps before it, but the first
        ENSURE(full_checks <= 3);  // the first removal, the freeing step (and one more at most)
        int pinned = 0;
        for (int i = 0; i < n; i++) pinned += hs_cut_node_pinned(c, i);
        if (variant == 0) // dropped: one piece left (pieces touching at a node count as one)
            ENSURE(hs_cut_components(c) == 1);
        else // pinned in place: its nodes, every one past the blade
            ENSURE(pinned >= 3 * 9);
        hs_cut_destroy(&c);
        hs_free(fixed);
        hs_mesh_destroy(&m);
    }
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// Cutting a deformed body: crossings use x0 + u, moves land on the blade in current space.
static int test_deformed_and_bad_input(void) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    hs_err e;
    ENSURE(hs_mesh_create_box(0.04, 0.04, 0.01, 4, 4, 1, &m, &e) == HS_OK);
    const int n = m->n_nodes;
    unsigned char* fixed = hs_calloc((size_t)n, 1);
    hs_mesh_select_plane(m, 0, -1, 1e-6, fixed);
    hs_cut_def def = hs_cut_default_def();
    hs_cut* c = NULL;
    def.min_quality = NAN;
    ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_ERR_INVALID && c == NULL);
    ENSURE(strstr(e.msg, "guard"));
    def.min_quality = 0.02;
    ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
    double bad[3] = {NAN, 0, 0}, ok[3] = {0, 0, 0};
    ENSURE(hs_cut_sweep(c, bad, ok, ok, ok, NULL, NULL, &e) == HS_ERR_INVALID);
    ENSURE(strstr(e.msg, "blade"));
    ENSURE(hs_cut_topology_version(c) == 0);
    // A uniform shear u = (0.2 z, 0, 0): the blade plane x = 22 mm in current space.
    double* u = hs_calloc(3 * (size_t)n, sizeof(double));
    for (int i = 0; i < n; i++) u[3 * i] = 0.2 * m->x0[3 * i + 2];
    double p0[3] = {0.022, 0.012, -0.005}, q0[3] = {0.022, 0.012, 0.015};
    double p1[3] = {0.022, 0.028, -0.005}, q1[3] = {0.022, 0.028, 0.015};
    hs_cut_result r;
    ENSURE(hs_cut_sweep(c, p0, q0, p1, q1, u, &r, &e) == HS_OK);
    ENSURE(r.moved > 0);
    const int* mv = NULL;
    int nm = hs_cut_last_moved(c, &mv);
    ENSURE(nm == r.moved);
    int on = 0;
    for (int k = 0; k < nm; k++) {
        int v = mv[k];
        double xc = m->x0[3 * v] + u[3 * v];
        // interior, unclamped moves land on the plane in current positions
        if (fabs(xc - 0.022) < 1e-9) on++;
        ENSURE(isfinite(u[3 * v]));
    }
    ENSURE(on > 0);
    const int* rm = NULL;
    ENSURE(hs_cut_last_removed(c, &rm) == r.removed && r.removed > 0);
    for (int k = 0; k < r.removed; k++) ENSURE(!hs_cut_tet_active(c, rm[k]));
    ENSURE(hs_cut_topology_version(c) == 1);
    hs_free(u);
    hs_free(fixed);
    hs_cut_destroy(&c);
    hs_cut_destroy(&c); // NULL is fine
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// A dynamic co-rotated body under gravity, cut progressively while it sags (the simulator's
/// set-up): each sweep takes the body's current displacement, and the body follows through
/// hs_cut_sync_fem. With KEEP_TET + FIX no node ever loses all its tets, so the body's own
/// matrix (mass included) stays SPD without pins, and every step stays finite.
static int test_dynamic_body(void) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    hs_err e;
    ENSURE(hs_mesh_create_box(0.06, 0.03, 0.01, 6, 3, 1, &m, &e) == HS_OK);
    const int n = m->n_nodes;
    unsigned char* fixed = hs_calloc((size_t)n, 1);
    hs_mesh_select_plane(m, 0, -1, 1e-6, fixed);
    hs_cut_def def = hs_cut_default_def();
    def.orphan = HS_CUT_ORPHAN_KEEP_TET;
    def.fragment = HS_CUT_FRAGMENT_FIX;
    hs_cut* c = NULL;
    ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
    hs_body_def bd = hs_body_default_def();
    bd.fem.model = HS_MODEL_COROTATED;
    bd.fem.material.rayleigh_mass = 5.0;
    bd.gravity[2] = -9.81;
    bd.dt = 0.01;
    hs_body* b = NULL;
    ENSURE(hs_body_create(m, &bd, fixed, &b, &e) == HS_OK);
    double* u = hs_alloc(sizeof(double) * 3 * (size_t)n);
    double* v = hs_alloc(sizeof(double) * 3 * (size_t)n);
    for (int s = 0; s < 20; s++) ENSURE(hs_body_step(b, NULL) == HS_OK); // sag first
    int removed = 0;
    for (int k = 0; k < 8; k++) {
        // Blade across y at x = 25 mm, spanning the sagging depth, advancing 3 mm per step.
        double y0 = -0.002 + 0.003 * k, y1 = y0 + 0.003;
        double p0[3] = {0.025, y0, -0.05}, q0[3] = {0.025, y0, 0.03};
        double p1[3] = {0.025, y1, -0.05}, q1[3] = {0.025, y1, 0.03};
        memcpy(u, hs_body_displacement(b), sizeof(double) * 3 * (size_t)n);
        memcpy(v, hs_body_velocity(b), sizeof(double) * 3 * (size_t)n);
        hs_cut_result r;
        hs_status st = hs_cut_sweep(c, p0, q0, p1, q1, u, &r, &e);
        if (st != HS_OK) printf("  sweep %d: %s\n", k, e.msg);
        ENSURE(st == HS_OK);
        removed += r.removed;
        ENSURE(hs_cut_sync_fem(c, hs_body_fem(b)) == HS_OK);
        hs_body_set_state(b, u, v);
        for (int s = 0; s < 5; s++) ENSURE(hs_body_step(b, NULL) == HS_OK); // finite, else error
    }
    ENSURE(removed > 0);
    const double* ub = hs_body_displacement(b);
    double tip = 0;
    for (int i = 0; i < n; i++) {
        for (int q = 0; q < 3; q++) ENSURE(isfinite(ub[3 * i + q]));
        if (m->x0[3 * i] > 0.06 - 1e-9) tip = fmin(tip, ub[3 * i + 2]);
    }
    printf("  dynamic body: %d tets removed over 8 sweeps, tip sag %.2f mm\n", removed, tip / MM);
    ENSURE(tip < 0);
    hs_free(u);
    hs_free(v);
    hs_free(fixed);
    hs_body_destroy(&b);
    hs_cut_destroy(&c);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// A body with the warped solver follows each sweep without refactoring its rest-state factor
/// (hs_body_change_elements): by a partial refactor of its supernodal factor, or (lowrank: the
/// factor put in update mode first) by a low-rank update. The factor agrees with a fresh one,
/// the steps need no refactor and match a twin body that refactors after each sweep
/// (hs_cut_sync_fem).
static int body_follows_cut(int lowrank) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    hs_err e;
    ENSURE(hs_mesh_create_box(0.06, 0.03, 0.01, 12, 6, 2, &m, &e) == HS_OK);
    const int n = m->n_nodes;
    unsigned char* fixed = hs_calloc((size_t)n, 1);
    hs_mesh_select_plane(m, 0, -1, 1e-6, fixed);
    hs_cut_def def = hs_cut_default_def();
    def.orphan = HS_CUT_ORPHAN_KEEP_TET;
    def.fragment = HS_CUT_FRAGMENT_FIX;
    hs_cut* c = NULL;
    ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
    hs_body_def bd = hs_body_default_def();
    bd.fem.model = HS_MODEL_COROTATED;
    bd.fem.material.youngs_pa = 1e6; // sags a few mm: the blade stays across the beam
    bd.fem.material.rayleigh_mass = 5.0;
    bd.fem.material.rayleigh_stiffness = 0.01;
    bd.gravity[2] = -9.81;
    bd.dt = 0.01;
    bd.solver = HS_SOLVER_WARPED;
    hs_body *a = NULL, *b = NULL, *d = NULL;
    ENSURE(hs_body_create(m, &bd, fixed, &a, &e) == HS_OK); // low-rank updates
    ENSURE(hs_body_create(m, &bd, fixed, &b, &e) == HS_OK); // refactors after each sweep
    bd.solver = HS_SOLVER_DIRECT;
    ENSURE(hs_body_create(m, &bd, fixed, &d, &e) == HS_OK); // no rest factor to keep
    double* u = hs_alloc(sizeof(double) * 3 * (size_t)n);
    double* v = hs_alloc(sizeof(double) * 3 * (size_t)n);
    hs_step_stats sa, sb;
    for (int s = 0; s < 20; s++) {
        ENSURE(hs_body_step(a, &sa) == HS_OK && hs_body_step(b, &sb) == HS_OK);
        ENSURE(hs_body_step(d, NULL) == HS_OK);
    }
    ENSURE(hs_cholesky_is_supernodal(hs_body_factor(a)));
    if (lowrank) ENSURE(hs_cholesky_prepare_updates(hs_body_factor(a), 64) == HS_OK);
    int removed = 0, changed = 0, updates = 0, part = 0, followed = 0;
    double worst_f = 0, worst_u = 0, least_share = 1;
    for (int k = 0; k < 8; k++) { // a partial cut: 25 of the 30 mm width
        double y0 = -0.002 + 0.003 * k, y1 = y0 + 0.003;
        double p0[3] = {0.031, y0, -0.05}, q0[3] = {0.031, y0, 0.03};
        double p1[3] = {0.031, y1, -0.05}, q1[3] = {0.031, y1, 0.03};
        memcpy(u, hs_body_displacement(a), sizeof(double) * 3 * (size_t)n);
        memcpy(v, hs_body_velocity(a), sizeof(double) * 3 * (size_t)n);
        hs_cut_result r;
        ENSURE(hs_cut_sweep(c, p0, q0, p1, q1, u, &r, &e) == HS_OK);
        const int *off, *mv;
        int n_off = hs_cut_last_removed(c, &off), n_mv = hs_cut_last_changed(c, &mv);
        removed += n_off;
        changed += n_mv;
        int lr = -1, lrd = -1;
        ENSURE(hs_body_change_elements(a, n_off, off, n_mv, mv, &lr) == HS_OK);
        ENSURE(hs_body_change_elements(d, n_off, off, n_mv, mv, &lrd) == HS_OK);
        ENSURE(lrd == 0);
        followed += lr == 1; // a sweep that cut nothing counts too (an empty change)
        ENSURE(hs_cut_sync_fem(c, hs_body_fem(b)) == HS_OK);
        if (n_off + n_mv > 0) {
            ENSURE(lr == 1);
            updates++;
            if (!lowrank) { // the first one sets up and does a full pass, the others less
                double share = hs_cholesky_partial_share(hs_body_factor(a));
                ENSURE(share > 0 && share <= 1);
                least_share = fmin(least_share, share);
                part += share < 1;
            }
            double df = INFINITY;
            ENSURE(hs_body_rest_factor_difference(a, &df) == HS_OK);
            worst_f = fmax(worst_f, df);
            ENSURE(df <= 1e-8);
        }
        hs_body_set_state(a, u, v);
        hs_body_set_state(b, u, v);
        hs_body_set_state(d, u, v);
        for (int s = 0; s < 5; s++) {
            ENSURE(hs_body_step(a, &sa) == HS_OK && hs_body_step(b, &sb) == HS_OK);
            ENSURE(hs_body_step(d, NULL) == HS_OK);
            if (s == 0 && n_off + n_mv > 0) ENSURE(sa.refactors == 0 && sb.refactors == 1);
        }
        const double *ua = hs_body_displacement(a), *ub = hs_body_displacement(b);
        double dn = 0, nn = 0;
        for (int i = 0; i < 3 * n; i++) {
            dn = fmax(dn, fabs(ua[i] - ub[i]));
            nn = fmax(nn, fabs(ub[i]));
        }
        worst_u = fmax(worst_u, dn / nn);
    }
    printf("  %s: %d sweeps updated the factor (%d tets off, %d refreshed): factor vs fresh "
           "%.2g, displacement vs refactoring twin %.2g (max rel)",
           lowrank ? "low-rank" : "partial refactor", updates, removed, changed, worst_f, worst_u);
    if (!lowrank) printf("; least share of a factorisation %.2f", least_share);
    printf("\n");
    ENSURE(removed > 0 && updates >= 5);
    ENSURE(lowrank ? !hs_cholesky_is_supernodal(hs_body_factor(a)) : part >= updates - 1);
    ENSURE(hs_body_lowrank_updates(a) == followed && followed >= updates);
    ENSURE(hs_body_lowrank_updates(d) == 0);
    ENSURE(worst_u <= 1e-8);
    // Bad input changes nothing.
    int bad = m->n_tets;
    ENSURE(hs_body_change_elements(a, 1, &bad, 0, NULL, NULL) == HS_ERR_INVALID);
    double df = 0;
    ENSURE(hs_body_rest_factor_difference(a, &df) == HS_OK && df <= 1e-8);
    hs_free(u);
    hs_free(v);
    hs_free(fixed);
    hs_body_destroy(&a);
    hs_body_destroy(&b);
    hs_body_destroy(&d);
    hs_cut_destroy(&c);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

static int test_body_follows_cut(void) {
    ENSURE(body_follows_cut(0) == 0);
    ENSURE(body_follows_cut(1) == 0);
    return 0;
}

/// Every allocation of hs_cut_create and of a first sweep failing in turn: a clean error, no
/// leak, and the mesh untouched by a failed create.
static int test_alloc_faults(void) {
    int64_t bytes = hs_byte_count();
    hs_mesh* m = NULL;
    hs_err e;
    ENSURE(hs_mesh_create_box(0.03, 0.03, 0.01, 3, 3, 1, &m, &e) == HS_OK);
    unsigned char* fixed = hs_calloc((size_t)m->n_nodes, 1);
    hs_mesh_select_plane(m, 0, -1, 1e-6, fixed);
    hs_cut_def def = hs_cut_default_def();
    int failed = 0, ok = 0;
    for (int k = 1; k < 400 && !ok; k++) {
        int64_t before = hs_byte_count();
        hs_cut* c = NULL;
        hs_alloc_fail_after(k);
        hs_status st = hs_cut_create(m, fixed, &def, &c, &e);
        hs_alloc_fail_after(0);
        if (st == HS_OK) {
            ok = 1;
            hs_cut_destroy(&c);
        } else {
            failed++;
            ENSURE(st < 0 && c == NULL);
        }
        ENSURE(hs_byte_count() == before);
    }
    ENSURE(ok && failed > 10);
    hs_free(fixed);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// 1,000 random short sweeps through the liver: validator after every cut (inside the sweep),
/// no orphan; every 50 cuts the stiffness from scratch on the cut mesh is positive definite and
/// its solve finite (every piece left is held).
static int test_liver_random_cuts(void) {
    int64_t bytes = hs_byte_count();
    g_rng = 0x9e3779b97f4a7c15ull; // its own seed
    char path[512];
    snprintf(path, sizeof path, "%s/scenes/liver/liver2.msh", HS_SOURCE_DIR);
    hs_mesh* m = NULL;
    hs_err e;
    ENSURE(hs_mesh_load(path, &m, &e) >= 0);
    const int n = m->n_nodes;
    unsigned char* fixed = hs_calloc((size_t)n, 1);
    double ext[3];
    for (int d = 0; d < 3; d++) ext[d] = m->bbox_max[d] - m->bbox_min[d];
    double diag = sqrt(ext[0] * ext[0] + ext[1] * ext[1] + ext[2] * ext[2]);
    ENSURE(hs_mesh_select_plane(m, 2, -1, 0.25 * ext[2], fixed) > 0);
    hs_cut_def def = hs_cut_default_def();
    hs_cut* c = NULL;
    ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
    double* f = hs_calloc(3 * (size_t)n, sizeof(double));
    double* u = hs_calloc(3 * (size_t)n, sizeof(double));
    int total_removed = 0, fragments = 0, cutting = 0;
    double max_ms = 0;
    for (int k = 0; k < 1000; k++) {
        double ctr[3], bl[3], mv[3];
        // Centred on a random remaining tet, so the sweeps keep hitting tissue.
        int t = (int)(urand() * m->n_tets);
        for (int tries = 0; tries < m->n_tets && !hs_cut_tet_active(c, t); tries++)
            t = (t + 1) % m->n_tets;
        for (int d = 0; d < 3; d++) {
            ctr[d] = 0;
            for (int a = 0; a < 4; a++) ctr[d] += 0.25 * m->x0[3 * m->tets[4 * t + a] + d];
            bl[d] = urand() - 0.5;
            mv[d] = urand() - 0.5;
        }
        double bn = sqrt(bl[0] * bl[0] + bl[1] * bl[1] + bl[2] * bl[2]);
        double mn = sqrt(mv[0] * mv[0] + mv[1] * mv[1] + mv[2] * mv[2]);
        double p0[3], q0[3], p1[3], q1[3];
        for (int d = 0; d < 3; d++) {
            p0[d] = ctr[d] - 0.025 * diag * bl[d] / bn;
            q0[d] = ctr[d] + 0.025 * diag * bl[d] / bn;
            p1[d] = p0[d] + 0.015 * diag * mv[d] / mn;
            q1[d] = q0[d] + 0.015 * diag * mv[d] / mn;
        }
        hs_cut_result r;
        hs_status st = hs_cut_sweep(c, p0, q0, p1, q1, NULL, &r, &e);
        if (st != HS_OK) printf("  cut %d: %s\n", k, e.msg);
        ENSURE(st == HS_OK); // includes hs_mesh_check and the cut invariants (def.validate)
        total_removed += r.removed;
        cutting += r.removed > 0;
        fragments += r.fragments;
        max_ms = fmax(max_ms, r.total_ms);
        if (k % 50 == 49) {
            for (int i = 0; i < 3 * n; i++) f[i] = 1e-3 * (urand() - 0.5);
            ENSURE(fresh_solve(c, m, fixed, f, u) == HS_OK);
        }
    }
    ENSURE(hs_cut_validate(c, &e) == HS_OK);
    printf("  1000 cuts (%d removed tets): %d tets removed of %d, %d pieces dropped, %d left; "
           "slowest sweep %.2f ms (validation included)\n",
           cutting, total_removed, m->n_tets, fragments, hs_cut_live_mesh(c)->n_tets, max_ms);
    // Sweeps that removed tets: the organ is used up within 1000 (187-269 seen, fewer since a
    // sweep also takes the tets its moves leave across the blade).
    ENSURE(cutting > 150);
    hs_free(f);
    hs_free(u);
    hs_free(fixed);
    hs_cut_destroy(&c);
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// Whether pins hold (pins_hold), under FIX on a box held at x = 0: a first cut across frees
/// the far part, whose nodes FIX pins; a second cut across splits that part in two. With pins
/// holding (default) both halves are held by the pins; without (a body with no pin springs, as
/// the simulator's) neither is, and both are free pieces.
static int test_pins_hold(void) {
    int64_t bytes = hs_byte_count();
    for (int hold = 0; hold < 2; hold++) {
        hs_mesh* m = NULL;
        hs_err e;
        ENSURE(hs_mesh_create_box(0.08, 0.04, 0.01, 8, 4, 2, &m, &e) == HS_OK);
        unsigned char* fixed = hs_calloc((size_t)m->n_nodes, 1);
        hs_mesh_select_plane(m, 0, -1, 1e-6, fixed);
        hs_cut_def def = hs_cut_default_def();
        def.fragment = HS_CUT_FRAGMENT_FIX;
        def.pins_hold = hold;
        hs_cut* c = NULL;
        ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
        int frag[2] = {0, 0};
        for (int k = 0; k < 2; k++) { // across y at x = 25 mm, then at x = 55 mm
            const double x = k ? 0.0551 : 0.0251;
            const double p0[3] = {x, -0.01, -0.005}, q0[3] = {x, -0.01, 0.015};
            const double p1[3] = {x, 0.05, -0.005}, q1[3] = {x, 0.05, 0.015};
            hs_cut_result r;
            hs_status st = hs_cut_sweep(c, p0, q0, p1, q1, NULL, &r, &e);
            if (st != HS_OK) printf("  %s\n", e.msg);
            ENSURE(st == HS_OK);
            frag[k] = r.fragments;
        }
        printf("  pins_hold %d: free pieces after the first cut %d, after the second %d\n", hold,
               frag[0], frag[1]);
        ENSURE(frag[0] == 1);
        ENSURE(frag[1] == (hold ? 0 : 2));
        hs_cut_destroy(&c);
        hs_free(fixed);
        hs_mesh_destroy(&m);
    }
    ENSURE(hs_byte_count() == bytes);
    return 0;
}

/// The short piece check after a sweep that took the last tets of a fixed node: that node held
/// its piece and now holds nothing, so the full check must run (before, it was skipped and a
/// piece with two holding nodes stayed, hinged). Random short blades near the node, until it
/// happened three times; the validator must pass every time.
static int test_piece_check_lost_hold(void) {
    uint64_t g = 88172645463325252ull;
    int found = 0, trials = 0;
    for (; trials < 5000 && found < 3; trials++) {
        hs_mesh* m = NULL;
        hs_err e;
        ENSURE(hs_mesh_create_box(0.03, 0.03, 0.01, 3, 3, 1, &m, &e) == HS_OK);
        const int n = m->n_nodes, ne = m->n_tets;
        // Three non-collinear fixed nodes on x = 0; C the one with the fewest tets.
        int cnt[64] = {0}, sel[64], ns = 0;
        for (int t = 0; t < 4 * ne; t++) cnt[m->tets[t]]++;
        for (int i = 0; i < n; i++)
            if (m->x0[3 * i] < 1e-9) sel[ns++] = i;
        int C = sel[0], A = -1, B = -1;
        for (int k = 0; k < ns; k++)
            if (cnt[sel[k]] < cnt[C]) C = sel[k];
        for (int k = 0; k < ns; k++) {
            int i = sel[k];
            double dy = m->x0[3 * i + 1] - m->x0[3 * C + 1],
                   dz = m->x0[3 * i + 2] - m->x0[3 * C + 2];
            if (i != C && A < 0 && fabs(dy) > 0.02 && fabs(dz) < 1e-9) A = i;
            if (i != C && B < 0 && fabs(dy) > 0.02 && fabs(dz) > 0.005) B = i;
        }
        ENSURE(A >= 0 && B >= 0);
        unsigned char* fixed = hs_calloc((size_t)n, 1);
        fixed[A] = fixed[B] = fixed[C] = 1;
        hs_cut_def def = hs_cut_default_def();
        def.validate = 0;
        hs_cut* c = NULL;
        ENSURE(hs_cut_create(m, fixed, &def, &c, &e) == HS_OK);
        hs_cut_result r;
        // A first cut away from C (the full check runs: every piece held), then one near C.
        double a0[3] = {0.025, 0.012, -0.01}, b0[3] = {0.025, 0.012, 0.02};
        double a1[3] = {0.025, 0.018, -0.01}, b1[3] = {0.025, 0.018, 0.02};
        ENSURE(hs_cut_sweep(c, a0, b0, a1, b1, NULL, &r, &e) == HS_OK);
        double p0[3], q0[3], p1[3], q1[3];
        for (int d = 0; d < 3; d++) {
            double u[3];
            for (int q = 0; q < 3; q++) {
                g ^= g << 13, g ^= g >> 7, g ^= g << 17;
                u[q] = (double)(g >> 11) / 9007199254740992.0 - 0.5;
            }
            double ctr = m->x0[3 * C + d] + u[0] * 0.012, bl = u[1] * 0.02, mv = u[2] * 0.01;
            p0[d] = ctr - bl, q0[d] = ctr + bl, p1[d] = p0[d] + mv, q1[d] = q0[d] + mv;
        }
        if (hs_cut_sweep(c, p0, q0, p1, q1, NULL, &r, &e) == HS_OK && r.removed > 0) {
            int left = 0;
            for (int t = 0; t < ne; t++)
                if (hs_cut_tet_active(c, t))
                    for (int a = 0; a < 4; a++) left += m->tets[4 * t + a] == C;
            if (left == 0) {
                found++;
                hs_status vs = hs_cut_validate(c, &e);
                printf("  trial %d: fixed node %d lost its last tet; %d fragment(s), piece check "
                       "visited %d tets; validate %d %s\n",
                       trials, C, r.fragments, r.piece_check_tets, (int)vs, vs ? e.msg : "");
                ENSURE(vs == HS_OK);
            }
        }
        hs_cut_destroy(&c);
        hs_free(fixed);
        hs_mesh_destroy(&m);
    }
    ENSURE(found == 3);
    return 0;
}

HS_TEST_MAIN(HS_CASE(test_force_model), HS_CASE(test_skin_full_separation),
             HS_CASE(test_skin_wound_angle), HS_CASE(test_straight_cut_drag),
             HS_CASE(test_cut_along_mesh_plane), HS_CASE(test_consistency), HS_CASE(test_rules),
             HS_CASE(test_pins_hold), HS_CASE(test_piece_check),
             HS_CASE(test_deformed_and_bad_input), HS_CASE(test_dynamic_body),
             HS_CASE(test_body_follows_cut), HS_CASE(test_alloc_faults),
             HS_CASE(test_piece_check_lost_hold), HS_CASE(test_liver_random_cuts))
