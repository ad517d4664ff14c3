"""Inflections of one NURBS surface: where the normal curvature changes sign along a direction.

A Nagata edge is quadratic, so it cannot follow an inflection between its end nodes (thesis
§6.2.2, Fig. 56): nodes must sit on (or near) the inflection lines. Two ways to find them:

* **Curvature** (`segment_inflections`, `inflection_lines`): the signed normal curvature
  k_n(t) along a straight (u, v) segment, from the analytic second fundamental form
  (`cadbridge.nurbs.curvature.normal_curvature`), sampled, and every sign change bisected on
  the exact surface down to a parameter tolerance.
* **Control polygon** (`control_polygon_inflections`, thesis Fig. 59): the iso-curve's exact
  control polygon (`cadbridge.nurbs.edits.isocurve`) turns one way, then the other; the leg
  joining the two corners where the turning changes sign crosses the curve near its
  inflection, and the crossing is taken as the estimate. By the variation-diminishing
  property a planar curve has no more inflections than its polygon has turning sign changes,
  but the crossing is not the inflection itself (tests measure how far off it is).

The curvature route is exact and is the one the mesher uses; the polygon route is kept as an
independent screen (it cannot miss an inflection between samples on a planar iso-curve).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cadbridge.nurbs.curvature import normal_curvature
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["InflectionLine", "control_polygon_inflections", "inflection_lines", "segment_inflections"]


def _kn(surface: NurbsSurface, u0, v0, du, dv, t):
    return normal_curvature(surface, u0 + t * du, v0 + t * dv, du, dv)


def segment_inflections(surface: NurbsSurface, uv0: ArrayLike, uv1: ArrayLike, samples: int = 17,
                        tol: float = 1e-12, rel_zero: float = 1e-9, k_zero: ArrayLike | None = None) -> NDArray:
    """First inflection on each straight (u, v) segment uv0 -> uv1 (N, 2): the parameter
    t in (0, 1) (N,) where the normal curvature in the segment's direction changes sign, or
    NaN where it does not. The sign change is bracketed on ``samples`` points and bisected
    to ``tol`` in t. Curvatures below ``rel_zero`` x the segment's largest |k_n|, or below
    ``k_zero`` (N,) or scalar [1/length] (default 1e-7 / the surface's control-net
    diagonal), count as 0: a straight direction (a cylinder along its axis, whose k_n is
    round-off) has no inflection."""
    uv0 = np.atleast_2d(np.asarray(uv0, dtype=float))
    uv1 = np.atleast_2d(np.asarray(uv1, dtype=float))
    n = len(uv0)
    du, dv = uv1[:, 0] - uv0[:, 0], uv1[:, 1] - uv0[:, 1]
    ts = np.linspace(0.0, 1.0, samples)
    T = np.broadcast_to(ts, (n, samples))
    rep = lambda a: np.repeat(a, samples)  # noqa: E731
    k = _kn(surface, rep(uv0[:, 0]), rep(uv0[:, 1]), rep(du), rep(dv), T.ravel()).reshape(n, samples)
    if k_zero is None:
        cp = np.asarray(surface.control_points).reshape(-1, 3)
        k_zero = 1e-7 / max(float(np.linalg.norm(cp.max(0) - cp.min(0))), 1e-300)
    kz = np.broadcast_to(np.asarray(k_zero, dtype=float), (n,))[:, None]
    scale = np.max(np.abs(k), axis=1, keepdims=True)
    sgn = np.where((np.abs(k) <= rel_zero * scale) | (np.abs(k) <= kz) | ~np.isfinite(k), 0, np.sign(k))
    # first pair of consecutive non-zero samples of opposite sign (zeros are skipped over)
    out = np.full(n, np.nan)
    lo = np.zeros(n)
    hi = np.zeros(n)
    found = np.zeros(n, bool)
    last_s = np.zeros(n)
    last_t = np.zeros(n)
    for j in range(samples):  # loop over the few samples, vectorised over segments
        s = sgn[:, j]
        flip = ~found & (s != 0) & (last_s != 0) & (s != last_s)
        lo[flip], hi[flip] = last_t[flip], ts[j]
        found |= flip
        upd = s != 0
        last_s = np.where(upd, s, last_s)
        last_t = np.where(upd, ts[j], last_t)
    idx = np.flatnonzero(found)
    if len(idx):
        a, b = lo[idx], hi[idx]
        ka = _kn(surface, uv0[idx, 0], uv0[idx, 1], du[idx], dv[idx], a)
        for _ in range(60):  # bisection on the exact curvature
            m = 0.5 * (a + b)
            km = _kn(surface, uv0[idx, 0], uv0[idx, 1], du[idx], dv[idx], m)
            left = np.sign(km) == np.sign(ka)
            a = np.where(left, m, a)
            ka = np.where(left, km, ka)
            b = np.where(left, b, m)
            if np.max(b - a) <= tol:
                break
        out[idx] = 0.5 * (a + b)
    return out


@dataclass
class InflectionLine:
    """An inflection line of a surface for curvature along ``direction`` ("u": along u).

    uv (K, 2) points of the line (bisected on iso-lines of the other parameter); iso: the
    line is the iso-line ``direction = value`` within ``iso_tol`` of the domain (then it can
    be inserted exactly as a mesh edge, `cadbridge.nurbs.edits.isocurve`)."""

    direction: str
    uv: NDArray
    iso: bool
    value: float


def inflection_lines(surface: NurbsSurface, direction: str = "u", lines: int = 9, samples: int = 65,
                     iso_tol: float = 1e-7) -> list[InflectionLine]:
    """Inflection lines for the normal curvature along ``direction`` over the whole domain:
    ``lines`` iso-lines of the other parameter, each searched for all its sign changes of
    k_n (``samples`` brackets, bisected). Roots are chained into lines when every iso-line
    has the same number of them (else each root set is returned as its own line)."""
    if direction not in ("u", "v"):
        raise ValueError(f"direction must be 'u' or 'v', got {direction!r}")
    u0, u1, v0, v1 = surface.domain
    a0, a1, b0, b1 = (u0, u1, v0, v1) if direction == "u" else (v0, v1, u0, u1)
    others = np.linspace(b0, b1, lines)
    edges = np.linspace(a0, a1, samples)
    # every bracket [edges[i], edges[i+1]] of every iso-line is a segment; segment_inflections
    # finds at most one root per bracket (brackets are fine enough for die surfaces)
    A0 = np.tile(edges[:-1], lines)
    A1 = np.tile(edges[1:], lines)
    B = np.repeat(others, samples - 1)
    if direction == "u":
        st, en = np.column_stack([A0, B]), np.column_stack([A1, B])
    else:
        st, en = np.column_stack([B, A0]), np.column_stack([B, A1])
    # k_n at both bracket ends in the iso direction, plus the middle (3 samples per bracket)
    t = segment_inflections(surface, st, en, samples=3)
    t = t.reshape(lines, samples - 1)
    roots = [A0.reshape(lines, -1)[i] + t[i] * (A1 - A0).reshape(lines, -1)[i] for i in range(lines)]
    roots = [r[np.isfinite(r)] for r in roots]
    counts = {len(r) for r in roots}
    out: list[InflectionLine] = []
    span = max(a1 - a0, 1e-300)

    def make(vals, oth):
        uv = np.column_stack([vals, oth]) if direction == "u" else np.column_stack([oth, vals])
        iso = bool(np.ptp(vals) <= iso_tol * span) if len(vals) > 1 else False
        return InflectionLine(direction, uv, iso, float(np.mean(vals)))

    if len(counts) == 1:
        for j in range(counts.pop()):
            out.append(make(np.array([r[j] for r in roots]), others))
    else:
        for i, r in enumerate(roots):
            for x in r:
                out.append(make(np.array([x]), np.array([others[i]])))
    return out


def control_polygon_inflections(surface: NurbsSurface, direction: str, at: float) -> NDArray:
    """Thesis Fig. 59 on the iso-curve along ``direction`` at the other parameter ``at``:
    parameters (K,) where the control-polygon legs across a turning sign change cross the
    curve (the estimates of its inflections). The turning of polygon corner i is the second
    divided difference of the polygon over the Greville abscissae, along the surface normal
    at the Greville point of Q_i: the polygon bends towards or away from the surface."""
    from cadbridge.nurbs.edits import isocurve

    curve = isocurve(surface, "v" if direction == "u" else "u", float(at))
    q = np.asarray(curve.control_points, dtype=float)
    p = curve.degree
    kn = np.asarray(curve.knots, dtype=float)
    greville = np.array([kn[i + 1:i + p + 1].mean() for i in range(len(q))])
    lo, hi = curve.domain
    greville = np.clip(greville, lo, hi)
    uu, vv = (greville, np.full_like(greville, at)) if direction == "u" else (np.full_like(greville, at), greville)
    nrm = surface.normal(uu, vv)
    # second divided difference of the polygon (its turning) along the surface normal
    g = np.diff(greville)
    g = np.where(g > 0, g, 1.0)[:, None]
    slope = np.diff(q, axis=0) / g
    turn = np.einsum("ij,ij->i", slope[1:] - slope[:-1], nrm[1:-1])
    scale = np.max(np.abs(turn)) if len(turn) else 0.0
    s = np.where(np.abs(turn) <= 1e-12 * max(scale, 1e-300), 0, np.sign(turn))
    nz = np.flatnonzero(s != 0)
    out = []
    for a, b in zip(nz[:-1], nz[1:]):  # loop over the polygon's (few) corners
        if s[a] == s[b]:
            continue
        i, j = a + 1, b + 1  # corners Q_i .. Q_j in q numbering; the leg Q_i Q_{i+1} for adjacent ones
        leg0, leg1 = q[i], q[j] if j == i + 1 else q[i + 1]
        lg = (leg1 - leg0) / np.linalg.norm(leg1 - leg0)
        nm = 0.5 * (nrm[i] + nrm[min(j, len(q) - 1)])
        m = nm - np.dot(nm, lg) * lg  # normal of the leg in the curve's osculating plane
        ta, tb = greville[i], greville[min(j, len(q) - 1)]
        f = lambda t: np.einsum("ij,j->i", curve.evaluate(np.atleast_1d(t)) - leg0, m)  # noqa: E731
        ts = np.linspace(ta, tb, 33)
        fs = f(ts)
        ch = np.flatnonzero(np.sign(fs[:-1]) * np.sign(fs[1:]) < 0)
        if not len(ch):
            continue
        x0, x1 = ts[ch[0]], ts[ch[0] + 1]
        f0 = f(x0)[0]
        for _ in range(60):  # bisection: the leg crosses the curve
            xm = 0.5 * (x0 + x1)
            fm = f(xm)[0]
            if np.sign(fm) == np.sign(f0):
                x0, f0 = xm, fm
            else:
                x1 = xm
        out.append(0.5 * (x0 + x1))
    return np.array(out)
