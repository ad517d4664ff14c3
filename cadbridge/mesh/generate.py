"""Mesh IGES CAD with gmsh (OpenCASCADE kernel): triangles or quads, free or structured.

gmsh is imported lazily inside the functions; this is the only module of the mesh layer
that touches gmsh. Every call owns a fresh gmsh model: it initialises gmsh (or, if the
caller already did, adds a private model and restores every option it changed), and always
finalises / removes it in ``finally`` — no gmsh state survives a call.

Parametric information per node (``Mesh.point_data``)
-----------------------------------------------------
``node_entity`` (N,) int64
    gmsh surface tag of the face the node is attributed to, or -1. Tags are those of the
    OCC import (``gmsh.model.occ.importShapes``), i.e. 1-based in the order OCC lists the
    file's faces (after sewing, when ``sew=True``). A node on an edge shared by several
    faces is attributed to the face with the lowest tag.
``node_uv`` (N, 2) float64
    (u, v) of the node in gmsh's parametrisation of that face (the OCC surface parameters,
    i.e. the underlying surface's own (u, v), not normalised; for IGES NURBS faces those are
    the knot-vector parameters). NaN where ``node_entity`` is -1.
``cell_data["element_entity"]`` (E,) int64
    gmsh surface tag each element was meshed on.
``cell_data["element_face"]`` (E,) int64
    only with ``face_anchors`` (the file is the model's own B-rep, `cadbridge.heal.brep`):
    the model face (index) each element was meshed on, -1 where it could not be told
    (`_model_faces`); as the QIT mesher writes it.

Structured mode and fillets
---------------------------
With ``structured=True`` every face bounded by exactly four curves (one loop) gets a
transfinite (mapped) mesh. Opposite curves of such faces must have equal node counts and
a curve shared by two faces has a single count, so curves are grouped into classes by
union-find over "opposite sides of a structured face", and each class gets one count:

1. ``radius_divisions`` if it contains the curved sides (across the radius) of a fillet;
2. else ``length_divisions`` (if given) if it contains the straight sides of a fillet;
3. else ``divisions`` (if given);
4. else ``ceil(longest curve in the class / size)`` (at least 1).

A *fillet face* is a four-sided face whose one pair of opposite curves are circular arcs
(constant curvature, sampled with ``gmsh.model.getCurvature`` at 7 points, relative spread
< 1e-6) and whose other pair are straight (curvature * length < 1e-9) or arcs of larger
radius (toroidal fillets). It qualifies as a fillet when the arc radius is <=
``fillet_max_radius``; when that is None, when the arcs are shorter than the other pair of
curves (a strip that is narrow across the radius). The arcs are the "radius" direction,
the other pair the "length" direction. This works for any surface type (cylinder, torus,
revolution, NURBS) since it looks only at the boundary curves.
"""

from __future__ import annotations

import math
import tempfile
import warnings
from pathlib import Path
from typing import Sequence

import numpy as np

from cadbridge.mesh.gmsh.isolated import gmsh_call
from cadbridge.mesh.gmsh.presew import presew_brep
from cadbridge.mesh.gmsh.session import GmshSession, apply_options, quiet_stdout
from cadbridge.mesh.mesh import CellBlock, Mesh, MeshError

__all__ = ["mesh_cad", "FaceInfo"]



class FaceInfo:
    """Classification of one gmsh surface for structured meshing.

    tag: gmsh surface tag; curves: boundary curve tags in loop order (4 for a structured
    face); kind: "fillet", "four-sided", "chained" or "other"; radius_pair / length_pair: for
    fillets, the index (0 -> curves 0 and 2, 1 -> curves 1 and 3) of the arc pair and of the
    other pair; radius: arc radius (model units) for fillets. A "chained" face has four
    corners but sides made of several curves (e.g. OCC splits a torus' tube arc at its
    equator, or a neighbour's vertices split a fillet strip's long side): corners are its
    four corner point tags, pairs the (curve, opposite curve) pairs that must get equal
    counts (opposite sides with as many curves, paired in order), sums the (side, opposite
    side) curve lists whose counts must add up to the same (opposite sides with different
    numbers of curves: `_settle_sums`). A chained face whose sums cannot be settled by
    raising counts goes back to "other".
    """

    __slots__ = ("tag", "surface_type", "curves", "kind", "radius_pair", "length_pair", "radius", "corners",
                 "pairs", "sums")

    def __init__(self, tag: int, surface_type: str, curves: list[int]) -> None:
        self.tag = tag
        self.surface_type = surface_type
        self.curves = curves
        self.kind = "four-sided" if len(curves) == 4 and len(set(curves)) == 4 else "other"
        self.radius_pair: int | None = None
        self.length_pair: int | None = None
        self.corners: list[int] = []
        self.pairs: list[tuple[int, int]] = []
        self.sums: list[tuple[list[int], list[int]]] = []
        self.radius: float | None = None

    def __repr__(self) -> str:
        r = f", radius={self.radius:.6g}, radius_pair={self.radius_pair}" if self.kind == "fillet" else ""
        return f"FaceInfo(tag={self.tag}, type={self.surface_type!r}, kind={self.kind!r}, curves={self.curves}{r})"


def _curve_shape(gmsh, c: int) -> tuple[str, float, float]:
    """('line' | 'arc' | 'curve', radius or inf, length) of curve c."""
    lo, hi = gmsh.model.getParametrizationBounds(1, c)
    length = float(gmsh.model.occ.getMass(1, c))
    with np.errstate(over="ignore", invalid="ignore"):
        span = hi[0] - lo[0]
    if not np.isfinite(span):  # a degenerate edge (a pole's): gmsh bounds it by +-1e308, no curve to sample
        return "curve", math.nan, length
    ts = np.linspace(lo[0], hi[0], 7)
    k = np.abs(np.asarray(gmsh.model.getCurvature(1, c, ts), dtype=float))
    with np.errstate(over="ignore", invalid="ignore"):  # gmsh gives ~1e308 on degenerate curves
        straight = bool(np.all(k * max(length, 1e-300) < 1e-9))
    if straight:
        return "line", math.inf, length
    km = float(k.mean())
    if km > 0 and float(k.max() - k.min()) <= 1e-6 * km:
        return "arc", 1.0 / km, length
    return "curve", math.nan, length


def _chained_sides(gmsh, loop: list[int], corner_deg: float = 20.0):
    """Four corners of a face whose single boundary ``loop`` (signed curve tags in order) has
    more than four curves: the points where the boundary turns by more than ``corner_deg``.
    Returns (corner point tags (4,), [(curve, opposite curve), ...], [(side, opposite side),
    ...]) when there are exactly four corners: opposite sides with as many curves are paired
    in order (the opposite side walked backwards), the others give a sum constraint; else
    None."""
    ends = []
    for c in loop:  # loop over the (few) boundary curves
        (_, p0), (_, p1) = gmsh.model.getBoundary([(1, abs(c))], combined=False, oriented=True)
        lo, hi = gmsh.model.getParametrizationBounds(1, abs(c))
        d = np.asarray(gmsh.model.getDerivative(1, abs(c), [lo[0], hi[0]]), dtype=float).reshape(2, 3)
        if c < 0:
            p0, p1, d = p1, p0, -d[::-1]
        ends.append((abs(p0), abs(p1), d[0], d[1]))
    n = len(loop)
    corners = []
    for i in range(n):
        a, b = ends[i - 1], ends[i]
        if a[1] != b[0]:
            return None  # not one closed chain (several loops, e.g. a hole)
        ta, tb = a[3], b[2]
        cos = float(ta @ tb) / max(float(np.linalg.norm(ta) * np.linalg.norm(tb)), 1e-300)
        if cos < math.cos(math.radians(corner_deg)):
            corners.append(i)
    if len(corners) != 4:
        return None
    sides = [[abs(loop[j % n]) for j in range(corners[k], corners[k + 1] if k < 3 else corners[0] + n)]
             for k in range(4)]
    pairs, sums = [], []
    for k in (0, 1):
        a, b = sides[k], sides[k + 2][::-1]
        if len(a) == len(b):
            pairs += list(zip(a, b))
        elif set(a) & set(b):
            return None  # one curve on both sides: no count can balance them
        else:
            sums.append((a, b))
    return [ends[i][0] for i in corners], pairs, sums


def _classify(gmsh, fillet_max_radius: float | None) -> tuple[list[FaceInfo], dict[int, tuple[str, float, float]]]:
    faces: list[FaceInfo] = []
    shapes: dict[int, tuple[str, float, float]] = {}
    for _, s in gmsh.model.getEntities(2):
        loops = gmsh.model.getBoundary([(2, s)], combined=False, oriented=True, recursive=False)
        curves = [abs(t) for d, t in loops if d == 1]
        fi = FaceInfo(s, gmsh.model.getType(2, s), curves)
        if fi.kind == "other" and len(curves) > 4 and len(set(curves)) == len(curves):
            chain = _chained_sides(gmsh, [t for d, t in loops if d == 1])
            if chain is not None:
                fi.kind, fi.corners, fi.pairs, fi.sums = "chained", chain[0], chain[1], chain[2]
        for c in curves:
            if c not in shapes:
                shapes[c] = _curve_shape(gmsh, c)
        if fi.kind == "four-sided":
            pair = [(shapes[curves[0]], shapes[curves[2]]), (shapes[curves[1]], shapes[curves[3]])]
            cands = []
            for p in (0, 1):
                (ka, ra, la), (kb, rb, lb) = pair[p]
                (kc, rc, lc), (kd, rd, ld) = pair[1 - p]
                if ka == kb == "arc" and abs(ra - rb) <= 1e-6 * max(ra, rb) and kc in ("line", "arc") and kd in ("line", "arc"):
                    other_r = min(rc, rd)
                    if other_r <= ra:  # the other pair must be straighter
                        continue
                    if fillet_max_radius is not None:
                        ok = ra <= fillet_max_radius
                    else:
                        ok = max(la, lb) < min(lc, ld)
                    if ok:
                        cands.append((ra, p))
            if cands:
                r, p = min(cands)
                fi.kind, fi.radius_pair, fi.length_pair, fi.radius = "fillet", p, 1 - p, r
        faces.append(fi)
    return faces, shapes


def _structured_counts(
    faces: list[FaceInfo],
    shapes: dict[int, tuple[str, float, float]],
    *,
    size: float,
    divisions: int | None,
    radius_divisions: int,
    length_divisions: int | None,
    curve_count=None,
    even: bool = False,
) -> dict[int, int]:
    """Curve tag -> number of elements (segments), one count per union-find class.
    ``curve_count(tag) -> float`` (elements a curve needs, e.g. from a size field) gives
    every class the largest need of its curves instead of rules 1-4 of the module docs.
    Chained faces' sum constraints are then met by raising counts (`_settle_sums`); with
    ``even`` (quad meshes, which the all-quad subdivision may halve) the classes in a sum
    get even counts, so that halving keeps the sums equal."""
    parent: dict[int, int] = {}

    def find(a: int) -> int:
        parent.setdefault(a, a)
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    def union(a: int, b: int) -> None:
        parent[find(a)] = find(b)

    for f in faces:
        if f.kind in ("four-sided", "fillet"):
            c = f.curves
            union(c[0], c[2])
            union(c[1], c[3])
        elif f.kind == "chained":
            for a, b in f.pairs:
                union(a, b)
            for a, b in f.sums:
                for c in a + b:
                    find(c)
    role: dict[int, set[str]] = {}
    for f in faces:
        if f.kind == "fillet":
            c = f.curves
            rp, lp = f.radius_pair, f.length_pair
            role.setdefault(find(c[rp]), set()).add("radius")
            role.setdefault(find(c[lp]), set()).add("length")
    members: dict[int, list[int]] = {}
    for c in list(parent):
        members.setdefault(find(c), []).append(c)
    counts: dict[int, int] = {}
    for root, cs in members.items():
        r = role.get(root, set())
        if curve_count is not None:
            n = max(1, math.ceil(max(curve_count(c) for c in cs) - 1e-9))
        elif "radius" in r:
            if "length" in r:
                warnings.warn(
                    f"curves {sorted(cs)} are across the radius of one fillet and along another; "
                    f"using radius_divisions={radius_divisions}",
                    stacklevel=3,
                )
            n = radius_divisions
        elif "length" in r and length_divisions is not None:
            n = length_divisions
        elif divisions is not None:
            n = divisions
        else:
            n = max(1, math.ceil(max(shapes[c][2] for c in cs) / size - 1e-9))
        counts[root] = int(n)
    length = {root: max(shapes[c][2] for c in cs) for root, cs in members.items()}
    _settle_sums(faces, find, counts, length, 2 if even else 1)
    return {c: counts[find(c)] for c in parent}


SUM_ROUNDS = 100
"""Sweeps of `_settle_sums` over the chained faces before the unsettled ones give up."""


def _settle_sums(faces: list[FaceInfo], find, n: dict[int, int], length: dict[int, float], step: int) -> None:
    """Raise class counts ``n`` (class root -> elements, in place) until on every chained face
    the curves of each side add up to those of the opposite side (`FaceInfo.sums`). Counts
    are only raised, never lowered, so every curve keeps at least its own need; the class
    raised is the one of the shorter side with the longest elements (length / count).
    ``step`` 2 keeps the classes in a sum even. A face whose sides cannot be balanced (the
    only classes that would raise its shorter side raise the other side as much) or do not
    settle within `SUM_ROUNDS` sweeps goes back to "other" (unstructured)."""
    active = [f for f in faces if f.kind == "chained" and f.sums]
    if step == 2:
        for r in {find(c) for f in active for a, b in f.sums for c in a + b}:
            n[r] += n[r] % 2
    for _ in range(SUM_ROUNDS):
        changed = False
        for f in active:  # loop over the (few hundred) chained faces
            if f.kind != "chained":
                continue
            for a, b in f.sums:
                ra, rb = [find(c) for c in a], [find(c) for c in b]
                sa, sb = sum(n[r] for r in ra), sum(n[r] for r in rb)
                if sa == sb:
                    continue
                low, high = (ra, rb) if sa < sb else (rb, ra)
                deficit = abs(sa - sb)
                gain = {r: (low.count(r) - high.count(r)) * step for r in set(low)}
                while deficit > 0:
                    cands = [r for r, g in gain.items() if 0 < g <= deficit]
                    if not cands:
                        break
                    r = max(cands, key=lambda r: length[r] / n[r])
                    n[r] += step
                    deficit -= gain[r]
                    changed = True
                if deficit:
                    f.kind = "other"
                    break
        if not changed:
            return
    for f in active:
        if f.kind == "chained" and any(sum(n[find(c)] for c in a) != sum(n[find(c)] for c in b) for a, b in f.sums):
            f.kind = "other"


MERGE_TOLERANCE = 1e-4
"""Nodes of a generated mesh closer than this x the element size are merged."""


def mesh_cad(
    path: str | Path,
    *,
    element: str = "tri",
    size: float | None = None,
    structured: bool = False,
    divisions: int | None = None,
    radius_divisions: int = 3,
    length_divisions: int | None = None,
    fillet_max_radius: float | None = None,
    sew: bool = True,
    sew_tolerance: float = 1e-4,
    curvature_elements: int = 0,
    target_unit: str | None = None,
    parametric: bool = True,
    verbose: bool = False,
    embed_curves: Sequence = (),
    size_callback=None,
    curve_size=None,
    mesher: str = "gmsh",
    background_sizes=None,
    loop_cuts: Sequence = (),
    straight_splines: bool = False,
    embed_faces: Sequence | None = None,
    face_anchors=None,
    exact_curve_nodes: bool = False,
    keep: dict | None = None,
    min_size: float | None = None,
) -> Mesh:
    """Mesh the surfaces of an IGES (or STEP/BREP) file with gmsh's OpenCASCADE kernel.

    path : CAD file read by ``gmsh.model.occ.importShapes``.
    element : "tri" (Frontal-Delaunay, gmsh algorithm 6) or "quad" (Delaunay, algorithm 5,
        recombined with Blossom; remaining triangles, if any, are removed by falling back to
        gmsh's all-quad subdivision at twice the size).
    size : target element size in model units (``Mesh.MeshSizeMax``); default bounding-box
        diagonal / 20.
    structured : transfinite (mapped) meshes on four-sided faces (see module docs).
    divisions : elements per curve of structured faces (default from ``size``).
    radius_divisions : elements across the radius of a fillet face (structured mode).
    length_divisions : elements along a fillet's straight direction (default: from
        ``divisions`` / ``size``); the thesis' U-shape die uses ``radius_divisions=3,
        length_divisions=1``.
    fillet_max_radius : arc radius below which a four-sided face with arc sides counts as a
        fillet; None -> narrow-strip criterion (module docs).
    sew : ``Geometry.OCCSewFaces`` so neighbouring faces share curves (conforming mesh).
    sew_tolerance : ``Geometry.Tolerance`` used by the sewing, model units after import (mm
        by default). OCC's IGES export of a cylinder leaves its circles ~1e-5 apart, so the
        gmsh default 1e-8 does not sew it; 1e-4 does.
    curvature_elements : if > 0, ``Mesh.MeshSizeFromCurvature`` (elements per 2*pi).
    target_unit : ``Geometry.OCCTargetUnit`` (e.g. "M"); None keeps OCC's default (mm).
    parametric : store ``node_entity`` / ``node_uv`` in point_data (module docs).
    embed_curves : 3D `NurbsCurve` s lying on the CAD faces (e.g. `cadbridge.heal.creases`'
        crease lines) that must become mesh edges: each is added as a gmsh B-spline and
        fragmented with the surfaces it lies on (OCC general fuse), which splits those faces
        along it; pieces of a curve that lie on no face are removed. Raises `MeshError` if a
        curve lies on no surface.
    size_callback : ``f(dim, tag, x, y, z, lc) -> size`` given to
        ``gmsh.model.mesh.setSizeCallback`` (e.g. `cadbridge.mesh.sizing.SizeField`); the
        size gmsh uses is what it returns (``lc`` is the size from the other rules).
    background_sizes : (points (M, 3), sizes (M,)): the size at a point is that of the
        nearest of the points, looked up inside gmsh (a list-based post-processing view of
        scalar points behind a ``PostView`` background field, no Python call per query:
        gmsh asks ~10^7 times on a production die, where a Python callback spent minutes);
        `cadbridge.mesh.sizing.SizeField.background` makes such points from a graded field.
    curve_size : with ``structured``, ``f(points (M, 3), curvature (M,)) -> sizes (M,)``:
        each class of structured curves gets the largest number of elements any of its
        curves needs, the integral of ds / f along it (its own curvature given, so a
        straight side gets few elements and an arc many); f may return a pair (sizes,
        uniform sizes), see `_curve_need`.

    Returns a `Mesh` with one triangle and/or one quad block (in that order), element
    orientation as gmsh gives it (following each OCC face's orientation), unused nodes
    dropped, ``cell_data["element_entity"]`` and (if ``parametric``) the node data above.
    Raises `MeshError` naming the file on import / meshing failure.
    loop_cuts : trim-loop excursions (`cadbridge.heal.loop_excursions.heal_excursions`): the faces
        holding them are meshed without them (`cadbridge.mesh.gmsh.loop_cuts`).
    straight_splines : a straight curve shorter than ``size`` that is no OCC line gets one
        segment, as a line would (`_one_segment_straight_splines`; for `cadbridge.heal.brep`).
    exact_curve_nodes : nodes on curves moved onto S(c(t)), the surface at the curve's pcurve
        on a face next to it (`_exact_curve_nodes`; for `cadbridge.heal.brep`, whose edges'
        3D curves are approximations of S(c(t)) within a tolerance).
    embed_faces, face_anchors : where the file is the model itself (`cadbridge.heal.brep`: face
        k of the model is the k-th OCC face, on the same surface parametrisation), the model
        face each of ``embed_curves`` lies on (index, or None) and one anchor per model face,
        (F, 9) rows (u, v, x, y, z, umin, umax, vmin, vmax), `ModelBrep.anchors`: a point
        S(u, v) of its surface and the face's (u, v) box. A curve is then embedded in the
        surface of its face, checked by the anchor, without the geometric search (which misses
        a knot line that runs mostly outside its trimmed face), and every element gets its
        model face (``cell_data["element_face"]``, `_model_faces`).
    keep : a dict the caller keeps across the refinement rounds of one model
        (`cadbridge.mesh.gmsh.kept`): a call without ``"snapshot"`` in it stores gmsh's mesh
        there; a later call with ``"snapshot"`` and ``"finer"`` (``finer(xyz (N, 3)) -> (N,)
        bool``, where the round asks for elements finer than that mesh's) meshes again only
        the curves and surfaces where ``finer`` is true and keeps the rest of the mesh.
    min_size : with ``curvature_elements``, the floor of every size instead of ``size`` / 20
        (the curvature rule's floor) where it is smaller: a background field below that floor
        (refinement marks) is then followed, and the curvature rule goes below it too.
    mesher : "gmsh" (default) or "qit": the quasi-isotropic triangulation of
        `cadbridge.mesh.qit.mesher` (IGES only; ``size`` is its target edge length R; the gmsh
        options do not apply).
    """
    if mesher == "qit":
        from cadbridge.mesh.qit.mesher import mesh_cad_qit

        return mesh_cad_qit(path, size=size, element=element, structured=structured, embed_curves=embed_curves)
    if mesher != "gmsh":
        raise MeshError(f"mesher must be 'gmsh' or 'qit', got {mesher!r}")
    path = Path(path)
    if element not in ("tri", "quad"):
        raise MeshError(f"element must be 'tri' or 'quad', got {element!r}")
    if not path.is_file():
        raise MeshError(f"{path}: no such file")
    if size is not None and not (size > 0 and math.isfinite(size)):
        raise MeshError(f"size must be a positive number, got {size!r}")
    for nm, v in (("divisions", divisions), ("radius_divisions", radius_divisions), ("length_divisions", length_divisions)):
        if v is not None and (int(v) != v or v < 1):
            raise MeshError(f"{nm} must be a positive integer, got {v!r}")


    kw = dict(element=element, size=size, structured=structured, divisions=divisions,
              radius_divisions=radius_divisions, length_divisions=length_divisions,
              fillet_max_radius=fillet_max_radius, sew=sew, sew_tolerance=sew_tolerance,
              curvature_elements=curvature_elements, target_unit=target_unit, parametric=parametric,
              embed_curves=list(embed_curves), size_callback=size_callback, curve_size=curve_size,
              background_sizes=background_sizes, loop_cuts=list(loop_cuts), straight_splines=straight_splines,
              embed_faces=None if embed_faces is None else list(embed_faces), face_anchors=face_anchors,
              exact_curve_nodes=exact_curve_nodes, keep=keep, min_size=min_size)
    try:
        return _mesh_watched(path, verbose, heal=False, **kw)
    except MeshError as first:
        if "gmsh failed" not in str(first):
            raise
        # real CAD: degenerated edges and edges shorter than the tolerance break gmsh's 1D
        # loops ("The 1D mesh seems not to be forming a closed loop"); OCC's shape fixing
        # (Geometry.OCCFixDegenerated / OCCFixSmallEdges) on import repairs them
        try:
            return _mesh_watched(path, verbose, heal=True, **kw)
        except MeshError as second:
            raise MeshError(f"{second} (also after OCC shape healing; first attempt: {first})") from second


MAX_HALTS = 3
"""Surfaces one meshing attempt may leave to cadbridge's (u, v) fill after gmsh stalled or
crashed on them (`_mesh_watched`); one more halt fails the attempt."""


def _mesh_watched(path: Path, verbose: bool, heal: bool, **kw) -> Mesh:
    """`_mesh_once` in a forked child, watched (`cadbridge.mesh.gmsh.isolated`). Where gmsh
    stalls or crashes on a surface, the attempt runs again with that surface hidden from gmsh
    and meshed by cadbridge in its (u, v) (`cadbridge.mesh.gmsh.empty_faces`, whose note names
    it), up to `MAX_HALTS` surfaces. Raises `MeshError` ("gmsh failed: ...") where gmsh halts
    outside a surface, twice on one surface, or more often."""
    from cadbridge.mesh.gmsh.isolated import GmshHalted, run_isolated

    keep = kw["keep"]
    first = keep is not None and "snapshot" not in keep
    skip: dict[int, str] = {}
    while True:
        attempt = dict(kw, skip=dict(skip))

        def job() -> tuple[Mesh, dict | None]:
            mesh = _mesh_once(path, verbose, heal, **attempt)
            return mesh, keep.get("snapshot") if first else None  # the child's keep: sent back

        try:
            mesh, snap = run_isolated(job, echo_gmsh=verbose)
        except GmshHalted as halt:
            if halt.surface is None or halt.surface in skip or len(skip) >= MAX_HALTS:
                raise MeshError(f"{path}: gmsh failed: {halt}") from None
            skip[halt.surface] = halt.reason
            continue
        if first and snap is not None:
            keep["snapshot"] = snap
        return mesh


def _mesh_once(path: Path, verbose: bool, heal: bool, **kw) -> Mesh:
    import gmsh

    with GmshSession(verbose) as sess:
        try:
            return _mesh_in_session(sess, path, heal=heal, **kw)
        except MeshError:
            raise
        except Exception as exc:
            last = ""
            try:
                last = gmsh.logger.getLastError()
            except Exception:
                pass
            msg = str(exc) or last or type(exc).__name__
            raise MeshError(f"{path}: gmsh failed: {msg}") from exc


def _mesh_in_session(sess: GmshSession, path: Path, **kw) -> Mesh:
    g = sess.gmsh
    opts: dict[str, float | str] = {
        "Geometry.OCCSewFaces": 1 if kw["sew"] else 0,
        "Geometry.Tolerance": kw["sew_tolerance"],
        "Geometry.OCCImportLabels": 0,
        "Geometry.OCCFixDegenerated": 1 if kw["heal"] else 0,
        "Geometry.OCCFixSmallEdges": 1 if kw["heal"] else 0,
    }
    if kw["target_unit"]:
        opts["Geometry.OCCTargetUnit"] = kw["target_unit"]
    with tempfile.TemporaryDirectory(prefix="cadbridge-sewn-") as tmp:
        source = path
        if kw["sew"] and not kw["heal"] and not kw["target_unit"] and path.suffix.lower() == ".brep":
            # gmsh's sewing without its area statistics (`cadbridge.mesh.gmsh.presew`)
            sewn = Path(tmp) / path.name
            if presew_brep(path, sewn, kw["sew_tolerance"]):
                source, opts["Geometry.OCCSewFaces"] = sewn, 0
        apply_options(sess, opts)
        try:
            with quiet_stdout(not sess.verbose):  # OCC's IGES reader prints to fd 1
                g.model.occ.importShapes(str(source))
            g.model.occ.synchronize()
        except Exception as exc:
            raise MeshError(f"{path}: gmsh/OCC cannot import the file: {exc}") from exc
    if not g.model.getEntities(2):
        raise MeshError(f"{path}: no surfaces found in the CAD file")
    unsewn = _unsew_collapsed(g, sess, path, kw) if kw["sew"] else []
    if kw["embed_curves"]:
        _embed_curves(g, kw["embed_curves"], path, _known_hosts(g, kw["embed_faces"], kw["face_anchors"]))
    surfaces = [t for _, t in g.model.getEntities(2)]
    bb = np.array(g.model.getBoundingBox(-1, -1), dtype=float)
    diag = float(np.linalg.norm(bb[3:] - bb[:3]))
    size = kw["size"] if kw["size"] is not None else diag / 20.0
    if not size > 0:
        raise MeshError(f"{path}: degenerate bounding box {bb.tolist()}")
    mopts: dict[str, float | str] = {
        "Mesh.MeshSizeFromPoints": 0,
        "Mesh.ElementOrder": 1,
        # triangles: Frontal-Delaunay (6). Quads: Delaunay (5) then Blossom recombination
        # with extra smoothing: on the samples this keeps quad corner angles below ~150
        # degrees, where "Frontal-Delaunay for quads" (8) left 170-degree corners that Nagata
        # patches cannot bend over, and its quads are rounder than from (6): on
        # multiple_knots.igs the Nagata normal error drops from 1.13 to 0.87 degrees.
        "Mesh.Algorithm": _algorithm(kw),
        "Mesh.RecombineAll": 1 if kw["element"] == "quad" else 0,
        "Mesh.RecombinationAlgorithm": 1,
        "Mesh.Smoothing": 10,
        "Mesh.SubdivisionAlgorithm": 0,
        # gmsh retries a face whose 1D mesh crosses itself in (u, v) after splitting edges there:
        # with recombination each retry costs more (the Inventor spring: > 200 s at the default
        # 10), and where a retry succeeds it fills zero-width cusp strips with slivers (nodes
        # 1e-13 apart, corner normals reversed, quads folded). No retry: such faces stay empty
        # and cadbridge.mesh.gmsh.empty_faces meshes them, cutting those strips off.
        "Mesh.MaxRetries": 0,
        # the size integral along curves (node spacing from curvature) to 1e-5 instead of
        # gmsh's 1e-9: the production die's 1D mesh 21 -> 3.5 s, 67 833 -> 67 784 nodes.
        # Not with structured meshes: their curves' nodes must stay at equal arc lengths (the
        # U-shape's radius elements then miss the thesis' 0.060 % by 4e-6 %).
        "Mesh.LcIntegrationPrecision": 1e-9 if kw["structured"] else 1e-5,
    }
    apply_options(sess, mopts)
    if kw["size_callback"] is not None or kw["background_sizes"] is not None:
        # the callback or field alone sets the sizes inside faces (else gmsh interpolates the
        # boundary sizes across them, filling a plane next to a small round with small elements)
        sess.set("Mesh.MeshSizeExtendFromBoundary", 0)
    _set_sizes(g, sess, kw, size, 1.0)
    if not kw["structured"]:
        _narrow_face_curves(g, surfaces, kw, size, 1.0)
    if kw["straight_splines"] and kw["size_callback"] is None and kw["background_sizes"] is None:
        _one_segment_straight_splines(g, size)
    if kw["structured"]:
        faces, shapes = _classify(g, kw["fillet_max_radius"])
        counts = _structured_counts(
            faces, shapes, size=size, divisions=kw["divisions"],
            radius_divisions=kw["radius_divisions"], length_divisions=kw["length_divisions"],
            curve_count=None if kw["curve_size"] is None else (lambda c: _curve_need(g, c, kw["curve_size"])),
            even=kw["element"] == "quad",
        )
        for c, n in counts.items():
            g.model.mesh.setTransfiniteCurve(c, n + 1)
        for f in faces:
            if f.kind in ("four-sided", "fillet", "chained"):
                g.model.mesh.setTransfiniteSurface(f.tag, cornerTags=f.corners)
                if kw["element"] == "quad":
                    g.model.mesh.setRecombine(2, f.tag)
    redone: dict[int, tuple[int, list[int]]] = {}  # {surface: (folded pairs, refold algorithms tried)}
    oversized: dict[int, float] = {}  # {surface: its longest element edge / size, as gmsh first made it}
    # every generate() meshes only what has no mesh yet: the faces meshed before it, and the
    # rest of a model after `g.model.mesh.clear()`
    sess.set("Mesh.MeshOnlyEmpty", 1)
    kept = None  # (surfaces meshed again, surfaces kept) where a refinement round keeps the rest
    keep = kw["keep"]
    if (keep is not None and "snapshot" in keep and keep.get("finer") is not None and kw["element"] == "tri"
            and not kw["structured"]):  # (quads: `_all_quads_possible` and the subdivision mesh everything)
        from cadbridge.mesh.gmsh.kept import restore

        kept = restore(g, keep["snapshot"], keep["finer"], heal=kw["heal"])
    hopeless = kw["element"] == "quad" and not _all_quads_possible(g, sess, surfaces, kw)
    if not hopeless:
        mesh, filled = _generate_unfolded(g, surfaces, size, kw, path, False, redone, sess, oversized)
    subdivided = False
    if kw["element"] == "quad" and (hopeless or len(mesh.triangles)):
        subdivided = True
        # recombination left triangles: gmsh's all-quad subdivision (splits every element into
        # quads, halving the size) on a mesh made at twice the target size
        g.model.mesh.clear()
        sess.set("Mesh.SubdivisionAlgorithm", 1)
        # one smoothing pass, not 10: the subdivision sets the quads' shape. On the production
        # die (this pass alone) gmsh's 2D time 21.1 -> 8.9 s,
        # quads' largest corner angle p99 158.1 -> 157.5 degrees, quads above 150: 4070 -> 4043
        sess.set("Mesh.Smoothing", SUBDIVISION_SMOOTHING)
        # every size at twice its value (else the subdivision halves them: 4x the elements)
        _set_sizes(g, sess, kw, size, 2.0)
        if kw["structured"]:
            for c, n in counts.items():
                g.model.mesh.setTransfiniteCurve(c, max(1, math.ceil(n / 2)) + 1)
        else:
            _narrow_face_curves(g, surfaces, kw, size, 2.0)
        _one_segment_short_curves(g, 4.0 * MERGE_TOLERANCE * size, set(counts) if kw["structured"] else set())
        mesh, filled = _generate_unfolded(g, surfaces, size, kw, path, True, redone, sess, oversized)
        if len(mesh.triangles):
            raise MeshError(f"{path}: gmsh left {len(mesh.triangles)} triangles in quad mode")
    # faces that pinch to a point (two boundary curves touching) and edges far below the
    # size make gmsh grade nodes down to ~1e-13 apart and overlap slivers there: nodes
    # closer than 1e-4 x size are one node (cadbridge.mesh.cleanup), but CAD vertices
    # farther apart stay apart (a chain of short CAD edges, each step below the tolerance)
    from cadbridge.mesh.cleanup import merge_close_nodes

    if keep is not None and "snapshot" not in keep:  # the first mesh of a model: kept for its rounds
        from cadbridge.mesh.gmsh.kept import snapshot

        keep["snapshot"] = snapshot(g, heal=kw["heal"], subdivided=subdivided)
    if kw["parametric"]:
        mesh = _collect(g, surfaces, True, path)
    if kw["face_anchors"] is not None:  # the model's own B-rep: each element's model face
        mesh.cell_data["element_face"] = _model_faces(g, np.asarray(mesh.cell_data["element_entity"]),
                                                      kw["face_anchors"])
    if kw["exact_curve_nodes"]:
        _exact_curve_nodes(g, mesh, diag)
    tol = _merge_tolerance(size, subdivided)
    mesh, merged = merge_close_nodes(mesh, tol, anchors=_vertex_nodes(g, mesh))
    mesh.notes += list(dict.fromkeys(filled))  # a face filled in each pass: one note
    folded = {t: v for t, v in redone.items() if v[0] > 0}
    if folded:
        mesh.notes.append(f"mesh: gmsh's mesh folded over itself on surface(s) "
                          f"{', '.join(f'{t} ({k} element pairs)' for t, (k, _) in sorted(folded.items()))} "
                          f"(neighbouring elements more than {FOLD_DEG:g} degrees apart); meshed again with gmsh "
                          f"algorithm " + ", ".join(f"{' then '.join(map(str, a))} on {t}" for t, (_, a) in sorted(folded.items())))
    if oversized:
        mesh.notes.append(f"mesh: gmsh's elements on surface(s) "
                          f"{', '.join(f'{t} (up to {r:.3g} x the size)' for t, r in sorted(oversized.items()))} "
                          f"were longer than {OVERSIZE:g} x the size asked (its Delaunay triangulation of a narrow "
                          f"face's boundary nodes, kept); meshed again with gmsh algorithm "
                          + ", ".join(f"{' then '.join(map(str, redone[t][1]))} on {t}" for t in sorted(oversized)))
    if merged:
        mesh.notes.append(f"mesh: {merged.summary()}")
    if kept is not None and not subdivided:  # (a subdivision pass meshed everything again)
        mesh.notes.append(f"mesh: meshed again {kept[0]} of {sum(kept)} surfaces, those where the refinement asks "
                          f"for finer elements; the other {kept[1]} kept their mesh")
    if unsewn:
        mesh.notes.append(f"mesh: {len(unsewn)} face(s) closed around a collapsed edge (a pole or apex) meshed unsewn, "
                          f"their borders joined by the node merge (gmsh's sewing drops collapsed edges)")
    return mesh


def _collapsed_surfaces(g, tol: float) -> list[int]:
    """gmsh surfaces closed around a collapsed side of their parameter box: one side maps onto
    one point within ``tol`` (model units; a pole or a cone apex, a degenerated edge of the
    face) and the two sides across it onto each other (a seam), so that point lies inside the
    face (5 points per side). A three-sided patch (a collapsed side, no seam) is not one: gmsh
    meshes those sewn."""
    t = np.linspace(0.0, 1.0, 5)
    out = []
    for _, s in g.model.getEntities(2):
        lo, hi = g.model.getParametrizationBounds(2, s)
        u, v = lo[0] + (hi[0] - lo[0]) * t, lo[1] + (hi[1] - lo[1]) * t
        sides = [(np.full(5, lo[0]), v), (np.full(5, hi[0]), v), (u, np.full(5, lo[1])), (u, np.full(5, hi[1]))]
        uv = np.concatenate([np.column_stack(side) for side in sides]).ravel()
        x = np.asarray(g.model.getValue(2, s, uv.tolist()), dtype=float).reshape(4, 5, 3)
        point = np.max(np.linalg.norm(x - x[:, :1], axis=2), axis=1) <= tol  # u0, u1, v0, v1 collapse
        closed_u = np.max(np.linalg.norm(x[0] - x[1], axis=1)) <= tol
        closed_v = np.max(np.linalg.norm(x[2] - x[3], axis=1)) <= tol
        if (closed_u and (point[2] or point[3])) or (closed_v and (point[0] or point[1])):
            out.append(s)
    return out


def _unsew_collapsed(g, sess: GmshSession, path: Path, kw: dict) -> list[int]:
    """Faces closed around a collapsed edge (`_collapsed_surfaces`) imported unsewn: gmsh's OCC
    healing (``Geometry.OCCSewFaces`` or ``healShapes``) removes every degenerated edge from the
    face loops, so the (u, v) loop of a cone or a sphere with its apex or pole inside the face
    (seam and collapsed edge) no longer closes ("The 1D mesh seems not to be forming a closed
    loop"), or meshes as slivers. If the
    sewn import has such faces, the file is imported again without sewing and the other faces
    are sewn among themselves; the node merge of `mesh_cad` joins the borders of the collapsed
    ones. Returns the collapsed faces' tags in the new import ([] when there are none)."""
    if not _collapsed_surfaces(g, kw["sew_tolerance"]):
        return []
    g.model.occ.remove(g.model.occ.getEntities(), recursive=True)
    g.model.occ.synchronize()
    sess.set("Geometry.OCCSewFaces", 0)
    with quiet_stdout(not sess.verbose):
        g.model.occ.importShapes(str(path))
    g.model.occ.synchronize()
    collapsed = _collapsed_surfaces(g, kw["sew_tolerance"])
    others = [(2, s) for _, s in g.model.getEntities(2) if s not in set(collapsed)]
    if len(others) > 1:
        g.model.occ.healShapes(others, tolerance=kw["sew_tolerance"], fixDegenerated=kw["heal"],
                               fixSmallEdges=kw["heal"], fixSmallFaces=False, sewFaces=True, makeSolids=False)
        g.model.occ.synchronize()
        collapsed = _collapsed_surfaces(g, kw["sew_tolerance"])
    return collapsed


SUBDIVISION_SMOOTHING = 1
"""gmsh's ``Mesh.Smoothing`` steps in the all-quad subdivision pass (10 before it)."""

FOLD_DEG = 150.0
"""Two elements of one gmsh surface sharing an edge whose normals differ by more than this
are a fold of gmsh's mesh."""

OVERSIZE = 2.0
"""An element edge longer than this x the size asked is gmsh's mistake, mended like a fold.
Frontal-Delaunay (and Delaunay) keep their triangulation of the boundary nodes of a narrow
curved face where they insert no point: on the conical wall of K1's bow from Think3
(trj5_k1-tc, 2.5 mm high) edges 3.5 x the size 6.8, Nagata error 0.22 mm where the other K1
tools stay below 0.08; on Euclid's turbine (ec_turbine-A, face 25) 4.2 x. MeshAdapt (1) meshes
both within 1.3 x. gmsh's sizes stay below 1.5 x elsewhere."""

_REFOLD_ALGORITHMS = {"quad": (6, 8), "tri": (1,)}
"""gmsh's 2D algorithms for a surface whose mesh folded, in turn while it still folds:
Frontal-Delaunay (6) then Frontal-Delaunay for quads (8) for quads, MeshAdapt (1) for
triangles. 8 meshes the production die's boss wall BOS00373 without its fold, but does not
follow a background size field: on the pilot ring of the die (seam face, t = 0.002) its quads
were 1.32x the sizes asked at the median and 4.5x at p90 (414 quads where 6 makes 1 882, at
0.82x like every other face), so the ring's error grew 10x in the pass it refolded."""


def _polygon_normals(x: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Unnormalised normals (E, 3) of the triangles or quads ``c`` (E, 3|4) over nodes ``x``
    (N, 3): the cross product of the edges, or of the diagonals for quads."""
    d1, d2 = ((x[c[:, 1]] - x[c[:, 0]], x[c[:, 2]] - x[c[:, 0]]) if c.shape[1] == 3 else
              (x[c[:, 2]] - x[c[:, 0]], x[c[:, 3]] - x[c[:, 1]]))
    return np.cross(d1, d2)


def _folded_surfaces(mesh: Mesh) -> dict[int, int]:
    """{gmsh surface: element pairs} of the surfaces where two elements sharing an edge have
    normals (of their corners' polygon) more than `FOLD_DEG` apart. A surface is smooth
    between its curves (creases are curves after `_embed_curves`) and the curvature sizing
    turns the normal by ~30 degrees an element, so such a pair is an element gmsh laid over
    its neighbours: on the production die quad the boss wall BOS00373 at (-31.1, -95.2, -85.1)
    (sub-quads' normals radial -1 among +1: the convert guard's 3 straddlers there; algorithm
    8 meshes it without) and the binder BND00963 near its corners (z -0.994 among +0.994; the
    same mesh with every algorithm tried, 1, 5, 6, 8: not repaired here)."""
    from cadbridge.mesh.topology import edge_table

    x = mesh.nodes
    nrm = []
    for b in mesh.cells:  # one or two blocks
        n = _polygon_normals(x, np.asarray(b.data))
        nrm.append(n / np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None])
    n = np.concatenate(nrm)
    ent = np.asarray(mesh.cell_data["element_entity"])
    t = edge_table(mesh)
    two = np.flatnonzero(t.counts == 2)
    a, b = t.elems[t.ptr[two]], t.elems[t.ptr[two] + 1]
    bad = (ent[a] == ent[b]) & (np.einsum("ij,ij->i", n[a], n[b]) < math.cos(math.radians(FOLD_DEG)))
    s, k = np.unique(ent[a[bad]], return_counts=True)
    return {int(i): int(j) for i, j in zip(s, k)}


def _generate_unfolded(g, surfaces: list[int], size: float, kw: dict, path: Path, subdivided: bool,
                       redone: dict[int, int], sess: GmshSession, oversized: dict[int, float] | None = None
                       ) -> tuple[Mesh, list[str]]:
    """gmsh's 2D mesh (`_generate`, `_fill_empty`) collected, with its folds and its oversized
    elements repaired.

    An oversized element is longer than `OVERSIZE` x ``size`` (`_oversized_surfaces`; not in
    structured meshes, whose fillet strips may be one element long): such a surface goes the
    way of a fold, with 0 folded pairs in ``redone``, and ``oversized`` gets
    {surface: longest edge / size} as gmsh first made it.

    A fold is an element gmsh laid over its neighbours: a pair more than `FOLD_DEG` apart
    (`_folded_surfaces`) on a surface where an element is wound against the surface
    (`_wound_against_surface`; a pair without one is the CAD's own turn, which no mesh of the
    face changes). A surface that folds is cleared and meshed once more alone with the next of
    `_REFOLD_ALGORITHMS` it has not tried (``Mesh.MeshOnlyEmpty``, set by the caller: the rest of
    the mesh stays; ``redone`` gets it: {surface: (folded pairs, algorithms tried)}). After the all-quad subdivision
    (``subdivided``) it is meshed at the target size without it (its boundary nodes are already
    subdivided, so their count is even and recombination may close them). A surface that still
    folds (the production die's binder BND00963 in the quad subdivision pass: every gmsh
    algorithm gave the same fold) or keeps triangles is cleared and meshed by cadbridge in its
    (u, v) on gmsh's boundary nodes (`cadbridge.mesh.gmsh.empty_faces`), as a surface gmsh failed
    on; where that cannot mesh a face that only kept triangles, the whole model is meshed again
    with the subdivision, the last refold algorithm on the redone surfaces (`_regenerate_all`).
    Returns (mesh without the nodes' (u, v), which the caller collects once at the end; notes
    of the filled faces). A quad mesh that leaves triangles before the subdivision is returned
    as it is: the subdivision pass follows."""
    failed = _generate(g, surfaces, kw)
    filled = _fill_empty(g, surfaces, size, kw, path, subdivided=subdivided, failed=failed)
    _check_all_meshed(g, surfaces, path)
    mesh = _collect(g, surfaces, False, path)
    if kw["element"] == "quad" and not subdivided and len(mesh.triangles):
        return mesh, filled
    left_triangles: set[int] = set()
    oversized = {} if oversized is None else oversized
    while True:
        folds = _folds(g, mesh)
        if not kw["structured"]:  # (a structured fillet strip is one element long on purpose)
            for s, r in _oversized_surfaces(mesh, size).items():
                oversized.setdefault(s, r)
                folds.setdefault(s, 0)
        algorithms = _REFOLD_ALGORITHMS[kw["element"]]
        new = {s: k for s, k in folds.items() if len(redone.get(s, (0, ()))[1]) < len(algorithms)}
        if not new:
            break
        for s, k in new.items():
            pairs, tried = redone.get(s, (k, []))
            redone[s] = (pairs, tried + [algorithms[len(tried)]])
            g.model.mesh.clear([(2, s)])  # its curves' nodes stay
            g.model.mesh.setAlgorithm(2, s, redone[s][1][-1])
        if subdivided:
            sess.set("Mesh.SubdivisionAlgorithm", 0)
            _set_sizes(g, sess, kw, size, 1.0)
        # the algorithm asked, as it is: gmsh would quietly remesh with MeshAdapt a surface
        # whose Delaunay-based mesh it finds invalid, which this chain follows anyway (the next
        # algorithm, then the (u, v) fill). On the production die's binder BND00963 (quad) that
        # MeshAdapt pass took 14 of the refold's 15 s and folded as well.
        sess.set("Mesh.AlgorithmSwitchOnFailure", 0)
        try:
            failed = _generate(g, sorted(new), kw)  # those alone: Mesh.MeshOnlyEmpty
        finally:
            sess.set("Mesh.AlgorithmSwitchOnFailure", 1)
            if subdivided:
                sess.set("Mesh.SubdivisionAlgorithm", 1)
                _set_sizes(g, sess, kw, size, 2.0)
        filled += _fill_empty(g, sorted(new), size, kw, path, subdivided=subdivided, failed=failed)
        _check_all_meshed(g, surfaces, path)
        mesh = _collect(g, surfaces, False, path)
        if subdivided:
            left_triangles |= _surfaces_with_triangles(mesh, new)
    for s in left_triangles - set(folds):
        folds[s] = redone[s][0]
    if not folds:
        return mesh, filled
    try:
        mesh, more = _fill_folds(g, surfaces, folds, left_triangles, size, kw, path, subdivided)
        return mesh, filled + more
    except MeshError:
        if not subdivided or not left_triangles:
            raise
    mesh, more = _regenerate_all(g, surfaces, size, kw, path)
    filled += more
    folds = _folds(g, mesh)
    if folds:
        mesh, more = _fill_folds(g, surfaces, folds, set(), size, kw, path, True)
        filled += more
    return mesh, filled


def _oversized_surfaces(mesh: Mesh, size: float) -> dict[int, float]:
    """{surface: longest element edge / size} of the surfaces with an element edge longer than
    `OVERSIZE` x ``size`` (the size asked, ``Mesh.MeshSizeMax``)."""
    ent = np.asarray(mesh.cell_data["element_entity"])
    x = mesh.nodes
    longest = np.concatenate([np.linalg.norm(x[np.roll(b.data, -1, axis=1)] - x[b.data], axis=2).max(axis=1)
                              for b in mesh.cells])
    out: dict[int, float] = {}
    for i in np.flatnonzero(longest > OVERSIZE * size):  # loop over the (few) oversized elements
        s = int(ent[i])
        out[s] = max(out.get(s, 0.0), float(longest[i] / size))
    return out


def _folds(g, mesh: Mesh) -> dict[int, int]:
    """{surface: pairs} of `_folded_surfaces` where an element is wound against the surface."""
    return {s: k for s, k in _folded_surfaces(mesh).items() if _wound_against_surface(g, mesh, s)}


def _fill_folds(g, surfaces: list[int], folds: dict[int, int], left_triangles: set[int], size: float, kw: dict,
                path: Path, subdivided: bool) -> tuple[Mesh, list[str]]:
    """Clear the surfaces ``folds`` {surface: pairs} and mesh them in their (u, v)
    (`cadbridge.mesh.gmsh.empty_faces`): (mesh, one note per face)."""
    from cadbridge.mesh.gmsh.empty_faces import fill_empty_faces

    for s in folds:
        g.model.mesh.clear([(2, s)])  # the surface's own nodes and elements; its curves' nodes stay
    why = {s: (f"its mesh folded over itself ({k} element pairs more than {FOLD_DEG:g} degrees apart)" if k else
               f"its elements were longer than {OVERSIZE:g} x the size asked") + f" with gmsh "
              f"algorithm {_algorithm(kw)}" + (
                  f", and algorithm {_refolds(kw)} left triangles" if s in left_triangles else
                  f" and {_refolds(kw)}") for s, k in folds.items()}
    notes = fill_empty_faces(g, sorted(folds), size=size, curvature_elements=kw["curvature_elements"],
                             element=kw["element"], subdivided=subdivided, label=str(path), failed=why,
                             merge_tolerance=_merge_tolerance(size, subdivided), size_at=_size_at(kw))
    return _collect(g, surfaces, False, path), [
        n.replace(") and left ", ") on ", 1).replace(" without elements;", ";", 1) for n in notes]


def _refolds(kw: dict) -> str:
    """The refold algorithms of ``kw["element"]`` as words: "6, then 8"."""
    return ", then ".join(map(str, _REFOLD_ALGORITHMS[kw["element"]]))


def _regenerate_all(g, surfaces: list[int], size: float, kw: dict, path: Path) -> tuple[Mesh, list[str]]:
    """The whole model meshed again in the subdivision pass (its options set), each surface
    with the algorithm it has now: (mesh, notes of the faces `_fill_empty` meshed)."""
    g.model.mesh.clear()
    failed = _generate(g, surfaces, kw)
    filled = _fill_empty(g, surfaces, size, kw, path, subdivided=True, failed=failed)
    _check_all_meshed(g, surfaces, path)
    return _collect(g, surfaces, False, path), filled


def _surfaces_with_triangles(mesh: Mesh, surfaces) -> set[int]:
    """The surfaces of ``surfaces`` holding a triangle of ``mesh``."""
    tri = [b for b in mesh.cells if b.type == "triangle"]
    if not tri:
        return set()
    ent = np.asarray(mesh.cell_data["element_entity"])[:len(tri[0].data)]  # triangles come first
    return set(np.unique(ent).tolist()) & set(surfaces)


ALL_QUAD_PROBES = (0.02, 0.1)
"""`_all_quads_possible` meshes these growing shares of the faces, fewest boundary nodes first."""


def _all_quads_possible(g, sess: GmshSession, surfaces: list[int], kw: dict) -> bool:
    """Whether gmsh's quad mesh at the target size (recombined triangles) may close without
    triangles on every face, tried cheaply before the whole model is meshed. Blossom cannot pair
    the triangles of a face with an odd number of boundary nodes, and on real CAD it leaves a
    few on other faces too (5 of the 7 corpus files and the production die, where 105 of its
    892 smallest faces kept some: each then needs the all-quad subdivision, so that first mesh
    was wasted, 43 s of the die's quad ``convert``). The 1D mesh is made and checked for odd
    faces; then the faces are meshed in the shares `ALL_QUAD_PROBES` of their number, those
    with the fewest boundary nodes first (gmsh's time per face is mostly a fixed cost, ~6 ms),
    the others hidden (``Mesh.MeshOnlyVisible``), stopping at the first share that keeps a
    triangle. False then or if a face is odd; the probed faces' elements stay (with
    ``Mesh.MeshOnlyEmpty`` the next generate meshes the rest)."""
    with gmsh_call(surfaces=False):
        g.model.mesh.generate(1)
    b = _boundary_nodes(g, surfaces)
    if np.any(b % 2):
        return False
    order = np.argsort(b, kind="stable")
    done = 0
    for share in ALL_QUAD_PROBES:
        k = max(1, math.ceil(share * len(surfaces)))
        if k <= done:
            continue
        probe = [surfaces[i] for i in order[done:k]]
        hidden = [(2, surfaces[i]) for i in np.concatenate([order[:done], order[k:]])]
        g.model.setVisibility(hidden, 0)
        sess.set("Mesh.MeshOnlyVisible", 1)
        try:
            _generate(g, probe, kw)
        finally:
            sess.set("Mesh.MeshOnlyVisible", 0)
            g.model.setVisibility(hidden, 1)
        if any(2 in g.model.mesh.getElements(2, s)[0] for s in probe):
            return False
        done = k
    return True


def _boundary_nodes(g, surfaces: list[int]) -> np.ndarray:
    """Number of 1D mesh nodes on each surface's boundary (S,) (gmsh's 1D mesh made). A
    triangulation of a face has as many triangles, mod 2, as boundary nodes (Euler:
    T = 2 V - B - 2 + 2 holes), so Blossom cannot pair all of them into quads where it is odd.
    A seam curve counts twice: gmsh lists it twice among the face's boundary curves."""
    segments: dict[int, int] = {}  # curve -> its 1D elements, asked once (two faces share most curves)
    out = np.zeros(len(surfaces), dtype=np.int64)
    for i, s in enumerate(surfaces):
        for _, c in g.model.getBoundary([(2, s)], combined=False, oriented=False):
            c = abs(c)
            if c not in segments:
                segments[c] = sum(len(t) for t in g.model.mesh.getElements(1, c)[1])
            out[i] += segments[c]
    return out


def _set_sizes(g, sess: GmshSession, kw: dict, size: float, scale: float) -> None:
    """gmsh's sizes for ``mesh_cad``: the largest element ``size``, the curvature rule, the
    size callback and the background field, every size times ``scale`` (2 before the all-quad
    subdivision, which halves them)."""
    n = kw["curvature_elements"]
    apply_options(sess, {
        "Mesh.MeshSizeMax": scale * size,
        # curvature sizing refines at most 20 x below the size (a pole or a sliver face
        # of tiny radius would otherwise ask for elements without end)
        "Mesh.MeshSizeMin": scale * min(size / 20.0, kw["min_size"] or math.inf) if n else 0.0,
        # elements per 2 pi of the normal's turn: size 2 pi R / n
        "Mesh.MeshSizeFromCurvature": math.ceil(n / scale) if n else 0,
    })
    if kw["size_callback"] is not None:
        cb = kw["size_callback"]
        g.model.mesh.setSizeCallback(cb if scale == 1.0 else
                                     (lambda dim, tag, x, y, z, lc: scale * cb(dim, tag, x, y, z, lc / scale)))
    if kw["background_sizes"] is not None:
        _background_field(g, sess, kw["background_sizes"], scale)


def _narrow_face_curves(g, surfaces: list[int], kw: dict, size: float, scale: float) -> None:
    """Uniform node counts on the curved boundary curves of narrow faces, whose chords at
    gmsh's sizes (times ``scale``) would cut the face (`cadbridge.mesh.gmsh.narrow_faces`).
    Not with a size callback, whose sizes along a curve are not known before gmsh asks (a
    uniform count could then be coarser than the callback's)."""
    from cadbridge.mesh.gmsh.narrow_faces import narrow_curve_counts

    if kw["size_callback"] is not None:
        return

    n = kw["curvature_elements"]
    size_at = _size_at(kw)
    counts = narrow_curve_counts(
        g, surfaces, size=scale * size, curvature_elements=math.ceil(n / scale) if n else 0,
        min_size=scale * min(size / 20.0, kw["min_size"] or math.inf),
        size_at=None if size_at is None else (lambda x: scale * size_at(x)),
        cache=kw.setdefault("narrow_cache", {}), even=kw["element"] == "quad" and scale == 1.0,
    )
    for c, m in counts.items():
        g.model.mesh.setTransfiniteCurve(c, m + 1)


def _wound_against_surface(g, mesh: Mesh, s: int) -> bool:
    """True if an element of gmsh surface ``s`` is wound against the surface: its polygon's
    normal and gmsh's surface normal at its centroid's (u, v) more than 90 degrees apart,
    where most of the surface's elements agree with it. A pair of neighbours more than
    `FOLD_DEG` apart can also be the CAD's own turn (FTR00131 of the production die: a band
    0.02 mm wide whose normal turns 180 degrees), which a mesh in (u, v) cannot change; only
    an element laid over its neighbours is a fold the (u, v) fill repairs."""
    ent = np.asarray(mesh.cell_data["element_entity"])
    x = mesh.nodes
    # the (u, v) of the surface's own nodes, as gmsh placed them (matched by coordinates: the
    # same numbers); an element of those nodes only takes their mean, the others (on the
    # surface's curves, whose (u, v) gmsh keeps on the curve) gmsh's inversion of the
    # centroid, which costs ~1 ms a point on a long B-spline face (Inventor's spring: 19 s)
    _, sx, suv = g.model.mesh.getNodes(2, s, includeBoundary=False, returnParametricCoord=True)
    sx = np.asarray(sx, dtype=float).reshape(-1, 3)
    suv = np.asarray(suv, dtype=float)
    node_uv = np.full((len(x), 2), np.nan)
    if len(sx) and suv.size == 2 * len(sx):
        from scipy.spatial import cKDTree

        d, i = cKDTree(x).query(sx)
        node_uv[i[d == 0.0]] = suv.reshape(-1, 2)[d == 0.0]
    dots = []
    first = 0
    for b in mesh.cells:
        c = np.asarray(b.data)
        on = np.flatnonzero(ent[first:first + len(c)] == s)
        first += len(c)
        if not len(on):
            continue
        c = c[on]
        n = _polygon_normals(x, c)
        uv = node_uv[c].mean(axis=1)  # (E, 2): NaN where a node is not the surface's own
        far = np.flatnonzero(np.isnan(uv[:, 0]))
        if len(far):
            uv[far] = np.asarray(g.model.getParametrization(2, s, x[c[far]].mean(axis=1).ravel().tolist()),
                                 dtype=float).reshape(-1, 2)  # centroids' (u, v)
        sn = np.asarray(g.model.getNormal(s, uv.ravel().tolist()), dtype=float).reshape(-1, 3)
        dots.append(np.einsum("ij,ij->i", n, sn))
    if not dots:
        return False
    d = np.concatenate(dots)
    major = 1.0 if np.sum(d > 0) >= np.sum(d < 0) else -1.0  # gmsh's winding of the surface
    return bool(np.any(major * d < 0))


def _algorithm(kw: dict) -> int:
    """gmsh's 2D algorithm `_mesh_in_session` sets for ``kw["element"]``."""
    return 5 if kw["element"] == "quad" else 6


def _vertex_nodes(g, mesh: Mesh) -> np.ndarray:
    """Indices (A,) of ``mesh``'s nodes at gmsh points (CAD vertices: the nodes gmsh
    classifies on dimension 0, found by their coordinates, which are the same numbers)."""
    _, xyz, _ = g.model.mesh.getNodes(0, -1)
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    if not len(xyz) or not len(mesh.nodes):
        return np.zeros(0, dtype=np.int64)
    from scipy.spatial import cKDTree

    d, i = cKDTree(mesh.nodes).query(xyz)
    return np.unique(i[d == 0.0]).astype(np.int64)


def _exact_curve_nodes(g, mesh: Mesh, diag: float) -> None:
    """Move the nodes gmsh put on curves onto S(c(t)): the curve parameter t of each node
    through the pcurve c of the curve on a surface next to it (gmsh's
    ``reparametrizeOnSurface``, OCC's pcurve), evaluated on that surface. Where an edge's 3D
    curve approximates S(c(t)) (a B-rep built from pcurves, `cadbridge.heal.brep`) its nodes
    lay up to that approximation's tolerance off the surface; now on it to rounding. A node
    moves only where the mesh holds a node at gmsh's position (found by its exact
    coordinates: the mesh drops gmsh's unused nodes), by at most 1e-6 x ``diag``."""
    nodes = mesh.nodes
    keys = _row_keys(nodes)  # exact coordinates -> mesh node, by a sorted search
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    for _, c in g.model.getEntities(1):  # loop over curves, vectorised over their nodes
        _, cx, ts = g.model.mesh.getNodes(1, c, includeBoundary=False, returnParametricCoord=True)
        up, _ = g.model.getAdjacencies(1, c)
        if len(ts) == 0 or len(up) == 0:
            continue
        try:
            uv = g.model.reparametrizeOnSurface(1, c, list(ts), int(up[0]))
        except Exception:  # noqa: BLE001 - gmsh raises a bare Exception where it cannot: keep gmsh's nodes
            continue
        x = np.asarray(g.model.getValue(2, int(up[0]), list(uv)), dtype=float).reshape(-1, 3)
        old = np.asarray(cx, dtype=float).reshape(-1, 3)
        q = _row_keys(old)
        j = np.minimum(np.searchsorted(sorted_keys, q), len(order) - 1)
        ok = (sorted_keys[j] == q) & (np.linalg.norm(x - old, axis=1) <= 1e-6 * diag)
        nodes[order[j[ok]]] = x[ok]


def _row_keys(points: np.ndarray) -> np.ndarray:
    """One opaque key per row of ``points`` (N, 3) equal exactly where the coordinates are
    bit-identical (a void view of the row's bytes), for sorting and searching, (N,)."""
    a = np.ascontiguousarray(points, dtype=np.float64)
    return a.view(np.dtype((np.void, a.dtype.itemsize * a.shape[1]))).ravel()


def _one_segment_straight_splines(g, size: float) -> None:
    """One segment on every straight curve shorter than ``size`` that OCC does not hold as a
    line (a B-spline edge of `cadbridge.heal.brep`, its 3D curve built from the trim's
    pcurve): gmsh meshes an OCC line shorter than the size with one segment but any other
    curve with two at least (``Mesh.MinimumCurveNodes``), so a model read by OCC's IGES
    reader (lines as lines) and the same model as cadbridge's B-rep mesh alike."""
    for _, c in g.model.getEntities(1):  # loop over curves: a few curvature samples each
        if g.model.getType(1, c) == "Line":
            continue
        kind, _, length = _curve_shape(g, c)
        if kind == "line" and length < size:
            g.model.mesh.setTransfiniteCurve(c, 2)


def _one_segment_short_curves(g, shorter: float, skip: set[int]) -> None:
    """One segment on every curve shorter than ``shorter`` (model units), but those in
    ``skip``, before gmsh's all-quad subdivision halves it. gmsh gives any curve at least two
    segments (``Mesh.MinimumCurveNodes``), so the subdivision would put a 0.023 mm edge of the
    production die in four steps of 0.006 mm, below the node merge tolerance (7e-3 mm there):
    the merge then joined the whole chain and the elements beside it into one node and left
    non-manifold edges. With one segment the step is half the curve, as in tri mode."""
    for _, c in g.model.getEntities(1):  # loop over curves: one OCC length each
        if c not in skip and g.model.occ.getMass(1, c) < shorter:
            g.model.mesh.setTransfiniteCurve(c, 2)


def _background_field(g, sess: GmshSession, sizes, scale: float = 1.0) -> None:
    """The background size field of ``mesh_cad``'s ``background_sizes`` (points (M, 3), sizes
    (M,)), times ``scale``: a list-based view of scalar points behind a PostView field (the
    size of the nearest point)."""
    bp, bh = (np.asarray(a, dtype=float) for a in sizes)
    view = g.view.add("cadbridge-sizes")
    sess.views.append(view)
    g.view.addListData(view, "SP", len(bh), np.column_stack([bp.reshape(-1, 3), scale * bh.ravel()]).ravel().tolist())
    fld = g.model.mesh.field.add("PostView")
    g.model.mesh.field.setNumber(fld, "ViewTag", view)
    g.model.mesh.field.setAsBackgroundMesh(fld)


def _curve_need(g, c: int, curve_size, samples: int = 65) -> float:
    """Elements curve ``c`` needs under ``curve_size``: the integral of ds / h over its
    polygon; where ``curve_size`` returns a pair (h, h_uniform), the larger of that and the
    length over the smallest h_uniform (a request that must hold all along the side, which is
    divided uniformly)."""
    lo, hi = g.model.getParametrizationBounds(1, c)
    ts = np.linspace(lo[0], hi[0], samples)
    x = np.asarray(g.model.getValue(1, c, ts), dtype=float).reshape(-1, 3)
    k = np.abs(np.asarray(g.model.getCurvature(1, c, ts), dtype=float))
    ds = np.linalg.norm(np.diff(x, axis=0), axis=1)
    h = curve_size(0.5 * (x[1:] + x[:-1]), np.maximum(k[1:], k[:-1]))
    if isinstance(h, tuple):
        h, hu = (np.asarray(a, dtype=float) for a in h)
        return float(max(np.sum(ds / h), np.sum(ds) / np.min(hu)))
    return float(np.sum(ds / np.asarray(h, dtype=float)))


def _generate(g, surfaces: list[int], kw: dict) -> dict[int, str]:
    """gmsh's 2D meshing, going on past a surface it cannot mesh: {failed surface: gmsh's error}
    (`cadbridge.mesh.gmsh.empty_faces.generate_surfaces`; those surfaces are then filled), and
    ``kw["skip"]``'s surfaces (gmsh stalled or crashed on them in an earlier attempt) left to
    the fill too."""
    from cadbridge.mesh.gmsh.empty_faces import generate_surfaces

    if g.option.getNumber("Mesh.SubdivisionAlgorithm") != 1:
        return generate_surfaces(g, surfaces, kw.get("skip"))
    # the all-quad subdivision made here (`cadbridge.mesh.gmsh.subdivide`), gmsh's needing an
    # OCC projector per new node: production die 7.3 -> 3.5 s
    from cadbridge.mesh.gmsh.subdivide import subdivide_to_quads

    g.option.setNumber("Mesh.SubdivisionAlgorithm", 0)
    try:
        failed = generate_surfaces(g, surfaces, kw.get("skip"))
    finally:
        g.option.setNumber("Mesh.SubdivisionAlgorithm", 1)
    if not subdivide_to_quads(g):
        g.model.mesh.refine()  # gmsh's own (nodes without parameters)
    return failed


def _fill_empty(g, surfaces: list[int], size: float, kw: dict, path: Path, subdivided: bool,
                failed: dict[int, str] | None = None) -> list[str]:
    """Mesh the surfaces gmsh left without elements ourselves (`cadbridge.mesh.gmsh.empty_faces`:
    in their (u, v) on gmsh's boundary nodes), and those holding a trim-loop excursion, less
    its nodes (`cadbridge.mesh.gmsh.loop_cuts`); one note per face."""
    from cadbridge.mesh.gmsh import loop_cuts
    from cadbridge.mesh.gmsh.empty_faces import fill_empty_faces

    cuts = {}
    if kw.get("loop_cuts"):
        bb = np.array(g.model.getBoundingBox(-1, -1), dtype=float)
        cuts = loop_cuts.surfaces_with_excursions(g, kw["loop_cuts"], surfaces, 1e-6 * float(np.linalg.norm(bb[3:] - bb[:3])))
        loop_cuts.clear(g, cuts)
    return fill_empty_faces(g, surfaces, size=size, curvature_elements=kw["curvature_elements"],
                            element=kw["element"], subdivided=subdivided, label=str(path), cuts=cuts,
                            failed=failed, merge_tolerance=_merge_tolerance(size, subdivided),
                            size_at=_size_at(kw))


def _size_at(kw: dict):
    """``size_at(xyz (N, 3)) -> (N,)``: the target size of ``kw["background_sizes"]`` at
    points, as gmsh reads that field (the size of the nearest carrier), for the faces
    cadbridge fills itself; None without a background field. The carriers' tree is built on
    the first call only (most meshes fill no face; the die's field has ~10^6 carriers)."""
    if kw.get("background_sizes") is None:
        return None
    from scipy.spatial import cKDTree

    bp, bh = (np.asarray(a, dtype=float) for a in kw["background_sizes"])
    tree: list = []

    def size_at(x):
        if not tree:
            tree.append(cKDTree(bp.reshape(-1, 3)))
        return bh.ravel()[tree[0].query(np.asarray(x, dtype=float).reshape(-1, 3))[1]]

    return size_at


def _merge_tolerance(size: float, subdivided: bool) -> float:
    """The distance (model units) below which `mesh_cad` merges nodes: MERGE_TOLERANCE x size,
    halved after the all-quad subdivision, which halves every distance of the mesh it splits
    (made at twice the size): the same node pairs as that mesh's merge (on the production die
    the subdivision put the midpoints of two needle triangles on 0.0077 and 0.0123 mm CAD edges
    0.0038 and 0.0062 mm apart; merged at 0.0072 mm they folded the elements there into
    non-manifold edges). The tiny-face fill (`empty_faces._fill_tiny_face`) uses the same."""
    return MERGE_TOLERANCE * size * (0.5 if subdivided else 1.0)


def _check_all_meshed(g, surfaces: list[int], path: Path) -> None:
    """Raise `MeshError` naming the surfaces gmsh left without elements.

    gmsh gives up on a surface whose boundary it cannot recover in parameter space ("No
    elements in surface ...", a warning only), e.g. the long helical wire faces of the
    Inventor spring; a tool without them would silently lack part of the CAD."""
    empty = [s for s in surfaces if not any(len(t) for t in g.model.mesh.getElements(2, s)[1])]
    if not empty:
        return
    parts = []
    for s in empty[:5]:
        bb = np.asarray(g.model.getBoundingBox(2, s), dtype=float)
        area = g.model.occ.getMass(2, s) if g.model.getType(2, s) else float("nan")
        parts.append(f"{s} ({g.model.getType(2, s)}, area {area:.4g}, box ({bb[0]:.4g}, {bb[1]:.4g}, {bb[2]:.4g})"
                     f"-({bb[3]:.4g}, {bb[4]:.4g}, {bb[5]:.4g}))")
    more = f" and {len(empty) - 5} more" if len(empty) > 5 else ""
    raise MeshError(f"{path}: gmsh left {len(empty)} of {len(surfaces)} surfaces without elements (it could not "
                    f"recover their boundary in parameter space): gmsh surface {', '.join(parts)}{more}; "
                    f"try another --size, or mesh the CAD elsewhere and run `cadbridge nagata MESH --cad CAD`")


def _add_bspline(g, c) -> int:
    """gmsh OCC tag of a new B-spline curve with the poles, weights and knots of ``c``."""
    knots, mult = np.unique(c.knots, return_counts=True)
    pts = [g.model.occ.addPoint(*map(float, x)) for x in c.control_points]
    return g.model.occ.addBSpline(pts, degree=int(c.degree), weights=[float(w) for w in c.weights],
                                  knots=knots.tolist(), multiplicities=mult.tolist())


def _known_hosts(g, embed_faces, anchors) -> list[int | None] | None:
    """gmsh surface tag of each embedded curve's model face (`mesh_cad`'s ``embed_faces``),
    None where the face is not known or its anchor is not on the surface at the same (u, v)."""
    if embed_faces is None or anchors is None:
        return None
    anchors = np.asarray(anchors, dtype=float).reshape(len(anchors), -1)
    surf = [t for _, t in g.model.getEntities(2)]
    if len(surf) != len(anchors):
        return None  # the import split or dropped faces: no face-by-face correspondence
    bb = np.array(g.model.getBoundingBox(-1, -1), dtype=float)
    tol = 1e-9 * float(np.linalg.norm(bb[3:] - bb[:3]))
    tags: list[int | None] = []
    for k in embed_faces:  # loop over the (few) embedded curves
        if k is None or not 0 <= int(k) < len(surf):
            tags.append(None)
            continue
        t = surf[int(k)]
        x = np.asarray(g.model.getValue(2, t, anchors[int(k), :2].tolist()), dtype=float)
        tags.append(t if float(np.linalg.norm(x - anchors[int(k), 2:5])) <= tol else None)
    return tags


def _model_faces(g, ent: np.ndarray, anchors) -> np.ndarray:
    """(E,) the model face (index) of each element, meshed on gmsh surface ``ent`` (E,), where
    the file is the model itself
    (`cadbridge.heal.brep`; ``anchors`` its (F, 9) `ModelBrep.anchors`): the face on the same
    surface (gmsh's S at the face's anchor (u, v) is the anchor's point, within 1e-9 x the
    model's size) whose (u, v) box holds the largest share of the gmsh surface's (faces split
    by embedded curves keep their model face; the halves of a cylinder share one surface and
    split its (u, v)). -1 on a surface with no such face, or two equally good. Tags follow
    every import, sewing and fragment of the session, since they are matched by geometry at
    the end."""
    out = np.full(int(ent.max()) + 1 if len(ent) else 1, -1, dtype=np.int64)  # gmsh tag -> model face
    anchors = np.asarray(anchors, dtype=float).reshape(len(anchors), -1)
    if anchors.shape[1] < 9 or not len(anchors):
        return out[ent]
    bb = np.array(g.model.getBoundingBox(-1, -1), dtype=float)
    tol = 1e-9 * float(np.linalg.norm(bb[3:] - bb[:3]))
    u0, u1, v0, v1 = anchors[:, 5], anchors[:, 6], anchors[:, 7], anchors[:, 8]
    for s in np.unique(ent):  # loop over surfaces, vectorised over the model's faces
        lo, hi = g.model.getParametrizationBounds(2, int(s))
        du = np.minimum(u1, hi[0]) - np.maximum(u0, lo[0])
        dv = np.minimum(v1, hi[1]) - np.maximum(v0, lo[1])
        area = max((hi[0] - lo[0]) * (hi[1] - lo[1]), 1e-300)
        share = np.where((du >= 0) & (dv >= 0), np.maximum(du, 0) * np.maximum(dv, 0) / area, -1.0)
        cand = np.flatnonzero(share >= 0)
        if not len(cand):
            continue
        x = np.asarray(g.model.getValue(2, int(s), anchors[cand, :2].ravel().tolist()), dtype=float).reshape(-1, 3)
        cand = cand[np.linalg.norm(x - anchors[cand, 2:5], axis=1) <= tol]
        if len(cand) == 1 or (len(cand) > 1 and np.sort(share[cand])[-2] < share[cand].max()):
            out[s] = cand[np.argmax(share[cand])]
    return out[ent]


def _embed_curves(g, curves: list, path: Path, known: list[int | None] | None = None) -> None:
    """Fragment the surfaces with the curves lying on them, so mesh edges follow the curves.
    ``known``: the host surface of each curve where it is known (`_known_hosts`), else
    found by probing 7 of the curve's points."""
    bb_all = np.array(g.model.getBoundingBox(-1, -1), dtype=float)
    tol = 1e-7 * float(np.linalg.norm(bb_all[3:] - bb_all[:3]))
    surf = [t for _, t in g.model.getEntities(2)]
    boxes = np.array([g.model.getBoundingBox(2, t) for t in surf], dtype=float).reshape(-1, 6)
    hosts: set[int] = set()
    tools = []
    for i, c in enumerate(curves):  # loop over the (few) crease curves
        t0, t1 = c.domain
        if known is not None and known[i] is not None:
            hosts.add(int(known[i]))
            tools.append((1, _add_bspline(g, c)))
            continue
        probe = c.evaluate(np.linspace(t0, t1, 9)[1:-1])  # (7, 3) interior points
        inbox = np.all((probe.min(0) >= boxes[:, :3] - 10 * tol) & (probe.max(0) <= boxes[:, 3:] + 10 * tol), axis=1)
        found = []
        for s in np.asarray(surf)[inbox]:
            cp = np.asarray(g.model.getClosestPoint(2, int(s), probe.ravel())[0], dtype=float).reshape(-1, 3)
            if np.any(np.linalg.norm(cp - probe, axis=1) <= tol):  # a piece of the curve lies on s
                found.append(int(s))
        if not found:
            raise MeshError(f"{path}: a crease curve (from {probe[0].tolist()}) lies on no gmsh surface")
        hosts.update(found)
        tools.append((1, _add_bspline(g, c)))
    # the hosts' neighbours go into the fuse too: where a curve ends on a host's boundary
    # (within tolerance of a corner or an edge), OCC's fuse rebuilds that vertex and the host's
    # edges there, and a neighbour left out keeps the old ones, so the two no longer share
    # them (the production die: 28 doubled corners, 112 edges meshed twice and merged node by
    # node afterwards, which in quad left 25 non-manifold edges; tests/mesh/test_crease_sewing.py)
    near = set(hosts)
    for s in hosts:
        for _, c in g.model.getBoundary([(2, s)], combined=False, oriented=False):
            near.update(int(t) for t in g.model.getAdjacencies(1, abs(c))[0])
    g.model.occ.fragment([(2, s) for s in sorted(near)], tools)
    g.model.occ.synchronize()
    # curve pieces outside every face (beyond trims) would be meshed as free edges: drop them
    free = [(1, t) for _, t in g.model.getEntities(1) if len(g.model.getAdjacencies(1, t)[0]) == 0]
    if free:
        g.model.occ.remove(free, recursive=True)
        g.model.occ.synchronize()


def _collect(g, surfaces: list[int], parametric: bool, path: Path) -> Mesh:
    tags, xyz, _ = g.model.mesh.getNodes()
    tags = np.asarray(tags, dtype=np.int64)
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    if tags.size == 0:
        raise MeshError(f"{path}: gmsh produced no nodes")
    index = np.full(int(tags.max()) + 1, -1, dtype=np.int64)
    index[tags] = np.arange(tags.size)
    tri, quad, tri_ent, quad_ent = [], [], [], []
    for s in surfaces:
        etypes, _, enodes = g.model.mesh.getElements(2, s)
        for et, en in zip(etypes, enodes):
            en = np.asarray(en, dtype=np.int64)
            if et == 2:
                t = index[en].reshape(-1, 3)
                # a triangle with two corners on one node (gmsh, at the collapsed edge of a face
                # closed around a pole, imported unsewn) has no area and its two other edges are
                # one: dropped, as `cadbridge.mesh.cleanup.merge_close_nodes` drops those it makes
                t = t[(t[:, 0] != t[:, 1]) & (t[:, 1] != t[:, 2]) & (t[:, 2] != t[:, 0])]
                tri.append(t)
                tri_ent.append(np.full(len(t), s, dtype=np.int64))
            elif et == 3:
                from cadbridge.mesh.cleanup import collapsed_quads

                q = index[en].reshape(-1, 4)
                # a quad with two adjacent corners on one node (gmsh, at a pole: [a, p, p, b]) is
                # the triangle of its other three, as `merge_close_nodes` makes it; with more
                # repeats it has no area (hemisphere_pole at size 1.4995 left one of each kind)
                t, _ = collapsed_quads(q)
                if len(t):
                    tri.append(t)
                    tri_ent.append(np.full(len(t), s, dtype=np.int64))
                q = q[np.all(np.diff(np.sort(q, axis=1), axis=1) != 0, axis=1)]
                quad.append(q)
                quad_ent.append(np.full(len(q), s, dtype=np.int64))
            else:
                name = g.model.mesh.getElementProperties(et)[0]
                raise MeshError(f"{path}: gmsh produced unsupported element type {name!r} on surface {s}")
    blocks, ent = [], []
    if tri:
        blocks.append(CellBlock("triangle", np.concatenate(tri)))
        ent += tri_ent
    if quad:
        blocks.append(CellBlock("quad", np.concatenate(quad)))
        ent += quad_ent
    if not blocks:
        raise MeshError(f"{path}: gmsh produced no surface elements")
    pd: dict[str, np.ndarray] = {}
    if parametric:
        node_entity = np.full(tags.size, -1, dtype=np.int64)
        node_uv = np.full((tags.size, 2), np.nan)
        for s in sorted(surfaces):  # lowest surface tag wins on shared curves
            st, sx, uv = g.model.mesh.getNodes(2, s, includeBoundary=True, returnParametricCoord=True)
            st = np.asarray(st, dtype=np.int64)
            uv = np.asarray(uv, dtype=np.float64)
            if st.size == 0:
                continue
            if uv.size != 2 * st.size:
                # gmsh keeps no (u, v) for some nodes (e.g. after quad subdivision): invert the
                # surface parametrisation at the node coordinates instead.
                uv = np.asarray(g.model.getParametrization(2, s, np.asarray(sx, dtype=float)), dtype=float)
            i = index[st]
            new = node_entity[i] < 0
            node_entity[i[new]] = s
            node_uv[i[new]] = uv.reshape(-1, 2)[new]
        pd = {"node_entity": node_entity, "node_uv": node_uv}
    m = Mesh(xyz, blocks, point_data=pd, cell_data={"element_entity": np.concatenate(ent)}, name=path.stem)
    return m.remove_unused_nodes()[0]
