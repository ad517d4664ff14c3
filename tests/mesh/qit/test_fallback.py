"""gmsh for the faces QIT refuses (cadbridge.mesh.gmsh.planar, qit_mesh(fallback=True),
`--mesher qit`).

Reference: the analytic geometry of two planar faces (a 100 x 60 plate and the 100 x 8
strip along its edge y = 60, which the hexagonal front of QIT cannot fill at R = 5): every
vertex on its plane and inside its rectangle, normals +z, the union a conforming mesh of
the 100 x 68 rectangle (area exact, every interior edge shared by two triangles, the nodes
on y = 60 shared by both faces); the plate's own QIT mesh unchanged.
"""

import numpy as np
import pytest

from cadbridge.cli import main
from cadbridge.iges import write_iges
from cadbridge.mesh.io import read_mesh
from cadbridge.mesh.qit.mesher import QitError, qit_mesh
from cadbridge.mesh.quality import triangle_angles
from cadbridge.cad.model import Face, Model
from cadbridge.nurbs.surface import NurbsSurface


def _plane(x0, x1, y0, y1) -> NurbsSurface:
    cp = np.array([[[x0, y0, 0.0], [x0, y1, 0.0]], [[x1, y0, 0.0], [x1, y1, 0.0]]])
    return NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], cp, np.ones((2, 2)))


def _model() -> Model:
    return Model(faces=[Face(_plane(0, 100, 0, 60), de=1), Face(_plane(0, 100, 60, 68), de=3)])


def test_narrow_face_refused_without_fallback():
    with pytest.raises(QitError, match=r"face 1 \(DE 3\).*hexagonal front"):
        qit_mesh(_model(), 5.0)


def test_fallback_meshes_the_refused_face_conformally():
    model = _model()
    reps = []
    mesh = qit_mesh(model, 5.0, fallback=True, reports=reps)
    assert [r.mesher for r in reps] == ["qit", "gmsh"] and "hexagonal front" in reps[1].refused
    x, t, ef = mesh.nodes, mesh.triangles, mesh.cell_data["element_face"]
    assert np.abs(x[:, 2]).max() == 0.0
    # each face's triangles inside its rectangle, CCW about +z (the planes' Su x Sv)
    c = x[t].mean(axis=1)
    assert (c[ef == 0, 1] < 60).all() and (c[ef == 1, 1] > 60).all()
    tn = np.cross(x[t[:, 1]] - x[t[:, 0]], x[t[:, 2]] - x[t[:, 0]])
    assert (tn[:, 2] > 0).all()
    assert triangle_angles(x, t).min() > 15.0
    assert 0.5 * tn[:, 2].sum() == pytest.approx(100 * 68, rel=1e-12)  # no gap, no overlap
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    u, cnt = np.unique(e, axis=0, return_counts=True)
    assert cnt.max() == 2
    boundary = u[cnt == 1]
    bx = x[np.unique(boundary)]
    on_rim = (np.abs(bx[:, 0]) < 1e-9) | (np.abs(bx[:, 0] - 100) < 1e-9) | (np.abs(bx[:, 1]) < 1e-9) \
        | (np.abs(bx[:, 1] - 68) < 1e-9)
    assert on_rim.all()  # the only free edges are on the outer rectangle: y = 60 is conformal
    shared = np.flatnonzero(np.abs(x[:, 1] - 60) < 1e-9)
    for f in (0, 1):
        assert set(shared) <= set(np.unique(t[ef == f]))
    # the plate's QIT mesh is the one it gets alone
    alone = qit_mesh(Model(faces=[model.faces[0]]), 5.0)
    assert len(alone.triangles) == int((ef == 0).sum())


def test_mesher_qit_falls_back_through_the_cli(tmp_path):
    p = tmp_path / "plate_strip.igs"
    write_iges(_model().faces, p)
    out = tmp_path / "m.msh"
    with pytest.warns(UserWarning, match=r"face 1 \(DE 3\).*hexagonal front.*meshing it with gmsh"):
        assert main(["mesh", str(p), "--mesher", "qit", "--element", "tri", "--size", "5", "-o", str(out)]) == 0
    back = read_mesh(out)
    assert len(back.triangles) == len(qit_mesh(_model(), 5.0, fallback=True).triangles)
