"""The first `cadbridge ushape` of a fresh clone, before and after a change (issue 35, item 3).

Clones this repository twice (``--before`` and ``--after``, commits or branches) into a
temporary folder and runs each clone as the README's install leaves it: the clone on
``PYTHONPATH`` of this interpreter (what `pip install -e` amounts to: the dependencies are
this virtual environment's), no numba cache and no bytecode (every ``__pycache__`` removed
before each repeat). Per repeat, side by side:

- before: `cadbridge ushape -o OUT` (cold: it compiles the kernels), then once more (warm);
- after:  `cadbridge warmup` (the README's install step: what it adds to the install), then
  `cadbridge ushape -o OUT` (the acceptance: at most 15 s), then once more (warm).

Wall and CPU time (user + system of the child, `resource.getrusage`) of every command, and
whether a run compiled (the "compiling numerical kernels" notice of `cadbridge.common.jit`).
``--kernels`` also times every compile of a cold `cadbridge ushape` of each clone (numba's
compile events: kernel, argument types, seconds excluding the kernels compiled inside it) in
a fresh NUMBA_CACHE_DIR, and prints the per-kernel table.

    python benchmarks/cold_start.py --before main --after cold --repeat 2 --kernels
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NOTICE = "compiling numerical kernels"

_PROFILER = r"""
import json, sys, time
from numba.core import event

rows, stack = [], []

class Timer(event.Listener):
    def on_start(self, ev):
        stack.append([time.perf_counter(), 0.0])

    def on_end(self, ev):
        t0, inner = stack.pop()
        dt = time.perf_counter() - t0
        if stack:
            stack[-1][1] += dt
        f = ev.data["dispatcher"].py_func
        rows.append([f"{f.__module__}.{f.__qualname__}", repr(tuple(ev.data["args"])), dt - inner, len(stack)])

event.register("numba:compile", Timer())
from cadbridge.cli import main

rc = main(["--quiet", "ushape", "-o", sys.argv[2]])
with open(sys.argv[1], "w") as f:
    json.dump(rows, f)
sys.exit(rc)
"""


def clone(ref: str, dest: Path) -> str:
    subprocess.run(["git", "clone", "--quiet", str(ROOT), str(dest)], check=True)
    subprocess.run(["git", "-C", str(dest), "checkout", "--quiet", ref], check=True)
    return subprocess.run(["git", "-C", str(dest), "rev-parse", "--short", "HEAD"], check=True, capture_output=True,
                          text=True).stdout.strip()


def wipe(tree: Path) -> None:
    """A fresh clone's state: no __pycache__ (numba's cache files and bytecode) anywhere."""
    for d in list(tree.rglob("__pycache__")):
        shutil.rmtree(d, ignore_errors=True)


def timed(cmd: list[str], env: dict) -> tuple[float, float, int, str]:
    """(wall s, CPU s, exit code, stderr) of one child process, run in the tree of
    ``env["PYTHONPATH"]`` (`python -m` puts the working directory first on sys.path)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    run = subprocess.run(cmd, env=env, cwd=env["PYTHONPATH"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                         text=True)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return wall, cpu, run.returncode, run.stderr


def env_for(tree: Path, cache: Path | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["PYTHONPATH"] = str(tree)
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    return env


def kernel_table(tree: Path, work: Path) -> tuple[list, float]:
    """Every compile of a cold `cadbridge ushape` of ``tree`` (fresh NUMBA_CACHE_DIR): rows
    (kernel, argument types, exclusive seconds, depth) and the run's CPU seconds."""
    out = work / "kernels.json"
    wall, cpu, rc, err = timed([sys.executable, "-c", _PROFILER, str(out), str(work / "ushape")],
                               env_for(tree, work / "cache"))
    if rc != 0:
        raise RuntimeError(f"ushape failed in {tree}: {err[-500:]}")
    return json.loads(out.read_text()), cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--before", default="main", help="commit or branch before the change (default: main)")
    ap.add_argument("--after", default="HEAD", help="commit or branch after the change (default: HEAD)")
    ap.add_argument("--repeat", type=int, default=2, help="fresh-clone repeats (default 2)")
    ap.add_argument("--kernels", action="store_true", help="also the per-kernel compile table of each clone")
    a = ap.parse_args()
    py = [sys.executable, "-m", "cadbridge"]
    lines = [f"load average at start: {' '.join(f'{x:.2f}' for x in os.getloadavg())}"]
    with tempfile.TemporaryDirectory(prefix="cadbridge-cold-") as tmp:
        tmp = Path(tmp)
        trees = {"before": tmp / "before", "after": tmp / "after"}
        refs = {k: clone(ref, trees[k]) for k, ref in (("before", a.before), ("after", a.after))}
        for k, tree in trees.items():  # the package each run imports is the clone's
            where = subprocess.run([sys.executable, "-c", "import cadbridge; print(cadbridge.__file__)"],
                                   env=env_for(tree), cwd=tree, capture_output=True, text=True, check=True).stdout
            if not Path(where.strip()).is_relative_to(tree):
                raise RuntimeError(f"{k}: cadbridge imported from {where.strip()}, not from {tree}")
        lines.append(f"before = {a.before} ({refs['before']}), after = {a.after} ({refs['after']}); python "
                     f"{sys.version.split()[0]}, {os.cpu_count()} cores")
        rows = []
        for r in range(a.repeat):
            for k in ("before", "after"):
                wipe(trees[k])
                env = env_for(trees[k])
                out = tmp / f"out_{k}"
                steps = ([("cadbridge warmup", py + ["warmup"])] if k == "after" else []) + [
                    ("cadbridge ushape (first)", py + ["ushape", "-o", str(out)]),
                    ("cadbridge ushape (again)", py + ["ushape", "-o", str(out)])]
                for name, cmd in steps:
                    wall, cpu, rc, err = timed(cmd, env)
                    rows.append((r + 1, k, name, wall, cpu, rc, NOTICE in err))
                    print(f"repeat {r + 1} {k}: {name}: {wall:.1f} s wall, {cpu:.1f} s CPU, exit {rc}, "
                          f"compiled {NOTICE in err}", file=sys.stderr, flush=True)
        lines += ["", "| repeat | tree | command | wall [s] | CPU [s] | exit | compiled |", "|---|---|---|---:|---:|---|---|"]
        lines += [f"| {r} | {k} | `{n}` | {w:.1f} | {c:.1f} | {rc} | {'yes' if comp else 'no'} |"
                  for r, k, n, w, c, rc, comp in rows]
        if a.kernels:
            for k in ("before", "after"):
                wipe(trees[k])
                work = tmp / f"kernels_{k}"
                work.mkdir()
                krows, cpu = kernel_table(trees[k], work)
                agg: dict[str, list] = defaultdict(lambda: [0, 0.0, 0])
                for name, _, excl, depth in krows:
                    agg[name][0] += 1
                    agg[name][1] += excl
                    agg[name][2] += depth == 0
                lines += ["", f"### compiles of a cold `cadbridge ushape`, {k} ({refs[k]}): {len(krows)} compiles, "
                          f"{sum(x[2] for x in krows):.1f} s compiling (exclusive sums), run {cpu:.1f} s CPU", "",
                          "| kernel | specialisations | seconds (exclusive) | called from Python |", "|---|---:|---:|---:|"]
                for name, (n, s, top) in sorted(agg.items(), key=lambda kv: -kv[1][1]):
                    if s >= 0.1 or name.startswith("cadbridge."):
                        lines.append(f"| {name} | {n} | {s:.2f} | {top} |")
    lines.append(f"\nload average at end: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
