"""Adaptive Nagata meshing (issue 12) against uniform gmsh meshes, in the same run.

For each sample and shape tolerance t: `cadbridge.tool.refine.refine_mesh` gives a mesh whose
max shape error E_a is measured on its dense check grid (11 divisions per patch). Uniform
gmsh meshes (`mesh_cad`, quads, one size everywhere, no curvature sizing) of shrinking size
h (x 0.8 per step) are measured on 6 divisions per patch (fewer samples: their errors can
only be underestimated, which favours them) until one reaches E_a; the node ratio of that
coarsest uniform mesh to the adaptive one is the efficiency. The default `cadbridge convert`
mesh (gmsh curvature sizing, 12 elements per turn) is listed too.

Samples: the U-shape die (R 5 and planes), a punch with R 3 and R 30 rounds (box 120 x 80 x
30, vertical edges R 30, top edges R 3, generated here with cadquery), the torus patch (tube
R 5, sweep R 20-25, a free R 20 border), and the production
die `iges_samples/production_die_nurbs.igs` when it exists locally (never generated here).

    python benchmarks/bench_adaptive.py [--quick] [--out benchmarks/results/adaptive.md]

The production die alone (minutes per mesh: uniform sizes are given, not searched; adaptive
and uniform meshes are measured on the same grid, the adaptive check's 3 divisions per patch):

    nice -n 10 python benchmarks/bench_adaptive.py --production-only --tols 0.05 \
        --uniform-sizes 5,4.5,4 --out benchmarks/results/adaptive_production.md
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def make_punch(path: Path) -> None:
    """Punch working surface: box 120 x 80 x 30, vertical edges R 30, top edges R 3 (the
    faces above its bottom), NURBS-mode IGES through `cadbridge.ushape.export_iges`."""
    import cadquery as cq
    from OCP.BRep import BRep_Builder
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS, TopoDS_Compound

    from cadbridge.ushape.geometry import export_iges

    solid = cq.Workplane("XY").box(120, 80, 30).edges("|Z").fillet(30).edges(">Z").fillet(3).val().wrapped
    b, comp = BRep_Builder(), TopoDS_Compound()
    b.MakeCompound(comp)
    exp = TopExp_Explorer(solid, TopAbs_FACE)
    while exp.More():
        f = TopoDS.Face_s(exp.Current())
        g = GProp_GProps()
        BRepGProp.SurfaceProperties_s(f, g)
        if g.CentreOfMass().Z() > -14.9:  # not the bottom
            b.Add(comp, f)
        exp.Next()
    export_iges({"PUNCH": comp}, path, mode="nurbs")


def measure(path: Path, mesh, model, projector, grid: int) -> tuple[float, float]:
    from cadbridge.tool.build import NoProgress, tools_from_mesh
    from cadbridge.tool.refine import shape_check

    tools = tools_from_mesh(mesh, model, method="cad", grid=2, projector=projector, progress=NoProgress(),
                            orient=True, meshed_per_face=True)
    c, _ = shape_check(tools, model, projector, grid)
    return c["max_error"], c["max_normal_error"]


def run(path: Path, tols, rows: list, max_steps: int) -> None:
    from cadbridge.iges import read_iges
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.tool.build import CadProjector
    from cadbridge.tool.refine import refine_mesh

    model = read_iges(path)
    projector = CadProjector(model)
    t0 = time.perf_counter()
    default = mesh_cad(path, element="quad", curvature_elements=12)
    t_def = time.perf_counter() - t0
    e_def, n_def = measure(path, default, model, projector, 6)
    rows.append((path.name, "-", "convert default (curvature 12/turn)", len(default.nodes), e_def, n_def, t_def, ""))
    for tol in tols:
        t0 = time.perf_counter()
        r = refine_mesh(path, tol, model=model, projector=projector)
        t_a = time.perf_counter() - t0
        e_a = r.check["max_error"]
        n_a = len(r.mesh.nodes)
        rows.append((path.name, f"{tol:g}", f"adaptive ({len(r.passes)} passes, {'met' if r.met else 'NOT met'})",
                     n_a, e_a, r.check["max_normal_error"], t_a, ""))
        h = model.size() / 2
        found = None
        for _ in range(max_steps):  # shrink the uniform size until it reaches E_a
            t0 = time.perf_counter()
            m = mesh_cad(path, element="quad", size=h, curvature_elements=0)
            t_u = time.perf_counter() - t0
            e_u, ne_u = measure(path, m, model, projector, 6)
            print(f"  {path.name} t={tol:g}: uniform h={h:.3g}: {len(m.nodes)} nodes, max error {e_u:.3e} "
                  f"(adaptive {n_a} nodes, {e_a:.3e})", flush=True)
            if e_u <= e_a:
                found = (h, m, e_u, ne_u, t_u)
                break
            h *= 0.8
        if found is None:
            rows.append((path.name, f"{tol:g}", f"uniform down to h = {h / 0.8:.3g}: not reached", len(m.nodes), e_u,
                         ne_u, t_u, f">= {len(m.nodes) / n_a:.1f}x"))
        else:
            h, m, e_u, ne_u, t_u = found
            rows.append((path.name, f"{tol:g}", f"coarsest uniform reaching it (h = {h:.3g})", len(m.nodes), e_u, ne_u,
                         t_u, f"{len(m.nodes) / n_a:.1f}x"))


def run_production(path: Path, tols, sizes, rows: list) -> None:
    """The production die: `refine_mesh(path, t, max_size=50)` per tolerance, then uniform
    gmsh quad meshes at the given ``sizes`` (coarsest first), all measured on the adaptive
    check's grid (3 divisions per patch); the coarsest uniform mesh reaching each adaptive
    max error gives the ratio. Progress goes to stdout with times."""
    from cadbridge.iges import read_iges
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.tool.build import CadProjector
    from cadbridge.tool.refine import refine_mesh

    t_all = time.perf_counter()

    class Say:
        def stage(self, s):
            print(f"{time.perf_counter() - t_all:8.1f} s  {s}", flush=True)

        def __getattr__(self, name):
            return lambda *a, **k: None

    model = read_iges(path)
    projector = CadProjector(model)
    adaptive = []
    for tol in tols:
        t0 = time.perf_counter()
        r = refine_mesh(path, tol, model=model, projector=projector, max_size=50.0, progress=Say())
        t_a = time.perf_counter() - t0
        print(r.summary(), flush=True)
        grid = r.check.get("grid", 3)
        adaptive.append((tol, len(r.mesh.nodes), r.check["max_error"], grid))
        rows.append((path.name, f"{tol:g}", f"adaptive ({len(r.passes)} passes, {'met' if r.met else 'NOT met'})",
                     len(r.mesh.nodes), r.check["max_error"], r.check["max_normal_error"], t_a, ""))
    grid = max(a[3] for a in adaptive) if adaptive else 3
    uniform = []
    for h in sizes:
        t0 = time.perf_counter()
        Say().stage(f"uniform gmsh quads h = {h:g}")
        m = mesh_cad(path, element="quad", size=h, curvature_elements=0)
        e_u, ne_u = measure(path, m, model, projector, grid)
        t_u = time.perf_counter() - t0
        print(f"  uniform h={h:g}: {len(m.nodes)} nodes, max error {e_u:.3e} ({grid} divisions), {t_u:.0f} s",
              flush=True)
        uniform.append((h, len(m.nodes), e_u, ne_u, t_u))
        rows.append((path.name, "-", f"uniform h = {h:g}", len(m.nodes), e_u, ne_u, t_u, ""))
    for tol, n_a, e_a, _ in adaptive:
        reach = [u for u in uniform if u[2] <= e_a]
        if reach:
            h, n_u = max(reach, key=lambda u: u[0])[:2]
            rows.append((path.name, f"{tol:g}", f"ratio: coarsest uniform reaching {e_a:.3e} (h = {h:g})", n_u, math.nan,
                         math.nan, math.nan, f"{n_u / n_a:.1f}x"))
        else:
            finest = min(uniform, key=lambda u: u[0]) if uniform else None
            what = f"no uniform size given reaches {e_a:.3e}" + (f" (h = {finest[0]:g}: {finest[2]:.3e})" if finest else "")
            rows.append((path.name, f"{tol:g}", what, finest[1] if finest else 0, math.nan, math.nan, math.nan,
                         f"> {finest[1] / n_a:.1f}x" if finest else ""))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one tolerance (0.01), U-shape die and punch only")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "adaptive.md"))
    ap.add_argument("--max-steps", type=int, default=22)
    ap.add_argument("--no-production", action="store_true", help="skip the production die even if present")
    ap.add_argument("--production-only", action="store_true",
                    help="only the production die (iges_samples/production_die_nurbs.igs), uniform sizes given")
    ap.add_argument("--tols", default="0.05", help="with --production-only: shape tolerances, comma separated")
    ap.add_argument("--uniform-sizes", default="5,4.5,4", help="with --production-only: uniform sizes, comma separated")
    a = ap.parse_args(argv)
    tols = (0.01,) if a.quick else (0.05, 0.01)
    rows: list = []
    speed = []
    if a.production_only:
        prod = ROOT / "iges_samples" / "production_die_nurbs.igs"
        if not prod.is_file():
            print(f"{prod} not found", file=sys.stderr)
            return 2
        run_production(prod, [float(x) for x in a.tols.split(",") if x],
                       [float(x) for x in a.uniform_sizes.split(",") if x], rows)
        out = a.out if a.out != ap.get_default("out") else str(ROOT / "benchmarks" / "results" / "adaptive_production.md")
        return _write(out, rows, [], production=True)
    with tempfile.TemporaryDirectory() as tmp:
        punch = Path(tmp) / "punch_r3_r30_nurbs.igs"
        make_punch(punch)
        samples = [ROOT / "iges_samples" / "ushape_die_nurbs.igs", punch, ROOT / "iges_samples" / "torus_patch.igs"]
        prod = ROOT / "iges_samples" / "production_die_nurbs.igs"
        if prod.is_file() and not a.quick and not a.no_production:
            samples.append(prod)
        for s in samples:
            print(f"{s.name} ...", flush=True)
            run(s, tols, rows, a.max_steps)
        # speed: adaptive U-shape tools at 0.002 mm vs one plain mesh + Nagata + measurement
        from cadbridge.iges import read_iges
        from cadbridge.mesh.generate import mesh_cad
        from cadbridge.tool.build import CadProjector
        from cadbridge.tool.refine import refine_mesh

        u = ROOT / "iges_samples" / "ushape_tools_nurbs.igs"
        model = read_iges(u)
        t0 = time.perf_counter()
        r = refine_mesh(u, 0.002, model=model, projector=CadProjector(model))
        t_ad = time.perf_counter() - t0
        t0 = time.perf_counter()
        m = mesh_cad(u, element="quad", curvature_elements=12)
        measure(u, m, model, CadProjector(model), 11)
        t_pl = time.perf_counter() - t0
        speed.append((u.name, r.met, len(r.passes), len(r.mesh.nodes), r.check["max_error"], t_ad, t_pl))
    return _write(a.out, rows, speed)


def _write(out: str, rows: list, speed: list, production: bool = False) -> int:
    """The results table (and the speed table) as markdown into ``out``."""
    def num(x, fmt):
        return "" if isinstance(x, float) and not math.isfinite(x) else format(x, fmt)

    if production:
        import os

        lines = ["# Adaptive Nagata meshing vs uniform gmsh meshes: production die", "",
                 f"`nice -n 10 python benchmarks/bench_adaptive.py --production-only ...` (one run, 2 cores shared with "
                 f"other work, load at the end {os.getloadavg()[0]:.1f}). Adaptive: `refine_mesh(die, t, max_size=50)`; "
                 "uniform: `mesh_cad(die, element='quad', size=h)`; both measured on the adaptive check's grid "
                 "(2 g - 1 divisions per patch for the loop's g: 3 on the die; the same points for both kinds). "
                 "Ratio = nodes of the coarsest uniform mesh reaching the adaptive max error / adaptive nodes.", ""]
    else:
        lines = ["# Adaptive Nagata meshing vs uniform gmsh meshes", "",
             "`python benchmarks/bench_adaptive.py` (one run, 2 cores shared with other work). Max shape error of the "
             "Nagata surface (exact CAD normals) against the CAD: adaptive meshes on 11 divisions per patch, uniform "
             "ones on 6 (which can only flatter them). Ratio = nodes of the coarsest uniform quad mesh (gmsh, size h "
             "shrunk by 0.8 per step, no curvature sizing) reaching the adaptive mesh's max error / adaptive nodes.",
             ""]
    lines += ["| sample | t [mm] | mesh | nodes | max shape error [mm] | max normal error [deg] | time [s] | ratio |",
              "|---|---:|---|---:|---:|---:|---:|---:|"]
    for name, tol, what, n, e, ne, t, ratio in rows:
        lines.append(f"| {name} | {tol} | {what} | {n} | {num(e, '.3e')} | {num(ne, '.3f')} | {num(t, '.1f')} | {ratio} |")
    if speed:
        lines += ["", "Speed: adaptive meshing at t = 0.002 mm against one plain mesh + Nagata + check of the same file, "
                  "same run:", "", "| file | met | passes | nodes | max error [mm] | adaptive [s] | plain [s] | ratio |",
                  "|---|---|---:|---:|---:|---:|---:|---:|"]
    for name, met, npass, n, e, ta, tp in speed:
        lines.append(f"| {name} | {met} | {npass} | {n} | {e:.3e} | {ta:.1f} | {tp:.1f} | {ta / tp:.2f}x |")
    text = "\n".join(lines) + "\n"
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    from cadbridge.common.atomic import atomic_write

    with atomic_write(out) as fh:
        fh.write(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
