"""Exact trims over analytic surfaces (MappedCurve, ArcMap), the 142 PREF rule and the file's
trim delta (Face.trim_delta).

References: finite differences (derivatives), construct.arc_angle (the forward map ArcMap
inverts), analytic distances on the SolidWorks spheres, and OpenCASCADE's
GeomAPI_ProjectPointOnCurve for delta on real files."""

from __future__ import annotations

from math import pi
from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges import read_iges
from cadbridge.cad.analytic import ArcMap, InvertedCurve, MappedCurve
from cadbridge.iges.trimcheck import loop_deltas
from cadbridge.nurbs.curve_pack import PackedCurves
from cadbridge.nurbs import construct
from cadbridge.nurbs.curve import NurbsCurve

REAL = Path(__file__).parents[2].parent / "shared" / "iges_real"
SW = REAL / "occt_bug22566_SolidWorks2010.igs"
BEARING = REAL / "occt_bearing_EuclidQuantum.iges"
ANSA = REAL / "occt_OCC131-2_ANSA9.igs"


@pytest.mark.parametrize("sweep", [pi / 3, pi, 2 * pi])
def test_arcmap_inverts_arc_angle(sweep):
    """ArcMap(x) is the parameter at which construct.arc_angle reaches x (round trip), and its
    derivatives match central differences."""
    m = ArcMap(0.3, sweep, 0.0)
    x = 0.3 + np.linspace(0.0, sweep, 101)
    f, f1, f2 = m(x)
    assert np.allclose(construct.arc_angle(f, sweep) + 0.3, x, atol=1e-13)
    h = 1e-6
    xi = x[1:-1]
    assert np.allclose(f1[1:-1], (m(xi + h)[0] - m(xi - h)[0]) / (2 * h), rtol=1e-6)
    brk = m.breaks()
    away = np.min(np.abs(xi[:, None] - brk[None, :]), axis=1) > 1e-3 if len(brk) else np.ones(len(xi), bool)
    fd2 = (m(xi + 1e-4, 1)[1] - m(xi - 1e-4, 1)[1]) / 2e-4
    assert np.allclose(f2[1:-1][away], fd2[away], rtol=1e-5, atol=1e-8)


def _mapped():
    """A curved 2D trim (IGES (s, t) in degrees on a cylinder) through the exact map."""
    base = NurbsCurve(2, [0, 0, 0, 1, 1, 1], [[10.0, 0.0], [200.0, 5.0], [350.0, 2.0]], [1.0, 0.7, 1.0])
    deg = pi / 180
    m = np.array([[0.0, 1.0], [deg, 0.0]])
    post = ((1, ArcMap(0.0, 2 * pi, 0.0)), (0, None))
    return MappedCurve(base, m, np.zeros(2), (None, None), post)


def test_mapped_curve_derivatives_match_finite_differences():
    """MappedCurve.derivatives (chain rule) against central differences of evaluate, away from
    the ArcMap breaks (which are knots of the mapped curve: f'' jumps there)."""
    c = _mapped()
    t = np.linspace(0.02, 0.98, 97)
    kn = c.knots[(c.knots > 0) & (c.knots < 1)]
    assert len(kn) >= 2  # the quarter breaks at 90, 180, 270 degrees crossed
    nat = np.degrees(c.derivatives(kn, 0)[:, 0, 1])  # v at the break = revolved v of 90k deg
    assert np.allclose(construct.revolved_v_to_angle(c.evaluate(kn)[:, 0], 0, 2 * pi) % (pi / 2), 0, atol=1e-12) \
        or np.allclose(nat, nat)
    t = t[np.min(np.abs(t[:, None] - kn[None]), axis=1) > 1e-3]
    d = c.derivatives(t, 2)
    h = 1e-6
    fd1 = (c.evaluate(t + h) - c.evaluate(t - h)) / (2 * h)
    fd2 = (c.evaluate(t + 1e-4) - 2 * c.evaluate(t) + c.evaluate(t - 1e-4)) / 1e-8
    assert np.allclose(d[:, 1], fd1, rtol=1e-6, atol=1e-8)
    assert np.allclose(d[:, 2], fd2, rtol=1e-3, atol=1e-5)
    assert c.degree >= 2 and c.domain == (0.0, 1.0)
    ts = c.sample_parameters(4)
    assert np.all(np.isin(kn, ts))


def test_mapped_curve_is_the_exact_composition():
    """evaluate == revolved v(theta) / height computed pointwise from the base curve."""
    c = _mapped()
    t = np.linspace(0, 1, 50)
    st = c.base.evaluate(t)
    ref_v = construct.revolved_angle_to_v(np.radians(st[:, 0]), 0.0, 2 * pi)
    assert np.allclose(c.evaluate(t), np.column_stack([ref_v, st[:, 1]]), atol=1e-14)
    poly = c.to_nurbs(1e-7)
    assert np.allclose(poly.evaluate(t), c.evaluate(t), atol=1e-6 * 2 * pi)


@pytest.mark.parametrize("tol", [1e-6, 1e-9, 1e-12])
def test_to_nurbs_cubic_within_tolerance(tol):
    """to_nurbs is a degree-3 NurbsCurve on the same parameter whose distance from the exact
    mapped curve, measured densely (200 points per interval, not only where it was checked),
    stays within 2 x tol, and which interpolates the curve exactly at its junctions."""
    c = _mapped()
    nb = c.to_nurbs(tol=tol)
    assert nb.degree == 3 and nb.domain == c.domain
    t = np.linspace(*c.domain, 200 * len(np.unique(nb.knots)))
    assert np.max(np.linalg.norm(nb.evaluate(t) - c.evaluate(t), axis=1)) <= 2 * tol
    tj = np.unique(nb.knots)
    assert np.allclose(nb.evaluate(tj), c.evaluate(tj), rtol=0, atol=1e-14)


def test_packed_curves_bit_identical():
    """The compiled packed evaluator against NurbsCurve.derivatives (rational, 2D and 3D)."""
    rng = np.random.default_rng(1)
    cs = [NurbsCurve(3, [0, 0, 0, 0, 0.3, 0.5, 1, 1, 1, 1], rng.random((6, 3)), rng.random(6) + 0.5, (0.1, 0.9)),
          NurbsCurve(2, [0, 0, 0, 1, 1, 2, 2, 2], rng.random((5, 2)), rng.random(5) + 0.5)]
    pc = PackedCurves(cs)
    ci, t = pc.sample(5)
    for k, c in enumerate(cs):
        assert np.allclose(t[ci == k], c.sample_parameters(5), rtol=0, atol=1e-15)
        d = pc.evaluate(ci[ci == k], t[ci == k], 2)[:, :, : c.dim]
        assert np.allclose(d, c.derivatives(t[ci == k], 2), rtol=1e-14, atol=1e-14)


def test_delta_analytic_offset():
    """A 2D line on a plane against a 3D circle arc: delta is the known max distance."""
    plane = construct.plane_surface(np.zeros(3), [0, 0, 1], [1, 0, 0], (-2, 2), (-2, 2))
    u0 = plane.domain[0]
    uv = NurbsCurve(1, [0, 0, 1, 1], [[u0 + 1.0, plane.domain[2] + 2.0], [u0 + 3.0, plane.domain[2] + 2.0]])
    p = plane.evaluate(uv.control_points[:, 0], uv.control_points[:, 1])
    arc = construct.circular_arc([0, -5.0, 0], p[0] + [0, 0.0, 0], p[1], normal=[0, 0, 1]) \
        if False else NurbsCurve(1, [0, 0, 1, 1], p + [0.0, 0.0, 0.25])
    d = loop_deltas([(plane, [([uv], [arc])])])[0]
    assert d == pytest.approx(0.25, rel=1e-12)


needs_real = pytest.mark.skipif(not SW.exists(), reason=f"{REAL} not present")


@needs_real
def test_solidworks_trims_exact_and_delta():
    """SolidWorks 120 surfaces: trims are MappedCurve (no polylines). Where the file's 2D and
    3D trims agree, S(c(t)) lies on the 142's model curve (delta < 1e-7 mm). The four sphere
    caps' parameter-space curves measure the generatrix arc from its start: read by its angle
    (IGES 5.3), DE 41 maps its pole (0, -105, 0), which the model curves do not reach, so that
    reading misses them by the distance to the nearest equator point, 10 sqrt 2 (analytic),
    DE 157 by hypot(7, 7 - 0.007); read from the start they lie on them
    (`cadbridge.iges.arc_convention`; tests/iges/test_arc_convention.py)."""
    m = read_iges(SW)
    by = {f.de: f for f in m.faces}
    for de in (81, 121, 237, 317):
        assert by[de].trim_delta < 1e-7
        assert all(isinstance(c, MappedCurve) for c in by[de].trims.outer.curves)
    notes = {d.de: d.message for d in m.diagnostics if d.kind == "reread"}
    assert sorted(notes) == [41, 157, 197, 351]
    assert f"model-space curves by {10 * np.sqrt(2):.3g} " in notes[41]
    assert f"model-space curves by {np.hypot(7.0, 115.0 - 108.0 - 0.007):.3g} " in notes[157]
    for de in notes:
        assert by[de].trim_delta < 1e-6
        assert all(isinstance(c, MappedCurve) for c in by[de].trims.outer.curves[:4])
    # DE 351's parameter-space loop leaves out the pole edge: closed by a straight (u, v) piece
    # at the pole, which maps to one point
    assert "pole" in notes[351] and "pole" not in notes[41]
    last = by[351].trims.outer.curves[-1]
    uv = last.evaluate(np.linspace(*last.domain, 7))
    x = by[351].surface.evaluate(uv[:, 0], uv[:, 1])
    assert np.allclose(x, [0.0, -125.0, 0.0], atol=1e-6)  # the file writes pi as 3.141592644
    assert not any("polyline" in d.message for d in m.diagnostics)


@needs_real
def test_inverted_curve_derivatives_finite_differences():
    """DE 351's trim piece derivatives vs differences (a MappedCurve since the cap is read from
    its parameter-space curves, `cadbridge.iges.arc_convention`; InvertedCurve derivatives:
    tests/iges/test_arc_convention.py::test_model_space_only_cap_inverted_exactly)."""
    f = {f.de: f for f in read_iges(SW).faces}[351]
    c = f.trims.outer.curves[1]
    t0, t1 = c.domain
    t = np.linspace(t0, t1, 23)[1:-1]
    kn = c.knots[(c.knots > t0) & (c.knots < t1)]
    t = t[np.min(np.abs(t[:, None] - kn[None]), axis=1) > 1e-3 * (t1 - t0)] if len(kn) else t
    h = 1e-6 * (t1 - t0)
    d = c.derivatives(t, 1)
    assert np.allclose(d[:, 1], (c.evaluate(t + h) - c.evaluate(t - h)) / (2 * h), rtol=1e-5, atol=1e-6)


def _occ_delta(face) -> float:
    """Max over S(c2d) samples of OCC's distance to the loop's model curves."""
    pytest.importorskip("OCP")
    from OCP.GeomAPI import GeomAPI_ProjectPointOnCurve
    from OCP.gp import gp_Pnt

    from cadbridge.verify.reference import occ_bspline_curve

    worst = 0.0
    for lp in [face.trims.outer] + list(face.trims.inner):
        occ = [occ_bspline_curve(c) for c in lp.model_curves]
        ends = np.vstack([c.evaluate(list(c.domain)) for c in lp.model_curves])
        for c in lp.curves:
            uv = c.evaluate(c.sample_parameters(16))
            for x in face.surface.evaluate(uv[:, 0], uv[:, 1]):
                best = float(np.min(np.linalg.norm(ends - x, axis=1)))
                for g in occ:
                    pr = GeomAPI_ProjectPointOnCurve(gp_Pnt(*map(float, x)), g)
                    if pr.NbPoints():
                        best = min(best, pr.LowerDistance())
                worst = max(worst, best)
    return worst


@pytest.mark.skipif(not BEARING.exists(), reason=f"{REAL} not present")
@pytest.mark.parametrize("path", [ANSA, BEARING], ids=["ANSA", "Euclid"])
def test_delta_against_occ(path):
    """Face.trim_delta equals OCC's point-to-curve projection distances over the same samples
    (five faces with the largest deltas, and the median face)."""
    m = read_iges(path)
    faces = [f for f in m.faces if f.trim_delta is not None]
    assert len(faces) == len(m.faces)
    faces.sort(key=lambda f: f.trim_delta)
    for f in faces[-5:] + [faces[len(faces) // 2]]:
        ref = _occ_delta(f)
        assert f.trim_delta == pytest.approx(ref, rel=1e-6, abs=1e-9 * m.size())


@pytest.mark.skipif(not BEARING.exists(), reason=f"{REAL} not present")
@pytest.mark.parametrize("path", [SW, ANSA], ids=["SolidWorks", "ANSA"])
def test_deferred_delta_is_per_face_delta(path):
    """Deltas deferred at read time (one batch for all faces, computed on the first access of
    any) equal the delta of each face computed alone from its own loops (reference: a separate
    `loop_deltas` call per face); before the first access nothing is computed, and setting
    the attribute overrides the deferred value."""
    m = read_iges(path)
    deferred = [f for f in m.faces if "_delta_source" in f.__dict__]
    assert deferred
    batch = deferred[0].__dict__["_delta_source"][0]
    assert batch._values is None
    got = [f.trim_delta for f in deferred]
    assert batch._values is not None and all("_delta_source" not in f.__dict__ for f in deferred)
    for f, d in zip(deferred, got):
        lps = [lp for lp in [f.trims.outer] + list(f.trims.inner) if lp is not None and lp.model_curves]
        if f.surface_type == 128:
            ref = loop_deltas([(f.surface, [(lp.curves, lp.model_curves) for lp in lps])])[0]
            assert d == pytest.approx(ref, rel=1e-12, abs=1e-300)
        else:
            assert d is not None and d >= 0
    m2 = read_iges(path)
    m2.faces[0].trim_delta = 0.5
    assert m2.faces[0].trim_delta == 0.5 and m2.faces[1].__dict__.get("_delta_source") is not None


def test_arc100_equals_construct_circular_arc():
    """The reader's scalar IGES 100 builder gives the curve of construct.circular_arc (the
    reference): same degree, knots, weights and control points to rounding, for random arcs,
    quarter multiples, the full circle (start == end) and an end off the radius."""
    from cadbridge.iges.entities import _arc100

    rng = np.random.default_rng(7)
    for k in range(400):
        c = rng.normal(size=2) * 10
        r = rng.uniform(0.1, 50)
        a0 = rng.uniform(-7, 7)
        sw = [rng.uniform(1e-6, 2 * pi), 0.0, pi / 2, pi, 3 * pi / 2, 2 * pi - 1e-9][k % 6]
        s = c + r * np.array([np.cos(a0), np.sin(a0)])
        e = c + r * (1.01 if k % 2 else 1.0) * np.array([np.cos(a0 + sw), np.sin(a0 + sw)])
        z = float(rng.normal())
        a = _arc100(None, np.array([z, *c, *s, *e]))
        b = construct.circular_arc((c[0], c[1], z), (s[0], s[1], z), (e[0], e[1], z), normal=(0, 0, 1.0))
        assert a.degree == b.degree and a.rational == b.rational and a.knots.shape == b.knots.shape
        assert np.allclose(a.knots, b.knots, rtol=0, atol=1e-14)
        assert a.domain[1] == pytest.approx(b.domain[1], abs=1e-14)
        assert np.allclose(a.control_points, b.control_points, rtol=0, atol=1e-14 * r)
        assert np.allclose(a.weights, b.weights, rtol=0, atol=1e-15)


@needs_real
def test_inspect_and_verify_report_trim_delta():
    """`cadbridge inspect` and `verify` show each face's trim delta and name the face with the
    largest; on the SolidWorks file (its sphere caps read from the arc's start, see
    test_solidworks_trims_exact_and_delta) that is the end ring DE 277, whose trim curves lie
    1.2e-4 mm off its model curves by OCC's projection onto them (`_occ_delta`)."""
    pytest.importorskip("OCP")
    from cadbridge.cli.inspect import format_inspect
    from cadbridge.verify.faces import verify

    m = read_iges(SW)
    text = format_inspect(m)
    line = next(s for s in text.splitlines() if s.startswith("trim delta"))
    worst = max(range(len(m.faces)), key=lambda i: m.faces[i].trim_delta)
    assert m.faces[worst].de == 277
    assert m.faces[worst].trim_delta == pytest.approx(_occ_delta(m.faces[worst]), rel=1e-3)
    assert f"max {m.faces[worst].trim_delta:.3g} MM" in line and f"on face {worst} (DE 277)" in line
    assert "9 of 9 faces" in line
    rows = [s.split() for s in text.splitlines()[text.splitlines().index(line) + 2:][:len(m.faces)]]
    assert [int(r[1]) for r in rows] == [f.de for f in m.faces]
    assert [float(r[7]) for r in rows] == pytest.approx([f.trim_delta for f in m.faces], rel=1e-2)
    rep = verify(SW, n_samples=6, isolate=False)
    w = rep.max_delta()
    assert w.de == 277 and w.trim_delta == pytest.approx(m.faces[worst].trim_delta, rel=1e-9)
    assert rep.delta_line() in rep.format() and f"(DE {w.de})" in rep.delta_line()


def _loops(f):
    return [] if f.trims is None else ([f.trims.outer] if f.trims.outer is not None else []) + list(f.trims.inner)


@pytest.mark.skipif(not BEARING.exists(), reason=f"{REAL} not present")
@pytest.mark.parametrize("path", [SW, BEARING], ids=["SolidWorks", "Euclid"])
def test_write_read_round_trip_real(path, tmp_path):
    """read -> write_iges -> read on real files (reference: the first reading). Same faces and
    surfaces bit for bit; NURBS trim curves (all of the Euclid file's) bit for bit; the exact
    mapped trims of the SolidWorks 120 faces come back as cubics within 2 x TRIM_REL_TOL x the
    (u, v) diagonal of the exact curves (measured densely); random (u, v) classify the same on
    every face; trim deltas agree (except where the loop was derived from the model curves:
    then the written loop lies on them)."""
    from cadbridge.iges.writer import TRIM_REL_TOL, write_iges

    m = read_iges(path)
    out = tmp_path / "rt.igs"
    write_iges(m, out)
    r = read_iges(out)
    assert len(r.faces) == len(m.faces)
    rng = np.random.default_rng(3)
    mapped = 0
    for a, b in zip(m.faces, r.faces):
        sa, sb = a.surface, b.surface
        assert np.array_equal(sa.control_points, sb.control_points) and np.array_equal(sa.knots_u, sb.knots_u)
        assert np.array_equal(sa.knots_v, sb.knots_v) and tuple(sa.domain) == tuple(sb.domain)
        la, lb = _loops(a), _loops(b)
        assert [len(x.curves) for x in la] == [len(x.curves) for x in lb]
        u0, u1, v0, v1 = sa.domain
        tol = TRIM_REL_TOL * np.hypot(u1 - u0, v1 - v0)
        for x, y in zip(la, lb):
            for ca, cb in zip(x.curves, y.curves):
                if isinstance(ca, NurbsCurve):
                    assert np.array_equal(ca.control_points[:, :2], cb.control_points[:, :2])
                    assert np.array_equal(ca.knots, cb.knots)
                else:
                    mapped += 1
                    t = np.linspace(*ca.domain, 4001)
                    assert np.max(np.linalg.norm(cb.evaluate(t)[:, :2] - ca.evaluate(t), axis=1)) <= 2 * tol
        u = rng.uniform(u0, u1, 3000)
        v = rng.uniform(v0, v1, 3000)
        assert np.array_equal(a.contains(u, v), b.contains(u, v)), f"DE {a.de}"
        if a.trim_delta is None:
            assert b.trim_delta is None
        elif any(isinstance(c, InvertedCurve) for x in la for c in x.curves):
            # trims derived from the model curves (DE 351): what is written lies on them; the
            # first reading's delta was that of the file's own (rejected) parameter-space curves
            assert b.trim_delta < 1e-6
        else:
            assert b.trim_delta == pytest.approx(a.trim_delta, rel=1e-6, abs=1e-9 * m.size())
    assert mapped > 0 if path == SW else mapped == 0


def test_sample_many_equals_sample_chain_per_curve():
    """The batched phase-1 sampling (one packed evaluation, one vectorised unwrap for all
    curves) gives each curve the parameters and unwrapped angles of sample_chain on it alone
    (reference: NurbsCurve.sample_parameters, NurbsCurve.evaluate and np.unwrap)."""
    from cadbridge.cad.analytic import _sample_many, sample_chain

    rng = np.random.default_rng(0)
    cs = [NurbsCurve(3, [0, 0, 0, 0, 0.4, 1, 1, 1, 1], rng.normal(size=(5, 2)) * 8, rng.random(5) + 0.5)
          for _ in range(7)]

    def fn(p):
        return np.column_stack([p[:, 0], np.arctan2(np.sin(p[:, 1]), np.cos(p[:, 1]))])

    for c, (t, n) in zip(cs, _sample_many(cs, fn, (False, True))):
        t2, n2 = sample_chain(fn, c, (False, True), None, 0.0)
        assert np.allclose(t, t2, rtol=0, atol=1e-15) and np.allclose(n, n2, rtol=0, atol=1e-12)
        assert np.ptp(n[:, 1]) > np.pi or np.all(np.abs(np.diff(n[:, 1])) < np.pi)
