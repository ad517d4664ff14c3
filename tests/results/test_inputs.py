"""Result inputs of `cadbridge map` (issue 9): GiD mesh + results, a tool file + CSV, Gmsh
.msh cell data, integration points, vector fields, and the clear errors for fields that are
absent, of the wrong length or not finite. References: round trips through our own writers
(write_gid / write_gid_results / write_toolfile, meshio) and hand-computed averages; the
mapped result is compared with the analytic plane (tests/results/test_mapping.py)."""

from __future__ import annotations

import numpy as np
import pytest

from cadbridge.mesh.mesh import CellBlock, Mesh
from cadbridge.results import map_results
from cadbridge.results.fields import FieldError, read_results


def _strip():
    nodes = np.array([[0, 0, 0], [1, 0, 0], [3, 0, 0], [0, 1, 0], [1, 1, 0], [3, 1, 0]], float)
    return Mesh(nodes, [CellBlock("quad", np.array([[0, 1, 4, 3], [1, 2, 5, 4]]))])


def test_gid_mesh_with_res_beside_it(tmp_path):
    """GiD .msh + .res (our writers): the nodal scalar comes back per node, the vector as its
    magnitude or one component; the mapping of the x field on the plane gives the analytic
    band areas (reference: (b - a) x 3)."""
    from cadbridge.mesh.io import write_gid, write_gid_results

    from tests.results.test_mapping import plane_case

    model, mesh = plane_case()
    p = tmp_path / "die.post.msh"
    write_gid(mesh, p)
    n = mesh.n_nodes
    vec = np.column_stack([mesh.nodes[:, 0], np.zeros(n), np.zeros(n)])
    write_gid_results(tmp_path / "die.post.res", {"x": mesh.nodes[:, 0], "U": vec}, n_nodes=n)
    m2, f = read_results(p, "x")
    assert np.allclose(f.values, mesh.nodes[:, 0]) and f.source == "point data"
    _, fu = read_results(p, "U")
    assert np.allclose(fu.values, np.abs(mesh.nodes[:, 0])) and "magnitude" in fu.source
    _, f0 = read_results(p, "U[0]")
    assert np.allclose(f0.values, mesh.nodes[:, 0]) and "component 0" in f0.source
    c = map_results(m2, f.values, model).contour([2.0, 3.0])
    assert np.allclose(c.bands.area, [3.0, 3.0, 6.0], rtol=1e-9)


def test_tool_file_with_csv(tmp_path):
    """A cadbridge tool file holds no results: it needs --values (clear error); with a CSV of
    node ids and values (any order) the values land on the right nodes."""
    from cadbridge.io.toolfile import ToolData, write_toolfile

    mesh = _strip()
    tool = ToolData(name="strip", units="MM", nodes=mesh.nodes, normals=np.tile([0.0, 0, 1], (6, 1)),
                    quads=mesh.cells[0].data)
    path = tmp_path / "strip.nagata"
    write_toolfile(tool, path)
    with pytest.raises(FieldError, match="--values"):
        read_results(path, "wear")
    csvp = tmp_path / "wear.csv"
    order = [5, 0, 3, 1, 4, 2]
    csvp.write_text("node,wear\n" + "".join(f"{i + 1},{10.0 * i}\n" for i in order))
    _, f = read_results(path, "wear", values=csvp)
    assert np.allclose(f.values, 10.0 * np.arange(6))
    csvp.write_text("node,wear\n1,0\n2,1\n")
    with pytest.raises(FieldError, match="no value for 4 nodes"):
        read_results(path, "wear", values=csvp)


def test_cell_data_with_integration_points(tmp_path):
    """VTU cell data with 4 integration-point values per element: averaged per element
    (equal weights), then area-weighted to the nodes; reference: hand computation
    (element means 1 and 4, node 1 shared: (1 x 1 + 2 x 4) / 3 = 3)."""
    import meshio

    mesh = _strip()
    ip = np.array([[0.0, 1.0, 2.0, 1.0], [4.0, 4.0, 3.0, 5.0]])
    p = tmp_path / "ip.vtu"
    meshio.write(p, meshio.Mesh(mesh.nodes, [("quad", mesh.cells[0].data)], cell_data={"s": [ip]}))
    _, f = read_results(p, "s")
    assert np.allclose(f.values, [1, 3, 4, 1, 3, 4])
    assert "4 integration-point values per element averaged" in f.source


def test_bad_fields(tmp_path):
    """Not finite, of the wrong length, absent: one clear error each, naming the field and the
    first bad nodes."""
    import meshio

    mesh = _strip()
    p = tmp_path / "bad.vtu"
    meshio.write(p, meshio.Mesh(mesh.nodes, [("quad", mesh.cells[0].data)],
                                point_data={"p": np.array([1.0, np.nan, 2, 3, np.inf, 5])}))
    with pytest.raises(FieldError, match=r"'p' is not finite at 2 nodes \(first: \[1, 4\]"):
        read_results(p, "p")
    with pytest.raises(FieldError, match="not found; available: p \\(point\\)"):
        read_results(p, "q")
    csvp = tmp_path / "v.csv"
    csvp.write_text("p\n1\n2\n3\n4\n")
    with pytest.raises(FieldError, match="4 values for 6 nodes"):
        read_results(p, "p", values=csvp)
