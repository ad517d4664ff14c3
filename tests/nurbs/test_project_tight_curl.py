"""Projection beside a tight curl of a surface: no point is left without a foot.

Class of defect: where a surface rolls over within one cell of the projection's sample grid
(`occt_bug24012_face`: a 0.4 mm edge roll, the normal turning by 120 degrees, on a 15 mm
face), the nearest sample can lie past the curl; Newton from it jumped out of the domain and
oscillated between corners (FAILED), and the sampled distance around it had no second local
minimum for the global check to restart from. The patch samples of `cadbridge convert` on
that file then had no foot (an internal ValueError). Points still FAILED now restart from
their next nearest samples (`cadbridge.nurbs.project._failed_check`, and the same step in
`cadbridge.nurbs.project_many`).

Reference: OpenCASCADE's GeomAPI_ProjectPointOnSurf on a Geom_BSplineSurface of the same
poles and knots (`tests.helpers.occ.surface_nearest`), on a generated surface with such a
roll, and on the corpus file's surface (skipped when ../shared/cad_corpus is absent).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cadbridge.nurbs.project import FAILED, project_to_surface
from cadbridge.nurbs.project_many import SurfacePack, project_to_surfaces
from cadbridge.nurbs.surface import NurbsSurface

OCP = pytest.importorskip("OCP")
from cadbridge.verify.reference import occ_bspline_surface as to_occ  # noqa: E402
from tests.helpers.occ import surface_nearest  # noqa: E402

FACE = Path(__file__).resolve().parents[3] / "shared" / "cad_corpus" / "iges" / "occt_bug24012_face_OpenCASCADE.igs"


def _rolled(r: float = 0.02) -> NurbsSurface:
    """Bicubic sheet 10 x 10 whose v = 0 edge rolls over with radius about r: the profile
    (y, z) runs (0, 0) -> (r, 0) -> (2r, r), then straight up to z = 10; slightly irregular in u."""
    prof = np.array([(0.0, 0.0), (r, 0.0), (2 * r, r), (2 * r, 3.0), (2 * r, 6.0), (2 * r, 10.0)])
    cp = np.zeros((9, len(prof), 3))
    for i in range(9):
        cp[i, :, 0] = 10.0 * i / 8 + 0.3 * np.sin(i)
        cp[i, :, 1:] = prof
    return NurbsSurface(3, 3, [0, 0, 0, 0, 0.2, 0.4, 0.5, 0.6, 0.8, 1, 1, 1, 1],
                        [0, 0, 0, 0, 1 / 3, 2 / 3, 1, 1, 1, 1], cp)


def _points_near_the_roll(s: NurbsSurface, n: int, r: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(0.05, 0.95, n), rng.uniform(0.0, 0.03, n)
    return s.evaluate(u, v) + s.normal(u, v) * rng.uniform(-2.0, 2.0, (n, 1)) * r


def _check_against_occ(s: NurbsSurface, pts: np.ndarray, res) -> None:
    gs = to_occ(s)
    for p, d in zip(pts, res.distance):
        cands, _ = surface_nearest(gs, s, p)
        assert d <= cands[0][0] + 1e-9, (p, d, cands[0][0])


def test_generated_roll_every_point_gets_occs_foot():
    s = _rolled()
    pts = _points_near_the_roll(s, 4000, 0.02, seed=0)
    res = project_to_surface(s, pts)
    assert not np.any(res.status == FAILED)
    # the points Newton from the nearest sample alone could not place, and a sample of the
    # rest, against OCC's nearest foot
    with pytest.MonkeyPatch.context() as mp:
        import cadbridge.nurbs.project as project

        mp.setattr(project, "FAILED_SEEDS", 0)
        hard = project_to_surface(s, pts).status == FAILED
    assert hard.any()  # the case needs the restarts
    sel = hard | (np.arange(len(pts)) % 50 == 0)
    _check_against_occ(s, pts[sel], _take(res, sel))


def _take(res, sel):
    import dataclasses

    return dataclasses.replace(res, **{f.name: getattr(res, f.name)[sel] for f in dataclasses.fields(res)})


def test_generated_roll_many_surfaces_path_agrees():
    """`project_to_surfaces` (the compiled path of the search and the error measure) gives the
    same feet as `project_to_surface`."""
    s = _rolled()
    pts = _points_near_the_roll(s, 4000, 0.02, seed=0)
    one = project_to_surface(s, pts)
    many = project_to_surfaces(SurfacePack([s]), np.zeros(len(pts), dtype=np.int64), pts)
    assert not np.any(many.status == FAILED)
    assert np.allclose(many.foot, one.foot, atol=1e-9)


@pytest.mark.skipif(not FACE.is_file(), reason="corpus file occt_bug24012_face_OpenCASCADE.igs absent")
def test_corpus_roll_against_occ():
    """Points off the corpus face's edge roll (v < 0.02, within 2e-3 of the surface): all
    placed, each foot as near as OCC's."""
    from cadbridge.iges import read_iges

    s = read_iges(FACE).faces[0].surface
    rng = np.random.default_rng(1)
    u, v = rng.uniform(0.02, 0.98, 2000), rng.uniform(0.0, 0.02, 2000)
    pts = s.evaluate(u, v) + s.normal(u, v) * rng.uniform(-2e-3, 2e-3, (2000, 1))
    res = project_to_surface(s, pts)
    assert not np.any(res.status == FAILED)
    sel = slice(None, None, 40)
    _check_against_occ(s, pts[sel], _take(res, sel))
