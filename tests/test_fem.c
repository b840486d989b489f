// SPDX-License-Identifier: GPL-2.0-or-later
#define _POSIX_C_SOURCE 200809L
// FEM element models: patch test, rigid rotation, tangents against finite differences, polar
// decomposition, locking-free bending, inversion recovery, mass, allocation discipline.
#include "fem.h"

#include "../server/fem/element.h"      // hs_polar_warm4, hs_polar_higham_ex
#include "../server/fem/fem_internal.h" // hs_fem_tangent_rotations

#include "test_macros.h"

#include <stdint.h>
#include <stdlib.h>
#include <time.h>

#define PI 3.14159265358979323846

// ---------------------------------------------------------------------------------------------
// Fixtures (test-side memory uses malloc so the library byte count stays meaningful)

typedef struct box {
    hs_mesh mesh;
    int nx, ny, nz;
} box;

static int box_node(const box* b, int i, int j, int k) {
    return i + (b->nx + 1) * (j + (b->ny + 1) * k);
}

static double tet_vol6(const double* x, const int* t) {
    double a[3], bb[3], c[3];
    for (int q = 0; q < 3; q++) {
        a[q] = x[3 * t[1] + q] - x[3 * t[0] + q];
        bb[q] = x[3 * t[2] + q] - x[3 * t[0] + q];
        c[q] = x[3 * t[3] + q] - x[3 * t[0] + q];
    }
    return a[0] * (bb[1] * c[2] - bb[2] * c[1]) - a[1] * (bb[0] * c[2] - bb[2] * c[0]) +
           a[2] * (bb[0] * c[1] - bb[1] * c[0]);
}

/// Box [0,lx]x[0,ly]x[0,lz], each cell split into 6 Kuhn tets (conforming), positively oriented.
static void box_make(box* b, double lx, double ly, double lz, int nx, int ny, int nz) {
    memset(b, 0, sizeof *b);
    b->nx = nx;
    b->ny = ny;
    b->nz = nz;
    int n = (nx + 1) * (ny + 1) * (nz + 1);
    b->mesh.n_nodes = n;
    b->mesh.n_tets = 6 * nx * ny * nz;
    b->mesh.x0 = malloc(sizeof(double) * 3 * (size_t)n);
    b->mesh.tets = malloc(sizeof(int) * 4 * (size_t)b->mesh.n_tets);
    for (int k = 0; k <= nz; k++)
        for (int j = 0; j <= ny; j++)
            for (int i = 0; i <= nx; i++) {
                int v = box_node(b, i, j, k);
                b->mesh.x0[3 * v] = lx * i / nx;
                b->mesh.x0[3 * v + 1] = ly * j / ny;
                b->mesh.x0[3 * v + 2] = lz * k / nz;
            }
    static const int perm[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2},
                                   {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
    int t = 0;
    for (int k = 0; k < nz; k++)
        for (int j = 0; j < ny; j++)
            for (int i = 0; i < nx; i++)
                for (int p = 0; p < 6; p++) {
                    int c[3] = {i, j, k};
                    int* tt = b->mesh.tets + 4 * t;
                    tt[0] = box_node(b, c[0], c[1], c[2]);
                    for (int s = 0; s < 3; s++) {
                        c[perm[p][s]]++;
                        tt[s + 1] = box_node(b, c[0], c[1], c[2]);
                    }
                    if (tet_vol6(b->mesh.x0, tt) < 0) {
                        int sw = tt[2];
                        tt[2] = tt[3];
                        tt[3] = sw;
                    }
                    t++;
                }
    b->mesh.volume = lx * ly * lz;
}

static void box_free(box* b) {
    free(b->mesh.x0);
    free(b->mesh.tets);
}

static int* dofs_all(int n) {
    int* d = malloc(sizeof(int) * 3 * (size_t)n);
    for (int i = 0; i < 3 * n; i++) d[i] = i;
    return d;
}

static double urand(uint64_t* s) {
    *s = *s * 6364136223846793005ull + 1442695040888963407ull;
    return (double)(*s >> 11) / 9007199254740992.0;
}

static double vnorm(const double* v, int n) {
    double s = 0;
    for (int i = 0; i < n; i++) s += v[i] * v[i];
    return sqrt(s);
}

static void rot_z(double ang, double r[9]) {
    double c = cos(ang), s = sin(ang);
    double m[9] = {c, -s, 0, s, c, 0, 0, 0, 1};
    memcpy(r, m, sizeof m);
}

/// Rotation about a unit axis by angle (Rodrigues).
static void rot_axis(const double ax[3], double ang, double r[9]) {
    double c = cos(ang), s = sin(ang), t = 1 - c;
    double x = ax[0], y = ax[1], z = ax[2];
    double m[9] = {t * x * x + c,     t * x * y - s * z, t * x * z + s * y,
                   t * x * y + s * z, t * y * y + c,     t * y * z - s * x,
                   t * x * z - s * y, t * y * z + s * x, t * z * z + c};
    memcpy(r, m, sizeof m);
}

static void mat3_mul(const double a[9], const double b[9], double c[9]) {
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            c[3 * i + j] = a[3 * i] * b[j] + a[3 * i + 1] * b[3 + j] + a[3 * i + 2] * b[6 + j];
}

static double det3(const double a[9]) {
    return a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6]) +
           a[2] * (a[3] * a[7] - a[4] * a[6]);
}

typedef struct cfg {
    const char* name;
    hs_model model;
    hs_rotation rot;
    int anp;
} cfg;

static const cfg k_cfgs[] = {
    {"linear", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 0},
    {"corot-polar", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 0},
    {"corot-svd", HS_MODEL_COROTATED, HS_ROTATION_SVD, 0},
    {"stvk", HS_MODEL_STVK, HS_ROTATION_POLAR, 0},
    {"linear-anp", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 1},
    {"corot-anp", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1},
    {"stvk-anp", HS_MODEL_STVK, HS_ROTATION_POLAR, 1},
    {"linear-sns", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 2},
    {"corot-sns", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 2},
    {"corot-svd-sns", HS_MODEL_COROTATED, HS_ROTATION_SVD, 2},
};
#define N_CFGS ((int)(sizeof k_cfgs / sizeof k_cfgs[0]))

static hs_fem_def make_def(const cfg* c, double E, double nu) {
    hs_fem_def d = hs_fem_default_def();
    d.model = c->model;
    d.rotation = c->rot;
    d.locking_free = c->anp;
    d.material.youngs_pa = E;
    d.material.poisson = nu;
    d.polar_tol = 1e-10;
    d.polar_max_iter = 30;
    return d;
}

static int is_interior(const box* b, int v) {
    int i = v % (b->nx + 1), j = (v / (b->nx + 1)) % (b->ny + 1),
        k = v / ((b->nx + 1) * (b->ny + 1));
    return i > 0 && i < b->nx && j > 0 && j < b->ny && k > 0 && k < b->nz;
}

// ---------------------------------------------------------------------------------------------

/// A homogeneous deformation x = A X + c gives zero force on every interior node.
static int test_patch(void) {
    int64_t bytes0 = hs_byte_count();
    box b;
    box_make(&b, 1.0, 0.8, 0.6, 3, 3, 3);
    int n = b.mesh.n_nodes;
    int* dof = dofs_all(n);
    double* x = malloc(sizeof(double) * 3 * n);
    double* f = malloc(sizeof(double) * 3 * n);
    // A moderate stretch+shear, and the same composed with a 60 degree rotation.
    double A0[9] = {1.08, 0.05, -0.03, 0.02, 0.95, 0.04, -0.01, 0.06, 1.03};
    double R[9], A1[9];
    double ax[3] = {0.48, 0.6, 0.64};
    rot_axis(ax, 1.047, R);
    mat3_mul(R, A0, A1);
    for (int c = 0; c < N_CFGS; c++) {
        for (int which = 0; which < 2; which++) {
            const double* A = which ? A1 : A0;
            hs_fem_def def = make_def(&k_cfgs[c], 1e4, 0.45);
            hs_fem* fem = NULL;
            hs_err err;
            hs_status cst = hs_fem_create(&b.mesh, &def, dof, 3 * n, &fem, &err);
            if (cst != HS_OK) printf("  %s\n", err.msg);
            ENSURE(cst == HS_OK);
            for (int v = 0; v < n; v++)
                for (int i = 0; i < 3; i++)
                    x[3 * v + i] = A[3 * i] * b.mesh.x0[3 * v] +
                                   A[3 * i + 1] * b.mesh.x0[3 * v + 1] +
                                   A[3 * i + 2] * b.mesh.x0[3 * v + 2] + 0.3 * i;
            hs_fem_update(fem, x, NULL);
            hs_fem_forces(fem, f);
            double fbnd = 0, fint = 0;
            for (int v = 0; v < n; v++) {
                double fv = vnorm(f + 3 * v, 3);
                if (is_interior(&b, v))
                    fint = fmax(fint, fv);
                else
                    fbnd = fmax(fbnd, fv);
            }
            if (!(fint <= 1e-10 * fbnd) || !(fbnd > 0))
                printf("  %s affine %d: interior %g boundary %g\n", k_cfgs[c].name, which, fint,
                       fbnd);
            ENSURE(fbnd > 0);
            ENSURE(fint <= 1e-10 * fbnd);
            hs_fem_destroy(&fem);
            ENSURE(fem == NULL);
        }
    }
    free(x);
    free(f);
    free(dof);
    box_free(&b);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

/// Rigid rotation by 90 degrees: no elastic force for co-rotated and StVK, large for linear.
static int test_rigid_rotation(void) {
    int64_t bytes0 = hs_byte_count();
    box b;
    box_make(&b, 0.1, 0.02, 0.02, 5, 2, 2);
    int n = b.mesh.n_nodes;
    int* dof = dofs_all(n);
    double* x = malloc(sizeof(double) * 3 * n);
    double* f = malloc(sizeof(double) * 3 * n);
    double R[9];
    rot_z(PI / 2, R);
    // Force scale: E * area of a face ~ what a 1 % strain would give.
    double E = 1e4, fscale = E * 0.01 * (0.02 * 0.02) / 9;
    for (int c = 0; c < N_CFGS; c++) {
        hs_fem_def def = make_def(&k_cfgs[c], E, 0.45);
        hs_fem* fem = NULL;
        ENSURE(hs_fem_create(&b.mesh, &def, dof, 3 * n, &fem, NULL) == HS_OK);
        for (int v = 0; v < n; v++) {
            for (int i = 0; i < 3; i++)
                x[3 * v + i] = R[3 * i] * b.mesh.x0[3 * v] + R[3 * i + 1] * b.mesh.x0[3 * v + 1] +
                               R[3 * i + 2] * b.mesh.x0[3 * v + 2] + 0.01;
        }
        hs_fem_stats st;
        hs_fem_update(fem, x, &st);
        hs_fem_forces(fem, f);
        double fm = 0;
        for (int v = 0; v < n; v++) fm = fmax(fm, vnorm(f + 3 * v, 3));
        if (k_cfgs[c].model == HS_MODEL_LINEAR) {
            ENSURE(fm > 10 * fscale);
            ENSURE(st.energy_j > 0);
        } else {
            ENSURE_SMALL(fm / fscale, 1e-6);
            ENSURE_SMALL(st.energy_j, 1e-12);
            // The nodal rotation recovers the rigid rotation.
            double rn[9];
            hs_fem_node_rotation(fem, n / 2, rn);
            for (int k = 0; k < 9; k++) ENSURE_NEAR(rn[k], R[k], 1e-9);
        }
        ENSURE_NEAR(st.volume_ratio_mean, 1.0, 1e-12);
        hs_fem_destroy(&fem);
    }
    free(x);
    free(f);
    free(dof);
    box_free(&b);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

/// Random deformed configuration x0 + amp * noise (+ optional rotation).
static void perturbed(const hs_mesh* m, double amp, const double* R, uint64_t seed, double* x) {
    uint64_t s = seed;
    for (int v = 0; v < m->n_nodes; v++) {
        double p[3];
        for (int i = 0; i < 3; i++) p[i] = m->x0[3 * v + i] + amp * (2 * urand(&s) - 1);
        for (int i = 0; i < 3; i++)
            x[3 * v + i] = R ? R[3 * i] * p[0] + R[3 * i + 1] * p[1] + R[3 * i + 2] * p[2] : p[i];
    }
}

/// Dense copy of a CSC matrix (n x n, row-major).
static void csc_dense(const hs_csc* a, double* d) {
    memset(d, 0, sizeof(double) * (size_t)a->n * a->n);
    for (int c = 0; c < a->n; c++)
        for (int p = a->colp[c]; p < a->colp[c + 1]; p++)
            d[(size_t)a->rowi[p] * a->n + c] = a->val[p];
}

/// Tangent = -d f / d x by central differences (linear, StVK, and both with ANP), and the
/// assembled matrix agrees with hs_fem_apply_tangent.
static int test_tangent_fd(void) {
    int64_t bytes0 = hs_byte_count();
    box b;
    box_make(&b, 0.03, 0.02, 0.02, 2, 1, 1);
    int n = b.mesh.n_nodes, nd = 3 * n;
    int* dof = dofs_all(n);
    double* x = malloc(sizeof(double) * nd);
    double* xp = malloc(sizeof(double) * nd);
    double* fp = malloc(sizeof(double) * nd);
    double* fm = malloc(sizeof(double) * nd);
    double* f0 = malloc(sizeof(double) * nd);
    double* e = malloc(sizeof(double) * nd);
    double* ke = malloc(sizeof(double) * nd);
    double* dense = malloc(sizeof(double) * nd * nd);
    double R[9];
    double ax[3] = {0.6, 0.0, 0.8};
    rot_axis(ax, 0.7, R);
    for (int c = 0; c < N_CFGS; c++) {
        const cfg* cf = &k_cfgs[c];
        hs_fem_def def = make_def(cf, 2e4, 0.4);
        hs_fem* fem = NULL;
        ENSURE(hs_fem_create(&b.mesh, &def, dof, nd, &fem, NULL) == HS_OK);
        perturbed(&b.mesh, 0.002, R, 7 + c, x);
        hs_fem_update(fem, x, NULL);
        hs_csc* a = NULL;
        ENSURE(hs_fem_create_matrix(fem, &a) == HS_OK);
        hs_fem_assemble(fem, 1.0, 0.0, a);
        csc_dense(a, dense);
        double dscale = 0;
        for (int i = 0; i < nd * nd; i++) dscale = fmax(dscale, fabs(dense[i]));
        double maxerr = 0, maxk = 0, asym = 0, ferr = 0, fmaxv = 0;
        for (int j = 0; j < nd; j++) {
            memset(e, 0, sizeof(double) * nd);
            e[j] = 1.0;
            hs_fem_stats s0, sp, sm;
            hs_fem_update(fem, x, &s0);
            hs_fem_apply_tangent(fem, e, ke);
            hs_fem_forces(fem, f0);
            double h = 1e-7;
            memcpy(xp, x, sizeof(double) * nd);
            xp[j] += h;
            hs_fem_update(fem, xp, &sp);
            hs_fem_forces(fem, fp);
            xp[j] -= 2 * h;
            hs_fem_update(fem, xp, &sm);
            hs_fem_forces(fem, fm);
            // the force is the exact gradient of the reported energy (co-rotated included:
            // R sigma(sym(R^T F - I)) is the gradient of mu |S - I|^2 + lambda/2 tr(S - I)^2)
            double fe = -(sp.energy_j - sm.energy_j) / (2 * h);
            ferr = fmax(ferr, fabs(fe - f0[j]));
            fmaxv = fmax(fmaxv, fabs(f0[j]));
            for (int i = 0; i < nd; i++) {
                double fd = -(fp[i] - fm[i]) / (2 * h);
                maxk = fmax(maxk, fabs(ke[i]));
                if (cf->model != HS_MODEL_COROTATED) maxerr = fmax(maxerr, fabs(fd - ke[i]));
                // assembled == applied
                ENSURE_SMALL(dense[(size_t)i * nd + j] - ke[i], 1e-10 * dscale);
                asym = fmax(asym, fabs(dense[(size_t)i * nd + j] - dense[(size_t)j * nd + i]));
            }
        }
        if (cf->model != HS_MODEL_COROTATED) {
            if (!(maxerr <= 1e-6 * maxk)) printf("  %s: fd err %g of %g\n", cf->name, maxerr, maxk);
            ENSURE(maxerr <= 1e-6 * maxk);
        }
        ENSURE(asym <= 1e-10 * maxk);
        if (!(ferr <= 1e-8 * fmaxv))
            printf("  %s: energy fd err %g of %g\n", cf->name, ferr, fmaxv);
        ENSURE(fmaxv > 0 && ferr <= 1e-8 * fmaxv);
        hs_csc_destroy(&a);
        hs_fem_destroy(&fem);
    }
    free(x);
    free(xp);
    free(fp);
    free(fm);
    free(f0);
    free(e);
    free(ke);
    free(dense);
    free(dof);
    box_free(&b);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

/// Co-rotated tangent: R K R^T (documented approximation, no dR/dx term). At rest it equals the
/// linear stiffness and is symmetric positive semi-definite; under a rigid rotation it is the
/// rotated linear stiffness; in a deformed state it is still symmetric PSD.
static int test_corot_tangent(void) {
    int64_t bytes0 = hs_byte_count();
    box b;
    box_make(&b, 0.04, 0.02, 0.02, 2, 1, 1);
    int n = b.mesh.n_nodes, nd = 3 * n;
    int* dof = dofs_all(n);
    double* x = malloc(sizeof(double) * nd);
    double* v = malloc(sizeof(double) * nd);
    double* rv = malloc(sizeof(double) * nd);
    double* y1 = malloc(sizeof(double) * nd);
    double* y2 = malloc(sizeof(double) * nd);
    double* dense = malloc(sizeof(double) * nd * nd);
    for (int anp = 0; anp < 2; anp++) {
        cfg cl = {"lin", HS_MODEL_LINEAR, HS_ROTATION_POLAR, anp};
        cfg cc = {"cor", HS_MODEL_COROTATED, HS_ROTATION_POLAR, anp};
        hs_fem_def dl = make_def(&cl, 1e4, 0.45), dc = make_def(&cc, 1e4, 0.45);
        hs_fem *fl = NULL, *fc = NULL;
        ENSURE(hs_fem_create(&b.mesh, &dl, dof, nd, &fl, NULL) == HS_OK);
        ENSURE(hs_fem_create(&b.mesh, &dc, dof, nd, &fc, NULL) == HS_OK);
        hs_fem_update(fl, b.mesh.x0, NULL);
        // rigid rotation: K_c(R x0) v = R K_l R^T v
        double R[9];
        double ax[3] = {0.0, 0.6, 0.8};
        rot_axis(ax, 2.0, R);
        for (int p = 0; p < n; p++)
            for (int i = 0; i < 3; i++)
                x[3 * p + i] = R[3 * i] * b.mesh.x0[3 * p] + R[3 * i + 1] * b.mesh.x0[3 * p + 1] +
                               R[3 * i + 2] * b.mesh.x0[3 * p + 2];
        hs_fem_update(fc, x, NULL);
        uint64_t s = 3;
        for (int i = 0; i < nd; i++) v[i] = 2 * urand(&s) - 1;
        for (int p = 0; p < n; p++)
            for (int i = 0; i < 3; i++)
                rv[3 * p + i] = R[i] * v[3 * p] + R[3 + i] * v[3 * p + 1] + R[6 + i] * v[3 * p + 2];
        hs_fem_apply_tangent(fl, rv, y1); // K_l R^T v
        hs_fem_apply_tangent(fc, v, y2);
        double ymax = vnorm(y2, nd);
        ENSURE(ymax > 0);
        for (int p = 0; p < n; p++)
            for (int i = 0; i < 3; i++) {
                double r = R[3 * i] * y1[3 * p] + R[3 * i + 1] * y1[3 * p + 1] +
                           R[3 * i + 2] * y1[3 * p + 2];
                ENSURE_SMALL(r - y2[3 * p + i], 1e-10 * ymax);
            }
        // deformed state: symmetric and PSD (random quadratic forms, and rigid modes give 0)
        perturbed(&b.mesh, 0.003, R, 11, x);
        hs_fem_update(fc, x, NULL);
        hs_csc* a = NULL;
        ENSURE(hs_fem_create_matrix(fc, &a) == HS_OK);
        hs_fem_assemble(fc, 1.0, 0.0, a);
        csc_dense(a, dense);
        double dmax = 0;
        for (int i = 0; i < nd * nd; i++) dmax = fmax(dmax, fabs(dense[i]));
        for (int i = 0; i < nd; i++)
            for (int j = 0; j < i; j++)
                ENSURE_SMALL(dense[(size_t)i * nd + j] - dense[(size_t)j * nd + i], 1e-12 * dmax);
        for (int trial = 0; trial < 200; trial++) {
            for (int i = 0; i < nd; i++) v[i] = 2 * urand(&s) - 1;
            hs_fem_apply_tangent(fc, v, y1);
            double q = 0;
            for (int i = 0; i < nd; i++) q += v[i] * y1[i];
            ENSURE(q >= -1e-12 * dmax * nd);
        }
        // a translation is in the null space
        for (int p = 0; p < n; p++) {
            v[3 * p] = 1;
            v[3 * p + 1] = -2;
            v[3 * p + 2] = 0.5;
        }
        hs_fem_apply_tangent(fc, v, y1);
        ENSURE_SMALL(vnorm(y1, nd), 1e-10 * dmax);
        hs_csc_destroy(&a);
        hs_fem_destroy(&fl);
        hs_fem_destroy(&fc);
    }
    free(x);
    free(v);
    free(rv);
    free(y1);
    free(y2);
    free(dense);
    free(dof);
    box_free(&b);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

/// Higham's iteration agrees with the SVD rotation; a warm start needs fewer iterations.
// The 4-wide warm polar step (the co-rotated element pass) must give bit for bit the scalar
// iteration's rotation, R^T F and iteration count (from a trusted start) for every lane it
// accepts, and leave the start untouched on every lane it hands back to the scalar code.
static int test_polar_batched(void) {
    uint64_t s = 7;
    int accepted = 0, handed = 0;
    for (int trial = 0; trial < 400; trial++) {
        const int max_iter = trial % 5 == 0 ? 2 : 20;
        const double tol = trial % 3 == 0 ? 1e-8 : 1e-6;
        double F[4][9], R0[4][9], R[4][9], Y[4][9];
        const double* fp[4];
        double* rp[4];
        double* yp[4];
        for (int l = 0; l < 4; l++) {
            double ax[3] = {2 * urand(&s) - 1, 2 * urand(&s) - 1, 2 * urand(&s) - 1};
            double an = vnorm(ax, 3);
            for (int i = 0; i < 3; i++) ax[i] /= an;
            double Rt[9], S[9] = {0}, dR[9];
            rot_axis(ax, 3.0 * urand(&s), Rt);
            for (int i = 0; i < 3; i++) S[4 * i] = 0.6 + urand(&s);
            S[1] = S[3] = 0.2 * (urand(&s) - 0.5);
            mat3_mul(Rt, S, F[l]);
            // start: the rotation turned by up to 0.5 rad, or by ~pi (no warm convergence)
            double ang = l == 3 && trial % 4 == 1 ? 3.1 : 0.5 * urand(&s) * urand(&s);
            double ax2[3] = {ax[1], -ax[0], 0.3}; // unit after the division below
            double n2 = vnorm(ax2, 3);
            for (int i = 0; i < 3; i++) ax2[i] /= n2;
            rot_axis(ax2, ang, dR);
            mat3_mul(dR, Rt, R0[l]);
            memcpy(R[l], R0[l], sizeof R[l]);
            fp[l] = F[l];
            rp[l] = R[l];
            yp[l] = Y[l];
        }
        int it[4];
        hs_polar_warm4(fp, rp, yp, tol, max_iter, it);
        for (int l = 0; l < 4; l++) {
            double rs[9], ys[9];
            memcpy(rs, R0[l], sizeof rs);
            int its = hs_polar_higham_ex(F[l], rs, tol, max_iter, 1, ys);
            if (it[l] >= 0) {
                ENSURE(it[l] == its);
                ENSURE(memcmp(R[l], rs, sizeof rs) == 0);
                ENSURE(memcmp(Y[l], ys, sizeof ys) == 0);
                accepted++;
            } else {
                ENSURE(memcmp(R[l], R0[l], sizeof rs) == 0);
                handed++;
            }
        }
    }
    printf("  batched warm polar: %d lanes bit-identical to the scalar code, %d handed back\n",
           accepted, handed);
    ENSURE(accepted > 1000 && handed > 0);

    // The warped solver's node rotations (chordal means of the tets' rotations): the batched
    // call equals the per-node call bit for bit, from a cold (zero) start and from the previous
    // rotations; a rigid turn gives that turn; a bend stays near the polar part of the node's
    // mean F (the definition before); past 90 degrees they are that polar part, warm.
    box b;
    box_make(&b, 0.1, 0.02, 0.02, 10, 3, 3);
    int n = b.mesh.n_nodes;
    int* dof = malloc(sizeof(int) * 3 * n);
    int nf = 0;
    for (int d = 0; d < 3 * n; d++) dof[d] = b.mesh.x0[3 * (d / 3)] < 1e-12 ? -1 : nf++;
    hs_fem_def def = hs_fem_default_def();
    def.model = HS_MODEL_COROTATED;
    hs_fem* fem = NULL;
    ENSURE(hs_fem_create(&b.mesh, &def, dof, nf, &fem, NULL) == HS_OK);
    double* x = malloc(sizeof(double) * 3 * n);
    double* r1 = calloc(9 * (size_t)n, sizeof(double));
    double* r2 = calloc(9 * (size_t)n, sizeof(double));
    double* r3 = calloc(9 * (size_t)n, sizeof(double));
    // turn (rad), bend (m at the tip), curl (turn at the tip, growing from 0 along the beam):
    // rigid, bent, bent and turned, rigid past 90 degrees, curled past 180 degrees near its tip
    // (there a node's tets turn by pi - d and pi + d: their quaternions, w >= 0, cancel)
    const double turn[] = {0.3, 0.0, 0.6, 2.0, 2.0, 0.0},
                 bend[] = {0.0, 0.03, 0.03, 0.0, 0.02, 0.0}, curl[] = {0, 0, 0, 0, 0, 3.5};
    double bend_dev = 0;
    int curl_quat = 0, curl_polar = 0;
    for (int step = 0; step < 6; step++) {
        double Rz[9];
        rot_z(turn[step], Rz);
        for (int v = 0; v < n; v++) {
            const double* p = b.mesh.x0 + 3 * v;
            if (curl[step] > 0) rot_z(curl[step] * p[0] / 0.1, Rz);
            for (int i = 0; i < 3; i++)
                x[3 * v + i] = Rz[3 * i] * p[0] + Rz[3 * i + 1] * p[1] + Rz[3 * i + 2] * p[2];
            x[3 * v + 2] -= bend[step] * (p[0] / 0.1) * (p[0] / 0.1);
        }
        hs_fem_update(fem, x, NULL);
        memcpy(r3, r2, sizeof(double) * 9 * (size_t)n); // the starts of the fallback
        for (int v = 0; v < n; v++) hs_fem_tangent_rotation(fem, v, r1 + 9 * v);
        hs_fem_tangent_rotations(fem, r2);
        ENSURE(memcmp(r1, r2, sizeof(double) * 9 * (size_t)n) == 0);
        if (curl[step] > 0) {
            // a node with a tet turned past 90 degrees takes the polar part of its mean F, the
            // others the mean of their tets' rotations (each tet's turn from the polar part of
            // its F; nodes with a tet within 0.1 rad of 90 degrees are left out)
            double* tmax = calloc((size_t)n, sizeof(double));
            for (int t = 0; t < b.mesh.n_tets; t++) {
                const int* tt = b.mesh.tets + 4 * t;
                double dm[9], ds[9], c[9], F[9], R[9];
                for (int i = 0; i < 3; i++)
                    for (int j = 0; j < 3; j++) {
                        dm[3 * i + j] = b.mesh.x0[3 * tt[j + 1] + i] - b.mesh.x0[3 * tt[0] + i];
                        ds[3 * i + j] = x[3 * tt[j + 1] + i] - x[3 * tt[0] + i];
                    }
                m3_cofactor(dm, c); // dm^-1 = c^T / det dm
                m3_mul_nt(ds, c, F);
                const double det = m3_det(dm);
                for (int k = 0; k < 9; k++) F[k] /= det;
                hs_polar_svd(F, R);
                const double ang = acos(fmin(1.0, fmax(-1.0, 0.5 * (R[0] + R[4] + R[8] - 1.0))));
                for (int a = 0; a < 4; a++) tmax[tt[a]] = fmax(tmax[tt[a]], ang);
            }
            for (int v = 0; v < n; v++) {
                double polar[9];
                memcpy(polar, r3 + 9 * v, sizeof polar);
                hs_fem_node_rotation_warm(fem, v, polar);
                int same = memcmp(polar, r2 + 9 * v, sizeof polar) == 0;
                if (tmax[v] > 1.5708 + 0.1) {
                    ENSURE(same);
                    curl_polar++;
                } else if (tmax[v] < 1.5708 - 0.1) {
                    double dev = 0;
                    for (int k = 0; k < 9; k++) dev = fmax(dev, fabs(polar[k] - r2[9 * v + k]));
                    ENSURE(dev < 0.05 && !same);
                    curl_quat++;
                }
            }
            free(tmax);
            continue;
        }
        for (int v = 0; v < n; v++) {
            double* r = r2 + 9 * v;
            double dev = 0, polar[9];
            if (turn[step] > 1.6) {
                memcpy(polar, r3 + 9 * v, sizeof polar);
                hs_fem_node_rotation_warm(fem, v, polar);
                ENSURE(memcmp(polar, r, sizeof polar) == 0);
                continue;
            }
            hs_fem_node_rotation(fem, v, polar);
            for (int k = 0; k < 9; k++) {
                dev = fmax(dev, fabs(r[k] - (bend[step] > 0 ? polar[k] : Rz[k])));
                double o = 0; // orthogonality: R R^T = I
                for (int j = 0; j < 3; j++) o += r[3 * (k / 3) + j] * r[3 * (k % 3) + j];
                ENSURE(fabs(o - (k % 4 == 0)) < 1e-14);
            }
            if (bend[step] > 0)
                bend_dev = fmax(bend_dev, dev);
            else
                ENSURE(dev < 2 * def.polar_tol); // the elements' rotations are to that
        }
    }
    printf("  tangent rotations of a bent beam: at most %.2g from the polar part of mean F\n",
           bend_dev);
    ENSURE(bend_dev > 0 && bend_dev < 1e-3); // measured 6.4e-5
    printf("  curled past 180 degrees: %d nodes took the polar part of mean F, %d the mean "
           "rotation\n",
           curl_polar, curl_quat);
    ENSURE(curl_polar > 0 && curl_quat > 0);
    // after hs_fem_reset_rotations the update's sums are stale: the batched call must not use
    // them (it did: every node kept the last turn)
    hs_fem_reset_rotations(fem);
    for (int v = 0; v < n; v++) hs_fem_tangent_rotation(fem, v, r1 + 9 * v);
    memcpy(r2, r1, sizeof(double) * 9 * (size_t)n);
    hs_fem_tangent_rotations(fem, r2);
    ENSURE(memcmp(r1, r2, sizeof(double) * 9 * (size_t)n) == 0);
    hs_fem_destroy(&fem);
    free(r1);
    free(r2);
    free(r3);
    free(x);
    free(dof);
    box_free(&b);
    return 0;
}

// The four-wide element pass of hs_fem_update (linear and co-rotated with the polar rotation)
// must give bit for bit what the element loop gives one element at a time: forces, energy,
// statistics and node rotations, through warm steps, a turn too large for the warm polar step
// (those lanes go back to the scalar code), inactive elements, inverted elements and a tail of
// ne mod 4 elements.
static int test_element_pass(void) {
    int64_t bytes0 = hs_byte_count();
    box b;
    box_make(&b, 0.1, 0.03, 0.03, 7, 3, 3); // 378 tets: 2 left after the groups of four
    const int n = b.mesh.n_nodes;
    ENSURE(b.mesh.n_tets % 4 != 0);
    int* dof = malloc(sizeof(int) * 3 * n);
    int nf = 0;
    for (int d = 0; d < 3 * n; d++) dof[d] = b.mesh.x0[3 * (d / 3)] < 1e-12 ? -1 : nf++;
    double* x = malloc(sizeof(double) * 3 * n);
    double* fa = malloc(sizeof(double) * 3 * n);
    double* fb = malloc(sizeof(double) * 3 * n);
    double* ra = calloc(9 * (size_t)n, sizeof(double));
    double* rb = calloc(9 * (size_t)n, sizeof(double));
    static const cfg cs[] = {{"linear", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 0},
                             {"corot", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 0},
                             {"linear-anp", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 1},
                             {"corot-anp", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1}};
    for (int ci = 0; ci < 4; ci++) {
        hs_fem_def def = hs_fem_default_def(); // the default polar tolerance, as in use
        def.model = cs[ci].model;
        def.locking_free = cs[ci].anp;
        hs_fem *A = NULL, *B = NULL;
        ENSURE(hs_fem_create(&b.mesh, &def, dof, nf, &A, NULL) == HS_OK);
        ENSURE(hs_fem_create(&b.mesh, &def, dof, nf, &B, NULL) == HS_OK);
        for (int e = 5; e < b.mesh.n_tets; e += 37) { // a lane of several groups off
            hs_fem_set_element_active(A, e, 0);
            hs_fem_set_element_active(B, e, 0);
        }
        int saw_inverted = 0;
        for (int step = 0; step < 6; step++) {
            // bend and turn a little more each step; step 3 turns by 3 rad at once
            double Rz[9];
            rot_z(step == 3 ? 3.0 : 0.05 * step, Rz);
            for (int v = 0; v < n; v++) {
                const double* p = b.mesh.x0 + 3 * v;
                for (int i = 0; i < 3; i++)
                    x[3 * v + i] = Rz[3 * i] * p[0] + Rz[3 * i + 1] * p[1] + Rz[3 * i + 2] * p[2];
                x[3 * v + 2] -= 2.0 * p[0] * p[0] * step;
            }
            if (step == 5) x[3 * box_node(&b, 3, 1, 1) + 2] += 0.05; // through its neighbours
            hs_fem_stats sa, sb;
            hs_fem_update(A, x, &sa);
            hs_fem_update_scalar(B, x, &sb);
            hs_fem_forces(A, fa);
            hs_fem_forces(B, fb);
            ENSURE(memcmp(fa, fb, sizeof(double) * 3 * (size_t)n) == 0);
            ENSURE(memcmp(&sa.energy_j, &sb.energy_j, sizeof sa.energy_j) == 0);
            ENSURE(sa.inverted == sb.inverted && sa.polar_iters_max == sb.polar_iters_max);
            ENSURE(sa.volume_ratio_mean == sb.volume_ratio_mean &&
                   sa.volume_ratio_min == sb.volume_ratio_min &&
                   sa.volume_ratio_max == sb.volume_ratio_max);
            saw_inverted |= sa.inverted > 0;
            // the 3 rad turn sends lanes back to the scalar code, whose cold iterations show
            // (warm steps alone: 2 here; measured with a counter: 365 of the 378 elements)
            if (def.model == HS_MODEL_COROTATED && step == 3) ENSURE(sa.polar_iters_max >= 4);
            if (def.model == HS_MODEL_COROTATED) {
                hs_fem_tangent_rotations(A, ra);
                hs_fem_tangent_rotations(B, rb);
                ENSURE(memcmp(ra, rb, sizeof(double) * 9 * (size_t)n) == 0);
            }
        }
        ENSURE(saw_inverted);
        if (def.model == HS_MODEL_COROTATED) {
            // an element taken out after the update (a cut): the node sums of that update
            // are stale, and the batched node rotations must not use them
            hs_fem_set_element_active(A, 100, 0);
            hs_fem_tangent_rotations(A, ra);
            for (int v = 0; v < n; v++) hs_fem_tangent_rotation(A, v, rb + 9 * v);
            ENSURE(memcmp(ra, rb, sizeof(double) * 9 * (size_t)n) == 0);
        }
        hs_fem_destroy(&A);
        hs_fem_destroy(&B);
    }
    free(x);
    free(fa);
    free(fb);
    free(ra);
    free(rb);
    free(dof);
    box_free(&b);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int test_polar(void) {
    uint64_t s = 42;
    int cold_total = 0, warm_total = 0;
    for (int trial = 0; trial < 200; trial++) {
        double ax[3] = {2 * urand(&s) - 1, 2 * urand(&s) - 1, 2 * urand(&s) - 1};
        double an = vnorm(ax, 3);
        for (int i = 0; i < 3; i++) ax[i] /= an;
        double R[9], Q[9], Sd[9] = {0}, tmp[9], S[9], F[9];
        rot_axis(ax, 3.0 * urand(&s), R);
        double ax2[3] = {ax[1], -ax[0], 0.3};
        double n2 = vnorm(ax2, 3);
        for (int i = 0; i < 3; i++) ax2[i] /= n2;
        rot_axis(ax2, 2.0 * urand(&s), Q);
        // S = Q diag(s) Q^T, stretches in [0.6, 1.6]
        for (int i = 0; i < 3; i++) Sd[4 * i] = 0.6 + urand(&s);
        mat3_mul(Q, Sd, tmp);
        double Qt[9];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) Qt[3 * i + j] = Q[3 * j + i];
        mat3_mul(tmp, Qt, S);
        mat3_mul(R, S, F);
        double rs[9], rh[9] = {0};
        hs_polar_svd(F, rs);
        for (int k = 0; k < 9; k++) ENSURE_NEAR(rs[k], R[k], 1e-9);
        int cold = hs_polar_higham(F, rh, 1e-8, 50); // zeros: not a rotation -> cold start
        ENSURE(cold > 0 && cold < 50);
        for (int k = 0; k < 9; k++) ENSURE_NEAR(rh[k], rs[k], 1e-7);
        ENSURE_NEAR(det3(rh), 1.0, 1e-7);
        // warm start: the rotation of a slightly different F (a 0.02 rad step)
        double dR[9], Rw[9];
        rot_axis(ax2, 0.02, dR);
        mat3_mul(dR, R, Rw);
        int warm = hs_polar_higham(F, Rw, 1e-8, 50);
        for (int k = 0; k < 9; k++) ENSURE_NEAR(Rw[k], rs[k], 1e-7);
        cold_total += cold;
        warm_total += warm;
        // an exact warm start costs nothing
        double Re[9];
        memcpy(Re, rs, sizeof Re);
        ENSURE(hs_polar_higham(F, Re, 1e-8, 50) == 0);
        // reflection kept in the stretch: det F < 0 still gives a proper rotation R with
        // R^T F symmetric (its smallest eigenvalue negative)
        double Fm[9];
        memcpy(Fm, F, sizeof Fm);
        for (int i = 0; i < 3; i++) Fm[3 * i + 2] = -Fm[3 * i + 2];
        double rm[9];
        hs_polar_svd(Fm, rm);
        ENSURE_NEAR(det3(rm), 1.0, 1e-9);
        double rtf[9], rt[9];
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++) rt[3 * i + j] = rm[3 * j + i];
        mat3_mul(rt, Fm, rtf);
        ENSURE_NEAR(rtf[1], rtf[3], 1e-9);
        ENSURE_NEAR(rtf[2], rtf[6], 1e-9);
        ENSURE_NEAR(rtf[5], rtf[7], 1e-9);
    }
    printf("  polar iterations over 200 matrices: cold %d, warm %d\n", cold_total, warm_total);
    ENSURE(warm_total * 2 < cold_total);
    // degenerate inputs: rank-deficient and zero F give a proper rotation, no NaN
    double flat[9] = {1, 0, 0, 0, 1, 0, 0, 0, 0}, zero[9] = {0}, r[9];
    hs_polar_svd(flat, r);
    ENSURE_NEAR(det3(r), 1.0, 1e-12);
    hs_polar_svd(zero, r);
    ENSURE_NEAR(det3(r), 1.0, 1e-12);
    double r2[9] = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    hs_polar_higham(flat, r2, 1e-8, 20);
    ENSURE_NEAR(det3(r2), 1.0, 1e-9);
    return 0;
}

// Dense Cholesky solve (test-only; small systems).
static int dense_solve(double* a, int n, double* b) {
    for (int j = 0; j < n; j++) {
        double d = a[(size_t)j * n + j];
        for (int k = 0; k < j; k++) d -= a[(size_t)j * n + k] * a[(size_t)j * n + k];
        if (!(d > 0)) return 1;
        d = sqrt(d);
        a[(size_t)j * n + j] = d;
        for (int i = j + 1; i < n; i++) {
            double s = a[(size_t)i * n + j];
            for (int k = 0; k < j; k++) s -= a[(size_t)i * n + k] * a[(size_t)j * n + k];
            a[(size_t)i * n + j] = s / d;
        }
    }
    for (int i = 0; i < n; i++) {
        double s = b[i];
        for (int k = 0; k < i; k++) s -= a[(size_t)i * n + k] * b[k];
        b[i] = s / a[(size_t)i * n + i];
    }
    for (int i = n - 1; i >= 0; i--) {
        double s = b[i];
        for (int k = i + 1; k < n; k++) s -= a[(size_t)k * n + i] * b[k];
        b[i] = s / a[(size_t)i * n + i];
    }
    return 0;
}

/// Cantilever (clamped at x = 0) with a small tip load: tip deflection of a linear solve.
static int cantilever_tip(const box* b, const cfg* c, double E, double nu, double load,
                          double* tip) {
    int n = b->mesh.n_nodes;
    int* dof = malloc(sizeof(int) * 3 * n);
    int nf = 0;
    for (int v = 0; v < n; v++)
        for (int i = 0; i < 3; i++) dof[3 * v + i] = b->mesh.x0[3 * v] < 1e-12 ? -1 : nf++;
    hs_fem_def def = make_def(c, E, nu);
    hs_fem* fem = NULL;
    ENSURE(hs_fem_create(&b->mesh, &def, dof, nf, &fem, NULL) == HS_OK);
    hs_fem_update(fem, b->mesh.x0, NULL);
    hs_csc* a = NULL;
    ENSURE(hs_fem_create_matrix(fem, &a) == HS_OK);
    hs_fem_assemble(fem, 1.0, 0.0, a);
    double* dense = malloc(sizeof(double) * nf * nf);
    double* rhs = calloc(nf, sizeof(double));
    csc_dense(a, dense);
    // load -z spread over the tip face nodes
    int ntip = 0;
    for (int v = 0; v < n; v++) ntip += fabs(b->mesh.x0[3 * v] - 0.1) < 1e-12;
    for (int v = 0; v < n; v++)
        if (fabs(b->mesh.x0[3 * v] - 0.1) < 1e-12) rhs[dof[3 * v + 2]] = -load / ntip;
    ENSURE(dense_solve(dense, nf, rhs) == 0);
    double sum = 0;
    for (int v = 0; v < n; v++)
        if (fabs(b->mesh.x0[3 * v] - 0.1) < 1e-12) sum += rhs[dof[3 * v + 2]];
    *tip = -sum / ntip;
    free(dense);
    free(rhs);
    free(dof);
    hs_csc_destroy(&a);
    hs_fem_destroy(&fem);
    return 0;
}

/// nu = 0.49 cantilever: standard linear tets lock; with ANP the (normalised) tip deflection
/// matches what the same mesh gives for a compressible material (nu = 0.3), i.e. the volumetric
/// locking is gone and only the bending error of a coarse linear-tet mesh remains.
static int test_locking(void) {
    int64_t bytes0 = hs_byte_count();
    box b;
    box_make(&b, 0.1, 0.02, 0.02, 15, 3, 3);
    double E = 1.5e6, P = 0.05;
    cfg cs = {"lin", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 0};
    cfg ca = {"lin-anp", HS_MODEL_LINEAR, HS_ROTATION_POLAR, 1};
    cfg cc = {"cor-anp", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1};
    double t_std, t_anp, t_cor, t_ref;
    ENSURE(cantilever_tip(&b, &cs, E, 0.49, P, &t_std) == 0);
    ENSURE(cantilever_tip(&b, &ca, E, 0.49, P, &t_anp) == 0);
    ENSURE(cantilever_tip(&b, &cc, E, 0.49, P, &t_cor) == 0);
    ENSURE(cantilever_tip(&b, &cs, E, 0.3, P, &t_ref) == 0);
    // Timoshenko: P L^3 / (3 E I) + P L / (k G A), k = 5/6 for a square section.
    double L = 0.1, h = 0.02, I = h * h * h * h / 12;
    double G49 = E / (2 * 1.49), G30 = E / (2 * 1.3);
    double beam49 = P * L * L * L / (3 * E * I) + P * L / (5.0 / 6.0 * G49 * h * h);
    double beam30 = P * L * L * L / (3 * E * I) + P * L / (5.0 / 6.0 * G30 * h * h);
    double r_std = t_std / beam49, r_anp = t_anp / beam49, r_ref = t_ref / beam30;
    printf("  tip / beam theory: nu 0.49 standard %.3f, ANP %.3f, co-rotated ANP %.3f; "
           "nu 0.3 standard %.3f\n",
           r_std, r_anp, t_cor / beam49, r_ref);
    ENSURE(r_std < 0.6 * r_ref);  // locked
    ENSURE(r_anp > 0.95 * r_ref); // not locked
    ENSURE(r_anp < 1.05);         // and not softer than the beam
    ENSURE(t_anp > 2.0 * t_std);
    ENSURE_NEAR(t_cor, t_anp, 1e-9 * t_anp); // at rest the co-rotated tangent is the linear one
    box_free(&b);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

/// Invert an element, release it, relax it (quasi-static Newton with a step limit): both
/// remedies bring it back to positive volume.
static int test_inversion(void) {
    int64_t bytes0 = hs_byte_count();
    hs_mesh m;
    memset(&m, 0, sizeof m);
    double x0[12] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1};
    int tets[4] = {0, 1, 2, 3};
    m.n_nodes = 4;
    m.n_tets = 1;
    m.x0 = x0;
    m.tets = tets;
    int dof[12] = {-1, -1, -1, -1, -1, -1, -1, -1, -1, 0, 1, 2}; // only node 3 moves
    for (int rem = 0; rem < 2; rem++) {
        for (int anp = 0; anp < 2; anp++) {
            cfg c = {"cor", HS_MODEL_COROTATED, HS_ROTATION_POLAR, anp};
            hs_fem_def def = make_def(&c, 1e4, 0.3);
            def.inversion = rem ? HS_INVERSION_KEEP_REFLECTION : HS_INVERSION_LINEAR_FALLBACK;
            hs_fem* fem = NULL;
            ENSURE(hs_fem_create(&m, &def, dof, 3, &fem, NULL) == HS_OK);
            double x[12];
            memcpy(x, x0, sizeof x);
            // drive node 3 through the opposite face in steps (the warm start follows)
            hs_fem_stats st;
            for (int k = 0; k <= 10; k++) {
                x[9] = 0.1 * k * 0.3;
                x[10] = 0.1 * k * 0.2;
                x[11] = 1.0 - 0.16 * k;
                hs_fem_update(fem, x, &st);
            }
            ENSURE(st.inverted == 1);
            ENSURE(st.volume_ratio_min < -0.5);
            double f[12], y[12];
            hs_fem_forces(fem, f);
            ENSURE(f[11] > 0); // restoring: pushes node 3 back up through the face
            // release: Newton on the free node with the step limited to 0.2 m
            hs_csc* a = NULL;
            ENSURE(hs_fem_create_matrix(fem, &a) == HS_OK);
            int it;
            for (it = 0; it < 60; it++) {
                hs_fem_update(fem, x, &st);
                hs_fem_forces(fem, f);
                if (vnorm(f + 9, 3) < 1e-9 && st.inverted == 0) break;
                hs_fem_assemble(fem, 1.0, 0.0, a);
                double k[9], du[3] = {f[9], f[10], f[11]};
                csc_dense(a, k);
                if (dense_solve(k, 3, du) != 0) {
                    // singular tangent: fall back to a gradient step
                    for (int i = 0; i < 3; i++) du[i] = f[9 + i] / 1e4;
                }
                double nrm = vnorm(du, 3);
                if (nrm > 0.2)
                    for (int i = 0; i < 3; i++) du[i] *= 0.2 / nrm;
                for (int i = 0; i < 3; i++) x[9 + i] += du[i];
            }
            (void)y;
            hs_fem_update(fem, x, &st);
            if (st.inverted != 0 || it >= 60)
                printf("  remedy %d anp %d: inverted %d after %d iterations, det %g\n", rem, anp,
                       st.inverted, it, st.volume_ratio_min);
            ENSURE(st.inverted == 0);
            ENSURE(st.volume_ratio_min > 0.5);
            ENSURE(it < 60);
            hs_csc_destroy(&a);
            hs_fem_destroy(&fem);
        }
    }
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

/// Same on a 6-tet block squashed flat through itself, relaxed by damped implicit Euler.
static int test_inversion_dynamic(void) {
    int64_t bytes0 = hs_byte_count();
    box b;
    box_make(&b, 1, 1, 1, 1, 1, 1);
    int n = b.mesh.n_nodes;
    int dof[24], nf = 0;
    for (int v = 0; v < n; v++)
        for (int i = 0; i < 3; i++) dof[3 * v + i] = b.mesh.x0[3 * v + 2] < 0.5 ? -1 : nf++;
    for (int rem = 0; rem < 2; rem++) {
        cfg c = {"cor", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 0};
        hs_fem_def def = make_def(&c, 1e4, 0.3);
        def.inversion = rem ? HS_INVERSION_KEEP_REFLECTION : HS_INVERSION_LINEAR_FALLBACK;
        hs_fem* fem = NULL;
        ENSURE(hs_fem_create(&b.mesh, &def, dof, nf, &fem, NULL) == HS_OK);
        double x[24], v[24] = {0}, f[24];
        memcpy(x, b.mesh.x0, sizeof x);
        hs_fem_stats st;
        // push the top face down through the bottom one (z: 1 -> -0.5)
        for (int k = 1; k <= 15; k++) {
            for (int p = 0; p < n; p++)
                if (b.mesh.x0[3 * p + 2] > 0.5) x[3 * p + 2] = 1.0 - 0.1 * k;
            hs_fem_update(fem, x, &st);
        }
        ENSURE(st.inverted == 6);
        // linearised implicit Euler (M + dt^2 K) v+ = M v + dt f, with velocity damping
        const double* mass = hs_fem_lumped_mass(fem);
        hs_csc* a = NULL;
        ENSURE(hs_fem_create_matrix(fem, &a) == HS_OK);
        double dt = 0.01, kd[144], rhs[12];
        for (int step = 0; step < 400; step++) {
            hs_fem_update(fem, x, &st);
            hs_fem_forces(fem, f);
            hs_fem_assemble(fem, dt * dt, 1.0, a);
            csc_dense(a, kd);
            for (int d = 0; d < 24; d++)
                if (dof[d] >= 0) rhs[dof[d]] = mass[d / 3] * v[d] + dt * f[d];
            ENSURE(dense_solve(kd, nf, rhs) == 0);
            for (int d = 0; d < 24; d++)
                if (dof[d] >= 0) {
                    v[d] = 0.95 * rhs[dof[d]];
                    x[d] += dt * v[d];
                }
        }
        hs_fem_update(fem, x, &st);
        if (st.inverted) printf("  remedy %d: %d inverted at the end\n", rem, st.inverted);
        ENSURE(st.inverted == 0);
        ENSURE(fabs(st.volume_ratio_min - 1) < 0.05 && fabs(st.volume_ratio_max - 1) < 0.05);
        hs_csc_destroy(&a);
        hs_fem_destroy(&fem);
    }
    box_free(&b);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

/// Lumped mass sums to density * volume; an inactive element removes its share and its force.
static int test_mass_and_active(void) {
    int64_t bytes0 = hs_byte_count();
    box b;
    box_make(&b, 0.3, 0.2, 0.1, 3, 2, 2);
    int n = b.mesh.n_nodes;
    int* dof = dofs_all(n);
    cfg c = {"cor", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1};
    hs_fem_def def = make_def(&c, 1e4, 0.45);
    def.material.density_kg_m3 = 960;
    hs_fem* fem = NULL;
    ENSURE(hs_fem_create(&b.mesh, &def, dof, 3 * n, &fem, NULL) == HS_OK);
    const double* m = hs_fem_lumped_mass(fem);
    double sum = 0;
    for (int i = 0; i < n; i++) sum += m[i];
    ENSURE_NEAR(sum, 960 * 0.3 * 0.2 * 0.1, 1e-12);
    double v0 = tet_vol6(b.mesh.x0, b.mesh.tets + 4 * 5) / 6;
    hs_fem_set_element_active(fem, 5, 0);
    sum = 0;
    for (int i = 0; i < n; i++) sum += m[i];
    ENSURE_NEAR(sum, 960 * (0.3 * 0.2 * 0.1 - v0), 1e-12);
    // with every element off, nothing is left
    for (int e = 0; e < b.mesh.n_tets; e++) hs_fem_set_element_active(fem, e, 0);
    double* x = malloc(sizeof(double) * 3 * n);
    double* f = malloc(sizeof(double) * 3 * n);
    perturbed(&b.mesh, 0.01, NULL, 5, x);
    hs_fem_stats st;
    hs_fem_update(fem, x, &st);
    hs_fem_forces(fem, f);
    ENSURE(vnorm(f, 3 * n) == 0);
    ENSURE(st.energy_j == 0);
    for (int i = 0; i < n; i++) ENSURE(m[i] == 0);
    hs_csc* a = NULL;
    ENSURE(hs_fem_create_matrix(fem, &a) == HS_OK);
    hs_fem_assemble(fem, 1.0, 0.0, a);
    ENSURE(vnorm(a->val, a->nnz) == 0);
    // ... but each node holds the mass it had on the diagonal of a dynamic system (and nothing
    // off it), so that system stays definite
    ENSURE(hs_fem_held_nodes(fem) == n);
    // the rest-state assembly too (it has no locking-free form: a second model without it)
    cfg c2 = {"cor", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 0};
    hs_fem_def def2 = make_def(&c2, 1e4, 0.45);
    def2.material.density_kg_m3 = 960;
    hs_fem* fem2 = NULL;
    ENSURE(hs_fem_create(&b.mesh, &def2, dof, 3 * n, &fem2, NULL) == HS_OK);
    for (int e = 0; e < b.mesh.n_tets; e++) hs_fem_set_element_active(fem2, e, 0);
    ENSURE(hs_fem_held_nodes(fem2) == n);
    hs_csc* a2 = NULL;
    ENSURE(hs_fem_create_matrix(fem2, &a2) == HS_OK);
    for (int pass = 0; pass < 2; pass++) {
        hs_csc* ap = pass == 0 ? a : a2;
        if (pass == 0)
            hs_fem_assemble(fem, 1.0, 1.0, ap);
        else
            ENSURE(hs_fem_assemble_rest(fem2, 1.0, 1.0, ap) == HS_OK);
        int diag_pos = 0;
        for (int j = 0; j < ap->n; j++)
            for (int p = ap->colp[j]; p < ap->colp[j + 1]; p++) {
                if (ap->rowi[p] == j)
                    diag_pos += ap->val[p] > 0;
                else
                    ENSURE(ap->val[p] == 0);
            }
        ENSURE(diag_pos == 3 * n);
    }
    hs_csc_destroy(&a2);
    hs_fem_destroy(&fem2);
    // one element back: its nodes have mass again and hold none; forces are its own and sum
    // to zero
    hs_fem_set_element_active(fem, 7, 1);
    ENSURE(hs_fem_held_nodes(fem) == n - 4);
    hs_fem_update(fem, x, &st);
    hs_fem_forces(fem, f);
    ENSURE(vnorm(f, 3 * n) > 0);
    double fs[3] = {0, 0, 0};
    for (int i = 0; i < n; i++)
        for (int k = 0; k < 3; k++) fs[k] += f[3 * i + k];
    ENSURE_SMALL(vnorm(fs, 3), 1e-12 * vnorm(f, 3 * n));
    int nz = 0;
    for (int i = 0; i < n; i++) nz += vnorm(f + 3 * i, 3) > 0;
    ENSURE(nz <= 4);
    free(x);
    free(f);
    hs_csc_destroy(&a);
    hs_fem_destroy(&fem);
    free(dof);
    box_free(&b);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

/// update / forces / assemble / apply_tangent never allocate; constrained dofs drop out of the
/// matrix consistently with apply_tangent.
static int test_no_alloc(void) {
    int64_t bytes0 = hs_byte_count();
    box b;
    box_make(&b, 0.1, 0.05, 0.05, 4, 2, 2);
    int n = b.mesh.n_nodes, nd = 3 * n;
    int* dof = malloc(sizeof(int) * nd);
    int* full = malloc(sizeof(int) * nd);
    int nf = 0;
    // free indices in reverse node order, to check the map is honoured
    for (int v = n - 1; v >= 0; v--)
        for (int i = 0; i < 3; i++) dof[3 * v + i] = b.mesh.x0[3 * v] < 1e-12 ? -1 : nf++;
    for (int d = 0; d < nd; d++)
        if (dof[d] >= 0) full[dof[d]] = d;
    double* x = malloc(sizeof(double) * nd);
    double* f = malloc(sizeof(double) * nd);
    double* u = calloc(nd, sizeof(double));
    double* y = malloc(sizeof(double) * nd);
    double* uf = malloc(sizeof(double) * nf);
    double* yf = malloc(sizeof(double) * nf);
    uint64_t s = 9;
    for (int c = 0; c < N_CFGS; c++) {
        hs_fem_def def = make_def(&k_cfgs[c], 1e4, 0.45);
        hs_fem* fem = NULL;
        hs_csc* a = NULL;
        ENSURE(hs_fem_create(&b.mesh, &def, dof, nf, &fem, NULL) == HS_OK);
        ENSURE(hs_fem_create_matrix(fem, &a) == HS_OK);
        ENSURE(a->n == nf);
        perturbed(&b.mesh, 0.002, NULL, 3, x);
        int64_t calls = hs_alloc_calls();
        hs_fem_stats st;
        for (int rep = 0; rep < 3; rep++) {
            hs_fem_update(fem, x, &st);
            hs_fem_forces(fem, f);
            hs_fem_assemble(fem, 0.5, 2.0, a);
            hs_fem_apply_tangent(fem, x, y);
            double r[9];
            hs_fem_node_rotation(fem, 3, r);
            hs_fem_set_element_active(fem, 2, rep % 2);
        }
        hs_fem_set_element_active(fem, 2, 1);
        ENSURE(hs_alloc_calls() == calls);
        // assembled matrix on free dofs == 0.5 K + 2 M restricted
        hs_fem_update(fem, x, &st);
        hs_fem_assemble(fem, 0.5, 2.0, a);
        for (int i = 0; i < nf; i++) uf[i] = 2 * urand(&s) - 1;
        memset(u, 0, sizeof(double) * nd);
        for (int i = 0; i < nf; i++) u[full[i]] = uf[i];
        hs_fem_apply_tangent(fem, u, y);
        hs_csc_spmv(a, uf, yf);
        const double* m = hs_fem_lumped_mass(fem);
        double ym = vnorm(yf, nf);
        for (int i = 0; i < nf; i++)
            ENSURE_SMALL(yf[i] - (0.5 * y[full[i]] + 2.0 * m[full[i] / 3] * uf[i]), 1e-10 * ym);
        hs_csc_destroy(&a);
        hs_fem_destroy(&fem);
    }
    free(x);
    free(f);
    free(u);
    free(y);
    free(uf);
    free(yf);
    free(dof);
    free(full);
    box_free(&b);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

/// Bad input gives an error (no crash, no leak); allocation failures unwind cleanly.
static int test_errors(void) {
    int64_t bytes0 = hs_byte_count();
    box b;
    box_make(&b, 1, 1, 1, 2, 1, 1);
    int n = b.mesh.n_nodes;
    int* dof = dofs_all(n);
    hs_fem* fem = NULL;
    hs_err err;
    hs_fem_def def;
    memset(&def, 0, sizeof def);
    ENSURE(hs_fem_create(&b.mesh, &def, dof, 3 * n, &fem, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "hs_fem_default_def") != NULL);
    def = hs_fem_default_def();
    def.material.poisson = 0.5;
    ENSURE(hs_fem_create(&b.mesh, &def, dof, 3 * n, &fem, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "Poisson") != NULL);
    def = hs_fem_default_def();
    dof[5] = 4; // repeated
    ENSURE(hs_fem_create(&b.mesh, &def, dof, 3 * n, &fem, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "dof_map[5]") != NULL);
    dof[5] = 5;
    int sw = b.mesh.tets[4 * 3 + 1];
    b.mesh.tets[4 * 3 + 1] = b.mesh.tets[4 * 3 + 2];
    b.mesh.tets[4 * 3 + 2] = sw;
    ENSURE(hs_fem_create(&b.mesh, &def, dof, 3 * n, &fem, &err) == HS_ERR_INVALID);
    ENSURE(strstr(err.msg, "tet 3") != NULL);
    b.mesh.tets[4 * 3 + 2] = b.mesh.tets[4 * 3 + 1];
    b.mesh.tets[4 * 3 + 1] = sw;
    b.mesh.tets[7] = n;
    ENSURE(hs_fem_create(&b.mesh, &def, dof, 3 * n, &fem, &err) == HS_ERR_INVALID);
    ENSURE(fem == NULL);
    ENSURE(hs_byte_count() == bytes0);
    // restore the mesh (re-make) and inject allocation failures at every point of create
    box_free(&b);
    box_make(&b, 1, 1, 1, 2, 1, 1);
    def.model = HS_MODEL_COROTATED;
    def.locking_free = 1;
    int failures = 0;
    for (int k = 1; k < 200; k++) {
        hs_alloc_fail_after(k);
        hs_status st = hs_fem_create(&b.mesh, &def, dof, 3 * n, &fem, &err);
        hs_alloc_fail_after(0);
        if (st == HS_OK) {
            hs_fem_destroy(&fem);
            break;
        }
        ENSURE(st == HS_ERR_NOMEM);
        ENSURE(fem == NULL);
        ENSURE(hs_byte_count() == bytes0);
        failures++;
    }
    ENSURE(failures > 10);
    hs_fem_destroy(&fem); // NULL is fine
    free(dof);
    box_free(&b);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

/// Unstructured meshes (bundled liver, shared meshes) through the mesh loader: affine patch test on
/// the interior vertices, zero force under a rigid rotation, lumped mass = density * volume, for
/// co-rotated with and without ANP and for StVK.
static int test_shared_meshes(void) {
    int64_t bytes0 = hs_byte_count();
    // the bundled liver always; the shared meshes when the folder is there
    const char* names[] = {"scenes/liver/liver2.msh", "liver_coarse.msh", "aneurysm_vessel.msh"};
    int loaded = 0;
    for (int k = 0; k < 3; k++) {
        char path[512];
        snprintf(path, sizeof path, "%s/%s", k == 0 ? HS_SOURCE_DIR : HS_SHARED_MESHES, names[k]);
        hs_mesh* mesh = NULL;
        hs_err err;
        hs_status ls = hs_mesh_load(path, &mesh, &err);
        if (ls < 0) {
            printf("  skipped %s: %s\n", names[k], err.msg);
            continue;
        }
        loaded++;
        int n = mesh->n_nodes;
        int* dof = dofs_all(n);
        double* x = malloc(sizeof(double) * 3 * n);
        double* f = malloc(sizeof(double) * 3 * n);
        double L = 0;
        for (int c = 0; c < 3; c++) L = fmax(L, mesh->bbox_max[c] - mesh->bbox_min[c]);
        static const cfg cs[] = {{"corot", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 0},
                                 {"corot-anp", HS_MODEL_COROTATED, HS_ROTATION_POLAR, 1},
                                 {"stvk", HS_MODEL_STVK, HS_ROTATION_POLAR, 0}};
        for (int c = 0; c < 3; c++) {
            hs_fem_def def = make_def(&cs[c], 3000, 0.49);
            def.material.density_kg_m3 = 1060;
            hs_fem* fem = NULL;
            ENSURE(hs_fem_create(mesh, &def, dof, 3 * n, &fem, &err) == HS_OK);
            double msum = 0;
            const double* ms = hs_fem_lumped_mass(fem);
            for (int i = 0; i < n; i++) msum += ms[i];
            ENSURE_NEAR(msum, 1060 * mesh->volume, 1e-9 * 1060 * mesh->volume);
            // affine: stretch + shear + rotation; interior vertices feel no force
            double A0[9] = {1.05, 0.02, 0.0, -0.03, 0.97, 0.04, 0.01, 0.0, 1.02}, R[9], A[9];
            double ax[3] = {0.0, 0.6, 0.8};
            rot_axis(ax, 0.8, R);
            for (int rigid = 0; rigid < 2; rigid++) {
                if (rigid)
                    memcpy(A, R, sizeof A);
                else
                    mat3_mul(R, A0, A);
                for (int v = 0; v < n; v++)
                    for (int i = 0; i < 3; i++)
                        x[3 * v + i] = A[3 * i] * mesh->x0[3 * v] +
                                       A[3 * i + 1] * mesh->x0[3 * v + 1] +
                                       A[3 * i + 2] * mesh->x0[3 * v + 2] + 0.1 * L;
                hs_fem_stats st;
                hs_fem_update(fem, x, &st);
                hs_fem_forces(fem, f);
                double fint = 0, fall = 0;
                for (int v = 0; v < n; v++) {
                    double fv = vnorm(f + 3 * v, 3);
                    fall = fmax(fall, fv);
                    if (mesh->node_surf[v] < 0 && mesh->node_used[v]) fint = fmax(fint, fv);
                }
                // force scale: 1 % strain on a face of the mean element size
                double h = cbrt(mesh->volume / mesh->n_tets), fscale = 3000 * 0.01 * h * h;
                if (rigid) {
                    ENSURE_SMALL(fall / fscale, 1e-6);
                } else {
                    ENSURE(fall > fscale);
                    if (!(fint <= 1e-9 * fall))
                        printf("  %s %s: interior %g of %g\n", names[k], cs[c].name, fint, fall);
                    ENSURE(fint <= 1e-9 * fall);
                }
                ENSURE(st.inverted == 0);
            }
            hs_fem_destroy(&fem);
        }
        printf("  %s: %d nodes, %d tets, volume %.4g m^3: ok\n", names[k], n, mesh->n_tets,
               mesh->volume);
        free(x);
        free(f);
        free(dof);
        hs_mesh_destroy(&mesh);
    }
    ENSURE(loaded > 0);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

static int64_t cpu_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (int64_t)ts.tv_sec * 1000000000 + ts.tv_nsec;
}

/// Timing of a co-rotated update + assemble on a ~10k-tet cantilever (printed, not asserted).
static int test_timing(void) {
    int64_t bytes0 = hs_byte_count();
    box b;
    box_make(&b, 0.1, 0.02, 0.02, 40, 8, 6); // 11520 tets
    int n = b.mesh.n_nodes;
    int* dof = malloc(sizeof(int) * 3 * n);
    int nf = 0;
    for (int d = 0; d < 3 * n; d++) dof[d] = b.mesh.x0[3 * (d / 3)] < 1e-12 ? -1 : nf++;
    double* x = malloc(sizeof(double) * 3 * n);
    double R[9];
    for (int c = 0; c < N_CFGS; c++) {
        if (k_cfgs[c].model == HS_MODEL_STVK && k_cfgs[c].anp) continue;
        hs_fem_def def = make_def(&k_cfgs[c], 1e4, 0.45);
        def.polar_tol = 1e-6;
        hs_fem* fem = NULL;
        hs_csc* a = NULL;
        ENSURE(hs_fem_create(&b.mesh, &def, dof, nf, &fem, NULL) == HS_OK);
        ENSURE(hs_fem_create_matrix(fem, &a) == HS_OK);
        int reps = 20;
        int64_t tu = 0, ta = 0;
        hs_fem_stats st;
        for (int r = 0; r < reps; r++) {
            // a slowly bending, rotating configuration (the warm start sees small steps)
            rot_z(0.01 * r, R);
            for (int v = 0; v < n; v++) {
                const double* p = b.mesh.x0 + 3 * v;
                double bend = 0.2 * p[0] * p[0];
                for (int i = 0; i < 3; i++)
                    x[3 * v + i] = R[3 * i] * p[0] + R[3 * i + 1] * p[1] + R[3 * i + 2] * p[2];
                x[3 * v + 2] -= bend * (1 + 0.02 * r);
            }
            int64_t t0 = cpu_ns();
            hs_fem_update(fem, x, &st);
            int64_t t1 = cpu_ns();
            hs_fem_assemble(fem, 1.0, 100.0, a);
            int64_t t2 = cpu_ns();
            if (r >= 2) {
                tu += t1 - t0;
                ta += t2 - t1;
            }
        }
        ENSURE(st.inverted == 0);
        int pmax = st.polar_iters_max;
        // the same configuration again (a converged Newton iterate): no polar iterations
        int64_t ts = 0;
        for (int r = 0; r < 5; r++) {
            int64_t t0 = cpu_ns();
            hs_fem_update(fem, x, &st);
            ts += cpu_ns() - t0;
        }
        if (k_cfgs[c].model == HS_MODEL_COROTATED && k_cfgs[c].rot == HS_ROTATION_POLAR)
            ENSURE(st.polar_iters_max == 0);
        printf("  %-12s %d tets (thread CPU ms): update %.3f (unchanged x %.3f), assemble %.3f "
               "(nnz %d, polar iters max %d)\n",
               k_cfgs[c].name, b.mesh.n_tets, tu / 1e6 / (reps - 2), ts / 1e6 / 5,
               ta / 1e6 / (reps - 2), a->nnz, pmax);
        hs_csc_destroy(&a);
        hs_fem_destroy(&fem);
    }
    free(x);
    free(dof);
    box_free(&b);
    ENSURE(hs_byte_count() == bytes0);
    return 0;
}

// Nodes no tet uses (a body fixes them) have a ring of their own only: 60 of them beside one tet
// overran build_rings' scratch array (ASan: heap-buffer-overflow), which sized it by tets alone.
static int test_unused_nodes(void) {
    enum { N = 64 };
    double x[3 * N] = {0}, xs[3 * N], f[3 * N];
    x[3] = x[7] = x[11] = 0.01; // nodes 0-3: a 1 cm corner tet; the rest unused
    for (int i = 4; i < N; i++) {
        x[3 * i] = 0.02 + 0.01 * i;
        x[3 * i + 1] = x[3 * i + 2] = 0.02;
    }
    int tets[4] = {0, 1, 2, 3}, dof[3 * N];
    for (int k = 0; k < 3 * N; k++) dof[k] = k;
    for (int anp = 0; anp < 2; anp++) {
        hs_mesh* mesh = NULL;
        ENSURE(hs_mesh_create(N, x, 1, tets, &mesh, NULL) == HS_OK);
        hs_fem_def def = hs_fem_default_def();
        def.model = HS_MODEL_COROTATED;
        def.locking_free = anp;
        hs_fem* fem = NULL;
        ENSURE(hs_fem_create(mesh, &def, dof, 3 * N, &fem, NULL) == HS_OK);
        memcpy(xs, x, sizeof xs);
        xs[3] += 0.001; // stretch along x by 10 %
        hs_fem_update(fem, xs, NULL);
        hs_fem_forces(fem, f);
        ENSURE(f[3] < 0); // pulls node 1 back
        for (int k = 12; k < 3 * N; k++) ENSURE(f[k] == 0.0);
        hs_csc* a = NULL;
        ENSURE(hs_fem_create_matrix(fem, &a) == HS_OK);
        hs_csc_destroy(&a);
        hs_fem_destroy(&fem);
        hs_mesh_destroy(&mesh);
    }
    return 0;
}

HS_TEST_MAIN(HS_CASE(test_patch), HS_CASE(test_rigid_rotation), HS_CASE(test_tangent_fd),
             HS_CASE(test_corot_tangent), HS_CASE(test_polar), HS_CASE(test_polar_batched),
             HS_CASE(test_element_pass), HS_CASE(test_locking), HS_CASE(test_inversion),
             HS_CASE(test_inversion_dynamic), HS_CASE(test_mass_and_active), HS_CASE(test_no_alloc),
             HS_CASE(test_errors), HS_CASE(test_unused_nodes), HS_CASE(test_shared_meshes),
             HS_CASE(test_timing))
