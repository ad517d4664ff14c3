"""The sizing law of doubly curved patches and mapped sides (issue 12, production die).

References: closed-form torus and sphere geometry (the distance of a point to a torus or a
sphere, its principal curvatures), Nagata patches with exact normals evaluated by
`cadbridge.nagata.NagataMesh`, and the law e = C h^4 / R^3 of thesis Fig. 8.
"""

import math

import numpy as np
import pytest

from cadbridge.mesh.sizing import (
    MAX_TURN,
    NAGATA_ERROR_CONSTANT as C,
    CurvatureFrames,
    edge_length_for_tolerance,
    patch_curvature,
)
from cadbridge.nagata import NagataMesh
from cadbridge.nurbs.construct import torus_patch
from cadbridge.nurbs.curvature import principal_curvatures


def _torus(R, r, phi, th):
    """Points and unit normals of the torus about z (tube angle phi, sweep angle th)."""
    rho = R + r * np.cos(phi)
    x = np.stack([rho * np.cos(th), rho * np.sin(th), r * np.sin(phi)], -1)
    n = np.stack([np.cos(phi) * np.cos(th), np.cos(phi) * np.sin(th), np.sin(phi)], -1)
    return x, n


def _torus_quad_error(R, r, phi0, dphi, dth):
    """Max distance to the torus of one Nagata quad (exact corner normals) over
    [phi0 +- dphi / 2] x [0, dth], with its tube and sweep chords."""
    P, T = np.meshgrid([phi0 - dphi / 2, phi0 + dphi / 2], [0.0, dth], indexing="ij")
    x, n = _torus(R, r, P.ravel(), T.ravel())
    nm = NagataMesh(x, np.array([[0, 2, 3, 1]]), n)
    g = nm.sample_grid(24)
    p, _ = nm.evaluate(g.elem, g.eta, g.zeta)
    rho = np.hypot(p[:, 0], p[:, 1])
    err = np.abs(np.hypot(rho - R, p[:, 2]) - r).max()
    return err, np.linalg.norm(x[0] - x[2]), np.linalg.norm(x[0] - x[1])


@pytest.mark.parametrize("dphi, dth", [(0.6, 0.6), (0.3, 0.8), (0.2, 0.2)])
def test_geodesic_rail_law_on_torus_top(dphi, dth):
    """Rails along the top circle of a torus tube (r 4, sweep R 10) have no normal curvature
    (k_n = 0) but bend in the tangent plane (k_g = 1 / R): the normal-curvature law predicts
    nothing there, and the patch error follows eq. (side) of `CurvatureFrames`,
    C h^4 k_g^2 k_x (k_x = 1 / r, across), plus the tube edges' own C h^4 / r^3: within
    0.7-1.5x (reference: the exact distance to the torus)."""
    R, r = 10.0, 4.0
    err, h_tube, h_rail = _torus_quad_error(R, r, math.pi / 2, dphi, dth)
    predicted = C * h_tube ** 4 / r ** 3 + C * h_rail ** 4 * (1 / R) ** 2 * (1 / r)
    assert 0.7 <= err / predicted <= 1.5
    assert err > 5 * C * h_tube ** 4 / r ** 3  # the rail term dominates: the old law missed it


def test_side_curvature_on_nurbs_torus():
    """`CurvatureFrames.side_curvature` on samples of a NURBS torus patch (R 20, r 5): at
    the top circle along the sweep k_eff^3 = k_g^2 k_x / (1/2) with k_g = 1 / R, k_x = 1 / r;
    on the outer equator along the sweep (a line of curvature) k_n = 1 / (R + r), and along
    the tube 1 / r, each with half the tolerance (the surface curves across both).
    Reference: the torus' closed-form curvatures."""
    R, r = 20.0, 5.0
    s = torus_patch(R, r, (-0.2, math.pi / 2 + 0.2), (0.0, 1.0))
    u0, u1, v0, v1 = s.domain
    U, V = np.meshgrid(np.linspace(u0, u1, 60), np.linspace(v0, v1, 30), indexing="ij")
    U, V = U.ravel(), V.ravel()
    k1, k2, d1, d2 = principal_curvatures(s, U, V, directions=True)
    frames = CurvatureFrames(s.evaluate(U, V), k1, k2, d1, d2)
    th = np.linspace(0.2, 0.8, 7)
    sweep_t = np.stack([-np.sin(th), np.cos(th), 0 * th], -1)
    top, _ = _torus(R, r, np.full_like(th, math.pi / 2), th)
    k_top = frames.side_curvature(top, sweep_t, np.full_like(th, 1 / R))  # the top circle has radius R
    assert np.allclose(k_top, np.cbrt((1 / R) ** 2 * (1 / r) / 0.5), rtol=2e-2)
    eq, _ = _torus(R, r, np.zeros_like(th), th)
    k_eq = frames.side_curvature(eq, sweep_t, np.full_like(th, 1 / (R + r)))
    assert np.allclose(k_eq, np.cbrt((1 / (R + r)) ** 3 / 0.5), rtol=2e-2)
    tube_t = np.stack([0 * th, 0 * th, np.ones_like(th)], -1)
    k_tube = frames.side_curvature(eq, tube_t, np.full_like(th, 1 / r))
    assert np.allclose(k_tube, np.cbrt((1 / r) ** 3 / 0.5), rtol=2e-2)


def test_side_curvature_ignores_a_tangent_neighbour():
    """A straight plane edge leaving a cylinder fillet tangentially (the U-shape die's flange
    and wall edges) gets k_eff = 0, though the nearest samples lie on the fillet (they fail
    the osculating-paraboloid test: the plane is d^2 / 2R off the fillet's paraboloid); the
    fillet's own arc gets its curvature 1 / R (a cylinder: no curvature across, full
    tolerance). Reference: the closed-form cylinder."""
    from pathlib import Path

    from cadbridge.iges import read_iges
    from cadbridge.mesh.sizing import curvature_samples

    m = read_iges(Path(__file__).parents[2] / "iges_samples" / "ushape_die_nurbs.igs")
    _, _, frames = curvature_samples(m, frames=True)
    # the R 5 shoulder, found from the samples: the curved ones
    curved = np.abs(frames.k1) + np.abs(frames.k2) > 0.1
    pc = frames.points[curved]
    ymid = 0.5 * (pc[:, 1].min() + pc[:, 1].max())
    # the arc end of the fillet nearest the mid plane y = ymid and its tangent-continuous wall
    lo = pc[np.argmin(pc[:, 2])]  # lowest point of the shoulder: where the wall leaves it
    # within ~1 mm of the junction the wall is on the fillet's paraboloid to 5 % (tangent
    # continuation): those points may take the fillet's size (at most ~1 / h of a division)
    z = lo[2] - np.linspace(1.0, 20.0, 40)
    wall = np.column_stack([np.full_like(z, lo[0]), np.full_like(z, ymid), z])
    k = frames.side_curvature(wall, np.tile([0.0, 0.0, -1.0], (len(z), 1)), np.zeros_like(z))
    assert np.all(k < 1e-9)
    arc = pc[np.abs(pc[:, 1] - pc[np.argmin(np.abs(pc[:, 1] - ymid)), 1]) < 1e-9]
    order = np.argsort(arc[:, 2])
    arc = arc[order]
    t = np.gradient(arc, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    k_arc = frames.side_curvature(arc, t, np.full(len(arc), 0.2))
    assert np.allclose(k_arc, 0.2, rtol=1e-6)


def test_patch_curvature_sphere_and_cylinder():
    """An isotropic element on a sphere: its centre is as far off as an edge along its
    diagonal (sqrt(2) h at curvature k): 4 C h^4 k^3, k_p = 4^(1/3) k; a cylinder keeps k.
    The Nagata quad on a sphere (R 10, exact normals, equal sides) follows C h^4 k_p^3
    within 0.8-1.2x (reference: the exact distance to the sphere; the single-edge law
    C h^4 k^3 is ~4x below it); square quads on a torus (r 4, R 10) too (exact distance to
    the torus)."""
    assert patch_curvature(0.1, 0.1) == pytest.approx(0.1 * 4 ** (1 / 3))
    assert patch_curvature(-0.2, 0.0) == pytest.approx(0.2)
    assert patch_curvature(0.2, -0.2) == pytest.approx(0.2 * 2 ** (1 / 3))  # saddle: the sides
    for phi0, d in ((0.0, 0.6), (0.0, 0.3), (math.pi / 2, 0.6)):
        R, r = 10.0, 4.0
        rho = R + r * math.cos(phi0)
        err, h_tube, h_sweep = _torus_quad_error(R, r, phi0, d, d * r / rho)  # square: equal chords
        kp = patch_curvature(1 / r, math.cos(phi0) / rho)
        assert 0.8 <= err / (C * max(h_tube, h_sweep) ** 4 * kp ** 3) <= 1.6
    Rs = 10.0
    for a in (0.15, 0.3):
        lat, lon = np.meshgrid([-a / 2, a / 2], [-a / 2, a / 2], indexing="ij")
        n = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1).reshape(-1, 3)
        x = Rs * n
        nm = NagataMesh(x, np.array([[0, 2, 3, 1]]), n)
        g = nm.sample_grid(24)
        p, _ = nm.evaluate(g.elem, g.eta, g.zeta)
        err = np.abs(np.linalg.norm(p, axis=1) - Rs).max()
        h = np.linalg.norm(x[0] - x[2])
        assert 0.8 <= err / (C * h ** 4 * patch_curvature(1 / Rs, 1 / Rs) ** 3) <= 1.2
        assert err > 3 * C * h ** 4 / Rs ** 3


def test_turn_cap():
    """No edge turns the normal by more than MAX_TURN (60 degrees): on R 1 at t = 0.05 the law
    alone gives h = 1.56 (89 degrees); the cap gives pi / 3. Large radii keep the law."""
    h = edge_length_for_tolerance(0.05, np.array([1.0, 0.01]), 100.0, MAX_TURN)
    law = (0.05 / C) ** 0.25
    assert law > math.pi / 3
    assert h[0] == pytest.approx(math.pi / 3)
    assert h[1] == pytest.approx((0.05 / (C * 1e-6)) ** 0.25)


def test_normal_turn_of_elements():
    """`refine._normal_turn`: the largest angle between an element's corner normals."""
    from cadbridge.tool.refine import _normal_turn

    x = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    ang = np.radians([0.0, 70.0, 10.0, 0.0])
    n = np.stack([np.sin(ang), np.zeros(4), np.cos(ang)], -1)
    nm = NagataMesh(x, np.array([[0, 1, 2, 3]]), n)
    assert _normal_turn(nm)[0] == pytest.approx(np.radians(70.0))


def test_marks_reach_the_border_of_a_mapped_face():
    """A mark inside a mapped face must reach its boundary curves (their divisions set the
    face's grid): `refine._mapped_border_marks` puts the marked quad's edge lengths times the
    factor on the border edges parallel to them. Reference: the U-shape die's mapped R 5
    shoulder (2 x n quads), its border found independently as the edges of one element."""
    from pathlib import Path

    from cadbridge.tool.refine import _mapped_border_marks, refine_mesh

    r = refine_mesh(Path(__file__).parents[2] / "iges_samples" / "ushape_die_nurbs.igs", 0.05)
    t = r.tools[0]
    conn = np.concatenate([np.asarray(b.data) for b in t.mesh.cells])
    x = t.mesh.nodes
    for f in np.unique(t.element_face):
        own = np.flatnonzero(t.element_face == f)
        el = own[len(own) // 2]
        pts, hs = _mapped_border_marks(t, np.array([el]), np.array([0.5]))
        assert len(pts) > 0  # every face of this die is mapped
        c = x[conn[el]]
        lengths = np.linalg.norm(np.roll(c, -1, axis=0) - c, axis=1)
        assert np.all(np.isin(np.round(hs, 9), np.round(0.5 * lengths, 9)))
        e = np.sort(np.stack([conn[own], np.roll(conn[own], -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
        u, cnt = np.unique(e, axis=0, return_counts=True)
        mids = 0.5 * (x[u[cnt == 1, 0]] + x[u[cnt == 1, 1]])
        assert len(mids) == len(pts) and np.allclose(np.sort(mids, axis=0), np.sort(pts, axis=0))


def test_border_marks_with_a_triangle_block_in_the_mesh():
    """The production die's adaptive meshes hold a block of triangles beside the quads; the
    border marks of its mapped faces must not depend on that. Reference: the marks of the
    U-shape die's all-quad tool, against the same tool with one face's quads split into a
    triangle block put first (its own marks: none, it is no grid any more)."""
    from pathlib import Path
    from types import SimpleNamespace

    from cadbridge.tool.refine import _mapped_border_marks, refine_mesh

    r = refine_mesh(Path(__file__).parents[2] / "iges_samples" / "ushape_die_nurbs.igs", 0.05)
    t = r.tools[0]
    conn = np.concatenate([np.asarray(b.data) for b in t.mesh.cells])
    ef = np.asarray(t.element_face)
    faces = np.unique(ef)
    split = faces[0]
    keep = np.flatnonzero(ef != split)
    q = conn[ef == split]
    tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    mixed = SimpleNamespace(
        mesh=SimpleNamespace(nodes=t.mesh.nodes, cells=[SimpleNamespace(type="triangle", data=tris),
                                                        SimpleNamespace(type="quad", data=conn[keep])]),
        element_face=np.concatenate([np.full(len(tris), split), ef[keep]]))
    for f in faces[1:]:
        el = np.flatnonzero(ef == f)[0]
        ref = _mapped_border_marks(t, np.array([el]), np.array([0.5]), np.array([1.0]))
        got = _mapped_border_marks(mixed, np.array([len(tris) + np.searchsorted(keep, el)]), np.array([0.5]),
                                   np.array([1.0]))
        assert len(ref[0]) > 0 and np.array_equal(ref[0], got[0]) and np.array_equal(ref[1], got[1])
    el = np.array([0, 1])  # triangles of the split face
    assert len(_mapped_border_marks(mixed, el, np.array([0.5, 0.5]), np.array([1.0, 1.0]))[0]) == 0


def test_strip_marks_cover_a_narrow_unmapped_face_only():
    """`refine.strip_marks`: a marked quad of a face narrower than STRIP_ELEMENTS of the sizes
    asked (width 2 A / P) marks every element of that face; a wide face gets nothing.
    Reference: flat rectangles of 2 x 2 quads, 1 x 20 (width 2 A / P = 160 / 84) and
    20 x 20 (width 20), whose element sizes are their edge length 2."""
    from types import SimpleNamespace

    from cadbridge.nagata import NagataMesh
    from cadbridge.tool.refine import STRIP_ELEMENTS, strip_marks

    def plate(nu, nv):
        gx, gy = np.meshgrid(np.arange(nu + 1) * 2.0, np.arange(nv + 1) * 2.0, indexing="ij")
        x = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
        idx = np.arange(x.shape[0]).reshape(nu + 1, nv + 1)
        q = np.array([[idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]] for i in range(nu) for j in range(nv)])
        n = np.tile([0.0, 0.0, 1.0], (len(x), 1))
        return SimpleNamespace(mesh=SimpleNamespace(nodes=x, cells=[SimpleNamespace(type="quad", data=q)]),
                               element_face=np.zeros(len(q), dtype=int), nagata=NagataMesh(x, q, n))

    assert 160 / 84 < STRIP_ELEMENTS * 1.2 < 20  # the size asked: 0.6 x 2
    strip = plate(20, 1)
    pts, hs = strip_marks(strip, np.array([7]), np.array([0.6]), np.array([1.2]))
    assert len(pts) > 0 and np.allclose(hs, 1.2)
    cen = strip.mesh.nodes[strip.mesh.cells[0].data].mean(axis=1)
    d = np.linalg.norm(cen[:, None, :] - pts[None], axis=2).min(axis=1)
    assert d.max() < 1e-9  # every element's centroid carries a mark (its ball's centre)
    wide = plate(20, 20)
    assert len(strip_marks(wide, np.array([7]), np.array([0.6]), np.array([1.2]))[0]) == 0
    short = plate(4, 1)  # narrow but short: 8 x 2, P^2 / 4 A = 400 / 64 < STRIP_ASPECT
    assert len(strip_marks(short, np.array([1]), np.array([0.6]), np.array([1.2]))[0]) == 0
