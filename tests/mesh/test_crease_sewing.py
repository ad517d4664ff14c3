"""Crease lines embedded into faces keep the faces sewn to their neighbours.

The production die's quad failure (issue 8/13, docs/production_die.md "NURBS quad"): its 14
crease lines each run across a small face from corner to corner, ending on vertices the face
shares with the binder. `mesh_cad` fragmented only the faces holding the creases; OCC's
general fuse then rebuilt their corner vertices (the crease's end lies on them within
tolerance) and the edges ending there, and the binder, left out, kept the old ones: 28
doubled corners and 112 edges no longer shared. Both copies of an edge were meshed, the node
merge joined them pairwise in tri, but in quad (all-quad subdivision: 0.006 mm steps on
0.02 mm edges, below the merge tolerance) it joined whole chains across the two copies and
left 25 non-manifold edges.

The reproduction here is that situation in three faces: the rational bicubic of
``iges_samples/multiple_knots.igs`` (a C0 knot line at u = 2) and two strips on its v = 1
edge, split at u = 2, so the crease ends on a vertex shared by three faces.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gmsh")
pytest.importorskip("OCP")

SAMPLES = Path(__file__).parents[2] / "iges_samples"


@pytest.fixture(scope="module")
def creased_sheet(tmp_path_factory) -> Path:
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeFace
    from OCP.BRepPrimAPI import BRepPrimAPI_MakePrism
    from OCP.gp import gp_Vec

    from cadbridge.ushape import export_iges

    spec = importlib.util.spec_from_file_location("make_samples", SAMPLES / "make_samples.py")
    ms = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ms)
    s = ms.multiple_knots_surface()
    iso = s.VIso(1.0)  # the v = 1 edge: the crease u = 2 ends on it
    faces = {
        "CREASED": BRepBuilderAPI_MakeFace(s, 1e-7).Face(),
        "NEXTA": BRepPrimAPI_MakePrism(BRepBuilderAPI_MakeEdge(iso, 0.0, 2.0).Edge(), gp_Vec(0, 12, 0)).Shape(),
        "NEXTB": BRepPrimAPI_MakePrism(BRepBuilderAPI_MakeEdge(iso, 2.0, 3.0).Edge(), gp_Vec(0, 12, 0)).Shape(),
    }
    path = tmp_path_factory.mktemp("crease_sewing") / "creased_sheet.igs"
    export_iges(faces, path, "nurbs")
    return path


def _creases(path: Path):
    from cadbridge.heal.creases import crease_lines
    from cadbridge.iges import read_iges

    lines = crease_lines(read_iges(path))
    assert len(lines) == 1 and lines[0].direction == "u" and abs(lines[0].knot - 2.0) < 1e-12
    return [c.curve for c in lines]


def _topology(g) -> tuple[int, int]:
    """(pairs of gmsh points closer than 1e-6, curves bounding exactly one surface)."""
    from scipy.spatial import cKDTree

    pts = [t for _, t in g.model.getEntities(0)]
    xyz = np.array([g.model.getValue(0, p, []) for p in pts], dtype=float).reshape(-1, 3)
    free = [t for _, t in g.model.getEntities(1) if len(g.model.getAdjacencies(1, t)[0]) == 1]
    return len(cKDTree(xyz).query_pairs(1e-6)), len(free)


def test_fragment_keeps_the_neighbours_sewn(creased_sheet):
    # reference: the sewn import itself (before any crease is embedded): no doubled point,
    # and its free curves are the sheet's outer boundary; the fragment may add curves (the
    # crease) but no doubled point and no free curve
    from cadbridge.mesh import generate as G
    from cadbridge.mesh.gmsh import session as S

    curves = _creases(creased_sheet)
    with S.GmshSession(False) as sess:
        g = sess.gmsh
        S.apply_options(sess, {"Geometry.OCCSewFaces": 1, "Geometry.Tolerance": 1e-4, "Geometry.OCCImportLabels": 0})
        g.model.occ.importShapes(str(creased_sheet))
        g.model.occ.synchronize()
        doubled0, free0 = _topology(g)
        G._embed_curves(g, curves, creased_sheet)
        doubled, free = _topology(g)
        n_surf = len(g.model.getEntities(2))
    assert doubled0 == 0 and free0 == 8  # 3 sewn faces: 8 outer curves (the v = 1 edge in 2)
    assert n_surf == 4  # the creased face split in two along u = 2
    assert doubled == 0, f"{doubled} points doubled by the fragment"
    assert free == free0, f"{free - free0} curves no longer shared after the fragment"


@pytest.mark.parametrize("element", ["tri", "quad"])
def test_mesh_is_conformal_without_merging(creased_sheet, element):
    # reference: a conformal mesh of the sewn sheet needs no node merge (every shared curve
    # meshed once); its boundary is the sheet's outer boundary, whose length OCC gives
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.mesh.topology import boundary_edges, non_manifold_edges

    mesh = mesh_cad(creased_sheet, element=element, curvature_elements=12, embed_curves=_creases(creased_sheet))
    assert not any("merged" in n for n in mesh.notes), mesh.notes
    assert len(non_manifold_edges(mesh)) == 0
    if element == "quad":
        assert [b.type for b in mesh.cells] == ["quad"]
    be = boundary_edges(mesh)
    length = float(np.linalg.norm(mesh.nodes[be[:, 1]] - mesh.nodes[be[:, 0]], axis=1).sum())
    assert abs(length - _outer_perimeter(creased_sheet)) < 1e-2 * length


def _outer_perimeter(path: Path) -> float:
    """Length of the free boundary of the file's faces sewn by OCC (BRepBuilderAPI_Sewing,
    ShapeAnalysis_FreeBounds), mm."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Sewing
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps
    from OCP.ShapeAnalysis import ShapeAnalysis_FreeBounds

    from cadbridge.verify.reference import occ_read_shape

    sew = BRepBuilderAPI_Sewing(1e-4)
    sew.Add(occ_read_shape(path))
    sew.Perform()
    wires = ShapeAnalysis_FreeBounds(sew.SewedShape(), 1e-4, False, False).GetClosedWires()
    props = GProp_GProps()
    BRepGProp.LinearProperties_s(wires, props)
    return float(props.Mass())
