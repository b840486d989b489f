// SPDX-License-Identifier: GPL-2.0-or-later
// Gmsh MSH 2.2 ASCII output with the mesh's regions as physical groups.
#include "mesh_internal.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int in_sorted(const int* a, int n, int v) {
    int lo = 0, hi = n;
    while (lo < hi) {
        int mid = lo + (hi - lo) / 2;
        if (a[mid] < v)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo < n && a[lo] == v;
}

static int has_all(const hs_mesh_region* g, const int* nodes, int k) {
    for (int i = 0; i < k; ++i)
        if (!in_sorted(g->nodes, g->n_nodes, nodes[i])) return 0;
    return 1;
}

hs_status hs_mesh_write_msh(const hs_mesh* m, const char* path, hs_err* err) {
    if (!m || !path) return hs_err_set(err, HS_ERR_INVALID, "mesh or path is NULL");
    FILE* f = fopen(path, "w");
    if (!f) return hs_err_set(err, HS_ERR_IO, "%s: cannot write: %s", path, strerror(errno));
    fprintf(f, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n");
    if (m->n_regions > 0) {
        fprintf(f, "$PhysicalNames\n%d\n", m->n_regions);
        for (int r = 0; r < m->n_regions; ++r)
            fprintf(f, "%d %d \"%s\"\n", m->regions[r].dim, m->regions[r].tag, m->regions[r].name);
        fprintf(f, "$EndPhysicalNames\n");
    }
    fprintf(f, "$Nodes\n%d\n", m->n_nodes);
    for (int i = 0; i < m->n_nodes; ++i)
        fprintf(f, "%d %.17g %.17g %.17g\n", i + 1, m->x0[3 * i], m->x0[3 * i + 1],
                m->x0[3 * i + 2]);
    fprintf(f, "$EndNodes\n");
    // Count first: the element count comes before the elements.
    long long count = m->n_tets;
    for (int r = 0; r < m->n_regions; ++r) {
        const hs_mesh_region* g = &m->regions[r];
        if (g->dim == 2) {
            for (int t = 0; t < m->n_tris; ++t) count += has_all(g, m->tris + 3 * t, 3);
        } else if (g->dim < 2) {
            count += g->n_nodes;
        }
    }
    fprintf(f, "$Elements\n%lld\n", count);
    long long id = 1;
    for (int r = 0; r < m->n_regions; ++r) {
        const hs_mesh_region* g = &m->regions[r];
        if (g->dim == 2) {
            for (int t = 0; t < m->n_tris; ++t)
                if (has_all(g, m->tris + 3 * t, 3))
                    fprintf(f, "%lld 2 2 %d %d %d %d %d\n", id++, g->tag, r + 1, m->tris[3 * t] + 1,
                            m->tris[3 * t + 1] + 1, m->tris[3 * t + 2] + 1);
        } else if (g->dim < 2) { // points and curves: their nodes, as point elements
            for (int i = 0; i < g->n_nodes; ++i)
                fprintf(f, "%lld 15 2 %d %d %d\n", id++, g->tag, r + 1, g->nodes[i] + 1);
        }
    }
    for (int t = 0; t < m->n_tets; ++t) {
        const int* tet = m->tets + 4 * t;
        int phys = 0, ent = 1;
        for (int r = 0; r < m->n_regions && !phys; ++r)
            if (m->regions[r].dim == 3 && has_all(&m->regions[r], tet, 4)) {
                phys = m->regions[r].tag;
                ent = r + 1;
            }
        fprintf(f, "%lld 4 2 %d %d %d %d %d %d\n", id++, phys, ent, tet[0] + 1, tet[1] + 1,
                tet[2] + 1, tet[3] + 1);
    }
    fprintf(f, "$EndElements\n");
    if (fclose(f) != 0) return hs_err_set(err, HS_ERR_IO, "%s: write failed", path);
    return HS_OK;
}
