"""Class 'interior knot of multiplicity above the degree' (126 curves, 128 surfaces).

IGES 5.3 (4.23, 4.24) allows at most the degree; CATIA V4 writes degree + 1 (Bezier pieces
side by side). Where the curve or surface is continuous at that knot the surplus occurrence
is removed exactly (P&T A5.8 with s = p + 1); a curve that jumps there is split into two
pieces, a surface that does is refused naming the DE and field. References: the same
geometry written with multiplicity p (hand-made), and OCC's reading of the corpus files
(`cadbridge verify`: 0 exit on all three).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.helpers.iges_fixtures import make_iges

from cadbridge.iges import IgesError, read_iges_string
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.knots import insert_knot, remove_surplus_knots, to_homogeneous

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT.parent / "shared" / "cad_corpus" / "iges"


def _numbers(values) -> str:
    return ",".join(repr(float(v)) for v in np.ravel(values))


# ---------------------------------------------------------------------------- array level
def _cubic() -> NurbsCurve:
    rng = np.random.default_rng(7)
    pts = rng.normal(size=(7, 3))
    w = rng.uniform(0.5, 2.0, 7)
    return NurbsCurve(3, [0, 0, 0, 0, 1, 2, 3, 4, 4, 4, 4], pts, w)


def test_continuous_knot_of_multiplicity_p_plus_1_removed_exactly():
    """Knot 2 raised to p (C0), then written as p + 1 with the joint point twice and the right
    piece's weights scaled by 3 (same curve): removal gives back the multiplicity-p curve."""
    c = _cubic()
    kn, qw = insert_knot(c.knots, 3, to_homogeneous(c.control_points, c.weights), 2.0, r=2)
    a = int(np.searchsorted(kn, 2.0))  # run kn[a .. a+2]; joint point index a - 1
    kn4 = np.insert(kn, a, 2.0)
    qw4 = np.concatenate([qw[:a], 3.0 * qw[a - 1 :]])
    k2, q2, removed, breaks = remove_surplus_knots(kn4, 3, qw4)
    assert removed == [(2.0, 1)] and breaks == []
    assert np.array_equal(k2, kn)
    t = np.linspace(0, 4, 201)
    out = NurbsCurve(3, k2, q2[:, :3] / q2[:, 3:], q2[:, 3]).evaluate(t)
    assert np.abs(out - c.evaluate(t)).max() <= 1e-13


def test_vanishing_basis_functions_dropped_and_jump_kept():
    """Multiplicity p + 2 with a jump: the control point whose basis function is zero
    everywhere goes (exact), the knot stays at p + 1 and is reported as a break."""
    kn = np.array([0, 0, 1, 1, 1, 2, 2], float)  # degree 1: knot 1 of multiplicity 3
    pts = np.array([[0, 0, 0], [1, 0, 0], [9, 9, 9], [1, 1e-3, 0], [2, 0, 0]], float)
    k2, q2, removed, breaks = remove_surplus_knots(kn, 1, to_homogeneous(pts))
    assert removed == [(1.0, 1)] and len(breaks) == 1
    assert breaks[0][0] == 1.0 and breaks[0][1] == pytest.approx(1e-3)
    assert np.array_equal(k2, [0, 0, 1, 1, 2, 2])
    assert np.array_equal(q2[:, :3], pts[[0, 1, 3, 4]])


# ---------------------------------------------------------------------------- reader level
def _surface_128(u_cols: list[list[tuple]], weights: list[float], s_knots: list[float]) -> str:
    """Degree (1, 1) 128 with the given columns (along u) of two points each (v = 0, 1)."""
    k1 = len(u_cols) - 1
    pts = [u_cols[i][j] for j in range(2) for i in range(k1 + 1)]  # first index fastest
    w = [weights[i] for _ in range(2) for i in range(k1 + 1)]
    u0, u1 = s_knots[0], s_knots[-1]
    return (f"128,{k1},1,1,1,0,0,0,0,0,{_numbers(s_knots)},0.,0.,1.,1.,{_numbers(w)},{_numbers(pts)},"
            f"{u0!r},{u1!r},0.,1.;")


COLS = [[(0, 0, 0), (0, 1, 0)], [(1, 0, 0.5), (1, 1, 0.5)], [(2, 0, 0), (2, 1, 0)]]


def test_surface_with_continuous_surplus_knot_reads_as_the_plain_surface():
    """S = 0,0,1,1,2,2 in degree 1 (middle column twice, right half's weights 2): the face
    is the surface with S = 0,0,1,2,2, and the repair is a diagnostic naming the knot."""
    doubled = [COLS[0], COLS[1], COLS[1], COLS[2]]
    m = read_iges_string(make_iges([{"params": _surface_128(doubled, [1, 1, 2, 2], [0, 0, 1, 1, 2, 2])}]))
    ref = read_iges_string(make_iges([{"params": _surface_128(COLS, [1, 1, 1], [0, 0, 1, 2, 2])}]))
    s, r = m.faces[0].surface, ref.faces[0].surface
    assert np.array_equal(s.knots_u, r.knots_u)
    uv = np.random.default_rng(1).uniform(0, 1, (50, 2)) * [2, 1]
    assert np.abs(s.evaluate(uv[:, 0], uv[:, 1]) - r.evaluate(uv[:, 0], uv[:, 1])).max() <= 1e-15
    msgs = [d.message for d in m.diagnostics]
    assert any("knot S = 1.0 of multiplicity 2 > degree 1, where the surface is continuous" in x for x in msgs)
    assert all(d.de == 1 for d in m.diagnostics)


def test_surface_discontinuous_at_surplus_knot_is_refused():
    apart = [COLS[0], COLS[1], [(1, 0, 0.6), (1, 1, 0.5)], COLS[2]]
    text = make_iges([{"params": _surface_128(apart, [1, 1, 1, 1], [0, 0, 1, 1, 2, 2])}])
    with pytest.raises(IgesError) as info:
        read_iges_string(text, "gap.igs")
    e = info.value
    s_line = next(k for k, ln in enumerate(text.splitlines(), 1) if ln[72] == "P" and "0.0,0.0,1.0,1.0,2.0" in ln)
    assert e.filename == "gap.igs" and e.de == 1 and e.field == "S" and e.line == s_line
    assert "multiplicity 2 > degree 1 and the surface is not continuous there (it jumps by 0.1)" in str(e)


def _trimmed(loop_126: str) -> str:
    return make_iges([
        {"params": _surface_128(COLS, [1, 1, 1], [0, 0, 1, 2, 2])},  # DE 1
        {"params": loop_126, "status": "00010500"},  # DE 3: the (u, v) loop
        {"params": "142,1,1,3,0,1;", "status": "00010000"},  # DE 5
        {"params": "144,1,1,0,5;"},  # DE 7
    ])


def _loop_126(uv: list[tuple], knots: list[float]) -> str:
    pts = [(u, v, 0.0) for u, v in uv]
    k = len(uv) - 1
    return (f"126,{k},1,0,0,1,0,{_numbers(knots)},{_numbers([1.0] * (k + 1))},{_numbers(pts)},"
            f"{knots[0]!r},{knots[-1]!r},0.,0.,1.;")


SQUARE = [(0.2, 0.2), (1.8, 0.2), (1.8, 0.8), (0.2, 0.8), (0.2, 0.2)]


def test_trim_curve_with_continuous_surplus_knot():
    """The loop's corner (1.8, 0.8) written twice with knot 2 doubled: one piece, the square."""
    uv = SQUARE[:3] + [SQUARE[2]] + SQUARE[3:]
    m = read_iges_string(_trimmed(_loop_126(uv, [0, 0, 1, 2, 2, 3, 4, 4])))
    [c] = m.faces[0].trims.outer.curves
    assert np.array_equal(c.knots, [0, 0, 1, 2, 3, 4, 4])
    assert np.array_equal(c.control_points[:, :2], SQUARE)
    assert any("knot T = 2.0 of multiplicity 2 > degree 1, where the curve is continuous: 1 occurrence(s) "
               "removed (exact)" in d.message and d.de == 3 for d in m.diagnostics)


def test_trim_curve_jumping_at_surplus_knot_is_split():
    """The second copy of the corner moved by 1e-7: two pieces, each exactly as written."""
    uv = SQUARE[:3] + [(1.8, 0.8 + 1e-7)] + SQUARE[3:]
    m = read_iges_string(_trimmed(_loop_126(uv, [0, 0, 1, 2, 2, 3, 4, 4])))
    a, b = m.faces[0].trims.outer.curves
    assert np.array_equal(a.control_points[:, :2], uv[:3]) and np.array_equal(b.control_points[:, :2], uv[3:])
    assert a.domain == (0.0, 2.0) and b.domain == (2.0, 4.0)
    assert any("the curve is not continuous there (it jumps by 1e-07): split into two pieces" in d.message
               for d in m.diagnostics)


@pytest.mark.skipif(not CORPUS.is_dir(), reason="shared/cad_corpus not present")
@pytest.mark.parametrize("name, kind, count", [
    ("occt_CTS17806-38038_CATIAV4.igs", "where the surface is continuous", 4),  # 128 S knots 1..4 x4, degree 3
    ("occt_PRO20359-L7_CATIAV4.igs", "the curve is not continuous there", 1),  # 126 knot 4 x6, degree 5
    ("occt_PRO20359-L13_CATIAV4.igs", "the curve is not continuous there", 2),  # 126 knots 1, 4 x6
])
def test_corpus_files_with_surplus_knots_read(name, kind, count):
    from cadbridge.iges import read_iges

    m = read_iges(CORPUS / name)
    assert len(m.faces) == 1
    assert sum(kind in d.message for d in m.diagnostics) == count
