"""Structured meshes of the analytic test geometries of thesis ch. 3, with exact normals.

All generators are vectorised and return ``nodes (N, 3)``, ``elements (E, 3|4)`` and
outward unit ``normals (N, 3)``, with the element winding giving the outward normal.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def cylinder_quads(n_around: int, n_along: int, radius: float = 1.0, height: float = 2.0
                   ) -> tuple[NDArray, NDArray, NDArray]:
    """Lateral surface of a cylinder (axis z, 0 <= z <= height), quadrilaterals
    (thesis Fig. 12 (b)): n_around * (n_along + 1) nodes."""
    th = 2 * np.pi * np.arange(n_around) / n_around
    z = height * np.arange(n_along + 1) / n_along
    T, Z = np.meshgrid(th, z, indexing="ij")  # node id = i * (n_along + 1) + j
    nodes = np.stack([radius * np.cos(T), radius * np.sin(T), Z], -1).reshape(-1, 3)
    normals = np.stack([np.cos(T), np.sin(T), 0 * T], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n_around), np.arange(n_along), indexing="ij")
    i, j = i.ravel(), j.ravel()
    ip = (i + 1) % n_around
    nid = lambda a, b: a * (n_along + 1) + b  # noqa: E731
    quads = np.stack([nid(i, j), nid(ip, j), nid(ip, j + 1), nid(i, j + 1)], 1)
    return nodes, quads, normals


def cylinder_tris(n_around: int, n_along: int, radius: float = 1.0, height: float = 2.0
                  ) -> tuple[NDArray, NDArray, NDArray]:
    """Cylinder triangles made from :func:`cylinder_quads` by splitting every quadrilateral
    into 4 triangles around a centre node at mid angle / mid height on the surface
    (thesis Fig. 12 (a))."""
    nodes, quads, normals = cylinder_quads(n_around, n_along, radius, height)
    e = len(quads)
    i = np.arange(e) // n_along
    j = np.arange(e) % n_along
    th = 2 * np.pi * (i + 0.5) / n_around
    zc = height * (j + 0.5) / n_along
    cn = np.stack([radius * np.cos(th), radius * np.sin(th), zc], 1)
    cnn = np.stack([np.cos(th), np.sin(th), 0 * th], 1)
    c = len(nodes) + np.arange(e)
    q = quads
    tris = np.concatenate([np.stack([q[:, k], q[:, (k + 1) % 4], c], 1)[:, None] for k in range(4)], 1)
    return np.vstack([nodes, cn]), tris.reshape(-1, 3), np.vstack([normals, cnn])


def octahedron_sphere(k: int, radius: float = 1.0, equal_angle: bool = False
                      ) -> tuple[NDArray, NDArray, NDArray]:
    """Sphere: each octant face of an octahedron subdivided into k^2 triangles
    (k elements per quarter arc), nodes projected radially (thesis Fig. 18 (a)).
    Shared nodes are merged; 4 k^2 + 2 nodes, 8 k^2 triangles.

    ``equal_angle``: lattice barycentric weights w -> sin(w pi / 2) before projection, so
    the nodes on the octant arcs are equally spaced in angle (slerp)."""
    a, b = np.meshgrid(np.arange(k + 1), np.arange(k + 1), indexing="ij")
    keep = a + b <= k
    a, b = a[keep], b[keep]
    lid = -np.ones((k + 1, k + 1), dtype=np.int64)
    lid[a, b] = np.arange(a.size)
    # local triangles in (a, b) lattice of a face with corners P0 (a=b=0), P1 (a=k), P2 (b=k)
    ta, tb = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    up = (ta + tb) <= k - 1
    t1 = np.stack([lid[ta[up], tb[up]], lid[ta[up] + 1, tb[up]], lid[ta[up], tb[up] + 1]], 1)
    dn = (ta + tb) <= k - 2
    t2 = np.stack([lid[ta[dn] + 1, tb[dn]], lid[ta[dn] + 1, tb[dn] + 1], lid[ta[dn], tb[dn] + 1]], 1)
    lt = np.vstack([t1, t2])
    s = np.array([[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)], float)
    # octant face corners: x-axis, y-axis, z-axis scaled by signs; orient outward
    p1 = s[:, 0, None] * np.array([1.0, 0, 0])
    p2 = s[:, 1, None] * np.array([0, 1.0, 0])
    p0 = s[:, 2, None] * np.array([0, 0, 1.0])
    bary = np.stack([(k - a - b) / k, a / k, b / k], 1)  # weights of p0, p1, p2
    if equal_angle:
        bary = np.sin(bary * np.pi / 2)
    pts = (bary[None, :, 0, None] * p0[:, None] + bary[None, :, 1, None] * p1[:, None]
           + bary[None, :, 2, None] * p2[:, None])  # (8, P, 3)
    pts = pts.reshape(-1, 3)
    tris = (lt[None] + (np.arange(8) * a.size)[:, None, None])
    # orientation: outward if (p1-p0)x(p2-p0) . centroid > 0
    orient = np.einsum("ij,ij->i", np.cross(p1 - p0, p2 - p0), p0 + p1 + p2) > 0
    tris = np.where(orient[:, None, None], tris, tris[:, :, ::-1]).reshape(-1, 3)
    key = np.round(pts * (4 * k), 0).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    nodes = pts[first]
    nodes = radius * nodes / np.linalg.norm(nodes, axis=1, keepdims=True)
    return nodes, inv.ravel()[tris], nodes / radius


def sphere_triangles_fine(n_tris: int, radius: float = 1.0) -> tuple[NDArray, NDArray, NDArray]:
    """Octahedral sphere with at least ``n_tris`` triangles."""
    k = int(np.ceil(np.sqrt(n_tris / 8)))
    return octahedron_sphere(k, radius)


def torus_quads(n_major: int, n_minor: int, R: float = 2.0, r: float = 1.0
                ) -> tuple[NDArray, NDArray, NDArray]:
    """Torus (axis z) quadrilaterals, uniform in both angles (thesis Fig. 25 (b))."""
    u = 2 * np.pi * np.arange(n_major) / n_major
    v = 2 * np.pi * np.arange(n_minor) / n_minor
    U, V = np.meshgrid(u, v, indexing="ij")
    nodes, normals = _torus_point(U.ravel(), V.ravel(), R, r)
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    i, j = i.ravel(), j.ravel()
    nid = lambda a, b: (a % n_major) * n_minor + (b % n_minor)  # noqa: E731
    quads = np.stack([nid(i, j), nid(i + 1, j), nid(i + 1, j + 1), nid(i, j + 1)], 1)
    return nodes, quads, normals


def _torus_point(u: NDArray, v: NDArray, R: float, r: float) -> tuple[NDArray, NDArray]:
    n = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], 1)
    c = np.stack([R * np.cos(u), R * np.sin(u), 0 * u], 1)
    return c + r * n, n


def torus_tris(n_major: int, n_minor: int, R: float = 2.0, r: float = 1.0
               ) -> tuple[NDArray, NDArray, NDArray]:
    """Torus triangles: every quadrilateral of :func:`torus_quads` split into 4 around a
    centre node at the mid angles, on the surface (thesis Fig. 25 (a))."""
    nodes, quads, normals = torus_quads(n_major, n_minor, R, r)
    e = np.arange(len(quads))
    u = 2 * np.pi * (e // n_minor + 0.5) / n_major
    v = 2 * np.pi * (e % n_minor + 0.5) / n_minor
    cn, cnn = _torus_point(u, v, R, r)
    c = len(nodes) + e
    q = quads
    tris = np.concatenate([np.stack([q[:, k], q[:, (k + 1) % 4], c], 1)[:, None] for k in range(4)], 1)
    return np.vstack([nodes, cn]), tris.reshape(-1, 3), np.vstack([normals, cnn])
