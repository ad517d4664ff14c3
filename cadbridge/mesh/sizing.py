"""Element sizes for a Nagata shape tolerance, from the exact CAD curvature.

The Nagata error law
--------------------
A Nagata edge over a circular arc of radius R with exact end normals has its largest radial
error in the middle of the edge, and that error converges at order 4 in the edge length
(thesis §3.1.1, Fig. 8 (b)):

    e = C h^4 / R^3,     C = 6.0e-4 / 0.52^4 = 8.2e-3                          (law)

with h the chord length (normalized edge length h / R; Fig. 8 gives a radial error of
0.060 % at h / R = 0.52, the U-shape's three elements over a quarter circle, §5.2). For a
surface the edge in the direction of the largest |principal curvature| k_max carries the
largest error, so the target edge length for a shape tolerance t is

    h(t, k) = (t / (C |k_max|^3))^(1/4)                                          (size)

(infinite on planes: they get the largest size allowed, i.e. as few elements as the
topology of their boundaries lets gmsh make).

`SizeField` turns (size) into a gmsh size callback: target sizes at sample points of the
faces (and at refinement marks added by the verification loop, `cadbridge.refine`), graded
away from each sample, h(x) = min_i (h_i + g |x - x_i|), clipped to [h_min, h_max].
Lengths in model units.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["NAGATA_ERROR_CONSTANT", "SizeField", "arc_error", "curvature_samples", "edge_length_for_tolerance"]

NAGATA_ERROR_CONSTANT = 6.0e-4 / 0.52 ** 4
"""C of e = C h^4 / R^3 (thesis Fig. 8: 0.060 % radial error at normalized edge length 0.52)."""


def arc_error(h: ArrayLike, radius: ArrayLike) -> NDArray:
    """Predicted max radial error [length] of a Nagata edge of chord ``h`` on an arc of ``radius``."""
    h = np.asarray(h, dtype=float)
    r = np.asarray(radius, dtype=float)
    return NAGATA_ERROR_CONSTANT * h ** 4 / r ** 3


def edge_length_for_tolerance(tolerance: float, curvature: ArrayLike, h_max: float = math.inf) -> NDArray:
    """Target edge length (N,) [length] for a shape ``tolerance`` [length] where the largest
    |principal curvature| is ``curvature`` (N,) [1/length]: eq. (size) of the module docs,
    ``h_max`` where the surface is flat."""
    if not (tolerance > 0 and math.isfinite(tolerance)):
        raise ValueError(f"shape tolerance must be a positive number, got {tolerance!r}")
    k = np.abs(np.asarray(curvature, dtype=float))
    with np.errstate(divide="ignore"):
        h = (tolerance / (NAGATA_ERROR_CONSTANT * k ** 3)) ** 0.25
    h = np.where(np.isfinite(h), h, h_max)
    return np.minimum(h, h_max)


def curvature_samples(model, per_span: int = 4, min_per_side: int = 9, max_per_side: int = 200):
    """Points on every face of ``model`` and the largest |principal curvature| there.

    Each face's underlying surface is sampled on a (u, v) grid with ``per_span`` points per
    knot span (at least ``min_per_side`` per side), so curvature changes inside spans are
    seen. Returns points (M, 3), k_max (M,) [1/length] (NaN at degenerate points are
    dropped) and face index (M,)."""
    from cadbridge.nurbs.curvature import principal_curvatures

    pts, ks, fs = [], [], []
    for i, f in enumerate(model.faces):  # loop over faces, vectorised over samples
        s = f.surface
        u0, u1, v0, v1 = s.domain
        nu = int(np.clip(per_span * len(np.unique(s.knots_u)), min_per_side, max_per_side))
        nv = int(np.clip(per_span * len(np.unique(s.knots_v)), min_per_side, max_per_side))
        # keep off the exact domain edge (one-sided knots) by a hair
        uu = np.linspace(u0, u1, nu)
        vv = np.linspace(v0, v1, nv)
        U, V = np.meshgrid(uu, vv, indexing="ij")
        U, V = U.ravel(), V.ravel()
        k1, k2 = principal_curvatures(s, U, V)
        k = np.maximum(np.abs(k1), np.abs(k2))
        ok = np.isfinite(k)
        pts.append(s.evaluate(U[ok], V[ok]))
        ks.append(k[ok])
        fs.append(np.full(int(ok.sum()), i))
    return np.concatenate(pts), np.concatenate(ks), np.concatenate(fs)


class SizeField:
    """Graded target size h(x) = clip(min_i (h_i + g |x - x_i|), h_min, h_max) over samples.

    points (M, 3), sizes (M,): target sizes at sample points; gradation g: how fast the size
    may grow away from a sample (0.5: an element next to one of size h may be 1.5 h).
    Marks (refinement requests) are added with `add`; the field is rebuilt lazily.
    """

    def __init__(self, points: ArrayLike, sizes: ArrayLike, h_min: float, h_max: float,
                 gradation: float = 0.5, k: int = 24) -> None:
        self.points = np.asarray(points, dtype=float).reshape(-1, 3)
        self.sizes = np.asarray(sizes, dtype=float).ravel()
        self.h_min, self.h_max, self.g, self.k = float(h_min), float(h_max), float(gradation), int(k)
        self._tree = None
        self.calls = 0

    def add(self, points: ArrayLike, sizes: ArrayLike) -> None:
        """Add samples (refinement marks): the field at x never exceeds h_i + g |x - x_i|."""
        self.points = np.vstack([self.points, np.asarray(points, dtype=float).reshape(-1, 3)])
        self.sizes = np.concatenate([self.sizes, np.asarray(sizes, dtype=float).ravel()])
        self._tree = None

    def _build(self):
        from scipy.spatial import cKDTree

        keep = self.sizes < self.h_max  # samples at h_max bound nothing
        pts, h = self.points[keep], np.maximum(self.sizes[keep], self.h_min)
        levels = np.unique(h)
        if len(levels) > self.max_levels:
            # round down to levels h_min r^j (r = LEVEL_RATIO): at most 1/r below the request
            j = np.floor(np.log(h / self.h_min) / math.log(self.LEVEL_RATIO) + 1e-9)
            h = self.h_min * self.LEVEL_RATIO ** j
            levels = np.unique(h)
        self._levels = [(float(lv), cKDTree(pts[h == lv])) for lv in levels]
        self._tree = True

    LEVEL_RATIO = 1.1
    max_levels = 64

    def __call__(self, x: ArrayLike) -> NDArray:
        """Target size at points x (N, 3) -> (N,): min_i (h_i + g |x - x_i|) over all samples,
        exactly (one nearest-sample query per size level, within the distance where that
        level can still be below h_max; with more than ``max_levels`` distinct sizes, sizes
        are first rounded down to levels LEVEL_RATIO apart)."""
        if self._tree is None:
            self._build()
        x = np.atleast_2d(np.asarray(x, dtype=float))
        h = np.full(len(x), self.h_max)
        for lv, tree in self._levels:  # loop over the size levels, vectorised over points
            reach = (self.h_max - lv) / self.g if self.g > 0 else np.inf
            d, _ = tree.query(x, k=1, distance_upper_bound=reach)
            h = np.minimum(h, lv + self.g * d)  # d = inf beyond reach
        return np.clip(h, self.h_min, self.h_max)

    def background(self, extra: ArrayLike | None = None, neighbours: int = 6) -> tuple[NDArray, NDArray]:
        """Points (M, 3) and sizes (M,) for a nearest-point background size field
        (`cadbridge.mesh.generate.mesh_cad`'s ``background_sizes``), evaluated in gmsh
        without a Python call per query.

        Carriers are the field's samples and marks plus ``extra`` points (K, 3) (e.g. the
        nodes of the previous mesh, dense where the sizes are small). A query point x takes
        the size of its nearest carrier c, so each carrier gets the smallest size the field
        reaches halfway to its ``neighbours`` nearest carriers j, min(h(c), h(j) + g |c - j| / 2)
        (the border of its Voronoi cell towards them): where the field falls from c towards a
        neighbour (a mark, a smaller radius), c's cell already has the smaller size; where
        it is flat, c keeps its own."""
        from scipy.spatial import cKDTree

        pts = self.points if extra is None else np.vstack([self.points, np.asarray(extra, dtype=float).reshape(-1, 3)])
        pts = np.unique(pts, axis=0)
        if len(pts) == 0:
            return np.zeros((1, 3)), np.array([self.h_max])
        k = min(neighbours + 1, len(pts))
        d, j = cKDTree(pts).query(pts, k=k)
        d, j = d.reshape(len(pts), -1), j.reshape(len(pts), -1)  # column 0: the point itself
        hc = self(pts)
        h = np.min(hc[j] + 0.5 * self.g * d, axis=1)
        return pts, np.clip(h, self.h_min, self.h_max)

    def gmsh_callback(self):
        """``callback(dim, tag, x, y, z, lc) -> size`` for `gmsh.model.mesh.setSizeCallback`.

        gmsh asks for sizes at many nearby points (about 90 000 calls for a 600-node mesh),
        so values are cached on a lattice of spacing q = h_min: a point gets the field at its
        cell centre less g q sqrt(3) / 2 (the most the field can drop within the cell), never
        more than the field at any point of the cell."""
        q = self.h_min
        off = self.g * q * math.sqrt(3.0) / 2.0
        cache: dict[tuple[int, int, int], float] = {}

        def cb(dim, tag, x, y, z, lc):
            self.calls += 1
            key = (math.floor(x / q), math.floor(y / q), math.floor(z / q))
            h = cache.get(key)
            if h is None:
                c = (np.array(key, dtype=float) + 0.5) * q
                h = max(float(self(c[None])[0]) - off, self.h_min)
                cache[key] = h
            return min(lc, h)

        return cb
