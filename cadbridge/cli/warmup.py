"""`cadbridge warmup`: compile the numba kernels of the main job (`cadbridge ushape`) and of a
first `convert` ahead of their first run, as the README's install command does.

The kernels are ``@numba.njit(cache=True)``: compiled on first use, then loaded from numba's
cache (``__pycache__`` next to the sources, or ``NUMBA_CACHE_DIR``). A fresh install has an
empty cache, so its first `cadbridge ushape` compiled for about 30 s of its 40 s. `warmup`
compiles the same kernels with the same argument types (`Dispatcher.compile` of the
signatures `cadbridge.cli.warmup_kernels.KERNELS` lists, recorded from a `cadbridge ushape`
on an empty cache), so numba saves the very cache entries the job looks up and the job then
compiles nothing. The kernels are compiled in ``--jobs`` processes at once (default 2), the
slowest first; a kernel compiled by one process is loaded, not compiled again, by the other.

A warm-up never fails an install: a listed kernel that is gone or takes other types now (a
stale list: the job compiles it on first use, as without a warm-up) is reported and skipped;
the exit code is 1 only if numba itself cannot compile (no listed kernel compiled, and
neither does a one-line function).
``cadbridge warmup --record`` re-records the list after kernels or their call sites change
(a cold `cadbridge ushape` in a temporary cache; the test `tests/cli/test_warmup.py` says when
the list no longer covers the job).
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from cadbridge.common.errors import EXIT_BAD_INPUT, EXIT_CHECK_FAILED, EXIT_OK
from cadbridge.common.progress import say

__all__ = ["compile_kernels", "parse_signature", "record_kernels"]

Entry = tuple[str, str, str, float]  # (module, function, argument types (repr), seconds when recorded)

LIST_FILE = Path(__file__).with_name("warmup_kernels.py")


def parse_signature(text: str) -> tuple:
    """The numba argument types of ``text``, the repr of a tuple of types as recorded
    (``"(Array(float64, 1, 'C', True, aligned=True), int64, bool)"``)."""
    from numba.core import types

    names = {k: getattr(types, k) for k in dir(types) if not k.startswith("_")}
    names["bool"] = types.boolean
    sig = eval(text, {"__builtins__": {}}, names)  # noqa: S307 - the package's own list, numba type names only
    return tuple(sig)


def _compile_one(entry: Entry) -> tuple[str, float, bool, str | None]:
    """Compile one listed kernel (in a worker process): (name, seconds, loaded from the cache,
    error line or None)."""
    module, name, sig, _ = entry
    t0 = time.perf_counter()
    try:
        disp = getattr(importlib.import_module(module), name)
        args = parse_signature(sig)
        disp.compile(args)
        cached = bool(disp.stats.cache_hits.get(args))
    except Exception as exc:  # noqa: BLE001 - reported, never fatal: the job compiles what is missing
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        return f"{module}.{name}", time.perf_counter() - t0, False, f"{type(exc).__name__}: {first}"[:200]
    return f"{module}.{name}", time.perf_counter() - t0, cached, None


def compile_kernels(entries: list[Entry], jobs: int = 2) -> list[tuple[str, float, bool, str | None]]:
    """`_compile_one` for every entry, slowest (as recorded) first, in ``jobs`` processes
    (1: in this process); the results in that order."""
    order = sorted(entries, key=lambda e: -e[3])
    if jobs <= 1 or len(order) <= 1:
        return [_compile_one(e) for e in order]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    # spawn: fresh interpreters (no fork of a process that may hold threads)
    with ProcessPoolExecutor(max_workers=jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        return list(pool.map(_compile_one, order))


def default_jobs() -> int:
    """Processes of a warm-up: 2, or fewer cores if that is what this process may use (more
    would mostly compile the kernels' shared callees twice)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(2, cores))


_RECORDER = r"""
import json, sys, time
from numba.core import event

rows, stack = [], []

class Recorder(event.Listener):
    def on_start(self, ev):
        stack.append(time.perf_counter())

    def on_end(self, ev):
        dt = time.perf_counter() - stack.pop()
        f = ev.data["dispatcher"].py_func
        if not stack and f.__module__.startswith("cadbridge."):  # called from Python, not from a kernel
            rows.append([f.__module__, f.__qualname__, repr(tuple(ev.data["args"])), round(dt, 2)])

event.register("numba:compile", Recorder())
from cadbridge.cli import main

rc = main(["--quiet", "ushape", "-o", sys.argv[2]])
for i, sample in enumerate(sys.argv[3:]):  # free meshes of trimmed CAD: kernels ushape does not call
    for element in ("tri", "quad"):
        rc = rc or main(["--quiet", "convert", sample, "-o", f"{sys.argv[2]}_{i}_{element}", "--element", element])
with open(sys.argv[1], "w") as f:
    json.dump(rows, f)
sys.exit(rc)
"""

RECORDED_SAMPLES = ("trimmed_hole.igs", "torus_patch.igs", "cone_apex.igs", "multiple_knots.igs")
"""Samples of ``iges_samples/`` converted (tri and quad) after the ushape when the list is
recorded: a first `convert` of real CAD after the warm-up compiled for 8-12 s more
(OCC131-2 tri: 25.0 s, then 4.5 s warm), as free meshes of trimmed faces, poles and C0 knot
lines call kernels and argument types the structured U-shape does not."""


def record_kernels() -> list[Entry]:
    """The kernels a `cadbridge ushape`, then tri and quad converts of `RECORDED_SAMPLES`,
    compile when called from Python (those compile the kernels they call) with their argument
    types and compile seconds: one cold run in a temporary, empty NUMBA_CACHE_DIR, in a
    subprocess. Raises RuntimeError if the run fails
    or a type does not read back (`parse_signature`) as recorded."""
    with tempfile.TemporaryDirectory(prefix="cadbridge-record-") as tmp:
        out = Path(tmp) / "kernels.json"
        env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "cache"))
        samples = Path(__file__).resolve().parents[2] / "iges_samples"
        run = subprocess.run([sys.executable, "-c", _RECORDER, str(out), str(Path(tmp) / "ushape"),
                              *[str(samples / n) for n in RECORDED_SAMPLES if (samples / n).is_file()]], env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        if run.returncode != 0 or not out.exists():
            raise RuntimeError(f"cadbridge ushape failed (exit {run.returncode}): {run.stderr.strip()[-500:]}")
        rows = json.loads(out.read_text())
    entries = []
    for module, name, sig, seconds in rows:
        if repr(parse_signature(sig)) != sig:
            raise RuntimeError(f"{module}.{name}: argument types {sig} do not read back")
        entries.append((module, name, sig, float(seconds)))
    return entries


def write_list(entries: list[Entry], path: Path = LIST_FILE) -> None:
    """Write ``entries`` as the module `cadbridge.cli.warmup_kernels`."""
    lines = ['"""The kernels a `cadbridge ushape` and converts of the samples `RECORDED_SAMPLES` compile on an',
             "empty cache, called from Python (they compile the kernels they call), with their argument",
             "types: what `cadbridge warmup` compiles.",
             "",
             "Written by `cadbridge warmup --record` (do not edit): (module, function, argument types,",
             'compile seconds of that recording)."""', "", "KERNELS = ("]
    lines += [f"    ({m!r}, {n!r},\n     {s!r},\n     {t!r})," for m, n, s, t in entries]
    lines += [")", ""]
    path.write_text("\n".join(lines))


def cmd_warmup(args: argparse.Namespace) -> int:
    if args.record:
        entries = record_kernels()
        write_list(entries)
        say(f"recorded {len(entries)} kernels ({sum(e[3] for e in entries):.1f} s of compiling) to {LIST_FILE}")
        return EXIT_OK
    from cadbridge.cli.warmup_kernels import KERNELS

    jobs = args.jobs if args.jobs is not None else default_jobs()
    if jobs < 1:
        print(f"cadbridge warmup: error: --jobs must be >= 1, got {jobs}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if not args.quiet:
        print(f"cadbridge warmup: compiling {len(KERNELS)} numerical kernels in {jobs} process"
              f"{'es' if jobs > 1 else ''} (once per install)", file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    results = compile_kernels(list(KERNELS), jobs)
    failed = [(name, err) for name, _, _, err in results if err]
    for name, err in failed:
        print(f"cadbridge warmup: warning: {name} not compiled ({err}); the first run compiles it", file=sys.stderr)
    cached = sum(1 for r in results if r[2] and not r[3])
    done = len(results) - len(failed)
    say(f"compiled {done - cached} kernels ({cached} already in the cache, {len(failed)} failed) in "
        f"{time.perf_counter() - t0:.1f} s")
    if results and done == 0 and not _numba_compiles():
        print("cadbridge warmup: error: numba cannot compile here (a one-line function failed too)", file=sys.stderr)
        return EXIT_CHECK_FAILED
    return EXIT_OK


def _numba_compiles() -> bool:
    """Whether numba compiles at all in this process (a stale list fails every entry, a broken
    numba fails this too)."""
    try:
        import numba

        return numba.njit(lambda x: x + 1)(1) == 2
    except Exception:  # noqa: BLE001 - any failure means: it does not
        return False


def register(sub, fmt) -> None:
    p = sub.add_parser("warmup", help="compile the numerical kernels ahead of the first run (the README's install)",
                       formatter_class=fmt, description=__doc__.split("\n\n")[0],
                       epilog="example:\n  cadbridge warmup            # after `pip install`: the first run is then warm")
    p.add_argument("--jobs", type=int, default=None, help="processes compiling at once (default: 2, or the cores "
                                                          "available if fewer)")
    p.add_argument("--record", action="store_true",
                   help="developers: re-record the kernel list (a cold `cadbridge ushape` in a temporary cache)")
    p.set_defaults(func=cmd_warmup)
