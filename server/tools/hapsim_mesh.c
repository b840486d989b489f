// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-mesh: organ models from surfaces. `tet` turns a closed surface (STL, OBJ, PLY, OFF, MSH)
// into tetrahedra with gmsh, `info` reports a mesh's quality, `points` picks probe points on its
// surface, `scene` makes a ready scene folder, `surface` writes a mesh's boundary.
#define _XOPEN_SOURCE 700 // mkdir
#include "hapsim/version.h"
#include "mesh.h"
#include "mesher.h"
#include "scene.h"
#include "surface.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>

static const char* usage =
    "usage: hapsim-mesh COMMAND INPUT [options]\n"
    "\n"
    "  tet SURFACE --size H --units mm|m [--out organ.msh] [--repair] [--keep-surface]\n"
    "        [--refine NAME:H2[,WIDTH]] [--feature-angle DEG] [--gmsh NAME=VALUE ...]\n"
    "        [--group NAME:box:X0,Y0,Z0,X1,Y1,Z1] [--group NAME:plane:PX,PY,PZ,NX,NY,NZ[,TOL]]\n"
    "      Closed surface (.stl ASCII/binary, .obj, .ply, .off, .vtk POLYDATA ASCII/binary,\n"
    "      .msh/.vtu triangles) -> tetrahedra of about size H (gmsh), written as Gmsh MSH 2.2\n"
    "      in metres. Groups become named surface regions (physical groups) of the surface\n"
    "      nodes in the box / behind the plane ((x - P) . N <= TOL); a scene can fix them by\n"
    "      name. --refine NAME:H2[,WIDTH] grades the tets from H2 in group NAME's box or\n"
    "      half-space to H at WIDTH (default 4 H) away. Remeshing splits the surface into\n"
    "      patches where it turns by more than --feature-angle (default 40); --gmsh sets any\n"
    "      gmsh option last (repeatable, e.g. --gmsh Mesh.Algorithm3D=10 for HXT).\n"
    "  info MESH [--json] [--units mm|m] [--probe-radius R]\n"
    "      Nodes, tets, bounding box, volume, area, dihedral angles, radius ratios, pieces,\n"
    "      surface edge lengths, regions; warns when surface edges dwarf the probe (R, default\n"
    "      5 mm).\n"
    "  points MESH [--count N] [--json] [--up X,Y,Z] [--probe-radius R] [--units mm|m]\n"
    "      N surface points (default 8) spread over the organ with their outward normals, and the\n"
    "      top-most point along --up (default +z), as probe-script lines (surface, touch).\n"
    "  scene SURFACE_OR_MESH [--size H] --units mm|m --fix REGION [--fix ...] --out DIR\n"
    "        [--group ...] [--repair] [--youngs PA] [--probe-radius R] [--up X,Y,Z] [--cut]\n"
    "      A scene folder: DIR/organ.msh, DIR/scene.json, DIR/probe.probe (press at the top-most\n"
    "      point along --up; default: away from the fixed region). REGION is a group name (of\n"
    "      the mesh or a --group), box:X0,Y0,Z0,X1,Y1,Z1, plane:PX,PY,PZ,NX,NY,NZ[,TOL],\n"
    "      sphere:CX,CY,CZ,R, patch:PX,PY,PZ,R or bbox:x|y|z,min|max,DEPTH. --cut adds a\n"
    "      scalpel (20 mm blade), turns cutting on and writes DIR/cut.probe (a 20 mm cut).\n"
    "  surface MESH --out FILE.stl|.obj|.ply|.off [--units mm|m]\n"
    "      The boundary of a tet mesh as a surface.\n"
    "\n"
    "Lengths on the command line (H, boxes, planes, R) are in --units; output meshes are in\n"
    "metres. --units is required for surfaces: there is no silent guess (a model hundreds of\n"
    "'metres' across is called out as probably millimetres).\n"
    "Exit status: 0 done, 1 bad input or a failed step (the message says which), 2 usage.\n";

#define MAX_SPECS 8

typedef struct opts {
    const char *cmd, *input, *out;
    double size;  // in units
    double units; // metres per unit; 0: not given
    int repair, keep_surface, json, count, have_up, have_probe, cut;
    double probe_radius; // in units (converted when used)
    double up[3];
    double youngs;
    int n_groups;
    const char* groups[MAX_SPECS];
    int n_fix;
    const char* fix[MAX_SPECS];
    const char* refine;   // NAME:H2[,WIDTH]
    double feature_angle; // degrees; 0: the default
    char gmsh[1024];      // --gmsh NAME=VALUE items joined by ';'
} opts;

static int parse_list(const char* s, double* v, int min_n, int max_n) {
    int n = 0;
    while (*s && n < max_n) {
        char* e;
        v[n] = strtod(s, &e);
        if (e == s || !isfinite(v[n])) return -1;
        ++n;
        s = e;
        if (*s == ',')
            ++s;
        else
            break;
    }
    return *s || n < min_n ? -1 : n;
}

// A string as JSON text without its quotes (paths may hold quotes, backslashes, control bytes).
static const char* json_esc(const char* in, char* buf, size_t cap) {
    size_t n = 0;
    for (const unsigned char* p = (const unsigned char*)in; *p && n + 7 < cap; ++p) {
        if (*p == '"' || *p == '\\') {
            buf[n++] = '\\';
            buf[n++] = (char)*p;
        } else if (*p < 0x20) {
            n += (size_t)snprintf(buf + n, cap - n, "\\u%04x", *p);
        } else {
            buf[n++] = (char)*p;
        }
    }
    buf[n] = '\0';
    return buf;
}

// ---------------------------------------------------------------------------------------------
// Loading

static int is_surface_ext(const char* p) {
    static const char* const ext[] = {".stl", ".obj", ".ply", ".off"};
    size_t n = strlen(p);
    for (int i = 0; i < 4; ++i)
        if (n >= 4 && strcasecmp(p + n - 4, ext[i]) == 0) return 1;
    return 0;
}

// A volume mesh in metres (after units), its repairs printed.
static int load_volume(const char* path, double units, hs_mesh** m) {
    hs_err e = {0};
    hs_status st = hs_mesh_load(path, m, &e);
    if (st < 0) {
        fprintf(stderr, "hapsim-mesh: %s\n", e.msg);
        return 0;
    }
    if (st == HS_WARN_MESH_REPAIRED) {
        char rep[512];
        hs_mesh_report_str(&(*m)->report, rep, sizeof rep);
        fprintf(stderr, "hapsim-mesh: %s was repaired on loading:\n%s", path, rep);
    }
    if (units != 1.0) {
        for (int i = 0; i < 3 * (*m)->n_nodes; ++i) (*m)->x0[i] *= units;
        if (hs_mesh_finalize(*m, &e) < 0) {
            fprintf(stderr, "hapsim-mesh: %s: after scaling: %s\n", path, e.msg);
            hs_mesh_destroy(m);
            return 0;
        }
    }
    return 1;
}

// Says when the size of the model does not fit its units (no silent guess).
static void check_units(const char* path, const double lo[3], const double hi[3], double units) {
    double e[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    double diag = sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2]); // m
    if (diag > 3.0)
        fprintf(stderr,
                "hapsim-mesh: warning: %s is %.4g m across with --units %s: organs are "
                "centimetres; is it in millimetres (--units mm)?\n",
                path, diag, units == 1.0 ? "m" : "mm");
    else if (diag < 0.002)
        fprintf(stderr,
                "hapsim-mesh: warning: %s is %.4g mm across with --units %s: is it in metres "
                "(--units m)?\n",
                path, diag * 1e3, units == 1.0 ? "m" : "mm");
}

// ---------------------------------------------------------------------------------------------
// Groups (--group NAME:box:... / NAME:plane:...) as surface regions

typedef struct group_spec {
    char name[HS_MESH_REGION_NAME_MAX];
    int box;     // 1 box, 0 plane
    double v[7]; // box: min, max; plane: point, unit normal, tolerance (in `units` * units)
} group_spec;

// Parses NAME:box:... / NAME:plane:..., lengths times k. 0 (printed) when malformed.
static int parse_group(const char* spec, double k, group_spec* g) {
    const char* c1 = strchr(spec, ':');
    const char* c2 = c1 ? strchr(c1 + 1, ':') : NULL;
    memset(g, 0, sizeof *g);
    int box = c1 && strncmp(c1 + 1, "box:", 4) == 0;
    int plane = c1 && strncmp(c1 + 1, "plane:", 6) == 0;
    if (!c1 || !c2 || c1 == spec || (size_t)(c1 - spec) >= sizeof g->name || (!box && !plane) ||
        parse_list(c2 + 1, g->v, 6, box ? 6 : 7) < 0) {
        fprintf(stderr,
                "hapsim-mesh: --group '%s': expected NAME:box:X0,Y0,Z0,X1,Y1,Z1 or "
                "NAME:plane:PX,PY,PZ,NX,NY,NZ[,TOL]\n",
                spec);
        return 0;
    }
    snprintf(g->name, sizeof g->name, "%.*s", (int)(c1 - spec), spec);
    g->box = box;
    for (int i = 0; i < 7; ++i)
        if (box || i < 3 || i == 6) g->v[i] *= k;
    if (!box) {
        double nl = sqrt(g->v[3] * g->v[3] + g->v[4] * g->v[4] + g->v[5] * g->v[5]);
        if (!(nl > 0)) {
            fprintf(stderr, "hapsim-mesh: --group '%s': the plane's normal is zero\n", spec);
            return 0;
        }
        for (int d = 3; d < 6; ++d) g->v[d] /= nl;
    }
    return 1;
}

// Distance from x to the group's region (0 inside).
static double group_distance(const group_spec* g, const double x[3]) {
    if (g->box) {
        double d2 = 0;
        for (int d = 0; d < 3; ++d) {
            double e = fmax(fmax(g->v[d] - x[d], x[d] - g->v[3 + d]), 0);
            d2 += e * e;
        }
        return sqrt(d2);
    }
    double s = 0;
    for (int d = 0; d < 3; ++d) s += (x[d] - g->v[d]) * g->v[3 + d];
    return fmax(s - g->v[6], 0);
}

// --refine: sizes from h_near in the group's region up to the global size over `width`.
typedef struct refine_ctx {
    group_spec g;
    double h_near, h_far, width; // surface units
} refine_ctx;

static double refine_size(const double x[3], void* ctx) {
    const refine_ctx* r = ctx;
    double t = fmin(group_distance(&r->g, x) / r->width, 1.0);
    return r->h_near + (r->h_far - r->h_near) * t;
}

static int add_group(hs_mesh* m, const char* spec, double units, int tag) {
    group_spec g;
    if (!parse_group(spec, units, &g)) return 0;
    int* nodes = malloc(((size_t)m->n_surf_nodes + 1) * sizeof(int));
    int cnt = 0;
    for (int s = 0; nodes && s < m->n_surf_nodes; ++s)
        if (group_distance(&g, m->x0 + 3 * m->surf_nodes[s]) <= 0) nodes[cnt++] = m->surf_nodes[s];
    const char* name = g.name;
    if (!nodes || cnt == 0) {
        fprintf(stderr,
                "hapsim-mesh: --group '%s' holds no surface node (mesh bounding box [%g, %g] x "
                "[%g, %g] x [%g, %g] m)\n",
                spec, m->bbox_min[0], m->bbox_max[0], m->bbox_min[1], m->bbox_max[1],
                m->bbox_min[2], m->bbox_max[2]);
        free(nodes);
        return 0;
    }
    hs_err e = {0};
    hs_status st = hs_mesh_add_region(m, name, 2, tag, cnt, nodes, &e);
    free(nodes);
    if (st < 0) {
        fprintf(stderr, "hapsim-mesh: --group '%s': %s\n", spec, e.msg);
        return 0;
    }
    fprintf(stderr, "hapsim-mesh: group '%s': %d surface nodes\n", name, cnt);
    return 1;
}

// ---------------------------------------------------------------------------------------------
// tet

static void print_quality(FILE* f, const hs_mesh* m, double probe_m) {
    hs_mesh_quality q;
    hs_mesh_quality_compute(m, &q);
    fprintf(f, "nodes           %d\n", q.n_nodes);
    fprintf(f, "tets            %d\n", q.n_tets);
    fprintf(f, "surface         %d triangles, %d nodes\n", q.n_tris, m->n_surf_nodes);
    fprintf(f, "bounding box    [%.6g, %.6g] x [%.6g, %.6g] x [%.6g, %.6g] m\n", q.bbox_min[0],
            q.bbox_max[0], q.bbox_min[1], q.bbox_max[1], q.bbox_min[2], q.bbox_max[2]);
    fprintf(f, "volume          %.6g m^3 (%.6g ml)\n", q.volume, q.volume * 1e6);
    fprintf(f, "surface area    %.6g m^2\n", q.area);
    fprintf(f, "dihedral angles %.3g .. %.4g degrees\n", q.min_dihedral_deg, q.max_dihedral_deg);
    fprintf(f, "slivers         %d tets below 5 degrees, %d below 10\n", q.below_5deg,
            q.below_10deg);
    fprintf(f, "radius ratio    min %.3g, mean %.3g (1 regular, 0 flat)\n", q.min_radius_ratio,
            q.mean_radius_ratio);
    fprintf(f, "  histogram    ");
    for (int i = 0; i < HS_QUALITY_BINS; ++i) fprintf(f, " %d", q.ratio_hist[i]);
    fprintf(f, "  (bins of 0.1 from 0)\n");
    fprintf(f, "pieces          %d\n", q.pieces);
    fprintf(f, "surface edges   %.4g .. %.4g mm\n", q.surf_edge_min * 1e3, q.surf_edge_max * 1e3);
    for (int r = 0; r < m->n_regions; ++r)
        fprintf(f, "region          '%s' (dim %d, tag %d): %d nodes\n", m->regions[r].name,
                m->regions[r].dim, m->regions[r].tag, m->regions[r].n_nodes);
    if (q.pieces > 1)
        fprintf(stderr,
                "hapsim-mesh: warning: %d separate pieces: each needs a fixed node or the "
                "server refuses the scene\n",
                q.pieces);
    if (probe_m > 0 && q.surf_edge_max > 4 * probe_m)
        fprintf(stderr,
                "hapsim-mesh: warning: surface edges up to %.3g mm against a %.3g mm probe: the "
                "probe can fall between nodes and contact feels faceted; remesh finer "
                "(hapsim-mesh tet --size %.2g --units mm)\n",
                q.surf_edge_max * 1e3, probe_m * 1e3, probe_m * 1e3 * 2);
    if (q.below_5deg > 0)
        fprintf(stderr,
                "hapsim-mesh: warning: %d slivers (dihedral angle below 5 degrees) stiffen the "
                "model and shrink the stable time step; remesh (hapsim-mesh tet; on a coarse "
                "surface with sharp edges also try --gmsh Mesh.Algorithm3D=10 or another "
                "--feature-angle)\n",
                q.below_5deg);
}

// Surface -> checked, meshed, in metres, with the --group regions. NULL on failure (printed).
static hs_mesh* make_tets(const opts* o) {
    hs_surface* s = NULL;
    hs_err e = {0};
    if (hs_surface_load(o->input, &s, &e) < 0) {
        fprintf(stderr, "hapsim-mesh: %s\n", e.msg);
        return NULL;
    }
    hs_surface_clean_def cd = hs_surface_clean_default_def();
    cd.repair = o->repair;
    hs_surface_report rep;
    hs_status st = hs_surface_clean(s, o->input, &cd, &rep, &e);
    if (st < 0) {
        fprintf(stderr, "hapsim-mesh: %s\n", e.msg);
        hs_surface_destroy(&s);
        return NULL;
    }
    fprintf(stderr, "hapsim-mesh: %s: %d vertices, %d triangles, %g x %g x %g %s, enclosed %g\n",
            o->input, s->n_verts, s->n_tris, rep.bbox_max[0] - rep.bbox_min[0],
            rep.bbox_max[1] - rep.bbox_min[1], rep.bbox_max[2] - rep.bbox_min[2],
            o->units == 1.0 ? "m" : "mm", rep.volume);
    if (st == HS_WARN_MESH_REPAIRED) {
        char buf[1024];
        hs_surface_report_str(&rep, buf, sizeof buf);
        fprintf(stderr, "hapsim-mesh: %s: changed:\n%s", o->input, buf);
    }
    double lo[3], hi[3];
    for (int d = 0; d < 3; ++d) {
        lo[d] = rep.bbox_min[d] * o->units;
        hi[d] = rep.bbox_max[d] * o->units;
    }
    check_units(o->input, lo, hi, o->units);
    double diag = sqrt((hi[0] - lo[0]) * (hi[0] - lo[0]) + (hi[1] - lo[1]) * (hi[1] - lo[1]) +
                       (hi[2] - lo[2]) * (hi[2] - lo[2]));
    if (o->size * o->units > diag / 3)
        fprintf(stderr,
                "hapsim-mesh: warning: size %g is more than a third of the model (%g across): "
                "a handful of tets\n",
                o->size, diag / o->units);
    hs_mesher_def md = hs_mesher_default_def();
    md.size = o->size;
    md.keep_surface = o->keep_surface;
    if (o->feature_angle > 0) md.feature_angle_deg = o->feature_angle;
    if (o->gmsh[0]) md.gmsh_options = o->gmsh;
    refine_ctx rc;
    if (o->refine) { // graded: h_near in the named --group's region, the size WIDTH away
        const char* c1 = strchr(o->refine, ':');
        double hv[2] = {0, 4 * o->size};
        int found = 0;
        if (c1 && parse_list(c1 + 1, hv, 1, 2) > 0 && hv[0] > 0 && hv[0] < o->size && hv[1] > 0)
            for (int g = 0; g < o->n_groups && !found; ++g)
                if (strncmp(o->groups[g], o->refine, (size_t)(c1 - o->refine)) == 0 &&
                    o->groups[g][c1 - o->refine] == ':')
                    found = parse_group(o->groups[g], 1.0, &rc.g); // surface units
        if (!found) {
            fprintf(stderr,
                    "hapsim-mesh: --refine '%s': expected NAME:H[,WIDTH] with NAME a --group "
                    "and 0 < H < --size\n",
                    o->refine);
            hs_surface_destroy(&s);
            return NULL;
        }
        rc.h_near = hv[0];
        rc.h_far = o->size;
        rc.width = hv[1];
        md.size_at = refine_size;
        md.size_ctx = &rc;
        md.size_min = hv[0];
    }
    hs_mesh* m = NULL;
    st = hs_mesher_tet(s, &md, &m, &e);
    if (st < 0) {
        fprintf(stderr, "hapsim-mesh: %s: %s\n", o->input, e.msg);
        hs_surface_destroy(&s);
        return NULL;
    }
    if (st == HS_WARN_MESH_REPAIRED) {
        char buf[512];
        hs_mesh_report_str(&m->report, buf, sizeof buf);
        fprintf(stderr, "hapsim-mesh: the tetrahedra were repaired:\n%s", buf);
    }
    double vs = rep.volume * pow(o->units, 3);
    hs_surface_destroy(&s);
    for (int i = 0; i < 3 * m->n_nodes; ++i) m->x0[i] *= o->units;
    if (hs_mesh_finalize(m, &e) < 0) {
        fprintf(stderr, "hapsim-mesh: after scaling: %s\n", e.msg);
        hs_mesh_destroy(&m);
        return NULL;
    }
    fprintf(stderr,
            "hapsim-mesh: %d tets, %d nodes; volume %.6g m^3, %.3f %% from the surface's %.6g\n",
            m->n_tets, m->n_nodes, m->volume, 100 * (m->volume - vs) / vs, vs);
    if (fabs(m->volume - vs) > 0.01 * vs)
        fprintf(stderr,
                "hapsim-mesh: warning: the tets' volume is %.1f %% off the surface's: the size "
                "is coarse for the surface's curvature (thin or curved parts); a smaller --size, "
                "or --keep-surface to keep the input triangles\n",
                100 * (m->volume - vs) / vs);
    for (int g = 0; g < o->n_groups; ++g)
        if (!add_group(m, o->groups[g], o->units, g + 1)) {
            hs_mesh_destroy(&m);
            return NULL;
        }
    return m;
}

static char* default_out(const char* in, const char* ext) {
    size_t n = strlen(in);
    char* p = malloc(n + 8);
    if (!p) return NULL;
    memcpy(p, in, n + 1);
    char* dot = strrchr(p, '.');
    char* slash = strrchr(p, '/');
    if (dot && (!slash || dot > slash)) *dot = '\0';
    strcat(p, ext);
    return p;
}

static int cmd_tet(const opts* o) {
    if (!(o->size > 0)) {
        fprintf(stderr, "hapsim-mesh tet: --size H (> 0, in --units) is required\n");
        return 2;
    }
    hs_mesh* m = make_tets(o);
    if (!m) return 1;
    char* out = o->out ? NULL : default_out(o->input, ".msh");
    const char* path = o->out ? o->out : out;
    if (path && strcmp(path, o->input) == 0) {
        fprintf(stderr, "hapsim-mesh tet: the output would overwrite the input; give --out\n");
        free(out);
        hs_mesh_destroy(&m);
        return 2;
    }
    hs_err e = {0};
    int rc = 0;
    if (!path || hs_mesh_write_msh(m, path, &e) < 0) {
        fprintf(stderr, "hapsim-mesh: %s\n", path ? e.msg : "out of memory");
        rc = 1;
    } else {
        print_quality(stdout, m, o->have_probe ? o->probe_radius * o->units : 0.005);
        printf("written         %s (Gmsh MSH 2.2, metres)\n", path);
    }
    free(out);
    hs_mesh_destroy(&m);
    return rc;
}

// ---------------------------------------------------------------------------------------------
// info

static int cmd_info(const opts* o) {
    hs_mesh* m = NULL;
    if (!load_volume(o->input, o->units > 0 ? o->units : 1.0, &m)) return 1;
    check_units(o->input, m->bbox_min, m->bbox_max, o->units > 0 ? o->units : 1.0);
    double probe = o->have_probe ? o->probe_radius * (o->units > 0 ? o->units : 1.0) : 0.005;
    if (!o->json) {
        print_quality(stdout, m, probe);
        hs_mesh_destroy(&m);
        return 0;
    }
    hs_mesh_quality q;
    hs_mesh_quality_compute(m, &q);
    char esc[1024];
    printf("{\n  \"file\": \"%s\",\n  \"units\": \"m\",\n", json_esc(o->input, esc, sizeof esc));
    printf("  \"nodes\": %d,\n  \"tets\": %d,\n  \"surface_triangles\": %d,\n", q.n_nodes, q.n_tets,
           q.n_tris);
    printf("  \"bbox_min\": [%.9g, %.9g, %.9g],\n  \"bbox_max\": [%.9g, %.9g, %.9g],\n",
           q.bbox_min[0], q.bbox_min[1], q.bbox_min[2], q.bbox_max[0], q.bbox_max[1],
           q.bbox_max[2]);
    printf("  \"volume_m3\": %.9g,\n  \"area_m2\": %.9g,\n", q.volume, q.area);
    printf("  \"min_dihedral_deg\": %.6g,\n  \"max_dihedral_deg\": %.6g,\n", q.min_dihedral_deg,
           q.max_dihedral_deg);
    printf("  \"below_5deg\": %d,\n  \"below_10deg\": %d,\n", q.below_5deg, q.below_10deg);
    printf("  \"min_radius_ratio\": %.6g,\n  \"mean_radius_ratio\": %.6g,\n", q.min_radius_ratio,
           q.mean_radius_ratio);
    printf("  \"radius_ratio_hist\": [");
    for (int i = 0; i < HS_QUALITY_BINS; ++i) printf("%s%d", i ? ", " : "", q.ratio_hist[i]);
    printf("],\n  \"pieces\": %d,\n", q.pieces);
    printf("  \"surface_edge_min_m\": %.9g,\n  \"surface_edge_max_m\": %.9g,\n", q.surf_edge_min,
           q.surf_edge_max);
    printf("  \"probe_radius_m\": %.9g,\n  \"probe_warning\": %s,\n", probe,
           q.surf_edge_max > 4 * probe ? "true" : "false");
    printf("  \"repairs\": {\"reoriented\": %d, \"degenerate\": %d, \"duplicate\": %d, "
           "\"unreferenced_nodes\": %d},\n",
           m->report.reoriented_tets, m->report.degenerate_tets, m->report.duplicate_tets,
           m->report.unreferenced_nodes);
    printf("  \"regions\": [");
    for (int r = 0; r < m->n_regions; ++r)
        printf("%s{\"name\": \"%s\", \"dim\": %d, \"tag\": %d, \"nodes\": %d}", r ? ", " : "",
               json_esc(m->regions[r].name, esc, sizeof esc), m->regions[r].dim, m->regions[r].tag,
               m->regions[r].n_nodes);
    printf("]\n}\n");
    hs_mesh_destroy(&m);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// points

typedef struct probe_pt {
    int node;
    double x[3], n[3];
} probe_pt;

// The surface node farthest along up (normal must not cancel).
static int top_point(const hs_mesh* m, const double up[3], probe_pt* p) {
    double best = -INFINITY;
    int found = 0;
    for (int s = 0; s < m->n_surf_nodes; ++s) {
        int i = m->surf_nodes[s];
        const double* x = m->x0 + 3 * i;
        double h = x[0] * up[0] + x[1] * up[1] + x[2] * up[2];
        double n[3];
        if (h > best && hs_mesh_rest_normal(m, i, n) == 0) {
            best = h;
            p->node = i;
            memcpy(p->x, x, sizeof p->x);
            memcpy(p->n, n, sizeof p->n);
            found = 1;
        }
    }
    return found;
}

// count points spread over the surface: farthest-point sampling from the top-most point, only
// nodes whose normal points outward of the organ's centre half-space (not in folds).
static int spread_points(const hs_mesh* m, const probe_pt* top, int count, probe_pt* out) {
    double* d = malloc(((size_t)m->n_surf_nodes + 1) * sizeof(double));
    if (!d) return 0;
    for (int s = 0; s < m->n_surf_nodes; ++s) d[s] = INFINITY;
    out[0] = *top;
    int got = 1;
    while (got < count) {
        const double* last = out[got - 1].x;
        int best = -1;
        for (int s = 0; s < m->n_surf_nodes; ++s) {
            const double* x = m->x0 + 3 * m->surf_nodes[s];
            double dd = (x[0] - last[0]) * (x[0] - last[0]) + (x[1] - last[1]) * (x[1] - last[1]) +
                        (x[2] - last[2]) * (x[2] - last[2]);
            if (dd < d[s]) d[s] = dd;
            if (best < 0 || d[s] > d[best]) best = s;
        }
        if (best < 0 || !(d[best] > 0)) break;
        probe_pt p = {m->surf_nodes[best], {0}, {0}};
        memcpy(p.x, m->x0 + 3 * p.node, sizeof p.x);
        d[best] = 0;
        if (hs_mesh_rest_normal(m, p.node, p.n) != 0) continue;
        out[got++] = p;
    }
    free(d);
    return got;
}

static void print_probe_lines(FILE* f, const probe_pt* p, double r, const char* label) {
    // In mm: the scripts the stylus takes read best at organ scale.
    fprintf(f,
            "# %s: surface node %d at (%.2f, %.2f, %.2f) mm, outward normal (%.3f, %.3f, %.3f)\n",
            label, p->node, p->x[0] * 1e3, p->x[1] * 1e3, p->x[2] * 1e3, p->n[0], p->n[1], p->n[2]);
    fprintf(f, "surface %.2f %.2f %.2f   %.3f %.3f %.3f\n", (p->x[0] + r * p->n[0]) * 1e3,
            (p->x[1] + r * p->n[1]) * 1e3, (p->x[2] + r * p->n[2]) * 1e3, p->n[0], p->n[1],
            p->n[2]);
    fprintf(f, "touch %.3f %.3f %.3f 20 5\n", p->n[0], p->n[1], p->n[2]);
}

static int cmd_points(const opts* o) {
    hs_mesh* m = NULL;
    if (!load_volume(o->input, o->units > 0 ? o->units : 1.0, &m)) return 1;
    double up[3] = {0, 0, 1};
    if (o->have_up) memcpy(up, o->up, sizeof up);
    double l = sqrt(up[0] * up[0] + up[1] * up[1] + up[2] * up[2]);
    for (int d = 0; d < 3; ++d) up[d] /= l;
    double r = o->have_probe ? o->probe_radius * (o->units > 0 ? o->units : 1.0) : 0.005;
    int count = o->count > 0 ? o->count : 8;
    probe_pt top;
    probe_pt* pts = malloc((size_t)count * sizeof(probe_pt));
    if (!pts || !top_point(m, up, &top)) {
        fprintf(stderr, "hapsim-mesh: %s: no surface point with a normal\n", o->input);
        free(pts);
        hs_mesh_destroy(&m);
        return 1;
    }
    int got = spread_points(m, &top, count, pts);
    if (o->json) {
        char esc[1024];
        printf("{\n  \"file\": \"%s\",\n  \"units\": \"m\",\n  \"probe_radius_m\": %.6g,\n",
               json_esc(o->input, esc, sizeof esc), r);
        printf("  \"up\": [%.6g, %.6g, %.6g],\n", up[0], up[1], up[2]);
        printf("  \"top\": {\"node\": %d, \"x\": [%.9g, %.9g, %.9g], \"normal\": [%.6g, %.6g, "
               "%.6g]},\n",
               top.node, top.x[0], top.x[1], top.x[2], top.n[0], top.n[1], top.n[2]);
        printf("  \"points\": [\n");
        for (int i = 0; i < got; ++i)
            printf(
                "    {\"node\": %d, \"x\": [%.9g, %.9g, %.9g], \"normal\": [%.6g, %.6g, %.6g]}%s\n",
                pts[i].node, pts[i].x[0], pts[i].x[1], pts[i].x[2], pts[i].n[0], pts[i].n[1],
                pts[i].n[2], i + 1 < got ? "," : "");
        printf("  ]\n}\n");
    } else {
        printf("# hapsim-mesh points %s: probe-script lines (docs/stylus.md), mm; 'surface' is\n"
               "# where contact begins for a %.3g mm probe sphere's centre.\n",
               o->input, r * 1e3);
        printf("units mm\n");
        print_probe_lines(stdout, &top, r, "top-most point along up");
        for (int i = 1; i < got; ++i) {
            char label[32];
            snprintf(label, sizeof label, "point %d", i + 1);
            printf("\n");
            print_probe_lines(stdout, &pts[i], r, label);
        }
    }
    free(pts);
    hs_mesh_destroy(&m);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// surface

static int cmd_surface(const opts* o) {
    if (!o->out) {
        fprintf(stderr, "hapsim-mesh surface: --out FILE is required\n");
        return 2;
    }
    hs_mesh* m = NULL;
    if (!load_volume(o->input, o->units > 0 ? o->units : 1.0, &m)) return 1;
    hs_surface* s = NULL;
    hs_err e = {0};
    int rc = 0;
    if (hs_surface_from_mesh(m, &s, &e) < 0 || hs_surface_write(s, o->out, &e) < 0) {
        fprintf(stderr, "hapsim-mesh: %s\n", e.msg);
        rc = 1;
    } else {
        printf("%s: %d vertices, %d triangles (metres)\n", o->out, s->n_verts, s->n_tris);
    }
    hs_surface_destroy(&s);
    hs_mesh_destroy(&m);
    return rc;
}

// ---------------------------------------------------------------------------------------------
// scene

// A --fix spec -> a JSON fixed entry (metres) and an hs_scene_fixed for checking.
static int fix_json(const char* spec, double u, char* buf, size_t cap) {
    double v[7] = {0};
    int n;
    if (strncmp(spec, "box:", 4) == 0) {
        if (parse_list(spec + 4, v, 6, 6) < 0) return 0;
        snprintf(buf, cap,
                 "{ \"type\": \"box\", \"min\": [%.9g, %.9g, %.9g], \"max\": [%.9g, %.9g, %.9g] }",
                 v[0] * u, v[1] * u, v[2] * u, v[3] * u, v[4] * u, v[5] * u);
    } else if (strncmp(spec, "plane:", 6) == 0) {
        if ((n = parse_list(spec + 6, v, 6, 7)) < 0) return 0;
        snprintf(buf, cap,
                 "{ \"type\": \"plane\", \"point\": [%.9g, %.9g, %.9g], \"normal\": [%.9g, %.9g, "
                 "%.9g], \"tolerance\": %.9g }",
                 v[0] * u, v[1] * u, v[2] * u, v[3], v[4], v[5], v[6] * u);
    } else if (strncmp(spec, "sphere:", 7) == 0 || strncmp(spec, "patch:", 6) == 0) {
        int sphere = spec[1] == 'p';
        if (parse_list(spec + (sphere ? 7 : 6), v, 4, 4) < 0) return 0;
        snprintf(buf, cap, "{ \"type\": \"%s\", \"%s\": [%.9g, %.9g, %.9g], \"radius\": %.9g }",
                 sphere ? "sphere" : "patch", sphere ? "center" : "point", v[0] * u, v[1] * u,
                 v[2] * u, v[3] * u);
    } else if (strncmp(spec, "bbox:", 5) == 0) {
        char axis = spec[5];
        const char* side = spec + 7;
        if (spec[6] != ',' || (axis != 'x' && axis != 'y' && axis != 'z') ||
            (strncmp(side, "min,", 4) != 0 && strncmp(side, "max,", 4) != 0) ||
            parse_list(side + 4, v, 1, 1) < 0)
            return 0;
        snprintf(buf, cap,
                 "{ \"type\": \"bbox_side\", \"axis\": \"%c\", \"side\": \"%.3s\", "
                 "\"depth\": %.9g }",
                 axis, side, v[0] * u);
    } else {
        for (const char* c = spec; *c; ++c)
            if (*c == '"' || *c == '\\' || (unsigned char)*c < 0x20) return 0;
        if (!spec[0] || strlen(spec) >= HS_MESH_REGION_NAME_MAX) return 0;
        snprintf(buf, cap, "{ \"type\": \"group\", \"name\": \"%s\" }", spec);
    }
    return 1;
}

// The tets for a scene: meshed from a surface (--size given), or a volume mesh with its
// --group regions.
static hs_mesh* scene_mesh(const opts* o) {
    hs_mesh* m = NULL;
    if (is_surface_ext(o->input) || o->size > 0) return make_tets(o);
    if (load_volume(o->input, o->units, &m)) {
        check_units(o->input, m->bbox_min, m->bbox_max, o->units);
        int base = m->n_regions;
        for (int g = 0; g < o->n_groups; ++g)
            if (!add_group(m, o->groups[g], o->units, 1000 + base + g)) hs_mesh_destroy(&m);
    }
    return m;
}

static FILE* open_out(const char* path) {
    FILE* f = fopen(path, "w");
    if (!f) fprintf(stderr, "hapsim-mesh: %s: cannot write: %s\n", path, strerror(errno));
    return f;
}

// Closes f written to path: 0, or 1 after saying the write failed.
static int close_out(FILE* f, const char* path) {
    int bad = ferror(f);
    bad |= fclose(f) != 0;
    if (bad) fprintf(stderr, "hapsim-mesh: %s: write failed\n", path);
    return bad ? 1 : 0;
}

// scene.json beside organ.msh: soft tissue defaults, the fixed regions, a probe of radius r
// (and a scalpel with --cut). 0, or 1 after saying why.
static int write_scene_json(const opts* o, const hs_mesh* m, char (*fixes)[400], double r,
                            const char* path) {
    double lo[3], hi[3];
    for (int d = 0; d < 3; ++d) {
        lo[d] = m->bbox_min[d] - 0.1;
        hi[d] = m->bbox_max[d] + 0.1;
    }
    FILE* f = open_out(path);
    if (!f) return 1;
    char esc[1024];
    fprintf(f,
            "{\n  \"_comment\": \"Made by hapsim-mesh scene from %s. Soft tissue defaults: "
            "co-rotated FEM, E %g Pa, nu 0.45, gravity off (the organ rests on its "
            "surroundings). Schema: docs/scenes.md\",\n",
            json_esc(o->input, esc, sizeof esc), o->youngs);
    fprintf(f, "  \"name\": \"organ\",\n  \"mesh\": \"organ.msh\",\n  \"units_scale\": 1.0,\n");
    fprintf(f,
            "  \"material\": { \"youngs_pa\": %g, \"poisson\": 0.45, \"density_kg_m3\": 1060, "
            "\"rayleigh_mass\": 0.5, \"rayleigh_stiffness\": 0.01 },\n",
            o->youngs);
    fprintf(f, "  \"model\": { \"type\": \"corotated\" },\n  \"fixed\": [\n");
    for (int i = 0; i < o->n_fix; ++i)
        fprintf(f, "    %s%s\n", fixes[i], i + 1 < o->n_fix ? "," : "");
    fprintf(f, "  ],\n  \"gravity\": [0.0, 0.0, 0.0],\n");
    if (o->cut) // a 20 mm blade along the tool z axis, centred on the tool point
        fprintf(f,
                "  \"tools\": [ { \"kind\": \"probe\", \"radius\": %.6g },\n"
                "             { \"kind\": \"scalpel\", \"blade_a\": [0.0, 0.0, -0.01], "
                "\"blade_b\": [0.0, 0.0, 0.01] } ],\n"
                "  \"features\": { \"haptics\": true, \"cutting\": true, \"visual_mesh\": true "
                "},\n",
                r);
    else
        fprintf(f, "  \"tools\": [ { \"kind\": \"probe\", \"radius\": %.6g } ],\n", r);
    fprintf(f, "  \"workspace\": { \"min\": [%.4f, %.4f, %.4f], \"max\": [%.4f, %.4f, %.4f] }\n}\n",
            lo[0], lo[1], lo[2], hi[0], hi[1], hi[2]);
    return close_out(f, path);
}

// The fixed nodes of the scene at path, checked as the server will: it loads, every region
// selects, one node stays free. fc: the sum of the fixed nodes' positions. 0, or 1 after
// saying why.
static int check_scene_fixed(const opts* o, const hs_mesh* m, const char* path, int* n_fixed,
                             int* n_used, double fc[3]) {
    hs_scene sc;
    hs_err e = {0};
    if (hs_scene_load(path, &sc, &e) < 0) {
        fprintf(stderr, "hapsim-mesh: the scene made does not load: %s\n", e.msg);
        return 1;
    }
    unsigned char* sel = calloc((size_t)m->n_nodes, 1);
    unsigned char* all = calloc((size_t)m->n_nodes, 1);
    int rc = 0;
    for (int k = 0; sel && all && k < sc.n_fixed && !rc; ++k) {
        if (hs_scene_fixed_select(&sc.fixed[k], m, sel, &e) < 0) {
            fprintf(stderr, "hapsim-mesh: --fix '%s': %s\n", o->fix[k], e.msg);
            rc = 1;
            break;
        }
        int any = 0;
        for (int i = 0; i < m->n_nodes; ++i) {
            any |= sel[i] && m->node_used[i];
            all[i] |= sel[i] && m->node_used[i];
        }
        if (!any) {
            fprintf(stderr,
                    "hapsim-mesh: --fix '%s' selects no node (mesh bounding box [%g, %g] x [%g, "
                    "%g] x [%g, %g] m)\n",
                    o->fix[k], m->bbox_min[0], m->bbox_max[0], m->bbox_min[1], m->bbox_max[1],
                    m->bbox_min[2], m->bbox_max[2]);
            rc = 1;
        }
    }
    *n_fixed = *n_used = 0;
    for (int i = 0; !rc && all && i < m->n_nodes; ++i) {
        *n_used += m->node_used[i] != 0;
        if (all[i]) {
            ++*n_fixed;
            for (int d = 0; d < 3; ++d) fc[d] += m->x0[3 * i + d];
        }
    }
    free(sel);
    free(all);
    if (!rc && (*n_fixed == 0 || *n_fixed == *n_used)) {
        fprintf(stderr, "hapsim-mesh: the --fix regions hold %s\n",
                *n_fixed ? "every node: nothing left to move" : "no node");
        rc = 1;
    }
    return rc;
}

// Where the scripts press: the top-most surface point along up (by default away from the
// fixed region, whose centre is fc), with the sphere centre c at contact, the start s0 and the
// approach a, in mm.
typedef struct press_plan {
    probe_pt p;
    double c[3], s0[3], a[3];
} press_plan;

static int plan_press(const opts* o, const hs_mesh* m, const double fc[3], double r,
                      press_plan* pl) {
    double up[3] = {0, 0, 1};
    if (o->have_up) {
        memcpy(up, o->up, sizeof up);
    } else {
        double mc[3] = {0, 0, 0};
        for (int i = 0; i < m->n_nodes; ++i)
            for (int d = 0; d < 3; ++d) mc[d] += m->x0[3 * i + d] / m->n_nodes;
        for (int d = 0; d < 3; ++d) up[d] = mc[d] - fc[d];
        if (!(sqrt(up[0] * up[0] + up[1] * up[1] + up[2] * up[2]) > 1e-9)) up[2] = 1;
    }
    double l = sqrt(up[0] * up[0] + up[1] * up[1] + up[2] * up[2]);
    for (int d = 0; d < 3; ++d) up[d] /= l;
    if (!top_point(m, up, &pl->p)) {
        fprintf(stderr, "hapsim-mesh: no surface point with a normal\n");
        return 1;
    }
    for (int d = 0; d < 3; ++d) {
        pl->c[d] = (pl->p.x[d] + r * pl->p.n[d]) * 1e3; // contact begins (sphere centre), mm
        pl->s0[d] = pl->c[d] + 15 * pl->p.n[d];         // start 15 mm out
        pl->a[d] = pl->c[d] + 10 * pl->p.n[d];          // approach 10 mm out
    }
    return 0;
}

static int write_probe_script(const press_plan* pl, const char* path) {
    FILE* f = open_out(path);
    if (!f) return 1;
    const probe_pt* p = &pl->p;
    const double *c = pl->c, *s0 = pl->s0, *a = pl->a;
    fprintf(
        f, "# Made by hapsim-mesh scene: touch the organ at its top-most point away from the\n"
           "# fixed region, press 5 mm along the normal, hold, release. Format: docs/stylus.md.\n");
    fprintf(f,
            "# Press point: surface node %d at (%.2f, %.2f, %.2f) mm, outward normal "
            "(%.3f, %.3f, %.3f).\n",
            p->node, p->x[0] * 1e3, p->x[1] * 1e3, p->x[2] * 1e3, p->n[0], p->n[1], p->n[2]);
    fprintf(f, "units mm\n");
    fprintf(f, "surface %.2f %.2f %.2f   %.3f %.3f %.3f\n", c[0], c[1], c[2], p->n[0], p->n[1],
            p->n[2]);
    fprintf(f, "origin %.2f %.2f %.2f\n", c[0], c[1], c[2]);
    fprintf(f, "start %.2f %.2f %.2f\n", s0[0], s0[1], s0[2]);
    fprintf(f, "profile minjerk\n");
    fprintf(f, "move_to %.2f %.2f %.2f 20\n", a[0], a[1], a[2]);
    fprintf(f, "touch %.3f %.3f %.3f 20 5\n", p->n[0], p->n[1], p->n[2]);
    fprintf(f, "hold 0.5\npress %.3f %.3f %.3f 5 5\nhold 2\nrelease 5 1\nhold 0.5\n", p->n[0],
            p->n[1], p->n[2]);
    fprintf(f, "move_to %.2f %.2f %.2f 20\n", s0[0], s0[1], s0[2]);
    return close_out(f, path);
}

// Touch with the probe (button up), then hold the button and sweep the blade 20 mm along the
// surface with its axis on the normal: it reaches 5 mm into the tissue.
static int write_cut_script(const press_plan* pl, const char* path) {
    const double* n = pl->p.n;
    const double *c = pl->c, *s0 = pl->s0, *a = pl->a;
    double t[3], ax[3] = {0, 0, 0};
    int k = fabs(n[0]) < fabs(n[1]) ? (fabs(n[0]) < fabs(n[2]) ? 0 : 2)
                                    : (fabs(n[1]) < fabs(n[2]) ? 1 : 2);
    ax[k] = 1;
    t[0] = n[1] * ax[2] - n[2] * ax[1];
    t[1] = n[2] * ax[0] - n[0] * ax[2];
    t[2] = n[0] * ax[1] - n[1] * ax[0];
    double tl = sqrt(t[0] * t[0] + t[1] * t[1] + t[2] * t[2]);
    FILE* f = open_out(path);
    if (!f) return 1;
    fprintf(f,
            "# Made by hapsim-mesh scene --cut: touch the organ where probe.probe presses, then\n"
            "# hold the button and draw the 20 mm blade 20 mm along the surface (5 mm deep),\n"
            "# then lift. Format: docs/stylus.md; cutting: docs/cutting.md.\n");
    fprintf(f, "units mm\nsurface %.2f %.2f %.2f   %.3f %.3f %.3f\n", c[0], c[1], c[2], n[0], n[1],
            n[2]);
    fprintf(f, "origin %.2f %.2f %.2f\nstart %.2f %.2f %.2f\nprofile minjerk\n", c[0], c[1], c[2],
            s0[0], s0[1], s0[2]);
    fprintf(f, "move_to %.2f %.2f %.2f 20\n", a[0], a[1], a[2]);
    fprintf(f, "touch %.3f %.3f %.3f 20 5\nhold 0.5\n", n[0], n[1], n[2]);
    fprintf(f, "cut %.2f %.2f %.2f 10 %.3f %.3f %.3f\n", c[0] + 20 * t[0] / tl,
            c[1] + 20 * t[1] / tl, c[2] + 20 * t[2] / tl, n[0], n[1], n[2]);
    fprintf(f, "hold 0.5\nmove_to %.2f %.2f %.2f 20\n", s0[0] + 20 * t[0] / tl,
            s0[1] + 20 * t[1] / tl, s0[2] + 20 * t[2] / tl);
    return close_out(f, path);
}

// organ.msh, scene.json and the stylus scripts into --out; the exit status.
static int write_scene_dir(const opts* o, hs_mesh* m, char (*fixes)[400]) {
    if (mkdir(o->out, 0777) != 0 && errno != EEXIST) {
        fprintf(stderr, "hapsim-mesh: %s: cannot create: %s\n", o->out, strerror(errno));
        return 1;
    }
    char path[4200];
    hs_err e = {0};
    snprintf(path, sizeof path, "%s/organ.msh", o->out);
    if (hs_mesh_write_msh(m, path, &e) < 0) {
        fprintf(stderr, "hapsim-mesh: %s\n", e.msg);
        return 1;
    }
    double r = o->have_probe ? o->probe_radius * o->units : 0.005;
    snprintf(path, sizeof path, "%s/scene.json", o->out);
    if (write_scene_json(o, m, fixes, r, path)) return 1;
    int n_fixed = 0, n_used = 0;
    double fc[3] = {0, 0, 0};
    if (check_scene_fixed(o, m, path, &n_fixed, &n_used, fc)) return 1;
    for (int d = 0; d < 3; ++d) fc[d] /= n_fixed;
    press_plan pl;
    if (plan_press(o, m, fc, r, &pl)) return 1;
    snprintf(path, sizeof path, "%s/probe.probe", o->out);
    if (write_probe_script(&pl, path)) return 1;
    snprintf(path, sizeof path, "%s/cut.probe", o->out);
    if (o->cut && write_cut_script(&pl, path)) return 1;
    print_quality(stdout, m, r);
    printf("fixed           %d of %d nodes\n", n_fixed, n_used);
    printf("probe point     node %d at (%.2f, %.2f, %.2f) mm\n", pl.p.node, pl.p.x[0] * 1e3,
           pl.p.x[1] * 1e3, pl.p.x[2] * 1e3);
    printf("scene           %s/scene.json\n", o->out);
    printf("run             hapsim-server %s/scene.json\n", o->out);
    printf("                hapsim-stylus --script %s/probe.probe\n", o->out);
    if (o->cut) printf("                hapsim-stylus --script %s/cut.probe\n", o->out);
    return 0;
}

static int cmd_scene(const opts* o) {
    if (!o->out || o->n_fix == 0) {
        fprintf(stderr, "hapsim-mesh scene: --out DIR and at least one --fix REGION are needed\n");
        return 2;
    }
    char fixes[MAX_SPECS][400];
    for (int i = 0; i < o->n_fix; ++i)
        if (!fix_json(o->fix[i], o->units, fixes[i], sizeof fixes[i])) {
            fprintf(stderr, "hapsim-mesh scene: bad --fix '%s' (see --help)\n", o->fix[i]);
            return 2;
        }
    if ((is_surface_ext(o->input) || o->size > 0) && !(o->size > 0)) {
        fprintf(stderr, "hapsim-mesh scene: %s is a surface: --size H is required\n", o->input);
        return 2;
    }
    hs_mesh* m = scene_mesh(o);
    if (!m) return 1;
    int rc = write_scene_dir(o, m, fixes);
    hs_mesh_destroy(&m);
    return rc;
}

// ---------------------------------------------------------------------------------------------

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "hapsim-mesh")) return 0;
    opts o = {0};
    o.youngs = 5000;
    if (argc < 2 || !strcmp(argv[1], "-h") || !strcmp(argv[1], "--help")) {
        fputs(usage, argc < 2 ? stderr : stdout);
        return argc < 2 ? 2 : 0;
    }
    o.cmd = argv[1];
    for (int i = 2; i < argc; ++i) {
        const char* a = argv[i];
        const char* v = i + 1 < argc ? argv[i + 1] : NULL;
        int takes = 1;
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            fputs(usage, stdout);
            return 0;
        } else if (!strcmp(a, "--repair")) {
            o.repair = 1;
            takes = 0;
        } else if (!strcmp(a, "--keep-surface")) {
            o.keep_surface = 1;
            takes = 0;
        } else if (!strcmp(a, "--json")) {
            o.json = 1;
            takes = 0;
        } else if (!strcmp(a, "--cut")) {
            o.cut = 1;
            takes = 0;
        } else if (a[0] == '-' && a[1] == '-' && !v) {
            fprintf(stderr, "hapsim-mesh: %s needs a value\n", a);
            return 2;
        } else if (!strcmp(a, "--out")) {
            o.out = v;
        } else if (!strcmp(a, "--refine")) {
            o.refine = v;
        } else if (!strcmp(a, "--gmsh")) {
            size_t used = strlen(o.gmsh);
            if (!strchr(v, '=') || strchr(v, ';') || used + strlen(v) + 2 > sizeof o.gmsh) {
                fprintf(stderr,
                        "hapsim-mesh: bad --gmsh '%s' (one NAME=VALUE, e.g. "
                        "Mesh.Algorithm3D=10)\n",
                        v);
                return 2;
            }
            snprintf(o.gmsh + used, sizeof o.gmsh - used, "%s%s", used ? ";" : "", v);
        } else if (!strcmp(a, "--feature-angle")) {
            char* e;
            o.feature_angle = strtod(v, &e);
            if (*e || !(o.feature_angle > 0 && o.feature_angle < 180)) {
                fprintf(stderr, "hapsim-mesh: bad --feature-angle '%s' (degrees, 0 to 180)\n", v);
                return 2;
            }
        } else if (!strcmp(a, "--size")) {
            char* e;
            o.size = strtod(v, &e);
            if (*e || !(o.size > 0) || !isfinite(o.size)) {
                fprintf(stderr, "hapsim-mesh: bad --size '%s' (a length > 0)\n", v);
                return 2;
            }
        } else if (!strcmp(a, "--units")) {
            if (!strcmp(v, "mm"))
                o.units = 1e-3;
            else if (!strcmp(v, "m"))
                o.units = 1.0;
            else {
                fprintf(stderr, "hapsim-mesh: --units must be mm or m, not '%s'\n", v);
                return 2;
            }
        } else if (!strcmp(a, "--count")) {
            char* e;
            long n = strtol(v, &e, 10);
            if (*e || n < 1 || n > 10000) {
                fprintf(stderr, "hapsim-mesh: bad --count '%s' (1..10000)\n", v);
                return 2;
            }
            o.count = (int)n;
        } else if (!strcmp(a, "--probe-radius") || !strcmp(a, "--youngs")) {
            char* e;
            double x = strtod(v, &e);
            if (*e || !(x > 0) || !isfinite(x)) {
                fprintf(stderr, "hapsim-mesh: bad %s '%s' (> 0)\n", a, v);
                return 2;
            }
            if (a[2] == 'p') {
                o.probe_radius = x;
                o.have_probe = 1;
            } else {
                o.youngs = x;
            }
        } else if (!strcmp(a, "--up")) {
            if (parse_list(v, o.up, 3, 3) < 0 ||
                !(fabs(o.up[0]) + fabs(o.up[1]) + fabs(o.up[2]) > 0)) {
                fprintf(stderr, "hapsim-mesh: bad --up '%s' (X,Y,Z, not zero)\n", v);
                return 2;
            }
            o.have_up = 1;
        } else if (!strcmp(a, "--group") || !strcmp(a, "--fix")) {
            int* n = a[2] == 'g' ? &o.n_groups : &o.n_fix;
            if (*n == MAX_SPECS) {
                fprintf(stderr, "hapsim-mesh: at most %d %s\n", MAX_SPECS, a);
                return 2;
            }
            (a[2] == 'g' ? o.groups : o.fix)[(*n)++] = v;
        } else if (a[0] == '-' && a[1]) {
            fprintf(stderr, "hapsim-mesh: unknown option %s (see --help)\n", a);
            return 2;
        } else if (!o.input) {
            o.input = a;
            takes = 0;
        } else {
            fprintf(stderr, "hapsim-mesh: unexpected argument '%s'\n", a);
            return 2;
        }
        i += takes;
    }
    if (!o.input) {
        fprintf(stderr, "hapsim-mesh %s: an input file is required (see --help)\n", o.cmd);
        return 2;
    }
    int needs_units = !strcmp(o.cmd, "tet") || !strcmp(o.cmd, "scene");
    if (needs_units && o.units == 0) {
        fprintf(stderr,
                "hapsim-mesh %s: --units mm|m is required: surfaces carry no unit, and a wrong "
                "guess makes an organ a thousand times too large or small\n",
                o.cmd);
        return 2;
    }
    if (!strcmp(o.cmd, "tet")) return cmd_tet(&o);
    if (!strcmp(o.cmd, "info")) return cmd_info(&o);
    if (!strcmp(o.cmd, "points")) return cmd_points(&o);
    if (!strcmp(o.cmd, "scene")) return cmd_scene(&o);
    if (!strcmp(o.cmd, "surface")) return cmd_surface(&o);
    fprintf(stderr, "hapsim-mesh: unknown command '%s' (tet, info, points, scene, surface)\n",
            o.cmd);
    return 2;
}
