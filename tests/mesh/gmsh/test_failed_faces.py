"""Surfaces gmsh fails on (an error, not only "no elements"), meshed by cadbridge on gmsh's
boundary nodes (`cadbridge.mesh.gmsh.empty_faces.generate_surfaces` + `fill_empty_faces`).

The reproduction: faces of the production die in analytic mode, written alone by OCC's IGES
writer into a temporary file: the binder BND00963 (a 120 surface of revolution, R 5000, 15
holes) with its neighbours. gmsh's periodic mesher stops on the binder with "Impossible to
mesh periodic surface" (before: `mesh_cad` raised, after two attempts); now the binder is
meshed in its (u, v) on gmsh's 1D nodes and the rest by gmsh.

References (OpenCASCADE, independent of gmsh's and cadbridge's meshing):
* the faces' total area (BRepGProp): a crack or a missing face lowers the mesh's area, an
  overlap raises it;
* the free boundary of the faces sewn by OCC (BRepBuilderAPI_Sewing, gmsh's tolerance):
  a mesh that is not conformal along a shared curve has boundary edges there, so the mesh's
  boundary is longer than OCC's free edges;
* the binder's surface (GeomAPI_ProjectPointOnSurf): the filled nodes lie on it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.helpers import occ as OCC

DIE = Path(__file__).parents[3] / "iges_samples" / "production_die_analytic.igs"
BINDER = 962  # 0-based root (face) index of BND00963 in the die file
NEIGHBOURS = list(range(1022, 1058))  # the draw beads and their land radii (36 faces): with them gmsh fails


def _faces(indices):
    from OCP.IGESControl import IGESControl_Reader
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    r = IGESControl_Reader()
    r.ReadFile(str(DIE))
    out = {}
    for k in indices:
        r.ClearShapes()
        assert r.TransferOneRoot(k + 1)
        ex = TopExp_Explorer(r.OneShape(), TopAbs_FACE)
        out[f"F{k:05d}"] = TopoDS.Face_s(ex.Current())
    return out


def _built_faces(indices):
    """The same faces where the die file is not written (a fresh checkout: it is generated on
    request and git-ignored): built as `make_samples.py --production` builds them (~20 s),
    in the order the die file holds them."""
    import importlib.util

    pytest.importorskip("cadquery")
    spec = importlib.util.spec_from_file_location("make_samples", DIE.parent / "make_samples.py")
    make_samples = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(make_samples)
    built = make_samples.production_die_faces()
    names = list(built)
    assert names[BINDER] == "BND00963"
    return {f"F{k:05d}": built[names[k]] for k in indices}


@pytest.fixture(scope="module")
def repro(tmp_path_factory):
    pytest.importorskip("OCP")
    pytest.importorskip("gmsh")
    from cadbridge.ushape.geometry import export_iges

    faces = _faces([BINDER] + NEIGHBOURS) if DIE.is_file() else _built_faces([BINDER] + NEIGHBOURS)
    path = tmp_path_factory.mktemp("failed") / "binder.igs"
    export_iges(faces, path, "analytic")
    return path, faces


def _occ_area_and_free_length(faces):
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Sewing
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    area = 0.0
    sew = BRepBuilderAPI_Sewing(1e-4)
    for f in faces.values():
        area += OCC.area(f)
        sew.Add(f)
    sew.Perform()
    free = 0.0
    for i in range(1, sew.NbFreeEdges() + 1):
        p = GProp_GProps()
        BRepGProp.LinearProperties_s(sew.FreeEdge(i), p)
        free += p.Mass()
    return area, free


def test_surface_gmsh_fails_on_is_meshed_conformally_on_its_surface(repro):
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.mesh.topology import boundary_edges, edge_table

    path, faces = repro
    mesh = mesh_cad(path, element="tri", curvature_elements=12)
    failed = [n for n in mesh.notes if "gmsh failed (Impossible to mesh periodic surface" in n]
    assert len(failed) == 1, mesh.notes  # the binder, meshed by cadbridge
    assert "cusp strip" not in failed[0]  # no strip cut off a face that has none: no crack
    x = mesh.nodes
    tri = mesh.triangles
    table = edge_table(mesh)
    assert table.counts.max() <= 2  # manifold
    area_ref, free_ref = _occ_area_and_free_length(faces)
    area = 0.5 * np.linalg.norm(np.cross(x[tri[:, 1]] - x[tri[:, 0]], x[tri[:, 2]] - x[tri[:, 0]]), axis=1).sum()
    # chords: the elements lie inside the curved faces (less area) and the polygons inscribed
    # in the holes cut less than the holes (more area: the pocket's coarse R 110 corners give
    # +0.16 % on the binder); an uncovered or doubly covered region of 0.5 % fails
    assert 0.995 * area_ref < area < 1.005 * area_ref
    b = boundary_edges(mesh, table)
    blen = np.linalg.norm(x[b[:, 1]] - x[b[:, 0]], axis=1).sum()
    # chords are shorter than the free curves; a crack along a shared curve would add its
    # length twice
    assert 0.99 * free_ref < blen <= free_ref * (1 + 1e-9)
    # the binder's own nodes lie on OCC's surface of it
    from OCP.BRep import BRep_Tool

    ent = mesh.cell_data["element_entity"]
    binder_tag = int(np.bincount(ent).argmax())  # the binder has most of the elements
    from cadbridge.mesh.mesh import CellBlock, Mesh

    own = tri[ent[: len(tri)] == binder_tag]
    rim = np.unique(boundary_edges(Mesh(x, [CellBlock("triangle", own)])))
    inner = np.setdiff1d(np.unique(own), rim)
    surf = BRep_Tool.Surface_s(faces[f"F{BINDER:05d}"])

    def dist(ids):
        pick = ids[:: max(1, len(ids) // 300)]
        return max(OCC.surface_distance(surf, x[i]) for i in pick)

    assert dist(inner) < 1e-8  # S(u, v): on the surface
    # gmsh's 1D nodes on the trim curves: within the file's trim tolerance (BND00963's delta,
    # its 2D/3D trim curves' disagreement, is 4.1e-5 mm)
    assert dist(rim) < 1e-4


@pytest.mark.slow
def test_without_the_fallback_gmsh_stops_on_the_binder(repro, monkeypatch):
    # the failure the fallback removes: gmsh's throwing generate, as before
    from cadbridge.mesh.gmsh import empty_faces
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.mesh.mesh import MeshError

    monkeypatch.setattr(empty_faces, "generate_surfaces", lambda g, s: (g.model.mesh.generate(2), {})[1])
    with pytest.raises(MeshError, match="Impossible to mesh periodic surface"):
        mesh_cad(repro[0], element="tri", curvature_elements=12)
