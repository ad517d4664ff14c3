"""Tests of the existing NURBS engine (basis.py, surface.py, curve.py).

References: exact identities of B-spline bases (partition of unity, derivative sum zero),
central finite differences, OpenCASCADE (OCP Geom_BSplineSurface / Geom_BSplineCurve built
from the same poles, weights and knots) and the analytic sphere.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cadbridge.nurbs import NurbsCurve, NurbsSurface
from cadbridge.nurbs.basis import basis_funs, ders1_basis_one, ders_basis_funs, find_span, find_span_one

occ = pytest.importorskip("OCP")
from OCP.Geom import Geom_BSplineCurve, Geom_BSplineSurface  # noqa: E402
from OCP.gp import gp_Pnt, gp_Vec  # noqa: E402
from OCP.TColgp import TColgp_Array1OfPnt, TColgp_Array2OfPnt  # noqa: E402
from OCP.TColStd import TColStd_Array1OfInteger, TColStd_Array1OfReal, TColStd_Array2OfReal  # noqa: E402

HYP = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


# ---------------------------------------------------------------------------- helpers
@st.composite
def knot_vectors(draw, max_degree: int = 5):
    """(p, clamped knots): degree 1..max_degree, up to 5 interior knots of multiplicity 1..p."""
    p = draw(st.integers(1, max_degree))
    k = draw(st.integers(0, 5))
    vals = sorted(set(round(x, 6) for x in draw(st.lists(st.floats(0.02, 0.98), min_size=k, max_size=k))))
    mults = [draw(st.integers(1, p)) for _ in vals]
    a = draw(st.floats(-3, 3))
    L = draw(st.floats(0.5, 4))
    inner = np.repeat(a + L * np.array(vals, dtype=float), mults)
    return p, np.concatenate([[a] * (p + 1), inner, [a + L] * (p + 1)])


def random_surface(rng, p=3, q=2, nu=6, nv=5, rational=True):
    ku = np.concatenate([[0] * (p + 1), np.sort(rng.uniform(0.1, 0.9, nu - p - 1)), [1] * (p + 1)])
    kv = np.concatenate([[0] * (q + 1), np.sort(rng.uniform(0.1, 0.9, nv - q - 1)), [1] * (q + 1)])
    cp = rng.uniform(-1, 1, (nu, nv, 3))
    w = rng.uniform(0.5, 2.0, (nu, nv)) if rational else None
    return NurbsSurface(p, q, ku, kv, cp, w)


from cadbridge.verify.reference import occ_bspline_curve as occ_curve  # noqa: E402
from cadbridge.verify.reference import occ_bspline_surface as occ_surface  # noqa: E402


def occ_d2(g, u, v):
    P, D1U, D1V, D2U, D2V, D2UV = gp_Pnt(), gp_Vec(), gp_Vec(), gp_Vec(), gp_Vec(), gp_Vec()
    g.D2(float(u), float(v), P, D1U, D1V, D2U, D2V, D2UV)
    xyz = lambda a: np.array([a.X(), a.Y(), a.Z()])  # noqa: E731
    return xyz(P), xyz(D1U), xyz(D1V), xyz(D2U), xyz(D2V), xyz(D2UV)


# ---------------------------------------------------------------------------- basis identities
@HYP
@given(knot_vectors())
def test_partition_of_unity_including_right_end(pk):
    """Reference: sum_i N_i,p(u) = 1 on the whole domain, the right end included (1e-14);
    a curve at the right end equals its last control point (no lost basis function)."""
    p, knots = pk
    n = len(knots) - p - 1
    u = np.concatenate([np.linspace(knots[0], knots[-1], 97), np.unique(knots)])
    N = basis_funs(find_span(knots, p, u), u, p, knots)
    assert np.abs(N.sum(axis=1) - 1.0).max() < 1e-14
    assert np.all(N >= -1e-15)
    cp = np.random.default_rng(0).uniform(-1, 1, (n, 3))
    c = NurbsCurve(p, knots, cp)
    np.testing.assert_allclose(c(np.array([knots[-1], knots[0]])), cp[[-1, 0]], atol=1e-14)


@HYP
@given(knot_vectors())
def test_basis_derivatives_sum_to_zero(pk):
    """Reference: d^k/du^k sum_i N_i,p = 0 for k >= 1 (derivative of a constant)."""
    p, knots = pk
    u = np.linspace(knots[0], knots[-1], 61)
    D = ders_basis_funs(find_span(knots, p, u), u, p, knots, p + 1)
    scale = np.abs(D).max(axis=(0, 2)) + 1.0
    for k in range(1, p + 2):
        assert np.abs(D[:, k].sum(axis=1)).max() <= 1e-12 * scale[k]
    assert np.all(D[:, p + 1 :] == 0)


# ---------------------------------------------------------------------------- derivatives
def _span_interior_params(knots, p, rng, n, margin):
    vals = np.unique(knots)
    spans = [(a, b) for a, b in zip(vals[:-1], vals[1:]) if b - a > 4 * margin]
    idx = rng.integers(0, len(spans), n)
    lo = np.array([spans[i][0] for i in idx]) + margin
    hi = np.array([spans[i][1] for i in idx]) - margin
    return rng.uniform(lo, hi)


@pytest.mark.parametrize("seed", range(4))
def test_rational_surface_derivatives_vs_finite_differences(seed):
    """Reference: central finite differences of S (1st: h=1e-5, 2nd and mixed: h=1e-4),
    at parameters inside knot spans (where S is smooth)."""
    rng = np.random.default_rng(seed)
    s = random_surface(rng, p=3, q=3, nu=7, nv=6)
    u = _span_interior_params(s.knots_u, 3, rng, 40, 1e-3)
    v = _span_interior_params(s.knots_v, 3, rng, 40, 1e-3)
    d = s.derivatives(u, v, order=2)
    f = s.evaluate
    h = 1e-5
    su = (f(u + h, v) - f(u - h, v)) / (2 * h)
    sv = (f(u, v + h) - f(u, v - h)) / (2 * h)
    h = 1e-4
    suu = (f(u + h, v) - 2 * f(u, v) + f(u - h, v)) / h**2
    svv = (f(u, v + h) - 2 * f(u, v) + f(u, v - h)) / h**2
    suv = (f(u + h, v + h) - f(u + h, v - h) - f(u - h, v + h) + f(u - h, v - h)) / (4 * h * h)
    for got, ref, tol in [
        (d[:, 1, 0], su, 1e-7),
        (d[:, 0, 1], sv, 1e-7),
        (d[:, 2, 0], suu, 1e-4),
        (d[:, 0, 2], svv, 1e-4),
        (d[:, 1, 1], suv, 1e-4),
    ]:
        scale = np.abs(ref).max()
        assert np.abs(got - ref).max() <= tol * scale


@HYP
@given(knot_vectors(), knot_vectors(), st.integers(0, 2**31 - 1), st.booleans())
def test_surface_vs_occ_d2(pku, pkv, seed, rational):
    """Reference: OpenCASCADE Geom_BSplineSurface.D2 built from the same poles, weights,
    knots and multiplicities: positions to 1e-12 x size, derivatives 1e-8 relative."""
    (p, ku), (q, kv) = pku, pkv
    rng = np.random.default_rng(seed)
    nu, nv = len(ku) - p - 1, len(kv) - q - 1
    cp = rng.uniform(-1, 1, (nu, nv, 3))
    w = rng.uniform(0.3, 3.0, (nu, nv)) if rational else None
    s = NurbsSurface(p, q, ku, kv, cp, w)
    g = occ_surface(s)
    u = np.concatenate([rng.uniform(ku[0], ku[-1], 12), [ku[0], ku[-1], ku[-1]]])
    v = np.concatenate([rng.uniform(kv[0], kv[-1], 12), [kv[0], kv[-1], kv[0]]])
    d = s.derivatives(u, v, order=2)
    size = np.linalg.norm(np.ptp(cp.reshape(-1, 3), axis=0))
    for i in range(len(u)):
        P, Du, Dv, Duu, Dvv, Duv = occ_d2(g, u[i], v[i])
        assert np.linalg.norm(d[i, 0, 0] - P) <= 1e-12 * size
        for got, ref in [(d[i, 1, 0], Du), (d[i, 0, 1], Dv), (d[i, 2, 0], Duu), (d[i, 0, 2], Dvv), (d[i, 1, 1], Duv)]:
            # at a knot of low continuity both sides are valid limits; OCC and we pick the same
            # (right-hand) span except at the right end, where both take the last span
            ref_scale = max(np.linalg.norm(ref), np.linalg.norm(d[i, 1:, 1:]), 1.0)
            assert np.linalg.norm(got - ref) <= 1e-8 * ref_scale


@HYP
@given(knot_vectors(), st.integers(0, 2**31 - 1))
def test_curve_vs_occ(pk, seed):
    """Reference: OpenCASCADE Geom_BSplineCurve.D2 from the same data (rational 3D curve)."""
    p, kn = pk
    rng = np.random.default_rng(seed)
    n = len(kn) - p - 1
    c = NurbsCurve(p, kn, rng.uniform(-1, 1, (n, 3)), rng.uniform(0.3, 3.0, n))
    g = occ_curve(c)
    t = np.concatenate([rng.uniform(kn[0], kn[-1], 15), [kn[0], kn[-1]]])
    d = c.derivatives(t, order=2)
    for i, ti in enumerate(t):
        P, V1, V2 = gp_Pnt(), gp_Vec(), gp_Vec()
        g.D2(float(ti), P, V1, V2)
        ref = np.array([[P.X(), P.Y(), P.Z()], [V1.X(), V1.Y(), V1.Z()], [V2.X(), V2.Y(), V2.Z()]])
        sc = max(np.abs(ref).max(), 1.0)
        assert np.abs(d[i, 0] - ref[0]).max() <= 1e-12 * 4
        assert np.abs(d[i, 1:] - ref[1:]).max() <= 1e-8 * sc


def test_geomdl_agrees_on_rational_surface():
    """Reference: geomdl (NURBS-Python) evaluation of the same rational surface."""
    geomdl = pytest.importorskip("geomdl")
    from geomdl import NURBS

    rng = np.random.default_rng(7)
    s = random_surface(rng, p=3, q=2, nu=6, nv=5)
    g = NURBS.Surface()
    g.degree_u, g.degree_v = 3, 2
    nu, nv = s.shape
    pw = s._pw.reshape(-1, 4)  # geomdl takes weighted points (w x, w y, w z, w), v fastest
    g.set_ctrlpts(pw.tolist(), nu, nv)
    g.knotvector_u = list(s.knots_u)
    g.knotvector_v = list(s.knots_v)
    uv = rng.uniform(0, 1, (30, 2))
    ref = np.array(g.evaluate_list(uv.tolist()))
    np.testing.assert_allclose(s(uv[:, 0], uv[:, 1]), ref, atol=1e-12)


# ---------------------------------------------------------------------------- degenerate normals
def test_sphere_pole_normal_is_axis_and_flagged():
    """Reference: the analytic sphere; at the poles (collapsed rows of the revolved NURBS)
    the limit normal is -+z (our sphere_patch has Su x Sv towards the centre) and the points
    are flagged degenerate; elsewhere normals are -P/R to 1e-12 rad."""
    from cadbridge.nurbs.construct import sphere_patch

    R = 2.5
    s = sphere_patch(R)
    u0, u1, v0, v1 = s.domain
    v = np.linspace(v0, v1, 13)
    n, flags = s.normal(np.full_like(v, u0), v, return_flags=True)
    assert flags.all()
    np.testing.assert_allclose(n, np.tile([0, 0, 1.0], (len(v), 1)), atol=1e-12)
    n, flags = s.normal(np.full_like(v, u1), v, return_flags=True)
    assert flags.all()
    np.testing.assert_allclose(n, np.tile([0, 0, -1.0], (len(v), 1)), atol=1e-12)
    u, vv = s.grid(15, 17)
    inner = (u > u0) & (u < u1)
    n, flags = s.normal(u[inner], vv[inner], return_flags=True)
    assert not flags.any()
    ref = -s(u[inner], vv[inner]) / R
    ang = np.arctan2(np.linalg.norm(np.cross(n, ref), axis=1), np.sum(n * ref, axis=1))
    assert ang.max() < 1e-12


# ---------------------------------------------------------------------------- compiled kernels
@pytest.mark.parametrize("rational", [True, False])
@pytest.mark.parametrize("p,q", [(1, 1), (2, 2), (3, 3), (5, 5), (1, 5), (4, 2)])
def test_first_order_kernel_bit_identical_to_generic_and_numpy(p, q, rational):
    """Reference: the generic order-d numba kernel (_ders_range with d = 0 and 1) and the numpy
    path (_derivatives_numpy), which use the same sums in the same order: the specialised
    order-0/1 kernel must reproduce both exactly, at random (u, v), at the domain ends and on
    interior knots (multiple knots included), serial and parallel."""
    import cadbridge.nurbs.surface as surf

    rng = np.random.default_rng(100 * p + 10 * q + rational)
    nu, nv = p + 7, q + 6

    def knots(deg, n):
        inner = np.sort(rng.uniform(0.05, 0.95, n - deg - 1))
        inner[1 : min(deg, 3)] = inner[0]  # a knot of multiplicity min(degree, 3)
        return np.concatenate([[0.0] * (deg + 1), inner, [1.0] * (deg + 1)])

    ku, kv = knots(p, nu), knots(q, nv)
    w = rng.uniform(0.3, 3.0, (nu, nv)) if rational else None
    s = NurbsSurface(p, q, ku, kv, rng.uniform(-1, 1, (nu, nv, 3)), w)
    n = surf._PARALLEL_MIN + 777  # over the threshold: the parallel kernel
    u = rng.uniform(0, 1, n)
    v = rng.uniform(0, 1, n)
    u[:6] = [0.0, 1.0, ku[p + 1], ku[nu - 1], 1.0, 0.0]
    v[:6] = [1.0, 0.0, kv[q + 1], kv[nv - 1], 0.0, 0.5]
    for d in (0, 1):
        got = s.derivatives(u, v, order=d)  # parallel specialised kernel
        small = s.derivatives(u[:500], v[:500], order=d)  # serial specialised kernel
        generic = np.empty_like(got)
        surf._ders_range(s._pw, s.knots_u, s.knots_v, p, q, d, s.rational, u, v, generic, 0, n, surf._binomials(d))
        ref = s._derivatives_numpy(u, v, order=d)
        assert np.array_equal(got, generic)
        assert np.array_equal(small, generic[:500])
        assert np.array_equal(got, ref)
    assert np.array_equal(s.evaluate(u, v), got[:, 0, 0])


@numba.njit
def _spans_and_d1_basis(knots, p, n_ctrl, x, spans, out):  # pragma: no cover - compiled
    """find_span_one and ders1_basis_one at each x: spans (N,), out (N, 2, p+1)."""
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    nb = np.empty(p + 1)
    for t in range(x.shape[0]):
        spans[t] = find_span_one(knots, p, n_ctrl, x[t])
        ders1_basis_one(spans[t], x[t], p, knots, left, right, nb, out[t])


@HYP
@given(knot_vectors(), st.integers(0, 2**31 - 1))
def test_compiled_span_and_first_derivative_basis_match_numpy(pk, seed):
    """Reference: the numpy find_span / ders_basis_funs (A2.1 / A2.3) on the same parameters:
    find_span_one gives the same spans (knots, domain ends and parameters
    outside the domain included) and ders1_basis_one the same values and first derivatives
    bit for bit."""
    p, knots = pk
    n_ctrl = len(knots) - p - 1
    rng = np.random.default_rng(seed)
    a, b = knots[0], knots[-1]
    x = np.concatenate([rng.uniform(a, b, 50), np.unique(knots), [a - 1.0, b + 1.0]])
    spans = np.empty(len(x), dtype=np.int64)
    out = np.empty((len(x), 2, p + 1))
    _spans_and_d1_basis(knots, p, n_ctrl, x, spans, out)
    ref_span = find_span(knots, p, x)
    assert np.array_equal(spans, ref_span)
    assert np.array_equal(out, ders_basis_funs(ref_span, x, p, knots, 1))


# ---------------------------------------------------------------------------- low-degree first-order kernel
def _occ_d1(g, u, v):
    """OCC Geom_BSplineSurface.D1 at each (u, v): (N, 3, 3) rows S, Su, Sv."""
    P, DU, DV = gp_Pnt(), gp_Vec(), gp_Vec()
    out = np.empty((len(u), 3, 3))
    for k, (a, b) in enumerate(zip(u.tolist(), v.tolist())):
        g.D1(a, b, P, DU, DV)
        out[k] = (P.Coord(), DU.Coord(), DV.Coord())
    return out


@pytest.mark.parametrize("rational", [True, False])
@pytest.mark.parametrize("case", ["bezier22", "deg11", "deg12", "deg21", "deg33", "deg55", "deg2_many_knots"])
def test_first_derivatives_vs_occ_d1(case, rational):
    """Reference: OpenCASCADE Geom_BSplineSurface.D1 from the same poles, weights and knots
    (cadbridge.verify.reference.occ_bspline_surface). Cases of the specialised paths of the
    first-order kernel: degrees 1 and 2 written out in scalars (2 x 2 Bezier biquadratic with
    double knots at 0.5, the layout of Herrero Adan's appendix D surfaces; degree 1; mixed
    1/2), the generic degrees 3 and 5, spans found by counting (<= 8 interior knots) and by
    bisection (20 interior knots). Points at random, on every knot and at the domain ends,
    serial (N < 16384) and parallel kernels: S within 1e-13 x net size, Su and Sv within 1e-12
    of the largest derivative."""
    import cadbridge.nurbs.surface as surf

    rng = np.random.default_rng([sum(map(ord, case)), rational])
    if case == "bezier22":
        p = q = 2
        ku = kv = np.array([0.0, 0.0, 0.0, 0.5, 0.5, 1.0, 1.0, 1.0])
    else:
        p, q = (2, 2) if case == "deg2_many_knots" else (int(case[3]), int(case[4]))
        n_in = 20 if case == "deg2_many_knots" else 4

        def knots(deg):
            return np.concatenate([[0.0] * (deg + 1), np.sort(rng.uniform(0.05, 0.95, n_in)), [1.0] * (deg + 1)])

        ku, kv = knots(p), knots(q)
    nu, nv = len(ku) - p - 1, len(kv) - q - 1
    w = rng.uniform(0.3, 3.0, (nu, nv)) if rational else None
    s = NurbsSurface(p, q, ku, kv, rng.uniform(-1, 1, (nu, nv, 3)), w)
    g = occ_surface(s)
    for n in (200, surf._PARALLEL_MIN + 100):
        u = rng.uniform(0, 1, n)
        v = rng.uniform(0, 1, n)
        u[: len(ku)] = ku
        v[: len(kv)] = kv
        u[-2:], v[-2:] = [0.0, 1.0], [1.0, 0.0]
        d = s.derivatives(u, v, order=1)
        m = np.r_[0 : len(ku) + len(kv), n - 200 : n]  # knots, ends and 200 random points per size
        ref = _occ_d1(g, u[m], v[m])
        size = np.ptp(s.control_points.reshape(-1, 3), axis=0).max()
        assert np.abs(d[m, 0, 0] - ref[:, 0]).max() <= 1e-13 * size
        got = np.stack([d[m, 1, 0], d[m, 0, 1]], axis=1)
        assert np.abs(got - ref[:, 1:]).max() <= 1e-12 * np.abs(ref[:, 1:]).max()
