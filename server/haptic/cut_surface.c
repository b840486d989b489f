// SPDX-License-Identifier: GPL-2.0-or-later
// Live boundary followed by removals (cut_surface.h). Face k of tet e is the one opposite its
// vertex k, id 4e + k. A face is on the boundary when its tet is live and the tet across it is
// not (or there is none); removing a tet drops its boundary faces and exposes the faces of its
// live neighbours, so a removal costs O(1) and the surface lists O(n).
#include "cut_surface.h"

#include <stdlib.h>
#include <string.h>

struct hs_cut_surface {
    const hs_mesh* mesh;
    hs_mesh view;        // tris, surf_nodes, node_surf owned here; x0 the mesh's
    int* across;         // [4 n_tets] face id across each face, -1 on the mesh's boundary
    int* slot;           // [4 n_tets] index of the face in view.tris, -1 when not on it
    int* tri_face;       // [4 n_tets] face id of each triangle
    int* count;          // [n] boundary triangles at each node
    unsigned char* gone; // [n_tets]
};

void hs_cut_surface_destroy(hs_cut_surface** ps) {
    if (!ps || !*ps) return;
    hs_cut_surface* s = *ps;
    hs_free(s->view.tris);
    hs_free(s->view.surf_nodes);
    hs_free(s->view.node_surf);
    hs_free(s->across);
    hs_free(s->slot);
    hs_free(s->tri_face);
    hs_free(s->count);
    hs_free(s->gone);
    hs_free(s);
    *ps = NULL;
}

typedef struct face_sort {
    int key[3]; // sorted nodes
    int id;
} face_sort;

static int face_cmp(const void* pa, const void* pb) {
    const face_sort* a = pa;
    const face_sort* b = pb;
    for (int k = 0; k < 3; ++k)
        if (a->key[k] != b->key[k]) return (a->key[k] > b->key[k]) - (a->key[k] < b->key[k]);
    return (a->id > b->id) - (a->id < b->id);
}

// Add face id to the boundary, its triangle counter-clockwise seen from outside its tet.
static void add_face(hs_cut_surface* s, int id) {
    const int e = id / 4, k = id % 4;
    const int* t = s->mesh->tets + 4 * e;
    int v[3], m = 0;
    for (int a = 0; a < 4; ++a)
        if (a != k) v[m++] = t[a];
    const double* x = s->mesh->x0;
    const double *p0 = x + 3 * v[0], *p1 = x + 3 * v[1], *p2 = x + 3 * v[2], *pk = x + 3 * t[k];
    const double a1[3] = {p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2]};
    const double a2[3] = {p2[0] - p0[0], p2[1] - p0[1], p2[2] - p0[2]};
    const double nrm[3] = {a1[1] * a2[2] - a1[2] * a2[1], a1[2] * a2[0] - a1[0] * a2[2],
                           a1[0] * a2[1] - a1[1] * a2[0]};
    if (nrm[0] * (pk[0] - p0[0]) + nrm[1] * (pk[1] - p0[1]) + nrm[2] * (pk[2] - p0[2]) > 0) {
        const int tmp = v[1]; // the normal pointed into the tet
        v[1] = v[2];
        v[2] = tmp;
    }
    const int at = s->view.n_tris++;
    memcpy(s->view.tris + 3 * at, v, sizeof v);
    s->tri_face[at] = id;
    s->slot[id] = at;
    for (int a = 0; a < 3; ++a) s->count[v[a]]++;
}

static void drop_face(hs_cut_surface* s, int id) {
    const int at = s->slot[id], last = --s->view.n_tris;
    for (int a = 0; a < 3; ++a) s->count[s->view.tris[3 * at + a]]--;
    if (at != last) {
        memcpy(s->view.tris + 3 * at, s->view.tris + 3 * last, 3 * sizeof(int));
        s->tri_face[at] = s->tri_face[last];
        s->slot[s->tri_face[at]] = at;
    }
    s->slot[id] = -1;
}

static void list_nodes(hs_cut_surface* s) {
    int ns = 0;
    for (int i = 0; i < s->view.n_nodes; ++i) {
        s->view.node_surf[i] = s->count[i] > 0 ? ns : -1;
        if (s->count[i] > 0) s->view.surf_nodes[ns++] = i;
    }
    s->view.n_surf_nodes = ns;
}

hs_status hs_cut_surface_create(const hs_mesh* mesh, hs_cut_surface** out) {
    *out = NULL;
    if (!mesh || mesh->n_tets < 1) return HS_ERR_INVALID;
    const size_t nt = (size_t)mesh->n_tets, n = (size_t)mesh->n_nodes;
    hs_cut_surface* s = hs_calloc(1, sizeof *s);
    if (!s) return HS_ERR_NOMEM;
    s->mesh = mesh;
    s->view.n_nodes = mesh->n_nodes;
    s->view.x0 = mesh->x0;
    s->view.tris = hs_alloc(3 * 4 * nt * sizeof(int));
    s->view.surf_nodes = hs_alloc(n * sizeof(int));
    s->view.node_surf = hs_alloc(n * sizeof(int));
    s->across = hs_alloc(4 * nt * sizeof(int));
    s->slot = hs_alloc(4 * nt * sizeof(int));
    s->tri_face = hs_alloc(4 * nt * sizeof(int));
    s->count = hs_calloc(n, sizeof(int));
    s->gone = hs_calloc(nt, 1);
    face_sort* f = hs_alloc(4 * nt * sizeof *f);
    if (!s->view.tris || !s->view.surf_nodes || !s->view.node_surf || !s->across || !s->slot ||
        !s->tri_face || !s->count || !s->gone || !f) {
        hs_free(f);
        hs_cut_surface_destroy(&s);
        return HS_ERR_NOMEM;
    }
    for (size_t id = 0; id < 4 * nt; ++id) {
        const int* t = mesh->tets + 4 * (id / 4);
        int m = 0;
        for (int a = 0; a < 4; ++a)
            if (a != (int)(id % 4)) f[id].key[m++] = t[a];
        for (int i = 0; i < 2; ++i) // sort 3
            for (int j = i + 1; j < 3; ++j)
                if (f[id].key[j] < f[id].key[i]) {
                    const int tmp = f[id].key[i];
                    f[id].key[i] = f[id].key[j];
                    f[id].key[j] = tmp;
                }
        f[id].id = (int)id;
        s->across[id] = -1;
        s->slot[id] = -1;
    }
    qsort(f, 4 * nt, sizeof *f, face_cmp);
    for (size_t k = 0; k + 1 < 4 * nt; ++k)
        if (!memcmp(f[k].key, f[k + 1].key, sizeof f[k].key)) {
            s->across[f[k].id] = f[k + 1].id;
            s->across[f[k + 1].id] = f[k].id;
            ++k;
        }
    hs_free(f);
    for (int id = 0; id < 4 * (int)nt; ++id)
        if (s->across[id] < 0) add_face(s, id);
    list_nodes(s);
    *out = s;
    return HS_OK;
}

void hs_cut_surface_remove(hs_cut_surface* s, int n, const int* gone) {
    for (int k = 0; k < n; ++k) {
        const int e = gone[k];
        if (e < 0 || e >= s->mesh->n_tets || s->gone[e]) continue;
        s->gone[e] = 1;
        for (int f = 0; f < 4; ++f) {
            const int id = 4 * e + f, other = s->across[id];
            if (s->slot[id] >= 0)
                drop_face(s, id);
            else if (other >= 0 && !s->gone[other / 4])
                add_face(s, other);
        }
    }
    list_nodes(s);
}

const hs_mesh* hs_cut_surface_mesh(const hs_cut_surface* s) {
    return &s->view;
}
