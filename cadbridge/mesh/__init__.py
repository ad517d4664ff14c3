"""Mesh layer: container, topology helpers, file I/O (meshio + GiD), gmsh meshing of CAD.

`generate.mesh_cad` needs gmsh and is imported lazily (the rest never imports gmsh/OCC).
"""

from cadbridge.mesh.io import (
    MeshWarning,
    read_gid,
    read_gid_results,
    read_mesh,
    write_gid,
    write_gid_results,
    write_mesh,
)
from cadbridge.mesh.mesh import CellBlock, Mesh, MeshError
from cadbridge.mesh.topology import (
    boundary_edges,
    connected_components,
    edge_table,
    element_areas,
    element_normals,
    node_elements,
    non_manifold_edges,
    orient_consistently,
    orientation_conflicts,
    unique_edges,
)

__all__ = [
    "CellBlock",
    "Mesh",
    "MeshError",
    "MeshWarning",
    "boundary_edges",
    "connected_components",
    "edge_table",
    "element_areas",
    "element_normals",
    "mesh_cad",
    "node_elements",
    "non_manifold_edges",
    "orient_consistently",
    "orientation_conflicts",
    "read_gid",
    "read_gid_results",
    "read_mesh",
    "unique_edges",
    "write_gid",
    "write_gid_results",
    "write_mesh",
]


def __getattr__(name: str):
    if name == "mesh_cad":
        from cadbridge.mesh.generate import mesh_cad

        return mesh_cad
    raise AttributeError(f"module 'cadbridge.mesh' has no attribute {name!r}")
