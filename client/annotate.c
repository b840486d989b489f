// SPDX-License-Identifier: MIT
// hapsim-view's picture annotations (view.h): a 5x7 bitmap font, lines, the tools with their
// force arrows, the colour bar in mm, a scale bar, the axes and a caption, so that a PNG says
// what it shows.
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "view.h"

// 5x7 glyphs, one byte per row (bit 4 = leftmost column), printable ASCII from 32.
static const uint8_t k_font[96][7] = {
    ['0' - 32] = {0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E},
    ['1' - 32] = {0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E},
    ['2' - 32] = {0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F},
    ['3' - 32] = {0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E},
    ['4' - 32] = {0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02},
    ['5' - 32] = {0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E},
    ['6' - 32] = {0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E},
    ['7' - 32] = {0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08},
    ['8' - 32] = {0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E},
    ['9' - 32] = {0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C},
    ['A' - 32] = {0x0E, 0x11, 0x11, 0x11, 0x1F, 0x11, 0x11},
    ['B' - 32] = {0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E},
    ['C' - 32] = {0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E},
    ['D' - 32] = {0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C},
    ['E' - 32] = {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F},
    ['F' - 32] = {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10},
    ['G' - 32] = {0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F},
    ['H' - 32] = {0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11},
    ['I' - 32] = {0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E},
    ['J' - 32] = {0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C},
    ['K' - 32] = {0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11},
    ['L' - 32] = {0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F},
    ['M' - 32] = {0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11},
    ['N' - 32] = {0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11},
    ['O' - 32] = {0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E},
    ['P' - 32] = {0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10},
    ['Q' - 32] = {0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D},
    ['R' - 32] = {0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11},
    ['S' - 32] = {0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E},
    ['T' - 32] = {0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04},
    ['U' - 32] = {0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E},
    ['V' - 32] = {0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04},
    ['W' - 32] = {0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A},
    ['X' - 32] = {0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11},
    ['Y' - 32] = {0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04},
    ['Z' - 32] = {0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F},
    ['a' - 32] = {0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F},
    ['b' - 32] = {0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E},
    ['c' - 32] = {0x00, 0x00, 0x0E, 0x10, 0x10, 0x11, 0x0E},
    ['d' - 32] = {0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F},
    ['e' - 32] = {0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E},
    ['f' - 32] = {0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08},
    ['g' - 32] = {0x00, 0x0F, 0x11, 0x11, 0x0F, 0x01, 0x0E},
    ['h' - 32] = {0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11},
    ['i' - 32] = {0x04, 0x00, 0x0C, 0x04, 0x04, 0x04, 0x0E},
    ['j' - 32] = {0x02, 0x00, 0x06, 0x02, 0x02, 0x12, 0x0C},
    ['k' - 32] = {0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12},
    ['l' - 32] = {0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E},
    ['m' - 32] = {0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11},
    ['n' - 32] = {0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11},
    ['o' - 32] = {0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E},
    ['p' - 32] = {0x00, 0x00, 0x1E, 0x11, 0x1E, 0x10, 0x10},
    ['q' - 32] = {0x00, 0x00, 0x0D, 0x13, 0x0F, 0x01, 0x01},
    ['r' - 32] = {0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10},
    ['s' - 32] = {0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E},
    ['t' - 32] = {0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06},
    ['u' - 32] = {0x00, 0x00, 0x11, 0x11, 0x11, 0x13, 0x0D},
    ['v' - 32] = {0x00, 0x00, 0x11, 0x11, 0x11, 0x0A, 0x04},
    ['w' - 32] = {0x00, 0x00, 0x11, 0x11, 0x15, 0x15, 0x0A},
    ['x' - 32] = {0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11},
    ['y' - 32] = {0x00, 0x00, 0x11, 0x11, 0x0F, 0x01, 0x0E},
    ['z' - 32] = {0x00, 0x00, 0x1F, 0x02, 0x04, 0x08, 0x1F},
    ['.' - 32] = {0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C},
    [',' - 32] = {0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08},
    [':' - 32] = {0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00},
    ['=' - 32] = {0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00},
    ['-' - 32] = {0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00},
    ['+' - 32] = {0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00},
    ['/' - 32] = {0x00, 0x01, 0x02, 0x04, 0x08, 0x10, 0x00},
    ['(' - 32] = {0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02},
    [')' - 32] = {0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08},
    ['%' - 32] = {0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03},
    ['|' - 32] = {0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04},
    ['_' - 32] = {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F},
    ['[' - 32] = {0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E},
    [']' - 32] = {0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E},
    ['\'' - 32] = {0x0C, 0x04, 0x08, 0x00, 0x00, 0x00, 0x00},
    ['<' - 32] = {0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02},
    ['>' - 32] = {0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08},
    ['#' - 32] = {0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A},
};
static const uint8_t k_unknown[7] = {0x1F, 0x11, 0x11, 0x11, 0x11, 0x11, 0x1F};

static void put_px(hs_image* img, int x, int y, const uint8_t c[3]) {
    if (x < 0 || y < 0 || x >= img->width || y >= img->height) return;
    uint8_t* p = img->rgb + 3 * ((size_t)y * img->width + x);
    p[0] = c[0];
    p[1] = c[1];
    p[2] = c[2];
}

static void fill_rect(hs_image* img, int x0, int y0, int w, int h, const uint8_t c[3]) {
    for (int y = y0; y < y0 + h; y++)
        for (int x = x0; x < x0 + w; x++) put_px(img, x, y, c);
}

static void glyph(hs_image* img, int x, int y, int s, const uint8_t c[3], char ch) {
    unsigned char u = (unsigned char)ch;
    if (u == ' ') return;
    const uint8_t* g = u >= 32 && u < 128 ? k_font[u - 32] : k_unknown;
    int empty = 1;
    for (int r = 0; r < 7; r++) empty &= g[r] == 0;
    if (empty) g = k_unknown;
    for (int r = 0; r < 7; r++)
        for (int col = 0; col < 5; col++)
            if (g[r] & (0x10 >> col)) fill_rect(img, x + col * s, y + r * s, s, s, c);
}

int hs_draw_text(hs_image* img, int x, int y, int scale, const uint8_t rgb[3], const char* text) {
    static const uint8_t shadow[3] = {0, 0, 0};
    if (scale < 1) scale = 1;
    int cx = x;
    for (const char* p = text; *p; p++, cx += 6 * scale) {
        glyph(img, cx + 1, y + 1, scale, shadow, *p); // a dark shadow keeps it readable anywhere
        glyph(img, cx, y, scale, rgb, *p);
    }
    return cx - x;
}

void hs_draw_line(hs_image* img, double x0, double y0, double x1, double y1, int width,
                  const uint8_t rgb[3]) {
    if (!(fabs(x0) < 1e6 && fabs(y0) < 1e6 && fabs(x1) < 1e6 && fabs(y1) < 1e6)) return;
    double dx = x1 - x0, dy = y1 - y0;
    int n = (int)ceil(fmax(fabs(dx), fabs(dy))) + 1;
    int h = width / 2;
    for (int i = 0; i <= n; i++) {
        double t = (double)i / n;
        int x = (int)lrint(x0 + t * dx), y = (int)lrint(y0 + t * dy);
        fill_rect(img, x - h, y - h, width, width, rgb);
    }
}

double hs_nice_ceil(double x) {
    if (!(x > 0) || !isfinite(x)) return 1;
    double e = pow(10, floor(log10(x)));
    double m = x / e;
    return (m <= 1.0000001 ? 1 : m <= 2 ? 2 : m <= 5 ? 5 : 10) * e;
}

// An arrow from (x0, y0) to (x1, y1) with a head of size hs pixels.
static void arrow(hs_image* img, double x0, double y0, double x1, double y1, int w, double hs,
                  const uint8_t c[3]) {
    hs_draw_line(img, x0, y0, x1, y1, w, c);
    double dx = x1 - x0, dy = y1 - y0, l = sqrt(dx * dx + dy * dy);
    if (l < 1e-9) return;
    dx /= l;
    dy /= l;
    for (int sgn = -1; sgn <= 1; sgn += 2)
        hs_draw_line(img, x1, y1, x1 - hs * (dx * 0.87 - sgn * dy * 0.5),
                     y1 - hs * (dy * 0.87 + sgn * dx * 0.5), w, c);
}

// A shaded sphere of radius r (m) at p, depth-tested against the surface.
static void sphere(hs_image* img, const hs_camera* cam, const double p[3], double r,
                   const uint8_t base[3]) {
    double cx, cy, cz;
    hs_camera_project(cam, p, &cx, &cy, &cz);
    double rp = r * cam->scale;
    if (!(rp > 0) || !(fabs(cx) < 1e6 && fabs(cy) < 1e6)) return;
    if (rp < 2) rp = 2;
    for (int y = (int)floor(cy - rp); y <= (int)ceil(cy + rp); y++)
        for (int x = (int)floor(cx - rp); x <= (int)ceil(cx + rp); x++) {
            if (x < 0 || y < 0 || x >= img->width || y >= img->height) continue;
            double dx = (x + 0.5 - cx) / rp, dy = (y + 0.5 - cy) / rp, d2 = dx * dx + dy * dy;
            if (d2 > 1) continue;
            double nz = sqrt(1 - d2);
            double z = cz - nz * r; // the sphere's front at this pixel
            size_t idx = (size_t)y * img->width + x;
            if (!(z < img->depth[idx])) continue;
            img->depth[idx] = (float)z;
            double shade = 0.35 + 0.65 * nz;
            uint8_t c[3];
            for (int k = 0; k < 3; k++) c[k] = (uint8_t)lrint(base[k] * shade);
            put_px(img, x, y, c);
        }
}

void hs_view_annotate(hs_image* img, const hs_camera* cam, const hs_view_tools* tools,
                      const hs_view_caption* cap) {
    static const uint8_t white[3] = {235, 238, 242}, grey[3] = {170, 178, 188},
                         cyan[3] = {68, 224, 255}, probe[3] = {232, 170, 80},
                         probe_on[3] = {255, 140, 50}, blade[3] = {240, 240, 240},
                         blade_on[3] = {255, 80, 80};
    const int W = img->width, H = img->height;
    const int s = H >= 700 ? 3 : H >= 360 ? 2 : 1; // text scale
    char buf[256];
    // Tools and force arrows (5 cm per N, from the tool's surface, at most 30 % of the picture).
    double fshow = -1;
    int fdev = -1;
    if (tools)
        for (int i = 0; i < tools->n; i++) {
            const hs_view_tool* t = &tools->tool[i];
            double cx, cy, cz;
            if (t->kind == 0) {
                sphere(img, cam, t->position, t->radius, t->contact ? probe_on : probe);
            } else {
                double ax, ay, bx, by, z;
                hs_camera_project(cam, t->blade_a, &ax, &ay, &z);
                hs_camera_project(cam, t->blade_b, &bx, &by, &z);
                hs_draw_line(img, ax, ay, bx, by, s + 1, t->cutting ? blade_on : blade);
            }
            double fn = sqrt(t->force[0] * t->force[0] + t->force[1] * t->force[1] +
                             t->force[2] * t->force[2]);
            if (fn > fshow) {
                fshow = fn;
                fdev = t->device;
            }
            if (!(fn > 1e-6) || !isfinite(fn)) continue;
            double dir[3] = {t->force[0] / fn, t->force[1] / fn, t->force[2] / fn};
            double r0 = t->kind == 0 ? t->radius : 0;
            double a[3], b[3], len = fmin(fn * 0.05, 0.3 * (W < H ? W : H) / cam->scale);
            for (int k = 0; k < 3; k++) {
                a[k] = t->position[k] + dir[k] * r0;
                b[k] = a[k] + dir[k] * len;
            }
            double ax, ay, bx, by;
            hs_camera_project(cam, a, &ax, &ay, &cz);
            hs_camera_project(cam, b, &bx, &by, &cz);
            arrow(img, ax, ay, bx, by, s + 1, 4.0 * s + 4, cyan);
            hs_camera_project(cam, t->position, &cx, &cy, &cz);
            snprintf(buf, sizeof buf, "%.3f N", fn);
            // Above the tool, kept clear of the colour bar and the image edges.
            double tw = 6.0 * s * (double)strlen(buf), xmax = W - 48.0 * s - 12 - tw;
            double ty = cy - r0 * cam->scale - 12.0 * s;
            if (ty < 26.0 * s) ty = cy + r0 * cam->scale + 6.0 * s;
            hs_draw_text(img, (int)lrint(fmax(fmin(cx - tw / 2, xmax), 0)),
                         (int)lrint(fmin(fmax(ty, 0), H - 10.0 * s)), s, cyan, buf);
        }
    // Caption: scene, time, step, topology; second line: largest displacement and force.
    snprintf(buf, sizeof buf, "%s  t = %.3f s  step %lld  topology v%lld",
             cap && cap->scene[0] ? cap->scene : "hapsim", cap ? cap->sim_time : 0.0,
             cap ? (long long)cap->sim_step : 0LL, cap ? (long long)cap->topology_version : 0LL);
    hs_draw_text(img, 6, 6, s, white, buf);
    if (fdev >= 0)
        snprintf(buf, sizeof buf, "max |u| %.2f mm   force %.3f N (device %d)",
                 cap ? cap->max_disp_m * 1e3 : 0.0, fshow, fdev);
    else
        snprintf(buf, sizeof buf, "max |u| %.2f mm   no tool", cap ? cap->max_disp_m * 1e3 : 0.0);
    hs_draw_text(img, 6, 6 + 10 * s, s, grey, buf);
    // Colour bar (right): 0 .. range in mm.
    double range = cap && cap->range_m > 0 ? cap->range_m : 1e-3;
    int bw = 6 * s, bh = H * 45 / 100, bx = W - 40 * s - 8, by = 6 + 34 * s;
    for (int y = 0; y < bh; y++) {
        uint8_t c[3];
        hs_colormap(1.0 - (double)y / (bh - 1 > 0 ? bh - 1 : 1), c);
        fill_rect(img, bx, by + y, bw, 1, c);
    }
    hs_draw_text(img, bx - 6 * s, by - 10 * s, s, white, "|u| mm");
    for (int i = 0; i <= 4; i++) {
        int y = by + bh - 1 - (bh - 1) * i / 4;
        fill_rect(img, bx + bw, y, s + 1, s > 1 ? 2 : 1, white);
        double v = range * 1e3 * i / 4;
        snprintf(buf, sizeof buf, v >= 10 ? "%.0f" : "%.2g", v);
        hs_draw_text(img, bx + bw + 4 * s, y - 3 * s, s, white, buf);
    }
    // Scale bar (bottom left): a 1-2-5 length near a fifth of the width (orthographic: exact).
    double want = 0.2 * W / cam->scale; // the largest 1-2-5 length up to a fifth of the width
    double e = pow(10, floor(log10(want))), mant = want / e;
    double len = (mant < 2 ? 1 : mant < 5 ? 2 : 5) * e;
    int lp = (int)lrint(len * cam->scale), sx = 10, sy = H - 10 - 8 * s;
    if (lp > 0 && lp < W) {
        fill_rect(img, sx, sy, lp, s + 1, white);
        fill_rect(img, sx, sy - 3 * s, s + 1, 7 * s, white);
        fill_rect(img, sx + lp - s - 1, sy - 3 * s, s + 1, 7 * s, white);
        if (len >= 0.01)
            snprintf(buf, sizeof buf, "%g cm", len * 100);
        else
            snprintf(buf, sizeof buf, "%g mm", len * 1000);
        hs_draw_text(img, sx + lp + 4 * s, sy - 3 * s, s, white, buf);
    }
    // Axes (bottom right): the scene axes as the camera sees them.
    static const uint8_t axc[3][3] = {{255, 90, 90}, {90, 223, 90}, {90, 160, 255}};
    static const char* axn[3] = {"x", "y", "z"};
    double ox = W - 30.0 * s, oy = H - 30.0 * s, L = 18.0 * s;
    for (int k = 0; k < 3; k++) {
        double vx = cam->right[k], vy = -cam->up[k];
        hs_draw_line(img, ox, oy, ox + vx * L, oy + vy * L, s, axc[k]);
        hs_draw_text(img, (int)lrint(ox + vx * (L + 5 * s) - 2 * s),
                     (int)lrint(oy + vy * (L + 5 * s) - 3 * s), s, axc[k], axn[k]);
    }
}
