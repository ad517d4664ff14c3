"""Contour bands on the exact CAD: regions between consecutive levels, their trim loops in
each face's (u, v) and their exact area (Hawkins 1989, ch. 5: contour/trim regions).

Band numbering for levels c_0 < ... < c_{L-1}: band 0 is f < c_0, band i (1 <= i <= L-1) is
c_{i-1} <= f <= c_i, band L is f > c_{L-1} (the open bands exist only where the field leaves
the level range, e.g. with --min / --max). Values equal to a level: a sub-triangle that a
level only touches (at a vertex or along an edge) lies whole in the band of its interior;
one of constant value lies in `band_index`'s band (`cadbridge.results.levels`). So no piece
has zero area, and every triangle is decided the same way on every face and seam side.

A sub-triangle of the mapping whose three values lie in one band belongs to it whole; its
exact area was computed once by the mapping. A sub-triangle that levels cross is clipped
(Sutherland-Hodgman on the linear field, at most 5 vertices per piece) into one convex
(u, v) polygon per band it meets; a piece's area is the integral of |Su x Sv| over its fan
triangles (conical Gauss rule). Cut points on an edge are computed in a canonical order of
the edge's ends, so the pieces of neighbouring triangles share their vertices bit for bit.

`Bands.regions()` assembles, per band and face, the boundary of the union of its pieces:
edges that no neighbouring piece of the same band runs back along, chained into loops;
counter-clockwise loops are outer boundaries, clockwise ones holes (assigned to the outer
loop that contains them). These loops are the trim curves of the IGES bands.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from cadbridge.results.areas import surface_area_of_triangles
from cadbridge.results.levels import level_ranks

__all__ = ["Bands", "BandRegion", "band_areas", "band_index"]


def band_index(values: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """Band of each value (see the module text), int64 of the same shape."""
    b = np.searchsorted(levels, values, side="right")
    if len(levels) >= 2:
        b = np.where(values == levels[-1], len(levels) - 1, b)
    return b.astype(np.int64)


def _clip(poly: np.ndarray, cnt: np.ndarray, c: np.ndarray, keep_above: bool) -> tuple[np.ndarray, np.ndarray]:
    """Clip convex polygons (P, M, 3) [u, v, f] with ``cnt`` (P,) vertices by f >= c
    (keep_above) or f <= c. Returns (P, M + 1, 3) and the new counts."""
    P, M, _ = poly.shape
    out = np.zeros((P, M + 1, 3))
    ncnt = np.zeros(P, dtype=np.int64)
    rows = np.arange(P)
    for j in range(M):
        valid = j < cnt
        nxt = np.where(j + 1 < cnt, j + 1, 0)
        a = poly[:, j]
        b = poly[rows, nxt]
        ga = a[:, 2] - c if keep_above else c - a[:, 2]
        gb = b[:, 2] - c if keep_above else c - b[:, 2]
        ina, inb = ga >= 0, gb >= 0
        m = valid & ina
        out[rows[m], ncnt[m]] = a[m]
        ncnt += m
        m = valid & (ina != inb)
        if np.any(m):
            pa, pb = a[m], b[m]
            swap = (pa[:, 0] > pb[:, 0]) | ((pa[:, 0] == pb[:, 0]) & (pa[:, 1] > pb[:, 1]))
            p = np.where(swap[:, None], pb, pa)
            q = np.where(swap[:, None], pa, pb)
            cc = c[m]
            t = (cc - p[:, 2]) / (q[:, 2] - p[:, 2])
            x = np.where((t == 1.0)[:, None], q, p + t[:, None] * (q - p))  # a vertex on c: itself
            x[:, 2] = cc
            out[rows[m], ncnt[m]] = x
            ncnt += m
    return out, ncnt


@dataclass
class BandRegion:
    """One connected region of one band on one face: trim loops in (u, v).

    band, face   indices; outer (n, 2) counter-clockwise loop (first point not repeated);
    holes        list of (m, 2) clockwise loops inside it
    area         exact area: the sum of the band's pieces inside the region
    """

    band: int
    face: int
    outer: np.ndarray
    holes: list[np.ndarray]
    area: float = 0.0


@dataclass
class Bands:
    """Bands of a mapping at given levels.

    levels        (L,); lower, upper (L + 1,) band limits (-inf / +inf for the open bands)
    area          (L + 1,) exact area per band (model units squared)
    face_area     (L + 1, F) per band and face
    pieces_*      the clipped pieces: band, face, sub-triangle, exact area (P,); their polygons
                  pieces_poly (P, 5, 3) [u, v, f] with pieces_count (P,) vertices (on demand)
    whole         (T,) band of each sub-triangle lying in one band, -1 where clipped
    """

    levels: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    area: np.ndarray
    face_area: np.ndarray
    whole: np.ndarray
    pieces_band: np.ndarray
    pieces_face: np.ndarray
    pieces_tri: np.ndarray
    pieces_area: np.ndarray
    slivers: tuple = field(repr=False, default=None)  # arc, band, t0, t1, area (S,) each
    bmin: np.ndarray = field(repr=False, default=None)
    bmax: np.ndarray = field(repr=False, default=None)
    mapping: object = field(repr=False, default=None)

    @cached_property
    def _polygons(self) -> tuple[np.ndarray, np.ndarray]:
        """All pieces' polygons (P, 5, 3) and counts, clipped on first use."""
        t, b = self.pieces_tri, self.pieces_band
        return _pieces(self.mapping, t, b, self.lower, self.upper, b > self.bmin[t], b < self.bmax[t])

    @property
    def pieces_poly(self) -> np.ndarray:
        return self._polygons[0]

    @property
    def pieces_count(self) -> np.ndarray:
        return self._polygons[1]

    @property
    def present(self) -> np.ndarray:
        """(L + 1,) bool: bands that hold area."""
        return self.area > 0

    def label(self, b: int, fmt: str = "{:.6g}") -> str:
        """'lo .. hi' for band b ('< c0', '> cL' for the open bands)."""
        lo, hi = self.lower[b], self.upper[b]
        if not np.isfinite(lo):
            return "< " + fmt.format(hi)
        if not np.isfinite(hi):
            return "> " + fmt.format(lo)
        return fmt.format(lo) + " .. " + fmt.format(hi)

    def polygons(self, band: int, face: int) -> list[np.ndarray]:
        """All (u, v) polygons (k, 2) of ``band`` on ``face``: whole sub-triangles and pieces."""
        m = self.mapping
        sel = np.flatnonzero((self.whole == band) & (m.tri_face == face))
        out = [t for t in m.tri_uv[sel]]
        ps = np.flatnonzero((self.pieces_band == band) & (self.pieces_face == face))
        out += [self.pieces_poly[i, : self.pieces_count[i], :2] for i in ps]
        return out

    def regions(self) -> list[BandRegion]:
        """Trim loops of every band on every face (see the module text)."""
        m = self.mapping
        T = len(m.tri_face)
        # all polygons as directed edges (band, face, a, b) with exact vertex coordinates
        wsel = np.flatnonzero(self.whole >= 0)
        polys = [(self.whole[wsel], m.tri_face[wsel], m.tri_uv[wsel], np.full(len(wsel), 3))]
        if len(self.pieces_band):
            polys.append((self.pieces_band, self.pieces_face, self.pieces_poly[:, :, :2], self.pieces_count))
        ea, eb, eband, eface = [], [], [], []
        for band, face, uv, cnt in polys:
            K = uv.shape[1]
            for j in range(K):
                ok = j < cnt
                nxt = np.where(j + 1 < cnt, j + 1, 0)
                r = np.flatnonzero(ok)
                ea.append(uv[r, j])
                eb.append(uv[r, nxt[r]])
                eband.append(band[r])
                eface.append(face[r])
        ea, eb = np.concatenate(ea), np.concatenate(eb)
        eband, eface = np.concatenate(eband), np.concatenate(eface)
        del T
        # vertex ids: the same (face, u, v) up to 1e-11 of the face's domain (vertices moved
        # back through a seam by one period differ from their neighbours' in the last bits)
        allv = np.concatenate([np.column_stack([eface, ea]), np.column_stack([eface, eb])])
        uniq, inv = np.unique(allv, axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        dom = np.array([f.surface.domain for f in m.model.faces])[uniq[:, 0].astype(np.int64)]
        span = np.maximum(np.stack([dom[:, 1] - dom[:, 0], dom[:, 3] - dom[:, 2]], axis=1), 1e-300)
        norm = (uniq[:, 1:] - dom[:, [0, 2]]) / span
        norm[:, 0] += 4.0 * uniq[:, 0]  # faces never merge
        pairs = cKDTree(norm).query_pairs(1e-11, output_type="ndarray")
        if len(pairs):
            g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(uniq), len(uniq)))
            _, rep = connected_components(g, directed=False)
            first = np.full(rep.max() + 1, -1)
            first[rep[::-1]] = np.arange(len(rep))[::-1]
            inv = first[rep][inv]
        ia, ib = inv[: len(ea)], inv[len(ea):]
        nv = np.int64(len(uniq))
        keep = ia != ib
        ia, ib, eband, eface = ia[keep], ib[keep], eband[keep], eface[keep]
        code = (eband * nv + ia) * nv + ib
        rcode = (eband * nv + ib) * nv + ia
        sc = np.sort(code)
        pos = np.searchsorted(sc, rcode)
        has_rev = (pos < len(sc)) & (sc[np.minimum(pos, len(sc) - 1)] == rcode)
        bd = np.flatnonzero(~has_rev)
        regions: list[BandRegion] = []
        # chain per (band, face)
        key = eband[bd] * (len(m.model.faces) + 1) + eface[bd]
        order = np.argsort(key, kind="stable")
        bd = bd[order]
        cuts = np.flatnonzero(np.diff(key[order])) + 1
        for grp in np.split(bd, cuts):
            if not len(grp):
                continue
            band, face = int(eband[grp[0]]), int(eface[grp[0]])
            nxt: dict[int, list[int]] = {}
            for a, b in zip(ia[grp].tolist(), ib[grp].tolist()):
                nxt.setdefault(a, []).append(b)
            loops = []
            while nxt:
                a0 = next(iter(nxt))
                loop = [a0]
                a = a0
                while True:
                    outs = nxt.get(a)
                    if not outs:
                        break
                    b = outs.pop()
                    if not outs:
                        del nxt[a]
                    if b == a0:
                        break
                    loop.append(b)
                    a = b
                if len(loop) >= 3:
                    loops.append(_simplify(uniq[np.array(loop), 1:]))
            outers = [lp for lp in loops if _signed_area(lp) > 0]
            holes = [lp for lp in loops if _signed_area(lp) <= 0]
            regs = [BandRegion(band, face, lp, []) for lp in outers]
            for h in holes:
                best, best_a = None, np.inf
                for r in regs:
                    if _inside(h, r.outer):
                        a = _signed_area(r.outer)
                        if a < best_a:
                            best, best_a = r, a
                if best is not None:
                    best.holes.append(h)
            self._region_areas(regs)
            regions += regs
        return regions


    def _region_areas(self, regs: list[BandRegion]) -> None:
        """Each region's area: the band's polygons on its face whose centroid lies in it (the
        loops are exactly these polygons' outline, so the polygon test is exact here)."""
        from cadbridge.cad.model import points_in_polygon

        if not regs:
            return
        b, f = regs[0].band, regs[0].face
        if len(regs) == 1:
            regs[0].area = float(self.face_area[b, f])
            return
        m = self.mapping
        sel = np.flatnonzero((self.whole == b) & (m.tri_face == f))
        ps = np.flatnonzero((self.pieces_band == b) & (self.pieces_face == f))
        pp, pc = self.pieces_poly[ps, :, :2], self.pieces_count[ps]
        valid = np.arange(pp.shape[1])[None, :] < pc[:, None]
        pcen = (pp * valid[:, :, None]).sum(axis=1) / np.maximum(pc, 1)[:, None]
        cen = np.concatenate([m.tri_uv[sel].mean(axis=1), pcen])
        area = np.concatenate([m.tri_area[sel], self.pieces_area[ps]])
        if self.slivers is not None and len(self.slivers[0]):  # slivers beyond curved-trim chords
            k, sb, t0, t1, sa = self.slivers
            arcs = m.arcs
            s_sel = np.flatnonzero((sb == b) & (arcs.face[k] == f))
            if len(s_sel):
                kk = k[s_sel]
                tm = 0.5 * (t0[s_sel] + t1[s_sel])
                at = arcs.a[kk] + tm[:, None] * (arcs.b[kk] - arcs.a[kk])
                opp = m.tri_uv[arcs.tri[kk], (arcs.edge[kk] + 2) % 3]
                cen = np.concatenate([cen, at + 1e-6 * (opp - at)])  # just inside the triangle
                area = np.concatenate([area, sa[s_sel]])
        taken = np.zeros(len(cen), dtype=bool)
        for r in regs:
            inside = points_in_polygon(cen, r.outer) & ~taken
            for h in r.holes:
                inside &= ~points_in_polygon(cen, h)
            taken |= inside
            r.area = float(area[inside].sum())


def _signed_area(loop: np.ndarray) -> float:
    x, y = loop[:, 0], loop[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _inside(hole: np.ndarray, outer: np.ndarray) -> bool:
    """Whether the hole loop lies in the outer loop: the hole's vertices are shared edges or
    inside, so the test uses the hole vertex farthest inside (largest even-odd majority)."""
    from cadbridge.cad.model import points_in_polygon

    return bool(np.mean(points_in_polygon(hole, outer)) > 0.5)


def _simplify(loop: np.ndarray, rel: float = 1e-13) -> np.ndarray:
    """Drop loop vertices where the loop runs straight on in (u, v) (the region is unchanged)."""
    if len(loop) <= 3:
        return loop
    prev = np.roll(loop, 1, axis=0)
    nxt = np.roll(loop, -1, axis=0)
    d1, d2 = loop - prev, nxt - loop
    cross = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    dot = np.einsum("ij,ij->i", d1, d2)
    scale = np.linalg.norm(d1, axis=1) * np.linalg.norm(d2, axis=1)
    straight = (np.abs(cross) <= rel * scale) & (dot > 0)
    if straight.all():
        return loop
    return loop[~straight]


def _pieces(mapping, tri: np.ndarray, band: np.ndarray, lower: np.ndarray, upper: np.ndarray,
            clip_lo: np.ndarray, clip_hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Polygons (P, 5, 3) [u, v, f] and vertex counts of sub-triangles ``tri`` clipped to their
    ``band``; only rows flagged ``clip_lo`` / ``clip_hi`` meet that bound."""
    poly = np.zeros((len(tri), 5, 3))
    poly[:, :3, :2] = mapping.tri_uv[tri]
    poly[:, :3, 2] = mapping.tri_f[tri]
    pc = np.full(len(tri), 3, dtype=np.int64)
    for flag, bound, above in ((clip_lo, lower, True), (clip_hi, upper, False)):
        r = np.flatnonzero(flag)
        if len(r):
            width = int(pc[r].max())
            out, n = _clip(poly[r, :width], pc[r], bound[band[r]], above)
            poly[r, : out.shape[1]] = out[:, :5]
            pc[r] = n
    return poly, pc


def _fan_areas(mapping, poly: np.ndarray, pc: np.ndarray, face: np.ndarray, quadrature: int) -> np.ndarray:
    """Exact area of convex (u, v) polygons (fan triangles from vertex 0), (P,)."""
    area = np.zeros(len(poly))
    uvs, owner = [], []
    for j in range(1, 4):
        r = np.flatnonzero(pc > j + 1)
        uvs.append(np.stack([poly[r, 0, :2], poly[r, j, :2], poly[r, j + 1, :2]], axis=1))
        owner.append(r)
    uv, owner = np.concatenate(uvs), np.concatenate(owner)
    fr = face[owner]
    order = np.argsort(fr, kind="stable")
    cuts = np.flatnonzero(np.diff(fr[order])) + 1
    for grp in np.split(order, cuts):
        if len(grp):
            a = surface_area_of_triangles(mapping.model.faces[int(fr[grp[0]])].surface, uv[grp], quadrature)
            area += np.bincount(owner[grp], weights=a, minlength=len(poly))
    return area


def _slivers(mapping, levels: np.ndarray):
    """The slivers between border chords and curved trim arcs, split at the levels: arc,
    band, t0, t1, exact area (S,) each (`cadbridge.results.borders`)."""
    arcs = mapping.arcs
    K = len(arcs)
    if K == 0:
        z = np.zeros(0)
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), z, z, z
    fa, fb = arcs.fa, arcs.fb
    lo = np.searchsorted(levels, np.minimum(fa, fb), side="right")
    hi = np.searchsorted(levels, np.maximum(fa, fb), side="left")
    cnt = np.maximum(hi - lo, 0)
    arc = np.repeat(np.arange(K), cnt)
    lev = np.repeat(lo, cnt) + (np.arange(len(arc)) - np.repeat(np.cumsum(cnt) - cnt, cnt))
    t = (levels[lev] - fa[arc]) / (fb[arc] - fa[arc])
    arc = np.concatenate([np.arange(K), np.arange(K), arc])
    t = np.concatenate([np.zeros(K), np.ones(K), t])
    order = np.lexsort((t, arc))
    arc, t = arc[order], t[order]
    same = arc[1:] == arc[:-1]
    k, t0, t1 = arc[:-1][same], t[:-1][same], t[1:][same]
    keep = t1 > t0
    k, t0, t1 = k[keep], t0[keep], t1[keep]
    fm = fa[k] + 0.5 * (t0 + t1) * (fb[k] - fa[k])
    band = band_index(fm, levels)
    # a chord of constant value on a level: the sliver (constant too) joins its sub-triangle's
    # band, the side of the level where the triangle's third vertex lies
    f3 = mapping.tri_f[arcs.tri[k], (arcs.edge[k] + 2) % 3]
    flat = (fa[k] == fb[k]) & np.isin(fm, levels) & (f3 != fm)
    band[flat] = np.where(f3[flat] < fm[flat], np.searchsorted(levels, fm[flat], side="left"),
                          np.searchsorted(levels, fm[flat], side="right"))
    return k, band, t0, t1, arcs.sliver_area(mapping, k, t0, t1)


def band_areas(mapping, levels: np.ndarray, quadrature: int = 4, ranks: tuple[np.ndarray, np.ndarray] | None = None
               ) -> Bands:
    """Bands of ``mapping`` at ``levels`` with exact areas (see the module text).

    Per crossed sub-triangle, the pieces below its highest band are clipped and integrated;
    the piece in the highest band is the triangle's exact area minus theirs (its polygon is
    clipped only when the regions are asked for). ranks: `level_ranks` if already computed."""
    levels = np.asarray(levels, dtype=float)
    L = len(levels)
    F = len(mapping.model.faces)
    lower = np.concatenate([[-np.inf], levels])
    upper = np.concatenate([levels, [np.inf]])
    if ranks is None:
        ranks = level_ranks(mapping, levels)
    # a triangle meets bands lo .. hi with positive area (`level_ranks`: a level equal to its
    # smallest or largest value only touches it); a constant one lies in band_index's band
    fmin, fmax = mapping.tri_range
    bmin, bmax = ranks[0].copy(), ranks[1].copy()
    const = fmin == fmax
    bmin[const] = bmax[const] = band_index(fmin[const], levels)
    one = bmin == bmax
    whole = np.where(one, bmin, -1)
    face_area = np.bincount(np.where(one, bmin * F + mapping.tri_face, (L + 1) * F), weights=mapping.tri_area,
                            minlength=(L + 1) * F + 1)[: (L + 1) * F].reshape(L + 1, F)
    # crossed triangles: one piece per band they meet
    ct = np.flatnonzero(~one)
    cnt = bmax[ct] - bmin[ct] + 1
    tri = np.repeat(ct, cnt)
    band = np.repeat(bmin[ct], cnt) + (np.arange(len(tri)) - np.repeat(np.cumsum(cnt) - cnt, cnt))
    pface = mapping.tri_face[tri]
    top = band == bmax[tri]
    sub = np.flatnonzero(~top)
    poly, pc = _pieces(mapping, tri[sub], band[sub], lower, upper, band[sub] > bmin[tri[sub]], np.ones(len(sub), bool))
    parea = np.zeros(len(tri))
    parea[sub] = _fan_areas(mapping, poly, pc, pface[sub], quadrature)
    below = np.bincount(tri[sub], weights=parea[sub], minlength=len(mapping.tri_face))
    ti = tri[top]
    parea[top] = np.maximum(mapping.tri_area[ti] - below[ti], 0.0)
    face_area += np.bincount(band * F + pface, weights=parea, minlength=(L + 1) * F).reshape(L + 1, F)
    sl = _slivers(mapping, levels)
    if len(sl[0]):
        face_area += np.bincount(sl[1] * F + mapping.arcs.face[sl[0]], weights=sl[4],
                                 minlength=(L + 1) * F).reshape(L + 1, F)
    return Bands(slivers=sl, levels=levels, lower=lower, upper=upper, area=face_area.sum(axis=1), face_area=face_area,
                 whole=whole, pieces_band=band, pieces_face=pface, pieces_tri=tri, pieces_area=parea,
                 bmin=bmin, bmax=bmax, mapping=mapping)
