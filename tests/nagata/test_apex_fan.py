"""Nagata patches around a cone apex (the normal choice of `cadbridge.normals.singular`).

A fan of triangles from the apex of an exact cone (apex at the origin, axis +z, half angle 30
deg) to a ring of nodes on it, with the exact cone normals at the ring. Reference: the
analytic cone.

* With the axis as the apex's normal every generatrix edge is straight and starts from rest
  (c = d), and each patch is exactly the cone over its ring edge: x(s eta, s zeta) = s^2
  x(eta, zeta) from the apex; its distance to the cone is its ring edge's.
* With each element's own limit normal at the apex instead (corner normals; the tool file's
  rule for an edge with several normals at one end picks the one most orthogonal to it), the
  generatrix edges bend and the patches leave the cone by more than the ring edges do.
* The patch normal at the apex (both tangents vanish there) is the limit from inside the
  patch, not the direction of round-off.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cadbridge.nagata import NagataMesh

HALF = math.radians(30.0)


def _cone_normal(az: np.ndarray) -> np.ndarray:
    """Outward unit normal of the cone r = z tan(30 deg) along the generatrix at azimuth az."""
    az = np.atleast_1d(az)
    return np.column_stack([np.cos(az) * math.cos(HALF), np.sin(az) * math.cos(HALF), np.full(len(az), -math.sin(HALF))])


def _cone_distance(p: np.ndarray) -> np.ndarray:
    r, z = np.hypot(p[:, 0], p[:, 1]), p[:, 2]
    return np.abs(r * math.cos(HALF) - z * math.sin(HALF))


def _fan(k: int, per_element: bool) -> NagataMesh:
    """Apex node 0 and a ring of k nodes at slant length 1, k triangles (apex, i + 1, i) wound
    with the outward normal; at the apex the axis -z (one normal) or each element's limit
    along its bisecting generatrix (corner normals)."""
    az = 2 * math.pi * np.arange(k) / k
    ring = np.column_stack([math.sin(HALF) * np.cos(az), math.sin(HALF) * np.sin(az), np.full(k, math.cos(HALF))])
    nodes = np.vstack([[0.0, 0.0, 0.0], ring])
    tri = np.array([[0, 1 + (i + 1) % k, 1 + i] for i in range(k)])
    cn = np.empty((k, 3, 3))
    cn[:, 1] = _cone_normal(az[(np.arange(k) + 1) % k])
    cn[:, 2] = _cone_normal(az)
    cn[:, 0] = _cone_normal(az + math.pi / k) if per_element else np.array([0.0, 0.0, -1.0])
    return NagataMesh(nodes, [tri], [cn])


def _samples(k: int, n: int = 10):
    g = np.linspace(0.0, 1.0, n + 1)
    eta, zeta = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    keep = zeta <= eta
    m = int(keep.sum())
    return np.repeat(np.arange(k), m), np.tile(eta[keep], k), np.tile(zeta[keep], k)


@pytest.mark.parametrize("k", [5, 6, 12])
def test_axis_normal_makes_each_patch_the_cone_over_its_ring_edge(k: int) -> None:
    nm = _fan(k, per_element=False)
    elem, eta, zeta = _samples(k)
    x, _ = nm.evaluate(elem, eta, zeta)
    for s in (0.5, 0.1):  # homogeneous of degree 2 about the apex
        xs, _ = nm.evaluate(elem, s * eta, s * zeta)
        assert np.abs(xs - s * s * x).max() < 1e-14
    # so no sample is farther from the cone than the ring edges (eta = 1) are
    edge, _ = nm.evaluate(np.repeat(np.arange(k), 201), np.ones(201 * k), np.tile(np.linspace(0, 1, 201), k))
    assert _cone_distance(x).max() <= _cone_distance(edge).max() * (1 + 1e-9) + 1e-15
    # the generatrix edges themselves lie on the cone (straight)
    g, _ = nm.evaluate(np.repeat(np.arange(k), 11), np.tile(np.linspace(0, 1, 11), k), np.zeros(11 * k))
    assert _cone_distance(g).max() < 1e-15


@pytest.mark.parametrize("k", [6, 12])
def test_per_element_apex_normals_bend_the_generatrices(k: int) -> None:
    elem, eta, zeta = _samples(k)
    common = _cone_distance(_fan(k, per_element=False).evaluate(elem, eta, zeta)[0]).max()
    own = _cone_distance(_fan(k, per_element=True).evaluate(elem, eta, zeta)[0]).max()
    assert own > 2.0 * common


@pytest.mark.parametrize("k", [5, 6, 12])
def test_patch_normal_at_the_apex_is_its_limit(k: int) -> None:
    """At the apex both tangents vanish (to round-off); the normal is the patch's along the
    ray to its centroid: the cone normal over that ray, the same as a little way along it."""
    nm = _fan(k, per_element=False)
    e = np.arange(k)
    _, at = nm.evaluate(e, np.zeros(k), np.zeros(k))
    _, near = nm.evaluate(e, np.full(k, 2e-3 / 3), np.full(k, 1e-3 / 3))
    assert np.all(np.isfinite(at))
    assert np.abs(at - near).max() < 1e-7  # (the limit is taken 1e-7 along that ray)
    mid = nm.evaluate(e, np.full(k, 2 / 3), np.full(k, 1 / 3))[0]
    ref = _cone_normal(np.arctan2(mid[:, 1], mid[:, 0]))
    assert np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", at, ref), -1, 1))).max() < 1.0 + 30.0 / k
