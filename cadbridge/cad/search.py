"""Global projection of points onto a whole model: which face, (u, v), foot, exact normal.

The index (`build_search_index`, cached on the model by `index_for`):
- boxes: every face is cut into Bezier sub-patches (knot spans, each halved up to 3 times,
  at most 256 per face); the box of a sub-patch's control net contains its piece of surface
  (convex hull property, weights > 0). Only sub-patches meeting the trimmed region are
  kept: a sub-patch cell that no trim curve crosses (control-point boxes of the trim curve
  spans) lies wholly inside or outside, decided at its centre. The boxes go into a bounding
  volume hierarchy (`cadbridge.cad.box_tree.BoxTree`: Morton order, compiled walk).
- samples: the start-value grid of every surface (`surface_samples`) restricted to the
  trimmed region (`Face.contains` only in cells crossed by a trim curve), one KD-tree.
Build cost is linear in surface spans, samples and trim-curve spans.

Projection:
1. Bound: the nearest valid sample bounds the distance to the nearest foot; its face is
   projected first (vectorised Newton, `project_to_surface`), and a foot inside that face's
   trims tightens the bound to its distance.
2. Candidates: (point, face) pairs from a compiled walk of the boxes' bounding volume
   hierarchy (`cadbridge.cad.box_tree`) with the exact point-box and point-slab distances against
   the bound; the faces of the surviving pairs are projected (one call per face, never a
   loop over points). Cost ~ N log B.
3. Trims: a foot outside a face's trim loops is not valid for that face, but the nearest
   point of its trim loops is (`project_to_trims`, ON_BOUNDARY); it is computed only where
   the untrimmed foot is nearer than the best valid foot found (a lower bound).
4. Choice: the nearest valid foot wins; at equal distance (within ``tie_tol`` x model size)
   a foot inside a face beats one on a face edge (ON_BOUNDARY). A point whose projection
   FAILED on a face that is nearer (at its last iterate) than the chosen foot is FAILED
   (``face`` names the face that failed): a failure is reported, never replaced by a foot
   on a farther face.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache

import numba
import numpy as np
from scipy.spatial import cKDTree

from cadbridge.cad.box_tree import BoxTree
from cadbridge.cad.model import Face, Model
from cadbridge.nurbs.project import (
    BEYOND_TOLERANCE,
    CONVERGED,
    FAILED,
    ON_BOUNDARY,
    STATUS_NAMES,
    SurfaceProjection,
    surface_samples,
)
from cadbridge.nurbs.edits import bezier_patches, curve_bezier_segments
from cadbridge.nurbs.project_many import SurfacePack, newton_is_final, newton_to_surfaces, project_to_surfaces
from cadbridge.nurbs.surface import NurbsSurface
from cadbridge.cad.trims import project_to_trims

__all__ = ["Projection", "SearchIndex", "build_search_index", "index_for", "project_points", "project_to_trims", "span_boxes"]  # project_to_trims: re-export


@dataclass
class Projection:
    """Result of `project_points` for N points.

    face       (N,) int: index into model.faces, -1 where no face gave a foot (where FAILED
               because a nearer face failed: that face)
    u, v       (N,) parameters on that face (NaN where FAILED)
    foot       (N, 3) nearest point on the model (NaN where FAILED)
    distance   (N,) |P - foot| (NaN where FAILED)
    normal     (N, 3) unit normal Su x Sv of that face at the foot (NaN where FAILED)
    status     (N,) int8: CONVERGED, ON_BOUNDARY (foot on a face edge, no face contains it
               in its interior), BEYOND_TOLERANCE (farther than max_distance; the rest is
               still filled in) or FAILED
    candidates (N,) int: faces projected for each point (diagnostics)
    """

    face: np.ndarray
    u: np.ndarray
    v: np.ndarray
    foot: np.ndarray
    distance: np.ndarray
    normal: np.ndarray
    status: np.ndarray
    candidates: np.ndarray

    def __len__(self) -> int:
        return len(self.face)

    def summary(self) -> str:
        """A few lines: counts per status, distances, faces used, failed node indices."""
        n = len(self)
        lines = [f"{n} points projected"]
        for code, name in STATUS_NAMES.items():
            k = int(np.count_nonzero(self.status == code))
            if k:
                lines.append(f"  {name:<16} {k:>9d}  ({100.0 * k / max(n, 1):.2f} %)")
        ok = self.status != FAILED
        if np.any(ok):
            d = self.distance[ok]
            lines.append(f"  distance: max {d.max():.6g}, mean {d.mean():.6g}")
            lines.append(f"  faces used: {np.unique(self.face[ok]).size}, candidates/point: {self.candidates.mean():.2f}")
        bad = np.nonzero(self.status == FAILED)[0]
        if bad.size:
            lines.append(f"  FAILED nodes (first 10, 0-based): {bad[:10].tolist()}")
        far = np.nonzero(self.status == BEYOND_TOLERANCE)[0]
        if far.size:
            lines.append(f"  beyond max_distance (first 10, 0-based): {far[:10].tolist()}")
        return "\n".join(lines)


def span_boxes(surface: NurbsSurface) -> np.ndarray:
    """Boxes of the control points of every non-empty knot span (i, j) that meets the domain,
    (B, 2, 3) [min, max]; each contains the surface piece over its span."""
    p, q = surface.degree_u, surface.degree_v
    ku, kv = surface.knots_u, surface.knots_v
    nu, nv = surface.shape
    u0, u1, v0, v1 = surface.domain
    iu = np.arange(p, nu)
    iu = iu[(ku[iu + 1] > ku[iu]) & (ku[iu] < u1) & (ku[iu + 1] > u0)]
    iv = np.arange(q, nv)
    iv = iv[(kv[iv + 1] > kv[iv]) & (kv[iv] < v1) & (kv[iv + 1] > v0)]
    cp = surface.control_points
    # (su, sv, p+1, q+1, 3) control points of each span
    ii = iu[:, None, None, None] - p + np.arange(p + 1)[None, None, :, None]
    jj = iv[None, :, None, None] - q + np.arange(q + 1)[None, None, None, :]
    ii, jj = np.broadcast_arrays(ii, jj)
    pts = cp[ii, jj]
    lo = pts.min(axis=(2, 3)).reshape(-1, 3)
    hi = pts.max(axis=(2, 3)).reshape(-1, 3)
    return np.stack([lo, hi], axis=1)


_SUB_PATCHES = 256  # Bezier sub-patches per face at most (boxes of the index)
_TRIM_SPLITS = 8  # parts per Bezier piece of a trim curve (boxes of the trim-crossed cells)
_SUB_SPLITS = 8  # parts of a knot span per direction at most (a power of 2)


@lru_cache(maxsize=64)
def _split_matrices(p: int, s: int) -> np.ndarray:
    """(s, p+1, p+1): row block k maps the control points of a degree-p Bezier piece on [0, 1]
    to those of its restriction to [k/s, (k+1)/s] (de Casteljau applied to the identity)."""

    def split(x: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
        left, right = [x[0]], [x[-1]]
        for _ in range(p):
            x = (1.0 - t) * x[:-1] + t * x[1:]
            left.append(x[0])
            right.append(x[-1])
        return np.array(left), np.array(right[::-1])

    out = np.empty((s, p + 1, p + 1))
    for k in range(s):
        a, b = k / s, (k + 1) / s
        left, _ = split(np.eye(p + 1), b)  # the piece on [0, b]
        out[k] = left if a == 0.0 else split(left, a / b)[1]
    return out


def _subpatches(surface: NurbsSurface) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bezier sub-patches of the surface over its domain: every knot span cut into up to
    ``_SUB_SPLITS`` equal parts per direction (at most ``_SUB_PATCHES`` per face). Returns uv
    boxes (K, 4) rows (u0, u1, v0, v1), xyz boxes (K, 2, 3) [min, max] of their control
    nets (each contains its piece of surface: convex hull property, weights > 0) and their
    slabs (K, 5) (`_slabs`)."""
    uvb, pts, w = bezier_patches(surface)
    net = np.concatenate([pts * w[..., None], w[..., None]], axis=-1)  # (K, p+1, q+1, 4)
    k, p1, q1 = net.shape[:3]
    su = sv = 1
    while su < _SUB_SPLITS and k * (2 * su) * sv <= _SUB_PATCHES:
        su *= 2
        if sv < _SUB_SPLITS and k * su * (2 * sv) <= _SUB_PATCHES:
            sv *= 2
    mu, mv = _split_matrices(p1 - 1, su), _split_matrices(q1 - 1, sv)
    # sub[n, a, b, i, k] = sum_jl mu[a, i, j] mv[b, k, l] net[n, j, l]: two matmuls
    t = mu.reshape(-1, p1) @ net.reshape(k, p1, -1)  # (K, su*(p+1), (q+1)*4)
    t = mv.reshape(-1, q1) @ t.reshape(k, -1, q1, 4)  # (K, su*(p+1), sv*(q+1), 4)
    sub = t.reshape(k, su, p1, sv, q1, 4).transpose(0, 1, 3, 2, 4, 5)
    fu = np.arange(su + 1) / su
    fv = np.arange(sv + 1) / sv
    ua = uvb[:, 0:1] + (uvb[:, 1:2] - uvb[:, 0:1]) * fu  # (K, su+1)
    va = uvb[:, 2:3] + (uvb[:, 3:4] - uvb[:, 2:3]) * fv
    ua[:, -1], va[:, -1] = uvb[:, 1], uvb[:, 3]  # exact shared breaks between patches
    box = np.empty((k, su, sv, 4))
    box[..., 0] = ua[:, :-1, None]
    box[..., 1] = ua[:, 1:, None]
    box[..., 2] = va[:, None, :-1]
    box[..., 3] = va[:, None, 1:]
    xyz = (sub[..., :3] / sub[..., 3:]).reshape(k * su * sv, -1, 3)
    return box.reshape(-1, 4), np.stack([xyz.min(axis=1), xyz.max(axis=1)], axis=1), _slabs(xyz, p1, q1)


def _slabs(xyz: np.ndarray, p1: int, q1: int) -> np.ndarray:
    """Slabs (K, 5) [nx, ny, nz, smin, smax] holding each sub-patch: n a unit normal from the
    diagonals of its control net (K, p1*q1, 3), [smin, smax] the range of n.x over the net (the
    piece lies in the net's convex hull, weights > 0). A degenerate net gets an unbounded slab."""
    net = xyz.reshape(len(xyz), p1, q1, 3)
    n = np.cross(net[:, -1, -1] - net[:, 0, 0], net[:, 0, -1] - net[:, -1, 0])
    ln = np.linalg.norm(n, axis=1)
    ok = ln > 0
    n[ok] /= ln[ok, None]
    s = np.einsum("kij,kj->ki", xyz, n)
    out = np.empty((len(xyz), 5))
    out[:, :3] = n
    out[:, 3] = np.where(ok, s.min(axis=1), -np.inf)
    out[:, 4] = np.where(ok, s.max(axis=1), np.inf)
    return out


def _trim_loops(face: Face) -> list:
    t = face.trims
    if t is None:
        return []
    return ([t.outer] if t.outer is not None else []) + list(t.inner)


def _trim_curve_boxes(face: Face) -> np.ndarray:
    """uv boxes (T, 2, 2) [min, max] covering every trim curve of ``face``: one per edge of
    each loop's `LoopBoundary` polygon (the same one `Face.contains` decides on), its chord
    widened by the edge's chord bound (the arc lies within that bound of its chord: for NURBS
    curves rigorous, from the Bezier net of the piece; for exactly mapped curves without a
    control net, `cadbridge.cad.trims`' sampled estimate)."""
    out = []
    for loop in _trim_loops(face):
        bd = loop.boundary
        r = bd.band[:, None]
        out.append(np.stack([np.minimum(bd.a, bd.b) - r, np.maximum(bd.a, bd.b) + r], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 2, 2))


def _face_cells(face: Face) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """`_face_cells_slabs` without the slabs."""
    return _face_cells_slabs(face)[:4]


def _crossed_cells(face: Face):
    """The sub-patches of ``face`` on their uv grid, and which cells a trim curve crosses.

    Returns (xyz boxes (K, 2, 3), slabs (K, 5), bu (Mu+1,), bv (Mv+1,), iu, iv (K,) the cell
    of each sub-patch, crossed (Mu, Mv) bool or None for a face without trim loops). A cell
    is crossed when a trim curve's control-point box, widened by 1e-9 of the domain, meets it.
    """
    uvb, xyz, slab = _subpatches(face.surface)
    bu = np.unique(np.concatenate([uvb[:, 0], uvb[:, 1]]))
    bv = np.unique(np.concatenate([uvb[:, 2], uvb[:, 3]]))
    iu = np.searchsorted(bu, uvb[:, 0])
    iv = np.searchsorted(bv, uvb[:, 2])
    mu, mv = len(bu) - 1, len(bv) - 1
    if not _trim_loops(face):
        return xyz, slab, bu, bv, iu, iv, None
    u0, u1, v0, v1 = face.surface.domain
    tb = _trim_curve_boxes(face)
    m = 1e-9 * max(u1 - u0, v1 - v0)
    # cells [bu[i], bu[i+1]] x [bv[j], bv[j+1]] met by each curve box: index ranges, then
    # a 2D difference array marks them all at once
    i0 = np.clip(np.searchsorted(bu, tb[:, 0, 0] - m, side="right") - 1, 0, mu)
    i1 = np.clip(np.searchsorted(bu, tb[:, 1, 0] + m, side="left"), 0, mu)
    j0 = np.clip(np.searchsorted(bv, tb[:, 0, 1] - m, side="right") - 1, 0, mv)
    j1 = np.clip(np.searchsorted(bv, tb[:, 1, 1] + m, side="left"), 0, mv)
    ok = (i1 > i0) & (j1 > j0)
    diff = np.zeros((mu + 1, mv + 1), dtype=np.int64)
    np.add.at(diff, (i0[ok], j0[ok]), 1)
    np.add.at(diff, (i0[ok], j1[ok]), -1)
    np.add.at(diff, (i1[ok], j0[ok]), -1)
    np.add.at(diff, (i1[ok], j1[ok]), 1)
    crossed = np.cumsum(np.cumsum(diff, axis=0), axis=1)[:mu, :mv] > 0
    return xyz, slab, bu, bv, iu, iv, crossed


def _face_cells_slabs(face: Face) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sub-patch boxes of ``face`` that meet its trimmed region.

    Returns xyz boxes (K, 2, 3), the uv grid breaks of the sub-patches (bu (Mu+1,),
    bv (Mv+1,)) and a cell state grid (Mu, Mv) int8: 0 outside the face, 1 inside, 2 crossed by
    a trim curve (`_crossed_cells`). Cells without a trim curve lie wholly on one side: their
    centre decides (`Face.contains`). Also the slabs (K, 5) of the kept sub-patches (`_slabs`).
    """
    b, slab, _, bu, bv, state, _, _ = _face_index_parts(face, None)
    return b, bu, bv, state, slab


def _face_index_parts(face: Face, smp: SurfaceSamples | None):
    """What the search index keeps of ``face``, with one `Face.contains` call for all its
    trim decisions (three calls per face cost the bearing's index 1 s).

    Returns boxes (K, 2, 3) and slabs (K, 5) of the sub-patches meeting the trimmed region,
    the inside mask (M,) of the start-value samples ``smp`` (None: not asked), bu, bv and the
    cell state (see `_face_cells_slabs`), and the surface points (C, 3) at the centres of the
    cells whose centre lies inside the face: extra index samples where the start-value grid
    is coarse (a large plane has a 5 x 5 grid, so a point on it was nearer the dense grid of
    a neighbouring fillet: the wrong first face, a loose bound and wasted Newton restarts on
    that neighbour). The last value is the number of uv points classified."""
    xyz, slab, bu, bv, iu, iv, crossed = _crossed_cells(face)
    mu, mv = len(bu) - 1, len(bv) - 1
    state = np.ones((mu, mv), dtype=np.int8)
    n_asked = 0
    if smp is not None:
        si = np.clip(np.searchsorted(bu, smp.uv[:, 0], side="right") - 1, 0, mu - 1)
        sj = np.clip(np.searchsorted(bv, smp.uv[:, 1], side="right") - 1, 0, mv - 1)
    if crossed is None:
        inside = np.ones(len(smp.uv), dtype=bool) if smp is not None else None
        cu, cv = np.meshgrid(0.5 * (bu[:-1] + bu[1:]), 0.5 * (bv[:-1] + bv[1:]), indexing="ij")
        cpts = face.surface.evaluate(cu.ravel(), cv.ravel())
        return xyz, slab, inside, bu, bv, state, cpts, n_asked
    cu_all, cv_all = 0.5 * (bu[:-1] + bu[1:]), 0.5 * (bv[:-1] + bv[1:])
    ii, jj = np.nonzero(~crossed)   # their centre decides the whole cell
    ci, cj = np.nonzero(crossed)    # their centre is an index sample if inside
    qu = [cu_all[ii], cu_all[ci]]
    qv = [cv_all[jj], cv_all[cj]]
    edge = np.flatnonzero(crossed[si, sj]) if smp is not None else np.zeros(0, dtype=np.int64)
    qu.append(smp.uv[edge, 0] if smp is not None else np.zeros(0))
    qv.append(smp.uv[edge, 1] if smp is not None else np.zeros(0))
    qu, qv = np.concatenate(qu), np.concatenate(qv)
    n_asked = len(qu)
    ins = face.contains(qu, qv) if n_asked else np.zeros(0, dtype=bool)
    a, b = len(ii), len(ii) + len(ci)
    state[:] = 2
    state[ii, jj] = ins[:a].astype(np.int8)
    keep = state[iu, iv] > 0
    centre_in = np.zeros((mu, mv), dtype=bool)
    centre_in[ii, jj] = ins[:a]
    centre_in[ci, cj] = ins[a:b]
    oi, oj = np.nonzero(centre_in)
    cpts = face.surface.evaluate(cu_all[oi], cv_all[oj]) if len(oi) else np.zeros((0, 3))
    inside = None
    if smp is not None:
        inside = state[si, sj] == 1
        inside[edge] = ins[b:]
    return xyz[keep], slab[keep], inside, bu, bv, state, cpts, n_asked


@dataclass
class SearchIndex:
    """Precomputed search structures of a model (reusable across calls; `index_for` caches
    one on the model).

    box_lo, box_hi (B, 3), box_face (B,): boxes of the Bezier sub-patches that meet each
    face's trimmed region; box_slab (B, 5): a slab {x: smin <= n.x <= smax} holding each
    sub-patch (a second, often much tighter, lower bound of the distance); tree: the
    compiled bounding volume hierarchy of those boxes (`cadbridge.cad.box_tree`); sample_tree over
    valid samples of all faces, sample_face (S,); size: model size (box diagonal).
    """

    box_lo: np.ndarray
    box_hi: np.ndarray
    box_face: np.ndarray
    box_slab: np.ndarray
    tree: BoxTree
    sample_tree: cKDTree | None
    sample_face: np.ndarray
    size: float
    n_faces: int
    pack: SurfacePack | None = None  # the faces' surfaces packed for `project_to_surfaces` (built on first use)

    def surface_pack(self, model: Model) -> SurfacePack:
        """The `SurfacePack` of the model's face surfaces (built once, kept on the index)."""
        if self.pack is None:
            self.pack = SurfacePack([f.surface for f in model.faces])
        return self.pack


def build_search_index(model: Model) -> SearchIndex:
    """Boxes, their tree and the sample KD-tree of ``model``; cost linear in the number of
    surface spans, samples and trim-curve spans (plus one sort of the boxes). Raises ValueError if the model has no
    faces."""
    if not model.faces:
        raise ValueError("project_points: empty model (no faces to project onto)")
    los, his, fids, spts, sfid, slabs = [], [], [], [], [], []
    for k, face in enumerate(model.faces):
        try:
            smp = surface_samples(face.surface)
            b, slab, inside, _, _, _, cpts, _ = _face_index_parts(face, smp)
        except Exception as exc:  # noqa: BLE001 - re-raised with the face named
            raise ValueError(f"search index: face {k} (DE {face.de}): {exc}") from exc
        los.append(b[:, 0])
        his.append(b[:, 1])
        slabs.append(slab)
        fids.append(np.full(len(b), k))
        spts.append(smp.points[inside])
        spts.append(cpts)
        sfid.append(np.full(int(inside.sum()) + len(cpts), k))
    lo, hi = np.concatenate(los), np.concatenate(his)
    face_of_box = np.concatenate(fids)
    slab = np.ascontiguousarray(np.concatenate(slabs))
    allpts = np.concatenate(spts)
    return SearchIndex(lo, hi, face_of_box, slab, BoxTree(lo, hi, slab, face_of_box),
                       cKDTree(allpts) if len(allpts) else None, np.concatenate(sfid), model.size(), len(model.faces))


_INDEX_KEY = "_cadbridge_search_index"


def index_for(model: Model) -> SearchIndex:
    """The search index of ``model``, built once and cached on the model object; rebuilt when
    its face list changed (other length or other Face/surface objects)."""
    key = tuple((id(f), id(f.surface), id(f.trims)) for f in model.faces)
    hit = model.__dict__.get(_INDEX_KEY)
    if hit is not None and hit[0] == key:
        return hit[1]
    idx = build_search_index(model)
    model.__dict__[_INDEX_KEY] = (key, idx)
    return idx


def candidate_pairs(index: SearchIndex, pts: np.ndarray, bound: np.ndarray, exclude: np.ndarray | None = None,
                     *, lower: bool = False) -> tuple[np.ndarray, ...]:
    """(point, face) pairs whose boxes lie within ``bound`` (N,) of the point, without the
    pairs (i, exclude[i]) (faces already projected); unique, sorted by face. Returns (point
    indices, face indices) and with ``lower`` (M,) a lower bound of each pair's distance from
    the point to the face's trimmed region: the least box / slab bound of its sub-patches
    (those not returned lie beyond ``bound``; -inf for a point without a bound)."""
    n = len(pts)
    finite = np.isfinite(bound)
    excl = np.full(n, -1, dtype=np.int64) if exclude is None else np.asarray(exclude, dtype=np.int64)
    face_of_box = index.box_face.astype(np.int64)
    keys, lows = [], []
    if np.any(~finite):  # no bound at all (no valid samples): every face is a candidate
        pi = np.nonzero(~finite)[0]
        f = np.unique(face_of_box)
        ff, pp = np.tile(f, len(pi)), np.repeat(pi, len(f))
        keep = ff != excl[pp]
        keys.append(ff[keep] * n + pp[keep])
        lows.append(np.full(int(keep.sum()), -np.inf))
    if np.any(finite):
        fidx = np.nonzero(finite)[0]
        pi, f, low = index.tree.pairs(pts[fidx], bound[fidx], excl[fidx])
        keys.append(f * n + fidx[pi])
        lows.append(low)
    if not keys:
        z = np.zeros(0, dtype=np.int64)
        return (z, z, np.zeros(0)) if lower else (z, z)
    if not lower:
        key = np.unique(np.concatenate(keys))  # sorted by face, then point
        return key % n, key // n
    key = np.concatenate(keys)
    order = np.argsort(key, kind="stable")
    ks = key[order]
    if not len(ks):
        return ks, ks, np.zeros(0)
    cut = np.flatnonzero(np.concatenate([[True], ks[1:] != ks[:-1]]))
    low = np.minimum.reduceat(np.concatenate(lows)[order], cut)
    key = ks[cut]  # = np.unique(key): sorted by face, then point
    return key % n, key // n, low


def _trim_flags(model: Model, cf: np.ndarray, u: np.ndarray, v: np.ndarray, status: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """Trim decisions of feet (u, v) on faces ``cf`` (sorted by face): inside (M,) (foot not
    FAILED and inside the face's trims) and out (M,) (not FAILED but outside the trims: that
    face's nearest point is on its loops). One `Face.contains` call per face."""
    m = len(cf)
    inside = status != FAILED
    out = np.zeros(m, dtype=bool)
    if m == 0:
        return inside, out
    cuts = np.flatnonzero(np.diff(cf)) + 1
    for a, b in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [m]])):
        face = model.faces[int(cf[a])]
        okf = inside[a:b]
        if face.trims is not None and np.any(okf):
            oi = np.nonzero(okf)[0]
            isin = face.contains(u[a + oi], v[a + oi])
            okf[oi[~isin]] = False
            if face.trims.outer is not None or face.trims.inner:
                out[a + oi[~isin]] = True
    return inside, out


class _Pairs:
    """(point, face) pairs of one search step (sorted by face), projected in two stages.

    On creation every pair gets its Newton foot (`newton_to_surfaces`, one compiled pass;
    faces with internal crease lines get the whole `project_to_surfaces` at once) and its
    trim decision. ``final`` marks the pairs whose result is already that of
    `project_to_surfaces` (a foot on its point: the global and edge checks would not run);
    `finish` runs the checks for the rest, only for the pairs still needed (a mesh node whose
    first face is a neighbour's never pays for that face's restarts).
    cp, cf (M,) point and face of each pair; u, v, foot, dist, normal, status as in
    `SurfaceProjection`; inside / out as `_trim_flags`."""

    def __init__(self, model: Model, index: SearchIndex, pts: np.ndarray, cp: np.ndarray, cf: np.ndarray,
                 tol: float) -> None:
        self.model, self.pack, self.pts, self.tol = model, index.surface_pack(model), pts, tol
        m = len(cp)
        self.cp, self.cf = cp, cf
        self.u, self.v, self.dist = np.empty(m), np.empty(m), np.empty(m)
        self.foot, self.normal = np.empty((m, 3)), np.empty((m, 3))
        self.status = np.empty(m, dtype=np.int8)
        self.first = np.zeros(m, dtype=np.int64)
        self.final = np.ones(m, dtype=bool)
        single = self.pack.single[cf] if m else np.zeros(0, dtype=bool)
        si, mi = np.flatnonzero(single), np.flatnonzero(~single)
        if len(si):
            r, self.first[si] = newton_to_surfaces(self.pack, cf[si], pts[cp[si]], tol=tol)
            self._put(si, r)
            self.final[si] = newton_is_final(self.pack, cf[si], r)
        if len(mi):
            self._put(mi, project_to_surfaces(self.pack, cf[mi], pts[cp[mi]], tol=tol))
        self.inside, self.out = _trim_flags(model, cf, self.u, self.v, self.status)

    def _put(self, rows: np.ndarray, r) -> None:
        self.u[rows], self.v[rows], self.foot[rows] = r.u, r.v, r.foot
        self.dist[rows], self.normal[rows], self.status[rows] = r.distance, r.normal, r.status

    def on_model(self, size: float) -> np.ndarray:
        """(M,) bool: feet inside their face, CONVERGED, within _ON_MODEL x size of the point
        after the checks (no other face can be nearer by more than that: the search ends
        there). Newton feet that near but not final (a small surface: within _ON_MODEL x the
        model's size, not within _ON_SURFACE x its own) are finished first."""
        near = self.inside & (self.status == CONVERGED) & (self.dist <= _ON_MODEL * size)
        self.finish(near & ~self.final)
        return self.final & self.inside & (self.status == CONVERGED) & (self.dist <= _ON_MODEL * size)

    def finish(self, rows: np.ndarray) -> None:
        """Complete the pairs ``rows`` (bool mask or indices) with the checks."""
        rows = np.flatnonzero(rows) if rows.dtype == bool else rows
        rows = rows[~self.final[rows]]
        if not len(rows):
            return
        prev = SurfaceProjection(self.u[rows], self.v[rows], self.foot[rows], self.dist[rows], self.normal[rows],
                                 self.status[rows], np.zeros(len(rows), dtype=np.int32))
        r = project_to_surfaces(self.pack, self.cf[rows], self.pts[self.cp[rows]], tol=self.tol,
                                resume=(prev, self.first[rows]))
        moved = (r.u != prev.u) | (r.v != prev.v) | (r.status != prev.status)
        self._put(rows, r)
        self.final[rows] = True
        rows = rows[moved]  # a restart replaced the foot: its trim decision again
        if len(rows):
            self.inside[rows], self.out[rows] = _trim_flags(self.model, self.cf[rows], self.u[rows], self.v[rows],
                                                            self.status[rows])

    def take(self, rows: np.ndarray) -> tuple:
        """cp, cf, u, v, foot, dist, normal, status, inside, out of ``rows``."""
        return (self.cp[rows], self.cf[rows], self.u[rows], self.v[rows], self.foot[rows], self.dist[rows],
                self.normal[rows], self.status[rows], self.inside[rows], self.out[rows])


def _known_distance(n: int, pairs: tuple) -> np.ndarray:
    """(n,) the nearest foot of each point that lies inside its face and CONVERGED, over the
    given `_Pairs` (inf where none): the search's answer is no farther."""
    d = np.full(n, np.inf)
    for pp in pairs:
        ok = pp.inside & (pp.status == CONVERGED)
        np.minimum.at(d, pp.cp[ok], pp.dist[ok])
    return d


def _concurrent_kernels() -> bool:
    """Whether numba's threading layer (known once a parallel kernel has run) lets two
    threads call parallel kernels at the same time: omp and tbb do, workqueue does not."""
    try:
        return numba.threading_layer() in ("omp", "tbb")
    except ValueError:  # no parallel kernel has run in this process yet
        return False


_ON_MODEL = 1e-10  # a foot inside its face this near its point (x model size) ends the search
_BLOCK = 262144  # points projected together at most (larger inputs go block by block)


def project_points(
    points,
    model: Model,
    *,
    max_distance: float | None = None,
    tol: float = 1e-12,
    tie_tol: float = 1e-9,
    index: SearchIndex | None = None,
) -> Projection:
    """Project (N, 3) points onto the nearest face of ``model``.

    max_distance: points whose nearest foot is farther get BEYOND_TOLERANCE (foot, face,
    distance still reported). tol: Newton tolerance (relative to each surface's size, see
    `project_to_surface`). tie_tol: relative band (x model size) in which distances count as
    equal when preferring a face that contains the foot over an edge foot. index: a
    `build_search_index(model)` result to reuse. Raises ValueError for an empty model or
    malformed points.
    """
    pts = np.asarray(points, dtype=float)
    if pts.ndim == 1 and pts.size == 3:
        pts = pts.reshape(1, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        bad = np.nonzero(~np.all(np.isfinite(pts), axis=1))[0]
        raise ValueError(f"points must be finite; node {int(bad[0])} (0-based) is {pts[bad[0]].tolist()}")
    if index is None:
        index = index_for(model)
    elif index.n_faces != len(model.faces):
        raise ValueError(f"index was built for another model ({index.n_faces} faces, the model has {len(model.faces)})")
    n = len(pts)
    if n > _BLOCK:
        # blocks of points keep the per-face work arrays (derivatives: 216 bytes per point
        # and iteration) cache- and memory-friendly: time stays linear in N. Blocks are
        # independent (each point's answer depends on the point alone): after the first,
        # two at a time on two threads where numba's threading layer allows concurrent
        # parallel kernels (the per-face Python steps of one overlap the other's compiled
        # ones); the parts are joined in block order, so the result is the same either way
        index.surface_pack(model)  # built once, before any thread

        def block(a: int) -> Projection:
            return project_points(pts[a : a + _BLOCK], model, max_distance=max_distance, tol=tol,
                                  tie_tol=tie_tol, index=index)

        starts = list(range(0, n, _BLOCK))
        parts = [block(starts[0])]
        if len(starts) > 2 and _concurrent_kernels():
            with ThreadPoolExecutor(max_workers=2, thread_name_prefix="cadbridge-project") as pool:
                parts += list(pool.map(block, starts[1:]))
        else:
            parts += [block(a) for a in starts[1:]]
        return Projection(*(np.concatenate([getattr(r, f) for r in parts]) for f in
                            ("face", "u", "v", "foot", "distance", "normal", "status", "candidates")))
    size = index.size

    # 1. upper bound from the nearest valid sample; its face is projected first
    if index.sample_tree is not None and n:
        ub, si = index.sample_tree.query(pts, workers=-1)
        ub = ub * (1.0 + 1e-9) + 1e-9 * size
        f0 = index.sample_face[si].astype(np.int64)
        order = np.argsort(f0, kind="stable")
        cp1, cf1 = order.astype(np.int64), f0[order]
    else:
        ub = np.full(n, np.inf)
        cp1 = cf1 = np.zeros(0, dtype=np.int64)
    p1 = _Pairs(model, index, pts, cp1, cf1, tol)
    # a foot inside the nearest sample's face is a point of the model: a tighter bound (from
    # its Newton foot; the checks can only bring it nearer)
    bound = ub.copy()
    np.minimum.at(bound, cp1[p1.inside], p1.dist[p1.inside] * (1.0 + 1e-9) + 1e-9 * size)

    # 2. the other candidate (point, face) pairs: sub-patch boxes within the bound; not for
    # points on the model: a foot inside its face within _ON_MODEL x size of the point (no
    # other face can be nearer by more than that; mesh nodes are such points)
    on1 = p1.on_model(size)
    open_ = np.ones(n, dtype=bool)
    open_[cp1[on1]] = False
    excl = f0 if len(cp1) else None
    # 2a. points that the first face missed (foot on its edge or outside its trims: a mesh
    # node next to a face border whose nearest sample lies on the neighbour) first try the
    # faces whose boxes hold them (bound 2 x _ON_MODEL x size: every face that could have a
    # foot on the model): a foot on the model there ends the search, the nearest of them
    # wins, and the first face's restarts are never needed. The box query at that bound
    # costs a fraction of the one at the full bound.
    missed = np.zeros(n, dtype=bool)
    missed[cp1] = ~(p1.inside & (p1.status == CONVERGED))
    sub = np.flatnonzero(open_ & missed)
    cpa, cfa = candidate_pairs(index, pts[sub], np.full(len(sub), 2.0 * _ON_MODEL * size),
                                exclude=excl[sub] if excl is not None else None)
    cpa = sub[cpa]
    pa = _Pairs(model, index, pts, cpa, cfa, tol)
    ona = pa.on_model(size)
    open_[cpa[ona]] = False
    # 2b. the rest: every face with a box within the bound (the pairs of 2a not again)
    sub = np.flatnonzero(open_)
    cp2, cf2, lb2 = candidate_pairs(index, pts[sub], bound[sub], exclude=excl[sub] if excl is not None else None,
                                     lower=True)
    cp2 = sub[cp2]
    if len(cpa) and len(cp2):
        fresh = ~np.isin(cf2 * n + cp2, cfa * n + cpa)
        cp2, cf2, lb2 = cp2[fresh], cf2[fresh], lb2[fresh]
    p2 = _Pairs(model, index, pts, cp2, cf2, tol)
    # checks (restarts) only where they can change the answer: a pair of 2b whose face lies
    # farther (its box / slab bound) than a known foot inside a face, CONVERGED, cannot win,
    # whatever its restarts find (every foot on its trimmed region, or on its trim loops in
    # step 3, is at least that far; a restart never makes a foot FAILED); the known foot is
    # taken again after the other pairs' checks (a restart may move it off its face)
    def beyond_known() -> np.ndarray:  # (len(cp2),) the pair's face lies beyond a known foot
        return lb2 > _known_distance(n, (p1, pa, p2))[cp2] * (1.0 + 1e-9) + 1e-9 * size

    hopeless = (p2.status != FAILED) & beyond_known()
    for pp, skip in ((p1, None), (pa, None), (p2, hopeless)):
        pp.finish(open_[pp.cp] if skip is None else open_[pp.cp] & ~skip)
    if np.any(hopeless):
        p2.finish(open_[cp2] & hopeless & ~beyond_known())
    parts = [p1.take(np.flatnonzero(open_[cp1] | on1)), pa.take(np.flatnonzero(open_[cpa] | ona)),
             p2.take(np.flatnonzero(open_[cp2]))]
    cp, cf, pu, pv, pfoot, pdist, pnorm, pstat, valid, out = (np.concatenate(x) for x in zip(*parts))
    candidates = np.bincount(np.concatenate([cp1, cpa, cp2]), minlength=n)

    # 3. feet outside a face's trims: the nearest point of that face lies on its trim loops,
    # no nearer than the untrimmed foot; needed only where that could beat the best valid foot
    best = np.full(n, np.inf)
    np.minimum.at(best, cp[valid], pdist[valid])
    need = np.nonzero(out & (pdist < best[cp]))[0]
    if len(need):
        need = need[np.argsort(cf[need], kind="stable")]
        fs = cf[need]
        cuts = np.flatnonzero(np.diff(fs)) + 1
        for grp in np.split(need, cuts):
            face = model.faces[int(cf[grp[0]])]
            tu, tv, tf, td, tok = project_to_trims(face, pts[cp[grp]], tol=tol)
            idx = grp[tok]
            pu[idx], pv[idx], pfoot[idx], pdist[idx] = tu[tok], tv[tok], tf[tok], td[tok]
            pnorm[idx] = face.surface.normal(tu[tok], tv[tok])
            pstat[idx] = ON_BOUNDARY
            valid[idx] = True

    # 4. nearest valid foot per point; interior beats edge at equal distance
    face = np.full(n, -1, dtype=np.int64)
    u = np.full(n, np.nan)
    v = np.full(n, np.nan)
    foot = np.full((n, 3), np.nan)
    dist = np.full(n, np.nan)
    normal = np.full((n, 3), np.nan)
    status = np.full(n, FAILED, dtype=np.int8)
    if np.any(valid):
        vi = np.nonzero(valid)[0]
        eff = pdist[vi] + np.where(pstat[vi] == ON_BOUNDARY, tie_tol * size, 0.0)
        order = np.lexsort((eff, cp[vi]))
        vi = vi[order]
        first = np.ones(len(vi), dtype=bool)
        first[1:] = cp[vi][1:] != cp[vi][:-1]
        win = vi[first]
        tgt = cp[win]
        face[tgt], u[tgt], v[tgt] = cf[win], pu[win], pv[win]
        foot[tgt], dist[tgt], normal[tgt] = pfoot[win], pdist[win], pnorm[win]
        status[tgt] = np.where(pstat[win] == ON_BOUNDARY, ON_BOUNDARY, CONVERGED)
    # a candidate face whose projection FAILED but whose last iterate is already nearer
    # than the chosen foot: the true nearest point lies on that face and is unknown, so the
    # point is FAILED too (never a foot on a farther face passed off as the nearest)
    bad = (pstat == FAILED) & np.isfinite(pdist)
    if np.any(bad):
        bi = np.nonzero(bad)[0]
        tgt = cp[bi]
        nearer = (status[tgt] != FAILED) & (pdist[bi] < dist[tgt] - tie_tol * size)
        if np.any(nearer):
            t = tgt[nearer]
            face[t] = cf[bi[nearer]]
            u[t], v[t], foot[t], dist[t] = np.nan, np.nan, np.nan, np.nan
            normal[t] = np.nan
            status[t] = FAILED
    named = face.copy()  # the face each FAILED point failed on; else its nearest sample's face
    if len(cp1):
        named[named < 0] = f0[named < 0]
    _retry_failed(model, pts, named, u, v, foot, dist, normal, status, tol)
    face[status != FAILED] = named[status != FAILED]
    if max_distance is not None:
        status[(status != FAILED) & (dist > max_distance)] = BEYOND_TOLERANCE
    return Projection(face, u, v, foot, dist, normal, status, candidates)


def _retry_failed(model: Model, pts, face, u, v, foot, dist, normal, status, tol: float) -> None:
    """Points FAILED on a named face (``face``; the nearest sample's where no face gave a
    foot): that face projected again by `project_to_surface`,
    whose restarts widen to 64 grid samples (the compiled pairs restart from 4: beside a
    pole, where many samples sit at one point, all four start Newton in the collapsed corner
    and it stalls: PRO19800's apex). A foot inside the face's trims is taken (CONVERGED);
    the arrays are updated in place."""
    from cadbridge.nurbs.project import project_to_surface

    bad = np.flatnonzero((status == FAILED) & (face >= 0))
    for fk in np.unique(face[bad]):  # loop over the (few) faces that failed
        rows = bad[face[bad] == fk]
        f = model.faces[int(fk)]
        r = project_to_surface(f.surface, pts[rows], tol=tol)
        ok = r.status != FAILED
        ok[ok] = f.contains(r.u[ok], r.v[ok])
        take = rows[ok]
        u[take], v[take], foot[take], dist[take], normal[take] = r.u[ok], r.v[ok], r.foot[ok], r.distance[ok], r.normal[ok]
        status[take] = CONVERGED
