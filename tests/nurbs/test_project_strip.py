"""Projection onto badly parametrised rational fillet strips: no FAILED foot, OCC's distance.

Class of defect (issue 35): a fillet strip of a die is a rational quadratic arc (v) swept along
a long spine (u), with u in [0, 1] over hundreds of millimetres: |Su| ~ 500 against |Sv| ~ 1.5,
the Hessian of the squared distance conditioned ~1e5, and weights varying along the spine. Newton
steps from a start sample must still land on the foot (a FAILED foot leaves a mesh node without
a normal); the compiled pairs (`project_to_surfaces`) must agree with `project_to_surface`.

Reference: OpenCASCADE's GeomAPI_ProjectPointOnSurf (initialised once on a Geom_BSplineSurface of
the same poles, weights and knots, then `Perform(P)` per point): its LowerDistance, independent of
our sampling and Newton. Points within half the least fillet radius of the strip have one foot;
points out to three radii (past the arc's centre on the concave side, where every point of an
arc is nearly equally far and OCC's LowerDistance itself is at times a farther extremum) must
get a foot (not FAILED) that is a point of the surface at the reported distance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cadbridge.nurbs.project import FAILED, project_to_surface
from cadbridge.nurbs.project_many import SurfacePack, project_to_surfaces
from cadbridge.nurbs.surface import NurbsSurface
from tests.helpers.surfaces import circle_arc

OCP = pytest.importorskip("OCP")
from cadbridge.verify.reference import occ_bspline_surface as to_occ  # noqa: E402


def strip(rng, length: float = 500.0, r: float = 1.0, nu: int = 12, spread: float = 1.0) -> tuple[NurbsSurface, float]:
    """Quarter-circle fillet of radius r (+-30 % along the spine; rational quadratic in v) swept
    along a wavy spine of ``length`` in x, u in [0, 1] (|Su| ~ length, |Sv| ~ r pi / 2); the
    weights of each cross-section scaled by exp(+-spread). Returns the surface and the least
    radius."""
    cc, cw, ck = circle_arc(0.0, math.pi / 2)
    rr = r * (1.0 + 0.3 * rng.uniform(-1.0, 1.0, nu))
    cp = np.empty((nu, 3, 3))
    cp[:, :, 0] = np.linspace(0.0, length, nu)[:, None]
    cp[:, :, 1] = rng.uniform(-0.02, 0.02, nu)[:, None] * length + rr[:, None] * cc[None, :, 0]
    cp[:, :, 2] = rng.uniform(-0.02, 0.02, nu)[:, None] * length + rr[:, None] * cc[None, :, 1]
    w = cw[None, :] * np.exp(spread * rng.uniform(-1.0, 1.0, (nu, 1)))
    ku = np.concatenate([[0.0] * 4, np.linspace(0.0, 1.0, nu - 2)[1:-1], [1.0] * 4])
    return NurbsSurface(3, 2, ku, ck, cp, w), float(rr.min())


def occ_lower_distance(s: NurbsSurface, pts: np.ndarray) -> np.ndarray:
    """(N,) OCC's LowerDistance of each point (NaN where it found no extremum)."""
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt

    pr = GeomAPI_ProjectPointOnSurf()
    pr.Init(to_occ(s), *s.domain)
    out = np.full(len(pts), np.nan)
    for i, p in enumerate(pts):
        pr.Perform(gp_Pnt(*map(float, p)))
        if pr.NbPoints() > 0:
            out[i] = pr.LowerDistance()
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_strip_feet_match_occ(seed):
    rng = np.random.default_rng(seed)
    s, rmin = strip(rng, spread=0.5 + seed)
    d1 = s.derivatives(np.array([0.5]), np.array([0.5]), order=1)
    assert np.linalg.norm(d1[0, 1, 0]) > 100.0 * np.linalg.norm(d1[0, 0, 1])  # badly parametrised
    n = 600
    u, v = rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 1.0, n)
    near = np.arange(n) < n // 2  # one foot: within half the least radius
    off = np.where(near, rng.uniform(-0.5, 0.5, n) * rmin, rng.uniform(-3.0, 3.0, n) * rmin)
    pts = s.evaluate(u, v) + off[:, None] * s.normal(u, v)
    occ = occ_lower_distance(s, pts)
    assert not np.any(np.isnan(occ))
    size = float(np.linalg.norm(np.ptp(s.control_points.reshape(-1, 3), axis=0)))
    one = project_to_surface(s, pts)
    many = project_to_surfaces(SurfacePack([s]), np.zeros(n, dtype=np.int64), pts)
    for r in (one, many):
        assert not np.any(r.status == FAILED)
        np.testing.assert_allclose(r.distance[near], occ[near], rtol=0, atol=1e-9 * size)
        np.testing.assert_allclose(r.foot, s.evaluate(r.u, r.v), rtol=0, atol=1e-12 * size)
        np.testing.assert_allclose(r.distance, np.linalg.norm(pts - r.foot, axis=1), rtol=0, atol=1e-12 * size)
    np.testing.assert_allclose(one.distance, many.distance, rtol=0, atol=1e-12 * size)
