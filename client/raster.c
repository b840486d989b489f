// SPDX-License-Identifier: MIT
// Software rasteriser for hapsim-view: orthographic camera, edge functions, z-buffer, flat
// two-sided Lambert shading with a per-pixel interpolated colour map. PNG through libpng's
// simplified API.
#include <math.h>
#include <png.h>
#include <stdio.h>
#include <string.h>

#include "view.h"
#include "wire.h"

static void cross(const double a[3], const double b[3], double o[3]) {
    o[0] = a[1] * b[2] - a[2] * b[1];
    o[1] = a[2] * b[0] - a[0] * b[2];
    o[2] = a[0] * b[1] - a[1] * b[0];
}
static double dot(const double a[3], const double b[3]) {
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
static void normalize(double a[3]) {
    double n = sqrt(dot(a, a));
    if (n > 0)
        for (int i = 0; i < 3; i++) a[i] /= n;
}

void hs_camera_fit(hs_camera* cam, const float* pts, int32_t n, double az_deg, double el_deg,
                   int width, int height) {
    memset(cam, 0, sizeof *cam);
    double lo[3] = {0, 0, 0}, hi[3] = {0, 0, 0};
    for (int32_t i = 0; i < n; i++)
        for (int k = 0; k < 3; k++) {
            double v = pts[3 * i + k];
            if (i == 0 || v < lo[k]) lo[k] = v;
            if (i == 0 || v > hi[k]) hi[k] = v;
        }
    double r2 = 0;
    for (int k = 0; k < 3; k++) cam->center[k] = 0.5 * (lo[k] + hi[k]);
    for (int32_t i = 0; i < n; i++) {
        double d2 = 0;
        for (int k = 0; k < 3; k++)
            d2 += (pts[3 * i + k] - cam->center[k]) * (pts[3 * i + k] - cam->center[k]);
        if (d2 > r2) r2 = d2;
    }
    double r = sqrt(r2) > 0 ? sqrt(r2) : 1.0;
    int side = width < height ? width : height;
    cam->scale = 0.45 * side / r;
    double az = az_deg * 3.14159265358979323846 / 180, el = el_deg * 3.14159265358979323846 / 180;
    cam->eye[0] = cos(el) * cos(az);
    cam->eye[1] = cos(el) * sin(az);
    cam->eye[2] = sin(el);
    double fwd[3] = {-cam->eye[0], -cam->eye[1], -cam->eye[2]};
    double wup[3] = {0, 0, 1};
    if (fabs(cam->eye[2]) > 0.999) { // looking straight along z: take +y as up
        wup[1] = 1;
        wup[2] = 0;
    }
    cross(fwd, wup, cam->right);
    normalize(cam->right);
    cross(cam->right, fwd, cam->up);
    normalize(cam->up);
    cam->az_deg = az_deg;
    cam->el_deg = el_deg;
    cam->width = width;
    cam->height = height;
}

void hs_camera_project(const hs_camera* cam, const double p[3], double* px, double* py,
                       double* depth) {
    double v[3] = {p[0] - cam->center[0], p[1] - cam->center[1], p[2] - cam->center[2]};
    *px = 0.5 * cam->width + dot(v, cam->right) * cam->scale;
    *py = 0.5 * cam->height - dot(v, cam->up) * cam->scale;
    *depth = -dot(v, cam->eye);
}

hs_status hs_image_create(int width, int height, hs_image** out, hs_err* err) {
    *out = NULL;
    if (width < 1 || height < 1 || width > 8192 || height > 8192) {
        if (err) {
            err->code = HS_ERR_INVALID;
            snprintf(err->msg, sizeof err->msg, "image size %dx%d not in 1..8192", width, height);
        }
        return HS_ERR_INVALID;
    }
    hs_image* im = hs_proto_calloc(1, sizeof *im);
    if (im) {
        im->rgb = hs_proto_alloc((size_t)width * height * 3);
        im->depth = hs_proto_alloc((size_t)width * height * sizeof(float));
    }
    if (!im || !im->rgb || !im->depth) {
        hs_image_destroy(&im);
        if (err) {
            err->code = HS_ERR_NOMEM;
            snprintf(err->msg, sizeof err->msg, "image %dx%d: out of memory", width, height);
        }
        return HS_ERR_NOMEM;
    }
    im->width = width;
    im->height = height;
    hs_image_clear(im);
    *out = im;
    return HS_OK;
}

void hs_image_destroy(hs_image** img) {
    if (!img || !*img) return;
    hs_proto_free((*img)->rgb);
    hs_proto_free((*img)->depth);
    hs_proto_free(*img);
    *img = NULL;
}

void hs_image_clear(hs_image* img) {
    size_t n = (size_t)img->width * img->height;
    for (size_t i = 0; i < n; i++) {
        img->rgb[3 * i] = HS_VIEW_BG_R;
        img->rgb[3 * i + 1] = HS_VIEW_BG_G;
        img->rgb[3 * i + 2] = HS_VIEW_BG_B;
        img->depth[i] = INFINITY;
    }
}

void hs_colormap(double t, uint8_t rgb[3]) {
    // Piecewise linear through blue, light grey, red (a diverging "cool to warm" map).
    static const double c[3][3] = {{59, 76, 192}, {221, 221, 221}, {180, 4, 38}};
    if (!(t > 0)) t = 0;
    if (t > 1) t = 1;
    int seg = t < 0.5 ? 0 : 1;
    double u = t < 0.5 ? t / 0.5 : (t - 0.5) / 0.5;
    for (int k = 0; k < 3; k++) {
        double v = c[seg][k] + u * (c[seg + 1][k] - c[seg][k]);
        rgb[k] = (uint8_t)lrint(v);
    }
}

int32_t hs_render_mesh(hs_image* img, const hs_camera* cam, const float* pos, int32_t n,
                       const int32_t* tri, int32_t n_tri, const float* scalar, float smin,
                       float smax) {
    int32_t drawn = 0;
    double range = smax > smin ? (double)smax - smin : 1.0;
    for (int32_t t = 0; t < n_tri; t++) {
        const int32_t* v = tri + 3 * t;
        if (v[0] < 0 || v[1] < 0 || v[2] < 0 || v[0] >= n || v[1] >= n || v[2] >= n) continue;
        double P[3][3], x[3], y[3], z[3], s[3];
        for (int i = 0; i < 3; i++) {
            for (int k = 0; k < 3; k++) P[i][k] = pos[3 * v[i] + k];
            hs_camera_project(cam, P[i], &x[i], &y[i], &z[i]);
            s[i] = scalar ? ((double)scalar[v[i]] - smin) / range : -1;
        }
        double e1[3], e2[3], nrm[3];
        for (int k = 0; k < 3; k++) {
            e1[k] = P[1][k] - P[0][k];
            e2[k] = P[2][k] - P[0][k];
        }
        cross(e1, e2, nrm);
        normalize(nrm);
        double shade = 0.25 + 0.75 * fabs(dot(nrm, cam->eye));
        // Signed area in pixel space; skip degenerate projections.
        double area = (x[1] - x[0]) * (y[2] - y[0]) - (x[2] - x[0]) * (y[1] - y[0]);
        if (fabs(area) < 1e-12) continue;
        // Positions are only checked finite: a vertex far off the picture (an exploded or corrupt
        // mesh) would overflow the int bounds below and make the depth interpolation garbage.
        if (!(fabs(x[0]) <= HS_RASTER_MAX_PX && fabs(x[1]) <= HS_RASTER_MAX_PX &&
              fabs(x[2]) <= HS_RASTER_MAX_PX && fabs(y[0]) <= HS_RASTER_MAX_PX &&
              fabs(y[1]) <= HS_RASTER_MAX_PX && fabs(y[2]) <= HS_RASTER_MAX_PX))
            continue;
        int x0 = (int)floor(fmin(x[0], fmin(x[1], x[2]))),
            x1 = (int)ceil(fmax(x[0], fmax(x[1], x[2])));
        int y0 = (int)floor(fmin(y[0], fmin(y[1], y[2]))),
            y1 = (int)ceil(fmax(y[0], fmax(y[1], y[2])));
        if (x0 < 0) x0 = 0;
        if (y0 < 0) y0 = 0;
        if (x1 > img->width - 1) x1 = img->width - 1;
        if (y1 > img->height - 1) y1 = img->height - 1;
        int hit = 0;
        for (int py = y0; py <= y1; py++)
            for (int px = x0; px <= x1; px++) {
                double cx = px + 0.5, cy = py + 0.5;
                double w0 = ((x[1] - cx) * (y[2] - cy) - (x[2] - cx) * (y[1] - cy)) / area;
                double w1 = ((x[2] - cx) * (y[0] - cy) - (x[0] - cx) * (y[2] - cy)) / area;
                double w2 = 1 - w0 - w1;
                if (w0 < 0 || w1 < 0 || w2 < 0) continue;
                double d = w0 * z[0] + w1 * z[1] + w2 * z[2];
                size_t idx = (size_t)py * img->width + px;
                if (!(d < img->depth[idx])) continue;
                img->depth[idx] = (float)d;
                uint8_t c[3] = {200, 200, 200};
                if (scalar) hs_colormap(w0 * s[0] + w1 * s[1] + w2 * s[2], c);
                for (int k = 0; k < 3; k++) img->rgb[3 * idx + k] = (uint8_t)lrint(c[k] * shade);
                hit = 1;
            }
        drawn += hit;
    }
    return drawn;
}

hs_status hs_png_write(const char* path, const hs_image* img, hs_err* err) {
    png_image pi;
    memset(&pi, 0, sizeof pi);
    pi.version = PNG_IMAGE_VERSION;
    pi.width = (png_uint_32)img->width;
    pi.height = (png_uint_32)img->height;
    pi.format = PNG_FORMAT_RGB;
    if (!png_image_write_to_file(&pi, path, 0, img->rgb, img->width * 3, NULL)) {
        if (err) {
            err->code = HS_ERR_IO;
            snprintf(err->msg, sizeof err->msg, "%s: cannot write PNG: %s", path, pi.message);
        }
        png_image_free(&pi);
        return HS_ERR_IO;
    }
    return HS_OK;
}

hs_status hs_png_read(const char* path, hs_image** out, hs_err* err) {
    *out = NULL;
    png_image pi;
    memset(&pi, 0, sizeof pi);
    pi.version = PNG_IMAGE_VERSION;
    if (!png_image_begin_read_from_file(&pi, path)) {
        if (err) {
            err->code = HS_ERR_IO;
            snprintf(err->msg, sizeof err->msg, "%s: cannot read PNG: %s", path, pi.message);
        }
        return HS_ERR_IO;
    }
    pi.format = PNG_FORMAT_RGB;
    hs_status s = hs_image_create((int)pi.width, (int)pi.height, out, err);
    if (s != HS_OK) {
        png_image_free(&pi);
        return s;
    }
    if (!png_image_finish_read(&pi, NULL, (*out)->rgb, (int)pi.width * 3, NULL)) {
        if (err) {
            err->code = HS_ERR_IO;
            snprintf(err->msg, sizeof err->msg, "%s: cannot decode PNG: %s", path, pi.message);
        }
        hs_image_destroy(out);
        return HS_ERR_IO;
    }
    return HS_OK;
}
