"""The error measure projects the samples of all faces in one `project_to_surfaces` call
(`tool_errors._on_faces`). Reference: the per-face measure, i.e. `_on_faces` on a model made
of each face alone (one face per call, so no state is carried from one face to the next),
and for a face without crease knot lines `project_to_surface` of that face's surface.
The combined model puts a crease face (multiple_knots.igs, smooth pieces) before a smooth
one (sphere_patch.igs) and after it, so the crease branch runs between batched faces.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cadbridge.iges import read_iges
from cadbridge.cad.model import Model
from cadbridge.nurbs.project import project_to_surface
from cadbridge.tool.accuracy import _on_faces

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"


def _near(face, n, rng, offset):
    s = face.surface
    u0, u1, v0, v1 = s.domain
    u, v = rng.uniform(u0, u1, n), rng.uniform(v0, v1, n)
    nrm = s.normal(u, v)
    ok = np.all(np.isfinite(nrm), axis=1)
    return (s.evaluate(u, v) + nrm * rng.uniform(-offset, offset, (n, 1)))[ok], nrm[ok]


def test_batched_faces_equal_face_by_face():
    crease = read_iges(SAMPLES / "multiple_knots.igs").faces[0]
    smooth = read_iges(SAMPLES / "sphere_patch.igs").faces[0]
    faces = [crease, smooth, crease]
    model = Model(faces=faces)
    rng = np.random.default_rng(5)
    parts = [_near(f, 300, rng, 1e-3 * model.size()) for f in faces]
    pts = np.concatenate([p for p, _ in parts])
    ref_n = np.concatenate([n for _, n in parts])
    face = np.concatenate([np.full(len(p), k) for k, (p, _) in enumerate(parts)])
    elem = np.arange(len(pts))  # each sample its own element: its piece is that of its own foot
    dist, nrm, uv = _on_faces(model, pts, face, elem, ref_n)
    assert np.all(np.isfinite(dist)) and np.all(np.isfinite(nrm))
    tol = 1e-12 * model.size()
    for k, f in enumerate(faces):
        sel = face == k
        alone = _on_faces(Model(faces=[f]), pts[sel], np.zeros(sel.sum(), dtype=np.int64), elem[sel], ref_n[sel])
        np.testing.assert_allclose(dist[sel], alone[0], rtol=0, atol=tol)
        np.testing.assert_allclose(nrm[sel], alone[1], rtol=0, atol=1e-12)
    sel = face == 1
    pr = project_to_surface(smooth.surface, pts[sel])
    np.testing.assert_allclose(np.abs(dist[sel]), pr.distance, rtol=0, atol=tol)
