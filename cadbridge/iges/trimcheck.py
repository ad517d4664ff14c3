"""The file's trim tolerance ("delta"): how far a face's own 2D and 3D trim curves disagree.

For every trim loop that carries both representations (a 142's BPTR and CPTR, or 141/508
edges with parameter-space and model-space curves), delta is the largest distance from
S(c2d(t)) -- the parameter-space curve followed on the face's surface -- to the loop's
model-space curves, over dense samples of c2d (`SAMPLES_PER_SPAN` per knot span):

1. all model-space pieces of the whole model are sampled in one compiled call
   (`eval_packed`), with first and second derivatives;
2. one KD-tree over those samples, each lifted by a fourth coordinate ``loop id x L`` (L far
   larger than the model), so the nearest sample of a query point always belongs to the
   same loop (no all-pairs distances, one tree for the whole file);
3. from the nearest of the `NEAREST` nearest samples on each distinct piece, Newton on
   f(t) = (C(t) - P) . C'(t) on its piece (exact curve, compiled, at most `NEWTON_STEPS`, a
   point leaves when its step is below 1e-15 of the piece's domain), t clamped to the
   piece's domain; the nearest foot wins (at a junction of two pieces the true foot may lie
   on the other one).

The result is per face (model units) and is what `Face.trim_delta` holds. Faces whose trim
route does not depend on delta get it lazily: `DeltaBatch` keeps what the computation needs
and runs `loop_deltas` once for all of them on the first access of any face's ``trim_delta``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from cadbridge.cad.analytic import SurfaceInvertedCurve, evaluate_inverted
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.curve_pack import PackedCurves

__all__ = ["CONTRADICTION", "DeltaBatch", "check_trim_agreement", "loop_deltas", "SAMPLES_PER_SPAN"]

SAMPLES_PER_SPAN = 16  # samples of c2d per knot span
TREE_PER_SPAN = 64  # samples per knot span of the model curves in the KD-tree (Newton starts; 16 let
# Newton settle in a wrong local minimum on the long degree-6 pieces of the ANSA file, 8 x degree
# on pieces of the Euclid bearing)
NEWTON_STEPS = 4
NEAREST = 3  # Newton starts per query point (nearest tree samples)
CONTRADICTION = 0.05
"""A face whose 2D and 3D trims disagree by more than this x the model size contradicts
itself (`check_trim_agreement`). The real files of the corpus and ../shared/iges_real stay
below 1.7e-3 (PRO19800); a damaged number in a surface's boundary poles or in a trim curve
gives about 1 (the whole model: the model size grows with the damage)."""


def loop_deltas(items: list[tuple]) -> np.ndarray:
    """Trim delta per item: ``items`` is a list of (surface, [(uv pieces, model pieces), ...])
    -- per face its NURBS surface and, per loop, the parameter-space pieces (objects with the
    NurbsCurve interface, in the surface's (u, v)) and the model-space pieces (3D
    `NurbsCurve`). Returns (len(items),): the largest distance from S(uv(t)) to the loop's
    model curves, NaN for an item without loops."""
    out = np.full(len(items), np.nan)
    model: list[NurbsCurve] = []
    model_loop: list[int] = []
    uvc: list[NurbsCurve] = []  # parameter-space NURBS pieces of all items: one compiled call
    uvc_loop: list[int] = []
    other: list[tuple[int, int, object]] = []  # (item, loop id, mapped piece)
    surfaces = []
    lid = 0
    for i, (surface, loops) in enumerate(items):
        loops = [lp for lp in loops if lp[0] and lp[1]]
        if not loops:
            continue
        surfaces.append((i, surface))
        for k, (pcs, mcs) in enumerate(loops):
            for c in pcs:
                if isinstance(c, NurbsCurve):
                    uvc.append(c)
                    uvc_loop.append(lid + k)
                else:
                    other.append((i, lid + k, c))
            model.extend(mcs)
            model_loop.extend([lid + k] * len(mcs))
        lid += len(loops)
    if not surfaces or not model:
        return out
    item_of_loop = np.empty(lid, dtype=np.int64)
    lid = 0
    for i, surface in surfaces:
        n = sum(1 for lp in items[i][1] if lp[0] and lp[1])
        item_of_loop[lid : lid + n] = i
        lid += n
    uv_rows, loop_rows = [], []
    if uvc:
        pu = PackedCurves(uvc)
        ci, tt = pu.sample(SAMPLES_PER_SPAN)
        uv_rows.append(pu.evaluate(ci, tt, 0)[:, 0, :2])
        loop_rows.append(np.asarray(uvc_loop, dtype=np.int64)[ci])
    inv = [k for k, (_, _, c) in enumerate(other) if isinstance(c, SurfaceInvertedCurve)]
    inv_uv = dict(zip(inv, evaluate_inverted([other[k][2] for k in inv],  # one pass per surface
                                             [other[k][2].base.sample_parameters(SAMPLES_PER_SPAN) for k in inv])))
    for k, (i, l, c) in enumerate(other):
        uv = inv_uv[k] if k in inv_uv else c.evaluate(getattr(c, "base", c).sample_parameters(SAMPLES_PER_SPAN))
        uv_rows.append(uv)
        loop_rows.append(np.full(len(uv), l, dtype=np.int64))
    uv = np.concatenate(uv_rows)
    qloop = np.concatenate(loop_rows)
    qitem = item_of_loop[qloop]
    order = np.argsort(qitem, kind="stable")
    uv, qloop, qitem = uv[order], qloop[order], qitem[order]
    pts = np.empty((len(uv), 3))
    for i, surface in surfaces:  # one surface evaluation per face
        a, b = np.searchsorted(qitem, [i, i + 1])
        u0, u1, v0, v1 = surface.domain
        pts[a:b] = surface.evaluate(np.clip(uv[a:b, 0], u0, u1), np.clip(uv[a:b, 1], v0, v1))
    pm = PackedCurves(model)
    ci, tt = pm.sample(TREE_PER_SPAN)
    cs = pm.evaluate(ci, tt, 0)[:, 0]
    lift = 1e3 * (float(np.ptp(np.concatenate([cs, pts]), axis=0).max()) + 1.0)
    sloop = np.asarray(model_loop)[ci]
    tree = cKDTree(np.column_stack([cs, sloop * lift]))
    # the 3 nearest samples (often on two pieces at a junction): Newton from each, the nearest foot wins
    _, kk = tree.query(np.column_stack([pts, qloop * lift]), k=min(NEAREST, len(cs)))
    kk = np.asarray(kk).reshape(len(pts), -1)
    # one start per (query, piece): further samples on the same piece lead to the same foot
    ck = ci[kk]
    keep = np.ones(kk.shape, dtype=bool)
    for j in range(1, kk.shape[1]):
        keep[:, j] = np.all(ck[:, j : j + 1] != ck[:, :j], axis=1)
    qi = np.nonzero(keep)[0]
    k = kk[keep]
    p3 = pts[qi]
    c = ci[k]
    t = tt[k].copy()
    lo, hi = pm.dom[c, 0], pm.dom[c, 1]
    act = np.arange(len(t))  # points still moving
    for _ in range(NEWTON_STEPS):
        ca, ta, pa = c[act], t[act], p3[act]
        d = pm.evaluate(ca, ta, 2)
        r = d[:, 0] - pa
        f = np.einsum("ij,ij->i", r, d[:, 1])
        g1 = np.einsum("ij,ij->i", d[:, 1], d[:, 1])
        fp = g1 + np.einsum("ij,ij->i", r, d[:, 2])
        fp = np.where(fp > 0, fp, g1 + 1e-300)
        tn = np.clip(ta - f / fp, lo[act], hi[act])
        t[act] = tn
        act = act[np.abs(tn - ta) > 1e-15 * np.maximum(hi[act] - lo[act], 1e-300)]
        if act.size == 0:
            break
    dist = np.linalg.norm(pm.evaluate(c, t, 0)[:, 0] - p3, axis=1)
    dist = np.minimum(dist, np.linalg.norm(cs[k] - p3, axis=1))  # Newton never worse than the sample
    best = np.full(len(pts), np.inf)
    np.minimum.at(best, qi, dist)
    res = np.full(len(items), -np.inf)
    np.maximum.at(res, qitem, best)
    have = np.isfinite(res)
    out[have] = res[have]
    return out


class DeltaBatch:
    """Trim deltas of many faces, computed together by one `loop_deltas` call on the first
    `value` request (what `Face.defer_trim_delta` points at).

    Entries are added with `add_face` (a face whose own surface and trim loops -- parameter-space
    ``curves`` against ``model_curves`` -- are read when the batch computes, i.e. after any
    placement) or `add_pairs` (a surface, (uv pieces, model pieces) per loop, a factor the
    result is multiplied by: a 408's scale for loops kept in the definition's coordinates, and
    optionally ``note``: called with the unscaled delta once it is computed, for a reader
    note that depends on delta but not the trim route, e.g. "the 2D and 3D curves disagree")."""

    def __init__(self) -> None:
        self._entries: list[tuple] = []
        self._values: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self._entries)

    def add_face(self, face) -> int:
        self._entries.append(("face", face))
        return len(self._entries) - 1

    def add_pairs(self, surface, pairs: list[tuple], scale: float = 1.0, note=None) -> int:
        self._entries.append(("pairs", surface, pairs, float(scale), note))
        return len(self._entries) - 1

    def value(self, index: int) -> float | None:
        """Delta of entry ``index`` (model units), None when it has no loop with both curves."""
        if self._values is None:
            items, scale, notes = [], np.ones(len(self._entries)), []
            for k, e in enumerate(self._entries):
                if e[0] == "face":
                    f = e[1]
                    lps = [] if f.trims is None else [lp for lp in [f.trims.outer] + list(f.trims.inner)
                                                      if lp is not None and lp.model_curves]
                    items.append((f.surface, [(lp.curves, lp.model_curves) for lp in lps]))
                else:
                    items.append((e[1], e[2]))
                    scale[k] = e[3]
                    if e[4] is not None:
                        notes.append((k, e[4]))
            raw = loop_deltas(items)
            self._values = raw * scale
            for k, note in notes:
                if not np.isnan(raw[k]):
                    note(float(raw[k]))
            self._entries = []  # the geometry is no longer needed
        d = self._values[index]
        return None if np.isnan(d) else float(d)


def check_trim_agreement(model) -> None:
    """Raise `IgesError` (file, the face's DE and entity) when a face's 2D and 3D trim curves
    disagree by more than `CONTRADICTION` x the model size: the file then holds two different
    boundaries for that face, mesher and projection would each follow another, and gmsh has
    been seen meshing such a face (a surface pole moved 10^6 times farther by a damaged
    number) without end. ``model``: a `cadbridge.cad.model.Model` (computes every face's
    ``trim_delta``, one pass for the file)."""
    from cadbridge.iges.errors import IgesError

    if not model.faces:
        return
    size = model.size()
    for k, f in enumerate(model.faces):
        d = f.trim_delta
        if d is not None and d > CONTRADICTION * size:
            raise IgesError(f"face {k} ({f.name or 'unnamed'}): its 2D and 3D trim curves disagree by {d:.3g} "
                            f"({d / size:.0%} of the model size {size:.3g}); the file contradicts itself there "
                            f"(a damaged number?)", filename=model.source, de=f.de, entity_type=f.entity_type)
