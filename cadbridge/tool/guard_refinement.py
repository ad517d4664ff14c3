"""Refine instead of refuse: where the soundness guards of `cadbridge.tool.build` trip
(elements that straddle a crease, elements over which the CAD normal reverses), mesh again
with a local size field that is finer there, a few rounds at most.

One round of `refine_where_guards_trip`:

1. **Marks.** Every element that trips (`GuardTrips.refinable`) asks for a new size: its
   longest edge h times 1/2, or times MAX_TURN / a where its corner normals are a > 120
   degrees apart (the normal turns at least that much across it; the new elements should
   turn it by at most MAX_TURN = 60 degrees each, the limit of the Nagata error law,
   `cadbridge.mesh.sizing`), over a ball about the element (`cadbridge.tool.refine.element_marks`:
   the nodes gmsh makes there read the size asked). Marks add up over the rounds.
2. **Field.** The carriers are the nodes of the first mesh, each with the mean length of its
   edges there (the sizes gmsh chose by its own rules: ``size`` and the curvature rule), and
   the marks; the field is the graded minimum of them (`cadbridge.mesh.sizing.SizeField`, g =
   0.5), so the smaller size wins and the sizes grow smoothly away from the marks. gmsh gets
   it as ``background_sizes`` with the curvature rule off: gmsh clamps every size, the field's
   too, to the curvature rule's floor (``Mesh.MeshSizeMin`` = size / 20), which is what the
   marks must go below on a tight radius; the first mesh's sizes already hold that rule.
3. **Mesh and check** again (the caller's ``remesh`` and ``build``).

The loop stops when no element trips (converged), when a round leaves as many or more
elements tripping than the one before (refinement does not cure them: a crease the mesh does
not follow, a seam, a degenerate element), after ``rounds`` rounds, or when a round's mesh
or projection fails (the round before stands). Lengths in model units.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from cadbridge.common.progress import NoProgress
from cadbridge.mesh.mesh import Mesh
from cadbridge.tool.build import ToolResult

__all__ = ["GUARD_ROUNDS", "GRADATION", "GuardRefinement", "node_sizes", "refine_where_guards_trip", "trip_marks"]

GUARD_ROUNDS = 3
"""Rounds of refinement at most before the guards' message stands."""
GRADATION = 0.3
"""How fast the local field grows away from a mark (an element next to one of size h: 1.3 h)."""
MIN_FACTOR = 1.0 / 16.0
"""The smallest factor on an element's size in one round."""


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


def turn_curvature(nm, ids: np.ndarray, faces: np.ndarray, model, samples: int = 9) -> np.ndarray:
    """Largest |principal curvature| (K,) [1/length] of the CAD over each element ``ids`` (K,)
    of the `NagataMesh` ``nm``: on a ``samples`` x ``samples`` grid over the (u, v) box of its
    corners' feet on its face ``faces`` (K,) (an element that spans a tight turn has its
    corners on the flat sides and the turn between them); 0 where no curvature is finite."""
    from cadbridge.nurbs.curvature import principal_curvatures
    from cadbridge.nurbs.project import project_to_surface

    out = np.zeros(len(ids))
    kind, local = nm.element_kind[ids], nm.element_local[ids]
    t = np.linspace(0.0, 1.0, samples)
    a, b = (g.ravel() for g in np.meshgrid(t, t, indexing="ij"))
    for f in np.unique(faces):  # loop over faces, vectorised over elements and samples
        if f < 0:
            continue
        s = model.faces[int(f)].surface
        for k, conn in ((3, nm.tri_elements), (4, nm.quad_elements)):
            sel = np.flatnonzero((faces == f) & (kind == k))
            if not len(sel):
                continue
            pr = project_to_surface(s, nm.nodes[conn[local[sel]]].reshape(-1, 3))
            u, v = pr.u.reshape(len(sel), k), pr.v.reshape(len(sel), k)
            uu = u.min(axis=1)[:, None] + np.ptp(u, axis=1)[:, None] * a[None]  # (S, samples^2)
            vv = v.min(axis=1)[:, None] + np.ptp(v, axis=1)[:, None] * b[None]
            k1, k2 = principal_curvatures(s, uu.ravel(), vv.ravel())
            kmax = np.maximum(np.abs(k1), np.abs(k2)).reshape(len(sel), -1)
            out[sel] = np.max(np.where(np.isfinite(kmax), kmax, 0.0), axis=1)
    return out


def trip_marks(tools: list[ToolResult], model) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Refinement marks (points (M, 3), sizes (M,)) at the elements of ``tools`` that trip the
    guards (module docs, step 1), and per tool a phrase naming how many elements on which
    faces of ``model``."""
    from cadbridge.mesh.sizing import MAX_TURN, ball_marks
    from cadbridge.tool.refine import _reach

    pts, sizes, where = [np.zeros((0, 3))], [np.zeros(0)], []
    for t in tools:
        ids = t.trips.refinable if t.trips is not None else np.zeros(0, dtype=np.int64)
        if not len(ids):
            continue
        h = _longest_edges(t.nagata, ids)
        need = np.full(len(ids), np.inf)  # MAX_TURN of the CAD's turn per new element, where it turns
        if t.element_face is not None:
            k = turn_curvature(t.nagata, ids, np.asarray(t.element_face)[ids], model)
            need = np.where(k > 0, MAX_TURN / np.where(k > 0, k, 1.0), np.inf)
        size = np.clip(need, MIN_FACTOR * h, 0.5 * h)
        cen = _centroids(t.mesh, ids)
        p, s = ball_marks(cen, _reach(t.mesh, ids, cen) + h, size)
        pts.append(p)
        sizes.append(s)
        faces = "" if t.element_face is None else " on " + ", ".join(
            model.faces[int(f)].name or f"DE {model.faces[int(f)].de}" for f in np.unique(t.element_face[ids])[:6])
        kinds = [f"{len(t.trips.reversed)} with a reversing normal"] if len(t.trips.reversed) else []
        kinds += [f"{len(t.trips.straddling)} straddling a crease"] if len(t.trips.straddling) else []
        where.append(f"{t.name}: {' and '.join(kinds)}{faces}")
    return np.concatenate(pts), np.concatenate(sizes), where


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


def local_sizes(first: Mesh, mark_points: np.ndarray, mark_sizes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``background_sizes`` (points (M, 3), sizes (M,)) of a round (module docs, step 2): the
    nodes of the ``first`` mesh with their `node_sizes`, and the marks, graded."""
    from cadbridge.mesh.sizing import SizeField

    h = node_sizes(first)
    used = h > 0
    h_max = float(h[used].max())
    field = SizeField(np.vstack([first.nodes[used], mark_points]), np.concatenate([h[used], mark_sizes]),
                      h_min=float(np.min(mark_sizes, initial=h_max)), h_max=h_max, gradation=GRADATION)
    # the nodes' own sizes bound nothing at h_max in SizeField (samples at h_max are left out):
    # carriers at the largest size keep it, as their nodes did
    return field.background()


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
) -> GuardRefinement:
    """Mesh again, finer where the guards trip, until none does (module docs).

    mesh, tools   the first mesh and the tools built on it (`cadbridge.tool.build.tools_from_mesh`)
    mesh_notes    what the mesher noted on the first mesh
    remesh        ``remesh(background_sizes) -> (mesh, notes)``: the mesh stage with a local size
                  field and the curvature rule off (`cadbridge.tool.meshing.mesh_for_tools`
                  with ``local_sizes`` and ``curvature_elements=0``)
    build         ``build(mesh) -> tools``: the tools of a mesh, as ``tools`` were built
    rounds        rounds at most

    Returns a `GuardRefinement`; with nothing tripping on the first mesh, that mesh and those
    tools unchanged (rounds 0)."""
    progress = progress or NoProgress()
    n = _tripping(tools)
    out = GuardRefinement(mesh, tools, list(mesh_notes), converged=n == 0)
    if n == 0:
        return out
    marks_p, marks_h = np.zeros((0, 3)), np.zeros(0)
    for r in range(1, rounds + 1):
        p, h, where = trip_marks(out.tools, model)
        marks_p, marks_h = np.vstack([marks_p, p]), np.concatenate([marks_h, h])
        progress.stage(f"refinement round {r} of at most {rounds}: meshing again finer at {n} elements where the "
                       f"tool guards tripped ({'; '.join(where)}; sizes down to {h.min():.3g})")
        try:
            new_mesh, new_notes = remesh(local_sizes(mesh, marks_p, marks_h))
            new_tools = build(new_mesh)
        except ValueError as exc:  # MeshError, ProjectionError, a measure that failed: the round before stands
            out.notes.append(f"refinement round {r} ({'; '.join(where)}): its mesh failed: {exc}")
            break
        m = _tripping(new_tools)
        out.notes.append(f"refinement round {r}: {n} elements refined ({'; '.join(where)}; sizes down to "
                         f"{h.min():.3g}): {len(new_mesh.nodes)} nodes, {m} elements tripping after it")
        out.mesh, out.tools, out.mesh_notes, out.rounds = new_mesh, new_tools, list(new_notes), r
        if m == 0 or m >= n:
            break
        n = m
    out.converged = _tripping(out.tools) == 0
    return out
