"""120 faces whose generatrix pcurves give the arc's angles one turn away from the arc's own
range (`cadbridge.cad.analytic.ArcMap` shifts such angles by whole turns instead of clipping).

The analytic production die's bead ends BED01060, BED01068, BED01079, BED01087: surfaces of
revolution of a 100 arc of angles -1.23..0 rad whose trim pcurves run at s = 5.05..6.28 rad.
Clipping collapsed every loop to one generatrix parameter and the faces read untrimmed
("trim loops degenerate (zero extent)"). Reference: OpenCASCADE's area of the same faces
(IGESControl_Reader, BRepGProp), against cadbridge's area by a midpoint rule of |S_u x S_v|
over its (u, v) box, cells kept where the face's trim contains their centre.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.helpers import occ as OCC

DIE = Path(__file__).parents[2] / "iges_samples" / "production_die_analytic.igs"
NAMES = ["BED01060", "BED01068", "BED01079", "BED01087"]


def _occ_area(root: int) -> float:
    from OCP.IGESControl import IGESControl_Reader

    r = IGESControl_Reader()
    r.ReadFile(str(DIE))
    assert r.TransferOneRoot(root)
    return OCC.area(r.OneShape())


def _cadbridge_area(face, n: int = 400) -> float:
    u0, u1, v0, v1 = face.surface.domain
    du, dv = (u1 - u0) / n, (v1 - v0) / n
    u, v = np.meshgrid(u0 + du * (np.arange(n) + 0.5), v0 + dv * (np.arange(n) + 0.5), indexing="ij")
    uv = np.column_stack([u.ravel(), v.ravel()])
    d = np.asarray(face.surface.derivatives(uv[:, 0], uv[:, 1], order=1))
    su, sv = d[:, 1, 0], d[:, 0, 1]
    jac = np.linalg.norm(np.cross(su, sv), axis=1)
    return float((jac * face.trims.contains(uv[:, 0], uv[:, 1])).sum() * du * dv)


@pytest.mark.skipif(not DIE.is_file(), reason="the analytic production die is generated on request")
def test_bead_end_revolutions_read_trimmed_with_occ_area():
    pytest.importorskip("OCP")
    from cadbridge.iges import read_iges

    model = read_iges(DIE)
    for name in NAMES:
        k, face = next((k, f) for k, f in enumerate(model.faces) if f.name == name)
        assert face.trims is not None, name
        ref = _occ_area(k + 1)  # roots in file order, 1-based
        area = _cadbridge_area(face)
        # 400 x 400 cells: the boundary cells' error is ~1e-3 of the area
        assert abs(area - ref) < 5e-3 * ref, (name, area, ref)
