// SPDX-License-Identifier: GPL-2.0-or-later
// Tetrahedralisation with gmsh's C API. The surface goes in as a discrete surface entity (nodes
// and triangles through the API, no file), is optionally remeshed at the target size (gmsh's
// tutorial t13 pipeline: classify, create a geometry, a volume bounded by the surfaces), and the
// volume is meshed and optimised. The tets come back through the API into an hs_mesh, which
// validates them as any loaded mesh.
#define _POSIX_C_SOURCE 200809L
#include "mesher.h"

#include <gmshc.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static pthread_mutex_t g_gmsh_lock = PTHREAD_MUTEX_INITIALIZER;

hs_mesher_def hs_mesher_default_def(void) {
    return (hs_mesher_def){.size = 0,
                           .keep_surface = 0,
                           .feature_angle_deg = 40,
                           .optimize = 1,
                           .verbose = 0,
                           .size_at = NULL,
                           .size_ctx = NULL,
                           .size_min = 0,
                           .gmsh_options = NULL};
}

const char* hs_mesher_gmsh_version(void) {
    return GMSH_API_VERSION;
}

// gmsh's last error (or the last logged line) into err.
static hs_status gmsh_fail(hs_err* err, const char* step) {
    int ierr = 0;
    char* last = NULL;
    gmshLoggerGetLastError(&last, &ierr);
    char msg[300] = "";
    if (last && last[0]) snprintf(msg, sizeof msg, "%s", last);
    if (last) gmshFree(last);
    if (!msg[0]) {
        char** log = NULL;
        size_t n = 0;
        gmshLoggerGet(&log, &n, &ierr);
        for (size_t i = 0; i < n; ++i) {
            if (strncmp(log[i], "Error", 5) == 0 || (i + 1 == n && !msg[0]))
                snprintf(msg, sizeof msg, "%s", log[i]);
            gmshFree(log[i]);
        }
        if (log) gmshFree(log);
    }
    return hs_err_set(err, HS_ERR_INVALID, "gmsh %s failed: %s", step,
                      msg[0] ? msg : "(no message)");
}

// "Name=value;Name=value": numbers through gmshOptionSetNumber, anything else as a string.
static hs_status set_gmsh_options(const char* list, hs_err* err) {
    const char* p = list;
    while (*p) {
        const char* end = strchr(p, ';');
        size_t n = end ? (size_t)(end - p) : strlen(p);
        char item[256];
        if (n >= sizeof item)
            return hs_err_set(err, HS_ERR_INVALID, "gmsh option '%.40s...' is too long", p);
        memcpy(item, p, n);
        item[n] = '\0';
        p += n + (end != NULL);
        if (n == 0) continue;
        char* eq = strchr(item, '=');
        if (!eq || eq == item)
            return hs_err_set(err, HS_ERR_INVALID, "gmsh option '%s' is not Name=value", item);
        *eq = '\0';
        char* e;
        double v = strtod(eq + 1, &e);
        int ierr = 0;
        if (eq[1] && !*e)
            gmshOptionSetNumber(item, v, &ierr);
        else
            gmshOptionSetString(item, eq + 1, &ierr);
        if (ierr) {
            hs_err e2 = {0};
            gmsh_fail(&e2, "option");
            return hs_err_set(err, HS_ERR_INVALID, "gmsh option %s=%s refused: %s", item, eq + 1,
                              e2.msg);
        }
    }
    return HS_OK;
}

typedef struct size_cb {
    const hs_mesher_def* def;
    double lo, hi;
} size_cb;

static double size_callback(int dim, int tag, double x, double y, double z, void* data) {
    (void)dim;
    (void)tag;
    const size_cb* c = data;
    const double p[3] = {x, y, z};
    double h = c->def->size_at(p, c->def->size_ctx);
    return !(h >= c->lo) ? c->lo : h > c->hi ? c->hi : h; // NaN -> the smallest
}

// Splits every triangle (1-based node tags) into four at its edge midpoints, in place: xyz and
// tri have room for the new nodes and triangles. scratch holds 3 * nt entries (edge keys).
static void split_triangles(double* xyz, size_t* nv, size_t* tri, size_t* nt, size_t* scratch) {
    size_t n_mid = 0, n0 = *nv, t0 = *nt;
    size_t* key = scratch; // edge (a, b), a < b, as a * (n0 + 1) + b, in order of creation
    for (size_t t = 0; t < t0; ++t) {
        size_t v[3] = {tri[3 * t], tri[3 * t + 1], tri[3 * t + 2]}, m[3];
        for (int k = 0; k < 3; ++k) {
            size_t a = v[k], b = v[(k + 1) % 3];
            size_t ek = a < b ? a * (n0 + 1) + b : b * (n0 + 1) + a, j = 0;
            while (j < n_mid && key[j] != ek) ++j;
            if (j == n_mid) {
                key[n_mid++] = ek;
                for (int d = 0; d < 3; ++d)
                    xyz[3 * (n0 + j) + d] = 0.5 * (xyz[3 * (a - 1) + d] + xyz[3 * (b - 1) + d]);
            }
            m[k] = n0 + j + 1;
        }
        const size_t q[4][3] = {
            {v[0], m[0], m[2]}, {m[0], v[1], m[1]}, {m[2], m[1], v[2]}, {m[0], m[1], m[2]}};
        memcpy(tri + 3 * t, q[0], sizeof q[0]);
        for (int c = 1; c < 4; ++c) memcpy(tri + 3 * (*nt)++, q[c], sizeof q[c]);
    }
    *nv = n0 + n_mid;
}

#define GMSH_TRY(call, step)                                                                       \
    do {                                                                                           \
        ierr = 0;                                                                                  \
        call;                                                                                      \
        if (ierr) return gmsh_fail(err, step);                                                     \
    } while (0)

// Input checks, and a size far below the model, which would ask for billions of tets: refused
// before gmsh tries.
static hs_status mesher_check(const hs_surface* s, const hs_mesher_def* def, hs_err* err) {
    if (!s || !def || s->n_tris < 4 || s->n_verts < 4)
        return hs_err_set(err, HS_ERR_INVALID, "mesher: no closed surface given");
    if (!(def->size > 0) || !isfinite(def->size))
        return hs_err_set(err, HS_ERR_INVALID, "mesher: size must be > 0, got %g", def->size);
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int i = 0; i < s->n_verts; ++i)
        for (int d = 0; d < 3; ++d) {
            lo[d] = fmin(lo[d], s->x[3 * i + d]);
            hi[d] = fmax(hi[d], s->x[3 * i + d]);
        }
    double est = (hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2]) /
                 (def->size * def->size * def->size) * 6;
    if (est > 2e7)
        return hs_err_set(err, HS_ERR_INVALID,
                          "mesher: size %g would give about %.3g tets in a %g x %g x %g box "
                          "(over 20 million): a larger size, or the wrong units?",
                          def->size, est, hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]);
    return HS_OK;
}

// The surface as gmsh takes it: 1-based tags, split until it has enough triangles.
typedef struct gmsh_input {
    size_t nv, nt;
    size_t *ntag, *ttag, *tnod;
    double* xyz;
} gmsh_input;

static void gmsh_input_free(gmsh_input* in) {
    free(in->ntag);
    free(in->ttag);
    free(in->tnod);
    free(in->xyz);
}

static hs_status gmsh_input_make(const hs_surface* s, const hs_mesher_def* def, gmsh_input* in,
                                 hs_err* err) {
    // gmsh 4.8's surface classification for remeshing never returns (it keeps partitioning a
    // patch with METIS) on a tetrahedron's four triangles: tiny surfaces are split 1 -> 4 at
    // their edge midpoints, which keeps their shape, until they have SPLIT_TO triangles.
    enum { SPLIT_TO = 64 };
    size_t nv = (size_t)s->n_verts, nt = (size_t)s->n_tris, nt_cap = nt, nv_cap = nv;
    while (!def->keep_surface && nt_cap < SPLIT_TO) {
        nv_cap += 3 * nt_cap;
        nt_cap *= 4;
    }
    in->ntag = malloc(nv_cap * sizeof(size_t));
    in->ttag = malloc(nt_cap * sizeof(size_t));
    in->tnod = malloc(3 * nt_cap * sizeof(size_t));
    in->xyz = malloc(3 * nv_cap * sizeof(double));
    if (!in->ntag || !in->ttag || !in->tnod || !in->xyz) {
        gmsh_input_free(in);
        return hs_err_set(err, HS_ERR_NOMEM, "mesher: out of memory");
    }
    for (size_t t = 0; t < 3 * nt; ++t) in->tnod[t] = (size_t)s->tris[t] + 1;
    memcpy(in->xyz, s->x, 3 * nv * sizeof(double));
    while (nt < nt_cap) split_triangles(in->xyz, &nv, in->tnod, &nt, in->ntag);
    for (size_t i = 0; i < nv; ++i) in->ntag[i] = i + 1;
    for (size_t t = 0; t < nt; ++t) in->ttag[t] = t + 1;
    in->nv = nv;
    in->nt = nt;
    return HS_OK;
}

// The discrete surface, its classification (or one patch when kept) and the volume inside it.
static hs_status gmsh_add_volume(const gmsh_input* in, const hs_mesher_def* def, hs_err* err) {
    int ierr = 0;
    GMSH_TRY(gmshModelAdd("hapsim", &ierr), "model");
    int sfc;
    GMSH_TRY(sfc = gmshModelAddDiscreteEntity(2, -1, NULL, 0, &ierr), "surface entity");
    GMSH_TRY(gmshModelMeshAddNodes(2, sfc, in->ntag, in->nv, in->xyz, 3 * in->nv, NULL, 0, &ierr),
             "nodes");
    GMSH_TRY(gmshModelMeshAddElementsByType(sfc, 2, in->ttag, in->nt, in->tnod, 3 * in->nt, &ierr),
             "triangles");
    // Keeping the surface: one patch, no parametrisation, so gmsh cannot remesh it.
    const double pi = 3.14159265358979323846;
    GMSH_TRY(
        gmshModelMeshClassifySurfaces(def->keep_surface ? pi : def->feature_angle_deg * pi / 180, 1,
                                      !def->keep_surface, pi, 1, &ierr),
        "surface classification");
    if (!def->keep_surface)
        GMSH_TRY(gmshModelMeshCreateGeometry(NULL, 0, &ierr), "surface parametrisation");
    int* dimtags = NULL;
    size_t ndt = 0;
    GMSH_TRY(gmshModelGetEntities(&dimtags, &ndt, 2, &ierr), "entities");
    int* surfs = malloc((ndt / 2 + 1) * sizeof(int));
    if (!surfs) {
        gmshFree(dimtags);
        return hs_err_set(err, HS_ERR_NOMEM, "mesher: out of memory");
    }
    for (size_t i = 0; i < ndt / 2; ++i) surfs[i] = dimtags[2 * i + 1];
    if (dimtags) gmshFree(dimtags);
    int loop = gmshModelGeoAddSurfaceLoop(surfs, ndt / 2, -1, &ierr);
    free(surfs);
    if (ierr) return gmsh_fail(err, "surface loop");
    GMSH_TRY(gmshModelGeoAddVolume(&loop, 1, -1, &ierr), "volume");
    GMSH_TRY(gmshModelGeoSynchronize(&ierr), "synchronise");
    return HS_OK;
}

// Sizes and meshing options; cb must live until the mesh is generated.
static hs_status gmsh_set_options(const hs_mesher_def* def, size_cb* cb, hs_err* err) {
    int ierr = 0;
    if (def->size_at) {
        GMSH_TRY(gmshModelMeshSetSizeCallback(size_callback, cb, &ierr), "size callback");
        // The callback alone decides: no growth from the boundary, no curvature sizes.
        GMSH_TRY(gmshOptionSetNumber("Mesh.MeshSizeExtendFromBoundary", 0, &ierr), "option");
    }
    GMSH_TRY(gmshOptionSetNumber("Mesh.MeshSizeMin", cb->lo, &ierr), "option");
    GMSH_TRY(gmshOptionSetNumber("Mesh.MeshSizeMax", def->size, &ierr), "option");
    GMSH_TRY(gmshOptionSetNumber("Mesh.Optimize", def->optimize ? 1 : 0, &ierr), "option");
    GMSH_TRY(gmshOptionSetNumber("General.NumThreads", 1, &ierr), "option");
    if (def->gmsh_options) return set_gmsh_options(def->gmsh_options, err);
    return HS_OK;
}

// The tets of a node's tag list: nodes compacted to those the tets use, in tag order.
static hs_status compact_tets(const size_t* node_tags, size_t n_nodes, const double* coord,
                              const size_t* elem_nodes, size_t n_en, hs_mesh** out, hs_err* err) {
    size_t max_tag = 0;
    for (size_t i = 0; i < n_nodes; ++i) max_tag = node_tags[i] > max_tag ? node_tags[i] : max_tag;
    int* map = malloc((max_tag + 1) * sizeof(int));
    int* slot = malloc((max_tag + 1) * sizeof(int)); // tag -> position in node_tags
    double* x = NULL;
    int* tets = NULL;
    hs_status st = HS_OK;
    if (!map || !slot) {
        st = hs_err_set(err, HS_ERR_NOMEM, "mesher: out of memory");
        goto done;
    }
    for (size_t i = 0; i <= max_tag; ++i) map[i] = slot[i] = -1;
    for (size_t i = 0; i < n_nodes; ++i) slot[node_tags[i]] = (int)i;
    for (size_t i = 0; i < n_en; ++i) {
        if (elem_nodes[i] > max_tag || slot[elem_nodes[i]] < 0) {
            st = hs_err_set(err, HS_ERR_INVALID, "gmsh returned a tet with an unknown node");
            goto done;
        }
        map[elem_nodes[i]] = 0;
    }
    int nn = 0;
    for (size_t tg = 0; tg <= max_tag; ++tg)
        if (map[tg] == 0) map[tg] = nn++;
    x = hs_alloc(((size_t)nn * 3 + 1) * sizeof(double));
    tets = hs_alloc((n_en + 1) * sizeof(int));
    if (!x || !tets) {
        st = hs_err_set(err, HS_ERR_NOMEM, "mesher: out of memory");
        goto done;
    }
    for (size_t tg = 0; tg <= max_tag; ++tg)
        if (map[tg] >= 0) memcpy(x + 3 * map[tg], coord + 3 * slot[tg], 3 * sizeof(double));
    for (size_t i = 0; i < n_en; ++i) tets[i] = map[elem_nodes[i]];
    st = hs_mesh_create(nn, x, (int)(n_en / 4), tets, out, err);
done:
    free(map);
    free(slot);
    hs_free(x);
    hs_free(tets);
    return st;
}

// The generated tets out of gmsh.
static hs_status gmsh_read_tets(hs_mesh** out, hs_err* err) {
    int ierr = 0;
    size_t *node_tags = NULL, *elem_tags = NULL, *elem_nodes = NULL;
    double *coord = NULL, *param = NULL;
    size_t n_nodes = 0, n_coord = 0, n_param = 0, n_et = 0, n_en = 0;
    hs_status st = HS_OK;
    gmshModelMeshGetNodes(&node_tags, &n_nodes, &coord, &n_coord, &param, &n_param, -1, -1, 0, 0,
                          &ierr);
    if (ierr) {
        st = gmsh_fail(err, "nodes");
    } else {
        gmshModelMeshGetElementsByType(4, &elem_tags, &n_et, &elem_nodes, &n_en, -1, 0, 1, &ierr);
        if (ierr) st = gmsh_fail(err, "tetrahedra");
    }
    if (st == HS_OK && (n_et == 0 || n_en != 4 * n_et))
        st = hs_err_set(err, HS_ERR_INVALID, "gmsh made no tetrahedra (is the surface closed?)");
    if (st == HS_OK && (n_et > 0x7fffffff / 16 || n_nodes > 0x7fffffff / 16))
        st = hs_err_set(err, HS_ERR_INVALID, "gmsh made %zu tetrahedra: too many", n_et);
    if (st == HS_OK) st = compact_tets(node_tags, n_nodes, coord, elem_nodes, n_en, out, err);
    if (node_tags) gmshFree(node_tags);
    if (coord) gmshFree(coord);
    if (param) gmshFree(param);
    if (elem_tags) gmshFree(elem_tags);
    if (elem_nodes) gmshFree(elem_nodes);
    return st;
}

// One gmsh session (gmsh is process-global: callers are serialised by g_gmsh_lock).
static hs_status gmsh_mesh(const gmsh_input* in, const hs_mesher_def* def, hs_mesh** out,
                           hs_err* err) {
    int ierr = 0;
    GMSH_TRY(gmshInitialize(0, NULL, 0, &ierr), "initialise");
    size_cb cb = {def, def->size_min > 0 ? fmin(def->size_min, def->size) : def->size * 0.5,
                  def->size};
    hs_status st = HS_OK;
    gmshOptionSetNumber("General.Terminal", def->verbose ? 1 : 0, &ierr);
    if (ierr) st = gmsh_fail(err, "option");
    if (st == HS_OK) {
        gmshLoggerStart(&ierr);
        if (ierr) st = gmsh_fail(err, "logger");
    }
    if (st == HS_OK) st = gmsh_add_volume(in, def, err);
    if (st == HS_OK) st = gmsh_set_options(def, &cb, err);
    if (st == HS_OK) {
        gmshModelMeshGenerate(3, &ierr);
        if (ierr) st = gmsh_fail(err, "meshing");
    }
    if (st == HS_OK) st = gmsh_read_tets(out, err);
    gmshLoggerStop(&ierr);
    gmshFinalize(&ierr);
    return st;
}

hs_status hs_mesher_tet(const hs_surface* s, const hs_mesher_def* def, hs_mesh** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "out is NULL");
    *out = NULL;
    hs_status st = mesher_check(s, def, err);
    if (st != HS_OK) return st;
    gmsh_input in = {0};
    st = gmsh_input_make(s, def, &in, err);
    if (st != HS_OK) return st;
    pthread_mutex_lock(&g_gmsh_lock);
    st = gmsh_mesh(&in, def, out, err);
    pthread_mutex_unlock(&g_gmsh_lock);
    gmsh_input_free(&in);
    return st;
}
