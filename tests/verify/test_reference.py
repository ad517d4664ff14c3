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
