"""Geometry-kernel benchmark (a script, not a test): NURBS evaluation and IGES reading against
OpenCASCADE (OCP) and pure-Python peers, measured in the same run and reported as ratios.

    python benchmarks/bench_kernel.py [--n 200000] [--n-peer 20000] [--repeat 3]

0. Unseen rational surfaces of degree 1, 2, 3 and 5 (fresh random nets, weights and knot
   vectors for every repeat, construction timed): S + Su + Sv at random (u, v), cadbridge
   single-threaded and with all numba threads against a Python loop over OCP
   ``Geom_BSplineSurface.D1`` on the same points (`bench_unseen`).
1. Surface points + first derivatives (u, v random, the same for every library):
   cadbridge ``NurbsSurface.derivatives(u, v, order=1)`` on arrays, a Python loop over OCP
   ``Geom_BSplineSurface.D1`` (surface built from our poles/weights/knots) and geomdl
   (``NURBS.Surface.derivatives`` per point, its documented derivative path; positions also
   cross-checked with ``evaluate_list``). Points/s, ratios and the max position/derivative
   difference between the libraries (sanity).
   Surfaces: the bicubic rational patch of the U-shape die samples (largest rational bicubic in
   ``iges_samples/``) and the highest-degree face of ``../shared/iges_real/occt_bearing_*``
   (if present).
2. Read time, best of ``--repeat``: ``cadbridge.read_iges`` vs OCP ``IGESControl_Reader``
   ``ReadFile`` + ``TransferRoots`` + ``OneShape``, and ``pyiges.read`` for reference, on the
   biggest ``iges_samples/*.igs`` and the bearing file.

The table is printed at the end and written to ``benchmarks/results/kernel.md``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from pathlib import Path

import numpy as np

import cadbridge
from cadbridge import NurbsSurface, read_iges

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "iges_samples"
REAL = ROOT.parent / "shared" / "iges_real"
if not REAL.is_dir():
    REAL = Path("/work/shared/iges_real")
BEARING = REAL / "occt_bearing_EuclidQuantum.iges"


# ---------------------------------------------------------------------------- helpers
@contextlib.contextmanager
def quiet_fd():
    """Silence C-level stdout/stderr (OCCT's reader prints its own messages)."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with open(os.devnull, "w") as null:
        os.dup2(null.fileno(), 1)
        os.dup2(null.fileno(), 2)
        try:
            yield
        finally:
            sys.stdout.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])


def best_of(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def fmt_rate(x: float) -> str:
    return f"{x:,.0f} pt/s"


def fmt_time(t: float) -> str:
    return f"{t * 1e3:,.1f} ms"


# ---------------------------------------------------------------------------- peers
def to_occ(s: NurbsSurface):
    """OCC Geom_BSplineSurface of the same data (the peer evaluator)."""
    from cadbridge.verify.reference import occ_bspline_surface

    return occ_bspline_surface(s)


def occ_d1(gs, u, v) -> np.ndarray:
    """Python loop over Geom_BSplineSurface.D1: (N, 3, 3) rows S, Su, Sv."""
    from OCP.gp import gp_Pnt, gp_Vec

    P, DU, DV = gp_Pnt(), gp_Vec(), gp_Vec()
    out = np.empty((len(u), 3, 3))
    d1 = gs.D1
    for k, (a, b) in enumerate(zip(u.tolist(), v.tolist())):
        d1(a, b, P, DU, DV)
        out[k] = ((P.X(), P.Y(), P.Z()), (DU.X(), DU.Y(), DU.Z()), (DV.X(), DV.Y(), DV.Z()))
    return out


def to_geomdl(s: NurbsSurface):
    from geomdl import NURBS

    g = NURBS.Surface()
    g.degree_u, g.degree_v = s.degree_u, s.degree_v
    nu, nv = s.shape
    g.ctrlpts_size_u, g.ctrlpts_size_v = nu, nv
    # geomdl's ctrlptsw: weighted points (x*w, y*w, z*w, w), v varying fastest
    pw = np.concatenate([s.control_points * s.weights[..., None], s.weights[..., None]], axis=2)
    g.ctrlptsw = pw.reshape(-1, 4).tolist()
    # geomdl only accepts parameters in [0, 1]: knots are mapped affinely onto [0, 1]
    # (geomdl_params / geomdl_d1 map the parameters and rescale the derivatives back)
    ku, kv = s.knots_u, s.knots_v
    g.knotvector_u = ((ku - ku[0]) / (ku[-1] - ku[0])).tolist()
    g.knotvector_v = ((kv - kv[0]) / (kv[-1] - kv[0])).tolist()
    g._cb_map = (ku[0], ku[-1] - ku[0], kv[0], kv[-1] - kv[0])
    return g


def geomdl_params(g, u, v):
    a, la, b, lb = g._cb_map
    return np.clip((u - a) / la, 0.0, 1.0).tolist(), np.clip((v - b) / lb, 0.0, 1.0).tolist()


def geomdl_d1(g, u, v) -> np.ndarray:
    _, la, _, lb = g._cb_map
    uu, vv = geomdl_params(g, u, v)
    out = np.empty((len(uu), 3, 3))
    ders = g.derivatives
    for k, (a, b) in enumerate(zip(uu, vv)):
        d = ders(a, b, order=1)
        out[k] = (d[0][0], d[1][0], d[0][1])
    out[:, 1] /= la
    out[:, 2] /= lb
    return out


# ---------------------------------------------------------------------------- surfaces
def sample_surfaces() -> list[tuple[str, NurbsSurface]]:
    out = []
    best = None
    for f in sorted(SAMPLES.glob("*.igs")):
        for face in read_iges(f).faces:
            s = face.surface
            if s.rational and s.degree_u == 3 and s.degree_v == 3:
                if best is None or s.shape[0] * s.shape[1] > best[1].shape[0] * best[1].shape[1]:
                    best = (f.name, s)
    if best is None:  # no rational bicubic in the samples: the biggest rational face instead
        for f in sorted(SAMPLES.glob("*.igs")):
            for face in read_iges(f).faces:
                s = face.surface
                if s.rational and (best is None or s.degree_u * s.degree_v > best[1].degree_u * best[1].degree_v):
                    best = (f.name, s)
    if best is not None:
        out.append((f"{best[0]}", best[1]))
    if BEARING.is_file():
        faces = read_iges(BEARING).faces
        s = max((f.surface for f in faces), key=lambda s: (s.degree_u * s.degree_v, s.shape[0] * s.shape[1]))
        out.append((BEARING.name, s))
    return out


def bench_surface(name: str, s: NurbsSurface, n: int, n_peer: int, repeat: int, rng) -> list[dict]:
    u0, u1, v0, v1 = s.domain
    u = rng.uniform(u0, u1, n)
    v = rng.uniform(v0, v1, n)
    s.derivatives(u[:10], v[:10], order=1)  # warm-up (loads the compiled kernel)
    t_ours = best_of(lambda: s.derivatives(u, v, order=1), repeat)
    ours = s.derivatives(u, v, order=1)
    ours3 = np.stack([ours[:, 0, 0], ours[:, 1, 0], ours[:, 0, 1]], axis=1)

    try:
        import numba

        nthreads = numba.get_num_threads()
        numba.set_num_threads(1)
        t_ours1 = best_of(lambda: s.derivatives(u, v, order=1), repeat)
        numba.set_num_threads(nthreads)
    except ImportError:  # pragma: no cover
        nthreads, t_ours1 = 1, t_ours

    up, vp = u[:n_peer], v[:n_peer]
    gs = to_occ(s)
    t_occ = best_of(lambda: occ_d1(gs, up, vp), repeat)
    occ = occ_d1(gs, up, vp)

    ng = max(n_peer // 10, 200)  # geomdl is slow: a smaller subset, scaled to points/s
    g = to_geomdl(s)
    t_gdl = best_of(lambda: geomdl_d1(g, u[:ng], v[:ng]), 1)
    gdl = geomdl_d1(g, u[:ng], v[:ng])
    gdl_pts = np.array(g.evaluate_list(list(zip(*geomdl_params(g, u[:ng], v[:ng])))))

    size = float(np.ptp(s.control_points.reshape(-1, 3), axis=0).max())
    d_occ = np.abs(ours3[:n_peer, 0] - occ[:, 0]).max()
    d_gdl = np.abs(ours3[:ng, 0] - gdl[:, 0]).max()
    d_gdl_list = np.abs(ours3[:ng, 0] - gdl_pts).max()
    d_occ_gdl = np.abs(occ[:ng, 0] - gdl[:, 0]).max()
    dd_occ = np.abs(ours3[:n_peer, 1:] - occ[:, 1:]).max() / max(np.abs(occ[:, 1:]).max(), 1e-300)
    dd_gdl = np.abs(ours3[:ng, 1:] - gdl[:, 1:]).max() / max(np.abs(gdl[:, 1:]).max(), 1e-300)

    r_ours, r_ours1 = n / t_ours, n / t_ours1
    r_occ, r_gdl = n_peer / t_occ, ng / t_gdl
    kind = "rational" if s.rational else "polynomial"
    label = f"S+D1, deg ({s.degree_u},{s.degree_v}) {kind} {s.shape[0]}x{s.shape[1]} [{name}]"
    print(f"\n{label}")
    print(f"  cadbridge derivatives(order=1), N={n:,} : {fmt_rate(r_ours)} ({nthreads} numba threads), "
          f"{fmt_rate(r_ours1)} (1 thread)")
    print(f"  OCP Geom_BSplineSurface.D1 loop, N={n_peer:,}: {fmt_rate(r_occ)}")
    print(f"  geomdl derivatives(order=1) loop, N={ng:,}   : {fmt_rate(r_gdl)}")
    print(f"  ratio cadbridge/OCP = {r_ours / r_occ:,.1f} (1 thread: {r_ours1 / r_occ:,.1f}),"
          f" cadbridge/geomdl = {r_ours / r_gdl:,.0f}")
    print(f"  max |S| difference (model size {size:.3g}): ours-OCP {d_occ:.2e}, ours-geomdl {d_gdl:.2e} "
          f"(evaluate_list {d_gdl_list:.2e}), OCP-geomdl {d_occ_gdl:.2e}")
    print(f"  max relative D1 difference: ours-OCP {dd_occ:.2e}, ours-geomdl {dd_gdl:.2e}")
    rows = [
        dict(what=f"{label}, points/s ({nthreads} thr)", ours=fmt_rate(r_ours), occ=fmt_rate(r_occ),
             peer=f"geomdl {fmt_rate(r_gdl)}", ratio=f"{r_ours / r_occ:,.1f}x OCP, {r_ours / r_gdl:,.0f}x geomdl"),
        dict(what=f"{label}, points/s (1 thr)", ours=fmt_rate(r_ours1), occ=fmt_rate(r_occ),
             peer=f"geomdl {fmt_rate(r_gdl)}", ratio=f"{r_ours1 / r_occ:,.1f}x OCP, {r_ours1 / r_gdl:,.0f}x geomdl"),
        dict(what=f"{label}, max position diff", ours="-", occ=f"{d_occ:.1e}", peer=f"geomdl {d_gdl:.1e}",
             ratio="(vs cadbridge)"),
    ]
    return rows


# ---------------------------------------------------------------------------- unseen surfaces
def unseen_surface(rng, p: int, n_ctrl: int = 10) -> NurbsSurface:
    """A fresh rational surface of degree (p, p): n_ctrl x n_ctrl random control points in
    [-1, 1]^3, weights in [0.5, 2], clamped knot vectors on [0, 1] with n_ctrl - p - 1 random
    interior knots (several spans in each direction)."""
    def knots():
        return np.concatenate([[0.0] * (p + 1), np.sort(rng.uniform(0.02, 0.98, n_ctrl - p - 1)), [1.0] * (p + 1)])

    return NurbsSurface(p, p, knots(), knots(), rng.uniform(-1, 1, (n_ctrl, n_ctrl, 3)),
                        rng.uniform(0.5, 2.0, (n_ctrl, n_ctrl)))


def bench_unseen(degrees, n: int, n_peer: int, n_small: int, repeat: int, rng) -> list[dict]:
    """S + Su + Sv on surfaces never seen before, random (u, v) (not sorted, not a grid).

    Each repeat draws a new surface and new points; ours is timed from the raw arrays
    (``NurbsSurface(...)`` construction included) to the (N, 2, 2, 3) result, single thread
    (numba.set_num_threads(1)) and, separately, with all numba threads; OCC is the Python
    loop over ``Geom_BSplineSurface.D1`` on the first ``n_peer`` of the same points (surface
    conversion not timed). Rates are best of ``repeat``; the ratio compares rates measured in
    this run. ``n_small`` points per fresh surface shows the per-surface setup cost."""
    import numba

    nthreads = numba.get_num_threads()
    rows = []
    for p in degrees:
        best = dict(one=np.inf, par=np.inf, small=np.inf, occ=np.inf)
        dpos = dder = 0.0
        unseen_surface(rng, p).derivatives(np.r_[0.5], np.r_[0.5], order=1)  # load the compiled kernel
        for _ in range(repeat):
            s = unseen_surface(rng, p)
            args = (p, p, s.knots_u.copy(), s.knots_v.copy(), s.control_points.copy(), s.weights.copy())
            u = rng.uniform(0.0, 1.0, n)
            v = rng.uniform(0.0, 1.0, n)

            def ours(m=n):
                return NurbsSurface(*args).derivatives(u[:m], v[:m], order=1)

            numba.set_num_threads(1)
            try:
                best["one"] = min(best["one"], best_of(ours, 1) / n)
                best["small"] = min(best["small"], best_of(lambda: ours(n_small), 3) / n_small)
            finally:
                numba.set_num_threads(nthreads)
            best["par"] = min(best["par"], best_of(ours, 1) / n)
            gs = to_occ(s)
            up, vp = u[:n_peer], v[:n_peer]
            best["occ"] = min(best["occ"], best_of(lambda: occ_d1(gs, up, vp), 1) / n_peer)
            d = ours(n_peer)
            ref = occ_d1(gs, up, vp)
            dpos = max(dpos, np.abs(d[:, 0, 0] - ref[:, 0]).max())
            got = np.stack([d[:, 1, 0], d[:, 0, 1]], axis=1)
            dder = max(dder, np.abs(got - ref[:, 1:]).max() / np.abs(ref[:, 1:]).max())
        r = {k: 1.0 / t for k, t in best.items()}
        label = f"unseen rational deg ({p},{p}) 10x10, random (u,v)"
        print(f"\n{label}")
        print(f"  cadbridge NurbsSurface(...) + derivatives(order=1), N={n:,}: {fmt_rate(r['one'])} (1 thread), "
              f"{fmt_rate(r['par'])} ({nthreads} threads); N={n_small:,} per fresh surface: {fmt_rate(r['small'])}")
        print(f"  OCP Geom_BSplineSurface.D1 loop, N={n_peer:,}: {fmt_rate(r['occ'])}")
        print(f"  ratio cadbridge/OCP: {r['one'] / r['occ']:.1f} (1 thread), {r['par'] / r['occ']:.1f} "
              f"({nthreads} threads), {r['small'] / r['occ']:.1f} (N={n_small:,}, 1 thread)")
        print(f"  max |S| difference ours-OCP {dpos:.1e}, max relative D1 difference {dder:.1e}")
        rows.append(dict(what=f"{label}, S+Su+Sv points/s, 1 thread", ours=fmt_rate(r["one"]), occ=fmt_rate(r["occ"]),
                         peer="-", ratio=f"**{r['one'] / r['occ']:.1f}x OCP**"))
        rows.append(dict(what=f"{label}, {nthreads} numba threads", ours=fmt_rate(r["par"]), occ=fmt_rate(r["occ"]),
                         peer="-", ratio=f"{r['par'] / r['occ']:.1f}x OCP"))
        rows.append(dict(what=f"{label}, {n_small:,} points per fresh surface, 1 thread", ours=fmt_rate(r["small"]),
                         occ=fmt_rate(r["occ"]), peer="-", ratio=f"{r['small'] / r['occ']:.1f}x OCP"))
    return rows


# ---------------------------------------------------------------------------- reading
def occ_read(path: Path):
    from OCP.IGESControl import IGESControl_Reader

    with quiet_fd():
        r = IGESControl_Reader()
        r.ReadFile(str(path))
        r.TransferRoots()
        return r.OneShape()


def bench_read(path: Path, repeat: int) -> list[dict]:
    read_iges(path)  # warm caches / imports
    t_ours = best_of(lambda: read_iges(path), repeat)
    nfaces = len(read_iges(path).faces)
    occ_read(path)
    t_occ = best_of(lambda: occ_read(path), repeat)
    try:
        import pyiges

        with quiet_fd():
            t_py = best_of(lambda: pyiges.read(str(path)), repeat)
        py = fmt_time(t_py)
    except Exception as e:  # noqa: BLE001 - a reference only
        py = f"failed ({type(e).__name__})"
    size = path.stat().st_size
    print(f"\nread {path.name} ({size / 1e3:,.0f} kB, {nfaces} faces)")
    print(f"  cadbridge.read_iges          : {fmt_time(t_ours)}")
    print(f"  OCP ReadFile+TransferRoots   : {fmt_time(t_occ)}")
    print(f"  pyiges.read (reference)      : {py}")
    print(f"  ratio OCP time / cadbridge time = {t_occ / t_ours:.2f} (>= 1: we are no slower)")
    return [dict(what=f"read {path.name} ({size / 1e3:,.0f} kB), best of {repeat}", ours=fmt_time(t_ours),
                 occ=fmt_time(t_occ), peer=f"pyiges {py}", ratio=f"{t_occ / t_ours:.2f}x (OCP time / ours)")]


# ---------------------------------------------------------------------------- main
def table(rows: list[dict]) -> str:
    head = ["measurement", "cadbridge", "OCP", "geomdl / pyiges", "ratio"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    for r in rows:
        lines.append(f"| {r['what']} | {r['ours']} | {r['occ']} | {r['peer']} | {r['ratio']} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200_000, help="points for cadbridge")
    ap.add_argument("--n-peer", type=int, default=20_000, help="points for OCP (geomdl gets a tenth)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--n-small", type=int, default=1000, help="points per fresh surface (setup-cost row)")
    ap.add_argument("--degrees", type=int, nargs="+", default=[1, 2, 3, 5], help="degrees of the unseen surfaces")
    ap.add_argument("--skip-unseen", action="store_true")
    ap.add_argument("--skip-eval", action="store_true")
    ap.add_argument("--skip-read", action="store_true")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "kernel.md",
                    help="markdown table written here")
    args = ap.parse_args()
    rng = np.random.default_rng(12345)
    env = (f"cadbridge {cadbridge.__version__} ({Path(cadbridge.__file__).parent}), numpy {np.__version__}, "
           f"python {sys.version.split()[0]}, load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    print(env)
    rows: list[dict] = []
    if not args.skip_unseen:
        rows += bench_unseen(args.degrees, args.n, min(args.n_peer, args.n), args.n_small, args.repeat, rng)
    if not args.skip_eval:
        for name, s in sample_surfaces():
            rows += bench_surface(name, s, args.n, min(args.n_peer, args.n), args.repeat, rng)
    if not args.skip_read:
        files = sorted(SAMPLES.glob("*.igs"), key=lambda p: p.stat().st_size)[-1:]
        if BEARING.is_file():
            files.append(BEARING)
        for f in files:
            rows += bench_read(f, args.repeat)
    md = table(rows)
    print("\n" + md)
    out = args.out
    out.parent.mkdir(parents=True, exist_ok=True)
    cmd = "python benchmarks/bench_kernel.py " + " ".join(sys.argv[1:])
    out.write_text(f"# Geometry-kernel benchmark\n\n`{cmd.strip()}`\n\n{env}, load average at the end "
                   f"{os.getloadavg()[0]:.2f}\n\n{md}\n")
    print(f"\nwritten to {out}")


if __name__ == "__main__":
    main()
