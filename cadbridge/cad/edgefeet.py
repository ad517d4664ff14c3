"""Feet of model-space trim edges on a NURBS surface: the reference tables of
`analytic.invert_edges` (B-rep loops without parameter-space curves).

The samples of one edge piece follow each other closely and lie on the surface (up to the
file's trim delta), so their feet follow each other too. Instead of a global projection of
every sample (`project_to_surface`: KD-tree seed, Newton, then restarts from other local
minima of the sampled distance and from inside a domain edge), only the two ends of each
piece are projected globally (the anchors); the samples in between are reached by
continuation: Newton on the foot condition (Neto 2010 app. B eqs. 32-36; the surface
derivatives of `nurbs.project`'s compiled evaluator) from the previous foot extrapolated
along the piece, one or two iterations each, in one compiled pass over all samples.

The continued feet are checked before they are used; a piece fails the check, and all its
samples get the global projection as before, when
  - a foot is not orthogonal (tangential offset above ``1e3 x 1e-12 x size`` plus round-off,
    the acceptance test of `nurbs.project`) where it is neither clamped to a domain edge
    nor at a pole;
  - a sample is farther than ``FAR_REL`` x size from its foot (beyond what the reader calls
    consistent trims: the continuation argument needs the edge on the surface);
  - the continued foot of the last sample is farther than the global foot of that sample
    (the continuation left the global branch), beyond ``1e-9 x size``.
Along a piece that stays within the surface's reach (distance to the surface below the
smallest radius of curvature and half the narrowest gap of the surface), the nearest point
is unique and moves continuously, so continuation from a global foot stays on the global
branch; seams and poles are the only ties, and `invert_edges` unwraps / fills them after.
"""

from __future__ import annotations

import numba
import numpy as np

from cadbridge.nurbs.newton import ders2_one, ders2_scratch, wrap_clamp
from cadbridge.nurbs.project import FAILED, project_to_surface, surface_samples
from cadbridge.nurbs.surface import NurbsSurface

__all__ = ["edge_feet", "FAR_REL"]

FAR_REL = 1e-3  # samples farther from the surface than this x size get the global projection
TOL = 1e-12  # Newton tolerance (eps1 = TOL x size, eps2 = TOL), as `project_to_surface`
MAX_ITER = 30


@numba.njit(cache=True, error_model="numpy")
def _march(pw, ku, kv, p, q, rational, u0, u1, v0, v1, cu, cv, eps1, eps2, pts, t, noise, starts, u, v, max_iter,
           far, off_tol, pole_tol, dist, ok):  # pragma: no cover - compiled
    """Continuation along each piece k (samples starts[k] .. starts[k+1]-1; u, v given at the
    first sample, a global foot). The seed of sample i is the foot of i-1 extrapolated
    linearly in t from i-2 and i-1 (periodic differences taken modulo the period), wrapped /
    clamped into the domain; then Newton on f = Su.r, g = Sv.r (r = S - P; full Hessian
    where positive definite, else Gauss-Newton; a parameter clamped at a domain edge whose
    gradient points outwards is held and the other one solved alone), convergence as in
    `nurbs.project` (|r| <= eps1, zero cosines <= eps2, or a step <= eps1), at most
    ``max_iter`` steps. Writes u, v (N,), dist (N,) = |r| at the foot and ok (N,): converged,
    finite, dist <= far and each parameter's tangential offset |S_a . r| / |S_a| <= off_tol +
    noise unless held or at a pole (|S_a| <= pole_tol). Scratch allocated once."""
    pu = u1 - u0
    pv = v1 - v0
    tiny = 1e-300
    scratch = ders2_scratch(p, q)
    der = np.empty((3, 3, 3))
    for k in range(len(starts) - 1):
        a0, b0 = starts[k], starts[k + 1]
        for i in range(a0, b0):
            uu, vv = u[i], v[i]
            if i > a0:  # the seed: extrapolated from the previous feet
                uu, vv = u[i - 1], v[i - 1]
                if i - 2 >= a0 and t[i - 1] > t[i - 2]:
                    du = u[i - 1] - u[i - 2]
                    dv = v[i - 1] - v[i - 2]
                    if cu:
                        du -= pu * np.rint(du / pu)
                    if cv:
                        dv -= pv * np.rint(dv / pv)
                    s = (t[i] - t[i - 1]) / (t[i - 1] - t[i - 2])
                    uu += du * s
                    vv += dv * s
                uu = wrap_clamp(uu, u0, u1, cu)
                vv = wrap_clamp(vv, v0, v1, cv)
            px, py, pz = pts[i, 0], pts[i, 1], pts[i, 2]
            small = False
            conv = False
            lr = np.inf
            f = g = lsu = lsv = 0.0
            act_u = act_v = False
            for it in range(max_iter + 1):
                ders2_one(pw, ku, kv, p, q, rational, uu, vv, scratch, der)
                rx, ry, rz = der[0, 0, 0] - px, der[0, 0, 1] - py, der[0, 0, 2] - pz
                sux, suy, suz = der[1, 0, 0], der[1, 0, 1], der[1, 0, 2]
                svx, svy, svz = der[0, 1, 0], der[0, 1, 1], der[0, 1, 2]
                f = sux * rx + suy * ry + suz * rz
                g = svx * rx + svy * ry + svz * rz
                guu = sux * sux + suy * suy + suz * suz
                gvv = svx * svx + svy * svy + svz * svz
                lsu = np.sqrt(guu)
                lsv = np.sqrt(gvv)
                lr = np.sqrt(rx * rx + ry * ry + rz * rz)
                act_u = (not cu) and ((uu <= u0 and f > 0) or (uu >= u1 and f < 0))
                act_v = (not cv) and ((vv <= v0 and g > 0) or (vv >= v1 and g < 0))
                cos_u = abs(f) / max(lsu * lr, tiny)
                cos_v = abs(g) / max(lsv * lr, tiny)
                conv = small or (lr <= eps1) or ((cos_u <= eps2 or act_u) and (cos_v <= eps2 or act_v))
                if conv or it == max_iter:
                    break
                guv = sux * svx + suy * svy + suz * svz
                ha = guu + rx * der[2, 0, 0] + ry * der[2, 0, 1] + rz * der[2, 0, 2]
                hb = guv + rx * der[1, 1, 0] + ry * der[1, 1, 1] + rz * der[1, 1, 2]
                hc = gvv + rx * der[0, 2, 0] + ry * der[0, 2, 1] + rz * der[0, 2, 2]
                lam = 1e-12 * (guu + gvv) + tiny
                if not ((ha > 0) and (hc > 0) and (ha * hc - hb * hb > 1e-12 * abs(ha * hc))):
                    ha, hb, hc = guu + lam, guv, gvv + lam  # Gauss-Newton
                if act_u and act_v:
                    break
                elif act_v:
                    du, dv = -f / ha, 0.0
                elif act_u:
                    du, dv = 0.0, -g / hc
                else:
                    det = ha * hc - hb * hb
                    du = (-hc * f + hb * g) / det
                    dv = (hb * f - ha * g) / det
                if not (np.isfinite(du) and np.isfinite(dv)):
                    break
                un = wrap_clamp(uu + du, u0, u1, cu)
                vn = wrap_clamp(vv + dv, v0, v1, cv)
                ddu = un - uu
                ddv = vn - vv
                if cu:
                    ddu -= pu * np.rint(ddu / pu)
                if cv:
                    ddv -= pv * np.rint(ddv / pv)
                sx = ddu * sux + ddv * svx
                sy = ddu * suy + ddv * svy
                sz = ddu * suz + ddv * svz
                small = np.sqrt(sx * sx + sy * sy + sz * sz) <= eps1
                uu, vv = un, vn
            u[i] = uu
            v[i] = vv
            dist[i] = lr
            good = conv and np.isfinite(lr) and lr <= far
            tol_i = off_tol + noise[i]
            good = good and (act_u or lsu <= pole_tol or abs(f) / max(lsu, tiny) <= tol_i)
            good = good and (act_v or lsv <= pole_tol or abs(g) / max(lsv, tiny) <= tol_i)
            ok[i] = good


def edge_feet(surface: NurbsSurface, pts: np.ndarray, t: np.ndarray, starts: np.ndarray,
              pole_tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Global feet on ``surface`` of the samples ``pts`` (M, 3) of consecutive edge pieces:
    piece k holds rows starts[k] .. starts[k+1]-1 (starts (P+1,), increasing), sampled at
    increasing parameters ``t`` (M,) of its own curve. ``pole_tol``: |S_u| or |S_v| at most
    this is a pole (that parameter undefined, its offset not checked).

    Returns (uv (M, 2), failed (M,) bool): the feet as `project_to_surface` gives them (closed
    directions wrapped into the domain): at the ends of each piece its global projections, in
    between continued from the first one (module docstring); where the continuation fails its
    checks, the piece's global projections (``failed``: rows where even that found no foot)."""
    pts = np.ascontiguousarray(pts, dtype=float)
    t = np.ascontiguousarray(t, dtype=float)
    starts = np.ascontiguousarray(starts, dtype=np.int64)
    n = len(pts)
    samples = surface_samples(surface)
    size = max(samples.size, 1e-300)
    u0, u1, v0, v1 = surface.domain
    first, last = starts[:-1], starts[1:] - 1
    anchors = np.unique(np.concatenate([first, last]))
    g = project_to_surface(surface, pts[anchors], tol=TOL, max_iter=MAX_ITER)
    u = np.empty(n)
    v = np.empty(n)
    pos = np.searchsorted(anchors, first)
    u[first], v[first] = g.u[pos], g.v[pos]
    noise = 64.0 * np.finfo(float).eps * (np.max(np.abs(pts), axis=1) + size)
    dist = np.empty(n)
    ok = np.empty(n, dtype=np.bool_)
    _march(surface._pw, surface.knots_u, surface.knots_v, surface.degree_u, surface.degree_v, surface.rational,
           u0, u1, v0, v1, samples.closed_u, samples.closed_v, TOL * size, TOL, pts, t, noise, starts, u, v,
           MAX_ITER, FAR_REL * size, 1e3 * TOL * size, pole_tol, dist, ok)
    bad = ~ok
    pos_last = np.searchsorted(anchors, last)
    gd = np.where(g.status[pos_last] == FAILED, np.inf, g.distance[pos_last])
    left = dist[last] > gd + 1e-9 * size  # the continuation is not on the global branch at the end
    piece_bad = np.add.reduceat(bad.astype(np.int64), first) > 0
    piece_bad |= left | (g.status[pos] == FAILED)
    uv = np.column_stack([u, v])
    # both ends keep their global feet (the continued last one agrees in distance): a vertex on
    # a domain edge is then exactly on it, as the projection's clamp puts it
    uv[first] = np.column_stack([g.u[pos], g.v[pos]])
    uv[last] = np.column_stack([g.u[pos_last], g.v[pos_last]])
    failed = np.zeros(n, dtype=bool)
    if np.any(piece_bad):
        rows = np.concatenate([np.arange(a, b) for a, b, x in zip(first, starts[1:], piece_bad) if x])
        full = project_to_surface(surface, pts[rows])
        uv[rows] = np.column_stack([full.u, full.v])
        failed[rows] = full.status == FAILED
    return uv, failed
