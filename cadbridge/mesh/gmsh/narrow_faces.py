"""Node counts for the curved boundary curves of narrow faces: chords that do not cut the face.

gmsh meshes a face on its boundary polygon: the chords between a curve's nodes. Where a face is
narrow (a ring 2 mm wide around a boss of R 28, a neck 0.6 mm wide between a straight edge and
two arcs) and its boundary curves bend within the face, the chords' sag L^2 k_g / 8 can reach
the width w of the face: the polygon then no longer holds the face, the elements cross its
edges, and their centres and edge midpoints lie outside it. With the all-quad subdivision,
which meshes at twice the size first and puts the new nodes on the surface nearest those
points, they land up to 3 mm off the trimmed face (trj10_b2, trj8_b1 in quads). gmsh's
curvature rule does not see it: it counts elements per turn of the curve, whatever the width.

Here every curved boundary curve of a face gets the node count that keeps each chord's sag
below `SAG_FRACTION` x the face's width there:

    h(s) <= sqrt(8 f w(s) / k_g(s))

w(s): the distance from the curve's point to the face's other boundary curves, those that
share no vertex with it (its neighbours at a corner meet it at distance 0). k_g(s): the
curve's geodesic curvature on the face (its curvature vector less the part along the surface
normal: a circle around a cylinder bends out of the face, not within it, and its chords cut
no band). The count is the integral of ds / min(h, gmsh's own size) over the curve, given to
gmsh as a transfinite curve (uniform nodes) only where it is more than gmsh would make.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

__all__ = ["narrow_curve_counts", "SAG_FRACTION", "SAMPLES"]

SAG_FRACTION = 0.25
"""Largest chord sag, as a fraction of the face's width where the chord is."""
SAMPLES = 33
"""Points per curve for its width and curvature."""
_MORE = 1.2
"""A count is set only where it is more than this x gmsh's own (else gmsh's grading stays)."""


def narrow_curve_counts(
    g,
    surfaces: list[int],
    *,
    size: float,
    curvature_elements: int,
    min_size: float,
    size_at: Callable[[np.ndarray], np.ndarray] | None = None,
    cache: dict | None = None,
    even: bool = False,
) -> dict[int, int]:
    """{gmsh curve tag: segments} for the curves of ``surfaces`` whose chords would cut a
    narrow face (module docs). ``size``, ``curvature_elements``, ``min_size``: gmsh's
    ``Mesh.MeshSizeMax``, ``Mesh.MeshSizeFromCurvature`` and ``Mesh.MeshSizeMin`` as set;
    ``size_at(xyz (N, 3)) -> (N,)``: the size the other rules ask at points (background field
    or callback), or None; ``cache``: a dict kept between calls on one gmsh model (the curves'
    samples); ``even``: even counts only (quads: a face whose boundary has an odd number of
    segments cannot be all quads, and the mesh would go through the subdivision at twice the
    size, with twice the nodes: the bearing in quads). ``g`` the gmsh module with the model
    loaded."""
    cache = {} if cache is None else cache
    samples = cache.setdefault("samples", {})  # {curve: (x, t, k) or None}
    ends = cache.setdefault("ends", {})  # {curve: its vertices}
    geodesic = cache.setdefault("geodesic", {})  # {(curve, surface): k_g}
    faces = cache.setdefault("faces", {})  # {surface: its curves}
    need: dict[int, float] = {}
    for s in surfaces:  # loop over faces: a few gmsh calls each, on the first call
        if s not in faces:
            faces[s] = sorted({abs(t) for _, t in g.model.getBoundary([(2, s)], combined=False, oriented=False)})
        curves = faces[s]
        for c in curves:
            if c not in samples:
                samples[c] = _sample(g, c)
                ends[c] = {abs(t) for _, t in g.model.getBoundary([(1, c)], combined=False, oriented=False)}
        curves = [c for c in curves if samples[c] is not None]
        if len(curves) < 2:
            continue
        boxes = np.array([np.concatenate([samples[c][0].min(axis=0), samples[c][0].max(axis=0)]) for c in curves])
        for i, c in enumerate(curves):
            x, t, k = samples[c]
            if not np.any(k > 0):
                continue
            own = _gmsh_sizes(x, k, size, curvature_elements, min_size, size_at)
            # the width below which a chord at gmsh's size would cut the face (k >= k_g)
            reach = float(np.max(own * own * k)) / (8.0 * SAG_FRACTION * _MORE * _MORE)
            gap = np.max(np.maximum(boxes[:, :3] - boxes[i, 3:], boxes[i, :3] - boxes[:, 3:]), axis=1)
            others = [o for j, o in enumerate(curves) if gap[j] < reach and o != c and not (ends[o] & ends[c])]
            if not others:  # most curves: no other curve of the face that near
                continue
            w = _distance_to_polylines(x, [samples[o][0] for o in others])
            if not np.any(np.sqrt(8.0 * SAG_FRACTION * w / np.maximum(k, 1e-300)) < own / _MORE):
                continue
            if (c, s) not in geodesic:
                geodesic[c, s] = _geodesic_curvature(g, c, s, t)
            h = np.maximum(np.sqrt(8.0 * SAG_FRACTION * w / np.maximum(geodesic[c, s], 1e-300)), min_size)
            ds = np.linalg.norm(np.diff(x, axis=0), axis=1)
            hh = np.minimum(h, own)
            n_own = float(np.sum(ds / np.maximum(0.5 * (own[1:] + own[:-1]), 1e-300)))
            n_need = float(np.sum(ds / np.maximum(0.5 * (hh[1:] + hh[:-1]), 1e-300)))
            if n_need > _MORE * max(n_own, 2.0):  # (gmsh gives a curve 2 segments at least)
                need[c] = max(need.get(c, 0.0), n_need)
    counts = {c: int(math.ceil(n)) for c, n in need.items()}
    return {c: m + (m % 2) for c, m in counts.items()} if even else counts


def _sample(g, c: int):
    """(points (K, 3), parameters (K,), curvature (K,)) of curve ``c``; None for a degenerate
    curve (gmsh bounds a pole's edge by +-1e308)."""
    lo, hi = g.model.getParametrizationBounds(1, c)
    if not (math.isfinite(lo[0]) and math.isfinite(hi[0])) or abs(hi[0]) > 1e300 or abs(lo[0]) > 1e300:
        return None
    t = np.linspace(lo[0], hi[0], SAMPLES)
    x = np.asarray(g.model.getValue(1, c, t.tolist()), dtype=float).reshape(-1, 3)
    k = np.abs(np.asarray(g.model.getCurvature(1, c, t.tolist()), dtype=float))
    k[~np.isfinite(k) | (k > 1e200)] = 0.0
    if not np.all(np.isfinite(x)):
        return None
    return x, t, k


def _distance_to_polylines(p: np.ndarray, lines: list[np.ndarray]) -> np.ndarray:
    """Distance (K,) from points ``p`` (K, 3) to the nearest segment of ``lines`` (polylines
    (M_i, 3))."""
    a = np.concatenate([q[:-1] for q in lines])  # (S, 3) segment starts
    ab = np.concatenate([np.diff(q, axis=0) for q in lines])
    ap = p[:, None, :] - a[None, :, :]  # (K, S, 3)
    s = np.clip(np.einsum("ksj,sj->ks", ap, ab) / np.maximum(np.einsum("sj,sj->s", ab, ab), 1e-300), 0.0, 1.0)
    return np.min(np.linalg.norm(ap - s[:, :, None] * ab[None, :, :], axis=2), axis=1)


def _gmsh_sizes(x: np.ndarray, k: np.ndarray, size: float, curvature_elements: int, min_size: float,
                size_at) -> np.ndarray:
    """The size (K,) gmsh's rules ask at a curve's points: the largest size, the curvature rule
    (``curvature_elements`` per turn), the field; no less than ``min_size``."""
    h = np.full(len(x), size)
    if curvature_elements:
        with np.errstate(divide="ignore"):
            h = np.minimum(h, 2.0 * math.pi / (np.maximum(k, 1e-300) * curvature_elements))
    if size_at is not None:
        h = np.minimum(h, np.asarray(size_at(x), dtype=float))
    return np.maximum(h, min_size)


def _geodesic_curvature(g, c: int, s: int, t: np.ndarray) -> np.ndarray:
    """|k - (k . n) n| (K,) of curve ``c`` at parameters ``t`` on surface ``s``: its curvature
    vector k = (r'' - (r'' . T) T) / |r'|^2 less the part along the surface normal n."""
    d1 = np.asarray(g.model.getDerivative(1, c, t.tolist()), dtype=float).reshape(-1, 3)
    d2 = np.asarray(g.model.getSecondDerivative(1, c, t.tolist()), dtype=float).reshape(-1, 3)
    speed = np.linalg.norm(d1, axis=1)
    ok = speed > 1e-300
    tt = d1 / np.where(ok, speed, 1.0)[:, None]
    kv = (d2 - np.einsum("ij,ij->i", d2, tt)[:, None] * tt) / np.where(ok, speed * speed, 1.0)[:, None]
    uv = np.asarray(g.model.reparametrizeOnSurface(1, c, t.tolist(), s), dtype=float)
    n = np.asarray(g.model.getNormal(s, uv.tolist()), dtype=float).reshape(-1, 3)
    nn = np.linalg.norm(n, axis=1)
    n = n / np.where(nn > 0, nn, 1.0)[:, None]
    kg = np.linalg.norm(kv - np.einsum("ij,ij->i", kv, n)[:, None] * n, axis=1)
    kg[~ok | ~np.isfinite(kg)] = 0.0
    return kg
