"""A base surface spanned by four boundary curves, read from an IGES file (`cadbridge fit
--base-curves`): the curves ordered into a closed loop and the bilinearly blended Coons patch
over them (`cadbridge.fitting.surface_fit.coons_surface`, Piegl & Tiller §10.5 eq. 10.21).

The curves are the file's standalone curve entities (IGES 126 B-spline, 110 line, and the other
curve types the reader builds: 100 arc, 102 composite, 104 conic, 106 copious data); entities
that exist only as part of another (subordinate switch 01/03: a composite's pieces, a trim's
model-space curves) are not counted. They must be polynomial (a Coons patch is a sum of
control nets, which rational curves do not allow) and exactly four.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cadbridge.fitting.surface_fit import FitInputError, coons_surface
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["CURVE_TYPES", "boundary_loop", "coons_base", "read_boundary_curves"]

CURVE_TYPES = (100, 102, 104, 106, 110, 126)


def read_boundary_curves(path) -> list[NurbsCurve]:
    """The standalone curve entities of an IGES file as NURBS curves (model space, each entity's
    transformation applied), in file order. Raises FitInputError (one line) for an unreadable
    file or a curve the reader cannot build."""
    from cadbridge.iges.directory import parse_directory
    from cadbridge.iges.entities import Builder, Unsupported
    from cadbridge.iges.errors import IgesError
    from cadbridge.iges.globals import parse_global
    from cadbridge.iges.lexer import split_sections

    p = Path(path)
    if not p.is_file():
        raise FitInputError(f"{p}: no such file")
    try:
        text = p.read_bytes().decode("latin-1")
        secs = split_sections(text, p.name)
        g = parse_global(secs.global_, p.name)
        entries = parse_directory(secs.directory, p.name)
        b = Builder(entries, secs.parameter, g.pdelim, g.rdelim, p.name, [])
        des = sorted(de for de, e in entries.items() if e.entity_type in CURVE_TYPES and not e.physically_dependent)
        return [b.curve(de) for de in des]
    except (IgesError, Unsupported) as exc:
        raise FitInputError(f"{p}: {str(exc).splitlines()[0]}") from None
    except OSError as exc:
        raise FitInputError(f"{p}: cannot read ({exc.strerror or exc})") from None


def _reversed(c: NurbsCurve) -> NurbsCurve:
    """The same curve traversed backwards (t -> a + b - t over its knot range)."""
    a, b = c.knots[0], c.knots[-1]
    return NurbsCurve(c.degree, (a + b) - c.knots[::-1], c.control_points[::-1], c.weights[::-1],
                      ((a + b) - c.domain[1], (a + b) - c.domain[0]))


def _ends(c: NurbsCurve) -> tuple[np.ndarray, np.ndarray]:
    e = c.evaluate(np.array(c.domain, dtype=float))
    return e[0], e[1]


def boundary_loop(curves: list[NurbsCurve], tol: float | None = None) -> list[NurbsCurve]:
    """Four curves ordered and oriented into a closed loop: c0 from P00 to P10, c1 from P10 to
    P11, c2 from P11 to P01, c3 from P01 back to P00 (the first curve keeps its direction). tol:
    largest gap between the ends that meet (default 1e-6 of the loop's size). Raises
    FitInputError if the curves are not four or do not close (says where the gap is)."""
    if len(curves) != 4:
        raise FitInputError(f"a surface spanned by boundary curves needs exactly 4 curves, got {len(curves)}")
    ends = [_ends(c) for c in curves]
    pts = np.array([p for e in ends for p in e])
    size = float(np.linalg.norm(np.ptp(pts, axis=0)))
    if not size > 0:
        raise FitInputError("the 4 boundary curves have all their ends at one point")
    tol = 1e-6 * size if tol is None else float(tol)
    for k, (a, b) in enumerate(ends):
        if np.linalg.norm(a - b) <= tol:
            raise FitInputError(f"boundary curve {k + 1} is closed (its ends coincide): 4 open curves meeting "
                                f"at 4 corners are needed")
    loop = [curves[0]]
    rest = list(range(1, 4))
    while rest:
        end = _ends(loop[-1])[1]
        gaps = []
        for k in rest:
            a, b = ends[k]
            gaps.append((np.linalg.norm(a - end), k, False))
            gaps.append((np.linalg.norm(b - end), k, True))
        gap, k, flip = min(gaps, key=lambda g: g[0])
        if gap > tol:
            raise FitInputError(f"the boundary curves do not form a closed loop: no curve starts where curve "
                                f"{len(loop)} of the loop ends (nearest end {gap:.3g} away, tolerance {tol:.3g})")
        loop.append(_reversed(curves[k]) if flip else curves[k])
        rest.remove(k)
    gap = float(np.linalg.norm(_ends(loop[-1])[1] - _ends(loop[0])[0]))
    if gap > tol:
        raise FitInputError(f"the boundary curves do not close: the last ends {gap:.3g} from the first's start "
                            f"(tolerance {tol:.3g})")
    return loop


def coons_base(curves: list[NurbsCurve], tol: float | None = None) -> NurbsSurface:
    """The bilinearly blended Coons patch spanned by four boundary curves in any order and
    orientation (`boundary_loop`): S(u, 0) = c0, S(1, v) = c1, S(u, 1) = c2 reversed,
    S(0, v) = c3 reversed, parameters over [0, 1]^2. Exact (P&T eq. 10.21)."""
    c0, c1, c2, c3 = boundary_loop(curves, tol)
    rational = [k + 1 for k, c in enumerate((c0, c1, c2, c3)) if c.rational]
    if rational:
        raise FitInputError(f"boundary curve(s) {rational} of the loop are rational (arcs, conics): a Coons base "
                            f"needs polynomial curves; give the face itself with --base instead")
    return coons_surface(c0, _reversed(c2), _reversed(c3), c1)
