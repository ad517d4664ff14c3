"""NUMISHEET'93 U-shape benchmark (thesis §5.2, Fig. 49): the same run as `cadbridge ushape`.

    python benchmarks/ushape_numisheet93.py -o out/
"""

from __future__ import annotations

import argparse
import sys

from cadbridge.cli import Progress
from cadbridge.ushape.benchmark import run_ushape


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-o", "--output", required=True, help="output folder")
    parser.add_argument("--grid", type=int, default=20, help="grid divisions per patch")
    parser.add_argument("--fine-size", type=float, default=4.0, help="element size of the triangle variant (mm)")
    args = parser.parse_args(argv)
    with Progress("ushape") as progress:
        summary = run_ushape(args.output, grid=args.grid, fine_size=args.fine_size, progress=progress)
    print(summary.table())
    print()
    print("\n".join(summary.findings("die")))
    return 0


if __name__ == "__main__":
    sys.exit(main())
