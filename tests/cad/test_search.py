"""Global projection over a model (cadbridge.cad.search.project_points).

References: analytic planes and an exact rational quarter-cylinder fillet (closest point in
closed form), and a brute-force reference that projects every point onto every face
(`project_to_surface`, N x F) and keeps the nearest valid foot.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from tests.helpers.surfaces import circle_arc, cylinder, random_surface, sphere

from cadbridge.cad.model import Face, Model, Trim, TrimLoop
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.project import BEYOND_TOLERANCE, CONVERGED, FAILED, ON_BOUNDARY, project_to_surface
from cadbridge.cad.search import build_search_index, project_points, span_boxes
from cadbridge.nurbs.surface import NurbsSurface


def plane(x0, x1, y0, y1, z=0.0) -> NurbsSurface:
    """Bilinear patch z = const over [x0, x1] x [y0, y1], u ~ x, v ~ y on [0, 1]^2; normal +z."""
    cp = np.array([[[x0, y0, z], [x0, y1, z]], [[x1, y0, z], [x1, y1, z]]], float)
    return NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], cp)


def fillet() -> NurbsSurface:
    """Quarter cylinder, axis along y through (5, *, 1), radius 1, from (5, y, 0) to (6, y, 1),
    y in [0, 10]. Built as a z-axis cylinder then rotated (x, y, z) <- (X, -Z, Y)."""
    c = cylinder(1.0, -10.0, 0.0, -math.pi / 2, 0.0)
    rot = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    return c.transformed(rot, [5.0, 0.0, 1.0])


def step_model() -> Model:
    """Floor z=0 (x in [0,5]), fillet, wall x=6 (z in [1,5]) — all for y in [0, 10]."""
    wall = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1],
                        [[[6, 0, 1], [6, 10, 1]], [[6, 0, 5], [6, 10, 5]]])
    return Model(faces=[Face(surface=plane(0, 5, 0, 10), de=1), Face(surface=fillet(), de=3), Face(surface=wall, de=5)])


def brute_force(points, model, tie=1e-9):
    """Reference: every point onto every face, nearest valid (inside trims) foot."""
    best_d = np.full(len(points), np.inf)
    best_f = np.full(len(points), -1)
    for k, face in enumerate(model.faces):
        r = project_to_surface(face.surface, points)
        ok = (r.status != FAILED) & face.contains(r.u, r.v)
        d = np.where(ok, r.distance, np.inf)
        better = d < best_d
        best_d[better], best_f[better] = d[better], k
    return best_f, best_d


def test_step_model_analytic():
    """Nearest face and foot against closed forms: floor (drop z), fillet (radial from the
    axis), wall (drop x)."""
    m = step_model()
    pts = np.array([
        [2.0, 3.0, 0.7],  # above the floor
        [5.6, 4.0, 0.6],  # inside the fillet's quarter circle
        [4.0, 7.0, 3.0],  # in front of the wall
        [5.2, 1.0, 0.1],  # near the floor/fillet seam, on the fillet side
    ])
    res = project_points(pts, m)
    assert res.face.tolist() == [0, 1, 2, 1]
    assert np.all(res.status == CONVERGED)
    assert np.allclose(res.foot[0], [2, 3, 0], atol=1e-12)
    assert np.allclose(res.foot[2], [6, 7, 3], atol=1e-12)
    for i in (1, 3):
        c = np.array([5.0, pts[i, 1], 1.0])
        d = pts[i] - c
        expect = c + d / np.linalg.norm(d)
        assert np.linalg.norm(res.foot[i] - expect) < 1e-12
        assert abs(abs(res.normal[i] @ (d / np.linalg.norm(d))) - 1) < 1e-12
        assert res.distance[i] == pytest.approx(1 - np.linalg.norm(d), abs=1e-12)
    # normals are the faces' own Su x Sv normals at the reported (u, v)
    for i in range(len(pts)):
        n = m.faces[res.face[i]].surface.normal(res.u[[i]], res.v[[i]])[0]
        assert np.allclose(n, res.normal[i], atol=1e-14)


def test_matches_brute_force_many_faces():
    """Search result == N x F brute force (same distance to 1e-12 x size; same face where the
    nearest face is unique), on a model of 12 random wavy patches, spheres and cylinders."""
    rng = np.random.default_rng(7)
    faces = []
    for k in range(8):
        s = random_surface(rng, rational=bool(k % 2), size=4.0)
        off = np.array([(k % 4) * 5.0, (k // 4) * 5.0, 0.0])
        faces.append(Face(surface=s.transformed(np.eye(3), off), de=2 * k + 1))
    faces.append(Face(surface=sphere(1.5).transformed(np.eye(3), [5, 12, 0]), de=101))
    faces.append(Face(surface=cylinder(1.0, 0, 3, 0.3, 2.5).transformed(np.eye(3), [12, 12, -1]), de=103))
    faces.append(Face(surface=sphere(2.0, 0, 3.0, -0.5, 1.0).transformed(np.eye(3), [-4, 4, 2]), de=105))
    faces.append(Face(surface=plane(-6, 20, -6, 16, -3.0), de=107))
    m = Model(faces=faces)
    size = m.size()
    pts = rng.uniform(m.bbox()[0] - 1, m.bbox()[1] + 1, (1500, 3))
    res = project_points(pts, m)
    ref_f, ref_d = brute_force(pts, m)
    assert np.all(res.status != FAILED)
    assert np.max(np.abs(res.distance - ref_d)) < 1e-12 * size
    same = res.face == ref_f
    # where faces differ the two distances tie (a point equidistant to two faces)
    assert np.all(np.abs(res.distance[~same] - ref_d[~same]) < 1e-12 * size)
    assert np.mean(same) > 0.99
    assert np.mean(res.candidates) < 4  # far fewer than the 12 faces


def _hole_trim(cu, cv, r) -> Trim:
    ctrl, w, kn = circle_arc(0.0, 2 * math.pi)
    circle = NurbsCurve(2, kn, np.column_stack([cu + r * ctrl[:, 0], cv + r * ctrl[:, 1]]), w)
    return Trim(outer=None, inner=[TrimLoop([circle])])


def test_trimmed_hole_goes_to_other_face():
    """A point above a hole in the floor: the floor's foot lies in the hole (outside the trim)
    and must not count; the face under the hole wins. Reference: analytic planes."""
    floor = Face(surface=plane(0, 10, 0, 10, 0.0), de=1, trims=_hole_trim(0.5, 0.5, 0.2))  # hole radius 2 at (5, 5)
    bottom = Face(surface=plane(4, 6, 4, 6, -1.0), de=3)
    m = Model(faces=[floor, bottom])
    pts = np.array([[5.0, 5.0, 0.3], [5.5, 4.6, 0.2], [1.0, 1.0, 0.2]])
    res = project_points(pts, m)
    assert res.face.tolist() == [1, 1, 0]
    assert np.allclose(res.foot[0], [5, 5, -1], atol=1e-12)
    assert res.distance[0] == pytest.approx(1.3, abs=1e-12)
    assert np.allclose(res.foot[2], [1, 1, 0], atol=1e-12)
    # without the bottom face the nearest point of the floor is on the rim of the hole
    # (radius 2 around (5, 5, 0)): an edge foot, as OpenCASCADE's BRepExtrema finds it
    res2 = project_points(pts[:1], Model(faces=[floor]))
    assert res2.status[0] == ON_BOUNDARY and res2.face[0] == 0
    assert res2.distance[0] == pytest.approx(np.hypot(2.0, 0.3), abs=1e-9)
    assert np.linalg.norm(res2.foot[0] - [5, 5, 0]) == pytest.approx(2.0, abs=1e-9)
    assert np.allclose(res2.normal[0], [0, 0, 1])


def test_edge_tie_prefers_containing_face():
    """Two coplanar halves: for x just right of the seam, face 1 contains the foot while face 0
    reports the same distance (in floating point) clamped to its edge; face 1 must win."""
    m = Model(faces=[Face(surface=plane(0, 5, 0, 10), de=1), Face(surface=plane(5, 10, 0, 10), de=3)])
    pts = np.array([[5.0 + 1e-12, 3.0, 1.0], [5.0 - 1e-12, 3.0, 1.0]])
    res = project_points(pts, m)
    assert res.face.tolist() == [1, 0]
    assert np.all(res.status == CONVERGED)
    # beyond every edge: nearest edge point, flagged ON_BOUNDARY
    r = project_points(np.array([[12.0, 3.0, 1.0]]), m)
    assert r.face[0] == 1 and r.status[0] == ON_BOUNDARY and np.allclose(r.foot[0], [10, 3, 0])


def test_empty_model_and_bad_points():
    with pytest.raises(ValueError, match="empty model"):
        project_points(np.zeros((3, 3)), Model(faces=[]))
    with pytest.raises(ValueError, match="node 1"):
        project_points(np.array([[0, 0, 0], [np.nan, 0, 0]]), step_model())


def test_max_distance_reports_far_points():
    """Far points: BEYOND_TOLERANCE with their real nearest foot and distance reported."""
    m = step_model()
    pts = np.array([[2.0, 3.0, 0.5], [2.0, 3.0, -50.0]])
    res = project_points(pts, m, max_distance=1.0)
    assert res.status.tolist() == [CONVERGED, BEYOND_TOLERANCE]
    assert res.face[1] == 0 and res.distance[1] == pytest.approx(50.0, abs=1e-12)
    assert np.allclose(res.foot[1], [2, 3, 0]) and np.all(np.isfinite(res.normal[1]))
    assert "BEYOND_TOLERANCE" in res.summary()


def test_span_boxes_contain_surface():
    """Strong convex hull: every sample of a span lies in that span's control-point box."""
    rng = np.random.default_rng(3)
    s = random_surface(rng, rational=True)
    boxes = span_boxes(s)
    assert len(boxes) == 4 * 4  # 4 non-empty spans in each direction
    u, v = rng.random(2000), rng.random(2000)
    x = s.evaluate(u, v)
    inside = np.all((x[:, None, :] >= boxes[None, :, 0] - 1e-12) & (x[:, None, :] <= boxes[None, :, 1] + 1e-12), axis=2)
    assert np.all(inside.any(axis=1))


def test_index_reuse():
    m = step_model()
    idx = build_search_index(m)
    pts = np.array([[2.0, 3.0, 0.7]])
    assert project_points(pts, m, index=idx).face[0] == 0


def test_index_cached_on_model_and_rebuilt_when_faces_change():
    """`index_for` builds once per model (the same object comes back, and project_points uses
    it by default); a changed face list (other length or a replaced face) gets a new index."""
    from cadbridge.cad.search import index_for

    m = step_model()
    idx = index_for(m)
    assert index_for(m) is idx
    project_points(np.array([[2.0, 3.0, 0.7]]), m)
    assert index_for(m) is idx
    m.faces.append(Face(surface=plane(0, 5, 0, 10, 7.0), de=7))
    idx2 = index_for(m)
    assert idx2 is not idx and idx2.n_faces == 4
    assert project_points(np.array([[2.0, 3.0, 6.5]]), m).face[0] == 3  # the new face is searched
    m.faces[3] = Face(surface=plane(0, 5, 0, 10, 8.0), de=7)
    assert index_for(m) is not idx2
    assert project_points(np.array([[2.0, 3.0, 6.5]]), m).distance[0] == pytest.approx(1.5, abs=1e-12)


def test_subpatch_boxes_contain_surface_and_cover_trimmed_region():
    """Strong convex hull on the Bezier sub-patches: every surface point inside the trims lies
    in a kept box of its face, and cells wholly inside a hole are dropped (fewer boxes than
    the untrimmed face). Reference: dense evaluation of the surface, `Face.contains`."""
    from cadbridge.cad.search import _face_cells

    rng = np.random.default_rng(5)
    s = random_surface(rng, rational=True)
    face = Face(surface=s, de=1, trims=_hole_trim(0.5, 0.5, 0.3))
    boxes, _, _, _ = _face_cells(face)
    full, _, _, _ = _face_cells(Face(surface=s, de=1))
    assert len(boxes) < len(full)
    u, v = rng.random(20000), rng.random(20000)
    keep = face.contains(u, v)
    x = s.evaluate(u[keep], v[keep])
    eps = 1e-12 * m_size(s)
    inside = np.all((x[:, None, :] >= boxes[None, :, 0] - eps) & (x[:, None, :] <= boxes[None, :, 1] + eps), axis=2)
    assert np.all(inside.any(axis=1))
    y = s.evaluate(u, v)
    assert np.all(np.all((y[:, None, :] >= full[None, :, 0] - eps) & (y[:, None, :] <= full[None, :, 1] + eps),
                         axis=2).any(axis=1))


def m_size(s: NurbsSurface) -> float:
    b = s.bbox()
    return float(np.linalg.norm(b[1] - b[0]))
