"""Feet of model-space edges on a NURBS surface by continuation (`iges.edgefeet.edge_feet`,
the reference tables of `analytic.invert_edges`).

References: the global projection of every sample (`nurbs.project.project_to_surface`, with
its restarts from other local minima: what `invert_edges` used before, independent of the
continuation) on the B-rep faces of the real SolidEdge / Inventor files, and closed-form feet
on analytic geometry (a NURBS cylinder; a thin U-channel whose nearest sheet changes along
the edge, where continuation alone would stay on the wrong sheet).
"""

from __future__ import annotations

from math import pi
from pathlib import Path

import numpy as np
import pytest

import cadbridge.cad.edgefeet as ef
from cadbridge.nurbs.curve_pack import PackedCurves
from cadbridge.nurbs import construct
from cadbridge.nurbs.project import FAILED, project_to_surface

REAL = Path(__file__).parents[2].parent / "shared" / "iges_real"
FILES = ["occt_occ22470_SolidEdge_SpatialXPlus.igs", "occt_bug22869_Inventor2011_Spring.igs"]


def _samples(pieces, per_span=16):
    """As `invert_edges`: (points (M, 3), t (M,), starts (P+1,)) of the pieces."""
    pk = PackedCurves(pieces)
    ci, t = pk.sample(per_span)
    return pk.evaluate(ci, t, 0)[:, 0], t, np.searchsorted(ci, np.arange(len(pieces) + 1))


def _pole_tol(surface):
    u0, u1, v0, v1 = surface.domain
    b = surface.bbox()
    return 1e-9 * float(np.linalg.norm(b[1] - b[0])) / np.hypot(u1 - u0, v1 - v0)


class _Count:
    """Counts the points `edge_feet` sends to the full global projection (the fallback)."""

    def __init__(self, monkeypatch):
        self.fallback = 0
        orig = ef.project_to_surface

        def wrapped(surface, pts, **kw):
            if not kw:  # the anchors are projected with explicit tol / max_iter, the fallback without
                self.fallback += len(pts)
            return orig(surface, pts, **kw)

        monkeypatch.setattr(ef, "project_to_surface", wrapped)


@pytest.mark.parametrize("name", FILES)
def test_feet_equal_the_global_projection_on_real_brep_faces(name, monkeypatch):
    """On every loop built from model-space edges in the file: the continued feet are at the
    distance of the global projection of each sample (within 1e-9 x size) and at the same 3D
    foot, and no piece needed the fallback (the fast path is what ran)."""
    path = REAL / name
    if not path.is_file():
        pytest.skip(f"{path} not present")
    from cadbridge.iges import read_iges

    model = read_iges(path)
    count = _Count(monkeypatch)
    loops = 0
    for f in model.faces:
        for lp in [f.trims.outer] + list(f.trims.inner):
            if lp is None or not lp.model_curves:
                continue
            s = f.surface
            size = float(np.linalg.norm(np.subtract(*s.bbox()[::-1])))
            pts, t, starts = _samples(lp.model_curves)
            uv, failed = ef.edge_feet(s, pts, t, starts, _pole_tol(s))
            ref = project_to_surface(s, pts)  # reference: global projection of every sample
            assert not failed.any() and not np.any(ref.status == FAILED)
            foot = s.evaluate(uv[:, 0], uv[:, 1])
            dist = np.linalg.norm(foot - pts, axis=1)
            assert np.allclose(dist, ref.distance, rtol=0, atol=1e-9 * size), np.abs(dist - ref.distance).max()
            assert np.allclose(foot, ref.foot, rtol=0, atol=1e-8 * size), np.abs(foot - ref.foot).max()
            loops += 1
    assert loops > 0
    assert count.fallback == 0


def test_seam_of_a_closed_cylinder_against_closed_form(monkeypatch):
    """A circle at height z0 on a full-turn NURBS cylinder, crossing the seam: every foot is at
    the closed-form (u, v) = (z0 / h, revolved_angle_to_v(angle)) modulo the period."""
    r, h, z0 = 3.0, 5.0, 2.0
    s = construct.revolved_surface(construct.line([r, 0, 0], [r, 0, h]), [0, 0, 0], [0, 0, 1], 0.0, 2 * pi)
    a0, a1 = -1.0, 1.5  # through angle 0 = 2 pi, the seam
    arc = construct.circular_arc([0, 0, z0], [r * np.cos(a0), r * np.sin(a0), z0], [r * np.cos(a1), r * np.sin(a1), z0])
    count = _Count(monkeypatch)
    pts, t, starts = _samples([arc])
    uv, failed = ef.edge_feet(s, pts, t, starts, _pole_tol(s))
    assert not failed.any() and count.fallback == 0
    ang = np.arctan2(pts[:, 1], pts[:, 0]) % (2 * pi)
    want_v = construct.revolved_angle_to_v(ang, 0.0, 2 * pi)
    assert np.allclose(uv[:, 0], z0 / h, atol=1e-12)
    dv = (uv[:, 1] - want_v + pi) % (2 * pi) - pi  # v runs over [0, 2 pi]: compare modulo the period
    assert np.abs(dv).max() <= 1e-10


def test_edge_far_off_the_surface_takes_the_global_projection(monkeypatch):
    """An edge 0.1 (1e-2 x size) off the cylinder is beyond FAR_REL: its piece is projected
    globally (counted), with the closed-form feet (same angle and height)."""
    r, h, z0, off = 3.0, 5.0, 2.0, 0.1
    s = construct.revolved_surface(construct.line([r, 0, 0], [r, 0, h]), [0, 0, 0], [0, 0, 1], 0.0, 2 * pi)
    rr = r + off
    arc = construct.circular_arc([0, 0, z0], [rr * np.cos(0.3), rr * np.sin(0.3), z0],
                                 [rr * np.cos(2.0), rr * np.sin(2.0), z0])
    count = _Count(monkeypatch)
    pts, t, starts = _samples([arc])
    uv, failed = ef.edge_feet(s, pts, t, starts, _pole_tol(s))
    assert not failed.any() and count.fallback == len(pts)
    ang = np.arctan2(pts[:, 1], pts[:, 0])
    assert np.allclose(uv[:, 0], z0 / h, atol=1e-12)
    assert np.allclose(uv[:, 1], construct.revolved_angle_to_v(ang, 0.0, 2 * pi), atol=1e-10)


def test_nearest_sheet_changes_along_the_edge(monkeypatch):
    """A thin U-channel (two sheets y = 0 and y = g, x in [0, 10], joined by a half circle at
    x = 0; extruded along z), g = 4e-4 x size, and an edge across the gap from y = 0.1 g to
    y = 0.9 g at x = 8: continuation from the foot on y = 0 would stay on that sheet; the foot
    of the last sample is on y = g, so the piece is projected globally. Closed form: the foot
    of (8, y, z) is (8, 0, z) for y < g / 2, (8, g, z) beyond."""
    g = 4e-3
    u_shape = construct.composite_curve([
        construct.line([10.0, 0, 0], [0.0, 0, 0]),
        construct.circular_arc([0.0, g / 2, 0], [0.0, 0, 0], [0.0, g, 0], normal=[0, 0, -1]),
        construct.line([0.0, g, 0], [10.0, g, 0]),
    ])
    s = construct.tabulated_cylinder(u_shape, [0, 0, 1.0])
    edge = construct.line([8.0, 0.1 * g, 0.5], [8.0, 0.9 * g, 0.5])
    count = _Count(monkeypatch)
    pts, t, starts = _samples([edge])
    keep = np.abs(pts[:, 1] - g / 2) > 1e-3 * g  # the tie at y = g / 2 has two feet
    uv, failed = ef.edge_feet(s, pts, t, starts, _pole_tol(s))
    assert not failed.any() and count.fallback == len(pts)
    foot = s.evaluate(uv[:, 0], uv[:, 1])
    want = np.column_stack([np.full(len(pts), 8.0), np.where(pts[:, 1] < g / 2, 0.0, g), pts[:, 2]])
    assert np.allclose(foot[keep], want[keep], rtol=0, atol=1e-10)
