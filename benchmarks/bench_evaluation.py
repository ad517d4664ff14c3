"""Evaluation benchmark (a script, not a test): point + first derivatives on unseen random
rational surfaces, cadbridge against the strongest use of OpenCASCADE (OCP) from Python and
geomdl, every ratio measured in the same run.

    python benchmarks/bench_evaluation.py [--n 200000] [--n-occ 20000] [--repeat 5]

Cases: rational surfaces of degree (p, p), p = 1, 2, 3, 5, with a 10 x 10 net and random
interior knots; 2 x 2 Bezier biquadratics (5 x 5 net, knots 0 0 0 .5 .5 1 1 1 both ways: the
double-knot Bezier layout of Herrero Adan & Cardoso 2020, appendix D); and, as a fixed
reference, that paper's Ex. 7.1 surface (biquadratic, 4 x 2 spans, tests/helpers/qit_examples).
Each repeat draws a new net, new weights in [0.5, 2], new knots and new (u, v) (random, not
sorted, not a grid): nothing is cached by identity. Rates are points/s, best of ``--repeat``.

cadbridge: ``NurbsSurface(...)`` built from the raw arrays + ``derivatives(u, v, order=1)``
((N, 2, 2, 3): S, Su, Sv, Suv), timed together, numba set to 1 thread and, separately, 2.

OCC (surface conversion not timed; OCP 7.9 has no batched surface evaluator: no
``GeomGridEval``, ``BSplSLib`` / ``GeomAdaptor`` / ``BSplSLib_Cache`` evaluate one point a
call), Python loops over the same points:

* ``Geom_BSplineSurface.D1`` and ``GeomAdaptor_Surface.D1`` (span cache, BSplSLib_Cache), the
  call alone, results discarded: a lower bound on the cost of any use of OCC from Python.
  The faster of the two is the reference of the ratios.
* ``Geom_BSplineSurface.D1`` + ``Coord()`` of the point and both vectors into an array: the
  cheapest loop that keeps the results.
* 2 workers: OCP's D1 holds the GIL (2 Python threads measured, no faster), so the 2-core
  reference is twice the single-thread rate (ideal scaling of 2 processes, an upper bound).

geomdl (if installed): ``NURBS.Surface.derivatives(u, v, order=1)`` per point (its documented
derivative path) on ``--n-geomdl`` points.

Allocator state: glibc's malloc adapts its mmap / trim thresholds to the arrays freed so far,
which changes a Python loop's per-call cost (issue 35). Unless both variables are already set,
the script re-executes itself with MALLOC_MMAP_THRESHOLD_=33554432 (32 MiB, glibc's maximum)
and MALLOC_TRIM_THRESHOLD_=268435456 (256 MiB): fixed thresholds, the same state for both
sides for the whole run (``--malloc-default`` keeps glibc's adaptive defaults instead).

Wall (perf_counter) and CPU (process_time, all threads of the process) rates are reported;
the results go to ``benchmarks/results/evaluation.md``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MALLOC = {"MALLOC_MMAP_THRESHOLD_": "33554432", "MALLOC_TRIM_THRESHOLD_": "268435456"}

if __name__ == "__main__" and "--malloc-default" not in sys.argv and any(k not in os.environ for k in MALLOC):
    os.environ.update(MALLOC)  # glibc reads these once, at start-up: run the script again
    os.execv(sys.executable, [sys.executable, *sys.argv])

import numba  # noqa: E402
import numpy as np  # noqa: E402

import cadbridge  # noqa: E402
from cadbridge import NurbsSurface  # noqa: E402

BEZIER2 = np.array([0.0, 0.0, 0.0, 0.5, 0.5, 1.0, 1.0, 1.0])


# ---------------------------------------------------------------------------- surfaces
def random_surface_args(rng, case: str) -> tuple:
    """Fresh (p, q, knots_u, knots_v, control_points, weights) for ``case``."""
    if case == "bezier22":
        p, n = 2, 5
        ku = kv = BEZIER2.copy()
    else:
        p, n = int(case[3:]), 10

        def knots():
            inner = np.sort(rng.uniform(0.02, 0.98, n - p - 1))
            return np.concatenate([[0.0] * (p + 1), inner, [1.0] * (p + 1)])

        ku, kv = knots(), knots()
    return p, p, ku, kv, rng.uniform(-1.0, 1.0, (n, n, 3)), rng.uniform(0.5, 2.0, (n, n))


def herrero_adan_71_args() -> tuple:
    """Herrero Adan & Cardoso (2020) Ex. 7.1 (appendix D, Tables D.2-D.3) as raw arrays."""
    sys.path.insert(0, str(ROOT))
    from tests.helpers.qit_examples import example_71

    s = example_71()
    return (s.degree_u, s.degree_v, s.knots_u.copy(), s.knots_v.copy(), s.control_points.copy(), s.weights.copy())


LABELS = {
    "deg1": "rational deg (1,1), 10x10 net, 9x9 spans",
    "deg2": "rational deg (2,2), 10x10 net, 8x8 spans",
    "deg3": "rational deg (3,3), 10x10 net, 7x7 spans",
    "deg5": "rational deg (5,5), 10x10 net, 5x5 spans",
    "bezier22": "rational 2x2 Bezier biquadratic, 5x5 net",
    "ex71": "Herrero Adan Ex. 7.1 (fixed), biquadratic 6x5 net, 4x2 spans",
}


# ---------------------------------------------------------------------------- peers
def occ_surfaces(args):
    from OCP.GeomAdaptor import GeomAdaptor_Surface

    from cadbridge.verify.reference import occ_bspline_surface

    gs = occ_bspline_surface(NurbsSurface(*args))
    return gs, GeomAdaptor_Surface(gs)


def occ_calls(obj, ul: list, vl: list) -> None:
    """The D1 calls alone (results discarded): OCC's floor from Python."""
    from OCP.gp import gp_Pnt, gp_Vec

    P, DU, DV = gp_Pnt(), gp_Vec(), gp_Vec()
    d1 = obj.D1
    for a, b in zip(ul, vl):
        d1(a, b, P, DU, DV)


def occ_keep(obj, ul: list, vl: list) -> np.ndarray:
    """D1 + Coord() of S, Su, Sv: (N, 3, 3), the cheapest loop that keeps the results."""
    from OCP.gp import gp_Pnt, gp_Vec

    P, DU, DV = gp_Pnt(), gp_Vec(), gp_Vec()
    d1, pc, uc, vc = obj.D1, P.Coord, DU.Coord, DV.Coord
    out = []
    add = out.append
    for a, b in zip(ul, vl):
        d1(a, b, P, DU, DV)
        add((pc(), uc(), vc()))
    return np.array(out)


def geomdl_d1(args, u: np.ndarray, v: np.ndarray) -> np.ndarray | None:
    """geomdl derivatives(order=1) per point (knots mapped onto [0, 1], derivatives scaled
    back): (N, 3, 3) S, Su, Sv; None without geomdl."""
    try:
        from geomdl import NURBS
    except ImportError:
        return None
    p, q, ku, kv, cp, w = args
    g = NURBS.Surface()
    g.degree_u, g.degree_v = p, q
    g.ctrlpts_size_u, g.ctrlpts_size_v = cp.shape[:2]
    g.ctrlptsw = np.concatenate([cp * w[..., None], w[..., None]], axis=2).reshape(-1, 4).tolist()
    lu, lv = ku[-1] - ku[0], kv[-1] - kv[0]
    g.knotvector_u = ((ku - ku[0]) / lu).tolist()
    g.knotvector_v = ((kv - kv[0]) / lv).tolist()
    out = np.empty((len(u), 3, 3))
    for k, (a, b) in enumerate(zip(((u - ku[0]) / lu).tolist(), ((v - kv[0]) / lv).tolist())):
        d = g.derivatives(a, b, order=1)
        out[k] = (d[0][0], d[1][0], d[0][1])
    out[:, 1] /= lu
    out[:, 2] /= lv
    return out


# ---------------------------------------------------------------------------- timing
def timed(fn) -> tuple[float, float]:
    """(wall, cpu) seconds of one call."""
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def bench_case(case: str, *, n: int, n_occ: int, n_geomdl: int, n_small: int, repeat: int, rng) -> dict:
    best: dict[str, list[float]] = {}

    def keep(key: str, wall_cpu: tuple[float, float], npts: int) -> None:
        w, c = wall_cpu
        b = best.setdefault(key, [np.inf, np.inf])
        b[0] = min(b[0], w / npts)
        b[1] = min(b[1], c / npts)

    dpos = dder = dgdl = 0.0
    nthreads = numba.get_num_threads()
    warm = herrero_adan_71_args() if case == "ex71" else random_surface_args(rng, case)
    NurbsSurface(*warm).derivatives(np.r_[0.5], np.r_[0.5], order=1)  # load the compiled kernels
    NurbsSurface(*warm).derivatives(np.full(20000, 0.5), np.full(20000, 0.5), order=1)
    for _ in range(repeat):
        args = herrero_adan_71_args() if case == "ex71" else random_surface_args(rng, case)
        ku, kv = args[2], args[3]
        u = rng.uniform(ku[0], ku[-1], n)
        v = rng.uniform(kv[0], kv[-1], n)

        def ours(m=n):
            return NurbsSurface(*args).derivatives(u[:m], v[:m], order=1)

        numba.set_num_threads(1)
        try:
            keep("ours1", timed(ours), n)
            for _ in range(3):
                keep("small1", timed(lambda: ours(n_small)), n_small)
        finally:
            numba.set_num_threads(min(2, nthreads))
        keep("ours2", timed(ours), n)
        numba.set_num_threads(nthreads)

        gs, ad = occ_surfaces(args)
        ul, vl = u[:n_occ].tolist(), v[:n_occ].tolist()
        keep("occ_geom", timed(lambda: occ_calls(gs, ul, vl)), n_occ)
        keep("occ_adaptor", timed(lambda: occ_calls(ad, ul, vl)), n_occ)
        keep("occ_keep", timed(lambda: occ_keep(gs, ul, vl)), n_occ)
        half = n_occ // 2
        with ThreadPoolExecutor(2) as ex:  # does OCP release the GIL? (it does not: no faster)
            keep("occ_2threads", timed(lambda: list(ex.map(lambda s: occ_calls(ad, ul[s], vl[s]),
                                                             [slice(0, half), slice(half, None)]))), n_occ)

        d = ours(n_occ)
        ref = occ_keep(gs, ul, vl)
        size = float(np.ptp(args[4].reshape(-1, 3), axis=0).max())
        dpos = max(dpos, np.abs(d[:, 0, 0] - ref[:, 0]).max() / size)
        got = np.stack([d[:, 1, 0], d[:, 0, 1]], axis=1)
        dder = max(dder, np.abs(got - ref[:, 1:]).max() / np.abs(ref[:, 1:]).max())
        g = geomdl_d1(args, u[:n_geomdl], v[:n_geomdl]) if n_geomdl else None
        if g is not None:
            keep("geomdl", timed(lambda: geomdl_d1(args, u[:n_geomdl], v[:n_geomdl])), n_geomdl)
            dgdl = max(dgdl, np.abs(np.stack([d[:n_geomdl, 0, 0], d[:n_geomdl, 1, 0], d[:n_geomdl, 0, 1]], axis=1)
                                    - g).max() / max(np.abs(g).max(), 1e-300))
    rate = {k: (1.0 / w, 1.0 / c) for k, (w, c) in best.items()}
    return dict(case=case, rate=rate, dpos=dpos, dder=dder, dgdl=dgdl)


# ---------------------------------------------------------------------------- report
def fmt(r: float) -> str:
    return f"{r / 1e6:.3g} M" if r >= 1e6 else f"{r / 1e3:.3g} k"


def report(res: list[dict], n: int, n_occ: int, n_small: int) -> str:
    lines = [
        "Rates in points/s (S + Su + Sv (+ Suv for cadbridge)), wall / CPU; ratios = cadbridge rate / OCC reference "
        "rate (the faster of the two call-only loops; for 2 threads, wall: twice that, ideal 2-process scaling; "
        "CPU: the same, CPU time per point does not drop with processes). On a loaded machine the CPU ratios are the "
        "ones to read: the wall rates move with the load, the CPU time per point much less.",
        "",
        f"| surface | cadbridge 1 thread (N={n:,}) | cadbridge 2 threads | cadbridge 1 thread, N={n_small:,} per fresh "
        f"surface | OCC Geom D1 calls (N={n_occ:,}) | OCC GeomAdaptor D1 calls | OCC D1 + Coord() kept | OCC 2 Python "
        f"threads | geomdl | **ratio 1 thread** wall / CPU | **ratio 2 threads** wall / CPU | ratio N={n_small:,} "
        f"wall | ratio vs OCC kept, 1 thread wall | max abs. S diff / size, rel. D1 diff vs OCC (geomdl) |",
        "|" + "---|" * 15,
    ]
    for r in res:
        q = r["rate"]
        occ_w = max(q["occ_geom"][0], q["occ_adaptor"][0])
        occ_c = max(q["occ_geom"][1], q["occ_adaptor"][1])

        def wc(k):
            return f"{fmt(q[k][0])} / {fmt(q[k][1])}" if k in q else "-"

        lines.append(
            f"| {LABELS[r['case']]} | {wc('ours1')} | {wc('ours2')} | {wc('small1')} | {wc('occ_geom')} | "
            f"{wc('occ_adaptor')} | {wc('occ_keep')} | {wc('occ_2threads')} | {wc('geomdl')} | "
            f"**{q['ours1'][0] / occ_w:.1f}x / {q['ours1'][1] / occ_c:.1f}x** | "
            f"**{q['ours2'][0] / (2 * occ_w):.1f}x / {q['ours2'][1] / occ_c:.1f}x** | "
            f"{q['small1'][0] / occ_w:.1f}x | {q['ours1'][0] / q['occ_keep'][0]:.1f}x | "
            f"{r['dpos']:.1e}, {r['dder']:.1e} ({r['dgdl']:.1e}) |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=200_000, help="points per surface for cadbridge")
    ap.add_argument("--n-occ", type=int, default=20_000, help="points per surface for the OCC loops")
    ap.add_argument("--n-geomdl", type=int, default=300, help="points per surface for geomdl (0: skip)")
    ap.add_argument("--n-small", type=int, default=1000, help="points per fresh surface (per-call cost row)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--cases", nargs="+", default=["deg1", "deg2", "deg3", "deg5", "bezier22", "ex71"],
                    choices=list(LABELS))
    ap.add_argument("--malloc-default", action="store_true", help="keep glibc's adaptive malloc thresholds")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "evaluation.md")
    args = ap.parse_args()
    rng = np.random.default_rng(35)
    import OCP

    malloc = ", ".join(f"{k}={os.environ.get(k, 'unset')}" for k in MALLOC)
    env = (f"cadbridge {cadbridge.__version__} ({Path(cadbridge.__file__).parent}), numba {numba.__version__} "
           f"({numba.get_num_threads()} threads available), OCP {getattr(OCP, '__version__', '?')}, numpy "
           f"{np.__version__}, python {sys.version.split()[0]}; {malloc}; load average at start "
           f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    print(env, flush=True)
    res = []
    for case in args.cases:
        r = bench_case(case, n=args.n, n_occ=args.n_occ, n_geomdl=args.n_geomdl, n_small=args.n_small,
                       repeat=args.repeat, rng=rng)
        res.append(r)
        q = r["rate"]
        print(f"{LABELS[case]}: ours {fmt(q['ours1'][0])}/s (1 thr), {fmt(q['ours2'][0])}/s (2 thr); OCC calls "
              f"{fmt(q['occ_geom'][0])}/s Geom, {fmt(q['occ_adaptor'][0])}/s GeomAdaptor, kept {fmt(q['occ_keep'][0])}/s",
              flush=True)
    md = report(res, args.n, args.n_occ, args.n_small)
    end = f"load average at the end {os.getloadavg()[0]:.2f}"
    print("\n" + md + "\n\n" + end)
    cmd = "python benchmarks/bench_evaluation.py " + " ".join(a for a in sys.argv[1:])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(f"# Evaluation benchmark (point + first derivatives)\n\n`{cmd.strip()}`\n\n{env}; {end}\n\n"
                        f"{md}\n")
    print(f"\nwritten to {args.out}")


if __name__ == "__main__":
    main()
