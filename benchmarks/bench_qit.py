"""QIT (cadbridge.mesh.qit.mesher) side by side with gmsh on the same CAD, same target size.

Cases: the appendix D surfaces of Herrero Adan & Cardoso (2020) (Ex. 7.1 at R = 12 and 5,
Ex. 7.2 at R = 5), the plate with a hole (trimmed), and the U-shape die and punch (NURBS).
For each case and mesher:

* quality (cadbridge.mesh.quality): Q (eq. 21), angle spread (std, min, max), size spread
  (std of triangle area / A_BIT);
* time to mesh (QIT: whole algorithm, best of 2 runs; gmsh: import + 2D mesh of the
  algorithm reported);
* QIT two ways: as shipped and the paper's construction alone (``strip_opt=False``);
* Nagata shape error with exact CAD normals (cadbridge.tool.pipeline.build_tool): max |distance|
  of the Nagata surface to the CAD, at equal node count (gmsh's size is rescaled until its
  node count is within 3 % of QIT's).

gmsh's "best isotropic algorithm": MeshAdapt (1), Delaunay (5) and Frontal-Delaunay (6)
are all run at MeshSizeMin = MeshSizeMax = R; the one with the highest Q is reported.

    python benchmarks/bench_qit.py [--quick] [--out benchmarks/results/qit.md]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # cadbridge, and the shared test geometry (tests/helpers)

from cadbridge.iges import read_iges, write_iges  # noqa: E402
from cadbridge.mesh.mesh import CellBlock, Mesh  # noqa: E402
from cadbridge.mesh.qit.mesher import QitOptions, qit_mesh  # noqa: E402
from tests.helpers.qit_examples import example_71, example_72  # noqa: E402
from cadbridge.mesh.quality import mesh_quality  # noqa: E402
from cadbridge.cad.model import Face  # noqa: E402

GMSH_ALGOS = {1: "MeshAdapt", 5: "Delaunay", 6: "Frontal-Delaunay"}
# QIT as shipped (with the strip step, docs/qit.md choice 19) and the paper's construction alone
QIT_VARIANTS = [("QIT", {}), ("QIT, paper's strip only", {"strip_opt": False})]


def gmsh_mesh(path: Path, size: float, algo: int) -> tuple[Mesh, float]:
    """Triangles of all faces of ``path`` by gmsh algorithm ``algo`` at uniform ``size``
    (faces sewn so shared edges conform). Returns the mesh and the seconds taken."""
    import gmsh

    t0 = time.perf_counter()
    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.option.setNumber("General.Verbosity", 0)
        gmsh.option.setNumber("Geometry.OCCSewFaces", 1)
        gmsh.option.setNumber("Geometry.Tolerance", 1e-4)
        gmsh.model.occ.importShapes(str(path))
        gmsh.model.occ.synchronize()
        gmsh.option.setNumber("Mesh.Algorithm", algo)
        gmsh.option.setNumber("Mesh.MeshSizeMin", size)
        gmsh.option.setNumber("Mesh.MeshSizeMax", size)
        gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", 0)
        gmsh.option.setNumber("Mesh.MeshSizeExtendFromBoundary", 1)
        gmsh.model.mesh.generate(2)
        tags, xyz, _ = gmsh.model.mesh.getNodes()
        index = np.full(int(tags.max()) + 1, -1)
        index[tags] = np.arange(len(tags))
        tris = []
        for _, s in gmsh.model.getEntities(2):
            et, _, en = gmsh.model.mesh.getElements(2, s)
            for t, n in zip(et, en):
                if t == 2:
                    tris.append(index[np.asarray(n, dtype=np.int64)].reshape(-1, 3))
        mesh = Mesh(np.asarray(xyz).reshape(-1, 3), [CellBlock("triangle", np.concatenate(tris))])
    finally:
        gmsh.finalize()
    return mesh.remove_unused_nodes()[0], time.perf_counter() - t0


def nagata_error(mesh: Mesh, model) -> float:
    """Max |distance| of the Nagata surface (exact CAD normals) to the CAD (mm)."""
    from cadbridge.normals.cad import cad_normals
    from cadbridge.tool.build import consistently_oriented, build_tool

    mesh = consistently_oriented(mesh, True)
    cn = cad_normals(mesh, model)
    tool = build_tool("t", mesh, cn.normals, cn.corner_normals, "cad", model=model, grid=6,
                      node_face=cn.face, node_distance=cn.distance)
    return float(tool.stats["max_abs_surface_error"])


def row(name, mesher, mesh, R, seconds, err) -> dict:
    q = mesh_quality(mesh.nodes, mesh.triangles, R).summary()
    return dict(case=name, mesher=mesher, nodes=len(mesh.nodes), tris=q["triangles"], q=q["q"],
                angle_std=q["angle_std"], angle_min=q["angle_min"], angle_max=q["angle_max"],
                size_std=q["size_rel_std"], seconds=seconds, nagata_err=err)


def cases(tmp: Path, quick: bool):
    p71 = tmp / "ex71.igs"
    write_iges([Face(example_71(), de=1)], p71)
    p72 = tmp / "ex72.igs"
    write_iges([Face(s, de=2 * i + 1) for i, s in enumerate(example_72())], p72)
    out = [("Ex. 7.1, R = 12", p71, 12.0), ("Ex. 7.1, R = 5", p71, 5.0), ("Ex. 7.2, R = 5", p72, 5.0),
           ("plate with hole, R = 5", ROOT / "iges_samples" / "trimmed_hole.igs", 5.0)]
    if not quick:
        out += [("U-shape die, R = 4", ROOT / "iges_samples" / "ushape_die_nurbs.igs", 4.0),
                ("U-shape punch, R = 4", ROOT / "iges_samples" / "ushape_punch_nurbs.igs", 4.0)]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="paper surfaces and plate only")
    ap.add_argument("--out", default=None, help="also write the markdown table here")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as td:
        for name, path, R in cases(Path(td), args.quick):
            model = read_iges(path)
            for label, kw in QIT_VARIANTS:
                tq = np.inf
                for _ in range(2):  # best of 2: the first run may include numba compilation
                    t0 = time.perf_counter()
                    m = qit_mesh(model, R, QitOptions(size=R, **kw))
                    tq = min(tq, time.perf_counter() - t0)
                rows.append(row(name, label, m, R, tq, nagata_error(m, model)))
                if not kw:
                    qm = m  # the default: gmsh's equal-node-count size is set against it
            best = None
            for algo in GMSH_ALGOS:
                gm, tg = gmsh_mesh(path, R, algo)
                q = mesh_quality(gm.nodes, gm.triangles, R).q
                if best is None or q > best[0]:
                    best = (q, algo, gm, tg)
            _, algo, gm, tg = best
            rows.append(row(name, f"gmsh {GMSH_ALGOS[algo]} (same R)", gm, R, tg, nagata_error(gm, model)))
            # equal node count: rescale gmsh's size (N ~ 1/h^2)
            h = R
            for _ in range(4):
                if abs(len(gm.nodes) / len(qm.nodes) - 1) <= 0.03:
                    break
                h *= np.sqrt(len(gm.nodes) / len(qm.nodes))
                gm, tg = gmsh_mesh(path, h, algo)
            rows.append(row(name, f"gmsh {GMSH_ALGOS[algo]} (h = {h:.3g}, equal nodes)", gm, R, tg,
                            nagata_error(gm, model)))
            print(f"{name}: done", file=sys.stderr)
    head = ("| case | mesher | nodes | triangles | Q [%] | angle std / min / max [deg] | size std [x A_BIT] "
            "| time [s] | Nagata error, CAD normals [mm] |\n|---|---|---:|---:|---:|---|---:|---:|---:|")
    lines = [head] + [
        f"| {r['case']} | {r['mesher']} | {r['nodes']} | {r['tris']} | {r['q']:.1f} | "
        f"{r['angle_std']:.1f} / {r['angle_min']:.1f} / {r['angle_max']:.1f} | {r['size_std']:.3f} | "
        f"{r['seconds']:.2f} | {r['nagata_err']:.3e} |" for r in rows]
    text = "\n".join(lines)
    print(text)
    if args.out:
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
