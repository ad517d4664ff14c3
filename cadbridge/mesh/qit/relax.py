"""Valence flips, vertex relocation and a max-angle clean-up on a parametric surface: the
building blocks of QIT's strip step (`cadbridge.mesh.qit.mesher._relax_strip`, docs/qit.md choice 19).

The paper (Herrero Adan & Cardoso 2020, section 1) names the four local operations that
bring a triangulation closer to isotropic: edge collapse, split, flip and vertex
relocation. QIT's lattice already has the sizes, so only flips and relocation are used,
after the pattern-space CDT and the edge-strip amendment (section 6.4):

* `valence_flips`: an interior edge is flipped when that brings the mean angle
  alpha_v / n_v at its four vertices closer to 60 degrees (n_v triangles share the angle
  alpha_v: 2 pi inside, the vertex's interior angle on the boundary; so 6 triangles inside
  and 3 on a straight edge, the valences of the BIT of appendix C) -- the valence rule of
  Botsch & Kobbelt (2004, "A remeshing approach to multiresolution modeling", section 4)
  with its targets taken from the angles -- and the flip neither lowers the smallest angle
  of the two triangles below min(before, ``min_angle``) nor raises the largest above
  max(before, ``max_angle``);
* `relax_vertices`: the free vertices move along the surface under springs of rest length
  R on their mesh edges (the force of Persson & Strang's DistMesh, both ways); a move is
  taken in the tangent plane, mapped to (du, dv) by the surface's Jacobian (least squares),
  and the vertex is the surface evaluated at its new (u, v), so it stays exactly on the
  surface. A vertex is put back where its move would lower the smallest angle of its
  triangles ("smart" smoothing; optionally also raise their largest), turn a triangle in
  (u, v) or against the surface normal, or leave the caller's admissible set (inside the
  face, at least Dx_th from its edges);
* `max_angle_flips`: a triangle with an angle over a bound has its longest edge flipped
  where that lowers the pair's largest angle.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

__all__ = ["vertex_angle_sums", "valence_flips", "relax_vertices", "max_angle_flips", "tri_angles"]


def _edges(tris: np.ndarray) -> np.ndarray:
    """Unique undirected edges (M, 2) of triangles (T, 3)."""
    e = np.sort(np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0)


def tri_angles(x: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Interior angles (T, 3) in radians of triangles (T, 3) on points x (N, 3)."""
    p = x[tris]
    out = np.empty(tris.shape)
    for i in range(3):
        a = p[:, (i + 1) % 3] - p[:, i]
        b = p[:, (i + 2) % 3] - p[:, i]
        out[:, i] = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))
    return out


def _orient_uv(uv: np.ndarray, tris: np.ndarray) -> np.ndarray:
    a, b, c = uv[tris[:, 0]], uv[tris[:, 1]], uv[tris[:, 2]]
    return (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


def vertex_angle_sums(tris: np.ndarray, x: np.ndarray, is_boundary: np.ndarray) -> np.ndarray:
    """Angle alpha (N,) a vertex's triangles share: 2 pi inside, the sum of the 3D angles of
    its triangles ``tris`` (T, 3) on points ``x`` (N, 3) where ``is_boundary`` (N,)."""
    ang = tri_angles(x, tris)
    s = np.zeros(len(x))
    for i in range(3):
        np.add.at(s, tris[:, i], ang[:, i])
    return np.where(is_boundary, s, 2 * np.pi)


def valence_flips(tris: np.ndarray, uv: np.ndarray, x: np.ndarray, alpha: np.ndarray, constrained: set,
                  min_angle: float = 20.0, max_angle: float = 120.0, max_sweeps: int = 8) -> tuple[np.ndarray, int]:
    """Flip interior edges of ``tris`` (T, 3; CCW in ``uv`` (N, 2)) not in ``constrained``
    (sorted vertex pairs) while sum_v (alpha_v / n_v - 60 deg)^2 over the four vertices of
    the quadrilateral falls (n_v: triangles at v; ``alpha`` from `vertex_angle_sums`).
    A flip is taken only if both new triangles are positive in (u, v) and, in 3D (``x``
    (N, 3)), their smallest angle is >= min(old smallest, ``min_angle``) and their largest
    <= max(old largest, ``max_angle``) (degrees). Returns the triangles and the flip count."""
    tris = [list(map(int, t)) for t in tris]
    val = np.bincount(np.asarray(tris).ravel(), minlength=len(uv)).astype(np.int64)
    adj = {(t[i], t[(i + 1) % 3]): n for n, t in enumerate(tris) for i in range(3)}
    lo, hi = np.radians(min_angle), np.radians(max_angle)
    flips = 0
    third = np.pi / 3
    for _ in range(max_sweeps):
        changed = 0
        # only a quadrilateral with a vertex off its ideal mean angle can gain: edges with an
        # end point or an opposite vertex deviating by more than 1 degree
        off = np.abs(alpha / np.maximum(val, 1) - third) > np.radians(1.0)
        t_off = [n for n, t in enumerate(tris) if off[t[0]] or off[t[1]] or off[t[2]]]
        keys = {(min(tris[n][i], tris[n][(i + 1) % 3]), max(tris[n][i], tris[n][(i + 1) % 3]))
                for n in t_off for i in range(3)}
        for key in sorted(keys):
            if key in constrained:
                continue
            a, b = key
            t1, t2 = adj.get((a, b)), adj.get((b, a))
            if t1 is None or t2 is None:
                continue
            c = [v for v in tris[t1] if v != a and v != b][0]
            d = [v for v in tris[t2] if v != a and v != b][0]
            if c == d or (c, d) in adj or (d, c) in adj:
                continue  # c-d already an edge: the flip would duplicate it
            q = np.array([a, b, c, d])
            nv = val[q] + np.array([-1, -1, 1, 1])
            if nv.min() < 1:
                continue
            if np.sum((alpha[q] / nv - np.pi / 3) ** 2) >= np.sum((alpha[q] / val[q] - np.pi / 3) ** 2):
                continue
            n1, n2 = [c, d, b], [d, c, a]  # a-b-c is CCW in t1
            if _orient_uv(uv, np.array([n1, n2])).min() <= 0:
                continue
            old_a = tri_angles(x, np.array([tris[t1], tris[t2]]))
            new_a = tri_angles(x, np.array([n1, n2]))
            if new_a.min() < min(old_a.min(), lo) or new_a.max() > max(old_a.max(), hi):
                continue
            for t in (t1, t2):
                tt = tris[t]
                for i in range(3):
                    adj.pop((tt[i], tt[(i + 1) % 3]), None)
            tris[t1], tris[t2] = n1, n2
            for t in (t1, t2):
                tt = tris[t]
                for i in range(3):
                    adj[(tt[i], tt[(i + 1) % 3])] = t
            val[[a, b]] -= 1
            val[[c, d]] += 1
            changed += 1
        flips += changed
        if not changed:
            break
    return np.array(tris, dtype=np.int64), flips


def max_angle_flips(tris: np.ndarray, uv: np.ndarray, x: np.ndarray, constrained: set, max_angle: float,
                    max_sweeps: int = 10) -> tuple[np.ndarray, int]:
    """Clean-up: a triangle with an angle above ``max_angle`` (degrees) has its longest edge
    (opposite that angle, not in ``constrained``) flipped where that lowers the largest 3D
    angle of the pair and keeps both new triangles positive in (u, v). tris (T, 3) CCW in
    ``uv`` (N, 2), points ``x`` (N, 3). Returns the triangles and the flip count."""
    tris = [list(map(int, t)) for t in tris]
    thr = np.radians(max_angle)
    flips = 0
    adj = None
    for _ in range(max_sweeps):
        ang = tri_angles(x, np.array(tris))
        over = np.flatnonzero(ang.max(axis=1) > thr)
        if over.size == 0:
            break
        if adj is None:  # kept up to date by the flips below
            adj = {(t[i], t[(i + 1) % 3]): n for n, t in enumerate(tris) for i in range(3)}
        changed = 0
        for t1 in over:
            tt = tris[t1]
            k = int(np.argmax(tri_angles(x, np.array([tt]))[0]))
            c, a, b = tt[k], tt[(k + 1) % 3], tt[(k + 2) % 3]
            t2 = adj.get((b, a))
            if (min(a, b), max(a, b)) in constrained or t2 is None:
                continue
            d = [v for v in tris[t2] if v != a and v != b][0]
            if (c, d) in adj or (d, c) in adj:
                continue
            n1, n2 = [c, a, d], [c, d, b]
            if _orient_uv(uv, np.array([n1, n2])).min() <= 0:
                continue
            if tri_angles(x, np.array([n1, n2])).max() >= tri_angles(x, np.array([tris[t1], tris[t2]])).max() - 1e-12:
                continue
            for t in (t1, t2):
                for i in range(3):
                    adj.pop((tris[t][i], tris[t][(i + 1) % 3]), None)
            tris[t1], tris[t2] = n1, n2
            for t in (t1, t2):
                for i in range(3):
                    adj[(tris[t][i], tris[t][(i + 1) % 3])] = t
            changed += 1
        flips += changed
        if not changed:
            break
    return np.array(tris, dtype=np.int64), flips


def relax_vertices(tris: np.ndarray, uv: np.ndarray, x: np.ndarray, free: np.ndarray, surface, R: float,
                   admissible: Callable[[np.ndarray, np.ndarray], np.ndarray], iters: int = 30,
                   step: float = 0.3, keep_max: bool = False) -> tuple[np.ndarray, np.ndarray, int]:
    """Move the ``free`` (N,) vertices along ``surface`` under springs of rest length ``R``
    on the mesh edges of ``tris`` (T, 3; CCW in (u, v)).

    Per iteration: f_i = sum_j (|x_j - x_i| - R) (x_j - x_i) / |x_j - x_i|; dx = ``step`` f_i;
    (du, dv) = (J^T J)^-1 J^T dx with J = [Su Sv]; x = S(u + du, v + dv) exactly. A vertex is
    put back where its move would lower the smallest angle of its triangles (``keep_max``:
    or raise their largest), make one of them non-positive in (u, v) or against Su x Sv at
    its (u, v) centroid, or where ``admissible(uv (M, 2), x (M, 3))`` is False. Returns uv (N, 2), x (N, 3) and the
    number of vertices that moved."""
    uv = np.array(uv, dtype=float)
    x = np.array(x, dtype=float)
    free = np.asarray(free, dtype=bool)
    if not free.any():
        return uv, x, 0
    u0, u1, v0, v1 = surface.domain
    lo, hi = np.array([u0, v0]), np.array([u1, v1])
    e = _edges(tris)
    fk = np.flatnonzero(free)
    tk = tris[np.isin(tris, fk).any(axis=1)]  # the triangles a move can change
    uv_start = uv.copy()
    for _ in range(iters):
        d = x[e[:, 1]] - x[e[:, 0]]
        ln = np.linalg.norm(d, axis=1)
        f = ((ln - R) / np.maximum(ln, 1e-300))[:, None] * d
        force = np.zeros_like(x)
        np.add.at(force, e[:, 0], f)
        np.add.at(force, e[:, 1], -f)
        der = surface.derivatives(uv[fk, 0], uv[fk, 1], order=1)
        su, sv = der[:, 1, 0], der[:, 0, 1]
        dx = step * force[fk]
        g11, g12, g22 = (np.einsum("ij,ij->i", su, su), np.einsum("ij,ij->i", su, sv), np.einsum("ij,ij->i", sv, sv))
        b1, b2 = np.einsum("ij,ij->i", su, dx), np.einsum("ij,ij->i", sv, dx)
        det = g11 * g22 - g12 * g12
        duv = np.column_stack([(g22 * b1 - g12 * b2) / det, (g11 * b2 - g12 * b1) / det])
        new_uv = np.clip(uv[fk] + duv, lo, hi)
        new_x = surface.evaluate(new_uv[:, 0], new_uv[:, 1])
        ok = np.isfinite(new_x).all(axis=1)
        ok[ok] = admissible(new_uv[ok], new_x[ok])
        cand_uv, cand_x = uv.copy(), x.copy()
        cand_uv[fk[ok]] = new_uv[ok]
        cand_x[fk[ok]] = new_x[ok]
        moved = np.zeros(len(uv), dtype=bool)
        moved[fk[ok]] = True
        old_min = tri_angles(x, tk).min(axis=1)
        star_old = np.full(len(x), np.inf)
        for i in range(3):
            np.minimum.at(star_old, tk[:, i], old_min)
        # put back vertices until every triangle is valid and no moved vertex's star lost
        # in smallest angle (the previous state qualifies, so this ends)
        while True:
            bad = _invalid(tk, cand_uv, cand_x, surface, lo, hi)
            star_new = np.full(len(x), np.inf)
            new_min = tri_angles(cand_x, tk).min(axis=1)
            for i in range(3):
                np.minimum.at(star_new, tk[:, i], new_min)
            worse = moved & (star_new < star_old - 1e-12)
            if keep_max:
                smax_old, smax_new = np.zeros(len(x)), np.zeros(len(x))
                mo, mn = tri_angles(x, tk).max(axis=1), tri_angles(cand_x, tk).max(axis=1)
                for i in range(3):
                    np.maximum.at(smax_old, tk[:, i], mo)
                    np.maximum.at(smax_new, tk[:, i], mn)
                worse |= moved & (smax_new > smax_old + 1e-12)
            bad |= np.isin(tk, np.flatnonzero(worse)).any(axis=1)
            back = np.unique(tk[bad].ravel())
            back = back[moved[back]]
            if back.size == 0:
                break
            cand_uv[back], cand_x[back] = uv[back], x[back]
            moved[back] = False
        if not moved.any():
            break
        shift = float(np.linalg.norm(cand_x[moved] - x[moved], axis=1).max())
        uv, x = cand_uv, cand_x
        if shift < 1e-6 * R:  # converged
            break
    return uv, x, int(np.sum(np.any(uv != uv_start, axis=1)))


def _invalid(tris: np.ndarray, uv: np.ndarray, x: np.ndarray, surface, lo, hi) -> np.ndarray:
    """Triangles (T,) non-positive in (u, v), or whose 3D normal is against Su x Sv at
    their (u, v) centroid."""
    o = _orient_uv(uv, tris) <= 0
    c = np.clip(uv[tris].mean(axis=1), lo, hi)
    d = surface.derivatives(c[:, 0], c[:, 1], order=1)
    n = np.cross(d[:, 1, 0], d[:, 0, 1])
    p = x[tris]
    tn = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return o | (np.einsum("ij,ij->i", tn, n) <= 0)
