"""The whole chain for one CAD file or mesh: mesh -> normals -> Nagata patches -> tool files
+ report (`convert`), or from a given mesh (`nagata_from_mesh`).

Everything is computed first and written last (`cadbridge.tool.outputs.staged_output`), so
an error never leaves partial output behind. Long stages report to an optional
``progress`` object (`cadbridge.common.progress.Progress` from the CLI; silent by default).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from cadbridge.mesh.mesh import Mesh
from cadbridge.tool.build import (CadProjector, check_tools, measure_tool, NoProgress, ToolQualityError, ToolResult,
                                  tools_from_mesh)
from cadbridge.tool import outputs
from cadbridge.tool.meshing import healed_notes, mesh_for_tools, read_healed
from cadbridge.tool.outputs import staged_output, write_tool_outputs

__all__ = ["RunResult", "convert", "guarded_mesh", "nagata_from_mesh"]


@dataclass
class RunResult:
    output: Path
    tools: list[ToolResult] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # what was done on the way (mesh clean-up, ...)

    def summary(self) -> str:
        nan = float("nan")
        lines = [f"wrote {len(self.files)} files to {self.output}"]
        w = max([16] + [len(t.name) + 2 for t in self.tools])  # long names keep their own column
        lines.append(f"  {'tool':<{w}}{'source':<8}{'nodes':>7}{'elems':>7}{'surface err':>13}{'boundary err':>14}"
                     f"{'flat err':>11}{'normal err':>12}")
        for t in self.tools:
            s = t.stats
            lines.append(
                f"  {t.name:<{w}}{t.normal_source:<8}{len(t.mesh.nodes):>7}{t.mesh.n_elements:>7}"
                f"{s.get('max_abs_surface_error', nan):>13.3e}{s.get('max_boundary_error', nan):>14.3e}"
                f"{s.get('max_abs_flat_surface_error', nan):>11.3e}{s.get('max_normal_error_deg', nan):>11.4f}°"
            )
        for t in self.tools:
            by_rule = t.stats.get("shape_error_by_rule")
            if by_rule:
                rule = t.nagata.edge_rule
                lines.append(f"  {t.name}: shape err by edge rule: " + ", ".join(
                    f"{r} {e:.3e}{' (tool file)' if r == rule else ''}" for r, e in by_rule.items()))
        if any(t.stats for t in self.tools):
            lines.append("  surface err: max |distance| of the Nagata surface to its faces' underlying surfaces; "
                         "boundary err: max distance to the trimmed faces (includes the patches' boundary chords); "
                         "flat err: surface err of the flat mesh at the same samples"
                         + ("; shape err: the larger of surface and boundary err, per edge rule (--edge-rule)"
                            if any(t.stats.get("shape_error_by_rule") for t in self.tools) else ""))
        for t in self.tools:
            lines += [f"  {t.name}: {d}" for d in t.diagnosis]
        lines += [f"  {n}" for n in self.notes]
        return "\n".join(lines)


def meshed_face_by_face(mesh: Mesh) -> bool:
    """Whether ``mesh`` carries the face each element was meshed on (``cell_data
    ["element_entity"]`` >= 1 everywhere, written by `cadbridge.mesh.generate.mesh_cad`):
    then no element spans two faces, and only crease lines inside faces need the straddle
    check (`tools_from_mesh` ``meshed_per_face``)."""
    ent = mesh.cell_data.get("element_entity")
    return ent is not None and len(ent) == mesh.n_elements and bool(np.all(np.asarray(ent) >= 1))


def _moved_notes(tools: list[ToolResult]) -> list[str]:
    """One line per tool whose nodes were moved onto the CAD (`cadbridge.tool.onto_cad`)."""
    from cadbridge.tool.onto_cad import moved_note

    return [n for t in tools if (n := moved_note(t.name, t.moved_nodes))]


def guarded_mesh(
    cad: str,
    model,
    *,
    excursions: list,
    build: Callable[[Mesh], list[ToolResult]],
    progress=None,
    unchecked_ok: bool = False,
    **mesh_options,
):
    """The mesh stage with the guards' refinement: `mesh_for_tools` (``mesh_options``), the
    tools ``build(mesh)`` makes on it and, where they trip the straddle or reversal guard,
    meshes made again finer there (`cadbridge.tool.guard_refinement.refine_where_guards_trip`;
    gmsh only: the QIT mesher takes no size field). `convert` and `cadbridge mesh` both mesh
    through it, so `cadbridge nagata` on the mesh `cadbridge mesh` writes builds the tools
    `convert` builds. ``unchecked_ok``: where no tools can be built on the first mesh (its
    nodes do not project, `ProjectionError`, or `MeshError`), that mesh unchecked instead of
    the error. gmsh meshes the model's own B-rep (`mesh_for_tools` route "model"); where
    that gives no sound tool (an error, or guards that still trip after the refinement)
    and the file as OCC reads it does, that mesh is taken, and its notes say why. Returns a
    `GuardRefinement` (mesh, tools, notes, rounds, converged)."""
    from cadbridge.mesh.mesh import MeshError
    from cadbridge.normals.cad import ProjectionError
    from cadbridge.tool.meshing import FILE_ROUTE_NOTE

    gmsh_route = mesh_options.get("mesher", "gmsh") == "gmsh"
    first = error = None
    try:
        first = _guarded_on("model", cad, model, excursions, build, progress, unchecked_ok, mesh_options)
    except (MeshError, ProjectionError) as e:
        if not gmsh_route or FILE_ROUTE_NOTE in getattr(e, "mesh_notes", []):
            raise  # QIT, or the model's B-rep could not be meshed and this was the file already
        error, why = e, str(e)
    else:
        if not gmsh_route or (first.converged and first.tools) or FILE_ROUTE_NOTE in first.mesh_notes:
            return first
        why = first.failure or "the guards still trip"
    (progress or NoProgress()).stage(f"the mesh of the model's B-rep gave no sound tool ({why[:80]}); "
                                     f"meshing the file as OCC reads it")
    try:
        second = _guarded_on("file", cad, model, excursions, build, progress, unchecked_ok, mesh_options)
    except (MeshError, ProjectionError):
        if first is None:
            raise error from None
        return first
    if second.converged and second.tools:
        second.mesh_notes[:0] = [f"mesh: the mesh of the model's B-rep gave no sound tool ({why}); {FILE_ROUTE_NOTE[6:]}"]
        return second
    return first if first is not None else second


def _guarded_on(route: str, cad, model, excursions, build, progress, unchecked_ok: bool, mesh_options: dict):
    """`guarded_mesh` on one route of `mesh_for_tools` ("model" or "file")."""
    from cadbridge.mesh.mesh import MeshError
    from cadbridge.normals.cad import ProjectionError
    from cadbridge.tool.guard_refinement import GuardRefinement, refine_where_guards_trip

    breps: dict = {}  # the model's B-reps, built once for all rounds (`mesh_for_tools` ``brep_cache``)
    # gmsh's first mesh, kept by the rounds where they ask for nothing finer (triangles:
    # `cadbridge.mesh.gmsh.kept`)
    first: dict | None = {} if mesh_options.get("element", "quad") == "tri" else None
    mesh, notes = mesh_for_tools(cad, model, excursions=excursions, progress=progress, route=route,
                                 brep_cache=breps, keep=first, **mesh_options)
    try:
        tools = build(mesh)
    except (MeshError, ProjectionError) as e:
        if not unchecked_ok:
            e.mesh_notes = notes  # which route the mesh took, for `guarded_mesh`
            raise
        return GuardRefinement(mesh, [], notes)
    if mesh_options.get("mesher", "gmsh") != "gmsh":
        return GuardRefinement(mesh, tools, notes)

    def remesh(sizes, finer=None, floor=None):  # a round: the first mesh kept where finer is false (tri)
        if finer is None:
            return mesh_for_tools(cad, model, excursions=excursions, progress=progress, route=route, brep_cache=breps,
                                  **{**mesh_options, "curvature_elements": 0}, local_sizes=sizes)
        return mesh_for_tools(cad, model, excursions=excursions, progress=progress, route=route, brep_cache=breps,
                              **mesh_options, local_sizes=sizes, min_size=floor, keep={**first, "finer": finer})

    return refine_where_guards_trip(mesh, tools, notes, model, progress=progress, build=build, remesh=remesh,
                                    keep_first=first is not None and "snapshot" in first)


def nagata_from_mesh(
    mesh_path: str,
    *,
    cad: str | None = None,
    output: str,
    method: str = "cad",
    name: str | None = None,
    report: bool = True,
    tolerance: float | None = None,
    flip: bool = False,
    allow_far: bool = False,
    grid: int = 10,
    progress=None,
    orient: bool = False,
    allow_worse: bool = False,
    edge_rule: str = "bounded",
) -> RunResult:
    """`cadbridge nagata`: tool file(s) + report from a user mesh (and the CAD).

    ``orient`` re-orients an inconsistently wound mesh instead of stopping with an error. A
    mesh that says which CAD face each element was meshed on (`meshed_face_by_face`: the
    meshes cadbridge writes) is checked as `convert` checks its own mesh.
    Raises `ToolQualityError` when a tool is worse than its flat mesh (`check_tools`),
    unless ``allow_worse``. ``edge_rule``: "bounded" (default) or "published", the rule of
    the edge coefficients (`cadbridge.nagata.edge`); with a CAD the summary gives the surface
    error of both rules.

    Example::

        >>> run = cadbridge.nagata_from_mesh("die.msh", cad="die.igs", output="die_tool/")  # doctest: +SKIP
    """
    from cadbridge.mesh.io import read_mesh
    from cadbridge.nagata import check_edge_rule

    progress = progress or NoProgress()
    check_edge_rule(edge_rule)
    if cad is None and method == "cad":
        raise ValueError("--method cad needs --cad FILE.igs")
    model, excursions = read_healed(cad, progress) if cad is not None else (None, [])  # as convert reads it
    progress.stage(f"reading {mesh_path}")
    mesh = read_mesh(mesh_path)
    mesh.name = Path(mesh_path).stem
    projector = CadProjector(model, progress) if model is not None else None
    tools = tools_from_mesh(mesh, model, method=method, name=name, grid=grid, tolerance=tolerance, flip=flip,
                            allow_far=allow_far, projector=projector, progress=progress, orient=orient,
                            meshed_per_face=meshed_face_by_face(mesh), measure=False, edge_rule=edge_rule)
    check_tools(tools, allow_worse)  # the guards, before the errors are measured (as `convert`)
    for t in tools:
        measure_tool(t, model, projector=projector, grid=grid, progress=progress, compare_rules=True)
    check_tools(tools, allow_worse)
    units = model.units.name if model is not None else "MM"
    result = RunResult(Path(output), tools, notes=healed_notes(excursions) + _moved_notes(tools))
    with staged_output(output) as tmp:
        pictures = _pictures(tools, tmp, units) if report else {}

        def files() -> None:
            for t in tools:
                progress.stage(f"{t.name}: writing tool file{' and report' if report else ''}")
                result.files += write_tool_outputs(t, tmp, units, cad, report, projector, pictures=False)
                result.files += [n for n, _ in pictures.get(t.name, [])]

        _write_with_pictures(files, tools, pictures, progress)
    return result


def _pictures(tools: list[ToolResult], folder: Path, units: str) -> dict[str, list]:
    """{tool name: [(file name, job)]} of the tools' report pictures (`outputs.tool_pictures`)."""
    return {t.name: outputs.tool_pictures(t, folder, units) for t in tools}


def _write_with_pictures(files: Callable[[], None], tools: list[ToolResult], pictures: dict[str, list],
                         progress) -> None:
    """``files()`` (the tool files, VTUs, listings) here while a forked copy of the process
    draws the ``pictures`` of `_pictures` (`cadbridge.common.fork_jobs.run_jobs`); this
    process takes its share of them when its files are written. The largest tools'
    pictures go first. On the production die the pictures are about 12 s of CPU in
    matplotlib, the files 4 s."""
    from cadbridge.common.fork_jobs import run_jobs

    order = sorted(tools, key=lambda t: -t.nagata.n_elements)
    jobs = [job for t in order for _, job in pictures.get(t.name, [])]
    jobs[:0] = [job for _, job in pictures.get("adaptive report", [])]  # a map of the largest tool: first

    def first() -> None:
        files()
        if jobs:
            progress.stage(f"drawing the report pictures ({len(jobs)} PNG files)")

    run_jobs(jobs, first=first)



def convert(
    cad: str,
    output: str,
    *,
    element: str = "quad",
    size: float | None = None,
    structured: bool = False,
    radius_divisions: int = 3,
    length_divisions: int | None = None,
    method: str = "cad",
    grid: int = 10,
    flip: bool = False,
    tolerance: float | None = None,
    progress=None,
    allow_worse: bool = False,
    curvature_elements: int = 12,
    shape_tolerance: float | None = None,
    min_size: float | None = None,
    mesher: str = "gmsh",
    full_report: bool = False,
    edge_rule: str = "bounded",
) -> RunResult:
    """`cadbridge convert`: mesh the CAD with gmsh (or ``mesher="qit"``, `cadbridge.mesh.qit.mesher`),
    exact normals, Nagata, tool files, report.

    ``shape_tolerance``: the mesh is sized and refined until the Nagata surface is within it
    (`cadbridge.tool.refine.refine_mesh`, ``size`` the largest element, ``min_size`` the floor);
    the adaptive report goes with the outputs, and a tolerance not met raises
    `ToolQualityError` naming the elements after the best mesh's outputs are written.

    Crease lines inside faces (`cadbridge.heal.creases.crease_lines`) become mesh edges.
    ``curvature_elements`` (gmsh ``Mesh.MeshSizeFromCurvature``): elements per full turn of
    the normal; the default 12 gives 30 degrees per element, the normalized edge length 0.52
    of thesis Fig. 8 (0.06 % radial error) and 3 elements across a quarter fillet (§5.2).
    Where elements straddle a crease or the CAD normal reverses inside them, the mesh is made
    again finer there, 3 rounds at most (`guarded_mesh`); the notes say which faces and
    elements and how many rounds. Raises `ToolQualityError` when a tool is worse than its
    flat mesh or those elements remain (the message says after how many rounds), unless
    ``allow_worse``. ``full_report``: the per-patch listings also for tools above
    `cadbridge.tool.outputs.LISTING_MAX_ELEMENTS` elements. ``edge_rule``: "bounded" (default)
    or "published", the rule of the edge coefficients (`cadbridge.nagata.edge`); the summary
    gives the surface error of both rules.

    Example::

        >>> import cadbridge
        >>> run = cadbridge.convert("die.igs", "die_out/", element="quad")   # doctest: +SKIP
        >>> [t.name for t in run.tools], run.tools[0].stats["max_abs_surface_error"]  # doctest: +SKIP
    """
    from cadbridge.mesh.io import write_mesh
    from cadbridge.nagata import check_edge_rule

    check_edge_rule(edge_rule)
    cad = str(cad)  # a Path as well (the tool file records the source as text)
    progress = progress or NoProgress()
    model, excursions = read_healed(cad, progress)
    if shape_tolerance is not None:  # sized and refined for a Nagata shape tolerance
        from cadbridge.tool.refine import refine_mesh

        projector = CadProjector(model, progress)
        adaptive = refine_mesh(cad, shape_tolerance, element=element, max_size=size, min_size=min_size,
                               model=model, projector=projector, progress=progress, loop_cuts=excursions,
                               edge_rule=edge_rule)
        mesh, notes = adaptive.mesh, healed_notes(excursions) + list(adaptive.mesh.notes)
    else:
        adaptive = None
        # the search index (2-3 s of CPU on the production die) is built on a second thread
        # while gmsh meshes (gmsh's calls release the GIL); nothing uses it before the mesh is made
        pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="cadbridge-index")
        pending = pool.submit(CadProjector, model, progress)
        pool.shutdown(wait=False)
    stem = Path(cad).stem

    def build(m: Mesh) -> list[ToolResult]:  # the tools and their guards; errors vs CAD measured last
        nonlocal projector
        projector = projector or pending.result()
        m.name = stem
        return tools_from_mesh(m, model, method=method, grid=grid, tolerance=tolerance, flip=flip,
                               projector=projector, progress=progress, orient=True, meshed_per_face=True,
                               measure=False, edge_rule=edge_rule)

    refined = ""
    if adaptive is None:
        projector = None
        try:
            guarded = guarded_mesh(cad, model, excursions=excursions, build=build, progress=progress,
                                   element=element, size=size, structured=structured,
                                   radius_divisions=radius_divisions, length_divisions=length_divisions,
                                   curvature_elements=curvature_elements, mesher=mesher)
        finally:
            pending.exception()  # the thread has ended before anything else runs (an error of its is raised below)
        projector = projector or pending.result()
        mesh, tools, notes = guarded.mesh, guarded.tools, guarded.mesh_notes + guarded.notes
        refined = "" if guarded.converged else guarded.failure
    elif method == "cad" and tolerance is None and not flip:
        # the loop's tools of its best mesh are what `build` would make of it (the same call
        # but for the measure, whose grid `measure_tool` keeps where the divisions agree)
        tools = adaptive.tools
    else:
        tools = build(mesh)
    # a guard that stayed tripped refuses the tools whatever their errors: not measured first
    # (trj4_s1 quad: 42 of the 82 s before its refusal); then worse than flat, once measured
    check_tools(tools, allow_worse, refinement=refined)
    for t in tools:
        measure_tool(t, model, projector=projector, grid=grid, progress=progress, compare_rules=True)
    check_tools(tools, allow_worse, refinement=refined)
    result = RunResult(Path(output), tools, notes=notes + _moved_notes(tools))
    with staged_output(output) as tmp:
        pictures = _pictures(tools, tmp, model.units.name)
        if adaptive is not None:
            pictures["adaptive report"] = adaptive.picture_jobs(tmp, model, projector)

        def files() -> None:
            write_mesh(mesh, tmp / f"{mesh.name}_mesh.msh")
            result.files.append(f"{mesh.name}_mesh.msh")
            for t in tools:
                progress.stage(f"{t.name}: writing tool file and report")
                result.files += write_tool_outputs(t, tmp, model.units.name, cad, True, projector,
                                                   listings=True if full_report else None, pictures=False)
                result.files += [n for n, _ in pictures[t.name]]
                if not full_report and t.nagata.n_elements > outputs.LISTING_MAX_ELEMENTS:
                    result.notes.append(f"{t.name}: {t.nagata.n_elements} elements: grid CSV, coefficient listing and "
                                        f"Nagata IGES not written (above {outputs.LISTING_MAX_ELEMENTS}; --full-report "
                                        f"writes them)")
            if adaptive is not None:
                result.files += adaptive.write_report(tmp, model, projector, pictures=False)

        _write_with_pictures(files, tools, pictures, progress)
    if adaptive is not None:
        result.adaptive = adaptive  # cadbridge.tool.refine.AdaptiveResult (the CLI prints its summary)
        if not adaptive.met:
            raise ToolQualityError(adaptive.failure_message())
    return result
