"""Scale benchmark of projection and exact CAD normals (issue 8; a script, not a test).

    python benchmarks/bench_normals_scale.py [--points 100000] [--occ-points 10000] [--repeat 3]
        [--nodes 1000000] [--mesh FILE] [--out benchmarks/results/normals_scale.md]

1. `project_points` on N points within 0.5 % of the model size of the trimmed faces of the
   bearing (../shared/iges_real/occt_bearing_EuclidQuantum.iges, 213 faces) and of the
   production die (iges_samples/production_die_{nurbs,analytic}.igs, 1 102 faces; made by
   ``python iges_samples/make_samples.py --production``), with the search index built before
   (its build time is a row of its own). Peer, in the same run: a Python loop over OCC's
   ``GeomAPI_ProjectPointOnSurf(P, S)`` onto the one face each point came from (the known
   face: no search at all). Ratio = our points/s over OCC's; both timings best of 3.
2. Cost against the number of faces: per-point time die / bearing, next to the face ratio
   and the log ratio; and per-point time in units of OCC's per-point time on the same file
   (OCC's known-face projection has no search, so this ratio shows the cost of the search
   apart from the surfaces' own evaluation cost, which differs: the die's fillets are
   rational degree 2 x 9..14).
3. `cad_normals` on a mesh of the production die with >= --nodes nodes: a gmsh triangle mesh
   (size 2.45 mm, about 265 000 nodes, cached in the temp folder; --mesh FILE reuses one)
   refined once 1 -> 4 (edge midpoints moved onto the CAD by `project_points`: set-up, timed
   apart). Timed with the index built first (a row of its own) and end to end from a freshly
   read model. Linear in points: `project_points` on 1/10 of the nodes and on all of them.

Every timing is given as wall time and as CPU time (``time.process_time``: all threads of the
process; ``os.times`` user / system for the die normals), since the machine is shared; the
bearing's index build is timed first in the process and again on freshly read models. The
last lines (``TARGET ...``) say, one per issue-8 target, the number and whether it holds, with
the load average. Prints the table and writes it to ``benchmarks/results/normals_scale.md``.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_projection import points_on_faces  # noqa: E402

from cadbridge.iges import read_iges  # noqa: E402
from cadbridge.cad.search import index_for, project_points  # noqa: E402

BEARING = ROOT.parent / "shared" / "iges_real" / "occt_bearing_EuclidQuantum.iges"
DIES = [ROOT / "iges_samples" / "production_die_nurbs.igs", ROOT / "iges_samples" / "production_die_analytic.igs"]
REPEAT = 3  # timings: best of 3 (set by --repeat)
TARGETS: list[str] = []  # one line per issue-8 target, printed last


class Clock:
    """Wall (perf_counter), CPU of this process (process_time: all threads, user + system) and
    os.times user / system, read together; ``lap()`` gives the differences since the start."""

    def __init__(self) -> None:
        self.t, self.c, self.o = time.perf_counter(), time.process_time(), os.times()

    def lap(self) -> tuple[float, float, float, float]:
        o = os.times()
        return (time.perf_counter() - self.t, time.process_time() - self.c, o.user - self.o.user,
                o.system - self.o.system)


def load() -> str:
    try:
        return f"{os.getloadavg()[0]:.2f}"
    except OSError:  # pragma: no cover - platform without getloadavg
        return "?"


def projection_case(path: Path, n: int, n_occ: int, seed: int = 3) -> dict:
    """Index build and `project_points` on n points near the trimmed faces vs the OCC loop."""
    from OCP.GeomAPI import GeomAPI_ProjectPointOnSurf
    from OCP.gp import gp_Pnt

    from cadbridge.verify.reference import occ_read

    model = read_iges(path)
    clk = Clock()
    idx = index_for(model)  # first build in this process (numba kernels loaded from the cache)
    t_first, c_first = clk.lap()[:2]
    warm = []
    for _ in range(REPEAT):  # the same build again on freshly read models (kernels in memory)
        fresh = read_iges(path)
        clk = Clock()
        index_for(fresh)
        warm.append(clk.lap()[:2])
    t_index, c_index = min(warm)
    rng = np.random.default_rng(seed)
    pts, fid = points_on_faces(rng, model, n, 0.005 * model.size())
    project_points(pts[:200], model, index=idx)  # compiled kernels loaded (cache) once per process
    t_ours, c_ours = math.inf, math.inf
    for _ in range(REPEAT):  # best of REPEAT, ours and OCC's alike: the machine is shared
        clk = Clock()
        res = project_points(pts, model, index=idx)
        w, c = clk.lap()[:2]
        if w < t_ours:
            t_ours, c_ours = w, c
    occ = occ_read(path)
    row = dict(name=path.name, faces=len(model.faces), n=n, t_index=t_index, t_ours=t_ours, c_ours=c_ours,
               c_index=c_index, t_first=t_first, c_first=c_first,
               status=np.bincount(res.status, minlength=4).tolist(), cand=float(res.candidates.mean()),
               same_face=float(np.mean(res.face == fid)), t_occ=math.nan, m=0, agree="-")
    if len(occ) != len(model.faces):
        print(f"{path.name}: OCC reads {len(occ)} faces, we {len(model.faces)}: no paired peer")
        return row
    surfs = [f.surface for f in occ]
    m = min(n_occ, n)
    occ_d = np.full(m, np.nan)
    t_occ, c_occ = math.inf, math.inf
    for _ in range(REPEAT):
        clk = Clock()
        for i in range(m):
            pr = GeomAPI_ProjectPointOnSurf(gp_Pnt(*map(float, pts[i])), surfs[fid[i]])
            if pr.NbPoints() > 0:
                occ_d[i] = pr.LowerDistance()
        w, c = clk.lap()[:2]
        if w < t_occ:
            t_occ, c_occ = w, c
    tol = 1e-9 * model.size()
    sub = res.distance[:m]
    row.update(t_occ=t_occ, c_occ=c_occ, m=m, agree=f"{np.count_nonzero(np.abs(sub - occ_d) <= tol)} equal, "
               f"{np.count_nonzero(sub < occ_d - tol)} nearer (other face), "
               f"{np.count_nonzero(sub > occ_d + tol)} farther")
    return row


def refine(mesh, model):
    """Uniform 1 -> 4 refinement of a triangle mesh; the edge midpoints are moved onto the
    CAD (their `project_points` foot). Returns the refined mesh and the set-up seconds."""
    from cadbridge.mesh.mesh import CellBlock, Mesh

    t0 = time.perf_counter()
    tri = np.concatenate([np.asarray(b.data) for b in mesh.cells if b.type == "triangle"])
    e = np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]), axis=1)
    edges, inv = np.unique(e, axis=0, return_inverse=True)
    inv = inv.reshape(3, -1).T  # (T, 3): edge ids of (01, 12, 20)
    mid = 0.5 * (mesh.nodes[edges[:, 0]] + mesh.nodes[edges[:, 1]])
    pr = project_points(mid, model)
    ok = np.isfinite(pr.distance)
    mid[ok] = pr.foot[ok]
    n0 = len(mesh.nodes)
    m01, m12, m20 = (n0 + inv[:, k] for k in range(3))
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    corners = ((a, m01, m20), (m01, b, m12), (m20, m12, c), (m01, m12, m20))
    cells = np.concatenate([np.column_stack(x) for x in corners])
    out = Mesh(np.concatenate([mesh.nodes, mid]), [CellBlock("triangle", cells)])
    return out, time.perf_counter() - t0


def die_mesh(path: Path, mesh_file: Path | None, size: float = 2.45):
    from cadbridge.mesh.io import read_mesh, write_mesh

    cache = mesh_file or Path(tempfile.gettempdir()) / "cadbridge-bench" / f"{path.stem}_h{size}.msh"
    if cache.is_file():
        t0 = time.perf_counter()
        mesh = read_mesh(cache)
        return mesh, f"read {cache} ({time.perf_counter() - t0:.1f} s)"
    from cadbridge.mesh.generate import mesh_cad

    t0 = time.perf_counter()
    mesh = mesh_cad(path, element="tri", size=size)
    t = time.perf_counter() - t0
    cache.parent.mkdir(parents=True, exist_ok=True)
    write_mesh(mesh, cache)
    return mesh, f"gmsh size {size} in {t:.0f} s (cached in {cache})"


def normals_case(path: Path, nodes: int, mesh_file: Path | None) -> list[tuple[str, str]]:
    from cadbridge.normals.cad import cad_normals

    model = read_iges(path)
    mesh, how = die_mesh(path, mesh_file)
    base_nodes = mesh.n_nodes
    t_ref = 0.0
    while mesh.n_nodes < nodes:
        mesh, t = refine(mesh, model)
        t_ref += t
    n = mesh.n_nodes
    rows = [("die mesh", f"{base_nodes:,} gmsh nodes ({how}), refined 1->4 to {n:,} nodes / "
                         f"{mesh.n_elements:,} triangles (set-up {t_ref:.1f} s)")]
    # end to end from a freshly read model: index build + cad_normals
    fresh = read_iges(path)
    clk = Clock()
    index_for(fresh)
    t_idx, c_idx = clk.lap()[:2]
    clk = Clock()
    cn = cad_normals(mesh, fresh, orient=True)
    t_cn, c_cn, u_cn, s_cn = clk.lap()
    st = np.bincount(cn.status, minlength=4).tolist()
    ok = bool(np.all(np.isfinite(cn.normals))) and bool(np.allclose(np.linalg.norm(cn.normals, axis=1), 1.0))
    rows.append(("search index build (fresh model)", f"{t_idx:.2f} s (CPU {c_idx:.2f} s)"))
    import numba

    from cadbridge.cad.search import _concurrent_kernels

    rows.append(("threads", f"{numba.config.NUMBA_NUM_THREADS} numba threads ({numba.threading_layer()} layer); "
                            f"cad_normals runs the mesh topology on a second thread during the node projection"
                            + ("; node blocks after the first two at a time" if _concurrent_kernels() else "")
                            + " (CPU time counts all threads: the OCC peer is single-threaded)"))
    rows.append((f"cad_normals, {n:,} nodes (index built)",
                 f"**{t_cn:.2f} s** ({n / t_cn:,.0f} nodes/s; CPU {c_cn:.2f} s: user {u_cn:.2f} s, system "
                 f"{s_cn:.2f} s); statuses {st} [C,B,T,F], creases {int(cn.crease.sum()):,}, "
                 f"finite unit normals: {ok}"))
    rows.append(("cad_normals end to end (index + normals)",
                 f"**{t_idx + t_cn:.2f} s** (CPU {c_idx + c_cn:.2f} s; target < 20 s)"))
    TARGETS.append(f"TARGET die {n:,} nodes cad_normals + index < 20 s: {t_idx + t_cn:.2f} s wall "
                   f"(index {t_idx:.2f} + normals {t_cn:.2f}), CPU {c_idx + c_cn:.2f} s -> "
                   f"{'holds' if t_idx + t_cn < 20 else 'does not hold'}")
    rng = np.random.default_rng(7)
    sub = rng.choice(n, n // 10, replace=False)
    idx = index_for(fresh)
    t0 = time.perf_counter()
    project_points(mesh.nodes[sub], fresh, index=idx)
    t1 = time.perf_counter() - t0
    t0 = time.perf_counter()
    project_points(mesh.nodes, fresh, index=idx)
    t10 = time.perf_counter() - t0
    rows.append(("project_points on the nodes: N/10 vs N",
                 f"{len(sub):,}: {t1:.2f} s, {n:,}: {t10:.2f} s, time ratio {t10 / t1:.1f} (linear = 10)"))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, default=100_000, help="points near the faces per file")
    ap.add_argument("--occ-points", type=int, default=10_000, help="points of the OCC loop per file")
    ap.add_argument("--repeat", type=int, default=3, help="projection timings: best of this many runs")
    ap.add_argument("--nodes", type=int, default=1_000_000, help="mesh nodes of the die normals run (0: skip)")
    ap.add_argument("--mesh", type=Path, default=None, help="die mesh file to reuse (else gmsh, cached)")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "normals_scale.md")
    a = ap.parse_args()
    global REPEAT
    REPEAT = max(1, a.repeat)
    load0 = load()
    files = [p for p in [BEARING, *DIES] if p.is_file()]
    for p in [BEARING, *DIES]:
        if not p.is_file():
            print(f"({p} not present: skipped)")
    rows = [projection_case(p, a.points, a.occ_points) for p in files]
    lines = ["| file | faces | index build: first / again (CPU) | project_points N | seconds (CPU) | points/s | "
             "OCC loop (known face) points/s (CPU s per point) | ratio (CPU ratio) | statuses [C,B,T,F] | "
             "faces tried/point | vs OCC distance |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---|---:|---|"]
    for r in rows:
        ours = r["n"] / r["t_ours"]
        occ = r["m"] / r["t_occ"] if r["m"] else math.nan
        cpu_ratio = (r["c_occ"] / r["m"]) / (r["c_ours"] / r["n"]) if r["m"] else math.nan
        lines.append(f"| `{r['name']}` | {r['faces']} | {r['t_first']:.2f} s / {r['t_index']:.2f} s "
                     f"({r['c_first']:.2f} / {r['c_index']:.2f}) | {r['n']:,} | {r['t_ours']:.2f} ({r['c_ours']:.2f}) | "
                     f"{ours:,.0f} | {occ:,.0f} ({r['c_occ'] / max(r['m'], 1) * 1e6:.0f} us) | **{ours / occ:.1f}x** "
                     f"({cpu_ratio:.1f}x) | {r['status']} | {r['cand']:.2f} | {r['agree']} |")
        if r["name"] == BEARING.name:
            TARGETS.append(f"TARGET bearing index build < 0.5 s: {r['t_index']:.2f} s wall again ({r['c_index']:.2f} s CPU), "
                           f"{r['t_first']:.2f} s first in the process -> "
                           f"{'holds' if max(r['t_index'], r['t_first']) < 0.5 else 'does not hold'}")
            TARGETS.append(f"TARGET bearing project_points {r['n']:,} points >= 20x OCC known-face loop: "
                           f"{ours / occ:.1f}x wall ({cpu_ratio:.1f}x CPU) -> "
                           f"{'holds' if ours / occ >= 20 else 'does not hold'}")
    scale = []
    b = next((r for r in rows if r["name"] == BEARING.name), None)
    for r in rows:
        if b is None or r is b:
            continue
        per_b, per_r = b["t_ours"] / b["n"], r["t_ours"] / r["n"]
        rel_b = per_b / (b["t_occ"] / b["m"]) if b["m"] else math.nan
        rel_r = per_r / (r["t_occ"] / r["m"]) if r["m"] else math.nan
        logr = math.log(r["faces"]) / math.log(b["faces"])
        scale.append(f"| bearing -> `{r['name']}` | x{r['faces'] / b['faces']:.1f} | x{logr:.2f} | "
                     f"x{per_r / per_b:.2f} | x{rel_r / rel_b:.2f} |")
        TARGETS.append(f"TARGET cost close to logarithmic in faces, bearing -> {r['name']}: time per point "
                       f"x{per_r / per_b:.2f} for faces x{r['faces'] / b['faces']:.1f} (log x{logr:.2f}); "
                       f"per point in units of OCC's on the same file x{rel_r / rel_b:.2f}")
    normals = normals_case(DIES[0], a.nodes, a.mesh) if a.nodes and DIES[0].is_file() else []
    cmd = "python benchmarks/bench_normals_scale.py" + "".join(f" {x}" for x in sys.argv[1:])
    md = [
        "# Projection and CAD normals at scale (issue 8)",
        "",
        f"`{cmd}`",
        "",
        f"python {platform.python_version()}, numpy {np.__version__}, {os.cpu_count()} CPUs, "
        f"load average {load0} at the start, {load()} at the end "
        "(shared machine: the ratios are measured in the same run).",
        "",
        "## project_points on points within 0.5 % of the model size of the trimmed faces",
        "",
        *lines,
        "",
        "The OCC peer projects each point onto the one face it was generated from (no search); "
        "cadbridge searches all faces and decides trims on the exact curves.",
        "",
    ]
    if scale:
        md += ["## Cost against the number of faces", "",
               "| models | faces | log(faces) | time per point | time per point / OCC's on the same file |",
               "|---|---:|---:|---:|---:|", *scale, "",
               "OCC's known-face projection does no search: the last column is the search's own growth "
               "(the surfaces differ: the die's fillets are rational degree 2 x 9..14).", ""]
    if normals:
        md += ["## Exact CAD normals on the production die", "", "| step | result |", "|---|---|",
               *[f"| {k} | {v} |" for k, v in normals], ""]
    TARGETS.append(f"load average {load0} at the start, {load()} at the end ({os.cpu_count()} CPUs)")
    md += ["## Targets (one line each)", "", "```", *TARGETS, "```", ""]
    text = "\n".join(md)
    print(text)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = a.out.with_suffix(".md.tmp")
    tmp.write_text(text)
    tmp.replace(a.out)
    print(f"\nwritten {a.out}")


if __name__ == "__main__":
    main()
