"""A crease line that misses a face corner by less than the node-merge tolerance fuses with
that corner (`cadbridge.mesh.generate._embed_curves`, ``snap``: OCC's fuzzy fuse).

The production die's crease 130 (docs/production_die.md, "NURBS quad") ends 0.006 mm from
the corner its face shares with the binder: OCC's fuse split the corner's edge at the
crease end, a 0.006 mm sliver edge below the merge tolerance (7.25e-3 mm), and the node
merge collapsed it into 3 non-manifold edges. Reproduction: the rational bicubic of
``iges_samples/multiple_knots.igs`` (C0 knot line u = 2, whose ends are corners) and two
strips on its v = 1 edge split at u = 2 (tests/test_crease_fragment_sewing.py), with the
line u = 2 - 0.00015 embedded: it lies on the face and ends ~0.005 mm (OCC's evaluation)
from the corners at u = 2, as the die's crease does.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("gmsh")
pytest.importorskip("OCP")

SAMPLES = Path(__file__).parents[1] / "iges_samples"
LINE = 2.0 - 0.00015  # the embedded line u = LINE; the corners (and the crease) at u = 2


@pytest.fixture(scope="module")
def sheet(tmp_path_factory):
    """(IGES path, 3D miss of the line's ends against the corners, (2,) mm: OCC's evaluation)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeEdge, BRepBuilderAPI_MakeFace
    from OCP.BRepPrimAPI import BRepPrimAPI_MakePrism
    from OCP.gp import gp_Vec

    from cadbridge.ushape import export_iges

    spec = importlib.util.spec_from_file_location("make_samples", SAMPLES / "make_samples.py")
    ms = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ms)
    s = ms.multiple_knots_surface()
    iso = s.VIso(1.0)
    faces = {
        "CREASED": BRepBuilderAPI_MakeFace(s, 1e-7).Face(),
        "NEXTA": BRepPrimAPI_MakePrism(BRepBuilderAPI_MakeEdge(iso, 0.0, 2.0).Edge(), gp_Vec(0, 12, 0)).Shape(),
        "NEXTB": BRepPrimAPI_MakePrism(BRepBuilderAPI_MakeEdge(iso, 2.0, 3.0).Edge(), gp_Vec(0, 12, 0)).Shape(),
    }
    path = tmp_path_factory.mktemp("crease_snap") / "crease_off_corner.igs"
    export_iges(faces, path, "nurbs")
    return path, np.array([s.Value(2.0, v).Distance(s.Value(LINE, v)) for v in (0.0, 1.0)])


def _line(path: Path):
    """The line u = LINE of the creased face (`isocurve` of the surface cadbridge reads)."""
    from cadbridge.creases import crease_lines
    from cadbridge.iges import read_iges
    from cadbridge.nurbs.ops import isocurve

    model = read_iges(path)
    face = [c.face for c in crease_lines(model) if c.direction == "u" and abs(c.knot - 2.0) < 1e-12]
    assert len(face) == 1
    return [isocurve(model.faces[face[0]].surface, "u", LINE)]


def _shortest_curve(path: Path, snap: float) -> tuple[float, int]:
    """(shortest gmsh curve after the fragment, mm (OCC length), number of surfaces)."""
    from cadbridge.mesh import generate as G

    with G.GmshSession(False) as sess:
        g = sess.gmsh
        G._apply(sess, {"Geometry.OCCSewFaces": 1, "Geometry.Tolerance": 1e-4, "Geometry.OCCImportLabels": 0})
        g.model.occ.importShapes(str(path))
        g.model.occ.synchronize()
        G._embed_curves(g, _line(path), path, snap=snap)
        lengths = [g.model.occ.getMass(1, t) for _, t in g.model.getEntities(1)]
        return min(lengths), len(g.model.getEntities(2))


def test_crease_end_snapped_onto_the_corner(sheet):
    # reference: OCC's points of the corners on the surface, ~0.005 mm from the line's ends;
    # without the snap the fuse leaves edges that short, with it no edge below 1 mm
    path, miss = sheet
    assert np.all((3e-3 < miss) & (miss < 7e-3)), miss
    short, _ = _shortest_curve(path, snap=0.0)
    assert short < 2 * miss.max()  # the sliver (the situation of the die)
    short, n_surf = _shortest_curve(path, snap=0.01)
    assert n_surf == 4  # the creased face split in two along the line
    assert short > 1.0, f"a {short:.3g} mm edge left at the crease end"


def test_quad_mesh_manifold_at_the_snapped_end(sheet):
    # reference: a sewn sheet's quad mesh has no non-manifold edge; at size 100 the merge
    # tolerance (1e-4 x size = 0.01 mm) exceeds the ~0.005 mm misses, as on the die
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.mesh.topology import non_manifold_edges

    path, _ = sheet
    mesh = mesh_cad(path, element="quad", size=100.0, curvature_elements=12, embed_curves=_line(path))
    assert [b.type for b in mesh.cells] == ["quad"]
    assert len(non_manifold_edges(mesh)) == 0
