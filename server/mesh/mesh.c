// SPDX-License-Identifier: GPL-2.0-or-later
// Mesh core: validation and repair, derived topology (boundary, adjacency), the invariant
// checker, the structured box, node selection and VTK output. The readers are in mesh_read.c.
#include "mesh_internal.h"
#include "vec3.h"

#include <float.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

// Faces of a positively oriented tet, face f opposite vertex f, counter-clockwise seen from
// outside (their normals point away from vertex f).
static const int k_face[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};

// Coordinates beyond this are rejected: volumes and quality products stay finite.
#define HS_MESH_MAX_COORD 1e30
// Absolute floor for a tet volume (m^3) so that underflowing tets count as degenerate.
#define HS_MESH_MIN_VOLUME 1e-200

double hs_tet_volume(const double* x, const int* tet) {
    const double* a = x + 3 * tet[0];
    const double* b = x + 3 * tet[1];
    const double* c = x + 3 * tet[2];
    const double* d = x + 3 * tet[3];
    double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    double v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double w[3] = {d[0] - a[0], d[1] - a[1], d[2] - a[2]};
    return (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) +
            u[2] * (v[0] * w[1] - v[1] * w[0])) /
           6.0;
}

static void free_derived(hs_mesh* m) {
    hs_free(m->tris);
    hs_free(m->tri_tet);
    hs_free(m->surf_nodes);
    hs_free(m->node_surf);
    hs_free(m->node_tet_start);
    hs_free(m->node_tet);
    hs_free(m->node_nbr_start);
    hs_free(m->node_nbr);
    hs_free(m->node_used);
    m->tris = m->tri_tet = m->surf_nodes = m->node_surf = NULL;
    m->node_tet_start = m->node_tet = m->node_nbr_start = m->node_nbr = NULL;
    m->node_used = NULL;
    m->n_tris = 0;
    m->n_surf_nodes = 0;
}

void hs_mesh_destroy(hs_mesh** mesh) {
    if (!mesh || !*mesh) return;
    free_derived(*mesh);
    for (int r = 0; r < (*mesh)->n_regions; ++r) hs_free((*mesh)->regions[r].nodes);
    hs_free((*mesh)->regions);
    hs_free((*mesh)->x0);
    hs_free((*mesh)->tets);
    hs_free(*mesh);
    *mesh = NULL;
}

// ---------------------------------------------------------------------------------------------
// Sorting helpers (qsort has no context argument, so keys travel with their payload).

typedef struct tet_key {
    int k[4]; // sorted node indices
    int t;
} tet_key;

static int cmp_tet_key(const void* pa, const void* pb) {
    const tet_key* a = pa;
    const tet_key* b = pb;
    for (int i = 0; i < 4; ++i)
        if (a->k[i] != b->k[i]) return a->k[i] < b->k[i] ? -1 : 1;
    return (a->t > b->t) - (a->t < b->t);
}

typedef struct face_key {
    int k[3];   // sorted node indices
    int slot;   // 4 * tet + local face
    int parity; // 0 if the outward order is an even permutation of k, else 1
} face_key;

static int cmp_face_key(const void* pa, const void* pb) {
    const face_key* a = pa;
    const face_key* b = pb;
    for (int i = 0; i < 3; ++i)
        if (a->k[i] != b->k[i]) return a->k[i] < b->k[i] ? -1 : 1;
    return (a->slot > b->slot) - (a->slot < b->slot);
}

static int cmp_int(const void* pa, const void* pb) {
    int a = *(const int*)pa, b = *(const int*)pb;
    return (a > b) - (a < b);
}

static void sort4(int k[4]) {
    for (int i = 1; i < 4; ++i)
        for (int j = i; j > 0 && k[j - 1] > k[j]; --j) {
            int s = k[j];
            k[j] = k[j - 1];
            k[j - 1] = s;
        }
}

// Sorts 3 values; returns the permutation parity (0 even, 1 odd).
static int sort3(int k[3]) {
    int parity = 0;
    for (int i = 1; i < 3; ++i)
        for (int j = i; j > 0 && k[j - 1] > k[j]; --j) {
            int s = k[j];
            k[j] = k[j - 1];
            k[j - 1] = s;
            parity ^= 1;
        }
    return parity;
}

static int find_root(int* parent, int i) {
    while (parent[i] != i) {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    return i;
}

// fmin/fmax without the NaN handling (and the library call): inputs are finite here.
static inline double min_d(double a, double b) {
    return b < a ? b : a;
}
static inline double max_d(double a, double b) {
    return b > a ? b : a;
}

// Quality of one positively oriented tet: smallest dihedral angle (deg) and the normalised
// aspect ratio (longest edge / inradius) / (2 sqrt 6), which is 1 for the regular tet.
static void tet_quality(const double* x, const int* tet, double* min_dihedral_deg, double* aspect) {
    const double* p[4];
    for (int i = 0; i < 4; ++i) p[i] = x + 3 * tet[i];
    double longest = 0.0;
    for (int i = 0; i < 4; ++i)
        for (int j = i + 1; j < 4; ++j) {
            double e[3] = {p[j][0] - p[i][0], p[j][1] - p[i][1], p[j][2] - p[i][2]};
            longest = max_d(longest, sqrt(hs_vec3_dot(e, e)));
        }
    double n[4][3], area[4], area_sum = 0.0;
    for (int f = 0; f < 4; ++f) {
        const double* a = p[k_face[f][0]];
        const double* b = p[k_face[f][1]];
        const double* c = p[k_face[f][2]];
        double u[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double v[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        hs_vec3_cross(u, v, n[f]);
        area[f] = 0.5 * sqrt(hs_vec3_dot(n[f], n[f]));
        area_sum += area[f];
    }
    double vol = hs_tet_volume(x, tet);
    double inradius = area_sum > 0.0 ? 3.0 * vol / area_sum : 0.0;
    *aspect = inradius > 0.0 ? longest / inradius / (2.0 * sqrt(6.0)) : INFINITY;
    // The dihedral angle between faces f and g is pi minus the angle of their outward normals.
    double min_deg = 180.0;
    for (int f = 0; f < 4; ++f)
        for (int g = f + 1; g < 4; ++g) {
            double den = 4.0 * area[f] * area[g];
            double c = den > 0.0 ? -hs_vec3_dot(n[f], n[g]) / den : 1.0;
            c = min_d(1.0, max_d(-1.0, c));
            min_deg = min_d(min_deg, acos(c) * (45.0 / atan(1.0)));
        }
    *min_dihedral_deg = min_deg;
}

// ---------------------------------------------------------------------------------------------
// Finalize: repair, then derive.

// Node -> tet CSR (tets ascending within each node) and the used nodes. marker: [nn] scratch.
static void derive_node_tets(hs_mesh* m, int* marker) {
    const int nn = m->n_nodes, nt = m->n_tets;
    for (int t = 0; t < nt; ++t)
        for (int i = 0; i < 4; ++i) m->node_tet_start[m->tets[4 * t + i] + 1]++;
    for (int i = 0; i < nn; ++i) m->node_tet_start[i + 1] += m->node_tet_start[i];
    for (int i = 0; i < nn; ++i) marker[i] = m->node_tet_start[i];
    for (int t = 0; t < nt; ++t)
        for (int i = 0; i < 4; ++i) m->node_tet[marker[m->tets[4 * t + i]]++] = t;
    m->report.unreferenced_nodes = 0;
    for (int i = 0; i < nn; ++i) {
        m->node_used[i] = m->node_tet_start[i + 1] > m->node_tet_start[i];
        if (!m->node_used[i]) m->report.unreferenced_nodes++;
    }
}

// Node i's neighbours (each once, through marker) into out when not NULL; their count.
static int node_neighbours(const hs_mesh* m, int i, int* marker, int* out) {
    int cnt = 0;
    for (int k = m->node_tet_start[i]; k < m->node_tet_start[i + 1]; ++k) {
        const int* tet = m->tets + 4 * m->node_tet[k];
        for (int j = 0; j < 4; ++j)
            if (tet[j] != i && marker[tet[j]] != i) {
                marker[tet[j]] = i;
                if (out) out[cnt] = tet[j];
                ++cnt;
            }
    }
    return cnt;
}

// Node -> node CSR: count, then fill, neighbours ascending. 0, or -1 out of memory.
static int derive_node_nbrs(hs_mesh* m, int* marker) {
    const int nn = m->n_nodes;
    for (int i = 0; i < nn; ++i) marker[i] = -1;
    for (int i = 0; i < nn; ++i)
        m->node_nbr_start[i + 1] = m->node_nbr_start[i] + node_neighbours(m, i, marker, NULL);
    m->node_nbr = hs_alloc(((size_t)m->node_nbr_start[nn] + 1) * sizeof(int));
    if (!m->node_nbr) return -1;
    for (int i = 0; i < nn; ++i) marker[i] = -1;
    for (int i = 0; i < nn; ++i) {
        int* out = m->node_nbr + m->node_nbr_start[i];
        qsort(out, (size_t)node_neighbours(m, i, marker, out), sizeof(int), cmp_int);
    }
    return 0;
}

// The faces whose smallest node is v, from v's tets, sorted; their count.
static int faces_at(const hs_mesh* m, int v, face_key* faces) {
    int n = 0;
    for (int q = m->node_tet_start[v]; q < m->node_tet_start[v + 1]; ++q) {
        const int t = m->node_tet[q];
        for (int f = 0; f < 4; ++f) {
            if (m->tets[4 * t + f] == v) continue; // the face opposite v lacks v
            face_key* fk = faces + n;
            for (int i = 0; i < 3; ++i) fk->k[i] = m->tets[4 * t + k_face[f][i]];
            fk->parity = sort3(fk->k);
            fk->slot = 4 * t + f;
            n += fk->k[0] == v;
        }
    }
    if (n <= 64) { // insertion sort: lists are short and often nearly sorted
        for (int i = 1; i < n; ++i)
            for (int j = i; j > 0 && cmp_face_key(faces + j - 1, faces + j) > 0; --j) {
                face_key tmp = faces[j];
                faces[j] = faces[j - 1];
                faces[j - 1] = tmp;
            }
    } else {
        qsort(faces, (size_t)n, sizeof(face_key), cmp_face_key);
    }
    return n;
}

// Faces: each face is collected at its smallest node, from that node's tets, and matched there
// by sorting that short list (O(sum deg log deg), no global sort). A face seen once is boundary
// (bnd[4 t + f] = 1), twice must be seen from opposite sides (else the tets overlap), more than
// twice is not a volume mesh. *n_tris: the boundary faces.
static hs_status match_faces(const hs_mesh* m, unsigned char* bnd, int* n_tris,
                             hs_mesh_fault* fault, hs_err* err) {
    const int nn = m->n_nodes;
    int max_deg = 0;
    for (int i = 0; i < nn; ++i)
        if (m->node_tet_start[i + 1] - m->node_tet_start[i] > max_deg)
            max_deg = m->node_tet_start[i + 1] - m->node_tet_start[i];
    face_key* faces = hs_alloc(((size_t)3 * max_deg + 1) * sizeof(face_key));
    if (!faces) return HS_ERR_NOMEM;
    hs_status st = HS_OK;
    *n_tris = 0;
    for (int v = 0; v < nn && st == HS_OK; ++v) {
        const int n = faces_at(m, v, faces);
        for (int a = 0; a < n;) {
            int b = a + 1;
            while (b < n && memcmp(faces[a].k, faces[b].k, sizeof faces[a].k) == 0) ++b;
            if (b - a == 1) {
                bnd[faces[a].slot] = 1;
                ++*n_tris;
            } else if (b - a > 2 || faces[a].parity == faces[a + 1].parity) {
                if (fault)
                    *fault = (hs_mesh_fault){{faces[a].slot / 4, faces[a + 1].slot / 4},
                                             {faces[a].k[0], faces[a].k[1], faces[a].k[2]},
                                             b - a};
                if (b - a > 2)
                    st = hs_err_set(err, HS_ERR_INVALID, "face (%d,%d,%d) is shared by %d tets",
                                    faces[a].k[0], faces[a].k[1], faces[a].k[2], b - a);
                else
                    st = hs_err_set(
                        err, HS_ERR_INVALID,
                        "tets %d and %d lie on the same side of face (%d,%d,%d) (overlap)",
                        faces[a].slot / 4, faces[a + 1].slot / 4, faces[a].k[0], faces[a].k[1],
                        faces[a].k[2]);
                break;
            }
            a = b;
        }
    }
    hs_free(faces);
    return st;
}

// Boundary triangles from bnd, and the surface nodes, ascending. 0, or -1 out of memory.
static int derive_surface(hs_mesh* m, const unsigned char* bnd, int n_tris) {
    const int nn = m->n_nodes, nt = m->n_tets;
    m->tris = hs_alloc(((size_t)3 * n_tris + 1) * sizeof(int));
    m->tri_tet = hs_alloc(((size_t)n_tris + 1) * sizeof(int));
    if (!m->tris || !m->tri_tet) return -1;
    m->n_tris = 0;
    for (int s = 0; s < 4 * nt; ++s) {
        if (!bnd[s]) continue;
        const int t = s / 4, f = s % 4;
        for (int i = 0; i < 3; ++i) m->tris[3 * m->n_tris + i] = m->tets[4 * t + k_face[f][i]];
        m->tri_tet[m->n_tris++] = t;
    }
    for (int i = 0; i < nn; ++i) m->node_surf[i] = -1;
    for (int k = 0; k < 3 * m->n_tris; ++k) m->node_surf[m->tris[k]] = 0;
    int ns = 0;
    for (int i = 0; i < nn; ++i) ns += m->node_surf[i] == 0;
    m->surf_nodes = hs_alloc(((size_t)ns + 1) * sizeof(int));
    if (!m->surf_nodes) return -1;
    m->n_surf_nodes = 0;
    for (int i = 0; i < nn; ++i)
        if (m->node_surf[i] == 0) {
            m->node_surf[i] = m->n_surf_nodes;
            m->surf_nodes[m->n_surf_nodes++] = i;
        }
    return 0;
}

// Components (union-find over the nodes of each tet: tets sharing a node are connected),
// volume and quality. marker: [nn] scratch.
static void derive_report(hs_mesh* m, int* marker) {
    const int nn = m->n_nodes, nt = m->n_tets;
    for (int i = 0; i < nn; ++i) marker[i] = i;
    for (int t = 0; t < nt; ++t) {
        int r0 = find_root(marker, m->tets[4 * t]);
        for (int j = 1; j < 4; ++j) {
            int r = find_root(marker, m->tets[4 * t + j]);
            if (r != r0) marker[r] = r0;
        }
    }
    m->report.components = 0;
    for (int i = 0; i < nn; ++i) m->report.components += m->node_used[i] && marker[i] == i;
    m->volume = 0.0;
    m->report.min_dihedral_deg = nt ? 180.0 : 0.0;
    m->report.max_aspect = 0.0;
    double aspect_sum = 0.0;
    for (int t = 0; t < nt; ++t) {
        double dih, asp;
        m->volume += hs_tet_volume(m->x0, m->tets + 4 * t);
        tet_quality(m->x0, m->tets + 4 * t, &dih, &asp);
        m->report.min_dihedral_deg = min_d(m->report.min_dihedral_deg, dih);
        m->report.max_aspect = max_d(m->report.max_aspect, asp);
        aspect_sum += asp;
    }
    m->report.mean_aspect = nt ? aspect_sum / nt : 0.0;
}

// Builds every derived array from valid, positively oriented, distinct tets.
// fault (may be NULL) gets a face error's tets and nodes, tets numbered as in m.
static hs_status build_derived(hs_mesh* m, hs_mesh_fault* fault, hs_err* err) {
    const int nn = m->n_nodes, nt = m->n_tets;
    hs_status st = HS_ERR_NOMEM;
    m->node_used = hs_calloc((size_t)nn + 1, 1);
    m->node_tet_start = hs_calloc((size_t)nn + 1, sizeof(int));
    m->node_tet = hs_alloc(((size_t)4 * nt + 1) * sizeof(int));
    m->node_nbr_start = hs_calloc((size_t)nn + 1, sizeof(int));
    m->node_surf = hs_alloc(((size_t)nn + 1) * sizeof(int));
    int* marker = hs_alloc(((size_t)nn + 1) * sizeof(int));
    unsigned char* bnd = hs_calloc((size_t)4 * nt + 1, 1);
    int n_tris = 0;
    if (!m->node_used || !m->node_tet_start || !m->node_tet || !m->node_nbr_start ||
        !m->node_surf || !marker || !bnd)
        goto fail;
    derive_node_tets(m, marker);
    if (derive_node_nbrs(m, marker) != 0) goto fail;
    st = match_faces(m, bnd, &n_tris, fault, err);
    if (st != HS_OK) goto fail;
    st = HS_ERR_NOMEM;
    if (derive_surface(m, bnd, n_tris) != 0) goto fail;
    derive_report(m, marker);
    hs_free(marker);
    hs_free(bnd);
    return HS_OK;

fail:
    if (st == HS_ERR_NOMEM) hs_err_set(err, HS_ERR_NOMEM, "mesh: out of memory");
    hs_free(marker);
    hs_free(bnd);
    free_derived(m);
    return st;
}

// hs_mesh_finalize; fault (may be NULL) gets a face error in input tet numbers.
static hs_status finalize(hs_mesh* m, hs_mesh_fault* fault, hs_err* err) {
    if (fault) *fault = (hs_mesh_fault){{-1, -1}, {-1, -1, -1}, 0};
    if (!m) return hs_err_set(err, HS_ERR_INVALID, "mesh is NULL");
    free_derived(m); // first: every error below leaves the mesh reading as not finalized
    const int nn = m->n_nodes;
    if (nn < 0 || m->n_tets < 0 || nn > HS_MESH_MAX_COUNT || m->n_tets > HS_MESH_MAX_COUNT)
        return hs_err_set(err, HS_ERR_INVALID, "bad counts: %d nodes, %d tets", nn, m->n_tets);
    if ((nn > 0 && !m->x0) || (m->n_tets > 0 && !m->tets))
        return hs_err_set(err, HS_ERR_INVALID, "mesh arrays are NULL");
    for (int i = 0; i < 3 * nn; ++i)
        if (!(fabs(m->x0[i]) <= HS_MESH_MAX_COORD))
            return hs_err_set(err, HS_ERR_INVALID,
                              "node %d: coordinate %g is not finite or beyond %g m", i / 3,
                              m->x0[i], HS_MESH_MAX_COORD);
    for (int k = 0; k < 4 * m->n_tets; ++k)
        if (m->tets[k] < 0 || m->tets[k] >= nn)
            return hs_err_set(err, HS_ERR_INVALID, "tet %d: node index %d out of range [0, %d)",
                              k / 4, m->tets[k], nn);

    unsigned char* keep = hs_alloc((size_t)m->n_tets + 1);
    tet_key* keys = hs_alloc(((size_t)m->n_tets + 1) * sizeof(tet_key));
    tet_key* sorted = hs_alloc(((size_t)m->n_tets + 1) * sizeof(tet_key));
    int* bucket = hs_calloc((size_t)nn + 2, sizeof(int));
    // The tets are repaired in place: a failure below puts them back (the arrays stay where
    // they are; derived data is then cleared: the mesh reads as not finalized).
    int* backup = hs_alloc(4 * (size_t)m->n_tets * sizeof(int) + sizeof(int));
    int* orig = hs_alloc(((size_t)m->n_tets + 1) * sizeof(int)); // kept tet -> input tet
    if (!keep || !keys || !sorted || !bucket || !backup || !orig) {
        hs_free(keep);
        hs_free(keys);
        hs_free(sorted);
        hs_free(bucket);
        hs_free(backup);
        hs_free(orig);
        return hs_err_set(err, HS_ERR_NOMEM, "mesh: out of memory");
    }
    const int n_tets0 = m->n_tets;
    const hs_mesh_report report0 = m->report;
    memcpy(backup, m->tets, 4 * (size_t)n_tets0 * sizeof(int));

    for (int d = 0; d < 3; ++d) {
        m->bbox_min[d] = nn ? INFINITY : 0.0;
        m->bbox_max[d] = nn ? -INFINITY : 0.0;
    }
    for (int i = 0; i < nn; ++i)
        for (int d = 0; d < 3; ++d) {
            m->bbox_min[d] = min_d(m->bbox_min[d], m->x0[3 * i + d]);
            m->bbox_max[d] = max_d(m->bbox_max[d], m->x0[3 * i + d]);
        }
    // The degeneracy scale comes from the box of the nodes tets use, so a stray unused node
    // far away cannot turn every tet degenerate.
    double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    for (int k = 0; k < 4 * m->n_tets; ++k)
        for (int d = 0; d < 3; ++d) {
            lo[d] = min_d(lo[d], m->x0[3 * m->tets[k] + d]);
            hi[d] = max_d(hi[d], m->x0[3 * m->tets[k] + d]);
        }
    const double used_vol = m->n_tets ? (hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2]) : 0.0;
    const double tiny = max_d(1e-12 * used_vol, HS_MESH_MIN_VOLUME);

    hs_mesh_report* r = &m->report;
    r->reoriented_tets = r->degenerate_tets = r->duplicate_tets = 0;
    for (int k = 0; k < HS_MESH_REPORT_FIRST; ++k)
        r->first_reoriented[k] = r->first_degenerate[k] = r->first_duplicate[k] = -1;
    for (int t = 0; t < m->n_tets; ++t) {
        int* tet = m->tets + 4 * t;
        double v = hs_tet_volume(m->x0, tet);
        keep[t] = fabs(v) > tiny;
        if (!keep[t]) {
            if (r->degenerate_tets < HS_MESH_REPORT_FIRST)
                r->first_degenerate[r->degenerate_tets] = t;
            r->degenerate_tets++;
            continue;
        }
        if (v < 0.0) {
            int s = tet[1];
            tet[1] = tet[2];
            tet[2] = s;
            if (r->reoriented_tets < HS_MESH_REPORT_FIRST)
                r->first_reoriented[r->reoriented_tets] = t;
            r->reoriented_tets++;
        }
    }
    int nk = 0;
    for (int t = 0; t < m->n_tets; ++t) {
        if (!keep[t]) continue;
        memcpy(keys[nk].k, m->tets + 4 * t, sizeof keys[nk].k);
        sort4(keys[nk].k);
        keys[nk++].t = t;
    }
    // Duplicates: counting sort by smallest node, then sort each (short) bucket.
    for (int i = 0; i < nk; ++i) bucket[keys[i].k[0] + 2]++;
    for (int v = 0; v < nn; ++v) bucket[v + 2] += bucket[v + 1];
    for (int i = 0; i < nk; ++i) sorted[bucket[keys[i].k[0] + 1]++] = keys[i];
    for (int v = 0; v < nn; ++v) {
        tet_key* b = sorted + bucket[v];
        int n_b = bucket[v + 1] - bucket[v];
        qsort(b, (size_t)n_b, sizeof(tet_key), cmp_tet_key);
        for (int i = 1; i < n_b; ++i)
            if (memcmp(b[i].k, b[i - 1].k, sizeof b[i].k) == 0) {
                keep[b[i].t] = 0; // the later tet of a duplicate run goes
                if (r->duplicate_tets < HS_MESH_REPORT_FIRST)
                    r->first_duplicate[r->duplicate_tets] = b[i].t;
                r->duplicate_tets++;
            }
    }
    int n = 0;
    for (int t = 0; t < m->n_tets; ++t)
        if (keep[t]) {
            if (n != t) memcpy(m->tets + 4 * n, m->tets + 4 * t, 4 * sizeof(int));
            orig[n++] = t;
        }
    m->n_tets = n;
    hs_free(keep);
    hs_free(keys);
    hs_free(sorted);
    hs_free(bucket);

    hs_status st =
        n > 0 || n_tets0 == 0
            ? build_derived(m, fault, err)
            : hs_err_set(err, HS_ERR_INVALID,
                         "no valid tetrahedra: %d degenerate (volume <= %g m^3), %d duplicate",
                         r->degenerate_tets, tiny, r->duplicate_tets);
    if (fault && fault->n_sharing)
        for (int k = 0; k < 2; ++k) fault->tet[k] = orig[fault->tet[k]];
    hs_free(orig);
    if (st != HS_OK) {
        free_derived(m);
        memcpy(m->tets, backup, 4 * (size_t)n_tets0 * sizeof(int));
        m->n_tets = n_tets0;
        m->report = report0;
        hs_free(backup);
        return st;
    }
    hs_free(backup);
    return r->reoriented_tets || r->degenerate_tets || r->duplicate_tets ? HS_WARN_MESH_REPAIRED
                                                                         : HS_OK;
}

hs_status hs_mesh_finalize(hs_mesh* m, hs_err* err) {
    return finalize(m, NULL, err);
}

hs_status hs_mesh_adopt(int n_nodes, double* x0, int n_tets, int* tets, int skipped, hs_mesh** out,
                        hs_mesh_fault* fault, hs_err* err) {
    if (fault) *fault = (hs_mesh_fault){{-1, -1}, {-1, -1, -1}, 0};
    *out = NULL;
    hs_mesh* m = hs_calloc(1, sizeof(hs_mesh));
    if (!m) {
        hs_free(x0);
        hs_free(tets);
        return hs_err_set(err, HS_ERR_NOMEM, "mesh: out of memory");
    }
    m->n_nodes = n_nodes;
    m->n_tets = n_tets;
    m->x0 = x0;
    m->tets = tets;
    m->report.skipped_elements = skipped;
    hs_status st = finalize(m, fault, err);
    if (st >= 0 && m->n_tets == 0)
        st = hs_err_set(err, HS_ERR_INVALID, "no valid tetrahedra (%d degenerate, %d duplicate)",
                        m->report.degenerate_tets, m->report.duplicate_tets);
    if (st < 0) {
        hs_mesh_destroy(&m);
        return st;
    }
    *out = m;
    return st;
}

hs_status hs_mesh_create(int n_nodes, const double* x0, int n_tets, const int* tets, hs_mesh** out,
                         hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "out is NULL");
    *out = NULL;
    if (n_nodes < 0 || n_tets < 0 || n_nodes > HS_MESH_MAX_COUNT || n_tets > HS_MESH_MAX_COUNT)
        return hs_err_set(err, HS_ERR_INVALID, "bad counts: %d nodes, %d tets", n_nodes, n_tets);
    if ((n_nodes > 0 && !x0) || (n_tets > 0 && !tets))
        return hs_err_set(err, HS_ERR_INVALID, "input arrays are NULL");
    double* x = hs_alloc(((size_t)3 * n_nodes + 1) * sizeof(double));
    int* t = hs_alloc(((size_t)4 * n_tets + 1) * sizeof(int));
    if (!x || !t) {
        hs_free(x);
        hs_free(t);
        return hs_err_set(err, HS_ERR_NOMEM, "mesh: out of memory");
    }
    if (n_nodes) memcpy(x, x0, (size_t)3 * n_nodes * sizeof(double));
    if (n_tets) memcpy(t, tets, (size_t)4 * n_tets * sizeof(int));
    return hs_mesh_adopt(n_nodes, x, n_tets, t, 0, out, NULL, err);
}

hs_status hs_mesh_create_box(double lx, double ly, double lz, int nx, int ny, int nz, hs_mesh** out,
                             hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "out is NULL");
    *out = NULL;
    if (!(lx > 0 && ly > 0 && lz > 0 && lx <= HS_MESH_MAX_COORD && ly <= HS_MESH_MAX_COORD &&
          lz <= HS_MESH_MAX_COORD))
        return hs_err_set(err, HS_ERR_INVALID, "box sides must be positive and finite");
    if (nx < 1 || ny < 1 || nz < 1 || (double)nx * ny * nz * 6.0 > (double)HS_MESH_MAX_COUNT ||
        (double)(nx + 1) * (ny + 1) * (nz + 1) > (double)HS_MESH_MAX_COUNT)
        return hs_err_set(err, HS_ERR_INVALID, "box divisions %d x %d x %d out of range", nx, ny,
                          nz);
    const int n_nodes = (nx + 1) * (ny + 1) * (nz + 1);
    const int n_tets = 6 * nx * ny * nz;
    double* x = hs_alloc((size_t)3 * n_nodes * sizeof(double));
    int* tets = hs_alloc((size_t)4 * n_tets * sizeof(int));
    if (!x || !tets) {
        hs_free(x);
        hs_free(tets);
        return hs_err_set(err, HS_ERR_NOMEM, "mesh: out of memory");
    }
    // x fastest, then y, then z.
    for (int k = 0; k <= nz; ++k)
        for (int j = 0; j <= ny; ++j)
            for (int i = 0; i <= nx; ++i) {
                double* p = x + 3 * (i + (nx + 1) * (j + (ny + 1) * k));
                p[0] = lx * i / nx;
                p[1] = ly * j / ny;
                p[2] = lz * k / nz;
            }
    // Kuhn split: one tet per axis order along the path from corner (0,0,0) to (1,1,1). All
    // hexes use the same main diagonal, so face diagonals match and the mesh is conforming.
    static const int perm[6][3] = {{0, 1, 2}, {1, 2, 0}, {2, 0, 1},
                                   {0, 2, 1}, {1, 0, 2}, {2, 1, 0}};
    const int stride[3] = {1, nx + 1, (nx + 1) * (ny + 1)};
    int* tp = tets;
    for (int k = 0; k < nz; ++k)
        for (int j = 0; j < ny; ++j)
            for (int i = 0; i < nx; ++i) {
                const int base = i + stride[1] * j + stride[2] * k;
                for (int p = 0; p < 6; ++p) {
                    int v1 = base + stride[perm[p][0]];
                    int v2 = v1 + stride[perm[p][1]];
                    int v3 = base + stride[0] + stride[1] + stride[2];
                    // Odd permutations (the last three) have negative orientation: swap.
                    tp[0] = base;
                    tp[1] = p < 3 ? v1 : v2;
                    tp[2] = p < 3 ? v2 : v1;
                    tp[3] = v3;
                    tp += 4;
                }
            }
    return hs_mesh_adopt(n_nodes, x, n_tets, tets, 0, out, NULL, err);
}

// ---------------------------------------------------------------------------------------------
// Invariant checker: recomputes what it checks from tets and the CSR lists, independently of
// build_derived's face sort.

typedef struct edge_key {
    int a, b;
} edge_key;

static int cmp_edge(const void* pa, const void* pb) {
    const edge_key* x = pa;
    const edge_key* y = pb;
    if (x->a != y->a) return x->a < y->a ? -1 : 1;
    return (x->b > y->b) - (x->b < y->b);
}

static int count_edge(const edge_key* e, int n, int a, int b) {
    int lo = 0, hi = n; // first index with e >= (a,b)
    edge_key key = {a, b};
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (cmp_edge(e + mid, &key) < 0)
            lo = mid + 1;
        else
            hi = mid;
    }
    int c = 0;
    while (lo + c < n && e[lo + c].a == a && e[lo + c].b == b) ++c;
    return c;
}

static int cmp_int3(const void* pa, const void* pb) {
    const int* a = pa;
    const int* b = pb;
    for (int i = 0; i < 3; ++i)
        if (a[i] != b[i]) return a[i] < b[i] ? -1 : 1;
    return 0;
}

static int tet_has(const int* tet, int v) {
    return tet[0] == v || tet[1] == v || tet[2] == v || tet[3] == v;
}

// Tets that contain nodes a, b and c (searched through a's incident tets).
static int tets_with_face(const hs_mesh* m, int a, int b, int c) {
    int n = 0;
    for (int k = m->node_tet_start[a]; k < m->node_tet_start[a + 1]; ++k) {
        const int* tet = m->tets + 4 * m->node_tet[k];
        n += tet_has(tet, b) && tet_has(tet, c);
    }
    return n;
}

static int has_nbr(const hs_mesh* m, int i, int j) {
    const int* lo = m->node_nbr + m->node_nbr_start[i];
    size_t n = (size_t)(m->node_nbr_start[i + 1] - m->node_nbr_start[i]);
    return bsearch(&j, lo, n, sizeof(int), cmp_int) != NULL;
}

static hs_status check_csr(const int* start, const int* idx, int n, int total, int hi,
                           const char* what, hs_err* err) {
    if (!start || !idx) return hs_err_set(err, HS_ERR_INVALID, "%s arrays are NULL", what);
    if (start[0] != 0 || start[n] != total)
        return hs_err_set(err, HS_ERR_INVALID, "%s: offsets span [%d, %d], expected [0, %d]", what,
                          start[0], start[n], total);
    for (int i = 0; i < n; ++i) {
        if (start[i + 1] < start[i])
            return hs_err_set(err, HS_ERR_INVALID, "%s: offsets decrease at node %d", what, i);
        for (int k = start[i]; k < start[i + 1]; ++k) {
            if (idx[k] < 0 || idx[k] >= hi)
                return hs_err_set(err, HS_ERR_INVALID, "%s: entry %d of node %d out of range", what,
                                  idx[k], i);
            if (k > start[i] && idx[k] <= idx[k - 1])
                return hs_err_set(err, HS_ERR_INVALID, "%s: list of node %d not ascending", what,
                                  i);
        }
    }
    return HS_OK;
}

// Regions: names, node indices in range, ascending.
static hs_status check_regions(const hs_mesh* m, hs_err* err) {
    const int nn = m->n_nodes;
    if (m->n_regions < 0 || (m->n_regions && !m->regions))
        return hs_err_set(err, HS_ERR_INVALID, "bad region list");
    for (int r = 0; r < m->n_regions; ++r) {
        const hs_mesh_region* g = &m->regions[r];
        if (!memchr(g->name, 0, sizeof g->name) || !g->name[0] || g->n_nodes < 0 ||
            g->n_nodes > nn || (g->n_nodes && !g->nodes))
            return hs_err_set(err, HS_ERR_INVALID, "region %d: bad name or node list", r);
        for (int i = 0; i < g->n_nodes; ++i)
            if (g->nodes[i] < 0 || g->nodes[i] >= nn || (i && g->nodes[i] <= g->nodes[i - 1]))
                return hs_err_set(err, HS_ERR_INVALID,
                                  "region '%s': node %d out of range or out of order", g->name,
                                  g->nodes[i]);
    }
    return HS_OK;
}

// Tets: ranges, distinct nodes, positive volume; node_used and the volume sum.
static hs_status check_tets(const hs_mesh* m, hs_err* err) {
    const int nn = m->n_nodes, nt = m->n_tets;
    double vol = 0.0;
    for (int t = 0; t < nt; ++t) {
        const int* tet = m->tets + 4 * t;
        for (int i = 0; i < 4; ++i) {
            if (tet[i] < 0 || tet[i] >= nn)
                return hs_err_set(err, HS_ERR_INVALID, "tet %d: node %d out of range", t, tet[i]);
            for (int j = 0; j < i; ++j)
                if (tet[i] == tet[j])
                    return hs_err_set(err, HS_ERR_INVALID, "tet %d repeats node %d", t, tet[i]);
        }
        double v = hs_tet_volume(m->x0, tet);
        if (!(v > 0.0))
            return hs_err_set(err, HS_ERR_INVALID, "tet %d has volume %g (not positive)", t, v);
        vol += v;
    }
    if (!(fabs(vol - m->volume) <= 1e-9 * fabs(vol)))
        return hs_err_set(err, HS_ERR_INVALID, "volume %g differs from the tet sum %g", m->volume,
                          vol);
    for (int i = 0; i < nn; ++i)
        for (int d = 0; d < 3; ++d)
            if (!(m->x0[3 * i + d] >= m->bbox_min[d] && m->x0[3 * i + d] <= m->bbox_max[d]))
                return hs_err_set(err, HS_ERR_INVALID, "node %d outside the bbox", i);
    return HS_OK;
}

// Node -> tet: every incidence exactly once (entries distinct and contain the node, and
// their number is 4 per tet).
static hs_status check_node_tets(const hs_mesh* m, hs_err* err) {
    const int nn = m->n_nodes, nt = m->n_tets;
    hs_status st = check_csr(m->node_tet_start, m->node_tet, nn, 4 * nt, nt, "node_tet", err);
    if (st != HS_OK) return st;
    int unused = 0;
    for (int i = 0; i < nn; ++i) {
        for (int k = m->node_tet_start[i]; k < m->node_tet_start[i + 1]; ++k)
            if (!tet_has(m->tets + 4 * m->node_tet[k], i))
                return hs_err_set(err, HS_ERR_INVALID, "node_tet: tet %d listed at node %d",
                                  m->node_tet[k], i);
        int used = m->node_tet_start[i + 1] > m->node_tet_start[i];
        if (m->node_used[i] != used)
            return hs_err_set(err, HS_ERR_INVALID, "node_used[%d] is %d", i, m->node_used[i]);
        unused += !used;
    }
    if (unused != m->report.unreferenced_nodes)
        return hs_err_set(err, HS_ERR_INVALID, "%d unreferenced nodes, report says %d", unused,
                          m->report.unreferenced_nodes);
    return HS_OK;
}

// Node -> node: sorted, no self, symmetric, and exactly the tet edges.
static hs_status check_node_nbrs(const hs_mesh* m, hs_err* err) {
    const int nn = m->n_nodes, nt = m->n_tets;
    if (!m->node_nbr_start)
        return hs_err_set(err, HS_ERR_INVALID, "node_nbr arrays are NULL (not finalized?)");
    hs_status st =
        check_csr(m->node_nbr_start, m->node_nbr, nn, m->node_nbr_start[nn], nn, "node_nbr", err);
    if (st != HS_OK) return st;
    for (int i = 0; i < nn; ++i)
        for (int k = m->node_nbr_start[i]; k < m->node_nbr_start[i + 1]; ++k) {
            int j = m->node_nbr[k], shared = 0;
            if (j == i) return hs_err_set(err, HS_ERR_INVALID, "node %d is its own neighbour", i);
            if (!has_nbr(m, j, i))
                return hs_err_set(err, HS_ERR_INVALID, "adjacency not symmetric: %d-%d", i, j);
            for (int q = m->node_tet_start[i]; q < m->node_tet_start[i + 1] && !shared; ++q)
                shared = tet_has(m->tets + 4 * m->node_tet[q], j);
            if (!shared)
                return hs_err_set(err, HS_ERR_INVALID, "neighbours %d-%d share no tet", i, j);
        }
    for (int t = 0; t < nt; ++t)
        for (int a = 0; a < 4; ++a)
            for (int b = 0; b < 4; ++b)
                if (a != b && !has_nbr(m, m->tets[4 * t + a], m->tets[4 * t + b]))
                    return hs_err_set(err, HS_ERR_INVALID, "edge %d-%d of tet %d not adjacent",
                                      m->tets[4 * t + a], m->tets[4 * t + b], t);
    return HS_OK;
}

// Boundary: each triangle is an outward face of its tet that no other tet has, and the
// number of such faces over all tets equals n_tris.
static hs_status check_boundary(const hs_mesh* m, hs_err* err) {
    const int nt = m->n_tets;
    int n_bnd = 0;
    for (int t = 0; t < nt; ++t)
        for (int f = 0; f < 4; ++f) {
            const int* tet = m->tets + 4 * t;
            n_bnd +=
                tets_with_face(m, tet[k_face[f][0]], tet[k_face[f][1]], tet[k_face[f][2]]) == 1;
        }
    if (n_bnd != m->n_tris)
        return hs_err_set(err, HS_ERR_INVALID, "%d boundary faces but %d triangles", n_bnd,
                          m->n_tris);
    edge_key* e = hs_alloc(((size_t)3 * m->n_tris + 1) * sizeof(edge_key));
    int* tri_sorted = hs_alloc(((size_t)3 * m->n_tris + 1) * sizeof(int));
    if (!e || !tri_sorted) {
        hs_free(e);
        hs_free(tri_sorted);
        return hs_err_set(err, HS_ERR_NOMEM, "mesh check: out of memory");
    }
    hs_status st = HS_OK;
    for (int s = 0; s < m->n_tris && st == HS_OK; ++s) {
        const int* tri = m->tris + 3 * s;
        int t = m->tri_tet[s];
        if (t < 0 || t >= nt) {
            st = hs_err_set(err, HS_ERR_INVALID, "triangle %d: owner tet %d out of range", s, t);
            break;
        }
        const int* tet = m->tets + 4 * t;
        int opp = -1, in = 0;
        for (int i = 0; i < 4; ++i) {
            int hit = tri[0] == tet[i] || tri[1] == tet[i] || tri[2] == tet[i];
            in += hit;
            if (!hit) opp = tet[i];
        }
        if (in != 3 || tri[0] == tri[1] || tri[1] == tri[2] || tri[0] == tri[2]) {
            st = hs_err_set(err, HS_ERR_INVALID, "triangle %d is not a face of tet %d", s, t);
            break;
        }
        const int probe[4] = {tri[0], tri[1], tri[2], opp};
        if (!(hs_tet_volume(m->x0, probe) < 0.0))
            st = hs_err_set(err, HS_ERR_INVALID, "triangle %d faces into its tet", s);
        else if (tets_with_face(m, tri[0], tri[1], tri[2]) != 1)
            st = hs_err_set(err, HS_ERR_INVALID, "triangle %d is an interior face", s);
        for (int i = 0; i < 3; ++i) {
            e[3 * s + i].a = tri[i];
            e[3 * s + i].b = tri[(i + 1) % 3];
            tri_sorted[3 * s + i] = tri[i];
        }
        sort3(tri_sorted + 3 * s);
    }
    // Closed and consistently oriented: every directed boundary edge a->b is matched by as
    // many b->a (exactly one each on a manifold surface).
    if (st == HS_OK) {
        const int ne = 3 * m->n_tris;
        qsort(e, (size_t)ne, sizeof(edge_key), cmp_edge);
        for (int k = 0; k < ne && st == HS_OK; ++k) {
            if (k > 0 && cmp_edge(e + k, e + k - 1) == 0) continue;
            int fwd = count_edge(e, ne, e[k].a, e[k].b);
            int back = count_edge(e, ne, e[k].b, e[k].a);
            if (fwd != back)
                st = hs_err_set(err, HS_ERR_INVALID,
                                "boundary edge %d-%d used %d times one way, %d the other "
                                "(surface open or misoriented)",
                                e[k].a, e[k].b, fwd, back);
        }
    }
    // Distinct triangles: with the count above, the triangles are exactly the boundary faces.
    if (st == HS_OK) {
        qsort(tri_sorted, (size_t)m->n_tris, 3 * sizeof(int), cmp_int3);
        for (int s = 1; s < m->n_tris && st == HS_OK; ++s)
            if (cmp_int3(tri_sorted + 3 * s, tri_sorted + 3 * (s - 1)) == 0)
                st = hs_err_set(err, HS_ERR_INVALID, "triangle (%d,%d,%d) appears twice",
                                tri_sorted[3 * s], tri_sorted[3 * s + 1], tri_sorted[3 * s + 2]);
    }
    hs_free(e);
    hs_free(tri_sorted);
    if (st != HS_OK) return st;
    return HS_OK;
}

// Surface nodes: exactly the triangle nodes, ascending, and node_surf their inverse.
static hs_status check_surface_nodes(const hs_mesh* m, hs_err* err) {
    const int nn = m->n_nodes;
    int ns = 0;
    for (int i = 0; i < nn; ++i) {
        int s = m->node_surf[i];
        if (s < -1 || s >= m->n_surf_nodes || (s >= 0 && m->surf_nodes[s] != i))
            return hs_err_set(err, HS_ERR_INVALID, "node_surf[%d] = %d is inconsistent", i, s);
        ns += s >= 0;
    }
    if (ns != m->n_surf_nodes)
        return hs_err_set(err, HS_ERR_INVALID, "%d nodes map to the surface, n_surf_nodes %d", ns,
                          m->n_surf_nodes);
    for (int k = 1; k < m->n_surf_nodes; ++k)
        if (m->surf_nodes[k] <= m->surf_nodes[k - 1])
            return hs_err_set(err, HS_ERR_INVALID, "surf_nodes not ascending at %d", k);
    for (int k = 0; k < 3 * m->n_tris; ++k)
        if (m->node_surf[m->tris[k]] < 0)
            return hs_err_set(err, HS_ERR_INVALID, "triangle node %d not a surface node",
                              m->tris[k]);
    // Each surface node lies on some triangle: count distinct triangle nodes.
    int on_tri = 0;
    for (int k = 0; k < m->n_surf_nodes; ++k) {
        int i = m->surf_nodes[k], found = 0;
        for (int q = m->node_tet_start[i]; q < m->node_tet_start[i + 1] && !found; ++q) {
            const int* tet = m->tets + 4 * m->node_tet[q];
            for (int f = 0; f < 4 && !found; ++f) {
                const int a = tet[k_face[f][0]], b = tet[k_face[f][1]], c = tet[k_face[f][2]];
                found = (a == i || b == i || c == i) && tets_with_face(m, a, b, c) == 1;
            }
        }
        on_tri += found;
    }
    if (on_tri != m->n_surf_nodes)
        return hs_err_set(err, HS_ERR_INVALID, "%d surface nodes lie on no boundary face",
                          m->n_surf_nodes - on_tri);
    return HS_OK;
}

hs_status hs_mesh_check(const hs_mesh* m, hs_err* err) {
    if (!m) return hs_err_set(err, HS_ERR_INVALID, "mesh is NULL");
    const int nn = m->n_nodes, nt = m->n_tets;
    if (nn < 0 || nt < 0 || nn > HS_MESH_MAX_COUNT || nt > HS_MESH_MAX_COUNT || m->n_tris < 0 ||
        m->n_tris > 4 * nt || m->n_surf_nodes < 0 || m->n_surf_nodes > nn)
        return hs_err_set(err, HS_ERR_INVALID, "bad counts: %d nodes, %d tets, %d tris", nn, nt,
                          m->n_tris);
    if ((nn && !m->x0) || (nt && !m->tets) || !m->node_used || !m->node_surf ||
        (m->n_tris && (!m->tris || !m->tri_tet)) || (m->n_surf_nodes && !m->surf_nodes))
        return hs_err_set(err, HS_ERR_INVALID, "mesh arrays are NULL (not finalized?)");

    hs_status (*const checks[])(const hs_mesh*, hs_err*) = {check_regions,   check_tets,
                                                            check_node_tets, check_node_nbrs,
                                                            check_boundary,  check_surface_nodes};
    for (size_t k = 0; k < sizeof checks / sizeof checks[0]; ++k) {
        hs_status st = checks[k](m, err);
        if (st != HS_OK) return st;
    }
    return HS_OK;
}

// ---------------------------------------------------------------------------------------------

int hs_mesh_select_box(const hs_mesh* m, const double box_min[3], const double box_max[3],
                       unsigned char* mask) {
    if (!m || !box_min || !box_max || !mask) return -1;
    int n = 0;
    for (int i = 0; i < m->n_nodes; ++i) {
        const double* p = m->x0 + 3 * i;
        mask[i] = p[0] >= box_min[0] && p[0] <= box_max[0] && p[1] >= box_min[1] &&
                  p[1] <= box_max[1] && p[2] >= box_min[2] && p[2] <= box_max[2];
        n += mask[i];
    }
    return n;
}

int hs_mesh_select_plane(const hs_mesh* m, int axis, int side, double tol_m, unsigned char* mask) {
    if (!m || !mask || axis < 0 || axis > 2 || (side != -1 && side != 1) || !(tol_m >= 0.0))
        return -1;
    // The side of the nodes that tets use: a stray unreferenced node (kept, and in the bbox)
    // must not move it (6 mm below a liver it made a region fix 23 nodes instead of 69).
    double lo = INFINITY, hi = -INFINITY;
    for (int i = 0; i < m->n_nodes; ++i)
        if (!m->node_used || m->node_used[i]) {
            lo = min_d(lo, m->x0[3 * i + axis]);
            hi = max_d(hi, m->x0[3 * i + axis]);
        }
    int n = 0;
    for (int i = 0; i < m->n_nodes; ++i) {
        double c = m->x0[3 * i + axis];
        mask[i] = side < 0 ? c <= lo + tol_m : c >= hi - tol_m;
        n += mask[i];
    }
    return n;
}

int hs_mesh_rest_normal(const hs_mesh* m, int node, double n[3]) {
    if (!n) return -1;
    n[0] = n[1] = n[2] = 0;
    if (!m || node < 0 || node >= m->n_nodes || !m->node_surf || m->node_surf[node] < 0) return -1;
    for (int t = 0; t < m->n_tris; ++t) {
        const int* tr = m->tris + 3 * t;
        if (tr[0] != node && tr[1] != node && tr[2] != node) continue;
        const double *a = m->x0 + 3 * tr[0], *b = m->x0 + 3 * tr[1], *c = m->x0 + 3 * tr[2];
        double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
        double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
        n[0] += e1[1] * e2[2] - e1[2] * e2[1];
        n[1] += e1[2] * e2[0] - e1[0] * e2[2];
        n[2] += e1[0] * e2[1] - e1[1] * e2[0];
    }
    double l = sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (!(l > 0)) {
        n[0] = n[1] = n[2] = 0;
        return -1;
    }
    for (int k = 0; k < 3; ++k) n[k] /= l;
    return 0;
}

hs_status hs_mesh_write_vtk(const hs_mesh* m, const double* u, const char* path, hs_err* err) {
    if (!m || !path) return hs_err_set(err, HS_ERR_INVALID, "mesh or path is NULL");
    FILE* f = fopen(path, "w");
    if (!f) return hs_err_set(err, HS_ERR_IO, "%s: cannot open for writing", path);
    fprintf(f, "# vtk DataFile Version 3.0\nhapsim mesh (m)\nASCII\nDATASET UNSTRUCTURED_GRID\n");
    fprintf(f, "POINTS %d double\n", m->n_nodes);
    for (int i = 0; i < m->n_nodes; ++i)
        fprintf(f, "%.17g %.17g %.17g\n", m->x0[3 * i], m->x0[3 * i + 1], m->x0[3 * i + 2]);
    fprintf(f, "CELLS %d %d\n", m->n_tets, 5 * m->n_tets);
    for (int t = 0; t < m->n_tets; ++t) {
        const int* tet = m->tets + 4 * t;
        fprintf(f, "4 %d %d %d %d\n", tet[0], tet[1], tet[2], tet[3]);
    }
    fprintf(f, "CELL_TYPES %d\n", m->n_tets);
    for (int t = 0; t < m->n_tets; ++t) fputs("10\n", f);
    if (u) {
        fprintf(f, "POINT_DATA %d\nVECTORS displacement double\n", m->n_nodes);
        for (int i = 0; i < m->n_nodes; ++i)
            fprintf(f, "%.17g %.17g %.17g\n", u[3 * i], u[3 * i + 1], u[3 * i + 2]);
    }
    int bad = ferror(f);
    bad |= fclose(f) != 0;
    return bad ? hs_err_set(err, HS_ERR_IO, "%s: write failed", path) : HS_OK;
}

// ---------------------------------------------------------------------------------------------
// Regions and the repair report

const hs_mesh_region* hs_mesh_find_region(const hs_mesh* m, const char* name) {
    if (!m || !name) return NULL;
    const hs_mesh_region* best = NULL;
    for (int r = 0; r < m->n_regions; ++r) {
        const hs_mesh_region* g = &m->regions[r];
        char tag[16];
        snprintf(tag, sizeof tag, "%d", g->tag);
        if (strcmp(g->name, name) != 0 && strcmp(tag, name) != 0) continue;
        // A surface group is what fixing usually means; else the lowest dimension above it.
        if (!best || (g->dim == 2 && best->dim != 2) ||
            (best->dim != 2 && g->dim != 2 && g->dim > best->dim))
            best = g;
    }
    return best;
}

hs_status hs_mesh_add_region(hs_mesh* m, const char* name, int dim, int tag, int n_nodes,
                             const int* nodes, hs_err* err) {
    if (!m || !name || !name[0] || strlen(name) >= HS_MESH_REGION_NAME_MAX || dim < 0 || dim > 3 ||
        n_nodes < 0 || (n_nodes && !nodes))
        return hs_err_set(err, HS_ERR_INVALID, "region: bad name, dimension or node list");
    for (int i = 0; i < n_nodes; ++i)
        if (nodes[i] < 0 || nodes[i] >= m->n_nodes)
            return hs_err_set(err, HS_ERR_INVALID, "region '%s': node %d out of range", name,
                              nodes[i]);
    hs_mesh_region* g = hs_realloc(m->regions, (size_t)(m->n_regions + 1) * sizeof *g);
    if (!g) return hs_err_set(err, HS_ERR_NOMEM, "region: out of memory");
    m->regions = g;
    hs_mesh_region* r = &g[m->n_regions];
    memset(r, 0, sizeof *r);
    r->nodes = hs_alloc(((size_t)n_nodes + 1) * sizeof(int));
    if (!r->nodes) return hs_err_set(err, HS_ERR_NOMEM, "region: out of memory");
    if (n_nodes) memcpy(r->nodes, nodes, (size_t)n_nodes * sizeof(int));
    qsort(r->nodes, (size_t)n_nodes, sizeof(int), cmp_int);
    int u = 0;
    for (int i = 0; i < n_nodes; ++i)
        if (i == 0 || r->nodes[i] != r->nodes[i - 1]) r->nodes[u++] = r->nodes[i];
    r->n_nodes = u;
    r->dim = dim;
    r->tag = tag;
    snprintf(r->name, sizeof r->name, "%s", name);
    ++m->n_regions;
    return HS_OK;
}

void hs_mesh_report_str(const hs_mesh_report* r, char* buf, size_t cap) {
    if (!buf || cap == 0) return;
    buf[0] = '\0';
    if (!r) return;
    size_t n = 0;
    const int counts[4] = {r->reoriented_tets, r->degenerate_tets, r->duplicate_tets,
                           r->unreferenced_nodes};
    const long long* first[4] = {r->first_reoriented, r->first_degenerate, r->first_duplicate,
                                 NULL};
    static const char* const text[4] = {"tets reoriented (negative volume, two nodes swapped)",
                                        "degenerate tets removed (zero volume or repeated node)",
                                        "repeated tets removed (same four nodes as another)",
                                        "nodes used by no tet (kept, not simulated)"};
    for (int k = 0; k < 4 && n < cap; ++k) {
        if (counts[k] <= 0) continue;
        n += (size_t)snprintf(buf + n, cap - n, "%d %s", counts[k], text[k]);
        for (int j = 0; first[k] && j < HS_MESH_REPORT_FIRST && first[k][j] >= 0 && n < cap; ++j)
            n += (size_t)snprintf(buf + n, cap - n, "%s%lld", j ? ", " : ": element ", first[k][j]);
        if (first[k] && counts[k] > HS_MESH_REPORT_FIRST && n < cap)
            n += (size_t)snprintf(buf + n, cap - n, ", ...");
        if (n < cap) n += (size_t)snprintf(buf + n, cap - n, "\n");
    }
}
