"""Trim classification on the exact curves (cadbridge.cad.trims, Face/Trim.contains) and the
nearest point of the trim boundary (project_to_trims).

References: analytic geometry (a cubic Bezier graph v = f(u) with u linear in t, circles,
the intersection of two discs), a brute-force crossing count, dense sampling of the
boundary curves on the surface, and OpenCASCADE's BRepClass_FaceClassifier on the real
files' B-spline faces (where our (u, v) is OCC's). The old polygon-band rule is rebuilt from
`TrimLoop.polygon` + `points_in_polygon` + `distance_to_polygon` to show the analytic tests
fail on it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from tests.helpers.surfaces import circle_arc

from cadbridge.cad.model import Face, Trim, TrimLoop, distance_to_polygon, points_in_polygon
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface
from cadbridge.cad.trims import LoopBoundary, project_to_trims

REAL = Path(__file__).parents[2].parent / "shared" / "iges_real"

BEZ_U = np.array([0.05, 0.35, 0.65, 0.95])
BEZ_V = np.array([0.2, 0.05, 0.35, 0.2])
HOLE_C, HOLE_R = np.array([0.5, 0.6]), 0.15


def line(p, q) -> NurbsCurve:
    return NurbsCurve(1, [0, 0, 1, 1], [p, q])


def circle(c, r, a0=0.0, a1=2 * math.pi) -> NurbsCurve:
    ctrl, w, kn = circle_arc(a0, a1)
    return NurbsCurve(2, kn, np.asarray(c) + r * np.asarray(ctrl), w)


def reverse(c: NurbsCurve) -> NurbsCurve:
    t0, t1 = c.knots[0], c.knots[-1]
    return NurbsCurve(c.degree, (t0 + t1) - c.knots[::-1], c.control_points[::-1], c.weights[::-1])


def reversed_loop(loop: TrimLoop) -> TrimLoop:
    return TrimLoop([reverse(c) for c in loop.curves[::-1]])


def bezier_v(u):
    """Analytic bottom edge: v = f(u) of the cubic Bezier with control u equally spaced
    (so u(t) = 0.05 + 0.9 t exactly), Bernstein form."""
    t = (np.asarray(u) - 0.05) / 0.9
    b = [(1 - t) ** 3, 3 * t * (1 - t) ** 2, 3 * t**2 * (1 - t), t**3]
    return sum(bk * vk for bk, vk in zip(b, BEZ_V))


def plane_face(trims) -> Face:
    s = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], [[[0, 0, 0], [0, 1, 0]], [[1, 0, 0], [1, 1, 0]]])
    return Face(surface=s, de=1, trims=trims)


def spline_face(reverse_outer=False, reverse_hole=False) -> Face:
    bottom = NurbsCurve(3, [0, 0, 0, 0, 1, 1, 1, 1], np.column_stack([BEZ_U, BEZ_V]))
    outer = TrimLoop([bottom, line((0.95, 0.2), (0.95, 0.9)), line((0.95, 0.9), (0.05, 0.9)), line((0.05, 0.9), (0.05, 0.2))])
    hole = TrimLoop([circle(HOLE_C, HOLE_R)])
    return plane_face(Trim(reversed_loop(outer) if reverse_outer else outer, [reversed_loop(hole) if reverse_hole else hole]))


def old_rule(trim: Trim, u, v, tol=0.0) -> np.ndarray:
    """The classification before issue #8: even-odd on a 32-per-span polygon, and points
    within 2 x its sampled chord deviation (+ tol) of a loop polygon counted inside."""
    uv = np.column_stack([u, v])
    loops = ([(trim.outer, True)] if trim.outer is not None else []) + [(h, False) for h in trim.inner]
    inside = np.ones(len(uv), dtype=bool)
    bands = []
    for loop, is_outer in loops:
        poly = loop.polygon(32)
        dev = 0.0
        for c in loop.curves:
            if c.degree > 1:
                t = c.sample_parameters(32)
                p = c.evaluate(t)
                dev = max(dev, float(np.max(np.linalg.norm(c.evaluate(0.5 * (t[:-1] + t[1:])) - 0.5 * (p[:-1] + p[1:]), axis=1))))
        bands.append((poly, 2 * dev))
        il = points_in_polygon(uv, poly)
        inside &= il if is_outer else ~il
    for poly, band in bands:
        inside |= distance_to_polygon(uv, poly) <= band + tol
    return inside


def near_points(rng, n=4000):
    """Points at distance 1e-7..1e-3 on both sides of the Bezier edge and the hole, with the
    analytic answer. (n, 2), (n,) bool."""
    d = 10.0 ** rng.uniform(-7, -3, n)
    side = rng.choice([-1.0, 1.0], n)
    half = n // 2
    u = rng.uniform(0.1, 0.9, half)
    # the bottom edge: inside iff v > f(u); offsets along v
    p1 = np.column_stack([u, bezier_v(u) + side[:half] * d[:half]])
    a = rng.uniform(0, 2 * np.pi, n - half)
    p2 = HOLE_C + (HOLE_R + side[half:] * d[half:])[:, None] * np.column_stack([np.cos(a), np.sin(a)])
    return np.vstack([p1, p2]), side > 0


@pytest.mark.parametrize("rev_outer,rev_hole", [(False, False), (True, False), (False, True), (True, True)])
def test_near_exact_curves_both_sides(rev_outer, rev_hole):
    """1e-7..1e-3 from the exact Bezier edge and the exact circle, both sides, both loop
    orientations: the analytic side is the answer. The old polygon-band rule accepts the
    outside points within its band (the test fails on it)."""
    face = spline_face(rev_outer, rev_hole)
    pts, want = near_points(np.random.default_rng(1))
    got = face.contains(pts[:, 0], pts[:, 1])
    assert np.array_equal(got, want), f"{np.sum(got != want)} misclassified"
    old = old_rule(face.trims, pts[:, 0], pts[:, 1])
    assert np.sum(old != want) > 100  # the old rule accepts feet on trimmed-away surface


def test_uniform_points_analytic():
    """Uniform points over the domain against the analytic region (box, above the Bezier
    graph, outside the circle)."""
    face = spline_face()
    rng = np.random.default_rng(2)
    p = rng.uniform(0, 1, (50000, 2))
    want = (p[:, 0] >= 0.05) & (p[:, 0] <= 0.95) & (p[:, 1] <= 0.9) & (p[:, 1] >= bezier_v(np.clip(p[:, 0], 0.05, 0.95)))
    want &= np.linalg.norm(p - HOLE_C, axis=1) >= HOLE_R
    assert np.array_equal(face.contains(p[:, 0], p[:, 1]), want)


def test_on_boundary_within_tol():
    """A point within tol of the exact curve is ON (inside) even on the cut-away side; one
    beyond tol is not. Reference: the circle, distance |p - c| - r."""
    face = spline_face()
    a = np.linspace(0, 2 * np.pi, 101)[:-1]
    dirs = np.column_stack([np.cos(a), np.sin(a)])
    on = HOLE_C + HOLE_R * dirs
    into_hole_tiny = HOLE_C + (HOLE_R - 1e-10) * dirs
    into_hole = HOLE_C + (HOLE_R - 1e-8) * dirs
    tr = face.trims
    assert tr.contains(on[:, 0], on[:, 1], tol=1e-12).all()
    assert tr.contains(into_hole_tiny[:, 0], into_hole_tiny[:, 1], tol=1e-9).all()
    assert not tr.contains(into_hole[:, 0], into_hole[:, 1], tol=1e-9).any()
    # vertices of the straight loop and points on it: on the boundary
    sq = np.array([[0.05, 0.2], [0.95, 0.2], [0.95, 0.9], [0.05, 0.9], [0.5, 0.9], [0.05, 0.5]])
    assert tr.contains(sq[:, 0], sq[:, 1], tol=1e-12).all()
    assert not tr.contains(np.array([0.5]), np.array([0.9 + 1e-8]), tol=1e-9).any()


def lens_loop(rev=False) -> TrimLoop:
    """Intersection of the discs |p - (0.4, 0.5)| <= 0.25 and |p - (0.6, 0.5)| <= 0.25: two
    arcs meeting at corners (0.5, 0.5 +- sqrt(0.25^2 - 0.1^2)) at an angle."""
    al = math.acos(0.4)
    loop = TrimLoop([circle((0.4, 0.5), 0.25, -al, al), circle((0.6, 0.5), 0.25, math.pi - al, math.pi + al)])
    return reversed_loop(loop) if rev else loop


@pytest.mark.parametrize("rev", [False, True])
@pytest.mark.parametrize("as_hole", [False, True])
def test_junction_corner(rev, as_hole):
    """Points 1e-7..1e-3 around the corners of the lens, in all directions: inside iff in
    both discs (analytic). As outer loop (convex corners) and as a hole in a square
    (reflex corners of the region), both orientations."""
    loop = lens_loop(rev)
    sq = TrimLoop([line((0.1, 0.1), (0.9, 0.1)), line((0.9, 0.1), (0.9, 0.9)), line((0.9, 0.9), (0.1, 0.9)), line((0.1, 0.9), (0.1, 0.1))])
    trim = Trim(sq, [loop]) if as_hole else Trim(loop, [])
    rng = np.random.default_rng(3)
    n = 20000
    h = math.sqrt(0.25**2 - 0.1**2)
    corner = np.array([[0.5, 0.5 + h], [0.5, 0.5 - h]])[rng.integers(2, size=n)]
    phi = rng.uniform(0, 2 * np.pi, n)
    p = corner + (10.0 ** rng.uniform(-7, -3, n))[:, None] * np.column_stack([np.cos(phi), np.sin(phi)])
    da = np.linalg.norm(p - [0.4, 0.5], axis=1) - 0.25
    db = np.linalg.norm(p - [0.6, 0.5], axis=1) - 0.25
    keep = np.minimum(np.abs(da), np.abs(db)) > 1e-12  # not ON either circle
    p = p[keep]
    in_lens = (da[keep] < 0) & (db[keep] < 0)
    got = trim.contains(p[:, 0], p[:, 1], tol=0.0)
    assert np.array_equal(got, ~in_lens if as_hole else in_lens), f"{np.sum(got != (~in_lens if as_hole else in_lens))} wrong"


def test_index_grows_with_curves_not_points():
    """A 4000-piece star polygon loop: grid entries stay a small multiple of the edges, and
    classification agrees with a brute-force crossing count (numpy, all pairs, small N)."""
    k = 4000
    a = np.linspace(0, 2 * np.pi, k, endpoint=False)
    r = 0.3 + 0.1 * np.cos(7 * a) + 0.02 * np.sin(91 * a)
    poly = 0.5 + r[:, None] * np.column_stack([np.cos(a), np.sin(a)])
    loop = TrimLoop([line(poly[i], poly[(i + 1) % k]) for i in range(k)])
    lb = loop.boundary
    g = lb.grid(1e-9)
    assert len(lb.a) >= k and len(g.cedges) <= 12 * len(lb.a)
    rng = np.random.default_rng(4)
    p = rng.uniform(0, 1, (3000, 2))
    ins, on = lb.contains(p, 0.0)
    b = np.roll(poly, -1, axis=0)
    st = (poly[None, :, 1] > p[:, None, 1]) != (b[None, :, 1] > p[:, None, 1])
    xc = poly[None, :, 0] + (p[:, None, 1] - poly[None, :, 1]) * (b[None, :, 0] - poly[None, :, 0]) / np.where(st, b[None, :, 1] - poly[None, :, 1], 1.0)
    ref = np.count_nonzero(st & (p[:, None, 0] < xc), axis=1) % 2 == 1
    assert np.array_equal(ins, ref) and not on.any()


def test_chord_bounds_are_bounds():
    """Every edge's arc stays within its band of the chord (dense samples of the exact
    curve), for the rational circle, the Bezier and a degree-5 random spline."""
    rng = np.random.default_rng(5)
    kn = np.concatenate([[0] * 6, [0.3, 0.55, 0.8], [1] * 6])
    spl = NurbsCurve(5, kn, rng.uniform(0, 1, (9, 2)), rng.uniform(0.5, 2.0, 9))
    for c in [circle((0.3, 0.2), 0.7), NurbsCurve(3, [0, 0, 0, 0, 1, 1, 1, 1], np.column_stack([BEZ_U, BEZ_V])), spl]:
        lb = LoopBoundary([c])
        s = np.linspace(0, 1, 41)
        for k in np.flatnonzero(lb.curve >= 0):
            t = lb.ta[k] + (lb.tb[k] - lb.ta[k]) * s
            x = c.evaluate(t)
            ab = lb.b[k] - lb.a[k]
            w = np.clip((x - lb.a[k]) @ ab / (ab @ ab), 0, 1)
            dev = np.linalg.norm(x - (lb.a[k] + w[:, None] * ab), axis=1).max()
            assert dev <= lb.band[k] * (1 + 1e-9) + 1e-15


def test_project_to_trims_vs_dense_samples():
    """Nearest point of the trim boundary of a trimmed hemisphere-like bicubic patch:
    distance equals the minimum over 2e5 dense samples of every boundary curve on the
    surface (to the sampling error), and the foot lies on the surface at (u, v)."""
    rng = np.random.default_rng(6)
    g = np.linspace(0, 1, 4)
    cp = np.array([[[x, y, 0.3 * np.sin(3 * x) * np.cos(2 * y) + 0.2 * rng.uniform()] for y in g] for x in g])
    s = NurbsSurface(3, 3, [0, 0, 0, 0, 1, 1, 1, 1], [0, 0, 0, 0, 1, 1, 1, 1], cp)
    face = spline_face()
    face = Face(surface=s, de=1, trims=face.trims)
    pts = rng.uniform([-0.2, -0.2, -0.5], [1.2, 1.2, 0.8], (400, 3))
    u, v, foot, dist, ok = project_to_trims(face, pts)
    assert ok.all()
    samp = []
    for loop in [face.trims.outer] + face.trims.inner:
        for c in loop.curves:
            uv = c.evaluate(np.linspace(*c.domain, 50001))
            samp.append(s.evaluate(uv[:, 0], uv[:, 1]))
    from scipy.spatial import cKDTree

    dref, _ = cKDTree(np.vstack(samp)).query(pts)
    assert np.all(dist <= dref + 1e-12)
    assert np.all(dist >= dref - 1e-4)  # sample spacing <= 2e-5 x |S'|
    assert np.allclose(s.evaluate(u, v), foot, atol=1e-12)


def _occ_states(face, u, v):
    from OCP.BRepClass import BRepClass_FaceClassifier
    from OCP.gp import gp_Pnt2d
    from OCP.TopAbs import TopAbs_IN, TopAbs_ON

    st = [BRepClass_FaceClassifier(face, gp_Pnt2d(float(a), float(b)), 1e-12).State() for a, b in zip(u, v)]
    return np.array([s == TopAbs_IN for s in st]), np.array([s == TopAbs_ON for s in st])


@pytest.mark.skipif(not REAL.is_dir(), reason=f"{REAL} not present")
@pytest.mark.parametrize("name", ["occt_bearing_EuclidQuantum.iges", "occt_OCC131-2_ANSA9.igs", "occt_bug33327_C3D.igs"])
def test_real_faces_vs_occ_classifier(name):
    """Points 1e-6..1e-3 x loop size from the exact trim curves of the real B-spline faces
    (where OCC keeps our (u, v), checked by evaluating both surfaces), classified by
    BRepClass_FaceClassifier: where OCC says IN or OUT (not ON within its edge tolerance)
    we agree on >= 99.9% (OCC may rebuild a pcurve to ~1e-6), and better than the old rule."""
    path = REAL / name
    if not path.exists():
        pytest.skip(f"{path} not present")
    pytest.importorskip("OCP")
    from cadbridge.iges import read_iges
    from cadbridge.verify.reference import occ_eval, occ_read

    m = read_iges(path)
    occ = occ_read(path)
    rng = np.random.default_rng(7)
    agree = agree_old = total = 0
    for k, f in enumerate(m.faces):
        if f.trims is None or f.surface_type != 128 or k >= len(occ):
            continue
        u0, u1, v0, v1 = f.surface.domain
        uu, vv = rng.uniform(u0, u1, 3), rng.uniform(v0, v1, 3)
        if np.max(np.abs(occ_eval(occ[k].surface, uu, vv, 0)[0] - f.surface.evaluate(uu, vv))) > 1e-9 * m.size():
            continue
        loops = ([f.trims.outer] if f.trims.outer is not None else []) + list(f.trims.inner)
        size = max(lp.boundary.size for lp in loops)
        pts = []
        for lp in loops:
            for c in lp.curves:
                t = rng.uniform(*c.domain, 12)
                d = c.derivatives(t, 1)[:, :, :2]
                tan = d[:, 1] / np.maximum(np.linalg.norm(d[:, 1], axis=1), 1e-300)[:, None]
                off = 10.0 ** rng.uniform(-6, -3, len(t)) * size * rng.choice([-1.0, 1.0], len(t))
                pts.append(d[:, 0] + off[:, None] * np.column_stack([-tan[:, 1], tan[:, 0]]))
        p = np.vstack(pts)
        p = p[(p[:, 0] >= u0) & (p[:, 0] <= u1) & (p[:, 1] >= v0) & (p[:, 1] <= v1)]
        occ_in, occ_on = _occ_states(occ[k].face, p[:, 0], p[:, 1])
        sel = ~occ_on
        tol = 1e-9 * max(u1 - u0, v1 - v0)
        ours = f.contains(p[sel, 0], p[sel, 1])
        old = old_rule(f.trims, p[sel, 0], p[sel, 1], tol)
        agree += int(np.sum(ours == occ_in[sel]))
        agree_old += int(np.sum(old == occ_in[sel]))
        total += int(sel.sum())
    assert total > 50
    assert agree >= 0.999 * total, f"{total - agree} of {total} disagree with OCC"
    assert agree >= agree_old


def test_project_to_trims_across_the_seam_of_a_closed_hole_curve():
    """A hole written as one closed curve (trimmed_hole.igs: circle R10 about (30, 25) in
    z = 0, start = end at (20, 25)): points near its seam must find the foot on the other
    side of the seam, not stop at the end the nearest sample gave. Reference: the distance to
    the analytic circle. (Newton clamped at t0 gave 0.518 instead of 0.121 at (20.134, 24.5).)"""
    from cadbridge.iges import read_iges
    from cadbridge.cad.trims import project_to_trims

    m = read_iges(Path(__file__).parents[2] / "iges_samples" / "trimmed_hole.igs")
    rng = np.random.default_rng(3)
    ang = np.concatenate([rng.uniform(0, 2 * np.pi, 1000), np.pi + rng.uniform(-0.05, 0.05, 1000)])
    rad = rng.uniform(9.0, 11.0, 2000)
    p = np.c_[30 + rad * np.cos(ang), 25 + rad * np.sin(ang), rng.uniform(-1, 1, 2000)]
    p = np.vstack([p, [[20.13397458, 24.50000003, 0.0]]])
    _, _, foot, d, ok = project_to_trims(m.faces[0], p)
    ref = np.hypot(np.hypot(p[:, 0] - 30, p[:, 1] - 25) - 10, p[:, 2])
    assert ok.all()
    np.testing.assert_allclose(d, ref, atol=1e-9)


def test_project_to_trims_at_a_kink_where_the_trim_crosses_a_crease():
    """A trim line crossing a C0 knot line of its surface (a roof, ridge at u = 0.5: a CATIA
    crease) has a kink there in model space, where (C - P).C' jumps and Newton finds no
    root. Points at and beyond the kink (the nearest boundary point is the kink, by the
    roof's symmetry) get that foot; the reference is the minimum over dense samples of
    every boundary curve on the surface, and the foot lies at the ridge (u = 0.5)."""
    s = NurbsSurface(1, 1, [0, 0, 0.5, 1, 1], [0, 0, 1, 1],
                     [[[0, 0, 0], [0, 1, 0]], [[0.5, 0, 0.3], [0.5, 1, 0.3]], [[1, 0, 0], [1, 1, 0]]])
    corners = [(0.1, 0.2), (0.9, 0.2), (0.9, 0.8), (0.1, 0.8)]
    face = Face(surface=s, de=1, trims=Trim(TrimLoop([line(corners[i], corners[(i + 1) % 4]) for i in range(4)]), []))
    kink = s.evaluate(np.array([0.5]), np.array([0.2]))[0]
    pts = kink + np.array([[0, 0, 0], [0, -0.05, 0], [0, -0.05, 0.02], [0, -0.2, 0.1], [0, -1e-7, 1e-7]])
    u, v, foot, dist, ok = project_to_trims(face, pts)
    assert ok.all()
    samp = []
    for c in face.trims.outer.curves:
        uv = c.evaluate(np.linspace(*c.domain, 80001))
        samp.append(s.evaluate(uv[:, 0], uv[:, 1]))
    from scipy.spatial import cKDTree

    dref, _ = cKDTree(np.vstack(samp)).query(pts)
    assert np.all(dist <= dref + 1e-12)
    assert np.all(dist >= dref - 1e-5)
    np.testing.assert_allclose(u, 0.5, atol=1e-9)
    np.testing.assert_allclose(v, 0.2, atol=1e-12)
