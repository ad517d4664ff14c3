"""Tests of cadbridge.nurbs.construct: exact NURBS of lines, arcs, conics, composites,
planes, ruled / revolved / tabulated surfaces and the analytic patches.

References: analytic geometry (circle, conics, plane, cylinder, cone, sphere, torus and
their normals), exact rotation of the generatrix, and OpenCASCADE (Geom_Circle,
Geom_SurfaceOfRevolution) evaluated at the same angle.
"""

from __future__ import annotations

from math import pi

import numpy as np
import pytest

from cadbridge.nurbs import NurbsCurve, edits
from cadbridge.nurbs import construct as K


def rot(axis, ang):
    """Rotation matrices (N, 3, 3) about unit ``axis`` by angles ``ang`` (N,) (Rodrigues)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    Kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    ang = np.atleast_1d(ang)[:, None, None]
    return np.eye(3) + np.sin(ang) * Kx + (1 - np.cos(ang)) * (Kx @ Kx)


def angle_between(n, m):
    return np.arctan2(np.linalg.norm(np.cross(n, m), axis=1), np.sum(n * m, axis=1))


def frame(normal):
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    x = np.cross(n, [0.3, 0.5, 0.7])
    x /= np.linalg.norm(x)
    return x, np.cross(n, x), n


# ---------------------------------------------------------------------------- curves
def test_line():
    """Reference: C(t) = p0 + t (p1 - p0) exactly, degree 1, domain [0, 1], 2D and 3D."""
    c = K.line((1, 2, 3), (4, 6, 8))
    t = np.linspace(0, 1, 11)
    np.testing.assert_allclose(c(t), np.array([1, 2, 3]) + t[:, None] * [3, 4, 5], atol=1e-15)
    assert c.degree == 1 and c.domain == (0, 1) and K.line((0, 0), (1, 1)).dim == 2


SWEEPS = [0.3, pi / 2, pi / 2 + 1e-9, 2.0, pi, 3.5, 3 * pi / 2, 5.5, 2 * pi - 1e-6, 2 * pi]


@pytest.mark.parametrize("sweep", SWEEPS)
@pytest.mark.parametrize("normal", [(0, 0, 1), (1, -2, 0.5)])
def test_circular_arc(sweep, normal):
    """Reference: the analytic circle: every point at radius R to 1e-14 R, in the plane,
    starts/ends where asked, runs counter-clockwise about the normal, <= 90deg per segment,
    domain [0, sweep]; the parameter-to-angle map arc_angle is exact (1e-13)."""
    R = 3.7
    c0 = np.array([0.4, -1.2, 2.0])
    ex, ey, n = frame(normal)
    start = c0 + R * ex
    end = c0 + R * (np.cos(sweep) * ex + np.sin(sweep) * ey) * 1.000001  # |end - c| differs slightly
    if sweep == 2 * pi:
        end = start.copy()
    c = K.circular_arc(c0, start, end, normal)
    assert c.degree == 2 and len(np.unique(c.knots)) - 1 == int(np.ceil(sweep / (pi / 2) * (1 - 1e-12)))
    assert c.domain[0] == 0 and abs(c.domain[1] - sweep) < 1e-12
    t = np.linspace(*c.domain, 1001)
    P = c(t) - c0
    assert np.abs(np.linalg.norm(P, axis=1) - R).max() < 1e-14 * R * 4
    assert np.abs(P @ n).max() < 1e-14 * R * 4
    np.testing.assert_allclose(P[0], R * ex, atol=1e-14 * R)
    np.testing.assert_allclose(P[-1], R * (np.cos(sweep) * ex + np.sin(sweep) * ey), atol=1e-13 * R)
    ang = np.unwrap(np.arctan2(P @ ey, P @ ex))
    assert np.all(np.diff(ang) > 0)  # counter-clockwise
    assert np.abs(K.arc_angle(t, c.domain[1]) - ang).max() < 1e-13
    assert np.abs(K.arc_parameter(ang, c.domain[1]) - t).max() < 1e-12


def test_circular_arc_vs_occ_circle():
    """Reference: OpenCASCADE Geom_Circle (parametrised by angle) evaluated at the angle
    arc_angle(t) gives our point C(t) to 1e-14 R."""
    from OCP.Geom import Geom_Circle
    from OCP.gp import gp_Ax2, gp_Dir, gp_Pnt

    R, sweep = 2.0, 4.0
    c0 = np.array([1.0, 2.0, -1.0])
    ex, ey, n = frame((0.2, 1.0, -0.3))
    arc = K.circular_arc(c0, c0 + R * ex, c0 + R * (np.cos(sweep) * ex + np.sin(sweep) * ey), n)
    circ = Geom_Circle(gp_Ax2(gp_Pnt(*c0), gp_Dir(*n), gp_Dir(*ex)), R)
    t = np.linspace(0, sweep, 77)
    ours = arc(t)
    for ti, a, p in zip(t, K.arc_angle(t, sweep), ours):
        q = circ.Value(float(a))
        assert np.linalg.norm(p - [q.X(), q.Y(), q.Z()]) < 1e-14 * R * 4


def test_circular_arc_2d():
    """Reference: the analytic circle in 2D (trim-curve use): radius and end points."""
    c = K.circular_arc((1.0, 1.0), (2.0, 1.0), (1.0, 0.0))  # 270deg counter-clockwise
    assert c.dim == 2 and abs(c.domain[1] - 1.5 * pi) < 1e-14
    P = c(np.linspace(*c.domain, 200)) - 1.0
    assert np.abs(np.linalg.norm(P, axis=1) - 1).max() < 1e-14
    np.testing.assert_allclose(c(np.array([c.domain[1]]))[0], [1.0, 0.0], atol=1e-15)


def test_circular_arc_rejects_off_plane_start():
    """Reference: IGES 100 consistency: start - center must be perpendicular to the normal."""
    with pytest.raises(ValueError):
        K.circular_arc((0, 0, 0), (1, 0, 0.1), (0, 1, 0))


# ---------------------------------------------------------------------------- conics
def _conic_value(coef, P):
    A, B, C, D, E, F = coef
    x, y = P[:, 0], P[:, 1]
    return A * x * x + B * x * y + C * y * y + D * x + E * y + F


def test_conic_ellipse_general_position():
    """Reference: the implicit equation of a rotated, shifted ellipse (residual 1e-13
    relative), the end points, counter-clockwise sense, z = zt; and the full ellipse."""
    a, b, th, cx, cy = 3.0, 1.2, 0.4, 0.5, -1.0
    c, s = np.cos(th), np.sin(th)
    # (x', y') = R^T (x - c);  x'^2/a^2 + y'^2/b^2 = 1
    Q = np.array([[c, -s], [s, c]]) @ np.diag([1 / a**2, 1 / b**2]) @ np.array([[c, s], [-s, c]])
    ctr = np.array([cx, cy])
    coef = (Q[0, 0], 2 * Q[0, 1], Q[1, 1], *(-2 * Q @ ctr), ctr @ Q @ ctr - 1)
    pt = lambda t: ctr + np.array([[c, -s], [s, c]]) @ [a * np.cos(t), b * np.sin(t)]  # noqa: E731
    for t0, t1 in [(0.2, 1.0), (0.2, 4.0), (5.0, 0.5), (1.0, 1.0)]:
        arc = K.conic_arc(*coef, 2.5, pt(t0), pt(t1))
        P = arc(np.linspace(*arc.domain, 500))
        assert np.abs(_conic_value(coef, P)).max() < 1e-13
        assert np.abs(P[:, 2] - 2.5).max() < 1e-15 * 2.5 * 2
        np.testing.assert_allclose(P[0, :2], pt(t0), atol=1e-14)
        np.testing.assert_allclose(P[-1, :2], pt(t1), atol=1e-13)
        d = P[:, :2] - ctr
        ang = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        assert np.all(np.diff(ang) > 0)
        if t0 == t1:
            assert abs(arc.domain[1] - 2 * pi) < 1e-12


def test_conic_large_ellipse_standard_position():
    """Reference: x^2/a^2 + y^2/b^2 = 1 with a = 2e4, b = 5e3 (tiny coefficients, as in
    IGES files in mm): classified as an ellipse, on the conic to 1e-13 relative."""
    a, b = 2.0e4, 5.0e3
    coef = (1 / a**2, 0.0, 1 / b**2, 0.0, 0.0, -1.0)
    arc = K.conic_arc(*coef, 0.0, (a, 0.0, 0.0), (0.0, -b, 0.0))  # 270deg counter-clockwise
    assert abs(arc.domain[1] - 1.5 * pi) < 1e-12
    P = arc(np.linspace(*arc.domain, 400))
    assert np.abs(_conic_value(coef, P)).max() < 1e-13


def test_conic_hyperbola_and_parabola():
    """Reference: implicit equations x^2 - y^2 = 1 (middle weight cosh(half the hyperbolic
    sweep), P&T 7.5) and y = x^2/4 shifted; end points exact."""
    h = K.conic_arc(1, 0, -1, 0, 0, -1, 0.0, (np.cosh(-1.0), np.sinh(-1.0)), (np.cosh(2.0), np.sinh(2.0)))
    P = h(np.linspace(0, 1, 300))
    assert np.abs(P[:, 0] ** 2 - P[:, 1] ** 2 - 1).max() < 1e-13 * 16
    assert abs(h.weights[1] - np.cosh(1.5)) < 1e-13
    np.testing.assert_allclose(P[[0, -1], :2], [[np.cosh(-1.0), np.sinh(-1.0)], [np.cosh(2.0), np.sinh(2.0)]], atol=1e-14)
    coef = (0.25, 0, 0, -0.5, -1, 1.25)  # y = (x - 1)^2 / 4 + 1
    p = K.conic_arc(*coef, -1.0, (-3.0, 5.0), (4.0, 3.25))
    P = p(np.linspace(0, 1, 300))
    assert np.abs(_conic_value(coef, P)).max() < 1e-13 * 8
    assert not p.rational


# ---------------------------------------------------------------------------- composite
def test_composite_curve():
    """Reference: a line + quarter circle + cubic piece: each piece reproduced exactly over
    its own shifted parameter range, degree raised to 3, joins are knots of multiplicity 3;
    a gap raises ValueError."""
    rng = np.random.default_rng(0)
    l = K.line((0, 0, 0), (1, 0, 0))
    a = K.circular_arc((1, 1, 0), (1, 0, 0), (2, 1, 0))
    cub_pts = np.vstack([[2, 1, 0], rng.uniform(0, 3, (4, 3))])
    cub = NurbsCurve(3, [0, 0, 0, 0, 0.5, 2, 2, 2, 2], cub_pts, domain=(0.0, 1.5))  # sub-domain
    comp = K.composite_curve([l, a, cub])
    L = [1.0, pi / 2, 1.5]
    assert comp.degree == 3 and comp.domain == (0.0, pytest.approx(sum(L)))
    assert np.count_nonzero(comp.knots == 1.0) == 3
    s = np.linspace(0, 1, 101)
    assert np.abs(comp(s * L[0]) - l(s)).max() < 1e-14
    assert np.abs(comp(L[0] + s * L[1]) - a(s * L[1])).max() < 1e-14
    assert np.abs(comp(L[0] + L[1] + s * L[2]) - cub(s * 1.5)).max() < 1e-13
    with pytest.raises(ValueError):
        K.composite_curve([l, K.line((1, 1e-6, 0), (2, 0, 0))])


# ---------------------------------------------------------------------------- surfaces
def test_plane_surface():
    """Reference: S(u, v) = point + u e_u + v e_v exactly, normal = +n, given domain."""
    n = np.array([1.0, 2.0, 2.0]) / 3
    s = K.plane_surface((1, 2, 3), n, (1, 0, 0), (-1, 2), (0.5, 3))
    assert s.domain == (-1, 2, 0.5, 3)
    eu = np.array([1.0, 0, 0]) - n[0] * n
    eu /= np.linalg.norm(eu)
    ev = np.cross(n, eu)
    u, v = s.grid(7, 9)
    np.testing.assert_allclose(s(u, v), np.array([1, 2, 3]) + u[:, None] * eu + v[:, None] * ev, atol=1e-14)
    np.testing.assert_allclose(s.normal(u, v), np.tile(n, (len(u), 1)), atol=1e-14)


def test_ruled_surface():
    """Reference: polynomial curves of different degree/knots: S(u, v) = (1 - v) c1(u') +
    v c2(u'') with u', u'' the affine maps of [0, 1] onto their domains (1e-13); with a
    rational c2 every point lies on the segment c1(u)-c2(u); reverse_second flips c2."""
    rng = np.random.default_rng(3)
    c1 = NurbsCurve(2, [0, 0, 0, 0.5, 1, 1, 1], rng.uniform(0, 1, (4, 3)))
    c2 = NurbsCurve(3, [2, 2, 2, 2, 3, 3, 3, 3], rng.uniform(0, 1, (4, 3)) + [0, 0, 2])
    s = K.ruled_surface(c1, c2)
    assert s.domain == (0, 1, 0, 1) and s.degree_v == 1
    u, v = s.grid(21, 11)
    ref = (1 - v)[:, None] * c1(u) + v[:, None] * c2(2 + u)
    assert np.abs(s(u, v) - ref).max() < 1e-13
    sr = K.ruled_surface(c1, c2, reverse_second=True)
    assert np.abs(sr(u, np.ones_like(u)) - c2(3 - u)).max() < 1e-13
    c3 = K.circular_arc((0, 0, 2), (1, 0, 2), (0, 1, 2))
    s3 = K.ruled_surface(c1, c3)
    P = s3(u, v)
    A, B = c1(u), c3(u * pi / 2)
    np.testing.assert_allclose(s3(u, np.zeros_like(u)), A, atol=1e-14)
    np.testing.assert_allclose(s3(u, np.ones_like(u)), B, atol=1e-14)
    d = np.linalg.norm(np.cross(P - A, B - A), axis=1) / np.linalg.norm(B - A, axis=1)
    assert d.max() < 1e-13


def test_tabulated_cylinder():
    """Reference: S(u, v) = C(u) + v * vector exactly for a rational directrix with a
    sub-domain."""
    c = K.circular_arc((0, 0, 0), (1, 0, 0), (-1, 0.5, 0))
    c = NurbsCurve(c.degree, c.knots, c.control_points, c.weights, (0.2, c.domain[1] - 0.1))
    vec = np.array([0.3, -0.2, 4.0])
    s = K.tabulated_cylinder(c, vec)
    assert s.domain[:2] == pytest.approx(c.domain) and s.domain[2:] == (0, 1)
    u, v = s.grid(31, 7)
    assert np.abs(s(u, v) - (c(u) + v[:, None] * vec)).max() < 1e-14


def _check_revolution(s, gen, o, a, a0):
    """S(u, v) == rotation by a0 + arc_angle(v) of gen(u) about (o, a), 1e-12 x size."""
    u, v = s.grid(41, 37)
    ang = a0 + K.arc_angle(v, s.domain[3] - s.domain[2], s.domain[2])
    ref = np.einsum("nij,nj->ni", rot(a, ang), gen(u) - o) + o
    size = np.linalg.norm(np.ptp(ref, axis=0))
    assert np.abs(s(u, v) - ref).max() < 1e-12 * size


def test_revolved_random_rational_generatrix_general_axis():
    """Reference: exact rotation (Rodrigues) of a random rational cubic generatrix about an
    oblique axis through an arbitrary point, for several angle ranges incl. > 180deg."""
    rng = np.random.default_rng(5)
    gen = NurbsCurve(3, [0, 0, 0, 0, 0.3, 0.7, 1, 1, 1, 1], rng.uniform(-2, 2, (6, 3)), rng.uniform(0.5, 2, 6))
    o, a = np.array([0.3, -0.5, 1.0]), np.array([0.2, 1.0, -0.4])
    for a0, a1 in [(0.0, 2 * pi), (0.3, 1.0), (-1.0, 3.0), (1.0, 1.0 + 3 * pi / 2)]:
        s = K.revolved_surface(gen, o, a, a0, a1)
        assert s.domain[2:] == (a0, a1)
        _check_revolution(s, gen, o, a, a0)
        th = np.linspace(a0, a1, 50)
        v = K.revolved_angle_to_v(th, a0, a1)
        assert np.abs(K.revolved_v_to_angle(v, a0, a1) - th).max() < 1e-13
        uu = np.full_like(v, 0.37)
        ref = np.einsum("nij,nj->ni", rot(a, th), gen(uu) - o) + o
        assert np.abs(s(uu, v) - ref).max() < 1e-12 * 4


def test_revolve_line_cylinder_and_cone():
    """Reference: analytic cylinder and cone: points on the surface to 1e-12 x size and
    normals equal to the analytic normals (sign: Su x Sv) to 1e-12 rad."""
    R, H = 2.0, 3.0
    s = K.cylinder_patch(R, H, 2 * pi)
    u, v = s.grid(25, 41)
    P = s(u, v)
    assert np.abs(np.hypot(P[:, 0], P[:, 1]) - R).max() < 1e-12 * R
    np.testing.assert_allclose(P[:, 2], u, atol=1e-14 * H)
    n = s.normal(u, v)
    ref = -np.column_stack([P[:, 0], P[:, 1], 0 * u]) / R  # towards the axis
    assert angle_between(n, ref).max() < 1e-12
    r0, r1, h = 1.0, 2.5, 2.0
    c = K.cone_patch(r0, r1, h, 4.0)
    u, v = c.grid(25, 41)
    P = c(u, v)
    rho = np.hypot(P[:, 0], P[:, 1])
    assert np.abs(rho - (r0 + (r1 - r0) * P[:, 2] / h)).max() < 1e-12 * r1
    phi = np.arctan2(P[:, 1], P[:, 0])
    ref = np.column_stack([-h * np.cos(phi), -h * np.sin(phi), np.full_like(phi, r1 - r0)])
    ref /= np.linalg.norm(ref, axis=1)[:, None]
    assert angle_between(c.normal(u, v), ref).max() < 1e-12


@pytest.mark.parametrize("lat, lon", [((-pi / 2, pi / 2), (0, 2 * pi)), ((-0.3, 1.2), (0.5, 2.5)), ((0.0, pi / 2), (-1.0, 4.0))])
def test_sphere_patch(lat, lon):
    """Reference: the analytic sphere |P| = R (1e-12 R), latitudes and longitudes within
    the ranges, normals = -P/R (towards the centre) to 1e-12 rad, poles included."""
    R = 1.7
    s = K.sphere_patch(R, lat, lon)
    u, v = s.grid(31, 33)
    P = s(u, v)
    assert np.abs(np.linalg.norm(P, axis=1) - R).max() < 1e-12 * R
    la = np.arcsin(np.clip(P[:, 2] / R, -1, 1))
    assert la.min() > lat[0] - 1e-9 and la.max() < lat[1] + 1e-9
    np.testing.assert_allclose(la, lat[0] + K.arc_angle(u, lat[1] - lat[0]), atol=1e-7)
    n = s.normal(u, v)
    assert angle_between(n, -P / R).max() < 1e-12


def test_torus_patch():
    """Reference: the analytic torus (rho - R)^2 + z^2 = r^2 (1e-12 x size) and its normal
    -(P - C)/r, C the tube centre, to 1e-12 rad; full and partial ranges."""
    R, r = 3.0, 0.8
    for tube, sweep in [((0, 2 * pi), (0, 2 * pi)), ((-1.0, 2.0), (0.3, 1.9))]:
        s = K.torus_patch(R, r, tube, sweep)
        u, v = s.grid(33, 35)
        P = s(u, v)
        rho = np.hypot(P[:, 0], P[:, 1])
        assert np.abs(np.hypot(rho - R, P[:, 2]) - r).max() < 1e-12 * (R + r)
        C = np.column_stack([R * P[:, 0] / rho, R * P[:, 1] / rho, 0 * rho])
        assert angle_between(s.normal(u, v), -(P - C) / r).max() < 1e-12


def test_revolved_vs_occ_surface_of_revolution():
    """Reference: OpenCASCADE Geom_SurfaceOfRevolution of the same B-spline generatrix (its
    U is the angle, V the curve parameter): our S(u, v) equals OCC Value(angle(v), u) to
    1e-12 x size, and OCC's points project onto ours at distance < 1e-12 x size."""
    from OCP.Geom import Geom_SurfaceOfRevolution
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Ax1, gp_Dir, gp_Pnt

    from tests.nurbs.test_engine import occ_curve, occ_surface

    rng = np.random.default_rng(8)
    gen = NurbsCurve(2, [0, 0, 0, 0.5, 1, 1, 1], rng.uniform(0.5, 2, (4, 3)), rng.uniform(0.5, 2, 4))
    o, a = np.array([0.0, 0.1, -0.2]), np.array([0.1, 0.2, 1.0])
    a0, a1 = 0.2, 4.0
    s = K.revolved_surface(gen, o, a, a0, a1)
    rev = Geom_SurfaceOfRevolution(occ_curve(gen), gp_Ax1(gp_Pnt(*o), gp_Dir(*a)))
    u, v = s.grid(13, 17)
    ours = s(u, v)
    size = np.linalg.norm(np.ptp(ours, axis=0))
    ang = a0 + K.arc_angle(v, a1 - a0, a0)
    for p, ui, ai in zip(ours, u, ang):
        q = rev.Value(float(ai), float(ui))
        assert np.linalg.norm(p - [q.X(), q.Y(), q.Z()]) < 1e-12 * size
    ours_occ = occ_surface(s)
    for ui, ai in zip(u[::7], np.linspace(a0, a1, len(u[::7]))):
        q = rev.Value(float(ai), float(ui))
        proj = GeomAPI_ProjectPointOnSurf(q, ours_occ)
        assert proj.LowerDistance() < 1e-9 * size  # OCC's projector tolerance


def test_revolved_surface_rejects_bad_input():
    """Reference: argument validation (2D generatrix, empty or > 2 pi sweep)."""
    with pytest.raises(ValueError):
        K.revolved_surface(K.line((1, 0), (1, 1)), (0, 0, 0), (0, 0, 1), 0, 1)
    with pytest.raises(ValueError):
        K.revolved_surface(K.line((1, 0, 0), (1, 0, 1)), (0, 0, 0), (0, 0, 1), 1, 1)
    with pytest.raises(ValueError):
        K.revolved_surface(K.line((1, 0, 0), (1, 0, 1)), (0, 0, 0), (0, 0, 1), 0, 7)


def test_tight_bbox_of_revolved_sub_domain():
    """Reference: for a full cylinder restricted to a quarter in v, tight_bbox contains the
    dense samples and is much smaller than the control-net box."""
    s = K.cylinder_patch(1.0, 1.0, 2 * pi).with_domain((0.0, 1.0, 0.0, pi / 2))
    tb = edits.tight_bbox(s)
    u, v = s.grid(50, 50)
    P = s(u, v)
    assert np.all(P >= tb[0] - 1e-12) and np.all(P <= tb[1] + 1e-12)
    np.testing.assert_allclose(tb, [[0, 0, 0], [1, 1, 1]], atol=1e-14)
