"""Spreadsheet outputs of thesis appendix D: layout and exact round trips.

References: Python's csv module reading the files back (independent of our readers), the
appendix D layout (block titles, 'Patch: k', x/y/z rows by coefficient columns), and
bit-for-bit equality with the written arrays.
"""

from __future__ import annotations

import csv
import os

import numpy as np
import pytest

from cadbridge.io.csvgrid import (
    read_coefficients_listing,
    read_grid_csv,
    write_coefficients_listing,
    write_grid_csv,
)


def grid(m: int = 12, seed: int = 0):
    rng = np.random.default_rng(seed)
    patch = np.repeat(np.arange(1, m // 4 + 1), 4)[:m]
    point = np.tile(np.arange(1, 5), m)[:m]
    xyz = rng.normal(size=(m, 3)) * 1e3
    xyz[0] = [-0.0, 5e-324, 1 / 3]
    nrm = rng.normal(size=(m, 3))
    errors = {"geom_error": rng.random(m) * 1e-6, "normal_error_deg": rng.random(m)}
    return patch, point, xyz, nrm, errors


def test_grid_csv_layout_and_roundtrip(tmp_path):
    patch, point, xyz, nrm, errors = grid()
    path = tmp_path / "grid.csv"
    write_grid_csv(path, patch, point, xyz, nrm, errors)
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["patch", "point", "x", "y", "z", "nx", "ny", "nz", "geom_error", "normal_error_deg"]
    assert len(rows) == 13 and all(len(r) == 10 for r in rows)
    assert [int(r[0]) for r in rows[1:]] == patch.tolist() and [int(r[1]) for r in rows[1:]] == point.tolist()
    vals = np.array([[float(x) for x in r[2:]] for r in rows[1:]])
    assert vals[:, :3].tobytes() == xyz.tobytes() and vals[:, 3:6].tobytes() == nrm.tobytes()
    assert vals[:, 6].tobytes() == errors["geom_error"].tobytes()
    back = read_grid_csv(path)
    assert back["xyz"].tobytes() == xyz.tobytes() and np.array_equal(back["patch"], patch)
    assert back["normal_error_deg"].tobytes() == errors["normal_error_deg"].tobytes()


def test_grid_csv_without_errors_and_validation(tmp_path):
    patch, point, xyz, nrm, _ = grid(4)
    path = tmp_path / "g.csv"
    write_grid_csv(path, patch, point, xyz, nrm)
    assert open(path).readline().strip() == "patch,point,x,y,z,nx,ny,nz"
    before = path.read_bytes()
    with pytest.raises(ValueError, match="shape"):
        write_grid_csv(path, patch, point, xyz[:3], nrm)
    with pytest.raises(ValueError, match="error column"):
        write_grid_csv(path, patch, point, xyz, nrm, {"a,b": np.zeros(4)})
    with pytest.raises(ValueError, match="integer"):
        write_grid_csv(path, patch.astype(float), point, xyz, nrm)
    assert path.read_bytes() == before and os.listdir(tmp_path) == ["g.csv"]


def test_coefficient_listing_layout(tmp_path):
    rng = np.random.default_rng(1)
    tri, quad = rng.normal(size=(2, 6, 3)), rng.normal(size=(3, 8, 3))
    path = tmp_path / "coef.csv"
    write_coefficients_listing(path, tri, quad)
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["-TRIANGULAR NAGATA PATCHES-"]
    assert rows[1] == ["c00", "c10", "c01", "c11", "c20", "c02"]
    assert rows[2] == ["Patch: 1"]
    # rows are x, y, z components; columns are coefficients (appendix D)
    for comp in range(3):
        assert [float(x) for x in rows[3 + comp]] == tri[0, :, comp].tolist()
    assert rows[6] == ["Patch: 2"]
    q = 2 + 2 * 4
    assert rows[q] == ["-QUADRILATERAL NAGATA PATCHES-"]
    assert rows[q + 1] == ["c00", "c10", "c01", "c11", "c20", "c02", "c21", "c12"]
    assert rows[q + 2] == ["Patch: 3"]  # global numbering: quads follow the triangles
    assert [float(x) for x in rows[q + 5]] == quad[0, :, 2].tolist()
    assert len(rows) == q + 2 + 3 * 4
    t2, q2 = read_coefficients_listing(path)
    assert t2.tobytes() == tri.tobytes() and q2.tobytes() == quad.tobytes()


@pytest.mark.parametrize("which", ["tri", "quad"])
def test_coefficient_listing_single_block(tmp_path, which):
    rng = np.random.default_rng(2)
    tri = rng.normal(size=(2, 6, 3)) if which == "tri" else None
    quad = rng.normal(size=(2, 8, 3)) if which == "quad" else np.zeros((0, 8, 3))
    path = tmp_path / "c.csv"
    write_coefficients_listing(path, tri, quad)
    text = path.read_text()
    assert ("TRIANGULAR" in text) == (which == "tri") and ("QUADRILATERAL" in text) == (which == "quad")
    assert "Patch: 1\n" in text and "Patch: 3" not in text
    t2, q2 = read_coefficients_listing(path)
    assert (t2 if which == "tri" else q2).tobytes() == (tri if which == "tri" else quad).tobytes()
    assert len(q2 if which == "tri" else t2) == 0
