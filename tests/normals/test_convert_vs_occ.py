"""The normals `convert` writes, against OpenCASCADE, on the real IGES files of the corpus
(../shared/iges_real; skipped when absent). Issue 8, "Conversion": node normals are finite
unit vectors everywhere, and at interior nodes they are OCC's face normal within 1e-9 rad.

The mesh is convert's own (gmsh through `mesh_cad`, default size, no curvature sizing to
keep the test fast), the normals come from `cad_normals(..., orient=True)` as in convert:
global search, orientation from the element winding, one-sided normals at creases.

Reference: OCC `BRepExtrema_DistShapeShape` from each node to the compound of all faces:
a node counts as interior when OCC's unique nearest point lies inside a face, farther than
the face's trim tolerance delta (see tests/cad/test_search_vs_occ_real.py) from every edge, and the
node carries one normal (no crease). OCC's normal there is `BRepAdaptor_Surface.D1` at
OCC's (u, v); compared sign-insensitively (OCC faces may be reversed, ours follow the mesh).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.cad.test_search_vs_occ_real import ANGLE, FILES, _face_delta
from tests.helpers import occ as OCC

pytestmark = pytest.mark.skipif(not FILES, reason="../shared/iges_real not present")

MAX_NODES = 80  # interior candidates checked against OCC per file (a Python loop over BRepExtrema)


@pytest.mark.parametrize("path", FILES, ids=[p.name for p in FILES])
def test_convert_node_normals_match_occ(path: Path):
    pytest.importorskip("OCP")
    pytest.importorskip("gmsh")
    from OCP.BRepExtrema import BRepExtrema_IsInFace
    from OCP.TopoDS import TopoDS

    from cadbridge.iges import read_iges
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.normals.cad import cad_normals
    from cadbridge.nurbs.project import CONVERGED
    from cadbridge.verify.reference import occ_read_shape

    model = read_iges(path)
    size = model.size()
    from cadbridge.heal.mesh_source import mesh_source

    # as convert meshes it: faces the reader re-read (the SolidWorks sphere caps) come from
    # the file's model-space curves, for gmsh and for the OCC reference below; faces gmsh
    # leaves empty (the Inventor spring's) are meshed by cadbridge.mesh.gmsh.empty_faces
    with mesh_source(path, model) as src:
        mesh = mesh_cad(src)
        shape = occ_read_shape(src)
    res = cad_normals(mesh, model, orient=True, allow_far=True)
    n = res.normals
    assert np.all(np.isfinite(n)), "non-finite node normals"
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    for cn in res.corner_normals:
        assert np.all(np.isfinite(cn))
        np.testing.assert_allclose(np.linalg.norm(cn, axis=2), 1.0, atol=1e-12)

    faces, edges = OCC.faces(shape), OCC.edges(shape)
    face_set, edge_set = OCC.compound(faces), OCC.compound(edges)
    face_delta = np.array([_face_delta(model.faces[k], faces[k], size) for k in range(len(faces))])
    cand = np.flatnonzero((res.status == CONVERGED) & ~res.crease & (res.distance <= 1e-6 * size))
    rng = np.random.default_rng(0)
    if len(cand) > MAX_NODES:
        cand = np.sort(rng.choice(cand, MAX_NODES, replace=False))
    checked, fails = 0, []
    for i in cand:
        x = res.mesh.nodes[i]
        d = OCC.dist_shape_shape(OCC.vertex(x), face_set)
        if d.NbSolution() != 1 or d.SupportTypeShape2(1) != BRepExtrema_IsInFace:
            continue
        foot = np.array(d.PointOnShape2(1).Coord())
        support = d.SupportOnShape2(1)
        k_occ = next(k for k, f in enumerate(faces) if f.IsSame(support))
        delta = max(face_delta[res.face[i]], face_delta[k_occ])  # per face, as in test_search_vs_occ_real
        if OCC.dist_shape_shape(OCC.vertex(foot), edge_set).Value() <= delta:
            continue
        checked += 1
        n_occ = OCC.face_normal(TopoDS.Face_s(d.SupportOnShape2(1)), *d.ParOnFaceS2(1))
        ang = float(np.arcsin(min(1.0, np.linalg.norm(np.cross(n_occ, n[i])))))
        if ang > ANGLE:
            fails.append(f"node {i} at {x.tolist()}: normal {ang:.3g} rad from OCC's (our face {res.face[i]})")
    assert not fails, f"{len(fails)} of {checked} interior nodes of {path.name}:\n" + "\n".join(fails[:10])
    assert checked >= min(10, len(cand) // 4), f"only {checked} of {len(cand)} candidates are interior for OCC"
