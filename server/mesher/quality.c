// SPDX-License-Identifier: GPL-2.0-or-later
// Quality statistics of a tetrahedral mesh: dihedral angles, radius ratios, sizes.
#include "surface.h"
#include "vec3.h"

#include <math.h>
#include <string.h>

// Smallest and largest dihedral angle (degrees) and the radius ratio 3 r_in / R_circ.
static void tet_measure(const double* x, const int* t, double* dmin, double* dmax, double* ratio) {
    static const int face[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
    const double* p[4] = {x + 3 * t[0], x + 3 * t[1], x + 3 * t[2], x + 3 * t[3]};
    double n[4][3], area[4], a_sum = 0;
    for (int f = 0; f < 4; ++f) {
        double u[3], v[3];
        hs_vec3_sub(p[face[f][1]], p[face[f][0]], u);
        hs_vec3_sub(p[face[f][2]], p[face[f][0]], v);
        hs_vec3_cross(u, v, n[f]);
        area[f] = 0.5 * sqrt(hs_vec3_dot(n[f], n[f]));
        a_sum += area[f];
        double l = 2 * area[f];
        for (int d = 0; d < 3; ++d) n[f][d] = l > 0 ? n[f][d] / l : 0;
    }
    *dmin = 180;
    *dmax = 0;
    for (int f = 0; f < 4; ++f)
        for (int g = f + 1; g < 4; ++g) {
            double c = -hs_vec3_dot(n[f], n[g]);
            c = c > 1 ? 1 : c < -1 ? -1 : c;
            double ang = acos(c) * 57.29577951308232;
            *dmin = fmin(*dmin, ang);
            *dmax = fmax(*dmax, ang);
        }
    double vol = fabs(hs_tet_volume(x, t));
    double e[6];
    static const int ed[6][2] = {{0, 1}, {2, 3}, {0, 2}, {1, 3}, {0, 3}, {1, 2}}; // opposite pairs
    for (int k = 0; k < 6; ++k) {
        double u[3];
        hs_vec3_sub(p[ed[k][0]], p[ed[k][1]], u);
        e[k] = sqrt(hs_vec3_dot(u, u));
    }
    double aA = e[0] * e[1], bB = e[2] * e[3], cC = e[4] * e[5];
    double q = (aA + bB + cC) * (aA + bB - cC) * (aA - bB + cC) * (-aA + bB + cC);
    double R = q > 0 && vol > 0 ? sqrt(q) / (24 * vol) : INFINITY;
    double r_in = a_sum > 0 ? 3 * vol / a_sum : 0;
    *ratio = isfinite(R) && R > 0 ? 3 * r_in / R : 0;
    if (*ratio > 1) *ratio = 1; // rounding on a regular tet
}

void hs_mesh_quality_compute(const hs_mesh* m, hs_mesh_quality* q) {
    memset(q, 0, sizeof *q);
    if (!m) return;
    q->n_nodes = m->n_nodes;
    q->n_tets = m->n_tets;
    q->n_tris = m->n_tris;
    memcpy(q->bbox_min, m->bbox_min, sizeof q->bbox_min);
    memcpy(q->bbox_max, m->bbox_max, sizeof q->bbox_max);
    q->volume = m->volume;
    q->pieces = m->report.components;
    q->min_dihedral_deg = 180;
    q->min_radius_ratio = 1;
    double sum = 0;
    for (int t = 0; t < m->n_tets; ++t) {
        double dmin, dmax, ratio;
        tet_measure(m->x0, m->tets + 4 * t, &dmin, &dmax, &ratio);
        q->min_dihedral_deg = fmin(q->min_dihedral_deg, dmin);
        q->max_dihedral_deg = fmax(q->max_dihedral_deg, dmax);
        q->below_5deg += dmin < 5;
        q->below_10deg += dmin < 10;
        q->min_radius_ratio = fmin(q->min_radius_ratio, ratio);
        sum += ratio;
        int bin = (int)(ratio * HS_QUALITY_BINS);
        q->ratio_hist[bin >= HS_QUALITY_BINS ? HS_QUALITY_BINS - 1 : bin]++;
    }
    q->mean_radius_ratio = m->n_tets ? sum / m->n_tets : 0;
    q->surf_edge_min = INFINITY;
    for (int s = 0; s < m->n_tris; ++s) {
        const int* v = m->tris + 3 * s;
        double u[3], w[3], n[3];
        hs_vec3_sub(m->x0 + 3 * v[1], m->x0 + 3 * v[0], u);
        hs_vec3_sub(m->x0 + 3 * v[2], m->x0 + 3 * v[0], w);
        hs_vec3_cross(u, w, n);
        q->area += 0.5 * sqrt(hs_vec3_dot(n, n));
        for (int k = 0; k < 3; ++k) {
            double e[3];
            hs_vec3_sub(m->x0 + 3 * v[k], m->x0 + 3 * v[(k + 1) % 3], e);
            double l = sqrt(hs_vec3_dot(e, e));
            q->surf_edge_min = fmin(q->surf_edge_min, l);
            q->surf_edge_max = fmax(q->surf_edge_max, l);
        }
    }
    if (m->n_tris == 0) q->surf_edge_min = 0;
}
