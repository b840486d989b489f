// Probe contact from a compliance snapshot: the per-tick work of the rt thread.
//
// DESIGN. Pure function of (snapshot, tool position): fixed-size stack arrays, no allocation.
// The probe is a smooth sphere, so the contact is frictionless: the force on node i is
// lambda_i n_i along the sphere's normal n_i = (q_i - p) / rho_i at the closest point to the
// node's contact-free position q_i (the radial direction; defined for every node off the
// centre, which a projection along the surface normal is not near the sphere's rim). The
// node's displacement is u_i = sum_j C_ij n_j lambda_j, and to first order its distance from
// the centre becomes rho_i + n_i . u_i. Contact is the linear complementarity problem
//     w = W lambda - delta >= 0,  lambda >= 0,  w . lambda = 0,
//     W_ij = n_i^T C_ij n_j,  delta_i = r - rho_i (penetration),
// i.e. every node ends on or outside the sphere, only pushed, and pushed only where it touches.
// W is symmetric positive definite, so the solution is unique and depends continuously on the
// tool position: the force never jumps when a node enters or leaves the contact. Solved by
// principal pivoting (Murty's least-index rule, candidates ordered deepest first; finite for
// positive definite W), one m x m Cholesky (m <= 16) per pivot.
#include "hapsim/compliance.h"

#include "dense.h"

#include <float.h>
#include <math.h>
#include <string.h>

#define M          HS_MAX_CONTACT
#define MAX_PIVOTS (4 * M)

typedef struct sel {
    int cand;    // candidate index in the snapshot
    double rho;  // distance of the contact-free position from the sphere centre, m
    double n[3]; // unit direction centre -> node
} sel;

// Solve W_AA lambda_A = delta_A for the active set; lambda = 0 elsewhere. Returns -1 if W_AA is
// not positive definite.
static int solve_active(const double* w, const double* delta, const unsigned char* act, int m,
                        double* lambda) {
    double a[M * M], x[M];
    int idx[M], k = 0;
    for (int i = 0; i < m; ++i)
        if (act[i]) idx[k++] = i;
    for (int i = 0; i < k; ++i) {
        for (int j = 0; j < k; ++j) a[i * k + j] = w[idx[i] * M + idx[j]];
        x[i] = delta[idx[i]];
    }
    for (int i = 0; i < m; ++i) lambda[i] = 0;
    if (k == 0) return 0;
    if (hs_dense_cholesky(a, k) != 0) return -1;
    hs_dense_cholesky_solve(a, k, x);
    for (int i = 0; i < k; ++i) lambda[idx[i]] = x[i];
    return 0;
}

void hs_contact_solve(const hs_contact_snapshot* s, const double tool_m[3], int warm_n,
                      const int* warm_nodes, hs_contact* out) {
    memset(out, 0, sizeof *out);
    out->version = s->version;
    for (int k = 0; k < 3; ++k) out->tool_m[k] = tool_m[k];
    const double r = s->probe_radius_m;
    double clearance = DBL_MAX;

    // The tool must stay inside the region whose nodes the snapshot lists.
    double off[3] = {tool_m[0] - s->centre_m[0], tool_m[1] - s->centre_m[1],
                     tool_m[2] - s->centre_m[2]};
    double cover = s->reach_m - r - sqrt(off[0] * off[0] + off[1] * off[1] + off[2] * off[2]);
    if (cover < clearance) clearance = cover;

    // LCP candidates: penetrating nodes and those within 25 % of r outside the sphere (which the
    // push on their neighbours may bring into contact), nearest the centre first, at most M.
    const double near = 1.25 * r;
    sel set[M];
    int m = 0;
    for (int i = 0; i < s->n_cand; ++i) {
        double v[3] = {s->free_m[i][0] - tool_m[0], s->free_m[i][1] - tool_m[1],
                       s->free_m[i][2] - tool_m[2]};
        double rho = sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        double gap = rho - r;
        if (fabs(gap) < clearance) clearance = fabs(gap);
        if (gap < 0) ++out->penetrating;
        if (rho >= near) continue;
        if (m == M && rho >= set[m - 1].rho) continue;
        int at = m < M ? m++ : m - 1;
        while (at > 0 && set[at - 1].rho > rho) {
            set[at] = set[at - 1];
            --at;
        }
        sel e;
        e.cand = i;
        e.rho = rho;
        if (rho > 1e-9 * (r > 0 ? r : 1)) {
            for (int k = 0; k < 3; ++k) e.n[k] = v[k] / rho;
        } else {
            // At the centre the radial direction is undefined: push along -normal (inward).
            for (int k = 0; k < 3; ++k) e.n[k] = -s->normal[i][k];
        }
        set[at] = e;
    }
    out->clearance_m = clearance > 0 ? clearance : 0;
    if (m == 0 || set[0].rho >= r) return; // nothing penetrates

    // W and delta.
    double w[M * M], cn[M][M][3], delta[M];
    for (int i = 0; i < m; ++i) {
        delta[i] = r - set[i].rho;
        for (int j = 0; j < m; ++j) {
            const double* b = s->c[set[i].cand][set[j].cand];
            const double* nj = set[j].n;
            if (i != j && !s->coupled[set[i].cand] && !s->coupled[set[j].cand]) out->approx = 1;
            // cn[i][j] = C_ij n_j
            for (int p = 0; p < 3; ++p)
                cn[i][j][p] = b[3 * p] * nj[0] + b[3 * p + 1] * nj[1] + b[3 * p + 2] * nj[2];
        }
    }
    for (int i = 0; i < m; ++i)
        for (int j = 0; j < m; ++j) {
            const double* ni = set[i].n;
            w[i * M + j] = ni[0] * cn[i][j][0] + ni[1] * cn[i][j][1] + ni[2] * cn[i][j][2];
        }
    for (int i = 0; i < m; ++i)
        for (int j = i + 1; j < m; ++j)
            w[i * M + j] = w[j * M + i] = 0.5 * (w[i * M + j] + w[j * M + i]);

    // Principal pivoting, least index first (deepest first). Start from the previous tick's
    // contact set when given (it rarely changes between ticks: usually one solve), else from
    // the penetrating set.
    unsigned char act[M];
    double lambda[M];
    for (int i = 0; i < m; ++i) {
        act[i] = warm_n > 0 ? 0 : delta[i] > 0;
        for (int j = 0; j < warm_n; ++j)
            if (warm_nodes[j] == s->node[set[i].cand]) act[i] = 1;
    }
    int converged = 0;
    for (int piv = 0; piv < MAX_PIVOTS; ++piv) {
        out->passes = piv + 1;
        if (solve_active(w, delta, act, m, lambda) != 0) {
            out->failed = 1;
            return;
        }
        int flip = -1;
        for (int i = 0; i < m && flip < 0; ++i) {
            if (act[i]) {
                if (lambda[i] < 0) flip = i; // would pull: leaves the contact
            } else {
                double wi = -delta[i];
                for (int j = 0; j < m; ++j) wi += w[i * M + j] * lambda[j];
                if (wi < -1e-12 * r) flip = i; // pushed into the sphere: joins the contact
            }
        }
        if (flip < 0) {
            converged = 1;
            break;
        }
        if (act[flip]) ++out->dropped;
        act[flip] = !act[flip];
    }
    if (!converged) {
        // Keep the last solve but never pull.
        for (int i = 0; i < m; ++i)
            if (lambda[i] < 0) lambda[i] = 0;
    }

    // Result: active nodes, forces on the tissue, their displacements.
    int k = 0;
    int ia[M];
    for (int i = 0; i < m; ++i) {
        if (!act[i] || lambda[i] <= 0) continue;
        ia[k] = i;
        out->node[k] = s->node[set[i].cand];
        for (int p = 0; p < 3; ++p) {
            out->f_n[k][p] = lambda[i] * set[i].n[p];
            out->force_n[p] -= out->f_n[k][p];
            double u = 0;
            for (int j = 0; j < m; ++j) u += cn[i][j][p] * lambda[j];
            out->d_m[k][p] = u;
        }
        ++k;
    }
    out->n = k;
    if (k == 0) return;

    // Stiffness K = -dF/dp with the active set fixed. F = -sum_i lambda_i n_i, lambda = W^-1
    // delta over the active set, dn_i/dp = -P_i / rho_i (P_i = I - n_i n_i^T), ddelta_i/dp =
    // n_i^T, dW_ij/dp = -(C_ij n_j)^T P_i / rho_i - (C_ji n_i)^T P_j / rho_j, so
    //     dlambda/dp = W^-1 G,  G_i = n_i^T + (u_i^T P_i) / rho_i
    //                                + sum_j lambda_j (C_ji n_i)^T P_j / rho_j,
    //     K = sum_i n_i (W^-1 G)_i - sum_i lambda_i P_i / rho_i.
    double a[M * M], g[3][M];
    for (int i = 0; i < k; ++i)
        for (int j = 0; j < k; ++j) a[i * k + j] = w[ia[i] * M + ia[j]];
    if (hs_dense_cholesky(a, k) != 0) {
        out->failed = 1;
        return;
    }
    for (int i = 0; i < k; ++i) {
        const sel* si = &set[ia[i]];
        const double* ni = si->n;
        double gi[3], u[3];
        for (int p = 0; p < 3; ++p) {
            gi[p] = ni[p];
            u[p] = out->d_m[i][p];
        }
        double un = u[0] * ni[0] + u[1] * ni[1] + u[2] * ni[2];
        for (int p = 0; p < 3; ++p) gi[p] += (u[p] - un * ni[p]) / si->rho;
        for (int j = 0; j < k; ++j) {
            const sel* sj = &set[ia[j]];
            const double* nj = sj->n;
            const double* c = cn[ia[j]][ia[i]]; // C_ji n_i
            double cnj = c[0] * nj[0] + c[1] * nj[1] + c[2] * nj[2];
            double lj = lambda[ia[j]] / sj->rho;
            for (int p = 0; p < 3; ++p) gi[p] += lj * (c[p] - cnj * nj[p]);
        }
        for (int p = 0; p < 3; ++p) g[p][i] = gi[p];
    }
    for (int p = 0; p < 3; ++p) hs_dense_cholesky_solve(a, k, g[p]);
    memset(out->stiffness_n_m, 0, sizeof out->stiffness_n_m);
    for (int i = 0; i < k; ++i) {
        const sel* si = &set[ia[i]];
        const double* ni = si->n;
        double l = lambda[ia[i]] / si->rho;
        for (int p = 0; p < 3; ++p)
            for (int q = 0; q < 3; ++q)
                out->stiffness_n_m[3 * p + q] +=
                    ni[p] * g[q][i] - l * ((p == q ? 1.0 : 0.0) - ni[p] * ni[q]);
    }
}

void hs_contact_model(const hs_contact* c, double min_radius_m, double max_radius_m,
                      double timeout_s, hs_haptic_model* m) {
    memset(m, 0, sizeof *m);
    m->seq = c->version;
    for (int k = 0; k < 3; ++k) {
        m->force_n[k] = c->force_n[k];
        m->anchor_m[k] = c->tool_m[k];
    }
    memcpy(m->stiffness_n_m, c->stiffness_n_m, sizeof m->stiffness_n_m);
    double rad = c->clearance_m;
    if (rad < min_radius_m) rad = min_radius_m;
    if (rad > max_radius_m) rad = max_radius_m;
    m->radius_m = rad;
    m->timeout_s = timeout_s;
}
