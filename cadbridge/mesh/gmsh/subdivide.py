"""gmsh's all-quad subdivision of a model's mesh, with the new nodes placed here.

gmsh's ``Mesh.SubdivisionAlgorithm`` 1 makes every element second order on the geometry
(``SetOrderN``) and then splits each triangle into 3 quads and each quad into 4 (the original
nodes stay where they are). For the second-order nodes of a surface it asks OCC for the
nearest point of the surface to each edge's midpoint, one OCC projector made per node
(``GFace::closestPoint``); on the production die that took 6.7 s of the subdivision's 7.3 s,
more than the 2D mesh itself (6.1 s).

Here the same split is made from gmsh's first-order mesh and every new node goes where gmsh
puts it: a curve's midpoint at equal arc length from both ends (`_curve_midpoints`), a
surface edge's midpoint and an element's centre at the surface's point nearest the edge's
midpoint, the quad's serendipity centre or the triangle's 6-node barycentre, found by
Gauss-Newton from the interpolated parameters (`_nearest`), with one batched gmsh
evaluation per entity and step. Where that does not settle near its target (a pole, a seam
the interpolation straddled, a parametrisation that turns back), OCC's search gives the
node (``gmsh.model.getClosestPoint``), as in gmsh. Curve nodes are shared by the surfaces
along the curve and every node keeps its parameters, so the model's mesh is what gmsh's
subdivision leaves, to the accuracy of the searches (gmsh's refold of a folded face did not
end on boundary nodes 0.014-0.36 mm off gmsh's; these are within 1e-6 mm).
"""

from __future__ import annotations

import numpy as np

__all__ = ["subdivide_to_quads", "GN_ITERATIONS", "FAR_FRACTION"]

GN_ITERATIONS = 4
"""Gauss-Newton steps towards the nearest point at most, from the interpolated parameters (the
node is S(u, v) whatever the steps: they centre it between its neighbours)."""
FAR_FRACTION = 0.25
"""A new node farther than this x its edge length (element diameter for a centre) from its
straight-sided position is found by OCC's search instead: the nearest point of a smooth
surface to an edge's midpoint lies within the edge's sagitta, L^2 / (8 R) (0.18 L for an edge
turning 90 degrees)."""
_TRI_EDGES = ((0, 1), (1, 2), (2, 0))
_QUAD_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0))


def subdivide_to_quads(g) -> bool:
    """Split every element of the current gmsh model into quads in place (triangle -> 3, quad
    -> 4, curve segment -> 2), the new nodes on the geometry (see module docs). Returns False,
    leaving the model as it was, when an entity's nodes come without parametric coordinates
    (the caller then uses gmsh's own ``refine``)."""
    tags, xyz, _ = g.model.mesh.getNodes()
    tags = np.asarray(tags, dtype=np.int64)
    if not len(tags):
        return True
    x = np.zeros((int(tags.max()) + 1, 3))
    x[tags] = np.asarray(xyz, dtype=float).reshape(-1, 3)
    diag = float(np.linalg.norm(np.ptp(x[tags], axis=0)))
    floor = 1e-12 * diag
    lower = np.zeros(len(x), dtype=bool)  # nodes on points, then also on curves
    lower[np.asarray(g.model.mesh.getNodes(0, -1)[0], dtype=np.int64)] = True
    curves = _entities(g, 1, lower.copy(), x)
    lower[np.asarray(g.model.mesh.getNodes(1, -1)[0], dtype=np.int64)] = True
    surfaces = _entities(g, 2, lower, x)
    if curves is None or surfaces is None:
        return False
    next_tag = int(g.model.mesh.getMaxNodeTag()) + 1
    # room for every new node: one per curve segment, surface edge and element at most
    room = sum(len(v[2]) for v in curves.values()) + sum(6 * len(b) for v in surfaces.values() for b in v[2])
    x = np.concatenate([x, np.zeros((max(next_tag - len(x), 0) + room, 3))])
    curve_key, curve_mid = [], []  # the curves' segments: key a * K + b (a < b), midpoint node tag
    key_base = int(tags.max()) + 1
    plan_c, plan_s = [], []
    for c, (own, own_par, lines, par_of) in curves.items():
        a, b = lines[:, 0], lines[:, 1]
        lo, hi = (np.asarray(v, dtype=float) for v in g.model.getParametrizationBounds(1, c))
        ta, tb = par_of(a), par_of(b)
        # a segment across the seam of a closed curve: its far end's parameter a period on
        closed = np.array([bool(np.any(np.abs(tb - ta) > 0.5 * (hi - lo))) and _closed(g, 1, c, lo, hi, diag)[0]])
        tb = _unwrap_to(ta, tb, hi - lo, closed)
        limit = np.maximum(FAR_FRACTION * np.linalg.norm(x[b] - x[a], axis=1), floor)
        px, pt = _curve_midpoints(g, c, x[a], x[b], ta[:, 0], tb[:, 0], limit, lo, hi, closed)
        m = np.arange(next_tag, next_tag + len(lines))
        next_tag += len(lines)
        x[m] = px
        curve_key.append(np.minimum(a, b) * key_base + np.maximum(a, b))
        curve_mid.append(m)
        # the curve's nodes in the order of their parameter, as gmsh keeps them (its meshers
        # walk a curve's nodes so: unsorted, its Frontal-Delaunay remesh of a face along such
        # curves did not end, PRO20359-L6)
        nt, par = np.concatenate([own, m]), np.concatenate([own_par, pt])
        o = np.argsort(par[:, 0], kind="stable")
        plan_c.append((c, nt[o], par[o], np.column_stack([a, m, m, b]).reshape(-1, 2)))
    ck = np.concatenate(curve_key) if curve_key else np.zeros(0, dtype=np.int64)
    o = np.argsort(ck, kind="stable")
    ck, cm = ck[o], (np.concatenate(curve_mid) if curve_mid else np.zeros(0, dtype=np.int64))[o]
    for s, (own, own_par, elems, uv_of) in surfaces.items():
        lo, hi = (np.asarray(v, dtype=float) for v in g.model.getParametrizationBounds(2, s))
        closed = _closed(g, 2, s, lo, hi, diag)
        period = hi - lo
        # the edges not on a curve: their midpoints are new nodes of the surface
        edges = np.concatenate([e[:, list(p)] for e in elems for p in (_TRI_EDGES if e.shape[1] == 3 else _QUAD_EDGES)])
        key = np.minimum(edges[:, 0], edges[:, 1]) * key_base + np.maximum(edges[:, 0], edges[:, 1])
        ukey, first, inv = np.unique(key, return_index=True, return_inverse=True)
        pos = np.minimum(np.searchsorted(ck, ukey), max(len(ck) - 1, 0))
        on_curve = ck[pos] == ukey if len(ck) else np.zeros(len(ukey), dtype=bool)
        e = edges[first[~on_curve]]
        uva = uv_of(e[:, 0])
        limit = np.maximum(FAR_FRACTION * np.linalg.norm(x[e[:, 1]] - x[e[:, 0]], axis=1), floor)
        uvb = _unwrap_to(uva, uv_of(e[:, 1]), period, closed)
        px, puv = _nearest(g, 2, s, 0.5 * (x[e[:, 0]] + x[e[:, 1]]), 0.5 * (uva + uvb), limit, lo, hi, closed)
        new = [np.arange(next_tag, next_tag + len(e))]
        next_tag += len(e)
        x[new[0]] = px
        umid = np.where(on_curve, cm[pos] if len(ck) else 0, 0)
        umid[~on_curve] = new[0]
        edge_mid = umid[inv.ravel()]  # per row of ``edges``
        new_uv = [puv]
        # the centres, as gmsh's second-order elements have them: the surface's point nearest
        # a triangle's barycentre (its corners and edge midpoints), or a quad's serendipity
        # centre (-1/4 of the corners + 1/2 of the edge midpoints), from the corners' mean (u, v)
        mids_of, starts, targets, limits = [], [], [], []
        row = 0
        for el in elems:  # triangles, then quads
            n = el.shape[1]
            mids = edge_mid[row:row + n * len(el)].reshape(n, len(el)).T  # (E, n): the midpoint of edge i -> i + 1
            row += n * len(el)
            mids_of.append(mids)
            uv0 = uv_of(el[:, 0])
            starts.append(np.mean([uv0] + [_unwrap_to(uv0, uv_of(el[:, i]), period, closed) for i in range(1, n)], axis=0))
            corners = x[el].mean(axis=1)
            # gmsh's: a 6-node triangle's barycenter (all 6 nodes), a 9-node quad's serendipity
            # centre
            targets.append(0.5 * (corners + x[mids].mean(axis=1)) if n == 3 else 2.0 * x[mids].mean(axis=1) - corners)
            limits.append(2.0 * FAR_FRACTION * np.max(np.linalg.norm(x[el] - corners[:, None], axis=2), axis=1))
        px, puv = _nearest(g, 2, s, np.concatenate(targets), np.concatenate(starts),
                           np.maximum(np.concatenate(limits), floor), lo, hi, closed)
        centres = np.arange(next_tag, next_tag + len(px))
        next_tag += len(px)
        x[centres] = px
        new.append(centres)
        new_uv.append(puv)
        quads, k = [], 0
        for el, mids in zip(elems, mids_of):
            n = el.shape[1]
            ctr = centres[k:k + len(el)]
            k += len(el)
            # corner i, midpoint of edge i -> i + 1, centre, midpoint of edge i - 1 -> i: the
            # element's winding
            quads.append(np.stack([np.column_stack([el[:, i], mids[:, i], ctr, mids[:, (i - 1) % n]])
                                   for i in range(n)], axis=1).reshape(-1, 4))
        plan_s.append((s, np.concatenate([own] + new), np.concatenate([own_par] + new_uv), np.concatenate(quads)))
    g.model.mesh.clear([(2, s) for s in surfaces])  # a curve's mesh can only go after its surfaces'
    g.model.mesh.clear([(1, c) for c in curves])
    plan_p = []  # the points' nodes go with the rest: the file's elements may only name its own nodes
    for _, p in g.model.getEntities(0):
        nt = np.asarray(g.model.mesh.getNodes(0, p)[0], dtype=np.int64)
        if len(nt):
            plan_p.append((p, nt, np.zeros((len(nt), 0)), nt[:, None]))
    g.model.mesh.clear([(0, p) for p, *_ in plan_p])
    _merge_mesh(g, plan_p, plan_c, plan_s, x)
    return True


def _merge_mesh(g, plan_p: list, plan_c: list, plan_s: list, x: np.ndarray) -> None:
    """Add the points', curves' and surfaces' nodes (with their parameters) and elements of the plans
    [(tag, node tags (N,), parameters (N, dim), elements (E, 2 | 4))] to the gmsh model, as one
    MSH 4.1 file merged into it (its entity blocks name the model's entities). The API's
    ``addElementsByType`` rebuilds gmsh's node cache on every call: 35 s for the production
    die's 7 000 curves and surfaces, against well under one here."""
    import os
    import tempfile

    blocks = [(dim, t, nt, par, el) for dim, plan in ((0, plan_p), (1, plan_c), (2, plan_s)) for t, nt, par, el in plan]
    all_nodes = np.concatenate([b[2] for b in blocks]) if blocks else np.zeros(0, dtype=np.int64)
    n_el = sum(len(b[4]) for b in blocks)
    first_el = int(g.model.mesh.getMaxElementTag()) + 1
    # MSH 4.1 binary: size_t counts and tags, int entity headers, doubles
    out = [b"$MeshFormat\n4.1 1 8\n", np.array([1], dtype=np.int32).tobytes(), b"\n$EndMeshFormat\n$Nodes\n",
           np.array([len(blocks), len(all_nodes), all_nodes.min() if len(all_nodes) else 0,
                     all_nodes.max() if len(all_nodes) else 0], dtype=np.uint64).tobytes()]
    for dim, t, nt, par, _ in blocks:
        out += [np.array([dim, t, int(dim > 0)], dtype=np.int32).tobytes(), np.array([len(nt)], dtype=np.uint64).tobytes(),
                np.asarray(nt, dtype=np.uint64).tobytes(),
                np.ascontiguousarray(np.column_stack([x[nt], par.reshape(len(nt), dim)]), dtype=np.float64).tobytes()]
    out += [b"\n$EndNodes\n$Elements\n", np.array([len(blocks), n_el, first_el, first_el + n_el - 1], dtype=np.uint64).tobytes()]
    tag = first_el
    for dim, t, _, _, el in blocks:
        out += [np.array([dim, t, (15, 1, 3)[dim]], dtype=np.int32).tobytes(), np.array([len(el)], dtype=np.uint64).tobytes(),
                np.ascontiguousarray(np.column_stack([np.arange(tag, tag + len(el)), el]), dtype=np.uint64).tobytes()]
        tag += len(el)
    out.append(b"\n$EndElements\n")
    fd, path = tempfile.mkstemp(suffix=".msh", prefix="cadbridge-subdivided-")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(b"".join(out))
        g.merge(path)
    finally:
        os.unlink(path)


def _entities(g, dim: int, lower: np.ndarray, x: np.ndarray) -> dict | None:
    """{tag: (own node tags (N,), their parameters (N, dim), elements, params_of(tags) -> (K, dim))}
    of the meshed entities of dimension ``dim`` (elements: (L, 2) segments for curves, a list
    of (E, 3) triangles and (E, 4) quads for surfaces); ``lower`` (T,) bool by node tag: the
    node lies on an entity of lower dimension; ``x`` (T, 3) the nodes' coordinates by tag.
    None if an entity's nodes come without parametric coordinates. A node on the entity's boundary takes gmsh's
    reparametrisation on it, one only touching it (on an embedded curve) gmsh's inversion."""
    out = {}
    for _, t in g.model.getEntities(dim):
        types, _, enodes = g.model.mesh.getElements(dim, t)
        blocks = []
        for et, en in zip(types, enodes):
            k = {1: 2, 2: 3, 3: 4}.get(int(et))
            if k is None or (dim == 1) != (k == 2):
                return None  # an element type this split does not make
            if len(en):
                blocks.append(np.asarray(en, dtype=np.int64).reshape(-1, k))
        if not blocks:
            continue
        blocks.sort(key=lambda b: b.shape[1])  # triangles first, as gmsh lists them
        allt, _, allp = g.model.mesh.getNodes(dim, t, includeBoundary=True, returnParametricCoord=True)
        allt, allp = np.asarray(allt, dtype=np.int64), np.asarray(allp, dtype=float)
        if allp.size != dim * len(allt):
            return None
        order = np.argsort(allt, kind="stable")
        st, sp = allt[order], allp.reshape(-1, dim)[order]
        used = np.unique(np.concatenate([b.ravel() for b in blocks]))
        pos = np.minimum(np.searchsorted(st, used), max(len(st) - 1, 0))
        missing = used[st[pos] != used] if len(st) else used
        if len(missing):
            mp = np.asarray(g.model.getParametrization(dim, t, x[missing].ravel().tolist()), dtype=float)
            o2 = np.argsort(np.concatenate([st, missing]), kind="stable")
            st, sp = np.concatenate([st, missing])[o2], np.concatenate([sp, mp.reshape(-1, dim)])[o2]
        own = ~lower[st]

        def params_of(q: np.ndarray, st=st, sp=sp) -> np.ndarray:
            return sp[np.searchsorted(st, q)]

        out[t] = (st[own], sp[own], blocks[0] if dim == 1 else blocks, params_of)
    return out


def _closed(g, dim: int, tag: int, lo: np.ndarray, hi: np.ndarray, diag: float) -> np.ndarray:
    """(dim,) bool: the two ends of each parameter range [lo, hi] map onto each other (within
    1e-9 x the model's diagonal ``diag``, at 5 points across for a surface)."""
    if dim == 1:
        p = np.array([[lo[0]], [hi[0]]])
    else:
        s = np.linspace(0.0, 1.0, 5)
        p = np.zeros((4, 5, 2))  # u = lo, u = hi, v = lo, v = hi
        p[0, :, 0], p[1, :, 0], p[2, :, 1], p[3, :, 1] = lo[0], hi[0], lo[1], hi[1]
        p[:2, :, 1] = lo[1] + (hi[1] - lo[1]) * s
        p[2:, :, 0] = lo[0] + (hi[0] - lo[0]) * s
    e = np.asarray(g.model.getValue(dim, tag, np.ascontiguousarray(p.ravel())), dtype=float).reshape(2 * dim, -1, 3)
    return np.max(np.linalg.norm(e[0::2] - e[1::2], axis=2), axis=1) <= 1e-9 * diag


def _unwrap_to(ref: np.ndarray, p: np.ndarray, period: np.ndarray, closed: np.ndarray) -> np.ndarray:
    """Parameters ``p`` (K, d) moved by whole periods to within half a period of ``ref`` (K, d)
    in the closed directions."""
    out = np.array(p, dtype=float, copy=True)
    for d in np.flatnonzero(closed):
        out[:, d] -= period[d] * np.round((out[:, d] - ref[:, d]) / period[d])
    return out


def _into(par: np.ndarray, lo: np.ndarray, hi: np.ndarray, closed: np.ndarray) -> np.ndarray:
    """Parameters wrapped into [lo, hi] in the closed directions, clamped in the others."""
    out = np.clip(par, lo, hi)
    for d in np.flatnonzero(closed):
        out[:, d] = lo[d] + np.mod(par[:, d] - lo[d], hi[d] - lo[d])
    return out


_GAUSS = np.polynomial.legendre.leggauss(10)
"""10-point Gauss-Legendre nodes and weights on [-1, 1] (arc lengths in `_curve_midpoints`)."""


def _curve_midpoints(g, c: int, xa: np.ndarray, xb: np.ndarray, ta: np.ndarray, tb: np.ndarray,
                     limit: np.ndarray, lo: np.ndarray, hi: np.ndarray, closed: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Midpoints (K, 3) and their parameters (K, 1) of curve ``c``'s segments from xa to xb
    (K, 3) at parameters ta, tb (K,): the point at equal arc length from both ends, as gmsh
    places it (Newton on L(ta, t) - L(t, tb), lengths by 10-point Gauss quadrature of |C'|, one
    batched gmsh call a step). A point that only halves the chord's projection (one step
    cheaper) moved the boundary nodes of PRO20359-L6's face by up to 0.014 mm from gmsh's,
    and gmsh's Frontal-Delaunay remesh of that face then did not end. OCC's search for the
    point nearest the chord's midpoint where Newton did not settle and the point lies farther
    than ``limit`` (K,) from it."""
    xi, w = _GAUSS
    par = 0.5 * (ta + tb)
    tol = 1e-12 * max(float(hi[0] - lo[0]), 1e-300)
    step = np.full(len(par), np.inf)
    for _ in range(2 * GN_ITERATIONS):
        # |C'| at the quadrature points of [ta, t] and [t, tb], and at t
        h1, h2 = 0.5 * (par - ta), 0.5 * (tb - par)
        q = np.concatenate([(ta + h1)[:, None] + h1[:, None] * xi, (par + h2)[:, None] + h2[:, None] * xi,
                            par[:, None]], axis=1)  # (K, 2 n + 1)
        d = np.asarray(g.model.getDerivative(1, c, np.ascontiguousarray(_into(q.reshape(-1, 1), lo, hi, closed).ravel())),
                       dtype=float).reshape(len(par), q.shape[1], 3)
        speed = np.linalg.norm(d, axis=2)
        n = len(w)
        f = h1 * (speed[:, :n] @ w) - h2 * (speed[:, n:2 * n] @ w)  # L(ta, t) - L(t, tb)
        fp = 2.0 * speed[:, -1]
        step = np.where(fp > 0, -f / np.where(fp > 0, fp, 1.0), np.inf)
        par = np.clip(par + np.where(np.isfinite(step), step, 0.0), np.minimum(ta, tb), np.maximum(ta, tb))
        if not np.any(~(np.abs(step) <= tol)):
            break  # every step below 1e-12 of the parameter range
    par = _into(par[:, None], lo, hi, closed)
    p = np.asarray(g.model.getValue(1, c, np.ascontiguousarray(par.ravel())), dtype=float).reshape(-1, 3)
    # OCC's search where Newton did not settle or ended far off the chord (a long segment
    # turning more than 120 degrees ends beyond a quarter of its chord legitimately: only
    # an unsettled one is searched again)
    bad = ~(np.abs(step) <= tol) & ~(np.linalg.norm(p - 0.5 * (xa + xb), axis=1) <= limit)
    bad |= ~np.all(np.isfinite(p), axis=1)
    if np.any(bad):
        cp, cpar = _nearest(g, 1, c, 0.5 * (xa + xb)[bad], par[bad], np.zeros(int(bad.sum())), lo, hi, closed,
                            iterations=0)
        p[bad], par[bad] = cp, cpar
    return p, par


def _nearest(g, dim: int, tag: int, target: np.ndarray, start: np.ndarray, limit: np.ndarray,
             lo: np.ndarray, hi: np.ndarray, closed: np.ndarray, *, iterations: int = GN_ITERATIONS
             ) -> tuple[np.ndarray, np.ndarray]:
    """Nearest points (K, 3) and their parameters (K, dim) of entity (dim, tag) to ``target``
    (K, 3): Gauss-Newton from ``start`` (K, dim), ``iterations`` steps at most; OCC's search
    where the point found is not finite or lies farther than ``limit`` (K,) from the target."""
    k = len(target)
    if k == 0:
        return np.zeros((0, 3)), np.zeros((0, dim))
    par = _into(np.asarray(start, dtype=float).reshape(k, dim), lo, hi, closed)
    for _ in range(iterations):
        p = np.asarray(g.model.getValue(dim, tag, np.ascontiguousarray(par.ravel())), dtype=float).reshape(k, 3)
        d = np.asarray(g.model.getDerivative(dim, tag, np.ascontiguousarray(par.ravel())), dtype=float).reshape(k, dim, 3)
        r = target - p
        if dim == 1:
            den = np.einsum("ij,ij->i", d[:, 0], d[:, 0])
            step = np.where(den > 0, np.einsum("ij,ij->i", r, d[:, 0]) / np.where(den > 0, den, 1.0), 0.0)[:, None]
        else:
            a11 = np.einsum("ij,ij->i", d[:, 0], d[:, 0])
            a12 = np.einsum("ij,ij->i", d[:, 0], d[:, 1])
            a22 = np.einsum("ij,ij->i", d[:, 1], d[:, 1])
            b1 = np.einsum("ij,ij->i", r, d[:, 0])
            b2 = np.einsum("ij,ij->i", r, d[:, 1])
            det = a11 * a22 - a12 * a12
            ok = det > 1e-12 * a11 * a22
            det = np.where(ok, det, 1.0)
            step = np.where(ok[:, None], np.column_stack([(a22 * b1 - a12 * b2) / det, (a11 * b2 - a12 * b1) / det]), 0.0)
        par = _into(par + step, lo, hi, closed)
        if not np.any(np.abs(step) > 1e-9 * np.maximum(hi - lo, 1e-300)):
            break  # every step below 1e-9 of the parameter range: centred
    p = np.asarray(g.model.getValue(dim, tag, np.ascontiguousarray(par.ravel())), dtype=float).reshape(k, 3)
    bad = np.flatnonzero(~(np.linalg.norm(p - target, axis=1) <= limit) | ~np.all(np.isfinite(par), axis=1))
    if len(bad):
        cx, cp = g.model.getClosestPoint(dim, tag, target[bad].ravel().tolist())
        p[bad] = np.asarray(cx, dtype=float).reshape(-1, 3)
        par[bad] = np.asarray(cp, dtype=float).reshape(-1, dim)
    return p, par
