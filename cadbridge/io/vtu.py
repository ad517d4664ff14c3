"""VTU (VTK XML unstructured grid) report files for ParaView, written through meshio.

Two writers, both on plain numpy arrays:

* :func:`write_surface_vtu` -- a refined (triangulated) Nagata surface with per-point results
  (normals, shape error, normal error, face id, element id).
* :func:`write_mesh_vtu` -- the original tri/quad mesh with node normals, distances, face ids,
  and dataset-level field data such as the normal source label (``"normal_source": "cad"``).

meshio 5.3 does not write VTU ``<FieldData>``; it is injected here after meshio has written
the file, in ASCII with round-trip precision, so both ParaView and ``meshio.read`` see it.
String labels are stored as ``UInt8`` arrays of their UTF-8 bytes (meshio cannot read the VTK
``String`` type); :func:`decode_field_string` turns such an array back into ``str``.

Writes are atomic: the file is written next to the target and ``os.replace``-d onto it.
"""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import meshio
import numpy as np

from cadbridge.common.atomic import atomic_path

__all__ = ["write_surface_vtu", "write_mesh_vtu", "decode_field_string"]

# meshio cell type -> nodes per cell (the linear cells a Nagata tool mesh is made of)
_CELL_NODES = {"triangle": 3, "quad": 4}

# dtypes meshio's VTU writer maps to a VTK type
_VTU_DTYPES = {
    np.dtype(t)
    for t in (np.float32, np.float64, np.int8, np.int16, np.int32, np.int64,
              np.uint8, np.uint16, np.uint32, np.uint64)
}
_VTU_TYPE_NAMES = {
    np.dtype(np.float32): "Float32", np.dtype(np.float64): "Float64",
    np.dtype(np.int8): "Int8", np.dtype(np.int16): "Int16",
    np.dtype(np.int32): "Int32", np.dtype(np.int64): "Int64",
    np.dtype(np.uint8): "UInt8", np.dtype(np.uint16): "UInt16",
    np.dtype(np.uint32): "UInt32", np.dtype(np.uint64): "UInt64",
}

ArrayLike = np.ndarray | Sequence


# ----------------------------------------------------------------------------- validation

def _points(name: str, points: ArrayLike) -> np.ndarray:
    """(M, 3) finite float64 coordinates."""
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{name} must have shape (M, 3), got {p.shape}")
    if p.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be numeric, got dtype {p.dtype}")
    p = p.astype(np.float64, copy=False)
    if not np.all(np.isfinite(p)):
        bad = np.flatnonzero(~np.all(np.isfinite(p), axis=1))
        raise ValueError(f"{name} has non-finite coordinates at rows {bad[:10].tolist()}")
    return p


def _connectivity(name: str, cells: ArrayLike, k: int, n_points: int) -> np.ndarray:
    """(E, k) int64 node indices, each in [0, n_points)."""
    c = np.asarray(cells)
    if c.ndim != 2 or c.shape[1] != k:
        raise ValueError(f"{name} must have shape (E, {k}), got {c.shape}")
    if c.size and c.dtype.kind not in "iu":
        raise ValueError(f"{name} must be an integer array, got dtype {c.dtype}")
    c = c.astype(np.int64, copy=False)
    if c.size and (c.min() < 0 or c.max() >= n_points):
        bad = np.flatnonzero(np.any((c < 0) | (c >= n_points), axis=1))
        raise ValueError(
            f"{name} references nodes outside [0, {n_points}) in rows {bad[:10].tolist()}"
        )
    return c


def _data_array(kind: str, name: str, data: ArrayLike, n: int, what: str) -> np.ndarray:
    """An (n,) or (n, k) array in a dtype VTU can hold (bool -> uint8, other floats -> float64)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"{kind} names must be non-empty strings, got {name!r}")
    a = np.asarray(data)
    if a.ndim not in (1, 2) or a.shape[0] != n or (a.ndim == 2 and a.shape[1] < 1):
        raise ValueError(
            f"{kind} {name!r} must have shape ({n},) or ({n}, k) (one row per {what}), "
            f"got {a.shape}"
        )
    if a.dtype == np.bool_:
        a = a.astype(np.uint8)
    elif a.dtype.kind == "f" and a.dtype not in _VTU_DTYPES:
        a = a.astype(np.float64)
    elif a.dtype.kind in "iu":
        a = a.astype(a.dtype.newbyteorder("="), copy=False)
    if a.dtype.newbyteorder("=") not in _VTU_DTYPES:
        raise ValueError(f"{kind} {name!r} has dtype {a.dtype}, which VTU cannot store")
    return np.ascontiguousarray(a)


def _field_array(name: str, value) -> np.ndarray:
    """Field data value -> 1-D or 2-D array; ``str`` -> UInt8 array of its UTF-8 bytes."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"field_data names must be non-empty strings, got {name!r}")
    if isinstance(value, str):
        raw = value.encode("utf-8")
        if not raw:
            raise ValueError(f"field_data {name!r} is an empty string")
        return np.frombuffer(raw, dtype=np.uint8).copy()
    a = np.atleast_1d(np.asarray(value))
    if a.ndim > 2 or a.size == 0:
        raise ValueError(f"field_data {name!r} must be a non-empty scalar, 1-D or 2-D array, "
                         f"got shape {a.shape}")
    if a.dtype == np.bool_:
        a = a.astype(np.uint8)
    elif a.dtype.kind == "f" and a.dtype not in _VTU_DTYPES:
        a = a.astype(np.float64)
    if a.dtype.newbyteorder("=") not in _VTU_DTYPES:
        raise ValueError(f"field_data {name!r} has dtype {a.dtype}, which VTU cannot store")
    return a


def decode_field_string(value: np.ndarray) -> str:
    """Inverse of the string encoding used for field data: UInt8 UTF-8 bytes -> ``str``."""
    a = np.asarray(value)
    if a.dtype != np.uint8 or a.ndim != 1:
        raise ValueError(f"expected a 1-D uint8 array of UTF-8 bytes, got {a.dtype} {a.shape}")
    return a.tobytes().decode("utf-8")


# ----------------------------------------------------------------------------- writing

def _field_data_xml(field: Mapping[str, np.ndarray]) -> bytes:
    """``<FieldData>`` element text: ASCII arrays with round-trip float precision."""
    fd = ET.Element("FieldData")
    for name, a in field.items():
        dt = a.dtype.newbyteorder("=")
        da = ET.SubElement(fd, "DataArray", type=_VTU_TYPE_NAMES[dt], Name=name,
                           NumberOfTuples=str(a.shape[0]), format="ascii")
        if a.ndim == 2:
            da.set("NumberOfComponents", str(a.shape[1]))
        flat = a.reshape(-1)
        if dt.kind == "f":
            da.text = " ".join(repr(float(x)) for x in flat)  # repr: round-trip precision
        else:
            da.text = " ".join(str(int(x)) for x in flat)
    return ET.tostring(fd)


def _inject_field_data(path: str, field: Mapping[str, np.ndarray]) -> None:
    """Insert ``<FieldData>`` as the first child of ``<UnstructuredGrid>`` in a meshio VTU."""
    with open(path, "rb") as fh:
        text = fh.read()
    m = re.search(rb"<UnstructuredGrid\b[^>]*>", text)
    if m is None or text[m.end() - 2: m.end()] == b"/>":
        raise RuntimeError(f"cannot place FieldData: no <UnstructuredGrid> element in {path}")
    text = text[: m.end()] + _field_data_xml(field) + text[m.end():]
    with open(path, "wb") as fh:
        fh.write(text)


def _write(path: str | os.PathLike, mesh: meshio.Mesh,
           field: Mapping[str, np.ndarray] | None) -> None:
    with atomic_path(path) as tmp:
        meshio.write(tmp, mesh, file_format="vtu", binary=True, compression="zlib")
        if field:
            _inject_field_data(tmp, field)


def write_surface_vtu(
    path: str | os.PathLike,
    points: ArrayLike,
    triangles: ArrayLike,
    point_data: Mapping[str, ArrayLike] | None = None,
    cell_data: Mapping[str, ArrayLike] | None = None,
) -> None:
    """Write a triangulated surface (e.g. a refined Nagata surface) to a VTU file.

    points : (M, 3) float, model units. triangles : (T, 3) int, 0-based node indices.
    point_data : name -> (M,) or (M, k), e.g. "normal" (M, 3), "shape_error", "normal_error",
    "face_id", "element". cell_data : name -> (T,) or (T, k). bool arrays are stored as UInt8.
    Raises ValueError naming the offending array on any shape/dtype/index mismatch.
    """
    pts = _points("points", points)
    tri = _connectivity("triangles", triangles, 3, len(pts))
    pd = {k: _data_array("point_data", k, v, len(pts), "point")
          for k, v in (point_data or {}).items()}
    cd = {k: [_data_array("cell_data", k, v, len(tri), "triangle")]
          for k, v in (cell_data or {}).items()}
    _write(path, meshio.Mesh(pts, [("triangle", tri)], point_data=pd, cell_data=cd), None)


def write_mesh_vtu(
    path: str | os.PathLike,
    nodes: ArrayLike,
    blocks: Sequence[tuple[str, ArrayLike]],
    point_data: Mapping[str, ArrayLike] | None = None,
    cell_data: Mapping[str, Sequence[ArrayLike]] | None = None,
    field_data: Mapping[str, object] | None = None,
) -> None:
    """Write the original tool mesh (triangles and/or quads) to a VTU file.

    nodes : (N, 3) float, model units. blocks : [(cell_type, (E_b, k) int), ...] with
    cell_type "triangle" (k=3) or "quad" (k=4), 0-based node indices. point_data : name ->
    (N,) or (N, k), e.g. "normal" (N, 3), "distance", "face_id". cell_data : name -> one array
    per block, (E_b,) or (E_b, k). field_data : name -> str | scalar | 1-D/2-D array, stored
    once per dataset (e.g. "normal_source": "cad"); strings become UInt8 UTF-8 bytes, see
    :func:`decode_field_string`. Raises ValueError naming the offending array.
    """
    pts = _points("nodes", nodes)
    if isinstance(blocks, (str, bytes)) or len(blocks) == 0:
        raise ValueError("blocks must be a non-empty list of (cell_type, connectivity)")
    cells = []
    for i, blk in enumerate(blocks):
        if not isinstance(blk, (tuple, list)) or len(blk) != 2:
            raise ValueError(f"blocks[{i}] must be a (cell_type, connectivity) pair")
        ctype, conn = blk
        if ctype not in _CELL_NODES:
            raise ValueError(f"blocks[{i}] has cell type {ctype!r}; expected one of "
                             f"{sorted(_CELL_NODES)}")
        cells.append((ctype, _connectivity(f"blocks[{i}] ({ctype})", conn,
                                           _CELL_NODES[ctype], len(pts))))
    pd = {k: _data_array("point_data", k, v, len(pts), "node")
          for k, v in (point_data or {}).items()}
    cd = {}
    for name, per_block in (cell_data or {}).items():
        if not isinstance(name, str) or not name:
            raise ValueError(f"cell_data names must be non-empty strings, got {name!r}")
        if isinstance(per_block, np.ndarray) or not isinstance(per_block, Sequence) \
                or len(per_block) != len(cells):
            raise ValueError(f"cell_data {name!r} must be a list with one array per block "
                             f"({len(cells)} blocks)")
        cd[name] = [
            _data_array("cell_data", f"{name}[{b}]", arr, len(cells[b][1]),
                        f"cell of block {b} ({cells[b][0]})")
            for b, arr in enumerate(per_block)
        ]
        dtypes = {a.dtype for a in cd[name]}
        ncomp = {a.shape[1:] for a in cd[name]}
        if len(ncomp) != 1:
            raise ValueError(f"cell_data {name!r} has different component counts per block: "
                             f"{sorted(ncomp)}")
        if len(dtypes) != 1:  # VTU stores one array over all blocks
            common = np.result_type(*dtypes)
            cd[name] = [a.astype(common) for a in cd[name]]
    fd = {k: _field_array(k, v) for k, v in (field_data or {}).items()}
    _write(path, meshio.Mesh(pts, cells, point_data=pd, cell_data=cd), fd)
