// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-solve: load a mesh, fix a region, apply gravity, and solve statically or run implicit
// dynamics with a chosen element model. Writes the nodal displacement as CSV.
#define _XOPEN_SOURCE 700 // realpath, stat
#include "hapsim/version.h"
#include "hapsim/body.h"
#include "hapsim/mesh.h"
#include "hapsim/mooney.h"
#include "hapsim/press.h"
#include "hapsim/sparse.h"

#include <errno.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

static const char* usage =
    "usage: hapsim-solve --mesh FILE --model linear|corotated|stvk|mooney [options] --out "
    "disp.csv\n"
    "\n"
    "Solves a tetrahedral soft-tissue model under gravity with a fixed region and writes one\n"
    "line per node, ux,uy,uz in metres in file order, after a header line.\n"
    "\n"
    "  --mesh FILE            .msh (Gmsh 2.2/4.1), .node/.ele (TetGen) or .vtk (legacy ASCII)\n"
    "  --model M              linear | corotated | stvk | mooney (pressure-stabilised\n"
    "                         Mooney-Rivlin reference, static only; see docs/mooney.md)\n"
    "  --beta B               mooney: pressure stabilisation (default 0 = plain P1/P0)\n"
    "  --locking-free [MODE]  locking-free tets for near-incompressible tissue (docs/fem.md):\n"
    "                         sns (default; stvk: anp) node-smoothed volumetric strain and a\n"
    "                         share of node-smoothed deviatoric strain | anp average nodal\n"
    "                         pressure | none\n"
    "  --locking-free-alpha A sns: node-smoothed share of the deviatoric energy, [0, 1)\n"
    "                         (default 0.6)\n"
    "  --E PA                 Young's modulus, Pa (default 5000, as scenes)\n"
    "  --nu NU                Poisson ratio (default 0.45)\n"
    "  --density KG_M3        density, kg/m^3 (default 1000)\n"
    "  --gravity GX,GY,GZ     gravity, m/s^2 (default 0,0,0)\n"
    "  --fix-box X0,Y0,Z0,X1,Y1,Z1   nodes inside the box are fixed in x, y and z (metres)\n"
    "  --fix-plane AXIS,SIDE,TOL     nodes within TOL (m) of the bounding box min or max along\n"
    "                         x|y|z are fixed, e.g. --fix-plane x,min,1e-6 (may be repeated with "
    "--fix-box)\n"
    "  --static               solve equilibrium (Newton; co-rotated uses its rotation-frozen "
    "tangent)\n"
    "  --steps N --dt S       run N implicit Euler steps of S seconds instead\n"
    "  --tol T                static relative residual tolerance (default 1e-8)\n"
    "  --max-iter N           static Newton iteration cap per load step (default 100)\n"
    "  --load-steps N         static load increments (default 1)\n"
    "  --rotation polar|svd   co-rotated rotation method (default polar)\n"
    "  --polar-tol T          rotation tolerance: the polar iteration's; with svd, how far an\n"
    "                         element's kept rotation may be from F's polar factor before a\n"
    "                         new SVD (default 1e-6 --static, 1e-4 steps)\n"
    "  --inversion fallback|reflect   inverted-element remedy (default fallback)\n"
    "  --damping ALPHA,BETA   Rayleigh damping C = alpha M + beta K (default 0,0)\n"
    "  --solver direct|pcg|warped  linear solver (default direct, CHOLMOD; warped: one\n"
    "                         rotated rest-factor solve per step, exact tangent when --static)\n"
    "  --precond none|jacobi|factor|warped   PCG preconditioner (default warped: the\n"
    "                         rest-state Cholesky factor turned by the node rotations)\n"
    "  --pcg-iters N          PCG iterations per solve (default 20)\n"
    "  --probe X,Y,Z          --static only: a frictionless rigid sphere centred at X,Y,Z (m)\n"
    "                         presses the body (linear, corotated, stvk); prints\n"
    "                         'probe force N: fx,fy,fz', the force on the tool; contact on\n"
    "                         the boundary triangles (--probe-contact nodes: on the nodes),\n"
    "                         co-rotated rotations to 1e-10 at least (docs/fem.md, \"Probe\n"
    "                         reference\")\n"
    "  --probe-radius R       sphere radius, m (required with --probe)\n"
    "  --probe-dir DX,DY,DZ   the sphere's direction of travel into the tissue (default: minus\n"
    "                         the rest normal of the surface node nearest the centre)\n"
    "  --vtk FILE             also write the deformed mesh as legacy VTK\n"
    "  --out FILE             displacement CSV (required)\n"
    "  -q, --quiet            no summary\n"
    "  -h, --help             this text\n"
    "\n"
    "A flag that the chosen model, mode or solver does not read (e.g. --dt with --static,\n"
    "--precond without --solver pcg) is refused. The outputs' folders are checked first.\n"
    "\n"
    "Exit status: 0 solved, 1 bad input (a mesh, a sphere touching nothing), 2 bad usage\n"
    "(also an output that cannot be written), 3 solver failure, 4 not converged.\n";

static int parse_doubles(const char* s, double* v, int n) {
    const char* p = s;
    for (int i = 0; i < n; ++i) {
        char* end;
        errno = 0;
        v[i] = strtod(p, &end);
        if (end == p || errno || !isfinite(v[i])) return 0;
        p = end;
        if (i < n - 1) {
            if (*p != ',') return 0;
            ++p;
        }
    }
    return *p == '\0';
}

static int parse_int(const char* s, int* v) {
    char* end;
    errno = 0;
    long x = strtol(s, &end, 10);
    if (end == s || *end || errno || x < 0 || x > 100000000) return 0;
    *v = (int)x;
    return 1;
}

// Whether a new file can be made at path (or an existing one rewritten): checked before the
// solve, which is otherwise lost when the output fails. 0 with errno set when not.
static int writable(const char* path) {
    struct stat sb;
    if (stat(path, &sb) == 0) {
        if (S_ISDIR(sb.st_mode)) {
            errno = EISDIR;
            return 0;
        }
        return access(path, W_OK) == 0;
    }
    if (errno != ENOENT) return 0;
    char dir[4096];
    const char* slash = strrchr(path, '/');
    if (!slash)
        snprintf(dir, sizeof dir, ".");
    else
        snprintf(dir, sizeof dir, "%.*s", slash == path ? 1 : (int)(slash - path), path);
    return access(dir, W_OK | X_OK) == 0;
}

// path as its folder's real path and its own name ("out" and "./out" alike, existing or not);
// 0 when the folder cannot be resolved.
static int canonical(const char* path, char* out, size_t cap) {
    const char* slash = strrchr(path, '/');
    char dir[4096], real[PATH_MAX];
    if (!slash)
        snprintf(dir, sizeof dir, ".");
    else
        snprintf(dir, sizeof dir, "%.*s", slash == path ? 1 : (int)(slash - path), path);
    if (!realpath(dir, real)) return 0;
    int n = snprintf(out, cap, "%s/%s", real, slash ? slash + 1 : path);
    return n > 0 && (size_t)n < cap;
}

// Whether two paths name one file: the same place (spelt either way), or an existing file
// reached twice (a link).
static int same_file(const char* a, const char* b) {
    if (!strcmp(a, b)) return 1;
    char ca[8192], cb[8192];
    if (canonical(a, ca, sizeof ca) && canonical(b, cb, sizeof cb) && !strcmp(ca, cb)) return 1;
    struct stat sa, sb;
    return stat(a, &sa) == 0 && stat(b, &sb) == 0 && sa.st_dev == sb.st_dev &&
           sa.st_ino == sb.st_ino;
}

// Flags that only some models, modes or solvers read (a bit each, in the order of flag_name).
enum {
    F_DT = 1 << 0,
    F_DAMPING = 1 << 1,
    F_TOL = 1 << 2,
    F_MAX_ITER = 1 << 3,
    F_LOAD_STEPS = 1 << 4,
    F_SOLVER = 1 << 5,
    F_PRECOND = 1 << 6,
    F_PCG_ITERS = 1 << 7,
    F_LOCKING_FREE = 1 << 8,
    F_BETA = 1 << 9,
    F_ROTATION = 1 << 10,
    F_INVERSION = 1 << 11,
    F_POLAR_TOL = 1 << 12,
    F_LF_ALPHA = 1 << 13,
    F_PROBE = 1 << 14,
};
static const char* const flag_name[] = {
    "--dt",       "--damping",   "--tol",       "--max-iter",           "--load-steps",
    "--solver",   "--precond",   "--pcg-iters", "--locking-free",       "--beta",
    "--rotation", "--inversion", "--polar-tol", "--locking-free-alpha", "--probe"};

// The static probe reference (hs_press): the body's model and material, a sphere of radius r
// brought to c along dir (NULL: the default approach). Prints the tool force; returns the
// exit status (0 solved, 1 bad input such as a sphere touching nothing, 3 solver failure, 4 not
// converged) and leaves the press in *out for the displacement output.
static int run_probe(const hs_mesh* mesh, const hs_body_def* def, const unsigned char* fixed,
                     const double c[3], double r, const double* dir, int nodes, hs_press** out,
                     hs_press_stats* st) {
    hs_press_def pd = hs_press_default_def();
    pd.surface = !nodes;
    pd.fem = def->fem;
    memcpy(pd.gravity, def->gravity, sizeof pd.gravity);
    pd.radius_m = r;
    pd.tol = def->static_tol;
    pd.max_newton = def->static_max_iter > 300 ? def->static_max_iter : 300;
    hs_err err = {0};
    hs_status s = hs_press_create(mesh, &pd, fixed, out, &err);
    if (s == HS_OK) s = hs_press_solve(*out, c, dir, st, &err);
    if (s != HS_OK) {
        fprintf(stderr, "hapsim-solve: probe: %s\n", err.msg);
        return s == HS_ERR_INVALID ? 1 : s == HS_ERR_NOT_CONVERGED ? 4 : 3;
    }
    printf("probe force N: %.9g,%.9g,%.9g\n", st->force_n[0], st->force_n[1], st->force_n[2]);
    return 0;
}

typedef struct plane_fix {
    int axis, side;
    double tol;
} plane_fix;

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "hapsim-solve")) return 0;
    hs_sparse_blas_select(argv); // before any thread: it may re-execute the program
    const char *mesh_path = NULL, *out_path = NULL, *vtk_path = NULL;
    hs_body_def def = hs_body_default_def();
    def.fem.material.youngs_pa = 5000; // the scene defaults (docs/scenes.md)
    def.fem.material.poisson = 0.45;
    def.fem.material.density_kg_m3 = 1000;
    int have_model = 0, do_static = 0, steps = 0, quiet = 0, have_dt = 0, mooney = 0;
    int lf_mode = HS_LOCKING_FREE_NONE; // -1: the model's default mode
    unsigned given = 0;                 // F_* flags on the command line
    double beta = 0;
    double probe_c[3] = {0}, probe_r = 0, probe_dir[3] = {0};
    int have_probe = 0, have_dir = 0, probe_nodes = 0;
    double boxes[8][6];
    int n_boxes = 0;
    plane_fix planes[8];
    int n_planes = 0;

#define NEED_ARG()                                                                                 \
    do {                                                                                           \
        if (i + 1 >= argc) {                                                                       \
            fprintf(stderr, "hapsim-solve: %s needs a value\n", a);                                \
            return 2;                                                                              \
        }                                                                                          \
    } while (0)
#define BAD(what)                                                                                  \
    do {                                                                                           \
        fprintf(stderr, "hapsim-solve: bad value for %s: '%s' (%s)\n", a, argv[i], what);          \
        return 2;                                                                                  \
    } while (0)

    for (int i = 1; i < argc; ++i) {
        const char* a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            fputs(usage, stdout);
            return 0;
        } else if (!strcmp(a, "-q") || !strcmp(a, "--quiet")) {
            quiet = 1;
        } else if (!strcmp(a, "--static")) {
            do_static = 1;
        } else if (!strcmp(a, "--locking-free")) {
            // MODE is optional so that the older bare flag keeps working (the default mode)
            lf_mode = -1;
            if (i + 1 < argc && strncmp(argv[i + 1], "--", 2) != 0) {
                const char* v = argv[++i];
                if (!strcmp(v, "none"))
                    lf_mode = HS_LOCKING_FREE_NONE;
                else if (!strcmp(v, "anp"))
                    lf_mode = HS_LOCKING_FREE_ANP;
                else if (!strcmp(v, "sns"))
                    lf_mode = HS_LOCKING_FREE_SNS;
                else {
                    fprintf(stderr, "hapsim-solve: --locking-free: '%s' is not none|anp|sns\n", v);
                    return 2;
                }
            }
            given |= F_LOCKING_FREE;
        } else if (!strcmp(a, "--locking-free-alpha")) {
            NEED_ARG();
            double v;
            if (!parse_doubles(argv[++i], &v, 1) || !(v >= 0 && v < 1)) {
                fprintf(stderr, "hapsim-solve: --locking-free-alpha: '%s' is not in [0, 1)\n",
                        argv[i]);
                return 2;
            }
            def.fem.locking_free_alpha = v;
            given |= F_LF_ALPHA;
        } else if (!strcmp(a, "--mesh")) {
            NEED_ARG();
            mesh_path = argv[++i];
        } else if (!strcmp(a, "--out")) {
            NEED_ARG();
            out_path = argv[++i];
        } else if (!strcmp(a, "--vtk")) {
            NEED_ARG();
            vtk_path = argv[++i];
        } else if (!strcmp(a, "--model")) {
            NEED_ARG();
            ++i;
            mooney = 0; // the last --model given counts
            if (!strcmp(argv[i], "linear"))
                def.fem.model = HS_MODEL_LINEAR;
            else if (!strcmp(argv[i], "corotated"))
                def.fem.model = HS_MODEL_COROTATED;
            else if (!strcmp(argv[i], "stvk"))
                def.fem.model = HS_MODEL_STVK;
            else if (!strcmp(argv[i], "mooney"))
                mooney = 1;
            else
                BAD("expected linear, corotated, stvk or mooney");
            have_model = 1;
        } else if (!strcmp(a, "--E")) {
            NEED_ARG();
            ++i;
            if (!parse_doubles(argv[i], &def.fem.material.youngs_pa, 1) ||
                def.fem.material.youngs_pa <= 0)
                BAD("a positive number of pascals");
        } else if (!strcmp(a, "--beta")) {
            NEED_ARG();
            ++i;
            if (!parse_doubles(argv[i], &beta, 1) || beta < 0) BAD("a stabilisation >= 0");
            given |= F_BETA;
        } else if (!strcmp(a, "--nu")) {
            NEED_ARG();
            ++i;
            double nu;
            if (!parse_doubles(argv[i], &nu, 1) || nu <= -1 || nu >= 0.5)
                BAD("a Poisson ratio in (-1, 0.5)");
            def.fem.material.poisson = nu;
        } else if (!strcmp(a, "--density")) {
            NEED_ARG();
            ++i;
            if (!parse_doubles(argv[i], &def.fem.material.density_kg_m3, 1) ||
                def.fem.material.density_kg_m3 <= 0)
                BAD("a positive density in kg/m^3");
        } else if (!strcmp(a, "--gravity")) {
            NEED_ARG();
            ++i;
            if (!parse_doubles(argv[i], def.gravity, 3)) BAD("GX,GY,GZ in m/s^2");
        } else if (!strcmp(a, "--fix-box")) {
            NEED_ARG();
            ++i;
            if (n_boxes == 8) BAD("at most 8 boxes");
            double* bx = boxes[n_boxes];
            if (!parse_doubles(argv[i], bx, 6) || bx[0] > bx[3] || bx[1] > bx[4] || bx[2] > bx[5])
                BAD("XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX with min <= max");
            ++n_boxes;
        } else if (!strcmp(a, "--fix-plane")) {
            NEED_ARG();
            ++i;
            if (n_planes == 8) BAD("at most 8 planes");
            const char* v = argv[i];
            double tol;
            // AXIS,SIDE,TOL: the tolerance parsed as every other number (finite, nothing after)
            if (!strchr("xyz", v[0]) || !v[0] || v[1] != ',' ||
                (strncmp(v + 2, "min,", 4) && strncmp(v + 2, "max,", 4)) ||
                !parse_doubles(v + 6, &tol, 1) || tol < 0)
                BAD("AXIS,SIDE,TOL as in x,min,1e-6");
            const char axis[1] = {v[0]}, side[2] = {v[2], v[3]};
            planes[n_planes].axis = axis[0] - 'x';
            planes[n_planes].side = side[1] == 'i' ? -1 : 1;
            planes[n_planes].tol = tol;
            ++n_planes;
        } else if (!strcmp(a, "--steps")) {
            NEED_ARG();
            ++i;
            if (!parse_int(argv[i], &steps) || steps < 1) BAD("a positive step count");
        } else if (!strcmp(a, "--dt")) {
            NEED_ARG();
            ++i;
            if (!parse_doubles(argv[i], &def.dt, 1) || def.dt <= 0) BAD("a positive time step");
            have_dt = 1;
            given |= F_DT;
        } else if (!strcmp(a, "--tol")) {
            NEED_ARG();
            ++i;
            if (!parse_doubles(argv[i], &def.static_tol, 1) || def.static_tol <= 0)
                BAD("a positive tolerance");
            given |= F_TOL;
        } else if (!strcmp(a, "--max-iter")) {
            NEED_ARG();
            ++i;
            if (!parse_int(argv[i], &def.static_max_iter) || def.static_max_iter < 1)
                BAD("a positive count");
            given |= F_MAX_ITER;
        } else if (!strcmp(a, "--load-steps")) {
            NEED_ARG();
            ++i;
            if (!parse_int(argv[i], &def.static_load_steps) || def.static_load_steps < 1)
                BAD("a positive count");
            given |= F_LOAD_STEPS;
        } else if (!strcmp(a, "--rotation")) {
            NEED_ARG();
            ++i;
            if (!strcmp(argv[i], "polar"))
                def.fem.rotation = HS_ROTATION_POLAR;
            else if (!strcmp(argv[i], "svd"))
                def.fem.rotation = HS_ROTATION_SVD;
            else
                BAD("polar or svd");
            given |= F_ROTATION;
        } else if (!strcmp(a, "--polar-tol")) {
            NEED_ARG();
            ++i;
            if (!parse_doubles(argv[i], &def.fem.polar_tol, 1) || def.fem.polar_tol <= 0)
                BAD("a positive tolerance");
            def.step_polar_tol = def.fem.polar_tol; // the one given, static or steps
            given |= F_POLAR_TOL;
        } else if (!strcmp(a, "--inversion")) {
            NEED_ARG();
            ++i;
            if (!strcmp(argv[i], "fallback"))
                def.fem.inversion = HS_INVERSION_LINEAR_FALLBACK;
            else if (!strcmp(argv[i], "reflect"))
                def.fem.inversion = HS_INVERSION_KEEP_REFLECTION;
            else
                BAD("fallback or reflect");
            given |= F_INVERSION;
        } else if (!strcmp(a, "--damping")) {
            NEED_ARG();
            ++i;
            double d[2];
            if (!parse_doubles(argv[i], d, 2) || d[0] < 0 || d[1] < 0) BAD("ALPHA,BETA >= 0");
            def.fem.material.rayleigh_mass = d[0];
            def.fem.material.rayleigh_stiffness = d[1];
            given |= F_DAMPING;
        } else if (!strcmp(a, "--solver")) {
            NEED_ARG();
            ++i;
            if (!strcmp(argv[i], "direct"))
                def.solver = HS_SOLVER_DIRECT;
            else if (!strcmp(argv[i], "pcg"))
                def.solver = HS_SOLVER_PCG;
            else if (!strcmp(argv[i], "warped"))
                def.solver = HS_SOLVER_WARPED;
            else
                BAD("direct, pcg or warped");
            given |= F_SOLVER;
        } else if (!strcmp(a, "--precond")) {
            NEED_ARG();
            ++i;
            if (!strcmp(argv[i], "none"))
                def.precond = HS_PRECOND_NONE;
            else if (!strcmp(argv[i], "jacobi"))
                def.precond = HS_PRECOND_JACOBI;
            else if (!strcmp(argv[i], "factor"))
                def.precond = HS_PRECOND_FACTOR;
            else if (!strcmp(argv[i], "warped"))
                def.precond = HS_PRECOND_WARPED;
            else
                BAD("none, jacobi, factor or warped");
            given |= F_PRECOND;
        } else if (!strcmp(a, "--probe")) {
            NEED_ARG();
            ++i;
            if (!parse_doubles(argv[i], probe_c, 3)) BAD("X,Y,Z in metres");
            have_probe = 1;
            given |= F_PROBE;
        } else if (!strcmp(a, "--probe-contact")) {
            NEED_ARG();
            ++i;
            if (strcmp(argv[i], "surface") && strcmp(argv[i], "nodes")) BAD("surface or nodes");
            probe_nodes = !strcmp(argv[i], "nodes");
            given |= F_PROBE;
        } else if (!strcmp(a, "--probe-radius")) {
            NEED_ARG();
            ++i;
            if (!parse_doubles(argv[i], &probe_r, 1) || probe_r <= 0) BAD("a positive radius in m");
            given |= F_PROBE;
        } else if (!strcmp(a, "--probe-dir")) {
            NEED_ARG();
            ++i;
            if (!parse_doubles(argv[i], probe_dir, 3) ||
                (probe_dir[0] == 0 && probe_dir[1] == 0 && probe_dir[2] == 0))
                BAD("DX,DY,DZ, not all zero");
            have_dir = 1;
            given |= F_PROBE;
        } else if (!strcmp(a, "--pcg-iters")) {
            NEED_ARG();
            ++i;
            if (!parse_int(argv[i], &def.pcg_max_iter) || def.pcg_max_iter < 1)
                BAD("a positive count");
            given |= F_PCG_ITERS;
        } else {
            fprintf(stderr, "hapsim-solve: unknown option '%s' (see --help)\n", a);
            return 2;
        }
    }
    if (!mesh_path || !out_path || !have_model) {
        fprintf(stderr, "hapsim-solve: --mesh, --model and --out are required (see --help)\n");
        return 2;
    }
    if (do_static == (steps > 0)) {
        fprintf(stderr, "hapsim-solve: give exactly one of --static or --steps N --dt S\n");
        return 2;
    }
    def.fem.locking_free = lf_mode >= 0 ? lf_mode : hs_fem_locking_free_default(def.fem.model);
    if ((given & F_LF_ALPHA) && def.fem.locking_free != HS_LOCKING_FREE_SNS) {
        fprintf(stderr, "hapsim-solve: --locking-free-alpha needs --locking-free sns\n");
        return 2;
    }
    if (mooney && !do_static) {
        fprintf(stderr, "hapsim-solve: --model mooney is a static reference: use --static\n");
        return 2;
    }
    if ((given & F_PROBE) && (!have_probe || probe_r <= 0)) {
        fprintf(stderr, "hapsim-solve: --probe X,Y,Z and --probe-radius R go together\n");
        return 2;
    }
    if (steps > 0 && !have_dt) {
        fprintf(stderr, "hapsim-solve: --steps needs --dt\n");
        return 2;
    }
    // A flag that nothing reads in this run would be silently ignored: refuse it, saying why.
    // Mooney has its own Newton solver and law; a static solve has no time step and no damping
    // (the warped solver solves it with the exact tangent); the element rotations are the
    // co-rotated model's, polar_tol also the warped node rotations'.
    const int pcg = def.solver == HS_SOLVER_PCG, corot = def.fem.model == HS_MODEL_COROTATED;
    const int polar = corot || (!do_static && def.solver == HS_SOLVER_WARPED) ||
                      (pcg && def.precond == HS_PRECOND_WARPED);
    const struct {
        unsigned flags;
        int unread;
        const char* why;
    } rules[] = {
        {F_LOCKING_FREE | F_LF_ALPHA | F_SOLVER | F_PRECOND | F_PCG_ITERS | F_ROTATION |
             F_INVERSION | F_POLAR_TOL,
         mooney, "--model mooney has its own solver and material law"},
        {F_BETA, !mooney, "only --model mooney reads it"},
        {F_PROBE, !do_static || mooney,
         "the probe is a --static reference of linear, corotated "
         "or stvk"},
        {F_SOLVER | F_PRECOND | F_PCG_ITERS | F_LOAD_STEPS | F_LOCKING_FREE | F_LF_ALPHA,
         have_probe,
         "the probe solve has its own direct Newton solver and sphere increments (locking-free: "
         "not supported)"},
        {F_DT | F_DAMPING, do_static, "--static has no time step and no damping"},
        {F_TOL | F_MAX_ITER | F_LOAD_STEPS, !do_static, "only --static reads it"},
        {F_PRECOND | F_PCG_ITERS, !pcg, "only --solver pcg reads it"},
        {F_ROTATION | F_INVERSION, !corot, "only --model corotated reads it"},
        {F_POLAR_TOL, !polar,
         "only the co-rotated model's rotations and warped node rotations (--solver warped "
         "steps, --solver pcg's default preconditioner) read it"},
    };
    for (size_t r = 0; r < sizeof rules / sizeof rules[0]; ++r) {
        unsigned bad = rules[r].unread ? given & rules[r].flags : 0;
        if (bad) {
            int b = 0;
            while (!(bad & 1u << b)) ++b;
            fprintf(stderr, "hapsim-solve: %s has no effect here: %s\n", flag_name[b],
                    rules[r].why);
            return 2;
        }
    }
    const char* outs[2] = {out_path, vtk_path};
    for (int k = 0; k < 2; ++k)
        if (outs[k] && !writable(outs[k])) {
            fprintf(stderr, "hapsim-solve: cannot write %s: %s\n", outs[k], strerror(errno));
            return 2;
        }
    if (vtk_path && same_file(out_path, vtk_path)) {
        fprintf(stderr, "hapsim-solve: --out and --vtk name the same file (%s)\n", out_path);
        return 2;
    }

    // From here on every exit goes through `done`, which frees what was made.
    int rc = 0;
    hs_err err = {0};
    hs_mesh* mesh = NULL;
    unsigned char *fixed = NULL, *mask = NULL;
    hs_body* body = NULL;
    hs_mooney* mr = NULL;
    hs_press* press = NULL;
    hs_press_stats pst = {0};
    hs_status load_st = hs_mesh_load(mesh_path, &mesh, &err);
    if (load_st < 0) {
        fprintf(stderr, "hapsim-solve: %s\n", err.msg);
        rc = 1;
        goto done;
    }
    if (load_st == HS_WARN_MESH_REPAIRED) { // repairs are never silent
        char rep[512];
        hs_mesh_report_str(&mesh->report, rep, sizeof rep);
        fprintf(stderr, "hapsim-solve: %s was repaired on loading:\n%s", mesh_path, rep);
    }
    fixed = calloc((size_t)mesh->n_nodes, 1);
    mask = calloc((size_t)mesh->n_nodes, 1);
    if (!fixed || !mask) {
        fprintf(stderr, "hapsim-solve: out of memory\n");
        rc = 1;
        goto done;
    }
    for (int b = 0; b < n_boxes; ++b) {
        hs_mesh_select_box(mesh, boxes[b], boxes[b] + 3, mask);
        for (int i = 0; i < mesh->n_nodes; ++i) fixed[i] |= mask[i];
    }
    for (int p = 0; p < n_planes; ++p) {
        if (hs_mesh_select_plane(mesh, planes[p].axis, planes[p].side, planes[p].tol, mask) < 0) {
            fprintf(stderr, "hapsim-solve: --fix-plane %d: invalid\n", p + 1);
            rc = 1;
            goto done;
        }
        for (int i = 0; i < mesh->n_nodes; ++i) fixed[i] |= mask[i];
    }
    // Only nodes of a tet count: a node no tet uses carries nothing and holds nothing.
    int n_fixed = 0, n_used = 0;
    for (int i = 0; i < mesh->n_nodes; ++i) {
        n_used += mesh->node_used[i] != 0;
        n_fixed += fixed[i] && mesh->node_used[i];
    }
    if (n_fixed == 0) {
        fprintf(stderr,
                "hapsim-solve: no node of a tet is fixed: give --fix-box or --fix-plane that "
                "contains nodes (bbox %g,%g,%g .. %g,%g,%g)\n",
                mesh->bbox_min[0], mesh->bbox_min[1], mesh->bbox_min[2], mesh->bbox_max[0],
                mesh->bbox_max[1], mesh->bbox_max[2]);
        rc = 1;
        goto done;
    }
    if (n_fixed == n_used) {
        fprintf(stderr,
                "hapsim-solve: the fixed regions hold every node of the mesh's %d tets: "
                "nothing is left to move\n",
                mesh->n_tets);
        rc = 1;
        goto done;
    }

    hs_step_stats st = {0};
    double total_ms = 0;
    int iters = 0, lin_iters = 0;
    hs_status s = HS_OK;
    if (mooney) {
        hs_mooney_def md = hs_mooney_default_def();
        md.youngs_pa = def.fem.material.youngs_pa;
        md.poisson = def.fem.material.poisson;
        md.density_kg_m3 = def.fem.material.density_kg_m3;
        md.beta = beta;
        md.tolerance = def.static_tol;
        md.max_newton_iter = def.static_max_iter;
        md.load_steps = def.static_load_steps;
        if (hs_mooney_create(mesh, &md, fixed, &mr, &err) < 0 ||
            hs_mooney_set_gravity(mr, def.gravity) < 0) {
            fprintf(stderr, "hapsim-solve: %s\n", err.msg);
            rc = 1;
            goto done;
        }
        hs_mooney_stats ms;
        s = hs_mooney_solve_static(mr, &ms, &err);
        total_ms = ms.solve_ms;
        iters = ms.newton_total;
        st.residual = ms.final_ratio;
        st.fem.volume_ratio_min = ms.volume_ratio_min;
        st.fem.volume_ratio_max = ms.volume_ratio_max;
        st.fem.volume_ratio_mean = ms.volume_ratio_total; // whole-mesh ratio for this model
    } else {
        if (hs_body_create(mesh, &def, fixed, &body, &err) < 0 ||
            (do_static && hs_body_check_static(body, &err) != HS_OK)) {
            fprintf(stderr, "hapsim-solve: %s\n", err.msg);
            rc = 1;
            goto done;
        }
        if (have_probe) {
            rc = run_probe(mesh, &def, fixed, probe_c, probe_r, have_dir ? probe_dir : NULL,
                           probe_nodes, &press, &pst);
            total_ms = pst.wall_ms;
            iters = pst.newton;
            st.residual = pst.residual;
            if (rc == 1 || rc == 3) goto done; // nothing to write: no answer
        } else if (do_static) {
            s = hs_body_solve_static(body, &st);
            total_ms = st.wall_ms;
            iters = st.iterations;
            lin_iters = st.linear_iterations;
        } else {
            for (int k = 0; k < steps && s >= 0; ++k) {
                s = hs_body_step(body, &st);
                total_ms += st.wall_ms;
                iters += st.iterations;
                lin_iters += st.linear_iterations;
            }
        }
    }
    if (s < 0) {
        fprintf(stderr, "hapsim-solve: solver failed: %s%s%s\n", hs_status_str(s),
                mooney && err.msg[0] ? ": " : "", mooney ? err.msg : "");
        rc = 3;
    } else if (s == HS_WARN_NOT_CONVERGED) {
        fprintf(stderr, "hapsim-solve: warning: not converged (residual ratio %.3g > %.3g)\n",
                st.residual, def.static_tol);
        rc = 4;
    }

    // A failed solve writes nothing: its state is not an answer.
    const double* u = mooney  ? hs_mooney_displacement(mr)
                      : press ? hs_press_displacement(press)
                              : hs_body_displacement(body);
    int wrote = 0;
    if (rc != 3) {
        FILE* f = fopen(out_path, "w");
        if (!f) {
            fprintf(stderr, "hapsim-solve: cannot write %s: %s\n", out_path, strerror(errno));
            rc = 1;
        } else {
            fprintf(f, "ux,uy,uz\n");
            for (int i = 0; i < mesh->n_nodes; ++i)
                fprintf(f, "%.9e,%.9e,%.9e\n", u[3 * i], u[3 * i + 1], u[3 * i + 2]);
            int bad = ferror(f);
            if (fclose(f) != 0 || bad) {
                fprintf(stderr, "hapsim-solve: error writing %s: %s\n", out_path, strerror(errno));
                rc = 1;
            } else {
                wrote = 1;
            }
        }
        if (vtk_path && hs_mesh_write_vtk(mesh, u, vtk_path, &err) < 0) {
            fprintf(stderr, "hapsim-solve: %s\n", err.msg);
            rc = 1;
        }
    }
    if (!quiet) {
        double umax = 0;
        int imax = 0;
        for (int i = 0; i < mesh->n_nodes; ++i) {
            double m = sqrt(u[3 * i] * u[3 * i] + u[3 * i + 1] * u[3 * i + 1] +
                            u[3 * i + 2] * u[3 * i + 2]);
            if (m > umax) umax = m, imax = i;
        }
        printf("mesh            %s: %d nodes, %d tets, %d fixed\n", mesh_path, mesh->n_nodes,
               mesh->n_tets, n_fixed);
        printf("max |u|         %.6e m at node %d\n", umax, imax);
        printf("volume ratio    %s %.5f min %.5f max %.5f, inverted %d\n",
               mooney ? "total" : "mean", st.fem.volume_ratio_mean, st.fem.volume_ratio_min,
               st.fem.volume_ratio_max, st.fem.inverted);
        if (press)
            printf("probe           r %g m, %d contact %s, %d increments, %d passes, %d "
                   "Newton (residual ratio %.2e, penetration %.2e r, longest contact edge "
                   "%.3g m)\n",
                   probe_r, pst.active, probe_nodes ? "nodes" : "triangles", pst.increments,
                   pst.passes, iters, pst.residual, pst.penetration_m / probe_r, pst.max_edge_m);
        else if (do_static)
            printf("iterations      %d Newton (residual ratio %.2e)\n", iters, st.residual);
        else
            printf("steps           %d x %g s, %d Newton iterations\n", steps, def.dt, iters);
        if (def.solver == HS_SOLVER_PCG) printf("pcg iterations  %d\n", lin_iters);
        printf("time            %.3f ms%s\n", total_ms, do_static ? "" : " (sum of steps)");
        if (wrote)
            printf("wrote           %s\n", out_path);
        else
            printf("wrote           nothing (%s)\n",
                   rc == 3 ? "the solve failed" : "the output failed");
    }
done:
    hs_body_destroy(&body);
    hs_press_destroy(&press);
    hs_mooney_destroy(&mr);
    hs_mesh_destroy(&mesh);
    free(fixed);
    free(mask);
    return rc;
}
