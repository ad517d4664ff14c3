"""OCC's elementary faces (plane, cylinder, cone, sphere, torus) as exact NURBS faces.

OCC's (u, v) on these surfaces is an affine image of the natural coordinates of
`cadbridge.cad.analytic` (lengths and true angles in the surface's frame):

    gp_Pln        P = O + u X + v Y                                natural (x, y) = (u, v)
    gp_Cylinder   P = O + R (cos u X + sin u Y) + v A              natural (h, theta) = (v, u)
    gp_Cone       P = O + (R + v sin a)(cos u X + sin u Y) + v cos a A
                                                                   natural (h, theta) = (v cos a, u)
    gp_Sphere     P = O + R cos v (cos u X + sin u Y) + R sin v A  natural (phi, theta) = (v, u)
    gp_Torus      P = O + (R + r cos v)(cos u X + sin u Y) + r sin v A
                                                                   natural (phi, theta) = (v, u)
    extrusion of a circle or ellipse (centre C, radii a, b, frame X, Y), direction D:
                  P = C + a cos u X + b sin u Y + v D              natural (h, theta) = (v, u)

    revolution of a curve C(v) about the axis (O, A):
                  P = Rot(A, u) C(v)                               natural (s, theta) = (v, -u)

The revolution's generatrix is a non-periodic B-spline curve (its own NURBS, s = v), a line (its
segment over the loops' v, s = v) or a circle or ellipse C + a cos v X + b sin v Y (the unit
circle's rational arc over the loops' v under the affine map [aX | bY] + C, s its parameter:
the closed-form `ArcMap` of the angle v, as for an IGES 100 generatrix). The revolution is
`cadbridge.cad.analytic`'s 120 map with that generatrix, revolved
over the angles the face's loops span (a full turn where they span one, its seam then moved off
a loop that crosses it as for a 120: `ParamMap.turned`) about -A (theta = -u): its
S_s x S_theta is then OCC's S_u x S_v; a reversed face is revolved about A (theta = u).

The extrusion is the unit cylinder (radius 1 about z) under the affine map x -> [aX | bY | D] x + C:
NURBS are affine-invariant, so the cylinder's exact NURBS and angle maps serve it unchanged, and its
S_u x S_v is OCC's C'(u) x D (both are the cofactor image of the unit cylinder's). OCC's conversion
of such a face whose loop crosses the curve's seam (u = 0) converts one side only and leaves
pcurves outside the B-spline (K1 from MicroStation: an elliptic fillet 1.37 rad across it).

(X, Y, A) of the surface's gp_Ax3, which may be left-handed (Y = -(A x X)): the natural frame
is then (O, -A, X), whose Y is OCC's, with h and phi negated. So the face's pcurves map
exactly onto the NURBS that `cadbridge.cad.analytic` builds over the loops' extent (`map_loops`:
`MappedCurve` pieces, the closed-form angle <-> rational-arc parameter relation), as the IGES
reader does for 190-198. This replaces OCC's NURBS conversion of such faces
(`BRepBuilderAPI_NurbsConvert`), which rewrites every pcurve by approximation and fails
outright on some closed faces (K1 from MicroStation: a full cylinder whose pcurves overshoot the
period by one ulp, "Knots interval values too close").

Orientation: the revolved NURBS's S_u x S_v points away from the axis and the plane's along its
frame axis; where the face's outward normal (OCC's natural normal, reversed for a REVERSED
face) points the other way, the revolved surface is transposed (u and v swapped) and the
plane's frame turned over.
"""

from __future__ import annotations

import dataclasses
from math import cos, sin, tan

import numpy as np

from cadbridge.cad.analytic import (ArcMap, Frame, ParamMap, _affine, _apply_affine, cylinder_map, map_loops,
                                    plane_map, sphere_map, torus_map, transposed_surface)
from cadbridge.cad.model import Trim, TrimLoop
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["ELEMENTARY", "elementary_face"]

ELEMENTARY = ("Geom_Plane", "Geom_CylindricalSurface", "Geom_ConicalSurface", "Geom_SphericalSurface",
              "Geom_ToroidalSurface", "Geom_SurfaceOfLinearExtrusion", "Geom_SurfaceOfRevolution")
"""The OCC surface types read here (an extrusion only of a circle or an ellipse, a revolution
only of a non-periodic B-spline curve, a line, a circle or an ellipse); every other surface goes
through OCC's NURBS conversion."""


def _vec(d) -> np.ndarray:
    return np.array([d.X(), d.Y(), d.Z()], dtype=float)


def _transposed(pm: ParamMap) -> ParamMap:
    """``pm`` with the built NURBS's u and v swapped (maps that build their surface; the
    revolution, whose surface is fixed, is oriented by its axis instead)."""
    build, uv_fn, parts = pm.build, pm.uv_fn, pm.uv_parts
    return dataclasses.replace(
        pm, build=lambda r0, r1: transposed_surface(build(r0, r1)),
        uv_fn=lambda nat, r0, r1: uv_fn(nat, r0, r1)[:, ::-1],
        uv_parts=lambda r0, r1: tuple(reversed(parts(r0, r1))), uv_identity=False)


def _with_pcurves(pm: ParamMap, m) -> ParamMap:
    """``pm`` reading pcurves in OCC's (u, v): natural = m @ (u, v), then ``pm``'s own
    per-coordinate `ArcMap` where it has one (a circle's angle to its arc's parameter)."""
    aff = _affine(m, np.zeros(2))
    pre = pm.pcurve_pre

    def fn(st):
        y = _apply_affine(aff, np.asarray(st, dtype=float))
        for k in (0, 1):
            if pre[k] is not None:
                y[:, k] = pre[k](y[:, k], 0)[0]
        return y

    return dataclasses.replace(pm, pcurve_fn=fn, pcurve_affine=aff)


def _mapped(pm: ParamMap, m: np.ndarray, c: np.ndarray) -> ParamMap:
    """``pm`` with the built NURBS moved by the affine map x -> m @ x + c (exact)."""
    build = pm.build

    def moved(r0, r1):
        s = build(r0, r1)
        return NurbsSurface(s.degree_u, s.degree_v, s.knots_u, s.knots_v, np.asarray(s.control_points) @ m.T + c,
                            s.weights, s.domain)

    return dataclasses.replace(pm, build=moved)


def _extrusion_map(surface, reversed_face: bool) -> ParamMap | None:
    """The `ParamMap` of a `Geom_SurfaceOfLinearExtrusion` of a circle or ellipse (module
    docstring), or None for other basis curves."""
    curve = surface.BasisCurve()
    while type(curve).__name__ == "Geom_TrimmedCurve":
        curve = curve.BasisCurve()
    kind = type(curve).__name__
    if kind == "Geom_Circle":
        a = b = curve.Radius()
    elif kind == "Geom_Ellipse":
        a, b = curve.MajorRadius(), curve.MinorRadius()
    else:
        return None
    ax = curve.Position()
    m = np.column_stack([a * _vec(ax.XDirection()), b * _vec(ax.YDirection()), _vec(surface.Direction())])
    if not abs(np.linalg.det(m)) > 1e-12 * a * b:
        return None  # extruded along the curve's own plane: no surface
    unit = Frame(np.zeros(3), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]))
    pm = _with_pcurves(cylinder_map(unit, 1.0), [[0.0, 1.0], [1.0, 0.0]])
    pm = dataclasses.replace(_mapped(pm, m, _vec(ax.Location())), points_fn=None)
    return _transposed(pm) if reversed_face else pm


def _bspline_curve(c) -> NurbsCurve | None:
    """cadbridge's NURBS of a non-periodic `Geom_BSplineCurve` (a `Geom_TrimmedCurve` of one
    read through), with the same parameter; None for other curves."""
    while type(c).__name__ == "Geom_TrimmedCurve":
        c = c.BasisCurve()
    if type(c).__name__ != "Geom_BSplineCurve" or c.IsPeriodic():
        return None
    n = c.NbPoles()
    cp = np.array([[c.Pole(i).X(), c.Pole(i).Y(), c.Pole(i).Z()] for i in range(1, n + 1)])
    w = np.array([c.Weight(i) for i in range(1, n + 1)]) if c.IsRational() else None
    knots = np.repeat([c.Knot(i) for i in range(1, c.NbKnots() + 1)],
                      [c.Multiplicity(i) for i in range(1, c.NbKnots() + 1)])
    return NurbsCurve(c.Degree(), knots, cp, w)


def _generatrix(curve, v_range: tuple[float, float]) -> tuple[NurbsCurve, ArcMap | None] | None:
    """(NURBS, ArcMap or None) of a revolution's generatrix ``curve`` (an OCC `Geom_Curve`) in
    OCC's v (module docstring): a non-periodic B-spline curve as it is, a line as its segment
    over ``v_range`` (the face's loops' v), a circle or ellipse as the exact rational arc over
    ``v_range`` (a full turn where it spans one) with the map from v to its parameter; None
    for other curves."""
    from cadbridge.nurbs.construct import circular_arc

    while type(curve).__name__ == "Geom_TrimmedCurve":
        curve = curve.BasisCurve()
    kind = type(curve).__name__
    if kind == "Geom_BSplineCurve":
        gen = _bspline_curve(curve)
        return None if gen is None else (gen, None)
    lo, hi = v_range
    if kind not in ("Geom_Line", "Geom_Circle", "Geom_Ellipse") or not hi > lo:
        return None
    if kind == "Geom_Line":  # P = L + v D, |D| = 1: linear in v
        return NurbsCurve(1, [lo, lo, hi, hi], np.array([_vec(curve.Value(lo)), _vec(curve.Value(hi))])), None
    a, b = (curve.Radius(), curve.Radius()) if kind == "Geom_Circle" else (curve.MajorRadius(), curve.MinorRadius())
    start, end = np.array([cos(lo), sin(lo)]), np.array([cos(hi), sin(hi)])
    if hi - lo >= 2 * np.pi * (1 - 1e-9):
        end = start  # a full turn
    unit = circular_arc(np.zeros(2), start, end)  # the unit circle from angle lo, domain [0, sweep]
    ax = curve.Position()
    pts = (_vec(ax.Location()) + a * unit.control_points[:, :1] * _vec(ax.XDirection())
           + b * unit.control_points[:, 1:] * _vec(ax.YDirection()))
    gen = NurbsCurve(2, unit.knots, pts, unit.weights)
    return gen, ArcMap(lo, gen.domain[1] - gen.domain[0], 0.0)


def _revolution_map(surface, reversed_face: bool, u_range: tuple[float, float],
                    v_range: tuple[float, float]) -> ParamMap | None:
    """The `ParamMap` of a `Geom_SurfaceOfRevolution` (module docstring), or None for a
    generatrix `_generatrix` does not read. ``u_range``, ``v_range``: OCC's (u, v) the face's
    loops span; the NURBS is revolved over that u range only (a full turn where they span one)."""
    from cadbridge.cad.analytic import revolution_map
    from cadbridge.nurbs.construct import revolved_surface

    got = _generatrix(surface.BasisCurve(), v_range)
    if got is None:
        return None
    gen, arc = got
    ax = surface.Axis()
    o, a = _vec(ax.Location()), _vec(ax.Direction())
    axis = a if reversed_face else -a
    lo, hi = u_range if reversed_face else (-u_range[1], -u_range[0])  # theta = u, or -u about -A
    if hi - lo >= 2 * np.pi * (1 - 1e-9):
        lo, hi = 0.0, 2 * np.pi
    s = revolved_surface(gen, o, axis, lo, hi)
    pm = revolution_map(s, lo, hi, None, arc, (o, axis), gen)
    return _with_pcurves(pm, [[0.0, 1.0], [1.0 if reversed_face else -1.0, 0.0]])


def param_map(surface, reversed_face: bool, u_range: tuple[float, float] = (0.0, 2 * np.pi),
              v_range: tuple[float, float] = (0.0, 1.0)) -> ParamMap | None:
    """The `ParamMap` of OCC surface ``surface`` (located, one of `ELEMENTARY`) for a face on
    it, oriented as the face (``reversed_face``: OCC's REVERSED), or None for other types.
    ``u_range``, ``v_range``: OCC's (u, v) the face's loops span (a revolution is built over
    them)."""
    kind = type(surface).__name__
    if kind not in ELEMENTARY:
        return None
    if kind == "Geom_SurfaceOfLinearExtrusion":
        return _extrusion_map(surface, reversed_face)
    if kind == "Geom_SurfaceOfRevolution":
        return _revolution_map(surface, reversed_face, u_range, v_range)
    ax = surface.Position()
    o, a, x = _vec(ax.Location()), _vec(ax.Direction()), _vec(ax.XDirection())
    direct = bool(ax.Direct())
    if kind == "Geom_Plane":
        normal = (a if direct else -a) * (-1.0 if reversed_face else 1.0)  # the face's outward normal
        # X kept; Y = normal x X is OCC's Y, or its opposite on a reversed face
        return _with_pcurves(plane_map(Frame(o, normal, x)), [[1.0, 0.0], [0.0, -1.0 if reversed_face else 1.0]])
    sign = 1.0 if direct else -1.0  # natural h and phi along A, or along -A in a left-handed frame
    frame = Frame(o, a * sign, x)
    if kind == "Geom_CylindricalSurface":
        pm = _with_pcurves(cylinder_map(frame, surface.Radius()), [[0.0, sign], [1.0, 0.0]])
    elif kind == "Geom_ConicalSurface":
        alpha = surface.SemiAngle()
        pm = _with_pcurves(cylinder_map(frame, surface.RefRadius(), sign * tan(alpha), "cone"),
                           [[0.0, sign * cos(alpha)], [1.0, 0.0]])
    elif kind == "Geom_SphericalSurface":
        pm = _with_pcurves(sphere_map(frame, surface.Radius()), [[0.0, sign], [1.0, 0.0]])
    else:
        pm = _with_pcurves(torus_map(frame, surface.MajorRadius(), surface.MinorRadius()), [[0.0, sign], [1.0, 0.0]])
    outward = direct != reversed_face  # OCC's natural normal points away from the axis iff its frame is direct
    return pm if outward else _transposed(pm)


def elementary_face(surface, reversed_face: bool, loops: list[list[NurbsCurve]]) -> tuple[NurbsSurface, Trim] | None:
    """(NURBS surface, trim) of a face on an elementary OCC surface, or None for other types.

    surface: the face's located surface (a `Geom_RectangularTrimmedSurface` is read through to
    its basis: the face's loops bound it); reversed_face: the face's orientation is REVERSED;
    loops: the face's trim loops, outer first, each a list of pcurves (2D `NurbsCurve`) in
    OCC's (u, v), in loop order and direction. Raises ValueError where the loops cannot be
    mapped (`map_loops`)."""
    while type(surface).__name__ == "Geom_RectangularTrimmedSurface":
        surface = surface.BasisSurface()
    u_range, v_range = (0.0, 2 * np.pi), (0.0, 1.0)
    if type(surface).__name__ == "Geom_SurfaceOfRevolution":  # the only map built over the loops' (u, v)
        pts = np.vstack([c.evaluate(np.linspace(c.domain[0], c.domain[1], 65)) for loop in loops for c in loop])
        u_range = (float(pts[:, 0].min()), float(pts[:, 0].max()))
        v_range = (float(pts[:, 1].min()), float(pts[:, 1].max()))
    pm = param_map(surface, reversed_face, u_range, v_range)
    if pm is None:
        return None
    res = map_loops(pm, [[([c], None) for c in loop] for loop in loops], True, True)  # each piece its own edge
    tl = [TrimLoop([c for _, c, _ in lp]) for lp in res.loops]
    return res.surface, Trim(tl[0], tl[1:])
