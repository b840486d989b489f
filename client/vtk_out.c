// SPDX-License-Identifier: MIT
// VTK XML output for ParaView: one .vtu per frame (surface triangles, ASCII) and a .pvd
// collection. Files are written to "<path>.tmp" and renamed, so a reader never sees half a file.
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <float.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "view.h"

static hs_status io_fail(hs_err* err, const char* path, const char* what) {
    if (err) {
        err->code = HS_ERR_IO;
        snprintf(err->msg, sizeof err->msg, "%s: %s: %s", path, what, strerror(errno));
    }
    return HS_ERR_IO;
}

static hs_status finish(FILE* f, const char* tmp, const char* path, hs_err* err) {
    int bad = ferror(f);
    if (fclose(f) != 0 || bad) {
        remove(tmp);
        return io_fail(err, path, "write failed");
    }
    if (rename(tmp, path) != 0) {
        remove(tmp);
        return io_fail(err, path, "rename failed");
    }
    return HS_OK;
}

/// Opens "<path>.tmp" (its name into tmp) for writing.
static hs_status open_tmp(const char* path, char* tmp, size_t cap, FILE** out, hs_err* err) {
    if (snprintf(tmp, cap, "%s.tmp", path) >= (int)cap) {
        errno = ENAMETOOLONG;
        return io_fail(err, path, "path too long");
    }
    *out = fopen(tmp, "w");
    return *out ? HS_OK : io_fail(err, tmp, "cannot create");
}

void hs_view_displacement(const hs_client_mesh* m, float* disp) {
    for (int32_t i = 0; i < m->n_vis; i++) {
        double s = 0;
        for (int k = 0; k < 3; k++) {
            double d = (double)m->position[3 * i + k] - m->rest[3 * i + k];
            s += d * d;
        }
        disp[i] = (float)sqrt(s);
    }
}

// Floats with 9 significant digits: exactly the float32 the server sent.
static void floats(FILE* f, const float* v, int64_t n, int per_line) {
    for (int64_t i = 0; i < n; i++)
        fprintf(f, "%.9g%c", (double)v[i], (i + 1) % per_line == 0 || i + 1 == n ? '\n' : ' ');
}

hs_status hs_vtu_write(const char* path, const hs_client_mesh* m, const float* disp,
                       const hs_view_tools* tools, hs_err* err) {
    // Positions are finite floats, but position - rest can overflow float32 (3e38 - -3e38):
    // refuse rather than write "inf", which VTK readers reject or misread.
    for (int32_t i = 0; i < m->n_vis; i++) {
        int bad = !(fabsf(disp[i]) <= FLT_MAX);
        for (int k = 0; k < 3; k++)
            bad |= !(fabs((double)m->position[3 * i + k] - m->rest[3 * i + k]) <= FLT_MAX);
        if (bad) {
            if (err) {
                err->code = HS_ERR_INVALID;
                snprintf(err->msg, sizeof err->msg,
                         "%s: not written: node %d displacement overflows float32 (position "
                         "%.9g %.9g %.9g, rest %.9g %.9g %.9g)",
                         path, i, (double)m->position[3 * i], (double)m->position[3 * i + 1],
                         (double)m->position[3 * i + 2], (double)m->rest[3 * i],
                         (double)m->rest[3 * i + 1], (double)m->rest[3 * i + 2]);
            }
            return HS_ERR_INVALID;
        }
    }
    char tmp[4200];
    FILE* f = NULL;
    hs_status st = open_tmp(path, tmp, sizeof tmp, &f, err);
    if (st != HS_OK) return st;
    fprintf(f,
            "<?xml version=\"1.0\"?>\n"
            "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" "
            "header_type=\"UInt64\">\n<UnstructuredGrid>\n"
            "<FieldData>\n"
            "<DataArray type=\"Float64\" Name=\"TimeValue\" NumberOfTuples=\"1\" "
            "format=\"ascii\">%.17g</DataArray>\n"
            "<DataArray type=\"Int64\" Name=\"sim_step\" NumberOfTuples=\"1\" "
            "format=\"ascii\">%lld</DataArray>\n",
            m->sim_time, (long long)m->sim_step);
    // The tools as rows (one row of zeros, device -1, when none is live: every frame of a series
    // then has the same arrays).
    int nt = tools && tools->n > 0 ? tools->n : 0;
    int rows = nt > 0 ? nt : 1;
    fprintf(f,
            "<DataArray type=\"Int32\" Name=\"tool_device\" NumberOfTuples=\"%d\" "
            "format=\"ascii\">",
            rows);
    for (int i = 0; i < rows; i++)
        fprintf(f, "%s%d", i ? " " : "", nt ? tools->tool[i].device : -1);
    const char* names[2] = {"tool_position_m", "tool_force_n"};
    for (int a = 0; a < 2; a++) {
        fprintf(f,
                "</DataArray>\n<DataArray type=\"Float64\" Name=\"%s\" NumberOfComponents=\"3\" "
                "NumberOfTuples=\"%d\" format=\"ascii\">",
                names[a], rows);
        for (int i = 0; i < rows; i++)
            for (int k = 0; k < 3; k++) {
                double v = nt ? (a ? tools->tool[i].force[k] : tools->tool[i].position[k]) : 0.0;
                fprintf(f, "%s%.9g", i || k ? " " : "", isfinite(v) ? v : 0.0);
            }
    }
    fprintf(f,
            "</DataArray>\n</FieldData>\n"
            "<Piece NumberOfPoints=\"%d\" NumberOfCells=\"%d\">\n",
            m->n_vis, m->n_tri);
    fprintf(f, "<PointData Scalars=\"displacement_magnitude\" Vectors=\"displacement\">\n");
    fprintf(f, "<DataArray type=\"Float32\" Name=\"displacement_magnitude\" format=\"ascii\">\n");
    floats(f, disp, m->n_vis, 8);
    fprintf(f, "</DataArray>\n<DataArray type=\"Float32\" Name=\"displacement\" "
               "NumberOfComponents=\"3\" format=\"ascii\">\n");
    for (int32_t i = 0; i < m->n_vis; i++)
        for (int k = 0; k < 3; k++)
            fprintf(f, "%.9g%c", (double)(m->position[3 * i + k] - m->rest[3 * i + k]),
                    k == 2 ? '\n' : ' ');
    fprintf(f, "</DataArray>\n<DataArray type=\"Float32\" Name=\"rest_position\" "
               "NumberOfComponents=\"3\" format=\"ascii\">\n");
    floats(f, m->rest, 3 * (int64_t)m->n_vis, 3);
    fprintf(f, "</DataArray>\n");
    if (m->stress) {
        fprintf(f, "<DataArray type=\"Float32\" Name=\"stress_von_mises\" format=\"ascii\">\n");
        floats(f, m->stress, m->n_vis, 8);
        fprintf(f, "</DataArray>\n");
    }
    fprintf(f, "</PointData>\n<Points>\n<DataArray type=\"Float32\" Name=\"Points\" "
               "NumberOfComponents=\"3\" format=\"ascii\">\n");
    floats(f, m->position, 3 * (int64_t)m->n_vis, 3);
    fprintf(f, "</DataArray>\n</Points>\n<Cells>\n"
               "<DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">\n");
    for (int32_t t = 0; t < m->n_tri; t++)
        fprintf(f, "%d %d %d\n", m->triangles[3 * t], m->triangles[3 * t + 1],
                m->triangles[3 * t + 2]);
    fprintf(f, "</DataArray>\n<DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">\n");
    for (int32_t t = 0; t < m->n_tri; t++)
        fprintf(f, "%d%c", 3 * (t + 1), (t + 1) % 16 == 0 || t + 1 == m->n_tri ? '\n' : ' ');
    fprintf(f, "</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n");
    for (int32_t t = 0; t < m->n_tri; t++) // 5 = VTK_TRIANGLE
        fprintf(f, "5%c", (t + 1) % 32 == 0 || t + 1 == m->n_tri ? '\n' : ' ');
    fprintf(f, "</DataArray>\n</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n");
    return finish(f, tmp, path, err);
}

hs_status hs_pvd_write(const char* path, int32_t n, const char* const* files, const double* times,
                       hs_err* err) {
    char tmp[4200];
    FILE* f = NULL;
    hs_status st = open_tmp(path, tmp, sizeof tmp, &f, err);
    if (st != HS_OK) return st;
    fprintf(f, "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" "
               "byte_order=\"LittleEndian\">\n<Collection>\n");
    for (int32_t i = 0; i < n; i++)
        fprintf(f, "<DataSet timestep=\"%.9g\" group=\"\" part=\"0\" file=\"%s\"/>\n", times[i],
                files[i]);
    fprintf(f, "</Collection>\n</VTKFile>\n");
    return finish(f, tmp, path, err);
}
