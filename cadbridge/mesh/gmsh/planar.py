"""gmsh on loops given in a face's (u, v): the faces QIT refuses (on QIT's own edge vertices,
conformal shared edges) and the faces the (u, v) fill of `mesh.gmsh.empty_faces` meshes.

A face QIT cannot mesh (narrow faces the hexagonal front does not fill, folds on strongly
curved faces, a zero Jacobian) is meshed by gmsh's Frontal-Delaunay in the face's (u, v)
scaled by its mean |Su| and |Sv| (so that R there is about R on the surface): every edge
vertex QIT made on the face's loops is a gmsh boundary point and every boundary segment one
gmsh line of a single element (transfinite, 2 nodes), so the face's boundary is exactly
QIT's discretisation and its neighbours conform. Interior vertices are S(u, v), exactly on
the surface. Triangles folded against Su x Sv still stop with a named error.
"""

from __future__ import annotations

import numpy as np

from cadbridge.mesh.gmsh.isolated import gmsh_call

__all__ = ["mesh_loops_in_parameter_space", "mesh_planar_loops"]


def mesh_loops_in_parameter_space(loops_uv: list[np.ndarray], scale: np.ndarray, size: float,
                                  label: str) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate the region bounded by ``loops_uv`` (outer loop first, then holes; each
    (n_i, 2) parameters, not closed) in (u, v) * ``scale`` (2,) with gmsh's Frontal-Delaunay
    at element size ``size``, keeping every loop vertex and adding none on the loops.

    Returns uv (N, 2) -- the loop vertices first, in the order given, then the interior
    vertices -- and triangles (T, 3) into it, counter-clockwise in (u, v).
    """
    uv, tris, _ = mesh_planar_loops(loops_uv, scale, size, label)
    return uv, tris


def mesh_planar_loops(loops_uv: list[np.ndarray], scale: np.ndarray, size: float, label: str, *,
                      point_sizes: list[np.ndarray] | None = None,
                      recombine: bool = False,
                      interior_sizes: tuple[np.ndarray, np.ndarray] | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`mesh_loops_in_parameter_space` with sizes per loop vertex (``point_sizes``, one (n_i,)
    array per loop, scaled units; the size then grows from them inside by `GRADING` per unit
    distance up to ``size``, `_graded_field`), at most ``interior_sizes`` inside (points (K, 2)
    in scaled (u, v), sizes (K,): each point's size over its nearest-point cell) and,
    with ``recombine``, gmsh's Blossom recombination into quads (triangles may remain).

    Returns uv (N, 2) as there, triangles (T, 3) and quads (Q, 4), counter-clockwise in (u, v).
    Works inside a caller's gmsh session too (a private model; every option it sets is
    restored on exit).

    The elements must cover the loops' area once (`_covers_once`). gmsh's Blossom
    recombination does not always: on the production die's binder (15 holes, boundary nodes
    from 1 to 70 mm apart) it laid quads over a triangle of three hole nodes, 25 mm^2 of
    overlap, which the winding fix below would have hidden. Such a mesh is made again with
    gmsh's simple recombination (0), then as triangles.
    """
    from cadbridge.mesh.mesh import MeshError

    tries = [(True, 1), (True, 0), (False, 1)] if recombine else [(False, 1)]
    for rec, algorithm in tries:
        uv, tris, quads = _mesh_planar_once(loops_uv, scale, size, label, point_sizes=point_sizes,
                                            recombine=rec, recombination=algorithm, interior_sizes=interior_sizes)
        if _covers_once(loops_uv, scale, uv, tris, quads):
            return uv, tris, quads
    raise MeshError(f"{label}: the gmsh fallback's triangles overlap (their area exceeds the face's in (u, v))")


GRADING = 0.25
"""Growth of the fill's element size per unit distance from the loop vertices: neighbouring
elements differ by about 1.25x. gmsh's own extension of the boundary sizes over the face
(``Mesh.MeshSizeExtendFromBoundary``) keeps a fine boundary's size all across it: the analytic
production die's binder, 1.7 mm boundary segments and a 72 mm size, got 318 196 quads."""


def _graded_field(g, pt_tags: list[int], sizes: np.ndarray, ratio: float = 1.5, sess=None,
                  interior_sizes: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """The background size min_i(h_i + GRADING d_i) over the loop vertices ``pt_tags`` (geo
    points, sizes ``sizes`` (n,)), as gmsh fields: the vertices binned by size (bins ``ratio``
    wide, each at its smallest size h_b), one Distance field d_b per bin, size h_b + GRADING d_b,
    the Min over bins. At most 1.5x finer than the exact minimum, never coarser. With
    ``interior_sizes`` (points (K, 2), sizes (K,)) also the Min with their nearest-point
    field (a list-based view behind a PostView field, as `mesh.generate._background_field`;
    ``sess`` keeps the view for removal)."""
    fld = g.model.mesh.field
    sizes = np.maximum(np.asarray(sizes, dtype=float), 1e-300)
    bins = np.floor(np.log(sizes / sizes.min()) / np.log(ratio)).astype(np.int64)
    terms = []
    for b in np.unique(bins):
        sel = np.flatnonzero(bins == b)
        dist = fld.add("Distance")
        fld.setNumbers(dist, "PointsList", [float(pt_tags[i]) for i in sel])
        term = fld.add("MathEval")
        fld.setString(term, "F", f"{float(sizes[sel].min())!r} + {GRADING!r} * F{dist}")
        terms.append(term)
    if interior_sizes is not None:
        ip, ih = (np.asarray(a, dtype=float) for a in interior_sizes)
        view = g.view.add("cadbridge-fill-sizes")
        if sess is not None:
            sess.views.append(view)
        xyz = np.column_stack([ip.reshape(-1, 2), np.zeros(len(ih))])
        g.view.addListData(view, "SP", len(ih), np.column_stack([xyz, ih.ravel()]).ravel().tolist())
        pv = fld.add("PostView")
        fld.setNumber(pv, "ViewTag", view)
        terms.append(pv)
    low = fld.add("Min")
    fld.setNumbers(low, "FieldsList", [float(t) for t in terms])
    fld.setAsBackgroundMesh(low)


def _covers_once(loops_uv: list[np.ndarray], scale: np.ndarray, uv: np.ndarray, tris: np.ndarray,
                 quads: np.ndarray) -> bool:
    """True if the elements' areas (their absolute values, scaled (u, v)) add up to the area
    inside the loops (outer minus holes) within 1e-9 relative: no element lies over another."""
    def area(p: np.ndarray) -> np.ndarray:  # (E, k, 2) -> (E,) shoelace
        return 0.5 * np.sum(p[..., 0] * np.roll(p[..., 1], -1, axis=-1) - np.roll(p[..., 0], -1, axis=-1) * p[..., 1],
                            axis=-1)

    scale = np.asarray(scale, dtype=float)
    a = [abs(float(area(np.asarray(lp, dtype=float)[None] * scale)[0])) for lp in loops_uv]
    inside = a[0] - sum(a[1:])
    q = uv * scale
    covered = sum(float(np.abs(area(q[e])).sum()) for e in (tris, quads) if len(e))
    return abs(covered - inside) <= 1e-9 * max(abs(inside), 1e-300)


def _mesh_planar_once(loops_uv: list[np.ndarray], scale: np.ndarray, size: float, label: str, *,
                      point_sizes: list[np.ndarray] | None, recombine: bool,
                      recombination: int, interior_sizes=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One gmsh run of `mesh_planar_loops` with ``Mesh.RecombinationAlgorithm`` ``recombination``."""
    from cadbridge.mesh.gmsh.session import GmshSession
    from cadbridge.mesh.mesh import MeshError

    scale = np.asarray(scale, dtype=float)
    n_loop = sum(len(lp) for lp in loops_uv)
    with GmshSession() as sess:
        g = sess.gmsh
        geo = g.model.geo
        pt_tags, line_tags, loops = [], [], []
        for li, lp in enumerate(loops_uv):
            q = np.asarray(lp, dtype=float) * scale
            hs = np.full(len(q), float(size)) if point_sizes is None else np.asarray(point_sizes[li], dtype=float)
            pts = [geo.addPoint(float(a), float(b), 0.0, float(h)) for (a, b), h in zip(q, hs)]
            lines = [geo.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
            loops.append(geo.addCurveLoop(lines))
            pt_tags += pts
            line_tags += lines
        surf = geo.addPlaneSurface(loops)
        geo.synchronize()
        for ln in line_tags:
            g.model.mesh.setTransfiniteCurve(ln, 2)  # the loop segments stay single elements
        sess.set("Mesh.Algorithm", 6)
        sess.set("Mesh.MeshSizeMin", size if point_sizes is None else 0.0)
        sess.set("Mesh.MeshSizeMax", size)
        sess.set("Mesh.MeshSizeFromCurvature", 0)
        sess.set("Mesh.MeshSizeExtendFromBoundary", 1 if point_sizes is None else 0)
        if point_sizes is not None:
            _graded_field(g, pt_tags, np.concatenate([np.asarray(h, dtype=float) for h in point_sizes]), sess=sess,
                          interior_sizes=interior_sizes)
        # a caller's session may have set these (all-quad subdivision, no point sizes)
        sess.set("Mesh.MeshSizeFromPoints", 1)
        sess.set("Mesh.SubdivisionAlgorithm", 0)
        sess.set("Mesh.RecombineAll", 1 if recombine else 0)
        sess.set("Mesh.RecombinationAlgorithm", recombination)
        sess.set("Mesh.ElementOrder", 1)
        try:
            with gmsh_call(surfaces=False):
                g.model.mesh.generate(2)
        except Exception as exc:  # gmsh raises a plain Exception
            raise MeshError(f"{label}: the gmsh fallback could not mesh the face ({exc})") from exc
        tags, xyz, _ = g.model.mesh.getNodes()
        xyz = np.asarray(xyz).reshape(-1, 3)
        index = {int(t): k for k, t in enumerate(tags)}
        loop_node = [int(g.model.mesh.getNodes(0, p)[0][0]) for p in pt_tags]
        et, _, en = g.model.mesh.getElements(2, surf)
        tri_nodes = [np.asarray(n, dtype=np.int64).reshape(-1, 3) for t, n in zip(et, en) if t == 2]
        quad_nodes = [np.asarray(n, dtype=np.int64).reshape(-1, 4) for t, n in zip(et, en) if t == 3]
        if not tri_nodes and not quad_nodes:
            raise MeshError(f"{label}: the gmsh fallback made no triangles (its edge loops in (u, v) "
                            "cross or enclose no area)")
    order = {t: k for k, t in enumerate(loop_node)}  # gmsh node tag -> local id
    interior = [int(t) for t in tags if int(t) not in order]
    for k, t in enumerate(interior):
        order[t] = n_loop + k
    uv = np.concatenate([np.concatenate(loops_uv), xyz[[index[t] for t in interior], :2] / scale])
    out = []
    for blocks, k in ((tri_nodes, 3), (quad_nodes, 4)):
        if not blocks:
            out.append(np.zeros((0, k), dtype=np.int64))
            continue
        el = np.vectorize(order.__getitem__)(np.concatenate(blocks)).reshape(-1, k)
        p = uv[el]  # (E, k, 2): shoelace area, clockwise ones reversed
        area = np.sum(p[:, :, 0] * np.roll(p[:, :, 1], -1, axis=1) - np.roll(p[:, :, 0], -1, axis=1) * p[:, :, 1],
                      axis=1)
        el[area < 0] = el[area < 0][:, ::-1]
        out.append(el)
    return uv, out[0], out[1]
