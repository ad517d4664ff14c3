"""Mesh file I/O: meshio formats plus GiD ASCII mesh / results written and read by us.

Formats (chosen from the extension unless ``fmt`` is given):

========  =====================================  ===========================================
fmt       extensions                             notes
========  =====================================  ===========================================
gmsh      .msh                                   MSH 4.1 (binary by default; ``binary=False``)
gid       .post.msh (or ``fmt="gid"``)           GiD ASCII mesh, one MESH block per CellBlock
vtk       .vtk                                   legacy VTK (binary by default)
vtu       .vtu                                   VTK XML (zlib-compressed binary by default)
abaqus    .inp
nastran   .bdf .nas .fem                         GRID* large field: 12 significant digits
stl       .stl                                   triangles only (quads split), float32
obj       .obj
========  =====================================  ===========================================

Reading keeps surface cells only: triangle/quad blocks are kept; triangle6/7 and quad8/9
are reduced to their corner nodes; lines, vertices and volume cells are dropped. Each
reduction / drop issues a `MeshWarning`. A ``.msh`` file is read as GiD when its first
non-comment line starts with ``MESH``, as gmsh otherwise.

GiD results (``.res``, "GiD Post Results File 1.0", nodal Scalar / Vector results) are
written by `write_gid_results` and read back by `read_gid_results`.

All writes are atomic: a temporary file in the target directory, then ``os.replace``.
No gmsh / OCC imports here (core module).
"""

from __future__ import annotations

import os
import re
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path

import numpy as np

from cadbridge.common.atomic import atomic_path

from cadbridge.mesh.mesh import CellBlock, Mesh, MeshError

__all__ = [
    "MeshWarning",
    "FORMATS",
    "read_mesh",
    "write_mesh",
    "from_meshio",
    "to_meshio",
    "read_gid",
    "write_gid",
    "write_gid_results",
    "read_gid_results",
    "atomic_write",
    "write_msh41",
]


class MeshWarning(UserWarning):
    """Something in a mesh file was dropped or reduced on read/write."""


#: extension -> format name (".post.msh" is checked before ".msh")
FORMATS: dict[str, str] = {
    ".post.msh": "gid",
    ".msh": "gmsh",
    ".vtk": "vtk",
    ".vtu": "vtu",
    ".inp": "abaqus",
    ".bdf": "nastran",
    ".nas": "nastran",
    ".fem": "nastran",
    ".stl": "stl",
    ".obj": "obj",
}
_EXTRA_FORMATS: set[str] = set()

_CORNERS = {"triangle6": ("triangle", 3), "triangle7": ("triangle", 3), "quad8": ("quad", 4), "quad9": ("quad", 4)}


def _format_of(path: Path, fmt: str | None) -> str:
    if fmt is not None:
        f = fmt.lower()
        known = set(FORMATS.values()) | _EXTRA_FORMATS
        if f not in known:
            raise MeshError(f"{path}: unknown mesh format {fmt!r}; known: {sorted(known)}")
        return f
    name = path.name.lower()
    for ext, f in FORMATS.items():
        if name.endswith(ext):
            return f
    raise MeshError(
        f"{path}: cannot tell the mesh format from the extension {path.suffix!r}; "
        f"known extensions: {', '.join(FORMATS)} (or pass fmt=...)"
    )


def _sniff_gid(path: Path) -> bool:
    """True if the first non-comment, non-blank line of a .msh file starts with MESH."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError as exc:
        raise MeshError(f"{path}: cannot open: {exc}") from exc
    for raw in head.splitlines():
        line = raw.strip()
        if not line or line.startswith(b"#"):
            continue
        return line[:4].upper() == b"MESH"
    return False


# ---------------------------------------------------------------------------- atomic write
def atomic_write(path: str | os.PathLike, write: Callable[[str], None]) -> None:
    """Call ``write(tmp_path)`` on a temporary file next to ``path``, then rename it onto
    ``path`` (`cadbridge.common.atomic.atomic_path`)."""
    path = Path(path)
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise MeshError(f"{path}: directory {parent} does not exist")
    with atomic_path(path) as tmp:
        write(str(tmp))


# ---------------------------------------------------------------------------- meshio bridge
def from_meshio(m, *, source: str = "<meshio.Mesh>") -> Mesh:
    """Convert a ``meshio.Mesh`` to `Mesh`, keeping surface cells (see module notes).

    cell_data keys present for every kept block with matching trailing shapes are
    concatenated into the global element numbering; others are dropped with a warning.
    """
    blocks: list[CellBlock] = []
    keep: list[int] = []
    dropped: dict[str, int] = {}
    reduced: dict[str, int] = {}
    for i, cb in enumerate(m.cells):
        t = cb.type
        data = np.asarray(cb.data)
        if t in ("triangle", "quad"):
            pass
        elif t in _CORNERS:
            t, k = _CORNERS[cb.type]
            data = data[:, :k]
            reduced[cb.type] = reduced.get(cb.type, 0) + len(data)
        elif t == "polygon" and data.ndim == 2 and data.shape[1] in (3, 4):
            t = "triangle" if data.shape[1] == 3 else "quad"
        else:
            dropped[t] = dropped.get(t, 0) + len(data)
            continue
        blocks.append(CellBlock(t, data))
        keep.append(i)
    if dropped:
        warnings.warn(
            f"{source}: dropped non-surface cells "
            + ", ".join(f"{n} {t}" for t, n in dropped.items())
            + " (only triangle/quad are kept)",
            MeshWarning,
            stacklevel=3,
        )
    if reduced:
        warnings.warn(
            f"{source}: reduced higher-order cells to their corner nodes: "
            + ", ".join(f"{n} {t}" for t, n in reduced.items()),
            MeshWarning,
            stacklevel=3,
        )
    cell_data: dict[str, np.ndarray] = {}
    for key, per_block in (m.cell_data or {}).items():
        parts = [np.asarray(per_block[i]) for i in keep]
        if not parts:
            continue
        if len({p.shape[1:] for p in parts}) != 1:
            warnings.warn(f"{source}: cell_data {key!r} has inconsistent shapes; dropped", MeshWarning, stacklevel=3)
            continue
        cell_data[key] = np.concatenate(parts)
    point_data = {k: np.asarray(v) for k, v in (m.point_data or {}).items()}
    points = np.asarray(m.points, dtype=np.float64)
    try:
        return Mesh(points, blocks, point_data=point_data, cell_data=cell_data, name=Path(source).stem)
    except MeshError as exc:
        raise MeshError(f"{source}: {exc}") from exc


def _meshio_safe(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    return a.astype(np.uint8) if a.dtype == bool else a


def to_meshio(mesh: Mesh, point_data: Mapping | None = None, cell_data: Mapping | None = None):
    """Convert to ``meshio.Mesh``. ``point_data`` / ``cell_data`` (global numbering) are added
    to (and override) the mesh's own."""
    import meshio

    pd = {**mesh.point_data, **(point_data or {})}
    cd = {**mesh.cell_data, **(cell_data or {})}
    n, ne = mesh.n_nodes, mesh.n_elements
    for k, v in pd.items():
        if np.asarray(v).shape[:1] != (n,):
            raise MeshError(f"point_data[{k!r}] has shape {np.shape(v)}; first axis must be {n}")
    for k, v in cd.items():
        if np.asarray(v).shape[:1] != (ne,):
            raise MeshError(f"cell_data[{k!r}] has shape {np.shape(v)}; first axis must be {ne}")
    off = mesh.element_offsets
    cells = [meshio.CellBlock(b.type, b.data) for b in mesh.cells]
    cdb = {k: [_meshio_safe(v)[off[i] : off[i + 1]] for i in range(len(cells))] for k, v in cd.items()}
    return meshio.Mesh(mesh.nodes, cells, point_data={k: _meshio_safe(v) for k, v in pd.items()}, cell_data=cdb)


# ---------------------------------------------------------------------------- public API
def read_mesh(path: str | os.PathLike, *, fmt: str | None = None, remove_unused: bool = False) -> Mesh:
    """Read a surface mesh file.

    path : file; format from the extension (see module table) or ``fmt``.
    remove_unused : drop nodes no kept element uses (renumbering; point_data follows).

    Raises `MeshError` naming the file if it is missing, of unknown type or unreadable, or
    holds no triangle/quad cells.
    """
    path = Path(path)
    f = _format_of(path, fmt)
    if not path.is_file():
        raise MeshError(f"{path}: no such file")
    if f == "gmsh" and fmt is None and _sniff_gid(path):
        f = "gid"
    if f == "gid":
        mesh = read_gid(path)
    else:
        import meshio


        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # meshio's own chatter
                m = meshio.read(path, file_format=f)
        except (Exception, SystemExit) as exc:
            # meshio raises ReadError, ValueError, IndexError, ... and, for a ReadError in
            # its dispatcher, prints and calls sys.exit(1): turn all into MeshError.
            detail = "unreadable (meshio gave up)" if isinstance(exc, SystemExit) else f"{type(exc).__name__}: {exc}"
            cause = None if isinstance(exc, SystemExit) else exc
            raise MeshError(f"{path}: cannot read as {f}: {detail}") from cause
        mesh = from_meshio(m, source=str(path))
    if mesh.n_elements == 0:
        raise MeshError(f"{path}: no triangle or quadrilateral elements")
    if remove_unused:
        mesh = mesh.remove_unused_nodes()[0]
    return mesh


def write_mesh(
    mesh: Mesh,
    path: str | os.PathLike,
    point_data: Mapping[str, np.ndarray] | None = None,
    cell_data: Mapping[str, np.ndarray] | None = None,
    *,
    fmt: str | None = None,
    binary: bool = True,
) -> None:
    """Write a mesh (atomically).

    point_data : name -> (N,) or (N, k) arrays, added to ``mesh.point_data``.
    cell_data : name -> (E,) or (E, k) arrays in global element numbering.
    fmt : format name overriding the extension ("gmsh", "gid", "vtk", "vtu",
        "abaqus", "nastran", "stl", "obj").
    binary : binary encoding for gmsh / vtk / vtu / stl.

    gmsh: written by `write_msh41` (cell block b -> surface entity b + 1); data keys
    starting with ``gmsh:`` (entity tags from a previous read) are not written.

    Format limits (each warned about with `MeshWarning` when data would be lost): STL
    stores triangles only (quads are split along the 0-2 diagonal) and no data; Abaqus,
    Nastran and OBJ store no point/cell data. For GiD, ``point_data`` given here is written
    as a results file next to the mesh (``x.post.msh`` -> ``x.post.res``).
    """
    path = Path(path)
    f = _format_of(path, fmt)
    if f == "gid":
        write_gid(mesh, path)
        res = {**(point_data or {})}
        if res:
            write_gid_results(_res_path(path), res, n_nodes=mesh.n_nodes)
        return
    import meshio

    out = mesh
    pd = dict(point_data or {})
    cd = dict(cell_data or {})
    if f == "stl":
        q = [b for b in mesh.cells if b.type == "quad"]
        if q:
            warnings.warn(f"{path}: STL stores triangles only; {sum(map(len, q))} quads split in two", MeshWarning, stacklevel=2)
            tris = []
            for b in mesh.cells:
                d = b.data
                tris.append(d if b.type == "triangle" else np.concatenate([d[:, [0, 1, 2]], d[:, [0, 2, 3]]]))
            out = Mesh(mesh.nodes, [CellBlock("triangle", np.concatenate(tris))], name=mesh.name)
    if f in ("stl", "abaqus", "nastran", "obj"):
        lost = sorted({*mesh.point_data, *mesh.cell_data, *pd, *cd})
        if lost:
            warnings.warn(f"{path}: format {f} stores no point/cell data; dropped {lost}", MeshWarning, stacklevel=2)
        out = Mesh(out.nodes, out.cells, name=mesh.name)
        pd, cd = {}, {}
    if f == "gmsh":
        atomic_write(path, lambda tmp: write_msh41(tmp, out, pd, cd, binary=binary))
        return
    m = to_meshio(out, pd, cd)
    kwargs: dict = {}
    if f in ("vtk", "vtu", "stl"):
        kwargs["binary"] = binary

    def _w(tmp: str) -> None:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if f == "gmsh":
                    ver = "4.1" if f == "gmsh" else "2.2"
                    meshio.gmsh.write(tmp, m, fmt_version=ver, binary=binary)
                else:
                    meshio.write(tmp, m, file_format=f, **kwargs)
        except Exception as exc:
            raise MeshError(f"{path}: cannot write as {f}: {type(exc).__name__}: {exc}") from exc

    atomic_write(path, _w)


_MSH_TYPE = {"triangle": 2, "quad": 3}


def write_msh41(
    path: str | os.PathLike,
    mesh: Mesh,
    point_data: Mapping[str, np.ndarray] | None = None,
    cell_data: Mapping[str, np.ndarray] | None = None,
    *,
    binary: bool = True,
) -> None:
    """Write gmsh MSH 4.1 (ASCII or binary, 8-byte size_t) directly (not atomic by itself).

    Cell block b becomes discrete surface entity b + 1 (its bounding box in $Entities); all
    nodes are listed in entity 1's node block in mesh order (node tag = index + 1; other
    entities have empty node blocks); element tags are global element numbers + 1. Data
    arrays with 1, 3 or 9 components per node/element are written as $NodeData/$ElementData
    (step 0); (N, 2) vectors are padded with a zero z; other shapes raise `MeshError`.
    meshio writes MSH 4.1 only with a node-to-entity map and, for ASCII, prints numpy 2
    scalars as "np.float64(...)", hence this writer. Reading goes through meshio.
    """
    pd = {**mesh.point_data, **(point_data or {})}
    cd = {**mesh.cell_data, **(cell_data or {})}
    pd = {k: v for k, v in pd.items() if not str(k).startswith("gmsh:")}
    cd = {k: v for k, v in cd.items() if not str(k).startswith("gmsh:")}
    N, E, B = mesh.n_nodes, mesh.n_elements, len(mesh.cells)

    def _prep(name: str, v: np.ndarray, n: int, what: str) -> np.ndarray:
        a = np.asarray(v, dtype=np.float64)
        if a.shape[:1] != (n,):
            raise MeshError(f"{path}: {what} {name!r} has shape {a.shape}; first axis must be {n}")
        a = a.reshape(n, -1)
        if a.shape[1] == 2:
            a = np.column_stack([a, np.zeros(n)])
        if a.shape[1] not in (1, 3, 9):
            raise MeshError(f"{path}: {what} {name!r} has {a.shape[1]} components; gmsh allows 1, 3 or 9")
        return a

    pdat = {k: _prep(k, v, N, "point_data") for k, v in pd.items()}
    cdat = {k: _prep(k, v, E, "cell_data") for k, v in cd.items()}
    sz, i32, f64 = np.uint64, np.int32, np.float64

    with open(path, "wb") as fh:
        w = fh.write

        def ints(*a: int) -> None:  # one ASCII line of integers
            w((" ".join(str(int(x)) for x in a) + "\n").encode())

        w(f"$MeshFormat\n4.1 {int(binary)} 8\n".encode())
        if binary:
            np.array([1], dtype=i32).tofile(fh)
            w(b"\n")
        w(b"$EndMeshFormat\n$Entities\n")
        if binary:
            np.array([0, 0, B, 0], dtype=sz).tofile(fh)
        else:
            ints(0, 0, B, 0)
        for b, blk in enumerate(mesh.cells):
            used = mesh.nodes[np.unique(blk.data)] if len(blk) else np.zeros((1, 3))
            box = np.concatenate([used.min(axis=0), used.max(axis=0)])
            if binary:
                np.array([b + 1], dtype=i32).tofile(fh)
                box.astype(f64).tofile(fh)
                np.array([0, 0], dtype=sz).tofile(fh)  # no physical tags, no bounding curves
            else:
                w((f"{b + 1} " + " ".join(f"{x:.17g}" for x in box) + " 0 0\n").encode())
        if binary:
            w(b"\n")
        w(b"$EndEntities\n$Nodes\n")
        nb = max(B, 1)
        tags = np.arange(1, N + 1, dtype=sz)
        if binary:
            np.array([nb, N, 1 if N else 0, N], dtype=sz).tofile(fh)
        else:
            ints(nb, N, 1 if N else 0, N)
        for b in range(nb):
            n_here = N if b == 0 else 0
            if binary:
                np.array([2, b + 1, 0], dtype=i32).tofile(fh)
                np.array([n_here], dtype=sz).tofile(fh)
                if n_here:
                    tags.tofile(fh)
                    mesh.nodes.astype(f64).tofile(fh)
            else:
                ints(2, b + 1, 0, n_here)
                if n_here:
                    np.savetxt(fh, tags, fmt="%d")
                    np.savetxt(fh, mesh.nodes, fmt="%.17g")
        if binary:
            w(b"\n")
        w(b"$EndNodes\n$Elements\n")
        if binary:
            np.array([B, E, 1 if E else 0, E], dtype=sz).tofile(fh)
        else:
            ints(B, E, 1 if E else 0, E)
        for b, (off, blk) in enumerate(mesh.elements()):
            rows = np.column_stack([np.arange(off + 1, off + len(blk) + 1), blk.data + 1])
            if binary:
                np.array([2, b + 1, _MSH_TYPE[blk.type]], dtype=i32).tofile(fh)
                np.array([len(blk)], dtype=sz).tofile(fh)
                rows.astype(sz).tofile(fh)
            else:
                ints(2, b + 1, _MSH_TYPE[blk.type], len(blk))
                np.savetxt(fh, rows, fmt="%d")
        if binary:
            w(b"\n")
        w(b"$EndElements\n")
        for section, data in (("NodeData", pdat), ("ElementData", cdat)):
            for name, a in data.items():
                n, k = a.shape
                nm = str(name).replace('"', "'")
                w(f'${section}\n1\n"{nm}"\n1\n0\n3\n0\n{k}\n{n}\n'.encode())
                if binary:
                    rec = np.empty(n, dtype=[("tag", i32), ("v", f64, (k,))])
                    rec["tag"] = np.arange(1, n + 1)
                    rec["v"] = a
                    rec.tofile(fh)
                    w(b"\n")
                else:
                    np.savetxt(fh, np.column_stack([np.arange(1, n + 1), a]), fmt=["%d"] + ["%.17g"] * k)
                w(f"$End{section}\n".encode())


def _res_path(path: Path) -> Path:
    return path.with_suffix(".res")


# ---------------------------------------------------------------------------- GiD mesh
_GID_TYPES = {"triangle": "Triangle", "quad": "Quadrilateral"}
_GID_HEADER = re.compile(
    r'^\s*MESH\s*(?:"(?P<qname>[^"]*)"|(?P<name>(?!dimension)\S+))?\s+dimension\s*=?\s*(?P<dim>\d)'
    r"\s+ElemType\s+(?P<etype>\w+)\s+Nnode\s*=?\s*(?P<nnode>\d+)",
    re.IGNORECASE,
)


def _gid_name(s: str) -> str:
    return s.replace('"', "'")


def write_gid(mesh: Mesh, path: str | os.PathLike) -> None:
    """Write a GiD ASCII mesh (post-process / import format), atomically.

    One ``MESH "name" dimension 3 ElemType Triangle|Quadrilateral Nnode 3|4`` block per
    CellBlock, in order (so global element numbering is preserved). Coordinates (1-based
    node ids, ``%.17g``) are written in the first block; later blocks have an empty
    Coordinates section, as GiD shares nodes between MESH blocks. Element ids are 1-based
    global element numbers + 1.
    """
    path = Path(path)
    ids = np.arange(1, mesh.n_nodes + 1)
    single = len(mesh.cells) <= 1
    name = _gid_name(mesh.name)

    def _w(tmp: str) -> None:
        with open(tmp, "w", encoding="ascii", newline="\n") as fh:
            blocks = list(mesh.elements()) or [(0, CellBlock("triangle", np.empty((0, 3), np.int64)))]
            for b, (off, blk) in enumerate(blocks):
                k = blk.nodes_per_element
                nm = name if single else f"{name}-{blk.type}-{b}"
                fh.write(f'MESH "{nm}" dimension 3 ElemType {_GID_TYPES[blk.type]} Nnode {k}\n')
                fh.write("Coordinates\n")
                if b == 0:
                    fh.write("# node_number coordinate_x coordinate_y coordinate_z\n")
                    np.savetxt(fh, np.column_stack([ids, mesh.nodes]), fmt=["%d"] + ["%.17g"] * 3)
                fh.write("End Coordinates\n\n")
                fh.write("Elements\n")
                fh.write("# element_number " + " ".join(f"node_{i + 1}" for i in range(k)) + "\n")
                eid = np.arange(off + 1, off + len(blk) + 1)
                np.savetxt(fh, np.column_stack([eid, blk.data + 1]), fmt="%d")
                fh.write("End Elements\n\n")

    atomic_write(path, _w)


def read_gid(path: str | os.PathLike) -> Mesh:
    """Read a GiD ASCII mesh written by `write_gid` or GiD itself.

    Node ids may be any positive integers (mapped to 0-based indices in ascending id order;
    when they are not exactly 1..N the original ids are kept in point_data["gid:node_id"]);
    a trailing material column on element lines is ignored. Triangle (3/6 nodes) and
    Quadrilateral (4/8/9) blocks are kept (higher order -> corners, with a warning); other
    element types are dropped with a warning.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="ascii", errors="replace")
    except OSError as exc:
        raise MeshError(f"{path}: cannot read: {exc}") from exc
    lines = text.splitlines()
    coords: list[np.ndarray] = []
    raw_blocks: list[tuple[str, int, np.ndarray, int]] = []  # (type, k, (E, k) node ids, line)
    names: list[str] = []
    dropped: dict[str, int] = {}
    reduced: dict[str, int] = {}
    i = 0
    cur: tuple[str, int, int] | None = None  # (etype, nnode, header line)
    while i < len(lines):
        s = lines[i].split("#", 1)[0].strip()
        low = s.lower()
        if not s:
            i += 1
            continue
        if low.startswith("mesh"):
            mh = _GID_HEADER.match(s)
            if not mh:
                raise MeshError(f"{path}, line {i + 1}: malformed MESH header: {lines[i]!r}")
            cur = (mh["etype"].lower(), int(mh["nnode"]), i + 1)
            names.append(mh["qname"] if mh["qname"] is not None else (mh["name"] or ""))
            i += 1
            continue
        if low in ("coordinates", "elements"):
            start = i + 1
            end_kw = "end " + low
            j = start
            body: list[str] = []
            while j < len(lines) and lines[j].split("#", 1)[0].strip().lower() != end_kw:
                t = lines[j].split("#", 1)[0].strip()
                if t:
                    body.append(t)
                j += 1
            if j == len(lines):
                raise MeshError(f"{path}, line {i + 1}: {s} without '{end_kw.title()}'")
            if low == "coordinates":
                if body:
                    try:
                        arr = np.array([[float(x) for x in b.split()[:4]] for b in body])
                    except ValueError as exc:
                        raise MeshError(f"{path}, lines {start + 1}-{j}: bad coordinate line: {exc}") from exc
                    if arr.ndim != 2 or arr.shape[1] < 3:
                        raise MeshError(f"{path}, line {start + 1}: coordinates need id x y [z]")
                    if arr.shape[1] == 3:
                        arr = np.column_stack([arr, np.zeros(len(arr))])
                    coords.append(arr)
            else:
                if cur is None:
                    raise MeshError(f"{path}, line {i + 1}: Elements before any MESH header")
                etype, k, hl = cur
                if body:
                    try:
                        rows = [[int(x) for x in b.split()[: 1 + k]] for b in body]
                        arr = np.array(rows, dtype=np.int64)
                    except ValueError as exc:
                        raise MeshError(f"{path}, lines {start + 1}-{j}: bad element line: {exc}") from exc
                    if arr.ndim != 2 or arr.shape[1] != 1 + k:
                        raise MeshError(f"{path}, line {start + 1}: element lines need id + {k} nodes")
                else:
                    arr = np.empty((0, 1 + k), dtype=np.int64)
                if etype == "triangle" and k in (3, 6):
                    if k == 6:
                        reduced["Triangle Nnode 6"] = reduced.get("Triangle Nnode 6", 0) + len(arr)
                    raw_blocks.append(("triangle", 3, arr[:, 1:4], hl))
                elif etype == "quadrilateral" and k in (4, 8, 9):
                    if k != 4:
                        reduced[f"Quadrilateral Nnode {k}"] = reduced.get(f"Quadrilateral Nnode {k}", 0) + len(arr)
                    raw_blocks.append(("quad", 4, arr[:, 1:5], hl))
                else:
                    dropped[f"{etype} Nnode {k}"] = dropped.get(f"{etype} Nnode {k}", 0) + len(arr)
            i = j + 1
            continue
        if low.startswith("unit") or low.startswith("color"):
            i += 1
            continue
        raise MeshError(f"{path}, line {i + 1}: unexpected line {lines[i]!r} (not a GiD mesh?)")
    if not coords:
        raise MeshError(f"{path}: no Coordinates in GiD mesh")
    allc = np.concatenate(coords)
    ids = allc[:, 0].astype(np.int64)
    order = np.argsort(ids, kind="stable")
    sids = ids[order]
    dup = np.flatnonzero(sids[1:] == sids[:-1])
    if dup.size:
        raise MeshError(f"{path}: node id {sids[dup[0]]} defined twice")
    nodes = allc[order, 1:4]
    blocks = []
    for t, k, conn, hl in raw_blocks:
        pos = np.searchsorted(sids, conn)
        pos_c = np.minimum(pos, len(sids) - 1)
        bad = sids[pos_c] != conn
        if bad.any():
            r, c = np.argwhere(bad)[0]
            raise MeshError(f"{path}: element in MESH block at line {hl} (row {r}) uses undefined node id {conn[r, c]}")
        blocks.append(CellBlock(t, pos_c))
    if dropped:
        warnings.warn(f"{path}: dropped non-surface GiD elements " + ", ".join(f"{n} {t}" for t, n in dropped.items()), MeshWarning, stacklevel=2)
    if reduced:
        warnings.warn(f"{path}: reduced to corner nodes: " + ", ".join(f"{n} {t}" for t, n in reduced.items()), MeshWarning, stacklevel=2)
    name = names[0] if names else path.stem
    if len(raw_blocks) > 1:
        name = re.sub(r"-(triangle|quad)-0$", "", name)
    try:
        pd = {} if np.array_equal(sids, np.arange(1, len(sids) + 1)) else {"gid:node_id": sids}
        return Mesh(nodes, blocks, point_data=pd, name=name)
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from exc


# ---------------------------------------------------------------------------- GiD results
def write_gid_results(
    path: str | os.PathLike,
    results: Mapping[str, np.ndarray],
    *,
    n_nodes: int | None = None,
    analysis: str = "cadbridge",
    step: float = 1.0,
) -> None:
    """Write nodal results as a GiD post-process results file (ASCII), atomically.

    results : name -> (N,) scalar or (N, 2|3) vector per node (node ids 1..N, as in
        `write_gid`). Rows containing NaN are omitted (GiD then shows no value there).
    Layout::

        GiD Post Results File 1.0
        Result "name" "analysis" step Scalar|Vector OnNodes
        ComponentNames "name" | "name-X", "name-Y", "name-Z"
        Values
        id value(s)
        End Values
    """
    path = Path(path)
    items = []
    for name, v in results.items():
        a = np.asarray(v, dtype=np.float64)
        if n_nodes is not None and a.shape[:1] != (n_nodes,):
            raise MeshError(f"{path}: result {name!r} has shape {a.shape}; first axis must be {n_nodes}")
        if a.ndim == 2 and a.shape[1] == 1:
            a = a[:, 0]
        if a.ndim == 1:
            kind = "Scalar"
        elif a.ndim == 2 and a.shape[1] in (2, 3):
            kind = "Vector"
            if a.shape[1] == 2:
                a = np.column_stack([a, np.zeros(len(a))])
        else:
            raise MeshError(f"{path}: result {name!r} has shape {a.shape}; need (N,) or (N, 2|3)")
        items.append((_gid_name(str(name)), kind, a))

    def _w(tmp: str) -> None:
        with open(tmp, "w", encoding="ascii", newline="\n") as fh:
            fh.write("GiD Post Results File 1.0\n\n")
            for name, kind, a in items:
                fh.write(f'Result "{name}" "{_gid_name(analysis)}" {step:.17g} {kind} OnNodes\n')
                if kind == "Scalar":
                    fh.write(f'ComponentNames "{name}"\n')
                else:
                    fh.write(f'ComponentNames "{name}-X", "{name}-Y", "{name}-Z"\n')
                fh.write("Values\n")
                a2 = a.reshape(len(a), -1)
                ok = np.all(np.isfinite(a2), axis=1)
                ids = np.flatnonzero(ok) + 1
                np.savetxt(fh, np.column_stack([ids, a2[ok]]), fmt=["%d"] + ["%.17g"] * a2.shape[1])
                fh.write("End Values\n\n")

    atomic_write(path, _w)


_RES_HEADER = re.compile(
    r'^\s*Result\s+"(?P<name>[^"]*)"\s+"(?P<analysis>[^"]*)"\s+(?P<step>\S+)\s+(?P<kind>\w+)\s+(?P<loc>\w+)',
    re.IGNORECASE,
)


def read_gid_results(path: str | os.PathLike, n_nodes: int | None = None) -> dict[str, np.ndarray]:
    """Read nodal Scalar / Vector results of a GiD ASCII results file.

    Returns name -> (n_nodes,) or (n_nodes, 3) float arrays indexed by node id - 1, NaN where
    a node has no value. ``n_nodes`` defaults to the largest node id seen. If a name occurs
    for several steps, the last one wins.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="ascii", errors="replace").splitlines()
    except OSError as exc:
        raise MeshError(f"{path}: cannot read: {exc}") from exc
    if not lines or not lines[0].strip().lower().startswith("gid post results file 1.0"):
        raise MeshError(f"{path}: not a GiD results file (first line must be 'GiD Post Results File 1.0')")
    raw: dict[str, np.ndarray] = {}
    i, cur = 1, None
    while i < len(lines):
        s = lines[i].split("#", 1)[0].strip()
        if s.lower().startswith("result ") and not s.lower().startswith("resultgroup"):
            m = _RES_HEADER.match(s)
            if not m or m["loc"].lower() != "onnodes" or m["kind"].lower() not in ("scalar", "vector"):
                raise MeshError(f"{path}, line {i + 1}: unsupported result header {lines[i]!r}")
            cur = (m["name"], m["kind"].lower())
        elif s.lower() == "values":
            if cur is None:
                raise MeshError(f"{path}, line {i + 1}: Values before a Result header")
            j = i + 1
            body = []
            while j < len(lines) and lines[j].strip().lower() != "end values":
                t = lines[j].split("#", 1)[0].strip()
                if t:
                    body.append(t)
                j += 1
            if j == len(lines):
                raise MeshError(f"{path}, line {i + 1}: Values without 'End Values'")
            ncol = 2 if cur[1] == "scalar" else 4
            try:
                arr = np.array([[float(x) for x in b.split()[:ncol]] for b in body]).reshape(-1, ncol)
            except ValueError as exc:
                raise MeshError(f"{path}, lines {i + 2}-{j}: bad value line: {exc}") from exc
            raw[cur[0]] = arr
            i = j
        i += 1
    n = n_nodes
    if n is None:
        n = max((int(a[:, 0].max()) for a in raw.values() if len(a)), default=0)
    out = {}
    for name, arr in raw.items():
        ids = arr[:, 0].astype(np.int64) - 1
        if len(ids) and (ids.min() < 0 or ids.max() >= n):
            raise MeshError(f"{path}: result {name!r} has node id {ids.max() + 1} outside 1..{n}")
        vals = arr[:, 1:]
        res = np.full((n, vals.shape[1]), np.nan)
        res[ids] = vals
        out[name] = res[:, 0] if vals.shape[1] == 1 else res
    return out
