"""Edge rule benchmark (a script, not a test): the shape error of the bounded and the published
edge rule (`cadbridge.nagata.edge`) on the samples and a handful of corpus files.

Runs ``cadbridge convert FILE -o OUT --element quad|tri`` (default settings otherwise, the
default edge rule) on every sample of ``iges_samples/`` (the production dies left out) and on
the corpus files of `CORPUS` (``../shared/cad_corpus``, read in place), each in its own
subprocess with a time limit, and takes from convert's summary the line
"shape err by edge rule": per tool the max shape error (the larger of |surface error| and the
boundary error at each sample of the error grid, `cadbridge.tool.build.rule_shape_errors`) of
both rules, measured on the same samples. Writes ``benchmarks/results/edge_rule.md``.

    python benchmarks/edge_rule.py [--timeout 240] [--modes quad tri] [--out benchmarks/results/edge_rule.md]

Columns: file, mode, tool, nodes, shape error bounded / published (the file's units), their
ratio published / bounded, the flat mesh's surface error (the "flat err" column) for scale,
and the largest edge coefficient difference between the rules over the model size (both
rebuilt from the written tool file).
One core: runs one after another (OMP/numba threads limited to 1).
"""

from __future__ import annotations

import argparse
import datetime
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "cad_corpus"
CORPUS = (  # converted and sound in benchmarks/results/corpus.md, a few seconds each
    "iges/occt_OCC131-3_ANSA9.igs",
    "iges/occt_OCC131-6_ANSA9.igs",
    "iges/occt_OCC8842_cylinder_CATIA_CATIAV5.igs",
    "iges/occt_PRO20359-L12_CATIAV4.igs",
    "iges/occt_PRO20360-T2_CATIAV4.igs",
    "iges/occt_bug23171_tube_surf_OpenCASCADE.igs",
    "step/OCC26308-Face.stp",
    "step/bug24283_spheres.stp",
    "step/occ23010.step",
    "step/trj2_io1-in-203.stp",
)
RULE_LINE = re.compile(r"^  (?P<tool>.+): shape err by edge rule: (?P<rest>.+)$")


def inputs() -> list[Path]:
    files = sorted(p for p in (ROOT / "iges_samples").glob("*.igs") if not p.name.startswith("production_die"))
    return files + [SHARED / f for f in CORPUS if (SHARED / f).is_file()]


def convert(cad: Path, mode: str, out: Path, timeout: float) -> tuple[str, str, float]:
    """(status, stdout, seconds) of one `cadbridge convert` run in its own process group."""
    env = dict(os.environ, OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1")
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "cadbridge", "--quiet", "convert", str(cad), "-o", str(out),
                             "--element", mode], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        return "timeout", "", time.perf_counter() - t0
    dt = time.perf_counter() - t0
    if proc.returncode != 0:
        return f"exit {proc.returncode}: {(stderr.strip().splitlines() or [''])[-1][:120]}", stdout, dt
    return "converted", stdout, dt


def coefficient_gap(toolfile: Path) -> float:
    """max |c_published - c_bounded| / model size over the edge coefficients of the tool file
    (both rebuilt from its nodes and normals; model size = node bounding box diagonal)."""
    import numpy as np

    from cadbridge.io.toolfile import read_toolfile

    td = read_toolfile(toolfile)
    td.edge_rule = "bounded"
    b = td.nagata_mesh()
    td.edge_rule = "published"
    p = td.nagata_mesh()
    gap = max(float(np.max(np.abs(p.tri_edge_coefficients - b.tri_edge_coefficients), initial=0.0)),
              float(np.max(np.abs(p.quad_edge_coefficients - b.quad_edge_coefficients), initial=0.0)))
    return gap / float(np.linalg.norm(td.nodes.max(axis=0) - td.nodes.min(axis=0)))


def rows_of(stdout: str, out: Path) -> list[dict]:
    """Per tool: nodes, flat err (from the table), the shape error of each rule and the
    coefficient gap (`coefficient_gap`)."""
    rows = []
    for ln in stdout.splitlines():
        m = RULE_LINE.match(ln)
        if m:
            errs = {}
            for part in m["rest"].split(", "):
                w = part.split()
                errs[w[0]] = float(w[1])
            rows.append({"tool": m["tool"], "nodes": 0, "flat": float("nan"), **errs})
    for r in rows:  # the summary table: name (may hold blanks), source, nodes, elems, surface, boundary, flat, normal
        for ln in stdout.splitlines():
            f = ln[2 + len(r["tool"]):].split() if ln.startswith("  " + r["tool"] + " ") else []
            if len(f) == 7 and f[1].isdigit():
                r["nodes"], r["flat"] = int(f[1]), float(f[5])
        path = out / f"{r['tool']}.nagata"
        r["gap"] = coefficient_gap(path) if path.is_file() else float("nan")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--timeout", type=float, default=240.0)
    ap.add_argument("--modes", nargs="+", default=["quad", "tri"])
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "edge_rule.md")
    args = ap.parse_args()
    t_all = time.perf_counter()
    lines, ratios, failed, gaps = [], [], [], []
    with tempfile.TemporaryDirectory(prefix="edge_rule_") as tmp:
        for cad in inputs():
            name = str(cad.relative_to(ROOT)) if cad.is_relative_to(ROOT) else "cad_corpus/" + str(cad.relative_to(SHARED))
            for mode in args.modes:
                status, stdout, dt = convert(cad, mode, Path(tmp) / f"{cad.stem}_{mode}", args.timeout)
                print(f"{name} {mode}: {status} ({dt:.1f} s)", file=sys.stderr, flush=True)
                rows = rows_of(stdout, Path(tmp) / f"{cad.stem}_{mode}") if status == "converted" else []
                if not rows:
                    failed.append(f"| {name} | {mode} | {status} |")
                    continue
                for r in rows:
                    b, p = r["bounded"], r["published"]
                    ratio = p / b if b > 0 else (1.0 if p == 0 else float("inf"))
                    ratios.append((ratio, name, mode, r["tool"], b, p))
                    lines.append(f"| {name} | {mode} | {r['tool']} | {r['nodes']} | {b:.3e} | {p:.3e} | {ratio:.3g} | "
                                 f"{r['flat']:.3e} | {r['gap']:.2e} |")
                    gaps.append(r["gap"])
    worse = sum(1 for r in ratios if r[0] > 1.0 + 1e-9)
    better = sum(1 for r in ratios if r[0] < 1.0 - 1e-9)
    same = len(ratios) - worse - better
    finite = sorted(r[0] for r in ratios if r[0] != float("inf"))
    median = finite[len(finite) // 2] if finite else float("nan")
    top = max(ratios, default=None)
    best = min(ratios, default=None)
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                            text=True).stdout.strip()
    text = [
        "# Edge rule: bounded vs published (Nagata 2005) shape error",
        "",
        f"`python benchmarks/edge_rule.py` at {commit}, {datetime.date.today().isoformat()}, "
        f"{time.perf_counter() - t_all:.0f} s on 1 core. `cadbridge convert FILE --element MODE` with default "
        "settings; per tool the max shape error (larger of |surface error| and boundary error at each sample of "
        "the error grid, in the file's units) of the tool under each edge rule, on the same mesh, normals and "
        "samples. Flat: the flat mesh's max |surface error| (the summary's \"flat err\"; surface only, no boundary "
        "error), for scale. max dc / size: the largest difference of an edge coefficient between the rules, "
        f"|c_published - c_bounded| / model size (largest here {max(gaps, default=float('nan')):.2e}).",
        "",
        f"**{len(ratios)} tools: published worse than bounded on {worse}, better on {better}, equal on {same}; "
        f"median ratio published / bounded {median:.3g}"
        + (f"; largest {top[0]:.3g} ({top[1]} {top[2]}, {top[3]}: {top[4]:.3e} -> {top[5]:.3e})" if top else "")
        + (f"; smallest {best[0]:.3g} ({best[1]} {best[2]}, {best[3]}: {best[4]:.3e} -> {best[5]:.3e})" if best else "")
        + ".**",
        "",
        "| file | mode | tool | nodes | bounded | published | published / bounded | flat | max dc / size |",
        "|---|---|---|---|---|---|---|---|---|",
        *lines,
    ]
    if failed:
        text += ["", "Not converted (no numbers):", "", "| file | mode | status |", "|---|---|---|", *failed]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(text) + "\n")
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
