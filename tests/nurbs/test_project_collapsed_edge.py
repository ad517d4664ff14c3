"""Projection onto a strip that runs out at a corner: one domain edge collapsed to a near-point.

A fillet strip whose two long edges meet at a corner has its u = 1 edge shrunk to 1e-4 where
the next grid ring spans tens of mm. Every point beside the strip's end then has its nearest
grid samples on that edge, Newton started there settles in a local minimum on the wrong side
of the fold (a point on the surface reported 2-6 mm off it), and the edge and global checks
restart only from those same samples. t4mec.stp (Euclid, degree-7 patches) lost two mesh nodes
this way (7.3 mm off by cadbridge, on the face by OCC). The restarts of a true pole
(`pole_starts`: the next ring's nearest sample, and half-way to it) now also serve such a
collapsed edge (`pole_edges`, `COLLAPSED_REL`) and every point whose nearest sample lies on it.

Reference: analytic (each point is S(u, v) of the surface by construction: its foot is the
point itself, distance 0).
"""

from __future__ import annotations

import numpy as np
import pytest

from cadbridge.cad.model import Face, Model
from cadbridge.cad.search import project_points
from cadbridge.nurbs.project import CONVERGED, ON_BOUNDARY, pole_edges, project_to_surface, surface_samples
from cadbridge.nurbs.surface import NurbsSurface


def _strip(degree_u: int) -> NurbsSurface:
    """A deep fold (quadratic in v, 200 wide and 400 deep at u = 0) running out at the corner
    (1000, -100, 0) at u = 1, where the v-edge spans 2e-4; degree ``degree_u`` along u."""
    corner = np.array([1000.0, -100.0, 0.0])
    top = np.array([[0.0, 0.0, 0.0], [0.0, -100.0, -800.0], [0.0, -200.0, 0.0]])
    end = corner + np.array([[0.0, 0.0, 0.0], [0.0, 1e-4, 0.0], [0.0, 2e-4, 0.0]])
    rows = np.array([top + (end - top) * t for t in np.linspace(0.0, 1.0, degree_u + 1)])
    knots_u = np.r_[np.zeros(degree_u + 1), np.ones(degree_u + 1)]
    return NurbsSurface(degree_u, 2, knots_u, np.array([0, 0, 0, 1, 1, 1.0]), rows)


U = np.array([0.99, 0.995, 0.999, 0.98, 0.97, 0.985, 0.9767])
V = np.array([1.0, 0.9, 0.75, 1.0, 0.999, 0.95, 1.0])


@pytest.mark.parametrize("degree_u", [1, 3, 7])
def test_collapsed_edge_is_seen(degree_u):
    s = _strip(degree_u)
    assert pole_edges(surface_samples(s))[1]  # u = 1: collapsed, not an exact pole


@pytest.mark.parametrize("degree_u", [1, 3, 7])
def test_points_beside_a_collapsed_edge_project_onto_themselves(degree_u):
    s = _strip(degree_u)
    pts = s.evaluate(U, V)
    r = project_to_surface(s, pts)
    assert np.all(np.isin(r.status, (CONVERGED, ON_BOUNDARY)))
    assert r.distance.max() <= 1e-9 * 1000.0, r.distance


def test_model_projection_beside_a_collapsed_edge():
    """The compiled multi-face search (`project_points`, `project_to_surfaces`) as well."""
    s = _strip(7)
    model = Model(faces=[Face(s, de=1)])
    pts = s.evaluate(U, V)
    r = project_points(pts, model)
    assert np.all(r.face == 0)
    assert r.distance.max() <= 1e-9 * 1000.0, r.distance
    np.testing.assert_allclose(r.foot, pts, atol=1e-9 * 1000.0)
