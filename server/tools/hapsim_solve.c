// SPDX-License-Identifier: GPL-2.0-or-later
// hapsim-solve: load a mesh, fix a region, apply gravity, and solve statically or run implicit
// dynamics with a chosen element model. Writes the nodal displacement as CSV.
#define _XOPEN_SOURCE 700 // realpath, stat
#include "hapsim/version.h"
#include "body.h"
#include "mesh.h"
#include "mooney.h"
#include "platform.h"
#include "press.h"
#include "sparse.h"

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

// The command line, parsed.
typedef struct solve_opts {
    const char *mesh_path, *out_path, *vtk_path;
    hs_body_def def;
    int have_model, do_static, steps, quiet, have_dt, mooney;
    int lf_mode;    // -1: the model's default mode
    unsigned given; // F_* flags on the command line
    double beta;
    double probe_c[3], probe_r, probe_dir[3];
    int have_probe, have_dir, probe_nodes;
    double boxes[8][6];
    int n_boxes;
    plane_fix planes[8];
    int n_planes;
} solve_opts;

// An option's value did not parse: say so; the exit status (2).
static int bad_value(const char* a, const char* v, const char* what) {
    fprintf(stderr, "hapsim-solve: bad value for %s: '%s' (%s)\n", a, v, what);
    return 2;
}

// One of several words: its index, -1 for none.
static int pick(const char* v, const char* const* words, int n) {
    for (int k = 0; k < n; ++k)
        if (!strcmp(v, words[k])) return k;
    return -1;
}

// The material and model options: 1 taken, 0 not one of them, 2 bad (said).
static int material_option(solve_opts* o, const char* a, const char* v) {
    hs_fem_def* fem = &o->def.fem;
    if (!strcmp(a, "--locking-free-alpha")) {
        double x;
        if (!parse_doubles(v, &x, 1) || !(x >= 0 && x < 1)) {
            fprintf(stderr, "hapsim-solve: --locking-free-alpha: '%s' is not in [0, 1)\n", v);
            return 2;
        }
        fem->locking_free_alpha = x;
        o->given |= F_LF_ALPHA;
    } else if (!strcmp(a, "--model")) {
        static const char* const names[] = {"linear", "corotated", "stvk", "mooney"};
        static const hs_model models[] = {HS_MODEL_LINEAR, HS_MODEL_COROTATED, HS_MODEL_STVK};
        int k = pick(v, names, 4);
        if (k < 0) return bad_value(a, v, "expected linear, corotated, stvk or mooney");
        o->mooney = k == 3; // the last --model given counts
        if (k < 3) fem->model = models[k];
        o->have_model = 1;
    } else if (!strcmp(a, "--E")) {
        if (!parse_doubles(v, &fem->material.youngs_pa, 1) || fem->material.youngs_pa <= 0)
            return bad_value(a, v, "a positive number of pascals");
    } else if (!strcmp(a, "--beta")) {
        if (!parse_doubles(v, &o->beta, 1) || o->beta < 0)
            return bad_value(a, v, "a stabilisation >= 0");
        o->given |= F_BETA;
    } else if (!strcmp(a, "--nu")) {
        double nu;
        if (!parse_doubles(v, &nu, 1) || nu <= -1 || nu >= 0.5)
            return bad_value(a, v, "a Poisson ratio in (-1, 0.5)");
        fem->material.poisson = nu;
    } else if (!strcmp(a, "--density")) {
        if (!parse_doubles(v, &fem->material.density_kg_m3, 1) || fem->material.density_kg_m3 <= 0)
            return bad_value(a, v, "a positive density in kg/m^3");
    } else if (!strcmp(a, "--gravity")) {
        if (!parse_doubles(v, o->def.gravity, 3)) return bad_value(a, v, "GX,GY,GZ in m/s^2");
    } else if (!strcmp(a, "--rotation")) {
        static const char* const names[] = {"polar", "svd"};
        int k = pick(v, names, 2);
        if (k < 0) return bad_value(a, v, "polar or svd");
        fem->rotation = k ? HS_ROTATION_SVD : HS_ROTATION_POLAR;
        o->given |= F_ROTATION;
    } else if (!strcmp(a, "--polar-tol")) {
        if (!parse_doubles(v, &fem->polar_tol, 1) || fem->polar_tol <= 0)
            return bad_value(a, v, "a positive tolerance");
        o->def.step_polar_tol = fem->polar_tol; // the one given, static or steps
        o->given |= F_POLAR_TOL;
    } else if (!strcmp(a, "--inversion")) {
        static const char* const names[] = {"fallback", "reflect"};
        int k = pick(v, names, 2);
        if (k < 0) return bad_value(a, v, "fallback or reflect");
        fem->inversion = k ? HS_INVERSION_KEEP_REFLECTION : HS_INVERSION_LINEAR_FALLBACK;
        o->given |= F_INVERSION;
    } else if (!strcmp(a, "--damping")) {
        double d[2];
        if (!parse_doubles(v, d, 2) || d[0] < 0 || d[1] < 0)
            return bad_value(a, v, "ALPHA,BETA >= 0");
        fem->material.rayleigh_mass = d[0];
        fem->material.rayleigh_stiffness = d[1];
        o->given |= F_DAMPING;
    } else {
        return 0;
    }
    return 1;
}

// The boundary and probe options: 1 taken, 0 not one of them, 2 bad (said).
static int region_option(solve_opts* o, const char* a, const char* v) {
    if (!strcmp(a, "--fix-box")) {
        if (o->n_boxes == 8) return bad_value(a, v, "at most 8 boxes");
        double* bx = o->boxes[o->n_boxes];
        if (!parse_doubles(v, bx, 6) || bx[0] > bx[3] || bx[1] > bx[4] || bx[2] > bx[5])
            return bad_value(a, v, "XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX with min <= max");
        ++o->n_boxes;
    } else if (!strcmp(a, "--fix-plane")) {
        if (o->n_planes == 8) return bad_value(a, v, "at most 8 planes");
        double tol;
        // AXIS,SIDE,TOL: the tolerance parsed as every other number (finite, nothing after)
        if (!strchr("xyz", v[0]) || !v[0] || v[1] != ',' ||
            (strncmp(v + 2, "min,", 4) && strncmp(v + 2, "max,", 4)) ||
            !parse_doubles(v + 6, &tol, 1) || tol < 0)
            return bad_value(a, v, "AXIS,SIDE,TOL as in x,min,1e-6");
        plane_fix* p = &o->planes[o->n_planes++];
        p->axis = v[0] - 'x';
        p->side = v[3] == 'i' ? -1 : 1;
        p->tol = tol;
    } else if (!strcmp(a, "--probe")) {
        if (!parse_doubles(v, o->probe_c, 3)) return bad_value(a, v, "X,Y,Z in metres");
        o->have_probe = 1;
        o->given |= F_PROBE;
    } else if (!strcmp(a, "--probe-contact")) {
        if (strcmp(v, "surface") && strcmp(v, "nodes")) return bad_value(a, v, "surface or nodes");
        o->probe_nodes = !strcmp(v, "nodes");
        o->given |= F_PROBE;
    } else if (!strcmp(a, "--probe-radius")) {
        if (!parse_doubles(v, &o->probe_r, 1) || o->probe_r <= 0)
            return bad_value(a, v, "a positive radius in m");
        o->given |= F_PROBE;
    } else if (!strcmp(a, "--probe-dir")) {
        const double* d = o->probe_dir;
        if (!parse_doubles(v, o->probe_dir, 3) || (d[0] == 0 && d[1] == 0 && d[2] == 0))
            return bad_value(a, v, "DX,DY,DZ, not all zero");
        o->have_dir = 1;
        o->given |= F_PROBE;
    } else {
        return 0;
    }
    return 1;
}

// The solver and stepping options: 1 taken, 0 not one of them, 2 bad (said).
static int solver_option(solve_opts* o, const char* a, const char* v) {
    hs_body_def* def = &o->def;
    if (!strcmp(a, "--steps")) {
        if (!parse_int(v, &o->steps) || o->steps < 1)
            return bad_value(a, v, "a positive step count");
    } else if (!strcmp(a, "--dt")) {
        if (!parse_doubles(v, &def->dt, 1) || def->dt <= 0)
            return bad_value(a, v, "a positive time step");
        o->have_dt = 1;
        o->given |= F_DT;
    } else if (!strcmp(a, "--tol")) {
        if (!parse_doubles(v, &def->static_tol, 1) || def->static_tol <= 0)
            return bad_value(a, v, "a positive tolerance");
        o->given |= F_TOL;
    } else if (!strcmp(a, "--max-iter")) {
        if (!parse_int(v, &def->static_max_iter) || def->static_max_iter < 1)
            return bad_value(a, v, "a positive count");
        o->given |= F_MAX_ITER;
    } else if (!strcmp(a, "--load-steps")) {
        if (!parse_int(v, &def->static_load_steps) || def->static_load_steps < 1)
            return bad_value(a, v, "a positive count");
        o->given |= F_LOAD_STEPS;
    } else if (!strcmp(a, "--solver")) {
        static const char* const names[] = {"direct", "pcg", "warped"};
        static const hs_solver_kind solvers[] = {HS_SOLVER_DIRECT, HS_SOLVER_PCG, HS_SOLVER_WARPED};
        int k = pick(v, names, 3);
        if (k < 0) return bad_value(a, v, "direct, pcg or warped");
        def->solver = solvers[k];
        o->given |= F_SOLVER;
    } else if (!strcmp(a, "--precond")) {
        static const char* const names[] = {"none", "jacobi", "factor", "warped"};
        static const hs_precond pre[] = {HS_PRECOND_NONE, HS_PRECOND_JACOBI, HS_PRECOND_FACTOR,
                                         HS_PRECOND_WARPED};
        int k = pick(v, names, 4);
        if (k < 0) return bad_value(a, v, "none, jacobi, factor or warped");
        def->precond = pre[k];
        o->given |= F_PRECOND;
    } else if (!strcmp(a, "--pcg-iters")) {
        if (!parse_int(v, &def->pcg_max_iter) || def->pcg_max_iter < 1)
            return bad_value(a, v, "a positive count");
        o->given |= F_PCG_ITERS;
    } else {
        return 0;
    }
    return 1;
}

// --locking-free [MODE]: MODE is optional so that the older bare flag keeps working (the
// default mode). 0, or the exit status (2).
static int locking_free_option(solve_opts* o, int argc, char** argv, int* i) {
    o->lf_mode = -1;
    o->given |= F_LOCKING_FREE;
    if (*i + 1 >= argc || strncmp(argv[*i + 1], "--", 2) == 0) return 0;
    static const char* const names[] = {"none", "anp", "sns"};
    static const int modes[] = {HS_LOCKING_FREE_NONE, HS_LOCKING_FREE_ANP, HS_LOCKING_FREE_SNS};
    const char* v = argv[++*i];
    int k = pick(v, names, 3);
    if (k < 0) {
        fprintf(stderr, "hapsim-solve: --locking-free: '%s' is not none|anp|sns\n", v);
        return 2;
    }
    o->lf_mode = modes[k];
    return 0;
}

// The command line into o: -1 to go on, else the exit status (0 after --help, 2 bad usage).
static int parse_args(int argc, char** argv, solve_opts* o) {
    static const char* const with_value[] = {"--mesh",          "--out",
                                             "--vtk",           "--locking-free-alpha",
                                             "--model",         "--E",
                                             "--beta",          "--nu",
                                             "--density",       "--gravity",
                                             "--rotation",      "--polar-tol",
                                             "--inversion",     "--damping",
                                             "--fix-box",       "--fix-plane",
                                             "--probe",         "--probe-radius",
                                             "--probe-contact", "--probe-dir",
                                             "--steps",         "--dt",
                                             "--tol",           "--max-iter",
                                             "--load-steps",    "--solver",
                                             "--precond",       "--pcg-iters"};
    for (int i = 1; i < argc; ++i) {
        const char* a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) {
            fputs(usage, stdout);
            return 0;
        }
        if (!strcmp(a, "-q") || !strcmp(a, "--quiet")) {
            o->quiet = 1;
            continue;
        }
        if (!strcmp(a, "--static")) {
            o->do_static = 1;
            continue;
        }
        if (!strcmp(a, "--locking-free")) {
            if (locking_free_option(o, argc, argv, &i)) return 2;
            continue;
        }
        if (pick(a, with_value, (int)(sizeof with_value / sizeof *with_value)) < 0) {
            fprintf(stderr, "hapsim-solve: unknown option '%s' (see --help)\n", a);
            return 2;
        }
        if (i + 1 >= argc) {
            fprintf(stderr, "hapsim-solve: %s needs a value\n", a);
            return 2;
        }
        const char* v = argv[++i];
        if (!strcmp(a, "--mesh"))
            o->mesh_path = v;
        else if (!strcmp(a, "--out"))
            o->out_path = v;
        else if (!strcmp(a, "--vtk"))
            o->vtk_path = v;
        else if (material_option(o, a, v) == 2 || region_option(o, a, v) == 2 ||
                 solver_option(o, a, v) == 2)
            return 2;
    }
    return -1;
}

// Combinations the run cannot take: 0, or the exit status (2) after saying why.
static int check_options(solve_opts* o) {
    hs_body_def* def = &o->def;
    if (!o->mesh_path || !o->out_path || !o->have_model) {
        fprintf(stderr, "hapsim-solve: --mesh, --model and --out are required (see --help)\n");
        return 2;
    }
    if (o->do_static == (o->steps > 0)) {
        fprintf(stderr, "hapsim-solve: give exactly one of --static or --steps N --dt S\n");
        return 2;
    }
    def->fem.locking_free =
        o->lf_mode >= 0 ? o->lf_mode : hs_fem_locking_free_default(def->fem.model);
    if ((o->given & F_LF_ALPHA) && def->fem.locking_free != HS_LOCKING_FREE_SNS) {
        fprintf(stderr, "hapsim-solve: --locking-free-alpha needs --locking-free sns\n");
        return 2;
    }
    if (o->mooney && !o->do_static) {
        fprintf(stderr, "hapsim-solve: --model mooney is a static reference: use --static\n");
        return 2;
    }
    if ((o->given & F_PROBE) && (!o->have_probe || o->probe_r <= 0)) {
        fprintf(stderr, "hapsim-solve: --probe X,Y,Z and --probe-radius R go together\n");
        return 2;
    }
    if (o->steps > 0 && !o->have_dt) {
        fprintf(stderr, "hapsim-solve: --steps needs --dt\n");
        return 2;
    }
    // A flag that nothing reads in this run would be silently ignored: refuse it, saying why.
    // Mooney has its own Newton solver and law; a static solve has no time step and no damping
    // (the warped solver solves it with the exact tangent); the element rotations are the
    // co-rotated model's, polar_tol also the warped node rotations'.
    const int mooney = o->mooney, do_static = o->do_static;
    const int pcg = def->solver == HS_SOLVER_PCG, corot = def->fem.model == HS_MODEL_COROTATED;
    const int polar = corot || (!do_static && def->solver == HS_SOLVER_WARPED) ||
                      (pcg && def->precond == HS_PRECOND_WARPED);
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
         o->have_probe,
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
        unsigned bad = rules[r].unread ? o->given & rules[r].flags : 0;
        if (bad) {
            int b = 0;
            while (!(bad & 1u << b)) ++b;
            fprintf(stderr, "hapsim-solve: %s has no effect here: %s\n", flag_name[b],
                    rules[r].why);
            return 2;
        }
    }
    const char* outs[2] = {o->out_path, o->vtk_path};
    for (int k = 0; k < 2; ++k)
        if (outs[k] && !writable(outs[k])) {
            fprintf(stderr, "hapsim-solve: cannot write %s: %s\n", outs[k], strerror(errno));
            return 2;
        }
    if (o->vtk_path && same_file(o->out_path, o->vtk_path)) {
        fprintf(stderr, "hapsim-solve: --out and --vtk name the same file (%s)\n", o->out_path);
        return 2;
    }
    return 0;
}

// The fixed nodes from the boxes and planes: 0, or the exit status (1) after saying why.
static int fix_nodes(const hs_mesh* mesh, const solve_opts* o, unsigned char* fixed,
                     unsigned char* mask, int* n_fixed_out) {
    for (int b = 0; b < o->n_boxes; ++b) {
        hs_mesh_select_box(mesh, o->boxes[b], o->boxes[b] + 3, mask);
        for (int i = 0; i < mesh->n_nodes; ++i) fixed[i] |= mask[i];
    }
    for (int p = 0; p < o->n_planes; ++p) {
        const plane_fix* pl = &o->planes[p];
        if (hs_mesh_select_plane(mesh, pl->axis, pl->side, pl->tol, mask) < 0) {
            fprintf(stderr, "hapsim-solve: --fix-plane %d: invalid\n", p + 1);
            return 1;
        }
        for (int i = 0; i < mesh->n_nodes; ++i) fixed[i] |= mask[i];
    }
    // Only nodes of a tet count: a node no tet uses carries nothing and holds nothing.
    int n_fixed = 0, n_used = 0;
    for (int i = 0; i < mesh->n_nodes; ++i) {
        n_used += mesh->node_used[i] != 0;
        n_fixed += fixed[i] && mesh->node_used[i];
    }
    *n_fixed_out = n_fixed;
    if (n_fixed == 0) {
        fprintf(stderr,
                "hapsim-solve: no node of a tet is fixed: give --fix-box or --fix-plane that "
                "contains nodes (bbox %g,%g,%g .. %g,%g,%g)\n",
                mesh->bbox_min[0], mesh->bbox_min[1], mesh->bbox_min[2], mesh->bbox_max[0],
                mesh->bbox_max[1], mesh->bbox_max[2]);
        return 1;
    }
    if (n_fixed == n_used) {
        fprintf(stderr,
                "hapsim-solve: the fixed regions hold every node of the mesh's %d tets: "
                "nothing is left to move\n",
                mesh->n_tets);
        return 1;
    }
    return 0;
}

// What a run made and measured.
typedef struct solve_run {
    hs_mesh* mesh;
    unsigned char *fixed, *mask;
    int n_fixed;
    hs_body* body;
    hs_mooney* mr;
    hs_press* press;
    hs_press_stats pst;
    hs_step_stats st;
    double total_ms;
    int iters, lin_iters;
    int wrote;
    int no_answer; // the run ended before an answer (nothing to write or report)
} solve_run;

// The Mooney-Rivlin static reference: its status; *rc 1 (no answer) when it could not be set up.
static hs_status solve_mooney(const solve_opts* o, solve_run* r, hs_err* err, int* rc) {
    hs_mooney_def md = hs_mooney_default_def();
    md.youngs_pa = o->def.fem.material.youngs_pa;
    md.poisson = o->def.fem.material.poisson;
    md.density_kg_m3 = o->def.fem.material.density_kg_m3;
    md.beta = o->beta;
    md.tolerance = o->def.static_tol;
    md.max_newton_iter = o->def.static_max_iter;
    md.load_steps = o->def.static_load_steps;
    if (hs_mooney_create(r->mesh, &md, r->fixed, &r->mr, err) < 0 ||
        hs_mooney_set_gravity(r->mr, o->def.gravity) < 0) {
        fprintf(stderr, "hapsim-solve: %s\n", err->msg);
        *rc = 1;
        r->no_answer = 1;
        return HS_OK;
    }
    hs_mooney_stats ms;
    hs_status s = hs_mooney_solve_static(r->mr, &ms, err);
    r->total_ms = ms.solve_ms;
    r->iters = ms.newton_total;
    r->st.residual = ms.final_ratio;
    r->st.fem.volume_ratio_min = ms.volume_ratio_min;
    r->st.fem.volume_ratio_max = ms.volume_ratio_max;
    r->st.fem.volume_ratio_mean = ms.volume_ratio_total; // whole-mesh ratio for this model
    return s;
}

// The body's static solve, probe press or time steps: their status; *rc 1 (no answer) on a bad
// set-up, run_probe's status for the probe.
static hs_status solve_body(const solve_opts* o, solve_run* r, hs_err* err, int* rc) {
    if (hs_body_create(r->mesh, &o->def, r->fixed, &r->body, err) < 0 ||
        (o->do_static && hs_body_check_static(r->body, err) != HS_OK)) {
        fprintf(stderr, "hapsim-solve: %s\n", err->msg);
        *rc = 1;
        r->no_answer = 1;
        return HS_OK;
    }
    hs_status s = HS_OK;
    if (o->have_probe) {
        *rc = run_probe(r->mesh, &o->def, r->fixed, o->probe_c, o->probe_r,
                        o->have_dir ? o->probe_dir : NULL, o->probe_nodes, &r->press, &r->pst);
        r->total_ms = r->pst.wall_ms;
        r->iters = r->pst.newton;
        r->st.residual = r->pst.residual;
        r->no_answer = *rc == 1 || *rc == 3;
    } else if (o->do_static) {
        s = hs_body_solve_static(r->body, &r->st);
        r->total_ms = r->st.wall_ms;
        r->iters = r->st.iterations;
        r->lin_iters = r->st.linear_iterations;
    } else {
        for (int k = 0; k < o->steps && s >= 0; ++k) {
            s = hs_body_step(r->body, &r->st);
            r->total_ms += r->st.wall_ms;
            r->iters += r->st.iterations;
            r->lin_iters += r->st.linear_iterations;
        }
    }
    return s;
}

// The displacements as CSV (and VTK when asked): the exit status, rc or 1 on a write error.
static int write_outputs(const solve_opts* o, solve_run* r, const double* u, int rc) {
    FILE* f = fopen(o->out_path, "w");
    if (!f) {
        fprintf(stderr, "hapsim-solve: cannot write %s: %s\n", o->out_path, strerror(errno));
        rc = 1;
    } else {
        fprintf(f, "ux,uy,uz\n");
        for (int i = 0; i < r->mesh->n_nodes; ++i)
            fprintf(f, "%.9e,%.9e,%.9e\n", u[3 * i], u[3 * i + 1], u[3 * i + 2]);
        int bad = ferror(f);
        if (fclose(f) != 0 || bad) {
            fprintf(stderr, "hapsim-solve: error writing %s: %s\n", o->out_path, strerror(errno));
            rc = 1;
        } else {
            r->wrote = 1;
        }
    }
    hs_err err = {0};
    if (o->vtk_path && hs_mesh_write_vtk(r->mesh, u, o->vtk_path, &err) < 0) {
        fprintf(stderr, "hapsim-solve: %s\n", err.msg);
        rc = 1;
    }
    return rc;
}

static void print_report(const solve_opts* o, const solve_run* r, const double* u, int rc) {
    const hs_mesh* mesh = r->mesh;
    double umax = 0;
    int imax = 0;
    for (int i = 0; i < mesh->n_nodes; ++i) {
        double m =
            sqrt(u[3 * i] * u[3 * i] + u[3 * i + 1] * u[3 * i + 1] + u[3 * i + 2] * u[3 * i + 2]);
        if (m > umax) umax = m, imax = i;
    }
    printf("mesh            %s: %d nodes, %d tets, %d fixed\n", o->mesh_path, mesh->n_nodes,
           mesh->n_tets, r->n_fixed);
    printf("max |u|         %.6e m at node %d\n", umax, imax);
    printf("volume ratio    %s %.5f min %.5f max %.5f, inverted %d\n", o->mooney ? "total" : "mean",
           r->st.fem.volume_ratio_mean, r->st.fem.volume_ratio_min, r->st.fem.volume_ratio_max,
           r->st.fem.inverted);
    const hs_press_stats* pst = &r->pst;
    if (r->press)
        printf("probe           r %g m, %d contact %s, %d increments, %d passes, %d "
               "Newton (residual ratio %.2e, penetration %.2e r, longest contact edge "
               "%.3g m)\n",
               o->probe_r, pst->active, o->probe_nodes ? "nodes" : "triangles", pst->increments,
               pst->passes, r->iters, pst->residual, pst->penetration_m / o->probe_r,
               pst->max_edge_m);
    else if (o->do_static)
        printf("iterations      %d Newton (residual ratio %.2e)\n", r->iters, r->st.residual);
    else
        printf("steps           %d x %g s, %d Newton iterations\n", o->steps, o->def.dt, r->iters);
    if (o->def.solver == HS_SOLVER_PCG) printf("pcg iterations  %d\n", r->lin_iters);
    printf("time            %.3f ms%s\n", r->total_ms, o->do_static ? "" : " (sum of steps)");
    if (r->wrote)
        printf("wrote           %s\n", o->out_path);
    else
        printf("wrote           nothing (%s)\n",
               rc == 3 ? "the solve failed" : "the output failed");
}

// Load, fix, solve, write and report: the exit status.
static int run(const solve_opts* o, solve_run* r) {
    hs_err err = {0};
    hs_status load_st = hs_mesh_load(o->mesh_path, &r->mesh, &err);
    if (load_st < 0) {
        fprintf(stderr, "hapsim-solve: %s\n", err.msg);
        return 1;
    }
    if (load_st == HS_WARN_MESH_REPAIRED) { // repairs are never silent
        char rep[512];
        hs_mesh_report_str(&r->mesh->report, rep, sizeof rep);
        fprintf(stderr, "hapsim-solve: %s was repaired on loading:\n%s", o->mesh_path, rep);
    }
    r->fixed = calloc((size_t)r->mesh->n_nodes, 1);
    r->mask = calloc((size_t)r->mesh->n_nodes, 1);
    if (!r->fixed || !r->mask) {
        fprintf(stderr, "hapsim-solve: out of memory\n");
        return 1;
    }
    if (fix_nodes(r->mesh, o, r->fixed, r->mask, &r->n_fixed) != 0) return 1;
    int rc = 0;
    hs_status s = o->mooney ? solve_mooney(o, r, &err, &rc) : solve_body(o, r, &err, &rc);
    if (r->no_answer) return rc;
    if (s < 0) {
        fprintf(stderr, "hapsim-solve: solver failed: %s%s%s\n", hs_status_str(s),
                o->mooney && err.msg[0] ? ": " : "", o->mooney ? err.msg : "");
        rc = 3;
    } else if (s == HS_WARN_NOT_CONVERGED) {
        fprintf(stderr, "hapsim-solve: warning: not converged (residual ratio %.3g > %.3g)\n",
                r->st.residual, o->def.static_tol);
        rc = 4;
    }
    // A failed solve writes nothing: its state is not an answer.
    const double* u = o->mooney  ? hs_mooney_displacement(r->mr)
                      : r->press ? hs_press_displacement(r->press)
                                 : hs_body_displacement(r->body);
    if (rc != 3) rc = write_outputs(o, r, u, rc);
    if (!o->quiet) print_report(o, r, u, rc);
    return rc;
}

int main(int argc, char** argv) {
    if (hapsim_version_asked(argc, argv, "hapsim-solve")) return 0;
    hs_platform_setup(argv); // before any thread: it may re-execute the program
    solve_opts o = {.lf_mode = HS_LOCKING_FREE_NONE};
    o.def = hs_body_default_def();
    o.def.fem.material.youngs_pa = 5000; // the scene defaults (docs/scenes.md)
    o.def.fem.material.poisson = 0.45;
    o.def.fem.material.density_kg_m3 = 1000;
    int rc = parse_args(argc, argv, &o);
    if (rc >= 0) return rc;
    rc = check_options(&o);
    if (rc) return rc;
    solve_run r = {0};
    rc = run(&o, &r);
    hs_body_destroy(&r.body);
    hs_press_destroy(&r.press);
    hs_mooney_destroy(&r.mr);
    hs_mesh_destroy(&r.mesh);
    free(r.fixed);
    free(r.mask);
    return rc;
}
