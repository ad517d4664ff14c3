"""Rational B-spline (NURBS) surfaces: exact evaluation, analytic derivatives, unit normals."""

from __future__ import annotations

from math import comb

import numba
import numpy as np

from cadbridge.common.jit import parallel_kernels
from cadbridge.nurbs.basis import (ders1_basis_one, ders_basis_funs, ders_basis_one, find_span, find_span_one,
                                   validate_knots)

__all__ = ["NurbsSurface", "d01_range"]

_CHUNK = 32768  # points per evaluation block of the numpy path (bounds temporary memory)
_BLOCK = 1024  # points per task of the parallel kernel
_PARALLEL_MIN = 16384  # fewer points: the serial kernel (thread start-up costs more than it saves)


def _binomials(d: int) -> np.ndarray:
    """Pascal's triangle up to row d, (d+1, d+1) floats (zero above the diagonal)."""
    return np.array([[float(comb(i, j)) for j in range(d + 1)] for i in range(d + 1)])


@numba.njit(cache=True, error_model="numpy")
def _ders_range(pw, ku, kv, p, q, d, rational, u, v, out, start, stop, binom):  # pragma: no cover - compiled
    """Surface derivatives up to order d in u and v at points start..stop-1 into out
    (N, d+1, d+1, 3): the homogeneous derivatives Aw = sum_a Nu^(k)_a sum_b Nv^(l)_b Pw_ab (the
    same sums, in the same order, as the numpy path ``_derivatives_block``) then, if
    rational, the quotient rule of P&T A4.4."""
    nu, nv = pw.shape[0], pw.shape[1]
    ndu_u = np.empty((p + 1, p + 1))
    ndu_v = np.empty((q + 1, q + 1))
    lu = np.empty(p + 1)
    ru = np.empty(p + 1)
    lv = np.empty(q + 1)
    rv = np.empty(q + 1)
    au = np.empty((2, p + 1))
    av = np.empty((2, q + 1))
    bu = np.empty((d + 1, p + 1))
    bv = np.empty((d + 1, q + 1))
    aw = np.empty((d + 1, d + 1, 4))
    for t in range(start, stop):
        su = find_span_one(ku, p, nu, u[t])
        sv = find_span_one(kv, q, nv, v[t])
        ders_basis_one(su, u[t], p, ku, d, ndu_u, lu, ru, au, bu)
        ders_basis_one(sv, v[t], q, kv, d, ndu_v, lv, rv, av, bv)
        aw[:] = 0.0
        for a in range(p + 1):
            row = pw[su - p + a]
            for l in range(d + 1):
                # sum over b of Nv^(l)_b Pw_ab, the four coordinates in scalars
                t0 = 0.0
                t1 = 0.0
                t2 = 0.0
                t3 = 0.0
                for b in range(q + 1):
                    w = bv[l, b]
                    pt = row[sv - q + b]
                    t0 += w * pt[0]
                    t1 += w * pt[1]
                    t2 += w * pt[2]
                    t3 += w * pt[3]
                for k in range(d + 1):
                    w = bu[k, a]
                    aw[k, l, 0] += w * t0
                    aw[k, l, 1] += w * t1
                    aw[k, l, 2] += w * t2
                    aw[k, l, 3] += w * t3
        if not rational:
            for k in range(d + 1):
                for l in range(d + 1):
                    for c in range(3):
                        out[t, k, l, c] = aw[k, l, c]
            continue
        w0 = aw[0, 0, 3]
        for k in range(d + 1):
            for l in range(d + 1):
                for c in range(3):
                    val = aw[k, l, c]
                    for j in range(1, l + 1):
                        val -= binom[l, j] * aw[0, j, 3] * out[t, k, l - j, c]
                    for i in range(1, k + 1):
                        val -= binom[k, i] * aw[i, 0, 3] * out[t, k - i, l, c]
                        for j in range(1, l + 1):
                            val -= binom[k, i] * binom[l, j] * aw[i, j, 3] * out[t, k - i, l - j, c]
                    out[t, k, l, c] = val / w0


@numba.njit(cache=True, error_model="numpy")
def d01_range(pw, ku, kv, p, q, d, rational, u, v, out, start, stop):  # pragma: no cover - compiled
    """`_ders_range` for d = 0 (S into out (N, 1, 1, 3)) or d = 1 (S, Su, Sv, Suv into out
    (N, 2, 2, 3)), specialised (one compiled kernel serves `evaluate` and first derivatives): basis values
    and first derivatives by `ders1_basis_one` into (2, p+1) / (2, q+1), the 16 homogeneous sums in scalars, the
    quotient rule written out. The same operations in the same order as the generic kernel
    (binomials of order 1 are 1.0, an exact factor), so the results are bit-identical."""
    nu, nv = pw.shape[0], pw.shape[1]
    nbu = np.empty(p + 1)
    nbv = np.empty(q + 1)
    lu = np.empty(p + 1)
    ru = np.empty(p + 1)
    lv = np.empty(q + 1)
    rv = np.empty(q + 1)
    bu = np.empty((2, p + 1))
    bv = np.empty((2, q + 1))
    for t in range(start, stop):
        x = u[t]
        y = v[t]
        su = find_span_one(ku, p, nu, x)
        sv = find_span_one(kv, q, nv, y)
        ders1_basis_one(su, x, p, ku, lu, ru, nbu, bu)
        ders1_basis_one(sv, y, q, kv, lv, rv, nbv, bv)
        i0 = su - p
        j0 = sv - q
        # homogeneous sums A_kl = sum_a Nu^(k)_a sum_b Nv^(l)_b Pw_ab, coordinates x y z w
        a00x = a00y = a00z = a00w = 0.0
        a01x = a01y = a01z = a01w = 0.0
        a10x = a10y = a10z = a10w = 0.0
        a11x = a11y = a11z = a11w = 0.0
        for a in range(p + 1):
            t0x = t0y = t0z = t0w = 0.0  # sum_b Nv_b Pw_ab
            t1x = t1y = t1z = t1w = 0.0  # sum_b Nv'_b Pw_ab
            for b in range(q + 1):
                # scalar loads (no (4,) view per control point: views cost ~10% at low degree)
                px = pw[i0 + a, j0 + b, 0]
                py = pw[i0 + a, j0 + b, 1]
                pz = pw[i0 + a, j0 + b, 2]
                pw_ = pw[i0 + a, j0 + b, 3]
                w = bv[0, b]
                t0x += w * px
                t0y += w * py
                t0z += w * pz
                t0w += w * pw_
                w = bv[1, b]
                t1x += w * px
                t1y += w * py
                t1z += w * pz
                t1w += w * pw_
            w = bu[0, a]
            a00x += w * t0x
            a00y += w * t0y
            a00z += w * t0z
            a00w += w * t0w
            a01x += w * t1x
            a01y += w * t1y
            a01z += w * t1z
            a01w += w * t1w
            w = bu[1, a]
            a10x += w * t0x
            a10y += w * t0y
            a10z += w * t0z
            a10w += w * t0w
            a11x += w * t1x
            a11y += w * t1y
            a11z += w * t1z
            a11w += w * t1w
        if d == 0:
            if rational:
                out[t, 0, 0, 0] = a00x / a00w
                out[t, 0, 0, 1] = a00y / a00w
                out[t, 0, 0, 2] = a00z / a00w
            else:
                out[t, 0, 0, 0] = a00x
                out[t, 0, 0, 1] = a00y
                out[t, 0, 0, 2] = a00z
            continue
        if not rational:
            out[t, 0, 0, 0] = a00x
            out[t, 0, 0, 1] = a00y
            out[t, 0, 0, 2] = a00z
            out[t, 0, 1, 0] = a01x
            out[t, 0, 1, 1] = a01y
            out[t, 0, 1, 2] = a01z
            out[t, 1, 0, 0] = a10x
            out[t, 1, 0, 1] = a10y
            out[t, 1, 0, 2] = a10z
            out[t, 1, 1, 0] = a11x
            out[t, 1, 1, 1] = a11y
            out[t, 1, 1, 2] = a11z
            continue
        # P&T A4.4 with k, l <= 1: S = A/w, S_v = (A_v - w_v S)/w, S_u = (A_u - w_u S)/w,
        # S_uv = (A_uv - w_v S_u - w_u S_v - w_uv S)/w (subtractions in the generic order)
        sx = a00x / a00w
        sy = a00y / a00w
        sz = a00z / a00w
        svx = (a01x - a01w * sx) / a00w
        svy = (a01y - a01w * sy) / a00w
        svz = (a01z - a01w * sz) / a00w
        sux = (a10x - a10w * sx) / a00w
        suy = (a10y - a10w * sy) / a00w
        suz = (a10z - a10w * sz) / a00w
        out[t, 0, 0, 0] = sx
        out[t, 0, 0, 1] = sy
        out[t, 0, 0, 2] = sz
        out[t, 0, 1, 0] = svx
        out[t, 0, 1, 1] = svy
        out[t, 0, 1, 2] = svz
        out[t, 1, 0, 0] = sux
        out[t, 1, 0, 1] = suy
        out[t, 1, 0, 2] = suz
        out[t, 1, 1, 0] = (((a11x - a01w * sux) - a10w * svx) - a11w * sx) / a00w
        out[t, 1, 1, 1] = (((a11y - a01w * suy) - a10w * svy) - a11w * sy) / a00w
        out[t, 1, 1, 2] = (((a11z - a01w * suz) - a10w * svz) - a11w * sz) / a00w


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _ders_parallel(pw, ku, kv, p, q, d, rational, u, v, out, binom):  # pragma: no cover - compiled
    n = u.shape[0]
    for blk in numba.prange((n + _BLOCK - 1) // _BLOCK):
        _ders_range(pw, ku, kv, p, q, d, rational, u, v, out, blk * _BLOCK, min(n, (blk + 1) * _BLOCK), binom)


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _d01_parallel(pw, ku, kv, p, q, d, rational, u, v, out):  # pragma: no cover - compiled
    n = u.shape[0]
    for blk in numba.prange((n + _BLOCK - 1) // _BLOCK):
        d01_range(pw, ku, kv, p, q, d, rational, u, v, out, blk * _BLOCK, min(n, (blk + 1) * _BLOCK))


class NurbsSurface:
    """A NURBS surface S(u, v) = sum R_ij(u, v) P_ij (Piegl & Tiller eq. 4.15).

    Parameters
    ----------
    degree_u, degree_v : int
        Degrees p, q (IGES M1, M2).
    knots_u, knots_v : (nu + p + 1,), (nv + q + 1,)
        Knot vectors (IGES S and T).
    control_points : (nu, nv, 3)
        Control net, [i, j] with i along u (IGES order: first index fastest).
    weights : (nu, nv), optional
        Positive weights; None or all equal means polynomial.
    domain : (u0, u1, v0, v1), optional
        Parameter range of the surface (IGES U0, U1, V0, V1); defaults to the knot domain.

    Instances are treated as immutable: arrays are copied and made read-only.
    """

    def __init__(
        self,
        degree_u: int,
        degree_v: int,
        knots_u,
        knots_v,
        control_points,
        weights=None,
        domain=None,
    ) -> None:
        p, q = int(degree_u), int(degree_v)
        cp = np.array(control_points, dtype=float)
        if cp.ndim != 3 or cp.shape[2] != 3:
            raise ValueError(f"control_points must have shape (nu, nv, 3), got {cp.shape}")
        nu, nv = cp.shape[:2]
        ku = np.array(knots_u, dtype=float)
        kv = np.array(knots_v, dtype=float)
        validate_knots(ku, p, nu, "knots_u")
        validate_knots(kv, q, nv, "knots_v")
        if not np.isfinite(cp).all():
            raise ValueError("control points must be finite")
        rational = False
        if weights is None:
            w = np.ones((nu, nv))
        else:
            w = np.array(weights, dtype=float)
            if w.shape != (nu, nv):
                raise ValueError(f"weights must have shape {(nu, nv)}, got {w.shape}")
            if not np.isfinite(w).all():
                raise ValueError("weights must be finite and positive")
            w_lo, w_hi = w.min(), w.max()
            if not w_lo > 0:
                raise ValueError("weights must be finite and positive")
            rational = bool(w_hi > w_lo)  # ptp(w) > 0
        full = (ku[p], ku[nu], kv[q], kv[nv])
        if domain is None:
            dom = full
        else:
            dom = tuple(float(x) for x in domain)
            if len(dom) != 4:
                raise ValueError("domain must be (u0, u1, v0, v1)")
            tol_u = 1e-9 * max(1.0, full[1] - full[0])
            tol_v = 1e-9 * max(1.0, full[3] - full[2])
            if not (full[0] - tol_u <= dom[0] < dom[1] <= full[1] + tol_u):
                raise ValueError(f"u range [{dom[0]!r}, {dom[1]!r}] not inside knot domain [{full[0]!r}, {full[1]!r}]")
            if not (full[2] - tol_v <= dom[2] < dom[3] <= full[3] + tol_v):
                raise ValueError(f"v range [{dom[2]!r}, {dom[3]!r}] not inside knot domain [{full[2]!r}, {full[3]!r}]")
            dom = (max(dom[0], full[0]), min(dom[1], full[1]), max(dom[2], full[2]), min(dom[3], full[3]))
        self.degree_u, self.degree_v = p, q
        self.knots_u, self.knots_v = ku, kv
        self.control_points = cp
        self.weights = w
        self.domain: tuple[float, float, float, float] = dom
        self.rational = rational
        pw = np.empty((nu, nv, 4))
        if self.rational:
            pw[..., :3] = cp * w[..., None]
            pw[..., 3] = w
        else:
            pw[..., :3] = cp
            pw[..., 3] = 1.0
        self._pw = pw
        for a in (ku, kv, cp, w, pw):
            a.setflags(write=False)

    # ------------------------------------------------------------------ basic properties
    @property
    def shape(self) -> tuple[int, int]:
        """Number of control points (nu, nv)."""
        return self.control_points.shape[:2]

    def __repr__(self) -> str:
        nu, nv = self.shape
        kind = "rational" if self.rational else "polynomial"
        return f"NurbsSurface(degrees=({self.degree_u}, {self.degree_v}), ctrl=({nu}, {nv}), {kind}, domain={self.domain})"

    def same_as(self, other: "NurbsSurface") -> bool:
        """Bit-for-bit equality of degrees, knots, control points, weights and domain."""
        return (
            self.degree_u == other.degree_u
            and self.degree_v == other.degree_v
            and np.array_equal(self.knots_u, other.knots_u)
            and np.array_equal(self.knots_v, other.knots_v)
            and np.array_equal(self.control_points, other.control_points)
            and np.array_equal(self.weights, other.weights)
            and tuple(self.domain) == tuple(other.domain)
        )

    # ------------------------------------------------------------------ evaluation
    def derivatives(self, u, v, order: int = 2, side_u=None, side_v=None) -> np.ndarray:
        """All partial derivatives up to ``order`` in each direction, analytically.

        u, v : (N,) parameters. Returns (N, order+1, order+1, 3) with
        [:, k, l] = d^(k+l) S / du^k dv^l (rational quotient rule, P&T A4.4).
        side_u, side_v : optional (N,) of -1/+1: at a knot, the one-sided derivatives from
        that side (they differ across a C0 knot, e.g. a crease inside one NURBS face).
        """
        if side_u is not None or side_v is not None:
            return self._derivatives_numpy(u, v, order, side_u, side_v)
        u = np.atleast_1d(np.asarray(u, dtype=float))
        v = np.atleast_1d(np.asarray(v, dtype=float))
        u, v = np.broadcast_arrays(u, v)
        u = np.ascontiguousarray(u.ravel())
        v = np.ascontiguousarray(v.ravel())
        if not u.flags.writeable:  # one compiled signature: writable C arrays (read-only ones
            u = u.copy()  # would be a second specialisation, compiled again)
        if not v.flags.writeable:
            v = v.copy()
        d = int(order)
        if d < 0:
            raise ValueError(f"order must be >= 0, got {order}")
        out = np.empty((u.size, d + 1, d + 1, 3))
        if u.size:
            # compiled kernels, loaded lazily: orders 0 and 1 share the specialised `d01_range`,
            # higher orders the generic `_ders_range`; the serial kernels are called directly and
            # the parallel (prange) ones, slower to compile, only for many points
            args = (self._pw, self.knots_u, self.knots_v, self.degree_u, self.degree_v, d, self.rational, u, v, out)
            many = u.size >= _PARALLEL_MIN and parallel_kernels()
            if d <= 1:
                if many:
                    _d01_parallel(*args)
                else:
                    d01_range(*args, 0, u.size)
            elif many:
                _ders_parallel(*args, _binomials(d))
            else:
                _ders_range(*args, 0, u.size, _binomials(d))
        return out

    def _derivatives_numpy(self, u, v, order: int = 2, side_u=None, side_v=None) -> np.ndarray:
        """numpy implementation of `derivatives` (same results; also the one-sided path)."""
        u = np.atleast_1d(np.asarray(u, dtype=float))
        v = np.atleast_1d(np.asarray(v, dtype=float))
        u, v = np.broadcast_arrays(u, v)
        u, v = u.ravel(), v.ravel()
        su = None if side_u is None else np.broadcast_to(np.asarray(side_u), u.shape)
        sv = None if side_v is None else np.broadcast_to(np.asarray(side_v), u.shape)
        out = np.empty((u.size, order + 1, order + 1, 3))
        for s in range(0, u.size, _CHUNK):
            blk = slice(s, s + _CHUNK)
            out[blk] = self._derivatives_block(u[blk], v[blk], order,
                                               None if su is None else su[blk], None if sv is None else sv[blk])
        return out

    def _homogeneous_derivatives(self, u: np.ndarray, v: np.ndarray, d: int, side_u=None, side_v=None) -> np.ndarray:
        """Derivatives of the homogeneous surface Sw = (wx, wy, wz, w): (N, d+1, d+1, 4)."""
        p, q = self.degree_u, self.degree_v
        su = find_span(self.knots_u, p, u, side_u)
        sv = find_span(self.knots_v, q, v, side_v)
        nu_d = ders_basis_funs(su, u, p, self.knots_u, d)  # (N, d+1, p+1)
        nv_d = ders_basis_funs(sv, v, q, self.knots_v, d)  # (N, d+1, q+1)
        iu = su[:, None] - p + np.arange(p + 1)
        iv = sv[:, None] - q + np.arange(q + 1)
        pw = self._pw[iu[:, :, None], iv[:, None, :]]  # (N, p+1, q+1, 4)
        tmp = np.einsum("nlb,nabc->nalc", nv_d, pw)  # (N, p+1, d+1, 4)
        return np.einsum("nka,nalc->nklc", nu_d, tmp)  # (N, d+1, d+1, 4)

    def _derivatives_block(self, u: np.ndarray, v: np.ndarray, d: int, side_u=None, side_v=None) -> np.ndarray:
        aw = self._homogeneous_derivatives(u, v, d, side_u, side_v)
        if not self.rational:
            return aw[..., :3].copy()
        a = aw[..., :3]
        w = aw[..., 3]
        skl = np.empty_like(a)
        w0 = w[:, 0, 0][:, None]
        for k in range(d + 1):
            for l in range(d + 1):
                val = a[:, k, l].copy()
                for j in range(1, l + 1):
                    val -= comb(l, j) * w[:, 0, j][:, None] * skl[:, k, l - j]
                for i in range(1, k + 1):
                    val -= comb(k, i) * w[:, i, 0][:, None] * skl[:, k - i, l]
                    for j in range(1, l + 1):
                        val -= comb(k, i) * comb(l, j) * w[:, i, j][:, None] * skl[:, k - i, l - j]
                skl[:, k, l] = val / w0
        return skl

    def evaluate(self, u, v) -> np.ndarray:
        """Points S(u, v): u, v (N,) -> (N, 3)."""
        return self.derivatives(u, v, order=0)[:, 0, 0]

    __call__ = evaluate

    def normal(self, u, v, return_flags: bool = False, side_u=None, side_v=None):
        """Unit normals in the direction of Su x Sv: u, v (N,) -> (N, 3).

        ``side_u``/``side_v`` (N,) of -1/+1 give one-sided normals at knots (see `derivatives`).

        At degenerate points, where |Su x Sv| <= 1e-10 max(|Su|, |Sv|)^2 (a collapsed edge:
        a pole or an apex; or Su parallel to Sv), the limit normal approached from inside the
        domain is returned (`limit_normal`): along v on a collapsed side v = v0 or v1
        (`collapsed_sides`) or where Su vanishes, along u on a collapsed side u = u0 or u1 or
        where Sv vanishes, else diagonally; each towards the nearer domain end's inside. With ``return_flags`` the (N,)
        bool array saying which points were degenerate is returned as well.
        """
        der = self.derivatives(u, v, order=1, side_u=side_u, side_v=side_v)
        su, sv = der[:, 1, 0], der[:, 0, 1]
        n = np.cross(su, sv)
        ln = np.linalg.norm(n, axis=1)
        lu = np.linalg.norm(su, axis=1)
        lv = np.linalg.norm(sv, axis=1)
        degenerate = ln <= 1e-10 * np.maximum(lu, lv) ** 2
        if np.any(degenerate):
            m = len(n)
            uu = np.broadcast_to(np.asarray(u, dtype=float).ravel(), (m,))[degenerate]
            vv = np.broadcast_to(np.asarray(v, dtype=float).ravel(), (m,))[degenerate]
            u0, u1, v0, v1 = self.domain
            sign_u = np.where(uu - u0 <= u1 - uu, 1.0, -1.0)  # moving into the domain along u
            sign_v = np.where(vv - v0 <= v1 - vv, 1.0, -1.0)
            lu_d, lv_d = lu[degenerate], lv[degenerate]
            # the iso-line v = const through the point collapses (on a collapsed side v = v0 or
            # v1, or Su vanishes): approach along v; u = const likewise; else diagonally
            cu0, cu1, cv0, cv1 = self.collapsed_sides()
            on_u = (cu0 & (uu == u0)) | (cu1 & (uu == u1))
            on_v = (cv0 & (vv == v0)) | (cv1 & (vv == v1))
            along_v = on_v | (~on_u & (lu_d <= 1e-6 * lv_d))
            along_u = on_u | (~on_v & (lv_d <= 1e-6 * lu_d))
            along_u &= ~along_v
            du = np.where(along_v, 0.0, sign_u)
            dv = np.where(along_u, 0.0, sign_v)
            sides = [None if s_ is None else np.broadcast_to(np.asarray(s_), (m,))[degenerate]
                     for s_ in (side_u, side_v)]
            n[degenerate] = self.limit_normal(uu, vv, du, dv, side_u=sides[0], side_v=sides[1])
            ln = np.linalg.norm(n, axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            n = n / ln[:, None]
        return (n, degenerate) if return_flags else n

    LIMIT_ORDER = 3
    """Highest order k of the Taylor terms of Su x Sv that `limit_normal` looks at."""

    def limit_normal(self, u, v, du, dv, side_u=None, side_v=None) -> np.ndarray:
        """Unit normal at (u, v) approached along the parameter direction (du, dv), (N,) each
        -> (N, 3), from the analytic derivatives (no step off the point).

        Along the ray (u + t du, v + t dv), t -> 0+, Su x Sv = sum_k t^k / k! f_k with
        f_k = sum_j C(k, j) D^j Su x D^(k-j) Sv, D = du d/du + dv d/dv; the normal is the
        direction of the first f_k that does not vanish (|f_k| > 1e-10 of its terms' scale,
        sum_j C(k, j) max(|D^j Su|, |D^(k-j) Sv|)^2), k = 0 .. `LIMIT_ORDER`. At a regular
        point that is f_0 = Su x Sv; on a collapsed edge v = v0 (Su = 0 for every u) with du =
        0, dv = 1 it is Suv x Sv, the normal along the generatrix u (a cone apex: one per u;
        a sphere pole: the axis for every u); where Sv vanishes there too (a profile leaving
        the axis with zero speed) it is a higher term, e.g. Suvv x Svv. Points where every
        term vanishes (no normal in any order up to `LIMIT_ORDER`) get the normal a step of
        1e-7 of the domain along the ray: a last resort, never met on the samples.
        """
        u = np.atleast_1d(np.asarray(u, dtype=float)).ravel()
        v = np.atleast_1d(np.asarray(v, dtype=float)).ravel()
        m = len(u)
        du = np.broadcast_to(np.asarray(du, dtype=float).ravel(), (m,))
        dv = np.broadcast_to(np.asarray(dv, dtype=float).ravel(), (m,))
        kmax = self.LIMIT_ORDER
        der = self.derivatives(u, v, order=kmax + 1, side_u=side_u, side_v=side_v)  # (N, K+2, K+2, 3)

        def directional(a: int, b: int, j: int) -> np.ndarray:
            """D^j of S_(a, b), (N, 3): sum_i C(j, i) du^i dv^(j-i) S_(a+i, b+j-i)."""
            out = np.zeros((m, 3))
            for i in range(j + 1):
                out += (comb(j, i) * du ** i * dv ** (j - i))[:, None] * der[:, a + i, b + j - i]
            return out

        dsu = [directional(1, 0, j) for j in range(kmax + 1)]
        dsv = [directional(0, 1, j) for j in range(kmax + 1)]
        n = np.zeros((m, 3))
        todo = np.ones(m, dtype=bool)
        for k in range(kmax + 1):
            f = np.zeros((m, 3))
            scale = np.zeros(m)
            for j in range(k + 1):
                f += comb(k, j) * np.cross(dsu[j], dsv[k - j])
                scale += comb(k, j) * np.maximum(np.linalg.norm(dsu[j], axis=1), np.linalg.norm(dsv[k - j], axis=1)) ** 2
            found = todo & (np.linalg.norm(f, axis=1) > 1e-10 * scale)
            n[found] = f[found]
            todo &= ~found
            if not np.any(todo):
                break
        if np.any(todo):  # every term up to LIMIT_ORDER vanishes: the normal just along the ray
            u0, u1, v0, v1 = self.domain
            d = self.derivatives(u[todo] + 1e-7 * (u1 - u0) * du[todo], v[todo] + 1e-7 * (v1 - v0) * dv[todo], order=1)
            n[todo] = np.cross(d[:, 1, 0], d[:, 0, 1])
        with np.errstate(invalid="ignore", divide="ignore"):
            return n / np.linalg.norm(n, axis=1)[:, None]

    def limit_tangent(self, u, v, du, dv) -> np.ndarray:
        """Unit tangent (N, 3) of the curve t -> S(u + t du, v + t dv) at t = 0+ ((N,) each), from
        the analytic derivatives: the first non-vanishing D^k S, k = 1 .. `LIMIT_ORDER` + 1
        (|D^k S| > 1e-10 of the largest term of its sum), D = du d/du + dv d/dv. Where the
        iso-line leaves a collapsed edge (a cone's generatrix at the apex) it is the
        direction the surface leaves the point in; NaN where every term vanishes."""
        u = np.atleast_1d(np.asarray(u, dtype=float)).ravel()
        v = np.atleast_1d(np.asarray(v, dtype=float)).ravel()
        m = len(u)
        du = np.broadcast_to(np.asarray(du, dtype=float).ravel(), (m,))
        dv = np.broadcast_to(np.asarray(dv, dtype=float).ravel(), (m,))
        kmax = self.LIMIT_ORDER + 1
        der = self.derivatives(u, v, order=kmax)
        t = np.full((m, 3), np.nan)
        todo = np.ones(m, dtype=bool)
        for k in range(1, kmax + 1):
            terms = [(comb(k, i) * du ** i * dv ** (k - i))[:, None] * der[:, i, k - i] for i in range(k + 1)]
            f = np.sum(terms, axis=0)
            scale = np.max([np.linalg.norm(x, axis=1) for x in terms], axis=0)
            found = todo & (np.linalg.norm(f, axis=1) > 1e-10 * scale)
            t[found] = f[found]
            todo &= ~found
            if not np.any(todo):
                break
        return t / np.linalg.norm(t, axis=1)[:, None]

    def collapsed_sides(self) -> tuple[bool, bool, bool, bool]:
        """Which sides of the domain, u = u0, u = u1, v = v0, v = v1, collapse onto one point
        (a pole or a cone apex: a degenerated edge): 17 points of the side within 1e-10 x
        the control net's size of each other. Cached (the surface is immutable)."""
        hit = self.__dict__.get("_collapsed")
        if hit is None:
            u0, u1, v0, v1 = self.domain
            t = np.linspace(0.0, 1.0, 17)
            uu, vv = u0 + (u1 - u0) * t, v0 + (v1 - v0) * t
            pts = self.evaluate(np.concatenate([np.full(17, u0), np.full(17, u1), uu, uu]),
                                np.concatenate([vv, vv, np.full(17, v0), np.full(17, v1)])).reshape(4, 17, 3)
            b = self.bbox()
            size = float(np.linalg.norm(b[1] - b[0]))
            spread = np.linalg.norm(pts - pts[:, :1], axis=2).max(axis=1)
            hit = tuple(bool(x) for x in spread <= 1e-10 * size)
            self.__dict__["_collapsed"] = hit
        return hit

    def closed_directions(self) -> tuple[bool, bool]:
        """Whether the surface closes on itself across u (S(u0, v) = S(u1, v)) and across v
        (S(u, v0) = S(u, v1)): a seam. 17 points along the sides within 1e-10 x the control
        net's size; a collapsed side (`collapsed_sides`) alone does not close. Cached."""
        hit = self.__dict__.get("_closed")
        if hit is None:
            u0, u1, v0, v1 = self.domain
            t = np.linspace(0.0, 1.0, 17)
            uu, vv = u0 + (u1 - u0) * t, v0 + (v1 - v0) * t
            b = self.bbox()
            tol = 1e-10 * float(np.linalg.norm(b[1] - b[0]))
            gap_u = self.evaluate(np.full(17, u0), vv) - self.evaluate(np.full(17, u1), vv)
            gap_v = self.evaluate(uu, np.full(17, v0)) - self.evaluate(uu, np.full(17, v1))
            cs = self.collapsed_sides()
            hit = (bool(np.linalg.norm(gap_u, axis=1).max() <= tol) and not (cs[0] and cs[1]),
                   bool(np.linalg.norm(gap_v, axis=1).max() <= tol) and not (cs[2] and cs[3]))
            self.__dict__["_closed"] = hit
        return hit

    def crease_knots(self, angle: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
        """Interior knots across which the surface normal jumps (a crease inside the face).

        Candidates are knots of multiplicity >= degree inside the domain (where the surface
        may be only C0); a candidate is kept when the normals on its two sides
        (`knot_jump`) at 17 points along its knot line differ by more than ``angle`` radians. A rational circle's double
        knots (C0 parametrisation, smooth geometry) are not creases. Returns (knots_u,
        knots_v) sorted arrays; cached (the surface is immutable).
        """
        cache = self.__dict__.setdefault("_crease_cache", {})
        if angle not in cache:
            u0, u1, v0, v1 = self.domain
            t = np.linspace(0.0, 1.0, 17)
            out = []
            for knots, p, lo, hi, other in ((self.knots_u, self.degree_u, u0, u1, v0 + (v1 - v0) * t),
                                            (self.knots_v, self.degree_v, v0, v1, u0 + (u1 - u0) * t)):
                k, counts = np.unique(knots, return_counts=True)
                keep = []
                for kk in k[(counts >= p) & (k > lo) & (k < hi)]:
                    jump = self.knot_jump("u" if knots is self.knots_u else "v", float(kk), other)
                    if np.any(jump > angle):  # NaN (no normal on either side: a degenerate line) is no crease
                        keep.append(kk)
                out.append(np.array(keep, dtype=float))
            cache[angle] = (out[0], out[1])
        return cache[angle]

    def knot_jump(self, direction: str, knot: float, t) -> np.ndarray:
        """Angle (radians) between the normals on the two sides of the knot line
        ``direction`` = ``knot`` ("u": the line u = knot, at v = t; "v": v = knot, at u = t),
        (M,) for (M,) ``t``.

        The smaller of two estimates: the one-sided normals at the knot (side_u / side_v),
        and the normals just off it (1e-6 of the neighbouring knot spans). A crease shows in
        both; a side whose derivative across the knot vanishes there (a sliver span of OCC's
        NURBS fillets, whose one-sided normal at the knot is 180 degrees off on the
        production die) only in the first."""
        t = np.asarray(t, dtype=float)
        at = np.full(len(t), knot)
        one = np.ones(len(t))
        ku = direction == "u"
        knots = np.unique(self.knots_u if ku else self.knots_v)
        i = int(np.searchsorted(knots, knot))
        lo = knot - 1e-6 * (knot - knots[max(i - 1, 0)])
        hi = knot + 1e-6 * (knots[min(i + 1, len(knots) - 1)] - knot)
        if ku:
            n1, n2 = self.normal(at, t, side_u=-one), self.normal(at, t, side_u=one)
            m1, m2 = self.normal(np.full(len(t), lo), t), self.normal(np.full(len(t), hi), t)
        else:
            n1, n2 = self.normal(t, at, side_v=-one), self.normal(t, at, side_v=one)
            m1, m2 = self.normal(t, np.full(len(t), lo)), self.normal(t, np.full(len(t), hi))
        a = np.arccos(np.clip(np.einsum("ij,ij->i", n1, n2), -1.0, 1.0))
        b = np.arccos(np.clip(np.einsum("ij,ij->i", m1, m2), -1.0, 1.0))
        return np.minimum(a, b)

    # ------------------------------------------------------------------ geometry helpers
    def bbox(self) -> np.ndarray:
        """Axis-aligned box, (2, 3) [min, max], of the control net: contains the surface (convex
        hull property, weights > 0). `cadbridge.nurbs.edits.tight_bbox` gives a tighter one."""
        pts = self.control_points.reshape(-1, 3)
        return np.array([pts.min(axis=0), pts.max(axis=0)])

    def grid(self, nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
        """Parameters of a uniform nu x nv grid over the domain, each (nu*nv,) (u fastest)."""
        u0, u1, v0, v1 = self.domain
        uu, vv = np.meshgrid(np.linspace(u0, u1, nu), np.linspace(v0, v1, nv), indexing="xy")
        return uu.ravel(), vv.ravel()

    def transformed(self, rotation, translation) -> "NurbsSurface":
        """The surface under x -> R x + t (exact: affine maps act on control points)."""
        r = np.asarray(rotation, dtype=float).reshape(3, 3)
        t = np.asarray(translation, dtype=float).reshape(3)
        cp = self.control_points @ r.T + t
        return NurbsSurface(
            self.degree_u, self.degree_v, self.knots_u, self.knots_v, cp, self.weights, self.domain
        )

    def with_domain(self, domain) -> "NurbsSurface":
        """The same surface restricted to another parameter range."""
        return NurbsSurface(
            self.degree_u, self.degree_v, self.knots_u, self.knots_v, self.control_points, self.weights, domain
        )
