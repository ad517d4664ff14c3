"""Work the adaptive loop and `convert` no longer do twice gives what doing it again gives.

- `tools_from_mesh(..., known_normals=cn)` with the `cad_normals` result the loop's
  inflection step made: reference = `tools_from_mesh` projecting the nodes itself; tool
  normals, corner normals, patch coefficients and errors bit for bit.
- `measure_tool` on a tool measured already on the same divisions keeps that measurement and
  adds the edge rules' line: reference = a fresh tool measured once with ``compare_rules``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cadbridge.normals.cad import cad_normals
from cadbridge.tool.build import CadProjector, measure_tool, tools_from_mesh
from cadbridge.tool.meshing import mesh_for_tools, read_healed

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"


@pytest.fixture(scope="module")
def die():
    cad = str(SAMPLES / "ushape_tools_nurbs.igs")
    model, exc = read_healed(cad)
    mesh, _ = mesh_for_tools(cad, model, excursions=exc, element="quad", size=12.0)
    return model, mesh


def _same(a, b):
    assert len(a) == len(b)
    for s, t in zip(a, b):
        assert s.name == t.name
        np.testing.assert_array_equal(s.normals, t.normals)
        for x, y in zip(s.corner_normals, t.corner_normals):
            np.testing.assert_array_equal(x, y)
        np.testing.assert_array_equal(s.nagata.quad_coefficients, t.nagata.quad_coefficients)
        np.testing.assert_array_equal(s.nagata.tri_coefficients, t.nagata.tri_coefficients)
        for k in ("surface_error", "boundary_error", "flat_surface_error", "normal_error"):
            np.testing.assert_array_equal(s.grid[k], t.grid[k])
        assert s.stats == t.stats and s.diagnosis == t.diagnosis


def test_known_normals_give_the_tools_projection_gives(die):
    model, mesh = die
    proj = CadProjector(model)
    cn = cad_normals(mesh, model, orient=True, allow_far=True)
    assert cn.mesh is mesh and not cn.flipped.any()  # gmsh's mesh is consistently wound: the result is for it
    kw = dict(method="cad", grid=6, projector=proj, orient=True, meshed_per_face=True)
    _same(tools_from_mesh(mesh, model, known_normals=cn, **kw), tools_from_mesh(mesh, model, **kw))


def test_known_normals_of_another_mesh_are_not_taken(die):
    model, mesh = die
    other = type(mesh)(mesh.nodes.copy(), mesh.cells, name=mesh.name, point_data=dict(mesh.point_data),
                       cell_data=dict(mesh.cell_data))
    cn = cad_normals(other, model, orient=True, allow_far=True)
    cn.normals[:] = np.nan  # would poison the tools if taken
    tools = tools_from_mesh(mesh, model, method="cad", grid=6, orient=True, meshed_per_face=True,
                            known_normals=cn)
    assert all(np.all(np.isfinite(t.normals)) for t in tools)


def test_measure_on_the_same_divisions_is_kept(die):
    model, mesh = die
    proj = CadProjector(model)
    kw = dict(method="cad", projector=proj, orient=True, meshed_per_face=True)
    measured = tools_from_mesh(mesh, model, grid=6, **kw)  # measured in build_tool, as the loop does
    fresh = tools_from_mesh(mesh, model, grid=6, measure=False, **kw)
    for t, f in zip(measured, fresh):
        grid_before = t.grid["surface_error"]
        measure_tool(t, model, projector=proj, grid=6, compare_rules=True)
        measure_tool(f, model, projector=proj, grid=6, compare_rules=True)
        assert t.grid["surface_error"] is grid_before  # not measured again
        assert t.stats == f.stats and t.diagnosis == f.diagnosis
        assert "shape_error_by_rule" in t.stats


def test_measure_on_other_divisions_replaces_the_diagnosis(die):
    """Measured on 6, then on 10 divisions: the same as measured on 10 alone (no line of the
    first measure kept)."""
    model, mesh = die
    proj = CadProjector(model)
    kw = dict(method="cad", projector=proj, orient=True, meshed_per_face=True)
    twice = tools_from_mesh(mesh, model, grid=6, **kw)
    once = tools_from_mesh(mesh, model, grid=10, measure=False, **kw)
    for t, f in zip(twice, once):
        measure_tool(t, model, projector=proj, grid=10, compare_rules=True)
        measure_tool(f, model, projector=proj, grid=10, compare_rules=True)
        np.testing.assert_array_equal(t.grid["surface_error"], f.grid["surface_error"])
        assert t.stats == f.stats and t.diagnosis == f.diagnosis
