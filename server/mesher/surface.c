// SPDX-License-Identifier: GPL-2.0-or-later
// Surfaces: check and repair before meshing, the boundary of a tet mesh, writers, scaling, and
// the quality statistics of a tet mesh. Messages name the surface, the problem, how many and
// where (a coordinate in the surface's units).
#include "base_internal.h"
#include "surface_internal.h"
#include "vec3.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void hs_surface_destroy(hs_surface** s) {
    if (!s || !*s) return;
    hs_free((*s)->x);
    hs_free((*s)->tris);
    hs_free(*s);
    *s = NULL;
}

void hs_surface_scale(hs_surface* s, double k) {
    if (!s) return;
    for (int i = 0; i < 3 * s->n_verts; ++i) s->x[i] *= k;
}

hs_surface_clean_def hs_surface_clean_default_def(void) {
    return (hs_surface_clean_def){.repair = 0, .max_hole_edges = 64, .check_crossings = 1};
}

static double tri_area(const double* x, const int* t) {
    double u[3], v[3], n[3];
    hs_vec3_sub(x + 3 * t[1], x + 3 * t[0], u);
    hs_vec3_sub(x + 3 * t[2], x + 3 * t[0], v);
    hs_vec3_cross(u, v, n);
    return 0.5 * hs_vec3_norm(n);
}

static void tri_centre(const double* x, const int* t, double* c) {
    for (int d = 0; d < 3; ++d) c[d] = (x[3 * t[0] + d] + x[3 * t[1] + d] + x[3 * t[2] + d]) / 3;
}

// Signed volume contribution of an outward triangle: x0 . (x1 x x2) / 6.
static double tri_volume(const double* x, const int* t) {
    double c[3];
    hs_vec3_cross(x + 3 * t[1], x + 3 * t[2], c);
    return hs_vec3_dot(x + 3 * t[0], c) / 6.0;
}

// ---------------------------------------------------------------------------------------------
// Edges: each triangle side once, sorted by its vertex pair.

typedef struct edge_use {
    int a, b; // a < b
    int tri;
    int k;   // side k: corner k -> corner k+1
    int dir; // 1 when the side runs b -> a
} edge_use;

static int cmp_edge_use(const void* pa, const void* pb) {
    const edge_use* a = pa;
    const edge_use* b = pb;
    if (a->a != b->a) return a->a < b->a ? -1 : 1;
    if (a->b != b->b) return a->b < b->b ? -1 : 1;
    return (a->tri > b->tri) - (a->tri < b->tri);
}

// E [3 n_tris] sorted; pos[3 t + k] its index in E.
static int build_edges(const hs_surface* s, edge_use** E_out, int** pos_out) {
    size_t m = 3 * (size_t)s->n_tris;
    edge_use* E = hs_alloc((m + 1) * sizeof(edge_use));
    int* pos = hs_alloc((m + 1) * sizeof(int));
    if (!E || !pos) {
        hs_free(E);
        hs_free(pos);
        return 0;
    }
    for (int t = 0; t < s->n_tris; ++t)
        for (int k = 0; k < 3; ++k) {
            int u = s->tris[3 * t + k], v = s->tris[3 * t + (k + 1) % 3];
            E[3 * t + k] = (edge_use){u < v ? u : v, u < v ? v : u, t, k, u > v};
        }
    qsort(E, m, sizeof(edge_use), cmp_edge_use);
    for (size_t i = 0; i < m; ++i) pos[3 * E[i].tri + E[i].k] = (int)i;
    *E_out = E;
    *pos_out = pos;
    return 1;
}

// [lo, hi) of the group of uses of the edge at E[i].
static void edge_group(const edge_use* E, int m, int i, int* lo, int* hi) {
    int a = i, b = i + 1;
    while (a > 0 && E[a - 1].a == E[i].a && E[a - 1].b == E[i].b) --a;
    while (b < m && E[b].a == E[i].a && E[b].b == E[i].b) ++b;
    *lo = a;
    *hi = b;
}

static void edge_mid(const hs_surface* s, const edge_use* e, double* w) {
    for (int d = 0; d < 3; ++d) w[d] = 0.5 * (s->x[3 * e->a + d] + s->x[3 * e->b + d]);
}

// ---------------------------------------------------------------------------------------------
// Steps of the clean

// Keeps triangles with keep[t] != 0, in order.
static void keep_tris(hs_surface* s, const unsigned char* keep) {
    int n = 0;
    for (int t = 0; t < s->n_tris; ++t)
        if (keep[t]) {
            memmove(s->tris + 3 * n, s->tris + 3 * t, 3 * sizeof(int));
            ++n;
        }
    s->n_tris = n;
}

typedef struct tkey {
    int v[3];
    int t;
} tkey;

static int cmp_tkey(const void* pa, const void* pb) {
    const tkey* a = pa;
    const tkey* b = pb;
    for (int i = 0; i < 3; ++i)
        if (a->v[i] != b->v[i]) return a->v[i] < b->v[i] ? -1 : 1;
    return (a->t > b->t) - (a->t < b->t);
}

static double bbox_diag(const hs_surface* s, double* lo, double* hi) {
    for (int d = 0; d < 3; ++d) {
        lo[d] = INFINITY;
        hi[d] = -INFINITY;
    }
    for (int i = 0; i < s->n_verts; ++i)
        for (int d = 0; d < 3; ++d) {
            lo[d] = fmin(lo[d], s->x[3 * i + d]);
            hi[d] = fmax(hi[d], s->x[3 * i + d]);
        }
    double e[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    return s->n_verts ? hs_vec3_norm(e) : 0.0;
}

// Degenerate (repeated vertex, zero area) and repeated triangles: counted; removed on repair.
// Returns 0 and sets err when found without repair.
static int drop_bad_tris(hs_surface* s, const char* name, int repair, hs_surface_report* r,
                         hs_err* err) {
    double lo[3], hi[3], diag = bbox_diag(s, lo, hi);
    double min_area = 1e-14 * diag * diag;
    unsigned char* keep = hs_alloc((size_t)s->n_tris + 1);
    tkey* k = hs_alloc(((size_t)s->n_tris + 1) * sizeof(tkey));
    if (!keep || !k) {
        hs_free(keep);
        hs_free(k);
        hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", name);
        return 0;
    }
    int first_bad = -1, first_dup = -1;
    for (int t = 0; t < s->n_tris; ++t) {
        const int* v = s->tris + 3 * t;
        keep[t] =
            !(v[0] == v[1] || v[1] == v[2] || v[0] == v[2] || !(tri_area(s->x, v) > min_area));
        if (!keep[t]) {
            ++r->degenerate_tris;
            if (first_bad < 0) first_bad = t;
        }
        int a = v[0], b = v[1], c = v[2], tmp;
        if (a > b) tmp = a, a = b, b = tmp;
        if (b > c) tmp = b, b = c, c = tmp;
        if (a > b) tmp = a, a = b, b = tmp;
        k[t] = (tkey){{a, b, c}, t};
    }
    qsort(k, (size_t)s->n_tris, sizeof(tkey), cmp_tkey);
    for (int i = 1; i < s->n_tris; ++i)
        if (memcmp(k[i].v, k[i - 1].v, sizeof k[i].v) == 0 && keep[k[i].t]) {
            keep[k[i].t] = 0;
            ++r->duplicate_tris;
            if (first_dup < 0 || k[i].t < first_dup) first_dup = k[i].t;
        }
    hs_free(k);
    int ok = 1;
    if (!repair && (first_bad >= 0 || first_dup >= 0)) {
        int t = first_bad >= 0 ? first_bad : first_dup;
        tri_centre(s->x, s->tris + 3 * t, r->where);
        hs_err_set(err, HS_ERR_INVALID,
                   "%s: %d degenerate triangles (zero area or a repeated vertex) and %d repeated "
                   "triangles; the first is triangle %d at (%g, %g, %g); --repair removes them",
                   name, r->degenerate_tris, r->duplicate_tris, t + 1, r->where[0], r->where[1],
                   r->where[2]);
        ok = 0;
    } else if (first_bad >= 0 || first_dup >= 0) {
        keep_tris(s, keep);
    }
    hs_free(keep);
    return ok;
}

// Orients every piece consistently (BFS through edges of two triangles). 0 on a surface that
// cannot be oriented (a Moebius strip) or no memory.
static int orient_consistently(hs_surface* s, const char* name, hs_surface_report* r, hs_err* err) {
    edge_use* E;
    int* pos;
    if (!build_edges(s, &E, &pos)) {
        hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", name);
        return 0;
    }
    const int n = s->n_tris, m = 3 * n;
    signed char* flip = hs_alloc((size_t)n + 1);
    int* queue = hs_alloc(((size_t)n + 1) * sizeof(int));
    int ok = flip && queue;
    if (!ok) hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", name);
    if (ok) memset(flip, -1, (size_t)n);
    for (int seed = 0; ok && seed < n; ++seed) {
        if (flip[seed] >= 0) continue;
        flip[seed] = 0;
        int qh = 0, qt = 0;
        queue[qt++] = seed;
        while (ok && qh < qt) {
            int t = queue[qh++];
            for (int k = 0; k < 3 && ok; ++k) {
                int i = pos[3 * t + k], lo, hi;
                edge_group(E, m, i, &lo, &hi);
                if (hi - lo != 2) continue;
                const edge_use* o = &E[lo == i ? hi - 1 : lo];
                // The two must run the edge in opposite directions.
                int want = E[i].dir ^ flip[t] ^ o->dir ^ 1;
                if (flip[o->tri] < 0) {
                    flip[o->tri] = (signed char)want;
                    queue[qt++] = o->tri;
                } else if (flip[o->tri] != want) {
                    edge_mid(s, &E[i], r->where);
                    hs_err_set(err, HS_ERR_INVALID,
                               "%s: the surface cannot be oriented (inside and outside meet, as "
                               "on a Moebius strip) near (%g, %g, %g)",
                               name, r->where[0], r->where[1], r->where[2]);
                    ok = 0;
                }
            }
        }
    }
    for (int t = 0; ok && t < n; ++t)
        if (flip[t] == 1) {
            int* v = s->tris + 3 * t;
            int tmp = v[1];
            v[1] = v[2];
            v[2] = tmp;
            ++r->flipped_tris;
        }
    hs_free(flip);
    hs_free(queue);
    hs_free(E);
    hs_free(pos);
    return ok;
}

// Counts boundary and non-manifold edges (report, first positions). 0 on no memory.
static int count_edges(const hs_surface* s, hs_surface_report* r, double* first_open,
                       double* first_nm, hs_err* err, const char* name) {
    edge_use* E;
    int* pos;
    if (!build_edges(s, &E, &pos)) {
        hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", name);
        return 0;
    }
    const int m = 3 * s->n_tris;
    r->boundary_edges = r->nonmanifold_edges = 0;
    for (int i = 0; i < m;) {
        int lo, hi;
        edge_group(E, m, i, &lo, &hi);
        if (hi - lo == 1 && r->boundary_edges++ == 0) edge_mid(s, &E[lo], first_open);
        if (hi - lo > 2 && r->nonmanifold_edges++ == 0) edge_mid(s, &E[lo], first_nm);
        i = hi;
    }
    hs_free(E);
    hs_free(pos);
    return 1;
}

typedef struct dedge {
    int a, b;
} dedge;

static int cmp_dedge(const void* pa, const void* pb) {
    const dedge* a = pa;
    const dedge* b = pb;
    if (a->a != b->a) return a->a < b->a ? -1 : 1;
    return (a->b > b->b) - (a->b < b->b);
}

// Closes holes of at most max_edges boundary edges with a fan around their centre (triangles
// for 3). Needs consistent orientation. Holes through a pinched vertex are left open.
static int close_holes(hs_surface* s, int max_edges, hs_surface_report* r, hs_err* err,
                       const char* name) {
    edge_use* E;
    int* pos;
    if (!build_edges(s, &E, &pos)) return hs_err_set(err, HS_ERR_NOMEM, "%s: no memory", name), 0;
    const int m = 3 * s->n_tris;
    dedge* be = hs_alloc(((size_t)m + 1) * sizeof(dedge));
    int nb = 0;
    if (!be) {
        hs_free(E);
        hs_free(pos);
        return hs_err_set(err, HS_ERR_NOMEM, "%s: no memory", name), 0;
    }
    for (int i = 0; i < m;) {
        int lo, hi;
        edge_group(E, m, i, &lo, &hi);
        if (hi - lo == 1) {
            int u = E[lo].dir ? E[lo].b : E[lo].a, v = E[lo].dir ? E[lo].a : E[lo].b;
            be[nb++] = (dedge){u, v};
        }
        i = hi;
    }
    hs_free(E);
    hs_free(pos);
    qsort(be, (size_t)nb, sizeof(dedge), cmp_dedge);
    unsigned char* used = hs_calloc((size_t)nb + 1, 1);
    int* loop = hs_alloc(((size_t)nb + 1) * sizeof(int));
    int ok = used && loop;
    for (int i = 0; ok && i < nb; ++i) {
        if (used[i]) continue;
        // Walk a -> b -> ... back to a, following the one boundary edge leaving each vertex.
        int len = 0, cur = i, closed = 0, pinched = 0;
        while (!used[cur]) {
            used[cur] = 1;
            loop[len++] = be[cur].a;
            int v = be[cur].b, lo = 0, hi = nb;
            while (lo < hi) {
                int mid = (lo + hi) / 2;
                if (be[mid].a < v)
                    lo = mid + 1;
                else
                    hi = mid;
            }
            if (lo >= nb || be[lo].a != v) break;
            if (lo + 1 < nb && be[lo + 1].a == v) pinched = 1;
            if (v == be[i].a) {
                closed = 1;
                break;
            }
            cur = lo;
        }
        if (!closed || pinched || len < 3 || len > max_edges) continue;
        // New triangles run each hole edge the other way: (b, a, centre).
        int need = len == 3 ? 1 : len;
        int* g = hs_realloc(s->tris, ((size_t)s->n_tris + need) * 3 * sizeof(int));
        if (!g) {
            ok = 0;
            break;
        }
        s->tris = g;
        if (len == 3) {
            int* t = s->tris + 3 * s->n_tris++;
            t[0] = loop[2];
            t[1] = loop[1];
            t[2] = loop[0];
        } else {
            double* gx = hs_realloc(s->x, ((size_t)s->n_verts + 1) * 3 * sizeof(double));
            if (!gx) {
                ok = 0;
                break;
            }
            s->x = gx;
            double* c = s->x + 3 * s->n_verts;
            c[0] = c[1] = c[2] = 0;
            for (int k = 0; k < len; ++k)
                for (int d = 0; d < 3; ++d) c[d] += s->x[3 * loop[k] + d] / len;
            int ci = s->n_verts++;
            for (int k = 0; k < len; ++k) {
                int* t = s->tris + 3 * s->n_tris++;
                t[0] = loop[(k + 1) % len];
                t[1] = loop[k];
                t[2] = ci;
            }
        }
        ++r->holes_closed;
        r->hole_tris_added += need;
    }
    hs_free(used);
    hs_free(loop);
    hs_free(be);
    if (!ok) hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", name);
    return ok;
}

static int find_root(int* p, int i) {
    while (p[i] != i) {
        p[i] = p[p[i]];
        i = p[i];
    }
    return i;
}

// Corner of triangle t at vertex v (3 t + k).
static int corner(const hs_surface* s, int t, int v) {
    const int* q = s->tris + 3 * t;
    return 3 * t + (q[0] == v ? 0 : q[1] == v ? 1 : 2);
}

// Vertices whose triangles form more than one fan (linked through edges of two triangles):
// surfaces touching at a point. Counted into r, the first one's position in *at. 0: no memory.
static int count_pinched(const hs_surface* s, hs_surface_report* r, double* at) {
    edge_use* E;
    int* pos;
    if (!build_edges(s, &E, &pos)) return 0;
    const int m = 3 * s->n_tris;
    int* p = hs_alloc(((size_t)m + 1) * sizeof(int));
    int* first = hs_alloc(((size_t)s->n_verts + 1) * sizeof(int));
    if (!p || !first) {
        hs_free(E);
        hs_free(pos);
        hs_free(p);
        hs_free(first);
        return 0;
    }
    for (int i = 0; i < m; ++i) p[i] = i;
    for (int i = 0; i + 1 < m; ++i) {
        int lo, hi;
        edge_group(E, m, i, &lo, &hi);
        if (hi - lo == 2 && lo == i) {
            const int t1 = E[lo].tri, t2 = E[lo + 1].tri, ends[2] = {E[lo].a, E[lo].b};
            for (int k = 0; k < 2; ++k) {
                int a = find_root(p, corner(s, t1, ends[k])),
                    b = find_root(p, corner(s, t2, ends[k]));
                if (a != b) p[a] = b;
            }
        }
    }
    r->nonmanifold_verts = 0;
    for (int v = 0; v < s->n_verts; ++v) first[v] = -1;
    for (int c = 0; c < m; ++c) {
        int v = s->tris[c], root = find_root(p, c);
        if (first[v] == -1) {
            first[v] = root;
        } else if (first[v] >= 0 && first[v] != root) {
            if (r->nonmanifold_verts++ == 0) memcpy(at, s->x + 3 * v, 3 * sizeof(double));
            first[v] = -2; // counted once
        }
    }
    hs_free(E);
    hs_free(pos);
    hs_free(p);
    hs_free(first);
    return 1;
}

// Connected pieces through shared edges; keeps the largest by |volume| when drop. Flips every
// piece whose volume is negative, so all face outward.
static int pieces(hs_surface* s, int drop, hs_surface_report* r, hs_err* err, const char* name) {
    edge_use* E;
    int* pos;
    if (!build_edges(s, &E, &pos)) return hs_err_set(err, HS_ERR_NOMEM, "%s: no memory", name), 0;
    const int n = s->n_tris, m = 3 * n;
    int* p = hs_alloc(((size_t)n + 1) * sizeof(int));
    double* vol = hs_calloc((size_t)n + 1, sizeof(double));
    if (!p || !vol) {
        hs_free(E);
        hs_free(pos);
        hs_free(p);
        hs_free(vol);
        return hs_err_set(err, HS_ERR_NOMEM, "%s: no memory", name), 0;
    }
    for (int t = 0; t < n; ++t) p[t] = t;
    for (int i = 1; i < m; ++i)
        if (E[i].a == E[i - 1].a && E[i].b == E[i - 1].b) {
            int a = find_root(p, E[i].tri), b = find_root(p, E[i - 1].tri);
            if (a != b) p[a] = b;
        }
    hs_free(E);
    hs_free(pos);
    int count = 0, best = -1;
    for (int t = 0; t < n; ++t) {
        int root = find_root(p, t);
        vol[root] += tri_volume(s->x, s->tris + 3 * t);
        count += root == t;
    }
    for (int t = 0; t < n; ++t)
        if (p[t] == t && (best < 0 || fabs(vol[t]) > fabs(vol[best]))) best = t;
    r->pieces = count;
    unsigned char* keep = hs_alloc((size_t)n + 1);
    if (!keep) {
        hs_free(p);
        hs_free(vol);
        return hs_err_set(err, HS_ERR_NOMEM, "%s: no memory", name), 0;
    }
    for (int t = 0; t < n; ++t) {
        int root = find_root(p, t);
        keep[t] = !drop || root == best;
        if (vol[root] < 0) { // inside out: turn it
            int* v = s->tris + 3 * t;
            int tmp = v[1];
            v[1] = v[2];
            v[2] = tmp;
            ++r->flipped_tris;
        }
    }
    if (drop && count > 1) {
        r->pieces_dropped = count - 1;
        keep_tris(s, keep);
    }
    hs_free(keep);
    hs_free(p);
    hs_free(vol);
    return 1;
}

// Drops vertices no triangle uses (renumbering the rest in order).
static int compact(hs_surface* s, hs_surface_report* r) {
    int* map = hs_alloc(((size_t)s->n_verts + 1) * sizeof(int));
    if (!map) return 0;
    for (int i = 0; i < s->n_verts; ++i) map[i] = -1;
    for (int t = 0; t < 3 * s->n_tris; ++t) map[s->tris[t]] = 0;
    int n = 0;
    for (int i = 0; i < s->n_verts; ++i)
        if (map[i] == 0) {
            memmove(s->x + 3 * n, s->x + 3 * i, 3 * sizeof(double));
            map[i] = n++;
        }
    r->unused_vertices += s->n_verts - n;
    for (int t = 0; t < 3 * s->n_tris; ++t) s->tris[t] = map[s->tris[t]];
    s->n_verts = n;
    hs_free(map);
    return 1;
}

// ---------------------------------------------------------------------------------------------
// Self-intersections: a uniform grid over the triangles' boxes. Pairs that share no vertex are
// tested edge against triangle; pairs that share exactly one vertex can still cross along a
// segment from it (a fold at that vertex). Pairs sharing an edge only meet on it unless
// coplanar, which is not looked for. An edge counts as crossing a triangle's plane only when its
// ends lie beyond a rounding tolerance on either side (so flat regions give no false hits); the
// test against the triangle's sides has no tolerance but computes each orientation from its
// vertices in index order, so an edge through a shared side is counted in exactly one of the
// two triangles (surfaces whose vertices line up still cross somewhere).

static double orient3(const double* a, const double* b, const double* c, const double* d) {
    double u[3], v[3], w[3], n[3];
    hs_vec3_sub(b, a, u);
    hs_vec3_sub(c, a, v);
    hs_vec3_sub(d, a, w);
    hs_vec3_cross(u, v, n);
    return hs_vec3_dot(n, w);
}

// orient3 of vertices i[0..3], evaluated in increasing index order and signed by the permutation,
// so it is exactly antisymmetric whatever order a caller names them in.
static double orient_ix(const double* x, const int* i4) {
    int k[4] = {i4[0], i4[1], i4[2], i4[3]}, odd = 0;
    for (int i = 1; i < 4; ++i)
        for (int j = i; j > 0 && k[j - 1] > k[j]; --j) {
            int tmp = k[j];
            k[j] = k[j - 1];
            k[j - 1] = tmp;
            odd ^= 1;
        }
    double o = orient3(x + 3 * k[0], x + 3 * k[1], x + 3 * k[2], x + 3 * k[3]);
    return odd ? -o : o;
}

// Edge (p, q) through the inside of triangle (a, b, c), all vertex indices.
static int seg_crosses_tri(const double* x, int p, int q, const int* t, double tol) {
    int i1[4] = {t[0], t[1], t[2], p}, i2[4] = {t[0], t[1], t[2], q};
    double dp = orient_ix(x, i1), dq = orient_ix(x, i2);
    if (!((dp > tol && dq < -tol) || (dp < -tol && dq > tol))) return 0;
    int s[3];
    for (int k = 0; k < 3; ++k) {
        int i3[4] = {p, q, t[k], t[(k + 1) % 3]};
        double o = orient_ix(x, i3);
        s[k] = (o > 0) - (o < 0);
    }
    return s[0] != 0 && s[0] == s[1] && s[1] == s[2];
}

// Whether direction d points strictly into the corner of triangle (v, v + a, v + b) at v, n its
// normal a x b (d lies in its plane).
static int in_wedge(const double* a, const double* b, const double* n, const double* d) {
    double c1[3], c2[3];
    hs_vec3_cross(a, d, c1);
    hs_vec3_cross(d, b, c2);
    double tol = 1e-9 * hs_vec3_norm(d) * hs_vec3_norm(n);
    return hs_vec3_dot(c1, n) > tol * hs_vec3_norm(a) && hs_vec3_dot(c2, n) > tol * hs_vec3_norm(b);
}

// Triangles (v, a, b) and (v, c, d) that share only v cross when the line where their planes
// meet enters both corners at v on the same side. Coplanar pairs are not judged.
static int fold_at_vertex(const double* v, const double* a, const double* b, const double* v2,
                          const double* c, const double* d) {
    double ea[3], eb[3], ec[3], ed[3], n1[3], n2[3], l[3], m[3];
    hs_vec3_sub(a, v, ea);
    hs_vec3_sub(b, v, eb);
    hs_vec3_sub(c, v2, ec);
    hs_vec3_sub(d, v2, ed);
    hs_vec3_cross(ea, eb, n1);
    hs_vec3_cross(ec, ed, n2);
    hs_vec3_cross(n1, n2, l);
    if (!(hs_vec3_norm(l) > 1e-8 * hs_vec3_norm(n1) * hs_vec3_norm(n2))) return 0;
    for (int k = 0; k < 3; ++k) m[k] = -l[k];
    return (in_wedge(ea, eb, n1, l) && in_wedge(ec, ed, n2, l)) ||
           (in_wedge(ea, eb, n1, m) && in_wedge(ec, ed, n2, m));
}

static int tris_cross(const double* x, const int* t, const int* u) {
    int shared = 0, ti = -1, uj = -1;
    for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j)
            if (t[i] == u[j]) ++shared, ti = i, uj = j;
    if (shared > 1) return 0;
    const double* p[6];
    for (int k = 0; k < 3; ++k) p[k] = x + 3 * t[k], p[3 + k] = x + 3 * u[k];
    if (shared == 1)
        return fold_at_vertex(p[ti], p[(ti + 1) % 3], p[(ti + 2) % 3], p[3 + uj],
                              p[3 + (uj + 1) % 3], p[3 + (uj + 2) % 3]);
    // Orientations are products of three edge vectors: the tolerance scales with the longest.
    double l2 = 0;
    for (int k = 0; k < 3; ++k) {
        double e[3];
        hs_vec3_sub(p[k], p[(k + 1) % 3], e);
        l2 = fmax(l2, hs_vec3_dot(e, e));
        hs_vec3_sub(p[3 + k], p[3 + (k + 1) % 3], e);
        l2 = fmax(l2, hs_vec3_dot(e, e));
    }
    double tol = 1e-9 * l2 * sqrt(l2);
    for (int k = 0; k < 3; ++k)
        if (seg_crosses_tri(x, t[k], t[(k + 1) % 3], u, tol) ||
            seg_crosses_tri(x, u[k], u[(k + 1) % 3], t, tol))
            return 1;
    return 0;
}

static int count_crossings(const hs_surface* s, hs_surface_report* r) {
    const int n = s->n_tris;
    if (n < 2) return 1;
    double lo[3], hi[3];
    bbox_diag(s, lo, hi);
    double mean = 0;
    for (int t = 0; t < n; ++t) mean += sqrt(2 * tri_area(s->x, s->tris + 3 * t));
    double e[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    double h = fmax(2 * mean / n, 1e-9 * hs_vec3_norm(e));
    if (!(h > 0) || !isfinite(h)) return 1; // all in one point: nothing can cross
    int dims[3];
    for (;;) {
        double cells = 1;
        for (int d = 0; d < 3; ++d) {
            dims[d] = (int)fmin((hi[d] - lo[d]) / h, 1e6) + 1;
            cells *= dims[d];
        }
        if (cells <= 4.0 * n + 64) break;
        h *= 1.5;
    }
    // Cell ranges of each triangle, then a counting sort of (cell, triangle).
    int* range = hs_alloc(((size_t)n * 6 + 1) * sizeof(int));
    size_t ncells = (size_t)dims[0] * dims[1] * dims[2];
    int* start = hs_calloc(ncells + 2, sizeof(int));
    int* mark = hs_alloc(((size_t)n + 1) * sizeof(int));
    if (!range || !start || !mark) {
        hs_free(range);
        hs_free(start);
        hs_free(mark);
        return 0;
    }
    size_t total = 0;
    for (int t = 0; t < n; ++t) {
        int* rg = range + 6 * t;
        for (int d = 0; d < 3; ++d) {
            double a = INFINITY, b = -INFINITY;
            for (int k = 0; k < 3; ++k) {
                a = fmin(a, s->x[3 * s->tris[3 * t + k] + d]);
                b = fmax(b, s->x[3 * s->tris[3 * t + k] + d]);
            }
            rg[d] = (int)((a - lo[d]) / h);
            rg[3 + d] = (int)((b - lo[d]) / h);
            if (rg[3 + d] >= dims[d]) rg[3 + d] = dims[d] - 1;
            if (rg[d] > rg[3 + d]) rg[d] = rg[3 + d];
        }
        for (int k = rg[2]; k <= rg[5]; ++k)
            for (int j = rg[1]; j <= rg[4]; ++j)
                for (int i = rg[0]; i <= rg[3]; ++i) {
                    ++start[(size_t)i + dims[0] * ((size_t)j + dims[1] * (size_t)k) + 1];
                    ++total;
                }
    }
    int* cell_tris = total < 0x7fffffff ? hs_alloc((total + 1) * sizeof(int)) : NULL;
    if (!cell_tris) {
        hs_free(range);
        hs_free(start);
        hs_free(mark);
        return 0;
    }
    for (size_t c = 0; c < ncells; ++c) start[c + 1] += start[c];
    int* cur = hs_alloc((ncells + 1) * sizeof(int));
    if (!cur) {
        hs_free(range);
        hs_free(start);
        hs_free(mark);
        hs_free(cell_tris);
        return 0;
    }
    memcpy(cur, start, ncells * sizeof(int));
    for (int t = 0; t < n; ++t) {
        const int* rg = range + 6 * t;
        for (int k = rg[2]; k <= rg[5]; ++k)
            for (int j = rg[1]; j <= rg[4]; ++j)
                for (int i = rg[0]; i <= rg[3]; ++i)
                    cell_tris[cur[(size_t)i + dims[0] * ((size_t)j + dims[1] * (size_t)k)]++] = t;
    }
    hs_free(cur);
    for (int t = 0; t < n; ++t) mark[t] = -1;
    int found = 0;
    for (int t = 0; t < n; ++t) {
        const int* rg = range + 6 * t;
        for (int k = rg[2]; k <= rg[5]; ++k)
            for (int j = rg[1]; j <= rg[4]; ++j)
                for (int i = rg[0]; i <= rg[3]; ++i) {
                    size_t c = (size_t)i + dims[0] * ((size_t)j + dims[1] * (size_t)k);
                    for (int q = start[c]; q < start[c + 1]; ++q) {
                        int u = cell_tris[q];
                        if (u <= t || mark[u] == t) continue;
                        mark[u] = t;
                        if (tris_cross(s->x, s->tris + 3 * t, s->tris + 3 * u)) {
                            if (found++ == 0) {
                                double c1[3], c2[3];
                                tri_centre(s->x, s->tris + 3 * t, c1);
                                tri_centre(s->x, s->tris + 3 * u, c2);
                                for (int d = 0; d < 3; ++d) r->where[d] = 0.5 * (c1[d] + c2[d]);
                            }
                        }
                    }
                }
    }
    r->self_intersections = found;
    hs_free(range);
    hs_free(start);
    hs_free(mark);
    hs_free(cell_tris);
    return 1;
}

// ---------------------------------------------------------------------------------------------

static void stats(const hs_surface* s, hs_surface_report* r) {
    bbox_diag(s, r->bbox_min, r->bbox_max);
    r->area = r->volume = 0;
    r->edge_min = INFINITY;
    r->edge_max = 0;
    for (int t = 0; t < s->n_tris; ++t) {
        const int* v = s->tris + 3 * t;
        r->area += tri_area(s->x, v);
        r->volume += tri_volume(s->x, v);
        for (int k = 0; k < 3; ++k) {
            double e[3];
            hs_vec3_sub(s->x + 3 * v[k], s->x + 3 * v[(k + 1) % 3], e);
            double l = hs_vec3_norm(e);
            r->edge_min = fmin(r->edge_min, l);
            r->edge_max = fmax(r->edge_max, l);
        }
    }
    if (s->n_tris == 0) r->edge_min = 0;
}

hs_status hs_surface_clean(hs_surface* s, const char* name, const hs_surface_clean_def* def,
                           hs_surface_report* r, hs_err* err) {
    if (!s || !r) return hs_err_set(err, HS_ERR_INVALID, "surface or report is NULL");
    hs_surface_clean_def dd = def ? *def : hs_surface_clean_default_def();
    if (!name) name = "surface";
    memset(r, 0, sizeof *r);
    r->merged_vertices = s->merged_on_read;
    if (s->n_tris == 0) return hs_err_set(err, HS_ERR_INVALID, "%s: no triangles", name);
    int merged = hs_surface_weld(s);
    if (merged < 0) return hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", name);
    r->merged_vertices += merged;
    if (!drop_bad_tris(s, name, dd.repair, r, err)) return err ? err->code : HS_ERR_INVALID;
    if (s->n_tris == 0)
        return hs_err_set(err, HS_ERR_INVALID, "%s: no triangle left after the repair", name);
    double open_at[3] = {0}, nm_at[3] = {0};
    if (!count_edges(s, r, open_at, nm_at, err, name)) return HS_ERR_NOMEM;
    if (r->nonmanifold_edges) {
        memcpy(r->where, nm_at, sizeof r->where);
        return hs_err_set(err, HS_ERR_INVALID,
                          "%s: not a manifold: %d edges are shared by more than two triangles, "
                          "the first at (%g, %g, %g) (surfaces touching along an edge; no repair "
                          "for this: separate or merge them in a mesh editor)",
                          name, r->nonmanifold_edges, nm_at[0], nm_at[1], nm_at[2]);
    }
    if (!orient_consistently(s, name, r, err)) return err ? err->code : HS_ERR_INVALID;
    if (r->boundary_edges && dd.repair) {
        if (!close_holes(s, dd.max_hole_edges, r, err, name)) return HS_ERR_NOMEM;
        if (!count_edges(s, r, open_at, nm_at, err, name)) return HS_ERR_NOMEM;
    }
    if (r->boundary_edges) {
        memcpy(r->where, open_at, sizeof r->where);
        return hs_err_set(err, HS_ERR_INVALID,
                          "%s: open surface: %d boundary edges (edges of one triangle), the first "
                          "at (%g, %g, %g)%s",
                          name, r->boundary_edges, open_at[0], open_at[1], open_at[2],
                          dd.repair ? "; holes above the repair limit of edges stay open"
                                    : "; --repair closes small holes");
    }
    double pinch_at[3] = {0};
    if (!count_pinched(s, r, pinch_at))
        return hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", name);
    if (r->nonmanifold_verts) {
        memcpy(r->where, pinch_at, sizeof r->where);
        return hs_err_set(err, HS_ERR_INVALID,
                          "%s: not a manifold: %d vertices where surfaces touch at a point, the "
                          "first at (%g, %g, %g) (no repair for this: separate them in a mesh "
                          "editor)",
                          name, r->nonmanifold_verts, pinch_at[0], pinch_at[1], pinch_at[2]);
    }
    if (!pieces(s, dd.repair, r, err, name)) return HS_ERR_NOMEM;
    if (r->pieces > 1 && !dd.repair)
        return hs_err_set(err, HS_ERR_INVALID,
                          "%s: %d separate closed pieces; --repair keeps the largest", name,
                          r->pieces);
    if (!compact(s, r)) return hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", name);
    if (dd.check_crossings) {
        if (!count_crossings(s, r)) return hs_err_set(err, HS_ERR_NOMEM, "%s: no memory", name);
        if (r->self_intersections)
            return hs_err_set(err, HS_ERR_INVALID,
                              "%s: self-intersecting: %d pairs of triangles cross, the first "
                              "near (%g, %g, %g) (no repair for this: fix it in a mesh editor)",
                              name, r->self_intersections, r->where[0], r->where[1], r->where[2]);
    }
    stats(s, r);
    if (!(r->volume > 0))
        return hs_err_set(err, HS_ERR_INVALID, "%s: encloses no volume (%g)", name, r->volume);
    return r->degenerate_tris || r->duplicate_tris || r->holes_closed || r->pieces_dropped ||
                   r->flipped_tris
               ? HS_WARN_MESH_REPAIRED
               : HS_OK;
}

void hs_surface_report_str(const hs_surface_report* r, char* buf, size_t cap) {
    if (!buf || !cap) return;
    buf[0] = '\0';
    if (!r) return;
    size_t n = 0;
#define HS_LINE(count, text)                                                                       \
    if ((count) > 0 && n < cap) n += (size_t)snprintf(buf + n, cap - n, "%d " text "\n", (count));
    HS_LINE(r->degenerate_tris, "degenerate triangles removed (zero area or a repeated vertex)")
    HS_LINE(r->duplicate_tris, "repeated triangles removed")
    HS_LINE(r->holes_closed, "holes closed")
    HS_LINE(r->hole_tris_added, "triangles added to close them")
    HS_LINE(r->pieces_dropped, "separate pieces removed (the largest kept)")
    HS_LINE(r->flipped_tris, "triangles turned to face outward consistently")
#undef HS_LINE
}

// ---------------------------------------------------------------------------------------------

hs_status hs_surface_from_mesh(const hs_mesh* m, hs_surface** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "out is NULL");
    *out = NULL;
    if (!m || m->n_tris == 0) return hs_err_set(err, HS_ERR_INVALID, "mesh has no surface");
    hs_surface* s = hs_calloc(1, sizeof *s);
    if (s) {
        s->x = hs_alloc(((size_t)m->n_surf_nodes * 3 + 1) * sizeof(double));
        s->tris = hs_alloc(((size_t)m->n_tris * 3 + 1) * sizeof(int));
    }
    if (!s || !s->x || !s->tris) {
        hs_surface_destroy(&s);
        return hs_err_set(err, HS_ERR_NOMEM, "surface: out of memory");
    }
    s->n_verts = m->n_surf_nodes;
    for (int i = 0; i < m->n_surf_nodes; ++i)
        memcpy(s->x + 3 * i, m->x0 + 3 * m->surf_nodes[i], 3 * sizeof(double));
    s->n_tris = m->n_tris;
    for (int t = 0; t < 3 * m->n_tris; ++t) s->tris[t] = m->node_surf[m->tris[t]];
    *out = s;
    return HS_OK;
}

hs_status hs_surface_parse_mesh(const char* name, const char* format, const char* data, size_t len,
                                hs_surface** out, hs_err* err) {
    *out = NULL;
    hs_surface* s = hs_calloc(1, sizeof *s);
    if (!s) return hs_err_set(err, HS_ERR_NOMEM, "%s: out of memory", name);
    hs_err e2 = {0};
    hs_status st = hs_mesh_parse_triangles(name, format, data, len, &s->n_verts, &s->x, &s->n_tris,
                                           &s->tris, &e2);
    if (st == HS_OK) {
        *out = s;
        return HS_OK;
    }
    hs_surface_destroy(&s);
    // A volume mesh without triangles: its boundary.
    if (st == HS_ERR_PARSE && strstr(e2.msg, "no triangles (") && !strstr(e2.msg, "(0 ")) {
        hs_mesh* m = NULL;
        st = hs_mesh_parse(name, format, data, len, &m, err);
        if (st < 0) return st;
        st = hs_surface_from_mesh(m, out, err);
        hs_mesh_destroy(&m);
        return st;
    }
    if (err) *err = e2;
    return st;
}

// ---------------------------------------------------------------------------------------------
// Writers

static void put_le32(unsigned char* p, uint32_t v) {
    p[0] = (unsigned char)v;
    p[1] = (unsigned char)(v >> 8);
    p[2] = (unsigned char)(v >> 16);
    p[3] = (unsigned char)(v >> 24);
}

static void put_f32(unsigned char* p, double v) {
    float f = (float)v;
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    put_le32(p, u);
}

hs_status hs_surface_write(const hs_surface* s, const char* path, hs_err* err) {
    if (!s || !path) return hs_err_set(err, HS_ERR_INVALID, "surface or path is NULL");
    int fmt = hs_path_has_ext(path, ".stl")   ? 0
              : hs_path_has_ext(path, ".obj") ? 1
              : hs_path_has_ext(path, ".ply") ? 2
              : hs_path_has_ext(path, ".off") ? 3
                                              : -1;
    if (fmt < 0)
        return hs_err_set(err, HS_ERR_UNSUPPORTED, "%s: write .stl, .obj, .ply or .off", path);
    FILE* f = fopen(path, fmt == 0 ? "wb" : "w");
    if (!f) return hs_err_set(err, HS_ERR_IO, "%s: cannot write: %s", path, strerror(errno));
    if (fmt == 0) {
        unsigned char head[84] = {0}, rec[50];
        snprintf((char*)head, 80, "hapsim surface");
        put_le32(head + 80, (uint32_t)s->n_tris);
        fwrite(head, 1, 84, f);
        for (int t = 0; t < s->n_tris; ++t) {
            const int* v = s->tris + 3 * t;
            double u[3], w[3], n[3];
            hs_vec3_sub(s->x + 3 * v[1], s->x + 3 * v[0], u);
            hs_vec3_sub(s->x + 3 * v[2], s->x + 3 * v[0], w);
            hs_vec3_cross(u, w, n);
            double l = hs_vec3_norm(n);
            memset(rec, 0, sizeof rec);
            for (int d = 0; d < 3; ++d) put_f32(rec + 4 * d, l > 0 ? n[d] / l : 0);
            for (int c = 0; c < 3; ++c)
                for (int d = 0; d < 3; ++d) put_f32(rec + 12 + 12 * c + 4 * d, s->x[3 * v[c] + d]);
            fwrite(rec, 1, 50, f);
        }
    } else if (fmt == 1) {
        fprintf(f, "# hapsim surface\n");
        for (int i = 0; i < s->n_verts; ++i)
            fprintf(f, "v %.17g %.17g %.17g\n", s->x[3 * i], s->x[3 * i + 1], s->x[3 * i + 2]);
        for (int t = 0; t < s->n_tris; ++t)
            fprintf(f, "f %d %d %d\n", s->tris[3 * t] + 1, s->tris[3 * t + 1] + 1,
                    s->tris[3 * t + 2] + 1);
    } else if (fmt == 2) {
        fprintf(f,
                "ply\nformat ascii 1.0\ncomment hapsim surface\nelement vertex %d\nproperty "
                "double x\nproperty double y\nproperty double z\nelement face %d\nproperty list "
                "uchar int vertex_indices\nend_header\n",
                s->n_verts, s->n_tris);
        for (int i = 0; i < s->n_verts; ++i)
            fprintf(f, "%.17g %.17g %.17g\n", s->x[3 * i], s->x[3 * i + 1], s->x[3 * i + 2]);
        for (int t = 0; t < s->n_tris; ++t)
            fprintf(f, "3 %d %d %d\n", s->tris[3 * t], s->tris[3 * t + 1], s->tris[3 * t + 2]);
    } else {
        fprintf(f, "OFF\n%d %d 0\n", s->n_verts, s->n_tris);
        for (int i = 0; i < s->n_verts; ++i)
            fprintf(f, "%.17g %.17g %.17g\n", s->x[3 * i], s->x[3 * i + 1], s->x[3 * i + 2]);
        for (int t = 0; t < s->n_tris; ++t)
            fprintf(f, "3 %d %d %d\n", s->tris[3 * t], s->tris[3 * t + 1], s->tris[3 * t + 2]);
    }
    if (ferror(f)) {
        fclose(f);
        return hs_err_set(err, HS_ERR_IO, "%s: write failed", path);
    }
    if (fclose(f) != 0) return hs_err_set(err, HS_ERR_IO, "%s: write failed", path);
    return HS_OK;
}
