"""The thesis' spreadsheet outputs (Neto 2010, sec. 6.3 and appendix D), at full precision.

* `write_grid_csv`: one row per grid point of a patch,
  ``patch,point,x,y,z,nx,ny,nz,<error names>``.
* `write_coefficients_listing`: the patch coefficients, appendix D layout (comma separated)::

      -TRIANGULAR NAGATA PATCHES-
      c00,c10,c01,c11,c20,c02
      Patch: 1
      <x components of c00..c02>
      <y components>
      <z components>
      Patch: 2
      ...
      -QUADRILATERAL NAGATA PATCHES-
      c00,c10,c01,c11,c20,c02,c21,c12
      Patch: <Et+1>
      ...

  Patches use the global element numbering (triangles 1..Et, then quads Et+1..Et+Eq), the
  same as the tool file; a block without patches is omitted. Floats are ``repr`` (round-trip).
"""

from __future__ import annotations

import csv
import os

import numpy as np

from cadbridge.common.atomic import atomic_write

__all__ = ["read_coefficients_listing", "read_grid_csv", "write_coefficients_listing", "write_grid_csv"]

TRI_TITLE = "-TRIANGULAR NAGATA PATCHES-"
QUAD_TITLE = "-QUADRILATERAL NAGATA PATCHES-"
_NAMES = ("c00", "c10", "c01", "c11", "c20", "c02", "c21", "c12")


def write_grid_csv(
    path: str | os.PathLike,
    patch,
    point,
    xyz,
    normals,
    errors: dict[str, np.ndarray] | None = None,
) -> None:
    """Write grid points: patch (M,) int, point (M,) int, xyz (M, 3), normals (M, 3), errors {name: (M,)}."""
    patch = np.asarray(patch)
    point = np.asarray(point)
    m = len(patch)
    for arr, what in ((patch, "patch"), (point, "point")):
        if arr.shape != (m,) or (arr.size and arr.dtype.kind not in "iu"):
            raise ValueError(f"{what} must be an integer array of shape ({m},), got {arr.dtype} {arr.shape}")
    xyz = np.asarray(xyz, dtype=float)
    normals = np.asarray(normals, dtype=float)
    if xyz.shape != (m, 3) or normals.shape != (m, 3):
        raise ValueError(f"xyz and normals must have shape ({m}, 3), got {xyz.shape} and {normals.shape}")
    errors = dict(errors or {})
    fixed = {"patch", "point", "x", "y", "z", "nx", "ny", "nz"}
    cols = [xyz, normals]
    for name, err in errors.items():
        if not name or name in fixed or any(c in name for c in ',"\r\n'):
            raise ValueError(f"invalid error column name {name!r}")
        e = np.asarray(err, dtype=float)
        if e.shape != (m,):
            raise ValueError(f"errors[{name!r}] must have shape ({m},), got {e.shape}")
        cols.append(e[:, None])
    values = np.hstack(cols).tolist()
    header = ["patch", "point", "x", "y", "z", "nx", "ny", "nz", *errors]
    lines = [",".join(header)]
    lines += [
        f"{a},{b}," + ",".join(map(repr, row)) for a, b, row in zip(patch.tolist(), point.tolist(), values)
    ]
    with atomic_write(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")


def read_grid_csv(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a grid CSV back: {"patch": (M,) int, "point": (M,) int, "xyz": (M, 3), "normals": (M, 3), <error>: (M,)}."""
    with open(path, encoding="utf-8", newline="") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    if header[:8] != ["patch", "point", "x", "y", "z", "nx", "ny", "nz"]:
        raise ValueError(f"{path}: unexpected header {header!r}")
    for i, r in enumerate(body, start=2):
        if len(r) != len(header):
            raise ValueError(f"{path}, line {i}: {len(r)} fields, header has {len(header)}")
    ints = np.array([[int(r[0]), int(r[1])] for r in body], dtype=np.int64).reshape(-1, 2)
    vals = np.array([[float(x) for x in r[2:]] for r in body], dtype=float).reshape(-1, len(header) - 2)
    out = {"patch": ints[:, 0], "point": ints[:, 1], "xyz": vals[:, 0:3], "normals": vals[:, 3:6]}
    for j, name in enumerate(header[8:]):
        out[name] = vals[:, 6 + j]
    return out


def _block_lines(title: str, coef: np.ndarray, first_id: int) -> list[str]:
    k = coef.shape[1]
    lines = [title, ",".join(_NAMES[:k])]
    rows = coef.transpose(0, 2, 1).tolist()  # (E, 3 components, k coefficients)
    for e, comp in enumerate(rows):
        lines.append(f"Patch: {first_id + e}")
        lines += [",".join(map(repr, r)) for r in comp]
    return lines


def write_coefficients_listing(path: str | os.PathLike, tri_coefficients=None, quad_coefficients=None) -> None:
    """Write tri (Et, 6, 3) and quad (Eq, 8, 3) coefficients in the appendix D layout (see module doc)."""
    lines: list[str] = []
    first_id = 1
    for coef, k, title in ((tri_coefficients, 6, TRI_TITLE), (quad_coefficients, 8, QUAD_TITLE)):
        c = np.zeros((0, k, 3)) if coef is None else np.asarray(coef, dtype=float)
        if c.size == 0:
            continue
        if c.ndim != 3 or c.shape[1:] != (k, 3):
            raise ValueError(f"{title}: coefficients must have shape (n, {k}, 3), got {c.shape}")
        lines += _block_lines(title, c, first_id)
        first_id += len(c)
    with atomic_write(path, "w") as fh:
        fh.write("\n".join(lines) + ("\n" if lines else ""))


def read_coefficients_listing(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Parse a listing back: (tri (Et, 6, 3), quad (Eq, 8, 3)); a missing block gives an empty array."""
    with open(path, encoding="utf-8", newline="") as fh:
        rows = list(csv.reader(fh))
    out = {TRI_TITLE: [], QUAD_TITLE: []}
    expect_id = 1
    i = 0
    while i < len(rows):
        title = rows[i][0] if rows[i] else ""
        if title not in out:
            raise ValueError(f"{path}, line {i + 1}: expected a block title, got {rows[i]!r}")
        k = 6 if title == TRI_TITLE else 8
        if rows[i + 1] != list(_NAMES[:k]):
            raise ValueError(f"{path}, line {i + 2}: expected coefficient names {_NAMES[:k]}")
        i += 2
        while i < len(rows) and rows[i] and rows[i][0].startswith("Patch:"):
            pid = int(rows[i][0].split(":")[1])
            if pid != expect_id:
                raise ValueError(f"{path}, line {i + 1}: patch {pid} where {expect_id} was expected")
            comp = rows[i + 1 : i + 4]
            if len(comp) != 3 or any(len(r) != k for r in comp):
                raise ValueError(f"{path}, line {i + 2}: expected 3 rows of {k} values")
            out[title].append(np.array([[float(x) for x in r] for r in comp]).T)
            expect_id += 1
            i += 4
    tri = np.array(out[TRI_TITLE]).reshape(-1, 6, 3)
    quad = np.array(out[QUAD_TITLE]).reshape(-1, 8, 3)
    return tri, quad
