// SPDX-License-Identifier: GPL-2.0-or-later
// Checks hapsim-view's PNGs of a probe pressing the liver (used by tests/test_client_e2e.sh):
// between the frame before the press and the frame with the largest displacement, pixels change
// near the probe and nowhere near the far side of the organ.
//   test_client_press DIR PX,PY,PZ FX,FY,FZ
// DIR holds camera.txt, frames.csv and the PNGs; P is the pressed point and F a point on the far
// side (m, scene frame). Exit 0 when the pictures show it, 1 otherwise.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "view.h"

static int read_camera(const char* dir, hs_camera* cam) {
    char path[1024], key[64];
    snprintf(path, sizeof path, "%s/camera.txt", dir);
    FILE* f = fopen(path, "r");
    if (!f) return -1;
    memset(cam, 0, sizeof *cam);
    char line[512];
    while (fgets(line, sizeof line, f)) {
        double a, b, c;
        if (line[0] == '#') continue;
        int n = sscanf(line, "%63s %lf %lf %lf", key, &a, &b, &c);
        if (n < 2) continue;
        if (!strcmp(key, "width"))
            cam->width = (int)a;
        else if (!strcmp(key, "height"))
            cam->height = (int)a;
        else if (!strcmp(key, "scale"))
            cam->scale = a;
        else if (n == 4 && !strcmp(key, "center"))
            cam->center[0] = a, cam->center[1] = b, cam->center[2] = c;
        else if (n == 4 && !strcmp(key, "right"))
            cam->right[0] = a, cam->right[1] = b, cam->right[2] = c;
        else if (n == 4 && !strcmp(key, "up"))
            cam->up[0] = a, cam->up[1] = b, cam->up[2] = c;
    }
    fclose(f);
    // eye = right x up
    cam->eye[0] = cam->right[1] * cam->up[2] - cam->right[2] * cam->up[1];
    cam->eye[1] = cam->right[2] * cam->up[0] - cam->right[0] * cam->up[2];
    cam->eye[2] = cam->right[0] * cam->up[1] - cam->right[1] * cam->up[0];
    return cam->width > 0 && cam->height > 0 && cam->scale > 0 ? 0 : -1;
}

static int parse3(const char* s, double p[3]) {
    return sscanf(s, "%lf,%lf,%lf", &p[0], &p[1], &p[2]) == 3 ? 0 : -1;
}

int main(int argc, char** argv) {
    if (argc != 4) {
        fprintf(stderr, "usage: test_client_press DIR PX,PY,PZ FX,FY,FZ\n");
        return 2;
    }
    const char* dir = argv[1];
    double P[3], F[3];
    hs_camera cam;
    if (parse3(argv[2], P) || parse3(argv[3], F) || read_camera(dir, &cam)) {
        fprintf(stderr, "test_client_press: bad points or %s/camera.txt\n", dir);
        return 2;
    }
    // frames.csv: index,png,vtu,sim_time_s,sim_step,topology_version,keyframe_id,max_disp_m
    char path[1024], line[1024];
    snprintf(path, sizeof path, "%s/frames.csv", dir);
    FILE* f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "test_client_press: cannot read %s\n", path);
        return 1;
    }
    char first[256] = "", best[256] = "";
    double dfirst = -1, dbest = -1;
    int rows = 0;
    if (!fgets(line, sizeof line, f)) line[0] = 0; // header
    while (fgets(line, sizeof line, f)) {
        char png[256];
        double d;
        char* c1 = strchr(line, ',');
        char* c2 = c1 ? strchr(c1 + 1, ',') : NULL;
        char* last = strrchr(line, ',');
        if (!c1 || !c2 || !last || c2 - c1 - 1 <= 0 || c2 - c1 - 1 >= 255) continue;
        memcpy(png, c1 + 1, (size_t)(c2 - c1 - 1));
        png[c2 - c1 - 1] = 0;
        d = atof(last + 1);
        rows++;
        if (!first[0]) {
            snprintf(first, sizeof first, "%s", png);
            dfirst = d;
        }
        if (d > dbest) {
            dbest = d;
            snprintf(best, sizeof best, "%s", png);
        }
    }
    fclose(f);
    printf("frames %d; first %s (max displacement %.2f mm), most pressed %s (%.2f mm)\n", rows,
           first, dfirst * 1e3, best, dbest * 1e3);
    if (rows < 3 || dbest < dfirst + 0.001) {
        printf("FAIL: no frame displaced by 1 mm more than the first\n");
        return 1;
    }
    hs_image *a = NULL, *b = NULL;
    hs_err err = {0};
    snprintf(path, sizeof path, "%s/%s", dir, first);
    if (hs_png_read(path, &a, &err) != HS_OK) {
        printf("FAIL: %s\n", err.msg);
        return 1;
    }
    snprintf(path, sizeof path, "%s/%s", dir, best);
    if (hs_png_read(path, &b, &err) != HS_OK || b->width != a->width || b->height != a->height) {
        printf("FAIL: %s\n", err.msg[0] ? err.msg : "sizes differ");
        return 1;
    }
    double pu, pv, fu, fv, d;
    hs_camera_project(&cam, P, &pu, &pv, &d);
    hs_camera_project(&cam, F, &fu, &fv, &d);
    double sep = hypot(fu - pu, fv - pv);
    // Changed: summed channel difference above 40 (of 765).
    int near_changed = 0, near_total = 0, far_changed = 0, far_total = 0;
    double r_near = 0.15 * sep, r_far = 0.25 * sep;
    for (int y = 0; y < a->height; y++)
        for (int x = 0; x < a->width; x++) {
            const uint8_t *ca = a->rgb + 3 * ((size_t)y * a->width + x),
                          *cb = b->rgb + 3 * ((size_t)y * a->width + x);
            int diff = abs(ca[0] - cb[0]) + abs(ca[1] - cb[1]) + abs(ca[2] - cb[2]);
            double dp = hypot(x + 0.5 - pu, y + 0.5 - pv), df = hypot(x + 0.5 - fu, y + 0.5 - fv);
            if (dp < r_near) {
                near_total++;
                near_changed += diff > 40;
            }
            if (df < r_far) {
                far_total++;
                far_changed += diff > 40;
            }
        }
    printf("probe at pixel (%.0f, %.0f): %d of %d pixels within %.0f px changed; far side at "
           "(%.0f, %.0f): %d of %d within %.0f px changed\n",
           pu, pv, near_changed, near_total, r_near, fu, fv, far_changed, far_total, r_far);
    int ok = near_total > 0 && far_total > 0 && near_changed >= 0.2 * near_total &&
             far_changed <= 0.01 * far_total;
    hs_image_destroy(&a);
    hs_image_destroy(&b);
    printf("%s\n", ok ? "OK: the picture changes where the probe presses, not on the far side"
                      : "FAIL: change not where expected");
    return ok ? 0 : 1;
}
