// SPDX-License-Identifier: GPL-2.0-or-later
// Nearly incompressible Mooney-Rivlin reference solver: P1 displacement / P0 pressure tets,
// perturbed Lagrange multiplier with face-jump pressure stabilisation, total Lagrangian Newton.
//
// Per element e (volume V, constant F, J = det F, one pressure p_e):
//   Pi(u, p) = sum_e V W_iso(F) + sum_e p_e V (J - 1) - 1/2 p^T A p - f_ext . u,
//   A = (diag(V) + beta L) / kappa, L the face graph Laplacian with weights h_f area_f.
// The pressure equation A p = V (J - 1) is linear in p, so after every Newton update the
// pressures are recomputed from it exactly (A is constant: total Lagrangian). The linearised
// coupled system then reduces to the displacement Schur complement
//   S = K(u, p) + B^T A^-1 B,   B_e = d(V (J - 1)) / du,
// which is symmetric positive definite at a stable state. With beta = 0, A = A0 = diag(V)/kappa
// and S is an ordinary sparse matrix (static condensation), solved by one Cholesky. With
// beta > 0, A^-1 couples all pressures (S is dense), so we factorise instead the sparse SPD
// augmented system over (du, q), q one unknown per interior face (A = A0 + E^T W E, E the
// face-element incidence, W the face weights beta h_f area_f / kappa):
//   [ K + B^T A0^-1 B      -B^T A0^-1 E^T     ] [du]   [r]
//   [ -E A0^-1 B        W^-1 + E A0^-1 E^T   ] [q ] = [0]
// whose Schur complement on du is exactly S (Woodbury); see docs/mooney.md.
#include "mooney.h"
#include "fem_internal.h"
#include "sparse.h"

#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define HS_MOONEY_COOKIE 0x6d6f6f6e

struct hs_mooney {
    const hs_mesh* mesh;
    hs_mooney_def def;
    double c1, c2, kappa;
    int n, nt, n_free;
    int* dof_map;      // [3n] free index or -1
    double* grad;      // [12 nt] reference shape gradients g_a, a = 0..3
    double* vol;       // [nt] rest volumes
    int n_faces;       // interior faces
    int* face_tet;     // [2 n_faces]
    double* face_area; // [n_faces] rest area
    double* face_w;    // [n_faces] h_f * area_f
    hs_csc* amat;      // pressure matrix (beta > 0 only)
    hs_cholesky* afac; // its factor
    hs_csc* kmat;      // condensed (beta = 0) or augmented (beta > 0) tangent
    hs_cholesky* kfac; // its factor (created at the first Newton step)
    int n_k;           // kmat size: n_free, plus n_faces when beta > 0
    int* kmap;         // [144 nt] position of (a i, b k) in kmat->val or -1
    int* fmap;         // [48 n_faces] positions of (dof, face) and (face, dof), beta > 0
    double* kconst;    // [nnz] constant face-face block of the augmented matrix, beta > 0
    // loads
    double* f_nodal; // [3n] user forces
    double* f_grav;  // [3n] lumped gravity
    double* f_prev;  // [3n] external load applied at the last converged state
    double* up_new;  // [3n] prescribed displacement (fixed dofs)
    double* up_prev; // [3n] prescribed displacement at the last converged state
    // state and per-element data of the last update
    double* u;    // [3n]
    double* p;    // [nt]
    double* fdef; // [9 nt] deformation gradients
    double* jac;  // [nt]
    double* wiso; // [nt] isochoric energy density
    double* ke;   // [144 nt] element tangents at fixed p
    double* be;   // [12 nt] d(V (J - 1)) / du
    double* q;    // [3n] internal forces
    // work
    double *r, *du, *u_old, *gap, *fext, *t0, *t1, *t2, *t3, *u_conv; // [3n]
    double *g, *g2, *g3;                                              // [nt] V (J - 1), work, work
    double *bf, *xf;                                                  // [n_k]
    double elem_force_scale; // N, RMS-sum of element nodal forces before assembly (round-off)
};

hs_mooney_def hs_mooney_default_def(void) {
    hs_mooney_def d;
    memset(&d, 0, sizeof d);
    d.youngs_pa = 3000.0;
    d.poisson = 0.45;
    d.density_kg_m3 = 1000.0;
    d.beta = 0.0;
    d.tolerance = 1e-8;
    d.max_newton_iter = 30;
    d.load_steps = 1;
    d.max_bisections = 10;
    d.cookie = HS_MOONEY_COOKIE;
    return d;
}

void hs_mooney_constants(const hs_mooney_def* def, double* c1, double* c2, double* kappa) {
    double e = def->youngs_pa, nu = def->poisson;
    double c = e / (8.0 * (1.0 + nu));
    if (c1) *c1 = c;
    if (c2) *c2 = c;
    if (kappa) *kappa = e / (3.0 * (1.0 - 2.0 * nu));
}

// ---------------------------------------------------------------------------------------------
// Small dense helpers (row-major 3x3)

static double det3(const double* a) {
    return a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6]) +
           a[2] * (a[3] * a[7] - a[4] * a[6]);
}

// Inverse transpose H = F^-T, given det.
static void inv_transpose3(const double* a, double det, double* h) {
    double id = 1.0 / det;
    // cofactor matrix divided by det equals the inverse transpose
    h[0] = (a[4] * a[8] - a[5] * a[7]) * id;
    h[1] = -(a[3] * a[8] - a[5] * a[6]) * id;
    h[2] = (a[3] * a[7] - a[4] * a[6]) * id;
    h[3] = -(a[1] * a[8] - a[2] * a[7]) * id;
    h[4] = (a[0] * a[8] - a[2] * a[6]) * id;
    h[5] = -(a[0] * a[7] - a[1] * a[6]) * id;
    h[6] = (a[1] * a[5] - a[2] * a[4]) * id;
    h[7] = -(a[0] * a[5] - a[2] * a[3]) * id;
    h[8] = (a[0] * a[4] - a[1] * a[3]) * id;
}

double hs_mooney_pk1(double c1, double c2, double p, const double f[9], double pk1[9], double* a) {
    double cm[9], bm[9], fc[9], h[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double sc = 0, sb = 0;
            for (int k = 0; k < 3; k++) {
                sc += f[k * 3 + i] * f[k * 3 + j];
                sb += f[i * 3 + k] * f[j * 3 + k];
            }
            cm[i * 3 + j] = sc;
            bm[i * 3 + j] = sb;
        }
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double s = 0;
            for (int k = 0; k < 3; k++) s += f[i * 3 + k] * cm[k * 3 + j];
            fc[i * 3 + j] = s;
        }
    double i1 = cm[0] + cm[4] + cm[8];
    double trc2 = 0;
    for (int k = 0; k < 9; k++) trc2 += cm[k] * cm[k];
    double i2 = 0.5 * (i1 * i1 - trc2);
    double jd = det3(f);
    inv_transpose3(f, jd, h);
    double j23 = 1.0 / (cbrt(jd) * cbrt(jd)); // J^-2/3
    double j43 = j23 * j23;                   // J^-4/3
    for (int k = 0; k < 9; k++) {
        pk1[k] = c1 * j23 * (2.0 * f[k] - (2.0 / 3.0) * i1 * h[k]) +
                 c2 * j43 * (2.0 * i1 * f[k] - 2.0 * fc[k] - (4.0 / 3.0) * i2 * h[k]) +
                 p * jd * h[k];
    }
    if (a) {
        for (int i = 0; i < 3; i++)
            for (int jj = 0; jj < 3; jj++) {
                int ij = i * 3 + jj;
                double p1 = 2.0 * f[ij] - (2.0 / 3.0) * i1 * h[ij];
                double p2 = 2.0 * i1 * f[ij] - 2.0 * fc[ij] - (4.0 / 3.0) * i2 * h[ij];
                for (int k = 0; k < 3; k++)
                    for (int l = 0; l < 3; l++) {
                        int kl = k * 3 + l;
                        double dik = i == k ? 1.0 : 0.0, djl = jj == l ? 1.0 : 0.0;
                        double hil_hkj = h[i * 3 + l] * h[k * 3 + jj];
                        double a1 = -(2.0 / 3.0) * h[kl] * p1 + 2.0 * dik * djl -
                                    (4.0 / 3.0) * f[kl] * h[ij] + (2.0 / 3.0) * i1 * hil_hkj;
                        double a2 = -(4.0 / 3.0) * h[kl] * p2 + 4.0 * f[kl] * f[ij] +
                                    2.0 * i1 * dik * djl -
                                    2.0 * (dik * cm[l * 3 + jj] + f[i * 3 + l] * f[k * 3 + jj] +
                                           bm[i * 3 + k] * djl) -
                                    (8.0 / 3.0) * (i1 * f[kl] - fc[kl]) * h[ij] +
                                    (4.0 / 3.0) * i2 * hil_hkj;
                        double av = p * jd * (h[kl] * h[ij] - hil_hkj);
                        a[ij * 9 + kl] = c1 * j23 * a1 + c2 * j43 * a2 + av;
                    }
            }
    }
    return c1 * (j23 * i1 - 3.0) + c2 * (j43 * i2 - 3.0);
}

static int mooney_update(hs_mooney* m, int tangent);
static void assemble_tangent(hs_mooney* m);

// ---------------------------------------------------------------------------------------------
// Set-up

typedef struct face_key {
    int v[3];
    int tet;
} face_key;

static int cmp_face(const void* pa, const void* pb) {
    const face_key* a = pa;
    const face_key* b = pb;
    for (int k = 0; k < 3; k++)
        if (a->v[k] != b->v[k]) return a->v[k] < b->v[k] ? -1 : 1;
    return (a->tet > b->tet) - (a->tet < b->tet);
}

static void sort3(int* v) {
    int t;
    if (v[0] > v[1]) t = v[0], v[0] = v[1], v[1] = t;
    if (v[1] > v[2]) t = v[1], v[1] = v[2], v[2] = t;
    if (v[0] > v[1]) t = v[0], v[0] = v[1], v[1] = t;
}

static double tri_area(const double* x, const int* v) {
    const double* a = x + 3 * v[0];
    const double* b = x + 3 * v[1];
    const double* c = x + 3 * v[2];
    double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                   e1[0] * e2[1] - e1[1] * e2[0]};
    return 0.5 * sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
}

// Mean edge length: the local element size h of the stabilisation term.
static double tet_size(const double* x, const int* t) {
    double s = 0;
    for (int a = 0; a < 4; a++)
        for (int b = a + 1; b < 4; b++) {
            const double* p = x + 3 * t[a];
            const double* q = x + 3 * t[b];
            s += sqrt((p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]) +
                      (p[2] - q[2]) * (p[2] - q[2]));
        }
    return s / 6.0;
}

static hs_status build_faces(hs_mooney* m, hs_err* err) {
    const hs_mesh* mesh = m->mesh;
    int nt = m->nt;
    face_key* keys = hs_alloc(sizeof(face_key) * 4 * (size_t)nt);
    double* hsz = hs_alloc(sizeof(double) * (size_t)nt);
    if (!keys || !hsz) {
        hs_free(keys);
        hs_free(hsz);
        return hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory (faces)", __FILE__, __LINE__);
    }
    static const int fv[4][3] = {{1, 2, 3}, {0, 2, 3}, {0, 1, 3}, {0, 1, 2}};
    for (int e = 0; e < nt; e++) {
        const int* t = mesh->tets + 4 * e;
        hsz[e] = tet_size(mesh->x0, t);
        for (int f = 0; f < 4; f++) {
            face_key* k = &keys[4 * e + f];
            for (int c = 0; c < 3; c++) k->v[c] = t[fv[f][c]];
            sort3(k->v);
            k->tet = e;
        }
    }
    qsort(keys, 4 * (size_t)nt, sizeof(face_key), cmp_face);
    int nf = 0;
    for (int i = 0; i + 1 < 4 * nt; i++)
        if (memcmp(keys[i].v, keys[i + 1].v, sizeof keys[i].v) == 0) nf++, i++;
    m->n_faces = nf;
    m->face_tet = hs_alloc(sizeof(int) * 2 * (size_t)(nf > 0 ? nf : 1));
    m->face_area = hs_alloc(sizeof(double) * (size_t)(nf > 0 ? nf : 1));
    m->face_w = hs_alloc(sizeof(double) * (size_t)(nf > 0 ? nf : 1));
    hs_status st = HS_OK;
    if (!m->face_tet || !m->face_area || !m->face_w) {
        st = hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory (faces)", __FILE__, __LINE__);
    } else {
        int f = 0;
        for (int i = 0; i + 1 < 4 * nt; i++) {
            if (memcmp(keys[i].v, keys[i + 1].v, sizeof keys[i].v) != 0) continue;
            if (i + 2 < 4 * nt && memcmp(keys[i].v, keys[i + 2].v, sizeof keys[i].v) == 0) {
                st = hs_err_set(err, HS_ERR_INVALID,
                                "%s:%d: face (%d %d %d) is shared by more than two tets "
                                "(non-manifold mesh)",
                                __FILE__, __LINE__, keys[i].v[0], keys[i].v[1], keys[i].v[2]);
                break;
            }
            int a = keys[i].tet, b = keys[i + 1].tet;
            m->face_tet[2 * f] = a;
            m->face_tet[2 * f + 1] = b;
            m->face_area[f] = tri_area(mesh->x0, keys[i].v);
            m->face_w[f] = 0.5 * (hsz[a] + hsz[b]) * m->face_area[f];
            f++;
            i++;
        }
    }
    hs_free(keys);
    hs_free(hsz);
    return st;
}

// Pressure matrix A = (diag(V) + beta L) / kappa, full pattern, for beta > 0.
static hs_status build_pressure_matrix(hs_mooney* m, hs_err* err) {
    int nt = m->nt, nf = m->n_faces;
    hs_csc* a = m->amat = hs_calloc(1, sizeof *a);
    int* cnt = hs_calloc((size_t)nt + 1, sizeof(int));
    if (!a || !cnt) goto nomem;
    a->n = nt;
    a->nnz = nt + 2 * nf;
    a->colp = hs_alloc(sizeof(int) * ((size_t)nt + 1));
    a->rowi = hs_alloc(sizeof(int) * (size_t)a->nnz);
    a->val = hs_calloc((size_t)a->nnz, sizeof(double));
    if (!a->colp || !a->rowi || !a->val) goto nomem;
    for (int f = 0; f < nf; f++) cnt[m->face_tet[2 * f]]++, cnt[m->face_tet[2 * f + 1]]++;
    a->colp[0] = 0;
    for (int e = 0; e < nt; e++) a->colp[e + 1] = a->colp[e] + cnt[e] + 1;
    for (int e = 0; e < nt; e++) {
        a->rowi[a->colp[e]] = e;
        cnt[e] = 1;
    }
    for (int f = 0; f < nf; f++) {
        int x = m->face_tet[2 * f], y = m->face_tet[2 * f + 1];
        a->rowi[a->colp[x] + cnt[x]++] = y;
        a->rowi[a->colp[y] + cnt[y]++] = x;
    }
    for (int e = 0; e < nt; e++) {
        int s = a->colp[e], len = a->colp[e + 1] - s;
        // insertion sort: a column has at most 5 entries
        for (int i = 1; i < len; i++) {
            int v = a->rowi[s + i], j = i - 1;
            while (j >= 0 && a->rowi[s + j] > v) a->rowi[s + j + 1] = a->rowi[s + j], j--;
            a->rowi[s + j + 1] = v;
        }
    }
    double ik = 1.0 / m->kappa, bk = m->def.beta / m->kappa;
    for (int e = 0; e < nt; e++) a->val[hs_csc_find(a, e, e)] += m->vol[e] * ik;
    for (int f = 0; f < nf; f++) {
        int x = m->face_tet[2 * f], y = m->face_tet[2 * f + 1];
        double w = bk * m->face_w[f];
        a->val[hs_csc_find(a, x, x)] += w;
        a->val[hs_csc_find(a, y, y)] += w;
        a->val[hs_csc_find(a, x, y)] -= w;
        a->val[hs_csc_find(a, y, x)] -= w;
    }
    hs_free(cnt);
    hs_status st = hs_cholesky_create(a, &m->afac, err);
    if (st != HS_OK)
        return hs_err_set(err, st, "%s:%d: pressure matrix factorisation failed: %s", __FILE__,
                          __LINE__, hs_status_str(st));
    return HS_OK;
nomem:
    hs_free(cnt);
    return hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory (pressure matrix)", __FILE__,
                      __LINE__);
}

static int cmp_i64(const void* pa, const void* pb) {
    int64_t a = *(const int64_t*)pa, b = *(const int64_t*)pb;
    return (a > b) - (a < b);
}

// Pattern of the augmented beta > 0 system: free dofs first, then one unknown per interior
// face. Couplings: dofs of a tet among themselves, a face with the dofs of its two tets, and
// faces that share a tet. Fills *tet_faces_out ([4 nt] interior faces per tet, -1 padded).
static hs_status build_augmented_pattern(hs_mooney* m, int** tet_faces_out, hs_err* err) {
    const int* tets = m->mesh->tets;
    int nt = m->nt, nf = m->n_faces, nk = m->n_k;
    int* tf = hs_alloc(sizeof(int) * 4 * (size_t)nt);
    size_t cap = 144 * (size_t)nt + 96 * (size_t)nf + 16 * (size_t)nt;
    int64_t* key = hs_alloc(sizeof(int64_t) * cap);
    hs_csc* a = m->kmat = hs_calloc(1, sizeof *a);
    *tet_faces_out = tf;
    if (!tf || !key || !a) goto nomem;
    for (int k = 0; k < 4 * nt; k++) tf[k] = -1;
    for (int f = 0; f < nf; f++)
        for (int s = 0; s < 2; s++) {
            int* slot = tf + 4 * m->face_tet[2 * f + s];
            while (*slot >= 0) slot++;
            *slot = f;
        }
    size_t nkey = 0;
#define PUSH(r, c) key[nkey++] = (int64_t)(c)*nk + (r)
    int dofs[12];
    for (int e = 0; e < nt; e++) {
        for (int r = 0; r < 12; r++) dofs[r] = m->dof_map[3 * tets[4 * e + r / 3] + r % 3];
        for (int r = 0; r < 12; r++)
            for (int c = 0; c < 12; c++)
                if (dofs[r] >= 0 && dofs[c] >= 0) PUSH(dofs[r], dofs[c]);
        for (int x = 0; x < 4 && tf[4 * e + x] >= 0; x++)
            for (int y = 0; y < 4 && tf[4 * e + y] >= 0; y++)
                PUSH(m->n_free + tf[4 * e + x], m->n_free + tf[4 * e + y]);
    }
    for (int f = 0; f < nf; f++)
        for (int s = 0; s < 2; s++) {
            int e = m->face_tet[2 * f + s];
            for (int r = 0; r < 12; r++) {
                int d = m->dof_map[3 * tets[4 * e + r / 3] + r % 3];
                if (d < 0) continue;
                PUSH(d, m->n_free + f);
                PUSH(m->n_free + f, d);
            }
        }
#undef PUSH
    qsort(key, nkey, sizeof(int64_t), cmp_i64);
    size_t nu = 0;
    for (size_t k = 0; k < nkey; k++)
        if (nu == 0 || key[nu - 1] != key[k]) key[nu++] = key[k];
    if (nu > (size_t)INT32_MAX) {
        hs_free(key);
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: augmented system too large", __FILE__,
                          __LINE__);
    }
    a->n = nk;
    a->nnz = (int)nu;
    a->colp = hs_calloc((size_t)nk + 1, sizeof(int));
    a->rowi = hs_alloc(sizeof(int) * (nu > 0 ? nu : 1));
    a->val = hs_calloc(nu > 0 ? nu : 1, sizeof(double));
    m->kconst = hs_calloc(nu > 0 ? nu : 1, sizeof(double));
    m->fmap = hs_alloc(sizeof(int) * 48 * (size_t)(nf > 0 ? nf : 1));
    if (!a->colp || !a->rowi || !a->val || !m->kconst || !m->fmap) goto nomem;
    for (size_t k = 0; k < nu; k++) {
        int c = (int)(key[k] / nk);
        a->rowi[k] = (int)(key[k] % nk);
        a->colp[c + 1]++;
    }
    for (int c = 0; c < nk; c++) a->colp[c + 1] += a->colp[c];
    hs_free(key);
    return HS_OK;
nomem:
    hs_free(key);
    return hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory (augmented pattern)", __FILE__,
                      __LINE__);
}

static hs_status build_stiffness_pattern(hs_mooney* m, hs_err* err) {
    const hs_mesh* mesh = m->mesh;
    int* tf = NULL;
    hs_status st;
    if (m->def.beta > 0)
        st = build_augmented_pattern(m, &tf, err);
    else
        st = hs_csc_create_block_pattern(m->n, mesh->node_nbr_start, mesh->node_nbr, m->dof_map,
                                         m->n_free, &m->kmat, err);
    if (st != HS_OK) {
        hs_free(tf);
        return st;
    }
    for (int e = 0; e < m->nt; e++) {
        const int* t = mesh->tets + 4 * e;
        for (int r = 0; r < 12; r++)
            for (int c = 0; c < 12; c++) {
                int dr = m->dof_map[3 * t[r / 3] + r % 3], dc = m->dof_map[3 * t[c / 3] + c % 3];
                int pos = (dr >= 0 && dc >= 0) ? hs_csc_find(m->kmat, dr, dc) : -1;
                if (dr >= 0 && dc >= 0 && pos < 0) {
                    hs_free(tf);
                    return hs_err_set(err, HS_ERR_INVALID,
                                      "%s:%d: tet %d couples nodes %d and %d, which the mesh "
                                      "adjacency does not list",
                                      __FILE__, __LINE__, e, t[r / 3], t[c / 3]);
                }
                m->kmap[144 * e + r * 12 + c] = pos;
            }
    }
    if (m->def.beta > 0) {
        // (dof, face) positions, and the constant block W^-1 + E A0^-1 E^T.
        int nfree = m->n_free;
        for (int f = 0; f < m->n_faces; f++) {
            for (int s = 0; s < 2; s++) {
                const int* t = mesh->tets + 4 * m->face_tet[2 * f + s];
                for (int r = 0; r < 12; r++) {
                    int d = m->dof_map[3 * t[r / 3] + r % 3];
                    int* fm = m->fmap + 48 * f + 24 * s + 2 * r;
                    fm[0] = d >= 0 ? hs_csc_find(m->kmat, d, nfree + f) : -1;
                    fm[1] = d >= 0 ? hs_csc_find(m->kmat, nfree + f, d) : -1;
                }
            }
            m->kconst[hs_csc_find(m->kmat, nfree + f, nfree + f)] +=
                m->kappa / (m->def.beta * m->face_w[f]);
        }
        for (int e = 0; e < m->nt; e++) {
            const int* fe = tf + 4 * e;
            for (int x = 0; x < 4 && fe[x] >= 0; x++)
                for (int y = 0; y < 4 && fe[y] >= 0; y++) {
                    // E_fe = +1 for the face's first tet, -1 for its second
                    double sx = m->face_tet[2 * fe[x]] == e ? 1.0 : -1.0;
                    double sy = m->face_tet[2 * fe[y]] == e ? 1.0 : -1.0;
                    m->kconst[hs_csc_find(m->kmat, nfree + fe[x], nfree + fe[y])] +=
                        sx * sy * m->kappa / m->vol[e];
                }
        }
    }
    hs_free(tf);
    return HS_OK;
}

#define MOONEY_ALLOC(ptr, count)                                                                   \
    do {                                                                                           \
        (ptr) = hs_calloc((size_t)(count) > 0 ? (size_t)(count) : 1, sizeof *(ptr));               \
        if (!(ptr)) goto nomem;                                                                    \
    } while (0)

hs_status hs_mooney_create(const hs_mesh* mesh, const hs_mooney_def* def,
                           const unsigned char* fixed, hs_mooney** out, hs_err* err) {
    if (!out) return hs_err_set(err, HS_ERR_INVALID, "%s:%d: out is NULL", __FILE__, __LINE__);
    *out = NULL;
    if (!mesh || !def)
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: mesh and def must not be NULL", __FILE__,
                          __LINE__);
    if (def->cookie != HS_MOONEY_COOKIE)
        return hs_err_set(err, HS_ERR_INVALID,
                          "%s:%d: hs_mooney_def not initialised with hs_mooney_default_def()",
                          __FILE__, __LINE__);
    if (!(def->youngs_pa > 0) || !(def->poisson > -1.0 && def->poisson < 0.5) ||
        !(def->density_kg_m3 >= 0) || !(def->beta >= 0) || !isfinite(def->beta) ||
        !(def->tolerance > 0 && def->tolerance < 1) || def->max_newton_iter < 1 ||
        def->load_steps < 1 || def->max_bisections < 0)
        return hs_err_set(err, HS_ERR_INVALID,
                          "%s:%d: invalid mooney def (E %g Pa > 0, nu %g in (-1, 0.5), density %g "
                          ">= 0, beta %g >= 0, tolerance %g in (0, 1), "
                          "max_newton_iter %d >= 1, load_steps %d >= 1, max_bisections %d >= 0)",
                          __FILE__, __LINE__, def->youngs_pa, def->poisson, def->density_kg_m3,
                          def->beta, def->tolerance, def->max_newton_iter, def->load_steps,
                          def->max_bisections);
    if (mesh->n_nodes <= 0 || mesh->n_tets <= 0 || !mesh->x0 || !mesh->tets ||
        !mesh->node_nbr_start)
        return hs_err_set(err, HS_ERR_INVALID,
                          "%s:%d: mesh is empty or not finalised (%d nodes, %d tets)", __FILE__,
                          __LINE__, mesh->n_nodes, mesh->n_tets);
    if (mesh->n_tets > (1 << 30) / 144)
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: mesh too large for the reference solver",
                          __FILE__, __LINE__);

    hs_mooney* m = hs_calloc(1, sizeof *m);
    if (!m) return hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory", __FILE__, __LINE__);
    hs_status st = HS_OK;
    m->mesh = mesh;
    m->def = *def;
    hs_mooney_constants(def, &m->c1, &m->c2, &m->kappa);
    int n = m->n = mesh->n_nodes;
    int nt = m->nt = mesh->n_tets;
    MOONEY_ALLOC(m->dof_map, 3 * n);
    MOONEY_ALLOC(m->grad, 12 * nt);
    MOONEY_ALLOC(m->vol, nt);
    MOONEY_ALLOC(m->kmap, 144 * nt);
    MOONEY_ALLOC(m->f_nodal, 3 * n);
    MOONEY_ALLOC(m->f_grav, 3 * n);
    MOONEY_ALLOC(m->f_prev, 3 * n);
    MOONEY_ALLOC(m->up_new, 3 * n);
    MOONEY_ALLOC(m->up_prev, 3 * n);
    MOONEY_ALLOC(m->u, 3 * n);
    MOONEY_ALLOC(m->p, nt);
    MOONEY_ALLOC(m->fdef, 9 * nt);
    MOONEY_ALLOC(m->jac, nt);
    MOONEY_ALLOC(m->wiso, nt);
    MOONEY_ALLOC(m->ke, 144 * nt);
    MOONEY_ALLOC(m->be, 12 * nt);
    MOONEY_ALLOC(m->q, 3 * n);
    MOONEY_ALLOC(m->r, 3 * n);
    MOONEY_ALLOC(m->du, 3 * n);
    MOONEY_ALLOC(m->u_old, 3 * n);
    MOONEY_ALLOC(m->gap, 3 * n);
    MOONEY_ALLOC(m->fext, 3 * n);
    MOONEY_ALLOC(m->t0, 3 * n);
    MOONEY_ALLOC(m->t1, 3 * n);
    MOONEY_ALLOC(m->t2, 3 * n);
    MOONEY_ALLOC(m->t3, 3 * n);
    MOONEY_ALLOC(m->u_conv, 3 * n);
    MOONEY_ALLOC(m->g, nt);
    MOONEY_ALLOC(m->g2, nt);
    MOONEY_ALLOC(m->g3, nt);

    // Shape gradients: g_a = rows of [x1-x0, x2-x0, x3-x0]^-T applied to the reference simplex.
    for (int e = 0; e < nt; e++) {
        const int* t = mesh->tets + 4 * e;
        for (int a = 0; a < 4; a++)
            if (t[a] < 0 || t[a] >= n) {
                st = hs_err_set(err, HS_ERR_INVALID, "%s:%d: tet %d has node %d outside [0, %d)",
                                __FILE__, __LINE__, e, t[a], n);
                goto fail;
            }
        const double* x0 = mesh->x0 + 3 * t[0];
        double dm[9]; // columns = edges
        for (int c = 0; c < 3; c++)
            for (int i = 0; i < 3; i++) dm[i * 3 + c] = mesh->x0[3 * t[c + 1] + i] - x0[i];
        double det = det3(dm);
        if (!(det > 0) || !isfinite(det)) {
            st = hs_err_set(err, HS_ERR_INVALID,
                            "%s:%d: tet %d has non-positive rest volume %g (mesh not finalised?)",
                            __FILE__, __LINE__, e, det / 6.0);
            goto fail;
        }
        m->vol[e] = det / 6.0;
        double h[9]; // Dm^-T; gradient of N_{c+1} is row c of Dm^-1 = column c of Dm^-T
        inv_transpose3(dm, det, h);
        double* g = m->grad + 12 * e;
        for (int c = 0; c < 3; c++)
            for (int j = 0; j < 3; j++) g[3 * (c + 1) + j] = h[j * 3 + c];
        for (int j = 0; j < 3; j++) g[j] = -(g[3 + j] + g[6 + j] + g[9 + j]);
    }
    // Nodes without a tet have no stiffness: treat them as fixed.
    int nf = 0;
    for (int i = 0; i < n; i++) {
        int used = mesh->node_tet_start ? mesh->node_tet_start[i + 1] > mesh->node_tet_start[i] : 1;
        int fx = (fixed && fixed[i]) || !used;
        for (int c = 0; c < 3; c++) m->dof_map[3 * i + c] = fx ? -1 : nf++;
    }
    m->n_free = nf;
    if ((st = build_faces(m, err)) != HS_OK) goto fail;
    m->n_k = nf + (m->def.beta > 0 ? m->n_faces : 0);
    MOONEY_ALLOC(m->bf, m->n_k);
    MOONEY_ALLOC(m->xf, m->n_k);
    if (m->def.beta > 0 && (st = build_pressure_matrix(m, err)) != HS_OK) goto fail;
    if ((st = hs_check_constrained(m->mesh, NULL, m->dof_map, err)) != HS_OK) goto fail;
    if (nf > 0 && (st = build_stiffness_pattern(m, err)) != HS_OK) goto fail;
    // Analyse and factorise at rest now, so solving allocates nothing and an unconstrained
    // body is reported here.
    mooney_update(m, 1);
    if (nf > 0) {
        assemble_tangent(m);
        st = hs_cholesky_create(m->kmat, &m->kfac, err);
        if (st == HS_ERR_NOT_POSDEF) {
            st = hs_err_set(err, st,
                            "%s:%d: the stiffness at rest is singular: the fixed nodes do not "
                            "stop rigid motion (fix at least 3 non-collinear nodes)",
                            __FILE__, __LINE__);
            goto fail;
        }
        if (st != HS_OK) {
            st = hs_err_set(err, st, "%s:%d: factorisation at rest failed: %s", __FILE__, __LINE__,
                            hs_status_str(st));
            goto fail;
        }
    }
    *out = m;
    return HS_OK;
nomem:
    st = hs_err_set(err, HS_ERR_NOMEM, "%s:%d: out of memory", __FILE__, __LINE__);
fail:
    hs_mooney_destroy(&m);
    return st;
}

void hs_mooney_destroy(hs_mooney** pm) {
    if (!pm || !*pm) return;
    hs_mooney* m = *pm;
    if (m->amat) {
        hs_free(m->amat->colp);
        hs_free(m->amat->rowi);
        hs_free(m->amat->val);
        hs_free(m->amat);
    }
    hs_cholesky_destroy(&m->afac);
    hs_csc_destroy(&m->kmat);
    hs_cholesky_destroy(&m->kfac);
    void* bufs[] = {m->fmap,      m->kconst,  m->dof_map, m->grad,    m->vol,    m->face_tet,
                    m->face_area, m->face_w,  m->kmap,    m->f_nodal, m->f_grav, m->f_prev,
                    m->up_new,    m->up_prev, m->u,       m->p,       m->fdef,   m->jac,
                    m->wiso,      m->ke,      m->be,      m->q,       m->r,      m->du,
                    m->u_old,     m->gap,     m->fext,    m->t0,      m->t1,     m->t2,
                    m->t3,        m->u_conv,  m->g,       m->g2,      m->g3,     m->bf,
                    m->xf};
    for (size_t i = 0; i < sizeof bufs / sizeof bufs[0]; i++) hs_free(bufs[i]);
    hs_free(m);
    *pm = NULL;
}

// ---------------------------------------------------------------------------------------------
// Loads

static int all_finite(const double* v, int n) {
    for (int i = 0; i < n; i++)
        if (!isfinite(v[i])) return 0;
    return 1;
}

// Bounds beyond which a load is a bug, not a load (as hs_body's): the residual norms would
// overflow and read as converged.
#define MOONEY_MAX_FORCE_N 1e9
#define MOONEY_MAX_GRAVITY 1e3
#define MOONEY_MAX_U       1e3

static int all_within(const double* x, int n, double bound) {
    for (int i = 0; i < n; i++)
        if (!(fabs(x[i]) <= bound)) return 0;
    return 1;
}

hs_status hs_mooney_set_forces(hs_mooney* m, const double* f) {
    if (!m) return HS_ERR_INVALID;
    if (!f) {
        memset(m->f_nodal, 0, sizeof(double) * 3 * (size_t)m->n);
        return HS_OK;
    }
    if (!all_within(f, 3 * m->n, MOONEY_MAX_FORCE_N)) return HS_ERR_INVALID;
    memcpy(m->f_nodal, f, sizeof(double) * 3 * (size_t)m->n);
    return HS_OK;
}

hs_status hs_mooney_set_gravity(hs_mooney* m, const double g[3]) {
    if (!m || !g || !all_within(g, 3, MOONEY_MAX_GRAVITY)) return HS_ERR_INVALID;
    memset(m->f_grav, 0, sizeof(double) * 3 * (size_t)m->n);
    for (int e = 0; e < m->nt; e++) {
        double w = m->def.density_kg_m3 * m->vol[e] * 0.25;
        for (int a = 0; a < 4; a++)
            for (int c = 0; c < 3; c++) m->f_grav[3 * m->mesh->tets[4 * e + a] + c] += w * g[c];
    }
    return HS_OK;
}

hs_status hs_mooney_set_prescribed(hs_mooney* m, const double* u) {
    if (!m) return HS_ERR_INVALID;
    if (u && !all_within(u, 3 * m->n, MOONEY_MAX_U)) return HS_ERR_INVALID;
    for (int d = 0; d < 3 * m->n; d++) m->up_new[d] = (u && m->dof_map[d] < 0) ? u[d] : 0.0;
    return HS_OK;
}

// ---------------------------------------------------------------------------------------------
// Evaluation at the current m->u

// Solve A p = g for the pressures (A diagonal when beta = 0).
static hs_status pressure_solve(hs_mooney* m, const double* g, double* p) {
    if (!m->afac) {
        for (int e = 0; e < m->nt; e++) p[e] = m->kappa * g[e] / m->vol[e];
        return HS_OK;
    }
    return hs_cholesky_solve(m->afac, g, p);
}

// Deformation gradients, pressures, element forces and tangents. Returns 0, or 1 if an element
// is inverted or degenerate (J <= 0) or a value is not finite.
static int mooney_update(hs_mooney* m, int tangent) {
    const hs_mesh* mesh = m->mesh;
    int bad = 0;
    for (int e = 0; e < m->nt; e++) {
        const int* t = mesh->tets + 4 * e;
        const double* g = m->grad + 12 * e;
        double* f = m->fdef + 9 * e;
        for (int k = 0; k < 9; k++) f[k] = (k % 4 == 0) ? 1.0 : 0.0;
        for (int a = 0; a < 4; a++) {
            const double* ua = m->u + 3 * t[a];
            for (int i = 0; i < 3; i++)
                for (int j = 0; j < 3; j++) f[i * 3 + j] += ua[i] * g[3 * a + j];
        }
        // J - 1 = det(I + H) - 1 = tr H + I2(H) + det H, H = grad u: no cancellation at small
        // strain, where kappa (J - 1) would otherwise lose digits at nu -> 0.5.
        double hm[9];
        for (int k = 0; k < 9; k++) hm[k] = f[k] - ((k % 4 == 0) ? 1.0 : 0.0);
        double tr = hm[0] + hm[4] + hm[8];
        double i2 = hm[0] * hm[4] + hm[4] * hm[8] + hm[0] * hm[8] - hm[1] * hm[3] - hm[2] * hm[6] -
                    hm[5] * hm[7];
        double jm1 = tr + i2 + det3(hm);
        double jd = 1.0 + jm1;
        m->jac[e] = jd;
        if (!(jd > 0) || !isfinite(jd)) bad = 1;
        m->g[e] = m->vol[e] * jm1;
    }
    if (bad) return 1;
    if (pressure_solve(m, m->g, m->p) != HS_OK) return 1;
    memset(m->q, 0, sizeof(double) * 3 * (size_t)m->n);
    double a[81], pk[9], h[9], efs2 = 0;
    for (int e = 0; e < m->nt; e++) {
        const int* t = mesh->tets + 4 * e;
        const double* g = m->grad + 12 * e;
        const double* f = m->fdef + 9 * e;
        double v = m->vol[e];
        m->wiso[e] = hs_mooney_pk1(m->c1, m->c2, m->p[e], f, pk, tangent ? a : NULL);
        inv_transpose3(f, m->jac[e], h);
        double* be = m->be + 12 * e;
        for (int n = 0; n < 4; n++)
            for (int i = 0; i < 3; i++) {
                double s = 0, sb = 0;
                for (int j = 0; j < 3; j++) {
                    s += pk[i * 3 + j] * g[3 * n + j];
                    sb += h[i * 3 + j] * g[3 * n + j];
                }
                m->q[3 * t[n] + i] += v * s;
                efs2 += v * s * v * s;
                be[3 * n + i] = v * m->jac[e] * sb;
            }
        if (!tangent) continue;
        double* ke = m->ke + 144 * e;
        // K_(ai)(bk) = V sum_JL A_iJkL g_aJ g_bL; contract L first.
        double ag[9 * 3 * 4]; // [iJk][b]
        for (int ijk = 0; ijk < 27; ijk++) {
            int ij = ijk / 3, k = ijk % 3;
            for (int b = 0; b < 4; b++) {
                double s = 0;
                for (int l = 0; l < 3; l++) s += a[ij * 9 + k * 3 + l] * g[3 * b + l];
                ag[ijk * 4 + b] = s;
            }
        }
        for (int an = 0; an < 4; an++)
            for (int i = 0; i < 3; i++)
                for (int b = 0; b < 4; b++)
                    for (int k = 0; k < 3; k++) {
                        double s = 0;
                        for (int j = 0; j < 3; j++)
                            s += g[3 * an + j] * ag[((i * 3 + j) * 3 + k) * 4 + b];
                        ke[(3 * an + i) * 12 + 3 * b + k] = v * s;
                    }
    }
    m->elem_force_scale = sqrt(efs2);
    return all_finite(m->q, 3 * m->n) ? 0 : 1;
}

// y = S x over all dofs: element tangents plus B^T A^-1 B. Uses m->g2, m->g3 as work.
static void apply_tangent(hs_mooney* m, const double* x, double* y) {
    const int* tets = m->mesh->tets;
    memset(y, 0, sizeof(double) * 3 * (size_t)m->n);
    for (int e = 0; e < m->nt; e++) {
        const int* t = tets + 4 * e;
        const double* ke = m->ke + 144 * e;
        const double* be = m->be + 12 * e;
        double xe[12], s = 0;
        for (int a = 0; a < 4; a++)
            for (int c = 0; c < 3; c++) xe[3 * a + c] = x[3 * t[a] + c];
        for (int r = 0; r < 12; r++) s += be[r] * xe[r];
        m->g3[e] = s;
        for (int r = 0; r < 12; r++) {
            double acc = 0;
            for (int c = 0; c < 12; c++) acc += ke[r * 12 + c] * xe[c];
            y[3 * t[r / 3] + r % 3] += acc;
        }
    }
    pressure_solve(m, m->g3, m->g2);
    for (int e = 0; e < m->nt; e++) {
        const int* t = tets + 4 * e;
        const double* be = m->be + 12 * e;
        for (int r = 0; r < 12; r++) y[3 * t[r / 3] + r % 3] += be[r] * m->g2[e];
    }
}

// Tangent matrix: K + B^T A0^-1 B over the free dofs (A0 = diag(V) / kappa), and with
// beta > 0 the face coupling -B^T A0^-1 E^T and the constant face block.
static void assemble_tangent(hs_mooney* m) {
    double* val = m->kmat->val;
    if (m->kconst)
        memcpy(val, m->kconst, sizeof(double) * (size_t)m->kmat->nnz);
    else
        hs_csc_zero(m->kmat);
    for (int e = 0; e < m->nt; e++) {
        const double* ke = m->ke + 144 * e;
        const double* be = m->be + 12 * e;
        const int* map = m->kmap + 144 * e;
        double w = m->kappa / m->vol[e];
        for (int r = 0; r < 12; r++)
            for (int c = 0; c < 12; c++) {
                int pos = map[r * 12 + c];
                if (pos >= 0) val[pos] += ke[r * 12 + c] + w * be[r] * be[c];
            }
    }
    if (!m->kconst) return;
    for (int f = 0; f < m->n_faces; f++)
        for (int s = 0; s < 2; s++) {
            int e = m->face_tet[2 * f + s];
            double w = (s == 0 ? -1.0 : 1.0) * m->kappa / m->vol[e]; // -E_fe / A0_e
            const double* be = m->be + 12 * e;
            const int* fm = m->fmap + 48 * f + 24 * s;
            for (int r = 0; r < 12; r++) {
                if (fm[2 * r] < 0) continue;
                val[fm[2 * r]] += w * be[r];
                val[fm[2 * r + 1]] += w * be[r];
            }
        }
}

// Solve S_ff x = b over the free dofs with the factor (b, x full length; fixed entries of x 0).
// With beta > 0 the face unknowns get a zero right-hand side and are dropped.
static hs_status solve_tangent(hs_mooney* m, const double* b, double* x) {
    memset(m->bf, 0, sizeof(double) * (size_t)m->n_k);
    for (int d = 0; d < 3 * m->n; d++)
        if (m->dof_map[d] >= 0) m->bf[m->dof_map[d]] = b[d];
    hs_status st = hs_cholesky_solve(m->kfac, m->bf, m->xf);
    for (int d = 0; d < 3 * m->n; d++) x[d] = m->dof_map[d] >= 0 ? m->xf[m->dof_map[d]] : 0.0;
    return st;
}

static double dot_free(const hs_mooney* m, const double* a, const double* b) {
    double s = 0;
    for (int d = 0; d < 3 * m->n; d++)
        if (m->dof_map[d] >= 0) s += a[d] * b[d];
    return s;
}

// Residual of the current increment: rhs = fext - Q - S gap over free dofs (gap = remaining
// prescribed motion of fixed dofs). Returns its norm. Needs a tangent update when gap != 0.
static double increment_residual(hs_mooney* m, int gap_nonzero) {
    int nd = 3 * m->n;
    if (gap_nonzero) apply_tangent(m, m->gap, m->t0);
    for (int d = 0; d < nd; d++) {
        if (m->dof_map[d] < 0) {
            m->r[d] = 0.0;
            continue;
        }
        m->r[d] = m->fext[d] - m->q[d] - (gap_nonzero ? m->t0[d] : 0.0);
    }
    return sqrt(dot_free(m, m->r, m->r));
}

static double total_energy(const hs_mooney* m) {
    double e = 0;
    for (int t = 0; t < m->nt; t++) e += m->vol[t] * m->wiso[t] + 0.5 * m->p[t] * m->g[t];
    for (int d = 0; d < 3 * m->n; d++) e -= m->fext[d] * m->u[d];
    return e;
}

// Size of the terms that cancel in the assembled residual: the residual cannot be computed
// more accurately than a small multiple of round-off on this.
static double qscale(const hs_mooney* m) {
    double s = m->elem_force_scale * m->elem_force_scale;
    for (int d = 0; d < 3 * m->n; d++) s += m->fext[d] * m->fext[d];
    return sqrt(s);
}

// One load increment to load factor s (0..1 between the previous and the new load).
// Returns HS_OK or a failure; on failure the caller restores the state.
static hs_status solve_increment(hs_mooney* m, double s, hs_mooney_stats* stats, hs_err* err) {
    int nd = 3 * m->n;
    int gap_nz = 0;
    for (int d = 0; d < nd; d++) {
        double fa = m->f_nodal[d] + m->f_grav[d];
        m->fext[d] = m->f_prev[d] + s * (fa - m->f_prev[d]);
        if (m->dof_map[d] < 0) {
            m->gap[d] = m->up_prev[d] + s * (m->up_new[d] - m->up_prev[d]) - m->u[d];
            if (m->gap[d] != 0.0) gap_nz = 1;
        } else {
            m->gap[d] = 0.0;
        }
    }
    if (mooney_update(m, 1))
        return hs_err_set(err, HS_ERR_NUMERIC, "%s:%d: inverted element at increment start",
                          __FILE__, __LINE__);
    double r0 = increment_residual(m, gap_nz);
    double rn = r0;
    stats->n_ratio = 1;
    stats->ratio[0] = 1.0;
    stats->final_ratio = 0.0;
    int iters = 0;
    double floor_abs = 1e-12 * qscale(m);
    if (!isfinite(r0) || !isfinite(floor_abs)) // an overflow would read as converged
        return hs_err_set(err, HS_ERR_NUMERIC, "%s:%d: residual not finite at increment start",
                          __FILE__, __LINE__);
    if (r0 <= floor_abs && !gap_nz) goto converged;
    while (iters < m->def.max_newton_iter) {
        if (m->n_free > 0) {
            assemble_tangent(m);
            hs_status st = hs_cholesky_refactor(m->kfac, m->kmat);
            if (st != HS_OK)
                return hs_err_set(err, st, "%s:%d: tangent factorisation failed: %s", __FILE__,
                                  __LINE__, hs_status_str(st));
            st = solve_tangent(m, m->r, m->du);
            if (st != HS_OK)
                return hs_err_set(err, st, "%s:%d: tangent solve failed: %s", __FILE__, __LINE__,
                                  hs_status_str(st));
        } else {
            memset(m->du, 0, sizeof(double) * (size_t)nd);
        }
        for (int d = 0; d < nd; d++)
            if (m->dof_map[d] < 0) m->du[d] = m->gap[d];
        // Line search: halve the step while an element inverts, or (with the boundary already
        // in place) while neither the residual nor the energy decreases.
        double e_old = total_energy(m);
        memcpy(m->u_old, m->u, sizeof(double) * (size_t)nd);
        double alpha = 1.0;
        int accepted = 0;
        for (int ls = 0; ls < 8; ls++) {
            for (int d = 0; d < nd; d++) m->u[d] = m->u_old[d] + alpha * m->du[d];
            if (!mooney_update(m, 1)) {
                int gap_now = 0;
                for (int d = 0; d < nd; d++) {
                    if (m->dof_map[d] < 0) {
                        m->gap[d] = (1.0 - alpha) * m->du[d];
                        if (m->gap[d] != 0.0) gap_now = 1;
                    }
                }
                double rt = increment_residual(m, gap_now);
                if (isfinite(rt) && (gap_nz || rt <= rn || total_energy(m) <= e_old)) {
                    rn = rt;
                    gap_nz = gap_now;
                    accepted = 1;
                    break;
                }
                if (ls == 7 && isfinite(rt)) { // smallest step still valid: take it
                    rn = rt;
                    gap_nz = gap_now;
                    accepted = 1;
                    break;
                }
            }
            alpha *= 0.5;
            stats->line_search_cuts++;
        }
        iters++;
        if (!accepted)
            return hs_err_set(err, HS_ERR_NUMERIC,
                              "%s:%d: Newton step inverts elements even when shortened to 1/128",
                              __FILE__, __LINE__);
        double ratio = r0 > 0 ? rn / r0 : 0.0;
        if (stats->n_ratio < HS_MOONEY_HISTORY) stats->ratio[stats->n_ratio++] = ratio;
        stats->final_ratio = ratio;
        if (!gap_nz && (ratio <= m->def.tolerance || rn <= 1e-12 * qscale(m))) goto converged;
    }
    stats->newton_total += iters;
    return hs_err_set(err, HS_ERR_NOT_CONVERGED,
                      "%s:%d: Newton reached %d iterations with ||F-Q||/||F-Q||_first = %.3g",
                      __FILE__, __LINE__, iters, r0 > 0 ? rn / r0 : 0.0);
converged:
    stats->newton_total += iters;
    if (iters > stats->newton_max) stats->newton_max = iters;
    if (stats->n_step_iters < HS_MOONEY_HISTORY) stats->step_iters[stats->n_step_iters++] = iters;
    stats->increments++;
    return HS_OK;
}

hs_status hs_mooney_solve_static(hs_mooney* m, hs_mooney_stats* stats_out, hs_err* err) {
    if (!m) return hs_err_set(err, HS_ERR_INVALID, "%s:%d: m is NULL", __FILE__, __LINE__);
    int64_t t0 = hs_now_ns();
    hs_mooney_stats stats;
    memset(&stats, 0, sizeof stats);
    int nd = 3 * m->n;
    double lam = 0.0, dl = 1.0 / m->def.load_steps;
    int bisect = 0;
    hs_status st = HS_OK;
    // The last converged displacement is kept in m->u_conv.
    memcpy(m->u_conv, m->u, sizeof(double) * (size_t)nd);
    // Step control: a failed increment is halved (at most max_bisections levels deep, and
    // 4 max_bisections failures in all); an easy one lets the increment grow back.
    int depth = 0;
    while (lam < 1.0) {
        double next = lam + dl;
        if (next > 1.0 - 1e-12) next = 1.0;
        // the increment works on load factor "next" relative to the previous converged loads
        int before = stats.newton_total;
        st = solve_increment(m, next, &stats, err);
        if (st == HS_OK) {
            memcpy(m->u_conv, m->u, sizeof(double) * (size_t)nd);
            lam = next;
            if (depth > 0 && 4 * (stats.newton_total - before) <= m->def.max_newton_iter) {
                depth--;
                dl *= 2.0;
            }
            continue;
        }
        memcpy(m->u, m->u_conv, sizeof(double) * (size_t)nd);
        if (depth >= m->def.max_bisections || bisect >= 4 * m->def.max_bisections) break;
        bisect++;
        depth++;
        stats.bisections++;
        dl *= 0.5;
    }
    if (st == HS_OK) {
        for (int d = 0; d < nd; d++) {
            m->f_prev[d] = m->f_nodal[d] + m->f_grav[d];
            m->up_prev[d] = m->up_new[d];
        }
    } else {
        // Keep the last converged partial state consistent: its load is the factor lam.
        for (int d = 0; d < nd; d++) {
            m->f_prev[d] += lam * (m->f_nodal[d] + m->f_grav[d] - m->f_prev[d]);
            m->up_prev[d] += lam * (m->up_new[d] - m->up_prev[d]);
        }
        char msg[sizeof err->msg];
        snprintf(msg, sizeof msg, "%s", err ? err->msg : "");
        hs_err_set(err, st, "%s (stopped at load factor %.4g after %d bisections)", msg, lam,
                   bisect);
    }
    mooney_update(m, 0);
    stats.volume_ratio_min = INFINITY;
    stats.volume_ratio_max = -INFINITY;
    double v0 = 0, v1 = 0;
    for (int e = 0; e < m->nt; e++) {
        if (m->jac[e] < stats.volume_ratio_min) stats.volume_ratio_min = m->jac[e];
        if (m->jac[e] > stats.volume_ratio_max) stats.volume_ratio_max = m->jac[e];
        v0 += m->vol[e];
        v1 += m->vol[e] * m->jac[e];
    }
    stats.volume_ratio_total = v1 / v0;
    stats.system_size = m->n_k;
    stats.factor_nnz = m->kfac ? hs_cholesky_factor_nnz(m->kfac) : 0;
    stats.solve_ms = (double)(hs_now_ns() - t0) * 1e-6;
    if (stats_out) *stats_out = stats;
    return st;
}

hs_status hs_mooney_set_displacement(hs_mooney* m, const double* u, hs_err* err) {
    if (!m || !u)
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: m and u must not be NULL", __FILE__,
                          __LINE__);
    if (!all_within(u, 3 * m->n, MOONEY_MAX_U))
        return hs_err_set(err, HS_ERR_INVALID, "%s:%d: displacement has NaN, Inf or above %g m",
                          __FILE__, __LINE__, MOONEY_MAX_U);
    const size_t n3 = 3 * (size_t)m->n;
    memcpy(m->u_old, m->u, sizeof(double) * n3);
    memcpy(m->u, u, sizeof(double) * n3);
    if (mooney_update(m, 0)) { // refused: the state as it was
        memcpy(m->u, m->u_old, sizeof(double) * n3);
        mooney_update(m, 0);
        return hs_err_set(err, HS_ERR_NUMERIC,
                          "%s:%d: displacement inverts or degenerates an element", __FILE__,
                          __LINE__);
    }
    memset(m->f_prev, 0, sizeof(double) * n3);
    memset(m->up_prev, 0, sizeof(double) * n3);
    return HS_OK;
}

const double* hs_mooney_displacement(const hs_mooney* m) {
    return m->u;
}
const double* hs_mooney_pressure(const hs_mooney* m) {
    return m->p;
}

void hs_mooney_internal_forces(const hs_mooney* m, double* q) {
    memcpy(q, m->q, sizeof(double) * 3 * (size_t)m->n);
}

void hs_mooney_element_stress(const hs_mooney* m, int t, double sigma[9]) {
    HS_ASSERT(m && t >= 0 && t < m->nt);
    const double* f = m->fdef + 9 * t;
    double pk[9];
    hs_mooney_pk1(m->c1, m->c2, m->p[t], f, pk, NULL);
    double jd = m->jac[t];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) {
            double s = 0;
            for (int k = 0; k < 3; k++) s += pk[i * 3 + k] * f[j * 3 + k];
            sigma[i * 3 + j] = s / jd;
        }
}

double hs_mooney_pressure_oscillation(const hs_mooney* m) {
    double jump = 0, area = 0, pp = 0, vol = 0;
    for (int f = 0; f < m->n_faces; f++) {
        double d = m->p[m->face_tet[2 * f]] - m->p[m->face_tet[2 * f + 1]];
        jump += m->face_area[f] * d * d;
        area += m->face_area[f];
    }
    for (int e = 0; e < m->nt; e++) pp += m->vol[e] * m->p[e] * m->p[e], vol += m->vol[e];
    if (pp <= 0 || area <= 0) return 0.0;
    return sqrt(jump / area) / sqrt(pp / vol);
}
