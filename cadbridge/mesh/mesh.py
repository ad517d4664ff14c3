"""The surface mesh container: nodes plus blocks of triangles and/or quadrilaterals.

Plain data (numpy arrays in small dataclasses), modelled on meshio's ``Mesh``:

* ``nodes`` — (N, 3) float64 coordinates (model units, as read / as meshed).
* ``cells`` — list of `CellBlock`; each block holds one element type, ``"triangle"``
  (E, 3) or ``"quad"`` (E, 4) node indices (0-based), counter-clockwise about the element
  normal. Mixed meshes are several blocks.
* Global element numbering is the blocks concatenated in order: element ``i`` of block
  ``b`` has global index ``element_offsets[b] + i``.
* ``point_data[name]`` — arrays with first axis N; ``cell_data[name]`` — arrays with first
  axis ``n_elements`` in the global element numbering (not meshio's per-block lists).

No gmsh / OCC imports here (core module).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["MeshError", "CellBlock", "Mesh", "NODES_PER_CELL"]

#: Number of nodes of each supported (linear, surface) element type.
NODES_PER_CELL: dict[str, int] = {"triangle": 3, "quad": 4}


class MeshError(ValueError):
    """A mesh is invalid, cannot be read/written, or cannot be generated.

    Messages name the offending file, element (global index) or node (0-based index).
    """


@dataclass(frozen=True, eq=False)
class CellBlock:
    """One block of elements of a single type.

    ``type`` is ``"triangle"`` or ``"quad"``; ``data`` is (E, 3) or (E, 4) int64 node indices.
    """

    type: str
    data: np.ndarray

    def __post_init__(self) -> None:
        if self.type not in NODES_PER_CELL:
            raise MeshError(
                f"unsupported cell type {self.type!r}; expected one of {sorted(NODES_PER_CELL)}"
            )
        data = np.asarray(self.data)
        k = NODES_PER_CELL[self.type]
        if data.size == 0:
            data = data.reshape(0, k)
        if data.ndim != 2 or data.shape[1] != k:
            raise MeshError(f"{self.type} block: data must have shape (E, {k}), got {data.shape}")
        if not (np.issubdtype(data.dtype, np.integer)):
            if np.issubdtype(data.dtype, np.floating) and np.all(np.mod(data, 1) == 0):
                data = data.astype(np.int64)
            else:
                raise MeshError(f"{self.type} block: node indices must be integers, got {data.dtype}")
        data = np.ascontiguousarray(data, dtype=np.int64)
        object.__setattr__(self, "data", data)

    def __len__(self) -> int:
        return int(self.data.shape[0])

    @property
    def nodes_per_element(self) -> int:
        return NODES_PER_CELL[self.type]


def _as_block(b: CellBlock | tuple[str, np.ndarray]) -> CellBlock:
    if isinstance(b, CellBlock):
        return b
    try:
        t, d = b
    except (TypeError, ValueError):
        raise MeshError(f"cell block must be a CellBlock or (type, data), got {type(b).__name__}")
    return CellBlock(str(t), d)


@dataclass
class Mesh:
    """Surface mesh of triangles and/or quadrilaterals.

    Parameters
    ----------
    nodes : (N, 3) float array of coordinates (2D input (N, 2) is padded with z = 0).
    cells : list of `CellBlock` (or ``(type, data)`` tuples), kept in order.
    point_data : name -> array with first axis N.
    cell_data : name -> array with first axis ``n_elements`` (global element numbering).
    name : a label (used e.g. for the GiD ``MESH "name"`` header).

    The constructor validates shapes, finiteness, index range and repeated nodes within an
    element, raising `MeshError` naming the first offending element / node.
    """

    nodes: np.ndarray
    cells: list[CellBlock]
    point_data: dict[str, np.ndarray] = field(default_factory=dict)
    cell_data: dict[str, np.ndarray] = field(default_factory=dict)
    name: str = "mesh"
    #: what was done to the mesh on the way (e.g. nodes merged by the mesher), for reports
    notes: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        nodes = np.asarray(self.nodes, dtype=np.float64)
        if nodes.ndim != 2 or nodes.shape[1] not in (2, 3):
            raise MeshError(f"nodes must have shape (N, 3), got {nodes.shape}")
        if nodes.shape[1] == 2:
            nodes = np.column_stack([nodes, np.zeros(len(nodes))])
        bad = np.flatnonzero(~np.all(np.isfinite(nodes), axis=1))
        if bad.size:
            raise MeshError(f"node {bad[0]} has non-finite coordinates {nodes[bad[0]].tolist()}")
        self.nodes = np.ascontiguousarray(nodes)
        if isinstance(self.cells, CellBlock) or (
            isinstance(self.cells, tuple) and len(self.cells) == 2 and isinstance(self.cells[0], str)
        ):
            self.cells = [self.cells]  # a single block given bare
        self.cells = [_as_block(b) for b in self.cells]
        n = len(self.nodes)
        offsets = self.element_offsets
        for b, blk, off in zip(range(len(self.cells)), self.cells, offsets[:-1]):
            d = blk.data
            if d.size == 0:
                continue
            out = (d < 0) | (d >= n)
            if out.any():
                r, c = np.argwhere(out)[0]
                raise MeshError(
                    f"element {off + r} (block {b} {blk.type!r}, row {r}) references node "
                    f"{d[r, c]}, but the mesh has {n} nodes (valid 0..{n - 1})"
                )
            s = np.sort(d, axis=1)
            rep = np.flatnonzero(np.any(s[:, 1:] == s[:, :-1], axis=1))
            if rep.size:
                r = rep[0]
                raise MeshError(
                    f"element {off + r} (block {b} {blk.type!r}, row {r}) repeats a node: "
                    f"{d[r].tolist()}"
                )
        self.point_data = {k: np.asarray(v) for k, v in (self.point_data or {}).items()}
        self.cell_data = {k: np.asarray(v) for k, v in (self.cell_data or {}).items()}
        for k, v in self.point_data.items():
            if v.ndim == 0 or v.shape[0] != n:
                raise MeshError(f"point_data[{k!r}] has shape {v.shape}; first axis must be {n}")
        ne = int(offsets[-1])
        for k, v in self.cell_data.items():
            if v.ndim == 0 or v.shape[0] != ne:
                raise MeshError(f"cell_data[{k!r}] has shape {v.shape}; first axis must be {ne}")

    # ------------------------------------------------------------------ sizes, blocks
    @property
    def n_nodes(self) -> int:
        return int(self.nodes.shape[0])

    @property
    def n_elements(self) -> int:
        return int(sum(len(b) for b in self.cells))

    @property
    def element_offsets(self) -> np.ndarray:
        """(n_blocks + 1,) int64: global index of the first element of each block, then total."""
        return np.concatenate([[0], np.cumsum([len(b) for b in self.cells], dtype=np.int64)]).astype(
            np.int64
        )

    def elements(self) -> Iterator[tuple[int, CellBlock]]:
        """Iterate over blocks as ``(global offset of the block's first element, block)``."""
        for off, blk in zip(self.element_offsets[:-1], self.cells):
            yield int(off), blk

    def _concat(self, kind: str) -> np.ndarray:
        k = NODES_PER_CELL[kind]
        parts = [b.data for b in self.cells if b.type == kind]
        return np.concatenate(parts) if parts else np.empty((0, k), dtype=np.int64)

    @property
    def triangles(self) -> np.ndarray:
        """(E_tri, 3) int64: all triangle blocks concatenated in block order."""
        return self._concat("triangle")

    @property
    def quads(self) -> np.ndarray:
        """(E_quad, 4) int64: all quad blocks concatenated in block order."""
        return self._concat("quad")

    @property
    def element_types(self) -> np.ndarray:
        """(E,) int8: nodes per element (3 or 4) in global element numbering."""
        parts = [np.full(len(b), b.nodes_per_element, dtype=np.int8) for b in self.cells]
        return np.concatenate(parts) if parts else np.empty(0, dtype=np.int8)

    def padded(self) -> np.ndarray:
        """(E, 4) int64 connectivity in global numbering; triangles padded with -1."""
        out = np.full((self.n_elements, 4), -1, dtype=np.int64)
        for off, blk in self.elements():
            out[off : off + len(blk), : blk.nodes_per_element] = blk.data
        return out

    def element_nodes(self, element: int) -> np.ndarray:
        """Node indices of one element given its global index."""
        block, row = self.locate(element)
        return self.cells[block].data[row]

    def locate(self, element: int) -> tuple[int, int]:
        """Global element index -> (block index, row within the block)."""
        off = self.element_offsets
        if not 0 <= element < off[-1]:
            raise MeshError(f"element {element} out of range (mesh has {off[-1]} elements)")
        b = int(np.searchsorted(off, element, side="right") - 1)
        return b, int(element - off[b])

    # ------------------------------------------------------------------ derived meshes
    def with_cells(self, cells: Sequence[CellBlock], **changes) -> Mesh:
        """A copy with new cell blocks (same nodes/point_data); cell_data dropped unless given."""
        return Mesh(
            self.nodes,
            list(cells),
            point_data=changes.get("point_data", dict(self.point_data)),
            cell_data=changes.get("cell_data", {}),
            name=changes.get("name", self.name),
        )

    def remove_unused_nodes(self) -> tuple[Mesh, np.ndarray]:
        """Drop nodes no element uses and renumber.

        Returns the new mesh and ``old_index`` (N_new,) int64: for each kept node its index in
        this mesh.
        """
        used = np.zeros(self.n_nodes, dtype=bool)
        for b in self.cells:
            used[b.data.ravel()] = True
        old = np.flatnonzero(used)
        if old.size == self.n_nodes:
            return self, old
        new = np.full(self.n_nodes, -1, dtype=np.int64)
        new[old] = np.arange(old.size)
        cells = [CellBlock(b.type, new[b.data]) for b in self.cells]
        pd = {k: v[old] for k, v in self.point_data.items()}
        return Mesh(self.nodes[old], cells, pd, dict(self.cell_data), self.name), old

    def __repr__(self) -> str:
        blocks = ", ".join(f"{b.type}: {len(b)}" for b in self.cells)
        return f"Mesh(name={self.name!r}, nodes={self.n_nodes}, cells=[{blocks}])"
