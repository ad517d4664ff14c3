"""Trim classification on the real IGES files (../shared/iges_real): old polygon-band rule vs
the exact-curve rule (cadbridge.cad.trims), timing and agreement with OCC's BRepClass_FaceClassifier.

Per file: build time of the loop boundaries (polygon + chord bounds + edge grid); N (u, v)
points over the trimmed B-spline faces, half uniform in each face's loop box, half near the
exact trim curves (offset along the curve normal by 1e-7..1e-3 x loop size, both sides);
time of `Face.contains` (new) and of the old rule (even-odd on a 32-per-span polygon, every
point against every edge, plus its chord band counted inside); agreement of both with OCC,
which classifies in its own (u, v) of the face: only faces whose (u, v) is OCC's are used
(128 B-spline faces, paired by order, checked by evaluating both surfaces at a few points).

    python benchmarks/bench_trims.py [N] [file ...]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from cadbridge.iges import read_iges

REAL = Path(__file__).parents[1].parent / "shared" / "iges_real"


def old_contains(trim, u, v, tol):
    """The rule before issue #8: polygon of 32 points per span, band = 2 x sampled chord
    deviation, all-pairs crossing test and distance (numpy)."""
    def outline(loop):
        pieces, dev = [], 0.0
        for c in loop.curves:
            t = c.sample_parameters(32)
            p = c.evaluate(t)[:, :2]
            pieces.append(p[:-1])
            if c.degree > 1:
                mid = c.evaluate(0.5 * (t[:-1] + t[1:]))[:, :2]
                dev = max(dev, float(np.max(np.linalg.norm(mid - 0.5 * (p[:-1] + p[1:]), axis=1))))
        return np.concatenate(pieces), 2 * dev

    def pip(pts, a):
        b = np.roll(a, -1, axis=0)
        out = np.empty(len(pts), bool)
        for s in range(0, len(pts), 4096):
            p = pts[s:s + 4096, None]
            st = (a[None, :, 1] > p[..., 1]) != (b[None, :, 1] > p[..., 1])
            with np.errstate(divide="ignore", invalid="ignore"):
                xc = a[None, :, 0] + (p[..., 1] - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / (b[None, :, 1] - a[None, :, 1])
            out[s:s + 4096] = np.count_nonzero(st & (p[..., 0] < xc), axis=1) % 2 == 1
        return out

    def dist(pts, a):
        b = np.roll(a, -1, axis=0)
        ab = b - a
        ll = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-300)
        out = np.empty(len(pts))
        for s in range(0, len(pts), 2048):
            p = pts[s:s + 2048, None]
            t = np.clip(np.einsum("nmj,mj->nm", p - a[None], ab) / ll, 0, 1)
            d = p - (a[None] + t[..., None] * ab[None])
            out[s:s + 2048] = np.sqrt(np.min(np.einsum("nmj,nmj->nm", d, d), axis=1))
        return out

    uv = np.column_stack([u, v])
    loops = ([(trim.outer, True)] if trim.outer is not None else []) + [(h, False) for h in trim.inner]
    outl = [(outline(lp), o) for lp, o in loops]
    inside = np.ones(len(uv), bool)
    for (poly, _), o in outl:
        il = pip(uv, poly)
        inside &= il if o else ~il
    out = np.flatnonzero(~inside)
    for (poly, band), _ in outl:
        if not len(out):
            break
        near = dist(uv[out], poly) <= band + tol
        inside[out[near]] = True
        out = out[~near]
    return inside


def face_points(face, n, rng):
    """(u, v) (n, 2) and offset (n,) (NaN for the uniform half) for one trimmed face."""
    loops = ([face.trims.outer] if face.trims.outer is not None else []) + list(face.trims.inner)
    polys = [lp.boundary for lp in loops]
    allp = np.concatenate([p.a for p in polys])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    u0, u1, v0, v1 = face.surface.domain
    if face.trims.outer is None:
        lo, hi = np.array([u0, v0]), np.array([u1, v1])
    nu = n // 2
    uni = rng.uniform(lo, hi, (nu, 2))
    size = float(np.linalg.norm(hi - lo))
    curves = [c for lp in loops for c in lp.curves]
    ci = rng.integers(len(curves), size=n - nu)
    pts = np.empty((n - nu, 2))
    for k in np.unique(ci):
        sel = np.flatnonzero(ci == k)
        c = curves[k]
        t = rng.uniform(*c.domain, len(sel))
        d = c.derivatives(t, 1)[:, :, :2]
        tan = d[:, 1] / np.maximum(np.linalg.norm(d[:, 1], axis=1), 1e-300)[:, None]
        off = 10.0 ** rng.uniform(-7, -3, len(sel)) * size * rng.choice([-1.0, 1.0], len(sel))
        pts[sel] = d[:, 0] + off[:, None] * np.column_stack([-tan[:, 1], tan[:, 0]])
    offs = np.concatenate([np.full(nu, np.nan), np.zeros(n - nu)])
    uv = np.clip(np.vstack([uni, pts]), [u0, v0], [u1, v1])
    return uv, offs


def occ_on(face, uv):
    """(N,) bool: OCC's classifier says ON (within the edge tolerances of the face)."""
    from OCP.BRepClass import BRepClass_FaceClassifier
    from OCP.gp import gp_Pnt2d
    from OCP.TopAbs import TopAbs_ON

    return np.array([BRepClass_FaceClassifier(face, gp_Pnt2d(float(a), float(b)), 1e-9).State() == TopAbs_ON for a, b in uv])


def main(n_total: int, files: list[Path]) -> None:
    from cadbridge.verify.reference import occ_eval, occ_inside, occ_read

    rng = np.random.default_rng(8)
    print(f"{'file':42s} {'faces':>5s} {'build s':>8s} {'pts':>7s} {'new s':>7s} {'old s':>7s} {'new=OCC':>8s} {'old=OCC':>8s} {'near!ON new':>12s} {'near!ON old':>12s} {'new!=old':>8s}")
    for path in files:
        m = read_iges(path)
        occ = occ_read(path)
        faces = []
        for k, f in enumerate(m.faces):
            if f.trims is None or f.surface_type != 128 or k >= len(occ):
                continue
            u0, u1, v0, v1 = f.surface.domain
            uu, vv = rng.uniform(u0, u1, 4), rng.uniform(v0, v1, 4)
            theirs = occ_eval(occ[k].surface, uu, vv, 0)[0]
            if np.max(np.abs(theirs - f.surface.evaluate(uu, vv))) > 1e-9 * m.size():
                continue
            faces.append((k, f))
        if not faces:
            print(f"{path.name:42s} no B-spline faces with OCC's (u, v)")
            continue
        t = time.perf_counter()
        for _, f in faces:
            for lp in ([f.trims.outer] if f.trims.outer is not None else []) + list(f.trims.inner):
                lp.boundary.grid(1e-9 * max(f.surface.domain[1] - f.surface.domain[0], f.surface.domain[3] - f.surface.domain[2]))
        build = time.perf_counter() - t
        per = max(2, n_total // len(faces))
        data = [face_points(f, per, rng) for _, f in faces]
        f0 = faces[0][1]
        f0.contains(*data[0][0][:10].T)  # compile outside the timing
        t = time.perf_counter()
        new = [f.contains(uv[:, 0], uv[:, 1]) for (_, f), (uv, _) in zip(faces, data)]
        t_new = time.perf_counter() - t
        t = time.perf_counter()
        old = []
        for (_, f), (uv, _) in zip(faces, data):
            u0, u1, v0, v1 = f.surface.domain
            old.append(old_contains(f.trims, uv[:, 0], uv[:, 1], 1e-9 * max(u1 - u0, v1 - v0)))
        t_old = time.perf_counter() - t
        ref = [occ_inside(occ[k], uv[:, 0], uv[:, 1], 1e-9) for (k, _), (uv, _) in zip(faces, data)]
        new, old, ref = np.concatenate(new), np.concatenate(old), np.concatenate(ref)
        # near: the points near the curves where OCC's state is not ON (within its edge tolerance)
        on = np.concatenate([occ_on(occ[k].face, uv) for (k, _), (uv, _) in zip(faces, data)])
        near = ~np.isnan(np.concatenate([o for _, o in data])) & ~on
        print(f"{path.name:42s} {len(faces):5d} {build:8.3f} {len(new):7d} {t_new:7.3f} {t_old:7.3f} "
              f"{np.mean(new == ref):8.5f} {np.mean(old == ref):8.5f} {np.mean(new[near] == ref[near]):12.5f} "
              f"{np.mean(old[near] == ref[near]):12.5f} {int(np.sum(new != old)):8d}")


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 100_000
    files = [Path(a) for a in sys.argv[2:]] or sorted(REAL.glob("*.ig*"))
    main(n, files)
