"""Rational B-spline (NURBS) curves in 2D or 3D, vectorised over parameters."""

from __future__ import annotations

from math import comb

import numpy as np

from cadbridge.nurbs.basis import ders_basis_funs, find_span, validate_knots

__all__ = ["NurbsCurve"]

_CHUNK = 65536


class NurbsCurve:
    """A NURBS curve C(t) = sum R_i(t) P_i (P&T eq. 4.1).

    degree : int (IGES M); knots : (n + p + 1,) (IGES T); control_points : (n, dim) with
    dim 2 (parameter-space trim curves) or 3; weights : (n,) positive or None; domain :
    (t0, t1) inside the knot domain, default the knot domain. Immutable like NurbsSurface.
    """

    def __init__(self, degree: int, knots, control_points, weights=None, domain=None) -> None:
        p = int(degree)
        cp = np.array(control_points, dtype=float)
        if cp.ndim != 2 or cp.shape[1] not in (2, 3):
            raise ValueError(f"control_points must have shape (n, 2) or (n, 3), got {cp.shape}")
        n = cp.shape[0]
        kn = np.array(knots, dtype=float)
        validate_knots(kn, p, n, "knots")
        if not np.all(np.isfinite(cp)):
            raise ValueError("control points must be finite")
        if weights is None:
            w = np.ones(n)
        else:
            w = np.array(weights, dtype=float).reshape(-1)
            if w.shape != (n,):
                raise ValueError(f"weights must have shape {(n,)}, got {w.shape}")
            if not np.all(np.isfinite(w)) or np.any(w <= 0):
                raise ValueError("weights must be finite and positive")
        full = (kn[p], kn[n])
        if domain is None:
            dom = full
        else:
            dom = (float(domain[0]), float(domain[1]))
            tol = 1e-9 * max(1.0, full[1] - full[0])
            if not (full[0] - tol <= dom[0] < dom[1] <= full[1] + tol):
                raise ValueError(f"range [{dom[0]!r}, {dom[1]!r}] not inside knot domain [{full[0]!r}, {full[1]!r}]")
            dom = (max(dom[0], full[0]), min(dom[1], full[1]))
        self.degree = p
        self.knots = kn
        self.control_points = cp
        self.weights = w
        self.domain: tuple[float, float] = dom
        self.rational = bool(np.ptp(w) > 0.0)
        dim = cp.shape[1]
        pw = np.empty((n, dim + 1))
        if self.rational:
            pw[:, :dim] = cp * w[:, None]
            pw[:, dim] = w
        else:
            pw[:, :dim] = cp
            pw[:, dim] = 1.0
        self._pw = pw
        for a in (kn, cp, w, pw):
            a.flags.writeable = False

    @property
    def dim(self) -> int:
        return self.control_points.shape[1]

    def __repr__(self) -> str:
        kind = "rational" if self.rational else "polynomial"
        return f"NurbsCurve(degree={self.degree}, ctrl={len(self.control_points)}, dim={self.dim}, {kind}, domain={self.domain})"

    def same_as(self, other: "NurbsCurve") -> bool:
        """Bit-for-bit equality of degree, knots, control points, weights and domain."""
        return (
            self.degree == other.degree
            and np.array_equal(self.knots, other.knots)
            and np.array_equal(self.control_points, other.control_points)
            and np.array_equal(self.weights, other.weights)
            and tuple(self.domain) == tuple(other.domain)
        )

    def derivatives(self, t, order: int = 1) -> np.ndarray:
        """Derivatives up to ``order``: t (N,) -> (N, order+1, dim); [:, k] = d^k C / dt^k."""
        t = np.atleast_1d(np.asarray(t, dtype=float)).ravel()
        out = np.empty((t.size, order + 1, self.dim))
        for s in range(0, t.size, _CHUNK):
            out[s : s + _CHUNK] = self._block(t[s : s + _CHUNK], order)
        return out

    def _block(self, t: np.ndarray, d: int) -> np.ndarray:
        p = self.degree
        span = find_span(self.knots, p, t)
        nd = ders_basis_funs(span, t, p, self.knots, d)  # (N, d+1, p+1)
        idx = span[:, None] - p + np.arange(p + 1)
        pw = self._pw[idx]  # (N, p+1, dim+1)
        aw = np.einsum("nka,nac->nkc", nd, pw)
        dim = self.dim
        if not self.rational:
            return aw[..., :dim].copy()
        a, w = aw[..., :dim], aw[..., dim]
        ck = np.empty_like(a)
        for k in range(d + 1):  # P&T A4.2
            val = a[:, k].copy()
            for i in range(1, k + 1):
                val -= comb(k, i) * w[:, i][:, None] * ck[:, k - i]
            ck[:, k] = val / w[:, 0][:, None]
        return ck

    def evaluate(self, t) -> np.ndarray:
        """Points C(t): t (N,) -> (N, dim)."""
        return self.derivatives(t, order=0)[:, 0]

    __call__ = evaluate

    def sample_parameters(self, per_span: int = 16) -> np.ndarray:
        """Increasing parameters covering the domain, ``per_span`` intervals per non-empty knot
        span (knots included), (M,)."""
        t0, t1 = self.domain
        brk = np.unique(self.knots[(self.knots > t0) & (self.knots < t1)])
        edges = np.concatenate([[t0], brk, [t1]])
        parts = [np.linspace(a, b, per_span + 1)[:-1] for a, b in zip(edges[:-1], edges[1:])]
        return np.concatenate(parts + [[t1]])

    def bbox(self) -> np.ndarray:
        """Box of the control polygon, (2, dim)."""
        return np.array([self.control_points.min(axis=0), self.control_points.max(axis=0)])

    def transformed(self, rotation, translation) -> "NurbsCurve":
        """The 3D curve under x -> R x + t."""
        r = np.asarray(rotation, dtype=float).reshape(3, 3)
        t = np.asarray(translation, dtype=float).reshape(3)
        return NurbsCurve(self.degree, self.knots, self.control_points @ r.T + t, self.weights, self.domain)
