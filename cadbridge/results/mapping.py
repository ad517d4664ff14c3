"""Nodal results mapped onto the exact CAD faces, once (Hawkins 1989, ch. 4).

`map_results(mesh, values, model)` inverts every node once to its face and (u, v)
(`cadbridge.normals.cad.cad_normals`: global box search + Newton, the farthest nodes named
when the mesh is off the CAD), gives every element the (u, v) of its corners on the
element's own face (a corner whose node projected onto a neighbouring face is projected
again onto the element's face: nodes on a shared face edge have a (u, v) on both faces),
and splits the elements into parameter-space triangles ("sub-triangles"):

- triangles stay as they are; quadrilaterals are split at their centre, whose value is the
  mean of the corner values (Hawkins' element "center value", Fig. 4.1 / 5.7);
- seams (a closed direction of a face, `closed_directions`): element corners are unwrapped
  to one side of the seam and triangles crossing it are cut at the seam line, the far part
  moved back by one period, so every sub-triangle lies in the face's domain (Hawkins §4.4,
  §4.6); seam nodes keep both parameter values, one per side;
- poles (a collapsed side of the domain): a pole corner's position along the pole line is
  undefined, so the corner becomes two vertices on the pole line under its two neighbours
  (the element becomes a quadrilateral in (u, v), split at its centre), which covers the
  parameter domain up to the pole exactly (Hawkins Fig. 5.8).

Inside a sub-triangle the field and the (u, v) are both linear in the barycentric
coordinates; a point of the result is S(u, v) on the exact surface. The exact area of every
sub-triangle, the integral of |Su x Sv| over its (u, v) triangle (conical Gauss product
rule), is computed here once, so re-levelling only clips the triangles that levels cross.

The returned `ResultMapping` re-contours (`.contour(levels)`) without repeating any of this.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from cadbridge.mesh.mesh import Mesh
from cadbridge.cad.model import Model
from cadbridge.nurbs.project import closed_directions, project_to_surface
from cadbridge.results.areas import surface_area_of_triangles, triangle_rule

__all__ = ["ResultMapping", "map_results", "triangle_rule", "surface_area_of_triangles", "face_topology"]

_SNAP = 1e-12  # parameters this close (x domain length) to a domain bound are put on it


@dataclass(frozen=True)
class FaceTopology:
    """Closed directions and collapsed domain sides of one face.

    closed  (closed_u, closed_v)
    poles   {(axis, value)}: the domain side ``axis`` = value (axis 0: u = value, a line
            along v) collapses to one point
    """

    closed: tuple[bool, bool]
    poles: tuple[tuple[int, float], ...]


def face_topology(surface, n: int = 33, rel_tol: float = 1e-10) -> FaceTopology:
    """Seams (`closed_directions`) and poles (a domain side whose points coincide within
    ``rel_tol`` x surface size) of ``surface``."""
    closed = closed_directions(surface)
    u0, u1, v0, v1 = surface.domain
    b = surface.bbox()
    tol = rel_tol * max(float(np.linalg.norm(b[1] - b[0])), 1e-300)
    t = np.linspace(0.0, 1.0, n)
    poles = []
    for axis, val in ((0, u0), (0, u1), (1, v0), (1, v1)):
        if axis == 0:
            p = surface.evaluate(np.full(n, val), v0 + (v1 - v0) * t)
        else:
            p = surface.evaluate(u0 + (u1 - u0) * t, np.full(n, val))
        if float(np.max(np.ptp(p, axis=0))) <= tol:
            poles.append((axis, float(val)))
    return FaceTopology((bool(closed[0]), bool(closed[1])), tuple(poles))


@dataclass
class ResultMapping:
    """Nodal field on the exact CAD: everything the contours and bands need, computed once.

    model        the `Model`
    nodes        (N, 3) result mesh nodes
    values       (N,) the field at the nodes
    field_name   its name; ``source`` how nodal values were obtained (`NodalField.source`)
    face, u, v   (N,) each node's face and parameters (the nearest face)
    distance     (N,) node-to-CAD distance
    element_face (E,) the face each element lies on (all cell blocks in order)
    corner_uv    list per cell block of (E_b, k, 2): element corners' (u, v) on the element's
                 face, seam-unwrapped (seam nodes have one value per side here)
    seam, pole   (N,) bool: node on a seam / at a pole of its element faces
    tri_face     (T,) face of each sub-triangle; tri_uv (T, 3, 2) counter-clockwise in
                 (u, v); tri_f (T, 3) field; tri_key (T, 3) int64 vertex keys (node index,
                 N + element for centres, more for seam cuts) that identify the same point
                 of the mesh across elements, faces and seams; tri_area (T,) exact area
    topology     per face `FaceTopology`
    timings      seconds per stage of the mapping
    arcs         `cadbridge.results.borders.BorderArcs`: mesh border chords on curved trim
                 curves, with the exact arcs the bands and lines follow there
    """

    model: Model
    nodes: np.ndarray
    values: np.ndarray
    field_name: str
    source: str
    face: np.ndarray
    u: np.ndarray
    v: np.ndarray
    distance: np.ndarray
    element_face: np.ndarray
    corner_uv: list[np.ndarray]
    seam: np.ndarray
    pole: np.ndarray
    tri_face: np.ndarray
    tri_uv: np.ndarray
    tri_f: np.ndarray
    tri_key: np.ndarray
    tri_area: np.ndarray
    topology: list[FaceTopology]
    n_keys: int
    timings: dict[str, float] = field(default_factory=dict)
    arcs: object = None  # cadbridge.results.borders.BorderArcs: border chords on curved trims

    def __post_init__(self) -> None:
        if self.arcs is None:
            from cadbridge.results.borders import find_border_arcs

            self.arcs = find_border_arcs(self.model, self.tri_face, self.tri_uv, self.tri_f, self.tri_key)

    @property
    def size(self) -> float:
        return self.model.size()

    @cached_property
    def tri_range(self) -> tuple[np.ndarray, np.ndarray]:
        """(T,) smallest and largest field value of each sub-triangle (levels-independent)."""
        f = self.tri_f
        return (np.minimum(np.minimum(f[:, 0], f[:, 1]), f[:, 2]),
                np.maximum(np.maximum(f[:, 0], f[:, 1]), f[:, 2]))

    def levels(self, levels: int | list[float] = 8, vmin: float | None = None, vmax: float | None = None) -> np.ndarray:
        """Contour levels: ``levels`` equal bands between vmin and vmax (default the data range),
        or the given increasing values. (L,)"""
        from cadbridge.results.contours import make_levels

        return make_levels(self.values, levels, vmin, vmax)

    def face_area(self) -> np.ndarray:
        """Exact area covered by the mapped elements per face, (F,)."""
        return np.bincount(self.tri_face, weights=self.tri_area, minlength=len(self.model.faces))

    def contour(self, levels: int | list[float] = 8, vmin: float | None = None, vmax: float | None = None,
                *, chord_tol: float | None = None):
        """Contour lines and bands at these levels (`cadbridge.results.contours.Contours`);
        the inversion is not repeated."""
        from cadbridge.results.contours import contour

        return contour(self, self.levels(levels, vmin, vmax), chord_tol=chord_tol)


def _snap(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    tol = _SNAP * (hi - lo)
    x = np.where(np.abs(x - lo) <= tol, lo, x)
    return np.where(np.abs(x - hi) <= tol, hi, x)


def _corner_params(mesh: Mesh, model: Model, face: np.ndarray, u: np.ndarray, v: np.ndarray,
                   element_face: np.ndarray) -> list[np.ndarray]:
    """(E_b, k, 2) corner (u, v) on each element's face; foreign corners projected once per
    (node, face) pair onto that face's surface."""
    blocks = [np.asarray(b.data) for b in mesh.cells]
    out = []
    pairs_n, pairs_f = [], []
    off = 0
    for c in blocks:
        ef = element_face[off : off + len(c)]
        uv = np.stack([u[c], v[c]], axis=-1)
        foreign = face[c] != ef[:, None]
        pairs_n.append(c[foreign])
        pairs_f.append(np.broadcast_to(ef[:, None], c.shape)[foreign])
        out.append(uv)
        off += len(c)
    pn = np.concatenate(pairs_n) if pairs_n else np.zeros(0, dtype=np.int64)
    pf = np.concatenate(pairs_f) if pairs_f else np.zeros(0, dtype=np.int64)
    if len(pn):
        codes = pf.astype(np.int64) * len(face) + pn
        uniq, inv = np.unique(codes, return_inverse=True)
        un, uf = uniq % len(face), uniq // len(face)
        uu = np.empty(len(uniq))
        vv = np.empty(len(uniq))
        for f in np.unique(uf):
            sel = np.flatnonzero(uf == f)
            sp = project_to_surface(model.faces[int(f)].surface, mesh.nodes[un[sel]])
            bad = ~(np.isfinite(sp.u) & np.isfinite(sp.v))
            if np.any(bad):
                raise ValueError(f"node {int(un[sel][bad][0])} could not be placed on face {int(f)} (its element's "
                                 f"face): projection failed for {int(bad.sum())} such corners")
            uu[sel], vv[sel] = sp.u, sp.v
        k = 0
        off = 0
        for c, uv in zip(blocks, out):
            ef = element_face[off : off + len(c)]
            foreign = face[c] != ef[:, None]
            m = int(foreign.sum())
            sel = inv[k : k + m]
            uv[foreign] = np.column_stack([uu[sel], vv[sel]])
            k += m
            off += len(c)
    return out


def _unwrap(uv: np.ndarray, ef: np.ndarray, model: Model, topo: list[FaceTopology], pole_mask: np.ndarray) -> None:
    """In place: shift corner parameters of closed directions by whole periods so each element
    is compact (within half a period of its first non-pole corner), and whole elements lying
    beyond a seam back into the domain."""
    for f in np.unique(ef):
        t = topo[f]
        if not any(t.closed):
            continue
        sel = np.flatnonzero(ef == f)
        dom = model.faces[f].surface.domain
        for axis in (0, 1):
            if not t.closed[axis]:
                continue
            lo, hi = dom[2 * axis], dom[2 * axis + 1]
            per = hi - lo
            x = uv[sel, :, axis]
            pm = pole_mask[sel]
            first = np.argmax(~pm, axis=1)
            ref = x[np.arange(len(sel)), first]
            x = x + per * np.round((ref[:, None] - x) / per)
            big = np.where(pm, -np.inf, x).max(axis=1)
            small = np.where(pm, np.inf, x).min(axis=1)
            eps = 1e-12 * per
            x = x - per * (small >= hi - eps)[:, None] + per * (big <= lo + eps)[:, None]
            uv[sel, :, axis] = x


@dataclass
class _SubTriangles:
    """Parameter-space sub-triangles collected in pieces: (T_i, 3, 2) (u, v), (T_i, 3) field,
    (T_i, 3) int64 vertex keys and (T_i,) faces per piece."""

    uv: list = field(default_factory=list)
    f: list = field(default_factory=list)
    key: list = field(default_factory=list)
    face: list = field(default_factory=list)

    def add(self, uv: np.ndarray, f: np.ndarray, key: np.ndarray, face: np.ndarray) -> None:
        self.uv.append(uv)
        self.f.append(f)
        self.key.append(key)
        self.face.append(face)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(T, 3, 2) uv, (T, 3) field, (T, 3) keys, (T,) faces of all pieces in order."""
        return (np.concatenate(self.uv).astype(float), np.concatenate(self.f).astype(float),
                np.concatenate(self.key), np.concatenate(self.face).astype(np.int64))


def _checked_values(mesh: Mesh, values) -> np.ndarray:
    """``values`` as (N,) floats; ValueError unless one finite value per node."""
    vals = np.asarray(values, dtype=float).reshape(-1)
    if len(vals) != mesh.n_nodes:
        raise ValueError(f"{len(vals)} values for {mesh.n_nodes} nodes")
    if not np.all(np.isfinite(vals)):
        raise ValueError(f"values are not finite at nodes {np.flatnonzero(~np.isfinite(vals))[:5].tolist()}")
    return vals


def _snap_and_mark(c: np.ndarray, ef: np.ndarray, uv: np.ndarray, model: Model, topo: list[FaceTopology],
                   seam: np.ndarray, pole: np.ndarray) -> np.ndarray:
    """Corner parameters uv (E, k, 2) of one cell block (c (E, k) nodes, ef (E,) faces) snapped
    onto their face's domain bounds (in place); marks seam and pole nodes in seam, pole (N,).
    Returns the (E, k) bool mask of the corners at a pole."""
    pm = np.zeros(c.shape, dtype=bool)
    for f in np.unique(ef):
        sel = np.flatnonzero(ef == f)
        dom = model.faces[f].surface.domain
        for axis in (0, 1):
            uv[sel, :, axis] = _snap(uv[sel, :, axis], dom[2 * axis], dom[2 * axis + 1])
            if topo[f].closed[axis]:
                x = uv[sel, :, axis]
                on = (x == dom[2 * axis]) | (x == dom[2 * axis + 1])
                seam[c[sel][on]] = True
        for axis, val in topo[f].poles:
            pm[sel] |= uv[sel, :, axis] == val
    pole[c[pm]] = True
    return pm


def _centre_value(fv: np.ndarray) -> np.ndarray:
    """Mean of each row of corner values (E, k), kept within the row's range: an element of
    constant value gets exactly that value at its centre (a rounded mean of 3, 5 or 6 equal
    values can miss it by an ulp, which would tip a plateau at a level off the level)."""
    return np.clip(fv.mean(axis=1), fv.min(axis=1), fv.max(axis=1))


def _regular_triangles(out: _SubTriangles, c: np.ndarray, uv: np.ndarray, fv: np.ndarray, ef: np.ndarray,
                       reg: np.ndarray, eidx: np.ndarray, n: int) -> None:
    """Sub-triangles of the elements ``reg`` (indices into the block) without a pole corner:
    triangles as they are, quadrilaterals split at their centre (key n + element index eidx).
    c (E, k) nodes, uv (E, k, 2), fv (E, k) field, ef (E,) faces, eidx (E,) global indices."""
    if c.shape[1] == 3:
        out.add(uv[reg], fv[reg], c[reg].astype(np.int64), ef[reg])
        return
    cu = uv[reg].mean(axis=1)
    cf = _centre_value(fv[reg])
    ck = n + eidx[reg]
    for k in range(4):
        k1 = (k + 1) % 4
        out.add(np.stack([cu, uv[reg, k], uv[reg, k1]], axis=1), np.column_stack([cf, fv[reg, k], fv[reg, k1]]),
                np.column_stack([ck, c[reg, k], c[reg, k1]]).astype(np.int64), ef[reg])


def _pole_triangles(out: _SubTriangles, e: int, f: int, keys: np.ndarray, uv: np.ndarray, fv: np.ndarray,
                    pm: np.ndarray, topo: list[FaceTopology], n: int) -> None:
    """Sub-triangles of element e (face f) with a pole corner: the corner doubled under its
    neighbours on the pole line, the polygon split at its centre (key n + e). keys (k,) nodes,
    uv (k, 2), fv (k,) field, pm (k,) pole corners."""
    k = len(keys)
    axis = next(a for a, val in topo[f].poles if np.any(uv[pm, a] == val))
    pu, pf, pk = [], [], []
    for i in range(k):
        if pm[i]:
            for j in ((i - 1) % k, (i + 1) % k):
                if pm[j]:
                    continue
                q = uv[i].copy()
                q[1 - axis] = uv[j, 1 - axis]
                if j == (i - 1) % k or not pu or not np.array_equal(pu[-1], q):
                    pu.append(q)
                    pf.append(fv[i])
                    pk.append(keys[i])
        else:
            pu.append(uv[i])
            pf.append(fv[i])
            pk.append(keys[i])
    pu, pf, pk = np.array(pu), np.array(pf), np.array(pk, dtype=np.int64)
    if len(pu) < 3:
        return  # an element with all corners at the pole covers nothing
    if len(pu) == 3:
        out.add(pu[None], pf[None], pk[None], np.array([f]))
        return
    cu, cf = pu.mean(axis=0), float(_centre_value(pf[None])[0])
    for i in range(len(pu)):
        i1 = (i + 1) % len(pu)
        out.add(np.array([[cu, pu[i], pu[i1]]]), np.array([[cf, pf[i], pf[i1]]]),
                np.array([[n + e, pk[i], pk[i1]]], dtype=np.int64), np.array([f]))


def _counter_clockwise(t_uv: np.ndarray, t_f: np.ndarray, t_key: np.ndarray) -> None:
    """In place: vertices 1 and 2 swapped where a triangle (T, 3, 2) runs clockwise in (u, v)."""
    e1 = t_uv[:, 1] - t_uv[:, 0]
    e2 = t_uv[:, 2] - t_uv[:, 0]
    cw = (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]) < 0
    for a in (t_uv, t_f, t_key):
        a[cw, 1], a[cw, 2] = a[cw, 2].copy(), a[cw, 1].copy()


def _exact_areas(model: Model, t_face: np.ndarray, t_uv: np.ndarray, quadrature: int) -> np.ndarray:
    """(T,) exact surface area of each sub-triangle (faces (T,), (u, v) (T, 3, 2)), face by face."""
    area = np.zeros(len(t_face))
    order = np.argsort(t_face, kind="stable")
    cuts = np.flatnonzero(np.diff(t_face[order])) + 1
    for grp in np.split(order, cuts):
        if len(grp):
            area[grp] = surface_area_of_triangles(model.faces[int(t_face[grp[0]])].surface, t_uv[grp], quadrature)
    return area


def map_results(mesh: Mesh, values, model: Model, *, field_name: str = "field", source: str = "point data",
                tolerance: float | None = None, quadrature: int = 4, progress=None) -> ResultMapping:
    """Map nodal ``values`` (N,) on ``mesh`` onto the faces of ``model`` (see the module text).

    tolerance   node-to-CAD distance above which the mesh counts as off the CAD (default
                1e-4 x model size): `cadbridge.normals.cad.ProjectionError` names the
                farthest nodes.
    quadrature  order n of the conical Gauss rule (n^2 points) for the exact areas.

    Example::

        >>> mesh, field = cadbridge.results.fields.read_results("result.vtu", "pressure")  # doctest: +SKIP
        >>> m = cadbridge.map_results(mesh, field.values, cadbridge.read_iges("die.igs"))
        >>> c = m.contour(8)                      # 8 bands: c.lines, c.bands (exact areas)
    """
    from cadbridge.normals.cad import cad_normals

    t0 = time.perf_counter()
    vals = _checked_values(mesh, values)
    if progress is not None:
        progress.stage(f"inverting {mesh.n_nodes} nodes onto {len(model.faces)} faces")
    cn = cad_normals(mesh, model, tolerance=tolerance, orient=True)
    mesh = cn.mesh if cn.mesh is not None else mesh
    timings = {"inversion": time.perf_counter() - t0}
    t1 = time.perf_counter()
    face, u, v = cn.face.astype(np.int64), np.asarray(cn.u, float), np.asarray(cn.v, float)
    element_face = np.concatenate(cn.element_face).astype(np.int64)
    if np.any(element_face < 0):
        bad = np.flatnonzero(element_face < 0)
        raise ValueError(f"{bad.size} elements could not be placed on a face (first: {bad[:5].tolist()})")
    topo = [face_topology(f.surface) for f in model.faces]
    corner_uv = _corner_params(mesh, model, face, u, v, element_face)

    n = mesh.n_nodes
    nodes = np.asarray(mesh.nodes, dtype=float)
    seam = np.zeros(n, dtype=bool)
    pole = np.zeros(n, dtype=bool)
    tris = _SubTriangles()
    special = []  # (element index, face, corner keys, corner uv, corner f, pole mask)
    off = 0
    for blk, uv in zip(mesh.cells, corner_uv):
        c = np.asarray(blk.data)
        ef = element_face[off : off + len(c)]
        pm = _snap_and_mark(c, ef, uv, model, topo, seam, pole)
        _unwrap(uv, ef, model, topo, pm)
        fv = vals[c]
        has_pole = pm.any(axis=1)
        _regular_triangles(tris, c, uv, fv, ef, np.flatnonzero(~has_pole), off + np.arange(len(c)), n)
        for e in np.flatnonzero(has_pole):
            special.append((off + e, int(ef[e]), c[e], uv[e], fv[e], pm[e]))
        off += len(c)
    for e, f, keys, uv, fv, pm in special:
        _pole_triangles(tris, e, f, keys, uv, fv, pm, topo, n)

    t_uv, t_f, t_key, t_face = tris.arrays()
    n_keys = n + len(element_face)
    t_uv, t_f, t_key, t_face, n_keys = _cut_seams(t_uv, t_f, t_key, t_face, model, topo, n_keys)
    _counter_clockwise(t_uv, t_f, t_key)
    timings["sub-triangles"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    if progress is not None:
        progress.stage(f"exact areas of {len(t_face)} parameter triangles")
    area = _exact_areas(model, t_face, t_uv, quadrature)
    timings["areas"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    from cadbridge.results.borders import find_border_arcs

    arcs = find_border_arcs(model, t_face, t_uv, t_f, t_key)
    timings["curved borders"] = time.perf_counter() - t3
    return ResultMapping(arcs=arcs, model=model, nodes=nodes, values=vals, field_name=field_name, source=source, face=face, u=u,
                         v=v, distance=np.asarray(cn.distance, float), element_face=element_face, corner_uv=corner_uv,
                         seam=seam, pole=pole, tri_face=t_face, tri_uv=t_uv, tri_f=t_f, tri_key=t_key, tri_area=area,
                         topology=topo, n_keys=n_keys, timings=timings)


def _clip_side(poly: list, axis: int, c: float, keep_below: bool, cut_keys: dict, n_keys: list) -> list:
    """Sutherland-Hodgman clip of a polygon [(uv, f, key), ...] by the line x_axis = c."""
    out = []
    m = len(poly)
    for i in range(m):
        a, b = poly[i], poly[(i + 1) % m]
        if (a[0][axis] <= c) if keep_below else (a[0][axis] >= c):
            out.append(a)
        if (a[0][axis] - c) * (b[0][axis] - c) < 0:  # strictly across: a vertex on the line stays itself
            p, q = (a, b) if a[2] < b[2] else (b, a)  # canonical order: same cut on both sides
            t = (c - p[0][axis]) / (q[0][axis] - p[0][axis])
            uv = p[0] + t * (q[0] - p[0])
            uv[axis] = c
            cut = cut_keys.get((p[2], q[2]))
            if cut is None:  # the first triangle through this mesh edge fixes its key and value
                cut = cut_keys[(p[2], q[2])] = (n_keys[0], p[1] + t * (q[1] - p[1]))
                n_keys[0] += 1
            out.append((uv, cut[1], cut[0]))
    return out


def _cut_seams(t_uv, t_f, t_key, t_face, model: Model, topo: list[FaceTopology], n_keys: int):
    """Cut sub-triangles that reach beyond a seam at the seam line; the far part moves back by
    one period. New vertices get a key and a field value per cut mesh edge, the same on both
    sides and in every triangle along that edge (each triangle's own (u, v) of the edge,
    unwrapped its way, would round the interpolated value differently: a level through the
    cut must see one value). Both directions in turn (a torus' corner element crosses two
    seams)."""
    cut_keys: dict = {}
    nk = [n_keys]
    for axis in (0, 1):
        extra_uv, extra_f, extra_key, extra_face = [], [], [], []
        drop = np.zeros(len(t_face), dtype=bool)
        for f in np.unique(t_face):
            if not topo[f].closed[axis]:
                continue
            dom = model.faces[f].surface.domain
            sel = np.flatnonzero(t_face == f)
            lo, hi = dom[2 * axis], dom[2 * axis + 1]
            eps = 1e-12 * (hi - lo)
            # vertices on the seam line (element centres too) exactly on it: a cut never
            # passes a hair beside a vertex, which would make a second point of another name
            t_uv[sel, :, axis] = _snap(t_uv[sel, :, axis], lo, hi)
            x = t_uv[sel, :, axis]
            out = sel[(x.max(axis=1) > hi + eps) | (x.min(axis=1) < lo - eps)]
            drop[out] = True
            for ti in out:
                poly = [(t_uv[ti, k].copy(), t_f[ti, k], int(t_key[ti, k])) for k in range(3)]
                if t_uv[ti, :, axis].max() > hi + eps:
                    pieces = [(_clip_side(poly, axis, hi, True, cut_keys, nk), 0.0),
                              (_clip_side(poly, axis, hi, False, cut_keys, nk), -(hi - lo))]
                else:
                    pieces = [(_clip_side(poly, axis, lo, False, cut_keys, nk), 0.0),
                              (_clip_side(poly, axis, lo, True, cut_keys, nk), hi - lo)]
                for pc, shift in pieces:
                    for j in range(1, len(pc) - 1):
                        tri = [pc[0], pc[j], pc[j + 1]]
                        uvs = np.array([p[0] for p in tri])
                        uvs[:, axis] = _snap(uvs[:, axis] + shift, lo, hi)
                        extra_uv.append(uvs)
                        extra_f.append([p[1] for p in tri])
                        extra_key.append([p[2] for p in tri])
                        extra_face.append(f)
        if extra_face:
            keep = ~drop
            t_uv = np.concatenate([t_uv[keep], np.array(extra_uv)])
            t_f = np.concatenate([t_f[keep], np.array(extra_f)])
            t_key = np.concatenate([t_key[keep], np.array(extra_key, dtype=np.int64)])
            t_face = np.concatenate([t_face[keep], np.array(extra_face, dtype=np.int64)])
    return t_uv, t_f, t_key, t_face, nk[0]
