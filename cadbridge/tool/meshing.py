"""The CAD and mesh stages of the tool chain, shared by `cadbridge convert` and the
step-by-step commands (`cadbridge mesh`, `normals`, `nagata`), so both make the same tools.

`read_cad`: the model as every tool stage uses it (trim-loop excursions cut out,
`cadbridge.heal.loop_excursions`). `mesh_for_tools`: the mesh of `convert` (crease and fold
lines inside faces as mesh edges, faces as the reader read them, consistent orientation).
"""

from __future__ import annotations

import math
from pathlib import Path

from cadbridge.cad.model import Model
from cadbridge.common.progress import NoProgress
from cadbridge.heal.loop_excursions import Excursion
from cadbridge.mesh.mesh import Mesh

__all__ = ["healed_notes", "mesh_for_tools", "read_cad"]


def read_cad(cad: str | Path, progress=None) -> tuple[Model, list[Excursion]]:
    """The IGES model of ``cad`` with its trim-loop excursions cut out (in place, before any
    search index or fold line is computed on it), and the excursions cut."""
    from cadbridge.heal.loop_excursions import heal_excursions
    from cadbridge.iges import read_iges
    from cadbridge.iges.trimcheck import check_trim_agreement

    (progress or NoProgress()).stage(f"reading {cad}")
    model = read_iges(str(cad))  # fails early, before anything is meshed or written, on a bad file
    check_trim_agreement(model)  # a face with two boundaries far apart: refused before meshing
    excursions = heal_excursions(model)  # trim loops that run back beside themselves: cut out
    return model, excursions


def healed_notes(excursions: list[Excursion]) -> list[str]:
    """One report line per excursion cut by `read_cad`."""
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
) -> tuple[Mesh, list[str]]:
    """The mesh `convert` builds its tools on, and what was done on the way.

    ``model`` and ``excursions`` come from `read_cad` (``cad``). Crease lines
    (`cadbridge.heal.creases.crease_lines`) and fold lines (`cadbridge.heal.folds.folds_for`)
    inside faces become mesh edges; the mesher reads the faces as the reader read them
    (`cadbridge.heal.mesh_source`) without the excursions; the elements are then oriented
    consistently (`cadbridge.tool.build.consistently_oriented`: the lowest element of each
    connected part keeps gmsh's orientation), so the mesh written to a file needs no
    ``--orient``. The mesh is named after ``cad``. Options as `cadbridge.mesh.generate.mesh_cad`;
    ``local_sizes`` (points (M, 3), sizes (M,)) is its ``background_sizes``.

    Returns (mesh, notes): the notes are the healed excursions and the mesher's notes.
    """
    from cadbridge.heal.creases import crease_lines
    from cadbridge.heal.folds import folds_for
    from cadbridge.heal.mesh_source import mesh_source
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.tool.build import consistently_oriented

    progress = progress or NoProgress()
    if size is not None and size > 0 and math.isfinite(size):  # a size far too small: refused before meshing
        from cadbridge.mesh.element_count import check_element_count

        check_element_count(model, size, element)
    creases = crease_lines(model)  # C0 knot lines where the normal jumps: mesh edges go there
    folds = folds_for(model).lines  # lines where a face runs back over itself: mesh edges too
    progress.stage(f"meshing {Path(cad).name} with {mesher}"
                   + (f" ({len(creases)} crease lines inside faces become mesh edges)" if creases else "")
                   + (f" ({len(folds)} fold lines inside faces become mesh edges)" if folds else ""))
    with mesh_source(cad, model) as source:  # the file as cadbridge read it (faces re-read by the reader)
        mesh = mesh_cad(source, element=element, size=size, structured=structured,
                        radius_divisions=radius_divisions, length_divisions=length_divisions,
                        curvature_elements=curvature_elements,
                        embed_curves=[c.curve for c in creases] + [f.curve for f in folds],
                        mesher=mesher, loop_cuts=excursions, background_sizes=local_sizes)
    mesh.name = Path(cad).stem
    if mesh.n_elements == 0:  # e.g. a default size from a bounding box one far control point inflates
        from cadbridge.mesh.mesh import MeshError

        lo, hi = model.bbox()
        raise MeshError(f"{Path(cad).name}: the mesher made no elements (element size "
                        f"{'the bounding box diagonal / 20' if size is None else f'{size:g}'}; the model's bounding box "
                        f"runs from ({', '.join(f'{x:.6g}' for x in lo)}) to ({', '.join(f'{x:.6g}' for x in hi)}))")
    notes = healed_notes(excursions) + list(mesh.notes)
    return consistently_oriented(mesh, True), notes
