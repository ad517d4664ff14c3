"""Search cost against the number of faces at constant face complexity (issue 8; a script).

    python benchmarks/bench_search_faces.py [--copies 1,2,4,8,16] [--points 100000]
        [--file ../shared/iges_real/occt_bearing_EuclidQuantum.iges] [--out FILE]

bench_normals_scale.py compares the bearing (213 faces) with the production die (1 102
faces), but the die's faces are not the bearing's: rational degree 2 x 9..14 fillets, trim
curves of degree 9-14. That ratio mixes the number of faces with what each face costs. Here
the number of faces alone changes: the model is N copies of one real file, translated on a
grid 1.5 x its extent apart (surfaces and 3D trim curves moved, 2D trims as they are), and the
same points (within 0.5 % of the file's size of its trimmed faces) are spread over the copies,
each point moved with its copy. The projection answer does not depend on N, so each tiled run
is also checked against the single copy's (distance within 1e-9 x size, the same face).

Peer in the same run: a Python loop over OCC's `GeomAPI_ProjectPointOnSurf` onto the one known
face (no search, so its per-point time does not depend on N). Reported per N: index build, the
time per point, its ratio to N = 1 next to the faces' and the log-faces' ratios, and the ratio
to OCC's loop.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_projection import points_on_faces  # noqa: E402

from cadbridge.iges import read_iges  # noqa: E402
from cadbridge.cad.model import Model, Trim, TrimLoop  # noqa: E402
from cadbridge.nurbs.curve import NurbsCurve  # noqa: E402
from cadbridge.nurbs.surface import NurbsSurface  # noqa: E402
from cadbridge.cad.search import index_for, project_points  # noqa: E402

REPEAT = 3


def _moved_curve(c, d: np.ndarray):
    if getattr(c, "dim", None) == 3 or (isinstance(c, NurbsCurve) and c.control_points.shape[1] == 3):
        return NurbsCurve(c.degree, c.knots, c.control_points + d, c.weights, c.domain)
    return c


def _moved_loop(loop: TrimLoop | None, d: np.ndarray) -> TrimLoop | None:
    if loop is None:
        return None
    mc = None if loop.model_curves is None else [_moved_curve(c, d) for c in loop.model_curves]
    return TrimLoop(list(loop.curves), mc)


def tiled(model: Model, copies: int) -> tuple[Model, np.ndarray]:
    """``copies`` translated copies of ``model`` on a square grid, 1.5 x its extent apart.
    Returns the tiled model (faces copy-major) and the (copies, 3) offsets."""
    lo, hi = model.bbox()
    step = 1.5 * (hi - lo)
    side = math.ceil(math.sqrt(copies))
    offsets = np.array([[step[0] * (k % side), step[1] * (k // side), 0.0] for k in range(copies)])
    faces = []
    for d in offsets:
        for f in model.faces:
            s = f.surface
            surf = NurbsSurface(s.degree_u, s.degree_v, s.knots_u, s.knots_v, s.control_points + d, s.weights,
                                s.domain)
            tr = f.trims
            trims = None if tr is None else Trim(_moved_loop(tr.outer, d), [_moved_loop(h, d) for h in tr.inner])
            faces.append(dataclasses.replace(f, surface=surf, trims=trims, trim_delta=f.trim_delta))
    return dataclasses.replace(model, faces=faces), offsets


def _best(fn):
    """Best of `REPEAT` by wall time (`timing.best_of`)."""
    from timing import best_of

    return best_of(fn, REPEAT)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--file", default=str(ROOT.parent / "shared" / "iges_real" / "occt_bearing_EuclidQuantum.iges"))
    ap.add_argument("--copies", default="1,2,4,8,16")
    ap.add_argument("--points", type=int, default=100_000)
    ap.add_argument("--occ-points", type=int, default=10_000)
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "search_faces.md"))
    a = ap.parse_args()
    path = Path(a.file)
    if not path.is_file():
        sys.exit(f"{path}: not found (the real-CAD corpus is ../shared/iges_real)")
    base = read_iges(path)
    size = base.size()
    rng = np.random.default_rng(3)
    pts, fid = points_on_faces(rng, base, a.points, 0.005 * size)
    ref = project_points(pts, base, index=index_for(base))

    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt

    from cadbridge.verify.reference import occ_read

    occ = [f.surface for f in occ_read(path)]
    m = min(a.occ_points, len(pts))

    def occ_loop():
        for i in range(m):
            GeomAPI_ProjectPointOnSurf(gp_Pnt(*map(float, pts[i])), occ[fid[i]])

    t_occ = _best(occ_loop)[0] / m if len(occ) == len(base.faces) else math.nan

    rows = []
    for n in [int(x) for x in a.copies.split(",")]:
        model, offsets = tiled(base, n)
        which = rng.integers(0, n, len(pts))
        moved = pts + offsets[which]
        w = time.perf_counter()
        idx = index_for(model)
        t_idx = time.perf_counter() - w
        project_points(moved[:200], model, index=idx)
        t, c, res = _best(lambda: project_points(moved, model, index=idx))
        tol = 1e-9 * size
        same = (np.abs(res.distance - ref.distance) <= tol) & (res.face == ref.face + which * len(base.faces))
        odd = ~same
        worst = float(np.max(np.abs(res.distance[odd] - ref.distance[odd]))) / size if odd.any() else 0.0
        rows.append(dict(n=n, faces=len(model.faces), t_idx=t_idx, t=t, c=c, per=t / len(pts),
                         cand=float(res.candidates.mean()), same=int(same.sum()), worst=worst,
                         other_face=int(np.count_nonzero(odd & (res.face != ref.face + which * len(base.faces))))))
        print(f"{n:3d} copies, {len(model.faces):5d} faces: index {t_idx:.2f} s, project {t:.2f} s wall / {c:.2f} s CPU, "
              f"{res.candidates.mean():.2f} candidate faces per point, {same.sum()} of {len(pts)} as one copy",
              flush=True)
    r0 = rows[0]
    load = os.getloadavg()[0]
    lines = [
        f"# Search cost against the number of faces ({path.name}, N copies)", "",
        f"`python benchmarks/bench_search_faces.py --copies {a.copies} --points {a.points}`, "
        f"{len(pts)} points within 0.5 % of the file's size, best of {REPEAT}, load {load:.1f}. "
        f"OCC's known-face loop: {t_occ * 1e6:.2f} us per point ({m} points).", "",
        "| copies | faces | index [s] | project [s] wall / CPU | us / point | x N = 1 | faces x | log faces x "
        "| candidates / point | as one copy | the others: max distance change / size, other face | ratio to OCC |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|",
    ]
    for r in rows:
        lines.append(f"| {r['n']} | {r['faces']} | {r['t_idx']:.2f} | {r['t']:.2f} / {r['c']:.2f} | {r['per'] * 1e6:.2f} "
                     f"| {r['per'] / r0['per']:.2f} | {r['faces'] / r0['faces']:.0f} "
                     f"| {math.log(r['faces']) / math.log(r0['faces']):.2f} | {r['cand']:.2f} "
                     f"| {r['same']} / {len(pts)} | {r['worst']:.1e}, {r['other_face']} | {t_occ / r['per']:.1f}x |")
    text = "\n".join(lines) + "\n"
    print(text)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, out)


if __name__ == "__main__":
    main()
