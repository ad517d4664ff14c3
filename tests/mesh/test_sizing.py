"""Curvatures of NURBS surfaces and the Nagata sizing law (issue 12).

References: closed-form curvatures of the cylinder, sphere and torus; Euler's formula for the
normal curvature; the thesis' Fig. 8 number (0.060 % radial error at normalized edge length
0.52); a Nagata edge on an analytic circle (exact normals) for the h^4 law.
"""

import numpy as np
import pytest

from cadbridge.mesh.sizing import (
    NAGATA_ERROR_CONSTANT,
    SizeField,
    arc_error,
    curvature_samples,
    edge_length_for_tolerance,
)
from cadbridge.nagata.edge import edge_coefficient
from cadbridge.nurbs.construct import cylinder_patch, sphere_patch, torus_patch
from cadbridge.nurbs.curvature import normal_curvature, principal_curvatures


def test_cylinder_curvatures_and_directions():
    """Cylinder R 5: k = 1/R around, 0 along the axis; the principal directions are the
    circle's tangent and the axis (closed form)."""
    s = cylinder_patch(5.0, 10.0, np.pi / 2)
    u = np.linspace(*s.domain[:2], 7)
    v = np.linspace(*s.domain[2:], 7)
    k1, k2, d1, d2 = principal_curvatures(s, u, v, directions=True)
    assert np.allclose(np.abs(k1 + k2), 0.2, atol=1e-12)  # one is +-1/R, the other 0
    assert np.allclose(np.minimum(np.abs(k1), np.abs(k2)), 0.0, atol=1e-12)
    x = s.evaluate(u, v)
    # the direction of the non-zero curvature is horizontal-tangent, the other along the axis (z)
    curved = np.where((np.abs(k1) > np.abs(k2))[:, None], d1, d2)
    straight = np.where((np.abs(k1) > np.abs(k2))[:, None], d2, d1)
    assert np.allclose(np.abs(straight[:, 2]), 1.0, atol=1e-12)
    radial = x[:, :2] / np.linalg.norm(x[:, :2], axis=1, keepdims=True)
    assert np.allclose(np.einsum("ij,ij->i", curved[:, :2], radial), 0.0, atol=1e-12)


def test_sphere_is_umbilic():
    s = sphere_patch(10.0, (0.1, 1.0), (0.0, 1.5))
    u = np.linspace(*s.domain[:2], 9)
    v = np.linspace(*s.domain[2:], 9)
    k1, k2 = principal_curvatures(s, u, v)
    assert np.allclose(np.abs(k1), 0.1, atol=1e-12) and np.allclose(k1, k2, atol=1e-12)


def test_torus_curvatures_closed_form():
    """Torus R 20, r 5: k_tube = 1/r, k_sweep = cos(phi) / (R + r cos(phi)), phi the tube
    angle (distance of the point from the axis is R + r cos(phi))."""
    R, r = 20.0, 5.0
    s = torus_patch(R, r, (0.0, np.pi), (0.0, 1.5))
    rng = np.random.default_rng(1)
    u = rng.uniform(*s.domain[:2], 50)
    v = rng.uniform(*s.domain[2:], 50)
    x = s.evaluate(u, v)
    rho = np.linalg.norm(x[:, :2], axis=1)  # R + r cos(phi)
    cos_phi = (rho - R) / r
    k1, k2 = principal_curvatures(s, u, v)
    a = np.sort(np.abs(np.column_stack([k1, k2])), axis=1)
    want = np.sort(np.abs(np.column_stack([np.full_like(rho, 1 / r), cos_phi / rho])), axis=1)
    assert np.allclose(a, want, atol=1e-12)


def test_euler_formula_for_normal_curvature():
    """k_n(theta) = k1 cos^2 + k2 sin^2 about the principal direction d1 (Euler)."""
    s = torus_patch(20.0, 5.0, (0.3, 2.0), (0.0, 1.5))
    u = np.full(12, 0.9)
    v = np.full(12, 0.7)
    k1, k2, d1, d2 = principal_curvatures(s, u, v, directions=True)
    der = s.derivatives(u[:1], v[:1], order=1)
    su, sv = der[0, 1, 0], der[0, 0, 1]
    th = np.linspace(0, np.pi, 12)
    t3 = np.cos(th)[:, None] * d1 + np.sin(th)[:, None] * d2  # tangent directions
    # parameter direction of each tangent: solve [su sv] (du, dv) = t3
    J = np.column_stack([su, sv])
    duv = np.linalg.lstsq(J, t3.T, rcond=None)[0].T
    kn = normal_curvature(s, u, v, duv[:, 0], duv[:, 1])
    assert np.allclose(kn, k1 * np.cos(th) ** 2 + k2 * np.sin(th) ** 2, atol=1e-12)


def test_law_constant_is_thesis_fig8():
    """0.060 % radial error at normalized edge length 0.52 (thesis Fig. 8, U-shape §5.2)."""
    assert arc_error(0.52, 1.0) == pytest.approx(6.0e-4, rel=1e-12)
    assert NAGATA_ERROR_CONSTANT == pytest.approx(8.2e-3, rel=1e-2)
    h = edge_length_for_tolerance(0.002, np.array([0.2, 0.0]), h_max=50.0)
    assert arc_error(h[0], 5.0) == pytest.approx(0.002, rel=1e-12)
    assert h[1] == 50.0  # a plane gets the largest size


@pytest.mark.parametrize("ratio", [0.52, 0.26, 0.13])
def test_law_predicts_nagata_edge_on_circle(ratio):
    """The max radial error of a Nagata edge (exact normals) on a circle of radius R with
    chord h = ratio R follows C h^4 / R^3 (the law is fitted at 0.52: within 1 % there, and
    the quartic holds to a few % below)."""
    R = 5.0
    half = np.arcsin(ratio / 2)
    a0, a1 = -half, half
    x0, x1 = R * np.array([np.cos(a0), np.sin(a0), 0]), R * np.array([np.cos(a1), np.sin(a1), 0])
    n0, n1 = x0 / R, x1 / R
    c = edge_coefficient(x0, x1, n0, n1)
    xi = np.linspace(0, 1, 2001)[:, None]
    pts = x0 + (x1 - x0 - c) * xi + c * xi ** 2
    err = np.abs(np.linalg.norm(pts, axis=1) - R).max()
    assert err == pytest.approx(arc_error(ratio * R, R), rel=0.05)


def test_size_field_grading_and_floor():
    pts = np.array([[0.0, 0, 0], [10.0, 0, 0]])
    f = SizeField(pts, [1.0, 4.0], h_min=0.5, h_max=8.0, gradation=0.5)
    x = np.array([[0.0, 0, 0], [2.0, 0, 0], [10.0, 0, 0], [100.0, 0, 0]])
    h = f(x)
    assert np.allclose(h, [1.0, 2.0, 4.0, 8.0])  # min_i (h_i + g d_i), capped at h_max
    f.add([[2.0, 0, 0]], [0.1])
    assert f(x[1:2])[0] == 0.5  # the floor
    cb = f.gmsh_callback()
    # the cached lattice value is never above the field anywhere in its cell
    rng = np.random.default_rng(3)
    y = rng.uniform(-3, 13, (200, 3))
    got = np.array([cb(2, 1, *p, 1e9) for p in y])
    assert np.all(got <= f(y) + 1e-12)


@pytest.mark.parametrize("levels", [64, 6])
def test_size_field_is_the_graded_minimum(levels):
    """`SizeField.__call__` (nearest sample per size level, each level querying only the
    points it can still lower, within the distance where it can) against the formula by brute
    force: min_i (h_i + g |x - x_i|) over every sample, clipped to [h_min, h_max]. Samples of
    sizes over four decades, query points inside and far outside their box. With
    ``max_levels`` 6 the sizes are first rounded down to levels (`LEVEL_RATIO` apart); the
    reference then takes the same rounded sizes."""
    rng = np.random.default_rng(11)
    pts = rng.uniform(0.0, 10.0, (400, 3))
    sizes = 10.0 ** rng.uniform(-3.0, 1.0, 400)
    f = SizeField(pts, sizes, h_min=2e-3, h_max=5.0, gradation=0.3)
    f.max_levels = levels
    x = np.vstack([rng.uniform(-5.0, 15.0, (3000, 3)), pts[:50]])
    h = np.maximum(sizes, f.h_min)
    if len(np.unique(h[h < f.h_max])) > levels:
        h = f.h_min * f.LEVEL_RATIO ** np.floor(np.log(h / f.h_min) / np.log(f.LEVEL_RATIO) + 1e-9)
    d = np.linalg.norm(x[:, None, :] - pts[None, :, :], axis=2)
    ref = np.clip(np.min(np.where(sizes < f.h_max, h, np.inf)[None, :] + 0.3 * d, axis=1), f.h_min, f.h_max)
    np.testing.assert_allclose(f(x), ref, rtol=1e-14, atol=0)


def test_curvature_samples_ushape_die():
    """The die's only curved face is the R5 shoulder: k_max = 1/5 there, 0 on the planes."""
    from pathlib import Path

    from cadbridge.iges import read_iges

    m = read_iges(Path(__file__).parents[2] / "iges_samples" / "ushape_die_nurbs.igs")
    _, k, face = curvature_samples(m)
    for f in np.unique(face):
        kf = k[face == f]
        assert np.allclose(kf, 0.2, atol=1e-9) or np.allclose(kf, 0.0, atol=1e-9)
    assert np.isclose(k.max(), 0.2, atol=1e-9)


def test_background_points_follow_the_field():
    """`SizeField.background` feeds gmsh a nearest-point size field. Reference: the exact
    graded field `SizeField.__call__`, which is g-Lipschitz (a min of h_i + g d_i), so a
    carrier's size (never above the field at the carrier) exceeds the field at a query
    point by at most g times its distance to the carrier; at a refinement mark the carrier
    holds the mark's size, and carriers between a mark and a coarser sample get the smaller
    size halfway to it."""
    from scipy.spatial import cKDTree

    s = cylinder_patch(5.0, 40.0, np.pi / 2)
    uu, vv = np.meshgrid(np.linspace(*s.domain[:2], 9), np.linspace(*s.domain[2:], 9), indexing="ij")
    pts = s.evaluate(uu.ravel(), vv.ravel())
    f = SizeField(pts, np.full(len(pts), 3.0), h_min=0.05, h_max=20.0, gradation=0.5)
    mark = pts[40] + 0.1
    f.add(mark[None], [0.2])
    u2, v2 = np.meshgrid(np.linspace(*s.domain[:2], 30), np.linspace(*s.domain[2:], 60), indexing="ij")
    bp, bh = f.background(s.evaluate(u2.ravel(), v2.ravel()))  # extra carriers, like a previous mesh's nodes
    assert np.all(bh <= f(bp) + 1e-12) and np.all((bh >= f.h_min) & (bh <= f.h_max))
    assert bh[np.argmin(np.linalg.norm(bp - mark, axis=1))] == pytest.approx(0.2)
    rng = np.random.default_rng(5)
    q = s.evaluate(rng.uniform(*s.domain[:2], 4000), rng.uniform(*s.domain[2:], 4000))
    d, i = cKDTree(bp).query(q)
    assert np.all(bh[i] <= f(q) + f.g * d + 1e-12)
    # without the halfway rule a carrier next to the mark would keep its own, larger size
    near = np.linalg.norm(bp - mark, axis=1) < 1.0
    assert np.all(bh[near] < 3.0)
