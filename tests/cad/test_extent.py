"""Class: a rational surface whose control net lies far outside the surface (the default size).

A rational patch can keep a pole very far away with a tiny weight: a circular arc of nearly
180 degrees as one quadratic span has its middle pole at R / cos(89.9 deg) = 573 R. trj6_b1
(Open CASCADE 4.0 STEP, a part 304 mm across) has two such faces whose nets reach 26.5 m. The
default element size is the box of the nets (gmsh's) / 20: 1 326 mm there. The trimmed faces'
box (`cadbridge.cad.extent`) is the part's, and convert's notes name it where the two differ.

Sample: a half cylinder R 20, 30 high (179.8 degrees), as one rational quadratic x linear
patch (OCP), written as STEP. References: OCC's `BRepBndLib::AddOptimal` (the shape's tight
box) and the analytic cylinder.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

R, H, SWEEP = 20.0, 30.0, math.radians(179.8)
CORPUS = Path(__file__).resolve().parents[2].parent / "shared" / "cad_corpus" / "step"


def _write_far_pole_patch(path: Path) -> None:
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace
    from OCP.Geom import Geom_BSplineSurface
    from OCP.gp import gp_Pnt
    from OCP.STEPControl import STEPControl_AsIs, STEPControl_Writer
    from OCP.TColgp import TColgp_Array2OfPnt
    from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal, TColStd_Array2OfReal

    c = math.cos(SWEEP / 2)
    arc = [(R * c, -R * math.sin(SWEEP / 2)), (R / c, 0.0), (R * c, R * math.sin(SWEEP / 2))]
    poles, weights = TColgp_Array2OfPnt(1, 3, 1, 2), TColStd_Array2OfReal(1, 3, 1, 2)
    for i, (x, y) in enumerate(arc):
        for j, z in enumerate((0.0, H)):
            poles.SetValue(i + 1, j + 1, gp_Pnt(x, y, z))
            weights.SetValue(i + 1, j + 1, c if i == 1 else 1.0)
    knots = TColStd_Array1OfReal(1, 2)
    knots.SetValue(1, 0.0)
    knots.SetValue(2, 1.0)
    mu, mv = TColStd_Array1OfInteger(1, 2), TColStd_Array1OfInteger(1, 2)
    for k in (1, 2):
        mu.SetValue(k, 3)
        mv.SetValue(k, 2)
    face = BRepBuilderAPI_MakeFace(Geom_BSplineSurface(poles, weights, knots, knots, mu, mv, 2, 1), 1e-7).Face()
    w = STEPControl_Writer()
    w.Transfer(face, STEPControl_AsIs)
    w.Write(str(path))


@pytest.fixture(scope="module")
def far_pole(tmp_path_factory):
    pytest.importorskip("OCP")
    path = tmp_path_factory.mktemp("extent") / "far_pole.step"
    _write_far_pole_patch(path)
    return path


def _occ_tight_box(path: Path) -> np.ndarray:
    from OCP.Bnd import Bnd_Box
    from OCP.BRepBndLib import BRepBndLib
    from OCP.STEPControl import STEPControl_Reader

    r = STEPControl_Reader()
    r.ReadFile(str(path))
    r.TransferRoots()
    box = Bnd_Box()
    BRepBndLib.AddOptimal_s(r.OneShape(), box, False, False)
    return np.array(box.Get()).reshape(2, 3)


@pytest.mark.parametrize("name", ["far_pole", "trj6_b1-ec-214.stp", "bug29241.stp"])
def test_trimmed_box_is_occs_tight_box(name, far_pole):
    from cadbridge import read_cad
    from cadbridge.cad.extent import trimmed_box

    path = far_pole if name == "far_pole" else CORPUS / name
    if not path.is_file():
        pytest.skip(f"{path} not present")
    model = read_cad(path)
    ours, occ = trimmed_box(model), _occ_tight_box(path)
    diag = float(np.linalg.norm(occ[1] - occ[0]))
    assert model.size() > 1.9 * diag  # the sample has the defect: the nets reach far past the part
    assert np.abs(ours - occ).max() <= 2e-3 * diag


def test_convert_notes_a_default_size_far_above_the_part(far_pole, tmp_path):
    """convert without --size on the far-pole patch: its notes give the nets' box against the
    part's (the half cylinder's box 2R x R x H, analytic) and the size that follows the part;
    the tool is still made."""
    from cadbridge import convert

    run = convert(str(far_pole), str(tmp_path), element="tri")
    (note,) = [n for n in run.notes if "control nets" in n]
    diag = math.hypot(2 * R, math.hypot(R, H))
    assert f"--size {diag / 20:.3g}" in note
    assert run.tools


@pytest.mark.parametrize("name", ["far_pole", "trj6_b1-ec-214.stp"])
def test_loop_start_box_lies_inside_the_trimmed_box(name, far_pole):
    """The cheap lower bound `_far_nets_note` asks first is inside OCC's tight box."""
    from cadbridge import read_cad
    from cadbridge.cad.extent import loop_start_box

    path = far_pole if name == "far_pole" else CORPUS / name
    if not path.is_file():
        pytest.skip(f"{path} not present")
    occ = _occ_tight_box(path)
    low = loop_start_box(read_cad(path))
    tol = 1e-6 * float(np.linalg.norm(occ[1] - occ[0]))
    assert np.all(low[0] >= occ[0] - tol) and np.all(low[1] <= occ[1] + tol)
