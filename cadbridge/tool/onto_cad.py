"""Mesh nodes moved onto the trimmed CAD faces they were projected to.

gmsh places each node on its face's surface, but not always inside the trimmed face: in a
narrow or concave part of a face (a sliver between a trim curve and a fillet's end) its
smoothing and quad recombination can leave an interior node a little outside the trim
curve (K1 from CATIA V5: four nodes 0.0031 mm outside, 2.3e-5 x size). The exact CAD normal
is taken at the node's foot on the trimmed face (`cadbridge.normals.cad.cad_normals`), so a
node left where gmsh put it carries a normal from another point. `onto_cad` moves such nodes
to their feet: node and normal then belong to the same point of the CAD.

A node is moved only where its foot lies on a trim boundary (status ``ON_BOUNDARY``: the node
is beside its trimmed face, not above or below it), more than ``SNAP_REL`` x model size away,
on the face of every element around it (off its own face, not nearer to another one), and
where no element around it turns over by the move (its normal reversed); otherwise it stays
where the mesher put it. Nodes above or below their face (a converged foot) are not moved:
on ANSA's OCC131-3, 17 nodes along a fold 0.0008 mm off their face, moved onto it, carried
normals 0.04 deg off OCC's at the same points (the fold's two sheets meet there).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cadbridge.cad.search import ON_BOUNDARY
from cadbridge.mesh.mesh import Mesh
from cadbridge.mesh.topology import element_normals

__all__ = ["SNAP_REL", "MovedNodes", "moved_note", "onto_cad"]

SNAP_REL = 1e-9  # nodes nearer their foot than this x model size are on the CAD already


@dataclass(frozen=True)
class MovedNodes:
    """What `onto_cad` did: ``nodes`` (K,) indices moved, ``distance`` (K,) how far each moved
    (model units), ``kept`` how many off-CAD nodes stayed because an element would turn over."""

    nodes: np.ndarray
    distance: np.ndarray
    kept: int = 0

    def __len__(self) -> int:
        return len(self.nodes)


def onto_cad(mesh: Mesh, foot: np.ndarray, distance: np.ndarray, status: np.ndarray, size: float, *,
             node_face: np.ndarray, element_face: list[np.ndarray]) -> tuple[Mesh, MovedNodes]:
    """``mesh`` with its nodes farther than ``SNAP_REL`` x ``size`` from their ``foot`` (N, 3)
    on a trim boundary of the CAD moved there (``distance`` (N,), ``status`` (N,), ``node_face`` (N,) of
    the projection, `cadbridge.cad.search.Projection`), where every element around the node
    lies on the node's face (``element_face``: per block (E_b,), the face of each element). A
    move that would reverse an element's normal (its area vector against the one before, per
    element around the node) is not made. Returns (the mesh, unchanged where nothing moves,
    and a `MovedNodes`)."""
    off = (distance > SNAP_REL * size) & (status == ON_BOUNDARY) & np.isfinite(distance)
    if not off.any():
        return mesh, MovedNodes(np.zeros(0, dtype=np.int64), np.zeros(0))
    for b, ef in zip(mesh.cells, element_face):  # off another element's face: left where it is
        c = np.asarray(b.data)
        other = np.asarray(ef)[:, None] != np.asarray(node_face)[c]
        off[c[other]] = False
    if not off.any():
        return mesh, MovedNodes(np.zeros(0, dtype=np.int64), np.zeros(0))
    x = np.asarray(mesh.nodes, dtype=float)
    new = x.copy()
    new[off] = foot[off]
    kept = np.zeros(len(x), dtype=bool)
    conn = mesh.padded()  # (E, 4), triangles padded with -1
    corner = conn >= 0
    before = element_normals(mesh, unit=False)  # area vectors, the elements' own winding
    for _ in range(4):  # undoing one node's move can turn over an element of a neighbour's
        touched = np.any(off[np.where(corner, conn, 0)] & corner, axis=1)
        after = element_normals(replace(mesh, nodes=new), unit=False)
        over = touched & (np.einsum("ij,ij->i", before, after) <= 0.0)
        if not over.any():
            break
        back = np.unique(conn[over][corner[over]])
        back = back[off[back]]
        new[back] = x[back]
        off[back] = False
        kept[back] = True
    moved = np.flatnonzero(off)
    if not len(moved):
        return mesh, MovedNodes(moved, np.zeros(0), int(kept.sum()))
    return replace(mesh, nodes=new), MovedNodes(moved, distance[moved].copy(), int(kept.sum()))


def moved_note(tool_name: str, distance: np.ndarray | None) -> str | None:
    """The report line for a tool's nodes moved onto the CAD (``distance`` (K,), model
    units), None where none moved."""
    if distance is None or not len(distance):
        return None
    return (f"{tool_name}: {len(distance)} mesh node{'s' if len(distance) > 1 else ''} the mesher left off "
            f"{'their' if len(distance) > 1 else 'its'} trimmed face (up to {float(np.max(distance)):.3g}) "
            f"moved onto {'them' if len(distance) > 1 else 'it'}")
