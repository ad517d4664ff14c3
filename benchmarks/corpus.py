"""Corpus benchmark (a script, not a test): does every real CAD file convert, and is the result sound?

Runs ``cadbridge convert FILE -o OUT --element quad`` and ``--element tri`` on every IGES file
of ``../shared/iges_real``, ``../shared/cad_corpus/iges`` and ``iges_samples/*.igs`` (the
git-ignored production dies ``iges_samples/production_die_*.igs`` are included when they
have been generated) and every STEP file of ``../shared/cad_corpus/step``, each run in its own subprocess with a time limit (``--timeout``,
default 60 s; the whole process group is killed at the limit), checks each converted
tool against OpenCASCADE in a second subprocess (``--check-timeout``, default 300 s), and writes
``benchmarks/results/corpus.md``: one row per file and mode.

    python benchmarks/corpus.py [--timeout 60] [--check-timeout 300] [--modes quad tri] [--only SUBSTRING ...]
                                [--out benchmarks/results/corpus.md] [--keep DIR]

Columns:
  CAD system   the IGES Global section's native system ID (parameter 5), or the STEP header's
               originating system (FILE_NAME), as the file states it
  faces        the number of faces cadbridge's reader finds (`read_iges`, `read_step`)
  expected     "refuse" for the files the corpus README marks "expected: clear refusal"
  status       converted (exit 0) / refused: the error line (exit 2 with a known input error:
               one line, no traceback hint) / failed: the error line (exit 1, an unanticipated
               error, a crash) / timeout
  time         wall time of the convert subprocess (s; a shared 2-core machine: scale only)
  nodes        mesh nodes over all tools, from convert's summary table
  Nagata, flat max |distance| of the Nagata surface and of the flat mesh to the faces' surfaces
               at the error grid (convert's own estimate, the summary's "surface err" and "flat
               err" columns, in the file's units; the largest over the tools)
  normal       convert's max normal error of the Nagata surface (degrees)
  OCC check    `cadbridge.verify.soundness.tool_soundness` on the tool files, in its own
               subprocess: "sound", or which check failed and by how much:
               (a) sampled nodes (up to 2000) on OCC's trimmed faces within 1e-6 x size,
               (b) node normals at interior nodes within 1e-4 deg of OCC's face normal at the
               node's foot (foot strictly inside the face by BRepClass_FaceClassifier, node on
               no free mesh edge and without corner-normal overrides), (c) Nagata patch
               centres no farther from OCC's faces than the flat element centres (maxima).
  ok           success: converted and sound, or an expected refusal refused

Progress goes to stderr, one line per run (file, mode, status, time).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
DIRS = (SHARED / "iges_real", SHARED / "cad_corpus" / "iges", ROOT / "iges_samples", SHARED / "cad_corpus" / "step")
SUFFIXES = (".igs", ".iges", ".stp", ".step")
CORPUS_README = SHARED / "cad_corpus" / "README.md"
RESULT = ROOT / "benchmarks" / "results" / "corpus.md"
MODES = ("quad", "tri")
ERROR_PREFIX = "cadbridge convert: error: "
UNANTICIPATED = "CADBRIDGE_DEBUG=1 shows the traceback"  # the CLI's hint on errors it did not foresee


REFUSE_OR_SOUND = {"occt_bug8363_f45_OpenCASCADE.igs"}
"""Expected refusals that may instead convert soundly, as issue "Every real CAD file converts"
accepts for this one (its loop crosses itself in a lobe within the trim tolerance, which
cadbridge cuts off as it does other such lobes; OCC calls the wire self-intersecting)."""


def corpus_files() -> list[Path]:
    """Every IGES file of `DIRS` that exists, directory by directory, sorted by name."""
    files: list[Path] = []
    for d in DIRS:
        if d.is_dir():
            files += sorted(p for p in d.iterdir() if p.suffix.lower() in SUFFIXES)
    return files


def expected_refusals(readme: Path = CORPUS_README) -> set[str]:
    """File names of the corpus README's table rows whose note says "expected: clear refusal"."""
    if not readme.is_file():
        return set()
    names = set()
    for line in readme.read_text(encoding="utf-8").splitlines():
        if line.startswith("|") and "expected: clear refusal" in line:
            first = line.strip("|").split("|")[0].strip()
            names.add(first.split()[0])
    return names


def _hollerith_fields(text: str, count: int) -> list[str]:
    """The first ``count`` Global fields of ``text`` (default delimiters assumed when the
    header cannot be parsed otherwise): Hollerith strings decoded, other fields stripped."""
    pd, i, out = ",", 0, []
    m = re.match(r"\s*1H(.)", text)
    if m:
        pd = m.group(1)
    while i < len(text) and len(out) < count:
        m = re.match(r"\s*(\d+)H", text[i:])
        if m:
            n = int(m.group(1))
            start = i + m.end()
            out.append(text[start:start + n])
            i = start + n
            j = text.find(pd, i)
            i = len(text) if j < 0 else j + 1
        else:
            j = text.find(pd, i)
            out.append(text[i:j if j >= 0 else len(text)].strip())
            i = len(text) if j < 0 else j + 1
    return out


def header(path: Path) -> tuple[str, int | None]:
    """(native system ID = Global parameter 5, or a STEP file's originating system;
    cadbridge's face count, None if it cannot read the file). The system comes from
    `read_iges`, or from the raw G records when that fails."""
    from cadbridge.formats import cad_format
    from cadbridge.iges import read_iges

    if cad_format(path) == "step":
        from cadbridge.step import originating_system, read_step

        try:
            return originating_system(path), len(read_step(path).faces)
        except Exception:
            return originating_system(path), None

    try:
        model = read_iges(path)
        return model.system or "", len(model.faces)
    except Exception:  # the table still names the system of a file cadbridge refuses
        from cadbridge.iges.lexer import split_sections

        try:
            secs = split_sections(path.read_bytes().decode("latin-1"), path.name)
            fields = _hollerith_fields("".join(r.text for r in secs.global_), 5)
            return (fields[4] if len(fields) > 4 else ""), None
        except Exception:
            return "", None


@dataclass
class Run:
    """One convert run of one file in one mode."""

    file: Path
    mode: str
    status: str  # "converted" | "refused" | "failed" | "timeout"
    line: str = ""  # the error line (refused / failed)
    seconds: float = 0.0
    nodes: int | None = None
    nagata: float | None = None
    flat: float | None = None
    normal: float | None = None
    soundness: dict = field(default_factory=dict)  # `SoundnessReport` as JSON (+ "line", "sound")
    written: list[str] = field(default_factory=list)  # files in the output folder afterwards

    @property
    def sound(self) -> bool:
        return self.status == "converted" and bool(self.soundness.get("sound"))


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def _run(cmd: list[str], timeout: float) -> tuple[int | None, str, str, float]:
    """(exit code or None on timeout, stdout, stderr, seconds); the process group is killed at the limit."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
        return proc.returncode, out, err, time.perf_counter() - t0
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        return None, out, err, time.perf_counter() - t0


def error_line(stderr: str) -> str:
    """The CLI's error line (without its prefix), else the last line of stderr."""
    lines = [ln.strip() for ln in stderr.splitlines() if ln.strip()]
    for ln in reversed(lines):
        if ln.startswith(ERROR_PREFIX):
            return ln[len(ERROR_PREFIX):]
    return lines[-1] if lines else "(no message)"


def parse_summary(stdout: str) -> list[dict]:
    """The tool rows of convert's summary table: name, nodes, elements, surface, boundary, flat
    and normal error (the last seven columns; the name may hold spaces)."""
    rows, inside = [], False
    for ln in stdout.splitlines():
        if ln.strip().startswith("tool") and "surface err" in ln:
            inside = True
            continue
        if inside:
            parts = ln.split()
            if len(parts) < 8 or not parts[-1].endswith("°"):
                break
            try:
                rows.append({"name": " ".join(parts[:-7]), "nodes": int(parts[-6]), "elements": int(parts[-5]),
                             "surface": float(parts[-4]), "boundary": float(parts[-3]), "flat": float(parts[-2]),
                             "normal": float(parts[-1].rstrip("°"))})
            except ValueError:
                break
    return rows


def convert_run(path: Path, mode: str, out: Path, timeout: float, check_timeout: float | None = None) -> Run:
    """``cadbridge convert path -o out --element mode`` in a subprocess, classified (see the
    module docstring); the OCC check of a converted run in a second one, with its own time
    limit ``check_timeout`` (None: no check)."""
    cmd = [sys.executable, "-m", "cadbridge", "convert", str(path), "-o", str(out), "--element", mode]
    rc, stdout, stderr, seconds = _run(cmd, timeout)
    written = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    if rc is None:
        return Run(path, mode, "timeout", f"no result after {timeout:g} s", seconds, written=written)
    if rc != 0:
        line = error_line(stderr)
        refused = rc == 2 and stderr.count(ERROR_PREFIX) == 1 and UNANTICIPATED not in line
        return Run(path, mode, "refused" if refused else "failed", line if refused else f"exit {rc}: {line}",
                   seconds, written=written)
    rows = parse_summary(stdout)
    run = Run(path, mode, "converted", "", seconds, written=written)
    if rows:
        run.nodes = sum(r["nodes"] for r in rows)
        run.nagata = max(r["surface"] for r in rows)
        run.flat = max(r["flat"] for r in rows)
        run.normal = max(r["normal"] for r in rows)
    if check_timeout is not None:
        run.soundness = check_soundness(path, sorted(out.glob("*.nagata")), check_timeout)
    return run


def check_soundness(path: Path, tools: list[Path], timeout: float) -> dict:
    """`cadbridge.verify.soundness` in a subprocess: its JSON report, or {"line": why not}."""
    if not tools:
        return {"sound": False, "line": "no tool file written"}
    cmd = [sys.executable, "-m", "cadbridge.verify.soundness", str(path), *map(str, tools)]
    rc, stdout, stderr, _ = _run(cmd, timeout)
    if rc is None:
        return {"sound": False, "line": f"OCC check: timeout after {timeout:g} s"}
    last = stdout.strip().splitlines()[-1] if stdout.strip() else ""
    if rc != 0 or not last.startswith("{"):
        return {"sound": False, "line": f"OCC check: exit {rc}: {error_line(stderr)}"}
    return json.loads(last)


def _num(x: float | None, fmt: str) -> str:
    return "—" if x is None else format(x, fmt)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def success(run: Run, expected: bool) -> bool:
    """Converted and sound, or refused as expected (or converted soundly: `REFUSE_OR_SOUND`)."""
    if expected and run.file.name in REFUSE_OR_SOUND:
        return run.status == "refused" or bool(run.sound)
    return run.status == "refused" if expected else run.sound


def markdown(runs: list[Run], systems: dict[Path, tuple[str, int | None]], expected: set[str], command: str,
             timeout: float, check_timeout: float) -> str:
    """The result page: how it was made, the totals per mode, one row per file and mode."""
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".",
                            f":(exclude){RESULT.relative_to(ROOT)}"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    lines = [
        "# Corpus: every real CAD file through `cadbridge convert`",
        "",
        f"Made by `{command}` on {now}, git commit {commit}{' (with uncommitted changes)' if dirty else ''}, "
        f"time limit {timeout:g} s per convert run and {check_timeout:g} s per OCC check, on a shared 2-core machine (times indicate scale only). "
        "What each column measures: the docstring of `benchmarks/corpus.py`; the OCC check is "
        "`cadbridge.verify.soundness.tool_soundness`.",
        "",
        "## Totals",
        "",
        "| mode | runs | converted | sound | refused | of which expected | failed | timeout | success |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for mode in dict.fromkeys(r.mode for r in runs):
        rs = [r for r in runs if r.mode == mode]
        n = lambda s: sum(r.status == s for r in rs)  # noqa: E731
        lines.append(f"| {mode} | {len(rs)} | {n('converted')} | {sum(r.sound for r in rs)} | {n('refused')} | "
                     f"{sum(r.status == 'refused' and r.file.name in expected for r in rs)} | {n('failed')} | "
                     f"{n('timeout')} | {sum(success(r, r.file.name in expected) for r in rs)} |")
    lines += [
        "",
        "success: converted and sound, or refused where the corpus README expects a clear refusal "
        f"({', '.join(sorted(REFUSE_OR_SOUND))}: either, as the issue accepts).",
        "",
        "## Runs",
        "",
        "| file | CAD system | faces | expected | mode | status | time (s) | nodes | Nagata err | flat err "
        "| normal err (°) | OCC check | ok |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        system, faces = systems[r.file]
        exp = r.file.name in expected
        status = r.status + (f": {r.line}" if r.line and r.status in ("refused", "failed") else "")
        if r.status != "converted" and r.written:
            status += f" (left {len(r.written)} files in the output folder)"
        occ = r.soundness.get("line", "") if r.status == "converted" else ""
        if exp and r.status != "refused" and not (r.file.name in REFUSE_OR_SOUND and r.sound):
            occ = (occ + "; " if occ else "") + "not refused"
        lines.append(
            f"| {_cell(r.file.parent.name + '/' + r.file.name)} | {_cell(system)} | {_num(faces, 'd')} | "
            f"{'refuse' if exp else ''} | {r.mode} | {_cell(status)} | {r.seconds:.1f} | {_num(r.nodes, 'd')} | "
            f"{_num(r.nagata, '.2e')} | {_num(r.flat, '.2e')} | {_num(r.normal, '.3g')} | {_cell(occ)} | "
            f"{'yes' if success(r, exp) else 'no'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--timeout", type=float, default=60.0, help="time limit per convert run, s")
    ap.add_argument("--check-timeout", type=float, default=300.0, help="time limit per OCC check, s")
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    ap.add_argument("--only", nargs="+", default=None, help="only files whose name contains one of these")
    ap.add_argument("--out", type=Path, default=RESULT, help="the Markdown table to write")
    ap.add_argument("--keep", type=Path, default=None, help="keep the convert outputs under this folder")
    args = ap.parse_args(argv)

    files = [p for p in corpus_files() if args.only is None or any(s in p.name for s in args.only)]
    expected = expected_refusals()
    systems = {p: header(p) for p in files}
    runs: list[Run] = []
    work = Path(tempfile.mkdtemp(prefix="cadbridge_corpus_"))
    try:
        for p in files:
            for mode in args.modes:
                out = (args.keep or work) / f"{p.stem}_{mode}"
                if out.exists():
                    shutil.rmtree(out)
                run = convert_run(p, mode, out, args.timeout, args.check_timeout)
                runs.append(run)
                what = run.status + (f" ({run.soundness.get('line', '')})" if run.status == "converted" else
                                     f": {run.line}" if run.line else "")
                print(f"{p.name} {mode}: {what}, {run.seconds:.1f} s", file=sys.stderr, flush=True)
                if args.keep is None:
                    shutil.rmtree(out, ignore_errors=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    command = "python benchmarks/corpus.py" + (" " + " ".join(argv if argv is not None else sys.argv[1:])).rstrip()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(markdown(runs, systems, expected, command, args.timeout, args.check_timeout), encoding="utf-8")
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
