"""Mesh I/O round trips (write -> read) for every supported format, GiD mesh/results, and
error handling.

References: the written mesh itself (round trip), with exactness per format's precision:
gmsh MSH 4.1 (binary and ASCII %.17g), VTK, VTU, Abaqus (%.16e), OBJ (repr), GiD (%.17g)
keep doubles bit-exactly; Nastran large-field GRID* keeps 12 significant digits; STL is
float32. gmsh itself re-reads our MSH files (independent reader).
"""

import os
import warnings

import numpy as np
import pytest

from cadbridge.mesh import CellBlock, Mesh, MeshError, MeshWarning, read_mesh, write_mesh
from cadbridge.mesh.io import read_gid_results, write_gid_results


def mixed_mesh() -> Mesh:
    """Curved mixed mesh: 3 quads, then two triangle blocks; awkward coordinates."""
    rng = np.random.default_rng(1)
    nx, ny = 3, 2
    x, y = np.meshgrid(np.arange(nx + 1) * 0.1, np.arange(ny + 1) / 3, indexing="ij")
    nodes = np.column_stack([x.ravel(), y.ravel(), np.sin(x.ravel()) + 1e-3 * rng.random(x.size)])
    nodes[0] = [np.pi, -1e-300, 1.0 / 3.0]
    idx = lambda i, j: i * (ny + 1) + j  # noqa: E731
    I, J = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"))
    q = np.column_stack([idx(I, J), idx(I + 1, J), idx(I + 1, J + 1), idx(I, J + 1)])
    return Mesh(nodes, [("quad", q[:3]), ("triangle", q[3:, :3]), ("triangle", q[3:, [0, 2, 3]])], name="demo")


def same_elements(a: Mesh, b: Mesh) -> bool:
    """Same global element sequence (types + connectivity); blocks may be merged."""
    return np.array_equal(a.padded(), b.padded())


EXACT = [("m.msh", {}), ("m.msh", {"binary": False}), ("m.vtk", {}), ("m.vtk", {"binary": False}),
         ("m.vtu", {}), ("m.inp", {}), ("m.obj", {}), ("m.post.msh", {})]


@pytest.mark.parametrize("name,kw", EXACT)
def test_round_trip_bit_exact(tmp_path, name, kw):
    m = mixed_mesh()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MeshWarning)  # formats without data say so
        write_mesh(m, tmp_path / name, **kw)
    r = read_mesh(tmp_path / name)
    assert np.array_equal(r.nodes, m.nodes)  # bit-exact doubles
    assert same_elements(r, m)
    assert [p for p in os.listdir(tmp_path) if p.endswith(".tmp")] == []  # atomic: no leftovers


def test_round_trip_nastran_12_digits(tmp_path):
    m = mixed_mesh()
    write_mesh(m, tmp_path / "m.bdf")
    r = read_mesh(tmp_path / "m.bdf")
    assert same_elements(r, m)
    np.testing.assert_allclose(r.nodes, m.nodes, rtol=1e-11, atol=1e-12)


def test_round_trip_stl_float32_and_quads_split(tmp_path):
    m = mixed_mesh()
    with pytest.warns(MeshWarning, match="3 quads split in two"):
        write_mesh(m, tmp_path / "m.stl")
    r = read_mesh(tmp_path / "m.stl")
    assert len(r.cells) == 1 and r.cells[0].type == "triangle" and r.n_elements == 3 * 2 + 6
    # STL keeps only float32 triangle corners (meshio merges equal points): compare the set
    # of triangles by their coordinates
    tri_ref = np.concatenate([m.quads[:, [0, 1, 2]], m.quads[:, [0, 2, 3]], m.triangles])
    a = np.sort(m.nodes[tri_ref].astype(np.float32).reshape(len(tri_ref), -1), axis=0)
    b = np.sort(r.nodes[r.triangles].reshape(r.n_elements, -1), axis=0)
    np.testing.assert_allclose(b, a, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(np.sort(r.nodes, axis=0), np.sort(m.nodes.astype(np.float32).astype(float), axis=0), rtol=0)


@pytest.mark.parametrize("name,kw", [("m.msh", {}), ("m.msh", {"binary": False}), ("m.vtu", {}), ("m.vtk", {})])
def test_round_trip_point_and_cell_data(tmp_path, name, kw):
    m = mixed_mesh()
    n, e = m.n_nodes, m.n_elements
    rng = np.random.default_rng(2)
    pd = {"err": rng.random(n), "normal": rng.normal(size=(n, 3))}
    cd = {"quality": rng.random(e), "vec": rng.normal(size=(e, 3))}
    write_mesh(m, tmp_path / name, point_data=pd, cell_data=cd, **kw)
    r = read_mesh(tmp_path / name)
    for k, v in pd.items():
        assert np.array_equal(np.asarray(r.point_data[k], float).reshape(v.shape), v), k
    for k, v in cd.items():
        assert np.array_equal(np.asarray(r.cell_data[k], float).reshape(v.shape), v), k


@pytest.mark.parametrize("binary", [True, False])
def test_gmsh_itself_reads_our_msh(tmp_path, binary):
    """Independent reader: gmsh opens the file and sees the same nodes and elements."""
    gmsh = pytest.importorskip("gmsh")
    m = mixed_mesh()
    write_mesh(m, tmp_path / "g.msh", point_data={"s": np.arange(m.n_nodes, dtype=float)}, binary=binary)
    gmsh.initialize(readConfigFiles=False, interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.open(str(tmp_path / "g.msh"))
        tags, xyz, _ = gmsh.model.mesh.getNodes()
        order = np.argsort(tags)
        assert np.array_equal(np.asarray(xyz).reshape(-1, 3)[order], m.nodes)
        conn = {}
        for _, s in gmsh.model.getEntities(2):
            for et, etags, en in zip(*gmsh.model.mesh.getElements(2, s)):
                k = {2: 3, 3: 4}[et]
                for t, row in zip(etags, np.asarray(en).reshape(-1, k)):
                    conn[int(t)] = (row - 1).tolist()
        assert [conn[i + 1] for i in range(m.n_elements)] == [
            r[r >= 0].tolist() for r in m.padded()
        ]
    finally:
        gmsh.finalize()


def test_gid_mesh_and_results_round_trip(tmp_path):
    m = mixed_mesh()
    n = m.n_nodes
    normals = np.random.default_rng(3).normal(size=(n, 3))
    err = np.linspace(0, 1, n)
    err[4] = np.nan  # omitted in the file -> NaN on read
    write_mesh(m, tmp_path / "die.post.msh", point_data={"normals": normals, "error": err})
    text = (tmp_path / "die.post.msh").read_text()
    assert text.startswith('MESH "demo-quad-0" dimension 3 ElemType Quadrilateral Nnode 4\nCoordinates\n')
    assert text.count("MESH ") == 3 and 'ElemType Triangle Nnode 3' in text
    r = read_mesh(tmp_path / "die.post.msh")
    assert np.array_equal(r.nodes, m.nodes) and r.name == "demo"
    assert [b.type for b in r.cells] == ["quad", "triangle", "triangle"] and same_elements(r, m)
    res_text = (tmp_path / "die.post.res").read_text()
    assert res_text.startswith("GiD Post Results File 1.0\n")
    assert 'Result "normals" "cadbridge" 1 Vector OnNodes' in res_text
    assert 'Result "error" "cadbridge" 1 Scalar OnNodes' in res_text
    res = read_gid_results(tmp_path / "die.post.res", n_nodes=n)
    assert np.array_equal(res["normals"], normals)
    assert np.array_equal(res["error"], err, equal_nan=True)


def test_gid_reader_handles_foreign_ids_material_and_plain_msh(tmp_path):
    # hand-written GiD file: non-consecutive node ids, material column, comments, 2 blocks
    txt = """# written by hand
MESH "plate" dimension 3 ElemType Quadrilateral Nnode 4
Coordinates
  10 0 0 0
  20 1 0 0
  30 1 1 0
  40 0 1 0
  50 2 0 0
End Coordinates
Elements
  1 10 20 30 40 7
End Elements
MESH "plate" dimension 3 ElemType Triangle Nnode 3
Coordinates
End Coordinates
Elements
  2 20 50 30 7
End Elements
MESH "edges" dimension 3 ElemType Linear Nnode 2
Coordinates
End Coordinates
Elements
  3 10 20
End Elements
"""
    (tmp_path / "hand.msh").write_text(txt)
    with pytest.warns(MeshWarning, match="dropped non-surface GiD elements 1 linear"):
        r = read_mesh(tmp_path / "hand.msh")  # .msh sniffed as GiD (starts with MESH)
    assert r.quads.tolist() == [[0, 1, 2, 3]] and r.triangles.tolist() == [[1, 4, 2]]
    assert r.point_data["gid:node_id"].tolist() == [10, 20, 30, 40, 50]


def test_meshio_reduction_and_dropping(tmp_path):
    import meshio

    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.5, 0, 0], [0.5, 0.5, 0], [0, 0.5, 0], [0, 0, 1]], float)
    mm = meshio.Mesh(pts, [("triangle6", np.array([[0, 1, 2, 3, 4, 5]])), ("line", np.array([[0, 1]])),
                           ("tetra", np.array([[0, 1, 2, 6]]))])
    mm.write(tmp_path / "ho.vtu")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        r = read_mesh(tmp_path / "ho.vtu")
    msgs = " ".join(str(x.message) for x in w)
    assert "1 line" in msgs and "1 tetra" in msgs and "1 triangle6" in msgs
    assert r.triangles.tolist() == [[0, 1, 2]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", MeshWarning)
        r2 = read_mesh(tmp_path / "ho.vtu", remove_unused=True)
    assert r2.n_nodes == 3 and np.array_equal(r2.nodes, pts[:3])


def test_errors_name_the_file(tmp_path):
    m = mixed_mesh()
    with pytest.raises(MeshError, match=r"x\.xyz.*cannot tell the mesh format"):
        write_mesh(m, tmp_path / "x.xyz")
    with pytest.raises(MeshError, match=r"nope\.vtu: no such file"):
        read_mesh(tmp_path / "nope.vtu")
    (tmp_path / "junk.vtu").write_text("this is not xml")
    with pytest.raises(MeshError, match=r"junk\.vtu: cannot read as vtu"):
        read_mesh(tmp_path / "junk.vtu")
    (tmp_path / "junk.msh").write_text("$MeshFormat\ngarbage\n")
    with pytest.raises(MeshError, match=r"junk\.msh: cannot read as gmsh"):
        read_mesh(tmp_path / "junk.msh")
    with pytest.raises(MeshError, match="not a GiD results file"):
        read_gid_results(tmp_path / "junk.msh")
    with pytest.raises(MeshError, match=r"result 'v' has shape \(3, 5\)"):
        write_gid_results(tmp_path / "r.res", {"v": np.zeros((3, 5))})


def test_failed_write_leaves_old_file_intact(tmp_path):
    m = mixed_mesh()
    target = tmp_path / "keep.msh"
    write_mesh(m, target)
    before = target.read_bytes()
    with pytest.raises(MeshError):
        write_mesh(m, target, point_data={"bad": np.zeros((m.n_nodes, 5))})  # 5 components
    assert target.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["keep.msh"]
