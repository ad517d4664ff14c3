"""Refine instead of refuse: where the soundness guards of `cadbridge.tool.build` trip
(elements that straddle a crease, elements over which the CAD normal reverses), mesh again
with a local size field that is finer there, a few rounds at most.

One round of `refine_where_guards_trip`:

1. **Marks.** Every element that trips (`GuardTrips.refinable`) asks for a new size:
   `TURN_PER_ELEMENT` / k, k the largest principal curvature of the CAD over the element
   (`turn_curvature`: an element over a tight turn has its corners on the flat sides and the
   turn between them), 30 degrees of the turn per element as convert's curvature rule asks
   (12 per full turn): gmsh's quads come out up to ~1.7 x the size asked, so asking for
   MAX_TURN = 60 degrees, the limit of the Nagata error law (`cadbridge.mesh.sizing`), left
   elements over 120 degrees on a 130-degree turn; at most half its longest edge h, at least
   h / 64 (`MIN_FACTOR`) per round, so that a tight turn gets the size it needs in one
   round. The size holds over a ball about the element of radius its reach plus that size
   (`cadbridge.mesh.sizing.ball_marks`: the nodes gmsh makes there read it). Marks add up
   over the rounds.
2. **Field.** The first mesh's nodes, each with the mean length of its edges there (the
   sizes gmsh chose by its own rules: ``size`` and the curvature rule), and the marks; the
   field is their graded minimum (`cadbridge.mesh.sizing.SizeField`, `GRADATION` 0.3), so the
   smaller size wins and the sizes grow smoothly away from the marks, read at the nodes, the
   marks and balls of growing radius about the marked elements (`grading_carriers`: gmsh
   takes the size of the nearest carrier). gmsh gets it as ``background_sizes`` with the
   curvature rule off: gmsh clamps every size, the field's too, to the curvature rule's
   floor (``Mesh.MeshSizeMin`` = size / 20), which is what the marks must go below on a
   tight radius; the first mesh's sizes already hold that rule.
3. **Mesh and check** again (the caller's ``remesh`` and ``build``).

Triangles (``keep_first``): the first mesh is kept wherever the marks ask for nothing finer.
Only the curves and surfaces where the marks, graded at `GRADATION`, ask for elements finer
than the first mesh's, and the surfaces those curves bound, are meshed again
(`cadbridge.mesh.gmsh.kept`), by the first mesh's own rules (``size`` and the curvature rule)
and the graded marks alone (`sizes_keeping_first`), their floor below the curvature rule's: the kept
curves where they meet the rest were made by the same rules, so the sizes agree there. A
round for 2 straddling elements of a 415-face STEP part (trj8_b1) re-meshed all of it with
the field of step 2 and doubled its nodes, 35 732 -> 67 639; now 27 of its 422 gmsh surfaces
are meshed again. Quads (gmsh's all-quad subdivision makes the whole mesh at once) take the
field of step 2 over the whole model.

The loop stops when no element trips (converged); when a round leaves as many elements
tripping as before or more (refinement does not cure them: a crease or seam the mesh does not
follow trips along its length, more elements the finer the mesh; a degenerate element; the
mesh before that round stands); after ``rounds`` rounds; or when a round's mesh or
projection fails (the round before stands). Lengths in model units.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from cadbridge.common.progress import NoProgress
from cadbridge.mesh.mesh import Mesh
from cadbridge.tool.build import ToolResult

__all__ = ["GUARD_ROUNDS", "GRADATION", "MIN_FACTOR", "TURN_PER_ELEMENT", "GuardRefinement", "node_sizes",
           "refine_where_guards_trip", "sizes_keeping_first", "trip_marks"]

GUARD_ROUNDS = 3
"""Rounds of refinement at most before the guards' message stands."""
GRADATION = 0.3
"""How fast the local field grows away from a mark (an element next to one of size h: 1.3 h).
Below the 0.5 of `cadbridge.mesh.sizing`: the two sides beside a tight turn part at about
2 sin(a / 2) per unit length (a: the angle between them, 0.85 at a turn of 130 degrees), and
elements growing faster than that bridge them."""
TURN_PER_ELEMENT = np.pi / 6
"""The turn of the normal [rad] a mark asks each new element to span at most (module docs)."""
MIN_FACTOR = 1.0 / 64.0
"""The smallest factor on an element's size in one round (a turn of radius 1e-5 x model size,
the fold radius of `cadbridge.heal.folds`, in an element of the curvature rule's floor, model
size / 400, asks for 1 / 40)."""


@dataclass
class GuardRefinement:
    """The outcome of `refine_where_guards_trip`: the last mesh and its tools, the rounds made,
    whether no element trips any more, and one summary line per round."""

    mesh: Mesh
    tools: list[ToolResult]
    mesh_notes: list[str]
    rounds: int = 0
    converged: bool = True
    notes: list[str] = field(default_factory=list)
    failed_round: str = ""  # why the last round tried gave no mesh to check, if it did not

    @property
    def failure(self) -> str:
        """What the refinement did, for the guards' message where it did not converge: "after N
        refinement rounds" (and why the round after them failed); "" with no round tried."""
        done = f"after {self.rounds} refinement round{'' if self.rounds == 1 else 's'}" if self.rounds else ""
        if not self.failed_round:
            return done
        failed = f"refinement round {self.rounds + 1} failed: {self.failed_round}"
        return f"{done}; {failed}" if done else failed


def _tripping(tools: list[ToolResult]) -> int:
    return sum(len(t.trips.refinable) for t in tools if t.trips is not None)


def _longest_edges(nm, ids: np.ndarray) -> np.ndarray:
    """Longest edge (K,) [length] of the elements ``ids`` (K,) of the `NagataMesh` ``nm``."""
    h = np.zeros(len(ids))
    kind, local = nm.element_kind[ids], nm.element_local[ids]
    for k, conn in ((3, nm.tri_elements), (4, nm.quad_elements)):
        sel = np.flatnonzero(kind == k)
        if len(sel):
            x = nm.nodes[conn[local[sel]]]  # (S, k, 3)
            h[sel] = np.linalg.norm(np.roll(x, -1, axis=1) - x, axis=2).max(axis=1)
    return h


def _box_samples(lo: float, hi: float, knots: np.ndarray, samples: int) -> np.ndarray:
    """Parameters over [lo, hi]: ``samples`` evenly, the knots inside and the middle of every
    knot span between them (a tight turn lies within a few spans: these find it however
    small it is against the box)."""
    k = np.unique(knots[(knots > lo) & (knots < hi)])
    ends = np.concatenate([[lo], k, [hi]])
    return np.unique(np.concatenate([np.linspace(lo, hi, samples), k, 0.5 * (ends[1:] + ends[:-1])]))


def turn_curvature(nm, ids: np.ndarray, faces: np.ndarray, model, samples: int = 9) -> np.ndarray:
    """Largest |principal curvature| (K,) [1/length] of the CAD over each element ``ids`` (K,)
    of the `NagataMesh` ``nm``: over the (u, v) box of its corners' feet on its face ``faces``
    (K,), on a grid of ``samples`` parameters per direction plus the knots inside the box and
    the middles of their spans (`_box_samples`); an element that spans a tight turn has its
    corners on the flat sides and the turn between them. 0 where no curvature is finite."""
    from cadbridge.nurbs.curvature import principal_curvatures
    from cadbridge.nurbs.project import project_to_surface

    out = np.zeros(len(ids))
    kind, local = nm.element_kind[ids], nm.element_local[ids]
    for f in np.unique(faces):  # loop over faces, vectorised over their elements' samples
        if f < 0:
            continue
        s = model.faces[int(f)].surface
        sel = np.flatnonzero(faces == f)
        uv = np.zeros((len(sel), 4))  # the (u, v) box of each element's corners
        for k, conn in ((3, nm.tri_elements), (4, nm.quad_elements)):
            on = np.flatnonzero(kind[sel] == k)
            if len(on):
                pr = project_to_surface(s, nm.nodes[conn[local[sel[on]]]].reshape(-1, 3))
                u, v = pr.u.reshape(len(on), k), pr.v.reshape(len(on), k)
                uv[on] = np.column_stack([u.min(axis=1), u.max(axis=1), v.min(axis=1), v.max(axis=1)])
        grids = [np.meshgrid(_box_samples(a, b, s.knots_u, samples), _box_samples(c, d, s.knots_v, samples),
                             indexing="ij") for a, b, c, d in uv]  # loop over the few tripping elements
        owner = np.concatenate([np.full(g[0].size, i) for i, g in enumerate(grids)])
        k1, k2 = principal_curvatures(s, np.concatenate([g[0].ravel() for g in grids]),
                                      np.concatenate([g[1].ravel() for g in grids]))
        kmax = np.maximum(np.abs(k1), np.abs(k2))
        best = np.zeros(len(sel))
        np.maximum.at(best, owner, np.where(np.isfinite(kmax), kmax, 0.0))
        out[sel] = best
    return out


def _span_samples(lo: float, hi: float, knots: np.ndarray, per_span: int) -> np.ndarray:
    """``per_span`` + 1 parameters over every knot span inside [lo, hi] (ends included)."""
    k = np.unique(np.concatenate([[lo, hi], knots[(knots > lo) & (knots < hi)]]))
    t = np.linspace(0.0, 1.0, per_span + 1)[:-1]
    return np.concatenate([(k[:-1, None] + np.diff(k)[:, None] * t[None]).ravel(), [hi]])


def turn_region(surface, curvature: float, size: float, per_span: int = 4, cap: int = 2_000_000) -> np.ndarray:
    """Points (M, 3) on ``surface`` no farther apart than ``size`` [length] over the whole
    region where its largest |principal curvature| reaches half ``curvature`` [1/length]:
    a tight turn found at a few tripping elements runs on along the face, and the next mesh
    spans it wherever it is left coarse. The region: the cells of a grid of ``per_span``
    parameters per knot span whose centre has that curvature; each such cell is sampled
    finer, to ``size`` along both its sides (at most ``cap`` points in all: beyond that the
    marks stay at the tripping elements)."""
    from cadbridge.nurbs.curvature import principal_curvatures

    u0, u1, v0, v1 = surface.domain
    uu = _span_samples(u0, u1, surface.knots_u, per_span)
    vv = _span_samples(v0, v1, surface.knots_v, per_span)
    U, V = np.meshgrid(uu, vv, indexing="ij")
    cu, cv = np.meshgrid(0.5 * (uu[1:] + uu[:-1]), 0.5 * (vv[1:] + vv[:-1]), indexing="ij")  # cell centres
    k1, k2 = principal_curvatures(surface, cu.ravel(), cv.ravel())
    k = np.nan_to_num(np.maximum(np.abs(k1), np.abs(k2)), nan=0.0).reshape(cu.shape)
    ci, cj = np.nonzero(k >= 0.5 * curvature)  # (not by corners: a corner on the knot that ends a
    if not len(ci):                             # turn's span would take in the flat span beside it)
        return np.zeros((0, 3))
    x = surface.evaluate(U.ravel(), V.ravel()).reshape(U.shape + (3,))
    along_u = np.maximum(np.linalg.norm(x[ci + 1, cj] - x[ci, cj], axis=1), np.linalg.norm(x[ci + 1, cj + 1] - x[ci, cj + 1], axis=1))
    along_v = np.maximum(np.linalg.norm(x[ci, cj + 1] - x[ci, cj], axis=1), np.linalg.norm(x[ci + 1, cj + 1] - x[ci + 1, cj], axis=1))
    nu = np.ceil(along_u / size).astype(np.int64) + 1  # chords: the arc between samples is longer only where it turns
    nv = np.ceil(along_v / size).astype(np.int64) + 1
    if int(np.sum(nu * nv)) > cap:
        return np.zeros((0, 3))
    pu, pv = [], []
    for i, j, a, b in zip(ci, cj, nu, nv):  # loop over the region's cells (a turn: a strip of them)
        su, sv = np.meshgrid(np.linspace(uu[i], uu[i + 1], a), np.linspace(vv[j], vv[j + 1], b), indexing="ij")
        pu.append(su.ravel())
        pv.append(sv.ravel())
    return surface.evaluate(np.concatenate(pu), np.concatenate(pv))


def trip_marks(tools: list[ToolResult], model) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Refinement marks (points (M, 3), sizes (M,)) at the elements of ``tools`` that trip the
    guards and at those that come near (module docs, step 1), the centroids (K, 3) of those
    elements, and per tool a phrase naming how many trip on which faces of ``model``."""
    from cadbridge.mesh.sizing import MAX_TURN, ball_marks
    from cadbridge.tool.refine import _normal_turn, _reach

    pts, sizes, centres, where = [np.zeros((0, 3))], [np.zeros(0)], [np.zeros((0, 3))], []
    for t in tools:
        trip = t.trips.refinable if t.trips is not None else np.zeros(0, dtype=np.int64)
        if not len(trip):
            continue
        ids = trip
        if t.element_face is not None:  # the rest of a tight turn: it trips wherever the next mesh spans it
            ef = np.asarray(t.element_face)
            near = (_normal_turn(t.nagata) > MAX_TURN) & np.isin(ef, ef[trip])
            ids = np.union1d(trip, np.flatnonzero(near))
        h = _longest_edges(t.nagata, ids)
        need = np.full(len(ids), np.inf)  # TURN_PER_ELEMENT of the CAD's turn per new element, where it turns
        if t.element_face is not None:
            k = turn_curvature(t.nagata, ids, np.asarray(t.element_face)[ids], model)
            need = np.where(k > 0, TURN_PER_ELEMENT / np.where(k > 0, k, 1.0), np.inf)
        size = np.clip(need, MIN_FACTOR * h, 0.5 * h)
        cen = _centroids(t.mesh, ids)
        p, s = ball_marks(cen, _reach(t.mesh, ids, cen) + size, size)
        pts.append(p)
        sizes.append(s)
        centres.append(cen)
        if t.element_face is not None:  # the whole tight turn of each face, where its curvature sets the size
            fid = np.asarray(t.element_face)[ids]
            for f in np.unique(fid[np.isfinite(need) & (need < 0.5 * h)]):  # loop over the few tripping faces
                on = fid == f
                kf, sf = float(np.max(k[on])), float(np.min(size[on]))
                region = turn_region(model.faces[int(f)].surface, kf, sf)
                pts.append(region)
                sizes.append(np.full(len(region), sf))
        faces = "" if t.element_face is None else " on " + ", ".join(
            model.faces[int(f)].name or f"DE {model.faces[int(f)].de}" for f in np.unique(t.element_face[trip])[:6])
        kinds = [f"{len(t.trips.reversed)} with a reversing normal"] if len(t.trips.reversed) else []
        kinds += [f"{len(t.trips.straddling)} straddling a crease"] if len(t.trips.straddling) else []
        close = (f", and {len(ids) - len(trip)} whose corner normals differ by more than {np.degrees(MAX_TURN):.0f} degrees"
                 if len(ids) > len(trip) else "")
        where.append(f"{t.name}: {' and '.join(kinds)}{faces}{close}")
    return np.concatenate(pts), np.concatenate(sizes), np.concatenate(centres), where


def _centroids(mesh: Mesh, ids: np.ndarray) -> np.ndarray:
    """Centroids (K, 3) of the elements ``ids`` (K,) (global numbering over ``mesh.cells``)."""
    return np.concatenate([mesh.nodes[np.asarray(b.data)].mean(axis=1) for b in mesh.cells])[ids]


def node_sizes(mesh: Mesh) -> np.ndarray:
    """Mean length (N,) of the element edges at each node of ``mesh`` (0 at unused nodes)."""
    total, count = np.zeros(len(mesh.nodes)), np.zeros(len(mesh.nodes))
    for b in mesh.cells:
        c = np.asarray(b.data)
        a, e = c.ravel(), np.roll(c, -1, axis=1).ravel()  # every element edge, once per element
        length = np.linalg.norm(mesh.nodes[a] - mesh.nodes[e], axis=1)
        for ends in (a, e):
            np.add.at(total, ends, length)
            np.add.at(count, ends, 1.0)
    return np.where(count > 0, total / np.maximum(count, 1.0), 0.0)


def grading_carriers(centres: np.ndarray, radius: float, reach: float) -> np.ndarray:
    """Points (M, 3) about ``centres`` (K, 3) at which a graded field is read, for gmsh's
    nearest-carrier view of it (`cadbridge.mesh.sizing.SizeField.background`): without them a
    point a few elements from a mark takes the mark's size, the nearest carrier being the
    mark (the first mesh has few nodes where its elements were large). Balls of radius
    ``radius`` x 2^j, j = 1, 2, ... up to ``reach``, each a lattice of spacing a third of its
    radius (`cadbridge.mesh.sizing.ball_marks`), about the centres snapped to a grid of
    half that radius (one ball per grid cell: overlapping balls add nothing)."""
    from cadbridge.mesh.sizing import ball_marks

    out = [np.zeros((0, 3))]
    r = 2.0 * radius
    while r <= 2.0 * reach:
        cells = np.unique(np.round(centres / (0.5 * r)), axis=0) * (0.5 * r)
        out.append(ball_marks(cells, np.full(len(cells), r), np.zeros(len(cells)))[0])
        r *= 2.0
    return np.concatenate(out)


def local_sizes(first: Mesh, mark_points: np.ndarray, mark_sizes: np.ndarray, centres: np.ndarray,
                radius: float) -> tuple[np.ndarray, np.ndarray]:
    """``background_sizes`` (points (M, 3), sizes (M,)) of a round (module docs, step 2): the
    nodes of the ``first`` mesh with their `node_sizes` and the marks, graded, read at those
    points, the marks and the `grading_carriers` about the marked elements' ``centres`` (K, 3)
    (innermost ball ``radius``)."""
    from cadbridge.mesh.sizing import SizeField

    h = node_sizes(first)
    used = h > 0
    h_max = float(h[used].max())
    h_min = float(np.min(mark_sizes, initial=h_max))
    field = SizeField(np.vstack([first.nodes[used], mark_points]), np.concatenate([h[used], mark_sizes]),
                      h_min=h_min, h_max=h_max, gradation=GRADATION)
    # (nodes at the largest size bound nothing in the field; as carriers they keep that size)
    extra = grading_carriers(centres, radius, (h_max - h_min) / GRADATION)
    return field.background(extra)


def sizes_keeping_first(first: Mesh, mark_points: np.ndarray, mark_sizes: np.ndarray, centres: np.ndarray,
                        radius: float) -> tuple[tuple[np.ndarray, np.ndarray], Callable[[np.ndarray], np.ndarray]]:
    """The sizes of a round that keeps the first mesh (module docs), from one field: the
    marks (points (M, 3), sizes (M,)) graded at `GRADATION` up to the first mesh's largest
    `node_sizes`. Returns ``background_sizes`` (the field read at the marks and the
    `grading_carriers` about the marked elements' ``centres`` (K, 3), innermost ball
    ``radius``; the first mesh's own sizes come from gmsh's rules, as they did) and
    ``finer(xyz (N, 3)) -> (N,) bool``: where the field is below the first mesh's size at the
    nearest node."""
    from scipy.spatial import cKDTree

    from cadbridge.mesh.sizing import SizeField

    h = node_sizes(first)
    used = h > 0
    h, tree = h[used], cKDTree(first.nodes[used])
    h_max = float(h.max())
    h_min = float(np.min(mark_sizes, initial=h_max))
    marks = SizeField(mark_points, mark_sizes, h_min=h_min, h_max=h_max, gradation=GRADATION)

    def finer(xyz: np.ndarray) -> np.ndarray:
        _, nearest = tree.query(np.asarray(xyz, dtype=float).reshape(-1, 3), workers=-1)
        return marks(xyz) < h[nearest]

    return marks.background(grading_carriers(centres, radius, (h_max - h_min) / GRADATION)), finer


def refine_where_guards_trip(
    mesh: Mesh,
    tools: list[ToolResult],
    mesh_notes: list[str],
    model,
    *,
    remesh: Callable[[tuple[np.ndarray, np.ndarray]], tuple[Mesh, list[str]]],
    build: Callable[[Mesh], list[ToolResult]],
    rounds: int = GUARD_ROUNDS,
    progress=None,
    keep_first: bool = False,
) -> GuardRefinement:
    """Mesh again, finer where the guards trip, until none does (module docs).

    mesh, tools   the first mesh and the tools built on it (`cadbridge.tool.build.tools_from_mesh`)
    mesh_notes    what the mesher noted on the first mesh
    remesh        ``remesh(background_sizes, finer, floor) -> (mesh, notes)``: the mesh stage with
                  a local size field (`cadbridge.tool.meshing.mesh_for_tools` with
                  ``local_sizes``); with ``keep_first`` False (``finer`` and ``floor`` None) the
                  curvature rule off; with it, the first mesh kept where ``finer``
                  (`sizes_keeping_first`) is false and the curvature rule as in the first mesh, its
                  floor at most ``floor`` (``min_size``)
    build         ``build(mesh) -> tools``: the tools of a mesh, as ``tools`` were built
    rounds        rounds at most

    Returns a `GuardRefinement`; with nothing tripping on the first mesh, that mesh and those
    tools unchanged (rounds 0)."""
    progress = progress or NoProgress()
    n = _tripping(tools)
    out = GuardRefinement(mesh, tools, list(mesh_notes), converged=n == 0)
    if n == 0:
        return out
    marks_p, marks_h, centres = np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3))
    for r in range(1, rounds + 1):
        p, h, c, where = trip_marks(out.tools, model)
        marks_p, marks_h, centres = np.vstack([marks_p, p]), np.concatenate([marks_h, h]), np.vstack([centres, c])
        progress.stage(f"refinement round {r} of at most {rounds}: meshing again finer at {n} elements where the "
                       f"tool guards tripped ({'; '.join(where)}; sizes down to {h.min():.3g})")
        try:
            if keep_first:
                sizes, finer = sizes_keeping_first(mesh, marks_p, marks_h, centres, float(marks_h.min()))
                new_mesh, new_notes = remesh(sizes, finer, float(marks_h.min()))
            else:
                new_mesh, new_notes = remesh(local_sizes(mesh, marks_p, marks_h, centres, float(marks_h.min())),
                                             None, None)
            new_tools = build(new_mesh)
        except ValueError as exc:  # MeshError, ProjectionError, a measure that failed: the round before stands
            first = str(exc).split(": node ")[0].split("; ")[0]  # its first clause: one line stays short
            out.failed_round = first[:160] + ("..." if len(first) > 160 else "")
            out.notes.append(f"refinement round {r} ({'; '.join(where)}): failed: {out.failed_round}")
            break
        m = _tripping(new_tools)
        line = (f"refinement round {r}: {n} elements refined ({'; '.join(where)}; sizes down to {h.min():.3g}): "
                f"{len(new_mesh.nodes)} nodes, {m} elements tripping after it")
        out.rounds = r
        if m >= n:  # refinement does not cure these elements
            out.notes.append(line + "; the mesh before it kept")
            break
        out.notes.append(line)
        out.mesh, out.tools, out.mesh_notes = new_mesh, new_tools, list(new_notes)
        if m == 0:
            break
        n = m
    out.converged = _tripping(out.tools) == 0
    return out
