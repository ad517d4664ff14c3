"""The error measure projects coincident samples once (`tool_errors._unique_points`):
neighbouring patches share their corner and edge samples.

Reference: the same measure with every sample projected on its own (the dedupe replaced by
the identity), i.e. the per-sample Newton projections onto the untrimmed surfaces and the
trimmed search; all four errors must agree within 1e-9 x size at every sample, on files with
trims, a hole, analytic faces, several faces and a crease face (smooth pieces), in tri and
quad, and far fewer points must be projected.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import cadbridge.tool.accuracy as TE
from cadbridge.iges import read_iges
from cadbridge.mesh.generate import mesh_cad
from cadbridge.nagata import NagataMesh
from cadbridge.normals.cad import cad_normals
from cadbridge.tool.build import CadProjector

SAMPLES = Path(__file__).resolve().parents[2] / "iges_samples"


def _identity(points, quantum, key=None):
    n = len(points)
    return np.arange(n), np.arange(n)


@pytest.mark.parametrize("name, element, div", [("trimmed_hole.igs", "tri", 2), ("ushape_tools_analytic.igs", "quad", 2),
                                                ("multiple_knots.igs", "tri", 2), ("sphere_patch.igs", "tri", 4)])
def test_unique_samples_give_the_per_sample_errors(name, element, div, monkeypatch):
    cad = SAMPLES / name
    model = read_iges(cad)
    mesh = mesh_cad(cad, element=element, curvature_elements=12)
    cn = cad_normals(mesh, model)
    nm = NagataMesh(mesh.nodes, [np.asarray(b.data) for b in mesh.cells], cn.corner_normals)
    g = nm.sample_grid(div)
    ef = np.concatenate(cn.element_face)
    proj = CadProjector(model)
    fast = TE.tool_errors(nm, g.elem, g.eta, g.zeta, ef, model, proj.project)
    rep, _ = TE._unique_points(g.points, TE.COINCIDENT * model.size())
    assert len(rep) < 0.75 * len(g.points)  # shared corner / edge samples are projected once
    monkeypatch.setattr(TE, "_unique_points", _identity)
    ref = TE.tool_errors(nm, g.elem, g.eta, g.zeta, ef, model, CadProjector(model).project)
    tol = 1e-9 * model.size()
    for a, b in ((fast.surface, ref.surface), (fast.flat_surface, ref.flat_surface), (fast.boundary, ref.boundary)):
        np.testing.assert_allclose(a, b, rtol=0, atol=tol)
    np.testing.assert_allclose(fast.normal, ref.normal, rtol=0, atol=1e-6)  # degrees
    assert np.array_equal(fast.face, ref.face)


def test_unique_points_cells_and_keys():
    """Points within a cell are one, a key separates them, points a cell apart stay apart
    (reference: the construction itself)."""
    x = np.array([[0.0, 0.0, 0.0], [1e-15, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 3e-12]])
    rep, inv = TE._unique_points(x, 1e-12)
    assert len(rep) == 3 and inv[0] == inv[1] == inv[2] and len({inv[0], inv[3], inv[4]}) == 3
    rep, inv = TE._unique_points(x, 1e-12, key=np.array([0, 0, 1, 0, 0]))
    assert len(rep) == 4 and inv[0] == inv[1] != inv[2]
    assert np.abs(x[rep][inv] - x).max() <= 1e-12


def test_toolfile_rows_are_str_and_repr_joined():
    """The tool file's row writer (`cadbridge.io.toolfile._rows`): reference is the plain
    join of ``str`` of the integers and ``repr`` of the floats (docs/toolfile.md: round-trip
    precision), on random values and the awkward ones (-0.0, subnormal, 1e300, integral)."""
    from cadbridge.io.toolfile import _rows

    rng = np.random.default_rng(7)
    ids = np.arange(1, 201)
    k = rng.integers(1, 9, 200)
    f = rng.normal(size=(200, 3)) * 10.0 ** rng.integers(-8, 8, (200, 3))
    f[0] = (-0.0, 5e-324, 1e300)
    f[1] = (3.0, -2.0, 0.1)
    ref = [" ".join([str(int(a)), str(int(b))] + [repr(float(x)) for x in row]) for a, b, row in zip(ids, k, f)]
    assert _rows(ids, [k], f) == ref
    assert _rows(ids, [], None) == [str(int(a)) for a in ids]
    assert [float(t) for t in _rows(ids, [k], f)[5].split()[2:]] == f[5].tolist()
