"""Untangle a planar mesh: move its free nodes until no element is inverted.

Splitting a coarse mesh into quads (gmsh's all-quad subdivision, and
`cadbridge.mesh.gmsh.empty_faces` after it) puts each boundary segment's midpoint on the curve,
not on the chord: where the boundary is curved and the coarse element beside it is thin,
the curve node lands beyond the element's inner nodes and the sub-quads there fold over
their neighbours (the production die's binder BND00963: 1 mm folds at its pilot holes).
Constrained Laplacian smoothing in the face's scaled (u, v) repairs that: every free node
moves towards the mean of its edge neighbours, and a move is kept only where it does not
make the worst corner of the elements around the node worse (or where that corner stays
convex enough, `GOOD_SINE`).
"""

from __future__ import annotations

import numpy as np

GOOD_SINE = 0.2
"""A corner whose sine (of the angle between its two edges) is above this is good enough: a
move that keeps every corner around a node above it is kept even if it lowers the worst."""


def corner_sines(p: np.ndarray, elems: np.ndarray) -> np.ndarray:
    """Signed sine of every corner of the counter-clockwise elements ``elems`` (E, k) over
    points ``p`` (N, 2): (E, k), negative at a reflex or inverted corner."""
    k = elems.shape[1]
    x, y = p[elems, 0], p[elems, 1]  # (E, k) each
    # the next and previous corners by a column permutation (np.roll of (E, k, 2) copies took
    # 2.5x as long on the binder's 12 000 quads, called 480 times per untangle); the same
    # numbers as before: |d| is sqrt(dx dx + dy dy) in np.linalg.norm's order
    nx, ny = x[:, _NEXT[k]] - x, y[:, _NEXT[k]] - y
    px, py = x[:, _PREV[k]] - x, y[:, _PREV[k]] - y
    cr = nx * py - ny * px
    return cr / np.maximum(np.sqrt(nx * nx + ny * ny) * np.sqrt(px * px + py * py), 1e-300)


_NEXT = {3: [1, 2, 0], 4: [1, 2, 3, 0]}
_PREV = {3: [2, 0, 1], 4: [3, 0, 1, 2]}


def _worst(p: np.ndarray, blocks: list[np.ndarray]) -> list[np.ndarray]:
    return [corner_sines(p, b).min(axis=1) if len(b) else np.zeros(0) for b in blocks]


def untangle(p: np.ndarray, blocks: list[np.ndarray], n_fixed: int, iterations: int = 60,
             relax: float = 0.7) -> tuple[np.ndarray, int]:
    """Points (N, 2) with the free nodes (index >= ``n_fixed``) of the counter-clockwise
    elements ``blocks`` (a list of (E_i, k_i) arrays: triangles, quads) smoothed as the module
    says, and the number of elements that still have a corner with a sine <= 0. ``p`` is not
    modified."""
    p = np.array(p, dtype=float)
    n = len(p)
    blocks = [np.asarray(b, dtype=np.int64) for b in blocks]
    e = np.concatenate([b[:, [i, (i + 1) % b.shape[1]]] for b in blocks if len(b) for i in range(b.shape[1])])
    e = np.unique(np.sort(e, axis=1), axis=0)
    src = np.concatenate([e[:, 0], e[:, 1]])
    dst = np.concatenate([e[:, 1], e[:, 0]])
    deg = np.bincount(src, minlength=n).astype(float)
    free = np.arange(n) >= n_fixed
    for _ in range(iterations):
        q_old = _worst(p, blocks)
        if min(float(q.min()) for q in q_old if len(q)) > GOOD_SINE:
            break
        mean = np.zeros_like(p)
        np.add.at(mean, src, p[dst])
        mean /= np.maximum(deg, 1.0)[:, None]
        move = free & (deg > 0)
        trial = p.copy()
        trial[move] += relax * (mean[move] - p[move])
        while True:  # undo the moves around every element they make worse (and not good)
            back = np.zeros(n, dtype=bool)
            for b, qo, qn in zip(blocks, q_old, _worst(trial, blocks)):
                back[b[(qn < qo) & (qn < GOOD_SINE)].ravel()] = True
            back &= move
            if not back.any():
                break
            trial[back] = p[back]
            move &= ~back
        if not move.any():
            break
        p = trial
    left = sum(int(np.sum(q <= 0.0)) for q in _worst(p, blocks))
    return p, left
