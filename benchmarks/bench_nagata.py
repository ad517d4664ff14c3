"""Time building Nagata coefficients for ~1 000 000 triangles (octahedral unit sphere,
analytic normals per node), plus the per-corner (crease-aware) path and grid evaluation.

    /work/venv/bin/python benchmarks/bench_nagata.py [n_triangles]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from cadbridge.nagata import NagataMesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # shared test geometry (tests/helpers)
from tests.helpers.nagata_shapes import sphere_triangles_fine  # noqa: E402


def best_of(fn, repeat: int = 3) -> float:
    t = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        t.append(time.perf_counter() - t0)
    return min(t)


def main() -> None:
    n_target = int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000
    x, e, n = sphere_triangles_fine(n_target)
    ne = len(e)
    print(f"mesh: {ne} triangles, {len(x)} nodes")
    t = best_of(lambda: NagataMesh(x, e, n))
    print(f"NagataMesh, node normals      : {t:.3f} s  -> {ne / t:,.0f} triangles/s")
    corner = n[e]
    t = best_of(lambda: NagataMesh(x, e, corner), 2)
    print(f"NagataMesh, corner normals    : {t:.3f} s  -> {ne / t:,.0f} triangles/s (global edges, crease test)")
    nm = NagataMesh(x, e, n)
    m = 2_000_000
    rng = np.random.default_rng(0)
    el = rng.integers(0, ne, m)
    eta = rng.uniform(0, 1, m)
    zeta = eta * rng.uniform(0, 1, m)
    t = best_of(lambda: nm.evaluate(el, eta, zeta))
    print(f"evaluate (points + normals)   : {t:.3f} s  -> {m / t:,.0f} points/s")


if __name__ == "__main__":
    main()
