"""Bounding volume hierarchy of a model's sub-patch boxes, with a compiled query of every
(point, face) pair whose box / slab lower bound lies within a per-point bound.

The tree (`BoxTree`) is a complete binary tree over the boxes sorted by the Morton code of
their centres: leaves of ``LEAF`` consecutive boxes, node boxes merged bottom-up (heap
layout: node 1 is the root, node k has children 2k and 2k + 1, leaf j is node P + j).
Build cost ~ B log B (one sort); a query walks only the nodes whose box lies within the
point's bound, ~ log B + the boxes it returns.

The pair test at the leaves is the exact lower bound of the distance from the point to the
box's sub-patch: the larger of the distance to the box and to the slab {x: smin <= n.x <=
smax} holding the sub-patch (`cadbridge.cad.search._slabs`).
"""

from __future__ import annotations

import numba
import numpy as np

LEAF = 4  # boxes per leaf
_BLOCK = 512  # points per parallel task (one traversal stack each)
_STACK = 128  # deeper than any tree of < 2^60 leaves needs
_CAP = 8  # faces per point held on the first walk (more: walked again with 4 x as many)


def _morton(c: np.ndarray) -> np.ndarray:
    """30-bit Morton codes (M,) uint64 of points c (M, 3), 10 bits per axis over their box."""
    lo, hi = c.min(axis=0), c.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    q = np.clip(((c - lo) / span * 1023.0).astype(np.int64), 0, 1023).astype(np.uint64)

    def spread(x):  # bit i of x to bit 3 i
        x = (x | (x << np.uint64(16))) & np.uint64(0x030000FF)
        x = (x | (x << np.uint64(8))) & np.uint64(0x0300F00F)
        x = (x | (x << np.uint64(4))) & np.uint64(0x030C30C3)
        return (x | (x << np.uint64(2))) & np.uint64(0x09249249)

    return spread(q[:, 0]) | (spread(q[:, 1]) << np.uint64(1)) | (spread(q[:, 2]) << np.uint64(2))


class BoxTree:
    """BVH of boxes lo, hi (B, 3) with slabs (B, 5) and the face (B,) of each box.

    order (B,): box indices in Morton order; node_lo, node_hi (2 P, 3): node boxes (P leaves,
    a power of two; empty leaves are the empty box +inf .. -inf, which no query enters)."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, slab: np.ndarray, face: np.ndarray) -> None:
        b = len(lo)
        self.lo = np.ascontiguousarray(lo, dtype=float)
        self.hi = np.ascontiguousarray(hi, dtype=float)
        self.slab = np.ascontiguousarray(slab, dtype=float)
        self.face = np.ascontiguousarray(face, dtype=np.int64)
        self.order = (np.argsort(_morton(0.5 * (self.lo + self.hi)), kind="stable") if b else
                      np.zeros(0, dtype=np.int64)).astype(np.int64)
        n_leaf = max(1, -(-b // LEAF))
        p = 1 << int(np.ceil(np.log2(n_leaf))) if n_leaf > 1 else 1
        self.p = p
        node_lo = np.full((2 * p, 3), np.inf)
        node_hi = np.full((2 * p, 3), -np.inf)
        if b:
            pad = p * LEAF - b  # leaves: LEAF consecutive sorted boxes, padded with empty boxes
            slo = np.concatenate([self.lo[self.order], np.full((pad, 3), np.inf)]).reshape(p, LEAF, 3)
            shi = np.concatenate([self.hi[self.order], np.full((pad, 3), -np.inf)]).reshape(p, LEAF, 3)
            node_lo[p:] = slo.min(axis=1)
            node_hi[p:] = shi.max(axis=1)
            k = p
            while k > 1:  # parents of nodes k .. 2k - 1 are k / 2 .. k - 1
                h = k // 2
                node_lo[h:k] = np.minimum(node_lo[k:2 * k:2], node_lo[k + 1:2 * k:2])
                node_hi[h:k] = np.maximum(node_hi[k:2 * k:2], node_hi[k + 1:2 * k:2])
                k = h
        self.node_lo, self.node_hi = node_lo, node_hi

    def pairs(self, pts: np.ndarray, bound: np.ndarray, exclude: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every (point, face) pair with a box of that face whose lower bound is <= the point's
        bound (finite, (N,)), faces equal to ``exclude`` (N,) (-1: none) left out.

        Returns point indices (M,), faces (M,) and the least lower bound over the pair's
        boxes (M,), one row per pair, sorted by point (faces in the order found)."""
        pts = np.ascontiguousarray(pts, dtype=float)
        bound = np.ascontiguousarray(bound, dtype=float)
        exclude = np.ascontiguousarray(exclude, dtype=np.int64)
        n = len(pts)
        if n == 0 or len(self.lo) == 0:
            z = np.zeros(0, dtype=np.int64)
            return z, z, np.zeros(0)
        rows = np.arange(n, dtype=np.int64)
        cap = _CAP
        out_p, out_f, out_l = [], [], []
        while len(rows):  # points with more than ``cap`` faces in their bound: again, with 4 x cap
            face = np.empty((len(rows), cap), dtype=np.int64)
            low = np.empty((len(rows), cap))
            count = np.empty(len(rows), dtype=np.int64)
            _query(pts, bound, exclude, rows, self.node_lo, self.node_hi, self.p, self.order, self.lo, self.hi,
                   self.slab, self.face, face, low, count)
            done = count <= cap
            c = count[done]
            take = np.arange(cap) < c[:, None]
            out_p.append(np.repeat(rows[done], c))
            out_f.append(face[done][take])
            out_l.append(low[done][take])
            rows, cap = rows[~done], 4 * cap
        return np.concatenate(out_p), np.concatenate(out_f), np.concatenate(out_l)


@numba.njit(cache=True, error_model="numpy", nogil=True, parallel=True)
def _query(pts, bound, exclude, rows, node_lo, node_hi, p, order, box_lo, box_hi, box_slab, box_face, out_face, out_low,
           count):  # pragma: no cover - compiled
    """Walk the tree for the points ``rows``: out_face[r, :count[r]] the faces (each once) of
    row r's pairs and out_low their least bounds; count[r] = cap + 1 if it has more faces
    than the cap (out_face.shape[1]) holds."""
    nb = box_lo.shape[0]
    cap = out_face.shape[1]
    nr = rows.shape[0]
    for blk in numba.prange((nr + _BLOCK - 1) // _BLOCK):
        stack = np.empty(_STACK, dtype=np.int64)
        for r in range(blk * _BLOCK, min(nr, (blk + 1) * _BLOCK)):
            i = rows[r]
            b = bound[i]
            ex = exclude[i]
            x0, x1, x2 = pts[i, 0], pts[i, 1], pts[i, 2]
            m = 0
            top = 0
            stack[0] = 1
            while top >= 0 and m <= cap:
                k = stack[top]
                top -= 1
                g0 = max(node_lo[k, 0] - x0, x0 - node_hi[k, 0], 0.0)
                g1 = max(node_lo[k, 1] - x1, x1 - node_hi[k, 1], 0.0)
                g2 = max(node_lo[k, 2] - x2, x2 - node_hi[k, 2], 0.0)
                if np.sqrt(g0 * g0 + g1 * g1 + g2 * g2) > b:
                    continue
                if k < p:
                    top += 1
                    stack[top] = 2 * k + 1
                    top += 1
                    stack[top] = 2 * k
                    continue
                s0 = (k - p) * LEAF
                for s in range(s0, min(s0 + LEAF, nb)):
                    j = order[s]
                    f = box_face[j]
                    if f == ex:
                        continue
                    q2 = 0.0
                    sx = 0.0
                    for c in range(3):
                        x = pts[i, c]
                        g = max(box_lo[j, c] - x, x - box_hi[j, c], 0.0)
                        q2 += g * g
                        sx += box_slab[j, c] * x
                    lb = max(np.sqrt(q2), box_slab[j, 3] - sx, sx - box_slab[j, 4])
                    if lb > b:
                        continue
                    t = 0
                    while t < m and out_face[r, t] != f:
                        t += 1
                    if t < m:
                        if lb < out_low[r, t]:
                            out_low[r, t] = lb
                    elif m < cap:
                        out_face[r, m] = f
                        out_low[r, m] = lb
                        m += 1
                    else:
                        m = cap + 1  # overflow: this row is walked again with a larger cap
                        break
            count[r] = m
