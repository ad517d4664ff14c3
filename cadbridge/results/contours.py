"""Contour lines of a mapped field on the exact CAD (Hawkins 1989, §4.8-4.10, §5.3).

Within each parameter-space sub-triangle of a `ResultMapping` the field is linear, so the
iso-line f = c is a straight segment in (u, v) between the crossings of two triangle edges
(marching triangles) where the level cuts the triangle, fmin < c < fmax; a crossing at a
vertex whose value is c is that vertex. A level equal to a triangle's smallest or largest
value only touches it: where two vertices lie on the level, the mesh edge between them is a
line exactly when it separates two bands, i.e. a sub-triangle along it lies below the level
and another above (`_level_edges`; the tie-break of `cadbridge.results.levels`), so the
lines are the borders of the bands. A crossing is named by its edge's vertex keys and the
level (a vertex by its own key), so the segments of neighbouring elements -- on one face,
on two faces sharing an edge, on both sides of a seam -- meet at the same named point and
are chained into polylines. Each segment is evaluated on the exact surface, S(u(t), v(t)),
subdivided until its chord deviates from the surface by at most ``chord_tol``.

Where a line passes from face A to face B the crossing is computed on the lower-numbered
face and projected onto the other (Newton from its own interpolated (u, v)), so both
faces' (u, v) give one point (the `ContourLines.joints` record the remaining gap).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from cadbridge.nurbs.project import project_to_surface
from cadbridge.results.bands import band_areas
from cadbridge.results.levels import level_ranks, make_levels

__all__ = ["ContourLines", "Contours", "contour", "contour_lines", "level_ranks", "make_levels"]  # the last two re-exported

_EDGES = ((0, 1), (1, 2), (2, 0))


@dataclass
class ContourLines:
    """Polylines of constant field on the exact surface.

    levels       (L,) contour levels
    points       (M, 3) model-space points of all lines, line by line
    face, u, v   (M,) the face and parameters each point was evaluated at
    offsets      (n + 1,) line i is points[offsets[i]:offsets[i + 1]]
    level        (n,) level index of each line; closed (n,) bool (a closed line repeats its
                 first point at the end)
    joints       (J,) indices into points where a line passes onto another face or through
                 a seam; joint_face, joint_u, joint_v: the same point on the side it comes
                 from; joint_gap (J,) |S_before(u, v) - S_after(u, v)|
    """

    levels: np.ndarray
    points: np.ndarray
    face: np.ndarray
    u: np.ndarray
    v: np.ndarray
    offsets: np.ndarray
    level: np.ndarray
    closed: np.ndarray
    joints: np.ndarray
    joint_face: np.ndarray
    joint_u: np.ndarray
    joint_v: np.ndarray
    joint_gap: np.ndarray

    def __len__(self) -> int:
        return len(self.level)

    def line(self, i: int) -> dict:
        """Line i: points (m, 3), face/u/v (m,), level value, closed."""
        a, b = self.offsets[i], self.offsets[i + 1]
        return {"points": self.points[a:b], "face": self.face[a:b], "u": self.u[a:b], "v": self.v[a:b],
                "level": float(self.levels[self.level[i]]), "closed": bool(self.closed[i])}

    def lengths(self) -> np.ndarray:
        """Polyline length of each line (model units), (n,)."""
        d = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        cs = np.concatenate([[0.0], np.cumsum(d)])
        return cs[self.offsets[1:] - 1] - cs[self.offsets[:-1]]


@numba.njit(cache=True)
def _chain(a, b, n_pts):  # pragma: no cover - compiled
    """Walk segments (a[s], b[s]) (point ids < n_pts) into polylines. Returns the segment
    order, a flip flag (walked b -> a), line start offsets into the order and closed flags."""
    s_count = len(a)
    deg = np.zeros(n_pts, np.int64)
    for s in range(s_count):
        deg[a[s]] += 1
        deg[b[s]] += 1
    start = np.zeros(n_pts + 1, np.int64)
    for i in range(n_pts):
        start[i + 1] = start[i] + deg[i]
    fill = start[:-1].copy()
    inc = np.empty(2 * s_count, np.int64)
    for s in range(s_count):
        inc[fill[a[s]]] = s
        fill[a[s]] += 1
        inc[fill[b[s]]] = s
        fill[b[s]] += 1
    used = np.zeros(s_count, np.bool_)
    order = np.empty(s_count, np.int64)
    flip = np.zeros(s_count, np.bool_)
    line_start = np.empty(s_count + 1, np.int64)
    closed = np.zeros(s_count, np.bool_)
    k = 0
    n_lines = 0
    for phase in range(2):  # open lines from their ends first, then the closed ones
        for p0 in range(n_pts):
            if phase == 0 and deg[p0] != 1:
                continue
            for j in range(start[p0], start[p0 + 1]):
                s0 = inc[j]
                if used[s0]:
                    continue
                line_start[n_lines] = k
                p = p0
                s = s0
                while True:
                    used[s] = True
                    order[k] = s
                    if a[s] == p:
                        flip[k] = False
                        p = b[s]
                    else:
                        flip[k] = True
                        p = a[s]
                    k += 1
                    nxt = -1
                    for jj in range(start[p], start[p + 1]):
                        if not used[inc[jj]]:
                            nxt = inc[jj]
                            break
                    if nxt < 0:
                        break
                    s = nxt
                closed[n_lines] = p == p0
                n_lines += 1
    line_start[n_lines] = k
    return order, flip, line_start[: n_lines + 1], closed[:n_lines]


def _level_pairs(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(triangle, level) pairs whose level crosses the triangle: fmin < c <= fmax."""
    cnt = np.maximum(hi - lo, 0)
    crossed = np.flatnonzero(cnt)
    lo, cnt = lo[crossed], cnt[crossed]
    tri = np.repeat(crossed, cnt)
    first = np.repeat(lo, cnt)
    step = np.arange(len(tri)) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    return tri, first + step


def _level_edges(mapping, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mesh edges lying on a level (both ends' values equal to it) that separate two bands:
    of the sub-triangles along the edge (on any face, either side of a seam, named by the
    edge's vertex keys), one lies below the level and one above it (by its third vertex; a
    constant one by `band_index`'s rule). A ridge or valley on the level, or a border edge,
    separates nothing. Returns per such edge one sub-triangle below it, the edge's local
    vertices a, b and the level index, (E,) int64 each."""
    tf, tkey = mapping.tri_f, mapping.tri_key
    L = len(levels)
    nk = np.int64(mapping.n_keys)
    rows, ia, ib, lev, up, code = [], [], [], [], [], []
    for i, j in _EDGES:
        r = np.flatnonzero(tf[:, i] == tf[:, j])  # few in general: level tests on these only
        c = tf[r, i]
        kr = np.minimum(np.searchsorted(levels, c), L - 1)
        on = (levels[kr] == c) & (tkey[r, i] != tkey[r, j])
        r, c, kr = r[on], c[on], kr[on]
        if not len(r):
            continue
        f3 = tf[r, 3 - i - j]
        ki, kj = tkey[r, i], tkey[r, j]
        rows.append(r)
        ia.append(np.full(len(r), i))
        ib.append(np.full(len(r), j))
        lev.append(kr)
        up.append((f3 > c) | ((f3 == c) & (kr < L - 1)))
        code.append((np.minimum(ki, kj) * nk + np.maximum(ki, kj)) * L + kr)
    if not rows:
        z = np.zeros(0, dtype=np.int64)
        return z, z, z, z
    rows, ia, ib = np.concatenate(rows), np.concatenate(ia), np.concatenate(ib)
    lev, up, code = np.concatenate(lev), np.concatenate(up), np.concatenate(code)
    uniq, inv = np.unique(code, return_inverse=True)
    n_up = np.bincount(inv, weights=up, minlength=len(uniq))
    n_down = np.bincount(inv, weights=~up, minlength=len(uniq))
    border = (n_up > 0) & (n_down > 0)
    down = np.flatnonzero(~up & border[inv])
    _, first = np.unique(inv[down], return_index=True)  # one segment per edge
    sel = down[first]
    return rows[sel], ia[sel], ib[sel], lev[sel]


def _eval(model, face: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    out = np.empty((len(face), 3))
    for f in np.unique(face):
        sel = np.flatnonzero(face == f)
        out[sel] = model.faces[int(f)].surface.evaluate(u[sel], v[sel])
    return out


def contour_lines(mapping, levels: np.ndarray, *, chord_tol: float | None = None, max_sub: int = 64,
                  ranks: tuple[np.ndarray, np.ndarray] | None = None) -> ContourLines:
    """Contour lines of ``mapping`` at ``levels`` (see the module text). chord_tol: largest
    chord-to-surface deviation of the polyline pieces (default 1e-5 x model size); ranks:
    `level_ranks` if already computed."""
    levels = np.asarray(levels, dtype=float)
    lo, hi = level_ranks(mapping, levels) if ranks is None else ranks
    model = mapping.model
    size = mapping.size
    tol = 1e-5 * size if chord_tol is None else float(chord_tol)
    tf, tuv, tkey, tface = mapping.tri_f, mapping.tri_uv, mapping.tri_key, mapping.tri_face
    tri, lev = _level_pairs(lo, hi)  # the levels cutting a triangle: fmin < c < fmax
    c = levels[lev]
    above = tf[tri] >= c[:, None]  # (P, 3)
    # per pair, the two crossed edges (in edge order); canonical orientation by key
    ends_code, ends_uv, ends_arc = [], [], []
    crossed = np.stack([above[:, i] != above[:, j] for i, j in _EDGES], axis=1)  # (P, 3)
    nk = np.int64(mapping.n_keys)
    arcs = mapping.arcs
    n_faces = np.int64(len(model.faces))
    arc_codes = arc_order = None
    if arcs is not None and len(arcs):
        codes = (np.minimum(arcs.ka, arcs.kb) * nk + np.maximum(arcs.ka, arcs.kb)) * n_faces + arcs.face
        arc_order = np.argsort(codes)
        arc_codes = codes[arc_order]
    for e, (i, j) in enumerate(_EDGES):
        ki, kj = tkey[tri, i], tkey[tri, j]
        swap = ki > kj
        a_i = np.where(swap, j, i)
        b_i = np.where(swap, i, j)
        fa, fb = tf[tri, a_i], tf[tri, b_i]
        t = (c - fa) / np.where(fb != fa, fb - fa, 1.0)
        uva, uvb = tuv[tri, a_i], tuv[tri, b_i]
        uv = uva + t[:, None] * (uvb - uva)
        ka, kb = np.minimum(ki, kj), np.maximum(ki, kj)
        auv = np.full((len(tri), 2), np.nan)
        if arc_codes is not None:  # a crossing on a border chord of a curved trim: on the arc
            ec = (ka * nk + kb) * n_faces + tface[tri]
            pos = np.minimum(np.searchsorted(arc_codes, ec), len(arc_codes) - 1)
            hit = np.flatnonzero((arc_codes[pos] == ec) & (t > 0.0) & (t < 1.0))
            if len(hit):
                k = arc_order[pos[hit]]
                ta = np.where(arcs.ka[k] == ka[hit], t[hit], 1.0 - t[hit])
                w = arcs.arc(k, ta)[:, 0]
                iso = arcs.iso[k]
                uv[hit[iso]] = w[iso]  # the line runs straight on (or stops) at the trim curve
                auv[hit[~iso]] = w[~iso]  # elsewhere it runs on to it along the sliver
        # a crossing at an edge's end is that vertex's point (key pair (k, k)): the segments of
        # all triangles around a vertex on the level meet there, the zero-length ones drop out
        ka = np.where(t == 1.0, kb, ka)
        kb = np.where(t == 0.0, ka, kb)
        code = (ka * nk + kb) * len(levels) + lev
        ends_code.append(code)
        ends_uv.append(uv)
        ends_arc.append(auv)
    ends_code = np.stack(ends_code, axis=1)  # (P, 3)
    ends_uv = np.stack(ends_uv, axis=1)  # (P, 3, 2)
    ends_arc = np.stack(ends_arc, axis=1)  # (P, 3, 2): the arc point beyond a border chord, or NaN
    # the two crossed edges of each pair
    idx = np.argsort(~crossed, axis=1, kind="stable")[:, :2]  # first two True
    rows = np.arange(len(tri))[:, None]
    seg_code = ends_code[rows, idx]  # (P, 2)
    seg_uv = ends_uv[rows, idx]  # (P, 2, 2)
    seg_arc = ends_arc[rows, idx]  # (P, 2, 2)
    seg_face = tface[tri]
    seg_lev = lev
    # mesh edges on a level between two bands: segments from vertex point to vertex point
    et, ea, eb, elev = _level_edges(mapping, levels)
    if len(et):
        ka, kb = tkey[et, ea], tkey[et, eb]
        seg_code = np.concatenate([seg_code, np.column_stack([(ka * nk + ka) * len(levels) + elev,
                                                              (kb * nk + kb) * len(levels) + elev])])
        seg_uv = np.concatenate([seg_uv, np.stack([tuv[et, ea], tuv[et, eb]], axis=1)])
        seg_arc = np.concatenate([seg_arc, np.full((len(et), 2, 2), np.nan)])
        seg_face = np.concatenate([seg_face, tface[et]])
        seg_lev = np.concatenate([seg_lev, elev])
    # drop segments of zero length in (u, v) on the same point name (a level through a vertex)
    keep = seg_code[:, 0] != seg_code[:, 1]
    seg_code, seg_uv, seg_face, seg_lev = seg_code[keep], seg_uv[keep], seg_face[keep], seg_lev[keep]
    seg_arc = seg_arc[keep]
    S = len(seg_face)
    if S == 0:
        z = np.zeros(0)
        zi = np.zeros(0, dtype=np.int64)
        return ContourLines(levels, np.zeros((0, 3)), zi, z, z, np.zeros(1, dtype=np.int64), zi,
                            np.zeros(0, dtype=bool), zi, zi, z, z, z)
    uniq, inv = np.unique(seg_code.ravel(), return_inverse=True)
    pid = inv.reshape(S, 2)
    # crossings shared by segments on different faces: one point, computed on the lowest face
    ef = np.repeat(seg_face, 2)
    euv = seg_uv.reshape(-1, 2).copy()
    pmin = np.full(len(uniq), np.iinfo(np.int64).max)
    np.minimum.at(pmin, pid.ravel(), ef)
    foreign = ef != pmin[pid.ravel()]
    if np.any(foreign):
        prim = np.flatnonzero(~foreign)
        ref = np.full(len(uniq), -1)
        ref[pid.ravel()[prim]] = prim
        fi = np.flatnonzero(foreign)
        src = ref[pid.ravel()[fi]]
        xyz = _eval(model, ef[src], euv[src, 0], euv[src, 1])
        for f in np.unique(ef[fi]):
            sel = np.flatnonzero(ef[fi] == f)
            sp = project_to_surface(model.faces[int(f)].surface, xyz[sel], uv0=euv[fi[sel]], global_check=False)
            euv[fi[sel], 0], euv[fi[sel], 1] = sp.u, sp.v
    seg_uv = euv.reshape(S, 2, 2)

    # subdivision to the chord tolerance
    mid = 0.5 * (seg_uv[:, 0] + seg_uv[:, 1])
    pts3 = _eval(model, np.repeat(seg_face, 3), np.column_stack([seg_uv[:, 0, 0], mid[:, 0], seg_uv[:, 1, 0]]).ravel(),
                 np.column_stack([seg_uv[:, 0, 1], mid[:, 1], seg_uv[:, 1, 1]]).ravel()).reshape(S, 3, 3)
    dev = np.linalg.norm(pts3[:, 1] - 0.5 * (pts3[:, 0] + pts3[:, 2]), axis=1)
    nsub = np.clip(np.ceil(np.sqrt(dev / max(tol, 1e-300))), 1, max_sub).astype(np.int64)

    order, flip, line_start, closed = _chain(pid[:, 0].copy(), pid[:, 1].copy(), len(uniq))
    n_lines = len(line_start) - 1
    # emit: per ordered segment its start point and interior points; the end of each line
    seg_o = order
    cnt = nsub[seg_o].copy()
    last = line_start[1:] - 1
    cnt[last] += 1  # the end point of each line (a closed line repeats its first point)
    tot = int(cnt.sum())
    rep = np.repeat(np.arange(len(seg_o)), cnt)
    local = np.arange(tot) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    tt = local / nsub[seg_o][rep]
    tt = np.where(flip[rep], 1.0 - tt, tt)
    s_of = seg_o[rep]
    uv = seg_uv[s_of, 0] + tt[:, None] * (seg_uv[s_of, 1] - seg_uv[s_of, 0])
    # end points exactly at the crossing (t = 0 / 1 written above are exact already)
    face = seg_face[s_of]
    pts = _eval(model, face, uv[:, 0], uv[:, 1])
    offsets = np.concatenate([[0], np.cumsum(np.add.reduceat(cnt, line_start[:-1]) if n_lines else [])]).astype(np.int64)
    level = seg_lev[seg_o[line_start[:-1]]]
    # joints: consecutive segments of a line on different faces or at different (u, v)
    prev_end_t = np.where(flip[:-1], 0.0, 1.0)
    same_line = np.ones(len(seg_o) - 1, dtype=bool) if len(seg_o) > 1 else np.zeros(0, dtype=bool)
    same_line[last[:-1]] = False
    s_prev, s_next = seg_o[:-1][same_line], seg_o[1:][same_line]
    uv_prev = seg_uv[s_prev, 0] + prev_end_t[same_line][:, None] * (seg_uv[s_prev, 1] - seg_uv[s_prev, 0])
    seg_first_point = np.cumsum(cnt) - cnt
    jpt = seg_first_point[1:][same_line]
    differs = (seg_face[s_prev] != face[jpt]) | np.any(uv_prev != uv[jpt], axis=1)
    jpt, s_prev, uv_prev = jpt[differs], s_prev[differs], uv_prev[differs]
    jface = seg_face[s_prev]
    jxyz = _eval(model, jface, uv_prev[:, 0], uv_prev[:, 1]) if len(jpt) else np.zeros((0, 3))
    gap = np.linalg.norm(jxyz - pts[jpt], axis=1) if len(jpt) else np.zeros(0)
    if n_lines and np.isfinite(seg_arc).any():
        # lines ending on a border chord of a curved trim run on to the trim curve, along the
        # sliver's line of constant field (cadbridge.results.borders)
        first_pos, last_pos = line_start[:-1], last
        a_start = seg_arc[seg_o[first_pos], np.where(flip[first_pos], 1, 0)]
        a_end = seg_arc[seg_o[last_pos], np.where(flip[last_pos], 0, 1)]
        f_start, f_end = seg_face[seg_o[first_pos]], seg_face[seg_o[last_pos]]
        ok_s = np.isfinite(a_start[:, 0]) & ~closed
        ok_e = np.isfinite(a_end[:, 0]) & ~closed
        # ends before starts where a line ends and the next begins (stable sort below)
        pos = np.concatenate([offsets[1:][ok_e], offsets[:-1][ok_s]])
        new_uv = np.concatenate([a_end[ok_e], a_start[ok_s]])
        new_face = np.concatenate([f_end[ok_e], f_start[ok_s]])
        order_i = np.argsort(pos, kind="stable")
        pos, new_uv, new_face = pos[order_i], new_uv[order_i], new_face[order_i]
        new_pts = _eval(model, new_face, new_uv[:, 0], new_uv[:, 1])
        pts = np.insert(pts, pos, new_pts, axis=0)
        face = np.insert(face, pos, new_face)
        uv = np.insert(uv, pos, new_uv, axis=0)
        # line i now starts after all points inserted for the lines before it
        offsets = offsets + np.concatenate([[0], np.cumsum(ok_s.astype(np.int64) + ok_e)])
        jpt = jpt + np.searchsorted(pos, jpt, side="right")
    return ContourLines(levels, pts, face, uv[:, 0], uv[:, 1], offsets, level.astype(np.int64), closed.astype(bool),
                        jpt.astype(np.int64), jface.astype(np.int64), uv_prev[:, 0].copy(), uv_prev[:, 1].copy(), gap)


@dataclass
class Contours:
    """Contour lines and bands of one mapping at one set of levels."""

    levels: np.ndarray
    lines: ContourLines
    bands: "object"  # cadbridge.results.bands.Bands
    mapping: "object"
    seconds: float = 0.0


def contour(mapping, levels: np.ndarray, *, chord_tol: float | None = None) -> Contours:
    """Lines (`contour_lines`) and bands (`cadbridge.results.bands.band_areas`) at ``levels``."""
    import time

    t0 = time.perf_counter()
    levels = np.asarray(levels, dtype=float)
    ranks = level_ranks(mapping, levels)
    lines = contour_lines(mapping, levels, chord_tol=chord_tol, ranks=ranks)
    bands = band_areas(mapping, levels, ranks=ranks)
    return Contours(np.asarray(levels, float), lines, bands, mapping, time.perf_counter() - t0)
