"""Building Nagata tools from a mesh on the CAD: node normals (exact, with the fold rule, or
estimated), one tool per connected group of faces, Nagata patches, their errors against the
CAD and the checks that a tool is sound (folded, reversed or crease-straddling elements).

`tools_from_mesh` is the stage `cadbridge nagata` and `cadbridge convert` share; long stages
report to an optional ``progress`` (`cadbridge.common.progress.NoProgress` by default).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field

import numpy as np

from cadbridge.common.progress import NoProgress
from cadbridge.mesh.mesh import CellBlock, Mesh

__all__ = ['CadProjector', 'GuardTrips', 'REVERSAL_DEG', 'SAMPLE_BUDGET', 'ToolQualityError', 'ToolResult', 'build_tool', 'check_tools', 'consistently_oriented', 'folded_elements', 'guard_trips', 'measure_tool', 'reversed_normal_elements', 'rule_shape_errors', 'sample_divisions', 'tool_groups', 'tool_normals', 'tools_from_mesh']


class ToolQualityError(ValueError):
    """A Nagata tool whose surface is worse than its own flat mesh (exit code 1 in the CLI):
    the message names the worst elements and why."""

@dataclass
class GuardTrips:
    """The elements of one tool that trip the soundness guards of `build_tool` (0-based ids in
    the tool's numbering: ``ToolResult.mesh`` and ``nagata``, triangles first), each (K,) int64
    sorted; ``reversed`` leaves out the straddling ones.

    straddling  corners on both sides of a crease line or sharp edge (`_straddling_ids`)
    reversed    two corner normals more than `REVERSAL_DEG` apart (`reversed_normal_elements`)
    folded      wound against the normals at all corners (`folded_elements`)
    """

    straddling: np.ndarray
    reversed: np.ndarray
    folded: np.ndarray

    @property
    def refinable(self) -> np.ndarray:
        """(K,) sorted ids of the elements a finer mesh can cure: straddling and reversed."""
        return np.union1d(self.straddling, self.reversed)

    def __bool__(self) -> bool:
        return bool(len(self.straddling) or len(self.reversed) or len(self.folded))


def guard_trips(nm, straddling=None, element_face=None, model=None) -> GuardTrips:
    """The `GuardTrips` of the `NagataMesh` ``nm``: ``straddling`` the element ids found
    straddling on the CAD (`cadbridge.heal.creases.straddling_elements`, tool numbering),
    ``element_face`` (E,) the face of each element and ``model`` its CAD (see
    `_straddling_ids`)."""
    strad = _straddling_ids(nm, straddling, element_face, model)
    turned = np.setdiff1d(reversed_normal_elements(nm), strad)
    return GuardTrips(strad, turned.astype(np.int64), folded_elements(nm).astype(np.int64))


@dataclass
class ToolResult:
    """One tool: its mesh, normals, Nagata surface and error statistics.

    The mesh's blocks are ordered triangles first, so the global element numbering of
    ``nagata``, ``grid["element"]`` and the tool file are the same.
    """

    name: str
    mesh: Mesh
    normals: np.ndarray  # (N, 3)
    corner_normals: list[np.ndarray]  # per block (E_b, k_b, 3)
    normal_source: str
    nagata: object  # cadbridge.nagata.NagataMesh
    grid: dict  # sample grid: points, normals, element, eta, zeta[, surface_error, boundary_error,
    #             flat_surface_error, normal_error] (see cadbridge.tool.accuracy)
    stats: dict  # max/mean surface, boundary, flat and normal errors
    node_face: np.ndarray | None = None
    node_distance: np.ndarray | None = None
    element_face: np.ndarray | None = None  # (E,) face of each element (global numbering)
    diagnosis: list[str] = field(default_factory=list)  # worst elements, when worse than flat
    trips: GuardTrips | None = None  # elements that trip the guards (their ids as data)
    moved_nodes: np.ndarray | None = None  # (K,) how far nodes were moved onto the CAD (`onto_cad`)

def element_blocks(mesh: Mesh) -> list[np.ndarray]:
    return [np.asarray(b.data) for b in mesh.cells]

def _split(values: np.ndarray, mesh: Mesh) -> list[np.ndarray]:
    """Cut a per-element array (E, ...) into per-block pieces."""
    return np.split(values, np.cumsum([len(b) for b in mesh.cells])[:-1])

def tool_groups(mesh: Mesh, model, element_face: list[np.ndarray]) -> dict[str, list[np.ndarray]]:
    """Split the mesh into tools: one per connected component of elements.

    Die, punch and blank holder are separate bodies, so each is a component of the mesh.
    A tool is named after its faces' IGES names (406 form 15 / DE labels): the common name
    when all agree, else their common prefix (e.g. DIEWALL, DIERAD, DIELAND -> "DIE"), else
    the mesh name with a number. Returns {tool name: [bool mask per block]}.
    """
    from cadbridge.mesh.topology import connected_components

    n, labels = connected_components(mesh)
    ef = np.concatenate(element_face) if element_face else np.zeros(0, dtype=np.int64)
    groups: dict[str, list[np.ndarray]] = {}
    for k in range(n):  # one pass per tool, not per element
        sel = labels == k
        names = sorted({model.faces[f].name for f in np.unique(ef[sel]) if f >= 0 and model.faces[f].name})
        prefix = os.path.commonprefix(names).rstrip("_- (") if names else ""
        name = (names[0] if len(names) == 1 else prefix if len(prefix) >= 2 else "") or (
            mesh.name if n == 1 else f"{mesh.name}_{k + 1}")
        base, i = name, 2
        while name in groups:
            name, i = f"{base}_{i}", i + 1
        groups[name] = _split(sel, mesh)
    return groups

def _submesh(mesh: Mesh, masks: list[np.ndarray], name: str) -> tuple[Mesh, np.ndarray, list[bool]]:
    """Elements selected by ``masks`` with their nodes renumbered; also the old node ids and
    which blocks were kept."""
    kept = [bool(np.any(m)) for m in masks]
    blocks = [(b.type, np.asarray(b.data)[m]) for b, m, k in zip(mesh.cells, masks, kept) if k]
    used = np.unique(np.concatenate([d.ravel() for _, d in blocks]))
    new = np.full(len(mesh.nodes), -1, dtype=np.int64)
    new[used] = np.arange(len(used))
    sub = Mesh(nodes=mesh.nodes[used], cells=[CellBlock(t, new[d]) for t, d in blocks], name=name)
    return sub, used, kept

class CadProjector:
    """``points (M, 3) -> (foot (M, 3), normal (M, 3))`` on a CAD model, for error measures.

    Keeps the search index of the model. Points the trimmed projection finds no foot for
    (e.g. a patch bulging over a hole of a trimmed plate, when every candidate foot lies on
    a trimmed-away part) are projected onto the untrimmed surfaces instead, and
    ``last_off_trims`` counts them. Works in chunks so ``progress`` can follow.
    """

    chunk = 20000

    def __init__(self, model, progress=None) -> None:
        from cadbridge.cad.search import index_for

        self.model = model
        self.index = index_for(model)  # cached on the model: shared with cad_normals
        self._untrimmed = None
        self.progress = progress or NoProgress()
        self.last_off_trims = 0

    def _untrimmed_model(self):
        from cadbridge.cad.search import build_search_index

        if self._untrimmed is None:
            faces = [dataclasses.replace(f, trims=None, trim_delta=None) for f in self.model.faces]
            m = dataclasses.replace(self.model, faces=faces)
            self._untrimmed = (m, build_search_index(m))
        return self._untrimmed

    def project(self, points: np.ndarray):
        """The `cadbridge.cad.search.Projection` of ``points`` (untrimmed fallback applied)."""
        from cadbridge.cad.search import project_points

        points = np.asarray(points, dtype=float)
        parts = []
        for a in range(0, max(len(points), 1), self.chunk):
            parts.append(project_points(points[a : a + self.chunk], self.model, index=self.index))
            self.progress.update(min(a + self.chunk, len(points)), len(points))
        proj = parts[0] if len(parts) == 1 else type(parts[0])(
            *[np.concatenate([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(parts[0])])
        miss = np.flatnonzero(~np.all(np.isfinite(proj.foot), axis=1))
        self.last_off_trims = len(miss)
        if len(miss):
            model, index = self._untrimmed_model()
            alt = project_points(points[miss], model, index=index)
            for f in dataclasses.fields(proj):
                getattr(proj, f.name)[miss] = getattr(alt, f.name)
        return proj

    def __call__(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = self.project(points)
        return p.foot, p.normal

def _triangles_first(mesh: Mesh, corner_normals: list[np.ndarray]) -> tuple[Mesh, list[np.ndarray]]:
    """Reorder the blocks so triangles come first (the tool file's element numbering)."""
    order = sorted(range(len(mesh.cells)), key=lambda i: mesh.cells[i].type != "triangle")
    if order == list(range(len(mesh.cells))):
        return mesh, corner_normals
    return (Mesh(nodes=mesh.nodes, cells=[mesh.cells[i] for i in order], name=mesh.name),
            [corner_normals[i] for i in order])

def build_tool(
    name: str,
    mesh: Mesh,
    normals: np.ndarray,
    corner_normals: list[np.ndarray],
    source: str,
    *,
    model=None,
    grid: int = 10,
    node_face=None,
    node_distance=None,
    projector: CadProjector | None = None,
    progress=None,
    element_face: list[np.ndarray] | np.ndarray | None = None,
    straddling: np.ndarray | None = None,
    boundary_curves: bool = True,
    measure: bool = True,
    edge_rule: str = "bounded",
) -> ToolResult:
    """Nagata patches over ``mesh`` with the given normals and their errors against the CAD
    (`cadbridge.tool.accuracy`: surface, boundary, flat surface and normal errors).

    element_face: face of each element (per block, or (E,) in block order); where None the
    element centroids are projected. straddling: global element ids (block order) that
    straddle a crease (`cadbridge.heal.creases.straddling_elements`), named in the diagnosis.
    boundary_curves: free boundary edges follow their faces' trim curves
    (`cadbridge.nagata.boundary_edges`; needs ``model``). measure: False leaves out the sample
    grid and the errors against the CAD (`measure_tool` adds them later; the guards'
    ``trips`` and lines only). edge_rule: "bounded" or "published" (`cadbridge.nagata.edge`)."""
    from cadbridge.nagata import NagataMesh

    progress = progress or NoProgress()
    order = sorted(range(len(mesh.cells)), key=lambda i: mesh.cells[i].type != "triangle")
    remap = None
    if order != list(range(len(mesh.cells))):
        sizes = [len(c) for c in mesh.cells]
        starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        remap = np.concatenate([starts[i] + np.arange(sizes[i]) for i in order])  # new -> old element id
    mesh, corner_normals = _triangles_first(mesh, corner_normals)
    ef = None
    edge_normals = None
    if model is not None:
        projector = projector or CadProjector(model, progress)
        if element_face is None:
            cent = np.concatenate([mesh.nodes[b].mean(axis=1) for b in element_blocks(mesh)])
            ef = np.asarray(projector.project(cent).face, dtype=np.int64)
        else:
            ef = np.concatenate(element_face) if isinstance(element_face, list) else np.asarray(element_face)
            ef = ef.astype(np.int64)
            if remap is not None:
                ef = ef[remap]
        if boundary_curves:
            from cadbridge.nagata.boundary_edges import boundary_conormals

            progress.stage(f"{name}: boundary edges along the trim curves")
            edge_normals = boundary_conormals(mesh, corner_normals, ef, model).as_edge_normals()
    progress.stage(f"{name}: Nagata patches")
    nm = NagataMesh(mesh.nodes, element_blocks(mesh), corner_normals, edge_normals=edge_normals, edge_rule=edge_rule)
    if straddling is not None and remap is not None:  # given in block order: to the tool's numbering
        inv = np.empty_like(remap)
        inv[remap] = np.arange(len(remap))
        straddling = inv[np.asarray(straddling, dtype=np.int64)]
    trips = guard_trips(nm, straddling, ef, model)
    tool = ToolResult(name, mesh, normals, corner_normals, source, nm, {}, {}, node_face, node_distance, ef,
                      _guard_lines(trips, ef, model), trips)
    if measure:
        measure_tool(tool, model, projector=projector, grid=grid, progress=progress)
    return tool


def measure_tool(tool: ToolResult, model, *, projector: CadProjector | None = None, grid: int = 10,
                 progress=None, compare_rules: bool = False) -> None:
    """The sample grid of ``tool`` (``grid`` divisions per patch at most, `sample_divisions`)
    and, with a ``model``, its errors against the CAD (`cadbridge.tool.accuracy.tool_errors`):
    sets ``tool.grid`` and ``tool.stats``, and adds the diagnosis line of a tool worse than
    its flat mesh (`_diagnose`) after the guards' lines. ``compare_rules``: also
    ``stats["shape_error_by_rule"]``, {edge rule: max shape error} for both edge rules
    (`rule_shape_errors`). A tool measured already on the same divisions (the adaptive
    loop's best tools, `cadbridge.tool.refine`, where the sample budget gives both grids the
    same divisions) keeps its grid and errors: the same numbers, not measured twice (the
    production die at t = 0.002: 2.9 M samples); only the rules' line is added."""
    progress = progress or NoProgress()
    nm = tool.nagata
    grid = sample_divisions(nm, grid)
    if model is not None and tool.stats.get("grid") == grid and "surface_error" in tool.grid:
        if compare_rules and "shape_error_by_rule" not in tool.stats:
            from cadbridge.tool.accuracy import ToolErrors

            g = tool.grid
            err = ToolErrors(g["surface_error"], g["normal_error"], g["boundary_error"], g["flat_surface_error"],
                             g["face"])
            projector = projector or CadProjector(model, progress)
            progress.stage(f"{tool.name}: shape error of the other edge rule ({grid} divisions per patch)")
            tool.stats["shape_error_by_rule"] = rule_shape_errors(tool, err, model, projector.project)
        return
    if tool.stats:  # measured before on other divisions: the guards' lines only, the new measure's added below
        tool.diagnosis = _guard_lines(tool.trips, tool.element_face, model)
    g = nm.sample_grid(grid)
    tool.grid = {"points": g.points, "normals": g.normals, "element": g.elem, "eta": g.eta, "zeta": g.zeta}
    if model is None:
        return
    from cadbridge.tool.accuracy import tool_errors

    projector = projector or CadProjector(model, progress)
    progress.stage(f"{tool.name}: errors vs CAD ({len(g.points)} patch points, {grid} divisions per patch)")
    err = tool_errors(nm, g.elem, g.eta, g.zeta, tool.element_face, model, projector.project)
    tool.grid.update(surface_error=err.surface, boundary_error=err.boundary,
                     flat_surface_error=err.flat_surface, normal_error=err.normal, face=err.face)
    tool.stats = err.stats()
    tool.stats["grid"] = grid
    if compare_rules:
        tool.stats["shape_error_by_rule"] = rule_shape_errors(tool, err, model, projector.project)
    tool.diagnosis += _diagnose(nm, err, g.elem, tool.trips.straddling, model.size())


def rule_shape_errors(tool: ToolResult, err, model, project_trimmed) -> dict[str, float]:
    """{edge rule: max shape error [length]} of ``tool`` under both edge rules
    (`cadbridge.nagata.edge.EDGE_RULES`), on the samples of ``tool.grid``. The shape error of
    a sample is the larger of its |surface error| and its boundary error
    (`cadbridge.tool.accuracy`; as `cadbridge.tool.refine` measures it). ``err`` (the
    `ToolErrors` of those samples) gives the tool's own rule; for the other rule the patches
    are built again, and a sample whose point moves by d can change its shape error by at
    most d (a distance to a set is 1-Lipschitz): only the samples whose own error + d could
    exceed the largest own error - d over all samples are measured again, and the maximum
    is exact. (On PRO20359-L2, one CATIA V4 face of 112 046 samples, measuring every changed
    sample again took 29 s, as long as the first measure.)"""
    from cadbridge.nagata import EDGE_RULES, NagataMesh
    from cadbridge.tool.accuracy import tool_errors

    nm = tool.nagata
    def shape(surface: np.ndarray, boundary: np.ndarray) -> float:
        return float(np.max(np.maximum(np.abs(surface), boundary))) if len(surface) else 0.0

    out = {nm.edge_rule: shape(err.surface, err.boundary)}
    for rule in EDGE_RULES:
        if rule == nm.edge_rule:
            continue
        pairs, p, q = nm.edge_normals
        other = NagataMesh(nm.nodes, element_blocks(tool.mesh), tool.corner_normals, edge_normals=(pairs, p, q),
                           edge_rule=rule)
        changed = np.zeros(nm.n_elements, dtype=bool)
        changed[nm.tri_global] = np.any(other.tri_coefficients != nm.tri_coefficients, axis=(1, 2))
        changed[nm.quad_global] = np.any(other.quad_coefficients != nm.quad_coefficients, axis=(1, 2))
        g = tool.grid
        own = np.maximum(np.abs(np.asarray(err.surface, dtype=float)), np.asarray(err.boundary, dtype=float))
        rows = np.flatnonzero(changed[g["element"]])
        if not len(rows):
            out[rule] = float(own.max()) if len(own) else 0.0
            continue
        moved = np.linalg.norm(other.evaluate(g["element"][rows], g["eta"][rows], g["zeta"][rows])[0]
                               - g["points"][rows], axis=1)
        low = own.copy()
        low[rows] = np.maximum(own[rows] - moved, 0.0)  # the other rule's error is at least this
        best = float(low.max())
        rows = rows[own[rows] + moved > best]  # the others cannot hold the maximum
        if len(rows):
            e = tool_errors(other, g["element"][rows], g["eta"][rows], g["zeta"][rows], tool.element_face, model,
                            project_trimmed)
            best = max(best, shape(e.surface, e.boundary))
        out[rule] = best
    return out


def _guard_lines(trips: GuardTrips, ef, model) -> list[str]:
    """The diagnosis lines of the guards that ``trips`` trip (folded, reversed, straddling, in
    that order), elements 1-based; ``ef`` (E,) element faces and ``model`` name the faces."""
    lines = []
    folded, turned, strad = trips.folded, trips.reversed.tolist(), trips.straddling
    if len(folded):
        more = f" (and {len(folded) - 10} more)" if len(folded) > 10 else ""
        lines.append(f"mesh folds over itself: elements {', '.join(str(int(e) + 1) for e in folded[:10])}{more} "
                     f"(1-based, {len(folded)} in all) are wound against the normals at all their corners "
                     f"(overlapping elements); remesh")
    if turned:
        more = f" (and {len(turned) - 10} more)" if len(turned) > 10 else ""
        where = ""
        if ef is not None and model is not None:
            fs = np.unique(ef[turned])
            where = " on face " + ", ".join(f"{int(f)} ({model.faces[int(f)].name or 'DE %d' % model.faces[int(f)].de})"
                                             for f in fs[:3])
        lines.append(f"the CAD normal reverses inside elements {', '.join(str(e + 1) for e in turned[:10])}"
                     f"{more} (1-based, {len(turned)} in all){where}: their corner normals differ by more "
                     f"than {REVERSAL_DEG:.0f} degrees, so the surface folds back over itself there or the "
                     f"elements span more than that of its turn; no quadratic patch can follow it (check the "
                     f"face in CAD, or refine)")
    if len(strad):
        more = f" (and {len(strad) - 10} more)" if len(strad) > 10 else ""
        lines.append(f"mesh straddles a crease: elements {', '.join(str(int(e) + 1) for e in strad[:10])}"
                     f"{more} (1-based, {len(strad)} in all) have corners on both sides of a crease line or "
                     f"sharp edge, and no normal can make a patch fold inside an element; remesh with mesh "
                     f"edges on the creases (cadbridge convert does)")
    return lines

def folded_elements(nm) -> np.ndarray:
    """Elements (global ids) whose polyhedral normal (winding) points against the normal at
    every one of their corners: in a consistently wound mesh with oriented normals, a folded
    (overlapping) element, e.g. triangles a mesher laid over each other. (K,) sorted."""
    out = []
    for conn, cn, glob in ((nm.tri_elements, nm.tri_corner_normals, nm.tri_global),
                           (nm.quad_elements, nm.quad_corner_normals, nm.quad_global)):
        if len(conn) == 0:
            continue
        x = nm.nodes[conn]
        en = (np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]) if conn.shape[1] == 3
              else np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 1]))
        against = np.einsum("eki,ei->ek", cn, en) < 0
        out.append(glob[against.all(axis=1) & (np.linalg.norm(en, axis=1) > 0)])
    return np.sort(np.concatenate(out)) if out else np.zeros(0, dtype=np.int64)

REVERSAL_DEG = 120.0

def reversed_normal_elements(nm, max_angle_deg: float = REVERSAL_DEG) -> np.ndarray:
    """Elements (global ids, sorted) with two corner normals more than ``max_angle_deg``
    apart: the CAD surface folds back between their corners (a parametrisation that turns
    over, e.g. the ANSA face FACE(274) of the OCC corpus, whose v-direction runs back over
    2.4 mm twice), or the element spans too much of a tight radius. (K,) int64."""
    c = np.cos(np.radians(max_angle_deg))
    out = []
    for cn, glob in ((nm.tri_corner_normals, nm.tri_global), (nm.quad_corner_normals, nm.quad_global)):
        if len(cn) == 0:
            continue
        dots = np.einsum("eai,ebi->eab", cn, cn)
        out.append(glob[(dots < c).any(axis=(1, 2))])
    return np.sort(np.concatenate(out)) if out else np.zeros(0, dtype=np.int64)

def _straddling_ids(nm, straddling, element_face=None, model=None) -> np.ndarray:
    """Sorted element ids that straddle a crease: the given ones (CAD check) and the elements
    on an edge with several corner normals at one end only (`NagataMesh.half_crease_edges`)
    whose elements lie on one face, unless the edge runs along a crease line of that face
    (``model`` given, `cadbridge.heal.creases.along_crease_lines`). On a face border, or
    along a crease line, such an edge is a sharp edge fading below the crease angle along
    its length, not a straddle."""
    ids = [np.asarray(straddling if straddling is not None else [], dtype=np.int64)]
    if len(nm.half_crease_edges):
        topo = nm.edges
        inst = np.flatnonzero(np.isin(topo["inst_edge"], nm.half_crease_edges))
        el = topo["inst_elem"][inst]
        if element_face is not None:
            ef = np.asarray(element_face)[el]
            edge = topo["inst_edge"][inst]
            lo = np.full(len(topo["edges"]), np.iinfo(np.int64).max)
            hi = np.full(len(topo["edges"]), -1)
            np.minimum.at(lo, edge, ef)
            np.maximum.at(hi, edge, ef)
            one = lo[edge] == hi[edge]
            if model is not None and one.any():
                from cadbridge.heal.creases import along_crease_lines

                ends = topo["edges"][edge[one]]
                one[np.flatnonzero(one)] = ~along_crease_lines(model, ef[one], nm.nodes[ends[:, 0]], nm.nodes[ends[:, 1]])
            el = el[one]
        ids.append(el)
    return np.unique(np.concatenate(ids))

SAMPLE_BUDGET = 400_000

def grid_rows(grid: dict, elem: np.ndarray, eta: np.ndarray, zeta: np.ndarray) -> np.ndarray | None:
    """Rows of the sample ``grid`` at the points (elem, eta, zeta), (V,); None unless every
    point is one of its samples (exactly the same patch parameters)."""
    ge = np.asarray(grid["element"], dtype=np.int64)
    gk = np.rec.fromarrays([ge, np.asarray(grid["eta"]), np.asarray(grid["zeta"])])
    q = np.rec.fromarrays([np.asarray(elem, dtype=np.int64), np.asarray(eta), np.asarray(zeta)])
    order = np.argsort(gk, order=("f0", "f1", "f2"), kind="stable")
    i = np.searchsorted(gk[order], q)
    i = np.minimum(i, len(order) - 1)
    rows = order[i]
    ok = (ge[rows] == q.f0) & (np.asarray(grid["eta"])[rows] == q.f1) & (np.asarray(grid["zeta"])[rows] == q.f2)
    return rows if len(q) and ok.all() else None

def sample_divisions(nm, grid: int, budget: int = SAMPLE_BUDGET) -> int:
    """The largest n <= ``grid`` (at least 2) whose uniform grid on every patch has at most
    ``budget`` points ((n+1)(n+2)/2 per triangle, (n+1)^2 per quadrilateral)."""
    nt, nq = len(nm.tri_elements), len(nm.quad_elements)
    n = int(grid)
    while n > 2 and nt * (n + 1) * (n + 2) // 2 + nq * (n + 1) ** 2 > budget:
        n -= 1
    return n

def _diagnose(nm, err, elem: np.ndarray, straddling: np.ndarray, size: float) -> list[str]:
    """Lines naming the elements (1-based, tool-file numbering) whose Nagata surface error
    exceeds their flat element's, worst first, each with the reason: straddles a crease,
    inadmissible edge (|c . d| >= |d|^2: the edge curve turns back), bad normal (a corner
    normal more than 60 degrees from the element's plane normal), or else too coarse for
    the curvature. Empty when the tool is no worse than its flat mesh."""
    from cadbridge.tool.accuracy import worst_elements

    s = err.stats()
    floor = 1e-9 * size
    if s["max_abs_surface_error"] <= max(s["max_abs_flat_surface_error"], floor):
        return []
    worst, nag, flat = worst_elements(err, elem, nm.n_elements, floor)
    strad = set(np.asarray(straddling).tolist())
    reasons = []
    for e, a, b in zip(worst[:5].tolist(), nag[:5], flat[:5]):  # the five worst, for the message
        reasons.append(f"element {e + 1} ({a:.3g} vs flat {b:.3g}): {_reason(nm, e, strad)}")
    return [f"Nagata surface error {s['max_abs_surface_error']:.3g} exceeds the flat mesh's "
            f"{s['max_abs_flat_surface_error']:.3g} on {len(worst)} elements; worst: " + "; ".join(reasons)]

def _reason(nm, e: int, straddling: set) -> str:
    if e in straddling:
        return "straddles a crease"
    kind, loc = int(nm.element_kind[e]), int(nm.element_local[e])
    conn = (nm.tri_elements if kind == 3 else nm.quad_elements)[loc]
    ec = (nm.tri_edge_coefficients if kind == 3 else nm.quad_edge_coefficients)[loc]
    corner_n = (nm.tri_corner_normals if kind == 3 else nm.quad_corner_normals)[loc]
    from cadbridge.nagata.patch import QUAD_EDGES, TRI_EDGES

    x = nm.nodes[conn]
    for (i, j), c in zip(TRI_EDGES if kind == 3 else QUAD_EDGES, ec):
        d = x[j] - x[i]
        if abs(float(np.dot(c, d))) >= float(np.dot(d, d)):
            return f"inadmissible edge {int(conn[i]) + 1}-{int(conn[j]) + 1} (the edge curve turns back)"
    en = np.cross(x[1] - x[0], x[2] - x[0]) if kind == 3 else np.cross(x[2] - x[0], x[3] - x[1])
    en /= max(np.linalg.norm(en), 1e-300)
    if np.min(np.abs(corner_n @ en)) < 0.5:
        return "bad normal (a corner normal is more than 60 degrees from the element's plane)"
    return "element too coarse for the curvature (refine the mesh)"

def corner_overrides(node_normals: np.ndarray, blocks: list[np.ndarray], corners: list[np.ndarray]):
    """(element, local corner, normal) where a corner normal differs from its node normal
    (global element numbering over ``blocks`` in order)."""
    b = [blk.reshape(len(blk), -1) for blk in blocks]
    elems, locs, nrms = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros((0, 3))]
    offset = 0
    for blk, c in zip(b, corners):  # one pass per block
        e, k = np.nonzero(np.any(c != node_normals[blk], axis=2))
        elems.append(e + offset)
        locs.append(k)
        nrms.append(c[e, k])
        offset += len(blk)
    return np.concatenate(elems), np.concatenate(locs), np.concatenate(nrms)

def tool_normals(mesh: Mesh, model, method: str, *, tolerance=None, flip=False, allow_far=False, known=None):
    """(node normals, corner normals per block, node face ids | None, node distances | None,
    element faces per block | None, `CadNormals` | None). ``known``: a `CadNormals` computed
    already by `cadbridge.normals.cad.cad_normals` with its default tolerance and no flip
    (``allow_far`` and ``orient`` as may be), taken where it refers to ``mesh`` itself with
    no element re-oriented (the adaptive loop's, `cadbridge.tool.refine`: the same call's
    result, not made twice); nodes beyond the tolerance still raise unless ``allow_far``."""
    blocks = element_blocks(mesh)
    if method == "cad":
        from cadbridge.heal.folds import apply_fold_normals, folds_for
        from cadbridge.normals.cad import cad_normals

        if (known is not None and known.mesh is mesh and not np.any(known.flipped) and tolerance is None
                and not flip):
            cn = known
            if not allow_far:
                from cadbridge.normals.cad import NODE_TOLERANCE, check_far

                check_far(np.asarray(mesh.nodes, dtype=float), cn, NODE_TOLERANCE * model.size())
        else:
            cn = cad_normals(mesh, model, tolerance=tolerance, flip=flip, allow_far=allow_far)
        apply_fold_normals(cn, mesh, model, folds_for(model), flip=flip)  # one-sided normals on fold lines
        return cn.normals, cn.corner_normals, cn.face, cn.distance, cn.element_face, cn
    from cadbridge.normals.estimators import estimate_normals

    n = estimate_normals(mesh.nodes, blocks, method=method)
    if flip:
        n = -n
    return n, [n[b] for b in blocks], None, None, None, None

def consistently_oriented(mesh: Mesh, orient: bool) -> Mesh:
    """``mesh`` if its elements agree in orientation, else re-oriented (``orient``) or an
    error naming the first pair of elements that disagree."""
    from cadbridge.mesh.mesh import MeshError
    from cadbridge.mesh.topology import orient_consistently, orientation_conflicts

    bad = orientation_conflicts(mesh)
    if len(bad) == 0:
        return mesh
    if not orient:
        raise MeshError(
            f"{mesh.name}: inconsistent element orientation: elements {int(bad[0, 0])} and {int(bad[0, 1])} "
            f"traverse their shared edge in the same direction ({len(bad)} such pairs); use --orient to "
            f"re-orient the mesh"
        )
    oriented, _ = orient_consistently(mesh)
    oriented.name = mesh.name
    return oriented

def tools_from_mesh(
    mesh: Mesh,
    model,
    *,
    method: str = "cad",
    name: str | None = None,
    grid: int = 10,
    tolerance: float | None = None,
    flip: bool = False,
    allow_far: bool = False,
    projector: CadProjector | None = None,
    progress=None,
    orient: bool = False,
    meshed_per_face: bool = False,
    measure: bool = True,
    edge_rule: str = "bounded",
    known_normals=None,
) -> list[ToolResult]:
    """Tools of ``mesh`` on ``model`` (None: estimated normals, no CAD errors): normals
    (`tool_normals`; ``known_normals`` its ``known``), one tool per connected part (`tool_groups`), Nagata patches and their
    errors (`build_tool`). ``orient``: re-orient an inconsistently wound mesh
    (`consistently_oriented`) instead of raising. ``meshed_per_face``: the mesh was made face
    by face from this CAD (gmsh), so no element can span two faces; only crease lines inside
    faces are checked for straddling elements; and nodes the mesher left off their trimmed
    face are moved onto it (`cadbridge.tool.onto_cad`; ``ToolResult.moved_nodes``).
    ``measure``: False skips the errors against the CAD (`build_tool`). ``edge_rule``:
    "bounded" or "published" (`cadbridge.nagata.edge`)."""
    progress = progress or NoProgress()
    mesh = consistently_oriented(mesh, orient)
    progress.stage(f"{mesh.name}: {'projecting nodes onto the CAD' if method == 'cad' else method + ' normals'}"
                   f" ({len(mesh.nodes)} nodes)")
    normals, corners, node_face, node_dist, elem_face, cn = tool_normals(
        mesh, model, method, tolerance=tolerance, flip=flip, allow_far=allow_far, known=known_normals
    )
    moved = None
    if cn is not None and meshed_per_face:  # cadbridge's own mesh: its nodes onto their feet
        from cadbridge.tool.onto_cad import onto_cad

        mesh, moved = onto_cad(mesh, cn.projection.foot, cn.distance, cn.status, model.size(), node_face=cn.face,
                               element_face=cn.element_face)
        if len(moved):
            node_dist = node_dist.copy()
            node_dist[moved.nodes] = 0.0
    straddle = np.zeros(mesh.n_elements, dtype=bool)
    if cn is not None:
        from cadbridge.heal.creases import straddling_elements

        between = not meshed_per_face
        straddle[straddling_elements(element_blocks(mesh), model, cn.face, cn.u, cn.v,
                                     mesh.nodes if between else None, cn.normals if between else None,
                                     element_face=cn.element_face)] = True
        from cadbridge.heal.folds import fold_straddling, folds_for

        straddle[fold_straddling(element_blocks(mesh), model, folds_for(model), mesh.nodes, cn.face, cn.u, cn.v)] = True
    if model is None:
        groups = {"": [np.ones(len(b), dtype=bool) for b in mesh.cells]}
    else:
        if elem_face is None:  # estimated normals: the CAD still names the tools
            projector = projector or CadProjector(model, progress)
            cent = np.concatenate([mesh.nodes[b].mean(axis=1) for b in element_blocks(mesh)])
            elem_face = _split(projector.project(cent).face, mesh)
        groups = tool_groups(mesh, model, elem_face)
    tools = []
    for gname, masks in groups.items():
        label = gname.lower() if gname.isupper() else gname  # IGES names are upper case
        tname = (f"{name}_{label}" if len(groups) > 1 else name) if name else (label or "tool")
        if all(m.all() for m in masks):
            sub, used, kept = mesh, np.arange(len(mesh.nodes)), [True] * len(masks)
        else:
            sub, used, kept = _submesh(mesh, masks, tname)
        sub_corners = [c[m] for c, m, k in zip(corners, masks, kept) if k]
        sel = np.concatenate(masks)  # this tool's elements, in block order
        tools.append(build_tool(
            tname, sub, normals[used], sub_corners, method, model=model, grid=grid,
            node_face=None if node_face is None else node_face[used],
            node_distance=None if node_dist is None else node_dist[used],
            projector=projector, progress=progress,
            element_face=None if elem_face is None else np.concatenate(elem_face)[sel],
            straddling=np.flatnonzero(straddle[sel]), measure=measure, edge_rule=edge_rule,
        ))
        if moved is not None:
            mine = np.zeros(len(mesh.nodes), dtype=bool)
            mine[used] = True
            tools[-1].moved_nodes = moved.distance[mine[moved.nodes]]
    return tools

def check_tools(tools: list[ToolResult], allow_worse: bool = False, refinement: str = "") -> None:
    """The guard: raise `ToolQualityError` if a tool has elements that straddle a crease, or
    its Nagata surface is worse than its flat mesh (max surface error on the same samples),
    naming the worst elements and why; ``allow_worse`` lets such tools through (for
    inspection: the summary still says so). ``refinement``: what the refinement where the
    guards tripped did (`cadbridge.tool.guard_refinement.GuardRefinement.failure`, e.g.
    "after 3 refinement rounds"), said in the message."""
    bad = [t for t in tools if t.diagnosis]
    if bad and not allow_worse:
        msg = " | ".join(f"{t.name}: {d}" for t in bad for d in t.diagnosis)
        done = f"{refinement}; " if refinement else ""
        raise ToolQualityError(f"{msg} ({done}nothing written; --allow-worse writes the tool anyway, for inspection)")
