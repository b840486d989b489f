// SPDX-License-Identifier: MIT
// hapsim-view core (internal, not installed): an orthographic camera, a software rasteriser of
// surface triangles (z-buffer, Lambert shading, colour map), PNG in/out through libpng, and
// VTK XML (.vtu + .pvd) writers. docs/client.md describes the output.
#ifndef HS_CLIENT_VIEW_H
#define HS_CLIENT_VIEW_H

#include <stdint.h>

#include "hapsim/client.h"

/// Orthographic camera looking at center from direction (azimuth about +z from +x, elevation
/// from the xy plane toward +z).
typedef struct hs_camera {
    double center[3];       ///< m, point at the image centre
    double scale;           ///< pixels per metre
    double right[3], up[3]; ///< unit screen axes in the scene frame
    double eye[3];          ///< unit vector from center toward the viewer
    double az_deg, el_deg;  ///< degrees, as given
    int width, height;      ///< pixels
} hs_camera;

/// Fit the camera to n points pts[3n] (bounding sphere fills 90 % of the smaller image side).
void hs_camera_fit(hs_camera* cam, const float* pts, int32_t n, double az_deg, double el_deg,
                   int width, int height);
/// Pixel coordinates (x right, y down; pixel centres at +0.5) and depth (m, larger = farther).
void hs_camera_project(const hs_camera* cam, const double p[3], double* px, double* py,
                       double* depth);

/// An RGB8 image with its depth buffer.
typedef struct hs_image {
    int width, height; ///< pixels
    uint8_t* rgb;      ///< [3 width height] row-major, top row first
    float* depth;      ///< [width height] m, +inf where nothing was drawn
} hs_image;

/// Allocate (1 .. 8192 pixels per side). Thread: any | Allocates: yes
hs_status hs_image_create(int width, int height, hs_image** out, hs_err* err);
/// Free; accepts NULL and *img == NULL; sets *img = NULL.
void hs_image_destroy(hs_image** img);
/// Fill with the background colour and clear the depth buffer.
void hs_image_clear(hs_image* img);
/// Background colour of hs_image_clear.
#define HS_VIEW_BG_R 28
#define HS_VIEW_BG_G 30
#define HS_VIEW_BG_B 36

/// Colour map (cool to warm): t in [0, 1] (clamped) -> rgb. Blue for 0, red for 1.
void hs_colormap(double t, uint8_t rgb[3]);

/// Pixel coordinate beyond which (either sign, x or y) a vertex's triangle is skipped.
#define HS_RASTER_MAX_PX 1e6

/// Draw triangles tri[3 n_tri] over positions pos[3 n] (m) with a per-vertex scalar[n] mapped
/// by (s - smin) / (smax - smin) through hs_colormap, times a two-sided Lambert factor
/// 0.25 + 0.75 |n . eye| (headlight). NULL scalar: uniform grey. A triangle with a vertex whose
/// pixel x or y is beyond +-HS_RASTER_MAX_PX is skipped. Returns triangles drawn.
int32_t hs_render_mesh(hs_image* img, const hs_camera* cam, const float* pos, int32_t n,
                       const int32_t* tri, int32_t n_tri, const float* scalar, float smin,
                       float smax);

/// One tool to draw (from the server's tool_state).
typedef struct hs_view_tool {
    int32_t device, kind;          ///< device id; 0 probe, 1 blade (tool_state KIND_*)
    double position[3];            ///< m, probe centre / blade origin
    double radius;                 ///< m, probe radius
    double blade_a[3], blade_b[3]; ///< m, blade segment
    double force[3];               ///< N, force on the tool
    int contact, cutting;          ///< flags as sent
} hs_view_tool;

/// The live tools of one picture or VTK frame.
typedef struct hs_view_tools {
    int n;                                    ///< tools in use
    hs_view_tool tool[HS_CLIENT_MAX_DEVICES]; ///< [n]
} hs_view_tools;

/// What a picture's caption and colour bar say.
typedef struct hs_view_caption {
    char scene[64];           ///< scene name ("" when no status arrived)
    double sim_time;          ///< s
    int64_t sim_step;         ///< deformation step
    int64_t topology_version; ///< topology shown
    double range_m;           ///< colour range: red at this displacement (m)
    double max_disp_m;        ///< largest displacement in the frame (m)
} hs_view_caption;

/// Draw text in the 5x7 font (scale: pixels per font pixel, >= 1) with a dark shadow; unknown
/// characters as a box. Returns the width drawn (pixels). Clipped to the image.
int hs_draw_text(hs_image* img, int x, int y, int scale, const uint8_t rgb[3], const char* text);
/// Draw a line width pixels thick (clipped; ends beyond 1e6 pixels: nothing drawn).
void hs_draw_line(hs_image* img, double x0, double y0, double x1, double y1, int width,
                  const uint8_t rgb[3]);
/// Smallest 1-2-5 x 10^k >= x (1 for x <= 0 or non-finite).
double hs_nice_ceil(double x);
/// Annotate a rendered picture: tools (a probe as a depth-tested shaded sphere, a blade as its
/// segment) with force arrows (5 cm per N from the tool's surface, capped at 30 % of the picture)
/// and their |F| in N, a caption (scene, time, step, topology; largest displacement, force), the
/// colour bar 0 .. range in mm (top right), a scale bar (bottom left) and the axes (bottom
/// right). tools and cap may be NULL.
void hs_view_annotate(hs_image* img, const hs_camera* cam, const hs_view_tools* tools,
                      const hs_view_caption* cap);

/// Write an RGB PNG. Returns HS_OK or HS_ERR_IO (err names the file).
hs_status hs_png_write(const char* path, const hs_image* img, hs_err* err);
/// Read a PNG as RGB8 (depth buffer cleared). Returns HS_OK, HS_ERR_IO or HS_ERR_NOMEM.
hs_status hs_png_read(const char* path, hs_image** out, hs_err* err);

/// Per-node displacement magnitude |position - rest| (m) into disp[n].
void hs_view_displacement(const hs_client_mesh* m, float* disp);
/// Write the visible mesh as a VTK XML UnstructuredGrid of its surface triangles (ASCII .vtu):
/// point data displacement (3 comp), displacement_magnitude, rest_position (3 comp) and, when
/// sent, stress_von_mises; field data TimeValue (s), sim_step, and per live tool (tools may be
/// NULL: one row of zeros with device -1) tool_device, tool_position_m, tool_force_n.
/// Writes to path + ".tmp" then renames. Returns HS_OK, HS_ERR_IO, or HS_ERR_INVALID (nothing
/// written) when a displacement or disp[i] is beyond float32 (err names the node).
hs_status hs_vtu_write(const char* path, const hs_client_mesh* m, const float* disp,
                       const hs_view_tools* tools, hs_err* err);
/// Write a ParaView collection (.pvd) listing files[i] at times[i] (s); atomic (tmp + rename).
hs_status hs_pvd_write(const char* path, int32_t n, const char* const* files, const double* times,
                       hs_err* err);

#endif
