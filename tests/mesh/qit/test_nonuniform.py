"""QIT on strongly non-uniform parametrisations (issue 34, item 2), and the choice between
gmsh on QIT's edge vertices and gmsh's own mesh for a face QIT still refuses.

Surfaces, generated here: rational bicubic sheets over a 100 x 100 mm (or 200 x 50 mm)
grid of control points, z a sine bump, with interior knots t^p (clustered near one end) and
weights drawn in 0.4..3.2 (ratio 8).

References: gmsh's mesh of the same IGES file at the same size (`mesh_cad`, Frontal-Delaunay,
made in the test): QIT's share of angles within 60 +- 10 deg must be at least gmsh's and
its edge-length CV at most gmsh's; OpenCASCADE's evaluation of the same NURBS at every
vertex's (u, v) (on the surface within 1e-9 x model size) and OCC's Su x Sv (no inverted
triangle), both through `check_invariants` of test_mesher.
"""

import re

import numpy as np
import pytest

from cadbridge.cad.model import Face, Model
from cadbridge.cli import main
from cadbridge.iges import read_iges, write_iges
from cadbridge.mesh.generate import mesh_cad
from cadbridge.mesh.io import read_mesh
from cadbridge.mesh.qit.mesher import QitError, qit_mesh
from cadbridge.mesh.quality import triangle_angles
from cadbridge.nurbs.surface import NurbsSurface
from tests.mesh.qit.test_mesher import check_invariants

R = 8.0


def _sheet(*, pu: float, pv: float, seed: int, n=(8, 8), size=(100.0, 100.0), amp: float = 8.0,
           vspan: float = 1.0) -> NurbsSurface:
    """Rational bicubic sheet: n control points on a uniform size[0] x size[1] grid, z =
    amp sin(pi x / L) cos(pi y / W), interior knots (k/m)^pu and (k/m)^pv (clustered near 0;
    p = 1 is uniform), v knots times ``vspan``, weights uniform in 0.4..3.2."""
    rng = np.random.default_rng(seed)

    def knots(m, p):
        return np.concatenate([np.zeros(4), (np.arange(1, m - 3) / (m - 3)) ** p, np.ones(4)])

    gx, gy = np.linspace(0, size[0], n[0]), np.linspace(0, size[1], n[1])
    cp = np.zeros((*n, 3))
    cp[..., 0], cp[..., 1] = gx[:, None], gy[None, :]
    cp[..., 2] = amp * np.sin(np.pi * gx[:, None] / size[0]) * np.cos(np.pi * gy[None, :] / size[1])
    w = 0.4 + 2.8 * rng.random(n)
    return NurbsSurface(3, 3, knots(n[0], pu), knots(n[1], pv) * vspan, cp, w)


SURFACES = {
    # knots clustered near u = 0 and v = 0 (spans 1 : 1000 in u), weights 0.4..3.2
    "clustered knots": dict(pu=5, pv=3, seed=2),
    # uniform knots, weights 0.4..3.2 (|Su| varies 4x across the sheet), a higher bump
    "strong weights": dict(pu=1, pv=1, seed=1, amp=20.0),
    # a 200 x 50 mm strip over a (u, v) box 1 x 20 (|Su| / |Sv| about 80), knots clustered in v
    "(u, v) aspect 1:20": dict(pu=1, pv=2, seed=3, n=(12, 6), size=(200.0, 50.0), vspan=20.0),
}


def angle_share(x, t):
    return float(np.mean(np.abs(triangle_angles(x, t) - 60.0) <= 10.0))


def _edge_cv(x, t):
    e = np.unique(np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1), axis=0)
    ln = np.linalg.norm(x[e[:, 0]] - x[e[:, 1]], axis=1)
    return ln.std() / ln.mean()


@pytest.mark.parametrize("name", SURFACES)
def test_qit_holds_quality_on_nonuniform_parametrisation(name, tmp_path):
    path = tmp_path / "sheet.igs"
    write_iges([Face(_sheet(**SURFACES[name]), de=1)], path)
    model = read_iges(path)
    reps = []
    mesh = qit_mesh(model, R, reports=reps)  # no fallback: QIT itself must mesh it
    assert reps[0].mesher == "qit"
    check_invariants(model, mesh, R)
    gm = mesh_cad(path, element="tri", size=R)
    share, share_g = angle_share(mesh.nodes, mesh.triangles), angle_share(gm.nodes, gm.triangles)
    cv, cv_g = _edge_cv(mesh.nodes, mesh.triangles), _edge_cv(gm.nodes, gm.triangles)
    assert share >= share_g, f"{name}: {share:.3f} of the angles within 60 +- 10 deg, gmsh {share_g:.3f}"
    assert cv <= cv_g, f"{name}: edge-length CV {cv:.3f}, gmsh {cv_g:.3f}"


def _narrow(tmp_path, weighted: bool = False):
    """A 100 x 8 mm strip alone, which the hexagonal front cannot fill at R = 5: flat and
    bilinear, or (``weighted``) a bicubic sheet with knots t^3 in u and weights 0.4..3.2,
    whose (u, v) one metric scaling cannot straighten (gmsh on QIT's edge vertices in that
    scaled (u, v) gets 21 % of its angles within 60 +- 10 deg, gmsh's own mesh 60 %)."""
    if weighted:
        s = _sheet(pu=3, pv=1, seed=2, n=(8, 4), size=(100.0, 8.0), amp=2.0)
    else:
        cp = np.array([[[0.0, 0.0, 0.0], [0.0, 8.0, 0.0]], [[100.0, 0.0, 0.0], [100.0, 8.0, 0.0]]])
        s = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], cp, np.ones((2, 2)))
    path = tmp_path / "strip.igs"
    write_iges([Face(s, de=1)], path)
    return path


@pytest.mark.parametrize("weighted, way", [(False, "gmsh"), (True, "gmsh-face")])
def test_refused_face_alone_takes_the_better_of_fallback_and_gmsh(weighted, way, tmp_path):
    """References: gmsh's own mesh is `mesh_cad` of the same file (its share recomputed
    here); OCC's evaluation of the NURBS at each vertex's (u, v) and OCC's Su x Sv."""
    from cadbridge.verify.reference import occ_bspline_surface, occ_eval

    path = _narrow(tmp_path, weighted)
    model = read_iges(path)
    with pytest.raises(QitError, match="hexagonal front"):
        qit_mesh(model, 5.0)
    reps = []
    mesh = qit_mesh(model, 5.0, fallback=True, reports=reps)
    gm = mesh_cad(path, element="tri", size=5.0)
    fb, own = (float(v) for v in re.findall(r"(\d+) %", reps[0].choice))
    assert own == pytest.approx(100 * angle_share(gm.nodes, gm.triangles), abs=0.5)
    assert 100 * angle_share(mesh.nodes, mesh.triangles) == pytest.approx(max(fb, own), abs=0.5)
    assert reps[0].mesher == way
    x, t, uv = mesh.nodes, mesh.triangles, mesh.point_data["node_uv"]
    occ = occ_bspline_surface(model.faces[0].surface)
    pts, _, _ = occ_eval(occ, uv[:, 0], uv[:, 1], order=0)
    assert np.abs(pts - x).max() <= 1e-9 * model.size()
    c = uv[t].mean(axis=1)
    _, d1, _ = occ_eval(occ, c[:, 0], c[:, 1], order=1)
    tn = np.cross(x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]])
    assert (np.einsum("ij,ij->i", tn, np.cross(d1[:, 0], d1[:, 1])) > 0).all()
    if not weighted:  # the rectangle exactly: no gap, no overlap
        assert 0.5 * tn[:, 2].sum() == pytest.approx(800.0, rel=1e-9)


def test_cli_notes_say_which_way_a_refused_face_went(tmp_path, capsys):
    path = _narrow(tmp_path, weighted=True)
    out = tmp_path / "m.msh"
    with pytest.warns(UserWarning, match=r"face 0 \(DE 1\).*hexagonal front.*meshing it with gmsh's own mesh"):
        assert main(["mesh", str(path), "--mesher", "qit", "--size", "5", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "face 0 (DE 1)" in text and "gmsh's own mesh of the face" in text and "within 60 +- 10 deg" in text
    assert len(read_mesh(out).triangles) > 0
