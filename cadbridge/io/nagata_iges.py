"""Exact export of Nagata patches as biquadratic Bézier (NURBS) surfaces and IGES 128 files.

Parameter maps (u, v) in [0, 1]^2 -> patch parameters (eta, zeta):

* quadrilateral patch: eta = u, zeta = v.
* triangular patch (0 <= zeta <= eta <= 1): eta = u, zeta = u * v. The edge u = 0 collapses
  to the corner x00; inverse map u = eta, v = zeta / eta (eta > 0).

With these maps x(eta, zeta) becomes a polynomial of degree 2 in u and 2 in v. Triangle::

    x(u, u v) = c00 + c10 u + c20 u^2 + c01 u v + c11 u^2 v + c02 u^2 v^2

and its power coefficients are converted to the 3x3 Bernstein control net exactly
(P = M^T A M with M[k, i] = C(i, k) / C(2, k)). Both maps preserve orientation:
S_u x S_v = x_eta x x_zeta (quad) and = u (x_eta x x_zeta) (triangle).
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from cadbridge.nurbs.surface import NurbsSurface

__all__ = [
    "IGES_UNIT_FLAGS",
    "nagata_control_points",
    "nagata_to_surfaces",
    "write_nagata_iges",
]

# Bernstein change of basis for degree 2: t^k = sum_i M[k, i] B_i(t), M[k, i] = C(i, k) / C(2, k)
_M = np.array([[1.0, 1.0, 1.0], [0.0, 0.5, 1.0], [0.0, 0.0, 1.0]])
_BEZIER2_KNOTS = (0.0, 0.0, 0.0, 1.0, 1.0, 1.0)

# IGES 5.3 Global section field 14 (units flag) by unit name
IGES_UNIT_FLAGS = {"IN": 1, "INCH": 1, "MM": 2, "FT": 4, "MI": 5, "M": 6, "KM": 7, "MIL": 8, "UM": 9,
                   "CM": 10, "UIN": 11}


def _as_coefficients(a, k: int, what: str) -> np.ndarray:
    if a is None:
        return np.zeros((0, k, 3))
    arr = np.asarray(a, dtype=float)
    if arr.size == 0:
        arr = arr.reshape(0, k, 3)
    if arr.ndim != 3 or arr.shape[1:] != (k, 3):
        raise ValueError(f"{what} must have shape (n, {k}, 3), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be finite")
    return arr


def nagata_control_points(tri_coefficients=None, quad_coefficients=None) -> np.ndarray:
    """Bézier control nets of all patches, triangles first then quads: (Et + Eq, 3, 3, 3).

    tri_coefficients (Et, 6, 3): c00 c10 c01 c11 c20 c02; quad_coefficients (Eq, 8, 3):
    c00 c10 c01 c11 c20 c02 c21 c12. Net [e, i, j] belongs to u-index i, v-index j.
    """
    tri = _as_coefficients(tri_coefficients, 6, "tri_coefficients")
    quad = _as_coefficients(quad_coefficients, 8, "quad_coefficients")
    et, eq = len(tri), len(quad)
    a = np.zeros((et + eq, 3, 3, 3))  # power coefficients a[e, k, l] of u^k v^l
    # triangle, (eta, zeta) = (u, u v)
    a[:et, 0, 0] = tri[:, 0]  # c00
    a[:et, 1, 0] = tri[:, 1]  # c10 eta
    a[:et, 1, 1] = tri[:, 2]  # c01 zeta = u v
    a[:et, 2, 1] = tri[:, 3]  # c11 eta zeta = u^2 v
    a[:et, 2, 0] = tri[:, 4]  # c20 eta^2
    a[:et, 2, 2] = tri[:, 5]  # c02 zeta^2 = u^2 v^2
    # quad, (eta, zeta) = (u, v)
    for idx, (k, l) in enumerate(((0, 0), (1, 0), (0, 1), (1, 1), (2, 0), (0, 2), (2, 1), (1, 2))):
        a[et:, k, l] = quad[:, idx]
    # P[i, j] = sum_kl M[k, i] a[k, l] M[l, j]
    return np.einsum("ki,eklc,lj->eijc", _M, a, _M)


def nagata_to_surfaces(tri_coefficients=None, quad_coefficients=None) -> list[NurbsSurface]:
    """One degree (2, 2) polynomial `NurbsSurface` on [0, 1]^2 per patch, triangles first.

    See the module docstring for the (u, v) -> (eta, zeta) maps.
    """
    nets = nagata_control_points(tri_coefficients, quad_coefficients)
    return [NurbsSurface(2, 2, _BEZIER2_KNOTS, _BEZIER2_KNOTS, net) for net in nets]


def write_nagata_iges(
    tri_coefficients,
    quad_coefficients,
    path: str | os.PathLike,
    *,
    units: str = "MM",
    names: Sequence[str] | None = None,
) -> None:
    """Write every Nagata patch as an IGES 5.3 entity 128 (polynomial Bézier) surface.

    Order: triangles then quads (global element numbering). ``names`` (one per patch, at most
    8 characters) go to the DE entity label; without names the labels are "NTRI"/"NQUAD". The
    entity subscript is the 1-based global patch number. The text is that of
    `cadbridge.iges.write_iges` of `nagata_to_surfaces` (`cadbridge.iges.writer.bezier_iges_text`), written atomically.
    """
    from cadbridge.common.atomic import atomic_write
    from cadbridge.iges.globals import units_from_flag
    from cadbridge.iges.writer import bezier_iges_text

    tri = _as_coefficients(tri_coefficients, 6, "tri_coefficients")
    quad = _as_coefficients(quad_coefficients, 8, "quad_coefficients")
    unit = units.upper()
    if unit not in IGES_UNIT_FLAGS:
        raise ValueError(f"unknown IGES unit {units!r}; known: {sorted(IGES_UNIT_FLAGS)}")
    nets = nagata_control_points(tri, quad)
    if names is None:
        names = ["NTRI"] * len(tri) + ["NQUAD"] * len(quad)
    names = list(names)
    if len(names) != len(nets):
        raise ValueError(f"{len(names)} names for {len(nets)} patches")
    text = bezier_iges_text(nets, units=units_from_flag(IGES_UNIT_FLAGS[unit], unit),
                            labels=[(nm, k + 1) for k, nm in enumerate(names)], filename=os.path.basename(path),
                            description=f"cadbridge Nagata patches: {len(tri)} triangles, {len(quad)} quads")
    with atomic_write(path, "w", encoding="latin-1") as fh:
        fh.write(text)
