"""Exact normals at mesh nodes from the CAD model (thesis ch. 5, Fig. 47).

Every node is projected onto the model (global box search, then Newton); its normal is the
exact NURBS normal at the foot point. Where faces meet at a sharp edge (normals of the faces
on either side differ by more than ``crease_angle``), a node gets one normal per adjacent
face, stored per element corner, so Nagata patches can keep the crease.

Normals are oriented with the element winding: each corner normal points to the side of
its element's (polyhedral) normal, and a node normal to the side of the summed normals of
the elements around it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cadbridge.mesh.mesh import Mesh
from cadbridge.model import Model
from cadbridge.nurbs.project import project_to_surface
from cadbridge.nurbs.search import BEYOND_TOLERANCE, CONVERGED, FAILED, ON_BOUNDARY, Projection, project_points

__all__ = ["CadNormals", "ProjectionError", "cad_normals"]


class ProjectionError(ValueError):
    """Mesh nodes that could not be given an exact CAD normal (too far, or failed)."""

    def __init__(self, message: str, nodes: np.ndarray, distances: np.ndarray) -> None:
        super().__init__(message)
        self.nodes = nodes
        self.distances = distances


@dataclass
class CadNormals:
    """Result of `cad_normals`.

    normals         (N, 3) unit node normals (one per node)
    corner_normals  list of (E_b, k_b, 3) per cell block of the mesh: the normal each element
                    corner uses (equal to the node normal except on creases)
    face, u, v      (N,) the face index (into model.faces) and parameters of each node's foot
    distance        (N,) node-to-CAD distance (model units)
    status          (N,) projection status (CONVERGED, ON_BOUNDARY, BEYOND_TOLERANCE, FAILED)
    crease          (N,) bool, node sits on a sharp edge (has several corner normals)
    element_face    list of (E_b,) face index of each element (from its centroid)
    """

    normals: np.ndarray
    corner_normals: list[np.ndarray]
    face: np.ndarray
    u: np.ndarray
    v: np.ndarray
    distance: np.ndarray
    status: np.ndarray
    crease: np.ndarray
    element_face: list[np.ndarray]
    projection: Projection

    @property
    def has_creases(self) -> bool:
        return bool(self.crease.any())

    def far_nodes(self) -> np.ndarray:
        """Indices of nodes beyond tolerance or failed."""
        return np.flatnonzero((self.status == BEYOND_TOLERANCE) | (self.status == FAILED))


def _element_normals(nodes: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Polyhedral element normals from the winding, (E, 3), unit (quads: diagonal cross)."""
    x = nodes[cells]
    if cells.shape[1] == 3:
        n = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
    else:
        n = np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 1])
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    return n / np.where(ln > 0, ln, 1.0)


def cad_normals(
    mesh: Mesh,
    model: Model,
    *,
    tolerance: float | None = None,
    crease_angle: float = 20.0,
    flip: bool = False,
    allow_far: bool = False,
) -> CadNormals:
    """Exact CAD normals at the nodes of ``mesh``.

    tolerance     maximum node-to-CAD distance (model units); default 1e-4 x model size.
    crease_angle  degrees; faces meeting at a node with normals further apart than this
                  make the node a crease node with per-corner normals.
    flip          reverse all normals (choose the other side of the tool).
    allow_far     return nodes beyond tolerance with their status instead of raising.

    Raises `ProjectionError` naming the nodes beyond tolerance (unless ``allow_far``) and
    ValueError for an empty model or mesh.
    """
    if not model.faces:
        raise ValueError("the CAD model has no faces: nothing to project onto")
    nodes = np.asarray(mesh.nodes, dtype=float)
    if len(nodes) == 0:
        raise ValueError("the mesh has no nodes")
    size = model.size()
    tol = 1e-4 * size if tolerance is None else float(tolerance)

    proj = project_points(nodes, model, max_distance=tol)
    status = np.asarray(proj.status).copy()
    far = np.flatnonzero((status == BEYOND_TOLERANCE) | (status == FAILED))
    if len(far) and not allow_far:
        worst = far[np.argsort(-np.nan_to_num(proj.distance[far], nan=np.inf))][:10]
        lines = ", ".join(
            f"node {i} at ({nodes[i, 0]:.6g}, {nodes[i, 1]:.6g}, {nodes[i, 2]:.6g}) distance {proj.distance[i]:.3g}"
            for i in worst
        )
        raise ProjectionError(
            f"{len(far)} of {len(nodes)} mesh nodes are further than {tol:.3g} from the CAD "
            f"(or could not be projected): {lines}",
            far,
            proj.distance[far],
        )

    node_n = np.array(proj.normal, dtype=float)
    sign = -1.0 if flip else 1.0

    # element faces: project element centroids (robust for nodes on face boundaries)
    blocks = [np.asarray(b.data) for b in mesh.cells]
    centroids = np.concatenate([nodes[c].mean(axis=1) for c in blocks]) if blocks else np.zeros((0, 3))
    cproj = project_points(centroids, model, max_distance=None)
    elem_face_all = np.asarray(cproj.face)

    # orient node normals with the winding: sum of element normals around each node
    acc = np.zeros_like(nodes)
    elem_normals = [_element_normals(nodes, c) for c in blocks]
    for c, en in zip(blocks, elem_normals):
        for k in range(c.shape[1]):
            np.add.at(acc, c[:, k], en)
    dots = np.einsum("ij,ij->i", node_n, acc)
    node_n = node_n * np.where(dots < 0, -1.0, 1.0)[:, None] * sign

    corner_normals: list[np.ndarray] = []
    element_face: list[np.ndarray] = []
    crease = np.zeros(len(nodes), dtype=bool)
    cos_crease = np.cos(np.radians(crease_angle))
    offset = 0
    for c, en in zip(blocks, elem_normals):
        ef = elem_face_all[offset : offset + len(c)]
        offset += len(c)
        element_face.append(ef)
        cn = node_n[c].copy()  # (E, k, 3)
        # corners whose element lies on another face than the node's foot point
        other = (ef[:, None] != proj.face[c]) & (ef[:, None] >= 0)
        if np.any(other):
            ei, ki = np.nonzero(other)
            nid = c[ei, ki]
            fids = ef[ei]
            nrm = np.empty((len(nid), 3))
            for f in np.unique(fids):  # loop over faces, vectorised over corners
                sel = fids == f
                sp = project_to_surface(model.faces[f].surface, nodes[nid[sel]])
                nrm[sel] = sp.normal
            nrm *= np.where(np.einsum("ij,ij->i", nrm, en[ei]) < 0, -1.0, 1.0)[:, None] * sign
            sharp = np.einsum("ij,ij->i", nrm, node_n[nid]) < cos_crease
            cn[ei[sharp], ki[sharp]] = nrm[sharp]
            crease[nid[sharp]] = True
        corner_normals.append(cn)

    # every corner at a crease node takes its own element's face normal, including the
    # elements on the node's own face (their value is the node normal, already in place)
    return CadNormals(
        normals=node_n,
        corner_normals=corner_normals,
        face=np.asarray(proj.face),
        u=np.asarray(proj.u),
        v=np.asarray(proj.v),
        distance=np.asarray(proj.distance),
        status=status,
        crease=crease,
        element_face=element_face,
        projection=proj,
    )
