"""The CAD and mesh stages of the tool chain, shared by `cadbridge convert` and the
step-by-step commands (`cadbridge mesh`, `normals`, `nagata`), so both make the same tools.

`read_healed`: the model as every tool stage uses it (trim-loop excursions cut out,
`cadbridge.heal.loop_excursions`). `mesh_for_tools`: the mesh of `convert` (the model itself
meshed, `cadbridge.heal.brep`; crease and fold lines inside faces as mesh edges; consistent
orientation).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from cadbridge.cad.model import Model
from cadbridge.common.progress import NoProgress
from cadbridge.heal.loop_excursions import Excursion
from cadbridge.mesh.mesh import Mesh

__all__ = ["FILE_ROUTE_NOTE", "healed_notes", "mesh_for_tools", "read_healed"]

FILE_ROUTE_NOTE = "mesh: meshed the file as OCC reads it instead"
"""The note of a mesh made of the file as OCC reads it where the model's B-rep was asked for."""


def read_healed(cad: str | Path, progress=None) -> tuple[Model, list[Excursion]]:
    """The model of ``cad`` (IGES or STEP, `cadbridge.formats.read_cad`) with its trim-loop excursions cut out (in place, before any
    search index or fold line is computed on it), and the excursions cut."""
    from cadbridge.formats import read_cad
    from cadbridge.heal.loop_excursions import heal_excursions
    from cadbridge.heal.winding_loops import close_winding_loops
    from cadbridge.iges.trimcheck import check_trim_agreement

    (progress or NoProgress()).stage(f"reading {cad}")
    model = read_cad(cad)  # fails early, before anything is meshed or written, on a bad file
    check_trim_agreement(model)  # a face with two boundaries far apart: refused before meshing
    close_winding_loops(model)  # loops round a closed surface: closed on the side they bound
    excursions = heal_excursions(model)  # trim loops that run back beside themselves: cut out
    return model, excursions


def healed_notes(excursions: list[Excursion]) -> list[str]:
    """One report line per excursion cut by `read_healed`."""
    return [f"trim defect healed: {e}" for e in excursions]


def mesh_for_tools(
    cad: str | Path,
    model: Model,
    *,
    excursions: list[Excursion],
    element: str = "quad",
    size: float | None = None,
    structured: bool = False,
    radius_divisions: int = 3,
    length_divisions: int | None = None,
    curvature_elements: int = 12,
    mesher: str = "gmsh",
    progress=None,
    local_sizes=None,
    route: str = "model",
    brep_cache: dict | None = None,
    keep: dict | None = None,
    min_size: float | None = None,
) -> tuple[Mesh, list[str]]:
    """The mesh `convert` builds its tools on, and what was done on the way.

    ``model`` and ``excursions`` come from `read_healed` (``cad``). Crease lines
    (`cadbridge.heal.creases.crease_lines`) and fold lines (`cadbridge.heal.folds.folds_for`)
    inside faces become mesh edges; gmsh meshes the model itself (`_mesh_model_brep`), or
    where that cannot be meshed the file as OCC reads it (`cadbridge.heal.mesh_source`),
    without the excursions; QIT meshes the file's faces. The elements are then oriented
    consistently (`cadbridge.tool.build.consistently_oriented`: the lowest element of each
    connected part keeps gmsh's orientation), so the mesh written to a file needs no
    ``--orient``. The mesh is named after ``cad``. Options as `cadbridge.mesh.generate.mesh_cad`;
    ``local_sizes`` (points (M, 3), sizes (M,)) is its ``background_sizes``.

    ``route``: "model" (gmsh on the model's B-rep, the file as OCC reads it where that cannot
    be meshed: the notes then hold `FILE_ROUTE_NOTE`) or "file" (the file as OCC reads it).
    ``brep_cache``: a dict the caller keeps across calls on the same ``model`` (the guards'
    refinement rounds), so the model's B-rep is built once (`_mesh_model_brep`).
    ``keep``, ``min_size``: `cadbridge.mesh.generate.mesh_cad`'s (gmsh's first mesh, kept by the
    rounds; the floor of the curvature rule there).

    Returns (mesh, notes): the notes are the healed excursions and the mesher's notes.
    """
    from cadbridge.heal.creases import crease_lines
    from cadbridge.heal.folds import folds_for
    from cadbridge.heal.mesh_source import mesh_source
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.tool.build import consistently_oriented

    progress = progress or NoProgress()
    size_note = _far_nets_note(model) if size is None and mesher == "gmsh" else None
    if size is not None and size > 0 and math.isfinite(size):  # a size far too small: refused before meshing
        from cadbridge.mesh.element_count import check_element_count

        check_element_count(model, size, element)
    creases = crease_lines(model)  # C0 knot lines where the normal jumps: mesh edges go there
    folds = folds_for(model).lines  # lines where a face runs back over itself: mesh edges too
    progress.stage(f"meshing {Path(cad).name} with {mesher}"
                   + (f" ({len(creases)} crease lines inside faces become mesh edges)" if creases else "")
                   + (f" ({len(folds)} fold lines inside faces become mesh edges)" if folds else ""))
    lines = [(c.face, c.curve) for c in creases] + [(f.face, f.curve) for f in folds]
    opts = dict(element=element, size=size, structured=structured, radius_divisions=radius_divisions,
                length_divisions=length_divisions, curvature_elements=curvature_elements,
                embed_curves=[c for _, c in lines], mesher=mesher, loop_cuts=excursions,
                background_sizes=local_sizes, keep=keep, min_size=min_size)
    mesh, tried = _mesh_model_brep(model, lines, opts, brep_cache) if mesher == "gmsh" and route == "model" else (None, [])
    if mesh is None:  # QIT (it meshes the file's faces itself), or the B-rep could not be meshed
        with mesh_source(cad, model) as source:  # the file as cadbridge read it (faces re-read by the reader)
            mesh = mesh_cad(source, **opts)
        mesh.notes = tried + list(mesh.notes)
    mesh.name = Path(cad).stem
    if mesh.n_elements == 0:  # e.g. a default size from a bounding box one far control point inflates
        from cadbridge.mesh.mesh import MeshError

        lo, hi = model.bbox()
        raise MeshError(f"{Path(cad).name}: the mesher made no elements (element size "
                        f"{'the bounding box diagonal / 20' if size is None else f'{size:g}'}; the model's bounding box "
                        f"runs from ({', '.join(f'{x:.6g}' for x in lo)}) to ({', '.join(f'{x:.6g}' for x in hi)}))")
    notes = healed_notes(excursions) + ([size_note] if size_note else []) + list(mesh.notes)
    return consistently_oriented(mesh, True), notes


def _far_nets_note(model: Model) -> str | None:
    """A note where the default element size (gmsh's box of the control nets / 20) is far above
    the part's (`cadbridge.cad.extent.trimmed_box` / 20): rational faces with far poles of tiny
    weight (trj6_b1: nets reaching 26.5 m on a 304 mm part, 87 x). None where the two boxes
    agree within `FAR_NETS` x. The default itself stays the nets' box: taken from the trimmed
    faces it moved every file's mesh and exposed gmsh failures at the new sizes (a segfault in
    algorithm 8 on bug24283's sphere, an odd curve in the spring's quads)."""
    from cadbridge.cad.extent import loop_start_box, trimmed_box

    lo, hi = loop_start_box(model)  # a part at least this large: most models stop here
    if model.size() <= FAR_NETS * float(np.linalg.norm(hi - lo)):
        return None
    lo, hi = trimmed_box(model)
    part = float(np.linalg.norm(hi - lo))
    if not part > 0 or model.size() <= FAR_NETS * part:
        return None
    return (f"mesh: the default element size comes from the faces' control nets, whose box ({model.size():.4g}) is "
            f"{model.size() / part:.3g} x the trimmed part's ({part:.4g}; rational faces with far poles); "
            f"--size {part / 20:.3g} sizes the mesh by the part")


FAR_NETS = 4.0
"""The nets' box above this x the trimmed part's diagonal gets `_far_nets_note`."""


def _mesh_model_brep(model: Model, lines: list, opts: dict, cache: dict | None = None) -> tuple[Mesh | None, list[str]]:
    """gmsh's mesh of the model itself (`cadbridge.heal.brep`): face k of the mesh is face k
    of the model by construction, crease and fold lines are embedded in their own faces, and
    the excursions are already cut out of the model's loops. Sewn first at the mesher's
    tolerance (`SEW_TOLERANCE_MM`), then, where OCC cannot make the faces' wires of that
    (trims that miss each other by more: gmsh's import fails), at the file's trim tolerance.
    Last, the B-rep sewn at the mesher's tolerance is imported without gmsh sewing it again:
    gmsh's second sewing can leave a face a wire it cannot close ("Could not fix wire";
    K1 from CADDS, 4 STEP files of the corpus).
    Returns (mesh, notes); mesh None where none meshes (`MeshError`): `convert` then
    meshes the file as OCC reads it, and the notes say why.
    ``lines``: (model face index, curve) of each crease and fold line; ``opts``: `mesh_cad`'s.
    ``cache``: kept by the caller across the refinement rounds of one model: the B-reps built
    (a round meshes the same B-rep with other sizes) and the attempt that meshed, where the
    next round starts."""
    from cadbridge.heal.brep import SEW_TOLERANCE_MM, brep_source, trim_sew_tolerance
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.mesh.mesh import MeshError
    from OCP.Standard import Standard_Failure

    failures: list[str] = []
    # (cadbridge's sewing tolerance, gmsh sews again): gmsh's own sewing of the sewn B-rep last
    # left out, since it can break wires cadbridge's sewing made (gmsh: "Could not fix wire")
    cache = {} if cache is None else cache
    trim_tolerance = trim_sew_tolerance(model)
    attempts = ((None, True), (trim_tolerance, True), (None, False))
    for i, (sew, gmsh_sews) in enumerate(attempts):
        if i < cache.get("meshed", 0):
            continue  # failed in an earlier round on the same model
        if sew is not None and sew <= SEW_TOLERANCE_MM / model.units.to_mm:
            continue  # the trim tolerance is the mesher's: the first attempt was this one
        try:
            with brep_source(model, sew_tolerance=sew, brep=cache.get(sew)) as (source, brep):
                cache[sew] = brep
                mesh = mesh_cad(source, straight_splines=True, exact_curve_nodes=True, embed_faces=[k for k, _ in lines],
                                face_anchors=brep.anchors, sew=gmsh_sews, **{**opts, "loop_cuts": ()})
        except (MeshError, ValueError, Standard_Failure) as e:  # ValueError: a trim no cubic follows
            failures.append(f"mesh: the model's B-rep sewn at {_sew_text(sew, model)}"
                            f"{'' if gmsh_sews else ' and imported without gmsh sewing again'} could not be meshed ({e})")
            continue
        cache["meshed"] = i
        mesh.notes = failures + brep.notes() + list(mesh.notes)
        return mesh, []
    failures.append(FILE_ROUTE_NOTE)
    return None, failures


def _sew_text(sew: float | None, model: Model) -> str:
    """The sewing tolerance in words, for the notes."""
    from cadbridge.heal.brep import SEW_TOLERANCE_MM

    return f"{SEW_TOLERANCE_MM / model.units.to_mm:.3g}" if sew is None else f"the trim tolerance {sew:.3g}"
