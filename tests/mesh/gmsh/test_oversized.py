"""Class: gmsh's Delaunay keeps its triangulation of a narrow curved face's boundary nodes.

On a wall 2.5 mm high and ~35 mm long (K1's bow from Think3, trj5_k1-tc; Euclid's turbine
face 25 when its B-rep is meshed as it is) Frontal-Delaunay and Delaunay insert no point,
and their triangles run 3.5-4.2 x the size asked along the wall: a Nagata error of 0.22 mm on
K1 where the other writers' K1 tools stay below 0.08. Such a surface is meshed again like a
fold, with MeshAdapt for triangles (`cadbridge.mesh.generate.OVERSIZE`).

Reference: the size asked (``Mesh.MeshSizeMax``): no element edge longer than 2 x it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

CORPUS = Path(__file__).resolve().parents[3].parent / "shared" / "cad_corpus" / "step"


@pytest.mark.parametrize("name, element", [("trj5_k1-tc-203.stp", "tri"), ("ec_turbine-A.stp", "tri"),
                                           ("ec_turbine-A.stp", "quad")])
def test_no_element_far_above_the_size(name, element):
    path = CORPUS / name
    if not path.is_file():
        pytest.skip(f"{path} not present")
    pytest.importorskip("OCP")
    from cadbridge import read_cad
    from cadbridge.heal.brep import brep_source
    from cadbridge.mesh.generate import OVERSIZE, mesh_cad

    model = read_cad(path)
    size = float(np.linalg.norm(np.ptp(model.bbox(), axis=0))) / 20
    with brep_source(model) as (src, brep):
        mesh = mesh_cad(src, element=element, size=size, straight_splines=True, exact_curve_nodes=True,
                        face_anchors=brep.anchors)
    x = mesh.nodes
    longest = max(float(np.linalg.norm(x[np.roll(b.data, -1, axis=1)] - x[b.data], axis=2).max()) for b in mesh.cells)
    assert longest <= OVERSIZE * size
    assert any("longer than" in n for n in mesh.notes)  # the sample had the defect, and it was mended
