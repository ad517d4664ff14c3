"""VTU and PNG report outputs: exact read-back with meshio (and VTK when installed), PNG size,
validation errors, atomic writes."""

from __future__ import annotations

import os
import struct

import meshio
import numpy as np
import pytest

from cadbridge.io import plots, vtu
from cadbridge.io.plots import (
    plot_arc_convergence,
    plot_error_histogram,
    plot_normal_sources,
    plot_section_error,
)
from cadbridge.io.vtu import decode_field_string, write_mesh_vtu, write_surface_vtu

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def png_size(path) -> tuple[int, int]:
    with open(path, "rb") as fh:
        head = fh.read(24)
    assert head[:8] == PNG_MAGIC, "not a PNG file"
    assert head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


def no_temp_files(directory) -> bool:
    return not [f for f in os.listdir(directory) if f.endswith(".tmp")]


# ----------------------------------------------------------------------------- fixtures

@pytest.fixture
def grid_surface():
    """A 4 x 3 grid of points on a cylinder split into triangles, with per-point data."""
    rng = np.random.default_rng(1)
    t, z = np.meshgrid(np.linspace(0, np.pi / 2, 4), np.linspace(0, 1, 3), indexing="ij")
    pts = np.column_stack([np.cos(t).ravel(), np.sin(t).ravel(), z.ravel()])
    idx = np.arange(12).reshape(4, 3)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    tri = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    normals = np.column_stack([np.cos(t).ravel(), np.sin(t).ravel(), np.zeros(12)])
    return pts, tri, normals, rng


def _compare_point_data(m: meshio.Mesh, expected: dict) -> None:
    assert set(m.point_data) == set(expected)
    for k, v in expected.items():
        np.testing.assert_array_equal(m.point_data[k], v, err_msg=k)


# ----------------------------------------------------------------------------- VTU

def test_surface_vtu_roundtrip_exact(tmp_path, grid_surface):
    pts, tri, normals, rng = grid_surface
    pd = {
        "normal": normals,
        "shape_error": rng.random(12) * 1e-3,
        "normal_error": rng.random(12).astype(np.float32),
        "face_id": np.arange(12, dtype=np.int32) % 3,
        "element": np.arange(12, dtype=np.int64),
    }
    cd = {"element": np.arange(len(tri)), "area": rng.random(len(tri))}
    path = tmp_path / "surface.vtu"
    write_surface_vtu(path, pts, tri, point_data=pd, cell_data=cd)

    m = meshio.read(path)
    np.testing.assert_array_equal(m.points, pts)
    assert [c.type for c in m.cells] == ["triangle"]
    np.testing.assert_array_equal(m.cells[0].data, tri)
    _compare_point_data(m, pd)
    assert m.point_data["normal_error"].dtype == np.float32
    assert m.point_data["face_id"].dtype == np.int32
    for k, v in cd.items():
        np.testing.assert_array_equal(m.cell_data[k][0], v)
    assert no_temp_files(tmp_path)


def test_surface_vtu_bool_point_data_stored_as_uint8(tmp_path, grid_surface):
    pts, tri, _, _ = grid_surface
    flag = np.arange(12) % 2 == 0
    write_surface_vtu(tmp_path / "s.vtu", pts, tri, point_data={"on_crease": flag})
    got = meshio.read(tmp_path / "s.vtu").point_data["on_crease"]
    assert got.dtype == np.uint8
    np.testing.assert_array_equal(got, flag.astype(np.uint8))


def test_mesh_vtu_mixed_blocks_and_field_data(tmp_path):
    # unit square split into a quad and two triangles
    nodes = np.array([[0, 0, 0], [0.5, 0, 0], [1, 0, 0], [0, 1, 0], [0.5, 1, 0], [1, 1, 0.1]],
                     dtype=float)
    quads = np.array([[0, 1, 4, 3]])
    tris = np.array([[1, 2, 5], [1, 5, 4]])
    normals = np.tile([0.0, 0.0, 1.0], (6, 1))
    pd = {"normal": normals, "distance": np.array([0, 1e-9, 2e-12, 0, 3.5e-7, 1.0])}
    cd = {"face_id": [np.array([7]), np.array([7, 8])],
          "quality": [np.array([1.0]), np.array([0.5, 0.25])]}
    fd = {"normal_source": "cad", "tolerance": 1e-7, "n_faces": np.array([2, 3])}
    path = tmp_path / "mesh.vtu"
    write_mesh_vtu(path, nodes, [("quad", quads), ("triangle", tris)],
                   point_data=pd, cell_data=cd, field_data=fd)

    m = meshio.read(path)
    np.testing.assert_array_equal(m.points, nodes)
    assert [c.type for c in m.cells] == ["quad", "triangle"]
    np.testing.assert_array_equal(m.cells[0].data, quads)
    np.testing.assert_array_equal(m.cells[1].data, tris)
    _compare_point_data(m, pd)
    for k, blocks in cd.items():
        assert len(m.cell_data[k]) == 2
        for got, exp in zip(m.cell_data[k], blocks):
            np.testing.assert_array_equal(got, exp)
    assert decode_field_string(m.field_data["normal_source"]) == "cad"
    np.testing.assert_array_equal(m.field_data["tolerance"], [1e-7])
    np.testing.assert_array_equal(m.field_data["n_faces"], [2, 3])
    assert no_temp_files(tmp_path)


def test_mesh_vtu_field_data_float_roundtrip_precision(tmp_path):
    vals = np.array([np.pi, 1 / 3, 1e-300, -2.5e300, 0.1 + 0.2])
    write_mesh_vtu(tmp_path / "m.vtu", np.eye(3), [("triangle", [[0, 1, 2]])],
                   field_data={"vals": vals, "label": "MWELR with planes µ"})
    m = meshio.read(tmp_path / "m.vtu")
    np.testing.assert_array_equal(m.field_data["vals"], vals)  # exact, not approx
    assert decode_field_string(m.field_data["label"]) == "MWELR with planes µ"


def test_mesh_vtu_readable_by_vtk(tmp_path):
    """What ParaView uses: the VTK XML reader sees cells, point data and field data."""
    vtk = pytest.importorskip("vtk")
    nodes = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0]], dtype=float)
    path = tmp_path / "mesh.vtu"
    write_mesh_vtu(path, nodes, [("quad", [[0, 1, 2, 3]]), ("triangle", [[1, 4, 2]])],
                   point_data={"normal": np.tile([0.0, 0, 1], (5, 1))},
                   cell_data={"face_id": [[3], [4]]},
                   field_data={"normal_source": "cad", "tol": 1e-6})
    r = vtk.vtkXMLUnstructuredGridReader()
    r.SetFileName(str(path))
    r.Update()
    g = r.GetOutput()
    assert (g.GetNumberOfPoints(), g.GetNumberOfCells()) == (5, 2)
    assert g.GetPointData().GetArray("normal").GetNumberOfComponents() == 3
    assert g.GetCellData().GetArray("face_id").GetNumberOfTuples() == 2
    src = g.GetFieldData().GetAbstractArray("normal_source")
    assert bytes(int(src.GetVariantValue(i).ToInt()) for i in range(src.GetNumberOfValues())) == b"cad"
    assert g.GetFieldData().GetArray("tol").GetValue(0) == 1e-6


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"points": np.zeros((4, 2))}, "points"),
        ({"points": np.full((4, 3), np.nan)}, "points"),
        ({"triangles": np.array([[0, 1, 2, 3]])}, "triangles"),
        ({"triangles": np.array([[0, 1, 4]])}, "triangles"),
        ({"triangles": np.array([[0.0, 1.0, 2.0]])}, "triangles"),
        ({"point_data": {"normal": np.zeros((3, 3))}}, "normal"),
        ({"point_data": {"shape_error": np.zeros((4, 3, 1))}}, "shape_error"),
        ({"point_data": {"label": np.array(["a"] * 4)}}, "label"),
        ({"cell_data": {"element": np.zeros(2)}}, "element"),
    ],
)
def test_surface_vtu_validation(tmp_path, kwargs, match):
    args = {"points": np.zeros((4, 3)), "triangles": np.array([[0, 1, 2]]),
            "point_data": None, "cell_data": None}
    args.update(kwargs)
    path = tmp_path / "bad.vtu"
    with pytest.raises(ValueError, match=match):
        write_surface_vtu(path, **args)
    assert not path.exists()
    assert no_temp_files(tmp_path)


@pytest.mark.parametrize(
    "blocks, cell_data, field_data, match",
    [
        ([("tetra", [[0, 1, 2, 3]])], None, None, "tetra"),
        ([("quad", [[0, 1, 2]])], None, None, r"blocks\[0\] \(quad\)"),
        ([], None, None, "blocks"),
        ([("triangle", [[0, 1, 2]])], {"face_id": np.array([1])}, None, "face_id"),
        ([("triangle", [[0, 1, 2]])], {"face_id": [np.array([1]), np.array([2])]}, None, "face_id"),
        ([("triangle", [[0, 1, 2]])], {"face_id": [np.array([1, 2])]}, None, "face_id"),
        ([("triangle", [[0, 1, 2]])], None, {"normal_source": ""}, "normal_source"),
        ([("triangle", [[0, 1, 2]])], None, {"obj": object()}, "obj"),
    ],
)
def test_mesh_vtu_validation(tmp_path, blocks, cell_data, field_data, match):
    path = tmp_path / "bad.vtu"
    with pytest.raises(ValueError, match=match):
        write_mesh_vtu(path, np.zeros((4, 3)), blocks, cell_data=cell_data,
                       field_data=field_data)
    assert not path.exists()


def test_vtu_failed_write_keeps_old_file(tmp_path, monkeypatch):
    path = tmp_path / "keep.vtu"
    path.write_text("previous")

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(vtu.meshio, "write", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        write_surface_vtu(path, np.eye(3), [[0, 1, 2]])
    assert path.read_text() == "previous"
    assert no_temp_files(tmp_path)


# ----------------------------------------------------------------------------- plots

def _section_series():
    """Fig. 49-like data: three elements on [0, 1], error zero at the nodes."""
    s = np.linspace(0, 1, 61)
    bump = np.abs(np.sin(3 * np.pi * s))
    return s, {
        "CAD": (s, 0.06 * bump),
        "MWE without planes": (s, 0.06 * bump * (1 + 4 * np.abs(s - 0.5))),
        "MWE with planes": (s, 0.08 * bump),
        "MWAAT with planes": (s, 0.07 * bump),
        "MWELR with planes": (s, 0.065 * bump),
    }


def test_plot_section_error_png(tmp_path):
    s, series = _section_series()
    path = tmp_path / "section.png"
    plot_section_error(path, series, element_boundaries=[0, 1 / 3, 2 / 3, 1],
                       title="cross-section A-A", polyhedral=(s, 0.35 * np.abs(np.sin(3 * np.pi * s))))
    assert png_size(path) == (1600, 1000)
    assert no_temp_files(tmp_path)


def test_plot_section_error_custom_size_and_unequal_series(tmp_path):
    path = tmp_path / "section_small.png"
    plot_section_error(path, {"a": ([0, 0.5, 1], [0, 1, 0]), "b": ([0, 1], [0, 0.5])},
                       figsize=(4, 3), dpi=100)
    assert png_size(path) == (400, 300)


def test_plot_section_error_rejects_mismatched_lengths(tmp_path):
    path = tmp_path / "bad.png"
    with pytest.raises(ValueError, match=r"'MWE with planes'.*61.*60"):
        plot_section_error(path, {"CAD": (np.zeros(3), np.zeros(3)),
                                  "MWE with planes": (np.zeros(61), np.zeros(60))})
    with pytest.raises(ValueError, match="polyhedral"):
        plot_section_error(path, {"CAD": (np.zeros(3), np.zeros(3))},
                           polyhedral=(np.zeros(3), np.zeros(4)))
    with pytest.raises(ValueError, match="series"):
        plot_section_error(path, {})
    assert not path.exists()
    assert no_temp_files(tmp_path)


def test_plot_error_histogram_png(tmp_path):
    rng = np.random.default_rng(0)
    errors = {"triangular": rng.exponential(0.01, 500), "quadrilateral": rng.exponential(0.02, 400)}
    for cumulative in (False, True):
        path = tmp_path / f"hist_{cumulative}.png"
        plot_error_histogram(path, errors, xlabel="radial error [%]", title="mesh 1",
                             cumulative=cumulative)
        assert png_size(path) == (1600, 1000)
    path = tmp_path / "hist_edges.png"
    plot_error_histogram(path, {"x": np.zeros(10)}, bins=[0, 0.5, 1], xlabel="e")  # constant data
    assert png_size(path) == (1600, 1000)


def test_plot_error_histogram_validation(tmp_path):
    path = tmp_path / "bad.png"
    with pytest.raises(ValueError, match="'tri'"):
        plot_error_histogram(path, {"tri": np.array([0.1, np.nan])}, xlabel="e")
    with pytest.raises(ValueError, match="'quad'"):
        plot_error_histogram(path, {"quad": np.zeros((3, 2))}, xlabel="e")
    with pytest.raises(ValueError, match="bins"):
        plot_error_histogram(path, {"quad": np.zeros(3)}, bins=[1, 0.5], xlabel="e")
    with pytest.raises(ValueError, match="bins"):
        plot_error_histogram(path, {"quad": np.zeros(3)}, bins=0, xlabel="e")
    assert not path.exists()


@pytest.mark.parametrize("kind", ["bar", "box"])
def test_plot_normal_sources_png(tmp_path, kind):
    rng = np.random.default_rng(2)
    angles = {m: rng.random(50) * k for m, k in
              [("MWE", 3.0), ("MWA", 2.0), ("MWSELR", 0.5), ("MWAAT", 1.5), ("MWRELR", 1.0)]}
    angles["CAD"] = np.zeros(48)  # different N is allowed
    path = tmp_path / f"normals_{kind}.png"
    plot_normal_sources(path, angles, title="sphere, triangular mesh", kind=kind)
    assert png_size(path) == (1600, 1000)


def test_plot_normal_sources_validation(tmp_path):
    path = tmp_path / "bad.png"
    with pytest.raises(ValueError, match="'MWE'.*degrees"):
        plot_normal_sources(path, {"MWE": np.array([10.0, 200.0])})
    with pytest.raises(ValueError, match="'MWA'"):
        plot_normal_sources(path, {"MWA": np.array([])})
    with pytest.raises(ValueError, match="kind"):
        plot_normal_sources(path, {"MWA": np.array([1.0])}, kind="pie")
    assert not path.exists()


def test_plot_arc_convergence_png(tmp_path):
    h = np.array([1.57, 0.78, 0.52, 0.39, 0.31])
    path = tmp_path / "conv.png"
    plot_arc_convergence(path, h, {"radial": 0.01 * h**4, "normal [°]": 2.0 * h**3})
    assert png_size(path) == (1600, 1000)
    plot_arc_convergence(tmp_path / "conv_noslope.png", h, {"radial": 0.01 * h**4}, slopes=False)
    assert png_size(tmp_path / "conv_noslope.png") == (1600, 1000)


def test_plot_arc_convergence_slope_in_legend(tmp_path, monkeypatch):
    """The legend carries the least-squares order (4.00 for err = c h^4)."""
    seen = {}
    real_save = plots._save

    def spy(fig, path):
        seen["labels"] = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
        real_save(fig, path)

    monkeypatch.setattr(plots, "_save", spy)
    h = np.array([1.0, 0.5, 0.25])
    plot_arc_convergence(tmp_path / "c.png", h, {"radial": 3 * h**4, "normal": h**3})
    assert seen["labels"] == ["radial (slope 4.00)", "normal (slope 3.00)"]


def test_plot_arc_convergence_validation(tmp_path):
    path = tmp_path / "bad.png"
    h = np.array([1.0, 0.5, 0.25])
    with pytest.raises(ValueError, match="'radial' has 2 values but h has 3"):
        plot_arc_convergence(path, h, {"radial": np.array([1.0, 0.1])})
    with pytest.raises(ValueError, match="'radial' must be positive"):
        plot_arc_convergence(path, h, {"radial": np.array([1.0, 0.0, 0.1])})
    with pytest.raises(ValueError, match="h must be positive"):
        plot_arc_convergence(path, -h, {"radial": np.ones(3)})
    with pytest.raises(ValueError, match="at least 2"):
        plot_arc_convergence(path, [1.0], {"radial": [1.0]})
    assert not path.exists()


def test_plot_failed_save_keeps_old_file(tmp_path, monkeypatch):
    path = tmp_path / "keep.png"
    path.write_bytes(b"previous")
    from matplotlib.figure import Figure

    def boom(self, *a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(Figure, "savefig", boom)
    with pytest.raises(RuntimeError, match="disk full"):
        plot_error_histogram(path, {"a": np.ones(3)}, xlabel="e")
    assert path.read_bytes() == b"previous"
    assert no_temp_files(tmp_path)
