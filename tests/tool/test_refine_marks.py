"""Refinement marks are delivered by gmsh (issue 12, the production die's stalled elements).

On the production die two elements kept their 7.3 mm edges in every pass although each pass
marked them for 5.5 mm: a mark at an element's corners and centroid, in a field graded at
g = 0.5, is 5.5 + 0.5 x 3.6 = 7.3 mm at the nodes gmsh makes half an element away, and gmsh
reads the field only at its nodes. The reproduction here: one plane face (the trimmed plate
of ``iges_samples/trimmed_hole.igs``, unstructured because of its hole), a uniform size, and
the loop's marking of the element over a fixed point, pass after pass.

Reference: gmsh's own ratio of the longest quad edge to the size asked, measured on the
uniform mesh of the same face in the same test. A marked element must come out within that
ratio of the size the loop asked for.
"""

from pathlib import Path

import numpy as np
import pytest

from cadbridge.mesh.generate import mesh_cad
from cadbridge.mesh.sizing import SizeField, ball_marks
from cadbridge.tool.refine import element_marks

PLATE = Path(__file__).resolve().parents[2] / "iges_samples" / "trimmed_hole.igs"
H = 10.0  # uniform size on the 100 x 60 plate


def _longest_edges(mesh):
    out = []
    for b in mesh.cells:
        x = mesh.nodes[np.asarray(b.data)]
        out.append(np.linalg.norm(np.roll(x, -1, axis=1) - x, axis=2).max(axis=1))
    return np.concatenate(out)


def _element_at(mesh, p):
    """The element whose (planar, z = 0) quad holds the point p (by its bounding box and the
    nearest centroid among those)."""
    x = np.concatenate([mesh.nodes[np.asarray(b.data)] for b in mesh.cells])
    lo, hi = x.min(axis=1), x.max(axis=1)
    ok = np.flatnonzero(np.all((lo[:, :2] <= p[:2] + 1e-9) & (p[:2] <= hi[:, :2] + 1e-9), axis=1))
    return int(ok[np.argmin(np.linalg.norm(x[ok].mean(axis=1) - p, axis=1))])


def test_ball_marks_cover_the_ball():
    """Every point of the ball is within the lattice's covering radius r sqrt(3) / (2 n) of
    a mark (closed form for a cubic lattice of spacing r / n)."""
    c = np.array([[1.0, 2.0, 3.0], [-5.0, 0.0, 0.0]])
    r = np.array([2.0, 0.5])
    pts, h = ball_marks(c, r, np.array([0.3, 0.1]), n=3)
    assert len(pts) == 2 * 251 and np.allclose(np.unique(h), [0.1, 0.3])
    rng = np.random.default_rng(3)
    for ci, ri in zip(c, r):
        d = rng.normal(size=(500, 3))
        q = ci + ri * d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(0, 1, (500, 1)) ** (1 / 3)
        dist = np.min(np.linalg.norm(q[:, None, :] - pts[None], axis=2), axis=1)
        assert dist.max() <= ri * np.sqrt(3) / 6 + 1e-12


@pytest.mark.skipif(not PLATE.is_file(), reason="iges_samples/trimmed_hole.igs missing")
@pytest.mark.parametrize("point", [(70.0, 45.0), (30.0, 10.0), (85.0, 12.0)])
def test_marked_element_gets_the_size_asked(point):
    p = np.array([point[0], point[1], 0.0])
    field = SizeField(np.zeros((0, 3)), np.zeros(0), 0.1, H, 0.5)  # the loop's field: graded 0.5
    marks = SizeField(np.zeros((0, 3)), np.zeros(0), 0.1, H, 0.5)  # the loop's requests only
    mesh = mesh_cad(PLATE, element="quad", size=H, background_sizes=field.background(None))
    ratio = float(np.max(_longest_edges(mesh))) / H  # gmsh's longest quad edge / size asked
    sizes, asked = [], []
    for _ in range(3):  # loop over passes, as refine_mesh marks an element above the tolerance
        i = _element_at(mesh, p)
        h = float(_longest_edges(mesh)[i])
        cen = mesh.nodes[np.concatenate([np.asarray(b.data) for b in mesh.cells])[i]].mean(axis=0)
        h_new = 0.75 * min(h, float(marks(cen[None])[0]))  # refine_mesh's rule at factor 0.75
        mp, mh = element_marks(mesh, np.array([i]), np.array([h_new]))
        field.add(mp, mh)
        marks.add(mp, mh)
        sizes.append(h)
        asked.append(h_new)
        mesh = mesh_cad(PLATE, element="quad", size=H, background_sizes=field.background(mesh.nodes))
    sizes.append(float(_longest_edges(mesh)[_element_at(mesh, p)]))
    # each pass's element is within gmsh's ratio of what the pass before asked for; with marks
    # at the corners and centroid only (the old rule) the element at (70, 45) went
    # 11.1 -> 10.0 -> 11.9 -> 8.8 for 8.3, 7.5, 9.0 asked
    assert all(s <= ratio * a * 1.05 for s, a in zip(sizes[1:], asked)), (sizes, asked, ratio)
    assert sizes[-1] < 0.75 * sizes[0], (sizes, asked)



def test_next_sizes_go_below_the_field():
    """The production die's stall in numbers (pass 2 of `refine_mesh(die, 0.05, max_size=50)`,
    face PKT00338: an element with a 7.28 mm edge, marks asking 5.62 mm at its centroid,
    gmsh's background field reading 3.3-4.4 mm at its nodes). The old rule asked 0.75 x 7.28
    = 5.46 mm, above the field: min(field, mark) was the field and the same element came back.
    The next size must be below what gmsh was given; inside a mapped face (field inf) the
    element's size and the marks decide."""
    from cadbridge.tool.refine import next_sizes

    h = next_sizes(np.array([7.28, 7.28, 7.28]), np.array([0.75, 0.75, 0.75]), np.array([5.62, 5.62, np.inf]),
                   np.array([3.63, np.inf, np.inf]))
    assert np.allclose(h, [0.75 * 3.63, 0.75 * 5.62, 0.75 * 7.28])
    assert h[0] < 3.3  # below every value gmsh read at the element's nodes


def test_face_law_scale_is_the_smallest_ratio_asked_and_never_above_one():
    """`scale_face_law` by hand: face 0 gets the smaller of its two elements' ratios asked /
    law (0.6 / 1.2 = 0.5 beats 0.9 / 1.0), face 2 one ratio (0.3 / 0.5 = 0.6), face 1
    none, and an element asking more than the law (face 3: 2.0 / 1.0) or on no face (-1)
    lowers nothing."""
    from cadbridge.tool.refine import scale_face_law

    scale = np.ones(4)
    scale_face_law(scale, np.array([0, 0, 2, 3, -1]), np.array([0.9, 0.6, 0.3, 2.0, 0.1]),
                   np.array([1.0, 1.2, 0.5, 1.0, 1.0]))
    assert np.allclose(scale, [0.5, 1.0, 0.6, 1.0])



DIE_NURBS = Path(__file__).parents[2] / "iges_samples" / "production_die_nurbs.igs"


@pytest.mark.slow
def test_the_die_boss_ring_meets_0002_with_its_face_law_scaled(tmp_path):
    """Reference: the dense independent check of `refine_mesh` (11 divisions per patch,
    mostly other points than the loop's). The boss of the production die (BOS00346,
    BOS00666, BOS00965 and the fillet FTR00026, written alone): gmsh's quads on the closed
    ring BOS00666 are misshapen (corners 50-120 degrees), 9x the arc law at their size, and a
    mark only moved the worst one round the ring (5 passes, node count falling in pass 4).
    With the ring's law scaled (`scale_face_law`) t = 0.002 holds by pass 3."""
    if not DIE_NURBS.is_file():
        pytest.skip("the production die is generated by iges_samples/make_samples.py --production")
    from OCP.IGESControl import IGESControl_Reader
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    from cadbridge.tool.refine import refine_mesh
    from cadbridge.ushape.geometry import export_iges

    r = IGESControl_Reader()
    r.ReadFile(str(DIE_NURBS))
    faces = {}
    for name in ("BOS00346", "BOS00666", "BOS00965", "FTR00026"):  # root index = number - 1
        r.ClearShapes()
        assert r.TransferOneRoot(int(name[3:]))
        faces[name] = TopoDS.Face_s(TopExp_Explorer(r.OneShape(), TopAbs_FACE).Current())
    path = tmp_path / "boss.igs"
    export_iges(faces, path, "nurbs")
    res = refine_mesh(path, 0.002)
    assert res.met and res.check["max_error"] <= 0.002, res.summary()
    assert len(res.passes) <= 3, res.summary()
    assert any("law's sizes scaled" in a and "BOS00666" in a for a in res.actions), res.actions


def test_the_background_carriers_stay_from_pass_to_pass(monkeypatch):
    """The field gmsh reads in pass 3 holds every carrier of pass 2 at the same place, marks
    only added (the thesis' S surface at t = 0.0001: 3 passes). gmsh meshes a face whose
    field and boundary did not change node for node, so faces that held the tolerance keep
    their mesh; with the previous pass's nodes as carriers every carrier moved, and on the
    production die at t = 0.002 each pass gave misshapen quads to a few faces without any mark."""
    import cadbridge.mesh.generate as G
    from cadbridge.tool.refine import refine_mesh

    real, fields = G.mesh_cad, []

    def recording(*a, **kw):
        fields.append(kw["background_sizes"])
        return real(*a, **kw)

    monkeypatch.setattr(G, "mesh_cad", recording)
    r = refine_mesh(Path(__file__).parents[2] / "iges_samples" / "thesis_appendix_a.igs", 0.0001)
    assert len(fields) >= 3, r.summary()
    p2, p3 = (np.unique(np.round(f[0], 12), axis=0) for f in fields[1:3])
    both = np.concatenate([p2, p3])
    assert len(np.unique(both, axis=0)) == len(p3) > len(p2)  # pass 2's carriers all in pass 3, and more
