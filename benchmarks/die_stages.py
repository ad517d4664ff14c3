"""Wall and CPU time of every stage of `cadbridge convert` on one file (the production die).

Runs `cadbridge.convert` in this process with a progress object that records, for every
stage line the pipeline reports (`cadbridge.common.progress`), its full text, its wall time
and the process CPU time (all threads) until the next stage; then prints them grouped into
the pipeline's stages (read, mesh, project, patches, errors, write, ...), with the load
average at start and end. CPU includes the forked picture process (counted when it ends):

    python benchmarks/die_stages.py iges_samples/production_die_nurbs.igs -o /tmp/die_out
    python benchmarks/die_stages.py DIE -o OUT --shape-tolerance 0.01 --detail

Options after the file are passed to `cadbridge.convert` (``--shape-tolerance``, ``--element``).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time

GROUPS = (  # (group, regular expression on the stage text), first match wins
    ("read + heal", r"^reading "),
    ("gmsh meshing", r"^meshing |with the Nagata size field|^the mesh of the model's B-rep"),
    ("sizing (curvature law, inflections, sewn BREP)", r"principal curvatures|inflection lines|sewing .* once"),
    ("project nodes + CAD normals + guards", r"projecting nodes|edges across inflections"),
    ("guard refinement", r"guard|finer"),
    ("boundary edges + Nagata patches", r"boundary edges|Nagata patches"),
    ("errors vs CAD (incl. both-rules line)", r"errors vs CAD"),
    ("independent check", r"independent check"),
    ("pass summary", r"^pass \d+ done"),
    ("write tool files + report (VTU, PNG, maps)", r"writing tool file|report pictures"),
)


def cpu() -> float:
    """CPU time [s] of this process (all threads) and of its ended children (the forked picture
    process, `cadbridge.common.fork_jobs`)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


class Recorder:
    """Duck-typed `cadbridge.common.progress.Progress`: (text, wall start, cpu start) per stage."""

    def __init__(self, echo: bool) -> None:
        self.rows: list[tuple[str, float, float]] = []
        self.echo = echo
        self.t0 = time.perf_counter()

    def stage(self, text: str) -> None:
        self.rows.append((text, time.perf_counter(), cpu()))
        if self.echo:
            print(f"[{time.perf_counter() - self.t0:7.1f} s] {text[:110]}", file=sys.stderr, flush=True)

    def update(self, done: int, total: int) -> None:
        pass

    def close(self) -> None:
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cad")
    ap.add_argument("-o", "--output", required=True)
    ap.add_argument("--shape-tolerance", type=float, default=None)
    ap.add_argument("--element", default="quad")
    ap.add_argument("--detail", action="store_true", help="also every stage line")
    ap.add_argument("--quiet", action="store_true", help="no stage lines on stderr while running")
    a = ap.parse_args()

    import cadbridge
    from cadbridge.tool.build import ToolQualityError

    load0 = os.getloadavg()
    rec = Recorder(not a.quiet)
    w0, c0 = time.perf_counter(), cpu()
    status = "exit 0"
    try:
        run = cadbridge.convert(a.cad, a.output, element=a.element, shape_tolerance=a.shape_tolerance, progress=rec)
    except ToolQualityError as e:
        status, run = f"ToolQualityError: {str(e)[:200]}", None
    w1, c1 = time.perf_counter(), cpu()
    load1 = os.getloadavg()
    rec.rows.append(("end", w1, c1))

    groups: dict[str, list[float]] = {}
    lines = []
    for (text, w, c), (_, wn, cn) in zip(rec.rows, rec.rows[1:]):
        g = next((name for name, rx in GROUPS if re.search(rx, text)), "other")
        acc = groups.setdefault(g, [0.0, 0.0])
        acc[0] += wn - w
        acc[1] += cn - c
        lines.append((text, wn - w, cn - c))
    print(f"# cadbridge convert {a.cad} (element {a.element}"
          + (f", shape tolerance {a.shape_tolerance:g}" if a.shape_tolerance else "") + f"): {status}")
    print(f"load average at start {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}, at end "
          f"{load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
    print(f"\n| stage | wall [s] | CPU [s] |\n|---|---:|---:|")
    for name, _ in GROUPS + (("other", ""),):
        if name in groups:
            print(f"| {name} | {groups[name][0]:.1f} | {groups[name][1]:.1f} |")
    print(f"| **total** | **{w1 - w0:.1f}** | **{c1 - c0:.1f}** |")
    if run is not None:
        print("\n```\n" + run.summary() + "\n```")
        if getattr(run, "adaptive", None) is not None:
            print("\n```\n" + run.adaptive.summary() + "\n```")
    if a.detail:
        print("\n| stage line | wall [s] | CPU [s] |\n|---|---:|---:|")
        for text, w, c in lines:
            if w >= 0.05:
                print(f"| {text[:120]} | {w:.2f} | {c:.2f} |")


if __name__ == "__main__":
    main()
