"""Feet of model-space trim edges on a NURBS surface: the reference tables of
`analytic.invert_edges` (B-rep loops without parameter-space curves).

The samples of one edge piece follow each other closely and lie on the surface (up to the
file's trim delta), so their feet follow each other too. Instead of a global projection of
every sample (`project_to_surface`: KD-tree seed, Newton, then restarts from other local
minima of the sampled distance and from inside a domain edge), only the two ends of each
piece are projected globally (the anchors); the samples in between are reached by
continuation: Newton (the projected Newton of `nurbs.project`, compiled, Neto 2010 app. B
eqs. 32-36) from the previous foot extrapolated along the piece, one or two iterations each.

The continued feet are checked before they are used; a piece fails the check, and all its
samples get the global projection as before, when
  - a foot is not orthogonal (tangential offset above ``1e3 x 1e-12 x size`` plus round-off,
    the acceptance test of `nurbs.project`) where it is neither clamped to a domain edge
    nor at a pole;
  - a sample is farther than ``FAR_REL`` x size from its foot (beyond what the reader calls
    consistent trims: the continuation argument needs the edge on the surface);
  - the continued foot of the last sample is farther than the global foot of that sample
    (the continuation left the global branch), beyond ``1e-9 x size``.
Along a piece that stays within the surface's reach (distance to the surface below the
smallest radius of curvature and half the narrowest gap of the surface), the nearest point
is unique and moves continuously, so continuation from a global foot stays on the global
branch; seams and poles are the only ties, and `invert_edges` unwraps / fills them after.
"""

from __future__ import annotations

import numba
import numpy as np

from cadbridge.nurbs.project import FAILED, _newton_range, project_to_surface, surface_samples
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["edge_feet", "FAR_REL"]

FAR_REL = 1e-3  # samples farther from the surface than this x size get the global projection
TOL = 1e-12  # Newton tolerance (eps1 = TOL x size, eps2 = TOL), as `project_to_surface`
MAX_ITER = 30


@numba.njit(cache=True, error_model="numpy")
def _march(pw, ku, kv, p, q, rational, u0, u1, v0, v1, cu, cv, eps1, eps2, pts, t, noise, starts, u, v, iters,
           max_iter):  # pragma: no cover - compiled
    """Continuation along each piece k (samples starts[k] .. starts[k+1]-1; u, v given at the
    first sample): the seed of sample i is the foot of i-1 extrapolated linearly in t from
    i-2 and i-1 (periodic differences taken modulo the period, then wrapped / clamped into
    the domain), then `_newton_range` on that one sample. Updates u, v, iters in place."""
    pu = u1 - u0
    pv = v1 - v0
    for k in range(len(starts) - 1):
        a, b = starts[k], starts[k + 1]
        for i in range(a + 1, b):
            su, sv = u[i - 1], v[i - 1]
            if i - 2 >= a and t[i - 1] > t[i - 2]:
                du = u[i - 1] - u[i - 2]
                dv = v[i - 1] - v[i - 2]
                if cu:
                    du -= pu * np.rint(du / pu)
                if cv:
                    dv -= pv * np.rint(dv / pv)
                s = (t[i] - t[i - 1]) / (t[i - 1] - t[i - 2])
                su += du * s
                sv += dv * s
            if cu:
                su = u0 + (su - u0) % pu
            else:
                su = min(max(su, u0), u1)
            if cv:
                sv = v0 + (sv - v0) % pv
            else:
                sv = min(max(sv, v0), v1)
            u[i] = su
            v[i] = sv
            _newton_range(pw, ku, kv, p, q, rational, u0, u1, v0, v1, cu, cv, eps1, eps2, pts, noise, u, v, iters,
                          max_iter, i, i + 1)


def edge_feet(surface: NurbsSurface, pts: np.ndarray, t: np.ndarray, starts: np.ndarray,
              pole_tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Global feet on ``surface`` of the samples ``pts`` (M, 3) of consecutive edge pieces:
    piece k holds rows starts[k] .. starts[k+1]-1 (starts (P+1,), increasing), sampled at
    increasing parameters ``t`` (M,) of its own curve. ``pole_tol``: |S_u| or |S_v| at most
    this is a pole (that parameter undefined, its offset not checked).

    Returns (uv (M, 2), failed (M,) bool): the feet as `project_to_surface` gives them (closed
    directions wrapped into the domain): at the ends of each piece its global projections, in
    between continued from the first one (module docstring); where the continuation fails its
    checks, the piece's global projections (``failed``: rows where even that found no foot)."""
    pts = np.ascontiguousarray(pts, dtype=float)
    t = np.ascontiguousarray(t, dtype=float)
    starts = np.ascontiguousarray(starts, dtype=np.int64)
    n = len(pts)
    samples = surface_samples(surface)
    size = max(samples.size, 1e-300)
    u0, u1, v0, v1 = surface.domain
    first, last = starts[:-1], starts[1:] - 1
    anchors = np.unique(np.concatenate([first, last]))
    g = project_to_surface(surface, pts[anchors], tol=TOL, max_iter=MAX_ITER)
    u = np.empty(n)
    v = np.empty(n)
    pos = np.searchsorted(anchors, first)
    u[first], v[first] = g.u[pos], g.v[pos]
    iters = np.zeros(n, dtype=np.int32)
    noise = 64.0 * np.finfo(float).eps * (np.max(np.abs(pts), axis=1) + size)
    _march(surface._pw, surface.knots_u, surface.knots_v, surface.degree_u, surface.degree_v, surface.rational,
           u0, u1, v0, v1, samples.closed_u, samples.closed_v, TOL * size, TOL, pts, t, noise, starts, u, v, iters,
           MAX_ITER)
    # ---------------------------------------------------------------- checks (module docstring)
    d = surface.derivatives(u, v, order=1)
    r = d[:, 0, 0] - pts
    dist = np.sqrt(np.einsum("ij,ij->i", r, r))
    bad = ~np.isfinite(dist) | (dist > FAR_REL * size)
    for k, s_k, x, lo, hi, closed in ((0, d[:, 1, 0], u, u0, u1, samples.closed_u),
                                      (1, d[:, 0, 1], v, v0, v1, samples.closed_v)):
        f = np.einsum("ij,ij->i", s_k, r)
        ls = np.sqrt(np.einsum("ij,ij->i", s_k, s_k))
        held = np.zeros(n, dtype=bool) if closed else ((x <= lo) & (f > 0)) | ((x >= hi) & (f < 0))
        off = np.abs(f) / np.maximum(ls, 1e-300)
        bad |= ~(held | (ls <= pole_tol) | (off <= 1e3 * TOL * size + noise))
    pos_last = np.searchsorted(anchors, last)
    gd = np.where(g.status[pos_last] == FAILED, np.inf, g.distance[pos_last])
    left = dist[last] > gd + 1e-9 * size  # the continuation is not on the global branch at the end
    piece_bad = np.add.reduceat(bad.astype(np.int64), first) > 0
    piece_bad |= left | (g.status[pos] == FAILED)
    uv = np.column_stack([u, v])
    # both ends keep their global feet (the continued last one agrees in distance): a vertex on
    # a domain edge is then exactly on it, as the projection's clamp puts it
    uv[last] = np.column_stack([g.u[pos_last], g.v[pos_last]])
    failed = np.zeros(n, dtype=bool)
    if np.any(piece_bad):
        rows = np.concatenate([np.arange(a, b) for a, b, x in zip(first, starts[1:], piece_bad) if x])
        full = project_to_surface(surface, pts[rows])
        uv[rows] = np.column_stack([full.u, full.v])
        failed[rows] = full.status == FAILED
    return uv, failed
