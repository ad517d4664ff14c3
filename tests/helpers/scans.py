"""A synthetic scan of the U-shape die (iges_samples/ushape_die_nurbs.igs) for the fitting
tests and benchmarks (tests/fitting, benchmarks/bench_fit.py, bench_fit_ab.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import cadbridge
from cadbridge.fitting.surface_fit import join_strip

DIE = Path(__file__).resolve().parents[2] / "iges_samples" / "ushape_die_nurbs.igs"


def die_scan(n: int, sigma: float = 0.01, outliers: float = 0.02, seed: int = 0):
    """Scan-like points of the die face: uniform by area, Gaussian noise along the normal, a
    fraction of outliers up to 1 mm, no points in a 20 mm hole in the land (x = 120, y = 10.25)."""
    model = cadbridge.read_iges(DIE)
    strip = join_strip([f.surface for f in model.faces])
    rng = np.random.default_rng(seed)
    u0, u1, v0, v1 = strip.domain
    u, v = rng.uniform(u0, u1, 2 * n), rng.uniform(v0, v1, 2 * n)
    x = strip.evaluate(u, v)
    keep = ~((np.abs(x[:, 2]) < 1e-9) & ((x[:, 0] - 120.0) ** 2 + (x[:, 1] - 10.25) ** 2 < 10.0**2))
    u, v, x = u[keep][:n], v[keep][:n], x[keep][:n]
    nrm = strip.normal(u, v)
    x = x + sigma * rng.standard_normal(n)[:, None] * nrm
    bad = rng.random(n) < outliers
    x[bad] += rng.uniform(-1.0, 1.0, bad.sum())[:, None] * nrm[bad]
    return model, strip, x, bad
