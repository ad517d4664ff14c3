"""Digests of the tool files `cadbridge convert` writes, to show a change leaves them bit-identical.

Runs `cadbridge convert F -o OUT` (default settings) on every sample of `iges_samples/` and
every file of `../shared/iges_real/`, one process each, and writes one line per tool file:
`<input file>  <tool file path in OUT>  <sha256>`. Two runs of two trees compare with `diff`:

    python benchmarks/toolfile_digests.py -o /tmp/before.txt            # on the old tree
    python benchmarks/toolfile_digests.py -o /tmp/after.txt             # on the new tree
    diff /tmp/before.txt /tmp/after.txt && echo bit-identical

`--ushape` also runs `cadbridge ushape` and digests its tool files and `summary.md` (the
U-shape table, its "Run time" line left out). A tool file records the path of its CAD file, so two
trees are compared on the same input paths (`--samples`). The package imported is the one `python -m cadbridge`
finds (set PYTHONPATH to digest another checkout).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REAL = ROOT.parent / "shared" / "iges_real"


def inputs(samples: Path, real: Path) -> list[Path]:
    """The samples (the production dies excluded: they are generated on request) and real files."""
    files = sorted(p for p in samples.glob("*.igs") if not p.name.startswith("production_die"))
    if real.is_dir():
        files += sorted(p for p in real.iterdir() if p.suffix.lower() in (".igs", ".iges"))
    return files


def digest_tree(out: Path, suffixes: tuple[str, ...]) -> list[tuple[str, str]]:
    """(relative path, sha256) of every file under `out` whose name ends with one of `suffixes`."""
    rows = []
    for p in sorted(out.rglob("*")):
        if p.is_file() and p.name.endswith(suffixes):
            data = p.read_bytes()
            if p.name == "summary.md":  # its "Run time" line is the one line that is a timing
                data = b"\n".join(ln for ln in data.split(b"\n") if not ln.startswith(b"Run time "))
            rows.append((str(p.relative_to(out)), hashlib.sha256(data).hexdigest()))
    return rows


def run(args: list[str]) -> int:
    env = dict(os.environ, CADBRIDGE_QUIET="1")
    return subprocess.run([sys.executable, "-m", "cadbridge", "--quiet", *args], env=env,
                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True).returncode


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--output", type=Path, required=True, help="digest listing to write")
    ap.add_argument("--ushape", action="store_true", help="also digest `cadbridge ushape`")
    ap.add_argument("--samples", type=Path, default=ROOT / "iges_samples",
                    help="folder of sample IGES files (default: %(default)s); a tool file records its CAD's path, "
                         "so compare two trees on the same input paths")
    ap.add_argument("--real", type=Path, default=REAL, help="folder of real IGES files (default: %(default)s)")
    a = ap.parse_args()
    lines = []
    with tempfile.TemporaryDirectory() as tmp:
        for f in inputs(a.samples, a.real):
            out = Path(tmp) / f.stem
            rc = run(["convert", str(f), "-o", str(out)])
            rows = digest_tree(out, (".nagata",)) if rc == 0 else []
            lines.append(f"{f.name}  exit {rc}")
            lines += [f"{f.name}  {rel}  {h}" for rel, h in rows]
            print(f"{f.name}: exit {rc}, {len(rows)} tool files", file=sys.stderr, flush=True)
        if a.ushape:
            out = Path(tmp) / "ushape"
            rc = run(["ushape", "-o", str(out)])
            rows = digest_tree(out, (".nagata", "summary.md"))
            lines.append(f"ushape  exit {rc}")
            lines += [f"ushape  {rel}  {h}" for rel, h in rows]
            print(f"ushape: exit {rc}, {len(rows)} files", file=sys.stderr, flush=True)
    a.output.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
