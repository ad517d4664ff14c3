"""Fundamental NURBS algorithms (Piegl & Tiller ch. 5) on homogeneous control points (arrays).

The array-level functions work on homogeneous control points ``ctrl_w`` = (w*P, w) of any
shape; ``axis`` selects the axis that runs along the knot vector, so the same code refines a
curve (n, d+1), the u direction of a surface (nu, nv, 4) with ``axis=0`` or its v direction
with ``axis=1``. Every function returns new arrays and leaves the geometry unchanged
(except ``reverse`` and ``reparametrize``, which change only the parametrisation).

Object-level helpers (``*_curve``, ``*_surface``, ``bezier_patches``, ``tight_bbox``) wrap
them for :class:`NurbsCurve` and :class:`NurbsSurface` in `cadbridge.nurbs.edits`.
"""

from __future__ import annotations

from math import comb
from typing import Sequence

import numpy as np

from cadbridge.nurbs.basis import find_span

__all__ = [
    "to_homogeneous",
    "from_homogeneous",
    "knot_multiplicity",
    "insert_knot",
    "refine_knots",
    "restrict",
    "decompose",
    "bezier_elevation_matrix",
    "elevate_degree",
    "reverse",
    "reparametrize",
    "merge_knots",
    "missing_knots",
    "remove_surplus_knots",
]

_SNAP = 1e-12  # relative tolerance for snapping a cut parameter onto an existing knot


# ---------------------------------------------------------------------------- homogeneous
def to_homogeneous(points: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """(..., d) points and (...) weights -> (..., d+1) homogeneous points (w*P, w)."""
    pts = np.asarray(points, dtype=float)
    w = np.ones(pts.shape[:-1]) if weights is None else np.asarray(weights, dtype=float)
    return np.concatenate([pts * w[..., None], w[..., None]], axis=-1)


def from_homogeneous(ctrl_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(..., d+1) homogeneous points -> ((..., d) points, (...) weights)."""
    cw = np.asarray(ctrl_w, dtype=float)
    w = cw[..., -1]
    return cw[..., :-1] / w[..., None], w.copy()


def knot_multiplicity(knots: np.ndarray, u: float) -> int:
    """Number of knots exactly equal to ``u``."""
    return int(np.count_nonzero(np.asarray(knots) == u))


def _span(knots: np.ndarray, p: int, u: float) -> int:
    """Index k of a non-empty span with knots[k] <= u <= knots[k+1], p <= k <= n (A2.1)."""
    n = len(knots) - p - 2
    if not knots[p] <= u <= knots[n + 1]:
        raise ValueError(f"parameter {u!r} outside the knot domain [{knots[p]!r}, {knots[n + 1]!r}]")
    k = int(np.searchsorted(knots, u, side="right")) - 1
    if k > n:  # u at the right end: last span that starts before u
        k = int(np.searchsorted(knots, u, side="left")) - 1
    return max(k, p)


# ---------------------------------------------------------------------------- insertion
def insert_knot(knots, p: int, ctrl_w, u: float, r: int = 1, axis: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Insert ``u`` ``r`` times (P&T A5.1, CurveKnotIns, in Boehm's form).

    knots (m+1,), ctrl_w (..., n+1 along ``axis``, ...). Returns (knots (m+1+r,), ctrl_w with
    n+1+r points along ``axis``). Raises ValueError if the multiplicity would exceed p.
    """
    U = np.asarray(knots, dtype=float)
    P = np.moveaxis(np.asarray(ctrl_w, dtype=float), axis, 0)
    if len(U) != P.shape[0] + p + 1:
        raise ValueError(f"{len(U)} knots do not match {P.shape[0]} control points of degree {p}")
    s = knot_multiplicity(U, u)
    if s + r > p:
        raise ValueError(f"inserting {u!r} {r} times would give multiplicity {s + r} > degree {p}")
    for _ in range(r):
        k = _span(U, p, u)
        n = P.shape[0] - 1
        Q = np.empty((n + 2,) + P.shape[1:])
        Q[: k - p + 1] = P[: k - p + 1]
        Q[k + 1 :] = P[k:]
        i = np.arange(k - p + 1, k + 1)
        alpha = (u - U[i]) / (U[i + p] - U[i])
        alpha = alpha.reshape((-1,) + (1,) * (P.ndim - 1))
        Q[k - p + 1 : k + 1] = alpha * P[k - p + 1 : k + 1] + (1.0 - alpha) * P[k - p : k]
        U = np.insert(U, k + 1, u)
        P = Q
    return U, np.moveaxis(P, 0, axis)


def refine_knots(knots, p: int, ctrl_w, new_knots, axis: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Insert all of ``new_knots`` at once (P&T A5.4, RefineKnotVectCurve).

    knots (m+1,), ctrl_w with n+1 points along ``axis``, new_knots (r+1,) inside the knot
    domain (sorted here). Returns (knots (m+r+2,), ctrl_w with n+r+2 points along ``axis``).
    """
    U = np.asarray(knots, dtype=float)
    X = np.sort(np.asarray(new_knots, dtype=float).ravel())
    P = np.moveaxis(np.asarray(ctrl_w, dtype=float), axis, 0)
    if X.size == 0:
        return U.copy(), np.moveaxis(P.copy(), 0, axis)
    n = P.shape[0] - 1
    m = n + p + 1
    if len(U) != m + 1:
        raise ValueError(f"{len(U)} knots do not match {n + 1} control points of degree {p}")
    if X[0] < U[p] or X[-1] > U[n + 1]:
        raise ValueError(f"new knots [{X[0]!r}, {X[-1]!r}] outside the domain [{U[p]!r}, {U[n + 1]!r}]")
    for x in np.unique(X):
        s = knot_multiplicity(U, x) + knot_multiplicity(X, x)
        if s > p:
            raise ValueError(f"inserting {x!r} would give multiplicity {s} > degree {p}")
    r = X.size - 1
    a = _span(U, p, X[0])
    b = _span(U, p, X[r]) + 1
    Q = np.empty((n + r + 2,) + P.shape[1:])
    Ub = np.empty(m + r + 2)
    Q[: a - p + 1] = P[: a - p + 1]
    Q[b + r : n + r + 2] = P[b - 1 : n + 1]
    Ub[: a + 1] = U[: a + 1]
    Ub[b + p + r + 1 :] = U[b + p :]
    i = b + p - 1
    k = b + p + r
    for j in range(r, -1, -1):
        while X[j] <= U[i] and i > a:
            Q[k - p - 1] = P[i - p - 1]
            Ub[k] = U[i]
            k -= 1
            i -= 1
        Q[k - p - 1] = Q[k - p]
        for l in range(1, p + 1):
            ind = k - p + l
            alfa = Ub[k + l] - X[j]
            if alfa == 0.0:
                Q[ind - 1] = Q[ind]
            else:
                alfa /= Ub[k + l] - U[i - p + l]
                Q[ind - 1] = alfa * Q[ind - 1] + (1.0 - alfa) * Q[ind]
        Ub[k] = X[j]
        k -= 1
    return Ub, np.moveaxis(Q, 0, axis)


def _snap(knots: np.ndarray, t: float) -> float:
    """``t`` replaced by an existing knot within _SNAP * (knot range)."""
    tol = _SNAP * max(1.0, float(knots[-1] - knots[0]))
    j = int(np.argmin(np.abs(knots - t)))
    return float(knots[j]) if abs(knots[j] - t) <= tol else float(t)


def _raise_to(knots: np.ndarray, values, p: int) -> np.ndarray:
    """Knots to insert so that every value in ``values`` has multiplicity >= p."""
    extra = []
    for t in values:
        s = knot_multiplicity(knots, t)
        extra += [t] * max(0, p - s)
    return np.array(extra, dtype=float)


def restrict(knots, p: int, ctrl_w, t0: float, t1: float, axis: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The piece over [t0, t1] with a clamped knot vector (ends of multiplicity p+1).

    Cut parameters within 1e-12 (relative) of a knot are snapped onto it. Also clamps an
    unclamped knot vector. Returns (knots, ctrl_w along ``axis``).
    """
    U = np.asarray(knots, dtype=float)
    t0, t1 = _snap(U, t0), _snap(U, t1)
    if not t0 < t1:
        raise ValueError(f"empty range [{t0!r}, {t1!r}]")
    Ur, Q = refine_knots(U, p, ctrl_w, _raise_to(U, (t0, t1), p), axis)
    k0 = int(np.searchsorted(Ur, t0, side="right")) - 1  # last knot equal to t0
    k1 = int(np.searchsorted(Ur, t1, side="left")) - 1  # last knot below t1
    inner = Ur[k0 + 1 : k1 + 1]
    new_knots = np.concatenate([[t0] * (p + 1), inner, [t1] * (p + 1)])
    Q = np.take(Q, np.arange(k0 - p, k1 + 1), axis=axis)
    return new_knots, Q


def decompose(knots, p: int, ctrl_w, axis: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Bézier segments of the curve over its knot domain (result of P&T A5.6, DecomposeCurve).

    Returns breaks (K+1,) and segments of shape (K,) + ctrl_w.shape with the ``axis`` length
    replaced by p+1: segments[k] is the Bézier control net on [breaks[k], breaks[k+1]]
    (the ``axis`` index of ctrl_w is shifted by one to make room for the leading K).
    """
    U = np.asarray(knots, dtype=float)
    n = len(U) - p - 2
    a, b = U[p], U[n + 1]
    breaks = np.unique(U[(U >= a) & (U <= b)])
    Ur, Q = refine_knots(U, p, ctrl_w, _raise_to(U, breaks, p), axis)
    Q = np.moveaxis(Q, axis, 0)
    segs = []
    for t in breaks[:-1]:
        k = int(np.searchsorted(Ur, t, side="right")) - 1  # span [t, next break)
        segs.append(Q[k - p : k + 1])
    segments = np.moveaxis(np.stack(segs), 1, axis + 1)
    return breaks, segments


# ---------------------------------------------------------------------------- surplus knots
def remove_surplus_knots(knots, p: int, ctrl_w, axis: int = 0, rel_tol: float = 1e-12
                         ) -> tuple[np.ndarray, np.ndarray, list[tuple[float, int]], list[tuple[float, float]]]:
    """Lower every interior knot of multiplicity s > p to p where that is exact (P&T A5.8).

    knots (m+1,); ctrl_w (..., n, ..., d+1) homogeneous, n = m - p along ``axis``. Only
    knots strictly inside the domain (knots[p], knots[n]) are touched. A run of s > p + 1
    equal knots carries s - p - 1 basis functions that vanish everywhere: their knots and
    control points are dropped (exact). At a run of p + 1 the curve falls into two
    independent pieces; one more occurrence is removed (A5.8 with s = p + 1) when they meet:
    the left piece's last point and the right piece's first point coincide within
    ``rel_tol`` x the control net's box diagonal along every row and their weights have one
    ratio, by which the right piece's weights are scaled (that leaves it unchanged).

    Returns (knots, ctrl_w, removed, breaks): ``removed`` lists (knot value, occurrences
    removed); ``breaks`` lists (knot value, gap) for the knots left at p + 1 (gap: largest
    distance between the two pieces' end points, inf when only the weights disagree).
    """
    U = np.asarray(knots, dtype=float)
    Q = np.moveaxis(np.array(ctrl_w, dtype=float), axis, 0)
    n = Q.shape[0]
    pts = Q[..., :-1] / Q[..., -1:]
    flat = pts.reshape(-1, pts.shape[-1])
    tol = rel_tol * float(np.linalg.norm(np.ptp(flat, axis=0))) if flat.size else 0.0
    keep_k = np.ones(len(U), dtype=bool)
    keep_q = np.ones(n, dtype=bool)
    removed: list[tuple[float, int]] = []
    breaks: list[tuple[float, float]] = []
    i = p + 1
    while i < n:
        j = i
        while j + 1 < n and U[j + 1] == U[i]:
            j += 1
        s = j - i + 1
        if s > p and U[p] < U[i] < U[n]:
            drop = s - p - 1  # N_i .. N_{i+drop-1} have all their knots equal: zero everywhere
            keep_k[i : i + drop] = False
            keep_q[i : i + drop] = False
            left, right = i - 1, j - p  # last point of the left piece, first of the right one
            gap = float(np.max(np.linalg.norm(pts[left] - pts[right], axis=-1)))
            ratio = Q[left, ..., -1] / Q[right, ..., -1]
            r = float(np.ravel(ratio)[0])
            if gap <= tol and np.all(np.abs(ratio - r) <= rel_tol * r):
                Q[right:] *= r
                keep_k[i + drop] = False
                keep_q[right] = False
                drop += 1
            else:
                breaks.append((float(U[i]), gap if gap > tol else float("inf")))
            if drop:
                removed.append((float(U[i]), drop))
        i = j + 1
    return U[keep_k], np.moveaxis(Q[keep_q], 0, axis), removed, breaks


# ---------------------------------------------------------------------------- degree elevation
def bezier_elevation_matrix(p: int, t: int) -> np.ndarray:
    """(p+t+1, p+1) matrix E with Q = E @ P elevating a degree-p Bézier by t (P&T eq. 5.36)."""
    E = np.zeros((p + t + 1, p + 1))
    for i in range(p + t + 1):
        for j in range(max(0, i - t), min(p, i) + 1):
            E[i, j] = comb(p, j) * comb(t, i - j) / comb(p + t, i)
    return E


def elevate_degree(knots, p: int, ctrl_w, t: int = 1, axis: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Raise the degree from p to p+t without changing the curve (result of P&T A5.9).

    Method: decompose into Bézier segments, elevate each (eq. 5.36), join them (C0 knot
    vector), then remove the surplus knots exactly so every interior knot of multiplicity s
    keeps continuity with multiplicity s+t; the removal solves the over-determined knot
    insertion system in the least-squares sense (exact here, since the curve lies in the
    smaller spline space). The result is clamped on the original knot domain.
    Returns (knots, ctrl_w along ``axis``).
    """
    U = np.asarray(knots, dtype=float)
    if t < 0:
        raise ValueError("t must be >= 0")
    if t == 0:
        return U.copy(), np.array(ctrl_w, dtype=float)
    n = len(U) - p - 2
    breaks, segs = decompose(U, p, ctrl_w, axis)
    segs = np.moveaxis(segs, axis + 1, 1)  # (K, p+1, ...)
    ph = p + t
    E = bezier_elevation_matrix(p, t)
    esegs = np.einsum("ij,kj...->ki...", E, segs)  # (K, ph+1, ...)
    K = len(breaks) - 1
    c0 = np.concatenate([esegs[0]] + [esegs[k, 1:] for k in range(1, K)], axis=0)
    if K == 1:
        kn = np.concatenate([[breaks[0]] * (ph + 1), [breaks[-1]] * (ph + 1)])
        return kn, np.moveaxis(c0, 0, axis)
    # target multiplicities: interior knot of multiplicity s (inside the domain) -> s + t
    inner = breaks[1:-1]
    mult = np.array([min(knot_multiplicity(U[p + 1 : n + 1], x), p) + t for x in inner])
    target = np.concatenate([[breaks[0]] * (ph + 1), np.repeat(inner, mult), [breaks[-1]] * (ph + 1)])
    if np.all(mult == ph):
        return target, np.moveaxis(c0, 0, axis)
    extra = np.repeat(inner, ph - mult)
    nt = len(target) - ph - 1
    # insertion matrix M (n_c0, nt): c0 = M @ ctrl_target
    _, M = refine_knots(target, ph, np.eye(nt), extra, axis=0)
    flat = c0.reshape(c0.shape[0], -1)
    sol, *_ = np.linalg.lstsq(M, flat, rcond=None)
    resid = np.abs(M @ sol - flat).max() if flat.size else 0.0
    scale = max(1.0, float(np.abs(flat).max()))
    if not resid <= 1e-9 * scale:  # cannot happen for valid input; keep the exact C0 form
        c0_knots = np.concatenate([[breaks[0]] * (ph + 1), np.repeat(inner, ph), [breaks[-1]] * (ph + 1)])
        return c0_knots, np.moveaxis(c0, 0, axis)
    ctrl = sol.reshape((nt,) + c0.shape[1:])
    return target, np.moveaxis(ctrl, 0, axis)


# ---------------------------------------------------------------------------- parametrisation
def reverse(knots, p: int, ctrl_w, axis: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The same curve traversed backwards: u -> a + b - u on the same knot range."""
    U = np.asarray(knots, dtype=float)
    return (U[0] + U[-1]) - U[::-1], np.flip(np.asarray(ctrl_w, dtype=float), axis=axis).copy()


def reparametrize(knots, new_range, old_range=None) -> np.ndarray:
    """Knots under the affine map taking ``old_range`` (default the knot range) to
    ``new_range``; control points are unchanged. Ends are set exactly."""
    U = np.asarray(knots, dtype=float)
    a, b = (U[0], U[-1]) if old_range is None else (float(old_range[0]), float(old_range[1]))
    c, d = float(new_range[0]), float(new_range[1])
    V = c + (U - a) * ((d - c) / (b - a))
    V[U == a] = c
    V[U == b] = d
    return V


def merge_knots(knot_vectors: Sequence[np.ndarray]) -> np.ndarray:
    """Union of knot vectors: every value with the largest multiplicity it has in any of them."""
    vals = np.unique(np.concatenate([np.asarray(k, dtype=float) for k in knot_vectors]))
    mult = [max(knot_multiplicity(k, x) for k in knot_vectors) for x in vals]
    return np.repeat(vals, mult)


def missing_knots(knots: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Knots of ``target`` (a superset in the multiset sense) that ``knots`` lacks."""
    vals = np.unique(target)
    return np.repeat(vals, [knot_multiplicity(target, x) - knot_multiplicity(knots, x) for x in vals])
