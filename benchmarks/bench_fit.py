"""Surface fitting against peers, measured in the same run.

1. Grid data (a smooth sheet-metal-like height field on an n x n grid): OCC's
   GeomAPI_PointsToBSplineSurface (degree 3, C2, its own net for --occ-tol), then geomdl's
   fitting.approximate_surface and cadbridge.nurbs.fit at OCC's control net size. Max deviation of
   the grid points from each surface (each point projected by cadbridge's point inversion; the
   same measure for all three) and the time ratio.
2. Scattered data: scan-like points of the U-shape die (noise, outliers, a hole), the whole
   `cadbridge.fitting.surface_fit.fit_points` job: points/s.
3. Scale: --scale N points of the same kind (default 1 000 000): wall time and peak memory.

    python benchmarks/bench_fit.py                 # all three
    python benchmarks/bench_fit.py --skip-scale    # grid + scattered only
    python benchmarks/bench_fit.py --only-scale --repeat 3   # the 1 M-point run, 3 times
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # cadbridge, and die_scan (tests/helpers)

from cadbridge.nurbs.fit import fit_surface, uniform_knots  # noqa: E402
from cadbridge.nurbs.project import project_to_surface  # noqa: E402
from cadbridge.nurbs.surface import NurbsSurface  # noqa: E402


def height(x, y):
    return 5.0 * np.sin(x / 15.0) * np.cos(y / 20.0) + 0.002 * x * y


def occ_to_nurbs(bs) -> NurbsSurface:
    """A Geom_BSplineSurface as a cadbridge NurbsSurface (poles, weights, flat knot vectors)."""
    nu, nv = bs.NbUPoles(), bs.NbVPoles()
    cp = np.array([[[bs.Pole(i, j).X(), bs.Pole(i, j).Y(), bs.Pole(i, j).Z()] for j in range(1, nv + 1)]
                   for i in range(1, nu + 1)])
    w = np.array([[bs.Weight(i, j) for j in range(1, nv + 1)] for i in range(1, nu + 1)])

    def flat(n_knots, knot, mult):
        return np.concatenate([[knot(k)] * mult(k) for k in range(1, n_knots + 1)])

    ku = flat(bs.NbUKnots(), bs.UKnot, bs.UMultiplicity)
    kv = flat(bs.NbVKnots(), bs.VKnot, bs.VMultiplicity)
    return NurbsSurface(bs.UDegree(), bs.VDegree(), ku, kv, cp, None if np.ptp(w) == 0 else w)


def max_dev(surface: NurbsSurface, pts: np.ndarray) -> float:
    return float(project_to_surface(surface, pts).distance.max())


def grid_bench(n: int, occ_tol: float) -> None:
    from OCP.GeomAbs import GeomAbs_C2
    from OCP.GeomAPI import GeomAPI_PointsToBSplineSurface
    from OCP.gp import gp_Pnt
    from OCP.TColgp import TColgp_Array2OfPnt

    xs, ys = np.linspace(0.0, 120.0, n), np.linspace(0.0, 90.0, n)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    pts = np.stack([X, Y, height(X, Y)], axis=-1)  # (n, n, 3), [i, j]: i along x
    flat = pts.reshape(-1, 3)
    arr = TColgp_Array2OfPnt(1, n, 1, n)
    for i in range(n):
        for j in range(n):
            arr.SetValue(i + 1, j + 1, gp_Pnt(*pts[i, j]))
    t = time.perf_counter()
    occ = GeomAPI_PointsToBSplineSurface(arr, 3, 3, GeomAbs_C2, occ_tol).Surface()
    t_occ = time.perf_counter() - t
    s_occ = occ_to_nurbs(occ)
    nu, nv = s_occ.shape
    print(f"grid {n}x{n} = {n * n} points; OCC net {nu}x{nv} for Tol3D {occ_tol:g}")

    import geomdl.fitting

    t = time.perf_counter()
    gd = geomdl.fitting.approximate_surface(flat.tolist(), n, n, 3, 3, ctrlpts_size_u=nu, ctrlpts_size_v=nv)
    t_gd = time.perf_counter() - t
    cp = np.array(gd.ctrlpts).reshape(nu, nv, 3)
    s_gd = NurbsSurface(3, 3, gd.knotvector_u, gd.knotvector_v, cp)

    # cadbridge: parameters = the grid's (x, y) (the best-fit-plane base of a height field), the
    # same net size with uniform knots, parameter correction on, no refinement, no smoothing
    u, v = X.ravel(), Y.ravel()
    ku, kv = uniform_knots(3, nu - 3, 0.0, 120.0), uniform_knots(3, nv - 3, 0.0, 90.0)
    fit_surface(flat[::37], u[::37], v[::37], knots=(uniform_knots(3, 1, 0, 120), uniform_knots(3, 1, 0, 90)),
                refine=False, robust=None, noise=0.0, smoothing=0.0)  # compile outside the timing
    t = time.perf_counter()
    ours = fit_surface(flat, u, v, knots=(ku, kv), refine=False, robust=None, noise=0.0, smoothing=0.0)
    t_cb = time.perf_counter() - t
    t = time.perf_counter()
    plain = fit_surface(flat, u, v, knots=(ku, kv), refine=False, robust=None, noise=0.0, smoothing=0.0,
                        correct_parameters=False)
    t_plain = time.perf_counter() - t
    rows = [("OCC GeomAPI_PointsToBSplineSurface", s_occ, t_occ), ("geomdl approximate_surface", s_gd, t_gd),
            ("cadbridge fit_surface", ours.surface, t_cb),
            ("cadbridge, no parameter correction", plain.surface, t_plain)]
    print(f"  {'fitter':<38}{'net':>8}{'max deviation':>16}{'time [s]':>11}")
    for name, s, tt in rows:
        print(f"  {name:<38}{f'{s.shape[0]}x{s.shape[1]}':>8}{max_dev(s, flat):>16.3e}{tt:>11.3f}")
    print(f"  time ratio: OCC / cadbridge = {t_occ / t_cb:.2f}x, geomdl / cadbridge = {t_gd / t_cb:.2f}x "
          f"(without parameter correction: {t_occ / t_plain:.2f}x, {t_gd / t_plain:.2f}x)")


def scattered_bench(n: int) -> None:
    from tests.helpers.scans import die_scan

    from cadbridge.fitting.surface_fit import fit_points

    model, _, x, _ = die_scan(n)
    fit_points(x[:5000], base=model, tolerance=0.01)  # compile outside the timing
    t = time.perf_counter()
    rep = fit_points(x, base=model, tolerance=0.01, trim=True)
    dt = time.perf_counter() - t
    f = rep.fit
    print(f"scattered die scan: {n} points in {dt:.2f} s = {n / dt:,.0f} points/s; net {f.surface.shape}, "
          f"stop {f.stop}, RMS {f.rms:.4f}, outliers {int(f.outliers.sum())}, fit vs CAD {cad_error(rep, model):.4f} mm "
          f"(sigma 0.01, tol 0.01: bound 0.04)")


def _rss_mb(field: str) -> float:
    """VmRSS / VmHWM (peak) of this process from /proc, MB (ru_maxrss where /proc is missing)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _reset_peak() -> bool:
    """Reset the peak RSS (VmHWM) to the current RSS (Linux >= 4.0: clear_refs 5)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def timed_scale_fit(model, x):
    """The timed scale fit (``trim=True``, tolerance 0.01 mm on the die base): (report, {wall,
    cpu [s], load0, load1 (load average before / after), peak, before (RSS [MB]), peak_over})."""
    from cadbridge.fitting.surface_fit import fit_points

    reset = _reset_peak()
    before = _rss_mb("VmRSS")
    load0 = os.getloadavg()[0]
    t, c = time.perf_counter(), time.process_time()
    rep = fit_points(x, base=model, tolerance=0.01, trim=True)
    dt, dc = time.perf_counter() - t, time.process_time() - c
    load1 = os.getloadavg()[0]
    peak = _rss_mb("VmHWM") if reset else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return rep, dict(wall=dt, cpu=dc, load0=load0, load1=load1, peak=peak, before=before, peak_over=peak - before)


def scale_bench(n: int, repeat: int = 1) -> None:
    import os

    from tests.helpers.scans import die_scan

    from cadbridge.fitting.surface_fit import fit_points

    model, _, x, _ = die_scan(n)
    # compile (or load from numba's cache) outside the timing, the large-input path included
    fit_points(x[:120000], base=model, tolerance=0.01)
    for r in range(repeat):
        rep, m = timed_scale_fit(model, x)
        dt, dc, load0, load1, peak, before = (m[k] for k in ("wall", "cpu", "load0", "load1", "peak", "before"))
        f = rep.fit
        print(f"scale: {n} points in {dt:.1f} s wall, {dc:.1f} s CPU ({n / dt:,.0f} points/s); load average "
              f"{load0:.1f} -> {load1:.1f} on {os.cpu_count()} cores; net {f.surface.shape}, stop {f.stop}; "
              f"peak RSS {peak:.0f} MB, {peak - before:.0f} MB over the {before:.0f} MB before the fit = "
              f"{(peak - before) / (n / 1e6):.0f} MB per million points (the points alone: {x.nbytes / 2**20:.0f} MB); "
              f"fit vs CAD {cad_error(rep, model):.4f} mm")
        del rep, f


def cad_error(rep, model) -> float:
    """Max distance of dense samples of the fit (inside its trim, feet inside the CAD) to the die CAD."""
    from cadbridge.cad.search import project_points

    s = rep.face.surface
    u, v = s.grid(500, 60)
    inside = rep.face.contains(u, v)
    pr = project_points(s.evaluate(u[inside], v[inside]), model)
    return float(pr.distance[pr.status == 0].max())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--grid", type=int, default=100, help="grid points per side (default 100)")
    ap.add_argument("--occ-tol", type=float, default=1e-3, help="OCC Tol3D, model units (default 1e-3)")
    ap.add_argument("--scattered", type=int, default=100000, help="scattered points (default 100000)")
    ap.add_argument("--scale", type=int, default=1000000, help="points of the scale run (default 1000000)")
    ap.add_argument("--skip-scale", action="store_true")
    ap.add_argument("--only-scale", action="store_true", help="the scale run only")
    ap.add_argument("--repeat", type=int, default=1, help="scale runs (default 1)")
    a = ap.parse_args()
    if not a.only_scale:
        grid_bench(a.grid, a.occ_tol)
        scattered_bench(a.scattered)
    if not a.skip_scale:
        scale_bench(a.scale, a.repeat)


if __name__ == "__main__":
    main()
