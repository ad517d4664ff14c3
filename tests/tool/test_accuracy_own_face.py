"""The boundary error's shortcut (`tool_errors.own_face_nearest`): where a sample's foot on
its own face is inside the trims and no other face is near, that foot is the nearest point
of the trimmed model.

Reference: the global trimmed search (`cadbridge.cad.search.project_points` over all faces,
trims decided on the curves), run on every sample; the shortcut must give the same distance
(1e-9 x size) wherever it claims a point, and `tool_errors`' boundary error must equal the
one measured with the global search everywhere.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges import read_iges
from cadbridge.mesh.generate import mesh_cad
from cadbridge.nagata import NagataMesh
from cadbridge.normals.cad import cad_normals
from cadbridge.tool.build import CadProjector
from cadbridge.tool.accuracy import _on_faces, own_face_nearest, tool_errors

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"


def _tool(name: str, element: str):
    cad = SAMPLES / name
    model = read_iges(cad)
    mesh = mesh_cad(cad, element=element, curvature_elements=12)
    cn = cad_normals(mesh, model)
    blocks = [np.asarray(b.data) for b in mesh.cells]
    nm = NagataMesh(mesh.nodes, blocks, cn.corner_normals)
    g = nm.sample_grid(4)
    ef = np.concatenate(cn.element_face)
    return model, nm, g, ef


@pytest.mark.parametrize("name, element", [("trimmed_hole.igs", "tri"), ("ushape_tools_analytic.igs", "quad"),
                                           ("sphere_patch.igs", "tri"), ("multiple_knots.igs", "quad")])
def test_own_face_foot_is_the_trimmed_nearest(name, element):
    model, nm, g, ef = _tool(name, element)
    proj = CadProjector(model)
    face = ef[g.elem]
    _, _, uv = _on_faces(model, g.points, face, g.elem, g.normals)
    ok, d = own_face_nearest(model, g.points, face, uv)
    ref = np.linalg.norm(g.points - proj.project(g.points).foot, axis=1)  # global trimmed search
    size = model.size()
    np.testing.assert_allclose(d[ok], ref[ok], rtol=0, atol=1e-9 * size)
    if name == "multiple_knots.igs":  # the crease face is left to the global search
        assert not ok.any()
    else:
        assert ok.sum() > 0.3 * len(ok)  # the shortcut takes a good part of the samples


def test_boundary_error_equals_the_global_search():
    """trimmed_hole: patches bridge the hole (boundary error ~0.34 there, issue 13); the
    boundary error with the shortcut is the one of the global search at every sample."""
    model, nm, g, ef = _tool("trimmed_hole.igs", "tri")
    proj = CadProjector(model)
    err = tool_errors(nm, g.elem, g.eta, g.zeta, ef, model, proj.project)
    ref = np.linalg.norm(g.points - proj.project(g.points).foot, axis=1)
    from cadbridge.nagata.boundary_edges import boundary_curve_distance, free_edge_samples

    free = np.flatnonzero(free_edge_samples(nm, g.elem, g.eta, g.zeta))
    ref[free] = np.maximum(ref[free], boundary_curve_distance(model.faces[0], g.points[free], model.size()))
    np.testing.assert_allclose(err.boundary, ref, rtol=0, atol=1e-9 * model.size())
    assert err.boundary.max() > 0.1  # the hole's chords are seen
