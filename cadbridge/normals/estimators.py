"""Vertex normals estimated from a polyhedral mesh (thesis ch. 4, eqs. 20-25).

At every element corner j the "plane" i is the one spanned by the two element edges
incident on j, e_i = x_next - x_j and e_{i+1} = x_prev - x_j (for a triangle: the
element plane; for a quadrilateral: the corner triangle).  Its unit normal
n_i = e_i x e_{i+1} / |e_i x e_{i+1}| follows the element winding, alpha_i is the angle
between the two edges.  The vertex normal is the normalised weighted sum:

    mwe     1                                  (eq. 20, Gouraud 1971)
    mwa     alpha_i                            (eq. 21, Thuermer & Wuethrich 1998)
    mwselr  sin(alpha_i) / (|e_i| |e_{i+1}|)   (eq. 22, Max 1999)
    mwaat   |e_i x e_{i+1}|                    (eq. 23)
    mwelr   1 / (|e_i| |e_{i+1}|)              (eq. 24)
    mwrelr  1 / sqrt(|e_i| |e_{i+1}|)          (eq. 25)
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

METHODS: tuple[str, ...] = ("mwe", "mwa", "mwselr", "mwaat", "mwelr", "mwrelr")


def _blocks(elements: ArrayLike | Sequence[ArrayLike]) -> list[NDArray]:
    if isinstance(elements, np.ndarray) or (
        isinstance(elements, Sequence) and len(elements) > 0 and np.ndim(elements[0]) == 1
    ):
        return [np.asarray(elements, dtype=np.int64)]
    return [np.asarray(b, dtype=np.int64) for b in elements]


def corner_weights(nodes: NDArray, conn: NDArray, method: str) -> tuple[NDArray, NDArray]:
    """Weighted corner plane normals of one element block.

    nodes (N, 3), conn (E, k) -> node ids (E*k,), weighted normals w_i n_i (E*k, 3).
    """
    k = conn.shape[1]
    xj = nodes[conn]  # (E, k, 3)
    e1 = np.roll(xj, -1, axis=1) - xj  # towards the next corner
    e2 = np.roll(xj, 1, axis=1) - xj  # towards the previous corner
    cr = np.cross(e1, e2)  # |cr| = |e1||e2| sin(alpha), direction = winding normal
    area2 = np.linalg.norm(cr, axis=-1)
    l1 = np.linalg.norm(e1, axis=-1)
    l2 = np.linalg.norm(e2, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        n = cr / area2[..., None]
        if method == "mwe":
            w = np.ones_like(area2)
        elif method == "mwa":
            w = np.arctan2(area2, np.einsum("...i,...i->...", e1, e2))
        elif method == "mwselr":
            w = area2 / (l1 * l1 * l2 * l2)  # sin(a)/(|e1||e2|) = |e1 x e2| / (|e1|^2 |e2|^2)
        elif method == "mwaat":
            w = area2
        elif method == "mwelr":
            w = 1.0 / (l1 * l2)
        elif method == "mwrelr":
            w = 1.0 / np.sqrt(l1 * l2)
        else:
            raise ValueError(f"unknown method {method!r}; expected one of {METHODS}")
        wn = n * w[..., None]
    wn = np.where(np.isfinite(wn), wn, 0.0)  # degenerate corners contribute nothing
    return conn.reshape(-1), wn.reshape(-1, 3)


def estimate_normals(
    nodes: ArrayLike, elements: ArrayLike | Sequence[ArrayLike], method: str = "mwselr"
) -> NDArray[np.float64]:
    """Unit vertex normals (N, 3) from a triangle, quadrilateral or mixed mesh.

    ``elements``: (E, 3), (E, 4) or a list of such blocks.  Orientation follows the
    element winding.  Nodes used by no element get NaN.
    """
    method = method.lower()
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; expected one of {METHODS}")
    x = np.asarray(nodes, dtype=float)
    nn = x.shape[0]
    acc = np.zeros((nn, 3))
    for conn in _blocks(elements):  # loop over element blocks (<= a few), vectorised inside
        if conn.size == 0:
            continue
        ids, wn = corner_weights(x, conn, method)
        for c in range(3):
            acc[:, c] += np.bincount(ids, weights=wn[:, c], minlength=nn)
    norm = np.linalg.norm(acc, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = acc / norm
    out[norm[:, 0] == 0] = np.nan
    return out
