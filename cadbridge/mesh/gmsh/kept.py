"""Mesh again only where finer sizes are asked: the rest of a gmsh mesh kept as it was.

A refinement round (`cadbridge.tool.guard_refinement`) asks for finer elements about a few
marked elements. Meshing the whole model again costs as much as the first mesh (gmsh's
curvature sizing on B-spline faces is most of it: 15 s of trj8_b1's 415 faces) and, with a
graded field, makes elements finer far from the marks too (a round for 2 elements of trj8_b1
doubled its nodes, 35 732 -> 67 639). Here the first mesh is kept wherever the round asks for
nothing finer:

1. `snapshot` takes gmsh's mesh of every point, curve and surface (nodes with their
   parameters, elements) after the first mesh, with a signature of the geometry (entity tags
   and surface boxes), before the caller's own clean-ups (node merge, (u, v) collection).
2. `restore`, in the session of a later round on the same geometry (same signature), before
   meshing: a curve is *re-meshed* where ``finer(points)`` is true at one of its first mesh's
   nodes; a surface where it is true at one of its nodes, or where one of its curves (boundary
   or embedded) is re-meshed; every other point, curve and surface gets its first mesh back
   and is hidden from gmsh's meshing (``Mesh.MeshOnlyVisible``), so gmsh meshes only the
   re-meshed entities, on the kept curves' nodes where they meet kept surfaces: the mesh
   stays conforming.

Triangles only (`cadbridge.mesh.generate.mesh_cad` calls `restore` for them): a quad mesh is
probed and, where recombination leaves triangles, made again whole at twice the size and
subdivided, which a kept part cannot follow.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from cadbridge.mesh.gmsh.isolated import gmsh_call

__all__ = ["restore", "snapshot"]


def _signature(g, heal: bool) -> tuple:
    """The geometry a mesh belongs to: the entity tags of each dimension and each surface's
    box (to 1e-9 of the model's), and whether gmsh's OCC healing ran on import."""
    ents = tuple(tuple(t for _, t in g.model.getEntities(d)) for d in range(3))
    box = np.array(g.model.getBoundingBox(-1, -1), dtype=float)
    q = 1e-9 * max(float(np.linalg.norm(box[3:] - box[:3])), 1e-300)
    boxes = tuple(tuple(np.round(np.array(g.model.getBoundingBox(2, s)) / q).astype(np.int64).tolist())
                  for s in ents[2])
    return heal, ents, boxes


def snapshot(g, *, heal: bool, subdivided: bool) -> dict:
    """gmsh's current mesh, entity by entity (module docs, step 1): {"signature",
    "subdivided", "entities": {(dim, tag): (node tags (n,), xyz (n, 3), parameters (n * dim,),
    element types, element tags, element node tags)}}; nodes without the entity's boundary."""
    entities = {}
    for dim, tag in g.model.getEntities():
        if dim > 2:
            continue
        ntags, xyz, par = g.model.mesh.getNodes(dim, tag, includeBoundary=False, returnParametricCoord=True)
        etypes, etags, enodes = g.model.mesh.getElements(dim, tag)
        entities[(dim, tag)] = (np.asarray(ntags, dtype=np.int64), np.asarray(xyz, dtype=float).reshape(-1, 3),
                                np.asarray(par, dtype=float), list(etypes),
                                [np.asarray(t, dtype=np.int64) for t in etags],
                                [np.asarray(n, dtype=np.int64) for n in enodes])
    return {"signature": _signature(g, heal), "subdivided": subdivided, "entities": entities}


def _touched(g, snap: dict, finer: Callable[[np.ndarray], np.ndarray]) -> tuple[set[int], set[int]]:
    """(curves, surfaces) to mesh again (module docs, step 2)."""
    ents = snap["entities"]
    tags = np.concatenate([e[0] for e in ents.values()])
    xyz = np.concatenate([e[1] for e in ents.values()])
    order = np.argsort(tags)
    tags, xyz = tags[order], xyz[order]
    asks = np.asarray(finer(xyz), dtype=bool)  # one call over every node

    def asked(dim: int, tag: int) -> bool:
        nodes = np.unique(np.concatenate([ents[(dim, tag)][0]] + ents[(dim, tag)][5]))
        i = np.searchsorted(tags, nodes)
        return bool(len(nodes)) and bool(asks[i].any())

    curves = {t for (d, t) in ents if d == 1 and asked(1, t)}
    surfaces = set()
    for (d, s) in ents:
        if d != 2:
            continue
        _, down = g.model.getAdjacencies(2, s)
        own = {int(c) for c in down} | {int(t) for dd, t in g.model.mesh.getEmbedded(2, s) if dd == 1}
        if own & curves or asked(2, s):
            surfaces.add(s)
    return curves, surfaces


def restore(g, snap: dict, finer: Callable[[np.ndarray], np.ndarray], *, heal: bool) -> tuple[int, int] | None:
    """Give the entities of the current gmsh model that ``finer`` leaves alone their mesh of
    ``snap`` (module docs, step 2): (surfaces to mesh again, surfaces kept), or None (nothing
    restored: the whole model is meshed) where the geometry differs from the snapshot's, the
    snapshot was subdivided, or every surface is to be meshed again. ``finer(xyz (N, 3)) ->
    (N,) bool``: where the round asks for elements finer than the first mesh's."""
    if snap["subdivided"] or snap["signature"] != _signature(g, heal):
        return None
    curves, surfaces = _touched(g, snap, finer)
    n_surfaces = sum(1 for d, _ in snap["entities"] if d == 2)
    if len(surfaces) == n_surfaces:
        return None
    # gmsh's generate(1) clears every surface's mesh, and generate(2) starts again from the 1D
    # mesh unless every curve it sees was meshed by gmsh itself (its status, not its elements,
    # counts): the kept points and curves first, the other curves meshed (``Mesh.MeshOnlyEmpty``:
    # only those; ``Mesh.Renumber`` off, so the kept nodes keep their tags), then the kept
    # surfaces, their own nodes under new tags above every tag in use; every kept curve and
    # surface is hidden for the rest of the session (``Mesh.MeshOnlyVisible``): gmsh meshes
    # and counts only the others
    _add(g, snap, lambda d, t: d == 0 or (d == 1 and t not in curves))
    hidden = [k for k in snap["entities"] if (k[0] == 1 and k[1] not in curves) or (k[0] == 2 and k[1] not in surfaces)]
    g.model.setVisibility(hidden, 0)
    g.option.setNumber("Mesh.MeshOnlyVisible", 1)
    renumber = g.option.getNumber("Mesh.Renumber")
    g.option.setNumber("Mesh.Renumber", 0)
    try:
        with gmsh_call(surfaces=False):
            g.model.mesh.generate(1)
    finally:
        g.option.setNumber("Mesh.Renumber", renumber)
    own = [(tag, e) for (d, tag), e in snap["entities"].items() if d == 2 and tag not in surfaces]
    old_tags = np.concatenate([e[0] for _, e in own])
    new_tags = int(g.model.mesh.getMaxNodeTag()) + 1 + np.arange(len(old_tags), dtype=np.int64)
    order = np.argsort(old_tags)
    old_sorted, new_sorted = old_tags[order], new_tags[order]

    def moved(n: np.ndarray) -> np.ndarray:  # a kept surface's own nodes to their new tags, the rest as they are
        if not len(old_sorted):
            return n
        i = np.minimum(np.searchsorted(old_sorted, n), len(old_sorted) - 1)
        return np.where(old_sorted[i] == n, new_sorted[i], n)

    start = 0
    for tag, (ntags, xyz, par, etypes, _, enodes) in own:
        if len(ntags):
            g.model.mesh.addNodes(2, tag, new_tags[start:start + len(ntags)].tolist(), xyz.ravel().tolist(), par.tolist())
        start += len(ntags)
        g.model.mesh.addElements(2, tag, etypes, [[] for _ in etypes], [moved(n).tolist() for n in enodes])
    return len(surfaces), n_surfaces - len(surfaces)


def _add(g, snap: dict, chosen: Callable[[int, int], bool]) -> None:
    """Add the nodes (under their own tags), then the elements (under new ones), of the
    snapshot's points and curves ``chosen`` (dim, tag)."""
    for dim in (0, 1):  # nodes before the elements that use them
        for (d, tag), (ntags, xyz, par, etypes, etags, enodes) in snap["entities"].items():
            if d != dim or not chosen(d, tag):
                continue
            if len(ntags):
                g.model.mesh.addNodes(d, tag, ntags.tolist(), xyz.ravel().tolist(), par.tolist())
            if etypes:
                g.model.mesh.addElements(d, tag, etypes, [[] for _ in etypes], [n.tolist() for n in enodes])
