"""Read a result mesh and one scalar field as nodal values (Hawkins 1989, §3.2 / Fig. 3.2).

Sources:
- any mesh meshio reads (VTU, Gmsh .msh, Abaqus .inp, ...) with point data or cell data;
- a GiD mesh (.msh / .post.msh) with its GiD results file (.res beside it, or ``values``);
- a cadbridge tool file (.nagata) with a CSV of nodal values (``values``).

Cell values (and integration-point values: a cell array with several columns, averaged per
element with equal weights first) become nodal values by area-weighted averaging over the
elements around each node, f_n = sum_e A_e f_e / sum_e A_e (Hawkins averages the
integration points around a node with equal weights; the area weight keeps a refined
region from dominating). A vector field (3 columns) is reduced to its magnitude, unless a
component is asked for as ``NAME[k]`` (0-based). ``NodalField.source`` says which of these
happened; it is written into every output.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cadbridge.mesh.mesh import CellBlock, Mesh

__all__ = ["FieldError", "NodalField", "read_results", "nodal_from_cells", "element_areas"]


class FieldError(ValueError):
    """The requested field is absent, of the wrong length or not finite (one line)."""


@dataclass(frozen=True)
class NodalField:
    """One scalar per mesh node.

    name    field name as asked for (``pressure``, ``U[2]``, ...)
    values  (N,) float, finite
    source  how the values were obtained: "point data", "cell data, area-weighted to nodes",
            "integration points (k per element) averaged, area-weighted to nodes", plus
            ", magnitude of a 3-vector" or ", component k" where that applied
    """

    name: str
    values: np.ndarray
    source: str


def element_areas(nodes: np.ndarray, blocks: list[np.ndarray]) -> np.ndarray:
    """Flat areas of all elements (blocks in order), (E,); quads by their two diagonals."""
    out = []
    for c in blocks:
        x = nodes[c]
        if c.shape[1] == 3:
            n = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])
        else:
            n = np.cross(x[:, 2] - x[:, 0], x[:, 3] - x[:, 1])
        out.append(0.5 * np.linalg.norm(n, axis=1))
    return np.concatenate(out) if out else np.zeros(0)


def nodal_from_cells(mesh: Mesh, values: np.ndarray) -> np.ndarray:
    """Area-weighted nodal average of per-element values (E,) -> (N,). Nodes used by no
    element get NaN (the caller reports them)."""
    blocks = [np.asarray(b.data) for b in mesh.cells]
    area = element_areas(mesh.nodes, blocks)
    area = np.where(area > 0, area, 1e-300)
    num = np.zeros(mesh.n_nodes)
    den = np.zeros(mesh.n_nodes)
    off = 0
    for c in blocks:
        a = area[off : off + len(c)]
        f = values[off : off + len(c)]
        for k in range(c.shape[1]):
            np.add.at(num, c[:, k], a * f)
            np.add.at(den, c[:, k], a)
        off += len(c)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / np.where(den > 0, den, 1.0), np.nan)


_COMPONENT = re.compile(r"^(?P<name>.+)\[(?P<k>\d+)\]$")


def _scalar(name: str, arr: np.ndarray, n: int, what: str) -> tuple[np.ndarray, str]:
    """(n,) or (n, k) -> (n,) scalar and a note; integration points averaged."""
    arr = np.asarray(arr, dtype=float)
    if arr.ndim == 0 or arr.shape[0] != n:
        raise FieldError(f"field {name!r} has {arr.shape[0] if arr.ndim else 0} values, the mesh has {n} {what}")
    if arr.ndim == 1:
        return arr, ""
    flat = arr.reshape(n, -1)
    if flat.shape[1] == 1:
        return flat[:, 0], ""
    if flat.shape[1] == 3:
        return np.linalg.norm(flat, axis=1), ", magnitude of a 3-vector"
    return flat.mean(axis=1), f", {flat.shape[1]} values per entry (integration points) averaged"


def _pick(mesh: Mesh, name: str, available: str) -> NodalField:
    m = _COMPONENT.match(name)
    base, comp = (m["name"], int(m["k"])) if m else (name, None)
    n, ne = mesh.n_nodes, mesh.n_elements
    if base in mesh.point_data:
        arr, kind, count = np.asarray(mesh.point_data[base], dtype=float), "point data", n
    elif base in mesh.cell_data:
        arr, kind, count = np.asarray(mesh.cell_data[base], dtype=float), "cell data", ne
    else:
        raise FieldError(f"field {base!r} not found; {available}")
    note = ""
    if comp is not None:
        if arr.ndim < 2 or comp >= arr.reshape(len(arr), -1).shape[1]:
            raise FieldError(f"field {base!r} has no component {comp} (shape {arr.shape})")
        arr, note = arr.reshape(len(arr), -1)[:, comp], f", component {comp}"
    vals, more = _scalar(name, arr, count, "nodes" if kind == "point data" else "elements")
    note += more
    bad = np.flatnonzero(~np.isfinite(vals))
    if bad.size:
        raise FieldError(f"field {name!r} is not finite at {bad.size} {'nodes' if kind == 'point data' else 'elements'} "
                         f"(first: {bad[:5].tolist()}, 0-based)")
    if kind == "cell data":
        vals = nodal_from_cells(mesh, vals)
        unused = np.flatnonzero(~np.isfinite(vals))
        if unused.size:
            raise FieldError(f"field {name!r}: {unused.size} nodes belong to no element, so the cell values give them "
                             f"no value (first: {unused[:5].tolist()})")
        if "integration" in more:
            k = more.split()[1]
            return NodalField(name, vals, f"{k} integration-point values per element averaged, area-weighted to nodes"
                              + note[: len(note) - len(more)])
        return NodalField(name, vals, "cell data, area-weighted to nodes" + note)
    return NodalField(name, vals, "point data" + note)


def _available(mesh: Mesh) -> str:
    names = [f"{k} (point)" for k in mesh.point_data] + [f"{k} (cell)" for k in mesh.cell_data]
    return "available: " + (", ".join(names) if names else "none (give values as a CSV with --values)")


def _read_csv_values(path: Path, name: str, n: int) -> np.ndarray:
    """A CSV of nodal values: a header naming the columns; the column ``name`` (or the only
    value column), rows in node order, or with a ``node`` column of 1-based node ids."""
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise FieldError(f"{path}: cannot read: {exc}") from exc
    rows = [r for r in rows if r and not r[0].lstrip().startswith("#")]
    if len(rows) < 2:
        raise FieldError(f"{path}: needs a header line and one line per node")
    head = [h.strip() for h in rows[0]]
    lower = [h.lower() for h in head]
    node_col = lower.index("node") if "node" in lower else None
    value_cols = [i for i in range(len(head)) if i != node_col]
    if name in head:
        col = head.index(name)
    elif len(value_cols) == 1:
        col = value_cols[0]
    else:
        raise FieldError(f"{path}: no column {name!r} (columns: {', '.join(head)})")
    try:
        vals = np.array([float(r[col]) for r in rows[1:]])
        ids = np.array([int(r[node_col]) for r in rows[1:]]) - 1 if node_col is not None else None
    except (ValueError, IndexError) as exc:
        raise FieldError(f"{path}: bad value line: {exc}") from exc
    if ids is None:
        if len(vals) != n:
            raise FieldError(f"{path}: {len(vals)} values for {n} nodes")
        return vals
    if ids.min() < 0 or ids.max() >= n:
        raise FieldError(f"{path}: node id {int(ids.max()) + 1 if ids.max() >= n else int(ids.min()) + 1} outside 1..{n}")
    out = np.full(n, np.nan)
    out[ids] = vals
    if np.isnan(out).any():
        raise FieldError(f"{path}: no value for {int(np.isnan(out).sum())} nodes (first: node {int(np.flatnonzero(np.isnan(out))[0]) + 1})")
    return out


def read_results(path: str | Path, field: str, *, values: str | Path | None = None) -> tuple[Mesh, NodalField]:
    """Read a result mesh and the nodal values of ``field``.

    path    mesh file (meshio formats, GiD .msh/.post.msh, or a cadbridge tool file .nagata)
    field   name of a point/cell array (``NAME[k]`` picks a component)
    values  optional CSV (column ``field``) or GiD .res file with the values; required for
            tool files. A GiD mesh reads the .res file beside it when ``values`` is None.
    Raises `FieldError` (absent, wrong length, not finite) or `MeshError` (unreadable mesh).
    """
    from cadbridge.mesh.io import read_gid_results, read_mesh

    path = Path(path)
    if path.suffix.lower() == ".nagata":
        from cadbridge.io.toolfile import read_toolfile

        tool = read_toolfile(path)
        blocks = [CellBlock(t, d) for t, d in (("triangle", tool.triangles), ("quad", tool.quads)) if len(d)]
        mesh = Mesh(tool.nodes, blocks, name=tool.name or path.stem)
        if values is None:
            raise FieldError(f"{path}: a tool file holds no results; give the nodal values as a CSV (--values)")
    else:
        mesh = read_mesh(path)
    if values is not None:
        vp = Path(values)
        if vp.suffix.lower() == ".res":
            res = read_gid_results(vp, n_nodes=mesh.n_nodes)
            mesh.point_data.update(res)
        else:
            vals = _read_csv_values(vp, field, mesh.n_nodes)
            return mesh, _finite_field(NodalField(field, vals, f"point data from {vp.name}"))
    elif path.suffix.lower() == ".msh" and mesh.point_data == {} and mesh.cell_data == {}:
        stem = path.name[: -len(".post.msh")] if path.name.lower().endswith(".post.msh") else path.stem
        for cand in (path.with_name(stem + ".post.res"), path.with_name(stem + ".res")):
            if cand.is_file():
                mesh.point_data.update(read_gid_results(cand, n_nodes=mesh.n_nodes))
                break
    return mesh, _pick(mesh, field, _available(mesh))


def _finite_field(f: NodalField) -> NodalField:
    bad = np.flatnonzero(~np.isfinite(f.values))
    if bad.size:
        raise FieldError(f"field {f.name!r} is not finite at {bad.size} nodes (first: {bad[:5].tolist()}, 0-based)")
    return f
