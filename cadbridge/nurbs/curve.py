"""Rational B-spline (NURBS) curves in 2D or 3D, vectorised over parameters."""

from __future__ import annotations

from math import comb, isfinite

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
        finite = all(map(isfinite, cp.ravel().tolist())) if cp.size <= 256 else np.isfinite(cp).all()
        if not finite:
            raise ValueError("control points must be finite")
        rational = False
        if weights is None:
            w = np.ones(n)
        else:
            w = np.array(weights, dtype=float).reshape(-1)
            if w.shape != (n,):
                raise ValueError(f"weights must have shape {(n,)}, got {w.shape}")
            wl = w.tolist()  # short: plain Python checks beat numpy call overhead
            if not (all(map(isfinite, wl)) and min(wl) > 0):
                raise ValueError("weights must be finite and positive")
            rational = max(wl) > min(wl)  # ptp(w) > 0
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
        self.rational = rational
        self._pw_cache: np.ndarray | None = None  # homogeneous net, built on first use (`_pw`)
        for a in (kn, cp, w):
            a.setflags(write=False)

    @classmethod
    def _trusted(cls, degree: int, knots: np.ndarray, control_points: np.ndarray, weights: np.ndarray,
                 domain: tuple[float, float], rational: bool) -> "NurbsCurve":
        """A curve from data already validated by another NurbsCurve (e.g. its control points
        with z dropped), skipping the checks: read-only float arrays of consistent shapes."""
        self = cls.__new__(cls)
        cp = np.array(control_points, dtype=float)
        cp.setflags(write=False)
        self.degree = degree
        self.knots = knots if not knots.flags.writeable else knots.copy()
        self.control_points = cp
        self.weights = weights if not weights.flags.writeable else weights.copy()
        for a in (self.knots, self.weights):
            a.setflags(write=False)
        self.domain = domain
        self.rational = rational
        self._pw_cache = None
        return self

    @property
    def _pw(self) -> np.ndarray:
        """Homogeneous control points (n, dim+1): (w x, w y[, w z], w), read-only."""
        pw = self._pw_cache
        if pw is None:
            cp, w = self.control_points, self.weights
            n, dim = cp.shape
            pw = np.empty((n, dim + 1))
            if self.rational:
                pw[:, :dim] = cp * w[:, None]
                pw[:, dim] = w
            else:
                pw[:, :dim] = cp
                pw[:, dim] = 1.0
            pw.setflags(write=False)
            self._pw_cache = pw
        return pw

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
        a = edges[:-1, None]
        step = (edges[1:, None] - a) / per_span  # each span as np.linspace(a, b, per_span + 1)[:-1]
        return np.append((np.arange(per_span) * step + a).ravel(), t1)

    def bbox(self) -> np.ndarray:
        """Box of the control polygon, (2, dim)."""
        return np.array([self.control_points.min(axis=0), self.control_points.max(axis=0)])

    def transformed(self, rotation, translation) -> "NurbsCurve":
        """The 3D curve under x -> R x + t."""
        r = np.asarray(rotation, dtype=float).reshape(3, 3)
        t = np.asarray(translation, dtype=float).reshape(3)
        return NurbsCurve(self.degree, self.knots, self.control_points @ r.T + t, self.weights, self.domain)
