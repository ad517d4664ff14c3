"""Least-squares fitting of one NURBS surface to scattered points with (u, v) parameters.

The fit minimises (Piegl & Tiller §9.4.3 extended by a smoothing term, as in Hoschek & Lasser §4.4)

    F(P) = sum_k w_k |S(u_k, v_k) - x_k|^2 + lam * E(P),
    E(P) = integral over the domain of |S_uu|^2 + 2 |S_uv|^2 + |S_vv|^2 du dv   (thin-plate energy)

over the control points P (the weights of a rational fit are fixed, so S is linear in P). The
normal equations (A^T W A + lam G) P = A^T W X are assembled directly in banded form by a numba
kernel (a point touches (p+1)^2 (q+1)^2 entries) and solved as a scipy.sparse system (SuperLU);
G = D2u (x) Mv + 2 D1u (x) D1v + Mu (x) D2v from exact 1D Gram matrices of basis derivatives
(Gauss-Legendre per knot span). lam = smoothing * trace(A^T W A) / trace(G): the user weight is
the ratio of the two terms' traces, dimensionless, independent of the units of coordinates and
parameters, and it keeps its meaning as knots are inserted (G grows like 1 / span^3; a weight
tied to the domain size instead biased a refined die radius by 0.02 mm).

Around the solve (`fit_surface`):

- robust reweighting: Huber (k = 1.345) while refining, then Tukey's biweight (c = 4.685) on the
  final net, applied to each point's residual contrast (its signed distance minus the median of
  its 8 nearest neighbours' on the surface, `nearest_neighbours`), scale 1.4826 MAD, never below the tolerance: an isolated
  outlier is rejected, a coherent region the current net does not follow yet is not (it gets
  knots instead); points below half weight keep their parameters;
- parameter correction: after every solve each point takes `CORRECTION_STEPS` Gauss-Newton steps
  of Hoschek's correction (Hoschek 1988; P&T §9.4.1) from its current (u, v) onto the new fit;
  the final fit's feet by Newton point inversion (P&T §6.1, the kernel of `cadbridge.nurbs.project`),
  both in one compiled pass (`reproject`);
- knot insertion: a cell (knot span pair) whose deviation statistic exceeds the tolerance gets a
  knot in the middle of its u-span and/or v-span (the direction(s) along which its residuals vary),
  until no cell exceeds the tolerance ("tolerance") or the control net limit is reached
  ("control-net limit"); "no improvement" when a refinement no longer lowers the worst cell.
  The statistic is the cell's maximum distance for exact data; for noisy data (estimated noise
  sigma above tol/20, `estimate_noise`) it is, over the cell's 4 x 4 sub-cells, the largest
  |mean signed residual| less 3 sigma / sqrt(n): the fit's offset from the local mean of the data,
  i.e. its deviation from the measured surface, once the noise of that mean is allowed for.

All arrays are float64; points (N, 3) in model units, parameters (N,).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from cadbridge.nurbs.basis import ders_basis_funs, ders_basis_one, find_span, find_span_one, validate_knots
from cadbridge.nurbs.newton import newton_range
from cadbridge.nurbs.surface import NurbsSurface, d01_range

__all__ = [
    "FitError",
    "SurfaceFit",
    "bending_matrix",
    "cox_de_boor",
    "estimate_noise",
    "fit_surface",
    "gram_matrix",
    "nearest_neighbours",
    "reproject",
    "solve_control_points",
    "uniform_knots",
]

HUBER_K = 1.345  # Huber's constant (95 % efficiency at the normal distribution)
TUKEY_C = 4.685  # Tukey's biweight constant (95 % efficiency)
MAD_TO_SIGMA = 1.4826  # sigma = 1.4826 x median absolute deviation for normal data
# Gauss-Newton steps of the parameter correction after each solve (`reproject`); a point moves
# by its foot's shift on the changed fit, and two steps from its last foot reach the new one to
# well below the tolerance (the error of a step is about distance x curvature times the last)
CORRECTION_STEPS = 2


class FitError(ValueError):
    """Input the fit cannot work with (too few points, no data under control points, ...)."""


# ---------------------------------------------------------------------------- Cox-de Boor
def cox_de_boor(knots, p: int, u: float) -> np.ndarray:
    """All B-spline basis functions N_{i,k}(u), k = 0..p, i = 0..m, by the raw Cox-de Boor
    recursion (P&T eq. 2.5; Krohe 2020 eq. 13) on any knot vector t_0..t_m, clamped or not.

    Returns (p+1, m+1) with [k, i] = N_{i,k}(u), laid out as Krohe's Table 5.1:
    N_{i,0} = 1 on [t_i, t_{i+1}) and N_{m,0} = 1 for u >= t_m; a fraction with a zero
    denominator is 0 (0/0 := 0); a term that needs a knot beyond t_m is 0 (Krohe's "numerical
    approach"). Only entries with i + k + 1 <= m are true basis functions (they agree with
    P&T A2.2 inside the domain); the others are what that table lists for a knot vector that is
    one knot short.
    """
    t = np.asarray(knots, dtype=float)
    m = len(t) - 1
    out = np.zeros((p + 1, m + 1))
    for i in range(m):
        out[0, i] = 1.0 if t[i] <= u < t[i + 1] else 0.0
    out[0, m] = 1.0 if u >= t[m] else 0.0
    for k in range(1, p + 1):
        for i in range(m + 1):
            f = 0.0
            if i + k <= m and t[i + k] != t[i]:
                f = (u - t[i]) / (t[i + k] - t[i]) * out[k - 1, i]
            g = 0.0
            if i + k + 1 <= m and t[i + k + 1] != t[i + 1]:
                g = (t[i + k + 1] - u) / (t[i + k + 1] - t[i + 1]) * out[k - 1, i + 1]
            out[k, i] = f + g
    return out


def uniform_knots(p: int, n_spans: int, lo: float, hi: float) -> np.ndarray:
    """Clamped knot vector with ``n_spans`` equal spans over [lo, hi]: (n_spans + 2p + 1,)."""
    inner = np.linspace(lo, hi, n_spans + 1)
    return np.concatenate([np.full(p, lo), inner, np.full(p, hi)])


# ---------------------------------------------------------------------------- smoothing matrices
def gram_matrix(knots: np.ndarray, p: int, order: int) -> sp.csr_matrix:
    """Exact Gram matrix G_ij = integral of N_i^(r) N_j^(r) over the knot domain, r = ``order``:
    (n, n) sparse, bandwidth p. Gauss-Legendre with p+1 nodes per span (exact for degree 2p)."""
    knots = np.asarray(knots, dtype=float)
    n = len(knots) - p - 1
    xg, wg = np.polynomial.legendre.leggauss(p + 1)
    spans = np.arange(p, n)
    a, b = knots[spans], knots[spans + 1]
    keep = b > a
    spans, a, b = spans[keep], a[keep], b[keep]
    uq = (0.5 * (b - a)[:, None] * (xg[None, :] + 1.0) + a[:, None]).ravel()
    wq = (0.5 * (b - a)[:, None] * wg[None, :]).ravel()
    sq = np.repeat(spans, p + 1)
    if order > p:
        return sp.csr_matrix((n, n))
    d = ders_basis_funs(sq, uq, p, knots, order)[:, order, :]  # (Q, p+1)
    idx = sq[:, None] - p + np.arange(p + 1)
    rows = np.repeat(idx, p + 1, axis=1).ravel()
    cols = np.tile(idx, (1, p + 1)).ravel()
    vals = (wq[:, None, None] * d[:, :, None] * d[:, None, :]).ravel()
    return sp.csr_matrix((vals, (rows, cols)), shape=(n, n))


def bending_matrix(knots_u, p: int, knots_v, q: int) -> sp.csr_matrix:
    """Matrix G of the thin-plate energy E = sum_c P_c^T G P_c of a polynomial tensor-product
    surface (P_c one coordinate of the control net flattened i * nv + j): (nu*nv, nu*nv)."""
    mu, mv = gram_matrix(knots_u, p, 0), gram_matrix(knots_v, q, 0)
    d1u, d1v = gram_matrix(knots_u, p, 1), gram_matrix(knots_v, q, 1)
    d2u, d2v = gram_matrix(knots_u, p, 2), gram_matrix(knots_v, q, 2)
    g = sp.kron(d2u, mv) + 2.0 * sp.kron(d1u, d1v) + sp.kron(mu, d2v)
    return g.tocsr()


# ---------------------------------------------------------------------------- normal equations
@numba.njit(cache=True, error_model="numpy")
def _assemble_range(ku, kv, p, q, cw, u, v, x, w, band, rhs, start, stop):  # pragma: no cover - compiled
    """Accumulate A^T W A (banded: band[i, j, di + p, dj + q] couples control points (i, j) and
    (i + di, j + dj)) and A^T W X (rhs (nu, nv, 3)) over points start..stop-1. A's entries are
    the rational basis R_ab = Nu_a Nv_b cw_ab / sum Nu Nv cw (cw all ones: polynomial)."""
    nu, nv = cw.shape
    ndu_u = np.empty((p + 1, p + 1))
    ndu_v = np.empty((q + 1, q + 1))
    lu = np.empty(p + 1)
    ru = np.empty(p + 1)
    lv = np.empty(q + 1)
    rv = np.empty(q + 1)
    au = np.empty((2, p + 1))
    av = np.empty((2, q + 1))
    bu = np.empty((1, p + 1))
    bv = np.empty((1, q + 1))
    r = np.empty((p + 1, q + 1))
    for t in range(start, stop):
        wt = w[t]
        if wt == 0.0:
            continue
        su = find_span_one(ku, p, nu, u[t])
        sv = find_span_one(kv, q, nv, v[t])
        ders_basis_one(su, u[t], p, ku, 0, ndu_u, lu, ru, au, bu)
        ders_basis_one(sv, v[t], q, kv, 0, ndu_v, lv, rv, av, bv)
        i0 = su - p
        j0 = sv - q
        den = 0.0
        for a in range(p + 1):
            for b in range(q + 1):
                val = bu[0, a] * bv[0, b] * cw[i0 + a, j0 + b]
                r[a, b] = val
                den += val
        inv = 1.0 / den
        for a in range(p + 1):
            for b in range(q + 1):
                r[a, b] *= inv
        x0, x1, x2 = x[t, 0], x[t, 1], x[t, 2]
        for a in range(p + 1):
            for b in range(q + 1):
                ra = r[a, b] * wt
                rhs[i0 + a, j0 + b, 0] += ra * x0
                rhs[i0 + a, j0 + b, 1] += ra * x1
                rhs[i0 + a, j0 + b, 2] += ra * x2
                # the upper half only (offset (c - a, d - b) after (0, 0) in row-major order);
                # `_normal_equations` mirrors it (A^T W A is symmetric)
                for d in range(b, q + 1):
                    band[i0 + a, j0 + b, p, d - b + q] += ra * r[a, d]
                for c in range(a + 1, p + 1):
                    for d in range(q + 1):
                        band[i0 + a, j0 + b, c - a + p, d - b + q] += ra * r[c, d]


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _assemble_parallel(ku, kv, p, q, cw, u, v, x, w, bands, rhss):  # pragma: no cover - compiled
    n = u.shape[0]
    nt = bands.shape[0]
    step = (n + nt - 1) // nt
    for k in numba.prange(nt):
        _assemble_range(ku, kv, p, q, cw, u, v, x, w, bands[k], rhss[k], k * step, min(n, (k + 1) * step))


def _normal_equations(ku, kv, p, q, cw, u, v, x, w) -> tuple[sp.csr_matrix, np.ndarray]:
    """(A^T W A as (n, n) CSR, A^T W X as (n, 3)), n = nu * nv, index i * nv + j."""
    nu, nv = cw.shape
    nt = max(1, min(numba.get_num_threads(), 1 + len(u) // 50000))
    bands = np.zeros((nt, nu, nv, 2 * p + 1, 2 * q + 1))
    rhss = np.zeros((nt, nu, nv, 3))
    args = (np.ascontiguousarray(ku), np.ascontiguousarray(kv), int(p), int(q), np.ascontiguousarray(cw),
            np.ascontiguousarray(u), np.ascontiguousarray(v), np.ascontiguousarray(x), np.ascontiguousarray(w))
    if nt == 1:
        _assemble_range(*args, bands[0], rhss[0], 0, len(u))
    else:
        _assemble_parallel(*args, bands, rhss)
    band = bands.sum(axis=0)
    rhs = rhss.sum(axis=0).reshape(nu * nv, 3)
    # the lower half from the upper: entry (i, j; -di, -dj) = entry (i - di, j - dj; di, dj)
    for di in range(0, p + 1):
        for dj in range(-q, q + 1):
            if di == 0 and dj <= 0:
                continue
            # rows (i, j) with (i - di, j - dj) inside the net
            j_lo, j_hi = max(0, dj), min(nv, nv + dj)
            band[di:, j_lo:j_hi, p - di, q - dj] = band[: nu - di, j_lo - dj : j_hi - dj, p + di, q + dj]
    i, j, di, dj = np.meshgrid(np.arange(nu), np.arange(nv), np.arange(-p, p + 1), np.arange(-q, q + 1), indexing="ij")
    ii, jj = i + di, j + dj
    ok = (ii >= 0) & (ii < nu) & (jj >= 0) & (jj < nv)
    rows = (i * nv + j)[ok]
    cols = (ii * nv + jj)[ok]
    mat = sp.csr_matrix((band[ok], (rows, cols)), shape=(nu * nv, nu * nv))
    return mat, rhs


def solve_control_points(u, v, points, weights, knots_u, p: int, knots_v, q: int, *, ctrl_weights=None,
                         smoothing: float = 0.0, gram: sp.csr_matrix | None = None) -> np.ndarray:
    """Control points (nu, nv, 3) minimising sum w_k |S(u_k, v_k) - x_k|^2 + lam E (module doc).

    u, v (N,), points (N, 3), weights (N,) >= 0; ctrl_weights (nu, nv) fixed NURBS weights (None:
    polynomial); smoothing the dimensionless user weight (0: plain least squares, which needs data
    under every control point); gram an already built `bending_matrix`. Raises FitError when the
    system is singular (say where).
    """
    ku, kv = np.asarray(knots_u, dtype=float), np.asarray(knots_v, dtype=float)
    nu, nv = len(ku) - p - 1, len(kv) - q - 1
    cw = np.ones((nu, nv)) if ctrl_weights is None else np.asarray(ctrl_weights, dtype=float)
    mat, rhs = _normal_equations(ku, kv, p, q, cw, u, v, points, weights)
    if smoothing > 0.0:
        if gram is None:
            gram = bending_matrix(ku, p, kv, q)
        lam = smoothing * float(mat.diagonal().sum()) / max(float(gram.diagonal().sum()), 1e-300)
        mat = mat + lam * gram
    else:
        diag = mat.diagonal()
        empty = np.nonzero(diag <= 1e-14 * max(float(diag.max(initial=0.0)), 1e-300))[0]
        if empty.size:
            i, j = divmod(int(empty[0]), nv)
            raise FitError(f"{empty.size} of {nu * nv} control points have no data under them "
                           f"(first: ({i}, {j}) of {nu}x{nv}); give --smoothing > 0 or fewer control points")
    try:
        lu = spla.splu(mat.tocsc())
        sol = lu.solve(rhs)
    except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
        raise FitError(f"the least-squares system of the {nu}x{nv} control net is singular ({exc}); "
                       f"the points do not span the surface: give --smoothing > 0 or fewer control points") from None
    if not np.all(np.isfinite(sol)):
        raise FitError(f"the least-squares system of the {nu}x{nv} control net is singular: the points do not "
                       f"span the surface; give --smoothing > 0 or fewer control points")
    return sol.reshape(nu, nv, 3)


# ---------------------------------------------------------------------------- noise
@numba.njit(cache=True, error_model="numpy")
def _local_scales(pts, nbr, out):  # pragma: no cover - compiled
    """Robust noise scale per neighbourhood: quadratic height field h(a, b) in the PCA frame of
    each neighbourhood (rows of nbr), 1.4826 x median |residual| x sqrt(k / (k - 6))."""
    k = nbr.shape[1]
    a = np.empty((k, 6))
    h = np.empty(k)
    loc = np.empty((k, 3))
    for s in range(nbr.shape[0]):
        c0 = 0.0
        c1 = 0.0
        c2 = 0.0
        for j in range(k):
            c0 += pts[nbr[s, j], 0]
            c1 += pts[nbr[s, j], 1]
            c2 += pts[nbr[s, j], 2]
        c0 /= k
        c1 /= k
        c2 /= k
        for j in range(k):
            loc[j, 0] = pts[nbr[s, j], 0] - c0
            loc[j, 1] = pts[nbr[s, j], 1] - c1
            loc[j, 2] = pts[nbr[s, j], 2] - c2
        cov = loc.T @ loc
        _, vec = np.linalg.eigh(cov)  # ascending: vec[:, 0] is the normal
        proj = loc @ vec
        for j in range(k):
            x = proj[j, 2]
            y = proj[j, 1]
            a[j, 0] = 1.0
            a[j, 1] = x
            a[j, 2] = y
            a[j, 3] = x * x
            a[j, 4] = x * y
            a[j, 5] = y * y
            h[j] = proj[j, 0]
        coef = np.linalg.lstsq(a, h)[0]
        res = np.abs(h - a @ coef)
        out[s] = MAD_TO_SIGMA * np.median(res) * math.sqrt(k / (k - 6.0))


def estimate_noise(points: np.ndarray, k: int = 12, sample: int = 20000, seed: int = 0) -> float:
    """Noise sigma of scattered surface points from the data alone: median over up to ``sample``
    points of the robust scale of a local quadratic fit to their k nearest neighbours (curvature
    does not bias it; isolated outliers do not either). Model units; ~0 for exact data."""
    from scipy.spatial import cKDTree

    pts = np.asarray(points, dtype=float)
    if len(pts) < k + 1:
        return 0.0
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(pts), size=min(sample, len(pts)), replace=False)
    tree = cKDTree(pts, balanced_tree=False, compact_nodes=False)  # half the build time; same neighbours
    _, nbr = tree.query(pts[pick], k=k, workers=-1)
    out = np.empty(len(pick))
    _local_scales(pts, np.ascontiguousarray(nbr, dtype=np.int64), out)
    return float(np.median(out))


# ---------------------------------------------------------------------------- the fit
@dataclass
class SurfaceFit:
    """Result of `fit_surface` for N points.

    surface    the fitted NurbsSurface
    u, v       (N,) final parameters (feet of the points on the fit)
    distance   (N,) |x - S(u, v)| after the last parameter correction, model units
    signed     (N,) (x - S) . n, n the unit normal of the fit at the foot
    weight     (N,) final robust weight in [0, 1] (0: outlier, ignored by the fit)
    stop       "tolerance", "control-net limit" or "no improvement"
    tolerance, noise   the tolerance and the noise sigma used (model units)
    history    one dict per refinement level: ctrl (nu, nv), max, rms, worst cell statistic
    """

    surface: NurbsSurface
    u: np.ndarray
    v: np.ndarray
    distance: np.ndarray
    signed: np.ndarray
    weight: np.ndarray
    stop: str
    tolerance: float
    noise: float
    history: list[dict] = field(default_factory=list)

    @property
    def outliers(self) -> np.ndarray:
        """(N,) bool: points the robust reweighting set to weight 0."""
        return self.weight <= 0.0

    @property
    def max_deviation(self) -> float:
        return float(self.distance.max())

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.distance**2)))

    def inlier_stats(self) -> tuple[float, float]:
        """(max, rms) distance over the points that are not outliers."""
        d = self.distance[~self.outliers]
        return (float(d.max()), float(np.sqrt(np.mean(d**2)))) if d.size else (0.0, 0.0)


_CORRECT_BLOCK = 2048  # points per task of the parallel correction kernel


@numba.njit(cache=True, error_model="numpy")
def _residual_at(der, k, px, py, pz):  # pragma: no cover - compiled
    """(|x - S|, (x - S) . unit Su x Sv, or the distance where the normal is undefined) from
    der[k] = (S, Sv; Su, Suv) of `d01_range`."""
    rx, ry, rz = px - der[k, 0, 0, 0], py - der[k, 0, 0, 1], pz - der[k, 0, 0, 2]
    d = np.sqrt(rx * rx + ry * ry + rz * rz)
    sux, suy, suz = der[k, 1, 0, 0], der[k, 1, 0, 1], der[k, 1, 0, 2]
    svx, svy, svz = der[k, 0, 1, 0], der[k, 0, 1, 1], der[k, 0, 1, 2]
    nx = suy * svz - suz * svy
    ny = suz * svx - sux * svz
    nz = sux * svy - suy * svx
    ln = np.sqrt(nx * nx + ny * ny + nz * nz)
    s = (rx * nx + ry * ny + rz * nz) / ln if ln > 0.0 else np.nan
    return d, (s if np.isfinite(s) else d)


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _correct_kernel(pw, ku, kv, p, q, rational, u0, u1, v0, v1, eps1, eps2, pts, noise, u, v, near, movable, edge,
                    max_iter, steps, dist, signed, moved):  # pragma: no cover - compiled
    """Parameter correction and residuals in one pass over the points (`reproject`).

    Point t with movable[t] and |x_t - S(u_t, v_t)| <= near (near < 0: no correction) gets, with
    steps = 0, the projected Newton iterations of `cadbridge.nurbs.project` (`nurbs.newton.newton_range`, the
    kernel of `project_to_surface`) from its (u_t, v_t), and the new foot is taken (moved[t] =
    True) if it passes that module's orthogonality check and is not farther than the old one;
    with steps > 0, that many Gauss-Newton steps of Hoschek's parameter correction (Hoschek 1988;
    P&T §9.4.1): [Su.Su Su.Sv; Su.Sv Sv.Sv] (du, dv) = ((x - S).Su, (x - S).Sv), clamped to the
    domain, along the free direction only for a point on an edge, taken if not farther. A taken
    foot with
    edge flags (bits 1, 2, 4, 8: u = u0, u1, v = v0, v1) is put back on its edge. Then
    dist[t] = |x - S|, signed[t] = (x - S) . Su x Sv / |Su x Sv| (dist where the normal is
    undefined), S and its first derivatives by `NurbsSurface.derivatives`' kernel (`d01_range`)."""
    n = pts.shape[0]
    nblk = (n + _CORRECT_BLOCK - 1) // _CORRECT_BLOCK
    for blk in numba.prange(nblk):
        a = blk * _CORRECT_BLOCK
        b = min(n, a + _CORRECT_BLOCK)
        m = b - a
        der = np.empty((m, 2, 2, 3))
        d01_range(pw, ku, kv, p, q, 1, rational, u[a:b], v[a:b], der, 0, m)
        for k in range(m):
            dist[a + k], signed[a + k] = _residual_at(der, k, pts[a + k, 0], pts[a + k, 1], pts[a + k, 2])
        if near < 0.0:
            continue
        # the block's points to correct, gathered for one `newton_range` call
        idx = np.empty(m, dtype=np.int64)
        pb = np.empty((m, 3))
        eb = np.empty(m)
        ub = np.empty(m)
        vb = np.empty(m)
        itb = np.zeros(m, dtype=np.int32)
        same = np.zeros(1, dtype=np.bool_)
        c = 0
        for t in range(a, b):
            if movable[t] and dist[t] <= near:
                idx[c] = t
                pb[c, 0], pb[c, 1], pb[c, 2] = pts[t, 0], pts[t, 1], pts[t, 2]
                eb[c] = noise[t]
                ub[c] = u[t]
                vb[c] = v[t]
                if steps > 0:
                    der[c] = der[t - a]  # c <= t - a: rows are moved forward only
                c += 1
        if c == 0:
            continue
        if steps == 0:
            newton_range(pw, ku, kv, p, q, rational, u0, u1, v0, v1, False, False, eps1, eps2, pb, eb, ub, vb,
                         itb, max_iter, 0, c, ub, vb, -1.0, -1.0, same)
        else:
            for _ in range(steps):
                for k in range(c):
                    rx, ry, rz = pb[k, 0] - der[k, 0, 0, 0], pb[k, 1] - der[k, 0, 0, 1], pb[k, 2] - der[k, 0, 0, 2]
                    sux, suy, suz = der[k, 1, 0, 0], der[k, 1, 0, 1], der[k, 1, 0, 2]
                    svx, svy, svz = der[k, 0, 1, 0], der[k, 0, 1, 1], der[k, 0, 1, 2]
                    ee = sux * sux + suy * suy + suz * suz
                    ff = sux * svx + suy * svy + suz * svz
                    gg = svx * svx + svy * svy + svz * svz
                    fu = rx * sux + ry * suy + rz * suz
                    fv = rx * svx + ry * svy + rz * svz
                    e = edge[idx[k]]
                    fix_u = (e & 3) != 0
                    fix_v = (e & 12) != 0
                    du = 0.0
                    dv = 0.0
                    if fix_u and not fix_v:
                        dv = fv / gg if gg > 0.0 else 0.0
                    elif fix_v and not fix_u:
                        du = fu / ee if ee > 0.0 else 0.0
                    elif not fix_u:
                        det = ee * gg - ff * ff
                        if det > 1e-14 * ee * gg:
                            du = (gg * fu - ff * fv) / det
                            dv = (ee * fv - ff * fu) / det
                    ub[k] = min(max(ub[k] + du, u0), u1)
                    vb[k] = min(max(vb[k] + dv, v0), v1)
                d01_range(pw, ku, kv, p, q, 1, rational, ub, vb, der, 0, c)
        if steps == 0:
            d01_range(pw, ku, kv, p, q, 1, rational, ub, vb, der, 0, c)
        clamped = 0
        for k in range(c):
            t = idx[k]
            un, vn = ub[k], vb[k]
            rx, ry, rz = der[k, 0, 0, 0] - pb[k, 0], der[k, 0, 0, 1] - pb[k, 1], der[k, 0, 0, 2] - pb[k, 2]
            dn = np.sqrt(rx * rx + ry * ry + rz * rz)
            f = der[k, 1, 0, 0] * rx + der[k, 1, 0, 1] * ry + der[k, 1, 0, 2] * rz
            g = der[k, 0, 1, 0] * rx + der[k, 0, 1, 1] * ry + der[k, 0, 1, 2] * rz
            lsu = np.sqrt(der[k, 1, 0, 0] ** 2 + der[k, 1, 0, 1] ** 2 + der[k, 1, 0, 2] ** 2)
            lsv = np.sqrt(der[k, 0, 1, 0] ** 2 + der[k, 0, 1, 1] ** 2 + der[k, 0, 1, 2] ** 2)
            edge_u = (un <= u0 and f > 0) or (un >= u1 and f < 0)
            edge_v = (vn <= v0 and g > 0) or (vn >= v1 and g < 0)
            off_u = 0.0 if edge_u else abs(f) / max(lsu, 1e-300)
            off_v = 0.0 if edge_v else abs(g) / max(lsv, 1e-300)
            ok = steps > 0 or max(off_u, off_v) <= 1e3 * eps1 + eb[k]
            if not (ok and np.isfinite(dn) and np.isfinite(un) and np.isfinite(vn) and dn <= dist[t]):
                continue
            moved[t] = True
            e = edge[t]
            uc = u0 if e & 1 else (u1 if e & 2 else un)
            vc = v0 if e & 4 else (v1 if e & 8 else vn)
            u[t] = uc
            v[t] = vc
            if uc != un or vc != vn:  # back on its edge: residuals evaluated there below
                idx[clamped] = t
                ub[clamped] = uc
                vb[clamped] = vc
                clamped += 1
            else:
                dist[t], signed[t] = _residual_at(der, k, pb[k, 0], pb[k, 1], pb[k, 2])
        if clamped:
            d01_range(pw, ku, kv, p, q, 1, rational, ub, vb, der, 0, clamped)
            for k in range(clamped):
                t = idx[k]
                dist[t], signed[t] = _residual_at(der, k, pts[t, 0], pts[t, 1], pts[t, 2])


def reproject(surface: NurbsSurface, points: np.ndarray, u, v, *, near: float = np.inf, movable=None, edge=None,
              tol: float = 1e-10, max_iter: int = 12, steps: int = 0
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points (N, 3) projected onto ``surface`` by Newton from their parameters u, v (N,), in one
    compiled parallel pass (`_correct_kernel`: the iterations of `cadbridge.nurbs.project`,
    P&T §6.1, its orthogonality check; a foot farther than the start is not taken).

    Only points within ``near`` of S(u, v) and ``movable`` ((N,) bool, None: all) are moved
    (near < 0: none, residuals only); edge (N,) uint8 flags (1, 2, 4, 8: u = u0, u1, v = v0, v1)
    keep parameters on the domain edges. Returns (u, v, dist, signed, moved), each (N,): the new
    parameters, |x - S|, (x - S) . unit Su x Sv (dist where the normal is undefined), and which
    points were moved. The inputs are not modified. No global search: the start must lie in the
    basin of the foot (a fit from its own points' parameters, a nearest sample of a base).
    steps > 0: instead of Newton to convergence (tol, max_iter), that many Gauss-Newton steps of
    Hoschek's parameter correction (first derivatives only; a fraction of Newton's cost, and
    what a fit that re-corrects after every solve needs).
    """
    x = np.asarray(points, dtype=float)
    n = len(x)
    u = np.array(u, dtype=float).ravel()
    v = np.array(v, dtype=float).ravel()
    dist, signed, moved = np.empty(n), np.empty(n), np.zeros(n, dtype=np.bool_)
    if n == 0:
        return u, v, dist, signed, moved
    pts = np.ascontiguousarray(x)
    size = max(float(np.linalg.norm(np.ptp(surface.control_points.reshape(-1, 3), axis=0))), 1e-300)
    noise = 64.0 * np.finfo(float).eps * (np.max(np.abs(pts), axis=1) + size)
    mv = np.ones(n, dtype=np.bool_) if movable is None else np.ascontiguousarray(movable, dtype=np.bool_)
    ed = np.zeros(n, dtype=np.uint8) if edge is None else np.ascontiguousarray(edge, dtype=np.uint8)
    u0, u1, v0, v1 = surface.domain
    u = np.clip(u, u0, u1)
    v = np.clip(v, v0, v1)
    _correct_kernel(surface._pw, surface.knots_u, surface.knots_v, surface.degree_u, surface.degree_v,
                    surface.rational, float(u0), float(u1), float(v0), float(v1), tol * size, tol, pts, noise, u, v,
                    float(min(near, 1e300)), mv, ed, int(max_iter), int(steps), dist, signed, moved)
    return u, v, dist, signed, moved


def _correct(surf: NurbsSurface, x: np.ndarray, u: np.ndarray, v: np.ndarray, *, near: float = -1.0,
             movable: np.ndarray | None = None, edge: np.ndarray | None = None, steps: int = 0
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, dist, signed) of `reproject` (default: residuals only)."""
    return reproject(surf, x, u, v, near=near, movable=movable, edge=edge, steps=steps)[:4]


def _residuals(surf: NurbsSurface, x: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distances |x - S(u, v)| (N,) and signed distances (x - S) . n (N,), n = Su x Sv / |.|
    (the distance where the normal is undefined), one compiled pass."""
    return _correct(surf, x, u, v)[2:]


@numba.njit(cache=True, parallel=True)
def _median_contrast(r, nbr, out):  # pragma: no cover - compiled
    """out[i] = r[i] - median(r[nbr[i, :]]) (insertion sort of the few neighbours)."""
    k = nbr.shape[1]
    for i in numba.prange(r.shape[0]):
        buf = np.empty(k)
        for j in range(k):
            val = r[nbr[i, j]]
            m = j
            while m > 0 and buf[m - 1] > val:
                buf[m] = buf[m - 1]
                m -= 1
            buf[m] = val
        med = buf[k // 2] if k % 2 == 1 else 0.5 * (buf[k // 2 - 1] + buf[k // 2])
        out[i] = r[i] - med


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _knn_cells(xy, k, x0, y0, h, gx, gy, start, order, out):  # pragma: no cover - compiled
    """k nearest other points of every point into out (N, k), nearest first, from a uniform grid
    of cells of size h (gx x gy); xy (N, 2) sorted by cell (cell c: rows start[c]:start[c + 1]),
    order[row] the point's index. The square of cells around a point grows until the k-th
    distance found is within the square, i.e. no point outside it can be nearer (exact)."""
    for c in numba.prange(gx * gy):
        ci = c // gy
        cj = c % gy
        bd = np.empty(k)
        bi = np.empty(k, dtype=np.int64)
        for s in range(start[c], start[c + 1]):
            t = order[s]
            px, py = xy[s, 0], xy[s, 1]
            for j in range(k):
                bd[j] = np.inf
                bi[j] = -1
            r = 0
            while True:
                # the ring of cells at Chebyshev distance r from (ci, cj)
                for a in range(ci - r, ci + r + 1):
                    if a < 0 or a >= gx:
                        continue
                    step = 1 if (a == ci - r or a == ci + r) else 2 * r
                    b = cj - r
                    while b <= cj + r:
                        if 0 <= b < gy:
                            cc = a * gy + b
                            for s2 in range(start[cc], start[cc + 1]):
                                o = order[s2]
                                if o == t:
                                    continue
                                dx = xy[s2, 0] - px
                                dy = xy[s2, 1] - py
                                d = dx * dx + dy * dy
                                if d < bd[k - 1] or (d == bd[k - 1] and o < bi[k - 1]):
                                    m = k - 1
                                    while m > 0 and (bd[m - 1] > d or (bd[m - 1] == d and bi[m - 1] > o)):
                                        bd[m] = bd[m - 1]
                                        bi[m] = bi[m - 1]
                                        m -= 1
                                    bd[m] = d
                                    bi[m] = o
                        b += step if step > 0 else 1
                # nearest distance from the point to anything outside the searched square
                lo = min(px - (x0 + (ci - r) * h), (x0 + (ci + r + 1) * h) - px,
                         py - (y0 + (cj - r) * h), (y0 + (cj + r + 1) * h) - py)
                if bi[k - 1] >= 0 and bd[k - 1] <= lo * lo:
                    break
                if ci - r <= 0 and cj - r <= 0 and ci + r >= gx - 1 and cj + r >= gy - 1:
                    break  # the whole grid searched
                r += 1
            for j in range(k):
                out[t, j] = bi[j]


def nearest_neighbours(xy: np.ndarray, k: int) -> np.ndarray:
    """Indices (N, k) (int32 below 2^31 points) of the k nearest other points of each point of xy (N, 2) (2D, Euclidean),
    nearest first, ties by index: a uniform cell grid (about 3 points per cell) searched outward
    until no nearer point can remain (exact; what cKDTree.query gives, without the point itself).
    k is capped at N - 1."""
    xy = np.ascontiguousarray(xy, dtype=float)
    n = len(xy)
    k = min(int(k), n - 1)
    if k <= 0:
        return np.empty((n, 0), dtype=np.int32)
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    w = np.maximum(hi - lo, 1e-300)
    area = float(w[0] * w[1])
    h = math.sqrt(area / max(n / 3.0, 1.0))
    h = max(h, float(w.max()) / max(n / 3.0, 1.0), 1e-300)  # points (nearly) on a line in (u, v)
    gx = int(w[0] / h) + 1
    gy = int(w[1] / h) + 1
    cell = np.minimum(((xy[:, 0] - lo[0]) / h).astype(np.int64), gx - 1) * gy + np.minimum(
        ((xy[:, 1] - lo[1]) / h).astype(np.int64), gy - 1)
    order = np.argsort(cell, kind="stable")
    start = np.zeros(gx * gy + 1, dtype=np.int64)
    np.cumsum(np.bincount(cell, minlength=gx * gy), out=start[1:])
    out = np.empty((n, k), dtype=np.int32 if n < 2**31 else np.int64)  # 4 bytes per index suffice
    _knn_cells(np.ascontiguousarray(xy[order]), int(k), float(lo[0]), float(lo[1]), h, gx, gy, start, order, out)
    return out


def _robust_weights(r: np.ndarray, kind: str, floor: float) -> np.ndarray:
    """Huber or Tukey weights of residuals r (N,) with scale 1.4826 MAD (at least ``floor``)."""
    s = max(MAD_TO_SIGMA * float(np.median(np.abs(r))), floor, 1e-300)
    z = np.abs(r) / s
    if kind == "huber":
        return np.minimum(1.0, HUBER_K / np.maximum(z, 1e-300))
    if kind == "tukey":
        t = z / TUKEY_C
        return np.where(t < 1.0, (1.0 - t * t) ** 2, 0.0)
    raise ValueError(f"robust must be 'tukey', 'huber' or None, got {kind!r}")


def _cell_statistic(cell: np.ndarray, d: np.ndarray, q: float, n_cells: int) -> np.ndarray:
    """Per cell (flat index, N,) the q-quantile of d (N,) (q = 1: the maximum); -inf if empty."""
    out = np.full(n_cells, -np.inf)
    if q >= 1.0:
        np.maximum.at(out, cell, d)
        return out
    order = np.lexsort((d, cell))
    cs, ds = cell[order], d[order]
    starts = np.flatnonzero(np.r_[True, cs[1:] != cs[:-1]])
    counts = np.diff(np.r_[starts, len(cs)])
    pick = starts + np.floor(q * (counts - 1)).astype(np.int64)
    out[cs[starts]] = ds[pick]
    return out


def _variation(cell, bins, r, n_cells) -> np.ndarray:
    """Variance over 4 bins (along one direction inside each cell) of the bins' mean residual."""
    key = cell * 4 + bins
    cnt = np.bincount(key, minlength=4 * n_cells).reshape(n_cells, 4)
    sm = np.bincount(key, weights=r, minlength=4 * n_cells).reshape(n_cells, 4)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cnt > 0, sm / np.maximum(cnt, 1), np.nan)
    ok = cnt > 0
    tot = np.maximum(ok.sum(axis=1), 1)
    mu = np.nansum(mean, axis=1) / tot
    var = np.nansum(np.where(ok, (mean - mu[:, None]) ** 2, 0.0), axis=1) / tot
    # fewer than 3 occupied bins: the variation along this direction is unknown (data too sparse
    # to tell), which must not send the knots the other way
    return np.where(ok.sum(axis=1) >= 3, var, np.inf)


@dataclass
class _FitRun:
    """What the stages of one `fit_surface` call share: the points, the options, and the state
    kept across solves. N points; lengths in model units."""

    x: np.ndarray  # (N, 3) points
    pw_user: np.ndarray  # (N,) point weights >= 0
    p: int  # degrees
    q: int
    base: NurbsSurface | None  # the rational base on the fit's domain; knots inserted as the fit refines
    tolerance: float
    smoothing: float
    robust: str | None
    correct_parameters: bool
    refine: bool
    rational_base: NurbsSurface | None  # as given (the subset fit starts from it again)
    max_ctrl: tuple[int, int]
    max_levels: int
    robust_iterations: int
    max_points_per_level: int
    project_final: bool
    progress: object
    sigma: float  # noise sigma of the data
    u0_par: np.ndarray  # (N,) start parameters, clipped into the domain
    v0_par: np.ndarray
    edge: np.ndarray  # (N,) uint8 domain-edge flags of the start parameters (1, 2, 4, 8: u0, u1, v0, v1)
    first_surf: NurbsSurface | None = None  # the first fit: scales the (u, v) of the neighbour search
    nbr: np.ndarray | None = None  # (N, k) nearest neighbours of each point, on first use
    weighted: bool = False  # robust weights exist: points may get corrected parameters
    done: bool = False  # the final reweighting ran on the current net

    @property
    def n(self) -> int:
        return len(self.x)

    @property
    def noisy(self) -> bool:
        return self.sigma > 0.05 * self.tolerance

    @property
    def near(self) -> float:
        """Parameters are corrected only on a fit this close (model units)."""
        return 10.0 * self.tolerance + 5.0 * self.sigma

    def stage(self, text: str) -> None:
        report = getattr(self.progress, "stage", None)
        if report:
            report(text)


def _check_inputs(points, u, v, tolerance: float, smoothing: float, point_weights
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Validated copies: points (N, 3), u, v (N,), point weights (N,); FitError otherwise."""
    x = np.asarray(points, dtype=float)
    if x.ndim != 2 or x.shape[1] != 3:
        raise FitError(f"points must have shape (N, 3), got {x.shape}")
    u = np.array(u, dtype=float).ravel()
    v = np.array(v, dtype=float).ravel()
    n = len(x)
    if len(u) != n or len(v) != n:
        raise FitError(f"{n} points but {len(u)} u and {len(v)} v parameters")
    bad = ~(np.isfinite(x).all(axis=1) & np.isfinite(u) & np.isfinite(v))
    if bad.any():
        k = int(np.argmax(bad))
        raise FitError(f"{int(bad.sum())} points or parameters are not finite (first: point {k}, 0-based)")
    if not tolerance > 0:
        raise FitError(f"tolerance must be > 0, got {tolerance}")
    if smoothing < 0:
        raise FitError(f"smoothing must be >= 0, got {smoothing}")
    pw_user = np.ones(n) if point_weights is None else np.asarray(point_weights, dtype=float).ravel()
    if pw_user.shape != (n,) or not np.all(np.isfinite(pw_user)) or np.any(pw_user < 0):
        raise FitError("point_weights must be (N,) finite and >= 0")
    return x, u, v, pw_user


def _start_net(n: int, u: np.ndarray, v: np.ndarray, degree: tuple[int, int], knots, initial_spans,
               max_ctrl: tuple[int, int], rational_base: NurbsSurface | None, domain
               ) -> tuple[int, int, NurbsSurface | None, np.ndarray, np.ndarray, tuple]:
    """Degrees, rational base (restricted to ``domain``; None for a polynomial fit), start knot
    vectors and domain (u0, u1, v0, v1) of a fit of n points with parameters u, v (N,)."""
    if rational_base is not None:
        p, q = rational_base.degree_u, rational_base.degree_v
        from cadbridge.nurbs.edits import restrict_surface

        base = restrict_surface(rational_base, domain) if domain is not None else restrict_surface(rational_base)
        ku, kv = base.knots_u.copy(), base.knots_v.copy()
        dom = (ku[p], ku[-p - 1], kv[q], kv[-q - 1])
    else:
        p, q = (int(degree[0]), int(degree[1]))
        base = None
        if domain is None:
            span_u, span_v = float(np.ptp(u)), float(np.ptp(v))
            if not (span_u > 0 and span_v > 0):
                raise FitError("the point parameters span no area (all points on one iso-line of the base): "
                               "are the points collinear?")
            dom = (float(u.min()), float(u.max()), float(v.min()), float(v.max()))
        else:
            dom = tuple(float(t) for t in domain)
        if knots is not None:
            ku, kv = (np.asarray(k, dtype=float) for k in knots)
        else:
            lu_, lv_ = dom[1] - dom[0], dom[3] - dom[2]
            if initial_spans is None:
                s = 4
                initial_spans = (max(1, round(s * lu_ / max(lu_, lv_))), max(1, round(s * lv_ / max(lu_, lv_))))
            ku = uniform_knots(p, int(initial_spans[0]), dom[0], dom[1])
            kv = uniform_knots(q, int(initial_spans[1]), dom[2], dom[3])
    validate_knots(ku, p, len(ku) - p - 1, "knots_u")
    validate_knots(kv, q, len(kv) - q - 1, "knots_v")
    dom = (ku[p], ku[-p - 1], kv[q], kv[-q - 1])
    nu, nv = len(ku) - p - 1, len(kv) - q - 1
    if n < nu * nv:
        raise FitError(f"{n} points are fewer than the {nu}x{nv} = {nu * nv} control points of the start net")
    if nu > max_ctrl[0] or nv > max_ctrl[1]:
        raise FitError(f"the start net {nu}x{nv} exceeds the control net limit {max_ctrl[0]}x{max_ctrl[1]}")
    return p, q, base, ku, kv, dom


def _correct_on(run: _FitRun, surf: NurbsSurface, u: np.ndarray, v: np.ndarray, movable: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Foot parameters, distances and signed distances (each (N,)) of all points on surf (one
    compiled pass, `_correct`: `CORRECTION_STEPS` Gauss-Newton steps of Hoschek's correction).
    Only points within ``run.near`` of the fit (and ``movable``, (N,) bool) get corrected
    parameters: on a coarse fit that cuts a corner, projection would slide the points along it
    and spoil a good base parametrisation. Points on the domain's edge stay on it (else they
    slide inward and the fit's edge floats past the data: 0.006 mm at the end of an FE-node die
    strip)."""
    if not run.correct_parameters:
        return (u, v) + _residuals(surf, run.x, u, v)
    return _correct(surf, run.x, u, v, near=run.near, movable=movable, edge=run.edge, steps=CORRECTION_STEPS)


def _contrast(run: _FitRun, r: np.ndarray) -> np.ndarray:
    """Residuals r (N,) less the median of each point's 8 nearest neighbours' on the surface.

    The residual a point is judged by: an isolated outlier stands out, a region the fit does
    not follow yet (a radius on a coarse net) does not, and is refined instead of rejected.
    Neighbours in (u, v) scaled by the mean |S_u|, |S_v| of the first fit (lengths)."""
    if run.nbr is None:
        gu, gv = run.first_surf.grid(12, 12)
        der = run.first_surf.derivatives(gu, gv, order=1)
        su = float(np.mean(np.linalg.norm(der[:, 1, 0], axis=1))) or 1.0
        sv = float(np.mean(np.linalg.norm(der[:, 0, 1], axis=1))) or 1.0
        run.stage(f"neighbours of {run.n} points")
        run.nbr = nearest_neighbours(np.column_stack([run.u0_par * su, run.v0_par * sv]), min(8, run.n - 1))
    nbr = run.nbr
    if not nbr.shape[1]:
        return r
    out = np.empty(run.n)
    _median_contrast(np.ascontiguousarray(r, dtype=float), nbr, out)
    return out


def _final_projection(run: _FitRun, surf: NurbsSurface, u: np.ndarray, v: np.ndarray, dist: np.ndarray,
                      signed: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every point projected onto the final fit for the reported deviations: the point
    inversion of `cadbridge.nurbs.project` (its Newton kernel and orthogonality check, as
    `project_to_surface` from given start parameters) from its parameters, tol 1e-12, in one
    compiled pass (`reproject`). Returns (u, v, dist, signed), each (N,); unchanged inputs when
    ``run.project_final`` is False."""
    if not run.project_final:
        return u, v, dist, signed
    run.stage(f"projecting all {run.n} points onto the fit")
    return reproject(surf, run.x, u, v, tol=1e-12, max_iter=30)[:4]


def _solve(run: _FitRun, ku: np.ndarray, kv: np.ndarray, rob_w: np.ndarray, u: np.ndarray, v: np.ndarray,
           text: str, correct_now: bool = True
           ) -> tuple[NurbsSurface, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The control points on knots (ku, kv) for the points at parameters u, v (N,) with weights
    point weight x rob_w (N,), then the parameter correction on the new fit (`_correct_on`;
    without correct_now only the residuals). Returns (surface, u, v, dist, signed)."""
    p, q = run.p, run.q
    nu, nv = len(ku) - p - 1, len(kv) - q - 1
    gram = bending_matrix(ku, p, kv, q) if run.smoothing > 0 else None
    cw = run.base.weights if run.base is not None else None
    run.stage(f"{nu}x{nv} control points: {text}")
    cp = solve_control_points(u, v, run.x, run.pw_user * rob_w, ku, p, kv, q, ctrl_weights=cw,
                              smoothing=run.smoothing, gram=gram)
    surf = NurbsSurface(p, q, ku, kv, cp, cw if run.base is not None else None)
    if run.first_surf is None:
        run.first_surf = surf
    if not correct_now:
        return (surf, u, v) + _residuals(surf, run.x, u, v)
    # a point the reweighting distrusts keeps its parameters: an outlier that slid onto the
    # bump it pulled would look like an inlier and keep the bump (no correction before the
    # first weights exist, for the same reason)
    if run.robust is not None and not run.weighted:
        run.weighted = True
        return (surf,) + _correct_on(run, surf, u, v, np.zeros(run.n, dtype=bool))
    return (surf,) + _correct_on(run, surf, u, v, None if run.robust is None else rob_w >= 0.5)


def _finish_robust(run: _FitRun, ku: np.ndarray, kv: np.ndarray, rob_w: np.ndarray, u: np.ndarray, v: np.ndarray,
                   surf: NurbsSurface, dist: np.ndarray, signed: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, NurbsSurface, np.ndarray, np.ndarray]:
    """IRLS on the final net: Huber until the weights settle, then Tukey (module doc). Returns
    (rob_w, u, v, surface, dist, signed), arrays (N,)."""
    kinds = ["huber"] * run.robust_iterations + (["tukey"] * run.robust_iterations if run.robust == "tukey" else [])
    phase = None
    for it, kind in enumerate(kinds):
        if kind != phase:
            phase, settled = kind, False
        elif settled:
            continue
        new_w = _robust_weights(_contrast(run, signed), kind, run.tolerance)
        settled = np.max(np.abs(new_w - rob_w)) < 1e-2 and it > 0
        rob_w = new_w
        surf, u, v, dist, signed = _solve(run, ku, kv, rob_w, u, v, f"robust iteration {it + 1} ({kind})")
    return rob_w, u, v, surf, dist, signed


def _fit_subset_then_all(run: _FitRun, ku: np.ndarray, kv: np.ndarray, u: np.ndarray, v: np.ndarray,
                         dom: tuple) -> SurfaceFit:
    """`fit_surface` of more than ``max_points_per_level`` points: knots from a random subset
    (a net of at most max_ctrl needs far fewer points than a dense scan has), then the final
    net solved on all points: parameters of all points corrected onto the subset's fit, weights
    from their residuals, two more solves. No further correction between them: the net is the
    subset's, its solution moves by the subset's sampling error (~sigma / sqrt(points per
    control point), microns), and the final projection puts every point on the final fit
    anyway. u, v (N,) are updated in place with the subset's feet."""
    x, n, p, q, robust, tolerance = run.x, run.n, run.p, run.q, run.robust, run.tolerance
    rng = np.random.default_rng(0)
    sub = np.sort(rng.choice(n, size=run.max_points_per_level, replace=False))
    f0 = fit_surface(x[sub], u[sub], v[sub], degree=(p, q), tolerance=tolerance, knots=(ku, kv),
                     max_ctrl=run.max_ctrl, smoothing=run.smoothing, robust=robust,
                     correct_parameters=run.correct_parameters, refine=True, rational_base=run.rational_base,
                     domain=dom, noise=run.sigma, point_weights=run.pw_user[sub], max_levels=run.max_levels,
                     robust_iterations=run.robust_iterations, max_points_per_level=run.max_points_per_level,
                     project_final=False, progress=run.progress)
    ku, kv = f0.surface.knots_u, f0.surface.knots_v
    if run.base is not None:
        from cadbridge.nurbs.edits import refine_surface

        extra_u = [t for t in ku[p + 1 : -p - 1] if t not in run.base.knots_u]
        extra_v = [t for t in kv[q + 1 : -q - 1] if t not in run.base.knots_v]
        run.base = refine_surface(run.base, extra_u, extra_v)
    u[sub], v[sub] = f0.u, f0.v
    run.weighted = True
    run.first_surf = f0.surface
    u, v, dist, signed = _correct_on(run, f0.surface, u, v)
    history = [dict(h, subset=len(sub)) for h in f0.history]
    rob_w = np.ones(n)
    n_full = 2 if robust is not None else 1
    for it in range(n_full):
        if robust is not None:
            rob_w = _robust_weights(_contrast(run, signed), robust, tolerance)
        surf, u, v, dist, signed = _solve(run, ku, kv, rob_w, u, v, f"all {n} points, solve {it + 1}",
                                          correct_now=False)
    if robust is not None:
        rob_w = _robust_weights(_contrast(run, signed), robust, tolerance)
    history.append(dict(ctrl=surf.shape, max=float(dist.max()), rms=float(np.sqrt(np.mean(dist**2))),
                        worst_cell=float("nan"), outliers=int(np.count_nonzero(rob_w <= 0)) if robust else 0))
    final_w = rob_w if robust is not None else np.ones(n)
    u, v, dist, signed = _final_projection(run, surf, u, v, dist, signed)
    return SurfaceFit(surf, u, v, dist, signed, final_w * (run.pw_user > 0), f0.stop, float(tolerance), run.sigma,
                      history)


def _sub_statistic(run: _FitRun, ku: np.ndarray, kv: np.ndarray, u: np.ndarray, v: np.ndarray, iu: np.ndarray,
                   iv: np.ndarray, cell: np.ndarray, keep: np.ndarray, dist: np.ndarray, signed_now: np.ndarray
                   ) -> np.ndarray:
    """Per cell (knot span pair, (cells,)) the largest statistic of its 4 x 4 sub-cells: a misfit
    on a tenth of a cell (a radius inside a wide span) must not hide under the cell's 90 %
    quantile. Points: parameters u, v, spans iu, iv, flat cell, keep (bool), dist, signed_now,
    each (N,)."""
    p, q = run.p, run.q
    bu = np.clip(((u - ku[p + iu]) / np.maximum(ku[p + iu + 1] - ku[p + iu], 1e-300) * 4).astype(np.int64), 0, 3)
    bv = np.clip(((v - kv[q + iv]) / np.maximum(kv[q + iv + 1] - kv[q + iv], 1e-300) * 4).astype(np.int64), 0, 3)
    key = (cell * 4 + bu) * 4 + bv
    n_cells = (len(ku) - 2 * p - 1) * (len(kv) - 2 * q - 1)
    if not run.noisy:
        return _cell_statistic(key[keep], dist[keep], 1.0, 16 * n_cells).reshape(n_cells, 16).max(axis=1)
    # noisy data: the sub-cell's mean signed residual (the fit's offset from the data's local
    # mean), less 3 standard errors of that mean; sub-cells with fewer than 4 points abstain
    k = key[keep]
    cnt = np.bincount(k, minlength=16 * n_cells)
    sm = np.bincount(k, weights=signed_now[keep], minlength=16 * n_cells)
    with np.errstate(invalid="ignore", divide="ignore"):
        st = np.abs(sm / cnt) - 3.0 * run.sigma / np.sqrt(cnt)
    st = np.where(cnt >= 4, st, -np.inf)
    return st.reshape(n_cells, 16).max(axis=1)


def _cell_stats(run: _FitRun, ku: np.ndarray, kv: np.ndarray, u: np.ndarray, v: np.ndarray, keep: np.ndarray,
                dist: np.ndarray, signed: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Knot spans iu, iv (N,) and flat cell iu * (v spans) + iv (N,) of each point, and each
    cell's deviation statistic (`_sub_statistic`) over the points with keep (N,)."""
    iu = find_span(ku, run.p, u) - run.p
    iv = find_span(kv, run.q, v) - run.q
    cell = iu * (len(kv) - 2 * run.q - 1) + iv
    return iu, iv, cell, _sub_statistic(run, ku, kv, u, v, iu, iv, cell, keep, dist, signed)


def _choose_knots(run: _FitRun, ku: np.ndarray, kv: np.ndarray, u: np.ndarray, v: np.ndarray, iu: np.ndarray,
                  iv: np.ndarray, cell: np.ndarray, keep: np.ndarray, signed: np.ndarray, stat: np.ndarray,
                  focus: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """New u and v knots: the middles of the spans with the worst flagged cells (focus, cell
    indices), along the direction(s) in which those cells' residuals vary, as many as the
    control-net limit leaves room for, where the data can carry them. Points as in
    `_sub_statistic`; stat (cells,). Returns (new_u, new_v), both empty when no span qualifies."""
    p, q = run.p, run.q
    nu, nv = len(ku) - p - 1, len(kv) - q - 1
    nsu, nsv = len(ku) - 2 * p - 1, len(kv) - 2 * q - 1
    # direction of refinement: the direction(s) along which a flagged cell's residuals vary
    lo_u, hi_u = ku[p + iu], ku[p + iu + 1]
    lo_v, hi_v = kv[q + iv], kv[q + iv + 1]
    bu = np.clip(((u - lo_u) / np.maximum(hi_u - lo_u, 1e-300) * 4).astype(np.int64), 0, 3)
    bv = np.clip(((v - lo_v) / np.maximum(hi_v - lo_v, 1e-300) * 4).astype(np.int64), 0, 3)
    var_u = _variation(cell[keep], bu[keep], signed[keep], nsu * nsv)
    var_v = _variation(cell[keep], bv[keep], signed[keep], nsu * nsv)
    top = np.maximum(var_u, var_v)
    with np.errstate(invalid="ignore"):
        want_u = focus[(var_u[focus] >= 0.3 * top[focus]) | np.isinf(var_u[focus])]
        want_v = focus[(var_v[focus] >= 0.3 * top[focus]) & ~np.isinf(var_u[focus])]
    cnt = np.bincount(cell, minlength=nsu * nsv).reshape(nsu, nsv)
    score_u = np.full(nsu, -np.inf)
    score_v = np.full(nsv, -np.inf)
    np.maximum.at(score_u, want_u // nsv, stat[want_u])
    np.maximum.at(score_v, want_v % nsv, stat[want_v])
    score_u[cnt.sum(axis=1) < 2 * nv] = -np.inf  # a u knot adds nv control points: enough data for them
    score_v[cnt.sum(axis=0) < 2 * nu] = -np.inf  # a v knot adds nu
    # and data spread along the span (>= 2 of its 8 eighths hold points), so the new basis
    # functions have data under them (Schoenberg-Whitney); rows of FE nodes 1 mm apart
    # cannot carry knots 0.25 mm apart
    iu0 = find_span(ku, p, run.u0_par) - p
    iv0 = find_span(kv, q, run.v0_par) - q
    for score, i_s, t, kn, deg, ns in ((score_u, iu0, run.u0_par, ku, p, nsu), (score_v, iv0, run.v0_par, kv, q, nsv)):
        lo, hi = kn[deg + i_s], kn[deg + i_s + 1]
        eighth = np.clip(((t - lo) / np.maximum(hi - lo, 1e-300) * 8).astype(np.int64), 0, 7)
        occ = np.bincount(i_s * 8 + eighth, minlength=8 * ns).reshape(ns, 8) > 0
        score[occ.sum(axis=1) < 2] = -np.inf
    room_u, room_v = run.max_ctrl[0] - nu, run.max_ctrl[1] - nv
    su_idx = np.argsort(-score_u)[: max(room_u, 0)]
    su_idx = su_idx[np.isfinite(score_u[su_idx])]
    sv_idx = np.argsort(-score_v)[: max(room_v, 0)]
    sv_idx = sv_idx[np.isfinite(score_v[sv_idx])]
    new_u = 0.5 * (ku[p + su_idx] + ku[p + su_idx + 1])
    new_v = 0.5 * (kv[q + sv_idx] + kv[q + sv_idx + 1])
    return new_u, new_v


def _insert_knots(run: _FitRun, ku: np.ndarray, kv: np.ndarray, new_u: np.ndarray, new_v: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Knot vectors with new_u, new_v inserted (into ``run.base`` too, whose weights they carry)."""
    if run.base is not None:
        from cadbridge.nurbs.edits import refine_surface

        run.base = refine_surface(run.base, new_u, new_v)
        return run.base.knots_u.copy(), run.base.knots_v.copy()
    return np.sort(np.concatenate([ku, new_u])), np.sort(np.concatenate([kv, new_v]))


def _fit_levels(run: _FitRun, ku: np.ndarray, kv: np.ndarray, u: np.ndarray, v: np.ndarray
                ) -> tuple[NurbsSurface, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, str, list[dict]]:
    """Solve, judge the cells, insert knots, level by level until the tolerance, the control-net
    limit or no improvement; the final reweighting on the last net. Returns (surface, u, v,
    dist, signed, rob_w, stop, history), arrays (N,)."""
    robust, tolerance, n = run.robust, run.tolerance, run.n
    thresh = tolerance
    history: list[dict] = []
    stop = "tolerance"
    rob_w = np.ones(n)
    best_worst = np.inf
    stale = 0
    for level in range(run.max_levels + 1):
        n_iter = 1  # Huber weights from the previous solve; the full IRLS runs on the final net
        for it in range(n_iter):
            surf, u, v, dist, signed = _solve(run, ku, kv, rob_w, u, v, f"level {level + 1}, solve {it + 1}/{n_iter}")
            if robust is not None:
                rob_w = _robust_weights(_contrast(run, signed), "huber", tolerance)
        nu, nv = len(ku) - run.p - 1, len(kv) - run.q - 1
        # cell (knot span pair) of each point and its deviation statistic; isolated outliers
        # (beyond Tukey's cut at the current MAD, never within 4.685 tol) do not ask for knots
        if robust is not None:
            keep = _robust_weights(_contrast(run, signed), "tukey", tolerance) > 0
        else:
            keep = np.ones(n, bool)
        iu, iv, cell, stat = _cell_stats(run, ku, kv, u, v, keep, dist, signed)
        flagged = np.nonzero(stat > thresh)[0]
        if (flagged.size == 0 or not run.refine or level == run.max_levels) and robust is not None and not run.done:
            rob_w, u, v, surf, dist, signed = _finish_robust(run, ku, kv, rob_w, u, v, surf, dist, signed)
            run.done = True
            keep = rob_w > 0
            iu, iv, cell, stat = _cell_stats(run, ku, kv, u, v, keep, dist, signed)
            flagged = np.nonzero(stat > thresh)[0]
        worst = float(stat.max())
        # knots go where the error comes from: cells within a factor 3 of the worst (a least-squares
        # misfit rings into the neighbouring spans; they settle once its source is resolved)
        focus = flagged[stat[flagged] >= worst / 3.0]
        history.append(dict(ctrl=(nu, nv), max=float(dist.max()), rms=float(np.sqrt(np.mean(dist**2))),
                            worst_cell=worst, outliers=int(np.count_nonzero(rob_w <= 0)) if robust else 0))
        if not run.refine:
            stop = "tolerance" if flagged.size == 0 else "fixed knots"
            break
        if flagged.size == 0:
            stop = "tolerance"
            break
        if level == run.max_levels:
            stop = "no improvement"
            break
        if worst < 0.98 * best_worst:
            best_worst, stale = worst, 0
        else:
            stale += 1
            if stale >= 3:
                stop = "no improvement"
                break
        new_u, new_v = _choose_knots(run, ku, kv, u, v, iu, iv, cell, keep, signed, stat, focus)
        if new_u.size == 0 and new_v.size == 0:
            stop = "control-net limit" if (run.max_ctrl[0] <= nu or run.max_ctrl[1] <= nv) else "no improvement"
            break
        ku, kv = _insert_knots(run, ku, kv, new_u, new_v)
        run.done = False
    if robust is not None and not run.done:
        rob_w, u, v, surf, dist, signed = _finish_robust(run, ku, kv, rob_w, u, v, surf, dist, signed)
        history[-1].update(max=float(dist.max()), rms=float(np.sqrt(np.mean(dist**2))),
                           outliers=int(np.count_nonzero(rob_w <= 0)))
    return surf, u, v, dist, signed, rob_w, stop, history


def fit_surface(
    points,
    u,
    v,
    *,
    degree: tuple[int, int] = (3, 3),
    tolerance: float = 0.01,
    knots: tuple[np.ndarray, np.ndarray] | None = None,
    initial_spans: tuple[int, int] | None = None,
    max_ctrl: tuple[int, int] = (60, 60),
    smoothing: float = 1e-6,
    robust: str | None = "tukey",
    correct_parameters: bool = True,
    refine: bool = True,
    rational_base: NurbsSurface | None = None,
    domain: tuple[float, float, float, float] | None = None,
    noise: float | None = None,
    point_weights=None,
    max_levels: int = 40,
    robust_iterations: int = 4,
    max_points_per_level: int = 100000,
    project_final: bool = True,
    progress=None,
) -> SurfaceFit:
    """Fit one NURBS surface to points with start parameters, refining knots to a tolerance.

    points (N, 3); u, v (N,) start parameters (from a base surface, `cadbridge.fitting.surface_fit`).
    degree (p, q); tolerance: max deviation wanted (model units); knots: fixed start knot vectors
    (clamped; default uniform with ``initial_spans`` spans, by default 4 along the longer side of
    the domain); max_ctrl: control net limit (nu, nv); smoothing: thin-plate weight (module doc;
    0 = plain least squares); robust: "tukey" (Huber, then Tukey), "huber" or None;
    correct_parameters: re-project onto the fit each iteration; refine: insert knots (False: one
    net, fixed knots); rational_base: a surface whose degrees, knots and weights the fit takes
    (knots inserted into it carry the weights along; its control points are not used);
    domain: (u0, u1, v0, v1) of the fit (default the box of the parameters); noise: sigma of
    the data (default `estimate_noise`); point_weights (N,) >= 0; progress: object with
    ``stage(text)`` (cadbridge.cli.Progress); robust_iterations: further reweighting solves on
    the final net (each phase stops when no weight changes by 0.01); max_points_per_level: more points
    than this choose their knots on a random subset of this size, then the final net is solved
    on all of them; project_final: project every point onto the final fit with
    `project_to_surface` for the reported deviations (False: the parameters and residuals of the
    last correction, as for the subset of a large input whose points are re-projected anyway).
    """
    x, u, v, pw_user = _check_inputs(points, u, v, tolerance, smoothing, point_weights)
    n = len(x)
    p, q, base, ku, kv, dom = _start_net(n, u, v, degree, knots, initial_spans, max_ctrl, rational_base, domain)
    u = np.clip(u, dom[0], dom[1])
    v = np.clip(v, dom[2], dom[3])
    sigma = estimate_noise(x) if noise is None else float(noise)
    edge = ((u <= dom[0]) * 1 + (u >= dom[1]) * 2 + (v <= dom[2]) * 4 + (v >= dom[3]) * 8).astype(np.uint8)
    run = _FitRun(x, pw_user, p, q, base, tolerance, smoothing, robust, correct_parameters, refine, rational_base,
                  max_ctrl, max_levels, robust_iterations, max_points_per_level, project_final, progress, sigma,
                  u.copy(), v.copy(), edge)
    if refine and n > max_points_per_level:
        return _fit_subset_then_all(run, ku, kv, u, v, dom)
    surf, u, v, dist, signed, rob_w, stop, history = _fit_levels(run, ku, kv, u, v)
    final_w = rob_w if robust is not None else np.ones(n)
    u, v, dist, signed = _final_projection(run, surf, u, v, dist, signed)
    return SurfaceFit(surf, u, v, dist, signed, final_w * (pw_user > 0), stop, float(tolerance), sigma, history)
