"""Mapped meshes on four-cornered faces whose opposite sides have different numbers of curves
(`mesh.generate._settle_sums`): a fillet strip whose long side a neighbour's vertex splits.

Reference: the structured grid itself. A 10 x 4 plane whose lower side is split at x = 2.5
(curves of 2.5 and 7.5) and whose upper side is one curve: with size 1 the lower curves need
3 and 8 elements, the upper one 10. Counts are only raised, so the sides must add up to
11 = 11 for triangles (the upper curve raised); for quads the curves in a sum are even, 4 + 8 =
12 = 12. The mesh is then an 11 x 4 (12 x 4) grid: that many quads, every interior node in
four of them, and no triangle in quad mode.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cadbridge.mesh.generate import FaceInfo, _settle_sums


def _split_plate(tmp_path: Path) -> Path:
    pytest.importorskip("OCP")
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakePolygon
    from OCP.BRepTools import BRepTools
    from OCP.gp import gp_Pnt

    poly = BRepBuilderAPI_MakePolygon()
    for x, y in ((0, 0), (2.5, 0), (10, 0), (10, 4), (0, 4)):
        poly.Add(gp_Pnt(float(x), float(y), 0.0))
    poly.Close()
    face = BRepBuilderAPI_MakeFace(poly.Wire(), True).Face()
    out = tmp_path / "split_plate.brep"
    BRepTools.Write_s(face, str(out))
    return out


@pytest.mark.parametrize("element, columns", [("quad", 12), ("tri", 11)])
def test_split_side_is_mapped(tmp_path, element, columns):
    pytest.importorskip("gmsh")
    from cadbridge.mesh.generate import mesh_cad

    m = mesh_cad(_split_plate(tmp_path), element=element, size=1.0, structured=True, parametric=False)
    if element == "quad":
        assert len(m.triangles) == 0
        assert len(m.quads) == columns * 4
        cells = m.quads
    else:
        assert len(m.triangles) == 2 * columns * 4  # a mapped grid of triangles: two per cell
        cells = m.triangles
    # the grid's nodes: (columns + 1) x 5, on the lines y = 0, 1, 2, 3, 4
    assert len(m.nodes) == (columns + 1) * 5
    assert np.allclose(np.unique(np.round(m.nodes[:, 1], 9)), [0, 1, 2, 3, 4])
    if element == "quad":
        valence = np.bincount(cells.ravel(), minlength=len(m.nodes))
        inner = (m.nodes[:, 0] > 1e-9) & (m.nodes[:, 0] < 10 - 1e-9) & (m.nodes[:, 1] > 1e-9) & (m.nodes[:, 1] < 4 - 1e-9)
        assert np.all(valence[inner] == 4)


def _face(sums) -> FaceInfo:
    f = FaceInfo(1, "Plane", sorted({c for a, b in sums for c in a + b}))
    f.kind, f.sums = "chained", sums
    return f


def test_settle_sums_only_raises_and_balances():
    """Two faces sharing curve 3: sides [1, 2] | [3] and [3] | [4, 5, 6]. Each count stays at or
    above its need, and both faces balance (reference: the constraints themselves)."""
    need = {1: 2, 2: 5, 3: 4, 4: 1, 5: 1, 6: 9}
    f1, f2 = _face([([1, 2], [3])]), _face([([3], [4, 5, 6])])
    n = dict(need)
    _settle_sums([f1, f2], lambda c: c, n, {c: 10.0 for c in need}, 1)
    assert all(n[c] >= need[c] for c in need)
    assert n[1] + n[2] == n[3] == n[4] + n[5] + n[6]
    assert f1.kind == f2.kind == "chained"
    n2 = dict(need)
    _settle_sums([_face([([1, 2], [3])]), _face([([3], [4, 5, 6])])], lambda c: c, n2, {c: 10.0 for c in need}, 2)
    assert all(n2[c] % 2 == 0 and n2[c] >= need[c] for c in need)
    assert n2[1] + n2[2] == n2[3] == n2[4] + n2[5] + n2[6]


def test_settle_sums_gives_up_where_the_same_class_is_on_both_sides():
    """Sides [1, 2] | [3] with curves 1, 2 and 3 all in one class (equal counts through other
    faces): 2 n == n never holds, so the face goes back to "other" and no count is lowered."""
    f = _face([([1, 2], [3])])
    n = {1: 5}
    _settle_sums([f], {1: 1, 2: 1, 3: 1}.get, n, {1: 10.0}, 1)
    assert f.kind == "other"
    assert n[1] >= 5
