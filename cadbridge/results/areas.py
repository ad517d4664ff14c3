"""Exact areas of parameter-space triangles on a NURBS surface (Hawkins 1989, App. D).

The area of a (u, v) triangle on S is the integral of |Su x Sv| over it; the conical Gauss
product rule of `triangle_rule` integrates it on the pieces the surface's interior knot lines
cut the triangle into (the integrand is smooth within a knot span only).
"""

from __future__ import annotations

import numpy as np

__all__ = ["surface_area_of_triangles", "triangle_rule"]


def triangle_rule(n: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Conical Gauss product rule on the reference triangle: barycentric points (n^2, 3) and
    weights (n^2,) summing to 1 (exact for polynomials of degree 2n - 1)."""
    x, w = np.polynomial.legendre.leggauss(n)
    x = 0.5 * (x + 1.0)
    w = 0.5 * w
    a, b = np.meshgrid(x, x, indexing="ij")  # Duffy: s = a, t = b (1 - a)
    wa, wb = np.meshgrid(w, w, indexing="ij")
    s = a.ravel()
    t = (b * (1.0 - a)).ravel()
    ww = (wa * wb * (1.0 - a)).ravel() * 2.0
    return np.column_stack([1.0 - s - t, s, t]), ww


def _split_at_line(uv: np.ndarray, owner: np.ndarray, axis: int, k: float) -> tuple[np.ndarray, np.ndarray]:
    """Triangles (T, 3, 2) that a line x_axis = k crosses are cut into three triangles (the
    two sides, each fanned); the others stay. ``owner`` (T,) follows the pieces."""
    x = uv[:, :, axis]
    cross = (x.min(axis=1) < k) & (x.max(axis=1) > k)
    if not np.any(cross):
        return uv, owner
    tri = uv[cross]
    # the vertex alone on its side: rotate it to position 0
    side = tri[:, :, axis] > k
    lone = np.where(side.sum(axis=1) == 1, np.argmax(side, axis=1), np.argmax(~side, axis=1))
    r = np.arange(len(tri))
    a, b, c = tri[r, lone], tri[r, (lone + 1) % 3], tri[r, (lone + 2) % 3]
    tab = ((k - a[:, axis]) / (b[:, axis] - a[:, axis]))[:, None]
    tac = ((k - a[:, axis]) / (c[:, axis] - a[:, axis]))[:, None]
    pab, pac = a + tab * (b - a), a + tac * (c - a)
    pab[:, axis] = k
    pac[:, axis] = k
    new = np.concatenate([np.stack([a, pab, pac], 1), np.stack([pab, b, c], 1), np.stack([pab, c, pac], 1)])
    own = np.concatenate([owner[cross]] * 3)
    return np.concatenate([uv[~cross], new]), np.concatenate([owner[~cross], own])


def _affine(surface) -> bool:
    """Whether S is an affine map of (u, v): bilinear, polynomial, one span each way, with a
    parallelogram control net (then Su and Sv are constant)."""
    if surface.rational or surface.degree_u != 1 or surface.degree_v != 1 or surface.shape != (2, 2):
        return False
    p = surface.control_points
    d = p[0, 0] + p[1, 1] - p[1, 0] - p[0, 1]
    return bool(np.linalg.norm(d) <= 1e-14 * max(float(np.ptp(p.reshape(-1, 3), axis=0).max()), 1e-300))


def surface_area_of_triangles(surface, uv: np.ndarray, n: int = 4) -> np.ndarray:
    """Exact-surface area of (T, 3, 2) parameter triangles: the integral of |Su x Sv| over
    each, by the conical Gauss rule of order ``n`` on the pieces the surface's interior knot
    lines cut them into (the integrand is smooth within a knot span only). (T,) in model
    units squared."""
    uv = np.asarray(uv, dtype=float)
    if len(uv) == 0:
        return np.zeros(0)
    n_tri = len(uv)
    e1 = uv[:, 1] - uv[:, 0]
    e2 = uv[:, 2] - uv[:, 0]
    if _affine(surface):  # a parallelogram: |Su x Sv| is constant, the rule is exact
        d = surface.derivatives(uv[:1, 0, 0], uv[:1, 0, 1], order=1)[0]
        return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) * float(np.linalg.norm(np.cross(d[1, 0], d[0, 1])))
    owner = np.arange(n_tri)
    u0, u1, v0, v1 = surface.domain
    for axis, knots, lo, hi in ((0, surface.knots_u, u0, u1), (1, surface.knots_v, v0, v1)):
        for k in np.unique(knots[(knots > lo) & (knots < hi)]):
            uv, owner = _split_at_line(uv, owner, axis, float(k))
    bary, w = triangle_rule(n)
    pts = np.einsum("qk,tkd->tqd", bary, uv).reshape(-1, 2)
    d = surface.derivatives(np.clip(pts[:, 0], u0, u1), np.clip(pts[:, 1], v0, v1), order=1)
    su, sv = d[:, 1, 0], d[:, 0, 1]
    cx = su[:, 1] * sv[:, 2] - su[:, 2] * sv[:, 1]
    cy = su[:, 2] * sv[:, 0] - su[:, 0] * sv[:, 2]
    cz = su[:, 0] * sv[:, 1] - su[:, 1] * sv[:, 0]
    jac = np.sqrt(cx * cx + cy * cy + cz * cz).reshape(len(uv), -1)
    e1 = uv[:, 1] - uv[:, 0]
    e2 = uv[:, 2] - uv[:, 0]
    a_uv = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return np.bincount(owner, weights=a_uv * (jac @ w), minlength=n_tri)
