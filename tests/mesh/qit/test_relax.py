"""Valence flips, spring relocation and the max-angle clean-up after QIT
(cadbridge.mesh.qit.relax; QitOptions(strip_opt=True), the default).

References: the exact triangular lattice on a tilted plane (relocation returns a perturbed
vertex to it, on the surface); the strip of equilateral triangles along a straight edge,
whose boundary vertices all have valence 3 (the BIT of the paper's appendix C); the mesh
invariants of tests/mesh/qit/test_mesher.py against OpenCASCADE; the paper's own mesh of each face
(strip_opt=False), which the step must not worsen; the issue's Q bounds.
"""

import numpy as np
import pytest

from cadbridge.mesh.qit.mesher import QitOptions, qit_mesh
from cadbridge.mesh.qit.relax import relax_vertices, valence_flips, vertex_angle_sums
from cadbridge.mesh.quality import mesh_quality, triangle_angles
from cadbridge.nurbs.surface import NurbsSurface
from tests.mesh.qit.test_mesher import case_model, check_invariants


def _tilted_plane() -> NurbsSurface:
    # x = (u, v, 0.5 u) over [0, 100]^2: |Su| = 1.118, |Sv| = 1 (so (u, v) is not isometric)
    cp = np.array([[[0, 0, 0], [0, 100, 0]], [[100, 0, 50], [100, 100, 50]]], dtype=float)
    return NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], cp, np.ones((2, 2)))


def test_relocation_restores_the_lattice_on_a_tilted_plane():
    s = _tilted_plane()
    R = 5.0
    e1 = np.array([1.0, 0.0, 0.5]) / np.sqrt(1.25)  # orthonormal frame of the plane
    e2 = np.array([0.0, 1.0, 0.0])
    n = 6
    ij = np.array([(i, j) for j in range(n) for i in range(n)])
    x3 = np.array([20.0, 20.0, 10.0]) + R * (ij[:, :1] + 0.5 * ij[:, 1:]) * e1 + R * (np.sqrt(3) / 2) * ij[:, 1:] * e2
    uv = np.column_stack([x3[:, 0] / 100.0, x3[:, 1] / 100.0])  # exact inverse of the plane
    k = lambda i, j: j * n + i  # noqa: E731
    tris = []
    for j in range(n - 1):
        for i in range(n - 1):
            tris += [(k(i, j), k(i + 1, j), k(i, j + 1)), (k(i + 1, j), k(i + 1, j + 1), k(i, j + 1))]
    tris = np.array(tris)
    exact = x3.copy()
    free = np.zeros(len(uv), dtype=bool)
    c = k(2, 2)
    free[c] = True
    # perturb the centre vertex by 0.2 R along the plane
    uv[c] += np.array([0.2 * R * e1[0], 0.2 * R * 0.7]) / 100.0
    x = s.evaluate(uv[:, 0], uv[:, 1])
    ang0 = triangle_angles(x, tris).min()
    uv2, x2, moved = relax_vertices(tris, uv, x, free, s, R, lambda a, b: np.ones(len(a), dtype=bool), iters=60)
    assert moved == 1
    assert np.linalg.norm(x2[c] - exact[c]) < 1e-6 * R  # back on the lattice
    assert np.abs(x2 - s.evaluate(uv2[:, 0], uv2[:, 1])).max() <= 1e-12 * 100  # on the surface
    assert np.array_equal(x2[~free], x[~free])  # nothing else moved
    assert triangle_angles(x2, tris).min() > ang0


def _flip_strip(x: np.ndarray, **kw):
    """The strip b0..b3 (on the edge y = 0), i0..i2 above, with the diagonal b1-i1 flipped
    to b2-i0, through valence_flips (options ``kw``) with its outline as constraints:
    (defect, out, flips)."""
    b0, b1, b2, b3, i0, i1, i2 = range(7)
    defect = np.array([(b0, b1, i0), (b1, b2, i0), (b2, i1, i0), (b2, i2, i1), (b2, b3, i2)])
    loop = [b0, b1, b2, b3, i2, i1, i0]
    cons = {(min(p, q), max(p, q)) for p, q in zip(loop, loop[1:] + loop[:1])}
    alpha = vertex_angle_sums(defect, x, np.ones(7, dtype=bool))
    out, n = valence_flips(defect, x[:, :2], x, alpha, cons, **kw)
    return defect, out, n


def test_valence_flip_restores_the_strip_along_a_straight_edge():
    # equilateral strip along y = 0: b0..b3 on the edge, i0..i2 at height sqrt(3)/2; the
    # diagonal b1-i1 flipped to b2-i0 gives b1 2 triangles and b2 4; the flip rule brings
    # every edge vertex back to 3 (and the triangles back to equilateral)
    h = np.sqrt(3) / 2
    x = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [0.5, h, 0], [1.5, h, 0], [2.5, h, 0]], dtype=float)
    b0, b1, b2, b3, i0, i1, i2 = range(7)
    defect, out, n = _flip_strip(x)
    assert n == 1
    val = np.bincount(out.ravel(), minlength=7)
    assert val[b1] == val[b2] == 3
    assert triangle_angles(x, out).min() == pytest.approx(60.0)


def test_valence_flip_respects_the_angle_guard():
    # the same defect with i0, i1 moved: the flip would lower the mean-angle deviation but
    # make a 128-degree angle where the pair has 97 at most: refused (max(97, 120) < 128)
    h = np.sqrt(3) / 2
    x = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [1.054, 0.461, 0], [1.454, 0.703, 0], [2.5, h, 0]])
    b0, b1, b2, b3, i0, i1, i2 = range(7)
    defect, out, n = _flip_strip(x)
    new = np.array([(b1, i1, i0), (b1, b2, i1)])
    assert triangle_angles(x, defect[1:3]).max() < 100.0 and triangle_angles(x, new).max() > 125.0
    assert n == 0 and np.array_equal(out, defect)
    _, _, n_free = _flip_strip(x, min_angle=0.0, max_angle=180.0)
    assert n_free == 1  # without the guard the valence rule alone would flip it


_CACHE = {}


def _mesh(key, tmp_path_factory, **kw):
    ck = key + tuple(sorted(kw.items()))
    if ck not in _CACHE:
        name, R = key
        model = case_model(name if name in ("71", "72") else "hole", tmp_path_factory.mktemp("qit_relax"))
        _CACHE[ck] = (model, qit_mesh(model, R, QitOptions(size=R, **kw)))
    return _CACHE[ck]


@pytest.mark.parametrize("key", [("71", 12.0), ("71", 5.0), ("72", 5.0), ("hole", 5.0)])
def test_strip_opt_does_not_worsen_the_paper_mesh(key, tmp_path_factory):
    # reference: the paper's construction of the same faces (strip_opt=False): Q not lower,
    # smallest angle not smaller, largest not larger, angle and size spread not wider
    model, mesh = _mesh(key, tmp_path_factory)
    _, base = _mesh(key, tmp_path_factory, strip_opt=False)
    q, q0 = (mesh_quality(m.nodes, m.triangles, key[1]) for m in (mesh, base))
    assert q.q >= q0.q - 1e-9, (q.q, q0.q)
    assert q.angles.min() >= q0.angles.min() - 1e-9
    assert q.angles.max() <= q0.angles.max() + 1e-9
    assert q.angles.std() <= q0.angles.std() + 1e-9
    assert q.summary()["size_rel_std"] <= q0.summary()["size_rel_std"] + 1e-9


@pytest.mark.parametrize("key, q_min", [(("71", 12.0), 62.0), (("71", 5.0), 80.0), (("72", 5.0), 73.0)])
def test_issue_q_bounds(key, q_min, tmp_path_factory):
    # reference: the issue's Q for the paper's examples (62 / 80 / 73 %); measured 67.9,
    # 81.2, 82.2 (the paper's construction alone: 67.7, 78.0, 79.1; docs/qit.md choice 19)
    model, mesh = _mesh(key, tmp_path_factory)
    q = mesh_quality(mesh.nodes, mesh.triangles, key[1])
    assert q.q >= q_min, q.summary()


@pytest.mark.parametrize("key", [("71", 5.0), ("72", 5.0)])
def test_strip_opt_invariants(key, tmp_path_factory):
    # test_mesher.py checks the invariants on the default meshes of all its cases; here the
    # step is shown to have been taken (not reverted) where it is measured
    model, mesh = _mesh(key, tmp_path_factory)
    check_invariants(model, mesh, key[1])
    reps = []
    qit_mesh(model, key[1], reports=reps)
    assert any(not r.strip_reverted and r.valence_flips > 0 and r.relaxed > 0 for r in reps)
