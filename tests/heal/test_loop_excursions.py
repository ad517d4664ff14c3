"""Trim-loop excursions (`cadbridge.heal.loop_excursions`, `cadbridge.mesh.gmsh.loop_cuts`).

References: OpenCASCADE's area of planar faces built from the loops (BRepGProp), OCC's
point classification on the original face (BRepClass_FaceClassifier), OCC's distance of the
excursion to the face's boundary (BRepExtrema), and analytic polygons.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cadbridge.heal.loop_excursions import find_excursions, heal_excursions
from cadbridge.cad.model import Face, Model, Trim, TrimLoop
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface
from tests.helpers import occ as OCC

ANSA = Path(__file__).resolve().parents[3] / "shared" / "iges_real" / "occt_OCC131-2_ANSA9.igs"
needs_ansa = pytest.mark.skipif(not ANSA.is_file(), reason="corpus file occt_OCC131-2_ANSA9.igs absent")

# a unit square's left edge, run down with a Z (down to v = 0.40, back up to 0.60, down
# again), its strands 2e-4 apart: FACE(401)'s defect in miniature (model size 1.41, so the
# default width is 1.41e-3)
Z_LEFT = [(0.0, 1.0), (2e-4, 0.40), (4e-4, 0.60), (6e-4, 0.45), (6e-4, 0.0)]
SLIT_LEFT = [(0.0, 1.0), (0.0, 0.60), (0.5, 0.60), (0.5, 0.5998), (0.0, 0.5998), (0.0, 0.0)]  # a U, not a Z


def _plane() -> NurbsSurface:
    """S(u, v) = (u, v, 0): (u, v) area is model-space area."""
    cp = np.array([[[0.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0]]])
    return NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], cp)


def _line(a, b) -> NurbsCurve:
    return NurbsCurve(1, [0, 0, 1, 1], np.array([a, b], dtype=float))


def _square_with(left: list) -> list:
    """Polygon (counter-clockwise): bottom, right, top edges, then ``left`` from (0, 1) down."""
    return [(left[-1][0], 0.0), (1.0, 0.0), (1.0, 1.0)] + left


def _model(poly: list) -> Model:
    curves = [_line(poly[k], poly[(k + 1) % len(poly)]) for k in range(len(poly))]
    face = Face(surface=_plane(), de=1, name="Z", trims=Trim(TrimLoop(curves)))
    return Model(faces=[face])


def _occ_face(poly: np.ndarray):
    """OCC planar face from a (u, v) polygon at z = 0."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace, BRepBuilderAPI_MakePolygon
    from OCP.gp import gp_Pnt

    mk = BRepBuilderAPI_MakePolygon()
    for u, v in poly:
        mk.Add(gp_Pnt(float(u), float(v), 0.0))
    mk.Close()
    return BRepBuilderAPI_MakeFace(mk.Wire(), True).Face()


def _loop_vertices(lp: TrimLoop) -> np.ndarray:
    """The healed loop's vertices (all its curves are straight): each curve's start."""
    return np.array([c.evaluate(np.array([c.domain[0]]))[0, :2] for c in lp.curves])


def test_z_excursion_found_and_cut_against_occ_area():
    poly = _square_with(Z_LEFT)
    model = _model(poly)
    ex = find_excursions(model)
    assert len(ex) == 1
    e = ex[0]
    # the Z: ~0.6 down, 0.2 up, 0.45 down; X before the first hairpin, Y after the second
    assert e.chord <= 1e-3 * model.size() + 1e-12
    assert 0.3 < e.length < 1.2
    assert e.start[1] > 0.40 and e.end[1] < 0.60

    healed = heal_excursions(model)
    assert len(healed) == 1 and find_excursions(model) == []
    new = _loop_vertices(model.faces[0].trims.outer)
    # reference: OCC's areas of the original face and of the healed one differ by the cut's
    # signed (u, v) area (the plane's Jacobian is 1)
    a0 = OCC.area(_occ_face(np.array(poly)))
    a1 = OCC.area(_occ_face(new))
    assert abs(a0 - a1 - e.uv_area) < 1e-12
    assert abs(a0 - a1) < 2e-4 * e.length  # a sliver: no wider than its strands


def test_cut_across_the_loop_start_against_occ_area():
    """The same Z with the loop starting inside it (at the up strand's top): the cut wraps
    over the loop's first curve; OCC's areas differ by the cut's signed area as before."""
    poly = _square_with(Z_LEFT)
    k = poly.index((4e-4, 0.60))
    poly = poly[k:] + poly[:k]
    model = _model(poly)
    (e,) = heal_excursions(model)
    assert find_excursions(model) == []
    a0 = OCC.area(_occ_face(np.array(poly)))
    a1 = OCC.area(_occ_face(_loop_vertices(model.faces[0].trims.outer)))
    assert abs(a0 - a1 - e.uv_area) < 1e-12
    assert abs(a0 - a1) < 2e-4 * e.length


def test_classification_after_the_cut_against_occ():
    """cadbridge's healed trims agree with OCC's classification of the original face except
    inside the cut sliver (within the chord of the cut stretch)."""
    from OCP.BRepClass import BRepClass_FaceClassifier
    from OCP.gp import gp_Pnt
    from OCP.TopAbs import TopAbs_IN, TopAbs_ON

    from cadbridge.heal.loop_excursions import _polyline_distance

    poly = _square_with(Z_LEFT)
    model = _model(poly)
    occ = _occ_face(np.array(poly))
    (e,) = heal_excursions(model)
    rng = np.random.default_rng(3)
    pts = np.vstack([rng.uniform(0, 1, (300, 2)),
                     np.column_stack([rng.uniform(0, 1e-3, 300), rng.uniform(0.3, 0.7, 300)])])
    inside = model.faces[0].contains(pts[:, 0], pts[:, 1])
    occ_in = np.array([BRepClass_FaceClassifier(occ, gp_Pnt(float(u), float(v), 0.0), 1e-12).State()
                       in (TopAbs_IN, TopAbs_ON) for u, v in pts])
    differ = inside != occ_in
    near = _polyline_distance(np.column_stack([pts, np.zeros(len(pts))]), e.stretch_xyz) <= e.chord
    assert differ.any()  # the sliver holds some of the points
    assert not np.any(differ & ~near)


def test_slit_and_straight_loops_are_not_excursions():
    """A U (a real slit 2e-4 wide) and a plain square have none."""
    assert find_excursions(_model(_square_with(SLIT_LEFT))) == []
    assert find_excursions(_model(_square_with([(0.0, 1.0), (0.0, 0.0)]))) == []


def _wire_distances(e) -> list[float]:
    """Per OCC face of ANSA9, the largest distance of the excursion's stretch to its outer wire."""
    from OCP.BRepTools import BRepTools

    return [max(OCC.distance(p, BRepTools.OuterWire_s(f)) for p in e.stretch_xyz[::4]) for f in OCC.read_faces(ANSA)]


@needs_ansa
def test_ansa_face_401_excursion_on_occ_edge():
    """ANSA9: only FACE(401) has one; its stretch lies on the face's boundary as OCC reads it
    (BRepExtrema distance to the outer wire), FACE(274)'s folded edge within the trim tolerance."""
    from cadbridge.iges import read_iges

    model = read_iges(ANSA)
    ex = find_excursions(model)
    assert [e.face_name for e in ex] == ["FACE(401)"]
    e = ex[0]
    face = model.faces[[f.de for f in model.faces].index(e.face_de)]
    assert e.chord < 0.13 and 8.0 < e.length < 8.6
    on_wire = sorted(_wire_distances(e))
    assert on_wire[0] < 1e-5 < on_wire[1] <= face.trim_delta
    assert heal_excursions(model) and find_excursions(model) == []


@needs_ansa
@pytest.mark.slow
def test_ansa_quad_mesh_leaves_the_excursion_out(tmp_path):
    """convert in quad (25 s): exit 0 and the healing reported; every element with a node on
    the cut stretch (away from X and Y) lies on OCC's FACE(274) (BRepExtrema <= its trim
    tolerance): FACE(401)'s mesh does not reach into the sliver."""
    from cadbridge.iges import read_iges
    from cadbridge.heal.loop_excursions import _polyline_distance
    from cadbridge.tool.pipeline import convert

    res = convert(str(ANSA), str(tmp_path / "q"), element="quad")
    assert any("trim defect healed: FACE(401)" in n for n in res.notes)
    assert any("without its trim-loop excursion" in n for n in res.notes)
    model = read_iges(ANSA)
    (e,) = find_excursions(model)
    d274 = model.faces[0].trim_delta
    dist = _wire_distances(e)
    f274 = OCC.read_faces(ANSA)[int(np.argsort(dist)[1])]  # the folded neighbour (see the test above)
    checked = 0
    for t in res.tools:
        x = t.mesh.nodes
        on = (_polyline_distance(x, e.stretch_xyz) < 1e-3) \
            & (np.linalg.norm(x - e.start, axis=1) > 2 * e.chord) & (np.linalg.norm(x - e.end, axis=1) > 2 * e.chord)
        for el in [*t.mesh.triangles.tolist(), *t.mesh.quads.tolist()]:
            if on[el].any():
                checked += 1
                assert max(OCC.distance(x[n], f274) for n in el) <= d274
    assert checked > 0


@needs_ansa
def test_inspect_names_the_trim_defect(capsys):
    """`cadbridge inspect` lists FACE(401)'s excursion with its location; a sample without one
    lists none (reference: find_excursions above, OCC-checked)."""
    from cadbridge.cli import main

    assert main(["inspect", str(ANSA)]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("trim defect"))
    assert "FACE(401) (DE 53)" in line and "(3545.44, -732.185, 145.195)" in line
    sample = Path(__file__).resolve().parents[2] / "iges_samples" / "trimmed_hole.igs"
    assert main(["inspect", str(sample)]) == 0
    assert "trim defect" not in capsys.readouterr().out


def test_restricted_mapped_trim_curve_is_the_same_curve():
    """A cut through a loop of an analytic face restricts a `MappedCurve` (trim curve mapped
    exactly into the converted surface's parameters). Reference: the unrestricted curve at
    the same parameters (the restriction changes the domain only); the U-shape's analytic
    tools have such curves."""
    from cadbridge.iges import read_iges
    from cadbridge.cad.analytic import MappedCurve
    from cadbridge.heal.loop_excursions import _restricted

    model = read_iges(Path(__file__).resolve().parents[2] / "iges_samples" / "ushape_tools_analytic.igs")
    mapped = [c for f in model.faces if f.trims is not None and f.trims.outer is not None
              for c in f.trims.outer.curves if isinstance(c, MappedCurve)]
    assert mapped
    for c in mapped:
        a, b = c.domain
        t0, t1 = a + 0.3 * (b - a), a + 0.8 * (b - a)
        r = _restricted(c, t0, t1)
        assert r.domain == (t0, t1) and c.domain == (a, b)
        t = np.linspace(t0, t1, 11)
        np.testing.assert_array_equal(r.evaluate(t), c.evaluate(t))
        np.testing.assert_array_equal(r.derivatives(t, 2), c.derivatives(t, 2))


def _dense_square_with(left: list, pieces: int) -> list:
    """`_square_with`, its ``left`` edges each split into ``pieces`` straight pieces (64 samples
    each: a loop sampled densely against the width)."""
    poly = _square_with(left)
    out = poly[:3]
    for p, q in zip(left[:-1], left[1:]):
        t = np.linspace(0.0, 1.0, pieces + 1)[:-1]
        out += [tuple(np.array(p) + s * (np.array(q) - np.array(p))) for s in t]
    return out + [left[-1]]


def test_z_excursion_found_on_every_kth_sample_where_pairs_are_too_many(monkeypatch):
    """A Z whose strands are sampled 5e-5 apart against the 1.4e-3 width (about 10^6 pairs
    within it), with `MAX_PAIRS` lowered to 10^5, is searched on every 3rd sample: the same
    excursion (reference: the search on all samples), its length within 5 %, and OCC's area
    check of the cut as in `test_z_excursion_found_and_cut_against_occ_area`."""
    import cadbridge.heal.loop_excursions as module

    poly = _dense_square_with(Z_LEFT, 150)
    full = find_excursions(_model(poly))
    model = _model(poly)
    f = model.faces[0]
    _, _, uv, xyz = module._samples(f, f.trims.outer)
    assert module._best_pair(xyz, uv, module.default_width(f, model.size())) is not None
    monkeypatch.setattr(module, "MAX_PAIRS", 100_000)
    strides = []
    real = module.cKDTree
    monkeypatch.setattr(module, "cKDTree", lambda x: strides.append(len(x)) or real(x))
    coarse = find_excursions(model)
    assert len(xyz) // 4 < min(strides) < len(xyz) // 2  # a subsampled search took place
    assert len(full) == len(coarse) == 1
    fe, c = full[0], coarse[0]
    assert c.chord <= 1e-3 * model.size() + 1e-12 and c.start[1] > 0.40 and c.end[1] < 0.60
    assert abs(c.length - fe.length) < 0.05 * fe.length
    heal_excursions(model)
    a0, a1 = OCC.area(_occ_face(np.array(poly))), OCC.area(_occ_face(_loop_vertices(model.faces[0].trims.outer)))
    assert abs(a0 - a1 - c.uv_area) < 1e-12
