"""The test surfaces of Herrero Adan & Cardoso (2020), appendix D, as NURBS surfaces.

Tables D.2-D.3 (Ex. 7.1, one distorted surface) and D.5-D.10 (Ex. 7.2, three contiguous
surfaces). Control points are printed [i, j] with i along xi (u, n rows) and j along eta
(v, m columns), the layout `NurbsSurface` takes.

Printed values kept / corrected (docs/qit.md):

* Table D.10 (top surface), middle row: printed weights (0.707, 0.50, 0.707, 0.707, 1)
  break the 90-degree elbow its control points describe (row 1 and row 3 are semicircles
  of radius 20, row 2 their corner points); the elbow needs row 1's weights times 0.707:
  (0.707, 0.5, 0.707, 0.5, 0.707). Those two are taken as typos and corrected.
* Table D.3 (Ex. 7.1) row 4, column 1: weight 6 is kept as printed (a valid positive
  weight; the example is built to distort the parametrisation). ``fix_71=True`` uses 1.
* 0.707 is kept as printed (not sqrt(2)/2): the three surfaces of Ex. 7.2 share their
  edges exactly either way, since they print the same weights on both sides.
"""

from __future__ import annotations

import numpy as np

from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["example_71", "example_72"]


def _surf(p, q, ku, kv, rows) -> NurbsSurface:
    a = np.array(rows, dtype=float)  # (n, m, 4): x, y, z, w
    return NurbsSurface(p, q, ku, kv, a[..., :3], a[..., 3])


def example_71(fix_71: bool = False) -> NurbsSurface:
    """Ex. 7.1 (Tables D.2, D.3): n = 6, m = 5, p = q = 2."""
    w = 1.0 if fix_71 else 6.0
    rows = [
        [(0, 0, -90, 1), (0, 0, 0, 0.707), (0, 30, 0, 1), (0, 60, 0, 0.707), (0, 60, -30, 1)],
        [(30, 0, -15, 1), (30, 15, 0, 1), (30, 30, 0, 1), (30, 45, 0, 1), (30, 60, -15, 1)],
        [(95, 0, 0, 1), (95, 15, 0, 1), (95, 30, 0, 1), (95, 45, 0, 1), (95, 60, 0, 1)],
        [(150, 0, 0, w), (137.5, 15, 0, 1), (125, 30, 0, 1), (112.5, 45, 0, 1), (100, 60, 0, 1)],
        [(150, 65, 0, 1), (137.5, 65, 0, 1), (125, 65, 0, 1), (112.5, 65, 0, 1), (100, 65, 0, 1)],
        [(150, 100, 0, 1), (137.5, 100, 0, 1), (125, 100, 0, 1), (112.5, 100, 0, 1), (100, 100, 0, 1)],
    ]
    return _surf(2, 2, [0, 0, 0, 0.25, 0.5, 0.75, 1, 1, 1], [0, 0, 0, 0.5, 0.5, 1, 1, 1], rows)


def example_72() -> list[NurbsSurface]:
    """Ex. 7.2 (Tables D.5-D.10): bottom, mid and top surfaces."""
    bottom = _surf(2, 2, [0, 0, 0, 1, 1, 1], [0, 0, 0, 0.5, 0.5, 1, 1, 1], [
        [(108, 40, 0, 1), (108, -28, 0, 0.707), (40, -28, 0, 1), (-28, -28, 0, 0.707), (-28, 40, 0, 1)],
        [(80, 40, 75, 1), (80, 0, 75, 0.707), (40, 0, 75, 1), (0, 0, 75, 0.707), (0, 40, 75, 1)],
        [(80, 40, 150, 1), (80, 0, 150, 0.707), (40, 0, 150, 1), (0, 0, 150, 0.707), (0, 40, 150, 1)],
    ])
    mid = _surf(2, 1, [0, 0, 0, 0.5, 0.5, 1, 1, 1], [0, 0, 1, 1], [
        [(0, 40, 150, 1), (20, 40, 150, 1)],
        [(0, 0, 150, 0.707), (20, 20, 150, 0.707)],
        [(40, 0, 150, 1), (40, 20, 150, 1)],
        [(80, 0, 150, 0.707), (60, 20, 150, 0.707)],
        [(80, 40, 150, 1), (60, 40, 150, 1)],
    ])
    top = _surf(2, 2, [0, 0, 0, 1, 1, 1], [0, 0, 0, 0.5, 0.5, 1, 1, 1], [
        [(60, 40, 150, 1), (60, 20, 150, 0.707), (40, 20, 150, 1), (20, 20, 150, 0.707), (20, 40, 150, 1)],
        [(60, 40, 210, 0.707), (60, 20, 230, 0.5), (40, 20, 230, 0.707), (20, 20, 230, 0.5), (20, 40, 210, 0.707)],
        [(60, 100, 210, 1), (60, 100, 230, 0.707), (40, 100, 230, 1), (20, 100, 230, 0.707), (20, 100, 210, 1)],
    ])
    return [bottom, mid, top]
