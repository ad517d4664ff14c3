"""Orthogonal projection of points onto one NURBS surface (point inversion).

Newton-Raphson on f = Su.r, g = Sv.r with r = S(u, v) - P and the full Jacobian
(Neto 2010, appendix B, eqs. 32-36; Piegl & Tiller section 6.1), vectorised over points:
every iteration evaluates the surface derivatives of all still-active points at once.

Start values come from the nearest point of a sample grid whose density follows the knot
spans and degrees (a KD-tree over the samples, cached per surface). Bounds are handled as a
projected Newton method: a direction whose minimum lies outside the domain is clamped to the
edge and the remaining variable is solved by Newton on that iso-curve (status ON_BOUNDARY);
closed (periodic) directions wrap instead of clamping.

Line search: a step that increases |r|^2 beyond its round-off (2 |r| e + e^2, e a few ulps
of the coordinates) is halved, unless it was cut at a domain edge: then the iteration goes on
from the previous point projected onto that edge (halving along a cut step need not descend;
it stalled a point of the bearing benchmark off the edge, FAILED); convergence is tested first, so a foot that is already
orthogonal is never sent back by round-off (this sent 9 of 200 000 points of the many-face
benchmark into an endless halving loop and FAILED, or worse, stopped at a point ~1e-8 off).

Convergence (P&T 6.1): point coincidence |r| <= eps1, or zero cosine |Su.r|/(|Su||r|) <= eps2
and |Sv.r|/(|Sv||r|) <= eps2 (directions clamped at an edge count as satisfied), or a step
|(u'-u) Su + (v'-v) Sv| <= eps1; at most ``max_iter`` iterations. eps1 = eps2 = tol (eps1
is scaled by the surface size).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numba
import numpy as np
from scipy.spatial import cKDTree

from cadbridge.common.jit import parallel_kernels
from cadbridge.nurbs.newton import CHECK_K, CHECK_SEEDS, EDGE_SEEDS, FAILED_SEEDS, global_seeds, newton_range
from cadbridge.nurbs.surface import NurbsSurface

__all__ = [
    "CONVERGED",
    "ON_BOUNDARY",
    "BEYOND_TOLERANCE",
    "FAILED",
    "STATUS_NAMES",
    "SurfaceProjection",
    "SurfaceSamples",
    "project_to_surface",
    "surface_samples",
    "sample_parameters",
    "closed_directions",
    "nearest_of_pieces",
]

CONVERGED: int = 0  # interior stationary point of the distance (foot is orthogonal)
ON_BOUNDARY: int = 1  # minimum lies outside the domain: nearest point on the domain edge
BEYOND_TOLERANCE: int = 2  # valid foot, but farther than the caller's max_distance
FAILED: int = 3  # no converged foot (iteration cap, non-finite values); normal is NaN
STATUS_NAMES: dict[int, str] = {
    CONVERGED: "CONVERGED",
    ON_BOUNDARY: "ON_BOUNDARY",
    BEYOND_TOLERANCE: "BEYOND_TOLERANCE",
    FAILED: "FAILED",
}

_SAMPLES_PER_DIRECTION_CAP = 256  # per parametric direction
_SAMPLES_TOTAL_CAP = 16384  # per surface


@dataclass
class SurfaceProjection:
    """Result of `project_to_surface` for N points.

    u, v       (N,) parameters of the foot point
    foot       (N, 3) S(u, v)
    distance   (N,) |P - foot|
    normal     (N, 3) unit normal along Su x Sv (limit normal at poles); NaN where FAILED
    status     (N,) int8: CONVERGED, ON_BOUNDARY, BEYOND_TOLERANCE or FAILED
    iterations (N,) int: Newton iterations used per point
    """

    u: np.ndarray
    v: np.ndarray
    foot: np.ndarray
    distance: np.ndarray
    normal: np.ndarray
    status: np.ndarray
    iterations: np.ndarray

    def __len__(self) -> int:
        return len(self.u)


# ---------------------------------------------------------------------------- sampling
def sample_parameters(knots: np.ndarray, degree: int, lo: float, hi: float, per_span: int) -> np.ndarray:
    """Parameters in [lo, hi]: ``per_span`` intervals in every non-empty knot span (knots
    included), (M,) increasing."""
    knots = np.asarray(knots, dtype=float)
    brk = np.unique(knots[(knots > lo) & (knots < hi)])
    edges = np.concatenate([[lo], brk, [hi]])
    per_span = max(int(per_span), 1)
    parts = [np.linspace(a, b, per_span + 1)[:-1] for a, b in zip(edges[:-1], edges[1:])]
    return np.concatenate(parts + [[hi]])


def _n_spans(knots: np.ndarray, lo: float, hi: float) -> int:
    k = np.unique(knots)
    return int(np.count_nonzero((k > lo) & (k < hi))) + 1


@dataclass
class SurfaceSamples:
    """Sample grid of a surface used for start values (cached per surface object).

    us (mu,), vs (mv,): grid parameters; uv (M, 2), points (M, 3); tree: cKDTree of points;
    size: control-net box diagonal; closed_u/closed_v: periodic directions.
    """

    us: np.ndarray
    vs: np.ndarray
    uv: np.ndarray
    points: np.ndarray
    tree: cKDTree
    size: float
    closed_u: bool
    closed_v: bool
    spacing: np.ndarray  # (M,) largest distance from each sample to its grid neighbours


_CACHE: "weakref.WeakKeyDictionary[NurbsSurface, SurfaceSamples]" = weakref.WeakKeyDictionary()


def closed_directions(surface: NurbsSurface, n: int = 33, rel_tol: float = 1e-10) -> tuple[bool, bool]:
    """Whether S(u0, v) == S(u1, v) for all v (closed in u) and S(u, v0) == S(u, v1) (closed
    in v), detected on ``n`` samples within ``rel_tol`` x surface size."""
    u0, u1, v0, v1 = surface.domain
    b = surface.bbox()
    tol = rel_tol * max(float(np.linalg.norm(b[1] - b[0])), 1e-300)
    t = np.linspace(0.0, 1.0, n)
    vs = v0 + (v1 - v0) * t
    us = u0 + (u1 - u0) * t
    # the four edges in one evaluation (pointwise: the same values as one call per edge)
    uu = np.concatenate([np.full(n, u0), np.full(n, u1), us, us])
    vv = np.concatenate([vs, vs, np.full(n, v0), np.full(n, v1)])
    e = surface.evaluate(uu, vv).reshape(4, n, -1)
    closed_u = bool(np.max(np.linalg.norm(e[0] - e[1], axis=1)) <= tol)
    closed_v = bool(np.max(np.linalg.norm(e[2] - e[3], axis=1)) <= tol)
    return closed_u, closed_v


def surface_samples(surface: NurbsSurface) -> SurfaceSamples:
    """The (cached) start-value grid: 2 (p+1) samples per non-empty knot span in u and
    2 (q+1) in v, capped at 256 per direction and 16384 in total."""
    hit = _CACHE.get(surface)
    if hit is not None:
        return hit
    u0, u1, v0, v1 = surface.domain
    p, q = surface.degree_u, surface.degree_v
    su, sv = _n_spans(surface.knots_u, u0, u1), _n_spans(surface.knots_v, v0, v1)
    per_u, per_v = 2 * (p + 1), 2 * (q + 1)
    per_u = max(1, min(per_u, _SAMPLES_PER_DIRECTION_CAP // su))
    per_v = max(1, min(per_v, _SAMPLES_PER_DIRECTION_CAP // sv))
    while (su * per_u + 1) * (sv * per_v + 1) > _SAMPLES_TOTAL_CAP and max(per_u, per_v) > 1:
        if per_u >= per_v:
            per_u -= 1
        else:
            per_v -= 1
    us = sample_parameters(surface.knots_u, p, u0, u1, per_u)
    vs = sample_parameters(surface.knots_v, q, v0, v1, per_v)
    uu, vv = np.meshgrid(us, vs, indexing="ij")
    uv = np.column_stack([uu.ravel(), vv.ravel()])
    pts = surface.evaluate(uv[:, 0], uv[:, 1])
    b = surface.bbox()
    size = float(np.linalg.norm(b[1] - b[0]))
    cu, cv = closed_directions(surface)
    g = pts.reshape(len(us), len(vs), 3)
    h = np.zeros((len(us), len(vs)))
    if len(us) > 1:
        du = np.linalg.norm(np.diff(g, axis=0), axis=2)
        h[:-1] = np.maximum(h[:-1], du)
        h[1:] = np.maximum(h[1:], du)
    if len(vs) > 1:
        dv = np.linalg.norm(np.diff(g, axis=1), axis=2)
        h[:, :-1] = np.maximum(h[:, :-1], dv)
        h[:, 1:] = np.maximum(h[:, 1:], dv)
    h = h.ravel()
    s = SurfaceSamples(us, vs, uv, pts, cKDTree(pts), size, cu, cv, h)
    _CACHE[surface] = s
    return s



# ---------------------------------------------------------------------------- projection
def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def project_to_surface(
    surface: NurbsSurface,
    points,
    *,
    uv0=None,
    tol: float = 1e-12,
    max_iter: int = 30,
    max_distance: float | None = None,
    n_starts: int = 1,
    global_check: bool = True,
) -> SurfaceProjection:
    """Project points onto ``surface``: the nearest point of S over its domain.

    points (N, 3); uv0 optional (N, 2) start parameters (else the nearest grid sample);
    tol: eps1 = tol x surface size (point coincidence, step size) and eps2 = tol (zero
    cosine); max_iter: Newton iterations; max_distance: feet farther than that get
    BEYOND_TOLERANCE; n_starts: start from the n nearest grid samples and keep the best
    (guards against local minima on strongly curved surfaces); global_check: after Newton,
    restart from grid samples (other than the first start) that are discrete local minima
    of the distance and are within sqrt(d^2 + (2h)^2) of the point (d: distance found, h: grid
    spacing at the first start), keeping the nearest result — a cheap guard against local minima that costs
    nothing for points close to the surface; feet clamped to an edge (ON_BOUNDARY) are
    also restarted from up to 6 nearby samples and from half / one grid cell inside the edge
    (`_edge_check`), since an interior minimum next to an edge can hide between samples.

    Every returned foot is checked for orthogonality (tangential offset <= 1e-9 x surface
    size, plus coordinate round-off): a point whose iteration stalls is FAILED, never a
    silently wrong foot.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim == 1:
        pts = pts.reshape(1, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    pieces = smooth_pieces(surface)
    if len(pieces) > 1 and uv0 is None:
        kw = dict(tol=tol, max_iter=max_iter, max_distance=max_distance, n_starts=n_starts, global_check=global_check)
        return nearest_of_pieces(surface, pieces, [project_to_surface(pc, pts, **kw) for pc in pieces])
    n = len(pts)
    samples = surface_samples(surface)
    if uv0 is not None:
        uv_start = np.asarray(uv0, dtype=float).reshape(n, 2)
        reps = 1
        seeds_pts = pts
    else:
        k = max(1, min(int(n_starts), len(samples.uv)))
        _, idx = samples.tree.query(pts, k=k)
        idx = np.asarray(idx).reshape(n, k)
        uv_start = samples.uv[idx.reshape(-1)]
        reps = k
        seeds_pts = np.repeat(pts, k, axis=0) if k > 1 else pts
    res = _newton(surface, samples, seeds_pts, uv_start[:, 0].copy(), uv_start[:, 1].copy(), tol, max_iter)
    if reps > 1:
        d = res.distance.reshape(n, reps).copy()
        d[res.status.reshape(n, reps) == FAILED] = np.inf
        best = np.argmin(np.where(np.isnan(d), np.inf, d), axis=1)
        pick = np.arange(n) * reps + best
        res = SurfaceProjection(
            res.u[pick], res.v[pick], res.foot[pick], res.distance[pick], res.normal[pick],
            res.status[pick], res.iterations.reshape(n, reps).sum(axis=1),
        )
    if uv0 is None and global_check:
        _global_check(surface, samples, pts, res, tol, max_iter)
        _edge_check(surface, samples, pts, res, tol, max_iter)
        _failed_check(surface, samples, pts, res, tol, max_iter)
    if max_distance is not None:
        far = (res.status != FAILED) & (res.distance > max_distance)
        res.status[far] = BEYOND_TOLERANCE
    return res


_PIECES: "weakref.WeakKeyDictionary[NurbsSurface, list[NurbsSurface]]" = weakref.WeakKeyDictionary()


def smooth_pieces(surface: NurbsSurface) -> list[NurbsSurface]:
    """The surface split along its crease knot lines (`NurbsSurface.crease_knots`: interior
    knots across which the normal jumps) into smooth pieces (cached); ``[surface]`` when
    there are none.

    Newton cannot converge onto a crease inside one surface (the distance is not
    differentiable there); on the smooth pieces the crease is an edge, handled by clamping.
    Each piece is cut out exactly with its own clamped knot vectors (`restrict_surface`), so
    that derivatives at a piece's upper end come from that piece's side of the crease. With
    the whole knot vector and a smaller domain they came from the span above: the lower
    piece of FTR00037 (production NURBS die, a 1e-5 rad crease) then saw the upper side's
    zero gradient at the knot, stopped there and FAILED, and the foot went to the crease.
    """
    hit = _PIECES.get(surface)
    if hit is None:
        u0, u1, v0, v1 = surface.domain
        ku, kv = surface.crease_knots()
        eu = np.concatenate([[u0], ku, [u1]])
        ev = np.concatenate([[v0], kv, [v1]])
        if len(eu) == 2 and len(ev) == 2:
            hit = [surface]
        else:
            from cadbridge.nurbs.edits import restrict_surface

            hit = [restrict_surface(surface, (a, b, c, d)) for a, b in zip(eu[:-1], eu[1:]) for c, d in zip(ev[:-1], ev[1:])]
        _PIECES[surface] = hit
    return hit


def nearest_of_pieces(surface: NurbsSurface, pieces: list[NurbsSurface], results: list[SurfaceProjection]
                      ) -> SurfaceProjection:
    """Per point the nearest valid foot over the pieces; a foot on an internal crease line is
    an interior point of the whole surface (CONVERGED, normal one-sided from its piece's side)."""
    d = np.stack([np.where(r.status == FAILED, np.inf, r.distance) for r in results])
    d = np.where(np.isfinite(d), d, np.inf)
    # ties (a foot on a crease line is in both pieces): the last piece, i.e. the one above
    # the knot, so the normal there follows the usual convention knots[i] <= u < knots[i+1]
    dmin = d.min(axis=0)
    tie = d <= dmin + 1e-12 * (1.0 + np.where(np.isfinite(dmin), dmin, 0.0))
    best = d.shape[0] - 1 - np.argmax(tie[::-1], axis=0)
    rows = np.arange(d.shape[1])
    pick = lambda name: np.stack([getattr(r, name) for r in results])[best, rows]  # noqa: E731
    out = SurfaceProjection(pick("u"), pick("v"), pick("foot"), pick("distance"), pick("normal"),
                            pick("status").copy(), np.stack([r.iterations for r in results]).sum(axis=0))
    u0, u1, v0, v1 = surface.domain
    dom = np.array([pc.domain for pc in pieces])[best]  # (N, 4) of each point's piece
    eps_u, eps_v = 1e-12 * (u1 - u0), 1e-12 * (v1 - v0)
    at_lo_u = (np.abs(out.u - dom[:, 0]) <= eps_u) & (dom[:, 0] > u0)
    at_hi_u = (np.abs(out.u - dom[:, 1]) <= eps_u) & (dom[:, 1] < u1)
    at_lo_v = (np.abs(out.v - dom[:, 2]) <= eps_v) & (dom[:, 2] > v0)
    at_hi_v = (np.abs(out.v - dom[:, 3]) <= eps_v) & (dom[:, 3] < v1)
    inner = (at_lo_u | at_hi_u | at_lo_v | at_hi_v) & (out.status != FAILED)
    if np.any(inner):
        side_u = np.where(at_hi_u[inner], -1, 1)
        side_v = np.where(at_hi_v[inner], -1, 1)
        out.normal[inner] = surface.normal(out.u[inner], out.v[inner], side_u=side_u, side_v=side_v)
        # still on the outer boundary in the other direction? keep ON_BOUNDARY then
        on_outer = ((np.abs(out.u[inner] - u0) <= eps_u) | (np.abs(out.u[inner] - u1) <= eps_u)
                    | (np.abs(out.v[inner] - v0) <= eps_v) | (np.abs(out.v[inner] - v1) <= eps_v))
        st = out.status[inner]
        st[(st == ON_BOUNDARY) & ~on_outer] = CONVERGED
        out.status[inner] = st
    return out


def _global_check(
    surface: NurbsSurface, samples: SurfaceSamples, pts: np.ndarray, res: SurfaceProjection, tol: float, max_iter: int
) -> None:
    """Restart Newton from other local minima of the sampled distance; update ``res`` in place
    where a nearer valid foot is found."""
    n = len(pts)
    m = len(samples.uv)
    mu, mv = len(samples.us), len(samples.vs)
    k = min(CHECK_K, m)
    if n == 0 or m < 2:
        return
    d = np.where(res.status == FAILED, np.inf, res.distance)
    d = np.where(np.isfinite(d), d, np.inf)
    dk, ik = samples.tree.query(pts, k=k)
    dk, ik = dk.reshape(n, k), ik.reshape(n, k)
    rows, sidx = global_seeds(d, dk, ik.astype(np.int64), samples.spacing, samples.points, pts,
                              np.ascontiguousarray(res.u), np.ascontiguousarray(res.v), samples.us, samples.vs,
                              samples.closed_u, samples.closed_v, CHECK_SEEDS)
    if rows.size == 0:
        return
    uv = samples.uv[sidx]
    extra = _newton(surface, samples, pts[rows], uv[:, 0].copy(), uv[:, 1].copy(), tol, max_iter)
    better = (extra.status != FAILED) & (extra.distance < d[rows])
    if not np.any(better):
        return
    rows, extra_idx = rows[better], np.nonzero(better)[0]
    # several improvements for one point: keep the nearest (last write wins after sorting)
    order = np.argsort(-extra.distance[extra_idx], kind="stable")
    rows, extra_idx = rows[order], extra_idx[order]
    for name in ("u", "v", "foot", "distance", "normal", "status"):
        getattr(res, name)[rows] = getattr(extra, name)[extra_idx]
    res.iterations[rows] += extra.iterations[extra_idx]


_EDGES = ((0, 0, 1), (0, -1, -2), (1, 0, 1), (1, -1, -2))  # (axis, edge row, next row): u0, u1, v0, v1


COLLAPSED_REL = 1e-2
"""A domain edge whose samples span less than this fraction of the next grid ring's span is
treated as a pole by the Newton restarts (`pole_starts`): a strip that runs out at a corner
(t4mec's fillet patch: its u = 1 edge spans 0.002 mm where the next ring spans 10 mm) has
all its nearest samples on that edge, and Newton from them stalls or slides to the wrong
edge as on a true pole."""


def pole_edges(samples: SurfaceSamples) -> tuple[bool, bool, bool, bool]:
    """Which domain edges u0, u1, v0, v1 are poles, or collapsed to a near-point: all their
    samples within 1e-9 x size, or spanning less than `COLLAPSED_REL` x the next grid ring."""
    g = samples.points.reshape(len(samples.us), len(samples.vs), 3)
    out = []
    for axis, e, r in _EDGES:
        if g.shape[axis] < 2 or g.shape[1 - axis] < 2:
            out.append(False)
            continue
        edge, ring = (g[e], g[r]) if axis == 0 else (g[:, e], g[:, r])
        span = float(np.ptp(edge, axis=0).max())
        out.append(span <= 1e-9 * samples.size or span < COLLAPSED_REL * float(np.ptp(ring, axis=0).max()))
    return tuple(out)


def on_pole_sample(samples: SurfaceSamples, idx: np.ndarray) -> np.ndarray:
    """(K,) bool: whether grid samples ``idx`` (K,) lie on a pole or collapsed edge (`pole_edges`)."""
    iu, iv = np.divmod(np.asarray(idx, dtype=np.int64), len(samples.vs))
    pe = pole_edges(samples)
    return ((pe[0] & (iu == 0)) | (pe[1] & (iu == len(samples.us) - 1))
            | (pe[2] & (iv == 0)) | (pe[3] & (iv == len(samples.vs) - 1)))


def pole_starts(samples: SurfaceSamples, domain, pts: np.ndarray, u: np.ndarray, v: np.ndarray,
                stalled: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Newton restarts for feet on a degenerate edge (a pole: the whole edge is one point,
    e.g. a sphere cap of revolution at u = 0).

    A pole has no azimuth: its samples all coincide, so the nearest samples and the inward
    steps keep the start's arbitrary v (or u) and Newton slides back to the pole, 0.68 mm
    off on the SolidWorks file of the OCC corpus. The restarts are the nearest sample of the
    grid ring next to the pole, and half-way to it, both carrying the point's azimuth.
    A point near the pole whose nearest sample is a pole sample starts Newton there with an
    arbitrary azimuth, where Su (or Sv) vanishes: the iteration can wander and stall
    (FAILED) anywhere; ``stalled`` (K,) bool marks such feet, which get the same restarts
    wherever they ended (points 6e-5 off a cone 0.6 mm from its apex).

    pts (K, 3), u, v (K,) the feet; returns start u, v and the row (into the K) of each."""
    u0, u1, v0, v1 = domain
    us, vs = samples.us, samples.vs
    g = samples.points.reshape(len(us), len(vs), 3)
    guv = samples.uv.reshape(len(us), len(vs), 2)
    eps = 1e-12 * (u1 - u0), 1e-12 * (v1 - v0)
    out_u, out_v, out_i = [np.zeros(0)], [np.zeros(0)], [np.zeros(0, dtype=np.int64)]
    for (axis, e, r), pole in zip(_EDGES, pole_edges(samples)):
        if not pole:
            continue
        t_edge = (u0, u1)[e] if axis == 0 else (v0, v1)[e]
        t_ring = (us if axis == 0 else vs)[r]
        # a foot on the pole, or in its first grid cell (a collapsed edge: the foot of a point
        # beside it lands near the edge, on a neighbouring edge)
        on = np.abs((u if axis == 0 else v) - t_edge) <= max(eps[axis], abs(t_ring - t_edge))
        on = np.flatnonzero(on if stalled is None else on | stalled)
        if not len(on):
            continue
        ring, ring_uv = (g[r], guv[r]) if axis == 0 else (g[:, r], guv[:, r])
        d2 = ((pts[on][:, None, :] - ring[None, :, :]) ** 2).sum(axis=2)
        best = ring_uv[np.argmin(d2, axis=1)]
        for frac in (1.0, 0.5):
            st = best.copy()
            st[:, axis] = t_edge + frac * (best[:, axis] - t_edge)
            out_u.append(st[:, 0])
            out_v.append(st[:, 1])
            out_i.append(on)
    return np.concatenate(out_u), np.concatenate(out_v), np.concatenate(out_i)


def _edge_check(
    surface: NurbsSurface, samples: SurfaceSamples, pts: np.ndarray, res: SurfaceProjection, tol: float, max_iter: int
) -> None:
    """Feet clamped to a domain edge (ON_BOUNDARY): restart Newton half a grid cell and one
    grid cell inside the domain from the edge foot. A wavy surface can have an interior
    minimum within one grid cell of the edge while the distance still decreases outwards at
    the edge (the edge sample is then the nearest sample and the discrete local-minimum test
    of `_global_check` cannot see the interior one). Updates ``res`` in place where nearer."""
    rows = np.nonzero(res.status == ON_BOUNDARY)[0]
    # a foot that FAILED (Newton stalled) on a pole gets the pole restarts as well, and so
    # does a point off the surface whose nearest sample lies on a pole or collapsed edge
    # (from there Newton may settle in a local minimum anywhere)
    near_pole = np.zeros(len(pts), dtype=bool)
    if any(pole_edges(samples)):
        near_pole = on_pole_sample(samples, samples.tree.query(pts)[1]) & ~(res.distance <= 1e-10 * samples.size)
    pole_rows = np.nonzero((res.status == ON_BOUNDARY) | (res.status == FAILED) | near_pole)[0]
    if pole_rows.size == 0:
        return
    u0, u1, v0, v1 = surface.domain
    us, vs = samples.us, samples.vs

    def inward(t, grid, lo, hi, frac):
        if len(grid) < 2:
            return t
        k = np.clip(np.searchsorted(grid, t), 1, len(grid) - 1)
        h = grid[k] - grid[k - 1]
        return np.where(t <= lo, lo + frac * h, np.where(t >= hi, hi - frac * h, t))

    ur, vr = res.u[rows], res.v[rows]
    starts_u, starts_v, owner = [], [], []
    for frac in (0.5, 1.0):
        starts_u.append(inward(ur, us, u0, u1, frac))
        starts_v.append(inward(vr, vs, v0, v1, frac))
        owner.append(rows)
    # ... and from the nearest grid samples within the global check's radius: along an edge
    # the sampled distance may fall monotonically towards the edge foot although a nearer
    # interior minimum sits between two samples of that edge (steep, wavy surfaces)
    k = min(CHECK_K, len(samples.uv))
    if k > 1:
        dk, ik = samples.tree.query(pts[rows], k=k)
        dk, ik = dk.reshape(len(rows), k), ik.reshape(len(rows), k)
        d = res.distance[rows]
        rad = np.sqrt(d * d + (2.0 * samples.spacing[ik[:, 0]]) ** 2)
        cand = dk <= rad[:, None]
        cand[:, 0] = False
        cand &= np.cumsum(cand, axis=1) <= EDGE_SEEDS
        rr, cc = np.nonzero(cand)
        uv = samples.uv[ik[rr, cc]]
        starts_u.append(uv[:, 0])
        starts_v.append(uv[:, 1])
        owner.append(rows[rr])
    pu, pv, pi = pole_starts(samples, surface.domain, pts[pole_rows], res.u[pole_rows], res.v[pole_rows],
                             (res.status[pole_rows] == FAILED) | near_pole[pole_rows])
    starts_u.append(pu)
    starts_v.append(pv)
    owner.append(pole_rows[pi])
    su, sv, owner = np.concatenate(starts_u), np.concatenate(starts_v), np.concatenate(owner)
    extra = _newton(surface, samples, pts[owner], su, sv, tol, max_iter)
    d = res.distance[owner]
    d = np.where((res.status[owner] == FAILED) | np.isnan(d), np.inf, d)  # any valid foot beats a failed one
    better = (extra.status != FAILED) & (extra.distance < d - 1e-3 * tol * samples.size)
    if not np.any(better):
        return
    idx = np.nonzero(better)[0]
    order = np.argsort(-extra.distance[idx], kind="stable")  # nearest written last
    idx = idx[order]
    tgt = owner[idx]
    for name in ("u", "v", "foot", "distance", "normal", "status"):
        getattr(res, name)[tgt] = getattr(extra, name)[idx]
    res.iterations[tgt] += extra.iterations[idx]


def _failed_check(
    surface: NurbsSurface, samples: SurfaceSamples, pts: np.ndarray, res: SurfaceProjection, tol: float, max_iter: int
) -> None:
    """Points whose Newton still FAILED after the global and edge checks: restart from their
    2nd to (1 + `FAILED_SEEDS`)th nearest grid samples, keeping the nearest foot found. Beside a
    tight curl of the surface (the 0.4 mm edge roll of ``occt_bug24012_face``, whose normal
    turns by 120 degrees within one grid cell) the nearest sample can lie past the curl, Newton
    from it leaves the domain, and the samples around it need not be discrete local minima of
    the sampled distance (which `_global_check` restarts from). Those still FAILED restart from
    the next 12 and then the next 48 samples: beside a pole many samples of the grid sit at
    almost one point (a generatrix ending 0.035 mm from the axis: PRO19800), so the nearest
    few all start Newton in the collapsed corner, where it stalls. Updates ``res`` in place."""
    done = 1
    for k in (FAILED_SEEDS + 1, 4 * (FAILED_SEEDS + 1), 16 * (FAILED_SEEDS + 1)):  # widening rings of seeds
        rows = np.nonzero(res.status == FAILED)[0]
        k = min(k, len(samples.uv))
        if rows.size == 0 or k <= done:
            return
        _, ik = samples.tree.query(pts[rows], k=k)
        ik = np.asarray(ik).reshape(len(rows), k)[:, done:]
        owner = np.repeat(rows, k - done)
        done = k
        uv = samples.uv[ik.ravel()]
        extra = _newton(surface, samples, pts[owner], uv[:, 0].copy(), uv[:, 1].copy(), tol, max_iter)
        idx = np.nonzero(extra.status != FAILED)[0]
        if idx.size == 0:
            continue
        idx = idx[np.argsort(-extra.distance[idx], kind="stable")]  # nearest written last
        tgt = owner[idx]
        for name in ("u", "v", "foot", "distance", "normal", "status"):
            getattr(res, name)[tgt] = getattr(extra, name)[idx]
        res.iterations[tgt] += extra.iterations[idx]


_NEWTON_BLOCK = 1024  # points per task of the parallel Newton kernel
_NEWTON_PARALLEL_MIN = 16384  # fewer points: serial (thread start-up costs more than it saves)


@numba.njit(cache=True, error_model="numpy")
def _newton_serial(pw, ku, kv, p, q, rational, u0, u1, v0, v1, cu, cv, eps1, eps2, pts, noise, u, v, iters,
                   max_iter):  # pragma: no cover - compiled
    newton_range(pw, ku, kv, p, q, rational, u0, u1, v0, v1, cu, cv, eps1, eps2, pts, noise, u, v, iters,
                 max_iter, 0, pts.shape[0], u, v, -1.0, -1.0, np.zeros(0, dtype=np.bool_))


@numba.njit(cache=True, parallel=True, error_model="numpy")
def _newton_parallel(pw, ku, kv, p, q, rational, u0, u1, v0, v1, cu, cv, eps1, eps2, pts, noise, u, v, iters,
                     max_iter):  # pragma: no cover - compiled
    n = pts.shape[0]
    for blk in numba.prange((n + _NEWTON_BLOCK - 1) // _NEWTON_BLOCK):
        newton_range(pw, ku, kv, p, q, rational, u0, u1, v0, v1, cu, cv, eps1, eps2, pts, noise, u, v, iters,
                     max_iter, blk * _NEWTON_BLOCK, min(n, (blk + 1) * _NEWTON_BLOCK), u, v, -1.0, -1.0,
                     np.zeros(0, dtype=np.bool_))


def _newton(
    surface: NurbsSurface,
    samples: SurfaceSamples,
    pts: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    tol: float,
    max_iter: int,
) -> SurfaceProjection:
    """Vectorised projected Newton iterations from (u, v); see the module docstring."""
    n = len(pts)
    u0, u1, v0, v1 = surface.domain
    pu, pv = u1 - u0, v1 - v0
    cu, cv = samples.closed_u, samples.closed_v
    size = max(samples.size, 1e-300)
    eps1 = tol * size
    eps2 = tol
    tiny = 1e-300

    def wrap_clamp(uu: np.ndarray, vv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uu = u0 + np.mod(uu - u0, pu) if cu else np.clip(uu, u0, u1)
        vv = v0 + np.mod(vv - v0, pv) if cv else np.clip(vv, v0, v1)
        return uu, vv

    u, v = wrap_clamp(u, v)
    u = np.ascontiguousarray(u, dtype=float)
    v = np.ascontiguousarray(v, dtype=float)
    iters = np.zeros(n, dtype=np.int32)
    # absolute round-off of r = S - P per point: a few ulps of the largest coordinate involved
    noise = 64.0 * np.finfo(float).eps * (np.max(np.abs(pts), axis=1) + size) if n else np.zeros(0)
    if n:
        kernel = _newton_parallel if n >= _NEWTON_PARALLEL_MIN and parallel_kernels() else _newton_serial
        kernel(surface._pw, surface.knots_u, surface.knots_v, surface.degree_u, surface.degree_v,
               surface.rational, u0, u1, v0, v1, cu, cv, eps1, eps2,
               np.ascontiguousarray(pts, dtype=float), noise, u, v, iters, int(max_iter))

    # ---------------------------------------------------------------- final classification
    der = surface.derivatives(u, v, order=1)
    foot, su, sv = der[:, 0, 0], der[:, 1, 0], der[:, 0, 1]
    r = foot - pts
    dist = np.sqrt(_dot(r, r))
    f, g = _dot(su, r), _dot(sv, r)
    lsu = np.sqrt(_dot(su, su))
    lsv = np.sqrt(_dot(sv, sv))
    edge_u = np.zeros(n, dtype=bool) if cu else ((u <= u0) & (f > 0)) | ((u >= u1) & (f < 0))
    edge_v = np.zeros(n, dtype=bool) if cv else ((v <= v0) & (g > 0)) | ((v >= v1) & (g < 0))
    # tangential offset of the foot (how far from orthogonal), in length units
    # (no offset along a direction that does not move the point: a pole, where it is round-off)
    off_u = np.where(edge_u | (lsu <= 1e-9 * lsv), 0.0, np.abs(f) / np.maximum(lsu, tiny))
    off_v = np.where(edge_v | (lsv <= 1e-9 * lsu), 0.0, np.abs(g) / np.maximum(lsv, tiny))
    cos_u = np.abs(f) / np.maximum(lsu * dist, tiny)
    cos_v = np.abs(g) / np.maximum(lsv * dist, tiny)
    # a binding edge is only reported when the cosine is really non-zero there
    binding = ((edge_u & (cos_u > eps2)) | (edge_v & (cos_v > eps2))) & (dist > eps1)
    # every foot (converged by a test or not) must be orthogonal to ~1e-9 x size: a stalled
    # iteration (line search at noise level, iteration cap) never passes as a foot point
    ok = np.maximum(off_u, off_v) <= 1e3 * eps1 + noise
    ok &= np.isfinite(dist) & np.isfinite(u) & np.isfinite(v)
    status = np.where(binding, ON_BOUNDARY, CONVERGED).astype(np.int8)
    status[~ok] = FAILED
    # unit Su x Sv from the derivatives at hand; degenerate points (poles, collapsed edges)
    # take the limit normal of `NurbsSurface.normal` (same test, same arithmetic otherwise)
    normal = np.cross(su, sv)
    ln = np.linalg.norm(normal, axis=1)
    degenerate = ~(ln > 1e-10 * np.maximum(lsu, lsv) ** 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        normal = normal / ln[:, None]
    if np.any(degenerate):
        normal[degenerate] = surface.normal(u[degenerate], v[degenerate])
    normal[status == FAILED] = np.nan
    return SurfaceProjection(u, v, foot, dist, normal, status, iters)
