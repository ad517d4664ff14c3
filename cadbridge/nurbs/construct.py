"""Exact NURBS constructions of lines, circular and conic arcs and of the analytic surfaces
of IGES (plane, ruled 118, revolution 120, tabulated cylinder 122), P&T ch. 7-8.

Parametrisation of circular arcs (used by ``circular_arc`` and in v by
``revolved_surface``): a sweep theta is split into n = ceil(theta / 90deg) equal rational
quadratic segments (P&T A7.1) with knots at k * theta / n, so the parameter equals the
angle at segment ends (and the domain is [0, theta]) but not in between; inside a segment of
sweep phi starting at angle a_k the exact relation is

    angle = a_k + phi/2 + 2 atan((2 s - 1) tan(phi/4)),   s = (t - t_k) / (t_{k+1} - t_k),

computed by :func:`arc_angle` and inverted by :func:`arc_parameter` (|angle - t| stays
below 0.0161 rad for 90deg segments).
"""

from __future__ import annotations

from math import ceil, pi
from typing import Sequence

import numpy as np

from cadbridge.nurbs import edits
from cadbridge.nurbs.knots import reparametrize
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface

__all__ = [
    "line",
    "circular_arc",
    "arc_segments",
    "arc_angle",
    "arc_parameter",
    "revolved_angle_to_v",
    "revolved_v_to_angle",
    "conic_arc",
    "composite_curve",
    "plane_surface",
    "ruled_surface",
    "revolved_surface",
    "tabulated_cylinder",
    "cylinder_patch",
    "cone_patch",
    "sphere_patch",
    "torus_patch",
]

_ANGLE_TOL = 1e-12


# ---------------------------------------------------------------------------- curves
def line(p0, p1) -> NurbsCurve:
    """Segment C(t) = p0 + t (p1 - p0), degree 1, t in [0, 1], dim = len(p0)."""
    a = np.asarray(p0, dtype=float)
    b = np.asarray(p1, dtype=float)
    return NurbsCurve(1, [0.0, 0.0, 1.0, 1.0], np.stack([a, b]))


def arc_segments(sweep: float) -> int:
    """Number of rational quadratic segments (<= 90deg each) for a sweep in radians (A7.1)."""
    if not sweep > 0:
        raise ValueError(f"sweep must be positive, got {sweep!r}")
    return max(1, ceil(sweep / (pi / 2) * (1.0 - _ANGLE_TOL)))


def _unit_arc(start_angle: float, sweep: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit circle arc from ``start_angle`` over ``sweep`` (A7.1).

    Returns knots (2n+4,) on [start_angle, start_angle + sweep], 2D control points
    (2n+1, 2) (coefficients of the x and y axes) and weights (2n+1,).
    """
    n = arc_segments(sweep)
    d = sweep / n
    ang = start_angle + d * np.arange(n + 1)
    pts = np.empty((2 * n + 1, 2))
    w = np.ones(2 * n + 1)
    pts[0::2] = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    mid = ang[:-1] + d / 2
    pts[1::2] = np.stack([np.cos(mid), np.sin(mid)], axis=1) / np.cos(d / 2)
    w[1::2] = np.cos(d / 2)
    brk = ang.copy()
    brk[-1] = start_angle + sweep
    knots = np.concatenate([[brk[0]] * 3, np.repeat(brk[1:-1], 2), [brk[-1]] * 3])
    return knots, pts, w


def arc_angle(t, sweep: float, start: float = 0.0) -> np.ndarray:
    """Angle (from the arc start) reached at parameter ``t`` of an arc with knots as made by
    ``circular_arc`` / ``revolved_surface`` (v) over [start, start + sweep]. t (N,) -> (N,)."""
    n = arc_segments(sweep)
    d = sweep / n
    x = (np.asarray(t, dtype=float) - start) / d
    k = np.clip(np.floor(x), 0, n - 1)
    s = x - k
    return k * d + d / 2 + 2.0 * np.arctan((2.0 * s - 1.0) * np.tan(d / 4))


def arc_parameter(angle, sweep: float, start: float = 0.0) -> np.ndarray:
    """Inverse of :func:`arc_angle`: parameter at which the arc reaches ``angle`` (radians
    from the arc start, in [0, sweep]). angle (N,) -> (N,)."""
    n = arc_segments(sweep)
    d = sweep / n
    a = np.asarray(angle, dtype=float)
    k = np.clip(np.floor(a / d), 0, n - 1)
    rel = a - k * d - d / 2
    s = 0.5 * (1.0 + np.tan(rel / 2) / np.tan(d / 4))
    return start + (k + s) * d


def revolved_v_to_angle(v, start_angle: float, end_angle: float) -> np.ndarray:
    """Absolute rotation angle (IGES 120 theta) at parameter v of ``revolved_surface(...,
    start_angle, end_angle)``. v (N,) -> (N,)."""
    sweep = float(end_angle) - float(start_angle)
    return float(start_angle) + arc_angle(v, sweep, float(start_angle))


def revolved_angle_to_v(theta, start_angle: float, end_angle: float) -> np.ndarray:
    """Parameter v of ``revolved_surface(..., start_angle, end_angle)`` at the absolute
    rotation angle theta in [start_angle, end_angle] (maps IGES 120 (t, theta) trim
    coordinates to NURBS (u, v) with u = t). theta (N,) -> (N,)."""
    sweep = float(end_angle) - float(start_angle)
    return arc_parameter(np.asarray(theta, dtype=float) - float(start_angle), sweep, float(start_angle))


def circular_arc(center, start, end, normal=(0.0, 0.0, 1.0)) -> NurbsCurve:
    """Circular arc with IGES 100 semantics, as an exact rational quadratic NURBS.

    Counter-clockwise about ``normal`` from ``start`` to ``end``; ``start == end`` (within
    1e-12 R) gives the full circle. Radius R = |start - center|; the end angle is taken from
    the direction of ``end - center`` (its distance may differ slightly). Points may be 2D
    (normal ignored, counter-clockwise in the plane, 2D result) or 3D (3D result);
    ``start - center`` must lie in the plane normal to ``normal`` (1e-9 R).
    The curve has ceil(theta / 90deg) segments and domain [0, theta], theta the sweep; the
    parameter equals the angle at the knots only, see :func:`arc_angle`.
    """
    c = np.asarray(center, dtype=float)
    s = np.asarray(start, dtype=float)
    e = np.asarray(end, dtype=float)
    dim = c.size
    if dim not in (2, 3) or s.shape != c.shape or e.shape != c.shape:
        raise ValueError("center, start and end must all be 2D or all 3D points")
    if dim == 2:
        c, s, e = (np.append(x, 0.0) for x in (c, s, e))
        nrm = np.array([0.0, 0.0, 1.0])
    else:
        nrm = np.asarray(normal, dtype=float)
        ln = np.linalg.norm(nrm)
        if not ln > 0:
            raise ValueError("normal must be non-zero")
        nrm = nrm / ln
    x = s - c
    r = np.linalg.norm(x)
    if not r > 0:
        raise ValueError("start coincides with center: zero radius")
    off = x @ nrm
    if abs(off) > 1e-9 * r:
        raise ValueError(f"start - center is not perpendicular to the normal (offset {off:.3g}, R {r:.3g})")
    x = x - off * nrm
    r = np.linalg.norm(x)
    ex = x / r
    ey = np.cross(nrm, ex)
    de = e - c
    if np.linalg.norm(e - s) <= 1e-12 * r:
        theta = 2 * pi
    else:
        theta = float(np.arctan2(de @ ey, de @ ex)) % (2 * pi)
        if theta <= _ANGLE_TOL:
            theta = 2 * pi
    knots, uv, w = _unit_arc(0.0, theta)
    pts = c + r * (uv[:, :1] * ex + uv[:, 1:] * ey)
    pts[0] = c + x  # exact start
    if theta == 2 * pi:
        pts[-1] = pts[0]
    return NurbsCurve(2, knots, pts[:, :dim], w)


def _conic_coeffs(A, B, C, D, E, F):
    return np.array([[A, B / 2, D / 2], [B / 2, C, E / 2], [D / 2, E / 2, F]], dtype=float)


def conic_arc(A, B, C, D, E, F, zt, start, end) -> NurbsCurve:
    """IGES 104 conic arc A x^2 + B xy + C y^2 + D x + E y + F = 0 in the plane z = zt, from
    ``start`` to ``end`` ((x, y) or (x, y, z); z ignored), as an exact rational quadratic
    NURBS in 3D (P&T 7.5).

    Ellipse: counter-clockwise from start to end (start == end: full ellipse), built as the
    affine image of a unit circular arc in its parametric angle (<= 90deg per segment).
    Parabola / hyperbola: one segment, the arc of the branch between the two points: middle
    control point at the intersection of the end tangents, weight from the shoulder point
    (1 for a parabola, cosh(half the hyperbolic sweep) for a hyperbola).
    Domain: [0, sweep] (ellipse, sweep in parametric angle) or [0, 1].
    """
    M = _conic_coeffs(A, B, C, D, E, F)
    P0 = np.asarray(start, dtype=float)[:2]
    P2 = np.asarray(end, dtype=float)[:2]
    Q = M[:2, :2]
    qscale = max(abs(A), abs(B), abs(C))
    if not qscale > 0:
        raise ValueError("conic_arc: A = B = C = 0 is a line, not a conic")
    disc = B * B - 4 * A * C  # classification invariant under scaling of the equation
    if abs(disc) <= 1e-12 * qscale * qscale:
        kind = "parabola"
    elif disc < 0:
        kind = "ellipse"
    else:
        kind = "hyperbola"
    if kind == "ellipse":
        ctr = np.linalg.solve(Q, -M[:2, 2])
        k = -(ctr @ M[:2, 2] + M[2, 2])  # (x-c)^T Q (x-c) = k
        lam, vec = np.linalg.eigh(Q / k)
        if np.any(lam <= 0):
            raise ValueError("conic_arc: imaginary ellipse")
        if np.linalg.det(vec) < 0:
            vec[:, 1] = -vec[:, 1]
        axes = vec / np.sqrt(lam)  # columns: semi-axis vectors a*e1, b*e2 (right-handed)
        inv = np.linalg.inv(axes)
        a0 = np.arctan2(*(inv @ (P0 - ctr))[::-1])
        a1 = np.arctan2(*(inv @ (P2 - ctr))[::-1])
        sweep = (a1 - a0) % (2 * pi)
        if np.linalg.norm(P2 - P0) <= 1e-12 * np.abs(axes).max() or sweep <= _ANGLE_TOL:
            sweep = 2 * pi
        knots, uv, w = _unit_arc(a0, sweep)
        pts2 = ctr + uv @ axes.T
        pts2[0] = P0
        pts2[-1] = P0 if sweep == 2 * pi else P2
        knots = reparametrize(knots, (0.0, sweep))
    else:
        g0 = M[:2, :] @ np.append(P0, 1.0)  # gradients (up to factor 2)
        g2 = M[:2, :] @ np.append(P2, 1.0)
        # tangent lines g . (x - P) = 0 ; intersect
        G = np.stack([g0, g2])
        if abs(np.linalg.det(G)) <= 1e-14 * np.linalg.norm(g0) * np.linalg.norm(g2):
            raise ValueError("conic_arc: end tangents are parallel (arc not representable by one segment)")
        P1 = np.linalg.solve(G, np.array([g0 @ P0, g2 @ P2]))
        Mid = 0.5 * (P0 + P2)
        dvec = P1 - Mid
        # conic along Mid + l * dvec: a l^2 + b l + c = 0
        h = np.append(Mid, 1.0)
        dh = np.append(dvec, 0.0)
        qa, qb, qc = dh @ M @ dh, 2 * (dh @ M @ h), h @ M @ h
        if abs(qa) <= 1e-14 * abs(qb):
            roots = np.array([-qc / qb])
        else:
            dsc = qb * qb - 4 * qa * qc
            if dsc < 0:
                raise ValueError("conic_arc: no shoulder point; start/end not on one branch")
            sq = np.sqrt(dsc)
            roots = np.array([(-qb - sq) / (2 * qa), (-qb + sq) / (2 * qa)])
        roots = roots[(roots > 0) & (roots < 1)]
        if roots.size == 0:
            raise ValueError("conic_arc: start and end are not on one branch of the conic")
        lam_ = roots.min()
        wm = lam_ / (1.0 - lam_)
        if kind == "parabola":
            wm = 1.0
        pts2 = np.stack([P0, P1, P2])
        w = np.array([1.0, wm, 1.0])
        knots = np.array([0.0, 0, 0, 1, 1, 1])
    pts = np.column_stack([pts2, np.full(len(pts2), float(zt))])
    return NurbsCurve(2, knots, pts, None if np.ptp(w) == 0 else w)


def composite_curve(curves: Sequence[NurbsCurve], tol: float = 1e-9) -> NurbsCurve:
    """Join curves end to start into one NURBS (IGES 102).

    Each piece is restricted to its domain and keeps its parameter length; pieces are
    shifted so they follow each other starting at the first piece's start parameter. All are
    elevated to the largest degree p; joins are knots of multiplicity p (C0). Raises
    ValueError if an end and the next start differ by more than ``tol`` times the size of
    the whole curve (the joint control point is the mean of the two).
    """
    if len(curves) == 0:
        raise ValueError("composite_curve: no curves")
    dims = {c.dim for c in curves}
    if len(dims) != 1:
        raise ValueError("composite_curve: curves of different dimensions")
    cs = [edits.restrict_curve(c) for c in curves]
    p = max(c.degree for c in cs)
    cs = [edits.elevate_curve(c, p - c.degree) if c.degree < p else c for c in cs]
    allpts = np.concatenate([c.control_points for c in cs])
    size = max(float(np.linalg.norm(np.ptp(allpts, axis=0))), 1e-300)
    knots = list(cs[0].knots[:-1])
    ctrl = [cs[0]._pw]
    t_end = cs[0].knots[-1]
    for i, c in enumerate(cs[1:], start=1):
        prev = ctrl[-1][-1]
        a = prev[:-1] / prev[-1]
        pw = c._pw.copy()
        b = pw[0, :-1] / pw[0, -1]
        gap = np.linalg.norm(a - b)
        if gap > tol * size:
            raise ValueError(f"composite_curve: gap {gap:.3g} between piece {i - 1} and {i} (size {size:.3g})")
        pw *= prev[-1] / pw[0, -1]  # same weight at the joint
        joint = 0.5 * (a + b) * prev[-1]
        ctrl[-1] = ctrl[-1].copy()
        ctrl[-1][-1, :-1] = joint
        pw[0, :-1] = joint
        kn = c.knots - c.knots[0] + t_end
        knots += list(kn[p + 1 : -1])
        ctrl.append(pw[1:])
        t_end = kn[-1]
    knots.append(t_end)
    return edits.curve_from_homogeneous(p, np.array(knots), np.concatenate(ctrl))


# ---------------------------------------------------------------------------- surfaces
def plane_surface(point, normal, u_dir, u_range, v_range) -> NurbsSurface:
    """Bilinear plane S(u, v) = point + u e_u + v e_v on u_range x v_range, with e_u the unit
    projection of ``u_dir`` into the plane and e_v = n x e_u (so Su x Sv = +n)."""
    o = np.asarray(point, dtype=float)
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    d = np.asarray(u_dir, dtype=float)
    eu = d - (d @ n) * n
    ln = np.linalg.norm(eu)
    if not ln > 1e-12 * np.linalg.norm(d):
        raise ValueError("plane_surface: u_dir is parallel to the normal")
    eu /= ln
    ev = np.cross(n, eu)
    u0, u1 = map(float, u_range)
    v0, v1 = map(float, v_range)
    cp = np.array([[o + u * eu + v * ev for v in (v0, v1)] for u in (u0, u1)])
    return NurbsSurface(1, 1, [u0, u0, u1, u1], [v0, v0, v1, v1], cp)


def ruled_surface(c1: NurbsCurve, c2: NurbsCurve, reverse_second: bool = False) -> NurbsSurface:
    """Ruled surface between two 3D curves (IGES 118, equal-parameter form).

    Both curves are made compatible (same degree, common knots over [0, 1] after affine
    reparametrisation of their domains); u in [0, 1] along the curves, v in [0, 1] from c1
    (v = 0) to c2 (v = 1), degree 1 in v. Each ruling v -> S(u, v) is the straight segment
    from c1(u) to c2(u); it is linear in v when both curves have equal weights at u
    (always for polynomial curves). ``reverse_second`` traverses c2 backwards.
    IGES form 0 (equal relative arc length) is not reproduced exactly.
    """
    if reverse_second:
        c2 = edits.reverse_curve(c2)
    a, b = edits.make_compatible([c1, c2])
    cw = np.stack([a._pw, b._pw], axis=1)  # (n, 2, 4)
    return edits.surface_from_homogeneous(a.degree, 1, a.knots, [0.0, 0.0, 1.0, 1.0], cw)


def revolved_surface(generatrix: NurbsCurve, axis_point, axis_dir, start_angle: float, end_angle: float) -> NurbsSurface:
    """Surface of revolution (IGES 120, P&T A8.1).

    u: the generatrix parameter (its domain, knots restricted to it); v in
    [start_angle, end_angle]: S(u, v) is C(u) rotated about the axis (right-hand rule about
    ``axis_dir``) by the angle ``arc_angle(v, end_angle - start_angle, start_angle) +
    start_angle``. v equals that angle at the v knots (every <= 90deg) and the ends only;
    use :func:`arc_parameter` to map an angle to v. A full turn (2 pi) gives 4 segments.
    Points of the generatrix on the axis give collapsed rows (poles).
    """
    g = edits.restrict_curve(generatrix)
    if g.dim != 3:
        raise ValueError("revolved_surface: the generatrix must be 3D")
    sweep = float(end_angle) - float(start_angle)
    if not sweep > 0:
        raise ValueError(f"revolved_surface: end_angle {end_angle!r} must exceed start_angle {start_angle!r}")
    if sweep > 2 * pi * (1 + _ANGLE_TOL):
        raise ValueError("revolved_surface: sweep above 2 pi")
    a = np.asarray(axis_dir, dtype=float)
    a = a / np.linalg.norm(a)
    o = np.asarray(axis_point, dtype=float)
    kv, uv, wv = _unit_arc(float(start_angle), sweep)
    P = g.control_points  # (n, 3)
    O = o + ((P - o) @ a)[:, None] * a  # projections on the axis
    X = P - O
    Y = np.cross(a, X)
    cp = O[:, None, :] + uv[None, :, 0, None] * X[:, None, :] + uv[None, :, 1, None] * Y[:, None, :]
    w = g.weights[:, None] * wv[None, :]
    return NurbsSurface(g.degree, 2, g.knots, kv, cp, None if np.ptp(w) == 0 else w)


def tabulated_cylinder(directrix: NurbsCurve, vector) -> NurbsSurface:
    """Tabulated cylinder S(u, v) = C(u) + v * vector (IGES 122): u the directrix
    parameter (its domain), v in [0, 1], exactly linear in v."""
    c = edits.restrict_curve(directrix)
    if c.dim != 3:
        raise ValueError("tabulated_cylinder: the directrix must be 3D")
    vec = np.asarray(vector, dtype=float)
    cp = np.stack([c.control_points, c.control_points + vec], axis=1)
    w = np.stack([c.weights, c.weights], axis=1)
    return NurbsSurface(c.degree, 1, c.knots, [0.0, 0.0, 1.0, 1.0], cp, w if c.rational else None)


# ---------------------------------------------------------------------------- analytic patches
def cylinder_patch(radius: float, height: float, angle: float = 2 * pi) -> NurbsSurface:
    """Cylinder x^2 + y^2 = radius^2, 0 <= z <= height, azimuth 0..angle about +z.
    u = z in [0, height], v in [0, angle] (angle at knots, see :func:`arc_angle`);
    Su x Sv points towards the axis."""
    gen = edits.reparametrize_curve(line((radius, 0.0, 0.0), (radius, 0.0, height)), (0.0, height))
    return revolved_surface(gen, (0, 0, 0), (0, 0, 1), 0.0, angle)


def cone_patch(r0: float, r1: float, height: float, angle: float = 2 * pi) -> NurbsSurface:
    """Cone (frustum) with radius r0 at z = 0 and r1 at z = height about +z; u in [0, 1]
    along the line, v in [0, angle]."""
    return revolved_surface(line((r0, 0.0, 0.0), (r1, 0.0, height)), (0, 0, 0), (0, 0, 1), 0.0, angle)


def sphere_patch(radius: float, lat_range=(-pi / 2, pi / 2), lon_range=(0.0, 2 * pi)) -> NurbsSurface:
    """Sphere of ``radius`` about the origin between latitudes lat_range (radians, -pi/2 =
    south pole) and longitudes lon_range about +z. u in [0, lat1 - lat0] along the
    meridian (the arc parameter of :func:`circular_arc`), v in lon_range; Su x Sv points
    towards the centre. Poles are collapsed rows."""
    la0, la1 = map(float, lat_range)
    s = radius * np.array([np.cos(la0), 0.0, np.sin(la0)])
    e = radius * np.array([np.cos(la1), 0.0, np.sin(la1)])
    gen = circular_arc((0, 0, 0), s, e, normal=(0.0, -1.0, 0.0))
    return revolved_surface(gen, (0, 0, 0), (0, 0, 1), lon_range[0], lon_range[1])


def torus_patch(R: float, r: float, tube_range=(0.0, 2 * pi), sweep_range=(0.0, 2 * pi)) -> NurbsSurface:
    """Torus about +z with major radius R, minor radius r: the tube circle (centre (R, 0, 0)
    in the xz plane, angle phi from +x towards +z) over tube_range revolved over
    sweep_range. u in [0, phi1 - phi0] (arc parameter), v in sweep_range."""
    f0, f1 = map(float, tube_range)
    c = np.array([R, 0.0, 0.0])
    s = c + r * np.array([np.cos(f0), 0.0, np.sin(f0)])
    e = c + r * np.array([np.cos(f1), 0.0, np.sin(f1)])
    gen = circular_arc(c, s, e, normal=(0.0, -1.0, 0.0))
    return revolved_surface(gen, (0, 0, 0), (0, 0, 1), sweep_range[0], sweep_range[1])
