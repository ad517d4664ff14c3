"""Faces gmsh leaves without elements, meshed in their own (u, v) on gmsh's boundary nodes.

gmsh gives up on a surface whose 1D mesh it cannot recover in parameter space ("No elements
in surface ..."). On the Inventor spring of the OCC corpus the cause is a *cusp*: a trim
curve leaves a face corner tangent to the neighbouring boundary curve and runs along it
within the file's tolerance (the grind planes touch the wire's half-tubes along their seam
lines for 45 mm at 0.004-0.017 mm), so in (u, v) the two boundary curves cross each other
(OCC's pcurves are ~7e-4 off) and no constrained triangulation exists.

For each such face this module:

1. gathers the face's loops from gmsh's own 1D mesh (every node shared with the neighbours,
   so the mesh stays conformal), with (u, v) from each curve's pcurve on the face
   (``reparametrizeOnSurface``);
2. *zips* cusps: from a loop corner, the two boundary chains are walked side by side while
   each next node lies within ``eps`` (3D) of the other chain, ``eps`` = 4 x the largest
   distance between a boundary node and the surface at its (u, v) (the file's own
   curve-to-surface disagreement), or, where the strip is the face's own material (a spike,
   not a notch of its outside), at least 1/8 of the element size; that strip has no width
   within the CAD's accuracy and is cut off the loop (left open: a crack of width <= eps,
   reported in the notes), since triangles across it would have random windings (a notch cut
   off would be meshed over, outside the face);
3. checks that the remaining loops are simple in (u, v) (else a `MeshError` naming the face);
4. triangulates them with gmsh's Frontal-Delaunay in (u, v) scaled by the mean |S_u|, |S_v|
   (`cadbridge.mesh.gmsh.planar.mesh_loops_in_parameter_space`), boundary nodes fixed,
   element size from the boundary spacing inside and at most the face's curvature size
   (``curvature_elements`` per full turn of the largest principal curvature, as gmsh's
   ``Mesh.MeshSizeFromCurvature``); interior nodes are S(u, v), exactly on the surface;
5. for quads, Blossom-recombines that triangulation; after gmsh's all-quad subdivision
   (``subdivided=True``, every curve's 1D mesh split in two) it meshes on the coarse nodes
   (every other node of each curve) and splits each element into quads itself (triangle ->
   3, quad -> 4, boundary midpoints = gmsh's fine nodes), so the face is all quads;
6. winds the elements like the neighbouring gmsh elements (a shared edge is traversed in
   opposite directions), or like gmsh's face normal where no neighbour is meshed, and adds
   nodes (with their (u, v)) and elements to the gmsh model, so the caller collects them
   with the rest.
"""

from __future__ import annotations

import math

import numpy as np

from cadbridge.mesh.gmsh.isolated import gmsh_call
from cadbridge.mesh.mesh import MeshError

__all__ = ["fill_empty_faces", "generate_surfaces", "EPS_FACTOR"]

EPS_FACTOR = 4.0
"""Cusp strips narrower than this x the face's curve-to-surface disagreement are cut off..."""
STRIP_FRACTION = 0.125
"""... or narrower than this x the face's element size: triangles across a narrower strip are
slivers whose centroid lies as near the neighbouring face as their own (at 0.04 mm on the
spring, with nodes 0.01 mm off the surface, one took the plane's normals: 90 degrees off)."""


def _has_elements(g, s: int) -> bool:
    return any(len(t) for t in g.model.mesh.getElements(2, s)[1])


def generate_surfaces(g, surfaces: list[int], skip: dict[int, str] | None = None) -> dict[int, str]:
    """``gmsh.model.mesh.generate(2)`` that does not stop at the first surface gmsh cannot mesh.

    By default (``General.AbortOnError`` 2) gmsh throws on the first error, e.g. "Impossible
    to mesh periodic surface 963" (its periodic mesher, used for every surface periodic in u or
    v, could not recover the face's boundary edges in (u, v); `Mesh.MaxRetries` is 0), and every
    surface after it stays unmeshed. Here gmsh logs the error and goes on; the surfaces it failed
    on are left without elements (gmsh's generators return before creating any; a surface an
    error names is cleared in case) and `fill_empty_faces` meshes them on gmsh's boundary nodes.
    Returns {surface: gmsh's error messages} for the failed surfaces: those an error names, and,
    when an error names no surface (e.g. "The 1D mesh seems not to be forming a closed loop"),
    those left without elements. Raises gmsh's ``Exception`` (as a throwing ``generate`` would)
    for an error naming no surface when every surface has elements: an error this fallback
    cannot locate. ``skip`` {surface: why}: surfaces not given to gmsh (hidden, as
    ``Mesh.MeshOnlyVisible`` hides them), returned as failed with that reason: those gmsh
    stalled or crashed on in an earlier attempt (`cadbridge.mesh.gmsh.isolated`)."""
    import re

    skip = skip or {}
    hidden = [(2, s) for s in surfaces if s in skip and g.model.getVisibility(2, s)]
    prev = g.option.getNumber("General.AbortOnError")
    prev_visible = g.option.getNumber("Mesh.MeshOnlyVisible")
    g.option.setNumber("General.AbortOnError", 0)
    if hidden:
        g.model.setVisibility(hidden, 0)
        g.option.setNumber("Mesh.MeshOnlyVisible", 1)
    g.logger.start()
    try:
        with gmsh_call():
            g.model.mesh.generate(2)
        log = g.logger.get()
    finally:
        g.logger.stop()
        g.option.setNumber("General.AbortOnError", prev)
        if hidden:
            g.model.setVisibility(hidden, 1)
            g.option.setNumber("Mesh.MeshOnlyVisible", prev_visible)
    skipped = {s: skip[s] for s in surfaces if s in skip and not _has_elements(g, s)}
    errors = [m for m in log if m.startswith("Error")]
    if not errors:
        return skipped
    known = set(surfaces)
    named: dict[int, list[str]] = {}
    for m in errors:
        for t in re.findall(r"surface (\d+)", m):
            if int(t) in known:
                named.setdefault(int(t), []).append(m)
    unnamed = [m for m in errors if not re.search(r"surface \d+", m)]
    empty = [s for s in surfaces if s not in named and s not in skipped and not _has_elements(g, s)] if unnamed else []
    if unnamed and not empty:
        raise Exception(unnamed[-1].removeprefix("Error").lstrip(": "))
    failed = {s: "; ".join(named[s]) for s in named}
    failed.update({s: "; ".join(unnamed) for s in empty})
    for s in named:
        if _has_elements(g, s):
            g.model.mesh.clear([(2, s)])  # a surface an error names starts again from its boundary
    return {s: m.replace("Error: ", "") for s, m in failed.items()} | skipped


def fill_empty_faces(g, surfaces: list[int], *, size: float, curvature_elements: int, element: str,
                     subdivided: bool, label: str, cuts: dict | None = None,
                     failed: dict[int, str] | None = None, merge_tolerance: float = 0.0,
                     size_at=None) -> list[str]:
    """Mesh every surface of ``surfaces`` that has no 2D elements in the current gmsh model
    (see module docs); ``size`` the largest element size (model units), ``element`` "tri" or
    "quad", ``subdivided`` when the model's mesh went through gmsh's all-quad subdivision;
    ``cuts`` {surface: trim-loop excursions} whose boundary nodes are left out of the loop
    (`cadbridge.mesh.gmsh.loop_cuts`); ``failed`` {surface: gmsh's error} from `generate_surfaces`;
    ``merge_tolerance`` the distance below which the caller merges nodes afterwards (a failed
    face smaller than it gets a fan that the merge collapses: `_fill_tiny_face`);
    ``size_at(xyz (N, 3)) -> (N,)`` the caller's target sizes (model units), followed inside
    the face too (`_interior_sizes`). Returns one note per face filled. Raises `MeshError` naming a face it cannot mesh; for a
    face gmsh failed on, the message says "gmsh failed" (so `mesh_cad` retries with OCC's
    shape healing)."""
    notes = []
    failed = failed or {}
    for s in surfaces:
        if _has_elements(g, s):
            continue
        if s in failed:
            tiny = _fill_tiny_face(g, s, merge_tolerance)
            if tiny:
                notes.append(tiny.replace("mesh: ", f"mesh: gmsh failed ({failed[s]}) on ", 1))
                continue
        try:
            # a face gmsh failed on is not a cusp face: only strips within the file's own
            # curve-to-surface disagreement are cut (not h / 8: its acute corners are geometry)
            note = _fill_face(g, s, size=size, curvature_elements=curvature_elements, element=element,
                              subdivided=subdivided, label=label, cut=(cuts or {}).get(s),
                              strip_fraction=0.0 if s in failed else STRIP_FRACTION, size_at=size_at)
        except MeshError as exc:
            if s in failed:
                raise MeshError(f"{label}: gmsh failed: {failed[s]}; meshing {_label(g, s)} in its (u, v) "
                                f"did not work either: {exc}") from exc
            raise
        if s in failed:
            note = note.replace("gmsh left", f"gmsh failed ({failed[s]}) and left", 1)
        notes.append(note)
    return notes


class _Loop:
    """One boundary loop of a face: node tags (n,), xyz (n, 3), uv (n, 2), and for each node
    its index along its curve (0 at the curve's first node, so corners are 0) and whether
    its curve has an even number of segments (for the coarse nodes after subdivision)."""

    def __init__(self) -> None:
        self.tags: list[int] = []
        self.xyz: list[np.ndarray] = []
        self.uv: list[np.ndarray] = []
        self.k: list[int] = []
        self.even: list[bool] = []

    def arrays(self):
        return (np.asarray(self.tags, dtype=np.int64), np.concatenate(self.xyz).reshape(-1, 3),
                np.concatenate(self.uv).reshape(-1, 2), np.asarray(self.k), np.asarray(self.even))


def _face_loops(g, s: int) -> list[tuple]:
    """The loops of surface ``s`` from gmsh's 1D mesh, each as (tags, xyz, uv, k, even) arrays
    (`_Loop`), nodes in loop order, not closed."""
    oriented = [t for d, t in g.model.getBoundary([(2, s)], combined=False, oriented=True, recursive=False)
                if d == 1]
    count: dict[int, int] = {}
    for ct in oriented:
        count[abs(ct)] = count.get(abs(ct), 0) + 1
    loops, cur, first_tag = [], None, None
    prev_uv = None
    for i, ct in enumerate(oriented):  # loop over the (few) boundary curves of the face
        c = abs(ct)
        ends = [t for _, t in g.model.getBoundary([(1, c)], combined=False, oriented=False)]
        p0, p1 = (ends[0], ends[-1]) if ends else (None, None)
        lo, hi = (float(a[0]) for a in g.model.getParametrizationBounds(1, c))
        nt, nx, npar = g.model.mesh.getNodes(1, c, includeBoundary=False, returnParametricCoord=True)
        nt, nx, npar = np.asarray(nt, dtype=np.int64), np.asarray(nx, dtype=float).reshape(-1, 3), np.asarray(npar)
        o = np.argsort(npar)
        tags, xyz, t = list(nt[o]), list(nx[o]), list(npar[o])
        if p0 is None:
            raise MeshError(f"{_label(g, s)}: curve {c} has no end points")
        for p, at in ((p0, 0), (p1, len(tags) + 1)):
            vt, vx, _ = g.model.mesh.getNodes(0, p)
            if len(vt) == 0:
                raise MeshError(f"{_label(g, s)}: curve {c} end point {p} has no mesh node")
            tags.insert(at, int(vt[0]))
            xyz.insert(at, np.asarray(vx, dtype=float)[:3])
        t = [lo] + t + [hi]
        uv = _pcurve(g, c, t, s, 0, ct < 0)
        if count[c] > 1:
            # a seam (the curve twice in the loop): the pcurve that continues the previous
            # curve, or where a loop starts on the seam, the one the next curve continues
            # (gmsh surface 546 of the production die, a ring whose loop starts on its seam:
            # pcurve 0 at u = 0 where the next curve starts at u = 2 pi, so the loop ended a
            # period away)
            uv1 = _pcurve(g, c, t, s, 1, ct < 0)
            if prev_uv is not None:
                if np.linalg.norm(uv1[0] - prev_uv) < np.linalg.norm(uv[0] - prev_uv):
                    uv = uv1
            elif i + 1 < len(oriented) and count[abs(oriented[i + 1])] == 1:
                nxt = oriented[i + 1]
                lo_n, hi_n = (float(a[0]) for a in g.model.getParametrizationBounds(1, abs(nxt)))
                start = _pcurve(g, abs(nxt), [lo_n, hi_n], s, 0, nxt < 0)[0]
                if np.linalg.norm(uv1[-1] - start) < np.linalg.norm(uv[-1] - start):
                    uv = uv1
        if ct < 0:
            tags, xyz = tags[::-1], xyz[::-1]
        n = len(tags) - 1  # segments of this curve
        # a degenerate curve (a pole or apex: one vertex at both ends, no node between) is one
        # segment of zero length in 3D that no subdivision splits: even for the quad split
        even = n % 2 == 0 or (p0 == p1 and len(nt) == 0)
        if cur is None:
            cur, first_tag = _Loop(), tags[0]
        for j in range(n):  # all but the last node (the next curve starts there)
            cur.tags.append(tags[j])
            cur.xyz.append(xyz[j])
            cur.uv.append(uv[j])
            cur.k.append(j)
            cur.even.append(even)
        prev_uv = uv[-1]
        # the loop closed: back at its first node, and in (u, v) too (a closed curve around a
        # periodic face, e.g. a cylinder's circle before its seam, ends where it began in 3D
        # but one period away in (u, v))
        span = float(np.ptp(np.concatenate(cur.uv).reshape(-1, 2), axis=0).max()) if len(cur.uv) > 1 else 0.0
        if tags[-1] == first_tag and np.linalg.norm(uv[-1] - cur.uv[0]) <= 1e-2 * max(span, 1e-300):
            loops.append(cur.arrays())
            cur, prev_uv = None, None
    if cur is not None:
        raise MeshError(f"{_label(g, s)}: its boundary curves do not close into loops")
    return loops


def _fill_tiny_face(g, s: int, tol: float) -> str | None:
    """Fill a face smaller than the node-merge tolerance ``tol`` (its 3D box diagonal below it)
    with a fan of triangles on its boundary nodes, and return a note; None for a larger face.

    OCC's fragment with a crease curve can leave such slivers (the analytic die's gmsh surface
    1131: 1.3e-4 x 7e-7 mm between the crease and a binder edge, its vertex tolerance larger
    than the face, so its two curves do not close in (u, v) and gmsh's periodic mesher fails).
    All its nodes lie within ``tol`` of each other, so `cadbridge.mesh.cleanup.merge_close_nodes`
    joins them into one and drops these triangles: the face leaves no element and no crack."""
    bb = np.asarray(g.model.getBoundingBox(2, s), dtype=float)
    if not float(np.linalg.norm(bb[3:] - bb[:3])) < tol:
        return None
    tags: list[int] = []
    for _, ct in g.model.getBoundary([(2, s)], combined=False, oriented=True, recursive=False):
        nt = g.model.mesh.getNodes(1, abs(ct), includeBoundary=True)[0]  # the curve's nodes, ends included
        tags.extend(int(t) for t in nt if int(t) not in tags)
    if len(tags) < 3:
        return None
    fan = np.array([[tags[0], tags[i], tags[i + 1]] for i in range(1, len(tags) - 1)], dtype=np.int64)
    g.model.mesh.addElementsByType(s, 2, [], fan.ravel().tolist())
    return (f"mesh: {_label(g, s)}, a sliver {float(np.linalg.norm(bb[3:] - bb[:3])):.2g} across (below the "
            f"node-merge tolerance {tol:.2g}); its {len(tags)} boundary nodes merge into one, it leaves no elements")


def _pcurve(g, c: int, t: list[float], s: int, which: int, backwards: bool) -> np.ndarray:
    """(u, v) on surface s of curve c at parameters t (its pcurve ``which`` of a seam),
    (len(t), 2), reversed when the loop runs the curve backwards."""
    uv = np.asarray(g.model.reparametrizeOnSurface(1, c, t, s, which), dtype=float).reshape(-1, 2)
    return uv[::-1] if backwards else uv


def _label(g, s: int) -> str:
    return f"gmsh surface {s} ({g.model.getType(2, s)})"


def _point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from p (3,) to the segments a-b (M, 3) -> (M,)."""
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300), 0.0, 1.0)
    return np.linalg.norm(a + t[:, None] * ab - p, axis=1)


def _zip_walk(xyz: np.ndarray, seg: np.ndarray, keep: np.ndarray, p: int, eps: float,
              tags: np.ndarray | None) -> tuple[int, int, float, float, float]:
    """Walk the two chains of a loop from corner ``p`` side by side while each next node lies
    within ``eps`` of the other chain (`_zip_cusps`): (a, b, sa, sb, w), the last node zipped
    forward (chain A) and backward (chain B), the arc length walked on each and the largest
    distance of a zipped node from the other chain (the strip's width)."""
    n = len(xyz)

    def gap(node: int, end: int, step: int) -> float:
        """Distance of ``node`` from the other chain's segments near the rung (that chain's
        nodes from ``end`` on, in direction ``step``); inf where it is one of those mesh nodes."""
        other = [(end + step * j) % n for j in range(0 if end == p else -1, 4)]
        if tags is not None and tags[node] in tags[other]:
            return np.inf
        return float(_point_segment_distance(xyz[node], xyz[other[:-1]], xyz[other[1:]]).min())

    a, b = p, p
    sa = sb = w = 0.0
    steps = 0
    while steps < n - 4:  # at least 3 nodes stay out of the strip
        na, nb = (a + 1) % n, (b - 1) % n
        if not (keep[na] and keep[nb]):
            break  # another strip's nodes
        # advance the chain that is behind in arc length; its next node must lie within
        # eps of the other chain's segments near the current rung
        if sa + seg[a] <= sb + seg[nb]:
            d = gap(na, b, -1)
            if d > eps:
                break
            sa += seg[a]
            a = na
        else:
            d = gap(nb, a, 1)
            if d > eps:
                break
            sb += seg[nb]
            b = nb
        w = max(w, d)
        steps += 1
    return a, b, sa, sb, w


def _zip_cusps(xyz: np.ndarray, corner: np.ndarray, eps: float,
               tags: np.ndarray | None = None, *, strip_eps: float = 0.0, uv: np.ndarray | None = None,
               material_left: bool = True) -> tuple[np.ndarray, list[tuple[int, float]]]:
    """Cut the zero-width strips off one loop (module docs, step 2).

    xyz (n, 3) loop nodes, corner (n,) bool (curve end points), tags (n,) their mesh node tags.
    Every strip narrower than ``eps`` (the CAD's accuracy) is cut; one up to ``strip_eps`` wide
    only where it is the face's own material (a spike), judged in (u, v) (``uv`` (n, 2), the
    face's material on the left of the loop if ``material_left``): the cut-off polygon (the
    strip's nodes closed by the new edge) winds as the loop's material does, or crosses itself
    (its sides run together). A notch (the face's outside running into it: a simple cut-off
    polygon wound the other way) is cut only within ``eps``: cut wider, the fill covers the
    notch, outside the face (trj10_b2-oc-214's plane: a 48 degree notch cut 1.4 mm deep at
    ``strip_eps`` = 1.3, a node 0.087 off every face). Without ``uv`` every strip up to
    max(eps, strip_eps) is cut.
    Returns the kept node indices in loop order and, per strip, (cusp node index, strip length
    along the loop). A chain never zips onto the same mesh nodes: a seam the loop runs down and
    back up (a cone's, from its apex) is no strip but the face's closure, a period apart in
    (u, v)."""
    n = len(xyz)
    keep = np.ones(n, dtype=bool)
    strips = []
    seg = np.linalg.norm(np.roll(xyz, -1, axis=0) - xyz, axis=1)  # seg[i]: node i -> i + 1
    wide = max(eps, strip_eps)
    for p in np.flatnonzero(corner):  # loop over the (few) corners
        if not keep[p]:
            continue
        a, b, sa, sb, w = _zip_walk(xyz, seg, keep, p, wide, tags)
        if w > eps and uv is not None and a != p and b != p:
            cut = np.array([(b + j) % n for j in range((a - b) % n + 1)])  # b .. p .. a
            # a notch (a simple cut-off polygon wound against the material): the CAD's accuracy
            # only; a strip whose sides cross in (u, v) runs together and is cut (a lens face)
            if (_signed_area(uv[cut]) > 0) != material_left and not _segments_cross([uv[cut]]):
                a, b, sa, sb, _ = _zip_walk(xyz, seg, keep, p, eps, tags)
        if a != p and b != p:
            # nodes strictly between b and a (through p) leave the loop: b -> a becomes an edge
            j = (b + 1) % n
            while j != a:
                keep[j] = False
                j = (j + 1) % n
            strips.append((int(p), max(sa, sb)))
    return np.flatnonzero(keep), strips


def _signed_area(uv: np.ndarray) -> float:
    """Signed area (shoelace) of a closed polygon uv (n, 2), positive counter-clockwise."""
    return 0.5 * float(np.sum(uv[:, 0] * np.roll(uv[:, 1], -1) - np.roll(uv[:, 0], -1) * uv[:, 1]))


def _joined_at_touching_corners(loops: list[tuple], tol: float) -> tuple[list[tuple], list[np.ndarray]]:
    """Loops whose corners coincide joined into one loop through that point: (loops, the
    points (3,) where two were joined).

    A hole that touches the outer loop (or another hole) at a vertex makes a pinched face:
    the crescent between two internally tangent circles (ec_turbine's planar face 2, whose
    hole and outer loop each have their own vertex at the same point). Meshed as two loops,
    the straight segments on either side of the touching point cut across each other (the
    two curves run together there), and the face's boundary "crosses itself". Joined, the
    touching point becomes two corners of one loop, outer .. P, around the hole from P back
    to P, P .. outer, and `_zip_cusps` cuts the strips narrower than the CAD's accuracy on
    either side of it, as at any cusp. ``loops`` as `_face_loops` gives them; two corners
    (index 0 along their curve) within ``tol`` (model units) touch. A hole is joined only
    where it runs against the loop it joins (opposite signed (u, v) area for the outer loop,
    the same for another hole), so the joined loop bounds the same region."""
    loops = list(loops)
    where = []
    outer = int(np.argmax([abs(_signed_area(lp[2])) for lp in loops])) if loops else 0
    joined = True
    while joined and len(loops) > 1:
        joined = False
        for i in range(len(loops)):
            for j in range(len(loops)):
                if i == j or j == outer:
                    continue
                ci, cj = np.flatnonzero(loops[i][3] == 0), np.flatnonzero(loops[j][3] == 0)
                if not len(ci) or not len(cj):
                    continue
                d = np.linalg.norm(loops[i][1][ci][:, None, :] - loops[j][1][cj][None, :, :], axis=2)
                a, b = np.unravel_index(int(np.argmin(d)), d.shape)
                if d[a, b] > tol:
                    continue
                si, sj = _signed_area(loops[i][2]), _signed_area(loops[j][2])
                if (si * sj < 0) != (i == outer):
                    continue  # wound so that the joined loop would cover the hole
                a, b = int(ci[a]), int(cj[b])
                merged = tuple(np.concatenate([x[:a], y[b:], y[:b], x[a:]]) for x, y in zip(loops[i], loops[j]))
                where.append(loops[i][1][a])
                keep = [lp for k, lp in enumerate(loops) if k not in (i, j)]
                loops = [merged] + keep
                outer = 0 if i == outer else outer - (outer > i) - (outer > j) + 1
                joined = True
                break
            if joined:
                break
    return loops, where


def _segments_cross(uv_loops: list[np.ndarray]) -> bool:
    """True if two non-adjacent segments of the loops (closed polygons in (u, v)) intersect."""
    from scipy.spatial import cKDTree

    a = np.concatenate([lp for lp in uv_loops])
    b = np.concatenate([np.roll(lp, -1, axis=0) for lp in uv_loops])
    start = np.concatenate([np.full(len(lp), i) for i, lp in enumerate(uv_loops)])
    idx = np.concatenate([np.arange(len(lp)) for lp in uv_loops])
    size = np.concatenate([np.full(len(lp), len(lp)) for lp in uv_loops])
    mid = 0.5 * (a + b)
    half = 0.5 * np.linalg.norm(b - a, axis=1)
    pairs = cKDTree(mid).query_pairs(2.0 * float(half.max()) + 1e-300, output_type="ndarray")
    if len(pairs) == 0:
        return False
    i, j = pairs[:, 0], pairs[:, 1]
    same = start[i] == start[j]
    adj = same & (((idx[i] - idx[j]) % size[i] == 1) | ((idx[j] - idx[i]) % size[i] == 1))
    i, j = i[~adj], j[~adj]

    def orient(p, q, r):
        return (q[:, 0] - p[:, 0]) * (r[:, 1] - p[:, 1]) - (q[:, 1] - p[:, 1]) * (r[:, 0] - p[:, 0])

    d1, d2 = orient(a[i], b[i], a[j]), orient(a[i], b[i], b[j])
    d3, d4 = orient(a[j], b[j], a[i]), orient(a[j], b[j], b[i])
    return bool(np.any((d1 * d2 < 0) & (d3 * d4 < 0)))


def _face_size(g, s: int, uv_box: np.ndarray, size: float, curvature_elements: int) -> tuple[float, np.ndarray]:
    """(element size, scale (2,)): the size from the largest principal curvature over a grid
    of the face's (u, v) box (as gmsh's MeshSizeFromCurvature, at least size / 20), and the
    mean |S_u|, |S_v| there."""
    gu = np.linspace(uv_box[0, 0], uv_box[1, 0], 9)
    gv = np.linspace(uv_box[0, 1], uv_box[1, 1], 33)
    uv = np.stack(np.meshgrid(gu, gv, indexing="ij"), axis=-1).reshape(-1, 2)
    d = np.asarray(g.model.getDerivative(2, s, uv.ravel().tolist()), dtype=float).reshape(-1, 2, 3)
    scale = np.linalg.norm(d, axis=2).mean(axis=0)
    if not np.all(scale > 0):
        raise MeshError(f"{_label(g, s)}: zero parametric derivative over the face")
    h = size
    if curvature_elements:
        k1, k2, *_ = g.model.getPrincipalCurvatures(s, uv.ravel().tolist())
        kmax = float(np.nanmax(np.abs(np.concatenate([np.asarray(k1, float), np.asarray(k2, float)]))))
        if kmax > 0 and math.isfinite(kmax):
            h = min(size, max(size / 20.0, 2.0 * math.pi / (curvature_elements * kmax)))
    return h, scale


INTERIOR_SAMPLES = 129
"""Most samples per side of the (u, v) grid on which a filled face reads the caller's sizes."""


def _interior_sizes(g, s: int, box: np.ndarray, scale: np.ndarray, h: float, size_at, factor: float):
    """(scaled (u, v) (K, 2), sizes (K,)) of the caller's size field on a grid over the face's
    (u, v) box ``box`` (2, 2): S(u, v) on the grid, ``factor`` x ``size_at`` there, each point
    the smallest size of its 3 x 3 neighbourhood (the mesher takes the nearest point's size,
    and the field may fall between grid points). Spacing at most the smallest size read on a
    first 17 x 17 grid, at most `INTERIOR_SAMPLES` per side; None where no size is below ``h``.

    Without it a filled face grows from its boundary spacing up to the largest size: the
    production die's pilot walls, filled after folding with every gmsh algorithm, came back
    at 22x the error law of their radius in the adaptive loop."""
    def grid(nu: int, nv: int):
        gu = np.linspace(box[0, 0], box[1, 0], nu)
        gv = np.linspace(box[0, 1], box[1, 1], nv)
        uv = np.stack(np.meshgrid(gu, gv, indexing="ij"), axis=-1).reshape(-1, 2)
        x = np.asarray(g.model.getValue(2, s, uv.ravel().tolist()), dtype=float).reshape(-1, 3)
        return uv, factor * np.asarray(size_at(x), dtype=float).reshape(nu, nv)

    _, first = grid(17, 17)
    lo = float(first.min())
    if not lo < h:
        return None
    ext = (box[1] - box[0]) * scale
    nu, nv = (int(np.clip(math.ceil(e / lo) + 1, 17, INTERIOR_SAMPLES)) for e in ext)
    from scipy.ndimage import minimum_filter

    uv, hs = grid(nu, nv)
    return uv * scale, np.minimum(minimum_filter(hs, size=3, mode="nearest").ravel(), h)


def _kept_loops(loops: list[tuple], *, coarse: bool, eps: float, strip_eps: float, cut: list | None,
                notches: bool, what: str) -> tuple[list[tuple], list[str], int]:
    """The loop nodes a face is meshed on: (kept loops (tags, xyz, uv, sel), one note per cusp
    strip cut, the number of boundary nodes left to trim-loop excursions ``cut``). All loop
    nodes, or after the quad subdivision (``coarse``) every other node per curve, without the
    cusp strips (`_zip_cusps`: narrower than ``eps``, or than ``strip_eps`` where they are the
    face's material, or with ``notches`` False wherever they are) and the excursions' nodes.
    ``loops`` as `_face_loops` gives them."""
    from cadbridge.mesh.gmsh.loop_cuts import drop_mask

    kept_loops, notes_strip, n_cut = [], [], 0
    areas = [_signed_area(lp[2]) for lp in loops]
    outer = int(np.argmax(np.abs(areas)))
    for i, (tags, xyz, uv, k, even) in enumerate(loops):
        use = np.ones(len(tags), dtype=bool)
        if coarse:
            if not np.all(even):
                raise MeshError(f"{what}: a boundary curve has an odd number of segments after "
                                f"gmsh's quad subdivision; cannot make all-quad elements there")
            use = k % 2 == 0
        sel = np.flatnonzero(use)
        # the face's material lies inside its outer loop and outside its holes
        keep, strips = _zip_cusps(xyz[sel], (k[sel] == 0), eps, np.asarray(tags)[sel], strip_eps=strip_eps,
                                  uv=uv[sel] if notches else None, material_left=(areas[i] > 0) == (i == outer))
        sel = sel[keep]
        for p, length in strips:
            x = xyz[np.flatnonzero(use)[p]]
            notes_strip.append(f"{length:.3g} long at ({x[0]:.4g}, {x[1]:.4g}, {x[2]:.4g})")
        if cut:  # trim-loop excursions: their nodes stay on the neighbour only
            drop = drop_mask(cut, xyz[sel])
            n_cut += int(drop.sum())
            sel = sel[~drop]
        if len(sel) < 3:
            continue  # the whole loop is a zero-width strip
        kept_loops.append((tags, xyz, uv, sel))
    return kept_loops, notes_strip, n_cut


def _mesh_kept_loops(g, s: int, kept_loops: list[tuple], *, coarse: bool, h: float, scale: np.ndarray,
                     box: np.ndarray, element: str, size_at, what: str):
    """Mesh surface ``s`` in its scaled (u, v) on the nodes ``kept_loops`` (`_kept_loops`) at
    size ``h``: gmsh's Frontal-Delaunay (`mesh_planar_loops`), Blossom-recombined for quads,
    split into quads after the subdivision (``coarse``, `_split_to_quads`), inverted elements
    smoothed out (`_untangled`). Where the split leaves the face (an inner node outside its
    loops, or an element still inverted: a thin curved face, whose chords between every other
    boundary node cut across it), its inner nodes are bent towards the boundary curves
    (`_bent_to_boundary`) if that mends it. Returns (loop node tags (L,), uv (N, 2): the L loop
    nodes first, triangles (T, 3), quads (Q, 4), counter-clockwise in (u, v), `_untangled`'s
    count, whether the nodes were bent)."""
    from cadbridge.mesh.gmsh.planar import mesh_planar_loops

    uv_loops = [uv[sel] for tags, xyz, uv, sel in kept_loops]
    # the outer loop first (largest area in (u, v)), as the fallback mesher expects
    area = [_signed_area(lp) for lp in uv_loops]
    order = sorted(range(len(uv_loops)), key=lambda i: -abs(area[i]))
    kept_loops = [kept_loops[i] for i in order]
    uv_loops = [uv_loops[i] for i in order]
    point_sizes = []
    for lp in uv_loops:
        q = lp * scale
        seg = np.linalg.norm(np.roll(q, -1, axis=0) - q, axis=1)
        point_sizes.append(np.minimum(0.5 * (seg + np.roll(seg, 1)), h))
    interior = None if size_at is None else _interior_sizes(g, s, box, scale, h, size_at, 2.0 if coarse else 1.0)
    uv, tris, quads = mesh_planar_loops(uv_loops, scale, h, what, point_sizes=point_sizes,
                                        recombine=element == "quad", interior_sizes=interior)
    loop_tags = np.concatenate([tags[sel] for tags, xyz, uv_, sel in kept_loops])
    if not coarse:
        uv, tangled = _untangled(uv, scale, tris, quads, len(loop_tags))
        return loop_tags, uv, tris, quads, tangled, False
    loop_tags, split, quads, shift = _split_to_quads(uv, tris, quads, kept_loops, len(loop_tags))
    tris = np.zeros((0, 3), dtype=np.int64)
    uv, tangled = _untangled(split, scale, tris, quads, len(loop_tags))
    if tangled >= 0 and not _outside_own_boundary(uv, tris, quads, len(loop_tags)):
        return loop_tags, uv, tris, quads, tangled, False
    bent, bent_tangled = _untangled(_bent_to_boundary(split, quads, len(loop_tags), shift), scale, tris, quads,
                                    len(loop_tags))
    if bent_tangled < 0 or _outside_own_boundary(bent, tris, quads, len(loop_tags)):
        return loop_tags, uv, tris, quads, tangled, False  # no better: as split (the caller's checks report it)
    return loop_tags, bent, tris, quads, bent_tangled, True


def _outside_own_boundary(uv: np.ndarray, tris: np.ndarray, quads: np.ndarray, n_loop: int) -> bool:
    """True if an interior node (index >= ``n_loop`` of uv (N, 2)) lies outside the region
    the elements' boundary edges (those of one element only: the face's loops) bound, by the
    even-odd rule (`cadbridge.cad.trims.polygon_contains` per loop): S(u, v) there is off the
    trimmed face."""
    from cadbridge.cad.trims import polygon_contains

    if len(uv) <= n_loop:
        return False
    edges = np.concatenate([np.stack([c[:, k], c[:, (k + 1) % c.shape[1]]], axis=1)
                            for c in (tris, quads) if len(c) for k in range(c.shape[1])])
    key = np.sort(edges, axis=1)
    _, first, count = np.unique(key[:, 0] * len(uv) + key[:, 1], return_index=True, return_counts=True)
    nxt = dict(edges[first[count == 1]].tolist())  # boundary edge a -> b, wound like the elements
    inside = np.zeros(len(uv) - n_loop, dtype=bool)
    while nxt:  # walk each boundary loop (a few)
        start = next(iter(nxt))
        loop, a = [start], nxt.pop(start)
        while a != start and a in nxt:
            loop.append(a)
            a = nxt.pop(a)
        if len(loop) >= 3:
            inside ^= polygon_contains(uv[n_loop:], uv[loop])
    return not bool(inside.all())


def _fill_face(g, s: int, *, size: float, curvature_elements: int, element: str, subdivided: bool,
               label: str, cut: list | None = None, strip_fraction: float = STRIP_FRACTION,
               size_at=None) -> str:
    name = _label(g, s)
    loops = _face_loops(g, s)
    all_uv = np.concatenate([lp[2] for lp in loops])
    all_xyz = np.concatenate([lp[1] for lp in loops])
    on = np.asarray(g.model.getValue(2, s, all_uv.ravel().tolist()), dtype=float).reshape(-1, 3)
    dev = float(np.linalg.norm(on - all_xyz, axis=1).max())
    box = np.array([all_uv.min(axis=0), all_uv.max(axis=0)])
    diag = float(np.linalg.norm(all_xyz.max(axis=0) - all_xyz.min(axis=0)))
    h, scale = _face_size(g, s, box, size, curvature_elements)
    eps = max(EPS_FACTOR * dev, 1e-9 * diag)  # the CAD's accuracy: every strip this narrow is cut
    strip_eps = strip_fraction * h  # the face's own material this narrow is cut too
    coarse = element == "quad" and subdivided
    if coarse:
        h *= 2.0  # split in two below
    loops, pinches = _joined_at_touching_corners(loops, max(EPS_FACTOR * dev, 1e-9 * diag))
    def zipped(coarse: bool):  # the loops meshed on, with the cusp strips cut
        kept, notes, n = _kept_loops(loops, coarse=coarse, eps=eps, strip_eps=strip_eps, cut=cut, notches=True,
                                     what=f"{label}: {name}")
        if kept and _segments_cross([uv[sel] for tags, xyz, uv, sel in kept]):
            # a notch whose sides cross in (u, v) has no width the (u, v) mesh can keep: cut like
            # a spike (a sliver face 7e-4 mm wide whose two curves cross, trj10_b2-oc-214)
            kept, notes, n = _kept_loops(loops, coarse=coarse, eps=eps, strip_eps=strip_eps, cut=cut,
                                         notches=False, what=f"{label}: {name}")
        if not kept:
            raise MeshError(f"{label}: {name}: the face has no width within the CAD's accuracy "
                            f"({max(eps, strip_eps):.3g})")
        if _segments_cross([uv[sel] for tags, xyz, uv, sel in kept]):
            raise MeshError(f"{label}: {name}: its boundary crosses itself in (u, v) (after cutting the "
                            f"cusp strips narrower than {max(eps, strip_eps):.3g}); cannot mesh it in parameter space")
        return kept, notes, n

    kept_loops, notes_strip, n_cut = zipped(coarse)
    loop_tags, uv, tris, quads, tangled, bent = _mesh_kept_loops(
        g, s, kept_loops, coarse=coarse, h=h, scale=scale, box=box, element=element, size_at=size_at,
        what=f"{label}: {name}")
    n_loop = len(loop_tags)
    interior_uv = uv[n_loop:]
    xyz_new = np.asarray(g.model.getValue(2, s, interior_uv.ravel().tolist()), dtype=float).reshape(-1, 3) \
        if len(interior_uv) else np.zeros((0, 3))
    base = int(g.model.mesh.getMaxNodeTag()) + 1
    new_tags = np.arange(base, base + len(interior_uv), dtype=np.int64)
    node_tag = np.concatenate([loop_tags, new_tags])
    tri_t, quad_t = node_tag[tris], node_tag[quads]
    if _flip_needed(g, s, tri_t, quad_t, uv, tris, quads):
        tri_t, quad_t = tri_t[:, ::-1], quad_t[:, ::-1]
    if len(new_tags):
        g.model.mesh.addNodes(2, s, new_tags.tolist(), xyz_new.ravel().tolist(), interior_uv.ravel().tolist())
    if len(tri_t):
        g.model.mesh.addElementsByType(s, 2, [], tri_t.ravel().tolist())
    if len(quad_t):
        g.model.mesh.addElementsByType(s, 3, [], quad_t.ravel().tolist())
    what = f"{len(tri_t)} triangles" if len(tri_t) else ""
    what += (", " if what and len(quad_t) else "") + (f"{len(quad_t)} quads" if len(quad_t) else "")
    note = f"mesh: gmsh left {name} without elements; meshed in its (u, v) on gmsh's boundary nodes ({what})"
    if cut:
        note = (f"mesh: {name} meshed in its (u, v) on gmsh's boundary nodes ({what}) without its trim-loop "
                f"excursion ({n_cut} boundary nodes left to the neighbour, a crack <= {max(e.chord for e in cut):.3g})")
    if bent:
        note += (" (the quads split from its mesh on every other boundary node left the face: their inner nodes "
                 "bent towards the boundary curves)")
    if tangled:
        note += f" ({tangled} element(s) inverted in (u, v) smoothed out)" if tangled > 0 else \
            f" ({-tangled} element(s) inverted in (u, v) that smoothing could not repair)"
    if pinches:
        note += (f"; a hole touching another loop at {len(pinches)} point(s) joined to it there: "
                 + "; ".join(f"({x[0]:.4g}, {x[1]:.4g}, {x[2]:.4g})" for x in pinches))
    if notes_strip:
        note += (f"; {len(notes_strip)} cusp strip(s) narrower than {max(eps, strip_eps):.2g} (where two boundary curves run "
                 f"together within the CAD's accuracy) left open: " + "; ".join(notes_strip))
    return note


def _untangled(uv: np.ndarray, scale: np.ndarray, tris: np.ndarray, quads: np.ndarray,
               n_loop: int) -> tuple[np.ndarray, int]:
    """(uv (N, 2), k): the interior nodes (index >= ``n_loop``) moved by
    `cadbridge.mesh.gmsh.untangle` in the face's scaled (u, v) where an element (counter-clockwise
    there) has an inverted corner: k > 0 elements were inverted and none is now, k < 0: -k
    are still inverted; (uv, 0) unchanged where none was (gmsh's and the split's meshes as
    they are)."""
    from cadbridge.mesh.gmsh.untangle import corner_sines, untangle

    q = uv * scale
    blocks = [b for b in (tris, quads) if len(b)]
    inverted = sum(int(np.sum(corner_sines(q, b).min(axis=1) <= 0.0)) for b in blocks)
    if not inverted:
        return uv, 0
    q, left = untangle(q, blocks, n_loop)
    return q / scale, (inverted if not left else -left)


def _split_to_quads(uv: np.ndarray, tris: np.ndarray, quads: np.ndarray, kept_loops: list, n_loop: int):
    """Split every element into quads (triangle -> 3, quad -> 4) through its edge midpoints
    and its centroid, in (u, v). A boundary segment between two coarse nodes takes the fine
    node between them (gmsh's subdivision node); other edges get a new node at the (u, v)
    midpoint. uv (N, 2): the n_loop coarse loop nodes first. Returns (loop tags (L,): the
    coarse then the fine boundary nodes, uv (M, 2): those L first, then the old interior
    nodes and the new ones, quads (Q, 4)) wound as the elements were, shift (F, 2): each fine
    node's offset from the midpoint of its coarse chord, in loop-tag order)."""
    coarse_tags, fine_tags, fine_uv, chord_mid = [], [], [], []
    mid_of: dict[tuple[int, int], int] = {}  # coarse boundary segment (local ids) -> fine node id
    off = 0
    for tags, xyz, luv, sel in kept_loops:
        coarse_tags.append(tags[sel])
        m = len(sel)
        for j in range(m):  # loop over the boundary segments (a few hundred)
            a, b = sel[j], sel[(j + 1) % m]
            if (b - a) % len(tags) == 2:  # one fine node between two coarse ones
                f = (a + 1) % len(tags)
                mid_of[(off + j, off + (j + 1) % m)] = mid_of[(off + (j + 1) % m, off + j)] = len(fine_tags)
                fine_tags.append(int(tags[f]))
                fine_uv.append(luv[f])
                chord_mid.append(0.5 * (luv[a] + luv[b]))
        off += m
    n_fine = len(fine_tags)
    n_int = len(uv) - n_loop
    base = n_loop + n_fine + n_int  # first new interior node

    def renum(i: int) -> int:  # old id -> id in the returned numbering
        return i if i < n_loop else i + n_fine

    new_uv: list[np.ndarray] = []
    edge_node: dict[tuple[int, int], int] = {}

    def midpoint(a: int, b: int) -> int:
        if (a, b) in mid_of:
            return n_loop + mid_of[(a, b)]
        key = (a, b) if a < b else (b, a)
        if key not in edge_node:
            edge_node[key] = base + len(new_uv)
            new_uv.append(0.5 * (uv[a] + uv[b]))
        return edge_node[key]

    out = []
    for el in [*tris.tolist(), *quads.tolist()]:  # loop over the coarse elements (a few thousand)
        k = len(el)
        c = base + len(new_uv)
        new_uv.append(uv[el].mean(axis=0))
        mids = [midpoint(el[i], el[(i + 1) % k]) for i in range(k)]
        for i in range(k):  # corner i, midpoint of edge i, centroid, midpoint of edge i - 1
            out.append((renum(el[i]), mids[i], c, mids[i - 1]))
    uv_all = np.concatenate([uv[:n_loop], np.asarray(fine_uv, dtype=float).reshape(-1, 2), uv[n_loop:],
                             np.asarray(new_uv, dtype=float).reshape(-1, 2)])
    tags_all = np.concatenate([*coarse_tags, np.asarray(fine_tags, dtype=np.int64)])
    shift = (np.asarray(fine_uv, dtype=float) - np.asarray(chord_mid, dtype=float)).reshape(-1, 2)
    return tags_all, uv_all, np.asarray(out, dtype=np.int64).reshape(-1, 4), shift


def _bent_to_boundary(uv: np.ndarray, quads: np.ndarray, n_loop: int, shift: np.ndarray) -> np.ndarray:
    """The split quads (`_split_to_quads`: uv (N, 2), its ``n_loop`` boundary nodes first, the
    coarse then the fine ones) with their inner nodes moved by the harmonic extension of the
    boundary's bend: each fine node lies ``shift`` (F, 2) off the midpoint of its coarse chord
    (the coarse nodes 0), and every inner node moves by the mean of its edge neighbours' moves
    (the graph Laplacian solved with those boundary values), as high-order meshes are curved
    to their boundary. On a 2 mm wide ring whose coarse chords cut 2 mm into its hole, the
    split's inner nodes lay 0.6 mm in the hole; bent, they lie in the ring."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.linalg import spsolve

    n = len(uv)
    if n <= n_loop:
        return uv
    e = np.concatenate([quads[:, [k, (k + 1) % 4]] for k in range(4)])
    e = np.unique(np.sort(e, axis=1), axis=0)
    e = np.concatenate([e, e[:, ::-1]])
    adj = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    lap = (coo_matrix((np.asarray(adj.sum(axis=1)).ravel(), (np.arange(n), np.arange(n))), shape=(n, n))
           - adj).tocsr()
    move = np.zeros((n, 2))
    move[n_loop - len(shift):n_loop] = shift
    inner = np.arange(n_loop, n)
    rhs = -lap[inner][:, :n_loop] @ move[:n_loop]
    move[inner] = np.asarray(spsolve(lap[inner][:, inner].tocsc(), rhs)).reshape(-1, 2)
    out = uv.copy()
    out[inner] += move[inner]
    return out


def _flip_needed(g, s: int, tri_t: np.ndarray, quad_t: np.ndarray, uv: np.ndarray, tris: np.ndarray,
                 quads: np.ndarray) -> bool:
    """True if the new elements (counter-clockwise in (u, v); node tags tri_t (T, 3), quad_t
    (Q, 4); local ids tris, quads into uv) must be reversed: the meshed neighbours traverse
    the shared edges in the same direction (a consistently wound mesh traverses them
    oppositely); without meshed neighbours, their normal disagrees with gmsh's face normal."""
    def directed(conn_list):
        e = [np.stack([c[:, k], c[:, (k + 1) % c.shape[1]]], axis=1) for c in conn_list if len(c)
             for k in range(c.shape[1])]
        return np.concatenate(e) if e else np.zeros((0, 2), dtype=np.int64)

    ours = directed([tri_t, quad_t])
    mx = int(max(ours.max(), 1)) + 1
    key = np.sort(ours[:, 0] * mx + ours[:, 1])

    def count_in_key(k: np.ndarray) -> int:
        if not len(key) or not len(k):
            return 0
        at = np.minimum(np.searchsorted(key, k), len(key) - 1)
        return int(np.sum(key[at] == k))
    # only the face's boundary nodes can be shared, and only with the surfaces on its curves
    # (not every node against every surface: the die's binder, 10^5 elements, took minutes)
    curves = {abs(t) for d, t in g.model.getBoundary([(2, s)], combined=False, oriented=False) if d == 1}
    bnd = np.unique(np.concatenate([np.asarray(g.model.mesh.getNodes(1, c, includeBoundary=True)[0], dtype=np.int64)
                                    for c in curves])) if curves else np.zeros(0, dtype=np.int64)
    near = sorted({int(t) for c in curves for t in g.model.getAdjacencies(1, c)[0]} - {s})
    same = opposite = 0
    for t in near:
        et, _, en = g.model.mesh.getElements(2, t)
        conns = [np.asarray(n, dtype=np.int64).reshape(-1, 3 if typ == 2 else 4) for typ, n in zip(et, en)
                 if typ in (2, 3)]
        if not conns or not len(bnd):
            continue
        on_bnd = np.zeros(max(int(bnd.max()), max(int(c.max(initial=0)) for c in conns)) + 1, dtype=bool)
        on_bnd[bnd] = True  # a lookup by node tag: the neighbours can hold 10^5 elements
        conns = [c[on_bnd[c].sum(axis=1) >= 2] for c in conns]
        e = directed(conns)
        e = e[(e < mx).all(axis=1)]
        same += count_in_key(e[:, 0] * mx + e[:, 1])
        opposite += count_in_key(e[:, 1] * mx + e[:, 0])
    if same or opposite:
        return same > opposite
    # no meshed neighbour: compare with gmsh's normal of the face at the element centroids
    conn = tris if len(tris) else quads
    c = uv[conn].mean(axis=1)
    nrm = np.asarray(g.model.getNormal(s, c.ravel().tolist()), dtype=float).reshape(-1, 3)
    x = np.asarray(g.model.getValue(2, s, uv.ravel().tolist()), dtype=float).reshape(-1, 3)
    en = np.cross(x[conn[:, 1]] - x[conn[:, 0]], x[conn[:, 2]] - x[conn[:, 0]])
    return float(np.einsum("ij,ij->i", en, nrm).sum()) < 0
