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
import time
from collections.abc import Sequence

import numpy as np

from cadbridge.io.atomic import atomic_write
from cadbridge.nurbs.surface import NurbsSurface

__all__ = [
    "IGES_UNIT_FLAGS",
    "nagata_control_points",
    "nagata_to_surfaces",
    "write_nagata_iges",
    "write_surfaces_iges",
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
    8 characters) go to the DE entity label; without names the labels are "NTRI"/"NQUAD" and
    the entity subscript is the 1-based global patch number.
    """
    tri = _as_coefficients(tri_coefficients, 6, "tri_coefficients")
    quad = _as_coefficients(quad_coefficients, 8, "quad_coefficients")
    surfaces = nagata_to_surfaces(tri, quad)
    if names is None:
        names = ["NTRI"] * len(tri) + ["NQUAD"] * len(quad)
    write_surfaces_iges(surfaces, path, units=units, names=names,
                        description=f"cadbridge Nagata patches: {len(tri)} triangles, {len(quad)} quads")


# -------------------------------------------------------------------------- IGES emitter
def _real(x: float) -> str:
    """Round-trip float with an explicit '.' or 'E' (IGES real)."""
    s = repr(float(x)).upper()
    if not np.isfinite(x):
        raise ValueError(f"non-finite value {x!r} cannot be written to IGES")
    return s if ("." in s or "E" in s) else s + ".0"


def _hollerith(s: str) -> str:
    return f"{len(s)}H{s}"


def _pack(tokens: list[str], width: int) -> list[str]:
    """Pack delimited tokens (each ending in ',' or ';') into lines of at most ``width`` chars.

    Tokens are never split unless a single token is longer than a line (only possible for
    long Hollerith strings in the Global section).
    """
    lines: list[str] = []
    cur = ""
    for tok in tokens:
        if len(cur) + len(tok) <= width:
            cur += tok
            continue
        if cur:
            lines.append(cur)
        while len(tok) > width:
            lines.append(tok[:width])
            tok = tok[width:]
        cur = tok
    if cur:
        lines.append(cur)
    return lines


def _entity128_tokens(s: NurbsSurface) -> list[str]:
    """Parameter data of a rational B-spline surface (IGES 5.3 section 4.24)."""
    nu, nv = s.shape
    p, q = s.degree_u, s.degree_v
    k1, k2 = nu - 1, nv - 1  # IGES K1, K2: upper indices of the (0-based) control net
    vals: list[str] = ["128", str(k1), str(k2), str(p), str(q), "0", "0", "0" if s.rational else "1", "0", "0"]
    vals += [_real(x) for x in s.knots_u]
    vals += [_real(x) for x in s.knots_v]
    # weights and control points with the first (u) index varying fastest
    vals += [_real(x) for x in s.weights.T.ravel()]
    for pt in s.control_points.transpose(1, 0, 2).reshape(-1, 3):
        vals += [_real(c) for c in pt]
    vals += [_real(x) for x in s.domain]
    return [v + "," for v in vals[:-1]] + [vals[-1] + ";"]


def _fixed(text: str, letter: str, seq: int) -> str:
    return f"{text:<72.72}{letter}{seq:7d}"


def write_surfaces_iges(
    surfaces: Sequence[NurbsSurface],
    path: str | os.PathLike,
    *,
    units: str = "MM",
    names: Sequence[str] | None = None,
    description: str = "cadbridge surfaces",
) -> None:
    """Write NURBS surfaces as independent IGES 5.3 entity 128 records (fixed 80 columns)."""
    unit = units.upper()
    if unit not in IGES_UNIT_FLAGS:
        raise ValueError(f"unknown IGES unit {units!r}; known: {sorted(IGES_UNIT_FLAGS)}")
    if names is not None:
        names = list(names)
        if len(names) != len(surfaces):
            raise ValueError(f"{len(names)} names for {len(surfaces)} surfaces")
        for nm in names:
            if len(nm) > 8 or not nm.isascii() or not nm.isprintable():
                raise ValueError(f"IGES entity labels are at most 8 printable ASCII characters: {nm!r}")
    else:
        names = [""] * len(surfaces)

    filename = os.path.basename(os.fspath(path))
    stamp = time.strftime("%Y%m%d.%H%M%S", time.gmtime())
    max_coord = max((float(np.abs(s.control_points).max()) for s in surfaces), default=0.0)
    start = [description[i : i + 72] for i in range(0, max(len(description), 1), 72)]
    glob = [
        ",", ";",  # parameter and record delimiters (written as 1H, and 1H;)
        _hollerith("cadbridge"), _hollerith(filename), _hollerith("cadbridge"), _hollerith("cadbridge 0.1"),
        "32", "38", "6", "308", "15", _hollerith("cadbridge"),
        "1.0", str(IGES_UNIT_FLAGS[unit]), _hollerith(unit), "1", "1.0", _hollerith(stamp),
        "1E-10", _real(max_coord), "", "", "11", "0", _hollerith(stamp),
    ]
    glob[0], glob[1] = "1H,", "1H;"
    g_tokens = [t + "," for t in glob[:-1]] + [glob[-1] + ";"]
    g_lines = _pack(g_tokens, 72)

    d_lines: list[str] = []
    p_lines: list[str] = []
    for idx, (surf, label) in enumerate(zip(surfaces, names)):
        de = 2 * idx + 1  # sequence number of the first DE line (odd, 1-based)
        first_p = len(p_lines) + 1
        body = _pack(_entity128_tokens(surf), 64)
        p_lines += [f"{b:<64.64} {de:7d}" for b in body]  # cols 66-72: DE back pointer
        d_lines.append(f"{128:8d}{first_p:8d}{0:8d}{0:8d}{0:8d}{0:8d}{0:8d}{0:8d}{'00000000':>8}")
        d_lines.append(f"{128:8d}{0:8d}{0:8d}{len(body):8d}{0:8d}{'':8}{'':8}{label:>8.8}{idx + 1:8d}")

    out = [_fixed(t, "S", i) for i, t in enumerate(start, 1)]
    out += [_fixed(t, "G", i) for i, t in enumerate(g_lines, 1)]
    out += [_fixed(t, "D", i) for i, t in enumerate(d_lines, 1)]
    out += [f"{t:<72.72}P{i:7d}" for i, t in enumerate(p_lines, 1)]
    out.append(_fixed(f"S{len(start):7d}G{len(g_lines):7d}D{len(d_lines):7d}P{len(p_lines):7d}", "T", 1))
    with atomic_write(path, "w") as fh:
        fh.write("\n".join(out) + "\n")
