"""Nagata edges and patches against the Coimbra thesis (Neto 2010, ch. 2-3) and
Nagata (2005).  Each test names the reference it reproduces."""

import numpy as np
import pytest

from cadbridge.nagata import (
    Cylinder,
    NagataMesh,
    Sphere,
    Torus,
    edge_coefficient,
    normal_error,
    patch_errors,
    radial_error,
)
from tests.helpers.nagata_shapes import (
    cylinder_quads,
    cylinder_tris,
    octahedron_sphere,
    torus_quads,
)

RNG = np.random.default_rng(1234)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ----------------------------------------------------------------------------- edge (eq. 15)
def test_edge_coefficient_matches_closed_form_eq3():
    """Nagata eq. (15) == thesis eq. (3) / Nagata eq. (11) for a != +-1, and the curve
    meets both orthogonality conditions (Nagata eq. 5a, 5b). ``bounded=False``: the formula
    as published, without the inflected-edge rule."""
    x0, x1 = RNG.normal(size=(500, 3)), RNG.normal(size=(500, 3))
    n0, n1 = _unit(RNG.normal(size=(500, 3))), _unit(RNG.normal(size=(500, 3)))
    c = edge_coefficient(x0, x1, n0, n1, bounded=False)
    d = x1 - x0
    a = np.einsum("ij,ij->i", n0, n1)
    rhs0, rhs1 = np.einsum("ij,ij->i", n0, d), -np.einsum("ij,ij->i", n1, d)
    ref = ((rhs0 - a * rhs1)[:, None] * n0 + (-a * rhs0 + rhs1)[:, None] * n1) / (1 - a * a)[:, None]
    np.testing.assert_allclose(c, ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.einsum("ij,ij->i", n0, d - c), 0, atol=1e-10)
    np.testing.assert_allclose(np.einsum("ij,ij->i", n1, d + c), 0, atol=1e-10)


def test_edge_coefficient_convex_edges_are_eq15_and_inflected_edges_bounded():
    """Inflected-edge and edge-plane rules (cadbridge.nagata.edge docs). Where the chord lies
    on opposite sides of the two tangent planes ((d.n0)(d.n1) < 0: a convex arc) c is eq.
    (15) as published without its sideways part along b = d x v; where it lies on the same
    side (an inflection between the ends, thesis §6.2.2) the unbounded (d.v / dc) dv term is
    dropped. References: eq. (15) itself; the S-curve y = x^3 on [-1, 1], whose end normals
    are parallel (eq. 15 divides by dc -> 0) and whose best quadratic through the ends is the
    chord (c = 0); symmetric edges of a sphere (d.v = 0), where nothing may change."""
    rng = np.random.default_rng(7)  # own generator: the module's RNG sequence stays as it was
    x0, x1 = rng.normal(size=(2000, 3)), rng.normal(size=(2000, 3))
    n0, n1 = _unit(rng.normal(size=(2000, 3))), _unit(rng.normal(size=(2000, 3)))
    d = x1 - x0
    convex = np.einsum("ij,ij->i", d, n0) * np.einsum("ij,ij->i", d, n1) < 0
    assert 500 < convex.sum() < 1500  # both kinds are exercised
    cb, cp = edge_coefficient(x0, x1, n0, n1), edge_coefficient(x0, x1, n0, n1, bounded=False)
    v, dv = 0.5 * (n0 + n1), 0.5 * (n0 - n1)
    b = _unit(np.cross(d, v))
    np.testing.assert_allclose(cb[convex], (cp - np.einsum("ij,ij->i", cp, b)[:, None] * b)[convex],
                               rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", cb, b), 0.0, atol=1e-12)
    dc = np.einsum("ij,ij->i", n0, dv)
    first = (np.einsum("ij,ij->i", d, dv) / (1 - dc))[:, None] * v
    np.testing.assert_allclose(cb[~convex], first[~convex], rtol=1e-10, atol=1e-12)
    # y = x^3 from (-1, -1) to (1, 1), normals (-3, 1)/sqrt(10) tilted by +-t: eq. (15) grows
    # like 4/t (until dc = t^2/10 falls below its threshold), the rules stay at the chord
    a, e = np.array([-1.0, -1.0, 0.0]), np.array([1.0, 1.0, 0.0])
    for t in (1e-2, 1e-3, 1e-4):
        m0 = _unit(np.array([-3.0, 1.0, t]))
        m1 = _unit(np.array([-3.0, 1.0, -t]))
        assert np.linalg.norm(edge_coefficient(a, e, m0, m1, bounded=False)) > 0.1 / t
        assert np.linalg.norm(edge_coefficient(a, e, m0, m1)) < 10 * t
    # sphere chords with exact normals: d.v = 0, the rules change nothing
    p0, p1 = _unit(rng.normal(size=(500, 3))), _unit(rng.normal(size=(500, 3)))
    np.testing.assert_allclose(edge_coefficient(p0, p1, p0, p1), edge_coefficient(p0, p1, p0, p1, bounded=False),
                               rtol=1e-12, atol=1e-14)


def test_edge_parallel_normals_exactly_straight():
    """Nagata eq. (15), singular case c = +-1: parallel normals give c = 0 bitwise,
    so planar edges stay straight (thesis §3.2.1)."""
    x0, x1 = RNG.normal(size=(100, 3)), RNG.normal(size=(100, 3))
    n = _unit(RNG.normal(size=(100, 3)))
    c = edge_coefficient(x0, x1, n, n)
    assert np.all(c == 0.0)
    # opposite normals: the v term is dropped, the dv term keeps d.v information (finite)
    c2 = edge_coefficient(x0, x1, n, -n)
    assert np.all(np.isfinite(c2))


def test_edge_near_parallel_graceful():
    """Nagata §2.1.1: decoupled thresholds keep c bounded as the normals become parallel."""
    d = np.array([1.0, 0, 0])
    for t in [1e-3, 1e-6, 1e-9, 1e-12, 1e-15]:
        n0 = _unit(np.array([t, 0.3 * t, 1.0]))
        n1 = _unit(np.array([-t, 0.1 * t, 1.0]))
        c = edge_coefficient(np.zeros(3), d, n0, n1)
        assert np.all(np.isfinite(c)) and np.linalg.norm(c) < 10 * max(t, 1e-12)


def test_edge_reversal_invariant():
    """Reversing an edge leaves c unchanged (same equations, Nagata eq. 6)."""
    x0, x1 = RNG.normal(size=(200, 3)), RNG.normal(size=(200, 3))
    n0, n1 = _unit(RNG.normal(size=(200, 3))), _unit(RNG.normal(size=(200, 3)))
    np.testing.assert_allclose(edge_coefficient(x0, x1, n0, n1), edge_coefficient(x1, x0, n1, n0),
                               rtol=1e-10, atol=1e-10)


# ----------------------------------------------------------------------------- 2D arc (§3.1.1)
def _arc(n_el, n_samples=100):
    th = np.linspace(0, np.pi / 2, n_el + 1)
    x = np.stack([np.cos(th), np.sin(th), 0 * th], 1)
    c = edge_coefficient(x[:-1], x[1:], x[:-1], x[1:])  # exact normals = positions (unit circle)
    xi = np.linspace(0, 1, n_samples + 1)[None, :, None]
    d = (x[1:] - x[:-1])[:, None]
    pts = x[:-1, None] + (d - c[:, None]) * xi + c[:, None] * xi ** 2
    tan = d + (2 * xi - 1) * c[:, None]  # eq. 2
    nrm = _unit(np.cross(tan, [0, 0, 1.0]))  # in-plane normal, outward for CCW arc
    circ = Cylinder([0, 0, 0], [0, 0, 1], 1.0)
    rad = radial_error(pts.reshape(-1, 3), circ).reshape(n_el, -1)
    ang = normal_error(nrm.reshape(-1, 3), pts.reshape(-1, 3), circ).reshape(n_el, -1)
    return rad, ang, np.linalg.norm(d[:, 0], axis=1).max()


def test_arc_quarter_circle_thesis_fig8_fig9():
    """Thesis §3.1.1: Nagata curve of a unit quarter circle with 1 and 2 elements.
    Max normal error 6.6 deg for 1 element (Fig. 9 text); curve always outside the circle
    with max radial error at xi = 0.5 (Fig. 8a); 2 elements an order of magnitude lower;
    normal error zero at xi = 0.5 and at the nodes; Nagata with 1 element similar to the
    polyhedral model with 2 elements (7.6 %)."""
    rad1, ang1, _ = _arc(1)
    rad2, ang2, _ = _arc(2)
    assert round(ang1.max(), 1) == 6.6
    assert rad1.min() > -1e-12 and rad2.min() > -1e-12
    assert np.argmax(rad1[0]) == 50 and np.argmax(rad2[0]) == 50
    assert ang1[0, 50] < 1e-12 and ang1[0, 0] < 1e-12 and ang1[0, -1] < 1e-12
    assert 8 < rad1.max() / rad2.max() < 20  # "an order of magnitude lower"
    poly2 = (1 - np.cos(np.pi / 8)) * 100  # polyhedral, 2 elements: 7.61 %
    assert 0.7 < rad1.max() / poly2 < 1.0
    # 2 elements per quarter == cylinder quad mesh 1 cross-section (thesis §3.2.2.2): 0.314 %
    assert round(rad2.max(), 3) == 0.314


def _slope(h, err):
    return np.polyfit(np.log(h), np.log(err), 1)[0]


def test_arc_convergence_orders():
    """Thesis Figs. 8b, 9b: radial error quartic, normal error cubic in the edge length;
    polyhedral (chord) radial error quadratic."""
    hs, er, en, ep = [], [], [], []
    for n in (4, 8, 16, 32, 64):
        rad, ang, h = _arc(n)
        hs.append(h)
        er.append(np.abs(rad).max())
        en.append(ang.max())
        ep.append((1 - np.cos(np.pi / 4 / n)) * 100)
    assert abs(_slope(hs, er) - 4) < 0.3
    assert abs(_slope(hs, en) - 3) < 0.3
    assert abs(_slope(hs, ep) - 2) < 0.3


def test_sphere_convergence_orders():
    """Nagata (2005) Fig. 9 / thesis §3.2.3: on octahedral sphere meshes the Nagata radial
    error converges quartically, the normal error cubically, the polyhedral mesh quadratically."""
    sph = Sphere([0, 0, 0], 1.0)
    hs, er, en, ep = [], [], [], []
    for k in (4, 8, 16, 32):
        x, e, n = octahedron_sphere(k)
        rep = patch_errors(NagataMesh(x, e, n), sph, 10)
        hs.append(np.linalg.norm(x[e] - x[np.roll(e, -1, 1)], axis=2).max())
        er.append(np.abs(rep.shape).max())
        en.append(rep.normal.max())
        # polyhedral: flat facets sampled at the same parameters
        flat = NagataMesh(x, e, np.broadcast_to([0, 0, 1.0], x.shape))
        pts = flat.sample_grid(10).points
        ep.append(np.abs(radial_error(pts, sph)).max())
    assert abs(_slope(hs, er) - 4) < 0.3
    assert abs(_slope(hs, en) - 3) < 0.3
    assert abs(_slope(hs, ep) - 2) < 0.3


# ----------------------------------------------------------------------------- plane (§3.2.1)
def _plane_mesh(quads=True):
    x, q, _ = cylinder_quads(4, 3)  # just for indices; build a unit square 3x3 instead
    g = np.linspace(0, 1, 4)
    X, Y = np.meshgrid(g, g, indexing="ij")
    nodes = np.stack([X.ravel(), Y.ravel(), 0 * X.ravel()], 1)
    i, j = np.meshgrid(np.arange(3), np.arange(3), indexing="ij")
    i, j = i.ravel(), j.ravel()
    nid = lambda a, b: a * 4 + b  # noqa: E731
    quad = np.stack([nid(i, j), nid(i + 1, j), nid(i + 1, j + 1), nid(i, j + 1)], 1)
    return nodes, quad


def test_plane_exact_linear_interpolation():
    """Thesis §3.2.1 eqs. (18), (19): with all-parallel normals the Nagata patch is the
    linear (triangle) / bilinear (quadrilateral) interpolation and reproduces the plane."""
    nodes, quad = _plane_mesh()
    nodes = nodes + np.array([0, 0, 0.5]) + RNG.normal(scale=0.05, size=nodes.shape) * [1, 1, 0]
    normals = np.broadcast_to([0, 0, 1.0], nodes.shape)
    nm = NagataMesh(nodes, quad, normals)
    g = nm.sample_grid(10)
    x = nodes[quad[g.elem]]
    e, z = g.eta[:, None], g.zeta[:, None]
    bil = x[:, 0] + (x[:, 1] - x[:, 0]) * e + (x[:, 3] - x[:, 0]) * z + (x[:, 2] - x[:, 1] - x[:, 3] + x[:, 0]) * e * z
    np.testing.assert_allclose(g.points, bil, atol=1e-15)
    assert np.all(g.points[:, 2] == 0.5)
    assert np.all(nm.coefficients[:, 4:] == 0)  # c20 c02 c21 c12 null (thesis §3.2.1)
    tri = np.concatenate([quad[:, [0, 1, 2]], quad[:, [0, 2, 3]]])
    nt = NagataMesh(nodes, tri, normals)
    g = nt.sample_grid(10)
    x = nodes[tri[g.elem]]
    lin = x[:, 0] + (x[:, 1] - x[:, 0]) * g.eta[:, None] + (x[:, 2] - x[:, 1]) * g.zeta[:, None]
    np.testing.assert_allclose(g.points, lin, atol=1e-15)
    assert np.all(g.points[:, 2] == 0.5)
    np.testing.assert_allclose(g.normals, np.broadcast_to([0, 0, 1.0], g.normals.shape), atol=1e-15)


def test_linear_edge_of_curved_patch_is_straight():
    """Nagata §2.1.1: an edge whose normals are parallel and orthogonal to it is exact."""
    x, q, n = cylinder_quads(8, 1)
    nm = NagataMesh(x, q, n)
    # axial edges (local edges 1 and 3 of every quad) have parallel radial normals
    np.testing.assert_array_equal(nm.quad_edge_coefficients[:, [1, 3]], 0.0)


# ----------------------------------------------------------------------------- cylinder (§3.2.2)
@pytest.mark.parametrize(
    "n_around, gen, n_el, n_nodes, max_edge, max_area",
    [
        (8, cylinder_tris, 96, 56, 0.765, 0.135),
        (12, cylinder_tris, 144, 84, 0.667, 0.090),
        (8, cylinder_quads, 24, 32, 0.765, 0.510),
        (12, cylinder_quads, 36, 48, 0.667, 0.345),
    ],
)
def test_cylinder_table1(n_around, gen, n_el, n_nodes, max_edge, max_area):
    """Thesis Table 1: element/node counts, maximum edge length, maximum element area."""
    x, e, _ = gen(n_around, 3)
    assert len(e) == n_el and len(x) == n_nodes
    assert round(np.linalg.norm(x[e] - x[np.roll(e, -1, 1)], axis=2).max(), 3) == max_edge
    if e.shape[1] == 3:
        # our centre node (mid angle, mid height, on the surface) gives 0.131 / 0.088, not the
        # printed 0.135 / 0.090: GiD's centre node placement is not documented; the error
        # maxima (test below) match the thesis to the printed digits nevertheless.
        area = 0.5 * np.linalg.norm(np.cross(x[e[:, 1]] - x[e[:, 0]], x[e[:, 2]] - x[e[:, 0]]), axis=1)
        assert abs(area.max() - max_area) < 0.005
    else:
        area = 0.5 * np.linalg.norm(np.cross(x[e[:, 2]] - x[e[:, 0]], x[e[:, 3]] - x[e[:, 1]]), axis=1)
        assert round(area.max(), 3) == max_area


@pytest.mark.parametrize(
    "n_around, gen, rad_max, nrm_max, nrm_digits",
    [
        (8, cylinder_quads, 0.314, 0.703, 3),  # §3.2.2.2
        (12, cylinder_quads, 0.060, 0.202, 3),
        (8, cylinder_tris, 0.314, 1.10, 2),  # §3.2.2.1
        (12, cylinder_tris, 0.060, 0.25, 2),
    ],
)
def test_cylinder_thesis_errors(n_around, gen, rad_max, nrm_max, nrm_digits):
    """Thesis §3.2.2 (Figs. 13, 16): max radial error 0.314 % / 0.060 % and max normal
    error 0.703 deg / 0.202 deg (quads), 1.10 deg / 0.25 deg (triangles); 100 divisions
    per parameter; radial error always >= 0 (Nagata patches outside the cylinder)."""
    x, e, n = gen(n_around, 3)
    rep = patch_errors(NagataMesh(x, e, n), Cylinder([0, 0, 0], [0, 0, 1], 1.0), 100)
    assert round(rep.summary["radial"]["max"], 3) == rad_max
    assert round(rep.summary["normal"]["max"], nrm_digits) == nrm_max
    assert rep.summary["radial"]["min"] > -1e-12


# ----------------------------------------------------------------------------- sphere (§3.2.3)
@pytest.mark.parametrize(
    "k, n_el, n_nodes, max_edge, rmax, rmin, nmax",
    [(2, 32, 18, 1.00, 1.03, -0.21, 5.1), (3, 72, 38, 0.707, 0.22, -0.01, 1.5)],
)
def test_sphere_triangles_table2(k, n_el, n_nodes, max_edge, rmax, rmin, nmax):
    """Thesis Table 2 and §3.2.3.1: triangular sphere meshes 1 and 2 (2 / 3 elements per
    quarter arc, arc nodes equally spaced): radial error 1.03 %..-0.21 % and
    0.22 %..-0.01 %, max normal error 5.1 deg and 1.5 deg."""
    x, e, n = octahedron_sphere(k, equal_angle=True)
    assert len(e) == n_el and len(x) == n_nodes
    assert round(np.linalg.norm(x[e] - x[np.roll(e, -1, 1)], axis=2).max(), 3) == max_edge
    rep = patch_errors(NagataMesh(x, e, n), Sphere([0, 0, 0], 1.0), 100)
    # mesh 1 gives 1.0363 (printed 1.03: truncated, or a grid missing the exact maximum)
    assert abs(rep.summary["radial"]["max"] - rmax) < 0.01
    assert round(rep.summary["radial"]["min"], 2) == rmin
    assert round(rep.summary["normal"]["max"], 1) == nmax


# ----------------------------------------------------------------------------- torus (§3.2.4)
def test_torus_quads_mesh1():
    """Thesis Table 3 / §3.2.4.2: quadrilateral torus mesh 1 (R=2, r=1, 8x8): 64 elements,
    64 nodes, max edge 2.3; radial error -2.42 %..2.36 %, max normal error 9.1 deg."""
    x, e, n = torus_quads(8, 8)
    assert len(e) == 64 and len(x) == 64
    assert round(np.linalg.norm(x[e] - x[np.roll(e, -1, 1)], axis=2).max(), 1) == 2.3
    rep = patch_errors(NagataMesh(x, e, n), Torus([0, 0, 0], [0, 0, 1], 2.0, 1.0), 100)
    assert round(rep.summary["radial"]["max"], 2) == 2.36
    assert round(rep.summary["radial"]["min"], 2) == -2.42
    assert round(rep.summary["normal"]["max"], 1) == 9.1


# ----------------------------------------------------------------------------- evaluation
def _mixed_mesh():
    x, q, n = cylinder_quads(12, 4)
    tris = np.concatenate([q[::2][:, [0, 1, 2]], q[::2][:, [0, 2, 3]]])
    return x, [q[1::2], tris], n


def test_derivatives_match_finite_differences():
    """Thesis eqs. (7), (8), (12), (13) against central differences; normals follow the winding."""
    x, blocks, n = _mixed_mesh()
    nm = NagataMesh(x, blocks, n)
    m = 400
    elem = RNG.integers(0, nm.n_elements, m)
    eta = RNG.uniform(0.2, 0.8, m)
    zeta = np.where(nm.element_kind[elem] == 3, eta * RNG.uniform(0.1, 0.9, m), RNG.uniform(0.1, 0.9, m))
    p, de, dz = nm.derivatives(elem, eta, zeta)
    h = 1e-6
    fe = (nm.evaluate(elem, eta + h, zeta)[0] - nm.evaluate(elem, eta - h, zeta)[0]) / (2 * h)
    fz = (nm.evaluate(elem, eta, zeta + h)[0] - nm.evaluate(elem, eta, zeta - h)[0]) / (2 * h)
    np.testing.assert_allclose(de, fe, atol=1e-8)
    np.testing.assert_allclose(dz, fz, atol=1e-8)
    _, nrm = nm.evaluate(elem, eta, zeta)
    radial = p * [1, 1, 0]
    assert np.all(np.einsum("ij,ij->i", nrm, radial) > 0.99 * np.linalg.norm(radial, axis=1))


def test_mixed_mesh_numbering_and_vertices():
    """Mixed blocks: global numbering follows the blocks; every patch interpolates its nodes."""
    x, blocks, n = _mixed_mesh()
    nm = NagataMesh(x, blocks, n)
    assert nm.n_elements == len(blocks[0]) + len(blocks[1])
    assert np.all(nm.element_kind[: len(blocks[0])] == 4) and np.all(nm.element_kind[len(blocks[0]):] == 3)
    with pytest.raises(ValueError):
        nm.coefficients
    assert nm.quad_coefficients.shape == (len(blocks[0]), 8, 3)
    assert nm.tri_coefficients.shape == (len(blocks[1]), 6, 3)
    # corners: quads (0,0),(1,0),(1,1),(0,1); triangles (0,0),(1,0),(1,1)
    qe = np.repeat(np.arange(len(blocks[0])), 4)
    p, _ = nm.evaluate(qe, np.tile([0, 1, 1, 0.0], len(blocks[0])), np.tile([0, 0, 1, 1.0], len(blocks[0])))
    np.testing.assert_allclose(p, x[blocks[0].ravel()], atol=1e-15)
    te = len(blocks[0]) + np.repeat(np.arange(len(blocks[1])), 3)
    p, _ = nm.evaluate(te, np.tile([0, 1, 1.0], len(blocks[1])), np.tile([0, 0, 1.0], len(blocks[1])))
    np.testing.assert_allclose(p, x[blocks[1].ravel()], atol=1e-15)


def test_c0_between_patches():
    """Nagata §2.2: adjacent patches share the edge curve (C0) with per-node normals."""
    x, e, n = octahedron_sphere(5)
    x = x + RNG.normal(scale=0.01, size=x.shape)
    n = _unit(n + RNG.normal(scale=0.05, size=n.shape))
    nm = NagataMesh(x, e, n)
    v, t = nm.refined_triangulation(6)
    # refined triangulation evaluates shared edge points from one patch; compare with the other
    g = nm.sample_grid(6)
    from scipy.spatial import cKDTree
    dist, _ = cKDTree(v).query(g.points)
    assert dist.max() < 1e-13


def test_sample_grid_and_refined_triangulation_watertight():
    """Grid sizes; refined triangulation of a closed sphere is a closed 2-manifold
    (Euler characteristic 2, every edge in exactly 2 triangles, consistent orientation)."""
    x, e, n = octahedron_sphere(3)
    nm = NagataMesh(x, e, n)
    g = nm.sample_grid(4)
    assert len(g.points) == len(e) * 15
    v, t = nm.refined_triangulation(4)
    assert len(t) == len(e) * 16
    ed = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    _, cnt = np.unique(ed, axis=0, return_counts=True)
    assert np.all(cnt == 2)
    assert len(v) - len(cnt) + len(t) == 2
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    assert len(np.unique(directed, axis=0)) == len(directed)  # consistent orientation
    fn = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    assert np.all(np.einsum("ij,ij->i", fn, v[t].mean(1)) > 0)  # outward
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1, atol=0.01)


def test_closest_point_on_sphere_patches():
    """Closest point (Newton + neighbour walk): foot is on the patch, orthogonality
    residual vanishes, and it is at least as close as a dense brute-force sample."""
    x, e, n = octahedron_sphere(4)
    nm = NagataMesh(x, e, n)
    p = _unit(RNG.normal(size=(300, 3))) * RNG.uniform(0.7, 1.3, (300, 1))
    cp = nm.closest_point(p)
    xx, _ = nm.evaluate(cp.elem, cp.eta, cp.zeta)
    np.testing.assert_allclose(xx, cp.foot, atol=1e-14)
    np.testing.assert_allclose(cp.dist, np.linalg.norm(p - cp.foot, axis=1), atol=1e-14)
    dense = nm.sample_grid(40).points
    from scipy.spatial import cKDTree
    dd, _ = cKDTree(dense).query(p)
    assert np.all(cp.dist <= dd + 1e-12)
    # stationarity where the foot is interior to its patch
    _, de, dz = nm.derivatives(cp.elem, cp.eta, cp.zeta)
    inner = (cp.zeta > 1e-9) & (cp.eta < 1 - 1e-9) & (cp.eta - cp.zeta > 1e-9)
    r = p - cp.foot
    assert inner.mean() > 0.8
    assert np.abs(np.einsum("ij,ij->i", r, de)[inner]).max() < 1e-10
    assert np.abs(np.einsum("ij,ij->i", r, dz)[inner]).max() < 1e-10
    # points on the surface project onto themselves
    g = nm.sample_grid(3)
    cp2 = nm.closest_point(g.points)
    assert cp2.dist.max() < 1e-12


def test_closest_point_walks_to_neighbour():
    """Newton started on the wrong patch crosses the shared edge to the right one."""
    x, e, n = cylinder_quads(8, 3)
    nm = NagataMesh(x, e, n)
    # targets right next to the node rows, just off the surface
    th = 2 * np.pi * (np.arange(8) + 0.97) / 8
    p = np.stack([1.05 * np.cos(th), 1.05 * np.sin(th), np.full(8, 0.4)], 1)
    cp = nm.closest_point(p)
    o, nrm, _ = Cylinder([0, 0, 0], [0, 0, 1], 1.0).frame(p)
    # the foot lies on the radial line through p (symmetry of the cylinder patches is only
    # approximate, so compare with the analytic answer loosely and the residual tightly)
    _, de, dz = nm.derivatives(cp.elem, cp.eta, cp.zeta)
    r = p - cp.foot
    assert np.abs(np.einsum("ij,ij->i", r, de)).max() < 1e-10
    assert np.abs(np.einsum("ij,ij->i", r, dz)).max() < 1e-10
    assert np.all(cp.dist < 0.06)
