"""The soundness check reads an IGES file's trims as its 142 curves prefer
(`cadbridge.verify.soundness._file_preference`).

References: OpenCASCADE's own readings of the file (read.surfacecurve.mode default and
forced), BRepCheck_Analyzer, and the analytic area of a generated plane whose two trim
representations disagree.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("OCP")

from cadbridge.cad.model import Face, Trim, TrimLoop  # noqa: E402
from cadbridge.iges.reader import curve_preferences  # noqa: E402
from cadbridge.iges.writer import write_iges  # noqa: E402
from cadbridge.nurbs.construct import line  # noqa: E402
from cadbridge.nurbs.surface import NurbsSurface  # noqa: E402
from cadbridge.verify.reference import occ_read  # noqa: E402
from cadbridge.verify.soundness import _file_preference  # noqa: E402

SHARED = Path(__file__).resolve().parents[3] / "shared"
OCC131_1 = SHARED / "cad_corpus" / "iges" / "occt_OCC131-1_ANSA9.igs"


def _area(face) -> float:
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    g = GProp_GProps()
    BRepGProp.SurfaceProperties_s(face, g)
    return g.Mass()


def test_a_plane_whose_trims_disagree_is_read_as_its_pref_says(tmp_path):
    """A plane 100 x 100 trimmed by the (u, v) square [0.1, 0.9]^2 (area 6400) whose
    model-space loop lies 0.2 inside (area 79.6^2): written with PREF = 1, so the check reads
    it with the parameter-space curves forced, and OCC's area is the analytic 6400."""
    s = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], [[[0, 0, 0], [0, 100, 0]], [[100, 0, 0], [100, 100, 0]]])
    c = [(0.1, 0.1), (0.9, 0.1), (0.9, 0.9), (0.1, 0.9)]
    q = [(10.2, 10.2, 0), (89.8, 10.2, 0), (89.8, 89.8, 0), (10.2, 89.8, 0)]
    loop = TrimLoop([line(c[i], c[(i + 1) % 4]) for i in range(4)], [line(q[i], q[(i + 1) % 4]) for i in range(4)])
    path = tmp_path / "plane.igs"
    write_iges([Face(s, de=1, trims=Trim(loop))], path)
    assert set(curve_preferences(path).values()) == {1}
    mode = _file_preference(path)
    assert mode == -2
    (face,) = occ_read(path, surface_curves=mode)
    assert _area(face.face) == pytest.approx(6400.0, rel=1e-9)


@pytest.mark.skipif(not OCC131_1.is_file(), reason="shared/cad_corpus not present")
def test_occ131_1_forced_reading_is_valid_and_holds_the_preferred_trims():
    """ANSA's OCC131-1: PREF = 1 on its one 142, a loop of 112 parametric splines 0.004 mm from
    its model-space curves. OCC's default reading bounds the face by the model-space curves
    (points of the preferred loop S(c(t)) lie up to 0.004 mm outside it); forced to the
    parameter-space curves, OCC's face is valid by BRepCheck_Analyzer and holds them."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeVertex
    from OCP.BRepCheck import BRepCheck_Analyzer
    from OCP.BRepExtrema import BRepExtrema_DistShapeShape
    from OCP.gp import gp_Pnt

    from cadbridge.iges import read_iges

    assert _file_preference(OCC131_1) == -2
    face = read_iges(OCC131_1).faces[0]
    uv = face.trims.outer.polygon(8)
    pts = face.surface.evaluate(uv[:, 0], uv[:, 1])[::7]

    def farthest(occ_face) -> float:
        d = []
        for p in pts:  # a yardstick: a loop over a few hundred points
            m = BRepExtrema_DistShapeShape(BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, p))).Vertex(), occ_face)
            m.Perform()
            d.append(m.Value())
        return float(np.max(d))

    (default,) = occ_read(OCC131_1)
    (forced,) = occ_read(OCC131_1, surface_curves=-2)
    assert BRepCheck_Analyzer(forced.face).IsValid()
    assert farthest(forced.face) < 1e-4
    assert farthest(default.face) > 2e-3
