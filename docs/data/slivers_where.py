#!/usr/bin/env python3
# SPDX-License-Identifier: GPL-2.0-or-later
# Of the tets below 10 degrees (smallest dihedral angle) in a Gmsh MSH 2.2 file, how many have
# all four nodes on the boundary: prints "N/M". Plain Python (no numpy), for mesher_slivers.sh.
import itertools
import math
import sys


def read_msh22(path):
    lines = open(path).read().split("\n")
    nodes, tets, i = {}, [], 0
    while i < len(lines):
        if lines[i] == "$Nodes":
            n = int(lines[i + 1])
            for k in range(n):
                a = lines[i + 2 + k].split()
                nodes[int(a[0])] = [float(x) for x in a[1:4]]
            i += n + 2
        elif lines[i] == "$Elements":
            n = int(lines[i + 1])
            for k in range(n):
                a = [int(x) for x in lines[i + 2 + k].split()]
                if a[1] == 4:
                    tets.append(a[3 + a[2]:])
            i += n + 2
        else:
            i += 1
    return nodes, tets


def min_dihedral(p):
    def sub(a, b):
        return [a[k] - b[k] for k in range(3)]

    def cross(a, b):
        return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]

    def dot(a, b):
        return sum(a[k] * b[k] for k in range(3))

    normals = []
    for f in ((1, 2, 3), (0, 3, 2), (0, 1, 3), (0, 2, 1)):
        a, b, c = (p[k] for k in f)
        v = cross(sub(b, a), sub(c, a))
        length = math.sqrt(dot(v, v)) or 1.0
        normals.append([x / length for x in v])
    return min(math.degrees(math.acos(max(-1.0, min(1.0, -dot(normals[i], normals[j])))))
               for i in range(4) for j in range(i + 1, 4))


nodes, tets = read_msh22(sys.argv[1])
faces = {}
for t in tets:
    for f in itertools.combinations(sorted(t), 3):
        faces[f] = faces.get(f, 0) + 1
on_surface = {v for f, c in faces.items() if c == 1 for v in f}
bad = [t for t in tets if min_dihedral([nodes[v] for v in t]) < 10]
print("%d/%d" % (sum(1 for t in bad if all(v in on_surface for v in t)), len(bad)))
