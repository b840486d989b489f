// SPDX-License-Identifier: GPL-2.0-or-later
// Surfaces and the mesher: every surface format on a sphere and on the bundled liver's
// boundary becomes tets whose volume is within 1 % of the surface's, all positive, no slivers;
// broken surfaces fail naming the file and the problem (and where); --repair says what changed;
// Gmsh physical groups (MSH 2.2 and 4.1) are kept as regions, written back, and fix a scene.
#define _XOPEN_SOURCE 700 // mkdtemp
#include "mesher.h"
#include "scene.h"
#include "surface.h"
#include "test_macros.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

// Smallest dihedral angle the mesher must reach on these smooth surfaces (gmsh 4.8 gave 10.7
// to 15 degrees here).
#define MIN_DIHEDRAL_BOUND 5.0

static char g_dir[64];

static const char* tmp_path(const char* name) {
    static char buf[4][256];
    static int k;
    k = (k + 1) % 4;
    snprintf(buf[k], sizeof buf[k], "%s/%s", g_dir, name);
    return buf[k];
}

static int write_file(const char* path, const void* data, size_t len) {
    FILE* f = fopen(path, "wb");
    if (!f) return 0;
    size_t n = fwrite(data, 1, len, f);
    return fclose(f) == 0 && n == len;
}

// Icosphere of radius r: the icosahedron split `level` times, pushed onto the sphere.
static hs_surface* icosphere(double r, int level) {
    const double t = (1 + sqrt(5.0)) / 2;
    double v0[12][3] = {{-1, t, 0},  {1, t, 0},  {-1, -t, 0}, {1, -t, 0}, {0, -1, t},  {0, 1, t},
                        {0, -1, -t}, {0, 1, -t}, {t, 0, -1},  {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
    int f0[20][3] = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                     {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                     {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                     {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
    int nt = 20, nv = 12;
    for (int l = 0; l < level; ++l) nt *= 4;
    double* x = malloc((size_t)(nt * 3 + 12) * 3 * sizeof(double));
    int* tr = malloc((size_t)nt * 3 * sizeof(int));
    memcpy(x, v0, sizeof v0);
    memcpy(tr, f0, sizeof f0);
    int cur = 20;
    for (int l = 0; l < level; ++l) {
        int* nt2 = malloc((size_t)cur * 4 * 3 * sizeof(int));
        for (int f = 0; f < cur; ++f) {
            int m[3];
            for (int k = 0; k < 3; ++k) {
                int a = tr[3 * f + k], b = tr[3 * f + (k + 1) % 3];
                // midpoints repeat between neighbours: welded later by the cleaner
                for (int d = 0; d < 3; ++d) x[3 * nv + d] = 0.5 * (x[3 * a + d] + x[3 * b + d]);
                m[k] = nv++;
            }
            int* o = nt2 + 12 * f;
            int a = tr[3 * f], b = tr[3 * f + 1], c = tr[3 * f + 2];
            int q[12] = {a, m[0], m[2], b, m[1], m[0], c, m[2], m[1], m[0], m[1], m[2]};
            memcpy(o, q, sizeof q);
        }
        free(tr);
        tr = nt2;
        cur *= 4;
        x = realloc(x, (size_t)(nv + cur * 3) * 3 * sizeof(double));
    }
    hs_surface* s = hs_calloc(1, sizeof *s);
    s->n_verts = nv;
    s->n_tris = cur;
    s->x = hs_alloc((size_t)nv * 3 * sizeof(double));
    s->tris = hs_alloc((size_t)cur * 3 * sizeof(int));
    for (int i = 0; i < nv; ++i) {
        double* p = x + 3 * i;
        double l = sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
        for (int d = 0; d < 3; ++d) s->x[3 * i + d] = r * p[d] / l;
    }
    memcpy(s->tris, tr, (size_t)cur * 3 * sizeof(int));
    free(x);
    free(tr);
    hs_surface_clean_def cd = hs_surface_clean_default_def();
    hs_surface_report rep;
    hs_err e = {0};
    if (hs_surface_clean(s, "icosphere", &cd, &rep, &e) < 0) {
        fprintf(stderr, "icosphere: %s\n", e.msg);
        hs_surface_destroy(&s);
    }
    return s;
}

// Text writers for the formats hs_surface_write does not produce (ASCII STL, binary PLY, MSH).
static int write_stl_ascii(const hs_surface* s, const char* path) {
    FILE* f = fopen(path, "w");
    if (!f) return 0;
    fprintf(f, "solid test\n");
    for (int t = 0; t < s->n_tris; ++t) {
        fprintf(f, "  facet normal 0 0 0\n    outer loop\n");
        for (int k = 0; k < 3; ++k) {
            const double* p = s->x + 3 * s->tris[3 * t + k];
            fprintf(f, "      vertex %.9g %.9g %.9g\n", p[0], p[1], p[2]);
        }
        fprintf(f, "    endloop\n  endfacet\n");
    }
    fprintf(f, "endsolid test\n");
    return fclose(f) == 0;
}

static int write_ply_binary(const hs_surface* s, const char* path) {
    FILE* f = fopen(path, "wb");
    if (!f) return 0;
    fprintf(f,
            "ply\nformat binary_little_endian 1.0\nelement vertex %d\nproperty float x\nproperty "
            "float y\nproperty float z\nelement face %d\nproperty list uchar int "
            "vertex_indices\nend_header\n",
            s->n_verts, s->n_tris);
    for (int i = 0; i < 3 * s->n_verts; ++i) {
        float v = (float)s->x[i];
        fwrite(&v, 4, 1, f); // this machine is little-endian (x86-64, arm64)
    }
    for (int t = 0; t < s->n_tris; ++t) {
        unsigned char three = 3;
        fwrite(&three, 1, 1, f);
        fwrite(s->tris + 3 * t, 4, 3, f);
    }
    return fclose(f) == 0;
}

static int write_msh_tris(const hs_surface* s, const char* path) {
    FILE* f = fopen(path, "w");
    if (!f) return 0;
    fprintf(f, "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n%d\n", s->n_verts);
    for (int i = 0; i < s->n_verts; ++i)
        fprintf(f, "%d %.17g %.17g %.17g\n", i + 1, s->x[3 * i], s->x[3 * i + 1], s->x[3 * i + 2]);
    fprintf(f, "$EndNodes\n$Elements\n%d\n", s->n_tris);
    for (int t = 0; t < s->n_tris; ++t)
        fprintf(f, "%d 2 2 0 1 %d %d %d\n", t + 1, s->tris[3 * t] + 1, s->tris[3 * t + 1] + 1,
                s->tris[3 * t + 2] + 1);
    fprintf(f, "$EndElements\n");
    return fclose(f) == 0;
}

// VTK XML unstructured grid, ASCII, as hapsim-view writes it: cells of k points and VTK type.
static int write_vtu(const char* path, int n_pts, const double* x, int n_cells, const int* cells,
                     int k, int type) {
    FILE* f = fopen(path, "w");
    if (!f) return 0;
    fprintf(f,
            "<?xml version=\"1.0\"?>\n<VTKFile type=\"UnstructuredGrid\" version=\"0.1\" "
            "byte_order=\"LittleEndian\">\n<UnstructuredGrid>\n<Piece NumberOfPoints=\"%d\" "
            "NumberOfCells=\"%d\">\n<PointData>\n<DataArray type=\"Float32\" Name=\"d\" "
            "format=\"ascii\">\n",
            n_pts, n_cells);
    for (int i = 0; i < n_pts; ++i) fprintf(f, "0\n");
    fprintf(f, "</DataArray>\n</PointData>\n<Points>\n<DataArray type=\"Float64\" "
               "Name=\"Points\" NumberOfComponents=\"3\" format=\"ascii\">\n");
    for (int i = 0; i < n_pts; ++i)
        fprintf(f, "%.17g %.17g %.17g\n", x[3 * i], x[3 * i + 1], x[3 * i + 2]);
    fprintf(f, "</DataArray>\n</Points>\n<Cells>\n<DataArray type=\"Int32\" "
               "Name=\"connectivity\" format=\"ascii\">\n");
    for (int c = 0; c < n_cells; ++c) {
        for (int j = 0; j < k; ++j) fprintf(f, "%d ", cells[k * c + j]);
        fprintf(f, "\n");
    }
    fprintf(f, "</DataArray>\n<DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">\n");
    for (int c = 0; c < n_cells; ++c) fprintf(f, "%d\n", k * (c + 1));
    fprintf(f, "</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for (int c = 0; c < n_cells; ++c) fprintf(f, "%d\n", type);
    fprintf(f, "</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    return fclose(f) == 0;
}

// Legacy VTK POLYDATA: ASCII in the classic cell layout (version 4.2), or binary (big-endian)
// in the 5.1 OFFSETS/CONNECTIVITY layout with float points.
static void put_be(unsigned char* p, uint64_t v, int n) {
    for (int i = 0; i < n; ++i) p[i] = (unsigned char)(v >> (8 * (n - 1 - i)));
}

static int write_vtk(const hs_surface* s, const char* path, int binary) {
    FILE* f = fopen(path, "wb");
    if (!f) return 0;
    fprintf(f, "# vtk DataFile Version %s\nsurface\n%s\nDATASET POLYDATA\n", binary ? "5.1" : "4.2",
            binary ? "BINARY" : "ASCII");
    fprintf(f, "POINTS %d %s\n", s->n_verts, binary ? "float" : "double");
    unsigned char b[8];
    for (int i = 0; i < 3 * s->n_verts; ++i) {
        if (!binary) {
            fprintf(f, "%.17g%s", s->x[i], i % 3 == 2 ? "\n" : " ");
            continue;
        }
        float v = (float)s->x[i];
        uint32_t u;
        memcpy(&u, &v, 4);
        put_be(b, u, 4);
        fwrite(b, 1, 4, f);
    }
    if (!binary) {
        fprintf(f, "POLYGONS %d %d\n", s->n_tris, 4 * s->n_tris);
        for (int t = 0; t < s->n_tris; ++t)
            fprintf(f, "3 %d %d %d\n", s->tris[3 * t], s->tris[3 * t + 1], s->tris[3 * t + 2]);
    } else {
        fprintf(f, "\nPOLYGONS %d %d\nOFFSETS vtktypeint64\n", s->n_tris + 1, 3 * s->n_tris);
        for (int t = 0; t <= s->n_tris; ++t) {
            put_be(b, (uint64_t)(3 * t), 8);
            fwrite(b, 1, 8, f);
        }
        fprintf(f, "\nCONNECTIVITY vtktypeint64\n");
        for (int i = 0; i < 3 * s->n_tris; ++i) {
            put_be(b, (uint64_t)s->tris[i], 8);
            fwrite(b, 1, 8, f);
        }
        fprintf(f, "\n");
    }
    fprintf(f, "POINT_DATA %d\nSCALARS id int 1\nLOOKUP_TABLE default\n", s->n_verts);
    return fclose(f) == 0;
}

// Writes `s` as `name` in the format its extension says.
static int write_as(const hs_surface* s, const char* name) {
    const char* path = tmp_path(name);
    if (strstr(name, "_ascii.stl")) return write_stl_ascii(s, path);
    if (strstr(name, "_bin.ply")) return write_ply_binary(s, path);
    if (strstr(name, ".msh")) return write_msh_tris(s, path);
    if (strstr(name, ".vtk")) return write_vtk(s, path, strstr(name, "_bin") != NULL);
    if (strstr(name, ".vtu")) return write_vtu(path, s->n_verts, s->x, s->n_tris, s->tris, 3, 5);
    hs_err e = {0};
    return hs_surface_write(s, path, &e) == HS_OK;
}

// Reads `path`, cleans, meshes at `size`: volume within 1 % of the enclosed one, all tets
// positive (hs_mesh_check), no dihedral angle below the bound.
static int mesh_and_check(const char* path, double size, int keep_surface) {
    hs_surface* s = NULL;
    hs_err e = {0};
    hs_status st = hs_surface_load(path, &s, &e);
    if (st < 0) fprintf(stderr, "%s\n", e.msg);
    ENSURE(st == HS_OK);
    hs_surface_clean_def cd = hs_surface_clean_default_def();
    hs_surface_report rep;
    st = hs_surface_clean(s, path, &cd, &rep, &e);
    if (st < 0) fprintf(stderr, "%s\n", e.msg);
    ENSURE(st >= 0);
    hs_mesher_def md = hs_mesher_default_def();
    md.size = size;
    md.keep_surface = keep_surface;
    hs_mesh* m = NULL;
    st = hs_mesher_tet(s, &md, &m, &e);
    if (st < 0) fprintf(stderr, "%s: %s\n", path, e.msg);
    ENSURE(st >= 0 && m);
    hs_err ce = {0};
    ENSURE(hs_mesh_check(m, &ce) == HS_OK);
    ENSURE(m->report.reoriented_tets == 0 && m->report.degenerate_tets == 0);
    hs_mesh_quality q;
    hs_mesh_quality_compute(m, &q);
    double rel = (m->volume - rep.volume) / rep.volume;
    printf("  %-28s %6d tets, volume %+.3f %%, min dihedral %.1f deg, %d pieces\n",
           strrchr(path, '/') + 1, m->n_tets, 100 * rel, q.min_dihedral_deg, q.pieces);
    ENSURE(fabs(rel) <= 0.01);
    ENSURE(q.min_dihedral_deg >= MIN_DIHEDRAL_BOUND && q.pieces == 1);
    hs_mesh_destroy(&m);
    hs_surface_destroy(&s);
    return 0;
}

static const char* const k_formats[] = {"_bin.stl", "_ascii.stl", ".obj", ".ply",       "_bin.ply",
                                        ".off",     ".msh",       ".vtu", "_ascii.vtk", "_bin.vtk"};

static int EveryFormatSphere(void) {
    int64_t before = hs_byte_count();
    hs_surface* s = icosphere(0.05, 3); // 642 vertices, 1280 triangles, radius 5 cm
    ENSURE(s && s->n_verts == 642 && s->n_tris == 1280);
    for (size_t f = 0; f < sizeof k_formats / sizeof *k_formats; ++f) {
        char name[64];
        snprintf(name, sizeof name, "sphere%s", k_formats[f]);
        ENSURE(write_as(s, name));
        ENSURE(mesh_and_check(tmp_path(name), 0.008, f % 2) == 0);
    }
    hs_surface_destroy(&s);
    ENSURE(hs_byte_count() == before);
    return 0;
}

static int EveryFormatLiver(void) {
    int64_t before = hs_byte_count();
    hs_mesh* m = NULL;
    hs_err e = {0};
    ENSURE(hs_mesh_load(HS_SOURCE_DIR "/scenes/liver/liver2.msh", &m, &e) >= 0);
    hs_surface* s = NULL;
    ENSURE(hs_surface_from_mesh(m, &s, &e) == HS_OK && s->n_tris == m->n_tris);
    hs_mesh_destroy(&m);
    for (size_t f = 0; f < sizeof k_formats / sizeof *k_formats; ++f) {
        char name[64];
        snprintf(name, sizeof name, "liver%s", k_formats[f]);
        ENSURE(write_as(s, name));
        ENSURE(mesh_and_check(tmp_path(name), 0.008, f % 2) == 0);
    }
    hs_surface_destroy(&s);
    ENSURE(hs_byte_count() == before);
    return 0;
}

// A failing load or clean: the message names the file and contains `what`.
static int expect_fail(const char* name, const void* data, size_t len, const char* what) {
    const char* path = tmp_path(name);
    ENSURE(write_file(path, data, len));
    hs_surface* s = NULL;
    hs_err e = {0};
    hs_status st = hs_surface_load(path, &s, &e);
    if (st >= 0) {
        hs_surface_clean_def cd = hs_surface_clean_default_def();
        hs_surface_report rep;
        st = hs_surface_clean(s, path, &cd, &rep, &e);
        hs_surface_destroy(&s);
    }
    printf("  %s -> %s\n", name, e.msg);
    ENSURE(st < 0 && s == NULL);
    ENSURE(strstr(e.msg, path) != NULL);
    ENSURE(strstr(e.msg, what) != NULL);
    return 0;
}

static int BrokenSurfaces(void) {
    int64_t before = hs_byte_count();
    // Tetrahedron surfaces as OBJ text.
    const char* tet_obj =
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
    ENSURE(expect_fail("open.obj", tet_obj, strlen(tet_obj) - 8, "open surface") == 0);
    ENSURE(expect_fail("open2.obj", tet_obj, strlen(tet_obj) - 8, "boundary edges") == 0);
    const char* nan_obj = "v 0 0 0\nv 1 0 nan\nv 0 1 0\nv 0 0 1\nf 1 3 2\n";
    ENSURE(expect_fail("nan.obj", nan_obj, strlen(nan_obj), ":2: vertex 2") == 0);
    ENSURE(expect_fail("empty.stl", "", 0, "empty file") == 0);
    ENSURE(expect_fail("empty.obj", "", 0, "empty file") == 0);
    ENSURE(expect_fail("empty.off", "", 0, "empty file") == 0);
    ENSURE(expect_fail("empty.ply", "", 0, "empty file") == 0);
    unsigned char junk[300];
    for (size_t i = 0; i < sizeof junk; ++i) junk[i] = (unsigned char)(i * 131 + 7);
    ENSURE(expect_fail("junk.stl", junk, sizeof junk, "binary STL header says") == 0);
    ENSURE(expect_fail("junk.obj", junk, sizeof junk, "") == 0);
    ENSURE(expect_fail("junk.ply", junk, sizeof junk, "not a PLY file") == 0);
    ENSURE(expect_fail("junk.off", junk, sizeof junk, "not an OFF file") == 0);
    ENSURE(expect_fail("junk.msh", junk, sizeof junk, "not a Gmsh MSH file") == 0);
    // Index out of range, short binary PLY, an ASCII STL facet of 2 vertices.
    const char* bad_idx = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n";
    ENSURE(expect_fail("idx.off", bad_idx, strlen(bad_idx), "vertex index 7 out of range") == 0);
    const char* stl2 = "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
                       "endloop\nendfacet\nendsolid x\n";
    ENSURE(expect_fail("two.stl", stl2, strlen(stl2), "has 2 vertices, not 3") == 0);
    // Two tetrahedra sharing one edge: not a manifold.
    const char* nm = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 0 -1 0\nv 0 0 -1\n"
                     "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\nf 1 2 5\nf 1 6 2\nf 1 5 6\nf 2 6 5\n";
    ENSURE(expect_fail("nonmanifold.obj", nm, strlen(nm), "not a manifold") == 0);
    // Two tetrahedra touching at one vertex: not a manifold either.
    const char* pinch = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv -1 0 0\nv 0 -1 0\nv 0 0 -1\n"
                        "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\nf 1 6 5\nf 1 5 7\nf 1 7 6\nf 5 6 7\n";
    ENSURE(expect_fail("pinched.obj", pinch, strlen(pinch),
                       "touch at a point, the first at (0, 0, 0)") == 0);
    // Two spheres in one file: two pieces, refused without --repair.
    hs_surface* a = icosphere(1.0, 1);
    hs_surface* b = icosphere(1.0, 1);
    for (int i = 0; i < b->n_verts; ++i) b->x[3 * i] += 3;
    FILE* f = fopen(tmp_path("two.obj"), "w");
    ENSURE(f);
    for (int i = 0; i < a->n_verts; ++i)
        fprintf(f, "v %.9g %.9g %.9g\n", a->x[3 * i], a->x[3 * i + 1], a->x[3 * i + 2]);
    for (int i = 0; i < b->n_verts; ++i)
        fprintf(f, "v %.9g %.9g %.9g\n", b->x[3 * i], b->x[3 * i + 1], b->x[3 * i + 2]);
    for (int t = 0; t < a->n_tris; ++t)
        fprintf(f, "f %d %d %d\n", a->tris[3 * t] + 1, a->tris[3 * t + 1] + 1,
                a->tris[3 * t + 2] + 1);
    for (int t = 0; t < b->n_tris; ++t)
        fprintf(f, "f %d %d %d\n", b->tris[3 * t] + 1 + a->n_verts,
                b->tris[3 * t + 1] + 1 + a->n_verts, b->tris[3 * t + 2] + 1 + a->n_verts);
    fclose(f);
    hs_surface* s = NULL;
    hs_err e = {0};
    ENSURE(hs_surface_load(tmp_path("two.obj"), &s, &e) == HS_OK);
    hs_surface_clean_def cd = hs_surface_clean_default_def();
    hs_surface_report rep;
    hs_status st = hs_surface_clean(s, "two.obj", &cd, &rep, &e);
    printf("  two.obj -> %s\n", e.msg);
    ENSURE(st == HS_ERR_INVALID && strstr(e.msg, "2 separate closed pieces"));
    cd.repair = 1; // keeps the larger piece and says so
    ENSURE(hs_surface_clean(s, "two.obj", &cd, &rep, &e) == HS_WARN_MESH_REPAIRED);
    ENSURE(rep.pieces_dropped == 1 && s->n_verts == a->n_verts && s->n_tris == a->n_tris);
    hs_surface_destroy(&s);
    hs_surface_destroy(&a);
    hs_surface_destroy(&b);
    ENSURE(hs_byte_count() == before);
    return 0;
}

// Legacy VTK POLYDATA beyond triangles: a cube of quads (ASCII), the same as triangle strips
// (binary, classic 32-bit cells), an unstructured grid of tets; then broken files.
static int VtkPolyData(void) {
    int64_t before = hs_byte_count();
    const char* pts = "POINTS 8 float\n0 0 0 1 0 0 1 1 0 0 1 0\n0 0 1 1 0 1 1 1 1 0 1 1\n";
    char quads[512];
    snprintf(quads, sizeof quads,
             "# vtk DataFile Version 3.0\ncube\nASCII\nDATASET POLYDATA\n%sPOLYGONS 6 30\n"
             "4 0 3 2 1\n4 4 5 6 7\n4 0 1 5 4\n4 1 2 6 5\n4 2 3 7 6\n4 3 0 4 7\n"
             "CELL_DATA 6\n",
             pts);
    const char* path = tmp_path("cube_quads.vtk");
    ENSURE(write_file(path, quads, strlen(quads)));
    hs_surface* s = NULL;
    hs_err e = {0};
    ENSURE(hs_surface_load(path, &s, &e) == HS_OK && s->n_verts == 8 && s->n_tris == 12);
    hs_surface_clean_def cd = hs_surface_clean_default_def();
    hs_surface_report rep;
    ENSURE(hs_surface_clean(s, path, &cd, &rep, &e) == HS_OK && fabs(rep.volume - 1) < 1e-12);
    hs_surface_destroy(&s);
    // Binary: two strips of 6 points cover the cube (4 + 4 triangles) plus the two caps.
    static const int strips[2][8] = {{4, 0, 5, 1, 6, 2, 7, 3}, {7, 3, 4, 0, -1, -1, -1, -1}};
    unsigned char bin[1024];
    size_t n = (size_t)snprintf((char*)bin, sizeof bin,
                                "# vtk DataFile Version 3.0\ncube\nBINARY\nDATASET POLYDATA\n"
                                "POINTS 8 float\n");
    static const float xyz[24] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0,
                                  0, 0, 1, 1, 0, 1, 1, 1, 1, 0, 1, 1};
    for (int i = 0; i < 24; ++i) {
        uint32_t u;
        memcpy(&u, &xyz[i], 4);
        put_be(bin + n, u, 4);
        n += 4;
    }
    n += (size_t)snprintf((char*)bin + n, sizeof bin - n, "\nTRIANGLE_STRIPS 2 14\n");
    for (int k = 0; k < 2; ++k) {
        int len = k ? 4 : 8;
        put_be(bin + n, (uint64_t)len, 4), n += 4;
        for (int j = 0; j < len; ++j) put_be(bin + n, (uint64_t)strips[k][j], 4), n += 4;
    }
    n += (size_t)snprintf((char*)bin + n, sizeof bin - n, "\nPOLYGONS 2 10\n");
    static const int caps[10] = {4, 0, 3, 2, 1, 4, 4, 5, 6, 7};
    for (int j = 0; j < 10; ++j) put_be(bin + n, (uint64_t)caps[j], 4), n += 4;
    path = tmp_path("cube_strips.vtk");
    ENSURE(write_file(path, bin, n));
    e.msg[0] = '\0';
    hs_status st = hs_surface_load(path, &s, &e);
    if (st < 0) printf("  %s\n", e.msg);
    ENSURE(st == HS_OK && s->n_tris == 12);
    st = hs_surface_clean(s, path, &cd, &rep, &e);
    ENSURE(st >= 0 && fabs(rep.volume - 1) < 1e-12 && rep.flipped_tris == 0);
    hs_surface_destroy(&s);
    // An unstructured grid of tets gives its boundary.
    const char* ug = "# vtk DataFile Version 3.0\ntet\nASCII\nDATASET UNSTRUCTURED_GRID\n"
                     "POINTS 4 float\n0 0 0 1 0 0 0 1 0 0 0 1\nCELLS 1 5\n4 0 1 2 3\n"
                     "CELL_TYPES 1\n10\n";
    path = tmp_path("tet_grid.vtk");
    ENSURE(write_file(path, ug, strlen(ug)));
    ENSURE(hs_surface_load(path, &s, &e) == HS_OK && s->n_tris == 4);
    hs_surface_destroy(&s);
    // Broken files: the file, the line (or byte) and the problem.
    const char* head = "# vtk DataFile Version 3.0\nx\nASCII\nDATASET POLYDATA\n";
    char buf[512];
#define HS_BROKEN(name, body, what)                                                                \
    snprintf(buf, sizeof buf, "%s%s", head, body);                                                 \
    ENSURE(expect_fail(name, buf, strlen(buf), what) == 0)
    HS_BROKEN("noface.vtk", "POINTS 3 float\n0 0 0 1 0 0 0 1 0\n", "no POLYGONS");
    HS_BROKEN("range.vtk", "POINTS 3 float\n0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 7\n",
              ":8: point index 7 out of range [0, 2]");
    HS_BROKEN("nan.vtk", "POINTS 3 float\n0 0 0\n1 nan 0\n0 1 0\n", ":7: vertex 2");
    HS_BROKEN("two.vtk", "POINTS 3 float\n0 0 0 1 0 0 0 1 0\nPOLYGONS 1 3\n2 0 1\n",
              "polygon 1 has 2 points");
    HS_BROKEN("size.vtk", "POINTS 3 float\n0 0 0 1 0 0 0 1 0\nPOLYGONS 1 5\n3 0 1 2\n",
              ":7: POLYGONS size is 5 but the cells use 4");
    HS_BROKEN("order.vtk", "POLYGONS 1 4\n3 0 1 2\n", ":5: POLYGONS before POINTS");
    HS_BROKEN("count.vtk", "POINTS 99999999 float\n0 0 0\n", "point count 99999999 does not fit");
    HS_BROKEN("short.vtk", "POINTS 2 float\n0 0 0 1 0\n", ":6: missing point coordinate");
    HS_BROKEN("type.vtk", "POINTS 3 quaternion\n", ":5: POINTS: unknown data type 'quaternion'");
    HS_BROKEN("grid.vtk", "POINTS 3 float\n0 0 0 1 0 0 0 1 0\nVOXELS 1\n",
              ":7: unexpected 'VOXELS'");
#undef HS_BROKEN
    const char* sp = "# vtk DataFile Version 3.0\nx\nASCII\nDATASET STRUCTURED_POINTS\n";
    ENSURE(expect_fail("sp.vtk", sp, strlen(sp),
                       ":4: DATASET STRUCTURED_POINTS is not a surface") == 0);
    ENSURE(expect_fail("empty.vtk", "", 0, "empty file") == 0);
    ENSURE(expect_fail("notvtk.vtk", "hello\n", 6, ":1: not a legacy VTK file") == 0);
    // A binary file cut short in its point data names the byte.
    ENSURE(expect_fail("cut.vtk", bin, n - 4, ": byte 296: file ends in the binary point index") ==
           0);
    ENSURE(hs_byte_count() == before);
    return 0;
}

static int SelfIntersection(void) {
    int64_t before = hs_byte_count();
    // A sphere whose top cap is pushed down through its bottom (a folded surface): one piece,
    // manifold, orientable, crossing itself.
    hs_surface* s = icosphere(1.0, 2);
    for (int i = 0; i < s->n_verts; ++i)
        if (s->x[3 * i + 2] > 0.5) s->x[3 * i + 2] = -1.3 + 0.3 * (s->x[3 * i + 2] - 0.5);
    hs_surface_clean_def cd = hs_surface_clean_default_def();
    hs_surface_report rep;
    hs_err e = {0};
    hs_status st = hs_surface_clean(s, "folded", &cd, &rep, &e);
    printf("  folded sphere -> %s\n", e.msg);
    ENSURE(st == HS_ERR_INVALID && strstr(e.msg, "self-intersecting") &&
           rep.self_intersections > 0);
    hs_surface_destroy(&s);
    ENSURE(hs_byte_count() == before);
    return 0;
}

// A fold at a shared vertex: the double cone over a pentagram. Each cone's triangles meet only
// at its apex, yet non-neighbouring ones cross along a line from it; no two triangles that
// share no vertex cross (the ring lies in z = 0, where cones touch but do not cross).
static int FoldAtSharedVertex(void) {
    int64_t before = hs_byte_count();
    hs_surface* s = hs_calloc(1, sizeof *s);
    s->n_verts = 7;
    s->n_tris = 10;
    s->x = hs_alloc(7 * 3 * sizeof(double));
    s->tris = hs_alloc(10 * 3 * sizeof(int));
    double apex[2][3] = {{0, 0, 1}, {0, 0, -1}};
    memcpy(s->x, apex, sizeof apex);
    for (int k = 0; k < 5; ++k) {
        double a = 2 * M_PI * ((2 * k) % 5) / 5; // pentagram order: every second pentagon corner
        double* p = s->x + 3 * (2 + k);
        p[0] = cos(a), p[1] = sin(a), p[2] = 0;
        int* t = s->tris + 6 * k;
        t[0] = 0, t[1] = 2 + k, t[2] = 2 + (k + 1) % 5;
        t[3] = 1, t[4] = 2 + (k + 1) % 5, t[5] = 2 + k;
    }
    hs_surface_clean_def cd = hs_surface_clean_default_def();
    hs_surface_report rep;
    hs_err e = {0};
    hs_status st = hs_surface_clean(s, "pentagram", &cd, &rep, &e);
    printf("  pentagram double cone -> %s\n", e.msg);
    // Per cone, the 5 pairs of non-neighbouring triangles cross.
    ENSURE(st == HS_ERR_INVALID && strstr(e.msg, "self-intersecting") &&
           rep.self_intersections == 10);
    // The same cone over a convex pentagon is fine.
    for (int k = 0; k < 5; ++k) {
        double a = 2 * M_PI * k / 5;
        s->x[3 * (2 + k)] = cos(a), s->x[3 * (2 + k) + 1] = sin(a);
    }
    ENSURE(hs_surface_clean(s, "pentagon", &cd, &rep, &e) >= 0 && rep.self_intersections == 0);
    hs_surface_destroy(&s);
    ENSURE(hs_byte_count() == before);
    return 0;
}

static int Repair(void) {
    int64_t before = hs_byte_count();
    hs_surface* s = icosphere(0.05, 2); // 162 vertices, 320 triangles
    // A hole of 6 edges (the fan of triangles around vertex 0), a repeated triangle and a
    // degenerate one, and one triangle turned inside out.
    int n_fan = 0;
    for (int t = 0; t < s->n_tris; ++t) {
        int* v = s->tris + 3 * t;
        if (v[0] == 0 || v[1] == 0 || v[2] == 0) {
            memmove(v, v + 3, (size_t)(s->n_tris - t - 1) * 3 * sizeof(int));
            --s->n_tris;
            --t;
            ++n_fan;
        }
    }
    ENSURE(n_fan == 5);
    s->tris = hs_realloc(s->tris, (size_t)(s->n_tris + 2) * 3 * sizeof(int));
    memcpy(s->tris + 3 * s->n_tris, s->tris, 3 * sizeof(int));
    int deg[3] = {s->tris[3], s->tris[3], s->tris[4]};
    memcpy(s->tris + 3 * (s->n_tris + 1), deg, sizeof deg);
    s->n_tris += 2;
    int tmp = s->tris[3 * 10 + 1];
    s->tris[3 * 10 + 1] = s->tris[3 * 10 + 2];
    s->tris[3 * 10 + 2] = tmp;
    hs_surface_clean_def cd = hs_surface_clean_default_def();
    hs_surface_report rep;
    hs_err e = {0};
    ENSURE(hs_surface_clean(s, "holed", &cd, &rep, &e) == HS_ERR_INVALID);
    ENSURE(strstr(e.msg, "1 degenerate triangles") && strstr(e.msg, "1 repeated"));
    cd.repair = 1;
    hs_status st = hs_surface_clean(s, "holed", &cd, &rep, &e);
    char buf[512];
    hs_surface_report_str(&rep, buf, sizeof buf);
    printf("  repaired:\n%s", buf);
    ENSURE(st == HS_WARN_MESH_REPAIRED);
    ENSURE(rep.degenerate_tris == 1 && rep.duplicate_tris == 1 && rep.holes_closed == 1 &&
           rep.hole_tris_added == 5 && rep.flipped_tris >= 1 && rep.boundary_edges == 0);
    ENSURE(strstr(buf, "1 holes closed") && strstr(buf, "1 repeated triangles removed"));
    // Closed again: the fan point sits in the hole's plane, so the volume is a little less.
    ENSURE(rep.volume > 0.95 * 4.0 / 3 * 3.14159265358979 * 0.05 * 0.05 * 0.05);
    hs_surface_destroy(&s);
    ENSURE(hs_byte_count() == before);
    return 0;
}

// ---------------------------------------------------------------------------------------------
// Named regions

static const char* k_msh22 =
    "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n"
    "$PhysicalNames\n2\n2 5 \"hilum\"\n3 7 \"liver tissue\"\n$EndPhysicalNames\n"
    "$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 1 1 1\n$EndNodes\n"
    "$Elements\n4\n1 2 2 5 1 1 3 2\n2 15 2 9 1 5\n3 4 2 7 1 1 2 3 4\n4 4 2 0 1 2 5 3 4\n"
    "$EndElements\n";

static const char* k_msh41 =
    "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n"
    "$PhysicalNames\n2\n2 5 \"base\"\n3 7 \"body\"\n$EndPhysicalNames\n"
    "$Entities\n0 0 1 1\n1 0 0 0 1 1 0 1 5 0\n1 0 0 0 1 1 1 1 7 1 1\n$EndEntities\n"
    "$Nodes\n1 4 1 4\n3 1 0 4\n1\n2\n3\n4\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n"
    "$Elements\n2 2 1 2\n2 1 2 1\n1 1 3 2\n3 1 4 1\n2 1 2 3 4\n$EndElements\n";

static int PhysicalGroups(void) {
    int64_t before = hs_byte_count();
    hs_mesh* m = NULL;
    hs_err e = {0};
    ENSURE(hs_mesh_parse("g.msh", "msh", k_msh22, strlen(k_msh22), &m, &e) >= 0);
    ENSURE(m->n_regions == 3);
    const hs_mesh_region* h = hs_mesh_find_region(m, "hilum");
    ENSURE(h && h->dim == 2 && h->tag == 5 && h->n_nodes == 3 && h->nodes[0] == 0 &&
           h->nodes[1] == 1 && h->nodes[2] == 2);
    const hs_mesh_region* v = hs_mesh_find_region(m, "liver tissue");
    ENSURE(v && v->dim == 3 && v->n_nodes == 4);
    const hs_mesh_region* p = hs_mesh_find_region(m, "9"); // unnamed: its tag
    ENSURE(p && p->dim == 0 && p->n_nodes == 1 && p->nodes[0] == 4);
    ENSURE(hs_mesh_find_region(m, "nothing") == NULL);
    ENSURE(hs_mesh_check(m, &e) == HS_OK);
    // Written and read back: same regions.
    ENSURE(hs_mesh_write_msh(m, tmp_path("g_out.msh"), &e) == HS_OK);
    hs_mesh* m2 = NULL;
    ENSURE(hs_mesh_load(tmp_path("g_out.msh"), &m2, &e) >= 0);
    ENSURE(m2->n_regions == 3 && m2->n_tets == 2);
    const hs_mesh_region* h2 = hs_mesh_find_region(m2, "hilum");
    ENSURE(h2 && h2->n_nodes == 3 && h2->dim == 2);
    hs_mesh_destroy(&m2);
    hs_mesh_destroy(&m);
    // MSH 4.1: groups through $Entities.
    ENSURE(hs_mesh_parse("g4.msh", "msh", k_msh41, strlen(k_msh41), &m, &e) >= 0);
    ENSURE(m->n_regions == 2);
    h = hs_mesh_find_region(m, "base");
    ENSURE(h && h->dim == 2 && h->n_nodes == 3);
    v = hs_mesh_find_region(m, "body");
    ENSURE(v && v->dim == 3 && v->n_nodes == 4);
    hs_mesh_destroy(&m);
    // Bad names: an error naming the line.
    const char* bad = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$PhysicalNames\n1\n2 5 hilum\n"
                      "$EndPhysicalNames\n";
    ENSURE(hs_mesh_parse("b.msh", "msh", bad, strlen(bad), &m, &e) == HS_ERR_PARSE);
    ENSURE(strstr(e.msg, "b.msh:6:") && strstr(e.msg, "double quotes"));
    ENSURE(hs_byte_count() == before);
    return 0;
}

static int SceneFixedKinds(void) {
    int64_t before = hs_byte_count();
    ENSURE(write_file(tmp_path("g.msh"), k_msh22, strlen(k_msh22)));
    char json[1024];
    snprintf(json, sizeof json,
             "{ \"mesh\": \"g.msh\", \"fixed\": [ {\"type\": \"group\", \"name\": \"hilum\"}, "
             "{\"type\": \"sphere\", \"center\": [1, 1, 1], \"radius\": 0.1}, "
             "{\"type\": \"patch\", \"point\": [0, 0, 1.01], \"radius\": 0.05} ] }");
    ENSURE(write_file(tmp_path("g.json"), json, strlen(json)));
    hs_scene sc;
    hs_err e = {0};
    ENSURE(hs_scene_load(tmp_path("g.json"), &sc, &e) == HS_OK);
    ENSURE(sc.n_fixed == 3 && sc.fixed[0].kind == HS_FIXED_GROUP &&
           strcmp(sc.fixed[0].group, "hilum") == 0 && sc.fixed[1].kind == HS_FIXED_SPHERE &&
           sc.fixed[1].radius == 0.1 && sc.fixed[2].kind == HS_FIXED_PATCH);
    hs_mesh* m = NULL;
    ENSURE(hs_mesh_load(sc.mesh_path, &m, &e) >= 0);
    unsigned char sel[5];
    ENSURE(hs_scene_fixed_select(&sc.fixed[0], m, sel, &e) == HS_OK);
    ENSURE(sel[0] && sel[1] && sel[2] && !sel[3] && !sel[4]);
    ENSURE(hs_scene_fixed_select(&sc.fixed[1], m, sel, &e) == HS_OK);
    ENSURE(!sel[0] && !sel[1] && !sel[2] && !sel[3] && sel[4]);
    ENSURE(hs_scene_fixed_select(&sc.fixed[2], m, sel, &e) == HS_OK);
    ENSURE(!sel[0] && !sel[1] && !sel[2] && sel[3] && !sel[4]);
    // A group the mesh does not have: the error lists those it has.
    hs_scene_fixed f = sc.fixed[0];
    snprintf(f.group, sizeof f.group, "hilus");
    ENSURE(hs_scene_fixed_select(&f, m, sel, &e) == HS_ERR_INVALID);
    ENSURE(strstr(e.msg, "no group 'hilus'") && strstr(e.msg, "'hilum' (dim 2)"));
    hs_mesh_destroy(&m);
    // A node list beside the scene: 0-based indices, comments, commas.
    const char* list = "# the apex\n2, 4 # and one more\n";
    ENSURE(write_file(tmp_path("fixed.txt"), list, strlen(list)));
    const char* nl = "{ \"mesh\": \"g.msh\", \"fixed\": [ {\"type\": \"nodes\", \"file\": "
                     "\"fixed.txt\"} ] }";
    ENSURE(write_file(tmp_path("n.json"), nl, strlen(nl)));
    ENSURE(hs_scene_load(tmp_path("n.json"), &sc, &e) == HS_OK &&
           sc.fixed[0].kind == HS_FIXED_NODES);
    ENSURE(strcmp(sc.fixed[0].file, tmp_path("fixed.txt")) == 0);
    ENSURE(hs_mesh_load(sc.mesh_path, &m, &e) >= 0);
    ENSURE(hs_scene_fixed_select(&sc.fixed[0], m, sel, &e) == HS_OK);
    ENSURE(!sel[0] && !sel[1] && sel[2] && !sel[3] && sel[4]);
    ENSURE(write_file(tmp_path("fixed.txt"), "1\n5\n", 4));
    ENSURE(hs_scene_fixed_select(&sc.fixed[0], m, sel, &e) == HS_ERR_INVALID);
    ENSURE(strstr(e.msg, "fixed.txt:2: node 5 out of range"));
    hs_mesh_destroy(&m);
    // mesh_quality: the refusal threshold (default 0.5 degrees).
    ENSURE(sc.min_dihedral_deg == 0.5);
    const char* mq = "{ \"mesh\": \"g.msh\", \"fixed\": [ {\"type\": \"group\", \"name\": "
                     "\"hilum\"} ], \"mesh_quality\": {\"min_dihedral_deg\": 0} }";
    ENSURE(hs_scene_parse(mq, tmp_path("q.json"), 0, &sc, &e) == HS_OK && sc.min_dihedral_deg == 0);
    // Missing keys are errors naming the key.
    const char* nokey = "{ \"mesh\": \"g.msh\", \"fixed\": [ {\"type\": \"sphere\", "
                        "\"center\": [0,0,0]} ] }";
    ENSURE(hs_scene_parse(nokey, tmp_path("n.json"), 0, &sc, &e) < 0);
    ENSURE(strstr(e.msg, "fixed[0].radius"));
    const char* noname = "{ \"mesh\": \"g.msh\", \"fixed\": [ {\"type\": \"group\"} ] }";
    ENSURE(hs_scene_parse(noname, tmp_path("n.json"), 0, &sc, &e) < 0);
    ENSURE(strstr(e.msg, "fixed[0].name"));
    ENSURE(hs_byte_count() == before);
    return 0;
}

// A .vtu with tets reads as a volume mesh: the same tets as the .msh it came from.
static int VtuVolume(void) {
    int64_t before = hs_byte_count();
    hs_mesh *m = NULL, *m2 = NULL;
    hs_err e = {0};
    ENSURE(hs_mesh_load(HS_SOURCE_DIR "/scenes/liver/liver2.msh", &m, &e) >= 0);
    ENSURE(write_vtu(tmp_path("liver.vtu"), m->n_nodes, m->x0, m->n_tets, m->tets, 4, 10));
    hs_status st = hs_mesh_load(tmp_path("liver.vtu"), &m2, &e);
    if (st < 0) printf("  %s\n", e.msg);
    ENSURE(st == HS_OK && m2->n_tets == m->n_tets && m2->n_nodes == m->n_nodes);
    ENSURE_NEAR(m2->volume, m->volume, 1e-12 * m->volume);
    hs_mesh_destroy(&m2);
    // A surface-only .vtu (hapsim-view's) is not a volume: the message says what to do.
    ENSURE(write_vtu(tmp_path("surf.vtu"), m->n_nodes, m->x0, m->n_tris, m->tris, 3, 5));
    ENSURE(hs_mesh_load(tmp_path("surf.vtu"), &m2, &e) == HS_ERR_PARSE);
    ENSURE(strstr(e.msg, "surf.vtu") && strstr(e.msg, "hapsim-mesh tet"));
    // Binary data: refused, saying so.
    const char* bin = "<VTKFile type=\"UnstructuredGrid\"><UnstructuredGrid><Piece "
                      "NumberOfPoints=\"1\" NumberOfCells=\"0\"><Points><DataArray "
                      "format=\"binary\">AAAA</DataArray></Points></Piece></UnstructuredGrid>"
                      "</VTKFile>";
    ENSURE(hs_mesh_parse("b.vtu", "vtu", bin, strlen(bin), &m2, &e) == HS_ERR_UNSUPPORTED);
    ENSURE(strstr(e.msg, "b.vtu:1:") && strstr(e.msg, "ascii"));
    hs_mesh_destroy(&m);
    ENSURE(hs_byte_count() == before);
    return 0;
}

// A tetrahedron's four triangles, remeshed: gmsh 4.8 alone never returns from classifying them
// (hs_mesher_tet splits tiny surfaces first).
static int TinySurface(void) {
    int64_t before = hs_byte_count();
    hs_surface* s = hs_calloc(1, sizeof *s);
    static const double x[12] = {0, 0, 0, 0.1, 0, 0, 0, 0.1, 0, 0, 0, 0.1};
    static const int t[12] = {0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3};
    s->n_verts = 4;
    s->n_tris = 4;
    s->x = hs_alloc(sizeof x);
    s->tris = hs_alloc(sizeof t);
    memcpy(s->x, x, sizeof x);
    memcpy(s->tris, t, sizeof t);
    hs_mesher_def md = hs_mesher_default_def();
    md.size = 0.02;
    hs_mesh* m = NULL;
    hs_err e = {0};
    hs_status st = hs_mesher_tet(s, &md, &m, &e);
    if (st < 0) printf("  %s\n", e.msg);
    ENSURE(st >= 0 && m && m->n_tets > 50);
    ENSURE(fabs(m->volume - 0.1 * 0.1 * 0.1 / 6) < 1e-9);
    hs_mesh_destroy(&m);
    hs_surface_destroy(&s);
    ENSURE(hs_byte_count() == before);
    return 0;
}

static int Quality(void) {
    hs_mesh* m = NULL;
    hs_err e = {0};
    ENSURE(hs_mesh_create_box(1, 1, 1, 2, 2, 2, &m, &e) == HS_OK);
    hs_mesh_quality q;
    hs_mesh_quality_compute(m, &q);
    // Kuhn tets of a cube: dihedral angles 45, 60 and 90 degrees; area 6; volume 1.
    ENSURE(fabs(q.min_dihedral_deg - 45) < 1e-9 && fabs(q.max_dihedral_deg - 90) < 1e-9);
    ENSURE(fabs(q.area - 6) < 1e-12 && fabs(q.volume - 1) < 1e-12 && q.pieces == 1);
    ENSURE(q.below_5deg == 0 && q.n_tets == 48);
    int total = 0;
    for (int i = 0; i < HS_QUALITY_BINS; ++i) total += q.ratio_hist[i];
    ENSURE(total == 48 && q.min_radius_ratio > 0.5 && q.min_radius_ratio < 1);
    ENSURE(fabs(q.surf_edge_min - 0.5) < 1e-12 && fabs(q.surf_edge_max - sqrt(0.5)) < 1e-12);
    // Repairs are reported in words.
    char buf[256];
    m->report.reoriented_tets = 2;
    hs_mesh_report_str(&m->report, buf, sizeof buf);
    ENSURE(strstr(buf, "2 tets reoriented"));
    hs_mesh_destroy(&m);
    return 0;
}

static int setup(void) {
    snprintf(g_dir, sizeof g_dir, "/tmp/hs_mesher.XXXXXX");
    return mkdtemp(g_dir) != NULL;
}

int main(int argc, char** argv) {
    if (!setup()) return 1;
    static const hs_test_case cases[] = {HS_CASE(EveryFormatSphere),
                                         HS_CASE(EveryFormatLiver),
                                         HS_CASE(BrokenSurfaces),
                                         HS_CASE(VtkPolyData),
                                         HS_CASE(SelfIntersection),
                                         HS_CASE(FoldAtSharedVertex),
                                         HS_CASE(Repair),
                                         HS_CASE(PhysicalGroups),
                                         HS_CASE(SceneFixedKinds),
                                         HS_CASE(VtuVolume),
                                         HS_CASE(TinySurface),
                                         HS_CASE(Quality)};
    int rc = hs_test_main(argc, argv, cases, (int)(sizeof cases / sizeof cases[0]));
    if (rc == 0) {
        char cmd[128];
        snprintf(cmd, sizeof cmd, "rm -rf %s", g_dir);
        if (system(cmd) != 0) return 1;
    }
    return rc;
}
