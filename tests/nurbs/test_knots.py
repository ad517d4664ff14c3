"""Tests of cadbridge.nurbs.knots and cadbridge.nurbs.edits (knot insertion, refinement, decomposition, degree
elevation, restriction, compatibility, Bézier patches, tight boxes).

References: invariance (every evaluated point unchanged to 1e-12 after an exact operation),
knot counts and multiplicities, Bernstein evaluation of the Bézier segments, and
OpenCASCADE (Geom_BSplineCurve.InsertKnot / IncreaseDegree on the same data).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from math import comb

from cadbridge.nurbs import NurbsCurve, NurbsSurface, edits, knots

from tests.nurbs.test_engine import knot_vectors, occ_curve, random_surface

HYP = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def random_curve(p, knots, seed, dim=3, rational=True):
    rng = np.random.default_rng(seed)
    n = len(knots) - p - 1
    return NurbsCurve(p, knots, rng.uniform(-1, 1, (n, dim)), rng.uniform(0.3, 3.0, n) if rational else None)


def dense(c: NurbsCurve, k=201):
    return np.linspace(c.domain[0], c.domain[1], k)


def mult(knots, x):
    return int(np.count_nonzero(knots == x))


# ---------------------------------------------------------------------------- insertion
@HYP
@given(knot_vectors(), st.integers(0, 2**31 - 1), st.floats(0.0, 1.0), st.integers(1, 5))
def test_insert_knot_invariant(pk, seed, frac, r):
    """Reference: invariance: the curve after inserting u r times (A5.1) equals the original
    at 201 parameters to 1e-12; the knot count grows by r, u gets multiplicity s + r."""
    p, kn = pk
    c = random_curve(p, kn, seed)
    u = kn[0] + frac * (kn[-1] - kn[0])
    s = mult(kn, u)
    if s + r > p:
        with pytest.raises(ValueError):
            knots.insert_knot(kn, p, c._pw, u, r)
        return
    k2, cw = knots.insert_knot(kn, p, c._pw, u, r)
    assert len(k2) == len(kn) + r and mult(k2, u) == s + r and cw.shape[0] == c._pw.shape[0] + r
    if np.any((np.diff(k2) > 0) & (np.diff(k2) < 1e-300)):  # denormal span: rejected, see below
        with pytest.raises(ValueError, match="differ by less than"):
            edits.curve_from_homogeneous(p, k2, cw)
        return
    c2 = edits.curve_from_homogeneous(p, k2, cw)
    t = dense(c)
    assert np.abs(c2(t) - c(t)).max() < 1e-12


@HYP
@given(knot_vectors(), st.integers(0, 2**31 - 1), st.lists(st.floats(0.0, 1.0), min_size=1, max_size=8))
def test_refine_matches_repeated_insertion_and_is_invariant(pk, seed, fracs):
    """Reference: A5.4 refinement == repeated single insertions (A5.1) to 1e-12, and the
    curve is unchanged at 201 parameters to 1e-12."""
    p, kn = pk
    c = random_curve(p, kn, seed)
    X = kn[0] + np.array(fracs) * (kn[-1] - kn[0])
    X = np.array([x for x in np.unique(X) if mult(kn, x) + 1 <= p])
    if X.size == 0:
        return
    gaps = np.diff(np.unique(np.concatenate([kn, X])))
    if np.any(gaps < 1e-300):  # a denormal-length span: rejected by the constructor (tested below)
        with pytest.raises(ValueError, match="differ by less than"):
            edits.curve_from_homogeneous(p, *knots.refine_knots(kn, p, c._pw, X))
        return
    k2, cw = knots.refine_knots(kn, p, c._pw, X)
    k3, cw3 = kn, c._pw
    for x in X:
        k3, cw3 = knots.insert_knot(k3, p, cw3, x)
    np.testing.assert_array_equal(k2, k3)
    assert np.abs(cw - cw3).max() < 1e-12
    t = dense(c)
    assert np.abs(edits.curve_from_homogeneous(p, k2, cw)(t) - c(t)).max() < 1e-12


def test_denormal_span_is_rejected():
    """Knots 0 and 5e-324 (found by hypothesis): the basis recurrence divides by the span and
    overflows to NaN, so the constructor refuses the knot vector with a clear message."""
    from cadbridge.nurbs import NurbsCurve

    with pytest.raises(ValueError, match="differ by less than"):
        NurbsCurve(1, [0.0, 0.0, 5e-324, 1.0, 1.0], [[0, 0, 0], [1, 0, 0], [2, 0, 0]])


def test_insert_knot_matches_occ():
    """Reference: OpenCASCADE Geom_BSplineCurve.InsertKnot on the same rational curve: the
    same poles and weights (the refined representation is unique)."""
    from OCP.gp import gp_Pnt  # noqa: F401

    p, kn = 3, np.array([0, 0, 0, 0, 0.3, 0.5, 0.5, 1, 1, 1, 1.0])
    c = random_curve(p, kn, 3)
    g = occ_curve(c)
    g.InsertKnot(0.4, 2, 0.0, True)
    k2, cw = knots.insert_knot(kn, p, c._pw, 0.4, r=2)
    pts, w = knots.from_homogeneous(cw)
    assert g.NbPoles() == len(pts)
    occ_pts = np.array([[g.Pole(i).X(), g.Pole(i).Y(), g.Pole(i).Z()] for i in range(1, g.NbPoles() + 1)])
    occ_w = np.array([g.Weight(i) for i in range(1, g.NbPoles() + 1)])
    np.testing.assert_allclose(pts, occ_pts, atol=1e-12)
    np.testing.assert_allclose(w, occ_w, atol=1e-12)


def test_refine_surface_both_directions_invariant():
    """Reference: invariance of a random rational surface under refinement in u (axis 0) and
    v (axis 1) on a 30x30 grid, to 1e-12."""
    s = random_surface(np.random.default_rng(1), p=3, q=2, nu=7, nv=6)
    r = edits.refine_surface(s, [0.05, 0.5, 0.5, 0.77], [0.2, 0.2, 0.9])
    assert r.shape == (s.shape[0] + 4, s.shape[1] + 3)
    u, v = s.grid(30, 30)
    assert np.abs(r(u, v) - s(u, v)).max() < 1e-12


# ---------------------------------------------------------------------------- decomposition
def bernstein_eval(ctrl_w, s):
    p = ctrl_w.shape[0] - 1
    B = np.array([[comb(p, i) * x**i * (1 - x) ** (p - i) for i in range(p + 1)] for x in s])
    h = B @ ctrl_w
    return h[:, :-1] / h[:, -1:]


@HYP
@given(knot_vectors(), st.integers(0, 2**31 - 1))
def test_decompose_segments_are_bezier_pieces(pk, seed):
    """Reference: each segment evaluated with Bernstein polynomials on its break interval
    equals the curve there to 1e-12; K = number of distinct knots in the domain - 1."""
    p, kn = pk
    c = random_curve(p, kn, seed)
    breaks, segs = knots.decompose(kn, p, c._pw)
    np.testing.assert_array_equal(breaks, np.unique(kn))
    assert segs.shape == (len(breaks) - 1, p + 1, 4)
    s = np.linspace(0, 1, 11)
    for k in range(len(breaks) - 1):
        t = breaks[k] + s * (breaks[k + 1] - breaks[k])
        loc = (t - breaks[k]) / (breaks[k + 1] - breaks[k])  # exact local parameter of t
        assert np.abs(bernstein_eval(segs[k], loc) - c(t)).max() < 1e-12


def test_decompose_axis_1_surface():
    """Reference: decomposing a surface along v (axis=1) equals decomposing each row of
    control points separately (trailing/leading dims are independent)."""
    s = random_surface(np.random.default_rng(2), p=2, q=3, nu=5, nv=7)
    br, segs = knots.decompose(s.knots_v, 3, s._pw, axis=1)
    assert segs.shape == (len(br) - 1, 5, 4, 4)
    for i in range(5):
        _, row = knots.decompose(s.knots_v, 3, s._pw[i])
        np.testing.assert_allclose(segs[:, i], row, atol=1e-15)


# ---------------------------------------------------------------------------- elevation
@HYP
@given(knot_vectors(max_degree=4), st.integers(0, 2**31 - 1), st.integers(1, 3))
def test_elevate_degree_invariant_and_multiplicities(pk, seed, t):
    """Reference: invariance at 201 parameters (1e-12 x size) and P&T's multiplicity rule:
    every interior knot of multiplicity s gets s + t, the ends p + t + 1."""
    p, kn = pk
    c = random_curve(p, kn, seed)
    e = edits.elevate_curve(c, t)
    assert e.degree == p + t
    for x in np.unique(kn[p + 1 : -p - 1]):
        assert mult(e.knots, x) == mult(kn, x) + t
    assert mult(e.knots, kn[0]) == p + t + 1 and mult(e.knots, kn[-1]) == p + t + 1
    tt = dense(c)
    assert np.abs(e(tt) - c(tt)).max() < 1e-11


def test_elevate_matches_occ_increase_degree():
    """Reference: OpenCASCADE Geom_BSplineCurve.IncreaseDegree on the same rational curve:
    identical knots/multiplicities, poles and weights to 1e-12."""
    p, kn = 3, np.array([0, 0, 0, 0, 0.25, 0.5, 0.5, 0.8, 1, 1, 1, 1.0])
    c = random_curve(p, kn, 11)
    g = occ_curve(c)
    g.IncreaseDegree(5)
    e = edits.elevate_curve(c, 2)
    occ_knots = np.concatenate([[g.Knot(i)] * g.Multiplicity(i) for i in range(1, g.NbKnots() + 1)])
    np.testing.assert_allclose(e.knots, occ_knots, atol=1e-15)
    occ_pts = np.array([[g.Pole(i).X(), g.Pole(i).Y(), g.Pole(i).Z()] for i in range(1, g.NbPoles() + 1)])
    occ_w = np.array([g.Weight(i) for i in range(1, g.NbPoles() + 1)])
    # OCC normalises weights differently only by a common factor
    np.testing.assert_allclose(e.control_points, occ_pts, atol=1e-12)
    np.testing.assert_allclose(e.weights / e.weights[0], occ_w / occ_w[0], atol=1e-12)


def test_elevate_surface_invariant():
    """Reference: invariance of a random rational surface elevated by (1, 2), 30x30 grid."""
    s = random_surface(np.random.default_rng(4), p=2, q=3, nu=6, nv=6)
    e = edits.elevate_surface(s, 1, 2)
    assert (e.degree_u, e.degree_v) == (3, 5)
    u, v = s.grid(30, 30)
    assert np.abs(e(u, v) - s(u, v)).max() < 1e-12


# ---------------------------------------------------------------------------- parametrisation
def test_restrict_unclamped_and_subrange():
    """Reference: invariance: an unclamped curve restricted to a sub-range [0.3, 0.7] of its
    domain is clamped and equals the original there to 1e-12."""
    p = 3
    kn = np.linspace(0, 1, 12)  # unclamped, domain [kn[3], kn[8]]
    c = random_curve(p, kn, 5)
    r = edits.restrict_curve(c, 0.3, 0.7)
    assert mult(r.knots, 0.3) == p + 1 and mult(r.knots, 0.7) == p + 1
    t = np.linspace(0.3, 0.7, 101)
    assert np.abs(r(t) - c(t)).max() < 1e-12
    full = edits.restrict_curve(c)
    t = dense(c)
    assert np.abs(full(t) - c(t)).max() < 1e-12


def test_reverse_and_reparametrize():
    """Reference: C_rev(a + b - t) = C(t) and C_rep(c + (t - a)(d - c)/(b - a)) = C(t)."""
    c = random_curve(3, np.array([0, 0, 0, 0, 0.4, 0.4, 1.5, 2, 2, 2, 2.0]), 8)
    t = dense(c)
    rv = edits.reverse_curve(c)
    assert np.abs(rv(2.0 - t) - c(t)).max() < 1e-12
    rp = edits.reparametrize_curve(c, (-1.0, 5.0))
    assert rp.domain == (-1.0, 5.0)
    assert np.abs(rp(-1.0 + t * 3.0) - c(t)).max() < 1e-12


def test_make_compatible():
    """Reference: after make_compatible all curves share degree and knot vector on [0, 1]
    and each equals its original under the affine parameter map, to 1e-12."""
    a = random_curve(2, np.array([1, 1, 1, 1.5, 2, 2, 2.0]), 1)
    b = random_curve(3, np.array([0, 0, 0, 0, 0.3, 0.3, 1, 1, 1, 1.0]), 2, rational=False)
    ca, cb = edits.make_compatible([a, b])
    assert ca.degree == cb.degree == 3
    np.testing.assert_array_equal(ca.knots, cb.knots)
    s = np.linspace(0, 1, 101)
    assert np.abs(ca(s) - a(1 + s)).max() < 1e-12
    assert np.abs(cb(s) - b(s)).max() < 1e-12
    np.testing.assert_array_equal(knots.merge_knots([[0, 0, 1, 1], [0, 0.5, 0.5, 1]]), [0, 0, 0.5, 0.5, 1, 1])


# ---------------------------------------------------------------------------- Bézier patches, boxes
def test_bezier_patches_reproduce_surface():
    """Reference: each Bézier patch (tensor Bernstein) equals the surface on its uv box."""
    s = random_surface(np.random.default_rng(6), p=3, q=2, nu=6, nv=5)
    boxes, pts, w = edits.bezier_patches(s)
    assert pts.shape[1:] == (4, 3, 3)
    x = np.linspace(0, 1, 7)
    Bu = np.array([[comb(3, i) * a**i * (1 - a) ** (3 - i) for i in range(4)] for a in x])
    Bv = np.array([[comb(2, j) * a**j * (1 - a) ** (2 - j) for j in range(3)] for a in x])
    for k in range(len(boxes)):
        h = np.einsum("ai,bj,ijc->abc", Bu, Bv, np.concatenate([pts[k] * w[k][..., None], w[k][..., None]], -1))
        got = (h[..., :3] / h[..., 3:]).reshape(-1, 3)
        uu, vv = np.meshgrid(boxes[k, 0] + x * (boxes[k, 1] - boxes[k, 0]), boxes[k, 2] + x * (boxes[k, 3] - boxes[k, 2]), indexing="ij")
        assert np.abs(got - s(uu.ravel(), vv.ravel())).max() < 1e-12


@pytest.mark.parametrize("domain", [None, (0.2, 0.45, 0.6, 0.95)])
def test_tight_bbox(domain):
    """Reference: the tight box lies inside the control-net box and contains 100x100
    samples of the surface (restricted to ``domain``); for a sub-domain it is smaller."""
    s = random_surface(np.random.default_rng(9), p=3, q=3, nu=8, nv=8)
    if domain is not None:
        s = s.with_domain(domain)
    tb = edits.tight_bbox(s)
    bb = s.bbox()
    assert np.all(tb[0] >= bb[0] - 1e-15) and np.all(tb[1] <= bb[1] + 1e-15)
    u, v = s.grid(100, 100)
    P = s(u, v)
    assert np.all(P >= tb[0] - 1e-12) and np.all(P <= tb[1] + 1e-12)
    if domain is not None:
        assert np.prod(tb[1] - tb[0]) < 0.5 * np.prod(bb[1] - bb[0])


def test_curve_tight_bbox():
    """Reference: the tight box of a curve with a sub-domain contains 2000 samples and lies
    inside the control-polygon box."""
    c = random_curve(3, np.array([0, 0, 0, 0, 0.2, 0.4, 0.6, 0.8, 1, 1, 1, 1.0]), 12)
    c = NurbsCurve(c.degree, c.knots, c.control_points, c.weights, (0.25, 0.55))
    tb = edits.curve_tight_bbox(c)
    P = c(np.linspace(0.25, 0.55, 2000))
    assert np.all(P >= tb[0] - 1e-12) and np.all(P <= tb[1] + 1e-12)
    bb = c.bbox()
    assert np.all(tb[0] >= bb[0]) and np.all(tb[1] <= bb[1])
