"""`cadbridge.mesh.gmsh.presew`: gmsh's sewing on import done by OCC through OCP.

Reference: gmsh's own import of the same ``.brep`` with ``Geometry.OCCSewFaces`` on (gmsh's
OpenCASCADE): the pre-sewn file imported with it off gives gmsh the same entities, in the
same order, with the same boxes. The models: the U-shape's analytic tools (7 faces sewn into
one shell) and faces with a degenerated edge at an apex or a pole (which gmsh's sewing
removes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cadbridge.heal.brep import brep_source
from cadbridge.iges import read_iges
from cadbridge.mesh.gmsh.presew import presew_brep

pytest.importorskip("OCP")
gmsh = pytest.importorskip("gmsh")

SAMPLES = Path(__file__).resolve().parents[3] / "iges_samples"


def _entities(path: Path, sew: bool) -> dict:
    """{(dim, tag): bounding box (6,)} of gmsh's import of ``path``."""
    gmsh.initialize()
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("Geometry.OCCSewFaces", 1 if sew else 0)
        gmsh.option.setNumber("Geometry.Tolerance", 1e-4)
        gmsh.option.setNumber("Geometry.OCCImportLabels", 0)
        gmsh.model.occ.importShapes(str(path))
        gmsh.model.occ.synchronize()
        return {(d, t): np.array(gmsh.model.getBoundingBox(d, t)) for d in (0, 1, 2) for _, t in gmsh.model.getEntities(d)}
    finally:
        gmsh.finalize()


@pytest.mark.parametrize("name", ["ushape_tools_analytic.igs", "cone_apex.igs", "hemisphere_pole.igs"])
def test_presewn_brep_is_what_gmshs_sewing_makes(name, tmp_path):
    model = read_iges(SAMPLES / name)
    with brep_source(model) as (path, brep):
        theirs = _entities(path, sew=True)
        out = tmp_path / "sewn.brep"
        assert presew_brep(path, out, 1e-4)
        mine = _entities(out, sew=False)
        unsewn = _entities(path, sew=False)
    assert mine.keys() == theirs.keys()
    size = float(np.linalg.norm(np.ptp(np.array([b for b in theirs.values()]).reshape(-1, 3), axis=0)))
    for key, box in theirs.items():
        np.testing.assert_allclose(mine[key], box, atol=1e-9 * size, err_msg=str(key))
    if any("degenerate" in f for b in brep.faces for f in b.fixes):  # the case is not vacuous
        assert len([k for k in unsewn if k[0] == 1]) > len([k for k in mine if k[0] == 1])


def test_an_unreadable_file_is_left_to_gmsh(tmp_path):
    bad = tmp_path / "bad.brep"
    bad.write_text("not a brep\n")
    assert presew_brep(bad, tmp_path / "out.brep", 1e-4) is False
    assert not (tmp_path / "out.brep").exists()
