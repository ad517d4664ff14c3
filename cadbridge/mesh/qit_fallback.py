"""gmsh for the faces QIT refuses, on QIT's own edge vertices (conformal shared edges).

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

__all__ = ["mesh_loops_in_parameter_space"]


def mesh_loops_in_parameter_space(loops_uv: list[np.ndarray], scale: np.ndarray, size: float,
                                  label: str) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate the region bounded by ``loops_uv`` (outer loop first, then holes; each
    (n_i, 2) parameters, not closed) in (u, v) * ``scale`` (2,) with gmsh's Frontal-Delaunay
    at element size ``size``, keeping every loop vertex and adding none on the loops.

    Returns uv (N, 2) -- the loop vertices first, in the order given, then the interior
    vertices -- and triangles (T, 3) into it, counter-clockwise in (u, v).
    """
    from cadbridge.mesh.generate import GmshSession
    from cadbridge.mesh.mesh import MeshError

    scale = np.asarray(scale, dtype=float)
    n_loop = sum(len(lp) for lp in loops_uv)
    with GmshSession() as sess:
        g = sess.gmsh
        geo = g.model.geo
        pt_tags, line_tags, loops = [], [], []
        for lp in loops_uv:
            q = np.asarray(lp, dtype=float) * scale
            pts = [geo.addPoint(float(a), float(b), 0.0, float(size)) for a, b in q]
            lines = [geo.addLine(pts[i], pts[(i + 1) % len(pts)]) for i in range(len(pts))]
            loops.append(geo.addCurveLoop(lines))
            pt_tags += pts
            line_tags += lines
        surf = geo.addPlaneSurface(loops)
        geo.synchronize()
        for ln in line_tags:
            g.model.mesh.setTransfiniteCurve(ln, 2)  # the loop segments stay single elements
        sess.set("Mesh.Algorithm", 6)
        sess.set("Mesh.MeshSizeMin", size)
        sess.set("Mesh.MeshSizeMax", size)
        sess.set("Mesh.MeshSizeFromCurvature", 0)
        sess.set("Mesh.MeshSizeExtendFromBoundary", 1)
        try:
            g.model.mesh.generate(2)
        except Exception as exc:  # gmsh raises a plain Exception
            raise MeshError(f"{label}: the gmsh fallback could not mesh the face ({exc})") from exc
        tags, xyz, _ = g.model.mesh.getNodes()
        xyz = np.asarray(xyz).reshape(-1, 3)
        index = {int(t): k for k, t in enumerate(tags)}
        loop_node = [int(g.model.mesh.getNodes(0, p)[0][0]) for p in pt_tags]
        et, _, en = g.model.mesh.getElements(2, surf)
        blocks = [np.asarray(n, dtype=np.int64).reshape(-1, 3) for t, n in zip(et, en) if t == 2]
        if not blocks:
            raise MeshError(f"{label}: the gmsh fallback made no triangles (its edge loops in (u, v) "
                            "cross or enclose no area)")
        tri_nodes = np.concatenate(blocks)
    order = {t: k for k, t in enumerate(loop_node)}  # gmsh node tag -> local id
    interior = [int(t) for t in tags if int(t) not in order]
    for k, t in enumerate(interior):
        order[t] = n_loop + k
    tris = np.vectorize(order.__getitem__)(tri_nodes)
    uv = np.concatenate([np.concatenate(loops_uv), xyz[[index[t] for t in interior], :2] / scale])
    a, b, c = uv[tris[:, 0]], uv[tris[:, 1]], uv[tris[:, 2]]
    neg = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) < 0
    tris[neg] = tris[neg][:, [0, 2, 1]]
    return uv, tris
