"""U-shape die end to end with `cadbridge map` (issue 9): a smooth synthetic contact pressure
and the Nagata shape error that `cadbridge ushape` writes, each mapped onto the exact die CAD
(bands, contour lines, VTU / IGES / CSV / PNG). Writes the two PNGs of docs/results.md.

    python benchmarks/results_ushape.py [-o out_results/] [--images docs/images]

The pressure lives on a gmsh triangle mesh of the die (1.5 mm); the shape error on the
refined Nagata surface of the structured quad tool (out/die/die_nagata.vtu, point data
``surface_error``, mm).
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

import numpy as np


def pressure(x: np.ndarray) -> np.ndarray:
    """Synthetic contact pressure [MPa]: a ridge along the die radius (the sheet bends over
    it), decaying into the land and the wall, modulated along y."""
    d = np.hypot(x[:, 0] - 41.0, x[:, 2] + 5.0) - 5.0  # distance from the R5 radius' surface
    ang = np.arctan2(x[:, 2] + 5.0, x[:, 0] - 41.0)  # 90 deg at the land, 180 deg at the wall
    ridge = np.exp(-((ang - np.radians(135.0)) / np.radians(30.0)) ** 2) * np.exp(-np.abs(d) / 3.0)
    land = np.exp(-np.clip(x[:, 0] - 41.0, 0, None) / 12.0) * np.exp(-np.clip(-x[:, 2], 0, None) / 2.0)
    return 40.0 * ridge * (1.0 + 0.3 * np.cos(x[:, 1] / 3.0)) + 12.0 * land


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", default="out_results", help="output folder")
    ap.add_argument("--images", default=None, help="also copy the PNGs here (e.g. docs/images)")
    ap.add_argument("--ushape", default=None, help="an existing `cadbridge ushape` output folder to reuse")
    args = ap.parse_args()

    import meshio

    from cadbridge.cli import main as cli
    from cadbridge.mesh.generate import mesh_cad
    from cadbridge.ushape.benchmark import run_ushape

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    us = Path(args.ushape) if args.ushape else out / "ushape"
    if not args.ushape:
        t0 = time.perf_counter()
        run_ushape(str(us))
        print(f"cadbridge ushape -o {us}: {time.perf_counter() - t0:.1f} s")
    cad = us / "cad" / "die.igs"

    mesh = mesh_cad(cad, element="tri", size=1.5)
    res = out / "die_pressure.vtu"
    meshio.write(res, meshio.Mesh(mesh.nodes, [(b.type, b.data) for b in mesh.cells],
                                  point_data={"pressure": pressure(mesh.nodes)}))
    zoom = "33,56,-1,22,-14,3"
    runs = [
        ("pressure", res, ["--field", "pressure", "--levels", "0,2,4,6,8,10,15,20,30,40,50"], "ushape_die_pressure.png"),
        ("nagata_error", us / "die" / "die_nagata.vtu", ["--field", "surface_error", "--levels", "6"],
         "ushape_die_nagata_error.png"),
    ]
    for name, src, opts, png in runs:
        dst = out / name
        argv = ["map", str(src), "--cad", str(cad), "-o", str(dst), "--zoom", zoom, "--view", "28,-128", *opts]
        print("cadbridge " + " ".join(argv))
        code = cli(argv)
        if code:
            raise SystemExit(code)
        if args.images:
            stem = src.name.split(".")[0]
            Path(args.images).mkdir(parents=True, exist_ok=True)
            shutil.copyfile(dst / f"{stem}.png", Path(args.images) / png)
            print(f"  -> {Path(args.images) / png}")


if __name__ == "__main__":
    main()
