"""Model-level trim geometry: where a face's trim loops are, decided on the exact curves.

`project_to_trims`: nearest point of a face's trim loops (followed on the surface) to 3D points.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["project_to_trims"]


def project_to_trims(face, points, *, tol: float = 1e-12, max_iter: int = 40):
    """Nearest points of the trim loops (outer and holes) of ``face`` to (N, 3) points.

    Each loop curve c(t) (in (u, v)) is followed on the surface, C(t) = S(c(t)); start from
    the nearest of a sample polyline, then Newton on f(t) = (C - P).C' with
    f' = C'.C' + (C - P).C'' (C' = Su u' + Sv v', C'' = Suu u'^2 + 2 Suv u' v' + Svv v'^2
    + Su u'' + Sv v''), t clamped to the curve's domain; the nearest over all curves wins.
    Vectorised over points; the loop runs over the (few) trim curves.
    Returns (u (N,), v (N,), foot (N, 3), distance (N,), ok (N,) bool: orthogonal foot or
    curve end). Raises ValueError if the face has no trim loops.
    """
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    n = len(pts)
    trims = face.trims
    loops = ([] if trims is None or trims.outer is None else [trims.outer]) + ([] if trims is None else list(trims.inner))
    if not loops:
        raise ValueError("project_to_trims: the face has no trim loops")
    surf = face.surface
    b = surf.bbox()
    eps1 = tol * max(float(np.linalg.norm(b[1] - b[0])), 1e-300)
    best = (np.full(n, np.nan), np.full(n, np.nan), np.full((n, 3), np.nan), np.full(n, np.inf), np.zeros(n, dtype=bool))
    u0, u1, v0, v1 = surf.domain

    def on_surface(curve, t, order):
        c = curve.derivatives(t, order=2)  # (N, 3, 2): uv, uv', uv''
        uu = np.clip(c[:, 0, 0], u0, u1)
        vv = np.clip(c[:, 0, 1], v0, v1)
        d = surf.derivatives(uu, vv, order=order)
        return uu, vv, c, d

    for loop in loops:
        for curve in loop.curves:
            t0, t1 = curve.domain
            ts = curve.sample_parameters(32)
            uu, vv, _, d = on_surface(curve, ts, 0)
            _, k = cKDTree(d[:, 0, 0]).query(pts)
            t = ts[np.asarray(k)]
            done = np.zeros(n, dtype=bool)
            for _ in range(max_iter):
                act = np.nonzero(~done)[0]
                if not len(act):
                    break
                uu, vv, c, d = on_surface(curve, t[act], 2)
                up, vp, upp, vpp = c[:, 1, 0], c[:, 1, 1], c[:, 2, 0], c[:, 2, 1]
                su, sv = d[:, 1, 0], d[:, 0, 1]
                c1 = su * up[:, None] + sv * vp[:, None]
                c2 = (d[:, 2, 0] * (up * up)[:, None] + 2.0 * d[:, 1, 1] * (up * vp)[:, None]
                      + d[:, 0, 2] * (vp * vp)[:, None] + su * upp[:, None] + sv * vpp[:, None])
                r = d[:, 0, 0] - pts[act]
                f = np.einsum("ij,ij->i", r, c1)
                fp = np.einsum("ij,ij->i", c1, c1) + np.einsum("ij,ij->i", r, c2)
                fp = np.where(fp > 0, fp, np.einsum("ij,ij->i", c1, c1) + 1e-300)
                tn = np.clip(t[act] - f / fp, t0, t1)
                step = np.abs(tn - t[act]) * np.linalg.norm(c1, axis=1)
                t[act] = tn
                done[act[step <= eps1]] = True
            uu, vv, c, d = on_surface(curve, t, 1)
            c1 = d[:, 1, 0] * c[:, 1, 0:1] + d[:, 0, 1] * c[:, 1, 1:2]
            r = d[:, 0, 0] - pts
            dist = np.linalg.norm(r, axis=1)
            off = np.abs(np.einsum("ij,ij->i", r, c1)) / np.maximum(np.linalg.norm(c1, axis=1), 1e-300)
            ok = (off <= 1e3 * eps1) | (t <= t0) | (t >= t1)
            better = np.where(ok, dist, np.inf) < best[3]
            best[0][better], best[1][better], best[2][better] = uu[better], vv[better], d[better, 0, 0]
            best[3][better], best[4][better] = dist[better], True
    return best
