"""The compiled patch evaluation `eval_rows` against the vectorised formulas.

Reference: `tri_eval` / `quad_eval` (thesis eqs. 4, 7-9, 12, 13 written as numpy sums) on the
gathered coefficients, and the patches' corners: a patch passes through its corner nodes
(eta, zeta at the parameter-domain corners).
"""

from __future__ import annotations

import numpy as np
import pytest

from cadbridge.nagata.patch import eval_rows, quad_coefficients, quad_eval, tri_coefficients, tri_eval


@pytest.mark.parametrize("kind", ["tri", "quad"])
@pytest.mark.parametrize("order", [0, 1, 2])
def test_eval_rows_matches_the_formulas(kind, order):
    rng = np.random.default_rng(7)
    p = 50
    cf = rng.normal(size=(p, 6 if kind == "tri" else 8, 3))
    m = 400
    loc = rng.integers(0, p, m)
    eta = rng.random(m)
    zeta = rng.random(m) * (eta if kind == "tri" else 1.0)
    rows = np.sort(rng.choice(m, 300, replace=False))
    out = tuple(np.full((m, 3), np.nan) for _ in range({0: 1, 1: 3, 2: 6}[order]))
    eval_rows(cf, loc, eta, zeta, rows, out)
    ref = (tri_eval if kind == "tri" else quad_eval)(cf[loc[rows]], eta[rows], zeta[rows], order)
    for o, r in zip(out, ref):
        np.testing.assert_allclose(o[rows], r, rtol=1e-13, atol=1e-13)
        others = np.setdiff1d(np.arange(m), rows)
        assert np.all(np.isnan(o[others]))  # rows not asked for are left alone


def test_eval_rows_passes_through_the_corners():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(5, 4, 3))
    c = 0.1 * rng.normal(size=(5, 4, 3))
    cf = quad_coefficients(x, c)
    loc = np.repeat(np.arange(5), 4)
    eta = np.tile([0.0, 1.0, 1.0, 0.0], 5)  # corners x00 x10 x11 x01
    zeta = np.tile([0.0, 0.0, 1.0, 1.0], 5)
    out = (np.empty((20, 3)),)
    eval_rows(cf, loc, eta, zeta, np.arange(20), out)
    np.testing.assert_allclose(out[0], x.reshape(-1, 3), atol=1e-14)
    xt = rng.normal(size=(5, 3, 3))
    cft = tri_coefficients(xt, 0.1 * rng.normal(size=(5, 3, 3)))
    loc = np.repeat(np.arange(5), 3)
    eta, zeta = np.tile([0.0, 1.0, 1.0], 5), np.tile([0.0, 0.0, 1.0], 5)  # x00 x10 x11
    out = (np.empty((15, 3)),)
    eval_rows(cft, loc, eta, zeta, np.arange(15), out)
    np.testing.assert_allclose(out[0], xt.reshape(-1, 3), atol=1e-14)
