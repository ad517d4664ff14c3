"""B-spline basis functions, vectorised over parameters (Piegl & Tiller A2.1-A2.3).

All functions take a knot vector ``knots`` (m+1,), a degree ``p`` and parameters ``u`` (N,)
and work on all N parameters at once; loops run only over the (small) degree.
"""

from __future__ import annotations

from math import isfinite
from operator import eq

import numba
import numpy as np

__all__ = ["find_span", "basis_funs", "ders_basis_funs", "validate_knots", "find_span_one", "ders_basis_one",
           "ders1_basis_one"]


_SCAN_MAX = 8  # `find_span_one` counts knots instead of bisecting up to this many interior knots
_MIN_SPAN = 1e-300  # shorter non-empty knot spans make 1 / span overflow in the recurrences


def validate_knots(knots: np.ndarray, degree: int, n_ctrl: int, what: str = "knots") -> None:
    """Raise ValueError unless ``knots`` is a valid knot vector for ``n_ctrl`` control points.

    Checks: length n_ctrl + degree + 1, finite, non-decreasing, no interior knot of
    multiplicity above ``degree`` + 1, a non-empty domain [knots[p], knots[n_ctrl]] and no
    non-empty span shorter than 1e-300 (its reciprocal would overflow to inf / NaN).
    """
    knots = np.asarray(knots, dtype=float)
    if (knots.ndim == 1 and 1 <= degree < n_ctrl and len(knots) == n_ctrl + degree + 1
            and len(knots) <= 64 and _small_knots_ok(knots.tolist(), degree, n_ctrl)):
        return  # fast path for the usual short vector; any failure is diagnosed below
    if degree < 1:
        raise ValueError(f"{what}: degree must be >= 1, got {degree}")
    if n_ctrl < degree + 1:
        raise ValueError(f"{what}: {n_ctrl} control points is fewer than degree + 1 = {degree + 1}")
    if knots.ndim != 1 or len(knots) != n_ctrl + degree + 1:
        raise ValueError(
            f"{what}: expected {n_ctrl + degree + 1} knots for {n_ctrl} control points of "
            f"degree {degree}, got {knots.size}"
        )
    if not np.all(np.isfinite(knots)):
        raise ValueError(f"{what}: knots must be finite")
    diffs = np.diff(knots)
    if np.any(diffs < 0):
        i = int(np.argmax(diffs < 0))
        raise ValueError(f"{what}: knots decrease at index {i + 1} ({knots[i]!r} > {knots[i + 1]!r})")
    if not knots[n_ctrl] > knots[degree]:
        raise ValueError(f"{what}: empty parameter domain [{knots[degree]!r}, {knots[n_ctrl]!r}]")
    tiny = (diffs > 0) & (diffs < _MIN_SPAN)
    if np.any(tiny):
        i = int(np.argmax(tiny))
        raise ValueError(f"{what}: knots {knots[i]!r} and {knots[i + 1]!r} differ by less than {_MIN_SPAN:g} "
                         f"(a span whose reciprocal overflows): make them equal")
    # multiplicity check on the domain part (the ends may carry up to p+1 equal knots)
    inner = knots[degree + 1 : n_ctrl]
    if inner.size:
        _, counts = np.unique(inner, return_counts=True)
        if counts.max() > degree:
            raise ValueError(f"{what}: an interior knot has multiplicity {counts.max()} > degree {degree}")


def _small_knots_ok(k: list[float], p: int, n_ctrl: int) -> bool:
    """The checks of `validate_knots` on a short list in plain Python (no numpy call overhead):
    True only if all of them pass."""
    if not all(map(isfinite, k)) or k != sorted(k):  # finite, non-decreasing
        return False
    if not k[n_ctrl] > k[p]:
        return False
    if any(0.0 < b - a < _MIN_SPAN for a, b in zip(k, k[1:])):
        return False
    inner = k[p + 1 : n_ctrl]  # sorted: a run longer than p means inner[i] == inner[i + p]
    return not any(map(eq, inner, inner[p:]))


def find_span(knots: np.ndarray, p: int, u: np.ndarray, side=None) -> np.ndarray:
    """Knot span index i with knots[i] <= u < knots[i+1] for each u (A2.1), (N,) int.

    Parameters outside the domain are clamped to the first/last span, and u at the right end
    of the domain belongs to the last non-empty span, so no basis function is lost there.
    ``side`` (N,) of -1/+1 picks, for u exactly at an interior knot, the span on that side
    (knots[i] < u <= knots[i+1] for -1): one-sided derivatives across a C0 knot.
    """
    knots = np.asarray(knots, dtype=float)
    n = len(knots) - p - 2  # index of the last control point
    u = np.asarray(u, dtype=float)
    span = np.searchsorted(knots, u, side="right") - 1
    if side is not None:
        left = np.searchsorted(knots, u, side="left") - 1
        span = np.where(np.asarray(side) < 0, np.maximum(left, p), span)
    return np.clip(span, p, n)


def basis_funs(span: np.ndarray, u: np.ndarray, p: int, knots: np.ndarray) -> np.ndarray:
    """The p+1 non-zero basis functions N_{span-p..span, p}(u) (A2.2). Returns (N, p+1)."""
    return ders_basis_funs(span, u, p, knots, 0)[:, 0, :]


def ders_basis_funs(span: np.ndarray, u: np.ndarray, p: int, knots: np.ndarray, n: int) -> np.ndarray:
    """Non-zero basis functions and their derivatives up to order ``n`` (A2.3).

    Returns (N, n+1, p+1): [:, k, j] = d^k N_{span-p+j, p} / du^k at u. Orders above p are zero.
    """
    knots = np.asarray(knots, dtype=float)
    u = np.asarray(u, dtype=float)
    span = np.asarray(span)
    npts = u.shape[0]
    ndu = np.empty((npts, p + 1, p + 1))
    ndu[:, 0, 0] = 1.0
    left = np.empty((npts, p + 1))
    right = np.empty((npts, p + 1))
    for j in range(1, p + 1):
        left[:, j] = u - knots[span + 1 - j]
        right[:, j] = knots[span + j] - u
        saved = np.zeros(npts)
        for r in range(j):
            ndu[:, j, r] = right[:, r + 1] + left[:, j - r]  # knot differences (lower triangle)
            temp = ndu[:, r, j - 1] / ndu[:, j, r]
            ndu[:, r, j] = saved + right[:, r + 1] * temp  # basis functions (upper triangle)
            saved = left[:, j - r] * temp
        ndu[:, j, j] = saved

    ders = np.zeros((npts, n + 1, p + 1))
    ders[:, 0, :] = ndu[:, :, p]
    nd = min(n, p)
    if nd == 0:
        return ders
    a = np.zeros((npts, 2, p + 1))
    for r in range(p + 1):
        s1, s2 = 0, 1
        a[:] = 0.0
        a[:, 0, 0] = 1.0
        for k in range(1, nd + 1):
            d = np.zeros(npts)
            rk, pk = r - k, p - k
            if r >= k:
                a[:, s2, 0] = a[:, s1, 0] / ndu[:, pk + 1, rk]
                d += a[:, s2, 0] * ndu[:, rk, pk]
            j1 = 1 if rk >= -1 else -rk
            j2 = k - 1 if r - 1 <= pk else p - r
            for j in range(j1, j2 + 1):
                a[:, s2, j] = (a[:, s1, j] - a[:, s1, j - 1]) / ndu[:, pk + 1, rk + j]
                d += a[:, s2, j] * ndu[:, rk + j, pk]
            if r <= pk:
                a[:, s2, k] = -a[:, s1, k - 1] / ndu[:, pk + 1, r]
                d += a[:, s2, k] * ndu[:, r, pk]
            ders[:, k, r] = d
            s1, s2 = s2, s1
    factor = float(p)
    for k in range(1, nd + 1):
        ders[:, k, :] *= factor
        factor *= p - k
    return ders


# ---------------------------------------------------------------------------- compiled, one parameter
# Scalar versions of A2.1 / A2.3 for numba kernels (surface/curve evaluation): same arithmetic,
# in the same order, as the vectorised functions above; scratch arrays are passed in so a
# kernel can allocate them once per block of points.
@numba.njit(cache=True, inline="always", error_model="numpy")
def find_span_one(knots, p, n_ctrl, x):  # pragma: no cover - compiled
    """Span index as ``find_span``: largest i in [p, n_ctrl - 1] with knots[i] <= x, else p.

    Up to `_SCAN_MAX` interior knots (a few spans: Bezier patches, most CAD faces) the span is
    p plus the count of knots[p+1 .. n_ctrl-1] <= x, without branches (sorted knots: the
    same index; a NaN x gives p either way): random parameters make the binary search's
    branches unpredictable, which cost more than the few comparisons (bench_kernel.py)."""
    if n_ctrl - p - 1 <= _SCAN_MAX:
        s = p
        for i in range(p + 1, n_ctrl):
            s += knots[i] <= x
        return s
    lo, hi = p, n_ctrl - 1
    if x >= knots[hi]:
        return hi
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if knots[mid] <= x:
            lo = mid
        else:
            hi = mid - 1
    return lo


@numba.njit(cache=True, inline="always", error_model="numpy")
def ders_basis_one(span, x, p, knots, n, ndu, left, right, a, out):  # pragma: no cover - compiled
    """A2.3 at one parameter: out[k, j] = d^k N_{span-p+j,p}(x), k <= n (orders above p zero).
    Scratch: ndu (p+1, p+1), left/right (p+1,), a (2, p+1); out (n+1, p+1)."""
    ndu[0, 0] = 1.0
    for j in range(1, p + 1):
        left[j] = x - knots[span + 1 - j]
        right[j] = knots[span + j] - x
        saved = 0.0
        for r in range(j):
            ndu[j, r] = right[r + 1] + left[j - r]
            temp = ndu[r, j - 1] / ndu[j, r]
            ndu[r, j] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j, j] = saved
    for k in range(n + 1):
        for j in range(p + 1):
            out[k, j] = 0.0
    for j in range(p + 1):
        out[0, j] = ndu[j, p]
    nd = min(n, p)
    if nd == 0:
        return
    if nd == 1:
        # first derivatives only: the k = 1 pass of the loop below with its (empty) j loop
        # removed, the same operations in the same order (bit-identical results; each
        # reciprocal 1 / ndu[p, r] is shared by r and r + 1, and -1.0 / x == -(1.0 / x))
        prev = 0.0  # 1 / ndu[p, r - 1]
        for r in range(p + 1):
            d = 0.0
            if r >= 1:
                d += prev * ndu[r - 1, p - 1]
            if r <= p - 1:
                inv = 1.0 / ndu[p, r]
                d += -inv * ndu[r, p - 1]
                prev = inv
            out[1, r] = d * p
        return
    for r in range(p + 1):
        s1, s2 = 0, 1
        for j in range(p + 1):
            a[0, j] = 0.0
            a[1, j] = 0.0
        a[0, 0] = 1.0
        for k in range(1, nd + 1):
            d = 0.0
            rk, pk = r - k, p - k
            if r >= k:
                a[s2, 0] = a[s1, 0] / ndu[pk + 1, rk]
                d += a[s2, 0] * ndu[rk, pk]
            j1 = 1 if rk >= -1 else -rk
            j2 = k - 1 if r - 1 <= pk else p - r
            for j in range(j1, j2 + 1):
                a[s2, j] = (a[s1, j] - a[s1, j - 1]) / ndu[pk + 1, rk + j]
                d += a[s2, j] * ndu[rk + j, pk]
            if r <= pk:
                a[s2, k] = -a[s1, k - 1] / ndu[pk + 1, r]
                d += a[s2, k] * ndu[r, pk]
            out[k, r] = d
            s1, s2 = s2, s1
    factor = float(p)
    for k in range(1, nd + 1):
        for j in range(p + 1):
            out[k, j] *= factor
        factor *= p - k


@numba.njit(cache=True, inline="always", error_model="numpy")
def ders1_basis_one(span, x, p, knots, left, right, nb, out):  # pragma: no cover - compiled
    """`ders_basis_one` with n = 1 (p >= 1), without the (p+1, p+1) table: out[0, j] =
    N_{span-p+j,p}(x), out[1, j] its first derivative. The degree p-1 functions are built in
    place in nb (A2.2), then the last step gives both the degree p values and the derivatives
    p (N_{j-1,p-1} / d_{j-1} - N_{j,p-1} / d_j), d_r = right[r+1] + left[p-r] (the knot
    differences ndu[p, r] of A2.3): the same operations in the same order as ``ders_basis_one``,
    bit-identical results. Scratch: left/right/nb (p+1,); out (2, p+1).

    Degrees 1 and 2 are written out in scalars (the same operations in the same order; the
    scratch arrays are not used): the loops and scratch traffic cost as much as the
    arithmetic at these degrees."""
    if p == 1:
        # r = 0 of the last step with nb[0] = 1: temp = inv = 1 / d_0
        l1 = x - knots[span]
        r1 = knots[span + 1] - x
        inv = 1.0 / (r1 + l1)
        out[0, 0] = 0.0 + r1 * inv
        out[0, 1] = l1 * inv
        out[1, 0] = (-inv * 1.0) * 1
        out[1, 1] = (inv * 1.0) * 1
        return
    if p == 2:
        l1 = x - knots[span]
        r1 = knots[span + 1] - x
        temp = 1.0 / (r1 + l1)
        nb0 = 0.0 + r1 * temp  # degree 1 functions (the j = 1 pass)
        nb1 = l1 * temp
        l2 = x - knots[span - 1]
        r2 = knots[span + 2] - x
        den = r1 + l2  # d_0
        temp = nb0 / den
        out[0, 0] = 0.0 + r1 * temp
        saved = l2 * temp
        inv0 = 1.0 / den
        out[1, 0] = (-inv0 * nb0) * 2
        den = r2 + l1  # d_1
        temp = nb1 / den
        out[0, 1] = saved + r2 * temp
        out[0, 2] = l1 * temp
        inv1 = 1.0 / den
        out[1, 1] = (inv0 * nb0 + -inv1 * nb1) * 2
        out[1, 2] = (inv1 * nb1) * 2
        return
    nb[0] = 1.0
    for j in range(1, p):
        left[j] = x - knots[span + 1 - j]
        right[j] = knots[span + j] - x
        saved = 0.0
        for r in range(j):
            temp = nb[r] / (right[r + 1] + left[j - r])
            nb[r] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        nb[j] = saved
    left[p] = x - knots[span + 1 - p]
    right[p] = knots[span + p] - x
    saved = 0.0
    prev = 0.0  # 1 / d_{r-1}
    for r in range(p):
        den = right[r + 1] + left[p - r]
        temp = nb[r] / den
        out[0, r] = saved + right[r + 1] * temp
        saved = left[p - r] * temp
        inv = 1.0 / den
        d = -inv * nb[r]
        if r >= 1:
            d = prev * nb[r - 1] + d
        out[1, r] = d * p
        prev = inv
    out[0, p] = saved
    out[1, p] = (prev * nb[p - 1]) * p
