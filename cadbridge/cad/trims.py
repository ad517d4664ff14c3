"""Model-level trim geometry: where a face's trim loops are, decided on the exact curves.

`LoopBoundary`: a polygon of one loop with a bound on each edge's chord error and a grid
index of its edges; `loop_contains`: inside/outside of one loop on the exact curves.
`trim_contains`: the closed trimmed region (outer loop and holes) of a face.
`project_to_trims`: nearest point of a face's trim loops (followed on the surface) to 3D points.

Decision rule (why lenses, not nearest points): the polygon's vertices lie on the exact
curves, so the region of the exact loop differs from the polygon's region only inside the
"lenses" between each edge (chord) and its arc. By the even-odd rule, inside(exact) =
inside(polygon) XOR (number of lenses containing the point, mod 2): exact for any loop, with
no special case at junctions of two pieces or at corners (a junction is a polygon vertex, on
both pieces). Each edge is refined until its arc is a graph over its chord (the tangent
keeps a positive component along the chord), so "is p in this lens" is one monotone 1D root
find on the exact curve (s(t) = s_p along the chord) and a comparison of normal offsets. A
point is in a lens only if it lies within that edge's chord bound, so the polygon (grid
index) decides every other point. A point within ``tol`` of an exact arc is ON (inside).

Curves are used through ``.domain``, ``.degree``, ``.knots``, ``.evaluate``,
``.derivatives`` and ``.sample_parameters`` only; a `NurbsCurve` additionally gets the
rigorous convex-hull chord bound from the Bezier net of each edge's piece.
"""

from __future__ import annotations

from functools import lru_cache
from math import comb

import numba
import numpy as np
from scipy.spatial import cKDTree

from cadbridge.nurbs.basis import ders_basis_one, find_span_one
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.newton import ders2_one, ders2_scratch

__all__ = ["LoopBoundary", "curve_ders", "loop_contains", "polygon_contains", "polygon_distance", "project_to_trims",
           "segment_distance", "trim_contains"]

_START_PER_SPAN = 8  # polygon edges per knot span before refinement
_MAX_ROUNDS = 24  # halvings of an edge at most (2^-24 of a span)
_BAND_TARGET = 2e-4  # chord bound aimed at, x loop size (smaller bands -> fewer exact checks)
_EDGE_TARGET = 1.0 / 32  # longest edge, x loop size (keeps grid cells near 1 edge each)
_GENERIC_SAFETY = 2.0  # factor on the sampled chord estimate of curves without a control net


# ---------------------------------------------------------------------------------------
# curve derivatives (compiled for NURBS curves: the trim loops' Newton steps call them often)
#
# One type per kernel argument, so that each kernel compiles once (the first run's compile
# time, `cadbridge.common.jit`): curve nets, knots and maps enter read-only (NurbsCurve's
# arrays are; the packs below are frozen likewise), and a constant passed from one kernel to
# another is written np.int64(k) / np.bool_(b) (a bare literal is typed Literal[int](k) by
# numba and compiles the callee once more per value).


def _frozen(a: np.ndarray) -> np.ndarray:
    """``a`` (a fresh array owned by the caller) made read-only, as the curves' own arrays."""
    a.setflags(write=False)
    return a


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _curve_ders_one(pw, knots, p, rational, x, d, ndu, left, right, a, nd, aw, out):  # pragma: no cover - compiled
    """`NurbsCurve.derivatives` at one parameter x into out (d+1, dim): A2.1 / A2.3
    (`find_span_one`, `ders_basis_one`), the homogeneous sums, then the quotient rule of P&T
    A4.2. pw (n, dim+1) homogeneous net; scratch ndu (p+1, p+1), left/right (p+1,),
    a (2, p+1), nd (d+1, p+1), aw (d+1, dim+1)."""
    n_ctrl = pw.shape[0]
    dim = pw.shape[1] - 1
    span = find_span_one(knots, p, n_ctrl, x)
    ders_basis_one(span, x, p, knots, d, ndu, left, right, a, nd)
    for k in range(d + 1):
        for c in range(dim + 1):
            acc = 0.0
            for j in range(p + 1):
                acc += nd[k, j] * pw[span - p + j, c]
            aw[k, c] = acc
    if not rational:
        for k in range(d + 1):
            for c in range(dim):
                out[k, c] = aw[k, c]
        return
    w0 = aw[0, dim]
    for k in range(d + 1):
        for c in range(dim):
            val = aw[k, c]
            b = 1.0  # binomial C(k, j)
            for j in range(1, k + 1):
                b = b * (k - j + 1) / j
                val -= b * aw[j, dim] * out[k - j, c]
            out[k, c] = val / w0


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _curve_ders_kernel(pw, knots, p, rational, t, d, out):  # pragma: no cover - compiled
    """`_curve_ders_one` for every t (N,) into out (N, d+1, dim)."""
    dim = pw.shape[1] - 1
    ndu = np.empty((p + 1, p + 1))
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    a = np.empty((2, p + 1))
    nd = np.empty((d + 1, p + 1))
    aw = np.empty((d + 1, dim + 1))
    for i in range(t.shape[0]):
        _curve_ders_one(pw, knots, p, rational, t[i], d, ndu, left, right, a, nd, aw, out[i])


MAP_LEN = 29  # floats of an exact trim-curve map in the kernels' form (`MappedCurve.packed_map`)
_NO_MAP = np.zeros(MAP_LEN)  # a NURBS curve's own (u, v): no map
_NO_MAP.setflags(write=False)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _arc_map_one(x, start_in, sweep, start_out, n):  # pragma: no cover - compiled
    """`cadbridge.cad.analytic.ArcMap` at one x: (f, f', f''), the same steps (n: its
    `arc_segments`)."""
    two_pi = 2.0 * np.pi
    d = sweep / n
    r = x - start_in
    wrapped = r - two_pi * np.rint((r - 0.5 * sweep) / two_pi)
    turn_tol = 1e-9 * max(abs(sweep), 1.0)
    if (r < -turn_tol or r > sweep + turn_tol) and wrapped >= -turn_tol and wrapped <= sweep + turn_tol:
        r = wrapped
    a = min(max(r, 0.0), sweep)
    k = min(max(np.floor(a / d), 0.0), n - 1.0)
    tt = np.tan((a - k * d - d / 2) / 2)
    q = 1.0 / np.tan(d / 4)
    f0 = start_out + (k + 0.5 * (1.0 + tt * q)) * d
    tol = 1e-12 * max(abs(sweep), 1.0)
    f1 = 0.25 * d * q * (1.0 + tt * tt) if (r >= -tol and r <= sweep + tol) else 0.0
    return f0, f1, f1 * tt


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _chain_one(mp, o, v0, v1, v2):  # pragma: no cover - compiled
    """A scalar map mp[o:o+5] = (flag, start_in, sweep, start_out, segments) applied to a value
    and its first two derivatives (Faa di Bruno; flag 0: the identity)."""
    if mp[o] == 0.0:
        return v0, v1, v2
    f0, f1, f2 = _arc_map_one(v0, mp[o + 1], mp[o + 2], mp[o + 3], mp[o + 4])
    return f0, f1 * v1, f2 * (v1 * v1) + f1 * v2


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _tcurve_ders_one(pw, knots, p, rational, mp, x, d, ndu, left, right, a, nd, aw, out):  # pragma: no cover - compiled
    """`_curve_ders_one` of a trim curve: a 2D NURBS curve, through the exact map ``mp`` of
    `MappedCurve` when mp[0] != 0 (y = M c + b, natural n_k = pre_k(y_k), uv_j = post_j(n_src_j),
    derivatives by the chain rule: the steps of `MappedCurve.derivatives`). out (d+1, 2)."""
    _curve_ders_one(pw, knots, p, rational, x, d, ndu, left, right, a, nd, aw, out)
    if mp[0] == 0.0:
        return
    y00 = out[0, 0] * mp[1] + out[0, 1] * mp[2] + mp[5]
    y01 = out[0, 0] * mp[3] + out[0, 1] * mp[4] + mp[6]
    y10 = y11 = y20 = y21 = 0.0
    if d >= 1:
        y10 = out[1, 0] * mp[1] + out[1, 1] * mp[2]
        y11 = out[1, 0] * mp[3] + out[1, 1] * mp[4]
    if d >= 2:
        y20 = out[2, 0] * mp[1] + out[2, 1] * mp[2]
        y21 = out[2, 0] * mp[3] + out[2, 1] * mp[4]
    n00, n10, n20 = _chain_one(mp, np.int64(7), y00, y10, y20)
    n01, n11, n21 = _chain_one(mp, np.int64(12), y01, y11, y21)
    for j in range(2):
        o = 17 + 6 * j
        if mp[o] == 0.0:
            g0, g1, g2 = _chain_one(mp, o + 1, n00, n10, n20)
        else:
            g0, g1, g2 = _chain_one(mp, o + 1, n01, n11, n21)
        out[0, j] = g0
        if d >= 1:
            out[1, j] = g1
        if d >= 2:
            out[2, j] = g2


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _mapped_ders_kernel(pw, knots, p, rational, mp, t, d, out):  # pragma: no cover - compiled
    """`_tcurve_ders_one` for every t (N,) into out (N, d+1, 2)."""
    ndu = np.empty((p + 1, p + 1))
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    a = np.empty((2, p + 1))
    nd = np.empty((d + 1, p + 1))
    aw = np.empty((d + 1, pw.shape[1]))
    for i in range(t.shape[0]):
        _tcurve_ders_one(pw, knots, p, rational, mp, t[i], d, ndu, left, right, a, nd, aw, out[i])


def _kernel_form(c):
    """(control net pw, knots, degree, rational, map (MAP_LEN,)) of a trim curve for the compiled
    kernels: a 2D `NurbsCurve` as it is, an exactly mapped curve (``packed_map``, e.g. the
    analytic surfaces' `MappedCurve`) as its 2D base curve and its map; None for others."""
    if isinstance(c, NurbsCurve):
        return c._pw, c.knots, c.degree, c.rational, _NO_MAP
    hit = getattr(c, "__dict__", {}).get("_kernel_form")
    if hit is not None:
        return hit
    base, pm = getattr(c, "base", None), getattr(c, "packed_map", None)
    if pm is None or not isinstance(base, NurbsCurve) or base.dim != 2:
        return None
    form = (base._pw, base.knots, base.degree, base.rational, _frozen(np.array(pm(), dtype=float)))
    c.__dict__["_kernel_form"] = form
    return form


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _trim_newton_one(spw, sku, skv, p, q, srat, u0, u1, v0, v1, cpw, cknots, cdeg, crat, cmap, t0, t1, closed, px, py,
                     pz, ti, eps1, max_iter, scratch, der, cndu, cl, cr, ca, cnd, caw, cd):  # pragma: no cover - compiled
    """The Newton iterations of `project_to_trims` for one point (px, py, pz) on one trim curve
    from ti: f(t) = (C - P).C', C = S(c(t)), f' = C'.C' + (C - P).C'' (C'.C' where f' <= 0),
    t wrapped (closed curve) or clamped, until a step moves C by at most eps1. Returns t."""
    for _ in range(max_iter):
        _tcurve_ders_one(cpw, cknots, cdeg, crat, cmap, ti, np.int64(2), cndu, cl, cr, ca, cnd, caw, cd)
        uu = min(max(cd[0, 0], u0), u1)
        vv = min(max(cd[0, 1], v0), v1)
        ders2_one(spw, sku, skv, p, q, srat, uu, vv, scratch, der)
        up, vp, upp, vpp = cd[1, 0], cd[1, 1], cd[2, 0], cd[2, 1]
        f = 0.0
        c11 = 0.0
        rc2 = 0.0
        for k in range(3):
            c1k = der[1, 0, k] * up + der[0, 1, k] * vp
            c2k = (der[2, 0, k] * (up * up) + 2.0 * der[1, 1, k] * (up * vp) + der[0, 2, k] * (vp * vp)
                   + der[1, 0, k] * upp + der[0, 1, k] * vpp)
            r = der[0, 0, k] - (px if k == 0 else py if k == 1 else pz)
            f += r * c1k
            c11 += c1k * c1k
            rc2 += r * c2k
        fp = c11 + rc2
        if not fp > 0:
            fp = c11 + 1e-300
        tn = ti - f / fp
        if closed:
            tn = t0 + (tn - t0) % (t1 - t0)
        else:
            tn = min(max(tn, t0), t1)
        step = abs(tn - ti) * np.sqrt(c11)
        ti = tn
        if step <= eps1:
            break
    return ti


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _trim_newton_kernel(spw, sku, skv, p, q, srat, u0, u1, v0, v1, cpw, cknots, cdeg, crat, cmap, t0, t1, closed,
                        pts, t, eps1, max_iter):  # pragma: no cover - compiled
    """`_trim_newton_one` for every point pts (N, 3) on one trim curve; updates t (N,) in place."""
    scratch = ders2_scratch(p, q)
    der = np.empty((3, 3, 3))
    cndu = np.empty((cdeg + 1, cdeg + 1))
    cl = np.empty(cdeg + 1)
    cr = np.empty(cdeg + 1)
    ca = np.empty((2, cdeg + 1))
    cnd = np.empty((3, cdeg + 1))
    caw = np.empty((3, cpw.shape[1]))
    cd = np.empty((3, max(cpw.shape[1] - 1, 2)))
    for i in range(pts.shape[0]):
        t[i] = _trim_newton_one(spw, sku, skv, p, q, srat, u0, u1, v0, v1, cpw, cknots, cdeg, crat, cmap, t0, t1,
                                closed, pts[i, 0], pts[i, 1], pts[i, 2], t[i], eps1, max_iter, scratch, der, cndu, cl,
                                cr, ca, cnd, caw, cd)


def curve_ders(c, t, order: int) -> np.ndarray:
    """d^k c / dt^k for k <= order at t (N,): (N, order+1, dim); compiled for a `NurbsCurve`,
    its own ``derivatives`` for other curves (e.g. exactly mapped analytic trims)."""
    if not isinstance(c, NurbsCurve):
        form = _kernel_form(c) if order <= 2 else None
        if form is None:
            return c.derivatives(t, order)
        t = np.ascontiguousarray(np.atleast_1d(np.asarray(t, dtype=float)).ravel())
        out = np.empty((t.size, order + 1, 2))
        if t.size:
            _mapped_ders_kernel(*form[:4], form[4], t, int(order), out)
        return out
    t = np.ascontiguousarray(np.atleast_1d(np.asarray(t, dtype=float)).ravel())
    out = np.empty((t.size, order + 1, c.dim))
    if t.size:
        _curve_ders_kernel(c._pw, c.knots, c.degree, c.rational, t, int(order), out)
    return out


# ---------------------------------------------------------------------------------------
# chord bounds of polygon edges


def segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance of points p (..., 2) to segments [a, b] (broadcast to p's shape), (...)."""
    ab = b - a
    ll = np.einsum("...j,...j->...", ab, ab)
    t = np.einsum("...j,...j->...", p - a, ab) / np.where(ll > 0, ll, 1.0)
    t = np.clip(np.where(ll > 0, t, 0.0), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


@lru_cache(maxsize=64)
def _taylor_to_bernstein(p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """j = 0..p, j! and the matrix C(k, j) / C(p, j) (j <= k) of `_bezier_bounds` (cached)."""
    j = np.arange(p + 1)
    fact = np.array([float(np.prod(np.arange(1, k + 1))) for k in j])
    tm = np.array([[comb(k, i) / comb(p, i) if i <= k else 0.0 for i in j] for k in j])
    for a in (j, fact, tm):
        a.setflags(write=False)
    return j, fact, tm


def _bezier_bounds(c: NurbsCurve, ta: np.ndarray, tb: np.ndarray, pa: np.ndarray, pb: np.ndarray):
    """Rigorous chord bound and graph test of the pieces [ta, tb] (M,) of a NURBS curve with
    chords pa -> pb (M, 2). The Bezier net of each piece comes from the homogeneous
    derivatives at ta (monomial -> Bernstein): b_k = sum_{j<=k} C(k,j)/C(p,j) h^j Cw^(j)(ta)/j!.
    The piece lies in the convex hull of its net (weights > 0), so max_k dist(P_k, chord)
    bounds its distance from the chord; C' is a non-negative combination of P_i - P_j (i > j)
    (B_i/B_j increases for i > j), so (P_{k+1} - P_k).chord >= 0 for all k makes the
    position along the chord non-decreasing in t. Returns band (M,), graph (M,) bool."""
    p = c.degree
    if p == 1:  # a (rational) linear piece is its chord
        return np.zeros(len(ta)), np.ones(len(ta), dtype=bool)
    hom = _homogeneous_xyw(c)
    j, fact, tm = _taylor_to_bernstein(p)
    m = len(ta)
    band, graph = np.empty(m), np.empty(m, dtype=np.bool_)
    if m:
        _bezier_bounds_kernel(hom._pw, hom.knots, p, np.ascontiguousarray(ta, dtype=float),
                              np.ascontiguousarray(tb, dtype=float), np.ascontiguousarray(pa, dtype=float),
                              np.ascontiguousarray(pb, dtype=float), fact, tm, band, graph)
    return band, graph


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _bezier_bounds_kernel(hpw, knots, p, ta, tb, pa, pb, fact, tm, band, graph):  # pragma: no cover - compiled
    """`_bezier_bounds` piece by piece (its docstring): the homogeneous derivatives at ta (hpw
    (n, 4): the (x w, y w, w) net as a non-rational curve), the Bezier net, band and graph."""
    ndu = np.empty((p + 1, p + 1))
    left = np.empty(p + 1)
    right = np.empty(p + 1)
    a = np.empty((2, p + 1))
    nd = np.empty((p + 1, p + 1))
    aw = np.empty((p + 1, 4))
    d = np.empty((p + 1, 3))
    h = np.empty(p + 1)
    net = np.empty((p + 1, 2))
    for i in range(ta.shape[0]):
        _curve_ders_one(hpw, knots, p, np.bool_(False), ta[i], p, ndu, left, right, a, nd, aw, d)
        dt = tb[i] - ta[i]
        for k in range(p + 1):
            h[k] = dt ** k / fact[k]
        good = True
        for k in range(p + 1):
            bx = 0.0
            by = 0.0
            bw = 0.0
            for m in range(k + 1):
                c = tm[k, m] * h[m]
                bx += c * d[m, 0]
                by += c * d[m, 1]
                bw += c * d[m, 2]
            if not bw > 0:
                good = False
                bw = 1.0
            net[k, 0] = bx / bw
            net[k, 1] = by / bw
        ax, ay, bx_, by_ = pa[i, 0], pa[i, 1], pb[i, 0], pb[i, 1]
        cx, cy = bx_ - ax, by_ - ay
        lc = np.sqrt(cx * cx + cy * cy)
        bd = 0.0
        mono = True
        for k in range(p + 1):
            bd = max(bd, _seg_dist(net[k, 0], net[k, 1], ax, ay, bx_, by_))
            if k < p:
                ex, ey = net[k + 1, 0] - net[k, 0], net[k + 1, 1] - net[k, 1]
                if ex * cx + ey * cy < -1e-13 * np.sqrt(ex * ex + ey * ey) * lc:
                    mono = False
        band[i] = bd if good else np.inf
        graph[i] = good and mono


def _sampled_bounds(c, ta: np.ndarray, tb: np.ndarray, pa: np.ndarray, pb: np.ndarray):
    """Chord bound and graph test of curves without a control net (e.g. mapped curves):
    _GENERIC_SAFETY x max(sampled deviation from the chord, h^2/8 max|C''|) over 7 samples
    per edge, tangent direction tested at the same samples. An estimate, not a proof: it
    holds where C'' varies by less than the safety factor within one edge, which the
    refinement (edges of at most a few 1e-4 of the loop size) makes the usual case."""
    s = np.linspace(0.0, 1.0, 7)
    t = (ta[:, None] + (tb - ta)[:, None] * s).ravel()
    d = curve_ders(c, t, 2)[:, :, :2].reshape(len(ta), len(s), 3, 2)
    dev = np.max(segment_distance(d[:, :, 0], pa[:, None], pb[:, None]), axis=1)
    curv = np.max(np.linalg.norm(d[:, :, 2], axis=2), axis=1) * (tb - ta) ** 2 / 8.0
    chord = pb - pa
    graph = np.all(np.einsum("msj,mj->ms", d[:, :, 1], chord) >= 0, axis=1)
    return _GENERIC_SAFETY * np.maximum(dev, curv), graph


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _refine_kernel(cpw, knots, deg, rat, hpw, fact, tm, t, p, target, lmax, max_rounds):  # pragma: no cover - compiled
    """`LoopBoundary`'s refinement of one NURBS curve's polygon in one compiled call: the
    chord bounds of `_bezier_bounds_kernel` (degree 1: 0, graph), then up to ``max_rounds``
    halvings of the edges whose bound exceeds ``target``, that are not a graph over their chord
    or longer than ``lmax``; only the new points (`_curve_ders_kernel`) and edges are computed,
    the same values as `_halve_edges` round by round. t (M+1,), p (M+1, 2) the start polygon.
    Returns t, p, band, graph of the final polygon."""
    m = t.shape[0] - 1
    bd = np.zeros(m)
    gr = np.ones(m, dtype=np.bool_)
    if deg > 1 and m > 0:
        _bezier_bounds_kernel(hpw, knots, deg, t[:-1].copy(), t[1:].copy(), p[:-1].copy(), p[1:].copy(), fact, tm,
                              bd, gr)
    dim = cpw.shape[1] - 1
    for r in range(max_rounds + 1):
        bad = np.zeros(m, dtype=np.bool_)
        nb = 0
        for i in range(m):
            dx = p[i + 1, 0] - p[i, 0]
            dy = p[i + 1, 1] - p[i, 1]
            bad[i] = bd[i] > target or not gr[i] or np.sqrt(dx * dx + dy * dy) > lmax
            if bad[i]:
                nb += 1
        if r == max_rounds or nb == 0:
            break
        bi = np.empty(nb, dtype=np.int64)
        k = 0
        for i in range(m):
            if bad[i]:
                bi[k] = i
                k += 1
        tmid = np.empty(nb)
        for k in range(nb):
            tmid[k] = 0.5 * (t[bi[k]] + t[bi[k] + 1])
        out = np.empty((nb, 1, dim))
        _curve_ders_kernel(cpw, knots, deg, rat, tmid, np.int64(0), out)
        pm = np.empty((nb, 2))
        ta_l = np.empty(nb)
        tb_r = np.empty(nb)
        pa_l = np.empty((nb, 2))
        pb_r = np.empty((nb, 2))
        for k in range(nb):
            pm[k, 0], pm[k, 1] = out[k, 0, 0], out[k, 0, 1]
            ta_l[k], tb_r[k] = t[bi[k]], t[bi[k] + 1]
            pa_l[k, 0], pa_l[k, 1] = p[bi[k], 0], p[bi[k], 1]
            pb_r[k, 0], pb_r[k, 1] = p[bi[k] + 1, 0], p[bi[k] + 1, 1]
        bl = np.zeros(nb)
        gl = np.ones(nb, dtype=np.bool_)
        br = np.zeros(nb)
        grr = np.ones(nb, dtype=np.bool_)
        if deg > 1:
            _bezier_bounds_kernel(hpw, knots, deg, ta_l, tmid, pa_l, pm, fact, tm, bl, gl)
            _bezier_bounds_kernel(hpw, knots, deg, tmid, tb_r, pm, pb_r, fact, tm, br, grr)
        m2 = m + nb
        t2 = np.empty(m2 + 1)
        p2 = np.empty((m2 + 1, 2))
        bd2 = np.empty(m2)
        g2 = np.empty(m2, dtype=np.bool_)
        j = 0  # next new vertex / edge
        k = 0  # next halved edge
        for i in range(m):
            t2[j], p2[j, 0], p2[j, 1] = t[i], p[i, 0], p[i, 1]
            if bad[i]:
                bd2[j], g2[j] = bl[k], gl[k]
                j += 1
                t2[j], p2[j, 0], p2[j, 1] = tmid[k], pm[k, 0], pm[k, 1]
                bd2[j], g2[j] = br[k], grr[k]
                k += 1
            else:
                bd2[j], g2[j] = bd[i], gr[i]
            j += 1
        t2[j], p2[j, 0], p2[j, 1] = t[m], p[m, 0], p[m, 1]
        t, p, bd, gr, m = t2, p2, bd2, g2, m2
    return t, p, bd, gr


def _homogeneous_xyw(c: NurbsCurve) -> NurbsCurve:
    """The (x w, y w, w) curve of ``c`` as a non-rational curve (built once per curve)."""
    hom = c.__dict__.get("_trim_hom")
    if hom is None:
        pw = np.ascontiguousarray(c._pw[:, [0, 1, -1]])
        hom = c.__dict__["_trim_hom"] = NurbsCurve._trusted(c.degree, c.knots, pw, np.ones(len(pw)), c.domain, False)
    return hom


def _halve_edges(c, bounds, t: np.ndarray, p: np.ndarray, bd: np.ndarray, graph: np.ndarray, bad: np.ndarray):
    """Polygon of curve ``c`` with the edges ``bad`` (M,) halved at their parameter midpoint:
    parameters t (M+1,), vertices p (M+1, 2), chord bounds bd and graph flags (M,) of the new
    polygon (B more vertices and edges, in parameter order)."""
    bi = np.flatnonzero(bad)
    tm = 0.5 * (t[bi] + t[bi + 1])
    pm = np.asarray(curve_ders(c, tm, 0)[:, 0], dtype=float)[:, :2]
    bl, gl = bounds(c, t[bi], tm, p[bi], pm)
    br, gr = bounds(c, tm, t[bi + 1], pm, p[bi + 1])
    m = len(bd)
    # vertex i moves by the number of midpoints before it; midpoint of edge i follows vertex i
    shift = np.zeros(m + 1, dtype=np.int64)
    shift[1:] = np.cumsum(bad)
    vi = np.arange(m + 1) + shift
    mi = bi + shift[bi] + 1
    t2 = np.empty(m + 1 + len(bi))
    p2 = np.empty((len(t2), 2))
    t2[vi], t2[mi] = t, tm
    p2[vi], p2[mi] = p, pm
    # edge i (kept) starts at vertex i; a halved edge becomes (left, right) at mi - 1, mi
    ei = np.arange(m) + shift[:-1]
    bd2 = np.empty(len(t2) - 1)
    g2 = np.empty(len(t2) - 1, dtype=bool)
    keep = ~bad
    bd2[ei[keep]], g2[ei[keep]] = bd[keep], graph[keep]
    bd2[mi - 1], g2[mi - 1] = bl, gl
    bd2[mi], g2[mi] = br, gr
    return t2, p2, bd2, g2


# ---------------------------------------------------------------------------------------
# grid index of polygon edges (numba kernels)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _seg_dist(x, y, ax, ay, bx, by):
    dx = bx - ax
    dy = by - ay
    ll = dx * dx + dy * dy
    t = 0.0
    if ll > 0.0:
        t = ((x - ax) * dx + (y - ay) * dy) / ll
        t = min(1.0, max(0.0, t))
    ex = x - (ax + t * dx)
    ey = y - (ay + t * dy)
    return np.sqrt(ex * ex + ey * ey)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _grid_start(x, y, x0, y0, h, nx, ny, vstart, vcross):
    """Cell (ci, cj) of point (x, y) on the crossing grid, and the number of crossings of grid
    line X (the cell's right side) at or below y (binary search in the sorted vcross); ci = -1
    outside the grid."""
    ci = int(np.floor((x - x0) / h))
    cj = int(np.floor((y - y0) / h))
    if ci < 0 or ci >= nx or cj < 0 or cj >= ny:
        return -1, -1, 0
    lo = vstart[ci]
    hi = vstart[ci + 1]
    base = lo
    while lo < hi:
        mid = (lo + hi) // 2
        if vcross[mid] <= y:
            lo = mid + 1
        else:
            hi = mid
    return ci, cj, lo - base


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _classify_kernel(pu, pv, x0, y0, h, nx, ny, cstart, cedges, vstart, vcross, ax, ay, bx, by, band, tol,
                     parity, near):
    """Even-odd parity of each point against the polygon along the path p -> (X, v) -> (X, -inf)
    (X the right side of p's cell: edges of the cell for the first leg, the sorted crossings
    of grid line X for the second), and whether some edge k is within band[k] + tol."""
    for i in range(pu.size):
        x = pu[i]
        y = pv[i]
        ci, cj, cnt = _grid_start(x, y, x0, y0, h, nx, ny, vstart, vcross)
        if ci < 0:
            parity[i] = False
            near[i] = False
            continue
        xr = x0 + (ci + 1) * h
        xa = min(x, xr)
        xb = max(x, xr)
        nr = False
        cell = cj * nx + ci
        for q in range(cstart[cell], cstart[cell + 1]):
            k = cedges[q]
            y1 = ay[k]
            y2 = by[k]
            if (y1 > y) != (y2 > y):
                uc = ax[k] + (y - y1) * (bx[k] - ax[k]) / (y2 - y1)
                if uc > xa and uc <= xb:
                    cnt += 1
            if not nr:
                if _seg_dist(x, y, ax[k], ay[k], bx[k], by[k]) <= band[k] + tol:
                    nr = True
        parity[i] = (cnt % 2) == 1
        near[i] = nr


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _pairs_kernel(pu, pv, x0, y0, h, nx, ny, cstart, cedges, ax, ay, bx, by, band, tol, fill, out_p, out_k, out_d):
    """(point, edge) pairs with distance <= band + tol, counted (fill False, returns the
    count) or written into out_p, out_k, out_d (fill True)."""
    m = 0
    for i in range(pu.size):
        x = pu[i]
        y = pv[i]
        ci = int(np.floor((x - x0) / h))
        cj = int(np.floor((y - y0) / h))
        if ci < 0 or ci >= nx or cj < 0 or cj >= ny:
            continue
        cell = cj * nx + ci
        for q in range(cstart[cell], cstart[cell + 1]):
            k = cedges[q]
            d = _seg_dist(x, y, ax[k], ay[k], bx[k], by[k])
            if d <= band[k] + tol:
                if fill:
                    out_p[m] = i
                    out_k[m] = k
                    out_d[m] = d
                m += 1
    return m


class _EdgeGrid:
    """Uniform grid over polygon edges a -> b (M, 2): cell (i, j) lists the edges whose box,
    grown by band[k] + reach, meets it (CSR: cstart (nx*ny+1,), cedges); vstart (nx+1,),
    vcross hold, per vertical grid line X_i = x0 + (i+1) h, the sorted v where edges cross
    it. Cells ~ edges in number; build cost ~ M + crossings of grid lines (the size of the
    curves), queries ~ edges per cell. Points farther than band + reach from every edge
    fall outside the grid or in cells without those edges."""

    def __init__(self, a: np.ndarray, b: np.ndarray, band: np.ndarray, reach: float) -> None:
        grow = (band + reach)[:, None]
        lo = np.minimum(a, b) - grow
        hi = np.maximum(a, b) + grow
        glo, ghi = lo.min(axis=0), hi.max(axis=0)
        w, ht = ghi - glo
        m = len(a)
        h = float(np.sqrt(w * ht / m)) if w * ht > 0 else max(w, ht) / m
        h = max(h, max(w, ht) / 2048.0, 1e-300)
        self.h = h
        self.x0 = float(glo[0] - 0.3819660112501051 * h)  # irrational offset: grid lines off the
        self.y0 = float(glo[1] - 0.3819660112501051 * h)  # axis-parallel edges at the box sides
        self.nx = int(np.floor((ghi[0] - self.x0) / h)) + 1
        self.ny = int(np.floor((ghi[1] - self.y0) / h)) + 1
        nx, ny = self.nx, self.ny
        i0 = np.clip(np.floor((lo[:, 0] - self.x0) / h).astype(np.int64), 0, nx - 1)
        i1 = np.clip(np.floor((hi[:, 0] - self.x0) / h).astype(np.int64), 0, nx - 1)
        j0 = np.clip(np.floor((lo[:, 1] - self.y0) / h).astype(np.int64), 0, ny - 1)
        j1 = np.clip(np.floor((hi[:, 1] - self.y0) / h).astype(np.int64), 0, ny - 1)
        ni, nj = i1 - i0 + 1, j1 - j0 + 1
        cnt = ni * nj
        edge = np.repeat(np.arange(m), cnt)
        local = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        cell = (j0[edge] + local // ni[edge]) * nx + i0[edge] + local % ni[edge]
        order = np.argsort(cell, kind="stable")
        self.cedges = edge[order].astype(np.int64)
        self.cstart = np.concatenate([[0], np.cumsum(np.bincount(cell, minlength=nx * ny))]).astype(np.int64)
        # crossings of the vertical grid lines (same predicate as the kernel's half-open rule)
        umin, umax = np.minimum(a[:, 0], b[:, 0]), np.maximum(a[:, 0], b[:, 0])
        l0 = np.clip(np.floor((umin - self.x0) / h).astype(np.int64) - 1, 0, nx - 1)
        l1 = np.clip(np.floor((umax - self.x0) / h).astype(np.int64) + 1, 0, nx - 1)
        lc = l1 - l0 + 1
        e2 = np.repeat(np.arange(m), lc)
        line = l0[e2] + np.arange(int(lc.sum())) - np.repeat(np.cumsum(lc) - lc, lc)
        xl = self.x0 + (line + 1) * h
        ax, ay, bx, by = a[e2, 0], a[e2, 1], b[e2, 0], b[e2, 1]
        hit = (ax > xl) != (bx > xl)
        ax, ay, bx, by, xl, line = ax[hit], ay[hit], bx[hit], by[hit], xl[hit], line[hit]
        vc = ay + (xl - ax) * (by - ay) / (bx - ax)
        order = np.lexsort((vc, line))
        self.vcross = np.ascontiguousarray(vc[order])
        self.vstart = np.concatenate([[0], np.cumsum(np.bincount(line, minlength=nx))]).astype(np.int64)
        self.ax, self.ay = np.ascontiguousarray(a[:, 0]), np.ascontiguousarray(a[:, 1])
        self.bx, self.by = np.ascontiguousarray(b[:, 0]), np.ascontiguousarray(b[:, 1])
        self.band = np.ascontiguousarray(band, dtype=float)
        self.reach = reach

    def classify(self, uv: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
        """(parity (N,) bool: inside the polygon, near (N,) bool: within band + tol of an edge)."""
        if tol > self.reach:
            raise ValueError(f"tolerance {tol!r} beyond the reach {self.reach!r} the grid was built for")
        n = len(uv)
        parity = np.empty(n, dtype=bool)
        near = np.empty(n, dtype=bool)
        _classify_kernel(np.ascontiguousarray(uv[:, 0]), np.ascontiguousarray(uv[:, 1]), self.x0, self.y0, self.h,
                         self.nx, self.ny, self.cstart, self.cedges, self.vstart, self.vcross,
                         self.ax, self.ay, self.bx, self.by, self.band, float(tol), parity, near)
        return parity, near

    def pairs(self, uv: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(point index, edge index, distance to the edge) of every pair within band + tol."""
        pu, pv = np.ascontiguousarray(uv[:, 0]), np.ascontiguousarray(uv[:, 1])
        args = (pu, pv, self.x0, self.y0, self.h, self.nx, self.ny, self.cstart, self.cedges,
                self.ax, self.ay, self.bx, self.by, self.band, float(tol))
        z = np.zeros(0, dtype=np.int64)
        m = _pairs_kernel(*args, False, z, z, np.zeros(0))
        out_p, out_k, out_d = np.empty(m, dtype=np.int64), np.empty(m, dtype=np.int64), np.empty(m)
        _pairs_kernel(*args, True, out_p, out_k, out_d)
        return out_p, out_k, out_d


# ---------------------------------------------------------------------------------------
# one loop: polygon with chord bounds, grids, exact decision


class LoopBoundary:
    """Polygon of one closed trim loop (curves joined end to start) with chord bounds.

    a, b    (M, 2) edge ends in (u, v); vertices are exact curve points (knots included)
    band    (M,) bound on the distance of edge k's exact arc from its chord (0: straight)
    curve   (M,) index into ``curves`` of edge k, -1 for a gap edge closing two pieces that
            do not meet (its exact boundary is the chord itself)
    ta, tb  (M,) parameter interval of edge k on its curve
    size    diagonal of the polygon's box (parameter units)
    Edges are halved until band <= 2e-4 x size, length <= size / 32, and the arc is a graph
    over its chord. Build cost ~ the number of edges (the size of the curves).
    """

    def __init__(self, curves) -> None:
        self.curves = list(curves)
        if not self.curves:
            raise ValueError("LoopBoundary: a trim loop needs at least one curve")
        ts = [np.asarray(c.sample_parameters(_START_PER_SPAN), dtype=float) for c in self.curves]
        ps = [np.asarray(curve_ders(c, t, 0)[:, 0], dtype=float)[:, :2] for c, t in zip(self.curves, ts)]
        allp = np.concatenate(ps)
        if not np.all(np.isfinite(allp)):
            raise ValueError("LoopBoundary: a trim curve evaluates to non-finite (u, v)")
        self.size = float(np.linalg.norm(allp.max(axis=0) - allp.min(axis=0))) or 1.0
        target, lmax = _BAND_TARGET * self.size, _EDGE_TARGET * self.size
        a, b, band, cid, ta, tb = [], [], [], [], [], []
        for k, c in enumerate(self.curves):
            t, p = ts[k], ps[k]
            if isinstance(c, NurbsCurve):  # the whole refinement compiled (same steps)
                fact, tmat = _taylor_to_bernstein(c.degree)[1:]
                t, p, bd, graph = _refine_kernel(c._pw, c.knots, c.degree, c.rational, _homogeneous_xyw(c)._pw,
                                                 fact, tmat, np.ascontiguousarray(t), np.ascontiguousarray(p),
                                                 float(target), float(lmax), _MAX_ROUNDS)
            else:  # exactly mapped curves: the same rounds in numpy (no control net to compile)
                bd, graph = _sampled_bounds(c, t[:-1], t[1:], p[:-1], p[1:])
                for r in range(_MAX_ROUNDS + 1):
                    long = np.linalg.norm(p[1:] - p[:-1], axis=1) > lmax
                    bad = (bd > target) | ~graph | long
                    if r == _MAX_ROUNDS or not bad.any():
                        break
                    # halve the bad edges: only the new points and the new edges are computed
                    # (evaluation and bounds are per point / per edge: the same values as a full pass)
                    t, p, bd, graph = _halve_edges(c, _sampled_bounds, t, p, bd, graph, bad)
            e0, e1 = t[:-1], t[1:]
            if not np.all(np.isfinite(bd)):
                raise ValueError(f"LoopBoundary: curve {k} ({c!r}) has no finite chord bound after {_MAX_ROUNDS} halvings")
            a.append(p[:-1]), b.append(p[1:]), band.append(bd + 1e-14 * self.size * (bd > 0))
            cid.append(np.full(len(e0), k)), ta.append(e0), tb.append(e1)
        # gap edges where a piece does not end where the next starts (and to close the loop)
        n = len(self.curves)
        for k in range(n):
            end, start = b[k][-1], a[(k + 1) % n][0]
            if np.any(end != start):
                a.append(end[None]), b.append(start[None]), band.append(np.zeros(1))
                cid.append(np.full(1, -1)), ta.append(np.zeros(1)), tb.append(np.zeros(1))
        self.a, self.b = np.concatenate(a), np.concatenate(b)
        self.band, self.curve = np.concatenate(band), np.concatenate(cid)
        self.ta, self.tb = np.concatenate(ta), np.concatenate(tb)
        self._grids: dict[float, _EdgeGrid] = {}

    def grid(self, tol: float) -> _EdgeGrid:
        """The edge grid reaching at least ``tol`` beyond the bands (built once per power of 2)."""
        reach = 2.0 ** np.ceil(np.log2(max(float(tol), 1e-9 * self.size, 1e-300)))
        g = self._grids.get(reach)
        if g is None:
            g = self._grids[reach] = _EdgeGrid(self.a, self.b, self.band, reach)
        return g

    def _packed(self):
        """The loop's edges and curves in flat arrays for `_contains_kernel` (built once): NURBS
        curves, and exactly mapped ones as their base curve and map (`_kernel_form`); None if
        a curve has neither form (the numpy path)."""
        if "_pack" not in self.__dict__:
            forms = [_kernel_form(c) for c in self.curves]
            if any(f is None for f in forms):
                self._pack = None
            else:
                pws = [np.ascontiguousarray(f[0], dtype=float) for f in forms]
                kns = [np.ascontiguousarray(f[1], dtype=float) for f in forms]
                cpw_off = np.concatenate([[0], np.cumsum([w.size for w in pws])]).astype(np.int64)
                k_off = np.concatenate([[0], np.cumsum([k.size for k in kns])]).astype(np.int64)
                self._pack = (np.ascontiguousarray(self.curve, dtype=np.int64), np.ascontiguousarray(self.ta),
                              np.ascontiguousarray(self.tb), _frozen(np.concatenate([w.ravel() for w in pws])),
                              cpw_off, np.array([w.shape[1] - 1 for w in pws], dtype=np.int64),
                              _frozen(np.concatenate(kns)), k_off, np.array([f[2] for f in forms], dtype=np.int64),
                              np.array([bool(f[3]) for f in forms], dtype=np.bool_),
                              _frozen(np.stack([f[4] for f in forms])))
        return self._pack

    def contains(self, uv: np.ndarray, tol: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """(inside (N,) bool, on (N,) bool) for points uv (N, 2) against the exact loop:
        inside the region it encloses (even-odd rule, either orientation), and within
        ``tol`` (parameter units) of an exact curve."""
        uv = np.ascontiguousarray(uv, dtype=float).reshape(-1, 2)
        if tol < 0 or not np.isfinite(tol):
            raise ValueError(f"tol must be finite and >= 0, got {tol!r}")
        g = self.grid(tol)
        packed = self._packed()
        if packed is not None:  # every curve a NURBS curve: one compiled pass
            inside = np.empty(len(uv), dtype=bool)
            on = np.empty(len(uv), dtype=bool)
            _contains_kernel(np.ascontiguousarray(uv[:, 0]), np.ascontiguousarray(uv[:, 1]), g.x0, g.y0, g.h, g.nx,
                             g.ny, g.cstart, g.cedges, g.vstart, g.vcross, g.ax, g.ay, g.bx, g.by, g.band,
                             float(tol), *packed, float(self.size), 60, inside, on)
            return inside, on
        inside, near = g.classify(uv, tol)
        on = np.zeros(len(uv), dtype=bool)
        ni = np.flatnonzero(near)
        if len(ni) == 0:
            return inside, on
        q = uv[ni]
        pi, ki, dseg = g.pairs(q, tol)
        flips = np.zeros(len(ni), dtype=np.int64)
        on_n = np.zeros(len(ni), dtype=bool)
        straight = self.band[ki] == 0.0
        on_n[pi[straight & (dseg <= tol)]] = True
        cur = ~straight
        for c in np.unique(self.curve[ki[cur]]):
            sel = np.flatnonzero(cur & (self.curve[ki] == c))
            k = ki[sel]
            lens, dist = _lens(self.curves[c], self.ta[k], self.tb[k], self.a[k], self.b[k], q[pi[sel]], self.size)
            np.add.at(flips, pi[sel], lens.astype(np.int64))
            on_n[pi[sel][dist <= tol]] = True
        inside[ni] ^= (flips % 2) == 1
        on[ni] = on_n
        return inside, on


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _lens_pair(cpw, knots, deg, rat, cmap, ta, tb, ax, ay, bx, by, px, py, size, max_iter, ndu, left, right, sa, nd, aw,
               cd):  # pragma: no cover - compiled
    """`_lens` for one pair (point (px, py), edge a -> b of a NURBS curve over [ta, tb]), with
    the same steps and tests (its docstring); scratch as `_curve_ders_one` (cd (3, >= 2)); cmap the curve's map
    (`_tcurve_ders_one`).
    Returns (lens, dist)."""
    dx, dy = bx - ax, by - ay
    ln = np.sqrt(dx * dx + dy * dy)
    ll = ln if ln > 0 else 1.0
    ex, ey = dx / ll, dy / ll  # dirn
    nx, ny = -ey, ex  # nrm
    qx, qy = px - ax, py - ay
    sp = qx * ex + qy * ey
    npp = qx * nx + qy * ny
    mid = sp > 0 and sp < ln
    t = ta + (tb - ta) * min(max(sp / ll, 0.0), 1.0)
    lo, hi = ta, tb
    eps = 1e-15 * (size + max(abs(ax), abs(ay)))
    if mid:
        for _ in range(max_iter):
            _tcurve_ders_one(cpw, knots, deg, rat, cmap, t, np.int64(1), ndu, left, right, sa, nd, aw, cd)
            g = (cd[0, 0] - ax) * ex + (cd[0, 1] - ay) * ey - sp
            gp = cd[1, 0] * ex + cd[1, 1] * ey
            if g < 0:
                lo = t
            if g > 0:
                hi = t
            tn = t - g / gp
            if not (tn > lo and tn < hi):
                tn = 0.5 * (lo + hi)
            if (abs(g) <= eps or hi - lo <= 4e-16 * (abs(hi) + abs(lo)) or abs(tn - t) * abs(gp) <= eps):
                break
            t = tn
    _tcurve_ders_one(cpw, knots, deg, rat, cmap, t, np.int64(0), ndu, left, right, sa, nd, aw, cd)
    f = (cd[0, 0] - ax) * nx + (cd[0, 1] - ay) * ny
    lens = mid and npp * f > 0 and abs(npp) < abs(f)
    # distance to the arc: Newton on (C - p).C' from the chord's abscissa (or the near end)
    for _ in range(8):
        _tcurve_ders_one(cpw, knots, deg, rat, cmap, t, np.int64(2), ndu, left, right, sa, nd, aw, cd)
        rx, ry = cd[0, 0] - px, cd[0, 1] - py
        g = rx * cd[1, 0] + ry * cd[1, 1]
        c11 = cd[1, 0] * cd[1, 0] + cd[1, 1] * cd[1, 1]
        gp = c11 + (rx * cd[2, 0] + ry * cd[2, 1])
        if not gp > 0:
            gp = c11 + 1e-300
        tn = min(max(t - g / gp, ta), tb)
        moved = abs(tn - t) * np.sqrt(c11) > 1e-15 * size
        t = tn
        if not moved:
            break
    _tcurve_ders_one(cpw, knots, deg, rat, cmap, t, np.int64(0), ndu, left, right, sa, nd, aw, cd)
    rx, ry = cd[0, 0] - px, cd[0, 1] - py
    dd = np.sqrt(rx * rx + ry * ry)
    da = np.sqrt((ax - px) ** 2 + (ay - py) ** 2)
    db = np.sqrt((bx - px) ** 2 + (by - py) ** 2)
    return lens, min(dd, min(da, db))


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _lens_kernel(cpw, knots, deg, rat, cmap, ta, tb, a, b, p, size, max_iter, lens, dist):  # pragma: no cover - compiled
    """`_lens` for a NURBS (or exactly mapped) curve, pair by pair (`_lens_pair`); writes lens
    (K,) and dist (K,)."""
    dim = max(cpw.shape[1] - 1, 2)
    ndu = np.empty((deg + 1, deg + 1))
    left = np.empty(deg + 1)
    right = np.empty(deg + 1)
    sa = np.empty((2, deg + 1))
    nd = np.empty((3, deg + 1))
    aw = np.empty((3, dim + 1))
    cd = np.empty((3, dim))
    for i in range(ta.shape[0]):
        lens[i], dist[i] = _lens_pair(cpw, knots, deg, rat, cmap, ta[i], tb[i], a[i, 0], a[i, 1], b[i, 0], b[i, 1],
                                      p[i, 0], p[i, 1], size, max_iter, ndu, left, right, sa, nd, aw, cd)


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _contains_kernel(pu, pv, x0, y0, h, nx, ny, cstart, cedges, vstart, vcross, ax, ay, bx, by, band, tol,
                     ecurve, eta, etb, cpw, cpw_off, cdim, knots, k_off, deg, rat, maps, size, max_iter, inside,
                     on):  # pragma: no cover - compiled
    """`LoopBoundary.contains` in one pass for a loop of NURBS curves (packed: control nets
    cpw[cpw_off[c]:cpw_off[c+1]] of shape (n, cdim[c] + 1), knots[k_off[c]:k_off[c+1]]):
    the parity of `_classify_kernel`; for points near an edge, the pairs of `_pairs_kernel`,
    straight edges deciding ``on`` by their distance, curved ones flipping the parity where
    the point lies between chord and arc (`_lens_pair`; maps[c] the exact map of an
    analytic surface's curve, `_kernel_form`). Same tests, same results."""
    pmax = 0
    dmax = 2
    for c in range(deg.shape[0]):
        pmax = max(pmax, deg[c])
        dmax = max(dmax, cdim[c])
    ndu = np.empty((pmax + 1, pmax + 1))
    left = np.empty(pmax + 1)
    right = np.empty(pmax + 1)
    sa = np.empty((2, pmax + 1))
    nd = np.empty((3, pmax + 1))
    aw = np.empty((3, dmax + 1))
    cd = np.empty((3, dmax))
    for i in range(pu.size):
        x = pu[i]
        y = pv[i]
        ci, cj, cnt = _grid_start(x, y, x0, y0, h, nx, ny, vstart, vcross)
        if ci < 0:
            inside[i] = False
            on[i] = False
            continue
        xr = x0 + (ci + 1) * h
        xa = min(x, xr)
        xb = max(x, xr)
        cell = cj * nx + ci
        flips = 0
        o = False
        for q in range(cstart[cell], cstart[cell + 1]):
            k = cedges[q]
            y1 = ay[k]
            y2 = by[k]
            if (y1 > y) != (y2 > y):
                uc = ax[k] + (y - y1) * (bx[k] - ax[k]) / (y2 - y1)
                if uc > xa and uc <= xb:
                    cnt += 1
            d = _seg_dist(x, y, ax[k], ay[k], bx[k], by[k])
            if d <= band[k] + tol:
                if band[k] == 0.0:
                    if d <= tol:
                        o = True
                else:
                    c = ecurve[k]
                    pw = cpw[cpw_off[c] : cpw_off[c + 1]].reshape((-1, cdim[c] + 1))
                    ln, dd = _lens_pair(pw, knots[k_off[c] : k_off[c + 1]], deg[c], rat[c], maps[c], eta[k], etb[k], ax[k],
                                        ay[k], bx[k], by[k], x, y, size, max_iter, ndu, left, right, sa, nd, aw, cd)
                    if ln:
                        flips += 1
                    if dd <= tol:
                        o = True
        inside[i] = ((cnt % 2) == 1) != ((flips % 2) == 1)
        on[i] = o


def _lens(c, ta, tb, a, b, p, size: float, max_iter: int = 60):
    """For pairs (point p (K, 2), edge k of curve c): whether p lies strictly between the
    chord a -> b and the exact arc c([ta, tb]) (the arc is a graph over its chord: solve
    s(t) = s_p by safeguarded Newton, compare normal offsets), and the distance of p to the
    arc (Newton on (C - p).C' from there, clamped; ends included). (K,) bool, (K,) float.
    NURBS and exactly mapped curves go through the compiled `_lens_kernel` (same steps)."""
    form = _kernel_form(c)
    if form is not None:
        lens = np.empty(len(ta), dtype=np.bool_)
        dist = np.empty(len(ta))
        _lens_kernel(*form, np.ascontiguousarray(ta, dtype=float),
                     np.ascontiguousarray(tb, dtype=float), np.ascontiguousarray(a, dtype=float),
                     np.ascontiguousarray(b, dtype=float), np.ascontiguousarray(p, dtype=float), float(size),
                     int(max_iter), lens, dist)
        return lens, dist
    d = b - a
    ln = np.linalg.norm(d, axis=1)
    dirn = d / np.where(ln > 0, ln, 1.0)[:, None]
    nrm = np.column_stack([-dirn[:, 1], dirn[:, 0]])
    sp = np.einsum("ij,ij->i", p - a, dirn)
    npp = np.einsum("ij,ij->i", p - a, nrm)
    mid = (sp > 0) & (sp < ln)
    t = ta + (tb - ta) * np.clip(sp / np.where(ln > 0, ln, 1.0), 0.0, 1.0)
    lo, hi = ta.copy(), tb.copy()
    eps = 1e-15 * (size + np.abs(a).max(axis=1))
    act = np.flatnonzero(mid)
    for _ in range(max_iter):
        if not len(act):
            break
        dv = curve_ders(c, t[act], 1)[:, :, :2]
        g = np.einsum("ij,ij->i", dv[:, 0] - a[act], dirn[act]) - sp[act]
        gp = np.einsum("ij,ij->i", dv[:, 1], dirn[act])
        lo[act] = np.where(g < 0, t[act], lo[act])
        hi[act] = np.where(g > 0, t[act], hi[act])
        with np.errstate(divide="ignore", invalid="ignore"):
            tn = t[act] - g / gp
        bad = ~((tn > lo[act]) & (tn < hi[act]))
        tn = np.where(bad, 0.5 * (lo[act] + hi[act]), tn)
        done = ((np.abs(g) <= eps[act]) | (hi[act] - lo[act] <= 4e-16 * (np.abs(hi[act]) + np.abs(lo[act])))
                | (np.abs(tn - t[act]) * np.abs(gp) <= eps[act]))
        t[act] = np.where(done, t[act], tn)
        act = act[~done]
    f = np.einsum("ij,ij->i", curve_ders(c, t, 0)[:, 0, :2] - a, nrm)
    lens = mid & (npp * f > 0) & (np.abs(npp) < np.abs(f))
    # distance to the arc: Newton on (C - p).C' from the chord's abscissa (or the near end)
    act = np.arange(len(t))
    for _ in range(8):
        dv = curve_ders(c, t[act], 2)[:, :, :2]
        r = dv[:, 0] - p[act]
        g = np.einsum("ij,ij->i", r, dv[:, 1])
        c11 = np.einsum("ij,ij->i", dv[:, 1], dv[:, 1])
        gp = c11 + np.einsum("ij,ij->i", r, dv[:, 2])
        gp = np.where(gp > 0, gp, c11 + 1e-300)
        tn = np.clip(t[act] - g / gp, ta[act], tb[act])
        moved = np.abs(tn - t[act]) * np.sqrt(c11) > 1e-15 * size
        t[act] = tn
        act = act[moved]
        if not len(act):
            break
    dist = np.linalg.norm(curve_ders(c, t, 0)[:, 0, :2] - p, axis=1)
    dist = np.minimum(dist, np.minimum(np.linalg.norm(a - p, axis=1), np.linalg.norm(b - p, axis=1)))
    return lens, dist


def loop_contains(loop, u, v, tol: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(inside (N,), on (N,)) of (u, v) (N,) against one `TrimLoop` (its cached boundary)."""
    uv = np.column_stack([np.ravel(u), np.ravel(v)]).astype(float)
    return loop.boundary.contains(uv, tol)


def trim_contains(trim, u, v, tol: float = 0.0) -> np.ndarray:
    """Whether (u, v) (N,) lie in the closed trimmed region of a `Trim`: inside or on the
    outer loop (none: everywhere) and not strictly inside any hole. (N,) bool."""
    uv = np.column_stack([np.ravel(u), np.ravel(v)]).astype(float)
    ok = np.ones(len(uv), dtype=bool)
    if trim.outer is not None:
        ins, on = trim.outer.boundary.contains(uv, tol)
        ok = ins | on
    for hole in trim.inner:
        idx = np.flatnonzero(ok)
        if not len(idx):
            break
        ins, on = hole.boundary.contains(uv[idx], tol)
        ok[idx] = ~ins | on
    return ok


def _straight_boundary(polygon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    poly = np.asarray(polygon, dtype=float).reshape(-1, 2)
    return poly, np.roll(poly, -1, axis=0)


def polygon_contains(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Even-odd test of (N, 2) points against the closed polygon (M, 2) through the edge
    grid (cost ~ edges per cell per point). (N,) bool; a point on an edge may go either way."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    a, b = _straight_boundary(polygon)
    if len(a) < 3:
        return np.zeros(len(pts), dtype=bool)
    size = float(np.linalg.norm(a.max(axis=0) - a.min(axis=0))) or 1.0
    return _EdgeGrid(a, b, np.zeros(len(a)), 1e-12 * size).classify(pts, 0.0)[0]


def polygon_distance(points: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Distance of (N, 2) points to the closed polyline (M, 2), (N,). Edges are split to
    half-length <= hm and their midpoints put in a KD-tree; the nearest midpoint gives an
    upper bound d, and only edges with midpoint within d + hm are measured."""
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    a, b = _straight_boundary(polygon)
    if len(a) == 0:
        return np.full(len(pts), np.inf)
    ln = np.linalg.norm(b - a, axis=1)
    hm = max(0.5 * float(np.median(ln)), float(ln.sum()) / (8 * len(a)), 1e-300)
    pieces = np.maximum(1, np.ceil(ln / (2 * hm)).astype(np.int64))
    e = np.repeat(np.arange(len(a)), pieces)
    k = np.arange(len(e)) - np.repeat(np.cumsum(pieces) - pieces, pieces)
    s0, s1 = (k / pieces[e])[:, None], ((k + 1) / pieces[e])[:, None]
    pa, pb = a[e] + s0 * (b[e] - a[e]), a[e] + s1 * (b[e] - a[e])
    tree = cKDTree(0.5 * (pa + pb))
    dup, _ = tree.query(pts)
    cand = tree.query_ball_point(pts, dup + hm + 1e-12 * (dup + hm))
    cnt = np.array([len(x) for x in cand])
    ci = np.concatenate([np.asarray(x, dtype=np.int64) for x in cand]) if len(pts) else np.zeros(0, dtype=np.int64)
    pi = np.repeat(np.arange(len(pts)), cnt)
    d = segment_distance(pts[pi], pa[ci], pb[ci])
    out = np.full(len(pts), np.inf)
    np.minimum.at(out, pi, d)
    return out


# ---------------------------------------------------------------------------------------
# nearest point of the trim boundary in 3D


def curve_newton(surf, curve, pts: np.ndarray, t: np.ndarray, closed: bool, eps: float, max_iter: int = 40) -> None:
    """Newton for the nearest point of the curve on the surface, C(t) = S(c(t)), to (M, 3)
    points, from start parameters t (M,), updated in place: f(t) = (C - P).C',
    f' = C'.C' + (C - P).C'' (C' = Su u' + Sv v', C'' = Suu u'^2 + 2 Suv u' v' + Svv v'^2
    + Su u'' + Sv v''; C'.C' where f' <= 0), t clamped to the curve's domain (wrapped through
    the seam of a ``closed`` curve), until a step moves C by at most ``eps``. Compiled for 2D
    NURBS curves and exactly mapped ones (`_kernel_form`); the same steps in numpy for others."""
    u0, u1, v0, v1 = surf.domain
    t0, t1 = curve.domain
    form = _kernel_form(curve) if getattr(curve, "dim", 2) == 2 else None
    if form is not None:
        _trim_newton_kernel(surf._pw, surf.knots_u, surf.knots_v, surf.degree_u, surf.degree_v, surf.rational,
                            u0, u1, v0, v1, *form, float(t0), float(t1), closed,
                            np.ascontiguousarray(pts, dtype=float), t, eps, int(max_iter))
        return
    done = np.zeros(len(t), dtype=bool)
    for _ in range(max_iter):
        act = np.nonzero(~done)[0]
        if not len(act):
            break
        c = curve_ders(curve, t[act], 2)  # (A, 3, 2): uv, uv', uv''
        d = surf.derivatives(np.clip(c[:, 0, 0], u0, u1), np.clip(c[:, 0, 1], v0, v1), order=2)
        up, vp, upp, vpp = c[:, 1, 0], c[:, 1, 1], c[:, 2, 0], c[:, 2, 1]
        su, sv = d[:, 1, 0], d[:, 0, 1]
        c1 = su * up[:, None] + sv * vp[:, None]
        c2 = (d[:, 2, 0] * (up * up)[:, None] + 2.0 * d[:, 1, 1] * (up * vp)[:, None]
              + d[:, 0, 2] * (vp * vp)[:, None] + su * upp[:, None] + sv * vpp[:, None])
        r = d[:, 0, 0] - pts[act]
        f = np.einsum("ij,ij->i", r, c1)
        fp = np.einsum("ij,ij->i", c1, c1) + np.einsum("ij,ij->i", r, c2)
        fp = np.where(fp > 0, fp, np.einsum("ij,ij->i", c1, c1) + 1e-300)
        tn = t[act] - f / fp
        tn = t0 + np.mod(tn - t0, t1 - t0) if closed else np.clip(tn, t0, t1)
        step = np.abs(tn - t[act]) * np.linalg.norm(c1, axis=1)
        t[act] = tn
        done[act[step <= eps]] = True


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _trim_pairs_kernel(spw, sku, skv, p, q, srat, u0, u1, v0, v1, cpw, cpw_off, cdim, cknots, k_off, cdeg, crat, cmaps,
                       ct0, ct1, cclosed, pc, pts, t, eps1, max_iter, out_u, out_v, out_foot, out_dist,
                       out_ok):  # pragma: no cover - compiled
    """`project_to_trims` on (point, curve) pairs: pair i is point pts[i] on curve pc[i] (curves
    packed as for `_contains_kernel`, domains [ct0, ct1], cclosed), from t[i]: Newton
    (`_trim_newton_one`), then at the final t: (u, v) = c(t) clamped to the
    surface's domain, foot S(u, v), its distance, and ok: orthogonal within 1e3 x eps1
    (|(S - P).C'| / |C'|) or at a curve end. Writes t and out_*."""
    pmax = 0
    dmax = 2
    for c in range(cdeg.shape[0]):
        pmax = max(pmax, cdeg[c])
        dmax = max(dmax, cdim[c])
    scratch = ders2_scratch(p, q)
    der = np.empty((3, 3, 3))
    cndu = np.empty((pmax + 1, pmax + 1))
    cl = np.empty(pmax + 1)
    cr = np.empty(pmax + 1)
    ca = np.empty((2, pmax + 1))
    cnd = np.empty((3, pmax + 1))
    caw = np.empty((3, dmax + 1))
    cd = np.empty((3, dmax))
    c1 = np.empty(3)
    for i in range(pts.shape[0]):
        c = pc[i]
        pw = cpw[cpw_off[c] : cpw_off[c + 1]].reshape((-1, cdim[c] + 1))
        kn = cknots[k_off[c] : k_off[c + 1]]
        t0, t1 = ct0[c], ct1[c]
        ti = _trim_newton_one(spw, sku, skv, p, q, srat, u0, u1, v0, v1, pw, kn, cdeg[c], crat[c], cmaps[c], t0, t1,
                              cclosed[c], pts[i, 0], pts[i, 1], pts[i, 2], t[i], eps1, max_iter, scratch, der, cndu,
                              cl, cr, ca, cnd, caw, cd)
        t[i] = ti
        _tcurve_ders_one(pw, kn, cdeg[c], crat[c], cmaps[c], ti, np.int64(2), cndu, cl, cr, ca, cnd, caw, cd)
        uu = min(max(cd[0, 0], u0), u1)
        vv = min(max(cd[0, 1], v0), v1)
        ders2_one(spw, sku, skv, p, q, srat, uu, vv, scratch, der)
        dd = 0.0
        rc = 0.0
        cc = 0.0
        for k in range(3):
            c1[k] = der[1, 0, k] * cd[1, 0] + der[0, 1, k] * cd[1, 1]
            r = der[0, 0, k] - pts[i, k]
            dd += r * r
            rc += r * c1[k]
            cc += c1[k] * c1[k]
            out_foot[i, k] = der[0, 0, k]
        out_u[i], out_v[i] = uu, vv
        out_dist[i] = np.sqrt(dd)
        off = abs(rc) / max(np.sqrt(cc), 1e-300)
        out_ok[i] = off <= 1e3 * eps1 or ti <= t0 or ti >= t1


def project_to_trims(face, points, *, tol: float = 1e-12, max_iter: int = 40):
    """Nearest points of the trim loops (outer and holes) of ``face`` to (N, 3) points.

    Each loop curve c(t) (in (u, v)) is followed on the surface, C(t) = S(c(t)). Narrowing:
    16 samples per knot span of every curve, in 3D; the nearest sample of all curves bounds
    the distance to the boundary from above (U), and a curve is kept for a point only if the
    point's distance to the curve's sample box grown by r (0.55 x its longest sample chord:
    every curve point is within r of a sample) is <= U. On the kept pairs only: start from
    the curve's nearest sample, then Newton and the orthogonality test (NURBS and exactly
    mapped curves: one compiled call for all pairs, `_trim_pairs_kernel`; others:
    `curve_newton` in numpy); the nearest orthogonal foot wins, at equal distance the first
    curve in loop order.
    Returns (u (N,), v (N,), foot (N, 3), distance (N,), ok (N,) bool: orthogonal foot or
    curve end). Raises ValueError if the face has no trim loops.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    n = len(pts)
    trims = face.trims
    loops = ([] if trims is None or trims.outer is None else [trims.outer]) + ([] if trims is None else list(trims.inner))
    if not loops:
        raise ValueError("project_to_trims: the face has no trim loops")
    surf = face.surface
    b = surf.bbox()
    size = max(float(np.linalg.norm(b[1] - b[0])), 1e-300)
    eps1 = tol * size
    best = (np.full(n, np.nan), np.full(n, np.nan), np.full((n, 3), np.nan), np.full(n, np.inf), np.zeros(n, dtype=bool))
    if n == 0:
        return best
    u0, u1, v0, v1 = surf.domain

    def on_surface(curve, t, order):
        c = curve_ders(curve, t, 2)  # (N, 3, 2): uv, uv', uv''
        uu = np.clip(c[:, 0, 0], u0, u1)
        vv = np.clip(c[:, 0, 1], v0, v1)
        d = surf.derivatives(uu, vv, order=order)
        return uu, vv, c, d

    curves = [c for loop in loops for c in loop.curves]
    key = (id(surf), id(trims), tuple(id(c) for c in curves))
    hit = face.__dict__.get("_cadbridge_trim_samples")
    if hit is not None and hit[0] == key:
        samples, alltree = hit[1], hit[2]
    else:  # samples of the curves on the surface, kept on the face (reused by later calls)
        samples = []
        for curve in curves:
            ts = curve.sample_parameters(16)
            x = on_surface(curve, ts, 0)[3][:, 0, 0]
            r = 0.55 * float(np.max(np.linalg.norm(np.diff(x, axis=0), axis=1))) if len(x) > 1 else 0.0
            samples.append((ts, x, r + 1e-12 * size, cKDTree(x), x.min(axis=0) - r - 1e-12 * size,
                            x.max(axis=0) + r + 1e-12 * size))
        alltree = cKDTree(np.concatenate([s[1] for s in samples]))
        face.__dict__["_cadbridge_trim_samples"] = (key, samples, alltree)
    upper, _ = alltree.query(pts)
    upper = upper * (1 + 1e-12) + 1e-12 * size

    # (point, curve) pairs: the curves whose grown sample box lies within the point's bound
    lo = np.array([smp[4] for smp in samples])
    hi = np.array([smp[5] for smp in samples])
    pts_c = np.ascontiguousarray(pts)
    cnt = _box_pairs(pts_c, lo, hi, upper, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    if not cnt:
        return best
    pi, ci = np.empty(cnt, dtype=np.int64), np.empty(cnt, dtype=np.int64)
    _box_pairs(pts_c, lo, hi, upper, pi, ci)  # by curve, points ascending within each
    t = np.empty(len(pi))  # each pair's start, then Newton's end
    cuts = np.flatnonzero(np.diff(ci)) + 1
    for a, b in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(ci)]])):
        ts, xtree = samples[ci[a]][0], samples[ci[a]][3]
        _, k = xtree.query(pts[pi[a:b]])  # the curve's nearest sample starts Newton
        t[a:b] = ts[np.asarray(k)]
    start = t.copy()
    hit = face.__dict__.get("_cadbridge_trim_pack")
    if hit is None or hit[0] != key:
        hit = face.__dict__["_cadbridge_trim_pack"] = (key, *_pack_curves(curves, samples, size))
    packed, renum, cargs = hit[1:]
    m = len(pi)
    uu, vv, foot, dist, ok = np.empty(m), np.empty(m), np.empty((m, 3)), np.empty(m), np.empty(m, dtype=np.bool_)
    comp = np.flatnonzero(packed[ci])
    if len(comp):  # the pairs on NURBS or exactly mapped curves: one compiled call
        k = len(comp)
        ru, rv, rf, rd, rk = np.empty(k), np.empty(k), np.empty((k, 3)), np.empty(k), np.empty(k, dtype=np.bool_)
        tc = np.ascontiguousarray(t[comp])
        _trim_pairs_kernel(surf._pw, surf.knots_u, surf.knots_v, surf.degree_u, surf.degree_v, surf.rational,
                           u0, u1, v0, v1, *cargs, renum[ci[comp]], np.ascontiguousarray(pts[pi[comp]]),
                           tc, eps1, int(max_iter), ru, rv, rf, rd, rk)
        uu[comp], vv[comp], foot[comp], dist[comp], ok[comp], t[comp] = ru, rv, rf, rd, rk, tc
    for j in np.unique(ci[~packed[ci]]):  # other curves: the numpy steps
        rows = np.flatnonzero(ci == j)
        curve, q = curves[j], pts[pi[rows]]
        tj = np.ascontiguousarray(t[rows])
        t0, t1 = curve.domain
        curve_newton(surf, curve, q, tj, _closed(samples[j][1], size), eps1, max_iter)
        u_, v_, c, d = on_surface(curve, tj, 1)
        c1 = d[:, 1, 0] * c[:, 1, 0:1] + d[:, 0, 1] * c[:, 1, 1:2]
        r = d[:, 0, 0] - q
        off = np.abs(np.einsum("ij,ij->i", r, c1)) / np.maximum(np.linalg.norm(c1, axis=1), 1e-300)
        uu[rows], vv[rows], foot[rows], dist[rows] = u_, v_, d[:, 0, 0], np.linalg.norm(r, axis=1)
        ok[rows] = (off <= 1e3 * eps1) | (tj <= t0) | (tj >= t1)
        t[rows] = tj
    for j in np.unique(ci[~ok]):  # Newton's feet that are not orthogonal: a kink of C there?
        rows = np.flatnonzero((ci == j) & ~ok)
        tj, hit = _kink_feet(surf, curves[j], pts[pi[rows]], t[rows], start[rows], eps1)
        rows, tj = rows[hit], tj[hit]
        u_, v_, _, d = on_surface(curves[j], tj, 0)
        uu[rows], vv[rows], foot[rows] = u_, v_, d[:, 0, 0]
        dist[rows], ok[rows] = np.linalg.norm(d[:, 0, 0] - pts[pi[rows]], axis=1), True
    # per point the nearest orthogonal foot; at equal distance the first curve in loop order
    dk = np.where(ok, dist, np.inf)
    pick = np.lexsort((ci, dk, pi))
    first = pick[np.concatenate([[True], pi[pick][1:] != pi[pick][:-1]])]
    first = first[np.isfinite(dk[first])]
    sel = pi[first]
    best[0][sel], best[1][sel], best[2][sel] = uu[first], vv[first], foot[first]
    best[3][sel], best[4][sel] = dist[first], True
    return best


def _kink_feet(surf, curve, q: np.ndarray, t: np.ndarray, start: np.ndarray, eps: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Nearest points of C(t) = S(c(t)) to (M, 3) points q where Newton (from ``start``
    (M,) to ``t`` (M,)) ended on no orthogonal foot: at a kink of C (a C0 knot of c, or c
    crossing a C0 knot line of S, as at a crease of a CATIA surface) f(t) = (C - P).C'
    jumps from negative to positive and has no root for Newton to find, yet the distance
    has its minimum there. Where f < 0 at t - h and f > 0 at t + h (h growing from 1e-9 to
    1e-2 of the domain; then the same around the start, up to 1e-1, past the nearest
    sample's neighbours), bisection on the sign of f narrows that bracket until C moves
    by at most ``eps`` over it (a local minimum of |C - P| lies inside: |C - P|^2 is
    continuous and its one-sided slopes are 2 f). Returns (t (M,), found (M,) bool)."""
    t0, t1 = curve.domain
    u0, u1, v0, v1 = surf.domain
    span = t1 - t0

    def f_and_speed(tt: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = curve_ders(curve, tt, 1)
        d = surf.derivatives(np.clip(c[:, 0, 0], u0, u1), np.clip(c[:, 0, 1], v0, v1), order=1)
        c1 = d[:, 1, 0] * c[:, 1, 0:1] + d[:, 0, 1] * c[:, 1, 1:2]
        return np.einsum("ij,ij->i", d[:, 0, 0] - pts, c1), np.linalg.norm(c1, axis=1)

    a, b = t.copy(), t.copy()
    found = np.zeros(len(t), dtype=bool)
    tries = [(t, h) for h in span * np.logspace(-9, -2, 15)] + [(start, h) for h in span * np.logspace(-9, -1, 17)]
    for centre, h in tries:  # the smallest bracket around t, then the start, that holds a sign change
        todo = np.flatnonzero(~found)
        if not len(todo):
            break
        lo, hi = np.maximum(centre[todo] - h, t0), np.minimum(centre[todo] + h, t1)
        flo, _ = f_and_speed(lo, q[todo])
        fhi, _ = f_and_speed(hi, q[todo])
        yes = (flo < 0) & (fhi > 0)
        a[todo[yes]], b[todo[yes]], found[todo[yes]] = lo[yes], hi[yes], True
    idx = np.flatnonzero(found)
    for _ in range(200):  # bisection: one bit of the bracket per step
        if not len(idx):
            break
        m = 0.5 * (a[idx] + b[idx])
        fm, speed = f_and_speed(m, q[idx])
        neg = fm < 0
        a[idx[neg]], b[idx[~neg]] = m[neg], m[~neg]
        idx = idx[(b[idx] - a[idx]) * speed > eps]
    return 0.5 * (a + b), found


@numba.njit(cache=True, error_model="numpy", nogil=True)
def _box_pairs(pts, lo, hi, upper, out_p, out_c):  # pragma: no cover - compiled
    """(point, curve) pairs with the point within upper[point] of the curve's box lo[c] ..
    hi[c] (the distance to the box), by curve, then point. Returns their number; writes
    them into out_p, out_c when those are long enough."""
    m = 0
    write = out_p.shape[0] > 0
    for c in range(lo.shape[0]):
        for i in range(pts.shape[0]):
            g2 = 0.0
            for k in range(3):
                g = max(0.0, max(lo[c, k] - pts[i, k], pts[i, k] - hi[c, k]))
                g2 += g * g
            if np.sqrt(g2) <= upper[i]:
                if write:
                    out_p[m] = i
                    out_c[m] = c
                m += 1
    return m


def _pack_curves(curves: list, samples: list, size: float):
    """The trim curves of a face for `_trim_pairs_kernel`: (packed (C,) bool: the curve has a
    compiled form (`_kernel_form`), renum (C,) its index among those, the kernel's curve
    arguments)."""
    forms = [_kernel_form(c) if getattr(c, "dim", 2) == 2 else None for c in curves]
    packed = np.array([f is not None for f in forms], dtype=bool)
    idx = np.flatnonzero(packed)
    renum = np.full(len(curves), -1, dtype=np.int64)
    renum[idx] = np.arange(len(idx))
    if not len(idx):
        return packed, renum, ()
    pws = [np.ascontiguousarray(forms[j][0], dtype=float) for j in idx]
    kns = [np.ascontiguousarray(forms[j][1], dtype=float) for j in idx]
    cargs = (_frozen(np.concatenate([w.ravel() for w in pws])),
             np.concatenate([[0], np.cumsum([w.size for w in pws])]).astype(np.int64),
             np.array([w.shape[1] - 1 for w in pws], dtype=np.int64), _frozen(np.concatenate(kns)),
             np.concatenate([[0], np.cumsum([k.size for k in kns])]).astype(np.int64),
             np.array([forms[j][2] for j in idx], dtype=np.int64),
             np.array([bool(forms[j][3]) for j in idx], dtype=np.bool_),
             _frozen(np.stack([forms[j][4] for j in idx])),
             np.array([float(curves[j].domain[0]) for j in idx]), np.array([float(curves[j].domain[1]) for j in idx]),
             np.array([_closed(samples[j][1], size) for j in idx], dtype=np.bool_))
    return packed, renum, cargs


def _closed(xs: np.ndarray, size: float) -> bool:
    """A trim curve whose samples xs (M, 3) on the surface start where they end (a hole's
    circle as one piece): Newton wraps through its seam instead of stopping at an end."""
    return float(np.linalg.norm(xs[0] - xs[-1])) <= 1e-9 * size
