"""Orthogonal projection of (point, surface) pairs onto many NURBS surfaces at once.

`project_to_surfaces(pack, which, points)` gives, for pair i, the nearest point of surface
``which[i]`` to ``points[i]``: the same algorithm as `project_to_surface` (start from the
nearest grid sample, projected Newton with the full Jacobian, Neto 2010 app. B eqs. 32-36 /
Piegl & Tiller §6.1; then its global check from other discrete local minima of the sampled
distance and its edge check for feet clamped to a domain edge), but each stage runs for all
pairs of all surfaces in one compiled call (`SurfacePack`: the surfaces' control nets, knots
and sample grids packed into flat arrays), in parallel over blocks of pairs. The sample
KD-tree queries of all pairs are one query of a tree over every surface's samples
(`SurfacePack.nearest_samples`). Surfaces with internal crease knot lines are projected onto
each of their smooth pieces (`smooth_pieces`, packed too) and the nearest is kept as in
`project_to_surface`.

Cost: a few Python steps per surface per call (the global-check seeds), the rest compiled;
for many surfaces with few points each this is several times faster than a loop over
`project_to_surface` (whose per-call numpy overhead dominated there).
"""

from __future__ import annotations

import numba
import numpy as np

from cadbridge.nurbs.newton import (
    CHECK_K,
    CHECK_SEEDS,
    EDGE_SEEDS,
    FAILED_SEEDS,
    ders2_one,
    ders2_scratch,
    global_seeds,
    newton_range,
    wrap_clamp,
)
from cadbridge.nurbs.project import (
    CONVERGED,
    FAILED,
    ON_BOUNDARY,
    SurfaceProjection,
    nearest_of_pieces,
    on_pole_sample,
    pole_edges,
    pole_starts,
    smooth_pieces,
    surface_samples,
)
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["SurfacePack", "newton_is_final", "newton_to_surfaces", "project_to_surfaces"]

_TASK = 256  # pairs per parallel task at most
# feet nearer their point than this x surface size get no restarts (global / edge check): a
# nearer foot could gain at most that distance, below every tolerance downstream (1e-9 x size),
# and a second foot so near would need the surface to come within 2e-10 x size of itself
_ON_SURFACE = 1e-10
# a restart whose iterate comes within this fraction of a sample-grid cell (in u and in v) of
# the foot already found for its point stops: Newton is then converging onto that same foot
# (quadratically, from well inside its basin), so the restart cannot be nearer
_SAME_FOOT = 1e-3


class SurfacePack:
    """Surfaces and their start-value sample grids (`surface_samples`) in flat arrays for the
    compiled kernels. faces_of: the surfaces given (ids 0..F-1); surfaces: those and, after
    them, the smooth pieces of the ones with internal crease lines (pieces[id]: their ids);
    single: (F,) bool, the surface has no internal crease lines."""

    def __init__(self, surfaces: list[NurbsSurface]) -> None:
        self.faces_of = list(surfaces)  # the surfaces asked for (ids 0..F-1)
        pieces = [smooth_pieces(x) for x in self.faces_of]
        self.single = np.array([len(pc) == 1 for pc in pieces], dtype=bool)
        # surfaces with internal creases: their smooth pieces are packed after them (ids >= F)
        self.pieces: dict[int, np.ndarray] = {}
        extra = []
        f = len(self.faces_of)
        for k, pc in enumerate(pieces):
            if len(pc) > 1:
                self.pieces[k] = f + len(extra) + np.arange(len(pc))
                extra.extend(pc)
        self.surfaces = self.faces_of + extra
        s = len(self.surfaces)
        self.samples = [surface_samples(x) for x in self.surfaces]
        self.deg = np.array([[x.degree_u, x.degree_v] for x in self.surfaces], dtype=np.int64).reshape(s, 2)
        self.shape = np.array([x.shape for x in self.surfaces], dtype=np.int64).reshape(s, 2)
        self.rational = np.array([x.rational for x in self.surfaces], dtype=np.bool_)
        self.domain = np.array([x.domain for x in self.surfaces], dtype=float).reshape(s, 4)
        self.closed = np.array([[m.closed_u, m.closed_v] for m in self.samples], dtype=np.bool_).reshape(s, 2)
        self.size = np.array([max(m.size, 1e-300) for m in self.samples], dtype=float)
        self.has_pole = np.array([any(pole_edges(m)) for m in self.samples], dtype=bool)
        self.box = np.array([x.bbox() for x in self.surfaces], dtype=float).reshape(s, 2, 3)  # control-net boxes

        def flat(arrays):
            off = np.zeros(len(arrays) + 1, dtype=np.int64)
            off[1:] = np.cumsum([a.size for a in arrays])
            data = np.ascontiguousarray(np.concatenate([np.ravel(a) for a in arrays]) if arrays else np.zeros(0),
                                        dtype=float)
            data.setflags(write=False)  # read-only as the surfaces' own nets: ders2_one & co compile once
            return data, off

        self.pw, self.pw_off = flat([x._pw for x in self.surfaces])
        self.ku, self.ku_off = flat([x.knots_u for x in self.surfaces])
        self.kv, self.kv_off = flat([x.knots_v for x in self.surfaces])
        self.us, self.us_off = flat([m.us for m in self.samples])
        self.vs, self.vs_off = flat([m.vs for m in self.samples])
        self.spts, self.s_off = flat([m.points for m in self.samples])
        self.s_off //= 3
        self.spts = self.spts.reshape(-1, 3)
        self.suv = np.ascontiguousarray(np.concatenate([m.uv for m in self.samples]) if s else np.zeros((0, 2)))
        self.spacing = np.ascontiguousarray(np.concatenate([m.spacing for m in self.samples]) if s else np.zeros(0))
        # restarts stop within this (u, v) reach of the known foot: _SAME_FOOT of a grid cell
        cells = np.array([[(x.domain[1] - x.domain[0]) / max(len(m.us) - 1, 1),
                           (x.domain[3] - x.domain[2]) / max(len(m.vs) - 1, 1)]
                          for x, m in zip(self.surfaces, self.samples)], dtype=float).reshape(s, 2)
        self.reach = np.ascontiguousarray(_SAME_FOOT * cells)
        self.no_reach = np.full((s, 2), -1.0)

    def nearest_samples(self, sid: np.ndarray, p: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` nearest samples of surface ``sid[i]`` to ``p[i]`` ((n,) ids, (n, 3) points):
        distances (n, k) and global sample indices (n, k), nearest first; beyond a surface's own
        sample count the columns hold other surfaces' samples (callers keep the first
        min(k, samples) columns).

        One KD-tree over all samples, with the surface id times a gap ``big`` as a 4th
        coordinate, answers all pairs in one query: another surface's sample is at least
        ``big`` away in 4D, farther than any of the point's own surface's (exactly the same
        distances: the 4th difference is 0.0). Points too far from the samples' box for that
        (``gap + diameter >= big``) are asked of their surface's own tree."""
        n = len(sid)
        if n == 0:
            return np.zeros((0, k)), np.zeros((0, k), dtype=np.int64)
        if getattr(self, "_tree4", None) is None:
            from scipy.spatial import cKDTree

            lo, hi = self.spts.min(axis=0), self.spts.max(axis=0)
            diam = float(np.linalg.norm(hi - lo))
            big = 16.0 * diam + 1.0
            owner = np.repeat(np.arange(len(self.samples)), np.diff(self.s_off))
            self._tree4 = (cKDTree(np.column_stack([self.spts, owner * big])), big, lo, hi, diam)
        tree, big, lo, hi, diam = self._tree4
        gap = np.linalg.norm(np.maximum(np.maximum(lo - p, p - hi), 0.0), axis=1)
        far = gap + diam >= 0.5 * big
        q = np.column_stack([p, sid * big])
        d, i = tree.query(q, k=k, workers=_workers(n))
        d, i = np.asarray(d, dtype=float).reshape(n, k), np.asarray(i, dtype=np.int64).reshape(n, k)
        for r in np.flatnonzero(far):  # rare: points far off the model
            smp = self.samples[int(sid[r])]
            ks = min(k, len(smp.uv))
            d_, i_ = smp.tree.query(p[r], k=ks)
            d[r, :ks] = np.ravel(d_)
            i[r, :ks] = np.ravel(i_) + self.s_off[int(sid[r])]
        return d, i

    def kernel_args(self) -> tuple:
        return (self.pw, self.pw_off, self.ku, self.ku_off, self.kv, self.kv_off, self.deg, self.shape,
                self.rational, self.domain, self.closed)


# ---------------------------------------------------------------------------- kernels
@numba.njit(cache=True, error_model="numpy")
def _surface(pw, pw_off, ku, ku_off, kv, kv_off, shape, s):  # pragma: no cover - compiled
    nu, nv = shape[s, 0], shape[s, 1]
    net = pw[pw_off[s] : pw_off[s + 1]].reshape((nu, nv, 4))
    return net, ku[ku_off[s] : ku_off[s + 1]], kv[kv_off[s] : kv_off[s + 1]]


@numba.njit(cache=True, error_model="numpy")
def _newton_task(pw, pw_off, ku, ku_off, kv, kv_off, deg, shape, rational, domain, closed, sid, eps1, tol,
                 pts, noise, u, v, iters, max_iter, a, b, tu, tv, reach, same):  # pragma: no cover - compiled
    """`newton_range` on pairs a..b-1 (one surface, sid[a]); restarts (reach[s, 0] >= 0) stop
    within reach of the known foot (tu, tv)."""
    s = sid[a]
    net, kku, kkv = _surface(pw, pw_off, ku, ku_off, kv, kv_off, shape, s)
    u0, u1, v0, v1 = domain[s, 0], domain[s, 1], domain[s, 2], domain[s, 3]
    cu, cv = closed[s, 0], closed[s, 1]
    for t in range(a, b):  # start values wrapped / clamped into the domain (as `_newton`)
        u[t] = wrap_clamp(u[t], u0, u1, cu)
        v[t] = wrap_clamp(v[t], v0, v1, cv)
    newton_range(net, kku, kkv, deg[s, 0], deg[s, 1], rational[s], u0, u1, v0, v1, cu, cv, eps1[s], tol,
                 pts, noise, u, v, iters, max_iter, a, b, tu, tv, reach[s, 0], reach[s, 1], same)


@numba.njit(cache=True, error_model="numpy")
def _classify_task(pw, pw_off, ku, ku_off, kv, kv_off, deg, shape, rational, domain, closed, sid, eps1, tol,
                   pts, noise, u, v, foot, dist, normal, status, degen, a, b):  # pragma: no cover - compiled
    """Final classification of `_newton` for pairs a..b-1 (one surface): foot, distance,
    status (orthogonality check, binding edge), unit normal Su x Sv (degen: the normal needs
    the limit normal of `NurbsSurface.normal`)."""
    s = sid[a]
    net, kku, kkv = _surface(pw, pw_off, ku, ku_off, kv, kv_off, shape, s)
    p, q = deg[s, 0], deg[s, 1]
    u0, u1, v0, v1 = domain[s, 0], domain[s, 1], domain[s, 2], domain[s, 3]
    cu, cv = closed[s, 0], closed[s, 1]
    e1 = eps1[s]
    tiny = 1e-300
    scratch = ders2_scratch(p, q)
    der = np.empty((3, 3, 3))
    for t in range(a, b):
        uu, vv = u[t], v[t]
        ders2_one(net, kku, kkv, p, q, rational[s], uu, vv, scratch, der)
        rx, ry, rz = der[0, 0, 0] - pts[t, 0], der[0, 0, 1] - pts[t, 1], der[0, 0, 2] - pts[t, 2]
        sux, suy, suz = der[1, 0, 0], der[1, 0, 1], der[1, 0, 2]
        svx, svy, svz = der[0, 1, 0], der[0, 1, 1], der[0, 1, 2]
        d = np.sqrt(rx * rx + ry * ry + rz * rz)
        f = sux * rx + suy * ry + suz * rz
        g = svx * rx + svy * ry + svz * rz
        lsu = np.sqrt(sux * sux + suy * suy + suz * suz)
        lsv = np.sqrt(svx * svx + svy * svy + svz * svz)
        edge_u = (not cu) and ((uu <= u0 and f > 0) or (uu >= u1 and f < 0))
        edge_v = (not cv) and ((vv <= v0 and g > 0) or (vv >= v1 and g < 0))
        # (no offset along a direction that does not move the point: a pole, where it is round-off)
        off_u = 0.0 if (edge_u or lsu <= 1e-9 * lsv) else abs(f) / max(lsu, tiny)
        off_v = 0.0 if (edge_v or lsv <= 1e-9 * lsu) else abs(g) / max(lsv, tiny)
        cos_u = abs(f) / max(lsu * d, tiny)
        cos_v = abs(g) / max(lsv * d, tiny)
        binding = ((edge_u and cos_u > tol) or (edge_v and cos_v > tol)) and d > e1
        ok = max(off_u, off_v) <= 1e3 * e1 + noise[t]
        ok = ok and np.isfinite(d) and np.isfinite(uu) and np.isfinite(vv)
        foot[t, 0], foot[t, 1], foot[t, 2] = der[0, 0, 0], der[0, 0, 1], der[0, 0, 2]
        dist[t] = d
        status[t] = FAILED if not ok else (ON_BOUNDARY if binding else CONVERGED)
        nx = suy * svz - suz * svy
        ny = suz * svx - sux * svz
        nz = sux * svy - suy * svx
        ln = np.sqrt(nx * nx + ny * ny + nz * nz)
        m = max(lsu, lsv)
        degen[t] = not (ln > 1e-10 * m * m)
        if not ok:
            normal[t, 0] = normal[t, 1] = normal[t, 2] = np.nan
        else:
            normal[t, 0], normal[t, 1], normal[t, 2] = nx / ln, ny / ln, nz / ln


@numba.njit(cache=True, parallel=True, error_model="numpy", nogil=True)
def _run_tasks(kind, pw, pw_off, ku, ku_off, kv, kv_off, deg, shape, rational, domain, closed, sid, eps1, tol,
               pts, noise, u, v, iters, max_iter, foot, dist, normal, status, degen, tstart, tstop, tu, tv,
               reach, same):  # pragma: no cover - compiled
    for k in numba.prange(tstart.shape[0]):
        if kind == 0:
            _newton_task(pw, pw_off, ku, ku_off, kv, kv_off, deg, shape, rational, domain, closed, sid, eps1, tol,
                         pts, noise, u, v, iters, max_iter, tstart[k], tstop[k], tu, tv, reach, same)
        else:
            _classify_task(pw, pw_off, ku, ku_off, kv, kv_off, deg, shape, rational, domain, closed, sid, eps1,
                           tol, pts, noise, u, v, foot, dist, normal, status, degen, tstart[k], tstop[k])


@numba.njit(cache=True, error_model="numpy")
def _inward(t, grid, lo, hi, frac):  # pragma: no cover - compiled
    """`_edge_check`'s start ``frac`` grid cells inside the domain from an edge parameter."""
    n = grid.shape[0]
    if n < 2:
        return t
    k = min(max(np.searchsorted(grid, t), 1), n - 1)
    h = grid[k] - grid[k - 1]
    if t <= lo:
        return lo + frac * h
    if t >= hi:
        return hi - frac * h
    return t


@numba.njit(cache=True, error_model="numpy")
def _inward_starts(rows, sid, u, v, us, us_off, vs, vs_off, domain, out_u, out_v):  # pragma: no cover - compiled
    """Starts half a cell (out[0]) and one cell (out[1]) inside from the edge feet of ``rows``."""
    for i in range(rows.shape[0]):
        r = rows[i]
        s = sid[r]
        gu = us[us_off[s] : us_off[s + 1]]
        gv = vs[vs_off[s] : vs_off[s + 1]]
        for j, frac in enumerate((0.5, 1.0)):
            out_u[j, i] = _inward(u[r], gu, domain[s, 0], domain[s, 1], frac)
            out_v[j, i] = _inward(v[r], gv, domain[s, 2], domain[s, 3], frac)


# ---------------------------------------------------------------------------- driver
def _workers(n: int) -> int:
    """Threads of a sample-tree query of n points: all cores for large ones (same result)."""
    return -1 if n >= 4096 else 1


def _tasks(sid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Runs of equal surface id (sid sorted) cut into pieces of at most _TASK pairs."""
    n = len(sid)
    if n == 0:
        z = np.zeros(0, dtype=np.int64)
        return z, z
    cuts = np.flatnonzero(np.diff(sid)) + 1
    starts = np.concatenate([[0], cuts])
    stops = np.concatenate([cuts, [n]])
    cnt = (stops - starts + _TASK - 1) // _TASK
    a = np.repeat(starts, cnt) + _TASK * (np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt))
    b = np.minimum(a + _TASK, np.repeat(stops, cnt))
    return a.astype(np.int64), b.astype(np.int64)


class _Run:
    """Newton + classification of pairs (sid sorted) from start values (u, v)."""

    def __init__(self, pack: SurfacePack, sid: np.ndarray, pts: np.ndarray, tol: float, max_iter: int) -> None:
        self.pack, self.sid, self.pts, self.tol, self.max_iter = pack, sid, pts, tol, max_iter
        self.eps1 = tol * pack.size
        # absolute round-off of r = S - P per pair: a few ulps of the largest coordinate involved
        n = len(pts)
        self.noise = 64.0 * np.finfo(float).eps * (np.max(np.abs(pts), axis=1) + pack.size[sid]) if n else np.zeros(0)
        self.tasks = _tasks(sid)

    def __call__(self, u: np.ndarray, v: np.ndarray, known: tuple[np.ndarray, np.ndarray] | None = None
                 ) -> tuple[SurfaceProjection, np.ndarray]:
        """Newton from (u, v), classified; known: the feet (tu, tv) already found for these
        pairs (restarts). Returns the projection and same (N,) bool: the restart was converging
        onto its known foot and stopped (not a foot; never better)."""
        n = len(self.pts)
        u = np.ascontiguousarray(u, dtype=float).copy()
        v = np.ascontiguousarray(v, dtype=float).copy()
        iters = np.zeros(n, dtype=np.int32)
        foot, normal = np.empty((n, 3)), np.empty((n, 3))
        dist, status, degen = np.empty(n), np.empty(n, dtype=np.int8), np.zeros(n, dtype=np.bool_)
        same = np.zeros(n, dtype=np.bool_)
        if known is None:
            tu, tv, reach = u, v, self.pack.no_reach
        else:
            tu, tv = np.ascontiguousarray(known[0], dtype=float), np.ascontiguousarray(known[1], dtype=float)
            reach = self.pack.reach
        if n:
            for kind in (0, 1):  # one parallel kernel (a serial twin would double the first-run compile)
                _run_tasks(kind, *self.pack.kernel_args(), self.sid, self.eps1, self.tol, self.pts, self.noise, u, v,
                           iters, int(self.max_iter), foot, dist, normal, status, degen, *self.tasks, tu, tv, reach,
                           same)
            bad = np.flatnonzero(degen & (status != FAILED))
            for s in np.unique(self.sid[bad]):  # poles, collapsed edges: the limit normal
                sel = bad[self.sid[bad] == s]
                normal[sel] = self.pack.surfaces[s].normal(u[sel], v[sel])
        return SurfaceProjection(u, v, foot, dist, normal, status, iters), same


def _known(res: SurfaceProjection, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The feet (u, v) of ``rows`` that restarts may stop at (`_Run`): NaN where the foot FAILED
    (a restart heading for a stalled iterate is no foot of its own: a start on a pole, whose
    restarts carrying the point's azimuth converge next to where it stalled)."""
    failed = res.status[rows] == FAILED
    return np.where(failed, np.nan, res.u[rows]), np.where(failed, np.nan, res.v[rows])


def _replace(res: SurfaceProjection, tgt: np.ndarray, extra: SurfaceProjection, better: np.ndarray) -> None:
    """Where ``better``, write the restart into the result of its pair ``tgt``; several for one
    pair: the nearest (stable order, nearest written last)."""
    idx = np.flatnonzero(better)
    if not len(idx):
        return
    idx = idx[np.argsort(-extra.distance[idx], kind="stable")]
    rows = tgt[idx]
    for name in ("u", "v", "foot", "distance", "normal", "status"):
        getattr(res, name)[rows] = getattr(extra, name)[idx]
    np.add.at(res.iterations, rows, extra.iterations[idx])


_FIELDS = ("u", "v", "foot", "distance", "normal", "status", "iterations")


def newton_to_surfaces(pack: SurfacePack, which, points, *, tol: float = 1e-12, max_iter: int = 30
                       ) -> tuple[SurfaceProjection, np.ndarray]:
    """The first stage of `project_to_surfaces` alone: Newton from the nearest grid sample,
    classified, without the global and edge checks (restarts). Only for surfaces without
    internal crease lines (``pack.single``; ValueError otherwise).

    Returns the projection of the M pairs and first (M,) the global index of each pair's
    start sample; ``project_to_surfaces(..., resume=(result, first))`` completes the same
    pairs with the checks, exactly as if run in one call. A pair that is CONVERGED within
    ``ON_SURFACE x pack.size`` of its point is already final (the checks skip it).
    """
    which = np.asarray(which, dtype=np.int64).ravel()
    pts = np.ascontiguousarray(points, dtype=float).reshape(-1, 3)
    m = len(which)
    if len(pts) != m:
        raise ValueError(f"newton_to_surfaces: {m} surface ids for {len(pts)} points")
    if m and not np.all(pack.single[which]):
        raise ValueError("newton_to_surfaces: surfaces with internal crease lines need project_to_surfaces")
    out = SurfaceProjection(np.empty(m), np.empty(m), np.empty((m, 3)), np.empty(m), np.empty((m, 3)),
                            np.empty(m, dtype=np.int8), np.zeros(m, dtype=np.int32))
    first = np.zeros(m, dtype=np.int64)
    if m == 0:
        return out, first
    order = np.argsort(which, kind="stable")
    res, fi = _sorted_pairs(pack, which[order], np.ascontiguousarray(pts[order]), tol, max_iter, None, checks=False)
    for name in _FIELDS:
        getattr(out, name)[order] = getattr(res, name)
    first[order] = fi
    return out, first


def newton_is_final(pack: SurfacePack, which, res: SurfaceProjection) -> np.ndarray:
    """(M,) bool: pairs of a `newton_to_surfaces` result that the checks would leave as they
    are (CONVERGED within ``_ON_SURFACE`` x surface size of the point: no restart runs)."""
    which = np.asarray(which, dtype=np.int64).ravel()
    return (res.status == CONVERGED) & (res.distance <= _ON_SURFACE * pack.size[which])


def project_to_surfaces(pack: SurfacePack, which, points, *, uv0=None, tol: float = 1e-12, max_iter: int = 30,
                        resume: tuple[SurfaceProjection, np.ndarray] | None = None) -> SurfaceProjection:
    """Nearest point of surface ``pack.surfaces[which[i]]`` to ``points[i]`` for every pair i.

    which (M,) int surface ids, points (M, 3). Same result as
    ``project_to_surface(pack.surfaces[which[i]], points[i], tol=tol, max_iter=max_iter)``
    (start from the nearest sample, Newton, global check, edge check; every foot checked for
    orthogonality, FAILED otherwise). uv0 (M, 2): start parameters instead of the nearest
    grid sample (the checks still use the grid). resume: the `newton_to_surfaces` result of
    these same pairs (single surfaces only): its Newton stage is reused, only the checks
    run. Returns a `SurfaceProjection` of M pairs.
    """
    which = np.asarray(which, dtype=np.int64).ravel()
    pts = np.ascontiguousarray(points, dtype=float).reshape(-1, 3)
    m = len(which)
    if len(pts) != m:
        raise ValueError(f"project_to_surfaces: {m} surface ids for {len(pts)} points")
    out = SurfaceProjection(np.empty(m), np.empty(m), np.empty((m, 3)), np.empty(m), np.empty((m, 3)),
                            np.empty(m, dtype=np.int8), np.zeros(m, dtype=np.int32))
    if m == 0:
        return out
    order = np.argsort(which, kind="stable")
    sid = which[order]
    if resume is not None:
        prev, first = resume
        if len(first) != m or not np.all(pack.single[sid]):
            raise ValueError("project_to_surfaces: resume needs the newton_to_surfaces result of single surfaces")
        res0 = SurfaceProjection(*(np.array(getattr(prev, name)[order]) for name in _FIELDS))
        res, _ = _sorted_pairs(pack, sid, np.ascontiguousarray(pts[order]), tol, max_iter, None,
                               resume=(res0, np.asarray(first, dtype=np.int64)[order]))
        for name in _FIELDS:
            getattr(out, name)[order] = getattr(res, name)
        return out
    multi = ~pack.single[sid]
    start = None if uv0 is None else np.asarray(uv0, dtype=float).reshape(m, 2)
    if not np.any(multi):
        res, _ = _sorted_pairs(pack, sid, np.ascontiguousarray(pts[order]), tol, max_iter,
                               None if start is None else start[order])
        for name in _FIELDS:
            getattr(out, name)[order] = getattr(res, name)
        return out
    # surfaces with internal creases: each pair on its smooth pieces (`nearest_of_pieces`),
    # nearest piece box first; another piece only where its control-net box (which holds the
    # piece: convex hull, weights > 0) is not farther than that first foot: a farther piece
    # cannot hold the nearest foot nor tie with it (the result is that of every piece)
    rows_m, piece_m, lb_m, faces_m = [], [], [], []
    for f in np.unique(sid[multi]):
        rows = order[sid == f]
        ids = pack.pieces[int(f)]
        lo, hi = pack.box[ids, 0], pack.box[ids, 1]  # (K, 3)
        gap = np.maximum(np.maximum(lo[None] - pts[rows, None], pts[rows, None] - hi[None]), 0.0)
        rows_m.append(np.repeat(rows, len(ids)))
        piece_m.append(np.tile(ids, len(rows)))
        lb_m.append(np.linalg.norm(gap, axis=2).ravel())
        faces_m.append(int(f))
    rows_m, piece_m, lb_m = np.concatenate(rows_m), np.concatenate(piece_m), np.concatenate(lb_m)
    # the first piece of each pair: least box distance (pairs are grouped by row)
    grp = np.flatnonzero(np.concatenate([[True], rows_m[1:] != rows_m[:-1]]))
    key = np.lexsort((lb_m, rows_m))
    first_pick = key[np.searchsorted(rows_m[key], rows_m[grp])]
    done = np.zeros(len(rows_m), dtype=bool)
    done[first_pick] = True
    single = ~multi
    r_rows = np.concatenate([order[single], rows_m[first_pick]])
    r_sid = np.concatenate([sid[single], piece_m[first_pick]])
    results = {}  # pair index in rows_m -> (result, position)

    def run(rows, ids):
        if not len(rows):
            return SurfaceProjection(*(np.zeros((0, 3) if name in ("foot", "normal") else 0) for name in _FIELDS)), \
                np.zeros(0, dtype=np.int64)
        o = np.argsort(ids, kind="stable")
        rows, ids = rows[o], ids[o]
        st = None if start is None else start[rows]
        res, _ = _sorted_pairs(pack, ids, np.ascontiguousarray(pts[rows]), tol, max_iter, st)
        back = np.empty(len(o), dtype=np.int64)
        back[o] = np.arange(len(o))
        return res, back

    res1, back1 = run(r_rows, r_sid)
    ns = int(single.sum())
    for name in _FIELDS:
        getattr(out, name)[order[single]] = getattr(res1, name)[back1[:ns]]
    d1 = np.full(m, np.inf)
    pos1 = back1[ns:]
    d1[rows_m[first_pick]] = np.where(res1.status[pos1] == FAILED, np.inf, res1.distance[pos1])
    d1 = np.where(np.isfinite(d1), d1, np.inf)
    psize = pack.size[piece_m]
    more = ~done & ~(lb_m > d1[rows_m] * (1.0 + 1e-9) + 1e-9 * psize)
    res2, back2 = run(rows_m[more], piece_m[more])
    fill = SurfaceProjection(np.full(len(rows_m), np.nan), np.full(len(rows_m), np.nan), np.full((len(rows_m), 3), np.nan),
                             np.full(len(rows_m), np.inf), np.full((len(rows_m), 3), np.nan),
                             np.full(len(rows_m), FAILED, dtype=np.int8), np.zeros(len(rows_m), dtype=np.int32))
    for name in _FIELDS:
        getattr(fill, name)[first_pick] = getattr(res1, name)[pos1]
        getattr(fill, name)[more] = getattr(res2, name)[back2]
    for f in faces_m:  # nearest over the pieces (`nearest_of_pieces`: feet on crease lines)
        ids = pack.pieces[f]
        sel = np.flatnonzero(np.isin(piece_m, ids))
        rows = rows_m[sel[::len(ids)]]
        o = np.argsort(rows, kind="stable")
        parts = [SurfaceProjection(*(getattr(fill, name)[sel[j::len(ids)][o]] for name in _FIELDS))
                 for j in range(len(ids))]
        r = nearest_of_pieces(pack.faces_of[f], [pack.surfaces[i] for i in ids], parts)
        for name in _FIELDS:
            getattr(out, name)[rows[o]] = getattr(r, name)
    return out


def _sorted_pairs(pack: SurfacePack, sid: np.ndarray, p: np.ndarray, tol: float, max_iter: int,
                  start: np.ndarray | None, *, checks: bool = True,
                  resume: tuple[SurfaceProjection, np.ndarray] | None = None) -> tuple[SurfaceProjection, np.ndarray]:
    """Pairs sorted by surface id: Newton (or its ``resume`` (result, first)), then the checks
    (``checks=False``: none). Returns the projection and the start samples' global indices."""
    n = len(p)
    # the nearest sample of each pair's surface starts Newton; the k nearest (global and edge
    # checks) are queried afterwards, only for the pairs that get restarts
    k = CHECK_K
    cuts = np.flatnonzero(np.diff(sid)) + 1
    starts, stops = np.concatenate([[0], cuts]), np.concatenate([cuts, [n]])
    if resume is not None:
        res, first = resume
    else:
        first = pack.s_off[sid].astype(np.int64)  # global sample index (pack.suv, pack.spts)
        if start is None:
            first = pack.nearest_samples(sid, p, 1)[1][:, 0]
            start = pack.suv[first]
        run = _Run(pack, sid, p, tol, max_iter)
        res, _ = run(start[:, 0], start[:, 1])
        if not checks:
            return res, first

    # global check: restarts from other discrete local minima of the sampled distance; not
    # for feet within _ON_SURFACE x size of their point (a restart could gain at most that)
    d = np.where(res.status == FAILED, np.inf, res.distance)
    d = np.where(np.isfinite(d), d, np.inf)
    d_seed = np.where(d <= _ON_SURFACE * pack.size[sid], np.nan, d)  # NaN: no sample is within the radius
    need = ~np.isnan(d_seed) | (res.status == ON_BOUNDARY)
    dk = np.full((n, k), np.inf)
    ik = np.repeat(first[:, None], k, axis=1)
    kk = np.minimum(k, np.diff(pack.s_off)[sid])  # k of the surface: min(CHECK_K, samples)
    rows = np.flatnonzero(need)
    if len(rows):
        d_, i_ = pack.nearest_samples(sid[rows], p[rows], k)
        own = np.arange(k)[None, :] < kk[rows][:, None]
        dk[rows] = np.where(own, d_, np.inf)
        ik[rows] = np.where(own, i_, i_[:, :1])
    rows_all, seeds_all = [], []
    for a, b in zip(starts, stops):
        s = int(sid[a])
        smp = pack.samples[s]
        ks = int(kk[a])
        if ks < 2:
            continue
        o = pack.s_off[s]
        rows, sidx = global_seeds(d_seed[a:b], np.ascontiguousarray(dk[a:b, :ks]),
                                  np.ascontiguousarray(ik[a:b, :ks] - o), smp.spacing, smp.points, p[a:b],
                                  res.u[a:b], res.v[a:b], smp.us, smp.vs, smp.closed_u, smp.closed_v, CHECK_SEEDS)
        if len(rows):
            rows_all.append(rows + a)
            seeds_all.append(sidx + o)
    if rows_all:
        rows = np.concatenate(rows_all)
        uv = pack.suv[np.concatenate(seeds_all)]
        extra, same = _Run(pack, sid[rows], p[rows], tol, max_iter)(uv[:, 0], uv[:, 1], _known(res, rows))
        _replace(res, rows, extra, ~same & (extra.status != FAILED) & (extra.distance < d[rows]))

    # edge check: feet clamped to a domain edge restart half / one cell inside and from the
    # nearby samples within sqrt(d^2 + (2h)^2)
    rows = np.flatnonzero((res.status == ON_BOUNDARY) & (res.distance > _ON_SURFACE * pack.size[sid]))
    # a foot that FAILED (Newton stalled) on a pole gets the pole restarts as well, and so
    # does a point off the surface whose nearest sample lies on a pole or collapsed edge
    near_pole = np.zeros(n, dtype=bool)
    hp = np.flatnonzero(pack.has_pole[sid] & ~(res.distance <= _ON_SURFACE * pack.size[sid]))
    if len(hp):
        gi = pack.nearest_samples(sid[hp], p[hp], 1)[1][:, 0]
        for s_ in np.unique(sid[hp]):  # loop over the (few) surfaces with a pole
            sel = sid[hp] == s_
            near_pole[hp[sel]] = on_pole_sample(pack.samples[s_], gi[sel] - pack.s_off[s_])
    prows = np.union1d(rows, np.flatnonzero((res.status == FAILED) | near_pole))
    if len(prows):
        su = np.empty((2, len(rows)))
        sv = np.empty((2, len(rows)))
        _inward_starts(rows, sid, res.u, res.v, pack.us, pack.us_off, pack.vs, pack.vs_off, pack.domain, su, sv)
        owners = [rows, rows]
        starts_u, starts_v = [su[0], su[1]], [sv[0], sv[1]]
        multi = kk[rows] > 1
        if np.any(multi):
            r = rows[multi]
            dkr, ikr = dk[r], ik[r]
            rad = np.sqrt(res.distance[r] ** 2 + (2.0 * pack.spacing[ikr[:, 0]]) ** 2)
            cand = dkr <= rad[:, None]
            cand[:, 0] = False
            cand &= np.arange(k)[None, :] < kk[r][:, None]
            cand &= np.cumsum(cand, axis=1) <= EDGE_SEEDS
            rr, cc = np.nonzero(cand)
            uv = pack.suv[ikr[rr, cc]]
            starts_u.append(uv[:, 0])
            starts_v.append(uv[:, 1])
            owners.append(r[rr])
        polar = np.unique(sid[prows])
        for s_ in polar[pack.has_pole[polar]]:  # feet on a pole: restarts carrying the point's azimuth
            r = prows[sid[prows] == s_]
            pu, pv, pi = pole_starts(pack.samples[s_], pack.surfaces[s_].domain, p[r], res.u[r], res.v[r],
                                     (res.status[r] == FAILED) | near_pole[r])
            if len(pi):
                starts_u.append(pu)
                starts_v.append(pv)
                owners.append(r[pi])
        owner = np.concatenate(owners)
        order = np.argsort(owner, kind="stable")  # by owner = by surface (sid sorted), same per-pair order
        owner = owner[order]
        eu, ev = np.concatenate(starts_u)[order], np.concatenate(starts_v)[order]
        extra, same = _Run(pack, sid[owner], p[owner], tol, max_iter)(eu, ev, _known(res, owner))
        dd = res.distance[owner]
        dd = np.where((res.status[owner] == FAILED) | np.isnan(dd), np.inf, dd)  # any valid foot beats a failed one
        better = ~same & (extra.status != FAILED) & (extra.distance < dd - 1e-3 * tol * pack.size[sid[owner]])
        _replace(res, owner, extra, better)

    # failed check (`cadbridge.nurbs.project._failed_check`): a point whose Newton still FAILED
    # restarts from its 2nd to (1 + FAILED_SEEDS)th nearest samples (queried above: a FAILED
    # pair always needs the global check)
    rows = np.flatnonzero(res.status == FAILED)
    if len(rows):
        j = np.arange(1, min(FAILED_SEEDS + 1, k))
        rr, cc = np.nonzero(j[None, :] < kk[rows][:, None])
        if len(rr):
            owner = rows[rr]  # ascending: by surface, as _Run needs
            uv = pack.suv[ik[owner, j[cc]]]
            extra, _ = _Run(pack, sid[owner], p[owner], tol, max_iter)(uv[:, 0], uv[:, 1])
            _replace(res, owner, extra, extra.status != FAILED)
    return res, first
