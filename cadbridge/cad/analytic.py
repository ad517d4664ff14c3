"""Trim curves over surfaces whose file parametrisation is not our NURBS parametrisation.

Written for IGES (below); the STEP reader uses the same maps for OCC's elementary surfaces
(`cadbridge.step.analytic`: OCC's (u, v) of a plane, cylinder, cone, sphere or torus is an
affine image of the natural coordinates, its ``pcurve_affine``).

For a 128 the trim curves of a 142/141/508 are in the NURBS (u, v) itself. For every other
base surface (108, 118, 120, 122 and the IGES 5.3 analytic surfaces 190-198) a trim curve
goes through two maps:

    IGES parameter space --(pcurve map)--> natural coordinates --(uv map)--> NURBS (u, v)
    model space          --(inversion)--->

"Natural coordinates" are lengths and true angles (radians) of the surface's frame, in
which a loop can be unwrapped across the seam of a closed surface and whose range decides
the domain of the NURBS built for an unbounded analytic surface:

  plane 108 / 190     (x, y) in the frame (O, X, Y = N x X)        NURBS (u, v) = (x, y)
  cylinder 192        (h, theta): height along A, angle about A   u = revolved v(theta), v = h
  cone 194            (h, theta)                                  u = revolved v(theta), v = h
  sphere 196          (phi, theta): latitude, longitude           u = revolved v(theta),
  torus 198           (phi, theta): tube angle, angle about A         v = arc parameter of phi
  120 revolution      (u, theta): generatrix parameter, angle      u, v = revolved v(theta)
  118 ruled, 122 tab. (u, v) of the NURBS itself

(revolved v(theta) = `construct.revolved_angle_to_v`, arc parameter = `construct.arc_parameter`:
angles equal the NURBS parameter only at knots.) The frame of every revolved surface has
its angle 0 along X and increases right-handed about the axis A (Y = A x X), as OCC's
gp_Ax3 does.

Curves whose whole chain is affine (planes) are transformed exactly (control points).
Every other parameter-space curve becomes a `MappedCurve`: the file's curve c(t) composed
with the exact map to NURBS (u, v) -- affine, then per coordinate the closed-form relation
angle <-> parameter of a rational quadratic arc (`ArcMap`) -- with analytic first and second
derivatives by the chain rule. A loop derived from model-space curves becomes an
`InvertedCurve`: the 3D curve through the surface's exact inversion (closed form for
190-198, meridian-plane Newton on the generatrix for 120), derivatives by the chain rule
through the surface Jacobian. Both offer the NurbsCurve interface the trim code uses
(``domain``, ``degree``, ``knots``, ``evaluate``, ``derivatives``, ``sample_parameters``)
and ``to_nurbs`` (a cubic Hermite NurbsCurve within a stated tolerance) for writers that
need control points.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import pi
from typing import Callable

import numpy as np

from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["ArcMap", "Frame", "InvertedCurve", "MappedCurve", "ParamMap", "SurfaceInvertedCurve", "ax2_x_direction",
           "evaluate_inverted", "invert_edges", "sample_chain", "transposed_surface", "HERMITE_REL_TOL"]

HERMITE_REL_TOL = 1e-10  # `to_nurbs` default: cubic deviation relative to the curve's (u, v) box
MIN_PER_SPAN = 16  # samples per knot span of the sampled curve at least
MAX_REFINE = 14  # bisection rounds of the adaptive sampling
TWO_PI = 2 * pi
WIND_TOL = 0.01
"""Trim loops over a surface of revolution whose angle spans more than (1 + WIND_TOL) turns
wind round the axis more than once (overlapping themselves): unusable (a damaged number in a
parameter-space curve made one wind 10^6 turns; a closed face spans exactly one)."""


def ax2_x_direction(n: np.ndarray) -> np.ndarray:
    """The X direction OpenCASCADE's gp_Ax2(P, N) picks for a normal N (no reference
    direction given): perpendicular to N with one zero coordinate, chosen from the
    smallest component of N. Used for 108 planes and 190-198 form 0 (unparametrised)."""
    a, b, c = (float(x) for x in n)
    aa, ba, ca = abs(a), abs(b), abs(c)
    if ba <= aa and ba <= ca:
        x = np.array([-c, 0.0, a]) if aa > ca else np.array([c, 0.0, -a])
    elif aa <= ba and aa <= ca:
        x = np.array([0.0, -c, b]) if ba > ca else np.array([0.0, c, -b])
    else:
        x = np.array([-b, a, 0.0]) if aa > ba else np.array([b, -a, 0.0])
    return x / np.linalg.norm(x)


@dataclass
class Frame:
    """Right-handed frame: origin O, axis (normal) A, X perpendicular to A, Y = A x X."""

    origin: np.ndarray
    axis: np.ndarray
    x: np.ndarray

    @property
    def y(self) -> np.ndarray:
        return np.cross(self.axis, self.x)

    @classmethod
    def make(cls, origin, axis, ref=None) -> "Frame":
        a = np.asarray(axis, dtype=float)
        la = np.linalg.norm(a)
        if not la > 0:
            raise ValueError("zero axis direction")
        a = a / la
        x = None
        if ref is not None:
            r = np.asarray(ref, dtype=float)
            r = r - (r @ a) * a
            if np.linalg.norm(r) > 1e-9 * max(1.0, float(np.linalg.norm(ref))):
                x = r / np.linalg.norm(r)
        if x is None:
            x = ax2_x_direction(a)
        return cls(np.asarray(origin, dtype=float), a, x)

    def local(self, pts: np.ndarray) -> np.ndarray:
        """(N, 3) model points -> (N, 3) coordinates along X, Y, A."""
        r = np.asarray(pts, dtype=float) - self.origin
        key = (id(self.axis), id(self.x))
        y = self.__dict__.get("_y")
        if y is None or y[0] != key:  # Y = A x X once per frame (the reader maps thousands of curves)
            y = self.__dict__["_y"] = (key, self.y)
        return np.column_stack([r @ self.x, r @ y[1], r @ self.axis])


@dataclass
class ParamMap:
    """How one base surface relates IGES trim data to our NURBS (see the module docstring).

    kind           "plane", "cylinder", "cone", "sphere", "torus", "revolution", "fixed"
    pcurve_affine  (M (2, 2), b (2,)) with natural = M @ st + b for IGES parameter-space
                   points st, or None when the pcurve map is not affine
    pcurve_fn      natural coordinates from IGES parameters (N, 2) -> (N, 2)
    points_fn      natural coordinates from model points (N, 3) -> (N, 2), or None
    angular        which natural coordinates are angles (unwrapped with period 2 pi)
    build          natural ranges ((lo0, hi0), (lo1, hi1)) -> NurbsSurface (None: fixed)
    uv_fn          natural -> NURBS (u, v) for the surface ``build`` returned, given the
                   natural ranges; uv_affine says whether it is the identity
    fixed_range    natural ranges that cannot change (a 120's [SA, TA]), or None
    pcurve_pre     per natural coordinate an `ArcMap` applied after ``pcurve_affine`` (or None)
    uv_parts       natural ranges -> ((src, ArcMap | None), (src, ArcMap | None)): NURBS u, v
                   as scalar maps of natural coordinate src (what `MappedCurve` composes)
    """

    kind: str
    pcurve_fn: Callable[[np.ndarray], np.ndarray]
    pcurve_affine: tuple[np.ndarray, np.ndarray] | None
    points_fn: Callable[[np.ndarray], np.ndarray] | None
    angular: tuple[bool, bool]
    build: Callable[[tuple, tuple], NurbsSurface] | None
    uv_fn: Callable[[np.ndarray, tuple, tuple], np.ndarray]
    uv_identity: bool = False
    fixed_range: tuple | None = None
    surface: NurbsSurface | None = None  # for fixed surfaces (118, 120, 122)
    pcurve_pre: tuple = (None, None)
    uv_parts: Callable[[tuple, tuple], tuple] = lambda r0, r1: ((0, None), (1, None))
    turned: Callable[[float], NurbsSurface | None] | None = None
    """For a full turn (a 120 with TA - SA = 2 pi): delta -> the same surface with its angle
    origin moved by delta, S'(u, theta) = S(u, theta + delta) (None where that cannot be
    made exactly); `map_loops` moves the seam off the loops with it."""


def _ders(curve: NurbsCurve, t, order: int) -> np.ndarray:
    """``curve.derivatives(t, order)`` through the compiled evaluator of `cadbridge.nurbs.curve_pack.eval_packed`
    (same algorithms, P&T A3.2 + A4.2; t clamped to the knot range): the trim maps evaluate
    the file's curves many times in small batches, where the numpy path is call-bound. The
    packed form is kept on the curve (``_packed``), built on first use. (N, order+1, dim)."""
    if not isinstance(curve, NurbsCurve):
        return curve.derivatives(t, order)
    pk = curve.__dict__.get("_packed")
    if pk is None:
        from cadbridge.nurbs.curve_pack import PackedCurves

        pk = curve.__dict__["_packed"] = PackedCurves([curve])
    t = np.atleast_1d(np.asarray(t, dtype=float)).ravel()
    return pk.evaluate(np.zeros(len(t), dtype=np.int64), t, order)[:, :, : curve.dim]


def _eval(curve: NurbsCurve, t) -> np.ndarray:
    """``curve.evaluate(t)`` through `_ders`, (N, dim)."""
    return _ders(curve, t, 0)[:, 0]


def _affine(m, b) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(m, dtype=float), np.asarray(b, dtype=float)


def _apply_affine(a: tuple[np.ndarray, np.ndarray], st: np.ndarray) -> np.ndarray:
    return st @ a[0].T + a[1]


def _unwrap_to(value: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """value shifted by multiples of 2 pi to be nearest ref (elementwise)."""
    return value - TWO_PI * np.round((value - ref) / TWO_PI)


def sample_chain(fn: Callable[[np.ndarray], np.ndarray], curve: NurbsCurve, angular: tuple[bool, bool],
                 to_uv: Callable[[np.ndarray], np.ndarray] | None, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Sample t -> fn(curve(t)) (natural coordinates) on the curve's domain: MIN_PER_SPAN per
    knot span, angular coordinates unwrapped along the curve, then (if ``to_uv`` is given)
    bisected where the chord in (u, v) deviates from the mapped midpoint by more than tol.

    Returns (t (M,), natural (M, 2)) with angular columns continuous."""
    t = curve.sample_parameters(MIN_PER_SPAN)
    nat = _unwrap_rows(fn(_eval(curve, t)), angular)
    if to_uv is None:
        return t, nat
    for _ in range(MAX_REFINE):
        uv = to_uv(nat)
        tm = 0.5 * (t[:-1] + t[1:])
        nm = fn(_eval(curve, tm))
        ref = 0.5 * (nat[:-1] + nat[1:])
        for k in (0, 1):
            if angular[k]:
                nm[:, k] = _unwrap_to(nm[:, k], ref[:, k])
        err = np.linalg.norm(to_uv(nm) - 0.5 * (uv[:-1] + uv[1:]), axis=1)
        bad = np.flatnonzero(~(err <= tol))
        if bad.size == 0:
            break
        t = np.insert(t, bad + 1, tm[bad])
        nat = np.insert(nat, bad + 1, nm[bad], axis=0)
    return t, nat


def _sample_many(curves: list[NurbsCurve], fn: Callable[[np.ndarray], np.ndarray],
                 angular: tuple[bool, bool]) -> list[tuple[np.ndarray, np.ndarray]]:
    """``sample_chain(fn, c, angular, None, 0.0)`` for each of many NurbsCurves of one
    dimension at once: one compiled sampling and evaluation (`cadbridge.nurbs.curve_pack.PackedCurves`, the
    parameters of `NurbsCurve.sample_parameters`), one call of fn; angles unwrapped per curve."""
    from cadbridge.nurbs.curve_pack import PackedCurves

    pk = PackedCurves(curves)
    ci, t = pk.sample(MIN_PER_SPAN)
    nat = np.array(fn(pk.evaluate(ci, t, 0)[:, 0, : curves[0].dim]), dtype=float)
    cuts = np.flatnonzero(np.diff(ci)) + 1
    starts = np.r_[0, cuts]
    for k in (0, 1):  # np.unwrap (period 2 pi, discont pi) of each curve's run, all runs at once
        if angular[k] and len(t) > 1:
            x = nat[:, k]
            d = np.diff(x)
            dd = np.mod(d + pi, TWO_PI) - pi
            dd[(dd == -pi) & (d > 0)] = pi
            corr = np.where(np.abs(d) < pi, 0.0, dd - d)
            corr[cuts - 1] = 0.0  # no correction across curves
            cs = np.concatenate([[0.0], np.cumsum(corr)])
            nat[:, k] = x + cs - np.repeat(cs[starts], np.diff(np.r_[starts, len(t)]))
    return [(t[a:b], nat[a:b]) for a, b in zip(starts, np.r_[cuts, len(t)])]


def _unwrap_rows(nat: np.ndarray, angular: tuple[bool, bool]) -> np.ndarray:
    nat = np.array(nat, dtype=float)
    for k in (0, 1):
        if angular[k] and len(nat) > 1:
            nat[:, k] = np.unwrap(nat[:, k])
    return nat


# ---------------------------------------------------------------------------- exact maps
@dataclass(frozen=True)
class ArcMap:
    """Scalar map x -> start_out + arc_parameter(x - start_in, sweep): the NURBS parameter of a
    rational quadratic arc (``construct.circular_arc`` / ``revolved_surface``) at the angle x,
    x clipped to [start_in, start_in + sweep], after a shift by whole turns where that puts an x
    farther outside the range than 1e-9 x the sweep inside it (an angle is modular: the analytic die's 120 faces BED01060 &c.
    have generatrix pcurves at 5.05..6.28 rad on an arc of angles -1.23..0, which clipping
    collapsed to one point). Closed form per quarter segment of width d:
    with T = tan(rel / 2), rel the angle from the segment's middle,
    f = start_out + (k + (1 + T / tan(d/4)) / 2) d, f' = d (1 + T^2) / (4 tan(d/4)),
    f'' = f' T; f is C1 at the segment breaks, f'' jumps there (`breaks`)."""

    start_in: float
    sweep: float
    start_out: float = 0.0

    def __call__(self, x: np.ndarray, order: int = 2) -> list[np.ndarray]:
        """[f, f', f''][:order+1] at x (N,)."""
        c = _construct()
        n = c.arc_segments(self.sweep)
        d = self.sweep / n
        r = np.asarray(x, dtype=float) - self.start_in
        wrapped = r - TWO_PI * np.round((r - 0.5 * self.sweep) / TWO_PI)
        turn_tol = 1e-9 * max(abs(self.sweep), 1.0)
        # only an x beyond the range by more than the tolerance is shifted: one within it is
        # the range's end up to rounding (on a full turn, the seam at 0 read as 1e-17 beyond
        # 2 pi went to the other end of the arc and folded the analytic die's boss BOS00346's
        # trim loop onto itself)
        r = np.where(((r < -turn_tol) | (r > self.sweep + turn_tol)) & (wrapped >= -turn_tol)
                     & (wrapped <= self.sweep + turn_tol), wrapped, r)
        a = np.clip(r, 0.0, self.sweep)
        k = np.clip(np.floor(a / d), 0, n - 1)
        tt = np.tan((a - k * d - d / 2) / 2)
        q = 1.0 / np.tan(d / 4)
        out = [self.start_out + (k + 0.5 * (1.0 + tt * q)) * d]
        if order >= 1:
            # f is constant where x is clipped: f' = f'' = 0; the ends themselves (up to rounding
            # of x - start_in, 2e-16 there on the U-die's fillets) are inside
            tol = 1e-12 * max(abs(self.sweep), 1.0)
            inside = (r >= -tol) & (r <= self.sweep + tol)
            f1 = np.where(inside, 0.25 * d * q * (1.0 + tt * tt), 0.0)
            out.append(f1)
            if order >= 2:
                out.append(f1 * tt)
        return out

    def breaks(self) -> np.ndarray:
        """Angles (in x) where f'' jumps, (n-1,)."""
        n = _construct().arc_segments(self.sweep)
        return self.start_in + self.sweep / n * np.arange(1, n)


def _apply_scalar(m: ArcMap | None, y: np.ndarray, order: int) -> np.ndarray:
    """(N, order+1) derivatives of m(y(t)) from those of y(t), (N, order+1) (Faa di Bruno, order <= 2)."""
    if m is None:
        return y
    f = m(y[:, 0], order)
    out = np.empty_like(y)
    out[:, 0] = f[0]
    if order >= 1:
        out[:, 1] = f[1] * y[:, 1]
    if order >= 2:
        out[:, 2] = f[2] * y[:, 1] ** 2 + f[1] * y[:, 2]
    return out


class _TrimCurve:
    """What the trim code needs of a trim curve in NURBS (u, v): ``domain``, ``degree``
    (at least 2: a mapped curve is not straight), ``knots`` (the base curve's, plus the
    parameters where an `ArcMap` break is crossed: f'' jumps there), ``evaluate``,
    ``derivatives``, ``sample_parameters``; subclasses define ``derivatives``."""

    base: NurbsCurve
    dim = 2
    rational = False

    @property
    def domain(self) -> tuple[float, float]:
        return self.base.domain

    @property
    def degree(self) -> int:
        return max(2, self.base.degree)

    def derivatives(self, t, order: int = 1) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def evaluate(self, t) -> np.ndarray:
        """Points (u, v): t (N,) -> (N, 2)."""
        return self.derivatives(t, order=0)[:, 0]

    __call__ = evaluate

    def sample_parameters(self, per_span: int = 16) -> np.ndarray:
        """As `NurbsCurve.sample_parameters`, over this curve's knots (breaks included), (M,)."""
        return NurbsCurve.sample_parameters(self, per_span)  # type: ignore[arg-type]

    def bbox(self) -> np.ndarray:
        """Box of dense samples, (2, 2)."""
        p = self.evaluate(self.sample_parameters(16))
        return np.array([p.min(axis=0), p.max(axis=0)])

    def to_nurbs(self, rel_tol: float = HERMITE_REL_TOL, tol: float | None = None) -> NurbsCurve:
        """This curve as a NurbsCurve for writers that need control points: no exact NURBS
        exists (the ArcMap / inversion of a NURBS is not rational), so the piecewise cubic
        Hermite interpolant on the same parameter t -- exact points and exact first derivatives
        (one-sided at the ends of each interval, so corners at knots are kept), Bezier form
        (knots of multiplicity 3, C0 at every junction, C1 wherever the curve is) -- with
        intervals bisected until its distance from this curve at 1/4, 1/2 and 3/4 of every
        interval is at most ``tol`` ((u, v) units; default ``rel_tol`` x the diagonal of the
        curve's box). Where the exact curve itself jumps (an InvertedCurve through a pole of its
        surface, where the angle is undefined) no continuous curve is within tol: the cubic
        crosses the jump within an interval of 1e-13 x the domain length. Degree 3, domain =
        this curve's domain."""
        from cadbridge.cad.trims import curve_ders  # compiled where the map packs (MappedCurve)

        def ders(x, order):  # compiled: the analytic die's 2 120 trims in 1.1 s, not 2.6 s (the same cubics)
            return curve_ders(self, x, order)

        def at(x):
            return ders(x, 0)[:, 0]

        if tol is None:
            p = at(self.sample_parameters(16))
            tol = rel_tol * max(float(np.linalg.norm(p.max(axis=0) - p.min(axis=0))), 1e-300)
        t = self.sample_parameters(2)  # every knot (and ArcMap break) is an interval end
        gap = 1e-13 * max(float(t[-1] - t[0]), 1e-300)  # a jump of the curve itself: bridged this narrowly
        # a break that falls on a knot within round-off (an OCC pcurve's knot at a seam angle:
        # K1 from MicroStation) is one interval end, not an interval of 1e-16 (OCC refuses the knots)
        keep = np.r_[True, np.diff(t) > gap]
        end = t[-1]
        t = t[keep]
        t[-1] = end
        s = np.array([0.25, 0.5, 0.75])
        for _ in range(60):  # 1e-13 of the domain is reached from one interval in 44 halvings
            a, b = t[:-1], t[1:]
            h = b - a
            d0 = ders(a, 1)
            d1 = ders(np.nextafter(b, -np.inf), 1)  # from the left: one-sided at a knot
            p0, p1 = d0[:, 0], at(b)
            c1, c2 = p0 + d0[:, 1] * (h / 3)[:, None], p1 - d1[:, 1] * (h / 3)[:, None]
            x = (a[:, None] + h[:, None] * s[None]).ravel()
            u = np.tile(s, len(a))[:, None]
            rep3 = lambda q: np.repeat(q, 3, axis=0)  # noqa: E731
            bez = ((1 - u) ** 3 * rep3(p0) + 3 * u * (1 - u) ** 2 * rep3(c1) + 3 * u * u * (1 - u) * rep3(c2)
                   + u ** 3 * rep3(p1))
            err = np.linalg.norm(bez - at(x), axis=1).reshape(-1, 3).max(axis=1)
            bad = np.flatnonzero(~(err <= tol) & (h > gap))
            if bad.size == 0:
                break
            if len(t) + bad.size > MAX_HERMITE_INTERVALS:  # no cubic within tol (noise, a jump): stop early
                raise ValueError(f"cubic approximation of the trim curve did not reach {tol:.3g} "
                                 f"within {MAX_HERMITE_INTERVALS} intervals")
            t = np.insert(t, bad + 1, a[bad] + 0.5 * h[bad])
        else:
            raise ValueError(f"cubic approximation of the trim curve did not reach {tol:.3g}")
        n = len(a)
        cp = np.empty((3 * n + 1, p0.shape[1]))
        cp[0:-1:3], cp[1::3], cp[2::3], cp[-1] = p0, c1, c2, p1[-1]
        knots = np.concatenate([[t[0]] * 4, np.repeat(t[1:-1], 3), [t[-1]] * 4])
        return NurbsCurve(3, knots, cp, None, (float(t[0]), float(t[-1])))

    @property
    def knots(self) -> np.ndarray:
        """Base knots plus the parameters where a natural coordinate crosses a break of its
        ArcMap (found on first use: sign changes on samples, then Illinois regula falsi)."""
        kn = self.__dict__.get("_knots")
        if kn is None:
            kn = self.__dict__["_knots"] = self._knots_with_breaks()
        return kn

    def _natural(self, t) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _break_values(self) -> list[tuple[int, np.ndarray]]:
        """(natural coordinate, values at which a derivative jumps)."""
        return [(src, m.breaks()) for src, m in self.post if m is not None]

    def _knots_with_breaks(self) -> np.ndarray:
        extra = []
        t = self.base.sample_parameters(8)
        nat = None
        for src, values in self._break_values():
            if len(values) and nat is None:
                nat = self._natural(t)
            for b in values:
                g = nat[:, src] - b
                idx = np.flatnonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0)
                if not idx.size:
                    continue
                lo, hi, glo, ghi = t[idx].copy(), t[idx + 1].copy(), g[idx].copy(), g[idx + 1].copy()
                x = lo
                for _ in range(60):  # Illinois: superlinear, bracket kept
                    x = (lo * ghi - hi * glo) / (ghi - glo)
                    gx = self._natural(x)[:, src] - b
                    same = np.sign(gx) == np.sign(glo)
                    lo, glo, ghi = np.where(same, x, lo), np.where(same, gx, glo), np.where(same, 0.5 * ghi, ghi)
                    hi, glo = np.where(same, hi, x), np.where(same, glo, 0.5 * glo)
                    ghi = np.where(same, ghi, gx)
                    if np.all(np.abs(gx) <= 1e-14 * max(1.0, abs(b))):
                        break
                extra.append(x)
        kn = np.asarray(self.base.knots)
        return np.sort(np.concatenate([kn] + extra)) if extra else kn


class MappedCurve(_TrimCurve):
    """A parameter-space trim curve c(t) (IGES (s, t), 2D NurbsCurve) mapped exactly into the
    NURBS (u, v) of the converted surface:

        y(t) = M c(t) + b            (affine: degrees -> radians, swaps, the 2 pi unwrap shift)
        n_k  = pre_k(y_k)            (natural coordinates; ArcMap for a 120's 100 generatrix)
        uv_j = post_j(n_{src_j})     (NURBS parameters; ArcMap for angles)

    Derivatives by the chain rule: y' = M c', y'' = M c''; (f o y)' = f' y',
    (f o y)'' = f'' y'^2 + f' y''. Exact to rounding (no sampling)."""

    def __init__(self, base: NurbsCurve, m: np.ndarray, b: np.ndarray, pre: tuple, post: tuple) -> None:
        self.base = base
        self.m = np.asarray(m, dtype=float)
        self.b = np.asarray(b, dtype=float)
        self.pre = tuple(pre)
        self.post = tuple(post)

    def _break_values(self) -> list[tuple[int, np.ndarray]]:
        out = [(k, m(m.breaks(), 0)[0]) for k, m in enumerate(self.pre) if m is not None]  # pre is monotone
        return out + super()._break_values()

    def _natural_ders(self, t, order: int) -> np.ndarray:
        c = _ders(self.base, t, order)  # (N, order+1, 2)
        y = c @ self.m.T
        y[:, 0] += self.b
        nat = np.empty_like(y)
        for k in (0, 1):
            nat[:, :, k] = _apply_scalar(self.pre[k], y[:, :, k], order)
        return nat

    def _natural(self, t) -> np.ndarray:
        return self._natural_ders(t, 0)[:, 0]

    def packed_map(self) -> np.ndarray:
        """The map in the flat form the compiled trim kernels take (`cadbridge.cad.trims.MAP_LEN`
        = 29 floats): 1, M row by row, b, then pre_0 and pre_1 as (flag, start_in, sweep,
        start_out, segments) (flag 0: identity), then post_0 and post_1 as (src, flag,
        start_in, sweep, start_out, segments)."""
        c = _construct()

        def arc(m: ArcMap | None) -> list[float]:
            return [0.0] * 5 if m is None else [1.0, m.start_in, m.sweep, m.start_out, float(c.arc_segments(m.sweep))]

        out = [1.0, *self.m.reshape(2, 2).ravel(), *self.b.reshape(2), *arc(self.pre[0]), *arc(self.pre[1])]
        for src, mp in self.post:
            out += [float(src), *arc(mp)]
        return np.array(out, dtype=float)

    def derivatives(self, t, order: int = 1) -> np.ndarray:
        """Derivatives of (u, v)(t) up to ``order`` (<= 2): t (N,) -> (N, order+1, 2)."""
        if order > 2:
            raise ValueError("MappedCurve derivatives are implemented up to order 2")
        nat = self._natural_ders(t, order)
        out = np.empty_like(nat)
        for j, (src, mp) in enumerate(self.post):
            out[:, :, j] = _apply_scalar(mp, nat[:, :, src], order)
        return out


MAX_HERMITE_INTERVALS = 20000
"""`_TrimCurve.to_nurbs` gives up beyond this many cubic pieces: where the exact curve is
noisy or jumps over a stretch, each bisection round doubled the pieces without end."""


class InvertedCurve(_TrimCurve):
    """A model-space trim curve C(t) (3D NurbsCurve) through the surface's inversion:
    uv(t) = post(points_fn(C(t)) + shift), angular natural coordinates kept continuous by
    unwrapping against a reference table (t_ref, nat_ref) sampled along the curve.

    Derivatives through the surface S at uv(t) (exact when C lies on S, i.e. up to the file's
    delta): with J = [Su Sv], J^T J uv' = J^T C' and
    J^T J uv'' = J^T (C'' - Suu u'^2 - 2 Suv u' v' - Svv v'^2)."""

    def __init__(self, base: NurbsCurve, points_fn, shift: np.ndarray, post: tuple, angular: tuple[bool, bool],
                 t_ref: np.ndarray, nat_ref: np.ndarray, surface: NurbsSurface) -> None:
        self.base = base
        self.points_fn = points_fn
        self.shift = np.asarray(shift, dtype=float)
        self.post = tuple(post)
        self.angular = angular
        self.t_ref = np.asarray(t_ref, dtype=float)
        self.nat_ref = np.asarray(nat_ref, dtype=float)
        self.surface = surface

    def _natural(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        nat = np.array(self.points_fn(_eval(self.base, t)), dtype=float) + self.shift
        for k in (0, 1):
            if self.angular[k]:
                nat[:, k] = _unwrap_to(nat[:, k], np.interp(t, self.t_ref, self.nat_ref[:, k]))
        return nat

    def derivatives(self, t, order: int = 1) -> np.ndarray:
        """Derivatives of (u, v)(t) up to ``order`` (<= 2): t (N,) -> (N, order+1, 2)."""
        if order > 2:
            raise ValueError("InvertedCurve derivatives are implemented up to order 2")
        t = np.atleast_1d(np.asarray(t, dtype=float)).ravel()
        nat = self._natural(t)
        uv = np.column_stack([_apply_scalar(mp, nat[:, src : src + 1], 0)[:, 0] for src, mp in self.post])
        out = np.zeros((len(t), order + 1, 2))
        out[:, 0] = uv
        if order == 0:
            return out
        u0, u1, v0, v1 = self.surface.domain
        d = self.surface.derivatives(np.clip(uv[:, 0], u0, u1), np.clip(uv[:, 1], v0, v1), order=order)
        c = _ders(self.base, t, order)
        jac = np.stack([d[:, 1, 0], d[:, 0, 1]], axis=2)  # (N, 3, 2)
        jtj = np.einsum("nia,nib->nab", jac, jac)
        out[:, 1] = np.linalg.solve(jtj, np.einsum("nia,ni->na", jac, c[:, 1])[..., None])[..., 0]
        if order >= 2:
            up, vp = out[:, 1, 0:1], out[:, 1, 1:2]
            rhs = c[:, 2] - d[:, 2, 0] * up * up - 2.0 * d[:, 1, 1] * up * vp - d[:, 0, 2] * vp * vp
            out[:, 2] = np.linalg.solve(jtj, np.einsum("nia,ni->na", jac, rhs)[..., None])[..., 0]
        return out


# ---------------------------------------------------------------------------- constructors
def _construct():
    from cadbridge.nurbs import construct

    return construct


def _angles(loc: np.ndarray) -> np.ndarray:
    return np.arctan2(loc[:, 1], loc[:, 0])


def plane_map(frame: Frame) -> ParamMap:
    """108 (OCC's gp_Pln(A, B, C, -D) frame) and 190: natural = NURBS = pcurve = (x, y)."""
    def build(r0, r1):
        return _construct().plane_surface(frame.origin, frame.axis, frame.x, r0, r1)

    ident = _affine(np.eye(2), np.zeros(2))
    return ParamMap("plane", lambda st: np.asarray(st, dtype=float), ident,
                    lambda p: frame.local(p)[:, :2], (False, False), build, lambda nat, r0, r1: nat, True)


def transposed_surface(s: NurbsSurface) -> NurbsSurface:
    """The same surface with u and v swapped (its normal S_u x S_v reversed)."""
    w = None if s.weights is None else np.asarray(s.weights).T
    u0, u1, v0, v1 = s.domain
    return NurbsSurface(s.degree_v, s.degree_u, s.knots_v, s.knots_u, np.asarray(s.control_points).transpose(1, 0, 2),
                        w, (v0, v1, u0, u1))


def _revolve(frame: Frame, generatrix: NurbsCurve, r1) -> NurbsSurface:
    """Revolved surface with u and v swapped: u = revolved v(theta), v = the generatrix
    parameter, so that Su x Sv points away from the axis as on OCC's gp_Cylinder, gp_Cone,
    gp_Sphere, gp_Torus (whose u is the angle about the axis too)."""
    return transposed_surface(_construct().revolved_surface(generatrix, frame.origin, frame.axis, r1[0], r1[1]))


def _theta_map(r1) -> ArcMap:
    """revolved v(theta) on the angle range r1 as an ArcMap."""
    return ArcMap(float(r1[0]), float(r1[1]) - float(r1[0]), float(r1[0]))


def _phi_map(r0) -> ArcMap:
    """arc parameter of phi on the range r0 as an ArcMap."""
    return ArcMap(float(r0[0]), float(r0[1]) - float(r0[0]), 0.0)


def _theta_v(nat: np.ndarray, r1) -> np.ndarray:
    return _construct().revolved_angle_to_v(np.clip(nat, r1[0], r1[1]), r1[0], r1[1])


def _height_line(frame: Frame, radius_at: Callable[[float], float], r0) -> NurbsCurve:
    c = _construct()
    from cadbridge.nurbs import edits

    h0, h1 = r0
    p0 = frame.origin + radius_at(h0) * frame.x + h0 * frame.axis
    p1 = frame.origin + radius_at(h1) * frame.x + h1 * frame.axis
    return edits.reparametrize_curve(c.line(p0, p1), (h0, h1))


def cylinder_map(frame: Frame, radius: float, cone_tan: float = 0.0, kind: str = "cylinder") -> ParamMap:
    """192 (cone_tan = 0) and 194 (radius + h tan(alpha) at height h): IGES (s, t) =
    (angle in degrees, height along the axis) as OpenCASCADE reads them; natural (h, theta);
    NURBS u = h, v = revolved v(theta)."""
    deg = pi / 180.0
    aff = _affine([[0.0, 1.0], [deg, 0.0]], np.zeros(2))

    def pts(p):
        loc = frame.local(p)
        return np.column_stack([loc[:, 2], _angles(loc)])

    def build(r0, r1):
        return _revolve(frame, _height_line(frame, lambda h: radius + h * cone_tan, r0), r1)

    def uv(nat, r0, r1):
        return np.column_stack([_theta_v(nat[:, 1], r1), nat[:, 0]])

    return ParamMap(kind, lambda st: _apply_affine(aff, np.asarray(st, dtype=float)), aff, pts, (False, True),
                    build, uv, uv_parts=lambda r0, r1: ((1, _theta_map(r1)), (0, None)))


def _tube_arc(frame: Frame, center: np.ndarray, r: float, r0) -> NurbsCurve:
    """Circle of radius r about ``center`` in the (X, A) plane, angle from X towards A,
    over r0 (arc parameter in [0, sweep])."""
    a0, a1 = r0
    s = center + r * (np.cos(a0) * frame.x + np.sin(a0) * frame.axis)
    e = center + r * (np.cos(a1) * frame.x + np.sin(a1) * frame.axis)
    if a1 - a0 >= TWO_PI * (1 - 1e-12):
        e = s
    return _construct().circular_arc(center, s, e, normal=-frame.y)


def _phi_u(nat0: np.ndarray, r0) -> np.ndarray:
    sweep = r0[1] - r0[0]
    return _construct().arc_parameter(np.clip(nat0 - r0[0], 0.0, sweep), sweep)


def sphere_map(frame: Frame, radius: float) -> ParamMap:
    """196: IGES (s, t) = (longitude, latitude) in degrees (OpenCASCADE's reading); natural
    (phi = latitude, theta); NURBS u = arc parameter of phi, v = revolved v(theta)."""
    deg = pi / 180.0
    aff = _affine([[0.0, deg], [deg, 0.0]], np.zeros(2))

    def pts(p):
        loc = frame.local(p)
        return np.column_stack([np.arctan2(loc[:, 2], np.hypot(loc[:, 0], loc[:, 1])), _angles(loc)])

    def build(r0, r1):
        r0 = (max(r0[0], -pi / 2), min(r0[1], pi / 2))
        return _revolve(frame, _tube_arc(frame, frame.origin, radius, r0), r1)

    def uv(nat, r0, r1):
        r0 = (max(r0[0], -pi / 2), min(r0[1], pi / 2))
        return np.column_stack([_theta_v(nat[:, 1], r1), _phi_u(nat[:, 0], r0)])

    def parts(r0, r1):
        return (1, _theta_map(r1)), (0, _phi_map((max(r0[0], -pi / 2), min(r0[1], pi / 2))))

    return ParamMap("sphere", lambda st: _apply_affine(aff, np.asarray(st, dtype=float)), aff, pts, (False, True),
                    build, uv, uv_parts=parts)


def torus_map(frame: Frame, major: float, minor: float) -> ParamMap:
    """198: IGES (s, t) in degrees with s the tube angle and theta = 360 - t about the axis
    (OpenCASCADE's reading: it mirrors t); natural (phi, theta); NURBS u = arc parameter of
    phi, v = revolved v(theta)."""
    deg = pi / 180.0
    aff = _affine([[deg, 0.0], [0.0, -deg]], np.array([0.0, TWO_PI]))

    def pts(p):
        loc = frame.local(p)
        rho = np.hypot(loc[:, 0], loc[:, 1])
        return np.column_stack([np.arctan2(loc[:, 2], rho - major), _angles(loc)])

    def build(r0, r1):
        return _revolve(frame, _tube_arc(frame, frame.origin + major * frame.x, minor, r0), r1)

    def uv(nat, r0, r1):
        return np.column_stack([_theta_v(nat[:, 1], r1), _phi_u(nat[:, 0], r0)])

    return ParamMap("torus", lambda st: _apply_affine(aff, np.asarray(st, dtype=float)), aff, pts, (True, True),
                    build, uv, uv_parts=lambda r0, r1: ((1, _theta_map(r1)), (0, _phi_map(r0))))


def _project(surface: NurbsSurface):
    try:
        from cadbridge.nurbs.project import project_to_surface
    except ImportError:  # pragma: no cover - optional module
        return None

    def fn(p):
        res = project_to_surface(surface, np.asarray(p, dtype=float))
        return np.column_stack([res.u, res.v])

    return fn


def _meridian_inverse(origin: np.ndarray, axis: np.ndarray, generatrix: NurbsCurve):
    """Exact inversion of the surface revolving the 3D ``generatrix`` about the line
    (origin, axis): a model point P -> (generatrix parameter u, rotation angle theta).
    theta = atan2 in the frame whose X is the generatrix's radial direction (right-handed
    about the axis); u from the nearest point of the generatrix to P rotated back into the
    generatrix half-plane (KD-tree over samples, then Newton on the curve). None when the
    generatrix lies on the axis."""
    from scipy.spatial import cKDTree

    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    o = np.asarray(origin, dtype=float)
    ts = generatrix.sample_parameters(32)
    g = _eval(generatrix, ts)
    rad = (g - o) - np.outer((g - o) @ a, a)
    rr = np.linalg.norm(rad, axis=1)
    if not rr.max() > 0:
        return None
    x = rad[int(np.argmax(rr))] / rr.max()
    y = np.cross(a, x)
    tree = cKDTree(g)
    t0, t1 = generatrix.domain

    def fn(p):
        r = np.asarray(p, dtype=float) - o
        h = r @ a
        rx, ry = r @ x, r @ y
        q = o + np.outer(h, a) + np.outer(np.hypot(rx, ry), x)
        t = ts[tree.query(q)[1]]
        for _ in range(6):
            d = _ders(generatrix, t, 2)
            e = d[:, 0] - q
            f = np.einsum("ij,ij->i", e, d[:, 1])
            g1 = np.einsum("ij,ij->i", d[:, 1], d[:, 1])
            fp = g1 + np.einsum("ij,ij->i", e, d[:, 2])
            t = np.clip(t - f / np.where(fp > 0, fp, g1 + 1e-300), t0, t1)
        return np.column_stack([t, np.arctan2(ry, rx)])

    return fn


def revolution_map(surface: NurbsSurface, sa: float, ta: float, gen_affine: tuple[float, float] | None,
                   gen_arc: ArcMap | None = None, axis: tuple[np.ndarray, np.ndarray] | None = None,
                   generatrix: NurbsCurve | None = None) -> ParamMap:
    """120: IGES (s, t) = (generatrix parameter, angle theta in radians); natural (u, theta)
    with u the NURBS generatrix parameter: u = a s + b (``gen_affine``) or the ArcMap of a 100
    generatrix (IGES parametrises it by angle); v = revolved v(theta) on [SA, TA]. Model points
    invert exactly through ``_meridian_inverse`` when the (model-space) axis and generatrix are
    given, else by projection onto the surface."""
    c = _construct()
    if gen_affine is not None:
        aff = _affine([[gen_affine[0], 0.0], [0.0, 1.0]], np.array([gen_affine[1], 0.0]))
    else:
        aff = _affine(np.eye(2), np.zeros(2))
    pre = (gen_arc, None)

    def pc(st):
        y = _apply_affine(aff, np.asarray(st, dtype=float))
        if gen_arc is not None:
            y[:, 0] = gen_arc(y[:, 0], 0)[0]
        return y

    def by_projection():
        proj = _project(surface)
        if proj is None:
            return None

        def fn(p):
            uv = proj(p)
            return np.column_stack([uv[:, 0], c.revolved_v_to_angle(uv[:, 1], sa, ta)])

        return fn

    pts = None
    if axis is not None and generatrix is not None:
        inv: list = []

        def pts(p):  # built on first use: most faces never invert model points
            if not inv:
                inv.append(_meridian_inverse(axis[0], axis[1], generatrix) or by_projection())
            return inv[0](p)
    else:
        pts = by_projection()

    def uv(nat, r0, r1):
        return np.column_stack([nat[:, 0], _theta_v(nat[:, 1], (sa, ta))])

    turned = None
    if axis is not None and abs((ta - sa) - TWO_PI) <= 1e-12 * TWO_PI:
        def turned(delta: float) -> NurbsSurface | None:
            return _turned_revolution(surface, axis[0], axis[1], (sa, ta), delta)

    return ParamMap("revolution", pc, aff, pts, (False, True), None, uv,
                    fixed_range=(None, (sa, ta)), surface=surface, pcurve_pre=pre,
                    uv_parts=lambda r0, r1: ((0, None), (1, _theta_map((sa, ta)))), turned=turned)


def _turned_revolution(surface: NurbsSurface, origin: np.ndarray, direction: np.ndarray, sweep: tuple[float, float],
                       delta: float) -> NurbsSurface | None:
    """A full-turn surface of revolution about the line ``origin`` + s ``direction`` with its
    control points rotated by +-delta about that line (exact: a rotation of the control net
    is the rotation of the surface), the sign for which S'(u, theta) = S(u, theta + delta)
    at sample points (a reflecting 124 turns the sense); None where neither sign gives that
    to 1e-9 x size."""
    n = np.asarray(direction, dtype=float)
    n = n / np.linalg.norm(n)
    o = np.asarray(origin, dtype=float)
    c = _construct()
    u0, u1, _, _ = surface.domain
    uu = np.linspace(u0, u1, 5)
    th = np.linspace(sweep[0], sweep[1], 7)[:-1]
    tt = np.tile(th, len(uu))
    uu = np.repeat(uu, len(th))
    want = surface.evaluate(uu, c.revolved_angle_to_v(np.mod(tt + delta - sweep[0], TWO_PI) + sweep[0], *sweep))
    box = surface.bbox()
    tol = 1e-9 * float(np.linalg.norm(box[1] - box[0]))
    for sign in (1.0, -1.0):
        a = sign * delta
        k = np.array([[0, -n[2], n[1]], [n[2], 0, -n[0]], [-n[1], n[0], 0]])
        rot = np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * (k @ k)  # Rodrigues
        cp = (surface.control_points - o) @ rot.T + o
        out = NurbsSurface(surface.degree_u, surface.degree_v, surface.knots_u, surface.knots_v, cp,
                           surface.weights if surface.rational else None)
        got = out.evaluate(uu, c.revolved_angle_to_v(tt, *sweep))
        if np.max(np.linalg.norm(got - want, axis=1)) <= tol:
            return out
    return None


def fixed_map(surface: NurbsSurface, pcurve_affine: tuple[np.ndarray, np.ndarray], kind: str) -> ParamMap:
    """118, 122 (and 128 without parameter-space curves): natural = NURBS (u, v); IGES
    parameters map to it by ``pcurve_affine``."""
    return ParamMap(kind, lambda st: _apply_affine(pcurve_affine, np.asarray(st, dtype=float)), pcurve_affine,
                    _project(surface), (False, False), None, lambda nat, r0, r1: nat, True, surface=surface)


# ---------------------------------------------------------------------------- loops
@dataclass
class MappedLoops:
    """Result of `map_loops`: the surface (built or fixed) and per loop the (u, v) pieces,
    each tagged with the index of the edge it came from and whether it is mapped (a
    `MappedCurve` / `InvertedCurve`, not a NurbsCurve)."""

    surface: NurbsSurface
    loops: list[list[tuple[int, "NurbsCurve | _TrimCurve", bool]]]
    sources: list[list[str]]  # per loop, per edge: "pcurve" or "model"
    ends: list[tuple[np.ndarray, np.ndarray]] | None = None  # per loop (u, v) of its start and end

    def closed(self, rel: float = 1e-6) -> list[bool]:
        """Per loop whether it closes in (u, v): end = start within rel x the domain's diagonal."""
        u0, u1, v0, v1 = self.surface.domain
        tol = rel * np.hypot(u1 - u0, v1 - v0)
        return [bool(np.linalg.norm(a - b) <= tol) for a, b in self.ends]


def _exact_natural(c: NurbsCurve, fn) -> NurbsCurve:
    """c with the affine map fn applied to its control points (knots, weights, domain kept:
    those of a valid curve, so only finiteness is left to check)."""
    cp = np.asarray(fn(c.control_points), dtype=float)
    if cp.ndim != 2 or cp.shape != (len(c.control_points), 2) or not np.isfinite(cp).all():
        return NurbsCurve(c.degree, c.knots, cp, c.weights, c.domain)  # its error
    return NurbsCurve._trusted(c.degree, c.knots, cp, c.weights, c.domain, c.rational)


def map_loops(pm: ParamMap, loops: list[list[tuple]], has_outer: bool, use_pcurves: bool) -> MappedLoops:
    """Map trim loops (lists of edges (pcurve pieces or None, model pieces or None)) into the
    NURBS (u, v) of the surface described by ``pm``, building the surface over the loops'
    extent when it is unbounded. Raises ValueError when an edge has no usable curve or the
    loops are degenerate."""
    ang = pm.angular
    items: list[list[tuple]] = []  # per loop: (edge index, curve, fn, exact)
    sources: list[list[str]] = []
    for loop in loops:
        its, src = [], []
        for j, (pc, mc) in enumerate(loop):
            if pc is not None and (use_pcurves or mc is None or pm.points_fn is None):
                chain, fn, s = pc, pm.pcurve_fn, "pcurve"
                exact = pm.pcurve_affine is not None and pm.pcurve_pre == (None, None)
            elif mc is not None and pm.points_fn is not None:
                chain, fn, exact, s = mc, pm.points_fn, pm.kind == "plane", "model"
            else:
                raise ValueError(f"edge {j + 1} of a trim loop has neither a parameter-space curve nor a "
                                 "model-space curve the reader can map")
            exact = exact and pm.uv_identity
            its.extend((j, c, fn, exact) for c in chain)
            src.append(s)
        if not its:
            raise ValueError("empty trim loop")
        items.append(its)
        sources.append(src)
    # phase 1: natural coordinates, angles continuous along each loop; the sampled pieces of
    # all loops in one batch per (map, dimension) (`_sample_many`), kept for the InvertedCurves
    groups: dict[tuple, list[tuple[int, int]]] = {}
    for li, its in enumerate(items):
        for ii, (_, c, fn, exact) in enumerate(its):
            if not exact:
                groups.setdefault((id(fn), c.dim), []).append((li, ii))
    samples: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}
    for keys in groups.values():
        fn = items[keys[0][0]][keys[0][1]][2]
        samples.update(zip(keys, _sample_many([items[li][ii][1] for li, ii in keys], fn, ang)))
    nats: list[list[np.ndarray]] = []
    shifts: list[list[np.ndarray]] = []
    exact_nat: dict[tuple[int, int], NurbsCurve] = {}  # the exactly mapped pieces, made once
    for li, its in enumerate(items):
        prev = None
        ln, ls = [], []
        for ii, (_, c, fn, exact) in enumerate(its):
            if exact:
                nat = exact_nat[li, ii] = _exact_natural(c, fn)
                # the curve lies in the convex hull of its control points (positive weights): their
                # box is the box of control points and curve samples together
                pts = nat.control_points
            else:
                pts = samples[li, ii][1]
            sh = np.zeros(2)
            if prev is not None:
                for k in (0, 1):
                    if ang[k]:
                        sh[k] = TWO_PI * np.round((prev[k] - pts[0, k]) / TWO_PI)
            pts = pts + sh
            if ang[0] or ang[1]:  # only angles need the previous piece's end
                prev = pts[-1] if not exact else _eval(exact_nat[li, ii], [c.domain[1]])[0]
            ln.append(pts)
            ls.append(sh)
        nats.append(ln)
        shifts.append(ls)
    # a full turn whose seam crosses the first loop: the seam moved off it (the surface turned
    # by delta about its axis, every angle shifted by -delta), so the loop lies inside [SA, TA]
    # and its (u, v) image does not jump by a period
    turned = None
    if pm.turned is not None and nats:
        for k in (0, 1):
            if not (ang[k] and pm.fixed_range is not None and pm.fixed_range[k] is not None):
                continue
            a0, a1 = pm.fixed_range[k]
            allp = np.vstack(nats[0])
            lo_k, hi_k = float(allp[:, k].min()), float(allp[:, k].max())
            mid, target = 0.5 * (lo_k + hi_k), 0.5 * (a0 + a1)
            d = TWO_PI * np.round((target - mid) / TWO_PI)
            slack = 1e-9 * TWO_PI
            if lo_k + d >= a0 - slack and hi_k + d <= a1 + slack or hi_k - lo_k >= TWO_PI * (1 - 1e-9):
                continue  # inside already, or a whole turn: no seam position helps
            delta = mid + d - target
            turned = pm.turned(delta)
            if turned is not None:
                step = -delta * np.eye(2)[k]
                nats = [[n + step for n in ln] for ln in nats]
                shifts = [[s_ + step for s_ in ls] for ls in shifts]
    # loop-level shifts: the first loop into the fixed range, the others next to it
    ranges = [None, None]
    ref_mid = [None, None]
    for li in range(len(nats)):
        allp = np.vstack(nats[li])
        for k in (0, 1):
            if not ang[k]:
                continue
            lo_k, hi_k = float(allp[:, k].min()), float(allp[:, k].max())
            if hi_k - lo_k > TWO_PI * (1 + WIND_TOL):  # a loop covers one turn at most
                raise ValueError(f"trim loop {li + 1} winds {(hi_k - lo_k) / TWO_PI:.4g} turns about the axis "
                                 f"(angles {lo_k:.6g}..{hi_k:.6g} rad)")
            mid = 0.5 * (lo_k + hi_k)
            target = None
            if pm.fixed_range is not None and pm.fixed_range[k] is not None:
                target = 0.5 * (pm.fixed_range[k][0] + pm.fixed_range[k][1])
            if li > 0 and ref_mid[k] is not None:
                target = ref_mid[k]
            if target is not None:
                d = TWO_PI * np.round((target - mid) / TWO_PI)
                if d:
                    nats[li] = [n + np.eye(2)[k] * d for n in nats[li]]
                    shifts[li] = [s + np.eye(2)[k] * d for s in shifts[li]]
                    mid += d
            if li == 0:
                ref_mid[k] = mid
    use = nats if not has_outer else nats[:1]
    allp = np.vstack([n for ln in use for n in ln])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    for k in (0, 1):
        if pm.fixed_range is not None and pm.fixed_range[k] is not None:
            ranges[k] = tuple(pm.fixed_range[k])
            continue
        a, b = float(lo[k]), float(hi[k])
        if ang[k] and b - a > TWO_PI * (1 - 1e-9):
            b = a + TWO_PI
        if not b - a > 1e-12 * max(1.0, abs(a), abs(b)):
            raise ValueError("trim loops are degenerate (zero extent)")
        ranges[k] = (a, b)
    r0, r1 = ranges
    surface = turned if turned is not None else pm.build(r0, r1) if pm.build is not None else pm.surface
    post = pm.uv_parts(r0, r1)
    out: list[list[tuple[int, NurbsCurve | _TrimCurve, bool]]] = []
    for li, (its, ls) in enumerate(zip(items, shifts)):
        pieces: list[tuple[int, NurbsCurve | _TrimCurve, bool]] = []
        for ii, ((j, c, fn, exact), sh) in enumerate(zip(its, ls)):
            if exact:
                nat = exact_nat[li, ii]
                if np.any(sh):
                    nat = NurbsCurve(nat.degree, nat.knots, nat.control_points + sh, nat.weights, nat.domain)
                pieces.append((j, nat, False))
            elif fn is pm.pcurve_fn:
                m, b = pm.pcurve_affine
                pieces.append((j, MappedCurve(c, m, b + sh, pm.pcurve_pre, post), True))
            else:
                t, nat = samples[li, ii]
                pieces.append((j, InvertedCurve(c, fn, sh, post, ang, t, nat + sh, surface), True))
        out.append(pieces)
    # (u, v) of each loop's start and end: exact pieces evaluated, mapped ones from their natural
    # samples (which include the domain ends) through the same scalar maps as their evaluation
    ends: list = []
    post_nat = []  # (loop, 0 start / 1 end, natural point) for the mapped ends
    for li, (its, pieces) in enumerate(zip(items, out)):
        pair: list = [None, None]
        for e, ii in ((0, 0), (1, len(its) - 1)):
            if its[ii][3]:
                c = pieces[ii][1]
                pair[e] = _eval(c, [c.domain[e]])[0]
            else:
                post_nat.append((li, e, samples[li, ii][1][-e] + shifts[li][ii]))
        ends.append(pair)
    if post_nat:
        nat = np.array([x for _, _, x in post_nat])
        uv = np.column_stack([nat[:, src] if mp is None else mp(nat[:, src], 0)[0] for src, mp in post])
        for (li, e, _), q in zip(post_nat, uv):
            ends[li][e] = q
    return MappedLoops(surface, out, sources, [(a, b) for a, b in ends])


# ---------------------------------------------------------------------------- 128 without pcurves
class SurfaceInvertedCurve(InvertedCurve):
    """A model-space edge C(t) (3D NurbsCurve) inverted onto a NURBS surface S by Newton:
    uv(t) = the foot of C(t) on S, each evaluation started from the reference table
    (t_ref, uv_ref) interpolated at t (`invert_edges` builds the table by the global
    projection, with periodic parameters unwrapped along the loop and parameters that are
    undefined at a pole filled from the neighbouring samples). In a closed direction the foot
    is shifted by whole periods to the reference; at a pole (where S's tangent along a
    parameter vanishes) that parameter is the reference's. Derivatives as `InvertedCurve`
    (chain rule through the surface Jacobian)."""

    def __init__(self, base: NurbsCurve, surface: NurbsSurface, t_ref: np.ndarray, uv_ref: np.ndarray,
                 period: tuple[float, float], pole_tol: float) -> None:
        super().__init__(base, None, np.zeros(2), ((0, None), (1, None)), (False, False), t_ref, uv_ref, surface)
        self.period = tuple(float(p) for p in period)
        self.pole_tol = float(pole_tol)

    def _natural(self, t) -> np.ndarray:
        t = np.atleast_1d(np.asarray(t, dtype=float)).ravel()
        seed, pts = self._seed_points(t)
        return _inverted_feet(self.surface, pts, seed, self.period, self.pole_tol)

    def _seed_points(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Seeds (N, 2) interpolated in the reference table and the edge's points C(t) (N, 3)."""
        seed = np.column_stack([np.interp(t, self.t_ref, self.nat_ref[:, k]) for k in (0, 1)])
        return seed, _eval(self.base, t)

    def derivatives(self, t, order: int = 1) -> np.ndarray:
        """Derivatives of the foot uv(t) up to ``order`` (<= 2): t (N,) -> (N, order+1, 2).

        Exact also where C is off S (by the file's delta): uv(t) solves F = J^T r = 0 with
        r = S(uv) - C(t), J = [Su Sv]; implicit differentiation gives H w = J^T C' with
        H_ab = S_a . S_b + S_ab . r, w = uv', and H w' = S_a . C'' + (S_ac w_c) . C'
        - (S_ac . S_b + S_a . S_bc + S_abc . r) w_b w_c - (S_ab . (J w - C')) w_b (summed
        over b, c). Where the foot is held on an edge of the domain (the nearest point of S
        lies beyond it), or at a pole along the parameter S does not depend on there, that
        parameter is constant and the other follows the same equations.
        """
        if order > 2:
            raise ValueError("SurfaceInvertedCurve derivatives are implemented up to order 2")
        t = np.atleast_1d(np.asarray(t, dtype=float)).ravel()
        uv = self._natural(t)
        out = np.zeros((len(t), order + 1, 2))
        out[:, 0] = uv
        if order == 0:
            return out
        u0, u1, v0, v1 = self.surface.domain
        d = self.surface.derivatives(np.clip(uv[:, 0], u0, u1), np.clip(uv[:, 1], v0, v1), order=order + 1)
        c = _ders(self.base, t, order)
        r = d[:, 0, 0] - c[:, 0]
        s1 = np.stack([d[:, 1, 0], d[:, 0, 1]], axis=1)  # (N, 2, 3): S_a
        s2 = np.stack([np.stack([d[:, 2, 0], d[:, 1, 1]], 1), np.stack([d[:, 1, 1], d[:, 0, 2]], 1)], 1)  # S_ab
        h = np.einsum("nai,nbi->nab", s1, s1) + np.einsum("nabi,ni->nab", s2, r)
        # a foot held on the domain's edge (the projection clamps there): that parameter is
        # constant, the other one follows the 1D foot condition along the edge
        held = np.column_stack([(uv[:, 0] <= u0) | (uv[:, 0] >= u1), (uv[:, 1] <= v0) | (uv[:, 1] >= v1)])
        held |= np.linalg.norm(s1, axis=2) <= self.pole_tol  # at a pole: the parameter S does not depend on
        for k in (0, 1):
            h[held[:, k], k, :] = 0.0
            h[held[:, k], :, k] = 0.0
            h[held[:, k], k, k] = 1.0
        rhs1 = np.einsum("nai,ni->na", s1, c[:, 1])
        rhs1[held] = 0.0
        w = np.linalg.solve(h, rhs1[..., None])[..., 0]
        out[:, 1] = w
        if order >= 2:
            s3 = np.empty((len(t), 2, 2, 2, 3))  # S_abc: index sum k = number of u's
            for a in (0, 1):
                for b in (0, 1):
                    for e in (0, 1):
                        nu = 3 - (a + b + e)
                        s3[:, a, b, e] = d[:, nu, 3 - nu]
            sw = np.einsum("naci,nc->nai", s2, w)  # S_ac w_c
            rhs = np.einsum("nai,ni->na", s1, c[:, 2]) + np.einsum("nai,ni->na", sw, c[:, 1])
            rhs -= np.einsum("nai,nbi,nb->na", sw, s1, w)  # (S_ac w_c) . S_b w_b
            rhs -= np.einsum("nai,nbi,nb->na", s1, sw, w)  # S_a . (S_bc w_c) w_b
            rhs -= np.einsum("nabci,ni,nb,nc->na", s3, r, w, w)
            rhs -= np.einsum("nabi,ni,nb->na", s2, np.einsum("nbi,nb->ni", s1, w) - c[:, 1], w)
            rhs[held] = 0.0
            out[:, 2] = np.linalg.solve(h, rhs[..., None])[..., 0]
        return out


def _inverted_feet(surface: NurbsSurface, pts: np.ndarray, seed: np.ndarray, period: tuple[float, float],
                   pole_tol: float) -> np.ndarray:
    """Feet (N, 2) of ``pts`` (N, 3) on ``surface`` from ``seed`` (N, 2): Newton from the seed
    (wrapped / clamped into the domain; the global projection where it stalls), `_polish`ed,
    made continuous with the seed (`_fix_uv`). Point by point: a batch of many curves' points
    gives what each curve's own call gives."""
    from cadbridge.nurbs.project import FAILED, project_to_surface

    u0, u1, v0, v1 = surface.domain
    lo, hi = np.array([u0, v0]), np.array([u1, v1])
    start = seed.copy()
    for k in (0, 1):
        if period[k] > 0:
            start[:, k] = lo[k] + np.mod(start[:, k] - lo[k], period[k])
    start = np.clip(start, lo, hi)
    res = project_to_surface(surface, pts, uv0=start, global_check=False)
    uv = np.column_stack([res.u, res.v])
    bad = res.status == FAILED
    if bad.any():  # Newton from the table stalled: the global projection
        g = project_to_surface(surface, pts[bad])
        uv[bad] = np.column_stack([g.u, g.v])
    uv = _polish(surface, uv, pts)
    return _fix_uv(surface, uv, seed, period, pole_tol)


def evaluate_inverted(curves: list[SurfaceInvertedCurve], ts: list[np.ndarray]) -> list[np.ndarray]:
    """``[c.evaluate(t) for c, t in zip(curves, ts)]`` with one Newton / polish pass per
    surface (curves of one loop share it): (N_k, 2) each."""
    out: list = [None] * len(curves)
    groups: dict[tuple, list[int]] = {}
    for k, c in enumerate(curves):
        groups.setdefault((id(c.surface), c.period, c.pole_tol), []).append(k)
    for (_, period, pole_tol), idx in groups.items():
        parts = [curves[k]._seed_points(np.atleast_1d(np.asarray(ts[k], dtype=float)).ravel()) for k in idx]
        uv = _inverted_feet(curves[idx[0]].surface, np.concatenate([p for _, p in parts]),
                            np.concatenate([s for s, _ in parts]), period, pole_tol)
        for k, piece in zip(idx, np.split(uv, np.cumsum([len(s) for s, _ in parts])[:-1])):
            out[k] = piece
    return out


def _polish(surface: NurbsSurface, uv: np.ndarray, pts: np.ndarray, steps: int = 2) -> np.ndarray:
    """Full Newton steps on J^T (S(uv) - P) = 0 (H = J^T J + S_ab . r) from converged feet:
    the feet to rounding, so that uv(t) is smooth to rounding too (the projection's stopping
    rule leaves noise that a 1e-10 Hermite fit, `to_nurbs`, chases without end). A step that
    would leave the domain, or where H is not positive definite (a pole), is not taken."""
    u0, u1, v0, v1 = surface.domain
    lo, hi = np.array([u0, v0]), np.array([u1, v1])
    uv = np.array(uv, dtype=float)
    for _ in range(steps):
        d = surface.derivatives(np.clip(uv[:, 0], u0, u1), np.clip(uv[:, 1], v0, v1), order=2)
        r = d[:, 0, 0] - pts
        su, sv = d[:, 1, 0], d[:, 0, 1]
        g = np.column_stack([np.einsum("ni,ni->n", su, r), np.einsum("ni,ni->n", sv, r)])
        huu = np.einsum("ni,ni->n", su, su) + np.einsum("ni,ni->n", d[:, 2, 0], r)
        huv = np.einsum("ni,ni->n", su, sv) + np.einsum("ni,ni->n", d[:, 1, 1], r)
        hvv = np.einsum("ni,ni->n", sv, sv) + np.einsum("ni,ni->n", d[:, 0, 2], r)
        det = huu * hvv - huv * huv
        ok = (huu > 0) & (hvv > 0) & (det > 1e-12 * np.maximum(huu * hvv, 1e-300))
        sd = np.where(ok, det, 1.0)
        step = np.column_stack([(hvv * g[:, 0] - huv * g[:, 1]) / sd, (huu * g[:, 1] - huv * g[:, 0]) / sd])
        new = uv - np.where(ok[:, None], step, 0.0)
        out = (new < lo) | (new > hi)
        # a foot on the domain's edge (the projection's clamp) stays there; the other
        # parameter by the 1D Newton step along the edge
        for k, hkk in ((0, hvv), (1, huu)):  # k clamped -> the other one (o) moves by g_o / H_oo
            o = 1 - k
            one = out[:, k] & ~out[:, o] & ok
            new[one, k] = np.clip(new[one, k], lo[k], hi[k])
            new[one, o] = uv[one, o] - g[one, o] / hkk[one]
        new = np.where((np.all(out, axis=1) | ~ok)[:, None], uv, new)
        new = np.where(np.all((new >= lo) & (new <= hi), axis=1)[:, None], new, uv)
        uv = new
    return uv


def _fix_uv(surface: NurbsSurface, uv: np.ndarray, ref: np.ndarray, period: tuple[float, float],
            pole_tol: float) -> np.ndarray:
    """Feet (N, 2) made continuous with ``ref`` (N, 2): closed directions shifted by whole
    periods to the reference, a parameter undefined at a pole (|S_u| or |S_v| <= pole_tol
    there) replaced by the reference's."""
    uv = np.array(uv, dtype=float)
    for k in (0, 1):
        if period[k] > 0:
            uv[:, k] -= period[k] * np.round((uv[:, k] - ref[:, k]) / period[k])
    u0, u1, v0, v1 = surface.domain
    d = surface.derivatives(np.clip(uv[:, 0], u0, u1), np.clip(uv[:, 1], v0, v1), order=1)
    for k, dk in ((0, d[:, 1, 0]), (1, d[:, 0, 1])):
        pole = np.linalg.norm(dk, axis=1) <= pole_tol
        uv[pole, k] = ref[pole, k]
    return uv


def invert_edges(surface: NurbsSurface, pieces: list[NurbsCurve], rel_gap: float = 1e-9,
                 join_rel: float = 1e-3) -> list:
    """A trim loop in the (u, v) of a NURBS surface from the model-space pieces of its edges
    (3D NurbsCurves joined end to start, in loop order, each already oriented along the loop).

    Each piece becomes a `SurfaceInvertedCurve`. Its reference table: the piece's samples
    (`MIN_PER_SPAN` per knot span) projected globally onto S (`project_to_surface`), then
    along the whole loop in order: periodic parameters of a closed surface
    (`closed_directions`) unwrapped (the loop shifted by whole periods so its middle lies in
    the domain), and a parameter left undefined at a pole filled from the nearest sample of
    the same piece where it is defined. Where two consecutive pieces (or the last and the
    first) meet at one 3D point but at (u, v) farther apart than ``rel_gap`` x the domain's
    diagonal (along a degenerate edge of S: a pole), the straight (u, v) line between the two
    is inserted (it maps to that one point). Returns the (u, v) pieces. Raises ValueError
    when a piece cannot be projected or the loop winds around a closed direction."""
    from cadbridge.cad.edgefeet import edge_feet
    from cadbridge.nurbs.curve_pack import PackedCurves
    from cadbridge.nurbs.project import surface_samples

    if not pieces:
        raise ValueError("empty trim loop")
    u0, u1, v0, v1 = surface.domain
    diag = float(np.hypot(u1 - u0, v1 - v0))
    box = surface.bbox()
    size = max(float(np.linalg.norm(box[1] - box[0])), 1e-300)
    samples = surface_samples(surface)  # cached per surface; its closed directions are `closed_directions`
    period = (u1 - u0 if samples.closed_u else 0.0, v1 - v0 if samples.closed_v else 0.0)
    pole_tol = 1e-9 * size / max(diag, 1e-300)
    packed = PackedCurves(pieces)  # all pieces sampled and evaluated in one compiled call each
    ci, tt = packed.sample(MIN_PER_SPAN)
    allp = packed.evaluate(ci, tt, 0)[:, 0]
    starts = np.searchsorted(ci, np.arange(len(pieces) + 1))
    uv, failed = edge_feet(surface, allp, tt, starts, pole_tol)  # global feet (continued along each piece)
    if np.any(failed):
        raise ValueError(f"{int(np.sum(failed))} points of the model-space edges could not be "
                         "projected onto the surface")
    cuts = starts[1:-1]
    ts = np.split(tt, cuts)
    pts = np.split(allp, cuts)
    d = surface.derivatives(uv[:, 0], uv[:, 1], order=1)
    # poles: fill an undefined parameter from the nearest defined sample of the same piece
    for k, dk in ((0, d[:, 1, 0]), (1, d[:, 0, 1])):
        pole = np.linalg.norm(dk, axis=1) <= pole_tol
        if not pole.any():
            continue
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, len(uv)]):
            ok = np.flatnonzero(~pole[a:b])
            if ok.size and not pole[a:b].all():
                idx = np.arange(b - a)
                near = ok[np.abs(idx[:, None] - ok[None, :]).argmin(axis=1)]
                uv[a:b, k] = uv[a + near, k]
    for k in (0, 1):  # seams: continuous along the loop, its middle inside the domain
        if period[k] > 0:
            uv[:, k] = np.unwrap(uv[:, k], period=period[k])
            lo = (u0, v0)[k]
            mid = 0.5 * (uv[:, k].min() + uv[:, k].max())
            uv[:, k] -= period[k] * np.floor((mid - lo) / period[k])
    refs = np.split(uv, cuts)
    out: list = []
    n = len(pieces)
    for i, (c, t, r) in enumerate(zip(pieces, ts, refs)):
        out.append(SurfaceInvertedCurve(c, surface, t, r, period, pole_tol))
        a, b = r[-1], refs[(i + 1) % n][0]
        gap3 = float(np.linalg.norm(pts[(i + 1) % n][0] - pts[i][-1]))
        if gap3 > join_rel * size:
            raise ValueError(f"pieces {i + 1} and {(i + 1) % n + 1} of the loop do not join in model space "
                             f"(gap {gap3:.3g})")
        if np.linalg.norm(b - a) > rel_gap * diag:
            for k in (0, 1):
                if period[k] > 0 and abs(b[k] - a[k]) > 0.5 * period[k]:
                    raise ValueError("the loop winds around the closed surface (no seam edge): not a "
                                     "closed loop in (u, v)")
            out.append(NurbsCurve(1, np.array([0.0, 0.0, 1.0, 1.0]), np.vstack([a, b])))
    return out
