"""Reader tests on hand-made IGES text: every expected value is computed by hand from the
IGES 5.3 field definitions (or, for the thesis file, read off its printed parameters)."""

from __future__ import annotations

from math import cos, pi, sin

import numpy as np
import pytest
from tests.helpers.iges_fixtures import (THESIS_APPENDIX_A, THESIS_KNOTS_S, THESIS_XY, bilinear_128,
                                make_iges)

from cadbridge.iges import IgesError, read_iges, read_iges_string
from cadbridge.iges.globals import units_from_flag


def test_thesis_appendix_a():
    """Neto (2010) Appendix A (GiD, one 128). Reference: the parameter values printed in the
    thesis: K1=7, K2=1, M1=3, M2=1, knots, 16 control points (8 at z=0, the same 8 at z=10),
    domain [0,1]x[0,1]; clamped knots make the corners interpolate the corner points."""
    m = read_iges_string(THESIS_APPENDIX_A, "thesis.igs")
    assert len(m.faces) == 1 and m.diagnostics == []
    s = m.faces[0].surface
    assert (s.degree_u, s.degree_v) == (3, 1)
    assert s.shape == (8, 2)  # K1+1, K2+1
    assert s.knots_u.tolist() == THESIS_KNOTS_S
    assert s.knots_v.tolist() == [0, 0, 1, 1]
    expect = np.array([[[x, y, z] for z in (0.0, 10.0)] for x, y in THESIS_XY])
    assert np.array_equal(s.control_points, expect)
    assert not s.rational and s.domain == (0.0, 1.0, 0.0, 1.0)
    corners = s.evaluate([0, 1, 0, 1], [0, 0, 1, 1])
    assert np.allclose(corners, [expect[0, 0], expect[-1, 0], expect[0, 1], expect[-1, 1]], rtol=0, atol=1e-14)
    assert m.units.flag == 2 and m.units.to_mm == 1.0
    assert m.system == "GID" and m.filename == "C:/CEMMUC/FA/60.igs" and m.author == "CIMNE"
    assert m.resolution == 0.001
    assert m.faces[0].name == "NURBSURF(1)"  # DE label + subscript (no 406 name)
    assert m.entity_counts == {128: 1}


def test_global_nondefault_delimiters_hollerith_and_d_exponents():
    """Global with '/' and '#' delimiters, Hollerith strings containing both, D exponents and
    empty fields. Reference: the field values as written (IGES 5.3 section 2.2.4)."""
    g = ("1H/,1H#/11Ha/b#c,d;e f/8Hfile.igs/3HSYS/3Hpre/32/38/6/308/15//1.0D0/1//1/0.5D-1/"
         "11H200101.0000/2.5D-3/1.0D+2/9HA. Author/7HOrg/Inc/11/0/#")
    ents = [{"params": "128/1/1/1/1/0/0/1/0/0/0./0./1.0D0/1.D0/0./0./1./1./1./1./1./1./"
                       "0./0./0./2.5D-1/0./0./0./1./0./1.5D+0/2./.5/0./1./0./1.#"}]
    text = make_iges(ents, global_text=g, pdelims="/#")
    m = read_iges_string(text)
    assert m.product_id == "a/b#c,d;e f"
    assert m.filename == "file.igs" and m.system == "SYS" and m.preprocessor == "pre"
    assert m.units.flag == 1 and m.units.name == "IN" and m.units.to_mm == 25.4  # field 14 = 1, 15 empty
    assert m.resolution == 2.5e-3
    assert m.author == "A. Author" and m.organization == "Org/Inc"
    s = m.faces[0].surface
    assert s.control_points[1, 0].tolist() == [0.25, 0.0, 0.0]
    assert s.control_points[1, 1].tolist() == [1.5, 2.0, 0.5]
    assert s.knots_u.tolist() == [0.0, 0.0, 1.0, 1.0]


def test_units_flags():
    """Units table of IGES 5.3 (Global field 14): mm per unit."""
    table = {1: 25.4, 2: 1.0, 4: 304.8, 5: 1609344.0, 6: 1000.0, 7: 1e6, 8: 0.0254, 9: 0.001, 10: 10.0,
             11: 2.54e-5}
    for flag, mm in table.items():
        assert units_from_flag(flag, None).to_mm == pytest.approx(mm, rel=1e-15)
    assert units_from_flag(3, "IN").to_mm == 25.4
    with pytest.raises(ValueError):
        units_from_flag(12, None)
    g = "1H,,1H;,1Hx,1Hy,1Hz,1Hw,32,38,6,308,15,1Hx,1.,1,4HINCH,1,1.,1H0,1E-6,1.,1Ha,1Hb,11,0;"
    m = read_iges_string(make_iges([{"params": bilinear_128()}], global_text=g))
    assert m.units.flag == 1 and m.units.to_mm == 25.4


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = cos(angle), sin(angle)
    if axis == "z":
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _m124(r: np.ndarray, t) -> str:
    vals = [r[0, 0], r[0, 1], r[0, 2], t[0], r[1, 0], r[1, 1], r[1, 2], t[1], r[2, 0], r[2, 1], r[2, 2], t[2]]
    return "124," + ",".join(repr(float(v)) for v in vals) + ";"


def test_transformation_chain():
    """A 128 placed by a 124 whose DE points to another 124: x -> B(A(x)). Reference: the
    hand-composed affine maps applied to points of the untransformed surface."""
    corners = ((0, 0, 0), (2, 0, 1), (0, 1, 0), (2, 1, -1))
    ra, ta = _rot("z", pi / 2), np.array([1.0, 2.0, 3.0])
    rb, tb = _rot("x", pi / 3), np.array([0.0, 0.0, 5.0])
    ents = [{"params": bilinear_128(corners), "transform": 3},  # DE 1
            {"params": _m124(ra, ta), "transform": 5},  # DE 3 -> DE 5
            {"params": _m124(rb, tb)}]  # DE 5
    m = read_iges_string(make_iges(ents))
    plain = read_iges_string(make_iges([{"params": bilinear_128(corners)}])).faces[0].surface
    u, v = np.random.default_rng(1).random((2, 20))
    x = plain.evaluate(u, v)
    expect = (rb @ (ra @ x.T + ta[:, None]) + tb[:, None]).T
    assert len(m.faces) == 1
    assert np.allclose(m.faces[0].surface.evaluate(u, v), expect, rtol=0, atol=1e-13)


def _lines_loop(pts) -> list[str]:
    return [f"110,{a[0]!r},{a[1]!r},0.,{b[0]!r},{b[1]!r},0.;" for a, b in zip(pts, pts[1:] + pts[:1])]


def test_trimmed_surface_144_with_hole_name_and_colour():
    """144 over a 128 with an outer loop (102 of four 110 lines in (u, v)) and a circular hole
    (100 full circle), colour through a 314 and name through a 406 form 15 property.
    Reference: the loop vertices, the circle radius, inside/outside by hand."""
    sq = [(0.1, 0.1), (0.9, 0.1), (0.9, 0.9), (0.1, 0.9)]
    ents = [{"params": "314,100.,50.,0.,3Hred;"},  # DE 1
            {"params": "406,1,8HMy Face1;", "form": 15},  # DE 3
            {"params": bilinear_128(((0, 0, 0), (10, 0, 0), (0, 10, 0), (10, 10, 0))), "status": "00010000"},  # 5
            ]
    for ln in _lines_loop(sq):  # DE 7, 9, 11, 13
        ents.append({"params": ln, "status": "00010500"})
    ents.append({"params": "102,4,7,9,11,13;", "status": "00010500"})  # DE 15
    ents.append({"params": "142,0,5,15,0,1;", "status": "00010000"})  # DE 17
    ents.append({"params": "100,0.,0.5,0.5,0.7,0.5,0.7,0.5;", "status": "00010500"})  # DE 19 full circle
    ents.append({"params": "142,0,5,19,0,1;", "status": "00010000"})  # DE 21
    ents.append({"params": "144,5,1,1,17,21,0,1,3;", "color": -1})  # DE 23 with NV=0, NP=1 -> 406
    m = read_iges_string(make_iges(ents))
    assert len(m.faces) == 1
    f = m.faces[0]
    assert f.de == 23 and f.surface_de == 5 and f.entity_type == 144 and f.surface_type == 128
    assert f.name == "My Face1"
    assert f.color == (1.0, 0.5, 0.0)
    outer = f.trims.outer
    assert len(outer.curves) == 4
    starts = np.array([c.evaluate([c.domain[0]])[0] for c in outer.curves])
    assert np.array_equal(starts, np.array(sq))
    hole = f.trims.inner[0].curves[0]
    t = np.linspace(*hole.domain, 17)
    assert np.allclose(np.linalg.norm(hole.evaluate(t) - [0.5, 0.5], axis=1), 0.2, rtol=0, atol=1e-14)
    inside = f.contains(np.array([0.2, 0.5, 0.05, 0.8]), np.array([0.2, 0.5, 0.5, 0.8]))
    assert inside.tolist() == [True, False, False, True]
    assert m.entity_counts[110] == 4


def test_model_space_only_curve_on_surface_keeps_face_untrimmed():
    """A 142 with BPTR = 0 (model space only): face kept untrimmed with a diagnostic
    (reference: the reader contract; no invented (u, v) curves)."""
    ents = [{"params": bilinear_128(), "status": "00010000"},  # 1
            {"params": "110,0.,0.,0.,1.,0.,0.;", "status": "00010000"},  # 3
            {"params": "142,0,1,0,3,2;", "status": "00010000"},  # 5
            {"params": "144,1,1,0,5;"}]  # 7
    m = read_iges_string(make_iges(ents))
    assert len(m.faces) == 1 and m.faces[0].trims is None
    assert any("model space only" in d.message and d.de == 5 for d in m.diagnostics)


def test_subfigure_instances():
    """308 holding a 128; two 408 instances: one with (X, Y, Z) and scale S, one also with a
    124. Reference: x -> M (S x + T) applied by hand to the definition surface."""
    corners = ((0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 1))
    r = _rot("z", pi / 2)
    ents = [{"params": bilinear_128(corners), "status": "00010000"},  # 1
            {"params": "308,0,4Hpart,1,1;", "status": "00000200"},  # 3
            {"params": "408,3,10.,0.,0.,2.;"},  # 5
            {"params": _m124(r, [0.0, 0.0, 7.0])},  # 7
            {"params": "408,3,0.,1.,0.;", "transform": 7}]  # 9 (S omitted -> 1)
    m = read_iges_string(make_iges(ents))
    assert len(m.faces) == 2
    base = read_iges_string(make_iges([{"params": bilinear_128(corners)}])).faces[0].surface
    u, v = np.random.default_rng(2).random((2, 10))
    x = base.evaluate(u, v)
    assert np.allclose(m.faces[0].surface.evaluate(u, v), 2.0 * x + [10.0, 0, 0], rtol=0, atol=1e-14)
    assert np.allclose(m.faces[1].surface.evaluate(u, v), (r @ (x + [0, 1.0, 0]).T).T + [0, 0, 7.0],
                       rtol=0, atol=1e-14)


def test_raw_entities_are_kept():
    """Entities the reader does not interpret are kept in model.raw and counted."""
    ents = [{"params": bilinear_128()}, {"params": "212,1,4,1.,1.,1,0.,0.,0,0,0.,0.,0.,4HNOTE;"},
            {"params": "402,2,1,3;", "form": 7}]
    m = read_iges_string(make_iges(ents))
    assert m.entity_counts == {128: 1, 212: 1, 402: 1}
    assert m.raw[3][0] == 212 and m.raw[3][2][-1] == "NOTE"
    assert m.raw[5] == (402, 7, ["2", "1", "3"])
    assert len(m.faces) == 1


def test_analytic_surfaces_108_118_120_122():
    """108 bounded plane, 118 ruled, 120 revolution, 122 tabulated cylinder, built exactly.
    References: plane z = 2 and its rectangle; the ruled surface between two lines is the
    bilinear patch; revolution of x = 1 about z is the unit cylinder; translating a unit
    circle arc by (0, 0, 3)."""
    rect = [(0.0, 0.0), (4.0, 0.0), (4.0, 1.0), (0.0, 1.0)]
    ents = [{"params": f"110,{a[0]!r},{a[1]!r},2.,{b[0]!r},{b[1]!r},2.;", "status": "00010000"}
            for a, b in zip(rect, rect[1:] + rect[:1])]  # 1, 3, 5, 7
    ents.append({"params": "102,4,1,3,5,7;", "status": "00010000"})  # 9
    ents.append({"params": "108,0.,0.,1.,2.,9,0.,0.,0.,0.;", "form": 1})  # 11
    ents.append({"params": "110,0.,0.,0.,1.,0.,0.;", "status": "00010000"})  # 13
    ents.append({"params": "110,0.,1.,1.,1.,1.,1.;", "status": "00010000"})  # 15
    ents.append({"params": "118,13,15,0,0;", "form": 1})  # 17
    ents.append({"params": "110,0.,0.,0.,0.,0.,1.;", "status": "00010000"})  # 19 axis
    ents.append({"params": "110,1.,0.,0.,1.,0.,1.;", "status": "00010000"})  # 21 generatrix
    ents.append({"params": f"120,19,21,0.,{pi!r};"})  # 23
    ents.append({"params": "100,0.,0.,0.,1.,0.,0.,1.;", "status": "00010000"})  # 25 quarter arc
    ents.append({"params": "122,25,1.,0.,3.;"})  # 27
    m = read_iges_string(make_iges(ents))
    assert [f.entity_type for f in m.faces] == [108, 118, 120, 122]
    rng = np.random.default_rng(3)
    for f in m.faces:
        u0, u1, v0, v1 = f.surface.domain
        u, v = u0 + (u1 - u0) * rng.random(25), v0 + (v1 - v0) * rng.random(25)
        x = f.surface.evaluate(u, v)
        if f.entity_type == 108:
            assert np.allclose(x[:, 2], 2.0, rtol=0, atol=1e-14)
            assert f.trims is not None and f.trims.outer is not None
            box = f.surface.evaluate([u0, u1, u0, u1], [v0, v0, v1, v1])
            assert np.allclose(np.sort(box[:, 0]), [0, 0, 4, 4], atol=1e-14)
            uv = f.trims.outer.polygon()
            pts = f.surface.evaluate(uv[:, 0], uv[:, 1])
            assert np.allclose(pts[:, :2].min(0), [0, 0], atol=1e-13)
            assert np.allclose(pts[:, :2].max(0), [4, 1], atol=1e-13)
        elif f.entity_type == 118:  # between y=0,z=0 and y=1,z=1 lines along x
            assert np.allclose(x[:, 1], x[:, 2], atol=1e-14)
            corners = f.surface.evaluate([u0, u1, u0, u1], [v0, v0, v1, v1])
            assert np.allclose(corners, [[0, 0, 0], [1, 0, 0], [0, 1, 1], [1, 1, 1]], atol=1e-14)
        elif f.entity_type == 120:
            assert np.allclose(np.hypot(x[:, 0], x[:, 1]), 1.0, rtol=0, atol=1e-14)
            assert np.all(x[:, 1] >= -1e-14)  # half turn: y >= 0
        else:
            assert np.allclose(np.hypot(x[:, 0], x[:, 1]), 1.0, rtol=0, atol=1e-14)
            assert np.all((x[:, 2] >= -1e-14) & (x[:, 2] <= 3 + 1e-14))
            assert np.all((x[:, 0] >= -1e-14) & (x[:, 1] >= -1e-14))


def test_126_curve_fields_and_composite():
    """126 used as a pcurve: knots, weights, control points and V0/V1 kept as written
    (reference: the fields). A 2-piece 102 gives two trim pieces in order."""
    c1 = "126,2,2,0,0,0,0,0.,0.,0.,1.,1.,1.,1.,0.5,1.,0.1,0.1,0.,0.5,0.2,0.,0.9,0.1,0.,0.,1.,0.,0.,1.;"
    c2 = "126,1,1,1,0,1,0,0.,0.,1.,1.,1.,1.,0.9,0.1,0.,0.1,0.1,0.,0.,1.,0.,0.,1.;"
    ents = [{"params": bilinear_128(), "status": "00010000"},
            {"params": c1, "status": "00010500"}, {"params": c2, "status": "00010500"},
            {"params": "102,2,3,5;", "status": "00010500"}, {"params": "142,0,1,7,0,1;", "status": "00010000"},
            {"params": "144,1,1,0,9;"}]
    m = read_iges_string(make_iges(ents))
    a, b = m.faces[0].trims.outer.curves
    assert a.degree == 2 and a.knots.tolist() == [0, 0, 0, 1, 1, 1] and a.weights.tolist() == [1, 0.5, 1]
    assert a.control_points.tolist() == [[0.1, 0.1], [0.5, 0.2], [0.9, 0.1]] and a.domain == (0.0, 1.0)
    assert b.degree == 1 and b.control_points.tolist() == [[0.9, 0.1], [0.1, 0.1]]


def test_read_iges_from_path(tmp_path):
    """read_iges on a file with CRLF line ends, trailing blanks stripped and no T section
    (a diagnostic). Reference: the same text read from a string."""
    text = make_iges([{"params": bilinear_128()}])
    lines = [l.rstrip() for l in text.splitlines()[:-1]]
    p = tmp_path / "x.igs"
    p.write_bytes(("\r\n".join(lines) + "\r\n").encode())
    m = read_iges(p)
    assert m.faces[0].surface.same_as(read_iges_string(text).faces[0].surface)
    assert any("Terminate" in d.message for d in m.diagnostics)


def test_independent_base_surface_not_duplicated():
    """A 128 marked independent but used as a 144 base surface yields one face, not two."""
    ents = [{"params": bilinear_128()},
            {"params": "144,1,0,0,0;"}]
    m = read_iges_string(make_iges(ents))
    assert [f.de for f in m.faces] == [3]
    assert m.faces[0].trims is None


def test_compressed_and_binary_rejected():
    """Compressed (C in column 73) and binary input: clear 'not supported' IgesError."""
    with pytest.raises(IgesError, match="compressed.*not supported"):
        read_iges_string("x" * 72 + "C      1\n")
    with pytest.raises(IgesError, match="binary"):
        read_iges_string("\x00\x01\x02" * 40)


def test_non_orthonormal_124_form0_is_flagged():
    """A form-0 124 whose R is not a rotation (one coefficient edited in the sample) is applied
    as written but reported with its line and DE (reference: R^T R computed by hand: the
    edited R11 = 0.966 makes |R^T R - I| = 0.183)."""
    from pathlib import Path

    from cadbridge.iges import read_iges_string

    text = (Path(__file__).parents[2] / "iges_samples" / "placed_by_124.igs").read_text()
    assert not read_iges_string(text).diagnostics
    lines = text.splitlines()
    i = next(k for k, line in enumerate(lines) if line.startswith("124,0.866"))
    lines[i] = lines[i].replace("124,0.866", "124,0.966", 1)
    notes = [d for d in read_iges_string("\n".join(lines) + "\n").diagnostics if "orthonormal" in d.message]
    assert len(notes) == 1 and notes[0].de == 1 and notes[0].line is not None
    assert "0.183" in notes[0].message
