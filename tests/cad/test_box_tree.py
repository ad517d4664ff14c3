"""`cadbridge.cad.box_tree.BoxTree.pairs` against a brute-force reference: every (point, box)
pair's lower bound (distance to the box, and to the slab) computed for all pairs in numpy,
kept where it is within the point's bound, reduced to the least bound per (point, face)."""

import numpy as np
import pytest

from cadbridge.cad.box_tree import BoxTree


def brute(pts, bound, excl, lo, hi, slab, face):
    g = np.maximum(np.maximum(lo[None] - pts[:, None], pts[:, None] - hi[None]), 0.0)  # (N, B, 3)
    d = np.sqrt((g[..., 0] ** 2 + g[..., 1] ** 2) + g[..., 2] ** 2)
    s = ((pts[:, None, 0] * slab[None, :, 0]) + pts[:, None, 1] * slab[None, :, 1]) + pts[:, None, 2] * slab[None, :, 2]
    lb = np.maximum(d, np.maximum(slab[None, :, 3] - s, s - slab[None, :, 4]))
    ok = (lb <= bound[:, None]) & (face[None] != excl[:, None])
    out = {}
    for i, j in zip(*np.nonzero(ok)):
        k = (int(i), int(face[j]))
        out[k] = min(out.get(k, np.inf), lb[i, j])
    return out


def random_boxes(rng, b, n_faces):
    c = rng.uniform(-50, 50, (b, 3))
    h = rng.uniform(0.01, 1.0, (b, 3)) * rng.choice([1.0, 10.0], (b, 1))  # small and large boxes mixed
    n = rng.normal(size=(b, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    s = np.einsum("ij,ij->i", c, n)
    w = rng.uniform(0.0, 2.0, b)
    slab = np.column_stack([n, s - w, s + w])
    slab[::7, 3], slab[::7, 4] = -np.inf, np.inf  # unbounded slabs (degenerate nets)
    return c - h, c + h, slab, rng.integers(0, n_faces, b)


@pytest.mark.parametrize("b, n_faces, radius", [(1, 1, 5.0), (3, 2, 20.0), (500, 40, 6.0), (2000, 300, 30.0)])
def test_pairs_equal_brute_force(b, n_faces, radius):
    rng = np.random.default_rng(b)
    lo, hi, slab, face = random_boxes(rng, b, n_faces)
    pts = rng.uniform(-60, 60, (700, 3))
    bound = rng.uniform(0.0, radius, len(pts))
    excl = np.where(rng.random(len(pts)) < 0.5, rng.integers(0, n_faces, len(pts)), -1)
    p, f, low = BoxTree(lo, hi, slab, face).pairs(pts, bound, excl)
    got = {(int(a), int(c)): x for a, c, x in zip(p, f, low)}
    assert len(got) == len(p)  # each (point, face) once
    ref = brute(pts, bound, excl, lo, hi, slab, face)
    assert got.keys() == ref.keys()
    assert all(got[k] == ref[k] for k in ref)  # the same arithmetic: equal bits
    if radius == 30.0:  # points with more faces than the first walk holds (walked again)
        assert np.bincount(p).max() > 8


def test_no_boxes_no_points():
    rng = np.random.default_rng(0)
    lo, hi, slab, face = random_boxes(rng, 10, 3)
    z = np.zeros((0, 3))
    assert all(len(a) == 0 for a in BoxTree(lo, hi, slab, face).pairs(z, np.zeros(0), np.zeros(0, dtype=int)))
    empty = BoxTree(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 5)), np.zeros(0, dtype=int))
    assert all(len(a) == 0 for a in empty.pairs(np.zeros((4, 3)), np.ones(4), -np.ones(4, dtype=int)))
