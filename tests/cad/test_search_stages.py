"""The two-stage search of `project_points` (Newton first, the checks only where needed).

References: the one-call `project_to_surfaces` (the Newton stage resumed with the checks must
give it bit for bit), the brute force of tests/cad/test_search.py (every point onto every face,
nearest valid foot) and the step model's closed forms (floor z = 0, quarter-cylinder fillet).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from tests.cad.test_search import brute_force, step_model

from cadbridge.iges import read_iges
from cadbridge.nurbs.project import CONVERGED
from cadbridge.nurbs.project_many import newton_is_final, newton_to_surfaces, project_to_surfaces
from cadbridge.cad.search import index_for, project_points

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"


def test_newton_then_resume_equals_one_call():
    """newton_to_surfaces + project_to_surfaces(resume=...) == project_to_surfaces, exactly,
    on the U-shape tools (24 faces): points on the faces, off them and far away; final
    Newton pairs are already the one-call result."""
    model = read_iges(SAMPLES / "ushape_tools_nurbs.igs")
    pack = index_for(model).surface_pack(model)
    rng = np.random.default_rng(5)
    single = np.flatnonzero(pack.single)
    which, pts = [], []
    for f in single:
        s = model.faces[f].surface
        u0, u1, v0, v1 = s.domain
        u, v = rng.uniform(u0, u1, 40), rng.uniform(v0, v1, 40)
        off = np.where(np.arange(40) < 15, 0.0, rng.uniform(-20.0, 20.0, 40))  # 15 on the surface
        pts.append(s.evaluate(u, v) + off[:, None] * s.normal(u, v))
        which.append(np.full(40, f))
    which, pts = np.concatenate(which), np.concatenate(pts)
    perm = rng.permutation(len(which))  # pairs in no particular order
    which, pts = which[perm], pts[perm]
    ref = project_to_surfaces(pack, which, pts)
    first_stage, first = newton_to_surfaces(pack, which, pts)
    done = project_to_surfaces(pack, which, pts, resume=(first_stage, first))
    for name in ("u", "v", "foot", "distance", "normal", "status"):
        np.testing.assert_array_equal(getattr(done, name), getattr(ref, name), err_msg=name)
    final = newton_is_final(pack, which, first_stage)
    assert final.sum() >= 0.5 * 15 * len(single)  # the on-surface points are final after Newton
    for name in ("u", "v", "foot", "distance", "normal", "status"):
        np.testing.assert_array_equal(getattr(first_stage, name)[final], getattr(ref, name)[final], err_msg=name)


def test_newton_stage_refuses_creased_surfaces():
    """A surface with an internal C0 knot line (`multiple_knots.igs`: u knot 2 of
    multiplicity 3) needs the whole projection over its smooth pieces; project_points on it
    still equals the brute force (nearest of the one face)."""
    model = read_iges(SAMPLES / "multiple_knots.igs")
    pack = index_for(model).surface_pack(model)
    assert not pack.single[0]
    with pytest.raises(ValueError, match="crease"):
        newton_to_surfaces(pack, [0], np.zeros((1, 3)))
    s = model.faces[0].surface
    u0, u1, v0, v1 = s.domain
    rng = np.random.default_rng(2)
    u, v = rng.uniform(u0, u1, 500), rng.uniform(v0, v1, 500)
    u[:50] = 2.0  # on the crease line
    pts = s.evaluate(u, v)
    res = project_points(pts, model)
    _, bd = brute_force(pts, model)
    np.testing.assert_allclose(res.distance, bd, rtol=0, atol=1e-12 * model.size())


def test_nodes_next_to_a_face_border_match_brute_force():
    """Mesh-node-like points on the step model's floor (z = 0) and fillet near their shared
    line x = 5, and on the line itself: many have their nearest index sample on the other
    face (the case the on-model candidate stage serves). Each lies on the model (distance 0
    up to round-off), its face holds the foot, the distance equals the brute force's, and on
    the floor the normal is +-z (closed form)."""
    model = step_model()
    rng = np.random.default_rng(11)
    n = 3000
    x = 5.0 - rng.uniform(0.0, 0.3, n)  # floor, up to 0.3 from the fillet
    x[:200] = 5.0  # on the shared line
    y = rng.uniform(0.0, 10.0, n)
    floor = np.column_stack([x, y, np.zeros(n)])
    t = rng.uniform(0.0, 0.3, n)  # fillet: angle from the floor's tangent line
    fillet = np.column_stack([5.0 + np.sin(t), rng.uniform(0.0, 10.0, n), 1.0 - np.cos(t)])
    pts = np.concatenate([floor, fillet])
    idx = index_for(model)
    _, si = idx.sample_tree.query(pts)
    res = project_points(pts, model, index=idx)
    bf, bd = brute_force(pts, model)
    assert np.all(res.status == CONVERGED)
    assert np.all(res.distance <= 1e-12 * idx.size)
    np.testing.assert_allclose(res.distance, bd, rtol=0, atol=1e-12 * idx.size)
    for k, face in enumerate(model.faces):  # the chosen face holds its foot
        sel = res.face == k
        assert np.all(face.contains(res.u[sel], res.v[sel]))
    on_floor = np.flatnonzero(res.face[:n] == 0)
    np.testing.assert_allclose(np.abs(res.normal[on_floor, 2]), 1.0, atol=1e-12)
    # the stage is exercised: points whose nearest sample lies on another face than the chosen one
    assert np.count_nonzero(idx.sample_face[si] != res.face) > 100
