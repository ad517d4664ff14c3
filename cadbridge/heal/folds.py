"""Fold lines inside CAD faces: where a NURBS surface runs back over itself.

Some real faces are parametrised over more than their sheet: the control net overshoots and
turns back, so the surface folds along a line in (u, v) and the part beyond the fold lies
back on the sheet (a Z-fold; FACE(274) of the OCC corpus file ``OCC131-2_ANSA9``, whose v
rows go x 3549.8 -> 3545.8 -> 3547.6, folds twice). The surface stays smooth in (u, v), but
along a line crossing the fold its speed nearly vanishes: the map is nearly singular there, a
cusp, and the normal turns by ~180 degrees within a hair's width (micrometres). One
quadratic Nagata patch cannot fold, and the exact normal right at the fold is the hairpin's
(perpendicular to both sheets), which no patch should take. So

* `fold_lines` finds the fold lines of every face on the exact surface: on each across-line
  (v-line at fixed u, or u-line at fixed v) the normal turns by more than 120 degrees between
  samples one or two apart; the turn is bisected on the normal, then the fold point is the
  speed minimum ``S_s . S_ss = 0`` next to it (bisection on analytic derivatives), and it is a
  fold when the across-line's radius of curvature there is below ``1e-5 x`` model size
  (tighter than any mesh can follow; a real fillet is a radius the mesher resolves) on a line
  that is not collapsed (poles are no folds). Each line is returned with a 3D curve for the
  mesher (a cubic interpolant of the fold points, refined until it lies on the fold within
  ``1e-9 x`` model size), so mesh edges follow it (the crease route of `cadbridge.heal.creases`,
  `mesh.generate.mesh_cad(embed_curves=...)`); `folds_for` caches them on the model;
* `cusp_normal`: the sheets' common tangent plane at the fold, the limit of the normal from
  either side: ``unit(S_t x S_ss)`` (S_t along the line, S_ss the across second derivative;
  at a true cusp S_s = 0 and the sheets are tangent to S_t and S_ss);
* `apply_fold_normals` gives every element corner at a node on a fold (`fold_nodes`) that
  normal, oriented by the element's winding (one-sided normals: each element keeps its own
  sheet's side); where the sheets overlap, a node takes the mesher's (u, v) when that is a
  foot too, or (`fold_sides`) is re-projected onto its element's sheet;
* `fold_straddling` names the elements with corners on both sides of a fold (the guard's
  "straddles a crease"; a user mesh that does so is stopped);
* `fold_reference_normals`: the cusp normal for error samples on a fold line.

Fold lines are found where they cross a whole family of across-lines (the same number of
folds on every line of the family, a line v = f(u) or u = f(v) over the face's domain); a
fold that ends inside a face is reported by `fold_lines`' ``partial`` list and left to the
guard.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from cadbridge.cad.model import Model
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["FoldLine", "Folds", "apply_fold_normals", "cusp_normal", "fold_lines", "fold_nodes", "fold_reference_normals",
           "fold_sides", "fold_straddling", "folds_for"]

REVERSAL_COS = np.cos(np.radians(120.0))
"""Adjacent samples whose normals are further apart than 120 degrees bracket a turn-back."""
FOLD_RADIUS = 1e-5
"""A turn-back is a fold when the across radius of curvature at it is below this x model size."""
CURVE_TOL = 1e-9
"""The fold's 3D curve lies on the exact fold points within this x model size."""
_SAMPLES_PER_SPAN = 16
_MAX_POINTS = 1025


@dataclass(frozen=True)
class FoldLine:
    """One fold line of a face.

    face     index into ``model.faces``
    across   "v": the line crosses the v-lines, v = f(u) (t = u, s = v); "u": u = f(v)
    t, s     (M,) exact fold points (t, f(t)) over the face's domain, t increasing
    lo, hi   (M,) the bracket of each fold point (normal reversed between them)
    curve    3D `NurbsCurve` of the line parametrised by t (cubic interpolant of S(t, f(t)))
    points   (M, 3) S(t, f(t))
    deviation  max distance of ``curve`` from the exact fold points between its nodes
    radius   (M,) radius of curvature of the across-line at the fold points
    """

    face: int
    across: str
    t: np.ndarray
    s: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    curve: NurbsCurve
    points: np.ndarray
    deviation: float
    radius: np.ndarray

    def uv(self, t=None, s=None) -> tuple[np.ndarray, np.ndarray]:
        """(u, v) of line parameters t and across parameters s (default: the fold points)."""
        t = self.t if t is None else t
        s = self.s if s is None else s
        return (t, s) if self.across == "v" else (s, t)


@dataclass
class Folds:
    """What `fold_lines` finds: ``lines`` (`FoldLine`) and ``partial`` (face, across) pairs
    where the normal turns back on some across-lines only (a fold ending inside the face;
    not split)."""

    lines: list[FoldLine] = field(default_factory=list)
    partial: list[tuple[int, str]] = field(default_factory=list)


def _unit(a: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(a, axis=-1, keepdims=True)
    return a / np.where(n > 0, n, 1.0)


def _ders(surface: NurbsSurface, across: str, t, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(S_t, S_s, S_ss) at line parameter t, across parameter s, each (N, 3)."""
    u, v = (t, s) if across == "v" else (s, t)
    d = surface.derivatives(np.asarray(u, dtype=float), np.asarray(v, dtype=float), order=2)
    if across == "v":
        return d[:, 1, 0], d[:, 0, 1], d[:, 0, 2]
    return d[:, 0, 1], d[:, 1, 0], d[:, 2, 0]


def _normals(surface: NurbsSurface, across: str, t, s) -> np.ndarray:
    u, v = (t, s) if across == "v" else (s, t)
    d = surface.derivatives(np.asarray(u, dtype=float), np.asarray(v, dtype=float), order=1)
    return _unit(np.cross(d[:, 1, 0], d[:, 0, 1]))


def _grid(knots: np.ndarray, lo: float, hi: float, per_span: int) -> np.ndarray:
    k = np.unique(np.clip(knots, lo, hi))
    k = k[(k >= lo) & (k <= hi)]
    k = np.unique(np.concatenate([[lo, hi], k]))
    pieces = [np.linspace(a, b, per_span + 1)[:-1] for a, b in zip(k[:-1], k[1:]) if b > a]
    return np.concatenate(pieces + [[hi]])


def _turn_backs(nn: np.ndarray, gs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Brackets where the normal turns back along each grid line: nn (T, S, 3) unit normals on
    lines t (rows) at samples gs (S,). Samples one and two apart are compared (a hairpin
    thinner than the spacing may hold one sample, at 90 degrees from both neighbours), and
    overlapping brackets of a line merged. Returns line index (K,), bracket lo, hi (K,)."""
    T, S = nn.shape[:2]
    rev = np.zeros((T, S - 1), dtype=bool)  # span j (samples j, j+1) inside a turn-back
    one = np.einsum("ijk,ijk->ij", nn[:, 1:], nn[:, :-1]) < REVERSAL_COS
    rev |= one
    if S > 2:
        two = np.einsum("ijk,ijk->ij", nn[:, 2:], nn[:, :-2]) < REVERSAL_COS
        rev[:, :-1] |= two
        rev[:, 1:] |= two
    # runs of True spans per line -> one bracket each
    pad = np.zeros((T, 1), dtype=bool)
    edge = np.diff(np.concatenate([pad, rev, pad], axis=1).astype(np.int8), axis=1)
    ts, js = np.nonzero(edge == 1)
    te, je = np.nonzero(edge == -1)  # same row-major order: runs pair up
    return ts, gs[js], gs[je]


def _speed_slope(surface: NurbsSurface, across: str, t, s) -> np.ndarray:
    _, ss, sss = _ders(surface, across, t, s)
    return np.einsum("ij,ij->i", ss, sss)


def _fold_points(surface: NurbsSurface, across: str, t: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 iters: int = 60) -> np.ndarray:
    """Fold point s in [lo, hi] on each across-line t (N,): the speed minimum S_s . S_ss = 0.
    The turn-back is first bisected on the normal (the point where it is orthogonal to the
    normal at lo), then the smallest bracket around that point over which S_s . S_ss goes
    from - to + is bisected (where none is found, the normal's point is kept)."""
    t = np.asarray(t, dtype=float)
    a, b = np.asarray(lo, dtype=float).copy(), np.asarray(hi, dtype=float).copy()
    lo0, hi0 = a.copy(), b.copy()
    na = _normals(surface, across, t, a)
    for _ in range(iters):  # bisection on the normal, vectorised over the lines
        m = 0.5 * (a + b)
        left = np.einsum("ij,ij->i", _normals(surface, across, t, m), na) < 0  # turned: root in [a, m]
        b = np.where(left, m, b)
        a = np.where(left, a, m)
    m0 = 0.5 * (a + b)
    w = hi0 - lo0
    a, b = m0.copy(), m0.copy()
    found = np.zeros(len(t), dtype=bool)
    for h in np.geomspace(1e-10, 1.0, 21):  # widen until the speed slope changes sign
        ta, tb = np.maximum(lo0, m0 - h * w), np.minimum(hi0, m0 + h * w)
        ok = ~found & (_speed_slope(surface, across, t, ta) < 0) & (_speed_slope(surface, across, t, tb) > 0)
        a, b = np.where(ok, ta, a), np.where(ok, tb, b)
        found |= ok
        if found.all():
            break
    for _ in range(iters):  # bisection on the speed slope
        m = 0.5 * (a + b)
        left = _speed_slope(surface, across, t, m) > 0
        b = np.where(found & left, m, b)
        a = np.where(found & ~left, m, a)
    return np.where(found, 0.5 * (a + b), m0)


def _across_radius(surface: NurbsSurface, across: str, t, s) -> np.ndarray:
    """Radius of curvature |S_s|^3 / |S_s x S_ss| of the across-line at (t, s), (N,)."""
    _, ss, sss = _ders(surface, across, t, s)
    c = np.linalg.norm(np.cross(ss, sss), axis=1)
    return np.linalg.norm(ss, axis=1) ** 3 / np.where(c > 0, c, 1e-300)


def cusp_normal(surface: NurbsSurface, across: str, t, s) -> np.ndarray:
    """Unit normal of the sheets' common tangent plane at fold points (t, s), (N, 3):
    unit(S_t x S_ss) (module docs); sign as the surface's normal on the side s < fold."""
    st, _, sss = _ders(surface, across, np.atleast_1d(t), np.atleast_1d(s))
    n = np.cross(st, sss) if across == "v" else np.cross(sss, st)
    # S_s ~ S_ss (s - s*): on the side s < s*, S_u x S_v ~ -(S_t x S_ss) (across "v")
    return -_unit(n)


def _line_curve(surface: NurbsSurface, across: str, t0: float, t1: float, t: np.ndarray,
                lo: np.ndarray, hi: np.ndarray, tol: float):
    """Fold points on a uniform t grid fine enough that their cubic interpolant lies on the
    exact fold within ``tol`` at the midpoints; returns (t, s, lo, hi, points, curve, dev)."""
    from scipy.interpolate import make_interp_spline  # here, not at the top: ~0.5 s to import, rarely needed

    u0, u1, v0, v1 = surface.domain
    s_min, s_max = (v0, v1) if across == "v" else (u0, u1)
    n = 17
    while True:
        tt = np.linspace(t0, t1, n)
        # brackets: linear in t between the coarse grid's brackets, widened to the coarse
        # bracket width (the fold moves smoothly)
        w = float(np.max(hi - lo))
        c_lo = np.maximum(np.interp(tt, t, lo) - 0.5 * w, s_min)
        c_hi = np.minimum(np.interp(tt, t, hi) + 0.5 * w, s_max)
        ss = _fold_points(surface, across, tt, c_lo, c_hi)
        u, v = (tt, ss) if across == "v" else (ss, tt)
        pts = surface.evaluate(u, v)
        spl = make_interp_spline(tt, pts, k=3)
        curve = NurbsCurve(3, spl.t, spl.c)
        tm = 0.5 * (tt[1:] + tt[:-1])
        sm = _fold_points(surface, across, tm, np.maximum(np.interp(tm, t, lo) - 0.5 * w, s_min),
                          np.minimum(np.interp(tm, t, hi) + 0.5 * w, s_max))
        um, vm = (tm, sm) if across == "v" else (sm, tm)
        dev = float(np.max(np.linalg.norm(curve.evaluate(tm) - surface.evaluate(um, vm), axis=1)))
        if dev <= tol or 2 * n - 1 > _MAX_POINTS:
            return tt, ss, c_lo, c_hi, pts, curve, dev
        n = 2 * n - 1


def fold_lines(model: Model, per_span: int = _SAMPLES_PER_SPAN) -> Folds:
    """Fold lines of every face of ``model`` (module docs). Faces without a turn-back cost
    one grid of normals each: ``per_span`` samples per knot span in both directions."""
    size = model.size()
    out = Folds()
    for k, face in enumerate(model.faces):  # loop over faces, vectorised over the grid
        s = face.surface
        u0, u1, v0, v1 = s.domain
        gu = _grid(s.knots_u, u0, u1, per_span)
        gv = _grid(s.knots_v, v0, v1, per_span)
        U, V = np.meshgrid(gu, gv, indexing="ij")
        n = _normals(s, "v", U.ravel(), V.ravel()).reshape(len(gu), len(gv), 3)
        x = s.evaluate(U.ravel(), V.ravel()).reshape(len(gu), len(gv), 3)
        # lengths of the v-lines (fixed u) and u-lines: a collapsed line (a pole) has normals
        # of round-off along it, no turn-back
        len_v = np.linalg.norm(np.diff(x, axis=1), axis=2).sum(axis=1)
        len_u = np.linalg.norm(np.diff(x, axis=0), axis=2).sum(axis=0)
        found = False
        for across, nn, gt, gs, (t0, t1), ln in (("v", n, gu, gv, (u0, u1), len_v),
                                                 ("u", n.transpose(1, 0, 2), gv, gu, (v0, v1), len_u)):
            ti, lo, hi = _turn_backs(nn, gs)
            keep = ln[ti] > 1e-6 * size
            ti, lo, hi = ti[keep], lo[keep], hi[keep]
            if not len(ti):
                continue
            sf = _fold_points(s, across, gt[ti], lo, hi)
            st = np.linalg.norm(_ders(s, across, gt[ti], sf)[0], axis=1)
            # a fold: the across-line's radius below FOLD_RADIUS x size, on a line the surface
            # does not collapse (a pole, S_t = 0, has normals of round-off along it)
            fold = (_across_radius(s, across, gt[ti], sf) < FOLD_RADIUS * size) & (st > 1e-6 * size / (t1 - t0))
            ti, lo, hi = ti[fold], lo[fold], hi[fold]
            if not len(ti):
                continue  # tight radii the mesher can follow, not folds
            counts = np.bincount(ti, minlength=len(gt))
            if counts.min() != counts.max():
                out.partial.append((k, across))
                continue
            kk = int(counts[0])
            order = np.lexsort((lo, ti))  # per line t, the folds in s order
            lo, hi = lo[order].reshape(len(gt), kk), hi[order].reshape(len(gt), kk)
            for j in range(kk):  # loop over the (one or two) fold lines of this family
                tt, ss, c_lo, c_hi, pts, curve, dev = _line_curve(s, across, t0, t1, gt, lo[:, j], hi[:, j],
                                                                  CURVE_TOL * size)
                out.lines.append(FoldLine(k, across, tt, ss, c_lo, c_hi, curve, pts, dev,
                                          _across_radius(s, across, tt, ss)))
                found = True
        if found:  # a fold line of one family crosses some lines of the other: not partial
            out.partial = [p for p in out.partial if p[0] != k]
    return out


_FOLDS_KEY = "_cadbridge_folds"


def folds_for(model: Model) -> Folds:
    """`fold_lines` of ``model``, computed once and cached on the model object (rebuilt when
    its face list changed)."""
    key = tuple((id(f), id(f.surface)) for f in model.faces)
    hit = model.__dict__.get(_FOLDS_KEY)
    if hit is not None and hit[0] == key:
        return hit[1]
    folds = fold_lines(model)
    model.__dict__[_FOLDS_KEY] = (key, folds)
    return folds


def _nearest_on_line(line: FoldLine, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (K,) of points x (K, 3) to the fold line's polyline of exact fold points,
    and the line parameter t (K,) of the nearest point."""
    p = line.points
    _, i = cKDTree(p).query(x)
    best_d = np.full(len(x), np.inf)
    best_t = np.zeros(len(x))
    for off in (-1, 0):  # the two segments at the nearest vertex
        a = np.clip(i + off, 0, len(p) - 2)
        pa, pb = p[a], p[a + 1]
        d = pb - pa
        w = np.clip(np.einsum("ij,ij->i", x - pa, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300), 0, 1)
        dist = np.linalg.norm(pa + w[:, None] * d - x, axis=1)
        better = dist < best_d
        best_d = np.where(better, dist, best_d)
        best_t = np.where(better, line.t[a] + w * (line.t[a + 1] - line.t[a]), best_t)
    return best_d, best_t


def fold_nodes(nodes: np.ndarray, folds: Folds, model: Model, tol: float | None = None):
    """Nodes lying on a fold line: (node ids (K,), fold line index (K,), line parameter (K,)).
    ``tol`` default 1e-6 x model size (a 3D distance; mesh nodes off the line lie an element
    away)."""
    tol = 1e-6 * model.size() if tol is None else float(tol)
    ids, which, tpar = [], [], []
    for j, line in enumerate(folds.lines):  # loop over the (few) fold lines
        lo, hi = line.points.min(0) - tol, line.points.max(0) + tol
        cand = np.flatnonzero(np.all((nodes >= lo) & (nodes <= hi), axis=1))
        if not len(cand):
            continue
        d, t = _nearest_on_line(line, nodes[cand])
        on = d <= tol
        ids.append(cand[on])
        which.append(np.full(int(on.sum()), j))
        tpar.append(t[on])
    if not ids:
        z = np.zeros(0, dtype=np.int64)
        return z, z, np.zeros(0)
    return np.concatenate(ids), np.concatenate(which), np.concatenate(tpar)


def _element_normals(nodes: np.ndarray, conn: np.ndarray) -> np.ndarray:
    x = nodes[conn]
    if conn.shape[1] == 3:
        return np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    return np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 1])


def apply_fold_normals(cn, mesh, model: Model, folds: Folds, flip: bool = False) -> int:
    """One-sided normals at fold lines, in place on ``cn`` (a `cadbridge.normals.cad.CadNormals`
    over ``mesh``):

    * every corner at a fold node (`fold_nodes`) whose element lies on the fold's face takes
      the cusp normal (`cusp_normal` at the node's point of the line), oriented by the
      element's winding; the node normal becomes the cusp normal (its sign kept) and the
      node a crease node;
    * a corner whose foot lay on another sheet than its element's (`fold_sides`) takes the
      normal of its element's sheet at its foot there, oriented by the element's winding.

    Returns the number of corners changed."""
    if not folds.lines:
        return 0
    nodes = np.asarray(mesh.nodes, dtype=float)
    blocks = [np.asarray(c.data) for c in mesh.cells]
    sign = -1.0 if flip else 1.0
    changed = 0
    changed += _mesher_feet(cn, mesh, model, folds, blocks, sign)
    ids, which, nrm = _fold_node_normals(nodes, folds, model)
    if len(ids):
        line_face = np.array([folds.lines[j].face for j in which])
        at = np.full(len(nodes), -1)
        at[ids] = np.arange(len(ids))
        for conn, cnb, ef in zip(blocks, cn.corner_normals, cn.element_face):  # loop over blocks
            k = at[conn]  # (E, k) row into ids, or -1
            hit = (k >= 0) & (np.asarray(ef)[:, None] == line_face[np.maximum(k, 0)])
            ei, ki = np.nonzero(hit)
            n = nrm[k[ei, ki]]
            n = n * np.where(np.einsum("ij,ij->i", n, _element_normals(nodes, conn[ei])) < 0, -1.0, 1.0)[:, None]
            cnb[ei, ki] = n * sign  # as `cad_normals`: the element's side, times the flip
            changed += len(ei)
        old = cn.normals[ids]
        cn.normals[ids] = nrm * np.where(np.einsum("ij,ij->i", nrm, old) < 0, -1.0, 1.0)[:, None]
        cn.crease[ids] = True
    _, moved = fold_sides(blocks, model, folds, nodes, cn.face, cn.u, cn.v)
    for bi, ei, ki, f, u, v in moved:  # corners on both sheets: their element's sheet's normal
        if not len(ei):
            continue
        d = model.faces[f].surface.derivatives(u, v, order=1)
        n = _unit(np.cross(d[:, 1, 0], d[:, 0, 1]))
        n = n * np.where(np.einsum("ij,ij->i", n, _element_normals(nodes, blocks[bi][ei])) < 0, -1.0, 1.0)[:, None]
        cn.corner_normals[bi][ei, ki] = n * sign
        cn.crease[blocks[bi][ei, ki]] = True
        changed += len(ei)
    return changed


def _mesher_feet(cn, mesh, model: Model, folds: Folds, blocks: list[np.ndarray], sign: float) -> int:
    """Nodes on a folded face whose mesher (u, v) (gmsh's ``node_uv``) is a foot on that face
    too (S(u, v) within 1e-9 x size of the node) take it, with its normal (oriented as the
    node's, and per corner by the element's winding): where the sheets overlap, the global
    projection may have chosen another sheet than the one the mesher put the node on.
    Returns the number of nodes changed."""
    uv = mesh.point_data.get("node_uv") if getattr(mesh, "point_data", None) else None
    if uv is None:
        return 0
    uv = np.asarray(uv, dtype=float)
    nodes = np.asarray(mesh.nodes, dtype=float)
    if uv.ndim != 2 or uv.shape[0] != len(nodes) or uv.shape[1] not in (2, 3):
        return 0
    uv = uv[:, :2]  # (N, 2); a gmsh .msh file holds it as a 3-vector (u, v, 0)
    tol = 1e-9 * model.size()
    count = 0
    for f in sorted({line.face for line in folds.lines}):  # loop over folded faces
        cand = np.flatnonzero((cn.face == f) & np.isfinite(uv).all(axis=1))
        if not len(cand):
            continue
        surf = model.faces[f].surface
        u0, u1, v0, v1 = surf.domain
        uu, vv = uv[cand, 0], uv[cand, 1]
        inside = (uu >= u0) & (uu <= u1) & (vv >= v0) & (vv <= v1)
        cand, uu, vv = cand[inside], uu[inside], vv[inside]
        if not len(cand):
            continue
        d = surf.derivatives(uu, vv, order=1)
        ok = (np.linalg.norm(d[:, 0, 0] - nodes[cand], axis=1) <= tol) & (
            (np.abs(uu - cn.u[cand]) > 0) | (np.abs(vv - cn.v[cand]) > 0))
        cand, uu, vv = cand[ok], uu[ok], vv[ok]
        if not len(cand):
            continue
        n = _unit(np.cross(d[ok, 1, 0], d[ok, 0, 1]))
        cn.u[cand], cn.v[cand] = uu, vv
        cn.normals[cand] = n * np.where(np.einsum("ij,ij->i", n, cn.normals[cand]) < 0, -1.0, 1.0)[:, None]
        at = np.full(len(nodes), -1)
        at[cand] = np.arange(len(cand))
        for conn, cnb, ef in zip(blocks, cn.corner_normals, cn.element_face):  # loop over blocks
            k = at[conn]
            ei, ki = np.nonzero((k >= 0) & (np.asarray(ef)[:, None] == f))
            m = n[k[ei, ki]]
            m = m * np.where(np.einsum("ij,ij->i", m, _element_normals(nodes, conn[ei])) < 0, -1.0, 1.0)[:, None]
            cnb[ei, ki] = m * sign
        count += len(cand)
    return count


def fold_sides(blocks: list[np.ndarray], model: Model, folds: Folds, nodes: np.ndarray, node_face: np.ndarray,
               node_u: np.ndarray, node_v: np.ndarray):
    """Elements across fold lines, and corners whose foot lay on the wrong sheet.

    For each fold line, every corner whose foot lies on the fold's face is on the side +1 / -1
    (s > f(t) / s < f(t), f(t) the exact fold point of its across-line, `_fold_points`), or
    on neither when it lies on the line (`fold_nodes`, within 1e-6 x size). Near a fold the
    sheets overlap, so a node's global foot may lie on either: a corner on the other side
    from the rest of its element that lies on its element's sheet as well (projected onto it
    from the other corners' mean (u, v): within 1e-6 x size, foot on their side) takes its
    element's side. Returns (straddle, moved): straddle per block (E_b,) bool, corners on
    both sides still; moved: list of (block, element (M,), corner (M,), face, u (M,), v (M,))
    the re-projected corners and their feet on their element's sheet."""
    from cadbridge.nurbs.project import project_to_surface

    nodes = np.asarray(nodes, dtype=float)
    tol = 1e-6 * model.size()
    on_line = np.zeros(len(nodes), dtype=bool)
    on_line[fold_nodes(nodes, folds, model)[0]] = True
    straddle, moved = [], []
    for bi, conn in enumerate(blocks):  # loop over blocks
        conn = np.asarray(conn)
        bad = np.zeros(len(conn), dtype=bool)
        for line in folds.lines:  # loop over fold lines
            surf = model.faces[line.face].surface
            mine = (node_face[conn] == line.face) & ~on_line[conn]  # (E, k) corners on its sheets
            e = np.flatnonzero(mine.sum(axis=1) >= 2)
            if not len(e):
                continue
            c = conn[e]
            t = (node_u if line.across == "v" else node_v)[c]
            sv = (node_v if line.across == "v" else node_u)[c]
            fp = _fold_points(surf, line.across, t.ravel(), np.interp(t.ravel(), line.t, line.lo),
                              np.interp(t.ravel(), line.t, line.hi)).reshape(t.shape)
            sd = (np.sign(sv - fp) * mine[e]).astype(np.int64)
            for pref in (1, -1):  # the majority's sheet first, then (ties, failures) the other
                mixed = np.flatnonzero((sd > 0).any(axis=1) & (sd < 0).any(axis=1))
                if not len(mixed):
                    break
                tot = sd[mixed].sum(axis=1)
                maj = np.where(tot != 0, np.sign(tot) * pref, pref)  # the sheet tried
                ri, ki = np.nonzero(sd[mixed] == -maj[:, None])  # corners on the other side
                rows = mixed[ri]
                w = (sd[rows] == maj[ri, None]).astype(float)  # the corners on the sheet tried
                uu, vv = node_u[c[rows]], node_v[c[rows]]
                uv0 = np.column_stack([(uu * w).sum(1) / w.sum(1), (vv * w).sum(1) / w.sum(1)])
                pr = project_to_surface(surf, nodes[c[rows, ki]], uv0=uv0, global_check=False)
                ft, fs = (pr.u, pr.v) if line.across == "v" else (pr.v, pr.u)
                ffp = _fold_points(surf, line.across, ft, np.interp(ft, line.t, line.lo),
                                   np.interp(ft, line.t, line.hi))
                ok = (pr.distance <= tol) & (np.sign(fs - ffp) == maj[ri])
                # an element moves only if all its other-side corners lie on the sheet tried
                all_ok = np.ones(len(mixed), dtype=bool)
                np.logical_and.at(all_ok, ri, ok)
                ok &= all_ok[ri]
                sd[rows[ok], ki[ok]] = maj[ri[ok]]
                moved.append((bi, e[rows[ok]], ki[ok], line.face, pr.u[ok], pr.v[ok]))
            bad[e[(sd > 0).any(axis=1) & (sd < 0).any(axis=1)]] = True
        straddle.append(bad)
    return straddle, moved


def fold_straddling(blocks: list[np.ndarray], model: Model, folds: Folds, nodes: np.ndarray,
                    node_face: np.ndarray, node_u: np.ndarray, node_v: np.ndarray) -> np.ndarray:
    """Global ids (over ``blocks`` in order) of elements with corners strictly on both sides
    of a fold line (`fold_sides`: a corner on the line is on neither; a corner lying on both
    sheets is on its element's), (K,) sorted."""
    if not folds.lines:
        return np.zeros(0, dtype=np.int64)
    straddle, _ = fold_sides(blocks, model, folds, nodes, node_face, node_u, node_v)
    return np.flatnonzero(np.concatenate(straddle)) if straddle else np.zeros(0, dtype=np.int64)


def _fold_node_normals(points: np.ndarray, folds: Folds, model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The points (N, 3) on a fold line (`fold_nodes`) and their cusp normals (unoriented):
    ids (K,) into ``points``, which (K,) fold line, normals (K, 3)."""
    ids, which, tpar = fold_nodes(points, folds, model)
    nrm = np.empty((len(ids), 3))
    for j in np.unique(which):  # loop over fold lines
        m = which == j
        line = folds.lines[j]
        surf = model.faces[line.face].surface
        s = _fold_points(surf, line.across, tpar[m], np.interp(tpar[m], line.t, line.lo),
                         np.interp(tpar[m], line.t, line.hi))
        nrm[m] = cusp_normal(surf, line.across, tpar[m], s)
    return ids, which, nrm


def fold_reference_normals(model: Model, feet: np.ndarray, normals: np.ndarray, orient: np.ndarray) -> np.ndarray:
    """The CAD normals an error measure should compare with, (M, 3): ``normals`` (M, 3) at
    the ``feet`` (M, 3), except at feet on a fold line (`fold_nodes`, within 1e-6 x size:
    inside the hairpin, whose own normal is perpendicular to both sheets), which take the
    cusp normal there (`cusp_normal`), oriented to the side of ``orient`` (M, 3)."""
    folds = folds_for(model)
    out = np.array(normals, dtype=float, copy=True)
    if not folds.lines:
        return out
    feet = np.asarray(feet, dtype=float)
    good = np.flatnonzero(np.isfinite(feet).all(axis=1))
    ids, _, n = _fold_node_normals(feet[good], folds, model)
    ids = good[ids]
    out[ids] = n * np.where(np.einsum("ij,ij->i", n, orient[ids]) < 0, -1.0, 1.0)[:, None]
    return out
