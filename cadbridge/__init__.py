"""cadbridge: IGES/STEP NURBS CAD to Nagata-patch tool files for sheet metal forming simulation.

The product in one call: ``convert("die.igs", "out/")`` (or ``"die.stp"``) (mesh, exact normals, Nagata
patches, tool files and report; ``nagata_from_mesh`` from a mesh of your own), and beside
it ``map_results`` (simulation results on the exact CAD), ``fit_points`` (a NURBS surface
from points), ``read_toolfile`` / ``write_toolfile``. ``convert`` and ``nagata_from_mesh`` take
``edge_rule="bounded"`` (default) or ``"published"`` (Nagata 2005 exactly; README "Edge rule").

The chain underneath (ARCHITECTURE.md): ``read_cad`` (IGES or STEP, by content; ``read_iges``,
``read_step``) -> ``Model`` of exact NURBS faces; a
mesh (``mesh_cad`` with gmsh, or ``read_mesh``); ``project_points`` / ``cad_normals`` for
exact node normals (or ``estimate_normals``); ``NagataMesh`` patches.
"""

from cadbridge.iges import IgesError, read_iges, read_iges_string, write_iges
from cadbridge.mesh import CellBlock, Mesh, MeshError, read_mesh, write_mesh
from cadbridge.cad.model import Diagnostic, Face, Model, Trim, TrimLoop, Units
from cadbridge.nagata import NagataMesh
from cadbridge.normals.estimators import METHODS, estimate_normals
from cadbridge.nurbs import NurbsCurve, NurbsSurface
from cadbridge.cad.search import BEYOND_TOLERANCE, CONVERGED, FAILED, ON_BOUNDARY, Projection, project_points

from cadbridge._version import __version__

__all__ = [
    "BEYOND_TOLERANCE",
    "CONVERGED",
    "FAILED",
    "METHODS",
    "ON_BOUNDARY",
    "CellBlock",
    "Diagnostic",
    "Face",
    "IgesError",
    "Mesh",
    "MeshError",
    "Model",
    "NagataMesh",
    "NurbsCurve",
    "NurbsSurface",
    "Projection",
    "Trim",
    "TrimLoop",
    "Units",
    "cad_normals",
    "convert",
    "fit_points",
    "map_results",
    "mesh_cad",
    "nagata_from_mesh",
    "read_toolfile",
    "write_toolfile",
    "estimate_normals",
    "project_points",
    "StepError",
    "read_cad",
    "read_iges",
    "read_iges_string",
    "read_step",
    "read_mesh",
    "write_iges",
    "write_mesh",
]


# heavy parts (the projection stack, gmsh, the pipeline) load on first use, so that
# `import cadbridge` stays light: name -> module that defines it
_LAZY = {
    "cad_normals": "cadbridge.normals.cad",
    "convert": "cadbridge.tool.pipeline",
    "fit_points": "cadbridge.fitting.surface_fit",
    "map_results": "cadbridge.results.mapping",
    "mesh_cad": "cadbridge.mesh.generate",
    "nagata_from_mesh": "cadbridge.tool.pipeline",
    "read_toolfile": "cadbridge.io.toolfile",
    "write_toolfile": "cadbridge.io.toolfile",
    "read_cad": "cadbridge.formats.read",
    "read_step": "cadbridge.step.reader",
    "StepError": "cadbridge.step.errors",
}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'cadbridge' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
