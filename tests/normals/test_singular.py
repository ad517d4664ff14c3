"""Exact CAD normals at singular points (`cadbridge.normals.singular`, through `cad_normals`).

Meshes of the samples iges_samples/cone_apex.igs, hemisphere_pole.igs and revolved_apex.igs
(gmsh, tri and quad). References:

* analytic geometry: a sphere's pole normal is its axis; on the cone (apex (0, 0, 20), half
  angle 30 deg) the normal along the generatrix at azimuth a is (cos a cos 30, sin a cos 30,
  sin 30); on the revolved profile (leaving the axis at 50 deg) it is (cos a cos 50, sin a
  cos 50, sin 50) up to one sign; the node normal of a whole apex is the axis; each element's
  limit is the one along the generatrix through its centroid;
* OpenCASCADE's normal (D1 cross product, tests/helpers/occ.py) on the element's generatrix a
  step 1e-7 of the parameter range away from the apex, where OCC has a normal.

The node gets the axis in all its elements (module docs of `cadbridge.normals.singular`: the
normal that keeps the generatrix edges straight); each element's own limit is what
`reference_normals` gives the error samples at the apex.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges.reader import read_iges
from cadbridge.mesh.generate import mesh_cad
from cadbridge.normals.cad import cad_normals
from cadbridge.normals.singular import reference_normals

SAMPLES = Path(__file__).parents[2] / "iges_samples"

# file, apex, angle (degrees) between the axis and the generatrix leaving the apex: the limit
# normals make that angle with the plane perpendicular to the axis (90: one normal, the axis)
CASES = [
    ("hemisphere_pole.igs", (0.0, 0.0, 10.0), 90.0),
    ("cone_apex.igs", (0.0, 0.0, 20.0), 30.0),
    ("revolved_apex.igs", (0.0, 0.0, 15.0), 50.0),
]


@pytest.fixture(scope="module", params=["tri", "quad"])
def element(request) -> str:
    return request.param


@pytest.fixture(scope="module")
def normals(element):
    """{file: (model, mesh, CadNormals)} for the three samples."""
    out = {}
    for name, _, _ in CASES:
        model = read_iges(SAMPLES / name)
        mesh = mesh_cad(SAMPLES / name, element=element)
        out[name] = (model, mesh, cad_normals(mesh, model))
    return out


def _apex_corners(mesh, cn, apex):
    """(node, [(block, element, corner)]) of the node at ``apex`` (at least 3 elements)."""
    i = int(np.argmin(np.linalg.norm(mesh.nodes - np.array(apex), axis=1)))
    assert np.linalg.norm(mesh.nodes[i] - np.array(apex)) < 1e-9
    at = []
    for b, c in enumerate(mesh.cells):
        e, k = np.nonzero(np.asarray(c.data) == i)
        at += [(b, int(x), int(y)) for x, y in zip(e, k)]
    assert len(at) >= 3
    return i, at


@pytest.mark.parametrize("name, apex, elevation", CASES, ids=[c[0] for c in CASES])
def test_apex_node_normal_is_the_axis(normals, name, apex, elevation) -> None:
    """The node at a pole or apex gets one normal in all its elements: the axis (the limit at
    a pole; at an apex the normal in the plane of every generatrix and its limit normal, which
    keeps the generatrix edges straight), outwards; no corner records, no NaN anywhere."""
    model, mesh, cn = normals[name]
    i, at = _apex_corners(mesh, cn, apex)
    assert cn.singular[i] and cn.singular.sum() == 1
    assert all(np.all(np.isfinite(c)) for c in cn.corner_normals) and np.all(np.isfinite(cn.normals))
    n = cn.normals[i]
    assert abs(abs(n[2]) - 1.0) < 1e-14 and np.hypot(n[0], n[1]) < 1e-12
    assert not cn.crease[i]
    corner = np.array([cn.corner_normals[b][e, k] for b, e, k in at])
    assert np.array_equal(corner, np.broadcast_to(n, corner.shape))
    # outwards: on the side of the normals of the nodes around it
    ring = np.unique(np.concatenate([np.asarray(mesh.cells[b].data)[e] for b, e, _ in at]))
    ring = ring[ring != i]
    assert np.all(cn.normals[ring] @ n > 0)
    # the elements' own limits (along the generatrix through each centroid) are the analytic
    # cone of directions around that axis
    cent = np.array([mesh.nodes[np.asarray(mesh.cells[b].data)[e]].mean(axis=0) for b, e, _ in at])
    lim = reference_normals(model, np.repeat(mesh.nodes[i][None], len(at), axis=0), np.zeros(len(at), dtype=np.int64),
                            cent, np.zeros((len(at), 3)), np.repeat(n[None], len(at), axis=0))
    az = np.arctan2(cent[:, 1], cent[:, 0])
    e = math.radians(elevation)
    ref = np.column_stack([np.cos(az) * math.cos(e), np.sin(az) * math.cos(e), np.full(len(az), math.sin(e))])
    ref[:, 2] *= np.sign(n[2])
    ref[:, :2] *= np.sign(np.einsum("ij,ij->", lim[:, :2], ref[:, :2]))  # one sign: opening up or down
    assert np.abs(lim - ref).max() < 1e-12


@pytest.mark.parametrize("name, apex, elevation", CASES, ids=[c[0] for c in CASES])
def test_limits_against_occ_off_the_apex(normals, name, apex, elevation) -> None:
    """Each element's limit at the apex (along the generatrix through its centroid) against
    OCC's normal on that generatrix 1e-7 of the parameter range off the apex, where OCC has one."""
    pytest.importorskip("OCP")
    from cadbridge.nurbs.project import project_to_surface
    from tests.helpers.occ import read_surfaces, surface_normals

    model, mesh, cn = normals[name]
    i, at = _apex_corners(mesh, cn, apex)
    s = model.faces[0].surface
    (occ,) = read_surfaces(SAMPLES / name)
    cent = np.array([mesh.nodes[np.asarray(mesh.cells[b].data)[e]].mean(axis=0) for b, e, _ in at])
    foot = project_to_surface(s, cent)
    u0, u1, v0, v1 = s.domain
    at_v, step = (v0, 1e-7) if s.collapsed_sides()[2] else (v1, -1e-7)
    theirs = surface_normals(occ, foot.u, np.full(len(at), at_v + step * (v1 - v0)))
    n = cn.normals[i]
    lim = reference_normals(model, np.repeat(mesh.nodes[i][None], len(at), axis=0), np.zeros(len(at), dtype=np.int64),
                            cent, np.zeros((len(at), 3)), np.repeat(n[None], len(at), axis=0))
    angle = np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", lim, theirs)), -1.0, 1.0))
    assert angle.max() < 1e-5


def test_reference_normals_only_at_singular_points(normals) -> None:
    """The CAD normal an error sample is measured against: at the apex, the limit along the
    generatrix through the given element centroid (the analytic cone normal there); elsewhere
    the normal given, untouched."""
    model, mesh, cn = normals["cone_apex.igs"]
    pts = np.array([[0.0, 0.0, 20.0], [0.0, 0.0, 20.0], [1.0, 0.0, 20.0 - 1.0 / math.tan(math.radians(30))]])
    given = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.5, 0.5, 0.70710678]])
    cent = np.array([[0.0, 1.0, 20.0 - 1.0 / math.tan(math.radians(30))], [-1.0, 0.0, 18.0], [0.0, 0.0, 0.0]])
    out = reference_normals(model, pts, np.zeros(3, dtype=np.int64), cent, given, given)
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    assert np.abs(out[0] - [0.0, c, s]).max() < 1e-14
    assert np.abs(out[1] - [-c, 0.0, s]).max() < 1e-14
    assert np.array_equal(out[2], given[2])


@pytest.mark.parametrize("sweep", [90.0, 40.0])
def test_partial_apex_gets_the_axis(tmp_path, sweep) -> None:
    """A cone face covering only a sector of the apex (a corner of the face): the node normal
    is still the axis (every generatrix edge straight), not the mean of the covered limits
    (56 degrees off the axis for a quarter cone, 60 for a 40-degree sector). Generated with OCC
    (the samples' helpers: a `Geom_ConicalSurface` sector as an exact rational 128)."""
    pytest.importorskip("OCP")
    import importlib.util

    from OCP.Geom import Geom_ConicalSurface

    spec = importlib.util.spec_from_file_location("make_samples", SAMPLES / "make_samples.py")
    ms = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ms)
    a = math.radians(30.0)
    cone = Geom_ConicalSurface(ms._ax3((0.0, 0.0, 20.0), (0, 0, -1)), a, 0.0)
    surf = ms._exact_bspline(cone, 0.0, math.radians(sweep), 0.0, 20.0 / math.cos(a))
    path = tmp_path / "sector.igs"
    ms.export_iges({"SECTOR": ms._face(surf)}, path, "nurbs")
    model = read_iges(path)
    mesh = mesh_cad(path, element="tri", size=2.0)
    cn = cad_normals(mesh, model)
    i = int(np.argmin(np.linalg.norm(mesh.nodes - [0.0, 0.0, 20.0], axis=1)))
    assert cn.singular[i] and np.linalg.norm(mesh.nodes[i] - [0.0, 0.0, 20.0]) < 1e-9
    n = cn.normals[i]
    assert abs(abs(n[2]) - 1.0) < 1e-12 and np.hypot(n[0], n[1]) < 1e-9
    assert np.all(np.isfinite(cn.normals))
