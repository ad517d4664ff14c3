"""Compiled kernels of point inversion shared by `project_to_surface`, `project_to_surfaces`,
the trim and edge-foot searches (`cadbridge.cad.trims`, `cadbridge.cad.edgefeet`) and the
fitting's foot correction (`cadbridge.nurbs.fit`).

- `ders2_one`: S and its derivatives of total order <= 2 at one (u, v) (basis function
  derivatives, P&T A2.3; rational quotient rule, P&T A4.4), with work arrays `ders2_scratch`.
- `newton_range`: the projected Newton-Raphson iterations on f = Su.r, g = Sv.r with the full
  Jacobian (Neto 2010, appendix B, eqs. 32-36; P&T section 6.1), point by point, with the
  lazy line search and edge handling of `cadbridge.nurbs.project` (its module docstring).
- `wrap_clamp`: a parameter wrapped into a closed direction or clamped into an open one.
- `global_seeds`: extra Newton starts of the global check (discrete local minima of the
  sampled distance), with its constants `CHECK_K`, `CHECK_SEEDS` and `EDGE_SEEDS`.
"""

from __future__ import annotations

import numba
import numpy as np

from cadbridge.nurbs.basis import ders_basis_one, find_span_one

__all__ = ["CHECK_K", "CHECK_SEEDS", "EDGE_SEEDS", "FAILED_SEEDS", "ders2_one", "ders2_scratch", "global_seeds", "newton_range",
           "wrap_clamp"]


@numba.njit(cache=True)
def ders2_scratch(p, q):  # pragma: no cover - compiled
    """The work arrays of `ders2_one` for degrees (p, q), allocated once per kernel call."""
    return (np.empty((p + 1, p + 1)), np.empty((q + 1, q + 1)), np.empty(p + 1), np.empty(p + 1),
            np.empty(q + 1), np.empty(q + 1), np.empty((2, p + 1)), np.empty((2, q + 1)),
            np.empty((3, p + 1)), np.empty((3, q + 1)), np.empty((3, 3, 4)))


@numba.njit(cache=True, error_model="numpy")
def ders2_one(pw, ku, kv, p, q, rational, u, v, scratch, out):  # pragma: no cover - compiled
    """S and its derivatives of total order <= 2 at one (u, v) into out (3, 3, 3): out[k, l] =
    d^(k+l) S / du^k dv^l for k + l <= 2 (what Newton uses; out[2, 1], out[1, 2], out[2, 2] are
    not computed), the same sums in the same order as `NurbsSurface.derivatives` (its
    compiled kernel); ``scratch`` from `ders2_scratch(p, q)`."""
    ndu_u, ndu_v, lu, ru, lv, rv, au, av, bu, bv, aw = scratch
    nu, nv = pw.shape[0], pw.shape[1]
    su = find_span_one(ku, p, nu, u)
    sv = find_span_one(kv, q, nv, v)
    ders_basis_one(su, u, p, ku, 2, ndu_u, lu, ru, au, bu)
    ders_basis_one(sv, v, q, kv, 2, ndu_v, lv, rv, av, bv)
    aw[:] = 0.0
    for a in range(p + 1):
        row = pw[su - p + a]
        for l in range(3):
            t0 = 0.0
            t1 = 0.0
            t2 = 0.0
            t3 = 0.0
            for b in range(q + 1):
                w = bv[l, b]
                pt = row[sv - q + b]
                t0 += w * pt[0]
                t1 += w * pt[1]
                t2 += w * pt[2]
                t3 += w * pt[3]
            for k in range(3 - l):
                w = bu[k, a]
                aw[k, l, 0] += w * t0
                aw[k, l, 1] += w * t1
                aw[k, l, 2] += w * t2
                aw[k, l, 3] += w * t3
    if not rational:
        for k in range(3):
            for l in range(3 - k):
                for c in range(3):
                    out[k, l, c] = aw[k, l, c]
        return
    # quotient rule (P&T A4.4) with binomials of row 2: (1, 1), (1, 2, 1)
    w0 = aw[0, 0, 3]
    for k in range(3):
        for l in range(3 - k):
            for c in range(3):
                val = aw[k, l, c]
                for j in range(1, l + 1):
                    bl = 2.0 if (l == 2 and j == 1) else 1.0
                    val -= bl * aw[0, j, 3] * out[k, l - j, c]
                for i in range(1, k + 1):
                    bk = 2.0 if (k == 2 and i == 1) else 1.0
                    val -= bk * aw[i, 0, 3] * out[k - i, l, c]
                    for j in range(1, l + 1):
                        bl = 2.0 if (l == 2 and j == 1) else 1.0
                        val -= bk * bl * aw[i, j, 3] * out[k - i, l - j, c]
                out[k, l, c] = val / w0


@numba.njit(cache=True, error_model="numpy")
def wrap_clamp(x, lo, hi, closed):  # pragma: no cover - compiled
    """x wrapped into [lo, hi) where ``closed`` (periodic), else clamped to [lo, hi]."""
    if closed:
        per = hi - lo
        r = (x - lo) % per  # Python modulo: same as np.mod, in [0, per)
        return lo + r
    return min(max(x, lo), hi)


@numba.njit(cache=True, error_model="numpy")
def newton_range(pw, ku, kv, p, q, rational, u0, u1, v0, v1, cu, cv, eps1, eps2, pts, noise, u, v, iters,
                 max_iter, start, stop, tu, tv, ru, rv, same):  # pragma: no cover - compiled
    """The projected Newton iterations of `cadbridge.nurbs.project` (its module docstring),
    point by point: updates u, v (N,) and iters (N,) in place. Same tests and steps as the
    former vectorised loop: convergence first, then the lazy line search (halve the previous step when |r|^2
    grew beyond round-off), then the full-Jacobian step (Gauss-Newton where not positive
    definite; 1D Newton on an edge iso-curve where one variable is clamped).

    Restarts (ru >= 0): an iterate after the start that comes within (ru, rv) of the known
    foot (tu, tv) of its point is heading back to that foot: it stops there with same[t] True
    (the restart cannot be nearer)."""
    tiny = 1e-300
    pu = u1 - u0
    pv = v1 - v0
    scratch = ders2_scratch(p, q)
    der = np.empty((3, 3, 3))
    for t in range(start, stop):
        px, py, pz = pts[t, 0], pts[t, 1], pts[t, 2]
        e = noise[t]
        uu, vv = u[t], v[t]
        u_prev, v_prev = uu, vv
        d2_prev = np.inf
        du_prev = 0.0
        dv_prev = 0.0
        hit_u = False  # the last Newton step was cut at an edge in u / in v
        hit_v = False
        it = 0
        for _ in range(max_iter):
            if ru >= 0.0 and it > 0 and abs(uu - tu[t]) <= ru and abs(vv - tv[t]) <= rv:
                same[t] = True
                break
            ders2_one(pw, ku, kv, p, q, rational, uu, vv, scratch, der)
            it += 1
            rx, ry, rz = der[0, 0, 0] - px, der[0, 0, 1] - py, der[0, 0, 2] - pz
            sux, suy, suz = der[1, 0, 0], der[1, 0, 1], der[1, 0, 2]
            svx, svy, svz = der[0, 1, 0], der[0, 1, 1], der[0, 1, 2]
            d2 = rx * rx + ry * ry + rz * rz
            f = sux * rx + suy * ry + suz * rz
            g = svx * rx + svy * ry + svz * rz
            guu = sux * sux + suy * suy + suz * suz
            gvv = svx * svx + svy * svy + svz * svz
            lsu = np.sqrt(guu)
            lsv = np.sqrt(gvv)
            lr = np.sqrt(d2)
            act_u = (not cu) and ((uu <= u0 and f > 0) or (uu >= u1 and f < 0))
            act_v = (not cv) and ((vv <= v0 and g > 0) or (vv >= v1 and g < 0))
            cos_u = abs(f) / max(lsu * lr, tiny)
            cos_v = abs(g) / max(lsv * lr, tiny)
            # a direction whose derivative is round-off of the other's (on a pole or apex, where
            # moving along it does not move the point) has no orthogonality to meet
            pole_u = lsu <= 1e-9 * lsv
            pole_v = lsv <= 1e-9 * lsu
            conv = (lr <= eps1) or ((cos_u <= eps2 or act_u or pole_u) and (cos_v <= eps2 or act_v or pole_v))
            if np.isfinite(d2_prev) and not conv:
                if d2 > d2_prev * (1.0 + 1e-13) + 2.0 * np.sqrt(d2_prev) * e + e * e:
                    if (hit_u and u_prev != uu) or (hit_v and v_prev != vv):
                        # the step was cut at an edge and went up: halving along the cut
                        # direction need not descend (it stalled off the edge, FAILED); go to
                        # the previous point projected onto that edge instead and go on from
                        # there (the edge test then decides: 1D Newton along it, or back in)
                        uu = uu if hit_u else u_prev
                        vv = vv if hit_v else v_prev
                        hit_u = False
                        hit_v = False
                        d2_prev = np.inf
                        continue
                    # distance went up: back to the previous point with half the step
                    du_prev *= 0.5
                    dv_prev *= 0.5
                    un = wrap_clamp(u_prev + du_prev, u0, u1, cu)
                    vn = wrap_clamp(v_prev + dv_prev, v0, v1, cv)
                    a_ = un - uu
                    b_ = vn - vv
                    sx = a_ * sux + b_ * svx
                    sy = a_ * suy + b_ * svy
                    sz = a_ * suz + b_ * svz
                    step = np.sqrt(sx * sx + sy * sy + sz * sz)
                    uu, vv = un, vn
                    if step <= eps1:  # halving at noise level: the previous point is the answer
                        uu, vv = u_prev, v_prev
                        break
                    continue
            guv = sux * svx + suy * svy + suz * svz
            a = guu + rx * der[2, 0, 0] + ry * der[2, 0, 1] + rz * der[2, 0, 2]
            b = guv + rx * der[1, 1, 0] + ry * der[1, 1, 1] + rz * der[1, 1, 2]
            c = gvv + rx * der[0, 2, 0] + ry * der[0, 2, 1] + rz * der[0, 2, 2]
            det = a * c - b * b
            pd = (a > 0) and (c > 0) and (det > 1e-12 * abs(a * c))
            lam = 1e-12 * (guu + gvv) + tiny
            a1 = a if a > 0 else guu + lam
            c1 = c if c > 0 else gvv + lam
            if not pd:
                a = guu + lam
                c = gvv + lam
                b = guv
            det = a * c - b * b
            if act_u and act_v:
                du = 0.0
                dv = 0.0
            elif act_v:
                du = -f / a1
                dv = 0.0
            elif act_u:
                du = 0.0
                dv = -g / c1
            else:
                du = (-c * f + b * g) / det
                dv = (b * f - a * g) / det
            if not (np.isfinite(du) and np.isfinite(dv)):
                du = 0.0
                dv = 0.0
            un = wrap_clamp(uu + du, u0, u1, cu)
            vn = wrap_clamp(vv + dv, v0, v1, cv)
            hit_u = (not cu) and un != uu + du
            hit_v = (not cv) and vn != vv + dv
            ddu = un - uu
            ddv = vn - vv
            if cu:
                ddu = ddu - pu * np.rint(ddu / pu)
            if cv:
                ddv = ddv - pv * np.rint(ddv / pv)
            sx = ddu * sux + ddv * svx
            sy = ddu * suy + ddv * svy
            sz = ddu * suz + ddv * svz
            step = np.sqrt(sx * sx + sy * sy + sz * sz)
            u_prev, v_prev, d2_prev = uu, vv, d2
            du_prev, dv_prev = ddu, ddv
            uu, vv = un, vn
            if conv or step <= eps1:
                break
        u[t] = uu
        v[t] = vv
        iters[t] += it


CHECK_K = 16  # nearest samples examined by the global check
CHECK_SEEDS = 4  # extra Newton starts per point at most
EDGE_SEEDS = 6  # extra starts from nearby samples for feet clamped to an edge
FAILED_SEEDS = 3  # extra starts from the next nearest samples for a point whose Newton FAILED


@numba.njit(cache=True, error_model="numpy")
def global_seeds(d, dk, ik, spacing, spts, pts, fu, fv, us, vs, closed_u, closed_v, max_seeds
                 ):  # pragma: no cover - compiled
    """Extra Newton starts of the global check of `project_to_surface`, point by point: among
    the k nearest samples (dk, ik (N, k)) within sqrt(d^2 + (2h)^2) of the point (d the distance found, h the grid
    spacing at the nearest sample): discrete local minima of the distance over their 4 grid
    neighbours (wrapping in closed directions), the farthest sample of a flat valley, at most
    ``max_seeds`` of those, plus the nearest sample more than 2 grid cells from the foot
    (fu, fv). Returns (point rows (S,), sample indices (S,)), rows ascending."""
    n, k = dk.shape
    mu, mv = us.shape[0], vs.shape[0]
    rows = np.empty(n * k, dtype=np.int64)
    cols = np.empty(n * k, dtype=np.int64)
    m = 0
    is_min = np.zeros(k, dtype=np.bool_)
    cand = np.zeros(k, dtype=np.bool_)
    for i in range(n):
        h0 = spacing[ik[i, 0]]
        rad = np.sqrt(d[i] * d[i] + (2.0 * h0) ** 2)
        any_c = False
        for c in range(k):
            cand[c] = dk[i, c] <= rad
            any_c = any_c or cand[c]
        if not any_c:
            continue
        px, py, pz = pts[i, 0], pts[i, 1], pts[i, 2]
        for c in range(k):
            ok = cand[c]
            if ok:
                s = ik[i, c]
                ii = s // mv
                jj = s - ii * mv
                for t in range(4):
                    ni = ii + (1 if t == 0 else (-1 if t == 1 else 0))
                    nj = jj + (1 if t == 2 else (-1 if t == 3 else 0))
                    if closed_u:
                        ni = ni % (mu - 1)
                    if closed_v:
                        nj = nj % (mv - 1)
                    if 0 <= ni < mu and 0 <= nj < mv:
                        q = ni * mv + nj
                        ex, ey, ez = spts[q, 0] - px, spts[q, 1] - py, spts[q, 2] - pz
                        if not (dk[i, c] <= np.sqrt(ex * ex + ey * ey + ez * ez)):
                            ok = False
                            break
            is_min[c] = ok
        is_min[0] = False
        # flat valley: the ball sample farthest (> 2 cells) from the first start whose
        # distance grows slower than one cell of tangential offset
        s0 = ik[i, 0]
        best = -1.0
        far = -1
        for c in range(k):
            if cand[c] and dk[i, c] * dk[i, c] <= dk[i, 0] * dk[i, 0] + h0 * h0:
                s = ik[i, c]
                ex, ey, ez = spts[s, 0] - spts[s0, 0], spts[s, 1] - spts[s0, 1], spts[s, 2] - spts[s0, 2]
                sep = np.sqrt(ex * ex + ey * ey + ez * ez)
                if sep > 2.0 * h0 and sep > best:
                    best = sep
                    far = c
        if far >= 0:
            is_min[far] = True
        # the nearest ball sample more than 2 grid cells away from the foot found
        first_away = -1
        if np.isfinite(d[i]):
            fi = min(max(np.searchsorted(us, fu[i]), 0), mu - 1)
            fj = min(max(np.searchsorted(vs, fv[i]), 0), mv - 1)
            for c in range(1, k):
                if not cand[c]:
                    continue
                s = ik[i, c]
                ii = s // mv
                jj = s - ii * mv
                away = abs(ii - fi) > 2 or abs(jj - fj) > 2
                if closed_u and abs(ii - fi) >= mu - 3:
                    away = False
                if closed_v and abs(jj - fj) >= mv - 3:
                    away = False
                if away:
                    first_away = c
                    break
        cnt = 0
        for c in range(k):
            if is_min[c]:
                cnt += 1
                if cnt > max_seeds:
                    is_min[c] = False
        if first_away >= 0:
            is_min[first_away] = True
        for c in range(k):
            if is_min[c]:
                rows[m] = i
                cols[m] = ik[i, c]
                m += 1
    return rows[:m], cols[:m]
