"""Class 'closed face whose seam is a sharp edge' (occt_OCC17026-2: 3Dipsos tubes of polygonal
section, one NURBS face each, closed at a corner of the section). A node on the seam
projects to either end of the closed parameter range; its corner normals, the centroids'
parameters and the straddle check must take the end on their element's side.

Generated case: a square tube, one bilinear-in-v NURBS face (degree 1 across the section,
knots 0, 0.25, 0.5, 0.75, 1: crease knot lines at 0.25, 0.5, 0.75, the seam at v = 0 = 1 on
a corner), written with cadbridge's IGES writer. Rotated by an angle so no side is axis
aligned. Reference (analytic): every corner normal of every element is the outward normal
of the tube side its element lies on; no element straddles a crease; the Nagata surface is
exact (the tube is flat sided).
"""

from __future__ import annotations

import numpy as np
import pytest

from cadbridge.cad.model import Face, Model, Units
from cadbridge.iges.writer import write_iges
from cadbridge.nurbs.surface import NurbsSurface
from cadbridge.tool import pipeline

ANGLE = 0.3  # rad about the tube axis z
HALF = 10.0  # half the side of the square section
LENGTH = 40.0


def _rot(p):
    c, s = np.cos(ANGLE), np.sin(ANGLE)
    return p @ np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def tube(tmp_path_factory):
    corners = HALF * np.array([[1, 1], [-1, 1], [-1, -1], [1, -1], [1, 1]], dtype=float)
    cp = np.array([[[x, y, z] for x, y in corners] for z in (0.0, LENGTH)])  # (2 along z, 5 around)
    surface = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 0.25, 0.5, 0.75, 1, 1], _rot(cp.reshape(-1, 3)).reshape(cp.shape))
    path = tmp_path_factory.mktemp("tube") / "square_tube.igs"
    write_iges(Model(faces=[Face(surface=surface, de=1)], units=Units()), path)  # mm
    return path


@pytest.mark.parametrize("element", ["tri", "quad"])
def test_sharp_seam_corner_normals_follow_their_element(tube, tmp_path, element):
    result = pipeline.convert(str(tube), str(tmp_path / "out"), element=element, size=6.0)
    (tool,) = result.tools
    nodes = tool.mesh.nodes
    sides = _rot(np.array([[0, 1, 0], [-1, 0, 0], [0, -1, 0], [1, 0, 0]], dtype=float))  # outward normals
    for block, corner_n in zip(tool.mesh.cells, tool.corner_normals):  # loop over the (one) block
        cen = nodes[block.data].mean(axis=1)
        side = sides[np.argmax(cen @ sides.T, axis=1)]  # the side each element lies on
        dots = np.einsum("ekj,ej->ek", corner_n, side)
        sign = np.sign(np.median(dots))  # the tool's orientation, in or out
        np.testing.assert_allclose(sign * dots, 1.0, atol=1e-12)
    assert len(tool.trips.straddling) == 0
    assert tool.stats["max_abs_surface_error"] <= 1e-9 * LENGTH
