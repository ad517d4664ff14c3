"""Many NURBS curves in flat arrays, sampled and evaluated in one compiled call.

`PackedCurves` holds the curves' degrees, knots and homogeneous control points end to end;
`eval_packed` evaluates point and derivatives (Piegl & Tiller A4.2 for the rational ones) of
curve ``ci[k]`` at ``t[k]`` for all k at once. The trim checks of the IGES reader
(`cadbridge.iges.trimcheck`, `cadbridge.cad.analytic`) sample whole files' curves this way.
"""

from __future__ import annotations

import numba
import numpy as np

from cadbridge.nurbs.basis import ders_basis_one, find_span_one
from cadbridge.nurbs.curve import NurbsCurve

__all__ = ["PackedCurves", "eval_packed"]


class PackedCurves:
    """Many NURBS curves (2D or 3D; 2D padded with z = 0) in flat arrays for one compiled call.

    degree (C,), koff (C+1,) offsets into knots (K,), coff (C+1,) offsets into pw (M, 4)
    homogeneous control points (w x, w y, w z, w), dom (C, 2) parameter domains.
    """

    def __init__(self, curves: list[NurbsCurve]) -> None:
        c = len(curves)
        self.degree = np.array([k.degree for k in curves], dtype=np.int64)
        self.koff = np.zeros(c + 1, dtype=np.int64)
        self.coff = np.zeros(c + 1, dtype=np.int64)
        self.koff[1:] = np.cumsum([len(k.knots) for k in curves])
        self.coff[1:] = np.cumsum([len(k.control_points) for k in curves])
        self.knots = np.concatenate([k.knots for k in curves]) if c else np.zeros(0)
        pw = np.zeros((int(self.coff[-1]), 4))
        for k, s in zip(curves, self.coff[:-1]):
            n, d = k.control_points.shape
            w = k.weights
            pw[s : s + n, :d] = k.control_points * w[:, None]
            pw[s : s + n, 3] = w
        self.pw = pw
        self.dom = np.array([k.domain for k in curves], dtype=float).reshape(c, 2)

    def __len__(self) -> int:
        return len(self.degree)

    def sample(self, per_span) -> tuple[np.ndarray, np.ndarray]:
        """(curve index (M,), t (M,)): ``per_span`` intervals (an int, or one per curve) per
        non-empty knot span of each curve's domain, ends included (as
        `NurbsCurve.sample_parameters`)."""
        per = np.broadcast_to(np.asarray(per_span, dtype=np.int64), self.degree.shape)
        return _sample_packed(self.degree, self.koff, self.knots, self.dom, np.ascontiguousarray(per))

    def evaluate(self, ci: np.ndarray, t: np.ndarray, order: int) -> np.ndarray:
        """Derivatives up to ``order`` of curve ci[k] at t[k]: (N, order+1, 3)."""
        return eval_packed(self.degree, self.koff, self.knots, self.coff, self.pw,
                           np.ascontiguousarray(ci, dtype=np.int64), np.ascontiguousarray(t, dtype=float), order)


@numba.njit(cache=True, error_model="numpy")
def _sample_packed(degree, koff, knots, dom, per):  # pragma: no cover - compiled
    nc = len(degree)
    count = 0
    for c in range(nc):
        t0, t1 = dom[c, 0], dom[c, 1]
        prev = t0
        for k in range(koff[c], koff[c + 1]):
            x = knots[k]
            if x > prev and x < t1:
                count += per[c]
                prev = x
        count += per[c] + 1
    ci = np.empty(count, dtype=np.int64)
    tt = np.empty(count)
    m = 0
    for c in range(nc):
        t0, t1 = dom[c, 0], dom[c, 1]
        a = t0
        for k in range(koff[c], koff[c + 1] + 1):
            last = k == koff[c + 1]
            x = t1 if last else knots[k]
            if last or (x > a and x < t1):
                for j in range(per[c]):
                    ci[m] = c
                    tt[m] = a + (x - a) * j / per[c]
                    m += 1
                a = x
        ci[m] = c
        tt[m] = t1
        m += 1
    return ci[:m], tt[:m]


@numba.njit(cache=True, error_model="numpy")
def eval_packed(degree, koff, knots, coff, pw, ci, t, order):  # pragma: no cover - compiled
    """C, C', ... (up to ``order``) of curve ci[k] at t[k] (P&T A3.2 + A4.2), (N, order+1, 3)."""
    n = len(t)
    out = np.zeros((n, order + 1, 3))
    pmax = 1
    for c in range(len(degree)):
        pmax = max(pmax, degree[c])
    ndu = np.empty((pmax + 1, pmax + 1))
    left = np.empty(pmax + 1)
    right = np.empty(pmax + 1)
    a = np.empty((2, pmax + 1))
    nd = np.empty((order + 1, pmax + 1))
    aw = np.empty((order + 1, 4))
    binom = np.ones((order + 1, order + 1))
    for k in range(order + 1):
        for i in range(1, k):
            binom[k, i] = binom[k - 1, i - 1] + binom[k - 1, i]
    for q in range(n):
        c = ci[q]
        p = degree[c]
        kn = knots[koff[c] : koff[c + 1]]
        nctrl = coff[c + 1] - coff[c]
        x = min(max(t[q], kn[p]), kn[nctrl])
        span = find_span_one(kn, p, nctrl, x)
        ders_basis_one(span, x, p, kn, order, ndu[: p + 1, : p + 1], left[: p + 1], right[: p + 1],
                       a[:, : p + 1], nd[:, : p + 1])
        for k in range(order + 1):
            for d in range(4):
                s = 0.0
                for j in range(p + 1):
                    s += nd[k, j] * pw[coff[c] + span - p + j, d]
                aw[k, d] = s
        for k in range(order + 1):  # A4.2: rational derivatives
            for d in range(3):
                v = aw[k, d]
                for i in range(1, k + 1):
                    v -= binom[k, i] * aw[i, 3] * out[q, k - i, d]
                out[q, k, d] = v / aw[0, 3]
    return out
