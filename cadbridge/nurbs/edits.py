"""Object-level NURBS edits (Piegl & Tiller ch. 5): the array algorithms of
`cadbridge.nurbs.knots` applied to :class:`NurbsCurve` and :class:`NurbsSurface`, each
returning a new object with the same geometry (or, for ``reverse`` and ``reparametrize``, the
same point set), plus Bézier decompositions, tight boxes and iso-curves."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from cadbridge.nurbs.basis import basis_funs, find_span
from cadbridge.nurbs.curve import NurbsCurve
from cadbridge.nurbs.knots import (decompose, elevate_degree, from_homogeneous, merge_knots, missing_knots, refine_knots,
                                   reparametrize, restrict, reverse)
from cadbridge.nurbs.surface import NurbsSurface

__all__ = [
    "make_compatible",
    "curve_from_homogeneous",
    "restrict_curve",
    "refine_curve",
    "elevate_curve",
    "reverse_curve",
    "reparametrize_curve",
    "curve_bezier_segments",
    "curve_tight_bbox",
    "surface_from_homogeneous",
    "restrict_surface",
    "refine_surface",
    "elevate_surface",
    "bezier_patches",
    "tight_bbox",
    "isocurve",
]


# ---------------------------------------------------------------------------- curve helpers
def curve_from_homogeneous(p: int, knots, ctrl_w, domain=None) -> NurbsCurve:
    """NurbsCurve from homogeneous control points (n, d+1)."""
    pts, w = from_homogeneous(ctrl_w)
    return NurbsCurve(p, knots, pts, None if np.ptp(w) == 0.0 else w, domain)


def restrict_curve(curve: NurbsCurve, t0: float | None = None, t1: float | None = None) -> NurbsCurve:
    """The curve over [t0, t1] (default its domain) with a clamped knot vector."""
    a, b = curve.domain
    t0 = a if t0 is None else t0
    t1 = b if t1 is None else t1
    k, p = curve.knots, curve.degree
    if (t0 == k[0] == k[p] and t1 == k[-1] == k[-p - 1]):
        return curve  # already clamped over exactly [t0, t1] (the usual IGES generatrix)
    kn, cw = restrict(k, p, curve._pw, t0, t1)
    return curve_from_homogeneous(curve.degree, kn, cw)


def refine_curve(curve: NurbsCurve, new_knots) -> NurbsCurve:
    """The curve with ``new_knots`` inserted (A5.4); domain kept."""
    kn, cw = refine_knots(curve.knots, curve.degree, curve._pw, new_knots)
    return curve_from_homogeneous(curve.degree, kn, cw, curve.domain)


def elevate_curve(curve: NurbsCurve, t: int = 1) -> NurbsCurve:
    """The curve restricted to its domain with degree raised by ``t``."""
    c = restrict_curve(curve)
    kn, cw = elevate_degree(c.knots, c.degree, c._pw, t)
    return curve_from_homogeneous(c.degree + t, kn, cw)


def reverse_curve(curve: NurbsCurve) -> NurbsCurve:
    """The curve traversed backwards over its domain [a, b]: C'(t) = C(a + b - t)."""
    c = restrict_curve(curve)
    kn, cw = reverse(c.knots, c.degree, c._pw)
    return curve_from_homogeneous(c.degree, kn, cw)


def reparametrize_curve(curve: NurbsCurve, new_range) -> NurbsCurve:
    """The curve restricted to its domain, affinely reparametrised onto ``new_range``."""
    c = restrict_curve(curve)
    return curve_from_homogeneous(c.degree, reparametrize(c.knots, new_range), c._pw)


def make_compatible(curves: Sequence[NurbsCurve], new_range=(0.0, 1.0)) -> list[NurbsCurve]:
    """Curves with the same degree (the largest), the same clamped knot vector over
    ``new_range`` and hence the same number of control points. Each curve is restricted to
    its domain and affinely reparametrised onto ``new_range`` first; geometry is unchanged."""
    cs = [reparametrize_curve(c, new_range) for c in curves]
    p = max(c.degree for c in cs)
    cs = [elevate_curve(c, p - c.degree) if c.degree < p else c for c in cs]
    common = merge_knots([c.knots for c in cs])
    return [refine_curve(c, missing_knots(c.knots, common)) for c in cs]


def curve_bezier_segments(curve: NurbsCurve) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bézier pieces of the curve over its domain.

    Returns breaks (K+1,), control points (K, p+1, dim), weights (K, p+1).
    """
    c = restrict_curve(curve)
    breaks, segs = decompose(c.knots, c.degree, c._pw)
    pts, w = from_homogeneous(segs)
    return breaks, pts, w


def curve_tight_bbox(curve: NurbsCurve) -> np.ndarray:
    """(2, dim) box of the Bézier control polygons over the domain; contains the curve and
    is contained in ``curve.bbox()``."""
    _, pts, _ = curve_bezier_segments(curve)
    pts = pts.reshape(-1, pts.shape[-1])
    return np.array([pts.min(axis=0), pts.max(axis=0)])


# ---------------------------------------------------------------------------- surface helpers
def surface_from_homogeneous(p: int, q: int, knots_u, knots_v, ctrl_w, domain=None) -> NurbsSurface:
    """NurbsSurface from homogeneous control points (nu, nv, 4)."""
    pts, w = from_homogeneous(ctrl_w)
    return NurbsSurface(p, q, knots_u, knots_v, pts, None if np.ptp(w) == 0.0 else w, domain)


def restrict_surface(surface: NurbsSurface, domain=None) -> NurbsSurface:
    """The surface over ``domain`` (default its own) with clamped knot vectors."""
    u0, u1, v0, v1 = surface.domain if domain is None else domain
    p, q = surface.degree_u, surface.degree_v
    ku, cw = restrict(surface.knots_u, p, surface._pw, u0, u1, axis=0)
    kv, cw = restrict(surface.knots_v, q, cw, v0, v1, axis=1)
    return surface_from_homogeneous(p, q, ku, kv, cw)


def refine_surface(surface: NurbsSurface, new_u=(), new_v=()) -> NurbsSurface:
    """The surface with knots inserted in u and/or v (A5.5); domain kept."""
    p, q = surface.degree_u, surface.degree_v
    ku, cw = refine_knots(surface.knots_u, p, surface._pw, new_u, axis=0)
    kv, cw = refine_knots(surface.knots_v, q, cw, new_v, axis=1)
    return surface_from_homogeneous(p, q, ku, kv, cw, surface.domain)


def elevate_surface(surface: NurbsSurface, tu: int = 0, tv: int = 0) -> NurbsSurface:
    """The surface restricted to its domain with degrees raised by (tu, tv) (A5.10)."""
    s = restrict_surface(surface)
    p, q = s.degree_u, s.degree_v
    ku, cw = elevate_degree(s.knots_u, p, s._pw, tu, axis=0)
    kv, cw = elevate_degree(s.knots_v, q, cw, tv, axis=1)
    return surface_from_homogeneous(p + tu, q + tv, ku, kv, cw)


def bezier_patches(surface: NurbsSurface) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bézier patches of the surface over its domain (split at the domain ends first).

    Returns uv_boxes (K, 4) rows (u0, u1, v0, v1), control points (K, p+1, q+1, 3) and
    weights (K, p+1, q+1); patch k = iu * Kv + iv (v fastest).
    """
    p, q = surface.degree_u, surface.degree_v
    ku_, kv_ = surface.knots_u, surface.knots_v
    if (len(ku_) == 2 * (p + 1) and len(kv_) == 2 * (q + 1) and ku_[0] == ku_[p] and ku_[p + 1] == ku_[-1]
            and kv_[0] == kv_[q] and kv_[q + 1] == kv_[-1]
            and tuple(surface.domain) == (ku_[p], ku_[p + 1], kv_[q], kv_[q + 1])):
        # already one clamped Bézier patch over its domain (most faces of real CAD): nothing to cut
        pts, w = from_homogeneous(surface._pw[None])
        return np.array([[ku_[p], ku_[p + 1], kv_[q], kv_[q + 1]]], dtype=float), pts, w
    s = restrict_surface(surface)
    p, q = s.degree_u, s.degree_v
    bu, segs = decompose(s.knots_u, p, s._pw, axis=0)  # (Ku, p+1, nv, 4)
    bv, segs = decompose(s.knots_v, q, segs, axis=2)  # (Kv, Ku, p+1, q+1, 4)
    segs = np.swapaxes(segs, 0, 1)  # (Ku, Kv, p+1, q+1, 4)
    ku, kv = len(bu) - 1, len(bv) - 1
    segs = segs.reshape(ku * kv, p + 1, q + 1, 4)
    iu, iv = np.divmod(np.arange(ku * kv), kv)
    boxes = np.stack([bu[iu], bu[iu + 1], bv[iv], bv[iv + 1]], axis=1)
    pts, w = from_homogeneous(segs)
    return boxes, pts, w


def tight_bbox(surface: NurbsSurface) -> np.ndarray:
    """(2, 3) box of the Bézier patch control nets over the surface domain: contains the
    surface (convex hull property) and is contained in ``surface.bbox()``; much tighter when
    the domain is a sub-range of the knot domain or the knots are dense."""
    _, pts, _ = bezier_patches(surface)
    pts = pts.reshape(-1, 3)
    return np.array([pts.min(axis=0), pts.max(axis=0)])


def isocurve(surface: NurbsSurface, direction: str, t: float) -> NurbsCurve:
    """The iso-parametric curve of ``surface`` at u = t (``direction="u"``, a curve in v) or
    v = t (``"v"``, a curve in u), exact, over the surface's domain in the other parameter.

    In homogeneous coordinates S^w(t, v) = sum_j (sum_i N_i(t) P^w_ij) N_j(v) (P&T eq. 4.15
    applied to one direction), so the curve's control points are Q^w_j = sum_i N_i(t) P^w_ij
    with the other direction's knots and degree. At a C0 knot both one-sided limits agree.
    """
    if direction not in ("u", "v"):
        raise ValueError(f"direction must be 'u' or 'v', got {direction!r}")
    pw = surface._pw  # (nu, nv, 4)
    if direction == "u":
        knots, p, other_knots, q, axis = surface.knots_u, surface.degree_u, surface.knots_v, surface.degree_v, 0
        dom = surface.domain[2:]
    else:
        knots, p, other_knots, q, axis = surface.knots_v, surface.degree_v, surface.knots_u, surface.degree_u, 1
        dom = surface.domain[:2]
    tt = np.array([float(t)])
    span = find_span(knots, p, tt)
    n = basis_funs(span, tt, p, knots)[0]  # (p+1,)
    rows = np.take(pw, np.arange(span[0] - p, span[0] + 1), axis=axis)  # (p+1, nv, 4) or (nu, p+1, 4)
    qw = np.tensordot(n, rows, axes=([0], [axis]))  # (n_other, 4)
    return curve_from_homogeneous(q, other_knots, qw, dom)
