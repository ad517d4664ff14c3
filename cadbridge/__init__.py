"""cadbridge: IGES/NURBS CAD to Nagata-patch tool files for sheet metal forming simulation.

The chain (see ARCHITECTURE.md): ``read_iges`` -> ``Model`` of exact NURBS faces; a mesh
(``mesh_cad`` with gmsh, or ``read_mesh``); ``project_points`` / ``cad_normals`` for exact
node normals (or ``estimate_normals``); ``NagataMesh`` patches; tool files and reports
(``cadbridge.io``, ``cadbridge.pipeline``).
"""

from cadbridge.iges import IgesError, read_iges, read_iges_string, write_iges
from cadbridge.mesh import CellBlock, Mesh, MeshError, read_mesh, write_mesh
from cadbridge.model import Diagnostic, Face, Model, Trim, TrimLoop, Units
from cadbridge.nagata import NagataMesh
from cadbridge.normals.estimators import METHODS, estimate_normals
from cadbridge.nurbs import NurbsCurve, NurbsSurface
from cadbridge.search import BEYOND_TOLERANCE, CONVERGED, FAILED, ON_BOUNDARY, Projection, project_points

__version__ = "0.1.0"

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
    "estimate_normals",
    "project_points",
    "read_iges",
    "read_iges_string",
    "read_mesh",
    "write_iges",
    "write_mesh",
]


def __getattr__(name: str):
    if name == "cad_normals":  # imports the projection stack; keep `import cadbridge` light
        from cadbridge.normals.cad import cad_normals

        return cad_normals
    if name == "mesh_cad":
        from cadbridge.mesh.generate import mesh_cad

        return mesh_cad
    raise AttributeError(f"module 'cadbridge' has no attribute {name!r}")
