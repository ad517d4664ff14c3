"""Triangular and quadrilateral Nagata patches (thesis eqs. 4-13), vectorised over patches.

Coefficient order (thesis / appendix D):
  triangle       c00 c10 c01 c11 c20 c02               -> (E, 6, 3), 0 <= zeta <= eta <= 1
  quadrilateral  c00 c10 c01 c11 c20 c02 c21 c12       -> (E, 8, 3), 0 <= eta, zeta <= 1
Corner order: triangle x00 x10 x11; quadrilateral x00 x10 x11 x01.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

# local edges as (first corner, second corner); xi runs from the first to the second corner
TRI_EDGES = np.array([[0, 1], [1, 2], [0, 2]])  # c1, c2, c3 (thesis eq. 6)
QUAD_EDGES = np.array([[0, 1], [1, 2], [3, 2], [0, 3]])  # c1, c2, c3, c4 (thesis eq. 11)


def tri_coefficients(x: NDArray, c: NDArray) -> NDArray[np.float64]:
    """Triangle patch coefficients, thesis eq. (5).

    x : (E, 3, 3) corners x00 x10 x11;  c : (E, 3, 3) edge coefficients c1 c2 c3.
    Returns (E, 6, 3): c00 c10 c01 c11 c20 c02.
    """
    c1, c2, c3 = c[:, 0], c[:, 1], c[:, 2]
    out = np.empty((x.shape[0], 6, 3))
    out[:, 0] = x[:, 0]
    out[:, 1] = x[:, 1] - x[:, 0] - c1
    out[:, 2] = x[:, 2] - x[:, 1] + c1 - c3
    out[:, 3] = c3 - c1 - c2
    out[:, 4] = c1
    out[:, 5] = c2
    return out


def quad_coefficients(x: NDArray, c: NDArray) -> NDArray[np.float64]:
    """Quadrilateral patch coefficients, thesis eq. (10).

    x : (E, 4, 3) corners x00 x10 x11 x01;  c : (E, 4, 3) edge coefficients c1..c4.
    Returns (E, 8, 3): c00 c10 c01 c11 c20 c02 c21 c12.
    """
    c1, c2, c3, c4 = c[:, 0], c[:, 1], c[:, 2], c[:, 3]
    x00, x10, x11, x01 = x[:, 0], x[:, 1], x[:, 2], x[:, 3]
    out = np.empty((x.shape[0], 8, 3))
    out[:, 0] = x00
    out[:, 1] = x10 - x00 - c1
    out[:, 2] = x01 - x00 - c4
    out[:, 3] = x11 - x10 - x01 + x00 + c1 - c2 - c3 + c4
    out[:, 4] = c1
    out[:, 5] = c4
    out[:, 6] = c3 - c1
    out[:, 7] = c2 - c4
    return out


def tri_eval(cf: NDArray, eta: NDArray, zeta: NDArray, order: int = 1) -> tuple[NDArray, ...]:
    """Evaluate triangle patches (eqs. 4, 7, 8) at one (eta, zeta) per coefficient row.

    cf : (M, 6, 3); eta, zeta : (M,).
    order 0 -> (x,); 1 -> (x, x_eta, x_zeta); 2 -> also (x_ee, x_ez, x_zz). Each (M, 3).
    """
    e = eta[:, None]
    z = zeta[:, None]
    c00, c10, c01, c11, c20, c02 = (cf[:, i] for i in range(6))
    x = c00 + c10 * e + c01 * z + c11 * e * z + c20 * e * e + c02 * z * z
    if order == 0:
        return (x,)
    xe = c10 + c11 * z + 2.0 * c20 * e
    xz = c01 + c11 * e + 2.0 * c02 * z
    if order == 1:
        return x, xe, xz
    return x, xe, xz, 2.0 * c20 + 0.0 * e, c11 + 0.0 * e, 2.0 * c02 + 0.0 * e


def quad_eval(cf: NDArray, eta: NDArray, zeta: NDArray, order: int = 1) -> tuple[NDArray, ...]:
    """Evaluate quadrilateral patches (eqs. 9, 12, 13); see :func:`tri_eval`. cf : (M, 8, 3)."""
    e = eta[:, None]
    z = zeta[:, None]
    c00, c10, c01, c11, c20, c02, c21, c12 = (cf[:, i] for i in range(8))
    x = c00 + c10 * e + c01 * z + c11 * e * z + c20 * e * e + c02 * z * z + c21 * e * e * z + c12 * e * z * z
    if order == 0:
        return (x,)
    xe = c10 + c11 * z + 2.0 * c20 * e + 2.0 * c21 * e * z + c12 * z * z
    xz = c01 + c11 * e + 2.0 * c02 * z + c21 * e * e + 2.0 * c12 * e * z
    if order == 1:
        return x, xe, xz
    xee = 2.0 * c20 + 2.0 * c21 * z
    xez = c11 + 2.0 * c21 * e + 2.0 * c12 * z
    xzz = 2.0 * c02 + 2.0 * c12 * e
    return x, xe, xz, xee, xez, xzz


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _eval_rows_kernel(quad, cf, loc, eta, zeta, rows, order, x, xe, xz, xee, xez, xzz):  # pragma: no cover - numba
    for r in range(rows.size):
        i = rows[r]
        c = cf[loc[i]]
        e = eta[i]
        z = zeta[i]
        for k in range(3):
            c00, c10, c01, c11, c20, c02 = c[0, k], c[1, k], c[2, k], c[3, k], c[4, k], c[5, k]
            c21 = c[6, k] if quad else 0.0
            c12 = c[7, k] if quad else 0.0
            x[i, k] = c00 + c10 * e + c01 * z + c11 * e * z + c20 * e * e + c02 * z * z + c21 * e * e * z + c12 * e * z * z
            if order >= 1:
                xe[i, k] = c10 + c11 * z + 2.0 * c20 * e + 2.0 * c21 * e * z + c12 * z * z
                xz[i, k] = c01 + c11 * e + 2.0 * c02 * z + c21 * e * e + 2.0 * c12 * e * z
            if order >= 2:
                xee[i, k] = 2.0 * c20 + 2.0 * c21 * z
                xez[i, k] = c11 + 2.0 * c21 * e + 2.0 * c12 * z
                xzz[i, k] = 2.0 * c02 + 2.0 * c12 * e


def eval_rows(cf: NDArray, loc: NDArray, eta: NDArray, zeta: NDArray, rows: NDArray,
              out: tuple[NDArray, ...]) -> None:
    """`tri_eval` / `quad_eval` (by ``cf``'s (P, 6, 3) or (P, 8, 3) shape) of patch ``loc[i]`` at
    (``eta[i]``, ``zeta[i]``) for each ``i`` of ``rows``, written into row ``i`` of the arrays
    ``out`` (1, 3 or 6 of them, each (M, 3): x, x_eta, x_zeta, x_ee, x_ez, x_zz; the order
    follows from their number). The same sums as those functions (eqs. 4, 7-9, 12, 13) in one
    compiled loop: no (M, 8, 3) gather of the coefficients (the production die's error check
    evaluates 1.1 M points)."""
    order = {1: 0, 3: 1, 6: 2}[len(out)]
    none = np.empty((0, 3))
    full = tuple(out) + (none,) * (6 - len(out))
    _eval_rows_kernel(cf.shape[1] == 8, np.ascontiguousarray(cf, dtype=np.float64), np.asarray(loc, dtype=np.int64),
                      np.asarray(eta, dtype=np.float64), np.asarray(zeta, dtype=np.float64),
                      np.asarray(rows, dtype=np.int64), order, *full)


def unit(v: NDArray) -> NDArray:
    """Normalise the last axis."""
    return v / np.linalg.norm(v, axis=-1, keepdims=True)
