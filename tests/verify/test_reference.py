"""The OpenCASCADE reference: reading, evaluation, normals, projection, classification."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cadbridge.verify.reference import OccReadError, occ_eval, occ_inside, occ_normal, occ_project, occ_read

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"


def test_read_errors(tmp_path: Path) -> None:
    with pytest.raises(OccReadError, match="no such file"):
        occ_read(tmp_path / "missing.igs")
    bad = tmp_path / "bad.igs"
    bad.write_text("this is not an IGES file\n")
    with pytest.raises(OccReadError):
        occ_read(bad)


def test_quarter_cylinder_exact() -> None:
    (face,) = occ_read(SAMPLES / "rational_quarter_cylinder.igs")
    assert face.kind == "Geom_BSplineSurface" and not face.reversed
    u0, u1, v0, v1 = face.bounds
    u = np.linspace(u0, u1, 50)
    v = np.linspace(v0, v1, 50)
    pos, d1, d2 = occ_eval(face.surface, u, v, order=2)
    assert d1.shape == (50, 2, 3) and d2.shape == (50, 3, 3)
    radial = pos[:, [0, 2]] - np.array([41.0, -5.0])
    assert np.allclose(np.linalg.norm(radial, axis=1), 5.0, atol=1e-12)
    n = occ_normal(face.surface, u, v)
    assert np.allclose(n[:, [0, 2]], radial / 5.0, atol=1e-12) and np.allclose(n[:, 1], 0, atol=1e-12)  # outward


def test_project_round_trip() -> None:
    (face,) = occ_read(SAMPLES / "sphere_patch.igs")
    u0, u1, v0, v1 = face.bounds
    rng = np.random.default_rng(0)
    u, v = rng.uniform(u0, u1, 30), rng.uniform(v0, v1, 30)
    pos = occ_eval(face.surface, u, v, order=0)[0]
    n = occ_normal(face.surface, u, v)
    pu, pv, foot, dist = occ_project(face.surface, pos + 0.5 * n)
    assert np.allclose(dist, 0.5, atol=1e-9) and np.allclose(foot, pos, atol=1e-9)
    assert np.allclose(np.linalg.norm(foot, axis=1), 10.0, atol=1e-9)


def test_inside_trimmed_hole() -> None:
    (face,) = occ_read(SAMPLES / "trimmed_hole.igs")
    uv_pts = np.array([[30.0, 25.0], [5.0, 5.0], [30.0, 36.0], [30.0, 34.0], [95.0, 55.0]])
    # plane NURBS: parameters are the x, y coordinates of the plate (checked below)
    pos = occ_eval(face.surface, uv_pts[:, 0], uv_pts[:, 1], order=0)[0]
    assert np.allclose(pos[:, :2], uv_pts, atol=1e-9)
    inside = occ_inside(face, uv_pts[:, 0], uv_pts[:, 1])
    assert inside.tolist() == [False, True, True, False, True]


def test_location_applied() -> None:
    faces = occ_read(SAMPLES / "placed_by_124.igs")
    assert len(faces) == 2
    sphere = faces[0]
    u0, u1, v0, v1 = sphere.bounds
    pos = occ_eval(sphere.surface, np.linspace(u0, u1, 7), np.linspace(v0, v1, 7), order=0)[0]
    # sphere R10 about the origin, moved by T1 (rotation about z, translation (10, 0, 5))
    assert np.allclose(np.linalg.norm(pos - [10.0, 0.0, 5.0], axis=1), 10.0, atol=1e-9)
    assert not math.isnan(pos.sum())


STEP_CORPUS = Path(__file__).resolve().parents[3] / "shared" / "cad_corpus" / "step"


@pytest.mark.skipif(not STEP_CORPUS.is_dir(), reason="shared/cad_corpus not present")
@pytest.mark.parametrize("name", ["trj6_k1-sd-214.stp", "trj8_k1-ct-214.stp"])
def test_face_boxes_hold_the_faces(name: str) -> None:
    """Each face's box (the nearest-face searches of `verify.soundness` prune by it) holds the
    face. OCC's quick box (`BRepBndLib.Add`, no triangulation) boxed K1's torus fillets as a flat
    disc and the soundness check put nodes that lie on the face (OCC's own projector and
    classifier: 1.6e-9 mm) 1.2 mm off it. Reference: OCC's mesh of each face (BRepMesh)."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepMesh import BRepMesh_IncrementalMesh
    from OCP.TopLoc import TopLoc_Location

    faces = occ_read(STEP_CORPUS / name)
    size = float(np.linalg.norm(np.max([f.bbox[1] for f in faces], axis=0) - np.min([f.bbox[0] for f in faces], axis=0)))
    for f in faces:  # loop over faces: each meshed by OCC, its nodes against its box
        BRepMesh_IncrementalMesh(f.face, 1e-3 * size, False, 0.1)
        loc = TopLoc_Location()
        tri = BRep_Tool.Triangulation_s(f.face, loc)
        assert tri is not None
        trsf = loc.Transformation()
        pts = np.array([[p.X(), p.Y(), p.Z()] for p in
                        (tri.Node(i).Transformed(trsf) for i in range(1, tri.NbNodes() + 1))])
        slack = 1e-6 * size  # the soundness tolerance (mesh nodes on edges lie within the edge tolerance)
        assert np.all(pts >= f.bbox[0] - slack) and np.all(pts <= f.bbox[1] + slack), (f.index, f.kind)


def test_projection_beside_a_pole_is_exact() -> None:
    """`occ_project` (verify's reference) of points on a surface of revolution 1e-4 rad from
    its pole: OCC's projector made once per surface (its sample grid from Init) stopped 7.4e-7 mm
    short there on K1 from CADDS; points not on the surface to round-off are projected again by
    a projector made for the point. Reference: the points are OCC's own S(u, v)."""
    from OCP.Geom import Geom_BSplineCurve, Geom_SurfaceOfRevolution
    from OCP.gp import gp_Ax1, gp_Dir, gp_Pnt
    from OCP.TColgp import TColgp_Array1OfPnt
    from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal

    r = 10.0  # a quarter circle from the axis (the pole) out to radius r, as a rational quadratic
    poles = TColgp_Array1OfPnt(1, 3)
    for i, p in enumerate([(0.0, 0.0, r), (r, 0.0, r), (r, 0.0, 0.0)]):
        poles.SetValue(i + 1, gp_Pnt(*p))
    weights = TColStd_Array1OfReal(1, 3)
    for i, w in enumerate([1.0, math.sqrt(0.5), 1.0]):
        weights.SetValue(i + 1, w)
    knots, mults = TColStd_Array1OfReal(1, 2), TColStd_Array1OfInteger(1, 2)
    knots.SetValue(1, -math.pi / 2)
    knots.SetValue(2, math.pi / 2)
    mults.SetValue(1, 3)
    mults.SetValue(2, 3)
    surf = Geom_SurfaceOfRevolution(Geom_BSplineCurve(poles, weights, knots, mults, 2),
                                    gp_Ax1(gp_Pnt(0, 0, 0), gp_Dir(0, 0, 1)))
    rng = np.random.default_rng(3)
    u = rng.uniform(0.0, 2 * math.pi, 50)
    v = -math.pi / 2 + rng.uniform(1e-5, 1e-3, 50)
    pts, _, _ = occ_eval(surf, u, v, order=0)
    _, _, _, dist = occ_project(surf, pts)
    assert np.nanmax(dist) <= 1e-12 * r, np.nanmax(dist)
