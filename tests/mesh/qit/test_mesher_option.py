"""`--mesher qit` through the CLI and `mesh_cad` (reference: `qit_mesh` called directly on
the same file, and the mesh read back by meshio)."""

from pathlib import Path

import numpy as np

from cadbridge.cli import main
from cadbridge.iges import read_iges, write_iges
from cadbridge.mesh.generate import mesh_cad
from cadbridge.mesh.io import read_mesh
from cadbridge.mesh.qit.mesher import qit_mesh
from cadbridge.cad.model import Face
from cadbridge.nurbs.surface import NurbsSurface

HOLE = Path(__file__).resolve().parents[3] / "iges_samples" / "trimmed_hole.igs"


def test_mesh_command_qit_round_trip(tmp_path, capsys):
    out = tmp_path / "hole.msh"
    assert main(["mesh", str(HOLE), "--mesher", "qit", "--element", "tri", "--size", "5", "-o", str(out)]) == 0
    back = read_mesh(out)
    ref = qit_mesh(read_iges(HOLE), 5.0)
    assert len(back.nodes) == len(ref.nodes) and len(back.triangles) == len(ref.triangles)
    assert np.abs(np.sort(back.nodes, axis=0) - np.sort(ref.nodes, axis=0)).max() < 1e-9


def test_mesh_cad_dispatch_and_default():
    m = mesh_cad(HOLE, element="tri", size=5.0, mesher="qit")
    assert "node_face" in m.point_data and len(m.quads) == 0
    g = mesh_cad(HOLE, element="tri", size=5.0)  # gmsh stays the default
    assert "node_face" not in g.point_data


def test_mesher_qit_implies_triangles(tmp_path, capsys):
    """Reference: the same command with --element tri (the mesh read back by meshio)."""
    out, ref = tmp_path / "implied.msh", tmp_path / "explicit.msh"
    assert main(["mesh", str(HOLE), "--mesher", "qit", "--size", "5", "-o", str(out)]) == 0
    assert main(["mesh", str(HOLE), "--mesher", "qit", "--element", "tri", "--size", "5", "-o", str(ref)]) == 0
    back, want = read_mesh(out), read_mesh(ref)
    assert len(back.quads) == 0 and len(back.triangles) == len(want.triangles) > 0
    assert np.array_equal(back.nodes, want.nodes)


def test_qit_refuses_quads_and_names_a_bad_face(tmp_path, capsys):
    assert main(["mesh", str(HOLE), "--mesher", "qit", "--element", "quad", "--size", "5",
                 "-o", str(tmp_path / "x.msh")]) == 2
    err = capsys.readouterr().err
    assert "QIT makes triangles only" in err and len(err.strip().splitlines()) == 1
    # a flat triangle as a bilinear patch: the edge u = 0 collapsed to a point (Jacobian 0)
    cp = [[(0, 0, 0), (0, 0, 0)], [(50, 0, 0), (50, 50, 0)]]
    bad = tmp_path / "pole.igs"
    write_iges([Face(NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1], cp), de=1)], bad)
    code = main(["mesh", str(bad), "--mesher", "qit", "--element", "tri", "--size", "12", "-o", str(tmp_path / "y.msh")])
    err = capsys.readouterr().err
    assert code == 2 and "face 0 (DE 1" in err and "Jacobian" in err and "Traceback" not in err
    assert not (tmp_path / "y.msh").exists()


def test_shape_tolerance_with_qit_is_a_usage_error(tmp_path, capsys):
    code = main(["mesh", str(HOLE), "--mesher", "qit", "--element", "tri", "--shape-tolerance", "0.01",
                 "-o", str(tmp_path / "z.msh")])
    assert code == 2 and "--shape-tolerance refines with gmsh" in capsys.readouterr().err
