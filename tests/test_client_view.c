// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-view core: the rasteriser (background vs object, z-buffer, shading follows the normal,
// colour follows displacement), PNG round trip, VTU/PVD writing. With HS_CLIENT_VTK_DIR set,
// the VTK case writes its files there and keeps them (tests/test_client_vtk.sh validates them
// with an independent reader).
#include <stdint.h>
#include <stdlib.h>
#include <unistd.h>

#define PI 3.14159265358979323846

#include "test_macros.h"
#include "view.h"

// Unit cube [0,1]^3: 8 corners, 12 triangles counter-clockwise from outside.
static const float cube_pos[24] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0,
                                   0, 0, 1, 1, 0, 1, 1, 1, 1, 0, 1, 1};
static const int32_t cube_tri[36] = {0, 2, 1, 0, 3, 2, 4, 5, 6, 4, 6, 7, 0, 1, 5, 0, 5, 4,
                                     2, 3, 7, 2, 7, 6, 1, 2, 6, 1, 6, 5, 0, 4, 7, 0, 7, 3};

static const uint8_t* px(const hs_image* im, double x, double y) {
    int ix = (int)x, iy = (int)y;
    return im->rgb + 3 * ((size_t)iy * im->width + ix);
}
static int is_bg(const uint8_t* c) {
    return c[0] == HS_VIEW_BG_R && c[1] == HS_VIEW_BG_G && c[2] == HS_VIEW_BG_B;
}
static void proj(const hs_camera* cam, double x, double y, double z, double* u, double* v) {
    double p[3] = {x, y, z}, d;
    hs_camera_project(cam, p, u, v, &d);
}

static int test_raster_box(void) {
    int64_t bytes0 = hs_client_byte_count();
    hs_image* im = NULL;
    ENSURE(hs_image_create(200, 160, &im, NULL) == HS_OK);
    hs_camera cam;
    hs_camera_fit(&cam, cube_pos, 8, 30, 20, 200, 160);
    ENSURE(hs_render_mesh(im, &cam, cube_pos, 8, cube_tri, 12, NULL, 0, 1) >= 6);
    // Corners are background, the centre is the cube.
    ENSURE(is_bg(px(im, 0, 0)) && is_bg(px(im, 199, 0)) && is_bg(px(im, 0, 159)) &&
           is_bg(px(im, 199, 159)));
    ENSURE(!is_bg(px(im, 100, 80)));
    int obj = 0;
    for (int i = 0; i < 200 * 160; i++) obj += !is_bg(im->rgb + 3 * i);
    ENSURE(obj > 2000 && obj < 200 * 160 / 2);
    // Lambert: the three visible faces get 0.25 + 0.75 n.eye: +x (0.81) > +y (0.47) > +z (0.34).
    double u, v;
    proj(&cam, 1, 0.5, 0.5, &u, &v);
    int bx = px(im, u, v)[0];
    proj(&cam, 0.5, 1, 0.5, &u, &v);
    int by = px(im, u, v)[0];
    proj(&cam, 0.5, 0.5, 1, &u, &v);
    int bz = px(im, u, v)[0];
    ENSURE(bx > by + 20 && by > bz + 5);
    ENSURE_NEAR(bx, 200 * (0.25 + 0.75 * cos(20 * PI / 180) * cos(30 * PI / 180)), 1.5);
    // Colour map follows the scalar: corner 6 (1,1,1) at the top of the range, the rest 0.
    float s[8] = {0, 0, 0, 0, 0, 0, 1, 0};
    hs_image_clear(im);
    hs_render_mesh(im, &cam, cube_pos, 8, cube_tri, 12, s, 0, 1);
    proj(&cam, 0.9, 0.9, 1, &u, &v); // near corner 6 on the top face
    const uint8_t* hot = px(im, u, v);
    proj(&cam, 0.1, 0.1, 1, &u, &v); // far corner of the same face
    const uint8_t* cold = px(im, u, v);
    ENSURE(hot[0] - hot[2] > 20 && cold[2] - cold[0] > 20);
    uint8_t c0[3], c1[3];
    hs_colormap(0, c0);
    hs_colormap(1, c1);
    ENSURE(c0[2] > c0[0] && c1[0] > c1[2]);
    // Z-buffer: a triangle behind the cube is hidden, one in front is drawn.
    float tri_pos[9];
    int32_t t3[3] = {0, 1, 2};
    double back = 3; // along -eye from the centre
    for (int i = 0; i < 3; i++) {
        double a = 2 * PI * i / 3;
        for (int k = 0; k < 3; k++)
            tri_pos[3 * i + k] = (float)(cam.center[k] - back * cam.eye[k] +
                                         0.3 * (cos(a) * cam.right[k] + sin(a) * cam.up[k]));
    }
    uint8_t before[3];
    memcpy(before, px(im, 100, 80), 3);
    hs_render_mesh(im, &cam, tri_pos, 3, t3, 1, NULL, 0, 1);
    ENSURE(memcmp(before, px(im, 100, 80), 3) == 0);
    for (int i = 0; i < 9; i++) tri_pos[i] = (float)(tri_pos[i] + 2 * back * cam.eye[i % 3]);
    hs_render_mesh(im, &cam, tri_pos, 3, t3, 1, NULL, 0, 1);
    ENSURE(memcmp(before, px(im, 100, 80), 3) != 0);
    // Bad indices are skipped, not read.
    int32_t bad[3] = {0, 1, 99};
    ENSURE(hs_render_mesh(im, &cam, cube_pos, 8, bad, 1, NULL, 0, 1) == 0);
    hs_image_destroy(&im);
    ENSURE(im == NULL && hs_client_byte_count() == bytes0);
    return 0;
}

// A vertex far off the picture (positions are only checked finite): its triangle is skipped,
// the image and depth buffer stay as they were (before: undefined float-to-int conversion, and
// for a vertex off the top left a sliver drawn with garbage depth).
static int test_raster_far_vertex(void) {
    int64_t bytes0 = hs_client_byte_count();
    hs_image* im = NULL;
    ENSURE(hs_image_create(200, 160, &im, NULL) == HS_OK);
    hs_camera cam;
    hs_camera_fit(&cam, cube_pos, 8, 30, 20, 200, 160);
    ENSURE(hs_render_mesh(im, &cam, cube_pos, 8, cube_tri, 12, NULL, 0, 1) >= 6);
    uint8_t* rgb0 = malloc(200 * 160 * 3);
    float* depth0 = malloc(200 * 160 * sizeof(float));
    ENSURE(rgb0 && depth0);
    memcpy(rgb0, im->rgb, 200 * 160 * 3);
    memcpy(depth0, im->depth, 200 * 160 * sizeof(float));
    static const double far[] = {3e30, 1e10, 1e38};
    for (int sr = -1; sr <= 1; sr += 2)
        for (int su = -1; su <= 1; su += 2)
            for (int f = 0; f < 3; f++) {
                // Two vertices in front of the cube's centre, across the direction d = +-right
                // +-up, and one far along d.
                float p[9];
                int32_t t3[3] = {0, 1, 2};
                for (int k = 0; k < 3; k++) {
                    double c = cam.center[k] + 2 * cam.eye[k];
                    double d = sr * cam.right[k] + su * cam.up[k];
                    double e = su * cam.right[k] - sr * cam.up[k];
                    p[k] = (float)(c + 0.2 * e);
                    p[3 + k] = (float)(c - 0.2 * e);
                    p[6 + k] = (float)(c + far[f] * d);
                }
                float sc[3] = {0, 0, 1e30f};
                ENSURE(hs_render_mesh(im, &cam, p, 3, t3, 1, sc, 0, 1) == 0);
                ENSURE(memcmp(rgb0, im->rgb, 200 * 160 * 3) == 0);
                ENSURE(memcmp(depth0, im->depth, 200 * 160 * sizeof(float)) == 0);
            }
    // A large but sane triangle (a vertex 100 cube sizes away) is still drawn.
    float p[9];
    int32_t t3[3] = {0, 1, 2};
    for (int k = 0; k < 3; k++) {
        double c = cam.center[k] + 2 * cam.eye[k];
        p[k] = (float)(c + 0.2 * (cam.right[k] - cam.up[k]));
        p[3 + k] = (float)(c - 0.2 * (cam.right[k] - cam.up[k]));
        p[6 + k] = (float)(c - 100 * (cam.right[k] + cam.up[k]));
    }
    ENSURE(hs_render_mesh(im, &cam, p, 3, t3, 1, NULL, 0, 1) == 1);
    ENSURE(memcmp(rgb0, im->rgb, 200 * 160 * 3) != 0);
    free(rgb0);
    free(depth0);
    hs_image_destroy(&im);
    ENSURE(hs_client_byte_count() == bytes0);
    return 0;
}

static int test_png_round_trip(void) {
    int64_t bytes0 = hs_client_byte_count();
    hs_image *im = NULL, *back = NULL;
    ENSURE(hs_image_create(64, 48, &im, NULL) == HS_OK);
    hs_camera cam;
    hs_camera_fit(&cam, cube_pos, 8, 120, -35, 64, 48);
    float s[8] = {0, 0.2f, 0.4f, 0.6f, 0.8f, 1, 0.5f, 0.3f};
    hs_render_mesh(im, &cam, cube_pos, 8, cube_tri, 12, s, 0, 1);
    char path[256];
    snprintf(path, sizeof path, "/tmp/hs_client_view_%d.png", (int)getpid());
    hs_err err = {0};
    ENSURE(hs_png_write(path, im, &err) == HS_OK);
    ENSURE(hs_png_read(path, &back, &err) == HS_OK);
    ENSURE(back->width == 64 && back->height == 48);
    ENSURE(memcmp(back->rgb, im->rgb, 64 * 48 * 3) == 0);
    remove(path);
    hs_image_destroy(&back);
    ENSURE(hs_png_read("/nonexistent/x.png", &back, &err) == HS_ERR_IO && back == NULL);
    ENSURE(strstr(err.msg, "/nonexistent/x.png") != NULL);
    ENSURE(hs_png_write("/nonexistent/x.png", im, &err) == HS_ERR_IO);
    ENSURE(hs_image_create(0, 10, &back, &err) == HS_ERR_INVALID);
    hs_image_destroy(&im);
    ENSURE(hs_client_byte_count() == bytes0);
    return 0;
}

static int test_vtk_series(void) {
    const char* keep = getenv("HS_CLIENT_VTK_DIR");
    char dir[256];
    if (keep)
        snprintf(dir, sizeof dir, "%s", keep);
    else
        snprintf(dir, sizeof dir, "/tmp");
    float pos[24];
    float stress[8];
    for (int i = 0; i < 8; i++) stress[i] = 1000.0f * (float)i;
    hs_client_mesh m;
    memset(&m, 0, sizeof m);
    int32_t vis[8] = {0, 1, 2, 3, 4, 5, 6, 7};
    m.ready = 1;
    m.n_nodes = 8;
    m.n_vis = 8;
    m.n_tri = 12;
    m.vis_nodes = vis;
    m.rest = cube_pos;
    m.position = pos;
    m.triangles = cube_tri;
    const char* files[3];
    char names[3][64];
    double times[3];
    hs_err err = {0};
    for (int f = 0; f < 3; f++) {
        memcpy(pos, cube_pos, sizeof pos);
        pos[3 * 6 + 2] += 0.1f * (float)f; // corner 6 rises
        pos[3 * 5 + 0] += 0.05f * (float)f;
        m.stress = f == 2 ? stress : NULL;
        m.sim_time = 0.5 * f;
        float disp[8];
        hs_view_displacement(&m, disp);
        ENSURE_NEAR(disp[6], 0.1 * f, 1e-6);
        ENSURE(disp[0] == 0);
        snprintf(names[f], sizeof names[f], "frame_%06d.vtu", f);
        char path[512];
        snprintf(path, sizeof path, "%s/%s%s", dir, keep ? "" : "hs_client_", names[f]);
        hs_view_tools vt = {.n = 2};
        vt.tool[0].device = 0;
        vt.tool[0].force[1] = 0.5;
        vt.tool[1].device = 3;
        vt.tool[1].position[0] = 0.25;
        ENSURE(hs_vtu_write(path, &m, disp, f == 1 ? &vt : NULL, &err) == HS_OK);
        files[f] = names[f];
        times[f] = m.sim_time;
        // The file parses back as we meant it (our own quick check; the shell test uses meshio).
        FILE* fp = fopen(path, "r");
        ENSURE(fp != NULL);
        char line[512];
        int saw_piece = 0, saw_stress = 0, saw_rest = 0, saw_force = 0, saw_time = 0;
        while (fgets(line, sizeof line, fp)) {
            saw_piece += strstr(line, "NumberOfPoints=\"8\" NumberOfCells=\"12\"") != NULL;
            saw_stress += strstr(line, "stress_von_mises") != NULL;
            saw_rest += strstr(line, "Name=\"rest_position\"") != NULL;
            saw_force += strstr(line, "Name=\"tool_force_n\"") != NULL;
            saw_time += strstr(line, "Name=\"TimeValue\"") != NULL;
        }
        fclose(fp);
        ENSURE(saw_piece == 1 && saw_stress == (f == 2));
        ENSURE(saw_rest == 1 && saw_force == 1 && saw_time == 1);
        if (!keep) remove(path);
    }
    char pvd[512];
    snprintf(pvd, sizeof pvd, "%s/%s", dir, keep ? "hapsim.pvd" : "hs_client_test.pvd");
    ENSURE(hs_pvd_write(pvd, 3, files, times, &err) == HS_OK);
    if (!keep) remove(pvd);
    ENSURE(hs_vtu_write("/nonexistent/dir/x.vtu", &m, stress, NULL, &err) == HS_ERR_IO);
    ENSURE(strstr(err.msg, "/nonexistent/dir/x.vtu") != NULL);
    ENSURE(hs_pvd_write("/nonexistent/dir/x.pvd", 3, files, times, &err) == HS_ERR_IO);
    ENSURE(strstr(err.msg, "/nonexistent/dir/x.pvd") != NULL);
    // Finite positions whose displacement overflows float32 (3e38 - -3e38): refused, nothing
    // written (before: "inf" in the file and HS_OK).
    float rest2[24];
    memcpy(rest2, cube_pos, sizeof rest2);
    memcpy(pos, cube_pos, sizeof pos);
    m.rest = rest2;
    m.stress = NULL;
    char path[512];
    snprintf(path, sizeof path, "%s/hs_client_overflow_%d.vtu", dir, (int)getpid());
    for (int k = 0; k < 2; k++) {
        memcpy(pos, cube_pos, sizeof pos);
        memcpy(rest2, cube_pos, sizeof rest2);
        pos[3 * 3 + 1] = 3e38f;
        rest2[3 * 3 + 1] = -3e38f;
        if (k == 1) { // components fit, the magnitude does not
            pos[3 * 3 + 1] = 3e38f, rest2[3 * 3 + 1] = 0;
            pos[3 * 3 + 2] = 3e38f, rest2[3 * 3 + 2] = 0;
        }
        float disp[8];
        hs_view_displacement(&m, disp);
        err.msg[0] = 0;
        ENSURE(hs_vtu_write(path, &m, disp, NULL, &err) == HS_ERR_INVALID);
        ENSURE(strstr(err.msg, path) != NULL && strstr(err.msg, "node 3") != NULL);
        ENSURE(access(path, F_OK) != 0);
        char tmp[600];
        snprintf(tmp, sizeof tmp, "%s.tmp", path);
        ENSURE(access(tmp, F_OK) != 0);
    }
    // The largest displacement that fits is written.
    memcpy(rest2, cube_pos, sizeof rest2);
    memcpy(pos, cube_pos, sizeof pos);
    pos[3 * 3 + 1] = 3e38f;
    float disp[8];
    hs_view_displacement(&m, disp);
    ENSURE(hs_vtu_write(path, &m, disp, NULL, &err) == HS_OK);
    ENSURE(remove(path) == 0);
    return 0;
}

// Annotations: caption text, colour bar (red top, blue bottom), scale bar, axes, a probe drawn
// as a depth-tested sphere with a cyan force arrow pointing along the force.
static int test_annotate(void) {
    hs_image* im = NULL;
    ENSURE(hs_image_create(640, 480, &im, NULL) == HS_OK);
    hs_camera cam;
    hs_camera_fit(&cam, cube_pos, 8, 30, 20, 640, 480);
    hs_render_mesh(im, &cam, cube_pos, 8, cube_tri, 12, NULL, 0, 1);
    hs_view_tools tools = {.n = 1};
    hs_view_tool* t = &tools.tool[0];
    t->device = 0;
    t->kind = 0;
    t->radius = 0.05;
    double top[3] = {0.5, 0.5, 1.08}; // resting on the top face, pushed up by 2 N
    memcpy(t->position, top, sizeof top);
    t->force[2] = 2.0;
    hs_view_caption cap = {.sim_time = 1.5,
                           .sim_step = 90,
                           .topology_version = 3,
                           .range_m = 0.01,
                           .max_disp_m = 0.004};
    snprintf(cap.scene, sizeof cap.scene, "liver");
    hs_view_annotate(im, &cam, &tools, &cap);
    // Caption: lit text pixels in the first two text rows at the top left, none were there.
    int text = 0;
    for (int y = 6; y < 40; y++)
        for (int x = 6; x < 300; x++) text += px(im, x, y)[0] > 200;
    ENSURE(text > 300);
    // Colour bar: W - 40 s - 8 (s = 2), from y = 6 + 34 s, 45 % of the height.
    int bx = 640 - 80 - 8 + 3, by = 6 + 68;
    const uint8_t* ctop = px(im, bx, by + 2);
    const uint8_t* cbot = px(im, bx, by + 480 * 45 / 100 - 3);
    ENSURE(ctop[0] > ctop[2] + 60 && cbot[2] > cbot[0] + 60);
    // Probe: its centre pixel is orange (shaded), in front of the cube.
    double u, v, d;
    hs_camera_project(&cam, top, &u, &v, &d);
    const uint8_t* pc = px(im, u, v);
    ENSURE(pc[0] > 150 && pc[0] > pc[2] + 80);
    // Force arrow: cyan pixels above the probe (screen up = +z here), none below it.
    int above = 0, below = 0;
    for (int y = 0; y < 480; y++)
        for (int x = (int)u - 4; x <= (int)u + 4; x++) {
            const uint8_t* c = px(im, x, y);
            int cyan = c[0] == 68 && c[1] == 224 && c[2] == 255;
            above += cyan && y < v - 0.05 * cam.scale;
            below += cyan && y > v + 0.05 * cam.scale;
        }
    ENSURE(above > 10 && below == 0);
    // Scale bar: a white run at the bottom left.
    int run = 0;
    for (int x = 10; x < 320; x++) run += px(im, x, 480 - 10 - 16)[0] > 200;
    ENSURE(run > 20);
    // 1-2-5 steps; the font draws unknown bytes as a box and clips at the edges.
    ENSURE(hs_nice_ceil(0.0063) == 0.01 && fabs(hs_nice_ceil(0.0021) - 0.005) < 1e-12 &&
           hs_nice_ceil(0) == 1 && fabs(hs_nice_ceil(1.5) - 2) < 1e-12);
    static const uint8_t w[3] = {255, 255, 255};
    ENSURE(hs_draw_text(im, 630, 475, 3, w, "\x01\xff~ mm") == 6 * 3 * 6);
    hs_draw_line(im, -1e9, 0, 1e9, 0, 3, w); // off the picture: nothing, no crash
    hs_image_destroy(&im);
    return 0;
}

HS_TEST_MAIN(HS_CASE(test_raster_box), HS_CASE(test_annotate), HS_CASE(test_raster_far_vertex),
             HS_CASE(test_png_round_trip), HS_CASE(test_vtk_series))
