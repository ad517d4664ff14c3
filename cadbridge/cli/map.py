"""`cadbridge map`: simulation results on the exact CAD (contour lines, bands, exports).

    cadbridge map RESULTS --cad CAD.igs --field NAME -o OUT/ [--levels 8 | --levels 0,5,10,20]
                  [--min A --max B] [--values CSV] [--chord-tol T] [--tolerance D] [--no-png]

The mapping (node inversion, sub-triangles, exact areas) is stored in OUT/mapping.npz with a
fingerprint of the inputs; running again into the same OUT with other levels or range reuses
it, so only the contouring is repeated.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import numpy as np

__all__ = ["register", "cmd_map", "parse_levels"]

_CACHE_VERSION = "cadbridge-map-2"  # 2: seam cuts and element centre values exact at levels (issue 34)


def parse_levels(text: str) -> int | list[float]:
    """'8' -> 8 bands; '0,5,10,20' -> those levels."""
    from cadbridge.common.errors import UsageError

    t = text.strip()
    try:
        if "," not in t:
            n = int(t)
            if n < 1:
                raise UsageError(f"--levels {text}: the number of bands must be at least 1")
            return n
        vals = [float(x) for x in t.split(",") if x.strip()]
    except ValueError:
        raise UsageError(f"--levels {text!r}: give a number of bands (8) or increasing levels (0,5,10,20)") from None
    if not vals or not all(np.isfinite(vals)) or any(b <= a for a, b in zip(vals, vals[1:])):
        raise UsageError(f"--levels {text!r}: levels must be finite and strictly increasing")
    return vals


def _digest(paths: list[Path | None], extra: dict) -> str:
    h = hashlib.sha256(_CACHE_VERSION.encode())
    for p in paths:
        if p is None:
            h.update(b"-")
            continue
        with open(p, "rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    h.update(json.dumps(extra, sort_keys=True).encode())
    return h.hexdigest()


_ARRAYS = ("nodes", "values", "face", "u", "v", "distance", "element_face", "seam", "pole", "tri_face", "tri_uv",
           "tri_f", "tri_key", "tri_area")


def save_mapping(path: Path, mapping, digest: str) -> None:
    """The mapping's arrays (not the model) with the input fingerprint, atomically."""
    from cadbridge.common.atomic import atomic_path

    data = {k: getattr(mapping, k) for k in _ARRAYS}
    data.update({f"corner_uv_{i}": c for i, c in enumerate(mapping.corner_uv)})
    meta = {"digest": digest, "field_name": mapping.field_name, "source": mapping.source, "n_keys": mapping.n_keys,
            "blocks": len(mapping.corner_uv), "timings": mapping.timings}
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **data)


def load_mapping(path: Path, model, digest: str):
    """The stored mapping if its fingerprint is ``digest``, else None."""
    from cadbridge.results.mapping import ResultMapping, face_topology

    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            if meta.get("digest") != digest:
                return None
            arrays = {k: z[k] for k in _ARRAYS}
            corner = [z[f"corner_uv_{i}"] for i in range(meta["blocks"])]
    except (OSError, ValueError, KeyError):
        return None
    return ResultMapping(model=model, field_name=meta["field_name"], source=meta["source"], corner_uv=corner,
                         topology=[face_topology(f.surface) for f in model.faces], n_keys=int(meta["n_keys"]),
                         timings=dict(meta["timings"], cached=True), **arrays)


def _png_options(args) -> dict:
    from cadbridge.common.errors import UsageError

    out = {}
    try:
        if args.view:
            elev, azim = (float(x) for x in args.view.split(","))
            out.update(elev=elev, azim=azim)
        if args.zoom:
            b = [float(x) for x in args.zoom.split(",")]
            if len(b) != 6 or not all(np.isfinite(b)) or b[1] <= b[0] or b[3] <= b[2] or b[5] <= b[4]:
                raise ValueError
            out["box"] = np.array([b[0::2], b[1::2]])
    except ValueError:
        raise UsageError("--view takes ELEV,AZIM and --zoom X0,X1,Y0,Y1,Z0,Z1 (each min < max)") from None
    return out


def cmd_map(args: argparse.Namespace) -> int:
    import time

    from cadbridge.common.errors import CheckFailed, UsageError
    from cadbridge.common.progress import Progress, say
    from cadbridge.formats import read_cad
    from cadbridge.normals.cad import ProjectionError
    from cadbridge.tool.outputs import staged_output
    from cadbridge.results.export import write_all
    from cadbridge.results.fields import FieldError, read_results
    from cadbridge.results.mapping import map_results

    levels = parse_levels(args.levels)
    png_options = _png_options(args)
    if args.min is not None and args.max is not None and not args.max > args.min:
        raise UsageError(f"--max ({args.max:g}) must be greater than --min ({args.min:g})")
    results = Path(args.results)
    out = Path(args.output)
    t0 = time.perf_counter()
    with Progress("cadbridge map") as progress:
        progress.stage(f"reading {args.cad}")
        model = read_cad(args.cad)
        if not model.faces:
            raise UsageError(f"{args.cad}: no faces to map onto")
        progress.stage(f"reading {results.name}")
        try:
            mesh, field = read_results(results, args.field, values=args.values)
        except FieldError as exc:
            raise UsageError(f"{results}: {exc}") from None
        digest = _digest([results, Path(args.cad), Path(args.values) if args.values else None],
                         {"field": args.field, "tolerance": args.tolerance})
        mapping = load_mapping(out / "mapping.npz", model, digest)
        if mapping is None:
            try:
                mapping = map_results(mesh, field.values, model, field_name=field.name, source=field.source,
                                      tolerance=args.tolerance, progress=progress)
            except ProjectionError as exc:
                raise CheckFailed(f"{results} does not lie on {args.cad}: {exc}; nothing written") from None
        t_map = time.perf_counter() - t0
        progress.stage("contour lines and bands")
        t1 = time.perf_counter()
        try:
            contours = mapping.contour(levels, args.min, args.max, chord_tol=args.chord_tol)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        t_contour = time.perf_counter() - t1
        chord = args.chord_tol if args.chord_tol is not None else 1e-4 * model.size()
        progress.stage("writing VTU, IGES, CSV, PNG")
        stem = results.name.split(".")[0] or "result"
        with staged_output(out) as tmp:
            files = write_all(tmp, contours, chord_tol=chord, stem=stem, png=not args.no_png, png_options=png_options)
            save_mapping(tmp / "mapping.npz", mapping, digest)
            files.append("mapping.npz")
            summary = _summary(contours, mapping, t_map, t_contour, files)
            (tmp / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
            files.append("summary.json")
    b = contours.bands
    L = contours.lines
    gap = float(L.joint_gap.max()) if len(L.joint_gap) else 0.0
    say(f"{field.name}: {mesh.n_nodes} nodes ({field.source}) on {len(np.unique(mapping.face))} faces, "
         f"max node distance {mapping.distance.max():.3g}")
    say(f"mapping {'reused from ' + str(out / 'mapping.npz') if mapping.timings.get('cached') else f'{t_map:.2f} s'}, "
         f"contouring {t_contour:.3f} s")
    say(f"{len(contours.levels)} levels {contours.levels[0]:.6g} .. {contours.levels[-1]:.6g}: "
         f"{int(b.present.sum())} bands, {len(L)} lines ({int(L.closed.sum())} closed), "
         f"largest gap where lines change face or cross a seam {gap:.2e}")
    for k in np.flatnonzero(b.present):
        say(f"  band {k:>3}  {b.label(k):<28} area {b.area[k]:.6g}")
    say(f"wrote {len(files)} files to {out}")
    return 0


def _summary(contours, mapping, t_map: float, t_contour: float, files: list[str]) -> dict:
    b = contours.bands
    L = contours.lines
    return {
        "field": mapping.field_name, "source": mapping.source, "nodes": int(len(mapping.nodes)),
        "levels": [float(x) for x in contours.levels],
        "bands": [{"band": int(k), "range": b.label(k), "lower": _num(b.lower[k]), "upper": _num(b.upper[k]),
                   "area": float(b.area[k])} for k in np.flatnonzero(b.present)],
        "lines": int(len(L)), "closed_lines": int(L.closed.sum()),
        "max_joint_gap": float(L.joint_gap.max()) if len(L.joint_gap) else 0.0,
        "max_node_distance": float(mapping.distance.max()),
        "seconds": {"mapping": t_map, "contouring": t_contour, **{k: v for k, v in mapping.timings.items() if k != "cached"}},
        "mapping_reused": bool(mapping.timings.get("cached", False)), "files": files,
    }


def _num(x: float):
    return float(x) if np.isfinite(x) else ("inf" if x > 0 else "-inf")


def register(sub, fmt) -> None:
    """Add the ``map`` subcommand."""
    p = sub.add_parser(
        "map", help="simulation results on the exact CAD: contour lines, bands, VTU/IGES/CSV/PNG", formatter_class=fmt,
        epilog="examples:\n  cadbridge map die_result.vtu --cad die.igs --field pressure -o die_map/\n"
               "  cadbridge map die_result.vtu --cad die.igs --field pressure -o die_map/ --levels 0,5,10,20\n"
               "  cadbridge map die.nagata --values wear.csv --cad die.igs --field wear -o wear/ --levels 6\n"
               "Reruns into the same OUT reuse the stored mapping (OUT/mapping.npz); see docs/results.md.")
    p.add_argument("results", metavar="RESULTS", help="result mesh (VTU, Gmsh .msh, Abaqus .inp, GiD .msh+.res, "
                                                      "or a cadbridge tool file with --values)")
    p.add_argument("--cad", required=True, help="IGES or STEP file of the tool")
    p.add_argument("--field", required=True, help="point or cell array to map (NAME[k] picks a component)")
    p.add_argument("-o", "--output", required=True, help="output folder")
    p.add_argument("--levels", default="8", help="number of equal bands (default 8) or increasing levels 0,5,10,20")
    p.add_argument("--min", type=float, default=None, help="lower end of the level range (default the data minimum)")
    p.add_argument("--max", type=float, default=None, help="upper end of the level range (default the data maximum)")
    p.add_argument("--values", default=None, help="CSV of nodal values (column FIELD) or GiD .res file")
    p.add_argument("--chord-tol", type=float, default=None,
                   help="largest chord-to-surface deviation of lines and tessellation (default 1e-4 x model size; "
                        "lines 1e-5 x size)")
    p.add_argument("--tolerance", type=float, default=None,
                   help="max node-to-CAD distance (default 1e-4 x model size); farther nodes stop the run (exit 1)")
    p.add_argument("--no-png", action="store_true", help="skip the PNG (large meshes)")
    p.add_argument("--view", default=None, metavar="ELEV,AZIM", help="PNG view angles in degrees (default 28,-58)")
    p.add_argument("--zoom", default=None, metavar="X0,X1,Y0,Y1,Z0,Z1",
                   help="PNG shows only this model-space box (e.g. a die radius)")
    p.set_defaults(func=cmd_map)
