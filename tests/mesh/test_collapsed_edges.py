"""gmsh meshes faces with a collapsed edge (a cone apex, a sphere pole) whole.

gmsh's OCC healing (``Geometry.OCCSewFaces``, ``healShapes``) removes every degenerated edge
from the face loops; the loop of a cone or a sphere whose apex or pole lies inside the face then
no longer closes in (u, v) ("The 1D mesh seems not to be forming a closed loop", the cone),
or the face is meshed as slivers (the revolved profile: 9 nodes, strips left open).
`mesh_cad` imports such files unsewn (`cadbridge.mesh.generate._unsew_collapsed`).

Reference: analytic geometry of the samples (iges_samples/README.md): every node on the
exact cone / sphere, the mesh one sheet whose only boundary is the base circle (the seam
and the apex are interior), one node at the apex or pole.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cadbridge.mesh.generate import mesh_cad
from cadbridge.mesh.topology import boundary_edges, non_manifold_edges

SAMPLES = Path(__file__).parents[2] / "iges_samples"
TAN30 = math.tan(math.radians(30.0))


def _cone_gap(x: np.ndarray) -> np.ndarray:
    """Distance-like residual of points (N, 3) from the cone of cone_apex.igs (apex (0, 0, 20),
    half angle 30 deg about -z): radius minus (20 - z) tan 30."""
    return np.hypot(x[:, 0], x[:, 1]) - (20.0 - x[:, 2]) * TAN30


CASES = [
    # file, singular point, residual from the exact surface, z of the free boundary
    ("cone_apex.igs", (0.0, 0.0, 20.0), _cone_gap, 0.0),
    ("hemisphere_pole.igs", (0.0, 0.0, 10.0), lambda x: np.linalg.norm(x, axis=1) - 10.0, 0.0),
]


@pytest.mark.parametrize("element, size", [("tri", None), ("quad", None), ("quad", 1.4995068222783021)])
@pytest.mark.parametrize("name, apex, gap, z_free", CASES, ids=[c[0] for c in CASES])
def test_face_with_collapsed_edge_meshes_whole(name, apex, gap, z_free, element, size) -> None:
    """(quads at size 1.4995, convert's default for hemisphere_pole: gmsh leaves a quad [a, p, p,
    b] at the pole, which `_collect` makes the triangle [a, p, b]; it raised "repeats a node")"""
    mesh = mesh_cad(SAMPLES / name, element=element, size=size)
    x = mesh.nodes
    assert np.abs(gap(x)).max() < 1e-6  # every node on the exact surface
    assert np.sum(np.linalg.norm(x - np.array(apex), axis=1) < 1e-9) == 1  # one node at the apex / pole
    b = np.asarray(boundary_edges(mesh))
    assert len(b) and np.abs(x[b.ravel(), 2] - z_free).max() < 1e-9  # the base circle only: seam closed
    assert len(non_manifold_edges(mesh).edges) == 0
    # the whole face is covered: the mesh area is the exact area (flat facets: slightly less)
    p = x[np.concatenate([c.data[:, [0, k, k + 1]] for c in mesh.cells for k in range(1, c.data.shape[1] - 1)])]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum()
    exact = math.pi * 20.0 * TAN30 * 20.0 / math.cos(math.radians(30.0)) if name.startswith("cone") else 2 * math.pi * 100.0
    assert 0.95 * exact < area <= exact * (1 + 1e-9)
    assert any("collapsed edge" in n for n in mesh.notes)


def test_revolved_apex_is_not_slivers() -> None:
    """The revolved profile sewn by gmsh gave 9 nodes and left cusp strips open; unsewn it is
    meshed like any face: every node on the exact surface of revolution (radius = the profile's
    radius at that height, from the profile curve sampled densely)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("make_samples", SAMPLES / "make_samples.py")
    ms = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ms)
    prof = ms.revolved_profile()
    t = np.linspace(0.0, 1.0, 20001)
    xz = np.array([[prof.Value(s).X(), prof.Value(s).Z()] for s in t])  # OCC's profile: z decreasing
    mesh = mesh_cad(SAMPLES / "revolved_apex.igs", element="tri")
    x = mesh.nodes
    assert len(x) > 50
    r_exact = np.interp(-x[:, 2], -xz[:, 1], xz[:, 0])
    assert np.abs(np.hypot(x[:, 0], x[:, 1]) - r_exact).max() < 1e-3  # interpolation of the dense profile
    b = np.asarray(boundary_edges(mesh))
    assert np.abs(x[b.ravel(), 2] + 1.0).max() < 1e-9


def test_sector_with_apex_corner_stays_sewn(tmp_path) -> None:
    """A cone sector (90 deg) has its collapsed edge at a corner of the face, not inside it (no
    seam around the apex): gmsh meshes it sewn, as every face was before, and it is left so
    (the bearing's 16 three-sided patches likewise keep their sewn, conforming mesh).
    Generated with OCC (the samples' helpers)."""
    pytest.importorskip("OCP")
    import importlib.util

    from OCP.Geom import Geom_ConicalSurface

    spec = importlib.util.spec_from_file_location("make_samples", SAMPLES / "make_samples.py")
    ms = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ms)
    a = math.radians(30.0)
    cone = Geom_ConicalSurface(ms._ax3((0.0, 0.0, 20.0), (0, 0, -1)), a, 0.0)
    path = tmp_path / "sector.igs"
    ms.export_iges({"SECTOR": ms._face(ms._exact_bspline(cone, 0.0, math.pi / 2, 0.0, 20.0 / math.cos(a)))}, path, "nurbs")
    mesh = mesh_cad(path, element="tri")
    assert not any("collapsed edge" in n for n in mesh.notes)
    assert np.abs(_cone_gap(mesh.nodes)).max() < 1e-6
    assert np.sum(np.linalg.norm(mesh.nodes - [0.0, 0.0, 20.0], axis=1) < 1e-9) == 1
