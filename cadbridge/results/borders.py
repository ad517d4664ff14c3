"""Mesh borders on curved trim curves: the exact arc beyond each border chord (Hawkins 1989,
§5.1: the band regions' boundary segments are pieces of the actual boundary curves).

A mesh edge on a face's trim curve is a straight chord in (u, v); the face itself ends at
the trim curve c(tau). Between the two lies a sliver, parametrised over the chord's
parameter t and s in [0, 1] as

    uv(t, s) = (1 - s) (a + t (b - a)) + s c(tau(t)),   tau(t) = tau_a + t (tau_b - tau_a),

with the field linear in t along the chord (the chord's own values, carried out to the
curve). Its exact area is -integral |Su x Sv| det(d uv / d(t, s)) dt ds (Gauss-Legendre
8 x 4, split at the levels and at the trim curve's knots); it is added to the bands of the
sub-triangle the chord bounds (a hole's curve bulging into the triangle gives a negative
sliver). Contour crossings on such chords move onto the arc, and the IGES band loops use
the trim curve itself (the same NURBS over [tau_a, tau_b]) instead of the chord.

Only chords whose two ends lie on the same trim curve are replaced (a chord across a
junction of two trim pieces stays straight); straight trims and domain edges need none.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from cadbridge.nurbs.curve import NurbsCurve

__all__ = ["BorderArcs", "find_border_arcs", "loop_curves", "NO_ARCS"]


@dataclass
class BorderArcs:
    """Border chords on curved trim curves (K of them).

    face, tri, edge  (K,) face, sub-triangle and its local edge (vertices edge -> edge + 1)
    ka, kb           (K,) vertex keys of the chord's ends, in that order
    a, b             (K, 2) the chord's ends in (u, v); fa, fb (K,) the field there
    curve            (K,) index into ``curves``: (face, trim curve, closed, t0, t1)
    ta, tb           (K,) curve parameters of the ends (for a closed curve unwrapped the
                     short way round; evaluation wraps them back)
    skipped          border chords with ends on two different trim pieces (left straight)
    """

    face: np.ndarray
    tri: np.ndarray
    edge: np.ndarray
    ka: np.ndarray
    kb: np.ndarray
    a: np.ndarray
    b: np.ndarray
    fa: np.ndarray
    fb: np.ndarray
    curve: np.ndarray
    ta: np.ndarray
    tb: np.ndarray
    curves: list = field(default_factory=list)
    skipped: int = 0
    grad: np.ndarray = None  # (K, 2) the sub-triangle's field gradient in (u, v)
    iso: np.ndarray = None  # (K,) bool: tau* follows its iso-lines (else the linear map)

    def __post_init__(self) -> None:
        if self.grad is None:
            self.grad = np.zeros((len(self.face), 2))
        if self.iso is None:
            self.iso = np.zeros(len(self.face), dtype=bool)

    def __len__(self) -> int:
        return len(self.face)

    def _wrap(self, k: np.ndarray, tau: np.ndarray) -> np.ndarray:
        out = tau.copy()
        for c in np.unique(self.curve[k]):
            _, _, closed, t0, t1 = self.curves[c]
            if closed:
                sel = self.curve[k] == c
                out[sel] = t0 + np.mod(tau[sel] - t0, t1 - t0)
        return out

    def _curve_ders(self, k: np.ndarray, tau: np.ndarray, order: int) -> np.ndarray:
        w = self._wrap(k, tau)
        out = np.empty((len(k), order + 1, 2))
        for c in np.unique(self.curve[k]):
            sel = np.flatnonzero(self.curve[k] == c)
            out[sel] = self.curves[c][1].derivatives(w[sel], order=order)[:, :, :2]
        return out

    def tau(self, k: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Curve parameter tau*(t) (unwrapped) and d tau* / dt at chord parameter t, (M,) each:
        the arc point on the iso-line of the sub-triangle's linear field through chord(t),
        grad . (c(tau*) - chord(t)) = 0 (Newton from the linear map); where the field has no
        gradient across the chord, or its iso-lines touch the arc, the linear map."""
        k = np.asarray(k)
        t = np.asarray(t, dtype=float)
        ta, tb = self.ta[k], self.tb[k]
        tau = ta + t * (tb - ta)
        dtau = tb - ta
        iso = self.iso[k]
        if not np.any(iso):
            return tau, dtau
        r = np.flatnonzero(iso)
        kr, g = k[r], self.grad[k[r]]
        chord = self.a[kr] + t[r, None] * (self.b[kr] - self.a[kr])
        lo, hi = np.minimum(ta[r], tb[r]), np.maximum(ta[r], tb[r])
        x = tau[r].copy()
        for _ in range(20):
            d = self._curve_ders(kr, x, 1)
            gv = np.einsum("ij,ij->i", g, d[:, 0] - chord)
            gp = np.einsum("ij,ij->i", g, d[:, 1])
            x = np.clip(x - gv / np.where(gp != 0, gp, 1e-300), lo, hi)
        d = self._curve_ders(kr, x, 1)
        gp = np.einsum("ij,ij->i", g, d[:, 1])
        tau[r] = x
        dtau[r] = np.einsum("ij,ij->i", g, self.b[kr] - self.a[kr]) / np.where(gp != 0, gp, 1e-300)
        return tau, dtau

    def arc(self, k: np.ndarray, t: np.ndarray, order: int = 0) -> np.ndarray:
        """(M, order + 1, 2): c(tau*(t)) and (order 1) its t-derivative c'(tau*) tau*'."""
        k = np.asarray(k)
        tau, dtau = self.tau(k, np.asarray(t, dtype=float))
        d = self._curve_ders(k, tau, min(order, 1))
        if order >= 1:
            d[:, 1] *= dtau[:, None]
        return d

    def sliver_area(self, mapping, k: np.ndarray, t0: np.ndarray, t1: np.ndarray, n: int = 8, m: int = 4) -> np.ndarray:
        """Exact area the face adds beyond chords ``k`` over chord parameters [t0, t1] (M,),
        split at the trim curve's knots (module text)."""
        k, t0, t1 = np.asarray(k), np.asarray(t0, float), np.asarray(t1, float)
        if len(k) == 0:
            return np.zeros(0)
        # split at the trim knots inside (t0, t1)
        rows, lo, hi = [], [], []
        for c in np.unique(self.curve[k]):
            sel = np.flatnonzero(self.curve[k] == c)
            crv = self.curves[c][1]
            kn = np.unique(getattr(crv, "knots", np.zeros(0)))
            _, _, closed, c0, c1 = self.curves[c]
            per = c1 - c0
            for i in sel:
                ki = k[i]
                ta, tb = self.ta[ki], self.tb[ki]
                cuts = []
                if tb != ta:
                    for q in kn:
                        for sh in ((-per, 0.0, per) if closed else (0.0,)):
                            if not min(ta, tb) < q + sh < max(ta, tb):
                                continue
                            if self.iso[ki]:  # the chord point on the knot's iso-line
                                cq = self._curve_ders(np.array([ki]), np.array([q + sh]), 0)[0, 0]
                                g = self.grad[ki]
                                tt = float(g @ (cq - self.a[ki]) / (g @ (self.b[ki] - self.a[ki])))
                            else:
                                tt = (q + sh - ta) / (tb - ta)
                            if t0[i] < tt < t1[i]:
                                cuts.append(tt)
                edges = np.concatenate([[t0[i]], np.sort(cuts), [t1[i]]])
                rows += [i] * (len(edges) - 1)
                lo += list(edges[:-1])
                hi += list(edges[1:])
        rows, lo, hi = np.array(rows), np.array(lo), np.array(hi)
        xg, wg = np.polynomial.legendre.leggauss(n)
        xs, ws = np.polynomial.legendre.leggauss(m)
        tq = 0.5 * (lo[:, None] + hi[:, None]) + 0.5 * (hi - lo)[:, None] * xg[None, :]  # (R, n)
        wt = 0.5 * (hi - lo)[:, None] * wg[None, :]
        s = 0.5 * (xs + 1.0)
        w_s = 0.5 * ws
        kk = np.repeat(k[rows], n)
        cd = self.arc(kk, tq.ravel(), order=1)  # (R n, 2, 2)
        a, b = self.a[kk], self.b[kk]
        chord = a + tq.ravel()[:, None] * (b - a)
        d_t = (1.0 - s[None, :, None]) * (b - a)[:, None, :] + s[None, :, None] * cd[:, None, 1, :]  # (Rn, m, 2)
        d_s = (cd[:, 0, :] - chord)[:, None, :]  # (Rn, 1, 2)
        det = d_t[..., 0] * d_s[..., 1] - d_t[..., 1] * d_s[..., 0]  # (Rn, m)
        uv = (1.0 - s[None, :, None]) * chord[:, None, :] + s[None, :, None] * cd[:, None, 0, :]
        jac = np.empty(det.shape)
        faces = self.face[kk]
        for f in np.unique(faces):
            sel = np.flatnonzero(faces == f)
            surf = mapping.model.faces[int(f)].surface
            u0, u1, v0, v1 = surf.domain
            q = uv[sel].reshape(-1, 2)
            d = surf.derivatives(np.clip(q[:, 0], u0, u1), np.clip(q[:, 1], v0, v1), order=1)
            jac[sel] = np.linalg.norm(np.cross(d[:, 1, 0], d[:, 0, 1]), axis=1).reshape(len(sel), m)
        val = -(det * jac) @ w_s  # (Rn,)
        per_row = (val.reshape(len(rows), n) * wt).sum(axis=1)
        return np.bincount(rows, weights=per_row, minlength=len(k))

    def subcurves(self, k: int, t0: float, t1: float) -> list:
        """The trim curve from tau(t0) to tau(t1) as NURBS pieces in that direction (the same
        control net, knots and weights over a sub-domain; reversed if need be; split where
        a closed curve wraps). Non-NURBS trim curves give None."""
        crv = self.curves[self.curve[k]][1]
        if not isinstance(crv, NurbsCurve):
            return None
        _, _, closed, c0, c1 = self.curves[self.curve[k]]
        tt, _ = self.tau(np.array([k, k]), np.array([t0, t1]))
        p, q = float(tt[0]), float(tt[1])
        pieces = []
        if closed:
            per = c1 - c0
            shift = np.floor((min(p, q) - c0) / per) * per
            p, q = p - shift, q - shift  # min(p, q) in [c0, c1)
            if max(p, q) > c1:
                mid = c1
                first, second = ((p, mid), (c0, q - per)) if p < q else ((p - per, c0), (mid, q))
                return [self._piece(crv, *first), self._piece(crv, *second)]
        pieces.append(self._piece(crv, p, q))
        return pieces

    @staticmethod
    def _piece(crv: NurbsCurve, p: float, q: float) -> NurbsCurve:
        """The curve over [p, q] (or reversed for p > q) as its own clamped NURBS (knot
        insertion: the same curve, exactly; OCC reads sub-ranges of unclamped curves badly)."""
        from cadbridge.nurbs.edits import restrict_curve, reverse_curve

        c2 = NurbsCurve(crv.degree, crv.knots, crv.control_points[:, :2], crv.weights if crv.rational else None,
                        crv.domain)
        piece = restrict_curve(c2, min(p, q), max(p, q))
        return piece if p <= q else reverse_curve(piece)


def _empty() -> BorderArcs:
    z = np.zeros(0)
    zi = np.zeros(0, dtype=np.int64)
    return BorderArcs(zi, zi, zi, zi, zi, np.zeros((0, 2)), np.zeros((0, 2)), z, z, zi, z, z)


NO_ARCS = _empty()


_SAMPLES: dict = {}


def _samples(c) -> tuple[np.ndarray, np.ndarray, float]:
    """Parameters, (u, v) points and largest spacing of a trim curve's samples (cached)."""
    key = id(c)
    hit = _SAMPLES.get(key)
    if hit is None or hit[0] is not c:
        ts = c.sample_parameters(32)
        xs = c.evaluate(ts)[:, :2]
        gap = float(np.max(np.linalg.norm(np.diff(xs, axis=0), axis=1))) if len(xs) > 1 else 0.0
        hit = _SAMPLES[key] = (c, ts, xs, gap)
        if len(_SAMPLES) > 4096:
            _SAMPLES.clear()
    return hit[1], hit[2], hit[3]


def _nearest_on_curves(curves: list, pts: np.ndarray, tol: float, iters: int = 30):
    """Nearest point of 2D curves to (N, 2) points: curve index, parameter, distance (N,);
    points farther than ``tol`` from every curve get distance inf (no Newton for them)."""
    samples, owner, params, reach = [], [], [], []
    for i, (_, c, _, t0, t1) in enumerate(curves):
        ts, xs, gap = _samples(c)
        samples.append(xs)
        owner.append(np.full(len(ts), i))
        params.append(ts)
        reach.append(np.full(len(ts), gap))
    tree = cKDTree(np.concatenate(samples))
    d0, j = tree.query(pts)
    ci = np.concatenate(owner)[j]
    t = np.concatenate(params)[j].astype(float)
    dist = np.full(len(pts), np.inf)
    near = d0 <= 0.51 * np.concatenate(reach)[j] + 2.0 * tol  # within half a sample gap of the curve
    for i, (_, c, closed, t0, t1) in enumerate(curves):
        sel = np.flatnonzero((ci == i) & near)
        if not len(sel):
            continue
        tt = t[sel]
        act = np.arange(len(sel))
        for _ in range(iters):
            d = c.derivatives(tt[act], order=2)[:, :, :2]
            r = d[:, 0] - pts[sel[act]]
            g = np.einsum("ij,ij->i", r, d[:, 1])
            h = np.einsum("ij,ij->i", d[:, 1], d[:, 1]) + np.einsum("ij,ij->i", r, d[:, 2])
            step = g / np.where(h > 0, h, np.einsum("ij,ij->i", d[:, 1], d[:, 1]) + 1e-300)
            tn = tt[act] - step
            tn = t0 + np.mod(tn - t0, t1 - t0) if closed else np.clip(tn, t0, t1)
            done = np.abs(tn - tt[act]) <= 1e-15 * max(t1 - t0, 1.0)
            tt[act] = tn
            act = act[~done]
            if not len(act):
                break
        t[sel] = tt
        dist[sel] = np.linalg.norm(c.evaluate(tt)[:, :2] - pts[sel], axis=1)
    return ci, t, dist


def find_border_arcs(model, tri_face, tri_uv, tri_f, tri_key) -> BorderArcs:
    """The border chords of the sub-triangles that lie on curved trim curves (see the module
    text); sub-triangles counter-clockwise in (u, v)."""
    F = len(model.faces)
    faces_with = [f for f in np.unique(tri_face)
                  if model.faces[f].trims is not None
                  and (model.faces[f].trims.outer is not None or model.faces[f].trims.inner)]
    if not faces_with:
        return NO_ARCS
    out = []
    skipped = 0
    curves = []
    for f in faces_with:
        face = model.faces[f]
        u0, u1, v0, v1 = face.surface.domain
        diag = float(np.hypot(u1 - u0, v1 - v0))
        sel = np.flatnonzero(tri_face == f)
        ka = tri_key[sel].reshape(-1)
        kb = np.roll(tri_key[sel], -1, axis=1).reshape(-1)
        lo, hi = np.minimum(ka, kb), np.maximum(ka, kb)
        code = lo * (int(tri_key.max()) + 1) + hi
        uniq, inv, cnt = np.unique(code, return_inverse=True, return_counts=True)
        border = np.flatnonzero(cnt[inv.reshape(-1)] == 1)
        if not len(border):
            continue
        ti, ej = sel[border // 3], border % 3
        a = tri_uv[ti, ej]
        b = tri_uv[ti, (ej + 1) % 3]
        loops = ([face.trims.outer] if face.trims.outer is not None else []) + list(face.trims.inner)
        base = len(curves)
        for loop in loops:
            for c in loop.curves:
                t0, t1 = (float(x) for x in c.domain)
                e0, e1 = c.evaluate(np.array([t0, t1]))[:, :2]
                curves.append((f, c, bool(np.linalg.norm(e0 - e1) <= 1e-12 * diag), t0, t1))
        fc = curves[base:]
        tol = 1e-6 * diag
        ca, ta, da = _nearest_on_curves(fc, a, tol)
        cb, tb, db = _nearest_on_curves(fc, b, tol)
        on = (da <= tol) & (db <= tol)
        # an end at a junction of two trim pieces is on both: try the other end's piece
        for i in np.unique(np.concatenate([ca[on & (ca != cb)], cb[on & (ca != cb)]])):
            for mine, other, tm, pts, dm in ((ca, cb, ta, a, da), (cb, ca, tb, b, db)):
                sel = np.flatnonzero(on & (ca != cb) & (other == i) & (mine != i))
                if len(sel):
                    _, t_alt, d_alt = _nearest_on_curves([fc[i]], pts[sel], tol)
                    ok = d_alt <= tol
                    mine[sel[ok]], tm[sel[ok]], dm[sel[ok]] = i, t_alt[ok], d_alt[ok]
        same = on & (ca == cb)
        skipped += int(np.count_nonzero(on & (ca != cb)))
        idx = np.flatnonzero(same)
        if not len(idx):
            continue
        ta, tb, ci = ta[idx], tb[idx], ca[idx]
        for i in range(len(fc)):  # closed curves: the short way round
            _, _, closed, t0, t1 = fc[i]
            if closed:
                s = ci == i
                per = t1 - t0
                d = tb[s] - ta[s]
                tb[s] = tb[s] - per * np.round(d / per)
        mid_t = 0.5 * (ta + tb)
        mids = np.empty((len(idx), 2))
        for i in np.unique(ci):
            s = ci == i
            _, c, closed, t0, t1 = fc[i]
            mt = t0 + np.mod(mid_t[s] - t0, t1 - t0) if closed else mid_t[s]
            mids[s] = c.evaluate(mt)[:, :2]
        chord_mid = 0.5 * (a[idx] + b[idx])
        curved = np.linalg.norm(mids - chord_mid, axis=1) > 1e-13 * diag
        idx, ta, tb, ci = idx[curved], ta[curved], tb[curved], ci[curved]
        if not len(idx):
            continue
        t_i, e_i = ti[idx], ej[idx]
        # the sub-triangle's linear field in (u, v): gradient from its corners
        uvt, ft = tri_uv[t_i], tri_f[t_i]
        e1, e2 = uvt[:, 1] - uvt[:, 0], uvt[:, 2] - uvt[:, 0]
        det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
        d1, d2 = ft[:, 1] - ft[:, 0], ft[:, 2] - ft[:, 0]
        det_s = np.where(det != 0, det, 1.0)
        grad = np.column_stack([(d1 * e2[:, 1] - d2 * e1[:, 1]) / det_s, (e1[:, 0] * d2 - e2[:, 0] * d1) / det_s])
        grad[det == 0] = 0.0
        # tau* along iso-lines where the field changes along the chord and f(c(tau)) is
        # monotone over the arc (its iso-lines cross the arc once)
        ab = b[idx] - a[idx]
        along = np.einsum("ij,ij->i", grad, ab)
        iso = np.abs(along) > 1e-12 * np.linalg.norm(grad, axis=1) * np.linalg.norm(ab, axis=1)
        ss = np.linspace(0.0, 1.0, 9)
        for i in np.unique(ci):
            sel = np.flatnonzero((ci == i) & iso)
            if not len(sel):
                continue
            _, c, closed, t0, t1 = fc[i]
            tt = ta[sel, None] + ss[None, :] * (tb[sel] - ta[sel])[:, None]
            if closed:
                tt = t0 + np.mod(tt - t0, t1 - t0)
            dc = c.derivatives(tt.ravel(), order=1)[:, 1, :2].reshape(len(sel), len(ss), 2)
            gp = np.einsum("ij,ikj->ik", grad[sel], dc) * np.sign(tb[sel] - ta[sel])[:, None]
            # the iso-lines must cross the arc at 6 degrees or more (tau*' stays bounded)
            steep = np.abs(gp) >= 0.1 * np.linalg.norm(grad[sel], axis=1)[:, None] * np.linalg.norm(dc, axis=2)
            iso[sel] = np.all((gp * np.sign(along[sel])[:, None] > 0) & steep, axis=1)
        out.append((np.full(len(idx), f), t_i, e_i, tri_key[t_i, e_i], tri_key[t_i, (e_i + 1) % 3], a[idx], b[idx],
                    tri_f[t_i, e_i], tri_f[t_i, (e_i + 1) % 3], base + ci, ta, tb, grad, iso))
    if not out:
        arcs = _empty()
        arcs.curves, arcs.skipped = curves, skipped
        return arcs
    cols = [np.concatenate([o[i] for o in out]) for i in range(14)]
    del F
    return BorderArcs(*cols[:12], curves=curves, skipped=skipped, grad=cols[12], iso=cols[13])


def _polyline(pts: list) -> NurbsCurve | None:
    p = np.asarray(pts, dtype=float)
    if len(p) < 2:
        return None
    knots = np.concatenate([[0.0], np.arange(len(p), dtype=float), [len(p) - 1.0]])
    return NurbsCurve(1, knots, p)


def loop_curves(loop: np.ndarray, face: int, arcs: BorderArcs, diag: float) -> list:
    """A closed (u, v) band loop (n, 2) as trim curve pieces: where an edge runs along a
    border chord of a curved trim, the trim curve itself between the edge's ends (plus the
    straight sliver lines from the chord to the curve at a level cut); elsewhere degree-1
    pieces. Pieces join end to start exactly."""
    ks = np.flatnonzero(arcs.face == face) if len(arcs) else np.zeros(0, dtype=np.int64)
    P = loop
    Q = np.roll(loop, -1, axis=0)
    hit = np.full(len(P), -1)
    tp = np.zeros(len(P))
    tq = np.zeros(len(P))
    if len(ks):
        a, b = arcs.a[ks], arcs.b[ks]
        d = b - a
        L2 = np.einsum("ij,ij->i", d, d)
        tree = cKDTree(0.5 * (a + b))
        reach = 0.5 * float(np.sqrt(L2.max())) * (1 + 1e-9) + 1e-12 * diag
        mids = 0.5 * (P + Q)
        for i, cand in enumerate(tree.query_ball_point(mids, reach)):
            for c in cand:
                for X, out in ((P[i], tp), (Q[i], tq)):
                    t = float(np.dot(X - a[c], d[c]) / L2[c])
                    off = abs(d[c, 0] * (X[1] - a[c, 1]) - d[c, 1] * (X[0] - a[c, 0])) / np.sqrt(L2[c])
                    if not (-1e-12 <= t <= 1 + 1e-12 and off <= 1e-10 * diag):
                        break
                    out[i] = min(max(t, 0.0), 1.0)
                else:
                    if tp[i] != tq[i]:
                        hit[i] = ks[c]
                        break
    if not (hit >= 0).any():
        return [_polyline(np.vstack([loop, loop[:1]]))]
    # rotate so the loop starts at a vertex that is no level cut on an arc chord
    n = len(P)
    cut_at = np.zeros(n, dtype=bool)  # vertex i is a level cut of an iso arc edge next to it
    for i in range(n):
        k = hit[i]
        if k >= 0 and arcs.iso[k]:
            cut_at[i] |= 0.0 < tp[i] < 1.0
            cut_at[(i + 1) % n] |= 0.0 < tq[i] < 1.0
    start = int(np.argmin(cut_at)) if not cut_at.all() else 0
    order = (np.arange(n) + start) % n
    pieces = []
    run = [P[order[0]]]
    tiny = 1e-13 * diag
    for i in order:
        k = hit[i]
        if k < 0:
            run.append(Q[i])
            continue
        subs = arcs.subcurves(int(k), tp[i], tq[i])
        if subs is None:  # not a NURBS trim: densely sampled instead
            t = np.linspace(tp[i], tq[i], 65)
            pts = arcs.arc(np.full(len(t), k), t)[:, 0]
            if cut_at[i] and arcs.iso[k] and len(run) > 1:
                run.pop()
            run += list(pts)
            if not (arcs.iso[k] and 0.0 < tq[i] < 1.0):
                run.append(Q[i])
            continue
        c0 = subs[0].evaluate(np.array([subs[0].domain[0]]))[0, :2]
        c1 = subs[-1].evaluate(np.array([subs[-1].domain[1]]))[0, :2]
        if cut_at[i] and arcs.iso[k] and len(run) > 1:
            run.pop()  # the level cut on the chord: the line runs straight on to c0
        if np.linalg.norm(c0 - run[-1]) > tiny:
            run.append(c0)
        else:
            run[-1] = c0
        pl = _polyline(run)
        if pl is not None:
            pieces.append(pl)
        pieces += subs
        run = [c1]
        if not (arcs.iso[k] and 0.0 < tq[i] < 1.0) and np.linalg.norm(Q[i] - c1) > tiny:
            run.append(Q[i])
    first = pieces[0].evaluate(np.array([pieces[0].domain[0]]))[0, :2] if pieces else P[order[0]]
    if np.linalg.norm(run[-1] - first) > tiny:
        run.append(first)
    else:
        run[-1] = first
    pl = _polyline(run)
    if pl is not None:
        pieces.append(pl)
    return pieces
