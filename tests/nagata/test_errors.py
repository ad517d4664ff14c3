"""Error measures of thesis eqs. (14)-(17) and CAD comparison."""

import numpy as np

from cadbridge.nagata import (
    Cylinder, NagataMesh, Plane, Sphere, Torus, cad_errors, normal_error, patch_errors, radial_error,
)
from tests.helpers.nagata_shapes import octahedron_sphere

RNG = np.random.default_rng(5)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_radial_and_normal_error_analytic():
    """Eq. (16): a point at 1.01 r is +1 %; eq. (17): a normal tilted 2 deg gives 2 deg."""
    d = _unit(RNG.normal(size=(50, 3)))
    s = Sphere([1, 2, 3], 2.0)
    np.testing.assert_allclose(radial_error(np.array([1, 2, 3]) + 2.02 * d, s), 1.0, atol=1e-12)
    a = np.radians(2.0)
    perp = _unit(np.cross(d, RNG.normal(size=(50, 3))))
    np.testing.assert_allclose(normal_error(np.cos(a) * d + np.sin(a) * perp, 2 * d, Sphere([0, 0, 0], 2)), 2.0, atol=1e-10)
    c = Cylinder([0, 0, 5], [0, 0, 3], 1.5)
    th, z = RNG.uniform(0, 6.3, 50), RNG.uniform(-3, 3, 50)
    p = np.stack([1.47 * np.cos(th), 1.47 * np.sin(th), z], 1)
    np.testing.assert_allclose(radial_error(p, c), -2.0, atol=1e-12)
    t = Torus([0, 0, 0], [0, 0, 1], 2.0, 1.0)
    u, v = RNG.uniform(0, 6.3, 50), RNG.uniform(0, 6.3, 50)
    nrm = np.stack([np.cos(v) * np.cos(u), np.cos(v) * np.sin(u), np.sin(v)], 1)
    p = np.stack([2 * np.cos(u), 2 * np.sin(u), 0 * u], 1) + 1.03 * nrm
    np.testing.assert_allclose(radial_error(p, t), 3.0, atol=1e-11)
    np.testing.assert_allclose(normal_error(nrm, p, t), 0.0, atol=1e-6)
    pl = Plane([0, 0, 1], [0, 0, 1], scale=2.0)
    np.testing.assert_allclose(radial_error(np.array([[5, 4, 1.2]]), pl), 10.0, atol=1e-12)


def test_patch_errors_summary_and_cad_errors():
    """patch_errors on a grid (thesis §3.2, 100 divisions) and cad_errors with an exact
    sphere projection: shape error = r * radial error / 100, same normal error."""
    x, e, n = octahedron_sphere(4)
    nm = NagataMesh(x, e, n)
    rep = patch_errors(nm, Sphere([0, 0, 0], 1.0), 20)
    assert rep.shape.shape == (len(e) * 231,)
    h, edges = rep.summary["radial"]["histogram"]
    assert h.sum() == rep.shape.size and edges[0] == rep.shape.min() and edges[-1] == rep.shape.max()
    assert rep.summary["radial"]["max"] == rep.shape.max()

    def project(p):
        f = _unit(p)
        return f, f

    cad = cad_errors(nm, project, 20)
    np.testing.assert_allclose(cad.shape, rep.shape / 100, atol=1e-15)
    np.testing.assert_allclose(cad.normal, rep.normal, atol=1e-12)
    assert set(cad.summary) == {"shape", "normal"}


def test_mapping_access():
    """Grid and ErrorReport also behave as mappings (used by the pipeline)."""
    x, e, n = octahedron_sphere(2)
    nm = NagataMesh(x, e, n)
    g = nm.sample_grid(3)
    d = dict(g)
    assert set(d) == {"points", "normals", "elem", "eta", "zeta"} and d["points"] is g.points
    pts, nrm, el, eta, zeta = g
    assert g[0] is pts
    rep = patch_errors(nm, Sphere([0, 0, 0], 1.0), 3)
    assert rep["shape_error"] is rep.shape and rep["normal_error"] is rep.normal
