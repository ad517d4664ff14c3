"""Creases inside one NURBS face: a C0 knot line (knot of multiplicity = degree).

`iges_samples/multiple_knots.igs` is a rational bicubic whose u knot 2 has multiplicity 3
(C0: a 13-22 degree kink along v) and knot 1 multiplicity 2 (C1: smooth normals). References:
the one-sided limits of the surface normal, approached numerically (finite parameter steps
of 1e-9 from either side), and the same Nagata surface built with single node normals.
"""

from pathlib import Path

import numpy as np
import pytest

from cadbridge.iges import read_iges
from cadbridge.mesh.mesh import CellBlock, Mesh
from cadbridge.nagata import NagataMesh
from cadbridge.normals.cad import cad_normals

SAMPLE = Path(__file__).parents[2] / "iges_samples" / "multiple_knots.igs"


@pytest.fixture(scope="module")
def grid_mesh():
    model = read_iges(SAMPLE)
    s = model.faces[0].surface
    u0, u1, v0, v1 = s.domain
    us = np.unique(np.concatenate([np.linspace(u0, u1, 13), [1.0, 2.0]]))  # node lines on both knots
    vs = np.linspace(v0, v1, 6)
    uu, vv = np.meshgrid(us, vs, indexing="ij")
    nodes = s.evaluate(uu.ravel(), vv.ravel())
    nu, nv = len(us), len(vs)
    i, j = np.meshgrid(np.arange(nu - 1), np.arange(nv - 1), indexing="ij")
    n00 = (i * nv + j).ravel()
    quads = np.column_stack([n00, n00 + nv, n00 + nv + 1, n00 + 1])
    return model, s, Mesh(nodes=nodes, cells=[CellBlock("quad", quads)]), us, vs


def test_c0_knot_nodes_get_one_sided_corner_normals(grid_mesh):
    model, s, mesh, us, vs = grid_mesh
    cn = cad_normals(mesh, model)
    nv = len(vs)
    on_c0 = np.flatnonzero(np.isclose(us, 2.0))[0] * nv + np.arange(nv)
    on_c1 = np.flatnonzero(np.isclose(us, 1.0))[0] * nv + np.arange(nv)
    assert cn.crease[on_c0].all()
    assert not cn.crease[on_c1].any()  # C1 knot: the normal is continuous
    assert cn.crease.sum() == nv
    # each corner on the knot line carries the limit normal from its element's side
    h = 1e-9
    quads = mesh.quads
    corners = cn.corner_normals[0]
    for side in (-1, 1):
        ref = s.normal(np.full(nv, 2.0 + side * h), vs)
        for k in range(4):
            e = np.flatnonzero(np.isin(quads[:, k], on_c0))
            elem_u = mesh.nodes[quads[e]].mean(axis=1)
            # which side of the knot is the element on? compare its centroid with the knot line
            sel = e[(np.sign(np.array([_u_of(s, p) for p in elem_u]) - 2.0) == side)]
            if len(sel) == 0:
                continue
            node = quads[sel, k]
            row = node - on_c0[0]
            got = corners[sel, k]
            assert np.allclose(np.abs(np.einsum("ij,ij->i", got, ref[row])), 1.0, atol=1e-12)


def _u_of(s, point):
    """u of a point on the surface by a dense search (independent of our projection)."""
    u0, u1, v0, v1 = s.domain
    uu, vv = np.meshgrid(np.linspace(u0, u1, 301), np.linspace(v0, v1, 101), indexing="ij")
    pts = s.evaluate(uu.ravel(), vv.ravel())
    return uu.ravel()[np.argmin(np.linalg.norm(pts - point, axis=1))]


def test_corner_normals_at_c0_knot_improve_the_nagata_surface(grid_mesh):
    """With per-corner normals on the C0 line the Nagata normals stay close to the CAD
    normals; with one normal per node (the old behaviour) they are far off near the kink.
    Reference normal at a grid point: the surface normal at its projection, one-sided from
    the side of the knot its element lies on."""
    from cadbridge.cad.search import project_points

    model, s, mesh, us, vs = grid_mesh
    cn = cad_normals(mesh, model)
    quads = mesh.quads
    elem_side = np.where(np.array([_u_of(s, c) for c in mesh.nodes[quads].mean(axis=1)]) >= 2.0, 1, -1)

    def max_normal_error(normals):
        nm = NagataMesh(mesh.nodes, quads, normals)
        g = nm.sample_grid(8)
        pr = project_points(g.points, model)
        u = np.where(np.abs(pr.u - 2.0) < 1e-3, 2.0, pr.u)  # feet on the kink: evaluate one-sided
        ref = s.normal(u, pr.v, side_u=elem_side[g.elem])
        ang = np.degrees(np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", ref, g.normals)), -1, 1)))
        return ang.max()

    with_corners = max_normal_error(cn.corner_normals[0])
    single = max_normal_error(cn.normals)
    assert with_corners < 0.5 * single


def test_points_on_a_crease_line_project_onto_it():
    """Points of the surface on and around the C0 knot line project back onto themselves
    (reference: the points were evaluated on the surface, distance 0) and are CONVERGED with
    a finite normal: Newton cannot converge onto a crease, so the surface is projected piece
    by piece (`smooth_pieces`). Rational circles' double knots are not split."""
    from cadbridge.nurbs.project import CONVERGED, project_to_surface, smooth_pieces

    s = read_iges(SAMPLE).faces[0].surface
    assert len(smooth_pieces(s)) == 2
    for name in ("sphere_patch.igs", "torus_patch.igs", "rational_quarter_cylinder.igs"):
        other = read_iges(SAMPLE.parent / name).faces[0].surface
        assert len(smooth_pieces(other)) == 1
    v = np.linspace(0.0, 1.0, 41)
    u = np.concatenate([np.full(41, 2.0), np.full(41, 2.0 - 1e-7), np.full(41, 2.0 + 1e-7)])
    pts = s.evaluate(u, np.tile(v, 3))
    res = project_to_surface(s, pts)
    assert np.all(res.status == CONVERGED)
    assert res.distance.max() < 1e-9 * np.linalg.norm(np.ptp(s.control_points.reshape(-1, 3), axis=0))
    assert np.all(np.isfinite(res.normal))
