"""Nagata edge curvature coefficient ``c`` (Nagata 2005, eqs. 1-33).

An edge ``x0 -> x1`` is replaced by the quadratic curve

    x(xi) = x0 + (d - c) xi + c xi^2,   d = x1 - x0,   0 <= xi <= 1        (eq. 1)

whose tangent is orthogonal to the normals given at its ends.  ``c`` is the
minimum-norm (least-squares) solution of ``[n] c = {d}`` (eqs. 6-7, 19-20, 32).

* Two normals (smooth edge): closed form of eq. (15) with the decoupled handling of
  the singular cases (dimensionless threshold ``eps`` on ``dc`` and ``1 - dc``), and the
  inflected-edge rule below.
* Inflected edge: the chord lies on the same side of both end tangent planes,
  ``(d . n0) (d . n1) > 0``. A convex arc has its chord below the tangent at one end and
  above it at the other (opposite signs), so this is an inflection between the ends, which
  no quadratic can hold (thesis §6.2.2, Fig. 56: the node is outside the admissible region).
  There the term ``(d . v / dc) dv`` of eq. (15) grows without bound as the normals become
  parallel (``dc = |dv|^2``), e.g. ``|c| = 3.7 |d|`` on a real sample. The rule drops that
  term, as eq. (15) itself does for parallel normals: ``c = (d . dv) / (1 - dc) v``.
* Edge plane: the two normals carry the normal curvature of the edge only; the sideways
  part of ``c`` — along ``b = d x v / |d x v|``, in the tangent plane across the edge —
  comes from the twist of the normals about the edge, and eq. (15) makes it as large as
  ``|d . v| / |dv|`` when the normals are nearly parallel (a bulge of 0.3 across a 4 mm
  edge whose surface is 0.01 from its chord, on a real sample). It is removed:
  ``c <- c - (c . b) b``, so the edge curve stays in the plane of ``d`` and ``v``. For
  symmetric edges (circle arcs, cylinders, spheres: ``d . v = 0``) ``c`` is parallel to
  ``v`` and nothing changes; the tangency conditions then hold up to
  ``(c . b)(b . dv)``.
* Any number of normals (sharp edge, non-manifold edge): generalized inverse of
  eqs. (20)-(31) with the rank tests on the dimensionless ``D^(k)``.

Edge rules (`EDGE_RULES`, chosen per mesh in `cadbridge.nagata.mesh.NagataMesh`): ``bounded``
applies the inflected-edge and edge-plane rules above, a boundary edge's conormals
(`edge_coefficient_conormal`) and, where only one end of a crease edge carries several
normals, the normal most orthogonal to the edge; ``published`` is Nagata 2005 as published:
eq. (15) with its singular cases only (``bounded=False``), the generalized inverse of
eqs. (19)-(33) wherever an end carries several distinct normals, no conormals.

Reversing an edge (swap ``x0, x1`` and ``n0, n1``) leaves ``c`` unchanged: the system
``[n] c = {d}`` is the same set of equations, and the reversed curve
``x1 + (-d - c) t + c t^2`` traces ``x(1 - t)``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

EPS_SINGULAR = 1e-10
"""Default threshold on the dimensionless ``dc`` and ``1 - dc`` of eq. (15)."""

EPS_RANK = 1e-12
"""Default threshold on the dimensionless determinant coefficients ``D^(k)`` of eq. (31)."""


EDGE_RULES = ("bounded", "published")
"""The edge rules (module docs); the first is the default."""


def check_edge_rule(rule: str) -> str:
    """``rule`` if it is one of `EDGE_RULES`, else ValueError naming them."""
    if rule not in EDGE_RULES:
        raise ValueError(f"edge rule must be one of {', '.join(EDGE_RULES)}, got {rule!r}")
    return rule


def _dot(a: NDArray, b: NDArray) -> NDArray:
    return np.einsum("...i,...i->...", a, b)


def edge_coefficient(
    x0: ArrayLike, x1: ArrayLike, n0: ArrayLike, n1: ArrayLike, eps: float = EPS_SINGULAR,
    bounded: bool = True,
) -> NDArray[np.float64]:
    """Curvature coefficient of Nagata edges with one normal per end (Nagata eq. 15).

    Parameters
    ----------
    x0, x1 : (..., 3) end points.
    n0, n1 : (..., 3) unit normals at the end points.
    eps : threshold on the dimensionless ``dc = n0 . (n0 - n1) / 2``: the ``v`` term is
        dropped when ``1 - dc < eps`` (opposite normals), the ``dv`` term when
        ``dc < eps`` (parallel normals) or when the edge is inflected
        (``(d . n0) (d . n1) > 0``, module docs).  For exactly parallel normals ``c`` is
        exactly 0.
    bounded : apply the inflected-edge and edge-plane rules (module docs); False gives
        eq. (15) as published.

    Returns
    -------
    c : (..., 3)
    """
    x0 = np.asarray(x0, dtype=float)
    x1 = np.asarray(x1, dtype=float)
    n0 = np.asarray(n0, dtype=float)
    n1 = np.asarray(n1, dtype=float)
    d = x1 - x0
    v = 0.5 * (n0 + n1)  # eq. 12a
    dv = 0.5 * (n0 - n1)  # eq. 12b
    dd = _dot(d, v)  # eq. 13a  ("d")
    ddelta = _dot(d, dv)  # eq. 13b  ("Delta d")
    dc = _dot(n0, dv)  # eq. 14b
    one_m = 1.0 - dc
    keep1 = one_m >= eps
    keep2 = dc >= eps
    if bounded:
        # inflected: (d.n0)(d.n1) > eps |d|^2 (dimensionless; round-off of a chord lying in a
        # tangent plane, e.g. the c = -d edge, does not count)
        keep2 &= ~(_dot(d, n0) * _dot(d, n1) > eps * _dot(d, d))
    f1 = np.where(keep1, ddelta / np.where(keep1, one_m, 1.0), 0.0)
    f2 = np.where(keep2, dd / np.where(keep2, dc, 1.0), 0.0)
    c = f1[..., None] * v + f2[..., None] * dv
    if bounded:
        b = np.cross(d, v)
        lb = np.sqrt(_dot(b, b))
        ok = lb > 1e-12 * np.sqrt(_dot(d, d)) * np.sqrt(_dot(v, v))  # d not along v
        b = b / np.where(ok, lb, 1.0)[..., None]
        c = c - np.where(ok, _dot(c, b), 0.0)[..., None] * b
    return c


def _cross(a: NDArray, b: NDArray) -> NDArray:
    return np.cross(a, b)


def pinv_solve_sym(s: NDArray, b: NDArray, eps: float = EPS_RANK) -> tuple[NDArray, NDArray]:
    """Minimum-norm least-squares solution ``c = [n]^+ {d}`` from ``s = [n]^T [n]``
    and ``b = [n]^T {d}`` by Nagata's limit formula (eqs. 21-31).

    Parameters
    ----------
    s : (K, 3, 3) symmetric, normalised so that ``trace(s) = 1`` (dimensionless).
    b : (K, 3)
    eps : zero threshold for ``|D^(k)|``.

    Returns
    -------
    c : (K, 3)
    rank : (K,) int, 3 - k for the case of eq. (31) used.
    """
    e = np.broadcast_to(np.eye(3), s.shape)
    # columns s_i (s is symmetric so rows == columns)
    si = [s[:, :, i] for i in range(3)]
    ei = [e[:, :, i] for i in range(3)]
    a1 = np.empty_like(s)
    a0 = np.empty_like(s)
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):  # loop over the 3 rows, not elements
        a1[:, i, :] = _cross(si[j], ei[k]) + _cross(ei[j], si[k])  # eq. 26b
        a0[:, i, :] = _cross(si[j], si[k])  # eq. 26c
    d2 = np.einsum("kii->k", s + a1) / 3.0  # eq. 29a averaged over i (all equal)
    d1 = (np.einsum("kij,kji->k", s, a1) + np.einsum("kii->k", a0)) / 3.0  # eq. 29b
    d0 = np.einsum("kij,kji->k", s, a0) / 3.0  # eq. 29c
    # eq. 31: [n]^+ {d} = a^(k) [n]^T {d} / D^(k)
    x0 = np.einsum("kij,kj->ki", a0, b)
    x1 = np.einsum("kij,kj->ki", a1, b)
    r3 = np.abs(d0) > eps
    r2 = ~r3 & (np.abs(d1) > eps)
    r1 = ~r3 & ~r2 & (np.abs(d2) > eps)
    c = np.zeros_like(b)
    c[r3] = x0[r3] / d0[r3, None]
    c[r2] = x1[r2] / d1[r2, None]
    c[r1] = b[r1] / d2[r1, None]
    rank = np.where(r3, 3, np.where(r2, 2, np.where(r1, 1, 0)))
    return c, rank


def edge_coefficient_multi(
    d: ArrayLike,
    normals0: ArrayLike,
    normals1: ArrayLike,
    mask0: ArrayLike | None = None,
    mask1: ArrayLike | None = None,
    eps: float = EPS_RANK,
) -> NDArray[np.float64]:
    """Curvature coefficient of edges carrying several normals at each end
    (sharp or non-manifold edges; Nagata eqs. 19-33).

    All orthogonality conditions ``n0_k . (d - c) = 0`` and ``n1_k . (d + c) = 0`` are
    solved together in the minimum-norm least-squares sense via the generalized inverse
    (eqs. 20, 21, 31, with ``[s]`` of eq. 33).

    Parameters
    ----------
    d : (K, 3) edge vectors ``x1 - x0``.
    normals0, normals1 : (K, P, 3) normals at ``x0`` and ``x1`` (P per edge, padded).
    mask0, mask1 : (K, P) bool, which rows are present (default: all).
    eps : threshold on the dimensionless ``D^(k)`` (``s`` is normalised to unit trace).

    Returns
    -------
    c : (K, 3)
    """
    d = np.asarray(d, dtype=float)
    n0 = np.asarray(normals0, dtype=float)
    n1 = np.asarray(normals1, dtype=float)
    w0 = np.ones(n0.shape[:2]) if mask0 is None else np.asarray(mask0, dtype=float)
    w1 = np.ones(n1.shape[:2]) if mask1 is None else np.asarray(mask1, dtype=float)
    # eq. 33: s = sum n n^T ; b = [n]^T {d} = sum n0 (n0.d) - sum n1 (n1.d)
    s = np.einsum("kp,kpi,kpj->kij", w0, n0, n0) + np.einsum("kp,kpi,kpj->kij", w1, n1, n1)
    p0 = np.einsum("kpi,ki->kp", n0, d) * w0
    p1 = np.einsum("kpi,ki->kp", n1, d) * w1
    b = np.einsum("kp,kpi->ki", p0, n0) - np.einsum("kp,kpi->ki", p1, n1)
    m = (w0.sum(1) + w1.sum(1))[:, None]
    c, _ = pinv_solve_sym(s / m[:, :, None], b / m, eps)
    return c


def edge_coefficient_conormal(
    x0: ArrayLike, x1: ArrayLike, n0: ArrayLike, n1: ArrayLike, p: ArrayLike, q: ArrayLike,
    eps: float = EPS_SINGULAR,
) -> NDArray[np.float64]:
    """Curvature coefficient of a boundary edge that follows a curve (normals ``n0, n1`` of
    the surface, conormals ``p, q`` of the curve at the ends; docs/toolfile.md rule 4b).

    The two surface normals fix the edge's normal curvature exactly (eq. 15, `edge_coefficient`,
    whose edge-plane rule leaves no component along ``b = d x v / |d x v|``); the conormals
    add that sideways component, the curve's geodesic curvature:

        c = c2 + s b,   s = argmin (p . (d - c))^2 + (q . (d + c))^2
          = [ (p . (d - c2)) (p . b) - (q . (d + c2)) (q . b) ] / [ (p . b)^2 + (q . b)^2 ]

    (s = 0 where ``d`` is along ``v`` or the denominator is below ``eps``). Like eq. 15 the
    result does not depend on the edge's direction.

    x0, x1, n0, n1, p, q : (..., 3). Returns c (..., 3).
    """
    x0 = np.asarray(x0, dtype=float)
    x1 = np.asarray(x1, dtype=float)
    n0 = np.asarray(n0, dtype=float)
    n1 = np.asarray(n1, dtype=float)
    p = np.asarray(p, dtype=float)
    q = np.asarray(q, dtype=float)
    c2 = edge_coefficient(x0, x1, n0, n1, eps)
    d = x1 - x0
    v = 0.5 * (n0 + n1)
    b = np.cross(d, v)
    lb = np.sqrt(_dot(b, b))
    ok = lb > 1e-12 * np.sqrt(_dot(d, d)) * np.sqrt(_dot(v, v))
    b = b / np.where(ok, lb, 1.0)[..., None]
    pb, qb = _dot(p, b), _dot(q, b)
    den = pb * pb + qb * qb
    ok &= den >= eps
    s = (_dot(p, d - c2) * pb - _dot(q, d + c2) * qb) / np.where(ok, den, 1.0)
    return c2 + np.where(ok, s, 0.0)[..., None] * b
