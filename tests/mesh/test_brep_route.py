"""gmsh on cadbridge's own B-rep (`cadbridge.heal.brep`), against gmsh on OCC's reading of the
same file.

A plate with a notch (made with cadquery, written by OCC's IGES writer in faces mode): its
straight trim edges are lines in OCC's reading and B-splines in the B-rep (their 3D curves
built from the pcurves). gmsh gives a line shorter than the size one segment and any other
curve two at least, so without ``straight_splines`` the B-rep mesh has extra nodes on the
notch's short sides. Reference: gmsh's mesh of OCC's reading of the file (a line is a
line), node count per curve length, and the analytic lengths of the notch's sides.
"""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("OCP")
cq = pytest.importorskip("cadquery")

from cadbridge.heal.brep import brep_source  # noqa: E402
from cadbridge.iges import read_iges  # noqa: E402
from cadbridge.mesh.generate import mesh_cad  # noqa: E402
from cadbridge.ushape import export_iges  # noqa: E402

SIZE = 5.0
NOTCH = 2.0  # the notch's sides: 2 mm, shorter than SIZE


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    """A 40 x 30 plate face with a 2 x 2 notch in one side, as IGES (faces mode, analytic: a 108 plane bounded by 110 lines)."""
    pts = [(0, 0), (40, 0), (40, 30), (21, 30), (21, 30 - NOTCH), (19, 30 - NOTCH), (19, 30), (0, 30)]
    face = cq.Workplane("XY").polyline(pts).close().extrude(1).faces("<Z").val().wrapped
    path = tmp_path_factory.mktemp("notch") / "notch.igs"
    export_iges({"plate": face}, path, mode="analytic")
    return path


def _notch_nodes(mesh) -> int:
    """Nodes on the notch's three 2 mm sides (corners included), (x, y) within 1e-9."""
    x, y = mesh.nodes[:, 0], mesh.nodes[:, 1]
    on_sides = ((np.abs(x - 19) < 1e-9) | (np.abs(x - 21) < 1e-9)) & (y >= 30 - NOTCH - 1e-9) & (y <= 30 + 1e-9)
    on_bottom = (np.abs(y - (30 - NOTCH)) < 1e-9) & (x >= 19 - 1e-9) & (x <= 21 + 1e-9)
    return int(np.count_nonzero(on_sides | on_bottom))


@pytest.mark.parametrize("element", ["tri", "quad"])
def test_short_straight_edges_mesh_as_occs_lines(plate, element):
    occ = mesh_cad(plate, element=element, size=SIZE)  # OCC's reading: the notch's sides are lines
    model = read_iges(plate)
    with brep_source(model) as (path, _):
        plain = mesh_cad(path, element=element, size=SIZE)
        straight = mesh_cad(path, element=element, size=SIZE, straight_splines=True)
    # one segment per 2 mm side on OCC's lines: the 4 corners of the three sides, and in quads
    # the midpoint gmsh's all-quad subdivision adds to each segment
    assert _notch_nodes(occ) == {"tri": 4, "quad": 7}[element]
    assert _notch_nodes(straight) == _notch_nodes(occ)
    assert straight.n_nodes == occ.n_nodes
    assert plain.n_nodes != occ.n_nodes  # what the option is for
