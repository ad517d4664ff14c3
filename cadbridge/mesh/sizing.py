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
faces (and at refinement marks added by the verification loop, `cadbridge.tool.refine`), graded
away from each sample, h(x) = min_i (h_i + g |x - x_i|), clipped to [h_min, h_max].
Lengths in model units.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["MAX_TURN", "NAGATA_ERROR_CONSTANT", "CurvatureFrames", "SizeField", "arc_error", "ball_marks",
           "curvature_samples", "edge_length_for_tolerance", "patch_curvature"]

NAGATA_ERROR_CONSTANT = 6.0e-4 / 0.52 ** 4
"""C of e = C h^4 / R^3 (thesis Fig. 8: 0.060 % radial error at normalized edge length 0.52)."""


def arc_error(h: ArrayLike, radius: ArrayLike) -> NDArray:
    """Predicted max radial error [length] of a Nagata edge of chord ``h`` on an arc of ``radius``."""
    h = np.asarray(h, dtype=float)
    r = np.asarray(radius, dtype=float)
    return NAGATA_ERROR_CONSTANT * h ** 4 / r ** 3


MAX_TURN = math.pi / 3
"""Largest turn of the normal along one element edge [rad] (60 degrees): beyond it the arc
law, an asymptotic expansion in h / R, no longer holds (and a quadratic edge over a nearly
reversing normal is what makes broken patches), so h <= MAX_TURN R."""


def edge_length_for_tolerance(tolerance: float, curvature: ArrayLike, h_max: float = math.inf,
                              max_turn: float | None = None, turn_curvature: ArrayLike | None = None) -> NDArray:
    """Target edge length (N,) [length] for a shape ``tolerance`` [length] where the largest
    |principal curvature| is ``curvature`` (N,) [1/length]: eq. (size) of the module docs,
    ``h_max`` where the surface is flat. With ``max_turn`` [rad] also h <= max_turn / |k|
    (k = ``turn_curvature``, default ``curvature``): no edge turns the normal by more."""
    if not (tolerance > 0 and math.isfinite(tolerance)):
        raise ValueError(f"shape tolerance must be a positive number, got {tolerance!r}")
    k = np.abs(np.asarray(curvature, dtype=float))
    with np.errstate(divide="ignore"):
        h = (tolerance / (NAGATA_ERROR_CONSTANT * k ** 3)) ** 0.25
    h = np.where(np.isfinite(h), h, h_max)
    if max_turn is not None:
        kt = k if turn_curvature is None else np.abs(np.asarray(turn_curvature, dtype=float))
        with np.errstate(divide="ignore"):
            h = np.minimum(h, np.where(kt > 0, max_turn / np.where(kt > 0, kt, 1.0), h_max))
    return np.minimum(h, h_max)


def patch_curvature(k1: ArrayLike, k2: ArrayLike) -> NDArray:
    """Curvature k_p (N,) [1/length] for the law e = C h^4 k_p^3 of an element of side h
    sized alike in both directions over a surface of principal curvatures k1, k2 (N,):

        k_p^3 = max(|k1|^3 + |k2|^3, |k1 + k2|^3 / 2)                               (patch)

    A Nagata quad's interior error is about the sum of its sides' errors, and at its centre
    that of its diagonal (length sqrt(2) h, normal curvature (k1 + k2) / 2 at 45 degrees by
    Euler: 4 C h^4 |(k1 + k2) / 2|^3). A cylinder keeps k (its sides dominate); a sphere
    gets 4^(1/3) k: a Nagata quad on a sphere is 3.8x the single-edge law
    (`tests/tool/test_refine_law.py`), on a torus (r 4, R 10) the diagonal term is within
    0.9-1.1x of the measured error of near-square quads. Saddles are not covered by it (the
    sides' sum is, to 1.5x)."""
    a, b = np.asarray(k1, dtype=float), np.asarray(k2, dtype=float)
    return np.cbrt(np.maximum(np.abs(a) ** 3 + np.abs(b) ** 3, np.abs(a + b) ** 3 / 2))


def curvature_samples(model, per_span: int = 4, min_per_side: int = 9, max_per_side: int = 200,
                      frames: bool = False):
    """Points on every face of ``model`` and the largest |principal curvature| there (with
    ``frames``: a `CurvatureFrames` of the same samples instead of the face index).

    Each face's underlying surface is sampled on a (u, v) grid with ``per_span`` points per
    knot span (at least ``min_per_side`` per side), so curvature changes inside spans are
    seen. Returns points (M, 3), k_max (M,) [1/length] (NaN at degenerate points are
    dropped) and face index (M,) (or the `CurvatureFrames`, whose ``face`` holds it)."""
    from cadbridge.nurbs.curvature import principal_curvatures

    pts, ks, fs, fr = [], [], [], []
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
        if frames:
            k1, k2, d1, d2 = principal_curvatures(s, U, V, directions=True)
        else:
            k1, k2 = principal_curvatures(s, U, V)
        k = np.maximum(np.abs(k1), np.abs(k2))
        ok = np.isfinite(k)
        pts.append(s.evaluate(U[ok], V[ok]))
        ks.append(k[ok])
        fs.append(np.full(int(ok.sum()), i))
        if frames:
            fr.append((k1[ok], k2[ok], d1[ok], d2[ok]))
    P, K = np.concatenate(pts), np.concatenate(ks)
    if frames:
        k1, k2, d1, d2 = (np.concatenate([f[m] for f in fr]) for m in range(4))
        return P, K, CurvatureFrames(P, k1, k2, d1, d2, face=np.concatenate(fs))
    return P, K, np.concatenate(fs)


class CurvatureFrames:
    """Principal curvatures and directions at sample points of the CAD faces, for sizing the
    sides of mapped faces by the error of the mesh lines *along* them.

    points (M, 3), k1, k2 (M,) [1/length], d1, d2 (M, 3) unit principal directions (from
    `curvature_samples(..., frames=True)`). `side_curvature` gives, at points of a face side
    with tangents t and space curvature k, the curvature k_eff for the law h = (t / (C
    k_eff^3))^(1/4) of the edges along that side inside the face next to it:

        e_side = C h^4 (|k_n|^3 + k_g^2 |k_x|) / s                                  (side)

    k_n = k1 (t.d1)^2 + k2 (t.d2)^2 the normal curvature along the side (Euler), k_x = k1
    (t.d2)^2 + k2 (t.d1)^2 the normal curvature across it, k_g^2 = k^2 - k_n^2 its geodesic
    curvature. The k_g term: a chord between two nodes on a side that bends in the tangent
    plane (a corner blend's rail on the floor, k_n = 0, k_g = 1 / rho) cuts inwards by
    k_g h^2 / 8, and the surface falls away across it by k_x (k_g h^2 / 8)^2 / 2 = k_g^2 k_x
    h^4 / 128 (C = 1 / 122): on a torus tube r 4 of sweep R 10 the top rail's chords are
    50-300x the normal-curvature law and within 0.7-1.5x of (side). s = 1/2 where the
    surface also curves across the side (|k_x| above 1 % of its largest curvature): the
    patch error is about the sum of both directions' edge errors, so each gets half the
    tolerance. Only samples of faces the side lies on count: x must sit on the sample's
    osculating paraboloid, | |n.(x - s)| - |k_d| d^2 / 2 | <= 0.05 |k_d| d^2 / 2 + 1e-6 d (d
    = |x - s| in the tangent plane, k_d the normal curvature towards x: a plane leaving a
    fillet tangentially is k_d d^2 / 2 off the fillet's paraboloid, rejected; points of the
    face itself are O(k' d^3) off); of those, the sample that asks
    for the most wins (several faces meet at a side). Where no sample passes, the side's own
    curvature: k_eff = |k|.
    """

    def __init__(self, points, k1, k2, d1, d2, neighbours: int = 8, face=None) -> None:
        from scipy.spatial import cKDTree

        self.points = np.asarray(points, dtype=float).reshape(-1, 3)
        self.face = None if face is None else np.asarray(face, dtype=np.int64)  # (M,) face index of each sample
        self.k1, self.k2 = np.asarray(k1, dtype=float), np.asarray(k2, dtype=float)
        self.d1, self.d2 = np.asarray(d1, dtype=float), np.asarray(d2, dtype=float)
        self.neighbours = int(min(neighbours, max(len(self.points), 1)))
        self._tree = cKDTree(self.points) if len(self.points) else None

    def side_curvature(self, x: ArrayLike, t: ArrayLike, k: ArrayLike) -> NDArray:
        """k_eff (N,) of eq. (side) at points x (N, 3) of a side with unit tangents t (N, 3)
        and space curvature k (N,); |k| where there are no samples."""
        x = np.asarray(x, dtype=float).reshape(-1, 3)
        t = np.asarray(t, dtype=float).reshape(-1, 3)
        k = np.abs(np.asarray(k, dtype=float)).ravel()
        if self._tree is None or len(x) == 0:
            return k
        _, j = self._tree.query(x, k=self.neighbours)
        j = j.reshape(len(x), -1)  # (N, J)
        d1, d2, k1, k2 = self.d1[j], self.d2[j], self.k1[j], self.k2[j]
        # on the sample's face? (osculating paraboloid test of the class docs)
        dx = x[:, None, :] - self.points[j]
        nrm = np.cross(d1, d2)
        nrm /= np.maximum(np.linalg.norm(nrm, axis=2, keepdims=True), 1e-300)
        p1, p2 = np.einsum("njd,njd->nj", dx, d1), np.einsum("njd,njd->nj", dx, d2)
        dist2 = p1 * p1 + p2 * p2
        k_dx = np.abs(k1 * p1 * p1 + k2 * p2 * p2) / np.maximum(dist2, 1e-300)  # normal curvature towards x
        off = np.abs(np.abs(np.einsum("njd,njd->nj", dx, nrm)) - 0.5 * k_dx * dist2)
        on = off <= 0.05 * 0.5 * k_dx * dist2 + 1e-6 * np.sqrt(dist2 + 1e-300)
        a = np.einsum("nd,njd->nj", t, d1)
        b = np.einsum("nd,njd->nj", t, d2)
        tan2 = np.maximum(a * a + b * b, 1e-300)  # the side's tangent projected on the face's plane
        a2, b2 = a * a / tan2, b * b / tan2
        kn = k1 * a2 + k2 * b2
        kx = k1 * b2 + k2 * a2
        kg2 = np.maximum(k[:, None] ** 2 - kn ** 2, 0.0)
        kmax = np.maximum(np.abs(k1), np.abs(k2))
        share = np.where(np.abs(kx) > 1e-2 * kmax, 0.5, 1.0)
        e = np.where(on, (np.abs(kn) ** 3 + kg2 * np.abs(kx)) / share, -1.0)  # (N, J): e / (C h^4)
        best = np.max(e, axis=1)
        return np.where(best >= 0, np.cbrt(np.maximum(best, 0.0)), k)


def ball_marks(centres: ArrayLike, radii: ArrayLike, sizes: ArrayLike, n: int = 3) -> tuple[NDArray, NDArray]:
    """Refinement marks that ask for ``sizes`` (K,) over whole balls (centres (K, 3), radii
    (K,) [length]) instead of at points: the points of a cubic lattice of spacing s = r / n
    within r + s sqrt(3) / 2 of each centre (so that every point of the ball has a mark
    within s sqrt(3) / 2; 251 points for n = 3), each with the ball's size.

    Why not a point: gmsh reads the size field only at the nodes it creates, and in a field
    graded at g (h(x) <= h_i + g |x - x_i|) a mark h_new at an element's corners and centroid
    is h_new + g h / 2 at the new nodes half an element away. With the loop's factor 0.75 and
    g = 0.5 that is 0.75 h + 0.25 h = h: the element is remade at its old size every pass
    (the production die's two 7.3 mm elements, marked for 5.5 mm: 5.5 + 0.5 x 3.64 = 7.3).
    Over a ball the field is within g s sqrt(3) / 2 = 0.14 g r of the size (s the lattice
    spacing), and in gmsh's nearest-carrier view (`SizeField.background`) it is the size.
    Returns points (M, 3), sizes (M,)."""
    c = np.asarray(centres, dtype=float).reshape(-1, 3)
    r = np.asarray(radii, dtype=float).ravel()
    h = np.asarray(sizes, dtype=float).ravel()
    a = np.arange(-n - 1, n + 2, dtype=float)
    lat = np.stack(np.meshgrid(a, a, a, indexing="ij"), axis=-1).reshape(-1, 3)
    lat = lat[np.linalg.norm(lat, axis=1) <= n + math.sqrt(3.0) / 2 + 1e-9] / n  # (L, 3), r = 1
    pts = c[:, None, :] + r[:, None, None] * lat[None]  # (K, L, 3)
    return pts.reshape(-1, 3), np.repeat(h, len(lat))


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
        are first rounded down to levels LEVEL_RATIO apart).

        Levels in increasing size: a level lv only lowers the points whose size so far is
        above lv, and only from samples nearer than (h - lv) / g, so each query takes only
        those points, within the largest such distance (plus 1e-12 of it: a candidate left
        out is >= h in floating point too, so the result is the same, bit for bit, as
        querying every point at every level). The queries run on every core. The field of a
        guard-refinement round of the 8-solid S1 assembly (341 k carriers, 35 k marks):
        8.4 -> 4.9 s."""
        if self._tree is None:
            self._build()
        x = np.atleast_2d(np.asarray(x, dtype=float))
        h = np.full(len(x), self.h_max)
        for lv, tree in self._levels:  # loop over the size levels (ascending), vectorised over points
            live = np.flatnonzero(h > lv)
            if not len(live):
                break  # every later level is larger still
            hl = h[live]
            reach = (float(hl.max()) - lv) / self.g * (1.0 + 1e-12) if self.g > 0 else np.inf
            d, _ = tree.query(x[live], k=1, distance_upper_bound=reach, workers=-1)
            h[live] = np.minimum(hl, lv + self.g * d)  # d = inf beyond reach
        return np.clip(h, self.h_min, self.h_max)

    def background(self, extra: ArrayLike | None = None, neighbours: int = 6) -> tuple[NDArray, NDArray]:
        """Points (M, 3) and sizes (M,) for a nearest-point background size field
        (`cadbridge.mesh.generate.mesh_cad`'s ``background_sizes``), evaluated in gmsh
        without a Python call per query.

        Carriers are the field's samples and marks plus ``extra`` points (K, 3) (e.g. the
        nodes of the first mesh, dense where the sizes are small). A query point x takes
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
