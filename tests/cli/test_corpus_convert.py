"""Every IGES and STEP file of the OCCT corpus (../shared/cad_corpus/iges and step; skipped
when absent) through `cadbridge convert`, in quad and tri mode (issues "Every real CAD file
converts" and "STEP input").

Reference, per file and mode: ``cadbridge -q convert FILE -o OUT --element MODE`` run as a
subprocess exits 0 and its tool files are sound against OpenCASCADE
(`cadbridge.verify.soundness.tool_soundness`: sampled nodes on OCC's trimmed faces, node
normals at interior nodes equal to OCC's face normals, Nagata patch centres no farther from
OCC's faces than the flat element centres; its docstring says how each is measured). The
files the corpus README marks "expected: clear refusal" must instead exit 2 with one line on
stderr (the CLI's known-error line, not its "unanticipated error" form) and write nothing.
`benchmarks/corpus.py` makes the same measurement into benchmarks/results/corpus.md.

The default run converts a fast subset: three small files that convert today (two IGES, one
STEP) and one expected refusal. The whole corpus is slow-marked (``-m slow``), one case per file and mode. Many
files fail today. They are not skipped: `KNOWN_FAILURES` lists each failing (file, mode) with
its current failure line (from benchmarks/results/corpus.md), and those cases are marked
``xfail(strict=True)`` with that line as the reason. A fix turns the case into XPASS, which
strict makes a failure: then delete the row from the table.
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CORPUS = ROOT.parent / "shared" / "cad_corpus" / "iges"
CORPUS_STEP = CORPUS.parent / "step"
MODES = ("quad", "tri")
TIMEOUT = 600  # s per convert: a limit against hangs, far above any file's time today

pytestmark = pytest.mark.skipif(not CORPUS.is_dir(), reason="shared/cad_corpus not present")


def _benchmark():
    """benchmarks/corpus.py as a module (it parses the README's expected refusals)."""
    spec = importlib.util.spec_from_file_location("bench_corpus", ROOT / "benchmarks" / "corpus.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


_BENCH = _benchmark()
EXPECTED_REFUSALS = _BENCH.expected_refusals()
REFUSE_OR_SOUND = _BENCH.REFUSE_OR_SOUND  # the acceptance: refused, or converted soundly

FAST = ["occt_PRO20358-W11_CATIAV4.igs", "occt_PRO20359-L15_CATIAV4.igs", "occ23010.step"]
FAST_REFUSAL = "occt_Disc_HPME.igs"

# (file, mode): the current failure line, as benchmarks/results/corpus.md gives it (2026-12-06 20:47,
# 7e342de, gmsh on the model's own B-rep).
# Not here, though the benchmark's 60 s limit stopped them: occt_bug22869_Inventor2011_Spring.igs
# quad, occt_PRO20358-X28_CATIAV4.igs quad (72 s beside other jobs, 39 s alone) and
# occt_PRO20359-L2_CATIAV4.igs quad convert soundly within this test's limit.
KNOWN_FAILURES: dict[tuple[str, str], str] = {
    # STEP: meshing failures (gmsh on periodic and cusp faces); the timeouts are the
    # benchmark's 60 s (docs/step.md). b1 (trj6) and b2 timed out in reading until
    # 2026-12-06 19:40 (the loop searches); their lines are from
    # `python benchmarks/corpus.py --only trj10_b2 trj6_b1` then. (OCC131-1 converts soundly
    # since the check reads it as its PREF says, the fuselage since a crease fading below the
    # crease angle along its knot line is no straddle: 2026-12-07.)
    # (2026-12-07: 16 nodes off, thin horns and arms of filled faces; tri converts soundly since
    # notches are cut only within the CAD's accuracy)
    ('trj10_b2-oc-214.stp', 'quad'):
        'failed: exit 1: 16 of 21920 mesh nodes are further than 0.0206 from the CAD (or could not be projected): node 20306 at (-21.8214, -11.6503, 61) distance 1.26331, node 11225 at (21.0541, 38.266, 40) ',
    ('trj4_s1-ai-214.stp', 'quad'):
        'refused: /tmp/cadbridge-mesh-ojs4u9la/trj4_s1-ai-214.brep: gmsh surface 11 (Plane): its boundary crosses itself in (u, v) (after cutting the cusp strips narrower than 1.94); cannot mesh it in paramete',
    # (2026-12-06 19:20: gmsh's pole triangles with a repeated node are dropped now; the
    # refinement then stops on the assembly's touching parts, 68 s alone)
    ('trj4_s1-ai-214.stp', 'tri'):
        "failed: exit 1: nauo_name_3: Nagata surface error 1.12 exceeds the flat mesh's 0.607 on 6 elements; worst: element 2554 (1.12 vs flat 0.171): inadmissible edge 1167-230 (the edge curve turns back)",
    ('trj6_b1-ec-214.stp', 'quad'):
        'refused: /tmp/cadbridge-mesh-77s_8hqf/trj6_b1-ec-214.brep: gmsh failed: Impossible to mesh periodic surface 7; meshing gmsh surface 7 (Cone) in its (u, v) did not work either: gmsh surface 7 (Cone): i',
    ('trj6_b1-ec-214.stp', 'tri'):
        'refused: gmsh left 3 of 292 surfaces without elements (it could not recover their boundary in parameter space): gmsh surface 43 (Plane, area 284.1, ...), 65 (BSpline surface, area 16.42), 84 (Plane, area 280.4)',
    ('trj8_b1-ec-214.stp', 'quad'):
        'failed: exit 1: 24 of 54620 mesh nodes are further than 0.0304 from the CAD (or could not be projected): node 34789 at (176.125, 35.2605, 6.85844) distance 0.862905 (a thin strip beside an arch hole; tri converts soundly since 2026-12-07)',
}


def _convert(path: Path, mode: str, out: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    cmd = [sys.executable, "-m", "cadbridge", "-q", "convert", str(path), "-o", str(out), "--element", mode]
    try:
        return subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        pytest.fail(f"{path.name} {mode}: no result after {TIMEOUT} s")


def check_file(path: Path, mode: str, tmp_path: Path) -> None:
    """The reference of the module docstring for one file and mode."""
    out = tmp_path / "out"
    res = _convert(path, mode, out)
    err = res.stderr.strip().splitlines()
    if path.name in EXPECTED_REFUSALS and not (path.name in REFUSE_OR_SOUND and res.returncode == 0):
        assert res.returncode == 2, f"exit {res.returncode} (expected a refusal): {err[-1:] or res.stdout[-200:]}"
        assert len(err) == 1, err
        assert "CADBRIDGE_DEBUG" not in err[0], f"an unanticipated error, not a refusal: {err[0]}"
        assert not out.exists(), f"a refusal wrote {sorted(p.name for p in out.iterdir())}"
        return
    assert res.returncode == 0, f"exit {res.returncode}: {err[-1] if err else ''}"
    pytest.importorskip("OCP")
    from cadbridge.verify.soundness import tool_soundness

    tools = sorted(out.glob("*.nagata"))
    assert tools, "no tool file written"
    report = tool_soundness(path, tools)
    assert report.sound, report.line()


@pytest.mark.parametrize("name", FAST)
def test_fast_subset_converts_soundly(name: str, tmp_path: Path):
    check_file((CORPUS_STEP if name.endswith((".stp", ".step")) else CORPUS) / name, "quad", tmp_path)


def test_fast_subset_expected_refusal(tmp_path: Path):
    assert FAST_REFUSAL in EXPECTED_REFUSALS
    check_file(CORPUS / FAST_REFUSAL, "quad", tmp_path)


def _corpus_files() -> list[Path]:
    """The corpus' IGES files, then its STEP files."""
    files = sorted(CORPUS.glob("*.igs")) if CORPUS.is_dir() else []
    if CORPUS_STEP.is_dir():
        files += sorted(p for p in CORPUS_STEP.iterdir() if p.suffix.lower() in (".stp", ".step"))
    return files


def _cases() -> list:
    files = _corpus_files()
    cases = []
    for p in files:
        for mode in MODES:
            reason = KNOWN_FAILURES.get((p.name, mode))
            marks = [pytest.mark.xfail(strict=True, reason=reason)] if reason else []
            cases.append(pytest.param(p, mode, id=f"{p.name}-{mode}", marks=marks))
    return cases


@pytest.mark.slow
@pytest.mark.parametrize(("path", "mode"), _cases())
def test_corpus_file_converts_soundly(path: Path, mode: str, tmp_path: Path):
    check_file(path, mode, tmp_path)


def test_known_failures_name_corpus_files():
    """The table lists only files and modes that exist (a renamed file must not leave a stale row)."""
    names = {p.name for p in _corpus_files()}
    assert {f for f, _ in KNOWN_FAILURES} <= names
    assert {m for _, m in KNOWN_FAILURES} <= set(MODES)
