"""Mutants benchmark (a script, not a test): do damaged IGES files convert or get refused cleanly?

Makes damaged copies ("mutants") of a few IGES files, deterministically from ``--seed``, with
the damage files get in transfer, and runs ``cadbridge --quiet convert MUTANT -o OUT`` on each
in its own subprocess with a time limit (``--timeout``, default 60 s; the whole process group
is killed at the limit). Writes ``benchmarks/results/mutants.md``: one row per mutant and the
totals. The mutants live in a temporary folder (``--keep DIR`` keeps them and the outputs).

    python benchmarks/mutants.py [--seed 1] [--per-kind 2] [--timeout 60] [--kinds KIND ...]
                                 [--only SUBSTRING ...] [--files FILE ...] [--keep DIR]
                                 [--out benchmarks/results/mutants.md]

Damage kinds (`KINDS`; each picks its place with the mutant's own random generator):
  truncate_line   a P line cut short at a random column (its sequence number lost)
  truncate_file   the file cut at a random place in its P section (an aborted transfer)
  digit_p         one digit of a P line's data changed to another digit
  digit_d         one digit of a Directory Entry field changed to another digit
  scale_number    one real of a P line multiplied by 10^3 or 10^6 (its exponent raised)
  swap_entities   the parameter pointers (and line counts) of two DEs swapped, of the same
                  entity type where the file has two
  delete_line     one line deleted (any section)
  duplicate_line  one line written twice
  crlf            every line ended by CR LF instead of LF
  line_length     one line one column longer or shorter (a blank inserted or a character dropped)
  garbage_field   one P parameter replaced by garbage ("?", "1..", "NAN", "1E999", "X", "-")

Status of a run:
  converted       exit 0 and no NaN or infinity in any output file
  refused         exit 1 or 2 with exactly one line on stderr (besides one-line warnings
                  "cadbridge convert: warning: ..." before it), which names no internal
                  exception class (ValueError, IndexError, ...), holds no "Traceback" and no
                  "CADBRIDGE_DEBUG" (the CLI's hint on errors it did not foresee), and nothing
                  left in the output folder
  internal error  any other ending (the line says what)
  timeout         no answer within the time limit
  nan             exit 0, but an output file holds a NaN or an infinity

A mutant is "readable" when `cadbridge.iges.read_iges` reads it as a model with faces (in its
own subprocess, same time limit); the totals count the readable mutants separately, as the
issue's acceptance speaks of mutated files that still read.
"""

from __future__ import annotations

import argparse
import datetime
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
RESULT = ROOT / "benchmarks" / "results" / "mutants.md"
DEFAULT_FILES = (
    SHARED / "iges_real" / "occt_OCC131-2_ANSA9.igs",
    SHARED / "iges_real" / "occt_bug33327_C3D.igs",
    SHARED / "cad_corpus" / "iges" / "occt_OCC131-1_ANSA9.igs",
    SHARED / "cad_corpus" / "iges" / "occt_PRO20360-T7_CATIAV4.igs",
    SHARED / "cad_corpus" / "iges" / "occt_bug29356_OpenCASCADE.igs",
    ROOT / "iges_samples" / "trimmed_hole.igs",
    ROOT / "iges_samples" / "ushape_tools_analytic.igs",
)
KINDS = ("truncate_line", "truncate_file", "digit_p", "digit_d", "scale_number", "swap_entities", "delete_line",
         "duplicate_line", "crlf", "line_length", "garbage_field")
GARBAGE = ("?", "1..", "NAN", "1E999", "X", "-")
INTERNAL = re.compile(r"Traceback|CADBRIDGE_DEBUG|\b(ValueError|IndexError|KeyError|TypeError|AttributeError|"
                      r"ZeroDivisionError|AssertionError|RuntimeError|FloatingPointError|OverflowError|MemoryError|"
                      r"RecursionError|NameError|NotImplementedError|LinAlgError|StopIteration|UnicodeError|"
                      r"UnicodeDecodeError|UnboundLocalError|BrokenPipeError)\b")
WARNING = re.compile(r"cadbridge \w+: warning: ")
NONFINITE = re.compile(r"(?<![A-Za-z_])[-+]?(nan|inf|infinity)(?![A-Za-z_])", re.IGNORECASE)
TEXT_OUTPUTS = (".nagata", ".txt", ".csv", ".md", ".json", ".igs", ".iges")
MESH_OUTPUTS = (".vtu", ".msh")
READ_PROBE = ("import sys\nfrom cadbridge.iges import read_iges\n"
              "m = read_iges(sys.argv[1])\nprint(len(m.faces))\n")


# ---------------------------------------------------------------- the damage

def _section(line: str) -> str:
    """The section letter of a fixed-format record (column 73), '' if the line is shorter."""
    return line[72] if len(line) > 72 else ""


def _lines_of(lines: list[str], letter: str) -> list[int]:
    return [i for i, ln in enumerate(lines) if _section(ln) == letter]


def _join(lines: list[str], eol: str = "\n") -> str:
    return eol.join(lines) + eol


def _truncate_line(lines, rng):
    i = rng.choice(_lines_of(lines, "P"))
    c = rng.randrange(8, 64)
    out = lines[:i] + [lines[i][:c]] + lines[i + 1:]
    return _join(out), f"line {i + 1} (P) cut after column {c}"


def _truncate_file(lines, rng):
    ps = _lines_of(lines, "P")
    i = rng.choice(ps)
    c = rng.randrange(1, 80)
    out = lines[:i] + [lines[i][:c]]
    return "\n".join(out), f"file ends in line {i + 1} after column {c} (no T section)"


def _change_digit(text: str, cols: range, rng) -> tuple[str, int, str, str] | None:
    where = [k for k in cols if k < len(text) and text[k].isdigit()]
    if not where:
        return None
    k = rng.choice(where)
    new = rng.choice([d for d in "0123456789" if d != text[k]])
    return text[:k] + new + text[k + 1:], k, text[k], new


def _digit_p(lines, rng):
    ps = _lines_of(lines, "P")
    while True:
        i = rng.choice(ps)
        r = _change_digit(lines[i], range(64), rng)
        if r is not None:
            break
    out = list(lines)
    out[i], k, old, new = r
    return _join(out), f"line {i + 1} (P) column {k + 1}: digit {old} -> {new}"


_D_FIELDS = ("entity type", "parameter data", "structure", "line font", "level", "view", "transformation",
             "label display", "status", "entity type", "line weight", "color", "parameter line count", "form",
             "reserved", "reserved", "label", "subscript")


def _digit_d(lines, rng):
    ds = _lines_of(lines, "D")
    while True:
        i = rng.choice(ds)
        r = _change_digit(lines[i], range(72), rng)
        if r is not None:
            break
    out = list(lines)
    out[i], k, old, new = r
    second = (ds.index(i) % 2) == 1
    fld = _D_FIELDS[9 * second + k // 8]
    return _join(out), f"line {i + 1} (D, {fld}) column {k + 1}: digit {old} -> {new}"


_REAL = re.compile(r"(?<![\w.])([-+]?(?:\d+\.\d*|\.\d+)(?:[EeDd][-+]?\d+)?)(?![\w.])")


def _scale_number(lines, rng):
    ps = _lines_of(lines, "P")
    k = rng.choice((3, 6))
    for _ in range(1000):
        i = rng.choice(ps)
        data = lines[i][:64]
        cands = [m for m in _REAL.finditer(data) if float(m.group(1).replace("D", "E").replace("d", "e")) != 0.0]
        if not cands:
            continue
        m = rng.choice(cands)
        t = m.group(1)
        em = re.search(r"[EeDd]([-+]?\d+)$", t)
        new = f"{t[:em.start()]}{t[em.start()]}{int(em.group(1)) + k}" if em else f"{t}E{k}"
        grow = len(new) - len(t)
        if len(data.rstrip()) + grow > 64:
            continue
        data = (data[:m.start(1)] + new + data[m.end(1):]).rstrip().ljust(64)[:64]
        out = list(lines)
        out[i] = data + lines[i][64:]
        return _join(out), f"line {i + 1} (P): {t} -> {new} (x 10^{k})"
    raise RuntimeError("no real number with room to grow")


def _swap_entities(lines, rng):
    ds = _lines_of(lines, "D")
    entries = [(ds[j], ds[j + 1]) for j in range(0, len(ds) - 1, 2)]
    by_type: dict[str, list] = {}
    for e in entries:
        by_type.setdefault(lines[e[0]][:8].strip(), []).append(e)
    pairs = [v for v in by_type.values() if len(v) >= 2]
    a, b = rng.sample(rng.choice(pairs), 2) if pairs else rng.sample(entries, 2)
    out = list(lines)
    # field 2 (parameter data pointer, columns 9-16) and field 14 (parameter line count, 25-32)
    out[a[0]] = lines[a[0]][:8] + lines[b[0]][8:16] + lines[a[0]][16:]
    out[b[0]] = lines[b[0]][:8] + lines[a[0]][8:16] + lines[b[0]][16:]
    out[a[1]] = lines[a[1]][:24] + lines[b[1]][24:32] + lines[a[1]][32:]
    out[b[1]] = lines[b[1]][:24] + lines[a[1]][24:32] + lines[b[1]][32:]
    de = lambda e: int(lines[e[0]][73:80])  # noqa: E731
    return _join(out), (f"DE {de(a)} and DE {de(b)} (entity {lines[a[0]][:8].strip()} and "
                        f"{lines[b[0]][:8].strip()}): parameter pointers swapped")


def _delete_line(lines, rng):
    i = rng.randrange(len(lines))
    return _join(lines[:i] + lines[i + 1:]), f"line {i + 1} ({_section(lines[i]) or '?'}) deleted"


def _duplicate_line(lines, rng):
    i = rng.randrange(len(lines))
    return _join(lines[:i + 1] + lines[i:]), f"line {i + 1} ({_section(lines[i]) or '?'}) duplicated"


def _crlf(lines, rng):
    return _join(lines, "\r\n"), "every line ended by CR LF"


def _line_length(lines, rng):
    i = rng.randrange(len(lines))
    c = rng.randrange(0, 72)
    out = list(lines)
    if rng.random() < 0.5:
        out[i] = lines[i][:c] + " " + lines[i][c:]
        what = f"a blank inserted at column {c + 1}"
    else:
        out[i] = lines[i][:c] + lines[i][c + 1:]
        what = f"column {c + 1} dropped"
    return _join(out), f"line {i + 1} ({_section(lines[i]) or '?'}): {what}"


def _garbage_field(lines, rng):
    ps = _lines_of(lines, "P")
    for _ in range(1000):
        i = rng.choice(ps)
        data = lines[i][:64]
        toks = [m for m in re.finditer(r"[^,;\s]+", data) if "H" not in m.group(0)]
        if not toks:
            continue
        m = rng.choice(toks)
        g = rng.choice([g for g in GARBAGE if len(data.rstrip()) - len(m.group(0)) + len(g) <= 64])
        data = (data[:m.start()] + g + data[m.end():]).rstrip().ljust(64)[:64]
        out = list(lines)
        out[i] = data + lines[i][64:]
        return _join(out), f"line {i + 1} (P): {m.group(0)} -> {g}"
    raise RuntimeError("no parameter to damage")


DAMAGE = {"truncate_line": _truncate_line, "truncate_file": _truncate_file, "digit_p": _digit_p,
          "digit_d": _digit_d, "scale_number": _scale_number, "swap_entities": _swap_entities,
          "delete_line": _delete_line, "duplicate_line": _duplicate_line, "crlf": _crlf,
          "line_length": _line_length, "garbage_field": _garbage_field}
assert tuple(DAMAGE) == KINDS


@dataclass
class Mutant:
    """One damaged copy of ``source``: its text and what was done to it."""

    source: Path
    kind: str
    index: int
    text: str
    damage: str

    @property
    def name(self) -> str:
        return f"{self.source.stem}__{self.kind}_{self.index}.igs"


def mutate(source: Path, kind: str, index: int = 0, seed: int = 1) -> Mutant:
    """The ``index``-th mutant of ``source`` with damage ``kind``: the same text for the same
    (file name, kind, index, seed) on every machine (a string-seeded `random.Random`)."""
    lines = source.read_bytes().decode("latin-1").splitlines()
    rng = random.Random(f"{seed}:{source.name}:{kind}:{index}")
    text, damage = DAMAGE[kind](lines, rng)
    return Mutant(source, kind, index, text, damage)


def mutants(files, kinds=KINDS, per_kind: int = 1, seed: int = 1) -> list[Mutant]:
    """Every (file, kind, index < per_kind) mutant, file by file."""
    return [mutate(Path(f), k, i, seed) for f in files for k in kinds for i in range(per_kind)]


# ---------------------------------------------------------------- the runs

def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.pop("CADBRIDGE_DEBUG", None)
    return env


def _run(cmd: list[str], timeout: float, cwd: Path) -> tuple[int | None, str, str, float]:
    """(exit code or None on timeout, stdout, stderr, seconds); the process group is killed at the limit."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=cwd, env=_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            errors="replace", start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
        return proc.returncode, out, err, time.perf_counter() - t0
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        out, err = proc.communicate()
        return None, out, err, time.perf_counter() - t0


def nonfinite_outputs(folder: Path) -> list[str]:
    """Output files of ``folder`` that hold a NaN or an infinity: text files as tokens, VTU and
    gmsh meshes through meshio (points and every float data array)."""
    import numpy as np

    bad = []
    for p in sorted(folder.rglob("*")) if folder.is_dir() else []:
        suffix = p.suffix.lower()
        if suffix in TEXT_OUTPUTS:
            if NONFINITE.search(p.read_text(encoding="latin-1")):
                bad.append(p.name)
        elif suffix in MESH_OUTPUTS:
            import meshio

            m = meshio.read(p)
            arrays = [m.points] + list(m.point_data.values()) + [a for v in m.cell_data.values() for a in v]
            if any(np.issubdtype(np.asarray(a).dtype, np.floating) and not np.all(np.isfinite(a)) for a in arrays):
                bad.append(p.name)
    return bad


@dataclass
class Result:
    """One mutant's runs: whether it reads, and how convert ends."""

    mutant: Mutant
    readable: str  # "yes (N faces)" or "no: ..." (the reader's line)
    status: str  # "converted" | "refused" | "internal error" | "timeout" | "nan"
    line: str
    seconds: float

    @property
    def reads(self) -> bool:
        return self.readable.startswith("yes")

    @property
    def clean(self) -> bool:
        return self.status in ("converted", "refused")


def classify(rc: int | None, stderr: str, out: Path, timeout: float) -> tuple[str, str]:
    """(status, line) of one ``cadbridge --quiet convert`` run (see the module docstring)."""
    lines = [ln.strip() for ln in stderr.splitlines() if ln.strip()]
    if rc is None:
        return "timeout", f"no answer within {timeout:g} s"
    if rc == 0:
        bad = nonfinite_outputs(out)
        return ("nan", "NaN or infinity in " + ", ".join(bad)) if bad else ("converted", "")
    last = lines[-1] if lines else "(nothing on stderr)"
    if rc not in (1, 2):
        return "internal error", f"exit {rc}: {last}"
    errors = [ln for ln in lines if not WARNING.match(ln)]  # one-line warnings may come first
    if len(errors) != 1 or errors[0] != last:
        return "internal error", f"exit {rc} with {len(errors)} lines on stderr besides warnings: {last}"
    if INTERNAL.search(last):
        return "internal error", f"exit {rc}: {last}"
    left = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    if left:
        return "internal error", f"exit {rc}, {len(left)} files left in the output folder: {last}"
    return "refused", f"exit {rc}: {last}"


def run_mutant(m: Mutant, work: Path, timeout: float) -> Result:
    """Write ``m`` under ``work``, probe that it reads, convert it; classified."""
    path = work / m.name
    path.write_bytes(m.text.encode("latin-1"))
    out = work / (path.stem + "_out")
    if out.exists():
        shutil.rmtree(out)
    rc, stdout, stderr, _ = _run([sys.executable, "-c", READ_PROBE, str(path)], timeout, work)
    if rc == 0 and stdout.strip().isdigit() and int(stdout.strip()) > 0:
        readable = f"yes ({int(stdout.strip())} faces)"
    elif rc == 0:
        readable = "no: no faces"
    elif rc is None:
        readable = f"no: reading takes more than {timeout:g} s"
    else:
        err = [ln for ln in stderr.splitlines() if ln.strip()]
        readable = "no: " + (err[-1].strip() if err else f"exit {rc}")
    rc, _, stderr, seconds = _run([sys.executable, "-m", "cadbridge", "--quiet", "convert", str(path), "-o", str(out)],
                                  timeout, work)
    status, line = classify(rc, stderr, out, timeout)
    return Result(m, readable, status, line, seconds)


# ---------------------------------------------------------------- the table

STATUSES = ("converted", "refused", "internal error", "timeout", "nan")


def _cell(text: str, limit: int = 300) -> str:
    text = text if len(text) <= limit else text[:limit - 3] + "..."
    return text.replace("|", "\\|")


def markdown(results: list[Result], command: str, timeout: float, seed: int) -> str:
    """The result page: how it was made, the totals (all and readable mutants), one row per mutant."""
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", ".",
                            f":(exclude){RESULT.relative_to(ROOT)}"], cwd=ROOT, capture_output=True,
                           text=True).stdout.strip()
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    files = list(dict.fromkeys(r.mutant.source for r in results))
    lines = [
        "# Mutants: damaged IGES files through `cadbridge convert`",
        "",
        f"Made by `{command}` on {now}, git commit {commit}{' (with uncommitted changes)' if dirty else ''}, "
        f"seed {seed}, time limit {timeout:g} s per run, on a shared 2-core machine (times indicate scale only). "
        f"{len(results)} mutants of {len(files)} files; the damage kinds and the statuses are defined in the "
        "docstring of `benchmarks/mutants.py`. A mutant is readable when `read_iges` reads it as a model with faces.",
        "",
        "## Totals",
        "",
        "| mutants | count | " + " | ".join(STATUSES) + " |",
        "|---|---|" + "---|" * len(STATUSES),
    ]
    for label, rs in (("all", results), ("readable", [r for r in results if r.reads])):
        lines.append(f"| {label} | {len(rs)} | " + " | ".join(str(sum(r.status == s for r in rs)) for s in STATUSES)
                     + " |")
    lines += [
        "",
        "## Runs",
        "",
        "| source | damage | readable | status | time (s) | line |",
        "|---|---|---|---|---|---|",
    ]
    for r in results:
        m = r.mutant
        lines.append(f"| {_cell(m.source.parent.name + '/' + m.source.name)} | {m.kind}: {_cell(m.damage)} | "
                     f"{_cell(r.readable, 120)} | {r.status} | {r.seconds:.1f} | {_cell(r.line)} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=1, help="the mutants' seed")
    ap.add_argument("--per-kind", type=int, default=2, help="mutants per file and damage kind")
    ap.add_argument("--timeout", type=float, default=60.0, help="time limit per run, s")
    ap.add_argument("--kinds", nargs="+", default=list(KINDS), choices=KINDS)
    ap.add_argument("--files", nargs="+", type=Path, default=None, help="IGES files to damage (default: seven)")
    ap.add_argument("--only", nargs="+", default=None, help="only files whose name contains one of these")
    ap.add_argument("--out", type=Path, default=RESULT, help="the Markdown table to write")
    ap.add_argument("--keep", type=Path, default=None, help="keep the mutants and outputs under this folder")
    args = ap.parse_args(argv)

    files = [Path(f) for f in (args.files or DEFAULT_FILES) if Path(f).is_file()]
    files = [f for f in files if args.only is None or any(s in f.name for s in args.only)]
    if not files:
        print("mutants: no input files", file=sys.stderr)
        return 2
    work = args.keep or Path(tempfile.mkdtemp(prefix="cadbridge_mutants_"))
    work.mkdir(parents=True, exist_ok=True)
    results = []
    try:
        for m in mutants(files, args.kinds, args.per_kind, args.seed):
            r = run_mutant(m, work, args.timeout)
            results.append(r)
            print(f"{m.name}: {m.damage}; reads: {r.readable}; {r.status}, {r.seconds:.1f} s"
                  + (f": {r.line}" if r.line else ""), file=sys.stderr, flush=True)
            if args.keep is None:
                (work / m.name).unlink(missing_ok=True)
                shutil.rmtree(work / (Path(m.name).stem + "_out"), ignore_errors=True)
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    command = "python benchmarks/mutants.py" + (" " + " ".join(argv if argv is not None else sys.argv[1:])).rstrip()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(markdown(results, command, args.timeout, args.seed), encoding="utf-8")
    bad = [r for r in results if not r.clean]
    print(f"wrote {args.out}: {len(results)} mutants, {sum(r.reads for r in results)} readable, "
          f"{len(bad)} internal errors, timeouts or NaN", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
