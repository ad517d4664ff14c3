"""Damaged IGES files through `cadbridge convert`: converted or refused cleanly, never an
internal error, a hang or a NaN (issue 32's mutants acceptance).

Reference: `benchmarks/mutants.py`'s classification of each run (its docstring): exit 0 with
finite outputs, or exit 1 / 2 with exactly one line on stderr that names no internal
exception class and leaves nothing written; each run in its own subprocess with a time limit.

The default run converts a handful of mutants of small sample files, among them the damage
that ended in an IndexError (loop_excursions: a hole small against a model one damaged
number made large), the one gmsh meshed without end (a quarter cylinder's pole moved 10^6
times farther) and the one whose trim loop wound 10^6 turns about a 120's axis. The full harness (seven files, every damage kind) is slow-marked.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SAMPLES = ROOT / "iges_samples"
TIMEOUT = 60.0  # s per run, the acceptance's limit


def _harness():
    spec = importlib.util.spec_from_file_location("bench_mutants", ROOT / "benchmarks" / "mutants.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


M = _harness()

# (sample file, damage kind, index, seed): what each was before the fixes
FAST = [
    ("trimmed_hole.igs", "scale_number", 0, 1),  # IndexError in loop_excursions
    ("rational_quarter_cylinder.igs", "scale_number", 0, 2),  # gmsh's surface mesher never returned
    ("ushape_tools_analytic.igs", "scale_number", 1, 1),  # a trim loop wound 10^6 turns: endless refinement
    ("trimmed_hole.igs", "garbage_field", 0, 1),
    ("sphere_patch.igs", "digit_p", 0, 1),
    ("torus_patch.igs", "crlf", 0, 1),
]


@pytest.mark.parametrize("name, kind, index, seed", FAST, ids=[f"{n}-{k}-{i}-{s}" for n, k, i, s in FAST])
def test_fast_mutant_ends_cleanly(name, kind, index, seed, tmp_path):
    m = M.mutate(SAMPLES / name, kind, index, seed)
    r = M.run_mutant(m, tmp_path, TIMEOUT)
    assert r.clean, f"{m.damage}: {r.status}: {r.line}"


def test_classification_catches_internal_errors(tmp_path):
    """The harness itself: a traceback, an exception class name, two lines, a timeout and a
    leftover output folder are not clean refusals."""
    out = tmp_path / "none"
    assert M.classify(2, "cadbridge convert: error: bad.igs line 3: expected a real\n", out, 60)[0] == "refused"
    assert M.classify(2, "cadbridge convert: error: IndexError: index 3 (at x.py:1; CADBRIDGE_DEBUG=1 ...)\n",
                      out, 60)[0] == "internal error"
    assert M.classify(1, "Traceback (most recent call last):\n  File ...\nValueError: x\n", out, 60)[0] == \
        "internal error"
    assert M.classify(2, "line one\nline two\n", out, 60)[0] == "internal error"
    assert M.classify(None, "", out, 60)[0] == "timeout"
    assert M.classify(-11, "", out, 60)[0] == "internal error"
    out.mkdir()
    (out / "half.nagata").write_text("nan\n")
    assert M.classify(2, "cadbridge convert: error: refused\n", out, 60)[0] == "internal error"
    assert M.classify(0, "", out, 60)[0] == "nan"


def test_mutants_are_deterministic():
    for kind in M.KINDS:
        a, b = M.mutate(SAMPLES / "trimmed_hole.igs", kind, 0, 1), M.mutate(SAMPLES / "trimmed_hole.igs", kind, 0, 1)
        assert a.text == b.text and a.damage == b.damage
        assert a.text != (SAMPLES / "trimmed_hole.igs").read_text()


@pytest.mark.slow
def test_full_harness_no_internal_error(tmp_path):
    """benchmarks/mutants.py with its defaults (seven files, two mutants per damage kind):
    every run clean, and at least 42 mutants still read."""
    files = [f for f in M.DEFAULT_FILES if f.is_file()]
    if len(files) < len(M.DEFAULT_FILES):
        pytest.skip("../shared corpus files absent")
    rc = M.main(["--out", str(tmp_path / "mutants.md"), "--timeout", str(TIMEOUT)])
    text = (tmp_path / "mutants.md").read_text()
    assert rc == 0, [ln for ln in text.splitlines() if "| internal error |" in ln or "| timeout |" in ln
                     or "| nan |" in ln]
    readable = next(ln for ln in text.splitlines() if ln.startswith("| readable |"))
    assert int(readable.split("|")[2]) >= 42, readable
