"""IGES read benchmark (a script, not a test): ``cadbridge.read_iges`` against OpenCASCADE's
``IGESControl_Reader.ReadFile`` + ``TransferRoots`` + ``OneShape`` on every file of
``../shared/iges_real`` and ``iges_samples/production_die_{nurbs,analytic}.igs`` (plus any ``--file``),
best of ``--repeat`` for each, measured in the same run and reported as ratios (OCC time /
cadbridge time; >= 1 means cadbridge reads at least as fast). The two readers are timed
alternately (one cadbridge read, one OCC read, ``--repeat`` times), so a change of load on a
shared machine hits both; ``--rounds R`` repeats that R times and also reports the lowest and
highest per-round ratio (how stable the ratio is), the times being the best over all rounds.

    python benchmarks/bench_read.py [--repeat 3] [--rounds 1] [--file PATH ...] [--only SUBSTRING ...]
                                    [--profile FILE_SUBSTRING]

cadbridge is warmed up once per file before timing (numba kernels compiled and cached, imports
done), so compile time does not count; OCC is warmed up the same way. Faces, trimmed faces and
the largest per-face trim delta (the file's own 2D/3D trim disagreement, ``Face.trim_delta``)
are printed alongside. Most deltas are not computed by the read (`Face.trim_delta` is filled
in for all faces on its first access): the "delta ms" column times that first access on a
fresh model (best of ``--repeat``), outside the read time. The table is also written to
``benchmarks/results/read.md``.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import sys
import time
from pathlib import Path

from cadbridge.iges import read_iges

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_kernel import occ_read  # noqa: E402  (shared helpers of the benchmarks)

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "iges_real"
if not REAL.is_dir():
    REAL = Path("/work/shared/iges_real")
SAMPLES = ROOT / "iges_samples"


def files(extra: list[str]) -> list[Path]:
    out = sorted(REAL.glob("*.ig*")) if REAL.is_dir() else []
    for mode in ("nurbs", "analytic"):  # both modes of the generated die (git-ignored; `make_samples.py`)
        die = SAMPLES / f"production_die_{mode}.igs"
        if die.exists():
            out.append(die)
    return out + [Path(p) for p in extra]


def delta_time(path: Path, repeat: int) -> float:
    """Best time of the first `Face.trim_delta` access (all faces' deltas in one pass)."""
    best = float("inf")
    for _ in range(repeat):
        m = read_iges(path)
        t0 = time.perf_counter()
        if m.faces:
            m.faces[0].trim_delta
        best = min(best, time.perf_counter() - t0)
    return best


def interleaved_best(fns, repeat: int) -> list[float]:
    """Best time of each function, timed in turn (fn 0, fn 1, ..., ``repeat`` times)."""
    best = [float("inf")] * len(fns)
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            t0 = time.perf_counter()
            fn()
            best[k] = min(best[k], time.perf_counter() - t0)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=1, help="repeat the timing; report the per-round ratio range")
    ap.add_argument("--profile", default=None, help="cProfile cadbridge's read of the file matching this")
    ap.add_argument("--file", action="append", default=[], help="another IGES file to measure")
    ap.add_argument("--only", action="append", default=[],
                    help="measure only files whose name contains this (repeatable); results/read.md is not written")
    args = ap.parse_args()
    rows = []
    for path in files(args.file):
        if args.only and not any(s in path.name for s in args.only):
            continue
        m = read_iges(path)  # warm-up: imports, numba compile / cache load
        occ_read(path)
        if args.profile and args.profile in path.name:
            pr = cProfile.Profile()
            pr.enable()
            read_iges(path)
            pr.disable()
            pstats.Stats(pr).sort_stats("cumulative").print_stats(30)
        rounds = [interleaved_best([lambda: read_iges(path), lambda: occ_read(path)], args.repeat)
                  for _ in range(max(1, args.rounds))]
        t_cb, t_occ = min(r[0] for r in rounds), min(r[1] for r in rounds)
        ratios = [o / c for c, o in rounds]
        t_delta = delta_time(path, args.repeat)
        deltas = [f.trim_delta for f in m.faces if getattr(f, "trim_delta", None) is not None]
        rows.append(dict(name=path.name, kb=path.stat().st_size / 1024, faces=len(m.faces),
                         trimmed=sum(f.trims is not None for f in m.faces), cb=t_cb, occ=t_occ,
                         lo=min(ratios), hi=max(ratios), delta=max(deltas) if deltas else None, t_delta=t_delta))
        r = rows[-1]
        print(f"{r['name']:45s} {r['faces']:4d} faces  cadbridge {t_cb * 1e3:8.1f} ms  "
              f"OCC {t_occ * 1e3:8.1f} ms  ratio {t_occ / t_cb:5.2f} (rounds {r['lo']:.2f}-{r['hi']:.2f})  "
              f"(deltas {t_delta * 1e3:.1f} ms)", flush=True)
    lines = ["| file | KB | faces | trimmed | max trim delta | cadbridge ms | OCC ReadFile+TransferRoots ms | ratio "
             "| ratio range (rounds) | delta ms (first access) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        d = "" if r["delta"] is None else f"{r['delta']:.2e}"
        lines.append(f"| {r['name']} | {r['kb']:.0f} | {r['faces']} | {r['trimmed']} | {d} | {r['cb'] * 1e3:.1f} | "
                     f"{r['occ'] * 1e3:.1f} | {r['occ'] / r['cb']:.2f} | {r['lo']:.2f}-{r['hi']:.2f} | "
                     f"{r['t_delta'] * 1e3:.1f} |")
    text = "\n".join(lines)
    print("\n" + text)
    if args.only:
        return
    out = ROOT / "benchmarks" / "results"
    out.mkdir(exist_ok=True)
    (out / "read.md").write_text(f"Best of {args.repeat} x {max(1, args.rounds)} rounds, cadbridge and OCC timed "
                                 f"alternately, one run (`python benchmarks/bench_read.py --repeat {args.repeat} "
                                 f"--rounds {max(1, args.rounds)}`).\n\n" + text + "\n")


if __name__ == "__main__":
    main()
