"""The (u, v) fill's planar mesher grades its size away from fine loop vertices
(`cadbridge.mesh.gmsh.planar._graded_field`), and a caller's gmsh size callback neither
reaches it nor is lost by it (gmsh keeps one per model; its Python wrapper is one global, so a
second ``setSizeCallback`` anywhere would free the caller's and crash its meshing).

References: the analytic area of the square (the elements cover it once), and the size law
h(x) = min(size, h_i + GRADING d_i) evaluated directly at the element centroids.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("gmsh")

from cadbridge.mesh.gmsh.session import GmshSession  # noqa: E402
from cadbridge.mesh.gmsh.planar import GRADING, mesh_planar_loops  # noqa: E402


def _square(n: int, side: float) -> np.ndarray:
    t = np.linspace(0.0, side, n + 1)[:-1]
    z, s = np.zeros(n), np.full(n, side)
    return np.concatenate([np.column_stack([t, z]), np.column_stack([s, t]),
                           np.column_stack([side - t, s]), np.column_stack([z, side - t])])


def _edges(uv: np.ndarray, el: np.ndarray) -> np.ndarray:
    p = uv[el]
    return np.linalg.norm(np.roll(p, -1, axis=1) - p, axis=2).max(axis=1)


def test_the_size_grows_from_a_fine_boundary_up_to_the_size():
    side, seg, size = 100.0, 1.0, 40.0
    loop = _square(int(side / seg), side)
    uv, tris, quads = mesh_planar_loops([loop], np.ones(2), size, "square",
                                        point_sizes=[np.full(len(loop), seg)])
    assert len(quads) == 0
    a, b = uv[tris[:, 1]] - uv[tris[:, 0]], uv[tris[:, 2]] - uv[tris[:, 0]]
    area = np.abs(0.5 * (a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])).sum()
    assert abs(area - side * side) < 1e-9 * side * side
    # gmsh's extension of the boundary size would give ~2 (side / seg)^2 = 20 000 triangles
    assert len(tris) < 4000
    c = uv[tris].mean(axis=1)
    d = np.min(np.column_stack([c, side - c]), axis=1)  # distance to the square's boundary
    law = np.minimum(size, seg + GRADING * d)
    longest = _edges(uv, tris)
    assert np.all(longest < 2.5 * law)  # never much coarser than the law
    mid = d > 30
    assert np.median(longest[mid]) > 0.5 * np.median(law[mid])  # and it does grow


def test_a_callers_size_callback_is_kept_and_not_used_inside():
    calls = []

    def tiny(dim, tag, x, y, z, lc):
        calls.append((x, y))
        return 0.05

    loop = _square(4, 1.0)
    with GmshSession() as sess:
        g = sess.gmsh
        g.model.mesh.setSizeCallback(tiny)
        uv, tris, _ = mesh_planar_loops([loop], np.ones(2), 0.25, "square", point_sizes=[np.full(len(loop), 0.25)])
        assert not calls  # the caller's callback did not size the private model
        assert len(tris) < 200  # at 0.05 it would be ~900
        g.model.occ.addRectangle(0, 0, 0, 1, 1)
        g.model.occ.synchronize()
        sess.set("Mesh.MeshSizeExtendFromBoundary", 0)
        g.model.mesh.generate(2)
        assert calls  # the caller's callback is in force again
        n = len(g.model.mesh.getNodes()[0])
        assert n > 300  # at 0.05 on a unit square: ~460 nodes
