"""Single-surface fitting (cadbridge.nurbs.fit): basis values, exact recovery, validation, smoothing,
robustness, refinement. References are stated per test."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import BSpline

from cadbridge.nurbs.basis import validate_knots
from cadbridge.nurbs.fit import FitError, bending_matrix, cox_de_boor, fit_surface, gram_matrix, uniform_knots
from cadbridge.nurbs.surface import NurbsSurface

# Krohe (2020) Table 5.1: knots U_1 = (0, 0.5, 1, 1.5, 2), degree 2; rows i = 0..4, columns k = 0, 1, 2
KROHE_TABLE_5_1 = {
    1.4: [[0, 0, 0.02], [0, 0.2, 0.66], [1, 0.8, 0.32], [0, 0, 0], [0, 0, 0]],
    1.5: [[0, 0, 0], [0, 0, 0.5], [0, 1, 0.5], [1, 0, 0], [0, 0, 0]],
    1.75: [[0, 0, 0], [0, 0, 0.125], [0, 0.5, 0.375], [1, 0.5, 0], [0, 0, 0]],
    2.0: [[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [1, 0, 0]],
}


@pytest.mark.parametrize("u", sorted(KROHE_TABLE_5_1))
def test_cox_de_boor_reproduces_krohe_table_5_1(u):
    # reference: the numbers printed in Krohe (2020) Table 5.1 (raw recursion, unclamped vector)
    got = cox_de_boor([0.0, 0.5, 1.0, 1.5, 2.0], 2, u).T
    assert np.max(np.abs(got - np.array(KROHE_TABLE_5_1[u], dtype=float))) <= 1e-12


def test_cox_de_boor_true_basis_functions_match_scipy():
    # reference: scipy.interpolate.BSpline.basis_element for every N_{i,k} whose knots t_i..t_{i+k+1}
    # all exist (the others are Krohe's truncated terms), on an unclamped, non-uniform vector
    t = np.array([0.0, 0.1, 1.0, 1.3, 2.0, 2.2, 3.0])
    for u in np.linspace(0.05, 2.95, 37):
        tab = cox_de_boor(t, 3, u)
        for k in range(4):
            for i in range(len(t) - k - 1):
                ref = BSpline.basis_element(t[i : i + k + 2], extrapolate=False)(u)
                ref = 0.0 if np.isnan(ref) else float(ref)
                assert abs(tab[k, i] - ref) <= 1e-12, (u, k, i)


def test_krohe_knot_vector_is_one_short():
    # reference: P&T eq. 2.x / Krohe's own rule 2 (m + 1 = n + p + 2 knots): 3 control points of
    # degree 2 need 6 knots; Krohe's U_1 has 5
    with pytest.raises(ValueError, match="expected 6 knots for 3 control points of degree 2, got 5"):
        validate_knots(np.array([0.0, 0.5, 1.0, 1.5, 2.0]), 2, 3)
    with pytest.raises(ValueError, match="expected 6 knots"):
        NurbsSurface(2, 2, [0, 0.5, 1, 1.5, 2], [0, 0, 0, 1, 1, 1], np.zeros((3, 3, 3)))


def test_vanishing_rational_denominator_is_an_error():
    # a weight of zero makes the denominator vanish where only that point acts: rejected, not a point at 0
    w = np.ones((3, 3))
    w[0, 0] = 0.0
    with pytest.raises(ValueError, match="weights must be finite and positive"):
        NurbsSurface(2, 2, [0, 0, 0, 1, 1, 1], [0, 0, 0, 1, 1, 1], np.zeros((3, 3, 3)), w)


def _known_bicubic(rational: bool = False):
    rng = np.random.default_rng(7)
    ku = np.r_[0, 0, 0, 0, 0.3, 0.55, 1, 1, 1, 1]
    kv = np.r_[0, 0, 0, 0, 0.5, 1, 1, 1, 1]
    g = np.meshgrid(np.linspace(0, 1, 6), np.linspace(0, 1, 5), indexing="ij")
    cp = np.zeros((6, 5, 3))
    cp[..., 0] = 10 * g[0]
    cp[..., 1] = 8 * g[1]
    cp[..., 2] = rng.standard_normal((6, 5))
    w = rng.uniform(0.6, 1.6, (6, 5)) if rational else None
    return NurbsSurface(3, 3, ku, kv, cp, w)


def _grid(n=21):
    uu, vv = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    return uu.ravel(), vv.ravel()


def test_recovers_known_bicubic_from_21x21_samples():
    # reference: the known bicubic itself (its own degree and knots; exact data) - least squares
    # must return its control points
    s = _known_bicubic()
    u, v = _grid()
    fit = fit_surface(s.evaluate(u, v), u, v, knots=(s.knots_u, s.knots_v), smoothing=0.0, robust=None,
                      refine=False, correct_parameters=False)
    assert np.max(np.abs(fit.surface.control_points - s.control_points)) <= 1e-10
    # with parameter correction on, the exact parameters stay (the projection finds the same feet)
    fit = fit_surface(s.evaluate(u, v), u, v, knots=(s.knots_u, s.knots_v), smoothing=0.0, robust=None,
                      refine=False, noise=0.0)
    assert np.max(np.abs(fit.surface.control_points - s.control_points)) <= 1e-10


def test_recovers_rational_with_weights_fixed_from_base():
    # reference: a known rational bicubic; its weights given through rational_base (control points
    # of the base are ignored: zeros), the fit must find its control points
    s = _known_bicubic(rational=True)
    base = NurbsSurface(3, 3, s.knots_u, s.knots_v, np.zeros_like(s.control_points), s.weights)
    u, v = _grid()
    fit = fit_surface(s.evaluate(u, v), u, v, rational_base=base, smoothing=0.0, robust=None, refine=False,
                      correct_parameters=False)
    assert fit.surface.rational
    assert np.max(np.abs(fit.surface.control_points - s.control_points)) <= 1e-10


def test_gram_matrices_against_quadrature_of_scipy_splines():
    # reference: scipy BSpline derivatives integrated by a fine composite Simpson rule
    from scipy.integrate import simpson

    k = np.r_[0, 0, 0, 0, 0.2, 0.7, 1, 1, 1, 1]
    n = len(k) - 4
    x = np.linspace(0, 1, 20001)
    for order in (0, 1, 2):
        g = gram_matrix(k, 3, order).toarray()
        basis = [BSpline(k, np.eye(n)[i], 3).derivative(order)(x) if order else BSpline(k, np.eye(n)[i], 3)(x)
                 for i in range(n)]
        ref = np.array([[simpson(bi * bj, x=x) for bj in basis] for bi in basis])
        assert np.allclose(g, ref, atol=1e-7 * np.abs(ref).max())


def test_bending_energy_of_a_paraboloid():
    # reference: z = a u^2 + b v^2 over [0,1]^2 has S_uu = (0,0,2a), S_vv = (0,0,2b), S_uv = 0, so
    # E = 4 a^2 + 4 b^2; a bicubic represents it exactly (interpolating a polynomial of degree 2)
    a, b = 0.7, -0.4
    ku = uniform_knots(3, 3, 0, 1)
    kv = uniform_knots(3, 2, 0, 1)
    u, v = np.meshgrid(np.linspace(0, 1, 15), np.linspace(0, 1, 15))
    u, v = u.ravel(), v.ravel()
    pts = np.column_stack([u, v, a * u**2 + b * v**2])
    fit = fit_surface(pts, u, v, knots=(ku, kv), smoothing=0.0, robust=None, refine=False, correct_parameters=False)
    z = fit.surface.control_points[..., 2].reshape(-1)
    energy = z @ (bending_matrix(ku, 3, kv, 3) @ z)
    assert energy == pytest.approx(4 * a * a + 4 * b * b, rel=1e-10)


def test_bad_input_messages():
    s = _known_bicubic()
    u, v = _grid(3)
    x = s.evaluate(u, v)
    with pytest.raises(FitError, match="fewer than the 7x7 = 49 control points"):
        fit_surface(x, u, v)
    x2 = x.copy()
    x2[4, 1] = np.nan
    with pytest.raises(FitError, match="not finite .first: point 4"):
        fit_surface(x2, u, v)
    uu, vv = _grid(21)
    with pytest.raises(FitError, match="no data under them"):
        keep = uu < 0.5  # half the net has no data and no smoothing
        fit_surface(s.evaluate(uu[keep], vv[keep]), uu[keep], vv[keep], knots=(s.knots_u, s.knots_v),
                    domain=(0, 1, 0, 1), smoothing=0.0, robust=None, refine=False)


def test_refines_to_tolerance_on_exact_data():
    # reference: the known bicubic (exact samples, 60x60); the fit must reach max deviation <= tol
    # by knot insertion from a coarse start and say so
    s = _known_bicubic()
    u, v = _grid(60)
    x = s.evaluate(u, v)
    fit = fit_surface(x, u + 0.01 * np.sin(np.pi * u) * np.sin(7 * v), v, tolerance=1e-3, noise=0.0)
    assert fit.stop == "tolerance"
    assert fit.max_deviation <= 1e-3
    # true error against the known surface at the fit's own dense samples
    from cadbridge.nurbs.project import project_to_surface

    uu, vv = fit.surface.grid(80, 80)
    res = project_to_surface(s, fit.surface.evaluate(uu, vv))
    inside = res.status == 0  # CONVERGED: an orthogonal foot inside s (the fit's rim may reach past s's edge)
    assert inside.mean() > 0.9
    assert res.distance[inside].max() <= 2e-3


def test_control_net_limit_is_reported():
    s = _known_bicubic()
    u, v = _grid(60)
    fit = fit_surface(s.evaluate(u, v), u, v, tolerance=1e-7, noise=0.0, max_ctrl=(8, 8))
    assert fit.stop == "control-net limit"
    assert fit.surface.shape[0] <= 8 and fit.surface.shape[1] <= 8


def test_tukey_ignores_outliers():
    # reference: a plane z = 0.1 x + 0.2 y; 3 % of the points moved by 1..5 units; the robust fit
    # must stay on the plane (its outliers at weight 0) while plain least squares is pulled off
    rng = np.random.default_rng(3)
    u, v = rng.random(4000), rng.random(4000)
    pts = np.column_stack([u, v, 0.1 * u + 0.2 * v])
    bad = rng.random(4000) < 0.03
    pts[bad, 2] += rng.uniform(1, 5, bad.sum())
    fit = fit_surface(pts, u, v, tolerance=1e-4, noise=0.0, refine=False, initial_spans=(3, 3))
    g_u, g_v = fit.surface.grid(30, 30)
    z = fit.surface.evaluate(g_u, g_v)
    assert np.abs(z[:, 2] - (0.1 * z[:, 0] + 0.2 * z[:, 1])).max() <= 1e-6
    assert np.array_equal(fit.outliers, bad)
    ls = fit_surface(pts, u, v, tolerance=1e-4, noise=0.0, refine=False, initial_spans=(3, 3), robust=None)
    z = ls.surface.evaluate(g_u, g_v)
    assert np.abs(z[:, 2] - (0.1 * z[:, 0] + 0.2 * z[:, 1])).max() > 1e-2


def test_smoothing_fills_a_hole_with_the_plane():
    # reference: a plane; no data in a disc; with smoothing the unconstrained control points follow
    # the minimum-bending fill, which for planar data is the plane itself
    rng = np.random.default_rng(4)
    u, v = rng.random(6000), rng.random(6000)
    keep = (u - 0.5) ** 2 + (v - 0.5) ** 2 > 0.3**2
    u, v = u[keep], v[keep]
    pts = np.column_stack([u, v, 0.3 * u - 0.1 * v + 2])
    fit = fit_surface(pts, u, v, tolerance=1e-6, noise=0.0, refine=False, initial_spans=(8, 8),
                      domain=(0, 1, 0, 1), smoothing=1e-6)
    g_u, g_v = fit.surface.grid(25, 25)
    z = fit.surface.evaluate(g_u, g_v)
    assert np.abs(z[:, 2] - (0.3 * z[:, 0] - 0.1 * z[:, 1] + 2)).max() <= 1e-8


def test_noise_estimate():
    # reference: the sigma of the Gaussian noise added to dense samples of a curved surface
    s = _known_bicubic()
    u, v = _grid(120)
    x = s.evaluate(u, v)
    from cadbridge.nurbs.fit import estimate_noise

    assert estimate_noise(x) < 1e-3
    noisy = x + 0.02 * np.random.default_rng(5).standard_normal(x.shape)
    assert estimate_noise(noisy) == pytest.approx(0.02, rel=0.15)
