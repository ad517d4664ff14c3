"""`project_to_surfaces`: many (point, surface) pairs in one compiled pass.

References: closed forms (cylinder, sphere, and a V-shaped bilinear crease surface whose
nearest point is the nearer of its two planes) and OpenCASCADE's
``GeomAPI_ProjectPointOnSurf`` on random rational surfaces.
"""

from __future__ import annotations

import math

import numpy as np
from cadbridge.verify.reference import occ_bspline_surface as to_occ
from tests.helpers.occ import surface_nearest
from tests.helpers.surfaces import cylinder, random_surface, sphere

from cadbridge.nurbs.project import CONVERGED, FAILED, ON_BOUNDARY
from cadbridge.nurbs.project_many import SurfacePack, project_to_surfaces
from cadbridge.nurbs.surface import NurbsSurface


def v_shape() -> NurbsSurface:
    """Two planes meeting at a C0 knot line x = 0 (a crease inside one surface): z = |x| for
    x in [-1, 1], y in [0, 2] (degree 1 in x with the interior knot at 0.5)."""
    cp = np.array([[[-1.0, 0.0, 1.0], [-1.0, 2.0, 1.0]],
                   [[0.0, 0.0, 0.0], [0.0, 2.0, 0.0]],
                   [[1.0, 0.0, 1.0], [1.0, 2.0, 1.0]]])
    return NurbsSurface(1, 1, [0, 0, 0.5, 1, 1], [0, 0, 1, 1], cp)


def test_pairs_on_mixed_surfaces_match_closed_forms():
    """Reference: closed forms, pairs interleaved over three surfaces (one with a crease)."""
    rng = np.random.default_rng(4)
    r, z0, z1 = 2.0, -1.0, 3.0
    surfs = [cylinder(r, z0, z1), sphere(1.5), v_shape()]
    pack = SurfacePack(surfs)
    n = 600
    which = rng.integers(0, 3, n)
    pts = np.empty((n, 3))
    th = rng.uniform(-math.pi, math.pi, n)
    rho = rng.uniform(0.5, 4.0, n)
    z = rng.uniform(z0, z1, n)
    cyl = which == 0
    pts[cyl] = np.column_stack([rho * np.cos(th), rho * np.sin(th), z])[cyl]
    sph = which == 1
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts[sph] = (d * rng.uniform(0.3, 3.0, (n, 1)))[sph]
    vee = which == 2
    # near the V, x in [-0.6, 0.6] (feet inside the domain): nearest point on the plane z = |x| of its side, or
    # on the crease line x = 0 where the point lies in the wedge between the two normals
    x, y, h = rng.uniform(-0.6, 0.6, n), rng.uniform(0.2, 1.8, n), rng.uniform(-0.3, 0.3, n)
    pts[vee] = np.column_stack([x, y, np.abs(x) + h])[vee]
    res = project_to_surfaces(pack, which, pts)
    assert not np.any(res.status == FAILED)
    # cylinder: radial foot
    foot = np.column_stack([r * np.cos(th), r * np.sin(th), z])
    assert np.max(np.linalg.norm(res.foot[cyl] - foot[cyl], axis=1)) < 1e-11
    assert np.all(res.status[cyl] == CONVERGED)
    # sphere: distance | |P| - R |
    assert np.max(np.abs(res.distance[sph] - np.abs(np.linalg.norm(pts[sph], axis=1) - 1.5))) < 1e-11
    # V: distance to the nearer plane z = x / z = -x (clipped to its half), or to the crease line
    p = pts[vee]
    s2 = math.sqrt(2.0)
    dr = np.where(p[:, 0] + p[:, 2] >= 0, np.abs(p[:, 2] - p[:, 0]) / s2, np.hypot(p[:, 0], p[:, 2]))
    dl = np.where(p[:, 2] - p[:, 0] >= 0, np.abs(p[:, 2] + p[:, 0]) / s2, np.hypot(p[:, 0], p[:, 2]))
    assert np.max(np.abs(res.distance[vee] - np.minimum(dr, dl))) < 1e-12
    assert np.all(res.status[vee] != ON_BOUNDARY)


def test_random_rational_surfaces_against_opencascade():
    """Reference: OCC's GeomAPI_ProjectPointOnSurf (lowest distance) per point on its surface;
    ours is never farther than OCC's by more than 1e-9 x size."""
    rng = np.random.default_rng(11)
    surfs = [random_surface(rng, rational=True, p=3, q=2, nu=7, nv=6, size=10.0, amp=0.2) for _ in range(4)]
    pack = SurfacePack(surfs)
    n = 160
    which = rng.integers(0, len(surfs), n)
    pts = np.empty((n, 3))
    for k, s in enumerate(surfs):
        sel = np.flatnonzero(which == k)
        u0, u1, v0, v1 = s.domain
        u, v = rng.uniform(u0, u1, len(sel)), rng.uniform(v0, v1, len(sel))
        pts[sel] = s.evaluate(u, v) + rng.uniform(-0.5, 0.5, (len(sel), 1)) * s.normal(u, v)
    res = project_to_surfaces(pack, which, pts)
    for k, s in enumerate(surfs):
        gs = to_occ(s)
        for i in np.flatnonzero(which == k):
            cands, _ = surface_nearest(gs, s, pts[i])
            d_occ = cands[0][0]  # OCC's nearest over interior extrema, edge curves and corners
            assert res.status[i] != FAILED
            assert abs(res.distance[i] - d_occ) <= 1e-9 * 10.0, (i, res.distance[i], d_occ)


def test_empty_and_mismatched_input():
    pack = SurfacePack([sphere(1.0)])
    r = project_to_surfaces(pack, np.zeros(0, dtype=int), np.zeros((0, 3)))
    assert len(r) == 0
    try:
        project_to_surfaces(pack, [0, 0], np.zeros((3, 3)))
    except ValueError as exc:
        assert "2 surface ids for 3 points" in str(exc)
    else:  # pragma: no cover
        raise AssertionError("mismatched input accepted")


def test_nearest_samples_of_all_surfaces_in_one_query():
    """`SurfacePack.nearest_samples` (one KD-tree over all surfaces' samples, the surface id as
    a 4th coordinate) against each surface's own sample tree queried alone. Reference: the
    per-surface cKDTree's k distances, which the returned samples of the own surface must
    have (the samples themselves differ at ties: the sphere's pole samples coincide), for points near the
    surfaces, points far off them (beyond the 4D gap: the per-surface fallback) and a surface
    with fewer samples than k (only its own first columns count)."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(8)
    flat = NurbsSurface(1, 1, [0, 0, 1, 1], [0, 0, 1, 1],
                        [[[5, 0, 0], [5, 1, 0]], [[6, 0, 0], [6, 1, 0]]])
    surfs = [cylinder(2.0, -1.0, 3.0), sphere(1.5), v_shape(), flat]
    pack = SurfacePack(surfs)
    counts = np.diff(pack.s_off)
    k = 32  # more than the bilinear surfaces' 25 samples
    assert counts.min() < k < counts.max()
    n = 2000
    sid = rng.integers(0, len(pack.samples), n)
    p = rng.uniform(-4, 7, (n, 3))
    p[:20] *= 1e4  # far off every surface: these take the per-surface route
    d, i = pack.nearest_samples(sid, p, k)
    for s in range(len(pack.samples)):
        rows = np.flatnonzero(sid == s)
        ks = min(k, counts[s])
        tree = cKDTree(pack.spts[pack.s_off[s]:pack.s_off[s + 1]])
        d_ref, i_ref = tree.query(p[rows], k=ks)
        d_ref = np.asarray(d_ref).reshape(len(rows), ks)
        i_ref = np.asarray(i_ref).reshape(len(rows), ks) + pack.s_off[s]
        np.testing.assert_allclose(d[rows, :ks], d_ref, rtol=1e-14, atol=1e-14)
        assert np.all((i[rows, :ks] >= pack.s_off[s]) & (i[rows, :ks] < pack.s_off[s + 1]))  # own samples
        np.testing.assert_allclose(np.linalg.norm(pack.spts[i[rows, :ks]] - p[rows, None], axis=2), d_ref,
                                   rtol=1e-14, atol=1e-14)
