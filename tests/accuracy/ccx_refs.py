#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-2.0-or-later
"""Independent CalculiX references for hapsim's accuracy tests (tests/accuracy/README.md).

Writes CalculiX (ccx) decks on hapsim's own structured Kuhn box meshes (the node and tet
numbering of hs_mesh_create_box, so results compare node by node), runs ccx, and keeps the
nodal displacements on the linear-tet nodes of each mesh in small text files:

  refs/<load>_<mat>_<elem>_<mesh>.txt   ccx on that mesh (C3D4, or C3D10 read at its corners)
  refs/<load>_<mat>_conv_<mesh>.txt     the converged solution (C3D10 on the finest mesh)
                                        interpolated with its quadratic shape functions
  refs/summary.csv                      tip displacement, reaction, relative L2 differences

Loads (cantilever 0.10 x 0.02 x 0.02 m, E 1.5 MPa, nu 0.49, 960 kg/m^3, x = 0 clamped):
  gravity  own weight, g = 9.81 m/s^2 along -z
  tip      0.5 N along -z on the x = L face, as the consistent load of a uniform traction
  bar      x = L face moved by -5 mm along x, both end faces clamped otherwise (a press)
Materials: lin (small strain, *ELASTIC), nlgeom (*ELASTIC with NLGEOM: St. Venant-Kirchhoff),
mr (*HYPERELASTIC, MOONEY-RIVLIN, C10 = C01 = E / (8 (1 + nu)), D1 = 2 / kappa, NLGEOM).

Pure python3 (no third-party modules). Usage: ccx_refs.py [--only LOAD] [--keep DIR]
"""
import math
import os
import shutil
import subprocess
import sys
import tempfile

LX, LY, LZ = 0.10, 0.02, 0.02
E, NU, RHO, G = 1.5e6, 0.49, 960.0, 9.81
TIP_FORCE = 0.5        # N, total, -z
BAR_SHORTEN = 0.005    # m
MESHES = {"1k": (20, 3, 3), "5k": (30, 5, 5), "20k": (45, 9, 9)}
FINE = "20k"
LOADS = ("gravity", "tip", "bar")
MATS = ("lin", "nlgeom", "mr")

# Kuhn split of hs_mesh_create_box (server/mesh/mesh.c): one tet per axis order.
PERM = ((0, 1, 2), (1, 2, 0), (2, 0, 1), (0, 2, 1), (1, 0, 2), (2, 1, 0))


def box(nx, ny, nz):
    """Nodes and positively oriented tets in hs_mesh_create_box's numbering."""
    x = []
    for k in range(nz + 1):
        for j in range(ny + 1):
            for i in range(nx + 1):
                x.append((LX * i / nx, LY * j / ny, LZ * k / nz))
    stride = (1, nx + 1, (nx + 1) * (ny + 1))
    tets = []
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                base = i + stride[1] * j + stride[2] * k
                for p in range(6):
                    v1 = base + stride[PERM[p][0]]
                    v2 = v1 + stride[PERM[p][1]]
                    v3 = base + stride[0] + stride[1] + stride[2]
                    t = [base, v1, v2, v3] if p < 3 else [base, v2, v1, v3]
                    if vol6(x, t) < 0:
                        t[1], t[2] = t[2], t[1]
                    tets.append(t)
    return x, tets


def vol6(x, t):
    a, b, c, d = (x[i] for i in t)
    u = [b[k] - a[k] for k in range(3)]
    v = [c[k] - a[k] for k in range(3)]
    w = [d[k] - a[k] for k in range(3)]
    return (u[0] * (v[1] * w[2] - v[2] * w[1]) - u[1] * (v[0] * w[2] - v[2] * w[0]) +
            u[2] * (v[0] * w[1] - v[1] * w[0]))


EDGES10 = ((0, 1), (1, 2), (2, 0), (0, 3), (1, 3), (2, 3))  # C3D10 nodes 5..10


def quadratic(x, tets):
    """Midside nodes (numbered after the corners) and 10-node connectivity."""
    xq = list(x)
    mid = {}
    t10 = []
    for t in tets:
        row = list(t)
        for a, b in EDGES10:
            key = (min(t[a], t[b]), max(t[a], t[b]))
            if key not in mid:
                mid[key] = len(xq)
                pa, pb = x[t[a]], x[t[b]]
                xq.append(tuple(0.5 * (pa[k] + pb[k]) for k in range(3)))
            row.append(mid[key])
        t10.append(row)
    return xq, t10


def end_faces(x, tets, xval):
    """Tet faces lying on the plane x = xval, as (tet, (a, b, c)) local corner triples."""
    out = []
    for e, t in enumerate(tets):
        on = [a for a in range(4) if abs(x[t[a]][0] - xval) < 1e-12]
        if len(on) == 3:
            out.append((e, tuple(on)))
    return out


def tip_loads(x, tets, t10):
    """Consistent nodal forces (z) of a uniform traction on x = L totalling TIP_FORCE:
    area / 3 per corner for linear triangles, area / 3 per midside node for quadratic ones."""
    faces = end_faces(x, tets, LX)
    area_total = LY * LZ
    f4, f10 = {}, {}
    for e, (a, b, c) in faces:
        t = tets[e]
        pa, pb, pc = x[t[a]], x[t[b]], x[t[c]]
        u = [pb[k] - pa[k] for k in range(3)]
        v = [pc[k] - pa[k] for k in range(3)]
        cr = (u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0])
        area = 0.5 * math.sqrt(sum(q * q for q in cr))
        share = -TIP_FORCE * area / area_total / 3.0
        for q in (a, b, c):
            f4[t[q]] = f4.get(t[q], 0.0) + share
        if t10 is not None:
            for i, (p, q) in enumerate(EDGES10):
                if p in (a, b, c) and q in (a, b, c):
                    n = t10[e][4 + i]
                    f10[n] = f10.get(n, 0.0) + share
    return f4, f10


def write_deck(path, xn, conn, etype, load, mat, nfix_x0, nend, floads):
    nu, e = NU, E
    kappa = e / (3 * (1 - 2 * nu))
    c10 = e / (8 * (1 + nu))
    with open(path, "w") as f:
        f.write("** hapsim accuracy reference, written by tests/accuracy/ccx_refs.py\n")
        f.write("*NODE, NSET=NALL\n")
        for i, p in enumerate(xn):
            f.write("%d,%.17g,%.17g,%.17g\n" % (i + 1, p[0], p[1], p[2]))
        f.write("*ELEMENT, TYPE=%s, ELSET=EALL\n" % etype)
        for i, t in enumerate(conn):
            f.write("%d,%s\n" % (i + 1, ",".join(str(v + 1) for v in t)))
        f.write("*NSET, NSET=NFIX\n")
        for n in nfix_x0:
            f.write("%d,\n" % (n + 1))
        if nend:
            f.write("*NSET, NSET=NEND\n")
            for n in nend:
                f.write("%d,\n" % (n + 1))
        f.write("*MATERIAL, NAME=TISSUE\n")
        if mat == "mr":
            f.write("*HYPERELASTIC, MOONEY-RIVLIN\n%.12g,%.12g,%.12g\n" % (c10, c10, 2.0 / kappa))
        else:
            f.write("*ELASTIC\n%.12g,%.12g\n" % (e, nu))
        f.write("*DENSITY\n%.17g\n" % RHO)
        f.write("*SOLID SECTION, ELSET=EALL, MATERIAL=TISSUE\n")
        f.write("*BOUNDARY\nNFIX,1,3\n")
        if load == "bar":
            f.write("NEND,1,1,%.17g\nNEND,2,3\n" % (-BAR_SHORTEN))
        nl = mat != "lin"
        f.write("*STEP%s, INC=1000\n" % (", NLGEOM" if nl else ""))
        f.write("*STATIC\n%s\n" % ("1.0,1.0,1e-5,1.0" if nl else ""))
        if load == "gravity":
            f.write("*DLOAD\nEALL,GRAV,%.17g,0.,0.,-1.\n" % G)
        elif load == "tip":
            f.write("*CLOAD\n")
            for n in sorted(floads):
                f.write("%d,3,%.17g\n" % (n + 1, floads[n]))
        f.write("*NODE PRINT, NSET=NALL\nU\n")
        f.write("*NODE PRINT, NSET=NFIX, TOTALS=ONLY\nRF\n")
        f.write("*END STEP\n")


def parse_dat(path, nnodes):
    """Last displacement block and last total reaction of NFIX from a ccx .dat file."""
    u, rf = None, None
    with open(path) as f:
        lines = f.readlines()
    i = 0
    while i < len(lines):
        s = lines[i].strip()
        if s.startswith("displacements"):
            cur = [None] * nnodes
            i += 1
            while i < len(lines) and not lines[i].strip():
                i += 1
            while i < len(lines) and lines[i].strip():
                p = lines[i].split()
                cur[int(p[0]) - 1] = (float(p[1]), float(p[2]), float(p[3]))
                i += 1
            u = cur
            continue
        if s.startswith("total force"):
            i += 1
            while i < len(lines) and not lines[i].strip():
                i += 1
            rf = tuple(float(v) for v in lines[i].split())
        i += 1
    if u is None or any(v is None for v in u):
        raise RuntimeError("%s: no complete displacement block" % path)
    return u, rf


def run_ccx(workdir, name):
    r = subprocess.run(["ccx", "-i", name], cwd=workdir, capture_output=True, text=True)
    log = r.stdout + r.stderr
    if r.returncode != 0 or "*ERROR" in log:
        tail = "\n".join(log.splitlines()[-15:])
        raise RuntimeError("ccx %s failed (exit %d):\n%s" % (name, r.returncode, tail))


def solve(workdir, mesh, load, mat, elem):
    nx, ny, nz = MESHES[mesh]
    x, tets = box(nx, ny, nz)
    if elem == "c3d10":
        xn, conn = quadratic(x, tets)
    else:
        xn, conn = x, tets
    f4, f10 = tip_loads(x, tets, conn if elem == "c3d10" else None) if load == "tip" else ({}, {})
    nfix = [i for i, p in enumerate(xn) if abs(p[0]) < 1e-12]
    nend = [i for i, p in enumerate(xn) if abs(p[0] - LX) < 1e-12] if load == "bar" else []
    name = "%s_%s_%s_%s" % (load, mat, elem, mesh)
    write_deck(os.path.join(workdir, name + ".inp"), xn, conn, elem.upper(), load, mat, nfix, nend,
               f10 if elem == "c3d10" else f4)
    run_ccx(workdir, name)
    u, rf = parse_dat(os.path.join(workdir, name + ".dat"), len(xn))
    return xn, conn, u, rf


def shape10(l):
    """C3D10 shape functions at barycentric coordinates l[0..3] (corner i has l[i] = 1)."""
    n = [li * (2 * li - 1) for li in l]
    for a, b in EDGES10:
        n.append(4 * l[a] * l[b])
    return n


def interpolate(fine_x, fine_t10, fine_u, nxyz, pts):
    """Quadratic interpolation of the fine C3D10 field at points: the Kuhn cell is found from
    the grid, the tet with the largest smallest barycentric coordinate in it is used."""
    nx, ny, nz = nxyz
    h = (LX / nx, LY / ny, LZ / nz)
    out = []
    for p in pts:
        c = [min(max(int(math.floor(p[k] / h[k])), 0), n - 1) for k, n in enumerate(nxyz)]
        best, bl = None, None
        for dk in (-1, 0, 1):
            for dj in (-1, 0, 1):
                for di in (-1, 0, 1):
                    i, j, k = c[0] + di, c[1] + dj, c[2] + dk
                    if not (0 <= i < nx and 0 <= j < ny and 0 <= k < nz):
                        continue
                    cell = i + nx * (j + ny * k)
                    for e in range(6 * cell, 6 * cell + 6):
                        t = fine_t10[e]
                        l = bary([fine_x[v] for v in t[:4]], p)
                        if best is None or min(l) > min(bl):
                            best, bl = e, l
            if bl is not None and min(bl) > -1e-12:
                break
        nsh = shape10(bl)
        t = fine_t10[best]
        out.append(tuple(sum(nsh[a] * fine_u[t[a]][k] for a in range(10)) for k in range(3)))
    return out


def bary(v, p):
    d = [[v[a][k] - v[0][k] for a in (1, 2, 3)] for k in range(3)]  # columns X1-X0, ...
    r = [p[k] - v[0][k] for k in range(3)]
    det = (d[0][0] * (d[1][1] * d[2][2] - d[1][2] * d[2][1]) -
           d[0][1] * (d[1][0] * d[2][2] - d[1][2] * d[2][0]) +
           d[0][2] * (d[1][0] * d[2][1] - d[1][1] * d[2][0]))
    s = []
    for col in range(3):
        m = [row[:] for row in d]
        for k in range(3):
            m[k][col] = r[k]
        s.append((m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1]) -
                  m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0]) +
                  m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])) / det)
    return [1.0 - s[0] - s[1] - s[2]] + s


def rel_l2(u, ref):
    num = sum((a[k] - b[k]) ** 2 for a, b in zip(u, ref) for k in range(3))
    den = sum(b[k] ** 2 for b in ref for k in range(3))
    return math.sqrt(num / den)


def write_field(path, u, what):
    with open(path, "w") as f:
        f.write("# %s; ux uy uz (m) per node of hs_mesh_create_box's numbering\n" % what)
        for v in u:
            f.write("%.6e %.6e %.6e\n" % v)


def tip_value(x, u):
    """Mean displacement of the x = L edge's centre line node(s) (y = LY / 2, z = LZ / 2 or the
    nearest), as (ux, uz)."""
    cand = [i for i, p in enumerate(x) if abs(p[0] - LX) < 1e-12]
    dmin = min(abs(x[i][1] - LY / 2) + abs(x[i][2] - LZ / 2) for i in cand)
    sel = [i for i in cand if abs(x[i][1] - LY / 2) + abs(x[i][2] - LZ / 2) < dmin + 1e-12]
    return tuple(sum(u[i][k] for i in sel) / len(sel) for k in (0, 2))


def main():
    args = sys.argv[1:]
    only = args[args.index("--only") + 1] if "--only" in args else None
    keep = args[args.index("--keep") + 1] if "--keep" in args else None
    here = os.path.dirname(os.path.abspath(__file__))
    outdir = os.path.join(here, "refs")
    os.makedirs(outdir, exist_ok=True)
    work = keep or tempfile.mkdtemp(prefix="hs_ccx_")
    os.makedirs(work, exist_ok=True)
    rows = []
    loads = [only] if only else LOADS
    for load in loads:
        for mat in MATS:
            res = {}
            for elem in ("c3d10", "c3d4"):
                for mesh in (FINE, "5k", "1k"):
                    xn, conn, u, rf = solve(work, mesh, load, mat, elem)
                    nc = (MESHES[mesh][0] + 1) * (MESHES[mesh][1] + 1) * (MESHES[mesh][2] + 1)
                    res[(elem, mesh)] = (xn, conn, u, rf)
                    tag = "%s_%s_%s_%s" % (load, mat, elem, mesh)
                    print("ccx_refs: %s done, reaction %s" % (tag, rf), flush=True)
                    if not (elem == "c3d10" and mesh == FINE) and not (elem == "c3d4" and mesh == FINE):
                        write_field(os.path.join(outdir, tag + ".txt"), u[:nc],
                                    "CalculiX %s on the %s box, %s, %s" % (elem.upper(), mesh,
                                                                          load, mat))
            fx, ft, fu, frf = res[("c3d10", FINE)]
            for mesh in MESHES:
                x4, _ = box(*MESHES[mesh])
                conv = interpolate(fx, ft, fu, MESHES[FINE], x4) if mesh != FINE else \
                    fu[:len(x4)]
                write_field(os.path.join(outdir, "%s_%s_conv_%s.txt" % (load, mat, mesh)), conv,
                            "converged: CalculiX C3D10 on the %s box, interpolated, %s, %s" %
                            (FINE, load, mat))
                for elem in ("c3d4", "c3d10"):
                    xn, conn, u, rf = res[(elem, mesh)]
                    tip = tip_value(x4, u[:len(x4)])
                    rows.append((load, mat, elem, mesh, len(conn), 100 * rel_l2(u[:len(x4)], conv),
                                 tip[0], tip[1], rf[0] if rf else float("nan"),
                                 rf[2] if rf else float("nan")))
    with open(os.path.join(outdir, "summary%s.csv" % ("_" + only if only else "")), "w") as f:
        f.write("load,material,element,mesh,tets,err_l2_pct_vs_conv,tip_ux_m,tip_uz_m,"
                "reaction_x_N,reaction_z_N\n")
        for r in rows:
            f.write("%s,%s,%s,%s,%d,%.4f,%.6e,%.6e,%.6e,%.6e\n" % r)
    if not keep:
        shutil.rmtree(work)


if __name__ == "__main__":
    main()
