"""Writer tests: round trip through our reader (bit-for-bit, the reference being the
surfaces written) and OpenCASCADE reading what we write (the independent reference)."""

from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cadbridge.iges import read_iges, write_iges
from cadbridge.iges.writer import format_real, iges_text
from cadbridge.cad.model import Face, Model, Trim, TrimLoop, Units
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface
from tests.helpers import occ as OCC


def _knots(rng: np.random.Generator, p: int, n: int) -> np.ndarray:
    """Clamped knot vector with random interior knots, some repeated (multiplicity <= p)."""
    interior = []
    while len(interior) < n - p - 1:
        k = float(rng.random())
        interior += [k] * min(int(rng.integers(1, p + 1)), n - p - 1 - len(interior))
    a, b = sorted(rng.normal(0, 10, 2))
    if b - a < 1e-3:
        b = a + 1.0
    inner = a + (b - a) * np.sort(np.array(interior))
    return np.concatenate([[a] * (p + 1), inner, [b] * (p + 1)])


def random_surface(seed: int) -> NurbsSurface:
    rng = np.random.default_rng(seed)
    p, q = (int(x) for x in rng.integers(1, 6, 2))
    nu, nv = p + 1 + int(rng.integers(0, 5)), q + 1 + int(rng.integers(0, 5))
    ku, kv = _knots(rng, p, nu), _knots(rng, q, nv)
    cp = rng.normal(0, 100, (nu, nv, 3)) * 10.0 ** rng.integers(-6, 6)
    w = None if rng.random() < 0.3 else np.exp(rng.normal(0, 1, (nu, nv)))
    dom = None
    if rng.random() < 0.5:
        u0, u1 = ku[p], ku[nu]
        v0, v1 = kv[q], kv[nv]
        dom = (u0 + 0.1 * (u1 - u0), u1 - 0.2 * (u1 - u0), v0, v0 + 0.5 * (v1 - v0))
    return NurbsSurface(p, q, ku, kv, cp, w, dom)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seeds=st.lists(st.integers(0, 2**32 - 1), min_size=1, max_size=4))
def test_round_trip_random_surfaces_bit_for_bit(tmp_path, seeds):
    """Random rational/polynomial surfaces, degrees 1-5, repeated knots, sub-domains:
    read(write(faces)) reproduces every surface bit for bit (reference: the input)."""
    faces = [Face(random_surface(s), de=0) for s in seeds]
    path = tmp_path / "rt.igs"
    write_iges(faces, path, units=Units(6, "M", 1000.0), author="me")
    m = read_iges(path)
    assert len(m.faces) == len(faces)
    for a, b in zip(faces, m.faces):
        assert b.surface.same_as(a.surface)
    assert m.units.flag == 6 and m.author == "me"
    assert m.diagnostics == []


def _square(u0, u1, v0, v1) -> list[NurbsCurve]:
    pts = [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
    return [NurbsCurve(1, [0, 0, 1, 1], [a, b]) for a, b in zip(pts, pts[1:] + pts[:1])]


def _circle(cu, cv, r) -> NurbsCurve:
    s = np.sqrt(0.5)
    pts = np.array([[1, 0], [1, 1], [0, 1], [-1, 1], [-1, 0], [-1, -1], [0, -1], [1, -1], [1, 0]], float)
    w = np.array([1, s, 1, s, 1, s, 1, s, 1])
    kn = [0, 0, 0, 0.25, 0.25, 0.5, 0.5, 0.75, 0.75, 1, 1, 1]
    return NurbsCurve(2, kn, pts * r + [cu, cv], w)


def trimmed_model() -> Model:
    s1 = random_surface(11)
    u0, u1, v0, v1 = s1.domain
    du, dv = u1 - u0, v1 - v0
    outer = TrimLoop(_square(u0 + 0.05 * du, u1 - 0.05 * du, v0 + 0.05 * dv, v1 - 0.05 * dv))
    hole = TrimLoop([_circle(u0 + 0.5 * du, v0 + 0.5 * dv, 0.1 * min(du, dv))])
    f1 = Face(s1, de=0, name="trimmed one", color=(0.25, 0.5, 1.0), trims=Trim(outer, [hole]))
    s2 = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], [[[0, 0, 0], [0, 1, 0]], [[1, 0, 0], [1, 1, 0.5]]])
    f2 = Face(s2, de=0, name="hole only", trims=Trim(None, [TrimLoop(_square(0.2, 0.4, 0.2, 0.4))]))
    f3 = Face(random_surface(12), de=0)
    return Model(faces=[f1, f2, f3], units=Units(1, "IN", 25.4), resolution=1e-7)


def test_round_trip_trimmed_faces(tmp_path):
    """Trimmed faces (outer square of 4 lines + circular hole; a hole without outer loop):
    surfaces, trim curves, names, colours and units come back exactly (reference: input)."""
    model = trimmed_model()
    path = tmp_path / "trim.igs"
    write_iges(model, path)
    m = read_iges(path)
    assert [f.entity_type for f in m.faces] == [144, 144, 128]
    for a, b in zip(model.faces, m.faces):
        assert b.surface.same_as(a.surface)
        assert b.name == a.name and b.color == a.color
        if a.trims is None:
            assert b.trims is None
            continue
        for la, lb in zip([a.trims.outer] + a.trims.inner, [b.trims.outer] + b.trims.inner):
            if la is None:
                assert lb is None
                continue
            assert len(la.curves) == len(lb.curves)
            assert all(x.same_as(y) for x, y in zip(la.curves, lb.curves))
    assert m.units == Units(1, "IN", 25.4) and m.resolution == 1e-7


def test_write_is_atomic_and_replaces(tmp_path):
    """The target is replaced as a whole and no temporary file is left behind."""
    path = tmp_path / "a.igs"
    path.write_text("old")
    write_iges([Face(random_surface(5), de=0)], path)
    assert os.listdir(tmp_path) == ["a.igs"]
    assert read_iges(path).faces[0].surface.same_as(random_surface(5))


def test_format_real():
    """Every real has a '.' or an 'E' and reads back to the same float."""
    for x in [0.0, -0.0, 1.0, 1e-7, 1.5e300, -2.5e-300, 123456789.0, 0.1, 1 / 3, 5e-324]:
        s = format_real(x)
        assert ("." in s or "E" in s) and "e" not in s
        assert float(s) == x
    with pytest.raises(ValueError):
        format_real(float("nan"))


def test_records_are_80_columns():
    """Every line is 80 columns with a valid section letter (IGES fixed format)."""
    text = iges_text(trimmed_model().faces)
    for line in text.splitlines():
        assert len(line) == 80 and line[72] in "SGDPT"


# ------------------------------------------------------------------ OpenCASCADE reads our files


def test_occ_reads_what_we_write(tmp_path):
    """OpenCASCADE's IGES reader accepts our file, finds one face per face, and its surfaces
    agree with ours at random (u, v) to 1e-12 relative to the model size (OCC converts
    to millimetres, so our points are scaled by the units' to_mm = 25.4)."""
    model = trimmed_model()
    model.faces += [Face(random_surface(s), de=0) for s in range(20, 26)]
    path = tmp_path / "occ.igs"
    write_iges(model, path)
    pytest.importorskip("OCP")
    faces = OCC.read_surfaces(path)  # surface with the face location applied
    assert len(faces) == len(model.faces)
    rng = np.random.default_rng(7)
    for ours, surf in zip(model.faces, faces):
        s = ours.surface
        u0, u1, v0, v1 = s.domain
        u, v = u0 + (u1 - u0) * rng.random(10), v0 + (v1 - v0) * rng.random(10)
        x = s.evaluate(u, v) * model.units.to_mm
        size = np.linalg.norm(np.ptp(s.control_points.reshape(-1, 3), axis=0)) * model.units.to_mm
        for k in range(10):
            p = surf.Value(float(u[k]), float(v[k]))
            assert np.linalg.norm(np.array([p.X(), p.Y(), p.Z()]) - x[k]) <= 1e-12 * size


def test_occ_trimmed_area(tmp_path):
    """OCC's area of our trimmed bilinear face equals the hand-computed trimmed area: a
    unit-square plane face minus a 0.2 x 0.2 square hole = 1 - 0.04 (z-tilt taken as
    the plane z = 0 here)."""
    pytest.importorskip("OCP")
    s = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], [[[0, 0, 0], [0, 1, 0]], [[1, 0, 0], [1, 1, 0]]])
    face = Face(s, de=0, trims=Trim(TrimLoop(_square(0, 1, 0, 1)), [TrimLoop(_square(0.2, 0.4, 0.2, 0.4))]))
    path = tmp_path / "area.igs"
    write_iges([face], path)
    (occ_face,) = OCC.read_faces(path)
    assert OCC.area(occ_face) == pytest.approx(0.96, rel=1e-9)
