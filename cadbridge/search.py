"""Global projection of points onto a whole model: which face, (u, v), foot, exact normal.

1. Upper bound: one KD-tree over grid samples of all faces (samples inside the trims only);
   the distance to the nearest sample bounds the distance to the nearest valid foot.
2. Candidates: every face is covered by per-knot-span boxes from its control net (the
   control points P[i-p..i, j-q..j] of span (i, j) contain that span's piece of surface:
   strong convex hull property, weights > 0). Boxes are grouped by size (octaves of their
   half-diagonal R) with a KD-tree of centres per group; (point, box) pairs come from dual
   tree traversals (``sparse_distance_matrix``) with points grouped by octave of their bound,
   then the exact point-box distance is tested against the point's bound. Cost ~ N log F.
3. Projection: all candidate points of one face are projected together (vectorised Newton,
   `project_to_surface`); the loop runs over faces, never over points.
4. Choice: the nearest valid foot wins; a foot outside a face's trim loops is not valid for
   that face but the nearest point of its trim loops is (`project_to_trims`, ON_BOUNDARY);
   at equal distance (within ``tie_tol`` x model size) a foot inside a face beats
   one clamped to a face edge (ON_BOUNDARY). A point whose projection FAILED on a face that
   is nearer (at its last iterate) than the chosen foot is FAILED (``face`` names the face
   that failed): a failure is reported, never replaced by a foot on a farther face.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from cadbridge.model import Model
from cadbridge.nurbs.project import (
    BEYOND_TOLERANCE,
    CONVERGED,
    FAILED,
    ON_BOUNDARY,
    STATUS_NAMES,
    project_to_surface,
    surface_samples,
)
from cadbridge.nurbs.surface import NurbsSurface
from cadbridge.trims import project_to_trims

__all__ = ["Projection", "SearchIndex", "build_search_index", "project_points", "project_to_trims", "span_boxes"]  # project_to_trims: re-export


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


@dataclass
class SearchIndex:
    """Precomputed search structures of a model (reusable across calls).

    box_lo, box_hi (B, 3), box_face (B,); groups: list of (cKDTree of centres, R max,
    box indices) per size octave; sample_tree over valid samples of all faces, sample_face
    (S,); size: model size (box diagonal).
    """

    box_lo: np.ndarray
    box_hi: np.ndarray
    box_face: np.ndarray
    groups: list
    sample_tree: cKDTree | None
    sample_face: np.ndarray
    size: float
    n_faces: int


def build_search_index(model: Model) -> SearchIndex:
    """Boxes, box-size groups and the sample KD-tree of ``model``. Raises ValueError if the
    model has no faces."""
    if not model.faces:
        raise ValueError("project_points: empty model (no faces to project onto)")
    los, his, fids, spts, sfid = [], [], [], [], []
    for k, face in enumerate(model.faces):
        b = span_boxes(face.surface)
        los.append(b[:, 0])
        his.append(b[:, 1])
        fids.append(np.full(len(b), k))
        smp = surface_samples(face.surface)
        inside = face.contains(smp.uv[:, 0], smp.uv[:, 1])
        spts.append(smp.points[inside])
        sfid.append(np.full(int(inside.sum()), k))
    lo, hi = np.concatenate(los), np.concatenate(his)
    face_of_box = np.concatenate(fids)
    centre = 0.5 * (lo + hi)
    rad = 0.5 * np.linalg.norm(hi - lo, axis=1)
    size = model.size()
    # octave of the half-diagonal (all tiny boxes in one group)
    octave = np.floor(np.log2(np.maximum(rad, 1e-6 * max(size, 1e-300)))).astype(int)
    groups = []
    for o in np.unique(octave):
        sel = np.nonzero(octave == o)[0]
        groups.append((cKDTree(centre[sel]), float(rad[sel].max()), sel))
    allpts = np.concatenate(spts)
    tree = cKDTree(allpts) if len(allpts) else None
    return SearchIndex(lo, hi, face_of_box, groups, tree, np.concatenate(sfid), size, len(model.faces))


def _candidate_pairs(index: SearchIndex, pts: np.ndarray, bound: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(point, face) pairs whose span boxes lie within ``bound`` (N,) of the point; unique,
    sorted by face. Returns (point indices, face indices)."""
    n = len(pts)
    finite = np.isfinite(bound)
    pairs_p, pairs_b = [], []
    if np.any(~finite):  # no bound at all (no valid samples): every face is a candidate
        pi = np.nonzero(~finite)[0]
        pairs_p.append(np.repeat(pi, len(index.box_face)))
        pairs_b.append(np.tile(np.arange(len(index.box_face)), len(pi)))
    if np.any(finite):
        fb = bound[finite]
        lvl = np.floor(np.log2(np.maximum(fb, 1e-9 * max(index.size, 1e-300)))).astype(int)
        fidx = np.nonzero(finite)[0]
        for o in np.unique(lvl):
            sel = fidx[lvl == o]
            ptree = cKDTree(pts[sel])
            bmax = float(bound[sel].max())
            for btree, rmax, boxes in index.groups:
                m = ptree.sparse_distance_matrix(btree, bmax + rmax, output_type="ndarray")
                if len(m) == 0:
                    continue
                pairs_p.append(sel[m["i"]])
                pairs_b.append(boxes[m["j"]])
    if not pairs_p:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    p = np.concatenate(pairs_p)
    b = np.concatenate(pairs_b)
    # exact point-box distance against the point's bound
    x = pts[p]
    gap = np.maximum(np.maximum(index.box_lo[b] - x, x - index.box_hi[b]), 0.0)
    dist = np.linalg.norm(gap, axis=1)
    keep = ~np.isfinite(bound[p]) | (dist <= bound[p])
    p, f = p[keep], index.box_face[b[keep]]
    key = np.unique(f.astype(np.int64) * n + p)  # sorted by face, then point
    return key % n, key // n


_BLOCK = 65536  # points projected together at most (larger inputs go block by block)


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
        index = build_search_index(model)
    elif index.n_faces != len(model.faces):
        raise ValueError("index was built for another model")
    n = len(pts)
    if n > _BLOCK:
        # blocks of points keep the per-face work arrays (derivatives: 216 bytes per point
        # and iteration) cache- and memory-friendly: time stays linear in N
        parts = [project_points(pts[a : a + _BLOCK], model, max_distance=max_distance, tol=tol,
                                tie_tol=tie_tol, index=index) for a in range(0, n, _BLOCK)]
        return Projection(*(np.concatenate([getattr(r, f) for r in parts]) for f in
                            ("face", "u", "v", "foot", "distance", "normal", "status", "candidates")))
    size = index.size

    # 1. upper bound from the nearest valid sample
    if index.sample_tree is not None and n:
        ub, _ = index.sample_tree.query(pts)
        ub = ub * (1.0 + 1e-9) + 1e-9 * size
    else:
        ub = np.full(n, np.inf)

    # 2. candidate (point, face) pairs
    cp, cf = _candidate_pairs(index, pts, ub)
    candidates = np.bincount(cp, minlength=n)

    # 3. project per face
    m = len(cp)
    pu = np.empty(m)
    pv = np.empty(m)
    pfoot = np.empty((m, 3))
    pdist = np.empty(m)
    pnorm = np.empty((m, 3))
    pstat = np.empty(m, dtype=np.int8)
    valid = np.zeros(m, dtype=bool)
    starts = np.searchsorted(cf, np.arange(index.n_faces + 1))
    for k in range(index.n_faces):
        a, b = starts[k], starts[k + 1]
        if a == b:
            continue
        face = model.faces[k]
        r = project_to_surface(face.surface, pts[cp[a:b]], tol=tol)
        pu[a:b], pv[a:b], pfoot[a:b], pdist[a:b] = r.u, r.v, r.foot, r.distance
        pnorm[a:b], pstat[a:b] = r.normal, r.status
        ok = r.status != FAILED
        if face.trims is not None and np.any(ok):
            inside = face.contains(r.u[ok], r.v[ok])
            out = np.nonzero(ok)[0][~inside]
            ok[out] = False
            if len(out) and (face.trims.outer is not None or face.trims.inner):
                # the nearest point of the untrimmed surface is cut away: the nearest point
                # of the trimmed face lies on its trim boundary
                tu, tv, tf, td, tok = project_to_trims(face, pts[cp[a:b][out]], tol=tol)
                sel = out[tok]
                idx = a + sel
                pu[idx], pv[idx], pfoot[idx], pdist[idx] = tu[tok], tv[tok], tf[tok], td[tok]
                pnorm[idx] = face.surface.normal(tu[tok], tv[tok])
                pstat[idx] = ON_BOUNDARY
                ok[sel] = True
        valid[a:b] = ok

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
    if max_distance is not None:
        status[(status != FAILED) & (dist > max_distance)] = BEYOND_TOLERANCE
    return Projection(face, u, v, foot, dist, normal, status, candidates)
