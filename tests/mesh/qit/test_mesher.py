"""QIT mesher (Herrero Adan & Cardoso 2020) on the paper's appendix D surfaces and trimmed
faces: the paper's Q values, the mesh invariants, conformal shared edges.

References: the paper's printed Q (sections 7.1, 7.2); OpenCASCADE's evaluation of the same
NURBS (vertices on the surface); Gauss-Legendre arc length on OCC derivatives (equal edge
segments); the analytic plate-with-hole geometry of iges_samples/trimmed_hole.igs.
"""

from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges import read_iges, read_iges_string, write_iges
from cadbridge.mesh.qit.mesher import QitError, QitOptions, discretise_edge, qit_mesh
from tests.helpers.qit_examples import example_71, example_72
from cadbridge.mesh.quality import mesh_quality, triangle_angles
from cadbridge.cad.model import Face, Model

ROOT = Path(__file__).resolve().parents[3]
REAL = ROOT.parent / "shared" / "iges_real"


def _as_128(surfaces, tmp_path) -> Model:
    """The surfaces written as IGES 128 entities and read back (the acceptance's '128')."""
    p = tmp_path / "qit_example.igs"
    write_iges([Face(s, de=2 * i + 1) for i, s in enumerate(surfaces)], p)
    m = read_iges(p)
    assert [f.entity_type for f in m.faces] == [128] * len(surfaces)
    return m


_CACHE = {}


def case_model(name: str, tmp) -> Model:
    """The model of a test case: the paper's Ex. 7.1 ("71") or 7.2 ("72") as 128 entities,
    the trimmed-hole sample ("hole") or the ANSA file (anything else; skips without it)."""
    if name == "71":
        return _as_128([example_71()], tmp)
    if name == "72":
        return _as_128(example_72(), tmp)
    if name == "hole":
        return read_iges(ROOT / "iges_samples" / "trimmed_hole.igs")
    p = REAL / "occt_OCC131-2_ANSA9.igs"
    if not p.is_file():
        pytest.skip("shared/iges_real absent")
    return read_iges(p)


def _mesh(key, tmp_path_factory):
    if key not in _CACHE:
        name, R = key
        model = case_model(name, tmp_path_factory.mktemp("qit"))
        reps = []
        _CACHE[key] = (model, qit_mesh(model, R, reports=reps), reps)
    return _CACHE[key]


def _faces_boundary(tris):
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    u, c = np.unique(e, axis=0, return_counts=True)
    return u[c == 1]


def _seg_dist(p, a, b):
    ab = b - a
    t = np.clip(np.einsum("kij,ij->ki", p[:, None] - a[None], ab) / np.einsum("ij,ij->i", ab, ab)[None], 0, 1)
    return np.linalg.norm(p[:, None] - (a[None] + t[..., None] * ab[None]), axis=2).min(axis=1)


def check_invariants(model, mesh, R):
    """The invariants of the issue, each against an independent reference."""
    from cadbridge.verify.reference import occ_bspline_surface, occ_eval

    size = model.size()
    x, tris = mesh.nodes, mesh.triangles
    nf, nuv, ef = mesh.point_data["node_face"], mesh.point_data["node_uv"], mesh.cell_data["element_face"]
    # 1. every vertex on its surface: OCC evaluates the same NURBS at the node's (u, v)
    for f in np.unique(nf):
        k = np.flatnonzero(nf == f)
        occ = occ_bspline_surface(model.faces[f].surface)
        pts, _, _ = occ_eval(occ, nuv[k, 0], nuv[k, 1], order=0)
        assert np.abs(pts - x[k]).max() <= 1e-9 * size
    # 2. no inverted or degenerate triangle: normal on the side of OCC's Su x Sv of its face
    #    at its (u, v) centroid, min angle bounded away from 0
    ang = triangle_angles(x, tris)
    assert ang.min() > 1.0, f"degenerate triangle, min angle {ang.min():.3g} deg"
    from cadbridge.nurbs.project import project_to_surface

    for f in np.unique(ef):
        t = tris[ef == f]
        surf = model.faces[f].surface
        occ = occ_bspline_surface(surf)
        p = x[t]
        # each node's (u, v) on this face (its own, or by projection for nodes made on a
        # neighbour), the triangle's (u, v) centroid, and OCC's Su x Sv there
        uvf = nuv.copy()
        other = np.flatnonzero(nf != f)
        if len(other):
            pr = project_to_surface(surf, x[other])
            uvf[other] = np.column_stack([pr.u, pr.v])
        c = uvf[t].mean(axis=1)
        _, d1, _ = occ_eval(occ, c[:, 0], c[:, 1], order=1)
        n = np.cross(d1[:, 0], d1[:, 1])
        tn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        cosang = np.einsum("ij,ij->i", n, tn) / (np.linalg.norm(n, axis=1) * np.linalg.norm(tn, axis=1))
        assert (cosang > 0).all(), f"face {f}: {np.sum(cosang <= 0)} triangles inverted"
        # 3. interior vertices at least dx_th = R/3 from the face's edge polyline
        be = _faces_boundary(t)
        inner = np.setdiff1d(np.unique(t), be.ravel())
        if len(inner):
            d = _seg_dist(x[inner], x[be[:, 0]], x[be[:, 1]])
            assert d.min() >= R / 3 * (1 - 1e-9)


@pytest.mark.parametrize("R, q_min", [(12.0, 62.0), (5.0, 80.0)])
def test_example_71_quality(R, q_min, tmp_path_factory):
    # reference: the paper's Q for Ex. 7.1: 62 % at R = 12 (reached: 67.9); at R = 5 the text
    # says 80 %, its own frequencies give 79.3 %; reached 81.2 % with the strip step
    # (docs/qit.md choice 19; the paper's construction alone gives 78.0)
    model, mesh, _ = _mesh(("71", R), tmp_path_factory)
    q = mesh_quality(mesh.nodes, mesh.triangles, R)
    assert q.q >= q_min, q.summary()


@pytest.mark.parametrize("key", [("71", 12.0), ("71", 5.0), ("72", 5.0), ("hole", 5.0)])
def test_invariants(key, tmp_path_factory):
    model, mesh, _ = _mesh(key, tmp_path_factory)
    check_invariants(model, mesh, key[1])


def test_example_72_conformal(tmp_path_factory):
    # reference: the paper's Q = 73 % for Ex. 7.2; shared edges are the semicircles of
    # radius 40 (bottom/mid) and 20 (mid/top) about (40, 40) at z = 150
    model, mesh, reps = _mesh(("72", 5.0), tmp_path_factory)
    q = mesh_quality(mesh.nodes, mesh.triangles, 5.0)
    assert q.q >= 73.0, q.summary()
    x, tris, ef = mesh.nodes, mesh.triangles, mesh.cell_data["element_face"]
    r = np.hypot(x[:, 0] - 40, x[:, 1] - 40)
    for fa, fb, rad in ((0, 1, 40.0), (1, 2, 20.0)):
        # the boundary nodes of each face on the shared curve (z = 150, near radius rad)
        sets = []
        for f in (fa, fb):
            be = np.unique(_faces_boundary(tris[ef == f]))
            sets.append(be[(np.abs(x[be, 2] - 150) < 1e-9) & (np.abs(r[be] - rad) < 2.0) & (x[be, 1] <= 40 + 1e-9)])
        assert len(sets[0]) >= round(np.pi * rad / 5) and np.array_equal(sets[0], sets[1])
        # and they are one discretisation: consecutive chords all of one length (within 1 %)
        pts = x[sets[0]]
        ch = np.linalg.norm(np.diff(pts[np.argsort(pts[:, 0])], axis=0), axis=1)  # a graph over x
        assert ch.max() / ch.min() < 1.02
    # the three faces form one conforming surface: every edge used by at most 2 triangles
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    _, cnt = np.unique(e, axis=0, return_counts=True)
    assert cnt.max() == 2


def test_edge_segments_equal_arc_length():
    # reference: Gauss-Legendre (20 points x 64 pieces) of |Su u' + Sv v'| with OCC's
    # derivatives along each boundary iso-line of Ex. 7.1
    from cadbridge.mesh.qit.mesher import _iso_loop
    from cadbridge.verify.reference import occ_bspline_surface, occ_eval

    s = example_71()
    occ = occ_bspline_surface(s)
    gx, gw = np.polynomial.legendre.leggauss(20)
    for R in (12.0, 5.0):
        for c in _iso_loop(s):
            t, _ = discretise_edge(s, c, R, 1.0)
            a, b = c.control_points
            lens = []
            for t0, t1 in zip(t[:-1], t[1:]):
                br = np.linspace(t0, t1, 65)
                tt = (0.5 * (br[1:] + br[:-1])[:, None] + 0.5 * np.diff(br)[:, None] * gx).ravel()
                uv = a + tt[:, None] * (b - a)
                _, d1, _ = occ_eval(occ, uv[:, 0], uv[:, 1], order=1)
                sp = np.linalg.norm(d1[:, 0] * (b - a)[0] + d1[:, 1] * (b - a)[1], axis=1)
                lens.append(np.sum(sp.reshape(64, 20) * gw * 0.5 * np.diff(br)[:, None]))
            lens = np.array(lens)
            ns = len(lens)
            assert ns == max(1, round(lens.sum() / R))
            assert np.abs(lens / (lens.sum() / ns) - 1).max() <= 0.01


def test_trim_curve_segments_equal_arc_length():
    # reference: the R10 hole of trimmed_hole.igs (a rational quadratic circle in (u, v) =
    # (x, y) of the plate): every segment subtends 2 pi / NS, NS = round(20 pi / R)
    model = read_iges(ROOT / "iges_samples" / "trimmed_hole.igs")
    f = model.faces[0]
    c = f.trims.inner[0].curves[0]
    for R in (5.0, 2.0):
        t, length = discretise_edge(f.surface, c, R, 1.0)
        assert length == pytest.approx(20 * np.pi, rel=0.01)
        p = c.evaluate(t)[:, :2]
        ang = np.unwrap(np.arctan2(p[:, 1] - 25, p[:, 0] - 30))
        seg = np.abs(np.diff(ang)) * 10.0  # exact arc lengths on the circle
        assert len(seg) == round(20 * np.pi / R)
        assert np.abs(seg / (20 * np.pi / len(seg)) - 1).max() <= 0.01


def test_tolerance_does_not_raise_q(tmp_path_factory):
    # the paper's Fig. 39: Q falls (does not rise) as the tolerances grow; edge 0.25 % -> 4 %,
    # surface 4x as in the paper
    s = example_71()
    model = Model(faces=[Face(s, de=1)])
    qs = []
    for tol in (0.25, 1.0, 4.0):
        mesh = qit_mesh(model, 12.0, QitOptions(size=12.0, edge_tol=tol, surface_tol=4 * tol))
        qs.append(mesh_quality(mesh.nodes, mesh.triangles, 12.0).q)
    assert qs[0] >= qs[1] >= qs[2], qs
    assert qs[0] > qs[2]  # and the tolerance matters at all


def test_trimmed_hole(tmp_path_factory):
    # reference: the plate 100 x 60 with the R10 hole about (30, 25) (iges_samples/README)
    model, mesh, _ = _mesh(("hole", 5.0), tmp_path_factory)
    x = mesh.nodes
    r = np.hypot(x[:, 0] - 30, x[:, 1] - 25)
    assert r.min() >= 10 - 1e-9
    assert (x[:, 0] >= -1e-9).all() and (x[:, 0] <= 100 + 1e-9).all()
    assert (x[:, 1] >= -1e-9).all() and (x[:, 1] <= 60 + 1e-9).all()
    hole = np.abs(r - 10) < 1e-7
    assert hole.sum() == round(2 * np.pi * 10 / 5)
    # no triangle covers the hole: its centroid is outside the R10 circle's polygon
    c = x[mesh.triangles].mean(axis=1)
    assert (np.hypot(c[:, 0] - 30, c[:, 1] - 25) > 10 * np.cos(np.pi / hole.sum()) - 1e-9).all()
    area = 0.5 * np.linalg.norm(np.cross(x[mesh.triangles[:, 1]] - x[mesh.triangles[:, 0]],
                                         x[mesh.triangles[:, 2]] - x[mesh.triangles[:, 0]]), axis=1).sum()
    hp = x[hole]
    hp = hp[np.argsort(np.arctan2(hp[:, 1] - 25, hp[:, 0] - 30))]
    hole_area = 0.5 * abs(np.sum(hp[:, 0] * np.roll(hp[:, 1], -1) - np.roll(hp[:, 0], -1) * hp[:, 1]))
    assert area == pytest.approx(6000 - hole_area, rel=1e-12)  # the plate minus the hole polygon


def test_trimmed_real_ansa(tmp_path_factory):
    model, mesh, reps = _mesh(("ansa", 5.0), tmp_path_factory)
    check_invariants(model, mesh, 5.0)
    # every vertex inside its trimmed face (exact trim curves; OCC agrees, tests/cad/test_trims.py)
    nf, nuv = mesh.point_data["node_face"], mesh.point_data["node_uv"]
    for f in np.unique(nf):
        k = nf == f
        size = model.size()
        assert model.faces[f].trims.contains(nuv[k, 0], nuv[k, 1], tol=1e-7).all()


def test_zero_jacobian_named():
    # a degenerate edge (all control points of one row equal): Su = 0 along u = 0
    s = example_71()
    cp = s.control_points.copy()
    cp[0, :] = cp[0, 0]
    from cadbridge.nurbs.surface import NurbsSurface

    bad = NurbsSurface(2, 2, s.knots_u, s.knots_v, cp, s.weights)
    model = Model(faces=[Face(example_71(), de=1), Face(bad, de=3, name="POLE")])
    with pytest.raises(QitError, match=r"face 1 \(DE 3 'POLE'\).*Jacobian"):
        qit_mesh(model, 12.0)


def test_sliver_of_collinear_edge_vertices_is_flipped():
    # three vertices of one straight edge joined into a flat triangle (what an extrapolated
    # pattern position can give on a face too small for an interior lattice): the flip of
    # its longest edge leaves two proper triangles; reference: exact geometry of the square
    from cadbridge.mesh.qit.mesher import _fix_slivers

    x = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [1, 1, 0]], dtype=float)
    uv = x[:, :2]
    tris = np.array([[0, 1, 2], [0, 2, 3]])  # [0, 1, 2] is flat
    out, n = _fix_slivers(tris, x, uv, {(0, 1), (1, 2), (2, 3), (0, 3)})
    assert n == 1
    assert sorted(map(sorted, out.tolist())) == [[0, 1, 3], [1, 2, 3]]
    ang = triangle_angles(x, out)
    assert ang.min() == pytest.approx(45.0)


def test_folded_face_is_named_not_meshed():
    # ANSA's 6 mm fillet (|Sv| varies 25x across it) at R = 2: the lattice leaves a gap that
    # the CDT bridges with triangles folded against the surface; QIT stops naming the face
    p = REAL / "occt_OCC131-2_ANSA9.igs"
    if not p.is_file():
        pytest.skip("shared/iges_real absent")
    model = read_iges(p)
    with pytest.raises(QitError, match=r"face 0 \(DE 1 'FACE\(274\)'\).*folded"):
        qit_mesh(model, 2.0, faces=[0])


@pytest.mark.slow
def test_ansa_other_faces_at_small_size():
    # the two other faces of the ANSA file at R = 2 keep all invariants
    p = REAL / "occt_OCC131-2_ANSA9.igs"
    if not p.is_file():
        pytest.skip("shared/iges_real absent")
    model = read_iges(p)
    mesh = qit_mesh(model, 2.0, faces=[1, 2])
    check_invariants(model, mesh, 2.0)
