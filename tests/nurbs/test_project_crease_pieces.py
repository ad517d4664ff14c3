"""Projection next to a crease inside one NURBS surface (`smooth_pieces`).

Reference: analytic. The surface is the plane z = 0 for v in [0, 1] and, across a C0 knot at
v = 1, a plane tilted by a small angle a about the line y = 1, z = 0 (a bilinear-in-u,
degree-2-in-v NURBS with the knot 1 doubled, so the halves are exactly flat). The point sits
above the lower plane, eps before the crease, at the height h with tan a = eps / h: from the
upper side the gradient of the distance vanishes exactly at the crease. This is the
production NURBS die's FTR00037 case (a 1e-5 rad crease) in small.
"""

from __future__ import annotations

import numpy as np

from cadbridge.nurbs.project import CONVERGED, project_to_surface, smooth_pieces
from cadbridge.nurbs.surface import NurbsSurface

EPS, H = 1e-5, 0.5
A = np.arctan(EPS / H)


def _kinked() -> NurbsSurface:
    c, s = np.cos(A), np.sin(A)
    # v control net: y = 0, 0.5, 1 (lower plane), then the tilted half along (0, c, s)
    row = np.array([[0.0, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 1.0 + 0.5 * c, 0.5 * s],
                    [0.0, 1.0 + c, s]])
    pts = np.stack([row, row + [1.0, 0.0, 0.0]])  # (2, 5, 3): u along x
    return NurbsSurface(1, 2, [0, 0, 1, 1], [0, 0, 0, 1, 1, 2, 2, 2], pts)


def test_the_surface_has_one_crease_and_two_pieces():
    s = _kinked()
    ku, kv = s.crease_knots()
    assert len(ku) == 0 and np.allclose(kv, [1.0])
    assert len(smooth_pieces(s)) == 2


def test_lower_piece_derivatives_at_the_crease_are_the_lower_side():
    """A piece's derivatives at its upper end come from its own side of the crease
    (reference: the whole surface's one-sided derivatives, side_v = -1, and the plane z = 0)."""
    s = _kinked()
    lower = smooth_pieces(s)[0]
    u = np.array([0.3])
    d_piece = lower.derivatives(u, np.array([1.0]), 1)[0]
    d_side = s.derivatives(u, np.array([1.0]), 1, side_v=np.array([-1]))[0]
    assert np.allclose(d_piece, d_side, rtol=0, atol=1e-14)
    assert abs(d_piece[0, 1, 2]) < 1e-14  # S_v of the lower plane has no z part


def test_foot_just_before_a_crease_is_on_the_lower_plane():
    """Foot (0.4, 1 - eps, 0), distance h, normal +z (analytic). Before the pieces had their own
    knot vectors, the lower piece stopped at the crease with the upper side's zero gradient and
    FAILED, and the foot went to the crease: 1e-5 off, normal 2e-5 rad off."""
    x = np.array([[0.4, 1.0 - EPS, H]])
    r = project_to_surface(_kinked(), x)
    assert r.status[0] == CONVERGED
    assert np.allclose(r.foot[0], [0.4, 1.0 - EPS, 0.0], rtol=0, atol=1e-12)
    assert abs(r.distance[0] - H) < 1e-12
    assert np.linalg.norm(np.cross(r.normal[0], [0.0, 0.0, 1.0])) < 1e-12
