"""The 1 M-point scan fit (bench_fit.py's scale case) of this tree against an earlier revision,
measured in the same session, runs interleaved (A B A B ...) so that both see the same load.

Each run is a fresh subprocess: the revision's `cadbridge` (exported with `git archive` into a
temporary directory, its own numba cache) or this tree's; it builds the same synthetic U-shape
die scan (sigma 0.01 mm, 2 % outliers up to 1 mm, a 20 mm hole, seed 0) with this tree's
`tests/helpers/scans.die_scan`, warms up on 120 000 points (kernels compiled or loaded from the
cache, the large-input path included), then times `fit_points(..., base=die, tolerance=0.01,
trim=True)` and reports wall and CPU seconds, the peak RSS over the RSS before the fit, and the
fit's distance to the die CAD.

    python benchmarks/bench_fit_ab.py --rev 240b474 --runs 2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys
from pathlib import Path
sys.path.insert(0, sys.argv[1])                    # the cadbridge under test
sys.path.insert(1, str(Path(sys.argv[2]) / "benchmarks"))
import cadbridge
assert Path(cadbridge.__file__).resolve().is_relative_to(Path(sys.argv[1]).resolve()), cadbridge.__file__
sys.path.insert(0, sys.argv[2])                    # die_scan of this tree (cadbridge is imported already)
from tests.helpers.scans import die_scan
from bench_fit import cad_error, timed_scale_fit
from cadbridge.fitting.surface_fit import fit_points
n = int(sys.argv[3])
model, _, x, _ = die_scan(n)
fit_points(x[:120000], base=model, tolerance=0.01)
rep, m = timed_scale_fit(model, x)
f = rep.fit
print(json.dumps(dict(wall=m["wall"], cpu=m["cpu"], load0=m["load0"], load1=m["load1"], peak_over=m["peak_over"],
                      net=list(f.surface.shape), stop=f.stop, rms=f.rms, outliers=int(f.outliers.sum()),
                      cad=cad_error(rep, model))))
"""


def run(root: Path, n: int) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(root), str(ROOT), str(n)], capture_output=True,
                         text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"run in {root} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rev", required=True, help="git revision to compare against (e.g. 240b474)")
    ap.add_argument("--runs", type=int, default=2, help="runs of each (default 2)")
    ap.add_argument("--points", type=int, default=1000000)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="cadbridge-ab-") as tmp:
        old = Path(tmp)
        arch = subprocess.run(["git", "-C", str(ROOT), "archive", a.rev, "cadbridge"], capture_output=True,
                              check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(old)], input=arch, check=True)
        print(f"{a.points} points; A = revision {a.rev}, B = this tree; {os.cpu_count()} cores", flush=True)
        res = {"A": [], "B": []}
        for k in range(a.runs):
            for name, root in (("A", old), ("B", ROOT)):
                r = run(root, a.points)
                res[name].append(r)
                print(f"  {name} run {k + 1}: {r['wall']:.1f} s wall, {r['cpu']:.1f} s CPU, load {r['load0']:.1f}"
                      f" -> {r['load1']:.1f}, peak +{r['peak_over']:.0f} MB, net {r['net']}, stop {r['stop']}, "
                      f"RMS {r['rms']:.6f}, outliers {r['outliers']}, fit vs CAD {r['cad']:.4f} mm", flush=True)
        wa = sorted(r["wall"] for r in res["A"])
        wb = sorted(r["wall"] for r in res["B"])
        ca = sorted(r["cpu"] for r in res["A"])
        cb = sorted(r["cpu"] for r in res["B"])
        med = lambda s: s[len(s) // 2]  # noqa: E731
        print(f"median wall A {med(wa):.1f} s, B {med(wb):.1f} s: B is {med(wa) / med(wb):.2f}x faster; "
              f"median CPU A {med(ca):.1f} s, B {med(cb):.1f} s: {med(ca) / med(cb):.2f}x less")


if __name__ == "__main__":
    main()
